//! Errors of the scene front end, located in the user's script (`file:line:column: message`).

use std::fmt;

use rhai::{EvalAltResult, ParseError, ParseErrorType, Position};

/// Something is wrong with a scene script or its `--set` overrides.
///
/// Displayed as `file:line:column: message` (line and column when known, 1-based), so editors
/// and terminals can jump to the offending spot.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneError {
    /// The script path as given by the user.
    pub file: String,
    pub line: Option<usize>,
    pub column: Option<usize>,
    pub message: String,
}

impl SceneError {
    /// An error about the script as a whole (no position).
    pub fn whole_file(file: &str, message: impl Into<String>) -> Self {
        Self {
            file: file.to_string(),
            line: None,
            column: None,
            message: message.into(),
        }
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
            if let Some(column) = self.column {
                write!(f, ":{column}")?;
            }
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for SceneError {}

/// An error at a position of the script, before the file name is attached.
#[derive(Clone, Debug, PartialEq)]
pub struct ScriptError {
    pub position: Position,
    pub message: String,
}

impl ScriptError {
    pub fn at(position: Position, message: impl Into<String>) -> Self {
        Self {
            position,
            message: message.into(),
        }
    }

    /// No position: the error concerns the scene as a whole.
    pub fn unlocated(message: impl Into<String>) -> Self {
        Self::at(Position::NONE, message)
    }

    /// Converts a Rhai parse error (syntax error).
    pub fn from_parse(error: &ParseError) -> Self {
        let message = match error.err_type() {
            ParseErrorType::VariableUndefined(name) => {
                format!("undefined variable '{name}' (declare it with let or const before its use)")
            }
            other => format!("syntax error: {other}"),
        };
        Self::at(error.position(), message)
    }

    /// Converts a Rhai runtime error. Errors raised inside a script function or closure are
    /// wrapped (`ErrorInFunctionCall`) with the position of the *call*; this walks to the
    /// innermost error so the message points at the line that actually failed.
    pub fn from_eval(error: Box<EvalAltResult>) -> Self {
        Self::from_eval_with(error, &|_| None)
    }

    /// [`ScriptError::from_eval`] that says how a scene call is called when it was called with
    /// the wrong arguments (`expected(name)`: its signatures).
    pub fn from_eval_with(
        error: Box<EvalAltResult>,
        expected: &dyn Fn(&str) -> Option<String>,
    ) -> Self {
        let mut outer_position = Position::NONE;
        let mut called_functions = Vec::new();
        let mut error = error;
        loop {
            match *error {
                EvalAltResult::ErrorInFunctionCall(name, _, inner, position) => {
                    if !position.is_none() {
                        outer_position = position;
                    }
                    if !name.starts_with("anon$") {
                        called_functions.push((name, position));
                    }
                    error = inner;
                }
                EvalAltResult::ErrorInModule(_, inner, position) => {
                    if !position.is_none() {
                        outer_position = position;
                    }
                    error = inner;
                }
                _ => break,
            }
        }
        let mut innermost = error;
        let mut position = innermost.take_position();
        if position.is_none() {
            position = outer_position;
        }
        let mut message = match *innermost {
            EvalAltResult::ErrorRuntime(ref value, _) if value.is_string() => value.to_string(),
            EvalAltResult::ErrorFunctionNotFound(ref signature, _) => {
                function_not_found_message(signature, expected)
            }
            ref other => limit_message(other).unwrap_or_else(|| other.to_string()),
        };
        for (name, call) in called_functions.iter().rev() {
            match call.line() {
                Some(line) => {
                    message.push_str(&format!(" (in function '{name}' called at line {line})"))
                }
                None => message.push_str(&format!(" (in function '{name}')")),
            }
        }
        Self::at(position, message)
    }

    /// Adds context to the message, e.g. which API call a closure was given to.
    pub fn with_context(mut self, context: &str) -> Self {
        self.message = format!("{} ({context})", self.message);
        self
    }

    pub fn in_file(self, file: &str) -> SceneError {
        SceneError {
            file: file.to_string(),
            line: self.position.line(),
            column: self.position.position(),
            message: self.message,
        }
    }
}

/// What a script that hit one of the engine's limits (`scene::SceneLimits`) is told.
fn limit_message(error: &EvalAltResult) -> Option<String> {
    Some(match error {
        EvalAltResult::ErrorTooManyOperations(_) => "the script hit the limit on operations (an endless loop?); if the scene really needs more, raise it with --limit operations=N".to_string(),
        EvalAltResult::ErrorDataTooLarge(what, _) => {
            let name = if what.contains("rray") {
                "array"
            } else if what.contains("ap") {
                "map"
            } else {
                "string"
            };
            format!("{what} grew beyond the limit on its size (a runaway loop?); --limit {name}=N raises it")
        }
        EvalAltResult::ErrorTerminated(value, _) if value.to_string() == super::limits::TIME_LIMIT => {
            "the scene took longer than the limit on its evaluation time (an endless loop, or a computation too long for a scene?); --limit seconds=N raises it".to_string()
        }
        EvalAltResult::ErrorStackOverflow(_) => "script functions nest deeper than the limit on calls (endless recursion?); --limit depth=N raises it".to_string(),
        _ => return None,
    })
}

/// "Function not found" with the expected call form when the name is one of the scene API's.
fn function_not_found_message(
    signature: &str,
    expected: &dyn Fn(&str) -> Option<String>,
) -> String {
    let name = signature.split([' ', '(']).next().unwrap_or_default();
    match expected(name) {
        Some(expected) => format!("wrong arguments in call {signature}; expected {expected}"),
        None => format!("function not found: {signature}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_with_and_without_position() {
        let mut error = SceneError::whole_file("scripts/x.rhai", "no grid");
        assert_eq!(error.to_string(), "scripts/x.rhai: no grid");
        error.line = Some(12);
        assert_eq!(error.to_string(), "scripts/x.rhai:12: no grid");
        error.column = Some(5);
        assert_eq!(error.to_string(), "scripts/x.rhai:12:5: no grid");
    }

    #[test]
    fn runtime_error_in_closure_points_inside_the_closure() {
        let engine = rhai::Engine::new();
        let script = "let f = |x| {\n  x[5]\n};\nf.call([1])";
        let error = engine.eval::<rhai::Dynamic>(script).unwrap_err();
        let located = ScriptError::from_eval(error).in_file("t.rhai");
        assert_eq!(located.line, Some(2), "{located}");
        assert!(located.message.contains("out of bounds"), "{located}");
    }
}
