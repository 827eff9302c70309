//! Tests of the scene language through whole scripts: the core's calls and the built-in
//! modules' (every module's scene words are registered as in a run).

mod common;

use std::path::{Path, PathBuf};

use impm::basis::{BasisKind, GimpDomain};
use impm::effects::body_force::BodyForceSpec;
use impm::effects::grid_constraints::{NodeConstraint, NodeConstraints};
use impm::run::load_scene;
use impm::scene::*;

/// The scene's constrained node components.
fn constraints(scene: &SceneSpec) -> &[NodeConstraint] {
    scene.part::<NodeConstraints>().map_or(&[], |c| &c.0)
}

fn shipped(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts")
        .join(name)
}

/// Writes an inline script to a per-process temporary directory.
fn inline_script(name: &str, text: &str) -> PathBuf {
    let directory = common::temp_dir("scene-tests", name);
    std::fs::create_dir_all(&directory).unwrap();
    let path = directory.join(format!("{name}.rhai"));
    std::fs::write(&path, text).unwrap();
    path
}

fn set(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|(name, value)| (name.to_string(), value.to_string()))
        .collect()
}

fn total_volume(scene: &SceneSpec) -> f64 {
    scene
        .bodies
        .iter()
        .flat_map(|body| &body.points)
        .map(|point| point.volume)
        .sum()
}

fn assert_close(actual: f64, expected: f64) {
    assert!(
        (actual - expected).abs() <= 1e-9 * expected.abs().max(1.0),
        "{actual} != {expected}"
    );
}

/// Loads an inline script expected to fail; returns the error.
fn failure(name: &str, text: &str) -> SceneError {
    let path = inline_script(name, text);
    let error = load_scene(&path, &[]).expect_err("the script should fail");
    assert!(
        error.to_string().starts_with(&path.display().to_string()),
        "{error}"
    );
    error
}

/// A valid 1D scene with `replace` substituted for the line that starts with `key`.
fn scene_1d_with(key: &str, replace: &str) -> String {
    let lines = [
        "let cells = 10;",
        "grid(#{ lower: [0.0], upper: [10.0], cells: [cells], basis: \"bspline\", order: 2 });",
        "const m = material(#{ name: \"m\", E: 1e6, nu: 0.0, density: 1.0 });",
        "body(#{ name: \"bar\", material: m, region: box([0.0], [10.0]), ppc: 2 });",
        "fix(|x| x[0] == 0.0, [0]);",
        "load_steps(2);",
    ];
    lines
        .iter()
        .map(|line| if line.starts_with(key) { replace } else { line })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn column_1d_defaults() {
    let scene = load_scene(&shipped("column_1d.rhai"), &[]).unwrap();
    assert_eq!(scene.name, "column_1d");
    assert_eq!(scene.dim(), 1);
    assert_eq!(scene.grid.cells, [50]);
    assert_eq!(scene.grid.basis, BasisKind::BSpline { order: 3 });
    assert_eq!(scene.bodies.len(), 1);
    assert_eq!(scene.bodies[0].points.len(), 50 * 4);
    assert_close(total_volume(&scene), 50.0);
    assert_eq!(scene.materials[0].stiffness, 1e6);
    assert_eq!(scene.materials[0].density, 1.0);
    assert_eq!(
        scene.part::<BodyForceSpec>(),
        Some(&BodyForceSpec(vec![-800.0]))
    );
    assert_eq!(
        constraints(&scene),
        [NodeConstraint {
            node: 0,
            component: 0,
            value: 0.0
        }]
    );
    assert_eq!(scene.load_factors.len(), 20);
    assert_eq!(scene.load_factors[0], 0.05);
    assert_eq!(scene.load_factors[19], 1.0);
    assert_eq!(
        scene.analytic,
        Some(AnalyticSpec::Column {
            axis: 0,
            height: 50.0,
            density: 1.0,
            body_force: -800.0,
            modulus: 1e6
        })
    );
    assert_eq!(scene.solver, SolverSpec::default());
    assert_eq!(scene.output, OutputSpec::default());
}

#[test]
fn column_2d_defaults() {
    let scene = load_scene(&shipped("column_2d.rhai"), &[]).unwrap();
    assert_eq!(scene.dim(), 2);
    assert_eq!(scene.grid.cells, [1, 50]);
    assert_eq!(scene.grid.upper, [1.0, 50.0]);
    assert_eq!(scene.bodies[0].points.len(), 50 * 4 * 4);
    assert_close(total_volume(&scene), 50.0);
    assert_eq!(
        scene.part::<BodyForceSpec>(),
        Some(&BodyForceSpec(vec![0.0, -800.0]))
    );
    // cubic B-splines: 1 + 3 = 4 nodes across, 50 + 3 = 53 up; axis 0 fastest
    let (across, up) = (4, 53);
    let mut expected: Vec<NodeConstraint> = Vec::new();
    for row in 0..up {
        for column in 0..across {
            let node = row * across + column;
            if column == 0 || column == across - 1 {
                expected.push(NodeConstraint {
                    node,
                    component: 0,
                    value: 0.0,
                });
            }
            if row == 0 {
                expected.push(NodeConstraint {
                    node,
                    component: 1,
                    value: 0.0,
                });
            }
        }
    }
    assert_eq!(constraints(&scene), expected);
    assert!(matches!(
        scene.analytic,
        Some(AnalyticSpec::Column { axis: 1, .. })
    ));
}

#[test]
fn column_3d_defaults() {
    let scene = load_scene(&shipped("column_3d.rhai"), &[]).unwrap();
    assert_eq!(scene.dim(), 3);
    assert_eq!(scene.grid.cells, [1, 1, 50]);
    assert_eq!(scene.bodies[0].points.len(), 50 * 4 * 4 * 4);
    assert_close(total_volume(&scene), 50.0);
    assert_eq!(
        scene.part::<BodyForceSpec>(),
        Some(&BodyForceSpec(vec![0.0, 0.0, -800.0]))
    );
    let across = 4;
    let count = |component: usize| {
        scene
            .part::<NodeConstraints>()
            .unwrap()
            .0
            .iter()
            .filter(|c| c.component == component)
            .count()
    };
    assert_eq!(count(2), across * across);
    assert_eq!(count(0), 2 * across * 53);
    assert_eq!(count(1), 2 * across * 53);
    for constraint in constraints(&scene) {
        let (i, j, k) = (
            constraint.node % across,
            constraint.node / across % across,
            constraint.node / (across * across),
        );
        let on_face = match constraint.component {
            0 => i == 0 || i == across - 1,
            1 => j == 0 || j == across - 1,
            _ => k == 0,
        };
        assert!(on_face, "{constraint:?}");
    }
    assert!(matches!(
        scene.analytic,
        Some(AnalyticSpec::Column { axis: 2, .. })
    ));
}

#[test]
fn overrides_change_the_scene() {
    let path = shipped("column_1d.rhai");
    let scene = load_scene(&path, &set(&[("cells", "10")])).unwrap();
    assert_eq!(scene.grid.cells, [10]);
    assert_eq!(scene.bodies[0].points.len(), 40);
    assert_close(total_volume(&scene), 50.0);

    let scene = load_scene(&path, &set(&[("basis", "linear")])).unwrap();
    assert_eq!(scene.grid.basis, BasisKind::Linear);
    assert_eq!(
        scene.bodies[0].points.len(),
        50,
        "linear defaults to one point per cell"
    );

    let scene = load_scene(&path, &set(&[("body_force", "-200"), ("steps", "5")])).unwrap();
    assert_eq!(
        scene.part::<BodyForceSpec>(),
        Some(&BodyForceSpec(vec![-200.0]))
    );
    assert!(matches!(
        scene.analytic,
        Some(AnalyticSpec::Column {
            body_force: -200.0,
            ..
        })
    ));
    assert_eq!(scene.load_factors, [0.2, 0.4, 0.6, 0.8, 1.0]);

    let scene = load_scene(
        &shipped("column_2d.rhai"),
        &set(&[("cells", "10"), ("order", "2")]),
    )
    .unwrap();
    assert_eq!(scene.grid.upper, [5.0, 50.0]);
    assert_eq!(scene.grid.basis, BasisKind::BSpline { order: 2 });
    assert_eq!(scene.bodies[0].points.len(), 10 * 16);
    assert_close(total_volume(&scene), 250.0);

    // a width that is not a round number: the side nodes must still be found exactly
    for cells in 1..=13 {
        let cells_text = cells.to_string();
        let scene =
            load_scene(&shipped("column_2d.rhai"), &set(&[("cells", &cells_text)])).unwrap();
        let nodes_up = cells + 3;
        assert_eq!(
            constraints(&scene).len(),
            2 * nodes_up + 4,
            "cells = {cells}"
        );
    }
}

#[test]
fn unknown_override_lists_the_parameters() {
    let error = load_scene(&shipped("column_1d.rhai"), &set(&[("cels", "10")])).unwrap_err();
    assert_eq!(error.line, None);
    let text = error.to_string();
    assert!(
        text.contains("column_1d.rhai: --set cels=10: there is no parameter 'cels'"),
        "{text}"
    );
    assert!(
        text.contains(
            "cells, basis, order, gimp, ppc, body_force, steps, placement, integration, recovery"
        ),
        "{text}"
    );
}

#[test]
fn scene_parameters_lists_the_column_parameters() {
    for script in ["column_1d.rhai", "column_2d.rhai", "column_3d.rhai"] {
        let parameters = scene_parameters(&shipped(script)).unwrap();
        let listed: Vec<(&str, &str)> = parameters
            .iter()
            .map(|p| (p.name.as_str(), p.default.as_str()))
            .collect();
        assert_eq!(
            listed,
            [
                ("cells", "50"),
                ("basis", "\"bspline\""),
                ("order", "3"),
                ("gimp", "\"stretched\""),
                (
                    "ppc",
                    "if basis == \"linear\" { 1 } else if basis == \"gimp\" || basis == \"cpdi\" { 2 } else { 4 }"
                ),
                ("body_force", "-800.0"),
                ("steps", "20"),
                ("placement", "\"uniform\""),
                ("integration", "\"points\""),
                ("recovery", "\"none\""),
            ],
            "{script}"
        );
        let text = std::fs::read_to_string(shipped(script)).unwrap();
        let cells_line = 1 + text
            .lines()
            .position(|line| line.starts_with("let cells"))
            .unwrap();
        assert_eq!(parameters[0].line, cells_line, "{script}");
        assert!(
            parameters
                .windows(2)
                .all(|pair| pair[1].line == pair[0].line + 1)
        );
    }
}

#[test]
fn syntax_error_points_at_the_line() {
    let error = failure(
        "syntax",
        "let cells = 10;\n\ngrid(#{ lower: [0.0] upper: [1.0] });\n",
    );
    assert_eq!(error.line, Some(3), "{error}");
    assert!(error.message.starts_with("syntax error"), "{error}");
}

#[test]
fn override_keeps_line_numbers_of_later_errors() {
    let text = "let cells = 10;\nlet ppc = if cells > 5 {\n  2\n} else {\n  1\n};\nlet broken = 1;\ngrid(#{ lower: [0.0], upper: [1.0], cells: [cells], basis: \"spline\" });\n";
    let path = inline_script("lines", text);
    let error = load_scene(&path, &set(&[("ppc", "3")])).unwrap_err();
    assert_eq!(error.line, Some(8), "{error}");
    assert!(
        error
            .message
            .contains("\"linear\", \"bspline\", \"gimp\", \"cpdi\" or \"fem\", got \"spline\""),
        "{error}"
    );
}

#[test]
fn unknown_key_names_the_allowed_keys() {
    let error = failure(
        "unknown_key",
        &scene_1d_with(
            "grid",
            "\n\ngrid(#{ lower: [0.0], upper: [10.0], cels: [10], basis: \"linear\" });",
        ),
    );
    assert_eq!(error.line, Some(4), "{error}");
    assert!(
        error
            .message
            .contains("unknown option 'cels' (did you mean 'cells'?)")
            && error.message.contains("lower, upper, cells, basis, order"),
        "{error}"
    );
}

#[test]
fn order_zero_and_zero_cells_are_rejected() {
    let error = failure(
        "order_zero",
        &scene_1d_with(
            "grid",
            "grid(#{ lower: [0.0], upper: [10.0], cells: [10], basis: \"bspline\", order: 0 });",
        ),
    );
    assert_eq!(error.line, Some(2), "{error}");
    assert!(
        error
            .message
            .contains("'order' must be a whole number >= 1, got integer 0"),
        "{error}"
    );

    let path = inline_script("zero_cells", &scene_1d_with("#", ""));
    let error = load_scene(&path, &set(&[("cells", "0")])).unwrap_err();
    assert_eq!(error.line, Some(2), "{error}");
    assert!(
        error
            .message
            .contains("'cells'[0] must be a whole number >= 1, got integer 0"),
        "{error}"
    );
}

#[test]
fn gimp_and_cpdi_scene_words() {
    let grid_with = |options: &str| {
        format!("grid(#{{ lower: [0.0], upper: [10.0], cells: [cells], {options} }});")
    };
    let cases = [
        (
            "basis: \"gimp\"",
            BasisKind::Gimp {
                domain: GimpDomain::Stretched,
            },
        ),
        (
            "basis: \"gimp\", gimp: \"fixed\"",
            BasisKind::Gimp {
                domain: GimpDomain::Fixed,
            },
        ),
        (
            "basis: \"gimp\", gimp: \"stretched\", order: 3",
            BasisKind::Gimp {
                domain: GimpDomain::Stretched,
            },
        ),
        ("basis: \"cpdi\"", BasisKind::Cpdi),
        (
            "basis: \"bspline\", order: 2, gimp: \"fixed\"",
            BasisKind::BSpline { order: 2 },
        ),
    ];
    for (k, (options, expected)) in cases.into_iter().enumerate() {
        let text = scene_1d_with("grid", &grid_with(options));
        let scene = load_scene(&inline_script(&format!("words{k}"), &text), &[]).unwrap();
        assert_eq!(scene.grid.basis, expected, "{options}");
        // 10 cells of 1, ppc 2: the points own boxes of side 0.5
        assert!(
            scene.bodies[0]
                .points
                .iter()
                .all(|point| point.half_lengths == [0.25]),
            "{options}"
        );
    }
    let error = failure(
        "gimp_variant",
        &scene_1d_with("grid", &grid_with("basis: \"gimp\", gimp: \"ugimp\"")),
    );
    assert_eq!(error.line, Some(2), "{error}");
    assert!(
        error
            .message
            .contains("option 'gimp' must be \"stretched\" (domains follow the deformation, cpGIMP) or \"fixed\""),
        "{error}"
    );
    let error = failure(
        "gimp_type",
        &scene_1d_with("grid", &grid_with("basis: \"cpdi\", gimp: 1")),
    );
    assert_eq!(error.line, Some(2), "{error}");
    assert!(error.message.contains("'gimp' must be a string"), "{error}");
}

#[test]
fn integration_domain_averages_bsplines_and_is_checked() {
    let grid_with = |options: &str| {
        format!("grid(#{{ lower: [0.0], upper: [10.0], cells: [cells], {options} }});")
    };
    let path = inline_script(
        "integration",
        &scene_1d_with(
            "grid",
            &grid_with("basis: \"bspline\", order: 2, integration: \"domain\""),
        ),
    );
    let scene = load_scene(&path, &[]).unwrap();
    assert_eq!(scene.grid.basis, BasisKind::BSplineDomain { order: 2 });
    assert!(scene.grid.basis.uses_point_domain());
    for (name, options, expected) in [
        (
            "integration_gimp",
            "basis: \"gimp\", integration: \"domain\"",
            "integration \"domain\" is an option of basis \"bspline\"",
        ),
        (
            "integration_word",
            "basis: \"bspline\", order: 2, integration: \"exact\"",
            "option 'integration' must be \"points\" (the basis at the material points) or \"domain\"",
        ),
    ] {
        let error = failure(name, &scene_1d_with("grid", &grid_with(options)));
        assert_eq!(error.line, Some(2), "{error}");
        assert!(error.message.contains(expected), "{error}");
    }
}

#[test]
fn shipped_columns_run_gimp_and_cpdi_with_two_points_per_cell() {
    for basis in ["gimp", "cpdi"] {
        for script in ["column_1d.rhai", "column_2d.rhai", "column_3d.rhai"] {
            let scene =
                load_scene(&shipped(script), &set(&[("basis", basis), ("cells", "4")])).unwrap();
            assert!(scene.grid.basis.uses_point_domain());
            let dim = scene.dim();
            // cells of 12.5 (one across in 2D/3D), 2 points per cell per axis
            for point in &scene.bodies[0].points {
                assert!(
                    point.half_lengths.iter().all(|l| (l - 3.125).abs() < 1e-12),
                    "{script}: {:?}",
                    point.half_lengths
                );
            }
            assert_eq!(scene.bodies[0].points.len(), 4 * (1 << dim), "{script}");
        }
    }
}

#[test]
fn invalid_materials_are_rejected_at_their_line() {
    let error = failure(
        "negative_e",
        &scene_1d_with(
            "const m",
            "const m = material(#{ name: \"m\", E: -5, nu: 0.0, density: 1.0 });",
        ),
    );
    assert_eq!((error.line, error.column), (Some(3), Some(11)), "{error}");
    assert!(
        error
            .message
            .contains("Young's modulus E must be positive, got -5"),
        "{error}"
    );

    let error = failure(
        "nu_half",
        &scene_1d_with(
            "const m",
            "const m = material(#{ name: \"m\", E: 1e6, nu: 0.5, density: 1.0 });",
        ),
    );
    assert_eq!(error.line, Some(3), "{error}");
    assert!(error.message.contains("-1 < nu < 0.5, got 0.5"), "{error}");
}

#[test]
fn bodies_outside_the_grid_are_rejected() {
    let error = failure(
        "box_outside",
        &scene_1d_with(
            "body",
            "body(#{ name: \"bar\", material: m, region: box([0.0], [12.0]), ppc: 2 });",
        ),
    );
    assert_eq!(error.line, Some(4), "{error}");
    assert!(
        error.message.contains("body 'bar'") && error.message.contains("not inside the grid"),
        "{error}"
    );

    let error = failure(
        "closure_outside",
        &scene_1d_with(
            "body",
            "body(#{ name: \"bar\", material: m, region: |x| x[0] < 10.5, ppc: 2 });",
        ),
    );
    assert_eq!(error.line, Some(4), "{error}");
    assert!(
        error.message.contains("body 'bar'") && error.message.contains("outside the grid"),
        "{error}"
    );

    let error = failure(
        "empty_body",
        &scene_1d_with(
            "body",
            "body(#{ name: \"bar\", material: m, region: |x| x[0] > 20.0, ppc: 2 });",
        ),
    );
    assert_eq!(error.line, Some(4), "{error}");
    assert!(
        error.message.contains("body 'bar': no material points"),
        "{error}"
    );
}

#[test]
fn runtime_error_in_a_predicate_reports_the_closure_line() {
    let error = failure(
        "closure_error",
        &scene_1d_with(
            "fix",
            "fix(|x| {\n    let y = x[0];\n    x[3] > y\n}, [0]);",
        ),
    );
    assert_eq!(error.line, Some(7), "{error}");
    assert!(
        error.message.contains("out of bounds") && error.message.contains("fix(...) at line 5"),
        "{error}"
    );

    let error = failure(
        "region_error",
        &scene_1d_with(
            "body",
            "body(#{ name: \"bar\", material: m, region: |x| x[1] < 1.0, ppc: 2 });",
        ),
    );
    assert_eq!(error.line, Some(4), "{error}");
    assert!(
        error.message.contains("region predicate of body 'bar'"),
        "{error}"
    );
}

#[test]
fn predicates_selecting_nothing_or_returning_non_booleans_are_rejected() {
    let error = failure(
        "no_node",
        &scene_1d_with("fix", "fix(|x| x[0] < -1.0, [0]);"),
    );
    assert_eq!(error.line, Some(5), "{error}");
    assert!(error.message.contains("selects no grid node"), "{error}");

    let error = failure("not_bool", &scene_1d_with("fix", "fix(|x| x[0], [0]);"));
    assert_eq!(error.line, Some(5), "{error}");
    assert!(
        error
            .message
            .contains("must return true or false, got float 0.0"),
        "{error}"
    );
}

#[test]
fn missing_and_repeated_declarations() {
    let error = failure("no_grid", &scene_1d_with("grid", ""));
    assert_eq!(error.line, None);
    assert!(error.message.contains("no grid"), "{error}");
    let error = failure("no_steps", &scene_1d_with("load_steps", ""));
    assert!(error.message.contains("no load steps"), "{error}");
    let error = failure("no_body", &scene_1d_with("body", ""));
    assert!(error.message.contains("no body"), "{error}");
    let mut text = scene_1d_with("#", "");
    text.push_str("\ngrid(#{ lower: [0.0], upper: [1.0], cells: [1], basis: \"linear\" });");
    let error = failure("grid_twice", &text);
    assert_eq!(error.line, Some(7), "{error}");
    assert!(
        error
            .message
            .contains("grid(...) was already called at line 2"),
        "{error}"
    );
}

#[test]
fn wrong_types_say_what_was_expected() {
    let error = failure(
        "wrong_type",
        &scene_1d_with("load_steps", "load_steps(\"ten\");"),
    );
    assert_eq!(error.line, Some(6), "{error}");
    assert!(
        error
            .message
            .contains("must be a whole number >= 1, got string \"ten\""),
        "{error}"
    );
    let error = failure("wrong_arity", &scene_1d_with("fix", "fix();"));
    assert_eq!(error.line, Some(5), "{error}");
    assert!(
        error
            .message
            .contains("expected fix(|x| predicate, [components]) or fix(|x| predicate)"),
        "{error}"
    );
    let error = failure("wrong_first", &scene_1d_with("fix", "fix([0]);"));
    assert_eq!(error.line, Some(5), "{error}");
    assert!(
        error
            .message
            .contains("fix(...): the first argument must be a function of the position"),
        "{error}"
    );
    let error = failure(
        "wrong_material",
        &scene_1d_with(
            "body",
            "body(#{ name: \"bar\", material: \"m\", region: box([0.0], [10.0]), ppc: 2 });",
        ),
    );
    assert!(
        error
            .message
            .contains("must be a material returned by material"),
        "{error}"
    );
}

#[test]
fn displacements_load_factors_solver_and_output() {
    let mut text = scene_1d_with("fix", "displace(|x| x[0] == 10.0, [0], [-1]);");
    text = text.replace("load_steps(2);", "load_factors([0.5, 1, 1.5]);");
    text.push_str("\nfix(|x| x[0] == 0.0, [0]);\nsolver(#{ tolerance: 1e-6, max_iterations: 12.0 });\noutput(#{ every: 2 });");
    let scene = load_scene(&inline_script("displace", &text), &[]).unwrap();
    // quadratic B-splines on 10 cells: 12 nodes, the last at x = 10
    assert_eq!(
        constraints(&scene),
        [
            NodeConstraint {
                node: 0,
                component: 0,
                value: 0.0
            },
            NodeConstraint {
                node: 11,
                component: 0,
                value: -1.0
            },
        ]
    );
    assert_eq!(scene.load_factors, [0.5, 1.0, 1.5]);
    assert_eq!(
        scene.solver,
        SolverSpec {
            tolerance: 1e-6,
            max_iterations: 12,
            max_step_cuts: 8,
            linear: impm::scene::LinearBackend::Auto,
            inexact: false,
            petsc_options: String::new(),
            line_search: false,
            max_backtracks: 10,
            merit: impm::scene::LineSearchMerit::Residual,
        }
    );
    assert_eq!(scene.output.every, 2);
    assert_eq!(scene.part::<BodyForceSpec>(), None);
}

#[test]
fn polygons_seed_inside_and_are_checked() {
    let text = "grid(#{ lower: [0.0, 0.0], upper: [4.0, 4.0], cells: [4, 4], basis: \"linear\" });\nconst m = material(#{ name: \"m\", E: 1e6, nu: 0.0, density: 1.0 });\nbody(#{ name: \"wedge\", material: m, region: polygon([[0.0, 0.0], [4.0, 0.0], [0, 4]]), ppc: 2 });\nfix(|x| x[1] == 0.0);\nload_steps(1);\n";
    let scene = load_scene(&inline_script("polygon", text), &[]).unwrap();
    let points = &scene.bodies[0].points;
    // lattice points with x + y < 4 (none lies on the hypotenuse): 8 x 8 lattice, spacing
    // 0.5 from 0.25: pairs (i, j) with i + j < 7, i.e. 28
    assert_eq!(points.len(), 28);
    assert!(points.iter().all(|p| p.position[0] + p.position[1] < 4.0));
    // fix(|x| ..) fixes every component of the 5 bottom nodes
    assert_eq!(constraints(&scene).len(), 10);

    let error = failure("polygon_3d", &text.replace("[0, 4]]", "[0, 4, 1]]"));
    assert_eq!(error.line, Some(3), "{error}");
    assert!(error.message.contains("must have 2 coordinates"), "{error}");
    let error = failure("polygon_out", &text.replace("[0, 4]]", "[0, 5]]"));
    assert!(error.message.contains("not inside the grid"), "{error}");
    let error = failure("polygon_flat", &text.replace("[0, 4]]", "[2, 0]]"));
    assert!(error.message.contains("enclose no area"), "{error}");
}

#[test]
fn several_bodies_keep_their_materials_and_order() {
    let text = "grid(#{ lower: [0.0, 0.0], upper: [2.0, 4.0], cells: [2, 4], basis: \"bspline\", order: 2 });\nconst soft = material(#{ name: \"soft\", E: 1e3, nu: 0.2, density: 1.0 });\nconst hard = material(#{ name: \"hard\", E: 1e6, nu: 0.3, density: 3.0 });\nbody(#{ name: \"base\", material: hard, region: box([0.0, 0.0], [2.0, 2.0]), ppc: 2 });\nbody(#{ name: \"top\", material: soft, region: |x| x[1] > 2.0 && x[1] < 3.0 && x[0] > 0.0 && x[0] < 2.0, ppc: [1, 3] });\nfix(|x| x[1] == 0.0);\nload_steps(1);\n";
    let scene = load_scene(&inline_script("bodies", text), &[]).unwrap();
    assert_eq!(scene.materials.len(), 2);
    assert_eq!(scene.bodies.len(), 2);
    assert_eq!((scene.bodies[0].material, scene.bodies[1].material), (1, 0));
    assert_eq!(scene.bodies[0].points.len(), 2 * 2 * 4);
    assert_eq!(scene.bodies[1].points.len(), 2 * 3);
    assert_close(total_volume(&scene), 4.0 + 2.0);
    let error = failure(
        "same_body",
        &text.replace("name: \"top\"", "name: \"base\""),
    );
    assert_eq!(error.line, Some(5), "{error}");
    assert!(
        error.message.contains("already declared at line 4"),
        "{error}"
    );
}

#[test]
fn load_schedules_from_functions_and_phases() {
    let function = scene_1d_with("load_steps", "load_factors(4, |k| (k / 4) ** 2);");
    let scene = load_scene(&inline_script("function", &function), &[]).unwrap();
    assert_eq!(scene.load_factors, [1.0 / 16.0, 0.25, 9.0 / 16.0, 1.0]);
    let function = scene_1d_with(
        "load_steps",
        "let n = 4;\nload_factors(n, |k| if k <= 2 { k / n } else { 0.5 });",
    );
    let scene = load_scene(&inline_script("function_if", &function), &[]).unwrap();
    assert_eq!(scene.load_factors, [0.25, 0.5, 0.5, 0.5]);

    let phases = scene_1d_with(
        "load_steps",
        "load_phases([#{ to: 1.0, steps: 4 }, #{ to: 1, steps: 2 }, #{ to: -0.5, steps: 3 }]);",
    );
    let scene = load_scene(&inline_script("phases", &phases), &[]).unwrap();
    assert_eq!(
        scene.load_factors,
        [0.25, 0.5, 0.75, 1.0, 1.0, 1.0, 0.5, 0.0, -0.5]
    );

    let error = failure(
        "function_error",
        &scene_1d_with(
            "load_steps",
            "load_factors(3, |k| {\n  if k == 2 { \"two\" } else { 1.0 }\n});",
        ),
    );
    assert_eq!(error.line, Some(6), "{error}");
    assert!(
        error
            .message
            .contains("load factor function of load_factors(...) at line 6 must be a number, got string \"two\" for step k = 2"),
        "{error}"
    );
    let error = failure(
        "function_runtime",
        &scene_1d_with(
            "load_steps",
            "load_factors(3, |k| {\n  let a = [1.0];\n  a[k.to_int()]\n});",
        ),
    );
    assert_eq!(error.line, Some(8), "{error}");
    assert!(error.message.contains("out of bounds"), "{error}");
    let error = failure(
        "phase_key",
        &scene_1d_with("load_steps", "load_phases([#{ to: 1.0, step: 4 }]);"),
    );
    assert!(error.message.contains("did you mean 'steps'"), "{error}");
    let error = failure(
        "two_schedules",
        &format!(
            "{}\nload_phases([#{{ to: 1.0, steps: 4 }}]);",
            scene_1d_with("#", "")
        ),
    );
    assert!(error.message.contains("already set at line 6"), "{error}");
}

#[test]
fn output_control_is_validated() {
    let text = format!(
        "{}\noutput(#{{ steps: [1, 2], fields: [\"displacement\", \"cauchy_stress\"], grid: false }});",
        scene_1d_with("#", "")
    );
    let scene = load_scene(&inline_script("output", &text), &[]).unwrap();
    assert_eq!(scene.output.steps, Some(vec![1, 2]));
    assert_eq!(
        scene.output.fields,
        Some(vec![
            "displacement".to_string(),
            "cauchy_stress".to_string()
        ])
    );
    assert!(!scene.output.grid);
    let error = failure("bad_field", &text.replace("\"displacement\"", "\"stress\""));
    assert_eq!(error.line, Some(7), "{error}");
    assert!(
        error
            .message
            .contains("unknown particle field \"stress\"; the fields are: reference_position"),
        "{error}"
    );
    let error = failure(
        "every_and_steps",
        &text.replace("steps: [1, 2]", "every: 2, steps: [1]"),
    );
    assert!(
        error.message.contains("'every' or 'steps', not both"),
        "{error}"
    );
}

#[test]
fn runtime_errors_in_point_selectors_point_inside_the_closure() {
    let text = scene_1d_with(
        "fix",
        "fix(|x| x[0] == 0.0);\npoint_load(|x| {\n  x[1] > 2.0\n}, [1.0]);",
    );
    let error = failure("selector_error", &text);
    assert_eq!(error.line, Some(7), "{error}");
    assert!(
        error.message.contains("out of bounds")
            && error
                .message
                .contains("point selector of point_load(...) at line 6"),
        "{error}"
    );
    let text = scene_1d_with(
        "fix",
        "fix(|x| x[0] == 0.0);\npoint_load_total(|x| 1.0, [1.0]);",
    );
    let error = failure("selector_not_bool", &text);
    assert_eq!(error.line, Some(6), "{error}");
    assert!(
        error
            .message
            .contains("must return true or false, got float 1.0"),
        "{error}"
    );
}
