//! Distributed runs: the processes of `mpirun -n N impm run SCENE` (cargo feature `mpi`).
//!
//! What exists (the first, replicated step of issue 14; `docs/distributed.md`): every process
//! holds the whole state (all points and the whole grid) and runs every stage on it, except
//! that it **assembles** only the points of its own slab of background cells
//! ([`partition`]); the processes' sums of the tangent go into one PETSc `MPIAIJ` matrix and
//! their sums of the internal force into one PETSc vector (off-process entries through
//! PETSc's own communication), KSP solves the distributed system, and the correction is
//! gathered to every process, which then updates every point identically. Only process 0
//! writes files and prints; the others run into a scratch folder of their own, removed at the
//! end, with their output silenced. The module that does this is `effects::distributed`; the
//! PETSc side is `solver::PetscSolver::distributed` and `solver::ProcessSum`.
//!
//! With `impm run --decompose` the **points are decomposed** instead: every process holds only
//! the points of its slab, and points move to the process of their slab at each step start
//! (`effects::distributed::decomposition`), and each process numbers and assembles only the
//! grid nodes its points touch (`effects::distributed::grid`, [`ownership`]).
//!
//! Built in every configuration: the pure kernels [`partition`] (the slabs), [`failure`] (a
//! failure on some processes made every process's: what travels, which one decides),
//! [`ownership`]
//! (the decomposed grid: each node's owner and the global DOF numbers, from messages to the
//! neighbouring processes only) and [`migration`]
//! (a point's whole state as numbers, who sends which points where), [`respawn`] (a point
//! taken out of a world as a record and spawned back from it, with every module's part),
//! [`launched_by_mpirun`], which reads the environment so that any build can refuse what it
//! cannot run under `mpirun`, and [`decomposed`] / [`sum_over_points`] /
//! [`gather_over_points`] / [`numbers_of_points`] for the sums over points outside the module
//! (the eq. 15 error, F-bar's sparse cells, probes, the prescribed-motion check). The process bookkeeping (`start`,
//! `processes`, `any`, `abort`) and the messages (`exchange`, `gather_all`, `sum_all`) exist
//! with the feature `mpi` only.

pub mod failure;
pub mod migration;
pub mod ownership;
pub mod partition;
pub mod respawn;
pub mod traffic;

#[cfg(feature = "mpi")]
mod world;
#[cfg(feature = "mpi")]
pub use world::{
    Ending, Started, abort, any, exchange, exchange_counted, gather_all, gather_all_counted,
    largest, path_of_process_0, processes, share_failures, start, sum, sum_all, sum_counts,
};

/// This process's place in a distributed run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Processes {
    /// This process's rank, `0..size`.
    pub rank: usize,
    /// The number of processes.
    pub size: usize,
}

/// This process's place among the processes `mpirun` started, read from the environment
/// without starting MPI (OpenMPI sets `OMPI_COMM_WORLD_RANK` and `OMPI_COMM_WORLD_SIZE` in
/// every process it starts); `None` when `mpirun` did not start this process.
pub fn launched_by_mpirun() -> Option<Processes> {
    let read = |name: &str| std::env::var(name).ok()?.trim().parse::<usize>().ok();
    let size = read("OMPI_COMM_WORLD_SIZE")?;
    Some(Processes {
        rank: read("OMPI_COMM_WORLD_RANK").unwrap_or(0),
        size: size.max(1),
    })
}

/// The cell layer along `axis` that `x` lies in: what decides a point's process
/// (`partition`). A point outside the grid counts in the nearest layer along `axis` (a
/// non-finite coordinate in layer 0), so it stays with the process that holds its side of the
/// grid, whose basis stage then fails it (the failure is shared with the others:
/// `effects::distributed`).
pub fn layer_of<const D: usize>(
    grid: &crate::basis::GridBasis<D>,
    axis: usize,
    x: &nalgebra::SVector<f64, D>,
) -> usize {
    let along = &grid.axes[axis];
    let last = along.cells.saturating_sub(1);
    match along.cell_of(x[axis]) {
        Ok(layer) => layer.min(last),
        Err(_) if x[axis] > along.lower => last,
        Err(_) => 0,
    }
}

/// In a decomposed run, whether this process spawns each point of the scene at the start
/// (indexed by `PointId`: the points of its slab, from the seeds' positions); `None`
/// otherwise (every point is spawned).
pub fn initial_points<const D: usize>(
    grid: &crate::basis::GridBasis<D>,
    spec: &crate::scene::SceneSpec,
) -> Option<Vec<bool>> {
    if !decomposed() {
        return None;
    }
    if FROM_PIECES.load(std::sync::atomic::Ordering::Relaxed) {
        let seeds = spec.bodies.iter().map(|body| body.points.len()).sum();
        return Some(vec![false; seeds]);
    }
    if RESUMING.load(std::sync::atomic::Ordering::Relaxed) {
        return None;
    }
    #[cfg(feature = "mpi")]
    let processes = processes()?;
    #[cfg(not(feature = "mpi"))]
    let processes = Processes { rank: 0, size: 1 };
    let axis = partition::slab_axis(&grid.cells_per_axis());
    let layers: Vec<usize> = spec
        .bodies
        .iter()
        .flat_map(|body| &body.points)
        .map(|seed| {
            let x = nalgebra::SVector::<f64, D>::from_fn(|a, _| {
                seed.position.get(a).copied().unwrap_or(f64::NAN)
            });
            layer_of(grid, axis, &x)
        })
        .collect();
    let owners = partition::owners_of_layers(&layers, grid.cells_per_axis()[axis], processes.size);
    Some(
        owners
            .iter()
            .map(|&owner| owner == processes.rank)
            .collect(),
    )
}

static DECOMPOSITION: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

static RESUMING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

static FROM_PIECES: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Says that the run resumes a checkpoint in pieces (written by a decomposed run over several
/// processes, `restart::Pieces`): a decomposed run then spawns no point at the start
/// ([`initial_points`] is all `false`), and each process spawns its slab's points from the
/// pieces (`effects::distributed::checkpoint::keep_own_points`). Call it before the simulation
/// is built.
pub fn request_resume_from_pieces() {
    request_resume();
    FROM_PIECES.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// Says that the run resumes a checkpoint (`impm run --resume`): a decomposed run then spawns
/// every point at the start ([`initial_points`] is `None`), the checkpoint restores them as in
/// a serial run, and each process keeps its slab's points
/// (`effects::distributed::checkpoint::keep_own_points`). Call it before the simulation is
/// built.
pub fn request_resume() {
    RESUMING.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// The measures a distributed run adds to every step's record (summary.json, history.csv):
/// what it sends by kind (`traffic`), the points process 0 assembled and the points that
/// changed process, and with decomposed points the decomposed grid's counts, the load
/// points (tractions, loads at positions) that changed process and the surface conditions'
/// boundary points whose host changed process, and the largest per-node storage of a process
/// in the step (`node_storage_bytes`: the core's grid fields, `node_storage`). A run resumed
/// from another run's checkpoint (serial, replicated or decomposed, over any number of
/// processes) takes the records of its steps with these measures as they are.
pub const RUN_MEASURES: [&str; 8] = [
    "assembled_points",
    "points_changing_process",
    "owned_dofs",
    "ghost_nodes",
    "local_dofs",
    "load_points_changing_process",
    "boundary_hosts_changing_process",
    "node_storage_bytes",
];

/// [`RUN_MEASURES`] and the traffic counters' names: every measure a distributed run may add.
pub fn run_measures() -> impl Iterator<Item = &'static str> {
    RUN_MEASURES.into_iter().chain(
        traffic::Traffic::ALL
            .into_iter()
            .map(traffic::Traffic::name),
    )
}

/// Asks for decomposed points (`impm run --decompose` under `mpirun`): every process then holds
/// only the points of its slab, and they move between the processes as the slabs change
/// (`effects::distributed`, `docs/distributed.md`). Call it before the simulation is built.
pub fn request_decomposition() {
    DECOMPOSITION.store(true, std::sync::atomic::Ordering::Relaxed);
}

/// Whether this process is one of a distributed run whose points are decomposed: every
/// process holds its own points only, so a sum over points is a sum over the processes of
/// their partial sums ([`sum_over_points`]).
pub fn decomposed() -> bool {
    #[cfg(feature = "mpi")]
    let distributed = processes().is_some();
    #[cfg(not(feature = "mpi"))]
    let distributed = false;
    distributed && DECOMPOSITION.load(std::sync::atomic::Ordering::Relaxed)
}

/// Turns this process's sums over its points into sums over all points, in place, when the
/// points are decomposed (collective then: every process must call it with as many values);
/// otherwise (a serial run, or every process holding every point) leaves them as they are.
pub fn sum_over_points(values: &mut [f64]) {
    #[cfg(feature = "mpi")]
    if decomposed() {
        sum_all(values);
    }
    #[cfg(not(feature = "mpi"))]
    let _ = values;
}

/// `width` numbers of each of `count` points wherever they are held (a probe's neighbours, the
/// points nearest a prescribed node): `fill(k, numbers)` writes point `k`'s numbers (zeros
/// given) and says whether this process holds it. With decomposed points the processes'
/// numbers are summed (collective then: every process calls it with the same `count` and
/// `width`); each point is held by one process and the others add zeros, so every process
/// gets the holder's numbers exactly, as the serial run reads them. Otherwise (a serial run,
/// or every process holding every point) this process's own. `None` for a point no process
/// holds (or, on a broken decomposition, several).
pub fn numbers_of_points(
    count: usize,
    width: usize,
    mut fill: impl FnMut(usize, &mut [f64]) -> bool,
) -> Vec<Option<Vec<f64>>> {
    let stride = width + 1;
    let mut all = vec![0.0; count * stride];
    for (k, slot) in all.chunks_mut(stride).enumerate() {
        let (held, numbers) = slot.split_at_mut(1);
        if fill(k, numbers) {
            held[0] = 1.0;
        } else {
            numbers.fill(0.0);
        }
    }
    sum_over_points(&mut all);
    all.chunks(stride)
        .map(|slot| (slot[0] == 1.0).then(|| slot[1..].to_vec()))
        .collect()
}

/// Every process's `local` numbers, one after another in rank order, when the points are
/// decomposed (collective then: an all-gather, counted as reductions); otherwise (a serial
/// run, or every process holding every point) `local` as it is. For records that need a few
/// numbers of every process's points, such as F-bar's sparse cells (`effects::fbar`).
pub fn gather_over_points(local: &[u64]) -> Result<Vec<u64>, String> {
    #[cfg(feature = "mpi")]
    if decomposed() {
        return gather_all_counted(local, traffic::Traffic::Reductions).map(|all| all.concat());
    }
    Ok(local.to_vec())
}

/// Whether this process is a serial run's or process 0 of a distributed run.
fn serial_or_process_0() -> bool {
    #[cfg(feature = "mpi")]
    if let Some(processes) = processes() {
        return processes.rank == 0;
    }
    true
}

/// Whether this process writes the run's own files (summary, series, checkpoints): a serial
/// run, and process 0 of a distributed one (the others run into scratch folders of their own).
pub fn writes_run_files() -> bool {
    serial_or_process_0()
}

/// Whether this process adds the terms that belong to the grid rather than to a point it
/// assembles (the ghost penalty's faces on the replicated path; with decomposed points a face
/// is added by the process holding its lower cell instead, `effects::ghost_penalty`): every
/// serial run, and process 0 alone in a distributed run. The processes' shares of `f_int` and
/// `K` are summed (`Hook::Combine`, PETSc's matrix), so a term every process added would count
/// once per process. Terms that
/// belong to a point (F-bar's rank-one terms of a group's members, a surface condition's
/// boundary point through its host) are added by the process that assembles that point
/// instead: `components::AssembledElsewhere` leaves them out elsewhere.
pub fn adds_grid_terms() -> bool {
    serial_or_process_0()
}
