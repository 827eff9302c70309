//! The solver stages as ECS systems, and the schedules that order them.
//!
//! One load step runs the [`LoadStep`] schedule, whose system sets run in this order:
//!
//! 1. [`StepSystems::Connectivity`] — evaluate the basis at the points (P2G connectivity) and
//!    mark the active nodes (`connectivity.rs`).
//! 2. [`StepSystems::Dofs`] — number the free components of active nodes and build the sparsity
//!    pattern of the step (`dofs.rs`).
//! 3. [`StepSystems::Loads`] — external forces and prescribed displacement increments, only the
//!    ones the scene uses (`loads.rs`).
//! 4. [`StepSystems::Solve`] — the Newton loop: an exclusive system that runs the
//!    [`NewtonIteration`] schedule until converged (`newton.rs`).
//! 5. [`StepSystems::UpdatePoints`] — G2P: move points, update F, volume (paper eq. 10,
//!    `update.rs`).
//! 6. [`StepSystems::Output`] — run the [`WriteOutput`] schedule (VTK files, `output.rs`).
//! 7. [`StepSystems::ResetGrid`] — clear the grid fields (`reset.rs`).
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
mod explain;
mod loads;
mod newton;
pub mod output;
mod reset;
mod stress;
mod tractions;
mod update;

pub use assembly::assemble;
pub use connectivity::evaluate_basis;
pub use dofs::number_dofs;
pub use explain::{Explanation, ScheduledSystem, explain_scene, scheduled_systems};
pub use loads::{
    apply_body_force, apply_point_loads, apply_prescribed_displacements, spread_force,
};
pub use newton::{check_convergence, solve_linear_system, solve_load_step};
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
}

impl Effects {
    /// Every effect on: the schedules with every optional system (for `--explain` and
    /// benchmarks).
    pub const ALL: Effects = Effects {
        body_force: true,
        point_loads: true,
        tractions: true,
        prescribed_displacements: true,
    };

    /// `(name, used)` for every effect.
    pub fn list(&self) -> [(&'static str, bool); 4] {
        [
            ("body force", self.body_force),
            ("point loads", self.point_loads),
            ("tractions", self.tractions),
            ("prescribed displacements", self.prescribed_displacements),
        ]
    }
}

/// Adds the solver's schedules for dimension `D` with only the effects in use to `world`.
pub fn add_schedules<const D: usize>(world: &mut World, effects: Effects) {
    world.add_schedule(load_step_schedule::<D>(effects));
    world.add_schedule(newton_schedule::<D>());
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
            .run_if(no_failure),
    );
    schedule.add_systems(evaluate_basis::<D>.in_set(StepSystems::Connectivity));
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
    schedule.add_systems(run_output.in_set(StepSystems::Output));
    schedule.add_systems(reset_grid::<D>.in_set(StepSystems::ResetGrid));
    schedule
}

/// The output schedule for dimension `D`, with the files of the effects in use.
pub fn output_schedule<const D: usize>(effects: Effects) -> Schedule {
    let mut schedule = strict(WriteOutput);
    schedule.add_systems(
        (output::write_particles::<D>, output::write_grid::<D>)
            .chain()
            .run_if(no_failure),
    );
    if effects.tractions {
        schedule.add_systems(
            output::write_tractions::<D>
                .after(output::write_grid::<D>)
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
pub fn newton_schedule<const D: usize>() -> Schedule {
    let mut schedule = strict(NewtonIteration);
    schedule.configure_sets(
        (
            NewtonSystems::StressUpdate,
            NewtonSystems::Assembly,
            NewtonSystems::Convergence,
            NewtonSystems::LinearSolve,
        )
            .chain()
            .run_if(no_failure),
    );
    schedule.add_systems((
        update_stress::<D>.in_set(NewtonSystems::StressUpdate),
        assemble::<D>.in_set(NewtonSystems::Assembly),
        check_convergence::<D>.in_set(NewtonSystems::Convergence),
        solve_linear_system::<D>
            .in_set(NewtonSystems::LinearSolve)
            .run_if(not_converged),
    ));
    schedule
}

fn not_converged(newton: Res<Newton>, settings: Res<NewtonSettings>) -> bool {
    !newton.converged && newton.iterations < settings.max_iterations
}
