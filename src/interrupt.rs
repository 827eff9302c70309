//! Stopping a run cleanly: the first SIGINT or SIGTERM asks the driver to stop after the load
//! step in flight (its files and `summary.json` are written, the status is `"interrupted"`); a
//! second one ends the process at once (exit status 130). A per-run deadline (`impm study
//! --timeout`) stops a run the same way with the status `"timed out"`.
//!
//! The signal handlers only set a flag (`signal-hook`, the ecosystem's crate for this); the
//! driver (`run.rs`) polls [`agreed_stop_reason`] between load steps, the study loop
//! [`stop_reason`] between runs. In a distributed run (`mpirun`) a signal or a deadline may
//! reach the processes at different steps; the command line then sets an agreement
//! ([`set_agreement`]) through which every process learns, at the same point between steps,
//! whether any of them is asked to stop, so that they stop together.
//!
//! `impm run --stop-after N` stops the run the same way ("interrupted") once N load steps are
//! done ([`stop_after_steps`], [`step_limit_reached`]): a stop at a step known in advance, the
//! same on every process of a distributed run (they count the same steps), so it needs no
//! agreement. It splits a long run into jobs of N steps (each resumed with `--resume`), and
//! lets tests interrupt a run at an exact step whatever the machine's load.

use std::sync::Arc;
use std::sync::Mutex;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
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

    /// The reason a run status names (the inverse of [`StopReason::status`]).
    pub fn from_status(status: &str) -> Option<Self> {
        [StopReason::Interrupted, StopReason::TimedOut]
            .into_iter()
            .find(|reason| reason.status() == status)
    }

    /// A number per reason, larger for the one that wins when several processes see different
    /// reasons (a signal over a deadline, as in [`stop_reason`]); 0 is no stop.
    pub fn precedence(reason: Option<Self>) -> i32 {
        match reason {
            None => 0,
            Some(StopReason::TimedOut) => 1,
            Some(StopReason::Interrupted) => 2,
        }
    }

    /// The reason of a [`StopReason::precedence`].
    pub fn from_precedence(precedence: i32) -> Option<Self> {
        match precedence {
            1 => Some(StopReason::TimedOut),
            p if p >= 2 => Some(StopReason::Interrupted),
            _ => None,
        }
    }
}

/// How the processes of a distributed run agree on a stop: given this process's own reason,
/// the reason of the run (collective: every process calls it at the same point).
pub type Agreement = fn(Option<StopReason>) -> Option<StopReason>;

fn agreement() -> &'static OnceLock<Agreement> {
    static AGREEMENT: OnceLock<Agreement> = OnceLock::new();
    &AGREEMENT
}

/// Makes [`agreed_stop_reason`] go through `agree` (once per process: the command line sets it
/// for a run under `mpirun` with more than one process).
pub fn set_agreement(agree: Agreement) -> Result<(), String> {
    agreement()
        .set(agree)
        .map_err(|_| "the processes' agreement on stopping was set twice".to_string())
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

/// No step limit ([`stop_after_steps`]).
const NO_STEP_LIMIT: usize = usize::MAX;

static STEP_LIMIT: AtomicUsize = AtomicUsize::new(NO_STEP_LIMIT);

/// Stops the run once `steps` load steps are done, counted from the run's start (a resumed
/// run's steps before its checkpoint included), as an interrupt would (`None`: no limit).
pub fn stop_after_steps(steps: Option<usize>) {
    STEP_LIMIT.store(steps.unwrap_or(NO_STEP_LIMIT), Ordering::SeqCst);
}

/// Whether the run, `steps_done` load steps in, has reached its step limit
/// ([`stop_after_steps`]).
pub fn step_limit_reached(steps_done: usize) -> bool {
    let limit = STEP_LIMIT.load(Ordering::SeqCst);
    limit != NO_STEP_LIMIT && steps_done >= limit
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

/// Whether the run should stop now, as all its processes decide together: [`stop_reason`]
/// alone in an ordinary run; in a distributed one, the reason any process has (collective,
/// see [`set_agreement`]).
pub fn agreed_stop_reason() -> Option<StopReason> {
    let mine = stop_reason();
    match agreement().get() {
        Some(agree) => agree(mine),
        None => mine,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reason_is_read_back_from_its_status_and_a_signal_wins_the_agreement() {
        for reason in [StopReason::Interrupted, StopReason::TimedOut] {
            assert_eq!(StopReason::from_status(reason.status()), Some(reason));
            let precedence = StopReason::precedence(Some(reason));
            assert_eq!(StopReason::from_precedence(precedence), Some(reason));
        }
        assert_eq!(StopReason::from_status("completed"), None);
        assert_eq!(
            StopReason::from_precedence(StopReason::precedence(None)),
            None
        );
        // the agreement takes the largest precedence over the processes
        let largest = [
            None,
            Some(StopReason::TimedOut),
            Some(StopReason::Interrupted),
        ]
        .map(StopReason::precedence)
        .into_iter()
        .max()
        .unwrap();
        assert_eq!(
            StopReason::from_precedence(largest),
            Some(StopReason::Interrupted)
        );
    }
}
