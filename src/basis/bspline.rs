//! Pure one-dimensional kernels in *knot units* (the coordinate `t = (x - lower) / h`, so that
//! grid vertex `k` sits at `t = k`): B-splines of any order on the open uniform knot vector,
//! the standard linear MPM hat functions, and the Greville abscissae (control points).
//!
//! # Open uniform knot vector
//!
//! For `c` cells and order `q` the knot vector has `c + 2q + 1` entries (0-based index `i`)
//!
//! ```text
//! xi_i = clamp(i - q, 0, c)      i.e.  { 0 (q+1 times), 1, 2, ..., c-1, c (q+1 times) }
//! ```
//!
//! and defines `n = c + q` functions `N_0^q, ..., N_{n-1}^q`. (The paper numbers knots and
//! functions from 1: its `xi_1, N_1` are our `xi_0, N_0`.) The paper's Fig. 1 knot vector
//! `{0, 0, 0, 1/4, 1/2, 3/4, 1, 1, 1}` is this one for `q = 2, c = 4`, scaled by `h = 1/4`.
//!
//! # Cox-de Boor recursion (paper eqs. 6-7)
//!
//! ```text
//! N_i^0(t) = 1 if xi_i <= t < xi_{i+1}, else 0
//!
//! N_i^p(t) = (t - xi_i) / (xi_{i+p} - xi_i) * N_i^{p-1}(t)
//!          + (xi_{i+p+1} - t) / (xi_{i+p+1} - xi_{i+1}) * N_{i+1}^{p-1}(t),     p = 1..q
//! ```
//!
//! with the convention that a quotient with a zero denominator is zero ("0/0 := 0"): a zero
//! denominator means the lower-order function it multiplies has an empty support (repeated
//! knots), so the term vanishes.
//!
//! # Derivative
//!
//! Differentiating the recursion gives (same 0/0 convention)
//!
//! ```text
//! dN_i^q/dt = q / (xi_{i+q} - xi_i) * N_i^{q-1}(t)  -  q / (xi_{i+q+1} - xi_{i+1}) * N_{i+1}^{q-1}(t).
//! ```
//!
//! # Spans
//!
//! Cell `k` (`0 <= k < c`) is the knot span `[xi_{k+q}, xi_{k+q+1}) = [k, k+1)`. On it exactly
//! the `q + 1` functions `N_k^q, ..., N_{k+q}^q` can be nonzero, so a span evaluation returns
//! those, local index `j` standing for the global function `k + j`. Spans are half-open, except
//! that the right end of the grid `t = c` belongs to the last span `k = c - 1` (so that the
//! functions, which are right-continuous, are also defined at the upper boundary, where the
//! open knot vector makes them interpolatory: `N_{n-1}(c) = 1`).
//!
//! The span kernels evaluate the polynomial *pieces* of span `k`: called with a `t` outside
//! `[k, k+1]` they extrapolate that piece, which the tests use to check continuity from both
//! sides of a knot.
//!
//! Each level of the triangular scheme only touches the `p + 1` functions that can be nonzero on
//! the span, so evaluating all `q + 1` values and derivatives costs `O(q^2)` flops and no
//! allocation.

/// Knot `i` (0-based) of the open uniform knot vector of order `order` over `cells` cells, in
/// cell units: `clamp(i - order, 0, cells)`.
#[inline]
pub fn open_uniform_knot(i: usize, order: usize, cells: usize) -> f64 {
    i.saturating_sub(order).min(cells) as f64
}

/// The whole open uniform knot vector (`cells + 2 order + 1` knots, cell units).
pub fn open_uniform_knot_vector(order: usize, cells: usize) -> Vec<f64> {
    (0..cells + 2 * order + 1)
        .map(|i| open_uniform_knot(i, order, cells))
        .collect()
}

/// The cell (knot span) containing `t` (knot units), with the half-open convention
/// `k <= t < k + 1` except that `t == cells` belongs to the last cell. `None` if `t` is outside
/// `[0, cells]` or NaN (or if `cells == 0`).
#[inline]
pub fn cell_of_knot_coordinate(t: f64, cells: usize) -> Option<usize> {
    // `!(a && b)` rather than `(!a || !b)` so that NaN is rejected.
    if cells == 0 || !(t >= 0.0 && t <= cells as f64) {
        return None;
    }
    Some((t.floor() as usize).min(cells - 1))
}

/// Quotient with the B-spline convention `x / 0 := 0` (paper, after eq. 7).
#[inline]
fn ratio(numerator: f64, denominator: f64) -> f64 {
    if denominator == 0.0 {
        0.0
    } else {
        numerator / denominator
    }
}

/// Values and first derivatives (d/dt, knot units) of the `order + 1` B-splines of order `order`
/// that can be nonzero on cell `cell` of the open uniform knot vector over `cells` cells:
/// `values[j] = N_{cell+j}^q(t)`, `derivatives[j] = dN_{cell+j}^q/dt(t)`, `j = 0..=q`.
///
/// Implements the Cox-de Boor recursion (module docs) restricted to the span, in place in
/// `values`: starting from `N_{cell+q}^0 = 1`, level `p` holds `N_{cell+q-p+j}^p` at index `j`.
/// The last level applies the derivative formula to the same order-`(q-1)` values. Both terms of
/// eq. 7 are written with reciprocal widths `w_i^p = 1 / (xi_{i+p} - xi_i)` (`1/0 := 0`):
///
/// ```text
/// N_i^p     = (t - xi_i) w_i^p N_i^{p-1}  +  (xi_{i+p+1} - t) w_{i+1}^p N_{i+1}^{p-1}
/// dN_i^q/dt = q (w_i^q N_i^{q-1}  -  w_{i+1}^q N_{i+1}^{q-1})
/// ```
///
/// so each width is computed once per level and shared by neighbouring functions (`p + 2`
/// divisions per level, no allocation).
///
/// `t` is normally in `[cell, cell + 1]`; outside it the polynomial piece of this span is
/// extrapolated. Works for `order = 0` too (`values = [1]`, `derivatives = [0]`).
///
/// # Panics
/// If `values` or `derivatives` is shorter than `order + 1`, or `cell >= cells`.
pub fn bspline_span(
    order: usize,
    cells: usize,
    cell: usize,
    t: f64,
    values: &mut [f64],
    derivatives: &mut [f64],
) {
    assert!(cell < cells, "cell {cell} out of range for {cells} cells");
    let q = order;
    let values = &mut values[..=q];
    let derivatives = &mut derivatives[..=q];
    let s = cell + q; // knot span index: xi_s <= t < xi_{s+1}
    let knot = |i: usize| open_uniform_knot(i, q, cells);
    let inverse_width = |i: usize, p: usize| ratio(1.0, knot(i + p) - knot(i));

    values[0] = 1.0; // N_s^0
    derivatives[0] = 0.0; // stays for q = 0
    // Raise N^{p-1} -> N^p in place; local j <-> global function i = s - p + j, so that
    // old[j-1] = N_i^{p-1} and old[j] = N_{i+1}^{p-1} (old[-1] = old[p] = 0: outside the span).
    // Descending j keeps old[j-1] intact until it has been used.
    for p in 1..=q {
        let mut w_right = inverse_width(s + 1, p); // w_{i+1}^p for j = p (i = s)
        for j in (0..=p).rev() {
            let i = s - p + j;
            let w_left = inverse_width(i, p);
            let left = if j > 0 { values[j - 1] } else { 0.0 };
            let right = if j < p { values[j] } else { 0.0 };
            let (a, b) = (w_left * left, w_right * right);
            if p == q {
                derivatives[j] = q as f64 * (a - b);
            }
            values[j] = (t - knot(i)) * a + (knot(i + p + 1) - t) * b;
            w_right = w_left; // w_{i+1}^p of the next (smaller) j
        }
    }
}

/// Standard linear MPM hat function of vertex `vertex` at `t` (knot units):
/// `N_v(t) = max(0, 1 - |t - v|)`. Its derivative is not defined at the vertices; the span
/// kernel [`hat_span`] gives the one-sided derivative of a chosen cell.
#[inline]
pub fn hat(vertex: usize, t: f64) -> f64 {
    (1.0 - (t - vertex as f64).abs()).max(0.0)
}

/// Values and derivatives (d/dt, knot units) of the two linear hat functions of cell `cell`
/// (vertices `cell` and `cell + 1`), written directly rather than through the Cox-de Boor
/// recursion: with the local coordinate `r = t - cell`,
///
/// ```text
/// values = [1 - r, r],    derivatives = [-1, 1].
/// ```
///
/// These are the B-splines of order 1 on the open uniform knot vector (tested to agree).
///
/// # Panics
/// If `values` or `derivatives` is shorter than 2.
#[inline]
pub fn hat_span(cell: usize, t: f64, values: &mut [f64], derivatives: &mut [f64]) {
    let r = t - cell as f64;
    values[0] = 1.0 - r;
    values[1] = r;
    derivatives[0] = -1.0;
    derivatives[1] = 1.0;
}

/// Greville abscissa `i` of the open uniform knot vector, in physical units:
/// `x_i = lower + h * (xi_{i+1} + ... + xi_{i+q}) / q` with `h = (upper - lower) / cells`.
///
/// Evaluated as `lower + (upper - lower) * s / (q cells)`, `s = xi_{i+1} + ... + xi_{i+q}`, with
/// the last abscissa set to exactly `upper`; the first is exactly `lower`. For `q = 1` the
/// abscissae are bitwise equal to the vertices of [`vertex_1d`]. Requires `order >= 1`.
pub fn greville_abscissa(lower: f64, upper: f64, cells: usize, order: usize, i: usize) -> f64 {
    let q = order;
    let s: f64 = (i + 1..=i + q)
        .map(|k| open_uniform_knot(k, q, cells))
        .sum();
    fraction_of_interval(lower, upper, s, (q * cells) as f64)
}

/// Grid vertex `i` (`0..=cells`) in physical units, exactly `lower` and `upper` at the ends.
#[inline]
pub fn vertex_1d(lower: f64, upper: f64, cells: usize, i: usize) -> f64 {
    fraction_of_interval(lower, upper, i as f64, cells as f64)
}

/// `lower + (upper - lower) * numerator / denominator`, exactly `upper` when the fraction is 1.
#[inline]
fn fraction_of_interval(lower: f64, upper: f64, numerator: f64, denominator: f64) -> f64 {
    if numerator >= denominator {
        upper
    } else {
        lower + (upper - lower) * numerator / denominator
    }
}

/// Positions of the control points (grid nodes) along one axis: the Greville abscissae of the
/// open uniform knot vector, `x_i = lower + h * (xi_{i+1} + ... + xi_{i+q}) / q` in knot units.
/// For q = 1 these are the grid vertices; there are `cells + q` of them and the first and last
/// lie on the grid boundary.
pub fn control_points_1d(lower: f64, upper: f64, cells: usize, order: usize) -> Vec<f64> {
    (0..cells + order)
        .map(|i| greville_abscissa(lower, upper, cells, order, i))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::test_points::Lcg;

    const MAX_ORDER: usize = 5;

    /// All `cells + q` functions at `t` as a dense vector (zero outside the span).
    fn dense(order: usize, cells: usize, t: f64) -> (Vec<f64>, Vec<f64>) {
        dense_on_cell(order, cells, cell_of_knot_coordinate(t, cells).unwrap(), t)
    }

    /// All functions, using the polynomial pieces of cell `cell` (extrapolated off the cell).
    fn dense_on_cell(order: usize, cells: usize, cell: usize, t: f64) -> (Vec<f64>, Vec<f64>) {
        let mut v = vec![0.0; order + 1];
        let mut d = vec![0.0; order + 1];
        bspline_span(order, cells, cell, t, &mut v, &mut d);
        let mut vals = vec![0.0; cells + order];
        let mut ders = vec![0.0; cells + order];
        vals[cell..=cell + order].copy_from_slice(&v);
        ders[cell..=cell + order].copy_from_slice(&d);
        (vals, ders)
    }

    /// Straight from eq. 6-7 on the full knot vector (all functions of all levels), as an
    /// independent reference for the span-restricted in-place kernel.
    fn cox_de_boor_reference(order: usize, cells: usize, t: f64) -> Vec<f64> {
        let xi = open_uniform_knot_vector(order, cells);
        let m = xi.len();
        let last = cell_of_knot_coordinate(t, cells).unwrap() + order;
        let mut n: Vec<f64> = (0..m - 1)
            .map(|i| if i == last { 1.0 } else { 0.0 })
            .collect();
        for p in 1..=order {
            n = (0..m - 1 - p)
                .map(|i| {
                    ratio(t - xi[i], xi[i + p] - xi[i]) * n[i]
                        + ratio(xi[i + p + 1] - t, xi[i + p + 1] - xi[i + 1]) * n[i + 1]
                })
                .collect();
        }
        n
    }

    #[test]
    fn knot_vector_is_open_uniform() {
        assert_eq!(
            open_uniform_knot_vector(2, 4),
            vec![0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 4.0, 4.0]
        );
        assert_eq!(open_uniform_knot_vector(1, 1), vec![0.0, 0.0, 1.0, 1.0]);
        assert_eq!(
            open_uniform_knot_vector(3, 2),
            vec![0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 2.0, 2.0, 2.0]
        );
    }

    #[test]
    fn cell_lookup_is_half_open_with_closed_upper_end() {
        assert_eq!(cell_of_knot_coordinate(0.0, 3), Some(0));
        assert_eq!(cell_of_knot_coordinate(0.999, 3), Some(0));
        assert_eq!(cell_of_knot_coordinate(1.0, 3), Some(1));
        assert_eq!(cell_of_knot_coordinate(2.5, 3), Some(2));
        assert_eq!(cell_of_knot_coordinate(3.0, 3), Some(2));
        assert_eq!(cell_of_knot_coordinate(3.0 + 1e-12, 3), None);
        assert_eq!(cell_of_knot_coordinate(-1e-300, 3), None);
        assert_eq!(cell_of_knot_coordinate(f64::NAN, 3), None);
        assert_eq!(cell_of_knot_coordinate(f64::INFINITY, 3), None);
        assert_eq!(cell_of_knot_coordinate(0.0, 0), None);
    }

    #[test]
    fn span_kernel_matches_full_recursion() {
        let mut rng = Lcg::new(1);
        for q in 0..=MAX_ORDER {
            for cells in [1, 2, 3, 7] {
                for _ in 0..200 {
                    let t = rng.uniform(0.0, cells as f64);
                    let (vals, _) = dense(q, cells, t);
                    let reference = cox_de_boor_reference(q, cells, t);
                    assert_eq!(vals.len(), reference.len());
                    for (a, b) in vals.iter().zip(&reference) {
                        assert!(
                            (a - b).abs() < 1e-14,
                            "q={q} cells={cells} t={t}: {a} vs {b}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn partition_of_unity_and_non_negativity() {
        let mut rng = Lcg::new(2);
        for q in 1..=MAX_ORDER {
            for cells in [1, 2, 3, 4, 9] {
                let c = cells as f64;
                let knots_and_ends = (0..=cells).map(|k| k as f64);
                let ts: Vec<f64> = (0..500)
                    .map(|_| rng.uniform(0.0, c))
                    .chain(knots_and_ends)
                    .collect();
                for t in ts {
                    let (vals, ders) = dense(q, cells, t);
                    let sum: f64 = vals.iter().sum();
                    assert!(
                        (sum - 1.0).abs() < 1e-14,
                        "q={q} cells={cells} t={t}: sum {sum}"
                    );
                    assert!(vals.iter().all(|&v| v >= 0.0), "q={q} t={t}: {vals:?}");
                    let dsum: f64 = ders.iter().sum();
                    assert!(
                        dsum.abs() < 1e-12,
                        "q={q} cells={cells} t={t}: sum d {dsum}"
                    );
                }
            }
        }
    }

    #[test]
    fn derivatives_match_central_differences() {
        let mut rng = Lcg::new(3);
        let eps = 1e-6;
        for q in 1..=MAX_ORDER {
            for cells in [1, 3, 6] {
                for _ in 0..200 {
                    let t = rng.uniform(0.0, cells as f64);
                    // keep t +- eps inside one span (q = 1 derivatives jump at knots)
                    if (t - t.round()).abs() < 10.0 * eps {
                        continue;
                    }
                    let (_, ders) = dense(q, cells, t);
                    let (plus, _) = dense(q, cells, t + eps);
                    let (minus, _) = dense(q, cells, t - eps);
                    for i in 0..cells + q {
                        let fd = (plus[i] - minus[i]) / (2.0 * eps);
                        assert!(
                            (fd - ders[i]).abs() < 1e-7 * (1.0 + q as f64),
                            "q={q} cells={cells} t={t} i={i}: fd {fd} vs {}",
                            ders[i]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn order_one_bsplines_are_the_hat_functions() {
        let mut rng = Lcg::new(4);
        for cells in [1, 2, 5, 10] {
            let mut ts: Vec<f64> = (0..300).map(|_| rng.uniform(0.0, cells as f64)).collect();
            ts.extend((0..=cells).map(|k| k as f64));
            for t in ts {
                let cell = cell_of_knot_coordinate(t, cells).unwrap();
                let (mut bv, mut bd) = ([0.0; 2], [0.0; 2]);
                let (mut hv, mut hd) = ([0.0; 2], [0.0; 2]);
                bspline_span(1, cells, cell, t, &mut bv, &mut bd);
                hat_span(cell, t, &mut hv, &mut hd);
                for j in 0..2 {
                    assert!((bv[j] - hv[j]).abs() <= 1e-14, "t={t}: {bv:?} vs {hv:?}");
                    assert!((bd[j] - hd[j]).abs() <= 1e-14, "t={t}: {bd:?} vs {hd:?}");
                }
                // and against the closed form max(0, 1 - |t - v|) for every vertex
                let (vals, _) = dense(1, cells, t);
                for (v, value) in vals.iter().enumerate() {
                    assert!((value - hat(v, t)).abs() <= 1e-14, "t={t} v={v}");
                }
            }
        }
    }

    /// C^{q-1} continuity across interior knots: the polynomial pieces of the two adjacent
    /// spans agree at the knot in value (q >= 1), first derivative (q >= 2) and, checked by
    /// one-sided differences of the derivative, second derivative (q >= 3). For q = 1 the first
    /// derivative must jump (so the comparison is able to fail).
    #[test]
    fn continuity_across_interior_knots() {
        for q in 1..=MAX_ORDER {
            for cells in [2, 3, 6] {
                for k in 1..cells {
                    let t = k as f64;
                    let piece = |cell: usize, t: f64| dense_on_cell(q, cells, cell, t);
                    let (vl, dl) = piece(k - 1, t);
                    let (vr, dr) = piece(k, t);
                    let mut derivative_jump = 0.0_f64;
                    for i in 0..cells + q {
                        assert!((vl[i] - vr[i]).abs() < 1e-14, "q={q} knot {k} N_{i}");
                        derivative_jump = derivative_jump.max((dl[i] - dr[i]).abs());
                    }
                    if q >= 2 {
                        assert!(derivative_jump < 1e-13, "q={q} knot {k}: {derivative_jump}");
                    } else {
                        assert!(derivative_jump > 0.5, "q=1 derivative should jump at knots");
                    }
                    if q >= 3 {
                        let e = 1e-5;
                        let (_, dl2) = piece(k - 1, t - e);
                        let (_, dr2) = piece(k, t + e);
                        for i in 0..cells + q {
                            let second_left = (dl[i] - dl2[i]) / e;
                            let second_right = (dr2[i] - dr[i]) / e;
                            assert!(
                                (second_left - second_right).abs() < 1e-3,
                                "q={q} knot {k} N_{i}: {second_left} vs {second_right}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn open_knot_vector_is_interpolatory_at_both_ends() {
        for q in 1..=MAX_ORDER {
            for cells in [1, 4] {
                let (v0, _) = dense(q, cells, 0.0);
                let (vn, _) = dense(q, cells, cells as f64);
                assert_eq!(v0[0], 1.0);
                assert!(v0[1..].iter().all(|&v| v == 0.0));
                assert_eq!(vn[cells + q - 1], 1.0);
                assert!(vn[..cells + q - 1].iter().all(|&v| v == 0.0));
            }
        }
    }

    #[test]
    fn greville_abscissae() {
        for q in 1..=MAX_ORDER {
            for cells in [1, 2, 5] {
                let x = control_points_1d(0.1, 0.3, cells, q);
                assert_eq!(x.len(), cells + q);
                assert_eq!(x[0], 0.1);
                assert_eq!(x[cells + q - 1], 0.3);
                assert!(x.windows(2).all(|w| w[0] < w[1]), "q={q}: {x:?}");
            }
        }
        // q = 1: exactly the vertices
        let x = control_points_1d(-1.0, 2.0, 3, 1);
        assert_eq!(x, vec![-1.0, 0.0, 1.0, 2.0]);
        for (i, xi) in x.iter().enumerate() {
            assert_eq!(*xi, vertex_1d(-1.0, 2.0, 3, i));
        }
        // q = 2, 4 cells on [0, 1] (paper Fig. 1): (xi_{i+1} + xi_{i+2}) / 2 * h
        let x = control_points_1d(0.0, 1.0, 4, 2);
        let expected = [0.0, 0.125, 0.375, 0.625, 0.875, 1.0];
        for (a, b) in x.iter().zip(expected) {
            assert!((a - b).abs() < 1e-15, "{x:?}");
        }
    }

    /// Linear precision: sum_i x_i N_i(t) = t with the Greville abscissae as coefficients.
    #[test]
    fn greville_abscissae_reproduce_linear_functions() {
        let mut rng = Lcg::new(5);
        for q in 1..=MAX_ORDER {
            for cells in [1, 3, 8] {
                let x = control_points_1d(0.0, cells as f64, cells, q);
                for _ in 0..100 {
                    let t = rng.uniform(0.0, cells as f64);
                    let (vals, ders) = dense(q, cells, t);
                    let interp: f64 = vals.iter().zip(&x).map(|(v, xi)| v * xi).sum();
                    let slope: f64 = ders.iter().zip(&x).map(|(d, xi)| d * xi).sum();
                    assert!((interp - t).abs() < 1e-12, "q={q} t={t}: {interp}");
                    assert!((slope - 1.0).abs() < 1e-12, "q={q} t={t}: {slope}");
                }
            }
        }
    }
}
