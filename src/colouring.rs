//! Colouring of material points for a threaded assembly that adds into one tangent.
//!
//! Two points whose supports share no node add to disjoint entries of the internal force and of
//! the tangent (K_ij couples the DOFs of nodes i and j of one support). The points are put into
//! **blocks** (here: the points whose supports have the same lowest corner, i.e. the points of
//! one background cell for a B-spline or linear basis) and the blocks into **colours** such
//! that two blocks of one colour share no node; the threads then work on the blocks of one
//! colour at a time, each block on one thread, adding straight into the shared arrays.
//!
//! The spacing is taken from the supports themselves, not from the basis' order. Node `n` has
//! the multi-index `m(n)` of the grid's node numbering (axis 0 fastest; the last axis is left
//! unbounded, so any index has one). A point's support `S_p` lies in the box
//! `[a_p, a_p + e_p - 1]` with the corner `a_{p,k} = min_{n ∈ S_p} m_k(n)` and the extent
//! `e_{p,k} = max_{n ∈ S_p} m_k(n) - a_{p,k} + 1`. With the widths `w_k = max_p e_{p,k}`:
//!
//! * block of p: its corner `a_p`;
//! * colour of p: `c_p = Σ_k (a_{p,k} mod w_k) Π_{l<k} w_l`, one of `C = Π_k w_k` colours.
//!
//! Two points of one colour with different corners differ in some axis k by a non-zero multiple
//! of `w_k`, so their boxes (of width at most `w_k`) do not overlap along k, and their supports
//! share no node. A B-spline basis of order q gives `w_k = q + 1`, `(q + 1)^D` colours; linear
//! 2 per axis; GIMP's and CPDI's wider supports give what their widths are. A support that is
//! not compact in the grid's numbering (an FEM mesh's nodes, numbered their own way) gives wide
//! boxes and many colours: above [`MAX_COLOURS`] there is no colouring ([`colour_points`]
//! returns `None`) and the assembly falls back to a copy of the sums per thread.
//!
//! The order is fixed by the points alone: colour by colour, block by block (increasing corner),
//! and within a block the points in their given order. So every entry of the sums receives its
//! terms in an order that does not depend on the number of threads.

use rayon::prelude::*;

/// Most colours a colouring may have (8 per axis in 3D): beyond it the blocks of a colour
/// are too few to share among threads, and the points' supports are not compact.
pub const MAX_COLOURS: usize = 512;

/// The points in colour order, cut into blocks and colours.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Colouring {
    /// Point indices (into the caller's points) by colour, then block, then given order.
    pub order: Vec<u32>,
    /// The points of block `b` are `order[block_start[b]..block_start[b + 1]]`.
    pub block_start: Vec<usize>,
    /// The blocks of colour `c` are `colour_start[c]..colour_start[c + 1]` (possibly empty).
    pub colour_start: Vec<usize>,
    /// The widths `w_k` (nodes per axis spanned by the widest support).
    pub widths: Vec<usize>,
}

impl Colouring {
    /// Number of colours.
    pub fn colours(&self) -> usize {
        self.colour_start.len().saturating_sub(1)
    }

    /// The blocks of colour `c`, as positions into `order`: `block_start[first]..`, one range
    /// of points per block.
    pub fn blocks_of(&self, c: usize) -> &[usize] {
        &self.block_start[self.colour_start[c]..=self.colour_start[c + 1]]
    }
}

/// The multi-index of node `index` in a grid of `sizes` nodes per axis (axis 0 fastest), the
/// last axis unbounded.
#[inline]
fn multi_index<const D: usize>(sizes: &[usize; D], mut index: usize) -> [usize; D] {
    let mut multi = [0; D];
    for k in 0..D {
        if k + 1 == D {
            multi[k] = index;
        } else {
            multi[k] = index % sizes[k];
            index /= sizes[k];
        }
    }
    multi
}

/// The corner `a_p` and extents `e_p` of a support (module docs); zero extents when empty.
fn support_box<const D: usize>(
    sizes: &[usize; D],
    nodes: impl Iterator<Item = usize>,
) -> ([usize; D], [usize; D]) {
    let mut lo = [usize::MAX; D];
    let mut hi = [0; D];
    let mut any = false;
    for node in nodes {
        any = true;
        let m = multi_index(sizes, node);
        for k in 0..D {
            lo[k] = lo[k].min(m[k]);
            hi[k] = hi[k].max(m[k]);
        }
    }
    if !any {
        return ([0; D], [0; D]);
    }
    (lo, std::array::from_fn(|k| hi[k] - lo[k] + 1))
}

/// Colours `n` points whose supports are `nodes_of(p)` (node indices of a grid with `sizes`
/// nodes per axis), as the module docs say; `None` when it takes more than [`MAX_COLOURS`]
/// colours or a corner does not fit the sort key (no colouring: the caller falls back).
///
/// `same_as_previous(p)` may say that point `p` has the support of point `p - 1` (the points of
/// a cell), which saves decomposing its nodes again; it must be exact.
pub fn colour_points<const D: usize, I: Iterator<Item = usize>>(
    sizes: [usize; D],
    n: usize,
    nodes_of: impl Fn(usize) -> I,
    same_as_previous: impl Fn(usize) -> bool,
) -> Option<Colouring> {
    if n > u32::MAX as usize || sizes.contains(&0) {
        return None;
    }
    let mut boxes: Vec<([usize; D], [usize; D])> = Vec::with_capacity(n);
    for p in 0..n {
        match boxes.last() {
            Some(&previous) if same_as_previous(p) => boxes.push(previous),
            _ => boxes.push(support_box(&sizes, nodes_of(p))),
        }
    }
    let widths: [usize; D] =
        std::array::from_fn(|k| boxes.iter().map(|(_, e)| e[k]).max().unwrap_or(1).max(1));
    let colours = widths
        .iter()
        .try_fold(1usize, |c, &w| c.checked_mul(w))
        .filter(|&c| c <= MAX_COLOURS)?;
    // The sort key: colour, then the corner's flat index, then the point (unique keys, so the
    // unstable sort gives one order).
    let mut strides = [1usize; D];
    for k in 1..D {
        strides[k] = strides[k - 1].checked_mul(sizes[k - 1])?;
    }
    let mut keys = Vec::with_capacity(n);
    for (p, (corner, _)) in boxes.iter().enumerate() {
        let mut flat = 0usize;
        let mut colour = 0usize;
        for k in (0..D).rev() {
            flat = flat.checked_add(corner[k].checked_mul(strides[k])?)?;
            colour = colour * widths[k] + corner[k] % widths[k];
        }
        // 32 bits of point, 64 of corner, 32 of colour (colour < MAX_COLOURS).
        let flat = u64::try_from(flat).ok()?;
        keys.push(((colour as u128) << 96) | (u128::from(flat) << 32) | p as u128);
    }
    drop(boxes);
    keys.par_sort_unstable();

    let mut order = Vec::with_capacity(n);
    let mut block_start = Vec::new();
    let mut colour_start = vec![0; colours + 1];
    let mut previous: Option<u128> = None;
    for (position, key) in keys.iter().enumerate() {
        let block = key >> 32;
        if previous != Some(block) {
            block_start.push(position);
            colour_start[(key >> 96) as usize + 1] += 1;
            previous = Some(block);
        }
        order.push(*key as u32);
    }
    block_start.push(n);
    for c in 0..colours {
        colour_start[c + 1] += colour_start[c];
    }
    Some(Colouring {
        order,
        block_start,
        colour_start,
        widths: widths.to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The nodes of a B-spline support of order `q` in a grid of `sizes` nodes: the box of
    /// `q + 1` nodes per axis from `corner`.
    fn box_nodes(sizes: [usize; 2], corner: [usize; 2], q: usize) -> Vec<usize> {
        let mut nodes = Vec::new();
        for j in 0..=q {
            for i in 0..=q {
                nodes.push(corner[0] + i + sizes[0] * (corner[1] + j));
            }
        }
        nodes
    }

    /// Every colour's blocks have pairwise disjoint node sets, every point appears once, and
    /// the points of a block keep their given order.
    fn assert_valid(colouring: &Colouring, supports: &[Vec<usize>]) {
        let mut seen = vec![false; supports.len()];
        for &p in &colouring.order {
            assert!(!seen[p as usize], "point {p} twice");
            seen[p as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
        for c in 0..colouring.colours() {
            let blocks = colouring.blocks_of(c);
            let mut owner = std::collections::HashMap::new();
            for (b, w) in blocks.windows(2).enumerate() {
                let points = &colouring.order[w[0]..w[1]];
                assert!(points.windows(2).all(|p| p[0] < p[1]), "block order");
                for &p in points {
                    for &node in &supports[p as usize] {
                        let first = *owner.entry(node).or_insert(b);
                        assert_eq!(first, b, "colour {c}: node {node} in two blocks");
                    }
                }
            }
        }
    }

    #[test]
    fn b_spline_supports_take_q_plus_one_colours_per_axis_with_disjoint_blocks() {
        for q in 1..=3 {
            let cells = [7, 5];
            let sizes = [cells[0] + q, cells[1] + q];
            // Two points per cell, cells visited in a scrambled order.
            let mut supports = Vec::new();
            for k in 0..cells[0] * cells[1] {
                let cell = (k * 17) % (cells[0] * cells[1]);
                let corner = [cell % cells[0], cell / cells[0]];
                supports.push(box_nodes(sizes, corner, q));
                supports.push(box_nodes(sizes, corner, q));
            }
            let colouring = colour_points(
                sizes,
                supports.len(),
                |p| supports[p].iter().copied(),
                |p| supports[p] == supports[p - 1],
            )
            .unwrap();
            assert_eq!(colouring.widths, vec![q + 1, q + 1]);
            assert_eq!(colouring.colours(), (q + 1) * (q + 1));
            assert_eq!(colouring.block_start.len(), cells[0] * cells[1] + 1);
            assert_valid(&colouring, &supports);
        }
    }

    #[test]
    fn uneven_supports_take_the_widest_extent() {
        // GIMP-like: 2 or 3 nodes per axis, linear grid of 6 x 6 nodes.
        let sizes = [6, 6];
        let mut supports = Vec::new();
        for j in 0..4 {
            for i in 0..4 {
                let width = 2 + (i + j) % 2;
                let mut nodes = Vec::new();
                for b in 0..width {
                    for a in 0..width {
                        nodes.push(i + a + sizes[0] * (j + b));
                    }
                }
                supports.push(nodes);
            }
        }
        supports.push(Vec::new());
        let colouring = colour_points(
            sizes,
            supports.len(),
            |p| supports[p].iter().copied(),
            |_| false,
        )
        .unwrap();
        assert_eq!(colouring.widths, vec![3, 3]);
        assert_valid(&colouring, &supports);
    }

    #[test]
    fn supports_spread_over_the_numbering_are_not_coloured() {
        // Nodes far apart in the numbering (an unstructured mesh): too many colours.
        let sizes = [100, 100];
        let supports: Vec<Vec<usize>> = (0..50).map(|p| vec![p, p + 77, 5000 + p]).collect();
        assert!(
            colour_points(
                sizes,
                supports.len(),
                |p| supports[p].iter().copied(),
                |_| false
            )
            .is_none()
        );
    }

    #[test]
    fn node_indices_beyond_the_grid_fall_on_the_unbounded_last_axis() {
        assert_eq!(multi_index(&[4, 3], 4 * 3 * 2 + 5), [1, 7]);
        assert_eq!(multi_index(&[9], 40), [40]);
    }
}
