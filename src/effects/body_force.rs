//! Body force: the volume term of the external force (paper eq. 9),
//!
//! ```text
//!   f_ext,i += λ Σ_p m_p b N_i(x_p),
//! ```
//!
//! with b the body force per unit mass at load factor 1 (`body_force([..])` in scenes). The basis
//! values of a point sum to one (partition of unity), so the resultant is exactly λ b Σ_p m_p.
//!
//! `body_force([..], #{ held: true })` holds the force at its full value from the first load
//! step on (λ replaced by 1, [`Ramp::Held`]) while the other loads follow the schedule: the
//! weight of soil that starts from its geostatic stress (`initial_stress`) before a footing is
//! pushed into it.
//!
//! In a staged scene, `body_force([..], #{ until_stage: "s" })` releases the force at the start
//! of the later stage s: ramped down over it from its value at the end of the stage before,
//! `(1 − λ_s) b`, and absent after it (`declarations::released_factor`): the weight of a
//! stage taken off again.

use bevy_ecs::prelude::*;
use nalgebra::SVector;
use rhai::Dynamic;

use super::arc_length::add_load_system;
use super::declarations::{
    LoadSummary, held_option, keep_largest_force, released_factor, released_note, until_stage,
    until_stage_option,
};
use crate::components::{Mass, Support};
use crate::mechanics::spread_force;
use crate::plugin::{Extension, Plugin};
use crate::resources::{CurrentStage, GridFields, LoadStep, Ramp, Stage, StageClock};
use crate::scene::{
    CallSpec, Located, Options, Resolver, SceneApi, SceneSpec, ScriptError, numbers,
};

/// The scene's body force per unit mass at load factor 1 (one entry per axis).
#[derive(Clone, Debug, PartialEq)]
pub struct BodyForceSpec(pub Vec<f64>);

/// How the scene's body force follows the load schedule (a part of the scene and a resource;
/// absent: it follows the schedule).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct BodyForceRamp(pub Ramp);

/// The stage whose start releases the body force (`until_stage`; a part of the scene and a
/// resource; absent: never released).
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct BodyForceRelease(pub usize);

/// The `until_stage` option as declared (the stage's name).
#[derive(Clone, Debug, PartialEq)]
struct BodyForceUntil(String);

/// Where the scene declared its body force (for `impm check`).
#[derive(Clone, Debug, PartialEq)]
struct BodyForceLine(Option<usize>);

/// Body force per unit mass at load factor 1.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct BodyForce<const D: usize>(pub SVector<f64, D>);

/// The module: scheduled when the scene's body force is not zero.
#[derive(Clone, Copy, Debug, Default)]
pub struct BodyForceModule;

impl Plugin for BodyForceModule {
    fn name(&self) -> &'static str {
        "body force"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::args(
            "body_force",
            "body_force([b0, ..])",
            "body force per unit mass at load factor 1, one entry per axis (call once)",
            1,
            |builder, args, at| {
                let ramp = Ramp::staged(false, builder.stage());
                declare_body_force(builder, &args[0], ramp, at)
            },
        ));
        api.call(CallSpec::args(
            "body_force",
            "body_force([b0, ..], #{ held: bool, until_stage: \"stage\" })",
            "the same; with `held: true` the force is applied in full from the first load step on instead of following the load factor (the weight of soil that starts from its geostatic stress, `initial_stress`, while other loads ramp); with `until_stage` it is released at the start of that later stage, ramped down to zero over it (docs/plasticity.md, \"Staged analysis\")",
            2,
            |builder, args, at| {
                let options = Options::read(
                    "body_force",
                    &args[1],
                    &[held_option(), until_stage_option()],
                    None,
                )?;
                let ramp = Ramp::staged(options.flag("held").unwrap_or(false), builder.stage());
                if let Some(until) = options.text("until_stage") {
                    builder.declare(Located::new(BodyForceUntil(until.to_string()), at));
                }
                declare_body_force(builder, &args[0], ramp, at)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let Some(declared) = scene.declarations::<BodyForceSpec>().first().cloned() else {
            return Ok(());
        };
        if declared.value.0.len() != scene.spec.dim() {
            return Err(ScriptError::at(
                declared.at,
                format!(
                    "body_force(...) has {} components but {}",
                    declared.value.0.len(),
                    scene.grid_note()
                ),
            ));
        }
        scene.spec.set_part(declared.value);
        scene.spec.set_part(BodyForceLine(declared.at.line()));
        if let Some(ramp) = scene.declarations::<BodyForceRamp>().first() {
            scene.spec.set_part(ramp.value);
        }
        if let Some(until) = scene.declarations::<BodyForceUntil>().first() {
            let stage = until_stage(
                scene.spec,
                "body_force",
                &until.value.0,
                until.stage,
                until.at,
            )?;
            scene.spec.set_part(BodyForceRelease(stage));
        }
        Ok(())
    }

    /// The force per unit mass, and the declaration with its total force b Σ ρ₀ V_p over every
    /// material point.
    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let b = spec.part::<BodyForceSpec>()?;
        let mass: f64 = spec
            .bodies
            .iter()
            .map(|body| {
                let density = spec.materials.get(body.material).map_or(0.0, |m| m.density);
                density * body.points.iter().map(|p| p.volume).sum::<f64>()
            })
            .sum();
        let summary = LoadSummary::new(
            spec.part::<BodyForceLine>().and_then(|l| l.0),
            "body_force",
            "material points (all)",
            spec.bodies
                .iter()
                .flat_map(|body| &body.points)
                .map(|p| &p.position[..]),
            b.0.iter().map(|c| c * mass).collect(),
        );
        let ramp = spec.part::<BodyForceRamp>().map_or(Ramp::Schedule, |r| r.0);
        let summary = summary.in_stage(spec, ramp.stage());
        let released = released_note(spec, spec.part::<BodyForceRelease>().map(|r| r.0));
        Some(format!(
            "{:?} per unit mass {}{released}\n    {}",
            b.0,
            if ramp.is_held() {
                "held in full from the first step".to_string()
            } else {
                summary.factor.clone()
            },
            summary.describe()
        ))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<BodyForceSpec>()
            .is_some_and(|b| b.0.iter().any(|&c| c != 0.0))
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        if let Some(b) = simulation.spec().part::<BodyForceSpec>() {
            if b.0.len() != D {
                simulation.fail(format!("body force has {} components in {D}D", b.0.len()));
                return;
            }
            let force = SVector::<f64, D>::from_fn(|a, _| b.0[a]);
            simulation.world().insert_resource(BodyForce(force));
        }
        if let Some(ramp) = simulation.spec().part::<BodyForceRamp>().copied() {
            simulation.world().insert_resource(ramp);
        }
        if let Some(release) = simulation.spec().part::<BodyForceRelease>().copied() {
            simulation.world().insert_resource(release);
            keep_largest_force(simulation);
        }
        add_load_system(simulation, apply_body_force::<D>);
    }
}

/// f_ext,i += λ m_p b N_i(x_p) (λ = 1 for a held body force; in a scene with stages the
/// factor of its stage, `LoadStep::factor_in`, or of its release,
/// `declarations::released_factor`) over every material point.
#[allow(clippy::too_many_arguments)]
pub fn apply_body_force<const D: usize>(
    body_force: Res<BodyForce<D>>,
    ramp: Option<Res<BodyForceRamp>>,
    release: Option<Res<BodyForceRelease>>,
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    points: Query<(&Mass, &Support<D>)>,
) {
    let _timer = clock.time(Stage::Loads);
    let ramp = ramp.map_or(Ramp::Schedule, |r| r.0);
    let stage = stage.map_or(0, |s| s.0);
    let factor = match release {
        Some(release) => released_factor(&step, ramp, Some(release.0), stage),
        None => step.factor_in(ramp, stage),
    };
    let acceleration = body_force.0 * factor;
    for (mass, support) in points.iter() {
        spread_force(
            &(acceleration * mass.0),
            &support.0,
            &mut fields.external_force,
        );
    }
}

/// Declares the scene's body force (once) from its components and how it follows the schedule.
fn declare_body_force(
    builder: &mut crate::scene::SceneBuilder,
    components: &Dynamic,
    ramp: Ramp,
    at: rhai::Position,
) -> Result<Dynamic, String> {
    if let Some(previous) = builder.declared::<BodyForceSpec>().first() {
        return Err(format!(
            "body_force(...) was already called{}; call it once",
            previous.line_note()
        ));
    }
    let force = numbers(components, "body_force(...): the force per unit mass")?;
    if force.is_empty() {
        return Err("body_force(...) needs one component per axis, got []".to_string());
    }
    builder.declare(Located::new(BodyForceSpec(force), at));
    if ramp != Ramp::Schedule {
        builder.declare(Located::new(BodyForceRamp(ramp), at));
    }
    Ok(Dynamic::UNIT)
}
