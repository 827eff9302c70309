//! The sparse tangent of one load step: pattern once, values every Newton iteration.
//!
//! Degrees of freedom (DOFs) are numbered node-major: the free components of an active node get
//! consecutive numbers, nodes in increasing index order. Two DOFs couple when their nodes share
//! a material point's support (or a module's coupling group), so the pattern is built from the
//! supports at the start of the load step and stays fixed through the step's Newton iterations;
//! only the values are refilled (`clear_values` then `add_block`). Both triangles are stored, so
//! a non-symmetric tangent is represented as it is.

use std::sync::Arc;

use crate::node_storage::NodeVec;

use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};

/// Marker for a node component that has no DOF (fixed, or node inactive).
pub const NO_DOF: u32 = u32::MAX;

/// Marker for a block position that is not stored (see [`SparseMatrix::block_starts`]).
pub const NO_ENTRY: usize = usize::MAX;

/// Compressed-sparse-column pattern and values of the tangent.
#[derive(Default, Clone, Debug)]
pub struct SparseMatrix {
    size: usize,
    /// The pattern, shared (not copied) with a solver that keeps an operator on it (multigrid's
    /// finest level); a rebuild makes new vectors.
    col_ptr: Arc<Vec<usize>>,
    row_idx: Arc<Vec<usize>>,
    values: Vec<f64>,
    /// Counts pattern rebuilds, so that solvers know when their analysis is stale.
    generation: u64,
    /// Which node and component each DOF belongs to, and where the nodes are.
    layout: DofLayout,
}

/// Where the DOFs sit: the nodes that have any (node-major, as numbered), the spatial
/// component of each DOF and, once told ([`SparseMatrix::set_node_positions`]), the nodes'
/// positions. Multigrid builds its aggregates and the rigid-body modes (its near-null space)
/// from it; a solver that needs no geometry ignores it.
#[derive(Default, Clone, Debug, PartialEq)]
pub struct DofLayout {
    /// Spatial dimension of the components.
    pub dimension: usize,
    /// The DOFs of the `b`-th node with any are `block_start[b]..block_start[b + 1]`.
    pub block_start: Vec<usize>,
    /// The node index of each such block.
    pub node: Vec<usize>,
    /// The spatial component (`0..dimension`) of each DOF.
    pub component: Vec<u8>,
    /// The position of each block's node (unused components zero); empty when not told.
    pub position: Vec<[f64; 3]>,
}

/// The DOF numbers of a grid's nodes for [`SparseMatrix::rebuild_pattern`]: a dense slice
/// (one entry per node) or the core's paged `NodeVec` (the nodes of its written pages).
pub trait NodeDofs<const D: usize> {
    /// The grid's node count.
    fn node_count(&self) -> usize;
    /// The DOF numbers of `node` (`NO_DOF` where none).
    fn of(&self, node: usize) -> [u32; D];
    /// In node order, every node that may have DOFs with its numbers (the others have none).
    fn with_dofs(&self) -> Box<dyn Iterator<Item = (usize, [u32; D])> + '_>;
}

impl<const D: usize> NodeDofs<D> for [[u32; D]] {
    fn node_count(&self) -> usize {
        self.len()
    }
    fn of(&self, node: usize) -> [u32; D] {
        self[node]
    }
    fn with_dofs(&self) -> Box<dyn Iterator<Item = (usize, [u32; D])> + '_> {
        Box::new(self.iter().copied().enumerate())
    }
}

impl<const D: usize> NodeDofs<D> for NodeVec<[u32; D]> {
    fn node_count(&self) -> usize {
        self.len()
    }
    fn of(&self, node: usize) -> [u32; D] {
        self[node]
    }
    fn with_dofs(&self) -> Box<dyn Iterator<Item = (usize, [u32; D])> + '_> {
        Box::new(self.written().map(|(node, &dofs)| (node, dofs)))
    }
}

impl SparseMatrix {
    /// Number of DOFs.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Number of stored entries.
    pub fn nonzeros(&self) -> usize {
        self.row_idx.len()
    }

    /// Builds the pattern for `size` DOFs from node adjacency.
    ///
    /// `node_dofs[i]` are the DOF numbers of node `i`'s components (`NO_DOF` where none);
    /// `supports` yields, for every material point, the nodes of its support. All pairs of
    /// nodes in one support couple. Previous symbolic factorisations are dropped.
    pub fn rebuild_pattern<'a, const D: usize>(
        &mut self,
        size: usize,
        node_dofs: &(impl NodeDofs<D> + ?Sized),
        supports: impl Iterator<Item = &'a [usize]>,
    ) {
        // The nodes with DOFs in node order (their blocks), and each one's place among them:
        // sized by these nodes, not by the grid (a decomposed run's process numbers its own).
        let blocks: Vec<(usize, [u32; D])> = (node_dofs.with_dofs())
            .filter(|(_, dofs)| dofs.iter().any(|&d| d != NO_DOF))
            .collect();
        let mut place = NodeVec::new(node_dofs.node_count(), u32::MAX);
        for (k, &(node, _)) in blocks.iter().enumerate() {
            place[node] = k as u32;
        }
        let mut adjacency: Vec<Vec<u32>> = vec![Vec::new(); blocks.len()];
        let mut previous: &[usize] = &[];
        for support in supports {
            // Points of one cell share their support (B-splines, linear): skip repeats.
            if support == previous {
                continue;
            }
            for &j in support {
                let k = place[j];
                if k == u32::MAX {
                    continue;
                }
                adjacency[k as usize].extend(support.iter().map(|&i| i as u32));
            }
            previous = support;
        }
        drop(place);
        for list in adjacency.iter_mut() {
            list.sort_unstable();
            list.dedup();
        }

        self.size = size;
        // New vectors at their exact sizes (a solver may still hold the old pattern).
        let dofs_of = |node: usize| {
            (node_dofs.of(node).iter())
                .filter(|&&d| d != NO_DOF)
                .count()
        };
        let entries: usize = (blocks.iter().zip(&adjacency))
            .map(|(&(j, _), nodes)| {
                dofs_of(j) * nodes.iter().map(|&i| dofs_of(i as usize)).sum::<usize>()
            })
            .sum();
        let mut col_ptr = Vec::with_capacity(size + 1);
        let mut row_idx = Vec::with_capacity(entries);
        col_ptr.push(0);
        // Columns in DOF order: nodes in index order, components in order (node-major numbering).
        for ((_, dofs_j), nodes) in blocks.iter().zip(&adjacency) {
            for &col in dofs_j.iter() {
                if col == NO_DOF {
                    continue;
                }
                debug_assert_eq!(col as usize, col_ptr.len() - 1);
                for &i in nodes {
                    for &row in node_dofs.of(i as usize).iter() {
                        if row != NO_DOF {
                            row_idx.push(row as usize);
                        }
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        drop(adjacency);
        self.col_ptr = Arc::new(col_ptr);
        self.row_idx = Arc::new(row_idx);
        self.values.clear();
        self.values.resize(self.row_idx.len(), 0.0);
        self.generation += 1;

        let layout = &mut self.layout;
        layout.dimension = D;
        layout.block_start.clear();
        layout.node.clear();
        layout.component.clear();
        layout.position.clear();
        layout.block_start.push(0);
        for &(node, dofs) in &blocks {
            for (c, &dof) in dofs.iter().enumerate() {
                if dof != NO_DOF {
                    debug_assert_eq!(dof as usize, layout.component.len());
                    layout.component.push(c as u8);
                }
            }
            layout.node.push(node);
            layout.block_start.push(layout.component.len());
        }
    }

    /// Records the position of every node with DOFs (see [`DofLayout`]); call after
    /// [`SparseMatrix::rebuild_pattern`]. The pattern generation does not change.
    pub fn set_node_positions<const D: usize>(
        &mut self,
        position: impl Fn(usize) -> nalgebra::SVector<f64, D>,
    ) {
        let layout = &mut self.layout;
        layout.position.clear();
        layout.position.extend(layout.node.iter().map(|&node| {
            let x = position(node);
            std::array::from_fn(|c| if c < D { x[c] } else { 0.0 })
        }));
    }

    /// The DOFs' nodes, components and positions.
    pub fn layout(&self) -> &DofLayout {
        &self.layout
    }

    /// Sets every stored value to zero, keeping the pattern.
    pub fn clear_values(&mut self) {
        self.values.fill(0.0);
    }

    /// Adds `value` to entry (`row`, `col`); both must be in the pattern.
    ///
    /// Rows of a column are sorted, so the entry is found by binary search.
    #[inline]
    pub fn add(&mut self, row: u32, col: u32, value: f64) {
        let (start, end) = (self.col_ptr[col as usize], self.col_ptr[col as usize + 1]);
        let rows = &self.row_idx[start..end];
        match rows.binary_search(&(row as usize)) {
            Ok(k) => self.values[start + k] += value,
            Err(_) => panic!("entry ({row}, {col}) is not in the sparsity pattern"),
        }
    }

    /// Adds the D x D block coupling node components `rows` (of node i) and `cols` (of node j):
    /// `K[rows[a], cols[b]] += block[(a, b)]`, skipping components without a DOF.
    #[inline]
    pub fn add_block<const D: usize>(
        &mut self,
        rows: &[u32; D],
        cols: &[u32; D],
        block: &nalgebra::SMatrix<f64, D, D>,
    ) {
        let starts = self.block_starts(rows, cols);
        self.add_block_at(&starts, rows, block);
    }

    /// Where the block of `rows` begins in each column of `cols` (an index into the values),
    /// `NO_ENTRY` for a column without a DOF or a row node without any.
    ///
    /// The free components of a node are consecutive in a column, so one binary search per
    /// column finds the block. Points with the same support share these positions, which is
    /// what lets assembly cache them (`stages/assembly.rs`).
    #[inline]
    pub fn block_starts<const D: usize>(&self, rows: &[u32; D], cols: &[u32; D]) -> [usize; D] {
        let first_row = rows.iter().copied().find(|&r| r != NO_DOF);
        std::array::from_fn(|b| {
            let (Some(first_row), col) = (first_row, cols[b]) else {
                return NO_ENTRY;
            };
            if col == NO_DOF {
                return NO_ENTRY;
            }
            let (start, end) = (self.col_ptr[col as usize], self.col_ptr[col as usize + 1]);
            match self.row_idx[start..end].binary_search(&(first_row as usize)) {
                Ok(k) => start + k,
                Err(_) => panic!("block ({first_row}, {col}) is not in the sparsity pattern"),
            }
        })
    }

    /// Adds `block` at positions from [`SparseMatrix::block_starts`].
    #[inline]
    pub fn add_block_at<const D: usize>(
        &mut self,
        starts: &[usize; D],
        rows: &[u32; D],
        block: &nalgebra::SMatrix<f64, D, D>,
    ) {
        Self::add_block_to(&mut self.values, starts, rows, block);
    }

    /// Adds `block` into `values` (laid out as this matrix's values) at positions from
    /// [`SparseMatrix::block_starts`], skipping components without a DOF.
    #[inline]
    pub fn add_block_to<const D: usize>(
        values: &mut [f64],
        starts: &[usize; D],
        rows: &[u32; D],
        block: &nalgebra::SMatrix<f64, D, D>,
    ) {
        Self::add_block_with(starts, rows, block, |k, v| values[k] += v);
    }

    /// Calls `add(k, value)` for every entry of `block` with a DOF, `k` its position in the
    /// values (from [`SparseMatrix::block_starts`]): [`SparseMatrix::add_block_to`] for values
    /// that are not a plain slice (the threads' shared values in `stages/assembly.rs`).
    #[inline]
    pub fn add_block_with<const D: usize>(
        starts: &[usize; D],
        rows: &[u32; D],
        block: &nalgebra::SMatrix<f64, D, D>,
        mut add: impl FnMut(usize, f64),
    ) {
        for (b, &start) in starts.iter().enumerate() {
            if start == NO_ENTRY {
                continue;
            }
            let mut k = start;
            for (a, &row) in rows.iter().enumerate() {
                if row != NO_DOF {
                    add(k, block[(a, b)]);
                    k += 1;
                }
            }
        }
    }

    /// Lends the values apart from the pattern: `fill` reads the pattern (`block_starts`)
    /// through `&Self` while it writes the values, or a copy of them per thread
    /// (`stages/assembly.rs`). Inside `fill`, `values()` of the matrix is empty.
    pub fn with_values_apart<R>(&mut self, fill: impl FnOnce(&Self, &mut [f64]) -> R) -> R {
        let mut values = std::mem::take(&mut self.values);
        let result = fill(self, &mut values);
        self.values = values;
        result
    }

    /// The matrix as a faer view.
    pub fn matrix(&self) -> SparseColMatRef<'_, usize, f64> {
        let symbolic = SymbolicSparseColMatRef::new_checked(
            self.size,
            self.size,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        SparseColMatRef::new(symbolic, &self.values)
    }

    /// Entry (`row`, `col`), zero where not stored. For tests and diagnostics.
    pub fn get(&self, row: usize, col: usize) -> f64 {
        let (start, end) = (self.col_ptr[col], self.col_ptr[col + 1]);
        match self.row_idx[start..end].binary_search(&row) {
            Ok(k) => self.values[start + k],
            Err(_) => 0.0,
        }
    }

    /// How many times the pattern was built (solvers redo their analysis when it changes).
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// The pattern as shared vectors (column pointers, row indices), for a solver that keeps an
    /// operator on this pattern without a copy of it.
    pub fn shared_pattern(&self) -> (Arc<Vec<usize>>, Arc<Vec<usize>>) {
        (Arc::clone(&self.col_ptr), Arc::clone(&self.row_idx))
    }

    /// The pattern: column pointers and row indices (CSC).
    pub fn pattern(&self) -> (&[usize], &[usize]) {
        (&self.col_ptr, &self.row_idx)
    }

    /// The stored values, in pattern order.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Whether `K = Kᵀ` to within `tolerance` times the largest entry (the pattern is
    /// symmetric by construction).
    pub fn is_symmetric(&self, tolerance: f64) -> bool {
        let scale = self.values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        (0..self.size).all(|col| {
            (self.col_ptr[col]..self.col_ptr[col + 1]).all(|k| {
                let row = self.row_idx[k];
                (self.values[k] - self.get(col, row)).abs() <= tolerance * scale
            })
        })
    }
}
