//! The isoparametric multilinear element: 2-node bar (D = 1), 4-node quadrilateral (D = 2),
//! 8-node hexahedron (D = 3), through one const-generic code path.
//!
//! # Corners and shape functions
//!
//! The parent element is `[-1, 1]^D`. Corner `a = b_0 + 2 b_1 + 4 b_2` (`b_k ∈ {0, 1}`, axis 0
//! fastest, the order of [`crate::basis::GridBasis::cell_vertices`]) sits at ξ_k = s_k with
//! `s_k = 2 b_k - 1`, and its shape function and parent gradient are
//!
//! ```text
//!   N_a(ξ) = Π_k (1 + s_k ξ_k) / 2,        ∂N_a/∂ξ_j = (s_j / 2) Π_{k≠j} (1 + s_k ξ_k) / 2.
//! ```
//!
//! # Isoparametric map
//!
//! With corner positions x_a, the element maps `x(ξ) = Σ_a N_a(ξ) x_a`, with Jacobian and
//! spatial gradients
//!
//! ```text
//!   J = ∂x/∂ξ = Σ_a x_a ⊗ ∇_ξ N_a,        ∇_x N_a = J⁻ᵀ ∇_ξ N_a,        dV = det J dξ.
//! ```
//!
//! An element is admissible at ξ when det J > 0 (corners in the order above, not inverted).

use nalgebra::{SMatrix, SVector};

use crate::basis::NodeWeight;
use crate::mechanics::{block, embed};

/// Number of corners (nodes) of the D-dimensional element: 2^D.
pub const fn corner_count(dim: usize) -> usize {
    1 << dim
}

/// Value and parent gradient ∇_ξ N_a of corner `corner`'s shape function at ξ.
#[inline]
pub fn shape_function<const D: usize>(
    corner: usize,
    xi: &SVector<f64, D>,
) -> (f64, SVector<f64, D>) {
    let factors: [f64; D] = std::array::from_fn(|k| 0.5 * (1.0 + sign(corner, k) * xi[k]));
    let value = factors.iter().product();
    let gradient = SVector::from_fn(|j, _| {
        let others: f64 = (0..D).filter(|&k| k != j).map(|k| factors[k]).product();
        0.5 * sign(corner, j) * others
    });
    (value, gradient)
}

/// s_k = ±1: the parent coordinate of corner `corner` along axis `k`.
#[inline]
fn sign(corner: usize, k: usize) -> f64 {
    if (corner >> k) & 1 == 1 { 1.0 } else { -1.0 }
}

/// x(ξ) = Σ_a N_a(ξ) x_a.
pub fn map_to_element<const D: usize>(
    corners: &[SVector<f64, D>],
    xi: &SVector<f64, D>,
) -> SVector<f64, D> {
    corners
        .iter()
        .enumerate()
        .fold(SVector::zeros(), |x, (a, xa)| {
            x + xa * shape_function(a, xi).0
        })
}

/// J = ∂x/∂ξ = Σ_a x_a ⊗ ∇_ξ N_a.
pub fn element_jacobian<const D: usize>(
    corners: &[SVector<f64, D>],
    xi: &SVector<f64, D>,
) -> SMatrix<f64, D, D> {
    corners
        .iter()
        .enumerate()
        .fold(SMatrix::zeros(), |j, (a, xa)| {
            j + xa * shape_function(a, xi).1.transpose()
        })
}

/// The element is inverted or degenerate at ξ: det J <= 0 or not finite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DegenerateElement {
    pub jacobian: f64,
}

impl std::fmt::Display for DegenerateElement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the element is inverted or degenerate (det J = {:e})",
            self.jacobian
        )
    }
}

impl std::error::Error for DegenerateElement {}

/// det J at ξ, checked to be positive and finite.
pub fn jacobian_determinant<const D: usize>(
    corners: &[SVector<f64, D>],
    xi: &SVector<f64, D>,
) -> Result<f64, DegenerateElement> {
    let det = embed(&element_jacobian(corners, xi)).determinant();
    if det.is_finite() && det > 0.0 {
        Ok(det)
    } else {
        Err(DegenerateElement { jacobian: det })
    }
}

/// The element's functions at ξ as a point support: clears `out` and pushes, for every corner
/// `a`, the node `nodes[a]`, the value N_a(ξ) and the spatial gradient J⁻ᵀ ∇_ξ N_a for the
/// corner positions `corners`. Returns det J.
pub fn element_weights<const D: usize>(
    nodes: &[usize],
    corners: &[SVector<f64, D>],
    xi: &SVector<f64, D>,
    out: &mut Vec<NodeWeight<D>>,
) -> Result<f64, DegenerateElement> {
    out.clear();
    let jacobian = element_jacobian(corners, xi);
    let det = embed(&jacobian).determinant();
    if !(det.is_finite() && det > 0.0) {
        return Err(DegenerateElement { jacobian: det });
    }
    let inverse_transpose: SMatrix<f64, D, D> = block(
        &embed(&jacobian)
            .try_inverse()
            .ok_or(DegenerateElement { jacobian: det })?
            .transpose(),
    );
    for (a, &node) in nodes.iter().enumerate() {
        let (value, parent_gradient) = shape_function(a, xi);
        out.push(NodeWeight {
            node,
            value,
            gradient: inverse_transpose * parent_gradient,
        });
    }
    Ok(det)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector1, Vector2, Vector3};

    /// Corners of the parent element mapped by x = A ξ + c plus a bilinear/trilinear
    /// distortion `d` (ξ_0 ξ_1 term), a = axis-0-fastest corner order.
    fn corners<const D: usize>(distortion: f64) -> Vec<SVector<f64, D>> {
        let a =
            SMatrix::<f64, D, D>::from_fn(|i, j| if i == j { 1.5 + 0.2 * i as f64 } else { 0.3 });
        (0..corner_count(D))
            .map(|corner| {
                let xi = SVector::<f64, D>::from_fn(|k, _| sign(corner, k));
                let bilinear = if D > 1 { xi[0] * xi[1] } else { 0.0 };
                a * xi
                    + SVector::from_fn(|k, _| 0.7 + k as f64)
                    + SVector::repeat(distortion * bilinear)
            })
            .collect()
    }

    fn sample_points<const D: usize>() -> Vec<SVector<f64, D>> {
        (0..7)
            .map(|s| SVector::from_fn(|k, _| ((s * 3 + k * 5) as f64 * 0.37).sin() * 0.9))
            .collect()
    }

    fn check_element<const D: usize>() {
        let x = corners::<D>(0.2);
        let nodes: Vec<usize> = (0..corner_count(D)).map(|a| 10 + 3 * a).collect();
        let mut out = Vec::new();
        for xi in sample_points::<D>() {
            let det = element_weights(&nodes, &x, &xi, &mut out).unwrap();
            assert_eq!(out.len(), corner_count(D));
            assert!(out.iter().zip(&nodes).all(|(w, &n)| w.node == n));
            // partition of unity, and linear completeness: Σ N_a x_a = x(ξ), Σ x_a ⊗ ∇N_a = I
            let sum: f64 = out.iter().map(|w| w.value).sum();
            assert!((sum - 1.0).abs() < 1e-14);
            let mapped = out
                .iter()
                .zip(&x)
                .fold(SVector::<f64, D>::zeros(), |s, (w, xa)| s + xa * w.value);
            assert!((mapped - map_to_element(&x, &xi)).norm() < 1e-13);
            let identity = out
                .iter()
                .zip(&x)
                .fold(SMatrix::<f64, D, D>::zeros(), |s, (w, xa)| {
                    s + xa * w.gradient.transpose()
                });
            assert!(
                (identity - SMatrix::<f64, D, D>::identity()).norm() < 1e-13,
                "{identity}"
            );
            // det J against central differences of the map
            let h = 1e-6;
            let fd = SMatrix::<f64, D, D>::from_fn(|i, k| {
                let e = SVector::<f64, D>::from_fn(|j, _| if j == k { h } else { 0.0 });
                (map_to_element(&x, &(xi + e))[i] - map_to_element(&x, &(xi - e))[i]) / (2.0 * h)
            });
            assert!((fd - element_jacobian(&x, &xi)).norm() < 1e-8);
            assert!((embed(&fd).determinant() - det).abs() < 1e-7 * det);
            // spatial gradient against differences along a physical direction: N_a(x + δ v)
            // with ξ(x + δ v) ≈ ξ + δ J⁻¹ v
            let jinv = block::<D>(&embed(&element_jacobian(&x, &xi)).try_inverse().unwrap());
            let v = SVector::<f64, D>::from_fn(|k, _| 0.3 + 0.1 * k as f64);
            for (a, w) in out.iter().enumerate() {
                let dxi = jinv * v * h;
                let fd = (shape_function(a, &(xi + dxi)).0 - shape_function(a, &(xi - dxi)).0)
                    / (2.0 * h);
                assert!((fd - w.gradient.dot(&v)).abs() < 1e-8, "corner {a}");
            }
        }
        // Kronecker property at the corners
        for b in 0..corner_count(D) {
            let xi = SVector::<f64, D>::from_fn(|k, _| sign(b, k));
            for a in 0..corner_count(D) {
                let expected = if a == b { 1.0 } else { 0.0 };
                assert_eq!(shape_function(a, &xi).0, expected);
            }
        }
    }

    #[test]
    fn bar_quad_and_hexahedron_are_complete_and_consistent() {
        check_element::<1>();
        check_element::<2>();
        check_element::<3>();
    }

    #[test]
    fn unit_cell_jacobians() {
        // A cell [2, 5] x [1, 2]: J = diag(3/2, 1/2) everywhere.
        let x = [
            Vector2::new(2.0, 1.0),
            Vector2::new(5.0, 1.0),
            Vector2::new(2.0, 2.0),
            Vector2::new(5.0, 2.0),
        ];
        let j = element_jacobian(&x, &Vector2::new(0.3, -0.8));
        assert!((j - nalgebra::Matrix2::new(1.5, 0.0, 0.0, 0.5)).norm() < 1e-15);
        let bar = [Vector1::new(1.0), Vector1::new(3.0)];
        assert_eq!(jacobian_determinant(&bar, &Vector1::new(0.4)), Ok(1.0));
        // A distorted quadrilateral's area is ∫ det J dξ, exact with 2x2 Gauss points.
        let quad = [
            Vector2::new(0.0, 0.0),
            Vector2::new(2.0, 0.0),
            Vector2::new(0.5, 1.0),
            Vector2::new(2.5, 3.0),
        ];
        let area: f64 = crate::fem::tensor_gauss_rule([2, 2])
            .iter()
            .map(|(xi, w)| w * jacobian_determinant(&quad, xi).unwrap())
            .sum();
        // shoelace formula, counter-clockwise order 0, 1, 3, 2
        let ccw = [quad[0], quad[1], quad[3], quad[2]];
        let shoelace: f64 = 0.5
            * (0..4)
                .map(|i| {
                    let (p, q) = (ccw[i], ccw[(i + 1) % 4]);
                    p.x * q.y - q.x * p.y
                })
                .sum::<f64>();
        assert!((area - shoelace).abs() < 1e-14, "{area} vs {shoelace}");
    }

    #[test]
    fn inverted_elements_are_errors() {
        let bar = [Vector1::new(3.0), Vector1::new(1.0)];
        let mut out = Vec::new();
        let e = element_weights(&[0, 1], &bar, &Vector1::new(0.0), &mut out).unwrap_err();
        assert_eq!(e.jacobian, -1.0);
        assert!(out.is_empty());
        let flat = [Vector3::zeros(); 8];
        assert!(jacobian_determinant(&flat, &Vector3::zeros()).is_err());
        assert!(e.to_string().contains("inverted"));
    }
}
