//! `study.csv` and `study.md`, and observed convergence rates.
//!
//! Numbers are written with Rust's shortest round-trip formatting (`{:e}` for errors), so a
//! value read back from the CSV equals the one in the run's `summary.json` exactly.
//!
//! The observed rate between two runs of a series is `r = −ln(e₂/e₁) / ln(n₂/n₁)` for errors
//! `e` at parameter values `n` (cells), i.e. the slope of the error on a log-log chart with the
//! sign turned so that a convergent method has a positive rate; the series rate is the
//! least-squares slope of `ln e` against `ln n` over all its runs, with the same sign.

use std::fmt::Write as _;

use super::{RunOutcome, RunRecord, StudyPlan};
use crate::resources::Stage;

/// The CSV columns after the swept parameters' own columns.
pub fn csv_header() -> Vec<String> {
    let mut columns: Vec<String> = [
        "status",
        "error",
        "error_recovered",
        "points",
        "nodes",
        "dofs",
        "steps",
        "iterations",
        "wall_seconds",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    columns.extend(Stage::ALL.iter().map(|s| format!("t_{}", s.name())));
    columns.extend(
        [
            "baseline_rss_mib",
            "peak_rss_mib",
            "peak_scope",
            "run_dir",
            "message",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    columns
}

fn optional<T: ToString>(value: Option<T>) -> String {
    value.map(|v| v.to_string()).unwrap_or_default()
}

fn optional_error(value: Option<f64>) -> String {
    value.map(|v| format!("{v:e}")).unwrap_or_default()
}

/// A CSV field: quoted when it holds a comma or a quote; line breaks become ` | `.
fn field(text: &str) -> String {
    let flat = text.replace(['\r', '\n'], " | ");
    if flat.contains([',', '"']) {
        format!("\"{}\"", flat.replace('"', "\"\""))
    } else {
        flat
    }
}

fn status(record: &RunRecord) -> (&'static str, String) {
    match &record.outcome {
        RunOutcome::Completed => ("completed", String::new()),
        RunOutcome::Failed(message) => ("failed", message.clone()),
        RunOutcome::Stopped { status, message } => (status, message.clone()),
    }
}

/// `study.csv`: header `index,<swept names>,<csv_header()>`, one row per run.
pub fn csv(names: &[String], records: &[RunRecord]) -> String {
    let mut out = String::new();
    let mut header = vec!["index".to_string()];
    header.extend(names.iter().cloned());
    header.extend(csv_header());
    out += &header.join(",");
    out.push('\n');
    for r in records {
        let (status, message) = status(r);
        let mut row = vec![r.index.to_string()];
        row.extend(
            names
                .iter()
                .map(|n| field(r.parameter(n).unwrap_or_default())),
        );
        row.extend([
            status.to_string(),
            optional_error(r.error),
            optional_error(r.error_recovered),
            optional(r.points),
            optional(r.nodes),
            optional(r.dofs),
            r.steps.to_string(),
            r.iterations.to_string(),
            format!("{:.6}", r.wall_seconds),
        ]);
        row.extend(r.stage_seconds.iter().map(|t| format!("{t:.6}")));
        row.extend([
            optional(r.memory.baseline_mib.map(|m| format!("{m:.1}"))),
            optional(r.memory.peak_mib.map(|m| format!("{m:.1}"))),
            if r.memory.peak_is_per_run {
                "run".to_string()
            } else {
                "process".to_string()
            },
            r.run_dir.clone(),
            field(&message),
        ]);
        out += &row.join(",");
        out.push('\n');
    }
    out
}

/// Observed rates of one series of `(n, error)` pairs sorted by `n`: the rate between each pair
/// of neighbours and the least-squares rate over all (see the module docs). Pairs with a
/// non-positive or non-finite value are skipped.
pub fn convergence_rates(points: &[(f64, f64)]) -> (Vec<f64>, Option<f64>) {
    let valid: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|(n, e)| n.is_finite() && e.is_finite() && *n > 0.0 && *e > 0.0)
        .collect();
    let pairwise = valid
        .windows(2)
        .map(|w| -(w[1].1 / w[0].1).ln() / (w[1].0 / w[0].0).ln())
        .collect();
    if valid.len() < 2 {
        return (pairwise, None);
    }
    let m = valid.len() as f64;
    let (sx, sy) = valid
        .iter()
        .fold((0.0, 0.0), |(a, b), (n, e)| (a + n.ln(), b + e.ln()));
    let (mx, my) = (sx / m, sy / m);
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (n, e) in &valid {
        sxy += (n.ln() - mx) * (e.ln() - my);
        sxx += (n.ln() - mx).powi(2);
    }
    let slope = if sxx > 0.0 { Some(-sxy / sxx) } else { None };
    (pairwise, slope)
}

/// The series of the error chart: label, and `(x, error)` / `(x, recovered error)` pairs sorted
/// by x, for completed runs, grouped by the swept parameters other than `against`.
pub(crate) type SeriesPoints = (String, Vec<(f64, f64)>, Vec<(f64, f64)>);

pub(crate) fn series_by(records: &[RunRecord], against: &str) -> Vec<SeriesPoints> {
    let mut series: Vec<SeriesPoints> = Vec::new();
    for r in records {
        if r.outcome != RunOutcome::Completed {
            continue;
        }
        let Some(x) = r.parameter(against).and_then(|v| v.parse::<f64>().ok()) else {
            continue;
        };
        let label = r.label_without(against);
        let index = match series.iter().position(|s| s.0 == label) {
            Some(i) => i,
            None => {
                series.push((label, Vec::new(), Vec::new()));
                series.len() - 1
            }
        };
        if let Some(e) = r.error {
            series[index].1.push((x, e));
        }
        if let Some(e) = r.error_recovered {
            series[index].2.push((x, e));
        }
    }
    for s in &mut series {
        s.1.sort_by(|a, b| a.0.total_cmp(&b.0));
        s.2.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    series
}

fn rates_text(points: &[(f64, f64)]) -> (String, String) {
    let (pairwise, overall) = convergence_rates(points);
    let pairwise = pairwise
        .iter()
        .map(|r| format!("{r:.2}"))
        .collect::<Vec<_>>()
        .join(", ");
    (pairwise, optional(overall.map(|r| format!("{r:.2}"))))
}

/// `study.md`: what was run, the table, observed rates and the charts.
pub fn markdown(
    plan: &StudyPlan,
    names: &[String],
    records: &[RunRecord],
    against: Option<&str>,
    charts: &[(String, String)],
) -> String {
    let mut md = intro(plan, records);
    if !super::has_error_measure(records) {
        let _ = writeln!(md, "Note: {}.\n", super::NO_ERROR_MEASURE);
    } else {
        let _ = writeln!(
            md,
            "Error: the {} after the last load step.\n",
            super::error_measure_name(records)
        );
    }
    md.push_str(&runs_table(names, records));
    if let Some(against) = against {
        md.push_str(&rates_section(records, against));
    }
    for (title, stem) in charts {
        let _ = writeln!(md, "\n## {title}\n\n![{title}]({stem}.svg)");
    }
    md
}

/// The title, sweeps, fixed overrides and what the columns mean.
fn intro(plan: &StudyPlan, records: &[RunRecord]) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# Study of `{}`\n", plan.scene.display());
    let sweeps: Vec<String> = plan
        .sweeps
        .iter()
        .map(|s| {
            let values: Vec<String> = s.values.iter().map(|t| t.join(":")).collect();
            format!("`{}={}`", s.names.join(":"), values.join(","))
        })
        .collect();
    let _ = writeln!(md, "Sweeps: {}.", sweeps.join(", "));
    if !plan.fixed.is_empty() {
        let fixed: Vec<String> = plan
            .fixed
            .iter()
            .map(|(n, v)| format!("`{n}={v}`"))
            .collect();
        let _ = writeln!(md, "Fixed: {}.", fixed.join(", "));
    }
    let failed = records
        .iter()
        .filter(|r| r.outcome != RunOutcome::Completed)
        .count();
    let _ = writeln!(
        md,
        "{} runs, {} failed. Wall time: the whole run (scene, world, load steps, initial and final output). \
         Peak: resident memory of the study process during the run{}.\n",
        records.len(),
        failed,
        if records.iter().all(|r| r.memory.peak_is_per_run) {
            " (reset before each run; includes the baseline before it)"
        } else {
            " (NOT reset per run on this system: the process's peak so far)"
        }
    );
    md
}

/// One row per run: its parameters, outcome, errors, sizes and times.
fn runs_table(names: &[String], records: &[RunRecord]) -> String {
    let mut md = String::new();
    let stage = |wanted: Stage| Stage::ALL.iter().position(|s| *s == wanted).unwrap_or(0);
    let (assembly, solve) = (stage(Stage::Assembly), stage(Stage::LinearSolve));
    let mut header: Vec<String> = names.to_vec();
    header.extend(
        [
            "status",
            "error",
            "error (recovered)",
            "points",
            "DOFs",
            "Newton its",
            "wall s",
            "assembly s",
            "solve s",
            "peak MiB",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    let _ = writeln!(md, "| {} |", header.join(" | "));
    let _ = writeln!(md, "|{}", "---|".repeat(header.len()));
    for r in records {
        let mut row: Vec<String> = names
            .iter()
            .map(|n| r.parameter(n).unwrap_or_default().to_string())
            .collect();
        let status = match &r.outcome {
            RunOutcome::Completed => "ok".to_string(),
            RunOutcome::Failed(m) => {
                let first = m.lines().next().unwrap_or_default();
                format!("failed: {}", first.replace('|', "/"))
            }
            RunOutcome::Stopped { status, message } => format!("{status}: {message}"),
        };
        row.extend([
            status,
            optional(r.error.map(|e| format!("{e:.3e}"))),
            optional(r.error_recovered.map(|e| format!("{e:.3e}"))),
            optional(r.points),
            optional(r.dofs),
            r.iterations.to_string(),
            format!("{:.3}", r.wall_seconds),
            format!("{:.3}", r.stage_seconds[assembly]),
            format!("{:.3}", r.stage_seconds[solve]),
            optional(r.memory.peak_mib.map(|m| format!("{m:.0}"))),
        ]);
        let _ = writeln!(md, "| {} |", row.join(" | "));
    }
    md
}

/// The observed convergence rates of each series against the swept parameter `against`.
fn rates_section(records: &[RunRecord], against: &str) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "\n## Observed convergence rates against `{against}`\n\n\
         Rate between neighbouring runs `−ln(e₂/e₁)/ln({against}₂/{against}₁)`, and the \
         least-squares rate over the series.\n"
    );
    let _ = writeln!(
        md,
        "| series | stress | rates between neighbours | least-squares rate |"
    );
    let _ = writeln!(md, "|---|---|---|---|");
    for (label, raw, recovered) in series_by(records, against) {
        let label = if label.is_empty() { "all" } else { &label };
        for (kind, points) in [("raw", &raw), ("recovered", &recovered)] {
            if points.is_empty() {
                continue;
            }
            let (pairwise, overall) = rates_text(points);
            let _ = writeln!(md, "| {label} | {kind} | {pairwise} | {overall} |");
        }
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_of_a_power_law_are_its_exponent() {
        let points: Vec<(f64, f64)> = [5.0, 10.0, 20.0, 40.0]
            .iter()
            .map(|&n: &f64| (n, 3.0 * n.powf(-1.5)))
            .collect();
        let (pairwise, overall) = convergence_rates(&points);
        assert_eq!(pairwise.len(), 3);
        for r in pairwise {
            assert!((r - 1.5).abs() < 1e-12, "{r}");
        }
        assert!((overall.unwrap() - 1.5).abs() < 1e-12);
    }

    #[test]
    fn rates_skip_invalid_points_and_need_two() {
        let (pairwise, overall) = convergence_rates(&[(10.0, 1e-3)]);
        assert!(pairwise.is_empty() && overall.is_none());
        let (pairwise, overall) = convergence_rates(&[(10.0, 1e-3), (20.0, 0.0), (40.0, 2.5e-4)]);
        assert_eq!(pairwise.len(), 1);
        assert!((pairwise[0] - 1.0).abs() < 1e-12);
        assert!((overall.unwrap() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn csv_fields_with_commas_quotes_and_lines_are_quoted_flat() {
        assert_eq!(field("plain"), "plain");
        assert_eq!(field("a,b"), "\"a,b\"");
        assert_eq!(field("say \"x\""), "\"say \"\"x\"\"\"");
        assert_eq!(field("one\ntwo"), "one | two");
    }
}
