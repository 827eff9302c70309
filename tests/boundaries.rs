//! Boundaries that follow the material (`surface_displace`), reactions and histories: uniaxial
//! strain against the exact Hencky solution, the conditions' tangents against finite
//! differences, the global balance of reactions and loads, and the warning of a grid-node
//! `displace` that the material no longer follows.

mod common;

use bevy_ecs::system::RunSystemOnce;
use impm::components::Trial;
use impm::effects::surface_conditions::{assemble_surface_conditions, find_boundary_supports};
use impm::records::StepRecord;
use impm::resources::{GridFields, LoadStep, Newton};
use impm::run::{Simulation, load_scene};
use impm::solver::NO_DOF;
use impm::stages::{evaluate_basis, number_dofs};

/// Young's modulus and Poisson's ratio of the uniaxial-strain scenes.
const E: f64 = 1000.0;
const NU: f64 = 0.3;

/// Loads a scene written inline, with overrides.
fn scene_sim<const D: usize>(name: &str, text: &str, set: &[(&str, &str)]) -> Simulation<D> {
    let dir = common::temp_dir("boundaries", name);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}.rhai"));
    std::fs::write(&path, text).unwrap();
    let spec = load_scene(&path, &common::overrides(set)).unwrap_or_else(|e| panic!("{e}"));
    Simulation::<D>::new(&spec, &dir.join("out")).unwrap_or_else(|e| panic!("{e}"))
}

/// A block of unit width (and depth) and height 1 on rollers (base and sides), its top moved
/// vertically to `stretch` times its height by a rough `surface_displace` (no lateral
/// motion): uniaxial strain. The grid reaches 0.2 above the top (room for tension).
fn uniaxial<const D: usize>() -> String {
    let (lower, upper, cells, corners, displacement, fixes) = match D {
        2 => (
            "[0.0, 0.0]",
            "[1.0, 1.2]",
            "[cells, cells]",
            "[[0.0, 1.0], [1.0, 1.0]]",
            "[0.0, stretch - 1.0]",
            "fix(|x| x[1] == 0.0, [1]);\nfix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);",
        ),
        _ => (
            "[0.0, 0.0, 0.0]",
            "[1.0, 1.0, 1.2]",
            "[2, 2, cells]",
            "[[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]",
            "[0.0, 0.0, stretch - 1.0]",
            "fix(|x| x[2] == 0.0, [2]);\nfix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\nfix(|x| x[1] == 0.0 || x[1] == 1.0, [1]);",
        ),
    };
    let top = if D == 2 {
        "[1.0, 1.0]"
    } else {
        "[1.0, 1.0, 1.0]"
    };
    format!(
        r#"
let basis = "bspline";
let order = 2;
let integration = "points";
let method = "penalty";
let cells = 4;
let steps = 5;
let ppc = 2;
let stretch = 0.8;
grid(#{{ lower: {lower}, upper: {upper}, cells: {cells}, basis: basis, order: order, integration: integration }});
const m = material(#{{ name: "m", E: {E}, nu: {NU}, density: 1.0 }});
body(#{{ name: "block", material: m, region: box({lower}, {top}), ppc: ppc }});
{fixes}
surface_displace(#{{ on: {corners}, displacement: {displacement}, method: method, name: "top" }});
load_steps(steps);
"#
    )
}

/// The scene of [`uniaxial`] with `surface_displace`'s option `nitsche: variant` (the same
/// lines: the line numbers of messages do not change).
fn with_variant(text: &str, variant: &str) -> String {
    text.replace(
        "method: method,",
        &format!("method: method, nitsche: \"{variant}\","),
    )
}

/// Runs to the end; returns the simulation and the records.
fn run<const D: usize>(
    name: &str,
    text: &str,
    set: &[(&str, &str)],
) -> (Simulation<D>, Vec<StepRecord>) {
    let mut sim = scene_sim::<D>(name, text, set);
    sim.run(|_| {})
        .unwrap_or_else(|e| panic!("{name} {set:?}: {e}"));
    let steps = sim.summary.steps.clone();
    (sim, steps)
}

/// The Hencky uniaxial-strain stresses for the vertical stretch s: (σ_vertical, σ_lateral) =
/// ((λ + 2μ) ln s / s, λ ln s / s).
fn hencky_uniaxial(stretch: f64) -> (f64, f64) {
    let lame = E * NU / ((1.0 + NU) * (1.0 - 2.0 * NU));
    let mu = E / (2.0 * (1.0 + NU));
    let strain = stretch.ln() / stretch;
    ((lame + 2.0 * mu) * strain, lame * strain)
}

/// Every point's σ against the exact uniaxial-strain state; returns the largest relative
/// difference (to |σ_vertical|) and the top's recorded displacement and reaction.
fn uniaxial_errors<const D: usize>(sim: &mut Simulation<D>, stretch: f64) -> (f64, f64, f64) {
    let (vertical, lateral) = hencky_uniaxial(stretch);
    let v = D - 1;
    let mut worst = 0.0f64;
    let mut q = sim.world.query::<&Trial<D>>();
    for trial in q.iter(&sim.world) {
        let sigma = trial.0.cauchy();
        for a in 0..3 {
            for b in 0..3 {
                let exact = match (a == b, a == v) {
                    (true, true) => vertical,
                    (true, false) => lateral,
                    _ => 0.0,
                };
                worst = worst.max((sigma[(a, b)] - exact).abs() / vertical.abs());
            }
        }
    }
    let axis = ["x", "y", "z"][v];
    let last = sim.summary.steps.last().unwrap();
    let u = last.measure(&format!("top_displacement_{axis}")).unwrap();
    let r = last.measure(&format!("top_reaction_{axis}")).unwrap();
    (worst, u, r)
}

/// Where the method integrates a homogeneous deformation exactly (GIMP, CPDI, B-splines with
/// domain integration), Nitsche's method gives the exact Hencky state at every point, the
/// prescribed top displacement and the exact reaction (σ times the unit top area) to 1e-6, in
/// compression to 80 % and tension to 120 %, 2D and 3D, in 5 load steps; with the symmetric
/// variant (the default on this elastic block) and, in 2D with GIMP, the non-symmetric one.
#[test]
fn nitsche_gives_the_exact_uniaxial_strain_where_the_method_is_exact() {
    let cases: [(&[(&str, &str)], &str); 4] = [
        (&[("basis", "gimp")], "auto"),
        (&[("basis", "gimp")], "nonsymmetric"),
        (&[("basis", "cpdi")], "auto"),
        (&[("integration", "domain")], "auto"),
    ];
    for stretch in ["0.8", "1.2"] {
        for (case, variant) in cases {
            let mut set = case.to_vec();
            set.extend([("method", "nitsche"), ("stretch", stretch)]);
            let s: f64 = stretch.parse().unwrap();
            let text = with_variant(&uniaxial::<2>(), variant);
            let (mut sim, steps) = run::<2>("exact2d", &text, &set);
            let symmetric = steps.last().unwrap().measure("top_symmetric").unwrap();
            assert_eq!(symmetric, if variant == "auto" { 1.0 } else { 0.0 });
            let (worst, u, r) = uniaxial_errors(&mut sim, s);
            let (exact, _) = hencky_uniaxial(s);
            eprintln!(
                "2D {set:?} {variant}: σ error {worst:.1e}, top u {u}, reaction {r} (exact {exact})"
            );
            assert_material_reads_the_prescribed_state(&steps, 2, s);
            assert!(worst < 1e-6, "2D {set:?}: σ off by {worst:e}");
            assert!(
                (u - (s - 1.0)).abs() < 1e-6 * (s - 1.0).abs(),
                "2D {set:?}: u {u}"
            );
            assert!(
                (r - exact).abs() < 1e-6 * exact.abs(),
                "2D {set:?}: reaction {r} vs {exact}"
            );
        }
        let set = [
            ("method", "nitsche"),
            ("stretch", stretch),
            ("integration", "domain"),
        ];
        let s: f64 = stretch.parse().unwrap();
        let (mut sim, steps) = run::<3>("exact3d", &uniaxial::<3>(), &set);
        let (worst, u, r) = uniaxial_errors(&mut sim, s);
        let (exact, _) = hencky_uniaxial(s);
        eprintln!("3D {set:?}: σ error {worst:.1e}, top u {u}, reaction {r} (exact {exact})");
        assert_material_reads_the_prescribed_state(&steps, 3, s);
        assert!(worst < 1e-6, "3D: σ off by {worst:e}");
        assert!((u - (s - 1.0)).abs() < 1e-6 * (s - 1.0).abs(), "3D: u {u}");
        assert!(
            (r - exact).abs() < 1e-6 * exact.abs(),
            "3D: reaction {r} vs {exact}"
        );
    }
}

/// The material check of a condition (module docs of `surface_conditions.rs`, "The material at
/// the condition") where the state is exact: at every step the material's mean displacement at
/// the top, read from the material points by the linear fit, is the prescribed one to 1e-9
/// relative, its mean offset from it below 1e-9 of the prescribed displacement, and the force the
/// material's stress carries across the top equals the reaction to 1e-6 relative.
fn assert_material_reads_the_prescribed_state(steps: &[StepRecord], dim: usize, stretch: f64) {
    let axis = ["x", "y", "z"][dim - 1];
    for step in steps {
        let prescribed = (stretch - 1.0) * step.load_factor;
        let m = |name: &str| step.measure(&format!("top_{name}")).unwrap();
        let u = m(&format!("material_displacement_{axis}"));
        let offset = m("material_offset");
        let (force, reaction) = (
            m(&format!("material_force_{axis}")),
            m(&format!("reaction_{axis}")),
        );
        assert!(
            (u - prescribed).abs() < 1e-9 * prescribed.abs() && offset < 1e-9 * prescribed.abs(),
            "{dim}D step {}: material u {u} offset {offset:e}, prescribed {prescribed}",
            step.step
        );
        assert!(
            (force - reaction).abs() < 1e-6 * reaction.abs(),
            "{dim}D step {}: material force {force} vs reaction {reaction}",
            step.step
        );
    }
}

/// The default (penalty, γ = 1e4) with the methods that do not integrate the homogeneous state
/// exactly (point-integrated quadratic B-splines, 2 points per cell and axis): the top's
/// material displacement within 0.1 % of the prescribed one and the reaction within 2 % of the
/// exact force, with 5 and with 40 load steps (a total displacement: the step count changes
/// the answer only by the method's own error), in compression and tension, 2D and 3D.
#[test]
fn penalty_default_holds_the_total_displacement_with_any_step_count() {
    for stretch in ["0.8", "1.2"] {
        let s: f64 = stretch.parse().unwrap();
        let (exact, _) = hencky_uniaxial(s);
        for steps in ["5", "40"] {
            let set = [("stretch", stretch), ("steps", steps)];
            let (mut sim, _) = run::<2>("penalty2d", &uniaxial::<2>(), &set);
            let (worst, u, r) = uniaxial_errors(&mut sim, s);
            eprintln!("2D {set:?}: σ spread {worst:.1e}, top u {u}, reaction {r} (exact {exact})");
            assert!(
                (u - (s - 1.0)).abs() < 1e-3 * (s - 1.0).abs(),
                "2D {set:?}: u {u}"
            );
            assert!(
                (r - exact).abs() < 0.02 * exact.abs(),
                "2D {set:?}: {r} vs {exact}"
            );
        }
        let set = [("stretch", stretch), ("steps", "5")];
        let (mut sim, _) = run::<3>("penalty3d", &uniaxial::<3>(), &set);
        let (worst, u, r) = uniaxial_errors(&mut sim, s);
        eprintln!("3D {set:?}: σ spread {worst:.1e}, top u {u}, reaction {r} (exact {exact})");
        assert!((u - (s - 1.0)).abs() < 1e-3 * (s - 1.0).abs(), "3D: u {u}");
        assert!((r - exact).abs() < 0.02 * exact.abs(), "3D: {r} vs {exact}");
    }
}

/// The material's top displacement (a probe at the top's centre: the least-squares linear fit
/// of the nearest material points, not the boundary points where the condition holds the grid
/// field) and the reaction after `steps` load steps, relative to the prescribed displacement
/// and the exact (Hencky) force; the spread of the points' stress (the largest difference from
/// the exact state over |σ_vertical|); and whether the run warned.
fn material_errors<const D: usize>(set: &[(&str, &str)], stretch: f64) -> (f64, f64, f64, bool) {
    let at = if D == 2 {
        "[0.5, 1.0]"
    } else {
        "[0.5, 0.5, 1.0]"
    };
    let text = format!(
        "{}probe(#{{ name: \"mid\", at: {at} }});\n",
        uniaxial::<D>()
    );
    let (mut sim, steps) = run::<D>("material", &text, set);
    let (spread, ..) = uniaxial_errors(&mut sim, stretch);
    let axis = ["x", "y", "z"][D - 1];
    let last = steps.last().unwrap();
    let u = last.measure(&format!("mid_displacement_{axis}")).unwrap();
    let r = last.measure(&format!("top_reaction_{axis}")).unwrap();
    let (exact, _) = hencky_uniaxial(stretch);
    (
        (u - (stretch - 1.0)) / (stretch - 1.0),
        (r - exact) / exact,
        spread,
        !sim.summary.warnings.is_empty(),
    )
}

/// Point-integrated B-splines (q = 2, 3) with 2 × 2 (2 × 2 × 2) points per cell and linear
/// MPM, penalty default, 5 load steps, compression to 80 % and tension to 120 %, 2D and 3D
/// (coarse: 2 × 2 × 4 cells): the issue asks for the top's *material* displacement within
/// 0.1 % of the prescribed one and the reaction within 1 % of the Hencky force. Asserted where
/// it holds (measured: q = 2 in 2D, compression and tension, material −2.9e-4 / −2.8e-4,
/// reaction −0.15 % / −0.55 %; q = 2 in 3D, compression, +9.1e-5, −0.15 %); the reaction alone
/// where only it holds (q = 2 3D tension: material +2.5e-3, reaction −0.55 %; q = 3 2D
/// compression: −3.3e-3, −0.31 %). The other cases do not meet the bounds and are recorded in
/// docs/boundaries.md with their figures and causes (the method's own error: q = 3 2D tension
/// −5.0e-3 / −2.0 %, linear MPM −4.5 % / −14 %); 3D cubic compression on this coarse grid,
/// where the material leaves the condition (reaction −80 %), must warn (3D cubic tension warns
/// at step 1 and then fails to converge at step 4: left out, recorded in the docs).
#[test]
fn material_follows_the_condition_with_point_integrated_bases() {
    type Case<'a> = (
        usize,
        &'a str,
        &'a [(&'a str, &'a str)],
        Option<f64>,
        Option<f64>,
    );
    let q2: &[(&str, &str)] = &[("order", "2")];
    let q3: &[(&str, &str)] = &[("order", "3")];
    let linear: &[(&str, &str)] = &[("basis", "linear"), ("order", "1")];
    let cases: [Case; 11] = [
        (2, "0.8", q2, Some(1e-3), Some(0.01)),
        (2, "1.2", q2, Some(1e-3), Some(0.01)),
        (2, "0.8", q3, None, Some(0.01)),
        (2, "1.2", q3, None, None),
        (2, "0.8", linear, None, None),
        (2, "1.2", linear, None, None),
        (3, "0.8", q2, Some(1e-3), Some(0.01)),
        (3, "1.2", q2, None, Some(0.01)),
        (3, "0.8", q3, None, None),
        (3, "0.8", linear, None, None),
        (3, "1.2", linear, None, None),
    ];
    for (dim, stretch, basis, material_bound, reaction_bound) in cases {
        let mut set = basis.to_vec();
        set.extend([("stretch", stretch), ("steps", "5")]);
        let s: f64 = stretch.parse().unwrap();
        let (material, reaction, spread, warned) = if dim == 2 {
            material_errors::<2>(&set, s)
        } else {
            material_errors::<3>(&set, s)
        };
        eprintln!(
            "{dim}D {set:?}: material top displacement {material:+.2e}, reaction {:+.3} %, σ spread {:.1} %, warned {warned}",
            100.0 * reaction,
            100.0 * spread
        );
        if let Some(bound) = material_bound {
            assert!(
                material.abs() < bound,
                "{dim}D {set:?}: material {material:e}"
            );
        }
        if let Some(bound) = reaction_bound {
            assert!(
                reaction.abs() < bound,
                "{dim}D {set:?}: reaction {reaction:e}"
            );
        }
        if dim == 3 && basis == q3 {
            assert!(
                reaction.abs() > 0.1 && warned,
                "3D cubic: {reaction:e}, {warned}"
            );
        }
    }
}

/// The methods that integrate a homogeneous deformation exactly give the same answer with 5
/// and with 40 load steps (the condition prescribes a total displacement): the penalty
/// default with GIMP, CPDI and domain-averaged B-splines in 2D, domain-averaged B-splines in
/// 3D, in compression to 80 % and tension to 120 %: the top's displacement and reaction of the
/// two runs equal to 1e-6 relative, and every point within 1e-4 of the exact state in both (the
/// penalty's own error, 6.5e-5; Nitsche's method is exact with either step count:
/// `nitsche_gives_the_same_exact_answer_with_5_and_40_steps`).
#[test]
fn exact_methods_give_the_same_answer_with_5_and_40_steps() {
    let cases: [(usize, &[(&str, &str)]); 4] = [
        (2, &[("basis", "gimp")]),
        (2, &[("basis", "cpdi")]),
        (2, &[("integration", "domain")]),
        (3, &[("integration", "domain")]),
    ];
    for stretch in ["0.8", "1.2"] {
        let s: f64 = stretch.parse().unwrap();
        for (dim, case) in cases {
            let mut results = Vec::new();
            for steps in ["5", "40"] {
                let mut set = case.to_vec();
                set.extend([("stretch", stretch), ("steps", steps)]);
                let (worst, u, r) = if dim == 2 {
                    let (mut sim, _) = run::<2>("steps2d", &uniaxial::<2>(), &set);
                    uniaxial_errors(&mut sim, s)
                } else {
                    let (mut sim, _) = run::<3>("steps3d", &uniaxial::<3>(), &set);
                    uniaxial_errors(&mut sim, s)
                };
                eprintln!("{dim}D {set:?}: σ error {worst:.1e}, top u {u:.9}, reaction {r:.6}");
                assert!(worst < 1e-4, "{dim}D {set:?}: σ off by {worst:e}");
                results.push((u, r));
            }
            let ((u5, r5), (u40, r40)) = (results[0], results[1]);
            assert!(
                (u5 - u40).abs() < 1e-6 * u5.abs() && (r5 - r40).abs() < 1e-6 * r5.abs(),
                "{dim}D {case:?} stretch {stretch}: 5 steps u {u5} R {r5}, 40 steps u {u40} R {r40}"
            );
        }
    }
}

/// Nitsche's method where the method integrates a homogeneous deformation exactly (GIMP, CPDI,
/// B-splines with domain integration; both variants in 2D, the symmetric one in 3D), in
/// compression to 80 % and tension to 120 %: with 5 and with 40 load steps every point's σ is
/// the Hencky value to 1e-6 (of |σ_vertical|) at the end, the top's displacement and reaction
/// are exact to 1e-6 relative at every step, and the two runs give the same top displacement
/// and reaction to 1e-6. The 40-step compression takes the top through the grid line
/// 3 × 0.3 = 0.8999999999999999 at the end of step 20 (1 − 20 × 0.005 = 0.9): the round-off
/// sliver of module docs of `surface_conditions.rs` ("Round-off slivers"), where Nitsche's
/// answer used to leave the exact one (GIMP −1.70 % at step 40, CPDI failing at step 21).
#[test]
fn nitsche_gives_the_same_exact_answer_with_5_and_40_steps() {
    type Case<'a> = (usize, &'a [(&'a str, &'a str)], &'a str);
    let cases: [Case; 7] = [
        (2, &[("basis", "gimp")], "auto"),
        (2, &[("basis", "gimp")], "nonsymmetric"),
        (2, &[("basis", "cpdi")], "auto"),
        (2, &[("basis", "cpdi")], "nonsymmetric"),
        (2, &[("integration", "domain")], "auto"),
        (2, &[("integration", "domain")], "nonsymmetric"),
        (3, &[("integration", "domain")], "auto"),
    ];
    for stretch in ["0.8", "1.2"] {
        let s: f64 = stretch.parse().unwrap();
        for (dim, case, variant) in cases {
            let mut results = Vec::new();
            for steps in ["5", "40"] {
                let mut set = case.to_vec();
                set.extend([
                    ("method", "nitsche"),
                    ("stretch", stretch),
                    ("steps", steps),
                ]);
                let ((worst, u, r), records) = if dim == 2 {
                    let text = with_variant(&uniaxial::<2>(), variant);
                    let (mut sim, records) = run::<2>("nitsche_steps2d", &text, &set);
                    (uniaxial_errors(&mut sim, s), records)
                } else {
                    let text = with_variant(&uniaxial::<3>(), variant);
                    let (mut sim, records) = run::<3>("nitsche_steps3d", &text, &set);
                    (uniaxial_errors(&mut sim, s), records)
                };
                let axis = ["x", "y", "z"][dim - 1];
                let mut worst_step = 0.0f64;
                for record in &records {
                    let stretch_now = 1.0 + (s - 1.0) * record.load_factor;
                    let (exact, _) = hencky_uniaxial(stretch_now);
                    let u_now = record.measure(&format!("top_displacement_{axis}")).unwrap();
                    let r_now = record.measure(&format!("top_reaction_{axis}")).unwrap();
                    worst_step = worst_step
                        .max((u_now - (stretch_now - 1.0)).abs() / (s - 1.0).abs())
                        .max((r_now - exact).abs() / exact.abs());
                }
                eprintln!(
                    "{dim}D {set:?} {variant}: σ error {worst:.1e}, worst step error {worst_step:.1e}, top u {u:.12}, reaction {r:.9}"
                );
                assert!(worst < 1e-6, "{dim}D {set:?} {variant}: σ off by {worst:e}");
                assert!(
                    worst_step < 1e-6,
                    "{dim}D {set:?} {variant}: a step's top displacement or reaction off by {worst_step:e}"
                );
                results.push((u, r));
            }
            let ((u5, r5), (u40, r40)) = (results[0], results[1]);
            assert!(
                (u5 - u40).abs() < 1e-6 * u5.abs() && (r5 - r40).abs() < 1e-6 * r5.abs(),
                "{dim}D {case:?} {variant} stretch {stretch}: 5 steps u {u5} R {r5}, 40 steps u {u40} R {r40}"
            );
        }
    }
}

/// `method: "nitsche"` takes the symmetric variant on an elastic body and the non-symmetric
/// one on a plastic body (von Mises); `nitsche: "symmetric"` / `"nonsymmetric"` forces either;
/// `impm check` and the run's log (`scene::scene_notes`) name the variant; the option with the
/// penalty method is an error naming the line.
#[test]
fn nitsche_variant_follows_the_material_and_can_be_forced() {
    use impm::effects::surface_conditions::{Imposition, SurfaceConditions};
    use impm::plugin::Plugin;
    let plastic = |text: &str| {
        text.replace(
            "density: 1.0 });",
            "density: 1.0, model: \"von_mises\", sigma_y: 2.0, H: 300.0 });",
        )
    };
    let imposition = |name: &str, text: &str| -> Result<(Imposition, String), String> {
        let dir = common::temp_dir("boundaries", name);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{name}.rhai"));
        std::fs::write(&path, text).unwrap();
        let spec = load_scene(&path, &common::overrides(&[("method", "nitsche")]));
        let _ = std::fs::remove_dir_all(&dir);
        let spec = spec.map_err(|e| e.to_string())?;
        let described = impm::effects::surface_conditions::SurfaceConditionsModule
            .describe(&spec)
            .unwrap();
        let imposition = spec.part::<SurfaceConditions>().unwrap().0[0].imposition;
        let notes = impm::scene::scene_notes(&spec);
        assert!(
            notes.len() == 1 && notes[0].ends_with(&format!("imposed by {}", imposition.word())),
            "{name}: {notes:?}"
        );
        Ok((imposition, described))
    };
    let elastic = uniaxial::<2>();
    let cases = [
        ("elastic", elastic.clone(), Imposition::SymmetricNitsche),
        ("plastic", plastic(&elastic), Imposition::Nitsche),
        (
            "forced",
            with_variant(&elastic, "nonsymmetric"),
            Imposition::Nitsche,
        ),
        (
            "forced_plastic",
            with_variant(&plastic(&elastic), "symmetric"),
            Imposition::SymmetricNitsche,
        ),
    ];
    for (name, text, expected) in cases {
        let (got, described) = imposition(name, &text).unwrap();
        eprintln!("{name}: {described}");
        assert_eq!(got, expected, "{name}");
        assert!(described.contains(expected.word()), "{name}: {described}");
    }
    let text =
        with_variant(&elastic, "symmetric").replace("method: method,", "method: \"penalty\",");
    let error = imposition("penalty", &text).unwrap_err();
    assert!(
        error.contains("15") && error.contains("option 'nitsche'"),
        "{error}"
    );
}

/// The assembled tangent with a surface condition equals finite differences of the assembled
/// internal force at a deformed state (after two steps of compression, the boundary inside a
/// cell) and a large trial increment: penalty (symmetric), non-symmetric Nitsche, and
/// symmetric Nitsche with its adjoint term's tangent frozen at the step's first iterate (here
/// that of step 2: the tangent is exact but not symmetric) and frozen at the state itself
/// (Newton iteration 0: the tangent is exact and symmetric, to 1e-9 of its largest entry).
#[test]
fn surface_condition_tangents_match_finite_differences() {
    let cases = [
        ("penalty", "auto", false),
        ("nitsche", "nonsymmetric", false),
        ("nitsche", "symmetric", false),
        ("nitsche", "symmetric", true),
    ];
    for (method, variant, frozen_here) in cases {
        let text = with_variant(&uniaxial::<2>(), variant);
        let mut sim = scene_sim::<2>("fd", &text, &[("method", method), ("cells", "3")]);
        sim.step().unwrap();
        sim.step().unwrap();
        *sim.world.resource_mut::<LoadStep>() = LoadStep {
            number: 3,
            factor: 0.6,
            previous_factor: 0.4,
            completes_step: true,
        };
        sim.world.run_system_once(evaluate_basis::<2>).unwrap();
        sim.world
            .run_system_once(find_boundary_supports::<2>)
            .unwrap();
        sim.world.run_system_once(number_dofs::<2>).unwrap();
        {
            let mut fields = sim.world.resource_mut::<GridFields<2>>();
            for node in 0..fields.dofs.len() {
                let dofs = fields.dofs[node];
                let t = node as f64;
                for (k, &dof) in dofs.iter().enumerate() {
                    if dof != NO_DOF {
                        fields.increment[node][k] = 0.02 * (1.3 * t + k as f64).sin() - 0.01;
                    }
                }
            }
        }
        let add = |world: &mut bevy_ecs::world::World| {
            world
                .run_system_once(assemble_surface_conditions::<2>)
                .unwrap();
        };
        if frozen_here {
            // the first iterate of a step: the adjoint term takes this state's tangent
            sim.world.resource_mut::<Newton>().iterations = 0;
            common::internal_force_of::<impm::material::Hencky>(&mut sim, &add);
            sim.world.resource_mut::<Newton>().iterations = 1;
        }
        let (worst, scale) = common::assert_tangent_matches_finite_differences_of::<
            impm::material::Hencky,
        >(&mut sim, &add, method == "penalty" || frozen_here);
        eprintln!(
            "{method} {variant} (frozen here: {frozen_here}): max |K - K_fd| = {worst:.2e} of {scale:.2e}"
        );
    }
}

/// Newton converges quadratically with either condition: once the residual is below 0.1,
/// each next one (above round-off, 1e-10: a stiff penalty raises it) is at most 10 r².
#[test]
fn newton_converges_quadratically_with_surface_conditions() {
    for (method, variant) in [
        ("penalty", "auto"),
        ("nitsche", "nonsymmetric"),
        ("nitsche", "symmetric"),
    ] {
        let text = with_variant(&uniaxial::<2>(), variant);
        let (_, steps) = run::<2>("quadratic", &text, &[("method", method)]);
        eprintln!(
            "{method} {variant}: residuals {:?}",
            steps.iter().map(|s| &s.residuals).collect::<Vec<_>>()
        );
        let mut checked = 0;
        for step in &steps {
            for pair in step.residuals.windows(2) {
                if pair[0] < 0.1 && pair[1] > 1e-10 {
                    checked += 1;
                    assert!(
                        pair[1] <= 10.0 * pair[0] * pair[0],
                        "{method}, step {}: residuals {:?}",
                        step.step,
                        step.residuals
                    );
                }
            }
        }
        assert!(
            checked > 0,
            "{method}: some iterations in the quadratic range"
        );
    }
}

/// Reactions of every constraint and surface condition plus the external loads (body force,
/// point loads, tractions) sum to zero at every converged step, to the Newton tolerance, 2D
/// and 3D.
#[test]
fn reactions_balance_the_loads() {
    let text2 = r#"
grid(#{ lower: [0.0, 0.0], upper: [2.0, 1.5], cells: [4, 3], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1000.0, nu: 0.3, density: 2.0 });
body(#{ name: "block", material: m, region: box([0.0, 0.0], [2.0, 1.0]), ppc: 2 });
body_force([0.0, -10.0]);
point_load_total(|x| x[0] > 1.7 && x[1] > 0.7, [5.0, -8.0]);
traction(#{ on: [[2.0, 0.2], [2.0, 0.8]], traction: [-30.0, 4.0] });
fix(|x| x[1] == 0.0);
surface_displace(#{ on: [[0.0, 1.0], [1.0, 1.0]], displacement: [0.0, -0.05], name: "platen" });
solver(#{ tolerance: 1e-10 });
load_steps(3);
"#;
    let (_, steps) = run::<2>("balance2d", text2, &[]);
    check_balance(&steps, &["fix1", "platen"], 2);
    let text3 = r#"
grid(#{ lower: [0.0, 0.0, 0.0], upper: [1.0, 1.0, 1.5], cells: [2, 2, 3], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1000.0, nu: 0.3, density: 2.0 });
body(#{ name: "block", material: m, region: box([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]), ppc: 2 });
body_force([0.0, 0.0, -10.0]);
point_load_total(|x| x[2] > 0.8, [1.0, 20.0, -3.0]);
traction(#{ on: [[1.0, 0.0, 0.2], [1.0, 1.0, 0.2], [1.0, 0.0, 0.8]], traction: [-20.0, 0.0, 3.0] });
fix(|x| x[2] == 0.0);
surface_displace(#{ on: [[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [0.0, 1.0, 1.0]], displacement: [0.0, 0.0, -0.03], method: "nitsche", name: "platen" });
solver(#{ tolerance: 1e-10 });
load_steps(2);
"#;
    let (_, steps) = run::<3>("balance3d", text3, &[]);
    check_balance(&steps, &["fix1", "platen"], 3);
}

fn check_balance(steps: &[StepRecord], conditions: &[&str], dim: usize) {
    for step in steps {
        for axis in ["x", "y", "z"].iter().take(dim) {
            let external = step.measure(&format!("external_force_{axis}")).unwrap();
            let reactions: Vec<f64> = conditions
                .iter()
                .map(|c| step.measure(&format!("{c}_reaction_{axis}")).unwrap())
                .collect();
            let scale = reactions.iter().fold(external.abs(), |m, r| m.max(r.abs()));
            let sum = external + reactions.iter().sum::<f64>();
            eprintln!(
                "{dim}D step {}, {axis}: external {external:.6}, reactions {reactions:?}, sum {sum:.2e}",
                step.step
            );
            assert!(scale > 1.0, "a meaningful load");
            assert!(
                sum.abs() < 1e-8 * scale,
                "{dim}D step {}, {axis}: sum {sum:e}",
                step.step
            );
        }
    }
}

/// A grid-node `displace` that compresses a block loses its material (the grid is reset every
/// step): the run warns, in `summary.json` too; stretching the same block in one step is
/// exact and does not warn.
#[test]
fn grid_node_displace_warns_when_the_material_leaves_it() {
    let text = r#"
let lift = -0.2;
let steps = 5;
grid(#{ lower: [0.0, 0.0], upper: [1.0, 1.0], cells: [4, 4], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1000.0, nu: 0.0, density: 1.0 });
body(#{ name: "block", material: m, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 2 });
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);
displace(|x| x[1] == 1.0, [1], [lift]);
load_steps(steps);
"#;
    let (sim, _) = run::<2>("warn", text, &[]);
    let json = sim.summary.to_json();
    let warnings = json["warnings"].as_array().expect("a warning");
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    let warning = warnings[0].as_str().unwrap();
    assert!(
        warning.contains("line 9") && warning.contains("surface_displace"),
        "{warning}"
    );
    let (sim, _) = run::<2>("nowarn", text, &[("lift", "0.05"), ("steps", "1")]);
    assert!(
        sim.summary.warnings.is_empty(),
        "{:?}",
        sim.summary.warnings
    );
}

/// The separation check of surface conditions (docs/boundaries.md): point-integrated cubic
/// B-splines with 2 × 2 points per cell, compression to 80 % in 40 steps, hold the grid's field
/// at the top where the condition says but the material does not follow (its top row of points
/// stays about 0.35 cells above the platen), and quadratic splines with 3 × 3 points per cell
/// part less but still 11 % of the reaction: the reaction is far off the exact force, and the
/// run warns (log and `summary.json`) naming the condition's line. The same run with quadratic
/// splines and 2 × 2 points (reaction within 2 %), with cubic splines in 5 steps, and with domain
/// integration (exact) stays silent, its separation below 0.6 of the threshold at every step.
/// The material check (the mean offset of the material's displacement at the top, read by the
/// linear fit of the material points, from the prescribed one, over the same threshold) agrees:
/// above 1.5 where the run warns (measured 6.84 and 1.63), below 0.7 where it is silent
/// (measured 0.59, 0.08, 0.05 and 0.00); one warning per condition from the two checks.
#[test]
fn surface_condition_warns_when_the_material_does_not_follow_it() {
    use impm::effects::surface_conditions::separation_threshold;
    let (exact, _) = hencky_uniaxial(0.8);
    let cell = 0.25;
    // the largest ratio of the material check (the material's mean offset at the condition
    // over the same threshold) at any step
    let worst_material = |steps: &[StepRecord]| -> f64 {
        steps
            .iter()
            .map(|s| s.measure("top_material_ratio").unwrap())
            .fold(0.0, f64::max)
    };
    // the largest separation over its threshold at any step
    let worst = |steps: &[StepRecord]| {
        let mut prescribed = 0.0f64;
        let mut worst = 0.0f64;
        for step in steps {
            prescribed = prescribed.max(0.2 * step.load_factor.abs());
            let separation = step.measure("top_separation").unwrap();
            worst = worst.max(separation / separation_threshold(prescribed, cell));
        }
        worst
    };
    for set in [
        [("order", "3"), ("ppc", "2")],
        [("order", "2"), ("ppc", "3")],
    ] {
        let mut set = set.to_vec();
        set.push(("steps", "40"));
        let (sim, steps) = run::<2>("separate", &uniaxial::<2>(), &set);
        let r = steps.last().unwrap().measure("top_reaction_y").unwrap();
        let worst = worst(&steps);
        let material = worst_material(&steps);
        eprintln!(
            "{set:?}: reaction {r} (exact {exact}), separation / threshold {worst}, material offset / threshold {material}"
        );
        assert!((r - exact).abs() > 0.1 * exact.abs(), "{r} vs {exact}");
        assert!(worst > 1.5, "{set:?}: {worst}");
        assert!(material > 1.5, "{set:?}: material {material}");
        // one warning of the run's checks, after the point-quadrature warning both get
        // before the run (cubic splines; quadratic with 3 points per cell)
        let json = sim.summary.to_json();
        let warnings = json["warnings"].as_array().expect("a warning");
        assert_eq!(warnings.len(), 2, "{warnings:?}");
        assert!(
            warnings[0].as_str().unwrap().contains("quadrature"),
            "{warnings:?}"
        );
        let warning = warnings[1].as_str().unwrap();
        assert!(
            warning.contains("line 15") && warning.contains("surface condition 'top'"),
            "{warning}"
        );
    }
    let silent: [&[(&str, &str)]; 4] = [
        &[("order", "2"), ("steps", "40")],
        &[("order", "2"), ("steps", "40"), ("stretch", "1.2")],
        &[("order", "3"), ("steps", "5")],
        &[("order", "3"), ("steps", "40"), ("integration", "domain")],
    ];
    for set in silent {
        let (sim, steps) = run::<2>("follow", &uniaxial::<2>(), set);
        let worst = worst(&steps);
        let material = worst_material(&steps);
        let r = steps.last().unwrap().measure("top_reaction_y").unwrap();
        eprintln!(
            "{set:?}: reaction {r}, separation / threshold {worst}, material offset / threshold {material}"
        );
        assert!(material < 0.7, "{set:?}: material {material}");
        // the run's checks are silent (cubic splines get the point-quadrature warning before
        // the run: `point_quadrature_is_warned_before_the_run`)
        let checks: Vec<_> = sim
            .summary
            .warnings
            .iter()
            .filter(|w| !w.contains("quadrature"))
            .collect();
        assert!(checks.is_empty(), "{set:?}: {checks:?}");
        assert!(worst < 0.6, "{set:?}: {worst}");
    }
}

/// The silent wrong answers neither check of the run can see (the material follows the
/// condition; the error is the point quadrature inside the body) are warned about before the
/// run, in `scene_warnings` (`impm check`, the log) and `summary.json`: point-integrated linear
/// MPM and cubic B-splines (measured on this block in tension to 120 %, 5 steps: reaction
/// −14.1 % and −2.0 %), quadratic B-splines with 3 × 3 points per cell (material displacement
/// −0.94 % in compression) and uGIMP (+2.3 % at 40 steps). The warning names the condition's
/// line and the alternatives. Not warned: cpGIMP, CPDI, domain integration (exact), quadratic
/// B-splines with 2 × 2 and 4 × 4 points (reaction −0.55 % and −0.04 %, material −2.9e-4),
/// a support (zero displacement) on linear MPM, and linear FEM with a grid-node `displace`.
/// Two coarse runs check that the warned case is wrong (linear MPM in tension, reaction off by
/// more than 5 %) and the warning reaches `summary.json`, and that a silent case is right
/// (quadratic B-splines, 2 × 2 points, tension: reaction within 1 %).
#[test]
fn point_quadrature_is_warned_before_the_run() {
    let text = uniaxial::<2>();
    let ugimp = text.replace(
        "integration: integration",
        "integration: integration, gimp: \"fixed\"",
    );
    let support = text.replace("displacement: [0.0, stretch - 1.0], ", "");
    // linear FEM on the block (a body-fitted mesh: the grid ends at the top), the top's nodes
    // displaced
    let fem = text.replace("upper: [1.0, 1.2]", "upper: [1.0, 1.0]").replace(
        "surface_displace(#{ on: [[0.0, 1.0], [1.0, 1.0]], displacement: [0.0, stretch - 1.0], method: method, name: \"top\" });",
        "displace(|x| x[1] == 1.0, [1], [stretch - 1.0]);",
    );
    let warnings = |name: &str, text: &str, set: &[(&str, &str)]| {
        let dir = common::temp_dir("boundaries", name);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{name}.rhai"));
        std::fs::write(&path, text).unwrap();
        let spec = load_scene(&path, &common::overrides(set)).unwrap_or_else(|e| panic!("{e}"));
        let _ = std::fs::remove_dir_all(&dir);
        impm::scene::scene_warnings(&spec)
    };
    let linear: &[(&str, &str)] = &[("basis", "linear"), ("order", "1"), ("stretch", "1.2")];
    // (scene, overrides, a figure the warning gives)
    type Warned<'a> = (&'a str, &'a [(&'a str, &'a str)], &'a str);
    let warned: [Warned; 5] = [
        (&text, linear, "14 % off in tension"),
        (
            &text,
            &[("order", "3"), ("stretch", "1.2")],
            "2.0 % off in tension",
        ),
        (&text, &[("order", "4")], "order 4"),
        (&text, &[("ppc", "3")], "0.94 %"),
        (&ugimp, &[("basis", "gimp")], "uGIMP"),
    ];
    for (text, set, figure) in warned {
        let found = warnings("warned", text, set);
        eprintln!("{set:?}: {found:?}");
        assert_eq!(found.len(), 1, "{set:?}: {found:?}");
        let w = &found[0];
        for part in [
            "line 15: 'top'",
            figure,
            "\"gimp\"",
            "\"cpdi\"",
            "integration: \"domain\"",
            "basis \"fem\"",
        ] {
            assert!(w.contains(part), "{set:?}: '{part}' not in {w}");
        }
    }
    let silent: [(&str, &[(&str, &str)]); 7] = [
        (&text, &[("basis", "gimp")]),
        (&text, &[("basis", "cpdi")]),
        (&text, &[("order", "3"), ("integration", "domain")]),
        (&text, &[("order", "2")]),
        (&text, &[("order", "2"), ("ppc", "4")]),
        (&support, linear),
        (&fem, &[("basis", "fem"), ("ppc", "1")]),
    ];
    for (text, set) in silent {
        let found = warnings("silent", text, set);
        assert!(found.is_empty(), "{set:?}: {found:?}");
    }
    let (exact, _) = hencky_uniaxial(1.2);
    let (sim, steps) = run::<2>("quadrature", &uniaxial::<2>(), linear);
    let r = steps.last().unwrap().measure("top_reaction_y").unwrap();
    eprintln!("linear MPM, tension: reaction {r} (exact {exact})");
    assert!((r - exact).abs() > 0.05 * exact, "{r} vs {exact}");
    let json = sim.summary.to_json();
    let recorded = json["warnings"].as_array().expect("warnings");
    assert!(
        recorded
            .iter()
            .any(|w| w.as_str().unwrap().contains("line 15: 'top'")),
        "{recorded:?}"
    );
    let (_, steps) = run::<2>("quadrature", &uniaxial::<2>(), &[("stretch", "1.2")]);
    let r = steps.last().unwrap().measure("top_reaction_y").unwrap();
    eprintln!("quadratic B-splines, 2 x 2 points, tension: reaction {r} (exact {exact})");
    assert!((r - exact).abs() < 0.01 * exact, "{r} vs {exact}");
}

/// A run resumed after a condition has warned does not warn again: the conditions' "already
/// warned" flags and largest prescribed displacements are part of the saved state (checkpoint
/// part "surface conditions"). The cubic 40-step compression warns at step 18 (its separation
/// then grows to the end); a new simulation restored from the state after step 24, with the
/// warnings recorded so far (as `--resume` restores them), runs to the end with the same one
/// warning of the run's checks and the uninterrupted run's reaction (bit for bit).
#[test]
fn a_resumed_run_does_not_warn_twice() {
    let set = [("order", "3"), ("steps", "40")];
    let checks = |warnings: &[String]| {
        warnings
            .iter()
            .filter(|w| w.contains("surface condition 'top'"))
            .count()
    };
    let mut whole = scene_sim::<2>("resumed_whole", &uniaxial::<2>(), &set);
    for _ in 0..24 {
        whole.step().unwrap();
    }
    assert_eq!(
        checks(&whole.summary.warnings),
        1,
        "{:?}",
        whole.summary.warnings
    );
    let saved = whole.save_state();
    let so_far = whole.summary.warnings.clone();
    whole.run(|_| {}).unwrap();
    assert_eq!(checks(&whole.summary.warnings), 1);
    let mut resumed = scene_sim::<2>("resumed", &uniaxial::<2>(), &set);
    resumed.restore_state(&saved).unwrap();
    resumed.summary.warnings = so_far;
    resumed.run(|_| {}).unwrap();
    let last = |sim: &Simulation<2>| {
        sim.summary
            .steps
            .last()
            .unwrap()
            .measure("top_reaction_y")
            .unwrap()
    };
    eprintln!(
        "resumed after step 24: warnings {:?}, reaction {} (uninterrupted {})",
        resumed.summary.warnings,
        last(&resumed),
        last(&whole)
    );
    assert_eq!(
        checks(&resumed.summary.warnings),
        1,
        "{:?}",
        resumed.summary.warnings
    );
    assert_eq!(last(&resumed), last(&whole));
}

/// `history.csv` has one row per converged step with the step, the load factor and every
/// recorded quantity, named from the scene, equal to the records of `summary.json`.
#[test]
fn history_has_a_row_per_step_with_named_columns() {
    let (sim, steps) = run::<2>("history", &uniaxial::<2>(), &[]);
    let path = sim.summary.path.with_file_name("history.csv");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(&header[..2], &["step", "load_factor"]);
    for name in [
        "top_reaction_y",
        "top_traction_y",
        "top_displacement_y",
        "fix1_reaction_y",
    ] {
        assert!(header.contains(&name), "{header:?}");
    }
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), steps.len());
    let column = header
        .iter()
        .position(|h| *h == "top_displacement_y")
        .unwrap();
    for (row, step) in rows.iter().zip(&steps) {
        assert_eq!(row[0], step.step as f64);
        assert_eq!(row[1], step.load_factor);
        assert_eq!(row[column], step.measure("top_displacement_y").unwrap());
    }
}

/// The footing pressure of `scripts/strip_footing.rhai` (rough, elastic, δ/B = 1e-3, one step)
/// after its last step.
fn footing_pressure(set: &[(&str, &str)]) -> f64 {
    let mut all = vec![("settlement", "0.001"), ("steps", "1")];
    all.extend_from_slice(set);
    let sim = common::run_shipped::<2>("strip_footing.rhai", &all);
    let last = sim.summary.steps.last().unwrap();
    assert!((last.measure("settlement").unwrap() - 1e-3).abs() < 1e-3 * 1e-3);
    last.measure("footing_pressure").unwrap()
}

/// The elastic rough strip footing at small settlement: the pressure under the footing with the
/// material-surface condition (quadratic B-splines, 16 cells across B) within 2 % of linear FEM
/// on the same geometry with 32 cells across B. The rigid footing's edge makes both converge
/// like h: their Richardson extrapolations (from 8 and 16, and 16 and 32 cells) agree to 0.5 %.
#[test]
fn strip_footing_matches_linear_fem() {
    let mpm = [
        footing_pressure(&[("cells", "8")]),
        footing_pressure(&[("cells", "16")]),
    ];
    let fem = [
        footing_pressure(&[("cells", "16"), ("basis", "fem")]),
        footing_pressure(&[("cells", "32"), ("basis", "fem")]),
    ];
    let extrapolated = |p: [f64; 2]| 2.0 * p[1] - p[0];
    eprintln!(
        "footing pressure: MPM {mpm:?} -> {:.4}, FEM {fem:?} -> {:.4}",
        extrapolated(mpm),
        extrapolated(fem)
    );
    assert!(
        (mpm[1] - fem[1]).abs() < 0.02 * fem[1],
        "{mpm:?} vs {fem:?}"
    );
    assert!(
        (extrapolated(mpm) - extrapolated(fem)).abs() < 0.005 * extrapolated(fem),
        "{mpm:?} vs {fem:?}"
    );
}

/// `record(...)` of a quantity no module measures is an error naming its line and the
/// quantities there are.
#[test]
fn record_of_an_unknown_quantity_is_an_error() {
    let text = uniaxial::<2>() + "record(#{ name: \"s\", quantity: \"top_reaction_q\" });\n";
    let dir = common::temp_dir("boundaries", "record");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("record.rhai");
    std::fs::write(&path, text).unwrap();
    let spec = load_scene(&path, &[]).unwrap();
    let error = Simulation::<2>::new(&spec, &dir.join("out"))
        .err()
        .expect("an error")
        .to_string();
    assert!(
        error.contains("line 17")
            && error.contains("top_reaction_q")
            && error.contains("top_reaction_y"),
        "{error}"
    );
}

/// `impm plot` draws history.csv columns of a run as SVG and PNG; an unknown column is an
/// error that lists the columns there are.
#[test]
fn plot_draws_history_columns() {
    let dir = common::temp_dir("boundaries", "plot");
    let scene = common::shipped_scene("strip_footing.rhai");
    let out = dir.display().to_string();
    let run = common::impm(&[
        "run",
        &scene.display().to_string(),
        "--out",
        &out,
        "--set",
        "steps=3",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let plot = common::impm(&[
        "plot",
        &out,
        "--x",
        "settlement",
        "--y",
        "footing_pressure,load_factor",
    ]);
    assert!(
        plot.status.success(),
        "{}",
        String::from_utf8_lossy(&plot.stderr)
    );
    for extension in ["svg", "png"] {
        let file = dir.join(format!(
            "history_settlement_footing_pressure_load_factor.{extension}"
        ));
        let size = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
        assert!(size > 1000, "{}: {size} bytes", file.display());
    }
    let svg =
        std::fs::read_to_string(dir.join("history_settlement_footing_pressure_load_factor.svg"))
            .unwrap();
    assert!(svg.contains("footing_pressure") && svg.contains("settlement"));
    let bad = common::impm(&["plot", &out, "--x", "settlement", "--y", "pressure"]);
    let message = String::from_utf8_lossy(&bad.stderr);
    assert!(
        !bad.status.success()
            && message.contains("no column 'pressure'")
            && message.contains("footing_pressure"),
        "{message}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A probe reads a homogeneous deformation exactly, inside the points and outside their hull
/// (at the top corner, where the fit extrapolates): with Nitsche and GIMP (2D) or domain
/// integration (3D) the uniaxial strain is exact at every point, so the probe's displacement,
/// Cauchy stress and F equal the exact ones to 1e-6.
#[test]
fn probes_read_a_homogeneous_deformation_exactly() {
    let stretch = 0.8;
    let (vertical, lateral) = hencky_uniaxial(stretch);
    type Probes<'a> = &'a [(&'a str, Vec<f64>)];
    for dim in [2, 3] {
        let (probes, set): (Probes, Vec<(&str, &str)>) = if dim == 2 {
            (
                &[("inside", vec![0.3, 0.77]), ("corner", vec![1.0, 1.0])],
                vec![("basis", "gimp"), ("method", "nitsche")],
            )
        } else {
            (
                &[
                    ("inside", vec![0.3, 0.6, 0.77]),
                    ("corner", vec![1.0, 1.0, 1.0]),
                ],
                vec![("integration", "domain"), ("method", "nitsche")],
            )
        };
        let mut text = if dim == 2 {
            uniaxial::<2>()
        } else {
            uniaxial::<3>()
        };
        for (name, at) in probes {
            text +=
                &format!("probe(#{{ name: \"{name}\", at: {at:?}, stress: true, F: true }});\n");
        }
        let steps = if dim == 2 {
            run::<2>("probe_exact", &text, &set).1
        } else {
            run::<3>("probe_exact", &text, &set).1
        };
        let last = steps.last().unwrap();
        let v = dim - 1;
        let axes = ["x", "y", "z"];
        for (name, at) in probes {
            let value = |key: String| {
                last.measure(&key)
                    .unwrap_or_else(|| panic!("{key} not recorded"))
            };
            for a in 0..dim {
                let exact_u = if a == v { (stretch - 1.0) * at[v] } else { 0.0 };
                let u = value(format!("{name}_displacement_{}", axes[a]));
                assert!(
                    (u - exact_u).abs() < 1e-6 * 0.2,
                    "{dim}D {name} u_{a} {u} vs {exact_u}"
                );
                for b in 0..dim {
                    let exact_f = match (a == b, a == v) {
                        (true, true) => stretch,
                        (true, false) => 1.0,
                        _ => 0.0,
                    };
                    let f = value(format!("{name}_F_{}{}", axes[a], axes[b]));
                    assert!((f - exact_f).abs() < 1e-6, "{dim}D {name} F_{a}{b} {f}");
                }
            }
            for (a, axis) in axes.iter().enumerate() {
                let exact = if a == v { vertical } else { lateral };
                let s = value(format!("{name}_stress_{axis}{axis}"));
                assert!(
                    (s - exact).abs() < 1e-6 * vertical.abs(),
                    "{dim}D {name} σ_{a}{a} {s} vs {exact}"
                );
            }
            let shear = value(format!("{name}_stress_xy"));
            assert!(
                shear.abs() < 1e-6 * vertical.abs(),
                "{dim}D {name} σ_xy {shear}"
            );
        }
    }
}

/// The tip deflection of `scripts/beam_tip_probe.rhai` (its `tip_deflection` column).
fn tip_deflection(set: &[(&str, &str)]) -> f64 {
    let sim = common::run_shipped::<2>("beam_tip_probe.rhai", set);
    let last = sim.summary.steps.last().unwrap();
    let external = last.measure("external_force_y").unwrap();
    assert!(
        (external + 0.2).abs() < 1e-12,
        "{set:?}: the load's resultant is {external}"
    );
    last.measure("tip_deflection").unwrap()
}

/// The cantilever of `scripts/beam_tip_probe.rhai`: a point load at the tip's mid-depth, where
/// there is no material point, read by a tip probe. Quadratic B-splines with 8 cells per unit
/// length give the tip deflection within 1 % of linear FEM on the same beam (Richardson
/// extrapolation of 16 and 32 cells per unit: both converge like h², FEM through its shear
/// locking); the MPM's own extrapolation (8 and 16) agrees with FEM's to 0.1 %.
#[test]
fn cantilever_tip_probe_matches_linear_fem() {
    let mpm = [
        tip_deflection(&[("cells_per_unit", "8")]),
        tip_deflection(&[("cells_per_unit", "16")]),
    ];
    let fem = [
        tip_deflection(&[("cells_per_unit", "16"), ("basis", "fem")]),
        tip_deflection(&[("cells_per_unit", "32"), ("basis", "fem")]),
    ];
    let extrapolated = |d: [f64; 2]| d[1] + (d[1] - d[0]) / 3.0;
    let reference = extrapolated(fem);
    eprintln!(
        "tip deflection: MPM {mpm:?} -> {:.6}, FEM {fem:?} -> {reference:.6}",
        extrapolated(mpm)
    );
    assert!(
        (mpm[0] - reference).abs() < 0.01 * reference.abs(),
        "{mpm:?} vs {reference}"
    );
    assert!((mpm[1] - reference).abs() < (mpm[0] - reference).abs());
    assert!(
        (extrapolated(mpm) - reference).abs() < 1e-3 * reference.abs(),
        "{mpm:?} vs {fem:?}"
    );
}

/// A point load at the position of a material point is the point load on that point: the
/// load point's basis is the point's own (every node of its support active), so the runs agree
/// to round-off.
#[test]
fn a_point_load_at_a_material_point_is_the_point_load_on_it() {
    let beam = std::fs::read_to_string(common::shipped_scene("beam_tip_probe.rhai")).unwrap();
    // the material point at (9.9375, 1.4375) with 4 cells per unit length and ppc 2
    let at = beam.replace(
        "point_load_at(#{ at: [length, mid], force: [0.0, force] });",
        "point_load_at(#{ at: [9.9375, 1.4375], force: [0.0, force] });",
    );
    let on = beam.replace(
        "point_load_at(#{ at: [length, mid], force: [0.0, force] });",
        "point_load(|x| x[0] > 9.93 && x[0] < 9.94 && x[1] > 1.43 && x[1] < 1.44, [0.0, force]);",
    );
    assert_ne!(at, beam);
    assert_ne!(on, beam);
    let tip = |name: &str, text: &str| {
        let (_, steps) = run::<2>(name, text, &[]);
        steps.last().unwrap().measure("tip_deflection").unwrap()
    };
    let (a, b) = (tip("load_at", &at), tip("load_on", &on));
    assert!((a - b).abs() < 1e-12 * b.abs(), "{a} vs {b}");
    assert!(b < -0.05, "{b}");
}

/// A probe or a point load away from every body is an error naming its line.
#[test]
fn probes_and_point_loads_off_the_body_are_errors() {
    let dir = common::temp_dir("boundaries", "probe_off");
    std::fs::create_dir_all(&dir).unwrap();
    for call in [
        "probe(#{ name: \"far\", at: [0.5, 3.0] });",
        "point_load_at(#{ at: [0.5, 3.0], force: [0.0, 1.0] });",
        "probe(#{ name: \"short\", at: [0.5, 0.5, 0.5] });",
    ] {
        let path = dir.join("off.rhai");
        std::fs::write(&path, uniaxial::<2>() + call + "\n").unwrap();
        let error = load_scene(&path, &[]).expect_err(call).to_string();
        assert!(error.contains("off.rhai:17:"), "{call}: {error}");
        assert!(
            error.contains("not in or on a body") || error.contains("components"),
            "{call}: {error}"
        );
    }
}

/// `impm study` over the cantilever of `scripts/beam_tip_probe.rhai` uses the scene's
/// reference tip deflection as its error measure: every run has the relative error of
/// `tip_deflection` (as its history.csv says), the error falls with the cells, and the error
/// charts are drawn and titled with the quantity. `--reference` replaces the scene's value.
#[test]
fn a_study_over_a_recorded_quantity_draws_its_error_chart() {
    use impm::study::{StudyPlan, Sweep, parse_reference, run_study};
    for reference in [None, Some("tip_deflection=-0.0732")] {
        let out_dir = common::temp_dir("boundaries", &format!("study{}", reference.is_some()));
        let _ = std::fs::remove_dir_all(&out_dir);
        let plan = StudyPlan {
            scene: common::shipped_scene("beam_tip_probe.rhai"),
            sweeps: vec![Sweep::parse("cells_per_unit=2,4,8").unwrap()],
            fixed: Vec::new(),
            out_dir: out_dir.clone(),
            against: "cells_per_unit".into(),
            profiles: false,
            timeout: None,
            limits: Default::default(),
            reference: reference.map(|r| parse_reference(r).unwrap()),
        };
        let records = run_study(&plan, |_| {}).unwrap();
        let value = if reference.is_some() {
            -0.0732
        } else {
            -0.07319
        };
        let mut errors = Vec::new();
        for record in &records {
            let history =
                std::fs::read_to_string(out_dir.join(&record.run_dir).join("history.csv")).unwrap();
            let (names, columns) = impm::study::read_history(&history).unwrap();
            let column = names.iter().position(|n| n == "tip_deflection").unwrap();
            let q = *columns[column].last().unwrap();
            let error = record.error.expect("an error measure");
            assert!(
                (error - (q - value).abs() / value.abs()).abs() < 1e-12,
                "{error} for {q} against {value}"
            );
            assert_eq!(record.error_of.as_deref(), Some("tip_deflection"));
            errors.push(error);
        }
        assert!(errors[0] > errors[1] && errors[1] > errors[2], "{errors:?}");
        for chart in ["error_vs_cells_per_unit.svg", "error_vs_time.svg"] {
            let svg = std::fs::read_to_string(out_dir.join(chart)).unwrap();
            assert!(svg.contains("relative error of tip_deflection"), "{chart}");
            assert!(
                svg.contains("<polyline") || svg.contains("<path"),
                "{chart} is empty"
            );
        }
        let md = std::fs::read_to_string(out_dir.join("study.md")).unwrap();
        assert!(md.contains("relative error of tip_deflection"), "{md}");
        assert!(!md.contains("no run reports an error"), "{md}");
    }
}

/// `impm check` lists every load declaration with its line, what it selects (count and
/// coordinate range) and its total force at load factor 1: a body force (ρ b times the body's
/// volume), point loads on every selected point and in total, a traction (h times the
/// segment's length) and a point load at a position.
/// What `impm check` prints of the scene `text` (written to a folder named by `tag`), which
/// must pass.
fn checked(tag: &str, text: &str) -> String {
    let dir = common::temp_dir("boundaries", tag);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.rhai");
    std::fs::write(&path, text).unwrap();
    let output = common::impm(&["check", path.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&output.stdout).to_string();
    assert!(
        output.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    stdout
}

/// `impm check` lists the calls of one line (a loop) once, summed: their points counted
/// together, the range of their positions and their total force (four `point_load_at` of
/// 0.25 each along the top, from line 4, and one more from line 5 listed apart).
#[test]
fn check_sums_the_calls_of_one_line() {
    let text = r#"grid(#{ lower: [0.0, 0.0], upper: [2.0, 1.5], cells: [4, 3], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1000.0, nu: 0.3, density: 2.0 });
body(#{ name: "block", material: m, region: box([0.0, 0.0], [2.0, 1.0]), ppc: 2 });
for i in 0..4 { point_load_at(#{ at: [0.25 + 0.5 * i, 1.0], force: [0.0, -0.25] }); }
point_load_at(#{ at: [1.0, 0.5], force: [1.0, 0.0] });
fix(|x| x[1] == 0.0);
load_steps(1);
"#;
    let stdout = checked("check_calls", text);
    for expected in [
        "line 4: point_load_at (4 calls): 4 load points, x in [0.25, 1.0] .. [1.75, 1.0], total force [0.0, -1.0]",
        "line 5: point_load_at: 1 load point, x in [1.0, 0.5] .. [1.0, 0.5], total force [1.0, 0.0]",
    ] {
        assert!(
            stdout.contains(expected),
            "missing '{expected}' in\n{stdout}"
        );
    }
    assert_eq!(stdout.matches("line 4:").count(), 1, "{stdout}");
}

#[test]
fn check_lists_every_load_with_its_total_force() {
    let text = r#"grid(#{ lower: [0.0, 0.0], upper: [2.0, 1.5], cells: [4, 3], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1000.0, nu: 0.3, density: 2.0 });
body(#{ name: "block", material: m, region: box([0.0, 0.0], [2.0, 1.0]), ppc: 2 });
body_force([0.0, -10.0]);
point_load(|x| x[1] > 0.7, [1.0, 0.0]);
point_load_total(|x| x[0] > 1.7, [5.0, -8.0]);
traction(#{ on: [[2.0, 0.2], [2.0, 0.8]], traction: [-30.0, 4.0] });
point_load_at(#{ at: [1.0, 1.0], force: [0.0, -3.0] });
fix(|x| x[1] == 0.0);
load_steps(1);
"#;
    let stdout = checked("check_loads", text);
    for expected in [
        "line 4: body_force: 32 material points (all), x in [0.125, 0.125] .. [1.875, 0.875], total force [0.0, -40.0]",
        "line 5: point_load: 8 material points, x in [0.125, 0.875] .. [1.875, 0.875], total force [8.0, 0.0]",
        "line 6: point_load_total: 4 material points, x in [1.875, 0.125] .. [1.875, 0.875], total force [5.0, -8.0]",
        "line 7: traction: 3 traction points, x in [2.0, 0.3] .. [2.0, 0.7], total force [-18.0, 2.4] at load factor 1",
        "line 8: point_load_at: 1 load point, x in [1.0, 1.0] .. [1.0, 1.0], total force [0.0, -3.0]",
        "line 9: fix1",
    ] {
        assert!(
            stdout.contains(expected),
            "missing '{expected}' in\n{stdout}"
        );
    }
}
