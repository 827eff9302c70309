//! The grid's functions averaged over a flat piece of surface: the weights of the quadrature
//! points of tractions and surface conditions.
//!
//! # Why
//!
//! A surface term `∫_Γ t N_i dΓ` sampled at points carried by the material,
//! `Σ_s A_s t N_i(x_s)`, is exact only while every piece of Γ a point stands for lies within
//! one knot span: the pieces are cut to the knot lines when they are seeded, and the material
//! moves them off. The error is small for functions whose support holds much material, but a
//! body whose side moves into a new column of cells gives functions supported by a sliver of
//! material (stiffness `∝` the sliver), and the equation of such a function is then decided by
//! the quadrature's error: a block squeezed by a smooth platen with a free side (an exactly
//! homogeneous state) showed `σ_xx` of ±40 % of `σ_yy` next to its corner after one step with
//! the exactly integrating bases. So each point stands for its *share* `Γ_s` of the surface (a
//! segment in 2D, a parallelogram in 3D) and is weighted by the exact average
//!
//! ```text
//!   N̄_is = (1/|Γ_s|) ∫_Γs N_i dΓ,      ∇N̄_is = (1/|Γ_s|) ∫_Γs ∇N_i dΓ,
//! ```
//!
//! so that `Σ_s A_s N̄_is = ∫_Γ N_i dΓ` for any position of the shares against the grid (the
//! shares tile Γ).
//!
//! # The rule
//!
//! A share is `x(s) = c + Σ_a s_a e_a`, `s ∈ [−1, 1]^{D−1}`, with centre `c` and half-edges
//! `e_a`. Along each parameter `s_a` the interval is cut where the line `c + s_a e_a` crosses a
//! grid line (of any axis), and every piece gets `n = ⌈(D q + 1) / 2⌉` Gauss–Legendre points: a
//! tensor-product function of order q is a polynomial of degree at most `D q` on a piece along
//! a line, which the rule integrates exactly. This is exact for every segment in 2D and, in 3D,
//! for shares whose edges are parallel to grid axes (the faces of boxes under stretches along
//! the axes, the usual case); a parallelogram turned against the grid is cut only along its
//! centre lines and is integrated approximately (to the rule's error on the pieces that a grid
//! line crosses obliquely). In 1D a share is the point itself. A share reaching past a face of
//! the grid (next to a fixed face, its half-edges carried by its host's F) is clipped there
//! (in 3D, a Gauss point of a turned share past a face is moved onto it); a centre outside the
//! grid is an error.

use nalgebra::SVector;

use super::axis::OutsideGrid;
use super::grid::{BasisScratch, GridBasis, NodeWeight};
use crate::quadrature::gauss_legendre;

/// Buffers reused by [`GridBasis::eval_surface_average`].
#[derive(Clone, Debug, Default)]
pub struct SurfaceScratch<const D: usize> {
    basis: BasisScratch,
    /// The basis at one Gauss point.
    at: Vec<NodeWeight<D>>,
    /// The running sums, one per function met.
    sums: Vec<NodeWeight<D>>,
    /// Per parameter: the cuts of [−1, 1], then the Gauss points `(s, weight)` of its pieces.
    breaks: Vec<Vec<f64>>,
    pieces: Vec<Vec<(f64, f64)>>,
}

impl<const D: usize> GridBasis<D> {
    /// Averages of the grid's functions and their gradients over the share with centre
    /// `center` and half-edges `half_edges` (`D − 1` of them; module docs). Fills `out` like
    /// [`GridBasis::eval`], one entry per function with a non-zero average, in increasing node
    /// order. On error (a part of the share outside the grid) `out` is left empty.
    pub fn eval_surface_average(
        &self,
        center: &SVector<f64, D>,
        half_edges: &[SVector<f64, D>],
        scratch: &mut SurfaceScratch<D>,
        out: &mut Vec<NodeWeight<D>>,
    ) -> Result<(), OutsideGrid> {
        out.clear();
        debug_assert_eq!(half_edges.len(), D.saturating_sub(1));
        let inside =
            (0..D).all(|k| center[k] >= self.axes[k].lower && center[k] <= self.axes[k].upper);
        if !inside || half_edges.iter().all(|e| e.amax() == 0.0) {
            // the point itself (or the error of a point outside the grid)
            return self.eval(center, &mut scratch.basis, out);
        }
        let order = self.axes[0].order();
        let (rule_points, rule_weights) = gauss_legendre((D * order + 1).div_ceil(2));
        scratch.breaks.resize_with(half_edges.len(), Vec::new);
        scratch.pieces.resize_with(half_edges.len(), Vec::new);
        for ((breaks, pieces), edge) in scratch
            .breaks
            .iter_mut()
            .zip(scratch.pieces.iter_mut())
            .zip(half_edges)
        {
            // the part of [−1, 1] inside the grid: a share is clipped at the grid's faces (the
            // share of a point next to a fixed face, carried by its host's F, may reach past it)
            let (mut low, mut high) = (-1.0f64, 1.0f64);
            for (k, axis) in self.axes.iter().enumerate() {
                if edge[k] != 0.0 {
                    let s0 = (axis.lower - center[k]) / edge[k];
                    let s1 = (axis.upper - center[k]) / edge[k];
                    low = low.max(s0.min(s1));
                    high = high.min(s0.max(s1));
                }
            }
            if low >= high {
                // nothing of the share inside the grid (a guard: the centre is inside)
                return self.eval(center, &mut scratch.basis, out);
            }
            // where the line c + s e crosses a grid line inside the share
            breaks.clear();
            breaks.extend([low, high]);
            for (k, axis) in self.axes.iter().enumerate() {
                if edge[k] == 0.0 {
                    continue;
                }
                let h = axis.spacing();
                let (a, b) = (center[k] - edge[k], center[k] + edge[k]);
                let first = ((a.min(b) - axis.lower) / h).ceil().max(0.0) as usize;
                let last =
                    (((a.max(b) - axis.lower) / h).floor().max(0.0) as usize).min(axis.cells);
                for line in first..=last {
                    let s = (axis.vertex(line) - center[k]) / edge[k];
                    if s > low && s < high {
                        breaks.push(s);
                    }
                }
            }
            breaks.sort_by(f64::total_cmp);
            breaks.dedup();
            // the Gauss points of the pieces; the weights of one parameter sum to 1
            let length = high - low;
            pieces.clear();
            for w in breaks.windows(2) {
                let (middle, radius) = (0.5 * (w[0] + w[1]), 0.5 * (w[1] - w[0]));
                for (xi, weight) in rule_points.iter().zip(&rule_weights) {
                    pieces.push((middle + radius * xi, radius * weight / length));
                }
            }
        }
        scratch.sums.clear();
        let mut index = vec![0usize; half_edges.len()];
        'points: loop {
            let mut x = *center;
            let mut weight = 1.0;
            for (a, &i) in index.iter().enumerate() {
                let (s, w) = scratch.pieces[a][i];
                x += half_edges[a] * s;
                weight *= w;
            }
            // a corner of a parallelogram turned against a face of the grid may reach past it
            for (k, axis) in self.axes.iter().enumerate() {
                x[k] = x[k].clamp(axis.lower, axis.upper);
            }
            self.eval(&x, &mut scratch.basis, &mut scratch.at)?;
            for w in &scratch.at {
                match scratch.sums.iter_mut().find(|sum| sum.node == w.node) {
                    Some(sum) => {
                        sum.value += weight * w.value;
                        sum.gradient += w.gradient * weight;
                    }
                    None => scratch.sums.push(NodeWeight {
                        node: w.node,
                        value: weight * w.value,
                        gradient: w.gradient * weight,
                    }),
                }
            }
            // the next Gauss point, the first parameter fastest
            for (a, i) in index.iter_mut().enumerate() {
                *i += 1;
                if *i < scratch.pieces[a].len() {
                    continue 'points;
                }
                *i = 0;
            }
            break;
        }
        scratch.sums.sort_by_key(|w| w.node);
        out.extend(
            scratch
                .sums
                .iter()
                .filter(|w| w.value != 0.0 || w.gradient.amax() != 0.0)
                .cloned(),
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::BasisKind;

    fn grid<const D: usize>(kind: BasisKind) -> GridBasis<D> {
        GridBasis::new(&[0.0; D], &[1.5; D], &[6; D], kind).unwrap()
    }

    /// The averages as a dense vector over all functions.
    fn dense<const D: usize>(weights: &[NodeWeight<D>], count: usize) -> Vec<f64> {
        let mut v = vec![0.0; count];
        for w in weights {
            v[w.node] = w.value;
        }
        v
    }

    /// A brute-force average along the segment: 4000 equal parts, 6 Gauss points each.
    fn brute_force(grid: &GridBasis<2>, c: SVector<f64, 2>, e: SVector<f64, 2>) -> Vec<f64> {
        let (points, weights) = gauss_legendre(6);
        let count = grid.axes.iter().map(|a| a.num_functions()).product();
        let mut sum = vec![0.0; count];
        let (mut scratch, mut at) = (BasisScratch::default(), Vec::new());
        let parts = 4000;
        for p in 0..parts {
            let (a, b) = (
                -1.0 + 2.0 * p as f64 / parts as f64,
                -1.0 + 2.0 * (p + 1) as f64 / parts as f64,
            );
            for (xi, w) in points.iter().zip(&weights) {
                let s = 0.5 * (a + b) + 0.5 * (b - a) * xi;
                grid.eval(&(c + e * s), &mut scratch, &mut at).unwrap();
                for n in &at {
                    sum[n.node] += n.value * w * 0.25 * (b - a);
                }
            }
        }
        sum
    }

    #[test]
    fn segments_are_averaged_exactly_at_any_angle() {
        for kind in [
            BasisKind::Linear,
            BasisKind::BSpline { order: 2 },
            BasisKind::BSpline { order: 3 },
        ] {
            let grid = grid::<2>(kind);
            let count = grid.axes.iter().map(|a| a.num_functions()).product();
            let mut scratch = SurfaceScratch::default();
            let mut out = Vec::new();
            for (c, e) in [
                ([0.61, 0.37], [0.23, 0.0]),
                ([0.5, 0.5], [0.31, 0.17]),
                ([1.0, 0.25], [-0.05, 0.2]),
                ([0.75, 0.75], [0.0, 0.001]),
            ] {
                let (c, e) = (SVector::from(c), SVector::from(e));
                grid.eval_surface_average(&c, &[e], &mut scratch, &mut out)
                    .unwrap();
                let exact = brute_force(&grid, c, e);
                let got = dense(&out, count);
                let error = got
                    .iter()
                    .zip(&exact)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(error < 1e-9, "{kind:?} {c:?} {e:?}: {error:e}");
                let sum: f64 = out.iter().map(|w| w.value).sum();
                let gradient: SVector<f64, 2> = out.iter().map(|w| w.gradient).sum();
                assert!(
                    (sum - 1.0).abs() < 1e-13 && gradient.amax() < 1e-11,
                    "{sum} {gradient:?}"
                );
            }
        }
    }

    #[test]
    fn an_axis_aligned_share_is_the_domain_average() {
        // a face of a box in 3D (a degenerate box of zero thickness) and the same in 2D
        let grid = grid::<3>(BasisKind::BSpline { order: 2 });
        let (c, e) = (
            SVector::from([0.4, 0.77, 1.0]),
            [
                SVector::from([0.33, 0.0, 0.0]),
                SVector::from([0.0, 0.12, 0.0]),
            ],
        );
        let (mut scratch, mut out) = (SurfaceScratch::default(), Vec::new());
        grid.eval_surface_average(&c, &e, &mut scratch, &mut out)
            .unwrap();
        let mut box_average = Vec::new();
        grid.eval_domain_average(
            &c,
            &SVector::from([0.33, 0.12, 0.0]),
            &mut BasisScratch::default(),
            &mut box_average,
        )
        .unwrap();
        assert_eq!(out.len(), box_average.len());
        for (a, b) in out.iter().zip(&box_average) {
            assert_eq!(a.node, b.node);
            assert!((a.value - b.value).abs() < 1e-14, "{a:?} {b:?}");
            assert!((a.gradient - b.gradient).amax() < 1e-12, "{a:?} {b:?}");
        }
    }

    #[test]
    fn linear_fields_are_averaged_to_the_centre_and_points_are_points() {
        let cubic = grid::<3>(BasisKind::BSpline { order: 3 });
        let c = SVector::from([0.7, 0.55, 0.9]);
        let e = [
            SVector::from([0.2, 0.1, 0.05]),
            SVector::from([-0.05, 0.15, 0.3]),
        ];
        let (mut scratch, mut out) = (SurfaceScratch::default(), Vec::new());
        cubic
            .eval_surface_average(&c, &e, &mut scratch, &mut out)
            .unwrap();
        // Σ N̄_i X_i = the share's centroid (the basis reproduces linear fields)
        let centroid: SVector<f64, 3> = out
            .iter()
            .map(|w| cubic.node_position(w.node) * w.value)
            .sum();
        assert!((centroid - c).amax() < 1e-13, "{centroid:?}");
        // a share of zero size is the point evaluation
        let zero = [SVector::zeros(), SVector::zeros()];
        cubic
            .eval_surface_average(&c, &zero, &mut scratch, &mut out)
            .unwrap();
        let mut point = Vec::new();
        cubic
            .eval(&c, &mut BasisScratch::default(), &mut point)
            .unwrap();
        assert_eq!(out, point);
        // a share reaching past the grid's face is clipped there: averaged over the part inside
        let grid2 = grid::<2>(BasisKind::BSpline { order: 2 });
        let c2 = SVector::from([0.03166060399060571, 0.97]);
        for (reach, ok) in [(1.0, true), (1.0 + 1e-14, true), (1.5, true)] {
            let e2 = [SVector::from([c2[0] * reach, 0.0])];
            let (mut scratch2, mut out2) = (SurfaceScratch::default(), Vec::new());
            let result = grid2.eval_surface_average(&c2, &e2, &mut scratch2, &mut out2);
            assert_eq!(result.is_ok(), ok, "{reach}: {result:?}");
            if ok {
                let sum: f64 = out2.iter().map(|w| w.value).sum();
                assert!((sum - 1.0).abs() < 1e-13);
            }
        }
        // a centre outside the grid: an error, nothing written
        let outside = SVector::from([1.6, 0.5, 0.5]);
        assert!(
            cubic
                .eval_surface_average(&outside, &e, &mut scratch, &mut out)
                .is_err()
        );
        assert!(out.is_empty());
    }
}
