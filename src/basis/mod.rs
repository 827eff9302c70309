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
//! # Particle-domain methods: GIMP and CPDI
//!
//! [`BasisKind::Gimp`] and [`BasisKind::Cpdi`] keep the hat functions as grid functions but
//! weight a point by their average over the point's domain instead of their value at its
//! centre: `S_ip = (1/V_p) ∫_Ωp N_i dx`, `∇S_ip = (1/V_p) ∫_Ωp ∇N_i dx` ([`gimp`]: exact
//! integral over an axis-aligned box; [`cpdi`]: the CPDI1 corner rule on a parallelepiped
//! carried by F). [`domain`] turns a point's state at the start of a load step into its domain
//! and dispatches. [`GridBasis::eval`] on such a grid evaluates the plain hat functions (used
//! for grid output).
//!
//! [`BasisKind::BSplineDomain`] applies GIMP's average to the B-splines ([`averaged`], whose
//! order-1 case is GIMP's kernel): the basis is integrated exactly over the point's box, which
//! removes the quadrature error of the boundary functions at a fixed base.
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

pub mod averaged;
pub mod axis;
pub mod bspline;
pub mod cpdi;
pub mod domain;
pub mod error;
pub mod gimp;
pub mod grid;
pub mod surface;

pub use axis::{Axis, OutsideGrid};
pub use bspline::control_points_1d;
pub use domain::{DomainScratch, eval_point_domain};
pub use error::DomainError;
pub use grid::{BasisScratch, GridBasis, GridSpec, NodeWeight};
pub use surface::SurfaceScratch;

/// Which family of grid functions maps between points and grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BasisKind {
    /// Standard MPM: piecewise-linear hat functions on the grid vertices.
    Linear,
    /// B-splines of order `order >= 1` on the open uniform knot vector over the grid.
    BSpline { order: usize },
    /// B-splines of order `order` averaged over the point's box domain, stretched with the
    /// deformation like contiguous GIMP: GIMP's integration with the B-spline basis
    /// ([`averaged`]; `integration: "domain"` in scenes).
    BSplineDomain { order: usize },
    /// GIMP (Bardenhagen & Kober 2004): the hat functions averaged over the point's box-shaped
    /// domain ([`gimp`]).
    Gimp { domain: GimpDomain },
    /// CPDI1 (Sadeghirad, Brannon & Burghardt 2011): the hat functions averaged from the
    /// corners of the point's parallelepiped domain carried by F ([`cpdi`]).
    Cpdi,
    /// Linear finite elements on the body-fitted mesh of grid cells (see `crate::fem`): the
    /// nodes are the grid vertices and move with the body. On the undeformed grid its functions
    /// are the hat functions, which is what [`GridBasis::eval`] evaluates for this kind.
    Fem,
}

/// How the GIMP particle domain follows the deformation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GimpDomain {
    /// uGIMP: the domain keeps its initial half-lengths `lp0`.
    Fixed,
    /// Contiguous-particle GIMP (cpGIMP): the half-lengths follow the diagonal of the
    /// deformation gradient, `lp_k = lp0_k F_kk`, so that domains of a uniformly deformed body
    /// stay contiguous.
    Stretched,
}

impl GimpDomain {
    /// The scene word (`grid(#{ basis: "gimp", gimp: .. })`).
    pub fn name(self) -> &'static str {
        match self {
            GimpDomain::Fixed => "fixed",
            GimpDomain::Stretched => "stretched",
        }
    }
}

/// The human name of a basis, as in `impm check` and `summary.json`: `linear`,
/// `bspline(q=3)`, `bspline(q=2, domain integration)`, `gimp(stretched)`, `cpdi`,
/// `fem(linear elements)`.
impl std::fmt::Display for BasisKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BasisKind::Linear => f.write_str("linear"),
            BasisKind::BSpline { order } => write!(f, "bspline(q={order})"),
            BasisKind::BSplineDomain { order } => {
                write!(f, "bspline(q={order}, domain integration)")
            }
            BasisKind::Gimp { domain } => write!(f, "gimp({})", domain.name()),
            BasisKind::Cpdi => f.write_str("cpdi"),
            BasisKind::Fem => f.write_str("fem(linear elements)"),
        }
    }
}

impl BasisKind {
    /// Polynomial order q of the grid functions (1 for linear, FEM, and GIMP and CPDI, which
    /// average the linear hat functions).
    pub fn order(&self) -> usize {
        match self {
            BasisKind::Linear | BasisKind::Fem | BasisKind::Gimp { .. } | BasisKind::Cpdi => 1,
            BasisKind::BSpline { order } | BasisKind::BSplineDomain { order } => *order,
        }
    }

    /// Whether a point's weights depend on its domain (GIMP, CPDI, averaged B-splines) rather
    /// than on its position alone: such points carry a `ParticleDomain` and use
    /// [`eval_point_domain`].
    pub fn uses_point_domain(&self) -> bool {
        matches!(
            self,
            BasisKind::Gimp { .. } | BasisKind::Cpdi | BasisKind::BSplineDomain { .. }
        )
    }
}

/// Deterministic pseudo-random sample points for the tests (no external crates), and the
/// invariants every family of weights here must satisfy.
#[cfg(test)]
pub(crate) mod test_points {
    use nalgebra::{SMatrix, SVector};

    use super::{Axis, GridBasis, NodeWeight};

    /// All the 1D weights of `axis` as dense vectors (values, derivatives), from a span kernel
    /// that fills consecutive functions and returns the index of the first.
    pub fn dense_span(
        axis: &Axis,
        span: impl FnOnce(&mut Vec<f64>, &mut Vec<f64>) -> usize,
    ) -> (Vec<f64>, Vec<f64>) {
        let (mut v, mut d) = (Vec::new(), Vec::new());
        let first = span(&mut v, &mut d);
        let mut values = vec![0.0; axis.num_functions()];
        let mut derivatives = vec![0.0; axis.num_functions()];
        values[first..first + v.len()].copy_from_slice(&v);
        derivatives[first..first + d.len()].copy_from_slice(&d);
        (values, derivatives)
    }

    /// Value and gradient of `node` among `weights` (zero if it is not there).
    pub fn weight_of<const D: usize>(
        weights: &[NodeWeight<D>],
        node: usize,
    ) -> (f64, SVector<f64, D>) {
        weights
            .iter()
            .find(|w| w.node == node)
            .map_or((0.0, SVector::zeros()), |w| (w.value, w.gradient))
    }

    /// Asserts, for the weights of a point (or of a domain centred) at `x`: non-negative values
    /// forming a partition of unity, gradients summing to zero, reproduction of linear fields
    /// `Σ_i S_i X_i = x` and `Σ_i X_i ⊗ ∇S_i = I` with the node positions, and unique increasing
    /// nodes. `tolerance` bounds the partition of unity; the others scale from it.
    pub fn assert_linear_reproduction<const D: usize>(
        grid: &GridBasis<D>,
        weights: &[NodeWeight<D>],
        x: &SVector<f64, D>,
        tolerance: f64,
    ) {
        assert!(!weights.is_empty(), "x={x:?}: no weights");
        let sum: f64 = weights.iter().map(|w| w.value).sum();
        assert!((sum - 1.0).abs() < tolerance, "x={x:?}: sum {sum}");
        assert!(weights.iter().all(|w| w.value >= 0.0), "x={x:?}");
        let h_min = grid
            .axes
            .iter()
            .map(|a| a.spacing())
            .fold(f64::MAX, f64::min);
        let gradient_sum: SVector<f64, D> = weights.iter().map(|w| w.gradient).sum();
        assert!(
            gradient_sum.norm() < 10.0 * tolerance / h_min,
            "x={x:?}: gradient sum {gradient_sum:?}"
        );
        let centre: SVector<f64, D> = weights
            .iter()
            .map(|w| grid.node_position(w.node) * w.value)
            .sum();
        assert!(
            (centre - x).norm() < 10.0 * tolerance,
            "x={x:?}: {centre:?}"
        );
        let jacobian: SMatrix<f64, D, D> = weights
            .iter()
            .map(|w| grid.node_position(w.node) * w.gradient.transpose())
            .sum();
        assert!(
            (jacobian - SMatrix::<f64, D, D>::identity()).norm() < 100.0 * tolerance,
            "x={x:?}: {jacobian:?}"
        );
        assert!(weights.windows(2).all(|p| p[0].node < p[1].node), "x={x:?}");
    }

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
