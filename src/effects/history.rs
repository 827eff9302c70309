//! Named columns of `history.csv`: `record(#{ name, quantity, scale })` records, after every
//! converged step, `scale` times a quantity another module measures (a reaction, a mean
//! traction, a surface's mean displacement...), under a name of the scene's choosing, so that
//! other tools read a load–displacement curve without knowing the scene (e.g. `settlement` and
//! `footing_pressure` of `scripts/strip_footing.rhai`).
//!
//! The recorded quantities of a run are the measures of its modules (`Extension::add_measure`):
//! `impm check` lists the names (e.g. `footing_reaction_y`); a `record` of a name no module
//! measures is an error naming the call's line and the names there are. This module is built
//! after the others, so its measures read theirs (`records::MeasuredValues`).

use rhai::Dynamic;

use crate::plugin::{Extension, Plugin};
use crate::records::{MeasuredValues, StepMeasures};
use crate::scene::{
    CallSpec, Kind, Located, OptionSpec, Options, Range, Resolver, SceneApi, SceneSpec, ScriptError,
};

/// The quantity that is the step's load factor.
pub const LOAD_FACTOR: &str = "load_factor";

/// One `record(...)`.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordSpec {
    pub name: String,
    pub quantity: String,
    pub scale: f64,
    pub line: Option<usize>,
}

/// The scene's `reference(...)`: the reference value of a recorded quantity.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceSpec {
    pub quantity: String,
    pub value: f64,
    pub line: Option<usize>,
}

impl ReferenceSpec {
    /// The name of the recorded error, `QUANTITY_error`.
    pub fn error_name(&self) -> String {
        format!("{}_error", self.quantity)
    }

    /// |q − value| / |value|, or |q| when the value is zero.
    pub fn error(&self, q: f64) -> f64 {
        let difference = (q - self.value).abs();
        if self.value == 0.0 {
            difference
        } else {
            difference / self.value.abs()
        }
    }
}

/// The scene's `record(...)` calls.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Records(pub Vec<RecordSpec>);

/// The module.
#[derive(Clone, Copy, Debug, Default)]
pub struct HistoryModule;

impl Plugin for HistoryModule {
    fn name(&self) -> &'static str {
        "history"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::options(
            "record",
            "records `scale` times a measured quantity (e.g. `footing_reaction_y`; `impm check` lists them) after every converged step as a column `name` of history.csv and a key of summary.json",
            vec![
                OptionSpec::required("name", Kind::Text, "the column's name (a word)"),
                OptionSpec::required("quantity", Kind::Text, "the measured quantity (or `load_factor`)"),
                OptionSpec::new(
                    "scale",
                    Kind::Number(Range::Any),
                    "factor applied to the quantity (default 1)",
                ),
            ],
            |builder, options: &Options, at| {
                builder.declare(Located::new(
                    RecordSpec {
                        name: options.text("name").unwrap_or_default().to_string(),
                        quantity: options.text("quantity").unwrap_or_default().to_string(),
                        scale: options.number("scale").unwrap_or(1.0),
                        line: at.line(),
                    },
                    at,
                ));
                Ok(Dynamic::UNIT)
            },
        ));
        api.call(CallSpec::options(
            "reference",
            "the reference (exact or converged) value of a recorded quantity at the end of the run: every step records its relative error as QUANTITY_error, and `impm study` uses it as the error measure (call once)",
            vec![
                OptionSpec::required(
                    "quantity",
                    Kind::Text,
                    "a recorded quantity: a measure (e.g. `tip_displacement_y`) or the name of a `record`",
                ),
                OptionSpec::required("value", Kind::Number(Range::Any), "its reference value"),
            ],
            |builder, options: &Options, at| {
                if let Some(previous) = builder.declared::<ReferenceSpec>().first() {
                    return Err(format!(
                        "reference(...) was already called{}; a run has one error measure",
                        previous.line_note()
                    ));
                }
                builder.declare(Located::new(
                    ReferenceSpec {
                        quantity: options.text("quantity").unwrap_or_default().to_string(),
                        value: options.number("value").unwrap_or_default(),
                        line: at.line(),
                    },
                    at,
                ));
                Ok(Dynamic::UNIT)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let mut records: Vec<RecordSpec> = Vec::new();
        for declaration in scene.declarations::<RecordSpec>() {
            let record = &declaration.value;
            let name = &record.name;
            if name.is_empty() || name.contains(|c: char| c.is_whitespace() || c == ',') {
                return Err(ScriptError::at(
                    declaration.at,
                    format!(
                        "record(...): name {name:?} must be a non-empty word without spaces or commas"
                    ),
                ));
            }
            if records.iter().any(|r| &r.name == name) {
                return Err(ScriptError::at(
                    declaration.at,
                    format!("record(...): '{name}' is recorded twice"),
                ));
            }
            records.push(record.clone());
        }
        if !records.is_empty() {
            scene.spec.set_part(Records(records));
        }
        if let Some(reference) = scene.declarations::<ReferenceSpec>().first() {
            scene.spec.set_part(reference.value.clone());
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let records = spec.part::<Records>().map_or(&[][..], |r| &r.0);
        let mut lines: Vec<String> = records
            .iter()
            .map(|r| {
                let line = r.line.map(|l| format!("line {l}: ")).unwrap_or_default();
                format!("{line}{} = {} × {}", r.name, r.scale, r.quantity)
            })
            .collect();
        if let Some(reference) = spec.part::<ReferenceSpec>() {
            let line = reference
                .line
                .map(|l| format!("line {l}: "))
                .unwrap_or_default();
            lines.push(format!(
                "{line}reference {} = {} ({} records its relative error)",
                reference.quantity,
                reference.value,
                reference.error_name()
            ));
        }
        (!lines.is_empty()).then(|| lines.join("\n    "))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<Records>().is_some() || spec.part::<ReferenceSpec>().is_some()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let records = simulation
            .spec()
            .part::<Records>()
            .map_or(Vec::new(), |r| r.0.clone());
        let measured: Vec<String> = simulation
            .world()
            .get_resource::<StepMeasures>()
            .map_or(Vec::new(), |m| {
                m.0.iter().map(|(name, _)| name.clone()).collect()
            });
        for record in records {
            let (quantity, scale) = (record.quantity.clone(), record.scale);
            let name = record.name.clone();
            if quantity == LOAD_FACTOR {
                simulation.add_measure(name, move |_, factor| Some(scale * factor));
                continue;
            }
            if !measured.contains(&record.quantity) {
                let line = record
                    .line
                    .map(|l| format!("line {l}: "))
                    .unwrap_or_default();
                simulation.fail(format!(
                    "{line}record(...): no module measures '{}'; the recorded quantities are: {LOAD_FACTOR}, {}",
                    record.quantity,
                    measured.join(", ")
                ));
                return;
            }
            simulation.add_measure(name, move |world, _| {
                Some(scale * world.get_resource::<MeasuredValues>()?.get(&quantity)?)
            });
        }
        if let Some(reference) = simulation.spec().part::<ReferenceSpec>().cloned() {
            add_reference_error(simulation, &measured, reference);
        }
    }
}

/// `QUANTITY_error` of the scene's reference value; an error if nothing records the quantity.
fn add_reference_error<const D: usize>(
    simulation: &mut Extension<'_, D>,
    measured: &[String],
    reference: ReferenceSpec,
) {
    let records: Vec<String> = simulation
        .spec()
        .part::<Records>()
        .map_or(Vec::new(), |r| r.0.iter().map(|r| r.name.clone()).collect());
    let quantity = reference.quantity.clone();
    let known =
        quantity == LOAD_FACTOR || measured.contains(&quantity) || records.contains(&quantity);
    if !known {
        let line = reference
            .line
            .map(|l| format!("line {l}: "))
            .unwrap_or_default();
        simulation.fail(format!(
            "{line}reference(...): '{quantity}' is not recorded; the recorded quantities are: {LOAD_FACTOR}, {}",
            measured
                .iter()
                .cloned()
                .chain(records)
                .collect::<Vec<_>>()
                .join(", ")
        ));
        return;
    }
    simulation.add_measure(reference.error_name(), move |world, factor| {
        let value = if quantity == LOAD_FACTOR {
            factor
        } else {
            world.get_resource::<MeasuredValues>()?.get(&quantity)?
        };
        Some(reference.error(value))
    });
}
