//! The built-in modules: every optional effect and every material model of the scene language,
//! each a [`Plugin`](crate::plugin::Plugin) in a file of its own that owns its components,
//! resources, world setup and systems. [`built_in`] lists them, one line each; a scene builds
//! only the ones it uses (`Plugin::used_by`).
//!
//! | module | what |
//! |---|---|
//! | `materials.rs` | a material model per body (Hencky elasticity; von Mises, Drucker–Prager and Mohr–Coulomb plasticity) |
//! | `material_switches.rs` | a body's material changed at a later stage's start (`material_of`) |
//! | `point_domains.rs` | GIMP, CPDI and domain-averaged B-splines: weights over point domains |
//! | `fem_mesh/` | linear FEM on the body-fitted mesh of grid cells |
//! | `body_force.rs` | body force per unit mass |
//! | `point_loads.rs` | forces on material points |
//! | `tractions.rs` | surface tractions carried by traction points |
//! | `grid_constraints.rs` | `fix` and `displace` on grid nodes |
//! | `surface_conditions.rs` | prescribed displacements and supports on material surfaces |
//! | `ghost_penalty.rs` | stabilisation of nearly empty cells |
//! | `fbar.rs` | F-bar: the volume change averaged over the points of a cell (`body(#{ fbar: true })`) or of the cells around it (`"patch"`) |
//! | `stress_recovery.rs` | moving-least-squares stress recovery |
//! | `probes.rs` | displacement, stress and F at material reference positions (`probe`) |
//! | `stages.rs` | displacements measured from a stage's start (`stage(#{ zero_displacements: true })`) |
//! | `history.rs` | named columns of history.csv from the measured quantities (`record`) |
//! | `initial_stress.rs` | geostatic `K0` initial stresses (`initial_stress`), applied by the materials' modules |
//! | `line_search.rs` | the Newton line search (`solver(#{ line_search: true })`; the method in `stages::line_search`) |
//! | `arc_length.rs` | arc-length load control (`solver(#{ control: "arc_length" })`; the method in `stages::arc_length`) |
//! | `weak_nodes.rs` | nodes the material barely reaches, extended from interior nodes (`solver(#{ weak_nodes: ε })`) |

pub mod arc_length;
pub mod body_force;
pub mod carried_points;
pub mod declarations;
#[cfg(feature = "mpi")]
pub mod distributed;
pub mod fbar;
pub mod fem_mesh;
pub mod ghost_penalty;
pub mod grid_constraints;
pub mod history;
pub mod initial_stress;
pub mod line_search;
pub mod material_switches;
pub mod materials;
pub mod point_domains;
pub mod point_loads;
pub mod pressure;
pub mod probes;
pub mod stages;
pub mod stress_recovery;
pub mod surface_conditions;
pub mod tractions;
pub mod weak_nodes;

use crate::material::{DruckerPrager, Hencky, MohrCoulomb, VonMises};
use crate::plugin::ModuleSet;

/// The modules every run has, in the order they are built (which is also the order of their
/// systems at a shared hook).
pub fn built_in() -> ModuleSet {
    let modules = ModuleSet::new()
        .with(materials::MaterialModule::<Hencky>::default())
        .with(materials::MaterialModule::<VonMises>::default())
        .with(materials::MaterialModule::<DruckerPrager>::default())
        .with(materials::MaterialModule::<MohrCoulomb>::default())
        .with(material_switches::MaterialSwitchesModule)
        .with(point_domains::PointDomainsModule)
        .with(fem_mesh::FemMeshModule)
        .with(body_force::BodyForceModule)
        .with(point_loads::PointLoadsModule)
        .with(tractions::TractionsModule)
        .with(pressure::PressureModule)
        .with(grid_constraints::GridConstraintsModule)
        .with(grid_constraints::PrescribedDisplacementsModule)
        .with(surface_conditions::SurfaceConditionsModule)
        .with(ghost_penalty::GhostPenaltyModule)
        .with(fbar::FbarModule)
        .with(stress_recovery::StressRecoveryModule)
        .with(probes::ProbesModule)
        .with(stages::StagesModule)
        .with(history::HistoryModule)
        .with(initial_stress::InitialStressModule)
        .with(line_search::LineSearchModule)
        .with(arc_length::ArcLengthModule)
        // after every module that adds to the tangent: it transforms the whole system
        .with(weak_nodes::WeakNodesModule);
    // last: it checks what the modules before it added after the assembly
    #[cfg(feature = "mpi")]
    let modules = modules.with(distributed::DistributedModule);
    modules
}
