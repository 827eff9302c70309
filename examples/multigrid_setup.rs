//! Where multigrid's time goes, on the tangent of one self-weight block: the hierarchy (levels,
//! rows and non-zeros, grid and operator complexity), the seconds of the setup and of the
//! whole CG solve, and the CG iterations, for box aggregates of several widths, against CG with
//! Jacobi and the direct solve of the same system. Then the whole load step (its Newton
//! iterations) with each backend: the direct solve, CG with Jacobi, and CG with multigrid
//! rebuilt from every tangent or kept for the step (`Multigrid::keep_hierarchy`): Krylov
//! iterations per Newton iteration, seconds of the linear solves and of the step.
//!
//! ```text
//! cargo run --release --example multigrid_setup [-- 3:11,16 2:200 --widths 3,4 \
//!     --smoothers gs,cheb2 --threads 1,2]
//! ```
//!
//! `D:cells,..` are the blocks (`scripts/block_2d_self_weight.rhai`,
//! `scripts/cube_self_weight.rhai`, B-spline q = 2, 2^D points per cell: 3D 11 cells a side is
//! 10 648 points, 16 is 32 768; 2D 200 is 160 000). The tangent is the one of the block's only
//! load step after its Newton iterations (direct backend); the right-hand side is smooth.
//! `--smoothers` lists multigrid's smoothers (`gs`: Gauss–Seidel, `chebK`: Chebyshev of degree
//! K; default `gs`), `--threads` the thread counts every study runs on (default: rayon's).
//! Timings are single runs: on a shared machine, say so next to them.

use std::path::Path;
use std::time::Instant;

use impm::resources::{Newton, Stage};
use impm::run::{Simulation, load_scene};
use impm::scene::LinearBackend;
use impm::solver::{
    DirectSolver, KrylovSolver, LinearSolver, Multigrid, Preconditioner, Smoother, SparseMatrix,
};

/// A smoother's name on the command line and in the output.
fn smoother_name(smoother: Smoother) -> String {
    match smoother {
        Smoother::GaussSeidel => "gs".into(),
        Smoother::Chebyshev(degree) => format!("cheb{degree}"),
    }
}

fn parse_smoother(name: &str) -> Smoother {
    match name.strip_prefix("cheb") {
        Some(degree) => Smoother::Chebyshev(
            degree
                .parse()
                .unwrap_or_else(|_| panic!("chebK: K a degree, got {name}")),
        ),
        None if name == "gs" => Smoother::GaussSeidel,
        None => panic!("unknown smoother {name}: gs or chebK"),
    }
}

/// The block's load step solved by `solver` (the direct solve if `None`): the simulation after
/// it and its wall seconds.
fn step<const D: usize>(
    cells: usize,
    solver: Option<Box<dyn LinearSolver>>,
) -> (Simulation<D>, f64) {
    let script = if D == 2 {
        "block_2d_self_weight.rhai"
    } else {
        "cube_self_weight.rhai"
    };
    let scene = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts")
        .join(script);
    let set = [("cells".to_string(), cells.to_string())];
    let mut spec = load_scene(&scene, &set).unwrap_or_else(|e| panic!("{e}"));
    spec.solver.linear = LinearBackend::Direct;
    let out = std::env::temp_dir().join(format!("impm-mg-setup-{}", std::process::id()));
    let mut sim = Simulation::<D>::new(&spec, &out).unwrap_or_else(|e| panic!("{e}"));
    if let Some(solver) = solver {
        sim.world.resource_mut::<Newton>().solver = solver;
    }
    let started = Instant::now();
    sim.run(|_| {}).unwrap_or_else(|e| panic!("{e}"));
    let seconds = started.elapsed().as_secs_f64();
    let _ = std::fs::remove_dir_all(&out);
    (sim, seconds)
}

/// The tangent of the block's last Newton iteration.
fn tangent<const D: usize>(cells: usize) -> SparseMatrix {
    step::<D>(cells, None)
        .0
        .world
        .resource::<Newton>()
        .matrix
        .clone()
}

/// The load step with each backend (see the module docs).
fn steps<const D: usize>(cells: usize, widths: &[usize], smoothers: &[Smoother]) {
    let mut backends: Vec<(String, Option<Box<dyn LinearSolver>>)> = vec![
        ("direct".into(), None),
        ("cg+jacobi".into(), Some(Box::new(KrylovSolver::default()))),
    ];
    for &width in widths {
        for &smoother in smoothers {
            for keep in [false, true] {
                let mut multigrid = Multigrid::default();
                multigrid.aggregate_width = width;
                multigrid.keep_hierarchy = keep;
                multigrid.smoother = smoother;
                let name = format!(
                    "cg+multigrid boxes of {width}, {}, {}",
                    smoother_name(smoother),
                    if keep { "kept for the step" } else { "rebuilt" }
                );
                let solver = KrylovSolver::with_preconditioner(Box::new(multigrid));
                backends.push((name, Some(Box::new(solver))));
            }
        }
    }
    for (name, solver) in backends {
        let (sim, seconds) = step::<D>(cells, solver);
        let record = &sim.summary.steps[0];
        // the blocks have no reference answer of their own
        let error = record
            .error
            .map_or("n/a".to_string(), |e| format!("{e:.3e}"));
        println!(
            "  step, {name}: {seconds:.3} s, linear solves {:.3} s, {} Newton iterations, \
             Krylov iterations {:?}, error {error}",
            record.seconds.get(Stage::LinearSolve).as_secs_f64(),
            record.iterations,
            record.linear_iterations,
        );
    }
}

fn study(dim: usize, cells: usize, widths: &[usize], smoothers: &[Smoother]) {
    let matrix = match dim {
        2 => tangent::<2>(cells),
        _ => tangent::<3>(cells),
    };
    let n = matrix.size();
    let rhs: Vec<f64> = (0..n).map(|i| (0.001 * i as f64).sin() + 0.5).collect();
    println!(
        "{dim}D block, {cells} cells a side: {n} DOFs, {} non-zeros",
        matrix.nonzeros()
    );
    let timed = |solver: &mut dyn LinearSolver| {
        let mut x = rhs.clone();
        let started = Instant::now();
        solver
            .solve(&matrix, true, &mut x)
            .unwrap_or_else(|e| panic!("{e}"));
        started.elapsed().as_secs_f64()
    };
    let seconds = timed(&mut DirectSolver::default());
    println!("  direct: {seconds:.3} s");
    let mut jacobi = KrylovSolver::default();
    let seconds = timed(&mut jacobi);
    println!(
        "  cg+jacobi: {seconds:.3} s, {} iterations",
        jacobi.last_iterations
    );
    for (&width, &smoother) in widths
        .iter()
        .flat_map(|w| smoothers.iter().map(move |s| (w, s)))
    {
        let multigrid = || {
            let mut multigrid = Multigrid::default();
            multigrid.aggregate_width = width;
            multigrid.smoother = smoother;
            multigrid
        };
        let mut alone = multigrid();
        let started = Instant::now();
        alone.setup(&matrix, true).unwrap_or_else(|e| panic!("{e}"));
        let first = started.elapsed().as_secs_f64();
        let started = Instant::now();
        alone.setup(&matrix, true).unwrap_or_else(|e| panic!("{e}"));
        let again = started.elapsed().as_secs_f64();
        let mut solver = KrylovSolver::with_preconditioner(Box::new(multigrid()));
        let seconds = timed(&mut solver);
        println!(
            "  cg+multigrid, boxes of {width}, {}: setup {first:.3} s (same pattern again \
             {again:.3} s), solve with setup {seconds:.3} s, {} iterations; {}",
            smoother_name(smoother),
            solver.last_iterations,
            alone.hierarchy().map(|h| h.to_string()).unwrap_or_default()
        );
    }
    match dim {
        2 => steps::<2>(cells, widths, smoothers),
        _ => steps::<3>(cells, widths, smoothers),
    }
}

fn main() {
    let mut cases: Vec<(usize, Vec<usize>)> = Vec::new();
    let mut widths = vec![4];
    let mut smoothers = vec![Smoother::GaussSeidel];
    let mut threads = vec![rayon::current_num_threads()];
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let list = |text: &str| -> Vec<usize> {
            text.split(',')
                .map(|v| v.parse().unwrap_or_else(|_| panic!("not a number: {v}")))
                .collect()
        };
        if arg == "--widths" {
            widths = list(&args.next().expect("--widths 2,3"));
        } else if arg == "--threads" {
            threads = list(&args.next().expect("--threads 1,2"));
        } else if arg == "--smoothers" {
            let names = args.next().expect("--smoothers gs,cheb2");
            smoothers = names.split(',').map(parse_smoother).collect();
        } else if let Some((dim, sizes)) = arg.split_once(':') {
            cases.push((dim.parse().expect("dimension 2 or 3"), list(sizes)));
        } else {
            panic!(
                "unknown argument {arg}: D:cells,.., --widths w,.., --smoothers gs,chebK,.. or \
                 --threads n,.."
            );
        }
    }
    if cases.is_empty() {
        cases = vec![(3, vec![11, 16]), (2, vec![200])];
    }
    for &count in &threads {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(count)
            .build()
            .unwrap_or_else(|e| panic!("{count} threads: {e}"));
        println!("--- {count} thread(s) ---");
        for (dim, sizes) in &cases {
            for &cells in sizes {
                pool.install(|| study(*dim, cells, &widths, &smoothers));
            }
        }
    }
}
