//! The linear-solver backends give the same runs: the iterative backend (`solver(#{ linear:
//! "iterative" })`: Jacobi-preconditioned CG) reproduces the direct solve's column (2D, eq. 15
//! error and every point's stress) and a 3D block under an inclined traction, to the Newton
//! tolerance, with the same Newton iterations; the scene word is read and checked.

mod common;

use common::{overrides, shipped_scene, temp_dir};
use impm::run::{Simulation, load_scene};
use impm::scene::LinearBackend;

/// Runs a shipped scene with the given backend; returns the summary's per-step Newton
/// iterations, the final eq. 15 error (if any) and the points' vertical stress profile.
fn run<const D: usize>(
    script: &str,
    set: &[(&str, &str)],
    backend: LinearBackend,
) -> (Vec<usize>, Option<f64>, Vec<(f64, f64)>) {
    let mut spec = load_scene(&shipped_scene(script), &overrides(set)).unwrap();
    spec.solver.linear = backend;
    let dir = temp_dir("solvers", &format!("{script}-{backend:?}"));
    let mut sim = Simulation::<D>::new(&spec, &dir).unwrap();
    sim.run(|_| {})
        .unwrap_or_else(|e| panic!("{script} {backend:?}: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    let iterations = sim.summary.steps.iter().map(|s| s.iterations).collect();
    (
        iterations,
        sim.summary.final_error(),
        sim.stress_profile(D - 1),
    )
}

/// Largest stress difference relative to the largest stress.
fn stress_difference(a: &[(f64, f64)], b: &[(f64, f64)]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().map(|p| p.1.abs()).fold(0.0, f64::max);
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            assert_eq!(p.0, q.0);
            (p.1 - q.1).abs() / scale
        })
        .fold(0.0, f64::max)
}

#[test]
fn the_iterative_backend_reproduces_the_direct_column_and_3d_block() {
    let column = [("cells", "16"), ("steps", "5")];
    let (direct_its, direct_error, direct) =
        run::<2>("column_2d.rhai", &column, LinearBackend::Direct);
    let (krylov_its, krylov_error, krylov) =
        run::<2>("column_2d.rhai", &column, LinearBackend::Iterative);
    let (direct_error, krylov_error) = (direct_error.unwrap(), krylov_error.unwrap());
    let difference = stress_difference(&krylov, &direct);
    eprintln!(
        "column 2D: eq. 15 error {direct_error:.6e} (direct) {krylov_error:.6e} (iterative), \
         stress difference {difference:.1e}, iterations {direct_its:?} {krylov_its:?}"
    );
    assert_eq!(krylov_its, direct_its);
    assert!((krylov_error - direct_error).abs() <= 1e-6 * direct_error);
    assert!(difference < 1e-8, "{difference:e}");

    let block = [("cells", "2"), ("steps", "2")];
    let (direct_its, _, direct) = run::<3>("block_3d_traction.rhai", &block, LinearBackend::Direct);
    let (krylov_its, _, krylov) =
        run::<3>("block_3d_traction.rhai", &block, LinearBackend::Iterative);
    let difference = stress_difference(&krylov, &direct);
    eprintln!(
        "block 3D: stress difference {difference:.1e}, iterations {direct_its:?} {krylov_its:?}"
    );
    assert_eq!(krylov_its, direct_its);
    assert!(difference < 1e-8, "{difference:e}");
}

#[test]
fn the_scene_chooses_the_backend_and_a_wrong_word_names_its_line() {
    let scene = |linear: &str| {
        let base = std::fs::read_to_string(shipped_scene("column_1d.rhai")).unwrap();
        let text = format!("{base}\nsolver(#{{ linear: \"{linear}\" }});\n");
        let dir = temp_dir("solvers", &format!("scene-{linear}"));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("column.rhai");
        std::fs::write(&path, text).unwrap();
        let lines = std::fs::read_to_string(&path).unwrap().lines().count();
        let result = load_scene(&path, &[]);
        let _ = std::fs::remove_dir_all(&dir);
        (result, lines)
    };
    let (spec, _) = scene("iterative");
    assert_eq!(spec.unwrap().solver.linear, LinearBackend::Iterative);
    let (spec, _) = scene("direct");
    assert_eq!(spec.unwrap().solver.linear, LinearBackend::Direct);
    let (error, lines) = scene("gmres");
    let message = error.unwrap_err().to_string();
    assert!(message.contains(&format!(":{lines}:")), "{message}");
    assert!(
        message.contains("gmres") && message.contains("iterative"),
        "{message}"
    );
}
