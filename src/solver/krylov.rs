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
//! rate; an inexact Newton with forcing terms would loosen it far from the solution). The
//! preconditioner is the inverse diagonal of `K` (Jacobi): cheap, parallel, and enough to show
//! the layer working, but its iteration count grows like the square root of the condition
//! number — roughly with the number of cells along the longest direction. A multigrid
//! preconditioner (geometric on the background grid, or smoothed aggregation with the
//! rigid-body modes) is what makes the count flat; it slots in here as another
//! [`Preconditioner`].
//!
//! A solve that does not reach the tolerance in `max_iterations` fails with
//! [`LinearSolveError::NotConverged`] (the Newton loop then cuts the step as for any failed
//! solve), and one that meets a breakdown (a zero or negative curvature `pᵀKp` in CG: the
//! tangent is not positive definite) fails at once with [`LinearSolveError::Singular`].

use super::{LinearSolveError, LinearSolver, SolverKind, SparseMatrix};

/// A preconditioner `M⁻¹ ≈ K⁻¹`, rebuilt from the matrix before each solve.
pub trait Preconditioner: Send + Sync {
    /// Prepares `M⁻¹` for `matrix`.
    fn setup(&mut self, matrix: &SparseMatrix) -> Result<(), LinearSolveError>;
    /// `z = M⁻¹ r`.
    fn apply(&self, r: &[f64], z: &mut [f64]);
}

/// Jacobi: `M = diag(K)`.
#[derive(Default, Clone, Debug)]
pub struct Jacobi {
    inverse_diagonal: Vec<f64>,
}

impl Preconditioner for Jacobi {
    fn setup(&mut self, matrix: &SparseMatrix) -> Result<(), LinearSolveError> {
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

    fn apply(&self, r: &[f64], z: &mut [f64]) {
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
}

impl Default for KrylovSolver {
    fn default() -> Self {
        Self {
            tolerance: 1e-10,
            max_iterations: 20_000,
            preconditioner: Box::new(Jacobi::default()),
            last_iterations: 0,
        }
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

impl KrylovSolver {
    /// Checks the true residual `‖r − K x‖` of the solution `x` of `K x = r` (the recursively
    /// updated one of CG and BiCGSTAB can drift from it, most on ill-conditioned or indefinite
    /// tangents) against the tolerance, with a factor 10 of slack for round-off.
    fn check_true_residual(
        &self,
        matrix: &SparseMatrix,
        rhs: &[f64],
        x: &[f64],
    ) -> Result<(), LinearSolveError> {
        let mut product = vec![0.0; x.len()];
        multiply(matrix, x, &mut product);
        let residual: f64 = rhs
            .iter()
            .zip(&product)
            .map(|(r, p)| (r - p).powi(2))
            .sum::<f64>()
            .sqrt();
        let relative = residual / norm(rhs);
        if relative <= 10.0 * self.tolerance {
            Ok(())
        } else {
            Err(LinearSolveError::NotConverged(format!(
                "the iterative solve stopped with a true residual of {relative:.2e} against a \
                 tolerance of {:.0e} (a badly conditioned or indefinite tangent); use the \
                 direct solver (solver(#{{ linear: \"direct\" }}))",
                self.tolerance
            )))
        }
    }

    fn not_converged(&self, residual: f64) -> LinearSolveError {
        LinearSolveError::NotConverged(format!(
            "the iterative solve reached a relative residual of {residual:.2e} after {} \
             iterations (tolerance {:.0e}); use the direct solver (solver(#{{ linear: \"direct\" }}))",
            self.max_iterations, self.tolerance
        ))
    }

    /// Preconditioned conjugate gradients from `x = 0`; `rhs` becomes the solution.
    fn conjugate_gradients(
        &mut self,
        matrix: &SparseMatrix,
        rhs: &mut [f64],
    ) -> Result<(), LinearSolveError> {
        let n = rhs.len();
        let target = self.tolerance * norm(rhs);
        let mut r = rhs.to_vec();
        let mut x = vec![0.0; n];
        let mut z = vec![0.0; n];
        let mut q = vec![0.0; n];
        self.preconditioner.apply(&r, &mut z);
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        self.last_iterations = 0;
        while norm(&r) > target {
            if self.last_iterations == self.max_iterations {
                return Err(self.not_converged(norm(&r) / (target / self.tolerance)));
            }
            self.last_iterations += 1;
            multiply(matrix, &p, &mut q);
            let curvature = dot(&p, &q);
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
            self.preconditioner.apply(&r, &mut z);
            let rz_next = dot(&r, &z);
            let beta = rz_next / rz;
            rz = rz_next;
            for i in 0..n {
                p[i] = z[i] + beta * p[i];
            }
        }
        self.check_true_residual(matrix, rhs, &x)?;
        rhs.copy_from_slice(&x);
        Ok(())
    }

    /// Right-preconditioned BiCGSTAB from `x = 0`; `rhs` becomes the solution.
    fn bicgstab(&mut self, matrix: &SparseMatrix, rhs: &mut [f64]) -> Result<(), LinearSolveError> {
        let n = rhs.len();
        let scale = norm(rhs);
        let target = self.tolerance * scale;
        let mut r = rhs.to_vec();
        let shadow = r.clone();
        let mut x = vec![0.0; n];
        let (mut p, mut v) = (vec![0.0; n], vec![0.0; n]);
        let (mut p_hat, mut s_hat, mut t) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let (mut rho, mut alpha, mut omega) = (1.0, 1.0, 1.0);
        let breakdown = |what: &str| {
            LinearSolveError::Singular(format!("BiCGSTAB broke down ({what} is zero)"))
        };
        self.last_iterations = 0;
        while norm(&r) > target {
            if self.last_iterations == self.max_iterations {
                return Err(self.not_converged(norm(&r) / scale));
            }
            self.last_iterations += 1;
            let rho_next = dot(&shadow, &r);
            if rho_next == 0.0 || omega == 0.0 {
                return Err(breakdown("ρ or ω"));
            }
            let beta = (rho_next / rho) * (alpha / omega);
            rho = rho_next;
            for i in 0..n {
                p[i] = r[i] + beta * (p[i] - omega * v[i]);
            }
            self.preconditioner.apply(&p, &mut p_hat);
            multiply(matrix, &p_hat, &mut v);
            let shadow_v = dot(&shadow, &v);
            if shadow_v == 0.0 || !shadow_v.is_finite() {
                return Err(breakdown("r̂·v"));
            }
            alpha = rho / shadow_v;
            // s = r − α v, kept in r
            for i in 0..n {
                x[i] += alpha * p_hat[i];
                r[i] -= alpha * v[i];
            }
            if norm(&r) <= target {
                break;
            }
            self.preconditioner.apply(&r, &mut s_hat);
            multiply(matrix, &s_hat, &mut t);
            let tt = dot(&t, &t);
            if tt == 0.0 || !tt.is_finite() {
                return Err(breakdown("t·t"));
            }
            omega = dot(&t, &r) / tt;
            for i in 0..n {
                x[i] += omega * s_hat[i];
                r[i] -= omega * t[i];
            }
        }
        self.check_true_residual(matrix, rhs, &x)?;
        rhs.copy_from_slice(&x);
        Ok(())
    }
}

impl LinearSolver for KrylovSolver {
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
        self.last_iterations = 0;
        if matrix.size() == 0 || rhs.iter().all(|&r| r == 0.0) {
            rhs.fill(0.0);
            return Ok(SolverKind::None);
        }
        self.preconditioner.setup(matrix)?;
        if symmetric {
            self.conjugate_gradients(matrix, rhs)?;
            Ok(SolverKind::ConjugateGradients)
        } else {
            self.bicgstab(matrix, rhs)?;
            Ok(SolverKind::BiCgStab)
        }
    }
}
