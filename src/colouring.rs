//! Colouring of material points for a threaded assembly that adds into one tangent.
//!
//! Two points whose supports share no node add to disjoint entries of the internal force and of
//! the tangent (K_ij couples the DOFs of nodes i and j of one support). The points are put into
//! **blocks** (slabs of background cells) and the blocks into two **colours** such that two
//! blocks of one colour share no node; the threads then work on the blocks of one colour at a
//! time, each block on one thread, adding straight into the shared arrays.
//!
//! The slabs are cut along one axis k, the one with the most nodes (the last, slowest in the
//! numbering, on a tie: its slabs are contiguous ranges of nodes). Node `n` has the index
//! `m_k(n) = ⌊n / s_k⌋ mod n_k` along it (`s_k` the stride of axis k in the grid's numbering,
//! axis 0 fastest; the last axis is left unbounded, so any index has one). A point's support
//! `S_p` spans `[a_p, b_p]` along k, `a_p = min_{n ∈ S_p} m_k(n)`, `b_p = max_{n ∈ S_p} m_k(n)`.
//! The spacing is taken from the supports themselves, not from the basis' order: with the
//! width `w = max_p (b_p − a_p + 1)` and the slab thickness `L = max(w − 1, 1)`:
//!
//! * block (slab) of p: `⌊a_p / L⌋`; colour of p: its slab's parity.
//!
//! Two slabs of one colour are `t ≥ 2` slabs apart: the support of a point of slab `t₀` ends at
//! `b ≤ a + w − 1 ≤ (t₀ + 1) L − 1 + w − 1 < (t₀ + 2) L` (as `L > w − 2`), where the other
//! slab's supports begin. So their supports share no node. A B-spline basis of order q gives
//! `w = q + 1`, linear 2, GIMP's and CPDI's wider supports what their widths are. Slabs keep the
//! cells of a slab in the grid's order, so the writes into the tangent move through memory as
//! in the plain loop (a finer colouring, cell by cell with `w^D` colours, made the assembly
//! twice as slow for the lost locality). A support that is not compact in the grid's numbering
//! (an FEM mesh's nodes, numbered their own way) gives a wide slab and few of them: below
//! [`MIN_SLABS`] there is no colouring ([`colour_points`] returns `None`) and the assembly falls
//! back to a copy of the sums per thread.
//!
//! The order is fixed by the points alone: colour by colour, slab by slab, within a slab by the
//! lowest node of the support (cell order) and then by the given order. So every entry of the
//! sums receives its terms in an order that does not depend on the number of threads.

use rayon::prelude::*;

/// Fewest slabs a colouring may have (two per colour): fewer, and the threads would have no
/// two blocks of a colour to share.
pub const MIN_SLABS: usize = 4;

/// The points in colour order, cut into blocks and colours.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Colouring {
    /// Point indices (into the caller's points) by colour, then block, then the lowest node of
    /// the support, then given order.
    pub order: Vec<u32>,
    /// The points of block `b` are `order[block_start[b]..block_start[b + 1]]`.
    pub block_start: Vec<usize>,
    /// The blocks of colour `c` are `colour_start[c]..colour_start[c + 1]` (possibly empty).
    pub colour_start: Vec<usize>,
    /// The axis the slabs are cut along.
    pub axis: usize,
    /// The width `w` (nodes along the axis spanned by the widest support).
    pub width: usize,
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

/// Colours `n` points whose supports are `nodes_of(p)` (node indices of a grid with `sizes`
/// nodes per axis), as the module docs say; `None` when it gives fewer than [`MIN_SLABS`]
/// slabs (no colouring: the caller falls back).
pub fn colour_points<const D: usize, I: Iterator<Item = usize>>(
    sizes: [usize; D],
    n: usize,
    nodes_of: impl Fn(usize) -> I + Sync,
) -> Option<Colouring> {
    if n > u32::MAX as usize || sizes.contains(&0) || D == 0 {
        return None;
    }
    // The axis with the most nodes, the last on a tie; its stride, bounded unless last.
    let axis = (0..D).rev().max_by_key(|&k| (sizes[k], k))?;
    let stride: usize = sizes[..axis].iter().product();
    let along = |node: usize| match axis + 1 == D {
        true => node / stride,
        false => node / stride % sizes[axis],
    };
    // Per point: (a_p, b_p, lowest node); an empty support spans nothing (width 0).
    let spans: Vec<(usize, usize, usize)> = (0..n)
        .into_par_iter()
        .map(|p| {
            let (mut a, mut b, mut low) = (usize::MAX, 0, usize::MAX);
            for node in nodes_of(p) {
                let m = along(node);
                (a, b, low) = (a.min(m), b.max(m), low.min(node));
            }
            if low == usize::MAX {
                (0, 0, 0)
            } else {
                (a, b + 1, low)
            }
        })
        .collect();
    let width = spans.iter().map(|&(a, b, _)| b - a).max().unwrap_or(1);
    let thickness = width.saturating_sub(1).max(1);
    let slabs = spans
        .iter()
        .map(|&(a, _, _)| a / thickness)
        .max()
        .unwrap_or(0)
        + 1;
    if slabs < MIN_SLABS || slabs > u32::MAX as usize / 2 {
        return None;
    }
    // The sort key: colour (1 bit), slab (31 bits), lowest node (64), point (32): unique keys,
    // so the unstable sort gives one order.
    let mut keys: Vec<u128> = spans
        .par_iter()
        .enumerate()
        .map(|(p, &(a, _, low))| {
            let slab = (a / thickness) as u128;
            let colour = slab % 2;
            (colour << 127) | (slab << 96) | ((low as u128) << 32) | p as u128
        })
        .collect();
    drop(spans);
    keys.par_sort_unstable();

    let mut order = Vec::with_capacity(n);
    let mut block_start = Vec::new();
    let mut colour_start = vec![0; 3];
    let mut previous: Option<u128> = None;
    for (position, key) in keys.iter().enumerate() {
        let block = key >> 96;
        if previous != Some(block) {
            block_start.push(position);
            colour_start[(key >> 127) as usize + 1] += 1;
            previous = Some(block);
        }
        order.push(*key as u32);
    }
    block_start.push(n);
    colour_start[2] += colour_start[1];
    Some(Colouring {
        order,
        block_start,
        colour_start,
        axis,
        width,
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
    /// the points of a block are in (lowest node, given order).
    fn assert_valid(colouring: &Colouring, supports: &[Vec<usize>]) {
        let mut seen = vec![false; supports.len()];
        for &p in &colouring.order {
            assert!(!seen[p as usize], "point {p} twice");
            seen[p as usize] = true;
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(colouring.colours(), 2);
        for c in 0..colouring.colours() {
            let blocks = colouring.blocks_of(c);
            let mut owner = std::collections::HashMap::new();
            for (b, w) in blocks.windows(2).enumerate() {
                let points = &colouring.order[w[0]..w[1]];
                let key = |p: u32| {
                    let low = supports[p as usize].iter().min().copied().unwrap_or(0);
                    (low, p)
                };
                assert!(
                    points.windows(2).all(|p| key(p[0]) < key(p[1])),
                    "block order"
                );
                for &p in points {
                    for &node in &supports[p as usize] {
                        let first = *owner.entry(node).or_insert(b);
                        assert_eq!(first, b, "colour {c}: node {node} in two blocks");
                    }
                }
            }
        }
    }

    fn colour(sizes: [usize; 2], supports: &[Vec<usize>]) -> Option<Colouring> {
        colour_points(sizes, supports.len(), |p| supports[p].iter().copied())
    }

    #[test]
    fn b_spline_supports_make_slabs_of_q_cells_with_disjoint_blocks_per_colour() {
        for q in 1..=3 {
            let cells = [7, 11];
            let sizes = [cells[0] + q, cells[1] + q];
            // Two points per cell, cells visited in a scrambled order.
            let mut supports = Vec::new();
            for k in 0..cells[0] * cells[1] {
                let cell = (k * 17) % (cells[0] * cells[1]);
                let corner = [cell % cells[0], cell / cells[0]];
                supports.push(box_nodes(sizes, corner, q));
                supports.push(box_nodes(sizes, corner, q));
            }
            let colouring = colour(sizes, &supports).unwrap();
            assert_eq!((colouring.axis, colouring.width), (1, q + 1));
            // Slabs of max(q, 1) cells along axis 1.
            assert_eq!(colouring.block_start.len() - 1, cells[1].div_ceil(q.max(1)));
            assert_valid(&colouring, &supports);
        }
    }

    #[test]
    fn uneven_supports_take_the_widest_extent_along_the_longest_axis() {
        // GIMP-like: 2 or 3 nodes per axis, linear grid of 12 x 6 nodes: slabs along axis 0.
        let sizes = [12, 6];
        let mut supports = Vec::new();
        for j in 0..4 {
            for i in 0..10 {
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
        let colouring = colour(sizes, &supports).unwrap();
        assert_eq!((colouring.axis, colouring.width), (0, 3));
        assert_valid(&colouring, &supports);
    }

    #[test]
    fn supports_spread_over_the_numbering_are_not_coloured() {
        // Nodes far apart in the numbering (an unstructured mesh): one wide slab.
        let sizes = [100, 100];
        let supports: Vec<Vec<usize>> = (0..50).map(|p| vec![p, p + 77, 5000 + p]).collect();
        assert!(colour(sizes, &supports).is_none());
    }

    #[test]
    fn node_indices_beyond_the_grid_fall_on_the_unbounded_last_axis() {
        // 2 x 3 nodes, supports of 2 nodes along axis 1 reaching past the grid's 3 rows.
        let sizes = [2, 3];
        let supports: Vec<Vec<usize>> = (0..10).map(|r| vec![2 * r, 2 * (r + 1)]).collect();
        let colouring = colour(sizes, &supports).unwrap();
        assert_eq!((colouring.axis, colouring.width), (1, 2));
        assert_eq!(colouring.block_start.len() - 1, 10);
        assert_valid(&colouring, &supports);
    }
}
