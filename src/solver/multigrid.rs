//! Smoothed-aggregation algebraic multigrid (Vaněk, Mandel & Brezina 1996) as a
//! [`Preconditioner`] of CG / BiCGSTAB: one V-cycle per application, so that the Krylov
//! iteration count stays nearly flat as the grid is refined (Jacobi's grows like the number of
//! cells along the body).
//!
//! **Why algebraic, and why this one.** The tangent comes from B-splines of any order, GIMP,
//! CPDI, linear hats or FEM meshes, over an active subset of grid nodes with some components
//! fixed: an algebraic method needs none of that structure, only the matrix and its
//! near-null space, which for elasticity are the rigid-body modes (translations and
//! rotations), built from the positions of the DOFs' nodes ([`super::DofLayout`]). No Rust crate
//! did the job when this was written: the AMG crates found (`kryst`, `numr`, `scirs2-sparse`,
//! `nalgebra-sparse-linalg`, `oxiphysics-fem`, the GPU `oxicuda-sparse`) are classical
//! Ruge–Stüben or scalar aggregation with the constant vector only, young, or pull a large
//! stack; none takes a vector problem's rigid-body modes. The sparse products and the coarsest
//! factorisation are faer's; the aggregation, the tentative prolongator and the cycle are here.
//!
//! **Setup** (level `l`, operator `A_l`, near-null space `B_l` of `k` columns):
//!
//! 1. *Aggregates* of node blocks (the DOFs of one node; on coarse levels the DOFs of one
//!    aggregate). With the nodes' positions known (the background grid, or a mesh), the
//!    aggregates are *boxes*: each node gets integer lattice coordinates `k` (its index along
//!    each axis, `lattice_coordinates`) and the nodes with the same `⌊k / w⌋`
//!    (`w` = [`Multigrid::aggregate_width`], 4 by default) form one aggregate; the coarse
//!    block keeps `⌊k / w⌋` as its coordinates, so the next level groups `w^D` aggregates again.
//!    Why boxes this wide: a B-spline basis of order `q` couples nodes `q` apart, and the
//!    smoothed prolongator below widens an aggregate by `q` nodes on each side; with `w`
//!    nodes a side, two coarse blocks `J − I` apart couple when `w (J − I) ≤ w + 3q − 1`
//!    (q = 2: `J − I ≤ 2` for `w = 3` or `4`, but `≤ 3` for `w = 2`). So `w = 4` keeps the coarse
//!    stencil `5^D` blocks wide at every level while each level has about `2·4^D / (D + 1)`
//!    times fewer unknowns than the one below (`4^D` nodes of `D` DOFs become the `D(D+1)/2`
//!    rigid-body modes: 32× in 3D, 10.7× in 2D): operator complexity 1.03 in 3D and 1.15 in
//!    2D on the self-weight blocks (`examples/multigrid_setup.rs`, `docs/performance.md`),
//!    against 1.09 and 1.27 for `w = 3` with one or two fewer CG iterations. The
//!    nearest-ring aggregates this module used first coarsened 3D by 2× per level (6 916 →
//!    3 444 DOFs at 12 cells), and its setup was most of a 17 s 10k-point step. Without
//!    positions, algebraic aggregation: `‖A_IJ‖_F ≥ θ √(‖A_II‖_F ‖A_JJ‖_F)`, `θ = 0.08`,
//!    strong neighbours; greedy: a block whose strong neighbours are all free forms an
//!    aggregate with them; the rest join the aggregate of their strongest neighbour, or form
//!    their own.
//! 2. *Tentative prolongator* `T`: per aggregate `g`, the rows of `B` on its DOFs are
//!    orthonormalised (Gram–Schmidt, twice), `B_g = Q_g R_g`, columns that vanish on the
//!    aggregate dropped (a node with one free component cannot rotate); `T = diag(Q_g)`, and the
//!    coarse near-null space is `B_{l+1} = R`, so `T B_{l+1} = B_l` exactly.
//! 3. *Smoothed prolongator* `P = (I − ω D⁻¹ A) T`, `ω = 4 / (3 ρ(D⁻¹A))` with `ρ` from
//!    Lanczos steps (power iterations for a non-symmetric tangent; [`spectral_radius`]);
//!    coarse operator `A_{l+1} = Pᵀ A P` (Galerkin: symmetric and positive definite when `A`
//!    is), formed a block `J` of `P`'s columns at a time as
//!    `(Pᵀ A P)_{:,J} = ((A P_J)ᵀ P)ᵀ`, so `Pᵀ` is never formed ([`galerkin_product`]).
//! 4. Until the coarsest level has at most [`Multigrid::coarsest_size`] DOFs, which is
//!    factorised (faer's sparse Cholesky, LU if the tangent is not symmetric or Cholesky fails).
//!
//! The sparse products run on rayon's threads, column by column (each column by one thread, in
//! a fixed order: the same hierarchy for any thread count).
//!
//! **Reuse within a load step** ([`Multigrid::keep_hierarchy`], on by default): the pattern is
//! fixed for a load step and its tangent changes little from one Newton iteration to the next,
//! so the whole hierarchy built from the step's first tangent preconditions the step's later
//! solves. It is a symmetric positive definite operator whatever tangent it was built from, so
//! CG stays correct; only the iteration count could change, and on the self-weight blocks it
//! does not (2D 160k points: 19, 18, 18 iterations kept against 19, 18, 17 rebuilt; the setup
//! was 40–55 % of the linear solves when redone at every iteration). Where the tangent changes
//! much within a step (a body yielding) the count may grow (no scene word turns reuse off yet;
//! the field does, through the library). With it off, the
//! aggregates and `T` (which depend on the pattern and the positions only) are kept and `P`,
//! the coarse operators and the coarsest factor are rebuilt from each tangent; with it on, `T`
//! is dropped once the hierarchy is built (a new pattern rebuilds the aggregates anyway).
//!
//! **Scaling.** Nodes at the edge of a body whose basis functions barely touch a material point
//! have diagonal entries many orders of magnitude below the others (1e-124 of them measured on
//! a cube with a cell of empty grid around it); smoothing the prolongator with `D⁻¹A` then
//! overflows. The hierarchy is therefore built for `Â = S K S`, `S = diag(|K_ii|^(-1/2))`
//! (unit diagonal, `|Â_ij| ≤ 1` when `K` is positive definite), with near-null space `S⁻¹B`, and
//! the preconditioner is `S M̂⁻¹ S`, symmetric as before.
//!
//! **Cycle**: a V-cycle whose smoother is, by default, [`Smoother::Chebyshev`] of degree 2: the
//! same Chebyshev polynomial of `D⁻¹A` before and after the coarse correction (self-adjoint in
//! the `A` inner product, so the cycle is a symmetric positive definite operator for a
//! symmetric positive definite `A`: a valid CG preconditioner), built from products with `A`
//! only, so it runs on every thread. The alternative, [`Smoother::GaussSeidel`], is one forward
//! Gauss–Seidel sweep before the coarse correction and one backward sweep after it (the
//! forward one starts from zero, so it reads only the lower triangle; the row products keep
//! four partial sums, `sparse_dot`); the backward sweep is the adjoint of the forward one, so
//! the cycle is symmetric too. Gauss–Seidel smooths a little more per sweep but is sequential
//! (each row waits for the rows before it); see [`Smoother`] for the figures that chose the
//! default.
//!
//! **Threads.** The residuals, restrictions (`Pᵀ r`, a gather along `P`'s columns), the
//! Chebyshev smoother, the scaling and the spectral-radius estimates run on rayon's threads
//! (`super::vectors`), the same for any thread count; the prolongation (`x += P e`) scatters
//! along `P`'s columns into one buffer per thread, added in order (bit-identical for a thread
//! count, round-off across counts). Gauss–Seidel sweeps and the coarsest solve are sequential.
//! A symmetric level operator is stored once: its columns, read as its rows. The finest
//! level's `Â = S K S` keeps only its values: its pattern is the tangent's, shared with the
//! `SparseMatrix` (`SparseMatrix::shared_pattern`), not copied (8 bytes per nonzero: ~200 bytes
//! per 2D point, q = 2).

use faer::linalg::solvers::SolveCore;
use faer::sparse::linalg::matmul::sparse_sparse_matmul;
use faer::sparse::linalg::solvers::{Llt, Lu, SymbolicLlt, SymbolicLu};
use faer::sparse::{
    SparseColMat, SparseColMatRef, SparseRowMat, SymbolicSparseColMat, SymbolicSparseColMatRef,
    Triplet,
};
use faer::{Conj, MatMut, Par, Side};
use std::sync::Arc;

use super::vectors::{self, ScatterParts, sparse_dot};
use super::{DofLayout, LinearSolveError, Preconditioner, SparseMatrix};

/// Relative strength of connection below which blocks are not aggregated together, when the
/// nodes' positions are not known.
const STRENGTH_THRESHOLD: f64 = 0.08;

/// The key of no pattern (a new multigrid, or one whose setup failed).
const NO_PATTERN: (u64, usize, usize) = (u64::MAX, 0, 0);

/// Power iterations estimating the spectral radius of `D⁻¹A`.
const POWER_ITERATIONS: usize = 15;

/// Smoothed-aggregation multigrid (see the module docs).
pub struct Multigrid {
    /// Levels are added until one has at most this many DOFs (it is factorised).
    pub coarsest_size: usize,
    /// At most this many levels, the coarsest included.
    pub max_levels: usize,
    /// Nodes per axis of a box aggregate (positions known; see the module docs).
    pub aggregate_width: usize,
    /// Keep the whole hierarchy (prolongators, coarse operators, coarsest factor) for the
    /// Newton iterations of a load step, rebuilding it only when the pattern changes; otherwise
    /// only the aggregates are kept and the rest is rebuilt from each tangent. A hierarchy
    /// built from an earlier tangent of the step is still a symmetric positive definite
    /// preconditioner, so CG stays correct; only the iteration count can change.
    pub keep_hierarchy: bool,
    /// The smoother of every level but the coarsest.
    pub smoother: Smoother,
    /// The pattern (generation, size, entries) the aggregates belong to.
    key: (u64, usize, usize),
    tentatives: Vec<SparseColMat<usize, f64>>,
    /// `S = diag(|K_ii|^(-1/2))`: the cycle works on `S K S` (see the module docs).
    scaling: Vec<f64>,
    levels: Vec<Level>,
    coarsest: Coarsest,
    coarse_rhs: Vec<f64>,
    /// Non-zeros of the coarsest operator (the other levels' are in their `rows`).
    coarse_nonzeros: usize,
}

/// The sizes of a multigrid hierarchy, finest level first, for the logs and `summary.json`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Hierarchy {
    /// Rows (DOFs) of each level's operator.
    pub rows: Vec<usize>,
    /// Stored entries of each level's operator.
    pub nonzeros: Vec<usize>,
}

impl Hierarchy {
    /// Σ rows of the levels / rows of the finest.
    pub fn grid_complexity(&self) -> f64 {
        ratio(&self.rows)
    }

    /// Σ non-zeros of the levels / non-zeros of the finest: the memory of the hierarchy and
    /// the work of a V-cycle against those of one product with the finest operator.
    pub fn operator_complexity(&self) -> f64 {
        ratio(&self.nonzeros)
    }
}

impl std::fmt::Display for Hierarchy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let levels: Vec<String> = self
            .rows
            .iter()
            .zip(&self.nonzeros)
            .map(|(r, n)| format!("{r} ({n} nnz)"))
            .collect();
        write!(
            f,
            "{} levels: {}; grid complexity {:.2}, operator complexity {:.2}",
            levels.len(),
            levels.join(" -> "),
            self.grid_complexity(),
            self.operator_complexity()
        )
    }
}

/// The smoother of the V-cycle (see the module docs, **Cycle**). The default is Chebyshev of
/// degree 2, measured faster than Gauss–Seidel on a quiet machine (docs/performance.md, "The
/// smoother"): 2D, 1M points, a load step's linear solves 10.1 s against 12.7 s on 2 threads
/// and 13.1 s against 15.3 s on 1 (20 CG iterations against 22); 3D, 33k points, 2.96 s
/// against 3.18 s on 2 threads, 3.22 s against 3.04 s on 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Smoother {
    /// One forward Gauss–Seidel sweep before the coarse correction, one backward sweep after:
    /// the strongest smoothing for its cost, but each row waits for the one before, so it runs
    /// on one thread.
    GaussSeidel,
    /// A Chebyshev polynomial of `D⁻¹A` of this degree (at least 1) before and after: products
    /// with `A` and element-wise updates only, so it runs on every thread, the same for any
    /// thread count.
    Chebyshev(usize),
}

impl Default for Smoother {
    fn default() -> Self {
        Smoother::Chebyshev(2)
    }
}

fn ratio(sizes: &[usize]) -> f64 {
    match sizes.first() {
        Some(&first) if first > 0 => sizes.iter().sum::<usize>() as f64 / first as f64,
        _ => 0.0,
    }
}

impl Default for Multigrid {
    fn default() -> Self {
        Self {
            coarsest_size: 1000,
            max_levels: 12,
            aggregate_width: 4,
            keep_hierarchy: true,
            smoother: Smoother::default(),
            key: NO_PATTERN,
            tentatives: Vec::new(),
            scaling: Vec::new(),
            levels: Vec::new(),
            coarsest: Coarsest::Empty,
            coarse_rhs: Vec::new(),
            coarse_nonzeros: 0,
        }
    }
}

/// An operator by rows (row starts, column indices, values); the pattern may be shared with
/// the tangent's (the finest level of a symmetric tangent).
struct Rows {
    row_ptr: Arc<Vec<usize>>,
    col_idx: Arc<Vec<usize>>,
    values: Vec<f64>,
}

impl Rows {
    /// Rows owned by this operator (row starts, column indices, values).
    fn owned(row_ptr: Vec<usize>, col_idx: Vec<usize>, values: Vec<f64>) -> Self {
        Self {
            row_ptr: Arc::new(row_ptr),
            col_idx: Arc::new(col_idx),
            values,
        }
    }

    fn from_faer(rows: SparseRowMat<usize, f64>) -> Self {
        let (symbolic, values) = rows.into_parts();
        let (_, _, row_ptr, _, col_idx) = symbolic.into_parts();
        Self::owned(row_ptr, col_idx, values)
    }

    fn parts(&self) -> (&[usize], &[usize], &[f64]) {
        (&self.row_ptr, &self.col_idx, &self.values)
    }
}

/// One level above the coarsest.
struct Level {
    /// The operator by rows (smoothing, residuals).
    rows: Rows,
    inverse_diagonal: Vec<f64>,
    /// Where each row's diagonal entry is in `rows` (its columns are sorted).
    diagonal: Vec<usize>,
    /// The estimate of the spectral radius of `D⁻¹A` ([`spectral_radius`]).
    radius: f64,
    /// From the next coarser level to this one.
    prolongation: SparseColMat<usize, f64>,
    x: Vec<f64>,
    b: Vec<f64>,
    r: Vec<f64>,
    /// The Chebyshev smoother's update (empty for Gauss–Seidel).
    direction: Vec<f64>,
    /// The threads' buffers of the prolongation (a product by columns).
    parts: ScatterParts,
}

enum Coarsest {
    Empty,
    Cholesky(Llt<usize, f64>),
    Lu(Box<Lu<usize, f64>>),
}

impl Multigrid {
    /// A multigrid whose coarsest level has at most `size` DOFs.
    pub fn with_coarsest_size(size: usize) -> Self {
        Self {
            coarsest_size: size,
            ..Self::default()
        }
    }

    /// The number of levels, the coarsest included (after a setup).
    pub fn level_count(&self) -> usize {
        self.levels.len() + 1
    }

    /// The sizes of the levels, finest first (after a setup).
    pub fn level_sizes(&self) -> Vec<usize> {
        self.sizes().rows
    }

    fn sizes(&self) -> Hierarchy {
        let mut hierarchy = Hierarchy::default();
        for level in &self.levels {
            hierarchy.rows.push(level.x.len());
            hierarchy.nonzeros.push(level.rows.values.len());
        }
        hierarchy.rows.push(self.coarse_rhs.len());
        hierarchy.nonzeros.push(self.coarse_nonzeros);
        hierarchy
    }

    /// The hierarchy for `matrix` (see the module docs), or the one kept for its pattern.
    fn build(&mut self, matrix: &SparseMatrix, symmetric: bool) -> Result<(), LinearSolveError> {
        let key = (matrix.generation(), matrix.size(), matrix.nonzeros());
        let same_pattern = key == self.key;
        if same_pattern && self.keep_hierarchy && !matches!(self.coarsest, Coarsest::Empty) {
            return Ok(());
        }
        // a kept hierarchy's setup drops the tentative prolongators (below): rebuild them
        let rebuild = !same_pattern || self.tentatives.len() < self.levels.len();
        if rebuild {
            self.tentatives.clear();
            self.key = key;
        }
        self.levels.clear();
        self.coarsest = Coarsest::Empty;
        let mut operator = Operator::Fine(scale_symmetrically(matrix, &mut self.scaling)?);
        let (mut blocks, mut near_null) = if rebuild {
            fine_blocks_and_modes(matrix.layout(), matrix.size())
        } else {
            (Blocks::default(), Vec::new())
        };
        // the near-null space of S K S is S⁻¹ B
        for mode in &mut near_null {
            for (value, s) in mode.iter_mut().zip(&self.scaling) {
                *value /= s;
            }
        }
        loop {
            let a = operator.view(matrix);
            let l = self.levels.len();
            if a.nrows() <= self.coarsest_size || l + 1 >= self.max_levels {
                break;
            }
            if rebuild {
                let Some((tentative, coarse_blocks, coarse_null)) =
                    aggregate(a, &blocks, &near_null, self.aggregate_width)
                else {
                    break;
                };
                self.tentatives.push(tentative);
                (blocks, near_null) = (coarse_blocks, coarse_null);
            } else if l == self.tentatives.len() {
                break;
            }
            let (inverse_diagonal, diagonal) = diagonal_of(a, l)?;
            let radius = spectral_radius(a, &inverse_diagonal, symmetric);
            let omega = 4.0 / (3.0 * radius);
            let prolongation =
                smooth_prolongator(a, self.tentatives[l].as_ref(), &inverse_diagonal, omega)?;
            let next = galerkin_product(a, prolongation.as_ref())?;
            let n = a.nrows();
            let direction = match self.smoother {
                Smoother::GaussSeidel => Vec::new(),
                Smoother::Chebyshev(_) => vec![0.0; n],
            };
            let finer = std::mem::replace(&mut operator, Operator::Coarse(next));
            let (rows, diagonal) = by_rows(finer, matrix, symmetric, diagonal)?;
            self.levels.push(Level {
                rows,
                inverse_diagonal,
                diagonal,
                radius,
                prolongation,
                x: vec![0.0; n],
                b: vec![0.0; n],
                r: vec![0.0; n],
                direction,
                parts: ScatterParts::default(),
            });
        }
        if rebuild {
            self.tentatives.truncate(self.levels.len());
        }
        let a = operator.view(matrix);
        self.coarse_rhs = vec![0.0; a.nrows()];
        self.coarse_nonzeros = a.val().len();
        self.coarsest = factorise(a, symmetric)?;
        if self.keep_hierarchy {
            // the hierarchy serves the whole load step and a new pattern rebuilds the
            // aggregates anyway: the tentative prolongators (~24 bytes per 2D point) are not
            // needed again
            self.tentatives = Vec::new();
        }
        Ok(())
    }
}

impl Preconditioner for Multigrid {
    fn setup(&mut self, matrix: &SparseMatrix, symmetric: bool) -> Result<(), LinearSolveError> {
        let result = self.build(matrix, symmetric);
        if result.is_err() {
            // what a failed setup left is not a hierarchy: the next one starts afresh
            self.key = NO_PATTERN;
            self.tentatives.clear();
        }
        result
    }

    fn hierarchy(&self) -> Option<Hierarchy> {
        Some(self.sizes())
    }

    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        let scaling = &self.scaling;
        let scale = |from: &[f64], to: &mut [f64]| {
            vectors::update(to, |range, to| {
                for ((to, from), s) in to.iter_mut().zip(&from[range.clone()]).zip(&scaling[range])
                {
                    *to = from * s;
                }
            });
        };
        let smoother = self.smoother;
        let Some(first) = self.levels.first_mut() else {
            scale(r, &mut self.coarse_rhs);
            self.coarsest.solve(&mut self.coarse_rhs);
            scale(&self.coarse_rhs, z);
            return;
        };
        scale(r, &mut first.b);
        let count = self.levels.len();
        // down: pre-smooth, restrict the residual
        for l in 0..count {
            let (head, tail) = self.levels.split_at_mut(l + 1);
            let level = &mut head[l];
            level.smooth(smoother, Direction::ForwardFromZero);
            level.residual();
            let next_b = match tail.first_mut() {
                Some(next) => &mut next.b,
                None => &mut self.coarse_rhs,
            };
            restrict(level.prolongation.as_ref(), &level.r, next_b);
        }
        self.coarsest.solve(&mut self.coarse_rhs);
        // up: correct, post-smooth
        for l in (0..count).rev() {
            let (head, tail) = self.levels.split_at_mut(l + 1);
            let level = &mut head[l];
            let correction = match tail.first() {
                Some(next) => &next.x,
                None => &self.coarse_rhs,
            };
            prolong_add(
                level.prolongation.as_ref(),
                correction,
                &mut level.x,
                &mut level.parts,
            );
            level.smooth(smoother, Direction::Backward);
        }
        scale(&self.levels[0].x, z);
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Direction {
    /// Forward, from `x = 0`.
    ForwardFromZero,
    Backward,
}

impl Level {
    /// Smooths `A x = b` before (`ForwardFromZero`) or after (`Backward`) the coarse
    /// correction.
    fn smooth(&mut self, smoother: Smoother, direction: Direction) {
        match smoother {
            Smoother::GaussSeidel => self.sweep(direction),
            Smoother::Chebyshev(degree) => {
                self.chebyshev(degree, direction == Direction::ForwardFromZero)
            }
        }
    }

    /// `degree` steps of Chebyshev's iteration on `A x = b` preconditioned by `D`, for the
    /// eigenvalues of `D⁻¹A` in `[λ/30, λ]`, `λ = 1.1 ρ` (`ρ` the power-iteration estimate,
    /// which is below the true radius): the error's components with eigenvalues in that
    /// interval — the ones the coarse levels cannot represent — are damped by the Chebyshev
    /// polynomial's bound (Saad, *Iterative Methods for Sparse Linear Systems*, algorithm
    /// 12.1; the interval as PETSc's and Trilinos' defaults). From `x = 0` the first step
    /// needs no product.
    fn chebyshev(&mut self, degree: usize, from_zero: bool) {
        let upper = 1.1 * self.radius;
        let lower = upper / 30.0;
        let (theta, delta) = (0.5 * (upper + lower), 0.5 * (upper - lower));
        let sigma = theta / delta;
        let mut rho = 1.0 / sigma;
        let (row_ptr, col_idx, values) = self.rows.parts();
        let (x, b, r, d) = (&mut self.x, &self.b, &mut self.r, &mut self.direction);
        let inverse_diagonal = &self.inverse_diagonal;
        // r = b − A x
        let residual = |x: &[f64], r: &mut [f64]| {
            vectors::gather(row_ptr, col_idx, values, x, r);
            vectors::update(r, |range, r| {
                for (r, b) in r.iter_mut().zip(&b[range]) {
                    *r = b - *r;
                }
            });
        };
        if from_zero {
            r.copy_from_slice(b);
        } else {
            residual(x, r);
        }
        // d = D⁻¹ r / θ, x += d
        vectors::update(d, |range, d| {
            for ((d, r), m) in d
                .iter_mut()
                .zip(&r[range.clone()])
                .zip(&inverse_diagonal[range])
            {
                *d = r * m / theta;
            }
        });
        if from_zero {
            x.copy_from_slice(d);
        } else {
            add(x, d);
        }
        for _ in 1..degree.max(1) {
            let rho_next = 1.0 / (2.0 * sigma - rho);
            residual(x, r);
            // d = ρ' ρ d + (2 ρ' / δ) D⁻¹ r
            let (keep, push) = (rho_next * rho, 2.0 * rho_next / delta);
            vectors::update(d, |range, d| {
                for ((d, r), m) in d
                    .iter_mut()
                    .zip(&r[range.clone()])
                    .zip(&inverse_diagonal[range])
                {
                    *d = keep * *d + push * r * m;
                }
            });
            add(x, d);
            rho = rho_next;
        }
    }

    /// One Gauss–Seidel sweep on `A x = b`.
    fn sweep(&mut self, direction: Direction) {
        let (row_ptr, col_idx, values) = self.rows.parts();
        let n = self.x.len();
        let x = &mut self.x;
        let (b, inverse_diagonal) = (&self.b, &self.inverse_diagonal);
        match direction {
            // x = 0 before the sweep: the entries at and above the diagonal multiply zeros
            Direction::ForwardFromZero => {
                for i in 0..n {
                    let row = row_ptr[i]..self.diagonal[i];
                    let s = b[i] - sparse_dot(&values[row.clone()], &col_idx[row], x);
                    x[i] = s * inverse_diagonal[i];
                }
            }
            Direction::Backward => {
                for i in (0..n).rev() {
                    let row = row_ptr[i]..row_ptr[i + 1];
                    let s = b[i] - sparse_dot(&values[row.clone()], &col_idx[row], x);
                    x[i] += s * inverse_diagonal[i];
                }
            }
        }
    }

    /// `r = b − A x`.
    fn residual(&mut self) {
        let (row_ptr, col_idx, values) = self.rows.parts();
        vectors::gather(row_ptr, col_idx, values, &self.x, &mut self.r);
        let b = &self.b;
        vectors::update(&mut self.r, |range, r| {
            for (r, b) in r.iter_mut().zip(&b[range]) {
                *r = b - *r;
            }
        });
    }
}

impl Coarsest {
    fn solve(&self, rhs: &mut [f64]) {
        let n = rhs.len();
        let column = MatMut::from_column_major_slice_mut(rhs, n, 1);
        match self {
            Coarsest::Empty => {}
            Coarsest::Cholesky(llt) => llt.solve_in_place_with_conj(Conj::No, column),
            Coarsest::Lu(lu) => lu.solve_in_place_with_conj(Conj::No, column),
        }
    }
}

/// `x += y` on the threads.
fn add(x: &mut [f64], y: &[f64]) {
    vectors::update(x, |range, x| {
        for (x, y) in x.iter_mut().zip(&y[range]) {
            *x += y;
        }
    });
}

/// `y = Pᵀ r` (a gather along `P`'s columns, on the threads).
fn restrict(p: SparseColMatRef<'_, usize, f64>, r: &[f64], y: &mut [f64]) {
    vectors::gather(
        p.symbolic().col_ptr(),
        p.symbolic().row_idx(),
        p.val(),
        r,
        y,
    );
}

/// `x += P e` (a scatter along `P`'s columns, on the threads).
fn prolong_add(
    p: SparseColMatRef<'_, usize, f64>,
    e: &[f64],
    x: &mut [f64],
    parts: &mut ScatterParts,
) {
    vectors::scatter_add(
        p.symbolic().col_ptr(),
        p.symbolic().row_idx(),
        p.val(),
        e,
        x,
        parts,
    );
}

fn out_of_memory(what: &str) -> LinearSolveError {
    LinearSolveError::Singular(format!("multigrid setup ran out of memory ({what})"))
}

/// The values of `S K S` with `S = diag(|K_ii|^(-1/2))` (so unit diagonal), on `K`'s pattern;
/// `scaling` becomes `S`. A zero or non-finite diagonal entry is an error.
fn scale_symmetrically(
    matrix: &SparseMatrix,
    scaling: &mut Vec<f64>,
) -> Result<Vec<f64>, LinearSolveError> {
    let (col_ptr, row_idx) = matrix.pattern();
    let values = matrix.values();
    scaling.clear();
    for col in 0..matrix.size() {
        let diagonal = (col_ptr[col]..col_ptr[col + 1])
            .find(|&k| row_idx[k] == col)
            .map_or(0.0, |k| values[k]);
        if diagonal == 0.0 || !diagonal.is_finite() {
            return Err(LinearSolveError::Singular(format!(
                "zero or non-finite diagonal entry {diagonal} at DOF {col}"
            )));
        }
        scaling.push(1.0 / diagonal.abs().sqrt());
    }
    let mut scaled = Vec::with_capacity(values.len());
    for col in 0..matrix.size() {
        for k in col_ptr[col]..col_ptr[col + 1] {
            scaled.push(values[k] * scaling[row_idx[k]] * scaling[col]);
        }
    }
    Ok(scaled)
}

/// A level's operator by columns while the hierarchy is built: the finest's values on the
/// tangent's pattern, or a coarse level's own matrix.
enum Operator {
    Fine(Vec<f64>),
    Coarse(SparseColMat<usize, f64>),
}

impl Operator {
    fn view<'a>(&'a self, matrix: &'a SparseMatrix) -> SparseColMatRef<'a, usize, f64> {
        match self {
            Operator::Fine(values) => {
                let (col_ptr, row_idx) = matrix.pattern();
                let n = matrix.size();
                let pattern = SymbolicSparseColMatRef::new_checked(n, n, col_ptr, None, row_idx);
                SparseColMatRef::new(pattern, values)
            }
            Operator::Coarse(a) => a.as_ref(),
        }
    }
}

/// The inverse diagonal of `a` and where each column's diagonal entry is in its values; a
/// zero or non-finite diagonal is an error.
fn diagonal_of(
    a: SparseColMatRef<'_, usize, f64>,
    level: usize,
) -> Result<(Vec<f64>, Vec<usize>), LinearSolveError> {
    let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    let mut inverse = Vec::with_capacity(a.nrows());
    let mut positions = Vec::with_capacity(a.nrows());
    for j in 0..a.ncols() {
        let position = (col_ptr[j]..col_ptr[j + 1]).find(|&k| row_idx[k] == j);
        let diagonal = position.map_or(0.0, |k| values[k]);
        if diagonal == 0.0 || !diagonal.is_finite() {
            return Err(LinearSolveError::Singular(format!(
                "zero or non-finite diagonal entry {diagonal} at DOF {j} (multigrid level {level})"
            )));
        }
        inverse.push(1.0 / diagonal);
        positions.push(position.unwrap_or(col_ptr[j]));
    }
    Ok((inverse, positions))
}

/// The operator by rows (the smoother reads rows, with sorted columns) and where each row's
/// diagonal entry is. A symmetric operator whose columns are sorted is taken as it is: its
/// columns are its rows (`Aᵀ = A`, to round-off), with no copy and the diagonal where
/// [`diagonal_of`] found it (the finest level's pattern stays shared with the tangent's);
/// otherwise it is transposed (faer's transposition leaves each row's columns sorted).
fn by_rows(
    operator: Operator,
    matrix: &SparseMatrix,
    symmetric: bool,
    diagonal: Vec<usize>,
) -> Result<(Rows, Vec<usize>), LinearSolveError> {
    let sorted = {
        let a = operator.view(matrix);
        let (col_ptr, row_idx) = (a.symbolic().col_ptr(), a.symbolic().row_idx());
        a.symbolic().col_nnz().is_none()
            && (0..a.ncols()).all(|j| row_idx[col_ptr[j]..col_ptr[j + 1]].is_sorted())
    };
    if symmetric && sorted {
        let rows = match operator {
            Operator::Fine(values) => {
                let (col_ptr, row_idx) = matrix.shared_pattern();
                Rows {
                    row_ptr: col_ptr,
                    col_idx: row_idx,
                    values,
                }
            }
            Operator::Coarse(a) => {
                // its columns, read as its rows
                let (symbolic, values) = a.into_parts();
                let (_, _, col_ptr, _, row_idx) = symbolic.into_parts();
                Rows::owned(col_ptr, row_idx, values)
            }
        };
        return Ok((rows, diagonal));
    }
    let rows = operator
        .view(matrix)
        .to_row_major()
        .map_err(|_| out_of_memory("operator by rows"))?;
    let (row_ptr, col_idx) = (rows.symbolic().row_ptr(), rows.symbolic().col_idx());
    let positions = (0..rows.nrows())
        .map(|i| {
            (row_ptr[i]..row_ptr[i + 1])
                .find(|&k| col_idx[k] == i)
                .unwrap_or(row_ptr[i])
        })
        .collect();
    Ok((Rows::from_faer(rows), positions))
}

/// An estimate of the spectral radius `ρ` of `D⁻¹A`, from below: the smoothed prolongator's
/// weight `ω = 4 / (3ρ)` and the Chebyshev smoother's interval `[λ/30, λ]`, `λ = 1.1 ρ`, rest
/// on it, and an estimate much below `ρ` ruins both (Chebyshev's polynomial grows outside its
/// interval, and `I − ω D⁻¹A` amplifies the modes above `4/(3ω)`).
///
/// For a symmetric `A` with a positive diagonal (every level of an elastic tangent), `D⁻¹A`
/// is similar to the symmetric `C = D^{-1/2} A D^{-1/2}`, and [`LANCZOS_STEPS`] steps of
/// Lanczos on `C` give the tridiagonal `T_k` whose largest eigenvalue (a Ritz value) converges
/// to `ρ` far faster than power iterations do: measured on the 2D self-weight block at 200
/// cells (81 002 DOFs), 15 power iterations left the estimate low enough that CG needed
/// 108, 105, 102 iterations per Newton iteration against 19 at 100 and 400 cells; 60 power
/// iterations, or Lanczos, give 19. Otherwise power iterations (with `Aᵀ` for a symmetric `A`:
/// its columns, a gather).
fn spectral_radius(
    a: SparseColMatRef<'_, usize, f64>,
    inverse_diagonal: &[f64],
    symmetric: bool,
) -> f64 {
    if symmetric && inverse_diagonal.iter().all(|&d| d > 0.0 && d.is_finite()) {
        lanczos_radius(a, inverse_diagonal)
    } else {
        power_radius(a, inverse_diagonal, symmetric)
    }
}

/// Lanczos steps of [`lanczos_radius`].
const LANCZOS_STEPS: usize = 20;

/// A fixed, non-smooth start vector, so that runs repeat exactly.
fn start_vector(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| 1.0 + ((i * 7919) % 101) as f64 / 101.0)
        .collect()
}

/// The largest Ritz value of [`LANCZOS_STEPS`] Lanczos steps on `D^{-1/2} A D^{-1/2}` for a
/// symmetric `A` (see [`spectral_radius`]): with `q_0` the normalised start, `w = C q_j −
/// β_j q_{j−1}`, `α_j = q_j · w`, `w −= α_j q_j`, `β_{j+1} = ‖w‖`, `q_{j+1} = w / β_{j+1}`;
/// the eigenvalues of the tridiagonal matrix of the `α` and `β` lie inside `C`'s spectrum
/// and the largest approaches `ρ` from below. No reorthogonalisation: its loss only repeats
/// converged Ritz values. Every reduction is [`vectors::dot`]'s, so the estimate is the same
/// for any thread count.
fn lanczos_radius(a: SparseColMatRef<'_, usize, f64>, inverse_diagonal: &[f64]) -> f64 {
    let n = inverse_diagonal.len();
    let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    let scale: Vec<f64> = inverse_diagonal.iter().map(|d| d.sqrt()).collect();
    let mut q = start_vector(n);
    let size = vectors::norm(&q);
    if n == 0 || size == 0.0 {
        return 1.0;
    }
    vectors::update(&mut q, |_, q| q.iter_mut().for_each(|v| *v /= size));
    let mut previous = vec![0.0; n];
    let mut scaled = vec![0.0; n];
    let mut w = vec![0.0; n];
    let (mut alpha, mut beta) = (Vec::new(), Vec::new());
    for _ in 0..LANCZOS_STEPS.min(n) {
        // w = S A S q − β q_prev, S = D^{-1/2}
        vectors::update(&mut scaled, |range, x| {
            for ((x, q), s) in x.iter_mut().zip(&q[range.clone()]).zip(&scale[range]) {
                *x = q * s;
            }
        });
        vectors::gather(col_ptr, row_idx, values, &scaled, &mut w);
        let last_beta = beta.last().copied().unwrap_or(0.0);
        vectors::update(&mut w, |range, w| {
            for ((w, s), p) in w
                .iter_mut()
                .zip(&scale[range.clone()])
                .zip(&previous[range])
            {
                *w = *w * s - last_beta * p;
            }
        });
        let a_j = vectors::dot(&q, &w);
        if !a_j.is_finite() {
            break;
        }
        alpha.push(a_j);
        vectors::update(&mut w, |range, w| {
            for (w, q) in w.iter_mut().zip(&q[range]) {
                *w -= a_j * q;
            }
        });
        let b = vectors::norm(&w);
        if b.is_nan() || b <= 1e-14 * a_j.abs() {
            break;
        }
        beta.push(b);
        std::mem::swap(&mut previous, &mut q);
        vectors::update(&mut q, |range, q| {
            for (q, w) in q.iter_mut().zip(&w[range]) {
                *q = w / b;
            }
        });
    }
    let k = alpha.len();
    if k == 0 {
        return power_radius(a, inverse_diagonal, true);
    }
    let tridiagonal = nalgebra::DMatrix::from_fn(k, k, |i, j| match i.abs_diff(j) {
        0 => alpha[i],
        1 => beta[i.min(j)],
        _ => 0.0,
    });
    let largest = tridiagonal
        .symmetric_eigenvalues()
        .iter()
        .fold(f64::NEG_INFINITY, |m, &l| m.max(l));
    if largest > 0.0 && largest.is_finite() {
        largest
    } else {
        power_radius(a, inverse_diagonal, true)
    }
}

/// An estimate of the spectral radius of `D⁻¹A` by power iterations (with `Aᵀ` for a
/// symmetric `A`: its columns, a gather): for non-symmetric tangents.
fn power_radius(
    a: SparseColMatRef<'_, usize, f64>,
    inverse_diagonal: &[f64],
    symmetric: bool,
) -> f64 {
    let n = inverse_diagonal.len();
    let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    let mut parts = ScatterParts::default();
    let mut v = start_vector(n);
    let mut w = vec![0.0; n];
    let mut radius = 1.0;
    for _ in 0..POWER_ITERATIONS {
        let size = vectors::norm(&v);
        if symmetric {
            vectors::gather(col_ptr, row_idx, values, &v, &mut w);
        } else {
            w.fill(0.0);
            vectors::scatter_add(col_ptr, row_idx, values, &v, &mut w, &mut parts);
        }
        vectors::update(&mut w, |range, w| {
            for (w, d) in w.iter_mut().zip(&inverse_diagonal[range]) {
                *w *= d;
            }
        });
        let grown = vectors::norm(&w);
        if grown == 0.0 || !grown.is_finite() || size == 0.0 {
            break;
        }
        radius = grown / size;
        vectors::update(&mut v, |range, v| {
            for (v, w) in v.iter_mut().zip(&w[range]) {
                *v = w / grown;
            }
        });
    }
    radius
}

/// `P = (I − ω D⁻¹ A) T`, made in place on `A T`'s values: `P` has `A T`'s pattern (`A`'s
/// diagonal is present, checked by [`diagonal_of`], so every entry of `T` is one of `A T`'s),
/// each column's rows sorted. No triplets are built: they took 24 bytes per entry of `P`
/// (with the sort's buffers, ~230 bytes per 2D point at q = 2, the setup's peak). The values
/// are the ones the triplets gave (`−ω d_i (A T)_ij`, plus `T_ij` where `T` has an entry).
fn smooth_prolongator(
    a: SparseColMatRef<'_, usize, f64>,
    tentative: SparseColMatRef<'_, usize, f64>,
    inverse_diagonal: &[f64],
    omega: f64,
) -> Result<SparseColMat<usize, f64>, LinearSolveError> {
    let at =
        sparse_sparse_matmul(a, tentative, 1.0, Par::rayon(0)).map_err(|_| out_of_memory("A T"))?;
    let (symbolic, mut values) = at.into_parts();
    let (nrows, ncols, col_ptr, col_nnz, mut row_idx) = symbolic.into_parts();
    let (t_ptr, t_idx, t_val) = (
        tentative.symbolic().col_ptr(),
        tentative.symbolic().row_idx(),
        tentative.val(),
    );
    let mut column: Vec<(usize, f64)> = Vec::new();
    for j in 0..ncols {
        let start = col_ptr[j];
        let end = col_nnz
            .as_ref()
            .map_or(col_ptr[j + 1], |nnz| start + nnz[j]);
        let (rows, column_values) = (&mut row_idx[start..end], &mut values[start..end]);
        if !rows.is_sorted() {
            column.clear();
            column.extend(rows.iter().copied().zip(column_values.iter().copied()));
            column.sort_unstable_by_key(|&(i, _)| i);
            for ((row, value), (i, v)) in rows.iter_mut().zip(column_values.iter_mut()).zip(&column)
            {
                (*row, *value) = (*i, *v);
            }
        }
        for (value, &i) in column_values.iter_mut().zip(rows.iter()) {
            *value *= -omega * inverse_diagonal[i];
        }
        for k in t_ptr[j]..t_ptr[j + 1] {
            let Ok(at) = rows.binary_search(&t_idx[k]) else {
                return Err(LinearSolveError::Singular(format!(
                    "multigrid: the tentative prolongator's entry ({}, {j}) is not in A T",
                    t_idx[k]
                )));
            };
            column_values[at] += t_val[k];
        }
    }
    // the product's vectors grew by doubling: P is kept for the load step
    row_idx.shrink_to_fit();
    values.shrink_to_fit();
    let symbolic = SymbolicSparseColMat::new_checked(nrows, ncols, col_ptr, col_nnz, row_idx);
    Ok(SparseColMat::new(symbolic, values))
}

/// Column blocks of `P` in which [`galerkin_product`] forms `A P`.
const GALERKIN_BLOCKS: usize = 16;

/// `C = Pᵀ A P`, a block `J` of `P`'s columns at a time, without forming `Pᵀ`:
///
/// ```text
/// W_J = A P_J,    C_J = Pᵀ W_J = (W_Jᵀ P)ᵀ,    (W_Jᵀ P)_ji = Σ_r W_rj P_ri,
/// ```
///
/// so only the block's `W_J` and `W_Jᵀ` (1/16 of `A P`, which has as many entries as `P`:
/// ~130 bytes per 2D point at q = 2) and the block's rows of `C` are held beside `P`; the
/// transpose `Pᵀ` (another ~130 bytes per point) is not formed. No symmetry of `A` is used.
/// The sums are the ones `Pᵀ (A P)` takes, term for term and in the same order (a sparse
/// product sums, for each entry, over the shared index `r` in increasing order: the rows of
/// `W_j` there, the rows of `P_i` here, both sorted), so `C` is bit for bit the whole product
/// (unit tests). Each column block of `C` comes out with its rows sorted.
fn galerkin_product(
    a: SparseColMatRef<'_, usize, f64>,
    p: SparseColMatRef<'_, usize, f64>,
) -> Result<SparseColMat<usize, f64>, LinearSolveError> {
    let (p_ptr, p_idx, p_val) = (p.symbolic().col_ptr(), p.symbolic().row_idx(), p.val());
    let (rows, columns) = (p.ncols(), p.ncols());
    let mut col_ptr = vec![0usize; columns + 1];
    let (mut row_idx, mut values) = (Vec::new(), Vec::new());
    let width = columns.div_ceil(GALERKIN_BLOCKS).max(1);
    for first in (0..columns).step_by(width) {
        let last = (first + width).min(columns);
        let (start, end) = (p_ptr[first], p_ptr[last]);
        let block_ptr: Vec<usize> = p_ptr[first..=last].iter().map(|k| k - start).collect();
        let block = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(
                p.nrows(),
                last - first,
                &block_ptr,
                None,
                &p_idx[start..end],
            ),
            &p_val[start..end],
        );
        let ap =
            sparse_sparse_matmul(a, block, 1.0, Par::rayon(0)).map_err(|_| out_of_memory("A P"))?;
        let apt = ap
            .as_ref()
            .transpose()
            .to_col_major()
            .map_err(|_| out_of_memory("(A P)ᵀ"))?;
        drop(ap);
        let ct = sparse_sparse_matmul(apt.as_ref(), p, 1.0, Par::rayon(0))
            .map_err(|_| out_of_memory("(A P)ᵀ P"))?;
        drop(apt);
        let c = ct
            .as_ref()
            .transpose()
            .to_col_major()
            .map_err(|_| out_of_memory("Pᵀ A P"))?;
        let c_ptr = c.symbolic().col_ptr();
        for j in 0..last - first {
            col_ptr[first + j + 1] = row_idx.len() + c_ptr[j + 1];
        }
        row_idx.extend_from_slice(c.symbolic().row_idx());
        values.extend_from_slice(c.val());
    }
    // grown by doubling: the operator is kept for the load step
    row_idx.shrink_to_fit();
    values.shrink_to_fit();
    let symbolic = SymbolicSparseColMat::new_checked(rows, columns, col_ptr, None, row_idx);
    Ok(SparseColMat::new(symbolic, values))
}

/// Factorises the coarsest operator.
fn factorise(
    a: SparseColMatRef<'_, usize, f64>,
    symmetric: bool,
) -> Result<Coarsest, LinearSolveError> {
    if a.nrows() == 0 {
        return Ok(Coarsest::Empty);
    }
    if symmetric
        && let Ok(symbolic) = SymbolicLlt::try_new(a.symbolic(), Side::Lower)
        && let Ok(llt) = Llt::try_new_with_symbolic(symbolic, a, Side::Lower)
    {
        return Ok(Coarsest::Cholesky(llt));
    }
    let symbolic = SymbolicLu::try_new(a.symbolic()).map_err(|e| {
        LinearSolveError::Singular(format!("multigrid: coarsest level analysis failed ({e:?})"))
    })?;
    let lu = Lu::try_new_with_symbolic(symbolic, a).map_err(|e| {
        LinearSolveError::Singular(format!(
            "the coarsest multigrid level ({} DOFs) is singular ({e:?})",
            a.nrows()
        ))
    })?;
    Ok(Coarsest::Lu(Box::new(lu)))
}

/// Groups of DOFs aggregated as one (a node's components; an aggregate's coarse DOFs).
#[derive(Default)]
struct Blocks {
    /// Block `b` is DOFs `start[b]..start[b + 1]`.
    start: Vec<usize>,
    /// Each block's integer coordinates on the box lattice of its level (see the module docs);
    /// empty when the positions are not known.
    cell: Vec<[i64; 3]>,
}

/// The finest level's blocks (the nodes) and near-null space: the rigid-body modes when the
/// layout gives positions (translations and the rotations about the centroid, scaled by the
/// extent so that all modes have entries of order one), the translations when it gives
/// components only, and the constant vector, one DOF a block, when it says nothing.
fn fine_blocks_and_modes(layout: &DofLayout, size: usize) -> (Blocks, Vec<Vec<f64>>) {
    if layout.component.len() != size || size == 0 {
        let blocks = Blocks {
            start: (0..=size).collect(),
            cell: Vec::new(),
        };
        return (blocks, vec![vec![1.0; size]]);
    }
    let d = layout.dimension;
    let mut modes: Vec<Vec<f64>> = (0..d)
        .map(|axis| {
            let on_axis = |&c: &u8| if c as usize == axis { 1.0 } else { 0.0 };
            layout.component.iter().map(on_axis).collect()
        })
        .collect();
    let positions = &layout.position;
    if positions.len() + 1 == layout.block_start.len() && !positions.is_empty() {
        let count = positions.len() as f64;
        let centre: [f64; 3] =
            std::array::from_fn(|c| positions.iter().map(|x| x[c]).sum::<f64>() / count);
        let extent = positions
            .iter()
            .flat_map(|x| (0..3).map(move |c| (x[c] - centre[c]).abs()))
            .fold(0.0f64, f64::max)
            .max(f64::MIN_POSITIVE);
        for a in 0..d {
            for b in a + 1..d {
                let mut values = vec![0.0; size];
                for (block, x) in positions.iter().enumerate() {
                    let relative = |c: usize| (x[c] - centre[c]) / extent;
                    let dofs = layout.block_start[block]..layout.block_start[block + 1];
                    for (value, &c) in values[dofs.clone()].iter_mut().zip(&layout.component[dofs])
                    {
                        let c = c as usize;
                        *value = match c {
                            _ if c == a => -relative(b),
                            _ if c == b => relative(a),
                            _ => 0.0,
                        };
                    }
                }
                modes.push(values);
            }
        }
    }
    let blocks = Blocks {
        start: layout.block_start.clone(),
        cell: if positions.len() + 1 == layout.block_start.len() {
            lattice_coordinates(positions)
        } else {
            Vec::new()
        },
    };
    (blocks, modes)
}

/// Integer coordinates of the positions. Along each axis the distinct coordinates (closer than
/// 1e-9 of the extent are one) are numbered in increasing order: on a structured grid that is
/// the node's index along the axis, whatever the spacing (a B-spline grid's Greville points
/// are `h/2` apart at its ends and `h` inside). When the positions are not on a lattice (the
/// distinct coordinates would span far more lattice points than there are nodes: a mesh),
/// `round((x − x_min) / h)` instead, with `h = (Π extents / nodes)^(1/d)` the side of the
/// volume per node (over the `d` axes with an extent): the gaps between distinct coordinates
/// do not give it, as most are the small offsets between nodes of one row of a mesh.
fn lattice_coordinates(positions: &[[f64; 3]]) -> Vec<[i64; 3]> {
    let mut distinct: Vec<Vec<f64>> = Vec::with_capacity(3);
    for axis in 0..3 {
        let mut values: Vec<f64> = positions.iter().map(|x| x[axis]).collect();
        values.sort_unstable_by(f64::total_cmp);
        let extent = values.last().unwrap_or(&0.0) - values.first().unwrap_or(&0.0);
        let tolerance = 1e-9 * extent.abs().max(f64::MIN_POSITIVE);
        values.dedup_by(|b, a| *b - *a <= tolerance);
        distinct.push(values);
    }
    let span: f64 = distinct.iter().map(|v| v.len() as f64).product();
    let on_lattice = span <= 8.0 * positions.len() as f64;
    let extents: Vec<f64> = distinct
        .iter()
        .filter(|v| v.len() > 1)
        .map(|v| v[v.len() - 1] - v[0])
        .collect();
    let spacing = if extents.is_empty() {
        1.0
    } else {
        (extents.iter().product::<f64>() / positions.len() as f64).powf(1.0 / extents.len() as f64)
    };
    let index = |axis: usize, x: f64| -> i64 {
        let values = &distinct[axis];
        if on_lattice {
            // the nearest distinct value's rank
            let above = values.partition_point(|&v| v < x);
            let nearer_below =
                above > 0 && (above == values.len() || x - values[above - 1] <= values[above] - x);
            (if nearer_below { above - 1 } else { above }) as i64
        } else {
            ((x - values[0]) / spacing).round() as i64
        }
    };
    positions
        .iter()
        .map(|x| std::array::from_fn(|c| index(c, x[c])))
        .collect()
}

/// Box aggregation (see the module docs): the blocks whose coordinates divided by `width`
/// agree form one aggregate, numbered in the order of their first block. Returns the
/// aggregate of each block, the number of aggregates and each one's coordinates.
fn box_aggregates(cells: &[[i64; 3]], width: usize) -> (Vec<usize>, usize, Vec<[i64; 3]>) {
    let width = width.max(2) as i64;
    let mut number = std::collections::HashMap::with_capacity(cells.len());
    let mut coarse = Vec::new();
    let of = cells
        .iter()
        .map(|k| {
            let key: [i64; 3] = std::array::from_fn(|c| k[c].div_euclid(width));
            *number.entry(key).or_insert_with(|| {
                coarse.push(key);
                coarse.len() - 1
            })
        })
        .collect();
    (of, coarse.len(), coarse)
}

/// The strong neighbours of each block with their strength (larger is stronger), for the
/// algebraic aggregation (positions not known).
fn strong_neighbours(
    a: SparseColMatRef<'_, usize, f64>,
    blocks: &Blocks,
) -> Vec<Vec<(usize, f64)>> {
    let count = blocks.start.len() - 1;
    let mut block_of = vec![0usize; a.nrows()];
    for b in 0..count {
        block_of[blocks.start[b]..blocks.start[b + 1]].fill(b);
    }
    let (col_ptr, row_idx, values) = (a.symbolic().col_ptr(), a.symbolic().row_idx(), a.val());
    // squared Frobenius norms of the diagonal blocks
    let mut own = vec![0.0; count];
    for col in 0..a.ncols() {
        for k in col_ptr[col]..col_ptr[col + 1] {
            if block_of[row_idx[k]] == block_of[col] {
                own[block_of[col]] += values[k] * values[k];
            }
        }
    }
    let mut weight = vec![0.0; count];
    let mut seen = vec![false; count];
    let mut touched = Vec::new();
    let mut strong = Vec::with_capacity(count);
    for block in 0..count {
        touched.clear();
        for col in blocks.start[block]..blocks.start[block + 1] {
            for k in col_ptr[col]..col_ptr[col + 1] {
                let other = block_of[row_idx[k]];
                if other == block {
                    continue;
                }
                if !seen[other] {
                    seen[other] = true;
                    touched.push(other);
                }
                weight[other] += values[k] * values[k];
            }
        }
        let list: Vec<(usize, f64)> = touched
            .iter()
            .map(|&o| {
                (
                    o,
                    (weight[o] / (own[block] * own[o]).sqrt().max(f64::MIN_POSITIVE)).sqrt(),
                )
            })
            .filter(|&(_, s)| s >= STRENGTH_THRESHOLD)
            .collect();
        for &o in &touched {
            seen[o] = false;
            weight[o] = 0.0;
        }
        strong.push(list);
    }
    strong
}

const FREE: usize = usize::MAX;

/// Greedy aggregation of the blocks (see the module docs): the aggregate of each block and the
/// number of aggregates.
fn aggregates(strong: &[Vec<(usize, f64)>]) -> (Vec<usize>, usize) {
    let mut of = vec![FREE; strong.len()];
    let mut count = 0;
    for (block, neighbours) in strong.iter().enumerate() {
        if of[block] == FREE && neighbours.iter().all(|&(o, _)| of[o] == FREE) {
            of[block] = count;
            for &(o, _) in neighbours {
                of[o] = count;
            }
            count += 1;
        }
    }
    let first_pass = of.clone();
    for (block, neighbours) in strong.iter().enumerate() {
        if of[block] == FREE
            && let Some(&(o, _)) = neighbours
                .iter()
                .filter(|&&(o, _)| first_pass[o] != FREE)
                .max_by(|a, b| a.1.total_cmp(&b.1))
        {
            of[block] = first_pass[o];
        }
    }
    for (block, neighbours) in strong.iter().enumerate() {
        if of[block] == FREE {
            of[block] = count;
            for &(o, _) in neighbours {
                if of[o] == FREE {
                    of[o] = count;
                }
            }
            count += 1;
        }
    }
    (of, count)
}

/// One coarsening: the tentative prolongator, the coarse blocks and the coarse near-null space.
type Coarsening = (SparseColMat<usize, f64>, Blocks, Vec<Vec<f64>>);

/// One coarsening (see [`Coarsening`]); `None` if the level would not get smaller.
fn aggregate(
    a: SparseColMatRef<'_, usize, f64>,
    blocks: &Blocks,
    near_null: &[Vec<f64>],
    width: usize,
) -> Option<Coarsening> {
    let (of, count, cells) = if blocks.cell.is_empty() {
        let (of, count) = aggregates(&strong_neighbours(a, blocks));
        (of, count, Vec::new())
    } else {
        box_aggregates(&blocks.cell, width)
    };
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); count];
    for (block, &g) in of.iter().enumerate() {
        members[g].push(block);
    }
    let k = near_null.len();
    let mut entries = Vec::new();
    let mut coarse_start = vec![0];
    let mut coarse_rows: Vec<Vec<f64>> = Vec::new(); // R_g rows, one per coarse DOF
    let mut dofs = Vec::new();
    for group in &members {
        dofs.clear();
        for &b in group {
            dofs.extend(blocks.start[b]..blocks.start[b + 1]);
        }
        // Gram–Schmidt (twice) of the near-null space's rows on these DOFs
        let mut q: Vec<Vec<f64>> = Vec::new();
        let mut r: Vec<Vec<f64>> = Vec::new(); // r[i][c]: coefficient of q_i in column c
        for (c, mode) in near_null.iter().enumerate() {
            let mut v: Vec<f64> = dofs.iter().map(|&i| mode[i]).collect();
            let original = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            for _ in 0..2 {
                for (qi, ri) in q.iter().zip(r.iter_mut()) {
                    let projection: f64 = qi.iter().zip(&v).map(|(a, b)| a * b).sum();
                    ri[c] += projection;
                    for (v, q) in v.iter_mut().zip(qi) {
                        *v -= projection * q;
                    }
                }
            }
            let left = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            if original > 0.0 && left > 1e-8 * original {
                v.iter_mut().for_each(|x| *x /= left);
                let mut row = vec![0.0; k];
                row[c] = left;
                q.push(v);
                r.push(row);
            }
        }
        let offset = coarse_rows.len();
        for (i, qi) in q.iter().enumerate() {
            for (&dof, &value) in dofs.iter().zip(qi) {
                entries.push(Triplet::new(dof, offset + i, value));
            }
        }
        coarse_rows.extend(r);
        coarse_start.push(coarse_rows.len());
    }
    // aggregates without coarse DOFs (the near-null space vanishes on them) are dropped
    let size = coarse_rows.len();
    if size == 0 || size >= a.nrows() {
        return None;
    }
    let mut kept = Blocks {
        start: vec![0],
        cell: Vec::new(),
    };
    for g in 0..count {
        if coarse_start[g + 1] > coarse_start[g] {
            kept.start.push(coarse_start[g + 1]);
            if let Some(&cell) = cells.get(g) {
                kept.cell.push(cell);
            }
        }
    }
    let tentative = SparseColMat::try_new_from_triplets(a.nrows(), size, &entries).ok()?;
    let modes = (0..k)
        .map(|c| coarse_rows.iter().map(|row| row[c]).collect())
        .collect();
    Some((tentative, kept, modes))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pattern of a 2D grid of `nx` x `ny` nodes, 2 DOFs each, with nearest-neighbour
    /// (9-point) coupling, and its cells' nodes (the supports).
    fn grid_pattern(nx: usize, ny: usize) -> (SparseMatrix, Vec<Vec<usize>>) {
        let nodes = nx * ny;
        let dofs: Vec<[u32; 2]> = (0..nodes)
            .map(|i| [2 * i as u32, 2 * i as u32 + 1])
            .collect();
        let mut supports = Vec::new();
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let n = |a: usize, b: usize| (i + a) + nx * (j + b);
                supports.push(vec![n(0, 0), n(1, 0), n(0, 1), n(1, 1)]);
            }
        }
        let mut matrix = SparseMatrix::default();
        matrix.rebuild_pattern(2 * nodes, &dofs[..], supports.iter().map(|s| s.as_slice()));
        matrix.set_node_positions(|n| nalgebra::Vector2::new((n % nx) as f64, (n / nx) as f64));
        (matrix, supports)
    }

    /// The tentative prolongator reproduces the near-null space exactly: `T B_c = B`, and its
    /// columns are orthonormal.
    #[test]
    fn the_tentative_prolongator_reproduces_the_rigid_body_modes() {
        // a 2D grid of 6 x 5 nodes, 2 DOFs each, nearest-neighbour (9-point) coupling
        let (mut matrix, _) = grid_pattern(6, 5);
        let nodes = matrix.size() / 2;
        for k in 0..2 * nodes {
            matrix.add(k as u32, k as u32, 1.0);
        }
        let (blocks, modes) = fine_blocks_and_modes(matrix.layout(), matrix.size());
        assert_eq!(modes.len(), 3);
        let (t, coarse, coarse_modes) = aggregate(matrix.matrix(), &blocks, &modes, 3).unwrap();
        assert!(t.ncols() < matrix.size() && t.ncols() == *coarse.start.last().unwrap());
        for (fine, coarse) in modes.iter().zip(&coarse_modes) {
            let mut product = vec![0.0; matrix.size()];
            prolong_add(
                t.as_ref(),
                coarse,
                &mut product,
                &mut ScatterParts::default(),
            );
            let error = product
                .iter()
                .zip(fine)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(error < 1e-12, "T B_c - B = {error:e}");
        }
        let tt = galerkin_product(
            SparseColMat::<usize, f64>::try_new_from_triplets(
                matrix.size(),
                matrix.size(),
                &(0..matrix.size())
                    .map(|i| Triplet::new(i, i, 1.0))
                    .collect::<Vec<_>>(),
            )
            .unwrap()
            .as_ref(),
            t.as_ref(),
        )
        .unwrap()
        .to_dense();
        for i in 0..t.ncols() {
            for j in 0..t.ncols() {
                let expected = if i == j { 1.0 } else { 0.0 };
                assert!((tt[(i, j)] - expected).abs() < 1e-12, "TᵀT[{i},{j}]");
            }
        }
    }

    /// A diagonally dominant operator on [`grid_pattern`]'s `nx` x `ny` grid, symmetric or,
    /// with `skew`, not (a skew part added off the diagonal).
    fn grid_operator(nx: usize, ny: usize, skew: f64) -> SparseMatrix {
        let (mut matrix, supports) = grid_pattern(nx, ny);
        for support in &supports {
            for &m in support {
                for &n in support {
                    for (a, b) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                        let (r, c) = (2 * m + a, 2 * n + b);
                        let value = if r == c {
                            8.0 + (r % 5) as f64 * 0.37
                        } else {
                            let sign = if r < c { 1.0 } else { -1.0 };
                            -0.1 - ((r.min(c) * 7 + r.max(c) * 3) % 11) as f64 * 0.013
                                + sign * skew * ((r + 2 * c) % 3) as f64
                        };
                        matrix.add(r as u32, c as u32, value);
                    }
                }
            }
        }
        matrix
    }

    /// The spectral radius of `D⁻¹A` for the 5-point Laplacian on an `m × m` interior grid
    /// (Dirichlet), `1 + cos(π / (m + 1))`, whose top eigenvalues cluster (the case that left
    /// 15 power iterations well below `ρ` on a 2D block): the Lanczos estimate within 2 %
    /// below it, and never above it (a Ritz value); the power estimate printed beside it.
    #[test]
    fn lanczos_estimates_the_spectral_radius_of_a_clustered_spectrum() {
        for m in [30usize, 60, 120] {
            let index = |i: usize, j: usize| i * m + j;
            let mut entries = Vec::new();
            for i in 0..m {
                for j in 0..m {
                    entries.push(Triplet::new(index(i, j), index(i, j), 4.0));
                    let neighbours = [
                        (i + 1, j),
                        (i, j + 1),
                        (i.wrapping_sub(1), j),
                        (i, j.wrapping_sub(1)),
                    ];
                    for (k, l) in neighbours {
                        if k < m && l < m {
                            entries.push(Triplet::new(index(i, j), index(k, l), -1.0));
                        }
                    }
                }
            }
            let a =
                SparseColMat::<usize, f64>::try_new_from_triplets(m * m, m * m, &entries).unwrap();
            let inverse_diagonal = vec![0.25; m * m];
            let exact = 1.0 + (std::f64::consts::PI / (m + 1) as f64).cos();
            let lanczos = spectral_radius(a.as_ref(), &inverse_diagonal, true);
            let power = power_radius(a.as_ref(), &inverse_diagonal, true);
            println!(
                "m = {m}: exact {exact:.6}, Lanczos {lanczos:.6}, {POWER_ITERATIONS} power iterations {power:.6}"
            );
            assert!(lanczos <= exact * (1.0 + 1e-12), "{lanczos} above {exact}");
            assert!(
                lanczos >= 0.98 * exact,
                "{lanczos} more than 2 % below {exact}"
            );
        }
    }

    /// The in-place smoothed prolongator and the blocked Galerkin product give, bit for bit,
    /// what the triplets (`P = −ω D⁻¹ A T + T`) and the whole product `Pᵀ (A P)` gave.
    #[test]
    fn the_prolongator_and_galerkin_product_equal_the_whole_products_bit_for_bit() {
        let matrix = grid_operator(13, 11, 0.0);
        let a = matrix.matrix();
        let (blocks, modes) = fine_blocks_and_modes(matrix.layout(), matrix.size());
        let (t, ..) = aggregate(a, &blocks, &modes, 3).unwrap();
        assert!(t.ncols() > 2 * GALERKIN_BLOCKS, "{} coarse DOFs", t.ncols());
        let (inverse_diagonal, _) = diagonal_of(a, 0).unwrap();
        let omega = 4.0 / (3.0 * spectral_radius(a, &inverse_diagonal, true));
        let p = smooth_prolongator(a, t.as_ref(), &inverse_diagonal, omega).unwrap();
        // the reference: triplets summed by faer
        let at = sparse_sparse_matmul(a, t.as_ref(), 1.0, Par::Seq).unwrap();
        let mut entries = Vec::new();
        for (m, scaled) in [(at.as_ref(), true), (t.as_ref(), false)] {
            let (col_ptr, row_idx, values) =
                (m.symbolic().col_ptr(), m.symbolic().row_idx(), m.val());
            for j in 0..m.ncols() {
                for k in col_ptr[j]..col_ptr[j + 1] {
                    let i = row_idx[k];
                    let value = match scaled {
                        true => -omega * inverse_diagonal[i] * values[k],
                        false => values[k],
                    };
                    entries.push(Triplet::new(i, j, value));
                }
            }
        }
        let expected = SparseColMat::try_new_from_triplets(a.nrows(), t.ncols(), &entries).unwrap();
        let parts = |m: SparseColMatRef<'_, usize, f64>| {
            let bits: Vec<u64> = m.val().iter().map(|v| v.to_bits()).collect();
            (
                m.symbolic().col_ptr().to_vec(),
                m.symbolic().row_idx().to_vec(),
                bits,
            )
        };
        assert_eq!(parts(p.as_ref()), parts(expected.as_ref()));
        let c = galerkin_product(a, p.as_ref()).unwrap();
        let ap = sparse_sparse_matmul(a, p.as_ref(), 1.0, Par::Seq).unwrap();
        let pt = p.as_ref().transpose().to_col_major().unwrap();
        let whole = sparse_sparse_matmul(pt.as_ref(), ap.as_ref(), 1.0, Par::Seq).unwrap();
        assert_eq!(parts(c.as_ref()), parts(whole.as_ref()));
    }

    /// The Galerkin product without `Pᵀ` is `Pᵀ A P` formed explicitly (dense `Pᵀ`, `A`, `P`,
    /// multiplied by faer's dense product, which sums in another order), to round-off: every
    /// entry within 1e-14 of the largest, and no entry of the explicit product outside the
    /// sparse one's pattern; for a symmetric `A` and for a non-symmetric one (the product uses
    /// no symmetry).
    #[test]
    fn the_galerkin_product_is_the_explicit_triple_product_to_round_off() {
        for skew in [0.0, 0.03] {
            let matrix = grid_operator(13, 11, skew);
            let a = matrix.matrix();
            let (blocks, modes) = fine_blocks_and_modes(matrix.layout(), matrix.size());
            let (t, ..) = aggregate(a, &blocks, &modes, 3).unwrap();
            let (inverse_diagonal, _) = diagonal_of(a, 0).unwrap();
            let omega = 4.0 / (3.0 * spectral_radius(a, &inverse_diagonal, skew == 0.0));
            let p = smooth_prolongator(a, t.as_ref(), &inverse_diagonal, omega).unwrap();
            assert!(p.ncols() > 2 * GALERKIN_BLOCKS, "{} coarse DOFs", p.ncols());
            let c = galerkin_product(a, p.as_ref()).unwrap();
            let p_dense = p.as_ref().to_dense();
            let explicit = p_dense.transpose() * a.to_dense() * &p_dense;
            let c_dense = c.as_ref().to_dense();
            let largest = (0..p.ncols())
                .flat_map(|j| (0..p.ncols()).map(move |i| (i, j)))
                .map(|(i, j)| explicit[(i, j)].abs())
                .fold(0.0, f64::max);
            let in_pattern = |i: usize, j: usize| {
                let col = c.symbolic().col_ptr()[j]..c.symbolic().col_ptr()[j + 1];
                c.symbolic().row_idx()[col].contains(&i)
            };
            let mut worst = 0.0f64;
            for j in 0..p.ncols() {
                for i in 0..p.ncols() {
                    let difference = (c_dense[(i, j)] - explicit[(i, j)]).abs();
                    worst = worst.max(difference);
                    assert!(
                        in_pattern(i, j) || explicit[(i, j)] == 0.0,
                        "skew {skew}: ({i}, {j}) = {:e} is not in the pattern",
                        explicit[(i, j)]
                    );
                }
            }
            println!("skew {skew}: |C − Pᵀ A P| = {worst:e}, largest entry {largest:e}");
            assert!(
                worst <= 1e-14 * largest,
                "skew {skew}: |C − Pᵀ A P| = {worst:e} against {largest:e}"
            );
            // and the non-symmetric product really is not symmetric
            let asymmetry = (0..p.ncols())
                .flat_map(|j| (0..p.ncols()).map(move |i| (i, j)))
                .map(|(i, j)| (c_dense[(i, j)] - c_dense[(j, i)]).abs())
                .fold(0.0, f64::max);
            assert_eq!(
                skew == 0.0,
                asymmetry <= 1e-14 * largest,
                "asymmetry {asymmetry:e}"
            );
        }
    }

    /// A kept hierarchy drops the tentative prolongators after its setup; a setup for the same
    /// pattern without keeping rebuilds them, and so does one after a failed setup: each gives
    /// the same preconditioner, bit for bit.
    #[test]
    fn a_kept_hierarchy_drops_the_tentative_prolongators_and_rebuilds_them() {
        let mut matrix = grid_operator(13, 11, 0.0);
        let mut multigrid = Multigrid::with_coarsest_size(30);
        multigrid.aggregate_width = 3;
        multigrid.setup(&matrix, true).unwrap();
        assert!(multigrid.level_count() >= 3, "{}", multigrid.level_count());
        assert!(multigrid.tentatives.is_empty());
        let sizes = multigrid.level_sizes();
        let r: Vec<f64> = (0..matrix.size()).map(|i| (i as f64 * 0.7).sin()).collect();
        let bits = |multigrid: &mut Multigrid| {
            let mut z = vec![0.0; r.len()];
            multigrid.apply(&r, &mut z);
            z.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        };
        let first = bits(&mut multigrid);
        // not kept: the aggregates are rebuilt and stay for the tangents of the pattern
        multigrid.keep_hierarchy = false;
        multigrid.setup(&matrix, true).unwrap();
        assert_eq!(multigrid.tentatives.len(), multigrid.level_count() - 1);
        assert_eq!(
            (multigrid.level_sizes(), bits(&mut multigrid)),
            (sizes.clone(), first.clone())
        );
        // a failed setup (a zero diagonal entry) leaves nothing to reuse
        let diagonal = matrix.get(0, 0);
        matrix.add(0, 0, -diagonal);
        assert!(multigrid.setup(&matrix, true).is_err());
        assert!(multigrid.tentatives.is_empty());
        matrix.add(0, 0, diagonal);
        multigrid.keep_hierarchy = true;
        multigrid.setup(&matrix, true).unwrap();
        assert_eq!(
            (multigrid.level_sizes(), bits(&mut multigrid)),
            (sizes, first)
        );
    }

    /// The active nodes of a quadratic B-spline grid (Greville abscissae: `h/2` apart at the
    /// ends, `h` inside) in `D` dimensions, kept by `keep(multi-index)`: positions and indices.
    fn active_nodes<const D: usize>(
        cells: [usize; D],
        keep: impl Fn(&[usize; D]) -> bool,
    ) -> (Vec<[f64; 3]>, Vec<[i64; 3]>) {
        use crate::basis::{BasisKind, GridBasis};
        let grid = GridBasis::<D>::new(
            &[0.0; D],
            &[1.0; D],
            &cells,
            BasisKind::BSpline { order: 2 },
        )
        .unwrap();
        (0..grid.num_nodes())
            .filter(|&n| keep(&grid.node_multi_index(n)))
            .map(|n| {
                let (x, k) = (grid.node_position(n), grid.node_multi_index(n));
                (
                    std::array::from_fn(|c| if c < D { x[c] } else { 0.0 }),
                    std::array::from_fn(|c| if c < D { k[c] as i64 } else { 0 }),
                )
            })
            .unzip()
    }

    /// On irregular active sets (an L-shaped body, a body with holes, a diagonal band) of a
    /// B-spline grid, in 1D, 2D and 3D, the lattice coordinates are the nodes' grid indices
    /// (shifted so that the lowest index present is 0), although the grid's spacing is `h/2` at
    /// its ends and `h` inside; the boxes of 4 nodes a side group exactly the nodes with the same
    /// `⌊index / 4⌋`.
    #[test]
    fn the_lattice_of_irregular_active_node_sets_is_the_grid_index_in_1d_2d_3d() {
        fn check<const D: usize>(
            name: &str,
            cells: [usize; D],
            keep: impl Fn(&[usize; D]) -> bool,
        ) {
            let (positions, indices) = active_nodes(cells, keep);
            assert!(positions.len() > 4, "{name}: {} nodes", positions.len());
            let lowest: [i64; 3] =
                std::array::from_fn(|c| indices.iter().map(|k| k[c]).min().unwrap());
            let expected: Vec<[i64; 3]> = indices
                .iter()
                .map(|k| std::array::from_fn(|c| k[c] - lowest[c]))
                .collect();
            let lattice = lattice_coordinates(&positions);
            assert_eq!(lattice, expected, "{name}");
            let (of, count, cells) = box_aggregates(&lattice, 4);
            for (block, k) in lattice.iter().enumerate() {
                let key: [i64; 3] = std::array::from_fn(|c| k[c].div_euclid(4));
                assert_eq!(cells[of[block]], key, "{name}: block {block}");
            }
            let mut seen = cells.clone();
            seen.sort_unstable();
            seen.dedup();
            assert_eq!(seen.len(), count, "{name}: one aggregate per box");
        }
        // 1D: a bar on part of the grid
        check::<1>("1D bar", [12], |k| k[0] >= 3);
        // 2D: an L-shape, and a block with holes
        check::<2>("2D L-shape", [10, 8], |k| k[0] < 4 || k[1] < 3);
        check::<2>("2D holes", [9, 9], |k| (k[0] * 3 + k[1] * 5) % 7 != 0);
        // 3D: a diagonal band (every index value along each axis still present)
        check::<3>("3D band", [6, 5, 4], |k| {
            (k[0] as i64 - k[1] as i64).abs() <= 2 && k[2] + k[0] >= 1
        });
    }

    /// Nodes off any lattice (a mesh's vertices: a grid of spacing `h` shaken by up to ±15 % of
    /// `h`) fall back to `round((x − x_min) / h)` with `h` estimated from the positions: the
    /// boxes of 4 nodes a side then hold many nodes each, as on the grid. (The first fallback,
    /// `h` = the median gap between distinct coordinates, made one aggregate per node here —
    /// 400 of 400 in 2D — which stops the coarsening: the gaps are mostly the shake.)
    #[test]
    fn scattered_positions_fall_back_to_the_spacing_and_keep_the_boxes() {
        for dimension in [2usize, 3] {
            let n: usize = if dimension == 2 { 20 } else { 8 };
            let count = n.pow(dimension as u32);
            let h = 0.1;
            // a fixed, irregular shake in [-0.15 h, 0.15 h]
            let shake =
                |i: usize, c: usize| ((i * 7919 + c * 104_729) % 1000) as f64 / 1000.0 * 0.3 - 0.15;
            let positions: Vec<[f64; 3]> = (0..count)
                .map(|i| {
                    std::array::from_fn(|c| {
                        if c < dimension {
                            (((i / n.pow(c as u32)) % n) as f64 + shake(i, c)) * h
                        } else {
                            0.0
                        }
                    })
                })
                .collect();
            let lattice = lattice_coordinates(&positions);
            let (_, aggregates, _) = box_aggregates(&lattice, 4);
            // on average more than a quarter of a box of 4^D nodes (the boxes at the ends of
            // each axis are cut), and not fewer aggregates than whole boxes fit
            let (boxes, per_box) = ((n / 4).pow(dimension as u32), 4usize.pow(dimension as u32));
            assert!(
                aggregates >= boxes && aggregates * per_box <= 4 * count,
                "{dimension}D: {aggregates} aggregates of {count} nodes, against {boxes} boxes \
                 of 4^D nodes"
            );
        }
    }
}
