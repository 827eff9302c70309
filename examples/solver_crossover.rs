//! Benchmark: where the iterative backend overtakes the direct one. The self-weight block
//! (`scripts/block_2d_self_weight.rhai`, `scripts/cube_self_weight.rhai`: B-spline q = 2, 2
//! points per cell and direction, one load step) at growing sizes, each solved by the direct
//! backend (faer Cholesky), CG with Jacobi and CG with multigrid, in the same process; per run
//! the DOFs, Newton iterations, Krylov iterations per Newton iteration, and the seconds of the
//! linear solves and of the whole step.
//!
//!   cargo run --release --example solver_crossover [-- 2d 16,32,64 3d 4,8,12]
//!
//! Results are recorded in docs/performance.md ("Linear solvers").

use std::path::Path;

use impm::resources::Stage;
use impm::run::{load_scene, run_scene};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut plan: Vec<(usize, Vec<usize>)> = Vec::new();
    for pair in args.chunks(2) {
        let dim = if pair[0] == "3d" { 3 } else { 2 };
        let sizes = pair
            .get(1)
            .map(|list| list.split(',').filter_map(|s| s.parse().ok()).collect())
            .unwrap_or_default();
        plan.push((dim, sizes));
    }
    if plan.is_empty() {
        plan = vec![(2, vec![16, 32, 64, 128]), (3, vec![4, 8, 12, 16])];
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let backends: [(&str, &[(&str, &str)]); 3] = [
        ("direct", &[("linear", "direct")]),
        ("cg+jacobi", &[("preconditioner", "jacobi")]),
        ("cg+multigrid", &[("preconditioner", "multigrid")]),
    ];
    println!(
        "{:>3} {:>5} {:>8} {:>13} {:>6} {:>16} {:>10} {:>9}",
        "dim", "cells", "dofs", "backend", "newton", "krylov sum (max)", "solve s", "step s"
    );
    for (dim, sizes) in plan {
        let script = if dim == 2 {
            "block_2d_self_weight.rhai"
        } else {
            "cube_self_weight.rhai"
        };
        for cells in sizes {
            for (name, set) in backends {
                let mut overrides = vec![("cells".to_string(), cells.to_string())];
                overrides.extend(set.iter().map(|(k, v)| (k.to_string(), v.to_string())));
                let spec = load_scene(&root.join("scripts").join(script), &overrides)
                    .unwrap_or_else(|e| panic!("{e}"));
                let out = std::env::temp_dir().join(format!(
                    "impm-crossover-{dim}d-{cells}-{name}-{}",
                    std::process::id()
                ));
                let summary = run_scene(&spec, &out, |_| {}).unwrap_or_else(|e| panic!("{e}"));
                let _ = std::fs::remove_dir_all(&out);
                let step = summary.steps.last().expect("one load step");
                let krylov = step
                    .linear_iterations
                    .iter()
                    .max()
                    .map_or("-".to_string(), |m| {
                        format!("{} ({m})", step.linear_iterations.iter().sum::<usize>())
                    });
                println!(
                    "{:>3} {:>5} {:>8} {:>13} {:>6} {:>16} {:>10.3} {:>9.3}",
                    dim,
                    cells,
                    step.dofs,
                    name,
                    step.iterations,
                    krylov,
                    step.seconds.get(Stage::LinearSolve).as_secs_f64(),
                    step.wall_seconds
                );
            }
        }
    }
}
