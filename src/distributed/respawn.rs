//! A material point taken out of a world as a [`PointRecord`] and spawned back from it: the ECS
//! side of moving points between processes (`migration` is the pure side; the exchange over MPI
//! that uses both is `effects::distributed::decomposition`).
//!
//! [`take_record`] reads the core's components and every module's part
//! (`checkpoint::pack_point_state`); [`spawn_record`] spawns the core's components
//! (`components::core_point`) and lets every module give the point its own
//! (`checkpoint::unpack_point_state`). A point moved this way continues exactly: a world whose
//! every point is taken out and spawned back gives the same results, bit for bit, as one left
//! alone (`tests/migration.rs`). Point loads are point-state parts, so they travel in the
//! record; traction and load points find their host again by its `PointId` after every
//! exchange (`effects::tractions::follow_hosts`), and so do the surface conditions' boundary
//! points (`effects::surface_conditions::follow_boundary_hosts`). Modules that keep a point's
//! `Entity` elsewhere (the host points of pressure points) do not follow it; a decomposed run
//! refuses them until they do (`decomposition::refusal`).

use bevy_ecs::prelude::*;

use crate::checkpoint::{pack_point_state, unpack_point_state};
use crate::components::{
    BodyIndex, DeformationGradient, Displacement, Mass, PointId, Position, ReferencePosition,
    ReferenceVolume, Volume, core_point,
};
use crate::distributed::migration::PointRecord;

/// The whole state of the point `entity` between load steps.
pub fn take_record<const D: usize>(
    world: &World,
    entity: Entity,
) -> Result<PointRecord<D>, String> {
    let point = world
        .get_entity(entity)
        .map_err(|_| format!("entity {entity} does not exist"))?;
    let (id, body, x, reference, u, f, mass, reference_volume, volume) = point
        .get_components::<(
            &PointId,
            &BodyIndex,
            &Position<D>,
            &ReferencePosition<D>,
            &Displacement<D>,
            &DeformationGradient<D>,
            &Mass,
            &ReferenceVolume,
            &Volume,
        )>()
        .map_err(|_| format!("entity {entity} is not a material point of dimension {D}"))?;
    Ok(PointRecord {
        id: id.0,
        body: body.0,
        position: x.0,
        reference_position: reference.0,
        displacement: u.0,
        deformation_gradient: f.0,
        mass: mass.0,
        reference_volume: reference_volume.0,
        volume: volume.0,
        history: pack_point_state(world, entity)?,
    })
}

/// Spawns the point `record` describes, with the core's components and every module's.
pub fn spawn_record<const D: usize>(
    world: &mut World,
    record: &PointRecord<D>,
) -> Result<Entity, String> {
    let entity = world.spawn(core_point(record)).id();
    unpack_point_state(world, entity, record.body, &record.history)
        .map_err(|why| format!("point {}: {why}", record.id))?;
    Ok(entity)
}
