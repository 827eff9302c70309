//! Constraints on grid nodes: `fix` (zero displacement) and `displace` (a prescribed total
//! displacement ramped with the load factor) on the components of the control points a
//! predicate selects.
//!
//! Two modules share the nodes' [`Fixity`]:
//!
//! * [`GridConstraintsModule`] marks the constrained components at `Hook::Constraints` every
//!   step (`GridFields::constrained`), so that they get no DOF: the Dirichlet conditions are
//!   eliminated from the system.
//! * [`PrescribedDisplacementsModule`], only when some prescribed value is not zero, sets the
//!   constrained components' increment at `Hook::Loads`: they move by (λ_{n+1} − λ_n) times
//!   their prescribed total before the first Newton iterate, so after the step the node has
//!   moved by λ_{n+1} times its prescribed value.
//!
//! A prescribed displacement moves the grid node, and so the material that is at the node at
//! the start of each step (the grid is reset every step): exact where the material stays at
//! the constrained nodes (tension, or linear FEM whose nodes move with the body).

use std::collections::BTreeMap;

use bevy_ecs::prelude::*;
use nalgebra::SVector;
use rhai::{Dynamic, FnPtr, Position};

use crate::components::GridNode;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{GridFields, LoadStep, Stage, StageClock};
use crate::scene::{
    CallSpec, Located, Resolver, SceneApi, SceneBuilder, SceneSpec, ScriptError, function, numbers,
    whole_numbers,
};

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
            "fixes the listed displacement components (0-based axes) of every grid node whose position satisfies the predicate (a roller: one component). Nodes are the control points (Greville abscissae; grid vertices for linear), with the first and last node of each axis exactly on the grid bounds",
            2,
            |builder, args, at| declare_constraint(builder, "fix", &args[0], &args[1], None, at),
        ))
        .call(CallSpec::args(
            "fix",
            "fix(|x| predicate)",
            "full fixity: every component of the selected nodes",
            1,
            |builder, args, at| {
                declare_constraint(builder, "fix", &args[0], &Dynamic::UNIT, None, at)
            },
        ))
        .call(CallSpec::args(
            "displace",
            "displace(|x| predicate, [components], [values])",
            "prescribes the displacement of the listed components of the selected grid nodes (values at load factor 1, ramped with the load factor); it moves the material at the node at the start of each step",
            3,
            |builder, args, at| {
                declare_constraint(builder, "displace", &args[0], &args[1], Some(&args[2]), at)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let constraints = resolve_constraints(scene)?;
        if !constraints.is_empty() {
            scene.spec.set_part(NodeConstraints(constraints));
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let constraints = constraints(spec);
        let prescribed = constraints.iter().filter(|c| c.value != 0.0).count();
        Some(format!(
            "{} constrained node components ({prescribed} with a prescribed displacement)",
            constraints.len()
        ))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        !constraints(spec).is_empty()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        let world = simulation.world();
        let nodes: Vec<(Entity, usize)> = world
            .query::<(Entity, &GridNode<D>)>()
            .iter(world)
            .map(|(entity, node)| (entity, node.index))
            .collect();
        let mut entities = vec![Entity::PLACEHOLDER; nodes.len()];
        for (entity, index) in nodes {
            entities[index] = entity;
        }
        let mut fixities = vec![None::<Fixity<D>>; entities.len()];
        for c in constraints(spec) {
            let Some(fixity) = fixities.get_mut(c.node) else {
                simulation.fail(format!("constraint on node {} outside the grid", c.node));
                return;
            };
            if c.component >= D {
                simulation.fail(format!("constraint on component {} in {D}D", c.component));
                return;
            }
            let fixity = fixity.get_or_insert_default();
            fixity.fixed[c.component] = true;
            fixity.prescribed[c.component] = c.value;
        }
        let world = simulation.world();
        let mut fields = world.resource_mut::<GridFields<D>>();
        for (node, fixity) in fixities.iter().enumerate() {
            if let Some(fixity) = fixity {
                fields.constrained[node] = fixity.fixed;
            }
        }
        let batch: Vec<(Entity, Fixity<D>)> = fixities
            .into_iter()
            .enumerate()
            .filter_map(|(node, fixity)| Some((entities[node], fixity?)))
            .collect();
        world.insert_batch(batch);
        simulation.add_systems(Hook::Constraints, constrain_nodes::<D>);
    }
}

/// The fixed components of every constrained node get no DOF.
pub fn constrain_nodes<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    nodes: Query<(&GridNode<D>, &Fixity<D>)>,
) {
    for (node, fixity) in nodes.iter() {
        fields.constrained[node.index] = fixity.fixed;
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
    }
}

pub fn apply_prescribed_displacements<const D: usize>(
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    nodes: Query<(&GridNode<D>, &Fixity<D>)>,
) {
    let _timer = clock.time(Stage::Loads);
    let ramp = step.factor - step.previous_factor;
    for (node, fixity) in nodes.iter() {
        for c in 0..D {
            if fixity.fixed[c] {
                fields.increment[node.index][c] = fixity.prescribed[c] * ramp;
            }
        }
    }
}

fn declare_constraint(
    builder: &mut SceneBuilder,
    function_name: &'static str,
    selector: &Dynamic,
    components: &Dynamic,
    values: Option<&Dynamic>,
    at: Position,
) -> Result<Dynamic, String> {
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
        },
        at,
    ));
    Ok(Dynamic::UNIT)
}

fn resolve_constraints(scene: &Resolver) -> Result<Vec<NodeConstraint>, ScriptError> {
    let declarations = scene.declarations::<ConstraintDeclaration>();
    if declarations.is_empty() {
        return Ok(Vec::new());
    }
    let grid = &scene.spec.grid;
    let dim = grid.dim();
    let nodes = scene.node_positions()?;
    // (node, component) -> (value, line of the declaring call)
    let mut prescribed: BTreeMap<(usize, usize), (f64, Position)> = BTreeMap::new();
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
        let context = format!(
            "node predicate of {function}(...){}",
            declaration.line_note()
        );
        let mut selected = 0usize;
        for (node, position) in nodes.iter().enumerate() {
            if !scene.call_predicate(&constraint.selector, position, declaration.at, &context)? {
                continue;
            }
            selected += 1;
            for (&component, &value) in constraint.components.iter().zip(&constraint.values) {
                if let Some(&(previous, previous_at)) = prescribed.get(&(node, component))
                    && previous != value
                {
                    let previous_line = previous_at
                        .line()
                        .map(|line| format!(" at line {line}"))
                        .unwrap_or_default();
                    return Err(ScriptError::at(
                        declaration.at,
                        format!(
                            "{function}(...): component {component} of the node at {position:?} is already prescribed to {previous}{previous_line}, not {value}"
                        ),
                    ));
                }
                prescribed.insert((node, component), (value, declaration.at));
            }
        }
        if selected == 0 {
            let ranges: Vec<String> = (0..dim)
                .map(|axis| format!("x[{axis}] in [{}, {}]", grid.lower[axis], grid.upper[axis]))
                .collect();
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): the predicate selects no grid node (nodes have {}; compare with a tolerance if needed)",
                    ranges.join(", ")
                ),
            ));
        }
    }
    Ok(prescribed
        .into_iter()
        .map(|((node, component), (value, _))| NodeConstraint {
            node,
            component,
            value,
        })
        .collect())
}
