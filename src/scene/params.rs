//! Script parameters: every top-level `let NAME = <expr>;` of a scene script, and `--set
//! NAME=VALUE` overrides that replace its initialiser.
//!
//! # How top-level lets are found
//!
//! Rhai only exposes its statement tree with the `internals` feature, which this crate does not
//! enable, so the script is scanned lexically instead. The scanner understands everything that
//! can hide a `let` or a bracket from a naive search: `//` and nested `/* */` comments, `"..."`
//! strings and `'c'` characters (with `\` escapes), raw strings `#"..."#` (any number of `#`),
//! and back-tick strings including code inside `${ ... }` interpolations. Outside those it
//! tracks the nesting depth of `(`, `[`, `{` and `#{`. A `let` at depth 0 is a top-level
//! statement (`let` is a statement keyword, so it cannot occur inside an expression, and
//! function bodies and blocks are inside braces); `let NAME =` starts a parameter whose
//! initialiser runs up to the next `;` at depth 0 (or the end of the file). Scripts are
//! compiled by Rhai before they are scanned, so the scanner only ever sees valid syntax.
//!
//! If a name is declared by several top-level lets, the first one is the parameter (later ones
//! are ordinary code, e.g. `let cells = cells * 2;`).
//!
//! # Overrides
//!
//! An override replaces the initialiser's source text with a literal: `true`/`false` stay
//! booleans, numbers stay numbers, anything else becomes a string literal. An integer given for
//! a parameter whose default is a float literal becomes a float (`--set body_force=-200` with
//! default `-800.0` gives `-200.0`), since Rhai does not mix integers and floats in arithmetic.
//! The replaced text keeps its line breaks, so every other line of the script keeps its number
//! and errors point at the user's real lines. Later parameters are evaluated by the script
//! itself, so they see overridden earlier ones (`let ppc = if basis == "linear" { 1 } else { 4 };`).

use std::ops::Range;

/// A script parameter: a top-level `let NAME = <default>;`.
#[derive(Clone, Debug, PartialEq)]
pub struct Parameter {
    pub name: String,
    /// Source text of the initialiser (trimmed), e.g. `50`, `"bspline"`, `if basis == ... }`.
    pub default: String,
    /// 1-based line of the `let`.
    pub line: usize,
}

/// A parameter and where its initialiser is in the source.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ParameterSite {
    pub parameter: Parameter,
    /// Byte range of the trimmed initialiser.
    pub initialiser: Range<usize>,
}

/// Finds the top-level `let NAME = <expr>;` statements, in source order (first declaration of
/// each name only).
pub(crate) fn find_parameters(source: &str) -> Vec<ParameterSite> {
    let tokens = Scanner::new(source).top_level_tokens();
    let mut sites: Vec<ParameterSite> = Vec::new();
    let mut index = 0;
    while index < tokens.len() {
        let is_let = tokens[index].depth == 0 && tokens[index].kind == TokenKind::Word("let");
        let declaration = is_let
            .then(|| (tokens.get(index + 1), tokens.get(index + 2)))
            .and_then(|pair| match pair {
                (Some(name), Some(assign)) if assign.kind == TokenKind::Assign => match name.kind {
                    TokenKind::Word(name) => Some((name, assign.span.end)),
                    _ => None,
                },
                _ => None,
            });
        let Some((name, initialiser_start)) = declaration else {
            index += 1;
            continue;
        };
        let mut end_index = index + 3;
        while end_index < tokens.len()
            && !(tokens[end_index].depth == 0 && tokens[end_index].kind == TokenKind::Semicolon)
        {
            end_index += 1;
        }
        let initialiser_end = tokens
            .get(end_index)
            .map_or(source.len(), |token| token.span.start);
        let initialiser = trimmed_range(source, initialiser_start..initialiser_end);
        if !sites.iter().any(|site| site.parameter.name == name) {
            sites.push(ParameterSite {
                parameter: Parameter {
                    name: name.to_string(),
                    default: source[initialiser.clone()].to_string(),
                    line: tokens[index].line,
                },
                initialiser,
            });
        }
        index = end_index + 1;
    }
    sites
}

/// Replaces the initialisers of the overridden parameters. Returns an error message if an
/// override names no parameter, names one twice, or is a number out of the range of a float.
pub(crate) fn apply_overrides(
    source: &str,
    sites: &[ParameterSite],
    overrides: &[(String, String)],
) -> Result<String, String> {
    let mut replacements: Vec<(Range<usize>, String)> = Vec::new();
    for (k, (name, value)) in overrides.iter().enumerate() {
        if let Some((_, first)) = overrides[..k].iter().find(|(other, _)| other == name) {
            return Err(format!(
                "--set {name} is given twice ({first} and {value}): give each parameter once"
            ));
        }
        let trimmed = value.trim();
        if looks_numeric(trimmed) && trimmed.parse::<f64>().is_ok_and(|x| !x.is_finite()) {
            return Err(format!(
                "--set {name}={value}: the number is out of the range of a float (about ±1.8e308)"
            ));
        }
        let Some(site) = sites.iter().find(|site| &site.parameter.name == name) else {
            let known: Vec<&str> = sites
                .iter()
                .map(|site| site.parameter.name.as_str())
                .collect();
            let known = if known.is_empty() {
                "the script has none (parameters are top-level `let NAME = ...;`)".to_string()
            } else {
                format!("the script's parameters are: {}", known.join(", "))
            };
            return Err(format!(
                "--set {name}={value}: there is no parameter '{name}'; {known}"
            ));
        };
        let original = &source[site.initialiser.clone()];
        let mut literal = override_literal(value, &site.parameter.default);
        // keep the line count of the replaced text so later lines keep their numbers
        literal.extend(std::iter::repeat_n('\n', original.matches('\n').count()));
        replacements.push((site.initialiser.clone(), literal));
    }
    replacements.sort_by_key(|(range, _)| range.start);
    let mut result = String::with_capacity(source.len());
    let mut copied_up_to = 0;
    for (range, literal) in replacements {
        result.push_str(&source[copied_up_to..range.start]);
        result.push_str(&literal);
        copied_up_to = range.end;
    }
    result.push_str(&source[copied_up_to..]);
    Ok(result)
}

/// The Rhai literal for an override value: boolean, number (float if the default is a float
/// literal), else string.
pub(crate) fn override_literal(value: &str, default: &str) -> String {
    let trimmed = value.trim();
    if trimmed == "true" || trimmed == "false" {
        return trimmed.to_string();
    }
    if let Ok(integer) = trimmed.parse::<i64>() {
        return if is_float_literal(default) {
            format!("{:?}", integer as f64)
        } else {
            integer.to_string()
        };
    }
    if looks_numeric(trimmed)
        && let Ok(float) = trimmed.parse::<f64>()
        && float.is_finite()
    {
        return format!("{float:?}");
    }
    string_literal(value)
}

/// `-800.0`, `1e6`, `2.5`, `1_000.0` (optionally signed).
fn is_float_literal(text: &str) -> bool {
    let unsigned = text.trim().trim_start_matches(['-', '+']).trim_start();
    let digits = unsigned.replace('_', "");
    looks_numeric(&digits) && digits.contains(['.', 'e', 'E']) && digits.parse::<f64>().is_ok()
}

/// Starts like a number (rules out `inf`, `NaN`, which Rust would parse as floats).
fn looks_numeric(text: &str) -> bool {
    let unsigned = text.trim_start_matches(['-', '+']);
    unsigned.starts_with(|c: char| c.is_ascii_digit() || c == '.')
}

fn string_literal(value: &str) -> String {
    let mut literal = String::with_capacity(value.len() + 2);
    literal.push('"');
    for c in value.chars() {
        match c {
            '"' => literal.push_str("\\\""),
            '\\' => literal.push_str("\\\\"),
            '\n' => literal.push_str("\\n"),
            '\r' => literal.push_str("\\r"),
            '\t' => literal.push_str("\\t"),
            c if c.is_control() => literal.push_str(&format!("\\u{:04x}", c as u32)),
            c => literal.push(c),
        }
    }
    literal.push('"');
    literal
}

fn trimmed_range(source: &str, range: Range<usize>) -> Range<usize> {
    let text = &source[range.clone()];
    let start = range.start + (text.len() - text.trim_start().len());
    let end = range.end - (text.len() - text.trim_end().len());
    start..end.max(start)
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum TokenKind<'a> {
    Word(&'a str),
    /// A single `=` (not `==`, `=>`, `+=`, ...).
    Assign,
    Semicolon,
    Open,
    Close,
    /// Literals, operators, anything else.
    Other,
}

#[derive(Clone, Debug)]
struct Token<'a> {
    kind: TokenKind<'a>,
    span: Range<usize>,
    line: usize,
    /// Bracket depth before an `Open`, after a `Close`: the depth the token sits at.
    depth: usize,
}

/// A lexical scanner over Rhai source, just precise enough to find statement boundaries.
struct Scanner<'a> {
    source: &'a str,
    bytes: &'a [u8],
    position: usize,
    line: usize,
}

impl<'a> Scanner<'a> {
    fn new(source: &'a str) -> Self {
        Self {
            source,
            bytes: source.as_bytes(),
            position: 0,
            line: 1,
        }
    }

    fn peek(&self, offset: usize) -> Option<u8> {
        self.bytes.get(self.position + offset).copied()
    }

    fn advance(&mut self) {
        if self.peek(0) == Some(b'\n') {
            self.line += 1;
        }
        self.position += 1;
    }

    fn advance_by(&mut self, count: usize) {
        for _ in 0..count {
            self.advance();
        }
    }

    /// All tokens of the script (string and comment contents skipped) with their depth.
    fn top_level_tokens(mut self) -> Vec<Token<'a>> {
        let mut tokens = Vec::new();
        let mut depth = 0usize;
        while let Some((kind, span, line)) = self.next_token() {
            let token_depth = match kind {
                TokenKind::Open => {
                    depth += 1;
                    depth - 1
                }
                TokenKind::Close => {
                    depth = depth.saturating_sub(1);
                    depth
                }
                _ => depth,
            };
            tokens.push(Token {
                kind,
                span,
                line,
                depth: token_depth,
            });
        }
        tokens
    }

    /// The next token, skipping whitespace, comments and the insides of literals.
    fn next_token(&mut self) -> Option<(TokenKind<'a>, Range<usize>, usize)> {
        loop {
            let current = self.peek(0)?;
            let start = self.position;
            let line = self.line;
            let kind = match current {
                c if c.is_ascii_whitespace() => {
                    self.advance();
                    continue;
                }
                b'/' if self.peek(1) == Some(b'/') => {
                    while self.peek(0).is_some_and(|c| c != b'\n') {
                        self.advance();
                    }
                    continue;
                }
                b'/' if self.peek(1) == Some(b'*') => {
                    self.skip_block_comment();
                    continue;
                }
                b'"' | b'\'' => {
                    self.skip_quoted(current);
                    TokenKind::Other
                }
                b'`' => {
                    self.skip_backtick_string();
                    TokenKind::Other
                }
                b'#' if self.peek(1) == Some(b'{') => {
                    self.advance_by(2);
                    TokenKind::Open
                }
                b'#' if matches!(self.peek(1), Some(b'"' | b'#')) => {
                    self.skip_raw_string();
                    TokenKind::Other
                }
                b'(' | b'[' | b'{' => {
                    self.advance();
                    TokenKind::Open
                }
                b')' | b']' | b'}' => {
                    self.advance();
                    TokenKind::Close
                }
                b';' => {
                    self.advance();
                    TokenKind::Semicolon
                }
                b'=' => {
                    self.advance();
                    if matches!(self.peek(0), Some(b'=' | b'>')) {
                        self.advance();
                        TokenKind::Other
                    } else {
                        TokenKind::Assign
                    }
                }
                c if c.is_ascii_alphabetic() || c == b'_' => {
                    while self
                        .peek(0)
                        .is_some_and(|c| c.is_ascii_alphanumeric() || c == b'_')
                    {
                        self.advance();
                    }
                    TokenKind::Word(&self.source[start..self.position])
                }
                c if c.is_ascii_digit() => {
                    while self
                        .peek(0)
                        .is_some_and(|c| c.is_ascii_alphanumeric() || c == b'_')
                    {
                        self.advance();
                    }
                    TokenKind::Other
                }
                c if !c.is_ascii() => {
                    // a non-ASCII character (not valid Rhai outside literals): skip it whole
                    let width = self.source[start..]
                        .chars()
                        .next()
                        .map_or(1, char::len_utf8);
                    self.advance_by(width);
                    TokenKind::Other
                }
                _ => {
                    // operators: swallow a trailing '=' so `+=`, `<=`, `!=` are not assignments
                    self.advance();
                    if self.peek(0) == Some(b'=') {
                        self.advance();
                    }
                    TokenKind::Other
                }
            };
            return Some((kind, start..self.position, line));
        }
    }

    /// `/* ... */`, nested like Rhai's.
    fn skip_block_comment(&mut self) {
        let mut level = 0usize;
        while let Some(current) = self.peek(0) {
            if current == b'/' && self.peek(1) == Some(b'*') {
                level += 1;
                self.advance_by(2);
            } else if current == b'*' && self.peek(1) == Some(b'/') {
                level -= 1;
                self.advance_by(2);
                if level == 0 {
                    return;
                }
            } else {
                self.advance();
            }
        }
    }

    /// `"..."` or `'.'` with backslash escapes (a doubled quote, Rhai's escaped quote, reads as
    /// two adjacent strings, which is equivalent here).
    fn skip_quoted(&mut self, quote: u8) {
        self.advance();
        while let Some(current) = self.peek(0) {
            self.advance();
            if current == b'\\' {
                self.advance();
            } else if current == quote {
                return;
            }
        }
    }

    /// `#"..."#`, `##"..."##`, ...: ends at `"` followed by as many `#` as opened it.
    fn skip_raw_string(&mut self) {
        let mut hashes = 0;
        while self.peek(0) == Some(b'#') {
            hashes += 1;
            self.advance();
        }
        if self.peek(0) != Some(b'"') {
            return;
        }
        self.advance();
        while let Some(current) = self.peek(0) {
            self.advance();
            if current == b'"' && (0..hashes).all(|offset| self.peek(offset) == Some(b'#')) {
                self.advance_by(hashes);
                return;
            }
        }
    }

    /// `` `text ${ code } text` ``: the code inside `${ }` is scanned as code (it may hold
    /// strings and braces of its own). Back-tick strings are verbatim: a backslash only
    /// escapes a following `$`, and a doubled back-tick reads as two adjacent strings, which
    /// is equivalent for finding statement boundaries.
    fn skip_backtick_string(&mut self) {
        self.advance();
        while let Some(current) = self.peek(0) {
            if current == b'\\' && self.peek(1) == Some(b'$') {
                // `\${` is an escaped `$`, not an interpolation; other backslashes are literal
                self.advance_by(2);
            } else if current == b'`' {
                self.advance();
                return;
            } else if current == b'$' && self.peek(1) == Some(b'{') {
                self.advance_by(2);
                let mut depth = 0usize;
                while let Some((kind, ..)) = self.next_token() {
                    match kind {
                        TokenKind::Open => depth += 1,
                        TokenKind::Close if depth == 0 => break,
                        TokenKind::Close => depth -= 1,
                        _ => {}
                    }
                }
            } else {
                self.advance();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(source: &str) -> Vec<(String, String, usize)> {
        find_parameters(source)
            .into_iter()
            .map(|site| {
                (
                    site.parameter.name,
                    site.parameter.default,
                    site.parameter.line,
                )
            })
            .collect()
    }

    /// Everything that can hide a `let` or a bracket from a naive search (valid Rhai).
    const TRICKY: &str = r##"// let commented = 1;
/* outer /* nested let inner = 2; */ still comment let x = 3; */
let cells = 50;
let basis = "let fake = 1; \" { [";
let label = `${ if true { "}" } else { "{" } } let b = 2;`;
let raw = #"let c = "3"; {"#;
let ch = '{';
fn helper(a) { let local = a; local }
if cells > 0 { let block = 1; }
let closure = |x| { let inner = x; inner };
let multi = if basis == "linear" {
    1
} else {
    4
};
let map = #{ a: 1, b: [2, 3] };
let cells = cells * 2;
let path = `C:\dir\` + "é";
let last = 5"##;

    #[test]
    fn finds_only_top_level_lets() {
        let found = names(TRICKY);
        let expected_names = [
            "cells", "basis", "label", "raw", "ch", "closure", "multi", "map", "path", "last",
        ];
        assert_eq!(
            found
                .iter()
                .map(|(name, ..)| name.as_str())
                .collect::<Vec<_>>(),
            expected_names
        );
        assert_eq!(found[0], ("cells".into(), "50".into(), 3));
        assert_eq!(found[1].1, r#""let fake = 1; \" { [""#);
        assert_eq!(
            found[6].1,
            "if basis == \"linear\" {\n    1\n} else {\n    4\n}"
        );
        assert_eq!(found[6].2, 11);
        assert_eq!(found[8].1, "`C:\\dir\\` + \"é\"");
        assert_eq!(found[9], ("last".into(), "5".into(), 19));
    }

    #[test]
    fn the_scanner_agrees_with_rhai() {
        // the scanner's parameters are exactly Rhai's top-level variables (first declarations)
        let engine = rhai::Engine::new();
        for source in [
            TRICKY,
            "let a = 1; let b = `x${a}y`; let c = a + 2; { let d = 4; } let e = [a, b];",
        ] {
            let mut scope = rhai::Scope::new();
            engine.run_with_scope(&mut scope, source).unwrap();
            let mut in_scope: Vec<String> = Vec::new();
            for (name, ..) in scope.iter() {
                if !in_scope.iter().any(|seen| seen == name) {
                    in_scope.push(name.to_string());
                }
            }
            let found: Vec<String> = names(source).into_iter().map(|(name, ..)| name).collect();
            assert_eq!(found, in_scope);
        }
    }

    #[test]
    fn override_literals() {
        assert_eq!(override_literal("100", "50"), "100");
        assert_eq!(override_literal("-200", "-800.0"), "-200.0");
        assert_eq!(override_literal("-200", "1e3"), "-200.0");
        assert_eq!(override_literal("2.5", "1"), "2.5");
        assert_eq!(override_literal("1e-7", "1.0").parse::<f64>(), Ok(1e-7));
        assert_eq!(override_literal("true", "false"), "true");
        assert_eq!(override_literal("bspline", "\"linear\""), "\"bspline\"");
        assert_eq!(override_literal("inf", "1.0"), "\"inf\"");
        assert_eq!(override_literal("a \"q\" \\", "\"\""), r#""a \"q\" \\""#);
        let engine = rhai::Engine::new();
        for (value, default) in [
            ("-200", "-800.0"),
            ("1e-7", "1.0"),
            ("a \"q\" \\\n", "\"\""),
        ] {
            let literal = override_literal(value, default);
            let evaluated = engine.eval::<rhai::Dynamic>(&literal).unwrap();
            match value.parse::<f64>() {
                Ok(number) => assert_eq!(evaluated.as_float(), Ok(number), "{literal}"),
                Err(_) => assert_eq!(evaluated.to_string(), value, "{literal}"),
            }
        }
    }

    #[test]
    fn overrides_keep_line_numbers_and_reject_unknown_names() {
        let source = "let a = 1;\nlet b = if a == 1 {\n  2\n} else {\n  3\n};\nlet c = b;\n";
        let sites = find_parameters(source);
        let replaced = apply_overrides(
            source,
            &sites,
            &[("b".into(), "7".into()), ("a".into(), "x".into())],
        )
        .unwrap();
        assert_eq!(replaced, "let a = \"x\";\nlet b = 7\n\n\n\n;\nlet c = b;\n");
        assert_eq!(replaced.lines().count(), source.lines().count());
        let error = apply_overrides(source, &sites, &[("d".into(), "1".into())]).unwrap_err();
        assert!(
            error.contains("no parameter 'd'") && error.contains("a, b, c"),
            "{error}"
        );
        let twice = [("a".into(), "1".into()), ("a".into(), "2".into())];
        let error = apply_overrides(source, &sites, &twice).unwrap_err();
        assert!(error.contains("given twice (1 and 2)"), "{error}");
        let error = apply_overrides(source, &sites, &[("a".into(), "1e400".into())]).unwrap_err();
        assert!(error.contains("out of the range"), "{error}");
    }
}
