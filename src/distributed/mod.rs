//! Distributed runs: the processes of `mpirun -n N impm run SCENE` (cargo feature `mpi`).
//!
//! What exists (the first, replicated step of issue 14; `docs/distributed.md`): every process
//! holds the whole state (all points and the whole grid) and runs every stage on it, except
//! that it **assembles** only the points of its own slab of background cells
//! ([`partition`]); the processes' sums of the tangent go into one PETSc `MPIAIJ` matrix and
//! their sums of the internal force into one PETSc vector (off-process entries through
//! PETSc's own communication), KSP solves the distributed system, and the correction is
//! gathered to every process, which then updates every point identically. Only process 0
//! writes files and prints; the others run into a scratch folder of their own, removed at the
//! end, with their output silenced. The module that does this is `effects::distributed`; the
//! PETSc side is `solver::PetscSolver::distributed` and `solver::ProcessSum`.
//!
//! [`partition`] is a pure kernel (built in every configuration); the process bookkeeping
//! (`start`, `processes`, `any`) exists with the feature `mpi` only.

pub mod partition;

#[cfg(feature = "mpi")]
mod world;
#[cfg(feature = "mpi")]
pub use world::{
    Processes, Started, any, launched_by_mpirun, path_of_process_0, processes, start, sum,
};
