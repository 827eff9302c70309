//! `linear: "auto"`: the backend chosen per solve from the system's dimension and size, by the
//! crossover measured with `examples/solver_crossover.rs` (docs/performance.md, "Linear
//! solvers"; B-spline q = 2 blocks, 2 points per cell and direction, one load step):
//!
//! | dimension | DOFs | backend | why (seconds of a step's linear solves) |
//! |---|---|---|---|
//! | 1 | any | direct | a banded tangent: the factorisation is linear in the DOFs |
//! | 2 | < [`MULTIGRID_FROM_2D`] | direct | 52k DOFs: direct 4.2, multigrid 5.0, Jacobi 13.7 |
//! | 2 | ≥ [`MULTIGRID_FROM_2D`] | CG + multigrid | 101k DOFs: multigrid 9.5, direct 13.0 |
//! | 3 | < [`ITERATIVE_FROM_3D`] | direct | 1.1k DOFs: direct 0.12, Jacobi 0.14, multigrid 0.29 |
//! | 3 | ≥ [`ITERATIVE_FROM_3D`] | CG + Jacobi | 3.2k DOFs: Jacobi 1.0, direct 2.2, multigrid 2.7 |
//!
//! In 3D Jacobi stays ahead of multigrid up to the largest size measured (1M points: Jacobi
//! 177 s per step; at 97k points Jacobi 8.3 s against multigrid 11.3 s), because a V-cycle over
//! a 3D q = 2 tangent (up to 375 entries a row) costs about four Jacobi iterations while
//! Jacobi needs only ~100 of them at these sizes. The rule counts DOFs, not points or the basis
//! order: it was measured at q = 2 only (a linear basis has sparser rows, which favours the
//! direct solve a little longer; higher orders the other way).
//!
//! **Never worse than direct in what it answers.** An iterative solve that fails (not
//! converged, a breakdown: the tangents of nearly empty cut cells are beyond what CG can
//! solve, see the multigrid module's known limit) is repeated by the direct solver from the
//! same right-hand side, and the direct solver is kept for the rest of the run; the choice and
//! its reason are what [`LinearSolver::choice`] reports (summary.json's `linear_backend`).

use super::{
    DirectSolver, Hierarchy, KrylovSolver, LinearSolveError, LinearSolver, SolverKind, SparseMatrix,
};

/// 2D systems of at least this many DOFs go to CG with multigrid.
pub const MULTIGRID_FROM_2D: usize = 75_000;

/// 3D systems of at least this many DOFs go to CG with Jacobi.
pub const ITERATIVE_FROM_3D: usize = 2_000;

/// A backend the automatic choice picks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// [`DirectSolver`].
    Direct,
    /// [`KrylovSolver`] with [`super::Jacobi`].
    Jacobi,
    /// [`KrylovSolver`] with [`super::Multigrid`].
    Multigrid,
}

impl Backend {
    /// The scene's words for it.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Direct => "direct",
            Backend::Jacobi => "iterative (jacobi)",
            Backend::Multigrid => "iterative (multigrid)",
        }
    }

    fn solver(self) -> Box<dyn LinearSolver> {
        match self {
            Backend::Direct => Box::new(DirectSolver::default()),
            Backend::Jacobi => Box::new(KrylovSolver::default()),
            Backend::Multigrid => Box::new(KrylovSolver::multigrid()),
        }
    }
}

/// The backend for a system of `dofs` unknowns from a `dimension`-dimensional grid, and why
/// (see the module docs).
pub fn choose(dimension: usize, dofs: usize) -> (Backend, String) {
    let below = |threshold: usize| format!("{dimension}D, {dofs} DOFs < {threshold}");
    let above = |threshold: usize| format!("{dimension}D, {dofs} DOFs ≥ {threshold}");
    match dimension {
        2 if dofs >= MULTIGRID_FROM_2D => (Backend::Multigrid, above(MULTIGRID_FROM_2D)),
        2 => (Backend::Direct, below(MULTIGRID_FROM_2D)),
        3 if dofs >= ITERATIVE_FROM_3D => (Backend::Jacobi, above(ITERATIVE_FROM_3D)),
        3 => (Backend::Direct, below(ITERATIVE_FROM_3D)),
        _ => (Backend::Direct, format!("{dimension}D: a banded tangent")),
    }
}

/// Whether a run should name `choice` (a [`LinearSolver::choice`] of this solver) on its last
/// lines: when it solved iteratively or fell back to the direct solver; a plain direct choice
/// (every small run) is left to summary.json.
pub fn worth_telling(choice: &str) -> bool {
    !choice.starts_with(Backend::Direct.name()) || choice.contains(FELL_BACK)
}

/// The words of a fallback's reason (see [`AutoSolver`]'s `solve`).
const FELL_BACK: &str = " failed (";

/// The solver of `linear: "auto"` (see the module docs).
#[derive(Default)]
pub struct AutoSolver {
    /// The backend in use, its solver, and why it was chosen.
    current: Option<(Backend, Box<dyn LinearSolver>, String)>,
    /// Set when an iterative solve failed: the direct solver from then on, and why.
    fell_back: Option<String>,
    /// An inexact Newton's forcing term for the next solve, passed to an iterative backend.
    requested: Option<f64>,
    /// A copy of the right-hand side, to repeat a failed iterative solve.
    copy: Vec<f64>,
}

impl AutoSolver {
    /// The backend in use after the last solve, and why.
    pub fn backend(&self) -> Option<(Backend, &str)> {
        self.current
            .as_ref()
            .map(|(backend, _, why)| (*backend, why.as_str()))
    }

    /// Makes `backend` the current one (a new solver only when it changes).
    fn use_backend(&mut self, backend: Backend, why: String) -> &mut dyn LinearSolver {
        match &mut self.current {
            Some((current, _, reason)) if *current == backend => *reason = why,
            _ => self.current = Some((backend, backend.solver(), why)),
        }
        match &mut self.current {
            Some((_, solver, _)) => solver.as_mut(),
            None => unreachable!("set just above"),
        }
    }
}

impl LinearSolver for AutoSolver {
    fn solve(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        rhs: &mut [f64],
    ) -> Result<SolverKind, LinearSolveError> {
        let (backend, why) = match &self.fell_back {
            Some(why) => (Backend::Direct, why.clone()),
            None => choose(matrix.layout().dimension, matrix.size()),
        };
        if backend == Backend::Direct {
            self.requested = None;
            return self.use_backend(backend, why).solve(matrix, symmetric, rhs);
        }
        self.copy.clear();
        self.copy.extend_from_slice(rhs);
        let requested = self.requested.take();
        let solver = self.use_backend(backend, why.clone());
        if let Some(relative) = requested {
            solver.request_tolerance(relative);
        }
        match solver.solve(matrix, symmetric, rhs) {
            Ok(kind) => Ok(kind),
            Err(failure) => {
                let why = format!(
                    "{why}, but {}{FELL_BACK}{failure}): the direct solver from then on",
                    backend.name()
                );
                self.fell_back = Some(why.clone());
                rhs.copy_from_slice(&self.copy);
                self.use_backend(Backend::Direct, why)
                    .solve(matrix, symmetric, rhs)
            }
        }
    }

    fn last_iterations(&self) -> Option<usize> {
        self.current.as_ref()?.1.last_iterations()
    }

    /// The backend in use keeps its factor (the direct one) or has none (an iterative one).
    fn solve_with_last_factor(&mut self, rhs: &mut [f64]) -> Option<Result<(), LinearSolveError>> {
        self.current.as_mut()?.1.solve_with_last_factor(rhs)
    }

    fn hierarchy(&self) -> Option<Hierarchy> {
        self.current.as_ref()?.1.hierarchy()
    }

    /// The tolerance of the backend in use (none before the first solve and for the direct
    /// one: an inexact Newton then solves exactly).
    fn tolerance(&self) -> Option<f64> {
        self.current.as_ref()?.1.tolerance()
    }

    fn request_tolerance(&mut self, relative: f64) {
        self.requested = Some(relative);
    }

    fn choice(&self) -> Option<String> {
        self.backend()
            .map(|(backend, why)| format!("{}: {why}", backend.name()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::multiply;

    #[test]
    fn the_rule_follows_the_dimension_and_the_size() {
        assert_eq!(choose(1, 10_000_000).0, Backend::Direct);
        assert_eq!(choose(2, MULTIGRID_FROM_2D - 1).0, Backend::Direct);
        assert_eq!(choose(2, MULTIGRID_FROM_2D).0, Backend::Multigrid);
        assert_eq!(choose(3, ITERATIVE_FROM_3D - 1).0, Backend::Direct);
        assert_eq!(choose(3, ITERATIVE_FROM_3D).0, Backend::Jacobi);
        assert!(choose(3, 5000).1.contains("5000 DOFs ≥ 2000"));
    }

    /// A system from a 3D grid (three DOFs per node) of `3 nodes` DOFs: a chain of springs in
    /// each component, `ground` added to the diagonal (positive: symmetric positive definite;
    /// −3: every eigenvalue in [−3, 1), CG breaks down on the first curvature of a constant
    /// right-hand side, the LU factorisation still solves it).
    fn chain_3d(nodes: usize, ground: f64) -> SparseMatrix {
        let dofs: Vec<[u32; 3]> = (0..nodes)
            .map(|i| std::array::from_fn(|c| (3 * i + c) as u32))
            .collect();
        let supports: Vec<Vec<usize>> = (0..nodes - 1).map(|i| vec![i, i + 1]).collect();
        let mut matrix = SparseMatrix::default();
        matrix.rebuild_pattern(3 * nodes, &dofs[..], supports.iter().map(|s| s.as_slice()));
        for i in 0..nodes - 1 {
            for (&a, &b) in dofs[i].iter().zip(&dofs[i + 1]) {
                matrix.add(a, a, 1.0);
                matrix.add(b, b, 1.0);
                matrix.add(a, b, -1.0);
                matrix.add(b, a, -1.0);
            }
        }
        for dof in 0..3 * nodes {
            matrix.add(dof as u32, dof as u32, ground);
        }
        matrix
    }

    fn residual(matrix: &SparseMatrix, x: &[f64], rhs: &[f64]) -> f64 {
        let mut product = vec![0.0; x.len()];
        multiply(matrix, x, &mut product);
        let norm = |v: &mut dyn Iterator<Item = f64>| v.map(|a| a * a).sum::<f64>().sqrt();
        norm(&mut product.iter().zip(rhs).map(|(p, r)| p - r)) / norm(&mut rhs.iter().copied())
    }

    #[test]
    fn a_large_3d_system_goes_to_cg_and_a_small_one_to_the_direct_solve() {
        for (nodes, expected, kind) in [
            (100, Backend::Direct, SolverKind::Cholesky),
            (
                ITERATIVE_FROM_3D / 3 + 1,
                Backend::Jacobi,
                SolverKind::ConjugateGradients,
            ),
        ] {
            let matrix = chain_3d(nodes, 0.5);
            let n = matrix.size();
            let rhs: Vec<f64> = (0..n).map(|i| ((i * 37) % 11) as f64 - 5.0).collect();
            let mut x = rhs.clone();
            let mut solver = AutoSolver::default();
            assert_eq!(solver.solve(&matrix, true, &mut x), Ok(kind));
            assert_eq!(solver.backend().map(|b| b.0), Some(expected));
            assert!(residual(&matrix, &x, &rhs) < 1e-9);
            let choice = solver.choice().unwrap_or_default();
            assert!(choice.contains(&format!("3D, {n} DOFs")), "{choice}");
            assert_eq!(
                worth_telling(&choice),
                expected != Backend::Direct,
                "{choice}"
            );
        }
    }

    /// A tangent CG cannot solve (indefinite: CG breaks down) is solved by the direct solver
    /// after CG fails, from the original right-hand side; the direct solver is kept, and the
    /// choice says why.
    #[test]
    fn a_failed_iterative_solve_is_repeated_by_the_direct_solver_and_says_so() {
        let matrix = chain_3d(ITERATIVE_FROM_3D / 3 + 1, -3.0);
        let rhs = vec![1.0; matrix.size()];
        let mut solver = AutoSolver::default();
        for _ in 0..2 {
            let mut x = rhs.clone();
            assert_eq!(solver.solve(&matrix, true, &mut x), Ok(SolverKind::Lu));
            assert!(
                residual(&matrix, &x, &rhs) < 1e-10,
                "{}",
                residual(&matrix, &x, &rhs)
            );
            let choice = solver.choice().unwrap_or_default();
            assert!(
                choice.starts_with("direct: 3D") && choice.contains("iterative (jacobi) failed"),
                "{choice}"
            );
            assert!(worth_telling(&choice), "{choice}");
        }
    }
}
