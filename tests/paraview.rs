//! ParaView reads what a run writes: the `.pvd` series with the load factor as time, the
//! particle fields with full tensors, the nodes with their fixities and forces, the traction
//! points with their forces, the pressure's load points (`pressure.pvd`), point loads on the
//! particles; and `scripts/show_stress.py` renders
//! the points coloured by the vertical stress. Uses `pvpython` (and `xvfb-run` for the
//! picture); where they are not installed the test prints why it is skipped and passes
//! (`.ci/run` installs them).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use impm::run::load_scene;
use impm::run::run_scene;

fn available(program: &str) -> bool {
    Command::new(program)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// xvfb-run has no `--version`: whether it runs at all.
fn has_xvfb() -> bool {
    Command::new("xvfb-run").arg("--help").output().is_ok()
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs a shipped scene with overrides into a fresh folder.
fn run(scene: &str, overrides: &[(&str, &str)]) -> PathBuf {
    let out = common::temp_dir("paraview", scene.trim_end_matches(".rhai"));
    let overrides: Vec<(String, String)> = overrides
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    let spec = load_scene(&root().join("scripts").join(scene), &overrides).unwrap();
    run_scene(&spec, &out, |_| {}).unwrap();
    out
}

fn text(output: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        output.status.code(),
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

fn check_output(out: &Path, arguments: &[&str]) {
    let output = Command::new("pvpython")
        .arg(root().join("scripts/check_output.py"))
        .arg(out)
        .args(arguments)
        .output()
        .unwrap();
    let report = text(&output);
    assert!(output.status.success(), "{report}");
    assert!(report.contains("\nOK\n"), "{report}");
}

/// Renders the stress picture (with `options` of show_stress.py) and returns what the script
/// printed; xvfb's X server occasionally fails to start under load, so a failed attempt is
/// retried once before it counts.
fn render(out: &Path, options: &[&str]) -> String {
    if !has_xvfb() {
        eprintln!("SKIPPED the picture: xvfb-run is not installed (apt-get install xvfb)");
        return String::new();
    }
    let png = out.join("stress.png");
    let attempt = || {
        Command::new("xvfb-run")
            .args(["-a", "pvpython"])
            .arg(root().join("scripts/show_stress.py"))
            .arg(out)
            .arg("--png")
            .arg(&png)
            .args(options)
            .output()
            .unwrap()
    };
    let mut output = attempt();
    if !output.status.success() {
        eprintln!(
            "first rendering attempt failed, retrying:\n{}",
            text(&output)
        );
        output = attempt();
    }
    assert!(output.status.success(), "{}", text(&output));
    let bytes = std::fs::read(&png).unwrap();
    assert!(
        bytes.starts_with(b"\x89PNG") && bytes.len() > 10_000,
        "{} bytes",
        bytes.len()
    );
    text(&output)
}

/// The value range show_stress.py printed ("values LOW .. HIGH") and its colour map.
fn shown(report: &str) -> (f64, f64, bool) {
    let line = report
        .lines()
        .find(|l| l.starts_with("picture:"))
        .unwrap_or_else(|| panic!("{report}"));
    let values = line.split("values ").nth(1).unwrap();
    let mut words = values.split([' ', ',']).filter(|w| !w.is_empty());
    let low: f64 = words.next().unwrap().parse().unwrap();
    assert_eq!(words.next(), Some(".."), "{line}");
    let high: f64 = words.next().unwrap().parse().unwrap();
    (low, high, line.contains("diverging colour map"))
}

#[test]
fn paraview_reads_the_series_fields_loads_and_renders_the_stress() {
    if !available("pvpython") {
        eprintln!(
            "SKIPPED: pvpython is not installed, so ParaView cannot be checked here \
             (apt-get install paraview python3-paraview xvfb; .ci/run does it when root)"
        );
        return;
    }
    let particle_fields = common::PARTICLE_FIELDS;
    let node_fields = [
        "--nodes",
        "active:1",
        "fixed:3",
        "displacement_increment:3",
        "external_force:3",
        "internal_force:3",
    ];

    let footing = run("footing_traction.rhai", &[("steps", "2")]);
    let mut arguments: Vec<&str> = particle_fields.to_vec();
    arguments.extend(node_fields);
    arguments.extend([
        "--tractions",
        "reference_position:3",
        "area:1",
        "traction:3",
        "force:3",
    ]);
    arguments.extend(["--times", "0,0.5,1"]);
    check_output(&footing, &arguments);
    render(&footing, &[]);

    let beam = run("beam_point_load.rhai", &[("steps", "3")]);
    let times = format!("0,{},{},1", 1.0 / 3.0, 2.0 / 3.0);
    let mut arguments: Vec<&str> = particle_fields.to_vec();
    arguments.push("point_load:3");
    arguments.extend(node_fields);
    arguments.extend(["--times", &times]);
    check_output(&beam, &arguments);

    // the pressure's load points (pressure.pvd) of the thick cylinder
    let cylinder = run(
        "thick_cylinder.rhai",
        &[
            ("material", "elastic"),
            ("control", "load"),
            ("last", "10"),
            ("steps", "2"),
            ("fbar", "false"),
            ("ppc", "2"),
        ],
    );
    check_output(
        &cylinder,
        &[
            "--pressure",
            "normal:3",
            "length:1",
            "pressure:1",
            "force:3",
            "--times",
            "0,5,10",
        ],
    );

    // --component and --warp: the bending stress XX takes both signs (a diverging map), von
    // Mises is one-signed (sequential), an unknown component is an error
    if has_xvfb() {
        let (low, high, diverging) = shown(&render(&beam, &["--component", "XX"]));
        eprintln!("XX {low} .. {high} diverging {diverging}");
        assert!(low < 0.0 && high > 0.0 && diverging, "XX {low} .. {high}");
        let report = render(&beam, &["--component", "von_mises", "--warp", "10"]);
        let (low, high, diverging) = shown(&report);
        assert!(
            low >= 0.0 && high > low && !diverging,
            "von Mises {low} .. {high}"
        );
        let output = Command::new("pvpython")
            .arg(root().join("scripts/show_stress.py"))
            .arg(&beam)
            .args(["--component", "sideways"])
            .output()
            .unwrap();
        let report = text(&output);
        assert!(
            !output.status.success() && report.contains("--component 'sideways'"),
            "{report}"
        );
    }

    // the checker fails on a missing field or wrong times, so it can fail
    let output = Command::new("pvpython")
        .arg(root().join("scripts/check_output.py"))
        .arg(&beam)
        .args(["cauchy_stress:9", "--times", "0,1"])
        .output()
        .unwrap();
    assert!(!output.status.success(), "{}", text(&output));
    let output = Command::new("pvpython")
        .arg(root().join("scripts/check_output.py"))
        .arg(&beam)
        .args(["--tractions", "force:3"])
        .output()
        .unwrap();
    assert!(!output.status.success(), "{}", text(&output));
}
