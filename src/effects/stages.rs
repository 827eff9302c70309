//! Displacements measured from a stage's start: `stage(#{ .., zero_displacements: true })`
//! (`scene::stages`). At the stage's start every material point keeps its displacement so far
//! as its origin, `u_0,p = x_p − X_p`, and its displacement field restarts from zero:
//!
//! ```text
//!   u_p ← 0,   and after the stage's steps   u_p = Σ Δu_p = x_p − X_p − u_0,p,
//! ```
//!
//! the `displacement` point field (the `Displacement` component) and the probes
//! (`probes.rs`: `Σ w (x − X − u_0)`) measure from the stage's start. Positions, `F`,
//! stresses and histories stay: the state is the one the earlier stages left (a geostatic
//! stage's stresses with the settlement under the soil's weight removed from the displacements
//! of the footing pushed after it). The origins are a part of the checkpoint, so that a run
//! resumed within the stage measures from the same state.

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::checkpoint::{self, CheckpointPart};
use crate::components::{Displacement, PointId, Position, ReferencePosition};
use crate::plugin::{Extension, Plugin};
use crate::scene::{SceneSpec, Stages};

/// A point's displacement at the start of the last stage that zeroed the displacements
/// (absent before one did: zero).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct DisplacementOrigin<const D: usize>(pub SVector<f64, D>);

/// The point's displacement origin (zero without one).
pub fn origin_of<const D: usize>(world: &World, entity: Entity) -> SVector<f64, D> {
    world
        .get::<DisplacementOrigin<D>>(entity)
        .map_or_else(SVector::zeros, |origin| origin.0)
}

/// Starts measuring displacements from the current state: `u_0,p = x_p − X_p`, `u_p = 0` for
/// every material point.
pub fn zero_displacements<const D: usize>(world: &mut World) {
    let mut query = world.query::<(
        Entity,
        &Position<D>,
        &ReferencePosition<D>,
        &mut Displacement<D>,
    )>();
    let mut origins = Vec::new();
    for (entity, x, reference, mut u) in query.iter_mut(world) {
        origins.push((entity, DisplacementOrigin(x.0 - reference.0)));
        u.0 = SVector::zeros();
    }
    for (entity, origin) in origins {
        world.entity_mut(entity).insert(origin);
    }
}

/// The module: keeps the origins in the checkpoint of a scene with a stage that zeroes the
/// displacements (the driver, `run.rs`, zeroes them at the stage's start).
#[derive(Clone, Copy, Debug, Default)]
pub struct StagesModule;

impl Plugin for StagesModule {
    fn name(&self) -> &'static str {
        "displacements from a stage's start"
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<Stages>()
            .is_some_and(|stages| stages.0.iter().any(|stage| stage.zero_displacements))
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        simulation.checkpoint(CheckpointPart {
            name: "displacement origins",
            save: save_origins::<D>,
            restore: restore_origins::<D>,
        });
    }
}

/// Every point's origin, in `PointId` order.
fn save_origins<const D: usize>(world: &mut World) -> Vec<f64> {
    let mut query = world.query::<(Entity, &PointId)>();
    let mut rows: Vec<(u32, Entity)> = query.iter(world).map(|(e, id)| (id.0, e)).collect();
    rows.sort_by_key(|row| row.0);
    let mut values = Vec::with_capacity(rows.len() * D);
    for (_, entity) in rows {
        values.extend(origin_of::<D>(world, entity).iter());
    }
    values
}

fn restore_origins<const D: usize>(world: &mut World, values: &[f64]) -> Result<(), String> {
    let mut query = world.query::<(Entity, &PointId)>();
    let rows: Vec<(u32, Entity)> = query.iter(world).map(|(e, id)| (id.0, e)).collect();
    let records: Vec<&[f64]> = checkpoint::records(values, D, rows.len())?.collect();
    for (id, entity) in rows {
        let record = records
            .get(id as usize)
            .ok_or_else(|| format!("no displacement origin saved for point {id}"))?;
        let origin = DisplacementOrigin(SVector::<f64, D>::from_column_slice(record));
        world.entity_mut(entity).insert(origin);
    }
    Ok(())
}
