//! `surface_displace(#{ .., until_stage: "s" })`: a footing pushed by a material-surface
//! condition in one stage and released at the start of a later one (its force at the end of
//! the stage before ramped down over the releasing stage, absent after it;
//! `effects::surface_conditions`, "Stages"). Elastic soil springs back to where it started,
//! plastic soil keeps a permanent set; the reactions fall to zero; bad values are refused with
//! the scene line.

mod common;

use impm::components::Trial;
use impm::run::Simulation;

/// Half of a rough strip footing (B = 1) on weightless soil 3 wide and 2 deep (`material`),
/// quadratic B-splines, 6 × 4 cells under the surface and one above, 2 × 2 Gauss points per
/// cell, rollers on the sides, base fixed (fix1). Stage "push" settles the footing by 0.01 B
/// in `push` steps (line 7), stage "release" (2 steps) releases it.
fn footing(material: &str, push: usize, until: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [3.0, 2.5], cells: [6, 5], basis: \"bspline\", order: 2 }});\n\
         const soil = {material};\n\
         body(#{{ name: \"soil\", material: soil, region: box([0.0, 0.0], [3.0, 2.0]), ppc: 2, placement: \"gauss\" }});\n\
         fix(|x| x[1] == 0.0);\n\
         fix(|x| x[0] == 0.0 || x[0] == 3.0, [0]);\n\
         stage(#{{ name: \"push\", steps: {push} }});\n\
         surface_displace(#{{ on: [[0.0, 2.0], [0.5, 2.0]], displacement: [0.0, -0.01], name: \"footing\"{until} }});\n\
         stage(#{{ name: \"release\", steps: 2 }});\n"
    )
}

const ELASTIC: &str = "material(#{ name: \"soil\", E: 1.0e5, nu: 0.3, density: 1.0 })";
/// Tresca soil, s_u = 50 (σ_y = √3 s_u): Prandtl's 5.14 s_u = 257 is well below the elastic
/// footing's pressure at 0.01 B (about 1100).
const TRESCA: &str = "material(#{ name: \"soil\", model: \"von_mises\", E: 1.0e5, nu: 0.3, sigma_y: 86.60254037844386, density: 1.0 })";

fn build(tag: &str, text: &str) -> Simulation<2> {
    let spec =
        common::scene_from_text("surface-release", tag, text).unwrap_or_else(|e| panic!("{e}"));
    Simulation::<2>::new(&spec, &common::temp_dir("surface-release-run", tag)).unwrap()
}

/// The footing's settlement, its reaction (the condition's force on the body, y) and the base's.
fn state(sim: &Simulation<2>) -> (f64, f64, f64) {
    let m = |name: &str| sim.summary.final_measure(name).unwrap();
    (
        m("footing_displacement_y"),
        m("footing_reaction_y"),
        m("fix1_reaction_y"),
    )
}

/// The largest |τ| component over the points.
fn largest_stress(sim: &mut Simulation<2>) -> f64 {
    let mut query = sim.world.query::<&Trial<2>>();
    query
        .iter(&sim.world)
        .map(|t| t.0.kirchhoff.amax())
        .fold(0.0, f64::max)
}

/// Elastic (Hencky) soil: pushed by 0.01 B in 2 steps, then released over 2 steps. At the end
/// of "push" the settlement is the prescribed one (to 1e-3: the penalty's gap). Half-way
/// through "release" the condition's force is half its value at the end of "push" (the ramp)
/// and the base carries it (equilibrium to 1e-6), and the settlement is half (to 2 %: the
/// response of elastic soil at strains of 1e-3 is nearly linear). At the end the footing is
/// back where it started (settlement within 1e-3 of the push), the reaction and the base's
/// force are zero (to 1e-6 of the push's) and the stress left is small (to 5e-3 of the largest
/// under the push, at the footing's edge: the updated-Lagrangian steps do not come back exactly
/// along their path). Measured: settlement −5.9e-7 after −9.9994e-3 (6e-5 of it), base force
/// 4.4e-11 of 567, stress left 2.2e-3 of the largest.
#[test]
fn elastic_soil_springs_back_when_the_footing_is_released() {
    let mut sim = build(
        "elastic",
        &footing(ELASTIC, 2, ", until_stage: \"release\""),
    );
    sim.write_initial_state().unwrap();
    sim.step().unwrap();
    sim.step().unwrap();
    let (pushed, force, base) = state(&sim);
    let loaded_stress = largest_stress(&mut sim);
    println!(
        "pushed: settlement {pushed:.6e}, reaction {force:.6e}, base {base:.6e}, largest |τ| {loaded_stress:.4e}"
    );
    assert!((pushed / -0.01 - 1.0).abs() < 1e-3, "{pushed}");
    assert!(
        force < 0.0 && (force + base).abs() < 1e-6 * force.abs(),
        "{force} {base}"
    );
    sim.step().unwrap();
    let (half, half_force, half_base) = state(&sim);
    println!(
        "half released: settlement {half:.6e}, reaction {half_force:.6e}, base {half_base:.6e}"
    );
    assert!(
        (half_force / (0.5 * force) - 1.0).abs() < 1e-12,
        "{half_force}"
    );
    assert!(
        (half_force + half_base).abs() < 1e-6 * force.abs(),
        "{half_force} {half_base}"
    );
    assert!(
        (half / (0.5 * pushed) - 1.0).abs() < 0.02,
        "{half} {pushed}"
    );
    sim.step().unwrap();
    let (end, end_force, end_base) = state(&sim);
    let left = largest_stress(&mut sim);
    println!(
        "released: settlement {end:.6e}, reaction {end_force:.6e}, base {end_base:.6e}, largest |τ| {left:.3e}"
    );
    assert!(end.abs() < 1e-3 * pushed.abs(), "{end}");
    assert_eq!(end_force, 0.0);
    assert!(end_base.abs() < 1e-6 * force.abs(), "{end_base}");
    assert!(left < 5e-3 * loaded_stress, "{left}");
    assert!(
        sim.summary.warnings.is_empty(),
        "{:?}",
        sim.summary.warnings
    );
}

/// Tresca soil (von Mises, s_u = 50, E = 1e5, ν = 0.3): pushed by 0.01 B in 8 steps, far past
/// the elastic range, then released over 2 steps. The footing keeps a permanent set (more than
/// half of the push: the soil under it has flowed), the base's force falls to zero with the
/// footing's (to 1e-6 of the push's force), and the rebound is elastic: the settlement
/// recovered is the push's force over the footing's elastic stiffness, read from the first
/// step of the push (elastic: the secant stiffness there), to 20 % (the stiffness of the
/// unloading soil is not quite that of the virgin soil: it has flowed and its residual
/// stresses are not zero). Measured: set −6.75e-3 of −1.0e-2, rebound 3.25e-3 against 3.05e-3
/// (+6.3 %), base force 5e-11 of 170.
#[test]
fn plastic_soil_keeps_a_permanent_set_when_the_footing_is_released() {
    let mut sim = build("tresca", &footing(TRESCA, 8, ", until_stage: \"release\""));
    sim.write_initial_state().unwrap();
    sim.step().unwrap();
    let (u1, f1, _) = state(&sim);
    let stiffness = f1 / -u1;
    for _ in 1..8 {
        sim.step().unwrap();
    }
    let (pushed, force, base) = state(&sim);
    println!(
        "pushed: settlement {pushed:.6e}, reaction {force:.6e} (first step {f1:.4e} at {u1:.4e}), base {base:.6e}"
    );
    assert!((pushed / -0.01 - 1.0).abs() < 1e-3, "{pushed}");
    for _ in 0..2 {
        sim.step().unwrap();
        let (u, f, b) = state(&sim);
        println!("release: settlement {u:.6e}, reaction {f:.6e}, base {b:.6e}");
        assert!((f + b).abs() < 1e-6 * force.abs(), "{f} {b}");
    }
    let (set, end_force, end_base) = state(&sim);
    let rebound = set - pushed;
    let elastic = force / stiffness;
    println!(
        "permanent set {set:.6e} of {pushed:.6e}; rebound {rebound:.4e} against {elastic:.4e} from the first step's stiffness ({:+.1} %)",
        100.0 * (rebound / elastic - 1.0)
    );
    assert!(set < 0.5 * pushed, "{set} {pushed}");
    assert_eq!(end_force, 0.0);
    assert!(end_base.abs() < 1e-6 * force.abs(), "{end_base}");
    assert!((rebound / elastic - 1.0).abs() < 0.2, "{rebound} {elastic}");
}

/// `until_stage` refused with the scene line: a stage that does not exist (the stages listed),
/// the condition's own stage, a scene without stages.
#[test]
fn bad_until_stage_is_refused_with_the_scene_line() {
    let cases = [
        (
            footing(ELASTIC, 2, ", until_stage: \"unload\""),
            "no stage is named 'unload'",
            ":7:",
        ),
        (
            footing(ELASTIC, 2, ", until_stage: \"push\""),
            "is not after the stage",
            ":7:",
        ),
        (
            footing(ELASTIC, 2, ", until_stage: \"release\"")
                .replace(
                    "stage(#{ name: \"push\", steps: 2 });\n",
                    "load_steps(2);\n",
                )
                .replace("stage(#{ name: \"release\", steps: 2 });\n", ""),
            "the scene has no stages",
            ":7:",
        ),
    ];
    for (index, (text, expected, line)) in cases.iter().enumerate() {
        let error = common::scene_from_text("surface-release-refusals", &index.to_string(), text)
            .expect_err(text);
        println!("{error}");
        assert!(error.contains(expected), "{error}");
        assert!(error.contains(line), "{error}");
        assert!(error.contains("surface_displace"), "{error}");
    }
}
