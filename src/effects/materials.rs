//! Materials as modules: [`MaterialModule<M>`] gives every point of a body whose material is of
//! model `M` its [`PointMaterial<M>`] (and a [`PointHistory<M>`] if `M` carries history), and
//! adds `M`'s stress update at `Hook::StressUpdate`, its history commit at `Hook::PointUpdate`
//! and its output fields at `Hook::PointFields`. A scene whose bodies use two models runs two
//! stress-update systems, each over its own points; a model no body uses schedules nothing.
//! A body switched to or from the model in a later stage (`material_of`,
//! `effects::material_switches`) adds the model's switching systems; a scene without
//! `material_of` schedules none.
//!
//! ```text
//! let modules = impm::effects::built_in().with(MaterialModule::<MyModel>::default());
//! ```
//! registers a model of your own (`examples/custom_material/`).

use std::marker::PhantomData;

use bevy_ecs::prelude::*;

use crate::checkpoint::{self, CheckpointPart};
use crate::components::{BodyIndex, PointId, ReferencePosition, Trial};
use crate::effects::initial_stress::InitialStressSpec;
use crate::effects::material_switches::{
    MaterialSwitches, SwitchPlan, restore_active, save_active, switch_in, switch_out,
};
use crate::material::HistoryValues;
use crate::material::Material;
use crate::plugin::{Extension, Hook, Plugin};
use crate::scene::{FieldSpec, ModelSpec, OptionSpec, SceneApi, SceneSpec};
use crate::stages::output::PointFields;
use crate::stages::{PointHistory, PointMaterial, commit_history, update_stress};

/// The module of material model `M`.
pub struct MaterialModule<M>(PhantomData<fn() -> M>);

impl<M> Default for MaterialModule<M> {
    fn default() -> Self {
        Self(PhantomData)
    }
}

impl<M: Material> Plugin for MaterialModule<M> {
    fn name(&self) -> &'static str {
        M::MODEL
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.word(ModelSpec {
            model: M::MODEL,
            doc: M::describe(),
            parameters: M::parameters().iter().map(OptionSpec::from).collect(),
            check: |parameters| M::from_parameters(parameters).map(|m| m.stiffness_scale()),
        });
        for &(name, _) in M::output_fields() {
            // several models write the same field (`plastic_strain`): one word, one array
            if api.words().fields.iter().any(|field| field.name == name) {
                continue;
            }
            api.word(FieldSpec {
                name,
                doc: "a history field of a material model (zero on points of other models)",
            });
        }
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let names: Vec<&str> = spec
            .materials
            .iter()
            .filter(|m| m.model == M::MODEL)
            .map(|m| m.name.as_str())
            .collect();
        Some(format!("materials {}", names.join(", ")))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.bodies.iter().any(|body| {
            spec.materials
                .get(body.material)
                .is_some_and(|m| m.model == M::MODEL)
        }) || spec
            .part::<MaterialSwitches>()
            .is_some_and(|switches| switches.to_model(spec, M::MODEL))
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        // The model of each body, or None for bodies of other models.
        let mut models = Vec::with_capacity(spec.bodies.len());
        for body in &spec.bodies {
            let Some(material) = spec.materials.get(body.material) else {
                simulation.fail(format!("body '{}' names no material", body.name));
                return;
            };
            if material.model != M::MODEL {
                models.push(None);
                continue;
            }
            match M::from_parameters(&material.parameters) {
                Ok(model) => models.push(Some(model)),
                Err(why) => {
                    simulation.fail(format!("material '{}': {why}", material.name));
                    return;
                }
            }
        }
        // The scene's materials of this model, by index, when a body switches to or from it
        // in a later stage (`material_of`).
        let switches = spec
            .part::<MaterialSwitches>()
            .filter(|switches| switches.involve_model(spec, M::MODEL));
        let mut switch_models = Vec::new();
        if let Some(switches) = switches {
            for material in &spec.materials {
                if material.model != M::MODEL {
                    switch_models.push(None);
                    continue;
                }
                match M::from_parameters(&material.parameters) {
                    Ok(model) => switch_models.push(Some(model)),
                    Err(why) => {
                        simulation.fail(format!("material '{}': {why}", material.name));
                        return;
                    }
                }
            }
            if !M::HAS_HISTORY
                && let Some(to) = switches
                    .0
                    .iter()
                    .find(|s| switch_models[s.material].is_some())
            {
                simulation.fail(format!(
                    "material_of(...){}: model '{}' has no history to hold the body's current stress: a body cannot switch to it",
                    to.line.map(|l| format!(" at line {l}")).unwrap_or_default(),
                    M::MODEL
                ));
                return;
            }
        }
        if models
            .iter()
            .chain(&switch_models)
            .flatten()
            .any(|model| !model.tangent_is_symmetric())
        {
            simulation.nonsymmetric_tangent();
        }
        let world = simulation.world();
        let points: Vec<(Entity, M)> = world
            .query::<(Entity, &BodyIndex)>()
            .iter(world)
            .filter_map(|(entity, body)| Some((entity, models[body.0 as usize].clone()?)))
            .collect();
        if M::HAS_HISTORY {
            world.insert_batch(points.iter().map(|(entity, model)| {
                (
                    *entity,
                    (PointMaterial(model.clone()), PointHistory::<M>::default()),
                )
            }));
        } else {
            world.insert_batch(
                points
                    .iter()
                    .map(|(entity, model)| (*entity, PointMaterial(model.clone()))),
            );
        }
        if let Some(initial) = spec.part::<InitialStressSpec>()
            && let Err(why) = apply_initial_stress::<D, M>(world, &points, initial)
        {
            simulation.fail(why);
            return;
        }
        if let Some(switches) = switches {
            let plan = SwitchPlan::new(spec, switches, switch_models);
            simulation.world().insert_resource(plan);
            simulation
                .add_systems(Hook::Connectivity, switch_out::<D, M>)
                .add_systems(Hook::Constraints, switch_in::<D, M>);
        }
        simulation.add_systems(Hook::StressUpdate, update_stress::<D, M>);
        simulation.point_state(M::MODEL, pack_point::<M>, move |point, body, values| {
            unpack_point(&models, point, body, values)
        });
        if M::HAS_HISTORY {
            simulation.add_systems(Hook::PointUpdate, commit_history::<M>);
        }
        if M::HAS_HISTORY || switches.is_some() {
            simulation.checkpoint(CheckpointPart {
                name: M::MODEL,
                save: save_history::<M>,
                restore: restore_history::<M>,
            });
        }
        if !M::output_fields().is_empty() {
            simulation.add_systems(Hook::PointFields, history_fields::<M>);
        }
    }
}

/// Gives the model's points (`points`) the geostatic stress of `initial` (`initial_stress`):
/// the history `history_from_stress(σ)` (committed and trial, where the points have a
/// `PointHistory`) and the stress of their initial state. An error names the call's line.
fn apply_initial_stress<const D: usize, M: Material>(
    world: &mut World,
    points: &[(Entity, M)],
    initial: &InitialStressSpec,
) -> Result<(), String> {
    for (entity, model) in points {
        let Some(z) = world
            .get::<ReferencePosition<D>>(*entity)
            .map(|x| x.0[D - 1])
        else {
            continue;
        };
        let stress = initial.stress_at(z, D);
        let history = model.history_from_stress(&stress).map_err(|why| {
            format!(
                "initial_stress(...){}: the point at height {z} (model '{}'): {why}",
                initial.line_note,
                M::MODEL
            )
        })?;
        if let Some(mut trial) = world.get_mut::<Trial<D>>(*entity) {
            trial.0.kirchhoff = stress;
        }
        if let Some(mut point) = world.get_mut::<PointHistory<M>>(*entity) {
            point.trial = history.clone();
            point.committed = history;
        }
    }
    Ok(())
}

/// A point's committed history (a `checkpoint::PointStatePart`): nothing for a point of
/// another model or a model without history.
fn pack_point<M: Material>(point: EntityRef<'_>, values: &mut Vec<f64>) {
    if let Some(history) = point.get::<PointHistory<M>>() {
        history.committed.write(values);
    }
}

/// Gives a point of `body` the body's model (`models`, by body, `None` for bodies of other
/// models) and the committed history `values` (trial = committed, as at a step's start).
fn unpack_point<M: Material>(
    models: &[Option<M>],
    point: &mut EntityWorldMut<'_>,
    body: u32,
    values: &[f64],
) -> Result<(), String> {
    let Some(model) = models.get(body as usize).cloned().flatten() else {
        return match values.is_empty() {
            true => Ok(()),
            false => Err(format!(
                "a history for a point of body {body}, not of this model"
            )),
        };
    };
    point.insert(PointMaterial(model));
    if M::HAS_HISTORY {
        let committed = M::History::read(values).ok_or("the history is not valid")?;
        point.insert(PointHistory::<M> {
            trial: committed.clone(),
            committed,
        });
    } else if !values.is_empty() {
        return Err("a history for a model without one".into());
    }
    Ok(())
}

/// The committed history of the model's points: (point id, values) records in id order;
/// in a scene with material switches first the material each body holds of the model
/// (`material_switches::save_active`).
fn save_history<M: Material>(world: &mut World) -> Vec<f64> {
    let mut values = Vec::new();
    save_active::<M>(world, &mut values);
    if !M::HAS_HISTORY {
        return values;
    }
    let mut rows: Vec<(u32, M::History)> = world
        .query::<(&PointId, &PointHistory<M>)>()
        .iter(world)
        .map(|(id, h)| (id.0, h.committed.clone()))
        .collect();
    rows.sort_by_key(|(id, _)| *id);
    values.reserve(rows.len() * (1 + M::History::LEN));
    for (id, history) in rows {
        values.push(id as f64);
        history.write(&mut values);
    }
    values
}

fn restore_history<M: Material>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let values = restore_active::<M>(world, values)?;
    if !M::HAS_HISTORY {
        return match values.is_empty() {
            true => Ok(()),
            false => Err("a history for a model without one".into()),
        };
    }
    let mut query = world.query::<(&PointId, &mut PointHistory<M>)>();
    let count = query.iter(world).len();
    let mut saved = std::collections::HashMap::with_capacity(count);
    for record in checkpoint::records(values, 1 + M::History::LEN, count)? {
        let history = M::History::read(&record[1..]).ok_or("a saved history is not valid")?;
        saved.insert(record[0] as u32, history);
    }
    for (id, mut history) in query.iter_mut(world) {
        let committed = saved
            .remove(&id.0)
            .ok_or_else(|| format!("no saved history for point {}", id.0))?;
        history.trial = committed.clone();
        history.committed = committed;
    }
    Ok(())
}

/// The model's output fields from the committed history. Points of other models get zeros, or
/// keep what another model with a field of the same name wrote: all models' values of one
/// field name end up in one array (`plastic_strain` of a von Mises and a Mohr–Coulomb body).
fn history_fields<M: Material>(
    mut out: ResMut<PointFields>,
    all: Query<&PointId>,
    points: Query<(&PointId, &PointHistory<M>)>,
) {
    // indexed by PointId: a process of a decomposed run holds some of the ids only
    let count = all.iter().map(|id| id.0 as usize + 1).max().unwrap_or(0);
    let mut values = Vec::new();
    let mut offset = 0;
    for &(name, components) in M::output_fields() {
        let index = match out
            .0
            .iter()
            .position(|field| field.name == name && field.components == components)
        {
            Some(index) => index,
            None => {
                out.0.push(crate::stages::output::PointField {
                    name,
                    components,
                    values: vec![0.0; components * count],
                });
                out.0.len() - 1
            }
        };
        let field = &mut out.0[index].values;
        for (id, history) in points.iter() {
            values.clear();
            M::output_values(&history.committed, &mut values);
            let start = components * id.0 as usize;
            if let (Some(slot), Some(value)) = (
                field.get_mut(start..start + components),
                values.get(offset..offset + components),
            ) {
                slot.copy_from_slice(value);
            }
        }
        offset += components;
    }
}
