//! Geostatic initial stresses (`initial_stress(#{ K0, unit_weight, surface })`,
//! `src/effects/initial_stress.rs`) and held loads (`body_force([..], #{ held: true })`,
//! `traction(#{ .., held: true })`: `resources::Ramp`): the K0 state against its closed form and
//! in equilibrium with its held weight at the first load step; a held load applied in full from
//! step 1; the strip footing with weight against Prandtl; the errors of a model that cannot
//! carry an initial stress.

use impm::components::{Displacement, ReferencePosition, Trial};
use impm::run::Simulation;

mod common;

fn scene(tag: &str, text: &str) -> Result<impm::scene::SceneSpec, String> {
    common::scene_from_text("geostatic-scene", tag, text)
}

/// A plane-strain column of soil, 1 wide and 10 high (quadratic B-splines, one cell wide,
/// 3 × 3 Gauss points per cell), rollers on the sides, base fixed, under its weight
/// γ = ρ0 g = 2 × 10 = 20 (`weight` is the body_force call); `extra` are further calls (the
/// initial_stress call on line 7), `schedule` the load schedule.
fn column(model: &str, weight: &str, extra: &str, schedule: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 10.0], cells: [1, 10], basis: \"bspline\", order: 2 }});\n\
         const soil = material(#{{ name: \"soil\", {model}E: 1.0e4, nu: 0.3, density: 2.0 }});\n\
         body(#{{ name: \"column\", material: soil, region: box([0.0, 0.0], [1.0, 10.0]), ppc: 3, placement: \"gauss\" }});\n\
         {weight}\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         {extra}\n\
         {schedule};\n"
    )
}

const VON_MISES: &str = "model: \"von_mises\", sigma_y: 1000.0, ";
const WEIGHT: &str = "body_force([0.0, -10.0]);";
const HELD_WEIGHT: &str = "body_force([0.0, -10.0], #{ held: true });";
const K0_STATE: &str = "initial_stress(#{ K0: 0.6, unit_weight: 20.0, surface: 10.0 });";

fn build(tag: &str, text: &str) -> (Simulation<2>, std::path::PathBuf) {
    let spec = scene(tag, text).unwrap_or_else(|e| panic!("{e}"));
    let dir = common::temp_dir("geostatic-run", tag);
    (Simulation::<2>::new(&spec, &dir).unwrap(), dir)
}

/// The largest displacement component of any point.
fn largest_displacement(sim: &mut Simulation<2>) -> f64 {
    let mut query = sim.world.query::<&Displacement<2>>();
    query
        .iter(&sim.world)
        .fold(0.0f64, |m, u| m.max(u.0.amax()))
}

/// Every point's (reference position, displacement) in point order.
fn displacements(sim: &mut Simulation<2>) -> Vec<(Vec<f64>, Vec<f64>)> {
    let mut query = sim
        .world
        .query::<(&ReferencePosition<2>, &Displacement<2>)>();
    let mut rows: Vec<_> = query
        .iter(&sim.world)
        .map(|(x, u)| {
            (
                x.0.iter().copied().collect::<Vec<_>>(),
                u.0.iter().copied().collect::<Vec<_>>(),
            )
        })
        .collect();
    rows.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
    rows
}

/// With `initial_stress(#{ K0: 0.6, unit_weight: 20, surface: 10 })` and its weight held
/// (`body_force([0, −10], #{ held: true })`, density 2) the column starts in equilibrium: in
/// load step 1 of 4 Newton converges in at most 2 iterations and the points do not move (below
/// 1e-9 of the 0.074 = γH²/(2M) the weight alone gives the top from a stress-free start,
/// which the same column without initial stresses shows); every point's Cauchy stress is the
/// closed form σ_yy = −γ (10 − y), σ_xx = σ_zz = K0 σ_yy, no shear, to 1e-9 of γH = 200, after
/// step 1 and after step 4. K0 = 0.6 differs from the elastic ν/(1 − ν) = 0.43: the state is
/// carried by the history, not by the deformation.
#[test]
fn a_k0_state_is_in_equilibrium_with_its_held_weight_and_matches_its_closed_form() {
    let (gamma, height, k0) = (20.0, 10.0, 0.6);
    let (mut sim, dir) = build(
        "k0",
        &column(VON_MISES, HELD_WEIGHT, K0_STATE, "load_steps(4)"),
    );
    let free_top = {
        let (mut free, free_dir) = build("no-k0", &column(VON_MISES, WEIGHT, "", "load_steps(1)"));
        free.run(|_| {}).unwrap();
        let _ = std::fs::remove_dir_all(&free_dir);
        largest_displacement(&mut free)
    };
    for step in 1..=4 {
        let record = sim.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
        let (iterations, residuals) = (record.iterations, record.residuals.clone());
        let worst_u = largest_displacement(&mut sim);
        let mut worst_stress = 0.0f64;
        let mut count = 0;
        let mut query = sim.world.query::<(&ReferencePosition<2>, &Trial<2>)>();
        for (x, trial) in query.iter(&sim.world) {
            let sigma = trial.0.cauchy();
            let vertical = -gamma * (height - x.0[1]);
            let mut expected = nalgebra::Matrix3::identity() * (k0 * vertical);
            expected[(1, 1)] = vertical;
            worst_stress = worst_stress.max((sigma - expected).amax());
            count += 1;
        }
        eprintln!(
            "step {step}: {iterations} iterations {residuals:?}, {count} points: max |u| {worst_u:.1e} (weight from a stress-free start {free_top:.4e}), max |σ − σ_K0| {worst_stress:.1e}"
        );
        assert_eq!(count, 10 * 9);
        assert!(iterations <= 2, "step {step}: {iterations} iterations");
        assert!(worst_u < 1e-9 * free_top, "step {step}: {worst_u:e}");
        assert!(
            worst_stress < 1e-9 * gamma * height,
            "step {step}: {worst_stress:e}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!((free_top - 0.074).abs() < 0.01, "{free_top}");
}

/// A held load is applied in full from the first step on: an elastic column whose weight is
/// held, in 3 load steps, has after every step the displacements of the same column whose
/// weight follows the schedule `load_factors([1, 1, 1])` (to 1e-12 of the largest; steps 2
/// and 3 change them by about 1e-4 relative, as the moved points integrate the same load a
/// little differently), while with `load_steps(3)` the ramped weight gives a third of them after
/// step 1; the same for a traction on the top (`traction(#{ .., held: true })`) of a weightless
/// column.
#[test]
fn a_held_load_is_applied_in_full_from_the_first_step() {
    let traction = |held: bool| {
        format!(
            "traction(#{{ on: [[0.0, 10.0], [1.0, 10.0]], traction: [0.0, -50.0], held: {held} }});"
        )
    };
    for (what, ramped, held) in [
        (
            "weight",
            (WEIGHT, String::new()),
            (HELD_WEIGHT, String::new()),
        ),
        ("traction", ("", traction(false)), ("", traction(true))),
    ] {
        let full_text = column("", ramped.0, &ramped.1, "load_factors([1.0, 1.0, 1.0])");
        let (mut full, full_dir) = build(&format!("{what}-full"), &full_text);
        let (mut thirds, thirds_dir) = build(
            &format!("{what}-thirds"),
            &column("", ramped.0, &ramped.1, "load_steps(3)"),
        );
        thirds.step().unwrap();
        let third = largest_displacement(&mut thirds);
        let held_text = column("", held.0, &held.1, "load_steps(3)");
        let (mut sim, dir) = build(&format!("{what}-held"), &held_text);
        let mut first = Vec::new();
        for step in 1..=3 {
            full.step().unwrap();
            sim.step().unwrap();
            let (expected, got) = (displacements(&mut full), displacements(&mut sim));
            let scale = largest_displacement(&mut full);
            assert_eq!(got.len(), expected.len());
            let difference = |a: &[(Vec<f64>, Vec<f64>)], b: &[(Vec<f64>, Vec<f64>)]| {
                a.iter()
                    .zip(b)
                    .flat_map(|(a, b)| a.1.iter().zip(&b.1).map(|(x, y)| (x - y).abs()))
                    .fold(0.0f64, f64::max)
            };
            let worst = difference(&got, &expected);
            if step == 1 {
                first = got.clone();
            }
            eprintln!(
                "{what} held, step {step}: max |u − u(λ = 1, 1, 1)| {worst:.1e} of {scale:.4e}; change since step 1 {:.1e} (ramped in 3 steps, step 1: {third:.4e})",
                difference(&got, &first)
            );
            assert!(worst <= 1e-12 * scale, "{what} step {step}: {worst:e}");
            if step == 1 {
                assert!((third / scale - 1.0 / 3.0).abs() < 0.05, "{third} {scale}");
            }
        }
        for dir in [full_dir, thirds_dir, dir] {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// Bad input names the line: a Hencky body cannot carry an initial stress; a K0 state outside
/// the yield surface is rejected when the simulation is built, naming the call; `held` must
/// be a flag and the second argument of body_force a map of known options.
#[test]
fn initial_stresses_a_model_cannot_carry_and_bad_held_options_are_rejected() {
    let error = scene(
        "hencky",
        &column("", HELD_WEIGHT, K0_STATE, "load_steps(1)"),
    )
    .unwrap_err();
    assert!(error.contains(":7") && error.contains("hencky"), "{error}");
    // q = (1 − K0) γ (10 − y) reaches 0.4 × 200 = 80 > σ_y = 50
    let weak = "model: \"von_mises\", sigma_y: 50.0, ";
    let spec = scene(
        "weak",
        &column(weak, HELD_WEIGHT, K0_STATE, "load_steps(1)"),
    )
    .unwrap();
    let dir = common::temp_dir("geostatic-run", "weak");
    let error = Simulation::<2>::new(&spec, &dir)
        .err()
        .expect("rejected")
        .to_string();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        error.contains("initial_stress") && error.contains("line 7"),
        "{error}"
    );
    for bad in [
        "body_force([0.0, -10.0], #{ held: 1 });",
        "body_force([0.0, -10.0], #{ hold: true });",
        "body_force([0.0, -10.0], true);",
    ] {
        let error = scene("bad-held", &column("", bad, "", "load_steps(1)")).unwrap_err();
        eprintln!("{bad}: {error}");
        assert!(
            error.contains(":4") && error.contains("body_force"),
            "{error}"
        );
    }
}

/// Prandtl's strip footing on Tresca soil with weight (`scripts/strip_footing.rhai`
/// `--set weight=true`: γ = 5 (γB/s_u = 0.5), K0 = 0.8 as initial stresses, the weight held,
/// then the footing pushed to δ/B = 0.05 in 10 steps; linear MPM with F-bar, 4 and 8 cells
/// across B). For uniform s_u the weight does not change the collapse pressure of a surface
/// footing (q_u − γD = (2 + π) s_u with D = 0). Checked against the weightless run of the same
/// resolution: the largest q/s_u of the curve within 1 % (observed +0.5 % and +0.4 %), every
/// step within 3 % (observed at most 2.3 %: the 8-cell curve with weight drops in its last
/// step, docs/plasticity.md), the largest within 20 % above 2 + π as for the weightless
/// footing (`tests/fbar.rs`), and the finer one closer.
#[test]
fn the_weight_does_not_change_the_tresca_footings_limit_pressure() {
    let prandtl = 2.0 + std::f64::consts::PI;
    let curve = |cells: &str, weight: &str| {
        common::tresca_footing_linear(&[("cells", cells), ("fbar", "true"), ("weight", weight)])
    };
    let largest = |curve: &[f64]| curve.iter().copied().fold(f64::MIN, f64::max);
    let mut limits = Vec::new();
    for cells in ["4", "8"] {
        let (weightless, heavy) = (curve(cells, "false"), curve(cells, "true"));
        let worst = weightless
            .iter()
            .zip(&heavy)
            .map(|(a, b)| (b / a - 1.0).abs())
            .fold(0.0f64, f64::max);
        let (q0, q) = (largest(&weightless), largest(&heavy));
        eprintln!(
            "{cells} cells: largest q/s_u weightless {q0:.4}, with weight {q:.4} ({:+.2} %); largest difference of a step {:.2} %\n  weightless  {weightless:.3?}\n  with weight {heavy:.3?}",
            100.0 * (q / q0 - 1.0),
            100.0 * worst
        );
        assert!((q / q0 - 1.0).abs() < 0.01, "{q} {q0}");
        assert!(worst < 0.03, "{worst}");
        assert!(q > prandtl && q < 1.2 * prandtl, "{q}");
        limits.push(q);
    }
    assert!(limits[1] < limits[0], "{limits:?}");
}
