//! Constraints on grid nodes: `fix` (zero displacement) and `displace` (a prescribed total
//! displacement ramped with the load factor) on the components of the control points a
//! predicate selects.
//!
//! Two modules share the nodes' [`Fixity`]:
//!
//! * [`GridConstraintsModule`] marks the constrained components at `Hook::Constraints` every
//!   step (`GridFields::constrained`), so that they get no DOF: the Dirichlet conditions are
//!   eliminated from the system. With decomposed points a process marks the nodes it
//!   touches, and process 0 the untouched ones in an output step ([`mark_untouched_fixity`]:
//!   the node file shows every constrained node, as serially).
//! * [`PrescribedDisplacementsModule`], only when some prescribed value is not zero, sets the
//!   constrained components' increment at `Hook::Loads`: they move by (λ_{n+1} − λ_n) times
//!   their prescribed total before the first Newton iterate, so after the step the node has
//!   moved by λ_{n+1} times its prescribed value.
//!
//! A prescribed displacement moves the grid node, and so the material that is at the node at
//! the start of each step (the grid is reset every step): exact where the material stays at
//! the constrained nodes (tension, or linear FEM whose nodes move with the body).
//!
//! # Stages
//!
//! In a staged scene (`scene::stages`) a `fix` / `displace` declared in stage k constrains its
//! components from stage k's start on; a `displace` of stage k moves its nodes by λ_k times
//! its value over stage k (its increment `(λ_k,n+1 − λ_k,n) ū`, from where stage k found them)
//! and holds them in the stages after it. `#{ until_stage: "s" }` releases (`until` is a keyword of the scene language) the constraint at the
//! start of stage s, with the excavation rule: the support's force on the body at the end of
//! the stage before, `R_i = f_int,i − f_ext,i` at each of its node components i, becomes a
//! load ramped down over stage s,
//!
//! ```text
//!   f_ext,i += (1 − λ_s) R_i   in stage s,    nothing after it,
//! ```
//!
//! so that the body starts stage s in equilibrium and is unloaded gradually (Newton converges
//! as in any load step). A component another declaration still constrains in stage s gets no
//! such load. The reaction measures (`fix1_reaction_y`, ...) are the support's force while it
//! acts, the ramped load `(1 − λ_s) Σ R_i` in stage s and 0 before its stage and after s. The
//! released forces are a checkpoint part ("released supports"). [`ConstraintWindows`] holds
//! the stages each constrained component acts in; a scene without stages has none and runs
//! as before.

use std::collections::BTreeMap;

use bevy_ecs::prelude::*;
use nalgebra::SVector;
use rhai::{Dynamic, FnPtr, Position};

use crate::checkpoint::CheckpointPart;
use crate::components::GridNode;
use crate::effects::declarations::{factor_one, keep_largest_force, selection_ranges, until_stage};
use crate::effects::surface_conditions::AXES;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    CurrentStage, GridFields, LoadStep, Newton, Ramp, RunStatus, SharedGrid, SolverError, Stage,
    StageClock, Warnings,
};
use crate::scene::{
    CallSpec, Kind, Located, OptionSpec, Options, Resolver, SceneApi, SceneBuilder, SceneSpec,
    ScriptError, Stages, function, numbers, whole_numbers,
};
use crate::stages::output::OutputPlan;

/// One constrained component of one grid node (control point). The prescribed displacement
/// `value` is the total at load factor 1; it is ramped with the load factor (0 = fixed).
#[derive(Clone, Debug, PartialEq)]
pub struct NodeConstraint {
    /// Global node index (axis 0 fastest, see `basis::GridSpec::node_positions`).
    pub node: usize,
    pub component: usize,
    pub value: f64,
}

/// The scene's constrained node components.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NodeConstraints(pub Vec<NodeConstraint>);

/// The stages a constraint acts in: from stage `from` on, up to (not including) stage
/// `until` (module docs, "Stages").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    pub from: usize,
    pub until: Option<usize>,
}

impl Window {
    /// Every stage (a scene without stages).
    pub const ALWAYS: Self = Self {
        from: 0,
        until: None,
    };

    /// Whether the constraint acts in stage `stage`.
    pub fn covers(self, stage: usize) -> bool {
        stage >= self.from && self.until.is_none_or(|until| stage < until)
    }
}

/// The windows of every entry of [`NodeConstraints`] (same order): a part of the scene only
/// when some constraint does not act in every stage.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ConstraintWindows(pub Vec<Vec<Window>>);

/// What one `fix`/`displace` call selected: for `impm check` and its reaction.
#[derive(Clone, Debug, PartialEq)]
pub struct DeclaredConstraint {
    /// `fix` or `displace`, numbered in declaration order per function (`fix1`, `displace1`):
    /// names its measures (`fix1_reaction_x`, ...).
    pub name: String,
    pub line: Option<usize>,
    /// The selected (node, component) pairs.
    pub components: Vec<(usize, usize)>,
    /// The constrained axes and their prescribed values at load factor 1.
    pub axes: Vec<usize>,
    pub values: Vec<f64>,
    /// The smallest and largest coordinate of the selected nodes, per axis.
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// The stages it acts in (module docs, "Stages").
    pub window: Window,
}

/// Every `fix`/`displace` call of the scene, in order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ConstraintDeclarations(pub Vec<DeclaredConstraint>);

/// `fix` (values all zero) or `displace`: components of every node the selector accepts.
#[derive(Clone, Debug)]
struct ConstraintDeclaration {
    /// The API function that declared it, for messages.
    function: &'static str,
    selector: FnPtr,
    /// The constrained components; empty = all of them (full fixity, `fix(|x| ..)`).
    components: Vec<usize>,
    /// One prescribed displacement (at load factor 1) per component.
    values: Vec<f64>,
    /// `#{ until_stage: "stage" }`: the stage whose start releases it.
    until: Option<String>,
}

/// The constraints of a scene (none if it declares none).
fn constraints(spec: &SceneSpec) -> &[NodeConstraint] {
    spec.part::<NodeConstraints>().map_or(&[], |c| &c.0)
}

/// Constraints of a node: which displacement components are prescribed, and the prescribed
/// total displacement at load factor 1 (zero for a plain fixity). Only constrained nodes have
/// it.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Fixity<const D: usize> {
    pub fixed: [bool; D],
    pub prescribed: SVector<f64, D>,
}

impl<const D: usize> Default for Fixity<D> {
    fn default() -> Self {
        Self {
            fixed: [false; D],
            prescribed: SVector::zeros(),
        }
    }
}

/// `fix` and `displace`: the constrained components of the nodes.
#[derive(Clone, Copy, Debug, Default)]
pub struct GridConstraintsModule;

impl Plugin for GridConstraintsModule {
    fn name(&self) -> &'static str {
        "grid constraints"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::args(
            "fix",
            "fix(|x| predicate, [components])",
            "fixes the listed displacement components (0-based axes) of every grid node whose position satisfies the predicate (a roller: one component). Nodes are the control points (Greville abscissae; grid vertices for linear), with the first and last node of each axis exactly on the grid bounds. In a staged scene it acts from the start of the stage it is declared in",
            2,
            |builder, args, at| {
                declare_constraint(builder, "fix", &args[0], &args[1], None, None, at)
            },
        ))
        .call(CallSpec::args(
            "fix",
            "fix(|x| predicate)",
            "full fixity: every component of the selected nodes",
            1,
            |builder, args, at| {
                declare_constraint(builder, "fix", &args[0], &Dynamic::UNIT, None, None, at)
            },
        ))
        .call(CallSpec::args(
            "fix",
            "fix(|x| predicate, [components], #{ until_stage: \"stage\" })",
            "a support released at the start of the named (later) stage of a staged scene: its force on the body at the end of the stage before becomes a load ramped down to zero over the named stage (the excavation rule; docs/plasticity.md, \"Staged analysis\")",
            3,
            |builder, args, at| {
                declare_constraint(builder, "fix", &args[0], &args[1], None, Some(&args[2]), at)
            },
        ))
        .call(CallSpec::args(
            "displace",
            "displace(|x| predicate, [components], [values])",
            "prescribes the displacement of the listed components of the selected grid nodes (values at load factor 1, ramped with the load factor; in a staged scene from the start of its stage, over its stage's schedule, then held); it moves the material at the node at the start of each step",
            3,
            |builder, args, at| {
                declare_constraint(
                    builder, "displace", &args[0], &args[1], Some(&args[2]), None, at,
                )
            },
        ))
        .call(CallSpec::args(
            "displace",
            "displace(|x| predicate, [components], [values], #{ until_stage: \"stage\" })",
            "a prescribed displacement released at the start of the named (later) stage, as fix(.., #{ until_stage })",
            4,
            |builder, args, at| {
                declare_constraint(
                    builder,
                    "displace",
                    &args[0],
                    &args[1],
                    Some(&args[2]),
                    Some(&args[3]),
                    at,
                )
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let (constraints, declared, windows) = resolve_constraints(scene)?;
        if !constraints.is_empty() {
            scene.spec.set_part(NodeConstraints(constraints));
            scene.spec.set_part(ConstraintDeclarations(declared));
            if let Some(windows) = windows {
                scene.spec.set_part(ConstraintWindows(windows));
            }
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let constraints = constraints(spec);
        let prescribed = constraints.iter().filter(|c| c.value != 0.0).count();
        let mut text = format!(
            "{} constrained node components ({prescribed} with a prescribed displacement)",
            constraints.len()
        );
        for d in spec
            .part::<ConstraintDeclarations>()
            .map_or(&[][..], |d| &d.0)
        {
            let line = d.line.map(|l| format!("line {l}: ")).unwrap_or_default();
            text += &format!(
                "\n    {line}{}: {} node components, nodes in {:?} .. {:?}, axes {:?}, values {:?} {}{} (reaction: {}_reaction_x, ...)",
                d.name,
                d.components.len(),
                d.lower,
                d.upper,
                d.axes,
                d.values,
                factor_one(spec, d.window.from),
                release_note(spec, d.window),
                d.name
            );
        }
        Some(text)
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        !constraints(spec).is_empty()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        let world = simulation.world();
        // by constrained node (not vectors over the whole grid: the grid's nodes may be many
        // more, and every process of a decomposed run builds this)
        let node_count = world.resource::<GridFields<D>>().active.len();
        let mut fixities: BTreeMap<usize, Fixity<D>> = BTreeMap::new();
        let windows = spec.part::<ConstraintWindows>().map(|w| w.0.clone());
        let mut staged: BTreeMap<usize, FixityWindows<D>> = BTreeMap::new();
        for (index, c) in constraints(spec).iter().enumerate() {
            if c.node >= node_count {
                simulation.fail(format!("constraint on node {} outside the grid", c.node));
                return;
            }
            if c.component >= D {
                simulation.fail(format!("constraint on component {} in {D}D", c.component));
                return;
            }
            let fixity = fixities.entry(c.node).or_default();
            fixity.prescribed[c.component] = c.value;
            match windows.as_ref().and_then(|w| w.get(index)) {
                None => fixity.fixed[c.component] = true,
                Some(windows) => {
                    // stage 0's fixity; `stage_fixities` sets it at every step
                    fixity.fixed[c.component] = windows.iter().any(|w| w.covers(0));
                    staged.entry(c.node).or_default().0[c.component] = windows.clone();
                }
            }
        }
        let world = simulation.world();
        let entities: BTreeMap<usize, Entity> = (world.query::<(Entity, &GridNode<D>)>())
            .iter(world)
            .filter(|(_, node)| fixities.contains_key(&node.index))
            .map(|(entity, node)| (node.index, entity))
            .collect();
        let mut fields = world.resource_mut::<GridFields<D>>();
        // decomposed points: each process marks the nodes it touches, every step
        // ([`constrain_nodes`]); the others' pages stay unallocated
        if !crate::distributed::decomposed() {
            for (&node, fixity) in &fixities {
                fields.constrained[node] = fixity.fixed;
            }
        }
        let batch: Vec<(Entity, Fixity<D>)> = (fixities.into_iter())
            .map(|(node, fixity)| (entities[&node], fixity))
            .collect();
        world.insert_batch(batch);
        let staged: Vec<(Entity, FixityWindows<D>)> = (staged.into_iter())
            .map(|(node, windows)| (entities[&node], windows))
            .collect();
        let has_windows = !staged.is_empty();
        world.insert_batch(staged);
        let declared = spec
            .part::<ConstraintDeclarations>()
            .map_or(Vec::new(), |d| d.0.clone());
        for (index, declaration) in declared.iter().enumerate() {
            for (axis, axis_name) in AXES.iter().enumerate().take(D) {
                let key = format!("{}_reaction_{axis_name}", declaration.name);
                simulation.add_measure(key, move |world, _| {
                    Some(
                        world
                            .get_resource::<GridReactions<D>>()?
                            .reactions
                            .get(index)?[axis],
                    )
                });
            }
        }
        for (axis, axis_name) in AXES.iter().enumerate().take(D) {
            let key = format!("external_force_{axis_name}");
            simulation.add_measure(key, move |world, _| {
                Some(world.get_resource::<GridReactions<D>>()?.external[axis])
            });
        }
        let releases = declared.iter().any(|d| d.window.until.is_some());
        simulation.world().insert_resource(GridReactions::<D> {
            released: declared
                .iter()
                .map(|d| match d.window.until {
                    Some(_) => vec![0.0; d.components.len()],
                    None => Vec::new(),
                })
                .collect(),
            declarations: declared,
            reactions: Vec::new(),
            external: SVector::zeros(),
        });
        if has_windows {
            simulation.add_systems(Hook::Constraints, stage_fixities::<D>);
        }
        simulation
            .add_systems(Hook::Constraints, constrain_nodes::<D>)
            .add_systems(Hook::AfterStep, grid_reactions::<D>);
        if crate::distributed::decomposed() {
            simulation.add_systems(Hook::PointFields, mark_untouched_fixity::<D>);
        }
        if releases {
            keep_largest_force(simulation);
            simulation
                .add_systems(Hook::Loads, apply_released_supports::<D>)
                .checkpoint(CheckpointPart {
                    name: "released supports",
                    save: save_released::<D>,
                    restore: restore_released::<D>,
                });
        }
    }
}

/// ", released at stage 'b' ..." for `impm check` (empty for a constraint never released).
fn release_note(spec: &SceneSpec, window: Window) -> String {
    match (spec.part::<Stages>(), window.until) {
        (Some(stages), Some(until)) => format!(
            ", released at the start of stage '{}' (its force then ramped down over that stage)",
            stages.name(until)
        ),
        _ => String::new(),
    }
}

/// The stages each constrained component of a node acts in (only on the nodes of a scene
/// with [`ConstraintWindows`]; empty for a component that is not constrained).
#[derive(Component, Clone, Debug)]
pub struct FixityWindows<const D: usize>(pub [Vec<Window>; D]);

impl<const D: usize> Default for FixityWindows<D> {
    fn default() -> Self {
        Self(std::array::from_fn(|_| Vec::new()))
    }
}

/// The stage of the step (0 without a `CurrentStage`).
fn stage_of(stage: &Option<Res<CurrentStage>>) -> usize {
    stage.as_ref().map_or(0, |s| s.0)
}

/// In a staged scene, before [`constrain_nodes`]: the components that act in the step's stage
/// are the fixed ones.
pub fn stage_fixities<const D: usize>(
    stage: Option<Res<CurrentStage>>,
    mut nodes: Query<(&mut Fixity<D>, &FixityWindows<D>)>,
) {
    let stage = stage_of(&stage);
    for (mut fixity, windows) in nodes.iter_mut() {
        let fixed = std::array::from_fn(|c| windows.0[c].iter().any(|w| w.covers(stage)));
        if fixity.fixed != fixed {
            fixity.fixed = fixed;
        }
    }
}

/// The reaction of every `fix`/`displace` call at the last converged step.
#[derive(Resource, Clone, Debug)]
pub struct GridReactions<const D: usize> {
    pub declarations: Vec<DeclaredConstraint>,
    /// The force the constrained components exert on the body, per declaration: while it acts
    /// the support's, in the stage that releases it the ramped load that replaces it, else 0.
    pub reactions: Vec<SVector<f64, D>>,
    /// Per declaration with `until_stage`, the force on the body at each of its node components at
    /// the last converged step it acted in (module docs, "Stages"; empty for the others).
    pub released: Vec<Vec<f64>>,
    /// The resultant of the external forces (Σ_i f_ext,i) at the same step, recorded as
    /// `external_force_x`, ...: with every reaction it sums to zero at equilibrium.
    pub external: SVector<f64, D>,
}

/// After a converged step, the reaction of each declaration: at its constrained components,
/// R = f_int − f_ext (equilibrium f_int = f_ext + R; f_int includes every module's
/// contribution, e.g. a surface condition's force on nodes that are also constrained). A
/// component selected by two declarations counts in both. On a grid split among processes
/// (`Newton::shared_grid`) each node counts on its owner (its forces are summed there) and
/// the owners' sums are added over the processes, so every process records the whole run's.
pub fn grid_reactions<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    fields: Res<GridFields<D>>,
    mut reactions: ResMut<GridReactions<D>>,
    newton: Res<Newton>,
    mut status: ResMut<RunStatus>,
) {
    let stage = stage_of(&stage);
    let shared = newton.shared_grid.as_deref();
    let counts = |node: usize| shared.is_none_or(|s| s.owned(node));
    let reactions = &mut *reactions;
    reactions.external = (fields.external_force.written())
        .filter(|&(node, _)| counts(node))
        .map(|(_, f)| f)
        .sum();
    reactions.reactions.clear();
    for (declaration, released) in reactions.declarations.iter().zip(&mut reactions.released) {
        let mut force = SVector::<f64, D>::zeros();
        let window = declaration.window;
        if window.covers(stage) {
            for (k, &(node, c)) in declaration.components.iter().enumerate() {
                let reaction = if counts(node) {
                    fields.internal_force[node][c] - fields.external_force[node][c]
                } else {
                    0.0 // its owner's
                };
                force[c] += reaction;
                if let Some(kept) = released.get_mut(k) {
                    *kept = reaction;
                }
            }
        } else if window.until == Some(stage) {
            let ramp = 1.0 - step.factor;
            for (&(node, c), &reaction) in declaration.components.iter().zip(released.iter()) {
                if !fields.constrained[node][c] && counts(node) {
                    force[c] += reaction * ramp;
                }
            }
        }
        reactions.reactions.push(force);
    }
    if let Some(shared) = shared
        && let Err(why) = sum_reactions(shared, reactions, stage)
    {
        status.fail(SolverError::Module {
            step: step.number,
            what: format!("summing the reactions over the processes: {why}"),
            recoverable: false,
        });
    }
}

/// The owners' parts of the reactions, the external resultant and the forces kept for a
/// release (those of the declarations acting in `stage`) added over the processes
/// (collective: every process gets the same sums).
fn sum_reactions<const D: usize>(
    shared: &dyn SharedGrid,
    reactions: &mut GridReactions<D>,
    stage: usize,
) -> Result<(), String> {
    let GridReactions {
        declarations,
        reactions,
        released,
        external,
    } = reactions;
    let kept = (declarations.iter().zip(released.iter_mut()))
        .filter(|(declaration, _)| declaration.window.covers(stage))
        .flat_map(|(_, kept)| kept.iter_mut());
    let mut values: Vec<&mut f64> = (external.iter_mut())
        .chain(reactions.iter_mut().flat_map(|r| r.iter_mut()))
        .chain(kept)
        .collect();
    let parts: Vec<f64> = values.iter().map(|v| **v).collect();
    let sums = shared.sum(&parts)?;
    if sums.len() != parts.len() {
        return Err(format!("{} sums of {} values", sums.len(), parts.len()));
    }
    for (value, sum) in values.iter_mut().zip(sums) {
        **value = sum;
    }
    Ok(())
}

/// In the stage that releases a support (`until_stage`): its force at the end of the stage before,
/// ramped down, `f_ext,i += (1 − λ) R_i` at each of its components no other declaration
/// still constrains (module docs, "Stages").
pub fn apply_released_supports<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    reactions: Res<GridReactions<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    newton: Res<Newton>,
) {
    let _timer = clock.time(Stage::Loads);
    let stage = stage_of(&stage);
    let ramp = 1.0 - step.factor;
    // a grid split among processes: added by the node's owner only (the processes' external
    // forces are summed after the loads)
    let shared = newton.shared_grid.as_deref();
    for (declaration, released) in reactions.declarations.iter().zip(&reactions.released) {
        if declaration.window.until != Some(stage) {
            continue;
        }
        for (&(node, c), &reaction) in declaration.components.iter().zip(released) {
            if !fields.constrained[node][c] && shared.is_none_or(|s| s.owned(node)) {
                fields.external_force[node][c] += reaction * ramp;
            }
        }
    }
}

/// The released supports' forces, declaration after declaration.
fn save_released<const D: usize>(world: &mut World) -> Vec<f64> {
    world
        .resource::<GridReactions<D>>()
        .released
        .iter()
        .flatten()
        .copied()
        .collect()
}

fn restore_released<const D: usize>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let mut reactions = world.resource_mut::<GridReactions<D>>();
    let total: usize = reactions.released.iter().map(Vec::len).sum();
    if values.len() != total {
        return Err(format!(
            "the checkpoint has {} released support forces, the scene {total}",
            values.len()
        ));
    }
    let mut rest = values;
    for released in &mut reactions.released {
        let (these, others) = rest.split_at(released.len());
        released.copy_from_slice(these);
        rest = others;
    }
    Ok(())
}

/// The fixed components of every constrained node get no DOF. With decomposed points a
/// process marks only the nodes it touches (active: `Hook::Constraints` runs after the
/// connectivity), and drops the marks of the step before (its slab moves), so that its
/// `constrained` pages are its own nodes' (`node_storage`); serially every constrained node
/// is marked (the grid output shows them).
pub fn constrain_nodes<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    nodes: Query<(&GridNode<D>, &Fixity<D>)>,
) {
    let decomposed = crate::distributed::decomposed();
    if decomposed {
        fields.constrained.reset();
    }
    for (node, fixity) in nodes.iter() {
        if !decomposed || fields.active[node.index] {
            fields.constrained[node.index] = fixity.fixed;
        }
    }
}

/// With decomposed points, in an output step with node files: process 0, which writes the
/// nodes no process's points touch (`stages::output::GridPieces`; with one process, every
/// node), marks the constrained components at the nodes it does not touch, so that the node
/// file shows every constrained node as the serial run's does. After the solve: it changes
/// no DOF, and the grid reset frees the pages. (A node another process touches is written by
/// its owner, which marked it in [`constrain_nodes`].)
pub fn mark_untouched_fixity<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    plan: Res<OutputPlan>,
    step: Res<LoadStep>,
    nodes: Query<(&GridNode<D>, &Fixity<D>)>,
) {
    if !plan.writes(&step) || !plan.grid_files || !crate::distributed::writes_run_files() {
        return;
    }
    for (node, fixity) in nodes.iter() {
        if !fields.active[node.index] {
            fields.constrained[node.index] = fixity.fixed;
        }
    }
}

/// `displace`: the prescribed increments of the step.
#[derive(Clone, Copy, Debug, Default)]
pub struct PrescribedDisplacementsModule;

impl Plugin for PrescribedDisplacementsModule {
    fn name(&self) -> &'static str {
        "prescribed displacements"
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        constraints(spec).iter().any(|c| c.value != 0.0)
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        simulation.add_systems(Hook::Loads, apply_prescribed_displacements::<D>);
        // linear FEM's nodes move with the body: the material at a node is the node, so the
        // motion is exact and there is nothing to check (the check's estimate `x_p + F_p (X_i −
        // X_p)` would even be off with F-bar, whose `F̄_p` is not the displacement's gradient)
        if simulation.spec().grid.basis != crate::basis::BasisKind::Fem {
            let watch = watched_nodes::<D>(simulation);
            simulation.world().insert_resource(watch);
            simulation.add_systems(Hook::AfterStep, check_prescribed_motion::<D>);
        }
    }
}

/// Tolerance of [`check_prescribed_motion`]: the material's boundary displacement may differ
/// from the prescribed one by this fraction.
pub const PRESCRIBED_MOTION_TOLERANCE: f64 = 0.01;

/// A node with a non-zero prescribed displacement and the material point that started
/// nearest to it (within a cell), whose motion [`check_prescribed_motion`] compares.
#[derive(Clone, Debug)]
pub struct WatchedNode<const D: usize> {
    pub declaration: usize,
    pub node: usize,
    pub position: SVector<f64, D>,
    /// The material point's `PointId` (its place among the scene's points).
    pub host: u32,
    pub prescribed: SVector<f64, D>,
    pub fixed: [bool; D],
    /// The stages the declaration acts in.
    pub window: Window,
    /// The material's displacement at the node when the declaration's stage started (zero
    /// for a declaration of the first stage; `None` in a run resumed after that start: the
    /// node is then not compared).
    pub origin: Option<SVector<f64, D>>,
}

/// The watched nodes of every `displace`, and the declarations already warned about.
#[derive(Resource, Clone, Debug)]
pub struct PrescribedMotion<const D: usize> {
    pub nodes: Vec<WatchedNode<D>>,
    pub names: Vec<(String, Option<usize>)>,
    pub warned: Vec<bool>,
}

fn watched_nodes<const D: usize>(simulation: &mut Extension<'_, D>) -> PrescribedMotion<D> {
    let spec = simulation.spec();
    let declared = spec
        .part::<ConstraintDeclarations>()
        .map_or(&[][..], |d| &d.0);
    let grid = &spec.grid;
    let world = simulation.world();
    // the positions of the nodes the declarations name (not a vector over the whole grid)
    let named: std::collections::BTreeSet<usize> = (declared.iter())
        .flat_map(|d| d.components.iter().map(|&(n, _)| n))
        .collect();
    let mut node_positions: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for node in world.query::<&GridNode<D>>().iter(world) {
        if named.contains(&node.index) {
            node_positions.insert(node.index, node.position.as_slice().to_vec());
        }
    }
    let cell = (0..D)
        .map(|a| (grid.upper[a] - grid.lower[a]) / grid.cells[a] as f64)
        .fold(0.0, f64::max);
    let material = spec.material_point_positions();
    let mut motion = PrescribedMotion::<D> {
        names: declared.iter().map(|d| (d.name.clone(), d.line)).collect(),
        warned: vec![false; declared.len()],
        nodes: Vec::new(),
    };
    for (index, declaration) in declared.iter().enumerate() {
        if declaration.values.iter().all(|&v| v == 0.0) {
            continue;
        }
        let mut nodes: Vec<usize> = declaration.components.iter().map(|&(n, _)| n).collect();
        nodes.dedup();
        let queries: Vec<Vec<f64>> = nodes.iter().map(|&n| node_positions[&n].clone()).collect();
        let hosts = crate::scene::nearest_points(grid, &material, &queries);
        for ((&node, query), host) in nodes.iter().zip(&queries).zip(hosts) {
            let Some(host) = host else { continue };
            let distance: f64 = query
                .iter()
                .zip(material[host])
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            if distance > cell {
                continue;
            }
            let mut watched = WatchedNode {
                declaration: index,
                node,
                position: SVector::from_column_slice(query),
                host: host as u32,
                prescribed: SVector::zeros(),
                fixed: [false; D],
                window: declaration.window,
                origin: None,
            };
            for (&axis, &value) in declaration.axes.iter().zip(&declaration.values) {
                watched.fixed[axis] = true;
                watched.prescribed[axis] = value;
            }
            if declaration.window.from == 0 {
                watched.origin = Some(SVector::zeros());
            }
            motion.nodes.push(watched);
        }
    }
    motion
}

/// What [`check_prescribed_motion`] reads of a held point: its id, `x_p`, `X_p` and `F_p`.
type WatchedPoint<'a, const D: usize> = (
    &'a crate::components::PointId,
    &'a crate::components::Position<D>,
    &'a crate::components::ReferencePosition<D>,
    &'a crate::components::DeformationGradient<D>,
);

/// After a converged step: does the material still carry the motion prescribed at the grid
/// nodes? The material that started at a watched node X_i is at x_p + F_p (X_i − X_p), with p
/// the material point that started nearest to it; its displacement along each prescribed axis
/// is compared with λ times the prescribed value. A difference of more than 1 % of the
/// largest prescribed component, or a prescribed node without material support, is a warning
/// (once per declaration): the grid is reset every step, so a node moves the material that is
/// at it at the start of the step, and in compression the material leaves the node.
pub fn check_prescribed_motion<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    fields: Res<GridFields<D>>,
    mut motion: ResMut<PrescribedMotion<D>>,
    mut warnings: ResMut<Warnings>,
    points: Query<WatchedPoint<D>>,
) {
    let stage = stage_of(&stage);
    let (displacements, active) = material_at_watched_nodes(&motion.nodes, &fields, &points);
    let PrescribedMotion {
        nodes,
        names,
        warned,
    } = &mut *motion;
    for ((watched, material_displacement), active) in
        nodes.iter_mut().zip(displacements).zip(active)
    {
        if warned[watched.declaration] {
            continue;
        }
        if !watched.window.covers(stage) {
            // before its stage: where its stage will start it from
            if stage < watched.window.from {
                watched.origin = material_displacement;
            }
            continue;
        }
        let Some(origin) = watched.origin else {
            continue;
        };
        let prescribed =
            watched.prescribed * step.factor_in(Ramp::staged(false, watched.window.from), stage);
        let scale = prescribed.amax();
        if scale == 0.0 {
            continue;
        }
        let (name, line) = &names[watched.declaration];
        let line = line.map(|l| format!("line {l}: ")).unwrap_or_default();
        let advice = "the grid is reset every step, so a grid-node displace moves the material that is at the node at the start of each step; use surface_displace(...) on the body's surface (docs/boundaries.md)";
        if !active {
            warned[watched.declaration] = true;
            warnings.0.push(format!(
                "{line}{name}: at step {} the prescribed node at {:?} has no material next to it any more: the material does not follow the prescribed displacement; {advice}",
                step.number,
                watched.position.as_slice()
            ));
            continue;
        }
        let Some(achieved) = material_displacement else {
            continue;
        };
        let achieved = achieved - origin;
        let worst = (0..D)
            .filter(|&a| watched.fixed[a])
            .map(|a| (achieved[a] - prescribed[a]).abs())
            .fold(0.0, f64::max);
        if worst > PRESCRIBED_MOTION_TOLERANCE * scale {
            warned[watched.declaration] = true;
            warnings.0.push(format!(
                "{line}{name}: at step {} (load factor {}) the material at the prescribed node {:?} moved by {:?} instead of {:?} ({:.1} % off): {advice}",
                step.number,
                step.factor,
                watched.position.as_slice(),
                achieved.as_slice(),
                prescribed.as_slice(),
                100.0 * worst / scale
            ));
        }
    }
}

/// For each watched node: the displacement of the material that started at it, `x_p + F_p
/// (X_i − X_p) − X_i` of its host point p (`None` if no process holds p), and whether the
/// node is active (touched by material). With decomposed points the host may be on another
/// process and a node may be active on another process only: the host's numbers come from
/// the process that holds it and the activity is summed over the processes
/// (`distributed::numbers_of_points`, collective), so every process sees the serial run's.
fn material_at_watched_nodes<const D: usize>(
    nodes: &[WatchedNode<D>],
    fields: &GridFields<D>,
    points: &Query<WatchedPoint<D>>,
) -> (Vec<Option<SVector<f64, D>>>, Vec<bool>) {
    let mut hosts: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for (k, watched) in nodes.iter().enumerate() {
        hosts.entry(watched.host).or_default().push(k);
    }
    let mut held = vec![None; nodes.len()];
    for (id, x, reference, f) in points.iter() {
        for &k in hosts.get(&id.0).map_or(&[][..], Vec::as_slice) {
            let at = nodes[k].position;
            held[k] = Some(x.0 + f.0 * (at - reference.0) - at);
        }
    }
    let displacements = crate::distributed::numbers_of_points(nodes.len(), D, |k, out| {
        held[k].is_some_and(|displacement| {
            out.copy_from_slice(displacement.as_slice());
            true
        })
    });
    let mut active: Vec<f64> = (nodes.iter())
        .map(|watched| f64::from(u8::from(fields.active[watched.node])))
        .collect();
    crate::distributed::sum_over_points(&mut active);
    (
        (displacements.into_iter())
            .map(|numbers| numbers.map(|n| SVector::from_column_slice(&n)))
            .collect(),
        active.into_iter().map(|count| count > 0.0).collect(),
    )
}

/// `displace`: the step's increment of every prescribed component, `(λ_n+1 − λ_n) ū`; in a
/// staged scene only in the stage the component starts acting in (held after it: module
/// docs, "Stages").
pub fn apply_prescribed_displacements<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    nodes: Query<(&GridNode<D>, &Fixity<D>, Option<&FixityWindows<D>>)>,
) {
    let _timer = clock.time(Stage::Loads);
    let stage = stage_of(&stage);
    let ramp = step.factor - step.previous_factor;
    // decomposed points: the nodes this process touches (no point reads another's increment)
    let decomposed = crate::distributed::decomposed();
    for (node, fixity, windows) in nodes.iter() {
        if decomposed && !fields.active[node.index] {
            continue;
        }
        for c in 0..D {
            if fixity.fixed[c] {
                let ramp = match windows {
                    Some(windows) if !windows.0[c].iter().any(|w| w.from == stage) => 0.0,
                    _ => ramp,
                };
                fields.increment[node.index][c] = fixity.prescribed[c] * ramp;
            }
        }
    }
}

/// The options map of `fix` / `displace`.
fn constraint_options() -> Vec<OptionSpec> {
    vec![OptionSpec::new(
        "until_stage",
        Kind::Text,
        "the stage whose start releases the constraint (its force ramped down over that stage)",
    )]
}

fn declare_constraint(
    builder: &mut SceneBuilder,
    function_name: &'static str,
    selector: &Dynamic,
    components: &Dynamic,
    values: Option<&Dynamic>,
    options: Option<&Dynamic>,
    at: Position,
) -> Result<Dynamic, String> {
    let until = match options {
        None => None,
        Some(options) => Options::read(function_name, options, &constraint_options(), None)?
            .text("until_stage")
            .map(str::to_string),
    };
    let selector = function(
        selector,
        &format!("{function_name}(...): the first argument"),
    )?;
    let components_subject = format!("{function_name}(...): the components");
    // fix(|x| ..) without components: all of them, known once the grid is
    let all_components = components.is_unit();
    let components = if all_components {
        Vec::new()
    } else {
        whole_numbers(components, &components_subject, 0)?
    };
    if components.is_empty() && !all_components {
        return Err(format!(
            "{components_subject} must list at least one axis index, got []"
        ));
    }
    if let Some(duplicate) = components
        .iter()
        .enumerate()
        .find_map(|(index, component)| components[..index].contains(component).then_some(component))
    {
        return Err(format!("{components_subject} list {duplicate} twice"));
    }
    let values = match values {
        None => vec![0.0; components.len()],
        Some(values) => {
            let values = numbers(values, &format!("{function_name}(...): the values"))?;
            if values.len() != components.len() {
                return Err(format!(
                    "{function_name}(...): {} components but {} values; give one value per component",
                    components.len(),
                    values.len()
                ));
            }
            values
        }
    };
    builder.declare(Located::new(
        ConstraintDeclaration {
            function: function_name,
            selector,
            components,
            values,
            until,
        },
        at,
    ));
    Ok(Dynamic::UNIT)
}

/// What [`resolve_constraints`] finds: the constrained components, the declarations, and the
/// stage windows of the components (`None` when every component acts in every stage).
type Resolved = (
    Vec<NodeConstraint>,
    Vec<DeclaredConstraint>,
    Option<Vec<Vec<Window>>>,
);

/// The stages `#{ until_stage }` of a declaration of stage `from` leaves it acting in (refused with
/// the line: no stages, an unknown stage, a stage not after its own).
fn window_of(
    scene: &Resolver,
    declaration: &Located<ConstraintDeclaration>,
) -> Result<Window, ScriptError> {
    let function = declaration.value.function;
    let from = declaration.stage;
    let Some(until) = &declaration.value.until else {
        return Ok(Window { from, until: None });
    };
    let index = until_stage(scene.spec, function, until, from, declaration.at)?;
    Ok(Window {
        from,
        until: Some(index),
    })
}

fn resolve_constraints(scene: &Resolver) -> Result<Resolved, ScriptError> {
    let declarations = scene.declarations::<ConstraintDeclaration>();
    if declarations.is_empty() {
        return Ok((Vec::new(), Vec::new(), None));
    }
    let mut declared: Vec<DeclaredConstraint> = Vec::new();
    let grid = &scene.spec.grid;
    let dim = grid.dim();
    let nodes = scene.node_positions()?;
    // (node, component) -> (value, line of the declaring call, the stages it acts in)
    let mut prescribed: BTreeMap<(usize, usize), (f64, Position, Vec<Window>)> = BTreeMap::new();
    for declaration in declarations {
        let mut constraint = declaration.value.clone();
        if constraint.components.is_empty() {
            constraint.components = (0..dim).collect();
            constraint.values = vec![0.0; dim];
        }
        let function = constraint.function;
        if let Some(&component) = constraint.components.iter().find(|&&c| c >= dim) {
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): component {component} does not exist, the grid is {dim}-dimensional (components 0..{})",
                    dim - 1
                ),
            ));
        }
        let window = window_of(scene, declaration)?;
        let context = format!(
            "node predicate of {function}(...){}",
            declaration.line_note()
        );
        let mut selected = 0usize;
        let number = 1 + declared
            .iter()
            .filter(|d| d.name.starts_with(function))
            .count();
        let mut this = DeclaredConstraint {
            name: format!("{function}{number}"),
            line: declaration.at.line(),
            components: Vec::new(),
            axes: constraint.components.clone(),
            values: constraint.values.clone(),
            lower: Vec::new(),
            upper: Vec::new(),
            window,
        };
        for (node, position) in nodes.iter().enumerate() {
            if !scene.call_predicate(&constraint.selector, position, declaration.at, &context)? {
                continue;
            }
            selected += 1;
            if this.lower.is_empty() {
                this.lower = position.clone();
                this.upper = position.clone();
            }
            for (a, &x) in position.iter().enumerate() {
                this.lower[a] = this.lower[a].min(x);
                this.upper[a] = this.upper[a].max(x);
            }
            this.components
                .extend(constraint.components.iter().map(|&c| (node, c)));
            for (&component, &value) in constraint.components.iter().zip(&constraint.values) {
                let mut windows = vec![window];
                if let Some((previous, previous_at, previous_windows)) =
                    prescribed.get(&(node, component))
                {
                    let previous_line = previous_at
                        .line()
                        .map(|line| format!(" at line {line}"))
                        .unwrap_or_default();
                    if *previous != value {
                        return Err(ScriptError::at(
                            declaration.at,
                            format!(
                                "{function}(...): component {component} of the node at {position:?} is already prescribed to {previous}{previous_line}, not {value}"
                            ),
                        ));
                    }
                    // a prescribed displacement follows the schedule of the one stage it
                    // starts in: two of them must act in the same stages
                    if value != 0.0 && previous_windows[..] != [window] {
                        return Err(ScriptError::at(
                            declaration.at,
                            format!(
                                "{function}(...): component {component} of the node at {position:?} is already prescribed{previous_line} in other stages; a prescribed displacement can be declared once per component"
                            ),
                        ));
                    }
                    windows = previous_windows.clone();
                    if !windows.contains(&window) {
                        windows.push(window);
                    }
                }
                prescribed.insert((node, component), (value, declaration.at, windows));
            }
        }
        if selected == 0 {
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): the predicate selects no grid node (nodes have {}; compare with a tolerance if needed)",
                    selection_ranges(nodes.iter().map(Vec::as_slice))
                ),
            ));
        }
        declared.push(this);
    }
    let staged = declared.iter().any(|d| d.window != Window::ALWAYS);
    let mut windows = Vec::new();
    let constraints = prescribed
        .into_iter()
        .map(|((node, component), (value, _, window))| {
            windows.push(window);
            NodeConstraint {
                node,
                component,
                value,
            }
        })
        .collect();
    Ok((constraints, declared, staged.then_some(windows)))
}
