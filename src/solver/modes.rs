//! Zero-energy modes of the tangent: rigid motions of a body that nothing resists.
//!
//! A body that no support holds (no `fix`, `displace`, surface condition or spring acting on
//! it) can translate, and at zero stress rotate, without straining: the displacement of its
//! nodes `u = t` (a translation) or `u = W (X − c)` (an infinitesimal rotation about its centre,
//! `W` skew) is reproduced exactly by the basis (partition of unity; linear precision with the
//! nodes at the Greville abscissae), so `K u = 0` and the tangent is singular. A support
//! eliminates or stiffens some of the body's degrees of freedom, and `K u` then feels the
//! coupling to them. The test of a mode `u` restricted to the free degrees of freedom is
//!
//! ```text
//!   ‖K u‖₂ ≤ ε · max_i |K_ii| · ‖u‖₂,   ε = 1e-10
//! ```
//!
//! a held body gives `‖K u‖ ~ |K_ii|` (the coupling to one constrained node is of the order of
//! a diagonal entry) and a free one round-off, `~1e-16 |K_ii| √n`: far from ε on both sides.

use nalgebra::{DMatrix, SVector};

use super::{NO_DOF, SparseMatrix};

/// The relative size of `K u` below which `u` is a zero-energy mode (see the module docs).
pub const ZERO_ENERGY_TOLERANCE: f64 = 1e-10;

/// A rigid motion of a set of nodes, over the matrix's degrees of freedom.
#[derive(Clone, Debug, PartialEq)]
pub struct RigidMode {
    /// "moving along x", "rotating in the x-y plane".
    pub name: String,
    pub values: Vec<f64>,
}

const AXES: [&str; 3] = ["x", "y", "z"];

/// The rigid motions of `nodes` (translations along each axis and, with `rotations`, the
/// rotations in each coordinate plane about their centre) over the free degrees of freedom
/// `dofs` (node → dof per component, [`NO_DOF`] if constrained) of a system of `size` unknowns.
/// A motion that touches no free degree of freedom is left out.
pub fn rigid_modes<const D: usize>(
    nodes: &[usize],
    position: &dyn Fn(usize) -> SVector<f64, D>,
    dofs: &impl std::ops::Index<usize, Output = [u32; D]>,
    size: usize,
    rotations: bool,
) -> Vec<RigidMode> {
    let mut modes = Vec::new();
    let mut push = |name: String, value: &dyn Fn(usize, usize) -> f64| {
        let mut values = vec![0.0; size];
        let mut touched = false;
        for &node in nodes {
            for (c, &dof) in dofs[node].iter().enumerate() {
                if dof != NO_DOF {
                    values[dof as usize] = value(node, c);
                    touched = true;
                }
            }
        }
        if touched {
            modes.push(RigidMode { name, values });
        }
    };
    for (axis, name) in AXES.iter().enumerate().take(D) {
        push(format!("moving along {name}"), &|_, c| {
            if c == axis { 1.0 } else { 0.0 }
        });
    }
    if rotations && !nodes.is_empty() {
        let centre =
            nodes.iter().map(|&n| position(n)).sum::<SVector<f64, D>>() / nodes.len() as f64;
        for a in 0..D {
            for b in a + 1..D {
                push(
                    format!("rotating in the {}-{} plane", AXES[a], AXES[b]),
                    &|node, c| {
                        let r = position(node) - centre;
                        match c {
                            _ if c == a => -r[b],
                            _ if c == b => r[a],
                            _ => 0.0,
                        }
                    },
                );
            }
        }
    }
    modes
}

/// Whether `u` is a zero-energy mode of `matrix` (see the module docs).
pub fn is_zero_energy(matrix: &SparseMatrix, u: &[f64]) -> bool {
    let (product, diagonal) = product_and_diagonal(matrix, u);
    let scale = diagonal * norm(u);
    scale > 0.0 && norm(&product) <= ZERO_ENERGY_TOLERANCE * scale
}

/// Whether some combination `u = Σ a_i m_i` of the `modes` is a zero-energy mode, although
/// none of them alone may be (a body pinned at one node rotates about that node, not about its
/// centre): with `Q` an orthonormal basis of the modes' span (from the SVD of the modes, so
/// that modes dependent over the free degrees of freedom count once), the smallest singular
/// value of `K Q` against the tolerance of the module docs. (Not the eigenvalues of
/// `(KM)ᵀ(KM)`: squaring the condition number would hide the round-off level.)
pub fn span_has_zero_energy(matrix: &SparseMatrix, modes: &[RigidMode]) -> bool {
    if modes.is_empty() || matrix.size() == 0 {
        return false;
    }
    let n = matrix.size();
    let basis = DMatrix::from_fn(n, modes.len(), |i, j| modes[j].values[i]).svd(true, false);
    let Some(u) = basis.u else {
        return false;
    };
    let largest = basis.singular_values.max();
    let mut diagonal: f64 = 0.0;
    let mut columns = Vec::new();
    for (j, &sigma) in basis.singular_values.iter().enumerate() {
        if sigma <= 1e-10 * largest {
            continue;
        }
        let q: Vec<f64> = u.column(j).iter().copied().collect();
        let (product, d) = product_and_diagonal(matrix, &q);
        diagonal = diagonal.max(d);
        columns.push(product);
    }
    if columns.is_empty() || diagonal == 0.0 {
        return false;
    }
    let images = DMatrix::from_fn(n, columns.len(), |i, j| columns[j][i]);
    let smallest = images.singular_values().min();
    smallest <= ZERO_ENERGY_TOLERANCE * diagonal
}

/// `K u` and the largest diagonal entry of `K` in magnitude.
fn product_and_diagonal(matrix: &SparseMatrix, u: &[f64]) -> (Vec<f64>, f64) {
    let (col_ptr, row_idx) = matrix.pattern();
    let values = matrix.values();
    let mut product = vec![0.0; matrix.size()];
    let mut diagonal: f64 = 0.0;
    for col in 0..matrix.size() {
        for k in col_ptr[col]..col_ptr[col + 1] {
            let row = row_idx[k];
            product[row] += values[k] * u[col];
            if row == col {
                diagonal = diagonal.max(values[k].abs());
            }
        }
    }
    (product, diagonal)
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 1D linear elements (nodes 0, 1, 2; unit stiffness): K = [1 -1 0; -1 2 -1; 0 -1 1].
    fn chain(fixed: Option<usize>) -> (SparseMatrix, Vec<[u32; 1]>) {
        let mut dofs = Vec::new();
        let mut next = 0;
        for node in 0..3 {
            if Some(node) == fixed {
                dofs.push([NO_DOF]);
            } else {
                dofs.push([next]);
                next += 1;
            }
        }
        let supports: [&[usize]; 2] = [&[0, 1], &[1, 2]];
        let mut matrix = SparseMatrix::default();
        matrix.rebuild_pattern(next as usize, &dofs[..], supports.into_iter());
        for (a, b) in [(0, 1), (1, 2)] {
            for (i, j, k) in [(a, a, 1.0), (a, b, -1.0), (b, a, -1.0), (b, b, 1.0)] {
                let (di, dj) = (dofs[i][0], dofs[j][0]);
                if di != NO_DOF && dj != NO_DOF {
                    matrix.add(di, dj, k);
                }
            }
        }
        (matrix, dofs)
    }

    #[test]
    fn a_free_chain_translates_and_a_fixed_one_does_not() {
        let position = |n: usize| SVector::<f64, 1>::new(n as f64);
        let (free, dofs) = chain(None);
        let modes = rigid_modes(&[0, 1, 2], &position, &dofs, free.size(), true);
        assert_eq!(modes.len(), 1, "1D has no rotation");
        assert_eq!(modes[0].name, "moving along x");
        assert!(is_zero_energy(&free, &modes[0].values));
        // a stretch is not a zero-energy mode
        assert!(!is_zero_energy(&free, &[0.0, 1.0, 2.0]));
        assert!(span_has_zero_energy(&free, &modes));
        let (held, dofs) = chain(Some(0));
        let modes = rigid_modes(&[0, 1, 2], &position, &dofs, held.size(), true);
        assert!(!is_zero_energy(&held, &modes[0].values));
        assert!(!span_has_zero_energy(&held, &modes));
    }

    /// Two 2D bars (axial springs) from a pinned node 0 at the origin: node 1 at (1, 0) held
    /// along x, node 2 at (0, 1) held along y. Neither a translation nor the rotation about the
    /// centre is free, but the rotation about the pin moves both nodes across their bars and
    /// costs nothing.
    #[test]
    fn a_body_pinned_at_one_node_rotates_about_it() {
        let position = |n: usize| match n {
            0 => SVector::<f64, 2>::new(0.0, 0.0),
            1 => SVector::<f64, 2>::new(1.0, 0.0),
            _ => SVector::<f64, 2>::new(0.0, 1.0),
        };
        let dofs: Vec<[u32; 2]> = vec![[NO_DOF, NO_DOF], [0, 1], [2, 3]];
        let supports: [&[usize]; 2] = [&[0, 1], &[0, 2]];
        let mut matrix = SparseMatrix::default();
        matrix.rebuild_pattern(4, &dofs[..], supports.into_iter());
        matrix.add(0, 0, 1.0); // bar 0-1 resists x at node 1
        matrix.add(3, 3, 1.0); // bar 0-2 resists y at node 2
        let modes = rigid_modes(&[0, 1, 2], &position, &dofs, 4, true);
        assert!(modes.iter().all(|m| !is_zero_energy(&matrix, &m.values)));
        assert!(span_has_zero_energy(&matrix, &modes));
        // a spring on node 1 along y stops it
        matrix.add(1, 1, 1.0);
        assert!(!span_has_zero_energy(&matrix, &modes));
    }

    #[test]
    fn rotations_are_about_the_centre_in_each_plane() {
        let position = |n: usize| SVector::<f64, 3>::new(n as f64, 0.0, 2.0 * n as f64);
        let dofs: Vec<[u32; 3]> = (0..2).map(|n| [3 * n, 3 * n + 1, 3 * n + 2]).collect();
        let modes = rigid_modes(&[0, 1], &position, &dofs, 6, true);
        let names: Vec<&str> = modes.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "moving along x",
                "moving along y",
                "moving along z",
                "rotating in the x-y plane",
                "rotating in the x-z plane",
                "rotating in the y-z plane"
            ]
        );
        // x-z rotation about the centre (0.5, 0, 1): node 0 at r = (-0.5, 0, -1) moves
        // (-r_z, 0, r_x) = (1, 0, -0.5)
        assert_eq!(modes[4].values[..3], [1.0, 0.0, -0.5]);
    }
}
