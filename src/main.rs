//! The `impm` command line: run, study or check a Rhai scene.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

mod cli;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use cli::console::{Failure, note, say};
use cli::progress::Progress;

use impm::effects;
use impm::explain::explain_scene;
use impm::output::{FolderLock, clear_earlier_run};
use impm::plugin::{Module, ModuleSet};
use impm::restart::{Checkpoint, RunIdentity};
use impm::run::{RestartPlan, RunError, default_output_dir, run_scene_restartable};
use impm::scene::{SceneLimits, scene_parameters, scene_warnings};
use impm::study::{
    RunOutcome, StudyEvent, StudyPlan, Sweep, default_study_dir, parse_reference, run_study,
};

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
        /// Raise or lower a limit on the scene (operations, string, array, map, depth, seconds,
        /// order, support, points, memory in MB), e.g. --limit operations=1000000000.
        #[arg(long = "limit", value_name = "NAME=VALUE")]
        limit: Vec<String>,
        /// Continue an interrupted, killed or failed run from its last checkpoint in OUT_DIR
        /// (same scene and --set values); see "Restart" in docs/restart.md.
        #[arg(long, value_name = "OUT_DIR")]
        resume: Option<PathBuf>,
        /// Write the checkpoint (OUT_DIR/checkpoint.json and checkpoint_NNNN.bin) every N load
        /// steps instead of at every output step.
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
        checkpoint_every: Option<u64>,
        /// Threads for the per-point stages (default: the machine's cores, or
        /// RAYON_NUM_THREADS); results are bit-identical for a given count.
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
        threads: Option<u64>,
        /// Options for PETSc's options database, for scenes with solver(#{ linear: "petsc" })
        /// (applied after the scene's petsc_options, so they win), e.g.
        /// --petsc-options "-ksp_monitor -pc_type hypre". Builds with the feature `petsc` only.
        #[arg(long, value_name = "OPTIONS", allow_hyphen_values = true)]
        petsc_options: Option<String>,
        /// Under mpirun: each process holds only the points of its slab of cells (decomposed
        /// points, moved between processes as they cross slabs) instead of every point; scenes
        /// with modules that cannot follow their points across processes are refused.
        /// Builds with the feature `mpi` only.
        #[arg(long)]
        decompose: bool,
        /// Stop once N load steps are done (counted from the run's start, a resumed run's
        /// earlier steps included), as an interrupt does: status "interrupted", resumed with
        /// --resume. Splits a long run into jobs; keep checkpoints (--checkpoint-every) so that
        /// the last one is near step N.
        #[arg(long, value_name = "N")]
        stop_after: Option<u64>,
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
        /// The error measure: the relative error of a recorded quantity (a history.csv column)
        /// against this value, e.g. --reference tip_deflection=-0.0732 (replaces the scene's
        /// reference(...)).
        #[arg(long, value_name = "NAME=VALUE")]
        reference: Option<String>,
        /// Stop a run after this many seconds (at the end of its load step in flight), record
        /// it as "timed out" and go on with the next.
        #[arg(long, value_name = "SECONDS")]
        timeout: Option<f64>,
        /// Raise or lower a limit on the scene (operations, string, array, map, depth, seconds,
        /// order, support, points, memory in MB), e.g. --limit operations=1000000000.
        #[arg(long = "limit", value_name = "NAME=VALUE")]
        limit: Vec<String>,
        /// Threads for the per-point stages (default: the machine's cores, or
        /// RAYON_NUM_THREADS); results are bit-identical for a given count.
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
        threads: Option<u64>,
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
        /// Raise or lower a limit on the scene (operations, string, array, map, depth, seconds,
        /// order, support, points, memory in MB), e.g. --limit operations=1000000000.
        #[arg(long = "limit", value_name = "NAME=VALUE")]
        limit: Vec<String>,
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
    /// Merge the pieces of a distributed run (mpirun -n N, N > 1): every OUT_DIR/STEM_NNNN.pvtu
    /// becomes OUT_DIR/STEM_NNNN.vtu, one file with all points in serial order, for tools that
    /// do not read .pvtu (meshio); ParaView reads the .pvd / .pvtu as they are.
    Merge {
        /// The run's output folder.
        out_dir: PathBuf,
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
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            // help and version go to stdout, usage errors to stderr; neither may panic
            let _ = e.print();
            return ExitCode::from(if e.use_stderr() { 2 } else { 0 });
        }
    };
    if let Err(why) = impm::interrupt::install() {
        note(&format!("warning: {why}"));
    }
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::Message(message)) => {
            note(&format!("error: {message}"));
            ExitCode::FAILURE
        }
        Err(Failure::BrokenPipe) => ExitCode::from(141),
        Err(Failure::Quiet) => ExitCode::FAILURE,
    }
}

fn run(cli: Cli) -> Result<(), Failure> {
    refuse_under_mpirun(&cli.command)?;
    let modules = effects::built_in();
    match cli.command {
        Command::Run {
            scene,
            out,
            set,
            limit,
            resume,
            checkpoint_every,
            threads,
            petsc_options,
            decompose,
            stop_after,
        } => {
            impm::interrupt::stop_after_steps(stop_after.map(|n| n as usize));
            use_threads(threads)?;
            use_petsc_options(petsc_options.as_deref())?;
            use_decomposition(decompose)?;
            // under mpirun: MPI until the end of the run; processes other than 0 silent
            #[cfg(feature = "mpi")]
            let distributed = cli::distributed::DistributedRun::start_if_launched()?;
            #[cfg(feature = "mpi")]
            let scratch = distributed.as_ref().and_then(|run| run.scratch_folder());
            #[cfg(not(feature = "mpi"))]
            let scratch = None;
            if resume.is_some() {
                impm::distributed::request_resume();
            }
            let restart = RunRestart {
                resume,
                every: checkpoint_every.map(|n| n as usize),
                limit: limit.clone(),
                scratch,
                launch: Launch {
                    processes: impm::distributed::launched_by_mpirun().map(|p| p.size),
                    decompose,
                    petsc_options,
                },
            };
            let job = || {
                limits(&limit)
                    .and_then(|limits| run_command(&modules, &scene, out, &set, &limits, &restart))
            };
            // under mpirun: a panic ends the job; end together with the other processes, or
            // end the whole job
            #[cfg(feature = "mpi")]
            if let Some(distributed) = distributed {
                let result = distributed.abort_on_panic(job);
                return distributed.end(result);
            }
            job()
        }
        Command::Study {
            scene,
            sweep,
            set,
            out,
            against,
            profiles,
            reference,
            timeout,
            limit,
            threads,
        } => {
            use_threads(threads)?;
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
                timeout: timeout_seconds(timeout)?,
                limits: limits(&limit)?,
                reference: reference.as_deref().map(parse_reference).transpose()?,
            };
            study_command(&plan)
        }
        Command::Check {
            scene,
            set,
            explain,
            limit,
        } => check_command(&modules, &scene, &set, explain, &limits(&limit)?),
        Command::Plot { out_dir, x, y } => plot_command(&out_dir, &x, &y),
        Command::Merge { out_dir } => merge_command(&out_dir),
        Command::Api => say(&modules.scene_api().reference()),
    }
}

/// Under `mpirun` with more than one process only `impm run` of a build with the feature
/// `mpi` runs (over all of them); every other command would run once per process, into the
/// same files, and is refused: process 0 says why, the others end quietly (exit status 1).
fn refuse_under_mpirun(command: &Command) -> Result<(), Failure> {
    let Some(processes) = impm::distributed::launched_by_mpirun() else {
        return Ok(());
    };
    if processes.size == 1 {
        return Ok(());
    }
    let (name, why) = match command {
        Command::Run { .. } if cfg!(feature = "mpi") => return Ok(()),
        Command::Run { .. } => (
            "run",
            "this build has no distributed runs: build impm with --features mpi (README, \
             \"Running on a cluster\")",
        ),
        Command::Study { .. } => (
            "study",
            "a study runs its sweep's runs one after another in one process; under mpirun \
             every process would run the whole study into the same folder",
        ),
        Command::Check { .. } => ("check", "it does not run over several processes"),
        Command::Plot { .. } => ("plot", "it does not run over several processes"),
        Command::Merge { .. } => ("merge", "it does not run over several processes"),
        Command::Api => ("api", "it does not run over several processes"),
    };
    if processes.rank > 0 {
        return Err(Failure::Quiet);
    }
    Err(Failure::Message(format!(
        "impm {name} under mpirun with {} processes: {why}; run it without mpirun (or with \
         mpirun -n 1). Only `impm run` runs over several processes.",
        processes.size
    )))
}

/// `--threads N`: the global thread pool's size (otherwise rayon's default).
fn use_threads(threads: Option<u64>) -> Result<(), Failure> {
    match threads {
        Some(n) => Ok(impm::parallel::use_threads(n as usize)?),
        None => Ok(()),
    }
}

/// `--decompose`: decomposed points, for a run under `mpirun` of a build with the feature
/// `mpi`; refused otherwise (a serial run has nothing to decompose).
fn use_decomposition(decompose: bool) -> Result<(), Failure> {
    if !decompose {
        return Ok(());
    }
    if !cfg!(feature = "mpi") {
        return Err(Failure::Message(
            "--decompose needs a build with the feature mpi (cargo build --release --features \
             mpi) and mpirun"
                .to_string(),
        ));
    }
    if impm::distributed::launched_by_mpirun().is_none() {
        return Err(Failure::Message(
            "--decompose spreads the points over the processes of mpirun: run it as mpirun -n \
             N impm run SCENE --decompose"
                .to_string(),
        ));
    }
    impm::distributed::request_decomposition();
    Ok(())
}

/// `--petsc-options`: PETSc's options for every PETSc solver of the run; refused by a build
/// without PETSc.
fn use_petsc_options(options: Option<&str>) -> Result<(), Failure> {
    match options {
        #[cfg(feature = "petsc")]
        Some(options) => {
            impm::solver::set_petsc_command_line_options(options);
            Ok(())
        }
        #[cfg(not(feature = "petsc"))]
        Some(_) => Err(Failure::Message(format!(
            "--petsc-options: {}",
            impm::scene::WITHOUT_PETSC
        ))),
        None => Ok(()),
    }
}

/// The `--limit` assignments over the default limits.
fn limits(assignments: &[String]) -> Result<SceneLimits, Failure> {
    Ok(SceneLimits::from_assignments(assignments)?)
}

/// `--timeout SECONDS`: positive and finite.
fn timeout_seconds(seconds: Option<f64>) -> Result<Option<std::time::Duration>, Failure> {
    match seconds {
        None => Ok(None),
        Some(s) if s.is_finite() && s > 0.0 => Ok(Some(std::time::Duration::from_secs_f64(s))),
        Some(s) => Err(format!("--timeout {s}: give a positive number of seconds").into()),
    }
}

/// `impm run`'s checkpoint options.
struct RunRestart {
    /// `--resume OUT_DIR`.
    resume: Option<PathBuf>,
    /// `--checkpoint-every N`.
    every: Option<usize>,
    /// The `--limit` assignments (repeated in the command that resumes the run).
    limit: Vec<String>,
    /// Under `mpirun`, the folder of its own a process other than 0 runs into: it reads the
    /// checkpoint `--resume` names (process 0's folder) but writes, locks and clears nothing
    /// there.
    scratch: Option<PathBuf>,
    /// Under mpirun, its number of processes, `--decompose` and `--petsc-options`, repeated in
    /// the command that resumes the run (`mpirun -n N impm run .. --decompose`).
    launch: Launch,
}

/// How the run was launched, beyond the scene's own options: what the command that resumes it
/// repeats so that it runs as this run did.
struct Launch {
    /// `mpirun -n N` (`None`: not under mpirun).
    processes: Option<usize>,
    /// `--decompose`.
    decompose: bool,
    /// `--petsc-options`.
    petsc_options: Option<String>,
}

/// `impm run`: solves the scene, with a progress display, and says where the results are
/// (results and the final line on stdout, diagnostics on stderr). The run keeps checkpoints;
/// with `--resume` it continues the run of its output folder.
fn run_command(
    modules: &ModuleSet,
    scene: &Path,
    out: Option<PathBuf>,
    set: &[String],
    limits: &SceneLimits,
    restart: &RunRestart,
) -> Result<(), Failure> {
    let overrides = parse_overrides(set)?;
    let spec = modules
        .load_scene_within(scene, &overrides, limits)
        .map_err(|e| e.to_string())?;
    let out_dir = match (&restart.resume, out) {
        (Some(resume), Some(out)) if *resume != out => {
            return Err(format!(
                "--resume {} and --out {} name different folders: a resumed run continues in                  the folder it resumes (leave out --out)",
                resume.display(),
                out.display()
            )
            .into());
        }
        (Some(resume), _) => resume.clone(),
        (None, Some(out)) => out,
        (None, None) => default_output_dir(&spec),
    };
    let plan = RestartPlan {
        identity: RunIdentity::of(scene, &overrides)?,
        every: restart.every,
        command: resume_command(scene, set, restart, &out_dir),
    };
    // where this process writes: the output folder, or its scratch folder under mpirun
    let run_dir = restart.scratch.clone().unwrap_or_else(|| out_dir.clone());
    let (_lock, checkpoint) = match &restart.resume {
        Some(dir) => {
            let lock = match &restart.scratch {
                Some(scratch) => lock_output_folder(scratch)?,
                None => FolderLock::acquire(dir)?,
            };
            if let Some(pid) = lock.killed_run() {
                note(&format!(
                    "the run into {} (process {pid}) was killed before it finished",
                    dir.display()
                ));
            }
            let checkpoint = Checkpoint::read(dir, &plan.identity)?;
            // a checkpoint in pieces: resumed with decomposed points only, each process
            // building its run without points and reading its own from the pieces
            if checkpoint.pieces.is_some() {
                if !impm::distributed::decomposed() {
                    let why = checkpoint.needs_decomposition(dir).unwrap_or_default();
                    return Err(why.into());
                }
                impm::distributed::request_resume_from_pieces();
            }
            note(&format!(
                "resuming {} after load step {} of {}",
                dir.display(),
                checkpoint.steps_done,
                spec.load_factors.len()
            ));
            (lock, Some(checkpoint))
        }
        None => (lock_output_folder(&run_dir)?, None),
    };
    let steps = spec.load_factors.len();
    let mut progress = Progress::new(steps);
    note(&format!(
        "{}: {}D, {} points, {} load steps -> {}",
        spec.name,
        spec.dim(),
        spec.point_count(),
        steps,
        out_dir.display()
    ));
    for line in impm::scene::scene_notes(&spec) {
        note(&line);
    }
    for warning in scene_warnings(&spec) {
        note(&format!("warning: {warning}"));
    }
    let result = run_scene_restartable(spec, &run_dir, modules, &plan, checkpoint, |record| {
        progress.step(record)
    });
    progress.finish();
    let summary = match result {
        Ok(summary) => summary,
        Err(e) => return Err(run_failure(&e, &run_dir, &plan.command).into()),
    };
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
    // a warning printed mid-run scrolls away: the last line repeats that there were some
    match summary.warnings.len() {
        0 => {}
        1 => line += ", 1 warning (above and in summary.json)",
        n => line += &format!(", {n} warnings (above and in summary.json)"),
    }
    // `auto` (the default) is worth a line when it solved iteratively or fell back to direct
    let choice = summary.steps.last().and_then(|s| s.linear_backend.as_ref());
    if let Some(choice) = choice.filter(|c| impm::solver::worth_telling(c)) {
        line += &format!("\nlinear solver (auto, last step): {choice}");
    }
    if let Some(hierarchy) = summary.steps.last().and_then(|s| s.multigrid.as_ref()) {
        line += &format!("\nmultigrid (last step): {hierarchy}");
    }
    say(&format!(
        "{line}\nresults: {}/particles.pvd (open in ParaView)\n",
        out_dir.display()
    ))
}

/// Locks the output folder for this run (a second run into it fails) and removes what an
/// earlier run left there; says so if that run was killed.
fn lock_output_folder(dir: &Path) -> Result<FolderLock, Failure> {
    let lock = FolderLock::acquire(dir)?;
    if let Some(pid) = lock.killed_run() {
        note(&format!(
            "warning: an earlier run into {} (process {pid}) was killed before it finished; its files are replaced",
            dir.display()
        ));
    }
    clear_earlier_run(dir).map_err(|e| {
        format!(
            "cannot remove the files of an earlier run from {}: {e}",
            dir.display()
        )
    })?;
    Ok(lock)
}

/// What a failed or stopped run tells the user: why, where what was done is (only if it was
/// written) and how to continue it (only if a checkpoint was written).
fn run_failure(error: &RunError, out_dir: &Path, resume: &str) -> String {
    let summary = out_dir.join("summary.json");
    let mut kept = if summary.is_file() {
        // a full disk can keep the failure from being recorded: say so rather than leave
        // "running" unexplained
        let unrecorded = std::fs::read_to_string(&summary)
            .is_ok_and(|text| text.contains("\"status\": \"running\""));
        format!(
            "\nresults up to the last completed step are in {} (summary.json says how far it got{})",
            out_dir.display(),
            if unrecorded {
                "; it could not be updated after the failure, so its status still says running"
            } else {
                ""
            }
        )
    } else {
        String::new()
    };
    // a scene that cannot be solved needs changing, not continuing
    let resumable = !matches!(
        error,
        RunError::Build(_)
            | RunError::Resume(_)
            | RunError::Solve(impm::resources::SolverError::NotHeld { .. })
    );
    if resumable && Checkpoint::path_in(out_dir).is_file() {
        kept += &format!("\nto continue from the last checkpoint: {resume}");
    }
    format!("{error}{kept}")
}

/// The command that resumes this run: the same scene, `--set`, `--limit` and
/// `--checkpoint-every`, and `--resume OUT_DIR`; under `mpirun` as `mpirun -n N impm run ..`
/// with the same `--decompose` and `--petsc-options` (a checkpoint resumes over any number of
/// processes, or serially, but this is the run as it was launched).
fn resume_command(scene: &Path, set: &[String], restart: &RunRestart, out_dir: &Path) -> String {
    let mut words = Vec::new();
    if let Some(n) = restart.launch.processes {
        words.extend(["mpirun".to_string(), "-n".to_string(), n.to_string()]);
    }
    words.extend([
        "impm".to_string(),
        "run".to_string(),
        shell_word(&scene.display().to_string()),
    ]);
    for assignment in set {
        words.extend(["--set".to_string(), shell_word(assignment)]);
    }
    for assignment in &restart.limit {
        words.extend(["--limit".to_string(), shell_word(assignment)]);
    }
    if let Some(every) = restart.every {
        words.extend(["--checkpoint-every".to_string(), every.to_string()]);
    }
    if restart.launch.decompose {
        words.push("--decompose".to_string());
    }
    if let Some(options) = &restart.launch.petsc_options {
        words.extend(["--petsc-options".to_string(), shell_word(options)]);
    }
    words.extend([
        "--resume".to_string(),
        shell_word(&out_dir.display().to_string()),
    ]);
    words.join(" ")
}

/// `word` as a POSIX shell reads it: as is when it has no special character, else in single
/// quotes.
fn shell_word(word: &str) -> String {
    let plain = !word.is_empty()
        && word
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "_-./=:,+@%".contains(c));
    if plain {
        word.to_string()
    } else {
        format!("'{}'", word.replace('\'', "'\\''"))
    }
}

/// `impm study`: the runs of the sweep, with a progress display.
fn study_command(plan: &StudyPlan) -> Result<(), Failure> {
    let lock = FolderLock::acquire(&plan.out_dir)?;
    if let Some(pid) = lock.killed_run() {
        note(&format!(
            "warning: an earlier study into {} (process {pid}) was killed before it finished",
            plan.out_dir.display()
        ));
    }
    let mut bar: Option<Progress> = None;
    let records = run_study(plan, |event| match event {
        StudyEvent::Started {
            index,
            total,
            label,
        } => bar
            .get_or_insert_with(|| Progress::new(total))
            .start_item(index, &format!("run {}/{total}: {label}", index + 1)),
        StudyEvent::Finished { .. } => {}
    });
    if let Some(bar) = &mut bar {
        bar.finish();
    }
    let records = records?;
    if !records.is_empty() && !impm::study::has_error_measure(&records) {
        note(&format!("warning: {}", impm::study::NO_ERROR_MEASURE));
    }
    for warning in impm::study::non_numeric_notes(plan, &records) {
        note(&format!("warning: {warning}"));
    }
    let failed = records
        .iter()
        .filter(|r| r.outcome != RunOutcome::Completed)
        .count();
    let line = format!(
        "{} runs ({failed} not completed) -> {}/study.csv, study.md and charts\n",
        records.len(),
        plan.out_dir.display()
    );
    if let Some(reason) = impm::interrupt::stop_reason() {
        say(&line)?;
        return Err(format!(
            "the study was {} after {} runs; the rows of the runs done are kept",
            reason.status(),
            records.len()
        )
        .into());
    }
    say(&line)
}

/// `impm check`: validates the scene and says what it declares (and, with `--explain`, what
/// will run).
fn check_command(
    modules: &ModuleSet,
    scene: &Path,
    set: &[String],
    explain: bool,
    limits: &SceneLimits,
) -> Result<(), Failure> {
    use std::fmt::Write;
    let overrides = parse_overrides(set)?;
    let parameters = scene_parameters(scene).map_err(|e| e.to_string())?;
    let spec = modules
        .load_scene_within(scene, &overrides, limits)
        .map_err(|e| e.to_string())?;
    let mut text = String::new();
    let _ = writeln!(text, "scene {} is valid", spec.name);
    for warning in scene_warnings(&spec) {
        let _ = writeln!(text, "warning: {warning}");
    }
    let _ = writeln!(text, "parameters (override with --set NAME=VALUE):");
    for p in &parameters {
        let _ = writeln!(
            text,
            "  {:<14} = {:<30} (line {})",
            p.name, p.default, p.line
        );
    }
    let _ = writeln!(
        text,
        "{}D grid {:?} cells, basis {}, {} bodies, {} points, {} load steps, load factors {}",
        spec.dim(),
        spec.grid.cells,
        spec.grid.basis,
        spec.bodies.len(),
        spec.point_count(),
        spec.load_factors.len(),
        describe_factors(&spec.load_factors)
    );
    if let Some(stages) = spec.part::<impm::scene::Stages>() {
        let list: Vec<String> = stages
            .0
            .iter()
            .map(|stage| {
                format!(
                    "'{}' {} steps{}{}",
                    stage.name,
                    stage.steps,
                    stage
                        .line
                        .map(|l| format!(" (line {l})"))
                        .unwrap_or_default(),
                    if stage.zero_displacements {
                        ", displacements from its start"
                    } else {
                        ""
                    }
                )
            })
            .collect();
        let _ = writeln!(
            text,
            "stages (each from load factor 0, loads held after their stage): {}",
            list.join(", ")
        );
    }
    let used: Vec<&dyn Module> = modules.iter().filter(|m| m.used_by(&spec)).collect();
    for module in &used {
        if let Some(description) = module.describe(&spec) {
            let _ = writeln!(text, "  {}: {description}", module.name());
        }
    }
    if explain {
        let _ = write!(text, "{}", explain_scene(&spec, modules)?);
    } else {
        let names: Vec<&str> = used.iter().map(|m| m.name()).collect();
        let _ = writeln!(
            text,
            "modules: {} (--explain lists the systems)",
            if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            }
        );
    }
    say(&text)
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

/// `impm merge`: one `.vtu` per `.pvtu` of the folder, from its pieces.
fn merge_command(out_dir: &Path) -> Result<(), Failure> {
    let entries = std::fs::read_dir(out_dir)
        .map_err(|e| format!("reading the folder {}: {e}", out_dir.display()))?;
    let mut parallel: Vec<PathBuf> = entries
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|path| path.extension().is_some_and(|x| x == "pvtu"))
        .collect();
    parallel.sort();
    if parallel.is_empty() {
        return Err(Failure::Message(format!(
            "no .pvtu files in {} (only runs under mpirun with more than one process write \
             their particles in pieces)",
            out_dir.display()
        )));
    }
    for pvtu in &parallel {
        let merged = pvtu.with_extension("vtu");
        let points = impm::output::merge_pvtu(pvtu, &merged)
            .map_err(|e| format!("merging {}: {e}", pvtu.display()))?;
        say(&format!("{}: {points} points\n", merged.display()))?;
    }
    Ok(())
}

/// `impm plot`: a chart of history.csv columns.
fn plot_command(out_dir: &Path, x: &str, ys: &[String]) -> Result<(), Failure> {
    let stem = impm::study::plot_history(out_dir, x, ys)?;
    say(&format!(
        "chart: {} and {}\n",
        stem.with_extension("svg").display(),
        stem.with_extension("png").display()
    ))
}
