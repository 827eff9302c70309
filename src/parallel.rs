//! Threads over points: the one place where the stages' per-point loops are split across cores.
//!
//! A stage collects its points (query items, in the query's fixed order) into a slice and hands
//! it to [`for_each_part`] with one state per part (its scratch memory and what it returns: a
//! partial sum, the first error). The slice is cut into [`part_count`] contiguous parts, one per
//! thread of the current rayon pool but none with fewer than [`grain`] points, and each part
//! runs on its own state; the stage then combines the states **in part order** ([`add_parts`]
//! for summed arrays). The cut depends only on the number of points, the number of threads and
//! the grain, never on timing, so a run is bit-identical from one repetition to the next for a
//! given thread count. Per-point work without sums (stress update, basis evaluation) is
//! identical for any thread count.
//!
//! **The grain.** Handing a part to another thread and waiting for it costs microseconds on an
//! idle machine and up to milliseconds when the cores are busy, once per stage per Newton
//! iteration; the light per-point kernels cost ~0.4 µs (1D stress update) to ~1 µs (2D cubic
//! assembly) a point. Below [`DEFAULT_GRAIN`] points a part the hand-over would cost more than
//! the second thread saves, so small problems (the paper's 1D and 2D columns) run on the calling
//! thread, as they did before threads existed (`docs/performance.md`, "Small problems"). Tests
//! and benchmarks that compare thread counts on small problems lower it with [`set_grain`].
//!
//! Sums over points into one array (the assembly's internal force and tangent) go through
//! [`for_each_colour`] instead: the points come in the colour order of `crate::colouring`, and
//! the blocks of one colour, which touch disjoint entries, are shared among the threads, colour
//! after colour; every part adds straight into the one array through [`Disjoint`]. No copy per
//! thread, no summing pass, and every entry receives its terms in the colouring's order, so the
//! sums are bit-identical for any thread count. Where the points cannot be coloured the
//! assembly sums per part and adds the parts in order, which agrees across thread counts only
//! to round-off.
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

use std::marker::PhantomData;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

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

/// The fewest points a part is given by default (module docs, "The grain").
pub const DEFAULT_GRAIN: usize = 1024;

static GRAIN: AtomicUsize = AtomicUsize::new(DEFAULT_GRAIN);

/// The fewest items a part is given: [`DEFAULT_GRAIN`] unless [`set_grain`] changed it.
pub fn grain() -> usize {
    GRAIN.load(Ordering::Relaxed)
}

/// Sets the fewest items a part is given, for the whole process (at least 1): tests and
/// benchmarks that compare thread counts on small problems set 1. Set it before a run, not
/// during one (a run's parts would change between its stages' calls).
pub fn set_grain(items: usize) {
    GRAIN.store(items.max(1), Ordering::Relaxed);
}

/// How many parts `n` items are cut into: one per thread, each of at least [`grain`] items
/// (at least one part).
pub fn part_count(n: usize) -> usize {
    parts_for(n, thread_count(), grain())
}

/// Whether `n` items are enough for two parts on some thread count (at least twice the grain):
/// a stage may then choose a different summation order (the assembly's colouring) that must not
/// depend on how many threads there are.
pub fn can_split(n: usize) -> bool {
    n / grain() >= 2
}

/// `threads` parts of `n` items, fewer where a part would hold under `grain` items, at least one.
fn parts_for(n: usize, threads: usize, grain: usize) -> usize {
    threads.min(n / grain.max(1)).max(1)
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
    if target.len() <= CHUNK {
        // One chunk: the same additions in the same order, without the hand-over.
        for part in parts {
            for (t, v) in target.iter_mut().zip(part.iter()) {
                *t += *v;
            }
        }
        return;
    }
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

/// Sets every element of `target` to `value`, in parallel over chunks.
pub fn fill<T: Copy + Send + Sync>(target: &mut [T], value: T) {
    const CHUNK: usize = 1 << 14;
    if target.len() <= CHUNK {
        target.fill(value);
        return;
    }
    target
        .par_chunks_mut(CHUNK)
        .for_each(|chunk| chunk.fill(value));
}

/// Runs `work(items, state)` over the blocks of `items`, colour after colour: colour `c` owns
/// the blocks `colour_start[c]..colour_start[c + 1]`, block `b` the items
/// `block_start[b]..block_start[b + 1]` (as `crate::colouring::Colouring`). A colour's blocks
/// are cut into `states.len()` contiguous runs of about equal item count, never inside a block,
/// and the runs are done in parallel, part `p` with `states[p]`; the next colour starts when
/// all of them are done. With one state everything runs on the calling thread, in order.
pub fn for_each_colour<T: Sync, S: Send>(
    items: &[T],
    block_start: &[usize],
    colour_start: &[usize],
    states: &mut [S],
    work: impl Fn(&[T], &mut S) + Sync,
) {
    for colour in colour_start.windows(2) {
        let blocks = &block_start[colour[0]..=colour[1]];
        let (first, last) = (blocks[0], blocks[blocks.len() - 1]);
        if first == last {
            continue;
        }
        if let [state] = states {
            work(&items[first..last], state);
            continue;
        }
        let parts = states.len();
        let mut cuts = Vec::with_capacity(parts + 1);
        cuts.push(first);
        for p in 1..parts {
            let target = first + (last - first) * p / parts;
            let at = blocks.partition_point(|&start| start < target);
            cuts.push(blocks[at.min(blocks.len() - 1)].max(cuts[p - 1]));
        }
        cuts.push(last);
        cuts.par_windows(2)
            .zip(states.par_iter_mut())
            .for_each(|(range, state)| {
                if range[0] < range[1] {
                    work(&items[range[0]..range[1]], state);
                }
            });
    }
}

/// A slice that several threads update at once, each at entries no other thread touches in the
/// meantime (the blocks of one colour, [`for_each_colour`]). Made from `&mut [T]`, which it
/// borrows for its lifetime; element access is `unsafe` because that promise is the caller's.
pub struct Disjoint<'a, T> {
    start: *mut T,
    len: usize,
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: the wrapper hands out `&mut T` to single elements only, through `update`, whose
// contract forbids two threads to be at one element at once; `T: Send` lets the element be
// written from another thread.
unsafe impl<T: Send> Send for Disjoint<'_, T> {}
// SAFETY: as for `Send`: sharing the wrapper shares no element.
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    pub fn new(slice: &'a mut [T]) -> Self {
        Self {
            start: slice.as_mut_ptr(),
            len: slice.len(),
            _borrow: PhantomData,
        }
    }

    /// The length of the slice.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the slice is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Applies `f` to element `k` (panics when `k` is out of range).
    ///
    /// # Safety
    /// While this runs, no other thread reads or writes element `k` through this wrapper.
    #[inline]
    pub unsafe fn update(&self, k: usize, f: impl FnOnce(&mut T)) {
        assert!(k < self.len, "index {k} out of range {}", self.len);
        // SAFETY: `k` is in range of the borrowed slice, and by the contract no other
        // reference to element `k` is alive while `f` runs.
        f(unsafe { &mut *self.start.add(k) })
    }
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
            let mut sums = vec![(usize::MAX, 0usize); parts_for(items.len(), 3, 1)];
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
    fn parts_hold_at_least_the_grain_and_there_is_at_most_one_per_thread() {
        // (items, threads, grain) -> parts
        for (n, threads, grain, parts) in [
            (0, 2, 1024, 1),
            (200, 2, 1024, 1),
            (2047, 2, 1024, 1),
            (2048, 2, 1024, 2),
            (1_000_000, 2, 1024, 2),
            (3200, 8, 1024, 3),
            (10, 3, 1, 3),
            (2, 3, 1, 2),
            (5, 2, 0, 2),
        ] {
            assert_eq!(parts_for(n, threads, grain), parts, "{n} {threads} {grain}");
        }
    }

    #[test]
    fn add_parts_adds_every_part() {
        // Above and below one chunk (the serial path).
        for n in [40_000, 100] {
            let mut target: Vec<f64> = (0..n).map(|k| k as f64).collect();
            let a: Vec<f64> = vec![0.5; n];
            let b: Vec<f64> = (0..n).map(|k| -(k as f64)).collect();
            add_parts(&mut target, &[&a, &b]);
            assert!(target.iter().all(|&t| t == 0.5));
        }
    }

    #[test]
    fn colours_run_in_order_and_no_block_is_cut() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        // 10 items in 5 blocks ([0,2) [2,3) [3,7) [7,9) [9,10)); colour 0: blocks 0..2,
        // colour 1: none, colour 2: blocks 2..5.
        let block_start = [0, 2, 3, 7, 9, 10];
        let colour_start = [0, 2, 2, 5];
        let items: Vec<usize> = (0..10).collect();
        pool.install(|| {
            let mut seen = vec![Vec::new(); 3];
            let log = std::sync::Mutex::new(Vec::new());
            for_each_colour(
                &items,
                &block_start,
                &colour_start,
                &mut seen,
                |run, state| {
                    state.push(run.to_vec());
                    log.lock().unwrap().push(run.to_vec());
                },
            );
            let mut runs = log.into_inner().unwrap();
            runs.sort();
            for run in &runs {
                assert!(block_start.contains(&run[0]));
                assert!(block_start.contains(&(run[run.len() - 1] + 1)));
            }
            let flat: Vec<usize> = runs.into_iter().flatten().collect();
            assert_eq!(flat, items);
            // Every item of colour 0 came before every item of colour 2 in each part.
            for part in seen {
                let flat: Vec<usize> = part.into_iter().flatten().collect();
                assert!(flat.windows(2).all(|w| w[0] < w[1]), "{flat:?}");
            }
        });
    }

    #[test]
    fn disjoint_updates_from_threads_reach_the_slice() {
        let mut target = vec![0.0f64; 1000];
        let shared = Disjoint::new(&mut target);
        (0..1000usize).into_par_iter().for_each(|k| {
            // SAFETY: every k is visited by one iteration only.
            unsafe { shared.update(k, |v| *v += k as f64) };
        });
        assert!(target.iter().enumerate().all(|(k, &v)| v == k as f64));
    }
}
