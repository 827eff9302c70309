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
//! forcing term, `super::EisenstatWalker`). The work vectors are kept between solves. The
//! preconditioner is the inverse diagonal of `K` (Jacobi): cheap, parallel, and enough to show
//! the layer working, but its iteration count grows like the square root of the condition
//! number — roughly with the number of cells along the longest direction. Smoothed-aggregation
//! multigrid with the rigid-body modes ([`super::Multigrid`]) keeps the count nearly flat; it is
//! another [`Preconditioner`].
//!
//! A solve that does not reach the tolerance in `max_iterations` fails with
//! [`LinearSolveError::NotConverged`] (the Newton loop then cuts the step as for any failed
//! solve), and one that meets a breakdown (a zero or negative curvature `pᵀKp` in CG: the
//! tangent is not positive definite) fails at once with [`LinearSolveError::Singular`].

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
        for col in 0..matrix.size() {
            let range = col_ptr[col]..col_ptr[col + 1];
            let diagonal = row_idx[range.clone()]
                .iter()
                .zip(&values[range])
                .find(|(row, _)| **row == col)
                .map_or(0.0, |(_, v)| *v);
            if diagonal == 0.0 || !diagonal.is_finite() {
                return Err(LinearSolveError::Singular(format!(
                    "zero or non-finite diagonal entry {diagonal} at DOF {col}"
                )));
            }
            self.inverse_diagonal.push(1.0 / diagonal);
        }
        Ok(())
    }

    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        for ((z, r), d) in z.iter_mut().zip(r).zip(&self.inverse_diagonal) {
            *z = r * d;
        }
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
    /// Work vectors, kept between solves so that Newton iterations do not allocate them.
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

/// `y = K x` for the stored (both-triangle) CSC matrix.
pub fn multiply(matrix: &SparseMatrix, x: &[f64], y: &mut [f64]) {
    let (col_ptr, row_idx) = matrix.pattern();
    let values = matrix.values();
    y.fill(0.0);
    for (col, &xc) in x.iter().enumerate() {
        for k in col_ptr[col]..col_ptr[col + 1] {
            y[row_idx[k]] += values[k] * xc;
        }
    }
}

fn dot(u: &[f64], v: &[f64]) -> f64 {
    u.iter().zip(v).map(|(a, b)| a * b).sum()
}

fn norm(u: &[f64]) -> f64 {
    dot(u, u).sqrt()
}

/// Checks the true residual `‖r − K x‖` of the solution `x` of `K x = r` (the recursively
/// updated one of CG and BiCGSTAB can drift from it, most on ill-conditioned or indefinite
/// tangents) against the tolerance, with a factor 10 of slack for round-off; `product` is
/// work space.
fn check_true_residual(
    matrix: &SparseMatrix,
    rhs: &[f64],
    x: &[f64],
    product: &mut [f64],
    tolerance: f64,
) -> Result<(), LinearSolveError> {
    multiply(matrix, x, product);
    let residual: f64 = rhs
        .iter()
        .zip(product.iter())
        .map(|(r, p)| (r - p).powi(2))
        .sum::<f64>()
        .sqrt();
    let relative = residual / norm(rhs);
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
            multiply(matrix, p, q);
            let curvature = dot(p, q);
            if curvature <= 0.0 || !curvature.is_finite() {
                return Err(LinearSolveError::Singular(format!(
                    "conjugate gradients met a non-positive curvature {curvature:.3e} \
                     (the tangent is not positive definite)"
                )));
            }
            let alpha = rz / curvature;
            for i in 0..n {
                x[i] += alpha * p[i];
                r[i] -= alpha * q[i];
            }
            self.preconditioner.apply(r, z);
            let rz_next = dot(r, z);
            let beta = rz_next / rz;
            rz = rz_next;
            for i in 0..n {
                p[i] = z[i] + beta * p[i];
            }
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
            for i in 0..n {
                p[i] = r[i] + beta * (p[i] - omega * v[i]);
            }
            self.preconditioner.apply(p, p_hat);
            multiply(matrix, p_hat, v);
            let shadow_v = dot(shadow, v);
            if shadow_v == 0.0 || !shadow_v.is_finite() {
                return Err(breakdown("r̂·v"));
            }
            alpha = rho / shadow_v;
            // s = r − α v, kept in r
            for i in 0..n {
                x[i] += alpha * p_hat[i];
                r[i] -= alpha * v[i];
            }
            if norm(r) <= target {
                break;
            }
            self.preconditioner.apply(r, s_hat);
            multiply(matrix, s_hat, t);
            let tt = dot(t, t);
            if tt == 0.0 || !tt.is_finite() {
                return Err(breakdown("t·t"));
            }
            omega = dot(t, r) / tt;
            for i in 0..n {
                x[i] += omega * s_hat[i];
                r[i] -= omega * t[i];
            }
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
        if symmetric {
            self.conjugate_gradients(matrix, rhs, tolerance)?;
            Ok(SolverKind::ConjugateGradients)
        } else {
            self.bicgstab(matrix, rhs, tolerance)?;
            Ok(SolverKind::BiCgStab)
        }
    }
}
