//! The scene API registry: one description of every call a scene can make.
//!
//! Each call is registered once, with its signature, its meaning and, for calls that take an
//! options map, the table of its options ([`OptionSpec`]). From that one description come:
//!
//! * the function registered in the Rhai engine (`engine.rs`), whose map argument is read and
//!   checked by the table before the call declares anything;
//! * the "expected ..." hint when a call has the wrong arguments;
//! * the reference of `docs/scene-api.md` ([`SceneApi::reference`]; a test fails when the
//!   document and the registry disagree, `impm api` prints it);
//!
//! The core registers its calls (`calls.rs`: grid, material, body, load schedules, solver,
//! output...); every module registers its own (`point_load`, `traction`, `fix`...) and may add
//! options to a core call (the ghost penalty's `ghost_penalty` of `solver`), words of the grid's
//! `basis` (`"gimp"`, `"fem"`), material models with their parameters, and point fields of the
//! output.

use std::sync::Arc;

use rhai::{Dynamic, Position};

use super::builder::SceneBuilder;
use super::options::{Choice, Kind, OptionSpec, Options};
use super::words::{Word, Words};
use crate::parameter::Range;

/// What a call does with its arguments.
#[derive(Clone)]
pub enum Declare {
    /// `call(#{ .. })`: the map is read by the call's table first.
    Options(Arc<OptionsFn>),
    /// Positional arguments (`fix(|x| .., [0])`), as many as `CallSpec::arity`.
    Args(Arc<ArgsFn>),
}

/// The declaration of a map call.
pub type OptionsFn =
    dyn Fn(&mut SceneBuilder, &Options, Position) -> Result<Dynamic, String> + Send + Sync;
/// The declaration of a call with positional arguments.
pub type ArgsFn =
    dyn Fn(&mut SceneBuilder, &[Dynamic], Position) -> Result<Dynamic, String> + Send + Sync;

/// One scene call (one arity of a name: `fix(f)` and `fix(f, [..])` are two).
#[derive(Clone)]
pub struct CallSpec {
    pub name: &'static str,
    /// How it is called, for messages and the reference; generated for map calls.
    pub signature: String,
    /// What it does (the reference table).
    pub doc: &'static str,
    /// The options table of a map call.
    pub options: Vec<OptionSpec>,
    /// The text option whose value names the thing declared in messages (`material 'soil'`).
    pub name_key: Option<&'static str>,
    pub arity: usize,
    pub declare: Declare,
}

impl CallSpec {
    /// A call taking one options map, read by `options`.
    pub fn options(
        name: &'static str,
        doc: &'static str,
        options: Vec<OptionSpec>,
        declare: impl Fn(&mut SceneBuilder, &Options, Position) -> Result<Dynamic, String>
        + Send
        + Sync
        + 'static,
    ) -> Self {
        Self {
            name,
            signature: String::new(),
            doc,
            options,
            name_key: None,
            arity: 1,
            declare: Declare::Options(Arc::new(declare)),
        }
    }

    /// A call with `arity` positional arguments.
    pub fn args(
        name: &'static str,
        signature: &str,
        doc: &'static str,
        arity: usize,
        declare: impl Fn(&mut SceneBuilder, &[Dynamic], Position) -> Result<Dynamic, String>
        + Send
        + Sync
        + 'static,
    ) -> Self {
        Self {
            name,
            signature: signature.to_string(),
            doc,
            options: Vec::new(),
            name_key: None,
            arity,
            declare: Declare::Args(Arc::new(declare)),
        }
    }

    /// Messages name the declared thing by the value of option `key` (`body 'bar'`).
    pub fn named_by(mut self, key: &'static str) -> Self {
        self.name_key = Some(key);
        self
    }

    /// The signature of a map call from its table.
    fn generated_signature(&self) -> String {
        let options: Vec<String> = self.options.iter().map(OptionSpec::placeholder).collect();
        format!("{}(#{{ {} }})", self.name, options.join(", "))
    }
}

/// Every scene word: calls, the options modules add to them, basis words, material models and
/// output fields.
#[derive(Clone, Default)]
pub struct SceneApi {
    calls: Vec<CallSpec>,
    words: Words,
}

impl SceneApi {
    /// Registers a call.
    pub fn call(&mut self, call: CallSpec) -> &mut Self {
        self.calls.push(call);
        self
    }

    /// Adds an option to the map call `call` (read and documented with it; modules find its
    /// value among the call's options when they resolve, `Resolver::call_options`).
    pub fn extend(&mut self, call: &str, option: OptionSpec) -> &mut Self {
        if let Some(spec) = self
            .calls
            .iter_mut()
            .find(|spec| spec.name == call && matches!(spec.declare, Declare::Options(_)))
        {
            spec.options.push(option);
        }
        self
    }

    /// Adds a word: a basis (`BasisWord`), a refinement of the basis (`BasisRefinement`), a
    /// material model (`ModelSpec`) or a point field (`FieldSpec`).
    pub fn word(&mut self, word: impl Word) -> &mut Self {
        word.add_to(&mut self.words);
        self
    }

    pub fn calls(&self) -> &[CallSpec] {
        &self.calls
    }

    /// The basis words, material models and point fields.
    pub fn words(&self) -> &Words {
        &self.words
    }

    /// Completes the calls once every module registered: the grid's `basis` takes the basis
    /// words, `material` the models and their parameters; signatures are generated.
    pub fn finish(&mut self) {
        let basis: Vec<Choice> = self
            .words
            .basis
            .iter()
            .map(|w| Choice {
                word: w.word,
                meaning: None,
            })
            .collect();
        let models: Vec<Choice> = self
            .words
            .models
            .iter()
            .map(|m| Choice {
                word: m.model,
                meaning: None,
            })
            .collect();
        let mut parameters: Vec<OptionSpec> = Vec::new();
        for parameter in self.words.models.iter().flat_map(|m| &m.parameters) {
            match parameters.iter_mut().find(|p| p.key == parameter.key) {
                None => parameters.push(OptionSpec {
                    required: false,
                    ..parameter.clone()
                }),
                // models that share a number with different ranges (`H`: von Mises hardens
                // only, the frictional models also soften): the table takes any number and
                // each model checks its own range
                Some(shared) => {
                    if let (Kind::Number(a), Kind::Number(b)) = (&shared.kind, &parameter.kind)
                        && a != b
                    {
                        shared.kind = Kind::Number(Range::Any);
                    }
                }
            }
        }
        for call in &mut self.calls {
            for option in &mut call.options {
                match (call.name, option.key) {
                    ("grid", "basis") => option.kind = Kind::Choice(basis.clone()),
                    ("material", "model") => option.kind = Kind::Choice(models.clone()),
                    _ => {}
                }
            }
            if call.name == "material" {
                call.options.extend(parameters.iter().cloned());
            }
            if matches!(call.declare, Declare::Options(_)) {
                call.signature = call.generated_signature();
            }
        }
    }

    /// How `name` is called ("expected ..." hints): its signatures, joined by " or ".
    pub fn expected(&self, name: &str) -> Option<String> {
        let signatures: Vec<&str> = self
            .calls
            .iter()
            .filter(|call| call.name == name)
            .map(|call| call.signature.as_str())
            .collect();
        (!signatures.is_empty()).then(|| signatures.join(" or "))
    }

    /// The reference of every scene word, as markdown (the generated part of
    /// `docs/scene-api.md`).
    pub fn reference(&self) -> String {
        let mut out = String::new();
        out.push_str("| call | meaning |\n|------|---------|\n");
        for call in &self.calls {
            let mut meaning = call.doc.to_string();
            if !call.options.is_empty() {
                let options: Vec<String> = call
                    .options
                    .iter()
                    .map(|option| {
                        let required = if option.required { ", required" } else { "" };
                        format!(
                            "`{}` ({}{required}): {}",
                            option.key,
                            option.describe_kind(),
                            option.doc
                        )
                    })
                    .collect();
                meaning.push_str("<br>Options: ");
                meaning.push_str(&options.join("; "));
            }
            out.push_str(&format!(
                "| `{}` | {} |\n",
                escape_cell(&call.signature),
                escape_cell(&meaning)
            ));
        }
        out.push_str("\n**Bases** (`grid(#{ basis: .. })`):\n\n| basis | method |\n|---|---|\n");
        for word in &self.words.basis {
            out.push_str(&format!(
                "| `\"{}\"` | {} |\n",
                word.word,
                escape_cell(word.doc)
            ));
        }
        out.push_str(
            "\n**Material models** (`material(#{ model: .., .. })`, with the model's parameters):\n\n| model | parameters | meaning |\n|---|---|---|\n",
        );
        for model in &self.words.models {
            let parameters: Vec<String> = model
                .parameters
                .iter()
                .map(|p| format!("`{}` ({}): {}", p.key, p.describe_kind(), p.doc))
                .collect();
            out.push_str(&format!(
                "| `\"{}\"` | {} | {} |\n",
                model.model,
                escape_cell(&parameters.join("; ")),
                escape_cell(model.doc)
            ));
        }
        out.push_str("\n**Point fields** of `particles_NNNN.vtu` (`output(#{ fields: [..] })` may name them):\n\n| field | meaning |\n|---|---|\n");
        for field in &self.words.fields {
            out.push_str(&format!(
                "| `{}` | {} |\n",
                field.name,
                escape_cell(field.doc)
            ));
        }
        out
    }
}

/// A markdown table cell: `|` escaped.
fn escape_cell(text: &str) -> String {
    text.replace('|', "\\|")
}
