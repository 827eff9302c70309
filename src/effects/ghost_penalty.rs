//! Ghost-penalty stabilisation of nearly empty cells (the formulation and kernels: `ghost`).
//! Used when the scene sets `solver(#{ ghost_penalty: γ })` with γ > 0 (MPM bases only).
//!
//! * [`find_ghost_faces`] (`Hook::Connectivity`): cell fill fractions from the points, the faces
//!   next to boundary cells, and their penalty matrices, constant through the load step; each
//!   face couples the nodes of its two cells (`GridFields::couplings`).
//! * [`assemble_ghost_penalty`] (`Hook::AfterAssembly`): f_int += G Δu, K += G (symmetric).
//!   In a distributed run (every process finds the same faces) process 0 alone adds them
//!   (`distributed::adds_grid_terms`): the processes' shares are summed.

use bevy_ecs::prelude::*;

use crate::basis::BasisKind;
use crate::components::{Position, Volume};
use crate::ghost::{FacePenalty, face_penalty, ghost_faces};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{Grid, GridFields, Newton, Stage, StageClock};
use crate::scene::{Kind, OptionSpec, Range, Resolver, SceneApi, SceneSpec, ScriptError};
use crate::solver::NO_DOF;

/// The ghost penalty of the current load step.
#[derive(Resource, Clone, Debug, Default)]
pub struct GhostPenalty {
    /// γ E: the dimensionless penalty times the scene's largest stiffness (Young's modulus).
    pub gamma_modulus: f64,
    /// The penalised faces of this step.
    pub faces: Vec<FacePenalty>,
}

/// The scene's dimensionless penalty factor γ (`solver(#{ ghost_penalty: γ })`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GhostPenaltySpec {
    pub gamma: f64,
}

/// Why the ghost penalty does not apply to linear FEM.
const NOT_WITH_FEM: &str = "ghost_penalty stabilises nearly empty MPM cells; basis \"fem\" has a body-fitted mesh without such cells (remove ghost_penalty)";

/// The module.
#[derive(Clone, Copy, Debug, Default)]
pub struct GhostPenaltyModule;

impl Plugin for GhostPenaltyModule {
    fn name(&self) -> &'static str {
        "ghost penalty"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.extend(
            "solver",
            OptionSpec::new(
                "ghost_penalty",
                Kind::Number(Range::NonNegative),
                "dimensionless ghost-penalty factor γ for nearly empty cells (0 = off, the default; 0.01 is a good start; MPM bases only)",
            ),
        );
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let Some(options) = scene.call_options("solver") else {
            return Ok(());
        };
        let gamma = options.value.number("ghost_penalty").unwrap_or(0.0);
        if gamma > 0.0 && !self.applies_to(scene.spec) {
            return Err(ScriptError::at(
                options.at,
                format!("solver(...): {NOT_WITH_FEM}"),
            ));
        }
        if gamma > 0.0 {
            scene.spec.set_part(GhostPenaltySpec { gamma });
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        spec.part::<GhostPenaltySpec>()
            .map(|g| format!("γ = {}", g.gamma))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<GhostPenaltySpec>().is_some()
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis != BasisKind::Fem
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        if !self.applies_to(spec) && self.used_by(spec) {
            simulation.fail(NOT_WITH_FEM);
            return;
        }
        let gamma = spec.part::<GhostPenaltySpec>().map_or(0.0, |g| g.gamma);
        let modulus = spec
            .materials
            .iter()
            .map(|m| m.stiffness)
            .fold(0.0, f64::max);
        simulation.world().insert_resource(GhostPenalty {
            gamma_modulus: gamma * modulus,
            faces: Vec::new(),
        });
        simulation
            .add_systems(Hook::Connectivity, find_ghost_faces::<D>)
            .add_systems(Hook::AfterAssembly, assemble_ghost_penalty::<D>);
    }
}

pub fn find_ghost_faces<const D: usize>(
    grid: Res<Grid<D>>,
    mut ghost: ResMut<GhostPenalty>,
    mut fields: ResMut<GridFields<D>>,
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
    fields
        .couplings
        .extend(ghost.faces.iter().map(|face| face.nodes.clone()));
}

pub fn assemble_ghost_penalty<const D: usize>(
    ghost: Res<GhostPenalty>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
) {
    let _timer = clock.time(Stage::Assembly);
    if !crate::distributed::adds_grid_terms() {
        return; // process 0 adds them for all (the shares are summed)
    }
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
                        newton.matrix.add(row, col, g);
                    }
                }
            }
        }
    }
}
