//! Threads (`src/parallel.rs`): a run on two threads equals the run on one bit for bit (the
//! assembly adds every entry's terms in the colouring's order, `src/colouring.rs`; the stress
//! update and the basis are per point; the linear solves cut their loops the same way for both
//! counts at these sizes), and so do repeated runs on two threads. (A grid fewer than 4 slabs of
//! supports high, `colouring::MIN_SLABS`, is assembled by copies per thread: equal to round-off
//! across counts.) Checked on the paper's 2D
//! column (with its eq. 15 error), on a 3D block and on a 2D block solved iteratively (CG with
//! multigrid on the threads): every point's position and Cauchy stress after the run. At the
//! assembly itself: the internal force and every tangent value on 1, 2 and 3 threads, for
//! linear, B-spline (q = 2, 3), GIMP and 3D. `impm run --threads N` records N in summary.json.

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

/// `work` on a pool of `threads` threads, every stage cut into one part per thread however few
/// its points (the grain set to 1 for the whole binary: the scenes here are small).
fn on_threads<R: Send>(threads: usize, work: impl FnOnce() -> R + Send) -> R {
    impm::parallel::set_grain(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(work)
}

/// The simulation of a shipped scene with overrides, and its (not yet written) output folder.
fn simulation<const D: usize>(
    script: &str,
    set: &[(&str, &str)],
    threads: usize,
) -> (Simulation<D>, std::path::PathBuf) {
    let spec = load_scene(&shipped_scene(script), &overrides(set)).unwrap();
    let dir = temp_dir("threads", &format!("{script}-{threads}"));
    (Simulation::<D>::new(&spec, &dir).unwrap(), dir)
}

fn run<const D: usize>(script: &str, set: &[(&str, &str)], threads: usize) -> Outcome {
    on_threads(threads, || {
        let (mut sim, dir) = simulation::<D>(script, set, threads);
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
        bits(&two) == bits(&one),
        "{name}: 2 threads differ from 1 (position {dx:e}, stress {ds:e} of the largest)"
    );
    assert_eq!(one.error.map(f64::to_bits), two.error.map(f64::to_bits));
    assert!(
        bits(&two) == bits(&again),
        "{name}: two runs on 2 threads differ"
    );
}

#[test]
fn the_2d_column_on_two_threads_equals_one_thread_bit_for_bit_and_repeats() {
    check::<2>(
        "column 2D",
        "column_2d.rhai",
        &[("cells", "16"), ("order", "2"), ("steps", "4")],
    );
}

#[test]
fn a_3d_block_on_two_threads_equals_one_thread_bit_for_bit_and_repeats() {
    check::<3>(
        "block 3D",
        "block_3d.rhai",
        // 8 cells high: 4 slabs, the fewest the colouring takes (`colouring::MIN_SLABS`).
        &[("cells", "8"), ("steps", "3")],
    );
}

/// The linear solve on the threads (`solver::vectors`: the Krylov loop's products, dot
/// products and updates, multigrid's cycle): a block large enough (18.6k DOFs) that the solver's
/// loops are cut into parts, solved by CG with multigrid.
#[test]
fn iterative_solves_on_two_threads_equal_one_thread_bit_for_bit_and_repeat() {
    check::<2>(
        "block 2D, CG + multigrid",
        "block_2d_self_weight.rhai",
        &[("cells", "96"), ("linear", "iterative")],
    );
}

/// The colouring is made once per load step and kept through the step's Newton iterations
/// (`stages::ColouringCache`, keyed on the pattern's generation): on the 2D column (4 steps, 2
/// threads) it is made 4 times, once after each grid reset, and reused in every other assembly;
/// the run is bit-identical to one that colours every assembly anew, and the colouring left
/// in the cache equals the one made from the last step's supports.
#[test]
fn the_colouring_is_made_once_per_load_step_and_the_run_is_unchanged() {
    use impm::components::Support;
    use impm::resources::Grid;
    use impm::stages::ColouringCache;
    let set = [("cells", "16"), ("order", "2"), ("steps", "4")];
    let outcome = |recolour: bool| {
        on_threads(2, || {
            let (mut sim, dir) = simulation::<2>("column_2d.rhai", &set, 2);
            sim.world
                .resource_mut::<ColouringCache>()
                .recolour_every_assembly = recolour;
            sim.run(|_| {}).unwrap();
            let _ = std::fs::remove_dir_all(&dir);
            let mut query = sim.world.query::<(&PointId, &Position<2>, &Trial<2>)>();
            let mut state: Vec<(u32, Vec<u64>)> = query
                .iter(&sim.world)
                .map(|(id, x, t)| {
                    let stress = t.0.cauchy();
                    let values = x.0.iter().chain(stress.iter());
                    (id.0, values.map(|v| v.to_bits()).collect())
                })
                .collect();
            state.sort_by_key(|p| p.0);
            let sizes = sim.world.resource::<Grid<2>>().0.nodes_per_axis();
            let supports: Vec<Vec<usize>> = sim
                .world
                .query::<&Support<2>>()
                .iter(&sim.world)
                .map(|s| s.0.iter().map(|w| w.node).collect())
                .collect();
            let fresh = impm::colouring::colour_points(sizes, supports.len(), |p| {
                supports[p].iter().copied()
            });
            let cache = sim.world.resource::<ColouringCache>();
            let counts = (cache.computed, cache.reused);
            assert!(fresh.is_some(), "the column is coloured");
            assert_eq!(
                cache.colouring(),
                fresh.as_ref(),
                "the cached colouring is current"
            );
            (state, counts, sim.summary.steps.len())
        })
    };
    let (cached, (computed, reused), steps) = outcome(false);
    let (fresh, (every, none), _) = outcome(true);
    eprintln!(
        "colouring: cached {computed} made + {reused} reused; recoloured {every} made + {none}"
    );
    assert_eq!(steps, 4);
    assert_eq!(computed, 4, "one colouring per load step");
    assert!(reused >= 4, "reused within the steps: {reused}");
    assert_eq!((every, none), (computed + reused, 0));
    assert!(cached == fresh, "the cached colouring changed the run");
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

/// The internal force and the tangent values (bits, in node and pattern order) after one stress
/// update and assembly on `threads` threads, at a non-uniform increment (a shear, a stretch
/// and a wobble, so that every point's blocks differ); and the colouring's width.
fn assembled<const D: usize>(
    script: &str,
    set: &[(&str, &str)],
    threads: usize,
) -> (Vec<u64>, Vec<u64>, Option<usize>) {
    use bevy_ecs::system::RunSystemOnce;
    use impm::components::Support;
    use impm::resources::{Grid, GridFields, LoadStep, Newton};
    use impm::stages::{assemble, evaluate_basis, number_dofs, update_stress};
    on_threads(threads, || {
        let (mut sim, dir) = simulation::<D>(script, set, threads);
        let _ = std::fs::remove_dir_all(&dir);
        let mut step = sim.world.resource_mut::<LoadStep>();
        (step.number, step.factor) = (1, 1.0);
        sim.world.run_system_once(evaluate_basis::<D>).unwrap();
        sim.world.run_system_once(number_dofs::<D>).unwrap();
        let grid = sim.world.resource::<Grid<D>>().0.clone();
        let mut fields = sim.world.resource_mut::<GridFields<D>>();
        for node in 0..fields.increment.len() {
            let u = &mut fields.increment[node];
            // A shear, a stretch and a wobble: x_0 += 0.1 x_{D-1}, x_k += 0.02 x_k + 0.01 sin(..).
            let x = grid.node_position(node);
            let phase = x
                .iter()
                .enumerate()
                .map(|(k, v)| (1.3 + 0.7 * k as f64) * v);
            let wobble = 0.01 * phase.sum::<f64>().sin();
            *u = x * 0.02 + nalgebra::SVector::<f64, D>::repeat(wobble);
            u[0] += 0.1 * x[D - 1];
        }
        sim.world
            .run_system_once(update_stress::<D, impm::material::Hencky>)
            .unwrap();
        sim.world.run_system_once(assemble::<D>).unwrap();
        let status = sim.world.resource::<impm::resources::RunStatus>();
        assert!(status.0.is_none(), "{:?}", status.0);
        let force = sim.world.resource::<GridFields<D>>().internal_force.clone();
        let force = force.iter().flat_map(|f| f.iter().map(|v| v.to_bits()));
        let values = sim.world.resource::<Newton>().matrix.values().to_vec();
        assert!(values.iter().any(|&v| v != 0.0));
        let sizes = sim.world.resource::<Grid<D>>().0.nodes_per_axis();
        let supports: Vec<Vec<usize>> = sim
            .world
            .query::<&Support<D>>()
            .iter(&sim.world)
            .map(|s| s.0.iter().map(|w| w.node).collect())
            .collect();
        let colouring =
            impm::colouring::colour_points(sizes, supports.len(), |p| supports[p].iter().copied());
        (
            force.collect(),
            values.iter().map(|v| v.to_bits()).collect(),
            colouring.map(|c| c.width),
        )
    })
}

/// The coloured assembly (`src/colouring.rs`): the internal force and every tangent value are
/// bit-identical on 1, 2 and 3 threads, for B-splines of order 1, 2, 3 (the 2D self-weight block
/// on 12 x 12 cells: supports q + 1 nodes wide, slabs of max(q, 1) cells) and a 3D block
/// (q = 2); each case is checked to be coloured, with the width its supports span.
#[test]
fn the_assembled_force_and_tangent_are_bit_identical_on_one_two_and_three_threads() {
    for order in ["1", "2", "3"] {
        let set = [("cells", "12"), ("order", order)];
        let one = assembled::<2>("block_2d_self_weight.rhai", &set, 1);
        let width = order.parse::<usize>().unwrap() + 1;
        assert_eq!(one.2, Some(width), "order {order}");
        for threads in [2, 3] {
            let other = assembled::<2>("block_2d_self_weight.rhai", &set, threads);
            assert!(
                one.0 == other.0,
                "order {order}: internal force, {threads} threads"
            );
            assert!(
                one.1 == other.1,
                "order {order}: tangent, {threads} threads"
            );
        }
        eprintln!(
            "order {order}: {} force components and {} tangent values bit-identical on 1, 2, 3 \
             threads",
            one.0.len(),
            one.1.len()
        );
    }
    let set = [("cells", "8")];
    let one = assembled::<3>("block_3d.rhai", &set, 1);
    assert_eq!(one.2, Some(3));
    let two = assembled::<3>("block_3d.rhai", &set, 2);
    assert!(one.0 == two.0 && one.1 == two.1, "3D block");
}

/// The bases whose supports differ from point to point (GIMP's domains, CPDI's corners) and
/// linear MPM, run on 1 and 2 threads: bit-identical runs (the strip footing; CPDI on the 2D
/// column, whose footing's corners leave the grid in step 2 on any thread count).
#[test]
fn linear_gimp_and_cpdi_runs_are_bit_identical_on_one_and_two_threads() {
    for basis in ["linear", "gimp"] {
        check::<2>(
            &format!("strip footing, {basis}"),
            "strip_footing.rhai",
            &[("basis", basis), ("steps", "2")],
        );
    }
    check::<2>(
        "column 2D, cpdi",
        "column_2d.rhai",
        &[("basis", "cpdi"), ("cells", "16"), ("steps", "3")],
    );
}
