//! Checkpoint and restart with real signals: a run interrupted (SIGINT) or killed (SIGKILL)
//! partway and resumed with `impm run SCENE --resume OUT_DIR` writes the same files as the run
//! that was never stopped: every `.vtu`, `.pvd` and `history.csv` byte for byte, and the same
//! `summary.json` apart from the timings. An elasto-plastic scene proves that the points'
//! plastic history is restored (its `plastic_strain` is in the compared files, and the run is
//! stopped after the material has yielded). A checkpoint of another scene or other `--set`
//! values is refused.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

mod common;

fn impm() -> Command {
    Command::new(env!("CARGO_BIN_EXE_impm"))
}

fn shipped(name: &str) -> String {
    common::shipped_scene(name).display().to_string()
}

/// `impm run SCENE --set .. EXTRA..`.
fn run_command(scene: &str, set: &[&str], extra: &[&str]) -> Command {
    let mut command = impm();
    command.args(["run", scene]);
    for assignment in set {
        command.args(["--set", assignment]);
    }
    command.args(extra);
    command
}

/// Runs to the end; panics with the output if the run fails.
fn run_to_end(mut command: Command) -> String {
    let out = command.output().unwrap();
    let text = String::from_utf8_lossy(&out.stderr).into_owned()
        + String::from_utf8_lossy(&out.stdout).as_ref();
    assert!(out.status.success(), "{text}");
    assert!(!text.contains("panicked"), "{text}");
    text
}

fn summary(dir: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

fn steps_done(dir: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(dir.join("summary.json")).ok()?;
    serde_json::from_str::<Value>(&text).ok()?["totals"]["steps"].as_u64()
}

/// Starts the run, waits until `after` steps are done and sends `signal` ("INT", "KILL");
/// returns the exit code (None when killed) and what the run printed.
fn stop_partway(
    mut command: Command,
    dir: &Path,
    after: u64,
    signal: &str,
) -> (Option<i32>, String) {
    let mut child: Child = command
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while steps_done(dir).is_none_or(|n| n < after) {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "the run did not get to step {after}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let status = Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let mut text = String::new();
    let _ = child.stderr.take().unwrap().read_to_string(&mut text);
    let _ = child.stdout.take().unwrap().read_to_string(&mut text);
    (child.wait().unwrap().code(), text)
}

/// The files impm wrote into `dir` (not the checkpoint, the summary or the lock), by name.
fn result_files(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.ends_with(".vtu") || n.ends_with(".pvd") || n == "history.csv")
        .collect();
    names.sort();
    names
}

/// `summary.json` without its timings.
fn without_timings(value: &Value) -> Value {
    match value {
        Value::Object(map) => Value::Object(
            map.iter()
                .filter(|(key, _)| !matches!(key.as_str(), "seconds" | "wall_seconds"))
                .map(|(key, v)| (key.clone(), without_timings(v)))
                .collect(),
        ),
        Value::Array(list) => Value::Array(list.iter().map(without_timings).collect()),
        other => other.clone(),
    }
}

/// The resumed run's folder holds exactly the files of the uninterrupted run, byte for byte,
/// and the same summary apart from timings.
fn assert_same_results(reference: &Path, resumed: &Path) {
    let names = result_files(reference);
    assert_eq!(result_files(resumed), names);
    assert!(names.len() > 10, "{names:?}");
    for name in &names {
        let a = std::fs::read(reference.join(name)).unwrap();
        let b = std::fs::read(resumed.join(name)).unwrap();
        assert!(a == b, "{name} differs after the resumed run");
    }
    let (a, b) = (summary(reference), summary(resumed));
    assert_eq!(b["status"], "completed");
    assert_eq!(without_timings(&a), without_timings(&b));
    assert!(
        b.get("resume").is_none(),
        "a completed run needs no resuming"
    );
}

struct Case {
    tag: &'static str,
    scene: String,
    set: Vec<&'static str>,
    /// Extra arguments of every run (e.g. `--checkpoint-every`).
    extra: Vec<&'static str>,
}

impl Case {
    fn dirs(&self) -> (PathBuf, PathBuf) {
        (
            common::temp_dir("resume", &format!("{}-reference", self.tag)),
            common::temp_dir("resume", &format!("{}-stopped", self.tag)),
        )
    }

    fn command(&self, extra: &[&str]) -> Command {
        let mut args = self.extra.clone();
        args.extend(extra);
        run_command(&self.scene, &self.set, &args)
    }

    fn out(dir: &Path) -> [&str; 2] {
        ["--out", dir.to_str().unwrap()]
    }

    /// Runs uninterrupted into `reference`; runs into `stopped`, stops it with `signal` after
    /// `after` steps, resumes it with the command it printed or wrote, and compares; returns
    /// the steps the stopped run had done.
    fn check(&self, reference: &Path, stopped: &Path, after: u64, signal: &str) -> u64 {
        let (code, text) = stop_partway(self.command(&Self::out(stopped)), stopped, after, signal);
        assert!(!text.contains("panicked"), "{text}");
        let partial = summary(stopped);
        let done = partial["totals"]["steps"].as_u64().unwrap();
        let planned = partial["planned_steps"].as_u64().unwrap();
        assert!(done < planned, "the run ended before the signal: {text}");
        let resume = partial["resume"].as_str().unwrap().to_string();
        if signal == "INT" {
            assert_eq!(code, Some(1), "{text}");
            assert_eq!(partial["status"], "interrupted");
            assert!(
                text.contains(&format!("to continue from the last checkpoint: {resume}")),
                "{text}"
            );
        } else {
            assert_eq!(code, None, "killed by the signal");
            assert_eq!(partial["status"], "running");
        }
        assert!(
            resume.ends_with(&format!("--resume {}", stopped.display())),
            "{resume}"
        );
        let text = run_to_end(self.command(&["--resume", stopped.to_str().unwrap()]));
        assert!(text.contains("resuming"), "{text}");
        assert_same_results(reference, stopped);
        done
    }
}

#[test]
fn a_run_stopped_by_sigint_resumes_to_bit_identical_results() {
    let case = Case {
        tag: "sigint",
        scene: shipped("column_2d.rhai"),
        set: vec!["cells=10", "steps=120"],
        extra: vec![],
    };
    let (reference, stopped) = case.dirs();
    run_to_end(case.command(&Case::out(&reference)));
    case.check(&reference, &stopped, 15, "INT");

    // the checkpoint belongs to this scene and these values: anything else is refused
    let other = run_command(&case.scene, &["cells=10", "steps=121"], &["--resume"])
        .arg(&stopped)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&other.stderr);
    assert_eq!(other.status.code(), Some(1), "{err}");
    assert!(
        err.contains("was written by a run with --set cells=10 --set steps=120")
            && err.contains("this command has --set cells=10 --set steps=121"),
        "{err}"
    );
    let other = run_command(&shipped("column_1d.rhai"), &case.set, &["--resume"])
        .arg(&stopped)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&other.stderr);
    assert_eq!(other.status.code(), Some(1), "{err}");
    assert!(err.contains("the scene changed"), "{err}");
    let _ = std::fs::remove_dir_all(&reference);
    let _ = std::fs::remove_dir_all(&stopped);
}

#[test]
fn a_killed_run_resumes_from_its_last_checkpoint_to_bit_identical_results() {
    // a checkpoint every 7 steps: the killed run wrote steps after its last checkpoint, which
    // the resumed run removes and writes again
    let case = Case {
        tag: "sigkill",
        scene: shipped("column_2d.rhai"),
        set: vec!["cells=10", "steps=120"],
        extra: vec!["--checkpoint-every", "7"],
    };
    let (reference, stopped) = case.dirs();
    run_to_end(case.command(&Case::out(&reference)));
    case.check(&reference, &stopped, 17, "KILL");
    let _ = std::fs::remove_dir_all(&reference);
    let _ = std::fs::remove_dir_all(&stopped);
}

/// A column of von Mises material under its weight: the base yields partway through the load.
const PLASTIC_COLUMN: &str = r#"let cells = 10;
let steps = 150;
const height = 50.0;
const width = height / cells;
const steel = material(#{ name: "steel", model: "von_mises", E: 1.0e6, nu: 0.3, sigma_y: 40000.0, H: 1.0e5, density: 1.0 });
grid(#{ lower: [0.0, 0.0], upper: [width, height], cells: [1, cells], basis: "bspline", order: 2 });
body(#{ name: "column", material: steel, region: box([0.0, 0.0], [width, height]), ppc: 3 });
body_force([0.0, -2000.0]);
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0 || x[0] == width, [0]);
load_steps(steps);
"#;

/// The largest plastic strain of the points in a particles file.
fn largest_plastic_strain(file: &Path) -> f64 {
    let contents = impm::output::read_vtu(file).unwrap();
    let (_, values) = contents.point_field("plastic_strain").unwrap();
    values.iter().copied().fold(0.0, f64::max)
}

#[test]
fn an_elasto_plastic_run_resumes_with_its_plastic_history() {
    let folder = common::temp_dir("resume", "plastic-scene");
    std::fs::create_dir_all(&folder).unwrap();
    let scene = folder.join("plastic_column.rhai");
    std::fs::write(&scene, PLASTIC_COLUMN).unwrap();
    let case = Case {
        tag: "plastic",
        scene: scene.display().to_string(),
        set: vec![],
        extra: vec![],
    };
    let (reference, stopped) = case.dirs();
    run_to_end(case.command(&Case::out(&reference)));
    // the first step after which a point has yielded (output is written every step)
    let planned = summary(&reference)["planned_steps"].as_u64().unwrap();
    let yielded = (1..=planned)
        .find(|&step| {
            let name = impm::output::step_file_name("particles", step as usize);
            largest_plastic_strain(&reference.join(name)) > 0.0
        })
        .expect("the base yields");
    assert!(
        yielded + 20 < planned,
        "yields at step {yielded} of {planned}"
    );
    // stopped after yielding: the checkpoint it resumes from holds plastic strains
    let done = case.check(&reference, &stopped, yielded + 5, "INT");
    assert!(
        done > yielded,
        "stopped after step {done}, yielded after {yielded}"
    );
    let _ = std::fs::remove_dir_all(&reference);
    let _ = std::fs::remove_dir_all(&stopped);
    let _ = std::fs::remove_dir_all(&folder);
}
