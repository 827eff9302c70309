//! Ghost-penalty stabilisation of nearly empty cells (see `ghost` for the formulation).
//! Scheduled only when the scene sets `solver(#{ ghost_penalty: γ })` with γ > 0.
//!
//! * [`find_ghost_faces`] (connectivity stage): cell fill fractions from the points, the faces
//!   next to boundary cells, and their penalty matrices, constant through the load step.
//! * [`assemble_ghost_penalty`] (assembly stage, after the points): f_int += G Δu, K += G.

use bevy_ecs::prelude::*;

use crate::components::{Position, Volume};
use crate::ghost::{FacePenalty, face_penalty, ghost_faces};
use crate::resources::{Grid, GridFields, Newton, Stage, StageClock};
use crate::sparse::NO_DOF;

/// The ghost penalty of the current load step.
#[derive(Resource, Clone, Debug, Default)]
pub struct GhostPenalty {
    /// γ E: the dimensionless penalty times the scene's largest Young's modulus.
    pub gamma_modulus: f64,
    /// The penalised faces of this step.
    pub faces: Vec<FacePenalty>,
}

pub fn find_ghost_faces<const D: usize>(
    grid: Res<Grid<D>>,
    mut ghost: ResMut<GhostPenalty>,
    mut clock: ResMut<StageClock>,
    mut filled: Local<Vec<f64>>,
    points: Query<(&Position<D>, &Volume)>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let basis = &grid.0;
    let cell_volume: f64 = basis.axes.iter().map(|a| a.spacing()).product();
    filled.clear();
    filled.resize(basis.num_cells(), 0.0);
    for (x, v) in points.iter() {
        if let Ok(cell) = basis.cell_of(&x.0) {
            filled[basis.cell_index(cell)] += v.0 / cell_volume;
        }
    }
    let gamma_modulus = ghost.gamma_modulus;
    ghost.faces = ghost_faces(basis, &filled)
        .iter()
        .map(|face| face_penalty(basis, face, gamma_modulus))
        .collect();
}

pub fn assemble_ghost_penalty<const D: usize>(
    ghost: Res<GhostPenalty>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
) {
    let _timer = clock.time(Stage::Assembly);
    let fields = &mut *fields;
    for face in &ghost.faces {
        let n = face.nodes.len();
        for (r, &row_node) in face.nodes.iter().enumerate() {
            for (c, &col_node) in face.nodes.iter().enumerate() {
                let g = face.matrix[r * n + c];
                for k in 0..D {
                    fields.internal_force[row_node][k] += g * fields.increment[col_node][k];
                    let (row, col) = (fields.dofs[row_node][k], fields.dofs[col_node][k]);
                    if row != NO_DOF && col != NO_DOF {
                        newton.system.add(row, col, g);
                    }
                }
            }
        }
    }
}
