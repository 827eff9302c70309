//! Staged analysis (`stage(#{ name, steps | load_factors, zero_displacements })`,
//! `src/scene/stages.rs`, `src/effects/stages.rs`): a gravity stage then a footing pushed in a
//! second stage, against the uniaxial-strain solution and from zero settlement; the loads of a
//! stage held in the stages after it; a scene of one stage is the scene without it, bit for
//! bit; the stage in `history.csv` and `summary.json`; a run resumed within a stage gives the
//! files of the run that was not stopped; bad input refused with the scene line.

use std::path::Path;

use impm::components::{Displacement, Position, ReferencePosition, Trial};
use impm::effects::stages::DisplacementOrigin;
use impm::run::{RestartPlan, Simulation, run_scene_restartable};

mod common;

fn scene(tag: &str, text: &str) -> Result<impm::scene::SceneSpec, String> {
    common::scene_from_text("stages-scene", tag, text)
}

fn build(tag: &str, text: &str) -> (Simulation<2>, std::path::PathBuf) {
    let spec = scene(tag, text).unwrap_or_else(|e| panic!("{e}"));
    let dir = common::temp_dir("stages-run", tag);
    (Simulation::<2>::new(&spec, &dir).unwrap(), dir)
}

const E: f64 = 1.0e5;
const NU: f64 = 0.3;
const GAMMA: f64 = 20.0;
const DEPTH: f64 = 2.0;

/// Half of a strip footing of width B = 1 on soil 3 wide and 2 deep (Hencky, E = 1e5,
/// ν = 0.3, density 2, g = 10: γ = 20), quadratic B-splines, 6 × 4 cells under the surface
/// and one above, 2 × 2 Gauss points per cell; rollers on the sides, base fixed. Stage
/// "gravity" brings the weight on in 2 steps (line 8), stage "footing" pushes the footing with
/// a traction q = 200 on 0 ≤ x ≤ B/2 in 3 steps (line 10); a probe under the footing's centre.
fn footing(zero: bool) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [3.0, 2.5], cells: [6, 5], basis: \"bspline\", order: 2 }});\n\
         const soil = material(#{{ name: \"soil\", E: {E}, nu: {NU}, density: 2.0 }});\n\
         body(#{{ name: \"soil\", material: soil, region: box([0.0, 0.0], [3.0, {DEPTH}]), ppc: 2, placement: \"gauss\" }});\n\
         fix(|x| x[1] == 0.0);\n\
         fix(|x| x[0] == 0.0 || x[0] == 3.0, [0]);\n\
         probe(#{{ name: \"centre\", at: [0.0, {DEPTH}] }});\n\
         stage(#{{ name: \"gravity\", steps: 2 }});\n\
         body_force([0.0, -10.0]);\n\
         stage(#{{ name: \"footing\", steps: 3, zero_displacements: {zero} }});\n\
         traction(#{{ on: [[0.0, {DEPTH}], [0.5, {DEPTH}]], traction: [0.0, -200.0] }});\n"
    )
}

/// The largest departure of the points' Cauchy stresses from the uniaxial-strain state under
/// the weight, σ_yy = −γ (H − Y) at the reference height Y (the weight above a point per unit
/// width, which lateral confinement keeps), σ_xx = σ_zz = ν/(1 − ν) σ_yy (exact for Hencky
/// at any strain: τ = λ tr(ln V) I + 2μ ln V), no shear; points with `x < skip` are left out.
fn uniaxial_strain_departure(sim: &mut Simulation<2>, skip: f64) -> (f64, usize) {
    let k0 = NU / (1.0 - NU);
    let mut worst = 0.0f64;
    let mut count = 0;
    let mut query = sim.world.query::<(&ReferencePosition<2>, &Trial<2>)>();
    for (x, trial) in query.iter(&sim.world) {
        if x.0[0] < skip {
            continue;
        }
        let sigma = trial.0.cauchy();
        let vertical = -GAMMA * (DEPTH - x.0[1]);
        let mut expected = nalgebra::Matrix3::identity() * (k0 * vertical);
        expected[(1, 1)] = vertical;
        worst = worst.max((sigma - expected).amax());
        count += 1;
    }
    (worst, count)
}

fn probe(sim: &Simulation<2>) -> f64 {
    sim.summary.final_measure("centre_displacement_y").unwrap()
}

/// Stage 1 brings the weight on; its stresses are the uniaxial-strain solution, to 1e-6 of
/// γH = 40 at every point (the block is laterally confined: no footing yet; measured 1.0e-6
/// absolute, 2.6e-8 of γH), its displacements the small-strain u_y = −(γ/M)(HY − Y²/2) to
/// 2e-3 of γH²/2M (measured 3e-4: the strains are 3e-4). Stage 2 starts
/// with every point's `displacement` zero (its origin the settlement under the weight) and
/// the footing's settlement curve (the probe) from zero: after each step of stage 2 the probe
/// differs from the same run without `zero_displacements` by exactly the settlement under the
/// weight (to 1e-12 of it), and `u + u_0 = x − X` at every point. The weight stays on in
/// stage 2 (held at its final value): the elastic end state is the one of weight and footing
/// load applied together in 3 steps, every point's position to 1e-3 of the settlement. `history.csv` has a `stage` column and the load factor
/// restarts from zero in stage 2; `summary.json` names the stage of every step.
#[test]
fn a_gravity_stage_then_a_footing_pushed_from_zero_settlement() {
    let (mut sim, dir) = build("footing", &footing(true));
    let (mut plain, plain_dir) = build("footing-plain", &footing(false));
    for _ in 0..2 {
        sim.step().unwrap();
        plain.step().unwrap();
    }
    let (worst, count) = uniaxial_strain_departure(&mut sim, 0.0);
    let weight_settlement = probe(&sim);
    let elastic = -GAMMA * DEPTH * DEPTH / (2.0 * E * (1.0 - NU) / ((1.0 + NU) * (1.0 - 2.0 * NU)));
    eprintln!(
        "end of stage 1: {count} points, max |σ − σ_uniaxial| {worst:.2e} (γH = {}); probe {weight_settlement:.6e} (γH²/2M = {elastic:.6e})",
        GAMMA * DEPTH
    );
    assert_eq!(count, 6 * 4 * 4);
    assert!(worst < 1e-6 * GAMMA * DEPTH, "{worst:e}");
    // the points' settlement: u_y = −(γ/M)(H Y − Y²/2) at small strain (strains ~3e-4 here)
    let modulus = E * (1.0 - NU) / ((1.0 + NU) * (1.0 - 2.0 * NU));
    let mut worst_u = 0.0f64;
    let mut query = sim
        .world
        .query::<(&ReferencePosition<2>, &Displacement<2>)>();
    for (x, u) in query.iter(&sim.world) {
        let y = x.0[1];
        let exact = -GAMMA / modulus * (DEPTH * y - 0.5 * y * y);
        worst_u = worst_u.max((u.0[1] - exact).abs().max(u.0[0].abs()));
    }
    eprintln!(
        "end of stage 1: max |u − u_uniaxial| {worst_u:.2e} of γH²/2M = {:.4e}",
        -elastic
    );
    assert!(worst_u < 2e-3 * elastic.abs(), "{worst_u:e}");
    let mut curve = Vec::new();
    for step in 3..=5 {
        let record = sim.step().unwrap();
        assert_eq!(record.stage, Some((1, "footing".to_string())));
        plain.step().unwrap();
        let (zeroed, total) = (probe(&sim), probe(&plain));
        let difference = (total - zeroed - weight_settlement).abs();
        let mut worst_origin = 0.0f64;
        let mut query = sim.world.query::<(
            &Position<2>,
            &ReferencePosition<2>,
            &Displacement<2>,
            &DisplacementOrigin<2>,
        )>();
        for (x, reference, u, origin) in query.iter(&sim.world) {
            worst_origin = worst_origin.max((u.0 + origin.0 - (x.0 - reference.0)).amax());
        }
        eprintln!(
            "step {step}: settlement from the stage's start {zeroed:.6e}, total {total:.6e}, |total − zeroed − weight's| {difference:.1e}, max |u + u0 − (x − X)| {worst_origin:.1e}"
        );
        assert!(
            difference <= 1e-12 * weight_settlement.abs(),
            "{difference:e}"
        );
        assert!(worst_origin <= 1e-15, "{worst_origin:e}");
        curve.push(-zeroed);
    }
    // the curve starts from zero and grows with the load: about a third of the stage's
    // settlement after its first step (elastic)
    assert!(
        curve[0] > 0.0 && curve.windows(2).all(|w| w[1] > w[0]),
        "{curve:?}"
    );
    assert!((curve[0] / curve[2] - 1.0 / 3.0).abs() < 0.01, "{curve:?}");
    // the weight held through stage 2: the elastic end state is the one of weight and footing
    // load applied together (up to the points' quadrature moving with a different path)
    let together = footing(false)
        .replace("stage(#{ name: \"gravity\", steps: 2 });", "")
        .replace(
            "stage(#{ name: \"footing\", steps: 3, zero_displacements: false });",
            "",
        )
        + "load_steps(3);\n";
    let (mut both, both_dir) = build("footing-together", &together);
    both.run(|_| {}).unwrap();
    let (x_staged, x_both) = (state(&mut sim), state(&mut both));
    let moved = x_both
        .iter()
        .zip(&x_staged)
        .map(|(a, b)| (a.0[1] - b.0[1]).abs().max((a.0[0] - b.0[0]).abs()))
        .fold(0.0f64, f64::max);
    let total = -probe(&plain);
    eprintln!(
        "end of stage 2 against weight and footing together: max |Δx| {moved:.2e} (settlement {total:.4e})"
    );
    assert!(moved < 1e-3 * total, "{moved:e}");
    let _ = std::fs::remove_dir_all(both_dir);

    sim.run(|_| {}).unwrap();
    let history = std::fs::read_to_string(dir.join("history.csv")).unwrap();
    eprintln!("{history}");
    let rows: Vec<Vec<&str>> = history
        .lines()
        .map(|line| line.split(',').collect())
        .collect();
    assert_eq!(&rows[0][..3], ["step", "stage", "load_factor"]);
    let stages: Vec<&str> = rows[1..].iter().map(|row| row[1]).collect();
    assert_eq!(stages, ["0", "0", "1", "1", "1"]);
    let factors: Vec<f64> = rows[1..]
        .iter()
        .map(|row| row[2].parse().unwrap())
        .collect();
    assert_eq!(factors, [0.5, 1.0, 1.0 / 3.0, 2.0 / 3.0, 1.0]);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let names: Vec<&str> = summary["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|step| step["stage_name"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        ["gravity", "gravity", "footing", "footing", "footing"]
    );
    for dir in [dir, plain_dir] {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// [`footing`] with the footing pushed down by 0.01 B through a rough `surface_displace`.
fn surface_footing(zero: bool) -> String {
    let text = footing(zero).replace(
        "traction(#{ on: [[0.0, 2], [0.5, 2]], traction: [0.0, -200.0] });",
        "surface_displace(#{ on: [[0.0, 2], [0.5, 2]], displacement: [0.0, -0.01], name: \"footing\" });",
    );
    assert!(text.contains("surface_displace"), "{text}");
    text
}

/// The footing of [`footing`] pushed down by 0.01 B through a rough `surface_displace` of
/// stage "footing" (line 10) instead of the traction. In stage "gravity" the condition does
/// nothing: the stresses are the uniaxial-strain ones to 1e-6 of γH as without it (a
/// condition acting then would hold the footing's surface up against the weight) and its
/// displacement and reaction measures are zero. In stage 2 it prescribes the settlement from
/// the stage's start: the footing's mean displacement is λ × 0.01 B after each step (to 1e-3
/// of the step's settlement: the penalty's gap, measured 6e-5), from zero, while the weight's settlement before
/// it (3.0e-4 at the surface) is not counted; the footing carries a growing pressure.
#[test]
fn a_footing_pushed_by_a_surface_displace_of_the_second_stage_settles_from_zero() {
    let (mut sim, dir) = build("surface-footing", &surface_footing(false));
    let measure = |sim: &Simulation<2>, name: &str| sim.summary.final_measure(name).unwrap();
    for _ in 0..2 {
        sim.step().unwrap();
        let (u, reaction) = (
            measure(&sim, "footing_displacement_y"),
            measure(&sim, "footing_reaction_y"),
        );
        assert_eq!((u, reaction), (0.0, 0.0));
    }
    let (worst, count) = uniaxial_strain_departure(&mut sim, 0.0);
    eprintln!(
        "end of stage 1 with the footing's condition waiting: {count} points, max |σ − σ_uniaxial| {worst:.2e}"
    );
    assert!(worst < 1e-6 * GAMMA * DEPTH, "{worst:e}");
    let mut pressures = Vec::new();
    for (k, step) in (3..=5).enumerate() {
        sim.step().unwrap();
        let expected = -0.01 * (k + 1) as f64 / 3.0;
        let settlement = measure(&sim, "footing_displacement_y");
        let pressure = -measure(&sim, "footing_traction_y");
        eprintln!(
            "step {step}: footing settlement {settlement:.6e} (prescribed {expected:.6e}), pressure {pressure:.4e}"
        );
        assert!(
            (settlement - expected).abs() < 1e-3 * expected.abs(),
            "{settlement} {expected}"
        );
        pressures.push(pressure);
    }
    assert!(
        pressures[0] > 0.0 && pressures.windows(2).all(|w| w[1] > w[0]),
        "{pressures:?}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// A column 1 wide and 10 high under its weight and a traction on its top (`extra`).
fn column(loads: &str, schedule: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 10.0], cells: [1, 10], basis: \"bspline\", order: 2 }});\n\
         const soil = material(#{{ name: \"soil\", E: 1.0e4, nu: 0.3, density: 2.0 }});\n\
         body(#{{ name: \"column\", material: soil, region: box([0.0, 0.0], [1.0, 10.0]), ppc: 3, placement: \"gauss\" }});\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         {loads}\n\
         {schedule}\n"
    )
}

const LOADS: &str = "body_force([0.0, -10.0]);\n\
                     traction(#{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -50.0] });";

/// Every point's position and Cauchy stress, in point order.
fn state(sim: &mut Simulation<2>) -> Vec<(Vec<f64>, Vec<f64>)> {
    let mut query = sim
        .world
        .query::<(&impm::components::PointId, &Position<2>, &Trial<2>)>();
    let mut rows: Vec<_> = query
        .iter(&sim.world)
        .map(|(id, x, trial)| {
            (
                id.0,
                x.0.iter().copied().collect::<Vec<_>>(),
                trial.0.cauchy().iter().copied().collect::<Vec<_>>(),
            )
        })
        .collect();
    rows.sort_by_key(|row| row.0);
    rows.into_iter().map(|(_, x, s)| (x, s)).collect()
}

/// A scene of one stage runs as the scene without it, bit for bit (positions and stresses
/// after every step, weight and traction ramped over `steps: 3` as by `load_steps(3)`), and
/// writes the same history but for the `stage` column. A stage's loads are held at their final
/// value in the stages after it: the weight and traction ramped over stage "load"
/// (`load_factors: [0.5, 1.0]`) then a stage "rest" of 2 steps with no load of its own give,
/// bit for bit, the stageless `load_factors([0.5, 1.0, 1.0, 1.0])`.
#[test]
fn one_stage_is_the_scene_without_stages_and_later_stages_hold_the_earlier_loads() {
    for (tag, staged, plain, steps) in [
        (
            "one",
            column(
                &format!("stage(#{{ name: \"only\", steps: 3 }});\n{LOADS}"),
                "",
            ),
            column(LOADS, "load_steps(3);"),
            3,
        ),
        (
            "held",
            column(
                &format!(
                    "stage(#{{ name: \"load\", load_factors: [0.5, 1.0] }});\n{LOADS}\nstage(#{{ name: \"rest\", steps: 2 }});"
                ),
                "",
            ),
            column(LOADS, "load_factors([0.5, 1.0, 1.0, 1.0]);"),
            4,
        ),
    ] {
        let (mut a, a_dir) = build(&format!("{tag}-staged"), &staged);
        let (mut b, b_dir) = build(&format!("{tag}-plain"), &plain);
        for step in 1..=steps {
            a.step().unwrap();
            b.step().unwrap();
            let (sa, sb) = (state(&mut a), state(&mut b));
            assert!(sa == sb, "{tag}: step {step} differs");
        }
        let top = b.summary.steps.last().map(|s| s.load_factor);
        eprintln!("{tag}: {steps} steps bit-identical (last load factor {top:?})");
        let history = |dir: &Path| std::fs::read_to_string(dir.join("history.csv")).unwrap();
        let without_stage: String = history(&a_dir)
            .lines()
            .map(|line| {
                let cells: Vec<&str> = line.split(',').collect();
                let mut kept = vec![cells[0]];
                kept.extend(&cells[2..]);
                kept.join(",") + "\n"
            })
            .collect();
        let pvd = |dir: &Path| std::fs::read_to_string(dir.join("particles.pvd")).unwrap();
        if tag == "one" {
            assert_eq!(without_stage, history(&b_dir));
            // a scene of one stage writes the series of the scene without it, byte for byte
            assert_eq!(pvd(&a_dir), pvd(&b_dir));
            let last = format!("particles_{steps:04}.vtu");
            assert!(
                std::fs::read(a_dir.join(&last)).unwrap()
                    == std::fs::read(b_dir.join(&last)).unwrap(),
                "{last} differs"
            );
        } else {
            // the series' time is stage + λ: it increases through the stages (λ: 0.5, 1 | 0.5, 1)
            let times = pvd_times(&pvd(&a_dir));
            eprintln!("{tag}: particles.pvd times {times:?}");
            assert!(times.ends_with(&[0.5, 1.0, 1.5, 2.0]), "{times:?}");
            assert!(times.windows(2).all(|w| w[0] < w[1]), "{times:?}");
        }
        for dir in [a_dir, b_dir] {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// The `timestep` attributes of a `.pvd` file, in order.
fn pvd_times(text: &str) -> Vec<f64> {
    text.split("timestep=\"")
        .skip(1)
        .map(|rest| rest.split('"').next().unwrap().parse().unwrap())
        .collect()
}

/// A run stopped in the middle of stage 2 (its checkpoint after step 4 of 5) and resumed
/// writes the files of the run that was never stopped: `history.csv` and the last
/// `particles_0005.vtu` byte for byte (the displacement field and probe measured from stage
/// 2's start, its origins restored from the checkpoint; the footing's surface_displace of
/// stage 2 measured from its start, restored too).
#[test]
fn a_run_resumed_within_a_stage_gives_the_results_of_the_run_not_stopped() {
    resumed_as_not_stopped("resume", &surface_footing(true), 4, 5);
    eprintln!(
        "resumed after step 4 (stage 'footing', step 2 of 3): history.csv and particles_0004/5.vtu identical"
    );
}

/// A run resumed inside the stage that releases a load: the column of
/// [`a_column_released_to_no_load_converges_back_to_its_start`] (its weight, the only load,
/// released over stage "unload") stopped after step 3 (the release's first step, its
/// checkpoint) and resumed writes `history.csv` (every step's iterations and residuals) and
/// `particles_0004.vtu` of the run not stopped byte for byte: the criterion's force floor
/// (`resources::LargestForce`, the checkpoint part "largest force") comes back with the
/// checkpoint; without it the resumed last step would not converge.
#[test]
fn a_run_resumed_inside_a_releasing_stage_gives_the_results_of_the_run_not_stopped() {
    let text = staged_column(
        "stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0], #{ until_stage: \"unload\" });\n\
         stage(#{ name: \"unload\", steps: 2 });",
    );
    resumed_as_not_stopped("resume-release", &text, 3, 4);
    eprintln!(
        "resumed after step 3 (stage 'unload', step 1 of 2): history.csv and particles_0003/4.vtu identical"
    );
}

/// A run resumed across the stage that switches a body's material (`material_of`): the block
/// of [`switched_block`] (Hencky in stage "elastic", 2 steps; von Mises from stage "plastic",
/// 5 steps, yielding from its 4th) stopped after step 2 (the end of stage "elastic": the switch
/// happens in the resumed run), after step 4 (inside stage "plastic", the switch made and
/// restored from the checkpoint's "which material each body holds") and after step 6 (the
/// points yielded: their plastic history restored) writes `history.csv` (every step's Newton
/// iterations and residuals) and the stopped and last particle files (stresses, plastic
/// strain) of the run not stopped, byte for byte.
#[test]
fn a_run_resumed_across_a_material_switch_gives_the_results_of_the_run_not_stopped() {
    let text = switched_block("");
    for stop in [2, 4, 6] {
        resumed_as_not_stopped(&format!("resume-switch-{stop}"), &text, stop, 7);
        eprintln!(
            "material_of: resumed after step {stop}: history.csv and particles_{stop:04}/0007.vtu identical"
        );
    }
}

/// A run resumed across a support's release (`fix(.., #{ until_stage })`): the prop example's
/// column ([`a_support_released_in_a_later_stage_is_ramped_down_to_the_analytic_state`], stage
/// "gravity" 2 steps, the prop released over stage "release" in 4) stopped after step 2 (the
/// release starts in the resumed run: the prop's force at the end of the stage before is taken
/// there) and after step 3 (inside the release: the released forces come from the checkpoint)
/// writes `history.csv` and the stopped and last particle files of the run not stopped, byte
/// for byte.
#[test]
fn a_run_resumed_across_a_support_release_gives_the_results_of_the_run_not_stopped() {
    let text = staged_column(
        "fix(|x| x[1] == 10.0, [1], #{ until_stage: \"release\" });\n\
         stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0]);\n\
         stage(#{ name: \"release\", steps: 4 });",
    );
    for stop in [2, 3] {
        resumed_as_not_stopped(&format!("resume-prop-{stop}"), &text, stop, 6);
        eprintln!(
            "support released: resumed after step {stop}: history.csv and particles_{stop:04}/0006.vtu identical"
        );
    }
}

/// A run resumed inside the stage that releases a footing (`surface_displace(#{ ..,
/// until_stage })`, `tests/surface_release.rs`): half a rough footing on Tresca soil (von
/// Mises, s_u = 50), pushed by 0.01 B over stage "push" (4 steps, the soil yielding), released
/// over stage "release" (2 steps), stopped after step 4 (the release starts in the resumed
/// run) and after step 5 (inside the release: the boundary points' released forces come from
/// the checkpoint) writes `history.csv` and the stopped and last particle files of the run not
/// stopped, byte for byte.
#[test]
fn a_run_resumed_inside_a_footing_release_gives_the_results_of_the_run_not_stopped() {
    let text = "grid(#{ lower: [0.0, 0.0], upper: [3.0, 2.5], cells: [6, 5], basis: \"bspline\", order: 2 });\n\
         const soil = material(#{ name: \"soil\", model: \"von_mises\", E: 1.0e5, nu: 0.3, sigma_y: 86.60254037844386, density: 1.0 });\n\
         body(#{ name: \"soil\", material: soil, region: box([0.0, 0.0], [3.0, 2.0]), ppc: 2, placement: \"gauss\" });\n\
         fix(|x| x[1] == 0.0);\n\
         fix(|x| x[0] == 0.0 || x[0] == 3.0, [0]);\n\
         stage(#{ name: \"push\", steps: 4 });\n\
         surface_displace(#{ on: [[0.0, 2.0], [0.5, 2.0]], displacement: [0.0, -0.01], name: \"footing\", until_stage: \"release\" });\n\
         stage(#{ name: \"release\", steps: 2 });\n";
    for stop in [4, 5] {
        resumed_as_not_stopped(&format!("resume-footing-{stop}"), text, stop, 6);
        eprintln!(
            "footing released: resumed after step {stop}: history.csv and particles_{stop:04}/0006.vtu identical"
        );
    }
}

/// A run resumed inside an arc-controlled last stage that switches a material: the column of
/// [`staged_column`] takes its weight over stage "gravity" (2 steps), then stage "load" (under
/// arc-length control, 6 steps) switches it to von Mises (σ_y = 200, the same elasticity: it
/// yields at the base once (1 − 2ν)/(1 − ν) (γH + λ q) = σ_y, λ ≈ 1.5) and adds a top
/// traction q = 100 per unit λ. Stopped after step 2 (the switch and the arc's first step in
/// the resumed run) and after step 5 (inside the arc stage), the resumed run writes
/// `history.csv` (the arc's load factors, iterations, residuals) and the stopped and last
/// particle files of the run not stopped, byte for byte.
#[test]
fn a_run_resumed_inside_an_arc_stage_with_a_switch_gives_the_results_of_the_run_not_stopped() {
    let text = staged_column(
        "const plastic = material(#{ name: \"plastic\", model: \"von_mises\", sigma_y: 200.0, E: 1.0e6, nu: 0.3, density: 2.0 });\n\
         solver(#{ target_iterations: 3 });\n\
         stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0]);\n\
         stage(#{ name: \"load\", load_factors: [0.5, 1.0, 1.5, 2.0, 2.5, 3.0], control: \"arc_length\" });\n\
         material_of(#{ body: \"column\", material: \"plastic\" });\n\
         traction(#{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -100.0] });",
    );
    for stop in [2, 5] {
        resumed_as_not_stopped(&format!("resume-arc-{stop}"), &text, stop, 8);
        eprintln!(
            "arc stage with a switch: resumed after step {stop}: history.csv and particles_{stop:04}/0008.vtu identical"
        );
    }
}

/// Runs scene `text` whole and stopped after step `stop` (its checkpoint) then resumed, and
/// compares `history.csv` and the last two particle files (`last` is the number of steps).
fn resumed_as_not_stopped(tag: &str, text: &str, stop: usize, last: usize) {
    let spec = scene(tag, text).unwrap();
    let plan = RestartPlan {
        identity: impm::restart::RunIdentity {
            scene: "scene.rhai".into(),
            scene_hash: "0".into(),
            overrides: Vec::new(),
        },
        every: Some(1),
        command: "resume".into(),
    };
    let modules = impm::effects::built_in();
    let whole = common::temp_dir("stages-run", &format!("{tag}-whole"));
    run_scene_restartable(&spec, &whole, &modules, &plan, None, |_| {}).unwrap();

    let stopped = common::temp_dir("stages-run", &format!("{tag}-stopped"));
    {
        let mut sim = Simulation::<2>::with_modules(&spec, &stopped, &modules).unwrap();
        sim.keep_checkpoints(plan.clone());
        sim.write_initial_state().unwrap();
        for _ in 0..stop {
            sim.step().unwrap();
            sim.write_checkpoint().unwrap();
        }
    }
    let checkpoint = impm::restart::Checkpoint::read(&stopped, &plan.identity).unwrap();
    assert_eq!(checkpoint.steps_done, stop);
    run_scene_restartable(&spec, &stopped, &modules, &plan, Some(checkpoint), |_| {}).unwrap();
    for file in [
        "history.csv".to_string(),
        format!("particles_{last:04}.vtu"),
        format!("particles_{stop:04}.vtu"),
    ] {
        let read = |dir: &Path| std::fs::read(dir.join(&file)).unwrap();
        assert!(read(&whole) == read(&stopped), "{tag}: {file} differs");
    }
    for dir in [whole, stopped] {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// Bad stages are refused with the line of the call at fault.
#[test]
fn bad_stages_are_refused_with_the_scene_line() {
    let base = "grid(#{ lower: [0.0, 0.0], upper: [1.0, 2.0], cells: [1, 2], basis: \"linear\" });\n\
                const soil = material(#{ name: \"soil\", E: 1.0e4, nu: 0.3, density: 2.0 });\n\
                body(#{ name: \"b\", material: soil, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 2 });\n\
                fix(|x| x[1] == 0.0);\n";
    for (case, text, line, words) in [
        (
            "no steps",
            "stage(#{ name: \"a\" });",
            5,
            vec!["no load steps"],
        ),
        (
            "empty factors",
            "stage(#{ name: \"a\", load_factors: [] });",
            5,
            vec!["load_factors is empty"],
        ),
        (
            "zero steps",
            "stage(#{ name: \"a\", steps: 0 });",
            5,
            vec!["steps"],
        ),
        (
            "duplicate name",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"a\", steps: 2 });",
            6,
            vec!["already declared at line 5"],
        ),
        (
            "schedule before",
            "load_steps(2);\nstage(#{ name: \"a\", steps: 1 });",
            6,
            vec!["already has a load schedule"],
        ),
        (
            "schedule after",
            "stage(#{ name: \"a\", steps: 1 });\nload_steps(2);",
            6,
            vec!["given by the stages"],
        ),
        (
            "unstaged column solution",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\nanalytic_column(#{ axis: 1, height: 1.0, material: soil, body_force: -10.0 });",
            7,
            vec!["analytic_column", "does not follow stages"],
        ),
        (
            "material in a later stage",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\nconst m2 = material(#{ name: \"m2\", E: 1.0e4, nu: 0.3, density: 2.0 });",
            7,
            vec!["material", "after stage 'b' at line 6"],
        ),
        (
            "until an unknown stage",
            "fix(|x| x[0] == 0.0, [0], #{ until_stage: \"c\" });\nstage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });",
            5,
            vec!["no stage is named 'c'", "'a', 'b'"],
        ),
        (
            "until its own stage",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\ndisplace(|x| x[1] == 2.0, [1], [0.1], #{ until_stage: \"b\" });",
            7,
            vec!["'b' is not after the stage the constraint belongs to ('b')"],
        ),
        (
            "until without stages",
            "load_steps(1);\nfix(|x| x[0] == 0.0, [0], #{ until_stage: \"a\" });",
            6,
            vec!["no stage is named 'a'", "the scene has no stages"],
        ),
        (
            "until_stage misspelt",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\nfix(|x| x[0] == 0.0, [0], #{ until_stag: \"b\" });",
            7,
            vec!["unknown option 'until_stag'", "until_stage"],
        ),
        (
            "body_force until its own stage",
            "stage(#{ name: \"a\", steps: 1 });\nbody_force([0.0, -1.0], #{ until_stage: \"a\" });\nstage(#{ name: \"b\", steps: 1 });",
            6,
            vec![
                "body_force(...): until_stage: 'a' is not after the stage the load belongs to ('a')",
            ],
        ),
        (
            "body_force until an unknown stage",
            "stage(#{ name: \"a\", steps: 1 });\nbody_force([0.0, -1.0], #{ until_stage: \"c\" });\nstage(#{ name: \"b\", steps: 1 });",
            6,
            vec!["no stage is named 'c'", "the stages are 'a', 'b'"],
        ),
        (
            "traction until an unknown stage",
            "stage(#{ name: \"a\", steps: 1 });\ntraction(#{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -1.0], until_stage: \"c\" });\nstage(#{ name: \"b\", steps: 1 });",
            6,
            vec![
                "traction(...): until_stage: no stage is named 'c'",
                "the stages are 'a', 'b'",
            ],
        ),
        (
            "traction until an earlier stage",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\ntraction(#{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -1.0], until_stage: \"a\" });",
            7,
            vec![
                "traction(...): until_stage: 'a' is not after the stage the load belongs to ('b')",
            ],
        ),
        (
            "point_load_at until its own stage",
            "stage(#{ name: \"a\", steps: 1 });\npoint_load_at(#{ at: [0.5, 1.0], force: [0.0, -1.0], until_stage: \"a\" });\nstage(#{ name: \"b\", steps: 1 });",
            6,
            vec![
                "point_load_at(...): until_stage: 'a' is not after the stage the load belongs to ('a')",
            ],
        ),
        (
            "point_load until an unknown stage",
            "stage(#{ name: \"a\", steps: 1 });\npoint_load(|x| x[1] > 0.5, [0.0, -1.0], #{ until_stage: \"c\" });\nstage(#{ name: \"b\", steps: 1 });",
            6,
            vec!["point_load(...): until_stage: no stage is named 'c'"],
        ),
        (
            "point_load_total until its own stage",
            "stage(#{ name: \"a\", steps: 1 });\npoint_load_total(|x| x[1] > 0.5, [0.0, -1.0], #{ until_stage: \"a\" });\nstage(#{ name: \"b\", steps: 1 });",
            6,
            vec![
                "point_load_total(...): until_stage: 'a' is not after the stage the load belongs to ('a')",
            ],
        ),
        (
            "point_load_total until without stages",
            "load_steps(1);\npoint_load_total(|x| x[1] > 0.5, [0.0, -1.0], #{ until_stage: \"a\" });",
            6,
            vec!["the scene has no stages"],
        ),
        (
            "point_load held not a flag",
            "load_steps(1);\npoint_load(|x| x[1] > 0.5, [0.0, -1.0], #{ held: 1 });",
            6,
            vec!["held"],
        ),
        (
            "material_of to hencky",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\nmaterial_of(#{ body: \"b\", material: \"soil\" });",
            7,
            vec!["'hencky'", "cannot take over the body's current stress"],
        ),
        (
            "material_of an unknown body",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\nmaterial_of(#{ body: \"x\", material: \"soil\" });",
            7,
            vec!["no body is named 'x'", "the bodies: b"],
        ),
        (
            "material_of an unknown material",
            "stage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });\nmaterial_of(#{ body: \"b\", material: \"x\" });",
            7,
            vec!["no material is named 'x'", "the materials: soil"],
        ),
        (
            "material_of in the first stage",
            "stage(#{ name: \"a\", steps: 1 });\nmaterial_of(#{ body: \"b\", material: \"soil\" });",
            6,
            vec!["after the second stage"],
        ),
        (
            "material_of without stages",
            "load_steps(1);\nmaterial_of(#{ body: \"b\", material: \"soil\" });",
            6,
            vec!["after the second stage"],
        ),
        (
            "arc length",
            "solver(#{ control: \"arc_length\" });\nstage(#{ name: \"a\", steps: 1 });\nstage(#{ name: \"b\", steps: 1 });",
            5,
            vec!["arc_length", "several stages"],
        ),
    ] {
        let error = scene("bad", &format!("{base}{text}\n")).unwrap_err();
        eprintln!("{case}: {error}");
        assert!(
            error.contains(&format!(":{line}")) || error.contains(&format!("line {line}")),
            "{case}: {error}"
        );
        for word in words {
            assert!(error.contains(word), "{case}: {error}");
        }
    }
}

/// The shipped staged footing (`scripts/strip_footing.rhai --set staged=true`, elastic, its
/// default resolution): `impm check` lists the stages; the run's settlement is 0 in stage
/// "gravity" (the footing waits for its stage) and the prescribed 0.01 B at the end of stage
/// "footing" (to 1e-3 of it), its pressure positive.
#[test]
fn the_shipped_staged_footing_runs_in_its_two_stages() {
    let scene = common::shipped_scene("strip_footing.rhai");
    let out = common::impm(&["check", scene.to_str().unwrap(), "--set", "staged=true"]);
    let text = String::from_utf8_lossy(&out.stdout).into_owned()
        + String::from_utf8_lossy(&out.stderr).as_ref();
    eprintln!("{text}");
    assert!(out.status.success(), "{text}");
    assert!(
        text.contains("stages (each from load factor 0")
            && text.contains("'gravity' 2 steps")
            && text.contains("'footing' 5 steps")
            && text.contains("displacements from its start"),
        "{text}"
    );
    let sim = common::run_shipped::<2>("strip_footing.rhai", &[("staged", "true")]);
    let steps = &sim.summary.steps;
    assert_eq!(steps.len(), 7);
    for step in &steps[..2] {
        assert_eq!(step.stage, Some((0, "gravity".to_string())));
        assert_eq!(step.measure("settlement"), Some(0.0));
    }
    let last = steps.last().unwrap();
    assert_eq!(last.stage, Some((1, "footing".to_string())));
    let settlement = last.measure("settlement").unwrap();
    let pressure = last.measure("footing_pressure").unwrap();
    eprintln!("end: settlement / B {settlement:.6e}, pressure {pressure:.4e}");
    assert!((settlement - 0.01).abs() < 1e-5, "{settlement}");
    assert!(pressure > 0.0, "{pressure}");
}

/// A column 1 wide and H = 10 high (Hencky, E = 1e6, ν = 0.3, density 2, g = 10: γ = 20;
/// strains ~1.5e-4, so that the small-strain solutions below hold to ~1e-4), quadratic
/// B-splines, 1 × 10 cells, 3 × 3 Gauss points per cell, base fixed vertically, sides on
/// rollers (uniaxial strain); `extra` adds the staged supports and loads.
fn staged_column(extra: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 10.0], cells: [1, 10], basis: \"bspline\", order: 2 }});\n\
         const soil = material(#{{ name: \"soil\", E: 1.0e6, nu: {NU}, density: 2.0 }});\n\
         body(#{{ name: \"column\", material: soil, region: box([0.0, 0.0], [1.0, 10.0]), ppc: 3, placement: \"gauss\" }});\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         {extra}\n"
    )
}

/// The column's constrained modulus M = E (1 − ν) / ((1 + ν)(1 − 2ν)) (E = 1e6).
fn column_modulus() -> f64 {
    1.0e6 * (1.0 - NU) / ((1.0 + NU) * (1.0 - 2.0 * NU))
}

/// The largest departure of the points' vertical displacement from `exact(Y)` (Y the
/// reference height), and of their horizontal one from 0.
fn column_departure(sim: &mut Simulation<2>, exact: impl Fn(f64) -> f64) -> f64 {
    let mut worst = 0.0f64;
    let mut query = sim
        .world
        .query::<(&ReferencePosition<2>, &Displacement<2>)>();
    for (x, u) in query.iter(&sim.world) {
        worst = worst.max((u.0[1] - exact(x.0[1])).abs().max(u.0[0].abs()));
    }
    worst
}

/// What [`follow_staged_column`] found over a run: the largest departure of the points'
/// displacements and of the two reactions from the exact ones, and the top support's reaction
/// at every step.
struct ColumnRun {
    worst_u: f64,
    worst_r: f64,
    tops: Vec<f64>,
}

/// Runs the staged column of [`staged_column`] through its two stages of `steps[0]` and
/// `steps[1]` load steps, checking every step's stage and comparing the top support's reaction
/// (measure `top`) and the base's (`fix1_reaction_y`) with `reactions(stage, λ)` and the
/// displacements with `displacement(stage, λ, Y)` ([`column_departure`]); the run must give
/// no warning. `scale` is the size of the displacements, for the printout.
fn follow_staged_column(
    sim: &mut Simulation<2>,
    steps: [usize; 2],
    top: &str,
    reactions: impl Fn(usize, f64) -> (f64, f64),
    displacement: impl Fn(usize, f64, f64) -> f64,
    scale: f64,
) -> ColumnRun {
    let mut run = ColumnRun {
        worst_u: 0.0,
        worst_r: 0.0,
        tops: Vec::new(),
    };
    for step in 1..=steps[0] + steps[1] {
        let record = sim.step().unwrap().clone();
        let (stage, lambda) = match step <= steps[0] {
            true => (0, step as f64 / steps[0] as f64),
            false => (1, (step - steps[0]) as f64 / steps[1] as f64),
        };
        assert_eq!(record.stage.as_ref().map(|s| s.0), Some(stage));
        let (top_exact, base_exact) = reactions(stage, lambda);
        let departure = column_departure(sim, |y| displacement(stage, lambda, y));
        let top_force = record.measure(top).unwrap();
        let base = record.measure("fix1_reaction_y").unwrap();
        eprintln!(
            "step {step} (stage {stage}, λ {lambda}): max |u − u_exact| {departure:.2e} of {scale:.4e}; top support {top_force:.6} (exact {top_exact:.6}), base {base:.6} (exact {base_exact:.6})"
        );
        run.worst_u = run.worst_u.max(departure);
        run.worst_r = run
            .worst_r
            .max((top_force - top_exact).abs())
            .max((base - base_exact).abs());
        run.tops.push(top_force);
    }
    eprintln!(
        "worst: u {:.2e} ({:.2e} relative), reactions {:.2e}",
        run.worst_u,
        run.worst_u / scale,
        run.worst_r
    );
    assert!(
        sim.summary.warnings.is_empty(),
        "{:?}",
        sim.summary.warnings
    );
    run
}

/// A support released in a later stage, by the excavation rule. Stage "gravity" (2 steps)
/// brings the weight on a column held at its base and at its top (`fix(.., #{ until_stage:
/// "release" })`): u_y = −λ (γ/2M) Y (H − Y), each support carrying half the weight,
/// γH/2 = 100 per unit width. Stage "release" (4 steps) turns the top support's force into a
/// load ramped down to zero: u_y = −(γ/2M) Y (H − Y) − λ γ H Y / (2M) (the released force
/// γH/2 (1 − λ) on the top of the column hanging from its base; at λ = 1 the column under its
/// weight, −(γ/M)(HY − Y²/2)). Every step: the displacements to 2e-3 of γH²/2M, the top
/// support's reaction (measure `fix3_reaction_y`) the ramp 50, 100 | 75, 50, 25, 0 to 1e-3 of
/// γH/2, the base's the rest of the weight (same tolerance), every step converged.
#[test]
fn a_support_released_in_a_later_stage_is_ramped_down_to_the_analytic_state() {
    let text = staged_column(
        "fix(|x| x[1] == 10.0, [1], #{ until_stage: \"release\" });\n\
         stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0]);\n\
         stage(#{ name: \"release\", steps: 4 });",
    );
    let (mut sim, dir) = build("release", &text);
    let (h, modulus) = (10.0, column_modulus());
    let scale = GAMMA * h * h / (2.0 * modulus);
    let half = GAMMA * h / 2.0;
    let run = follow_staged_column(
        &mut sim,
        [2, 4],
        "fix3_reaction_y",
        |stage, lambda| match stage {
            0 => (lambda * half, lambda * half),
            _ => ((1.0 - lambda) * half, (1.0 + lambda) * half),
        },
        |stage, lambda, y| match stage {
            0 => -lambda * GAMMA / (2.0 * modulus) * y * (h - y),
            _ => -GAMMA / (2.0 * modulus) * y * (h - y) - lambda * GAMMA * h * y / (2.0 * modulus),
        },
        scale,
    );
    assert!(run.worst_u < 2e-3 * scale, "{:e}", run.worst_u);
    assert!(
        run.worst_r < 1e-3 * half,
        "{:e} {:?}",
        run.worst_r,
        run.tops
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// A support added in a later stage moves its nodes from where that stage finds them. Stage
/// "gravity" (2 steps) settles the column under its weight, the top free
/// (u_y = −λ(γ/M)(HY − Y²/2)); stage "lift" (2 steps) declares `displace` of the top by
/// d = 1e-3, which acts from the stage's start: u_y = −(γ/M)(HY − Y²/2) + λ d Y/H (a uniform
/// stretch added), the top's reaction λ M d / H and the base's γH − λ M d / H. Before its
/// stage the waiting support carries nothing (reaction exactly 0) and the top settles freely
/// (γH²/2M). Displacements to 2e-3 of γH²/2M, reactions to 1e-3 of γH; no warning (the
/// material follows the node from the stage's start: the prescribed-motion check measures
/// from there).
#[test]
fn a_support_added_in_a_later_stage_acts_from_its_start() {
    let text = staged_column(
        "stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0]);\n\
         stage(#{ name: \"lift\", steps: 2 });\n\
         displace(|x| x[1] == 10.0, [1], [1.0e-3]);",
    );
    let (mut sim, dir) = build("lift", &text);
    let (h, modulus, d) = (10.0, column_modulus(), 1.0e-3);
    let scale = GAMMA * h * h / (2.0 * modulus);
    let weight = GAMMA * h;
    let run = follow_staged_column(
        &mut sim,
        [2, 2],
        "displace1_reaction_y",
        |stage, lambda| match stage {
            0 => (0.0, lambda * weight),
            _ => (lambda * modulus * d / h, weight - lambda * modulus * d / h),
        },
        |stage, lambda, y| match stage {
            0 => -lambda * GAMMA / modulus * (h * y - 0.5 * y * y),
            _ => -GAMMA / modulus * (h * y - 0.5 * y * y) + lambda * d * y / h,
        },
        scale,
    );
    assert_eq!(
        run.tops[..2],
        [0.0, 0.0],
        "the waiting support carries nothing"
    );
    assert!(run.worst_u < 2e-3 * scale, "{:e}", run.worst_u);
    assert!(run.worst_r < 1e-3 * weight, "{:e}", run.worst_r);
    let _ = std::fs::remove_dir_all(dir);
}

/// `impm check` on a staged scene says which stage each load's and constraint's "load factor 1"
/// is of (each stage has its own schedule), and when a support is released.
#[test]
fn check_names_the_stage_of_every_load() {
    let text = check_output(
        "names",
        &staged_column(
            "fix(|x| x[1] == 10.0, [1], #{ until_stage: \"release\" });\n\
         stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0]);\n\
         stage(#{ name: \"release\", steps: 2 });\n\
         traction(#{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -50.0] });\n\
         displace(|x| x[1] > 8.0 && x[1] < 9.9, [1], [1.0e-4]);",
        ),
    );
    for expected in [
        "per unit mass at load factor 1 of stage 'gravity'",
        "total force [0.0, -50.0] at load factor 1 of stage 'release'",
        "values [0.0] at load factor 1 of stage 'gravity', released at the start of stage 'release'",
        "values [0.0001] at load factor 1 of stage 'release'",
    ] {
        assert!(text.contains(expected), "missing {expected:?}");
    }
    assert!(!text.contains("at load factor 1 ("), "{text}");
}

/// What `impm check` prints (stdout and stderr) for the scene `text`, which it must accept.
fn check_output(tag: &str, text: &str) -> String {
    let dir = common::temp_dir("stages-check", tag);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.rhai");
    std::fs::write(&path, text).unwrap();
    let out = common::impm(&["check", path.to_str().unwrap()]);
    let _ = std::fs::remove_dir_all(dir);
    let text = String::from_utf8_lossy(&out.stdout).into_owned()
        + String::from_utf8_lossy(&out.stderr).as_ref();
    eprintln!("{text}");
    assert!(out.status.success(), "{text}");
    text
}

/// Point loads follow stages: `point_load_total` of 100 on the column's top points in stage
/// "a" (2 steps), another of 50 in stage "b" (2 steps): the base's reaction (equilibrium:
/// the loads on the body) is 50, 100 | 125, 150 (stage a's load held, stage b's following its
/// own λ) to 1e-6 relative (measured 2.4e-12), and the end state is the one of the 150
/// applied in 2 steps without stages: every position to 1e-5 of the top's settlement
/// (measured 1.5e-6: a hyperelastic body, but the loads are spread through the basis at the
/// points' current positions, which move along another path in 4 steps than in 2).
#[test]
fn point_loads_follow_their_stages() {
    let staged = staged_column(
        "stage(#{ name: \"a\", steps: 2 });\n\
         point_load_total(|x| x[1] > 9.5, [0.0, -100.0]);\n\
         stage(#{ name: \"b\", steps: 2 });\n\
         point_load_total(|x| x[1] > 9.5, [0.0, -50.0]);",
    );
    let plain = staged_column("load_steps(2);\npoint_load_total(|x| x[1] > 9.5, [0.0, -150.0]);");
    let (mut a, a_dir) = build("point-loads-staged", &staged);
    let (mut b, b_dir) = build("point-loads-plain", &plain);
    let mut worst = 0.0f64;
    for (step, exact) in [50.0, 100.0, 125.0, 150.0].into_iter().enumerate() {
        let record = a.step().unwrap().clone();
        let base = record.measure("fix1_reaction_y").unwrap();
        eprintln!("step {}: base reaction {base:.9} (exact {exact})", step + 1);
        worst = worst.max((base - exact).abs() / exact);
    }
    for _ in 0..2 {
        b.step().unwrap();
    }
    let (sa, sb) = (state(&mut a), state(&mut b));
    let settlement = 150.0 * 10.0 / column_modulus();
    let departure = sa
        .iter()
        .zip(&sb)
        .flat_map(|(pa, pb)| pa.0.iter().zip(&pb.0).map(|(x, y)| (x - y).abs()))
        .fold(0.0f64, f64::max);
    eprintln!(
        "reactions to {worst:.1e} relative; end positions vs the stageless run {departure:.2e} (settlement ~{settlement:.3e})"
    );
    assert!(worst < 1e-6, "{worst:e}");
    assert!(departure < 1e-5 * settlement, "{departure:e}");
    for dir in [a_dir, b_dir] {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// A block 1 × 1 in plane strain (E = 1e6, ν = 0), quadratic B-splines, 2 × 2 cells of a
/// 2 × 3 grid (room above), 3 × 3 Gauss points per cell, on rollers at its base and both
/// sides, its top loaded by a traction (32 traction points per cell: the load's quadrature
/// leaves the stress uniform to 3.4e-4 of q): stage "elastic" (Hencky, material "elastic") brings
/// q = 50 on in 2 steps; stage "plastic" switches the body to von Mises (σ_y = 100, material
/// "plastic") and adds another 50 × λ with λ = 0, 0.8, 0.96, 1.04, 1.2: the totals
/// 50 | 50, 90, 98, 102, 110.
fn switched_block(extra: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 1.5], cells: [2, 3], basis: \"bspline\", order: 2 }});\n\
         const elastic = material(#{{ name: \"elastic\", E: 1.0e6, nu: 0.0, density: 1.0 }});\n\
         const plastic = material(#{{ name: \"plastic\", model: \"von_mises\", sigma_y: 100.0, E: 1.0e6, nu: 0.0, density: 1.0 }});\n\
         body(#{{ name: \"block\", material: elastic, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 3, placement: \"gauss\" }});\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         stage(#{{ name: \"elastic\", steps: 2 }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -50.0], per_cell: 32 }});\n\
         stage(#{{ name: \"plastic\", load_factors: [0.0, 0.8, 0.96, 1.04, 1.2] }});\n\
         material_of(#{{ body: \"block\", material: \"plastic\" }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -50.0], per_cell: 32 }});\n\
         {extra}"
    )
}

/// Every point's Kirchhoff stress, in `PointId` order.
fn stresses(sim: &mut Simulation<2>) -> Vec<nalgebra::Matrix3<f64>> {
    let mut query = sim.world.query::<(&impm::components::PointId, &Trial<2>)>();
    let mut rows: Vec<_> = query
        .iter(&sim.world)
        .map(|(id, t)| (id.0, t.0.kirchhoff))
        .collect();
    rows.sort_by_key(|row| row.0);
    rows.into_iter().map(|row| row.1).collect()
}

/// The plastic strain of every point that is of the von Mises model (and how many are not).
fn plastic_strains(sim: &mut Simulation<2>) -> (Vec<f64>, usize) {
    use impm::material::VonMises;
    use impm::stages::PointHistory;
    let mut query = sim
        .world
        .query::<(&Trial<2>, Option<&PointHistory<VonMises>>)>();
    let mut strains = Vec::new();
    let mut others = 0;
    for (_, history) in query.iter(&sim.world) {
        match history {
            Some(h) => strains.push(h.committed.plastic_strain),
            None => others += 1,
        }
    }
    (strains, others)
}

/// `material_of` (`effects::material_switches`): the Hencky block of [`switched_block`],
/// switched to von Mises at the start of stage "plastic", keeps every point's stress at the
/// switch: after the stage's first step (λ = 0, no new load) every Kirchhoff stress is the one
/// of the same run without the switch (Hencky all along) to 1e-9 of q (measured 3.3e-10
/// absolute: the elastic law inverted and applied again, round-off), every point is of the
/// new model (the stress after stage "elastic" is uniaxial to 1e-3 of q, measured 3.4e-4). Under more load
/// it is elastic while q ≤ 98 and yields between 98 and 102: confined compression with ν = 0
/// is uniaxial stress while elastic (σ_xx = σ_zz = ν/(1 − ν) σ_yy = 0), which reaches the von
/// Mises surface at q = σ_y = 100 (no point has plastic strain at 98, every point has at
/// 102: measured 3.9e-6 to 4.0e-6). Past it the lateral stresses follow the yield condition of the axisymmetric state,
/// σ_xx = σ_zz = σ_yy + σ_y: at q = 110, σ_yy = −110 (equilibrium), σ_xx = σ_zz = −10, each
/// to 1e-3 of σ_y (measured 4.0e-2 absolute: Cauchy against the small-strain solution, the
/// strains are ~1e-4), and the Kirchhoff stress on the yield surface (q_vm = σ_y to 1e-9 of
/// it, measured 7e-14).
#[test]
fn a_body_switched_to_von_mises_keeps_its_stress_and_yields_at_sigma_y() {
    let text = switched_block("");
    let (mut sim, dir) = build("switch", &text);
    let unswitched = text.replace("material_of(", "// material_of(");
    let (mut plain, plain_dir) = build("switch-plain", &unswitched);
    for _ in 0..2 {
        sim.step().unwrap();
        plain.step().unwrap();
    }
    let before = stresses(&mut sim);
    let spread = before
        .iter()
        .map(|t| (t[(1, 1)] + 50.0).abs().max(t[(0, 0)].abs()))
        .fold(0.0f64, f64::max);
    eprintln!("end of stage 'elastic': max |τ − τ_uniaxial| {spread:.2e} (q = 50)");
    assert!(spread < 1e-3 * 50.0, "{spread:e}");
    assert_eq!(plastic_strains(&mut sim), (vec![], before.len()));
    let record = sim.step().unwrap().clone();
    plain.step().unwrap();
    assert_eq!(record.stage, Some((1, "plastic".to_string())));
    let (after, hencky) = (stresses(&mut sim), stresses(&mut plain));
    let largest = |a: &[nalgebra::Matrix3<f64>], b: &[nalgebra::Matrix3<f64>]| {
        a.iter()
            .zip(b)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0f64, f64::max)
    };
    let jump = largest(&after, &hencky);
    let (strains, others) = plastic_strains(&mut sim);
    eprintln!(
        "switch: {} points, largest stress difference to the unswitched run after the stage's first step {jump:.2e} (q = 50; τ_yy {:.6}; the step itself changed the stress by {:.2e}: Newton's tolerance)",
        after.len(),
        after[0][(1, 1)],
        largest(&before, &after)
    );
    assert!(jump < 1e-9 * 50.0, "{jump:e}");
    assert_eq!((strains.len(), others), (after.len(), 0));
    assert!(strains.iter().all(|&e| e == 0.0));
    let sigma_y: f64 = 100.0;
    for (q, plastic) in [(90.0, false), (98.0, false), (102.0, true), (110.0, true)] {
        sim.step().unwrap();
        let (strains, _) = plastic_strains(&mut sim);
        let least = strains.iter().copied().fold(f64::INFINITY, f64::min);
        let most = strains.iter().copied().fold(0.0f64, f64::max);
        eprintln!("q = {q}: plastic strain {least:.3e} .. {most:.3e}");
        match plastic {
            false => assert_eq!(most, 0.0, "q = {q}"),
            true => assert!(least > 0.0, "q = {q}: {least:e}"),
        }
    }
    let q: f64 = 110.0;
    let lateral = sigma_y - q;
    let mut worst = 0.0f64;
    let mut worst_yield = 0.0f64;
    let mut query = sim.world.query::<&Trial<2>>();
    for trial in query.iter(&sim.world) {
        let sigma = trial.0.cauchy();
        let expected =
            nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(lateral, -q, lateral));
        worst = worst.max((sigma - expected).amax());
        let tau = trial.0.kirchhoff;
        let deviator = tau - nalgebra::Matrix3::identity() * (tau.trace() / 3.0);
        let equivalent = (1.5 * deviator.norm_squared()).sqrt();
        worst_yield = worst_yield.max((equivalent - sigma_y).abs());
    }
    eprintln!(
        "q = 110: max |σ − σ_exact| {worst:.2e} (σ_xx = σ_zz exact {lateral}), max |q_vm(τ) − σ_y| {worst_yield:.2e}"
    );
    assert!(worst < 1e-3 * sigma_y, "{worst:e}");
    assert!(worst_yield < 1e-9 * sigma_y, "{worst_yield:e}");
    for dir in [dir, plain_dir] {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// `impm check` lists a material switch with its stage and line.
#[test]
fn check_lists_a_material_switch_with_its_stage() {
    let dir = common::temp_dir("stages-check", "switch");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("switch.rhai");
    std::fs::write(&path, switched_block("")).unwrap();
    let out = common::impm(&["check", path.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout).into_owned()
        + String::from_utf8_lossy(&out.stderr).as_ref();
    eprintln!("{text}");
    assert!(out.status.success(), "{text}");
    let expected = "body 'block' takes material 'plastic' (von_mises) from the start of stage 'plastic' (line 10)";
    assert!(text.contains(expected), "missing {expected:?}");
    let _ = std::fs::remove_dir_all(dir);
}

/// `body_force([..], #{ until_stage })`: the column of [`staged_column`] (Hencky, γ = 20,
/// H = 10) takes its weight and a traction q = 50 on its top over stage "gravity" (2 steps);
/// the weight is released at the start of stage "unload" (2 steps), where it is ramped down,
/// `(1 − λ) γ`, while the traction stays. The base's reaction is the loads on the body,
/// 125, 250 | 150, 50 (to 1e-6 of 250; measured 1.6e-12), and at the end of "unload" the
/// elastic column is where the traction alone puts it (a run of the traction without stages,
/// 2 steps): every position to 1e-6 of the weight's settlement γH²/2M = 7.43e-4 (measured
/// 1.9e-10, 2.5e-7 of it: Newton's tolerance and the load spread at the points' current
/// positions, as for the point loads above). The departure of the displacements from the
/// small-strain `u = −λ_g (γ/M)(HY − Y²/2) − λ_q (q/M) Y` is printed (1.9e-6), not checked. The traction stays so that the end state carries a load (the release to no load
/// at all: [`a_column_released_to_no_load_converges_back_to_its_start`]).
#[test]
fn a_body_force_released_in_a_later_stage_unloads_the_column() {
    let text = staged_column(
        "stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0], #{ until_stage: \"unload\" });\n\
         traction(#{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -50.0] });\n\
         stage(#{ name: \"unload\", steps: 2 });",
    );
    let plain = staged_column(
        "load_steps(2);\n\
         traction(#{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -50.0] });",
    );
    let (mut sim, dir) = build("body-force-released", &text);
    let (mut alone, alone_dir) = build("body-force-released-plain", &plain);
    let modulus = column_modulus();
    let settlement = GAMMA * 100.0 / (2.0 * modulus);
    let q = 50.0;
    let mut worst_reaction = 0.0f64;
    let mut worst_u = 0.0f64;
    for (weight, traction, stage) in [(0.5, 0.5, 0), (1.0, 1.0, 0), (0.5, 1.0, 1), (0.0, 1.0, 1)] {
        let record = sim.step().unwrap().clone();
        assert_eq!(record.stage.as_ref().map(|s| s.0), Some(stage));
        let base = record.measure("fix1_reaction_y").unwrap();
        let exact = 200.0 * weight + q * traction;
        let departure = column_departure(&mut sim, |y| {
            -weight * GAMMA / modulus * (10.0 * y - 0.5 * y * y) - traction * q / modulus * y
        });
        eprintln!(
            "step {}: stage {stage}, weight × {weight}, traction × {traction}: base reaction {base:.9} (exact {exact}), max |u − u_exact| {departure:.2e}",
            record.step
        );
        worst_reaction = worst_reaction.max((base - exact).abs() / 250.0);
        worst_u = worst_u.max(departure);
    }
    for _ in 0..2 {
        alone.step().unwrap();
    }
    let (end, traction_only) = (state(&mut sim), state(&mut alone));
    let departure = end
        .iter()
        .zip(&traction_only)
        .flat_map(|(a, b)| a.0.iter().zip(&b.0).map(|(x, y)| (x - y).abs()))
        .fold(0.0f64, f64::max);
    eprintln!(
        "reactions to {worst_reaction:.1e} of 250; u to {worst_u:.2e} (settlement {settlement:.4e}); end positions vs the traction alone {departure:.2e}"
    );
    assert!(worst_reaction < 1e-6, "{worst_reaction:e}");
    assert!(departure < 1e-6 * settlement, "{departure:e}");
    for dir in [dir, alone_dir] {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// A release that leaves the body with no load converges (`control::NormalisedResidual`,
/// "Releases": the scale of the out-of-balance force has the run's largest converged force as
/// its floor). The column of [`staged_column`] takes its weight over stage "gravity" (2
/// steps); `body_force(.., #{ until_stage: "unload" })` is its only load, ramped down over
/// stage "unload" (2 steps) to nothing. Every step converges without a cut; the displacements
/// follow `u_y = −w (γ/M)(HY − Y²/2)` with w = 0.5, 1 | 0.5, 0 (to 2e-3 of γH²/2M, the
/// small-strain formula against Hencky) and at the end every point is back where it started:
/// |u| below 1e-7 of γH²/2M (measured 2.1e-12, 2.9e-9 of it: the last step converges
/// quadratically to a measure of 1.1e-12, and the internal force's round-off floor, about
/// 1e-12 of the full-load force, comes back multiplied by the column's stiffness ratio). Before
/// the floor, the last step's measure stayed of order 1 and the run stopped.
#[test]
fn a_column_released_to_no_load_converges_back_to_its_start() {
    let text = staged_column(
        "stage(#{ name: \"gravity\", steps: 2 });\n\
         body_force([0.0, -10.0], #{ until_stage: \"unload\" });\n\
         stage(#{ name: \"unload\", steps: 2 });",
    );
    let (mut sim, dir) = build("released-to-nothing", &text);
    let modulus = column_modulus();
    let settlement = GAMMA * 100.0 / (2.0 * modulus);
    let mut worst = 0.0f64;
    let mut end = f64::NAN;
    for (weight, stage) in [(0.5, 0), (1.0, 0), (0.5, 1), (0.0, 1)] {
        let record = sim.step().unwrap().clone();
        assert_eq!(record.stage.as_ref().map(|s| s.0), Some(stage));
        assert!(record.converged && record.cuts == 0, "{record:?}");
        let departure = column_departure(&mut sim, |y| {
            -weight * GAMMA / modulus * (10.0 * y - 0.5 * y * y)
        });
        eprintln!(
            "step {}: stage {stage}, weight × {weight}: {} iterations, residuals {:?}, max |u − u_exact| {departure:.2e} (γH²/2M {settlement:.4e})",
            record.step, record.iterations, record.residuals
        );
        worst = worst.max(departure);
        end = departure;
    }
    assert!(worst < 2e-3 * settlement, "{worst:e}");
    assert!(end < 1e-7 * settlement, "{end:e}");
    released_cleanly(&sim, "column", dir);
}

/// The run gave no warning; its directory is removed.
fn released_cleanly(sim: &Simulation<2>, case: &str, dir: std::path::PathBuf) {
    assert!(
        sim.summary.warnings.is_empty(),
        "{case}: {:?}",
        sim.summary.warnings
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// `until_stage` on the other loads, and `held` on the point loads. The elastic column of
/// [`staged_column`] under an end load of stage "load" (2 steps) released over stage "unload"
/// (2 steps), the end load given by each call in turn: `traction` q = 50 on the top,
/// `point_load_at` 50 at its top centre, `point_load_total` 50 on the top row of points,
/// `point_load` 10 on each of the 3 points of that row, and `point_load(.., #{ held: true,
/// until_stage })` (30 in full from the first step). The base's reaction (the loads on the
/// body) follows the factors 0.5, 1 | 0.5, 0 (held: 1, 1 | 0.5, 0) to 1e-9 of the load, the
/// traction's displacements are the uniaxial-strain `−w (q/M) Y` at the end of "load" (to 1e-3
/// of qH/M: small strain against Hencky), and at the end of "unload" every point is back at
/// its start: under the traction (a uniform strain) to 1e-9 of qH/M, under the point loads to
/// 1e-5 of it (the strain under a concentrated load is not uniform, and the updated-Lagrangian
/// steps, the basis evaluated where the points are, do not return exactly along the path they
/// came: as for the point loads of [`point_loads_follow_their_stages`]); every step converges
/// without a cut.
#[test]
fn loads_released_in_a_later_stage_leave_the_elastic_column_where_it_started() {
    let modulus = column_modulus();
    for (case, load, total, held) in [
        (
            "traction",
            "traction(#{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -50.0], until_stage: \"unload\" });",
            50.0,
            false,
        ),
        (
            "point_load_at",
            "point_load_at(#{ at: [0.5, 10.0], force: [0.0, -50.0], until_stage: \"unload\" });",
            50.0,
            false,
        ),
        (
            "point_load_total",
            "point_load_total(|x| x[1] > 9.6, [0.0, -50.0], #{ until_stage: \"unload\" });",
            50.0,
            false,
        ),
        (
            "point_load",
            "point_load(|x| x[1] > 9.6, [0.0, -10.0], #{ until_stage: \"unload\" });",
            30.0,
            false,
        ),
        (
            "point_load held",
            "point_load(|x| x[1] > 9.6, [0.0, -10.0], #{ held: true, until_stage: \"unload\" });",
            30.0,
            true,
        ),
    ] {
        let text = staged_column(&format!(
            "stage(#{{ name: \"load\", steps: 2 }});\n{load}\nstage(#{{ name: \"unload\", steps: 2 }});"
        ));
        let (mut sim, dir) = build(&format!("released-{}", case.replace(' ', "-")), &text);
        let scale = total * 10.0 / modulus;
        let factors = match held {
            false => [0.5, 1.0, 0.5, 0.0],
            true => [1.0, 1.0, 0.5, 0.0],
        };
        let mut worst_reaction = 0.0f64;
        let mut end = f64::NAN;
        for (step, factor) in factors.into_iter().enumerate() {
            let record = sim.step().unwrap().clone();
            assert!(record.converged && record.cuts == 0, "{case}: {record:?}");
            let base = record.measure("fix1_reaction_y").unwrap();
            worst_reaction = worst_reaction.max((base - factor * total).abs() / total);
            let departure = column_departure(&mut sim, |y| -factor * total / modulus * y);
            eprintln!(
                "{case}: step {}: factor {factor}: base reaction {base:.9} (exact {}), max |u − (−w q Y/M)| {departure:.2e} of qH/M {scale:.3e}",
                step + 1,
                factor * total
            );
            if case == "traction" && step == 1 {
                assert!(departure < 1e-3 * scale, "{case}: {departure:e}");
            }
            end = departure;
        }
        eprintln!("{case}: reactions to {worst_reaction:.1e} of the load; end |u| {end:.2e}");
        assert!(worst_reaction < 1e-9, "{case}: {worst_reaction:e}");
        // a uniform strain comes back exactly; a concentrated load's does not quite (doc above)
        let tolerance = if case == "traction" { 1e-9 } else { 1e-5 };
        assert!(end < tolerance * scale, "{case}: {end:e}");
        released_cleanly(&sim, case, dir);
    }
}

/// The permanent set of a von Mises block loaded past yield and released (`traction(..,
/// #{ until_stage })`). The block of [`switched_block`]'s geometry (1 × 1, rollers at its base
/// and sides: uniaxial strain), von Mises from the start (E = 1e6, ν = 0, σ_y = 100, perfectly
/// plastic), q = 150 on its top over stage "load" (λ = 0.5, 0.6, 0.8, 1: it yields at
/// q = σ_y, λ = 2/3), released over stage "unload" (2 steps). The closed form of uniaxial
/// strain at small strain (K = E/3(1 − 2ν), M = E(1 − ν)/((1 + ν)(1 − 2ν)), G = E/2(1 + ν),
/// compression positive): loaded, `σ_yy = K ε_m + 2σ_y/3`, so `ε_m = (q − 2σ_y/3)/K`;
/// unloading is elastic (`Δσ_yy = M Δε`, reverse yield only past `q = σ_y M/G = 200`), so at
/// q = 0 the permanent strain is `ε_p = ε_m − q/M` = 1.0e-4 and the locked-in lateral stress
/// `σ_xx = σ_zz = K ε_m − σ_y/3 − (M − 2G) q/M` = 50 (compression). Checked: every point
/// yielded; at the end of "unload" `u_y = −ε_p Y` at every point to 1e-2 of ε_p H (the strains
/// are ~2.5e-4: Hencky's logarithmic strain against the small-strain formula, and the
/// traction's quadrature, uniform to 3.4e-4 of q; measured 7.5e-4 of it), `σ_yy` = 0 and
/// `σ_xx`, `σ_zz` = −50 to 1e-3 of σ_y (measured 3.3e-4); every step converges without a cut.
#[test]
fn a_von_mises_block_released_past_yield_keeps_the_closed_form_permanent_set() {
    let text = "grid(#{ lower: [0.0, 0.0], upper: [1.0, 1.5], cells: [2, 3], basis: \"bspline\", order: 2 });\n\
         const plastic = material(#{ name: \"plastic\", model: \"von_mises\", sigma_y: 100.0, E: 1.0e6, nu: 0.0, density: 1.0 });\n\
         body(#{ name: \"block\", material: plastic, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 3, placement: \"gauss\" });\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         stage(#{ name: \"load\", load_factors: [0.5, 0.6, 0.8, 1.0] });\n\
         traction(#{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -150.0], per_cell: 32, until_stage: \"unload\" });\n\
         stage(#{ name: \"unload\", steps: 2 });\n";
    let (mut sim, dir) = build("released-von-mises", text);
    let (e, nu, sigma_y, q): (f64, f64, f64, f64) = (1.0e6, 0.0, 100.0, 150.0);
    let bulk = e / (3.0 * (1.0 - 2.0 * nu));
    let shear = e / (2.0 * (1.0 + nu));
    let constrained = e * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let loaded = (q - 2.0 * sigma_y / 3.0) / bulk;
    let set = loaded - q / constrained;
    let lateral = bulk * loaded - sigma_y / 3.0 - (constrained - 2.0 * shear) * q / constrained;
    for step in 1..=6 {
        let record = sim.step().unwrap().clone();
        assert!(record.converged && record.cuts == 0, "{record:?}");
        let (strains, _) = plastic_strains(&mut sim);
        let most = strains.iter().copied().fold(0.0f64, f64::max);
        eprintln!(
            "step {step} ({:?}, λ {}): {} iterations, plastic strain up to {most:.3e}, base reaction {:.6}",
            record.stage,
            record.load_factor,
            record.iterations,
            record.measure("fix1_reaction_y").unwrap_or(f64::NAN)
        );
        if step == 4 {
            assert!(strains.iter().all(|&e| e > 0.0), "not every point yielded");
        }
    }
    let worst_u = {
        let mut worst = 0.0f64;
        let mut query = sim
            .world
            .query::<(&ReferencePosition<2>, &Displacement<2>)>();
        for (x, u) in query.iter(&sim.world) {
            worst = worst.max((u.0[1] + set * x.0[1]).abs().max(u.0[0].abs()));
        }
        worst
    };
    let mut worst_sigma = 0.0f64;
    let mut query = sim.world.query::<&Trial<2>>();
    for trial in query.iter(&sim.world) {
        let sigma = trial.0.cauchy();
        let expected =
            nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(-lateral, 0.0, -lateral));
        worst_sigma = worst_sigma.max((sigma - expected).amax());
    }
    eprintln!(
        "released: permanent strain (closed form) {set:.4e}, max |u_y + ε_p Y| {worst_u:.2e} ({:.2e} of ε_p H); locked-in σ_xx = σ_zz = −{lateral:.3}, σ_yy = 0: max departure {worst_sigma:.2e} ({:.2e} of σ_y)",
        worst_u / set,
        worst_sigma / sigma_y
    );
    assert!((set - 1.0e-4).abs() < 1e-12 && (lateral - 50.0).abs() < 1e-9);
    assert!(worst_u < 1e-2 * set, "{worst_u:e}");
    assert!(worst_sigma < 1e-3 * sigma_y, "{worst_sigma:e}");
    // the only warning: volumetric locking without F-bar (no matter for this uniform state)
    assert!(
        sim.summary
            .warnings
            .iter()
            .all(|w| w.contains("lock volumetrically")),
        "{:?}",
        sim.summary.warnings
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// `impm check` says which stage releases each load (`traction`, `point_load_at`,
/// `point_load`, `point_load_total`, `body_force`).
#[test]
fn check_says_which_stage_releases_each_load() {
    let text = check_output(
        "releases",
        &staged_column(
            "stage(#{ name: \"load\", steps: 2 });\n\
         body_force([0.0, -10.0], #{ until_stage: \"unload\" });\n\
         traction(#{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -50.0], until_stage: \"unload\" });\n\
         point_load_at(#{ at: [0.5, 10.0], force: [0.0, -5.0], until_stage: \"unload\" });\n\
         point_load(|x| x[1] > 9.6, [0.0, -1.0], #{ held: true, until_stage: \"unload\" });\n\
         point_load_total(|x| x[1] > 9.6, [0.0, -3.0], #{ until_stage: \"unload\" });\n\
         stage(#{ name: \"unload\", steps: 2 });",
        ),
    );
    let released = "released at the start of stage 'unload' (ramped down over that stage)";
    for call in [
        "per unit mass",
        "line 8: traction:",
        "line 9: point_load_at:",
        "line 10: point_load:",
        "line 11: point_load_total:",
    ] {
        let line = text
            .lines()
            .find(|line| line.contains(call))
            .unwrap_or_else(|| panic!("no line with {call:?}"));
        assert!(line.contains(released), "{call}: {line}");
    }
}
