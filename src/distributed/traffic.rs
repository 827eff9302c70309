//! What a process of a distributed run sends, counted by kind (bytes since the run started):
//! the figures of the communication volume in `docs/distributed.md`. Counters only: nothing
//! here sends anything, and a serial run counts nothing.
//!
//! | kind | what | bytes counted |
//! |---|---|---|
//! | [`Traffic::Reductions`] | `MPI_Allreduce` / broadcasts of impm's decisions and small sums | the values this process contributes |
//! | [`Traffic::Points`] | migration records (`exchange`), the supports shared (`gather_all`) | sent to other processes (a gathered message once per other process) |
//! | [`Traffic::MatrixEntries`] | `MatSetValues` entries in rows another process owns | 16 per entry (row and column index, value) |
//! | [`Traffic::VectorEntries`] | `VecSetValues` entries (the sums of `f_int`, `f_ext`) another process owns; with the decomposed grid, the shares at ghost nodes sent to their owners | 12 per entry (index, value); decomposed: 8 per value (and the counts' all-to-all) |
//! | [`Traffic::Gathered`] | `VecScatterCreateToAll` gathers (the correction, the sums back to all); with the decomposed grid, the correction's ghost rows and the owners' sums sent back to the processes touching their nodes | the owned part, 8 per value, once per other process; decomposed: 8 per value received (correction) or sent (sums) |
//! | [`Traffic::KrylovHalo`] | the ghost values of one `MatMult` (PETSc's `MPIAIJ` off-diagonal columns) per Krylov iteration | received, 8 per ghost value and iteration |
//! | [`Traffic::GridNumbers`] | the decomposed grid's ownership and numbering (`ownership`): layer ranges and owned counts to all, shared nodes and their numbers to the neighbours | sent to other processes, 8 per number (a gathered message once per other process) |
//!
//! Not counted: PETSc's own reductions inside the Krylov method (a few 8-byte all-reduces per
//! iteration) and the coarse levels of its multigrid (GAMG's setup and its coarse solves).

use std::sync::atomic::{AtomicU64, Ordering};

/// The kinds of messages counted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Traffic {
    Reductions,
    Points,
    MatrixEntries,
    VectorEntries,
    Gathered,
    KrylovHalo,
    GridNumbers,
}

impl Traffic {
    /// Every kind, in the order of [`Traffic::name`]'s measures.
    pub const ALL: [Traffic; 7] = [
        Traffic::Reductions,
        Traffic::Points,
        Traffic::MatrixEntries,
        Traffic::VectorEntries,
        Traffic::Gathered,
        Traffic::KrylovHalo,
        Traffic::GridNumbers,
    ];

    /// The measure's name in summary.json (`bytes_...`, cumulative since the run started).
    pub fn name(self) -> &'static str {
        match self {
            Traffic::Reductions => "bytes_reductions",
            Traffic::Points => "bytes_points",
            Traffic::MatrixEntries => "bytes_matrix_entries",
            Traffic::VectorEntries => "bytes_vector_entries",
            Traffic::Gathered => "bytes_gathered",
            Traffic::KrylovHalo => "bytes_krylov_halo",
            Traffic::GridNumbers => "bytes_grid_numbers",
        }
    }
}

static COUNTS: [AtomicU64; 7] = [const { AtomicU64::new(0) }; 7];

/// Counts `bytes` of `kind`.
pub fn count(kind: Traffic, bytes: u64) {
    COUNTS[kind as usize].fetch_add(bytes, Ordering::Relaxed);
}

/// The bytes of `kind` counted since the run started.
pub fn counted(kind: Traffic) -> u64 {
    COUNTS[kind as usize].load(Ordering::Relaxed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_add_up_by_kind() {
        let before = counted(Traffic::Points);
        count(Traffic::Points, 40);
        count(Traffic::Points, 2);
        assert_eq!(counted(Traffic::Points) - before, 42);
        assert_eq!(Traffic::ALL.len(), COUNTS.len());
    }
}
