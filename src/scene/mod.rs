//! Scenes: what a simulation is made of, as plain resolved data (`SceneSpec`), and the Rhai
//! front end that builds one from a script (`rhai_api`).
//!
//! A `SceneSpec` holds no script state: predicates on position have already been evaluated
//! (points seeded, constrained nodes selected) and the load schedule is a list of factors, so
//! the solver never calls back into Rhai.
//!
//! Entry points: [`load_scene`] (script + `--set` overrides -> `SceneSpec`), [`scene_parameters`]
//! (the overridable top-level `let`s) and [`SceneError`] (`file:line:column: message`).
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
//! Modules: `rhai_api` (the functions a script can call; their reference is in its docs),
//! `params` (parameters and overrides), `builder` (declarations and their resolution),
//! `seeding` (material-point seeding), `fem_seeding` (integration points of the body-fitted
//! mesh for `basis: "fem"`), `options` (argument checking), `error`.

mod builder;
mod error;
mod fem_seeding;
mod geometry;
mod options;
mod params;
mod rhai_api;
mod seeding;

pub use error::SceneError;
pub use geometry::{point_in_polygon, polygon_double_area};
pub use params::Parameter;
pub use rhai_api::{load_scene, scene_parameters};
pub use seeding::{
    Placement, first_point_outside_grid, nearest_points, seed_boundary, seed_box, seed_points,
    seed_points_placed,
};

use crate::analytic::SelfWeightColumn;
use crate::basis::BasisKind;
use crate::material::MaterialParameters;

/// The background grid: an axis-aligned box split into uniform cells.
#[derive(Clone, Debug, PartialEq)]
pub struct GridSpec {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    pub cells: Vec<usize>,
    pub basis: BasisKind,
}

impl GridSpec {
    pub fn dim(&self) -> usize {
        self.cells.len()
    }
}

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

/// One constrained component of one grid node (control point). The prescribed displacement
/// `value` is the total at load factor 1; it is ramped with the load factor (0 = fixed).
#[derive(Clone, Debug, PartialEq)]
pub struct NodeConstraint {
    /// Global node index (axis 0 fastest, see `basis::GridBasis::node_index`).
    pub node: usize,
    pub component: usize,
    pub value: f64,
}

/// A force on one material point at load factor 1 (paper eq. 9, a concentrated term of the
/// external force): it adds λ P N_i(x_p) to the external force of the point's support nodes.
#[derive(Clone, Debug, PartialEq)]
pub struct PointLoadSpec {
    /// Global point index: points are numbered body after body, in seeding order (`PointId`).
    pub point: usize,
    /// The force P (length = dimension).
    pub force: Vec<f64>,
}

/// A quadrature point of a surface traction (paper eqs. 1 and 9: the Neumann term
/// ∫_ΓN h N_i dΓ): a piece of boundary of reference area (length in 2D, 1 in 1D) `area` at
/// `position`, carrying the traction `traction` (force per unit reference area at load factor
/// 1). It adds λ h A N_i(x_s) to the external force and moves with the material: with the
/// deformation of its host, the nearest material point (`host`, a global point index).
#[derive(Clone, Debug, PartialEq)]
pub struct TractionPointSpec {
    pub position: Vec<f64>,
    pub area: f64,
    pub traction: Vec<f64>,
    pub host: usize,
}

/// Newton solver controls.
#[derive(Clone, Debug, PartialEq)]
pub struct SolverSpec {
    /// Convergence tolerance on the normalised out-of-balance force.
    pub tolerance: f64,
    pub max_iterations: usize,
    /// How many times a load step may be halved when Newton fails (0 = never cut).
    pub max_step_cuts: usize,
    /// Dimensionless ghost-penalty factor γ for nearly empty cells (0 = off; see `ghost`).
    pub ghost_penalty: f64,
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            tolerance: 1e-9,
            max_iterations: 30,
            max_step_cuts: 8,
            ghost_penalty: 0.0,
        }
    }
}

/// Which steps and fields are written.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputSpec {
    /// Write every n-th load step (the initial state and the last step are always written).
    pub every: usize,
    /// If set, write exactly these load steps (and the initial state) instead.
    pub steps: Option<Vec<usize>>,
    /// If set, the particle fields written (names from `stages::output::PARTICLE_FIELDS`).
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

/// Moving-least-squares recovery of the point stresses (see `crate::recovery`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecoverySpec {
    /// Total degree of the fitted polynomial (0, 1, 2, ...).
    pub order: usize,
    /// Support radius as a multiple of the largest cell size.
    pub radius_in_cells: f64,
}

impl Default for RecoverySpec {
    fn default() -> Self {
        Self {
            order: 2,
            radius_in_cells: 2.5,
        }
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
    /// Body force per unit mass (length = dimension) at load factor 1, if any.
    pub body_force: Option<Vec<f64>>,
    pub constraints: Vec<NodeConstraint>,
    /// Forces on single material points (summed per point), at load factor 1.
    pub point_loads: Vec<PointLoadSpec>,
    /// Traction points of all `traction(...)` declarations.
    pub tractions: Vec<TractionPointSpec>,
    /// Load factor at the end of each load step, in order (`len()` = number of steps).
    pub load_factors: Vec<f64>,
    pub solver: SolverSpec,
    pub output: OutputSpec,
    pub analytic: Option<AnalyticSpec>,
    /// Stress recovery written beside the raw point stress, if asked for.
    pub recovery: Option<RecoverySpec>,
}

impl SceneSpec {
    pub fn dim(&self) -> usize {
        self.grid.dim()
    }

    /// Number of material points of all bodies.
    pub fn point_count(&self) -> usize {
        self.bodies.iter().map(|body| body.points.len()).sum()
    }
}
