//! Benchmark: what the systems of unused effects would cost if they were always scheduled.
//!
//! impm builds each scene's world from the modules the scene uses (`Plugin::used_by`), so a
//! scene without point loads, tractions or prescribed displacements runs none of their systems.
//! This program measures what that saves on one scene, honestly: the same world is run with
//!
//! * A, "scene": the schedules built for the scene (what `impm run` does), and
//! * B, "all":   the world built with every load module too (body force, point loads,
//!   tractions, prescribed displacements): the systems of the unused ones are registered and run
//!   every step, with nothing to do (no point carries a point load, there are no traction
//!   points, every prescribed value is zero, an unused body force is zero but still spread from
//!   every point). The other optional effects (ghost penalty, stress recovery) do real work
//!   whenever they are scheduled, so "registered but idle" has no meaning for them.
//!
//! Rounds alternate A and B (A B A B ...) on fresh simulations, to spread drift of the machine
//! evenly; each round runs every load step of the scene with output switched off (file writing
//! would drown the difference in disk noise). Printed per variant: the median and the spread
//! (min..max) of the wall time of the run, and the median of the time spent in the external
//! force stage (the stage where the optional load systems run, `StageClock`).
//!
//!   cargo run --release --example effects_cost -- scripts/column_2d.rhai --rounds 9
//!
//! Arguments: SCENE [--rounds N] [--set NAME=VALUE]... Results are recorded in
//! docs/effects.md.

use std::path::{Path, PathBuf};
use std::time::Instant;

use impm::effects::{self, body_force::BodyForce};
use impm::explain::explain_scene;
use impm::plugin::Module;
use impm::resources::Stage;
use impm::run::Simulation;
use impm::run::load_scene;
use impm::scene::SceneSpec;
use impm::stages::output::OutputPlan;
use nalgebra::SVector;

/// The modules of the loads: what variant B adds when the scene does not use them.
const LOAD_MODULES: [&str; 4] = [
    "body force",
    "point loads",
    "tractions",
    "prescribed displacements",
];

/// One timed run: wall seconds of all load steps, seconds in the loads stage. `all_loads`:
/// variant B.
fn run_once<const D: usize>(spec: &SceneSpec, all_loads: bool, out: &Path) -> (f64, f64) {
    let modules = effects::built_in();
    let include = |module: &dyn Module| {
        module.used_by(spec) || (all_loads && LOAD_MODULES.contains(&module.name()))
    };
    let mut sim = Simulation::<D>::with_modules_where(spec, out, &modules, &include)
        .expect("the scene builds");
    if all_loads && !sim.world.contains_resource::<BodyForce<D>>() {
        // an idle body force: zero, but applied to every point every step
        sim.world
            .insert_resource(BodyForce(SVector::<f64, D>::zeros()));
    }
    // no output at all: no step is in the list of written steps
    sim.world.resource_mut::<OutputPlan>().steps = Some(Vec::new());
    let start = Instant::now();
    let mut loads = 0.0;
    sim.run(|record| loads += record.seconds.get(Stage::Loads).as_secs_f64())
        .expect("the scene runs");
    (start.elapsed().as_secs_f64(), loads)
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    }
}

fn main() -> Result<(), String> {
    let usage = "usage: effects_cost SCENE [--rounds N] [--set NAME=VALUE]...";
    let mut args = std::env::args().skip(1);
    let scene = PathBuf::from(args.next().ok_or(usage)?);
    let (mut rounds, mut overrides) = (7usize, Vec::new());
    while let Some(flag) = args.next() {
        let value = args.next().ok_or(usage)?;
        match flag.as_str() {
            "--rounds" => rounds = value.parse().map_err(|e| format!("--rounds: {e}"))?,
            "--set" => {
                let (name, value) = value.split_once('=').ok_or(usage)?;
                overrides.push((name.to_string(), value.to_string()));
            }
            _ => return Err(usage.into()),
        }
    }
    let spec = load_scene(&scene, &overrides).map_err(|e| e.to_string())?;
    let modules = effects::built_in();
    let unused: Vec<&str> = modules
        .iter()
        .filter(|m| LOAD_MODULES.contains(&m.name()) && !m.used_by(&spec))
        .map(|m| m.name())
        .collect();
    let load_systems = [
        "body_force::",
        "point_loads::apply",
        "tractions::",
        "prescribed",
    ];
    let left_out: Vec<_> = explain_scene(&spec, &modules)?
        .left_out
        .into_iter()
        .filter(|system| load_systems.iter().any(|s| system.name.contains(s)))
        .collect();
    println!(
        "scene {}: {}D, {} points, {} load steps; unused effects: {}",
        spec.name,
        spec.dim(),
        spec.point_count(),
        spec.load_factors.len(),
        unused.join(", ")
    );
    println!("systems B runs and A does not:");
    for system in &left_out {
        println!("  {} ({})", system.name, system.schedule);
    }
    let out = std::env::temp_dir().join(format!("impm-effects-cost-{}", std::process::id()));
    let run: fn(&SceneSpec, bool, &Path) -> (f64, f64) = match spec.dim() {
        1 => run_once::<1>,
        2 => run_once::<2>,
        3 => run_once::<3>,
        d => return Err(format!("dimension {d}")),
    };
    run(&spec, false, &out); // warm-up (page faults, allocator)
    let (mut wall_a, mut wall_b, mut loads_a, mut loads_b) = (vec![], vec![], vec![], vec![]);
    for _ in 0..rounds {
        let (wall, loads) = run(&spec, false, &out);
        wall_a.push(wall);
        loads_a.push(loads);
        let (wall, loads) = run(&spec, true, &out);
        wall_b.push(wall);
        loads_b.push(loads);
    }
    let _ = std::fs::remove_dir_all(&out);
    let spread = |v: &[f64]| {
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
                (lo.min(x), hi.max(x))
            });
        (lo, hi)
    };
    let (a_lo, a_hi) = spread(&wall_a);
    let (b_lo, b_hi) = spread(&wall_b);
    let (wa, wb) = (median(&mut wall_a), median(&mut wall_b));
    let (la, lb) = (median(&mut loads_a), median(&mut loads_b));
    println!("{rounds} rounds, alternating; wall time of all load steps, output off:");
    println!(
        "  A scene schedules:   median {:8.4} s  (min {:.4}, max {:.4})  loads stage {:.6} s",
        wa, a_lo, a_hi, la
    );
    println!(
        "  B all load effects:  median {:8.4} s  (min {:.4}, max {:.4})  loads stage {:.6} s",
        wb, b_lo, b_hi, lb
    );
    println!(
        "  B - A: {:+.4} s ({:+.2} % of A); spread of A: {:.2} %; idle systems in B: {:.6} s",
        wb - wa,
        100.0 * (wb - wa) / wa,
        100.0 * (a_hi - a_lo) / wa,
        lb - la
    );
    Ok(())
}
