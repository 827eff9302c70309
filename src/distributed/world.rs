//! The processes of a distributed run (cargo feature `mpi`), through the `mpi` crate.
//!
//! MPI is started only when the process was launched by `mpirun` (OpenMPI sets
//! `OMPI_COMM_WORLD_SIZE` in every process it starts), so a build with the feature still runs
//! `impm run SCENE` as one ordinary process. PETSc, started later on first use, finds MPI
//! running and works on `MPI_COMM_WORLD`. The `mpi` crate gives rank, size and the two small
//! reductions the driver needs (whether any process failed; a sum of one number); the large
//! sums (internal force, tangent) go through PETSc's vectors and matrices.

use std::sync::OnceLock;

use mpi::collective::SystemOperation;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;

/// This process's place in a distributed run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Processes {
    /// This process's rank, `0..size`.
    pub rank: usize,
    /// The number of processes.
    pub size: usize,
}

static PROCESSES: OnceLock<Processes> = OnceLock::new();

/// MPI, running from [`start`] until this is dropped (at the end of `main`: `MPI_Finalize`).
pub struct Started {
    _universe: mpi::environment::Universe,
}

/// Whether this process was launched by `mpirun` (OpenMPI's `OMPI_COMM_WORLD_SIZE`).
pub fn launched_by_mpirun() -> bool {
    std::env::var_os("OMPI_COMM_WORLD_SIZE").is_some()
}

/// Starts MPI (MPI calls from the main thread only: `MPI_THREAD_FUNNELED`) and records this
/// process's rank and the number of processes for [`processes`].
pub fn start() -> Result<Started, String> {
    let (universe, _) = mpi::initialize_with_threading(mpi::Threading::Funneled)
        .ok_or_else(|| "MPI could not be started (MPI_Init_thread)".to_string())?;
    let world = universe.world();
    let processes = Processes {
        rank: world.rank() as usize,
        size: world.size() as usize,
    };
    PROCESSES
        .set(processes)
        .map_err(|_| "MPI was started twice".to_string())?;
    Ok(Started {
        _universe: universe,
    })
}

/// The processes of this run, if it is a distributed one ([`start`] was called).
pub fn processes() -> Option<Processes> {
    PROCESSES.get().copied()
}

/// Whether `flag` holds on any process (collective: every process must call it).
pub fn any(flag: bool) -> bool {
    if processes().is_none() {
        return flag;
    }
    let mine = i32::from(flag);
    let mut all = 0i32;
    SimpleCommunicator::world().all_reduce_into(&mine, &mut all, SystemOperation::max());
    all != 0
}

/// The sum of `value` over the processes (collective). Not bit-identical across processes in
/// general (MPI's reduction order): use it where that does not matter.
pub fn sum(value: f64) -> f64 {
    if processes().is_none() {
        return value;
    }
    let mut all = 0.0f64;
    SimpleCommunicator::world().all_reduce_into(&value, &mut all, SystemOperation::sum());
    all
}

/// Process 0's `path`, on every process (collective). The processes of a distributed run
/// write their pieces of the output into process 0's folder.
pub fn path_of_process_0(path: &std::path::Path) -> std::path::PathBuf {
    use std::os::unix::ffi::{OsStrExt, OsStringExt};
    if processes().is_none() {
        return path.to_path_buf();
    }
    let world = SimpleCommunicator::world();
    let root = world.process_at_rank(0);
    let mut bytes = path.as_os_str().as_bytes().to_vec();
    let mut length = bytes.len() as u64;
    root.broadcast_into(&mut length);
    bytes.resize(length as usize, 0);
    root.broadcast_into(&mut bytes[..]);
    std::ffi::OsString::from_vec(bytes).into()
}
