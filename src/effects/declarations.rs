//! What `impm check` says of a load declaration: its line, what it selects (how many points,
//! their coordinate range) and the total force at load factor 1, so that a user verifies the
//! loads before solving. Each load module keeps a [`LoadSummary`] per declaration in its part
//! of the scene and prints them in its `describe`. Also the options the loads share: `held`,
//! and `until_stage` (a load or support released at a later stage's start, [`until_stage`],
//! the load then ramped down over that stage, [`released_factor`]).

use rhai::Position;

use crate::checkpoint::CheckpointPart;
use crate::plugin::Extension;
use crate::resources::{LargestForce, LoadStep, Ramp};
use crate::scene::{Kind, OptionSpec, SceneSpec, ScriptError, Stages};

/// The option of a load that can be held (`traction`, `point_load_at`, `body_force`): `held`
/// (`resources::Ramp`).
pub fn held_option() -> OptionSpec {
    OptionSpec::new(
        "held",
        Kind::Flag,
        "true: applied in full from the first load step on instead of following the load factor (default false)",
    )
}

/// The option of a load released at a later stage's start (`body_force`): `until_stage`.
pub fn until_stage_option() -> OptionSpec {
    OptionSpec::new(
        "until_stage",
        Kind::Text,
        "the (later) stage whose start releases the load: it is ramped down to zero over that stage, f = (1 − λ) f_end, and is absent after it",
    )
}

/// The index of stage `until` (an `until_stage` option) of a declaration of `function` that
/// belongs to stage `from`: refused with the line `at` when the scene has no stages, no stage
/// of that name, or the stage is not after `from`.
pub fn until_stage(
    spec: &SceneSpec,
    function: &str,
    until: &str,
    from: usize,
    at: Position,
) -> Result<usize, ScriptError> {
    let stages = spec.part::<Stages>().map_or(&[][..], |s| &s.0);
    let names = || {
        stages
            .iter()
            .map(|stage| format!("'{}'", stage.name))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let Some(index) = stages.iter().position(|stage| stage.name == until) else {
        let why = if stages.is_empty() {
            "the scene has no stages (until_stage releases a load or constraint at a stage's start: declare the stages with stage(...))".to_string()
        } else {
            format!("the stages are {}", names())
        };
        return Err(ScriptError::at(
            at,
            format!("{function}(...): until_stage: no stage is named '{until}': {why}"),
        ));
    };
    if index <= from {
        return Err(ScriptError::at(
            at,
            format!(
                "{function}(...): until_stage: '{until}' is not after the stage the {} belongs to ('{}'): it is released at the start of a later stage (the stages are {})",
                if matches!(function, "fix" | "displace") {
                    "constraint"
                } else {
                    "load"
                },
                stages[from].name,
                names()
            ),
        ));
    }
    if stages[index].arc_length {
        return Err(ScriptError::at(
            at,
            format!(
                "{function}(...): until_stage: '{until}' is arc-controlled (control: \"arc_length\"): a release is ramped down with the stage's load factor, (1 − λ) f_end, and the arc takes λ past 1 to the limit load, where the released force would act the other way; release it in an earlier stage under load control"
            ),
        ));
    }
    Ok(index)
}

/// The factor a load of `ramp` released at the start of stage `until` is applied with in a
/// step of stage `stage`: as [`LoadStep::factor_in`] before stage `until`, ramped down over
/// it (its value at the end of the stage before, held in full, times `1 − λ`), and 0 after it:
///
/// ```text
///   f(stage s = until) = (1 − λ_s) f_end,   f(stage > until) = 0.
/// ```
pub fn released_factor(step: &LoadStep, ramp: Ramp, until: Option<usize>, stage: usize) -> f64 {
    match until {
        Some(until) if stage == until => (1.0 - step.factor) * step.factor_in(ramp, stage),
        Some(until) if stage > until => 0.0,
        _ => step.factor_in(ramp, stage),
    }
}

/// Keeps the run's largest converged force (`resources::LargestForce`, the floor of the
/// convergence criterion's scale, `control::NormalisedResidual` "Releases") in a scene that
/// releases a load or support: every module with a release calls this in its `build`; the
/// first inserts the resource and its checkpoint part, the others find them.
pub fn keep_largest_force<const D: usize>(simulation: &mut Extension<'_, D>) {
    if simulation.world().contains_resource::<LargestForce>() {
        return;
    }
    simulation.world().insert_resource(LargestForce::default());
    simulation.checkpoint(CheckpointPart {
        name: "largest force",
        save: |world| vec![world.resource::<LargestForce>().0],
        restore: |world, values| match values {
            [value] => {
                world.resource_mut::<LargestForce>().0 = *value;
                Ok(())
            }
            _ => Err(format!("{} values saved, 1 expected", values.len())),
        },
    });
}

/// ", released at the start of stage 's' (ramped down over that stage)" for `impm check`: what
/// a load's `until_stage` does (empty for a load never released).
pub fn released_note(spec: &SceneSpec, until: Option<usize>) -> String {
    match (until, spec.part::<Stages>()) {
        (Some(until), Some(stages)) => format!(
            ", released at the start of stage '{}' (ramped down over that stage)",
            stages.name(until)
        ),
        _ => String::new(),
    }
}

/// The stage an optional `until_stage` names ([`until_stage`], refused with the line `at`).
pub fn until_stage_of(
    spec: &SceneSpec,
    function: &str,
    until: Option<&str>,
    from: usize,
    at: Position,
) -> Result<Option<usize>, ScriptError> {
    until
        .map(|until| until_stage(spec, function, until, from, at))
        .transpose()
}

/// One load declaration as `impm check` lists it.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadSummary {
    /// Line of the declaring call.
    pub line: Option<usize>,
    /// The call (`point_load_total`, `traction`, ...).
    pub call: &'static str,
    /// What it selects, counted: "12 material points", "40 traction points".
    pub selects: String,
    /// How many points it selects (the number in `selects`).
    pub count: usize,
    /// How many calls of the same line it sums (a loop in the scene: [`grouped`]).
    pub calls: usize,
    /// Coordinate range of the selection (reference positions), per axis.
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// The total force at load factor 1.
    pub total_force: Vec<f64>,
    /// "at load factor 1", with the stage in a scene of several stages ([`factor_one`]).
    pub factor: String,
}

/// "at load factor 1" for `impm check`, naming the stage in a scene of several stages, where a
/// load of a later stage is at load factor 1 of that stage's own schedule (`scene::stages`).
pub fn factor_one(spec: &SceneSpec, stage: usize) -> String {
    match spec.part::<Stages>() {
        Some(stages) if stages.0.len() > 1 => {
            format!("at load factor 1 of stage '{}'", stages.name(stage))
        }
        _ => "at load factor 1".to_string(),
    }
}

impl LoadSummary {
    /// A summary of `call` at `line` over the reference `positions` it selects.
    pub fn new<'a>(
        line: Option<usize>,
        call: &'static str,
        what: &str,
        positions: impl Iterator<Item = &'a [f64]>,
        total_force: Vec<f64>,
    ) -> Self {
        let positions: Vec<&[f64]> = positions.collect();
        let (lower, upper) = coordinate_range(positions.iter().copied());
        Self {
            line,
            call,
            selects: format!("{} {what}", positions.len()),
            count: positions.len(),
            calls: 1,
            lower,
            upper,
            total_force: total_force.into_iter().map(round).collect(),
            factor: "at load factor 1".to_string(),
        }
    }

    /// The summary of a load of stage `stage` (its factor named by [`factor_one`]).
    pub fn in_stage(mut self, spec: &SceneSpec, stage: usize) -> Self {
        self.factor = factor_one(spec, stage);
        self
    }

    /// The summary of a load released at the start of stage `until` ([`released_note`]).
    pub fn released(mut self, spec: &SceneSpec, until: Option<usize>) -> Self {
        self.factor += &released_note(spec, until);
        self
    }

    /// `line 12: point_load_total: 4 material points, x in [..] .. [..], total force [..] at
    /// load factor 1`.
    pub fn describe(&self) -> String {
        let line = self.line.map(|l| format!("line {l}: ")).unwrap_or_default();
        let calls = match self.calls {
            1 => String::new(),
            n => format!(" ({n} calls)"),
        };
        format!(
            "{line}{}{calls}: {}, x in {:?} .. {:?}, total force {:?} {}",
            self.call, self.selects, self.lower, self.upper, self.total_force, self.factor
        )
    }
}

/// The summaries with the calls of one line (a loop in the scene: `point_load_at` at each of
/// a face's quadrature points, say) summed into one, in the order of their first call: their
/// points counted together, the range of all their positions and their total force. `impm
/// check` lists a line once, not once per call.
pub fn grouped(summaries: &[LoadSummary]) -> Vec<LoadSummary> {
    let mut grouped: Vec<LoadSummary> = Vec::new();
    for summary in summaries {
        let same = |g: &&mut LoadSummary| {
            g.line.is_some()
                && g.line == summary.line
                && g.call == summary.call
                && g.factor == summary.factor
                && g.total_force.len() == summary.total_force.len()
        };
        let Some(group) = grouped.iter_mut().find(same) else {
            grouped.push(summary.clone());
            continue;
        };
        let what = group
            .selects
            .trim_start_matches(|c: char| c.is_ascii_digit())
            .trim();
        let what = match what.ends_with("point") {
            true => format!("{what}s"),
            false => what.to_string(),
        };
        group.count += summary.count;
        group.calls += summary.calls;
        group.selects = format!("{} {what}", group.count);
        for (a, (l, u)) in summary.lower.iter().zip(&summary.upper).enumerate() {
            group.lower[a] = group.lower[a].min(*l);
            group.upper[a] = group.upper[a].max(*u);
        }
        for (total, f) in group.total_force.iter_mut().zip(&summary.total_force) {
            *total = round(*total + f);
        }
    }
    grouped
}

/// Rounds to 9 decimals for listings.
pub fn round(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}

/// What a predicate that selected nothing could have selected, for its message: the range of
/// `positions` per axis (`x[0] in [0, 10], x[1] in [0, 50]`), and a reminder of Rhai's integer
/// division, the usual cause of a coordinate that silently became 0.
pub fn selection_ranges<'a>(positions: impl Iterator<Item = &'a [f64]>) -> String {
    let (lower, upper) = coordinate_range(positions);
    let ranges: Vec<String> = lower
        .iter()
        .zip(&upper)
        .enumerate()
        .map(|(axis, (l, u))| format!("x[{axis}] in [{l}, {u}]"))
        .collect();
    format!(
        "{}; a coordinate computed as a division of whole numbers is itself whole in the scene language (1 / 4 is 0: write 1.0 / 4)",
        ranges.join(", ")
    )
}

/// The smallest and largest coordinate per axis of `positions` (rounded for listings).
pub fn coordinate_range<'a>(positions: impl Iterator<Item = &'a [f64]>) -> (Vec<f64>, Vec<f64>) {
    let (mut lower, mut upper) = (Vec::<f64>::new(), Vec::<f64>::new());
    for x in positions {
        if lower.is_empty() {
            lower = x.to_vec();
            upper = x.to_vec();
        }
        for (a, &c) in x.iter().enumerate() {
            lower[a] = lower[a].min(c);
            upper[a] = upper[a].max(c);
        }
    }
    (
        lower.into_iter().map(round).collect(),
        upper.into_iter().map(round).collect(),
    )
}
