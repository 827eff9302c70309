//! Per-node storage that costs what a process touches: [`NodeVec`], a vector over the grid's
//! global node indices whose memory is allocated in pages of [`PAGE`] consecutive indices,
//! only when an entry of the page is written.
//!
//! Under `impm run --decompose` each process holds its slab's points, and only the nodes their
//! supports reach (its owned nodes and ghost layer) get values: a vector sized by the whole grid
//! would cost every process the whole grid's memory (`GridFields` holds about 88 bytes per node
//! in 3D). A `NodeVec` keeps the global numbering (`fields.dofs[n]` reads node `n` as before),
//! but its memory is
//!
//! ```text
//!   bytes = P · PAGE · size_of::<T>()  +  ⌈len / PAGE⌉ · size_of::<pointer>()
//! ```
//!
//! for `P` written pages: the page table costs 8 bytes per 64 nodes of the grid (0.125 byte per
//! node, the part that still grows with the whole grid), the pages what the process writes.
//!
//! **Reads** of an entry in an unwritten page give the vector's default (the value every entry
//! starts with: `false`, `NO_DOF`, zero); **writes** (`IndexMut`) allocate the page, filled
//! with the default. [`NodeVec::reset`] returns every entry to the default and frees the
//! pages (the grid reset of every load step). Iteration over every entry ([`NodeVec::iter`])
//! reads the default for unwritten pages (time over the whole grid, no memory); iteration over
//! the written pages only ([`NodeVec::written`], [`NodeVec::written_mut`]) is what callers that
//! look for non-default entries use under decomposition. Both go in increasing node order, so a
//! sum over them adds the same non-zero terms in the same order (the skipped entries are the
//! default, zero).
//!
//! **Why pages of 64.** The grid numbers nodes with axis 0 fastest (`GridBasis`), so a slab
//! along the slowest axis is one run of consecutive indices (its pages are full), and a slab
//! along axis 0 is a run of `w` consecutive indices in every row of `n_0` nodes: its pages are
//! those that meet these runs, at most `⌈w / 64⌉ + 1` per row. Smaller pages waste less on the
//! fast axis but cost more page table; 64 entries of a 3D vector are 1.5 KiB. A hash map per
//! node would cost more than the dense vector it replaces. In a serial run every page a point
//! touches is written once per step; the access adds one page-table load and a branch to the
//! dense vector's load (measured in docs/distributed.md, "Node storage sized by the process's
//! nodes").

use std::ops::{Index, IndexMut};

/// Consecutive node indices per page.
pub const PAGE: usize = 64;

/// A vector over `len` global node indices, allocated in pages when written (module docs).
#[derive(Clone, Debug)]
pub struct NodeVec<T> {
    len: usize,
    default: T,
    pages: Vec<Option<Box<[T; PAGE]>>>,
    written: usize,
}

impl<T: Copy + PartialEq> NodeVec<T> {
    /// `len` entries, every one `default`, no page allocated.
    pub fn new(len: usize, default: T) -> Self {
        Self {
            len,
            default,
            pages: vec![None; len.div_ceil(PAGE)],
            written: 0,
        }
    }

    /// The entries of `values` (pages holding only `default` are not allocated).
    pub fn from_values(values: &[T], default: T) -> Self {
        let mut vector = Self::new(values.len(), default);
        for (i, &value) in values.iter().enumerate() {
            if value != default {
                vector[i] = value;
            }
        }
        vector
    }

    /// The number of entries: the grid's node count, whatever is allocated.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The value of every unwritten entry.
    pub fn default_value(&self) -> T {
        self.default
    }

    /// Entry `i`, `None` past the end.
    pub fn get(&self, i: usize) -> Option<&T> {
        (i < self.len).then(|| &self[i])
    }

    /// Entry `i` to write (its page allocated), `None` past the end.
    pub fn get_mut(&mut self, i: usize) -> Option<&mut T> {
        (i < self.len).then(|| &mut self[i])
    }

    /// Every entry back to the default; the pages are freed.
    pub fn reset(&mut self) {
        if self.written > 0 {
            self.pages.iter_mut().for_each(|page| *page = None);
            self.written = 0;
        }
    }

    /// Every entry set to `value`: [`NodeVec::reset`] for the default, else every page
    /// allocated (the whole grid's memory).
    pub fn fill(&mut self, value: T) {
        if value == self.default {
            self.reset();
            return;
        }
        for page in &mut self.pages {
            *page = Some(Box::new([value; PAGE]));
        }
        self.written = self.pages.len();
    }

    /// Every entry, in node order (the default for unwritten pages).
    pub fn iter(&self) -> impl Iterator<Item = &T> + '_ {
        (0..self.len).map(move |i| &self[i])
    }

    /// The entries of the written pages with their node index, in node order.
    pub fn written(&self) -> impl Iterator<Item = (usize, &T)> + '_ {
        let len = self.len;
        (self.pages.iter().enumerate())
            .filter_map(|(p, page)| Some((p * PAGE, page.as_deref()?)))
            .flat_map(move |(first, page)| {
                let end = (len - first).min(PAGE);
                page[..end]
                    .iter()
                    .enumerate()
                    .map(move |(k, v)| (first + k, v))
            })
    }

    /// The entries of the written pages with their node index, mutable, in node order.
    pub fn written_mut(&mut self) -> impl Iterator<Item = (usize, &mut T)> + '_ {
        let len = self.len;
        (self.pages.iter_mut().enumerate())
            .filter_map(|(p, page)| Some((p * PAGE, page.as_deref_mut()?)))
            .flat_map(move |(first, page)| {
                let end = (len - first).min(PAGE);
                (page[..end].iter_mut().enumerate()).map(move |(k, v)| (first + k, v))
            })
    }

    /// Every entry as a dense vector (the whole grid's memory: for tests and small grids).
    pub fn to_vec(&self) -> Vec<T> {
        self.iter().copied().collect()
    }

    /// The number of allocated pages.
    pub fn pages(&self) -> usize {
        self.written
    }

    /// The bytes this vector holds: its pages and its page table.
    pub fn bytes(&self) -> usize {
        self.written * std::mem::size_of::<[T; PAGE]>()
            + self.pages.capacity() * std::mem::size_of::<Option<Box<[T; PAGE]>>>()
    }
}

impl<T: Copy + PartialEq> Index<usize> for NodeVec<T> {
    type Output = T;

    #[inline]
    fn index(&self, i: usize) -> &T {
        assert!(i < self.len, "node {i} of a grid of {} nodes", self.len);
        match &self.pages[i / PAGE] {
            Some(page) => &page[i % PAGE],
            None => &self.default,
        }
    }
}

impl<T: Copy + PartialEq> IndexMut<usize> for NodeVec<T> {
    /// Allocates entry `i`'s page (filled with the default) if it is not yet.
    #[inline]
    fn index_mut(&mut self, i: usize) -> &mut T {
        assert!(i < self.len, "node {i} of a grid of {} nodes", self.len);
        let page = &mut self.pages[i / PAGE];
        if page.is_none() {
            *page = Some(Box::new([self.default; PAGE]));
            self.written += 1;
        }
        match page {
            Some(page) => &mut page[i % PAGE],
            None => unreachable!("allocated above"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unwritten_entries_read_the_default_and_allocate_nothing() {
        let v = NodeVec::new(1000, 7u32);
        assert_eq!(v.len(), 1000);
        assert!((0..1000).all(|i| v[i] == 7));
        assert_eq!(v.iter().count(), 1000);
        assert_eq!(v.pages(), 0);
        assert_eq!(v.written().count(), 0);
        assert_eq!(v.get(1000), None);
        // the page table only: 16 pointers
        assert_eq!(v.bytes(), 16 * 8);
    }

    #[test]
    fn a_write_allocates_its_page_only_and_reset_frees_it() {
        let mut v = NodeVec::new(1000, 0.0f64);
        v[130] = 2.0;
        v[131] += 3.0;
        assert_eq!(v.pages(), 1);
        assert_eq!((v[130], v[131], v[129], v[192]), (2.0, 3.0, 0.0, 0.0));
        // the whole page is listed, in order, the others not
        let written: Vec<usize> = v.written().map(|(i, _)| i).collect();
        assert_eq!(written, (128..192).collect::<Vec<_>>());
        assert_eq!(v.bytes(), 64 * 8 + 16 * 8);
        for (_, value) in v.written_mut() {
            *value *= 2.0;
        }
        assert_eq!(v.to_vec().iter().sum::<f64>(), 10.0);
        v.reset();
        assert_eq!((v.pages(), v[130], v.len()), (0, 0.0, 1000));
    }

    #[test]
    fn the_last_page_is_cut_at_the_length() {
        let mut v = NodeVec::new(70, false);
        v[69] = true;
        assert_eq!(v.written().count(), 6);
        assert_eq!(v.written().last(), Some((69, &true)));
        let dense: Vec<bool> = (0..70).map(|i| i == 3 || i == 69).collect();
        let w = NodeVec::from_values(&dense, false);
        assert_eq!((w.pages(), w.to_vec()), (2, dense));
    }

    /// The pages a slab of 5 node layers writes on a 3D grid (axis 0 fastest). Along the
    /// slowest axis the slab is one run of consecutive indices: its pages are its own nodes'
    /// (rounded to pages). Along the fastest axis every row of `n_0` nodes has a run of 5: on
    /// rows of 640 nodes one page of the row's 10, on rows of 40 (shorter than a page) every
    /// page.
    #[test]
    fn the_pages_a_slab_of_nodes_writes() {
        let slab = |n: [usize; 3], axis: usize, low: usize| {
            let mut v = NodeVec::new(n.iter().product(), 0u8);
            for k in 0..n[2] {
                for j in 0..n[1] {
                    for i in 0..n[0] {
                        let m = [i, j, k];
                        if (low..low + 5).contains(&m[axis]) {
                            v[i + n[0] * (j + n[1] * k)] = 1;
                        }
                    }
                }
            }
            assert_eq!(
                v.written().filter(|&(_, &v)| v == 1).count(),
                5 * n.iter().product::<usize>() / n[axis]
            );
            v.pages()
        };
        // 6 000 consecutive nodes from 12 000 (of 24 000): pages 187..=281
        assert_eq!(slab([40, 30, 20], 2, 10), (18000 - 1) / 64 - 12000 / 64 + 1);
        // nodes 300..305 of every row of 640: page 4 of the row's 10
        assert_eq!(slab([640, 10, 10], 0, 300), 100);
        // rows of 40 nodes: every page of 64 meets a run
        assert_eq!(slab([40, 30, 20], 0, 30), 24000 / 64);
    }
}
