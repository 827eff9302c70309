//! Materials behind the trait: a model written outside the crate (the compressible neo-Hookean
//! of `examples/custom_material`) has the consistent tangent of its stress, runs from a scene by
//! its word, and mixes with Hencky bodies in one scene (one stress-update system per kind).

#[path = "../examples/custom_material/neo_hookean.rs"]
mod neo_hookean;

mod common;

use nalgebra::{SMatrix, SVector};

use impm::effects::{self, materials::MaterialModule};
use impm::explain::explain_scene;
use impm::material::Hencky;
use impm::mechanics::tangent_against_finite_differences;
use impm::plugin::ModuleSet;
use impm::run::Simulation;
use neo_hookean::NeoHookean;

fn modules() -> ModuleSet {
    effects::built_in().with(MaterialModule::<NeoHookean>::default())
}

/// The point tangent of the neo-Hookean model against central finite differences of the point
/// internal force (what assembly uses), at a stretched, sheared state.
fn check_tangent<const D: usize>() {
    let model = NeoHookean::new(1000.0, 0.3);
    let grads: Vec<SVector<f64, D>> = (0..3)
        .map(|n| SVector::from_fn(|a, _| 0.3 * (n as f64 + 1.0) - 0.2 * a as f64 + 0.05))
        .collect();
    let u: Vec<SVector<f64, D>> = (0..3)
        .map(|n| SVector::from_fn(|a, _| 0.05 * ((n * 3 + a) as f64).sin()))
        .collect();
    let f_prev =
        SMatrix::<f64, D, D>::from_fn(|a, b| if a == b { 0.9 + 0.05 * a as f64 } else { 0.04 });
    let (worst, scale) =
        tangent_against_finite_differences(&model, &(), &f_prev, &grads, &u, 1e-7).unwrap();
    assert!(
        worst < 1e-6 * scale,
        "D = {D}: tangent error {worst:e}, scale {scale:e}"
    );
}

#[test]
fn a_material_written_outside_the_crate_has_its_consistent_tangent() {
    check_tangent::<1>();
    check_tangent::<2>();
    check_tangent::<3>();
}

/// The column with a Hencky lower half and a neo-Hookean upper half: the stress is statically
/// determinate (paper eq. 11) whatever the materials, and each point's stretch is its own
/// model's answer to that stress. Two stress-update systems run, one per kind.
#[test]
fn bodies_of_different_material_kinds_share_a_scene() {
    let dir = common::temp_dir("materials", "mixed");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("mixed.rhai");
    std::fs::write(
        &path,
        r#"grid(#{ lower: [0.0], upper: [50.0], cells: [50], basis: "bspline", order: 3 });
const soft = material(#{ name: "soft", E: 1.0e6, nu: 0.0, density: 1.0 });
const rubber = material(#{ name: "rubber", model: "neo_hookean", E: 1.0e6, nu: 0.25, density: 1.0 });
body(#{ name: "lower", material: soft, region: box([0.0], [25.0]), ppc: 4 });
body(#{ name: "upper", material: rubber, region: box([25.0], [50.0]), ppc: 4 });
body_force([-2000.0]);
fix(|x| x[0] == 0.0, [0]);
load_steps(10);
analytic_column(#{ axis: 0, height: 50.0, material: soft, body_force: -2000.0 });
"#,
    )
    .unwrap();
    let modules = modules();
    let spec = modules.load_scene(&path, &[]).unwrap();
    let explanation = explain_scene(&spec, &modules).unwrap();
    let stress_updates: Vec<&str> = explanation
        .systems
        .iter()
        .filter(|s| s.name.starts_with("stress::update_stress"))
        .map(|s| s.name.as_str())
        .collect();
    assert_eq!(
        stress_updates,
        [
            "stress::update_stress<Hencky>",
            "stress::update_stress<NeoHookean>"
        ]
    );
    let mut sim = Simulation::<1>::with_modules(&spec, &dir.join("out"), &modules).unwrap();
    sim.run(|_| {}).unwrap();
    let error = sim.summary.final_error().unwrap();
    assert!(error < 2e-3, "eq. 15 error {error:e}");
    // each point's stretch against its model's answer to the exact stress sigma = b (50 - X)
    let hencky = Hencky::new(1.0e6, 0.0).unwrap();
    let rubber = NeoHookean::new(1.0e6, 0.25);
    let solve = |sigma_of: &dyn Fn(f64) -> f64, sigma: f64| {
        let mut f = 1.0f64;
        for _ in 0..60 {
            let slope = (sigma_of(f + 1e-7) - sigma_of(f - 1e-7)) / 2e-7;
            f -= (sigma_of(f) - sigma) / slope;
        }
        f
    };
    let hencky_sigma = |f: f64| hencky.constrained_modulus() * f.ln() / f;
    let rubber_sigma = |f: f64| rubber.uniaxial_cauchy(f);
    let mut query = sim.world.query::<(
        &impm::components::ReferencePosition<1>,
        &impm::components::DeformationGradient<1>,
        &impm::components::BodyIndex,
    )>();
    // the mean stretch error of each body (like eq. 15: the base cells carry the known
    // integration error of point-integrated B-splines)
    let mut sums = [(0.0f64, 0.0f64); 2];
    for (x, f, body) in query.iter(&sim.world) {
        let sigma = -2000.0 * (50.0 - x.0[0]);
        let exact = if body.0 == 0 {
            solve(&hencky_sigma, sigma)
        } else {
            solve(&rubber_sigma, sigma)
        };
        let sum = &mut sums[body.0 as usize];
        sum.0 += (f.0[(0, 0)] - exact).abs();
        sum.1 += 1.0;
    }
    let mean = sums.map(|(error, count)| error / count);
    // the two laws give different stretches at the interface (a model mixed up would show), and
    // the points follow their own law to a small fraction of that
    let at_interface = (solve(&hencky_sigma, -5e4) - solve(&rubber_sigma, -5e4)).abs();
    eprintln!(
        "mean stretch errors {mean:?}, difference of the laws at the interface {at_interface:e}"
    );
    assert!(at_interface > 5e-3, "{at_interface:e}");
    for error in mean {
        assert!(error < 0.05 * at_interface, "mean stretch error {error:e}");
    }
}

/// A model word that no module provides, and a parameter of another model, are errors at the
/// material's line.
#[test]
fn unknown_models_and_foreign_parameters_are_rejected_at_their_line() {
    let dir = common::temp_dir("materials", "unknown");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = |material: &str| {
        format!(
            "grid(#{{ lower: [0.0], upper: [1.0], cells: [2], basis: \"linear\" }});\n{material}\nbody(#{{ name: \"b\", material: m, region: box([0.0], [1.0]), ppc: 1 }});\nfix(|x| x[0] == 0.0);\nload_steps(1);\n"
        )
    };
    let path = dir.join("unknown.rhai");
    std::fs::write(
        &path,
        scene("const m = material(#{ name: \"m\", model: \"mooney\", E: 1.0, nu: 0.0, density: 1.0 });"),
    )
    .unwrap();
    let error = modules().load_scene(&path, &[]).unwrap_err();
    assert_eq!(error.line, Some(2), "{error}");
    assert!(
        error
            .message
            .contains("option 'model' must be \"hencky\", \"von_mises\", \"drucker_prager\", \"mohr_coulomb\" or \"neo_hookean\", got \"mooney\""),
        "{error}"
    );
    // without the module, the word is unknown
    let error = effects::built_in().load_scene(&path, &[]).unwrap_err();
    assert!(error.message.contains("must be \"hencky\""), "{error}");
    std::fs::write(
        &path,
        scene(
            "const m = material(#{ name: \"m\", model: \"neo_hookean\", E: 1.0, density: 1.0 });",
        ),
    )
    .unwrap();
    let error = modules().load_scene(&path, &[]).unwrap_err();
    assert!(
        error
            .message
            .contains("model \"neo_hookean\" needs parameter 'nu'"),
        "{error}"
    );
}
