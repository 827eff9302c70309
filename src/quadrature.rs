//! Gauss–Legendre quadrature: the rule on the parent interval `[-1, 1]`, on the unit interval
//! `[0, 1]`, and tensor products. One implementation serves every user: FEM integration
//! points, Gauss placement of material points, the ghost penalty's face integrals and the
//! B-spline domain averages.
//!
//! The n-point rule takes the roots ξ_g of the Legendre polynomial P_n as points and
//!
//! ```text
//!   w_g = 2 / ((1 - ξ_g²) P_n'(ξ_g)²)
//! ```
//!
//! as weights; it integrates polynomials of degree up to 2n - 1 exactly. P_n and P_n' come
//! from the three-term recurrence
//!
//! ```text
//!   P_0 = 1,  P_1 = ξ,  k P_k = (2k - 1) ξ P_{k-1} - (k - 1) P_{k-2},
//!   P_n' = n (ξ P_n - P_{n-1}) / (ξ² - 1),
//! ```
//!
//! and the roots from Newton's method started at ξ ≈ cos(π (g + 3/4) / (n + 1/2)), which
//! converges to machine precision in a few iterations for every n. The rule is symmetric: the
//! points are computed for one half and mirrored, so ξ_g = -ξ_{n-1-g} exactly.
//!
//! In D dimensions the rule with `n_k` points along axis `k` is the tensor product: points
//! `(ξ_{g_0}, ..., ξ_{g_{D-1}})` with weights `Π_k w_{g_k}`, numbered axis 0 fastest.

use nalgebra::SVector;

/// P_n(ξ) and P_n'(ξ) for n >= 1 and |ξ| < 1.
fn legendre_with_derivative(n: usize, xi: f64) -> (f64, f64) {
    let (mut previous, mut current) = (1.0, xi);
    for k in 2..=n {
        let k = k as f64;
        let next = ((2.0 * k - 1.0) * xi * current - (k - 1.0) * previous) / k;
        previous = current;
        current = next;
    }
    let derivative = n as f64 * (xi * current - previous) / (xi * xi - 1.0);
    (current, derivative)
}

/// The n-point Gauss–Legendre rule on `[-1, 1]`: points in increasing order and their weights.
/// `n = 0` gives the empty rule.
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut points = vec![0.0; n];
    let mut weights = vec![0.0; n];
    for g in 0..n.div_ceil(2) {
        // The g-th largest root.
        let mut xi = (std::f64::consts::PI * (g as f64 + 0.75) / (n as f64 + 0.5)).cos();
        if n % 2 == 1 && g == n / 2 {
            xi = 0.0;
        } else {
            for _ in 0..100 {
                let (p, dp) = legendre_with_derivative(n, xi);
                let step = p / dp;
                xi -= step;
                if step.abs() <= 1e-16 {
                    break;
                }
            }
        }
        let (_, dp) = legendre_with_derivative(n, xi);
        let weight = 2.0 / ((1.0 - xi * xi) * dp * dp);
        points[g] = -xi;
        points[n - 1 - g] = xi;
        weights[g] = weight;
        weights[n - 1 - g] = weight;
    }
    (points, weights)
}

/// The n-point rule mapped to `[0, 1]`: `(point, weight)` pairs in increasing order,
/// `u_g = (1 + ξ_g) / 2`, `w_g / 2`.
pub fn gauss_legendre_unit(n: usize) -> Vec<(f64, f64)> {
    let (points, weights) = gauss_legendre(n);
    points
        .into_iter()
        .zip(weights)
        .map(|(xi, w)| (0.5 * (1.0 + xi), 0.5 * w))
        .collect()
}

/// The tensor-product Gauss rule with `counts[k]` points along axis `k`: every point's parent
/// coordinates and weight, axis 0 fastest.
pub fn tensor_gauss_rule<const D: usize>(counts: [usize; D]) -> Vec<(SVector<f64, D>, f64)> {
    let rules = counts.map(gauss_legendre);
    let total: usize = counts.iter().product();
    let mut out = Vec::with_capacity(total);
    for flat in 0..total {
        let mut rest = flat;
        let mut xi = SVector::<f64, D>::zeros();
        let mut weight = 1.0;
        for (k, (points, weights)) in rules.iter().enumerate() {
            let g = rest % counts[k];
            rest /= counts[k];
            xi[k] = points[g];
            weight *= weights[g];
        }
        out.push((xi, weight));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_order_rules_have_their_closed_forms() {
        assert_eq!(gauss_legendre(1), (vec![0.0], vec![2.0]));
        let (p, w) = gauss_legendre(2);
        let a = 1.0 / 3f64.sqrt();
        assert!(
            (p[0] + a).abs() < 1e-15 && (p[1] - a).abs() < 1e-15,
            "{p:?}"
        );
        assert!(w.iter().all(|w| (w - 1.0).abs() < 1e-15), "{w:?}");
        let (p, w) = gauss_legendre(3);
        let b = (0.6f64).sqrt();
        assert!((p[0] + b).abs() < 1e-15 && p[1] == 0.0 && (p[2] - b).abs() < 1e-15);
        assert!((w[0] - 5.0 / 9.0).abs() < 1e-15 && (w[1] - 8.0 / 9.0).abs() < 1e-15);
        assert_eq!(gauss_legendre(0), (vec![], vec![]));
    }

    /// The n-point rule integrates x^k exactly for k <= 2n - 1, and x^(2n) with the error of
    /// the Gauss–Legendre error formula.
    #[test]
    fn rules_are_exact_to_degree_two_n_minus_one() {
        for n in 1..=12 {
            let (points, weights) = gauss_legendre(n);
            assert!(
                points.windows(2).all(|p| p[0] < p[1]),
                "n = {n}: {points:?}"
            );
            assert!(points.iter().all(|p| p.abs() < 1.0));
            for k in 0..=2 * n {
                let quadrature: f64 = points
                    .iter()
                    .zip(&weights)
                    .map(|(x, w)| w * x.powi(k as i32))
                    .sum();
                let exact = if k % 2 == 1 {
                    0.0
                } else {
                    2.0 / (k as f64 + 1.0)
                };
                if k < 2 * n {
                    assert!(
                        (quadrature - exact).abs() < 1e-14,
                        "n = {n}, x^{k}: {quadrature} vs {exact}"
                    );
                } else {
                    // the known error of the rule: ∫f - Q = 2^(2n+1) (n!)^4 / ((2n+1) ((2n)!)^3)
                    // f^(2n), with f^(2n) = (2n)! for f = x^(2n)
                    let factorial = |m: usize| (1..=m).map(|i| i as f64).product::<f64>();
                    let error = 2f64.powi(2 * n as i32 + 1) * factorial(n).powi(4)
                        / ((2 * n + 1) as f64 * factorial(2 * n).powi(2));
                    let observed = exact - quadrature;
                    assert!(
                        (observed - error).abs() < 1e-6 * error + 1e-15,
                        "n = {n}, x^{k}: error {observed:e}, theory {error:e}"
                    );
                }
            }
        }
    }

    #[test]
    fn unit_rule_integrates_degree_2n_minus_1_exactly() {
        for n in 1..=8usize {
            let rule = gauss_legendre_unit(n);
            assert_eq!(rule.len(), n);
            for degree in 0..2 * n {
                let sum: f64 = rule.iter().map(|(x, w)| w * x.powi(degree as i32)).sum();
                let exact = 1.0 / (degree as f64 + 1.0);
                assert!((sum - exact).abs() < 1e-14, "n {n}, degree {degree}: {sum}");
            }
            // ... and not degree 2n (the test can fail)
            let sum: f64 = rule.iter().map(|(x, w)| w * x.powi(2 * n as i32)).sum();
            assert!((sum - 1.0 / (2 * n + 1) as f64).abs() > 1e-11, "n {n}");
        }
        let two = gauss_legendre_unit(2);
        let a = 0.5 - 0.5 / 3f64.sqrt();
        assert!((two[0].0 - a).abs() < 1e-15 && (two[0].1 - 0.5).abs() < 1e-15);
    }

    #[test]
    fn tensor_rule_integrates_products_and_orders_axis_zero_fastest() {
        let rule = tensor_gauss_rule([2, 3, 1]);
        assert_eq!(rule.len(), 6);
        let volume: f64 = rule.iter().map(|(_, w)| w).sum();
        assert!((volume - 8.0).abs() < 1e-14);
        // ∫ x² y⁴ z⁰ over [-1,1]³ = (2/3)(2/5)(2) with 2 points in x, 3 in y.
        let integral: f64 = rule
            .iter()
            .map(|(xi, w)| w * xi[0].powi(2) * xi[1].powi(4))
            .sum();
        assert!((integral - 2.0 / 3.0 * 2.0 / 5.0 * 2.0).abs() < 1e-14);
        assert!(rule[0].0[0] < rule[1].0[0] && rule[0].0[1] == rule[1].0[1]);
    }
}
