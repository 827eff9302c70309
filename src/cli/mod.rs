//! Pieces of the command line kept out of `main.rs`: writing to the console without panicking
//! ([`console`]) and the progress display ([`progress`]).

pub mod console;
#[cfg(feature = "mpi")]
pub mod distributed;
pub mod progress;
