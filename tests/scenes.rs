//! The shipped scenes: each opens with what it demonstrates and the command that runs it, each
//! runs, and each schedule holds exactly the systems of the effects the scene uses.

mod common;

use std::path::{Path, PathBuf};

use impm::effects;
use impm::effects::tractions::Tractions;
use impm::explain::{ScheduledSystem, explain_scene, scheduled_systems};
use impm::output::read_vtu;
use impm::run::Simulation;
use impm::run::load_scene;
use impm::scene::SceneSpec;

fn scripts() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts")
}

fn shipped() -> Vec<PathBuf> {
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(scripts())
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "rhai"))
        .collect();
    scenes.sort();
    scenes
}

fn load(name: &str, overrides: &[(&str, &str)]) -> SceneSpec {
    let overrides: Vec<(String, String)> = overrides
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    load_scene(&scripts().join(name), &overrides).unwrap_or_else(|e| panic!("{e}"))
}

fn temp_dir(name: &str) -> PathBuf {
    common::temp_dir("scenes", name)
}

#[test]
fn every_shipped_scene_opens_with_what_it_demonstrates_and_its_command() {
    let scenes = shipped();
    assert!(scenes.len() >= 8, "{scenes:?}");
    for path in scenes {
        let text = std::fs::read_to_string(&path).unwrap();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let header: Vec<&str> = text.lines().take_while(|l| l.starts_with("//")).collect();
        assert!(header.len() >= 4, "{name}: no header comment");
        assert!(
            header.iter().any(|l| l.contains("Demonstrates:")),
            "{name}: the header says what it demonstrates"
        );
        let command = format!("cargo run --release -- run scripts/{name}");
        assert!(
            header
                .iter()
                .any(|l| l.trim_start_matches("//").trim().starts_with(&command)),
            "{name}: the header gives the command `{command}`"
        );
        load_scene(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
    }
}

/// The beam's tip deflection against Euler-Bernoulli, P L^3 / (3 E' I), within 4 % on the
/// default (coarse) grid; the scene's header records the convergence to 0.1 % at 8 cells per
/// unit length.
#[test]
fn beam_point_load_matches_euler_bernoulli() {
    let spec = load("beam_point_load.rhai", &[]);
    let mut sim = Simulation::<2>::new(&spec, &temp_dir("beam")).unwrap();
    sim.run(|_| {}).unwrap();
    let (e, nu, p, l, d) = (1.0e4, 0.3, -0.2, 10.0, 1.0);
    let expected = p * l * l * l / (3.0 * e / (1.0 - nu * nu) * d * d * d / 12.0);
    let mut q = sim.world.query::<(
        &impm::components::ReferencePosition<2>,
        &impm::components::Displacement<2>,
    )>();
    let tip: Vec<f64> = q
        .iter(&sim.world)
        .filter(|(x, _)| x.0[0] > 9.8)
        .map(|(_, u)| u.0[1])
        .collect();
    let mean = tip.iter().sum::<f64>() / tip.len() as f64;
    assert!(
        (mean - expected).abs() < 0.04 * expected.abs(),
        "tip deflection {mean}, Euler-Bernoulli {expected}"
    );
}

/// The footing: the applied force is q B, the base and sides take it, the surface settles most
/// under the footing and the traction points follow the surface down.
#[test]
fn footing_traction_runs_and_settles_under_the_load() {
    let spec = load("footing_traction.rhai", &[]);
    let out = temp_dir("footing");
    let mut sim = Simulation::<2>::new(&spec, &out).unwrap();
    sim.run(|_| {}).unwrap();
    let nodes = read_vtu(&out.join("nodes_0005.vtu")).unwrap();
    let (_, force) = nodes.point_field("external_force").unwrap();
    let total: f64 = force.chunks(3).map(|f| f[1]).sum();
    assert!((total - (-200.0 * 2.0)).abs() < 1e-9, "{total}");
    let tractions = read_vtu(&out.join("tractions_0005.vtu")).unwrap();
    assert_eq!(tractions.points.len(), 6);
    assert!(tractions.points.iter().all(|x| x[1] < 5.5 && x[0] < 2.1));
    let particles = read_vtu(&out.join("particles_0005.vtu")).unwrap();
    let (_, reference) = particles.point_field("reference_position").unwrap();
    let (_, u) = particles.point_field("displacement").unwrap();
    let top = |x: f64| {
        (0..particles.points.len())
            .filter(|&p| reference[3 * p + 1] > 5.0 && (reference[3 * p] - x).abs() < 0.5)
            .map(|p| u[3 * p + 1])
            .sum::<f64>()
    };
    assert!(
        top(0.75) < 0.0 && top(0.75) < 3.0 * top(8.75),
        "{} {}",
        top(0.75),
        top(8.75)
    );
}

/// Prescribed displacements with phases, and output control: only every other step and the
/// named fields are written, and the schedule loaded, held and unloaded.
#[test]
fn stretch_phases_writes_what_the_scene_asks_for() {
    let spec = load("stretch_phases.rhai", &[("basis", "linear")]);
    assert_eq!(
        spec.load_factors,
        [0.25, 0.5, 0.75, 1.0, 1.0, 1.0, 0.5, 0.0, -0.5]
    );
    let out = temp_dir("stretch");
    let mut sim = Simulation::<2>::new(&spec, &out).unwrap();
    sim.write_initial_state().unwrap();
    sim.run(|_| {}).unwrap();
    let written: Vec<bool> = (0..=9)
        .map(|k| out.join(format!("particles_{k:04}.vtu")).exists())
        .collect();
    assert_eq!(
        written,
        [
            true, false, true, false, true, false, true, false, true, true
        ]
    );
    let last = read_vtu(&out.join("particles_0009.vtu")).unwrap();
    let names: Vec<&str> = last.point_data.iter().map(|(n, _, _)| n.as_str()).collect();
    assert_eq!(names, ["displacement", "cauchy_stress"]);
    // compression at the end: λ = -0.5
    let (_, stress) = last.point_field("cauchy_stress").unwrap();
    assert!(stress.chunks(9).all(|s| s[4] < 0.0));
}

/// Two bodies of different materials: each point keeps its body's material and mass.
#[test]
fn embankment_keeps_two_bodies_apart() {
    let spec = load("embankment.rhai", &[]);
    assert_eq!(spec.bodies.len(), 2);
    assert_eq!(spec.load_factors.len(), 5);
    for (k, f) in spec.load_factors.iter().enumerate() {
        let expected = ((k + 1) as f64 / 5.0).powi(2);
        assert!((f - expected).abs() < 1e-15, "{f} vs {expected}");
    }
    let out = temp_dir("embankment");
    let mut sim = Simulation::<2>::new(&spec, &out).unwrap();
    sim.run(|_| {}).unwrap();
    let particles = read_vtu(&out.join("particles_0005.vtu")).unwrap();
    let (_, body) = particles.point_field("body").unwrap();
    let (_, mass) = particles.point_field("mass").unwrap();
    let (_, volume) = particles.point_field("reference_volume").unwrap();
    for p in 0..body.len() {
        let density = if body[p] == 0.0 { 1.8 } else { 2.0 };
        assert!((mass[p] / volume[p] - density).abs() < 1e-12);
    }
    assert!(body.contains(&0.0) && body.contains(&1.0));
}

#[test]
fn block_3d_traction_runs() {
    let spec = load("block_3d_traction.rhai", &[("cells", "2")]);
    assert_eq!(spec.part::<Tractions>().unwrap().0.len(), 4 * 4);
    let area: f64 = spec
        .part::<Tractions>()
        .unwrap()
        .0
        .iter()
        .map(|t| t.area)
        .sum();
    assert!((area - 1.0).abs() < 1e-12);
    let mut sim = Simulation::<3>::new(&spec, &temp_dir("block3d")).unwrap();
    sim.run(|_| {}).unwrap();
}

fn names(systems: &[ScheduledSystem]) -> Vec<String> {
    systems.iter().map(|s| s.name.clone()).collect()
}

const OPTIONAL: [&str; 11] = [
    "body_force::apply_body_force",
    "point_loads::apply_point_loads",
    "point_loads::point_load_field",
    "tractions::apply_tractions",
    "tractions::update_traction_points",
    "grid_constraints::apply_prescribed_displacements",
    "surface_conditions::find_boundary_supports",
    "surface_conditions::assemble_surface_conditions",
    "surface_conditions::update_boundary_points",
    "surface_conditions::measure_material_at_conditions",
    "surface_conditions::check_surface_conditions",
];

/// For several scenes, the schedule holds the systems of exactly the effects it uses, and
/// `explain_scene` (what `impm check --explain` prints) agrees with the schedules of the
/// simulation actually built for the scene.
#[test]
fn schedules_hold_only_the_effects_a_scene_uses() {
    let cases: [(&str, &[&str]); 6] = [
        ("column_2d.rhai", &["body_force::apply_body_force"]),
        (
            "beam_point_load.rhai",
            &[
                "point_loads::apply_point_loads",
                "point_loads::point_load_field",
            ],
        ),
        (
            "footing_traction.rhai",
            &[
                "tractions::apply_tractions",
                "tractions::update_traction_points",
            ],
        ),
        (
            "stretch_phases.rhai",
            &[
                "surface_conditions::find_boundary_supports",
                "surface_conditions::assemble_surface_conditions",
                "surface_conditions::update_boundary_points",
                "surface_conditions::measure_material_at_conditions",
                "surface_conditions::check_surface_conditions",
            ],
        ),
        ("embankment.rhai", &["body_force::apply_body_force"]),
        (
            "block_3d_traction.rhai",
            &[
                "tractions::apply_tractions",
                "tractions::update_traction_points",
            ],
        ),
    ];
    let modules = effects::built_in();
    for (scene, expected) in cases {
        let spec = load(scene, &[]);
        let explanation = explain_scene(&spec, &modules).unwrap();
        let scheduled = names(&explanation.systems);
        for system in OPTIONAL {
            assert_eq!(
                scheduled.iter().any(|s| s == system),
                expected.contains(&system),
                "{scene}: {system}"
            );
            assert_eq!(
                explanation.left_out.iter().any(|s| s.name == system),
                !expected.contains(&system),
                "{scene}: {system} left out"
            );
        }
        let writes_tractions = scheduled.iter().any(|s| s == "tractions::write_tractions");
        assert_eq!(
            writes_tractions,
            expected.contains(&"tractions::apply_tractions")
        );
        // the core stages are always there, in the method's order, with the hooks in between
        let order = [
            "Hook::Basis",
            "Hook::Connectivity",
            "Hook::Constraints",
            "Dofs",
            "Hook::Loads",
            "Solve",
            "UpdatePoints",
            "Hook::PointUpdate",
            "Hook::AfterStep",
            "Output",
            "ResetGrid",
        ];
        let mut stages: Vec<&str> = explanation
            .systems
            .iter()
            .filter(|s| s.schedule == "StepSchedule")
            .filter_map(|s| s.stage.as_deref())
            .collect();
        stages.dedup();
        let positions: Vec<usize> = stages
            .iter()
            .map(|stage| order.iter().position(|o| o == stage).unwrap())
            .collect();
        assert!(
            positions.windows(2).all(|p| p[0] < p[1]),
            "{scene}: {stages:?}"
        );
        for core in [
            "Hook::Basis",
            "Dofs",
            "Solve",
            "UpdatePoints",
            "Output",
            "ResetGrid",
        ] {
            assert!(stages.contains(&core), "{scene}: {core} in {stages:?}");
        }
        // the same systems as the simulation's own world
        let dir = temp_dir("explain");
        let built = match spec.dim() {
            2 => {
                let mut sim = Simulation::<2>::new(&spec, &dir).unwrap();
                scheduled_systems(&mut sim.world).unwrap()
            }
            3 => {
                let mut sim = Simulation::<3>::new(&spec, &dir).unwrap();
                scheduled_systems(&mut sim.world).unwrap()
            }
            _ => unreachable!(),
        };
        assert_eq!(built, explanation.systems, "{scene}");
        let used: Vec<&str> = modules
            .iter()
            .filter(|m| m.used_by(&spec))
            .map(|m| m.name())
            .collect();
        let listed: Vec<&str> = explanation
            .modules
            .iter()
            .filter(|(_, used)| *used)
            .map(|(name, _)| *name)
            .collect();
        assert_eq!(used, listed, "{scene}");
    }
    // a scene with no load at all has no loads stage; its only modules are the material and
    // the grid constraints
    let spec = load("footing_traction.rhai", &[("pressure", "0.0")]);
    let explanation = explain_scene(&spec, &modules).unwrap();
    let used: Vec<&str> = explanation
        .modules
        .iter()
        .filter(|(_, used)| *used)
        .map(|(name, _)| *name)
        .collect();
    assert_eq!(used, ["hencky", "grid constraints"]);
    assert!(
        explanation
            .systems
            .iter()
            .all(|s| s.stage.as_deref() != Some("Hook::Loads"))
    );
    let left_out = names(&explanation.left_out);
    for system in OPTIONAL.iter().chain(&[
        "tractions::write_tractions",
        "ghost_penalty::measure_cell_fill",
        "ghost_penalty::find_ghost_faces",
        "ghost_penalty::assemble_ghost_penalty",
        "stress_recovery::recover_stress",
        "grid_constraints::check_prescribed_motion",
        "probes::read_probes",
        "fbar::group_points_by_cell",
        "fbar::average_volume_change",
        "fbar::assemble_fbar_tangent",
        "line_search::judge_iterate",
        "arc_length::unit_load",
        "arc_length::take_reference_load",
        "arc_length::record_start_imbalance",
        "arc_length::keep_going_forward",
        "arc_length::correct_load_factor",
    ]) {
        assert!(
            left_out.iter().any(|s| s == system),
            "{system}: {left_out:?}"
        );
    }
    // the three plastic models' stress update, history commit and history fields
    for model in ["VonMises", "DruckerPrager", "MohrCoulomb"] {
        for system in [
            "stress::update_stress",
            "stress::commit_history",
            "materials::history_fields",
        ] {
            let name = format!("{system}<{model}>");
            assert!(left_out.contains(&name), "{name}: {left_out:?}");
        }
    }
    // the optional systems above, the recovered-stress output field, F-bar, the line search,
    // arc-length control and the plastic systems (+ 1: the arc's record_start_imbalance;
    // + 1: the probes' read after each step; + 1: the ghost penalty's fill fractions)
    assert_eq!(
        left_out.len(),
        OPTIONAL.len() + 6 + 3 + 5 + 9 + 1 + 1 + 1,
        "{left_out:?}"
    );
}

/// The complete scene of docs/scene-api.md, written from the documentation alone, runs.
#[test]
fn the_documented_scene_runs() {
    let doc =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/scene-api.md"))
            .unwrap();
    let after = doc
        .split("<!-- tutorial scene")
        .nth(1)
        .expect("the tutorial marker");
    let block = after
        .split("```rhai\n")
        .nth(1)
        .and_then(|rest| rest.split("```").next())
        .expect("a rhai block after the marker");
    let dir = temp_dir("tutorial");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("notched.rhai");
    std::fs::write(&path, block).unwrap();
    let spec = load_scene(&path, &[("pull".to_string(), "0.03".to_string())])
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(spec.point_count() > 0);
    assert_eq!(spec.load_factors, [0.25, 0.5, 0.75, 1.0, 0.5, 0.0]);
    let mut sim = Simulation::<2>::new(&spec, &dir.join("out")).unwrap();
    sim.run(|_| {}).unwrap();
    // and with its default pull
    let spec = load_scene(&path, &[]).unwrap();
    let mut sim = Simulation::<2>::new(&spec, &dir.join("out_default")).unwrap();
    sim.run(|_| {}).unwrap();
}

/// The method decides the connectivity system: exactly one of the three basis evaluations is
/// scheduled, and the FEM mesh systems only for FEM; recovery and the ghost penalty only when a
/// scene asks for them.
#[test]
fn the_method_and_solver_options_pick_their_systems() {
    // (overrides, the basis evaluation scheduled, the FEM mesh systems scheduled)
    type Case<'a> = (&'a [(&'a str, &'a str)], &'a str, &'a [&'a str]);
    let cases: [Case; 4] = [
        (&[], "connectivity::evaluate_basis", &[]),
        (
            &[("basis", "gimp")],
            "point_domains::evaluate_domain_basis",
            &[],
        ),
        (
            &[("basis", "cpdi")],
            "point_domains::evaluate_domain_basis",
            &[],
        ),
        (
            &[("basis", "fem"), ("ppc", "1")],
            "fem_mesh::evaluate_element_basis",
            &["fem_mesh::advance_mesh", "fem_mesh::write_mesh"],
        ),
    ];
    let evaluations = [
        "connectivity::evaluate_basis",
        "point_domains::evaluate_domain_basis",
        "fem_mesh::evaluate_element_basis",
    ];
    for (overrides, evaluation, extra) in cases {
        let spec = load("column_1d.rhai", overrides);
        let scheduled = names(&explain_scene(&spec, &effects::built_in()).unwrap().systems);
        for candidate in evaluations {
            assert_eq!(
                scheduled.iter().any(|s| s == candidate),
                candidate == evaluation,
                "{overrides:?}: {candidate}"
            );
        }
        for system in ["fem_mesh::advance_mesh", "fem_mesh::write_mesh"] {
            assert_eq!(
                scheduled.iter().any(|s| s == system),
                extra.contains(&system),
                "{overrides:?}: {system}"
            );
        }
        assert!(!scheduled.iter().any(|s| s.starts_with("ghost_penalty::")));
        assert!(
            !scheduled
                .iter()
                .any(|s| s == "stress_recovery::recover_stress")
        );
    }
    let spec = load("sliver_column.rhai", &[]);
    let scheduled = names(&explain_scene(&spec, &effects::built_in()).unwrap().systems);
    assert!(
        scheduled
            .iter()
            .any(|s| s == "ghost_penalty::assemble_ghost_penalty")
    );
}
