//! The linear-solver layer: the sparse tangent ([`SparseMatrix`]) and the solvers of
//! `K δ = r` behind one interface ([`LinearSolver`]), so that a backend (the faer direct solve
//! today, iterative and distributed ones later) is chosen without touching the stages.
//!
//! The Newton state says whether the tangent is symmetric (hyperelastic materials under dead
//! loads and symmetric penalties keep it so; non-associated plasticity, follower loads,
//! arc-length and F-bar do not): a solver may use a symmetric method (Cholesky, CG) only then.
//! Arc-length control adds one unknown, the load factor: [`LinearSolver::solve_bordered`] solves
//! the bordered system with two solves of `K` by default.
//!
//! Backends: [`DirectSolver`] (faer's sparse Cholesky / LU, the default) and [`KrylovSolver`]
//! (preconditioned CG / BiCGSTAB with a [`Preconditioner`]: [`Jacobi`], or smoothed-aggregation
//! [`Multigrid`] whose iteration count stays nearly flat under refinement); [`AutoSolver`]
//! picks one of them per solve by the dimension and the DOFs (the measured crossover); with the
//! cargo feature `petsc`, `PetscSolver` (PETSc's KSP and preconditioners, GAMG by default).

mod auto;
mod direct;
mod forcing;
mod krylov;
mod matrix;
pub mod modes;
mod multigrid;
#[cfg(feature = "petsc")]
mod petsc;
mod vectors;

pub use auto::{
    AutoSolver, Backend as AutoBackend, ITERATIVE_FROM_3D, MULTIGRID_FROM_2D,
    choose as choose_backend, worth_telling,
};
pub use direct::DirectSolver;
pub use forcing::EisenstatWalker;
pub use krylov::{Jacobi, KrylovSolver, Preconditioner, multiply};
pub use matrix::{DofLayout, NO_DOF, NO_ENTRY, SparseMatrix};
pub use multigrid::{Hierarchy, Multigrid, Smoother};
#[cfg(feature = "mpi")]
pub use petsc::{GlobalBlocks, ProcessSum, SharedBlocks};
#[cfg(feature = "petsc")]
pub use petsc::{PetscSolver, set_command_line_options as set_petsc_command_line_options};

/// Which factorisation solved a system.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SolverKind {
    #[default]
    None,
    Cholesky,
    Lu,
    /// Preconditioned conjugate gradients ([`KrylovSolver`], symmetric tangents).
    ConjugateGradients,
    /// Preconditioned BiCGSTAB ([`KrylovSolver`], non-symmetric tangents).
    BiCgStab,
    /// PETSc's KSP with its preconditioner (`PetscSolver`, feature `petsc`).
    Petsc,
}

/// A failure of the linear solve.
#[derive(Clone, Debug, PartialEq)]
pub enum LinearSolveError {
    /// Every factorisation failed: the tangent is singular (for example a node with no
    /// stiffness, or a mechanism in the constraints).
    Singular(String),
    /// An iterative solve did not reach its tolerance.
    NotConverged(String),
    /// The backend failed for a reason of its own (a PETSc error code, with the function).
    Backend(String),
}

impl std::fmt::Display for LinearSolveError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LinearSolveError::Singular(why) => {
                write!(f, "the tangent stiffness is singular ({why})")
            }
            LinearSolveError::NotConverged(why) | LinearSolveError::Backend(why) => {
                write!(f, "{why}")
            }
        }
    }
}

/// Solves `K x = r` for the tangent of a Newton iteration.
pub trait LinearSolver: Send + Sync {
    /// Solves `matrix x = rhs` in place; `symmetric` says whether `matrix` is symmetric (a
    /// symmetric method may be used only then). Returns how it was solved.
    fn solve(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        rhs: &mut [f64],
    ) -> Result<SolverKind, LinearSolveError>;

    /// Solves `K x = rhs` in place with the factorisation of the last [`solve`](Self::solve)
    /// again (the tangent of the Newton iterate the last correction came from), without
    /// factorising anything: `None` when the solver keeps no factor (an iterative solver, a
    /// solve not yet done, or a `rhs` of another size). The natural level function of the line
    /// search (`stages::line_search`) needs it.
    fn solve_with_last_factor(&mut self, _rhs: &mut [f64]) -> Option<Result<(), LinearSolveError>> {
        None
    }

    /// Iterations of the last solve, for an iterative solver (`None` for a direct one).
    fn last_iterations(&self) -> Option<usize> {
        None
    }

    /// The levels of a multigrid preconditioner after the last solve (`None` without one).
    fn hierarchy(&self) -> Option<Hierarchy> {
        None
    }

    /// Which backend an automatic solver ([`AutoSolver`]) used for the last solve, and why
    /// (`None` for a solver that is one backend).
    fn choice(&self) -> Option<String> {
        None
    }

    /// The relative residual an iterative solver stops at (`None` for a direct one).
    fn tolerance(&self) -> Option<f64> {
        None
    }

    /// What the solver changed on its own that the run should say once (a warning), taken
    /// from it: e.g. the PETSc backend's fallback from its failed default method. `None` when
    /// there is nothing new.
    fn take_notice(&mut self) -> Option<String> {
        None
    }

    /// Lets the next solve stop at the relative residual `relative` (an inexact Newton's
    /// forcing term) if that is looser than the solver's own tolerance; a direct solver ignores
    /// it.
    fn request_tolerance(&mut self, _relative: f64) {}

    /// Solves the bordered system of arc-length control,
    ///
    /// ```text
    ///   [ K   b ] [ x ]   [ r ]
    ///   [ cᵀ  d ] [ y ] = [ s ],
    /// ```
    ///
    /// in place (`r` becomes `x`), returning `y`: with `K x_r = r` and `K x_b = b`,
    /// `y = (s − c·x_r) / (d − c·x_b)` and `x = x_r − y x_b` (two solves with one
    /// factorisation for a direct solver). A backend may do better.
    fn solve_bordered(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        border: (&[f64], &[f64], f64),
        r: &mut [f64],
        s: f64,
    ) -> Result<f64, LinearSolveError> {
        let (b, c, d) = border;
        let mut x_b = b.to_vec();
        self.solve(matrix, symmetric, r)?;
        self.solve(matrix, symmetric, &mut x_b)?;
        let dot = |u: &[f64], v: &[f64]| u.iter().zip(v).map(|(a, b)| a * b).sum::<f64>();
        let denominator = d - dot(c, &x_b);
        if denominator == 0.0 || !denominator.is_finite() {
            return Err(LinearSolveError::Singular(
                "the bordered (arc-length) system is singular".to_string(),
            ));
        }
        let y = (s - dot(c, r)) / denominator;
        for (x, xb) in r.iter_mut().zip(&x_b) {
            *x -= y * xb;
        }
        Ok(y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1D chain of `n` nodes with node 0 fixed: the Laplacian-like pattern of linear elements.
    fn chain(n: usize) -> (SparseMatrix, Vec<[u32; 1]>) {
        let mut dofs = vec![[NO_DOF]; n];
        for (i, d) in dofs.iter_mut().enumerate().skip(1) {
            d[0] = (i - 1) as u32;
        }
        let supports: Vec<Vec<usize>> = (0..n - 1).map(|e| vec![e, e + 1]).collect();
        let mut sys = SparseMatrix::default();
        sys.rebuild_pattern(n - 1, &dofs[..], supports.iter().map(|s| s.as_slice()));
        (sys, dofs)
    }

    /// Springs of stiffness `k(e)` between the nodes of the chain.
    fn fill_chain(sys: &mut SparseMatrix, dofs: &[[u32; 1]], k: impl Fn(usize) -> f64) {
        sys.clear_values();
        for e in 0..dofs.len() - 1 {
            let block = |v: f64| nalgebra::SMatrix::<f64, 1, 1>::new(v);
            sys.add_block(&dofs[e], &dofs[e], &block(k(e)));
            sys.add_block(&dofs[e + 1], &dofs[e + 1], &block(k(e)));
            sys.add_block(&dofs[e], &dofs[e + 1], &block(-k(e)));
            sys.add_block(&dofs[e + 1], &dofs[e], &block(-k(e)));
        }
    }

    #[test]
    fn pattern_of_a_chain_is_tridiagonal() {
        let (sys, _) = chain(5);
        assert_eq!(sys.size(), 4);
        // 4 diagonal + 2 * 3 off-diagonal
        assert_eq!(sys.nonzeros(), 10);
    }

    #[test]
    fn cholesky_solves_a_spring_chain_and_reuses_the_analysis() {
        let n = 6;
        let (mut sys, dofs) = chain(n);
        let mut solver = DirectSolver::default();
        for pass in 0..2 {
            let k = 1.0 + pass as f64;
            fill_chain(&mut sys, &dofs, |_| k);
            // unit load at the free end: displacement grows linearly, u_i = i / k
            let mut rhs = vec![0.0; n - 1];
            rhs[n - 2] = 1.0;
            let kind = solver.solve(&sys, true, &mut rhs).unwrap();
            assert_eq!(kind, SolverKind::Cholesky);
            for (i, u) in rhs.iter().enumerate() {
                assert!((u - (i + 1) as f64 / k).abs() < 1e-12, "u[{i}] = {u}");
            }
        }
    }

    /// A 2x2 matrix as the tangent of one node with two components.
    fn two_by_two(m: nalgebra::Matrix2<f64>) -> SparseMatrix {
        let dofs = [[0u32, 1u32]];
        let mut sys = SparseMatrix::default();
        sys.rebuild_pattern(2, &dofs[..], std::iter::once(&[0usize][..]));
        sys.add_block(&dofs[0], &dofs[0], &m);
        sys
    }

    #[test]
    fn indefinite_matrix_falls_back_to_lu() {
        // [[1, 2], [2, 1]] is symmetric indefinite
        let sys = two_by_two(nalgebra::Matrix2::new(1.0, 2.0, 2.0, 1.0));
        let mut rhs = vec![3.0, 3.0];
        let kind = DirectSolver::default().solve(&sys, true, &mut rhs).unwrap();
        assert_eq!(kind, SolverKind::Lu);
        assert!((rhs[0] - 1.0).abs() < 1e-12 && (rhs[1] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn singular_matrix_is_an_error_not_a_panic() {
        let sys = two_by_two(nalgebra::Matrix2::new(1.0, 1.0, 1.0, 1.0));
        let mut rhs = vec![1.0, 0.0];
        assert!(DirectSolver::default().solve(&sys, true, &mut rhs).is_err());
    }

    /// A non-symmetric matrix whose lower triangle is symmetric positive definite: Cholesky
    /// (which reads one triangle) would succeed and solve the wrong system. Declared
    /// non-symmetric it is solved by LU, correctly; the matrix knows it is not symmetric.
    #[test]
    fn a_non_symmetric_tangent_is_never_solved_by_cholesky() {
        // [[4, 3], [1, 2]]: lower triangle [[4, .], [1, 2]] is SPD as a symmetric matrix
        let sys = two_by_two(nalgebra::Matrix2::new(4.0, 3.0, 1.0, 2.0));
        assert!(!sys.is_symmetric(1e-12));
        let exact = nalgebra::Matrix2::new(4.0, 3.0, 1.0, 2.0)
            .lu()
            .solve(&nalgebra::Vector2::new(1.0, 1.0))
            .unwrap();
        let mut rhs = vec![1.0, 1.0];
        let kind = DirectSolver::default()
            .solve(&sys, false, &mut rhs)
            .unwrap();
        assert_eq!(kind, SolverKind::Lu);
        assert!((rhs[0] - exact[0]).abs() < 1e-12 && (rhs[1] - exact[1]).abs() < 1e-12);
    }

    /// The bordered solve against a dense solve of the whole system.
    #[test]
    fn the_bordered_system_of_arc_length_is_solved_exactly() {
        let n = 5;
        let (mut sys, dofs) = chain(n + 1);
        fill_chain(&mut sys, &dofs, |e| 1.0 + e as f64);
        let b: Vec<f64> = (0..n).map(|i| 0.3 + i as f64).collect();
        let c: Vec<f64> = (0..n).map(|i| 1.0 - 0.2 * i as f64).collect();
        let (d, s) = (0.7, 2.0);
        let r: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        let mut dense = nalgebra::DMatrix::<f64>::zeros(n + 1, n + 1);
        for i in 0..n {
            for j in 0..n {
                dense[(i, j)] = sys.get(i, j);
            }
            dense[(i, n)] = b[i];
            dense[(n, i)] = c[i];
        }
        dense[(n, n)] = d;
        let mut rhs = nalgebra::DVector::from_vec(r.clone());
        rhs = rhs.push(s);
        let exact = dense.lu().solve(&rhs).unwrap();
        let mut x = r;
        let y = DirectSolver::default()
            .solve_bordered(&sys, true, (&b, &c, d), &mut x, s)
            .unwrap();
        for i in 0..n {
            assert!((x[i] - exact[i]).abs() < 1e-10, "x[{i}]");
        }
        assert!((y - exact[n]).abs() < 1e-10);
    }

    /// A 2D grid Laplacian (5-point stencil, Dirichlet outside) of `m x m` DOFs, scaled by a
    /// smoothly varying stiffness, plus `skew` times a first-difference (convection) term that
    /// makes it non-symmetric. The direct LU solve is the reference.
    fn grid_operator(m: usize, skew: f64) -> SparseMatrix {
        let index = |i: usize, j: usize| (i + m * j) as u32;
        let dofs: Vec<[u32; 1]> = (0..m * m).map(|k| [k as u32]).collect();
        let mut stencils = Vec::new();
        for j in 0..m {
            for i in 0..m {
                let mut s = vec![i + m * j];
                if i > 0 {
                    s.push(i - 1 + m * j);
                }
                if i + 1 < m {
                    s.push(i + 1 + m * j);
                }
                if j > 0 {
                    s.push(i + m * (j - 1));
                }
                if j + 1 < m {
                    s.push(i + m * (j + 1));
                }
                s.sort_unstable();
                stencils.push(s);
            }
        }
        let mut sys = SparseMatrix::default();
        sys.rebuild_pattern(m * m, &dofs[..], stencils.iter().map(|s| s.as_slice()));
        // stiffness of node (i, j); an edge has the mean of its two nodes' (symmetric part)
        let k = |i: usize, j: usize| 1.0 + 0.5 * ((i * j) as f64 * 0.1).sin();
        for j in 0..m {
            for i in 0..m {
                let mut diagonal = 0.1;
                let mut couple = |a: usize, b: usize, sign: f64| {
                    let edge = 0.5 * (k(i, j) + k(a, b));
                    diagonal += edge;
                    sys.add(index(i, j), index(a, b), -edge + sign * skew);
                };
                if i > 0 {
                    couple(i - 1, j, -1.0);
                }
                if i + 1 < m {
                    couple(i + 1, j, 1.0);
                }
                if j > 0 {
                    couple(i, j - 1, -1.0);
                }
                if j + 1 < m {
                    couple(i, j + 1, 1.0);
                }
                sys.add(index(i, j), index(i, j), diagonal);
            }
        }
        sys
    }

    fn relative_difference(a: &[f64], b: &[f64]) -> f64 {
        let diff: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
        let size: f64 = b.iter().map(|y| y * y).sum();
        (diff / size).sqrt()
    }

    #[test]
    fn conjugate_gradients_and_bicgstab_match_the_direct_solve() {
        for (skew, symmetric, kind) in [
            (0.0, true, SolverKind::ConjugateGradients),
            (0.3, false, SolverKind::BiCgStab),
        ] {
            let sys = grid_operator(20, skew);
            assert_eq!(sys.is_symmetric(1e-14), symmetric);
            let rhs: Vec<f64> = (0..400).map(|k| (k as f64 * 0.37).cos()).collect();
            let mut direct = rhs.clone();
            DirectSolver::default()
                .solve(&sys, symmetric, &mut direct)
                .unwrap();
            let mut iterative = rhs.clone();
            let mut krylov = KrylovSolver::default();
            assert_eq!(krylov.solve(&sys, symmetric, &mut iterative), Ok(kind));
            // the residual is reduced by 1e-10; the error by that times the condition number
            let error = relative_difference(&iterative, &direct);
            assert!(error < 1e-8, "{kind:?}: relative error {error:.2e}");
            let mut check = vec![0.0; 400];
            multiply(&sys, &iterative, &mut check);
            assert!(
                relative_difference(&check, &rhs) <= 1e-10,
                "{kind:?} residual"
            );
            assert!(krylov.last_iterations > 5 && krylov.last_iterations < 400);
        }
    }

    #[test]
    fn a_dof_without_stiffness_is_singular_with_its_number() {
        let mut sys = grid_operator(6, 0.0);
        let diagonal = sys.get(7, 7);
        sys.add(7, 7, -diagonal);
        let mut rhs = vec![1.0; 36];
        let error = KrylovSolver::default()
            .solve(&sys, true, &mut rhs)
            .unwrap_err();
        assert!(error.to_string().contains("DOF 7"), "{error}");
    }

    /// An indefinite tangent (a body past a limit point): CG either fails with a reason or
    /// returns a solution whose true residual meets the tolerance, never a wrong answer.
    #[test]
    fn an_indefinite_tangent_is_solved_or_refused_never_answered_wrongly() {
        for shift in [-2.0, -5.0, -40.0] {
            let mut sys = grid_operator(6, 0.0);
            sys.add(7, 7, shift);
            let rhs: Vec<f64> = (0..36).map(|k| 1.0 + k as f64 * 0.1).collect();
            let mut x = rhs.clone();
            match KrylovSolver::default().solve(&sys, true, &mut x) {
                Ok(_) => {
                    let mut check = vec![0.0; 36];
                    multiply(&sys, &x, &mut check);
                    assert!(relative_difference(&check, &rhs) <= 1e-10, "shift {shift}");
                }
                Err(error) => assert!(
                    error.to_string().contains("positive definite")
                        || error.to_string().contains("true residual"),
                    "{error}"
                ),
            }
        }
    }

    #[test]
    fn too_few_iterations_is_an_error_that_names_the_way_out() {
        let sys = grid_operator(20, 0.0);
        let mut rhs = vec![1.0; 400];
        let mut krylov = KrylovSolver::default();
        krylov.max_iterations = 3;
        let error = krylov.solve(&sys, true, &mut rhs).unwrap_err();
        assert!(matches!(error, LinearSolveError::NotConverged(_)));
        assert!(error.to_string().contains("linear: \"direct\""), "{error}");
    }
}
