//! The PETSc backend (`solver(#{ linear: "petsc" })`, cargo feature `petsc`).
//!
//! With the feature: PETSc's CG with GAMG (the rigid-body modes as its near-null space) and
//! with hypre's BoomerAMG reproduces the direct solve's runs of the 2D and 3D columns and a 3D
//! block — the same eq. 15 error, every point's stress to 1e-8 of the largest, the same Newton
//! iterations — with a tight linear tolerance (`-ksp_rtol 1e-12`); a non-symmetric tangent
//! (Nitsche) goes to GMRES and gives the LU run; a KSP that stops short (`-ksp_max_it 1`, from
//! the scene or from `--petsc-options`, with the method chosen) is a failed solve with PETSc's
//! reason, never an answer; a default that fails (GMRES + GAMG on a stiff, non-symmetric ring)
//! falls back to GMRES + ASM with LU, says so once and gives the direct run, while a chosen
//! method that fails stays a failure;
//! a PETSc error (an unknown KSP type) names the PETSc function and PETSc's message; an option
//! PETSc did not use (misspelled) is refused by name.
//!
//! Without the feature: a scene asking for PETSc and `--petsc-options` are refused, saying how
//! to rebuild, with the scene's file and line.

mod common;

use std::path::PathBuf;

use common::{impm, shipped_scene, temp_dir};

/// A shipped scene with `solver_call` appended, written to a fresh folder; its path and the
/// number of its lines (the line of the call).
fn scene_with(script: &str, solver_call: &str, tag: &str) -> (PathBuf, usize) {
    let base = std::fs::read_to_string(shipped_scene(script)).unwrap();
    let text = format!("{base}\n{solver_call}\n");
    let dir = temp_dir("petsc", tag);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(script);
    std::fs::write(&path, &text).unwrap();
    (path, text.lines().count())
}

#[cfg(not(feature = "petsc"))]
#[test]
fn a_build_without_petsc_refuses_it_and_says_how_to_rebuild() {
    let (path, line) = scene_with(
        "column_1d.rhai",
        "solver(#{ linear: \"petsc\" });",
        "without",
    );
    let message = impm::run::load_scene(&path, &[]).unwrap_err().to_string();
    assert!(message.contains(&format!(":{line}:")), "{message}");
    assert!(message.contains("--features petsc"), "{message}");
    let column = shipped_scene("column_1d.rhai").display().to_string();
    let out = temp_dir("petsc", "without-cli");
    let run = impm(&[
        "run",
        &column,
        "--out",
        &out.display().to_string(),
        "--petsc-options",
        "-ksp_monitor",
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(
        stderr.contains("--petsc-options") && stderr.contains("--features petsc"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
    let _ = std::fs::remove_dir_all(&out);
}

#[cfg(feature = "petsc")]
mod with_petsc {
    use super::*;
    use common::{overrides, stress_difference};
    use impm::resources::Newton;
    use impm::run::{Simulation, load_scene};
    use impm::scene::LinearBackend;
    use impm::solver::{DirectSolver, LinearSolver, SolverKind};

    /// A run's per-step Newton iterations, its per-step Krylov iterations, its final eq. 15
    /// error (if any), the points' stress profile along the last axis and how the last system
    /// was solved.
    struct Outcome {
        newton: Vec<usize>,
        krylov: Vec<Vec<usize>>,
        error: Option<f64>,
        stress: Vec<(f64, f64)>,
        kind: SolverKind,
        warnings: Vec<String>,
    }

    /// Runs the scene at `path`, with its own solver or with `solver`.
    fn run<const D: usize>(
        path: &std::path::Path,
        set: &[(&str, &str)],
        tag: &str,
        solver: Option<Box<dyn LinearSolver>>,
    ) -> Result<Outcome, String> {
        let spec = load_scene(path, &overrides(set)).map_err(|e| e.to_string())?;
        let dir = temp_dir("petsc-run", tag);
        let mut sim = Simulation::<D>::new(&spec, &dir).map_err(|e| e.to_string())?;
        if let Some(solver) = solver {
            sim.world.resource_mut::<Newton>().solver = solver;
        }
        let result = sim.run(|_| {});
        let _ = std::fs::remove_dir_all(&dir);
        result.map_err(|e| e.to_string())?;
        let steps = &sim.summary.steps;
        Ok(Outcome {
            newton: steps.iter().map(|s| s.iterations).collect(),
            krylov: steps.iter().map(|s| s.linear_iterations.clone()).collect(),
            error: sim.summary.final_error(),
            stress: sim.stress_profile(D - 1),
            kind: sim.world.resource::<Newton>().last_solver,
            warnings: sim.summary.warnings.clone(),
        })
    }

    /// The scene's PETSc runs against its direct run.
    fn compare<const D: usize>(script: &str, set: &[(&str, &str)], options: &[&str]) {
        let direct = Box::new(DirectSolver::default()) as Box<dyn LinearSolver>;
        let reference = run::<D>(
            &shipped_scene(script),
            set,
            &format!("{script}-direct"),
            Some(direct),
        )
        .unwrap();
        for (k, options) in options.iter().enumerate() {
            let call = format!("solver(#{{ linear: \"petsc\", petsc_options: \"{options}\" }});");
            let (path, _) = scene_with(script, &call, &format!("{script}-{k}"));
            assert_eq!(
                load_scene(&path, &overrides(set)).unwrap().solver.linear,
                LinearBackend::Petsc
            );
            let petsc = run::<D>(&path, set, &format!("{script}-petsc{k}"), None)
                .unwrap_or_else(|e| panic!("{script} {options}: {e}"));
            let _ = std::fs::remove_dir_all(path.parent().unwrap());
            let difference = stress_difference(&petsc.stress, &reference.stress);
            eprintln!(
                "{script} with {options}: Newton {:?} (direct {:?}), Krylov {:?}, eq. 15 \
                 error {:?} (direct {:?}), stress difference {difference:.1e}",
                petsc.newton, reference.newton, petsc.krylov, petsc.error, reference.error
            );
            assert_eq!(petsc.kind, SolverKind::Petsc);
            assert_eq!(petsc.newton, reference.newton, "{script} {options}");
            assert!(
                petsc.krylov.iter().flatten().all(|&k| k >= 1),
                "{:?}",
                petsc.krylov
            );
            if let (Some(a), Some(b)) = (petsc.error, reference.error) {
                assert!((a - b).abs() <= 1e-6 * b, "{script} {options}: {a} {b}");
            }
            assert_eq!(petsc.error.is_some(), reference.error.is_some());
            assert!(difference < 1e-8, "{script} {options}: {difference:e}");
        }
    }

    const GAMG: &str = "-ksp_type cg -pc_type gamg -ksp_rtol 1e-12";
    const HYPRE: &str = "-ksp_type cg -pc_type hypre -ksp_rtol 1e-12";

    #[test]
    fn cg_with_gamg_or_boomeramg_reproduces_the_direct_2d_column() {
        compare::<2>(
            "column_2d.rhai",
            &[("cells", "16"), ("steps", "5")],
            &[GAMG, HYPRE],
        );
    }

    #[test]
    fn cg_with_gamg_reproduces_the_direct_3d_column_and_block() {
        compare::<3>("column_3d.rhai", &[("cells", "8"), ("steps", "3")], &[GAMG]);
        compare::<3>("block_3d.rhai", &[("cells", "4"), ("steps", "2")], &[GAMG]);
    }

    /// Nitsche's surface condition: a non-symmetric tangent, solved by the default GMRES.
    #[test]
    fn a_non_symmetric_tangent_goes_to_gmres_and_gives_the_lu_run() {
        compare::<2>(
            "stretch_phases.rhai",
            &[("up", "2"), ("down", "2")],
            &["-ksp_rtol 1e-12"],
        );
    }

    /// The stiff ring (`common::stiff_ring`) ended by `solver_call`, written to a fresh folder.
    fn ring_scene(solver_call: &str, tag: &str) -> PathBuf {
        let dir = temp_dir("petsc", tag);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("ring.rhai");
        std::fs::write(&path, common::stiff_ring(solver_call)).unwrap();
        path
    }

    /// PETSc's default (GMRES + GAMG) does not converge on the ring's system (DIVERGED_ITS in
    /// step 1); the backend then solves it again with its fallback (GMRES + ASM, LU on the
    /// block), keeps it, and says so once: the run equals the direct one (Newton per step,
    /// stresses to 1e-8). With the method chosen (`-pc_type gamg`, in the scene or on the
    /// command line) nothing falls back: the run fails with PETSc's reason.
    #[test]
    fn a_failed_default_falls_back_to_asm_with_lu_and_says_so_an_explicit_choice_fails() {
        let direct_scene = ring_scene("solver(#{ linear: \"direct\" });", "ring-direct");
        let reference = run::<2>(&direct_scene, &[], "ring-direct", None).unwrap();
        let default_scene = ring_scene(
            "solver(#{ linear: \"petsc\", petsc_options: \"-ksp_rtol 1e-12\" });",
            "ring-default",
        );
        let petsc = run::<2>(&default_scene, &[], "ring-default", None)
            .unwrap_or_else(|e| panic!("the ring with PETSc's default: {e}"));
        let difference = stress_difference(&petsc.stress, &reference.stress);
        let said: Vec<&String> = (petsc.warnings.iter())
            .filter(|w| w.contains("PETSc's default method failed"))
            .collect();
        eprintln!(
            "ring, PETSc's default: Newton {:?} (direct {:?}), Krylov {:?}, stress difference \
             {difference:.1e}, said {said:?}",
            petsc.newton, reference.newton, petsc.krylov
        );
        assert_eq!(petsc.kind, SolverKind::Petsc);
        assert_eq!(petsc.newton, reference.newton);
        assert!(difference < 1e-8, "{difference:e}");
        assert_eq!(said.len(), 1, "{:?}", petsc.warnings);
        assert!(
            said[0].contains("gmres+gamg")
                && said[0].contains("DIVERGED")
                && said[0].contains("gmres+asm"),
            "{}",
            said[0]
        );
        // chosen in the scene: no fallback (the iteration limit only shortens the failure)
        let chosen_scene = ring_scene(
            "solver(#{ linear: \"petsc\", petsc_options: \"-pc_type gamg -ksp_max_it 1000\", \
             max_step_cuts: 0 });",
            "ring-chosen",
        );
        let error = run::<2>(&chosen_scene, &[], "ring-chosen", None)
            .err()
            .expect("GMRES + GAMG chosen does not solve the ring");
        assert!(
            error.contains("DIVERGED") && error.contains("gmres+gamg"),
            "{error}"
        );
        // chosen on the command line
        let cli_scene = ring_scene(
            "solver(#{ linear: \"petsc\", max_step_cuts: 0 });",
            "ring-chosen-cli",
        );
        let out = cli_scene.parent().unwrap().join("out");
        let chosen = impm(&[
            "run",
            &cli_scene.display().to_string(),
            "--out",
            &out.display().to_string(),
            "--threads",
            "1",
            "--petsc-options",
            "-pc_type gamg -ksp_max_it 1000",
        ]);
        let stderr = String::from_utf8_lossy(&chosen.stderr);
        assert!(!chosen.status.success(), "{stderr}");
        assert!(
            stderr.contains("DIVERGED") && !stderr.contains("fallback"),
            "{stderr}"
        );
        for scene in [direct_scene, default_scene, chosen_scene, cli_scene] {
            let _ = std::fs::remove_dir_all(scene.parent().unwrap());
        }
    }

    /// A KSP stopped short with the method chosen (the default falls back instead, above).
    #[test]
    fn a_krylov_solve_stopped_short_fails_with_petscs_reason() {
        let call = "solver(#{ linear: \"petsc\", petsc_options: \"-pc_type gamg -ksp_max_it 1\", \
                    max_step_cuts: 1 });";
        let (path, _) = scene_with("column_2d.rhai", call, "max-it");
        let error = run::<2>(&path, &[("cells", "8"), ("steps", "1")], "max-it", None)
            .err()
            .expect("one CG iteration cannot solve the column");
        assert!(
            error.contains("DIVERGED_ITS") && error.contains("did not converge"),
            "{error}"
        );
        // the same from the command line, over a scene that would converge
        let (path, _) = scene_with(
            "column_2d.rhai",
            "solver(#{ linear: \"petsc\", max_step_cuts: 1 });",
            "max-it-cli",
        );
        let out = path.parent().unwrap().join("out").display().to_string();
        let out_short = path.parent().unwrap().join("short").display().to_string();
        let path = path.display().to_string();
        let set = ["--set", "cells=8", "--set", "steps=1"];
        let good = impm(&[&["run", &path, "--out", &out][..], &set].concat());
        assert!(
            good.status.success(),
            "{}",
            String::from_utf8_lossy(&good.stderr)
        );
        let short = impm(
            &[
                &[
                    "run",
                    &path,
                    "--out",
                    &out_short,
                    "--petsc-options",
                    "-ksp_type cg -ksp_max_it 1",
                ][..],
                &set,
            ]
            .concat(),
        );
        let stderr = String::from_utf8_lossy(&short.stderr);
        assert!(!short.status.success());
        assert!(stderr.contains("DIVERGED_ITS"), "{stderr}");
        let _ = std::fs::remove_dir_all(std::path::Path::new(&path).parent().unwrap());
    }

    #[test]
    fn a_petsc_error_names_the_function_and_petscs_message() {
        let call = "solver(#{ linear: \"petsc\", petsc_options: \"-ksp_type no_such_method\", \
                    max_step_cuts: 0 });";
        let (path, _) = scene_with("column_2d.rhai", call, "unknown-type");
        let error = run::<2>(
            &path,
            &[("cells", "4"), ("steps", "1")],
            "unknown-type",
            None,
        )
        .err()
        .expect("an unknown KSP type fails");
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
        assert!(
            error.contains("KSPSetFromOptions") && error.contains("no_such_method"),
            "{error}"
        );
    }

    /// PETSc ignores options nobody reads; the backend refuses them after its first solve.
    #[test]
    fn a_misspelled_option_is_refused_by_name() {
        let call = "solver(#{ linear: \"petsc\", petsc_options: \"-ksp_typ gmres -pc_type gamg\", \
                    max_step_cuts: 0 });";
        let (path, _) = scene_with("column_2d.rhai", call, "misspelled");
        let error = run::<2>(&path, &[("cells", "4"), ("steps", "1")], "misspelled", None)
            .err()
            .expect("a misspelled option fails");
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
        assert!(
            error.contains("did not use the option(s) -ksp_typ"),
            "{error}"
        );
        assert!(!error.contains("-pc_type"), "{error}");
    }

    /// Arc-length control with the serial PETSc backend (`scripts/footing_pressure_arc.rhai`,
    /// 2 cells across the footing, 6 steps: past first yield, λ 1.0 to 5.45): its first
    /// residual, at λ = 0 on an unstressed body, is zero, and the solver returns the zero
    /// correction without a solve (no Krylov iteration) instead of failing its true-residual
    /// check on 0 / 0; the arc's second solve `K δu_f = f̂` goes through PETSc too. The run
    /// equals the direct one: Newton per step, the load factor per step to 1e-8, stresses to
    /// 1e-8 of the largest.
    #[test]
    fn arc_length_control_with_petsc_equals_the_direct_run() {
        let base = std::fs::read_to_string(shipped_scene("footing_pressure_arc.rhai")).unwrap();
        let asked = "solver(#{ control: \"arc_length\",";
        assert!(base.contains(asked));
        let text = base.replace(
            asked,
            "solver(#{ linear: \"petsc\", petsc_options: \"-ksp_rtol 1e-12\", control: \"arc_length\",",
        );
        let dir = temp_dir("petsc", "arc");
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("footing_pressure_arc.rhai");
        std::fs::write(&path, text).unwrap();
        let set = [("cells", "2"), ("steps", "6")];
        let factors = |tag: &str, solver: Option<Box<dyn LinearSolver>>| {
            let spec = load_scene(&path, &overrides(&set)).unwrap();
            let out = temp_dir("petsc-run", tag);
            let mut sim = Simulation::<2>::new(&spec, &out).unwrap();
            if let Some(solver) = solver {
                sim.world.resource_mut::<Newton>().solver = solver;
            }
            let result = sim.run(|_| {});
            let _ = std::fs::remove_dir_all(&out);
            result.unwrap_or_else(|e| panic!("{tag}: {e}"));
            let steps = &sim.summary.steps;
            (
                steps.iter().map(|s| s.iterations).collect::<Vec<_>>(),
                steps.iter().map(|s| s.load_factor).collect::<Vec<_>>(),
                steps
                    .iter()
                    .map(|s| s.linear_iterations.clone())
                    .collect::<Vec<_>>(),
                sim.stress_profile(1),
                sim.world.resource::<Newton>().last_solver,
            )
        };
        let direct = Box::new(DirectSolver::default()) as Box<dyn LinearSolver>;
        let (newton, load, _, stress, _) = factors("arc-direct", Some(direct));
        let (petsc_newton, petsc_load, krylov, petsc_stress, kind) = factors("arc-petsc", None);
        let _ = std::fs::remove_dir_all(&dir);
        let largest = load.iter().fold(0.0f64, |m, l| m.max(l.abs()));
        let load_difference = (load.iter().zip(&petsc_load))
            .map(|(a, b)| (a - b).abs() / largest)
            .fold(0.0, f64::max);
        let difference = stress_difference(&petsc_stress, &stress);
        eprintln!(
            "footing arc with PETSc: Newton {petsc_newton:?} (direct {newton:?}), Krylov \
             {krylov:?}, load factors {petsc_load:?}, load factor difference \
             {load_difference:.1e}, stress difference {difference:.1e}"
        );
        assert_eq!(kind, SolverKind::Petsc);
        assert_eq!(petsc_newton, newton);
        assert_eq!(petsc_load.len(), load.len());
        assert!(load_difference <= 1e-8, "{load_difference:e}");
        assert!(difference < 1e-8, "{difference:e}");
        // the first residual is zero: no Krylov iteration; every other solve iterated
        assert_eq!(krylov[0][0], 0, "{krylov:?}");
        assert!(
            krylov.iter().flatten().skip(1).all(|&k| k >= 1),
            "{krylov:?}"
        );
        assert!(*load.last().unwrap() > 5.0, "{load:?}");
    }

    #[test]
    fn petsc_options_belong_to_linear_petsc() {
        let call = "solver(#{ linear: \"direct\", petsc_options: \"-ksp_monitor\" });";
        let (path, line) = scene_with("column_1d.rhai", call, "options-without-petsc");
        let message = load_scene(&path, &[]).unwrap_err().to_string();
        let _ = std::fs::remove_dir_all(path.parent().unwrap());
        assert!(message.contains(&format!(":{line}:")), "{message}");
        assert!(
            message.contains("applies to linear: \"petsc\""),
            "{message}"
        );
    }
}
