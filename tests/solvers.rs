//! The linear-solver backends give the same runs: the iterative backend (`solver(#{ linear:
//! "iterative" })`, CG with the Jacobi or the multigrid preconditioner) reproduces the direct
//! solve's column (2D, eq. 15 error and every point's stress) and a 3D block under an inclined
//! traction, to the Newton tolerance, with the same Newton iterations; a non-symmetric tangent
//! (Nitsche's surface condition) goes to BiCGSTAB with multigrid and gives the same run; the
//! multigrid preconditioner keeps CG's iteration count nearly flat under refinement of a
//! self-weight block in 2D and 3D (where Jacobi's grows); the scene words are read and checked;
//! `linear: "auto"` picks by dimension and size and records its choice.

mod common;

use common::{overrides, shipped_scene, stress_difference, temp_dir};
use impm::resources::Newton;
use impm::run::{Simulation, load_scene};
use impm::scene::{LinearBackend, Preconditioning};
use impm::solver::{
    DirectSolver, ITERATIVE_FROM_3D, KrylovSolver, LinearSolver, Multigrid, Smoother, SolverKind,
    SparseMatrix, multiply,
};

/// Makes a new linear solver.
type MakeSolver = Box<dyn Fn() -> Box<dyn LinearSolver>>;

/// The backends compared with the direct solve: the scene's words, and multigrid with a
/// coarsest level of 8 DOFs so that these small problems go through the whole V-cycle (with
/// either smoother).
fn iterative_backends() -> Vec<(&'static str, MakeSolver)> {
    vec![
        (
            "jacobi",
            Box::new(|| LinearBackend::Iterative(Preconditioning::Jacobi).solver()),
        ),
        (
            "multigrid",
            Box::new(|| LinearBackend::Iterative(Preconditioning::default()).solver()),
        ),
        (
            "multigrid-deep",
            Box::new(|| {
                let multigrid = Multigrid::with_coarsest_size(8);
                Box::new(KrylovSolver::with_preconditioner(Box::new(multigrid)))
            }),
        ),
        (
            "multigrid-deep-chebyshev",
            Box::new(|| {
                let mut multigrid = Multigrid::with_coarsest_size(8);
                multigrid.smoother = Smoother::Chebyshev(2);
                Box::new(KrylovSolver::with_preconditioner(Box::new(multigrid)))
            }),
        ),
    ]
}

/// A run's per-step Newton iterations, final eq. 15 error (if any), the points' stress
/// profile along the last axis and how the last system was solved.
type Outcome = (Vec<usize>, Option<f64>, Vec<(f64, f64)>, SolverKind);

/// Runs a shipped scene with the linear solver `solver`.
fn run<const D: usize>(
    script: &str,
    set: &[(&str, &str)],
    tag: &str,
    solver: Box<dyn LinearSolver>,
) -> Outcome {
    let spec = load_scene(&shipped_scene(script), &overrides(set)).unwrap();
    let dir = temp_dir("solvers", &format!("{script}-{tag}"));
    let mut sim = Simulation::<D>::new(&spec, &dir).unwrap();
    sim.world.resource_mut::<Newton>().solver = solver;
    sim.run(|_| {})
        .unwrap_or_else(|e| panic!("{script} {tag}: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    let iterations = sim.summary.steps.iter().map(|s| s.iterations).collect();
    let kind = sim.world.resource::<Newton>().last_solver;
    (
        iterations,
        sim.summary.final_error(),
        sim.stress_profile(D - 1),
        kind,
    )
}

#[test]
fn the_iterative_backends_reproduce_the_direct_column_and_3d_block() {
    let column = [("cells", "16"), ("steps", "5")];
    let block = [("cells", "2"), ("steps", "2")];
    let direct = || Box::new(DirectSolver::default()) as Box<dyn LinearSolver>;
    let (direct_its, direct_error, direct_column, _) =
        run::<2>("column_2d.rhai", &column, "direct", direct());
    let direct_error = direct_error.unwrap();
    let (block_its, _, direct_block, _) =
        run::<3>("block_3d_traction.rhai", &block, "direct", direct());
    for (name, make) in iterative_backends() {
        let (its, error, stresses, kind) = run::<2>("column_2d.rhai", &column, name, make());
        let error = error.unwrap();
        let difference = stress_difference(&stresses, &direct_column);
        eprintln!(
            "column 2D {name}: eq. 15 error {direct_error:.6e} (direct) {error:.6e}, \
             stress difference {difference:.1e}, iterations {direct_its:?} {its:?}"
        );
        assert_eq!(kind, SolverKind::ConjugateGradients);
        assert_eq!(its, direct_its, "{name}");
        assert!(
            (error - direct_error).abs() <= 1e-6 * direct_error,
            "{name}"
        );
        assert!(difference < 1e-8, "{name}: {difference:e}");

        let (its, _, stresses, _) = run::<3>("block_3d_traction.rhai", &block, name, make());
        let difference = stress_difference(&stresses, &direct_block);
        eprintln!(
            "block 3D {name}: stress difference {difference:.1e}, iterations {block_its:?} {its:?}"
        );
        assert_eq!(its, block_its, "{name}");
        assert!(difference < 1e-8, "{name}: {difference:e}");
    }
}

/// Nitsche's surface condition makes the tangent non-symmetric: the iterative backends solve
/// it with BiCGSTAB (multigrid built from the whole tangent, LU on its coarsest level) and
/// give the direct (LU) run's stresses and Newton iterations, loading and unloading.
#[test]
fn a_non_symmetric_tangent_goes_to_bicgstab_with_multigrid_and_gives_the_direct_run() {
    let set = [("up", "2"), ("down", "2")];
    let direct = Box::new(DirectSolver::default());
    let (direct_its, _, direct_stress, kind) =
        run::<2>("stretch_phases.rhai", &set, "direct", direct);
    assert_eq!(kind, SolverKind::Lu);
    for (name, make) in iterative_backends() {
        let (its, _, stresses, kind) = run::<2>("stretch_phases.rhai", &set, name, make());
        let difference = stress_difference(&stresses, &direct_stress);
        eprintln!(
            "stretch (Nitsche) {name}: stress difference {difference:.1e}, iterations \
             {direct_its:?} {its:?}"
        );
        assert_eq!(kind, SolverKind::BiCgStab, "{name}");
        assert_eq!(its, direct_its, "{name}");
        assert!(difference < 1e-8, "{name}: {difference:e}");
    }
}

/// The self-weight block of `scripts/block_2d_self_weight.rhai` (2D) or
/// `scripts/cube_self_weight.rhai` (3D) with `cells` B-spline (q = 2) cells a side, solved in
/// one load step by the multigrid backend; returns the tangent of its last Newton iteration
/// (with its DOF layout).
fn self_weight_tangent<const D: usize>(cells: usize) -> SparseMatrix {
    let script = if D == 2 {
        "block_2d_self_weight.rhai"
    } else {
        "cube_self_weight.rhai"
    };
    let cells = cells.to_string();
    let spec = load_scene(&shipped_scene(script), &overrides(&[("cells", &cells)])).unwrap();
    let dir = temp_dir("solvers", &format!("block{D}d-{cells}"));
    let mut sim = Simulation::<D>::new(&spec, &dir).unwrap();
    sim.run(|_| {})
        .unwrap_or_else(|e| panic!("block {D}D {cells}: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    sim.world.resource::<Newton>().matrix.clone()
}

/// The smoothers every multigrid test below runs with.
const SMOOTHERS: [Smoother; 2] = [Smoother::GaussSeidel, Smoother::Chebyshev(2)];

/// CG iterations to a relative residual of 1e-10 on the tangent of a self-weight block (a
/// smooth right-hand side), with multigrid (its coarsest level at most 50 DOFs, so that every
/// refinement goes through a V-cycle of two levels or more) and with Jacobi, at three
/// refinements; the multigrid solution against the direct one. One list per smoother of
/// [`SMOOTHERS`], in that order.
fn iteration_counts<const D: usize>(refinements: [usize; 3]) -> Vec<Vec<(usize, usize, usize)>> {
    let mut counts = vec![Vec::new(); SMOOTHERS.len()];
    for cells in refinements {
        let matrix = self_weight_tangent::<D>(cells);
        let n = matrix.size();
        let rhs: Vec<f64> = (0..n).map(|i| (0.001 * i as f64).sin() + 0.5).collect();
        let mut direct = rhs.clone();
        DirectSolver::default()
            .solve(&matrix, true, &mut direct)
            .unwrap();
        let mut jacobi = KrylovSolver::default();
        let mut y = rhs.clone();
        jacobi.solve(&matrix, true, &mut y).unwrap();
        for (smoother, counts) in SMOOTHERS.iter().zip(counts.iter_mut()) {
            let mut preconditioner = Multigrid::with_coarsest_size(50);
            preconditioner.smoother = *smoother;
            let mut multigrid = KrylovSolver::with_preconditioner(Box::new(preconditioner));
            let mut x = rhs.clone();
            assert_eq!(
                multigrid.solve(&matrix, true, &mut x),
                Ok(SolverKind::ConjugateGradients)
            );
            let hierarchy = multigrid.hierarchy().expect("a multigrid hierarchy");
            let mut check = vec![0.0; n];
            multiply(&matrix, &x, &mut check);
            let residual = relative(&check, &rhs);
            let error = relative(&x, &direct);
            eprintln!(
                "{D}D block, {cells} cells a side, {n} DOFs: CG iterations multigrid ({smoother:?}) {} jacobi {}, \
             multigrid residual {residual:.1e}, difference from direct {error:.1e}; {hierarchy}",
                multigrid.last_iterations, jacobi.last_iterations
            );
            assert!(residual <= 1e-9, "{residual:e}");
            assert!(error < 1e-6, "{error:e}");
            // each level far smaller than the one below: the setup's products and a V-cycle cost
            // little more than the finest level's
            assert!(
                hierarchy.operator_complexity() <= MAX_OPERATOR_COMPLEXITY,
                "{D}D, {cells} cells: {hierarchy}"
            );
            assert!(hierarchy.rows.len() >= 2, "{hierarchy}");
            counts.push((n, multigrid.last_iterations, jacobi.last_iterations));
        }
    }
    counts
}

fn relative(a: &[f64], b: &[f64]) -> f64 {
    let diff: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    (diff / b.iter().map(|y| y * y).sum::<f64>()).sqrt()
}

/// The multigrid bound: from the coarsest to the finest of three refinements (each doubling
/// the cells per side) the multigrid count grows by at most MULTIGRID_GROWTH and stays below
/// MULTIGRID_MAX, while Jacobi grows and needs more than JACOBI_RATIO times multigrid's
/// iterations at the finest (so the test sees the difference multigrid makes).
const MULTIGRID_GROWTH: f64 = 1.5;
const MULTIGRID_MAX: usize = 60;
const JACOBI_RATIO: f64 = 3.0;
/// Σ non-zeros of the levels / non-zeros of the tangent, at every refinement (box aggregates of
/// 4 nodes a side: measured 1.0x in 3D and 1.1x in 2D, see docs/performance.md).
const MAX_OPERATOR_COMPLEXITY: f64 = 1.5;

fn assert_flat(counts: &[(usize, usize, usize)]) {
    let (first, last) = (counts[0], counts[counts.len() - 1]);
    let growth = last.1 as f64 / first.1 as f64;
    assert!(
        growth <= MULTIGRID_GROWTH,
        "multigrid iterations {counts:?}"
    );
    assert!(counts.iter().all(|c| c.1 <= MULTIGRID_MAX), "{counts:?}");
    assert!(last.2 > first.2, "Jacobi iterations {counts:?}");
    assert!(
        last.2 as f64 > JACOBI_RATIO * last.1 as f64,
        "Jacobi iterations {counts:?}"
    );
}

#[test]
fn multigrid_keeps_the_cg_iterations_flat_under_refinement_in_2d() {
    iteration_counts::<2>([16, 32, 64])
        .iter()
        .for_each(|c| assert_flat(c));
}

#[test]
fn multigrid_keeps_the_cg_iterations_flat_under_refinement_in_3d() {
    iteration_counts::<3>([3, 6, 12])
        .iter()
        .for_each(|c| assert_flat(c));
}

#[test]
fn the_scene_chooses_the_backend_and_a_wrong_word_names_its_line() {
    let scene = |linear: &str| {
        let base = std::fs::read_to_string(shipped_scene("column_1d.rhai")).unwrap();
        let text = format!("{base}\nsolver(#{{ linear: \"{linear}\" }});\n");
        let tag = linear.replace(|c: char| !c.is_alphanumeric(), "_");
        let dir = temp_dir("solvers", &format!("scene-{tag}"));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("column.rhai");
        std::fs::write(&path, text).unwrap();
        let lines = std::fs::read_to_string(&path).unwrap().lines().count();
        let result = load_scene(&path, &[]);
        let _ = std::fs::remove_dir_all(&dir);
        (result, lines)
    };
    let (spec, _) = scene("iterative");
    assert_eq!(
        spec.unwrap().solver.linear,
        LinearBackend::Iterative(Preconditioning::default())
    );
    let (spec, _) = scene("iterative\", preconditioner: \"jacobi");
    assert_eq!(
        spec.unwrap().solver.linear,
        LinearBackend::Iterative(Preconditioning::Jacobi)
    );
    let (spec, _) = scene("iterative\", smoother: \"gauss_seidel");
    assert_eq!(
        spec.unwrap().solver.linear,
        LinearBackend::Iterative(Preconditioning::Multigrid(Smoother::GaussSeidel))
    );
    assert_eq!(Smoother::default(), Smoother::Chebyshev(2));
    let (spec, _) = scene("direct");
    assert_eq!(spec.unwrap().solver.linear, LinearBackend::Direct);
    let (error, lines) = scene("gmres");
    let message = error.unwrap_err().to_string();
    assert!(message.contains(&format!(":{lines}:")), "{message}");
    assert!(
        message.contains("gmres") && message.contains("iterative"),
        "{message}"
    );
    for (wrong, says) in [
        ("iterative\", preconditioner: \"ilu", "multigrid"),
        ("direct\", preconditioner: \"jacobi", "applies to"),
        ("iterative\", smoother: \"jacobi", "gauss_seidel"),
        (
            "iterative\", preconditioner: \"jacobi\", smoother: \"chebyshev",
            "multigrid preconditioner only",
        ),
        ("auto\", smoother: \"chebyshev", "applies to"),
    ] {
        let (error, lines) = scene(wrong);
        let message = error.unwrap_err().to_string();
        assert!(message.contains(&format!(":{lines}:")), "{message}");
        assert!(message.contains(says), "{message}");
    }
}

/// Inexact Newton (Eisenstat–Walker forcing terms) on the 2D block under a heavy self-weight
/// (stretches of several per cent: Newton needs several iterations): the same converged
/// stresses as exact solves to the Newton tolerance, at most two more Newton iterations per
/// step, and fewer Krylov iterations in all; each step's Krylov iterations are recorded.
#[test]
fn inexact_newton_converges_to_the_same_answer_with_fewer_krylov_iterations() {
    let run = |inexact: &str| {
        let set = [
            ("cells", "24"),
            ("steps", "2"),
            ("gravity", "5000.0"),
            ("inexact", inexact),
        ];
        let sim = common::run_shipped::<2>("block_2d_self_weight.rhai", &set);
        let steps = &sim.summary.steps;
        let newton: Vec<usize> = steps.iter().map(|s| s.iterations).collect();
        let krylov: Vec<Vec<usize>> = steps.iter().map(|s| s.linear_iterations.clone()).collect();
        let residuals: Vec<Vec<f64>> = steps.iter().map(|s| s.residuals.clone()).collect();
        let mut sim = sim;
        (newton, krylov, residuals, sim.stress_profile(1))
    };
    let (exact_newton, exact_krylov, exact_residuals, exact_stress) = run("false");
    let (newton, krylov, residuals, stress) = run("true");
    let difference = stress_difference(&stress, &exact_stress);
    eprintln!(
        "exact: Newton {exact_newton:?}, Krylov {exact_krylov:?}, residuals {exact_residuals:?}"
    );
    eprintln!(
        "inexact: Newton {newton:?}, Krylov {krylov:?}, residuals {residuals:?}, stress \
         difference {difference:.1e}"
    );
    assert!(exact_newton.iter().all(|&n| n >= 3), "{exact_newton:?}");
    for (k, n) in krylov.iter().zip(&newton) {
        assert_eq!(k.len(), *n);
    }
    for (inexact, exact) in newton.iter().zip(&exact_newton) {
        assert!(inexact <= &(exact + 2), "{newton:?} {exact_newton:?}");
    }
    let total = |k: &[Vec<usize>]| k.iter().flatten().sum::<usize>();
    assert!(
        total(&krylov) < total(&exact_krylov),
        "{krylov:?} {exact_krylov:?}"
    );
    assert!(difference < 1e-6, "{difference:e}");
}

/// The multigrid hierarchy of each step is in `summary.json` (rows and non-zeros per level,
/// grid and operator complexity) and in the step's record, and matches what the solver built.
#[test]
fn the_multigrid_hierarchy_is_recorded_in_the_summary() {
    let spec = load_scene(
        &shipped_scene("block_2d_self_weight.rhai"),
        &overrides(&[("cells", "32")]),
    )
    .unwrap();
    let dir = temp_dir("solvers", "hierarchy-summary");
    let mut sim = Simulation::<2>::new(&spec, &dir).unwrap();
    sim.run(|_| {}).unwrap();
    let built = sim.world.resource::<Newton>().solver.hierarchy().unwrap();
    let recorded = sim.summary.steps[0].multigrid.clone().unwrap();
    assert_eq!(recorded, built);
    assert_eq!(recorded.rows[0], sim.summary.steps[0].dofs);
    assert!(recorded.rows.len() >= 2, "{recorded}");
    assert!(recorded.rows.windows(2).all(|w| w[1] < w[0]), "{recorded}");
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let multigrid = &json["steps"][0]["multigrid"];
    let rows: Vec<usize> = multigrid["rows"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    assert_eq!(rows, recorded.rows);
    let complexity = multigrid["operator_complexity"].as_f64().unwrap();
    let expected = recorded.nonzeros.iter().sum::<usize>() as f64 / recorded.nonzeros[0] as f64;
    assert!((complexity - expected).abs() < 1e-12 && complexity <= MAX_OPERATOR_COMPLEXITY);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `linear: "auto"` (`solver::AutoSolver`): a cube above the 3D threshold is solved by CG with
/// Jacobi and gives the direct run's Newton iterations and stresses (to 1e-8 of the largest);
/// the 1D column is solved directly; each step's summary says which backend and why, in
/// `summary.json` too; `preconditioner` with "auto" is refused at its line.
#[test]
fn auto_chooses_the_backend_by_dimension_and_size_and_says_why() {
    let cube = |linear| {
        common::run_shipped::<3>(
            "cube_self_weight.rhai",
            &[("cells", "8"), ("linear", linear)],
        )
    };
    let (mut auto, mut direct) = (cube("auto"), cube("direct"));
    let difference = stress_difference(&auto.stress_profile(2), &direct.stress_profile(2));
    let (step, reference) = (&auto.summary.steps[0], &direct.summary.steps[0]);
    assert!(step.dofs >= ITERATIVE_FROM_3D, "{} DOFs", step.dofs);
    let choice = step.linear_backend.clone().unwrap_or_default();
    assert!(
        choice.starts_with(&format!("iterative (jacobi): 3D, {} DOFs ≥", step.dofs)),
        "{choice}"
    );
    assert_eq!(step.linear_iterations.len(), step.iterations);
    assert_eq!(
        auto.world.resource::<Newton>().last_solver,
        SolverKind::ConjugateGradients
    );
    assert_eq!(step.iterations, reference.iterations);
    eprintln!("cube, 8 cells, auto ({choice}) against direct: stresses {difference:.1e}");
    assert!(difference < 1e-8, "{difference:e}");
    assert_eq!(reference.linear_backend, None);

    let base = std::fs::read_to_string(shipped_scene("column_1d.rhai")).unwrap();
    let dir = temp_dir("solvers", "auto-column");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("column.rhai");
    std::fs::write(&path, format!("{base}\nsolver(#{{ linear: \"auto\" }});\n")).unwrap();
    let spec = load_scene(&path, &[]).unwrap();
    assert_eq!(spec.solver.linear, LinearBackend::Auto);
    let out = dir.join("out");
    let mut sim = Simulation::<1>::new(&spec, &out).unwrap();
    sim.run(|_| {}).unwrap();
    let text = std::fs::read_to_string(out.join("summary.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    for step in json["steps"].as_array().unwrap() {
        let choice = step["linear_backend"].as_str().unwrap_or_default();
        assert!(choice.starts_with("direct: 1D"), "{choice}");
    }
    std::fs::write(
        &path,
        format!("{base}\nsolver(#{{ linear: \"auto\", preconditioner: \"jacobi\" }});\n"),
    )
    .unwrap();
    let lines = std::fs::read_to_string(&path).unwrap().lines().count();
    let message = load_scene(&path, &[]).unwrap_err().to_string();
    assert!(
        message.contains(&format!(":{lines}:")) && message.contains("applies to"),
        "{message}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The direct solver solves again with the factor of its last solve (what the line search's
/// natural level function needs): Cholesky and LU alike, the answer that of the matrix it
/// factorised even after the matrix changed (its values doubled), and `None` where no factor
/// is kept (before a first solve, another size, an iterative solver).
#[test]
fn the_direct_solver_solves_again_with_its_last_factorisation() {
    let mut matrix = self_weight_tangent::<2>(4);
    let n = matrix.size();
    let first: Vec<f64> = (0..n).map(|i| (0.01 * i as f64).cos()).collect();
    let second: Vec<f64> = (0..n).map(|i| (0.003 * i as f64).sin() + 0.2).collect();
    assert!(
        DirectSolver::default()
            .solve_with_last_factor(&mut second.clone())
            .is_none()
    );
    for (symmetric, kind) in [(true, SolverKind::Cholesky), (false, SolverKind::Lu)] {
        let mut solver = DirectSolver::default();
        let mut x = first.clone();
        assert_eq!(solver.solve(&matrix, symmetric, &mut x), Ok(kind));
        let mut y = second.clone();
        assert!(matches!(
            solver.solve_with_last_factor(&mut y),
            Some(Ok(()))
        ));
        let mut check = vec![0.0; n];
        multiply(&matrix, &y, &mut check);
        let residual = relative(&check, &second);
        assert!(residual < 1e-10, "{kind:?}: {residual:e}");
        // the matrix changes (a new iterate's tangent, same pattern): the kept factor is the old one
        matrix.with_values_apart(|_, values| values.iter_mut().for_each(|v| *v *= 2.0));
        let mut z = second.clone();
        assert!(matches!(
            solver.solve_with_last_factor(&mut z),
            Some(Ok(()))
        ));
        assert!(relative(&z, &y) < 1e-12, "{kind:?}");
        matrix.with_values_apart(|_, values| values.iter_mut().for_each(|v| *v *= 0.5));
        assert!(
            solver
                .solve_with_last_factor(&mut vec![1.0; n + 1])
                .is_none()
        );
    }
    let mut krylov = KrylovSolver::default();
    let mut x = first.clone();
    krylov.solve(&matrix, true, &mut x).unwrap();
    assert!(krylov.solve_with_last_factor(&mut second.clone()).is_none());
}
