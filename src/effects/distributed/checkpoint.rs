//! Checkpoints of decomposed runs (`mpirun -n N impm run SCENE --decompose
//! --checkpoint-every K`, and `--resume`).
//!
//! With one process (`-n 1 --decompose`) the checkpoint is the serial one (one binary file,
//! `crate::restart`). With several, it is **in pieces**, so that no process ever holds more
//! points than its own, writing or resuming:
//!
//! ```text
//! checkpoint_NNNN_pK.bin   process K's points as records (PointRecord: the core's state and
//!                          every module's point-state part, what the exchange between the
//!                          processes sends), in PointId order, written by process K itself
//! checkpoint_NNNN.bin      the parts that are not the points' (process 0's: the arc-length
//!                          control, released supports, boundary and pressure points, ...)
//! checkpoint.json          the header, by process 0, last: it names the binary file and every
//!                          piece (points, bytes, FNV-1a hash, first and last cell layer of its
//!                          points), the parts the records carry, and the points in each cell
//!                          layer along the slab axis
//! ```
//!
//! **Writing** ([`saved_parts_of_every_point`], at every checkpoint step, collective): each
//! process packs its points, one record after the other, straight into the bytes of its piece
//! and writes them durably into process 0's folder (`restart::write_piece`: a temporary file,
//! fsynced, renamed, the folder fsynced). Then every process learns whether every piece was
//! written (`share_outcome`: a failure is every process's, naming the process and the file,
//! and no header is written: the previous checkpoint stays the valid one), process 0 gathers
//! the pieces' counts, lengths and hashes (one `gather_all` of 6 numbers per process) and the
//! points per cell layer (one `sum_all` of a number per layer), saves the parts the records do
//! not carry, and `Simulation::write_checkpoint` writes the binary file and then the header
//! (both durably). Only once the header is in place are the files of the earlier checkpoint
//! removed (`restart`), so a crash at any point leaves the previous header with its files.
//!
//! The parts the records carry ([`carried_parts`]): the core's `points`, every part named as a
//! point-state part (a material's history, the displacement origins), and the load points'
//! positions (`traction points`), which are their hosts' `x + F·offset` and are placed again
//! from the hosts a process holds at the next step's start (`tractions::follow_hosts`). Every
//! other part is replicated (every process holds every boundary and pressure point, the
//! arc-length state is agreed), so process 0's is the run's.
//!
//! **Resuming** ([`keep_own_points`], under `mpirun -n M --decompose --resume`, any `M`):
//! every process reads the header (`Checkpoint::read` checks that every piece exists with its
//! length, so a missing or truncated piece is refused alike by every process, naming it,
//! before the run is built), builds the run without any point (`distributed::initial_points`
//! when resuming in pieces), restores the non-carried parts, and divides the points by the
//! header's points per cell layer with the rule of a step's start (`partition::slab_owners`
//! over `M` processes): it then reads only the pieces whose cell layers meet its own slab, one
//! at a time (checking each piece's hash and count), keeps the records of its layers and spawns
//! them in `PointId` order (`respawn::spawn_record`), as the exchange leaves them. A piece that
//! cannot be read is shared (`distributed::any`): every process fails, the one that read it
//! naming the file. A serial or replicated `--resume` of a checkpoint in pieces is refused,
//! saying how to resume it (`Checkpoint::needs_decomposition`).
//!
//! **Cost.** Writing, a process holds its own points as entities plus the bytes of its piece
//! (`8 (FIXED + n)` per point: 16 + n numbers in 2D, `n` the point-state numbers) and one
//! record; process 0 also the non-carried parts. Resuming, a process holds at peak its own
//! points' records (kept), one piece's bytes and numbers at a time, and then its own points
//! as entities; never another process's points as entities. (Before 2026-12-08 process 0
//! gathered every point's record and spawned them all to write one serial file, and every
//! process spawned every point when resuming: `docs/distributed.md` gives the measured peaks.)

use bevy_ecs::prelude::*;

use super::{AssemblyShare, point_slices, share_outcome};
use crate::checkpoint::{CheckpointParts, PointStateParts, save_parts};
use crate::components::PointId;
use crate::distributed::migration::{PointRecord, unpack_points};
use crate::distributed::partition::slab_owners;
use crate::distributed::respawn::{spawn_record, take_record};
use crate::distributed::{any, decomposed, gather_all, layer_of, sum_all};
use crate::resources::{Grid, SolverError};
use crate::restart::{Piece, Pieces, piece_file_name, read_piece, write_piece};
use crate::stages::output::ParticlePieces;

/// A checkpoint's parts: each owner's name and numbers (`checkpoint::save_parts`).
pub type SavedParts = Vec<(String, Vec<f64>)>;

/// The parts of positions derived from the host points (`x + F·offset`), which a resumed
/// process places again from the hosts it holds (`tractions::follow_hosts`).
const PLACED_FROM_HOSTS: [&str; 1] = ["traction points"];

/// The checkpoint of the steps done so far (collective: every process of a decomposed run
/// must call it at the same step), on process 0: its parts and, over several processes, its
/// pieces (every process has written its own; see the module docs); `Ok(None)` on the other
/// processes. With decomposed points on one process, or outside a decomposed run, the serial
/// checkpoint's parts of the points this process holds (all of them) on process 0 or in a
/// serial run; `Ok(None)` on the other processes of a replicated run (process 0's checkpoint
/// is the same).
pub fn saved_parts_of_every_point<const D: usize>(
    world: &mut World,
    steps_done: usize,
) -> Result<Option<(SavedParts, Option<Pieces>)>, SolverError> {
    if !decomposed() {
        return Ok(crate::distributed::writes_run_files().then(|| (save_parts(world), None)));
    }
    if world.resource::<AssemblyShare>().processes.size > 1 {
        return saved_in_pieces::<D>(world, steps_done);
    }
    // one process: it holds every point
    Ok(Some((save_parts(world), None)))
}

/// [`saved_parts_of_every_point`] over several processes: each writes its piece (module docs).
fn saved_in_pieces<const D: usize>(
    world: &mut World,
    steps_done: usize,
) -> Result<Option<(SavedParts, Option<Pieces>)>, SolverError> {
    let (rank, axis) = {
        let share = world.resource::<AssemblyShare>();
        (share.processes.rank, share.axis)
    };
    let dir = world.resource::<ParticlePieces>().dir.clone();
    let file = piece_file_name(steps_done, rank);
    let (_, per_layer) = point_slices::<D>(world);
    let layers = per_layer
        .iter()
        .position(|&n| n > 0)
        .zip(per_layer.iter().rposition(|&n| n > 0));
    let written = piece_bytes::<D>(world).and_then(|(points, bytes)| {
        write_piece(&dir, &file, &bytes).map(|(length, hash)| (points, length, hash))
    });
    // every piece written, or every process fails alike (the header is not written)
    let outcome = written
        .as_ref()
        .map(|_| ())
        .map_err(|why| SolverError::Output {
            step: steps_done,
            why: format!("writing this process's piece of the checkpoint: {why}"),
        });
    share_outcome(outcome, steps_done)?;
    let (points, length, hash) = written.unwrap_or_default();
    let (first, last) = layers.unwrap_or_default();
    let mine = [
        points,
        length,
        hash,
        u64::from(layers.is_some()),
        first as u64,
        last as u64,
    ];
    let every = gather_all(&mine).map_err(|why| SolverError::Output {
        step: steps_done,
        why: format!("gathering the checkpoint's pieces: {why}"),
    })?;
    let mut counts: Vec<f64> = per_layer.iter().map(|&n| n as f64).collect();
    sum_all(&mut counts);
    if rank != 0 {
        return Ok(None);
    }
    let files = every
        .iter()
        .enumerate()
        .map(|(k, piece)| Piece {
            file: piece_file_name(steps_done, k),
            points: piece[0],
            bytes: piece[1],
            fnv1a: piece[2],
            layers: (piece[3] == 1).then(|| (piece[4] as usize, piece[5] as usize)),
        })
        .collect();
    let carried = carried_parts(world);
    let parts = world
        .get_resource::<CheckpointParts>()
        .cloned()
        .unwrap_or_default();
    let saved = parts
        .0
        .iter()
        .filter(|part| !carried.iter().any(|name| name == part.name))
        .map(|part| (part.name.to_string(), (part.save)(world)))
        .collect();
    let pieces = Pieces {
        carried,
        dim: D,
        axis,
        layers: counts.iter().map(|&n| n as u64).collect(),
        files,
        folder: dir,
    };
    Ok(Some((saved, Some(pieces))))
}

/// The names of the registered checkpoint parts that the points' records carry, in
/// registration order: the core's `points`, every part named as a point-state part, and the
/// load points placed from their hosts (module docs).
pub fn carried_parts(world: &World) -> Vec<String> {
    let point_state: Vec<&str> = world
        .get_resource::<PointStateParts>()
        .map(|parts| parts.0.iter().map(|part| part.name).collect())
        .unwrap_or_default();
    world
        .get_resource::<CheckpointParts>()
        .map(|parts| {
            parts
                .0
                .iter()
                .map(|part| part.name)
                .filter(|name| {
                    *name == "points"
                        || point_state.contains(name)
                        || PLACED_FROM_HOSTS.contains(name)
                })
                .map(str::to_string)
                .collect()
        })
        .unwrap_or_default()
}

/// The points this process holds, in `PointId` order, as the bytes of its piece (each record
/// packed and appended in turn: one record held at a time), and their number.
fn piece_bytes<const D: usize>(world: &mut World) -> Result<(u64, Vec<u8>), String> {
    let mut points: Vec<(u32, Entity)> = world
        .query::<(Entity, &PointId)>()
        .iter(world)
        .map(|(entity, id)| (id.0, entity))
        .collect();
    points.sort_unstable_by_key(|&(id, _)| id);
    let mut bytes = Vec::new();
    let mut numbers = Vec::new();
    for &(_, entity) in &points {
        numbers.clear();
        take_record::<D>(world, entity)?.pack(&mut numbers);
        for value in &numbers {
            bytes.extend_from_slice(&value.to_bits().to_le_bytes());
        }
    }
    Ok((points.len() as u64, bytes))
}

/// After a resumed decomposed run restored the checkpoint's parts: gives this process the
/// points of its slab, and counts them in the share (collective). From a checkpoint in
/// `pieces`, the records of the pieces that meet its slab, read one at a time (module docs);
/// from a serial checkpoint, which restored every point, the ownership rule of a step's start
/// over every point, which this process holds. Nothing outside a decomposed run.
pub fn keep_own_points<const D: usize>(
    world: &mut World,
    pieces: Option<&Pieces>,
) -> Result<(), String> {
    if !decomposed() {
        return Ok(());
    }
    let (rank, size) = {
        let share = world.resource::<AssemblyShare>();
        (share.processes.rank, share.processes.size)
    };
    let kept = match pieces {
        Some(pieces) => {
            let read = own_records::<D>(world, pieces, rank, size);
            // a piece one process could not read fails every process
            if any(read.is_err()) {
                return Err(read.err().unwrap_or_else(|| {
                    format!(
                        "another process could not read its pieces of the checkpoint in {} \
                         (it says which)",
                        pieces.folder.display()
                    )
                }));
            }
            read?
        }
        None => {
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
            kept
        }
    };
    let mut kept = kept;
    kept.sort_by_key(|record| record.id);
    for record in &kept {
        spawn_record::<D>(world, record)?;
    }
    let mut share = world.resource_mut::<AssemblyShare>();
    share.points = kept.len();
    share.moved = 0;
    Ok(())
}

/// The records of this process's slab from the pieces that meet it (module docs), checking
/// each piece's count and that the pieces' points add up to the header's.
fn own_records<const D: usize>(
    world: &World,
    pieces: &Pieces,
    rank: usize,
    size: usize,
) -> Result<Vec<PointRecord<D>>, String> {
    let header = crate::restart::Checkpoint::path_in(&pieces.folder);
    let grid = &world.resource::<Grid<D>>().0;
    let axis = world.resource::<AssemblyShare>().axis;
    if pieces.dim != D {
        return Err(format!(
            "{} holds points of dimension {}, this run's are of dimension {D}",
            header.display(),
            pieces.dim
        ));
    }
    if axis != pieces.axis || pieces.layers.len() != grid.cells_per_axis()[axis] {
        return Err(format!(
            "{} divides its points in {} cell layers along axis {}, but this run's slabs are \
             {} cell layers along axis {axis}: the grid differs",
            header.display(),
            pieces.layers.len(),
            pieces.axis,
            grid.cells_per_axis()[axis]
        ));
    }
    let listed: u64 = pieces.files.iter().map(|piece| piece.points).sum();
    let counted: u64 = pieces.layers.iter().sum();
    if listed != counted {
        return Err(format!(
            "{} lists {listed} points in its pieces but {counted} in its cell layers: it is \
             damaged",
            header.display()
        ));
    }
    let per_layer: Vec<usize> = pieces.layers.iter().map(|&n| n as usize).collect();
    let owners = slab_owners(&per_layer, size);
    let mine = |layer: usize| owners[layer] == rank;
    let mut kept = Vec::new();
    for piece in &pieces.files {
        let meets = piece
            .layers
            .is_some_and(|(first, last)| (first..=last.min(owners.len() - 1)).any(mine));
        if !meets {
            continue;
        }
        let path = pieces.folder.join(&piece.file);
        let numbers = read_piece(pieces, piece)?;
        let records =
            unpack_points::<D>(&numbers).map_err(|why| format!("{}: {why}", path.display()))?;
        drop(numbers);
        if records.len() as u64 != piece.points {
            return Err(format!(
                "{} holds {} points, but the checkpoint {} names {}: the piece is damaged",
                path.display(),
                records.len(),
                header.display(),
                piece.points
            ));
        }
        kept.extend(
            records
                .into_iter()
                .filter(|record| mine(layer_of(grid, axis, &record.position))),
        );
    }
    Ok(kept)
}
