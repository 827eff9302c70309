//! The run's records (bookkeeping beside the method): per load step the load factor, Newton
//! iterations and residual history, the attempts of a cut step, seconds per stage and, when the
//! scene declares an analytic solution, the paper's error (eq. 15), plus the measures modules
//! add ([`StepMeasures`], e.g. `error_recovered`); then totals. Written as `summary.json`,
//! atomically after every step, so it is valid at any time.

use std::path::{Path, PathBuf};

use bevy_ecs::prelude::*;
use serde_json::{Map, Value, json};

use crate::control::Attempt;
use crate::resources::{Stage, StageClock};
use crate::scene::SceneSpec;
use crate::solver::Hierarchy;

/// A quantity a module measures after every converged step, from the world and the load
/// factor (`None` when it does not apply).
pub type Measure = Box<dyn Fn(&mut World, f64) -> Option<f64> + Send + Sync>;

/// The measures of the run, by name; each becomes a key of the step's record.
#[derive(Resource, Default)]
pub struct StepMeasures(pub Vec<(String, Measure)>);

/// The values of the step's measures computed so far, in order: a measure may read the ones
/// added before it (e.g. `record(...)` rescales a reaction into a named column).
#[derive(Resource, Default, Debug)]
pub struct MeasuredValues(pub Vec<(String, f64)>);

impl MeasuredValues {
    pub fn get(&self, name: &str) -> Option<f64> {
        self.0.iter().find(|(n, _)| *n == name).map(|(_, v)| *v)
    }
}

/// What one load step did.
#[derive(Clone, Debug)]
pub struct StepRecord {
    pub step: usize,
    pub load_factor: f64,
    /// The stage of the step (index and name) in a scene with stages (`scene::Stages`); the
    /// load factor is then the stage's own.
    pub stage: Option<(usize, String)>,
    /// Linear solves (Newton iterations).
    pub iterations: usize,
    /// Normalised out-of-balance force of each iterate.
    pub residuals: Vec<f64>,
    /// Krylov iterations of each linear solve (empty for the direct backend).
    pub linear_iterations: Vec<usize>,
    /// The multigrid preconditioner's levels at the step's last linear solve, if it has one.
    pub multigrid: Option<Hierarchy>,
    /// The backend `linear: "auto"` used for the step's last linear solve, and why
    /// (`LinearSolver::choice`; `None` for a backend the scene named).
    pub linear_backend: Option<String>,
    pub converged: bool,
    pub dofs: usize,
    pub seconds: StageClock,
    pub wall_seconds: f64,
    /// Eq. 15 error after the step, if the scene has an analytic solution.
    pub error: Option<f64>,
    /// The modules' measures after the step (see [`StepMeasures`]).
    pub measures: Vec<(String, f64)>,
    /// How many times the step was cut (halved) after a failed Newton solve.
    pub cuts: usize,
    /// Every attempt in order, failed ones included (one entry when the step was not cut).
    pub substeps: Vec<SubstepRecord>,
    /// What the line search did over the step's attempts (zero without one).
    pub line_search: LineSearchCounts,
}

/// The line search's work in a load step (`stages::line_search`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineSearchCounts {
    /// Newton iterations whose step was shortened.
    pub shortened: usize,
    /// Trial steps rejected (each an evaluation without a linear solve).
    pub rejected: usize,
}

impl StepRecord {
    /// The record of load step `step` towards load factor `load_factor`, before any attempt.
    pub fn new(step: usize, load_factor: f64) -> Self {
        Self {
            step,
            load_factor,
            stage: None,
            iterations: 0,
            residuals: Vec::new(),
            linear_iterations: Vec::new(),
            multigrid: None,
            linear_backend: None,
            converged: false,
            dofs: 0,
            seconds: StageClock::default(),
            wall_seconds: 0.0,
            error: None,
            measures: Vec::new(),
            cuts: 0,
            substeps: Vec::new(),
            line_search: LineSearchCounts::default(),
        }
    }

    /// A measure by name.
    pub fn measure(&self, name: &str) -> Option<f64> {
        self.measures
            .iter()
            .find(|(key, _)| *key == name)
            .map(|(_, value)| *value)
    }

    /// Adds an attempt (a Newton solve from `from` to `to`) with its outcome: its Newton
    /// iterations, residual history and Krylov iterations per linear solve.
    pub fn add_attempt(
        &mut self,
        attempt: &Attempt,
        iterations: usize,
        residuals: &[f64],
        linear_iterations: &[usize],
        failure: Option<String>,
    ) {
        self.iterations += iterations;
        self.residuals = residuals.to_vec();
        self.linear_iterations = linear_iterations.to_vec();
        self.converged = failure.is_none();
        self.substeps.push(SubstepRecord {
            from: attempt.from,
            to: attempt.to,
            iterations,
            residuals: residuals.to_vec(),
            linear_iterations: linear_iterations.to_vec(),
            converged: failure.is_none(),
            failure,
        });
    }
}

/// One Newton solve from load factor `from` to `to` within a load step.
#[derive(Clone, Debug)]
pub struct SubstepRecord {
    pub from: f64,
    pub to: f64,
    pub iterations: usize,
    pub residuals: Vec<f64>,
    pub linear_iterations: Vec<usize>,
    pub converged: bool,
    /// Why the attempt failed, if it did.
    pub failure: Option<String>,
}

/// The run's summary.
#[derive(Clone, Debug)]
pub struct Summary {
    pub path: PathBuf,
    pub scene: String,
    pub dimension: usize,
    pub basis: String,
    pub points: usize,
    pub nodes: usize,
    pub planned_steps: usize,
    pub steps: Vec<StepRecord>,
    /// "running", "completed", "failed", "interrupted" or "timed out".
    pub status: &'static str,
    pub failure: Option<String>,
    pub failed_step: Option<StepRecord>,
    /// What the scene cannot do right (`scene::scene_warnings`, printed when the run starts: too
    /// few points for the basis across a direction, volumetric locking) and what the modules
    /// warned about during the run (e.g. a condition the material no longer follows).
    pub warnings: Vec<String>,
    /// The command that continues this run from its last checkpoint (`impm run .. --resume`),
    /// written as `"resume"` while the run is not completed, when it keeps checkpoints.
    pub resume: Option<String>,
    /// The threads the stages ran on (`parallel::thread_count` when the run was built).
    pub threads: usize,
    /// Under arc-length control: the peak load factor, whether the run passed it, why it
    /// ended (`stages::arc_length::ArcLengthControl::to_json`); after a failure too, with
    /// `"end": "failed"` and the failure (`run::failed_arc_length`).
    pub arc_length: Option<Value>,
}

/// A JSON number, or null where not finite (JSON has no NaN).
fn number(x: f64) -> Value {
    serde_json::Number::from_f64(x).map_or(Value::Null, Value::Number)
}

fn stage_seconds(clock: &StageClock) -> Value {
    let mut map = Map::new();
    for stage in Stage::ALL {
        map.insert(stage.name().into(), number(clock.get(stage).as_secs_f64()));
    }
    Value::Object(map)
}

fn step_json(r: &StepRecord) -> Value {
    let mut v = json!({
        "step": r.step,
        "load_factor": number(r.load_factor),
        "iterations": r.iterations,
        "residuals": r.residuals.iter().map(|&x| number(x)).collect::<Vec<_>>(),
        "converged": r.converged,
        "dofs": r.dofs,
        "seconds": stage_seconds(&r.seconds),
        "wall_seconds": number(r.wall_seconds),
    });
    if let Some((index, name)) = &r.stage {
        v["stage"] = json!(index);
        v["stage_name"] = json!(name);
    }
    if !r.linear_iterations.is_empty() {
        v["linear_iterations"] = json!(r.linear_iterations);
    }
    if let Some(h) = &r.multigrid {
        v["multigrid"] = json!({
            "rows": h.rows,
            "nonzeros": h.nonzeros,
            "grid_complexity": number(h.grid_complexity()),
            "operator_complexity": number(h.operator_complexity()),
        });
    }
    if let Some(choice) = &r.linear_backend {
        v["linear_backend"] = json!(choice);
    }
    if let Some(e) = r.error {
        v["error"] = number(e);
    }
    for (name, value) in &r.measures {
        v[name.as_str()] = number(*value);
    }
    v["cuts"] = json!(r.cuts);
    if r.line_search.rejected > 0 {
        v["line_search"] = json!({
            "shortened": r.line_search.shortened,
            "rejected": r.line_search.rejected,
        });
    }
    if r.substeps.len() > 1 {
        v["substeps"] = Value::Array(
            r.substeps
                .iter()
                .map(|a| {
                    let mut sub = json!({
                        "from": number(a.from),
                        "to": number(a.to),
                        "iterations": a.iterations,
                        "residuals": a.residuals.iter().map(|&x| number(x)).collect::<Vec<_>>(),
                        "converged": a.converged,
                    });
                    if !a.linear_iterations.is_empty() {
                        sub["linear_iterations"] = json!(a.linear_iterations);
                    }
                    if let Some(f) = &a.failure {
                        sub["failure"] = Value::String(f.clone());
                    }
                    sub
                })
                .collect(),
        );
    }
    v
}

impl Summary {
    pub fn new(spec: &SceneSpec, points: usize, nodes: usize, out_dir: &Path) -> Self {
        Self {
            path: out_dir.join("summary.json"),
            scene: spec.name.clone(),
            dimension: spec.dim(),
            basis: spec.grid.basis.to_string(),
            points,
            nodes,
            planned_steps: spec.load_factors.len(),
            steps: Vec::new(),
            status: "running",
            failure: None,
            failed_step: None,
            warnings: crate::scene::scene_warnings(spec),
            resume: None,
            threads: crate::parallel::thread_count(),
            arc_length: None,
        }
    }

    pub fn push(&mut self, record: StepRecord) {
        self.steps.push(record);
    }

    pub fn fail(&mut self, record: StepRecord, error: &dyn std::fmt::Display) {
        self.status = "failed";
        self.failure = Some(error.to_string());
        self.failed_step = Some(record);
    }

    /// Marks the run as stopped before its end (`"interrupted"`, `"timed out"`).
    pub fn stop(&mut self, status: &'static str) {
        self.status = status;
    }

    pub fn finish(&mut self) {
        if self.status == "running" {
            self.status = "completed";
        }
    }

    /// The eq. 15 error after the last completed step.
    pub fn final_error(&self) -> Option<f64> {
        self.steps.last().and_then(|s| s.error)
    }

    /// A measure (e.g. `error_recovered`) after the last completed step.
    pub fn final_measure(&self, name: &str) -> Option<f64> {
        self.steps.last().and_then(|s| s.measure(name))
    }

    /// Total Newton iterations.
    pub fn total_iterations(&self) -> usize {
        self.steps.iter().map(|s| s.iterations).sum()
    }

    /// Total seconds per stage and wall time over the completed steps.
    pub fn total_seconds(&self) -> (StageClock, f64) {
        let mut total = StageClock::default();
        for s in &self.steps {
            for (t, d) in total.seconds.iter_mut().zip(s.seconds.seconds.iter()) {
                *t += *d;
            }
        }
        (total, self.steps.iter().map(|s| s.wall_seconds).sum())
    }

    pub fn to_json(&self) -> Value {
        let (stages, wall) = self.total_seconds();
        let mut v = json!({
            "scene": self.scene,
            "dimension": self.dimension,
            "basis": self.basis,
            "points": self.points,
            "nodes": self.nodes,
            "planned_steps": self.planned_steps,
            "threads": self.threads,
            "status": self.status,
            "steps": self.steps.iter().map(step_json).collect::<Vec<_>>(),
            "totals": {
                "steps": self.steps.len(),
                "iterations": self.total_iterations(),
                "cuts": self.steps.iter().map(|s| s.cuts).sum::<usize>(),
                "line_search_steps": self.steps.iter().filter(|s| s.line_search.rejected > 0).count(),
                "line_search_shortened": self.steps.iter().map(|s| s.line_search.shortened).sum::<usize>(),
                "seconds": stage_seconds(&stages),
                "wall_seconds": number(wall),
            },
        });
        if let Some(e) = self.final_error() {
            v["error"] = number(e);
        }
        if let Some(last) = self.steps.last() {
            for (name, value) in &last.measures {
                v[name.as_str()] = number(*value);
            }
        }
        if let Some(f) = &self.failure {
            v["failure"] = Value::String(f.clone());
        }
        if let Some(r) = &self.failed_step {
            v["failed_step"] = step_json(r);
        }
        if !self.warnings.is_empty() {
            v["warnings"] = json!(self.warnings);
        }
        if let Some(arc) = &self.arc_length {
            v["arc_length"] = arc.clone();
        }
        if let Some(command) = self.resume.as_ref().filter(|_| self.status != "completed") {
            v["resume"] = Value::String(command.clone());
        }
        v
    }

    /// The completed steps' records as in `summary.json` (what a checkpoint keeps).
    pub fn steps_json(&self) -> Vec<Value> {
        self.steps.iter().map(step_json).collect()
    }

    /// Writes `summary.json` atomically.
    pub fn write(&self) -> Result<(), String> {
        let text = serde_json::to_string_pretty(&self.to_json()).map_err(|e| e.to_string())?;
        crate::output::write_atomic(&self.path, text.as_bytes())
            .map_err(|e| format!("{}: {e}", self.path.display()))
    }

    /// Writes `history.csv` beside `summary.json` (atomically): one row per converged step with
    /// `step`, `load_factor`, the eq. 15 `error` when the scene has one, and every measure the
    /// modules recorded (reactions, probes...), named as in `summary.json`; a value a step does
    /// not have is left empty.
    pub fn write_history(&self) -> Result<(), String> {
        let path = self.path.with_file_name("history.csv");
        crate::output::write_atomic(&path, history_csv(&self.steps).as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))
    }
}

/// A step's record read back from its `summary.json` form ([`Summary::steps_json`]), as a
/// resumed run restores the steps done before. `measures` are the names of the run's measures
/// in the order they are taken; the record's measures come back in that order.
pub fn step_from_json(value: &Value, measures: &[String]) -> Result<StepRecord, String> {
    let count = |key: &str| {
        value[key]
            .as_u64()
            .map(|n| n as usize)
            .ok_or_else(|| format!("a step's {key} is not a count"))
    };
    let real = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    let reals = |v: &Value| -> Vec<f64> {
        v.as_array()
            .map(|list| list.iter().map(real).collect())
            .unwrap_or_default()
    };
    let counts = |v: &Value| -> Vec<usize> {
        v.as_array()
            .map(|list| {
                list.iter()
                    .filter_map(|n| n.as_u64())
                    .map(|n| n as usize)
                    .collect()
            })
            .unwrap_or_default()
    };
    let mut record = StepRecord::new(count("step")?, real(&value["load_factor"]));
    if let Some(index) = value["stage"].as_u64() {
        let name = value["stage_name"].as_str().unwrap_or_default();
        record.stage = Some((index as usize, name.to_string()));
    }
    record.iterations = count("iterations")?;
    record.residuals = reals(&value["residuals"]);
    record.linear_iterations = counts(&value["linear_iterations"]);
    record.multigrid = value.get("multigrid").map(|m| Hierarchy {
        rows: counts(&m["rows"]),
        nonzeros: counts(&m["nonzeros"]),
    });
    record.linear_backend = value["linear_backend"].as_str().map(str::to_string);
    record.converged = value["converged"].as_bool().unwrap_or(false);
    record.dofs = count("dofs")?;
    record.seconds = stage_clock(&value["seconds"]);
    record.wall_seconds = real(&value["wall_seconds"]);
    record.error = value.get("error").map(real);
    record.cuts = count("cuts")?;
    if let Some(search) = value.get("line_search") {
        let count = |key: &str| search[key].as_u64().unwrap_or(0) as usize;
        record.line_search = LineSearchCounts {
            shortened: count("shortened"),
            rejected: count("rejected"),
        };
    }
    for name in measures {
        if let Some(v) = value.get(name) {
            record.measures.push((name.clone(), real(v)));
        }
    }
    let object = value.as_object().ok_or("a step is not an object")?;
    if let Some(unknown) = object
        .keys()
        .find(|key| !STEP_KEYS.contains(&key.as_str()) && !measures.contains(key))
    {
        return Err(format!(
            "a step has the measure {unknown}, which this run does not take"
        ));
    }
    record.substeps = match value["substeps"].as_array() {
        Some(list) => list
            .iter()
            .map(|a| SubstepRecord {
                from: real(&a["from"]),
                to: real(&a["to"]),
                iterations: a["iterations"].as_u64().unwrap_or(0) as usize,
                residuals: reals(&a["residuals"]),
                linear_iterations: counts(&a["linear_iterations"]),
                converged: a["converged"].as_bool().unwrap_or(false),
                failure: a["failure"].as_str().map(str::to_string),
            })
            .collect(),
        // a step solved in one attempt records it only in the step's own figures
        None => vec![SubstepRecord {
            from: f64::NAN,
            to: record.load_factor,
            iterations: record.iterations,
            residuals: record.residuals.clone(),
            linear_iterations: record.linear_iterations.clone(),
            converged: record.converged,
            failure: None,
        }],
    };
    Ok(record)
}

/// The keys of a step's record that are not measures.
const STEP_KEYS: &[&str] = &[
    "step",
    "load_factor",
    "stage",
    "stage_name",
    "iterations",
    "residuals",
    "linear_iterations",
    "multigrid",
    "linear_backend",
    "converged",
    "dofs",
    "seconds",
    "wall_seconds",
    "error",
    "cuts",
    "line_search",
    "substeps",
];

fn stage_clock(value: &Value) -> StageClock {
    let mut clock = StageClock::default();
    for stage in Stage::ALL {
        let seconds = value[stage.name()].as_f64().unwrap_or(0.0);
        clock.seconds[stage as usize] =
            std::time::Duration::try_from_secs_f64(seconds).unwrap_or_default();
    }
    clock
}

/// The text of `history.csv` for these steps (see [`Summary::write_history`]).
pub fn history_csv(steps: &[StepRecord]) -> String {
    let mut names: Vec<&str> = Vec::new();
    if steps.iter().any(|s| s.error.is_some()) {
        names.push("error");
    }
    for step in steps {
        for (name, _) in &step.measures {
            if !names.contains(&name.as_str()) {
                names.push(name);
            }
        }
    }
    let staged = steps.iter().any(|s| s.stage.is_some());
    let mut text = String::from(if staged {
        "step,stage,load_factor"
    } else {
        "step,load_factor"
    });
    for name in &names {
        text += ",";
        text += name;
    }
    text += "\n";
    for step in steps {
        match (&step.stage, staged) {
            (Some((stage, _)), _) => {
                text += &format!("{},{},{}", step.step, stage, step.load_factor);
            }
            (None, true) => text += &format!("{},,{}", step.step, step.load_factor),
            (None, false) => text += &format!("{},{}", step.step, step.load_factor),
        }
        for &name in &names {
            let value = if name == "error" {
                step.error
            } else {
                step.measure(name)
            };
            text += ",";
            if let Some(value) = value {
                text += &value.to_string();
            }
        }
        text += "\n";
    }
    text
}
