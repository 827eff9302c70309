//! B-splines averaged over the point's domain: GIMP's integration with the B-spline basis
//! (`grid(#{ basis: "bspline", order: q, integration: "domain" })`).
//!
//! # Why
//!
//! With the points as quadrature points, B-spline MPM integrates the functions of the open knot
//! vector at a fixed boundary with a rule whose relative error depends on the points per cell
//! but not on h (the composite midpoint rule's end correction, `−Δ²/24 [f']`, with `f ~ σ N'`
//! varying on the scale h). The stress next to a fixed base is then wrong by a fixed fraction
//! of the load at any resolution, and the paper's eq. 15 converges at first order only
//! (`docs/results.md`). Here the basis itself is integrated exactly over each point's domain,
//! as GIMP does for the hat functions (`super::gimp`):
//!
//! ```text
//!   S_ip = (1/V_p) ∫_Ωp N_i dx,        ∇S_ip = (1/V_p) ∫_Ωp ∇N_i dx,
//! ```
//!
//! with `Ω_p` the box of half-lengths `lp0_k F_kk` around the point (the contiguous-GIMP domain,
//! `super::domain`), clipped to the grid. Since the domains tile the body, `Σ_p V_p σ_p ∇S_ip`
//! is `∫ σ ∇N_i` over the body with only the stress held constant on each domain: the basis is
//! never sampled, so the boundary functions cost no quadrature error, and what remains is
//! `σ'' lp²`-small in the interior and confined to the free surface.
//!
//! # The 1D weight
//!
//! The B-splines are polynomials of degree q on every cell, so the average over the part
//! `[a_c, b_c]` of the domain inside cell c is exact with `n = ⌊q/2⌋ + 1` Gauss–Legendre points
//! (exact for degree `2n − 1 ≥ q`):
//!
//! ```text
//!   S_i = Σ_c Σ_g w_cg N_i(x_cg),     S_i' = Σ_c Σ_g w_cg N_i'(x_cg),     Σ_cg w_cg = 1,
//! ```
//!
//! a partition of unity piece by piece (`Σ_i S_i = 1`, `Σ_i S_i' = 0`); a domain of zero length
//! gives the B-spline at the point. For q = 1 these are GIMP's weights (`super::gimp`): the
//! one-point rule is the midpoint, taken in closed form. In 2D/3D the weights are tensor
//! products.

use nalgebra::SVector;

use super::axis::{Axis, OutsideGrid};
use super::bspline::bspline_span;
use super::grid::{BasisScratch, GridBasis, NodeWeight};

impl<const D: usize> GridBasis<D> {
    /// Weights of a point at `x` whose box domain has half-lengths `half_lengths`: the grid's
    /// functions (B-splines, or the hats of GIMP) averaged over the box, the tensor product of
    /// [`averaged_span`] on every axis. Fills `out` like [`GridBasis::eval`] (empty on error).
    pub fn eval_domain_average(
        &self,
        x: &SVector<f64, D>,
        half_lengths: &SVector<f64, D>,
        scratch: &mut BasisScratch,
        out: &mut Vec<NodeWeight<D>>,
    ) -> Result<(), OutsideGrid> {
        let order = self.axes[0].order();
        // the hats (GIMP) are averaged in closed form: no Gauss rule, no work buffers
        let (mut rule, mut span) = if order == 1 {
            (Vec::new(), [Vec::new(), Vec::new()])
        } else {
            scratch.take_domain_buffers(order / 2 + 1)
        };
        let evaluated = self.eval_tensor_product(scratch, out, |k, axis, values, derivatives| {
            averaged_span(
                axis,
                order,
                x[k],
                half_lengths[k],
                &rule,
                &mut span,
                values,
                derivatives,
            )
        });
        if order > 1 {
            scratch.put_domain_buffers(std::mem::take(&mut rule), std::mem::take(&mut span));
        }
        evaluated
    }
}

/// Averages of the order-q B-splines of `axis` (q = `order`; the hats for q = 1) and of their
/// derivatives (physical units) over `[x − half_length, x + half_length]` clipped to the axis,
/// with the Gauss rule `rule` (points
/// on `[−1, 1]`, weights summing to 2) of at least `⌊q/2⌋ + 1` points. Returns the index of the
/// first function with a weight and fills `values`/`derivatives` for consecutive functions
/// (cleared first; left empty on error). `work` holds the per-point span values. For q = 1 the
/// pieces are averaged in closed form (the hats are linear on them) and `rule` and `work` are
/// not used.
#[allow(clippy::too_many_arguments)]
pub fn averaged_span(
    axis: &Axis,
    order: usize,
    x: f64,
    half_length: f64,
    rule: &[(f64, f64)],
    work: &mut [Vec<f64>; 2],
    values: &mut Vec<f64>,
    derivatives: &mut Vec<f64>,
) -> Result<usize, OutsideGrid> {
    debug_assert!(half_length >= 0.0 && half_length.is_finite());
    debug_assert!(order == 1 || 2 * rule.len() > order);
    values.clear();
    derivatives.clear();
    let (cell, t) = axis.locate(x)?;
    let cells = axis.cells;
    let half = half_length / axis.spacing();
    let ta = (t - half).max(0.0);
    let tb = (t + half).min(cells as f64);
    let first = if tb <= ta {
        values.resize(order + 1, 0.0);
        derivatives.resize(order + 1, 0.0);
        bspline_span(order, cells, cell, t, values, derivatives);
        cell
    } else {
        let first = (ta.floor() as usize).min(cells - 1);
        let last = (tb.ceil() as usize)
            .saturating_sub(1)
            .clamp(first, cells - 1);
        values.resize(last - first + 1 + order, 0.0);
        derivatives.resize(last - first + 1 + order, 0.0);
        let inverse_length = 1.0 / (tb - ta);
        for c in first..=last {
            let a = ta.max(c as f64);
            let b = tb.min((c + 1) as f64);
            if b <= a {
                continue;
            }
            let (middle, radius) = (0.5 * (a + b), 0.5 * (b - a));
            let offset = c - first;
            if order == 1 {
                // the hats (GIMP): linear on the piece, the midpoint value in closed form
                let (w, m) = ((b - a) * inverse_length, middle - c as f64);
                values[offset] += w * (1.0 - m);
                values[offset + 1] += w * m;
                derivatives[offset] -= w;
                derivatives[offset + 1] += w;
                continue;
            }
            let [span_values, span_derivatives] = &mut *work;
            span_values.resize(order + 1, 0.0);
            span_derivatives.resize(order + 1, 0.0);
            for &(xi, weight) in rule {
                let w = 0.5 * weight * (b - a) * inverse_length;
                bspline_span(
                    order,
                    cells,
                    c,
                    middle + radius * xi,
                    span_values,
                    span_derivatives,
                );
                for j in 0..=order {
                    values[offset + j] += w * span_values[j];
                    derivatives[offset + j] += w * span_derivatives[j];
                }
            }
        }
        first
    };
    let inverse_h = 1.0 / axis.spacing();
    for d in derivatives.iter_mut() {
        *d *= inverse_h;
    }
    Ok(first)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::BasisKind;
    use crate::basis::test_points::dense_span;
    use crate::quadrature::gauss_legendre;

    fn rule(n: usize) -> Vec<(f64, f64)> {
        let (points, weights) = gauss_legendre(n);
        points.into_iter().zip(weights).collect()
    }

    /// All function averages of the axis as dense vectors.
    fn dense(axis: &Axis, order: usize, x: f64, l: f64) -> (Vec<f64>, Vec<f64>) {
        let rule = rule(order / 2 + 1);
        let mut work = [Vec::new(), Vec::new()];
        dense_span(axis, |v, d| {
            averaged_span(axis, order, x, l, &rule, &mut work, v, d).unwrap()
        })
    }

    /// Function i and its derivative at y, from the point evaluation.
    fn point(axis: &Axis, i: usize, y: f64) -> (f64, f64) {
        let (mut v, mut d) = (Vec::new(), Vec::new());
        let first = axis.eval(y, &mut v, &mut d).unwrap();
        if i < first || i >= first + v.len() {
            (0.0, 0.0)
        } else {
            (v[i - first], d[i - first])
        }
    }

    #[test]
    fn averages_are_the_integrals_of_the_functions_over_the_clipped_domain() {
        // values against a fine midpoint sum (the functions are continuous), derivatives against
        // the difference quotient (N(b) − N(a)) / (b − a), which is their exact average
        for order in 1..=5 {
            let axis = Axis::new(-1.0, 2.5, 7, BasisKind::BSpline { order }).unwrap();
            // domains inside a cell, across several knots, and clipped at both ends
            for (x, l) in [(0.6, 0.1), (0.3, 0.7), (-0.9, 0.3), (2.4, 0.45), (1.0, 3.0)] {
                let (values, derivatives) = dense(&axis, order, x, l);
                let (a, b) = ((x - l).max(-1.0), (x + l).min(2.5));
                let steps = 20_000;
                let dx = (b - a) / steps as f64;
                for i in 0..axis.num_functions() {
                    let mean: f64 = (0..steps)
                        .map(|k| point(&axis, i, a + (k as f64 + 0.5) * dx).0 * dx / (b - a))
                        .sum();
                    let quotient = (point(&axis, i, b).0 - point(&axis, i, a).0) / (b - a);
                    assert!(
                        (values[i] - mean).abs() < 1e-8,
                        "q={order} x={x} l={l} i={i}: {} vs {mean}",
                        values[i]
                    );
                    assert!(
                        (derivatives[i] - quotient).abs() < 1e-12,
                        "q={order} x={x} l={l} i={i}: {} vs {quotient}",
                        derivatives[i]
                    );
                }
                assert!((values.iter().sum::<f64>() - 1.0).abs() < 1e-13);
                assert!(derivatives.iter().sum::<f64>().abs() < 1e-12);
            }
        }
    }

    #[test]
    fn a_vanishing_domain_is_the_point_evaluation() {
        let axis = Axis::new(0.0, 3.0, 6, BasisKind::BSpline { order: 3 }).unwrap();
        let (values, derivatives) = dense(&axis, 3, 1.23, 0.0);
        for (i, (v, d)) in values.iter().zip(&derivatives).enumerate() {
            let (n, dn) = point(&axis, i, 1.23);
            assert!((v - n).abs() < 1e-15 && (d - dn).abs() < 1e-13);
        }
    }
}
