//! The `impm` command line: runs, clear errors on bad scenes, and failed solves that keep
//! their results valid and exit non-zero.

use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
use common::{column_script, impm};

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn temp(name: &str) -> PathBuf {
    let dir = common::temp_dir("cli", name);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A 1D column scene with a solver section, written to `dir`.
fn scene_with(dir: &Path, name: &str, extra: &str, body_force: &str) -> String {
    let text = format!(
        r#"let cells = 10;
grid(#{{ lower: [0.0], upper: [10.0], cells: [cells], basis: "bspline", order: 2 }});
const m = material(#{{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 }});
body(#{{ name: "column", material: m, region: box([0.0], [10.0]), ppc: 2 }});
body_force([{body_force}]);
fix(|x| x[0] == 0.0, [0]);
load_steps(4);
{extra}
"#
    );
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path.display().to_string()
}

#[test]
fn run_writes_the_series_and_the_summary() {
    let dir = temp("run");
    let out = impm(&[
        "run",
        &column_script(),
        "--set",
        "cells=10",
        "--set",
        "steps=4",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    for k in 0..=4 {
        for stem in ["particles", "grid", "nodes"] {
            let file = dir.join(format!("{stem}_{k:04}.vtu"));
            assert!(impm::output::read_vtu(&file).is_ok(), "{}", file.display());
        }
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["status"], "completed");
    assert_eq!(summary["steps"].as_array().unwrap().len(), 4);
    assert!(summary["error"].as_f64().unwrap() < 1e-2);
    let pvd = std::fs::read_to_string(dir.join("particles.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 5);
}

#[test]
fn bad_scenes_name_the_file_and_line() {
    let dir = temp("bad");
    let cases: [(&str, &str, &str); 4] = [
        (
            "syntax.rhai",
            "let cells = 3;\ngrid(#{ lower: [0.0] upper: [1.0] });\n",
            ":2:",
        ),
        (
            "negative_e.rhai",
            "let a = 1;\nconst m = material(#{ name: \"x\", E: -1.0, nu: 0.0, density: 1.0 });\n",
            ":2:",
        ),
        (
            "outside.rhai",
            "grid(#{ lower: [0.0], upper: [1.0], cells: [2], basis: \"linear\" });\nconst m = material(#{ name: \"m\", E: 1.0, nu: 0.0, density: 1.0 });\n\nbody(#{ name: \"b\", material: m, region: box([0.0], [2.0]), ppc: 1 });\nload_steps(1);\n",
            ":4:",
        ),
        (
            "typo.rhai",
            "grid(#{ lower: [0.0], upper: [1.0], cell: [2], basis: \"linear\" });\n",
            ":1:",
        ),
    ];
    for (name, text, line) in cases {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        let out_dir = dir.join("o");
        for args in [
            vec!["check", path.to_str().unwrap()],
            vec![
                "run",
                path.to_str().unwrap(),
                "--out",
                out_dir.to_str().unwrap(),
            ],
        ] {
            let out = impm(&args);
            let err = stderr(&out);
            assert!(!out.status.success(), "{name}: should fail");
            assert!(err.contains(&format!("{name}{line}")), "{name}: {err}");
            assert!(!err.contains("panicked"), "{name}: {err}");
        }
    }
    // Impossible parameter values through --set
    for (set, needle) in [
        ("order=0", "order"),
        ("cells=0", "cells"),
        ("nope=1", "no parameter 'nope'"),
    ] {
        let out = impm(&["check", &column_script(), "--set", set]);
        assert!(!out.status.success());
        assert!(stderr(&out).contains(needle), "{set}: {}", stderr(&out));
    }
}

#[test]
fn a_solve_that_does_not_converge_says_where_keeps_results_and_fails() {
    let dir = temp("diverge");
    // One Newton iteration is not enough for any load step.
    let scene = scene_with(
        &dir,
        "stiff.rhai",
        "solver(#{ tolerance: 1.0e-12, max_iterations: 1 });",
        "-100.0",
    );
    let out_dir = dir.join("out");
    let out = impm(&["run", &scene, "--out", out_dir.to_str().unwrap()]);
    let err = stderr(&out);
    assert!(!out.status.success());
    assert!(
        err.contains("load step 1") && err.contains("did not converge"),
        "{err}"
    );
    assert!(
        err.contains("iteration   0") && err.contains("iteration   1"),
        "residual history: {err}"
    );
    // What was written before the failure is valid.
    assert!(impm::output::read_vtu(&out_dir.join("particles_0000.vtu")).is_ok());
    let pvd = std::fs::read_to_string(out_dir.join("particles.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 1);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["status"], "failed");
    assert!(
        summary["failure"]
            .as_str()
            .unwrap()
            .contains("did not converge")
    );
}

#[test]
fn a_point_leaving_the_grid_is_reported_not_a_panic() {
    let dir = temp("leave");
    // Upward body force on a column that fills its grid: the top rises out of the grid.
    let scene = scene_with(&dir, "rise.rhai", "", "200.0");
    let out = impm(&["run", &scene, "--out", dir.join("out").to_str().unwrap()]);
    let err = stderr(&out);
    assert!(!out.status.success());
    assert!(err.contains("left the background grid"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn check_explain_lists_the_systems_of_the_scene() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/beam_point_load.rhai");
    let out = impm(&["check", scene.to_str().unwrap(), "--explain"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("force          = -0.2"), "{text}");
    assert!(text.contains("  point loads                 yes"), "{text}");
    let scheduled = text.split("left out").next().unwrap();
    assert!(
        scheduled.contains("Hook::Loads             point_loads::apply_point_loads"),
        "{text}"
    );
    assert!(!scheduled.contains("apply_body_force"), "{text}");
    assert!(!scheduled.contains("tractions::"), "{text}");
    let left_out = text.split("left out").nth(1).unwrap();
    assert!(left_out.contains("body_force::apply_body_force"), "{text}");
    assert!(left_out.contains("tractions::apply_tractions"), "{text}");
}

#[test]
fn a_cpdi_domain_leaving_the_grid_names_the_point_and_corner() {
    let dir = temp("cpdi-leave");
    // A rising column with CPDI: the top point's domain reaches the top of the grid at the
    // start; after the first step its upper corner is outside the grid by more than the
    // twentieth of a cell that is projected (basis::cpdi), the point is not.
    let scene = scene_with(&dir, "rise.rhai", "", "60.0");
    let text = std::fs::read_to_string(&scene)
        .unwrap()
        .replace(r#"basis: "bspline", order: 2"#, r#"basis: "cpdi""#);
    std::fs::write(&scene, text).unwrap();
    let out = impm(&["run", &scene, "--out", dir.join("out").to_str().unwrap()]);
    let err = stderr(&out);
    assert!(!out.status.success());
    assert!(
        err.contains("load step 2: the domain of material point 19 cannot be used: the corner")
            && err.contains("of its CPDI domain is outside the background grid along axis 0"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// Under `mpirun` with more than one process (OpenMPI's environment, set here by hand so that
/// no MPI is needed) only `impm run` runs: `impm study` and `impm check` are refused before
/// they write anything, by process 0 with the reason and by the others quietly, all with exit
/// status 1; with one process they run as usual. (`tests/mpi.rs` checks it under `mpirun`.)
#[test]
fn commands_other_than_run_are_refused_over_several_mpi_processes() {
    let dir = temp("mpi-refused");
    let scene = scene_with(&dir, "column.rhai", "", "-10.0");
    let out = dir.join("study").display().to_string();
    let under = |rank: &str, size: &str, args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_impm"))
            .args(args)
            .env("OMPI_COMM_WORLD_RANK", rank)
            .env("OMPI_COMM_WORLD_SIZE", size)
            .output()
            .unwrap()
    };
    let study = ["study", &scene, "--sweep", "cells=4,8", "--out", &out];
    let first = under("0", "2", &study);
    let err = stderr(&first);
    assert_eq!(first.status.code(), Some(1), "{err}");
    assert!(
        err.contains("impm study under mpirun with 2 processes")
            && err.contains("every process would run the whole study into the same folder")
            && err.contains("run it without mpirun (or with mpirun -n 1)"),
        "{err}"
    );
    let other = under("1", "2", &study);
    assert_eq!(other.status.code(), Some(1));
    assert!(other.stderr.is_empty(), "{}", stderr(&other));
    assert!(!Path::new(&out).exists(), "nothing written");
    let check = under("0", "3", &["check", &scene]);
    assert_eq!(check.status.code(), Some(1));
    assert!(
        stderr(&check).contains("impm check under mpirun with 3 processes"),
        "{}",
        stderr(&check)
    );
    assert!(under("0", "1", &["check", &scene]).status.success());
    // a build without distributed runs refuses `impm run` too (with them, it runs)
    #[cfg(not(feature = "mpi"))]
    {
        let run = under("0", "2", &["run", &scene, "--out", &out]);
        assert_eq!(run.status.code(), Some(1));
        assert!(
            stderr(&run)
                .contains("this build has no distributed runs: build impm with --features mpi"),
            "{}",
            stderr(&run)
        );
        assert!(!Path::new(&out).exists(), "nothing written");
    }
    let alone = under("0", "1", &study);
    assert!(alone.status.success(), "{}", stderr(&alone));
    assert!(Path::new(&out).join("study.csv").is_file());
}
