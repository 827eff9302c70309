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
use super::failure::{FailureNote, Severity};
use super::traffic::{Traffic, count};

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

impl Started {
    /// Waits until every process has come here (blocking, on the communicator of
    /// [`Started::all_ended`], after it found the processes together): what a process says
    /// before it comes here is said before any process exits (`mpirun` ends the whole job as
    /// soon as one process exits with a failure).
    pub fn all_said(&self) {
        self.ending.barrier();
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
    count(Traffic::Reductions, 4);
    SimpleCommunicator::world().all_reduce_into(&value, &mut all, SystemOperation::max());
    all
}

/// Every process's failure at this point of the run, by rank, when any process failed
/// (collective: an `MPI_Allreduce` of the severity; then, only when one failed, an all-gather
/// of the failures, `failure::FailureNote::pack`); `None` when none did.
pub fn share_failures(
    mine: Option<&FailureNote>,
) -> Result<Option<Vec<Option<FailureNote>>>, String> {
    let level = Severity::level(mine.map(|f| f.severity));
    if largest(level) == 0 {
        return Ok(None);
    }
    let numbers = mine.map(FailureNote::pack).unwrap_or_default();
    let all = gather_all_counted(&numbers, Traffic::Reductions)?;
    Ok(Some(
        all.iter()
            .map(|numbers| FailureNote::unpack(numbers))
            .collect(),
    ))
}

/// The sum of `value` over the processes (collective). Not bit-identical across processes in
/// general (MPI's reduction order): use it where that does not matter.
pub fn sum(value: f64) -> f64 {
    if processes().is_none() {
        return value;
    }
    let mut all = 0.0f64;
    count(Traffic::Reductions, 8);
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

/// Adds `values` over the processes, entry by entry, in place (collective; every process
/// passes as many). As [`sum`]: not bit-identical to a serial sum.
pub fn sum_all(values: &mut [f64]) {
    if processes().is_none() || values.is_empty() {
        return;
    }
    let local = values.to_vec();
    count(Traffic::Reductions, 8 * values.len() as u64);
    SimpleCommunicator::world().all_reduce_into(&local[..], values, SystemOperation::sum());
}

/// Adds the counts `values` over the processes, entry by entry, in place (collective).
pub fn sum_counts(values: &mut [u64]) {
    if processes().is_none() || values.is_empty() {
        return;
    }
    let local = values.to_vec();
    count(Traffic::Reductions, 8 * values.len() as u64);
    SimpleCommunicator::world().all_reduce_into(&local[..], values, SystemOperation::sum());
}

/// The offsets of messages of `counts` numbers one after another, if they all fit MPI's
/// `int` counts.
fn offsets(counts: &[i64]) -> Option<(Vec<i32>, Vec<i32>)> {
    let mut at = 0i64;
    let mut offsets = Vec::with_capacity(counts.len());
    for &count in counts {
        offsets.push(i32::try_from(at).ok()?);
        at += count;
    }
    i32::try_from(at).ok()?;
    let counts = counts
        .iter()
        .map(|&c| i32::try_from(c).ok())
        .collect::<Option<_>>()?;
    Some((counts, offsets))
}

/// Sends `outgoing[r]` to process `r` (empty for none, also for this process) and returns what
/// every process sent to this one, by source rank (collective: an all-to-all of the counts,
/// then `MPI_Alltoallv` of the numbers). Messages too long for MPI's counts (2^31 numbers in
/// all, sent or received by a process) are an error on every process, before anything is
/// sent.
pub fn exchange(outgoing: &[Vec<f64>]) -> Result<Vec<Vec<f64>>, String> {
    exchange_counted(outgoing, Traffic::Points)
}

/// [`exchange`] of any MPI type, its bytes counted as `kind`.
pub fn exchange_counted<T: Equivalence + Copy + Default>(
    outgoing: &[Vec<T>],
    kind: Traffic,
) -> Result<Vec<Vec<T>>, String> {
    let width = std::mem::size_of::<T>() as u64;
    let Some(processes) = processes() else {
        return Ok(outgoing.to_vec());
    };
    let world = SimpleCommunicator::world();
    let mut lengths: Vec<i64> = outgoing.iter().map(|m| m.len() as i64).collect();
    lengths.resize(processes.size, 0);
    let mut received_lengths = vec![0i64; processes.size];
    count(kind, 8 * processes.size as u64);
    world.all_to_all_into(&lengths[..], &mut received_lengths[..]);
    let send = offsets(&lengths).filter(|_| outgoing.len() == processes.size);
    let receive = offsets(&received_lengths);
    let (Some((send_counts, send_offsets)), Some((receive_counts, receive_offsets))) =
        (send, receive)
    else {
        any(true);
        return Err(format!(
            "the points one process sends or receives in one exchange exceed MPI's 2^31 - 1 \
             numbers (this process: {} sent, {} received)",
            lengths.iter().sum::<i64>(),
            received_lengths.iter().sum::<i64>()
        ));
    };
    if any(false) {
        return Err("another process's messages exceed MPI's 2^31 - 1 numbers".to_string());
    }
    let sent: Vec<T> = outgoing.concat();
    let elsewhere: usize = (outgoing.iter().enumerate())
        .filter(|&(to, _)| to != processes.rank)
        .map(|(_, message)| message.len())
        .sum();
    count(kind, width * elsewhere as u64);
    let total = receive_counts.iter().map(|&c| c as usize).sum();
    let mut received = vec![T::default(); total];
    {
        let send = mpi::datatype::Partition::new(&sent[..], &send_counts[..], &send_offsets[..]);
        let mut receive = mpi::datatype::PartitionMut::new(
            &mut received[..],
            &receive_counts[..],
            &receive_offsets[..],
        );
        world.all_to_all_varcount_into(&send, &mut receive);
    }
    Ok(receive_offsets
        .iter()
        .zip(&receive_counts)
        .map(|(&at, &count)| received[at as usize..(at + count) as usize].to_vec())
        .collect())
}

/// Every process's `local`, by rank (collective: `MPI_Allgather` of the lengths, then
/// `MPI_Allgatherv`).
pub fn gather_all(local: &[u64]) -> Result<Vec<Vec<u64>>, String> {
    gather_all_counted(local, Traffic::Points)
}

/// [`gather_all`], its bytes counted as `kind`.
pub fn gather_all_counted(local: &[u64], kind: Traffic) -> Result<Vec<Vec<u64>>, String> {
    let Some(processes) = processes() else {
        return Ok(vec![local.to_vec()]);
    };
    let world = SimpleCommunicator::world();
    let mut lengths = vec![0i64; processes.size];
    let others = processes.size as u64 - 1;
    count(kind, 8 * others * (1 + local.len() as u64));
    world.all_gather_into(&(local.len() as i64), &mut lengths[..]);
    // the same lengths on every process: the same decision
    let (counts, offsets) = offsets(&lengths).ok_or_else(|| {
        format!(
            "the processes' messages ({} numbers) exceed MPI's 2^31 - 1",
            lengths.iter().sum::<i64>()
        )
    })?;
    let total = counts.iter().map(|&c| c as usize).sum();
    let mut all = vec![0u64; total];
    {
        let mut receive = mpi::datatype::PartitionMut::new(&mut all[..], &counts[..], &offsets[..]);
        world.all_gather_varcount_into(local, &mut receive);
    }
    Ok(offsets
        .iter()
        .zip(&counts)
        .map(|(&at, &count)| all[at as usize..(at + count) as usize].to_vec())
        .collect())
}
