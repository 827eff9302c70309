//! Materials changed in a later stage: `material_of(#{ body: "soil", material: "soft" })`
//! declared in stage s (`scene::stages`) gives the body's points the named material from the
//! start of stage s on ("change materials" of a staged analysis).
//!
//! At the start of stage s every point p of the body keeps its position, `F_p` and mass (the
//! new material's density is not used); what else it carries is said by the two models through
//! the `Material` trait (`material` module docs, "Handing a point over to another model"): the
//! old model's `hand_over` gives its stress at the committed state (the response at `Δf = I`,
//! the stress of the last converged step) and the internal variables it keeps, the new model's
//! `take_over` makes its committed history of them, or says why it cannot:
//!
//! ```text
//!   τ_p = τ_old(F_p, h_p)                         (Δf = I: the committed state)
//!   carried = hand_over_old(h_p, {F_p, τ_p})      + b_e, ε̄_p where the old model keeps them
//!   h_p ← take_over_new(carried)                  or the run stops at the stage's start
//! ```
//!
//! This module only moves the [`CarriedState`] from the old model's points to the new one's
//! (as the component [`CarriedAtSwitch`]) and reports a refusal with the `material_of` line,
//! the body, the stage and the point. A user's model with its own history type takes part by
//! implementing the two methods (`tests/stages_switch_custom.rs` switches such a model to and
//! from von Mises).
//!
//! # The crate's models
//!
//! The elasto-plastic models (von Mises, Drucker–Prager, Mohr–Coulomb) hand over `b_e` and the
//! accumulated equivalent plastic strain `ε̄_p`, and take over through
//! `material::elastoplastic::take_over`: the new history is the one of the stress
//! (`history_from_stress`, the seam the geostatic initial stresses use: `b_e = exp(2 D_e⁻¹ τ_p)`
//! on the principal axes of `τ_p`), so that the new model's response at the stage's start is
//! `τ_p` again (to round-off), with the carried `ε̄_p` (a hardening von Mises model goes on from
//! its hardened yield stress `σ_y + H ε̄_p`, and the output's `plastic_strain` continues); from
//! a model that keeps none (Hencky) it starts from zero. A yielded point lies *on* the old
//! surface; where the new surface passes through it, round-off may put it just outside: its
//! state is projected onto the new surface by the new model's return map when the departure is
//! within `1e-6` of the yield stress there (`ON_SURFACE_TOLERANCE`) and refused beyond, with the
//! departure. A model that keeps no plastic strain and keeps the trait's default `take_over`
//! refuses a carried `ε̄_p > 0` (it would be lost).
//!
//! Refused: a switch to a model whose stress is a function of the deformation alone (the
//! hyperelastic `hencky`): its stress from the current `F` would not be `τ_p` (after plastic
//! flow, or with other elastic constants the stress would jump), and its history cannot hold
//! a stress (a model without history is refused when the scene is built).
//!
//! A point's model is which `PointMaterial<M>` component it carries (one stress-update system
//! per model kind, `effects::materials`): the old kind's module takes its components away at
//! `Hook::Connectivity` of the stage's first step (leaving what it hands over as a
//! [`CarriedAtSwitch`]), the new kind's module gives its own at `Hook::Constraints`. Those
//! systems are scheduled only by the modules of the models a `material_of` involves: a scene
//! without `material_of` schedules nothing new. Which material each body holds is a part of
//! the models' checkpoint parts, so that a run resumed after a switch continues with it.

use bevy_ecs::prelude::*;
use nalgebra::SMatrix;

use crate::components::{BodyIndex, DeformationGradient, PointId};
use crate::material::{CarriedState, Material, embed};
use crate::mechanics::trial_state_with_history;
use crate::plugin::{Extension, Plugin};
use crate::resources::{CurrentStage, LoadStep, RunStatus, SolverError};
use crate::scene::{
    CallSpec, Kind, Located, OptionSpec, Options, Resolver, SceneApi, SceneSpec, ScriptError,
    Stages,
};
use crate::stages::{PointHistory, PointMaterial};

/// One `material_of(...)` call as declared (names resolved later).
#[derive(Clone, Debug, PartialEq)]
struct MaterialOfDeclaration {
    body: String,
    material: String,
}

/// A body given another material from the start of a stage.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialSwitch {
    /// Index into `SceneSpec::bodies`.
    pub body: usize,
    /// Index into `SceneSpec::materials`.
    pub material: usize,
    /// The stage whose start switches it (≥ 1).
    pub stage: usize,
    /// The line of the `material_of` call.
    pub line: Option<usize>,
}

/// The scene's material switches (a part of the scene when it calls `material_of`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialSwitches(pub Vec<MaterialSwitch>);

impl MaterialSwitches {
    /// The switch that gives body `body` its material in stage `stage` (the last one declared
    /// for a stage up to `stage`), if any.
    pub fn in_force(&self, body: usize, stage: usize) -> Option<&MaterialSwitch> {
        self.0
            .iter()
            .filter(|s| s.body == body && s.stage <= stage)
            .max_by_key(|s| s.stage)
    }

    /// The material of body `body` in stage `stage`, `initial` before any switch.
    pub fn material_in(&self, body: usize, stage: usize, initial: usize) -> usize {
        self.in_force(body, stage).map_or(initial, |s| s.material)
    }

    /// Whether a switch gives some body a material of model `model`.
    pub fn to_model(&self, spec: &SceneSpec, model: &str) -> bool {
        self.0.iter().any(|s| {
            spec.materials
                .get(s.material)
                .is_some_and(|m| m.model == model)
        })
    }

    /// Whether a body of model `model` (at the start or after a switch) is switched.
    pub fn involve_model(&self, spec: &SceneSpec, model: &str) -> bool {
        let of = |material: usize| {
            spec.materials
                .get(material)
                .is_some_and(|m| m.model == model)
        };
        self.to_model(spec, model)
            || self.0.iter().any(|s| {
                spec.bodies
                    .get(s.body)
                    .is_some_and(|body| of(body.material))
            })
    }
}

/// A point's state at the start of the stage that switches its material: handed over by the
/// old model's module, taken over by the new one's (module docs).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[component(storage = "SparseSet")]
pub struct CarriedAtSwitch(pub CarriedState);

/// What the module of model `M` needs to switch bodies to and from it.
#[derive(Resource)]
pub struct SwitchPlan<M: Material> {
    switches: MaterialSwitches,
    /// The material of each body at the start.
    initial: Vec<usize>,
    /// The model of each material of model `M` (by material index; `None` for other models).
    models: Vec<Option<M>>,
    /// Per body: the material of model `M` its points hold now (`None`: another model's).
    pub active: Vec<Option<usize>>,
    /// The bodies' and the stages' names, for messages.
    body_names: Vec<String>,
    stage_names: Vec<String>,
}

impl<M: Material> SwitchPlan<M> {
    /// The plan of a scene (`models`: the scene's materials of model `M`, by index).
    pub fn new(spec: &SceneSpec, switches: &MaterialSwitches, models: Vec<Option<M>>) -> Self {
        let initial: Vec<usize> = spec.bodies.iter().map(|b| b.material).collect();
        let active = initial
            .iter()
            .map(|&m| models.get(m).and_then(Option::as_ref).map(|_| m))
            .collect();
        Self {
            switches: switches.clone(),
            initial,
            models,
            active,
            body_names: spec.bodies.iter().map(|b| b.name.clone()).collect(),
            stage_names: spec
                .part::<Stages>()
                .map(|s| s.0.iter().map(|stage| stage.name.clone()).collect())
                .unwrap_or_default(),
        }
    }

    /// The material body `body` has in stage `stage`.
    fn material_in(&self, body: usize, stage: usize) -> usize {
        self.switches.material_in(body, stage, self.initial[body])
    }

    /// "material_of(...) at line N (body 'b', stage 's')" for messages.
    fn line_note(&self, body: usize, stage: usize) -> String {
        let line = match self.switches.in_force(body, stage).and_then(|s| s.line) {
            Some(line) => format!(" at line {line}"),
            None => String::new(),
        };
        let name = |names: &[String], i: usize| names.get(i).cloned().unwrap_or_default();
        format!(
            "material_of(...){line} (body '{}', stage '{}')",
            name(&self.body_names, body),
            name(&self.stage_names, stage)
        )
    }
}

/// The `material_of(...)` call and its part of the scene.
#[derive(Clone, Copy, Debug, Default)]
pub struct MaterialSwitchesModule;

impl Plugin for MaterialSwitchesModule {
    fn name(&self) -> &'static str {
        "material switches"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::options(
            "material_of",
            "in a later stage of a staged scene: the body takes the named material from the stage's start on; positions, F and mass stay; the old model hands over its current stress and the internal variables it keeps, the new one takes them over (Material::hand_over / take_over; the crate's plastic models: the history of the stress, as for initial stresses, with the accumulated plastic strain carried, a state on the new yield surface within 1e-6 of its yield stress projected onto it); what the new model cannot take stops the run with this line. Not to a model whose stress is a function of the deformation alone (hencky) (docs/plasticity.md, \"Staged analysis\")",
            vec![
                OptionSpec::required("body", Kind::Text, "the body's name"),
                OptionSpec::required(
                    "material",
                    Kind::Text,
                    "the name of the material it takes (declared with material(...))",
                ),
            ],
            |builder, options: &Options, at| {
                builder.declare(Located::new(
                    MaterialOfDeclaration {
                        body: options.text("body").unwrap_or_default().to_string(),
                        material: options.text("material").unwrap_or_default().to_string(),
                    },
                    at,
                ));
                Ok(rhai::Dynamic::UNIT)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let declared = scene.declarations::<MaterialOfDeclaration>().to_vec();
        if declared.is_empty() {
            return Ok(());
        }
        let spec = &*scene.spec;
        let mut switches = MaterialSwitches::default();
        for call in &declared {
            let refuse = |why: String| Err(ScriptError::at(call.at, why));
            if call.stage == 0 || spec.part::<Stages>().is_none_or(|s| s.0.len() < 2) {
                return refuse(
                    "material_of(...) switches a body's material at the start of a later stage: declare it after the second stage(...) (the first stage's material is the one body(...) names)".to_string(),
                );
            }
            let Some(body) = spec.bodies.iter().position(|b| b.name == call.value.body) else {
                let names: Vec<&str> = spec.bodies.iter().map(|b| b.name.as_str()).collect();
                return refuse(format!(
                    "material_of(...): no body is named '{}' (the bodies: {})",
                    call.value.body,
                    names.join(", ")
                ));
            };
            let Some(material) = spec
                .materials
                .iter()
                .position(|m| m.name == call.value.material)
            else {
                let names: Vec<&str> = spec.materials.iter().map(|m| m.name.as_str()).collect();
                return refuse(format!(
                    "material_of(...): no material is named '{}' (the materials: {})",
                    call.value.material,
                    names.join(", ")
                ));
            };
            let model = spec.materials[material].model.as_str();
            if model == "hencky" {
                return refuse(format!(
                    "material_of(...): material '{}' is of the hyperelastic model 'hencky', whose stress is a function of the deformation alone: it cannot take over the body's current stress (the stress would jump); switch to a plastic model (von_mises, drucker_prager, mohr_coulomb)",
                    call.value.material
                ));
            }
            if let Some(twice) = switches
                .0
                .iter()
                .find(|s| s.body == body && s.stage == call.stage)
            {
                return refuse(format!(
                    "material_of(...): body '{}' already takes another material in this stage{}; one switch per body and stage",
                    call.value.body,
                    twice
                        .line
                        .map(|l| format!(" (line {l})"))
                        .unwrap_or_default()
                ));
            }
            switches.0.push(MaterialSwitch {
                body,
                material,
                stage: call.stage,
                line: call.at.line(),
            });
        }
        scene.spec.set_part(switches);
        Ok(())
    }

    /// Every switch: the body, the material and its model, the stage and the line.
    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let switches = spec.part::<MaterialSwitches>()?;
        let stages = spec.part::<Stages>();
        let lines: Vec<String> = switches
            .0
            .iter()
            .map(|s| {
                let material = &spec.materials[s.material];
                format!(
                    "body '{}' takes material '{}' ({}) from the start of stage '{}'{}",
                    spec.bodies[s.body].name,
                    material.name,
                    material.model,
                    stages.map_or("", |st| st.name(s.stage)),
                    s.line.map(|l| format!(" (line {l})")).unwrap_or_default()
                )
            })
            .collect();
        Some(lines.join("; "))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<MaterialSwitches>()
            .is_some_and(|s| !s.0.is_empty())
    }

    /// Nothing of its own: the models' modules switch their points (module docs).
    fn build<const D: usize>(&self, _: &mut Extension<'_, D>) {}
}

/// At `Hook::Connectivity`: the points of the bodies that leave model `M` in the step's stage
/// keep what `M` hands over (`Material::hand_over`) as a [`CarriedAtSwitch`] and lose `M`'s
/// components.
pub fn switch_out<const D: usize, M: Material>(world: &mut World) {
    let stage = world.resource::<CurrentStage>().0;
    let plan = world.resource::<SwitchPlan<M>>();
    let leaving: Vec<usize> = (0..plan.active.len())
        .filter(|&b| plan.active[b].is_some_and(|m| m != plan.material_in(b, stage)))
        .collect();
    if leaving.is_empty() {
        return;
    }
    let mut query = world.query::<(
        Entity,
        &PointId,
        &BodyIndex,
        &DeformationGradient<D>,
        &PointMaterial<M>,
        Option<&PointHistory<M>>,
    )>();
    let none = M::History::default();
    let mut stresses = Vec::new();
    for (entity, id, body, f, material, history) in query.iter(world) {
        if !leaving.contains(&(body.0 as usize)) {
            continue;
        }
        let committed = history.map_or(&none, |h| &h.committed);
        match trial_state_with_history(&material.0, committed, &f.0, &SMatrix::identity()) {
            Ok((state, _)) => {
                let carried = CarriedState::of_stress(embed(&f.0), state.kirchhoff);
                stresses.push((
                    entity,
                    CarriedAtSwitch(material.0.hand_over(committed, carried)),
                ));
            }
            Err(why) => {
                let what = format!(
                    "{}: material point {}: the stress of model '{}' at the stage's start: {why}",
                    plan_note::<M>(world, body.0 as usize, stage),
                    id.0,
                    M::MODEL
                );
                return fail(world, what);
            }
        }
    }
    for (entity, stress) in stresses {
        world
            .entity_mut(entity)
            .insert(stress)
            .remove::<(PointMaterial<M>, PointHistory<M>)>();
    }
    let mut plan = world.resource_mut::<SwitchPlan<M>>();
    for body in leaving {
        plan.active[body] = None;
    }
}

/// At `Hook::Constraints`: the points of the bodies that take a material of model `M` in the
/// step's stage get it, with the history `Material::take_over` makes of their
/// [`CarriedAtSwitch`].
pub fn switch_in<const D: usize, M: Material>(world: &mut World) {
    let stage = world.resource::<CurrentStage>().0;
    let plan = world.resource::<SwitchPlan<M>>();
    // (body, material, its model, the line of its switch)
    let arriving: Vec<(usize, usize, M, String)> = (0..plan.active.len())
        .filter_map(|b| {
            let m = plan.material_in(b, stage);
            let model = plan.models.get(m).cloned().flatten()?;
            (plan.active[b] != Some(m)).then(|| (b, m, model, plan.line_note(b, stage)))
        })
        .collect();
    if arriving.is_empty() {
        return;
    }
    let mut query = world.query::<(Entity, &PointId, &BodyIndex, Option<&CarriedAtSwitch>)>();
    let mut given = Vec::new();
    for (entity, id, body, start) in query.iter(world) {
        let Some((_, _, model, note)) = arriving.iter().find(|a| a.0 == body.0 as usize) else {
            continue;
        };
        let history = match start {
            Some(carried) => model.take_over(&carried.0),
            None => Err("the old model handed over no state".to_string()),
        };
        match history {
            Ok(history) => given.push((entity, model.clone(), history)),
            Err(why) => {
                let what = format!(
                    "{note}: material point {} cannot take model '{}' with its current stress: {why}",
                    id.0,
                    M::MODEL
                );
                return fail(world, what);
            }
        }
    }
    for (entity, model, history) in given {
        let mut point = world.entity_mut(entity);
        point
            .remove::<CarriedAtSwitch>()
            .insert(PointMaterial(model));
        if M::HAS_HISTORY {
            point.insert(PointHistory::<M> {
                trial: history.clone(),
                committed: history,
            });
        }
    }
    let mut plan = world.resource_mut::<SwitchPlan<M>>();
    for (body, material, _, _) in arriving {
        plan.active[body] = Some(material);
    }
}

fn plan_note<M: Material>(world: &World, body: usize, stage: usize) -> String {
    world.resource::<SwitchPlan<M>>().line_note(body, stage)
}

fn fail(world: &mut World, what: String) {
    let step = world.resource::<LoadStep>().number;
    world.resource_mut::<RunStatus>().fail(SolverError::Module {
        step,
        what,
        recoverable: false,
    });
}

/// The material each body holds of model `M` (`-1`: another model's), for the checkpoint.
pub fn save_active<M: Material>(world: &World, values: &mut Vec<f64>) {
    if let Some(plan) = world.get_resource::<SwitchPlan<M>>() {
        values.extend(plan.active.iter().map(|a| a.map_or(-1.0, |m| m as f64)));
    }
}

/// Gives the bodies the materials of model `M` they held when `values` were saved (the first
/// values; the rest are returned): the components of `M` (a default history, which the
/// checkpoint's histories then fill) on the bodies that held one, none on the others.
pub fn restore_active<'v, M: Material>(
    world: &mut World,
    values: &'v [f64],
) -> Result<&'v [f64], String> {
    let Some(plan) = world.get_resource::<SwitchPlan<M>>() else {
        return Ok(values);
    };
    let bodies = plan.active.len();
    if values.len() < bodies {
        return Err(format!(
            "the materials of {bodies} bodies were not saved ({} numbers)",
            values.len()
        ));
    }
    let (saved, rest) = values.split_at(bodies);
    // per body: the material of model `M` it held, and that model
    let mut held: Vec<Option<(usize, M)>> = Vec::with_capacity(bodies);
    for &value in saved {
        held.push(match value {
            v if v < 0.0 => None,
            v => {
                let m = v as usize;
                let Some(model) = plan.models.get(m).cloned().flatten() else {
                    return Err(format!("material {m} is not of model '{}'", M::MODEL));
                };
                Some((m, model))
            }
        });
    }
    let mut query = world.query::<(Entity, &BodyIndex)>();
    let points: Vec<(Entity, usize)> = query.iter(world).map(|(e, b)| (e, b.0 as usize)).collect();
    for (entity, body) in points {
        let mut point = world.entity_mut(entity);
        match held.get(body).cloned().flatten() {
            Some((_, model)) => {
                point.insert(PointMaterial(model));
                if M::HAS_HISTORY {
                    point.insert(PointHistory::<M>::default());
                }
            }
            None => {
                point.remove::<(PointMaterial<M>, PointHistory<M>)>();
            }
        }
    }
    let held = held.into_iter().map(|h| h.map(|(m, _)| m)).collect();
    world.resource_mut::<SwitchPlan<M>>().active = held;
    Ok(rest)
}
