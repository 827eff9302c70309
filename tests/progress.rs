//! The progress display of `impm run`: on a terminal an `indicatif` bar that draws while the
//! run goes and is cleared at its end, so the last lines on the screen are the summary; with
//! stdout not a terminal no terminal codes reach it; with neither stream a terminal one plain
//! line per step. The terminal is a pseudo-terminal made by util-linux `script` (where it is
//! not installed the terminal tests print why they are skipped and pass).

mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};

/// The terminal's width in the tests: wide enough that the bar's line does not wrap.
const COLUMNS: usize = 200;

/// `impm run` of the 1D column (4 steps) into `out`, as a shell command; `redirect` is appended
/// (e.g. `> file`).
fn run_command(out: &Path, redirect: &str) -> String {
    format!(
        "stty cols {COLUMNS} rows 40; '{}' run '{}' --set cells=5 --set steps=4 --out '{}' {redirect}",
        env!("CARGO_BIN_EXE_impm"),
        common::column_script(),
        out.display()
    )
}

/// Runs `command` in a shell under a pseudo-terminal; `None` (with the reason printed) where
/// `script` cannot make one.
fn under_terminal(command: &str) -> Option<Output> {
    let output = Command::new("script")
        .args(["-qec", command, "/dev/null"])
        .stdin(Stdio::null())
        .output();
    match output {
        Ok(output) if output.status.code() != Some(127) => Some(output),
        Ok(output) => {
            eprintln!(
                "skipped: `script` could not run the command: {}",
                String::from_utf8_lossy(&output.stderr)
            );
            None
        }
        Err(e) => {
            eprintln!("skipped: util-linux `script` (for a pseudo-terminal) is not available: {e}");
            None
        }
    }
}

/// The screen a terminal shows after `transcript`: carriage return, line feed, and the
/// cursor and erase codes indicatif writes (`ESC[nA`, `ESC[nB`, `ESC[2K`, `ESC[K`); other
/// escape sequences are dropped. Lines do not wrap (the tests make the terminal wide).
fn screen(transcript: &str) -> Vec<String> {
    let mut lines: Vec<Vec<char>> = vec![Vec::new()];
    let (mut row, mut column) = (0usize, 0usize);
    let mut chars = transcript.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\r' => column = 0,
            '\n' => {
                row += 1;
                column = 0;
                if lines.len() <= row {
                    lines.push(Vec::new());
                }
            }
            '\u{1b}' => {
                if chars.peek() != Some(&'[') {
                    continue;
                }
                chars.next();
                let mut argument = String::new();
                let mut command = ' ';
                for d in chars.by_ref() {
                    if d.is_ascii_digit() || d == ';' || d == '?' {
                        argument.push(d);
                    } else {
                        command = d;
                        break;
                    }
                }
                let n: usize = argument.parse().unwrap_or(1);
                match (command, argument.as_str()) {
                    ('A', _) => row = row.saturating_sub(n),
                    ('B', _) => {
                        row += n;
                        while lines.len() <= row {
                            lines.push(Vec::new());
                        }
                    }
                    ('K', "2") => lines[row].clear(),
                    ('K', _) => lines[row].truncate(column),
                    _ => {}
                }
            }
            c => {
                let line = &mut lines[row];
                while line.len() < column {
                    line.push(' ');
                }
                if column < line.len() {
                    line[column] = c;
                } else {
                    line.push(c);
                }
                column += 1;
            }
        }
    }
    lines
        .into_iter()
        .map(|l| l.into_iter().collect::<String>().trim_end().to_string())
        .filter(|l| !l.is_empty())
        .collect()
}

#[test]
fn the_screen_model_follows_the_codes_indicatif_writes() {
    assert_eq!(
        screen("head\r\nbar 1/4\r\u{1b}[2Kbar 2/4\r\u{1b}[2Kdone\r\n"),
        vec!["head", "done"]
    );
    assert_eq!(
        screen("a\r\nb\r\n\u{1b}[1A\r\u{1b}[2Kc\u{1b}[1B\r\nd"),
        vec!["a", "c", "d"]
    );
}

#[test]
fn on_a_terminal_the_bar_draws_and_is_cleared_leaving_the_summary_last() {
    let out = common::temp_dir("progress", "terminal");
    let Some(output) = under_terminal(&run_command(&out, "")) else {
        return;
    };
    let transcript = String::from_utf8_lossy(&output.stdout);
    assert_eq!(output.status.code(), Some(0), "{transcript}");
    // the bar drew: its elapsed time, its position, its ETA and the step's figures, with the
    // codes that redraw it in place
    for fragment in ["[00:00:0", "4/4", "ETA", "λ=1.0000", "\u{1b}[2K"] {
        assert!(
            transcript.contains(fragment),
            "no {fragment:?} in {transcript:?}"
        );
    }
    let lines = screen(&transcript);
    let last_two = &lines[lines.len().saturating_sub(2)..];
    assert!(
        last_two.len() == 2
            && last_two[0].starts_with("done: 4 steps")
            && last_two[1].starts_with("results: ")
            && last_two[1].ends_with("particles.pvd (open in ParaView)"),
        "the screen ends {last_two:?}; all of it: {lines:#?}"
    );
    assert!(
        lines.iter().all(|l| !l.contains("ETA") && !l.contains('█')),
        "the bar is left on the screen: {lines:#?}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn with_stdout_not_a_terminal_no_terminal_codes_reach_it() {
    let out = common::temp_dir("progress", "stdout-file");
    let file = common::temp_dir("progress", "stdout-file.txt");
    let Some(output) = under_terminal(&run_command(&out, &format!("> '{}'", file.display())))
    else {
        return;
    };
    let transcript = String::from_utf8_lossy(&output.stdout);
    assert_eq!(output.status.code(), Some(0), "{transcript}");
    // the bar still draws on the terminal (stderr) ...
    assert!(transcript.contains("4/4"), "{transcript:?}");
    // ... while stdout holds the results alone, in plain lines
    let stdout = std::fs::read_to_string(&file).unwrap();
    assert!(stdout.starts_with("done: 4 steps"), "{stdout:?}");
    assert!(
        !stdout.contains('\u{1b}') && !stdout.contains('\r') && !stdout.contains("ETA"),
        "{stdout:?}"
    );
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_file(&file);
}

#[test]
fn with_no_terminal_each_step_is_one_plain_line() {
    let out = common::temp_dir("progress", "piped");
    let output = Command::new(env!("CARGO_BIN_EXE_impm"))
        .args(["run", &common::column_script(), "--set", "cells=5"])
        .args(["--set", "steps=4", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr),
    );
    assert_eq!(output.status.code(), Some(0), "{stderr}");
    for step in 1..=4 {
        let line = stderr
            .lines()
            .find(|l| l.starts_with(&format!("step {step}/4 ")))
            .unwrap_or_else(|| panic!("no line for step {step} in {stderr}"));
        assert!(
            ["λ=", "iterations", "residual", "elapsed", "ETA"]
                .iter()
                .all(|word| line.contains(word)),
            "{line}"
        );
    }
    for text in [&stdout, &stderr] {
        assert!(
            !text.contains('\u{1b}') && !text.contains('\r') && !text.contains('█'),
            "{text:?}"
        );
    }
    assert!(stdout.starts_with("done: 4 steps"), "{stdout}");
    let _ = std::fs::remove_dir_all(&out);
}
