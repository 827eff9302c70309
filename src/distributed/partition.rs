//! Slabs of background cells for the processes of a distributed run, balanced by points.
//!
//! The cells are cut into `P` slabs along one axis, the one with the most cells (the first of
//! equal ones): slab `r` is a contiguous run of cell layers ("slices") along that axis, and a
//! point belongs to the slab of the cell its position lies in at the start of the load step.
//! The cuts balance points, not cells: with `n_i` points in slice `i`, `c_i` the points in the
//! slices before it and `T` the total, slice `i` goes to process
//!
//! ```text
//!   r_i = min(P − 1, ⌊P (c_i + n_i / 2) / T⌋),
//! ```
//!
//! the process whose share `[r T / P, (r + 1) T / P)` holds the slice's middle point. `r_i`
//! never decreases with `i`, so every slab is contiguous, and a process gets its share `T / P`
//! to within one slice's points on either side. A process may get no slice (more processes
//! than populated slices): it then assembles nothing.

/// The axis the slabs cut: the one with the most cells (the last of equal ones). The grid
/// numbers its nodes with axis 0 fastest, so PETSc's rows, split among the processes in node
/// order, are layers along the last axis: slabs along it put a process's assembled rows
/// mostly in its own rows (with slabs along axis 0 of a square grid about half of every
/// process's matrix entries went to another process: `docs/distributed.md`).
pub fn slab_axis(cells_per_axis: &[usize]) -> usize {
    let mut axis = 0;
    for (a, &cells) in cells_per_axis.iter().enumerate() {
        if cells >= cells_per_axis[axis] {
            axis = a;
        }
    }
    axis
}

/// The process of each slice (cell layer along the slab axis) given the points in each slice,
/// for `processes` processes (see the module docs). Everything goes to process 0 when there
/// are no points.
pub fn slab_owners(points_per_slice: &[usize], processes: usize) -> Vec<usize> {
    let total: usize = points_per_slice.iter().sum();
    let last = processes.saturating_sub(1);
    let mut before = 0usize;
    points_per_slice
        .iter()
        .map(|&n| {
            let owner = if total == 0 {
                0
            } else {
                // P (c + n / 2) / T in integers: (2 P c + P n) / (2 T)
                ((2 * processes * before + processes * n) / (2 * total)).min(last)
            };
            before += n;
            owner
        })
        .collect()
}

/// The process of each point given the cell layer it lies in (`layers[p] < slices`), for
/// `processes` processes: [`slab_owners`] of the layers' point counts.
pub fn owners_of_layers(layers: &[usize], slices: usize, processes: usize) -> Vec<usize> {
    let mut per_slice = vec![0usize; slices];
    for &layer in layers {
        per_slice[layer] += 1;
    }
    let owners = slab_owners(&per_slice, processes);
    layers.iter().map(|&layer| owners[layer]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_axis_with_the_most_cells_is_cut() {
        assert_eq!(slab_axis(&[8, 32]), 1);
        assert_eq!(slab_axis(&[8, 8, 4]), 1);
        assert_eq!(slab_axis(&[4, 6, 6]), 2);
        assert_eq!(slab_axis(&[5]), 0);
    }

    /// Every slab is contiguous, every process's points are within one slice of its share, and
    /// the counts add up, for uneven point counts and 1 to 5 processes.
    #[test]
    fn slabs_are_contiguous_and_balanced_by_points() {
        let slices: Vec<usize> = (0..23).map(|i| 4 + (i * 7) % 11).collect();
        let total: usize = slices.iter().sum();
        let largest = *slices.iter().max().unwrap();
        for processes in 1..=5 {
            let owners = slab_owners(&slices, processes);
            assert_eq!(owners.len(), slices.len());
            assert!(owners.windows(2).all(|w| w[0] <= w[1]), "{owners:?}");
            assert_eq!(owners[0], 0);
            assert!(owners.iter().all(|&r| r < processes));
            let mut count = vec![0usize; processes];
            for (&n, &r) in slices.iter().zip(&owners) {
                count[r] += n;
            }
            assert_eq!(count.iter().sum::<usize>(), total);
            let share = total as f64 / processes as f64;
            for (r, &c) in count.iter().enumerate() {
                assert!(
                    (c as f64 - share).abs() <= largest as f64,
                    "{processes} processes: process {r} has {c} points, share {share}"
                );
            }
        }
    }

    /// Each point gets the owner of its layer, and the counts per process are those of
    /// `slab_owners` over the layers' counts.
    #[test]
    fn points_get_the_owners_of_their_layers() {
        // 12 points: 4 in layer 0, 2 in layer 1, none in 2, 6 in layer 3 (out of order)
        let layers = [3, 0, 1, 3, 0, 3, 0, 1, 3, 3, 0, 3];
        let owners = owners_of_layers(&layers, 4, 2);
        let by_layer = slab_owners(&[4, 2, 0, 6], 2);
        assert_eq!(by_layer, vec![0, 0, 1, 1]);
        for (&layer, &owner) in layers.iter().zip(&owners) {
            assert_eq!(owner, by_layer[layer]);
        }
        assert_eq!(owners.iter().filter(|&&r| r == 0).count(), 6);
        assert_eq!(owners_of_layers(&[], 3, 2), Vec::<usize>::new());
    }

    #[test]
    fn a_column_of_equal_slices_is_cut_evenly() {
        // 12 layers of 8 points over 3 processes: 4 layers each
        assert_eq!(
            slab_owners(&[8; 12], 3),
            vec![0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2]
        );
        // empty layers (above a body) go with their neighbours; no points: all on process 0
        assert_eq!(slab_owners(&[4, 4, 0, 0], 2), vec![0, 1, 1, 1]);
        assert_eq!(slab_owners(&[0, 0, 0], 2), vec![0, 0, 0]);
        // more processes than layers: some processes assemble nothing
        assert_eq!(slab_owners(&[5, 5], 4), vec![1, 3]);
    }
}
