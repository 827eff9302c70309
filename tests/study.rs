//! `impm study` end to end on small sweeps of the 1D column: the CSV holds what it says (one
//! row per run, the documented columns, errors equal to each run's own summary.json), failed
//! runs are recorded and not fatal, and the charts, table and profiles are written.

use std::path::{Path, PathBuf};

mod common;
use common::{column_script, impm};

fn temp(name: &str) -> PathBuf {
    common::temp_dir("study", name)
}

/// A CSV without quoted fields: header and rows as maps from column name to text.
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<(String, String)>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|line| {
            let cells: Vec<&str> = line.split(',').collect();
            assert_eq!(cells.len(), header.len(), "row {line}");
            header
                .iter()
                .cloned()
                .zip(cells.iter().map(|c| c.to_string()))
                .collect()
        })
        .collect();
    (header, rows)
}

fn get<'a>(row: &'a [(String, String)], name: &str) -> &'a str {
    &row.iter().find(|(n, _)| n == name).unwrap().1
}

fn summary(dir: &Path, row: &[(String, String)]) -> serde_json::Value {
    let path = dir.join(get(row, "run_dir")).join("summary.json");
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn study_runs_the_cross_product_and_its_csv_matches_each_run() {
    let dir = temp("cross");
    let out = impm(&[
        "study",
        &column_script(),
        "--sweep",
        "cells=5,10",
        "--sweep",
        "basis=linear,bspline",
        "--set",
        "steps=2",
        "--set",
        "recovery=mls",
        "--profiles",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (header, rows) = read_csv(&dir.join("study.csv"));
    assert_eq!(rows.len(), 4);
    assert_eq!(&header[..3], ["index", "cells", "basis"]);
    for column in [
        "status",
        "error",
        "error_recovered",
        "points",
        "dofs",
        "iterations",
        "wall_seconds",
        "t_assembly",
        "t_linear_solve",
        "t_update_points",
        "peak_rss_mib",
        "message",
    ] {
        assert!(header.iter().any(|h| h == column), "column {column}");
    }
    let mut bspline_errors = Vec::new();
    for (k, row) in rows.iter().enumerate() {
        // first sweep outermost
        let cells = if k < 2 { "5" } else { "10" };
        let basis = if k % 2 == 0 { "linear" } else { "bspline" };
        assert_eq!((get(row, "cells"), get(row, "basis")), (cells, basis));
        assert_eq!(get(row, "status"), "completed");
        let s = summary(&dir, row);
        assert_eq!(s["status"], "completed");
        for (column, key) in [("error", "error"), ("error_recovered", "error_recovered")] {
            let value: f64 = get(row, column).parse().unwrap();
            assert!(value.is_finite() && value > 0.0, "{column} {value}");
            assert_eq!(value, s[key].as_f64().unwrap(), "{column} of run {k}");
        }
        assert_eq!(
            get(row, "points").parse::<u64>().unwrap(),
            s["points"].as_u64().unwrap()
        );
        assert_eq!(
            get(row, "iterations").parse::<u64>().unwrap(),
            s["totals"]["iterations"].as_u64().unwrap()
        );
        let steps = s["steps"].as_array().unwrap();
        assert_eq!(
            get(row, "dofs").parse::<u64>().unwrap(),
            steps.last().unwrap()["dofs"].as_u64().unwrap()
        );
        let wall: f64 = get(row, "wall_seconds").parse().unwrap();
        let steps_wall = s["totals"]["wall_seconds"].as_f64().unwrap();
        assert!(wall >= steps_wall, "run wall {wall} < steps {steps_wall}");
        let peak: f64 = get(row, "peak_rss_mib").parse().unwrap();
        let base: f64 = get(row, "baseline_rss_mib").parse().unwrap();
        assert!(peak >= base && peak > 0.0, "peak {peak}, baseline {base}");
        if basis == "bspline" {
            bspline_errors.push(get(row, "error").parse::<f64>().unwrap());
        }
        // each run wrote only its initial and final state
        let run = dir.join(get(row, "run_dir"));
        assert!(run.join("particles_0000.vtu").exists());
        assert!(run.join("particles_0002.vtu").exists());
        assert!(!run.join("particles_0001.vtu").exists());
    }
    assert!(
        bspline_errors[1] < 0.75 * bspline_errors[0],
        "B-spline error should fall with cells: {bspline_errors:?}"
    );

    // Profiles: eq. 15 recomputed from the points' stresses equals the study's error.
    let (_, points) = read_csv(&dir.join("profiles.csv"));
    for row in &rows {
        let index = get(row, "index");
        let run: Vec<_> = points.iter().filter(|p| get(p, "index") == index).collect();
        let n = get(row, "points").parse::<usize>().unwrap();
        assert_eq!(run.len(), n);
        let weight = 800.0 * 50.0;
        let sum: f64 = run
            .iter()
            .map(|p| {
                let s: f64 = get(p, "stress").parse().unwrap();
                let a: f64 = get(p, "analytic").parse().unwrap();
                (s - a).abs()
            })
            .sum();
        // uniform seeding: V0 = L0 / n, so eq. 15 = sum |σ − σ_A| / (n W)
        let error: f64 = get(row, "error").parse().unwrap();
        let recomputed = sum / (n as f64 * weight);
        assert!(
            (recomputed - error).abs() <= 1e-9 * error,
            "run {index}: {recomputed} vs {error}"
        );
    }

    for stem in [
        "error_vs_cells",
        "error_vs_time",
        "profiles",
        "profile_errors",
    ] {
        let svg = std::fs::read_to_string(dir.join(format!("{stem}.svg"))).unwrap();
        assert!(
            svg.contains("<svg") && svg.contains("<polyline"),
            "{stem}.svg"
        );
        let png = std::fs::read(dir.join(format!("{stem}.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{stem}.png");
    }
    let md = std::fs::read_to_string(dir.join("study.md")).unwrap();
    assert!(md.contains("| 10 | bspline | ok |"), "{md}");
    assert!(md.contains("| basis=bspline | raw |"), "{md}");
    assert!(md.contains("| basis=bspline | recovered |"), "{md}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_failed_run_is_recorded_and_the_study_goes_on() {
    let dir = temp("failed");
    let out = impm(&[
        "study",
        &column_script(),
        "--sweep",
        "basis:order=bspline:2,bspline:0",
        "--set",
        "cells=5",
        "--set",
        "steps=1",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(dir.join("study.csv")).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 3);
    assert!(lines[1].contains(",completed,"), "{}", lines[1]);
    assert!(
        lines[2].contains(",failed,") && lines[2].contains("order"),
        "{}",
        lines[2]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unknown_sweep_parameters_are_refused_before_running() {
    let dir = temp("unknown");
    let out = impm(&[
        "study",
        &column_script(),
        "--sweep",
        "cels=5,10",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no parameter 'cels'"), "{err}");
    assert!(!dir.join("study.csv").exists());
}

/// A scene without an analytic solution (the strip footing): the study runs, says that no run
/// reports an error (console and study.md) and draws no empty error charts.
#[test]
fn a_study_without_an_error_measure_says_so_and_draws_no_error_charts() {
    let dir = temp("no_error");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/strip_footing.rhai");
    let out = impm(&[
        "study",
        scene.to_str().unwrap(),
        "--sweep",
        "cells=2,4",
        "--set",
        "steps=1",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("no run reports an error"), "{err}");
    let md = std::fs::read_to_string(dir.join("study.md")).unwrap();
    assert!(md.contains("no run reports an error"), "{md}");
    assert!(!md.contains("error_vs_"), "{md}");
    assert!(!dir.join("error_vs_time.svg").exists());
    assert!(!dir.join("error_vs_cells.svg").exists());
    let (_, rows) = read_csv(&dir.join("study.csv"));
    assert_eq!(rows.len(), 2);
    assert!(rows.iter().all(|r| get(r, "status") == "completed"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A word among the values of a parameter whose default is a number is refused before any run
/// (it would fail its run and, before, silently took the error chart and every rate with it).
#[test]
fn a_word_in_a_numeric_sweep_is_refused_naming_the_parameter_and_value() {
    let dir = temp("word");
    let out = impm(&[
        "study",
        &column_script(),
        "--sweep",
        "cells=5,ten",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("parameter 'cells' = 'ten' is not a number"),
        "{err}"
    );
    assert!(!dir.join("study.csv").exists());
}

/// When the default is an expression (the column's `ppc`), a word cannot be told from the
/// scene: the run fails, and study.md and stderr say that the chart and rates against that
/// parameter are left out and why.
#[test]
fn a_word_in_a_sweep_over_an_expression_is_reported_in_study_md_and_on_stderr() {
    let dir = temp("word_expression");
    let out = impm(&[
        "study",
        &column_script(),
        "--sweep",
        "ppc=2,x,3",
        "--set",
        "cells=5",
        "--set",
        "steps=1",
        "--against",
        "ppc",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let note = "parameter 'ppc' took the value 'x', which is not a number";
    assert!(err.contains(note), "{err}");
    let md = std::fs::read_to_string(dir.join("study.md")).unwrap();
    assert!(md.contains(note), "{md}");
    // the failed run's message is a quoted field with commas: read the rows as text
    let csv = std::fs::read_to_string(dir.join("study.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 3, "{csv}");
    assert!(rows[0].starts_with("0,2,completed,"), "{csv}");
    assert!(rows[1].starts_with("1,x,failed,"), "{csv}");
    assert!(rows[2].starts_with("2,3,completed,"), "{csv}");
    let _ = std::fs::remove_dir_all(&dir);
}
