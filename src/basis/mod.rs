//! Background-grid bases: standard linear MPM (hat functions) and B-splines of order q on open
//! knot vectors (paper eqs. 5-8), with tensor products in 2D/3D.
//!
//! # The grid
//!
//! Each axis `k` is a uniform partition of `[lower_k, upper_k]` into `c_k` cells of size
//! `h_k = (upper_k - lower_k) / c_k` ([`Axis`]). Positions are mapped to *knot units*
//! `t = (x - lower) / h`, in which the grid vertices are the integers `0, 1, ..., c`.
//!
//! # B-splines of order q (paper eqs. 5-7)
//!
//! On the open uniform knot vector (0-based; the paper counts from 1)
//!
//! ```text
//! Xi = { xi_0, ..., xi_{c+2q} } = { 0 (q+1 times), 1, 2, ..., c-1, c (q+1 times) }
//! ```
//!
//! the `n = c + q` functions are built by the Cox-de Boor recursion
//!
//! ```text
//! N_i^0(t) = 1 if xi_i <= t < xi_{i+1}, else 0
//! N_i^p(t) = (t - xi_i) / (xi_{i+p} - xi_i) N_i^{p-1}(t)
//!          + (xi_{i+p+1} - t) / (xi_{i+p+1} - xi_{i+1}) N_{i+1}^{p-1}(t)        (0/0 := 0)
//! dN_i^q/dt = q / (xi_{i+q} - xi_i) N_i^{q-1}(t) - q / (xi_{i+q+1} - xi_{i+1}) N_{i+1}^{q-1}(t)
//! ```
//!
//! and `dN/dx = (1/h) dN/dt`. They are non-negative, a partition of unity, `C^{q-1}` across
//! interior knots, and interpolatory at the two ends of the grid. On cell `k` (`k <= t < k+1`,
//! the upper end `t = c` belonging to the last cell) exactly `N_k, ..., N_{k+q}` can be nonzero.
//! Details and the kernels: [`bspline`].
//!
//! # Linear MPM
//!
//! [`BasisKind::Linear`] uses the hat functions `N_v(x) = max(0, 1 - |x - X_v| / h)` of the
//! `c + 1` vertices, implemented directly ([`bspline::hat_span`]); they coincide with the
//! B-splines of order 1 (tested to round-off).
//!
//! # Control points (nodes)
//!
//! Function `i` is attached to a node at the Greville abscissa
//! `X_i = lower + h (xi_{i+1} + ... + xi_{i+q}) / q` ([`control_points_1d`]): the vertices for
//! `q = 1`, always with the first and last node on the boundary. With these positions the basis
//! reproduces linear fields, `sum_i N_i(x) X_i = x`.
//!
//! # Tensor products
//!
//! [`GridBasis<D>`] combines `D` axes: `N_i(x) = prod_k N^k_{i_k}(x_k)`, nodes numbered
//! lexicographically with axis 0 fastest. [`GridBasis::eval`] returns, for a point, the nodes
//! whose function or gradient is nonzero there, with values and physical gradients, without
//! allocating (buffers in [`BasisScratch`]).

pub mod axis;
pub mod bspline;
pub mod grid;

pub use axis::{Axis, OutsideGrid};
pub use bspline::control_points_1d;
pub use grid::{BasisScratch, GridBasis, NodeWeight};

/// Which family of grid functions maps between points and grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BasisKind {
    /// Standard MPM: piecewise-linear hat functions on the grid vertices.
    Linear,
    /// B-splines of order `order >= 1` on the open uniform knot vector over the grid.
    BSpline { order: usize },
    /// Linear finite elements on the body-fitted mesh of grid cells (see `crate::fem`): the
    /// nodes are the grid vertices and move with the body. On the undeformed grid its functions
    /// are the hat functions, which is what [`GridBasis::eval`] evaluates for this kind.
    Fem,
}

impl BasisKind {
    /// Polynomial order q of the functions (1 for linear).
    pub fn order(&self) -> usize {
        match self {
            BasisKind::Linear | BasisKind::Fem => 1,
            BasisKind::BSpline { order } => *order,
        }
    }
}

/// Deterministic pseudo-random sample points for the tests (no external crates).
#[cfg(test)]
pub(crate) mod test_points {
    /// 64-bit linear congruential generator (Knuth's MMIX constants), top 53 bits as a double.
    pub struct Lcg(u64);

    impl Lcg {
        pub fn new(seed: u64) -> Self {
            Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03)
        }

        /// Uniform in `[0, 1)`.
        pub fn next_f64(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }

        /// Uniform in `[lower, upper)`.
        pub fn uniform(&mut self, lower: f64, upper: f64) -> f64 {
            lower + (upper - lower) * self.next_f64()
        }
    }
}
