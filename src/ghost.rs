//! Ghost-penalty stabilisation of nearly empty cells (pure kernels).
//!
//! # The problem
//! A basis function whose support holds only a sliver of material — a body edge just past a
//! grid line, or points drifting into the corner of a cell — contributes a tiny, nearly
//! singular stiffness: for a B-spline of order q cut at distance δ from its knot, the
//! stiffness scales like δ^{2q-1}. Its control value is then set by round-off (the solve still
//! "converges", but nodal fields are garbage and the tangent may lose definiteness).
//!
//! # The remedy (Burman 2010; Coombs 2023 for implicit MPM)
//! On every interior face F between two cells that hold material, where at least one of them
//! is a boundary cell (a neighbour across some face is empty, or it is less than half full),
//! the jump of the q-th normal derivative of the displacement increment is penalised:
//!
//! ```text
//!   G(Δu, w) = Σ_F  γ E h_n^{2q-1} ∫_F [[∂_n^q Δu]] · [[∂_n^q w]] dΓ
//! ```
//!
//! B-splines of order q are C^{q-1}, so only the q-th derivative can jump; a displacement that
//! is one polynomial across F has no jump, which makes the penalty weakly consistent (it does
//! not spoil the convergence rate). The term ties the sliver's function to its well-supported
//! neighbours — the sliver node follows the smooth extension of the field — and bounds the
//! condition number independently of the cut. γ is dimensionless (`solver(#{ ghost_penalty })`),
//! E is the largest Young's modulus of the scene, h_n the cell size normal to F; the scaling
//! h^{2q-1} makes G scale like the bulk stiffness in every dimension.
//!
//! G is linear in Δu and added to the internal force (G Δu) and the tangent (G), so Newton
//! stays exact and K stays symmetric.
//!
//! # Evaluation
//! For a tensor-product function N_I = N_{i_n}(x_n) Π_t N_{i_t}(x_t), the jump across a face
//! normal to axis n is J_{i_n} Π_t N_{i_t}, with J the difference of the (cell-wise constant)
//! q-th derivatives in the two cells. The face integral separates:
//!
//! ```text
//!   G_IJ = γ E h_n^{2q-1} J_{i_n} J_{j_n} Π_t M^t_{i_t j_t},   M^t = ∫_cell N_i N_j dx_t,
//! ```
//!
//! with the one-cell mass matrices M^t integrated exactly by (q+1)-point Gauss-Legendre.

use crate::basis::bspline::{bspline_span, open_uniform_knot};
use crate::basis::{Axis, GridBasis};
use crate::quadrature::gauss_legendre_unit;

/// d^k N_i^p / dt^k at `t` (knot units) on the open uniform knot vector, by recursion on the
/// order: N^(k)_{i,p} = p (N^(k-1)_{i,p-1} / (ξ_{i+p} − ξ_i) − N^(k-1)_{i+1,p-1} / (ξ_{i+p+1} − ξ_{i+1})),
/// with 0/0 := 0. `t` must not sit on a knot (the functions are evaluated inside cells).
pub fn bspline_derivative(i: usize, p: usize, k: usize, t: f64, order: usize, cells: usize) -> f64 {
    let knot = |j: usize| open_uniform_knot(j, order, cells);
    let ratio = |a: f64, b: f64| if b == 0.0 { 0.0 } else { a / b };
    if k == 0 {
        if p == 0 {
            return if knot(i) <= t && t < knot(i + 1) {
                1.0
            } else {
                0.0
            };
        }
        return ratio(t - knot(i), knot(i + p) - knot(i))
            * bspline_derivative(i, p - 1, 0, t, order, cells)
            + ratio(knot(i + p + 1) - t, knot(i + p + 1) - knot(i + 1))
                * bspline_derivative(i + 1, p - 1, 0, t, order, cells);
    }
    if p == 0 {
        return 0.0;
    }
    p as f64
        * (ratio(
            bspline_derivative(i, p - 1, k - 1, t, order, cells),
            knot(i + p) - knot(i),
        ) - ratio(
            bspline_derivative(i + 1, p - 1, k - 1, t, order, cells),
            knot(i + p + 1) - knot(i + 1),
        ))
}

/// Jumps of the q-th derivative (physical units) of the q + 2 functions `first..first+q+1`,
/// `first = left_cell`, across the knot between `left_cell` and `left_cell + 1` of `axis`
/// (right-cell value minus left-cell value).
pub fn normal_derivative_jumps(axis: &Axis, left_cell: usize) -> Vec<f64> {
    let (q, cells) = (axis.order(), axis.cells);
    let h = axis.spacing();
    let (t_left, t_right) = (left_cell as f64 + 0.5, left_cell as f64 + 1.5);
    (left_cell..=left_cell + q + 1)
        .map(|i| {
            let d = |t: f64| bspline_derivative(i, q, q, t, q, cells);
            (d(t_right) - d(t_left)) / h.powi(q as i32)
        })
        .collect()
}

/// Mass matrix M_ij = ∫_cell N_i N_j dx of the q + 1 functions of `cell` on `axis`.
pub fn cell_mass_matrix(axis: &Axis, cell: usize) -> Vec<Vec<f64>> {
    let q = axis.order();
    let h = axis.spacing();
    let mut values = vec![0.0; q + 1];
    let mut derivatives = vec![0.0; q + 1];
    let mut m = vec![vec![0.0; q + 1]; q + 1];
    for (s, w) in gauss_legendre_unit(q + 1) {
        bspline_span(
            q,
            axis.cells,
            cell,
            cell as f64 + s,
            &mut values,
            &mut derivatives,
        );
        for i in 0..=q {
            for j in 0..=q {
                m[i][j] += w * h * values[i] * values[j];
            }
        }
    }
    m
}

/// A face between two cells: normal `axis`, the multi-index of the cell on its lower side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Face<const D: usize> {
    pub axis: usize,
    pub lower_cell: [usize; D],
}

/// The penalty of one face: the nodes of its stencil and the symmetric matrix G (row-major,
/// `nodes.len()` squared), to be applied to every displacement component.
#[derive(Clone, Debug, PartialEq)]
pub struct FacePenalty {
    pub nodes: Vec<usize>,
    pub matrix: Vec<f64>,
}

/// G of `face` with the factor γ E (module docs).
pub fn face_penalty<const D: usize>(
    basis: &GridBasis<D>,
    face: &Face<D>,
    gamma_modulus: f64,
) -> FacePenalty {
    let n = face.axis;
    let normal_axis = &basis.axes[n];
    let q = normal_axis.order();
    let jumps = normal_derivative_jumps(normal_axis, face.lower_cell[n]);
    let scale = gamma_modulus * normal_axis.spacing().powi(2 * q as i32 - 1);
    // Per axis: first function index and the factor matrix between local functions.
    let factors: Vec<(usize, Vec<Vec<f64>>)> = (0..D)
        .map(|a| {
            if a == n {
                let m = jumps
                    .iter()
                    .map(|&ji| jumps.iter().map(|&jj| scale * ji * jj).collect())
                    .collect();
                (face.lower_cell[a], m)
            } else {
                (
                    face.lower_cell[a],
                    cell_mass_matrix(&basis.axes[a], face.lower_cell[a]),
                )
            }
        })
        .collect();
    let counts: Vec<usize> = factors.iter().map(|(_, m)| m.len()).collect();
    let total: usize = counts.iter().product();
    let local = |mut k: usize| -> [usize; D] {
        std::array::from_fn(|a| {
            let i = k % counts[a];
            k /= counts[a];
            i
        })
    };
    let nodes: Vec<usize> = (0..total)
        .map(|k| {
            let l = local(k);
            basis.node_index(std::array::from_fn(|a| factors[a].0 + l[a]))
        })
        .collect();
    let mut matrix = vec![0.0; total * total];
    for r in 0..total {
        let lr = local(r);
        for c in 0..total {
            let lc = local(c);
            matrix[r * total + c] = (0..D).map(|a| factors[a].1[lr[a]][lc[a]]).product();
        }
    }
    FacePenalty { nodes, matrix }
}

/// The faces to stabilise, from the cells that hold material (`filled[cell]` = fraction of
/// the cell's volume the points occupy, 0 for an empty cell): faces between two occupied cells
/// of which at least one is a boundary cell — with an empty face-neighbour inside the grid, or
/// less than half full.
pub fn ghost_faces<const D: usize>(basis: &GridBasis<D>, filled: &[f64]) -> Vec<Face<D>> {
    let cells = basis.cells_per_axis();
    let occupied = |c: usize| filled[c] > 0.0;
    let neighbour = |m: [usize; D], a: usize, up: bool| -> Option<usize> {
        let mut n = m;
        if up {
            if m[a] + 1 >= cells[a] {
                return None;
            }
            n[a] += 1;
        } else {
            if m[a] == 0 {
                return None;
            }
            n[a] -= 1;
        }
        Some(basis.cell_index(n))
    };
    let boundary = |c: usize| {
        let m = basis.cell_multi_index(c);
        filled[c] < 0.5
            || (0..D).any(|a| {
                [false, true]
                    .iter()
                    .any(|&up| neighbour(m, a, up).is_some_and(|n| !occupied(n)))
            })
    };
    let mut faces = Vec::new();
    for c in 0..basis.num_cells() {
        if !occupied(c) {
            continue;
        }
        let m = basis.cell_multi_index(c);
        for a in 0..D {
            if let Some(n) = neighbour(m, a, true)
                && occupied(n)
                && (boundary(c) || boundary(n))
            {
                faces.push(Face {
                    axis: a,
                    lower_cell: m,
                });
            }
        }
    }
    faces
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::BasisKind;

    fn axis(order: usize, cells: usize) -> Axis {
        Axis::new(0.0, cells as f64 * 0.5, cells, BasisKind::BSpline { order }).unwrap()
    }

    #[test]
    fn recursive_values_match_the_span_kernel() {
        for q in 1..=4 {
            let cells = 6;
            let mut v = vec![0.0; q + 1];
            let mut d = vec![0.0; q + 1];
            for cell in 0..cells {
                let t = cell as f64 + 0.3;
                bspline_span(q, cells, cell, t, &mut v, &mut d);
                for j in 0..=q {
                    let value = bspline_derivative(cell + j, q, 0, t, q, cells);
                    let slope = bspline_derivative(cell + j, q, 1, t, q, cells);
                    assert!((value - v[j]).abs() < 1e-13 && (slope - d[j]).abs() < 1e-12);
                }
            }
        }
    }

    #[test]
    fn jumps_annihilate_polynomials_of_order_q() {
        // Σ_i J_i X_i^k = 0 for k <= q: the jump of the q-th derivative of a polynomial of
        // degree <= q represented in the spline space is zero (weak consistency). Greville
        // abscissae reproduce linear fields; for k = 0 this is partition of unity.
        for q in 1..=4 {
            let a = axis(q, 8);
            for left in 0..7 {
                let jumps = normal_derivative_jumps(&a, left);
                let sum: f64 = jumps.iter().sum();
                let first: f64 = jumps
                    .iter()
                    .enumerate()
                    .map(|(k, j)| j * a.control_point(left + k))
                    .sum();
                let scale = jumps.iter().fold(0.0f64, |m, j| m.max(j.abs()));
                assert!(sum.abs() < 1e-9 * scale, "q={q} left={left}: Σ J = {sum}");
                assert!(
                    first.abs() < 1e-9 * scale,
                    "q={q} left={left}: Σ J X = {first}"
                );
                assert!(scale > 0.0);
            }
        }
    }

    #[test]
    fn cubic_jump_of_the_cut_function_is_one_over_h_cubed() {
        // The first function of the right cell, N_{k+q+1}, is t^q/q! there and zero on the
        // left: its q-th derivative jumps by 1/h^q.
        let a = axis(3, 8);
        let jumps = normal_derivative_jumps(&a, 4);
        assert!((jumps[4] - 1.0 / 0.5f64.powi(3)).abs() < 1e-9, "{jumps:?}");
    }

    #[test]
    fn face_penalty_is_symmetric_positive_semidefinite_and_zero_on_linear_fields() {
        let basis = GridBasis::<2>::new(
            &[0.0, 0.0],
            &[3.0, 2.0],
            &[6, 4],
            BasisKind::BSpline { order: 2 },
        )
        .unwrap();
        let face = Face {
            axis: 1,
            lower_cell: [2, 1],
        };
        let g = face_penalty(&basis, &face, 10.0);
        let n = g.nodes.len();
        assert_eq!(n, 3 * 4);
        for r in 0..n {
            for c in 0..n {
                assert!((g.matrix[r * n + c] - g.matrix[c * n + r]).abs() < 1e-12);
            }
        }
        // a linear field u = 1 + 2x - 3y at the nodes gives no jump
        let u: Vec<f64> = g
            .nodes
            .iter()
            .map(|&i| {
                let x = basis.node_position(i);
                1.0 + 2.0 * x[0] - 3.0 * x[1]
            })
            .collect();
        let energy: f64 = (0..n)
            .map(|r| {
                (0..n)
                    .map(|c| u[r] * g.matrix[r * n + c] * u[c])
                    .sum::<f64>()
            })
            .sum();
        assert!(energy.abs() < 1e-10, "{energy}");
        // a field with a kink has positive energy
        let v: Vec<f64> = (0..n).map(|k| if k % 4 == 3 { 1.0 } else { 0.0 }).collect();
        let energy: f64 = (0..n)
            .map(|r| {
                (0..n)
                    .map(|c| v[r] * g.matrix[r * n + c] * v[c])
                    .sum::<f64>()
            })
            .sum();
        assert!(energy > 0.0);
    }

    #[test]
    fn faces_are_found_next_to_boundary_cells_only() {
        let basis =
            GridBasis::<1>::new(&[0.0], &[6.0], &[6], BasisKind::BSpline { order: 2 }).unwrap();
        // cells 0..4 full, cell 4 a sliver, cell 5 empty
        let filled = [1.0, 1.0, 1.0, 1.0, 0.001, 0.0];
        let faces = ghost_faces(&basis, &filled);
        let lower: Vec<usize> = faces.iter().map(|f| f.lower_cell[0]).collect();
        // face 3|4 (4 is a boundary cell); no face 4|5 (5 empty); 0..3 interior full cells
        assert_eq!(lower, vec![3]);
    }
}
