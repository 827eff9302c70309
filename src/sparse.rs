//! The sparse linear system of one load step: pattern once, values every Newton iteration.
//!
//! Degrees of freedom (DOFs) are numbered node-major: the free components of an active node get
//! consecutive numbers, nodes in increasing index order. Two DOFs couple when their nodes share
//! a material point's support, so the pattern is built from the point supports at the start of
//! the load step and stays fixed through the step's Newton iterations; only the values are
//! refilled (`clear_values` then `add_block`).
//!
//! The tangent of a hyperelastic body under dead loads is the Hessian of its potential energy,
//! so it is symmetric; where it is also positive definite the system is solved by a sparse
//! Cholesky factorisation (`LL^T`) whose symbolic analysis (fill-reducing ordering, elimination
//! tree) is computed once per load step and reused. Numeric factor and scratch memory are
//! owned here and reused, so Newton iterations do not allocate. If the matrix is not positive
//! definite (for example past a limit point) the solve falls back to a sparse LU.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{LltRef, SymbolicCholesky, factorize_symbolic_cholesky};
use faer::sparse::linalg::solvers::{Lu, SymbolicLu};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

/// Marker for a node component that has no DOF (fixed, or node inactive).
pub const NO_DOF: u32 = u32::MAX;

/// Marker for a block position that is not stored (see [`LinearSystem::block_starts`]).
pub const NO_ENTRY: usize = usize::MAX;

/// Compressed-sparse-column pattern and values of the tangent, with its factorisations.
#[derive(Default)]
pub struct LinearSystem {
    size: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    cholesky: Option<SymbolicCholesky<usize>>,
    factor_values: Vec<f64>,
    scratch: Option<MemBuffer>,
    lu_symbolic: Option<SymbolicLu<usize>>,
    /// How the last system was solved.
    pub last_solver: SolverKind,
}

/// Which factorisation solved a system.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SolverKind {
    #[default]
    None,
    Cholesky,
    Lu,
}

/// A failure of the linear solve.
#[derive(Clone, Debug, PartialEq)]
pub enum LinearSolveError {
    /// Both Cholesky and LU failed: the tangent is singular (for example a node with no
    /// stiffness, or a mechanism in the constraints).
    Singular(String),
}

impl std::fmt::Display for LinearSolveError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LinearSolveError::Singular(why) => {
                write!(f, "the tangent stiffness is singular ({why})")
            }
        }
    }
}

impl LinearSystem {
    /// Number of DOFs.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Number of stored entries.
    pub fn nonzeros(&self) -> usize {
        self.row_idx.len()
    }

    /// Builds the pattern for `size` DOFs from node adjacency.
    ///
    /// `node_dofs[i]` are the DOF numbers of node `i`'s components (`NO_DOF` where none);
    /// `supports` yields, for every material point, the nodes of its support. All pairs of
    /// nodes in one support couple. Previous symbolic factorisations are dropped.
    pub fn rebuild_pattern<'a, const D: usize>(
        &mut self,
        size: usize,
        node_dofs: &[[u32; D]],
        supports: impl Iterator<Item = &'a [usize]>,
    ) {
        let mut adjacency: Vec<Vec<u32>> = vec![Vec::new(); node_dofs.len()];
        let mut previous: &[usize] = &[];
        for support in supports {
            // Points of one cell share their support (B-splines, linear): skip repeats.
            if support == previous {
                continue;
            }
            for &j in support {
                if node_dofs[j].iter().all(|&d| d == NO_DOF) {
                    continue;
                }
                let list = &mut adjacency[j];
                list.extend(support.iter().map(|&i| i as u32));
            }
            previous = support;
        }
        for list in adjacency.iter_mut() {
            list.sort_unstable();
            list.dedup();
        }

        self.size = size;
        self.col_ptr.clear();
        self.row_idx.clear();
        self.col_ptr.push(0);
        // Columns in DOF order: nodes in index order, components in order (node-major numbering).
        for (j, dofs_j) in node_dofs.iter().enumerate() {
            for &col in dofs_j.iter() {
                if col == NO_DOF {
                    continue;
                }
                debug_assert_eq!(col as usize, self.col_ptr.len() - 1);
                for &i in &adjacency[j] {
                    for &row in node_dofs[i as usize].iter() {
                        if row != NO_DOF {
                            self.row_idx.push(row as usize);
                        }
                    }
                }
                self.col_ptr.push(self.row_idx.len());
            }
        }
        self.values.clear();
        self.values.resize(self.row_idx.len(), 0.0);
        self.cholesky = None;
        self.lu_symbolic = None;
        self.scratch = None;
        self.last_solver = SolverKind::None;
    }

    /// Sets every stored value to zero, keeping the pattern.
    pub fn clear_values(&mut self) {
        self.values.fill(0.0);
    }

    /// Adds `value` to entry (`row`, `col`); both must be in the pattern.
    ///
    /// Rows of a column are sorted, so the entry is found by binary search.
    #[inline]
    pub fn add(&mut self, row: u32, col: u32, value: f64) {
        let (start, end) = (self.col_ptr[col as usize], self.col_ptr[col as usize + 1]);
        let rows = &self.row_idx[start..end];
        match rows.binary_search(&(row as usize)) {
            Ok(k) => self.values[start + k] += value,
            Err(_) => panic!("entry ({row}, {col}) is not in the sparsity pattern"),
        }
    }

    /// Adds the D x D block coupling node components `rows` (of node i) and `cols` (of node j):
    /// `K[rows[a], cols[b]] += block[(a, b)]`, skipping components without a DOF.
    #[inline]
    pub fn add_block<const D: usize>(
        &mut self,
        rows: &[u32; D],
        cols: &[u32; D],
        block: &nalgebra::SMatrix<f64, D, D>,
    ) {
        let starts = self.block_starts(rows, cols);
        self.add_block_at(&starts, rows, block);
    }

    /// Where the block of `rows` begins in each column of `cols` (an index into the values),
    /// `NO_ENTRY` for a column without a DOF or a row node without any.
    ///
    /// The free components of a node are consecutive in a column, so one binary search per
    /// column finds the block. Points with the same support share these positions, which is
    /// what lets assembly cache them (`stages/assembly.rs`).
    #[inline]
    pub fn block_starts<const D: usize>(&self, rows: &[u32; D], cols: &[u32; D]) -> [usize; D] {
        let first_row = rows.iter().copied().find(|&r| r != NO_DOF);
        std::array::from_fn(|b| {
            let (Some(first_row), col) = (first_row, cols[b]) else {
                return NO_ENTRY;
            };
            if col == NO_DOF {
                return NO_ENTRY;
            }
            let (start, end) = (self.col_ptr[col as usize], self.col_ptr[col as usize + 1]);
            match self.row_idx[start..end].binary_search(&(first_row as usize)) {
                Ok(k) => start + k,
                Err(_) => panic!("block ({first_row}, {col}) is not in the sparsity pattern"),
            }
        })
    }

    /// Adds `block` at positions from [`LinearSystem::block_starts`].
    #[inline]
    pub fn add_block_at<const D: usize>(
        &mut self,
        starts: &[usize; D],
        rows: &[u32; D],
        block: &nalgebra::SMatrix<f64, D, D>,
    ) {
        for (b, &start) in starts.iter().enumerate() {
            if start == NO_ENTRY {
                continue;
            }
            let mut k = start;
            for (a, &row) in rows.iter().enumerate() {
                if row != NO_DOF {
                    debug_assert_eq!(self.row_idx[k], row as usize);
                    self.values[k] += block[(a, b)];
                    k += 1;
                }
            }
        }
    }

    /// The matrix as a faer view.
    pub fn matrix(&self) -> SparseColMatRef<'_, usize, f64> {
        let symbolic = SymbolicSparseColMatRef::new_checked(
            self.size,
            self.size,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        SparseColMatRef::new(symbolic, &self.values)
    }

    /// Entry (`row`, `col`), zero where not stored. For tests and diagnostics.
    pub fn get(&self, row: usize, col: usize) -> f64 {
        let (start, end) = (self.col_ptr[col], self.col_ptr[col + 1]);
        match self.row_idx[start..end].binary_search(&row) {
            Ok(k) => self.values[start + k],
            Err(_) => 0.0,
        }
    }

    /// Solves `K x = rhs` in place (Cholesky, or LU if K is not positive definite).
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) -> Result<SolverKind, LinearSolveError> {
        assert_eq!(rhs.len(), self.size, "right-hand side has the wrong length");
        if self.size == 0 {
            return Ok(SolverKind::None);
        }
        let kind = match self.solve_cholesky(rhs) {
            Ok(()) => SolverKind::Cholesky,
            Err(_) => {
                self.solve_lu(rhs)?;
                SolverKind::Lu
            }
        };
        self.last_solver = kind;
        Ok(kind)
    }

    fn solve_cholesky(&mut self, rhs: &mut [f64]) -> Result<(), String> {
        if self.cholesky.is_none() {
            let pattern = SymbolicSparseColMatRef::new_checked(
                self.size,
                self.size,
                &self.col_ptr,
                None,
                &self.row_idx,
            );
            let symbolic = factorize_symbolic_cholesky(
                pattern,
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
        let symbolic = self
            .cholesky
            .as_ref()
            .expect("symbolic factorisation built above");
        let scratch = self
            .scratch
            .as_mut()
            .expect("scratch allocated with the symbolic factorisation");
        let matrix = {
            let pattern = SymbolicSparseColMatRef::new_checked(
                self.size,
                self.size,
                &self.col_ptr,
                None,
                &self.row_idx,
            );
            SparseColMatRef::new(pattern, &self.values)
        };
        let par = Par::Seq;
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.factor_values,
                matrix,
                Side::Lower,
                LltRegularization::default(),
                par,
                MemStack::new(scratch),
                Default::default(),
            )
            .map_err(|e| format!("{e:?}"))?;
        let factor = LltRef::<usize, f64>::new(symbolic, &self.factor_values);
        let rhs_mat = MatMut::from_column_major_slice_mut(rhs, self.size, 1);
        factor.solve_in_place_with_conj(Conj::No, rhs_mat, par, MemStack::new(scratch));
        Ok(())
    }

    fn solve_lu(&mut self, rhs: &mut [f64]) -> Result<(), LinearSolveError> {
        if self.lu_symbolic.is_none() {
            let pattern = SymbolicSparseColMat::<usize>::new_checked(
                self.size,
                self.size,
                self.col_ptr.clone(),
                None,
                self.row_idx.clone(),
            );
            let symbolic = SymbolicLu::try_new(pattern.as_ref())
                .map_err(|e| LinearSolveError::Singular(format!("LU analysis failed: {e:?}")))?;
            self.lu_symbolic = Some(symbolic);
        }
        let symbolic = self.lu_symbolic.clone().expect("built above");
        let lu = Lu::try_new_with_symbolic(symbolic, self.matrix())
            .map_err(|e| LinearSolveError::Singular(format!("LU factorisation failed: {e:?}")))?;
        let rhs_mat = MatMut::from_column_major_slice_mut(rhs, self.size, 1);
        use faer::linalg::solvers::SolveCore;
        lu.solve_in_place_with_conj(Conj::No, rhs_mat);
        if rhs.iter().any(|v| !v.is_finite()) {
            return Err(LinearSolveError::Singular(
                "LU solution is not finite".to_string(),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1D chain of `n` nodes with node 0 fixed: the Laplacian-like pattern of linear elements.
    fn chain(n: usize) -> (LinearSystem, Vec<[u32; 1]>) {
        let mut dofs = vec![[NO_DOF]; n];
        for (i, d) in dofs.iter_mut().enumerate().skip(1) {
            d[0] = (i - 1) as u32;
        }
        let supports: Vec<Vec<usize>> = (0..n - 1).map(|e| vec![e, e + 1]).collect();
        let mut sys = LinearSystem::default();
        sys.rebuild_pattern(n - 1, &dofs, supports.iter().map(|s| s.as_slice()));
        (sys, dofs)
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
        for pass in 0..2 {
            let k = 1.0 + pass as f64;
            sys.clear_values();
            for e in 0..n - 1 {
                let block = |v: f64| nalgebra::SMatrix::<f64, 1, 1>::new(v);
                sys.add_block(&dofs[e], &dofs[e], &block(k));
                sys.add_block(&dofs[e + 1], &dofs[e + 1], &block(k));
                sys.add_block(&dofs[e], &dofs[e + 1], &block(-k));
                sys.add_block(&dofs[e + 1], &dofs[e], &block(-k));
            }
            // unit load at the free end: displacement grows linearly, u_i = i / k
            let mut rhs = vec![0.0; n - 1];
            rhs[n - 2] = 1.0;
            let kind = sys.solve_in_place(&mut rhs).unwrap();
            assert_eq!(kind, SolverKind::Cholesky);
            for (i, u) in rhs.iter().enumerate() {
                assert!((u - (i + 1) as f64 / k).abs() < 1e-12, "u[{i}] = {u}");
            }
        }
    }

    #[test]
    fn indefinite_matrix_falls_back_to_lu() {
        let dofs = vec![[0u32, 1u32]];
        let mut sys = LinearSystem::default();
        sys.rebuild_pattern(2, &dofs, std::iter::once(&[0usize][..]));
        // [[1, 2], [2, 1]] is symmetric indefinite
        sys.add_block(
            &dofs[0],
            &dofs[0],
            &nalgebra::Matrix2::new(1.0, 2.0, 2.0, 1.0),
        );
        let mut rhs = vec![3.0, 3.0];
        assert_eq!(sys.solve_in_place(&mut rhs).unwrap(), SolverKind::Lu);
        assert!((rhs[0] - 1.0).abs() < 1e-12 && (rhs[1] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn singular_matrix_is_an_error_not_a_panic() {
        let dofs = vec![[0u32, 1u32]];
        let mut sys = LinearSystem::default();
        sys.rebuild_pattern(2, &dofs, std::iter::once(&[0usize][..]));
        sys.add_block(
            &dofs[0],
            &dofs[0],
            &nalgebra::Matrix2::new(1.0, 1.0, 1.0, 1.0),
        );
        let mut rhs = vec![1.0, 0.0];
        assert!(sys.solve_in_place(&mut rhs).is_err());
    }
}
