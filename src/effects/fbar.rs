//! F-bar for MPM: the volume change of every point replaced by the average over the points of
//! its background cell, against volumetric locking (Coombs, Charlton, Cortis & Augarde 2018,
//! "Overcoming volumetric locking in material point methods", CMAME 333; after de Souza Neto,
//! Perić, Dutko & Owen 1996). Used for the bodies whose `body(..)` call sets `fbar: true`.
//!
//! # Averaging
//! At the start of a load step every F-bar point is assigned the background cell that holds
//! its position `x_p^n`; the F-bar points of one body in one cell form a group `c`. In every
//! Newton iterate, with `Δf_p = I + Σ_i Δu_i ⊗ ∇_n N_i(x_p)` the point's own increment of
//! deformation and `Δj_p = det Δf_p`,
//!
//! ```text
//!   Δj̄_c = Σ_{q∈c} V_q^n Δj_q / Σ_{q∈c} V_q^n,        Δf̄_p = (Δj̄_c / Δj_p)^{1/D} Δf_p,
//! ```
//!
//! weighted by the points' volumes at the step start `V_q^n` (the configuration the grid is
//! reset to), so `Σ_q V_q^n Δj̄_c` is the volume the group's points occupy at the end of the
//! increment. The material is evaluated at `F̄_p = Δf̄_p F̄_p^n` (the point's
//! `components::ModifiedIncrement`): its volume change is the group's, its isochoric part the
//! point's own.
//! The point's stored `F`, `J` and volume `V = J V0` are the F-bar ones (`F̄`, `J̄ = det F̄`);
//! its position follows the displacement field. In plane strain (`D = 2`) only the in-plane
//! block is modified, with the exponent 1/2: the out-of-plane stretch stays 1; in 1D `Δf̄ = Δj̄`.
//! A uniform deformation of a group (every `Δj_q` equal) gives `Δf̄ = Δf`: the standard answer.
//!
//! # Internal force and consistent tangent
//! The internal force keeps the form of `mechanics`, `f_int,i = Σ_p V0_p τ̄_p g_i` with `τ̄_p`
//! the Kirchhoff stress at `F̄_p` and `g_i = Δf_p⁻ᵀ ∇_n N_i` the gradient in the current
//! configuration of the displacement field (the Cauchy stress `τ̄/J̄` integrated over the
//! volume `J̄ V0`). Differentiating with respect to `Δu_jk`, with `s_p = (Δj̄/Δj_p)^{1/D}`,
//! `∂Δf̄ Δf̄⁻¹ = e_k ⊗ g_j + (∂s/s) I` and `∂ ln Δj = (g_j)_k`,
//! `∂ ln Δj̄ = (ḡ_j)_k` where
//!
//! ```text
//!   ḡ_j = Σ_{q∈c} α_q g_j^q,    α_q = V_q^n Δj_q / Σ_{r∈c} V_r^n Δj_r     (g_j^q = 0 off q's support)
//! ```
//!
//! the tangent is the standard block of `mechanics` (taken at `b̄`, `τ̄`, `c̄` and the point's own
//! `g`) plus a rank-one term that couples the point's support nodes `i` with every node `j` of
//! the group's supports:
//!
//! ```text
//!   K_ij += V0_p (P_p g_i) ⊗ (ḡ_j − g_j^p),     P_p,ab = (1/D) Σ_{m,d} c̄_abmd b̄_md,
//! ```
//!
//! from `∂τ̄_ab = ½ c̄_abmd ∂b̄_md` and `∂b̄ = 2 (∂s/s) b̄ + (e_k ⊗ b̄ g_j + b̄ g_j ⊗ e_k)`. It is
//! not symmetric: a scene with an F-bar body declares its tangent non-symmetric (LU).
//! Checked against finite differences of the assembled internal force (`tests/fbar.rs`).
//!
//! # Systems and seams
//! * [`group_points_by_cell`] (`Hook::Connectivity`): the groups of the step and, for each group
//!   of more than one point, the union of its points' supports as a coupling group
//!   (`GridFields::couplings`: the sparsity pattern then holds every pair of its nodes);
//! * [`average_volume_change`] (`Hook::Kinematics`): `Δj̄` and every point's `Δf̄`;
//! * [`assemble_fbar_tangent`] (`Hook::AfterAssembly`): the rank-one terms above, summed per
//!   group in a dense buffer and scattered once.

use bevy_ecs::prelude::*;
use nalgebra::{SMatrix, SVector};

use crate::basis::BasisKind;
use crate::components::{
    BodyIndex, ModifiedIncrement, PointId, Position, ReferenceVolume, Support, Trial, Volume,
};
use crate::mechanics::{embed, increment_gradient};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    Grid, GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock,
};
use crate::scene::{Kind, LockingTreated, OptionSpec, Resolver, SceneApi, SceneSpec, ScriptError};

/// The bodies (indices into `SceneSpec::bodies`) with `fbar: true`.
#[derive(Clone, Debug, PartialEq)]
pub struct FbarSpec {
    pub bodies: Vec<usize>,
}

/// Marks the points of F-bar bodies.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct FbarPoint;

/// The F-bar points of one body in one background cell.
#[derive(Clone, Debug, Default)]
pub struct FbarGroup {
    pub points: Vec<Entity>,
    /// The union of the points' support nodes, sorted.
    pub nodes: Vec<usize>,
    /// For each point, the position in `nodes` of each of its support entries.
    pub local: Vec<Vec<usize>>,
    /// `α_q = V_q^n Δj_q / Σ_r V_r^n Δj_r` of the current iterate, per point.
    pub weights: Vec<f64>,
}

/// The groups of the current load step.
#[derive(Resource, Clone, Debug, Default)]
pub struct FbarCells {
    pub groups: Vec<FbarGroup>,
}

/// Why F-bar does not apply to linear FEM.
const NOT_WITH_FEM: &str = "fbar averages the volume change over the points of a background cell of MPM; basis \"fem\" has no such cells (remove fbar)";

/// The module.
#[derive(Clone, Copy, Debug, Default)]
pub struct FbarModule;

impl Plugin for FbarModule {
    fn name(&self) -> &'static str {
        "F-bar"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.extend(
            "body",
            OptionSpec::new(
                "fbar",
                Kind::Flag,
                "F-bar against volumetric locking (Coombs et al. 2018): each point's volume change is the volume-weighted average over the body's points in its background cell (default false; MPM bases only; makes the tangent non-symmetric)",
            ),
        );
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let mut bodies = Vec::new();
        for options in scene.every_call_options("body") {
            if options.value.flag("fbar") != Some(true) {
                continue;
            }
            if scene.spec.grid.basis == BasisKind::Fem {
                return Err(ScriptError::at(
                    options.at,
                    format!("body(...): {NOT_WITH_FEM}"),
                ));
            }
            let name = options.value.text("name").unwrap_or_default();
            if let Some(index) = scene.spec.bodies.iter().position(|b| b.name == name) {
                bodies.push(index);
            }
        }
        if !bodies.is_empty() {
            scene.spec.set_part(LockingTreated(bodies.clone()));
            scene.spec.set_part(FbarSpec { bodies });
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let spec_bodies = &spec.bodies;
        spec.part::<FbarSpec>().map(|f| {
            let names: Vec<&str> = f
                .bodies
                .iter()
                .map(|&b| spec_bodies[b].name.as_str())
                .collect();
            format!("bodies {}", names.join(", "))
        })
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<FbarSpec>().is_some()
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis != BasisKind::Fem
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        if !self.applies_to(spec) {
            simulation.fail(NOT_WITH_FEM);
            return;
        }
        let bodies = spec.part::<FbarSpec>().map_or(Vec::new(), |f| {
            f.bodies.iter().map(|&b| b as u32).collect::<Vec<_>>()
        });
        simulation.nonsymmetric_tangent();
        let world = simulation.world();
        let points: Vec<Entity> = world
            .query::<(Entity, &BodyIndex)>()
            .iter(world)
            .filter(|(_, body)| bodies.contains(&body.0))
            .map(|(entity, _)| entity)
            .collect();
        world.insert_batch(points.into_iter().map(|entity| {
            (
                entity,
                (FbarPoint, ModifiedIncrement::<D>(SMatrix::identity())),
            )
        }));
        world.insert_resource(FbarCells::default());
        simulation
            .add_systems(Hook::Connectivity, group_points_by_cell::<D>)
            .add_systems(Hook::Kinematics, average_volume_change::<D>)
            .add_systems(Hook::AfterAssembly, assemble_fbar_tangent::<D>);
    }
}

/// The groups of the step (points of one body in one cell) and their coupling groups.
#[allow(clippy::type_complexity)]
pub fn group_points_by_cell<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut cells: ResMut<FbarCells>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    points: Query<(Entity, &PointId, &BodyIndex, &Position<D>, &Support<D>), With<FbarPoint>>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let mut keyed = Vec::with_capacity(points.iter().len());
    for (entity, id, body, x, _) in points.iter() {
        match grid.0.cell_of(&x.0) {
            Ok(cell) => keyed.push((body.0, grid.0.cell_index(cell), id.0, entity)),
            Err(_) => {
                status.fail(SolverError::BadPointState {
                    point: id.0,
                    step: step.number,
                    iteration: 0,
                    why: "F-bar: the point is outside the grid".to_string(),
                });
                return;
            }
        }
    }
    keyed.sort_unstable_by_key(|&(body, cell, id, _)| (body, cell, id));
    cells.groups.clear();
    for run in keyed.chunk_by(|a, b| (a.0, a.1) == (b.0, b.1)) {
        let mut group = FbarGroup::default();
        for &(_, _, _, entity) in run {
            group.points.push(entity);
            if let Ok((.., support)) = points.get(entity) {
                group.nodes.extend(support.0.iter().map(|w| w.node));
            }
        }
        group.nodes.sort_unstable();
        group.nodes.dedup();
        for &entity in &group.points {
            let local = points.get(entity).map_or(Vec::new(), |(.., support)| {
                support
                    .0
                    .iter()
                    .map(|w| group.nodes.binary_search(&w.node).unwrap_or(0))
                    .collect()
            });
            group.local.push(local);
        }
        group.weights = vec![0.0; group.points.len()];
        if group.points.len() > 1 {
            fields.couplings.push(group.nodes.clone());
        }
        cells.groups.push(group);
    }
}

/// `Δj̄` of every group and `Δf̄` of its points for the current increments (module docs).
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn average_volume_change<const D: usize>(
    fields: Res<GridFields<D>>,
    step: Res<LoadStep>,
    newton: Res<Newton>,
    mut cells: ResMut<FbarCells>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut increments: Local<Vec<(SMatrix<f64, D, D>, f64, f64)>>,
    mut points: Query<(&PointId, &Support<D>, &Volume, &mut ModifiedIncrement<D>)>,
) {
    let _timer = clock.time(Stage::StressUpdate);
    for group in cells.groups.iter_mut() {
        increments.clear();
        for &entity in &group.points {
            let Ok((id, support, volume, _)) = points.get(entity) else {
                continue;
            };
            let df = increment_gradient(&support.0, |node| fields.increment[node]);
            let dj = embed(&df).determinant();
            if !(dj.is_finite() && dj > 0.0) {
                status.fail(SolverError::BadPointState {
                    point: id.0,
                    step: step.number,
                    iteration: newton.iterations,
                    why: format!("F-bar: non-positive or non-finite det Δf = {dj:e}"),
                });
                return;
            }
            increments.push((df, dj, volume.0));
        }
        let volume: f64 = increments.iter().map(|(_, _, v)| v).sum();
        let changed: f64 = increments.iter().map(|(_, dj, v)| v * dj).sum();
        let average = changed / volume;
        for ((&entity, weight), (df, dj, v)) in group
            .points
            .iter()
            .zip(group.weights.iter_mut())
            .zip(increments.iter())
        {
            *weight = v * dj / changed;
            if let Ok((.., mut seen)) = points.get_mut(entity) {
                seen.0 = df * (average / dj).powf(1.0 / D as f64);
            }
        }
    }
}

/// Scratch memory of [`assemble_fbar_tangent`], kept between iterations.
#[derive(Default)]
pub struct FbarScratch<const D: usize> {
    /// `ḡ_j` per node of the group.
    averaged: Vec<SVector<f64, D>>,
    /// The point's `g_i` per support entry.
    gradients: Vec<SVector<f64, D>>,
    /// The group's blocks, `nodes × nodes`, row-major.
    blocks: Vec<SMatrix<f64, D, D>>,
}

/// Adds the F-bar terms `V0 (P g_i) ⊗ (ḡ_j − g_j)` of every group to the tangent.
pub fn assemble_fbar_tangent<const D: usize>(
    cells: Res<FbarCells>,
    fields: Res<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<FbarScratch<D>>,
    points: Query<(&Support<D>, &Trial<D>, &ReferenceVolume)>,
) {
    let _timer = clock.time(Stage::Assembly);
    let scratch = &mut *scratch;
    for group in cells.groups.iter().filter(|g| g.points.len() > 1) {
        let n = group.nodes.len();
        scratch.averaged.clear();
        scratch.averaged.resize(n, SVector::zeros());
        for ((&entity, local), alpha) in group.points.iter().zip(&group.local).zip(&group.weights) {
            let Ok((support, trial, _)) = points.get(entity) else {
                continue;
            };
            for (w, &l) in support.0.iter().zip(local) {
                scratch.averaged[l] += trial.0.spatial_gradient(&w.gradient) * *alpha;
            }
        }
        scratch.blocks.clear();
        scratch.blocks.resize(n * n, SMatrix::zeros());
        for (&entity, local) in group.points.iter().zip(&group.local) {
            let Ok((support, trial, v0)) = points.get(entity) else {
                continue;
            };
            let state = &trial.0;
            let projection = volumetric_projection(state);
            scratch.gradients.clear();
            scratch.gradients.extend(
                support
                    .0
                    .iter()
                    .map(|w| state.spatial_gradient(&w.gradient)),
            );
            for (g_i, &row) in scratch.gradients.iter().zip(local) {
                let v_i = projection * g_i * v0.0;
                let blocks = &mut scratch.blocks[row * n..(row + 1) * n];
                for (block, g_bar) in blocks.iter_mut().zip(&scratch.averaged) {
                    *block += v_i * g_bar.transpose();
                }
                for (g_j, &col) in scratch.gradients.iter().zip(local) {
                    blocks[col] -= v_i * g_j.transpose();
                }
            }
        }
        for (i, &node_i) in group.nodes.iter().enumerate() {
            for (j, &node_j) in group.nodes.iter().enumerate() {
                newton.matrix.add_block(
                    &fields.dofs[node_i],
                    &fields.dofs[node_j],
                    &scratch.blocks[i * n + j],
                );
            }
        }
    }
}

/// `P_ab = (1/D) Σ_{m,d} c_abmd b_md`: the response of τ to a volumetric scaling of the
/// increment (`∂τ = P ∂ ln Δj̄` at fixed isochoric part).
fn volumetric_projection<const D: usize>(
    state: &crate::mechanics::TrialState<D>,
) -> SMatrix<f64, D, D> {
    let (c, b) = (&state.tangent, &state.left_cauchy_green);
    SMatrix::from_fn(|a, bb| {
        let mut sum = 0.0;
        for m in 0..D {
            for d in 0..D {
                sum += c[a][bb][m][d] * b[(m, d)];
            }
        }
        sum / D as f64
    })
}
