//! Threads (`src/parallel.rs`): a run on two threads equals the run on one to round-off (the
//! sums over points are added in another order), and repeated runs on two threads are
//! bit-identical (the points are cut into parts by count, and the parts' sums added in order).
//! Checked on the paper's 2D column (against its eq. 15 error too), on a 3D block and on a 2D
//! block solved iteratively (CG with multigrid on the threads); `impm run --threads N` records
//! N in summary.json.

mod common;

use common::{impm, overrides, shipped_scene, temp_dir};
use impm::components::{PointId, Position, Trial};
use impm::run::{Simulation, load_scene};

/// A point's id, position and Cauchy stress after the run.
type PointState = (u32, Vec<f64>, Vec<f64>);

/// Every point's state after the run, by point id, and the run's figures.
struct Outcome {
    iterations: Vec<usize>,
    error: Option<f64>,
    threads: usize,
    points: Vec<PointState>,
}

fn run<const D: usize>(script: &str, set: &[(&str, &str)], threads: usize) -> Outcome {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let spec = load_scene(&shipped_scene(script), &overrides(set)).unwrap();
        let dir = temp_dir("threads", &format!("{script}-{threads}"));
        let mut sim = Simulation::<D>::new(&spec, &dir).unwrap();
        sim.run(|_| {})
            .unwrap_or_else(|e| panic!("{script} on {threads} threads: {e}"));
        let _ = std::fs::remove_dir_all(&dir);
        let mut query = sim.world.query::<(&PointId, &Position<D>, &Trial<D>)>();
        let mut points: Vec<_> = query
            .iter(&sim.world)
            .map(|(id, x, t)| {
                let x = x.0.iter().copied().collect();
                let stress = t.0.cauchy().iter().copied().collect();
                (id.0, x, stress)
            })
            .collect();
        points.sort_by_key(|p| p.0);
        Outcome {
            iterations: sim.summary.steps.iter().map(|s| s.iterations).collect(),
            error: sim.summary.final_error(),
            threads: sim.summary.threads,
            points,
        }
    })
}

/// Largest difference of positions (relative to the largest coordinate) and of stresses
/// (relative to the largest stress component) between two runs of the same scene.
fn difference(a: &Outcome, b: &Outcome) -> (f64, f64) {
    assert_eq!(a.points.len(), b.points.len());
    let largest = |pick: fn(&PointState) -> &Vec<f64>| {
        b.points
            .iter()
            .flat_map(|p| pick(p).iter())
            .fold(0.0f64, |m, v| m.max(v.abs()))
    };
    let (x_scale, s_scale) = (largest(|p| &p.1), largest(|p| &p.2));
    let mut worst = (0.0f64, 0.0f64);
    for (p, q) in a.points.iter().zip(&b.points) {
        assert_eq!(p.0, q.0);
        for (u, v) in p.1.iter().zip(&q.1) {
            worst.0 = worst.0.max((u - v).abs() / x_scale);
        }
        for (u, v) in p.2.iter().zip(&q.2) {
            worst.1 = worst.1.max((u - v).abs() / s_scale);
        }
    }
    worst
}

fn bits(o: &Outcome) -> Vec<u64> {
    o.points
        .iter()
        .flat_map(|p| p.1.iter().chain(&p.2))
        .map(|v| v.to_bits())
        .collect()
}

/// Round-off tolerance across thread counts: the Newton iterates differ by the summation order
/// of the internal force and tangent (~1e-16 relative per sum), and the converged states by that
/// amplified through a few solves; 1e-12 of the largest value (2.4e-14 measured on the column) leaves room for the conditioning
/// while failing for any real difference (a point missed or counted twice changes the stress
/// at the percent level).
const ACROSS_THREADS: f64 = 1e-12;

fn check<const D: usize>(name: &str, script: &str, set: &[(&str, &str)]) {
    let one = run::<D>(script, set, 1);
    let two = run::<D>(script, set, 2);
    let again = run::<D>(script, set, 2);
    let (dx, ds) = difference(&two, &one);
    eprintln!(
        "{name}: {} points, iterations {:?} (1 thread) {:?} (2), position difference {dx:.1e}, \
         stress difference {ds:.1e}, eq. 15 error {:?} / {:?}",
        one.points.len(),
        one.iterations,
        two.iterations,
        one.error,
        two.error
    );
    assert_eq!((one.threads, two.threads), (1, 2));
    assert_eq!(two.iterations, one.iterations);
    assert!(
        dx <= ACROSS_THREADS && ds <= ACROSS_THREADS,
        "{dx:e} {ds:e}"
    );
    if let (Some(a), Some(b)) = (one.error, two.error) {
        assert!((a - b).abs() <= 1e-8 * a, "{a:e} {b:e}");
    }
    assert!(
        bits(&two) == bits(&again),
        "{name}: two runs on 2 threads differ"
    );
}

#[test]
fn the_2d_column_on_two_threads_equals_one_thread_to_round_off_and_repeats_bit_for_bit() {
    check::<2>(
        "column 2D",
        "column_2d.rhai",
        &[("cells", "16"), ("order", "2"), ("steps", "4")],
    );
}

#[test]
fn a_3d_block_on_two_threads_equals_one_thread_to_round_off_and_repeats_bit_for_bit() {
    check::<3>(
        "block 3D",
        "block_3d.rhai",
        &[("cells", "4"), ("steps", "3")],
    );
}

/// The linear solve on the threads (`solver::vectors`: the Krylov loop's products, dot
/// products and updates, multigrid's cycle): a block large enough (18.6k DOFs) that the solver's
/// loops are cut into parts, solved by CG with multigrid.
#[test]
fn iterative_solves_on_two_threads_equal_one_thread_to_round_off_and_repeat_bit_for_bit() {
    check::<2>(
        "block 2D, CG + multigrid",
        "block_2d_self_weight.rhai",
        &[("cells", "96"), ("linear", "iterative")],
    );
}

#[test]
fn the_threads_option_is_recorded_in_the_summary() {
    let out = temp_dir("threads", "cli");
    let out_arg = out.display().to_string();
    let scene = shipped_scene("column_1d.rhai").display().to_string();
    let run = impm(&[
        "run",
        &scene,
        "--out",
        &out_arg,
        "--threads",
        "2",
        "--set",
        "cells=4",
        "--set",
        "steps=2",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["threads"], 2);
    let _ = std::fs::remove_dir_all(&out);
    let zero = impm(&["run", &scene, "--threads", "0"]);
    assert!(!zero.status.success());
    assert!(String::from_utf8_lossy(&zero.stderr).contains("--threads"));
}
