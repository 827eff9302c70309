//! Reading the arguments of scene API calls: option maps with a fixed set of keys, numbers
//! (integers and floats alike), whole numbers, vectors and strings, with messages that say what
//! was expected and what was given.

use rhai::{Dynamic, FnPtr, Map};

/// The options map of one API call, e.g. the `#{ ... }` of `grid(#{ ... })`.
pub(crate) struct OptionMap {
    function: &'static str,
    allowed: &'static [&'static str],
    entries: Map,
}

impl OptionMap {
    /// Checks that `value` is a map whose keys are all in `allowed`.
    pub fn new(
        function: &'static str,
        value: Dynamic,
        allowed: &'static [&'static str],
    ) -> Result<Self, String> {
        let value = value.flatten();
        if !value.is_map() {
            return Err(format!(
                "{function}(...) expects an options map #{{ {} }}, got {}",
                allowed
                    .iter()
                    .map(|key| format!("{key}: .."))
                    .collect::<Vec<_>>()
                    .join(", "),
                describe(&value)
            ));
        }
        let entries = value.cast::<Map>();
        for key in entries.keys() {
            if !allowed.contains(&key.as_str()) {
                let suggestion = closest(key, allowed)
                    .map(|close| format!(" (did you mean '{close}'?)"))
                    .unwrap_or_default();
                return Err(format!(
                    "{function}(...): unknown option '{key}'{suggestion}; allowed options are: {}",
                    allowed.join(", ")
                ));
            }
        }
        Ok(Self {
            function,
            allowed,
            entries,
        })
    }

    /// The value of an optional key.
    pub fn optional(&self, key: &str) -> Option<Dynamic> {
        self.entries.get(key).map(Dynamic::flatten_clone)
    }

    /// The value of a required key.
    pub fn required(&self, key: &str) -> Result<Dynamic, String> {
        self.optional(key).ok_or_else(|| {
            format!(
                "{}(...): missing option '{key}' (options: {})",
                self.function,
                self.allowed.join(", ")
            )
        })
    }

    /// `function(...): option 'key'`, the subject of messages about one option.
    pub fn subject(&self, key: &str) -> String {
        format!("{}(...): option '{key}'", self.function)
    }
}

/// A short description of a value for error messages: `integer 3`, `string "abc"`, ...
pub(crate) fn describe(value: &Dynamic) -> String {
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
pub(crate) fn number(value: &Dynamic, subject: &str) -> Result<f64, String> {
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
pub(crate) fn whole_number(
    value: &Dynamic,
    subject: &str,
    minimum: usize,
) -> Result<usize, String> {
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
pub(crate) fn array_of<T>(
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
pub(crate) fn numbers(value: &Dynamic, subject: &str) -> Result<Vec<f64>, String> {
    array_of(value, subject, "numbers like [0.0, 1.5]", number)
}

/// An array of whole numbers >= `minimum`.
pub(crate) fn whole_numbers(
    value: &Dynamic,
    subject: &str,
    minimum: usize,
) -> Result<Vec<usize>, String> {
    array_of(
        value,
        subject,
        "whole numbers like [0, 1]",
        |item, item_subject| whole_number(item, item_subject, minimum),
    )
}

pub(crate) fn string(value: &Dynamic, subject: &str) -> Result<String, String> {
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

pub(crate) fn function(value: &Dynamic, subject: &str) -> Result<FnPtr, String> {
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

    #[test]
    fn unknown_keys_are_named_with_the_allowed_ones() {
        let mut map = Map::new();
        map.insert("cels".into(), Dynamic::from_int(1));
        let error = OptionMap::new("grid", Dynamic::from_map(map), &["cells", "basis"])
            .err()
            .unwrap();
        assert_eq!(
            error,
            "grid(...): unknown option 'cels' (did you mean 'cells'?); allowed options are: cells, basis"
        );
    }
}
