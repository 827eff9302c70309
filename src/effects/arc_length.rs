//! Arc-length load control as a scene option: `solver(#{ control: "arc_length",
//! target_iterations: 5, max_load_factor: 2.0 })`. The method is in `stages::arc_length`; this
//! module reads the options, refuses what the arc cannot control, adds the arc's five systems
//! (six with `rebalance`, seven with held loads, whose default rebalancing, `"auto"`,
//! rebalances a step whose start correction is at least its arc: [`Rebalance::resolve`]) at
//! their hooks (scenes without the option schedule none of them) and the measure
//! `initial_imbalance` (each step's out-of-balance force at its start, relative to λ_n f̂):
//!
//! ```text
//!   Hook::AfterDofs         unit_load              the loads are evaluated at λ = 1 ...
//!   Hook::BeforeSolve       split_fixed_loads      (held loads only) again at λ = 0: f_fixed, f̂ = f(1) − f(0)
//!   Hook::BeforeSolve       take_reference_load    ... and kept as f̂; f_ext = f_fixed + λ_n f̂
//!   Hook::Convergence       record_start_imbalance the step's start residual, warned when large
//!   Hook::Convergence       finish_rebalance       (rebalance or held loads) the start residual removed: the arc begins
//!   Hook::Convergence       keep_going_forward     a converged iterate that went back is refused
//!   Hook::AfterLinearSolve  correct_load_factor    K δu_f = f̂, δλ from the arc, Δu += δu_r + δλ δu_f
//! ```
//!
//! The arc controls proportional loads f_ext = λ f̂: tractions, follower pressures
//! (`effects::pressure`, whose f̂ follows the current shape), point loads and a body force that
//! follow the load factor. Held loads (`held: true`) are f_fixed beside them,
//! f_ext = f_fixed + λ f̂: with them the loads are evaluated a second time per step at λ = 0
//! (`split_fixed_loads` before `take_reference_load`; [`add_load_system`]) and the first step
//! first balances them (module docs of `stages::arc_length`, "Held loads"). It refuses, at the
//! scene line that asks for them:
//! * a prescribed displacement that is not zero (`displace`, `surface_displace` with a
//!   `displacement`): its ramp would be a second load parameter the arc does not constrain;
//!   supports (`fix`, zero displacements) are fine;
//! * the Newton line search, which would move the iterate off the arc.
//!
//! Under `mpirun` with replicated state the arc runs as serially (module docs of
//! `stages::arc_length`, "Over several processes"); with `--decompose` its sums are taken
//! over the processes' owned DOFs ("With decomposed points" there; the follower pressure is
//! still refused there, `effects::distributed::decomposition`).
//!
//! # Stages
//!
//! In a staged scene the arc is asked for by the last stage, `stage(#{ .., control:
//! "arc_length" })` (`scene::stages` refuses it on another stage, and `solver(#{ control:
//! "arc_length" })`, which names no stage); `solver(...)` still tunes it (`target_iterations`,
//! `max_load_factor`, `rebalance`). The refusals above are then made at the stage's line. The
//! arc starts at the stage's first step ([`ArcLengthSpec::first_step`]); every system above is
//! gated on it (`arc_controls_step`), so the earlier, load-controlled stages run as without
//! the arc, bit for bit; the earlier stages' loads are held beside the arc's
//! (`fixed_loads`, module docs of `stages::arc_length`, "Stages").

use super::body_force::BodyForceRamp;
use super::grid_constraints::ConstraintDeclarations;
use super::point_loads::PointLoads;
use crate::checkpoint::CheckpointPart;
use crate::method::Hook;
use crate::plugin::{Extension, Plugin};
use crate::resources::RunStatus;
use crate::scene::{
    Choice, Kind, OptionSpec, Range, Resolver, SceneApi, SceneSpec, ScriptError, Stages,
};
use crate::stages::arc_length::{
    ArcLength, ArcLengthSpec, FixedLoadSlot, FixedLoadSlots, FixedLoadsSchedule, Rebalance,
    arc_controls_step, correct_load_factor, finish_rebalance, keep_going_forward,
    record_start_imbalance, restore_arc_state, save_arc_state, split_fixed_loads,
    take_reference_load, unit_load,
};
use bevy_ecs::prelude::{IntoScheduleConfigs, Res, World};
use bevy_ecs::schedule::{Schedule, Schedules, SingleThreadedExecutor};
use bevy_ecs::system::ScheduleSystem;
use rhai::Position;

/// The module: built when the scene asks for arc-length control.
#[derive(Clone, Copy, Debug, Default)]
pub struct ArcLengthModule;

impl Plugin for ArcLengthModule {
    fn name(&self) -> &'static str {
        "arc-length control"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.extend(
            "solver",
            OptionSpec::new(
                "control",
                Kind::Choice(vec![
                    Choice {
                        word: "load",
                        meaning: Some("the load factors of the schedule, steps cut on failure"),
                    },
                    Choice {
                        word: "arc_length",
                        meaning: Some(
                            "arc-length (Riks/Crisfield, cylindrical arc): the load factor is an \
                             unknown of each step, so the run follows a load-controlled problem \
                             past its limit load; the first load factor sizes the first arc, the \
                             schedule's step count is the most steps; tractions, pressures, \
                             point loads and a body force following the load factor are the \
                             controlled loads, held loads (held: true) stay in full beside them",
                        ),
                    },
                ]),
                "how the load factor of a step is found (default \"load\")",
            ),
        );
        api.extend(
            "solver",
            OptionSpec::new(
                "target_iterations",
                Kind::Whole {
                    min: 1,
                    max: Some(50),
                },
                "control: \"arc_length\": the Newton iterations per step the arc length is \
                 scaled towards, √(target / iterations) within [1/2, 2] (default 5)",
            ),
        );
        api.extend(
            "solver",
            OptionSpec::new(
                "max_load_factor",
                Kind::Number(Range::Positive),
                "control: \"arc_length\": the run ends after the step that reaches this load \
                 factor (default: no such end; the run also ends when the load factor falls \
                 back to zero after its peak, or after the schedule's steps)",
            ),
        );
        api.extend(
            "solver",
            OptionSpec::new(
                "rebalance",
                Kind::Choice(vec![
                    Choice {
                        word: "auto",
                        meaning: Some(
                            "the default: in a scene with held loads (held: true, or the \
                             earlier stages' loads under a staged arc), a step whose start \
                             residual needs a correction at least as long as its arc is \
                             rebalanced as \"fixed\" (the held loads' out-of-balance force on \
                             nodes a step newly reaches would otherwise steer the arc); \"off\" \
                             without held loads",
                        ),
                    },
                    Choice {
                        word: "off",
                        meaning: Some("the arc starts from the committed state"),
                    },
                    Choice {
                        word: "fixed",
                        meaning: Some(
                            "each step first removes the out-of-balance force it starts with by \
                             Newton at the last load factor, without the arc; the arc starts \
                             from that equilibrium",
                        ),
                    },
                    Choice {
                        word: "free",
                        meaning: Some(
                            "the same with the load factor free: each correction the shortest \
                             one (normal to δu_f), so the load factor moves as little as the \
                             equilibrium needs",
                        ),
                    },
                ]),
                "control: \"arc_length\": remove the start residual of each step (points that \
                 crossed cell faces leave one, and held loads on nodes a step newly reaches) \
                 before its arc (default \"auto\")",
            ),
        );
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let solver = scene.call_options("solver");
        // the arc-controlled stage of a staged scene (the last one): its call and first step
        let staged = scene
            .spec
            .part::<Stages>()
            .and_then(Stages::arc_length_stage);
        let stage_call = staged.and_then(|(index, _)| scene.every_call_options("stage").nth(index));
        let asked = solver.is_some_and(|s| s.value.text("control") == Some("arc_length"));
        if !asked && staged.is_none() {
            if let Some(solver) = solver {
                for key in ["target_iterations", "max_load_factor", "rebalance"] {
                    if solver.value.has(key) {
                        return Err(ScriptError::at(
                            solver.at,
                            format!(
                                "solver(...): '{key}' applies to control: \"arc_length\" only \
                                 (in solver(...), or in a staged scene on the last \
                                 stage(#{{ .., control: \"arc_length\" }}))"
                            ),
                        ));
                    }
                }
            }
            return Ok(());
        }
        // refused at the line that asks for the arc: the arc-controlled stage, or solver(...)
        let (subject, at) = match (stage_call, solver) {
            (Some(stage), _) => ("stage(...)", stage.at),
            (None, Some(solver)) => ("solver(...)", solver.at),
            (None, None) => ("solver(...)", Position::NONE),
        };
        let refuse = |why: String| ScriptError::at(at, format!("{subject}: {why}"));
        if let Some(solver) = solver
            && solver.value.flag("line_search") == Some(true)
        {
            return Err(ScriptError::at(
                solver.at,
                "solver(...): control: \"arc_length\" cannot be combined with line_search: true \
                 (the line search would move the iterate off the arc)",
            ));
        }
        let first_step = staged.map_or(1, |(_, first)| first);
        let first = ArcLengthSpec {
            first_step,
            ..ArcLengthSpec::default()
        }
        .first_factor(&scene.spec.load_factors);
        if first == 0.0 || !first.is_finite() {
            return Err(refuse(format!(
                "control: \"arc_length\" sizes its first arc from the first load factor{}, \
                 which is {first}: give a schedule whose first factor is not zero",
                if staged.is_some() {
                    " of the stage"
                } else {
                    ""
                }
            )));
        }
        let options = solver.map(|s| &s.value);
        let conflict = |what: &str, line: Option<usize>| {
            let line = line.map(|l| format!(" (line {l})")).unwrap_or_default();
            refuse(format!(
                "control: \"arc_length\" controls tractions, pressures, point loads and a body \
                 force that follow the load factor; {what}{line} is not one of them: the arc \
                 cannot control two load parameters. Use supports (zero displacement) with \
                 arc-length, or load control for prescribed displacements"
            ))
        };
        if let Some(declared) = scene.spec.part::<ConstraintDeclarations>()
            && let Some(d) = declared
                .0
                .iter()
                .find(|d| d.values.iter().any(|&v| v != 0.0))
        {
            return Err(conflict(
                &format!("the prescribed displacement {}", d.name),
                d.line,
            ));
        }
        for call in scene.every_call_options("surface_displace") {
            if call
                .value
                .numbers("displacement")
                .is_some_and(|u| u.iter().any(|&v| v != 0.0))
            {
                return Err(conflict(
                    "surface_displace with a displacement",
                    call.at.line(),
                ));
            }
        }
        // held loads are f_fixed beside the controlled λ f̂ (module docs of
        // `stages::arc_length`, "Held loads")
        let held_call = ["traction", "point_load_at"].iter().any(|name| {
            scene
                .every_call_options(name)
                .any(|call| call.value.flag("held") == Some(true))
        });
        // in a staged scene the earlier stages' loads are held under the arc (f_fixed)
        let fixed_loads = first_step > 1
            || held_call
            || scene
                .declarations::<BodyForceRamp>()
                .iter()
                .any(|r| r.value.0.is_held())
            || scene
                .spec
                .part::<PointLoads>()
                .is_some_and(|loads| loads.0.iter().any(|l| l.ramp.is_held()));
        let default = ArcLengthSpec::default();
        scene.spec.set_part(ArcLengthSpec {
            target_iterations: options
                .and_then(|o| o.whole("target_iterations"))
                .unwrap_or(default.target_iterations),
            max_load_factor: options
                .and_then(|o| o.number("max_load_factor"))
                .unwrap_or(default.max_load_factor),
            // (the options table admits only the words of its choices)
            rebalance: Rebalance::resolve(options.and_then(|o| o.text("rebalance")), fixed_loads)
                .unwrap_or(default.rebalance),
            fixed_loads,
            first_step,
        });
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        spec.part::<ArcLengthSpec>().map(|arc| {
            let stage = match (spec.part::<Stages>(), arc.first_step) {
                (Some(stages), first) if first > 1 => {
                    let index = stages.of_step(first).0;
                    format!(
                        "stage '{}' (from step {first}; the stages before it under load control, \
                         their loads held beside the arc's): ",
                        stages.name(index)
                    )
                }
                _ => String::new(),
            };
            format!(
                "{stage}target {} iterations per step, at most {} steps, first arc from the load \
                 increment {}{}{}{}",
                arc.target_iterations,
                (spec.load_factors.len() + 1).saturating_sub(arc.first_step),
                arc.first_factor(&spec.load_factors),
                if arc.max_load_factor.is_finite() {
                    format!(", ends at load factor {}", arc.max_load_factor)
                } else {
                    String::new()
                },
                if arc.rebalance == Rebalance::Off {
                    String::new()
                } else {
                    format!(", rebalance: {}", arc.rebalance.word())
                },
                if arc.fixed_loads {
                    "; the held loads stay in full beside the controlled ones (f_ext = f_fixed \
                     + λ f̂), balanced at λ = 0 before the first arc"
                } else {
                    ""
                }
            )
        })
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<ArcLengthSpec>().is_some()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        // (built without the scene's part too: `impm check --explain` lists what it adds)
        let arc_spec = spec.part::<ArcLengthSpec>().copied().unwrap_or_default();
        let first = arc_spec.first_factor(&spec.load_factors);
        let (rebalance, fixed_loads) = (arc_spec.rebalance, arc_spec.fixed_loads);
        let mut arc = ArcLength::<D>::new(first);
        arc.rebalance = rebalance;
        arc.fixed_loads = fixed_loads;
        arc.first_step = arc_spec.first_step;
        simulation.world().insert_resource(arc);
        // nothing of the arc runs in the load-controlled steps before its stage
        let controls = arc_controls_step::<D>;
        simulation.add_systems(Hook::AfterDofs, unit_load.run_if(controls));
        if fixed_loads {
            simulation.add_systems(Hook::BeforeSolve, split_fixed_loads::<D>.run_if(controls));
        }
        simulation
            .add_systems(Hook::BeforeSolve, take_reference_load::<D>.run_if(controls))
            .add_systems(
                Hook::Convergence,
                record_start_imbalance::<D>.run_if(controls),
            );
        if rebalance != Rebalance::Off || fixed_loads {
            simulation.add_systems(Hook::Convergence, finish_rebalance::<D>.run_if(controls));
        }
        simulation
            .add_systems(Hook::Convergence, keep_going_forward::<D>.run_if(controls))
            .add_systems(
                Hook::AfterLinearSolve,
                correct_load_factor::<D>.run_if(controls),
            )
            .add_measure("initial_imbalance", |world, _| {
                world.resource::<ArcLength<D>>().start_imbalance
            })
            .checkpoint(CheckpointPart {
                name: "arc-length control",
                save: save_arc_state::<D>,
                restore: restore_arc_state::<D>,
            });
        if rebalance != Rebalance::Off {
            // (none on a step that did not rebalance: "auto")
            let rebalanced = |world: &World| world.resource::<ArcLength<D>>().rebalanced;
            simulation
                .add_measure("rebalance_iterations", move |world, _| {
                    rebalanced(world).map(|r| r.iterations as f64)
                })
                .add_measure("rebalanced_imbalance", move |world, _| {
                    rebalanced(world).and_then(|r| r.imbalance)
                })
                .add_measure("rebalanced_load_factor", move |world, _| {
                    rebalanced(world).map(|r| r.factor)
                });
        }
    }
}

/// Adds a load's system at `Hook::Loads` and, in a scene with held loads under arc-length
/// control, to the loads' second evaluation at λ = 0 ([`FixedLoadsSchedule`], module docs of
/// `stages::arc_length`, "Held loads"), in the order the modules add them. A load module
/// whose force is not affine in the load factor, or that is evaluated elsewhere, must not use
/// it.
pub fn add_load_system<const D: usize, M>(
    simulation: &mut Extension<'_, D>,
    system: impl IntoScheduleConfigs<ScheduleSystem, M> + Copy,
) {
    simulation.add_systems(Hook::Loads, system);
    if !simulation
        .spec()
        .part::<ArcLengthSpec>()
        .is_some_and(|a| a.fixed_loads)
    {
        return;
    }
    let world = simulation.world();
    let slot = {
        let mut slots = world.get_resource_or_init::<FixedLoadSlots>();
        slots.0 += 1;
        FixedLoadSlot(slots.0 - 1)
    };
    let mut schedules = world.resource_mut::<Schedules>();
    if !schedules.contains(FixedLoadsSchedule) {
        let mut schedule = Schedule::new(FixedLoadsSchedule);
        schedule.set_executor(SingleThreadedExecutor::new());
        schedules.insert(schedule);
    }
    let schedule = schedules.entry(FixedLoadsSchedule);
    if slot.0 == 0 {
        schedule.configure_sets(slot);
    } else {
        schedule.configure_sets(slot.after(FixedLoadSlot(slot.0 - 1)));
    }
    schedule.add_systems(
        system
            .in_set(slot)
            .run_if(|status: Res<RunStatus>| status.0.is_none()),
    );
}
