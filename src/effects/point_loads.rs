//! Point loads: concentrated forces on material points (paper eq. 9),
//!
//! ```text
//!   f_ext,i += λ Σ_p P_p N_i(x_p),
//! ```
//!
//! for every point p that carries a [`PointLoad`] (`point_load` / `point_load_total` in scenes).
//! The load moves with its point. The output gains the point field `point_load` (λ P, zero on
//! unloaded points).
//!
//! In a staged scene (`scene::stages`) a load declared in stage k is absent before stage k,
//! follows stage k's own λ in it and is held in full after it (`LoadStep::factor_in`).
//! `point_load(.., #{ held: true })` applies it in full from its stage's start instead
//! (`resources::Ramp::Held` / `HeldFrom`), and `#{ until_stage: "s" }` releases it at the start
//! of the later stage s: ramped down over that stage from its value at the end of the stage
//! before, `(1 − λ_s) P`, and absent after it (`declarations::released_factor`). The loads of
//! the first stage that follow the schedule are the [`PointLoad`]s (as in a scene without
//! stages); the others (later stages, held, released) the points' [`LaterPointLoads`] (a point
//! state of their own, only in a scene that has them).
//!
//! **Decomposed points** (`mpirun -n N impm run SCENE --decompose`): a load is a component of
//! its point, given when the simulation is built by the process that holds the point (found
//! by `PointId`; the other processes leave it), and both components are point-state parts, so
//! the load travels in the point's record when the point moves to another process
//! (`distributed::respawn`). Each process spreads the loads of its own points; `f_ext` is
//! summed over the processes after the loads. The `point_load` field is indexed by `PointId`
//! (each process's piece of the particle file writes its own points').

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use std::collections::BTreeMap;

use rhai::{Dynamic, FnPtr};

use super::arc_length::add_load_system;
use super::declarations::{
    LoadSummary, factor_one, grouped, held_option, keep_largest_force, released_factor,
    selection_ranges, until_stage_of, until_stage_option,
};
use crate::components::{PointId, Support};
use crate::mechanics::spread_force;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{CurrentStage, GridFields, LoadStep, Ramp, Stage, StageClock};
use crate::scene::{
    CallSpec, FieldSpec, Located, Options, Resolver, SceneApi, SceneBuilder, SceneSpec,
    ScriptError, function, numbers,
};
use crate::stages::output::{PointFields, pad};

/// A force on one material point at load factor 1 (paper eq. 9, a concentrated term of the
/// external force): it adds λ P N_i(x_p) to the external force of the point's support nodes.
#[derive(Clone, Debug, PartialEq)]
pub struct PointLoadSpec {
    /// Global point index: points are numbered body after body, in seeding order (`PointId`).
    pub point: usize,
    /// The force P (length = dimension).
    pub force: Vec<f64>,
    /// How it follows the schedule: its stage (0 without stages), held or ramped.
    pub ramp: Ramp,
    /// The stage whose start releases it (`until_stage`), if any.
    pub until: Option<usize>,
}

impl PointLoadSpec {
    /// Whether it is a load of the first stage that follows the schedule and is never
    /// released (a [`PointLoad`]; the others are [`LaterPointLoads`]).
    fn is_plain(&self) -> bool {
        self.ramp == Ramp::Schedule && self.until.is_none()
    }
}

/// The scene's point loads (summed per point).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointLoads(pub Vec<PointLoadSpec>);

/// Each `point_load` / `point_load_total` as `impm check` lists it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointLoadDeclarations(pub Vec<LoadSummary>);

/// How a point load's force is given to the points its selector picks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Share {
    /// Every selected point carries the whole force (`point_load`).
    Each,
    /// The force is the total, shared in proportion to reference volume (`point_load_total`).
    Total,
}

/// `point_load` / `point_load_total`: a force on the material points whose reference position
/// the selector accepts.
#[derive(Clone, Debug)]
struct PointLoadDeclaration {
    function: &'static str,
    selector: FnPtr,
    force: Vec<f64>,
    share: Share,
    ramp: Ramp,
    until: Option<String>,
}

/// A force on the material point at load factor 1; only points that carry one have it.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct PointLoad<const D: usize>(pub SVector<f64, D>);

/// The other forces on the material point (of later stages, held or released): `(how it
/// follows the schedule, the stage that releases it, force at load factor 1)`; only points
/// that carry one have it.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct LaterPointLoads<const D: usize>(pub Vec<(Ramp, Option<usize>, SVector<f64, D>)>);

impl<const D: usize> LaterPointLoads<D> {
    /// Σ_k f_k P_k in `step` of stage `stage`, f_k each load's factor (module docs).
    fn force(&self, step: &LoadStep, stage: usize) -> SVector<f64, D> {
        self.0
            .iter()
            .map(|(ramp, until, force)| force * released_factor(step, *ramp, *until, stage))
            .sum()
    }
}

/// The module: scheduled when some point carries a non-zero load.
#[derive(Clone, Copy, Debug, Default)]
pub struct PointLoadsModule;

impl Plugin for PointLoadsModule {
    fn name(&self) -> &'static str {
        "point loads"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        for (name, share, signature, doc) in [
            (
                "point_load",
                Share::Each,
                "point_load(|x| predicate, [force components])",
                "a force (at load factor 1) on every material point whose reference position satisfies the predicate",
            ),
            (
                "point_load_total",
                Share::Total,
                "point_load_total(|x| predicate, [total force components])",
                "a total force (at load factor 1) shared by the selected points in proportion to their volume",
            ),
        ] {
            api.call(CallSpec::args(
                name,
                signature,
                doc,
                2,
                move |builder, args, at| declare(builder, name, share, args, None, at),
            ));
            api.call(CallSpec::args(
                name,
                match share {
                    Share::Each => "point_load(|x| predicate, [force components], #{ held: bool, until_stage: \"stage\" })",
                    Share::Total => "point_load_total(|x| predicate, [total force components], #{ held: bool, until_stage: \"stage\" })",
                },
                "the same; with `held: true` the force is applied in full from its stage's first load step on instead of following the load factor; with `until_stage` it is released at the start of that later stage, ramped down to zero over it (docs/plasticity.md, \"Staged analysis\")",
                3,
                move |builder, args, at| {
                    let options = Options::read(
                        name,
                        &args[2],
                        &[held_option(), until_stage_option()],
                        None,
                    )?;
                    declare(builder, name, share, args, Some(&options), at)
                },
            ));
        }
        api.word(FieldSpec {
            name: "point_load",
            doc: "λ P: the point load at the step's load factor (zero on unloaded points); written when the scene has point loads",
        });
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let (loads, declarations) = resolve_point_loads(scene)?;
        if !loads.is_empty() {
            scene.spec.set_part(PointLoads(loads));
            scene.spec.set_part(PointLoadDeclarations(declarations));
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let loads = &spec.part::<PointLoads>()?.0;
        let mut totals: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
        for load in loads {
            let total = totals
                .entry(load.ramp.stage())
                .or_insert_with(|| vec![0.0; spec.dim()]);
            for (sum, c) in total.iter_mut().zip(&load.force) {
                *sum += c;
            }
        }
        let mut text = format!(
            "{} loaded points, total force {}",
            loads.len(),
            totals
                .iter()
                .map(|(&stage, total)| format!("{total:?} {}", factor_one(spec, stage)))
                .collect::<Vec<_>>()
                .join(", ")
        );
        let declarations = spec.part::<PointLoadDeclarations>();
        for declaration in grouped(declarations.map_or(&[][..], |d| &d.0)) {
            text += "\n    ";
            text += &declaration.describe();
        }
        Some(text)
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<PointLoads>().is_some_and(|loads| {
            loads
                .0
                .iter()
                .any(|load| load.force.iter().any(|&c| c != 0.0))
        })
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let entities = simulation.point_entities();
        let points = simulation.spec().point_count();
        let loads = simulation.spec().part::<PointLoads>();
        for load in loads.iter().flat_map(|loads| &loads.0) {
            if load.point >= points {
                simulation.fail(format!(
                    "point load on point {} which does not exist",
                    load.point
                ));
                return;
            }
            // a point another process holds (decomposed points): its load is that process's,
            // and travels with the point (the point-state parts below)
            let entity = entities
                .get(load.point)
                .copied()
                .unwrap_or(Entity::PLACEHOLDER);
            if entity == Entity::PLACEHOLDER {
                continue;
            }
            if load.force.len() != D {
                simulation.fail(format!(
                    "point load with {} components in {D}D",
                    load.force.len()
                ));
                return;
            }
            let force = SVector::<f64, D>::from_fn(|a, _| load.force[a]);
            let world = simulation.world();
            let mut point = world.entity_mut(entity);
            if load.is_plain() {
                point.insert(PointLoad(force));
            } else if let Some(mut later) = point.get_mut::<LaterPointLoads<D>>() {
                later.0.push((load.ramp, load.until, force));
            } else {
                point.insert(LaterPointLoads(vec![(load.ramp, load.until, force)]));
            }
        }
        if loads.is_some_and(|loads| loads.0.iter().any(|load| load.until.is_some())) {
            keep_largest_force(simulation);
        }
        if loads.is_some_and(|loads| loads.0.iter().any(|load| !load.is_plain())) {
            simulation.point_state(
                "later point loads",
                |point, values| {
                    for (ramp, until, force) in
                        point.get::<LaterPointLoads<D>>().iter().flat_map(|l| &l.0)
                    {
                        values.push(ramp.stage() as f64);
                        values.push(if ramp.is_held() { 1.0 } else { 0.0 });
                        values.push(until.map_or(-1.0, |u| u as f64));
                        values.extend(force.iter());
                    }
                },
                |point, _, values| {
                    if values.is_empty() {
                        return Ok(());
                    }
                    if values.len() % (D + 3) != 0 {
                        return Err(format!(
                            "later point loads of {} values in {D}D",
                            values.len()
                        ));
                    }
                    let loads = values
                        .chunks(D + 3)
                        .map(|record| {
                            (
                                Ramp::staged(record[1] != 0.0, record[0] as usize),
                                (record[2] >= 0.0).then_some(record[2] as usize),
                                SVector::<f64, D>::from_column_slice(&record[3..]),
                            )
                        })
                        .collect();
                    point.insert(LaterPointLoads(loads));
                    Ok(())
                },
            );
        }
        simulation
            .point_state(
                "point loads",
                |point, values| {
                    if let Some(load) = point.get::<PointLoad<D>>() {
                        values.extend(load.0.iter());
                    }
                },
                |point, _, values| match values.len() {
                    0 => Ok(()),
                    n if n == D => {
                        point.insert(PointLoad(SVector::<f64, D>::from_column_slice(values)));
                        Ok(())
                    }
                    n => Err(format!("a force of {n} components in {D}D")),
                },
            )
            .add_systems(Hook::PointFields, point_load_field::<D>);
        add_load_system(simulation, apply_point_loads::<D>);
    }
}

/// Declares a `point_load` / `point_load_total` (its options, when given, from the third
/// argument).
fn declare(
    builder: &mut SceneBuilder,
    name: &'static str,
    share: Share,
    args: &[Dynamic],
    options: Option<&Options>,
    at: rhai::Position,
) -> Result<Dynamic, String> {
    let selector = function(&args[0], &format!("{name}(...): the first argument"))?;
    let force = numbers(&args[1], &format!("{name}(...): the force"))?;
    let held = options.and_then(|o| o.flag("held")).unwrap_or(false);
    builder.declare(Located::new(
        PointLoadDeclaration {
            function: name,
            selector,
            force,
            share,
            ramp: Ramp::staged(held, builder.stage()),
            until: options
                .and_then(|o| o.text("until_stage"))
                .map(str::to_string),
        },
        at,
    ));
    Ok(Dynamic::UNIT)
}

/// f_ext,i += λ P_p N_i(x_p) for every point p that carries a [`PointLoad`].
/// In a staged scene the first stage's loads are held after it and the later stages' follow
/// their own (module docs).
pub fn apply_point_loads<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    points: Query<(&PointLoad<D>, &Support<D>)>,
    later: Query<(&LaterPointLoads<D>, &Support<D>)>,
) {
    let _timer = clock.time(Stage::Loads);
    let stage = stage.map_or(0, |s| s.0);
    let factor = step.factor_in(Ramp::Schedule, stage);
    for (load, support) in points.iter() {
        spread_force(&(load.0 * factor), &support.0, &mut fields.external_force);
    }
    for (loads, support) in later.iter() {
        let force = loads.force(&step, stage);
        if force != SVector::<f64, D>::zeros() {
            spread_force(&force, &support.0, &mut fields.external_force);
        }
    }
}

/// The output field `point_load`: λ P on loaded points, zero elsewhere.
fn point_load_field<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut out: ResMut<PointFields>,
    all: Query<&PointId>,
    loaded: Query<(&PointId, Option<&PointLoad<D>>, Option<&LaterPointLoads<D>>)>,
) {
    let stage = stage.map_or(0, |s| s.0);
    let factor = step.factor_in(Ramp::Schedule, stage);
    // indexed by PointId: a process of a decomposed run holds some of the ids only
    out.add(
        "point_load",
        all.iter().map(|id| id.0 as usize + 1).max().unwrap_or(0),
        loaded.iter().filter_map(|(id, load, later)| {
            let force = match (load, later) {
                (None, None) => return None,
                (Some(load), None) => load.0 * factor,
                (load, Some(later)) => {
                    load.map_or_else(SVector::zeros, |l| l.0 * factor) + later.force(&step, stage)
                }
            };
            Some((id.0, pad(&force)))
        }),
    );
}

/// Point loads on the seeded points: each declaration's selector is called with the reference
/// position of every point (body after body, seeding order, which is the global point index);
/// several loads on one point add up. Also each declaration's summary for `impm check`.
fn resolve_point_loads(
    scene: &Resolver,
) -> Result<(Vec<PointLoadSpec>, Vec<LoadSummary>), ScriptError> {
    let dim = scene.spec.dim();
    let positions = scene.spec.material_point_positions();
    let mut summaries = Vec::new();
    // (stage, held, release, point) -> force: stage 0 first, in point order
    type Key = (usize, bool, Option<usize>, usize);
    let mut forces: BTreeMap<Key, Vec<f64>> = BTreeMap::new();
    for declaration in scene.declarations::<PointLoadDeclaration>() {
        let load = &declaration.value;
        let function = load.function;
        if load.force.len() != dim {
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): the force has {} components but the grid is {dim}-dimensional",
                    load.force.len()
                ),
            ));
        }
        let context = format!(
            "point selector of {function}(...){}",
            declaration.line_note()
        );
        let mut selected = Vec::new();
        let points = scene.spec.bodies.iter().flat_map(|body| &body.points);
        for (index, point) in points.enumerate() {
            if scene.call_predicate(&load.selector, &point.position, declaration.at, &context)? {
                selected.push((index, point.volume));
            }
        }
        if selected.is_empty() {
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): the predicate selects no material point (it is called with the reference position of every point, and points have {}; points sit inside their cells, not on cell faces)",
                    selection_ranges(positions.iter().copied())
                ),
            ));
        }
        let until = until_stage_of(
            scene.spec,
            function,
            load.until.as_deref(),
            declaration.stage,
            declaration.at,
        )?;
        let total_volume: f64 = selected.iter().map(|(_, volume)| volume).sum();
        let count = match load.share {
            Share::Each => selected.len() as f64,
            Share::Total => 1.0,
        };
        summaries.push(
            LoadSummary::new(
                declaration.at.line(),
                function,
                "material points",
                selected.iter().map(|(index, _)| positions[*index]),
                load.force.iter().map(|c| c * count).collect(),
            )
            .in_stage(scene.spec, declaration.stage)
            .released(scene.spec, until),
        );
        for (index, volume) in selected {
            let scale = match load.share {
                Share::Each => 1.0,
                Share::Total => volume / total_volume,
            };
            let force = forces
                .entry((declaration.stage, load.ramp.is_held(), until, index))
                .or_insert_with(|| vec![0.0; dim]);
            for (sum, component) in force.iter_mut().zip(&load.force) {
                *sum += scale * component;
            }
        }
    }
    let loads = forces
        .into_iter()
        .map(|((stage, held, until, point), force)| PointLoadSpec {
            point,
            force,
            ramp: Ramp::staged(held, stage),
            until,
        })
        .collect();
    Ok((loads, summaries))
}
