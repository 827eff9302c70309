//! Modules: how every optional effect, every material and your own code extend the solver.
//!
//! A [`Plugin`] adds bevy systems (and the resources or components they need) to a simulation
//! at the [`Hook`]s of the method (`method.rs` lists them and where they sit). The built-in
//! effects (`effects/`) and materials (`material/`) are plugins too, built through exactly this
//! trait: the core never names them.
//!
//! ```no_run
//! use bevy_ecs::prelude::*;
//! use impm::plugin::{Extension, Hook, Plugin};
//! use impm::run::run_scene_with;
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
//! let spec = impm::run::load_scene("scripts/column_1d.rhai".as_ref(), &[]).unwrap();
//! run_scene_with(&spec, "out/announce".as_ref(), &Announce, |_| {}).unwrap();
//! ```
//!
//! A plugin is generic over the dimension `D` (it is built for the scene's), so its systems can
//! use `Position<D>`, `GridFields<D>` and so on. A module says whether a scene uses it
//! ([`Plugin::used_by`]): only then is it built, so a scene pays only for what it declares.
//!
//! Order: systems added to one hook run in the order they were added (one `add_systems` call
//! after the previous); systems of one call that write the same data must be ordered among
//! themselves (`.chain()`), or the schedule does not build (a `BuildError` naming both).
//! Hooks cost nothing when unused, and `()` is the plugin that adds nothing.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::IntoScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;

use crate::checkpoint::{
    CheckpointPart, CheckpointParts, CheckpointSeries, PointStatePart, PointStateParts,
    SeriesAccess,
};
use crate::components::PointId;
pub use crate::method::Hook;
use crate::method::Providers;
use crate::records::StepMeasures;
use crate::resources::{Newton, RunStatus};
use crate::scene::{
    FieldSpec, Resolver, SceneApi, SceneError, SceneModule, SceneSpec, ScriptError,
};
use crate::stages::output::PARTICLE_FIELDS;

/// Why a simulation could not be built from a scene (or a plugin could not be added).
#[derive(Clone, Debug, PartialEq)]
pub struct BuildError(pub String);

impl std::fmt::Display for BuildError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BuildError {}

/// A set of systems, resources and components that extends a simulation.
pub trait Plugin {
    /// A short name for `impm check` and messages (e.g. `"tractions"`).
    fn name(&self) -> &'static str {
        let name = std::any::type_name::<Self>();
        name.rsplit("::").next().unwrap_or(name)
    }

    /// The scene words the plugin adds (calls, options of other calls, basis words, material
    /// models, point fields), if any.
    fn scene_api(&self, _api: &mut SceneApi) {}

    /// Resolves what a script declared with the plugin's words into its part of the scene.
    fn resolve(&self, _scene: &mut Resolver) -> Result<(), ScriptError> {
        Ok(())
    }

    /// What the scene declared for this plugin, in a line for `impm check` (e.g. "4 loaded
    /// points, total force [0, -0.8]"), if anything.
    fn describe(&self, _spec: &SceneSpec) -> Option<String> {
        None
    }

    /// Whether a scene uses the plugin; only then is it built. User plugins: always.
    fn used_by(&self, _spec: &SceneSpec) -> bool {
        true
    }

    /// Whether the plugin could run with the scene's method (basis, dimension): `impm check
    /// --explain` lists the systems of the applicable plugins a scene does not use.
    fn applies_to(&self, _spec: &SceneSpec) -> bool {
        true
    }

    /// Adds the plugin's systems, resources and components to a simulation of dimension `D`
    /// (called once, after the core world is built from the scene and before the first step).
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
    fn name(&self) -> &'static str {
        (*self).name()
    }
    fn scene_api(&self, api: &mut SceneApi) {
        (*self).scene_api(api)
    }
    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        (*self).resolve(scene)
    }
    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        (*self).describe(spec)
    }
    fn used_by(&self, spec: &SceneSpec) -> bool {
        (*self).used_by(spec)
    }
    fn applies_to(&self, spec: &SceneSpec) -> bool {
        (*self).applies_to(spec)
    }
    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        (*self).build(simulation);
    }
}

/// A plugin as an object, so that a list of different plugins can be kept and built for the
/// dimension of a scene (implemented for every [`Plugin`]).
pub trait Module: SceneModule + Send + Sync {
    fn name(&self) -> &'static str;
    fn describe(&self, spec: &SceneSpec) -> Option<String>;
    fn used_by(&self, spec: &SceneSpec) -> bool;
    fn applies_to(&self, spec: &SceneSpec) -> bool;
    /// Builds the plugin into `world` for the scene's dimension.
    fn build_into(&self, world: &mut World, spec: &SceneSpec) -> Result<(), BuildError>;
}

impl<P: Plugin> SceneModule for P {
    fn scene_api(&self, api: &mut SceneApi) {
        Plugin::scene_api(self, api)
    }
    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        Plugin::resolve(self, scene)
    }
}

impl<P: Plugin + Send + Sync> Module for P {
    fn name(&self) -> &'static str {
        Plugin::name(self)
    }
    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        Plugin::describe(self, spec)
    }
    fn used_by(&self, spec: &SceneSpec) -> bool {
        Plugin::used_by(self, spec)
    }
    fn applies_to(&self, spec: &SceneSpec) -> bool {
        Plugin::applies_to(self, spec)
    }
    fn build_into(&self, world: &mut World, spec: &SceneSpec) -> Result<(), BuildError> {
        match spec.dim() {
            1 => build_plugin::<1>(self, world, spec),
            2 => build_plugin::<2>(self, world, spec),
            3 => build_plugin::<3>(self, world, spec),
            d => Err(BuildError(format!(
                "dimension {d} is not supported (1, 2 or 3)"
            ))),
        }
    }
}

/// The scene words of the core's output: its point fields.
struct CoreOutput;

impl Plugin for CoreOutput {
    fn name(&self) -> &'static str {
        "output"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        for &(name, doc) in PARTICLE_FIELDS {
            api.word(FieldSpec { name, doc });
        }
    }

    fn used_by(&self, _spec: &SceneSpec) -> bool {
        false
    }

    fn applies_to(&self, _spec: &SceneSpec) -> bool {
        false
    }

    fn build<const D: usize>(&self, _: &mut Extension<'_, D>) {}
}

/// The modules a run can use, in build order (`effects::built_in()` and your own).
#[derive(Clone, Default)]
pub struct ModuleSet(Vec<Arc<dyn Module>>);

impl ModuleSet {
    /// The core's own words (its point fields) and no module yet.
    pub fn new() -> Self {
        Self::default().with(CoreOutput)
    }

    /// Adds a module after the others.
    pub fn with(mut self, module: impl Plugin + Send + Sync + 'static) -> Self {
        self.0.push(Arc::new(module));
        self
    }

    pub fn iter(&self) -> impl Iterator<Item = &dyn Module> {
        self.0.iter().map(|module| module.as_ref())
    }

    /// Runs a scene script in the scene language of the core and these modules (see
    /// `scene::load_scene_with`).
    pub fn load_scene(
        &self,
        path: &std::path::Path,
        overrides: &[(String, String)],
    ) -> Result<SceneSpec, SceneError> {
        self.load_scene_within(path, overrides, &crate::scene::SceneLimits::default())
    }

    /// [`ModuleSet::load_scene`] within `limits` (`impm --limit NAME=VALUE`).
    pub fn load_scene_within(
        &self,
        path: &std::path::Path,
        overrides: &[(String, String)],
        limits: &crate::scene::SceneLimits,
    ) -> Result<SceneSpec, SceneError> {
        let modules: Vec<&dyn SceneModule> = self.iter().map(|m| m as &dyn SceneModule).collect();
        crate::scene::load_scene_within(path, overrides, &modules, limits)
    }

    /// The scene language of the core and these modules.
    pub fn scene_api(&self) -> SceneApi {
        let modules: Vec<&dyn SceneModule> = self.iter().map(|m| m as &dyn SceneModule).collect();
        crate::scene::scene_api(&modules)
    }

    /// Every material model a body uses must have its module (a module named like the
    /// model, see `effects::materials`).
    pub fn check_materials(&self, spec: &SceneSpec) -> Result<(), BuildError> {
        for body in &spec.bodies {
            let Some(material) = spec.materials.get(body.material) else {
                return Err(BuildError(format!(
                    "body '{}' names no material",
                    body.name
                )));
            };
            if !self.iter().any(|module| module.name() == material.model) {
                return Err(BuildError(format!(
                    "material '{}' is of model '{}', which no module provides",
                    material.name, material.model
                )));
            }
        }
        Ok(())
    }
}

/// Builds `plugin` for dimension `D`; the first error it reported, if any.
pub fn build_plugin<const D: usize>(
    plugin: &(impl Plugin + ?Sized),
    world: &mut World,
    spec: &SceneSpec,
) -> Result<(), BuildError> {
    let mut extension = Extension::<D>::new(world, spec);
    plugin.build(&mut extension);
    match extension.error {
        Some(error) => Err(error),
        None => Ok(()),
    }
}

/// What a plugin sees of the simulation it extends: the world, the scene, and the hooks.
pub struct Extension<'w, const D: usize> {
    world: &'w mut World,
    spec: &'w SceneSpec,
    error: Option<BuildError>,
}

/// How many `add_systems` calls each hook has had (their order is the run order).
#[derive(Resource, Default)]
struct HookSlots([u32; Hook::ALL.len()]);

/// The systems of one `add_systems` call at a hook.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct HookSlot(Hook, u32);

impl<'w, const D: usize> Extension<'w, D> {
    /// Wraps a simulation's world and scene (usually through `run::Simulation::add_plugin`).
    pub fn new(world: &'w mut World, spec: &'w SceneSpec) -> Self {
        Self {
            world,
            spec,
            error: None,
        }
    }

    /// The simulation's world: insert resources, give points components of your own...
    pub fn world(&mut self) -> &mut World {
        self.world
    }

    /// The scene the simulation was built from.
    pub fn spec(&self) -> &'w SceneSpec {
        self.spec
    }

    /// Reports why the plugin cannot be built for this scene; the first error is kept and the
    /// simulation is not built.
    pub fn fail(&mut self, why: impl Into<String>) {
        if self.error.is_none() {
            self.error = Some(BuildError(why.into()));
        }
    }

    /// The entity of every material point, indexed by `PointId` (points are numbered body
    /// after body in seeding order); `Entity::PLACEHOLDER` for the points another process
    /// holds (a decomposed distributed run).
    pub fn point_entities(&mut self) -> Vec<Entity> {
        let mut query = self.world.query::<(Entity, &PointId)>();
        let count = query
            .iter(self.world)
            .map(|(_, id)| id.0 as usize + 1)
            .max();
        let mut entities = vec![Entity::PLACEHOLDER; count.unwrap_or(0)];
        for (entity, id) in query.iter(self.world) {
            entities[id.0 as usize] = entity;
        }
        entities
    }

    /// Adds a quantity measured after every converged step (a key of the step's record in
    /// `summary.json`, e.g. `error_recovered`, or a name made from the scene's, such as
    /// `top_reaction_y`).
    pub fn add_measure(
        &mut self,
        name: impl Into<String>,
        measure: impl Fn(&mut World, f64) -> Option<f64> + Send + Sync + 'static,
    ) -> &mut Self {
        self.world
            .get_resource_or_init::<StepMeasures>()
            .0
            .push((name.into(), Box::new(measure)));
        self
    }

    /// Registers a part of the simulation's saved state (see `checkpoint`): what the plugin
    /// keeps from one load step to the next, so that a restored run continues exactly.
    pub fn checkpoint(&mut self, part: CheckpointPart) -> &mut Self {
        self.world
            .get_resource_or_init::<CheckpointParts>()
            .0
            .push(part);
        self
    }

    /// Registers the plugin's state on single material points (see
    /// `checkpoint::PointStatePart`): what a point must carry, and what the plugin gives a point
    /// spawned from that record, when it moves to another process.
    pub fn point_state(
        &mut self,
        name: &'static str,
        pack: impl Fn(EntityRef<'_>, &mut Vec<f64>) + Send + Sync + 'static,
        unpack: impl Fn(&mut EntityWorldMut<'_>, u32, &[f64]) -> Result<(), String>
        + Send
        + Sync
        + 'static,
    ) -> &mut Self {
        self.world
            .get_resource_or_init::<PointStateParts>()
            .0
            .push(PointStatePart {
                name,
                pack: Arc::new(pack),
                unpack: Arc::new(unpack),
            });
        self
    }

    /// Registers the `.pvd` series the plugin writes (see `checkpoint`), so that a resumed run
    /// continues them and each lists every step once.
    pub fn series(&mut self, access: SeriesAccess) -> &mut Self {
        self.world
            .get_resource_or_init::<CheckpointSeries>()
            .0
            .push(access);
        self
    }

    /// Declares that the plugin's contributions make the tangent non-symmetric (a follower
    /// load, non-associated flow, arc-length...): the linear solve then uses no symmetric
    /// method. Symmetric contributions need not say anything.
    pub fn nonsymmetric_tangent(&mut self) -> &mut Self {
        self.world.resource_mut::<Newton>().symmetric = false;
        self
    }

    /// How many `add_systems` calls `hook` has had so far (by the modules built before this
    /// one): a module that cannot work with what others add there can say so.
    pub fn systems_at(&mut self, hook: Hook) -> usize {
        self.world.get_resource_or_init::<HookSlots>().0[hook as usize] as usize
    }

    /// Adds `systems` at `hook`, after the systems added there before. They run only while no
    /// stage has failed, like the core stages (except at `Hook::Combine`, which runs after a
    /// failure too: see `Hook::runs_after_failure`).
    pub fn add_systems<M>(
        &mut self,
        hook: Hook,
        systems: impl IntoScheduleConfigs<ScheduleSystem, M>,
    ) -> &mut Self {
        let slot = {
            let mut slots = self.world.get_resource_or_init::<HookSlots>();
            let counter = &mut slots.0[hook as usize];
            *counter += 1;
            HookSlot(hook, *counter - 1)
        };
        let mut schedules = self.world.resource_mut::<Schedules>();
        let schedule = schedules.entry(hook.schedule());
        let after_failure = hook.runs_after_failure();
        let set = slot
            .in_set(hook)
            .run_if(move |status: Res<RunStatus>| after_failure || status.0.is_none());
        if slot.1 == 0 {
            schedule.configure_sets(set);
        } else {
            schedule.configure_sets(set.after(HookSlot(hook, slot.1 - 1)));
        }
        schedule.add_systems(systems.in_set(slot));
        self
    }

    /// Provides a stage that the core otherwise fills with its default (the basis evaluation
    /// at `Hook::Basis`, the grid file at `Hook::GridOutput`). One module per stage.
    pub fn provide<M>(
        &mut self,
        hook: Hook,
        name: &'static str,
        systems: impl IntoScheduleConfigs<ScheduleSystem, M>,
    ) -> &mut Self {
        debug_assert!(hook.is_replaceable_default(), "{hook:?} has no default");
        let other = self
            .world
            .get_resource_or_init::<Providers>()
            .0
            .iter()
            .find(|(h, _)| *h == hook)
            .map(|(_, other)| *other);
        if let Some(other) = other {
            self.fail(format!("{name} and {other} both provide {hook:?}"));
            return self;
        }
        self.world.resource_mut::<Providers>().0.push((hook, name));
        self.add_systems(hook, systems)
    }
}
