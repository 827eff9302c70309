//! `impm run` under `mpirun` (cargo feature `mpi`): starts MPI, and keeps every process but
//! the first from writing files or printing (`impm::distributed`).
//!
//! The state is replicated on every process (the first step of issue 14), so the processes
//! would all write the same files: process 0 writes them into the run's folder; every other
//! process runs into a scratch folder of its own under the system's temporary folder, removed
//! when the run ends, with its standard output and error sent to `/dev/null`.

use std::path::PathBuf;

use impm::distributed::{Started, launched_by_mpirun, processes, start};

use super::console::Failure;

/// MPI, started for a run under `mpirun`, and the scratch folder of a process other than 0.
pub struct DistributedRun {
    _mpi: Started,
    scratch: Option<PathBuf>,
}

impl Drop for DistributedRun {
    fn drop(&mut self) {
        if let Some(scratch) = &self.scratch {
            let _ = std::fs::remove_dir_all(scratch);
        }
    }
}

impl DistributedRun {
    /// Starts MPI when this process was launched by `mpirun` (otherwise `None`: an ordinary
    /// run). A process other than 0 is silenced. `--resume` is refused with more than one
    /// process (the other processes' checkpoints are not kept).
    pub fn start_if_launched(resume: bool) -> Result<Option<Self>, Failure> {
        if !launched_by_mpirun() {
            return Ok(None);
        }
        let mpi = start().map_err(Failure::Message)?;
        let Some(processes) = processes() else {
            return Err(Failure::Message(
                "MPI started without processes".to_string(),
            ));
        };
        if resume && processes.size > 1 {
            return Err(Failure::Message(
                "--resume under mpirun with more than one process is not supported yet (only \
                 process 0 keeps checkpoints): resume with mpirun -n 1 or without mpirun"
                    .to_string(),
            ));
        }
        let scratch = (processes.rank > 0).then(|| {
            std::env::temp_dir().join(format!(
                "impm-process{}-{}",
                processes.rank,
                std::process::id()
            ))
        });
        if scratch.is_some() {
            silence();
        }
        Ok(Some(Self { _mpi: mpi, scratch }))
    }

    /// The folder this process writes into: `out` for process 0, its scratch folder for the
    /// others.
    pub fn output_folder(&self, out: Option<PathBuf>) -> Option<PathBuf> {
        match &self.scratch {
            Some(scratch) => Some(scratch.clone()),
            None => out,
        }
    }
}

/// Sends this process's standard output and error to `/dev/null` (`dup2`: std has no safe
/// way to replace the process's own descriptors; libc is linked anyway).
fn silence() {
    use std::os::fd::AsRawFd;
    unsafe extern "C" {
        fn dup2(old: std::ffi::c_int, new: std::ffi::c_int) -> std::ffi::c_int;
    }
    if let Ok(null) = std::fs::OpenOptions::new().write(true).open("/dev/null") {
        // SAFETY: both descriptors are open; dup2 replaces 1 and 2 atomically.
        unsafe {
            dup2(null.as_raw_fd(), 1);
            dup2(null.as_raw_fd(), 2);
        }
    }
}
