//! Benchmark: seconds per solver stage for the self-weight column in 1D, 2D and 3D, with the
//! same discretisation along the column, and the ratio of each run's total to the 1D run in the
//! same process. The 2D/3D columns are one cell wide, so their extra cost is the price of the
//! dimension itself (tensor-product supports: (q+1)^D nodes per point, D x D blocks).
//!
//!   cargo run --release --example bench_stages [-- CELLS ORDER]
//!
//! Results are recorded in docs/performance.md.

use std::path::Path;

use impm::resources::Stage;
use impm::run::load_scene;
use impm::run::run_scene;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let cells = args.get(1).cloned().unwrap_or_else(|| "50".into());
    let order = args.get(2).cloned().unwrap_or_else(|| "3".into());
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    println!(
        "column, {cells} cells, B-spline q = {order}, 4 points per cell per direction, 20 steps"
    );
    println!(
        "{:>4} {:>7} {:>6} {:>6} | {}| {:>8} {:>8}",
        "dim",
        "points",
        "dofs",
        "iters",
        Stage::ALL
            .iter()
            .map(|s| format!("{:>13} ", s.name()))
            .collect::<String>(),
        "total s",
        "vs 1D"
    );
    let mut baseline = None;
    for (dim, script) in [
        (1, "column_1d.rhai"),
        (2, "column_2d.rhai"),
        (3, "column_3d.rhai"),
    ] {
        let set = vec![
            ("cells".to_string(), cells.clone()),
            ("order".to_string(), order.clone()),
        ];
        let spec =
            load_scene(&root.join("scripts").join(script), &set).unwrap_or_else(|e| panic!("{e}"));
        let out = std::env::temp_dir().join(format!("impm-bench-{dim}d-{}", std::process::id()));
        let summary = run_scene(&spec, &out, |_| {}).unwrap_or_else(|e| panic!("{e}"));
        let _ = std::fs::remove_dir_all(&out);
        let (stages, total) = summary.total_seconds();
        let base = *baseline.get_or_insert(total);
        println!(
            "{:>4} {:>7} {:>6} {:>6} | {}| {:>8.3} {:>7.1}x",
            dim,
            summary.points,
            summary.steps.last().map_or(0, |s| s.dofs),
            summary.total_iterations(),
            Stage::ALL
                .iter()
                .map(|&s| format!("{:>13.4} ", stages.get(s).as_secs_f64()))
                .collect::<String>(),
            total,
            total / base
        );
    }
}
