//! F-bar for MPM: the volume change of every point replaced by the average over the points of
//! its background cell (or of the cells around it, or its projection onto the grid's tent
//! functions), against volumetric locking (Coombs, Charlton, Cortis & Augarde 2018,
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
//! # Patch averaging (`fbar: "patch"`)
//! `fbar: true` (or `"cell"`) averages over the points of the point's own cell, as Coombs et
//! al. do for linear and GIMP bases. A B-spline of order `q` spreads a point's support over
//! `(q + 1)^D` cells, so with `fbar: "patch"` the average `Δj̄_c` of the points of cell `c` is
//! taken over the body's points in the patch of `3^D` cells around `c` (`c` and its
//! neighbours: `(q + 1)^D` for `q = 2`), a wider, overlapping average: the points of `c` (the
//! group's *members*) get the patch's `Δj̄`, the patch's points (its *sources*) enter the
//! average. Everything below holds with the sums over the sources and the rank-one terms
//! added for the members only. A uniform deformation still gives the standard answer.
//!
//! # Linear FEM (`basis: "fem"`)
//! On the body-fitted mesh a group is an element: its Gauss points stay in it however the mesh
//! moves (`effects::fem_mesh::ElementPoint`), and the volume-weighted average of `Δj` over them
//! is the element's volume change (`det J` is multilinear in `ξ`, so the Gauss rule of the
//! scene's `ppc ≥ 2` integrates it exactly). This is the F-bar element of de Souza Neto et al.
//! 1996 with the element average in place of the centroid value; only `fbar: true` applies.
//!
//! # Nodal projection (`fbar: "nodal"`)
//! With `fbar: "nodal"` the volume change is projected onto a continuous space instead of
//! being averaged over a cell: the linear tent functions `N̂_a` of the background grid's
//! vertices `a` (the `q − 1` space of quadratic B-splines, the B-bar/F-bar projection of
//! Elguedj, Bazilevs, Calo & Hughes 2008; for linear MPM a smoother space than the
//! cell-constant one, Bonet & Burton's nodal averaging). A lumped-mass L2 projection, with the
//! positions and volumes at the step start:
//!
//! ```text
//!   c_a = Σ_q N̂_a(x_q^n) V_q^n Δj_q / m_a,   m_a = Σ_q N̂_a(x_q^n) V_q^n,
//!   Δj̄_p = Σ_a N̂_a(x_p^n) c_a,               Δf̄_p = (Δj̄_p / Δj_p)^{1/D} Δf_p.
//! ```
//!
//! The vertices whose tents reach a point of cell `c` are `c`'s `2^D` corners, and the points
//! those tents reach lie in the `3^D` cells around `c`, so the group of cell `c` has the
//! patch's sources and each member its own `Δj̄_p`; its derivative keeps the rank-one form
//! below with per-member weights:
//!
//! ```text
//!   ∂ ln Δj̄_p = Σ_q α_q^p g^q,    α_q^p = Σ_a N̂_a(x_p) N̂_a(x_q) V_q^n Δj_q / (m_a Δj̄_p).
//! ```
//!
//! A uniform volume change gives `c_a = Δj` and, the tents summing to one in every cell,
//! `Δj̄_p = Δj`: the standard answer. The projection is [`project_volume_change`], a pure
//! kernel on one group.
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
//! (`α_q^p` of the member `p` for the nodal projection, so `ḡ_j` is then the member's own)
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
//! # The mixed form (`fbar: "mixed"`)
//! The internal force above tests each point's own Kirchhoff stress with its own gradients. It
//! is the derivative of the stored energy `Σ_p V0_p W(F̄_p)` only when the pressure
//! `p_p = (1/D) Σ_{a<D} τ̄_p,aa` is the same at every point of the group (a hyperelastic or a
//! von Mises point, whose pressure is a function of `J̄` alone). A dilatant plastic return
//! (Mohr–Coulomb or Drucker–Prager with `ψ > 0`) changes each point's pressure by its own
//! plastic volume change, so the pressures of a group differ, and then the system is not the
//! stationarity of any potential: its tangent is not symmetric even for associated flow, and
//! Newton loses the convex structure of the associated incremental problem
//! (docs/plasticity.md, "Benchmark 4"). `fbar: "mixed"` (cell groups and FEM elements) uses the
//! derivative of the stored energy instead, `δ ln Δf̄ = sym ∇δu + (1/D)(δ ln Δj̄ − δ ln Δj) I`:
//!
//! ```text
//!   f_int,i = Σ_p V0_p (τ̄_p g_i^p + p_p (ḡ_i − g_i^p)) = Σ_p V0_p (τ̄_p − p_p I) g_i^p + Π ḡ_i,
//!   Π = Σ_p V0_p p_p,
//! ```
//!
//! the deviatoric stress of each point and the group's total pressure tested with the averaged
//! gradient: the weak form of the mixed element with a constant volume change and a constant
//! pressure per group (Q1/P0; Simo, Taylor & Pister 1985), of which F-bar is the displacement
//! form. Its tangent adds to the blocks above, with `∂p_p = Q_p b̄_p g_j + (tr P_p / D)(ḡ_j −
//! g_j)`, `Q_kd = (1/D) Σ_a c̄_aakd`, `∂g_i = −g_j (g_i)_k` and
//! `∂ḡ_i = Σ_q α_q (g_i^q ⊗ g_j^q − g_j^q ⊗ g_i^q) − ḡ_i ⊗ ḡ_j`:
//!
//! ```text
//!   K_ij += Σ_p V0_p ((ḡ_i − g_i^p) ⊗ ∂p_p + p_p g_j^p ⊗ g_i^p)
//!         + Π (Σ_q α_q (g_i^q ⊗ g_j^q − g_j^q ⊗ g_i^q) − ḡ_i ⊗ ḡ_j).
//! ```
//!
//! When the group's pressures are equal and `V0_p ∝ α_p` (a uniform deformation) the added
//! force is zero and the two forms agree.
//!
//! # Sparse cells
//! A group whose members hold less than half their cell's volume at the step start
//! (`Σ_{q∈c} V_q^n < h^D / 2`) is *sparse*: its cell is less than half full of points (the
//! points crossed a cell face, or the surface moved through the cell), so its average is taken
//! over one or two points, and the constraint it puts on them differs from the full cells'.
//! On the Tresca strip footing (docs/plasticity.md, "F-bar") such groups appear under the
//! footing once its settlement passes a quarter of a cell (the lower points of the top row
//! under it cross into the next row); at 8 cells across B the pressure's rise in that step is
//! 16 times the step before's, and merging each sparse group into its fullest
//! face-neighbour's (tried, not kept) moved the end of the curve by −20 % to +1.4 % at 8 to 16
//! cells: past that step the curve depends on this averaging, not only on the soil. The count
//! is the measure `fbar_sparse_cells` (history.csv, summary.json) of every F-bar scene, and
//! the first step in which it exceeds the first step's count gives the run a warning. With
//! decomposed points (`mpirun --decompose`) it is counted over every process, each cell once
//! by the volume of its points on all of them ([`count_sparse_cells`]).
//!
//! # Systems and seams
//! * [`group_points_by_cell`] (`Hook::Connectivity`): the groups of the step and, for each group
//!   of more than one source, the union of its sources' supports as a coupling group
//!   (`GridFields::couplings`: the sparsity pattern then holds every pair of its nodes);
//! * [`average_volume_change`] (`Hook::Kinematics`): `Δj̄` and every point's `Δf̄`;
//! * [`assemble_fbar_tangent`] (`Hook::AfterAssembly`): the rank-one terms above (and the mixed
//!   form's force and blocks), summed per group in a dense buffer and scattered once. In a distributed run a process adds the terms
//!   of the members it assembles only (not those marked `AssembledElsewhere`): the processes'
//!   shares of `K` are summed.

use std::collections::HashMap;

use bevy_ecs::prelude::*;
use nalgebra::{SMatrix, SVector};

use crate::basis::BasisKind;
use crate::components::{
    AssembledElsewhere, BodyIndex, ModifiedIncrement, PointId, Position, ReferenceVolume, Support,
    Trial, Volume,
};
use crate::effects::fem_mesh::ElementPoint;
use crate::mechanics::{TrialState, embed, increment_gradient};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    Grid, GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock, Warnings,
};
use crate::scene::{
    Kind, LockingTreated, ModuleWarnings, OptionSpec, Resolver, SceneApi, SceneSpec, ScriptError,
};

/// Over which points an F-bar body averages the volume change of a cell's points.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FbarAveraging {
    /// The body's points in the cell (`fbar: true` or `"cell"`).
    #[default]
    Cell,
    /// The body's points in the `3^D` cells around the cell (`fbar: "patch"`).
    Patch,
    /// The lumped L2 projection onto the grid's linear tent functions (`fbar: "nodal"`).
    Nodal,
    /// The body's points in the cell, with the group's mean pressure in the internal force
    /// (`fbar: "mixed"`; module docs, "The mixed form").
    Mixed,
}

impl FbarAveraging {
    /// Whether the group is the cell's own points (`true`, `"cell"`, `"mixed"`).
    pub fn over_the_cell(self) -> bool {
        matches!(self, Self::Cell | Self::Mixed)
    }
}

/// The bodies (indices into `SceneSpec::bodies`) with F-bar, and how each averages.
#[derive(Clone, Debug, PartialEq)]
pub struct FbarSpec {
    pub bodies: Vec<(usize, FbarAveraging)>,
}

/// Marks the points of F-bar bodies, with their body's averaging.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct FbarPoint(pub FbarAveraging);

/// The F-bar points of one body in one background cell (the members) and the points their
/// volume change is averaged over (the sources: the members first, then, for a patch, the
/// body's points in the neighbouring cells).
#[derive(Clone, Debug, Default)]
pub struct FbarGroup {
    /// Indices into [`FbarCells::points`]; the first `members` are the cell's own points.
    pub sources: Vec<usize>,
    pub members: usize,
    /// The union of the sources' support nodes, sorted.
    pub nodes: Vec<usize>,
    /// For each source, the position in `nodes` of each of its support entries.
    pub local: Vec<Vec<usize>>,
    /// `α_q = V_q^n Δj_q / Σ_r V_r^n Δj_r` of the current iterate, per source; for a nodal
    /// group `α_q^p` per member `p` (row) and source `q` (column), row-major.
    pub weights: Vec<f64>,
    /// Nodal groups only: `N̂_a(x_q^n)` of the cell's `2^D` vertices `a` (vertex `a` is the
    /// cell's lower corner plus `e_k` along every axis `k` with bit `k` of `a` set), per source,
    /// row-major; empty for cell and patch groups.
    pub tents: Vec<f64>,
    /// Whether the internal force has the group's mean pressure (`fbar: "mixed"`).
    pub mixed: bool,
}

/// The F-bar points and groups of the current load step.
#[derive(Resource, Clone, Debug, Default)]
pub struct FbarCells {
    /// Every F-bar point, ordered by body, cell and point id.
    pub points: Vec<Entity>,
    pub groups: Vec<FbarGroup>,
    /// The group and the member index of each point that is a member of a group.
    pub membership: HashMap<Entity, (usize, usize)>,
    /// The volume at the step start of this process's F-bar points in each (body, cell) it
    /// holds some of, ordered by body and cell (with decomposed points, another process may
    /// hold more of a cell's points: [`count_sparse_cells`]).
    pub fills: Vec<((u32, usize), f64)>,
    /// The groups whose members hold less than [`SPARSE_CELL_FRACTION`] of their cell's
    /// volume at the step start (module docs, "Sparse cells"), over every process: the
    /// measure of the last recorded step.
    pub sparse: usize,
    /// `sparse` of the run's first step (of the resumed step after `--resume`).
    pub sparse_at_start: Option<usize>,
    /// Whether the run was warned that sparse groups appeared.
    pub warned: bool,
}

/// A group whose members hold less than this fraction of their cell's volume at the step
/// start is sparse (module docs).
pub const SPARSE_CELL_FRACTION: f64 = 0.5;

/// Why only the cell average applies to linear FEM.
const ONLY_CELL_WITH_FEM: &str = "with basis \"fem\" F-bar averages over the Gauss points of each element (fbar: true); the \"patch\" and \"nodal\" averages read the background grid's neighbouring cells, which a body-fitted mesh does not have";

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
                Kind::Value {
                    what: "true | false | \"cell\" | \"mixed\" | \"patch\" | \"nodal\"",
                },
                "F-bar against volumetric locking (Coombs et al. 2018): each point's volume change is the volume-weighted average over the body's points in its background cell (`true` or \"cell\"), or in the 3^D cells around it (\"patch\", for B-splines of order 2; experimental: Newton does not converge on the plastic strip footing, docs/plasticity.md), or over the cell with the cell's mean pressure in the internal force (\"mixed\": the weak form of the constant-pressure mixed element; for dilatant plastic flow, where the points' pressures differ, docs/plasticity.md Benchmark 4), or projected onto the grid's linear tent functions (\"nodal\": a lumped L2 projection from the points of the 3^D cells around, for B-splines of order 2 the B-bar of the q − 1 space; experimental: on the plastic strip footing no better than \"cell\", docs/plasticity.md); default false; with basis \"fem\" only true or \"mixed\" (the average over each element's Gauss points); makes the tangent non-symmetric",
            ),
        );
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let mut bodies = Vec::new();
        for options in scene.every_call_options("body") {
            let averaging = match options.value.value("fbar") {
                None => continue,
                Some(value) => match fbar_averaging(value) {
                    Ok(Some(averaging)) => averaging,
                    Ok(None) => continue,
                    Err(why) => {
                        return Err(ScriptError::at(options.at, format!("body(...): {why}")));
                    }
                },
            };
            if scene.spec.grid.basis == BasisKind::Fem && !averaging.over_the_cell() {
                return Err(ScriptError::at(
                    options.at,
                    format!("body(...): {ONLY_CELL_WITH_FEM}"),
                ));
            }
            let name = options.value.text("name").unwrap_or_default();
            if let Some(index) = scene.spec.bodies.iter().position(|b| b.name == name) {
                bodies.push((index, averaging));
            }
        }
        let dilatant = dilatant_fbar_warnings(scene.spec, &bodies);
        ModuleWarnings::add(scene.spec, dilatant);
        if !bodies.is_empty() {
            let treated = bodies.iter().map(|&(body, _)| body).collect();
            scene.spec.set_part(LockingTreated(treated));
            scene.spec.set_part(FbarSpec { bodies });
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let spec_bodies = &spec.bodies;
        spec.part::<FbarSpec>().map(|f| {
            let names: Vec<String> = f
                .bodies
                .iter()
                .map(|&(b, averaging)| match averaging {
                    FbarAveraging::Cell => spec_bodies[b].name.clone(),
                    FbarAveraging::Patch => format!("{} (patch)", spec_bodies[b].name),
                    FbarAveraging::Nodal => format!("{} (nodal)", spec_bodies[b].name),
                    FbarAveraging::Mixed => format!("{} (mixed)", spec_bodies[b].name),
                })
                .collect();
            format!("bodies {}", names.join(", "))
        })
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<FbarSpec>().is_some()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        let bodies = spec
            .part::<FbarSpec>()
            .map_or(Vec::new(), |f| f.bodies.clone());
        if crate::distributed::decomposed()
            && bodies.iter().any(|&(_, a)| a == FbarAveraging::Nodal)
        {
            // the projection reads the neighbouring cells' points, which may be on another
            // process (as the patch average, which the decomposition refuses)
            simulation.fail(
                "--decompose: F-bar with the nodal projection (fbar: \"nodal\") reads the neighbouring cells' points, which may be on another process; run it without --decompose",
            );
            return;
        }
        simulation.nonsymmetric_tangent();
        let world = simulation.world();
        let points: Vec<(Entity, FbarAveraging)> = world
            .query::<(Entity, &BodyIndex)>()
            .iter(world)
            .filter_map(|(entity, body)| {
                let &(_, averaging) = bodies.iter().find(|(b, _)| *b == body.0 as usize)?;
                Some((entity, averaging))
            })
            .collect();
        world.insert_batch(points.into_iter().map(|(entity, averaging)| {
            (
                entity,
                (
                    FbarPoint(averaging),
                    ModifiedIncrement::<D>(SMatrix::identity()),
                ),
            )
        }));
        world.insert_resource(FbarCells::default());
        simulation.point_state(
            "F-bar points",
            |_, _| {},
            move |point, body, _| {
                if let Some(&(_, averaging)) = bodies.iter().find(|(b, _)| *b == body as usize) {
                    point.insert((
                        FbarPoint(averaging),
                        ModifiedIncrement::<D>(SMatrix::identity()),
                    ));
                }
                Ok(())
            },
        );
        simulation
            .add_systems(Hook::Connectivity, group_points_by_cell::<D>)
            .add_systems(Hook::Kinematics, average_volume_change::<D>)
            .add_systems(Hook::AfterAssembly, assemble_fbar_tangent::<D>)
            .add_measure("fbar_sparse_cells", |world, _| {
                measure_sparse_cells::<D>(world).map(|n| n as f64)
            });
    }
}

/// The groups of the step (points of one body in one cell, with their sources) and their
/// coupling groups; keeps the volume of each (body, cell)'s points for the sparse cells'
/// count (the measure `fbar_sparse_cells`, [`count_sparse_cells`]).
#[allow(clippy::type_complexity)] // a system: its parameters are what it reads and writes
pub fn group_points_by_cell<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut cells: ResMut<FbarCells>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    points: Query<
        (
            Entity,
            &PointId,
            &BodyIndex,
            &Position<D>,
            &Support<D>,
            &FbarPoint,
            &Volume,
            Option<&ElementPoint<D>>,
        ),
        With<FbarPoint>,
    >,
) {
    let _timer = clock.time(Stage::Connectivity);
    let mut keyed = Vec::with_capacity(points.iter().len());
    for (entity, id, body, x, _, averaging, _, element) in points.iter() {
        // a finite element's Gauss points stay in their element however the mesh moves
        let cell = match element {
            Some(element) => Ok(element.element),
            None => grid.0.cell_of(&x.0).map(|cell| grid.0.cell_index(cell)),
        };
        match cell {
            Ok(cell) => keyed.push((body.0, cell, id.0, entity, averaging.0)),
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
    keyed.sort_unstable_by_key(|&(body, cell, id, ..)| (body, cell, id));
    let cells = &mut *cells;
    cells.points.clear();
    cells.points.extend(keyed.iter().map(|k| k.3));
    cells.membership.clear();
    // the range of `keyed` of each (body, cell)
    let mut runs: Vec<((u32, usize), std::ops::Range<usize>)> = Vec::new();
    let mut start = 0;
    for run in keyed.chunk_by(|a, b| (a.0, a.1) == (b.0, b.1)) {
        runs.push(((run[0].0, run[0].1), start..start + run.len()));
        start += run.len();
    }
    let per_axis = grid.0.cells_per_axis();
    cells.groups.clear();
    for ((body, cell), members) in &runs {
        let mut group = FbarGroup {
            sources: members.clone().collect(),
            members: members.len(),
            ..FbarGroup::default()
        };
        let averaging = keyed[members.start].4;
        group.mixed = averaging == FbarAveraging::Mixed;
        if !averaging.over_the_cell() {
            let centre = grid.0.cell_multi_index(*cell);
            for offset in 0..3usize.pow(D as u32) {
                let mut neighbour = [0; D];
                let mut inside = true;
                let mut code = offset;
                for a in 0..D {
                    let shifted = centre[a] as isize + (code % 3) as isize - 1;
                    code /= 3;
                    inside &= shifted >= 0 && (shifted as usize) < per_axis[a];
                    neighbour[a] = shifted.max(0) as usize;
                }
                let index = grid.0.cell_index(neighbour);
                if !inside || index == *cell {
                    continue;
                }
                if let Ok(found) = runs.binary_search_by_key(&(*body, index), |(key, _)| *key) {
                    group.sources.extend(runs[found].1.clone());
                }
            }
        }
        for &source in &group.sources {
            if let Ok((.., support, _, _, _)) = points.get(cells.points[source]) {
                group.nodes.extend(support.0.iter().map(|w| w.node));
            }
        }
        group.nodes.sort_unstable();
        group.nodes.dedup();
        for &source in &group.sources {
            let local =
                points
                    .get(cells.points[source])
                    .map_or(Vec::new(), |(.., support, _, _, _)| {
                        support
                            .0
                            .iter()
                            .map(|w| group.nodes.binary_search(&w.node).unwrap_or(0))
                            .collect()
                    });
            group.local.push(local);
        }
        group.weights = vec![0.0; group.sources.len()];
        if averaging == FbarAveraging::Nodal {
            let corner = grid.0.cell_multi_index(*cell);
            for &source in &group.sources {
                let x = points.get(cells.points[source]).map(|p| p.3.0);
                for vertex in 0..1usize << D {
                    let mut tent = 1.0;
                    for (k, axis) in grid.0.axes.iter().enumerate() {
                        // the knot coordinate t = (x − lower)/h; the vertex at corner + bit k
                        let t = x.map_or(f64::INFINITY, |x| (x[k] - axis.lower) / axis.spacing());
                        let at = (corner[k] + ((vertex >> k) & 1)) as f64;
                        tent *= (1.0 - (t - at).abs()).max(0.0);
                    }
                    group.tents.push(tent);
                }
            }
            group.weights = vec![0.0; group.members * group.sources.len()];
        }
        if group.sources.len() > 1 {
            fields.couplings.push(group.nodes.clone());
        }
        for (member, &source) in group.sources[..group.members].iter().enumerate() {
            let index = cells.groups.len();
            cells
                .membership
                .insert(cells.points[source], (index, member));
        }
        cells.groups.push(group);
    }
    cells.fills.clear();
    cells.fills.extend(runs.iter().map(|(key, members)| {
        let volume: f64 = keyed[members.clone()]
            .iter()
            .map(|k| points.get(k.3).map_or(0.0, |p| p.6.0))
            .sum();
        (*key, volume)
    }));
}

/// The measure `fbar_sparse_cells` of a converged step: its sparse groups over every process
/// ([`count_sparse_cells`]; collective with decomposed points: every process records every
/// converged step, in the same order); warns once when more are sparse than at the run's
/// first recorded step. `None` (and a warning) if the processes could not count them.
fn measure_sparse_cells<const D: usize>(world: &mut World) -> Option<usize> {
    let cell_volume: f64 = world
        .resource::<Grid<D>>()
        .0
        .axes
        .iter()
        .map(|a| a.spacing())
        .product();
    let step = world.resource::<LoadStep>().number;
    let cells = world.get_resource::<FbarCells>()?;
    let counted = count_sparse_cells(
        &cells.fills,
        SPARSE_CELL_FRACTION * cell_volume,
        |candidates| {
            let numbers: Vec<u64> = candidates
                .iter()
                .flat_map(|&(body, cell)| [u64::from(body), cell as u64])
                .collect();
            let all = crate::distributed::gather_over_points(&numbers)?;
            Ok(all
                .chunks_exact(2)
                .map(|pair| (pair[0] as u32, pair[1] as usize))
                .collect())
        },
        crate::distributed::sum_over_points,
    );
    let sparse = match counted {
        Ok(sparse) => sparse,
        Err(why) => {
            world.resource_mut::<Warnings>().0.push(format!(
                "F-bar: load step {step}: the sparse cells could not be counted over the processes ({why}); fbar_sparse_cells is left out of this step's record"
            ));
            return None;
        }
    };
    let mut cells = world.resource_mut::<FbarCells>();
    cells.sparse = sparse;
    let at_start = *cells.sparse_at_start.get_or_insert(sparse);
    let appeared = (sparse > at_start && !cells.warned).then(|| sparse - at_start);
    if let Some(appeared) = appeared {
        cells.warned = true;
        world
            .resource_mut::<Warnings>()
            .0
            .push(sparse_cells_warning(step, appeared));
    }
    Some(sparse)
}

/// The number of sparse (body, cell)s: those whose points hold less than `limit` of volume,
/// over every process. `fills` is this process's volume in each (body, cell) it holds points
/// of, ordered by (body, cell). A cell's points may be on several processes (with decomposed
/// points each process holds the points of its slab of cells at the step start, so a cell's
/// points are normally on one; the count does not rely on it): a cell is below `limit` only
/// if every process's part of it is, so each process offers its parts below `limit` as
/// candidates, `union` gathers every process's candidates (in any order, repeated), and
/// `sum` adds the candidates' volumes over the processes, entry by entry (each process's
/// part, 0 where it holds none of the cell); a candidate whose sum is below `limit` is
/// counted, once. Serially `union` returns the candidates and `sum` does nothing: the count
/// of `fills` below `limit`.
pub fn count_sparse_cells(
    fills: &[((u32, usize), f64)],
    limit: f64,
    union: impl FnOnce(&[(u32, usize)]) -> Result<Vec<(u32, usize)>, String>,
    sum: impl FnOnce(&mut [f64]),
) -> Result<usize, String> {
    let candidates: Vec<(u32, usize)> = fills
        .iter()
        .filter(|(_, volume)| *volume < limit)
        .map(|(key, _)| *key)
        .collect();
    let mut all = union(&candidates)?;
    all.sort_unstable();
    all.dedup();
    let mut volumes: Vec<f64> = all
        .iter()
        .map(|key| {
            fills
                .binary_search_by_key(key, |(k, _)| *k)
                .map_or(0.0, |found| fills[found].1)
        })
        .collect();
    sum(&mut volumes);
    Ok(volumes.iter().filter(|&&volume| volume < limit).count())
}

/// The run's warning when `appeared` more F-bar groups than at the first step are sparse.
fn sparse_cells_warning(step: usize, appeared: usize) -> String {
    format!(
        "F-bar: from load step {step} on, {appeared} more background cells than at the start are less than half full of F-bar points (points crossed cell faces, or the surface moved through them); their volume change is averaged over one or two points, and loads measured from here on depend on it by several per cent (the Tresca strip footing: at 8 cells across B the pressure rises 16 times as much in the step where such cells appear under the footing as in the step before; docs/plasticity.md, \"F-bar\"); the measure fbar_sparse_cells counts them per step"
    )
}

/// `Δj̄` of every group and `Δf̄` of its members for the current increments (module docs).
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
    let cells = &mut *cells;
    increments.clear();
    for &entity in &cells.points {
        let Ok((id, support, volume, _)) = points.get(entity) else {
            increments.push((SMatrix::identity(), 1.0, 0.0));
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
    for group in cells.groups.iter_mut() {
        if !group.tents.is_empty() {
            project_volume_change::<D>(group, &increments[..], |q, df| {
                if let Ok((.., mut seen)) = points.get_mut(cells.points[q]) {
                    seen.0 = df;
                }
            });
            continue;
        }
        let volume: f64 = group.sources.iter().map(|&q| increments[q].2).sum();
        let changed: f64 = group
            .sources
            .iter()
            .map(|&q| increments[q].2 * increments[q].1)
            .sum();
        let average = changed / volume;
        for (weight, &q) in group.weights.iter_mut().zip(&group.sources) {
            let (_, dj, v) = increments[q];
            *weight = v * dj / changed;
        }
        for &q in &group.sources[..group.members] {
            let (df, dj, _) = increments[q];
            if let Ok((.., mut seen)) = points.get_mut(cells.points[q]) {
                seen.0 = df * (average / dj).powf(1.0 / D as f64);
            }
        }
    }
}

/// The nodal projection of a group (module docs, "Nodal projection"): from the sources'
/// increments `(Δf_q, Δj_q, V_q^n)` (indexed by [`FbarCells::points`]) the vertex values
/// `c_a = Σ_q N̂_a(x_q) V_q Δj_q / m_a`, `m_a = Σ_q N̂_a(x_q) V_q`, each member's
/// `Δj̄_p = Σ_a N̂_a(x_p) c_a` and its weights `α_q^p` (stored in `group.weights`), and
/// `modified(q, Δf̄_q)` for every member `q`.
pub fn project_volume_change<const D: usize>(
    group: &mut FbarGroup,
    increments: &[(SMatrix<f64, D, D>, f64, f64)],
    mut modified: impl FnMut(usize, SMatrix<f64, D, D>),
) {
    let vertices = 1usize << D;
    let sources = group.sources.len();
    // m_a and Σ_q N̂_a V_q Δj_q per vertex
    let mut mass = [0.0; 8];
    let mut changed = [0.0; 8];
    for (&q, tents) in group.sources.iter().zip(group.tents.chunks_exact(vertices)) {
        let (_, dj, v) = increments[q];
        for a in 0..vertices {
            mass[a] += tents[a] * v;
            changed[a] += tents[a] * v * dj;
        }
    }
    for member in 0..group.members {
        let own = &group.tents[member * vertices..(member + 1) * vertices];
        let averaged: f64 = (0..vertices)
            .filter(|&a| own[a] > 0.0)
            .map(|a| own[a] * changed[a] / mass[a])
            .sum();
        let row = &mut group.weights[member * sources..(member + 1) * sources];
        let q = group.sources[member];
        let (df, dj, _) = increments[q];
        if !(averaged.is_finite() && averaged > 0.0) {
            // no tent reaches the member (a point the step could not place): its own increment
            row.fill(0.0);
            row[member] = 1.0;
            modified(q, df);
            continue;
        }
        for ((weight, &q), tents) in row
            .iter_mut()
            .zip(&group.sources)
            .zip(group.tents.chunks_exact(vertices))
        {
            let (_, dj, v) = increments[q];
            *weight = (0..vertices)
                .filter(|&a| own[a] > 0.0)
                .map(|a| own[a] * tents[a] / mass[a])
                .sum::<f64>()
                * v
                * dj
                / averaged;
        }
        modified(q, df * (averaged / dj).powf(1.0 / D as f64));
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
    /// The mixed form: a member's own `g_j` per node of the group, and `∂p_p/∂Δu_j`.
    own: Vec<SVector<f64, D>>,
    response: Vec<SVector<f64, D>>,
}

/// Adds the F-bar terms `V0 (P g_i) ⊗ (ḡ_j − g_j)` of every group to the tangent.
pub fn assemble_fbar_tangent<const D: usize>(
    cells: Res<FbarCells>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<FbarScratch<D>>,
    points: Query<(&Support<D>, &Trial<D>, &ReferenceVolume)>,
    elsewhere: Query<(), With<AssembledElsewhere>>,
) {
    let _timer = clock.time(Stage::Assembly);
    let scratch = &mut *scratch;
    // distributed runs: the members another process assembles are its to add (a group's
    // members share a cell, so one process adds the whole group)
    let here = |q: &usize| !elsewhere.contains(cells.points[*q]);
    for group in cells.groups.iter().filter(|g| g.sources.len() > 1) {
        if !group.sources[..group.members].iter().any(here) {
            continue;
        }
        let n = group.nodes.len();
        let nodal = !group.tents.is_empty();
        let state_of = |e: Entity| points.get(e).ok().map(|(s, t, _)| (s, &t.0));
        if !nodal {
            average_gradients(
                group,
                &cells,
                &group.weights,
                state_of,
                &mut scratch.averaged,
            );
        }
        scratch.blocks.clear();
        scratch.blocks.resize(n * n, SMatrix::zeros());
        let sources = group.sources.len();
        let members = group.sources[..group.members].iter().zip(&group.local);
        for (member, (&q, local)) in members.enumerate().filter(|(_, (q, _))| here(q)) {
            let Ok((support, trial, v0)) = points.get(cells.points[q]) else {
                continue;
            };
            if nodal {
                let row = &group.weights[member * sources..(member + 1) * sources];
                average_gradients(group, &cells, row, state_of, &mut scratch.averaged);
            }
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
        if group.mixed {
            add_mixed_pressure_terms(group, &cells, &points, &mut fields, scratch);
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

/// `ḡ_j = Σ_q α_q g_j^q` on every node of a group (module docs, "Internal force and consistent
/// tangent"), with `weights` the group's `α_q` (for a nodal group a member's row `α_q^p`) and
/// `state_of` a source's support and trial state.
fn average_gradients<'a, const D: usize>(
    group: &FbarGroup,
    cells: &FbarCells,
    weights: &[f64],
    state_of: impl Fn(Entity) -> Option<(&'a Support<D>, &'a TrialState<D>)>,
    averaged: &mut Vec<SVector<f64, D>>,
) {
    averaged.clear();
    averaged.resize(group.nodes.len(), SVector::zeros());
    for ((&q, local), alpha) in group.sources.iter().zip(&group.local).zip(weights) {
        let Some((support, state)) = state_of(cells.points[q]) else {
            continue;
        };
        for (w, &l) in support.0.iter().zip(local) {
            averaged[l] += state.spatial_gradient(&w.gradient) * *alpha;
        }
    }
}

/// The volume-change coupling of an F-bar point: the derivative of `ln Δj̄_p − ln Δj_p` with
/// respect to the increment of every node `j` of its group, `ḡ_j − g_j^p` (into `coupling`,
/// as `(node, ḡ_j − g_j^p)`), and its `P_p` (module docs, "Internal force and consistent
/// tangent"). A force `τ̄_p v` linear in the point's stress then has, beyond the standard
/// block of `mechanics`, the derivative `(P_p v) ⊗ (ḡ_j − g_j^p)`: the rank-one term of the
/// internal force with `v = V0 g_i`, of Nitsche's consistency term with `v = Δf⁻ᵀ m_s`
/// (`effects::surface_conditions`). `None` when the point's volume change is its own (not an
/// F-bar point, or the only source of its group).
pub fn volume_change_coupling<'a, const D: usize>(
    cells: &FbarCells,
    point: Entity,
    state_of: impl Fn(Entity) -> Option<(&'a Support<D>, &'a TrialState<D>)>,
    coupling: &mut Vec<(usize, SVector<f64, D>)>,
) -> Option<SMatrix<f64, D, D>> {
    let &(index, member) = cells.membership.get(&point)?;
    let group = &cells.groups[index];
    let sources = group.sources.len();
    if sources < 2 {
        return None;
    }
    let (support, state) = state_of(point)?;
    let weights = match group.tents.is_empty() {
        true => &group.weights[..],
        false => &group.weights[member * sources..(member + 1) * sources],
    };
    let mut averaged = Vec::new();
    average_gradients(group, cells, weights, &state_of, &mut averaged);
    for (w, &l) in support.0.iter().zip(&group.local[member]) {
        averaged[l] -= state.spatial_gradient(&w.gradient);
    }
    coupling.clear();
    coupling.extend(group.nodes.iter().copied().zip(averaged));
    Some(volumetric_projection(state))
}

/// The mixed form's terms of a cell group (module docs, "The mixed form"): adds
/// `Π ḡ_i − Σ_p V0_p p_p g_i^p` to the internal force and its derivative to the group's blocks
/// (`scratch.averaged` holds `ḡ`).
fn add_mixed_pressure_terms<const D: usize>(
    group: &FbarGroup,
    cells: &FbarCells,
    points: &Query<(&Support<D>, &Trial<D>, &ReferenceVolume)>,
    fields: &mut GridFields<D>,
    scratch: &mut FbarScratch<D>,
) {
    let n = group.nodes.len();
    let FbarScratch {
        averaged,
        gradients,
        blocks,
        own,
        response,
    } = scratch;
    let mut total_pressure = 0.0;
    own.clear();
    own.resize(n, SVector::zeros());
    for (&q, local) in group.sources[..group.members].iter().zip(&group.local) {
        let Ok((support, trial, v0)) = points.get(cells.points[q]) else {
            continue;
        };
        let state = &trial.0;
        let pressure = (0..D).map(|a| state.kirchhoff[(a, a)]).sum::<f64>() / D as f64;
        let projection = volumetric_projection(state);
        let dilation = projection.trace() / D as f64;
        let trace_response = pressure_response(state);
        total_pressure += v0.0 * pressure;
        // the point's own gradients on the group's nodes
        own.iter_mut().for_each(|g| *g = SVector::zeros());
        for (w, &l) in support.0.iter().zip(local) {
            own[l] = state.spatial_gradient(&w.gradient);
        }
        // ∂p_p/∂Δu_j = Q_p b̄ g_j + (tr P_p / D)(ḡ_j − g_j)
        response.clear();
        response.extend((0..n).map(|j| {
            trace_response * state.left_cauchy_green * own[j] + (averaged[j] - own[j]) * dilation
        }));
        for i in 0..n {
            let d_i = (averaged[i] - own[i]) * v0.0;
            fields.internal_force[group.nodes[i]] -= own[i] * (v0.0 * pressure);
            for j in 0..n {
                blocks[i * n + j] +=
                    d_i * response[j].transpose() + own[j] * own[i].transpose() * (v0.0 * pressure);
            }
        }
    }
    // the group-level terms: Π ḡ_i in the force, Π (Σ_q α_q (g_i^q ⊗ g_j^q − g_j^q ⊗ g_i^q)
    // − ḡ_i ⊗ ḡ_j) in the tangent
    for (&q, (local, &alpha)) in group.sources[..group.members]
        .iter()
        .zip(group.local.iter().zip(&group.weights))
    {
        let Ok((support, trial, _)) = points.get(cells.points[q]) else {
            continue;
        };
        gradients.clear();
        gradients.extend(
            support
                .0
                .iter()
                .map(|w| trial.0.spatial_gradient(&w.gradient)),
        );
        for (g_i, &i) in gradients.iter().zip(local) {
            for (g_j, &j) in gradients.iter().zip(local) {
                blocks[i * n + j] +=
                    (g_i * g_j.transpose() - g_j * g_i.transpose()) * (alpha * total_pressure);
            }
        }
    }
    for i in 0..n {
        fields.internal_force[group.nodes[i]] += averaged[i] * total_pressure;
        for j in 0..n {
            blocks[i * n + j] -= averaged[i] * averaged[j].transpose() * total_pressure;
        }
    }
}

/// `Q_kd = (1/D) Σ_a ½ (c_aakd + c_aadk)`: the response of the pressure `p = (1/D) tr τ` to
/// `b` (`∂p = Q : ½ ∂b` for a symmetric `∂b`).
fn pressure_response<const D: usize>(
    state: &crate::mechanics::TrialState<D>,
) -> SMatrix<f64, D, D> {
    let c = &state.tangent;
    SMatrix::from_fn(|k, d| {
        (0..D)
            .map(|a| 0.5 * (c[a][a][k][d] + c[a][a][d][k]))
            .sum::<f64>()
            / D as f64
    })
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

/// One warning per body with the standard F-bar (not `"mixed"`) and dilatant plastic flow
/// (Mohr–Coulomb or Drucker–Prager with `ψ > 0`; `ψ` defaults to `φ`): its points' pressures
/// differ within a group, the standard internal force is not the gradient of a potential, and
/// Newton cycles near collapse (module docs, "The mixed form").
fn dilatant_fbar_warnings(spec: &SceneSpec, bodies: &[(usize, FbarAveraging)]) -> Vec<String> {
    let mut warnings = Vec::new();
    for &(index, averaging) in bodies {
        let body = &spec.bodies[index];
        let Some(material) = spec.materials.get(body.material) else {
            continue;
        };
        if averaging == FbarAveraging::Mixed
            || !matches!(material.model.as_str(), "mohr_coulomb" | "drucker_prager")
        {
            continue;
        }
        let parameters = &material.parameters;
        let friction = parameters.optional_number("phi").ok().flatten();
        let dilation = parameters
            .optional_number("psi")
            .ok()
            .flatten()
            .or(friction);
        if let Some(psi) = dilation.filter(|&psi| psi > 0.0) {
            warnings.push(format!(
                "body '{}' (material '{}', {} with psi = {psi}) uses F-bar with dilatant plastic flow: the points of a cell then carry different pressures, the standard F-bar internal force is not the gradient of a potential, and Newton cycles between active sets near collapse (the associated Mohr-Coulomb strip footing fails before settlement/B = 0.05 on FEM and MPM); use fbar: \"mixed\" (docs/plasticity.md, Benchmark 4)",
                body.name, material.name, material.model
            ));
        }
    }
    warnings
}

/// The averaging of a `fbar` option's value: `true` or `"cell"`, `"patch"`, `"nodal"`; `false`:
/// none.
fn fbar_averaging(value: &rhai::Dynamic) -> Result<Option<FbarAveraging>, String> {
    if let Ok(flag) = value.as_bool() {
        return Ok(flag.then_some(FbarAveraging::Cell));
    }
    match value.clone().into_string().as_deref() {
        Ok("cell") => Ok(Some(FbarAveraging::Cell)),
        Ok("patch") => Ok(Some(FbarAveraging::Patch)),
        Ok("nodal") => Ok(Some(FbarAveraging::Nodal)),
        Ok("mixed") => Ok(Some(FbarAveraging::Mixed)),
        _ => Err(format!(
            "option 'fbar' must be true, false, \"cell\", \"mixed\", \"patch\" or \"nodal\", got {}",
            crate::scene::describe(value)
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three processes' fills of the same cells (limit 0.5 of a unit cell): cell 1 is split
    /// 0.3 + 0.3 (each part below the limit, the whole above: not sparse), cell 2 0.2 + 0.1
    /// (sparse, counted once), cell 3 0.3 on one process and 0.6 on another (the full part
    /// is no candidate: not sparse), cell 4 0.4 on one process only (sparse), cell 5 full on
    /// one process; body 1's cell 2 (0.9) is another group than body 0's.
    #[test]
    fn a_cell_split_over_processes_is_counted_once_by_its_whole_volume() {
        let fills: [Vec<((u32, usize), f64)>; 3] = [
            vec![((0, 1), 0.3), ((0, 2), 0.2), ((0, 3), 0.3), ((0, 5), 1.0)],
            vec![((0, 1), 0.3), ((0, 2), 0.1), ((0, 4), 0.4), ((1, 2), 0.9)],
            vec![((0, 3), 0.6)],
        ];
        let limit = 0.5;
        // what every process offers, gathered as the all-gather would
        let mut gathered = Vec::new();
        for mine in &fills {
            count_sparse_cells(
                mine,
                limit,
                |candidates| {
                    gathered.extend_from_slice(candidates);
                    Ok(candidates.to_vec())
                },
                |_| {},
            )
            .unwrap();
        }
        // each process's parts of the gathered candidates, summed as the reduction would
        let mut parts = Vec::new();
        for mine in &fills {
            count_sparse_cells(
                mine,
                limit,
                |_| Ok(gathered.clone()),
                |volumes| parts.push(volumes.to_vec()),
            )
            .unwrap();
        }
        let sums: Vec<f64> = (0..parts[0].len())
            .map(|k| parts.iter().map(|p| p[k]).sum())
            .collect();
        for mine in &fills {
            let sparse = count_sparse_cells(
                mine,
                limit,
                |_| Ok(gathered.clone()),
                |volumes| volumes.copy_from_slice(&sums),
            )
            .unwrap();
            assert_eq!(sparse, 2, "cells 2 and 4 of body 0");
        }
        // serially (every point on one process) the count of the fills below the limit
        let whole = [
            ((0, 1), 0.6),
            ((0, 2), 0.3),
            ((0, 3), 0.9),
            ((0, 4), 0.4),
            ((0, 5), 1.0),
        ];
        let serial = count_sparse_cells(&whole, limit, |c| Ok(c.to_vec()), |_| {}).unwrap();
        assert_eq!(serial, 2);
        // a sum of the processes' own counts would count the split cells' parts: 6
        let per_process: usize = fills
            .iter()
            .map(|mine| mine.iter().filter(|(_, v)| *v < limit).count())
            .sum();
        assert_eq!(per_process, 6);
    }
}
