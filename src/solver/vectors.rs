//! The iterative solvers' vector and sparse-matrix kernels on rayon's threads: dot products,
//! element-wise updates, and sparse matrix–vector products (`y = K x`) by gathering along
//! rows or scattering along columns.
//!
//! **Determinism.** Everything except the scatter is the same for any thread count, bit for bit:
//!
//! * reductions (`dot`, `norm`) cut the vectors into chunks of [`CHUNK`] entries — fixed by the
//!   length, never by the threads — sum each chunk in four interleaved partial sums, and add
//!   the chunks' sums in chunk order;
//! * element-wise updates and gathers (`y_i = Σ_j A_ij x_j` with row `i` read as one slice) write
//!   each entry from one thread, in a fixed order.
//!
//! The scatter (`y += Σ_j A_:j x_j` over the columns of a compressed-column matrix) cuts the
//! columns into one contiguous part per thread; each part adds into its own buffer over the rows
//! its columns reach (the node-major numbering keeps that a band, not the whole vector), and
//! the buffers are added to `y` in part order. So a given thread count gives the same bits run
//! after run, and 1 and 2 threads agree to round-off.
//!
//! Loops shorter than [`PARALLEL_FROM`] run on the calling thread (the same chunks, so the same
//! result): below that, the threads' start-up costs more than they save.

use std::ops::Range;

use rayon::prelude::*;

/// Entries per chunk of a reduction or an element-wise update.
pub const CHUNK: usize = 4096;

/// Vectors shorter than this are handled on the calling thread.
pub const PARALLEL_FROM: usize = 4 * CHUNK;

/// `Σ_k values[k] x[indices[k]]` in four partial sums. The additions of one running sum wait
/// on each other (a q = 2 B-spline row has up to 375 entries in 3D), which makes a long sum
/// latency-bound; four independent chains keep the floating-point units busy. The order is
/// fixed, so the result is the same every run.
#[inline]
pub fn sparse_dot(values: &[f64], indices: &[usize], x: &[f64]) -> f64 {
    let mut sums = [0.0; 4];
    let (values_4, values_rest) = values.split_at(values.len() / 4 * 4);
    let (indices_4, indices_rest) = indices.split_at(values_4.len());
    for (v, i) in values_4.chunks_exact(4).zip(indices_4.chunks_exact(4)) {
        for lane in 0..4 {
            sums[lane] += v[lane] * x[i[lane]];
        }
    }
    let rest: f64 = values_rest
        .iter()
        .zip(indices_rest)
        .map(|(v, &i)| v * x[i])
        .sum();
    (sums[0] + sums[1]) + (sums[2] + sums[3]) + rest
}

/// `u · v` of one chunk, in four partial sums (fixed order).
#[inline]
fn chunk_dot(u: &[f64], v: &[f64]) -> f64 {
    let mut sums = [0.0; 4];
    let (u4, u_rest) = u.split_at(u.len() / 4 * 4);
    let (v4, v_rest) = v.split_at(u4.len());
    for (a, b) in u4.chunks_exact(4).zip(v4.chunks_exact(4)) {
        for lane in 0..4 {
            sums[lane] += a[lane] * b[lane];
        }
    }
    let rest: f64 = u_rest.iter().zip(v_rest).map(|(a, b)| a * b).sum();
    (sums[0] + sums[1]) + (sums[2] + sums[3]) + rest
}

/// `u · v`, the same for any thread count (see the module docs).
pub fn dot(u: &[f64], v: &[f64]) -> f64 {
    debug_assert_eq!(u.len(), v.len());
    if u.len() < PARALLEL_FROM {
        return u
            .chunks(CHUNK)
            .zip(v.chunks(CHUNK))
            .map(|(a, b)| chunk_dot(a, b))
            .fold(0.0, |s, c| s + c);
    }
    let sums: Vec<f64> = u
        .par_chunks(CHUNK)
        .zip(v.par_chunks(CHUNK))
        .map(|(a, b)| chunk_dot(a, b))
        .collect();
    sums.iter().fold(0.0, |s, c| s + c)
}

/// `‖u‖₂`.
pub fn norm(u: &[f64]) -> f64 {
    dot(u, u).sqrt()
}

/// Calls `update(range, chunk)` on the chunks of `target` (`range`: where the chunk lies in
/// `target`, to read other vectors at the same entries), on the threads when it is long.
pub fn update(target: &mut [f64], update: impl Fn(Range<usize>, &mut [f64]) + Sync) {
    let run = |(c, chunk): (usize, &mut [f64])| {
        let start = c * CHUNK;
        update(start..start + chunk.len(), chunk)
    };
    if target.len() < PARALLEL_FROM {
        target.chunks_mut(CHUNK).enumerate().for_each(run);
    } else {
        target.par_chunks_mut(CHUNK).enumerate().for_each(run);
    }
}

/// `y_i = Σ_k values[k] x[indices[k]]` over `k ∈ starts[i]..starts[i + 1]`: the product of a
/// matrix stored by rows (`starts` = row pointers, `indices` = column indices), or the
/// transpose's product of one stored by columns. The same for any thread count.
pub fn gather(starts: &[usize], indices: &[usize], values: &[f64], x: &[f64], y: &mut [f64]) {
    update(y, |range, chunk| {
        for (y, i) in chunk.iter_mut().zip(range) {
            let entries = starts[i]..starts[i + 1];
            *y = sparse_dot(&values[entries.clone()], &indices[entries], x);
        }
    });
}

/// Work space of [`scatter_add`]: one buffer per part, kept between products.
#[derive(Default, Clone, Debug)]
pub struct ScatterParts {
    buffers: Vec<Vec<f64>>,
}

/// `y += A x` for `A` stored by columns (`starts` = column pointers, `indices` = row indices,
/// sorted within each column): the columns are cut into one part per thread, each part adds
/// its columns into its own buffer over the band of rows they reach, and the buffers are added
/// to `y` in part order (see the module docs). One part (one thread, or a short `x`) adds
/// straight into `y`, column by column.
pub fn scatter_add(
    starts: &[usize],
    indices: &[usize],
    values: &[f64],
    x: &[f64],
    y: &mut [f64],
    parts: &mut ScatterParts,
) {
    let columns = x.len();
    let count = if columns < PARALLEL_FROM {
        1
    } else {
        crate::parallel::part_count(columns)
    };
    let add_columns = |range: Range<usize>, y: &mut [f64], first_row: usize| {
        for j in range {
            let xj = x[j];
            for k in starts[j]..starts[j + 1] {
                y[indices[k] - first_row] += values[k] * xj;
            }
        }
    };
    if count == 1 {
        add_columns(0..columns, y, 0);
        return;
    }
    let ranges = crate::parallel::split(columns, count);
    // the rows each part's columns reach: rows are sorted within a column
    let bands: Vec<Range<usize>> = ranges
        .iter()
        .map(|range| {
            let (mut low, mut high) = (usize::MAX, 0);
            for j in range.clone() {
                if starts[j] < starts[j + 1] {
                    low = low.min(indices[starts[j]]);
                    high = high.max(indices[starts[j + 1] - 1] + 1);
                }
            }
            if low < high { low..high } else { 0..0 }
        })
        .collect();
    parts.buffers.resize_with(count, Vec::new);
    parts
        .buffers
        .par_iter_mut()
        .zip(ranges.par_iter().zip(bands.par_iter()))
        .for_each(|(buffer, (range, band))| {
            buffer.clear();
            buffer.resize(band.len(), 0.0);
            add_columns(range.clone(), buffer, band.start);
        });
    let (buffers, bands) = (&parts.buffers, &bands);
    update(y, |rows, chunk| {
        for (buffer, band) in buffers.iter().zip(bands) {
            let (from, to) = (rows.start.max(band.start), rows.end.min(band.end));
            if from < to {
                let part = &buffer[from - band.start..to - band.start];
                for (y, b) in chunk[from - rows.start..to - rows.start]
                    .iter_mut()
                    .zip(part)
                {
                    *y += b;
                }
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A banded random-looking matrix by columns (rows sorted), `n x n`.
    fn banded(n: usize, band: usize) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
        let (mut starts, mut indices, mut values) = (vec![0], Vec::new(), Vec::new());
        for j in 0..n {
            for i in j.saturating_sub(band)..(j + band + 1).min(n) {
                if (i * 31 + j * 17) % 5 != 0 || i == j {
                    indices.push(i);
                    values.push(((i * 7 + j * 13) % 23) as f64 / 23.0 - 0.4);
                }
            }
            starts.push(indices.len());
        }
        (starts, indices, values)
    }

    fn in_pool<R: Send>(threads: usize, work: impl FnOnce() -> R + Send) -> R {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(work)
    }

    #[test]
    fn reductions_and_gathers_are_the_same_bits_on_any_thread_count() {
        let n = 3 * PARALLEL_FROM + 17;
        let u: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let v: Vec<f64> = (0..n).map(|i| (i as f64 * 0.11).cos() + 0.1).collect();
        let (starts, indices, values) = banded(n, 40);
        let run = || {
            let mut y = vec![0.0; n];
            gather(&starts, &indices, &values, &u, &mut y);
            (dot(&u, &v).to_bits(), y)
        };
        let one = in_pool(1, run);
        for threads in [2, 3] {
            let many = in_pool(threads, run);
            assert_eq!(one.0, many.0, "dot on {threads} threads");
            assert!(
                one.1
                    .iter()
                    .zip(&many.1)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
        }
        // and equal to a plain sum to round-off
        let plain: f64 = u.iter().zip(&v).map(|(a, b)| a * b).sum();
        let scale: f64 = u.iter().zip(&v).map(|(a, b)| (a * b).abs()).sum();
        assert!((f64::from_bits(one.0) - plain).abs() <= 1e-13 * scale);
    }

    #[test]
    fn the_scatter_product_is_the_matrix_product_and_repeats_bit_for_bit() {
        let n = 2 * PARALLEL_FROM + 5;
        let (starts, indices, values) = banded(n, 60);
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.013).sin()).collect();
        // the reference: y_i = Σ_j A_ij x_j summed row by row from the dense entries
        let mut reference = vec![0.0; n];
        for j in 0..n {
            for k in starts[j]..starts[j + 1] {
                reference[indices[k]] += values[k] * x[j];
            }
        }
        for threads in [1, 2, 3] {
            let run = || {
                let mut y: Vec<f64> = vec![1.0; n];
                scatter_add(
                    &starts,
                    &indices,
                    &values,
                    &x,
                    &mut y,
                    &mut ScatterParts::default(),
                );
                y
            };
            let (first, again) = (in_pool(threads, run), in_pool(threads, run));
            assert!(
                first
                    .iter()
                    .zip(&again)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
            );
            let worst = first
                .iter()
                .zip(&reference)
                .map(|(y, r)| (y - 1.0 - r).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-12, "{threads} threads: {worst:e}");
        }
    }
}
