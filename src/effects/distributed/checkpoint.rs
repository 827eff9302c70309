//! Checkpoints of decomposed runs (`mpirun -n N impm run SCENE --decompose
//! --checkpoint-every K`, and `--resume`): one checkpoint file in the serial format, whatever
//! the number of processes, so that a decomposed run resumes a serial checkpoint and a serial
//! run a decomposed one, over any number of processes.
//!
//! **Writing** ([`saved_parts_of_every_point`], at every checkpoint step, collective): each
//! process packs the points it holds as `PointRecord`s (`respawn::take_record`: the core's
//! state and every module's point-state part, the records the exchange between the processes
//! sends) and sends them to process 0 (`distributed::exchange`, the other processes' messages
//! empty). Process 0 spawns the arrivals beside its own points (`respawn::spawn_record`),
//! saves every checkpoint part as a serial run does (`checkpoint::save_parts`: each part
//! writes its points in `PointId` order, so the numbers are the serial run's), and despawns
//! the arrivals again, last first (a table of the world then only loses its last rows: its
//! own points keep their order, the order its stages sum in). Process 0 then writes the
//! checkpoint as a serial run does (atomically, the previous one valid until the new header
//! names the new binary file); the other processes write none. A failure (a point that does
//! not pack, process 0 failing to spawn or to write) is shared between the load steps as every
//! failure of what a process does alone there (`share_outcome`): every process stops after the
//! same step, the previous checkpoint kept.
//!
//! Cost: process 0 holds, while it saves, every point's record (`FIXED + n` numbers, 16 + n in
//! 2D) and every point as an entity, as a replicated process does; the other processes hold
//! nothing more. Past one machine's memory the checkpoint should be written per process
//! (each its points' records beside process 0's header) instead.
//!
//! **Resuming** (`--resume` under `mpirun --decompose`): every process reads the checkpoint and
//! spawns every point of the scene (`distributed::initial_points` is `None` when resuming), the
//! checkpoint restores them as in a serial run, and [`keep_own_points`] then keeps the points of
//! the process's slab: the rule of a step's start (`partition::slab_owners` over the points in
//! each cell layer), here over every point, which each process holds, so no message is needed.
//! The points kept are spawned anew in `PointId` order, as the exchange leaves them. While it
//! resumes, each process holds every point once (as a replicated process does).

use bevy_ecs::prelude::*;

use super::{AssemblyShare, point_slices};
use crate::checkpoint::save_parts;
use crate::components::PointId;
use crate::distributed::migration::{PointRecord, pack_points, unpack_points};
use crate::distributed::partition::slab_owners;
use crate::distributed::respawn::{spawn_record, take_record};
use crate::distributed::{decomposed, exchange};

/// A checkpoint's parts: each owner's name and numbers (`checkpoint::save_parts`).
pub type SavedParts = Vec<(String, Vec<f64>)>;

/// Every point's checkpoint parts, on process 0 of a decomposed run (collective: every process
/// must call it at the same step); `Ok(None)` on the other processes, which write no
/// checkpoint. Outside a decomposed run, the parts of the points this process holds (all of
/// them) on process 0 or in a serial run; `Ok(None)` on the other processes of a replicated
/// run (process 0's checkpoint is the same).
pub fn saved_parts_of_every_point<const D: usize>(
    world: &mut World,
) -> Result<Option<SavedParts>, String> {
    if !decomposed() {
        return Ok(crate::distributed::writes_run_files().then(|| save_parts(world)));
    }
    let rank = world.resource::<AssemblyShare>().processes.rank;
    let size = world.resource::<AssemblyShare>().processes.size;
    // the points this process holds, as the exchange sends them (a failure to pack one still
    // takes part in the exchange, with nothing sent)
    let mut outgoing = vec![Vec::new(); size];
    let packed = if rank == 0 {
        Ok(())
    } else {
        held_records::<D>(world).map(|records| outgoing[0] = pack_points(&records))
    };
    let received = exchange(&outgoing)?;
    // process 0 must not write a checkpoint without some process's points
    if crate::distributed::any(packed.is_err()) {
        return packed.and(Err("a point could not be packed on another process".into()));
    }
    if rank != 0 {
        return Ok(None);
    }
    let mut arrived = Vec::new();
    for message in &received {
        arrived.extend(unpack_points::<D>(message)?);
    }
    let mut spawned = Vec::with_capacity(arrived.len());
    let mut result = Ok(());
    for record in &arrived {
        match spawn_record::<D>(world, record) {
            Ok(entity) => spawned.push(entity),
            Err(why) => {
                result = Err(format!("a point of another process: {why}"));
                break;
            }
        }
    }
    let parts = result.map(|()| save_parts(world));
    // last first: each removal takes the last row of its table, so no point of this
    // process's own moves
    for entity in spawned.into_iter().rev() {
        world.despawn(entity);
    }
    parts.map(Some)
}

/// The points this process holds, in `PointId` order, as records.
fn held_records<const D: usize>(world: &mut World) -> Result<Vec<PointRecord<D>>, String> {
    let mut points: Vec<(u32, Entity)> = world
        .query::<(Entity, &PointId)>()
        .iter(world)
        .map(|(entity, id)| (id.0, entity))
        .collect();
    points.sort_unstable_by_key(|&(id, _)| id);
    points
        .into_iter()
        .map(|(_, entity)| take_record::<D>(world, entity))
        .collect()
}

/// After a resumed decomposed run restored every point from the checkpoint: keeps the points
/// of this process's slab (the ownership rule of a step's start, over every point, which this
/// process holds), spawned anew in `PointId` order, and counts them in the share. Nothing
/// outside a decomposed run.
pub fn keep_own_points<const D: usize>(world: &mut World) -> Result<(), String> {
    if !decomposed() {
        return Ok(());
    }
    let (rank, size) = {
        let share = world.resource::<AssemblyShare>();
        (share.processes.rank, share.processes.size)
    };
    let (points, per_slice) = point_slices::<D>(world);
    let layer_owners = slab_owners(&per_slice, size);
    let mut kept = Vec::new();
    for &(entity, slice) in &points {
        if layer_owners[slice] == rank {
            kept.push(take_record::<D>(world, entity)?);
        }
    }
    for (entity, _) in points {
        world.despawn(entity);
    }
    kept.sort_by_key(|record| record.id);
    for record in &kept {
        spawn_record::<D>(world, record)?;
    }
    let mut share = world.resource_mut::<AssemblyShare>();
    share.points = kept.len();
    share.moved = 0;
    Ok(())
}
