//! The paper's self-weight column (section 3) through the shipped scenes: accuracy against the
//! semi-analytic solution (eq. 15), quadratic Newton convergence, and 2D/3D against 1D.

mod common;

use common::run_shipped;
use impm::summary::Summary;

/// Runs a column scene; returns the summary and the final (reference height, vertical stress)
/// of every point.
fn run<const D: usize>(script: &str, set: &[(&str, &str)]) -> (Summary, Vec<(f64, f64)>) {
    let mut sim = run_shipped::<D>(script, set);
    let profile = sim.stress_profile(D - 1);
    (sim.summary, profile)
}

/// Eq. 15 error at or below 1e-3 for B-spline q = 2 and q = 3, 4 points per cell, 50 cells,
/// at W = 10000 (b_f = -200) and W = 40000 (b_f = -800).
#[test]
fn bspline_column_1d_is_accurate() {
    for order in ["2", "3"] {
        for body_force in ["-200", "-800"] {
            let (summary, _) = run::<1>(
                "column_1d.rhai",
                &[
                    ("basis", "bspline"),
                    ("order", order),
                    ("ppc", "4"),
                    ("cells", "50"),
                    ("body_force", body_force),
                ],
            );
            let error = summary.final_error().unwrap();
            eprintln!("q = {order}, b_f = {body_force}: error {error:.3e}");
            assert!(
                error <= 1e-3,
                "q = {order}, b_f = {body_force}: error {error:e}"
            );
            assert!(summary.steps.iter().all(|s| s.converged));
        }
    }
}

/// Newton converges quadratically: once the residual is well above round-off, each iterate's
/// residual is bounded by C r_k² (observed order log r_{k+1} / log r_k >= 1.8).
#[test]
fn newton_converges_quadratically_on_the_column() {
    let (summary, _) = run::<1>("column_1d.rhai", &[("body_force", "-8000")]);
    let mut checked = 0;
    for step in &summary.steps {
        assert!(step.converged);
        for pair in step.residuals.windows(2) {
            let (r0, r1) = (pair[0], pair[1]);
            // Only where both are meaningfully above round-off and below 1 (asymptotic range).
            if r0 < 1e-2 && r1 > 1e-13 {
                let order = r1.ln() / r0.ln();
                assert!(
                    order >= 1.8,
                    "step {}: residuals {:?}: order {order}",
                    step.step,
                    step.residuals
                );
                checked += 1;
            }
        }
    }
    assert!(
        checked >= 10,
        "too few iterates in the asymptotic range: {checked}"
    );
}

fn assert_profiles_agree(
    lower: &[(f64, f64)],
    higher: &[(f64, f64)],
    per_height: usize,
    what: &str,
) {
    assert_eq!(
        higher.len(),
        lower.len() * per_height,
        "{what}: point counts"
    );
    let scale = lower.iter().fold(0.0f64, |m, p| m.max(p.1.abs()));
    for (k, chunk) in higher.chunks(per_height).enumerate() {
        for p in chunk {
            assert!(
                (p.0 - lower[k].0).abs() < 1e-9,
                "{what}: heights {} vs {}",
                p.0,
                lower[k].0
            );
            assert!(
                (p.1 - lower[k].1).abs() <= 1e-6 * scale,
                "{what}: stress at X = {}: {} vs 1D {}",
                p.0,
                p.1,
                lower[k].1
            );
        }
    }
}

/// The one-cell-wide 2D column (plane strain, rollers, nu = 0) has the 1D stresses.
#[test]
fn column_2d_agrees_with_1d() {
    let set = [
        ("cells", "20"),
        ("order", "3"),
        ("ppc", "3"),
        ("body_force", "-800"),
    ];
    let (s1, p1) = run::<1>("column_1d.rhai", &set);
    let (s2, p2) = run::<2>("column_2d.rhai", &set);
    assert_profiles_agree(&p1, &p2, 3, "2D");
    let (e1, e2) = (s1.final_error().unwrap(), s2.final_error().unwrap());
    assert!((e1 - e2).abs() <= 1e-6 * e1, "eq. 15: 1D {e1:e}, 2D {e2:e}");
}

/// The 3D column (rollers on four sides) has the 1D stresses.
#[test]
fn column_3d_agrees_with_1d() {
    let set = [
        ("cells", "10"),
        ("order", "2"),
        ("ppc", "2"),
        ("body_force", "-800"),
        ("steps", "5"),
    ];
    let (s1, p1) = run::<1>("column_1d.rhai", &set);
    let (s3, p3) = run::<3>("column_3d.rhai", &set);
    assert_profiles_agree(&p1, &p3, 4, "3D");
    let (e1, e3) = (s1.final_error().unwrap(), s3.final_error().unwrap());
    assert!((e1 - e3).abs() <= 1e-6 * e1, "eq. 15: 1D {e1:e}, 3D {e3:e}");
}

/// Linear MPM with one point per cell is the paper's comparator: it runs, but is far less
/// accurate than cubic B-splines on the same grid (paper Fig. 2b).
#[test]
fn linear_mpm_is_less_accurate_than_bspline() {
    let (linear, _) = run::<1>("column_1d.rhai", &[("basis", "linear")]);
    let (cubic, _) = run::<1>("column_1d.rhai", &[]);
    let (el, ec) = (linear.final_error().unwrap(), cubic.final_error().unwrap());
    assert!(el > 10.0 * ec, "linear {el:e} vs cubic {ec:e}");
}
