//! Arc-length control with held loads (`solver(#{ control: "arc_length" })` beside
//! `held: true` loads; `src/stages/arc_length.rs`, "Held loads"): f_ext = f_fixed + λ f̂, the
//! arc and λ acting on f̂ only. A bar with a held end force traced through its limit on the
//! closed-form curve; a geostatic column (K0 state, weight held) under a top traction against
//! load control at the same load factors and against its closed-form stress; a von Mises
//! footing with its weight held past its limit against Prandtl.

use impm::components::{Position, ReferencePosition, Trial};
use impm::run::Simulation;
use impm::stages::arc_length::ArcLength;

mod common;

fn scene(tag: &str, text: &str) -> Result<impm::scene::SceneSpec, String> {
    common::scene_from_text("arc-length-held-scene", tag, text)
}

/// The bar of `tests/arc_length.rs` (1D FEM, E = 1, ν = 0, fixed at x = 0: λ = ln F / F under
/// a dead end force λ) with a held end force P0 beside the controlled unit force: equilibrium
/// is λ + P0 = ln F / F, the limit λ = 1/e − P0 at F = e.
const HELD_FORCE: f64 = 0.1;

fn held_bar() -> String {
    format!(
        "\
grid(#{{ lower: [0.0], upper: [1.0], cells: [4], basis: \"fem\" }});
const m = material(#{{ name: \"bar\", E: 1.0, nu: 0.0, density: 1.0 }});
body(#{{ name: \"bar\", material: m, region: box([0.0], [1.0]), ppc: 2 }});
fix(|x| x[0] == 0.0, [0]);
point_load_at(#{{ at: [1.0], force: [1.0] }});
point_load_at(#{{ at: [1.0], force: [{HELD_FORCE}], held: true }});
probe(#{{ name: \"end\", at: [1.0] }});
solver(#{{ control: \"arc_length\", target_iterations: 2 }});
load_factors(60, |k| 0.05 * k);
"
    )
}

/// Every converged point on the closed-form curve λ = ln F / F − P0 (to 1e-10: the uniform
/// strain is exact in linear FEM, Newton's tolerance leaves less); each step's increment from
/// the state the first step balanced under the held force alone lies on its arc; the peak is
/// 1/e − P0 to 1e-4 (the steps sample the curve near its flat top) and the load falls past it.
#[test]
fn a_bar_with_a_held_force_is_traced_on_its_closed_form_curve() {
    let spec = scene("bar", &held_bar()).unwrap();
    let dir = common::temp_dir("arc-length-held", "bar");
    let mut sim = Simulation::<1>::new(&spec, &dir).unwrap();
    sim.write_initial_state().unwrap();
    let (mut worst, mut off_arc, mut peak, mut rows) = (0.0f64, 0.0f64, (f64::MIN, 0.0), vec![]);
    while sim.steps_done() < spec.load_factors.len() {
        let record = sim.step().unwrap();
        let (factor, u) = (
            record.load_factor,
            record.measure("end_displacement_x").unwrap(),
        );
        let stretch = 1.0 + u;
        worst = worst.max((factor + HELD_FORCE - stretch.ln() / stretch).abs());
        let arc = sim.world.resource::<ArcLength<1>>();
        off_arc = off_arc.max((arc.increment_norm() - arc.radius).abs() / arc.radius);
        if factor > peak.0 {
            peak = (factor, stretch);
        }
        rows.push((factor, stretch));
    }
    let _ = std::fs::remove_dir_all(&dir);
    let limit = (-1.0f64).exp() - HELD_FORCE;
    let (first, last) = (rows[0], rows[rows.len() - 1]);
    println!(
        "{} steps: first λ = {:.6} at F = {:.5}, peak λ = {:.6} at F = {:.4} (closed form {limit:.6} \
         at e), last λ = {:.5} at F = {:.4}; max |λ + P0 − ln F/F| {worst:.1e}, max \
         |‖Δu − Δu_c‖ − Δl| / Δl {off_arc:.1e}; warnings {:?}",
        rows.len(),
        first.0,
        first.1,
        peak.0,
        peak.1,
        last.0,
        last.1,
        sim.summary.warnings
    );
    assert!(worst < 1e-10, "{worst:e}");
    assert!(off_arc < 1e-12, "{off_arc:e}");
    assert!((peak.0 - limit).abs() < 1e-4, "{peak:?}");
    assert!(last.0 < peak.0 - 0.01 && last.1 > std::f64::consts::E);
    // the held force alone stretches the bar to ln F / F = P0 (F = 1.1183) before the arc: the
    // first step's load factor is the arc's, above zero
    assert!(first.0 > 0.0 && first.1 > 1.118, "{first:?}");
    assert!(
        sim.summary.warnings.is_empty(),
        "{:?}",
        sim.summary.warnings
    );
}

/// A plane-strain column 1 wide and H = 10 high (the column of `tests/geostatic.rs`: quadratic
/// B-splines, 1 × 10 cells, 3 × 3 Gauss points per cell, rollers on the sides, base fixed,
/// von Mises with σ_y = 1000: elastic here) in its K0 state with its weight held (γ = 20), a
/// traction of `Q` per unit load factor on its top; `control` is the solver's options,
/// `schedule` the load schedule.
const Q: f64 = 20.0;

fn column(control: &str, schedule: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 11.0], cells: [1, 11], basis: \"bspline\", order: 2 }});\n\
         const soil = material(#{{ name: \"soil\", model: \"von_mises\", sigma_y: 1000.0, E: 1.0e4, nu: 0.3, density: 2.0 }});\n\
         body(#{{ name: \"column\", material: soil, region: box([0.0, 0.0], [1.0, 10.0]), ppc: 3, placement: \"gauss\" }});\n\
         body_force([0.0, -10.0], #{{ held: true }});\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         initial_stress(#{{ K0: 0.6, unit_weight: 20.0, surface: 10.0 }});\n\
         traction(#{{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -{Q}], per_cell: 4 }});\n\
         solver(#{{ tolerance: 1e-10, linear: \"direct\"{control} }});\n\
         {schedule};\n"
    )
}

/// Every point's position, in point order (by reference position).
fn positions(sim: &mut Simulation<2>) -> Vec<[f64; 2]> {
    let mut query = sim.world.query::<(&ReferencePosition<2>, &Position<2>)>();
    let mut rows: Vec<_> = query
        .iter(&sim.world)
        .map(|(x, p)| ([x.0[0], x.0[1]], [p.0[0], p.0[1]]))
        .collect();
    rows.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
    rows.into_iter().map(|(_, p)| p).collect()
}

/// The largest |σ_yy − σ_exact| over the points, σ_exact = −(λ Q + γ (H − Y)): uniaxial strain
/// keeps the width, so the vertical Cauchy stress at reference height Y carries the traction
/// and the weight of the mass above, exactly at any strain.
fn vertical_stress_error(sim: &mut Simulation<2>, factor: f64) -> f64 {
    let mut query = sim.world.query::<(&ReferencePosition<2>, &Trial<2>)>();
    query
        .iter(&sim.world)
        .map(|(x, trial)| {
            let exact = -(factor * Q + 20.0 * (10.0 - x.0[1]));
            (trial.0.cauchy()[(1, 1)] - exact).abs()
        })
        .fold(0.0, f64::max)
}

/// Arc-length on the geostatic column with its weight held: the first step starts in
/// equilibrium (the K0 state balances the held weight; its rebalancing at λ = 0 takes no
/// iteration), and after every step the points are where load control with the arc's load
/// factors (`load_factors([λ_1, .., λ_4])`, the weight held) puts them, to 1e-6 of the
/// traction's settlement (both converged to 1e-10); every point's vertical Cauchy stress is
/// −(λ Q + γ (H − Y)) to 1e-3 of the stress at the base (measured 9e-7 of it after step 1,
/// while the points sit at their Gauss positions; growing to 1.4e-4 at a settlement of 0.03 as
/// they move: the quadrature's error, not the arc's, since load control gives the same state).
#[test]
fn a_geostatic_column_under_the_arc_matches_load_control_and_its_closed_form() {
    let spec = scene(
        "column-arc",
        &column(", control: \"arc_length\"", "load_factors(4, |k| 0.25 * k)"),
    )
    .unwrap();
    let dir = common::temp_dir("arc-length-held", "column-arc");
    let mut arc = Simulation::<2>::new(&spec, &dir).unwrap();
    arc.write_initial_state().unwrap();
    let start = positions(&mut arc);
    let (mut factors, mut arc_positions, mut stress) = (vec![], vec![], 0.0f64);
    for step in 1..=4 {
        let factor = arc
            .step()
            .unwrap_or_else(|e| panic!("step {step}: {e}"))
            .load_factor;
        factors.push(factor);
        let error = vertical_stress_error(&mut arc, factor);
        println!("step {step}: λ = {factor:.4}, max |σ_yy − σ_exact| {error:.2e}");
        stress = stress.max(error);
        arc_positions.push(positions(&mut arc));
        if step == 1 {
            let rebalancing = arc.world.resource::<ArcLength<2>>().rebalanced.unwrap();
            assert_eq!(rebalancing.iterations, 0, "{rebalancing:?}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    // (von Mises without F-bar is warned of locking; this column stays elastic)
    let warned: Vec<_> = arc
        .summary
        .warnings
        .iter()
        .filter(|w| !w.contains("lock volumetrically"))
        .collect();
    assert!(warned.is_empty(), "{warned:?}");
    let list = factors
        .iter()
        .map(|f| format!("{f:?}"))
        .collect::<Vec<_>>()
        .join(", ");
    let spec = scene(
        "column-load",
        &column("", &format!("load_factors([{list}])")),
    )
    .unwrap();
    let dir = common::temp_dir("arc-length-held", "column-load");
    let mut load = Simulation::<2>::new(&spec, &dir).unwrap();
    load.write_initial_state().unwrap();
    let mut worst = 0.0f64;
    let settlement = start.last().unwrap()[1] - arc_positions[3].last().unwrap()[1];
    for (step, arc_step) in arc_positions.iter().enumerate() {
        load.step()
            .unwrap_or_else(|e| panic!("load control, step {}: {e}", step + 1));
        for (a, b) in arc_step.iter().zip(positions(&mut load)) {
            worst = worst.max((a[0] - b[0]).abs().max((a[1] - b[1]).abs()));
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    println!(
        "arc load factors {factors:?} (q = {Q} λ); top settlement {settlement:.4e}; max |x_arc − \
         x_load| {worst:.1e} ({:.1e} of it); max |σ_yy − σ_exact| {stress:.1e} ({:.1e} of the \
         base's)",
        worst / settlement,
        stress / (factors[3] * Q + 200.0)
    );
    assert!(factors.windows(2).all(|w| w[1] > w[0]) && factors[0] > 0.0);
    assert!(worst < 1e-6 * settlement, "{worst:e}");
    assert!(stress < 1e-3 * (factors[3] * Q + 200.0), "{stress:e}");
}

/// The Tresca footing of `scripts/footing_pressure_arc.rhai` (a uniform pressure on the strip,
/// 4 cells across B, linear MPM with F-bar) with weight: γ = 5 (γB/s_u = 0.5), the K0 = 0.8
/// state and the weight held, the pressure under arc-length. For a surface strip load on soil
/// of uniform s_u the weight does not change the limit pressure, q_u = (2 + π) s_u (the closed
/// form, as without weight). The run passes its limit: the largest q/s_u within 10 % of
/// 2 + π (the weightless run of the same scene: +4.4 %, first peak +2.1 %), the first peak
/// above 0.95 (2 + π), the load falling after it while the settlement grows.
#[test]
fn a_footing_with_its_weight_held_passes_prandtls_limit_under_the_arc() {
    let scene_text = std::fs::read_to_string(common::shipped_scene("footing_pressure_arc.rhai"))
        .unwrap()
        .replace(
            "probe(#{ name: \"centre\"",
            "initial_stress(#{ K0: 0.8, unit_weight: 5.0, surface: depth });\n\
             body_force([0.0, -5.0], #{ held: true });\n\
             probe(#{ name: \"centre\"",
        );
    let spec = scene("footing", &scene_text).unwrap();
    let dir = common::temp_dir("arc-length-held", "footing");
    let mut sim = Simulation::<2>::new(&spec, &dir).unwrap();
    sim.write_initial_state().unwrap();
    while sim.steps_done() < spec.load_factors.len() {
        sim.step().unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
    let steps = &sim.summary.steps;
    let prandtl = 2.0 + std::f64::consts::PI;
    let (peak, first_peak) = common::largest_and_first_peak(steps, "settlement");
    let last = steps.last().unwrap();
    println!(
        "with weight: q_max / s_u = {peak:.4} ({:+.1} % against 2 + π); first peak {:.4} \
         ({:+.1} %) at δ/B = {:.4}; last {:.4} at δ/B = {:.4}; {} steps; curve {}",
        100.0 * (peak / prandtl - 1.0),
        first_peak.0,
        100.0 * (first_peak.0 / prandtl - 1.0),
        first_peak.1,
        last.load_factor,
        last.measure("settlement").unwrap(),
        steps.len(),
        steps
            .iter()
            .map(|s| format!("{:.3}", s.load_factor))
            .collect::<Vec<_>>()
            .join(" ")
    );
    assert!((peak / prandtl - 1.0).abs() < 0.10, "{peak}");
    assert!(first_peak.0 > prandtl * 0.95, "{first_peak:?}");
    assert!(last.load_factor < peak);
    assert!(last.measure("settlement").unwrap() > first_peak.1);
}

/// A new user's scene: an elastic block 0.5 × 1 (4 cells across its height, its edges on grid
/// lines) on a smooth base with a symmetry roller, its weight 5 held and a top traction of 5
/// per unit load factor under the arc, `solver(#{ control: "arc_length" })` and nothing else.
/// After the first step the expanding block's GIMP/CPDI domains reach new nodes with slivers of
/// support (22 DOFs, then 31); the held weight's out-of-balance force there, left in the step,
/// is 140 times the arc (|K⁻¹ r| = 4.4e-2 against Δl = 3.2e-4 at step 2), so it made step 2's
/// increment and steered step 3's predictor down (Δu_2·δu_f < 0): the arc's other root, refused
/// as a turn-back until the cuts ran out. The default rebalancing with held loads
/// (`rebalance: "auto"`) removes it before the arc on the steps where it needs a correction at
/// least as long as the arc (step 2 among them): the scene runs its 12 steps with GIMP and with
/// CPDI, λ rising, the base carrying 5 + 5 λ at every step (to 1e-8 relative; observed 5.7e-11
/// with GIMP, 5.2e-9 with CPDI). The explicit `rebalance: "off"` still fails (GIMP), and its
/// error names the cause and `"fixed"`.
#[test]
fn a_held_weight_on_gimp_and_cpdi_runs_under_the_default_arc() {
    let text = |basis: &str, rebalance: &str| {
        format!(
            "\
grid(#{{ lower: [0.0, 0.0], upper: [1.5, 1.25], cells: [6, 5], basis: \"{basis}\" }});
const m = material(#{{ name: \"m\", E: 1.0e4, nu: 0.3, density: 1.0 }});
body(#{{ name: \"block\", material: m, region: box([0.0, 0.0], [0.5, 1.0]), ppc: 2 }});
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0, [0]);
solver(#{{ control: \"arc_length\", target_iterations: 6{rebalance} }});
load_steps(12);
body_force([0.0, -10.0], #{{ held: true }});
traction(#{{ on: [[0.0, 1.0], [0.5, 1.0]], traction: [0.0, -10.0] }});
"
        )
    };
    let run = |basis: &str, rebalance: &str| {
        let tag = format!("{basis}{}", rebalance.replace(['"', ':', ',', ' '], ""));
        let spec = scene(&tag, &text(basis, rebalance)).unwrap();
        let dir = common::temp_dir("arc-length-held", &tag);
        let mut sim = Simulation::<2>::new(&spec, &dir).unwrap();
        sim.write_initial_state().unwrap();
        let mut rows = Vec::new();
        let mut failure = None;
        while sim.steps_done() < spec.load_factors.len() {
            match sim.step() {
                Ok(record) => rows.push((
                    record.load_factor,
                    record.measure("fix1_reaction_y").unwrap(),
                    record.measure("rebalance_iterations"),
                )),
                Err(error) => {
                    failure = Some(error.to_string());
                    break;
                }
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
        (rows, failure)
    };
    let (_, failure) = run("gimp", ", rebalance: \"off\"");
    let failure = failure.expect("the held weight on GIMP fails without the rebalancing");
    eprintln!("rebalance off: {failure}");
    assert!(
        failure.contains("turns back")
            && failure.contains("rebalance: \"off\"")
            && failure.contains("\"fixed\""),
        "{failure}"
    );
    for basis in ["gimp", "cpdi"] {
        let (rows, failure) = run(basis, "");
        assert!(failure.is_none(), "{basis}: {failure:?}");
        assert_eq!(rows.len(), 12, "{basis}");
        let worst = rows
            .iter()
            .map(|&(factor, reaction, _)| {
                (reaction - (5.0 + 5.0 * factor)).abs() / (5.0 + 5.0 * factor)
            })
            .fold(0.0f64, f64::max);
        eprintln!(
            "{basis}, default rebalance: λ {:.4} … {:.4}, base reaction against 5 + 5 λ: \
             {worst:.1e}, rebalancing iterations {:?}",
            rows[0].0,
            rows[rows.len() - 1].0,
            rows.iter()
                .map(|r| r.2.unwrap_or(f64::NAN))
                .collect::<Vec<_>>()
        );
        assert!(worst < 1e-8, "{basis}: {worst:e}");
        assert!(
            rows.windows(2).all(|w| w[1].0 > w[0].0),
            "{basis}: {rows:?}"
        );
        // step 2, whose start correction (the new sliver nodes) exceeds its arc, rebalanced
        assert!(rows[1].2.is_some_and(|n| n > 0.0), "{basis}: {rows:?}");
    }
}
