//! One axis of the background grid: a uniform partition of `[lower, upper]` into `cells` cells
//! and the family of 1D functions on it, evaluated in physical units.
//!
//! With `h = (upper - lower) / cells` and the knot coordinate `t = (x - lower) / h`, a
//! function of the axis is `N_i(x) = N_i(t(x))` and, by the chain rule,
//!
//! ```text
//! dN_i/dx = (1 / h) dN_i/dt.
//! ```

use std::fmt;

use super::BasisKind;
use super::bspline::{
    bspline_span, cell_of_knot_coordinate, greville_abscissa, hat_span, vertex_1d,
};

/// A point lies outside the background grid (or a coordinate is NaN).
#[derive(Clone, Debug, PartialEq)]
pub struct OutsideGrid {
    /// The axis along which the point is outside. [`Axis`] methods, which do not know their
    /// position in a grid, report 0; [`super::GridBasis`] reports the true axis.
    pub axis: usize,
    /// The offending coordinate along that axis.
    pub coordinate: f64,
}

impl fmt::Display for OutsideGrid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "coordinate {} along axis {} is outside the background grid",
            self.coordinate, self.axis
        )
    }
}

impl std::error::Error for OutsideGrid {}

/// The smallest ratio of the cell size to the spacing of double-precision numbers at the
/// grid's largest coordinate: positions inside a cell keep at least 6 significant digits.
///
/// The basis is evaluated at the knot coordinate `t = (x - lower) / h`, so a position stored
/// to the precision `ulp(x)` gives `t` to `ulp(x) / h`; the stresses of the 2D column follow
/// with an error of 2 to 4 `ulp(x) / h` of the largest stress (`tests/far_from_origin.rs`:
/// 8e-11 at a shift of 1e6, 6e-7 at 1e10, with h = 5). At this limit that is a few parts in a
/// million; a grid beyond it is refused ([`unresolved_grid_line`]) rather than run to wrong stresses.
pub const MIN_CELL_RESOLUTION: f64 = 1e6;

/// The spacing of double-precision numbers at `x` (its unit in the last place).
pub fn spacing_of_doubles_at(x: f64) -> f64 {
    let magnitude = x.abs();
    f64::from_bits(magnitude.to_bits() + 1) - magnitude
}

/// The grid line of the axis `[lower, upper]` split into `cells` cells that lies too far from
/// the origin for the cell size (see [`MIN_CELL_RESOLUTION`]): `(line index, coordinate,
/// spacing of doubles there)`, or `None` when every position in a cell is resolved.
pub fn unresolved_grid_line(lower: f64, upper: f64, cells: usize) -> Option<(usize, f64, f64)> {
    let (line, coordinate) = if lower.abs() >= upper.abs() {
        (0, lower)
    } else {
        (cells, upper)
    };
    let resolution = spacing_of_doubles_at(coordinate);
    let spacing = (upper - lower) / cells as f64;
    (spacing < MIN_CELL_RESOLUTION * resolution).then_some((line, coordinate, resolution))
}

/// One axis of the background grid. Build it with [`Axis::new`] (which validates); the other
/// methods assume a valid axis (`cells >= 1`, finite `lower < upper`, order >= 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Axis {
    pub lower: f64,
    pub upper: f64,
    pub cells: usize,
    pub kind: BasisKind,
}

impl Axis {
    /// A validated axis. Errors name the offending quantity; [`super::GridBasis::new`] prefixes
    /// them with the axis index.
    pub fn new(lower: f64, upper: f64, cells: usize, kind: BasisKind) -> Result<Self, String> {
        if !lower.is_finite() || !upper.is_finite() {
            return Err(format!(
                "bounds must be finite (lower = {lower}, upper = {upper})"
            ));
        }
        if upper <= lower {
            return Err(format!(
                "upper bound {upper} must be greater than lower bound {lower}"
            ));
        }
        if cells == 0 {
            return Err("the number of cells must be at least 1".to_string());
        }
        if kind.order() == 0 {
            return Err("the B-spline order must be at least 1".to_string());
        }
        if !((upper - lower) / cells as f64).is_normal() {
            return Err(format!(
                "cell size (upper - lower) / cells = ({upper} - {lower}) / {cells} is not a \
                 normal positive number"
            ));
        }
        if let Some((line, coordinate, resolution)) = unresolved_grid_line(lower, upper, cells) {
            return Err(format!(
                "grid line {line} lies at {coordinate}, where double precision resolves only {resolution:e}: the cell size {} is not {MIN_CELL_RESOLUTION:e} times that; place the grid near the origin",
                (upper - lower) / cells as f64
            ));
        }
        Ok(Self {
            lower,
            upper,
            cells,
            kind,
        })
    }

    /// Polynomial order q of the functions.
    #[inline]
    pub fn order(&self) -> usize {
        self.kind.order()
    }

    /// Cell size h.
    #[inline]
    pub fn spacing(&self) -> f64 {
        (self.upper - self.lower) / self.cells as f64
    }

    /// Number of functions (nodes, control points) along the axis: `cells + q`.
    #[inline]
    pub fn num_functions(&self) -> usize {
        self.cells + self.order()
    }

    /// Number of functions that can be nonzero at a point: `q + 1`.
    #[inline]
    pub fn support_len(&self) -> usize {
        self.order() + 1
    }

    /// Number of grid vertices along the axis: `cells + 1`.
    #[inline]
    pub fn num_vertices(&self) -> usize {
        self.cells + 1
    }

    /// Position of control point (node) `i`: the Greville abscissa (see
    /// [`super::control_points_1d`]).
    #[inline]
    pub fn control_point(&self, i: usize) -> f64 {
        greville_abscissa(self.lower, self.upper, self.cells, self.order(), i)
    }

    /// All control point positions along the axis.
    pub fn control_points(&self) -> Vec<f64> {
        super::control_points_1d(self.lower, self.upper, self.cells, self.order())
    }

    /// Position of grid vertex `i` (`0..=cells`); exactly `lower` and `upper` at the ends.
    #[inline]
    pub fn vertex(&self, i: usize) -> f64 {
        vertex_1d(self.lower, self.upper, self.cells, i)
    }

    /// The cell containing `x` and the knot coordinate `t = (x - lower) / h` (clamped to
    /// `[0, cells]` against rounding). Cells are half-open `[x_k, x_{k+1})`, except that
    /// `x == upper` belongs to the last cell.
    #[inline]
    pub fn locate(&self, x: f64) -> Result<(usize, f64), OutsideGrid> {
        let outside = OutsideGrid {
            axis: 0,
            coordinate: x,
        };
        // `!(a && b)` so that NaN is outside.
        if !(x >= self.lower && x <= self.upper) {
            return Err(outside);
        }
        let t = ((x - self.lower) / self.spacing()).clamp(0.0, self.cells as f64);
        let cell = cell_of_knot_coordinate(t, self.cells).ok_or(outside)?;
        Ok((cell, t))
    }

    /// The cell containing `x` (see [`Axis::locate`]).
    #[inline]
    pub fn cell_of(&self, x: f64) -> Result<usize, OutsideGrid> {
        self.locate(x).map(|(cell, _)| cell)
    }

    /// Evaluates the `q + 1` functions that can be nonzero at `x`: returns the index `first` of
    /// the first one and fills `values[j] = N_{first+j}(x)` and `derivatives[j] =
    /// dN_{first+j}/dx(x)` (physical units), `j = 0..=q`. `first` is the cell containing `x`.
    ///
    /// The buffers are cleared and resized to `q + 1`: no allocation once they have that
    /// capacity. On error they are left empty. [`BasisKind::Linear`] uses the hat functions,
    /// [`BasisKind::BSpline`] the Cox-de Boor kernel; [`BasisKind::Fem`] the hat functions of the
    /// undeformed mesh; the particle-domain kinds (GIMP, CPDI) their underlying hat functions
    /// at the point.
    pub fn eval(
        &self,
        x: f64,
        values: &mut Vec<f64>,
        derivatives: &mut Vec<f64>,
    ) -> Result<usize, OutsideGrid> {
        values.clear();
        derivatives.clear();
        let (cell, t) = self.locate(x)?;
        let n = self.support_len();
        values.resize(n, 0.0);
        derivatives.resize(n, 0.0);
        match self.kind {
            BasisKind::Linear | BasisKind::Fem | BasisKind::Gimp { .. } | BasisKind::Cpdi => {
                hat_span(cell, t, values, derivatives)
            }
            BasisKind::BSpline { order } | BasisKind::BSplineDomain { order } => {
                bspline_span(order, self.cells, cell, t, values, derivatives)
            }
        }
        let inv_h = 1.0 / self.spacing();
        for d in derivatives.iter_mut() {
            *d *= inv_h;
        }
        Ok(cell)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::test_points::Lcg;

    fn bspline(lower: f64, upper: f64, cells: usize, order: usize) -> Axis {
        Axis::new(lower, upper, cells, BasisKind::BSpline { order }).unwrap()
    }

    /// All functions of the axis at x as dense vectors.
    fn dense(axis: &Axis, x: f64) -> (Vec<f64>, Vec<f64>) {
        let (mut v, mut d) = (Vec::new(), Vec::new());
        let first = axis.eval(x, &mut v, &mut d).unwrap();
        let mut vals = vec![0.0; axis.num_functions()];
        let mut ders = vec![0.0; axis.num_functions()];
        vals[first..first + v.len()].copy_from_slice(&v);
        ders[first..first + d.len()].copy_from_slice(&d);
        (vals, ders)
    }

    #[test]
    fn sizes() {
        let a = bspline(-1.0, 2.0, 6, 3);
        assert_eq!(a.spacing(), 0.5);
        assert_eq!(a.num_functions(), 9);
        assert_eq!(a.support_len(), 4);
        assert_eq!(a.num_vertices(), 7);
        let l = Axis::new(0.0, 1.0, 5, BasisKind::Linear).unwrap();
        assert_eq!(l.num_functions(), 6);
        assert_eq!(l.support_len(), 2);
    }

    #[test]
    fn validation() {
        let k = BasisKind::BSpline { order: 2 };
        assert!(Axis::new(0.0, 1.0, 1, k).is_ok());
        assert!(Axis::new(1.0, 1.0, 1, k).unwrap_err().contains("greater"));
        assert!(Axis::new(2.0, 1.0, 1, k).unwrap_err().contains("greater"));
        assert!(
            Axis::new(f64::NAN, 1.0, 1, k)
                .unwrap_err()
                .contains("finite")
        );
        assert!(
            Axis::new(0.0, f64::INFINITY, 1, k)
                .unwrap_err()
                .contains("finite")
        );
        assert!(Axis::new(0.0, 1.0, 0, k).unwrap_err().contains("cells"));
        let q0 = BasisKind::BSpline { order: 0 };
        assert!(Axis::new(0.0, 1.0, 3, q0).unwrap_err().contains("order"));
    }

    /// Paper Fig. 1: q = 2, 4 cells on [0, 1], knots {0,0,0,1/4,1/2,3/4,1,1,1}, 6 functions.
    /// Closed forms derived by hand from eq. 7 with u = 4x (0-based names; the paper's N_1 is
    /// our N_0):
    ///
    /// ```text
    /// N_0 = (1-u)^2                          on [0,1)
    /// N_1 = 2u - 3u^2/2     on [0,1),  (2-u)^2/2 on [1,2)
    /// N_2 = u^2/2 on [0,1), (-2u^2+6u-3)/2 on [1,2), (3-u)^2/2 on [2,3)
    /// N_3 = N_2(4 - u),  N_4 = N_1(4 - u),  N_5 = N_0(4 - u)      (symmetry)
    /// ```
    #[test]
    fn paper_fig1_quadratic_closed_forms() {
        let axis = bspline(0.0, 1.0, 4, 2);
        assert_eq!(axis.num_functions(), 6);
        fn n0(u: f64) -> (f64, f64) {
            if u < 1.0 {
                ((1.0 - u).powi(2), -2.0 * (1.0 - u))
            } else {
                (0.0, 0.0)
            }
        }
        fn n1(u: f64) -> (f64, f64) {
            if u < 1.0 {
                (2.0 * u - 1.5 * u * u, 2.0 - 3.0 * u)
            } else if u < 2.0 {
                ((2.0 - u).powi(2) / 2.0, -(2.0 - u))
            } else {
                (0.0, 0.0)
            }
        }
        fn n2(u: f64) -> (f64, f64) {
            if u < 1.0 {
                (u * u / 2.0, u)
            } else if u < 2.0 {
                ((-2.0 * u * u + 6.0 * u - 3.0) / 2.0, -2.0 * u + 3.0)
            } else if u < 3.0 {
                ((3.0 - u).powi(2) / 2.0, -(3.0 - u))
            } else {
                (0.0, 0.0)
            }
        }
        // mirror: N(4-u), derivative d/du = -N'(4-u)
        fn mirror(f: fn(f64) -> (f64, f64), u: f64) -> (f64, f64) {
            let (v, d) = f(4.0 - u);
            (v, -d)
        }
        let xs = [
            0.0, 0.05, 0.1, 0.2, 0.25, 0.3, 0.4, 0.5, 0.55, 0.7, 0.75, 0.8, 0.9, 0.99, 1.0,
        ];
        for x in xs {
            let u = 4.0 * x;
            // at u = 4 the mirrored pieces are evaluated at 0 from the right, which is the
            // correct (left-continuous) value at the closed upper end.
            let expected = [
                n0(u),
                n1(u),
                n2(u),
                mirror(n2, u),
                mirror(n1, u),
                mirror(n0, u),
            ];
            let (vals, ders) = dense(&axis, x);
            for i in 0..6 {
                let (v, du) = expected[i];
                if x < 1.0 || i >= 3 {
                    assert!(
                        (vals[i] - v).abs() < 1e-14,
                        "x={x} N_{i}: {} vs {v}",
                        vals[i]
                    );
                    // d/dx = 4 d/du
                    assert!(
                        (ders[i] - 4.0 * du).abs() < 1e-13,
                        "x={x} N_{i}': {} vs {}",
                        ders[i],
                        4.0 * du
                    );
                }
            }
        }
        // spot values worth remembering: at x = 1/8, (N_0, N_1, N_2) = (1/4, 5/8, 1/8)
        let (vals, _) = dense(&axis, 0.125);
        assert!((vals[0] - 0.25).abs() < 1e-15);
        assert!((vals[1] - 0.625).abs() < 1e-15);
        assert!((vals[2] - 0.125).abs() < 1e-15);
        // at the interior knot x = 1/4: N_1 = N_2 = 1/2
        let (vals, _) = dense(&axis, 0.25);
        assert_eq!(&vals, &[0.0, 0.5, 0.5, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn physical_derivatives_match_central_differences() {
        let mut rng = Lcg::new(11);
        let eps = 1e-6;
        for kind in [
            BasisKind::Linear,
            BasisKind::BSpline { order: 1 },
            BasisKind::BSpline { order: 2 },
            BasisKind::BSpline { order: 4 },
        ] {
            let axis = Axis::new(-2.0, 3.5, 7, kind).unwrap();
            for _ in 0..200 {
                let x = rng.uniform(-2.0 + eps, 3.5 - eps);
                let t = (x - axis.lower) / axis.spacing();
                if (t - t.round()).abs() < 1e-4 {
                    continue; // q = 1 kinks
                }
                let (_, ders) = dense(&axis, x);
                let (plus, _) = dense(&axis, x + eps);
                let (minus, _) = dense(&axis, x - eps);
                for i in 0..axis.num_functions() {
                    let fd = (plus[i] - minus[i]) / (2.0 * eps);
                    assert!((fd - ders[i]).abs() < 1e-6, "{kind:?} x={x} i={i}");
                }
            }
        }
    }

    #[test]
    fn linear_kind_equals_order_one_bspline() {
        let mut rng = Lcg::new(12);
        let lin = Axis::new(0.3, 1.9, 5, BasisKind::Linear).unwrap();
        let q1 = Axis::new(0.3, 1.9, 5, BasisKind::BSpline { order: 1 }).unwrap();
        for _ in 0..300 {
            let x = rng.uniform(0.3, 1.9);
            let (lv, ld) = dense(&lin, x);
            let (bv, bd) = dense(&q1, x);
            for i in 0..lin.num_functions() {
                assert!((lv[i] - bv[i]).abs() <= 1e-14);
                assert!((ld[i] - bd[i]).abs() <= 1e-14 / lin.spacing());
            }
        }
    }

    #[test]
    fn upper_end_belongs_to_last_cell() {
        for kind in [
            BasisKind::Linear,
            BasisKind::BSpline { order: 2 },
            BasisKind::BSpline { order: 3 },
        ] {
            let axis = Axis::new(0.1, 0.7, 3, kind).unwrap();
            let (mut v, mut d) = (Vec::new(), Vec::new());
            let first = axis.eval(0.7, &mut v, &mut d).unwrap();
            assert_eq!(first, 2);
            assert_eq!(axis.cell_of(0.7), Ok(2));
            assert_eq!(v.len(), axis.support_len());
            assert_eq!(*v.last().unwrap(), 1.0, "{kind:?}: {v:?}");
            assert!(v[..v.len() - 1].iter().all(|&x| x == 0.0));
            // the derivative there is the left derivative of the last piece: q / h for the last
            let h = axis.spacing();
            let q = axis.order() as f64;
            assert!((d.last().unwrap() - q / h).abs() < 1e-10, "{kind:?}: {d:?}");
            // lower end: first cell, first function 1
            assert_eq!(axis.eval(0.1, &mut v, &mut d), Ok(0));
            assert_eq!(v[0], 1.0);
            assert!((d[0] + q / h).abs() < 1e-10, "{kind:?}: {d:?}");
        }
    }

    /// For these bounds `(upper - lower) / h` rounds to slightly more than `cells`: without the
    /// clamp the last span would be extrapolated and produce negative values.
    #[test]
    fn upper_end_is_robust_to_rounding() {
        let (lower, upper, cells) = (0.2326362976473355, 8.159512078030577, 14);
        for kind in [BasisKind::Linear, BasisKind::BSpline { order: 2 }] {
            let axis = Axis::new(lower, upper, cells, kind).unwrap();
            assert!((upper - lower) / axis.spacing() > cells as f64, "premise");
            let (mut v, mut d) = (Vec::new(), Vec::new());
            assert_eq!(axis.eval(upper, &mut v, &mut d), Ok(cells - 1));
            assert!(
                v.iter().all(|&x| (0.0..=1.0).contains(&x)),
                "{kind:?}: {v:?}"
            );
            assert_eq!(*v.last().unwrap(), 1.0);
        }
    }

    #[test]
    fn cells_are_half_open() {
        let axis = bspline(0.0, 1.0, 4, 2);
        assert_eq!(axis.cell_of(0.0), Ok(0));
        assert_eq!(axis.cell_of(0.2499), Ok(0));
        assert_eq!(axis.cell_of(0.25), Ok(1));
        assert_eq!(axis.cell_of(0.75), Ok(3));
        assert_eq!(axis.cell_of(1.0), Ok(3));
    }

    #[test]
    fn outside_points_are_errors() {
        let axis = bspline(0.0, 1.0, 4, 3);
        let (mut v, mut d) = (vec![1.0; 4], vec![1.0; 4]);
        for x in [
            -1e-12,
            1.0 + 1e-12,
            -5.0,
            7.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            assert_eq!(
                axis.eval(x, &mut v, &mut d),
                Err(OutsideGrid {
                    axis: 0,
                    coordinate: x
                })
            );
            assert!(v.is_empty() && d.is_empty());
            assert!(axis.cell_of(x).is_err());
        }
        let err = axis.eval(f64::NAN, &mut v, &mut d).unwrap_err();
        assert!(err.coordinate.is_nan());
        let message = OutsideGrid {
            axis: 2,
            coordinate: 1.5,
        }
        .to_string();
        assert!(
            message.contains("1.5") && message.contains("axis 2"),
            "{message}"
        );
    }

    #[test]
    fn eval_reuses_buffers() {
        let axis = bspline(0.0, 1.0, 8, 3);
        let (mut v, mut d) = (Vec::new(), Vec::new());
        axis.eval(0.5, &mut v, &mut d).unwrap();
        let (pv, pd) = (v.as_ptr(), d.as_ptr());
        for i in 0..100 {
            axis.eval(i as f64 / 100.0, &mut v, &mut d).unwrap();
            assert_eq!((v.as_ptr(), d.as_ptr()), (pv, pd));
        }
    }

    #[test]
    fn control_points_and_vertices() {
        let axis = bspline(-1.0, 1.0, 4, 3);
        let cp = axis.control_points();
        assert_eq!(cp.len(), axis.num_functions());
        assert_eq!(cp[0], -1.0);
        assert_eq!(*cp.last().unwrap(), 1.0);
        for (i, x) in cp.iter().enumerate() {
            assert_eq!(*x, axis.control_point(i));
        }
        let lin = Axis::new(-1.0, 1.0, 4, BasisKind::Linear).unwrap();
        let v: Vec<f64> = (0..lin.num_vertices()).map(|i| lin.vertex(i)).collect();
        assert_eq!(v, vec![-1.0, -0.5, 0.0, 0.5, 1.0]);
        assert_eq!(lin.control_points(), v);
    }
}
