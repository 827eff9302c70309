//! Staged analysis: `stage(#{ name: "gravity", steps: 10 })` splits a scene's loading into
//! stages run one after the other, each with its own load schedule from λ = 0 to its last
//! factor (`steps: n`, the factors k/n, or `load_factors: [..]`).
//!
//! ```text
//! body_force(..) (before any stage)  ── belongs to the first stage
//! stage(#{ name: "gravity", steps: 4 })      stage 0: λ₀ = 1/4 .. 1
//! traction(..)                        ── belongs to "gravity" too
//! stage(#{ name: "footing", steps: 5 })      stage 1: λ₁ = 1/5 .. 1
//! traction(..)                        ── belongs to "footing"
//! ```
//!
//! A load of stage k is absent before stage k, follows λ_k in it (or is held in full from its
//! start, `held: true`) and is held at its final value in the stages after it
//! (`resources::Ramp`, `LoadStep::factor_in`): with `f_j` the loads of stage j at factor 1,
//!
//! ```text
//!   f_ext(step in stage k) = Σ_{j<k} f_j λ_j,end + λ_k f_k.
//! ```
//!
//! The scene's load steps are the stages' steps in order (`SceneSpec::load_factors` holds each
//! stage's own factors; [`Stages::of_step`] says which stage a step is in and whether it
//! starts it, so that the driver steps from λ = 0 there). A `surface_displace` of stage k acts
//! from stage k's start on and prescribes the displacement from there
//! (`effects::surface_conditions`, "Stages"): the footing pushed after a gravity stage. A
//! `fix` / `displace` of stage k constrains its nodes from stage k's start on, and
//! `#{ until_stage: "s" }` releases it at stage s's start, its force ramped down over stage s
//! (`effects::grid_constraints`, "Stages"). The
//! calls that do not follow the load factor (`grid`, `material`, `body`, `solver`,
//! `output`, `stress_recovery`, `initial_stress`) belong to every stage: a scene of two or
//! more stages refuses them after its second `stage(...)` call (only the calls that follow
//! stages, `body_force`, `traction`, `point_load_at`, `surface_displace`, `fix`, `displace`,
//! `point_load`, `point_load_total`, `pressure`, `material_of` (`effects::material_switches`:
//! a body's material changed at its stage's start), and the observers, `record`, `probe`,
//! `reference`, may come there), and refuses anywhere the calls that follow the one load
//! factor without telling stages apart (`analytic_column`, and any call these lists do not
//! know: a module's new load is refused until it follows stages), naming the line.
//! A scene with one stage is the scene without it, with the stage's schedule.
//!
//! The last stage may be arc-controlled, `stage(#{ .., control: "arc_length" })`: its load
//! factor is then an unknown of each of its steps (`stages::arc_length`), the earlier stages'
//! loads held beside it at their final value (`effects::arc_length`, "Stages"). Only the last:
//! the arc ends past the limit load at a factor nobody chose, so no stage could follow with
//! its loads held at a known value. `solver(#{ control: "arc_length" })` in a scene of several
//! stages is refused (it names no stage), and so is an `until_stage` naming the arc-controlled
//! stage (`effects::declarations::until_stage`: a release ramped by `1 − λ` would turn into a
//! load of the other sign once the arc takes λ past 1).

use rhai::{Dynamic, Position};

use super::ScriptError;
use super::builder::{Located, SceneBuilder};
use super::options::{Choice, Kind, OptionSpec, Options};
use super::registry::CallSpec;
use super::schedule::{MAX_STEPS, equal_steps};

/// One `stage(...)` call.
#[derive(Clone, Debug, PartialEq)]
pub struct StageDeclaration {
    pub name: String,
    /// The stage's own load factors (from λ = 0).
    pub factors: Vec<f64>,
    pub zero_displacements: bool,
    /// `control: "arc_length"`: the stage's load factor is found by arc-length control.
    pub arc_length: bool,
}

/// A stage of the scene: its name, its number of load steps and the line of its call.
#[derive(Clone, Debug, PartialEq)]
pub struct StageSpec {
    pub name: String,
    pub steps: usize,
    /// Displacements are measured from the stage's start (`effects::stages`).
    pub zero_displacements: bool,
    /// The stage's load factor is found by arc-length control (`control: "arc_length"`; only
    /// the last stage may ask for it: `effects::arc_length`, "Stages").
    pub arc_length: bool,
    pub line: Option<usize>,
}

/// The stages of a scene (a part of the scene when it calls `stage(...)`).
#[derive(Clone, Debug, PartialEq)]
pub struct Stages(pub Vec<StageSpec>);

impl Stages {
    /// The stage of load step `step` (1-based) and whether the step is the stage's first;
    /// steps after the last stage's count as its own.
    pub fn of_step(&self, step: usize) -> (usize, bool) {
        let mut first = 1;
        for (index, stage) in self.0.iter().enumerate() {
            if step < first + stage.steps {
                return (index, step == first);
            }
            first += stage.steps;
        }
        (self.0.len().saturating_sub(1), false)
    }

    /// Whether stage `index` measures displacements from its start.
    pub fn zeroes_displacements(&self, index: usize) -> bool {
        self.0
            .get(index)
            .is_some_and(|stage| stage.zero_displacements)
    }

    /// The arc-length stage (`control: "arc_length"`, the last stage when there is one) and
    /// the number of its first load step (1-based).
    pub fn arc_length_stage(&self) -> Option<(usize, usize)> {
        let index = self.0.iter().position(|stage| stage.arc_length)?;
        let first = 1 + self.0[..index].iter().map(|s| s.steps).sum::<usize>();
        Some((index, first))
    }

    /// The name of stage `index` ("" if there is none).
    pub fn name(&self, index: usize) -> &str {
        self.0.get(index).map_or("", |stage| stage.name.as_str())
    }
}

/// The calls that follow stages: declared in any stage, they belong to it.
const STAGED_CALLS: &[&str] = &[
    "body_force",
    "traction",
    "point_load_at",
    "surface_displace",
    "fix",
    "displace",
    "point_load",
    "point_load_total",
    "material_of",
    "pressure",
];

/// The calls that may come after the second `stage(...)` call besides those: the stages
/// themselves, region shapes and what only observes the run.
const ANYWHERE_CALLS: &[&str] = &[
    "stage",
    "box",
    "polygon",
    "arc",
    "record",
    "probe",
    "reference",
];

/// The calls a scene of two or more stages may make before its second `stage(...)` besides
/// those: what does not follow the load factor (the grid, materials, bodies, supports, solver,
/// output and recovery controls, initial stresses). Any other call (`pressure`,
/// `analytic_column`, or a call of a
/// module this list does not know) follows the one load factor λ, which restarts in every
/// stage: refused.
const STAGE_FREE_CALLS: &[&str] = &[
    "grid",
    "material",
    "body",
    "solver",
    "output",
    "stress_recovery",
    "initial_stress",
];

/// The `stage(...)` call.
pub fn stage_call() -> CallSpec {
    CallSpec::options(
        "stage",
        "starts a stage of a staged analysis (docs/plasticity.md, \"Staged analysis\"): the loads declared after it, up to the next stage, follow its own schedule from λ = 0 (`steps`: n equal steps, or `load_factors`) and are held at their final value in the stages after it; declarations before the first stage belong to it; replaces load_steps(...) and the other schedules",
        vec![
            OptionSpec::required("name", Kind::Text, "the stage's name (unique)"),
            OptionSpec::new(
                "steps",
                Kind::Whole {
                    min: 1,
                    max: Some(MAX_STEPS),
                },
                "n equal load steps to λ = 1 (factors k/n)",
            ),
            OptionSpec::new(
                "load_factors",
                Kind::Numbers,
                "the stage's load factor at the end of each of its steps (instead of `steps`)",
            ),
            OptionSpec::new(
                "control",
                Kind::Choice(vec![
                    Choice {
                        word: "load",
                        meaning: Some(
                            "the stage's load factors (`steps` or `load_factors`), steps cut on failure (the default)",
                        ),
                    },
                    Choice {
                        word: "arc_length",
                        meaning: Some(
                            "arc-length control (docs/plasticity.md, \"Past the limit load\"): the stage's load factor is an unknown of each step, so its loads are traced to and past their limit load; the earlier stages' loads stay at their final value beside them; its first load factor sizes the first arc, its step count is the most steps; the last stage only, tuned by solver(#{ target_iterations, max_load_factor, rebalance })",
                        ),
                    },
                ]),
                "how the stage's load factor is found (default \"load\")",
            ),
            OptionSpec::new(
                "zero_displacements",
                Kind::Flag,
                "measure displacements from the stage's start (the `displacement` point field, probes): the state of the stages before it (positions, stresses, histories) stays (default false)",
            ),
        ],
        declare_stage,
    )
}

fn declare_stage(
    builder: &mut SceneBuilder,
    options: &Options,
    at: Position,
) -> Result<Dynamic, String> {
    let name = options.text("name").unwrap_or_default().to_string();
    if name.trim().is_empty() {
        return Err("stage(...): the name must not be empty".to_string());
    }
    if let Some(previous) = builder.stages.iter().find(|stage| stage.value.name == name) {
        return Err(format!(
            "stage(...): a stage named '{name}' was already declared{}; stage names are unique",
            previous.line_note()
        ));
    }
    if let Some(schedule) = &builder.load_schedule {
        return Err(format!(
            "stage(...): the scene already has a load schedule{}; a staged scene gives each stage its own (`steps` or `load_factors` of stage(...)): remove the schedule call",
            schedule.line_note()
        ));
    }
    let factors = match (options.whole("steps"), options.numbers("load_factors")) {
        (Some(steps), None) => equal_steps(steps),
        (None, Some(factors)) if !factors.is_empty() => factors.to_vec(),
        (None, Some(_)) => {
            return Err(format!(
                "stage(...) '{name}': load_factors is empty; a stage needs at least one load step"
            ));
        }
        (None, None) => {
            return Err(format!(
                "stage(...) '{name}' has no load steps: give it `steps: n` or `load_factors: [..]`"
            ));
        }
        (Some(_), Some(_)) => {
            return Err(format!(
                "stage(...) '{name}': give `steps` or `load_factors`, not both"
            ));
        }
    };
    builder.stages.push(Located::new(
        StageDeclaration {
            name,
            factors,
            zero_displacements: options.flag("zero_displacements").unwrap_or(false),
            arc_length: options.text("control") == Some("arc_length"),
        },
        at,
    ));
    Ok(Dynamic::UNIT)
}

/// The stages of a scene that calls `stage(...)`, and its load factors (each stage's own, in
/// order); `None` for a scene without stages. Refuses the calls a staged scene cannot take
/// (module docs), naming their lines.
pub fn resolve_stages(builder: &SceneBuilder) -> Result<Option<(Stages, Vec<f64>)>, ScriptError> {
    let Some(first) = builder.stages.first() else {
        return Ok(None);
    };
    if let Some(schedule) = &builder.load_schedule {
        return Err(ScriptError::at(
            schedule.at,
            format!(
                "the load schedule is given by the stages (stage(...){}): remove this schedule call, or give its steps to the stages",
                first.line_note()
            ),
        ));
    }
    if builder.stages.len() > 1 {
        for (name, call) in &builder.calls {
            let known = STAGED_CALLS.contains(name) || ANYWHERE_CALLS.contains(name);
            if !known && !STAGE_FREE_CALLS.contains(name) {
                return Err(ScriptError::at(
                    call.at,
                    format!(
                        "{name}(...) does not follow stages yet (what follows the load factor would restart from zero in every stage); in a scene of several stages use {}, or run it without stage(...)",
                        STAGED_CALLS.join(", ")
                    ),
                ));
            }
            if call.stage > 0 && !known {
                let stage = &builder.stages[call.stage];
                return Err(ScriptError::at(
                    call.at,
                    format!(
                        "{name}(...) after stage '{}'{}: only the loads that follow stages ({}) can be declared in a later stage; declare it before the second stage(...), where it belongs to every stage",
                        stage.value.name,
                        stage.line_note(),
                        STAGED_CALLS.join(", ")
                    ),
                ));
            }
        }
        if let Some((_, solver)) = builder.call_options.iter().find(|(name, options)| {
            *name == "solver" && options.value.text("control") == Some("arc_length")
        }) {
            return Err(ScriptError::at(
                solver.at,
                "solver(#{ control: \"arc_length\" }) in a scene of several stages: say which stage is arc-controlled with stage(#{ .., control: \"arc_length\" }) on the last stage (the earlier stages run under load control, their loads held beside the arc's); keep target_iterations, max_load_factor and rebalance in solver(...)",
            ));
        }
    }
    let last = builder.stages.len() - 1;
    if let Some(stage) = builder.stages[..last]
        .iter()
        .find(|stage| stage.value.arc_length)
    {
        return Err(ScriptError::at(
            stage.at,
            format!(
                "stage(...) '{}': control: \"arc_length\" is taken by the last stage only (its load factor ends where the arc ends, past the limit load, so no stage can follow it with its loads held at a known value); stage '{}' comes after it",
                stage.value.name, builder.stages[last].value.name
            ),
        ));
    }
    let mut factors = Vec::new();
    let mut stages = Vec::new();
    for stage in &builder.stages {
        factors.extend_from_slice(&stage.value.factors);
        stages.push(StageSpec {
            name: stage.value.name.clone(),
            steps: stage.value.factors.len(),
            zero_displacements: stage.value.zero_displacements,
            arc_length: stage.value.arc_length,
            line: stage.at.line(),
        });
    }
    if factors.len() > MAX_STEPS {
        return Err(ScriptError::at(
            first.at,
            format!(
                "the stages have {} load steps in all: too many",
                factors.len()
            ),
        ));
    }
    Ok(Some((Stages(stages), factors)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_knows_its_stage_and_whether_it_starts_it() {
        let stages = Stages(vec![
            StageSpec {
                name: "a".into(),
                steps: 2,
                zero_displacements: false,
                arc_length: false,
                line: None,
            },
            StageSpec {
                name: "b".into(),
                steps: 3,
                zero_displacements: true,
                arc_length: false,
                line: None,
            },
        ]);
        let found: Vec<_> = (1..=6).map(|step| stages.of_step(step)).collect();
        assert_eq!(
            found,
            [
                (0, true),
                (0, false),
                (1, true),
                (1, false),
                (1, false),
                (1, false)
            ]
        );
        assert_eq!(stages.name(1), "b");
        assert_eq!(stages.name(2), "");
    }
}
