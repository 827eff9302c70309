//! The processes of a distributed run (cargo feature `mpi`), through the `mpi` crate.
//!
//! MPI is started only when the process was launched by `mpirun` (OpenMPI sets
//! `OMPI_COMM_WORLD_SIZE` in every process it starts), so a build with the feature still runs
//! `impm run SCENE` as one ordinary process. PETSc, started later on first use, finds MPI
//! running and works on `MPI_COMM_WORLD`. The `mpi` crate gives rank, size and the two small
//! reductions the driver needs (whether any process failed or is asked to stop; a sum of one
//! number); the large
//! sums (internal force, tangent) go through PETSc's vectors and matrices.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use mpi::collective::SystemOperation;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;

use super::Processes;

static PROCESSES: OnceLock<Processes> = OnceLock::new();

/// MPI, running from [`start`] until this is dropped (at the end of `main`: `MPI_Finalize`).
pub struct Started {
    /// A communicator of its own for [`Started::all_ended`], so that the agreement at the end
    /// can never be taken for one of the run's collective calls by a process still inside the
    /// run.
    ending: SimpleCommunicator,
    // dropped last: MPI_Finalize
    _universe: mpi::environment::Universe,
}

/// How every process ended its run, as [`Started::all_ended`] finds it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ending {
    /// Every process reached the end of its run; whether process 0's run failed.
    Together { process_0_failed: bool },
    /// Some process did not reach the end within the wait: it is waiting in a collective call
    /// this process will never make (this process failed outside the collective decisions).
    NotTogether,
}

impl Started {
    /// Waits until every process has reached the end of its run (collective, on a
    /// communicator of its own: `MPI_Ibarrier`, polled), at most `wait` (`None`: as long as
    /// it takes), then shares whether process 0's run `failed`. A process that failed where
    /// the others did not (e.g. process 0 could not write its output) waits a bounded time:
    /// the others are then blocked in the run's next collective call and never come, and it
    /// must end the job ([`abort`]); a process that completed its run waits as long as it
    /// takes (the others either come or one of them aborts the job).
    pub fn all_ended(&self, failed: bool, wait: Option<Duration>) -> Ending {
        let started = Instant::now();
        let mut request = self.ending.immediate_barrier();
        loop {
            match request.test() {
                Ok(_) => break,
                Err(pending) => {
                    if wait.is_some_and(|wait| started.elapsed() > wait) {
                        // never completed: the job is about to be aborted (dropping an
                        // incomplete request panics in the `mpi` crate)
                        std::mem::forget(pending);
                        return Ending::NotTogether;
                    }
                    request = pending;
                    std::thread::sleep(Duration::from_millis(5));
                }
            }
        }
        let mut process_0_failed = i32::from(failed);
        self.ending
            .process_at_rank(0)
            .broadcast_into(&mut process_0_failed);
        Ending::Together {
            process_0_failed: process_0_failed != 0,
        }
    }
}

/// Ends every process of the job (`MPI_Abort` on `MPI_COMM_WORLD`, exit status `code`): for a
/// process that cannot go on while the others wait for it in a collective call. Say why on
/// standard error first.
pub fn abort(code: i32) -> ! {
    SimpleCommunicator::world().abort(code)
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
        ending: world.duplicate(),
        _universe: universe,
    })
}

/// The processes of this run, if it is a distributed one ([`start`] was called).
pub fn processes() -> Option<Processes> {
    PROCESSES.get().copied()
}

/// Whether `flag` holds on any process (collective: every process must call it).
pub fn any(flag: bool) -> bool {
    largest(i32::from(flag)) != 0
}

/// The largest of `value` over the processes (collective: every process must call it).
pub fn largest(value: i32) -> i32 {
    if processes().is_none() {
        return value;
    }
    let mut all = 0i32;
    SimpleCommunicator::world().all_reduce_into(&value, &mut all, SystemOperation::max());
    all
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
