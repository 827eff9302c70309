//! `material_of` from a yielded state and under arc-length control
//! (`src/effects/material_switches.rs`, "The plastic strain carried", "A state on the yield
//! surface"): a von Mises block yielded in its first stage and switched to a model whose
//! surface passes through its stress (the same von Mises surface, a hardening one at the
//! carried plastic strain, Mohr–Coulomb touching it) goes on as the run that was not switched,
//! its plastic strain carried; a stress outside the new surface beyond the stated tolerance is
//! refused with the `material_of` line, body and stage; a switch at the start of an
//! arc-controlled stage runs, each arc point where load control at the arc's load factors
//! puts the block.

use impm::components::Position;
use impm::material::PlasticHistory;
use impm::run::Simulation;
use nalgebra::Matrix3;

mod common;

fn build(tag: &str, text: &str) -> (Simulation<2>, std::path::PathBuf) {
    let spec =
        common::scene_from_text("stages-switch-scene", tag, text).unwrap_or_else(|e| panic!("{e}"));
    let dir = common::temp_dir("stages-switch", tag);
    (Simulation::<2>::new(&spec, &dir).unwrap(), dir)
}

/// The yield stress of the first material.
const SIGMA_Y: f64 = 100.0;

/// A block 1 × 1 in plane strain (E = 1e6, ν = 0), quadratic B-splines, 2 × 2 cells of a
/// 2 × 3 grid, 3 × 3 Gauss points per cell, on rollers at its base and sides, its top loaded
/// by a traction (32 traction points per cell). Stage "yield" (line 7): von Mises (σ_y = 100,
/// hardening `hardening`) under q = 55, 110: confined compression with ν = 0 is uniaxial
/// stress while elastic and yields at q = σ_y (σ_yy = −q, σ_xx = σ_zz = σ_yy + σ_y(ε̄_p) past
/// it). Stage "switch" (line 9): `material_of` (line 10) gives the block material "second"
/// (`second`: its model and parameters) and another traction adds 10 λ, λ = 0, 0.5, 1.
fn yielded_block(hardening: f64, second: &str) -> String {
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 1.5], cells: [2, 3], basis: \"bspline\", order: 2 }});\n\
         const first = material(#{{ name: \"first\", model: \"von_mises\", sigma_y: {SIGMA_Y:?}, H: {hardening:?}, E: 1.0e6, nu: 0.0, density: 1.0 }});\n\
         const second = material(#{{ name: \"second\", {second}, E: 1.0e6, nu: 0.0, density: 1.0 }});\n\
         body(#{{ name: \"block\", material: first, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 3, placement: \"gauss\" }});\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         stage(#{{ name: \"yield\", steps: 2 }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -110.0], per_cell: 32 }});\n\
         stage(#{{ name: \"switch\", load_factors: [0.0, 0.5, 1.0] }});\n\
         material_of(#{{ body: \"block\", material: \"second\" }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -10.0], per_cell: 32 }});\n"
    )
}

/// Every point's Kirchhoff stress and plastic strain (0 for a point without a plastic
/// history), in `PointId` order.
fn states(sim: &mut Simulation<2>) -> Vec<(Matrix3<f64>, f64)> {
    use impm::material::{MohrCoulomb, VonMises};
    let strain = |h: &PlasticHistory| h.plastic_strain;
    common::point_states::<VonMises, MohrCoulomb>(sim, strain, strain)
        .into_iter()
        .map(|(stress, e)| (stress, e.unwrap_or(0.0)))
        .collect()
}

/// The largest stress difference and the largest plastic-strain difference of two states.
fn departures(a: &[(Matrix3<f64>, f64)], b: &[(Matrix3<f64>, f64)]) -> (f64, f64) {
    a.iter().zip(b).fold((0.0f64, 0.0f64), |(s, e), (a, b)| {
        (s.max((a.0 - b.0).amax()), e.max((a.1 - b.1).abs()))
    })
}

/// A yielded von Mises block switched to a model whose surface is the one it stands on: the
/// same von Mises material (perfectly plastic, σ_y = 100: the stress on the surface, which the
/// check at ε̄_p = 0 may find outside by round-off), and with linear hardening (H = 1e4, the
/// first material the same: the stress on the surface at the accumulated ε̄_p, outside the
/// initial one by H ε̄_p; without the plastic strain carried it would be refused, or flow
/// again). Both go on as the run not switched: after every step of stage "switch" every
/// stress within 1e-8 σ_y and every plastic strain within 1e-9 of it (both: the history
/// rebuilt from the stress, round-off), the Newton iterations per step the same; after the
/// stage's first step (no new load) the plastic strain is the one before the switch to 1e-6 of
/// it (carried, not restarted from zero; measured 5.9e-12 absolute of 2.0e-5 with perfect
/// plasticity: the λ = 0 step's own flow on the surface, the same in the run not switched).
#[test]
fn a_yielded_von_mises_body_switched_onto_its_surface_goes_on_as_the_run_not_switched() {
    for (hardening, tag) in [(0.0, "perfect"), (1.0e4, "hardening")] {
        let second = format!("model: \"von_mises\", sigma_y: {SIGMA_Y:?}, H: {hardening:?}");
        let text = yielded_block(hardening, &second);
        let (mut sim, dir) = build(&format!("vm-{tag}"), &text);
        let plain_text = text.replace("material_of(", "// material_of(");
        let (mut plain, plain_dir) = build(&format!("vm-{tag}-plain"), &plain_text);
        for _ in 0..2 {
            sim.step().unwrap();
            plain.step().unwrap();
        }
        let before = states(&mut sim);
        let yielded = before.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
        assert!(yielded > 0.0, "{tag}: every point yielded in stage 'yield'");
        let (mut worst_stress, mut worst_strain) = (0.0f64, 0.0f64);
        for step in 3..=5 {
            let iterations = sim.step().unwrap().iterations;
            assert_eq!(
                iterations,
                plain.step().unwrap().iterations,
                "{tag} step {step}"
            );
            let (now, reference) = (states(&mut sim), states(&mut plain));
            let (stress, strain) = departures(&now, &reference);
            if step == 3 {
                let (_, carried) = departures(&now, &before);
                println!(
                    "{tag}: plastic strain before the switch {yielded:.4e}..; after the stage's first step it differs by {carried:.1e}"
                );
                assert!(carried <= 1e-6 * yielded, "{tag}: {carried:e}");
            }
            println!(
                "{tag}: step {step} ({iterations} iterations): against the run not switched: stress {stress:.2e}, plastic strain {strain:.2e}"
            );
            worst_stress = worst_stress.max(stress);
            worst_strain = worst_strain.max(strain);
        }
        assert!(worst_stress < 1e-8 * SIGMA_Y, "{tag}: {worst_stress:e}");
        assert!(worst_strain < 1e-9, "{tag}: {worst_strain:e}");
        for dir in [dir, plain_dir] {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// The cohesion at which the Mohr–Coulomb surface (φ = 30°) passes through the most loaded of
/// the Kirchhoff stresses `states`: the largest `((τ_1 − τ_3) + (τ_1 + τ_3) sin φ) / (2 cos φ)`.
fn cohesion_through(states: &[(Matrix3<f64>, f64)]) -> f64 {
    let phi = 30.0f64.to_radians();
    states
        .iter()
        .map(|(tau, _)| {
            let mut p: Vec<f64> = tau.symmetric_eigen().eigenvalues.iter().copied().collect();
            p.sort_by(|a, b| b.total_cmp(a));
            ((p[0] - p[2]) + (p[0] + p[2]) * phi.sin()) / (2.0 * phi.cos())
        })
        .fold(f64::NEG_INFINITY, f64::max)
}

/// A yielded von Mises block (σ_y = 100, at q = 110: σ = (−10, −110, −10)) switched to
/// Mohr–Coulomb (φ = ψ = 30°): with c = 30 its stress lies well inside (c = 23.1 passes
/// through it): taken as it is (every stress after the stage's first step the one before to
/// 1e-6 σ_y, measured 3.5e-8 σ_y: that step resolves the out-of-balance force Newton left at
/// the end of stage "yield" with the new elastic stiffness; the plastic strain carried bit for
/// bit); with c a relative 1e-7 below the
/// cohesion through the most loaded point (outside by about 3e-8 of the yield stress there,
/// within the tolerance 1e-6) projected onto the surface (the stress within 1e-6 σ_y, the
/// plastic strain carried to 1e-6 of it); with c a relative 1e-4 below (outside by 3.4e-5)
/// refused at the stage's first step, the error naming the `material_of` line, the body, the
/// stage and the departure.
#[test]
fn a_yielded_von_mises_body_switched_to_mohr_coulomb_is_taken_within_the_tolerance_only() {
    let probe_text = yielded_block(0.0, "model: \"mohr_coulomb\", c: 30.0, phi: 30.0");
    let (mut probe, dir) = build("mc-inside", &probe_text);
    for _ in 0..2 {
        probe.step().unwrap();
    }
    let before = states(&mut probe);
    let through = cohesion_through(&before);
    println!("the Mohr–Coulomb cohesion through the most loaded point: {through:.12}");
    assert!(through < 30.0 && through > 20.0, "{through}");
    probe.step().unwrap();
    let (stress, strain) = departures(&states(&mut probe), &before);
    println!(
        "c = 30: after the switch's first step: stress {stress:.2e}, plastic strain {strain:.1e}"
    );
    assert!(stress < 1e-6 * SIGMA_Y, "{stress:e}");
    assert_eq!(strain, 0.0);
    for _ in 4..=5 {
        probe.step().unwrap();
    }
    let _ = std::fs::remove_dir_all(dir);

    for (relative, accepted) in [(1e-7, true), (1e-4, false)] {
        let c = through * (1.0 - relative);
        let text = yielded_block(
            0.0,
            &format!("model: \"mohr_coulomb\", c: {c:?}, phi: 30.0"),
        );
        let (mut sim, dir) = build(&format!("mc-{relative:e}"), &text);
        for _ in 0..2 {
            sim.step().unwrap();
        }
        let result = sim.step().map(|r| r.iterations);
        match accepted {
            true => {
                let iterations = result.unwrap_or_else(|e| panic!("c = {c}: {e}"));
                let (stress, strain) = departures(&states(&mut sim), &before);
                println!(
                    "c = {c:.12} (−{relative:e}): taken, {iterations} iterations; stress moved {stress:.2e}, plastic strain {strain:.1e}"
                );
                assert!(stress < 1e-6 * SIGMA_Y, "{stress:e}");
                assert!(strain <= 1e-6 * before[0].1, "{strain:e}");
            }
            false => {
                let error = result.expect_err("refused").to_string();
                println!("c = {c:.12} (−{relative:e}): {error}");
                for part in [
                    "material_of(...) at line 10 (body 'block', stage 'switch')",
                    "outside the new yield surface by",
                    "mohr_coulomb",
                ] {
                    assert!(error.contains(part), "{part}: {error}");
                }
            }
        }
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// The block of `tests/arc_length_staged.rs` (Hencky, E = 1000, ν = 0.3, density 1, 1 × 1,
/// quadratic B-splines, 2 × 2 cells, rollers at the base and sides; its weight in stage
/// "gravity", 2 steps) whose stage "load" (the last) is under arc-length control when
/// `control` is `arc_length` (else at `factors`) and switches the block to von Mises
/// (σ_y = 12, the same elasticity) at its start when `switch`; the load a top traction q = 10.
fn switched_arc_block(control: &str, factors: &[f64], switch: bool) -> String {
    let plastic = "const plastic = material(#{ name: \"plastic\", model: \"von_mises\", \
                   sigma_y: 12.0, E: 1000.0, nu: 0.3, density: 1.0 });\n";
    let load = format!(
        "{}material_of(#{{ body: \"block\", material: \"plastic\" }});\n\
         traction(#{{ on: [[0.0, 1.0], [1.0, 1.0]], traction: [0.0, -10.0] }});\n",
        if switch { "" } else { "// " }
    );
    common::staged_block(plastic, control, factors, &load)
}

/// `material_of` in the arc-controlled stage: the switch is made at the arc stage's first
/// step. Confined compression (ν = 0.3) reaches the von Mises surface at the base when
/// (1 − 2ν)/(1 − ν) (γH + λ q) = σ_y, λ ≈ 1.1, and the block then goes on hardening
/// structurally (no limit: the arc runs to max_load_factor 3). Checked: every arc step
/// converges with the base reaction W + λ q B to 1e-9; every point's end position is where load
/// control at the arc's load factors, with the same switch, puts the block (to 1e-8); points
/// yielded; the switch changed the answer (the run without it ends elsewhere by more than 1e-4).
#[test]
fn a_material_switched_at_the_start_of_the_arc_stage_runs_as_under_load_control() {
    let text = switched_arc_block("arc_length", &[0.5, 1.0, 1.5, 2.0, 2.5, 3.0], true);
    let (mut sim, dir) = build("arc", &text);
    let steps = 8;
    let mut worst = 0.0f64;
    while sim.steps_done() < steps {
        let record = sim.step().unwrap().clone();
        if record.step <= 2 {
            continue;
        }
        let (lambda, base) = (
            record.load_factor,
            record.measure("fix1_reaction_y").unwrap(),
        );
        let expected = 10.0 + lambda * 10.0;
        println!(
            "arc step {}: λ = {lambda:.6}, base {base:.9} against {expected:.9}, {} iterations",
            record.step, record.iterations
        );
        worst = worst.max((base - expected).abs() / expected);
        if lambda >= 3.0 {
            break;
        }
    }
    assert!(worst < 1e-9, "{worst:e}");
    let factors: Vec<f64> = sim.summary.steps[2..]
        .iter()
        .map(|s| s.load_factor)
        .collect();
    assert!(
        factors.len() >= 3 && factors.last().unwrap() > &1.2,
        "{factors:?}"
    );
    let yielded = states_plastic(&mut sim);
    let arc_end = positions(&mut sim);
    let _ = std::fs::remove_dir_all(dir);

    let mut ends = Vec::new();
    for switch in [true, false] {
        let text = switched_arc_block("load", &factors, switch);
        let (mut load, dir) = build(&format!("arc-load-{switch}"), &text);
        load.run(|_| {}).unwrap();
        ends.push(positions(&mut load));
        let _ = std::fs::remove_dir_all(dir);
    }
    let difference = |a: &[[f64; 2]], b: &[[f64; 2]]| {
        a.iter()
            .zip(b)
            .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
            .fold(0.0f64, f64::max)
    };
    let (same, unswitched) = (
        difference(&arc_end, &ends[0]),
        difference(&arc_end, &ends[1]),
    );
    println!(
        "arc load factors {factors:?}; {yielded} points yielded; end positions against load control with the switch {same:.1e}, without it {unswitched:.1e}; warnings {:?}",
        sim.summary.warnings
    );
    assert!(yielded > 0);
    assert!(same < 1e-8, "{same:e}");
    assert!(unswitched > 1e-4, "{unswitched:e}");
}

/// How many points of the von Mises model carry plastic strain.
fn states_plastic(sim: &mut Simulation<2>) -> usize {
    states(sim).iter().filter(|s| s.1 > 0.0).count()
}

/// Every point's position, in entity order (the same scene spawns the same order).
fn positions(sim: &mut Simulation<2>) -> Vec<[f64; 2]> {
    let mut query = sim.world.query::<&Position<2>>();
    query.iter(&sim.world).map(|x| [x.0[0], x.0[1]]).collect()
}
