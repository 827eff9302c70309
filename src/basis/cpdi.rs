//! CPDI1: convected particle domain interpolation (Sadeghirad, Brannon & Burghardt 2011, paper
//! ref. \[8\]), weights of the linear hat functions averaged from the corners of a particle
//! domain carried by the deformation.
//!
//! # Domain
//!
//! The domain of point p is the parallelepiped (a segment in 1D, a parallelogram in 2D)
//!
//! ```text
//!   Ω_p = { x_p + Σ_k ξ_k r_k : ξ ∈ [-1, 1]^D },    r_k = F r_k0,    r_k0 = lp0_k e_k,
//! ```
//!
//! spanned by the D vectors `r_k` (the columns of `J = F diag(lp0)`, `lp0_k = h_k / (2 ppc_k)`,
//! half the initial point spacing), with volume `V_p = 2^D det J` and `2^D` corners
//! `x_c = x_p + Σ_k s_ck r_k`, `s_c ∈ {-1, +1}^D`.
//!
//! # Weights (CPDI1)
//!
//! Each hat function is replaced on the domain by the multilinear interpolation of its corner
//! values, `N_i ≈ Σ_c N_i(x_c) M_c(ξ)` with `M_c = Π_k (1 + s_ck ξ_k) / 2`. Averaging over the
//! domain (J is constant, `∫ M_c dξ = 1`, `∫ ∂M_c/∂ξ_k dξ = s_ck` over `[-1, 1]^D`):
//!
//! ```text
//!   S_ip  = (1/V_p) ∫ N_i dx    ≈ 2^{-D} Σ_c N_i(x_c),
//!   ∇S_ip = (1/V_p) ∫ ∇N_i dx   ≈ 2^{-D} J^{-T} Σ_c s_c N_i(x_c).
//! ```
//!
//! In 2D this is Sadeghirad et al.'s formula: with corners 1..4 = (-,-), (+,-), (+,+), (-,+),
//!
//! ```text
//!   ∇S_ip = (1/V_p) [ (N_1 - N_3) (r_1y - r_2y, r_2x - r_1x) + (N_2 - N_4) (r_1y + r_2y, -r_1x - r_2x) ],
//! ```
//!
//! and in 1D `S = (N(x - r) + N(x + r)) / 2`, `S' = (N(x + r) - N(x - r)) / (2r)`: the GIMP
//! gradient for a domain of half-length r, and the GIMP value as long as the domain lies in one
//! cell (the trapezoidal rule is exact for a linear function; it is not across a vertex, where
//! the hat has its kink). The weights are a partition of unity with `Σ_i ∇S_ip = 0`, and they
//! reproduce linear fields: `Σ_i S_ip X_i = x_p`, `Σ_i X_i ⊗ ∇S_ip = I`. For a diagonal F they
//! are the tensor products of the 1D weights.
//!
//! The nodes of a point are those supporting any of its corners. Only hat values at the corners
//! are needed, so the support follows the domain through large deformations without the
//! cell-by-cell integration of GIMP.
//!
//! # Corners at the grid boundary
//!
//! Every corner must lie in the grid (the hats end there). A body against a supported grid face
//! (a symmetry plane with rollers, a fixed base) keeps its material inside, but the
//! parallelogram `x_p + F r_k0` of a sheared point next to the face does not: its side along
//! the face tilts, and one corner crosses by about `lp0 ∂u_n/∂t` (the point's half-spacing times
//! the shear of the normal displacement along the face: 2e-6 cells after one elastic step of
//! the strip footing, 4e-8 cells on the thick cylinder's axes); under large plastic flow the
//! side's centre drifts out too (on the footing's symmetry plane at 4 cells/B a corner was out
//! by 1.6e-3 cells in step 7 with its side's centre out by more than 1e-3). A corner outside
//! by at most [`CORNER_TOLERANCE`] cells is therefore projected onto the grid face (its
//! coordinate clamped to the grid's range), the analogue of GIMP's clipping of a domain to the
//! grid: the weights stay a partition of unity with `Σ_i ∇S_ip = 0`, and only linear
//! reproduction is lost, by the projected distance. The same holds where material does leave
//! the grid (a free surface rising through its top): there up to a twentieth of a cell of the
//! domain is squeezed onto the face. Further out is a [`DomainError::CornerOutside`] error
//! naming the corner: enlarge the grid so that the body's domains stay inside it.

use nalgebra::{SMatrix, SVector};

use super::error::DomainError;
use super::grid::{BasisScratch, GridBasis, NodeWeight};

/// How far (in cells) a corner may lie outside the grid and be projected onto its boundary
/// (module docs, "Corners at the grid boundary").
pub const CORNER_TOLERANCE: f64 = 0.05;

/// Buffers reused by [`GridBasis::eval_cpdi`].
#[derive(Clone, Debug, Default)]
pub struct CpdiScratch<const D: usize> {
    basis: BasisScratch,
    corner: Vec<NodeWeight<D>>,
    /// (node, Σ_c N_i(x_c), Σ_c s_c N_i(x_c)) per corner contribution, merged by node.
    sums: Vec<(usize, f64, SVector<f64, D>)>,
}

impl<const D: usize> GridBasis<D> {
    /// CPDI1 weights of a point at `centre` with the domain spanned by the columns of
    /// `vectors` (`J = [r_1 .. r_D]`). Fills `out` like [`GridBasis::eval`] (increasing node
    /// order, only nonzero weights or gradients; empty on error).
    pub fn eval_cpdi(
        &self,
        centre: &SVector<f64, D>,
        vectors: &SMatrix<f64, D, D>,
        scratch: &mut CpdiScratch<D>,
        out: &mut Vec<NodeWeight<D>>,
    ) -> Result<(), DomainError> {
        out.clear();
        self.cell_of(centre).map_err(DomainError::Outside)?;
        let inverse_transpose = vectors
            .try_inverse()
            .filter(|inverse| inverse.iter().all(|c| c.is_finite()))
            .ok_or_else(|| {
                DomainError::Degenerate(format!(
                    "its CPDI domain is degenerate (singular domain vectors {:?})",
                    vectors.as_slice()
                ))
            })?
            .transpose();
        scratch.sums.clear();
        let corners = 1usize << D;
        for c in 0..corners {
            let signs =
                SVector::<f64, D>::from_fn(|k, _| if (c >> k) & 1 == 1 { 1.0 } else { -1.0 });
            let mut corner = centre + vectors * signs;
            for (k, axis) in self.axes.iter().enumerate() {
                let tolerance = CORNER_TOLERANCE * axis.spacing();
                if corner[k] < axis.lower && corner[k] >= axis.lower - tolerance {
                    corner[k] = axis.lower;
                } else if corner[k] > axis.upper && corner[k] <= axis.upper + tolerance {
                    corner[k] = axis.upper;
                }
            }
            self.eval(&corner, &mut scratch.basis, &mut scratch.corner)
                .map_err(|outside| DomainError::CornerOutside {
                    corner: corner.iter().copied().collect(),
                    axis: outside.axis,
                })?;
            for w in &scratch.corner {
                if w.value != 0.0 {
                    scratch.sums.push((w.node, w.value, signs * w.value));
                }
            }
        }
        scratch.sums.sort_unstable_by_key(|entry| entry.0);
        let scale = 1.0 / corners as f64;
        let mut entries = scratch.sums.iter().peekable();
        while let Some(&(node, mut value, mut signed)) = entries.next() {
            while let Some(&&(next, v, s)) = entries.peek() {
                if next != node {
                    break;
                }
                value += v;
                signed += s;
                entries.next();
            }
            let weight = NodeWeight {
                node,
                value: scale * value,
                gradient: inverse_transpose * signed * scale,
            };
            if weight.value != 0.0 || weight.gradient.iter().any(|&g| g != 0.0) {
                out.push(weight);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::gimp::tests::dense_1d;
    use crate::basis::test_points::{Lcg, assert_linear_reproduction, weight_of};
    use crate::basis::{BasisKind, GimpDomain};
    use nalgebra::{Matrix2, Vector2};

    fn grid<const D: usize>(lower: [f64; D], upper: [f64; D], cells: [usize; D]) -> GridBasis<D> {
        GridBasis::new(&lower, &upper, &cells, BasisKind::Cpdi).unwrap()
    }

    fn eval<const D: usize>(
        grid: &GridBasis<D>,
        x: &SVector<f64, D>,
        vectors: &SMatrix<f64, D, D>,
    ) -> Vec<NodeWeight<D>> {
        let mut out = Vec::new();
        grid.eval_cpdi(x, vectors, &mut CpdiScratch::default(), &mut out)
            .unwrap();
        out
    }

    /// A random deformation gradient with det > 0 (stretch, shear, rotation).
    fn random_deformation<const D: usize>(rng: &mut Lcg) -> SMatrix<f64, D, D> {
        loop {
            let f = SMatrix::<f64, D, D>::from_fn(|a, b| {
                (if a == b { 1.0 } else { 0.0 }) + rng.uniform(-0.4, 0.4)
            });
            if crate::mechanics::embed(&f).determinant() > 0.2 {
                return f;
            }
        }
    }

    /// Random centre and domain vectors whose corners lie inside the grid.
    fn random_domain<const D: usize>(
        grid: &GridBasis<D>,
        rng: &mut Lcg,
    ) -> (SVector<f64, D>, SMatrix<f64, D, D>) {
        loop {
            let r0 =
                SVector::<f64, D>::from_fn(|k, _| rng.uniform(0.05, 0.7) * grid.axes[k].spacing());
            let vectors = random_deformation::<D>(rng) * SMatrix::from_diagonal(&r0);
            let x = SVector::<f64, D>::from_fn(|k, _| {
                rng.uniform(grid.axes[k].lower, grid.axes[k].upper)
            });
            let inside = (0..1usize << D).all(|c| {
                let s =
                    SVector::<f64, D>::from_fn(|k, _| if (c >> k) & 1 == 1 { 1.0 } else { -1.0 });
                let corner = x + vectors * s;
                (0..D).all(|k| corner[k] >= grid.axes[k].lower && corner[k] <= grid.axes[k].upper)
            });
            if inside {
                return (x, vectors);
            }
        }
    }

    /// Partition of unity, Σ ∇S = 0, and linear reproduction Σ S X = x_p, Σ X ⊗ ∇S = I, for
    /// sheared and rotated domains.
    fn check_invariants<const D: usize>(grid: &GridBasis<D>, seed: u64) {
        let mut rng = Lcg::new(seed);
        for _ in 0..300 {
            let (x, vectors) = random_domain(grid, &mut rng);
            let out = eval(grid, &x, &vectors);
            assert_linear_reproduction(grid, &out, &x, 1e-12);
        }
    }

    #[test]
    fn partition_of_unity_and_linear_reproduction() {
        check_invariants(&grid([-1.0], [2.5], [7]), 31);
        check_invariants(&grid([-1.0, 0.5], [2.0, 1.5], [5, 3]), 32);
        check_invariants(&grid([0.0, -1.0, 2.0], [1.0, 1.0, 2.5], [3, 4, 2]), 33);
    }

    /// Sadeghirad et al.'s explicit 2D gradient formula (module docs).
    #[test]
    #[allow(clippy::needless_range_loop)] // node indexes the corner tables and the output
    fn gradient_matches_the_2d_formula_of_the_paper() {
        let g = grid([-1.0, 0.5], [2.0, 1.5], [5, 3]);
        let mut rng = Lcg::new(34);
        for _ in 0..200 {
            let (x, vectors) = random_domain(&g, &mut rng);
            let (r1, r2): (Vector2<f64>, Vector2<f64>) =
                (vectors.column(0).into(), vectors.column(1).into());
            let corners = [x - r1 - r2, x + r1 - r2, x + r1 + r2, x - r1 + r2];
            let volume = 4.0 * (r1.x * r2.y - r1.y * r2.x);
            let hats = |c: &Vector2<f64>| {
                let mut out = Vec::new();
                g.eval(c, &mut BasisScratch::default(), &mut out).unwrap();
                let mut dense = vec![0.0; g.num_nodes()];
                for w in out {
                    dense[w.node] = w.value;
                }
                dense
            };
            let n: Vec<Vec<f64>> = corners.iter().map(hats).collect();
            let out = eval(&g, &x, &vectors);
            for node in 0..g.num_nodes() {
                let expected = ((n[0][node] - n[2][node]) * Vector2::new(r1.y - r2.y, r2.x - r1.x)
                    + (n[1][node] - n[3][node]) * Vector2::new(r1.y + r2.y, -r1.x - r2.x))
                    / volume;
                let value = (n[0][node] + n[1][node] + n[2][node] + n[3][node]) / 4.0;
                let (v, grad) = weight_of(&out, node);
                assert!((v - value).abs() < 1e-15);
                assert!((grad - expected).norm() < 1e-11, "{grad:?} vs {expected:?}");
            }
        }
    }

    /// In 1D, CPDI with F = I and uGIMP with the same half-length have identical gradients;
    /// identical values when the domain lies in one cell, and different ones when it contains
    /// a vertex (trapezoidal rule vs exact integral across the hat's kink).
    #[test]
    fn one_dimensional_cpdi_versus_ugimp() {
        let g = grid([-1.0], [2.5], [7]);
        let gimp_axis = crate::basis::Axis {
            kind: BasisKind::Gimp {
                domain: GimpDomain::Fixed,
            },
            ..g.axes[0]
        };
        let h = g.axes[0].spacing();
        let mut rng = Lcg::new(35);
        let (mut same_cell, mut straddling) = (0, 0);
        for _ in 0..1000 {
            let r = rng.uniform(0.02, 0.5) * h;
            let x = rng.uniform(g.axes[0].lower + r, g.axes[0].upper - r);
            let out = eval(
                &g,
                &SVector::<f64, 1>::new(x),
                &SMatrix::<f64, 1, 1>::new(r),
            );
            let (gv, gd) = dense_1d(&gimp_axis, x, r);
            let mut cv = vec![0.0; gv.len()];
            let mut cd = vec![0.0; gd.len()];
            for w in &out {
                cv[w.node] = w.value;
                cd[w.node] = w.gradient[0];
            }
            for i in 0..gv.len() {
                assert!((cd[i] - gd[i]).abs() < 1e-12, "x={x} r={r}");
            }
            let t = |y: f64| ((y - g.axes[0].lower) / h).floor();
            let max_difference = (0..gv.len())
                .map(|i| (cv[i] - gv[i]).abs())
                .fold(0.0, f64::max);
            if t(x - r) == t(x + r) {
                same_cell += 1;
                assert!(max_difference < 1e-14, "x={x} r={r}: {max_difference}");
            } else {
                straddling += 1;
                // the vertex at distance d from the centre: the trapezoid underestimates its
                // weight by (r^2 - d^2) / (2 r h), and overestimates each neighbour by half that
                let vertex = (t(x + r)) * h + g.axes[0].lower;
                let d = (x - vertex).abs();
                let expected = (r * r - d * d) / (2.0 * r * h);
                assert!(
                    (max_difference - expected).abs() < 1e-12,
                    "x={x} r={r}: {max_difference} vs {expected}"
                );
            }
        }
        assert!(same_cell > 100 && straddling > 100);
    }

    /// For a diagonal F the 2D/3D weights are products of the 1D CPDI weights.
    fn check_tensor<const D: usize>(grid: &GridBasis<D>, seed: u64) {
        let mut rng = Lcg::new(seed);
        for _ in 0..100 {
            let (x, vectors) = loop {
                let (x, v) = random_domain(grid, &mut rng);
                let diagonal = SMatrix::from_diagonal(&v.diagonal().map(f64::abs));
                let (x, v) = (x, diagonal);
                let inside = (0..D).all(|k| {
                    x[k] - v[(k, k)] >= grid.axes[k].lower && x[k] + v[(k, k)] <= grid.axes[k].upper
                });
                if inside {
                    break (x, v);
                }
            };
            let out = eval(grid, &x, &vectors);
            let axes: Vec<GridBasis<1>> = (0..D)
                .map(|k| GridBasis {
                    axes: [grid.axes[k]],
                })
                .collect();
            let one_d: Vec<Vec<NodeWeight<1>>> = (0..D)
                .map(|k| {
                    eval(
                        &axes[k],
                        &SVector::<f64, 1>::new(x[k]),
                        &SMatrix::<f64, 1, 1>::new(vectors[(k, k)]),
                    )
                })
                .collect();
            let lookup = |k: usize, i: usize| {
                let (value, gradient) = weight_of(&one_d[k], i);
                (value, gradient[0])
            };
            for index in 0..grid.num_nodes() {
                let multi = grid.node_multi_index(index);
                let value: f64 = (0..D).map(|k| lookup(k, multi[k]).0).product();
                let gradient = SVector::<f64, D>::from_fn(|j, _| {
                    (0..D)
                        .map(|k| {
                            let (v, d) = lookup(k, multi[k]);
                            if k == j { d } else { v }
                        })
                        .product()
                });
                let (v, g) = weight_of(&out, index);
                assert!((v - value).abs() < 1e-14);
                assert!((g - gradient).norm() < 1e-11, "{g:?} vs {gradient:?}");
            }
        }
    }

    #[test]
    fn diagonal_deformation_gives_tensor_products() {
        check_tensor(&grid([-1.0, 0.5], [2.0, 1.5], [5, 3]), 36);
        check_tensor(&grid([0.0, -1.0, 2.0], [1.0, 1.0, 2.5], [3, 4, 2]), 37);
    }

    #[test]
    fn corners_outside_the_grid() {
        let g = grid([0.0, 0.0], [2.0, 1.0], [4, 2]);
        let mut scratch = CpdiScratch::default();
        let mut out = Vec::new();
        // a domain ending on the boundary up to round-off is accepted
        let r = Matrix2::from_diagonal(&Vector2::new(0.125, 0.125));
        let x = Vector2::new(0.125 - 1e-17, 0.5);
        assert!(g.eval_cpdi(&x, &r, &mut scratch, &mut out).is_ok());
        let sum: f64 = out.iter().map(|w| w.value).sum();
        assert!((sum - 1.0).abs() < 1e-14);
        // an overhang within CORNER_TOLERANCE cells (a sheared domain against a roller face)
        // is projected onto the face: the weights are those of the clamped corners, still a
        // partition of unity with gradients summing to zero
        let sheared = Matrix2::new(0.125, 0.01, 0.0, 0.125);
        let x = Vector2::new(0.13, 0.5); // one corner at x = -0.005 (0.01 cells) ...
        g.eval_cpdi(&x, &sheared, &mut scratch, &mut out).unwrap();
        let sum: f64 = out.iter().map(|w| w.value).sum();
        let gradient: Vector2<f64> = out.iter().map(|w| w.gradient).sum();
        assert!(
            (sum - 1.0).abs() < 1e-14 && gradient.norm() < 1e-12,
            "{sum} {gradient}"
        );
        // ... and that corner is projected to x = 0: the node at (0, 0.5) gets the average of
        // its hat (1 − x/h)(1 − |y − 0.5|/h) over the corners, the outside one clamped
        let node = g.node_index([0, 1]);
        let mut expected = 0.0;
        for c in 0..4 {
            let s = Vector2::new(
                if c & 1 == 1 { 1.0 } else { -1.0 },
                if c & 2 == 2 { 1.0 } else { -1.0 },
            );
            let corner = x + sheared * s;
            expected +=
                (1.0 - corner.x.max(0.0) / 0.5) * (1.0 - (corner.y - 0.5).abs() / 0.5) / 4.0;
        }
        let (value, _) = weight_of(&out, node);
        assert!((value - expected).abs() < 1e-14, "{value} {expected}");
        // a real overhang is an error naming the corner
        let x = Vector2::new(0.05, 0.5); // a corner at x = −0.075 (0.15 cells)
        match g.eval_cpdi(&x, &r, &mut scratch, &mut out) {
            Err(DomainError::CornerOutside { corner, axis }) => {
                assert_eq!(axis, 0);
                assert!((corner[0] + 0.075).abs() < 1e-15, "{corner:?}");
            }
            other => panic!("{other:?}"),
        }
        assert!(out.is_empty());
        // the centre outside is reported as such
        let x = Vector2::new(2.5, 0.5);
        assert!(matches!(
            g.eval_cpdi(&x, &r, &mut scratch, &mut out),
            Err(DomainError::Outside(_))
        ));
        // singular vectors
        let x = Vector2::new(1.0, 0.5);
        let flat = Matrix2::new(0.1, 0.2, 0.05, 0.1);
        assert!(matches!(
            g.eval_cpdi(&x, &flat, &mut scratch, &mut out),
            Err(DomainError::Degenerate(_))
        ));
    }
}
