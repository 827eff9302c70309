//! A user-defined material plugged in without editing the crate: a compressible neo-Hookean
//! solid (`neo_hookean.rs`), registered as a module beside the built-in ones and used from a
//! scene by its word (`material(#{ model: "neo_hookean", E: .., nu: .., density: .. })`).
//!
//! Recipe (what this file does):
//! 1. implement `impm::material::Material` for your model (`neo_hookean.rs`);
//! 2. `let modules = impm::effects::built_in().with(MaterialModule::<NeoHookean>::default());`
//! 3. `modules.load_scene(..)` reads scenes that name your model;
//! 4. `run_scene_with_modules(&spec, out, &modules, ..)` runs them.
//!
//! The scene `examples/custom_material/neo_hookean_column.rhai` is the paper's self-weight column in the new
//! material; its stress is statically determinate and its settlement follows from the model
//! (scene header). The example runs it at the scene's resolution and at twice as many cells,
//! prints the paper's error measure (eq. 15) and the error of the top displacement, and fails
//! (exit 1) unless both are below 2e-3 at either resolution and do not grow with refinement.
//!
//!   cargo run --release --example custom_material -- examples/custom_material/neo_hookean_column.rhai out/neo_hookean
//!
//! Arguments: SCENE OUT_DIR [--set NAME=VALUE]...

mod neo_hookean;

use std::path::{Path, PathBuf};

use impm::analytic::SelfWeightColumn;
use impm::effects::body_force::BodyForceSpec;
use impm::effects::{self, materials::MaterialModule};
use impm::output::read_vtu;
use impm::plugin::ModuleSet;
use impm::run::run_scene_with_modules;
use impm::scene::SceneSpec;
use neo_hookean::NeoHookean;

/// The largest error (eq. 15, and the top displacement relative to its exact value) accepted.
const TOLERANCE: f64 = 2e-3;

fn main() -> std::process::ExitCode {
    match run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    let usage = "usage: custom_material SCENE OUT_DIR [--set NAME=VALUE]...";
    let mut args = std::env::args().skip(1);
    let scene = PathBuf::from(args.next().ok_or(usage)?);
    let out = PathBuf::from(args.next().ok_or(usage)?);
    let mut overrides = Vec::new();
    while let Some(flag) = args.next() {
        let value = args.next().ok_or(usage)?;
        let (name, value) = match flag.as_str() {
            "--set" => value.split_once('=').ok_or(usage)?,
            _ => return Err(usage.into()),
        };
        overrides.push((name.to_string(), value.to_string()));
    }
    let modules = effects::built_in().with(MaterialModule::<NeoHookean>::default());
    let base = modules
        .load_scene(&scene, &overrides)
        .map_err(|e| e.to_string())?;
    let cells = base.grid.cells[0];
    let mut errors = Vec::new();
    for resolution in [cells, 2 * cells] {
        let mut set = overrides.clone();
        set.retain(|(name, _)| name != "cells");
        set.push(("cells".to_string(), resolution.to_string()));
        let spec = modules
            .load_scene(&scene, &set)
            .map_err(|e| e.to_string())?;
        let dir = out.join(format!("cells_{resolution}"));
        let (stress, top) = run_and_check(&spec, &dir, &modules)?;
        println!("{resolution} cells: eq. 15 error {stress:.3e}, top displacement error {top:.3e}");
        errors.push((stress, top));
    }
    let (coarse, fine) = (errors[0], errors[1]);
    let within = |(stress, top): (f64, f64)| stress < TOLERANCE && top < TOLERANCE;
    if !(within(coarse) && within(fine) && fine.0 <= coarse.0 && fine.1 <= coarse.1) {
        return Err(format!(
            "the neo-Hookean column is off its answer: {errors:?} (tolerance {TOLERANCE:e}, errors must not grow with refinement)"
        ));
    }
    println!("the neo-Hookean column matches its semi-analytic answer");
    Ok(())
}

/// Runs the column; the eq. 15 error of the final stresses and the relative error of the top
/// point's displacement.
fn run_and_check(spec: &SceneSpec, dir: &Path, modules: &ModuleSet) -> Result<(f64, f64), String> {
    let summary = run_scene_with_modules(spec, dir, modules, |_| {}).map_err(|e| e.to_string())?;
    let material = &spec.materials[0];
    let model = NeoHookean::new(
        material.parameters.number("E")?,
        material.parameters.number("nu")?,
    );
    let gravity = spec
        .part::<BodyForceSpec>()
        .ok_or("the scene has no body force")?
        .0[0]
        * spec.load_factors.last().copied().unwrap_or(0.0);
    let height = spec.grid.upper[0];
    // the stress is statically determinate: the paper's column gives it (its modulus is not used)
    let column = SelfWeightColumn {
        density: material.density,
        body_force: gravity,
        height,
        modulus: material.stiffness,
    };
    let file = dir.join(format!("particles_{:04}.vtu", summary.steps.len()));
    let contents = read_vtu(&file).map_err(|e| format!("{}: {e}", file.display()))?;
    let field = |name: &str| {
        contents
            .point_field(name)
            .map(|(_, values)| values)
            .ok_or(format!("{}: no {name}", file.display()))
    };
    let (stress, reference, volume, displacement) = (
        field("cauchy_stress")?,
        field("reference_position")?,
        field("reference_volume")?,
        field("displacement")?,
    );
    let points = (0..volume.len()).map(|p| (reference[3 * p], volume[p], stress[9 * p]));
    let stress_error = column.error(points);
    let top = (0..volume.len())
        .max_by(|&a, &b| reference[3 * a].total_cmp(&reference[3 * b]))
        .ok_or("no points")?;
    let exact = settlement(&model, &column, reference[3 * top]);
    let top_error = (displacement[3 * top] - exact).abs() / exact.abs();
    Ok((stress_error, top_error))
}

/// u(X) = ∫_0^X (F(s) − 1) ds with F solving the model's uniaxial σ(F) = σ_A(s), by Simpson's
/// rule on 2000 intervals.
fn settlement(model: &NeoHookean, column: &SelfWeightColumn, x: f64) -> f64 {
    let n = 2000;
    let h = x / n as f64;
    let integrand = |s: f64| solve_stretch(model, column.stress(s)) - 1.0;
    let sum: f64 = (0..=n)
        .map(|i| {
            let weight = if i == 0 || i == n {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            weight * integrand(i as f64 * h)
        })
        .sum();
    sum * h / 3.0
}

/// F with (μ (F² − 1) + λ ln F) / F = σ, by Newton's method from F = 1.
fn solve_stretch(model: &NeoHookean, sigma: f64) -> f64 {
    let mut f = 1.0;
    for _ in 0..100 {
        let residual = model.uniaxial_cauchy(f) - sigma;
        let h = 1e-7 * f;
        let slope = (model.uniaxial_cauchy(f + h) - model.uniaxial_cauchy(f - h)) / (2.0 * h);
        let step = residual / slope;
        f -= step;
        if step.abs() < 1e-15 * f {
            break;
        }
    }
    f
}
