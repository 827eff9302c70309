//! The PETSc backend over every process of a distributed run (cargo feature `mpi`).
//!
//! Each process holds the whole pattern of `K` (the state is replicated, see
//! `crate::distributed`) but only its **share of the values**: the sum over the points it
//! assembles. The padded system of the serial backend (see the parent module) becomes one
//! PETSc `MPIAIJ` matrix with the same global numbering; process `r` of `P` owns the rows of
//! the nodes `[B r / P, B (r + 1) / P)` of the `B` padded nodes (whole nodes, so block size
//! `D` and the rigid-body modes carry over). Every Newton iteration each process adds its
//! nonzero rows with `MatSetValues(ADD_VALUES)`; entries in rows another process owns travel
//! through PETSc's assembly (`MatAssemblyBegin/End`). The right-hand side is the same on
//! every process (it is formed from the internal force already summed over the processes,
//! [`ProcessSum`]): each process copies its own rows into the `MPI` vector. KSP solves, and
//! the correction is gathered to every process (`VecScatterCreateToAll`), so that every
//! process updates every point with the same numbers.
//!
//! The padded rows of constrained components get `s` on the diagonal (their owner adds it),
//! with `s` the mean `|K_ii|` of the processes' shares (an `MPI_Allreduce`; it only has to be
//! of the order of `K`'s diagonal). "Converged" is re-checked on the true residual
//! `‖r − K δ‖ / ‖r‖` computed by PETSc on the distributed objects (`MatMult`, `VecNorm`), so the
//! decision is the same on every process.
//!
//! **The decomposed grid** (`impm run --decompose`, [`PetscSolver::decomposed`]): each
//! process passes its *local* system instead — the DOFs of the nodes its own points touch
//! (owned nodes and ghost layer), numbered by its own DOF stage — and the decomposed grid's
//! global block numbers of those nodes ([`GlobalBlocks`]: the lowest rank touching a node owns
//! it, owned blocks numbered contiguously per process, `distributed::ownership`). Local padded
//! row `b D + c` (block `b`, component `c`) is global row `g(b) D + c`; process `r` owns the
//! rows of its owned blocks, `[first D, (first + owned) D)`. The owned rows are preallocated
//! from every process's local pattern (a `MATPREALLOCATOR` matrix: each process inserts its
//! local rows with global indices, rows of ghost nodes travel to their owners), each process
//! adds its local rows with `MatSetValues(ADD_VALUES)` and global indices, sets the
//! right-hand side's owned rows, the rigid-body modes come from the owned nodes, and the
//! correction comes back to this process's local rows only (`VecScatterCreate` with their
//! global numbers): no process holds the whole grid's pattern or vectors.

use std::ffi::CStr;
use std::sync::{Arc, Mutex};

use super::ffi::{self, PetscInt};
use super::{
    BuiltFor, Comm, IDENTITY, LinearSolveError, Method, Padding, PatternObjects, PetscSolver,
    SolverKind, SparseMatrix, check, configure_ksp, objects_for, refuse_unused_options, session,
    set_rigid_body_modes, solve_with_ksp,
};
use crate::distributed::traffic::{Traffic, count};

impl PetscSolver {
    /// A solver whose objects live on every process of a distributed run (`MPI_COMM_WORLD`):
    /// each process passes the tangent holding its share of the values (see the module docs)
    /// and the same right-hand side; every process gets the whole solution. Collective: every
    /// process must solve, with the same pattern and right-hand side.
    pub fn distributed(options: &str) -> Self {
        let mut solver = Self::new(options);
        solver.distributed = true;
        solver
    }

    /// A distributed solver over the decomposed grid: the tangent passed is this process's
    /// local system, and `blocks` holds its nodes' global block numbers (refilled every step
    /// by the decomposed grid's numbering, before the first solve; see the module docs).
    pub fn decomposed(options: &str, blocks: SharedBlocks) -> Self {
        let mut solver = Self::distributed(options);
        solver.global_blocks = Some(blocks);
        solver
    }

    /// `LinearSolver::solve` of a distributed solver.
    pub(super) fn solve_distributed(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        rhs: &mut [f64],
    ) -> Result<SolverKind, LinearSolveError> {
        let _session = session()?;
        let prefix = self.prefix()?;
        let blocks = match &self.global_blocks {
            Some(shared) => {
                let blocks = shared.lock().unwrap_or_else(|e| e.into_inner());
                Some(blocks.clone().ok_or_else(|| {
                    LinearSolveError::Backend(
                        "the decomposed grid's global numbers are missing".to_string(),
                    )
                })?)
            }
            None => None,
        };
        let method = self.method();
        let (objects, _) = objects_for(&mut self.distributed_objects, matrix, symmetric, || {
            let (objects, tolerance) =
                DistributedObjects::new(matrix, symmetric, &prefix, blocks.as_ref(), method)?;
            self.tolerance = tolerance;
            Ok(objects)
        })?;
        let tolerance = self
            .requested
            .take()
            .map_or(self.tolerance, |r| r.max(self.tolerance));
        objects.set_values(matrix)?;
        let solved = objects.solve(rhs, tolerance);
        let method = objects.method.clone();
        if !self.options_checked {
            self.options_checked = true;
            if let Some(prefix) = &self.prefix {
                refuse_unused_options(prefix)?;
            }
        }
        let (iterations, relative) = solved?;
        self.last_iterations = iterations;
        let converged = relative <= 10.0 * tolerance; // false for NaN
        if !converged {
            return Err(LinearSolveError::NotConverged(format!(
                "PETSc's {method} solve (distributed) reported convergence but its true \
                 residual is {relative:.2e} of the right-hand side against a tolerance of \
                 {tolerance:.0e}; change petsc_options"
            )));
        }
        Ok(SolverKind::Petsc)
    }
}

/// The decomposed grid's global numbers of the nodes a process holds, for the solver.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GlobalBlocks {
    /// The nodes this process holds (its points' supports' nodes), in increasing order.
    pub nodes: Vec<usize>,
    /// Each node's global block number (`u64::MAX`: no free component).
    pub blocks: Vec<u64>,
    /// The first global block this process owns, and how many.
    pub first: u64,
    pub owned: u64,
    /// Global blocks over all processes.
    pub total: u64,
    /// Components per node (the block size; also on a process with no DOFs).
    pub components: usize,
}

/// The global numbers shared between the decomposed grid's numbering (which fills them every
/// step) and the solver (which reads them when it builds its objects).
pub type SharedBlocks = Arc<Mutex<Option<GlobalBlocks>>>;

/// The distributed PETSc objects of one pattern.
pub(super) struct DistributedObjects {
    /// The block size (the padding's; the grid's components for a decomposed grid, also on
    /// a process with no DOFs: PETSc wants the same on every process).
    block: usize,
    built_for: BuiltFor,
    padding: Padding,
    /// The padded rows this process owns (global numbers): `first..end`.
    first: usize,
    end: usize,
    /// Global padded rows: the whole padded system on every process (replicated grid).
    size_global: usize,
    /// The global row of each local padded row (decomposed grid); `None`: the identity.
    global: Option<Vec<PetscInt>>,
    /// `padding.columns` in global numbers (decomposed grid).
    global_columns: Vec<PetscInt>,
    matrix: ffi::Mat,
    rhs: ffi::Vec,
    solution: ffi::Vec,
    /// `r − K δ`, for the true-residual check.
    residual: ffi::Vec,
    ksp: ffi::KSP,
    /// Gathers the solution to every process (replicated grid), or brings this process's
    /// local rows back (decomposed grid).
    scatter: ffi::VecScatter,
    gathered: ffi::Vec,
    method: String,
    /// Scratch: a padded vector, one row's values.
    padded: Vec<f64>,
    row: Vec<f64>,
    /// The values of other processes one product with the matrix needs here (the columns of
    /// the owned rows outside `first..end`: `MPIAIJ`'s off-diagonal block), and the processes.
    ghosts: usize,
    size: usize,
}

impl PatternObjects for DistributedObjects {
    fn built_for(&self) -> BuiltFor {
        self.built_for
    }

    fn destroy(mut self) {
        // SAFETY: PETSc ignores null handles; each object is destroyed once.
        unsafe {
            ffi::KSPDestroy(&mut self.ksp);
            ffi::VecScatterDestroy(&mut self.scatter);
            ffi::VecDestroy(&mut self.gathered);
            ffi::VecDestroy(&mut self.residual);
            ffi::VecDestroy(&mut self.solution);
            ffi::VecDestroy(&mut self.rhs);
            ffi::MatDestroy(&mut self.matrix);
        }
    }
}

impl DistributedObjects {
    /// Creates the objects for `matrix`'s pattern (with `blocks`: the local system of a
    /// decomposed grid); returns them and the relative tolerance the options set.
    /// Collective; the caller holds the session.
    fn new(
        matrix: &SparseMatrix,
        symmetric: bool,
        prefix: &CStr,
        blocks: Option<&GlobalBlocks>,
        method: Method,
    ) -> Result<(Self, f64), LinearSolveError> {
        let padding = Padding::new(matrix)?;
        let processes = crate::distributed::processes()
            .unwrap_or(crate::distributed::Processes { rank: 0, size: 1 });
        let (rank, size) = (processes.rank, processes.size.max(1));
        let d = blocks.map_or(padding.block, |numbers| numbers.components);
        let (first, end, size_global, global) = match blocks {
            None => {
                let blocks = padding.size / d;
                let first = blocks * rank / size * d;
                let end = blocks * (rank + 1) / size * d;
                (first, end, padding.size, None)
            }
            Some(numbers) => {
                let global = global_rows(matrix, &padding, numbers)?;
                let first = numbers.first as usize * d;
                let end = (numbers.first + numbers.owned) as usize * d;
                (first, end, numbers.total as usize * d, Some(global))
            }
        };
        let global_columns = match &global {
            Some(rows) => padding.columns.iter().map(|&c| rows[c as usize]).collect(),
            None => Vec::new(),
        };
        let null = std::ptr::null_mut();
        let mut objects = Self {
            block: d,
            built_for: BuiltFor::of(matrix, symmetric),
            first,
            end,
            size_global,
            global,
            global_columns,
            matrix: null,
            rhs: null,
            solution: null,
            residual: null,
            ksp: null,
            scatter: null,
            gathered: null,
            method: String::new(),
            padded: vec![0.0; padding.size],
            row: Vec::new(),
            ghosts: 0,
            size,
            padding,
        };
        let mut ghosts: Vec<PetscInt> = (0..objects.padding.size)
            .filter(|&p| objects.owns(p))
            .flat_map(|p| objects.columns_of(p).to_vec())
            .filter(|&c| !(objects.first..objects.end).contains(&(c as usize)))
            .collect();
        ghosts.sort_unstable();
        ghosts.dedup();
        objects.ghosts = ghosts.len();
        match objects.create(prefix, method) {
            Ok(tolerance) => Ok((objects, tolerance)),
            Err(e) => {
                objects.destroy();
                Err(e)
            }
        }
    }

    /// The global row of local padded row `p`.
    fn global_row(&self, p: usize) -> usize {
        self.global.as_ref().map_or(p, |rows| rows[p] as usize)
    }

    /// Whether this process owns local padded row `p`.
    fn owns(&self, p: usize) -> bool {
        (self.first..self.end).contains(&self.global_row(p))
    }

    /// The global columns of local padded row `p`.
    fn columns_of(&self, p: usize) -> &[PetscInt] {
        let rows = &self.padding.row_start;
        let range = rows[p] as usize..rows[p + 1] as usize;
        match self.global {
            Some(_) => &self.global_columns[range],
            None => &self.padding.columns[range],
        }
    }

    fn create(&mut self, prefix: &CStr, method: Method) -> Result<f64, LinearSolveError> {
        let comm = Comm::World.raw();
        let local = (self.end - self.first) as PetscInt;
        let global = self.size_global as PetscInt;
        let block = self.block as PetscInt;
        // SAFETY: the session is held; the arrays passed are copied by PETSc.
        unsafe {
            check(ffi::MatCreate(comm, &mut self.matrix), "MatCreate")?;
            check(
                ffi::MatSetSizes(self.matrix, local, local, global, global),
                "MatSetSizes",
            )?;
            check(ffi::MatSetBlockSize(self.matrix, block), "MatSetBlockSize")?;
            check(
                ffi::MatSetType(self.matrix, c"mpiaij".as_ptr()),
                "MatSetType",
            )?;
            match self.global {
                None => self.preallocate_replicated()?,
                Some(_) => self.preallocate_decomposed()?,
            }
            // (collective: a decomposed grid's process with no DOFs, hence no positions,
            // takes part with no coordinates)
            let empty = (self.global.is_some() && self.padding.size == 0).then(Vec::new);
            if let Some(coordinates) = self.padding.coordinates.as_ref().or(empty.as_ref()) {
                // the owned blocks' nodes, in their global order (node order: the owned
                // blocks are numbered node-major in node order, as the local ones)
                let owned: Vec<f64> = match self.global {
                    None => coordinates[self.first..self.end].to_vec(),
                    Some(_) => (0..self.padding.size)
                        .filter(|&p| self.owns(p))
                        .map(|p| coordinates[p])
                        .collect(),
                };
                set_rigid_body_modes(self.matrix, self.block, &owned, Comm::World)?;
            }
            for vector in [&mut self.rhs, &mut self.solution, &mut self.residual] {
                check(
                    ffi::VecCreateMPI(comm, local, global, vector),
                    "VecCreateMPI",
                )?;
            }
            match &self.global {
                None => check(
                    ffi::VecScatterCreateToAll(
                        self.solution,
                        &mut self.scatter,
                        &mut self.gathered,
                    ),
                    "VecScatterCreateToAll",
                )?,
                Some(rows) => {
                    let count = rows.len() as PetscInt;
                    check(
                        ffi::VecCreateSeq(ffi::comm_self(), count, &mut self.gathered),
                        "VecCreateSeq",
                    )?;
                    let mut set = std::ptr::null_mut();
                    check(
                        ffi::ISCreateGeneral(
                            ffi::comm_self(),
                            count,
                            rows.as_ptr(),
                            ffi::PETSC_COPY_VALUES,
                            &mut set,
                        ),
                        "ISCreateGeneral",
                    )?;
                    let null = std::ptr::null_mut();
                    let created = check(
                        ffi::VecScatterCreate(
                            self.solution,
                            set,
                            self.gathered,
                            null,
                            &mut self.scatter,
                        ),
                        "VecScatterCreate",
                    );
                    ffi::ISDestroy(&mut set);
                    created?;
                }
            }
            check(ffi::KSPCreate(comm, &mut self.ksp), "KSPCreate")?;
            let symmetric = self.built_for.symmetric;
            let (method, relative) =
                configure_ksp(self.ksp, self.matrix, symmetric, prefix, method)?;
            self.method = method;
            Ok(relative)
        }
    }

    /// The replicated grid: every process holds the whole pattern and gives PETSc its owned
    /// rows' CSR.
    ///
    /// # Safety
    /// The session is held; the matrix is created with its sizes and type.
    unsafe fn preallocate_replicated(&self) -> Result<(), LinearSolveError> {
        let padding = &self.padding;
        let base = padding.row_start[self.first];
        let starts: Vec<PetscInt> = padding.row_start[self.first..=self.end]
            .iter()
            .map(|&r| r - base)
            .collect();
        let columns = &padding.columns[base as usize..padding.row_start[self.end] as usize];
        let zeros = vec![0.0; columns.len()];
        // SAFETY: as the caller promises; the CSR arrays are copied by PETSc.
        unsafe {
            check(
                ffi::MatMPIAIJSetPreallocationCSR(
                    self.matrix,
                    starts.as_ptr(),
                    columns.as_ptr(),
                    zeros.as_ptr(),
                ),
                "MatMPIAIJSetPreallocationCSR",
            )
        }
    }

    /// The decomposed grid: no process holds all of its owned rows' pattern (a neighbour's
    /// points add to the rows of the nodes it shares), so every process inserts its local
    /// rows, with global numbers, into a `MATPREALLOCATOR` matrix, whose assembly sends the
    /// rows of ghost nodes to their owners; it then preallocates the matrix, zeros filled in
    /// (the pattern fixed for the load step).
    ///
    /// # Safety
    /// The session is held; the matrix is created with its sizes and type.
    unsafe fn preallocate_decomposed(&self) -> Result<(), LinearSolveError> {
        let comm = Comm::World.raw();
        let local = (self.end - self.first) as PetscInt;
        let global = self.size_global as PetscInt;
        let mut preallocator = std::ptr::null_mut();
        // SAFETY: as the caller promises; every row passed has its columns' count of values.
        unsafe {
            let result = (|| {
                check(ffi::MatCreate(comm, &mut preallocator), "MatCreate")?;
                check(
                    ffi::MatSetSizes(preallocator, local, local, global, global),
                    "MatSetSizes",
                )?;
                check(
                    ffi::MatSetBlockSize(preallocator, self.block as PetscInt),
                    "MatSetBlockSize",
                )?;
                check(
                    ffi::MatSetType(preallocator, c"preallocator".as_ptr()),
                    "MatSetType",
                )?;
                check(ffi::MatSetUp(preallocator), "MatSetUp")?;
                let mut zeros = Vec::new();
                for p in 0..self.padding.size {
                    let columns = self.columns_of(p);
                    zeros.resize(columns.len(), 0.0);
                    let row = self.global_row(p) as PetscInt;
                    check(
                        ffi::MatSetValues(
                            preallocator,
                            1,
                            &row,
                            columns.len() as PetscInt,
                            columns.as_ptr(),
                            zeros.as_ptr(),
                            ffi::INSERT_VALUES,
                        ),
                        "MatSetValues",
                    )?;
                }
                check(
                    ffi::MatAssemblyBegin(preallocator, ffi::MAT_FINAL_ASSEMBLY),
                    "MatAssemblyBegin",
                )?;
                check(
                    ffi::MatAssemblyEnd(preallocator, ffi::MAT_FINAL_ASSEMBLY),
                    "MatAssemblyEnd",
                )?;
                check(
                    ffi::MatPreallocatorPreallocate(preallocator, ffi::PETSC_TRUE, self.matrix),
                    "MatPreallocatorPreallocate",
                )
            })();
            ffi::MatDestroy(&mut preallocator);
            result
        }
    }

    /// Puts this process's share of `matrix`'s values into the distributed matrix and
    /// assembles it (collective).
    fn set_values(&mut self, matrix: &SparseMatrix) -> Result<(), LinearSolveError> {
        let values = matrix.values();
        let padding = &self.padding;
        let share: f64 = padding.diagonal.iter().map(|&k| values[k].abs()).sum();
        // the diagonal's entries over the processes (a ghost's counted by each holder: `s`
        // only has to be of the order of K's diagonal)
        let entries = match self.global {
            None => padding.diagonal.len() as f64,
            Some(_) => crate::distributed::sum(padding.diagonal.len() as f64),
        };
        let mean = crate::distributed::sum(share) / entries.max(1.0);
        let scale = if mean > 0.0 && mean.is_finite() {
            mean
        } else {
            1.0
        };
        // SAFETY: the session is held; every row passed has its columns' count of values.
        unsafe {
            check(ffi::MatZeroEntries(self.matrix), "MatZeroEntries")?;
            for p in 0..self.padding.size {
                let padding = &self.padding;
                let range = padding.row_start[p] as usize..padding.row_start[p + 1] as usize;
                let owned = self.owns(p);
                let mut row = std::mem::take(&mut self.row);
                row.clear();
                row.extend(padding.source[range].iter().map(|&k| {
                    if k != IDENTITY {
                        values[k]
                    } else if owned {
                        scale
                    } else {
                        0.0
                    }
                }));
                let columns = self.columns_of(p);
                let skip = row.iter().all(|&v| v == 0.0);
                if !skip && !owned {
                    count(Traffic::MatrixEntries, 16 * row.len() as u64);
                }
                let result = if skip {
                    Ok(())
                } else {
                    let global_row = self.global_row(p) as PetscInt;
                    check(
                        ffi::MatSetValues(
                            self.matrix,
                            1,
                            &global_row,
                            row.len() as PetscInt,
                            columns.as_ptr(),
                            row.as_ptr(),
                            ffi::ADD_VALUES,
                        ),
                        "MatSetValues",
                    )
                };
                self.row = row;
                result?;
            }
            check(
                ffi::MatAssemblyBegin(self.matrix, ffi::MAT_FINAL_ASSEMBLY),
                "MatAssemblyBegin",
            )?;
            check(
                ffi::MatAssemblyEnd(self.matrix, ffi::MAT_FINAL_ASSEMBLY),
                "MatAssemblyEnd",
            )
        }
    }

    /// Solves for `rhs` (in place; replicated grid: the same on every process, every process
    /// gets the whole solution; decomposed grid: this process's local system, right for its
    /// owned rows, and it gets its local rows back); returns PETSc's iterations and the true
    /// relative residual. Collective.
    fn solve(&mut self, rhs: &mut [f64], tolerance: f64) -> Result<(usize, f64), LinearSolveError> {
        self.padded.fill(0.0);
        for (&p, &r) in self.padding.of_dof.iter().zip(rhs.iter()) {
            self.padded[p] = r;
        }
        let mut array = std::ptr::null_mut();
        // SAFETY: the session is held; the local part of an MPI vector has end − first
        // entries, the gathered vector the replicated system's or this process's local rows.
        unsafe {
            check(ffi::VecGetArray(self.rhs, &mut array), "VecGetArray")?;
            let owned = local_part(array, self.end - self.first);
            match self.global {
                None => owned.copy_from_slice(&self.padded[self.first..self.end]),
                Some(_) => {
                    for p in (0..self.padding.size).filter(|&p| self.owns(p)) {
                        owned[self.global_row(p) - self.first] = self.padded[p];
                    }
                }
            }
            check(
                ffi::VecRestoreArray(self.rhs, &mut array),
                "VecRestoreArray",
            )?;
            let iterations =
                solve_with_ksp(self.ksp, self.rhs, self.solution, tolerance, &self.method)?;
            // one product per Krylov iteration, one for the true residual below
            count(
                Traffic::KrylovHalo,
                8 * (self.ghosts * (iterations + 1)) as u64,
            );
            let received = match self.global {
                None => (self.size as u64 - 1) * (self.end - self.first) as u64,
                Some(_) => (0..self.padding.size).filter(|&p| !self.owns(p)).count() as u64,
            };
            count(Traffic::Gathered, 8 * received);
            gather_to_all(self.scatter, self.solution, self.gathered)?;
            check(ffi::VecGetArray(self.gathered, &mut array), "VecGetArray")?;
            let all: &[f64] = local_part(array, self.padding.size);
            for (&p, r) in self.padding.of_dof.iter().zip(rhs.iter_mut()) {
                *r = all[p];
            }
            check(
                ffi::VecRestoreArray(self.gathered, &mut array),
                "VecRestoreArray",
            )?;
            // the true residual r − K δ, measured by PETSc: the same on every process
            check(
                ffi::MatMult(self.matrix, self.solution, self.residual),
                "MatMult",
            )?;
            check(ffi::VecAYPX(self.residual, -1.0, self.rhs), "VecAYPX")?;
            let (mut residual, mut size) = (0.0, 0.0);
            check(
                ffi::VecNorm(self.residual, ffi::NORM_2, &mut residual),
                "VecNorm",
            )?;
            check(ffi::VecNorm(self.rhs, ffi::NORM_2, &mut size), "VecNorm")?;
            let relative = if size > 0.0 {
                residual / size
            } else if residual == 0.0 {
                0.0
            } else {
                f64::INFINITY
            };
            Ok((iterations, relative))
        }
    }
}

/// The global padded row of each local padded row of `matrix` (its blocks' nodes looked up
/// in `numbers`). Errors when a block's node is not among the numbered ones, or has no global
/// block (the DOF stage and the numbering disagree).
fn global_rows(
    matrix: &SparseMatrix,
    padding: &Padding,
    numbers: &GlobalBlocks,
) -> Result<Vec<PetscInt>, LinearSolveError> {
    let d = numbers.components;
    let layout = matrix.layout();
    if padding.size == 0 {
        return Ok(Vec::new()); // no DOFs here: the process takes part in the collective calls
    }
    if d != padding.block || d != layout.dimension || layout.node.len() * d != padding.size {
        return Err(LinearSolveError::Backend(
            "the decomposed grid needs the whole-node (padded) system".to_string(),
        ));
    }
    let mut rows = Vec::with_capacity(padding.size);
    for &node in &layout.node {
        let block = numbers
            .nodes
            .binary_search(&node)
            .ok()
            .map(|i| numbers.blocks[i])
            .filter(|&b| b != u64::MAX && b < numbers.total)
            .ok_or_else(|| {
                LinearSolveError::Backend(format!(
                    "node {node} has DOFs here but no global number in the decomposed grid"
                ))
            })?;
        for c in 0..d {
            let row = block as usize * d + c;
            rows.push(PetscInt::try_from(row).map_err(|_| {
                LinearSolveError::Backend(format!(
                    "the system has {row} rows, more than PETSc's PetscInt holds"
                ))
            })?);
        }
    }
    Ok(rows)
}

/// The `len` entries of a vector's local part at `array` (`VecGetArray`), empty for none (a
/// process of a decomposed grid without DOFs: PETSc may hand back no array).
///
/// # Safety
/// `array` holds `len` entries, valid while the slice is used.
unsafe fn local_part<'a>(array: *mut f64, len: usize) -> &'a mut [f64] {
    if len == 0 || array.is_null() {
        return &mut [];
    }
    // SAFETY: as the caller promises.
    unsafe { std::slice::from_raw_parts_mut(array, len) }
}

/// Copies the distributed vector `from` into `to`, the whole vector on every process, with a
/// scatter made by `VecScatterCreateToAll` (collective).
///
/// # Safety
/// The session is held; the objects were created together.
unsafe fn gather_to_all(
    scatter: ffi::VecScatter,
    from: ffi::Vec,
    to: ffi::Vec,
) -> Result<(), LinearSolveError> {
    let (insert, forward) = (ffi::INSERT_VALUES, ffi::SCATTER_FORWARD);
    // SAFETY: as the caller promises.
    unsafe {
        check(
            ffi::VecScatterBegin(scatter, from, to, insert, forward),
            "VecScatterBegin",
        )?;
        check(
            ffi::VecScatterEnd(scatter, from, to, insert, forward),
            "VecScatterEnd",
        )
    }
}

/// Sums a vector over the processes of a distributed run through a PETSc `MPI` vector: each
/// process adds its nonzero entries (`VecSetValues(ADD_VALUES)`, off-process entries through
/// `VecAssemblyBegin/End`), and the sums are gathered back to every process
/// (`VecScatterCreateToAll`). Every process gets the same numbers, bit for bit (each entry is
/// summed once, by the process that owns it); across runs the order in which the owner adds
/// the other processes' entries may differ (the order messages arrive), so the last bits may.
#[derive(Default)]
pub struct ProcessSum {
    length: usize,
    vector: Option<(ffi::Vec, ffi::VecScatter, ffi::Vec)>,
    indices: Vec<PetscInt>,
    values: Vec<f64>,
}

// SAFETY: the PETSc objects are touched only under the process-wide lock.
unsafe impl Send for ProcessSum {}
// SAFETY: as for Send.
unsafe impl Sync for ProcessSum {}

impl ProcessSum {
    /// Replaces `values` by their sum over the processes. Collective: every process calls it
    /// with a slice of the same length.
    pub fn sum(&mut self, values: &mut [f64]) -> Result<(), LinearSolveError> {
        let _session = session()?;
        if self.length != values.len() {
            self.destroy();
        }
        let (vector, scatter, gathered) = match self.vector {
            Some(objects) => objects,
            None => {
                let mut objects = (
                    std::ptr::null_mut(),
                    std::ptr::null_mut(),
                    std::ptr::null_mut(),
                );
                // SAFETY: the session is held; out-pointers are valid.
                let created = unsafe {
                    check(
                        ffi::VecCreateMPI(
                            Comm::World.raw(),
                            ffi::PETSC_DECIDE,
                            values.len() as PetscInt,
                            &mut objects.0,
                        ),
                        "VecCreateMPI",
                    )
                    .and_then(|()| {
                        check(
                            ffi::VecScatterCreateToAll(objects.0, &mut objects.1, &mut objects.2),
                            "VecScatterCreateToAll",
                        )
                    })
                };
                self.vector = Some(objects);
                self.length = values.len();
                created?;
                objects
            }
        };
        self.indices.clear();
        self.values.clear();
        for (i, &v) in values.iter().enumerate() {
            if v != 0.0 {
                self.indices.push(i as PetscInt);
                self.values.push(v);
            }
        }
        // PETSc's own split of the entries (PETSC_DECIDE: PetscSplitOwnership)
        let processes = crate::distributed::processes()
            .unwrap_or(crate::distributed::Processes { rank: 0, size: 1 });
        let (n, size, rank) = (values.len(), processes.size.max(1), processes.rank);
        let first = rank * (n / size) + rank.min(n % size);
        let owned = first..first + n / size + usize::from(rank < n % size);
        let elsewhere = (self.indices.iter())
            .filter(|&&i| !owned.contains(&(i as usize)))
            .count();
        count(Traffic::VectorEntries, 12 * elsewhere as u64);
        count(
            Traffic::Gathered,
            8 * (size as u64 - 1) * owned.len() as u64,
        );
        // SAFETY: the session is held; the objects were created for this length.
        unsafe {
            check(ffi::VecSet(vector, 0.0), "VecSet")?;
            check(
                ffi::VecSetValues(
                    vector,
                    self.indices.len() as PetscInt,
                    self.indices.as_ptr(),
                    self.values.as_ptr(),
                    ffi::ADD_VALUES,
                ),
                "VecSetValues",
            )?;
            check(ffi::VecAssemblyBegin(vector), "VecAssemblyBegin")?;
            check(ffi::VecAssemblyEnd(vector), "VecAssemblyEnd")?;
            gather_to_all(scatter, vector, gathered)?;
            let mut array = std::ptr::null_mut();
            check(ffi::VecGetArray(gathered, &mut array), "VecGetArray")?;
            values.copy_from_slice(std::slice::from_raw_parts(array, values.len()));
            check(
                ffi::VecRestoreArray(gathered, &mut array),
                "VecRestoreArray",
            )
        }
    }

    /// Destroys the PETSc objects; the caller holds the session.
    fn destroy(&mut self) {
        if let Some((mut vector, mut scatter, mut gathered)) = self.vector.take() {
            // SAFETY: PETSc ignores null handles; each object is destroyed once.
            unsafe {
                ffi::VecScatterDestroy(&mut scatter);
                ffi::VecDestroy(&mut gathered);
                ffi::VecDestroy(&mut vector);
            }
        }
        self.length = 0;
    }
}

impl Drop for ProcessSum {
    fn drop(&mut self) {
        if self.vector.is_some() {
            let _session = super::PETSC.lock().unwrap_or_else(|e| e.into_inner());
            self.destroy();
        }
    }
}
