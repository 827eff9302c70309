//! What a scene will run: the systems of its schedules, read from the built schedules.
//!
//! [`scheduled_systems`] initialises every schedule of a world (the same schedules a
//! [`Simulation`] runs, including systems added by modules and plugins) and lists their
//! systems in execution order with the stage or hook each belongs to. [`explain_scene`] does it
//! for a scene, and also lists the systems the scene leaves out: those of the modules that could
//! run with the scene's method but that the scene does not use (their systems are built into a
//! second simulation of the same scene). `impm check SCENE --explain` prints both.

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{InternedScheduleLabel, InternedSystemSet, ScheduleLabel, SystemSet};

use crate::method::{
    BuiltInOutput, Hook, NewtonSchedule, NewtonSystems, OutputSchedule, RollbackSchedule,
    StepSchedule, StepSystems, initialize_schedules,
};
use crate::plugin::ModuleSet;
use crate::run::Simulation;
use crate::scene::SceneSpec;

/// One system of a schedule.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScheduledSystem {
    /// The schedule: `StepSchedule`, `NewtonSchedule`, `OutputSchedule` or `RollbackSchedule`.
    pub schedule: String,
    /// The hook it was added at, e.g. `Hook::Loads`, or else the core stage it runs in, e.g.
    /// `Dofs`.
    pub stage: Option<String>,
    /// The system's path without the crate's `impm::`, `stages::` and `effects::` prefixes,
    /// with generic arguments shortened, e.g. `point_loads::apply_point_loads` or
    /// `stress::update_stress<Hencky>`.
    pub name: String,
}

/// The schedules and their named sets, hooks first (a hook lies inside a stage).
fn schedules_and_stages() -> Vec<(InternedScheduleLabel, Vec<(String, InternedSystemSet)>)> {
    let hooks = |schedule: InternedScheduleLabel| {
        Hook::ALL
            .iter()
            .filter(move |hook| hook.schedule() == schedule)
            .map(|hook| (format!("Hook::{hook:?}"), hook.intern()))
    };
    let with_hooks = |label: InternedScheduleLabel, stages: Vec<(String, InternedSystemSet)>| {
        let mut sets: Vec<_> = hooks(label).collect();
        sets.extend(stages);
        (label, sets)
    };
    use NewtonSystems as N;
    use StepSystems as S;
    let named = |sets: Vec<(&str, InternedSystemSet)>| {
        sets.into_iter()
            .map(|(name, set)| (name.to_string(), set))
            .collect::<Vec<_>>()
    };
    vec![
        with_hooks(
            StepSchedule.intern(),
            named(vec![
                ("Connectivity", S::Connectivity.intern()),
                ("Dofs", S::Dofs.intern()),
                ("Loads", S::Loads.intern()),
                ("Solve", S::Solve.intern()),
                ("UpdatePoints", S::UpdatePoints.intern()),
                ("Output", S::Output.intern()),
                ("ResetGrid", S::ResetGrid.intern()),
            ]),
        ),
        with_hooks(
            NewtonSchedule.intern(),
            named(vec![
                ("StressUpdate", N::StressUpdate.intern()),
                ("Assembly", N::Assembly.intern()),
                ("Convergence", N::Convergence.intern()),
                ("LinearSolve", N::LinearSolve.intern()),
            ]),
        ),
        with_hooks(
            OutputSchedule.intern(),
            named(vec![("Output", BuiltInOutput.intern())]),
        ),
        with_hooks(RollbackSchedule.intern(), Vec::new()),
    ]
}

/// `impm::effects::point_loads::apply_point_loads<2>` -> `point_loads::apply_point_loads`;
/// `impm::stages::stress::update_stress<2, impm::material::hencky::Hencky>` ->
/// `stress::update_stress<Hencky>`.
fn readable(name: &str) -> String {
    let (path, generics) = name.split_once('<').unwrap_or((name, ""));
    let mut path = path.strip_prefix("impm::").unwrap_or(path);
    for prefix in ["stages::", "effects::"] {
        path = path.strip_prefix(prefix).unwrap_or(path);
    }
    let types: Vec<&str> = generics
        .trim_end_matches('>')
        .split(',')
        .map(str::trim)
        .filter(|argument| !argument.is_empty() && !argument.chars().all(|c| c.is_ascii_digit()))
        .map(|argument| argument.rsplit("::").next().unwrap_or(argument))
        .collect();
    if types.is_empty() {
        path.to_string()
    } else {
        format!("{path}<{}>", types.join(", "))
    }
}

/// The systems of the solver schedules present in `world`, in execution order per schedule
/// (step, Newton, output, rollback). Initialises the schedules; an error says why one does not
/// build (e.g. a plugin's system is ambiguous with another).
pub fn scheduled_systems(world: &mut World) -> Result<Vec<ScheduledSystem>, String> {
    initialize_schedules(world)?;
    let mut out = Vec::new();
    for (label, stages) in schedules_and_stages() {
        let listed = world.try_schedule_scope(label, |_, schedule| {
            let graph = schedule.graph();
            let members: Vec<_> = stages
                .iter()
                .map(|(stage, set)| (stage, graph.systems_in_set(*set).ok()))
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

/// The modules a scene could use and the systems its schedules hold or leave out.
#[derive(Clone, Debug)]
pub struct Explanation {
    /// Every module that applies to the scene's method, and whether the scene uses it.
    pub modules: Vec<(&'static str, bool)>,
    pub systems: Vec<ScheduledSystem>,
    /// Systems of the applicable modules that this scene's schedules do not have.
    pub left_out: Vec<ScheduledSystem>,
}

fn explain_in<const D: usize>(
    spec: &SceneSpec,
    modules: &ModuleSet,
) -> Result<Explanation, String> {
    let out = std::env::temp_dir().join(format!("impm-explain-{}", std::process::id()));
    let build = |include: &dyn Fn(&dyn crate::plugin::Module) -> bool| {
        Simulation::<D>::with_modules_where(spec, &out, modules, include).map_err(|e| e.to_string())
    };
    let mut scene = build(&|module| module.used_by(spec))?;
    let systems = scheduled_systems(&mut scene.world)?;
    let mut all = build(&|module| module.used_by(spec) || module.applies_to(spec))?;
    let left_out = scheduled_systems(&mut all.world)?
        .into_iter()
        .filter(|system| !systems.contains(system))
        .collect();
    // nothing was written there: the simulations were only built
    let _ = std::fs::remove_dir(&out);
    Ok(Explanation {
        modules: modules
            .iter()
            .filter(|module| module.used_by(spec) || module.applies_to(spec))
            .map(|module| (module.name(), module.used_by(spec)))
            .collect(),
        systems,
        left_out,
    })
}

/// Explains the schedules of `spec` (dimension 1, 2 or 3) built with `modules`.
pub fn explain_scene(spec: &SceneSpec, modules: &ModuleSet) -> Result<Explanation, String> {
    match spec.dim() {
        1 => explain_in::<1>(spec, modules),
        2 => explain_in::<2>(spec, modules),
        3 => explain_in::<3>(spec, modules),
        d => Err(format!("dimension {d} is not supported (1, 2 or 3)")),
    }
}

impl std::fmt::Display for Explanation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "modules (built only when the scene uses them):")?;
        for (name, used) in &self.modules {
            writeln!(f, "  {name:<27} {}", if *used { "yes" } else { "no" })?;
        }
        let mut schedule = "";
        for system in &self.systems {
            if system.schedule != schedule {
                schedule = &system.schedule;
                let note = match schedule {
                    "StepSchedule" => " (once per load step)",
                    "NewtonSchedule" => {
                        " (once per Newton iteration, run by method::solve_load_step)"
                    }
                    "OutputSchedule" => " (run by method::run_output and for the initial state)",
                    "RollbackSchedule" => " (after a failed attempt, before the next)",
                    _ => "",
                };
                writeln!(f, "schedule {schedule}{note}:")?;
            }
            writeln!(
                f,
                "  {:<23} {}",
                system.stage.as_deref().unwrap_or("-"),
                system.name
            )?;
        }
        if self.left_out.is_empty() {
            writeln!(f, "no optional system is left out")?;
        } else {
            writeln!(f, "left out (modules this scene does not use):")?;
            for system in &self.left_out {
                writeln!(
                    f,
                    "  {:<23} {} ({})",
                    system.stage.as_deref().unwrap_or("-"),
                    system.name,
                    system.schedule
                )?;
            }
        }
        Ok(())
    }
}
