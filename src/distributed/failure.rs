//! A failure on some processes of a distributed run, made every process's (the kernel; the
//! collective call is `distributed::share_failures`, its use `effects::distributed`).
//!
//! **Why.** Every process must make the same collective calls in the same order. A stage that
//! fails on one process only (a point of its own leaves the grid, inverts, its material
//! refuses; a file it cannot write) makes that process skip what follows, while the others go
//! on into their next collective call and wait there forever. So at each synchronisation point
//! of a step every process says whether it failed, and all of them decide alike what to do
//! next: go on, let the line search shorten the Newton step, cut the load step, or stop.
//!
//! **The decision.** Each process's failure has a [`Severity`]; the processes agree on the
//! largest, and the failure that decides is the one of the lowest rank with that severity
//! ([`deciding`]). A process that failed less severely takes the deciding failure on top of
//! its own, a process that did not fail takes the deciding one as it is (said as `process K
//! of N: ...`): so every process stops (or retries) alike, and process 0, which writes
//! `summary.json` and the log, names the failing process and what failed.
//!
//! **On the wire.** A failure is a few numbers: its severity, the point it concerns (if one),
//! and three texts (the stage, the detail, the whole message), each as its length in bytes
//! followed by its bytes packed eight to a `u64` ([`FailureNote::pack`],
//! [`FailureNote::unpack`]).

/// How far a failure lets the run go on, in increasing order: the processes follow the largest.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// An inadmissible trial state (a point's deformation, a non-finite value): the line
    /// search may shorten the Newton step, else the load step is cut.
    TrialState = 1,
    /// Cutting the load step may succeed.
    Recoverable = 2,
    /// The run stops.
    Fatal = 3,
}

impl Severity {
    /// The severity of a level received from [`Severity::level`] (`None`: no failure).
    pub fn from_level(level: i32) -> Option<Self> {
        match level {
            1 => Some(Severity::TrialState),
            2 => Some(Severity::Recoverable),
            l if l >= 3 => Some(Severity::Fatal),
            _ => None,
        }
    }

    /// The number the processes reduce (the largest wins; 0 for no failure).
    pub fn level(severity: Option<Self>) -> i32 {
        severity.map_or(0, |s| s as i32)
    }
}

/// One process's failure as the others learn it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FailureNote {
    pub severity: Severity,
    /// The material point whose state failed, if one did.
    pub point: Option<u32>,
    /// The stage a non-finite value came from (empty otherwise).
    pub stage: String,
    /// What failed, without the step (a point state's reason, the non-finite quantity).
    pub detail: String,
    /// The whole message, as the failing process says it.
    pub message: String,
}

impl FailureNote {
    /// The numbers sent for this failure: `[severity, point + 1 or 0, texts...]`.
    pub fn pack(&self) -> Vec<u64> {
        let mut numbers = vec![
            self.severity as u64,
            self.point.map_or(0, |p| u64::from(p) + 1),
        ];
        for text in [&self.stage, &self.detail, &self.message] {
            pack_text(text, &mut numbers);
        }
        numbers
    }

    /// The failure [`FailureNote::pack`] sent; `None` for an empty message (no failure) or
    /// numbers that are not one.
    pub fn unpack(numbers: &[u64]) -> Option<Self> {
        let (&[severity, point], mut rest) = numbers.split_first_chunk::<2>()?;
        let severity = Severity::from_level(i32::try_from(severity).ok()?)?;
        let mut texts = [String::new(), String::new(), String::new()];
        for text in &mut texts {
            let (read, after) = unpack_text(rest)?;
            *text = read;
            rest = after;
        }
        let [stage, detail, message] = texts;
        Some(Self {
            severity,
            point: point.checked_sub(1).and_then(|p| u32::try_from(p).ok()),
            stage,
            detail,
            message,
        })
    }
}

/// Appends `text` as its length in bytes and its bytes, eight to a number (little-endian).
fn pack_text(text: &str, numbers: &mut Vec<u64>) {
    let bytes = text.as_bytes();
    numbers.push(bytes.len() as u64);
    for chunk in bytes.chunks(8) {
        let mut word = [0u8; 8];
        word[..chunk.len()].copy_from_slice(chunk);
        numbers.push(u64::from_le_bytes(word));
    }
}

/// The text [`pack_text`] wrote at the start of `numbers`, and the numbers after it.
fn unpack_text(numbers: &[u64]) -> Option<(String, &[u64])> {
    let (&length, rest) = numbers.split_first()?;
    let length = usize::try_from(length).ok()?;
    let words = length.div_ceil(8);
    if rest.len() < words {
        return None;
    }
    let bytes: Vec<u8> = rest[..words]
        .iter()
        .flat_map(|word| word.to_le_bytes())
        .take(length)
        .collect();
    Some((String::from_utf8_lossy(&bytes).into_owned(), &rest[words..]))
}

/// The failure that decides, among every process's (indexed by rank): the lowest rank among
/// the most severe. `None` when no process failed.
pub fn deciding(failures: &[Option<FailureNote>]) -> Option<(usize, &FailureNote)> {
    let severity = failures.iter().flatten().map(|f| f.severity).max()?;
    failures.iter().enumerate().find_map(|(rank, f)| {
        f.as_ref()
            .filter(|f| f.severity == severity)
            .map(|f| (rank, f))
    })
}

/// `message` without its leading `load step N: ` or `load step N, ` (the step is said once, by
/// the error that carries it).
pub fn without_step(message: &str, step: usize) -> &str {
    let prefix = format!("load step {step}");
    message
        .strip_prefix(&prefix)
        .and_then(|rest| rest.strip_prefix(": ").or_else(|| rest.strip_prefix(", ")))
        .unwrap_or(message)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn note(severity: Severity, message: &str) -> FailureNote {
        FailureNote {
            severity,
            point: None,
            stage: String::new(),
            detail: String::new(),
            message: message.to_string(),
        }
    }

    /// Every field survives the trip, texts of every length modulo 8 and non-ASCII ones too;
    /// truncated numbers are not a failure.
    #[test]
    fn a_failure_is_read_back_from_its_numbers() {
        for length in 0..20 {
            let sent = FailureNote {
                severity: Severity::TrialState,
                point: Some(u32::MAX),
                stage: "assembly".to_string(),
                detail: "é".repeat(length),
                message: "x".repeat(length),
            };
            let numbers = sent.pack();
            assert_eq!(FailureNote::unpack(&numbers), Some(sent.clone()));
            assert_eq!(FailureNote::unpack(&numbers[..numbers.len() - 1]), None);
        }
        let zero = FailureNote {
            point: Some(0),
            ..note(Severity::Fatal, "")
        };
        assert_eq!(FailureNote::unpack(&zero.pack()), Some(zero));
        assert_eq!(FailureNote::unpack(&[]), None);
        assert_eq!(FailureNote::unpack(&[0, 0, 0, 0, 0]), None, "severity 0");
    }

    /// The most severe failure decides; among equals, the lowest rank's.
    #[test]
    fn the_lowest_rank_of_the_most_severe_failure_decides() {
        assert_eq!(deciding(&[None, None]), None);
        let failures = [
            None,
            Some(note(Severity::TrialState, "a")),
            Some(note(Severity::Recoverable, "b")),
            Some(note(Severity::Recoverable, "c")),
        ];
        let (rank, failure) = deciding(&failures).unwrap();
        assert_eq!((rank, failure.message.as_str()), (2, "b"));
        let (rank, _) = deciding(&failures[..2]).unwrap();
        assert_eq!(rank, 1);
        assert!(Severity::TrialState < Severity::Recoverable);
        assert!(Severity::Recoverable < Severity::Fatal);
        for severity in [Severity::TrialState, Severity::Recoverable, Severity::Fatal] {
            assert_eq!(
                Severity::from_level(Severity::level(Some(severity))),
                Some(severity)
            );
        }
        assert_eq!(Severity::from_level(Severity::level(None)), None);
    }

    #[test]
    fn the_step_is_said_once() {
        assert_eq!(without_step("load step 3: point 4 left", 3), "point 4 left");
        assert_eq!(
            without_step("load step 3, Newton iteration 2: x", 3),
            "Newton iteration 2: x"
        );
        assert_eq!(without_step("load step 13: x", 1), "load step 13: x");
        assert_eq!(without_step("other", 1), "other");
    }
}
