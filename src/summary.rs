//! `summary.json`: per load step the load factor, Newton iterations and residual history,
//! seconds per stage and, when the scene declares an analytic solution, the paper's error
//! (eq. 15); then totals. Rewritten atomically after every step, so it is valid at any time.

use std::path::{Path, PathBuf};

use serde_json::{Map, Value, json};

use crate::resources::{Stage, StageClock};
use crate::scene::SceneSpec;

/// What one load step did.
#[derive(Clone, Debug)]
pub struct StepRecord {
    pub step: usize,
    pub load_factor: f64,
    /// Linear solves (Newton iterations).
    pub iterations: usize,
    /// Normalised out-of-balance force of each iterate.
    pub residuals: Vec<f64>,
    pub converged: bool,
    pub dofs: usize,
    pub seconds: StageClock,
    pub wall_seconds: f64,
    /// Eq. 15 error after the step, if the scene has an analytic solution.
    pub error: Option<f64>,
    /// Eq. 15 error of the MLS-recovered stress, if the scene asks for stress recovery.
    pub error_recovered: Option<f64>,
    /// How many times the step was cut (halved) after a failed Newton solve.
    pub cuts: usize,
    /// Every attempt in order, failed ones included (one entry when the step was not cut).
    pub substeps: Vec<SubstepRecord>,
}

/// One Newton solve from load factor `from` to `to` within a load step.
#[derive(Clone, Debug)]
pub struct SubstepRecord {
    pub from: f64,
    pub to: f64,
    pub iterations: usize,
    pub residuals: Vec<f64>,
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
    /// "running", "completed" or "failed".
    pub status: &'static str,
    pub failure: Option<String>,
    pub failed_step: Option<StepRecord>,
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
    if let Some(e) = r.error {
        v["error"] = number(e);
    }
    if let Some(e) = r.error_recovered {
        v["error_recovered"] = number(e);
    }
    v["cuts"] = json!(r.cuts);
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

    pub fn finish(&mut self) {
        if self.status == "running" {
            self.status = "completed";
        }
    }

    /// The eq. 15 error after the last completed step.
    pub fn final_error(&self) -> Option<f64> {
        self.steps.last().and_then(|s| s.error)
    }

    /// The eq. 15 error of the recovered stress after the last completed step.
    pub fn final_error_recovered(&self) -> Option<f64> {
        self.steps.last().and_then(|s| s.error_recovered)
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
            "status": self.status,
            "steps": self.steps.iter().map(step_json).collect::<Vec<_>>(),
            "totals": {
                "steps": self.steps.len(),
                "iterations": self.total_iterations(),
                "cuts": self.steps.iter().map(|s| s.cuts).sum::<usize>(),
                "seconds": stage_seconds(&stages),
                "wall_seconds": number(wall),
            },
        });
        if let Some(e) = self.final_error() {
            v["error"] = number(e);
        }
        if let Some(e) = self.final_error_recovered() {
            v["error_recovered"] = number(e);
        }
        if let Some(f) = &self.failure {
            v["failure"] = Value::String(f.clone());
        }
        if let Some(r) = &self.failed_step {
            v["failed_step"] = step_json(r);
        }
        v
    }

    /// Writes `summary.json` atomically.
    pub fn write(&self) -> Result<(), String> {
        let text = serde_json::to_string_pretty(&self.to_json()).map_err(|e| e.to_string())?;
        crate::output::write_atomic(&self.path, text.as_bytes())
            .map_err(|e| format!("{}: {e}", self.path.display()))
    }
}
