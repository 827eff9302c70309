//! `impm run` under `mpirun` (cargo feature `mpi`): starts MPI, keeps every process but the
//! first from writing files or printing (`impm::distributed`), and makes sure that a process
//! that cannot go on ends the whole job instead of leaving the others waiting.
//!
//! The state is replicated on every process (the first step of issue 14), so the processes
//! would all write the same files: process 0 writes them into the run's folder; every other
//! process runs into a scratch folder of its own under the system's temporary folder, removed
//! when the run ends, with its standard output and error sent to `/dev/null`.
//!
//! **Nothing hangs.** Inside a load step every failure is shared where the processes meet
//! (`effects::distributed`: every Newton iteration, after the point update, around the output)
//! and so is what a process does alone between steps (process 0 writing `summary.json`,
//! `history.csv`, a checkpoint: `effects::distributed::share_outcome`): the processes fail
//! and cut the step alike, and end their runs together after the same step, process 0 naming
//! the process that failed. A stop (a signal, a deadline) is agreed between steps
//! ([`agree_on_stop`]): if any process is asked to stop, all stop after the same step. What
//! is left, a failure before the run's first agreement (process 0 cannot lock or clear its
//! output folder) or a process killed from outside, would leave the others waiting in their
//! next collective call. So at its end every process meets the others
//! ([`DistributedRun::end`], a barrier on a communicator of its own): a process whose run
//! failed waits at most [`FAILED_PROCESS_WAIT`] for them, and if they do not come it says
//! which process failed and why on the console's standard error and ends the job with
//! `MPI_Abort` (exit status 1); files already written stay as they are. A panic on any process
//! ends the job at once (exit status 101), from the main thread also when a worker of the
//! thread pool panicked ([`DistributedRun::abort_on_panic`]). When the processes end together,
//! process 0 reports a failure they share; a process other than 0 whose run failed alone says
//! so itself.

use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

use impm::distributed::{Ending, Processes, Started, abort, launched_by_mpirun, start};
use impm::interrupt::StopReason;

use super::console::{Failure, note};

/// How long a process whose run failed waits for the others at the end before it ends the job
/// (`MPI_Abort`): in a failure the processes share, they all come within the time process 0
/// takes to record it in `summary.json`.
pub const FAILED_PROCESS_WAIT: Duration = Duration::from_secs(20);

/// The console's standard error, kept by a process other than 0 before its own is silenced:
/// for the message that ends the job.
static CONSOLE: OnceLock<File> = OnceLock::new();

/// MPI, started for a run under `mpirun`, and the scratch folder of a process other than 0.
pub struct DistributedRun {
    processes: Processes,
    scratch: Option<PathBuf>,
    // dropped last: MPI_Finalize
    mpi: Started,
}

impl Drop for DistributedRun {
    fn drop(&mut self) {
        self.remove_scratch();
    }
}

impl DistributedRun {
    /// Starts MPI when this process was launched by `mpirun` (otherwise `None`: an ordinary
    /// run). A process other than 0 is silenced. Checkpoints and `--resume` work over any
    /// number of processes, with or without `--decompose`: process 0 writes one checkpoint in
    /// the serial format (with decomposed points, every process's points gathered to it:
    /// `effects::distributed::checkpoint`), and every process of a resumed run reads it from
    /// process 0's folder.
    pub fn start_if_launched() -> Result<Option<Self>, Failure> {
        if launched_by_mpirun().is_none() {
            return Ok(None);
        }
        let mpi = start().map_err(Failure::Message)?;
        let Some(processes) = impm::distributed::processes() else {
            return Err(Failure::Message(
                "MPI started without processes".to_string(),
            ));
        };
        let scratch = (processes.rank > 0).then(|| {
            remove_stale_scratch();
            std::env::temp_dir().join(format!(
                "{SCRATCH_PREFIX}{}-{}",
                processes.rank,
                std::process::id()
            ))
        });
        if scratch.is_some() {
            silence();
        }
        if processes.size > 1 {
            abort_on_panic(processes);
            impm::interrupt::set_agreement(agree_on_stop).map_err(Failure::Message)?;
        }
        Ok(Some(Self {
            processes,
            scratch,
            mpi,
        }))
    }

    /// Runs `job` on the main thread; a panic in it (on this thread or on a worker of the
    /// thread pool, which carries it here) ends the whole job with `MPI_Abort` (exit status
    /// 101) once the panic hook has said why: the other processes would wait for this one in
    /// their next collective call. One process runs `job` as it is.
    pub fn abort_on_panic<R>(&self, job: impl FnOnce() -> R) -> R {
        if self.processes.size == 1 {
            return job();
        }
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(job)) {
            Ok(result) => result,
            Err(_) => {
                self.remove_scratch();
                abort(101)
            }
        }
    }

    /// The scratch folder a process other than 0 writes into instead of the run's folder
    /// (`None` for process 0).
    pub fn scratch_folder(&self) -> Option<PathBuf> {
        self.scratch.clone()
    }

    /// Ends this process's run in agreement with the others (see the module docs): returns
    /// `result` when every process reached its end; otherwise says why on the console and
    /// ends the whole job (`MPI_Abort`, exit status 1). A process other than 0 whose run
    /// failed where process 0's did not says why itself (its own output is silenced).
    pub fn end(self, result: Result<(), Failure>) -> Result<(), Failure> {
        let Processes { rank, size } = self.processes;
        if size == 1 {
            return result;
        }
        let failed = result.is_err();
        let wait = failed.then_some(FAILED_PROCESS_WAIT);
        match self.mpi.all_ended(failed, wait) {
            Ending::Together { process_0_failed } => {
                // said before any process exits: mpirun ends the job when the first one exits
                // with a failure, which could cut process 0's message
                let result = match result {
                    Err(Failure::Message(why)) if rank == 0 => {
                        note(&format!("error: {why}"));
                        Err(Failure::Quiet)
                    }
                    Err(Failure::Message(why)) if !process_0_failed => {
                        to_console(&format!("error (process {rank} of {size}): {why}"));
                        Err(Failure::Quiet)
                    }
                    other => other,
                };
                self.mpi.all_said();
                result
            }
            Ending::NotTogether => {
                let why = match &result {
                    Err(Failure::Message(why)) => why.as_str(),
                    _ => "its standard output was closed",
                };
                to_console(&format!(
                    "error (process {rank} of {size}): {why}\nthe other processes did not end \
                     their runs within {} s (they wait for this one in the run's next \
                     collective step): ending the whole job (MPI_Abort); the files written so \
                     far are kept",
                    FAILED_PROCESS_WAIT.as_secs()
                ));
                self.remove_scratch();
                abort(1)
            }
        }
    }

    fn remove_scratch(&self) {
        if let Some(scratch) = &self.scratch {
            let _ = std::fs::remove_dir_all(scratch);
        }
    }
}

/// The start of a scratch folder's name: `impm-processRANK-PID`.
const SCRATCH_PREFIX: &str = "impm-process";

/// Removes the scratch folders of earlier runs whose process no longer exists: a job ended by
/// `MPI_Abort` kills its processes before they can remove their own.
fn remove_stale_scratch() {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let pid = name
            .to_str()
            .and_then(|name| name.strip_prefix(SCRATCH_PREFIX))
            .and_then(|rest| rest.rsplit_once('-'))
            .and_then(|(_, pid)| pid.parse::<u32>().ok());
        if let Some(pid) = pid
            && !std::path::Path::new("/proc").join(pid.to_string()).exists()
        {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// Writes a line on the console's standard error (process 0's own, or the one a silenced
/// process kept), ignoring a failure.
fn to_console(line: &str) {
    match CONSOLE.get() {
        Some(mut console) => {
            // one write, so lines of several threads do not interleave
            let _ = console.write_all(format!("{line}\n").as_bytes());
        }
        None => note(line),
    }
}

/// The processes stop together: each learns, between load steps, whether any of them got a
/// signal or passed its deadline (`mpirun` forwards a signal to every process, but they may be
/// at different points of a step when it arrives).
fn agree_on_stop(mine: Option<StopReason>) -> Option<StopReason> {
    StopReason::from_precedence(impm::distributed::largest(StopReason::precedence(mine)))
}

/// A panic on any process ends the job: the others would wait for it forever. The hook runs
/// on the thread that panicked, which may be a worker of the thread pool; MPI was started for
/// the main thread only (`Threading::Funneled`), so the hook only says what happened, and
/// [`DistributedRun::abort_on_panic`] ends the job from the main thread, where the thread pool
/// carries a worker's panic.
fn abort_on_panic(processes: Processes) {
    static SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    std::panic::set_hook(Box::new(move |info| {
        // the first panic is the cause: other workers of the same loop may panic after it
        if SAID.swap(true, std::sync::atomic::Ordering::SeqCst) {
            return;
        }
        to_console(&format!(
            "error (process {} of {}): {info}\nending the whole job (MPI_Abort)",
            processes.rank, processes.size
        ));
    }));
}

/// Sends this process's standard output and error to `/dev/null` (`dup2`: std has no safe
/// way to replace the process's own descriptors; libc is linked anyway), keeping the
/// console's standard error ([`CONSOLE`]) for a message that ends the job.
fn silence() {
    use std::os::fd::{AsRawFd, FromRawFd};
    unsafe extern "C" {
        fn dup(old: std::ffi::c_int) -> std::ffi::c_int;
        fn dup2(old: std::ffi::c_int, new: std::ffi::c_int) -> std::ffi::c_int;
    }
    // SAFETY: 2 is open (or dup fails with -1); a new descriptor belongs to the File alone
    let kept = unsafe { dup(2) };
    if kept >= 0 {
        let _ = CONSOLE.set(unsafe { File::from_raw_fd(kept) });
    }
    if let Ok(null) = std::fs::OpenOptions::new().write(true).open("/dev/null") {
        // SAFETY: both descriptors are open; dup2 replaces 1 and 2 atomically.
        unsafe {
            dup2(null.as_raw_fd(), 1);
            dup2(null.as_raw_fd(), 2);
        }
    }
}
