//! Distributed runs (cargo feature `mpi`): `mpirun -n N impm run SCENE`, the scene unchanged.
//!
//! The state is replicated on every process; each process assembles the points of its slab of
//! cells, the shares are summed by PETSc (`MPIAIJ` matrix, `MPI` vector) and KSP solves the
//! distributed system (`src/effects/distributed/`). Checked against the serial run of the
//! same scene with the direct solver, for 1, 2 and 3 processes (oversubscribed on a 2-core
//! machine: `--oversubscribe`, and MPI's yield-when-idle so waiting processes give way), with
//! a tight linear tolerance (`-ksp_rtol 1e-12`):
//!
//! * the same Newton iterations in every step;
//! * the same eq. 15 error, to 1e-8 relative;
//! * every point's Cauchy stress to 1e-8 of the largest, and its position to 1e-8 of the
//!   body's height (the point files of process 0 hold every point, in the serial order);
//! * the run says, in its log and in summary.json, that the state is replicated;
//! * the heavy column (1D; points travel across cells, and so across the slab boundaries,
//!   between steps: `points_changing_process` counts them) equals its serial run as well;
//! * over 2 and 3 processes the particle files are pieces listed by `.pvtu` files, which
//!   ParaView reads with every field and point (pvpython, where installed) and `impm merge`
//!   turns into the serial file (the comparisons above are made on the merged file);
//! * the modules that add to `f_int` and `K` after the assembly add each term once over the
//!   processes: the elastic strip footing (surface condition), a Tresca footing with F-bar and
//!   the sliver column (ghost penalty) under `mpirun -n 2` and `-n 3` equal their serial runs
//!   as above, and so do the footing pressure and reaction in every step; F-bar with
//!   decomposed points too (a nearly incompressible 2D column);
//! * the ghost penalty with decomposed points (`-n 2`, `-n 3`) equals its serial run: the
//!   sliver column, the heavy column emptying its top cells as points cross the slabs, and a
//!   sheared block whose sliver row has faces on the slab boundaries;
//! * a process that fails alone outside the Newton iteration (writing a record) ends every
//!   process after that step, without an abort, with the cause, instead of leaving the others
//!   waiting; summary.json says failed and what was written before stays readable; a failure
//!   before the first step (process 0 cannot lock its folder) ends the job by `MPI_Abort`,
//!   naming the process and the cause;
//! * with decomposed points, points of one process only leaving the grid (`-n 2`, `-n 3`) stop
//!   every process at the same step within a bounded time, without an abort, naming the
//!   failing process and the cause; summary.json says failed after the steps the serial run
//!   converged and the `.pvd` series is readable up to the last of them;
//! * arc-length control (the thick cylinder, past its peak) under `mpirun -n 2` and `-n 3`
//!   equals its serial run: iterations and step cuts per step, the load factor, the pressure
//!   and the bore's displacement; with `--decompose` the arc-controlled pressure is refused,
//!   naming the pressure; with decomposed points arc-length control equals its serial run
//!   too (a traction-loaded footing past first yield, and a column with its weight held whose
//!   points change process), its sums taken over the processes;
//! * a signal to one process only stops every process after the same load step (the stop is
//!   agreed between steps), with the status "interrupted" and no abort;
//! * `impm study` under `mpirun -n 2` is refused, said once, before anything is written;
//! * with decomposed points (`--decompose`: each process holds its slab's points only, and
//!   they move between the processes), the heavy column, the 2D column and a von Mises column
//!   under `mpirun -n 2` and `-n 3` (and the heavy column with GIMP under `-n 2`) equal their
//!   serial runs as above (the plastic strain too:
//!   the history travels with its points), points change process in the heavy and the plastic
//!   column, and the log says the points are decomposed; so does a staged scene with
//!   `zero_displacements` (its `displacement` field too: each point's origin travels with it);
//!   so do point loads (every point of a heavy column loaded, the loads travelling with the
//!   points that change process; the `point_load` field, the reaction and the external
//!   resultant too), tractions and loads at positions (their points follow their hosts to
//!   other processes; a load point's support reaching nodes only another process's points
//!   touch; the tractions file, reactions and resultant too); so do a column compressed by a
//!   grid-node `displace` (its reactions and its prescribed-motion warning) and probes whose
//!   neighbours are on two processes (their values in summary.json and history.csv); a scene
//!   with stress recovery is refused naming it, and `--decompose` without mpirun is refused;
//! * decomposed runs report as the serial run does: every comparison also compares
//!   `particles.pvd`'s times (a staged scene's `k + λ_k`), the F-bar column's sparse top cell
//!   is counted in `fbar_sparse_cells` (summary.json, history.csv) over every process, and an
//!   interrupted run's resume command (printed and in summary.json) is `mpirun -n N impm run
//!   .. --decompose` as launched;
//! * with decomposed points the grid and node files are pieces too (each node by its owner,
//!   each cell by the process of its slab): the 2D and the 3D column over 2 and 3 processes
//!   list one piece per process in every step's `.pvtu`, the node pieces hold every node once,
//!   `impm merge` turns them into the serial run's files (every point, cell and array, every
//!   step) and ParaView reads both series with every array and the right nodes and cells;
//! * checkpoints under mpirun: a run stopped after a checkpoint and resumed gives the
//!   uninterrupted serial run's results whatever wrote the checkpoint and whatever resumes it
//!   (decomposed `-n 2` by `-n 2`, `-n 3` by `-n 1`, serial by `-n 2`; a von Mises column
//!   `-n 3` by `-n 2`), a decomposed run's checkpoint holds the serial one's numbers, and a
//!   checkpoint process 0 fails to write stops every process, the previous one kept; with
//!   decomposed points over several processes the checkpoint is in pieces (one per process,
//!   since 2026-12-08): the 2D column's, written over 3 processes, resumes over 2 with the
//!   serial run's results and history.csv, and a serial or replicated resume of it, and a
//!   missing, truncated or damaged piece, are refused, naming what to do or the file.
//!
//! Skipped, with a message, where `mpirun` is missing (`.ci/run` installs OpenMPI as root).

#![cfg(feature = "mpi")]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output};
use std::sync::MutexGuard;
use std::time::Duration;

use common::{shipped_scene, temp_dir};
use impm::output::read_vtu;

/// The runs of this file, one at a time: each oversubscribes a 2-core machine already.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Whether `mpirun` runs here; says why not otherwise.
fn mpirun_available() -> bool {
    let ok = Command::new("mpirun")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!("skipped: mpirun not found (apt-get install openmpi-bin libopenmpi-dev)");
    }
    ok
}

/// The right to launch a job where `mpirun` runs here (`None` otherwise, said why): the
/// runs of this file go one at a time.
fn mpi_job_slot() -> Option<MutexGuard<'static, ()>> {
    mpirun_available().then(one_job_at_a_time)
}

/// Waits for the job of another test to end (also one that failed holding the lock).
fn one_job_at_a_time() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// `impm run SCENE --out OUT --set ...` (plus `extra`), under `mpirun -n N` when `processes`
/// is given.
fn run(processes: Option<usize>, scene: &Path, set: &[&str], out: &Path, extra: &[&str]) -> Output {
    let args = run_arguments(scene, set, out, extra);
    impm_command(processes, &args)
        .output()
        .expect("the run starts")
}

/// The arguments of `impm run SCENE --out OUT --threads 1 --set ...` (plus `extra`).
fn run_arguments(scene: &Path, set: &[&str], out: &Path, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = vec![
        "run".into(),
        scene.display().to_string(),
        "--out".into(),
        out.display().to_string(),
        "--threads".into(),
        "1".into(),
    ];
    for assignment in set {
        args.extend(["--set".into(), assignment.to_string()]);
    }
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

/// The `impm` binary with `args`, under `mpirun -n N` when `processes` is given.
fn impm_command(processes: Option<usize>, args: &[String]) -> Command {
    let binary = env!("CARGO_BIN_EXE_impm");
    let mut command = match processes {
        Some(n) => {
            let mut c = Command::new("mpirun");
            c.args([
                "--allow-run-as-root",
                "--oversubscribe",
                "-n",
                &n.to_string(),
                binary,
            ]);
            c.env("OMPI_MCA_mpi_yield_when_idle", "1");
            c
        }
        None => Command::new(binary),
    };
    command.args(args);
    command
}

/// Starts `command` with its standard output and error in the files `stdout.txt` and
/// `stderr.txt` of `logs` (created).
fn spawn_logged(mut command: Command, logs: &Path) -> Child {
    std::fs::create_dir_all(logs).unwrap();
    command
        .stdout(std::fs::File::create(logs.join("stdout.txt")).unwrap())
        .stderr(std::fs::File::create(logs.join("stderr.txt")).unwrap())
        .spawn()
        .expect("the job starts")
}

/// `impm run SCENE --out OUT --set ...` (plus `extra`) under `mpirun -n N`, with its standard
/// output and error in files of `logs`, within `limit` ([`run_within`]).
fn launch_within(
    n: usize,
    scene: &Path,
    set: &[&str],
    out: &Path,
    extra: &[&str],
    logs: &Path,
    limit: Duration,
) -> Option<(ExitStatus, String)> {
    let args = run_arguments(scene, set, out, extra);
    run_within(impm_command(Some(n), &args), logs, limit)
}

/// Runs `command` with its standard output and error in files of `dir`; kills it if it has not
/// ended after `limit` (a hung job: `None`). Returns its exit status and standard error.
fn run_within(command: Command, dir: &Path, limit: Duration) -> Option<(ExitStatus, String)> {
    let mut child = spawn_logged(command, dir);
    let stderr = dir.join("stderr.txt");
    let started = std::time::Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return Some((status, std::fs::read_to_string(&stderr).unwrap()));
        }
        if started.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// What a run left: Newton iterations per step, the final eq. 15 error, the last point file's
/// positions and Cauchy stresses, and summary.json's warnings.
struct Outcome {
    iterations: Vec<u64>,
    error: Option<f64>,
    positions: Vec<f64>,
    stress: Vec<f64>,
    /// The points' plastic strain, for scenes of plastic materials.
    plastic: Option<Vec<f64>>,
    warnings: Vec<String>,
    /// Per step: the points process 0 assembled.
    assembled: Vec<Option<f64>>,
    /// summary.json's steps (the modules' measures by name).
    steps: Vec<serde_json::Value>,
    /// The last point file, for other fields.
    points: impm::output::VtuContents,
}

fn outcome(out: &Path) -> Outcome {
    let text = std::fs::read_to_string(out.join("summary.json")).expect("summary.json");
    let summary: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(summary["status"], "completed", "{text}");
    let steps = summary["steps"].as_array().unwrap();
    let last = out.join(impm::output::step_file_name("particles", steps.len()));
    // over several processes the particles are in pieces: `impm merge` writes the one file
    if last.with_extension("pvtu").is_file() {
        assert!(!last.exists());
        let merge = Command::new(env!("CARGO_BIN_EXE_impm"))
            .arg("merge")
            .arg(out)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&merge.stdout);
        assert!(
            merge.status.success() && said.contains("points"),
            "{said}{}",
            String::from_utf8_lossy(&merge.stderr)
        );
    }
    let points = read_vtu(&last).unwrap_or_else(|e| panic!("{}: {e}", last.display()));
    Outcome {
        iterations: steps
            .iter()
            .map(|s| s["iterations"].as_u64().unwrap())
            .collect(),
        error: summary["error"].as_f64(),
        positions: points.points.iter().flatten().copied().collect(),
        stress: points.point_field("cauchy_stress").unwrap().1.to_vec(),
        plastic: points
            .point_field("plastic_strain")
            .map(|(_, values)| values.to_vec()),
        assembled: steps
            .iter()
            .map(|s| s["assembled_points"].as_f64())
            .collect(),
        warnings: summary["warnings"]
            .as_array()
            .map(|w| w.iter().map(|s| s.as_str().unwrap().to_string()).collect())
            .unwrap_or_default(),
        steps: steps.clone(),
        points,
    }
}

/// The serial run of the scene into `dir` (with `extra`), which must complete: what it left.
fn serial_reference(scene: &Path, set: &[&str], dir: &Path, extra: &[&str]) -> Outcome {
    let output = run(None, scene, set, dir, extra);
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    outcome(dir)
}

/// The summary.json of the run in `dir`.
fn read_summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

/// The scene under `mpirun -n N` (with `extra`), which must refuse to run: it fails, without
/// an abort. Returns its standard error.
fn refused(n: usize, scene: &Path, set: &[&str], out: &Path, extra: &[&str]) -> String {
    let output = run(Some(n), scene, set, out, extra);
    let stderr = String::from_utf8_lossy(&output.stderr).to_string();
    assert!(!output.status.success(), "{stderr}");
    assert!(!stderr.contains("MPI_Abort"), "{stderr}");
    stderr
}

/// The points of the pieces the `.pvtu` file `pvtu` lists, in all.
fn points_in_pieces(pvtu: &Path) -> usize {
    impm::output::pvtu_pieces(pvtu)
        .unwrap()
        .iter()
        .map(|piece| read_vtu(piece).unwrap().points.len())
        .sum()
}

/// The scene `text` written as `name` into a fresh folder of its own (named after `tag`):
/// the folder and the scene's path.
fn scene_file(tag: &str, name: &str, text: &str) -> (PathBuf, PathBuf) {
    let dir = temp_dir("mpi", tag);
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join(name);
    std::fs::write(&scene, text).unwrap();
    (dir, scene)
}

/// The decomposed grid's numbering in every step of a run over `n` processes (the run itself
/// checks that its DOF stage numbered exactly its owned and ghost DOFs and that every ghost
/// got its numbers from its owner, and fails otherwise; `dofs` is the whole problem's, the
/// owned DOFs summed over the processes): process 0 owns all DOFs alone and none are ghosts;
/// with more processes it owns some but not all, its local system (owned and ghost DOFs; the
/// lowest rank touching a node owns it, so process 0 has no ghosts) is smaller than the whole
/// problem, there are ghosts, and numbers were sent.
fn decomposed_grid_is_numbered(script: &str, n: usize, steps: &[serde_json::Value]) {
    for (k, step) in steps.iter().enumerate() {
        let value = |name: &str| {
            step[name]
                .as_f64()
                .unwrap_or_else(|| panic!("{script} -n {n}: no {name} in step {}", k + 1))
        };
        let (dofs, owned, ghosts) = (value("dofs"), value("owned_dofs"), value("ghost_nodes"));
        let local = value("local_dofs");
        if n == 1 {
            assert_eq!((owned, ghosts), (dofs, 0.0), "{script} step {}", k + 1);
            assert_eq!(local, dofs, "{script} step {}", k + 1);
        } else {
            assert!(
                owned > 0.0 && owned <= local && local < dofs,
                "{script} -n {n}: owns {owned}, holds {local} of {dofs}"
            );
            assert!(ghosts > 0.0, "{script} -n {n}: no ghosts in step {}", k + 1);
            assert!(value("bytes_grid_numbers") > 0.0);
        }
    }
    let last = steps.last().unwrap();
    eprintln!(
        "{script} -n {n}: decomposed grid, last step: {} DOFs, process 0 owns {} and holds {}, \
         ghost nodes {}, bytes_grid_numbers {} (bytes_points {}, bytes_gathered {})",
        last["dofs"],
        last["owned_dofs"],
        last["local_dofs"],
        last["ghost_nodes"],
        last["bytes_grid_numbers"],
        last["bytes_points"],
        last["bytes_gathered"]
    );
}

/// Largest difference between `a` and `b` relative to the largest magnitude in `b`.
fn relative_difference(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().map(|v| v.abs()).fold(0.0, f64::max);
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() / scale)
        .fold(0.0, f64::max)
}

/// The scene's runs under `mpirun -n 1, 2, 3` against its serial run (direct solver); the
/// number of points that changed process at a step start, summed over the steps, for each `n`.
fn compare(script: &str, set: &[&str], tag: &str, paraview: bool) -> Vec<f64> {
    compare_runs(&shipped_scene(script), set, tag, paraview, None)
}

/// As [`compare`] with decomposed points (`--decompose`), over each of `processes`.
fn compare_decomposed(scene: &Path, set: &[&str], tag: &str, processes: &[usize]) -> Vec<f64> {
    compare_runs(scene, set, tag, false, Some(processes))
}

/// [`compare`] (replicated, `decomposed` `None`: over 1, 2 and 3 processes) or
/// [`compare_decomposed`].
fn compare_runs(
    scene: &Path,
    set: &[&str],
    tag: &str,
    paraview: bool,
    decomposed: Option<&[usize]>,
) -> Vec<f64> {
    let runs = match decomposed {
        Some(counts) => Runs::decomposed(counts),
        None => Runs {
            paraview,
            ..Runs::replicated(&[1, 2, 3])
        },
    };
    summed_over_steps(
        &compare_with(scene, set, tag, &runs),
        "points_changing_process",
    )
}

/// For each run (the steps of its summary.json), the measure `name` summed over its steps
/// (0 where a step does not have it).
fn summed_over_steps(runs: &[Vec<serde_json::Value>], name: &str) -> Vec<f64> {
    runs.iter()
        .map(|steps| steps.iter().map(|s| s[name].as_f64().unwrap_or(0.0)).sum())
        .collect()
}

/// Which distributed runs [`compare_with`] makes of a scene, and what it compares besides
/// iterations, the eq. 15 error, stresses and positions.
struct Runs<'a> {
    /// ParaView reads the pieces (where pvpython is installed).
    paraview: bool,
    /// `--decompose`.
    decompose: bool,
    /// The numbers of processes.
    counts: &'a [usize],
    /// Measures of summary.json compared in every step to 1e-8 relative (e.g. a footing's
    /// pressure, a reaction).
    measures: &'a [&'a str],
    /// Point fields compared in the last point file to 1e-8 of their largest value, or of the
    /// body's extent where that is larger (a field zeroed by a stage).
    fields: &'a [&'a str],
    /// history.csv's columns compared in every row to 1e-8 of the column's largest value.
    history: &'a [&'a str],
    /// The last tractions file (`tractions_NNNN.vtu`): every load point's position and force
    /// compared to 1e-8 of the largest.
    tractions: bool,
    /// The last pressure file (`pressure_NNNN.vtu`): every load point's position and force
    /// compared to 1e-8 of the largest.
    pressure: bool,
    /// Texts of warnings the serial run says: the distributed run says the same warnings
    /// containing each (as many, the same words up to ` moved by `, after which the numbers
    /// may differ in their last digits).
    warned: &'a [&'a str],
    /// Texts of warnings the distributed runs say and the serial (direct) run does not: each
    /// distributed run says exactly one warning containing each (its linear solver's).
    said: &'a [&'a str],
    /// The distributed runs' `--petsc-options` (default `-ksp_rtol 1e-12`).
    petsc_options: &'a str,
}

impl<'a> Runs<'a> {
    /// Over each of `counts` processes, replicated, comparing what every run compares only.
    const fn replicated(counts: &'a [usize]) -> Self {
        Runs {
            paraview: false,
            decompose: false,
            counts,
            measures: &[],
            fields: &[],
            history: &[],
            tractions: false,
            pressure: false,
            warned: &[],
            said: &[],
            petsc_options: "-ksp_rtol 1e-12",
        }
    }

    /// As [`Runs::replicated`] with decomposed points.
    const fn decomposed(counts: &'a [usize]) -> Self {
        Runs {
            decompose: true,
            ..Runs::replicated(counts)
        }
    }
}

/// The column `name` of the history.csv in `dir`, by row.
fn history_column(dir: &Path, name: &str) -> Vec<f64> {
    let text = std::fs::read_to_string(dir.join("history.csv")).expect("history.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let k = header
        .iter()
        .position(|h| h.trim() == name)
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"));
    lines
        .map(|line| line.split(',').nth(k).unwrap().trim().parse().unwrap())
        .collect()
}

/// The scene's runs over each of `runs.counts` processes against its serial run (direct
/// solver); the steps of each run's summary.json (its measures).
fn compare_with(
    scene: &Path,
    set: &[&str],
    tag: &str,
    runs: &Runs<'_>,
) -> Vec<Vec<serde_json::Value>> {
    let Some(_one) = mpi_job_slot() else {
        return Vec::new();
    };
    let script = scene.file_name().unwrap().to_string_lossy().to_string();
    let (counts, paraview) = (runs.counts, runs.paraview);
    let mut extra = vec!["--petsc-options", runs.petsc_options];
    if runs.decompose {
        extra.push("--decompose");
    }
    let serial_dir = temp_dir("mpi", &format!("{tag}-serial"));
    let reference = serial_reference(scene, set, &serial_dir, &[]);
    let mut measured = Vec::new();
    for &n in counts {
        let dir = temp_dir("mpi", &format!("{tag}-{n}"));
        let started = std::time::Instant::now();
        let output = run(Some(n), scene, set, &dir, &extra);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{script} -n {n}: {stderr}");
        let points = reference.positions.len() / 3;
        if n > 1 {
            pieces_are_listed(&dir, n, points, paraview);
        }
        let got = outcome(&dir);
        let label = format!("{script} -n {n}");
        same_results(&label, &got, &reference, started.elapsed().as_secs_f64());
        // the series' times are the serial run's (`k + λ_k` in stage k of a staged scene; under
        // arc-length control λ is a solution, so to 1e-8 of the largest time)
        let (times, serial_times) = (pvd_times(&dir), pvd_times(&serial_dir));
        assert_eq!(times.len(), serial_times.len(), "{label}: particles.pvd");
        let times_difference = relative_difference(&times, &serial_times);
        assert!(
            times_difference <= 1e-8,
            "{label}: particles.pvd's times {times:?} against {serial_times:?}"
        );
        for name in runs.fields {
            let field = |o: &Outcome| o.points.point_field(name).unwrap().1.to_vec();
            let (serial, distributed) = (field(&reference), field(&got));
            let largest = |values: &[f64]| values.iter().map(|v| v.abs()).fold(0.0, f64::max);
            let scale = largest(&serial).max(largest(&reference.positions));
            assert_eq!(serial.len(), distributed.len());
            let difference = (serial.iter().zip(&distributed))
                .map(|(a, b)| (a - b).abs() / scale)
                .fold(0.0, f64::max);
            eprintln!("{script} -n {n}: {name} difference {difference:.1e}");
            assert!(difference <= 1e-8, "{script} -n {n}: {name} {difference:e}");
        }
        for name in runs.measures {
            let largest = reference
                .steps
                .iter()
                .map(|s| s[name].as_f64().unwrap().abs())
                .fold(0.0, f64::max);
            assert!(largest > 0.0, "{script}: {name} is zero in every step");
            let mut difference = 0.0f64;
            for (got, serial) in got.steps.iter().zip(&reference.steps) {
                let (a, b) = (got[name].as_f64().unwrap(), serial[name].as_f64().unwrap());
                difference = difference.max((a - b).abs() / largest);
            }
            let last = reference.steps.last().unwrap()[name].as_f64().unwrap();
            eprintln!("{script} -n {n}: {name} {last:e} (serial), difference {difference:.1e}");
            assert!(difference <= 1e-8, "{script} -n {n}: {name} {difference:e}");
        }
        for name in runs.history {
            let (serial, distributed) = (
                history_column(&serial_dir, name),
                history_column(&dir, name),
            );
            let difference = relative_difference(&distributed, &serial);
            eprintln!(
                "{script} -n {n}: history.csv {name} {:e} (serial, last row), difference \
                 {difference:.1e}",
                serial.last().unwrap()
            );
            assert!(difference <= 1e-8, "{script} -n {n}: {name} {difference:e}");
        }
        // said in the log (process 0's stderr, once) and in summary.json
        let state = if runs.decompose {
            "the points are decomposed"
        } else {
            "replicated, not decomposed"
        };
        assert_eq!(stderr.matches(state).count(), 1, "{stderr}");
        assert!(
            got.warnings
                .iter()
                .any(|w| w.contains(&format!("over {n} MPI processes"))),
            "{:?}",
            got.warnings
        );
        // process 0 assembles its slab's points only: all of them alone, fewer with others
        let points = points as f64;
        for assembled in &got.assembled {
            let assembled = assembled.expect("assembled_points in every step");
            if n == 1 {
                assert_eq!(assembled, points);
            } else {
                assert!(
                    assembled > 0.0 && assembled < points,
                    "{assembled} of {points}"
                );
            }
        }
        if runs.decompose {
            decomposed_grid_is_numbered(&script, n, &got.steps);
        }
        if runs.tractions {
            same_load_points(&label, "tractions", &dir, &serial_dir, got.steps.len());
        }
        if runs.pressure {
            same_load_points(&label, "pressure", &dir, &serial_dir, got.steps.len());
        }
        for text in runs.warned {
            let said = |outcome: &Outcome| -> Vec<String> {
                (outcome.warnings.iter())
                    .filter(|w| w.contains(text))
                    .map(|w| w.split(" moved by ").next().unwrap().to_string())
                    .collect()
            };
            let serial = said(&reference);
            assert!(!serial.is_empty(), "{script}: no serial warning {text:?}");
            eprintln!("{label}: warned as serially: {serial:?}");
            assert_eq!(said(&got), serial, "{label}: warnings");
        }
        for text in runs.said {
            let said: Vec<&String> = got.warnings.iter().filter(|w| w.contains(text)).collect();
            eprintln!("{label}: said {said:?}");
            assert_eq!(said.len(), 1, "{label}: {text:?} in {:?}", got.warnings);
        }
        measured.push(got.steps);
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&serial_dir);
    measured
}

/// The last file of load points `stem` (`tractions`, `pressure`; step `last`) in `dir` against
/// the serial run's in `serial_dir`: as many load points, every position and force to 1e-8 of
/// the largest.
fn same_load_points(label: &str, stem: &str, dir: &Path, serial_dir: &Path, last: usize) {
    let read = |dir: &Path| {
        let file = dir.join(impm::output::step_file_name(stem, last));
        read_vtu(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()))
    };
    let (got, serial) = (read(dir), read(serial_dir));
    assert_eq!(
        got.points.len(),
        serial.points.len(),
        "{label}: load points"
    );
    let flat = |points: &impm::output::VtuContents| -> Vec<f64> {
        points.points.iter().flatten().copied().collect()
    };
    let positions = relative_difference(&flat(&got), &flat(&serial));
    let force =
        |points: &impm::output::VtuContents| points.point_field("force").unwrap().1.to_vec();
    let forces = relative_difference(&force(&got), &force(&serial));
    eprintln!(
        "{label}: {} load points, positions difference {positions:.1e}, forces {forces:.1e}",
        serial.points.len()
    );
    assert!(
        positions <= 1e-8,
        "{label}: load point positions {positions:e}"
    );
    assert!(forces <= 1e-8, "{label}: load point forces {forces:e}");
}

/// The times of `particles.pvd` in `dir`, in the order listed.
fn pvd_times(dir: &Path) -> Vec<f64> {
    let pvd = std::fs::read_to_string(dir.join("particles.pvd")).unwrap();
    pvd.split("timestep=\"")
        .skip(1)
        .map(|rest| rest.split('"').next().unwrap().parse().unwrap())
        .collect()
}

/// `got` against `reference` (the serial run): the same Newton iterations in every step, the
/// same shortened and rejected trials of the line search, the eq. 15 error to 1e-8 relative,
/// every point's Cauchy stress (and plastic strain, where the scene has it: the serial run must
/// yield) to 1e-8 of the largest, and positions to 1e-8; says the figures (`seconds`: how long
/// the run took).
fn same_results(label: &str, got: &Outcome, reference: &Outcome, seconds: f64) {
    let stress = relative_difference(&got.stress, &reference.stress);
    let positions = relative_difference(&got.positions, &reference.positions);
    eprintln!(
        "{label}: {seconds:.1} s, Newton {:?} (serial {:?}), eq. 15 {:?} (serial {:?}), \
         stress difference {stress:.1e}, positions {positions:.1e}",
        got.iterations, reference.iterations, got.error, reference.error
    );
    assert_eq!(got.iterations, reference.iterations, "{label}");
    // the line search (where the scene has one) shortened and rejected alike
    for (step, serial) in got.steps.iter().zip(&reference.steps) {
        assert_eq!(
            step["line_search"], serial["line_search"],
            "{label}: step {}",
            serial["step"]
        );
    }
    match (got.error, reference.error) {
        (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-8 * b.abs(), "{label}: {a} {b}"),
        (a, b) => assert_eq!(a.is_some(), b.is_some(), "{label}"),
    }
    assert!(stress <= 1e-8, "{label}: stress {stress:e}");
    if let (Some(got), Some(serial)) = (&got.plastic, &reference.plastic) {
        // the history travelled with its points
        assert!(serial.iter().any(|&e| e > 0.0), "the serial run yields");
        let plastic = relative_difference(got, serial);
        eprintln!("{label}: plastic strain difference {plastic:.1e}");
        assert!(plastic <= 1e-8, "{label}: plastic strain {plastic:e}");
    }
    assert_eq!(got.plastic.is_some(), reference.plastic.is_some());
    assert!(positions <= 1e-8, "{label}: positions {positions:e}");
}

/// Over `n` processes: every output step's particles are `n` pieces listed by a `.pvtu`,
/// which `particles.pvd` lists, with `points` points in all; with `paraview`, ParaView reads
/// the series (`scripts/check_output.py` under `pvpython`, where installed) with every field
/// and that many points in every step.
fn pieces_are_listed(dir: &Path, n: usize, points: usize, paraview: bool) {
    let pvd = std::fs::read_to_string(dir.join("particles.pvd")).unwrap();
    assert!(pvd.contains("particles_0000.pvtu"), "{pvd}");
    assert!(!pvd.contains(".vtu\""), "{pvd}");
    let pvtu = dir.join("particles_0000.pvtu");
    assert_eq!(impm::output::pvtu_pieces(&pvtu).unwrap().len(), n);
    assert_eq!(points_in_pieces(&pvtu), points);
    if !paraview {
        return;
    }
    let Some(report) = read_by_paraview(dir, &[]) else {
        return;
    };
    assert!(
        report.contains(&format!("points: {points},")),
        "{points} points expected: {report}"
    );
}

/// ParaView's report on the run in `dir` (`scripts/check_output.py` under `pvpython`, with the
/// particle fields, `point_id` and `extra`), which must say OK; `None` (said) where pvpython
/// is not installed.
fn read_by_paraview(dir: &Path, extra: &[&str]) -> Option<String> {
    let available = Command::new("pvpython")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !available {
        eprintln!("skipped the ParaView check: pvpython is not installed");
        return None;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/check_output.py");
    let output = Command::new("pvpython")
        .arg(script)
        .arg(dir)
        .args(common::PARTICLE_FIELDS)
        .arg("point_id:1")
        .args(extra)
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&output.stdout).to_string();
    assert!(
        output.status.success() && report.contains("\nOK\n"),
        "{report}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    Some(report)
}

#[test]
fn the_2d_column_over_1_2_and_3_processes_equals_the_serial_run() {
    compare("column_2d.rhai", &["cells=16", "steps=3"], "column2d", true);
}

#[test]
fn the_3d_column_over_1_2_and_3_processes_equals_the_serial_run() {
    compare("column_3d.rhai", &["cells=4", "steps=2"], "column3d", false);
}

/// The heavy column (1D) shortens a lot: points cross cells, and so the slab boundaries, from
/// step to step (the slabs are recut at every step start, balanced by points).
#[test]
fn points_crossing_slab_boundaries_stay_equal_to_the_serial_run() {
    let changes = compare("heavy_column.rhai", &["cells=8", "steps=4"], "heavy", false);
    if let [one, two, three] = changes[..] {
        assert_eq!(one, 0.0);
        assert!(two > 0.0 && three > 0.0, "{changes:?}");
    }
}

/// Decomposed points (`--decompose`): each process holds its slab's points only; the heavy
/// column's points cross the slabs between steps, so they move between the processes.
#[test]
fn decomposed_points_crossing_slabs_equal_the_serial_run() {
    let scene = shipped_scene("heavy_column.rhai");
    let changes = compare_decomposed(&scene, &["cells=8", "steps=4"], "heavy-dec", &[2, 3]);
    if let [two, three] = changes[..] {
        assert!(two > 0.0 && three > 0.0, "{changes:?}");
    }
    // GIMP: the points' domains travel too
    let set = ["cells=8", "steps=4", "basis=gimp"];
    let changes = compare_decomposed(&scene, &set, "heavy-gimp-dec", &[2]);
    if let [two] = changes[..] {
        assert!(two > 0.0, "{changes:?}");
    }
}

#[test]
fn the_2d_column_with_decomposed_points_equals_the_serial_run() {
    let scene = shipped_scene("column_2d.rhai");
    compare_decomposed(&scene, &["cells=16", "steps=3"], "column2d-dec", &[2, 3]);
}

/// Modules that add to `f_int` and `K` after the assembly add each term once over the
/// processes (`Hook::AfterAssembly`): a surface condition's boundary point by the process that
/// assembles its host. The elastic strip footing (penalty, rough): the footing pressure (the
/// condition's mean traction, a record) in every step too.
#[test]
fn the_strip_footing_over_2_and_3_processes_equals_the_serial_run() {
    let runs = Runs {
        measures: &["footing_pressure", "footing_reaction_x"],
        ..Runs::replicated(&[2, 3])
    };
    let scene = shipped_scene("strip_footing.rhai");
    compare_with(&scene, &["cells=4", "steps=2"], "footing", &runs);
}

/// F-bar's rank-one terms by the process that assembles the group's members, and the surface
/// condition's: a Tresca footing (von Mises, linear basis, F-bar) yielding under the footing.
#[test]
fn a_tresca_footing_with_fbar_over_2_and_3_processes_equals_the_serial_run() {
    let runs = Runs {
        measures: &["footing_pressure"],
        ..Runs::replicated(&[2, 3])
    };
    let scene = shipped_scene("strip_footing.rhai");
    let set = [
        "material=tresca",
        "fbar=true",
        "basis=linear",
        "cells=4",
        "steps=3",
        "settlement=0.015",
    ];
    compare_with(&scene, &set, "tresca-fbar", &runs);
}

/// The follower pressure over several processes, replicated (issue 14): its force is part of
/// the replicated `f_ext` (every process adds and follows it in full), its load stiffness is
/// added by process 0 alone (the shares of `K` are summed). The thick cylinder under pressure
/// control (`control=load`, 4 cells, 6 steps to p = 0.6 σ_y, past the elastic limit 0.433 σ_y:
/// the wall yields): the same Newton iterations, stresses, plastic strain and positions as the
/// serial run, history.csv's `inner_pressure` and `inner_displacement` to 1e-8.
#[test]
fn the_follower_pressure_over_2_and_3_processes_equals_the_serial_run() {
    let runs = Runs {
        history: &["inner_pressure", "inner_displacement"],
        ..Runs::replicated(&[2, 3])
    };
    let scene = shipped_scene("thick_cylinder.rhai");
    let set = ["control=load", "cells=4", "steps=6", "last=0.6"];
    compare_with(&scene, &set, "pressure", &runs);
}

/// The shipped scene `script` (with `set`) under `mpirun -n 2 --decompose` is refused, naming
/// `named` once and saying to run it without `--decompose`, without an abort; its standard
/// error (empty where `mpirun` does not run).
fn refused_with_decomposed_points(tag: &str, script: &str, set: &[&str], named: &str) -> String {
    let Some(_one) = mpi_job_slot() else {
        return String::new();
    };
    let dir: PathBuf = temp_dir("mpi", tag);
    let stderr = refused(2, &shipped_scene(script), set, &dir, &["--decompose"]);
    assert_eq!(stderr.matches(named).count(), 1, "{stderr}");
    assert!(stderr.contains("without --decompose"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
    stderr
}

/// Stress recovery fits each point's stress over its neighbours, which may be on another
/// process: with decomposed points it is refused before any point is spawned (the 2D column
/// with `recovery=mls`), naming it once.
#[test]
fn stress_recovery_is_refused_with_decomposed_points() {
    refused_with_decomposed_points(
        "recovery-decomposed",
        "column_2d.rhai",
        &["recovery=mls"],
        "stress recovery (fits over neighbouring points",
    );
}

/// The ghost penalty's faces by process 0 (every process finds the same faces): the sliver
/// column (1D, B-splines q = 3, a sliver of material in the top cell), replicated.
#[test]
fn the_ghost_penalty_over_2_and_3_processes_equals_the_serial_run() {
    let runs = Runs::replicated(&[2, 3]);
    let scene = shipped_scene("sliver_column.rhai");
    compare_with(&scene, &["steps=2"], "sliver", &runs);
}

/// F-bar with decomposed points: a group is the F-bar points of one cell, so one process holds
/// it; its coupling group is shared with the others for the pattern
/// (`decomposition::agree_on_grid`). A nearly incompressible 2D column (as
/// `column_2d_nearly_incompressible.rhai` with 8 cells, `fbar: true`) whose top cell, above the
/// 8 full ones and on the top slab's process, holds one row of its 4 × 4 points: a sparse F-bar
/// cell, which `fbar_sparse_cells` (summary.json and history.csv, every step) counts as the
/// serial run does, over every process (before, process 0's cells only: 0).
const FBAR_COLUMN: &str = "
const soil = material(#{ name: \"column\", E: 1.0e6, nu: 0.49, density: 1.0 });
grid(#{ lower: [0.0, 0.0], upper: [6.25, 56.25], cells: [1, 9], basis: \"bspline\", order: 3 });
body(#{ name: \"column\", material: soil, region: box([0.0, 0.0], [6.25, 51.5625]), ppc: 4, fbar: true });
body_force([0.0, -800.0]);
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0 || x[0] == 6.25, [0]);
load_steps(2);
analytic_column(#{ axis: 1, height: 51.5625, material: soil, body_force: -800.0 });
";

#[test]
fn fbar_with_decomposed_points_equals_the_serial_run() {
    let runs = Runs {
        measures: &["fbar_sparse_cells"],
        history: &["fbar_sparse_cells"],
        ..Runs::decomposed(&[2, 3])
    };
    compare_scene_text(FBAR_COLUMN, "fbar_column.rhai", "fbar-dec", &runs);
}

/// [`compare_with`] of the scene `text`, written as `name` into a folder of its own (removed
/// after): the steps of each run.
fn compare_scene_text(
    text: &str,
    name: &str,
    tag: &str,
    runs: &Runs<'_>,
) -> Vec<Vec<serde_json::Value>> {
    let (dir, scene) = scene_file(&format!("{tag}-scene"), name, text);
    let measured = compare_with(&scene, &[], tag, runs);
    let _ = std::fs::remove_dir_all(&dir);
    measured
}

/// The measure `name` summed over the steps is more than zero in each of `runs` (the steps
/// of each run; none where MPI is missing): said and asserted.
fn counted_in_every_run(label: &str, runs: &[Vec<serde_json::Value>], name: &str) {
    let sums = summed_over_steps(runs, name);
    eprintln!("{label}: {name} summed over the steps {sums:?}");
    assert!(
        sums.iter().all(|&sum| sum > 0.0),
        "{label}: {name} {sums:?}"
    );
}

/// A staged scene with `zero_displacements` (a gravity stage, then a stage measuring
/// displacements from its start, the weight held) with decomposed points: each point's origin
/// travels with it (`decomposition::carry_displacement_origins`); the `displacement` field
/// (zero from the second stage's start: every process zeroed its own points, which had
/// settled by about 0.1 of the body's height) equals the serial run's to 1e-8 of the body's
/// extent. (Under decomposition a scene can have one load only, the body force, called once.)
const STAGED_BLOCK: &str =
    "grid(#{ lower: [0.0, 0.0], upper: [1.0, 2.0], cells: [4, 8], basis: \"bspline\", order: 2 });
const soil = material(#{ name: \"soil\", E: 1000.0, nu: 0.3, density: 1.0 });
body(#{ name: \"soil\", material: soil, region: box([0.0, 0.0], [1.0, 1.5]), ppc: 2 });
fix(|x| x[1] == 0.0);
fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);
stage(#{ name: \"gravity\", steps: 2 });
body_force([0.0, -100.0]);
stage(#{ name: \"more\", steps: 1, zero_displacements: true });
";

#[test]
fn a_staged_scene_zeroing_displacements_with_decomposed_points_equals_the_serial_run() {
    let runs = Runs {
        fields: &["displacement"],
        ..Runs::decomposed(&[2, 3])
    };
    compare_scene_text(STAGED_BLOCK, "staged_block.rhai", "staged-dec", &runs);
}

/// A block on a fixed base between two rollers under its weight (stage "gravity", 2 steps),
/// the rollers then released (stage "open", 2 steps: their forces at the end of "gravity"
/// become loads ramped down to zero, and the block spreads sideways), with decomposed points
/// and grid. The reactions sum the owners' nodes over the processes, and a released force is
/// added by the node's owner only: the base's and the left roller's reactions and the
/// external resultant in summary.json (every step) and history.csv equal the serial run's to
/// 1e-8, and the base carries the block's weight, `λ ρ g V = λ 150` in "gravity" and 150 in
/// "open", to the Newton tolerance (1e-6 asserted).
const RELEASED_BLOCK: &str =
    "grid(#{ lower: [0.0, 0.0], upper: [1.0, 2.0], cells: [4, 8], basis: \"bspline\", order: 2 });
const soil = material(#{ name: \"soil\", E: 1000.0, nu: 0.3, density: 1.0 });
body(#{ name: \"soil\", material: soil, region: box([0.0, 0.0], [1.0, 1.5]), ppc: 2 });
fix(|x| x[1] == 0.0);
fix(|x| x[0] == 0.0, [0], #{ until_stage: \"open\" });
fix(|x| x[0] == 1.0, [0], #{ until_stage: \"open\" });
stage(#{ name: \"gravity\", steps: 2 });
body_force([0.0, -100.0]);
stage(#{ name: \"open\", steps: 2 });
record(#{ name: \"base\", quantity: \"fix1_reaction_y\" });
record(#{ name: \"left\", quantity: \"fix2_reaction_x\" });
";

#[test]
fn reactions_with_decomposed_points_and_grid_equal_the_serial_run() {
    let (dir, scene) = scene_file("released-scene", "released_block.rhai", RELEASED_BLOCK);
    let runs = Runs {
        measures: &["fix1_reaction_y", "fix2_reaction_x", "external_force_y"],
        history: &["base", "left"],
        ..Runs::decomposed(&[2, 3])
    };
    compare_with(&scene, &[], "released-dec", &runs);
    // the serial run (compared with above): the base carries the weight
    if mpirun_available() {
        let serial = temp_dir("mpi", "released-weight");
        let output = run(None, &scene, &[], &serial, &[]);
        assert!(output.status.success());
        let base = history_column(&serial, "base");
        let factors = history_column(&serial, "load_factor");
        assert_eq!(base.len(), 4);
        for (k, (reaction, factor)) in base.iter().zip(&factors).enumerate() {
            let weight = if k < 2 { 150.0 * factor } else { 150.0 };
            let error = (reaction - weight).abs() / 150.0;
            eprintln!(
                "released block, step {}: base reaction {reaction}, weight {weight}, error {error:.1e}",
                k + 1
            );
            assert!(error <= 1e-6, "step {}: {reaction} against {weight}", k + 1);
        }
        let _ = std::fs::remove_dir_all(&serial);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A block whose points fill only the lowest 2 of the grid's 4 cell layers along the slab
/// axis: over 3 processes the slabs, balanced by points, give process 1 no points at all
/// (layer 0 goes to process 0, layer 1 to process 2), so it has no nodes and no DOFs but
/// takes part in every collective call (the matrix's block size, the rigid-body modes, the
/// sums, the correction's scatter).
const HALF_FILLED_BLOCK: &str =
    "grid(#{ lower: [0.0, 0.0], upper: [1.0, 2.0], cells: [2, 4], basis: \"bspline\", order: 2 });
const soil = material(#{ name: \"soil\", E: 1000.0, nu: 0.3, density: 1.0 });
body(#{ name: \"soil\", material: soil, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 2 });
fix(|x| x[1] == 0.0);
fix(|x| x[0] == 0.0, [0]);
body_force([0.0, -100.0]);
load_steps(2);
";

/// A process that holds no points under `--decompose` (`HALF_FILLED_BLOCK`, `-n 3`): the run
/// ends, with exit status 0, within a bounded time (no hang), process 1's piece of the
/// particle file has no points, and the run equals the serial one (iterations, eq. 15 error,
/// stresses, positions to 1e-8, the base's reaction in every step).
#[test]
fn a_process_holding_no_points_takes_part_and_the_run_equals_the_serial_run() {
    if !mpirun_available() {
        return;
    }
    let (dir, scene) = scene_file(
        "empty-slab-scene",
        "half_filled_block.rhai",
        HALF_FILLED_BLOCK,
    );
    {
        let _one = one_job_at_a_time();
        let out = temp_dir("mpi", "empty-slab-3");
        let logs = temp_dir("mpi", "empty-slab-logs");
        let limit = Duration::from_secs(120);
        let (status, stderr) = launch_within(3, &scene, &[], &out, &["--decompose"], &logs, limit)
            .expect("the run over 3 processes, one without points, ends (no hang)");
        assert!(status.success(), "{stderr}");
        let pieces: Vec<usize> = (0..3)
            .map(|k| {
                let piece = out.join(format!("particles_0002_p{k}.vtu"));
                read_vtu(&piece).unwrap().points.len()
            })
            .collect();
        eprintln!("half-filled block -n 3: points per process {pieces:?}");
        assert_eq!(pieces[1], 0, "{pieces:?}");
        assert!(pieces[0] > 0 && pieces[2] > 0, "{pieces:?}");
        let _ = std::fs::remove_dir_all(&out);
        let _ = std::fs::remove_dir_all(&logs);
    }
    let runs = Runs {
        measures: &["fix1_reaction_y"],
        ..Runs::decomposed(&[3])
    };
    compare_with(&scene, &[], "empty-slab-dec", &runs);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A point's displacement origin, packed as its point-state part and given to a point spawned
/// afresh, is the same; a point without one gets none; a short record is an error
/// (`decomposition::pack_origin`, `unpack_origin`: the origin travels with its point).
#[test]
fn a_displacement_origin_travels_with_its_point() {
    use bevy_ecs::world::World;
    use impm::effects::distributed::decomposition::{pack_origin, unpack_origin};
    use impm::effects::stages::DisplacementOrigin;
    let mut world = World::new();
    let origin = DisplacementOrigin(nalgebra::SVector::<f64, 2>::new(0.25, -1.5e-3));
    let with = world.spawn(origin).id();
    let without = world.spawn_empty().id();
    for (from, expected) in [(with, Some(origin)), (without, None)] {
        let mut values = Vec::new();
        pack_origin::<2>(world.entity(from), &mut values);
        assert_eq!(values.len(), 3);
        let mut arrived = world.spawn_empty();
        unpack_origin::<2>(&mut arrived, 0, &values).unwrap();
        assert_eq!(arrived.get::<DisplacementOrigin<2>>().copied(), expected);
    }
    let mut arrived = world.spawn_empty();
    assert!(unpack_origin::<2>(&mut arrived, 0, &[1.0, 0.5]).is_err());
    assert!(unpack_origin::<2>(&mut arrived, 0, &[]).is_err());
}

/// A von Mises column under a heavy self-weight (1D): it yields from the base up, and its
/// points cross cells, and so slabs, between steps, taking their plastic history along.
const PLASTIC_COLUMN: &str = r#"
let cells = 8;
let steps = 4;
const height = 50.0;
const soil = material(#{ name: "column", model: "von_mises", E: 1.0e6, nu: 0.0,
                         sigma_y: 1.0e5, H: 2.0e5, density: 1.0 });
grid(#{ lower: [0.0], upper: [height], cells: [cells], basis: "bspline", order: 3 });
body(#{ name: "column", material: soil, region: box([0.0], [height]), ppc: 4 });
body_force([-16000.0]);
fix(|x| x[0] == 0.0, [0]);
load_steps(steps);
"#;

#[test]
fn a_plastic_column_with_decomposed_points_equals_the_serial_run() {
    let (dir, scene) = scene_file("plastic-scene", "plastic_column.rhai", PLASTIC_COLUMN);
    let changes = compare_decomposed(&scene, &[], "plastic-dec", &[2, 3]);
    if let [two, three] = changes[..] {
        assert!(two > 0.0 && three > 0.0, "{changes:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A heavy column (1D, as `heavy_column.rhai` with 8 cells) whose every point also carries a
/// point load, and its upper half a second one held in full from the first step (a
/// `LaterPointLoads` part): the points cross the slabs between steps, each taking its loads
/// along (`PointLoad`, `LaterPointLoads`: point-state parts of its record).
const LOADED_COLUMN: &str = r#"
const height = 50.0;
const soil = material(#{ name: "column", E: 1.0e6, nu: 0.0, density: 1.0 });
grid(#{ lower: [0.0], upper: [height], cells: [8], basis: "bspline", order: 3 });
body(#{ name: "column", material: soil, region: box([0.0], [height]), ppc: 4 });
body_force([-20000.0]);
point_load(|x| true, [-1500.0]);
point_load(|x| x[0] > 25.0, [-1000.0], #{ held: true });
fix(|x| x[0] == 0.0, [0]);
load_steps(4);
"#;

/// Point loads with decomposed points (`-n 2`, `-n 3`): the same Newton iterations, stresses
/// and positions as the serial run, the `point_load` field (λ P, by `PointId` over the
/// processes' pieces), the base's reaction and the external resultant in every step to 1e-8;
/// every point is loaded, so the points that change process (more than zero) are loaded ones.
#[test]
fn point_loads_with_decomposed_points_equal_the_serial_run() {
    let runs = Runs {
        measures: &["fix1_reaction_x", "external_force_x"],
        fields: &["point_load"],
        ..Runs::decomposed(&[2, 3])
    };
    let runs = compare_scene_text(LOADED_COLUMN, "loaded_column.rhai", "loaded-dec", &runs);
    counted_in_every_run("loaded column", &runs, "points_changing_process");
}

/// Tractions and a load at a position with decomposed points, where a load point's support
/// reaches another process's nodes. A block (4 × 4 cells) under its weight with a second one
/// (2 × 4 cells) on its right half, a traction pushing on the left side of the lower block
/// and a `point_load_at` just above the lower block's left half, in the empty part of the
/// cell layer above it: its host is the nearest material point, in the layer below. Over 3
/// processes the slabs, balanced by points, put that layer on process 1 and the load point's
/// layer on process 2: part of the load point's support is grid nodes only process 2's points
/// touch (the upper block's), active in the serial run, which the host's process must count
/// as active and whose forces it sends to their owner (`tractions::active_elsewhere`; without
/// it the `-n 3` run differs from the serial one). The same Newton iterations, stresses and
/// positions as the serial run; the reactions and the external resultant in every step, and
/// every load point's position and force in the last tractions file, to 1e-8.
const TRACTION_BLOCKS: &str = r#"
grid(#{ lower: [-0.25, 0.0], upper: [1.25, 2.0], cells: [6, 8], basis: "bspline", order: 2 });
const soil = material(#{ name: "soil", E: 1000.0, nu: 0.3, density: 1.0 });
body(#{ name: "lower", material: soil, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 2 });
body(#{ name: "upper", material: soil, region: box([0.5, 1.0], [1.0, 2.0]), ppc: 2 });
body_force([0.0, -60.0]);
traction(#{ on: [[0.0, 0.0], [0.0, 1.0]], traction: [8.0, 0.0] });
point_load_at(#{ at: [0.3, 1.05], force: [0.0, -4.0] });
fix(|x| x[1] == 0.0);
load_steps(3);
"#;

/// The reactions, the external resultant and the tractions file of the traction scenes.
const TRACTION_RUNS: Runs<'static> = Runs {
    measures: &[
        "fix1_reaction_x",
        "fix1_reaction_y",
        "external_force_x",
        "external_force_y",
    ],
    tractions: true,
    ..Runs::decomposed(&[2, 3])
};

#[test]
fn a_load_point_reaching_another_process_s_nodes_equals_the_serial_run() {
    compare_scene_text(
        TRACTION_BLOCKS,
        "traction_blocks.rhai",
        "traction-dec",
        &TRACTION_RUNS,
    );
}

/// A 2D column between rollers (ν = 0) compressed by its weight and by a shear traction down
/// its left side, which carries a quarter of the load: its points cross the slabs, and the
/// traction points follow their hosts to other processes (`load_points_changing_process` more
/// than zero over 2 and over 3 processes), equal to the serial run as above.
const TRACTION_COLUMN: &str = r#"
grid(#{ lower: [-0.5, 0.0], upper: [1.0, 4.0], cells: [3, 8], basis: "bspline", order: 2 });
const soil = material(#{ name: "column", E: 1000.0, nu: 0.0, density: 1.0 });
body(#{ name: "column", material: soil, region: box([0.0, 0.0], [1.0, 4.0]), ppc: 2 });
body_force([0.0, -100.0]);
traction(#{ on: [[0.0, 0.0], [0.0, 4.0]], traction: [0.0, -25.0] });
fix(|x| x[1] == 0.0);
fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);
let steps = 4;
load_steps(steps);
"#;

#[test]
fn traction_points_following_their_hosts_to_other_processes_equal_the_serial_run() {
    let runs = Runs {
        measures: &["fix1_reaction_y", "external_force_y"],
        ..TRACTION_RUNS
    };
    let name = "traction_column.rhai";
    let runs = compare_scene_text(TRACTION_COLUMN, name, "traction-column-dec", &runs);
    counted_in_every_run("traction column", &runs, "load_points_changing_process");
}

/// The steps done of the checkpoint in `dir`, if it has one.
fn checkpoint_steps(dir: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(dir.join("checkpoint.json")).ok()?;
    serde_json::from_str::<serde_json::Value>(&text).ok()?["steps_done"].as_u64()
}

/// The process to signal in a job: process 1 of a run over several processes (it writes
/// nothing of the run's own), the one process otherwise.
fn signalled_process(job: &Child, processes: Option<usize>) -> u32 {
    let rank = match processes {
        Some(n) if n > 1 => 1,
        Some(_) => 0,
        None => return job.id(),
    };
    let started = std::time::Instant::now();
    loop {
        if let Some(pid) = process_of_rank(job.id(), rank) {
            return pid;
        }
        assert!(
            started.elapsed().as_secs() < 60,
            "no process {rank} in the job"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Sends `signal` ("STOP", "INT", "CONT") to the process `pid`.
fn signal(pid: u32, signal: &str) {
    let sent = Command::new("kill")
        .args([format!("-{signal}"), pid.to_string()])
        .status()
        .unwrap();
    assert!(sent.success(), "kill -{signal} {pid}");
}

/// Waits for `job` at most `limit` (killed and failed after it: it hung); its exit status.
fn wait_for(job: &mut Child, limit: Duration) -> ExitStatus {
    let started = std::time::Instant::now();
    loop {
        if let Some(status) = job.try_wait().unwrap() {
            return status;
        }
        if started.elapsed() > limit {
            let _ = job.kill();
            let _ = job.wait();
            panic!("the job did not end within {limit:?}: it hung");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// What [`run_until_checkpoint`] does once the run's checkpoint is after the step it waits
/// for, while the run is held (SIGSTOP).
enum Then<'a> {
    /// SIGINT: the run finishes the step in flight and ends "interrupted" (over several
    /// processes the stop is agreed between the steps).
    Interrupt,
    /// Puts a folder (holding one named `.0`) in the way of the binary file of the next
    /// checkpoint (2 steps after the one written): process 0 fails to write it.
    BlockNextCheckpoint(&'a str),
}

/// Runs the scene under `mpirun -n N` (with `extra`) keeping a checkpoint every 2 steps; once
/// a checkpoint after step `after` or later is written, holds the run (SIGSTOP to process 1 of
/// the job, or to the one process, whose others then wait for it in their next collective
/// call, so it cannot run to its end meanwhile), does `then`, and lets it go on (SIGCONT).
/// Returns the run's exit status, standard error, the steps of the checkpoint it was held
/// after and those of its checkpoint at the end. (A run can still end between two looks at
/// its checkpoint on a loaded machine: [`stopped_after`] stops one at an exact step.)
fn run_until_checkpoint(
    processes: usize,
    scene: &Path,
    set: &[&str],
    dir: &Path,
    extra: &[&str],
    after: u64,
    then: Then<'_>,
) -> (ExitStatus, String, u64, u64) {
    let logs = dir.with_extension("logs");
    let mut extra = extra.to_vec();
    extra.extend(["--checkpoint-every", "2"]);
    let args = run_arguments(scene, set, dir, &extra);
    let mut job = spawn_logged(impm_command(Some(processes), &args), &logs);
    let pid = signalled_process(&job, Some(processes));
    let started = std::time::Instant::now();
    let stderr = || std::fs::read_to_string(logs.join("stderr.txt")).unwrap();
    while checkpoint_steps(dir).is_none_or(|n| n < after) {
        if job.try_wait().unwrap().is_some() {
            panic!(
                "the run ended before a checkpoint after step {after}: {}",
                stderr()
            );
        }
        assert!(
            started.elapsed().as_secs() < 300,
            "no checkpoint: {}",
            stderr()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    signal(pid, "STOP");
    let held_after = checkpoint_steps(dir).unwrap();
    match then {
        Then::Interrupt => signal(pid, "INT"),
        Then::BlockNextCheckpoint(name) => {
            let blocked = dir.join(format!("checkpoint_{:04}.bin", held_after + 2));
            std::fs::create_dir_all(blocked.join(name)).unwrap();
        }
    }
    signal(pid, "CONT");
    let status = wait_for(&mut job, Duration::from_secs(600));
    let stderr = stderr();
    assert!(!stderr.contains("MPI_Abort"), "ended by an abort: {stderr}");
    let _ = std::fs::remove_dir_all(&logs);
    let done = checkpoint_steps(dir).expect("a checkpoint");
    (status, stderr, held_after, done)
}

/// [`run_until_checkpoint`] with an interrupt: the run ends "interrupted" before its last step,
/// with a checkpoint; returns the checkpoint's steps done.
fn interrupt_after_checkpoint(
    processes: usize,
    scene: &Path,
    set: &[&str],
    dir: &Path,
    extra: &[&str],
    after: u64,
) -> u64 {
    let (status, stderr, _, done) =
        run_until_checkpoint(processes, scene, set, dir, extra, after, Then::Interrupt);
    assert!(
        !status.success(),
        "an interrupted run exits non-zero: {stderr}"
    );
    assert!(stderr.contains("interrupted after load step"), "{stderr}");
    let summary = read_summary(dir);
    assert_eq!(summary["status"], "interrupted", "{summary}");
    resume_command_is_the_launch(Some(processes), extra, &stderr, &summary);
    let steps = summary["steps"].as_array().unwrap().len() as u64;
    assert!(
        steps < summary["planned_steps"].as_u64().unwrap(),
        "the run ended before the signal"
    );
    assert!(
        done >= after && done <= steps,
        "checkpoint after {done} of {steps} steps"
    );
    done
}

/// Runs the scene (under `mpirun -n N` when `processes` is given, with `extra`) keeping a
/// checkpoint every 2 steps and stopping after step `steps` (`--stop-after`: the step is
/// exact, whatever the machine's load): the run ends "interrupted" after exactly `steps`
/// steps, exits non-zero, and prints and records the command that resumes it (the launch,
/// without `--stop-after`); returns the checkpoint's steps done (the last even step).
fn stopped_after(
    processes: Option<usize>,
    scene: &Path,
    set: &[&str],
    dir: &Path,
    extra: &[&str],
    steps: u64,
) -> u64 {
    let limit = steps.to_string();
    let mut arguments = extra.to_vec();
    arguments.extend(["--checkpoint-every", "2", "--stop-after", &limit]);
    let output = run(processes, scene, set, dir, &arguments);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success(),
        "a stopped run exits non-zero: {stderr}"
    );
    assert!(!stderr.contains("MPI_Abort"), "ended by an abort: {stderr}");
    let said = format!("interrupted after load step {steps}");
    assert!(stderr.contains(&said), "{stderr}");
    let summary = read_summary(dir);
    assert_eq!(summary["status"], "interrupted", "{summary}");
    assert_eq!(summary["steps"].as_array().unwrap().len() as u64, steps);
    resume_command_is_the_launch(processes, extra, &stderr, &summary);
    assert!(
        !summary["resume"].as_str().unwrap().contains("--stop-after"),
        "{summary}"
    );
    let done = checkpoint_steps(dir).expect("a checkpoint");
    assert_eq!(done, steps - steps % 2, "checkpoints every 2 steps");
    done
}

/// The command an interrupted run prints and records (summary.json's `resume`) to continue it
/// is the one it was launched with: `mpirun -n N impm run ..` under `mpirun -n N` (`impm run
/// ..` serially), with `--decompose` if it was given, and `--resume`.
fn resume_command_is_the_launch(
    processes: Option<usize>,
    extra: &[&str],
    stderr: &str,
    summary: &serde_json::Value,
) {
    let said = "to continue from the last checkpoint: ";
    let printed = stderr
        .lines()
        .find_map(|line| line.split_once(said).map(|(_, command)| command.trim()))
        .unwrap_or_else(|| panic!("no resume command: {stderr}"));
    assert_eq!(summary["resume"].as_str(), Some(printed), "{summary}");
    let launcher = match processes {
        Some(n) => format!("mpirun -n {n} impm run "),
        None => "impm run ".to_string(),
    };
    assert!(
        printed.starts_with(&launcher),
        "{printed}: not {launcher}.."
    );
    let decompose = extra.contains(&"--decompose");
    let words: Vec<&str> = printed.split_whitespace().collect();
    assert_eq!(words.contains(&"--decompose"), decompose, "{printed}");
    assert!(words.contains(&"--resume"), "{printed}");
    eprintln!("resume command: {printed}");
}

/// Resumes the run of `dir` (under `mpirun -n N` when `processes` is given, with `extra`) and
/// checks it completed: every step listed once in summary.json and in `particles.pvd`; returns
/// its outcome and how long it took.
fn resume(
    processes: Option<usize>,
    scene: &Path,
    set: &[&str],
    dir: &Path,
    extra: &[&str],
) -> (Outcome, f64) {
    let started = std::time::Instant::now();
    let mut extra = extra.to_vec();
    let folder = dir.display().to_string();
    extra.extend(["--resume", &folder]);
    let output = run(processes, scene, set, dir, &extra);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("resuming"), "{stderr}");
    let seconds = started.elapsed().as_secs_f64();
    let got = outcome(dir);
    let pvd = std::fs::read_to_string(dir.join("particles.pvd")).unwrap();
    for step in 0..=got.iterations.len() {
        let name = format!("particles_{step:04}.");
        assert_eq!(pvd.matches(&name).count(), 1, "{name} in {pvd}");
    }
    (got, seconds)
}

/// A run's checkpoint parts: (name, numbers), read back from the header and binary file.
fn checkpoint_parts(dir: &Path) -> Vec<(String, Vec<f64>)> {
    let text = std::fs::read_to_string(dir.join("checkpoint.json")).unwrap();
    let header: serde_json::Value = serde_json::from_str(&text).unwrap();
    let data = std::fs::read(dir.join(header["data"]["file"].as_str().unwrap())).unwrap();
    let mut numbers = data
        .chunks_exact(8)
        .map(|bytes| f64::from_le_bytes(bytes.try_into().unwrap()));
    header["parts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|part| {
            let count = part["count"].as_u64().unwrap() as usize;
            let values: Vec<f64> = numbers.by_ref().take(count).collect();
            assert_eq!(values.len(), count);
            (part["name"].as_str().unwrap().to_string(), values)
        })
        .collect()
}

/// Checkpoints and resume with decomposed points, on the heavy column (1D; it shortens by a
/// third, so points cross slabs and change process; eq. 15 error): a run interrupted after
/// step 3 (`--stop-after 3`: at that step whatever the machine's load; until 2026-11-26 a
/// signal, which a loaded machine could deliver after the run's end) with the checkpoint of
/// step 2 (one every 2 steps) and resumed gives the serial run's results (Newton iterations
/// in every step, the eq. 15 error to 1e-8 relative, stresses and positions to 1e-8) whatever
/// wrote the checkpoint and whatever resumes it: decomposed `-n 2` resumed by `-n 2`,
/// decomposed `-n 3` resumed by decomposed `-n 1` (refused serially first: a checkpoint in
/// pieces is resumed with decomposed points only, and the message says how; until 2026-12-08
/// the checkpoint was one serial file and this case resumed serially), serial resumed by
/// decomposed `-n 2`. A completed decomposed run's last checkpoint holds the serial one's
/// parts and numbers (to 1e-12 of each part's largest number): over one process in the serial
/// format, over several in pieces (the points' core part rebuilt from the pieces' records,
/// every point once: `same_checkpoint`).
#[test]
fn a_decomposed_run_resumes_from_checkpoints_of_any_process_count() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("heavy_column.rhai");
    let set = ["cells=8", "steps=8"];
    let decomposed = ["--petsc-options", "-ksp_rtol 1e-12", "--decompose"];
    let serial_dir = temp_dir("mpi", "resume-serial");
    let reference = serial_reference(&scene, &set, &serial_dir, &["--checkpoint-every", "2"]);
    // a checkpoint in pieces (-n 3) is refused serially, saying how to resume it (below),
    // and resumed by -n 1 with decomposed points
    let cases: [(&str, Option<usize>, Option<usize>); 3] = [
        ("-n 2 then -n 2", Some(2), Some(2)),
        ("-n 3 then -n 1", Some(3), Some(1)),
        ("serial then -n 2", None, Some(2)),
    ];
    for (label, first, then) in cases {
        let dir = temp_dir("mpi", "resume-heavy");
        let flags = |processes: Option<usize>| {
            if processes.is_some() {
                &decomposed[..]
            } else {
                &[][..]
            }
        };
        let done = stopped_after(first, &scene, &set, &dir, flags(first), 3);
        if first.is_some_and(|n| n > 1) {
            let said = refused_serially(&scene, &set, &dir);
            assert!(said.contains("--decompose --resume"), "{said}");
        }
        let (got, seconds) = resume(then, &scene, &set, &dir, flags(then));
        eprintln!("heavy column, {label}: stopped after step 3, checkpoint after step {done}");
        same_results(&format!("heavy column, {label}"), &got, &reference, seconds);
        if then.is_some() {
            same_checkpoint(label, &dir, &serial_dir);
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&serial_dir);
}

/// A serial `--resume` of the checkpoint in pieces in `dir`: refused (non-zero, no panic),
/// saying that it is in pieces; its standard error.
fn refused_serially(scene: &Path, set: &[&str], dir: &Path) -> String {
    let folder = dir.display().to_string();
    let output = run(None, scene, set, dir, &["--resume", &folder]);
    let stderr = String::from_utf8_lossy(&output.stderr).to_string();
    assert!(!output.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        stderr.contains("written in")
            && stderr.contains("pieces")
            && stderr.contains("mpirun -n N impm run"),
        "{stderr}"
    );
    stderr
}

/// The last checkpoint in `dir` (of a resumed decomposed run) against the serial run's in
/// `serial_dir`: the same parts, each to 1e-12 of its largest number.
///
/// A checkpoint in pieces (decomposed over several processes) holds the parts its points'
/// records do not carry, each compared so; of the carried ones, the core's `points` (x, u, F,
/// V) is rebuilt from the pieces' records and compared so, every point once
/// ([`points_of_pieces`]); the others (a material's history, the load points placed from
/// their hosts) must be named as carried.
fn same_checkpoint(label: &str, dir: &Path, serial_dir: &Path) {
    let serial = checkpoint_parts(serial_dir);
    let mut decomposed = checkpoint_parts(dir);
    let header: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("checkpoint.json")).unwrap())
            .unwrap();
    let carried: Vec<String> = header["pieces"]["carried"]
        .as_array()
        .map(|names| {
            names
                .iter()
                .map(|name| name.as_str().unwrap().to_string())
                .collect()
        })
        .unwrap_or_default();
    if header["pieces"].is_object() {
        assert!(carried.iter().any(|name| name == "points"), "{header}");
        decomposed.push(("points".to_string(), points_of_pieces(dir)));
    }
    for (name, a) in &serial {
        let Some((_, b)) = decomposed.iter().find(|(other, _)| other == name) else {
            assert!(
                carried.contains(name),
                "{label}: part {name} is neither in the checkpoint nor carried by its pieces"
            );
            eprintln!("{label}: checkpoint part {name}: carried by the pieces' records");
            continue;
        };
        let difference = relative_difference(b, a);
        eprintln!(
            "{label}: checkpoint part {name}: {} numbers, difference {difference:.1e}",
            a.len()
        );
        assert!(difference <= 1e-12, "{label}: part {name}: {difference:e}");
    }
    for (name, _) in &decomposed {
        assert!(
            serial.iter().any(|(other, _)| other == name),
            "{label}: the checkpoint has a part {name} the serial one has not"
        );
    }
}

/// The core's checkpoint part (`points`: per point x, u, F by rows and V, in `PointId` order)
/// rebuilt from the records of a checkpoint in pieces (`checkpoint_NNNN_pK.bin`, each record
/// `id, body, x, X, u, F by rows, m, V0, V, n, n numbers`); every point id once, 0 to N - 1,
/// each piece's count and length as the header names them.
fn points_of_pieces(dir: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(dir.join("checkpoint.json")).unwrap();
    let header: serde_json::Value = serde_json::from_str(&text).unwrap();
    let pieces = &header["pieces"];
    let d = pieces["dim"].as_u64().unwrap() as usize;
    let fixed = 2 + 3 * d + d * d + 4;
    let mut points: Vec<(u64, Vec<f64>)> = Vec::new();
    for piece in pieces["files"].as_array().unwrap() {
        let file = piece["file"].as_str().unwrap();
        let data = std::fs::read(dir.join(file)).unwrap();
        assert_eq!(
            data.len() as u64,
            piece["bytes"].as_u64().unwrap(),
            "{file}"
        );
        let numbers: Vec<f64> = data
            .chunks_exact(8)
            .map(|bytes| f64::from_le_bytes(bytes.try_into().unwrap()))
            .collect();
        let mut rest = &numbers[..];
        let mut count = 0;
        while !rest.is_empty() {
            let n = rest[fixed - 1] as usize;
            let record = &rest[..fixed + n];
            let mut core = record[2..2 + d].to_vec(); // x
            core.extend(&record[2 + 2 * d..2 + 3 * d]); // u
            core.extend(&record[2 + 3 * d..2 + 3 * d + d * d]); // F by rows
            core.push(record[2 + 3 * d + d * d + 2]); // V
            points.push((record[0] as u64, core));
            rest = &rest[fixed + n..];
            count += 1;
        }
        assert_eq!(count, piece["points"].as_u64().unwrap(), "{file}");
    }
    points.sort_by_key(|(id, _)| *id);
    let ids: Vec<u64> = points.iter().map(|(id, _)| *id).collect();
    assert!(
        ids.iter().enumerate().all(|(k, &id)| id == k as u64),
        "the pieces hold every point once"
    );
    points.into_iter().flat_map(|(_, core)| core).collect()
}

/// Load points in checkpoints of decomposed runs: the traction column (8 steps) decomposed
/// over 3 processes, interrupted after a checkpoint and resumed over 2, gives the serial
/// run's results (iterations, stresses, positions, the last tractions file), and its last
/// checkpoint holds the serial run's numbers, the load points' positions included (process 0
/// places the load points it does not hold from their hosts).
#[test]
fn a_decomposed_run_with_tractions_resumes_from_its_checkpoint() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let name = "traction_column.rhai";
    let (scene_dir, scene) = scene_file("traction-resume-scene", name, TRACTION_COLUMN);
    let set = ["steps=8"];
    let decomposed = ["--petsc-options", "-ksp_rtol 1e-12", "--decompose"];
    let serial_dir = temp_dir("mpi", "traction-resume-serial");
    let reference = serial_reference(&scene, &set, &serial_dir, &["--checkpoint-every", "2"]);
    let dir = temp_dir("mpi", "traction-resume");
    let done = interrupt_after_checkpoint(3, &scene, &set, &dir, &decomposed, 2);
    let (got, seconds) = resume(Some(2), &scene, &set, &dir, &decomposed);
    let label = format!("traction column, -n 3 interrupted after step {done}, then -n 2");
    same_results(&label, &got, &reference, seconds);
    same_load_points(&label, "tractions", &dir, &serial_dir, got.iterations.len());
    same_checkpoint(&label, &dir, &serial_dir);
    for dir in [dir, serial_dir, scene_dir] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// A plastic scene (the von Mises column, its history carried in the checkpoint): decomposed
/// `-n 3` interrupted after a checkpoint and resumed by `-n 2`; and a failure writing a
/// checkpoint on process 0 (a folder in the way of the binary file of the checkpoint after the
/// one of step 4 or later) under `-n 2` stops every process after that step, without an abort,
/// naming the file, with the previous checkpoint kept: resumed by `-n 2` once the folder is
/// gone, the run gives the serial run's results (iterations, stresses, plastic strain,
/// positions).
#[test]
fn a_plastic_decomposed_run_resumes_and_a_failed_checkpoint_keeps_the_previous_one() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let (scenes, scene) = scene_file(
        "resume-plastic-scene",
        "plastic_column.rhai",
        PLASTIC_COLUMN,
    );
    let set = ["steps=8"];
    let decomposed = ["--petsc-options", "-ksp_rtol 1e-12", "--decompose"];
    let serial_dir = temp_dir("mpi", "resume-plastic-serial");
    let reference = serial_reference(&scene, &set, &serial_dir, &[]);

    let dir = temp_dir("mpi", "resume-plastic");
    let done = interrupt_after_checkpoint(3, &scene, &set, &dir, &decomposed, 2);
    let (got, seconds) = resume(Some(2), &scene, &set, &dir, &decomposed);
    eprintln!("plastic column, -n 3 then -n 2: interrupted, checkpoint after step {done}");
    same_results("plastic column, -n 3 then -n 2", &got, &reference, seconds);
    let _ = std::fs::remove_dir_all(&dir);

    let dir = temp_dir("mpi", "resume-plastic-blocked");
    let (status, stderr, held, done) = run_until_checkpoint(
        2,
        &scene,
        &set,
        &dir,
        &decomposed,
        4,
        Then::BlockNextCheckpoint("in-the-way"),
    );
    let blocked = format!("checkpoint_{:04}.bin", held + 2);
    eprintln!("plastic column, -n 2: {blocked} blocked, the run said: {stderr}");
    assert!(!status.success(), "{stderr}");
    assert!(stderr.contains(&blocked), "{stderr}");
    assert!(stderr.contains("process 0 of 2 failed"), "{stderr}");
    assert_eq!(done, held, "the previous checkpoint is kept");
    let summary = read_summary(&dir);
    assert_eq!(summary["status"], "failed", "{summary}");
    let steps = summary["steps"].as_array().unwrap().len() as u64;
    assert_eq!(steps, held + 2, "{summary}");
    std::fs::remove_dir_all(dir.join(&blocked)).unwrap();
    let (got, seconds) = resume(Some(2), &scene, &set, &dir, &decomposed);
    same_results(
        "plastic column, -n 2 after a failed checkpoint",
        &got,
        &reference,
        seconds,
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&serial_dir);
    let _ = std::fs::remove_dir_all(&scenes);
}

/// A stiff base under a soft top (1D, both under their weight, one load step) with the line
/// search: the full Newton step compresses the soft top past zero volume (its linear strain
/// at the base reaches ρ b L / E = 300 × 20 / 2000 = 3, so det F = 1 − 3 < 0), so the line
/// search shortens it, and later steps that do not reduce the residual enough. With decomposed
/// points the soft top is held by the upper processes alone: a trial state inadmissible there
/// is every process's (the same kind of failure, so every process's line search shortens the
/// step), and every process judges a trial by the residual summed over all of them. Under
/// `mpirun -n 2` and `-n 3` the run equals the serial one (iterations, the line search's
/// shortened and rejected trials, stresses and positions; `compare_with`). Before, the
/// processes judged the trials by their own residual only (`-n 2`: 14 Newton iterations and
/// 10 shortened steps against the serial 11 and 6; `-n 3` hung) and a process whose points
/// were fine failed the attempt where the other shortened the step.
const SOFT_TOP: &str = r#"
const stiff = material(#{ name: "stiff", E: 1.0e6, nu: 0.0, density: 1.0 });
const soft = material(#{ name: "soft", E: 2.0e3, nu: 0.0, density: 1.0 });
grid(#{ lower: [0.0], upper: [40.0], cells: [10], basis: "bspline", order: 2 });
body(#{ name: "base", material: stiff, region: box([0.0], [20.0]), ppc: 2 });
body(#{ name: "top", material: soft, region: box([20.0], [40.0]), ppc: 2 });
body_force([-300.0]);
fix(|x| x[0] == 0.0, [0]);
load_steps(1);
solver(#{ line_search: true });
"#;

#[test]
fn the_line_search_with_decomposed_points_equals_the_serial_run() {
    let (dir, scene) = scene_file("soft-top-scene", "soft_top.rhai", SOFT_TOP);
    // the serial run shortens steps (the comparison then checks the distributed runs do alike)
    let serial = dir.join("serial");
    let output = run(None, &scene, &[], &serial, &[]);
    assert!(output.status.success());
    let summary = read_summary(&serial);
    let search = &summary["steps"][0]["line_search"];
    assert!(
        search["shortened"].as_u64().unwrap() > 0 && search["rejected"].as_u64().unwrap() > 0,
        "{summary}"
    );
    compare_decomposed(&scene, &[], "soft-top", &[2, 3]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The line search's natural level function needs the whole tangent's factor, which a divided
/// grid has not: with decomposed points (`mpirun -n 2 --decompose`) the soft top with `merit:
/// "natural"` warns once that it uses the residual test, and then does what the residual test
/// does serially (the same Newton iterations and the same shortened and rejected trials).
#[test]
fn the_natural_line_search_with_decomposed_points_says_it_uses_the_residual_test() {
    let natural = SOFT_TOP.replace(
        "solver(#{ line_search: true });",
        "solver(#{ line_search: true, merit: \"natural\" });",
    );
    assert_ne!(natural, SOFT_TOP);
    let (dir, residual_scene) = scene_file("soft-top-natural", "soft_top.rhai", SOFT_TOP);
    let natural_scene = dir.join("soft_top_natural.rhai");
    std::fs::write(&natural_scene, &natural).unwrap();
    let serial = dir.join("serial");
    assert!(
        run(None, &residual_scene, &[], &serial, &[])
            .status
            .success()
    );
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let decomposed = dir.join("decomposed");
    let output = run(Some(2), &natural_scene, &[], &decomposed, &["--decompose"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let (reference, got) = (read_summary(&serial), read_summary(&decomposed));
    let warnings: Vec<&str> = got["warnings"]
        .as_array()
        .map(|w| w.iter().filter_map(|w| w.as_str()).collect())
        .unwrap_or_default();
    assert_eq!(
        warnings
            .iter()
            .filter(
                |w| w.contains("natural level function") && w.contains("divided among processes")
            )
            .count(),
        1,
        "{warnings:?}"
    );
    for key in ["iterations", "line_search"] {
        assert_eq!(
            got["steps"][0][key], reference["steps"][0][key],
            "{key}: {got} against {reference}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Modules that read other points (stress recovery) are refused with decomposed points,
/// naming them, once, without an abort; `--decompose` outside mpirun is refused. (Point loads
/// and tractions follow their points since 2026-11-26, and so do prescribed displacements'
/// checks and probes: the tests above and below.)
#[test]
fn decomposition_refuses_what_cannot_follow_its_points() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("beam_point_load.rhai");
    let dir: PathBuf = temp_dir("mpi", "decompose-refused");
    // stress recovery fits over the neighbouring points, which may be on another process
    let recovered = dir.join("recovered_block.rhai");
    std::fs::create_dir_all(&dir).unwrap();
    let recovery = "stress_recovery(#{ order: 1, radius: 2.5 });\n";
    std::fs::write(&recovered, format!("{HALF_FILLED_BLOCK}{recovery}")).unwrap();
    let stderr = refused(2, &recovered, &[], &dir.join("out"), &["--decompose"]);
    assert_eq!(
        stderr.matches("stress recovery (fits over").count(),
        1,
        "{stderr}"
    );
    assert!(stderr.contains("without --decompose"), "{stderr}");
    let output = run(None, &scene, &[], &dir, &["--decompose"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("mpirun -n N impm run SCENE --decompose"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A failure on one process outside the Newton iteration (process 0 cannot write history.csv
/// at the end of step 1: a folder is in its way; the other process writes into its own
/// scratch folder) ends every process after that step: the processes agree on the step's
/// outcome before the next one (`effects::distributed::share_outcome`), so the job ends
/// together, without an abort, with a non-zero exit status and the cause (named `process 0 of
/// 2 failed: ...`, like another process's failure); summary.json says
/// the run failed, with step 1 done, and what was written before stays readable. Before the
/// agreement the other process went into step 2 and waited there, until process 0 gave up
/// after 20 s and aborted the job (and before that mend, forever).
#[test]
fn a_process_failing_alone_outside_newton_ends_every_process_after_that_step() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("column_2d.rhai");
    let dir = temp_dir("mpi", "fails-alone");
    std::fs::create_dir_all(dir.join("history.csv")).unwrap();
    let logs = temp_dir("mpi", "fails-alone-logs");
    // the scratch folder a process killed by an earlier abort left (its process is gone): a
    // process other than 0 removes it when it starts
    let mut gone = Command::new("true").spawn().unwrap();
    gone.wait().unwrap();
    let stale = std::env::temp_dir().join(format!("impm-process1-{}", gone.id()));
    std::fs::create_dir_all(&stale).unwrap();
    let set = ["cells=4", "steps=3"];
    let ended = launch_within(2, &scene, &set, &dir, &[], &logs, Duration::from_secs(300));
    let (status, stderr) = ended.expect("the job ends (it hung before: killed after 300 s)");
    assert!(!status.success(), "{stderr}");
    assert!(stderr.contains("history.csv"), "{stderr}");
    // process 0's own failure is named like another process's
    assert!(
        stderr.contains("load step 1: process 0 of 2 failed: "),
        "{stderr}"
    );
    assert!(!stderr.contains("MPI_Abort"), "ended by an abort: {stderr}");
    // step 1's records and particle pieces were written before the failure, and read back
    let summary = read_summary(&dir);
    assert_eq!(summary["status"], "failed", "{summary}");
    assert!(
        summary["failure"].as_str().unwrap().contains("history.csv"),
        "{summary}"
    );
    assert_eq!(summary["steps"].as_array().unwrap().len(), 1, "{summary}");
    let listed = series_is_readable(&dir, 1, 4 * 4 * 4);
    assert_eq!(listed, ["particles_0000.pvtu", "particles_0001.pvtu"]);
    assert!(!stale.exists(), "{} left", stale.display());
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&logs);
}

/// What is left to the safety net: a failure on one process before the processes' first
/// agreement (process 0 cannot lock its output folder: a live process's lock is in it; the
/// others run into their scratch folders and wait in the initial output) ends the whole job
/// with `MPI_Abort` after the failed process's wait, naming the process and the cause; the
/// lock of the other run is left as it was.
#[test]
fn a_process_failing_before_the_first_step_ends_the_job_by_an_abort() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("column_2d.rhai");
    let dir = temp_dir("mpi", "locked");
    std::fs::create_dir_all(&dir).unwrap();
    let lock = dir.join(".impm.lock");
    let holder = std::process::id().to_string();
    std::fs::write(&lock, &holder).unwrap();
    let logs = temp_dir("mpi", "locked-logs");
    let set = ["cells=4", "steps=2"];
    let ended = launch_within(2, &scene, &set, &dir, &[], &logs, Duration::from_secs(300));
    let (status, stderr) = ended.expect("the job ends (killed after 300 s: it hung)");
    assert!(!status.success(), "{stderr}");
    assert!(
        stderr.contains("error (process 0 of 2)")
            && stderr.contains(&format!("another impm run (process {holder})"))
            && stderr.contains("MPI_Abort"),
        "{stderr}"
    );
    assert_eq!(std::fs::read_to_string(&lock).unwrap(), holder);
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&logs);
}

/// The files `particles.pvd` lists, after checking that the series is readable up to step
/// `last`: it lists `particles_0000` to `particles_{last}` in order (`.pvtu` pieces or a
/// `.vtu`), each listed file reads back with `points` points.
fn series_is_readable(dir: &Path, last: usize, points: usize) -> Vec<String> {
    let pvd = std::fs::read_to_string(dir.join("particles.pvd")).unwrap();
    assert!(pvd.trim_end().ends_with("</VTKFile>"), "{pvd}");
    let listed: Vec<String> = pvd
        .split("file=\"")
        .skip(1)
        .filter_map(|rest| rest.split('"').next())
        .map(str::to_string)
        .collect();
    assert_eq!(listed.len(), last + 1, "{pvd}");
    for (step, name) in listed.iter().enumerate() {
        assert!(
            name.starts_with(&format!("particles_{step:04}.")),
            "{name} at step {step}"
        );
        let file = dir.join(name);
        let read = if name.ends_with(".pvtu") {
            points_in_pieces(&file)
        } else {
            read_vtu(&file).unwrap().points.len()
        };
        assert_eq!(read, points, "{name}");
    }
    listed
}

/// A column fixed at its base and pulled up by its own weight (a body force along +x): it
/// stretches out of the top of the grid, and its top points leave the grid at the end of a
/// step that converged; the next step's basis fails for them (a point outside the grid). In
/// 1D with Hencky's law, `E ln λ / λ = ρ b (L − X)`: the top point (X = 39) is at 42.5 after
/// step 2 and at 45.0 after step 3 (`docs/distributed.md`, "Failure handling"), past the
/// grid's 44.
const STRETCHED_COLUMN: &str = r#"
const soil = material(#{ name: "column", E: 1.0e6, nu: 0.0, density: 1.0 });
grid(#{ lower: [0.0], upper: [44.0], cells: [11], basis: "bspline", order: 2 });
body(#{ name: "column", material: soil, region: box([0.0], [40.0]), ppc: 2 });
body_force([7500.0]);
fix(|x| x[0] == 0.0, [0]);
load_steps(4);
"#;

/// Only one process's points fail: the stretched column's top points leave the grid, and with
/// decomposed points they are held by the process of the top slab alone (process 1 of 2,
/// process 2 of 3), whose basis fails at the step after. Every process stops at that step
/// (the failure is shared where the processes meet after the basis), the job ends within the
/// time allowed (killed and failed otherwise), without an abort, with a non-zero exit status;
/// the log and summary.json name the failing process and what failed; summary.json says
/// failed with the steps the serial run converged; the `.pvd` series lists every step up to
/// the last converged one, and each lists every point.
#[test]
fn a_point_leaving_the_grid_on_one_process_stops_every_process_naming_it() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let (dir, scene) = scene_file("leaves-grid", "stretched_column.rhai", STRETCHED_COLUMN);
    let points = 10 * 2;
    // the serial run: which step fails, and why
    let serial = dir.join("serial");
    let output = run(None, &scene, &[], &serial, &[]);
    assert!(!output.status.success());
    let summary = read_summary(&serial);
    assert_eq!(summary["status"], "failed", "{summary}");
    let converged = summary["steps"].as_array().unwrap().len();
    assert_eq!(converged, 3, "{summary}");
    let failure = summary["failure"].as_str().unwrap().to_string();
    assert!(
        failure.contains(&format!("load step {}", converged + 1))
            && failure.contains("left the background grid"),
        "{failure}"
    );
    series_is_readable(&serial, converged, points);
    for n in [2, 3] {
        let out = dir.join(format!("n{n}"));
        let logs = dir.join(format!("n{n}-logs"));
        let limit = Duration::from_secs(300);
        let ended = launch_within(n, &scene, &[], &out, &["--decompose"], &logs, limit);
        let (status, stderr) = ended.expect("the job ends (killed after 300 s: it hung)");
        assert!(!status.success(), "{stderr}");
        assert!(!stderr.contains("MPI_Abort"), "ended by an abort: {stderr}");
        let named = format!("process {} of {n} failed", n - 1);
        assert!(
            stderr.contains(&named) && stderr.contains("left the background grid"),
            "{stderr}"
        );
        let summary = read_summary(&out);
        assert_eq!(summary["status"], "failed", "{summary}");
        assert_eq!(
            summary["steps"].as_array().unwrap().len(),
            converged,
            "{summary}"
        );
        let said = summary["failure"].as_str().unwrap();
        assert!(
            said.contains(&named)
                && said.contains(&format!("load step {}", converged + 1))
                && said.contains("left the background grid"),
            "{said}"
        );
        series_is_readable(&out, converged, points);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Arc-length control over several processes, replicated (issue 14): every process holds f̂,
/// Δu and the previous increment whole and alike, so the arc's dot products and decisions are
/// the same on every process, and its second solve `K δu_f = f̂` goes through the distributed
/// solver like the first (the shares of `K` set again, the same right-hand side on every
/// process). The thick cylinder under its default arc-length control (the follower pressure
/// with its load stiffness), 4 cells, 8 steps: past the elastic limit, the peak at step 5 and
/// past it, with turn-backs refused and the arc cut at steps 7 and 8 (the serial run's cuts).
/// Over 2 and 3 processes: the same Newton iterations and cuts in every step as the serial
/// run, the load factor per step and history.csv's `inner_pressure` and `inner_displacement`
/// to 1e-8, stresses, plastic strain and positions as every comparison.
///
/// The linear solve is LU on every process (`-pc_type redundant`) with `-ksp_rtol 1e-10`: at
/// the peak `K` is nearly singular, and the solver's true-residual check (10 × the tolerance)
/// fails a GMRES+GAMG solve at 1e-12 and even an LU solve at 1e-12 (under `-n 1` too): the
/// step is cut where the serial direct solve is not (docs/distributed.md, 2026-12-07).
#[test]
fn arc_length_control_over_2_and_3_processes_equals_the_serial_run() {
    arc_controlled_cylinder_equals_the_serial_run("arc", Runs::replicated(&[2, 3]));
}

/// The arc-controlled thick cylinder of the test above with decomposed points: the arc's sums
/// over the processes' owned DOFs and the follower pressure's shared host weights and positions
/// together, past the peak and through the cut steps (the arc's decisions at a near-singular
/// tangent taken alike on every process), equal to the serial run as above.
#[test]
fn the_arc_controlled_cylinder_with_decomposed_points_equals_the_serial_run() {
    arc_controlled_cylinder_equals_the_serial_run("arc-dec-cylinder", Runs::decomposed(&[2, 3]));
}

/// The thick cylinder under its default arc-length control, 4 cells, 8 steps, run as `base`
/// says against the serial run (the two tests above).
fn arc_controlled_cylinder_equals_the_serial_run(tag: &str, base: Runs<'_>) {
    let runs = Runs {
        history: &["inner_pressure", "inner_displacement"],
        measures: &["load_factor", "cuts"],
        petsc_options: "-ksp_rtol 1e-10 -pc_type redundant -redundant_pc_type lu",
        ..base
    };
    let scene = shipped_scene("thick_cylinder.rhai");
    let set = ["cells=4", "steps=8"];
    for steps in compare_with(&scene, &set, tag, &runs) {
        // the run went past its peak: the arc's decisions past a limit load were taken alike
        let factors: Vec<f64> = (steps.iter())
            .map(|s| s["load_factor"].as_f64().unwrap())
            .collect();
        let peak = factors.iter().copied().fold(f64::MIN, f64::max);
        assert!(
            *factors.last().unwrap() < peak * (1.0 - 1e-4),
            "the run did not pass its peak: {factors:?}"
        );
        assert!(steps.iter().any(|s| s["cuts"].as_u64().unwrap() > 0));
    }
}

/// The process of rank `rank` that `mpirun` (process `launcher`) started: a descendant of it
/// whose environment says that rank (OpenMPI's `OMPI_COMM_WORLD_RANK`).
fn process_of_rank(launcher: u32, rank: usize) -> Option<u32> {
    let parent = |pid: u32| -> Option<u32> {
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
        // "pid (comm) state ppid ...": comm may hold spaces, so split after its ')'
        stat.rsplit_once(')')?
            .1
            .split_whitespace()
            .nth(1)?
            .parse()
            .ok()
    };
    let wanted = format!("OMPI_COMM_WORLD_RANK={rank}");
    std::fs::read_dir("/proc")
        .ok()?
        .flatten()
        .find_map(|entry| {
            let pid: u32 = entry.file_name().to_str()?.parse().ok()?;
            let environ = std::fs::read(format!("/proc/{pid}/environ")).ok()?;
            if !environ.split(|&b| b == 0).any(|v| v == wanted.as_bytes()) {
                return None;
            }
            let mut ancestor = parent(pid);
            while let Some(a) = ancestor.filter(|&a| a > 1) {
                if a == launcher {
                    return Some(pid);
                }
                ancestor = parent(a);
            }
            None
        })
}

/// A signal that reaches one process only (here process 1, which writes nothing of the run's
/// own) stops every process after the same load step: the stop is agreed between steps. The
/// job ends with the status "interrupted" in summary.json, without an abort, and the files of
/// the steps done read back. Before, process 1 stopped alone, process 0 went on into the next
/// step and waited there until process 1 ended the job with MPI_Abort (after 20 s).
#[test]
fn a_signal_to_one_process_stops_them_all_after_the_same_step() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("column_2d.rhai");
    let dir = temp_dir("mpi", "signal-one");
    let logs = temp_dir("mpi", "signal-one-logs");
    let args = run_arguments(&scene, &["cells=4", "steps=20000"], &dir, &[]);
    let mut job = spawn_logged(impm_command(Some(2), &args), &logs);
    let started = std::time::Instant::now();
    let limit = Duration::from_secs(120);
    // a few steps done, then SIGINT to process 1 alone
    while !dir.join("particles_0003.pvtu").exists() {
        assert!(job.try_wait().unwrap().is_none(), "the job ended early");
        assert!(started.elapsed() < limit, "no third step within {limit:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
    let process_1 = process_of_rank(job.id(), 1).expect("process 1 of the job");
    let sent = Command::new("kill")
        .args(["-INT", &process_1.to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let signalled = std::time::Instant::now();
    let status = wait_for(&mut job, limit.saturating_sub(started.elapsed()));
    let stderr = std::fs::read_to_string(logs.join("stderr.txt")).unwrap();
    let ended_in = signalled.elapsed().as_secs_f64();
    assert!(
        !status.success(),
        "an interrupted run exits non-zero: {stderr}"
    );
    assert!(!stderr.contains("MPI_Abort"), "ended by an abort: {stderr}");
    assert!(stderr.contains("interrupted after load step"), "{stderr}");
    // the abort path waits 20 s first; the agreed stop ends at the next step
    assert!(ended_in < 15.0, "ended {ended_in:.1} s after the signal");
    let summary = read_summary(&dir);
    assert_eq!(summary["status"], "interrupted", "{summary}");
    let steps = summary["steps"].as_array().unwrap().len();
    assert!((3..20000).contains(&steps), "{steps} steps");
    let last = dir.join(format!("particles_{steps:04}.pvtu"));
    assert_eq!(
        points_in_pieces(&last),
        4 * 4 * 4,
        "the last step's pieces hold every point"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&logs);
}

/// `impm study` (and every command but `impm run`) is refused under mpirun with more than one
/// process, said once (by process 0), before anything is written.
#[test]
fn a_study_under_mpirun_is_refused() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("column_1d.rhai");
    let dir = temp_dir("mpi", "study");
    let args = vec![
        "study".to_string(),
        scene.display().to_string(),
        "--sweep".into(),
        "cells=4,8".into(),
        "--out".into(),
        dir.display().to_string(),
    ];
    let output = impm_command(Some(2), &args).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert_eq!(
        stderr
            .matches("impm study under mpirun with 2 processes")
            .count(),
        1,
        "{stderr}"
    );
    assert!(stderr.contains("without mpirun"), "{stderr}");
    assert!(!dir.exists(), "nothing written");
    // with one process it is an ordinary study
    let output = impm_command(Some(1), &args).output().unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(dir.join("study.csv").is_file());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A column compressed by a grid-node `displace` on its top (2D, 2 × 8 cells, B-splines q = 2,
/// rollers, 10 % in 4 steps): its points cross the slabs. The prescribed-motion check reads
/// the points that started nearest the top nodes, which may be on another process, and the
/// top nodes may be active on another process only; the reactions are summed at each node's
/// owner. In compression the material leaves the top nodes, so the serial run warns.
const DISPLACED_COLUMN: &str = r#"
grid(#{ lower: [0.0, 0.0], upper: [1.0, 2.0], cells: [2, 8], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1000.0, nu: 0.0, density: 1.0 });
body(#{ name: "column", material: m, region: box([0.0, 0.0], [1.0, 2.0]), ppc: 2 });
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);
displace(|x| x[1] == 2.0, [1], [-0.2]);
load_steps(4);
"#;

/// Prescribed displacements with decomposed points (`-n 2`, `-n 3`) equal the serial run:
/// iterations, stresses and positions, the reactions of the `displace` and of the base in
/// every step to 1e-8 relative, and the prescribed-motion warning (the same step and node).
#[test]
fn prescribed_displacements_with_decomposed_points_equal_the_serial_run() {
    let runs = Runs {
        measures: &["displace1_reaction_y", "fix1_reaction_y"],
        history: &["displace1_reaction_y"],
        warned: &["displace1: at step"],
        ..Runs::decomposed(&[2, 3])
    };
    let name = "displaced_column.rhai";
    let runs = compare_scene_text(DISPLACED_COLUMN, name, "displaced-column-dec", &runs);
    counted_in_every_run("displaced column", &runs, "points_changing_process");
}

/// A 2D column under its weight between rollers (3 × 8 cells) with probes: `mid` at the
/// height where the points are split between two processes at `-n 2` (its 8 neighbours on both
/// sides), `upper` at a third of the height from the top, which splits them at `-n 3`, with
/// the stress and F.
const PROBED_COLUMN: &str = r#"
grid(#{ lower: [0.0, 0.0], upper: [1.5, 4.0], cells: [3, 8], basis: "bspline", order: 2 });
const soil = material(#{ name: "soil", E: 1000.0, nu: 0.3, density: 1.0 });
body(#{ name: "column", material: soil, region: box([0.0, 0.0], [1.5, 4.0]), ppc: 2 });
body_force([0.0, -100.0]);
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0 || x[0] == 1.5, [0]);
probe(#{ name: "mid", at: [0.75, 2.0] });
probe(#{ name: "upper", at: [0.6, 2.7], stress: true, F: true });
load_steps(3);
"#;

/// Probes with decomposed points (`-n 2`, `-n 3`) equal the serial run: every probe column in
/// every step of summary.json and history.csv to 1e-8 relative (the neighbours' numbers come
/// from the processes that hold them), with iterations, stresses and positions as above.
#[test]
fn probes_with_decomposed_points_equal_the_serial_run() {
    let columns = [
        "mid_displacement_y",
        "upper_displacement_y",
        "upper_stress_yy",
        "upper_stress_xx",
        "upper_stress_zz",
        "upper_F_yy",
    ];
    let runs = Runs {
        measures: &columns,
        history: &columns,
        ..Runs::decomposed(&[2, 3])
    };
    compare_scene_text(
        PROBED_COLUMN,
        "probed_column.rhai",
        "probed-column-dec",
        &runs,
    );
}

/// Material-surface conditions with decomposed points (`surface_displace`): each boundary
/// point is handled by the process holding its host (found by `PointId`), which adds its
/// terms after the assembly once over the processes; the boundary points are shared after
/// every step, so that a process a host arrives at holds its boundary point as the host's old
/// process left it, and the conditions' records (reactions, mean tractions, the material
/// check's fit over points of several processes) are the whole run's on every process. The
/// elastic strip footing (penalty, rough; `cells=4`, 2 steps) over 2 and 3 processes: the same
/// Newton iterations, stresses and positions as the serial run, the footing pressure and the
/// horizontal reaction in every step, and history.csv's `footing_pressure`, to 1e-8.
#[test]
fn the_strip_footing_with_decomposed_points_equals_the_serial_run() {
    let runs = Runs {
        measures: &[
            "footing_pressure",
            "footing_reaction_x",
            "footing_material_force_y",
        ],
        history: &["footing_pressure"],
        ..Runs::decomposed(&[2, 3])
    };
    let scene = shipped_scene("strip_footing.rhai");
    compare_with(&scene, &["cells=4", "steps=2"], "footing-dec", &runs);
}

/// As above with non-symmetric Nitsche on a plastic soil: the Tresca footing (`cells=2`,
/// 3 steps, settlement 0.03 B), which yields under the footing (the plastic strain equal to the
/// serial run's), the consistency term from the host's stress on the host's process.
#[test]
fn a_tresca_footing_by_nitsche_with_decomposed_points_equals_the_serial_run() {
    tresca_footing_with_decomposed_points("tresca-nitsche-dec", "method=nitsche");
}

/// The Tresca footing (`strip_footing.rhai`, `cells=2`, 3 steps, settlement 0.03 B) with
/// `option` over 2 and 3 processes with decomposed points against the serial run, its
/// footing pressure and reaction in every step to 1e-8 (the two tests beside it).
fn tresca_footing_with_decomposed_points(tag: &str, option: &str) {
    let runs = Runs {
        measures: &["footing_pressure", "footing_reaction_x"],
        history: &["footing_pressure"],
        ..Runs::decomposed(&[2, 3])
    };
    let scene = shipped_scene("strip_footing.rhai");
    let set = [
        "material=tresca",
        option,
        "cells=2",
        "steps=3",
        "settlement=0.03",
    ];
    compare_with(&scene, &set, tag, &runs);
}

/// Geostatic initial stresses with decomposed points (`initial_stress`): each process gives
/// the points it spawns (its slab's) their K0 stress from their own height, and the history
/// that carries it travels with a point that changes process (the material's point-state
/// part). The Tresca footing on soil with weight (`weight=true`: K0 = 0.8, γ = 5, the weight
/// held; `cells=2`, 3 steps, settlement 0.03 B) over 2 and 3 processes: the same Newton
/// iterations, stresses (the initial ones included: they are most of the stress) and plastic
/// strain as the serial run, and the footing pressure in every step, to 1e-8.
#[test]
fn a_footing_on_soil_with_initial_stresses_with_decomposed_points_equals_the_serial_run() {
    tresca_footing_with_decomposed_points("geostatic-footing-dec", "weight=true");
}

/// The K0 column of tests/geostatic.rs (von Mises, here σ_y = 300 so that it yields; K0 = 0.6,
/// γ = 20, its weight held; 21 cells of 0.5 up to 10.5) pushed down by 1.0 on its top (penalty
/// `surface_displace`) in 3 steps: points cross the slabs' boundaries and change process carrying the history that
/// holds their initial stress (`points_changing_process` more than zero over 2 and 3
/// processes). The same Newton iterations, stresses, plastic strain and positions as the
/// serial run, and the top's reaction in every step, to 1e-8.
const K0_COLUMN: &str = r#"
grid(#{ lower: [0.0, 0.0], upper: [1.0, 10.5], cells: [1, 21], basis: "bspline", order: 2 });
const soil = material(#{ name: "soil", model: "von_mises", sigma_y: 300.0, E: 1.0e4, nu: 0.3, density: 2.0 });
body(#{ name: "column", material: soil, region: box([0.0, 0.0], [1.0, 10.0]), ppc: 3, placement: "gauss" });
body_force([0.0, -10.0], #{ held: true });
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);
initial_stress(#{ K0: 0.6, unit_weight: 20.0, surface: 10.0 });
surface_displace(#{ on: [[0.0, 10.0], [1.0, 10.0]], displacement: [0.0, -1.0], name: "top" });
load_steps(3);
"#;

#[test]
fn a_pushed_k0_column_with_decomposed_points_equals_the_serial_run() {
    let runs = Runs {
        measures: &["top_reaction_y"],
        ..Runs::decomposed(&[2, 3])
    };
    let runs = compare_scene_text(K0_COLUMN, "k0_column.rhai", "k0-column-dec", &runs);
    counted_in_every_run("K0 column", &runs, "points_changing_process");
}

/// Boundary points whose hosts change process: a 2D column (slabs across its height) held on
/// its left side by a smooth support (`surface_displace` of the x component, symmetric
/// Nitsche) and pushed down on its top by a rough one (penalty), under its weight. The side's
/// hosts move down across the slabs, so at the last step's start a host arrives at another
/// process (`boundary_hosts_changing_process` more than zero over 2 and over 3 processes).
/// The same Newton iterations, stresses and positions as the serial run; the side's reaction,
/// mean displacement and material force, the top's pressure, and the base's reaction in every
/// step, to 1e-8. (With the boundary points left where their hosts' old processes had them,
/// the side's mean displacement differed by 48 % at `-n 2` and the last step failed.)
const SUPPORTED_COLUMN: &str = r#"
grid(#{ lower: [-0.5, 0.0], upper: [1.0, 4.5], cells: [3, 9], basis: "bspline", order: 2 });
const soil = material(#{ name: "column", E: 1000.0, nu: 0.2, density: 1.0 });
body(#{ name: "column", material: soil, region: box([0.0, 0.0], [1.0, 4.0]), ppc: 2 });
body_force([0.0, -25.0]);
fix(|x| x[1] == 0.0);
fix(|x| x[0] == 1.0, [0]);
surface_displace(#{ on: [[0.0, 0.0], [0.0, 4.0]], components: [0], method: "nitsche", name: "side" });
surface_displace(#{ on: [[0.0, 4.0], [1.0, 4.0]], displacement: [0.0, -0.3], name: "top" });
record(#{ name: "top_pressure", quantity: "top_traction_y", scale: -1.0 });
load_steps(3);
"#;

#[test]
fn boundary_points_whose_hosts_change_process_equal_the_serial_run() {
    let runs = Runs {
        measures: &[
            "side_reaction_x",
            "side_displacement_y",
            "side_material_force_x",
            "top_reaction_y",
            "fix1_reaction_y",
        ],
        history: &["top_pressure", "side_reaction_x"],
        ..Runs::decomposed(&[2, 3])
    };
    let runs = compare_scene_text(SUPPORTED_COLUMN, "supported_column.rhai", "side-dec", &runs);
    counted_in_every_run("supported column", &runs, "boundary_hosts_changing_process");
}

/// A boundary point whose support holds a grid node that only another process's material
/// points touch is refused at the step, naming the nodes, rather than given another answer
/// than the serial run's (serially the node is active and the point takes the basis at its
/// position; the host's process would take the host's extrapolation): a quarter ring driven
/// by a radial `surface_displace` on its bore (linear basis), whose bore's boundary points
/// and their hosts lie in different slabs over 2 processes. The job ends together, without an
/// abort, and the serial run of the same scene completes.
const DRIVEN_BORE: &str = r#"
const wall = material(#{ name: "wall", model: "von_mises", E: 500.0, nu: 0.3, sigma_y: 1.0, density: 1.0 });
grid(#{ lower: [0.0, 0.0], upper: [2.5, 2.5], cells: [10, 10], basis: "linear" });
body(#{
    name: "wall",
    material: wall,
    region: |x| {
        let r2 = x[0] * x[0] + x[1] * x[1];
        x[0] >= 0.0 && x[1] >= 0.0 && r2 >= 1.0 && r2 <= 4.0
    },
    ppc: 4,
});
fix(|x| x[0] == 0.0, [0]);
fix(|x| x[1] == 0.0, [1]);
surface_displace(#{ on: arc(#{ centre: [0.0, 0.0], radius: 1.0, from: 0.0, to: 90.0 }), radial: 0.02, name: "bore" });
load_steps(2);
"#;

#[test]
fn a_boundary_point_reaching_another_process_s_nodes_is_refused_at_the_step() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let (scene_dir, scene) = scene_file("bore-scene", "driven_bore.rhai", DRIVEN_BORE);
    let serial_dir = temp_dir("mpi", "bore-serial");
    serial_reference(&scene, &[], &serial_dir, &[]);
    let dir = temp_dir("mpi", "bore-decomposed");
    let stderr = refused(2, &scene, &[], &dir, &["--decompose"]);
    assert!(
        stderr.contains(
            "load step 1: the support of a surface condition's boundary point holds grid nodes"
        ) && stderr.contains("that only another process's material points touch"),
        "{stderr}"
    );
    for dir in [scene_dir, serial_dir, dir] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// The stiff ring (`common::stiff_ring`; docs/distributed.md, "A stiff, non-symmetric ring"),
/// its step cuts set by `cuts`. Over 3 processes PETSc's default (GMRES + GAMG) does not
/// converge; the backend falls back to GMRES + ASM with LU on each process's block, every
/// process alike, and says so once.
fn stiff_ring_scene() -> String {
    common::stiff_ring("let cuts = 8;\nsolver(#{ max_step_cuts: cuts });")
}

/// The stiff ring over 3 processes with PETSc's default equals the serial run (Newton per
/// step, stresses, plastic strain, positions, the bore pressure in every step, to 1e-8) and
/// says the fallback once; with the method chosen (`-pc_type gamg`) the run fails with PETSc's
/// reason, as before.
#[test]
fn the_stiff_ring_falls_back_from_petscs_default_over_3_processes_and_equals_the_serial_run() {
    let runs = Runs {
        measures: &["bore_pressure"],
        said: &["PETSc's default method failed"],
        ..Runs::replicated(&[3])
    };
    let text = stiff_ring_scene();
    compare_scene_text(&text, "stiff_ring.rhai", "stiff-ring", &runs);
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let (scene_dir, scene) = scene_file("stiff-ring-chosen", "stiff_ring.rhai", &text);
    let dir = temp_dir("mpi", "stiff-ring-chosen-3");
    let extra = ["--petsc-options", "-pc_type gamg -ksp_max_it 1000"];
    let output = run(Some(3), &scene, &["cuts=0"], &dir, &extra);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(
        stderr.contains("DIVERGED") && stderr.contains("gmres+gamg"),
        "{stderr}"
    );
    assert!(!stderr.contains("MPI_Abort"), "{stderr}");
    let summary = read_summary(&dir);
    assert_eq!(summary["status"], "failed");
    let warnings = summary["warnings"].as_array().unwrap();
    assert!(
        !warnings
            .iter()
            .any(|w| w.as_str().unwrap().contains("fallback")),
        "{warnings:?}"
    );
    for dir in [scene_dir, dir] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Arc-length control with decomposed points (`--decompose`): f̂ is the processes' sum at the
/// shared nodes (as `f_ext`), the arc's dot products and norms count each DOF on its node's
/// owner and are summed over the processes, Δu_{n−1} is kept whole on every process (the
/// next step's owners are not this one's), so every process takes the arc's decisions alike
/// (`stages::arc_length`, "With decomposed points"). Two scenes over 2 and 3 processes
/// against the serial run: the footing of `footing_pressure_arc.rhai` (tractions, F-bar,
/// von Mises, a probe; 2 cells across the footing, 12 steps, past first yield to λ = 5.75;
/// history.csv's settlement and pressure), and a confined von Mises column pressed by a
/// traction with its weight held (`held: true`: the loads' second evaluation at λ = 0 summed
/// too, the first step's rebalancing), whose points change process as it is compressed. The
/// same Newton iterations per step (no step is cut, serially or here), the load factor (and
/// the column's `initial_imbalance`) per step to 1e-8, stresses, plastic strain and positions
/// as every comparison.
#[test]
fn arc_length_control_with_decomposed_points_equals_the_serial_run() {
    let runs = Runs {
        history: &["settlement", "footing_pressure"],
        // (no initial_imbalance at step 1: λ_0 f̂ = 0)
        measures: &["load_factor"],
        ..Runs::decomposed(&[2, 3])
    };
    let scene = shipped_scene("footing_pressure_arc.rhai");
    let runs_of = compare_with(&scene, &["cells=2", "steps=12"], "arc-dec", &runs);
    for steps in &runs_of {
        assert!(steps.iter().all(|s| s["cuts"].as_u64() == Some(0)));
        let last = steps.last().unwrap()["load_factor"].as_f64().unwrap();
        assert!(
            last > 5.0,
            "the footing did not load past first yield: {last}"
        );
    }
    let (dir, column) = scene_file("arc-dec-column", "column.rhai", ARC_COLUMN);
    let runs = Runs {
        measures: &["load_factor", "initial_imbalance"],
        ..Runs::decomposed(&[2, 3])
    };
    let runs_of = compare_with(&column, &[], "arc-dec-column", &runs);
    for (moved, steps) in summed_over_steps(&runs_of, "points_changing_process")
        .iter()
        .zip(&runs_of)
    {
        assert!(*moved > 0.0, "no point changed process");
        // the first step balanced the held weight at λ = 0 before its arc
        assert!(steps[0]["rebalance_iterations"].as_f64().unwrap() > 0.0);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A confined von Mises column (2 × 9 cells: the slabs cut along its height) pressed by a
/// traction on its top under arc-length control, its weight held: yields in the first step,
/// and its points cross cell faces, and so slab boundaries, as it shortens (λ 0.52 to 8.76).
const ARC_COLUMN: &str = "
const soil = material(#{ name: \"soil\", model: \"von_mises\", E: 1.0e3, nu: 0.3, s_u: 5.0, density: 1.0 });
grid(#{ lower: [0.0, 0.0], upper: [1.0, 4.5], cells: [2, 9], basis: \"linear\" });
body(#{ name: \"column\", material: soil, region: box([0.0, 0.0], [1.0, 4.0]), ppc: 2 });
fix(|x| x[1] == 0.0);
fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);
traction(#{ on: [[0.0, 4.0], [1.0, 4.0]], traction: [0.0, -100.0], per_cell: 2 });
body_force([0.0, -20.0], #{ held: true });
solver(#{ control: \"arc_length\", target_iterations: 5 });
load_factors(6, |k| k * 0.5);
";

/// The follower pressure with decomposed points (issue 14): every process holds every
/// pressure point, the process holding a point's host finds its host weights and its position
/// at each iterate and shares them, process 0 adds the pressure's force before `f_ext` is
/// summed and its load stiffness (it numbers every node of the parts), and every process
/// follows the force at the iterate at its own nodes. The thick cylinder under pressure
/// control (4 cells, 6 steps to p = 0.6 σ_y, past the elastic limit: the wall yields): the same
/// Newton iterations, stresses, plastic strain and positions as the serial run, history.csv's
/// `inner_pressure` and `inner_displacement`, the reactions on the symmetry axes in every step
/// and the last pressure file's load points and forces, to 1e-8.
#[test]
fn the_follower_pressure_with_decomposed_points_equals_the_serial_run() {
    let runs = Runs {
        history: &["inner_pressure", "inner_displacement"],
        measures: &["fix1_reaction_x", "fix2_reaction_y"],
        pressure: true,
        ..Runs::decomposed(&[2, 3])
    };
    let scene = shipped_scene("thick_cylinder.rhai");
    let set = ["control=load", "cells=4", "steps=6", "last=0.6"];
    compare_with(&scene, &set, "pressure-dec", &runs);
}

/// The ghost penalty with decomposed points (`effects::ghost_penalty`, "Which process adds a
/// face"): the cells' fill fractions summed over the processes, each face added by the process
/// holding its lower cell. The sliver column (the face below the sliver cell, inside the top
/// slab) and the heavy column with the penalty (`ghost_penalty=0.01`, 8 cells, 4 steps: the
/// column shortens by half, its top cells empty out and points cross the slabs, so they change
/// process) over 2 and 3 processes: Newton iterations per step, the eq. 15 error, stresses and
/// positions as the serial run, to 1e-8.
#[test]
fn the_ghost_penalty_with_decomposed_points_equals_the_serial_run() {
    let runs = Runs::decomposed(&[2, 3]);
    let sliver = shipped_scene("sliver_column.rhai");
    compare_with(&sliver, &["steps=2"], "sliver-dec", &runs);
    let heavy = shipped_scene("heavy_column.rhai");
    let set = ["cells=8", "steps=4", "ghost_penalty=0.01"];
    let measured = compare_with(&heavy, &set, "heavy-ghost-dec", &runs);
    counted_in_every_run(
        "heavy column, ghost penalty",
        &measured,
        "points_changing_process",
    );
}

/// A block (8 × 4.2 cells of 0.5, q = 2, 2 × 2 points per cell) on a grid 10 × 5 cells, fixed
/// at its base and sheared by a sideways body force: its top row of cells is a sliver (a fifth
/// full), so every face between two of its cells is penalised, and as the slabs cut along x
/// (the axis with the most cells) some of those faces lie on a slab boundary, normal to the
/// slab axis: their stencils (3 + 1 node columns) reach one node column past the points of
/// the process holding their lower cell (`effects::distributed::grid`, `local_nodes`). The top
/// moves by about 0.3 (0.6 of a cell) in 3 steps, so points change process.
const SHEARED_BLOCK: &str = "
let ghost_penalty = 0.01;
grid(#{ lower: [0.0, 0.0], upper: [5.0, 2.5], cells: [10, 5], basis: \"bspline\", order: 2 });
const soil = material(#{ name: \"block\", E: 1000.0, nu: 0.3, density: 1.0 });
body(#{ name: \"block\", material: soil, region: box([0.0, 0.0], [4.0, 2.1]), ppc: 2 });
body_force([50.0, -10.0]);
fix(|x| x[1] == 0.0);
load_steps(3);
solver(#{ ghost_penalty: ghost_penalty });
";

/// [`SHEARED_BLOCK`] over 2 and 3 processes with decomposed points equals its serial run
/// (Newton iterations per step, stresses and positions to 1e-8), points change process, and
/// the penalty matters: the serial run without it (`ghost_penalty=0`) differs by more than
/// 1e-6 in stress or positions (so a face left out could not pass unseen).
#[test]
fn ghost_faces_on_slab_boundaries_with_decomposed_points_equal_the_serial_run() {
    let (dir, scene) = scene_file("ghost-slab-scene", "sheared_block.rhai", SHEARED_BLOCK);
    let measured = compare_with(&scene, &[], "ghost-slab-dec", &Runs::decomposed(&[2, 3]));
    if !measured.is_empty() {
        counted_in_every_run("sheared block", &measured, "points_changing_process");
        let with = temp_dir("mpi", "ghost-slab-with");
        let without = temp_dir("mpi", "ghost-slab-without");
        let penalised = serial_reference(&scene, &[], &with, &[]);
        let plain = serial_reference(&scene, &["ghost_penalty=0"], &without, &[]);
        let stress = relative_difference(&plain.stress, &penalised.stress);
        let positions = relative_difference(&plain.positions, &penalised.positions);
        eprintln!(
            "sheared block: without the ghost penalty, stress differs by {stress:.1e}, \
             positions by {positions:.1e}"
        );
        assert!(stress.max(positions) > 1e-6, "{stress:e} {positions:e}");
        for dir in [with, without] {
            let _ = std::fs::remove_dir_all(&dir);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Node storage sized by the process's nodes (`node_storage`, docs/distributed.md "Node
/// storage sized by the process's nodes"): the 2D block on a 64 × 64-cell grid (slabs along
/// y, the grid's slowest axis) under `--decompose` over 1 and 2 processes equals its serial
/// run, and in every step the largest process's grid fields over 2 processes
/// (`node_storage_bytes`: written pages and page tables) are at most 56 % of the one process's
/// (a process holds its 32 cell rows' 34 node rows of 66, plus the pages they end in: 53.0 %;
/// with every node's DOF numbers written on every process, as before, 59.4 %: seen to fail).
#[test]
fn decomposed_processes_hold_the_node_storage_of_their_own_nodes() {
    let scene = shipped_scene("block_2d_self_weight.rhai");
    let set = ["cells=64", "linear=direct"];
    let runs = compare_with(&scene, &set, "node-storage", &Runs::decomposed(&[1, 2]));
    if runs.is_empty() {
        return;
    }
    let bytes = |run: &[serde_json::Value]| -> Vec<f64> {
        (run.iter())
            .map(|step| {
                step["node_storage_bytes"]
                    .as_f64()
                    .expect("node_storage_bytes")
            })
            .collect()
    };
    let (one, two) = (bytes(&runs[0]), bytes(&runs[1]));
    assert_eq!(one.len(), two.len());
    // the whole grid's fields, dense: 66² nodes of 1 + 2 + 8 + 3 × 16 bytes
    let dense = (66.0 * 66.0) * (1.0 + 2.0 + 8.0 + 3.0 * 16.0);
    for (k, (&one, &two)) in one.iter().zip(&two).enumerate() {
        eprintln!(
            "block 64 × 64, step {}: node storage -n 1 {one} B, -n 2 largest process {two} B \
             ({:.1} %; dense fields {dense} B)",
            k + 1,
            100.0 * two / one
        );
        assert!(
            one > 0.9 * dense && one < 1.1 * dense,
            "{one} B against {dense}"
        );
        assert!(two <= 0.56 * one, "step {}: {two} B of {one}", k + 1);
    }
}

/// The values of `file` (a `.vtu` of the serial run, `stem` its series) against `merged` (the
/// same step's file `impm merge` wrote from a decomposed run's pieces): the same points (to
/// 1e-12 of the grid's extent), the same cells (kinds and corners, exactly), and every array
/// of the serial file to 1e-8 of its largest value (exactly where that is zero). Returns the
/// largest difference.
fn same_grid_file(label: &str, merged: &Path, file: &Path) -> f64 {
    let read = |path: &Path| read_vtu(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let (got, serial) = (read(merged), read(file));
    let flat = |v: &impm::output::VtuContents| -> Vec<f64> {
        v.points.iter().flatten().copied().collect()
    };
    assert_eq!(got.points.len(), serial.points.len(), "{label}: points");
    let positions = relative_difference(&flat(&got), &flat(&serial));
    assert!(positions <= 1e-12, "{label}: positions {positions:e}");
    assert_eq!(got.cell_types, serial.cell_types, "{label}: cell kinds");
    assert_eq!(
        got.connectivity, serial.connectivity,
        "{label}: cells' corners"
    );
    assert_eq!(got.offsets, serial.offsets, "{label}: cells");
    let mut largest_difference = 0.0f64;
    for (kind, arrays, got_arrays) in [
        ("point", &serial.point_data, &got.point_data),
        ("cell", &serial.cell_data, &got.cell_data),
    ] {
        assert!(
            !arrays.is_empty() || kind == "cell",
            "{label}: no point arrays"
        );
        for (name, components, values) in arrays {
            let (_, got_components, got_values) = got_arrays
                .iter()
                .find(|(n, _, _)| n == name)
                .unwrap_or_else(|| panic!("{label}: no {kind} array {name} in the merged file"));
            assert_eq!(got_components, components, "{label}: {name}");
            assert_eq!(got_values.len(), values.len(), "{label}: {name}");
            let scale = values.iter().map(|v| v.abs()).fold(0.0, f64::max);
            let difference = (got_values.iter().zip(values))
                .map(|(a, b)| (a - b).abs() / scale.max(f64::MIN_POSITIVE))
                .fold(0.0, f64::max);
            assert!(
                difference <= 1e-8,
                "{label}: {kind} array {name} differs by {difference:e} of {scale:e}"
            );
            largest_difference = largest_difference.max(difference);
        }
    }
    largest_difference
}

/// Issue 14, the grid and node files of a decomposed run over each of `counts` processes
/// (`--decompose`; one process writes the serial files, compared as below): over several, every output step's `grid_NNNN.pvtu` and `nodes_NNNN.pvtu` list one piece
/// per process and `grid.pvd` and `nodes.pvd` list them; the node pieces hold every node of
/// the serial file once; `impm merge` turns them into files equal to the serial run's (every
/// point, cell and array, every step: [`same_grid_file`]); the run no longer says they are
/// not written; with `paraview`, ParaView reads the series (`scripts/check_output.py`) with
/// every array and the serial file's nodes and cells (the grid's points: its pieces' vertices,
/// a vertex on a slab boundary in both).
fn grid_pieces_equal_the_serial_files(
    script: &str,
    set: &[&str],
    tag: &str,
    counts: &[usize],
    paraview: bool,
) {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene(script);
    let serial_dir = temp_dir("mpi", &format!("{tag}-serial"));
    let reference = serial_reference(&scene, set, &serial_dir, &[]);
    let steps = reference.steps.len();
    let serial_file =
        |stem: &str, step: usize| serial_dir.join(impm::output::step_file_name(stem, step));
    let serial_nodes = read_vtu(&serial_file("nodes", 0)).unwrap().points.len();
    let serial_cells = read_vtu(&serial_file("grid", 0)).unwrap().cell_count;
    for &n in counts {
        let label = format!("{script} -n {n} --decompose");
        let dir = temp_dir("mpi", &format!("{tag}-{n}"));
        let extra = ["--petsc-options", "-ksp_rtol 1e-12", "--decompose"];
        let output = run(Some(n), &scene, set, &dir, &extra);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{label}: {stderr}");
        assert!(!stderr.contains("not written"), "{label}: {stderr}");
        // the pieces: one per process, every node once (one process writes the serial files)
        let mut grid_points = Vec::new();
        for stem in ["grid", "nodes"].into_iter().filter(|_| n > 1) {
            let pvd = std::fs::read_to_string(dir.join(format!("{stem}.pvd"))).unwrap();
            assert_eq!(pvd.matches(".pvtu\"").count(), steps + 1, "{label}: {pvd}");
            assert!(!pvd.contains(".vtu\""), "{label}: {pvd}");
            for step in 0..=steps {
                let pvtu =
                    dir.join(impm::output::step_file_name(stem, step).replace(".vtu", ".pvtu"));
                assert_eq!(
                    impm::output::pvtu_pieces(&pvtu).unwrap().len(),
                    n,
                    "{label}"
                );
                let points = points_in_pieces(&pvtu);
                if stem == "nodes" {
                    assert_eq!(
                        points, serial_nodes,
                        "{label}: step {step}'s nodes in pieces"
                    );
                } else {
                    grid_points.push(points);
                }
            }
        }
        if paraview && n > 1 {
            grid_series_read_by_paraview(&label, &dir, serial_nodes, serial_cells, &grid_points);
        }
        let got = outcome(&dir); // merges the pieces
        same_results(&label, &got, &reference, 0.0);
        let mut largest = 0.0f64;
        for step in 0..=steps {
            for stem in ["grid", "nodes"] {
                let name = impm::output::step_file_name(stem, step);
                let difference = same_grid_file(
                    &format!("{label}: {name}"),
                    &dir.join(&name),
                    &serial_file(stem, step),
                );
                largest = largest.max(difference);
            }
        }
        eprintln!(
            "{label}: grid and node files of {} steps merged from the pieces, {serial_nodes} \
             nodes and {serial_cells} cells as the serial run's; grid's points in pieces \
             {grid_points:?}; largest difference {largest:.1e}",
            steps + 1
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
    let _ = std::fs::remove_dir_all(&serial_dir);
}

/// ParaView (`scripts/check_output.py` under `pvpython`, where installed) reads the run in
/// `dir`: the node series with its arrays and `nodes` points in every step, the grid series
/// with its arrays, `cells` cells in every step and its pieces' points (`grid_points`, by
/// step).
fn grid_series_read_by_paraview(
    label: &str,
    dir: &Path,
    nodes: usize,
    cells: usize,
    grid_points: &[usize],
) {
    let nodes_arrays = [
        "--nodes",
        "active:1",
        "fixed:3",
        "displacement_increment:3",
        "external_force:3",
        "internal_force:3",
        "node_id:1",
    ];
    let Some(report) = read_by_paraview(dir, &nodes_arrays) else {
        return;
    };
    let section = |name: &str| -> String {
        let start = report
            .find(&format!("\n{name}: "))
            .unwrap_or_else(|| panic!("{label}: no {name} series in {report}"));
        let rest = &report[start + 1..];
        let end = rest[1..].find("\n  required").map_or(rest.len(), |e| e + 1);
        let end = ["\ngrid: ", "\nnodes: ", "\ntractions: ", "\npressure: "]
            .iter()
            .filter_map(|next| rest[1..].find(next).map(|e| e + 1))
            .fold(end, usize::min);
        rest[..end].to_string()
    };
    let span = |values: &[usize]| {
        let (low, high) = (values.iter().min().unwrap(), values.iter().max().unwrap());
        if low == high {
            format!("{low}")
        } else {
            format!("{low}..{high}")
        }
    };
    let grid = section("grid");
    eprintln!("{label}: ParaView's grid series:\n{grid}");
    assert!(
        grid.contains(&format!("points: {}, cells: {cells}\n", span(grid_points))),
        "{label}: {grid}"
    );
    for array in [
        "point array displacement_increment: 3 components",
        "point array vertex_id: 1 component",
        "cell array material_points: 1 component",
        "cell array cell_id: 1 component",
    ] {
        assert!(grid.contains(array), "{label}: {array} in {grid}");
    }
    let node_series = section("nodes");
    eprintln!("{label}: ParaView's node series:\n{node_series}");
    assert!(
        node_series.contains(&format!("points: {nodes}, cells: {nodes}\n")),
        "{label}: {node_series}"
    );
}

#[test]
fn the_2d_column_s_grid_and_node_files_in_pieces_equal_the_serial_run_s() {
    grid_pieces_equal_the_serial_files(
        "column_2d.rhai",
        &["cells=16", "steps=3"],
        "grid-pieces-2d",
        &[1, 2, 3],
        true,
    );
}

#[test]
fn the_3d_column_s_grid_and_node_files_in_pieces_equal_the_serial_run_s() {
    grid_pieces_equal_the_serial_files(
        "column_3d.rhai",
        &["cells=4", "steps=2"],
        "grid-pieces-3d",
        &[2, 3],
        true,
    );
}

/// A decomposed run with the follower pressure (the thick cylinder of
/// [`the_follower_pressure_with_decomposed_points_equals_the_serial_run`], past the elastic
/// limit) stopped after step 3 under `mpirun -n 2 --decompose` with a checkpoint every 2 steps
/// and resumed by `-n 2` from step 2 gives the uninterrupted serial run's results: Newton
/// iterations per step, stresses, plastic strain, positions, the history's `inner_pressure`
/// and `inner_displacement` (every row), the last pressure file's load points and forces, to
/// 1e-8, and the last checkpoint's parts to 1e-12.
#[test]
fn a_decomposed_run_with_a_pressure_resumes_from_its_checkpoint() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("thick_cylinder.rhai");
    let set = ["control=load", "cells=4", "steps=6", "last=0.6"];
    let decomposed = ["--petsc-options", "-ksp_rtol 1e-12", "--decompose"];
    let serial_dir = temp_dir("mpi", "pressure-resume-serial");
    let reference = serial_reference(&scene, &set, &serial_dir, &["--checkpoint-every", "2"]);
    let dir = temp_dir("mpi", "pressure-resume");
    let done = stopped_after(Some(2), &scene, &set, &dir, &decomposed, 3);
    let (got, seconds) = resume(Some(2), &scene, &set, &dir, &decomposed);
    let label = format!("thick cylinder, -n 2 stopped after step 3, resumed from step {done}");
    same_results(&label, &got, &reference, seconds);
    for name in ["inner_pressure", "inner_displacement"] {
        let (serial, resumed) = (
            history_column(&serial_dir, name),
            history_column(&dir, name),
        );
        let difference = relative_difference(&resumed, &serial);
        eprintln!("{label}: history.csv {name}: difference {difference:.1e}");
        assert!(difference <= 1e-8, "{label}: {name} {difference:e}");
    }
    same_load_points(&label, "pressure", &dir, &serial_dir, got.iterations.len());
    same_checkpoint(&label, &dir, &serial_dir);
    // the grid and node series in pieces list every step once after the resume too
    for stem in ["grid", "nodes"] {
        let pvd = std::fs::read_to_string(dir.join(format!("{stem}.pvd"))).unwrap();
        for step in 0..=got.iterations.len() {
            let name = format!("{stem}_{step:04}.pvtu");
            assert_eq!(pvd.matches(&name).count(), 1, "{label}: {name} in {pvd}");
        }
    }
    for dir in [dir, serial_dir] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Checkpoints in pieces (2026-12-08): the 2D column (16 cells, 6 steps) decomposed over 3
/// processes and stopped after step 3 (`--stop-after`) leaves the checkpoint of step 2 in
/// pieces: the header names one piece per process (`checkpoint_0002_pK.bin`), which hold every
/// point once, and the folder holds no earlier checkpoint's files. A serial `--resume` and a
/// replicated `mpirun -n 2` one (no `--decompose`) are refused, saying how to resume it; a
/// deleted piece, a truncated one and a damaged one are refused by `mpirun -n 2 --decompose
/// --resume`, non-zero, without a panic or an abort, naming the file. Resumed over 2
/// processes, the run gives the uninterrupted serial run's results (Newton iterations, eq. 15
/// error, stresses and positions to 1e-8: `same_results`), the serial run's history.csv in
/// every column it has (to 1e-8 of the column's largest value) and a last checkpoint (in 2
/// pieces) holding the serial one's numbers (`same_checkpoint`).
#[test]
fn a_checkpoint_in_pieces_over_3_processes_resumes_over_2_and_names_a_missing_piece() {
    let Some(_one) = mpi_job_slot() else {
        return;
    };
    let scene = shipped_scene("column_2d.rhai");
    let set = ["cells=16", "steps=6"];
    let decomposed = ["--petsc-options", "-ksp_rtol 1e-12", "--decompose"];
    let serial_dir = temp_dir("mpi", "pieces-serial");
    let reference = serial_reference(&scene, &set, &serial_dir, &["--checkpoint-every", "2"]);
    let dir = temp_dir("mpi", "pieces");
    let done = stopped_after(Some(3), &scene, &set, &dir, &decomposed, 3);
    assert_eq!(done, 2);
    let header: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("checkpoint.json")).unwrap())
            .unwrap();
    let pieces: Vec<String> = header["pieces"]["files"]
        .as_array()
        .unwrap_or_else(|| panic!("no pieces: {header}"))
        .iter()
        .map(|piece| piece["file"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(
        pieces,
        [
            "checkpoint_0002_p0.bin",
            "checkpoint_0002_p1.bin",
            "checkpoint_0002_p2.bin"
        ]
    );
    let mut left: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|entry| entry.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with("checkpoint_"))
        .collect();
    left.sort();
    let mut expected = pieces.clone();
    expected.insert(0, "checkpoint_0002.bin".to_string());
    assert_eq!(left, expected, "only the last checkpoint's files are kept");
    let record = 2 * 2 + 2 * 2 + 1; // x, u, F, V in 2D
    let points = points_of_pieces(&dir).len() / record;
    assert_eq!(points, reference.points.points.len());
    eprintln!("pieces of step 2: {pieces:?}, {points} points in all");

    // refused without decomposed points, and with a piece missing, truncated or damaged
    let broken = temp_dir("mpi", "pieces-broken");
    let copy = |from: &Path, to: &Path| {
        let _ = std::fs::remove_dir_all(to);
        let status = Command::new("cp")
            .arg("-r")
            .arg(from)
            .arg(to)
            .status()
            .unwrap();
        assert!(status.success());
    };
    copy(&dir, &broken);
    let folder = broken.display().to_string();
    refused_serially(&scene, &set, &broken);
    let replicated = ["--petsc-options", "-ksp_rtol 1e-12", "--resume", &folder];
    let said = refused(2, &scene, &set, &broken, &replicated);
    assert!(said.contains("--decompose --resume"), "{said}");
    let resume_broken = [&decomposed[..], &["--resume", &folder]].concat();
    let refused_naming = |what: &str, file: &str| {
        let said = refused(2, &scene, &set, &broken, &resume_broken);
        eprintln!("a {what} piece: {said}");
        assert!(!said.contains("panicked"), "{said}");
        assert!(said.contains(file), "{what}: {said}");
        said
    };
    std::fs::remove_file(broken.join(&pieces[1])).unwrap();
    let said = refused_naming("deleted", &pieces[1]);
    assert!(said.contains("cannot read"), "{said}");
    copy(&dir, &broken);
    let bytes = std::fs::read(dir.join(&pieces[2])).unwrap();
    std::fs::write(broken.join(&pieces[2]), &bytes[..bytes.len() / 2]).unwrap();
    let said = refused_naming("truncated", &pieces[2]);
    assert!(said.contains("truncated"), "{said}");
    copy(&dir, &broken);
    let mut damaged = std::fs::read(dir.join(&pieces[0])).unwrap();
    damaged[100] ^= 1;
    std::fs::write(broken.join(&pieces[0]), &damaged).unwrap();
    let said = refused_naming("damaged", &pieces[0]);
    assert!(said.contains("does not have the hash"), "{said}");
    let _ = std::fs::remove_dir_all(&broken);

    let (got, seconds) = resume(Some(2), &scene, &set, &dir, &decomposed);
    let label = "2D column, -n 3 in pieces then -n 2";
    same_results(label, &got, &reference, seconds);
    same_history(label, &dir, &serial_dir);
    same_checkpoint(label, &dir, &serial_dir);
    for dir in [dir, serial_dir] {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Every column of the serial run's history.csv (in `serial_dir`) in the one of `dir`, with
/// the same rows: each value to 1e-8 of the column's largest, a force's (a reaction or an
/// external force) to 1e-8 of the largest force of the run (a component zero up to roundoff,
/// such as the 2D column's side reaction `fix2_reaction_x`, 2.4e-10 against 4e4, has no scale
/// of its own); empty where the serial one is.
fn same_history(label: &str, dir: &Path, serial_dir: &Path) {
    let table = |dir: &Path| {
        let text = std::fs::read_to_string(dir.join("history.csv")).expect("history.csv");
        let mut lines = text.lines();
        let names: Vec<String> = lines
            .next()
            .unwrap()
            .split(',')
            .map(|name| name.trim().to_string())
            .collect();
        let rows: Vec<Vec<Option<f64>>> = lines
            .map(|line| {
                line.split(',')
                    .map(|value| value.trim().parse::<f64>().ok())
                    .collect()
            })
            .collect();
        (names, rows)
    };
    let (serial_names, serial_rows) = table(serial_dir);
    let (names, rows) = table(dir);
    assert_eq!(rows.len(), serial_rows.len(), "{label}: history.csv rows");
    let is_force = |name: &str| name.contains("reaction") || name.contains("force");
    let largest_force = serial_names
        .iter()
        .enumerate()
        .filter(|(_, name)| is_force(name))
        .flat_map(|(k, _)| serial_rows.iter().filter_map(move |row| row[k]))
        .fold(0.0f64, |m, v| m.max(v.abs()));
    for (k, name) in serial_names.iter().enumerate() {
        let j = names
            .iter()
            .position(|other| other == name)
            .unwrap_or_else(|| panic!("{label}: no column {name} in history.csv"));
        let serial: Vec<Option<f64>> = serial_rows.iter().map(|row| row[k]).collect();
        let got: Vec<Option<f64>> = rows
            .iter()
            .map(|row| row.get(j).copied().flatten())
            .collect();
        let mut scale = serial.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        if is_force(name) {
            scale = scale.max(largest_force);
        }
        for (step, (a, b)) in got.iter().zip(&serial).enumerate() {
            match (a, b) {
                (Some(a), Some(b)) => assert!(
                    (a - b).abs() <= 1e-8 * scale,
                    "{label}: history.csv {name}, row {step}: {a} against {b}"
                ),
                _ => assert_eq!(a.is_some(), b.is_some(), "{label}: {name}, row {step}"),
            }
        }
    }
    eprintln!(
        "{label}: history.csv: the serial run's {} columns, {} rows, equal",
        serial_names.len(),
        serial_rows.len()
    );
}
