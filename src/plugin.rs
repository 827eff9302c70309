//! Extending a simulation with your own systems, without editing the crate.
//!
//! A [`Plugin`] adds bevy systems (and the resources or components they need) to a simulation
//! at named [`Hook`]s of the solver's schedules:
//!
//! | hook | schedule, place | typical use |
//! |------|-----------------|-------------|
//! | [`Hook::Loads`] | `LoadStep`, after the built-in loads, before the Newton loop | a custom external force into `GridFields::external_force`, a custom prescribed increment |
//! | [`Hook::BeforeAssembly`] | `NewtonIteration`, after the stress update, before assembly | inspect or adjust the trial state of the points |
//! | [`Hook::AfterAssembly`] | `NewtonIteration`, after assembly, before the convergence check | add to the internal force and the tangent (springs, penalties, contact) |
//! | [`Hook::AfterStep`] | `LoadStep`, after a converged step's point update, before output | diagnostics, state updates of your own components |
//! | [`Hook::Output`] | `WriteOutput`, after the built-in files; also for the initial state | your own output files (see `OutputPlan::dir`, `LoadStep`) |
//!
//! ```no_run
//! use bevy_ecs::prelude::*;
//! use impm::plugin::{Extension, Hook, Plugin, run_scene_with};
//! use impm::resources::LoadStep;
//!
//! struct Announce;
//!
//! fn announce(step: Res<LoadStep>) {
//!     println!("step {} converged at load factor {}", step.number, step.factor);
//! }
//!
//! impl Plugin for Announce {
//!     fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
//!         simulation.add_systems(Hook::AfterStep, announce);
//!     }
//! }
//!
//! let spec = impm::scene::load_scene("scripts/column_1d.rhai".as_ref(), &[]).unwrap();
//! run_scene_with(&spec, "out/announce".as_ref(), &Announce, |_| {}).unwrap();
//! ```
//!
//! A plugin is generic over the dimension `D` (it is built for the scene's), so its systems can
//! use `Position<D>`, `GridFields<D>` and so on. The solver's schedules detect ambiguous system
//! order as an error: the systems of one hook are ordered after the built-in stages before the
//! hook and before those after it, but two systems a plugin adds to the same hook that write
//! the same data must be ordered among themselves (`.chain()`, `.after(...)`), or the schedule
//! does not build (a `BuildError` naming both).
//!
//! Hooks cost nothing when unused: a hook's system set is configured only when a plugin adds a
//! system to it, and `()` is the plugin that adds nothing.

use std::path::Path;

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};
use bevy_ecs::system::ScheduleSystem;

use crate::resources::no_failure;
use crate::scene::SceneSpec;
use crate::simulation::{BuildError, RunError, Simulation, run_scene_keeping_summary_with};
use crate::stages::{
    BuiltInOutput, LoadStep, NewtonIteration, NewtonSystems, StepSystems, WriteOutput,
    scheduled_systems,
};
use crate::summary::{StepRecord, Summary};

/// Where a plugin's systems run (see the module docs for the table).
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Hook {
    Loads,
    BeforeAssembly,
    AfterAssembly,
    AfterStep,
    Output,
}

/// A set of systems and resources to add to a simulation.
pub trait Plugin {
    /// Adds the plugin's systems, resources and components to a simulation of dimension `D`
    /// (called once, after the world is built from the scene and before the first step).
    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>);
}

/// The plugin that adds nothing.
impl Plugin for () {
    fn build<const D: usize>(&self, _: &mut Extension<'_, D>) {}
}

impl<A: Plugin, B: Plugin> Plugin for (A, B) {
    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        self.0.build(simulation);
        self.1.build(simulation);
    }
}

impl<P: Plugin> Plugin for &P {
    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        (*self).build(simulation);
    }
}

/// What a plugin sees of the simulation it extends.
pub struct Extension<'w, const D: usize> {
    world: &'w mut World,
}

impl<'w, const D: usize> Extension<'w, D> {
    /// Wraps a simulation's world (usually through [`Simulation::add_plugin`]).
    pub fn new(world: &'w mut World) -> Self {
        Self { world }
    }

    /// The simulation's world: insert resources, give points components of your own...
    pub fn world(&mut self) -> &mut World {
        self.world
    }

    /// Adds `systems` at `hook`. They run only while no stage has failed, like the built-in
    /// stages.
    pub fn add_systems<M>(
        &mut self,
        hook: Hook,
        systems: impl IntoScheduleConfigs<ScheduleSystem, M>,
    ) -> &mut Self {
        let systems = systems.in_set(hook);
        let mut schedules = self.world.resource_mut::<Schedules>();
        match hook {
            Hook::Loads => schedules.entry(LoadStep).configure_sets(
                hook.after(StepSystems::Loads)
                    .before(StepSystems::Solve)
                    .run_if(no_failure),
            ),
            Hook::AfterStep => schedules.entry(LoadStep).configure_sets(
                hook.after(StepSystems::UpdatePoints)
                    .before(StepSystems::Output)
                    .run_if(no_failure),
            ),
            Hook::BeforeAssembly => schedules.entry(NewtonIteration).configure_sets(
                hook.after(NewtonSystems::StressUpdate)
                    .before(NewtonSystems::Assembly)
                    .run_if(no_failure),
            ),
            Hook::AfterAssembly => schedules.entry(NewtonIteration).configure_sets(
                hook.after(NewtonSystems::Assembly)
                    .before(NewtonSystems::Convergence)
                    .run_if(no_failure),
            ),
            Hook::Output => schedules
                .entry(WriteOutput)
                .configure_sets(hook.after(BuiltInOutput).run_if(no_failure)),
        };
        schedules.entry(hook.schedule()).add_systems(systems);
        self
    }
}

impl Hook {
    /// The schedule the hook belongs to.
    pub fn schedule(self) -> impl ScheduleLabel {
        match self {
            Hook::Loads | Hook::AfterStep => LoadStep.intern(),
            Hook::BeforeAssembly | Hook::AfterAssembly => NewtonIteration.intern(),
            Hook::Output => WriteOutput.intern(),
        }
    }
}

impl<const D: usize> Simulation<D> {
    /// Adds a plugin's systems and resources, and checks that the schedules still build.
    pub fn add_plugin(&mut self, plugin: &impl Plugin) -> Result<(), BuildError> {
        plugin.build(&mut Extension::<D>::new(&mut self.world));
        scheduled_systems(&mut self.world)
            .map(|_| ())
            .map_err(|why| BuildError(format!("a plugin's systems do not fit: {why}")))
    }
}

/// [`crate::simulation::run_scene`] with a plugin: builds the simulation for the scene's
/// dimension, adds the plugin, writes the initial state and runs every load step.
pub fn run_scene_with(
    spec: &SceneSpec,
    out_dir: &Path,
    plugin: &impl Plugin,
    on_step: impl FnMut(&StepRecord),
) -> Result<Summary, RunError> {
    let (summary, result) = run_scene_keeping_summary_with(spec, out_dir, plugin, on_step);
    result?;
    summary.ok_or_else(|| RunError::Build(BuildError("the run produced no summary".into())))
}
