//! Writing to the console without panicking: `println!` panics when stdout is closed (a broken
//! pipe, `impm check .. | head -1`) or full (`/dev/full`). Results go to stdout through
//! [`say`], which reports the failure instead; diagnostics go to stderr through [`note`],
//! which ignores one (there is nowhere left to report it).

use std::io::{ErrorKind, Write};

/// Why the program stops early.
#[derive(Debug)]
pub enum Failure {
    /// A message for stderr (`error: ...`), exit status 1.
    Message(String),
    /// Stdout is closed (the reader went away): end quietly, exit status 141 (as a shell
    /// reports a process ended by SIGPIPE).
    BrokenPipe,
    /// Exit status 1 without a message: another process of the same `mpirun` job says why.
    Quiet,
}

impl From<String> for Failure {
    fn from(message: String) -> Self {
        Failure::Message(message)
    }
}

/// Writes `text` to stdout (as is: add the newline yourself).
pub fn say(text: &str) -> Result<(), Failure> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .map_err(|e| match e.kind() {
            ErrorKind::BrokenPipe => Failure::BrokenPipe,
            _ => Failure::Message(format!("cannot write to standard output: {e}")),
        })
}

/// Writes a line to stderr, ignoring a failure.
pub fn note(line: &str) {
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "{line}");
}
