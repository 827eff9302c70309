//! Materials changed in a later stage: `material_of(#{ body: "soil", material: "soft" })`
//! declared in stage s (`scene::stages`) gives the body's points the named material from the
//! start of stage s on ("change materials" of a staged analysis).
//!
//! At the start of stage s every point p of the body keeps its position, `F_p` and stress; its
//! old model's stress at the committed state (the response at `Δf = I`, which is the stress of
//! the last converged step) becomes the new model's starting point through the new model's
//! `Material::history_from_stress` (the seam the geostatic initial stresses use):
//!
//! ```text
//!   τ_p = τ_old(F_p, h_p)            (Δf = I: the committed state)
//!   h_p ← h_new(τ_p)                 elasto-plastic models: b_e = exp(2 D_e⁻¹ τ_p) on the
//!                                    principal axes of τ_p, ε̄_p = 0
//! ```
//!
//! so that the new model's response at the stage's start is `τ_p` again (to round-off: the
//! elastic law inverted and applied once more), and the following steps load or unload from
//! there with the new model's elasticity and yield surface. The points keep their mass (the
//! new material's density is not used).
//!
//! # The plastic strain carried
//!
//! Where both models keep the accumulated equivalent plastic strain (their history is the
//! elasto-plastic [`PlasticHistory`]: von Mises, Drucker–Prager, Mohr–Coulomb) the new history
//! takes the old `ε̄_p` (a hardening von Mises model goes on from its hardened yield stress
//! `σ_y + H ε̄_p`, and the output's `plastic_strain` continues); from a model without it
//! (Hencky) it starts from zero.
//!
//! # A state on the yield surface
//!
//! `history_from_stress` checks the stress against the new surface at `ε̄_p = 0` and refuses a
//! stress its return map finds outside; a point that yielded under the old model lies *on* a
//! surface, and when the new surface passes through it (the same surface, or one that touches
//! it there) round-off may put it just outside. When the check refuses, or when a plastic strain
//! is carried (the surface then is the one at `ε̄_p`), the switch instead builds the elastic
//! history of `τ_p` without the check ([`elastic_history_unchecked`]: `ln b_e = 2 D_e⁻¹ τ` is
//! linear in `τ`, so it follows from two stresses the check accepts), and evaluates the new
//! model at it (`Δf = I`): its return map gives the closest admissible stress `τ_r`. The
//! switch accepts the projected state when
//!
//! ```text
//!   ‖τ_r − τ_p‖ ≤ 1e-6 q(τ_r)          (q: the von Mises equivalent stress, the yield stress
//!                                     of the new surface at that pressure)
//! ```
//!
//! ([`ON_SURFACE_TOLERANCE`]: round-off of the exp/log chain is `~1e-16 E/σ_y` relative, so
//! this holds for `E/σ_y` up to 1e9), and otherwise stops the run at the stage's start with an
//! error naming the `material_of` line, the body, the stage, the point and the departure.
//!
//! Refused: a switch to a model whose stress is a function of the deformation alone (the
//! hyperelastic `hencky`): its stress from the current `F` would not be `τ_p` (after plastic
//! flow, or with other elastic constants the stress would jump), and its history cannot hold
//! a stress.
//!
//! A point's model is which `PointMaterial<M>` component it carries (one stress-update system
//! per model kind, `effects::materials`): the old kind's module takes its components away at
//! `Hook::Connectivity` of the stage's first step (leaving the stress τ_p as a
//! [`SwitchStress`]), the new kind's module gives its own at `Hook::Constraints`. Those
//! systems are scheduled only by the modules of the models a `material_of` involves: a scene
//! without `material_of` schedules nothing new. Which material each body holds is a part of
//! the models' checkpoint parts, so that a run resumed after a switch continues with it.

use std::any::Any;

use bevy_ecs::prelude::*;
use nalgebra::{Matrix3, SMatrix};

use crate::components::{BodyIndex, DeformationGradient, PointId};
use crate::material::{Material, PlasticHistory};
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

/// A point's state at the start of the stage that switches its material: left by the old
/// model's module, taken by the new one's (module docs).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[component(storage = "SparseSet")]
pub struct SwitchStress {
    /// The old model's Kirchhoff stress at the committed state.
    pub stress: Matrix3<f64>,
    /// Its accumulated equivalent plastic strain, where its history has one.
    pub plastic_strain: Option<f64>,
}

/// How far (relative to the yield stress there, module docs) a stress may lie outside the new
/// model's yield surface and still be taken, projected onto it by the new model's return map.
pub const ON_SURFACE_TOLERANCE: f64 = 1e-6;

/// The elasto-plastic part of a history, if it is one.
fn plastic_part<H: Any>(history: &H) -> Option<&PlasticHistory> {
    (history as &dyn Any).downcast_ref()
}

/// The elastic history of the stress `tau` under model `model` without the yield check of
/// `history_from_stress`: `ln b_e = 2 D_e⁻¹ τ = dev τ / G + 2 tr τ / (9K) I` is linear in
/// `τ`, so with two stresses the check accepts, `σ₁ = p₀ I` and `σ₂ = p₀ I + ε dev τ` (`p₀`
/// compressive, where every surface is widest; `ε` halved until accepted),
/// `ln b_e(τ) = (ln b_e(σ₂) − ln b_e(σ₁))/ε + (p/p₀) ln b_e(σ₁)`. `None` when the model keeps
/// no such history or accepts no such pair.
pub fn elastic_history_unchecked<M: Material>(model: &M, tau: &Matrix3<f64>) -> Option<M::History> {
    let log = |sigma: &Matrix3<f64>| -> Option<Matrix3<f64>> {
        let history = model.history_from_stress(sigma).ok()?;
        let b = plastic_part(&history)?.elastic_left_cauchy_green;
        let eigen = b.symmetric_eigen();
        Some(
            eigen.eigenvectors
                * Matrix3::from_diagonal(&eigen.eigenvalues.map(f64::ln))
                * eigen.eigenvectors.transpose(),
        )
    };
    let mean = tau.trace() / 3.0;
    let deviator = tau - Matrix3::identity() * mean;
    let p0 = -4.0 * tau.norm().max(f64::MIN_POSITIVE.sqrt());
    let first = log(&(Matrix3::identity() * p0))?;
    let (epsilon, second) = (0..40).find_map(|k| {
        let epsilon = 0.5f64.powi(k);
        log(&(Matrix3::identity() * p0 + deviator * epsilon)).map(|l| (epsilon, l))
    })?;
    let ln_b = (second - first) / epsilon + first * (mean / p0);
    let eigen = ln_b.symmetric_eigen();
    let b = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(f64::exp))
        * eigen.eigenvectors.transpose();
    let mut history = model
        .history_from_stress(&(Matrix3::identity() * p0))
        .ok()?;
    let plastic = (&mut history as &mut dyn Any).downcast_mut::<PlasticHistory>()?;
    plastic.elastic_left_cauchy_green = (b + b.transpose()) * 0.5;
    Some(history)
}

/// The new model's history for a point switched with `start` (module docs): the history of its
/// stress with the plastic strain carried, projected onto the new surface within
/// [`ON_SURFACE_TOLERANCE`]; an error says why not.
pub fn history_at_switch<const D: usize, M: Material>(
    model: &M,
    start: &SwitchStress,
    deformation_gradient: &SMatrix<f64, D, D>,
) -> Result<M::History, String> {
    let tau = start.stress;
    let (mut history, refused) = match model.history_from_stress(&tau) {
        Ok(history) => (history, None),
        Err(why) => match elastic_history_unchecked(model, &tau) {
            Some(history) => (history, Some(why)),
            None => return Err(why),
        },
    };
    let carried = start.plastic_strain.filter(|&e| e > 0.0);
    if let (Some(strain), Some(plastic)) = (
        carried,
        (&mut history as &mut dyn Any).downcast_mut::<PlasticHistory>(),
    ) {
        plastic.plastic_strain = strain;
    }
    if refused.is_none() && carried.is_none() {
        return Ok(history);
    }
    let (state, projected) =
        trial_state_with_history(model, &history, deformation_gradient, &SMatrix::identity())
            .map_err(|why| format!("the new model's response at the switch: {why}"))?;
    if !plastic_part(&projected).is_some_and(|p| p.yielding) && refused.is_none() {
        return Ok(history);
    }
    let returned = state.kirchhoff;
    let deviator = returned - Matrix3::identity() * (returned.trace() / 3.0);
    let yield_stress = (1.5 * deviator.norm_squared()).sqrt();
    let departure = (returned - tau).norm();
    if departure <= ON_SURFACE_TOLERANCE * yield_stress {
        return Ok(projected);
    }
    Err(format!(
        "{}: the stress lies outside the new yield surface by {:.3e} of the yield stress there ({:.6e}), beyond the {ON_SURFACE_TOLERANCE:e} within which a state on the surface is projected onto it",
        refused.unwrap_or_else(|| "with the plastic strain carried".to_string()),
        departure / yield_stress.max(f64::MIN_POSITIVE),
        yield_stress
    ))
}

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
            "in a later stage of a staged scene: the body takes the named material from the stage's start on; the new model starts from the current stress (its history from the stress, as for initial stresses; the accumulated plastic strain carried where both models keep it; a state on the new yield surface within 1e-6 of its yield stress projected onto it; positions, F and mass stay). Not to a model whose stress is a function of the deformation alone (hencky) (docs/plasticity.md, \"Staged analysis\")",
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
/// keep their stress as a [`SwitchStress`] and lose `M`'s components.
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
            Ok((state, _)) => stresses.push((
                entity,
                SwitchStress {
                    stress: state.kirchhoff,
                    plastic_strain: plastic_part(committed).map(|p| p.plastic_strain),
                },
            )),
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
/// step's stage get it, with the history `history_from_stress` of their [`SwitchStress`].
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
    let mut query = world.query::<(
        Entity,
        &PointId,
        &BodyIndex,
        &DeformationGradient<D>,
        Option<&SwitchStress>,
    )>();
    let mut given = Vec::new();
    for (entity, id, body, f, start) in query.iter(world) {
        let Some((_, _, model, note)) = arriving.iter().find(|a| a.0 == body.0 as usize) else {
            continue;
        };
        let history = match start {
            Some(start) => history_at_switch(model, start, &f.0),
            None => Err("the old model left no stress".to_string()),
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
        point.remove::<SwitchStress>().insert(PointMaterial(model));
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
