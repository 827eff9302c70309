//! The solver stages as ECS systems, and the schedules that order them.
//!
//! One load step runs the [`LoadStep`] schedule, whose system sets run in this order:
//!
//! 1. [`StepSystems::Connectivity`] — evaluate the basis at the points (P2G connectivity) and
//!    mark the active nodes (`connectivity.rs`; over the points' domains for GIMP and CPDI;
//!    for linear FEM the element shape functions on the current mesh, `element_basis.rs`).
//! 2. [`StepSystems::Dofs`] — number the free components of active nodes and build the sparsity
//!    pattern of the step (`dofs.rs`).
//! 3. [`StepSystems::Loads`] — external forces and prescribed displacement increments, only the
//!    ones the scene uses (`loads.rs`).
//! 4. [`StepSystems::Solve`] — the Newton loop: an exclusive system that runs the
//!    [`NewtonIteration`] schedule until converged (`newton.rs`).
//! 5. [`StepSystems::UpdatePoints`] — G2P: move points, update F, volume (paper eq. 10,
//!    `update.rs`); for linear FEM then move the mesh nodes by Δu (`mesh_advance.rs`).
//! 6. [`StepSystems::Output`] — MLS stress recovery if the scene asks for it (`recovery.rs`),
//!    then run the [`WriteOutput`] schedule (VTK files, `output.rs`).
//! 7. [`StepSystems::ResetGrid`] — clear the grid fields (`reset.rs`). The MPM grid is back to
//!    its undeformed state; the FEM mesh keeps its advanced node positions.
//!
//! The [`NewtonIteration`] schedule runs, in order:
//!
//! 1. [`NewtonSystems::StressUpdate`] — trial F, Kirchhoff stress and tangent at every point.
//! 2. [`NewtonSystems::Assembly`] — internal force and consistent tangent (`assembly.rs`).
//! 3. [`NewtonSystems::Convergence`] — out-of-balance force and its normalised norm.
//! 4. [`NewtonSystems::LinearSolve`] — solve K δ = r and update Δu, unless converged.
//!
//! Output is its own schedule, [`WriteOutput`], so the driver can also write the initial state;
//! users may add their own output systems to it. Every set after a failure is skipped
//! (`no_failure`).

mod assembly;
mod connectivity;
mod dofs;
mod element_basis;
mod explain;
pub mod ghost;
mod loads;
mod mesh_advance;
mod mesh_output;
mod newton;
pub mod output;
mod recovery;
mod reset;
mod stress;
mod tractions;
mod update;

pub use assembly::assemble;
pub use connectivity::{evaluate_basis, evaluate_domain_basis};
pub use dofs::number_dofs;
pub use element_basis::evaluate_element_basis;
pub use explain::{Explanation, ScheduledSystem, explain_scene, scheduled_systems};
pub use loads::{
    apply_body_force, apply_point_loads, apply_prescribed_displacements, spread_force,
};
pub use mesh_advance::advance_mesh;
pub use mesh_output::write_mesh;
pub use newton::{check_convergence, solve_linear_system, solve_load_step};
pub use recovery::recover_stress;
pub use reset::reset_grid;
pub use stress::update_stress;
pub use tractions::{apply_tractions, spread_over_active, update_traction_points};
pub use update::update_points;

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{LogLevel, ScheduleBuildSettings, ScheduleLabel};

use crate::resources::{Newton, NewtonSettings, no_failure};

/// The schedule of one load step.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct LoadStep;

/// The schedule of one Newton iteration, run repeatedly by [`solve_load_step`].
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct NewtonIteration;

/// The output schedule.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct WriteOutput;

/// The stages of a load step, in order.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum StepSystems {
    Connectivity,
    Dofs,
    Loads,
    Solve,
    UpdatePoints,
    Output,
    ResetGrid,
}

/// The stages of a Newton iteration, in order.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum NewtonSystems {
    StressUpdate,
    Assembly,
    Convergence,
    LinearSolve,
}

/// The output systems of the crate (particles, grid or mesh, nodes, tractions): systems added
/// to [`WriteOutput`] by plugins run after them.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BuiltInOutput;

/// The connectivity system that evaluates the basis at the points (one per kind of basis:
/// [`evaluate_basis`], [`evaluate_domain_basis`] or `evaluate_element_basis`); the systems that
/// need the step's supports run after it.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
struct BasisEvaluation;

/// Which optional effects a scene uses; the schedules contain only their systems.
///
/// A new effect (plasticity, dynamics, contact...) adds a flag here, sets it in
/// `simulation::effects_of` from what the scene declares, and adds its systems in
/// [`load_step_schedule`] / [`newton_schedule`] / [`output_schedule`] only when the flag is set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Effects {
    pub body_force: bool,
    /// Forces on material points (`point_load`).
    pub point_loads: bool,
    /// Surface tractions carried by traction points (`traction`).
    pub tractions: bool,
    pub prescribed_displacements: bool,
    /// Linear FEM on a body-fitted mesh (`basis = "fem"`) instead of MPM: element
    /// connectivity, a mesh that advances with the body, and the mesh as grid output.
    pub fem_mesh: bool,
    /// Ghost-penalty stabilisation of nearly empty cells (`ghost`).
    pub ghost_penalty: bool,
    /// MLS recovery of the point stresses after every step (`RecoveredStress`).
    pub stress_recovery: bool,
    /// The basis averages over particle domains (GIMP, CPDI, domain-integrated B-splines):
    /// connectivity uses [`evaluate_domain_basis`] instead of [`evaluate_basis`].
    pub point_domains: bool,
}

impl Effects {
    /// The same method (FEM mesh or not, point domains or not) with every optional effect that
    /// adds systems on: what `--explain` compares a scene's schedules with. Tractions and the
    /// ghost penalty are MPM-only, so they stay off with a FEM mesh.
    pub fn with_every_optional_effect(self) -> Effects {
        Effects {
            body_force: true,
            point_loads: true,
            tractions: !self.fem_mesh,
            prescribed_displacements: true,
            ghost_penalty: !self.fem_mesh,
            stress_recovery: true,
            ..self
        }
    }

    /// `(name, used)` for every effect.
    pub fn list(&self) -> [(&'static str, bool); 8] {
        [
            ("body force", self.body_force),
            ("point loads", self.point_loads),
            ("tractions", self.tractions),
            ("prescribed displacements", self.prescribed_displacements),
            ("ghost penalty", self.ghost_penalty),
            ("stress recovery", self.stress_recovery),
            ("basis averaged over domains", self.point_domains),
            ("finite-element mesh", self.fem_mesh),
        ]
    }
}

/// Adds the solver's schedules for dimension `D` with only the effects in use to `world`.
pub fn add_schedules<const D: usize>(world: &mut World, effects: Effects) {
    world.add_schedule(load_step_schedule::<D>(effects));
    world.add_schedule(newton_schedule::<D>(effects));
    world.add_schedule(output_schedule::<D>(effects));
}

/// Schedule settings shared by all solver schedules: single-threaded, and any ambiguity in
/// system order is an error (the solver's result must not depend on chance ordering).
fn strict(label: impl ScheduleLabel) -> Schedule {
    let mut schedule = Schedule::new(label);
    schedule.set_build_settings(ScheduleBuildSettings {
        ambiguity_detection: LogLevel::Error,
        ..Default::default()
    });
    schedule.set_executor(bevy_ecs::schedule::SingleThreadedExecutor::new());
    schedule
}

/// The load-step schedule for dimension `D` with only the effects in use.
pub fn load_step_schedule<const D: usize>(effects: Effects) -> Schedule {
    let mut schedule = strict(LoadStep);
    schedule.configure_sets(
        (
            StepSystems::Connectivity,
            StepSystems::Dofs,
            StepSystems::Loads,
            StepSystems::Solve,
            StepSystems::UpdatePoints,
            StepSystems::Output,
            StepSystems::ResetGrid,
        )
            .chain()
            .distributive_run_if(no_failure),
    );
    // One basis evaluation per kind of basis, in the BasisEvaluation set.
    if effects.fem_mesh {
        schedule.add_systems(
            evaluate_element_basis::<D>
                .in_set(StepSystems::Connectivity)
                .in_set(BasisEvaluation),
        );
        schedule.add_systems(
            advance_mesh::<D>
                .in_set(StepSystems::UpdatePoints)
                .after(update_points::<D>)
                .run_if(no_failure),
        );
    } else if effects.point_domains {
        schedule.add_systems(
            evaluate_domain_basis::<D>
                .in_set(StepSystems::Connectivity)
                .in_set(BasisEvaluation),
        );
    } else {
        schedule.add_systems(
            evaluate_basis::<D>
                .in_set(StepSystems::Connectivity)
                .in_set(BasisEvaluation),
        );
    }
    if effects.ghost_penalty {
        schedule.add_systems(
            ghost::find_ghost_faces::<D>
                .in_set(StepSystems::Connectivity)
                .after(BasisEvaluation),
        );
    }
    schedule.add_systems(number_dofs::<D>.in_set(StepSystems::Dofs));
    if effects.body_force {
        schedule.add_systems(apply_body_force::<D>.in_set(StepSystems::Loads));
    }
    if effects.point_loads {
        schedule.add_systems(
            apply_point_loads::<D>
                .in_set(StepSystems::Loads)
                .after(apply_body_force::<D>),
        );
    }
    if effects.tractions {
        schedule.add_systems((
            apply_tractions::<D>
                .in_set(StepSystems::Loads)
                .after(apply_body_force::<D>)
                .after(apply_point_loads::<D>),
            update_traction_points::<D>
                .in_set(StepSystems::UpdatePoints)
                .after(update_points::<D>),
        ));
    }
    if effects.prescribed_displacements {
        schedule.add_systems(
            apply_prescribed_displacements::<D>
                .in_set(StepSystems::Loads)
                .after(apply_body_force::<D>)
                .after(apply_point_loads::<D>)
                .after(apply_tractions::<D>),
        );
    }
    schedule.add_systems(solve_load_step.in_set(StepSystems::Solve));
    schedule.add_systems(update_points::<D>.in_set(StepSystems::UpdatePoints));
    if effects.stress_recovery {
        schedule.add_systems(
            recover_stress::<D>
                .in_set(StepSystems::Output)
                .before(run_output),
        );
    }
    schedule.add_systems(run_output.in_set(StepSystems::Output));
    schedule.add_systems(reset_grid::<D>.in_set(StepSystems::ResetGrid));
    schedule
}

/// The output schedule for dimension `D`: points, grid (the deformed mesh for FEM), nodes, and
/// the traction points in scenes with tractions.
pub fn output_schedule<const D: usize>(effects: Effects) -> Schedule {
    let mut schedule = strict(WriteOutput);
    if effects.fem_mesh {
        schedule.add_systems(
            (
                output::write_particles::<D>,
                write_mesh::<D>,
                output::write_nodes::<D>,
            )
                .chain()
                .in_set(BuiltInOutput)
                .distributive_run_if(no_failure),
        );
    } else {
        schedule.add_systems(
            (
                output::write_particles::<D>,
                output::write_grid::<D>,
                output::write_nodes::<D>,
            )
                .chain()
                .in_set(BuiltInOutput)
                .distributive_run_if(no_failure),
        );
    }
    if effects.tractions {
        schedule.add_systems(
            output::write_tractions::<D>
                .after(output::write_nodes::<D>)
                .in_set(BuiltInOutput)
                .run_if(no_failure),
        );
    }
    schedule
}

/// Runs the output schedule (exclusive, so that user systems added to it see the whole world).
pub fn run_output(world: &mut World) {
    world.run_schedule(WriteOutput);
}

/// The Newton-iteration schedule for dimension `D`.
pub fn newton_schedule<const D: usize>(effects: Effects) -> Schedule {
    let mut schedule = strict(NewtonIteration);
    schedule.configure_sets(
        (
            NewtonSystems::StressUpdate,
            NewtonSystems::Assembly,
            NewtonSystems::Convergence,
            NewtonSystems::LinearSolve,
        )
            .chain()
            .distributive_run_if(no_failure),
    );
    schedule.add_systems((
        update_stress::<D>.in_set(NewtonSystems::StressUpdate),
        assemble::<D>.in_set(NewtonSystems::Assembly),
        check_convergence::<D>.in_set(NewtonSystems::Convergence),
        solve_linear_system::<D>
            .in_set(NewtonSystems::LinearSolve)
            .run_if(not_converged),
    ));
    if effects.ghost_penalty {
        schedule.add_systems(
            ghost::assemble_ghost_penalty::<D>
                .in_set(NewtonSystems::Assembly)
                .after(assemble::<D>),
        );
    }
    schedule
}

fn not_converged(newton: Res<Newton>, settings: Res<NewtonSettings>) -> bool {
    !newton.converged && newton.iterations < settings.max_iterations
}
