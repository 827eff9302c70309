//! Threads over points: the one place where the stages' per-point loops are split across cores.
//!
//! A stage collects its points (query items, in the query's fixed order) into a slice and hands
//! it to [`for_each_part`] with one state per part (its scratch memory and what it returns: a
//! partial sum, the first error). The slice is cut into [`part_count`] contiguous parts, one per
//! thread of the current rayon pool, and each part runs on its own state; the stage then
//! combines the states **in part order** ([`add_parts`] for summed arrays). The cut depends only
//! on the number of points and the number of threads, never on timing, so a run is bit-identical
//! from one repetition to the next for a given thread count. Sums over points (internal force,
//! tangent) are added in another order for another thread count, so runs with 1 and 2 threads
//! agree to round-off, not bit for bit; per-point work without sums (stress update, basis
//! evaluation) is identical for any thread count.
//!
//! The kernels (`mechanics`, `basis`, `material`) know nothing of this: only the thin systems
//! over them call here.
//!
//! The thread count is rayon's: the machine's cores, `RAYON_NUM_THREADS`, or `impm run/study
//! --threads N` ([`use_threads`]); a caller may also run a simulation inside its own
//! `rayon::ThreadPool::install` (the tests and `examples/scale.rs` compare 1 and 2 threads in
//! one process that way). rayon rather than bevy_ecs's task pool: the stages need an ordered,
//! deterministic split and merge of partial sums, which `Query::par_iter` does not give (its
//! batches follow the task pool), and rayon is already built for faer.

use std::ops::Range;

use rayon::prelude::*;

/// The number of threads of the current pool (the global one unless inside `install`).
pub fn thread_count() -> usize {
    rayon::current_num_threads()
}

/// Sets the global pool's thread count (`--threads N`). Must come before the first parallel
/// stage runs; afterwards the pool exists and this reports that it could not be changed.
pub fn use_threads(threads: usize) -> Result<(), String> {
    if threads == 0 {
        return Err("--threads 0: give at least one thread".into());
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .map_err(|e| format!("--threads {threads}: {e}"))
}

/// How many parts `n` items are cut into: one per thread, none empty (at least one part).
pub fn part_count(n: usize) -> usize {
    thread_count().min(n).max(1)
}

/// The `parts` contiguous ranges covering `0..n`, their lengths differing by at most one.
pub fn split(n: usize, parts: usize) -> Vec<Range<usize>> {
    let parts = parts.max(1);
    let (base, extra) = (n / parts, n % parts);
    let mut start = 0;
    (0..parts)
        .map(|p| {
            let len = base + usize::from(p < extra);
            let range = start..start + len;
            start += len;
            range
        })
        .collect()
}

/// Runs `work(part, items, state)` on `states.len()` contiguous parts of `items` (cut as
/// [`split`]), in parallel; part `p` gets `states[p]`. With one state it runs on the calling
/// thread.
pub fn for_each_part<T: Send, S: Send>(
    items: &mut [T],
    states: &mut [S],
    work: impl Fn(usize, &mut [T], &mut S) + Sync,
) {
    if let [state] = states {
        work(0, items, state);
        return;
    }
    let mut pieces = Vec::with_capacity(states.len());
    let mut rest = items;
    for range in split(rest.len(), states.len()) {
        let (head, tail) = rest.split_at_mut(range.len());
        pieces.push(head);
        rest = tail;
    }
    pieces
        .into_par_iter()
        .zip(states.par_iter_mut())
        .enumerate()
        .for_each(|(p, (items, state))| work(p, items, state));
}

/// `target[k] += parts[0][k] + parts[1][k] + ...`, added in part order for every k (so the
/// result does not depend on the threads that do it), in parallel over k.
pub fn add_parts<T: Copy + Send + Sync + std::ops::AddAssign>(target: &mut [T], parts: &[&[T]]) {
    if parts.is_empty() {
        return;
    }
    const CHUNK: usize = 1 << 14;
    target
        .par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let range = c * CHUNK..c * CHUNK + chunk.len();
            for part in parts {
                for (t, v) in chunk.iter_mut().zip(&part[range.clone()]) {
                    *t += *v;
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_covers_the_items_in_order_with_parts_differing_by_at_most_one() {
        for n in [0, 1, 5, 17, 1000] {
            for parts in 1..6 {
                let ranges = split(n, parts);
                assert_eq!(ranges.len(), parts);
                let flat: Vec<usize> = ranges.iter().cloned().flatten().collect();
                assert_eq!(flat, (0..n).collect::<Vec<_>>());
                let lens: Vec<usize> = ranges.iter().map(|r| r.len()).collect();
                let (lo, hi) = (lens.iter().min().unwrap(), lens.iter().max().unwrap());
                assert!(hi - lo <= 1, "{lens:?}");
            }
        }
    }

    #[test]
    fn each_part_sees_its_own_items_and_state() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        pool.install(|| {
            let mut items: Vec<usize> = (0..10).collect();
            let mut sums = vec![(usize::MAX, 0usize); part_count(items.len())];
            assert_eq!(sums.len(), 3);
            for_each_part(&mut items, &mut sums, |p, items, state| {
                *state = (p, items.iter().sum());
                items.iter_mut().for_each(|i| *i *= 2);
            });
            assert_eq!(sums, vec![(0, 6), (1, 15), (2, 24)]);
            assert_eq!(items, (0..10).map(|i| 2 * i).collect::<Vec<_>>());
        });
    }

    #[test]
    fn add_parts_adds_every_part() {
        let n = 40_000;
        let mut target: Vec<f64> = (0..n).map(|k| k as f64).collect();
        let a: Vec<f64> = vec![0.5; n];
        let b: Vec<f64> = (0..n).map(|k| -(k as f64)).collect();
        add_parts(&mut target, &[&a, &b]);
        assert!(target.iter().all(|&t| t == 0.5));
    }
}
