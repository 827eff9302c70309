//! The iterative backend: preconditioned Krylov solves of `K δ = r`.
//!
//! * Symmetric tangents: preconditioned conjugate gradients (CG; Hestenes & Stiefel), which
//!   needs `K` symmetric positive definite — the tangent of a stable, supported body.
//! * Non-symmetric tangents (plasticity at finite strain, non-associated flow, follower loads,
//!   Nitsche's non-symmetric variant): BiCGSTAB (van der Vorst 1992).
//!
//! Both stop when `‖r − K x‖ ≤ tol ‖r‖` (Euclidean norms; the true residual is checked at the
//! end, so a drifted recursive residual cannot pass a wrong answer) with `tol` the relative
//! tolerance
//! (default 1e-10, well below Newton's normalised tolerance so that Newton keeps its quadratic
//! rate; an inexact Newton loosens it for one solve, [`LinearSolver::request_tolerance`], to its
//! forcing term, `super::EisenstatWalker`). The work vectors live for one solve only (kept, they
//! would sit beside the assembly and the output, the run's memory peaks). The
//! preconditioner is the inverse diagonal of `K` (Jacobi): cheap, parallel, and enough to show
//! the layer working, but its iteration count grows like the square root of the condition
//! number — roughly with the number of cells along the longest direction. Smoothed-aggregation
//! multigrid with the rigid-body modes ([`super::Multigrid`]) keeps the count nearly flat; it is
//! another [`Preconditioner`].
//!
//! Threads: the products with `K`, the dot products and the vector updates run on rayon's
//! threads (`super::vectors`). A symmetric tangent is multiplied by gathering along its
//! columns, so CG with Jacobi gives the same bits on any thread count; BiCGSTAB's products
//! scatter along the columns into one buffer per thread, added in order: bit-identical for a
//! given thread count, equal to round-off across counts.
//!
//! A solve that does not reach the tolerance in `max_iterations` fails with
//! [`LinearSolveError::NotConverged`] (the Newton loop then cuts the step as for any failed
//! solve), and one that meets a breakdown (a zero or negative curvature `pᵀKp` in CG: the
//! tangent is not positive definite) fails at once with [`LinearSolveError::Singular`].

use super::vectors::{self, ScatterParts, dot, norm};
use super::{LinearSolveError, LinearSolver, SolverKind, SparseMatrix};

/// A preconditioner `M⁻¹ ≈ K⁻¹`, rebuilt from the matrix before each solve.
pub trait Preconditioner: Send + Sync {
    /// Prepares `M⁻¹` for `matrix`; `symmetric` says whether `matrix` is symmetric.
    fn setup(&mut self, matrix: &SparseMatrix, symmetric: bool) -> Result<(), LinearSolveError>;
    /// `z = M⁻¹ r` (`&mut self`: a preconditioner may keep work vectors).
    fn apply(&mut self, r: &[f64], z: &mut [f64]);
    /// The levels of a multigrid preconditioner after its last setup (`None` for others).
    fn hierarchy(&self) -> Option<super::Hierarchy> {
        None
    }
}

/// Jacobi: `M = diag(K)`.
#[derive(Default, Clone, Debug)]
pub struct Jacobi {
    inverse_diagonal: Vec<f64>,
}

impl Preconditioner for Jacobi {
    fn setup(&mut self, matrix: &SparseMatrix, _symmetric: bool) -> Result<(), LinearSolveError> {
        let (col_ptr, row_idx) = matrix.pattern();
        let values = matrix.values();
        self.inverse_diagonal.clear();
        self.inverse_diagonal.resize(matrix.size(), 0.0);
        // the diagonal first (on the threads), then its inverse where it is usable
        vectors::update(&mut self.inverse_diagonal, |columns, chunk| {
            for (d, col) in chunk.iter_mut().zip(columns) {
                let range = col_ptr[col]..col_ptr[col + 1];
                *d = row_idx[range.clone()]
                    .iter()
                    .zip(&values[range])
                    .find(|(row, _)| **row == col)
                    .map_or(0.0, |(_, v)| *v);
            }
        });
        if let Some((col, &diagonal)) = self
            .inverse_diagonal
            .iter()
            .enumerate()
            .find(|(_, d)| **d == 0.0 || !d.is_finite())
        {
            return Err(LinearSolveError::Singular(format!(
                "zero or non-finite diagonal entry {diagonal} at DOF {col}"
            )));
        }
        vectors::update(&mut self.inverse_diagonal, |_, chunk| {
            chunk.iter_mut().for_each(|d| *d = 1.0 / *d);
        });
        Ok(())
    }

    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        let inverse_diagonal = &self.inverse_diagonal;
        vectors::update(z, |range, z| {
            for ((z, r), d) in z
                .iter_mut()
                .zip(&r[range.clone()])
                .zip(&inverse_diagonal[range])
            {
                *z = r * d;
            }
        });
    }
}

/// Preconditioned CG / BiCGSTAB (see the module docs).
pub struct KrylovSolver {
    /// Relative residual reduction at which a solve stops.
    pub tolerance: f64,
    /// Iterations allowed per solve.
    pub max_iterations: usize,
    preconditioner: Box<dyn Preconditioner>,
    /// Iterations of the last solve.
    pub last_iterations: usize,
    /// A looser tolerance for the next solve only (an inexact Newton's forcing term).
    requested: Option<f64>,
    /// Work vectors of the solve under way (released when it ends: see `solve`).
    work: Work,
}

/// The vectors of one solve (CG uses the first five).
#[derive(Default)]
struct Work {
    r: Vec<f64>,
    x: Vec<f64>,
    z: Vec<f64>,
    q: Vec<f64>,
    p: Vec<f64>,
    shadow: Vec<f64>,
    p_hat: Vec<f64>,
    s_hat: Vec<f64>,
    t: Vec<f64>,
    /// The threads' buffers of the products by columns.
    parts: ScatterParts,
}

/// `v` as `n` zeros, keeping its allocation.
fn zeros(v: &mut Vec<f64>, n: usize) -> &mut Vec<f64> {
    v.clear();
    v.resize(n, 0.0);
    v
}

impl Default for KrylovSolver {
    /// Jacobi-preconditioned.
    fn default() -> Self {
        Self::with_preconditioner(Box::new(Jacobi::default()))
    }
}

impl KrylovSolver {
    /// A solver with the given preconditioner (default tolerances).
    pub fn with_preconditioner(preconditioner: Box<dyn Preconditioner>) -> Self {
        Self {
            tolerance: 1e-10,
            max_iterations: 20_000,
            preconditioner,
            last_iterations: 0,
            requested: None,
            work: Work::default(),
        }
    }

    /// Multigrid-preconditioned ([`super::Multigrid`]).
    pub fn multigrid() -> Self {
        Self::with_preconditioner(Box::new(super::Multigrid::default()))
    }
}

/// `y = K x` for the stored (both-triangle) CSC matrix, on the threads (a scatter along the
/// columns: bit-identical for a given thread count, see `vectors`).
pub fn multiply(matrix: &SparseMatrix, x: &[f64], y: &mut [f64]) {
    multiply_with(matrix, x, y, &mut ScatterParts::default());
}

/// [`multiply`] with the threads' buffers kept by the caller.
fn multiply_with(matrix: &SparseMatrix, x: &[f64], y: &mut [f64], parts: &mut ScatterParts) {
    let (col_ptr, row_idx) = matrix.pattern();
    y.fill(0.0);
    vectors::scatter_add(col_ptr, row_idx, matrix.values(), x, y, parts);
}

/// `y = K x` inside a Krylov loop. A tangent declared symmetric is multiplied as `Kᵀ x`: its
/// columns read as rows, a gather that is the same for any thread count and needs no buffers
/// (`K` and `Kᵀ` differ by the assembly's round-off at most; the true residual at the end of a
/// solve is checked with `K` itself). Otherwise the scatter of [`multiply`].
fn product(
    matrix: &SparseMatrix,
    symmetric: bool,
    x: &[f64],
    y: &mut [f64],
    parts: &mut ScatterParts,
) {
    if symmetric {
        let (col_ptr, row_idx) = matrix.pattern();
        vectors::gather(col_ptr, row_idx, matrix.values(), x, y);
    } else {
        multiply_with(matrix, x, y, parts);
    }
}

/// The relative true residual `‖r − K x‖ / ‖r‖` of a solution `x` of `K x = r` (`product` is
/// work space; NaN where `x` is not finite). Every iterative backend checks its answer with it:
/// a recursively updated residual (CG, BiCGSTAB) or a preconditioned norm (PETSc's default) can
/// report convergence that the system does not have.
pub(crate) fn true_relative_residual(
    matrix: &SparseMatrix,
    rhs: &[f64],
    x: &[f64],
    product: &mut [f64],
) -> f64 {
    multiply(matrix, x, product);
    vectors::update(product, |range, chunk| {
        for (p, r) in chunk.iter_mut().zip(&rhs[range]) {
            *p = r - *p;
        }
    });
    norm(product) / norm(rhs)
}

/// Checks the true residual of the solution `x` of `K x = r` (the recursively updated one of
/// CG and BiCGSTAB can drift from it, most on ill-conditioned or indefinite tangents) against
/// the tolerance, with a factor 10 of slack for round-off; `product` is work space.
fn check_true_residual(
    matrix: &SparseMatrix,
    rhs: &[f64],
    x: &[f64],
    product: &mut [f64],
    tolerance: f64,
) -> Result<(), LinearSolveError> {
    let relative = true_relative_residual(matrix, rhs, x, product);
    if relative <= 10.0 * tolerance {
        Ok(())
    } else {
        Err(LinearSolveError::NotConverged(format!(
            "the iterative solve stopped with a true residual of {relative:.2e} against a \
             tolerance of {tolerance:.0e} (a badly conditioned or indefinite tangent); use the \
             direct solver (solver(#{{ linear: \"direct\" }}))"
        )))
    }
}

fn not_converged(residual: f64, iterations: usize, tolerance: f64) -> LinearSolveError {
    LinearSolveError::NotConverged(format!(
        "the iterative solve reached a relative residual of {residual:.2e} after {iterations} \
         iterations (tolerance {tolerance:.0e}); use the direct solver (solver(#{{ linear: \"direct\" }}))"
    ))
}

/// `y += alpha x` on the threads.
fn add_scaled(y: &mut [f64], alpha: f64, x: &[f64]) {
    vectors::update(y, |range, y| {
        for (y, x) in y.iter_mut().zip(&x[range]) {
            *y += alpha * x;
        }
    });
}

impl KrylovSolver {
    /// Preconditioned conjugate gradients from `x = 0` to the relative residual `tolerance`;
    /// `rhs` becomes the solution.
    fn conjugate_gradients(
        &mut self,
        matrix: &SparseMatrix,
        rhs: &mut [f64],
        tolerance: f64,
    ) -> Result<(), LinearSolveError> {
        let n = rhs.len();
        let target = tolerance * norm(rhs);
        let work = &mut self.work;
        let r = zeros(&mut work.r, n);
        r.copy_from_slice(rhs);
        let x = zeros(&mut work.x, n);
        let z = zeros(&mut work.z, n);
        let q = zeros(&mut work.q, n);
        self.preconditioner.apply(r, z);
        let p = zeros(&mut work.p, n);
        p.copy_from_slice(z);
        let mut rz = dot(r, z);
        self.last_iterations = 0;
        while norm(r) > target {
            if self.last_iterations == self.max_iterations {
                let reached = norm(r) / (target / tolerance);
                return Err(not_converged(reached, self.max_iterations, tolerance));
            }
            self.last_iterations += 1;
            product(matrix, true, p, q, &mut work.parts);
            let curvature = dot(p, q);
            if curvature <= 0.0 || !curvature.is_finite() {
                return Err(LinearSolveError::Singular(format!(
                    "conjugate gradients met a non-positive curvature {curvature:.3e} \
                     (the tangent is not positive definite)"
                )));
            }
            let alpha = rz / curvature;
            add_scaled(x, alpha, p);
            add_scaled(r, -alpha, q);
            self.preconditioner.apply(r, z);
            let rz_next = dot(r, z);
            let beta = rz_next / rz;
            rz = rz_next;
            vectors::update(p, |range, p| {
                for (p, z) in p.iter_mut().zip(&z[range]) {
                    *p = z + beta * *p;
                }
            });
        }
        check_true_residual(matrix, rhs, x, q, tolerance)?;
        rhs.copy_from_slice(x);
        Ok(())
    }

    /// Right-preconditioned BiCGSTAB from `x = 0` to the relative residual `tolerance`; `rhs`
    /// becomes the solution.
    fn bicgstab(
        &mut self,
        matrix: &SparseMatrix,
        rhs: &mut [f64],
        tolerance: f64,
    ) -> Result<(), LinearSolveError> {
        let n = rhs.len();
        let scale = norm(rhs);
        let target = tolerance * scale;
        let work = &mut self.work;
        let r = zeros(&mut work.r, n);
        r.copy_from_slice(rhs);
        let shadow = zeros(&mut work.shadow, n);
        shadow.copy_from_slice(r);
        let x = zeros(&mut work.x, n);
        let (p, v) = (zeros(&mut work.p, n), zeros(&mut work.q, n));
        let (p_hat, s_hat, t) = (
            zeros(&mut work.p_hat, n),
            zeros(&mut work.s_hat, n),
            zeros(&mut work.t, n),
        );
        let parts = &mut work.parts;
        let (mut rho, mut alpha, mut omega) = (1.0, 1.0, 1.0);
        let breakdown = |what: &str| {
            LinearSolveError::Singular(format!("BiCGSTAB broke down ({what} is zero)"))
        };
        self.last_iterations = 0;
        while norm(r) > target {
            if self.last_iterations == self.max_iterations {
                return Err(not_converged(
                    norm(r) / scale,
                    self.max_iterations,
                    tolerance,
                ));
            }
            self.last_iterations += 1;
            let rho_next = dot(shadow, r);
            if rho_next == 0.0 || omega == 0.0 {
                return Err(breakdown("ρ or ω"));
            }
            let beta = (rho_next / rho) * (alpha / omega);
            rho = rho_next;
            vectors::update(p, |range, p| {
                for ((p, r), v) in p.iter_mut().zip(&r[range.clone()]).zip(&v[range]) {
                    *p = r + beta * (*p - omega * v);
                }
            });
            self.preconditioner.apply(p, p_hat);
            product(matrix, false, p_hat, v, parts);
            let shadow_v = dot(shadow, v);
            if shadow_v == 0.0 || !shadow_v.is_finite() {
                return Err(breakdown("r̂·v"));
            }
            alpha = rho / shadow_v;
            // s = r − α v, kept in r
            add_scaled(x, alpha, p_hat);
            add_scaled(r, -alpha, v);
            if norm(r) <= target {
                break;
            }
            self.preconditioner.apply(r, s_hat);
            product(matrix, false, s_hat, t, parts);
            let tt = dot(t, t);
            if tt == 0.0 || !tt.is_finite() {
                return Err(breakdown("t·t"));
            }
            omega = dot(t, r) / tt;
            add_scaled(x, omega, s_hat);
            add_scaled(r, -omega, t);
        }
        check_true_residual(matrix, rhs, x, t, tolerance)?;
        rhs.copy_from_slice(x);
        Ok(())
    }
}

impl LinearSolver for KrylovSolver {
    fn hierarchy(&self) -> Option<super::Hierarchy> {
        self.preconditioner.hierarchy()
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

    fn solve(
        &mut self,
        matrix: &SparseMatrix,
        symmetric: bool,
        rhs: &mut [f64],
    ) -> Result<SolverKind, LinearSolveError> {
        assert_eq!(
            rhs.len(),
            matrix.size(),
            "right-hand side has the wrong length"
        );
        let tolerance = self
            .requested
            .take()
            .map_or(self.tolerance, |t| t.max(self.tolerance));
        self.last_iterations = 0;
        if matrix.size() == 0 || rhs.iter().all(|&r| r == 0.0) {
            rhs.fill(0.0);
            return Ok(SolverKind::None);
        }
        self.preconditioner.setup(matrix, symmetric)?;
        let result = if symmetric {
            self.conjugate_gradients(matrix, rhs, tolerance)
                .map(|()| SolverKind::ConjugateGradients)
        } else {
            self.bicgstab(matrix, rhs, tolerance)
                .map(|()| SolverKind::BiCgStab)
        };
        // not kept for the next solve: the assembly and the output, the run's peaks, would hold
        // them (CG's five vectors are ~20 bytes per 2D point); allocating them again costs
        // milliseconds against the seconds of a solve that needs them
        self.work = Work::default();
        result
    }
}
