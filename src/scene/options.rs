//! Reading the arguments of scene API calls: one reader for every `#{ ... }` options map,
//! driven by the call's table of [`OptionSpec`]s (known keys with "did you mean", required keys,
//! kinds, ranges, choices), and the converters of single values (numbers — integers and floats
//! alike —, whole numbers, arrays, strings, functions) that positional arguments use too.
//! Every message says what was expected and what was given.

use rhai::{Dynamic, FnPtr, Map};

pub use crate::parameter::Range;
use crate::parameter::{ParameterKind, ParameterSpec};

/// One option of a `#{ ... }` map: its key, what it takes, whether it must be given, and what
/// it means. The registry documents and reads every map through these descriptions.
#[derive(Clone, Debug)]
pub struct OptionSpec {
    pub key: &'static str,
    pub kind: Kind,
    pub required: bool,
    /// What the option means (the reference table).
    pub doc: &'static str,
    /// How messages name it ("Young's modulus E"); default `option 'key'`.
    pub label: Option<&'static str>,
}

/// What an option takes.
#[derive(Clone, Debug)]
pub enum Kind {
    /// A finite number (integers accepted) in a range.
    Number(Range),
    /// A whole number `>= min` (and `<= max`).
    Whole { min: usize, max: Option<usize> },
    /// A whole number, or one per axis.
    WholeOrWholes { min: usize },
    /// One of the listed words.
    Choice(Vec<Choice>),
    /// Any string.
    Text,
    /// An array of finite numbers.
    Numbers,
    /// An array of whole numbers `>= min`.
    Wholes { min: usize },
    /// An array of points (arrays of numbers).
    Points,
    /// true or false.
    Flag,
    /// Anything; the call checks it (a region, a material, a function): `what` for the docs.
    Value { what: &'static str },
}

/// An allowed word of a [`Kind::Choice`] and, for messages that explain it, its meaning.
#[derive(Clone, Debug)]
pub struct Choice {
    pub word: &'static str,
    pub meaning: Option<&'static str>,
}

impl From<&ParameterSpec> for OptionSpec {
    /// A model parameter as an option of `material(#{ .. })`.
    fn from(parameter: &ParameterSpec) -> Self {
        let kind = match parameter.kind {
            ParameterKind::Number(range) => Kind::Number(range),
            ParameterKind::Word(words) => Kind::Choice(
                words
                    .iter()
                    .map(|&word| Choice {
                        word,
                        meaning: None,
                    })
                    .collect(),
            ),
            ParameterKind::Flag => Kind::Flag,
        };
        Self {
            key: parameter.name,
            kind,
            required: parameter.required,
            doc: parameter.meaning,
            label: parameter.label,
        }
    }
}

impl OptionSpec {
    /// An optional option.
    pub fn new(key: &'static str, kind: Kind, doc: &'static str) -> Self {
        Self {
            key,
            kind,
            required: false,
            doc,
            label: None,
        }
    }

    /// A required option.
    pub fn required(key: &'static str, kind: Kind, doc: &'static str) -> Self {
        Self {
            required: true,
            ..Self::new(key, kind, doc)
        }
    }

    /// Names the option in messages by `label` instead of `option 'key'`.
    pub fn labelled(mut self, label: &'static str) -> Self {
        self.label = Some(label);
        self
    }

    /// How the option reads in a call's signature: `lower: [..]`, `basis: "a" | "b"`.
    pub fn placeholder(&self) -> String {
        let value = match &self.kind {
            Kind::Number(_) => "..".to_string(),
            Kind::Whole { .. } => "n".to_string(),
            Kind::WholeOrWholes { .. } => "n or [n0, ..]".to_string(),
            Kind::Choice(choices) => choices
                .iter()
                .map(|c| format!("\"{}\"", c.word))
                .collect::<Vec<_>>()
                .join(" | "),
            Kind::Text => "\"..\"".to_string(),
            Kind::Numbers | Kind::Wholes { .. } => "[..]".to_string(),
            Kind::Points => "[[..], ..]".to_string(),
            Kind::Flag => "true | false".to_string(),
            Kind::Value { what } => what.to_string(),
        };
        format!("{}: {value}", self.key)
    }

    /// What the option takes, in words (the reference table).
    pub fn describe_kind(&self) -> String {
        match &self.kind {
            Kind::Number(range) => range.describe(),
            Kind::Whole { min, max } => match max {
                Some(max) => format!("whole number {min}..{max}"),
                None => format!("whole number >= {min}"),
            },
            Kind::WholeOrWholes { min } => format!("whole number >= {min}, or one per axis"),
            Kind::Choice(choices) => choices
                .iter()
                .map(|c| format!("`\"{}\"`", c.word))
                .collect::<Vec<_>>()
                .join(", "),
            Kind::Text => "string".to_string(),
            Kind::Numbers => "array of numbers".to_string(),
            Kind::Wholes { min } => format!("array of whole numbers >= {min}"),
            Kind::Points => "array of points".to_string(),
            Kind::Flag => "true or false".to_string(),
            Kind::Value { what } => what.to_string(),
        }
    }
}

/// A value read from an options map, converted as its [`Kind`] says.
#[derive(Clone, Debug)]
pub enum OptionValue {
    Number(f64),
    Whole(usize),
    Wholes(Vec<usize>),
    Text(String),
    Numbers(Vec<f64>),
    Points(Vec<Vec<f64>>),
    Flag(bool),
    Value(Dynamic),
}

/// The options of one call, read and checked against the call's table.
#[derive(Clone, Debug)]
pub struct Options {
    /// `grid(...)` or `material 'soil'`: how messages name the call.
    pub subject: String,
    values: Vec<(&'static str, OptionValue)>,
}

impl Options {
    /// Reads the map `value` of call `call` against `table`: every key known ("did you
    /// mean"), required keys present, every value of its kind and in its range. The subject of
    /// messages is `call(...)`, or `call 'NAME'` when `name_key` names a text option given.
    pub fn read(
        call: &str,
        value: &Dynamic,
        table: &[OptionSpec],
        name_key: Option<&str>,
    ) -> Result<Self, String> {
        let value = value.flatten_clone();
        if !value.is_map() {
            return Err(format!(
                "{call}(...) expects an options map #{{ {} }}, got {}",
                table
                    .iter()
                    .map(|option| format!("{}: ..", option.key))
                    .collect::<Vec<_>>()
                    .join(", "),
                describe(&value)
            ));
        }
        let entries = value.cast::<Map>();
        let keys: Vec<&str> = table.iter().map(|option| option.key).collect();
        for key in entries.keys() {
            if !keys.contains(&key.as_str()) {
                let suggestion = closest(key, &keys)
                    .map(|close| format!(" (did you mean '{close}'?)"))
                    .unwrap_or_default();
                return Err(format!(
                    "{call}(...): unknown option '{key}'{suggestion}; allowed options are: {}",
                    keys.join(", ")
                ));
            }
        }
        let mut subject = format!("{call}(...)");
        if let Some(name) = name_key
            .and_then(|key| entries.get(key))
            .filter(|name| name.is_string())
        {
            subject = format!("{call} '{name}'");
        }
        let mut values = Vec::new();
        for option in table {
            match entries.get(option.key) {
                Some(given) => {
                    let read = read_value(&subject, call, option, given)?;
                    values.push((option.key, read));
                }
                None if option.required => {
                    return Err(format!(
                        "{call}(...): missing option '{}' (options: {})",
                        option.key,
                        keys.join(", ")
                    ));
                }
                None => {}
            }
        }
        Ok(Self { subject, values })
    }

    /// Whether the option was given.
    pub fn has(&self, key: &str) -> bool {
        self.get(key).is_some()
    }

    pub fn get(&self, key: &str) -> Option<&OptionValue> {
        self.values.iter().find(|(k, _)| *k == key).map(|(_, v)| v)
    }

    pub fn number(&self, key: &str) -> Option<f64> {
        match self.get(key)? {
            OptionValue::Number(x) => Some(*x),
            _ => None,
        }
    }

    pub fn whole(&self, key: &str) -> Option<usize> {
        match self.get(key)? {
            OptionValue::Whole(n) => Some(*n),
            _ => None,
        }
    }

    pub fn wholes(&self, key: &str) -> Option<&[usize]> {
        match self.get(key)? {
            OptionValue::Wholes(n) => Some(n),
            _ => None,
        }
    }

    pub fn text(&self, key: &str) -> Option<&str> {
        match self.get(key)? {
            OptionValue::Text(t) => Some(t),
            _ => None,
        }
    }

    pub fn numbers(&self, key: &str) -> Option<&[f64]> {
        match self.get(key)? {
            OptionValue::Numbers(n) => Some(n),
            _ => None,
        }
    }

    pub fn points(&self, key: &str) -> Option<&[Vec<f64>]> {
        match self.get(key)? {
            OptionValue::Points(p) => Some(p),
            _ => None,
        }
    }

    pub fn flag(&self, key: &str) -> Option<bool> {
        match self.get(key)? {
            OptionValue::Flag(b) => Some(*b),
            _ => None,
        }
    }

    pub fn value(&self, key: &str) -> Option<&Dynamic> {
        match self.get(key)? {
            OptionValue::Value(v) => Some(v),
            _ => None,
        }
    }

    /// The values as they were read, in table order.
    pub fn entries(&self) -> &[(&'static str, OptionValue)] {
        &self.values
    }

    /// `call(...): option 'key'`, the subject of messages about one option.
    pub fn subject_of(&self, key: &str) -> String {
        format!("{}: option '{key}'", self.subject)
    }
}

/// One value of an options map, checked against its description.
fn read_value(
    subject: &str,
    call: &str,
    option: &OptionSpec,
    given: &Dynamic,
) -> Result<OptionValue, String> {
    let key = option.key;
    let named = match option.label {
        Some(label) => format!("{subject}: {label}"),
        None => format!("{call}(...): option '{key}'"),
    };
    Ok(match &option.kind {
        Kind::Number(range) => {
            let x = number(given, &named)?;
            if !range.contains(x) {
                return Err(format!("{named} must {}, got {x}", range.rule(key)));
            }
            OptionValue::Number(x)
        }
        Kind::Whole { min, max } => {
            let n = whole_number(given, &named, *min)?;
            if let Some(max) = max
                && n > *max
            {
                return Err(format!("{named} must be at most {max}, got {n}"));
            }
            OptionValue::Whole(n)
        }
        Kind::WholeOrWholes { min } => {
            if given.is_array() {
                OptionValue::Wholes(whole_numbers(given, &named, *min)?)
            } else {
                OptionValue::Whole(whole_number(given, &named, *min)?)
            }
        }
        Kind::Choice(choices) => {
            let word = string(given, &named)?;
            if !choices.iter().any(|c| c.word == word) {
                let listed: Vec<String> = choices
                    .iter()
                    .map(|c| match c.meaning {
                        Some(meaning) => format!("\"{}\" ({meaning})", c.word),
                        None => format!("\"{}\"", c.word),
                    })
                    .collect();
                let listed = match listed.split_last() {
                    Some((last, [])) => last.clone(),
                    Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
                    None => String::new(),
                };
                return Err(format!("{named} must be {listed}, got {word:?}"));
            }
            OptionValue::Text(word)
        }
        Kind::Text => OptionValue::Text(string(given, &named)?),
        Kind::Numbers => OptionValue::Numbers(numbers(given, &named)?),
        Kind::Wholes { min } => OptionValue::Wholes(whole_numbers(given, &named, *min)?),
        Kind::Points => OptionValue::Points(array_of(
            given,
            &named,
            "points like [[0.0, 1.0], [2.0, 1.0]]",
            numbers,
        )?),
        Kind::Flag => OptionValue::Flag(
            given
                .as_bool()
                .map_err(|_| format!("{named} must be true or false, got {}", describe(given)))?,
        ),
        Kind::Value { .. } => OptionValue::Value(given.flatten_clone()),
    })
}

/// A short description of a value for error messages: `integer 3`, `string "abc"`, ...
pub fn describe(value: &Dynamic) -> String {
    let value = value.flatten_clone();
    let kind = if value.is_int() {
        "integer"
    } else if value.is_float() {
        "float"
    } else if value.is_bool() {
        "boolean"
    } else if value.is_string() {
        return format!("string {:?}", value.to_string());
    } else if value.is_array() {
        "array"
    } else if value.is_map() {
        "map"
    } else if value.is_fnptr() {
        return "a function".to_string();
    } else if value.is_unit() {
        return "() (nothing)".to_string();
    } else {
        return format!("a value of type {}", value.type_name());
    };
    let mut text = value.to_string();
    if text.len() > 60 {
        let cut = (0..=60)
            .rev()
            .find(|&index| text.is_char_boundary(index))
            .unwrap_or(0);
        text.truncate(cut);
        text.push_str("...");
    }
    format!("{kind} {text}")
}

/// A finite number; integers and floats are both accepted.
pub fn number(value: &Dynamic, subject: &str) -> Result<f64, String> {
    let value = value.flatten_clone();
    let number = if let Ok(integer) = value.as_int() {
        integer as f64
    } else if let Ok(float) = value.as_float() {
        float
    } else {
        return Err(format!(
            "{subject} must be a number, got {}",
            describe(&value)
        ));
    };
    if !number.is_finite() {
        return Err(format!("{subject} must be finite, got {number}"));
    }
    Ok(number)
}

/// A whole number >= `minimum` (a float with an integral value is accepted).
pub fn whole_number(value: &Dynamic, subject: &str, minimum: usize) -> Result<usize, String> {
    let value = value.flatten_clone();
    let expected = || {
        format!(
            "{subject} must be a whole number >= {minimum}, got {}",
            describe(&value)
        )
    };
    let whole = if let Ok(integer) = value.as_int() {
        usize::try_from(integer).map_err(|_| expected())?
    } else if let Ok(float) = value.as_float() {
        if float.fract() != 0.0 || !(0.0..=u32::MAX as f64).contains(&float) {
            return Err(expected());
        }
        float as usize
    } else {
        return Err(expected());
    };
    if whole < minimum {
        return Err(expected());
    }
    Ok(whole)
}

/// A non-empty array of elements converted by `element`.
pub fn array_of<T>(
    value: &Dynamic,
    subject: &str,
    expected: &str,
    mut element: impl FnMut(&Dynamic, &str) -> Result<T, String>,
) -> Result<Vec<T>, String> {
    let value = value.flatten_clone();
    if !value.is_array() {
        return Err(format!(
            "{subject} must be an array of {expected}, got {}",
            describe(&value)
        ));
    }
    let items = value.cast::<rhai::Array>();
    items
        .iter()
        .enumerate()
        .map(|(index, item)| element(item, &format!("{subject}[{index}]")))
        .collect()
}

/// An array of finite numbers.
pub fn numbers(value: &Dynamic, subject: &str) -> Result<Vec<f64>, String> {
    array_of(value, subject, "numbers like [0.0, 1.5]", number)
}

/// An array of whole numbers >= `minimum`.
pub fn whole_numbers(value: &Dynamic, subject: &str, minimum: usize) -> Result<Vec<usize>, String> {
    array_of(
        value,
        subject,
        "whole numbers like [0, 1]",
        |item, item_subject| whole_number(item, item_subject, minimum),
    )
}

pub fn string(value: &Dynamic, subject: &str) -> Result<String, String> {
    let value = value.flatten_clone();
    if value.is_string() {
        Ok(value.to_string())
    } else {
        Err(format!(
            "{subject} must be a string, got {}",
            describe(&value)
        ))
    }
}

pub fn function(value: &Dynamic, subject: &str) -> Result<FnPtr, String> {
    let value = value.flatten_clone();
    if value.is_fnptr() {
        Ok(value.cast::<FnPtr>())
    } else {
        Err(format!(
            "{subject} must be a function of the position like |x| x[0] < 1.0, got {}",
            describe(&value)
        ))
    }
}

/// The allowed key closest to a misspelt one (edit distance at most 2).
fn closest<'a>(key: &str, allowed: &[&'a str]) -> Option<&'a str> {
    allowed
        .iter()
        .map(|candidate| (edit_distance(key, candidate), *candidate))
        .filter(|(distance, _)| *distance <= 2)
        .min_by_key(|(distance, _)| *distance)
        .map(|(_, candidate)| candidate)
}

fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut previous: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut current = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            let substitution = previous[j] + usize::from(ca != *cb);
            current[j + 1] = substitution.min(previous[j + 1] + 1).min(current[j] + 1);
        }
        previous = current;
    }
    previous[b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_accept_ints_and_floats() {
        assert_eq!(number(&Dynamic::from_int(3), "x"), Ok(3.0));
        assert_eq!(number(&Dynamic::from_float(2.5), "x"), Ok(2.5));
        assert!(
            number(&Dynamic::from("a"), "x")
                .unwrap_err()
                .contains("must be a number, got string \"a\"")
        );
        assert!(
            number(&Dynamic::from_float(f64::NAN), "x")
                .unwrap_err()
                .contains("finite")
        );
    }

    #[test]
    fn whole_numbers_reject_fractions_and_negatives() {
        assert_eq!(whole_number(&Dynamic::from_float(4.0), "n", 1), Ok(4));
        assert!(whole_number(&Dynamic::from_float(4.5), "n", 1).is_err());
        assert!(whole_number(&Dynamic::from_int(-1), "n", 0).is_err());
        let error = whole_number(&Dynamic::from_int(0), "n", 1).unwrap_err();
        assert_eq!(error, "n must be a whole number >= 1, got integer 0");
    }

    fn table() -> Vec<OptionSpec> {
        vec![
            OptionSpec::required("cells", Kind::Wholes { min: 1 }, ""),
            OptionSpec::new(
                "basis",
                Kind::Choice(vec![
                    Choice {
                        word: "linear",
                        meaning: None,
                    },
                    Choice {
                        word: "bspline",
                        meaning: None,
                    },
                ]),
                "",
            ),
            OptionSpec::new("E", Kind::Number(Range::Positive), "").labelled("Young's modulus E"),
            OptionSpec::new("nu", Kind::Number(Range::Open(-1.0, 0.5)), ""),
            OptionSpec::new(
                "per_cell",
                Kind::Whole {
                    min: 1,
                    max: Some(10),
                },
                "",
            ),
            OptionSpec::new("name", Kind::Text, ""),
        ]
    }

    fn read(entries: &[(&str, Dynamic)]) -> Result<Options, String> {
        let mut map = Map::new();
        for (key, value) in entries {
            map.insert((*key).into(), value.clone());
        }
        Options::read("grid", &Dynamic::from_map(map), &table(), Some("name"))
    }

    #[test]
    fn unknown_keys_are_named_with_the_allowed_ones() {
        let error = read(&[("cels", Dynamic::from_int(1))]).unwrap_err();
        assert_eq!(
            error,
            "grid(...): unknown option 'cels' (did you mean 'cells'?); allowed options are: cells, basis, E, nu, per_cell, name"
        );
    }

    #[test]
    fn the_table_checks_presence_kinds_ranges_and_choices() {
        let cells = || ("cells", Dynamic::from_array(vec![Dynamic::from_int(2)]));
        assert!(read(&[]).unwrap_err().contains("missing option 'cells'"));
        let options = read(&[cells(), ("E", Dynamic::from_int(5))]).unwrap();
        assert_eq!(options.wholes("cells"), Some(&[2][..]));
        assert_eq!(options.number("E"), Some(5.0));
        assert!(!options.has("basis"));
        let error = read(&[cells(), ("E", Dynamic::from_float(-1.0))]).unwrap_err();
        assert_eq!(
            error,
            "grid(...): Young's modulus E must be positive, got -1"
        );
        let error =
            read(&[cells(), ("name", "x".into()), ("E", Dynamic::from_int(0))]).unwrap_err();
        assert_eq!(error, "grid 'x': Young's modulus E must be positive, got 0");
        let error = read(&[cells(), ("nu", Dynamic::from_float(0.5))]).unwrap_err();
        assert_eq!(
            error,
            "grid(...): option 'nu' must satisfy -1 < nu < 0.5, got 0.5"
        );
        let error = read(&[cells(), ("basis", "spline".into())]).unwrap_err();
        assert_eq!(
            error,
            "grid(...): option 'basis' must be \"linear\" or \"bspline\", got \"spline\""
        );
        let error = read(&[cells(), ("per_cell", Dynamic::from_int(11))]).unwrap_err();
        assert_eq!(
            error,
            "grid(...): option 'per_cell' must be at most 10, got 11"
        );
        let error = read(&[("cells", Dynamic::from_int(2))]).unwrap_err();
        assert!(
            error.contains("'cells' must be an array of whole numbers"),
            "{error}"
        );
    }
}
