//! Progress of a run or a study: on a terminal an `indicatif` bar with the step, λ, Newton
//! iterations, residual, elapsed time and ETA; otherwise (CI, a cluster job log) one line per
//! converged step with the same figures. Both on stderr. The bar is cleared when the run ends
//! (it left its line without a line break, so the summary printed next ran on from the bar's
//! end), so the last lines on the screen are the summary (`tests/progress.rs`).

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use impm::records::StepRecord;

use super::console::note;

pub struct Progress {
    bar: Option<ProgressBar>,
    total: usize,
    started: Instant,
}

impl Progress {
    /// A display for `total` steps (or runs), a bar if stderr is a terminal.
    pub fn new(total: usize) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar =
                ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr());
            if let Ok(style) = ProgressStyle::with_template(
                "[{elapsed_precise}] {bar:30} {pos}/{len} ETA {eta} {msg}",
            ) {
                bar.set_style(style);
            }
            bar
        });
        Self {
            bar,
            total,
            started: Instant::now(),
        }
    }

    /// A converged load step.
    pub fn step(&mut self, r: &StepRecord) {
        let last = r.residuals.last().copied().unwrap_or(0.0);
        let cuts = if r.cuts > 0 {
            format!(" (cut {}x)", r.cuts)
        } else {
            String::new()
        };
        let figures = format!(
            "λ={:.4} iterations {} residual {last:.1e}{cuts}",
            r.load_factor, r.iterations
        );
        match &self.bar {
            Some(bar) => {
                bar.set_position(r.step as u64);
                bar.set_message(figures);
            }
            None => note(&format!(
                "step {}/{} {figures} elapsed {} ETA {}",
                r.step,
                self.total,
                seconds(self.started.elapsed()),
                seconds(self.eta(r.step)),
            )),
        }
    }

    /// Item `index` (0-based) of the total starts, described by `text` (study runs).
    pub fn start_item(&mut self, index: usize, text: &str) {
        match &self.bar {
            Some(bar) => {
                bar.set_position(index as u64);
                bar.set_message(text.to_string());
            }
            None => note(&format!(
                "{text} (elapsed {}, ETA {})",
                seconds(self.started.elapsed()),
                if index == 0 {
                    "-".to_string()
                } else {
                    seconds(self.eta(index))
                }
            )),
        }
    }

    /// Clears the bar: what follows (the summary, an error) starts on a clean line.
    pub fn finish(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }

    /// The time left after `done` of `total`, at the pace so far.
    fn eta(&self, done: usize) -> Duration {
        if done == 0 {
            return Duration::ZERO;
        }
        let left = self.total.saturating_sub(done) as f64;
        Duration::from_secs_f64(self.started.elapsed().as_secs_f64() / done as f64 * left)
    }
}

/// `12.3 s`, `4 min 05 s`, `1 h 02 min`.
fn seconds(duration: Duration) -> String {
    let s = duration.as_secs_f64();
    if s < 60.0 {
        format!("{s:.1} s")
    } else if s < 3600.0 {
        format!("{} min {:02} s", (s / 60.0) as u64, (s % 60.0) as u64)
    } else {
        format!(
            "{} h {:02} min",
            (s / 3600.0) as u64,
            ((s % 3600.0) / 60.0) as u64
        )
    }
}
