//! Stopping a run cleanly: the first SIGINT or SIGTERM asks the driver to stop after the load
//! step in flight (its files and `summary.json` are written, the status is `"interrupted"`); a
//! second one ends the process at once (exit status 130). A per-run deadline (`impm study
//! --timeout`) stops a run the same way with the status `"timed out"`.
//!
//! The signal handlers only set a flag (`signal-hook`, the ecosystem's crate for this); the
//! driver (`run.rs`) and the study loop poll [`stop_reason`] between load steps and runs.

use std::sync::Arc;
use std::sync::Mutex;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Why a run is asked to stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// SIGINT or SIGTERM.
    Interrupted,
    /// The run's deadline passed ([`set_deadline`]).
    TimedOut,
}

impl StopReason {
    /// The run status written to `summary.json` and `study.csv`.
    pub fn status(self) -> &'static str {
        match self {
            StopReason::Interrupted => "interrupted",
            StopReason::TimedOut => "timed out",
        }
    }
}

fn flag() -> &'static Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    FLAG.get_or_init(|| Arc::new(AtomicBool::new(false)))
}

fn deadline() -> &'static Mutex<Option<Instant>> {
    static DEADLINE: Mutex<Option<Instant>> = Mutex::new(None);
    &DEADLINE
}

/// Installs the SIGINT/SIGTERM handlers (the command line does this once; a library user who
/// does not call it keeps the default behaviour of the signals).
pub fn install() -> Result<(), String> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    for signal in [SIGINT, SIGTERM] {
        // the shutdown must be registered first: it acts only once the flag is already set
        signal_hook::flag::register_conditional_shutdown(signal, 130, flag().clone())
            .and_then(|_| signal_hook::flag::register(signal, flag().clone()))
            .map_err(|e| format!("cannot install the handler of signal {signal}: {e}"))?;
    }
    Ok(())
}

/// Asks the run to stop as a first signal would (for tests and embedding programs).
pub fn request_stop() {
    flag().store(true, Ordering::SeqCst);
}

/// Sets (or clears) the deadline of the current run.
pub fn set_deadline(at: Option<Instant>) {
    *deadline()
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = at;
}

/// Whether the run should stop now, and why (a signal wins over the deadline).
pub fn stop_reason() -> Option<StopReason> {
    if flag().load(Ordering::SeqCst) {
        return Some(StopReason::Interrupted);
    }
    let at = *deadline()
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    at.filter(|&at| Instant::now() >= at)
        .map(|_| StopReason::TimedOut)
}
