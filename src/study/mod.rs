//! # Studies: what accuracy costs
//!
//! `impm study SCENE --sweep NAME=V1,V2,.. [--sweep ..] [--set NAME=VALUE ..] [--out DIR]` runs
//! a scene over the cross product of the sweep values and records, for every run, the
//! parameters, the eq. 15 error (and the error of the recovered stress, where the scene asks
//! for recovery), points, nodes and DOFs, Newton iterations, wall time and time per stage, peak
//! memory and status. A sweep is over scene parameters only (top-level `let`s), so a study works
//! with any method a scene can name, today and later.
//!
//! A sweep can also move several parameters together: `--sweep basis:order:ppc=bspline:3:4,linear:1:1`
//! gives two runs per value of the other sweeps (a "zipped" sweep, for methods whose parameters
//! do not combine freely).
//!
//! ## What is written (`DIR`, default `out/study-<scene>/`)
//!
//! | file | contents |
//! |---|---|
//! | `study.csv` | one row per run (columns: [`csv_header`]) |
//! | `study.md` | the same as a markdown table, the observed convergence rates, the charts |
//! | `error_vs_<x>.svg/.png` | eq. 15 error against the sweep parameter `x` (default `cells`), log-log, one series per combination of the other swept parameters (recovered stress dashed) |
//! | `error_vs_time.svg/.png` | eq. 15 error against wall time: the accuracy-cost front |
//! | `profiles.csv`, `profiles.svg/.png`, `profile_errors.svg/.png` | with `--profiles`: the final stress of every point along the column axis against the analytic solution, and the pointwise error |
//! | `runs/NNN/` | each run's own output (`summary.json`, initial and final `.vtu`) |
//!
//! ## The error measure
//!
//! The error of a run is, in this order:
//! * with `--reference NAME=VALUE`, or when the scene declares `reference(#{ quantity, value })`
//!   (the command line wins): the relative error |q − value| / |value| of the recorded quantity
//!   q (a history column: a probe's `tip_displacement_y`, a `record`'s name, a reaction...)
//!   after the last step; the charts say which quantity;
//! * else, when the scene declares an analytic solution (`analytic_column(...)`): eq. 15.
//!
//! The error charts and rates need an error measure: a scene with neither gets none, and
//! `study.md` and the console say so ([`NO_ERROR_MEASURE`]) instead of drawing empty charts.
//!
//! ## How runs are executed and measured
//!
//! Runs execute one after the other **in this process**, through the library (no subprocess):
//! a failed run (a scene error for one value, a Newton failure) is recorded with its message and
//! the study goes on. Each run writes only its initial and final state (`output every` is set
//! to the number of load steps), so that file output does not dominate the timings.
//! * `wall_seconds`: the whole run as a user waits for it — scene evaluation, building the world,
//!   the load steps and the output of the run.
//! * `t_<stage>`: seconds per stage summed over the load steps (from `summary.json`).
//! * Memory (`study::memory`): the peak resident size of the process during the run (`VmHWM`, reset
//!   before each run), which includes the baseline resident size before the run (also
//!   recorded). Where the reset is not available, the column holds the process's lifetime peak
//!   and `study.md` says so.

mod history_plot;
pub mod memory;
mod plot;
mod profile;
mod table;

pub use history_plot::{plot_history, read_history};
pub use memory::MemoryUse;
pub use plot::{Series, chart};
pub use profile::{ProfilePoint, read_profile};
pub use table::{convergence_rates, csv_header};

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::effects::history::ReferenceSpec;
use crate::interrupt::{StopReason, set_deadline, stop_reason};
use crate::resources::Stage;
use crate::run::{RunError, run_scene_keeping_summary};
use crate::scene::{AnalyticSpec, scene_parameters};

/// One `--sweep`: parameter names moved together and their value tuples.
#[derive(Clone, Debug, PartialEq)]
pub struct Sweep {
    pub names: Vec<String>,
    /// One tuple per run, each with `names.len()` values.
    pub values: Vec<Vec<String>>,
}

impl Sweep {
    /// Parses `NAME=V1,V2,...` or `A:B=a1:b1,a2:b2,...`.
    pub fn parse(text: &str) -> Result<Self, String> {
        let (names, values) = text
            .split_once('=')
            .ok_or_else(|| format!("--sweep expects NAME=V1,V2,... got '{text}'"))?;
        let names: Vec<String> = names.split(':').map(|n| n.trim().to_string()).collect();
        if names.iter().any(|n| n.is_empty()) {
            return Err(format!("--sweep '{text}': empty parameter name"));
        }
        let values: Vec<Vec<String>> = values
            .split(',')
            .map(|tuple| tuple.split(':').map(|v| v.trim().to_string()).collect())
            .collect();
        for tuple in &values {
            if tuple.len() != names.len() || tuple.iter().any(|v| v.is_empty()) {
                return Err(format!(
                    "--sweep '{text}': every value must give {} non-empty part(s) separated by ':' like the names",
                    names.len()
                ));
            }
        }
        Ok(Self { names, values })
    }
}

/// What a study runs.
#[derive(Clone, Debug)]
pub struct StudyPlan {
    pub scene: PathBuf,
    pub sweeps: Vec<Sweep>,
    /// Fixed overrides for every run (`--set`).
    pub fixed: Vec<(String, String)>,
    pub out_dir: PathBuf,
    /// The sweep parameter of the error plot's x axis (default `cells`).
    pub against: String,
    /// Also read, write and plot the final stress profile of every run.
    pub profiles: bool,
    /// The longest a run may take (`--timeout`): it then stops at the end of its load step
    /// and is recorded as "timed out".
    pub timeout: Option<std::time::Duration>,
    /// The scene limits of every run (`--limit`).
    pub limits: crate::scene::SceneLimits,
    /// The error measure's reference value (`--reference NAME=VALUE`), replacing the scene's.
    pub reference: Option<ReferenceSpec>,
}

/// Parses `--reference NAME=VALUE`.
pub fn parse_reference(text: &str) -> Result<ReferenceSpec, String> {
    let (name, value) = text
        .split_once('=')
        .ok_or_else(|| format!("--reference expects NAME=VALUE, got '{text}'"))?;
    let value: f64 = value
        .trim()
        .parse()
        .ok()
        .filter(|v: &f64| v.is_finite())
        .ok_or_else(|| {
            format!(
                "--reference '{text}': '{}' is not a finite number",
                value.trim()
            )
        })?;
    let name = name.trim();
    if name.is_empty() {
        return Err(format!("--reference '{text}': empty quantity name"));
    }
    Ok(ReferenceSpec {
        quantity: name.to_string(),
        value,
        line: None,
    })
}

/// A run's result.
#[derive(Clone, Debug, PartialEq)]
pub enum RunOutcome {
    Completed,
    Failed(String),
    /// Stopped before its end: `status` is "interrupted" (a signal) or "timed out"
    /// (`--timeout`); the message says after which step.
    Stopped {
        status: &'static str,
        message: String,
    },
}

/// One row of the study.
#[derive(Clone, Debug)]
pub struct RunRecord {
    /// 0-based run number (the `runs/NNN` folder).
    pub index: usize,
    /// The swept parameters of this run, in sweep order.
    pub parameters: Vec<(String, String)>,
    pub outcome: RunOutcome,
    /// The error measure after the last step: eq. 15, or the relative error of `error_of`.
    pub error: Option<f64>,
    /// The recorded quantity whose relative error `error` is (`None`: eq. 15).
    pub error_of: Option<String>,
    pub error_recovered: Option<f64>,
    pub points: Option<usize>,
    pub nodes: Option<usize>,
    /// Free DOFs of the last load step.
    pub dofs: Option<usize>,
    pub steps: usize,
    pub iterations: usize,
    pub wall_seconds: f64,
    /// Seconds per stage ([`Stage::ALL`] order), summed over the load steps.
    pub stage_seconds: [f64; Stage::ALL.len()],
    pub memory: MemoryUse,
    /// `runs/NNN`, relative to the study folder.
    pub run_dir: String,
    /// The final stress profile (with `--profiles`).
    pub profile: Vec<ProfilePoint>,
}

impl RunRecord {
    /// `name=value` of the swept parameters except `skip`, space separated (a series label).
    pub fn label_without(&self, skip: &str) -> String {
        self.parameters
            .iter()
            .filter(|(n, _)| n != skip)
            .map(|(n, v)| format!("{n}={v}"))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// The value of a swept parameter.
    pub fn parameter(&self, name: &str) -> Option<&str> {
        self.parameters
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }
}

/// What the caller hears while a study runs.
pub enum StudyEvent<'a> {
    Started {
        index: usize,
        total: usize,
        label: &'a str,
    },
    Finished {
        index: usize,
        total: usize,
        record: &'a RunRecord,
    },
}

/// The cross product of the sweeps, first sweep outermost: each run's `(name, value)` list.
pub fn cross_product(sweeps: &[Sweep]) -> Vec<Vec<(String, String)>> {
    let mut runs: Vec<Vec<(String, String)>> = vec![Vec::new()];
    for sweep in sweeps {
        let mut next = Vec::with_capacity(runs.len() * sweep.values.len());
        for run in &runs {
            for tuple in &sweep.values {
                let mut extended = run.clone();
                extended.extend(sweep.names.iter().cloned().zip(tuple.iter().cloned()));
                next.push(extended);
            }
        }
        runs = next;
    }
    runs
}

/// Checks the plan against the scene's parameters before running anything: every name is a
/// parameter, given once (in `--sweep` or `--set`, the rule of `run` and `check`), and a
/// parameter whose default is a number is swept over numbers only (a word among them would
/// fail its run and take the error chart and the rates of every run with it).
fn validate(plan: &StudyPlan) -> Result<(), String> {
    if plan.sweeps.is_empty() {
        return Err("a study needs at least one --sweep NAME=V1,V2,...".into());
    }
    let known = scene_parameters(&plan.scene).map_err(|e| e.to_string())?;
    let mut seen: Vec<(&str, String)> = Vec::new();
    let swept = plan.sweeps.iter().flat_map(|sweep| {
        sweep.names.iter().enumerate().map(move |(k, name)| {
            let values: Vec<&str> = sweep.values.iter().map(|tuple| tuple[k].as_str()).collect();
            (name, values)
        })
    });
    let fixed = plan
        .fixed
        .iter()
        .map(|(name, value)| (name, vec![value.as_str()]));
    for (name, values) in swept.chain(fixed) {
        let Some(parameter) = known.iter().find(|p| &p.name == name) else {
            let names: Vec<&str> = known.iter().map(|p| p.name.as_str()).collect();
            return Err(format!(
                "{}: there is no parameter '{name}'; the scene's parameters are: {}",
                plan.scene.display(),
                names.join(", ")
            ));
        };
        let given = values.join(",");
        if let Some((_, first)) = seen.iter().find(|(other, _)| *other == name.as_str()) {
            return Err(format!(
                "parameter '{name}' is given twice ({first} and {given}, in --sweep or --set): give each parameter once"
            ));
        }
        if is_number(&parameter.default)
            && let Some(word) = values.iter().find(|value| !is_number(value))
        {
            return Err(format!(
                "parameter '{name}' = '{word}' is not a number, but the scene's {name} is one (line {}: let {name} = {}); give numbers only",
                parameter.line, parameter.default
            ));
        }
        seen.push((name, given));
    }
    Ok(())
}

/// A number as the scene language reads it (`10`, `-800.0`, `1e6`, `1_000`), finite.
fn is_number(text: &str) -> bool {
    let digits = text.trim().replace('_', "");
    let unsigned = digits.trim_start_matches(['-', '+']);
    unsigned.starts_with(|c: char| c.is_ascii_digit() || c == '.')
        && digits.parse::<f64>().is_ok_and(f64::is_finite)
}

/// What the study leaves out because a swept parameter took a value that is not a number in
/// some run (possible when its default is an expression): one note per such parameter, for
/// `study.md` and the end of `impm study`.
pub fn non_numeric_notes(plan: &StudyPlan, records: &[RunRecord]) -> Vec<String> {
    plan.sweeps
        .iter()
        .flat_map(|sweep| sweep.names.iter())
        .filter_map(|name| {
            let values: Vec<&str> = records.iter().filter_map(|r| r.parameter(name)).collect();
            let word = values.iter().find(|value| !is_number(value))?;
            values.iter().any(|value| is_number(value)).then(|| {
                format!(
                    "parameter '{name}' took the value '{word}', which is not a number: no error chart and no convergence rates are drawn against {name}"
                )
            })
        })
        .collect()
}

/// Runs one parameter combination into `dir`.
fn run_one(plan: &StudyPlan, index: usize, parameters: Vec<(String, String)>) -> RunRecord {
    let run_dir = format!("runs/{index:03}");
    let dir = plan.out_dir.join(&run_dir);
    let _ = std::fs::remove_dir_all(&dir);
    let mut overrides = plan.fixed.clone();
    overrides.extend(parameters.iter().cloned());
    let mut record = RunRecord {
        index,
        parameters,
        outcome: RunOutcome::Completed,
        error: None,
        error_of: None,
        error_recovered: None,
        points: None,
        nodes: None,
        dofs: None,
        steps: 0,
        iterations: 0,
        wall_seconds: 0.0,
        stage_seconds: [0.0; Stage::ALL.len()],
        memory: MemoryUse::default(),
        run_dir,
        profile: Vec::new(),
    };
    let memory = memory::begin_run();
    let start = Instant::now();
    let spec =
        match crate::effects::built_in().load_scene_within(&plan.scene, &overrides, &plan.limits) {
            Ok(mut spec) => {
                spec.output.every = spec.load_factors.len().max(1);
                if let Some(reference) = &plan.reference {
                    spec.set_part(reference.clone());
                }
                spec
            }
            Err(e) => {
                record.outcome = RunOutcome::Failed(e.to_string());
                record.wall_seconds = start.elapsed().as_secs_f64();
                record.memory = memory::end_run(memory);
                return record;
            }
        };
    set_deadline(plan.timeout.map(|limit| start + limit));
    let (summary, result) = run_scene_keeping_summary(&spec, &dir, |_| {});
    set_deadline(None);
    record.wall_seconds = start.elapsed().as_secs_f64();
    record.memory = memory::end_run(memory);
    match result {
        Ok(()) => {}
        Err(RunError::Stopped { reason, steps_done }) => {
            record.outcome = RunOutcome::Stopped {
                status: reason.status(),
                message: format!(
                    "after load step {steps_done} of {} ({:.1} s)",
                    spec.load_factors.len(),
                    record.wall_seconds
                ),
            };
        }
        Err(e) => record.outcome = RunOutcome::Failed(e.to_string()),
    }
    if let Some(summary) = summary {
        record.points = Some(summary.points);
        record.nodes = Some(summary.nodes);
        record.dofs = summary.steps.last().map(|s| s.dofs);
        record.steps = summary.steps.len();
        record.iterations = summary.total_iterations();
        let (clock, _) = summary.total_seconds();
        for (k, stage) in Stage::ALL.iter().enumerate() {
            record.stage_seconds[k] = clock.get(*stage).as_secs_f64();
        }
        if record.outcome == RunOutcome::Completed {
            match spec.part::<ReferenceSpec>() {
                Some(reference) => {
                    record.error = summary.final_measure(&reference.error_name());
                    record.error_of = Some(reference.quantity.clone());
                }
                None => record.error = summary.final_error(),
            }
            record.error_recovered = summary.final_measure("error_recovered");
        }
    }
    if plan.profiles && record.outcome == RunOutcome::Completed {
        let axis = match &spec.analytic {
            Some(AnalyticSpec::Column { axis, .. }) => *axis,
            None => spec.dim() - 1,
        };
        let last = spec.load_factors.len();
        let file = dir.join(crate::output::step_file_name("particles", last));
        match read_profile(
            &file,
            axis,
            spec.analytic.as_ref(),
            spec.load_factors[last - 1],
        ) {
            Ok(profile) => record.profile = profile,
            Err(e) => {
                record.outcome = RunOutcome::Failed(format!("reading the profile: {e}"));
            }
        }
    }
    record
}

/// Runs the study and writes its files; `on_event` hears each run start and finish. The
/// files are rewritten after every run (atomically), so a study stopped by a signal keeps every
/// run done so far; it stops after the run in flight (which is recorded as interrupted).
pub fn run_study(
    plan: &StudyPlan,
    mut on_event: impl FnMut(StudyEvent),
) -> Result<Vec<RunRecord>, String> {
    validate(plan)?;
    std::fs::create_dir_all(&plan.out_dir)
        .map_err(|e| format!("cannot create {}: {e}", plan.out_dir.display()))?;
    let combinations = cross_product(&plan.sweeps);
    let total = combinations.len();
    let mut records = Vec::with_capacity(total);
    for (index, parameters) in combinations.into_iter().enumerate() {
        if stop_reason() == Some(StopReason::Interrupted) {
            break;
        }
        let label = parameters
            .iter()
            .map(|(n, v)| format!("{n}={v}"))
            .collect::<Vec<_>>()
            .join(" ");
        on_event(StudyEvent::Started {
            index,
            total,
            label: &label,
        });
        let record = run_one(plan, index, parameters);
        on_event(StudyEvent::Finished {
            index,
            total,
            record: &record,
        });
        records.push(record);
        write_study_files(plan, &records)?;
    }
    Ok(records)
}

/// `study.csv`, `study.md` and the charts of the runs done so far.
fn write_study_files(plan: &StudyPlan, records: &[RunRecord]) -> Result<(), String> {
    let names: Vec<String> = plan
        .sweeps
        .iter()
        .flat_map(|s| s.names.iter().cloned())
        .collect();
    let write = |name: &str, text: String| -> Result<(), String> {
        let path = plan.out_dir.join(name);
        crate::output::write_atomic(&path, text.as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))
    };
    write("study.csv", table::csv(&names, records))?;
    let measured = has_error_measure(records);
    let against = plot_axis(plan, records).filter(|_| measured);
    let mut charts = Vec::new();
    let measure = error_measure_name(records);
    if let Some(against) = &against {
        let stem = format!("error_vs_{against}");
        plot::error_against_parameter(records, against, &measure, &plan.out_dir.join(&stem))?;
        charts.push((format!("{} against {against}", capitalised(&measure)), stem));
    }
    if measured {
        plot::error_against_time(
            records,
            against.as_deref(),
            &measure,
            &plan.out_dir.join("error_vs_time"),
        )?;
        charts.push((
            format!("Accuracy-cost front: {measure} against wall time"),
            "error_vs_time".to_string(),
        ));
    }
    if plan.profiles {
        write("profiles.csv", profile::csv(&names, records))?;
        profile::charts(records, &plan.out_dir)?;
        charts.push(("Stress along the column".into(), "profiles".into()));
        charts.push((
            "Pointwise stress error along the column".into(),
            "profile_errors".into(),
        ));
    }
    let mut markdown = table::markdown(plan, &names, records, against.as_deref(), &charts);
    for note in non_numeric_notes(plan, records) {
        markdown.push_str(&format!("\nNote: {note}.\n"));
    }
    write("study.md", markdown)
}

/// What a study says when no run reports an error (the error charts would be empty).
pub const NO_ERROR_MEASURE: &str = "no run reports an error: the scene declares no analytic \
    solution (analytic_column(...)) and no reference value of a recorded quantity \
    (reference(#{ quantity, value }) in the scene or --reference NAME=VALUE), so the study \
    tabulates times and iterations only, without error charts or convergence rates";

/// Whether any run reports an error measure (eq. 15, or a quantity against its reference).
pub fn has_error_measure(records: &[RunRecord]) -> bool {
    records.iter().any(|r| r.error.is_some())
}

/// What the runs' error is, for chart titles and axes: "relative error of NAME" or "eq. 15
/// error".
pub fn error_measure_name(records: &[RunRecord]) -> String {
    match records.iter().find_map(|r| r.error_of.as_deref()) {
        Some(quantity) => format!("relative error of {quantity}"),
        None => "eq. 15 error".to_string(),
    }
}

fn capitalised(text: &str) -> String {
    let mut chars = text.chars();
    chars
        .next()
        .map(|c| c.to_uppercase().chain(chars).collect())
        .unwrap_or_default()
}

/// The x parameter of the error plot: `plan.against` if swept and numeric, else the first
/// numeric swept parameter; `None` if no swept parameter is numeric.
fn plot_axis(plan: &StudyPlan, records: &[RunRecord]) -> Option<String> {
    let numeric = |name: &str| {
        records
            .iter()
            .all(|r| r.parameter(name).is_some_and(|v| v.parse::<f64>().is_ok()))
    };
    let names: Vec<&String> = plan.sweeps.iter().flat_map(|s| s.names.iter()).collect();
    if names.iter().any(|n| **n == plan.against) && numeric(&plan.against) {
        return Some(plan.against.clone());
    }
    names.into_iter().find(|n| numeric(n)).cloned()
}

/// `DIR` default: `out/study-<scene stem>/`.
pub fn default_study_dir(scene: &Path) -> PathBuf {
    let stem = scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    Path::new("out").join(format!("study-{stem}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweeps_parse_single_and_zipped() {
        let s = Sweep::parse("cells=5,10, 20").unwrap();
        assert_eq!(s.names, ["cells"]);
        assert_eq!(s.values, [["5"], ["10"], ["20"]]);
        let z = Sweep::parse("basis:order=bspline:3,linear:1").unwrap();
        assert_eq!(z.names, ["basis", "order"]);
        assert_eq!(z.values, [["bspline", "3"], ["linear", "1"]]);
        assert!(Sweep::parse("cells").is_err());
        assert!(Sweep::parse("a:b=1:2,3").is_err());
        assert!(Sweep::parse("=1,2").is_err());
        assert!(Sweep::parse("cells=5,,10").is_err());
    }

    #[test]
    fn the_cross_product_has_every_combination_first_sweep_outermost() {
        let sweeps = [
            Sweep::parse("basis:order=bspline:3,linear:1").unwrap(),
            Sweep::parse("cells=5,10,20").unwrap(),
        ];
        let runs = cross_product(&sweeps);
        assert_eq!(runs.len(), 6);
        let pair = |k: usize| (runs[k][0].1.clone(), runs[k][2].1.clone());
        assert_eq!(pair(0), ("bspline".into(), "5".into()));
        assert_eq!(pair(2), ("bspline".into(), "20".into()));
        assert_eq!(pair(3), ("linear".into(), "5".into()));
        assert_eq!(runs[4][1], ("order".into(), "1".into()));
        for run in &runs {
            assert_eq!(run.len(), 3);
        }
    }
}
