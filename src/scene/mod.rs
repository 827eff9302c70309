//! Scenes: what a simulation is made of, as plain resolved data ([`SceneSpec`]), and the Rhai
//! front end that builds one from a script.
//!
//! A `SceneSpec` holds no script state: predicates on position have already been evaluated
//! (points seeded, constrained nodes selected) and the load schedule is a list of factors, so
//! the solver never calls back into Rhai. Its core parts (grid, materials, bodies, load
//! factors, solver and output controls, analytic solution) are fields; what modules declare
//! (point loads, tractions, constraints, ...) is in [`SceneSpec::parts`], each part a type
//! the module owns.
//!
//! A scene script, e.g. `scripts/column_1d.rhai`:
//!
//! ```rhai
//! let cells = 50;                      // parameters: top-level lets, `--set cells=100`
//! let basis = "bspline";
//! grid(#{ lower: [0.0], upper: [50.0], cells: [cells], basis: basis, order: 3 });
//! const soil = material(#{ name: "soil", E: 1e6, nu: 0.0, density: 1.0 });
//! body(#{ name: "column", material: soil, region: box([0.0], [50.0]), ppc: 4 });
//! body_force([-800.0]);
//! fix(|x| x[0] == 0.0, [0]);
//! load_steps(20);
//! ```
//!
//! Files: `engine.rs` (runs a script: [`load_scene_with`], [`scene_parameters`]),
//! `registry.rs` (the description of every scene call: [`SceneApi`]), `calls.rs` (the core's
//! calls), `options.rs` (the table-driven reader of options maps), `builder.rs` (declarations
//! and their resolution), `schedule.rs` (load-step schedules), `params.rs` (parameters and
//! overrides), `seeding.rs` and `fem_seeding.rs` (material points and integration points),
//! `geometry.rs`, `error.rs` (`file:line:column: message`). The reference of the scene
//! language is generated from the registry into `docs/scene-api.md`.

mod builder;
mod calls;
mod cone_matching;
mod engine;
mod error;
mod fem_seeding;
mod geometry;
mod limits;
mod locking;
mod options;
mod params;
mod rank;
mod registry;
mod schedule;
mod seeding;
mod softening;
mod stages;
mod words;

use std::any::Any;
use std::collections::BTreeMap;
use std::fmt::Debug;
use std::sync::Arc;

pub use builder::{
    BodyDeclaration, LoadSchedule, Located, MAX_NODES, MAX_SEED_CANDIDATES, MaterialHandle,
    PointsPerCell, Region, Resolver, SceneBuilder, ensure_unset,
};
pub use cone_matching::cone_matching_warnings;
pub use engine::{SceneModule, load_scene_with, load_scene_within, scene_api, scene_parameters};
pub use error::{SceneError, ScriptError};
pub use fem_seeding::{PartialCell, seed_element_points};
pub use geometry::{point_in_polygon, polygon_double_area};
pub use limits::{SceneLimits, memory_estimate, support_size};
pub use locking::{
    LockingTreated, ModuleNotes, ModuleWarnings, is_plastic_model, locking_warnings, scene_notes,
    scene_warnings,
};
pub use options::{
    Choice, Kind, OptionSpec, OptionValue, Options, Range, array_of, describe, function, number,
    numbers, string, whole_number, whole_numbers,
};
pub use params::Parameter;
pub use rank::{points_across, rank_warnings};
pub use registry::{CallSpec, Declare, SceneApi};
pub use schedule::{MAX_STEPS, phase_factors};
pub use seeding::{
    PartRule, Placement, SurfacePointSeed, first_point_outside_grid, nearest_points, seed_boundary,
    seed_box, seed_points, seed_points_placed, seed_surface,
};
pub use softening::softening_warnings;
pub use stages::{StageDeclaration, StageSpec, Stages};
pub use words::{BasisRefinement, BasisWord, FieldSpec, ModelSpec, Seeder, Word, Words};

use crate::analytic::SelfWeightColumn;
pub use crate::basis::GridSpec;
use crate::material::MaterialParameters;

/// A material: its model (`"hencky"`, ...), the model's parameters and the density.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialSpec {
    pub name: String,
    /// The model's scene word; a module of that name builds it (`effects::materials`).
    pub model: String,
    pub parameters: MaterialParameters,
    /// Reference (initial) mass density rho0.
    pub density: f64,
    /// A stiffness scale of the model (Young's modulus): default penalty factors use it.
    pub stiffness: f64,
}

impl MaterialSpec {
    /// A Hencky material (Kirchhoff stress linear in logarithmic strain).
    pub fn hencky(name: &str, youngs_modulus: f64, poisson_ratio: f64, density: f64) -> Self {
        Self {
            name: name.to_string(),
            model: "hencky".to_string(),
            parameters: MaterialParameters::numbers(&[
                ("E", youngs_modulus),
                ("nu", poisson_ratio),
            ]),
            density,
            stiffness: youngs_modulus,
        }
    }
}

/// One material point as seeded: reference position and reference volume, and the box it
/// owns (its share of the seeded cell, or of the cell's overlap with a box region).
#[derive(Clone, Debug, PartialEq)]
pub struct PointSeed {
    pub position: Vec<f64>,
    pub volume: f64,
    /// Half the side lengths of the point's box, one per axis: `h_k / (2 ppc_k)` on the
    /// seeding lattice. The initial particle domain for GIMP and CPDI (`basis::domain`).
    pub half_lengths: Vec<f64>,
}

/// A body: material points of one material.
#[derive(Clone, Debug, PartialEq)]
pub struct BodySpec {
    pub name: String,
    /// Index into `SceneSpec::materials`.
    pub material: usize,
    pub points: Vec<PointSeed>,
}

/// Newton solver controls.
#[derive(Clone, Debug, PartialEq)]
pub struct SolverSpec {
    /// Convergence tolerance on the normalised out-of-balance force.
    pub tolerance: f64,
    pub max_iterations: usize,
    /// How many times a load step may be halved when Newton fails (0 = never cut).
    pub max_step_cuts: usize,
    /// The backend of the linear solves.
    pub linear: LinearBackend,
    /// Inexact Newton: iterative solves only as accurate as Eisenstat–Walker forcing terms ask
    /// (`solver::EisenstatWalker`).
    pub inexact: bool,
    /// Options for PETSc's options database (`linear: "petsc"`), e.g. `-ksp_type cg -pc_type
    /// gamg`; empty for PETSc's defaults as the backend sets them.
    pub petsc_options: String,
    /// Backtracking line search (`stages::line_search`).
    pub line_search: bool,
    /// Most shortenings of one Newton step by the line search.
    pub max_backtracks: usize,
    /// What the line search asks of a shortened step (`stages::line_search`).
    pub merit: LineSearchMerit,
}

/// The test a trial step of the line search must pass (`stages::line_search`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LineSearchMerit {
    /// Armijo's sufficient decrease of the out-of-balance force ‖r‖ (the default).
    #[default]
    Residual,
    /// Deuflhard's natural level function ‖K_k⁻¹ r‖: the simplified Newton correction with
    /// the tangent of the iterate the step starts from, which the tangent's scaling does not
    /// distort (needs the direct solver's kept factor; otherwise the residual test is used).
    Natural,
}

impl SolverSpec {
    /// A new solver of the chosen backend, with its options.
    pub fn linear_solver(&self) -> Box<dyn crate::solver::LinearSolver> {
        match self.linear {
            #[cfg(feature = "petsc")]
            LinearBackend::Petsc => Box::new(crate::solver::PetscSolver::new(&self.petsc_options)),
            other => other.solver(),
        }
    }
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            tolerance: 1e-9,
            max_iterations: 30,
            max_step_cuts: 8,
            linear: LinearBackend::Auto,
            inexact: false,
            petsc_options: String::new(),
            line_search: false,
            max_backtracks: 10,
            merit: LineSearchMerit::Residual,
        }
    }
}

/// The backend of the linear solves of Newton's method (see `solver`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LinearBackend {
    /// Sparse Cholesky / LU (`solver::DirectSolver`).
    Direct,
    /// Preconditioned CG / BiCGSTAB (`solver::KrylovSolver`).
    Iterative(Preconditioning),
    /// PETSc's KSP and preconditioners (`solver::PetscSolver`); only in a build with the cargo
    /// feature `petsc`, scenes asking for it elsewhere are refused when they load.
    Petsc,
    /// Direct or iterative by the dimension and the DOFs of each system, the crossover measured
    /// (`solver::AutoSolver`): the default.
    #[default]
    Auto,
}

/// The preconditioner of the iterative backend.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preconditioning {
    /// Smoothed-aggregation multigrid with the rigid-body modes (`solver::Multigrid`), with
    /// this smoother.
    Multigrid(crate::solver::Smoother),
    /// The inverse diagonal (`solver::Jacobi`).
    Jacobi,
}

impl Default for Preconditioning {
    fn default() -> Self {
        Preconditioning::Multigrid(Default::default())
    }
}

impl LinearBackend {
    /// A new solver of this kind.
    pub fn solver(self) -> Box<dyn crate::solver::LinearSolver> {
        use crate::solver::{DirectSolver, KrylovSolver};
        match self {
            LinearBackend::Direct => Box::new(DirectSolver::default()),
            LinearBackend::Auto => Box::new(crate::solver::AutoSolver::default()),
            LinearBackend::Iterative(Preconditioning::Jacobi) => Box::new(KrylovSolver::default()),
            LinearBackend::Iterative(Preconditioning::Multigrid(smoother)) => {
                let mut multigrid = crate::solver::Multigrid::default();
                multigrid.smoother = smoother;
                Box::new(KrylovSolver::with_preconditioner(Box::new(multigrid)))
            }
            #[cfg(feature = "petsc")]
            LinearBackend::Petsc => Box::new(crate::solver::PetscSolver::new("")),
            #[cfg(not(feature = "petsc"))]
            LinearBackend::Petsc => Box::new(WithoutPetsc),
        }
    }
}

/// `linear: "petsc"` in a build without PETSc (reached only by building a [`SolverSpec`] in
/// code: scenes asking for it are refused when they load): every solve fails, saying so.
#[cfg(not(feature = "petsc"))]
struct WithoutPetsc;

#[cfg(not(feature = "petsc"))]
impl crate::solver::LinearSolver for WithoutPetsc {
    fn solve(
        &mut self,
        _matrix: &crate::solver::SparseMatrix,
        _symmetric: bool,
        _rhs: &mut [f64],
    ) -> Result<crate::solver::SolverKind, crate::solver::LinearSolveError> {
        Err(crate::solver::LinearSolveError::Backend(
            WITHOUT_PETSC.to_string(),
        ))
    }
}

/// What a build without the cargo feature `petsc` says when PETSc is asked for.
pub const WITHOUT_PETSC: &str = "this build of impm has no PETSc: rebuild with \
                                 `cargo build --release --features petsc` (see README.md, \
                                 \"Running on a cluster\")";

/// Which steps and fields are written.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputSpec {
    /// Write every n-th load step (the initial state and the last step are always written).
    pub every: usize,
    /// If set, write exactly these load steps (and the initial state) instead.
    pub steps: Option<Vec<usize>>,
    /// If set, the particle fields written (the core's and the modules' point fields).
    pub fields: Option<Vec<String>>,
    /// Write the grid and node files (`grid_*.vtu`, `nodes_*.vtu`).
    pub grid: bool,
}

impl Default for OutputSpec {
    fn default() -> Self {
        Self {
            every: 1,
            steps: None,
            fields: None,
            grid: true,
        }
    }
}

/// An analytic solution the scene declares, so runs report the paper's error (eq. 15).
#[derive(Clone, Debug, PartialEq)]
pub enum AnalyticSpec {
    /// The self-weight column (paper eqs. 11-14): base at reference coordinate 0 along `axis`,
    /// free top at `height`; `body_force` is per unit mass along `axis` at load factor 1.
    Column {
        axis: usize,
        height: f64,
        density: f64,
        body_force: f64,
        modulus: f64,
    },
}

impl AnalyticSpec {
    /// The column at load factor `factor` and its axis.
    pub fn column_at(&self, factor: f64) -> (SelfWeightColumn, usize) {
        let AnalyticSpec::Column {
            axis,
            height,
            density,
            body_force,
            modulus,
        } = *self;
        let column = SelfWeightColumn {
            density,
            body_force: body_force * factor,
            height,
            modulus,
        };
        (column, axis)
    }
}

/// Everything a run needs, fully resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneSpec {
    /// Scene name (the script's file stem); the default output folder is `out/<name>/`.
    pub name: String,
    pub grid: GridSpec,
    pub materials: Vec<MaterialSpec>,
    pub bodies: Vec<BodySpec>,
    /// Load factor at the end of each load step, in order (`len()` = number of steps).
    pub load_factors: Vec<f64>,
    pub solver: SolverSpec,
    pub output: OutputSpec,
    pub analytic: Option<AnalyticSpec>,
    /// What modules declared (point loads, tractions, constraints...), by type.
    pub parts: Parts,
}

/// A scene given by value to a run that can drop it once the points are spawned
/// (`run::run_scene_restartable`).
impl From<SceneSpec> for std::borrow::Cow<'_, SceneSpec> {
    fn from(spec: SceneSpec) -> Self {
        std::borrow::Cow::Owned(spec)
    }
}

/// A scene lent to a run: the caller keeps it (and its seeds).
impl<'a> From<&'a SceneSpec> for std::borrow::Cow<'a, SceneSpec> {
    fn from(spec: &'a SceneSpec) -> Self {
        std::borrow::Cow::Borrowed(spec)
    }
}

impl SceneSpec {
    pub fn dim(&self) -> usize {
        self.grid.dim()
    }

    /// Number of material points of all bodies.
    pub fn point_count(&self) -> usize {
        self.bodies.iter().map(|body| body.points.len()).sum()
    }

    /// A copy without the bodies' point seeds (each body keeps its name and material, with no
    /// points): what a simulation keeps of its scene once it has spawned the points, which then
    /// live only in its world. The seeds are the largest part of a scene (two small vectors per
    /// point, ~125 B per point in 2D); they are not cloned to be dropped.
    pub fn without_point_seeds(&self) -> SceneSpec {
        SceneSpec {
            name: self.name.clone(),
            grid: self.grid.clone(),
            materials: self.materials.clone(),
            bodies: self
                .bodies
                .iter()
                .map(|body| BodySpec {
                    name: body.name.clone(),
                    material: body.material,
                    points: Vec::new(),
                })
                .collect(),
            load_factors: self.load_factors.clone(),
            solver: self.solver.clone(),
            output: self.output.clone(),
            analytic: self.analytic.clone(),
            parts: self.parts.clone(),
        }
    }

    /// The reference positions of every material point, body after body (global point index
    /// order).
    pub fn material_point_positions(&self) -> Vec<&[f64]> {
        self.bodies
            .iter()
            .flat_map(|body| &body.points)
            .map(|point| point.position.as_slice())
            .collect()
    }

    /// A module's part, if the scene declared it.
    pub fn part<T: ScenePart>(&self) -> Option<&T> {
        self.parts.get::<T>()
    }

    /// Sets a module's part (replacing one of the same type).
    pub fn set_part<T: ScenePart>(&mut self, part: T) {
        self.parts.insert(part);
    }
}

/// A module's part of a scene: plain data, comparable and printable.
pub trait ScenePart: Any + Debug + Send + Sync {
    fn as_any(&self) -> &dyn Any;
    fn equals(&self, other: &dyn ScenePart) -> bool;
}

impl<T: Any + Debug + PartialEq + Send + Sync> ScenePart for T {
    fn as_any(&self) -> &dyn Any {
        self
    }

    fn equals(&self, other: &dyn ScenePart) -> bool {
        other
            .as_any()
            .downcast_ref::<T>()
            .is_some_and(|other| other == self)
    }
}

/// The modules' parts of a scene, one per type.
#[derive(Clone, Debug, Default)]
pub struct Parts(BTreeMap<&'static str, Arc<dyn ScenePart>>);

impl Parts {
    pub fn get<T: ScenePart>(&self) -> Option<&T> {
        self.0
            .get(std::any::type_name::<T>())
            .and_then(|part| part.as_any().downcast_ref::<T>())
    }

    pub fn insert<T: ScenePart>(&mut self, part: T) {
        self.0.insert(std::any::type_name::<T>(), Arc::new(part));
    }
}

impl PartialEq for Parts {
    fn eq(&self, other: &Self) -> bool {
        self.0.len() == other.0.len()
            && self.0.iter().all(|(name, part)| {
                other
                    .0
                    .get(name)
                    .is_some_and(|theirs| part.equals(theirs.as_ref()))
            })
    }
}
