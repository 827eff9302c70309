//! Decomposed points (`mpirun -n N impm run SCENE --decompose`): every process holds only the
//! points of its slab of cells, and points move to the process of the slab they are in at the
//! start of each load step. The grid is decomposed too: each process numbers, assembles and
//! gets back from the solver only the nodes its own points touch (its owned nodes and ghost
//! layer, `super::grid`; `docs/distributed.md`).
//!
//! **Ownership** (as the replicated runs' assembly share, `distributed::partition`): with
//! `n_i` the points in cell layer `i` along the slab axis, summed over the processes, layer `i`
//! goes to process `r_i = min(P − 1, ⌊P (c_i + n_i / 2) / T⌋)`, and a point to the process of
//! its layer at the start of the step.
//!
//! **A load step, decomposed** (the systems of this file; the others are the core's, each
//! on the points a process holds):
//!
//! 1. [`exchange_points`] (before the basis): owners from the layers' counts over all
//!    processes; `migration::plan_departures`; each departing point is taken out as a
//!    `PointRecord` (`respawn::take_record`, every module's part), packed per destination,
//!    and sent (`distributed::exchange`: an all-to-all of the counts, then of the numbers);
//!    the arrivals are spawned from their records (`respawn::spawn_record`). When anything
//!    left or arrived, every point the process holds is spawned anew in `PointId` order, so
//!    that its stages visit its points in the serial order (the world's order is the order
//!    the sums over points are taken in; `tests/migration.rs`). At the start of a run every
//!    process spawns its slab's points only (`distributed::initial_points`, from the seeds'
//!    positions; no message).
//! 2. The core's basis and DOF stages on the process's own points: its active nodes are the
//!    nodes its points touch, its pattern that of their supports and of its modules' coupling
//!    groups (F-bar's, whose members lie in one cell, so on one process; the ghost penalty's
//!    faces, each on the process holding its lower cell, whose nodes it makes active:
//!    `effects::ghost_penalty`); then the decomposed grid's owners and global numbers
//!    (`super::grid`, which first shares failures: a point outside the grid fails the basis
//!    on its own process only).
//! 3. [`sum_external_force`] (after the loads, outside their stage: it runs after a failure
//!    too, and shares it first): the body force, point loads and tractions are spread from the
//!    points (and load points) a process holds, so `f_ext` is a sum over the processes, as
//!    `f_int` is at `Hook::Combine`. Point loads travel as point-state parts of their points;
//!    traction and load points follow their hosts by `PointId` (`effects::tractions`), and so
//!    do the surface conditions' boundary points, whose terms after the assembly the host's
//!    process adds (`effects::surface_conditions`, "Decomposed points"). The follower
//!    pressure's points are held by every process, their positions shared by their hosts'
//!    processes; process 0 adds its force before this sum and its load stiffness
//!    (`effects::pressure`, "Over several processes").
//!
//! A stage's displacement origins travel with their points ([`carry_displacement_origins`]).
//! What sums over points elsewhere is summed over the processes too: the eq. 15 error
//! (`Simulation::analytic_error`, `distributed::sum_over_points`). Each process writes its
//! own points (`particles_NNNN_pK.vtu`). Checkpoints gather every process's points to process
//! 0, which writes the serial format (`super::checkpoint`). Modules that keep points' entities
//! or read other points are refused ([`refusal`]).

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use super::{AssemblyShare, point_slices, share_failure, sum_grid_vectors};
use crate::components::PointId;
use crate::distributed::migration::{PointRecord, pack_points, plan_departures, unpack_points};
use crate::distributed::partition::slab_owners;
use crate::distributed::respawn::{spawn_record, take_record};
use crate::distributed::{exchange, sum_counts};
use crate::effects::fbar::{FbarAveraging, FbarSpec};
use crate::effects::stages::DisplacementOrigin;
use crate::plugin::Extension;
use crate::resources::{GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock};
use crate::scene::SceneSpec;

/// The modules a decomposed run refuses, and why.
const REFUSED: &[(&str, &str)] = &[
    ("finite-element mesh", "its elements refer to their points"),
    (
        "stress recovery",
        "fits over neighbouring points, which may be on another process",
    ),
];

/// Why the scene cannot run with decomposed points, if the points are decomposed and it
/// cannot: the modules it uses that the decomposition refuses (checked by the simulation
/// before any point is spawned).
pub fn refusal(spec: &SceneSpec) -> Option<String> {
    if !crate::distributed::decomposed() {
        return None;
    }
    let modules = crate::effects::built_in();
    let mut refused: Vec<String> = modules
        .iter()
        .filter(|module| module.used_by(spec))
        .filter_map(|module| {
            REFUSED
                .iter()
                .find(|(name, _)| *name == module.name())
                .map(|(name, why)| format!("{name} ({why})"))
        })
        .collect();
    let patch = spec.part::<FbarSpec>().is_some_and(|fbar| {
        fbar.bodies
            .iter()
            .any(|&(_, averaging)| averaging == FbarAveraging::Patch)
    });
    if patch {
        refused.push(
            "F-bar with patch averaging (averages over the neighbouring cells' points, which \
             may be on another process)"
                .to_string(),
        );
    }
    (!refused.is_empty()).then(|| {
        format!(
            "--decompose: the scene uses {} — not supported with decomposed points yet; run \
             it without --decompose (every process then holds every point)",
            refused.join(", ")
        )
    })
}

/// A stage's displacement origins (`effects::stages::DisplacementOrigin`, set at the start of
/// a stage with `zero_displacements`) travel with their points ([`pack_origin`],
/// [`unpack_origin`]). The decomposed run's output does not read them (the `displacement`
/// field is the `Displacement` component, zeroed at the stage's start on every process's own
/// points); probes and checkpoints read them (a checkpoint through the point's record,
/// `super::checkpoint`).
pub fn carry_displacement_origins<const D: usize>(simulation: &mut Extension<'_, D>) {
    simulation.point_state("displacement origins", pack_origin::<D>, unpack_origin::<D>);
}

/// `1 + D` numbers: whether the point has an origin (1 or 0), then the origin (zeros
/// without one).
pub fn pack_origin<const D: usize>(point: EntityRef<'_>, values: &mut Vec<f64>) {
    match point.get::<DisplacementOrigin<D>>() {
        Some(origin) => {
            values.push(1.0);
            values.extend(origin.0.iter());
        }
        None => values.extend(std::iter::repeat_n(0.0, D + 1)),
    }
}

/// Gives the point the origin [`pack_origin`] wrote, if it had one.
pub fn unpack_origin<const D: usize>(
    point: &mut EntityWorldMut<'_>,
    _body: u32,
    values: &[f64],
) -> Result<(), String> {
    let [flag, origin @ ..] = values else {
        return Err("no displacement origin in the record".to_string());
    };
    if origin.len() != D {
        return Err(format!(
            "a displacement origin of {} numbers, not {D}",
            origin.len()
        ));
    }
    if *flag != 0.0 {
        point.insert(DisplacementOrigin(SVector::<f64, D>::from_column_slice(
            origin,
        )));
    }
    Ok(())
}

/// At the start of a run every process has spawned its slab's points only
/// (`distributed::initial_points`, no message): the share counts them.
pub fn count_own_points<const D: usize>(world: &mut World) {
    let held = world.query::<&PointId>().iter(world).len();
    let mut share = world.resource_mut::<AssemblyShare>();
    share.points = held;
    share.moved = 0;
}

/// Step 1 of the module docs: the points go to the processes of their slabs.
pub fn exchange_points<const D: usize>(world: &mut World) {
    let settled = world.resource_scope(|world, mut clock: Mut<StageClock>| {
        let _timer = clock.time(Stage::Connectivity);
        settle::<D>(world)
    });
    if let Err(why) = settled {
        let step = world.resource::<LoadStep>().number;
        world.resource_mut::<RunStatus>().fail(SolverError::Module {
            step,
            what: format!("moving points between the processes: {why}"),
            recoverable: false,
        });
    }
}

/// Owners from the layers' counts summed over the processes, then the departures sent to
/// their owners; the points kept and arrived spawned anew in `PointId` order when anything
/// changed. Sets the share's counts.
fn settle<const D: usize>(world: &mut World) -> Result<(), String> {
    let (rank, size) = {
        let share = world.resource::<AssemblyShare>();
        (share.processes.rank, share.processes.size)
    };
    let (mut points, per_slice) = point_slices::<D>(world);
    let mut counts: Vec<u64> = per_slice.iter().map(|&n| n as u64).collect();
    sum_counts(&mut counts);
    let per_slice: Vec<usize> = counts.iter().map(|&n| n as usize).collect();
    let layer_owners = slab_owners(&per_slice, size);
    points.sort_by_key(|&(entity, _)| world.get::<PointId>(entity).map_or(u32::MAX, |id| id.0));
    let owners: Vec<usize> = points
        .iter()
        .map(|&(_, slice)| layer_owners[slice])
        .collect();
    let plan = plan_departures(&owners, rank);
    // take every departing point out (packing can fail only on a broken world; the decision
    // to go on is shared before any point moves)
    let mut outgoing = vec![Vec::new(); size];
    let mut packed: Result<(), String> = Ok(());
    for (to, list) in &plan.sent {
        let records: Result<Vec<PointRecord<D>>, String> = list
            .iter()
            .map(|&i| take_record::<D>(world, points[i].0))
            .collect();
        match records {
            Ok(records) => outgoing[*to] = pack_points(&records),
            Err(why) => packed = Err(why),
        }
    }
    let departed: usize = plan.sent.iter().map(|(_, list)| list.len()).sum();
    if crate::distributed::any(packed.is_err()) {
        return packed.and(Err("a point could not be packed on another process".into()));
    }
    let mut arrived = Vec::new();
    for message in exchange(&outgoing)? {
        arrived.extend(unpack_points::<D>(&message)?);
    }
    let mut moved = [departed as u64];
    sum_counts(&mut moved);
    let points_held = plan.kept.len() + arrived.len();
    if departed > 0 || !arrived.is_empty() {
        let mut records: Vec<PointRecord<D>> = plan
            .kept
            .iter()
            .map(|&i| take_record::<D>(world, points[i].0))
            .collect::<Result<_, _>>()?;
        for (entity, _) in points {
            world.despawn(entity);
        }
        records.extend(arrived);
        records.sort_by_key(|record| record.id);
        for record in &records {
            spawn_record::<D>(world, record)?;
        }
    }
    let mut share = world.resource_mut::<AssemblyShare>();
    share.points = points_held;
    share.moved = moved[0] as usize;
    Ok(())
}

/// Step 3 of the module docs: `f_ext` summed over the processes, after the loads (collective:
/// it runs after a failure too, and shares it first: a load can fail on one process alone,
/// e.g. a traction point leaving the grid).
pub fn sum_external_force<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    mut share: ResMut<AssemblyShare>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    step: Res<LoadStep>,
    newton: Res<Newton>,
    grid: Res<super::grid::DecomposedGrid>,
) {
    if share_failure(&mut status, step.number, newton.iterations) {
        return;
    }
    let _timer = clock.time(Stage::Loads);
    if let Err(why) = sum_grid_vectors(&mut share, Some(&grid), &mut fields.external_force) {
        status.fail(SolverError::Module {
            step: step.number,
            what: format!("summing the external force over the processes: {why}"),
            recoverable: false,
        });
    }
}
