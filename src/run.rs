//! Running a scene: the world is built from the scene and the modules it uses, then the driver
//! runs its load steps with the load-step control policy and keeps the records.
//!
//! ```text
//! build world: grid nodes, material points, core resources, the method's schedules   Simulation::new
//!              + every module the scene uses (materials, loads, constraints...)
//! write the initial state                                                           write_initial_state
//! for each load step: attempts as the control policy says (control.rs),             step
//!     each attempt runs the step schedule (method.rs); a failed one is rolled back
//!     records: iterations, residuals, cuts, stage times, eq. 15 error, measures   -> summary.json
//!     a checkpoint after every output step (or every N steps), if the run keeps them
//!                                                                   -> checkpoint.json + .bin (restart.rs)
//! ```
//!
//! A run that resumes (`impm run SCENE --resume OUT_DIR`) builds the same world, restores the
//! checkpoint's state, records and series instead of writing the initial state, removes the
//! files of steps after it, and goes on from the step after the checkpoint
//! ([`Simulation::resume_from`]).

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::time::Instant;

use bevy_ecs::prelude::*;
use nalgebra::{SMatrix, SVector};

use crate::basis::GridBasis;
use crate::checkpoint::{self, CheckpointPart, CheckpointParts, CheckpointSeries, SavedState};
use crate::components::*;
use crate::control::{Attempt, LoadStepControl, StepCutting};
use crate::distributed::migration::PointRecord;
use crate::effects;
use crate::method::{
    OutputSchedule, RollbackSchedule, StepSchedule, add_core_schedules, add_default_providers,
    initialize_schedules,
};
pub use crate::plugin::BuildError;
use crate::plugin::{Module, ModuleSet, Plugin, build_plugin};
use crate::records::{MeasuredValues, StepMeasures, StepRecord, Summary, step_from_json};
use crate::resources::*;
use crate::restart::{Checkpoint, RunIdentity};
use crate::scene::{SceneSpec, Stages};
use crate::stages::arc_length::{ArcControlState, ArcLength, ArcLengthControl, ArcLengthSpec};
use crate::stages::line_search::LineSearch;
use crate::stages::output::{OutputPlan, PointFields};

/// A simulation of dimension `D`: the world and its schedules.
pub struct Simulation<const D: usize> {
    pub world: World,
    /// The scene without its point seeds ([`SceneSpec::without_point_seeds`]): once spawned,
    /// the points live only in the world (their components), so a plugin added later
    /// ([`Simulation::add_plugin`]) reads them there, not from `spec.bodies`.
    pub spec: SceneSpec,
    pub summary: Summary,
    steps_done: usize,
    control: Box<dyn LoadStepControl>,
    /// Arc-length control (`stages::arc_length`), when the scene asks for it: then the load
    /// factor of each step is an unknown, and `control` is not used.
    arc: Option<ArcLengthControl>,
    restart: Option<RestartPlan>,
}

/// How a run keeps checkpoints (see [`crate::restart`]).
#[derive(Clone, Debug)]
pub struct RestartPlan {
    /// The scene file and overrides the run is made of (checked when it is resumed).
    pub identity: RunIdentity,
    /// A checkpoint every this many steps (and after the last); `None`: after every output
    /// step.
    pub every: Option<usize>,
    /// The command that resumes the run, for the messages and `summary.json`.
    pub command: String,
}

impl<const D: usize> Simulation<D> {
    /// Builds the world for `spec` with the built-in modules, writing results to `out_dir`.
    pub fn new(spec: &SceneSpec, out_dir: &Path) -> Result<Self, BuildError> {
        Self::with_modules(spec, out_dir, &effects::built_in())
    }

    /// Builds the world for `spec` with the modules of `modules` that the scene uses.
    pub fn with_modules(
        spec: &SceneSpec,
        out_dir: &Path,
        modules: &ModuleSet,
    ) -> Result<Self, BuildError> {
        Self::with_modules_where(spec, out_dir, modules, &|module| module.used_by(spec))
    }

    /// Builds the world for `spec` with the modules for which `include` holds (`impm check
    /// --explain` and the effects benchmark also build modules a scene does not use).
    pub fn with_modules_where(
        spec: &SceneSpec,
        out_dir: &Path,
        modules: &ModuleSet,
        include: &dyn Fn(&dyn Module) -> bool,
    ) -> Result<Self, BuildError> {
        // before any point is spawned: a decomposed run spawns only its own
        #[cfg(feature = "mpi")]
        if let Some(why) = effects::distributed::decomposition::refusal(spec) {
            return Err(BuildError(why));
        }
        let mut world = core_world::<D>(spec, out_dir)?;
        modules.check_materials(spec)?;
        std::fs::create_dir_all(out_dir).map_err(|e| {
            BuildError(format!(
                "cannot create the output folder {}: {e}",
                out_dir.display()
            ))
        })?;
        for module in modules.iter().filter(|&m| include(m)) {
            module.build_into(&mut world, spec)?;
        }
        add_default_providers::<D>(&mut world);
        let points = spec.point_count();
        let active = world.resource::<GridFields<D>>().active.len();
        Ok(Self {
            world,
            spec: spec.without_point_seeds(),
            summary: Summary::new(spec, points, active, out_dir),
            steps_done: 0,
            control: Box::new(StepCutting::new(spec.solver.max_step_cuts)),
            arc: spec.part::<ArcLengthSpec>().map(|arc| {
                let first = arc.first_factor(&spec.load_factors);
                ArcLengthControl::new(*arc, spec.solver.max_step_cuts, first)
            }),
            restart: None,
        })
    }

    /// Adds a plugin's systems and resources, and checks that the schedules still build.
    pub fn add_plugin(&mut self, plugin: &impl Plugin) -> Result<(), BuildError> {
        build_plugin::<D>(plugin, &mut self.world, &self.spec)?;
        initialize_schedules(&mut self.world)
            .map_err(|why| BuildError(format!("a plugin's systems do not fit: {why}")))
    }

    /// The state after the last completed step: enough to continue the run exactly in a new
    /// simulation of the same scene ([`Simulation::restore_state`]).
    pub fn save_state(&mut self) -> SavedState {
        self.share_arc_control();
        SavedState {
            steps_done: self.steps_done,
            parts: checkpoint::save_parts(&mut self.world),
        }
    }

    /// Restores a state saved from a simulation of the same scene (with the same modules):
    /// the next step is the one after `saved.steps_done`.
    pub fn restore_state(&mut self, saved: &SavedState) -> Result<(), String> {
        self.restore_state_except(saved, &[])
    }

    /// [`Simulation::restore_state`] but for the parts named in `carried`, which `saved` leaves
    /// out (a checkpoint in pieces: the points' records carry them).
    fn restore_state_except(
        &mut self,
        saved: &SavedState,
        carried: &[String],
    ) -> Result<(), String> {
        if saved.steps_done > self.spec.load_factors.len() {
            return Err(format!(
                "the saved state is after step {} but the scene has {} steps",
                saved.steps_done,
                self.spec.load_factors.len()
            ));
        }
        checkpoint::restore_parts_except(&mut self.world, &saved.parts, carried)?;
        if let Some(arc) = &mut self.arc {
            let state = self
                .world
                .remove_resource::<ArcControlState>()
                .ok_or("the saved state has no arc-length step policy")?;
            arc.restore(&state.0)?;
        }
        self.steps_done = saved.steps_done;
        Ok(())
    }

    /// Puts the arc-length step policy's state (kept here, not in the world) where the arc
    /// module's checkpoint part saves it.
    fn share_arc_control(&mut self) {
        if let Some(arc) = &self.arc {
            self.world.insert_resource(ArcControlState(arc.state()));
        }
    }

    /// Keeps checkpoints as `plan` says (after the initial state and then after every output
    /// step or every N steps); `summary.json` says how to resume.
    pub fn keep_checkpoints(&mut self, plan: RestartPlan) {
        self.summary.resume = Some(plan.command.clone());
        self.restart = Some(plan);
    }

    /// Whether a checkpoint is due after the steps done so far.
    fn checkpoint_due(&self) -> bool {
        let Some(plan) = &self.restart else {
            return false;
        };
        let done = self.steps_done;
        match plan.every {
            Some(every) => {
                done.is_multiple_of(every.max(1)) || done == self.spec.load_factors.len()
            }
            None => self.world.resource::<OutputPlan>().writes(&LoadStep {
                number: done,
                completes_step: true,
                ..LoadStep::default()
            }),
        }
    }

    /// Writes the checkpoint of the steps done so far, if the run keeps checkpoints ([`run`]
    /// does after the steps its plan says; a program that drives the steps itself with
    /// [`Simulation::step`] may call it after any step).
    ///
    /// [`run`]: Simulation::run
    pub fn write_checkpoint(&mut self) -> Result<(), SolverError> {
        let Some(plan) = self.restart.as_ref() else {
            return Ok(());
        };
        let identity = plan.identity.clone();
        // with decomposed points every process's points, on process 0 (the others write none)
        // (over several processes each has written its piece, and process 0 writes the rest)
        #[cfg(feature = "mpi")]
        let saved = {
            self.share_arc_control();
            effects::distributed::checkpoint::saved_parts_of_every_point::<D>(
                &mut self.world,
                self.steps_done,
            )?
        };
        #[cfg(not(feature = "mpi"))]
        let saved = Some((self.save_state().parts, None));
        let Some((parts, pieces)) = saved else {
            return Ok(());
        };
        let checkpoint = Checkpoint {
            identity,
            steps_done: self.steps_done,
            parts,
            series: checkpoint::save_series(&mut self.world),
            steps: self.summary.steps_json(),
            warnings: self.summary.warnings.clone(),
            pieces,
        };
        let dir = self.world.resource::<OutputPlan>().dir.clone();
        checkpoint.write(&dir).map_err(|why| SolverError::Output {
            step: self.steps_done,
            why,
        })
    }

    /// Continues a run from its checkpoint instead of writing the initial state: restores the
    /// points and every module's state, the records (`summary.json`, `history.csv`) and the
    /// `.pvd` series, and removes the files of the steps after the checkpoint.
    pub fn resume_from(&mut self, checkpoint: Checkpoint) -> Result<(), String> {
        let carried = checkpoint
            .pieces
            .as_ref()
            .map(|pieces| pieces.carried.clone())
            .unwrap_or_default();
        self.restore_state_except(
            &SavedState {
                steps_done: checkpoint.steps_done,
                parts: checkpoint.parts,
            },
            &carried,
        )?;
        // a decomposed run restored every point, or none from a checkpoint in pieces: each
        // process keeps (or reads) its slab's
        #[cfg(feature = "mpi")]
        effects::distributed::checkpoint::keep_own_points::<D>(
            &mut self.world,
            checkpoint.pieces.as_ref(),
        )?;
        let mut measures: Vec<String> = self
            .world
            .get_resource::<StepMeasures>()
            .map(|m| m.0.iter().map(|(name, _)| name.clone()).collect())
            .unwrap_or_default();
        // the steps of a checkpoint of another kind of run (serial, replicated, decomposed)
        // keep their measures
        for name in crate::distributed::run_measures() {
            if !measures.iter().any(|taken| taken == name) {
                measures.push(name.to_string());
            }
        }
        self.summary.steps = checkpoint
            .steps
            .iter()
            .map(|step| step_from_json(step, &measures))
            .collect::<Result<_, _>>()
            .map_err(|why| format!("the checkpoint's records: {why}"))?;
        self.summary.warnings = checkpoint.warnings;
        let dir = self.world.resource::<OutputPlan>().dir.clone();
        crate::output::clear_after_step(&dir, checkpoint.steps_done).map_err(|e| {
            format!(
                "cannot remove the files of the steps after the checkpoint from {}: {e}",
                dir.display()
            )
        })?;
        checkpoint::restore_series(&mut self.world, &checkpoint.series)?;
        self.summary.write()?;
        self.summary.write_history()
    }

    /// Number of load steps done.
    pub fn steps_done(&self) -> usize {
        self.steps_done
    }

    /// Writes the initial state (step 0) and the summary.
    pub fn write_initial_state(&mut self) -> Result<(), SolverError> {
        *self.world.resource_mut::<LoadStep>() = LoadStep::default();
        self.world.run_schedule(OutputSchedule);
        self.take_failure()?;
        self.summary
            .write()
            .map_err(|e| SolverError::Output { step: 0, why: e })?;
        self.write_checkpoint()
    }

    /// Solves the next load step with the attempts the control policy asks for (see
    /// `control.rs`); on failure the error is also recorded in the summary.
    pub fn step(&mut self) -> Result<&StepRecord, SolverError> {
        let number = self.steps_done + 1;
        if self.arc_controls(number) {
            return self.arc_length_step();
        }
        let target = self.spec.load_factors[number - 1];
        // a stage's schedule starts from λ = 0 (`scene::stages`)
        let (stage, starts_stage) = self.begin_stage(number);
        let start = match number {
            1 => 0.0,
            _ if starts_stage => 0.0,
            n => self.spec.load_factors[n - 2],
        };
        *self.world.resource_mut::<StageClock>() = StageClock::default();
        let clock = Instant::now();
        let mut record = StepRecord::new(number, target);
        record.stage = self.stage_record(stage);
        let mut attempt = self.control.begin(start, target);
        loop {
            match self.attempt(number, attempt, &mut record) {
                Ok(()) => match self.control.succeeded(attempt) {
                    Some(next) => attempt = next,
                    None => break,
                },
                Err(e) => match self.control.failed(attempt, e.is_recoverable_by_cutting()) {
                    Some(next) => {
                        self.world.run_schedule(RollbackSchedule);
                        attempt = next;
                    }
                    None => {
                        let cuts = self.control.cuts();
                        return Err(self.fail_step(record, e, clock, cuts));
                    }
                },
            }
        }
        record.cuts = self.control.cuts();
        self.complete_step(record, clock)
    }

    /// The stage of load step `number` and whether the step starts it (stage 0 and whether it
    /// is step 1 in a scene without stages).
    fn stage_of(&self, number: usize) -> (usize, bool) {
        self.spec
            .part::<Stages>()
            .map_or((0, number == 1), |stages| stages.of_step(number))
    }

    /// Whether arc-length control solves load step `number`: every step of a scene that asks
    /// for it, the steps of the arc-controlled stage of a staged scene (the last stage; the
    /// stages before it are load-controlled).
    fn arc_controls(&self, number: usize) -> bool {
        self.arc
            .as_ref()
            .is_some_and(|arc| number >= arc.spec.first_step)
    }

    /// Sets the stage of load step `number` for the step's systems and, at a stage's first
    /// step, measures the displacements from its start if it asks for that; returns the stage
    /// and whether the step starts it.
    fn begin_stage(&mut self, number: usize) -> (usize, bool) {
        let (stage, starts_stage) = self.stage_of(number);
        self.world.resource_mut::<CurrentStage>().0 = stage;
        if starts_stage
            && self
                .spec
                .part::<Stages>()
                .is_some_and(|stages| stages.zeroes_displacements(stage))
        {
            effects::stages::zero_displacements::<D>(&mut self.world);
        }
        (stage, starts_stage)
    }

    /// The stage's index and name for the step's record (none in a scene without stages).
    fn stage_record(&self, stage: usize) -> Option<(usize, String)> {
        self.spec
            .part::<Stages>()
            .map(|stages| (stage, stages.name(stage).to_string()))
    }

    /// Records a converged step (at the load factor of its record) and writes the records.
    fn complete_step(
        &mut self,
        mut record: StepRecord,
        clock: Instant,
    ) -> Result<&StepRecord, SolverError> {
        let number = record.step;
        let factor = record.load_factor;
        record.seconds = self.world.resource::<StageClock>().clone();
        record.wall_seconds = clock.elapsed().as_secs_f64();
        record.error = self.analytic_error(factor);
        record.measures = self.measures(factor);
        self.steps_done = number;
        self.summary.push(record);
        self.take_warnings();
        self.summary
            .write()
            .and_then(|()| self.summary.write_history())
            .map_err(|e| SolverError::Output {
                step: number,
                why: e,
            })?;
        #[allow(clippy::expect_used, reason = "the step's record was pushed above")]
        let record = self.summary.steps.last().expect("just pushed");
        Ok(record)
    }

    /// A load step under arc-length control (`stages::arc_length`): attempts on the arc from
    /// the last converged point, the arc halved after a failure; the step's load factor is the
    /// one it converged at.
    fn arc_length_step(&mut self) -> Result<&StepRecord, SolverError> {
        let number = self.steps_done + 1;
        // in a staged scene, the arc-controlled stage (its λ from 0, the earlier stages' loads
        // held: `effects::arc_length`)
        let (stage, _) = self.begin_stage(number);
        *self.world.resource_mut::<StageClock>() = StageClock::default();
        let clock = Instant::now();
        let start = self.arc_control().begin();
        let mut record = StepRecord::new(number, start);
        record.stage = self.stage_record(stage);
        loop {
            let (start, radius, first) = self.arc_control().begin_attempt();
            {
                let mut arc = self.world.resource_mut::<ArcLength<D>>();
                arc.first_increment = first;
                arc.begin_attempt(start, radius);
            }
            let attempt = Attempt {
                from: start,
                to: start,
                completes_step: true,
            };
            match self.attempt(number, attempt, &mut record) {
                Ok(()) => break,
                Err(e) => {
                    let recoverable = e.is_recoverable_by_cutting();
                    if self.arc_control().failed(recoverable) {
                        self.world.run_schedule(RollbackSchedule);
                    } else {
                        let cuts = self.arc_control().cuts();
                        return Err(self.fail_step(record, e, clock, cuts));
                    }
                }
            }
        }
        // (collective on a grid split among processes: Δu_{n−1} kept whole)
        let accepted = self
            .world
            .resource_scope(|world, mut arc: Mut<ArcLength<D>>| {
                arc.accept(world.resource::<Newton>().shared_grid.as_deref())
            });
        if let Err(why) = accepted {
            let cuts = self.arc_control().cuts();
            let error = SolverError::Module {
                step: number,
                what: format!("arc-length control: summing over the processes: {why}"),
                recoverable: false,
            };
            return Err(self.fail_step(record, error, clock, cuts));
        }
        let (factor, radius, linearised, rebalancing) = {
            let arc = self.world.resource::<ArcLength<D>>();
            let rebalancing = arc.rebalanced.map_or(0, |r| r.iterations);
            (arc.factor, arc.radius, arc.linearised, rebalancing)
        };
        // the arc is sized by its own iterations, not those of the rebalancing before it
        let iterations = record
            .substeps
            .last()
            .map_or(0, |s| s.iterations.saturating_sub(rebalancing));
        let control = self.arc_control();
        control.succeeded(number, factor, iterations, radius, linearised);
        record.cuts = control.cuts();
        record.load_factor = factor;
        self.complete_step(record, clock)
    }

    fn arc_control(&mut self) -> &mut ArcLengthControl {
        #[allow(clippy::expect_used, reason = "called under arc-length control only")]
        self.arc.as_mut().expect("arc-length control")
    }

    /// Records a step that could not be solved, and the error to report.
    fn fail_step(
        &mut self,
        mut record: StepRecord,
        last: SolverError,
        clock: Instant,
        cuts: usize,
    ) -> SolverError {
        record.cuts = cuts;
        let error = if record.cuts > 0 && last.is_recoverable_by_cutting() {
            SolverError::CuttingFailed {
                step: record.step,
                cuts: record.cuts,
                last: Box::new(last),
            }
        } else {
            last
        };
        record.seconds = self.world.resource::<StageClock>().clone();
        record.wall_seconds = clock.elapsed().as_secs_f64();
        if let Some(arc) = &self.arc
            && record.step >= arc.spec.first_step
        {
            let on_plateau = self
                .world
                .get_resource::<ArcLength<D>>()
                .is_some_and(ArcLength::on_plateau);
            self.summary.arc_length = Some(failed_arc_length(arc, record.step, &error, on_plateau));
        }
        self.summary.fail(record, &error);
        let _ = self.summary.write();
        error
    }

    /// One attempt: the step schedule from `attempt.from` to `attempt.to`, recorded.
    fn attempt(
        &mut self,
        number: usize,
        attempt: Attempt,
        record: &mut StepRecord,
    ) -> Result<(), SolverError> {
        *self.world.resource_mut::<LoadStep>() = LoadStep {
            number,
            factor: attempt.to,
            previous_factor: attempt.from,
            completes_step: attempt.completes_step,
        };
        self.world.run_schedule(StepSchedule);
        let outcome = self.take_failure();
        let newton = self.world.resource::<Newton>();
        record.dofs = (newton.shared_grid.as_ref()).map_or(newton.matrix.size(), |g| g.dofs());
        record.multigrid = newton.solver.hierarchy();
        record.linear_backend = newton.solver.choice();
        let failure = outcome.as_ref().err().map(|e| e.to_string());
        // the load factor reached (arc-length control moves it inside the solve)
        let attempt = Attempt {
            to: self.world.resource::<LoadStep>().factor,
            ..attempt
        };
        record.add_attempt(
            &attempt,
            newton.iterations,
            &newton.residuals,
            &newton.linear_iterations,
            failure,
        );
        // taken, so that an attempt that fails before its Newton solve adds nothing
        if let Some(mut search) = self.world.get_resource_mut::<LineSearch>() {
            record.line_search.shortened += std::mem::take(&mut search.shortened);
            record.line_search.rejected += std::mem::take(&mut search.rejected);
        }
        outcome
    }

    /// Runs all remaining load steps, calling `on_step` after each. A stop asked between steps
    /// (a signal, the deadline or the step limit, see [`crate::interrupt`]) ends the run after
    /// the step in flight, with the summary's status saying why.
    pub fn run(&mut self, mut on_step: impl FnMut(&StepRecord)) -> Result<(), SolverError> {
        while self.steps_done < self.spec.load_factors.len() {
            // a signal or the deadline (agreed between the processes), or the step limit
            // (`--stop-after`: the same step on every process)
            let limit = crate::interrupt::step_limit_reached(self.steps_done)
                .then_some(crate::interrupt::StopReason::Interrupted);
            if let Some(reason) = crate::interrupt::agreed_stop_reason().or(limit) {
                self.summary.stop(reason.status());
                break;
            }
            let outcome = self.step_and_checkpoint(&mut on_step);
            self.agree_on(outcome)?;
            if self.arc.as_ref().is_some_and(|arc| arc.end().is_some()) {
                break;
            }
        }
        if let Some(arc) = &self.arc
            && self.steps_done >= arc.spec.first_step
        {
            self.summary.arc_length = Some(arc.to_json());
            let report = arc.report();
            let stalled = arc.stalled_warning();
            if arc.passed_peak() || arc.end().is_some() {
                use std::io::Write;
                let _ = writeln!(std::io::stderr(), "{report}");
            } else {
                self.world.resource_mut::<Warnings>().0.push(report);
            }
            if let Some(stalled) = stalled {
                self.world.resource_mut::<Warnings>().0.push(stalled);
            }
            self.take_warnings();
        }
        self.summary.finish();
        self.summary.write().map_err(|e| SolverError::Output {
            step: self.steps_done,
            why: e,
        })
    }

    /// The next load step, its records and, when due, its checkpoint.
    fn step_and_checkpoint(
        &mut self,
        on_step: &mut impl FnMut(&StepRecord),
    ) -> Result<(), SolverError> {
        on_step(self.step()?);
        if self.checkpoint_due() {
            self.write_checkpoint()?;
        }
        Ok(())
    }

    /// What the run did since the last load step, agreed between the processes of a
    /// distributed run (collective there: `effects::distributed::share_outcome`; a process that
    /// failed alone, e.g. writing a record, would leave the others waiting in their next
    /// collective call), and a failure recorded in the summary if the step's own record did
    /// not say it.
    fn agree_on(&mut self, outcome: Result<(), SolverError>) -> Result<(), SolverError> {
        #[cfg(feature = "mpi")]
        let outcome = effects::distributed::share_outcome(outcome, self.steps_done);
        if let Err(error) = &outcome
            && self.summary.status != "failed"
        {
            self.summary.status = "failed";
            self.summary.failure = Some(error.to_string());
            let _ = self.summary.write();
        }
        outcome
    }

    /// Moves the step's warnings into the summary and prints them on stderr (a closed or
    /// full stderr is ignored: `eprintln!` would panic).
    fn take_warnings(&mut self) {
        use std::io::Write;
        let warnings = std::mem::take(&mut self.world.resource_mut::<Warnings>().0);
        let mut err = std::io::stderr().lock();
        for warning in &warnings {
            let _ = writeln!(err, "warning: {warning}");
        }
        self.summary.warnings.extend(warnings);
    }

    fn take_failure(&mut self) -> Result<(), SolverError> {
        match self.world.resource_mut::<RunStatus>().0.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// The scene's analytic error measure (paper eq. 15) at load factor `factor`, if declared.
    pub fn analytic_error(&mut self, factor: f64) -> Option<f64> {
        let (column, axis) = self.spec.analytic.as_ref()?.column_at(factor);
        let mut query = self
            .world
            .query::<(&ReferencePosition<D>, &ReferenceVolume, &Trial<D>)>();
        let points: Vec<(f64, f64, f64)> = query
            .iter(&self.world)
            .map(|(x, v, t)| (x.0[axis], v.0, t.0.cauchy()[(axis, axis)]))
            .collect();
        // with decomposed points, the other processes' points too
        let mut sums = column.error_sums(points);
        crate::distributed::sum_over_points(&mut sums);
        Some(column.error_of_sums(sums))
    }

    /// The modules' measures at load factor `factor`.
    fn measures(&mut self, factor: f64) -> Vec<(String, f64)> {
        let Some(measures) = self.world.remove_resource::<StepMeasures>() else {
            return Vec::new();
        };
        self.world.insert_resource(MeasuredValues::default());
        for (name, measure) in &measures.0 {
            if let Some(value) = measure(&mut self.world, factor) {
                self.world
                    .resource_mut::<MeasuredValues>()
                    .0
                    .push((name.clone(), value));
            }
        }
        self.world.insert_resource(measures);
        std::mem::take(&mut self.world.resource_mut::<MeasuredValues>().0)
    }

    /// Points' (reference coordinate, Cauchy stress component) along `axis`, sorted by the
    /// reference coordinate. For tests and studies.
    pub fn stress_profile(&mut self, axis: usize) -> Vec<(f64, f64)> {
        let mut query = self.world.query::<(&ReferencePosition<D>, &Trial<D>)>();
        let mut out: Vec<(f64, f64)> = query
            .iter(&self.world)
            .map(|(x, t)| (x.0[axis], t.0.cauchy()[(axis, axis)]))
            .collect();
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }
}

/// `summary.json`'s `"arc_length"` entry of a run that failed at step `step` under arc-length
/// control: the control's record of its converged steps (the largest load factor, its step,
/// whether the load had passed it) with `"end": "failed"`, the failure, and a report that says
/// what the largest load factor is worth — the limit load only when the load had come down
/// from it before the failure.
fn failed_arc_length(
    arc: &ArcLengthControl,
    step: usize,
    failure: &SolverError,
    on_plateau: bool,
) -> serde_json::Value {
    let mut entry = arc.to_json();
    let report = match arc.peak() {
        None => {
            format!("arc-length control: the run failed at step {step} before any step converged")
        }
        Some((peak, at)) if on_plateau => format!(
            "arc-length control: the run failed at step {step} on a plateau: the load factor \
             stayed at its largest value, {peak:.6e} (step {at}), while the displacement grew, \
             so that value is the limit load; the plateau was not followed past it"
        ),
        Some((peak, at)) if arc.passed_peak() => format!(
            "arc-length control: the run failed at step {step} after passing the limit load; \
             the largest load factor of its converged steps was {peak:.6e} at step {at}"
        ),
        Some((peak, at)) => format!(
            "arc-length control: the run failed at step {step} before passing a limit load: \
             the largest load factor of its converged steps, {peak:.6e} at step {at}, was \
             still rising, so it is not the limit load"
        ),
    };
    entry["end"] = "failed".into();
    entry["failure"] = failure.to_string().into();
    entry["report"] = report.into();
    entry
}

/// The world of the fixed core: grid nodes, material points with their kinematic state, the
/// core resources and the method's schedules (no module yet).
fn core_world<const D: usize>(spec: &SceneSpec, out_dir: &Path) -> Result<World, BuildError> {
    if spec.dim() != D {
        return Err(BuildError(format!(
            "scene is {}D, simulation is {D}D",
            spec.dim()
        )));
    }
    let grid = &spec.grid;
    let basis = GridBasis::<D>::new(&grid.lower, &grid.upper, &grid.cells, grid.basis)
        .map_err(BuildError)?;
    let mut world = World::new();
    world.spawn_batch(
        (0..basis.num_nodes())
            .map(|index| GridNode {
                index,
                position: basis.node_position(index),
            })
            .collect::<Vec<_>>(),
    );
    spawn_points::<D>(&mut world, spec, &basis)?;
    world.insert_resource(GridFields::<D>::new(basis.num_nodes()));
    world.insert_resource(Grid(basis));
    world.insert_resource(LoadStep::default());
    world.insert_resource(CurrentStage::default());
    world.insert_resource(NewtonSettings {
        tolerance: spec.solver.tolerance,
        max_iterations: spec.solver.max_iterations,
        inexact: spec.solver.inexact,
        max_backtracks: spec.solver.max_backtracks,
    });
    world.insert_resource(Newton {
        solver: spec.solver.linear_solver(),
        ..Newton::default()
    });
    world.insert_resource(crate::stages::ColouringCache::default());
    world.insert_resource(Convergence::default());
    world.insert_resource(RunStatus::default());
    world.insert_resource(StageClock::default());
    world.insert_resource(PointFields::default());
    world.insert_resource(StepMeasures::default());
    world.insert_resource(Warnings::default());
    world.insert_resource(BodyNames(
        spec.bodies.iter().map(|body| body.name.clone()).collect(),
    ));
    let output = &spec.output;
    world.insert_resource(OutputPlan {
        steps: output.steps.clone(),
        fields: output.fields.clone(),
        grid_files: output.grid,
        ..OutputPlan::new(out_dir.to_path_buf(), output.every, spec.load_factors.len())
    });
    add_core_schedules::<D>(&mut world);
    world.insert_resource(CheckpointParts(vec![CheckpointPart {
        name: "points",
        save: save_points::<D>,
        restore: restore_points::<D>,
    }]));
    world.insert_resource(CheckpointSeries(vec![core_series]));
    Ok(world)
}

/// The core's series: particles, grid and nodes.
fn core_series(world: &mut World) -> Vec<&mut crate::output::PvdSeries> {
    let plan = world.resource_mut::<OutputPlan>().into_inner();
    vec![&mut plan.particles, &mut plan.grid, &mut plan.nodes]
}

/// The numbers of a point's state: x, u, F (row by row), V.
const fn point_record(dim: usize) -> usize {
    2 * dim + dim * dim + 1
}

/// The converged state of every point, in `PointId` order.
fn save_points<const D: usize>(world: &mut World) -> Vec<f64> {
    let mut query = world.query::<(
        &PointId,
        &Position<D>,
        &Displacement<D>,
        &DeformationGradient<D>,
        &Volume,
    )>();
    let mut rows: Vec<_> = query.iter(world).collect();
    rows.sort_by_key(|row| row.0.0);
    let mut values = Vec::with_capacity(rows.len() * point_record(D));
    for (_, x, u, f, v) in rows {
        values.extend(x.0.iter());
        values.extend(u.0.iter());
        values.extend(f.0.transpose().iter());
        values.push(v.0);
    }
    values
}

fn restore_points<const D: usize>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let mut query = world.query::<(
        &PointId,
        &mut Position<D>,
        &mut Displacement<D>,
        &mut DeformationGradient<D>,
        &mut Volume,
    )>();
    let count = query.iter(world).len();
    let records: Vec<&[f64]> = checkpoint::records(values, point_record(D), count)?.collect();
    for (id, mut x, mut u, mut f, mut v) in query.iter_mut(world) {
        let record = records[id.0 as usize];
        x.0 = SVector::from_column_slice(&record[..D]);
        u.0 = SVector::from_column_slice(&record[D..2 * D]);
        f.0 = SMatrix::from_row_slice(&record[2 * D..2 * D + D * D]);
        v.0 = record[2 * D + D * D];
    }
    Ok(())
}

/// Every body's points with the core's components, numbered body after body (`PointId`).
/// A process of a decomposed run spawns its slab's points only (`distributed::initial_points`).
fn spawn_points<const D: usize>(
    world: &mut World,
    spec: &SceneSpec,
    grid: &GridBasis<D>,
) -> Result<(), BuildError> {
    let kept = crate::distributed::initial_points(grid, spec);
    let mut id = 0u32;
    for (body_index, body) in spec.bodies.iter().enumerate() {
        let density = spec
            .materials
            .get(body.material)
            .ok_or_else(|| BuildError(format!("body '{}' names no material", body.name)))?
            .density;
        let mut batch = Vec::with_capacity(body.points.len());
        for seed in &body.points {
            if seed.position.len() != D {
                return Err(BuildError(format!(
                    "body '{}': point of dimension {}",
                    body.name,
                    seed.position.len()
                )));
            }
            if kept.as_ref().is_some_and(|kept| !kept[id as usize]) {
                id += 1;
                continue;
            }
            let x = SVector::<f64, D>::from_fn(|a, _| seed.position[a]);
            batch.push(core_point(&PointRecord {
                id,
                body: body_index as u32,
                position: x,
                reference_position: x,
                displacement: SVector::zeros(),
                deformation_gradient: SMatrix::identity(),
                mass: density * seed.volume,
                reference_volume: seed.volume,
                volume: seed.volume,
                history: Vec::new(),
            }));
            id += 1;
        }
        world.spawn_batch(batch);
    }
    if id == 0 {
        return Err(BuildError("the scene has no material points".into()));
    }
    Ok(())
}

/// Runs the scene script at `path` with `--set` overrides, in the scene language of the
/// built-in modules (`effects::built_in().load_scene(..)`; with modules of your own, use a
/// `ModuleSet`).
pub fn load_scene(
    path: &Path,
    overrides: &[(String, String)],
) -> Result<SceneSpec, crate::scene::SceneError> {
    effects::built_in().load_scene(path, overrides)
}

/// Runs a whole scene in dimension `spec.dim()`, writing to `out_dir` (with a plugin:
/// [`run_scene_with`]).
pub fn run_scene(
    spec: &SceneSpec,
    out_dir: &Path,
    on_step: impl FnMut(&StepRecord),
) -> Result<Summary, RunError> {
    run_scene_with(spec, out_dir, &(), on_step)
}

/// [`run_scene`] with a plugin: builds the simulation for the scene's dimension, adds the
/// plugin, writes the initial state and runs every load step.
pub fn run_scene_with(
    spec: &SceneSpec,
    out_dir: &Path,
    plugin: &impl Plugin,
    on_step: impl FnMut(&StepRecord),
) -> Result<Summary, RunError> {
    completed(run_scene_keeping_summary_with(
        spec, out_dir, plugin, on_step,
    ))
}

/// The summary of a completed run, or why it did not complete.
fn completed(
    (summary, result): (Option<Summary>, Result<(), RunError>),
) -> Result<Summary, RunError> {
    result?;
    summary.ok_or_else(|| RunError::Build(BuildError("the run produced no summary".into())))
}

/// Like [`run_scene`], but also returns the summary of a run that failed after it was built
/// (its completed steps and the failed one), as studies record failed runs.
pub fn run_scene_keeping_summary(
    spec: &SceneSpec,
    out_dir: &Path,
    on_step: impl FnMut(&StepRecord),
) -> (Option<Summary>, Result<(), RunError>) {
    run_scene_keeping_summary_with(spec, out_dir, &(), on_step)
}

/// [`run_scene_keeping_summary`] with a plugin (see [`crate::plugin`]).
pub fn run_scene_keeping_summary_with(
    spec: &SceneSpec,
    out_dir: &Path,
    plugin: &impl Plugin,
    on_step: impl FnMut(&StepRecord),
) -> (Option<Summary>, Result<(), RunError>) {
    run_with(
        Cow::Borrowed(spec),
        out_dir,
        &effects::built_in(),
        plugin,
        None,
        on_step,
    )
}

/// [`run_scene`] with the modules of `modules` (the built-in ones and your own, e.g. a
/// material model: `effects::built_in().with(MaterialModule::<YourModel>::default())`).
pub fn run_scene_with_modules(
    spec: &SceneSpec,
    out_dir: &Path,
    modules: &ModuleSet,
    on_step: impl FnMut(&StepRecord),
) -> Result<Summary, RunError> {
    completed(run_with(
        Cow::Borrowed(spec),
        out_dir,
        modules,
        &(),
        None,
        on_step,
    ))
}

/// [`run_scene_with_modules`] keeping checkpoints as `plan` says, and continuing from
/// `resume` (a checkpoint of this run read with [`Checkpoint::read`]) if given. The scene
/// may be given by value (`impm run` does): its point seeds, the largest part of it (~125 B per
/// point in 2D), are then freed as soon as the points are spawned, instead of living through
/// the run beside the points they became.
pub fn run_scene_restartable<'a>(
    spec: impl Into<Cow<'a, SceneSpec>>,
    out_dir: &Path,
    modules: &ModuleSet,
    plan: &RestartPlan,
    resume: Option<Checkpoint>,
    on_step: impl FnMut(&StepRecord),
) -> Result<Summary, RunError> {
    completed(run_with(
        spec.into(),
        out_dir,
        modules,
        &(),
        Some((plan, resume)),
        on_step,
    ))
}

/// A run's checkpoint plan, and the checkpoint it resumes from.
type Restart<'a> = Option<(&'a RestartPlan, Option<Checkpoint>)>;

fn run_with(
    spec: Cow<'_, SceneSpec>,
    out_dir: &Path,
    modules: &ModuleSet,
    plugin: &impl Plugin,
    restart: Restart<'_>,
    on_step: impl FnMut(&StepRecord),
) -> (Option<Summary>, Result<(), RunError>) {
    match spec.dim() {
        1 => run_in::<1>(spec, out_dir, modules, plugin, restart, on_step),
        2 => run_in::<2>(spec, out_dir, modules, plugin, restart, on_step),
        3 => run_in::<3>(spec, out_dir, modules, plugin, restart, on_step),
        d => (
            None,
            Err(RunError::Build(BuildError(format!(
                "dimension {d} is not supported (1, 2 or 3)"
            )))),
        ),
    }
}

fn run_in<const D: usize>(
    spec: Cow<'_, SceneSpec>,
    out_dir: &Path,
    modules: &ModuleSet,
    plugin: &impl Plugin,
    restart: Restart<'_>,
    on_step: impl FnMut(&StepRecord),
) -> (Option<Summary>, Result<(), RunError>) {
    let mut sim = match Simulation::<D>::with_modules(&spec, out_dir, modules) {
        Ok(sim) => sim,
        Err(e) => return (None, Err(RunError::Build(e))),
    };
    // the points are spawned: an owned scene's seeds are no longer needed
    drop(spec);
    if let Err(e) = sim.add_plugin(plugin) {
        return (None, Err(RunError::Build(e)));
    }
    let mut resume = None;
    if let Some((plan, checkpoint)) = restart {
        sim.keep_checkpoints(plan.clone());
        resume = checkpoint;
    }
    let start = match resume {
        Some(checkpoint) => match sim.resume_from(checkpoint) {
            Ok(()) => Ok(()),
            Err(why) => return (None, Err(RunError::Resume(why))),
        },
        None => {
            let written = sim.write_initial_state();
            sim.agree_on(written)
        }
    };
    let result = start
        .and_then(|()| sim.run(on_step))
        .map_err(RunError::Solve)
        .and_then(
            // the status, not this process's own flag: in a distributed run a process may stop
            // because another one was asked to
            |()| match crate::interrupt::StopReason::from_status(sim.summary.status) {
                Some(reason) => Err(RunError::Stopped {
                    reason,
                    steps_done: sim.steps_done(),
                }),
                None => Ok(()),
            },
        );
    (Some(sim.summary), result)
}

/// A failed run.
#[derive(Debug)]
pub enum RunError {
    Build(BuildError),
    Solve(SolverError),
    /// The checkpoint could not be restored.
    Resume(String),
    /// Stopped by a signal or the deadline after `steps_done` completed steps.
    Stopped {
        reason: crate::interrupt::StopReason,
        steps_done: usize,
    },
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Build(e) => write!(f, "cannot set up the simulation: {e}"),
            RunError::Solve(e) => write!(f, "{e}"),
            RunError::Resume(why) => write!(f, "cannot resume the run: {why}"),
            RunError::Stopped { reason, steps_done } => {
                write!(f, "{} after load step {steps_done}", reason.status())
            }
        }
    }
}

impl std::error::Error for RunError {}

/// The default output folder of a scene: `out/<scene name>/`.
pub fn default_output_dir(spec: &SceneSpec) -> PathBuf {
    Path::new("out").join(&spec.name)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The failure's entry keeps the control's figures and says what the largest load factor is
    /// worth: the limit load only when the load had come down from it.
    #[test]
    fn a_failed_arc_length_run_says_whether_its_largest_load_factor_is_the_limit() {
        let spec = ArcLengthSpec {
            target_iterations: 5,
            max_load_factor: f64::INFINITY,
            ..ArcLengthSpec::default()
        };
        let failure = SolverError::BadPointState {
            point: 7,
            step: 4,
            iteration: 3,
            why: "det F <= 0".to_string(),
        };
        let mut arc = ArcLengthControl::new(spec, 8, 0.1);
        let entry = failed_arc_length(&arc, 1, &failure, false);
        assert_eq!(entry["end"], "failed");
        assert_eq!(entry["failure"], failure.to_string());
        assert!(entry["peak_load_factor"].is_null());
        assert!(
            entry["report"]
                .as_str()
                .unwrap()
                .contains("before any step converged")
        );

        arc.succeeded(1, 1.0, 5, 0.2, 0);
        arc.succeeded(2, 2.0, 5, 0.2, 0);
        arc.succeeded(3, 3.0, 5, 0.2, 0);
        let entry = failed_arc_length(&arc, 4, &failure, false);
        assert_eq!(entry["peak_load_factor"], 3.0);
        assert_eq!(entry["peak_step"], 3);
        assert_eq!(entry["passed_limit"], false);
        let report = entry["report"].as_str().unwrap();
        assert!(
            report.contains("failed at step 4 before passing a limit load"),
            "{report}"
        );
        assert!(report.contains("not the limit load"), "{report}");
        // the same failure where the load factor had levelled off at its largest value
        let report = failed_arc_length(&arc, 4, &failure, true)["report"].to_string();
        assert!(report.contains("failed at step 4 on a plateau"), "{report}");
        assert!(report.contains("3.000000e0 (step 3)"), "{report}");
        assert!(!report.contains("not the limit load"), "{report}");

        arc.succeeded(4, 2.5, 5, 0.2, 0);
        let entry = failed_arc_length(&arc, 5, &failure, false);
        assert_eq!(entry["peak_load_factor"], 3.0);
        assert_eq!(entry["passed_limit"], true);
        let report = entry["report"].as_str().unwrap();
        assert!(
            report.contains("failed at step 5 after passing the limit load"),
            "{report}"
        );
        assert!(!report.contains("not the limit load"), "{report}");
    }
}
