//! GIMP: the generalized interpolation material point method (Bardenhagen & Kober 2004, paper
//! ref. \[7\]), weights of the linear hat functions averaged over a box-shaped particle domain.
//!
//! # Weights
//!
//! A point p carries a characteristic function `χ_p`: 1 on its domain, the axis-aligned box
//! `Ω_p = Π_k [x_k - l_k, x_k + l_k]` (half-lengths `l_k`), 0 elsewhere, with `V_p = ∫ χ_p`.
//! Its weight and weight gradient for grid node i are the averages of the hat function and of
//! its gradient over the domain:
//!
//! ```text
//!   S_ip = (1/V_p) ∫ χ_p N_i dx,        ∇S_ip = (1/V_p) ∫ χ_p ∇N_i dx.
//! ```
//!
//! They replace `N_i(x_p)` and `∇N_i(x_p)` everywhere (internal and external force, tangent,
//! point update). Both `χ_p` and `N_i = Π_k N^k_{i_k}(x_k)` are products over the axes, so
//! the weights are tensor products of 1D weights, `S_ip = Π_k S^k`, `∂_j S_ip = S^j' Π_{k≠j}
//! S^k`, and `∇S_ip` is the derivative of `S_ip` with respect to the point position.
//!
//! # The 1D weight
//!
//! With `ξ = x_p - X_i` and `l ≤ h/2` the average of a hat is the standard piecewise quadratic
//! of Bardenhagen & Kober:
//!
//! ```text
//!   S(ξ) = (h + l + ξ)² / (4hl)        -h - l < ξ ≤ -h + l        S' = (h + l + ξ) / (2hl)
//!          1 + ξ/h                     -h + l < ξ ≤ -l                 1/h
//!          1 - (ξ² + l²) / (2hl)           -l < ξ ≤  l                 -ξ / (hl)
//!          1 - ξ/h                          l < ξ ≤ h - l              -1/h
//!          (h + l - ξ)² / (4hl)         h - l < ξ ≤ h + l              -(h + l - ξ) / (2hl)
//!          0                            otherwise
//! ```
//!
//! The kernel [`gimp_span`] (the order-1 case of [`super::averaged`]) computes the same
//! integral for any `l` (also `l > h/2`, which a stretched domain can reach) without case
//! analysis: the hat is linear on every cell, so its integral over the part `[a_c, b_c]` of the
//! domain inside cell c is exact by the midpoint rule, and
//!
//! ```text
//!   S_i = Σ_c w_c N_i(m_c),    S_i' = Σ_c w_c N_i'|_c,    w_c = (b_c - a_c) / (b - a),
//!   m_c = (a_c + b_c) / 2,
//! ```
//!
//! which is a partition of unity (`Σ_i S_i = 1`, `Σ_i S_i' = 0`) piece by piece and stays
//! accurate as `l → 0`, where it becomes the linear MPM weight `N_i(x_p)` (one piece, `w = 1`,
//! `m = x_p`); `l = 0` is exactly linear MPM. The tests check it against the closed form above,
//! against a 1000-point numerical integration and against finite differences.
//!
//! # Domains at the grid boundary
//!
//! The hat functions end at the grid boundary, so the domain is clipped to the grid:
//! `[a, b] = [x - l, x + l] ∩ [lower, upper]` per axis, and the averages are taken over the
//! clipped box (volume `b - a` per axis). This keeps the partition of unity. For a clipped
//! domain `∇S_ip` is still the domain average of `∇N_i` (the GIMP definition used in the weak
//! form), which then differs from the derivative of `S_ip` with respect to `x_p`. The point
//! itself must be inside the grid ([`OutsideGrid`] otherwise).
//!
//! # Variants
//!
//! The half-lengths at the start of a load step come from [`super::domain`]: uGIMP keeps the
//! initial `l_k = lp0_k` (`lp0_k = h_k / (2 ppc_k)`, the point's share of its cell); the
//! contiguous-particle variant stretches them with the deformation, `l_k = lp0_k F_kk`. On the
//! compressed column the stretched domains stay contiguous and converge (`tests/column.rs`);
//! the fixed ones overlap and the error stalls (W = 40000: 6.5e-4 against 9.9e-5 at 200 cells),
//! so `"stretched"` is the scene default.
//!
//! # Points per cell
//!
//! Use at least 2 points per cell per axis. With one, each domain is about a cell long, and a
//! point centred on a grid vertex sees no strain from the alternating nodal mode
//! `w_i = (-1)^i` (the hats' mean slope over `[X_i - h/2, X_i + h/2]` vanishes). When a
//! compressed column carries its points over the vertices the stiffness nearly loses that mode,
//! and GIMP, fixed or stretched, diverges: 1D column at W = 10000 runs at 50 and 100 cells but
//! fails at 200 and 400 cells once the top points have moved about half a cell. (CPDI has the
//! same stiffness, but its trapezoidal weights move every point with the ends of its domain,
//! which stay contiguous; in 1D with one point per cell it then behaves like linear finite
//! elements on the statically determinate column and reproduces the semi-analytic stress
//! almost to round-off: eq. 15 error 4e-12 at W = 10000, 3.5e-9 at W = 40000.)

use super::averaged::averaged_span;
use super::axis::{Axis, OutsideGrid};

/// 1D GIMP weights on one axis: the hat functions averaged over the domain
/// `[x - half_length, x + half_length]` clipped to the axis.
///
/// Returns the index `first` of the first vertex with a weight and fills `values[j] =
/// S_{first+j}` and `derivatives[j] = S'_{first+j}` (physical units) for consecutive vertices;
/// as many as the clipped domain touches (2 for a domain inside one cell). The buffers are
/// cleared first and left empty on error (`x` outside the axis or NaN). `half_length` must be
/// finite and non-negative; 0 gives the linear hat functions at `x`.
pub fn gimp_span(
    axis: &Axis,
    x: f64,
    half_length: f64,
    values: &mut Vec<f64>,
    derivatives: &mut Vec<f64>,
) -> Result<usize, OutsideGrid> {
    // the hats are the B-splines of order 1, and the one-point Gauss rule is the midpoint rule
    let mut work = [Vec::new(), Vec::new()];
    averaged_span(
        axis,
        1,
        x,
        half_length,
        &[(0.0, 2.0)],
        &mut work,
        values,
        derivatives,
    )
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::basis::test_points::{Lcg, assert_linear_reproduction, dense_span, weight_of};
    use crate::basis::{BasisKind, GimpDomain};
    use crate::basis::{BasisScratch, GridBasis};
    use nalgebra::SVector;

    const GIMP: BasisKind = BasisKind::Gimp {
        domain: GimpDomain::Fixed,
    };

    fn axis() -> Axis {
        Axis::new(-1.0, 2.5, 7, GIMP).unwrap() // h = 0.5
    }

    /// All vertex weights of the axis as dense vectors.
    pub(crate) fn dense_1d(axis: &Axis, x: f64, l: f64) -> (Vec<f64>, Vec<f64>) {
        dense_span(axis, |v, d| gimp_span(axis, x, l, v, d).unwrap())
    }

    /// The hat of vertex i and its derivative at y (0 outside the axis).
    fn hat(axis: &Axis, i: usize, y: f64) -> (f64, f64) {
        let h = axis.spacing();
        let s = (y - axis.vertex(i)) / h;
        if y < axis.lower || y > axis.upper || s.abs() >= 1.0 {
            (0.0, 0.0)
        } else {
            (1.0 - s.abs(), -s.signum() / h)
        }
    }

    /// Bardenhagen & Kober's closed form (module docs), valid for l <= h/2.
    fn closed_form(xi: f64, h: f64, l: f64) -> (f64, f64) {
        if xi <= -h - l || xi >= h + l {
            (0.0, 0.0)
        } else if xi <= -h + l {
            (
                (h + l + xi).powi(2) / (4.0 * h * l),
                (h + l + xi) / (2.0 * h * l),
            )
        } else if xi <= -l {
            (1.0 + xi / h, 1.0 / h)
        } else if xi <= l {
            (1.0 - (xi * xi + l * l) / (2.0 * h * l), -xi / (h * l))
        } else if xi <= h - l {
            (1.0 - xi / h, -1.0 / h)
        } else {
            (
                (h + l - xi).powi(2) / (4.0 * h * l),
                -(h + l - xi) / (2.0 * h * l),
            )
        }
    }

    #[test]
    fn partition_of_unity_and_non_negative() {
        let axis = axis();
        let mut rng = Lcg::new(1);
        for _ in 0..2000 {
            let x = rng.uniform(axis.lower, axis.upper);
            let l = rng.uniform(0.0, 1.6) * axis.spacing();
            let (vals, ders) = dense_1d(&axis, x, l);
            let sum: f64 = vals.iter().sum();
            let dsum: f64 = ders.iter().sum();
            assert!((sum - 1.0).abs() < 1e-14, "x={x} l={l}: {sum}");
            assert!(dsum.abs() < 1e-12, "x={x} l={l}: {dsum}");
            assert!(vals.iter().all(|&v| v >= 0.0));
        }
    }

    /// Against a 1000-point midpoint rule of the hat and its derivative over the clipped
    /// domain, domains of any size, also cut by the grid boundary.
    #[test]
    fn matches_numerical_integration_of_the_hat() {
        let axis = axis();
        let mut rng = Lcg::new(2);
        let samples = 1000;
        for _ in 0..300 {
            let x = rng.uniform(axis.lower, axis.upper);
            let l = rng.uniform(0.01, 1.3) * axis.spacing();
            let (a, b) = ((x - l).max(axis.lower), (x + l).min(axis.upper));
            let (vals, ders) = dense_1d(&axis, x, l);
            for i in 0..axis.num_functions() {
                let dy = (b - a) / samples as f64;
                let (mut v, mut d) = (0.0, 0.0);
                for k in 0..samples {
                    let (nv, nd) = hat(&axis, i, a + (k as f64 + 0.5) * dy);
                    v += nv * dy;
                    d += nd * dy;
                }
                let (v, d) = (v / (b - a), d / (b - a));
                assert!(
                    (vals[i] - v).abs() < 1e-6,
                    "x={x} l={l} i={i}: {} vs {v}",
                    vals[i]
                );
                // the derivative of a hat jumps: one sample per kink is off by up to 2/h
                let tolerance = 4.0 / (axis.spacing() * samples as f64);
                assert!(
                    (ders[i] - d).abs() < tolerance,
                    "x={x} l={l} i={i}: {} vs {d}",
                    ders[i]
                );
            }
        }
    }

    #[test]
    fn matches_the_closed_form_piecewise_quadratic() {
        let axis = axis();
        let h = axis.spacing();
        let mut rng = Lcg::new(3);
        for _ in 0..2000 {
            let l = rng.uniform(0.02, 0.5) * h;
            // keep the domain inside the grid so no clipping
            let x = rng.uniform(axis.lower + l, axis.upper - l);
            let (vals, ders) = dense_1d(&axis, x, l);
            for i in 0..axis.num_functions() {
                let (v, d) = closed_form(x - axis.vertex(i), h, l);
                assert!(
                    (vals[i] - v).abs() < 1e-13,
                    "x={x} l={l} i={i}: {} vs {v}",
                    vals[i]
                );
                assert!(
                    (ders[i] - d).abs() < 1e-11,
                    "x={x} l={l} i={i}: {} vs {d}",
                    ders[i]
                );
            }
        }
    }

    #[test]
    fn derivatives_match_central_differences() {
        let axis = axis();
        let mut rng = Lcg::new(4);
        let eps = 1e-7;
        for _ in 0..500 {
            let l = rng.uniform(0.05, 1.2) * axis.spacing();
            let x = rng.uniform(axis.lower + l + eps, axis.upper - l - eps);
            let (_, ders) = dense_1d(&axis, x, l);
            let (plus, _) = dense_1d(&axis, x + eps, l);
            let (minus, _) = dense_1d(&axis, x - eps, l);
            for i in 0..axis.num_functions() {
                let fd = (plus[i] - minus[i]) / (2.0 * eps);
                assert!(
                    (fd - ders[i]).abs() < 1e-6,
                    "x={x} l={l} i={i}: {fd} vs {}",
                    ders[i]
                );
            }
        }
    }

    #[test]
    fn vanishing_domain_is_linear_mpm() {
        let axis = axis();
        let linear = Axis {
            kind: BasisKind::Linear,
            ..axis
        };
        let mut rng = Lcg::new(5);
        let (mut lv, mut ld) = (Vec::new(), Vec::new());
        for _ in 0..500 {
            let x = rng.uniform(axis.lower, axis.upper);
            let first = linear.eval(x, &mut lv, &mut ld).unwrap();
            let mut hats = vec![(0.0, 0.0); axis.num_functions()];
            for j in 0..2 {
                hats[first + j] = (lv[j], ld[j]);
            }
            // l = 0: bitwise the linear basis
            let (vals, ders) = dense_1d(&axis, x, 0.0);
            for i in 0..axis.num_functions() {
                assert_eq!((vals[i], ders[i]), hats[i], "x={x}");
            }
            // l -> 0: converges to it (derivatives away from the vertices)
            let l = 1e-9 * axis.spacing();
            let (vals, ders) = dense_1d(&axis, x, l);
            let t = (x - axis.lower) / axis.spacing();
            for i in 0..axis.num_functions() {
                assert!((vals[i] - hats[i].0).abs() < 1e-9, "x={x}");
                if (t - t.round()).abs() > 1e-6 {
                    assert!((ders[i] - hats[i].1).abs() < 1e-9, "x={x}");
                }
            }
        }
    }

    #[test]
    fn domain_cut_by_the_boundary_is_averaged_over_its_inside_part() {
        let axis = axis();
        let h = axis.spacing();
        // x = lower + h/4, l = h/2: clipped domain [lower, lower + 3h/4]
        let (vals, ders) = dense_1d(&axis, axis.lower + 0.25 * h, 0.5 * h);
        // ∫_0^{3/4} (1 - s) ds / (3/4) = (3/4 - 9/32) / (3/4) = 5/8
        assert!((vals[0] - 0.625).abs() < 1e-15);
        assert!((vals[1] - 0.375).abs() < 1e-15);
        assert!((ders[0] + 1.0 / h).abs() < 1e-14 && (ders[1] - 1.0 / h).abs() < 1e-14);
    }

    #[test]
    fn point_outside_the_grid_is_an_error() {
        let axis = axis();
        let (mut v, mut d) = (vec![1.0], vec![1.0]);
        assert!(gimp_span(&axis, axis.upper + 1e-9, 0.1, &mut v, &mut d).is_err());
        assert!(v.is_empty() && d.is_empty());
        assert!(gimp_span(&axis, f64::NAN, 0.1, &mut v, &mut d).is_err());
    }

    /// 2D/3D weights are products of the 1D weights; partition of unity, and the domain
    /// average reproduces linear fields: Σ S_i X_i = x_p (unclipped), Σ X_i ⊗ ∇S_i = I.
    fn check_tensor<const D: usize>(grid: &GridBasis<D>, seed: u64) {
        let mut rng = Lcg::new(seed);
        let mut scratch = BasisScratch::default();
        let mut out = Vec::new();
        for _ in 0..200 {
            let l =
                SVector::<f64, D>::from_fn(|k, _| rng.uniform(0.05, 0.9) * grid.axes[k].spacing());
            let x = SVector::<f64, D>::from_fn(|k, _| {
                rng.uniform(grid.axes[k].lower + l[k], grid.axes[k].upper - l[k])
            });
            grid.eval_domain_average(&x, &l, &mut scratch, &mut out)
                .unwrap();
            let axes: Vec<(Vec<f64>, Vec<f64>)> = (0..D)
                .map(|k| dense_1d(&grid.axes[k], x[k], l[k]))
                .collect();
            let mut expected_count = 0;
            for index in 0..grid.num_nodes() {
                let multi = grid.node_multi_index(index);
                let value: f64 = (0..D).map(|k| axes[k].0[multi[k]]).product();
                let gradient = SVector::<f64, D>::from_fn(|j, _| {
                    (0..D)
                        .map(|k| {
                            if k == j {
                                axes[k].1[multi[k]]
                            } else {
                                axes[k].0[multi[k]]
                            }
                        })
                        .product()
                });
                let (v, g) = weight_of(&out, index);
                assert!((v - value).abs() < 1e-15);
                assert!((g - gradient).norm() < 1e-12);
                if value != 0.0 || gradient.norm() != 0.0 {
                    expected_count += 1;
                }
            }
            assert_eq!(out.len(), expected_count);
            assert_linear_reproduction(grid, &out, &x, 1e-13);
        }
    }

    #[test]
    fn tensor_products_in_2d_and_3d() {
        let g2 = GridBasis::<2>::new(&[-1.0, 0.5], &[2.0, 1.5], &[5, 3], GIMP).unwrap();
        let g3 =
            GridBasis::<3>::new(&[0.0, -1.0, 2.0], &[1.0, 1.0, 2.5], &[3, 4, 2], GIMP).unwrap();
        check_tensor(&g2, 6);
        check_tensor(&g3, 7);
    }
}
