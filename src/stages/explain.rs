//! What a scene will run: the systems of its schedules, read from the built schedules.
//!
//! [`scheduled_systems`] initialises every solver schedule of a world (the same schedules a
//! [`crate::simulation::Simulation`] runs, including systems added by plugins) and lists their
//! systems in execution order with the stage (system set) each belongs to. [`explain_scene`]
//! does it for a scene without building its points, and also lists the optional systems the
//! scene leaves out: those of the schedules built with every optional effect on
//! ([`Effects::with_every_optional_effect`]) that are missing from the scene's own. `impm check SCENE --explain` prints both.

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{InternedScheduleLabel, InternedSystemSet, ScheduleLabel, SystemSet};

use super::{
    Effects, LoadStep, NewtonIteration, NewtonSystems, StepSystems, WriteOutput, add_schedules,
};
use crate::plugin::Hook;
use crate::scene::SceneSpec;

/// One system of a schedule.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScheduledSystem {
    /// The schedule: `LoadStep`, `NewtonIteration` or `WriteOutput`.
    pub schedule: String,
    /// The stage (system set) it runs in, e.g. `Loads`, or the plugin hook, e.g.
    /// `Hook::Output`, if it is in one of the solver's sets.
    pub stage: Option<String>,
    /// The system's path without the crate's `impm::stages::` prefix and without generic
    /// arguments, e.g. `loads::apply_body_force`.
    pub name: String,
}

/// The solver's schedules and their stages, in execution order.
fn schedules_and_stages() -> Vec<(
    InternedScheduleLabel,
    Vec<(&'static str, InternedSystemSet)>,
)> {
    vec![
        (
            LoadStep.intern(),
            vec![
                ("Connectivity", StepSystems::Connectivity.intern()),
                ("Dofs", StepSystems::Dofs.intern()),
                ("Loads", StepSystems::Loads.intern()),
                ("Solve", StepSystems::Solve.intern()),
                ("UpdatePoints", StepSystems::UpdatePoints.intern()),
                ("Output", StepSystems::Output.intern()),
                ("ResetGrid", StepSystems::ResetGrid.intern()),
                ("Hook::Loads", Hook::Loads.intern()),
                ("Hook::AfterStep", Hook::AfterStep.intern()),
            ],
        ),
        (
            NewtonIteration.intern(),
            vec![
                ("StressUpdate", NewtonSystems::StressUpdate.intern()),
                ("Assembly", NewtonSystems::Assembly.intern()),
                ("Convergence", NewtonSystems::Convergence.intern()),
                ("LinearSolve", NewtonSystems::LinearSolve.intern()),
                ("Hook::BeforeAssembly", Hook::BeforeAssembly.intern()),
                ("Hook::AfterAssembly", Hook::AfterAssembly.intern()),
            ],
        ),
        (
            WriteOutput.intern(),
            vec![("Hook::Output", Hook::Output.intern())],
        ),
    ]
}

/// `impm::stages::loads::apply_body_force<2>` -> `loads::apply_body_force`.
fn readable(name: &str) -> String {
    let name = name.strip_prefix("impm::stages::").unwrap_or(name);
    let name = name.split('<').next().unwrap_or(name);
    name.to_string()
}

/// The systems of the solver schedules present in `world`, in execution order per schedule
/// (`LoadStep`, then `NewtonIteration`, then `WriteOutput`). Initialises the schedules; an
/// error says why one does not build (e.g. a plugin's system is ambiguous with another).
pub fn scheduled_systems(world: &mut World) -> Result<Vec<ScheduledSystem>, String> {
    let mut out = Vec::new();
    for (label, stages) in schedules_and_stages() {
        let listed = world.try_schedule_scope(label, |world, schedule| {
            if let Err(error) = schedule.initialize(world) {
                let why = error.to_string(schedule.graph(), world);
                return Err(format!("the {label:?} schedule does not build: {why}"));
            }
            let graph = schedule.graph();
            let members: Vec<_> = stages
                .iter()
                .map(|(stage, set)| (*stage, graph.systems_in_set(*set).ok()))
                .collect();
            let systems = schedule
                .systems()
                .map_err(|_| format!("the {label:?} schedule is not initialised"))?
                .map(|(key, system)| {
                    let stage = members
                        .iter()
                        .find(|(_, keys)| keys.is_some_and(|keys| keys.contains(&key)))
                        .map(|(stage, _)| stage.to_string());
                    ScheduledSystem {
                        schedule: format!("{label:?}"),
                        stage,
                        name: readable(&system.name()),
                    }
                })
                .collect::<Vec<_>>();
            Ok::<_, String>(systems)
        });
        // a schedule the world does not have is simply not listed
        if let Ok(systems) = listed {
            out.extend(systems?);
        }
    }
    Ok(out)
}

/// The systems the scene's schedules contain, and the optional systems they leave out.
#[derive(Clone, Debug)]
pub struct Explanation {
    pub effects: Effects,
    pub systems: Vec<ScheduledSystem>,
    /// Systems of the schedules with every effect on that this scene's schedules do not have.
    pub left_out: Vec<ScheduledSystem>,
}

fn systems_for<const D: usize>(effects: Effects) -> Result<Vec<ScheduledSystem>, String> {
    let mut world = World::new();
    add_schedules::<D>(&mut world, effects);
    scheduled_systems(&mut world)
}

/// Explains the schedules of `spec` (dimension 1, 2 or 3).
pub fn explain_scene(spec: &SceneSpec) -> Result<Explanation, String> {
    let effects = crate::simulation::effects_of(spec);
    let build: fn(Effects) -> Result<Vec<ScheduledSystem>, String> = match spec.dim() {
        1 => systems_for::<1>,
        2 => systems_for::<2>,
        3 => systems_for::<3>,
        d => return Err(format!("dimension {d} is not supported (1, 2 or 3)")),
    };
    let systems = build(effects)?;
    let left_out = build(effects.with_every_optional_effect())?
        .into_iter()
        .filter(|system| !systems.contains(system))
        .collect();
    Ok(Explanation {
        effects,
        systems,
        left_out,
    })
}

impl std::fmt::Display for Explanation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "effects used by the scene:")?;
        for (name, used) in self.effects.list() {
            writeln!(f, "  {name:<27} {}", if used { "yes" } else { "no" })?;
        }
        let mut schedule = "";
        for system in &self.systems {
            if system.schedule != schedule {
                schedule = &system.schedule;
                let note = match schedule {
                    "LoadStep" => " (once per load step)",
                    "NewtonIteration" => {
                        " (once per Newton iteration, run by newton::solve_load_step)"
                    }
                    "WriteOutput" => " (run by stages::run_output and for the initial state)",
                    _ => "",
                };
                writeln!(f, "schedule {schedule}{note}:")?;
            }
            writeln!(
                f,
                "  {:<20} {}",
                system.stage.as_deref().unwrap_or("-"),
                system.name
            )?;
        }
        if self.left_out.is_empty() {
            writeln!(f, "no optional system is left out")?;
        } else {
            writeln!(f, "left out (effects this scene does not use):")?;
            for system in &self.left_out {
                writeln!(
                    f,
                    "  {:<20} {} ({})",
                    system.stage.as_deref().unwrap_or("-"),
                    system.name,
                    system.schedule
                )?;
            }
        }
        Ok(())
    }
}
