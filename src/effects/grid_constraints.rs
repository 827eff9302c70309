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

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::components::GridNode;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{GridFields, LoadStep, Stage, StageClock};
use crate::scene::SceneSpec;

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

    fn used_by(&self, spec: &SceneSpec) -> bool {
        !spec.constraints.is_empty()
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
        for c in &spec.constraints {
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
        spec.constraints.iter().any(|c| c.value != 0.0)
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
