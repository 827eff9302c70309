//! Ghost-penalty stabilisation of nearly empty cells (the formulation and kernels: `ghost`).
//! Used when the scene sets `solver(#{ ghost_penalty: γ })` with γ > 0 (MPM bases only).
//!
//! * [`measure_cell_fill`] (at the step start, before the basis): each cell's fill fraction
//!   `φ_c = Σ_{p in c} V_p / |c|` from the points' positions and volumes, and which cells hold
//!   points of this process. With decomposed points (`--decompose`) the fractions are summed
//!   over the processes (`distributed::sum_over_points`, collective: it runs where every
//!   process runs alike, after the points' exchange and before the basis, which can fail on
//!   one process alone). All points of a cell are on one process (the process of the cell's
//!   layer along the slab axis: `distributed::layer_of` is the cell's index inside the grid),
//!   so the others add exact zeros: every process gets the serial run's fractions, bit for bit.
//! * [`find_ghost_faces`] (`Hook::Connectivity`): the faces next to boundary cells and their
//!   penalty matrices, constant through the load step; each face couples the nodes of its two
//!   cells (`GridFields::couplings`), which it makes active.
//! * [`assemble_ghost_penalty`] (`Hook::AfterAssembly`): f_int += G Δu, K += G (symmetric).
//!
//! **Which process adds a face.** Serial: all. Replicated (every process holds every point):
//! every process finds every face (its pattern holds them) and process 0 alone adds them
//! (`distributed::adds_grid_terms`); the processes' shares are summed. Decomposed: a face is
//! found and added by the process holding the points of its lower cell, once over the
//! processes. Its stencil is `q + 2` node layers along its normal (the nodes of both cells),
//! one more than that process's points touch when the face lies on a slab boundary (normal to
//! the slab axis, its upper cell on the next process): the face's nodes are made active, so
//! that process's local nodes (`effects::distributed::grid`: its points' supports and the
//! nodes made active on it) take in that layer, and its rows of `G` are assembled with the decomposed
//! grid's numbering like any other local rows (the ghost rows go to their owners; `G Δu` is
//! summed at the shared nodes with `f_int`). In a serial run the nodes of two occupied cells
//! are active already (the points' supports cover their cells' nodes): nothing changes.

use bevy_ecs::prelude::*;

use crate::basis::BasisKind;
use crate::components::{Position, Volume};
use crate::ghost::{FacePenalty, face_penalty, ghost_faces};
use crate::method::{StepSchedule, StepSystems};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{Grid, GridFields, Newton, Stage, StageClock};
use crate::scene::{Kind, OptionSpec, Range, Resolver, SceneApi, SceneSpec, ScriptError};
use crate::solver::NO_DOF;

/// The ghost penalty of the current load step.
#[derive(Resource, Clone, Debug, Default)]
pub struct GhostPenalty {
    /// γ E: the dimensionless penalty times the scene's largest stiffness (Young's modulus).
    pub gamma_modulus: f64,
    /// Each cell's fill fraction in this step, over every process's points.
    pub filled: Vec<f64>,
    /// Whether this process holds points in each cell in this step.
    pub held: Vec<bool>,
    /// The penalised faces of this step that this process finds (module docs).
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
            ..GhostPenalty::default()
        });
        // before the basis, where every process runs alike (module docs); with decomposed
        // points after their exchange (`effects::distributed` orders it)
        let mut schedules = simulation.world().resource_mut::<Schedules>();
        schedules.entry(StepSchedule).add_systems(
            measure_cell_fill::<D>
                .in_set(StepSystems::Connectivity)
                .before(Hook::Basis),
        );
        simulation
            .add_systems(Hook::Connectivity, find_ghost_faces::<D>)
            .add_systems(Hook::AfterAssembly, assemble_ghost_penalty::<D>);
    }
}

/// The cells' fill fractions and which hold this process's points (module docs; collective
/// with decomposed points).
pub fn measure_cell_fill<const D: usize>(
    grid: Res<Grid<D>>,
    mut ghost: ResMut<GhostPenalty>,
    mut clock: ResMut<StageClock>,
    points: Query<(&Position<D>, &Volume)>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let basis = &grid.0;
    let cell_volume: f64 = basis.axes.iter().map(|a| a.spacing()).product();
    let ghost = &mut *ghost;
    ghost.filled.clear();
    ghost.filled.resize(basis.num_cells(), 0.0);
    for (x, v) in points.iter() {
        if let Ok(cell) = basis.cell_of(&x.0) {
            ghost.filled[basis.cell_index(cell)] += v.0 / cell_volume;
        }
    }
    ghost.held.clear();
    ghost.held.extend(ghost.filled.iter().map(|&f| f > 0.0));
    crate::distributed::sum_over_points(&mut ghost.filled);
}

/// The faces of this step this process finds (module docs), their penalties, their coupling
/// groups, and their nodes made active.
pub fn find_ghost_faces<const D: usize>(
    grid: Res<Grid<D>>,
    mut ghost: ResMut<GhostPenalty>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let basis = &grid.0;
    let ghost = &mut *ghost;
    let gamma_modulus = ghost.gamma_modulus;
    ghost.faces = ghost_faces(basis, &ghost.filled)
        .iter()
        .filter(|face| ghost.held[basis.cell_index(face.lower_cell)])
        .map(|face| face_penalty(basis, face, gamma_modulus))
        .collect();
    for face in &ghost.faces {
        for &node in &face.nodes {
            fields.active[node] = true;
        }
    }
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
    if !crate::distributed::decomposed() && !crate::distributed::adds_grid_terms() {
        return; // replicated: process 0 adds them for all (the shares are summed)
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
