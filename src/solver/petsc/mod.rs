//! The PETSc backend (cargo feature `petsc`): `K δ = r` solved by PETSc's Krylov methods and
//! preconditioners (KSP/PC), by default conjugate gradients (GMRES for a non-symmetric tangent)
//! with smoothed-aggregation algebraic multigrid (GAMG) given the elasticity near-null space.
//!
//! **The system PETSc sees.** [`SparseMatrix`] numbers only the free components of the active
//! nodes, so a node on a roller has fewer DOFs than `D`. PETSc's elasticity multigrid wants
//! whole nodes: a block size `D` (aggregation by node) and the rigid-body modes built from the
//! node coordinates (`MatNullSpaceCreateRigidBody`: `D` translations and `D (D − 1) / 2`
//! rotations). So the backend hands PETSc the *padded* system over every component of every
//! node with any DOF, `n_blocks · D` unknowns, in which a constrained component is an
//! uncoupled row and column `s · δ_i = 0` (`s` the mean diagonal of `K`, so that the row is
//! neither stiff nor soft against the others):
//!
//! ```text
//!   [ K  0   ] [ δ ]   [ r ]
//!   [ 0  s I ] [ 0 ] = [ 0 ]
//! ```
//!
//! whose solution is `δ` and zero, exactly. When the matrix has no [`super::DofLayout`]
//! (built without nodes), the system is passed as it is, with block size 1 and no near-null
//! space.
//!
//! **Reuse.** The padded CSR pattern, the map from [`SparseMatrix`]'s CSC values to it and the
//! PETSc objects (matrix, vectors, KSP) are built once per pattern (`SparseMatrix::generation`,
//! i.e. once per load step); each Newton iteration only copies the values into the matrix
//! (`MatSeqAIJGetArray`), which tells PETSc the operator changed and makes the preconditioner
//! redo its numerical setup. GAMG's option `-pc_gamg_reuse_interpolation true` also keeps its
//! prolongators between those setups.
//!
//! **Options.** The scene's `petsc_options` and the command line's `--petsc-options`
//! ([`set_command_line_options`], applied after the scene's, so they win) go to PETSc's options
//! database under a prefix of this solver's own, then `KSPSetFromOptions` reads them: any KSP
//! or PC option of PETSc works (`-ksp_type gmres -pc_type hypre`, `-pc_gamg_threshold 0.05`,
//! `-ksp_monitor`, ...). Defaults: relative tolerance 1e-10 on the unpreconditioned residual
//! (as the built-in solvers), at most 10 000 iterations. PETSc ignores an option nobody reads;
//! here an option still unused after the solver's first solve (a misspelling, an option of a
//! method not chosen, a global option such as `-log_view`, which the prefix hides) fails the
//! solve, naming it.
//!
//! **Never a wrong answer.** A solve that PETSc reports as diverged (its `KSPConvergedReason`
//! is negative, e.g. `DIVERGED_ITS`) is a failed solve with PETSc's reason; one that it
//! reports as converged is checked once more against the true residual `‖r − K δ‖ ≤ 10 tol ‖r‖`
//! (options may make PETSc measure another norm). A PETSc error code becomes an error naming
//! the function and PETSc's message; nothing panics. A zero right-hand side (the arc-length
//! control's first residual at λ = 0) returns the zero solution without a solve, where that
//! check would divide by ‖r‖ = 0; over several processes the test is collective (zero on
//! every process), so every process skips the solve alike.
//!
//! **A fallback when the default fails.** GMRES + GAMG does not converge on every system: a
//! stiff penalty on a few boundary points with F-bar's non-symmetric coupling (the quarter
//! ring of `docs/distributed.md`) ends in `DIVERGED_ITS` after the 10 000 iterations. When a
//! solve with the default fails to converge (PETSc's reason, or the true-residual check above)
//! and the options did not choose the method (no `-ksp_type`, no `-pc_type` in the scene's
//! `petsc_options` or in `--petsc-options`), the solver destroys its objects, builds them
//! again with GMRES and additive Schwarz (`-pc_type asm`: one block per process, PETSc's
//! default overlap of 1, each block factorised by LU: `-sub_pc_type lu` unless the options
//! set it) and solves the same system again; the other options (`-ksp_rtol`, ...) still
//! apply. It keeps the fallback for the rest of the run: the system that defeated GAMG is the
//! scene's (its penalty and its coupling stay), and trying the default again in every step
//! would pay its failed iterations each time. The run says it once, as a warning naming the
//! failed default and the fallback (`LinearSolver::take_notice`). On one process ASM is one
//! block, an exact LU; over several it is a block-Jacobi of exact solves with overlap,
//! whose GMRES iterations grow with the processes (tens on the ring over 3). A parallel direct
//! LU (`-pc_type lu -pc_factor_mat_solver_type mumps`; Debian's PETSc has MUMPS) was measured
//! as fast on the ring; ASM was kept as it needs no external package and no global
//! factorisation. A method the user chose is never replaced: its failure stays a failed
//! solve. Over several processes every process takes the same decision (the reason and the
//! true residual are collective, the options the same).
//!
//! **One process, one thread at a time.** PETSc is initialised once per process
//! (`PetscInitializeNoArguments`, with `-no_signal_handler` so that impm's own SIGINT/SIGTERM
//! handling stays) and is not thread-safe: every call runs under one process-wide lock. The
//! objects live on `PETSC_COMM_SELF`: this is the serial backend. With the cargo feature
//! `mpi`, `PetscSolver::distributed` puts them on every process of a distributed run
//! (`distributed.rs`: an `MPIAIJ` matrix summed from the processes' shares).

#[cfg(feature = "mpi")]
mod distributed;
mod ffi;

#[cfg(feature = "mpi")]
pub use distributed::{GlobalBlocks, ProcessSum, SharedBlocks};

use std::ffi::{CStr, CString, c_char, c_int, c_void};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard, OnceLock};

use ffi::PetscInt;

use super::krylov::true_relative_residual;
use super::{LinearSolveError, LinearSolver, SolverKind, SparseMatrix};

/// Serialises every call into PETSc (see the module docs).
static PETSC: Mutex<()> = Mutex::new(());
/// The outcome of initialising PETSc, once per process.
static INITIALISED: OnceLock<Result<(), String>> = OnceLock::new();
/// The message of the last PETSc error, recorded by [`record_error`].
static LAST_ERROR: Mutex<String> = Mutex::new(String::new());
/// `--petsc-options`, applied to every PETSc solver after the scene's options.
static COMMAND_LINE: Mutex<String> = Mutex::new(String::new());
/// Gives each solver its options prefix.
static NEXT_PREFIX: AtomicUsize = AtomicUsize::new(0);

/// The default relative tolerance, as the built-in Krylov solvers.
const DEFAULT_TOLERANCE: f64 = 1e-10;
/// The default iteration limit per solve.
const DEFAULT_MAX_ITERATIONS: usize = 10_000;

/// How a solver's KSP is configured before the options are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Method {
    /// CG (symmetric) or GMRES with GAMG.
    Default,
    /// After the default failed: GMRES with [`FALLBACK_PC`] (see the module docs).
    Fallback,
}

/// The fallback's preconditioner: additive Schwarz, one block per process with PETSc's
/// default overlap of 1, each block factorised exactly ([`set_fallback_options`]).
const FALLBACK_PC: &CStr = c"asm";
/// The fallback, for messages.
const FALLBACK_NAME: &str = "gmres+asm (LU on each block: -pc_type asm -sub_pc_type lu)";

/// Whether PETSc's options database (the scene's and the command line's options) names
/// `name` under `prefix`. The caller holds the session.
fn option_given(prefix: &CStr, name: &CStr) -> Result<bool, LinearSolveError> {
    let mut set = ffi::PETSC_FALSE;
    // SAFETY: PETSc is initialised (the caller holds the session); valid strings, out-pointer.
    check(
        unsafe {
            ffi::PetscOptionsHasName(
                std::ptr::null_mut(),
                prefix.as_ptr(),
                name.as_ptr(),
                &mut set,
            )
        },
        "PetscOptionsHasName",
    )?;
    Ok(set == ffi::PETSC_TRUE)
}

/// Sets the fallback's sub-solver options under `prefix` (LU on each block), unless the
/// options give them. The caller holds the session.
fn set_fallback_options(prefix: &CStr) -> Result<(), LinearSolveError> {
    if option_given(prefix, c"-sub_pc_type")? {
        return Ok(());
    }
    let null = std::ptr::null_mut();
    let name = c_string(
        &format!("-{}sub_pc_type", prefix.to_string_lossy()),
        "the options prefix",
    )?;
    // SAFETY: as above; PETSc copies the strings.
    check(
        unsafe { ffi::PetscOptionsSetValue(null, name.as_ptr(), c"lu".as_ptr()) },
        "PetscOptionsSetValue",
    )
}

/// Options from the command line (`--petsc-options`) for every PETSc solver made after this
/// call; they are applied after the scene's `petsc_options`, so they override them.
pub fn set_command_line_options(options: &str) {
    *COMMAND_LINE.lock().unwrap_or_else(|e| e.into_inner()) = options.to_string();
}

/// Records PETSc's message for the error being raised (its first report; the ones that follow
/// up the call stack repeat it). Installed with `PetscPushErrorHandler`, so PETSc prints nothing.
unsafe extern "C" fn record_error(
    _comm: ffi::MPI_Comm,
    _line: c_int,
    function: *const c_char,
    _file: *const c_char,
    code: ffi::PetscErrorCode,
    kind: ffi::PetscErrorType,
    message: *const c_char,
    _context: *mut c_void,
) -> ffi::PetscErrorCode {
    if kind == ffi::PETSC_ERROR_INITIAL {
        let text = |p: *const c_char| {
            if p.is_null() {
                String::new()
            } else {
                // SAFETY: PETSc passes NUL-terminated strings that live during the call.
                unsafe { CStr::from_ptr(p) }
                    .to_string_lossy()
                    .trim()
                    .to_string()
            }
        };
        if let Ok(mut last) = LAST_ERROR.lock() {
            *last = format!("{} (in {})", text(message), text(function));
        }
    }
    code
}

/// `Ok` for PETSc's success code, otherwise an error naming `function`, the code's meaning and
/// PETSc's message.
fn check(code: ffi::PetscErrorCode, function: &str) -> Result<(), LinearSolveError> {
    if code == 0 {
        return Ok(());
    }
    let mut meaning: *const c_char = std::ptr::null();
    // SAFETY: PetscErrorMessage writes a pointer to a static string (or leaves it null).
    let _ = unsafe { ffi::PetscErrorMessage(code, &mut meaning, std::ptr::null_mut()) };
    let meaning = if meaning.is_null() {
        String::from("unknown error")
    } else {
        // SAFETY: a NUL-terminated static string of PETSc's.
        unsafe { CStr::from_ptr(meaning) }
            .to_string_lossy()
            .into_owned()
    };
    let detail = std::mem::take(&mut *LAST_ERROR.lock().unwrap_or_else(|e| e.into_inner()));
    Err(LinearSolveError::Backend(format!(
        "PETSc's {function} failed with error {code} ({meaning}){}",
        if detail.is_empty() {
            String::new()
        } else {
            format!(": {detail}")
        }
    )))
}

/// A C string for PETSc, or an error naming what held a NUL byte.
fn c_string(text: &str, what: &str) -> Result<CString, LinearSolveError> {
    CString::new(text).map_err(|_| {
        LinearSolveError::Backend(format!("{what} contains a NUL character: {text:?}"))
    })
}

/// Takes the process-wide PETSc lock, initialising PETSc the first time.
fn session() -> Result<MutexGuard<'static, ()>, LinearSolveError> {
    let guard = PETSC.lock().unwrap_or_else(|e| e.into_inner());
    let initialised = INITIALISED.get_or_init(|| {
        let null = std::ptr::null_mut();
        // SAFETY: setting an option before PetscInitialize is allowed; the strings are static.
        let run = || unsafe {
            check(
                ffi::PetscOptionsSetValue(null, c"-no_signal_handler".as_ptr(), std::ptr::null()),
                "PetscOptionsSetValue",
            )?;
            check(
                ffi::PetscInitializeNoArguments(),
                "PetscInitializeNoArguments",
            )?;
            check(
                ffi::PetscPushErrorHandler(record_error, null.cast()),
                "PetscPushErrorHandler",
            )
        };
        run().map_err(|e| e.to_string())
    });
    match initialised {
        Ok(()) => Ok(guard),
        Err(why) => Err(LinearSolveError::Backend(format!(
            "PETSc could not be initialised: {why}"
        ))),
    }
}

/// Fails when options under `prefix` were not used by PETSc in the first solve (a misspelled
/// name, an option of a method not chosen, or one that is not a KSP or PC option): PETSc itself
/// ignores them silently. The caller holds the session.
fn refuse_unused_options(prefix: &CStr) -> Result<(), LinearSolveError> {
    let null = std::ptr::null_mut();
    let (mut count, mut names, mut values) = (0, std::ptr::null_mut(), std::ptr::null_mut());
    // SAFETY: PETSc fills the count and two arrays of `count` strings, given back by
    // PetscOptionsLeftRestore.
    check(
        unsafe { ffi::PetscOptionsLeftGet(null, &mut count, &mut names, &mut values) },
        "PetscOptionsLeftGet",
    )?;
    let prefix = prefix.to_string_lossy();
    let mut unused = Vec::new();
    for i in 0..count.max(0) as usize {
        // SAFETY: `names` holds `count` NUL-terminated strings.
        let name = unsafe { CStr::from_ptr(*names.add(i)) }.to_string_lossy();
        if let Some(option) = name.trim_start_matches('-').strip_prefix(prefix.as_ref()) {
            unused.push(format!("-{option}"));
        }
    }
    // SAFETY: gives back what PetscOptionsLeftGet lent.
    check(
        unsafe { ffi::PetscOptionsLeftRestore(null, &mut count, &mut names, &mut values) },
        "PetscOptionsLeftRestore",
    )?;
    if unused.is_empty() {
        return Ok(());
    }
    Err(LinearSolveError::Backend(format!(
        "PETSc did not use the option(s) {} of petsc_options / --petsc-options: misspelled, \
         meant for a method not chosen, or not an option of the linear solver (KSP and PC \
         options only)",
        unused.join(" ")
    )))
}

/// The linear solver over PETSc's KSP (see the module docs).
pub struct PetscSolver {
    /// The scene's options string (PETSc's command-line syntax).
    options: String,
    /// This solver's options prefix (`impm3_`), once its options are in the database.
    prefix: Option<CString>,
    /// Relative tolerance of a solve (PETSc's `-ksp_rtol` once the options are read).
    tolerance: f64,
    /// A looser tolerance for the next solve only (inexact Newton).
    requested: Option<f64>,
    last_iterations: usize,
    objects: Option<UnderLock<Objects>>,
    /// Whether PETSc's use of this solver's options was checked (after its first solve).
    options_checked: bool,
    /// Whether the solver went over to the fallback after its default method failed (kept
    /// for the rest of the run; see the module docs).
    fallen_back: bool,
    /// The warning of that change, until the run takes it (`LinearSolver::take_notice`).
    notice: Option<String>,
    /// Whether the solver works over every process of a distributed run (made by
    /// [`PetscSolver::distributed`]), and its objects there.
    #[cfg(feature = "mpi")]
    distributed: bool,
    #[cfg(feature = "mpi")]
    distributed_objects: Option<UnderLock<distributed::DistributedObjects>>,
    /// The decomposed grid's global block numbers (`impm run --decompose`): the tangent
    /// passed is this process's local system, numbered by its own DOF stage.
    #[cfg(feature = "mpi")]
    global_blocks: Option<distributed::SharedBlocks>,
}

impl PetscSolver {
    /// A solver with `options` in PETSc's syntax, e.g. `-ksp_type cg -pc_type gamg`.
    pub fn new(options: &str) -> Self {
        Self {
            options: options.to_string(),
            prefix: None,
            tolerance: DEFAULT_TOLERANCE,
            requested: None,
            last_iterations: 0,
            objects: None,
            options_checked: false,
            fallen_back: false,
            notice: None,
            #[cfg(feature = "mpi")]
            distributed: false,
            #[cfg(feature = "mpi")]
            distributed_objects: None,
            #[cfg(feature = "mpi")]
            global_blocks: None,
        }
    }

    /// The options prefix of this solver, inserting its options (the scene's, then the
    /// command line's) into PETSc's database under it the first time.
    fn prefix(&mut self) -> Result<CString, LinearSolveError> {
        if let Some(prefix) = &self.prefix {
            return Ok(prefix.clone());
        }
        let prefix = format!("impm{}_", NEXT_PREFIX.fetch_add(1, Ordering::Relaxed));
        let prefix = c_string(&prefix, "the options prefix")?;
        let command_line = COMMAND_LINE
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        let scene = c_string(&self.options, "petsc_options")?;
        let command_line = c_string(&command_line, "--petsc-options")?;
        let null = std::ptr::null_mut();
        // SAFETY: PETSc is initialised (the caller holds the session); the strings live
        // through the calls.
        unsafe {
            check(
                ffi::PetscOptionsPrefixPush(null, prefix.as_ptr()),
                "PetscOptionsPrefixPush",
            )?;
            let inserted = check(
                ffi::PetscOptionsInsertString(null, scene.as_ptr()),
                "PetscOptionsInsertString (the scene's petsc_options)",
            )
            .and_then(|()| {
                check(
                    ffi::PetscOptionsInsertString(null, command_line.as_ptr()),
                    "PetscOptionsInsertString (--petsc-options)",
                )
            });
            check(ffi::PetscOptionsPrefixPop(null), "PetscOptionsPrefixPop")?;
            inserted?;
        }
        self.prefix = Some(prefix.clone());
        Ok(prefix)
    }
}

impl Drop for PetscSolver {
    fn drop(&mut self) {
        if let Some(objects) = self.objects.take() {
            let _session = PETSC.lock().unwrap_or_else(|e| e.into_inner());
            objects.0.destroy();
        }
        #[cfg(feature = "mpi")]
        if let Some(objects) = self.distributed_objects.take() {
            let _session = PETSC.lock().unwrap_or_else(|e| e.into_inner());
            objects.0.destroy();
        }
    }
}

/// The padded system's pattern and where its values come from (see the module docs).
struct Padding {
    /// Unknowns of the padded system.
    size: usize,
    /// Block size: `D` when padded, else 1.
    block: usize,
    /// The padded index of each DOF.
    of_dof: Vec<usize>,
    /// CSR row starts and columns of the padded system.
    row_start: Vec<PetscInt>,
    columns: Vec<PetscInt>,
    /// For each CSR entry, the index into the [`SparseMatrix`] values, or [`IDENTITY`].
    source: Vec<usize>,
    /// The values' indices of `K`'s diagonal.
    diagonal: Vec<usize>,
    /// Node coordinates, `block` per node, when the layout has positions.
    coordinates: Option<Vec<f64>>,
}

/// A padded row's diagonal entry (`s` of the module docs).
const IDENTITY: usize = usize::MAX;

impl Padding {
    fn new(matrix: &SparseMatrix) -> Result<Self, LinearSolveError> {
        let n = matrix.size();
        let layout = matrix.layout();
        let blocks = layout.block_start.len().saturating_sub(1);
        let padded = n > 0
            && layout.dimension > 0
            && layout.component.len() == n
            && layout.block_start.last() == Some(&n);
        let (block, size, of_dof, coordinates) = if padded {
            let d = layout.dimension;
            // the DOFs of block b are block_start[b]..block_start[b + 1], node-major
            let mut of_dof = Vec::with_capacity(n);
            for (b, range) in layout.block_start.windows(2).enumerate() {
                let components = &layout.component[range[0]..range[1]];
                of_dof.extend(components.iter().map(|&c| b * d + c as usize));
            }
            let coordinates = (layout.position.len() == blocks).then(|| {
                layout
                    .position
                    .iter()
                    .flat_map(|x| x[..d].to_vec())
                    .collect()
            });
            (d, blocks * d, of_dof, coordinates)
        } else {
            (1, n, (0..n).collect(), None)
        };
        // K's rows (a transpose of the CSC pattern: columns in increasing order per row)
        let (col_ptr, row_idx) = matrix.pattern();
        let mut row_count = vec![0usize; n + 1];
        for &row in row_idx {
            row_count[row + 1] += 1;
        }
        for i in 0..n {
            row_count[i + 1] += row_count[i];
        }
        let mut fill = row_count.clone();
        let mut entries = vec![(0usize, 0usize); row_idx.len()];
        for col in 0..n {
            for (k, &row) in row_idx
                .iter()
                .enumerate()
                .take(col_ptr[col + 1])
                .skip(col_ptr[col])
            {
                entries[fill[row]] = (col, k);
                fill[row] += 1;
            }
        }
        let mut dof_of = vec![usize::MAX; size];
        for (dof, &p) in of_dof.iter().enumerate() {
            dof_of[p] = dof;
        }
        let index = |i: usize| {
            PetscInt::try_from(i).map_err(|_| {
                LinearSolveError::Backend(format!(
                    "the system has {i} entries, more than PETSc's PetscInt holds"
                ))
            })
        };
        let mut padding = Self {
            size,
            block,
            of_dof,
            row_start: vec![0],
            columns: Vec::with_capacity(row_idx.len() + size - n),
            source: Vec::with_capacity(row_idx.len() + size - n),
            diagonal: Vec::with_capacity(n),
            coordinates,
        };
        for (p, &dof) in dof_of.iter().enumerate() {
            if dof == usize::MAX {
                padding.columns.push(index(p)?);
                padding.source.push(IDENTITY);
            } else {
                for &(col, k) in &entries[row_count[dof]..row_count[dof + 1]] {
                    padding.columns.push(index(padding.of_dof[col])?);
                    padding.source.push(k);
                    if col == dof {
                        padding.diagonal.push(k);
                    }
                }
            }
            padding.row_start.push(index(padding.columns.len())?);
        }
        Ok(padding)
    }

    /// The padded matrix's values from `K`'s.
    fn fill(&self, values: &[f64], padded: &mut [f64]) {
        let mean = self.diagonal.iter().map(|&k| values[k].abs()).sum::<f64>()
            / self.diagonal.len().max(1) as f64;
        let scale = if mean > 0.0 && mean.is_finite() {
            mean
        } else {
            1.0
        };
        for (value, &k) in padded.iter_mut().zip(&self.source) {
            *value = if k == IDENTITY { scale } else { values[k] };
        }
    }
}

/// The communicator of a backend's objects: one process (`PETSC_COMM_SELF`, sequential
/// objects) or every process of a distributed run (`MPI_COMM_WORLD`, MPI objects).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Comm {
    Serial,
    #[cfg(feature = "mpi")]
    World,
}

impl Comm {
    fn raw(self) -> ffi::MPI_Comm {
        match self {
            Comm::Serial => ffi::comm_self(),
            #[cfg(feature = "mpi")]
            Comm::World => ffi::comm_world(),
        }
    }
}

/// Configures a created KSP over `matrix`: CG (symmetric) or GMRES with GAMG, the default
/// tolerances, then the options under `prefix`, and the true-residual norm
/// ([`measure_the_true_residual`]). Returns the method ("cg+gamg") and the relative tolerance
/// the options left.
///
/// # Safety
/// The session is held; `ksp` and `matrix` are created objects.
unsafe fn configure_ksp(
    ksp: ffi::KSP,
    matrix: ffi::Mat,
    symmetric: bool,
    prefix: &CStr,
    method: Method,
) -> Result<(String, f64), LinearSolveError> {
    // SAFETY: as the caller promises; every out-pointer is valid.
    unsafe {
        check(ffi::KSPSetOperators(ksp, matrix, matrix), "KSPSetOperators")?;
        let (kind, preconditioner) = match method {
            Method::Default if symmetric => (c"cg", c"gamg"),
            Method::Default => (c"gmres", c"gamg"),
            Method::Fallback => (c"gmres", FALLBACK_PC),
        };
        check(ffi::KSPSetType(ksp, kind.as_ptr()), "KSPSetType")?;
        let mut pc = std::ptr::null_mut();
        check(ffi::KSPGetPC(ksp, &mut pc), "KSPGetPC")?;
        check(ffi::PCSetType(pc, preconditioner.as_ptr()), "PCSetType")?;
        if method == Method::Fallback {
            set_fallback_options(prefix)?;
        }
        check(
            ffi::KSPSetTolerances(
                ksp,
                DEFAULT_TOLERANCE,
                f64::from(ffi::PETSC_DEFAULT),
                f64::from(ffi::PETSC_DEFAULT),
                DEFAULT_MAX_ITERATIONS as PetscInt,
            ),
            "KSPSetTolerances",
        )?;
        check(
            ffi::KSPSetOptionsPrefix(ksp, prefix.as_ptr()),
            "KSPSetOptionsPrefix",
        )?;
        check(ffi::KSPSetFromOptions(ksp), "KSPSetFromOptions")?;
        measure_the_true_residual(ksp, prefix)?;
        let (mut ksp_type, mut pc_type) = (std::ptr::null(), std::ptr::null());
        check(ffi::KSPGetType(ksp, &mut ksp_type), "KSPGetType")?;
        check(ffi::KSPGetPC(ksp, &mut pc), "KSPGetPC")?;
        check(ffi::PCGetType(pc, &mut pc_type), "PCGetType")?;
        let name = |p: *const c_char| {
            if p.is_null() {
                "?".to_string()
            } else {
                CStr::from_ptr(p).to_string_lossy().into_owned()
            }
        };
        let method = format!("{}+{}", name(ksp_type), name(pc_type));
        let (mut relative, mut absolute, mut divergence, mut iterations) = (0.0, 0.0, 0.0, 0);
        check(
            ffi::KSPGetTolerances(
                ksp,
                &mut relative,
                &mut absolute,
                &mut divergence,
                &mut iterations,
            ),
            "KSPGetTolerances",
        )?;
        Ok((method, relative))
    }
}

/// The rigid-body modes of the nodes at `coordinates` (`block` per node; this process's
/// nodes of a distributed matrix) as `matrix`'s near-null space.
///
/// # Safety
/// The session is held and `matrix` is a created matrix on `comm`.
unsafe fn set_rigid_body_modes(
    matrix: ffi::Mat,
    block: usize,
    coordinates: &[f64],
    comm: Comm,
) -> Result<(), LinearSolveError> {
    let mut vector = std::ptr::null_mut();
    let mut space = std::ptr::null_mut();
    let length = coordinates.len() as PetscInt;
    // SAFETY: as the caller promises; the array is written within its length.
    let result = unsafe {
        (|| {
            match comm {
                Comm::Serial => check(
                    ffi::VecCreateSeq(comm.raw(), length, &mut vector),
                    "VecCreateSeq",
                )?,
                #[cfg(feature = "mpi")]
                Comm::World => check(
                    ffi::VecCreateMPI(comm.raw(), length, ffi::PETSC_DECIDE, &mut vector),
                    "VecCreateMPI",
                )?,
            }
            check(
                ffi::VecSetBlockSize(vector, block as PetscInt),
                "VecSetBlockSize",
            )?;
            let mut array = std::ptr::null_mut();
            check(ffi::VecGetArray(vector, &mut array), "VecGetArray")?;
            std::slice::from_raw_parts_mut(array, coordinates.len()).copy_from_slice(coordinates);
            check(ffi::VecRestoreArray(vector, &mut array), "VecRestoreArray")?;
            check(
                ffi::MatNullSpaceCreateRigidBody(vector, &mut space),
                "MatNullSpaceCreateRigidBody",
            )?;
            check(
                ffi::MatSetNearNullSpace(matrix, space),
                "MatSetNearNullSpace",
            )
        })()
    };
    // SAFETY: destroying what was created (null handles are ignored by PETSc); the matrix
    // keeps its own reference to the null space.
    unsafe {
        ffi::MatNullSpaceDestroy(&mut space);
        ffi::VecDestroy(&mut vector);
    }
    result
}

/// Makes CG, GMRES and BiCGSTAB stop on the unpreconditioned residual `‖r − K δ‖`, as the
/// built-in solvers do (GMRES and BiCGSTAB then precondition from the right), unless the
/// options chose the norm or the side themselves; other methods keep PETSc's defaults.
///
/// # Safety
/// The session is held and `ksp` is a created KSP.
unsafe fn measure_the_true_residual(ksp: ffi::KSP, prefix: &CStr) -> Result<(), LinearSolveError> {
    let given = |name: &CStr| option_given(prefix, name);
    if given(c"-ksp_norm_type")? {
        return Ok(());
    }
    let mut kind = std::ptr::null();
    // SAFETY: as the caller promises.
    check(unsafe { ffi::KSPGetType(ksp, &mut kind) }, "KSPGetType")?;
    let kind = if kind.is_null() {
        String::new()
    } else {
        // SAFETY: PETSc's NUL-terminated type name.
        unsafe { CStr::from_ptr(kind) }
            .to_string_lossy()
            .into_owned()
    };
    let right = match kind.as_str() {
        "cg" => false,
        "gmres" | "fgmres" | "bcgs" if !given(c"-ksp_pc_side")? => true,
        _ => return Ok(()),
    };
    // SAFETY: as the caller promises.
    unsafe {
        if right {
            check(ffi::KSPSetPCSide(ksp, ffi::PC_RIGHT), "KSPSetPCSide")?;
        }
        check(
            ffi::KSPSetNormType(ksp, ffi::KSP_NORM_UNPRECONDITIONED),
            "KSPSetNormType",
        )
    }
}

/// Solves with a configured KSP to the relative tolerance `tolerance`; PETSc's iteration
/// count, or why the solve failed (PETSc's reason; `method` names the KSP and PC).
///
/// # Safety
/// The session is held; the objects are created and fit each other.
unsafe fn solve_with_ksp(
    ksp: ffi::KSP,
    rhs: ffi::Vec,
    solution: ffi::Vec,
    tolerance: f64,
    method: &str,
) -> Result<usize, LinearSolveError> {
    // SAFETY: as the caller promises; every out-pointer is valid.
    unsafe {
        check(
            ffi::KSPSetTolerances(
                ksp,
                tolerance,
                f64::from(ffi::PETSC_DEFAULT),
                f64::from(ffi::PETSC_DEFAULT),
                ffi::PETSC_DEFAULT as PetscInt,
            ),
            "KSPSetTolerances",
        )?;
        check(ffi::KSPSolve(ksp, rhs, solution), "KSPSolve")?;
        let (mut reason, mut iterations) = (0, 0);
        check(
            ffi::KSPGetConvergedReason(ksp, &mut reason),
            "KSPGetConvergedReason",
        )?;
        check(
            ffi::KSPGetIterationNumber(ksp, &mut iterations),
            "KSPGetIterationNumber",
        )?;
        if reason < 0 {
            let mut text = std::ptr::null();
            check(
                ffi::KSPGetConvergedReasonString(ksp, &mut text),
                "KSPGetConvergedReasonString",
            )?;
            let text = if text.is_null() {
                format!("reason {reason}")
            } else {
                CStr::from_ptr(text).to_string_lossy().into_owned()
            };
            return Err(LinearSolveError::NotConverged(format!(
                "PETSc's {} solve did not converge: {text} (KSPConvergedReason {reason}) \
                     after {iterations} iterations, relative tolerance {tolerance:.0e}; change \
                     petsc_options or use solver(#{{ linear: \"direct\" }})",
                method
            )));
        }
        Ok(iterations.max(0) as usize)
    }
}

/// PETSc objects built for one pattern of `K` (the serial [`Objects`], the distributed
/// `DistributedObjects`): kept through a load step, rebuilt when the pattern or the symmetry
/// changes ([`objects_for`]).
trait PatternObjects: Sized {
    /// The pattern generation and symmetry they were built for.
    fn built_for(&self) -> BuiltFor;
    /// Destroys the PETSc objects (collective for distributed ones). The caller holds the
    /// session.
    fn destroy(self);
}

/// What PETSc objects were built for: a pattern generation of `K` and its symmetry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct BuiltFor {
    generation: u64,
    symmetric: bool,
}

impl BuiltFor {
    fn of(matrix: &SparseMatrix, symmetric: bool) -> Self {
        Self {
            generation: matrix.generation(),
            symmetric,
        }
    }
}

/// PETSc objects a solver keeps between solves.
struct UnderLock<T>(T);

// SAFETY: the PETSc objects are only touched under the process-wide lock `PETSC`, from one
// thread at a time (a `&UnderLock` gives no access to PETSc without it).
unsafe impl<T> Send for UnderLock<T> {}
// SAFETY: as for Send.
unsafe impl<T> Sync for UnderLock<T> {}

/// The objects in `slot` for `matrix`'s pattern and `symmetric`: the ones there if they were
/// built for it, else new ones from `build` (the old ones destroyed first); and whether they
/// are new. The caller holds the session.
fn objects_for<'s, T: PatternObjects>(
    slot: &'s mut Option<UnderLock<T>>,
    matrix: &SparseMatrix,
    symmetric: bool,
    build: impl FnOnce() -> Result<T, LinearSolveError>,
) -> Result<(&'s mut T, bool), LinearSolveError> {
    let wanted = BuiltFor::of(matrix, symmetric);
    let fresh = slot.as_ref().is_none_or(|o| o.0.built_for() != wanted);
    if fresh && let Some(old) = slot.take() {
        old.0.destroy();
    }
    let objects = match slot.take() {
        Some(objects) => objects,
        None => UnderLock(build()?),
    };
    Ok((&mut slot.insert(objects).0, fresh))
}

/// The PETSc objects of one pattern.
struct Objects {
    built_for: BuiltFor,
    padding: Padding,
    matrix: ffi::Mat,
    rhs: ffi::Vec,
    solution: ffi::Vec,
    ksp: ffi::KSP,
    /// The KSP and PC types after the options ("cg+gamg"), for messages.
    method: String,
}

impl PatternObjects for Objects {
    fn built_for(&self) -> BuiltFor {
        self.built_for
    }

    fn destroy(mut self) {
        // SAFETY: PETSc ignores null handles; each object is destroyed once.
        unsafe {
            ffi::KSPDestroy(&mut self.ksp);
            ffi::VecDestroy(&mut self.solution);
            ffi::VecDestroy(&mut self.rhs);
            ffi::MatDestroy(&mut self.matrix);
        }
    }
}

impl Objects {
    /// Creates the matrix with `matrix`'s values, the vectors, the near-null space and the KSP
    /// configured by the options under `prefix`. The caller holds the session.
    fn new(
        matrix: &SparseMatrix,
        symmetric: bool,
        prefix: &CStr,
        method: Method,
    ) -> Result<(Self, f64), LinearSolveError> {
        let padding = Padding::new(matrix)?;
        let mut objects = Self {
            built_for: BuiltFor::of(matrix, symmetric),
            matrix: std::ptr::null_mut(),
            rhs: std::ptr::null_mut(),
            solution: std::ptr::null_mut(),
            ksp: std::ptr::null_mut(),
            method: String::new(),
            padding,
        };
        match objects.create(matrix, prefix, method) {
            Ok(tolerance) => Ok((objects, tolerance)),
            Err(e) => {
                objects.destroy();
                Err(e)
            }
        }
    }

    /// The PETSc calls of [`Objects::new`]; returns the relative tolerance the options set.
    fn create(
        &mut self,
        matrix: &SparseMatrix,
        prefix: &CStr,
        method: Method,
    ) -> Result<f64, LinearSolveError> {
        let padding = &self.padding;
        let size = padding.size as PetscInt;
        let comm = Comm::Serial.raw();
        let mut values = vec![0.0; padding.source.len()];
        padding.fill(matrix.values(), &mut values);
        // SAFETY: PETSc is initialised and the session held; every pointer passed is valid for
        // the call (the CSR arrays are copied by MatSeqAIJSetPreallocationCSR).
        unsafe {
            check(ffi::MatCreate(comm, &mut self.matrix), "MatCreate")?;
            check(
                ffi::MatSetSizes(self.matrix, size, size, size, size),
                "MatSetSizes",
            )?;
            check(
                ffi::MatSetBlockSize(self.matrix, padding.block as PetscInt),
                "MatSetBlockSize",
            )?;
            check(
                ffi::MatSetType(self.matrix, c"seqaij".as_ptr()),
                "MatSetType",
            )?;
            check(
                ffi::MatSeqAIJSetPreallocationCSR(
                    self.matrix,
                    padding.row_start.as_ptr(),
                    padding.columns.as_ptr(),
                    values.as_ptr(),
                ),
                "MatSeqAIJSetPreallocationCSR",
            )?;
            if let Some(coordinates) = &padding.coordinates {
                set_rigid_body_modes(self.matrix, padding.block, coordinates, Comm::Serial)?;
            }
            check(ffi::VecCreateSeq(comm, size, &mut self.rhs), "VecCreateSeq")?;
            check(
                ffi::VecCreateSeq(comm, size, &mut self.solution),
                "VecCreateSeq",
            )?;
            check(ffi::KSPCreate(comm, &mut self.ksp), "KSPCreate")?;
            let symmetric = self.built_for.symmetric;
            let (method, relative) =
                configure_ksp(self.ksp, self.matrix, symmetric, prefix, method)?;
            self.method = method;
            Ok(relative)
        }
    }

    /// Copies `matrix`'s values into the PETSc matrix.
    fn set_values(&mut self, matrix: &SparseMatrix) -> Result<(), LinearSolveError> {
        let mut array = std::ptr::null_mut();
        // SAFETY: the session is held; the array has one value per CSR entry.
        unsafe {
            check(
                ffi::MatSeqAIJGetArray(self.matrix, &mut array),
                "MatSeqAIJGetArray",
            )?;
            let padded = std::slice::from_raw_parts_mut(array, self.padding.source.len());
            self.padding.fill(matrix.values(), padded);
            check(
                ffi::MatSeqAIJRestoreArray(self.matrix, &mut array),
                "MatSeqAIJRestoreArray",
            )
        }
    }

    /// Solves for `rhs` (in place) to the relative tolerance `tolerance`; returns PETSc's
    /// iteration count.
    fn solve(&mut self, rhs: &mut [f64], tolerance: f64) -> Result<usize, LinearSolveError> {
        let padding = &self.padding;
        let mut array = std::ptr::null_mut();
        // SAFETY: the session is held; the vectors have `padding.size` entries.
        unsafe {
            check(ffi::VecGetArray(self.rhs, &mut array), "VecGetArray")?;
            let padded = std::slice::from_raw_parts_mut(array, padding.size);
            padded.fill(0.0);
            for (&p, &r) in padding.of_dof.iter().zip(rhs.iter()) {
                padded[p] = r;
            }
            check(
                ffi::VecRestoreArray(self.rhs, &mut array),
                "VecRestoreArray",
            )?;
            let iterations =
                solve_with_ksp(self.ksp, self.rhs, self.solution, tolerance, &self.method)?;
            check(ffi::VecGetArray(self.solution, &mut array), "VecGetArray")?;
            let padded = std::slice::from_raw_parts(array, padding.size);
            for (&p, r) in padding.of_dof.iter().zip(rhs.iter_mut()) {
                *r = padded[p];
            }
            check(
                ffi::VecRestoreArray(self.solution, &mut array),
                "VecRestoreArray",
            )?;
            Ok(iterations)
        }
    }
}

impl PetscSolver {
    /// The method the solver's objects are built with: the default until it fell back.
    fn method(&self) -> Method {
        if self.fallen_back {
            Method::Fallback
        } else {
            Method::Default
        }
    }

    /// One solve with the current method, on every process of a distributed solver.
    fn solve_once(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        rhs: &mut [f64],
    ) -> Result<SolverKind, LinearSolveError> {
        #[cfg(feature = "mpi")]
        if self.distributed {
            return self.solve_distributed(matrix, symmetric, rhs);
        }
        self.solve_serial(matrix, symmetric, rhs)
    }

    /// Whether the options (the scene's or the command line's) choose the Krylov method or the
    /// preconditioner (`-ksp_type`, `-pc_type`): then the solver never falls back.
    fn method_chosen(&mut self) -> Result<bool, LinearSolveError> {
        let _session = session()?;
        let prefix = self.prefix()?;
        for name in [c"-ksp_type", c"-pc_type"] {
            if option_given(&prefix, name)? {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Goes over to the fallback for the rest of the run after the default failed with
    /// `why`: the objects are destroyed (collectively for a distributed solver: every process
    /// decides alike, see the module docs), to be built anew with the fallback by the next
    /// solve, and the warning is kept for the run.
    fn fall_back(&mut self, why: &str) {
        {
            let _session = PETSC.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(objects) = self.objects.take() {
                objects.0.destroy();
            }
            #[cfg(feature = "mpi")]
            if let Some(objects) = self.distributed_objects.take() {
                objects.0.destroy();
            }
        }
        self.fallen_back = true;
        // the failure's own advice (change the options) is what the fallback does
        let why = why.split("; change petsc_options").next().unwrap_or(why);
        self.notice = Some(format!(
            "PETSc's default method failed: {why}; the system is solved again, and the rest of \
             the run's, with the fallback {FALLBACK_NAME} (choose the method with -ksp_type / \
             -pc_type in petsc_options or --petsc-options to keep it from falling back)"
        ));
    }

    /// `LinearSolver::solve` of the serial solver, with the current method.
    fn solve_serial(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        rhs: &mut [f64],
    ) -> Result<SolverKind, LinearSolveError> {
        let _session = session()?;
        let prefix = self.prefix()?;
        let method = self.method();
        let (objects, fresh) = objects_for(&mut self.objects, matrix, symmetric, || {
            let (objects, tolerance) = Objects::new(matrix, symmetric, &prefix, method)?;
            self.tolerance = tolerance;
            Ok(objects)
        })?;
        if !fresh {
            objects.set_values(matrix)?;
        }
        let tolerance = self
            .requested
            .take()
            .map_or(self.tolerance, |r| r.max(self.tolerance));
        let original = rhs.to_vec();
        let solved = objects.solve(rhs, tolerance);
        if !self.options_checked {
            self.options_checked = true;
            if let Some(prefix) = &self.prefix {
                refuse_unused_options(prefix)?;
            }
        }
        self.last_iterations = solved?;
        // the true residual, whatever norm PETSc's options made it measure
        let mut product = vec![0.0; rhs.len()];
        let relative = true_relative_residual(matrix, &original, rhs, &mut product);
        let converged = relative <= 10.0 * tolerance; // false for NaN
        if !converged {
            return Err(LinearSolveError::NotConverged(format!(
                "PETSc's {} solve reported convergence but its true residual is {:.2e} of the \
                 right-hand side against a tolerance of {tolerance:.0e}; change petsc_options \
                 or use solver(#{{ linear: \"direct\" }})",
                objects.method, relative
            )));
        }
        Ok(SolverKind::Petsc)
    }
}

impl PetscSolver {
    /// Whether `local` holds on any process of a distributed solver (collective: every process
    /// of a distributed solver calls it alike, as they solve together), or here serially.
    fn on_any_process(&self, local: bool) -> bool {
        #[cfg(feature = "mpi")]
        if self.distributed {
            return crate::distributed::any(local);
        }
        local
    }
}

impl LinearSolver for PetscSolver {
    /// Solves with the current method; when the default fails to converge (PETSc's reason, or
    /// the true-residual check) and the options did not choose the method, falls back (see
    /// the module docs) and solves the same system again.
    fn solve(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        rhs: &mut [f64],
    ) -> Result<SolverKind, LinearSolveError> {
        // Both tests are collective (a process of a decomposed grid holds its local rows only):
        // every process returns alike, or every process solves.
        let bad = rhs.iter().position(|v| !v.is_finite());
        if self.on_any_process(bad.is_some()) {
            return Err(LinearSolveError::Backend(match bad {
                Some(bad) => format!("the right-hand side is not finite at DOF {bad}"),
                None => "the right-hand side is not finite on another process".to_string(),
            }));
        }
        if !self.on_any_process(rhs.iter().any(|&v| v != 0.0)) {
            // K δ = 0: δ = 0, without a solve (the true-residual check would divide by
            // ‖r‖ = 0; the arc's first residual at λ = 0 is zero)
            self.requested = None;
            self.last_iterations = 0;
            return Ok(SolverKind::Petsc);
        }
        let (original, requested) = (rhs.to_vec(), self.requested);
        match self.solve_once(matrix, symmetric, rhs) {
            Err(LinearSolveError::NotConverged(why))
                if !self.fallen_back && !self.method_chosen()? =>
            {
                self.fall_back(&why);
                rhs.copy_from_slice(&original);
                self.requested = requested;
                self.solve_once(matrix, symmetric, rhs)
            }
            solved => solved,
        }
    }

    fn take_notice(&mut self) -> Option<String> {
        self.notice.take()
    }

    fn last_iterations(&self) -> Option<usize> {
        Some(self.last_iterations)
    }

    fn tolerance(&self) -> Option<f64> {
        Some(self.tolerance)
    }

    fn request_tolerance(&mut self, relative: f64) {
        self.requested = Some(relative);
    }
}
