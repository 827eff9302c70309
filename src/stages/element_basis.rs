//! Stage 1 for linear FEM: element shape functions at the integration points.
//!
//! At the start of a load step every integration point evaluates its element's shape functions
//! at its fixed parent coordinates ξ_p, with spatial gradients from the CURRENT node positions
//! (`GridNode::position`, which move with the body): `N_a(ξ_p)` and `∇_n N_a = J_n⁻ᵀ ∇_ξ N_a`
//! (`fem::element_weights`). They are kept for the whole step in `Support`, exactly like the
//! MPM basis, so every later stage is unchanged (see `fem` for why this is linear FEM). The
//! element's nodes become active.

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::components::{ElementPoint, GridNode, PointId, Support};
use crate::fem::element_weights;
use crate::resources::{FemMesh, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};

/// Scratch memory: the current node positions by node index, and one element's corners.
#[derive(Default)]
pub struct ElementScratch<const D: usize> {
    positions: Vec<SVector<f64, D>>,
    corners: Vec<SVector<f64, D>>,
}

#[allow(clippy::too_many_arguments)]
pub fn evaluate_element_basis<const D: usize>(
    mesh: Res<FemMesh<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<ElementScratch<D>>,
    nodes: Query<&GridNode<D>>,
    mut points: Query<(&PointId, &ElementPoint<D>, &mut Support<D>)>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let ElementScratch { positions, corners } = &mut *scratch;
    positions.resize(fields.active.len(), SVector::zeros());
    for node in nodes.iter() {
        positions[node.index] = node.position;
    }
    for (id, point, mut support) in points.iter_mut() {
        let element_nodes = mesh.0.element_nodes(point.element);
        corners.clear();
        corners.extend(element_nodes.iter().map(|&n| positions[n]));
        if let Err(degenerate) = element_weights(element_nodes, corners, &point.xi, &mut support.0)
        {
            status.fail(SolverError::BadPointState {
                point: id.0,
                step: step.number,
                iteration: 0,
                why: format!("element {}: {degenerate}", point.element),
            });
            return;
        }
        for &node in element_nodes {
            fields.active[node] = true;
        }
    }
}
