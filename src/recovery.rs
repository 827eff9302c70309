//! # Moving-least-squares (MLS) stress recovery
//!
//! The paper closes with "optimum rates of convergence were not achieved due to projection and
//! integration errors", and names MLS data reconstruction (its ref. \[11\], Sulsky & Gong) as the
//! remedy. This module is that reconstruction as a pure kernel over plain slices: given values
//! `v_j` (any number of components) at points `x_j`, it returns at every point `x_p` the value
//! of the weighted least-squares polynomial fitted to its neighbours.
//!
//! ## Fit
//!
//! For the point `p`, with the support radius `R` and the scaled offsets `ξ_j = (x_j − x_p) / R`,
//! the polynomial `P(ξ) = Σ_k a_k m_k(ξ)` over the monomials `m_k` of total degree `≤ m`
//! (`m` = [`MlsSettings::order`]; in `D` dimensions there are `C(m + D, D)` of them, `m_0 = 1`)
//! minimises
//!
//! ```text
//! J(a) = Σ_j w(|ξ_j|) (P(ξ_j) − v_j)²,      w(s) = (1 − s²)³ for s < 1, 0 otherwise,
//! ```
//!
//! i.e. solves the normal equations `A a = b` with the moment matrix `A = Σ_j w_j m(ξ_j) m(ξ_j)ᵀ`
//! and `b = Σ_j w_j m(ξ_j) v_j` (one right-hand side per component). The recovered value is
//! `P(0) = a_0`, because every other monomial vanishes at the centre.
//!
//! ## Properties
//!
//! * **Reproduction**: if the data are a polynomial of degree `≤ m` and `A` is regular, the fit
//!   returns it exactly (to round-off), wherever `p` is — also at a boundary, where the
//!   neighbourhood is one-sided. This is what the unit tests check.
//! * **Degenerate neighbourhoods**: `A` is singular when the neighbours do not determine a
//!   polynomial of degree `m` (fewer than `m + 1` distinct positions along an axis, e.g. a
//!   2D column one point wide). The normal equations are then solved with the pseudo-inverse of
//!   `A` (its eigenvalues below `1e-10` of the largest are dropped), which gives the
//!   minimum-norm fit: monomials that the neighbourhood cannot see get no weight, and
//!   polynomial data along the directions it can see are still reproduced. The number of such
//!   points is reported in [`MlsReport::rank_deficient`].
//! * Scaling the offsets by `R` keeps the entries of `A` of order one, whatever the units.
//!
//! ## Cost
//!
//! Neighbours are found by binning the points into cubes of side `R` (visiting `3^D` bins per
//! point): `O(N · n_neighbours · n_monomials²)` plus one symmetric eigen-decomposition of a
//! `C(m + D, D)`-square matrix per point.

use std::collections::HashMap;

use nalgebra::{DMatrix, DVector, SVector};

/// What the fit uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MlsSettings {
    /// Total degree `m` of the fitted polynomial (0 = weighted average, 1 linear, 2 quadratic).
    pub order: usize,
    /// Support radius `R` of the weight (a length, > 0).
    pub radius: f64,
}

/// What happened during a recovery.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MlsReport {
    /// Points whose moment matrix was singular (solved by the pseudo-inverse).
    pub rank_deficient: usize,
}

/// Relative eigenvalue below which a direction of the moment matrix is dropped.
const RELATIVE_EIGENVALUE_CUTOFF: f64 = 1e-10;

/// Exponent tuples of the monomials of total degree `<= order` in `D` variables, constant first,
/// then by increasing degree.
pub fn monomial_exponents<const D: usize>(order: usize) -> Vec<[usize; D]> {
    let mut all = Vec::new();
    for degree in 0..=order {
        let mut current = [0usize; D];
        push_exponents_of_degree(0, degree, &mut current, &mut all);
    }
    all
}

fn push_exponents_of_degree<const D: usize>(
    axis: usize,
    remaining: usize,
    current: &mut [usize; D],
    out: &mut Vec<[usize; D]>,
) {
    if axis + 1 == D {
        current[axis] = remaining;
        out.push(*current);
        return;
    }
    for k in (0..=remaining).rev() {
        current[axis] = k;
        push_exponents_of_degree(axis + 1, remaining - k, current, out);
    }
}

/// The MLS weight `w(s) = (1 − s²)³` for `s < 1`, zero beyond.
pub fn weight(s: f64) -> f64 {
    if s < 1.0 {
        let t = 1.0 - s * s;
        t * t * t
    } else {
        0.0
    }
}

/// Recovers `values` (`components` numbers per point, point-major) at every point of
/// `positions` by MLS (see the [module docs](self)); writes `out` (same layout as `values`).
///
/// Errors (nothing is written then): a radius that is not positive and finite, a length of
/// `values` that is not `components * positions.len()`, or a non-finite position or value.
pub fn mls_recover<const D: usize>(
    positions: &[SVector<f64, D>],
    values: &[f64],
    components: usize,
    settings: MlsSettings,
    out: &mut Vec<f64>,
) -> Result<MlsReport, String> {
    let radius = settings.radius;
    if !(radius.is_finite() && radius > 0.0) {
        return Err(format!(
            "MLS recovery: the radius must be positive and finite, got {radius}"
        ));
    }
    if values.len() != components * positions.len() {
        return Err(format!(
            "MLS recovery: {} values for {} points of {components} components",
            values.len(),
            positions.len()
        ));
    }
    if let Some(p) = positions
        .iter()
        .position(|x| x.iter().any(|c| !c.is_finite()))
    {
        return Err(format!("MLS recovery: position of point {p} is not finite"));
    }
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "MLS recovery: value {} of point {} is not finite",
            k % components.max(1),
            k / components.max(1)
        ));
    }

    // Bin the points into cubes of side R.
    let bin_of = |x: &SVector<f64, D>| -> [i64; D] {
        std::array::from_fn(|a| (x[a] / radius).floor() as i64)
    };
    let mut bins: HashMap<[i64; D], Vec<usize>> = HashMap::new();
    for (j, x) in positions.iter().enumerate() {
        bins.entry(bin_of(x)).or_default().push(j);
    }

    let exponents = monomial_exponents::<D>(settings.order);
    let n = exponents.len();
    let mut moments = DMatrix::<f64>::zeros(n, n);
    let mut rhs = DMatrix::<f64>::zeros(n, components);
    let mut monomials = DVector::<f64>::zeros(n);
    let mut report = MlsReport::default();
    out.clear();
    out.resize(values.len(), 0.0);
    let neighbour_offsets = bin_offsets::<D>();

    for (p, xp) in positions.iter().enumerate() {
        moments.fill(0.0);
        rhs.fill(0.0);
        let home = bin_of(xp);
        for offset in &neighbour_offsets {
            let key: [i64; D] = std::array::from_fn(|a| home[a] + offset[a]);
            let Some(members) = bins.get(&key) else {
                continue;
            };
            for &j in members {
                let xi = (positions[j] - xp) / radius;
                let w = weight(xi.norm());
                if w == 0.0 {
                    continue;
                }
                for (k, e) in exponents.iter().enumerate() {
                    monomials[k] = (0..D).map(|a| xi[a].powi(e[a] as i32)).product();
                }
                moments.ger(w, &monomials, &monomials, 1.0);
                for c in 0..components {
                    let v = values[j * components + c];
                    for k in 0..n {
                        rhs[(k, c)] += w * monomials[k] * v;
                    }
                }
            }
        }
        // a_0 = e_0ᵀ A⁺ b = Σ_k (v_k[0] / λ_k) v_kᵀ b over the kept eigenpairs.
        let eigen = moments.clone().symmetric_eigen();
        let largest = eigen.eigenvalues.iter().fold(0.0f64, |m, &l| m.max(l));
        let cutoff = RELATIVE_EIGENVALUE_CUTOFF * largest;
        let mut dropped = false;
        for c in 0..components {
            out[p * components + c] = 0.0;
        }
        for (k, &lambda) in eigen.eigenvalues.iter().enumerate() {
            if lambda <= cutoff || lambda <= 0.0 {
                dropped = true;
                continue;
            }
            let vk = eigen.eigenvectors.column(k);
            let scale = vk[0] / lambda;
            for c in 0..components {
                out[p * components + c] += scale * vk.dot(&rhs.column(c));
            }
        }
        if dropped {
            report.rank_deficient += 1;
        }
    }
    Ok(report)
}

/// The `3^D` bin offsets `{-1, 0, 1}^D`.
fn bin_offsets<const D: usize>() -> Vec<[i64; D]> {
    let count = 3usize.pow(D as u32);
    (0..count)
        .map(|mut index| {
            std::array::from_fn(|_| {
                let digit = (index % 3) as i64 - 1;
                index /= 3;
                digit
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic, irregular point cloud in the unit box (a low-discrepancy sequence with
    /// a jitter), so that tests do not depend on a random-number crate.
    fn cloud<const D: usize>(n: usize) -> Vec<SVector<f64, D>> {
        const STEPS: [f64; 3] = [0.754_877_666_2, 0.569_840_290_9, 0.438_670_842_3];
        (0..n)
            .map(|i| {
                SVector::<f64, D>::from_fn(|a, _| {
                    let t = 0.5 + STEPS[a] * i as f64;
                    t - t.floor()
                })
            })
            .collect()
    }

    /// A polynomial of total degree `degree` in `D` variables with two components.
    fn polynomial<const D: usize>(x: &SVector<f64, D>, degree: usize) -> [f64; 2] {
        let linear: f64 = 3.0 + (0..D).map(|a| (a as f64 + 1.5) * x[a]).sum::<f64>();
        let quadratic = if degree >= 2 {
            (0..D)
                .map(|a| {
                    (0..D)
                        .map(|b| (a + 2 * b) as f64 * 0.7 * x[a] * x[b])
                        .sum::<f64>()
                })
                .sum::<f64>()
        } else {
            0.0
        };
        let value = if degree == 0 { 3.0 } else { linear + quadratic };
        [value, -2.0 * value + 1.0]
    }

    fn reproduces<const D: usize>(degree: usize, order: usize, points: usize, radius: f64) {
        let x = cloud::<D>(points);
        let values: Vec<f64> = x.iter().flat_map(|p| polynomial(p, degree)).collect();
        let mut out = Vec::new();
        let report = mls_recover(&x, &values, 2, MlsSettings { order, radius }, &mut out).unwrap();
        assert_eq!(report.rank_deficient, 0, "{D}D degree {degree}");
        let scale = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (k, (a, b)) in out.iter().zip(&values).enumerate() {
            assert!(
                (a - b).abs() <= 1e-10 * scale,
                "{D}D degree {degree} order {order}: value {k}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn linear_fields_are_reproduced_exactly_in_1d_2d_3d() {
        reproduces::<1>(1, 1, 40, 0.12);
        reproduces::<2>(1, 1, 300, 0.2);
        reproduces::<3>(1, 1, 1500, 0.3);
    }

    #[test]
    fn quadratic_fields_are_reproduced_exactly_in_1d_2d_3d() {
        reproduces::<1>(2, 2, 40, 0.12);
        reproduces::<2>(2, 2, 300, 0.25);
        reproduces::<3>(2, 2, 1500, 0.35);
    }

    #[test]
    fn a_lower_order_does_not_reproduce_a_quadratic() {
        // The test above can fail: order 1 misses the curvature of a quadratic field.
        let x = cloud::<1>(40);
        let values: Vec<f64> = x.iter().map(|p| p[0] * p[0]).collect();
        let mut out = Vec::new();
        mls_recover(
            &x,
            &values,
            1,
            MlsSettings {
                order: 1,
                radius: 0.12,
            },
            &mut out,
        )
        .unwrap();
        let worst = out
            .iter()
            .zip(&values)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst > 1e-4, "order 1 on x²: worst error {worst}");
    }

    #[test]
    fn order_zero_is_the_weighted_average() {
        let x: Vec<SVector<f64, 1>> = [0.0, 0.5, 2.0].map(|v| SVector::from([v])).to_vec();
        let values = [1.0, 3.0, 10.0];
        let mut out = Vec::new();
        let settings = MlsSettings {
            order: 0,
            radius: 1.0,
        };
        mls_recover(&x, &values, 1, settings, &mut out).unwrap();
        let w = weight(0.5);
        assert!((out[0] - (1.0 + 3.0 * w) / (1.0 + w)).abs() < 1e-14);
        assert!((out[1] - (3.0 + w) / (1.0 + w)).abs() < 1e-14);
        assert_eq!(out[2], 10.0, "an isolated point keeps its value");
    }

    #[test]
    fn a_column_one_point_wide_reproduces_along_its_axis() {
        // 2D points on the line x = 0.3: x-monomials are invisible, y-quadratics are recovered.
        let x: Vec<SVector<f64, 2>> = (0..30)
            .map(|i| SVector::from([0.3, (i as f64 + 0.5) / 30.0]))
            .collect();
        let values: Vec<f64> = x.iter().map(|p| 2.0 - p[1] + 4.0 * p[1] * p[1]).collect();
        let mut out = Vec::new();
        let settings = MlsSettings {
            order: 2,
            radius: 0.15,
        };
        let report = mls_recover(&x, &values, 1, settings, &mut out).unwrap();
        assert_eq!(report.rank_deficient, 30);
        for (a, b) in out.iter().zip(&values) {
            assert!((a - b).abs() < 1e-9, "{a} vs {b}");
        }
    }

    #[test]
    fn monomials_are_counted_and_ordered() {
        assert_eq!(monomial_exponents::<1>(2), vec![[0], [1], [2]]);
        assert_eq!(monomial_exponents::<2>(2).len(), 6);
        assert_eq!(monomial_exponents::<3>(2).len(), 10);
        assert_eq!(monomial_exponents::<3>(3).len(), 20);
        assert_eq!(monomial_exponents::<2>(1), vec![[0, 0], [1, 0], [0, 1]]);
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let x = vec![SVector::from([0.0]), SVector::from([1.0])];
        let mut out = Vec::new();
        let ok = MlsSettings {
            order: 1,
            radius: 1.0,
        };
        for radius in [0.0, -1.0, f64::NAN] {
            let settings = MlsSettings { order: 1, radius };
            assert!(mls_recover(&x, &[1.0, 2.0], 1, settings, &mut out).is_err());
        }
        assert!(mls_recover(&x, &[1.0], 1, ok, &mut out).is_err());
        assert!(mls_recover(&x, &[1.0, f64::NAN], 1, ok, &mut out).is_err());
        let bad = vec![SVector::from([0.0]), SVector::from([f64::INFINITY])];
        assert!(mls_recover(&bad, &[1.0, 2.0], 1, ok, &mut out).is_err());
    }
}
