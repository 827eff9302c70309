//! Describing a parameter: what it takes and where a number must lie. Pure data, shared by the
//! scene's option tables (`scene::OptionSpec`) and the materials' parameter lists
//! (`material::Material::parameters`).

/// Where a number must lie.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Range {
    Any,
    Positive,
    NonNegative,
    /// `lower < x < upper`.
    Open(f64, f64),
    /// `lower <= x <= upper`.
    Closed(f64, f64),
    /// `lower <= x < upper` (an angle from 0 up to, not including, 90 degrees).
    ClosedOpen(f64, f64),
}

impl Range {
    pub fn contains(self, x: f64) -> bool {
        match self {
            Range::Any => true,
            Range::Positive => x > 0.0,
            Range::NonNegative => x >= 0.0,
            Range::Open(lo, hi) => lo < x && x < hi,
            Range::Closed(lo, hi) => lo <= x && x <= hi,
            Range::ClosedOpen(lo, hi) => lo <= x && x < hi,
        }
    }

    /// What a value named `key` must do: "be positive", "satisfy -1 < nu < 0.5".
    pub fn rule(self, key: &str) -> String {
        match self {
            Range::Any => "be a number".to_string(),
            Range::Positive => "be positive".to_string(),
            Range::NonNegative => "be zero or positive".to_string(),
            Range::Open(lo, hi) => format!("satisfy {lo} < {key} < {hi}"),
            Range::Closed(lo, hi) => format!("satisfy {lo} <= {key} <= {hi}"),
            Range::ClosedOpen(lo, hi) => format!("satisfy {lo} <= {key} < {hi}"),
        }
    }

    /// The range in words, for references: "number > 0".
    pub fn describe(self) -> String {
        match self {
            Range::Any => "number".to_string(),
            Range::Positive => "number > 0".to_string(),
            Range::NonNegative => "number >= 0".to_string(),
            Range::Open(lo, hi) => format!("{lo} < number < {hi}"),
            Range::Closed(lo, hi) => format!("{lo} <= number <= {hi}"),
            Range::ClosedOpen(lo, hi) => format!("{lo} <= number < {hi}"),
        }
    }
}

/// What a parameter takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ParameterKind {
    Number(Range),
    /// One of the words.
    Word(&'static [&'static str]),
    Flag,
}

/// A parameter of a model: its name, meaning, how messages name it, what it takes, and
/// whether it must be given.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParameterSpec {
    pub name: &'static str,
    pub meaning: &'static str,
    /// How messages name it ("Young's modulus E"); default the name.
    pub label: Option<&'static str>,
    pub kind: ParameterKind,
    pub required: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_hold_what_they_say_and_say_it() {
        assert!(Range::Positive.contains(1e-300) && !Range::Positive.contains(0.0));
        assert!(Range::NonNegative.contains(0.0) && !Range::NonNegative.contains(-1e-300));
        assert!(Range::Open(-1.0, 0.5).contains(0.49) && !Range::Open(-1.0, 0.5).contains(0.5));
        assert!(Range::Closed(0.0, 90.0).contains(90.0));
        assert!(Range::ClosedOpen(0.0, 90.0).contains(0.0));
        assert!(!Range::ClosedOpen(0.0, 90.0).contains(90.0));
        assert_eq!(
            Range::ClosedOpen(0.0, 90.0).rule("phi"),
            "satisfy 0 <= phi < 90"
        );
        assert_eq!(Range::Open(-1.0, 0.5).rule("nu"), "satisfy -1 < nu < 0.5");
        assert_eq!(Range::Positive.describe(), "number > 0");
    }
}
