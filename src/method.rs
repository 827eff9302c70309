//! The method on one page: what one load step does, in the order the paper states it.
//!
//! ```text
//! for each load step n -> n+1 (load factor λ_n -> λ_{n+1}):           StepSchedule
//!   1. Connectivity   basis N_i(x_p), ∇N_i at the step start; active nodes   (Hook::Basis, Hook::Connectivity)
//!   2. Dofs           constrained components, then DOF numbers and the sparsity pattern (Hook::Constraints, Hook::AfterDofs)
//!   3. Loads          f_ext at λ_{n+1}; prescribed increments                (Hook::Loads)
//!   4. Solve          Newton until ‖f_ext − f_int‖ is small:                NewtonSchedule (Hook::BeforeSolve before it)
//!        a. StressUpdate   Δf, F = Δf F^n, τ and its tangent per point     (Hook::Kinematics before it: what the material sees;
//!                                                                           Hook::StressUpdate: one system per material kind)
//!        b. Assembly       f_int = Σ_p V0 τ g_i, consistent K              (Hook::BeforeAssembly, Hook::AfterAssembly;
//!                                                                           Hook::Combine: the processes' sums, distributed runs)
//!        c. Convergence    r = f_ext − f_int at the free DOFs (Hook::Convergence: a module may
//!                          overrule the verdict; the line search shortens a trial step that does
//!                          not reduce ‖r‖ enough, evaluated again without a solve)
//!        d. LinearSolve    K δ = r, Δu += δ                                   (Hook::AfterLinearSolve:
//!                                                                           e.g. arc-length's load-factor correction)
//!   5. UpdatePoints   G2P: x_p, u_p, F_p, V_p (paper eq. 10): the step is committed (Hook::PointUpdate, Hook::AfterStep)
//!   6. Output         VTK files of the converged state                   OutputSchedule (Hook::PointFields, Hook::GridOutput, Hook::Output)
//!   7. ResetGrid      the grid forgets the step: back to its undeformed state
//! ```
//!
//! When an attempt fails (Newton does not converge, an inverted point, a singular tangent) the
//! driver runs [`RollbackSchedule`] (the grid is reset; points were not touched) and asks the
//! load-step control policy (`control.rs`, step cutting) what to try next.
//!
//! This file holds only the fixed core: the stages (system sets) in order, the core systems in
//! them, and where the [`Hook`]s sit. Every optional effect (loads, constraints, tractions,
//! GIMP/CPDI/FEM connectivity, ghost penalty, stress recovery) and every material is a module
//! that adds its systems at a hook (`effects/`, `material/`, through `plugin::Extension`), so
//! the core never names them. Two stages have a default that a module may replace: the basis
//! evaluation (point basis; replaced by GIMP/CPDI/domain-averaged B-splines or the FEM
//! element basis) and the grid output (the background grid; replaced by the FEM mesh).
//!
//! Schedules are single-threaded and any ambiguity in system order is an error: the result
//! must not depend on chance ordering. Every set after a failure is skipped (`no_failure`).

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{
    InternedScheduleLabel, LogLevel, ScheduleBuildSettings, ScheduleLabel, SingleThreadedExecutor,
};

use crate::resources::{LoadStep, Newton, NewtonSettings, RunStatus, SolverError, no_failure};
use crate::stages::line_search;
use crate::stages::output::writes_output;
use crate::stages::{
    assemble, check_convergence, evaluate_basis, number_dofs, reset_grid, solve_linear_system,
    update_points, write_grid, write_nodes, write_particles,
};

/// The schedule of one load step (or one attempt at it, when the step is cut).
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct StepSchedule;

/// The schedule of one Newton iteration, run repeatedly by [`solve_load_step`].
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct NewtonSchedule;

/// The output schedule: run after a completed step, and by the driver for the initial state.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct OutputSchedule;

/// Run by the driver after a failed attempt, before the next one: undo what the attempt left.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct RollbackSchedule;

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

/// Where modules (built-in effects, materials, your plugins) add their systems.
///
/// | hook | schedule, place | built-in users |
/// |------|-----------------|----------------|
/// | `Basis` | step, connectivity: the one system that evaluates the basis at the points | point basis (default), point domains (GIMP, CPDI, domain-averaged B-splines), FEM elements |
/// | `Connectivity` | step, connectivity, after the basis; node groups coupled in the tangent (`GridFields::couplings`) | ghost faces, F-bar cells |
/// | `Constraints` | step, before DOF numbering: constrained components, extra couplings | grid constraints (`fix`, `displace`), weak nodes (which nodes, their masters) |
/// | `AfterDofs` | step, after DOF numbering, before the loads | arc-length control (the loads at λ = 1) |
/// | `Loads` | step, external forces and prescribed increments of the step | body force, point loads, tractions, prescribed displacements |
/// | `BeforeSolve` | step, after the loads, before the Newton iterations | arc-length control (keeps f̂) |
/// | `Kinematics` | Newton, before the stress update: the increment of deformation a material sees, when not the point's own (`components::ModifiedIncrement`), e.g. averaged over the points of a cell | F-bar |
/// | `StressUpdate` | Newton: trial stress and tangent of every point | one system per material kind |
/// | `BeforeAssembly` | Newton, after the stress update | (plugins) |
/// | `AfterAssembly` | Newton, after assembly: contributions to f_int and K, also blocks between the nodes of a coupling group | ghost penalty, F-bar, weak nodes (`K' = Tᵀ K T` after the others) |
/// | `Combine` | Newton, after all of assembly, before the convergence check; runs after a failure of the iteration too (every process must take part in collective operations) | distributed runs: the processes' sums of f_int, a failure on any process |
/// | `Convergence` | Newton, after the convergence check: may overrule the verdict | arc-length control (an iterate that went back along the path), the line search (accepts or shortens the iterate) |
/// | `AfterLinearSolve` | Newton, after the linear solve; runs in a converged iteration too, where no solve happened (`Newton::iterations` did not grow) | arc-length control (the load factor's correction), weak nodes (their increments from their masters') |
/// | `PointUpdate` | step, after the G2P update: state that follows the material | traction points, FEM mesh, material history |
/// | `AfterStep` | step, after the point update, before output | stress recovery |
/// | `PointFields` | output, before the particle file: extra point fields | point loads, stress recovery |
/// | `GridOutput` | output: the grid file | background grid (default), FEM mesh |
/// | `Output` | output, after the built-in files | traction points |
/// | `Rollback` | rollback, after a failed attempt | grid reset (core) |
///
/// Systems added to one hook run in the order they were added (each `add_systems` call after
/// the previous one); systems added in one call must be ordered among themselves where they
/// conflict, or the schedule does not build.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Hook {
    Basis,
    Connectivity,
    Constraints,
    AfterDofs,
    Loads,
    BeforeSolve,
    Kinematics,
    StressUpdate,
    BeforeAssembly,
    AfterAssembly,
    Combine,
    Convergence,
    AfterLinearSolve,
    PointUpdate,
    AfterStep,
    PointFields,
    GridOutput,
    Output,
    Rollback,
}

impl Hook {
    pub const ALL: [Hook; 19] = [
        Hook::Basis,
        Hook::Connectivity,
        Hook::Constraints,
        Hook::AfterDofs,
        Hook::Loads,
        Hook::BeforeSolve,
        Hook::Kinematics,
        Hook::StressUpdate,
        Hook::BeforeAssembly,
        Hook::AfterAssembly,
        Hook::Combine,
        Hook::Convergence,
        Hook::AfterLinearSolve,
        Hook::PointUpdate,
        Hook::AfterStep,
        Hook::PointFields,
        Hook::GridOutput,
        Hook::Output,
        Hook::Rollback,
    ];

    /// The schedule the hook belongs to.
    pub fn schedule(self) -> InternedScheduleLabel {
        match self {
            Hook::Basis
            | Hook::Connectivity
            | Hook::Constraints
            | Hook::AfterDofs
            | Hook::Loads
            | Hook::BeforeSolve
            | Hook::PointUpdate
            | Hook::AfterStep => StepSchedule.intern(),
            Hook::Kinematics
            | Hook::StressUpdate
            | Hook::BeforeAssembly
            | Hook::AfterAssembly
            | Hook::Combine
            | Hook::Convergence
            | Hook::AfterLinearSolve => NewtonSchedule.intern(),
            Hook::PointFields | Hook::GridOutput | Hook::Output => OutputSchedule.intern(),
            Hook::Rollback => RollbackSchedule.intern(),
        }
    }

    /// Whether the hook's systems run after a stage of the iteration failed, too: those of
    /// `Combine`, where the processes of a distributed run meet (a process that skipped it
    /// would leave the others waiting), and share whether any of them failed.
    pub fn runs_after_failure(self) -> bool {
        matches!(self, Hook::Combine)
    }

    /// Whether exactly one module provides this stage (the core adds its default when none
    /// does): the basis evaluation and the grid file.
    pub fn is_replaceable_default(self) -> bool {
        matches!(self, Hook::Basis | Hook::GridOutput)
    }
}

/// Adds the core schedules for dimension `D` to `world`: the stages in order, the core
/// systems, and every hook set in its place (empty until modules add to it).
pub fn add_core_schedules<const D: usize>(world: &mut World) {
    world.add_schedule(step_schedule::<D>());
    world.add_schedule(newton_schedule::<D>());
    world.add_schedule(output_schedule::<D>());
    world.add_schedule(rollback_schedule::<D>());
}

fn step_schedule<const D: usize>() -> Schedule {
    use StepSystems::*;
    let mut schedule = strict(StepSchedule);
    schedule.configure_sets(
        (
            Connectivity,
            Dofs,
            Loads,
            Solve,
            UpdatePoints,
            Output,
            ResetGrid,
        )
            .chain()
            .distributive_run_if(no_failure),
    );
    schedule.configure_sets(
        (
            (Hook::Basis, Hook::Connectivity)
                .chain()
                .in_set(Connectivity),
            Hook::Constraints.in_set(Dofs).before(number_dofs::<D>),
            Hook::AfterDofs.in_set(Dofs).after(number_dofs::<D>),
            Hook::Loads.in_set(Loads),
            Hook::BeforeSolve.in_set(Solve).before(solve_load_step::<D>),
            (Hook::PointUpdate, Hook::AfterStep)
                .chain()
                .in_set(UpdatePoints)
                .after(update_points::<D>),
        )
            .distributive_run_if(no_failure),
    );
    schedule.add_systems((
        number_dofs::<D>.in_set(Dofs),
        solve_load_step::<D>.in_set(Solve),
        update_points::<D>.in_set(UpdatePoints),
        run_output.in_set(Output),
        reset_grid::<D>.in_set(ResetGrid),
    ));
    schedule
}

fn newton_schedule<const D: usize>() -> Schedule {
    use NewtonSystems::*;
    let mut schedule = strict(NewtonSchedule);
    schedule.configure_sets(
        (StressUpdate, Assembly, Convergence, LinearSolve)
            .chain()
            .distributive_run_if(no_failure),
    );
    schedule.configure_sets(
        (
            Hook::Kinematics.before(StressUpdate),
            Hook::StressUpdate.in_set(StressUpdate),
            Hook::BeforeAssembly.after(StressUpdate).before(Assembly),
            Hook::AfterAssembly.in_set(Assembly).after(assemble::<D>),
            Hook::Convergence
                .in_set(Convergence)
                .after(check_convergence::<D>),
            Hook::AfterLinearSolve
                .in_set(LinearSolve)
                .after(solve_linear_system::<D>),
        )
            .distributive_run_if(no_failure),
    );
    // not `no_failure`: see `Hook::runs_after_failure`
    schedule.configure_sets(Hook::Combine.after(Assembly).before(Convergence));
    schedule.add_systems((
        assemble::<D>.in_set(Assembly),
        check_convergence::<D>.in_set(Convergence),
        solve_linear_system::<D>
            .in_set(LinearSolve)
            .run_if(not_converged)
            .run_if(line_search::iterate_accepted),
    ));
    schedule
}

fn output_schedule<const D: usize>() -> Schedule {
    let mut schedule = strict(OutputSchedule);
    schedule.configure_sets(
        (
            Hook::PointFields,
            BuiltInOutput,
            Hook::GridOutput,
            Hook::Output,
        )
            .chain()
            .distributive_run_if(no_failure),
    );
    schedule.configure_sets(Hook::PointFields.run_if(writes_output));
    schedule.add_systems(
        (write_particles::<D>, write_nodes::<D>)
            .chain()
            .in_set(BuiltInOutput),
    );
    schedule
}

fn rollback_schedule<const D: usize>() -> Schedule {
    let mut schedule = strict(RollbackSchedule);
    schedule.add_systems(reset_grid::<D>.before(Hook::Rollback));
    schedule
}

/// The modules that provide a replaceable stage (`Hook::is_replaceable_default`), by hook.
#[derive(Resource, Default, Debug)]
pub struct Providers(pub Vec<(Hook, &'static str)>);

/// Adds the core's default for every replaceable stage no module provided (`Hook::Basis`: the
/// point basis of linear and B-spline MPM; `Hook::GridOutput`: the background grid file).
pub fn add_default_providers<const D: usize>(world: &mut World) {
    let provided = |world: &World, hook: Hook| {
        world
            .get_resource::<Providers>()
            .is_some_and(|p| p.0.iter().any(|(h, _)| *h == hook))
    };
    let basis = !provided(world, Hook::Basis);
    let grid_file = !provided(world, Hook::GridOutput);
    let mut schedules = world.resource_mut::<Schedules>();
    if basis {
        schedules
            .entry(StepSchedule)
            .add_systems(evaluate_basis::<D>.in_set(Hook::Basis));
    }
    if grid_file {
        schedules
            .entry(OutputSchedule)
            .add_systems(write_grid::<D>.in_set(Hook::GridOutput));
    }
}

/// Initialises every schedule of the method in `world`: an error says why one does not build
/// (e.g. two systems of a hook that write the same data, unordered).
pub fn initialize_schedules(world: &mut World) -> Result<(), String> {
    let labels = [
        StepSchedule.intern(),
        NewtonSchedule.intern(),
        OutputSchedule.intern(),
        RollbackSchedule.intern(),
    ];
    for label in labels {
        let built = world.try_schedule_scope(label, |world, schedule| {
            schedule.initialize(world).map_err(|error| {
                let why = error.to_string(schedule.graph(), world);
                format!("the {label:?} schedule does not build: {why}")
            })
        });
        // a schedule the world does not have is not checked
        if let Ok(result) = built {
            result?;
        }
    }
    Ok(())
}

/// The core's own output files (points and grid nodes).
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BuiltInOutput;

/// Schedule settings shared by all solver schedules: single-threaded, and any ambiguity in
/// system order is an error.
fn strict(label: impl ScheduleLabel) -> Schedule {
    let mut schedule = Schedule::new(label);
    schedule.set_build_settings(ScheduleBuildSettings {
        ambiguity_detection: LogLevel::Error,
        ..Default::default()
    });
    schedule.set_executor(SingleThreadedExecutor::new());
    schedule
}

/// Stage 4: runs Newton iterations until converged, failed, or out of iterations
/// (exclusive, so that it can run the Newton schedule). With a line search
/// (`stages::line_search`) a rejected trial step is evaluated again shorter, without a solve.
pub fn solve_load_step<const D: usize>(world: &mut World) {
    world.resource_mut::<Newton>().begin_step();
    line_search::begin_step(world);
    loop {
        let before = world.resource::<Newton>().iterations;
        world.run_schedule(NewtonSchedule);
        if world.resource::<RunStatus>().0.is_some() {
            if line_search::retry_after_failure::<D>(world) {
                continue;
            }
            return;
        }
        let newton = world.resource::<Newton>();
        if newton.converged {
            return;
        }
        if line_search::is_backtracking(world) {
            continue;
        }
        if newton.iterations == before {
            // No solve happened: out of iterations.
            let error = SolverError::NotConverged {
                step: world.resource::<LoadStep>().number,
                residuals: newton.residuals.clone(),
                tolerance: world.resource::<NewtonSettings>().tolerance,
            };
            world.resource_mut::<RunStatus>().fail(error);
            return;
        }
    }
}

/// Stage 6: runs the output schedule (exclusive, so that output systems see the whole world).
pub fn run_output(world: &mut World) {
    world.run_schedule(OutputSchedule);
}

fn not_converged(newton: Res<Newton>, settings: Res<NewtonSettings>) -> bool {
    !newton.converged && newton.iterations < settings.max_iterations
}
