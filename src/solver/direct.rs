//! The direct backend: sparse Cholesky (`LLᵀ`) for symmetric tangents, LU otherwise, with
//! faer. The symbolic analysis (fill-reducing ordering, elimination tree) is computed once per
//! pattern and reused; the numeric factor and scratch memory are owned here and reused, so
//! Newton iterations do not allocate.
//!
//! Cholesky reads one triangle only, so it is used only when the tangent is declared symmetric;
//! if that fails (not positive definite, e.g. past a limit point) the solve falls back to LU. A
//! non-symmetric tangent always goes to LU.
//!
//! The factor of the last solve is kept until the next one, so a right-hand side can be solved
//! with it again (`LinearSolver::solve_with_last_factor`: the line search's natural level
//! function solves with the tangent of the iterate its correction came from).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{LltRef, SymbolicCholesky, factorize_symbolic_cholesky};
use faer::sparse::linalg::solvers::{Lu, SymbolicLu};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

use super::{LinearSolveError, LinearSolver, SolverKind, SparseMatrix};

/// Sparse direct solves with faer (see the module docs).
#[derive(Default)]
pub struct DirectSolver {
    /// The pattern generation the analyses below belong to.
    generation: u64,
    cholesky: Option<SymbolicCholesky<usize>>,
    factor_values: Vec<f64>,
    scratch: Option<MemBuffer>,
    lu_symbolic: Option<SymbolicLu<usize>>,
    /// The factorisation the last solve used, kept for `solve_with_last_factor`.
    last: LastFactor,
}

/// Which factor the last solve left (the Cholesky factor's values live in `factor_values`).
#[derive(Default)]
enum LastFactor {
    #[default]
    None,
    Cholesky {
        size: usize,
    },
    Lu {
        factor: Box<Lu<usize, f64>>,
        size: usize,
    },
}

impl LinearSolver for DirectSolver {
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
        if matrix.size() == 0 {
            return Ok(SolverKind::None);
        }
        if self.generation != matrix.generation() {
            *self = Self {
                generation: matrix.generation(),
                ..Self::default()
            };
        }
        self.last = LastFactor::None;
        if symmetric {
            debug_assert!(
                matrix.is_symmetric(1e-9),
                "a tangent declared symmetric is not"
            );
            // a failed factorisation returns before rhs is touched
            if self.solve_cholesky(matrix, rhs).is_ok() {
                self.last = LastFactor::Cholesky {
                    size: matrix.size(),
                };
                return Ok(SolverKind::Cholesky);
            }
        }
        self.solve_lu(matrix, rhs)?;
        Ok(SolverKind::Lu)
    }

    fn solve_with_last_factor(&mut self, rhs: &mut [f64]) -> Option<Result<(), LinearSolveError>> {
        use faer::linalg::solvers::SolveCore;
        let size = rhs.len();
        match &self.last {
            LastFactor::Cholesky { size: n } if *n == size => {
                let (symbolic, scratch) = (self.cholesky.as_ref()?, self.scratch.as_mut()?);
                let factor = LltRef::<usize, f64>::new(symbolic, &self.factor_values);
                let rhs_mat = MatMut::from_column_major_slice_mut(rhs, size, 1);
                factor.solve_in_place_with_conj(
                    Conj::No,
                    rhs_mat,
                    Par::Seq,
                    MemStack::new(scratch),
                );
            }
            LastFactor::Lu { factor, size: n } if *n == size => {
                let rhs_mat = MatMut::from_column_major_slice_mut(rhs, size, 1);
                factor.solve_in_place_with_conj(Conj::No, rhs_mat);
            }
            _ => return None,
        }
        Some(if rhs.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(LinearSolveError::Singular(
                "the solution with the last factor is not finite".to_string(),
            ))
        })
    }
}

fn pattern(matrix: &SparseMatrix) -> SymbolicSparseColMatRef<'_, usize> {
    let (col_ptr, row_idx) = matrix.pattern();
    SymbolicSparseColMatRef::new_checked(matrix.size(), matrix.size(), col_ptr, None, row_idx)
}

impl DirectSolver {
    fn solve_cholesky(&mut self, matrix: &SparseMatrix, rhs: &mut [f64]) -> Result<(), String> {
        if self.cholesky.is_none() {
            let symbolic = factorize_symbolic_cholesky(
                pattern(matrix),
                Side::Lower,
                Default::default(),
                Default::default(),
            )
            .map_err(|e| format!("{e:?}"))?;
            let par = Par::Seq;
            let req = symbolic
                .factorize_numeric_llt_scratch::<f64>(par, Default::default())
                .or(symbolic.solve_in_place_scratch::<f64>(1, par));
            self.scratch = Some(MemBuffer::try_new(req).map_err(|e| format!("{e:?}"))?);
            self.factor_values.clear();
            self.factor_values.resize(symbolic.len_val(), 0.0);
            self.cholesky = Some(symbolic);
        }
        #[allow(clippy::expect_used, reason = "set just above when it was None")]
        let symbolic = self
            .cholesky
            .as_ref()
            .expect("symbolic factorisation built above");
        #[allow(clippy::expect_used, reason = "set together with the factorisation")]
        let scratch = self
            .scratch
            .as_mut()
            .expect("scratch allocated with the symbolic factorisation");
        let values = SparseColMatRef::new(pattern(matrix), matrix.values());
        let par = Par::Seq;
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.factor_values,
                values,
                Side::Lower,
                LltRegularization::default(),
                par,
                MemStack::new(scratch),
                Default::default(),
            )
            .map_err(|e| format!("{e:?}"))?;
        let factor = LltRef::<usize, f64>::new(symbolic, &self.factor_values);
        let rhs_mat = MatMut::from_column_major_slice_mut(rhs, matrix.size(), 1);
        factor.solve_in_place_with_conj(Conj::No, rhs_mat, par, MemStack::new(scratch));
        Ok(())
    }

    fn solve_lu(&mut self, matrix: &SparseMatrix, rhs: &mut [f64]) -> Result<(), LinearSolveError> {
        if self.lu_symbolic.is_none() {
            let (col_ptr, row_idx) = matrix.pattern();
            let pattern = SymbolicSparseColMat::<usize>::new_checked(
                matrix.size(),
                matrix.size(),
                col_ptr.to_vec(),
                None,
                row_idx.to_vec(),
            );
            let symbolic = SymbolicLu::try_new(pattern.as_ref())
                .map_err(|e| LinearSolveError::Singular(format!("LU analysis failed: {e:?}")))?;
            self.lu_symbolic = Some(symbolic);
        }
        #[allow(clippy::expect_used, reason = "set just above when it was None")]
        let symbolic = self.lu_symbolic.clone().expect("built above");
        let lu = Lu::try_new_with_symbolic(symbolic, matrix.matrix())
            .map_err(|e| LinearSolveError::Singular(format!("LU factorisation failed: {e:?}")))?;
        let rhs_mat = MatMut::from_column_major_slice_mut(rhs, matrix.size(), 1);
        use faer::linalg::solvers::SolveCore;
        lu.solve_in_place_with_conj(Conj::No, rhs_mat);
        if rhs.iter().any(|v| !v.is_finite()) {
            return Err(LinearSolveError::Singular(
                "LU solution is not finite".to_string(),
            ));
        }
        self.last = LastFactor::Lu {
            factor: Box::new(lu),
            size: matrix.size(),
        };
        Ok(())
    }
}
