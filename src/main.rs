//! The `impm` command line: run, study or check a Rhai scene.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use impm::effects;
use impm::explain::explain_scene;
use impm::plugin::{Module, ModuleSet};
use impm::records::StepRecord;
use impm::run::{default_output_dir, run_scene};
use impm::scene::scene_parameters;
use impm::study::{RunOutcome, StudyEvent, StudyPlan, Sweep, default_study_dir, run_study};

#[derive(Parser)]
#[command(
    name = "impm",
    version,
    about = "Implicit high-order Material Point Method"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene and write VTK results for ParaView.
    Run {
        /// The Rhai scene file.
        scene: PathBuf,
        /// Output folder (default: out/<scene name>/).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a scene parameter (a top-level `let`), e.g. --set cells=100.
        #[arg(long = "set", value_name = "NAME=VALUE")]
        set: Vec<String>,
    },
    /// Run a scene over the cross product of parameter values; write study.csv, study.md and
    /// charts of error against cells and against wall time.
    Study {
        scene: PathBuf,
        /// Values of a parameter, e.g. --sweep cells=5,10,20; several parameters moved together:
        /// --sweep basis:order=bspline:3,linear:1.
        #[arg(long = "sweep", value_name = "NAME=V1,V2,..", required = true)]
        sweep: Vec<String>,
        /// A fixed override for every run, e.g. --set body_force=-200.
        #[arg(long = "set", value_name = "NAME=VALUE")]
        set: Vec<String>,
        /// Output folder (default: out/study-<scene name>/).
        #[arg(long)]
        out: Option<PathBuf>,
        /// The swept parameter on the x axis of the error chart.
        #[arg(long, default_value = "cells")]
        against: String,
        /// Also write and plot the final stress of every point along the column.
        #[arg(long)]
        profiles: bool,
    },
    /// Validate a scene without solving; list its parameters.
    Check {
        scene: PathBuf,
        #[arg(long = "set", value_name = "NAME=VALUE")]
        set: Vec<String>,
        /// Also print the stages and systems that will run for this scene (and the optional
        /// ones it leaves out), read from the built schedules.
        #[arg(long)]
        explain: bool,
    },
    /// Draw columns of a run's history.csv against another (a load–displacement curve), as
    /// OUT_DIR/history_X_Y.svg and .png.
    Plot {
        /// The run's output folder (with history.csv).
        out_dir: PathBuf,
        /// The column along the horizontal axis, e.g. settlement.
        #[arg(long)]
        x: String,
        /// One or more columns along the vertical axis, comma-separated.
        #[arg(long, value_delimiter = ',')]
        y: Vec<String>,
    },
    /// Print the reference of the scene language (every call, its options, the bases, the
    /// material models and point fields), as in docs/scene-api.md.
    Api,
}

fn parse_overrides(set: &[String]) -> Result<Vec<(String, String)>, String> {
    set.iter()
        .map(|s| match s.split_once('=') {
            Some((name, value)) if !name.trim().is_empty() => {
                Ok((name.trim().to_string(), value.trim().to_string()))
            }
            _ => Err(format!("--set expects NAME=VALUE, got '{s}'")),
        })
        .collect()
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<(), String> {
    let modules = effects::built_in();
    match cli.command {
        Command::Run { scene, out, set } => run_command(&modules, &scene, out, &set),
        Command::Study {
            scene,
            sweep,
            set,
            out,
            against,
            profiles,
        } => {
            let plan = StudyPlan {
                out_dir: out.unwrap_or_else(|| default_study_dir(&scene)),
                scene,
                sweeps: sweep
                    .iter()
                    .map(|s| Sweep::parse(s))
                    .collect::<Result<_, _>>()?,
                fixed: parse_overrides(&set)?,
                against,
                profiles,
            };
            study_command(&plan)
        }
        Command::Check {
            scene,
            set,
            explain,
        } => check_command(&modules, &scene, &set, explain),
        Command::Plot { out_dir, x, y } => plot_command(&out_dir, &x, &y),
        Command::Api => {
            print!("{}", modules.scene_api().reference());
            Ok(())
        }
    }
}

/// `impm run`: solves the scene, with a progress line, and says where the results are.
fn run_command(
    modules: &ModuleSet,
    scene: &Path,
    out: Option<PathBuf>,
    set: &[String],
) -> Result<(), String> {
    let overrides = parse_overrides(set)?;
    let spec = modules
        .load_scene(scene, &overrides)
        .map_err(|e| e.to_string())?;
    let out_dir = out.unwrap_or_else(|| default_output_dir(&spec));
    let steps = spec.load_factors.len();
    let mut progress = Progress::new(steps);
    eprintln!(
        "{}: {}D, {} points, {} load steps -> {}",
        spec.name,
        spec.dim(),
        spec.point_count(),
        steps,
        out_dir.display()
    );
    let result = run_scene(&spec, &out_dir, |record| progress.step(record));
    progress.finish();
    let summary = result.map_err(|e| {
        format!(
            "{e}\nresults up to the last completed step are in {}",
            out_dir.display()
        )
    })?;
    let (_, wall) = summary.total_seconds();
    let mut line = format!(
        "done: {} steps, {} Newton iterations, {:.2} s",
        summary.steps.len(),
        summary.total_iterations(),
        wall
    );
    let cuts: usize = summary.steps.iter().map(|s| s.cuts).sum();
    if cuts > 0 {
        line += &format!(", {cuts} step cuts");
    }
    if let Some(e) = summary.final_error() {
        line += &format!(", error (eq. 15) {e:.3e}");
    }
    eprintln!("{line}");
    eprintln!(
        "results: {}/particles.pvd (open in ParaView)",
        out_dir.display()
    );
    Ok(())
}

/// `impm study`: the runs of the sweep, with a progress line.
fn study_command(plan: &StudyPlan) -> Result<(), String> {
    let mut bar = Progress::new(0);
    let records = run_study(plan, |event| match event {
        StudyEvent::Started {
            index,
            total,
            label,
        } => {
            bar.total = total;
            bar.show(index, &format!("run {}/{total}: {label}", index + 1));
        }
        StudyEvent::Finished { .. } => {}
    })?;
    bar.finish();
    let failed = records
        .iter()
        .filter(|r| r.outcome != RunOutcome::Completed)
        .count();
    eprintln!(
        "{} runs ({failed} failed) -> {}/study.csv, study.md and charts",
        records.len(),
        plan.out_dir.display()
    );
    Ok(())
}

/// `impm check`: validates the scene and says what it declares (and, with `--explain`, what
/// will run).
fn check_command(
    modules: &ModuleSet,
    scene: &Path,
    set: &[String],
    explain: bool,
) -> Result<(), String> {
    let overrides = parse_overrides(set)?;
    let parameters = scene_parameters(scene).map_err(|e| e.to_string())?;
    let spec = modules
        .load_scene(scene, &overrides)
        .map_err(|e| e.to_string())?;
    println!("scene {} is valid", spec.name);
    println!("parameters (override with --set NAME=VALUE):");
    for p in &parameters {
        println!("  {:<14} = {:<30} (line {})", p.name, p.default, p.line);
    }
    println!(
        "{}D grid {:?} cells, basis {}, {} bodies, {} points, {} load steps, load factors {}",
        spec.dim(),
        spec.grid.cells,
        spec.grid.basis,
        spec.bodies.len(),
        spec.point_count(),
        spec.load_factors.len(),
        describe_factors(&spec.load_factors)
    );
    let used: Vec<&dyn Module> = modules.iter().filter(|m| m.used_by(&spec)).collect();
    for module in &used {
        if let Some(description) = module.describe(&spec) {
            println!("  {}: {description}", module.name());
        }
    }
    if explain {
        print!("{}", explain_scene(&spec, modules)?);
    } else {
        let names: Vec<&str> = used.iter().map(|m| m.name()).collect();
        println!(
            "modules: {} (--explain lists the systems)",
            if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            }
        );
    }
    Ok(())
}

/// The load factors in short: all of them if few, else first, last, extremes.
fn describe_factors(factors: &[f64]) -> String {
    if factors.len() <= 8 {
        return format!("{factors:?}");
    }
    let (lo, hi) = factors
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &f| {
            (lo.min(f), hi.max(f))
        });
    format!(
        "{} .. {} ({} steps, range [{lo}, {hi}])",
        factors[0],
        factors[factors.len() - 1],
        factors.len()
    )
}

/// A one-line progress display on a terminal; silent otherwise.
struct Progress {
    total: usize,
    terminal: bool,
}

impl Progress {
    fn new(total: usize) -> Self {
        Self {
            total,
            terminal: std::io::stderr().is_terminal(),
        }
    }

    fn step(&mut self, r: &StepRecord) {
        let last = r.residuals.last().copied().unwrap_or(0.0);
        self.show(
            r.step,
            &format!(
                "step {}/{} λ={:.3} iterations {} residual {:.1e}{}",
                r.step,
                self.total,
                r.load_factor,
                r.iterations,
                last,
                if r.cuts > 0 {
                    format!(" (cut {}x)", r.cuts)
                } else {
                    String::new()
                }
            ),
        );
    }

    /// Draws the bar at `done` of `total` with a status text.
    fn show(&mut self, done: usize, text: &str) {
        if !self.terminal {
            return;
        }
        let width = 30;
        let filled = (width * done / self.total.max(1)).min(width);
        let mut err = std::io::stderr();
        let _ = write!(
            err,
            "\r[{}{}] {text:<70.70}",
            "#".repeat(filled),
            " ".repeat(width - filled),
        );
        let _ = err.flush();
    }

    fn finish(&mut self) {
        if self.terminal {
            eprintln!();
        }
    }
}

/// `impm plot`: a chart of history.csv columns.
fn plot_command(out_dir: &Path, x: &str, ys: &[String]) -> Result<(), String> {
    let stem = impm::study::plot_history(out_dir, x, ys)?;
    println!(
        "chart: {} and {}",
        stem.with_extension("svg").display(),
        stem.with_extension("png").display()
    );
    Ok(())
}
