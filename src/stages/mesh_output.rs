//! Output for linear FEM: the deformed mesh as `grid_NNNN.vtu` (in place of the background
//! grid), so the MPM ParaView workflow applies unchanged.
//!
//! The file holds the mesh nodes at their current positions and one `VTK_LINE`, `VTK_QUAD` or
//! `VTK_HEXAHEDRON` per element, with point data `displacement` (x_i - X_i) and
//! `displacement_increment` (the step's Δu_i) and cell data `integration_points` (points per
//! element). The integration points themselves are the points of `particles_NNNN.vtu`.

use bevy_ecs::prelude::*;

use super::output::{OutputPlan, pad};
use crate::components::{ElementPoint, GridNode};
use crate::fem::Mesh;
use crate::output::{Cells, Field, write_vtu};
use crate::resources::{FemMesh, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};

#[allow(clippy::too_many_arguments)]
pub fn write_mesh<const D: usize>(
    step: Res<LoadStep>,
    mesh: Res<FemMesh<D>>,
    fields: Res<GridFields<D>>,
    mut plan: ResMut<OutputPlan>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    nodes: Query<&GridNode<D>>,
    points: Query<&ElementPoint<D>>,
) {
    if !plan.writes(&step) || !plan.grid_files {
        return;
    }
    let _timer = clock.time(Stage::Output);
    let mesh = &mesh.0;
    let mut current = mesh.reference_positions.clone();
    for node in nodes.iter() {
        current[node.index] = node.position;
    }
    let used = mesh.mesh_nodes();
    let positions: Vec<[f64; 3]> = used.iter().map(|&n| pad(&current[n])).collect();
    let displacement: Vec<f64> = used
        .iter()
        .flat_map(|&n| pad(&(current[n] - mesh.reference_positions[n])))
        .collect();
    let increment: Vec<f64> = used
        .iter()
        .flat_map(|&n| pad(&fields.increment[n]))
        .collect();
    let mut per_element = vec![0.0; mesh.element_count()];
    for point in points.iter() {
        per_element[point.element] += 1.0;
    }
    let name = format!("grid_{:04}.vtu", step.number);
    let cells = Cells {
        kind: Mesh::<D>::vtk_kind(),
        connectivity: mesh.vtk_connectivity(),
    };
    let result = write_vtu(
        &plan.dir.join(&name),
        &positions,
        &cells,
        &[
            Field::new("displacement", 3, &displacement),
            Field::new("displacement_increment", 3, &increment),
        ],
        &[Field::scalar("integration_points", &per_element)],
    )
    .and_then(|()| plan.grid.push(step.factor, &name));
    if let Err(e) = result {
        status.fail(SolverError::Output {
            step: step.number,
            why: format!("{name}: {e}"),
        });
    }
}
