//! Real signals and closed or full output streams: SIGINT and SIGKILL sent to a running
//! `impm run` and `impm study`, a reader that goes away, stdout on `/dev/full`. Nothing may
//! panic; every file written stays readable; an interrupted run says so in `summary.json` and
//! an interrupted study keeps its rows.

use std::io::Read;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

mod common;

fn impm() -> Command {
    Command::new(env!("CARGO_BIN_EXE_impm"))
}

fn shipped(name: &str) -> String {
    common::shipped_scene(name).display().to_string()
}

/// Sends `signal` (e.g. "INT", "KILL") to the child.
fn signal(child: &Child, signal: &str) {
    let status = Command::new("kill")
        .args([format!("-{signal}"), child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success());
}

/// Waits until `ready` holds (polling), at most 60 s.
fn wait_for(what: &str, ready: impl Fn() -> bool) {
    let start = Instant::now();
    while !ready() {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "timed out waiting for {what}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Completed steps recorded in `summary.json`, if it is there.
fn steps_done(dir: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(dir.join("summary.json")).ok()?;
    let summary: serde_json::Value = serde_json::from_str(&text).ok()?;
    summary["totals"]["steps"].as_u64()
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

/// Every `.vtu` of the folder reads back; returns how many there are.
fn all_vtu_readable(dir: &Path) -> usize {
    let mut count = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "vtu") {
            assert!(impm::output::read_vtu(&path).is_ok(), "{}", path.display());
            count += 1;
        }
    }
    count
}

/// A long run of the 2D column (many small steps) into `dir`.
fn long_run(dir: &Path) -> Child {
    impm()
        .args([
            "run",
            &shipped("column_2d.rhai"),
            "--set",
            "cells=20",
            "--set",
            "steps=2000",
        ])
        .arg("--out")
        .arg(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn output_of(mut child: Child) -> (Option<i32>, String) {
    let mut text = String::new();
    let _ = child.stderr.take().unwrap().read_to_string(&mut text);
    let _ = child.stdout.take().unwrap().read_to_string(&mut text);
    (child.wait().unwrap().code(), text)
}

#[test]
fn sigint_ends_a_run_after_its_step_with_status_interrupted() {
    let dir = common::temp_dir("signals", "sigint-run");
    let child = long_run(&dir);
    wait_for("two steps", || steps_done(&dir).is_some_and(|n| n >= 2));
    signal(&child, "INT");
    let (status, text) = output_of(child);
    assert_eq!(status, Some(1), "{text}");
    assert!(text.contains("interrupted after load step"), "{text}");
    assert!(
        text.contains("results up to the last completed step are in"),
        "{text}"
    );
    assert!(!text.contains("panicked"), "{text}");
    let summary = summary(&dir);
    assert_eq!(summary["status"], "interrupted");
    let done = summary["totals"]["steps"].as_u64().unwrap();
    assert!((2..2000).contains(&done), "{done}");
    // output every step: the initial state and one file per completed step, for particles,
    // grid and nodes
    assert_eq!(all_vtu_readable(&dir) as u64, 3 * (done + 1));
    let pvd = std::fs::read_to_string(dir.join("particles.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count() as u64, done + 1);
    assert!(!dir.join(".impm.lock").exists(), "the lock is released");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sigkill_leaves_readable_files_and_the_next_run_reports_it_and_replaces_them() {
    let dir = common::temp_dir("signals", "sigkill-run");
    let child = long_run(&dir);
    wait_for("two steps", || steps_done(&dir).is_some_and(|n| n >= 2));
    signal(&child, "KILL");
    let (status, _) = output_of(child);
    assert_eq!(status, None, "killed by the signal");
    assert!(all_vtu_readable(&dir) >= 9);
    assert_eq!(summary(&dir)["status"], "running");
    assert!(
        dir.join(".impm.lock").exists(),
        "a killed run leaves its lock"
    );
    // the next run into the folder: the stale lock is reported, the earlier files replaced
    let out = impm()
        .args([
            "run",
            &shipped("column_1d.rhai"),
            "--set",
            "cells=5",
            "--set",
            "steps=1",
        ])
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("was killed before it finished"), "{err}");
    assert_eq!(summary(&dir)["status"], "completed");
    // steps 0 and 1 of particles, grid and nodes: nothing of the killed run is left
    assert_eq!(all_vtu_readable(&dir), 6);
    assert!(
        !std::fs::read_dir(&dir)
            .unwrap()
            .any(|e| { e.unwrap().file_name().to_string_lossy().ends_with(".tmp") })
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_second_run_into_a_busy_folder_is_refused() {
    let dir = common::temp_dir("signals", "busy");
    let child = long_run(&dir);
    wait_for("a step", || steps_done(&dir).is_some_and(|n| n >= 1));
    let out = impm()
        .args(["run", &shipped("column_1d.rhai"), "--set", "cells=5"])
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("another impm run (process {})", child.id())),
        "{err}"
    );
    signal(&child, "INT");
    let (status, _) = output_of(child);
    assert_eq!(status, Some(1));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sigint_ends_a_study_keeping_the_rows_of_the_runs_done() {
    let dir = common::temp_dir("signals", "sigint-study");
    let child = impm()
        .args(["study", &shipped("column_2d.rhai")])
        .args([
            "--sweep",
            "cells=4,5,6,7,8,9,10,11,12,13",
            "--set",
            "steps=400",
        ])
        .arg("--out")
        .arg(&dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let rows = |dir: &Path| {
        std::fs::read_to_string(dir.join("study.csv"))
            .map_or(0, |t| t.lines().count().saturating_sub(1))
    };
    wait_for("one row", || rows(&dir) >= 1);
    signal(&child, "INT");
    let (status, text) = output_of(child);
    assert_eq!(status, Some(1), "{text}");
    assert!(text.contains("the study was interrupted after"), "{text}");
    let csv = std::fs::read_to_string(dir.join("study.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().skip(1).collect();
    assert!(!lines.is_empty() && lines.len() < 10, "{csv}");
    // every run before the last completed; the last either completed (the signal came between
    // runs) or stopped after its load step in flight, recorded as interrupted
    let (last, before) = lines.split_last().unwrap();
    assert!(before.iter().all(|l| l.contains(",completed,")), "{csv}");
    assert!(
        last.contains(",completed,") || last.contains(",interrupted,"),
        "{csv}"
    );
    let md = std::fs::read_to_string(dir.join("study.md")).unwrap();
    assert_eq!(
        md.contains("interrupted"),
        last.contains(",interrupted,"),
        "{md}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_study_run_past_its_timeout_is_recorded_and_the_study_goes_on() {
    let dir = common::temp_dir("signals", "timeout");
    let out = impm()
        .args(["study", &shipped("column_1d.rhai")])
        .args([
            "--sweep",
            "steps=2,3000",
            "--set",
            "cells=20",
            "--timeout",
            "0.5",
        ])
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(dir.join("study.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(lines.len(), 2, "{csv}");
    assert!(lines[0].contains(",completed,"), "{csv}");
    assert!(lines[1].contains(",timed out,"), "{csv}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_reader_that_goes_away_ends_the_program_quietly() {
    let mut child = impm()
        .arg("api")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let mut err = String::new();
    let _ = child.stderr.take().unwrap().read_to_string(&mut err);
    let status = child.wait().unwrap();
    // either it wrote everything before the pipe closed, or it ends with 141 and no panic
    assert!(
        matches!(status.code(), Some(0) | Some(141)),
        "{status:?} {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn full_stdout_and_stderr_do_not_panic() {
    let full = || {
        std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap()
    };
    let out = impm()
        .args(["check", &shipped("column_1d.rhai")])
        .stdout(full())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("cannot write to standard output: No space left"),
        "{err}"
    );
    let dir = common::temp_dir("signals", "full-stderr");
    let out = impm()
        .args([
            "run",
            &shipped("column_1d.rhai"),
            "--set",
            "cells=5",
            "--set",
            "steps=2",
        ])
        .arg("--out")
        .arg(&dir)
        .stderr(full())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&out.stdout).contains("done: 2 steps"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The files a `.pvd` series lists, in order.
fn listed_in(pvd: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(pvd).unwrap();
    text.split("file=\"")
        .skip(1)
        .filter_map(|rest| rest.split('"').next())
        .map(str::to_string)
        .collect()
}

/// A full disk: the output folder is a small `tmpfs` mounted in a user and mount namespace of
/// the test's own (`unshare -rm`, which needs no privileges where the kernel allows user
/// namespaces), so the run fills it after a few steps. What the run wrote is copied out of the
/// namespace before it ends. Skipped, saying why, where such a mount cannot be made.
#[test]
fn a_full_disk_ends_the_run_naming_the_file_and_keeps_the_steps_done_readable() {
    let dir = common::temp_dir("signals", "full-disk");
    let (disk, kept) = (dir.join("disk"), dir.join("kept"));
    std::fs::create_dir_all(&disk).unwrap();
    std::fs::create_dir_all(&kept).unwrap();
    let probe = Command::new("unshare")
        .args(["-rm", "sh", "-c", "mount -t tmpfs -o size=4k tmpfs \"$0\""])
        .arg(&disk)
        .output();
    match probe {
        Ok(probe) if probe.status.success() => {}
        Ok(probe) => {
            eprintln!(
                "skipped: no tmpfs can be mounted in a user namespace here: {}",
                String::from_utf8_lossy(&probe.stderr)
            );
            return;
        }
        Err(e) => {
            eprintln!("skipped: `unshare` (util-linux) cannot run: {e}");
            return;
        }
    }
    // $0 impm, $1 the small disk, $2 the scene, $3 where to keep what was written
    let script = "mount -t tmpfs -o size=160k tmpfs \"$1\" || exit 99; \
                  \"$0\" run \"$2\" --set cells=5 --set steps=40 --out \"$1\"; status=$?; \
                  cp -a \"$1\"/. \"$3\"/; exit $status";
    let out = Command::new("unshare")
        .args(["-rm", "sh", "-c", script, env!("CARGO_BIN_EXE_impm")])
        .arg(&disk)
        .arg(common::column_script())
        .arg(&kept)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    // the message names the file and says what to do
    assert!(
        err.contains(&format!("writing {}/", disk.display()))
            && err
                .contains("no space left on the device: free space, or write elsewhere with --out"),
        "{err}"
    );
    // every series lists complete, readable steps only, the same ones summary.json records
    let particles = listed_in(&kept.join("particles.pvd"));
    assert!(
        (3..41).contains(&particles.len()),
        "the disk filled after {} output steps (expected a few): {err}",
        particles.len()
    );
    for series in ["particles.pvd", "grid.pvd", "nodes.pvd"] {
        let files = listed_in(&kept.join(series));
        assert_eq!(files.len(), particles.len(), "{series}");
        for file in files {
            assert!(
                impm::output::read_vtu(&kept.join(&file)).is_ok(),
                "{series} lists {file}, which does not read"
            );
        }
    }
    all_vtu_readable(&kept);
    let summary = summary(&kept);
    assert_eq!(
        summary["steps"].as_array().map(Vec::len),
        Some(particles.len() - 1),
        "summary.json records other steps than particles.pvd lists"
    );
    // the failure is recorded, or the message says it could not be
    if summary["status"] == "running" {
        assert!(
            err.contains("could not be updated after the failure"),
            "{err}"
        );
    } else {
        assert_eq!(summary["status"], "failed");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
