//! Stage 2: DOF numbering of the active nodes and the sparsity pattern of the step.
//!
//! Free components of active nodes are numbered node-major in node order; constrained
//! components (`GridFields::constrained`, set by modules at `Hook::Constraints`) and inactive
//! nodes get no DOF (`NO_DOF`), which eliminates Dirichlet conditions from the system. Two
//! nodes couple when a point's support or a module's coupling group (`GridFields::couplings`)
//! holds both. The matrix is told where its DOFs' nodes are (`solver::DofLayout`).

use bevy_ecs::prelude::*;

use crate::components::Support;
use crate::resources::{Grid, GridFields, Newton, Stage, StageClock};
use crate::solver::NO_DOF;

pub fn number_dofs<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
    points: Query<&Support<D>>,
    grid: Res<Grid<D>>,
) {
    let _timer = clock.time(Stage::Dofs);
    let fields = &mut *fields;
    // Number the free components of the active nodes in node order (NO_DOF = none): only the
    // active nodes' pages are written (`node_storage`), the others read NO_DOF.
    fields.dofs.reset();
    let mut count = 0u32;
    let active = fields.active.written().filter(|&(_, &a)| a).map(|(i, _)| i);
    for i in active {
        let constrained = fields.constrained[i];
        fields.dofs[i] = std::array::from_fn(|c| {
            if constrained[c] {
                NO_DOF
            } else {
                count += 1;
                count - 1
            }
        });
    }
    fields.dof_count = count as usize;

    // The supports' nodes, flat: built for the pattern and freed with it (not kept between
    // steps: 9 node indices per 2D point, q = 2, would stay allocated through the solve).
    let (count, entries) = points
        .iter()
        .fold((0, 0), |(n, m), support| (n + 1, m + support.0.len()));
    let groups = fields.couplings.len();
    let grouped: usize = fields.couplings.iter().map(Vec::len).sum();
    let mut offsets = Vec::with_capacity(count + groups + 1);
    let mut flat = Vec::with_capacity(entries + grouped);
    offsets.push(0);
    for support in points.iter() {
        flat.extend(support.0.iter().map(|w| w.node));
        offsets.push(flat.len());
    }
    for group in &fields.couplings {
        flat.extend(group);
        offsets.push(flat.len());
    }
    let supports = offsets.windows(2).map(|w| &flat[w[0]..w[1]]);
    newton
        .matrix
        .rebuild_pattern(fields.dof_count, &fields.dofs, supports);
    // The nodes' positions, for solvers that use the geometry (multigrid's rigid-body modes).
    newton
        .matrix
        .set_node_positions(|node| grid.0.node_position(node));
    newton.residual.clear();
    newton.residual.resize(fields.dof_count, 0.0);
}
