//! A custom output written by a plugin: a CSV of the vertical stress along a vertical line of
//! material points, at every output step.
//!
//! Demonstrates the plugin API (`impm::plugin`): a `Plugin` adds a bevy system at
//! `Hook::Output`, which runs after the built-in VTK files of every output step (the initial
//! state included), sees the whole world, and writes `profile_NNNN.csv` next to them. The crate
//! is not edited.
//!
//!   cargo run --release --example csv_profile -- scripts/column_2d.rhai out/profile --set cells=20
//!
//! Arguments: SCENE OUT_DIR [--set NAME=VALUE]... [--at X[,Z]]. The line is the vertical (the
//! last axis) through the horizontal reference coordinates X (and Z in 3D); by default those of
//! the first material point. Each CSV has the columns `reference_height,height,sigma_vv` (the
//! Cauchy stress along the vertical), one row per point on the line, sorted by height.

use std::io::Write;
use std::path::PathBuf;

use bevy_ecs::prelude::*;

use impm::components::{PointId, Position, ReferencePosition, Trial};
use impm::plugin::{Extension, Hook, Plugin};
use impm::resources::{LoadStep, RunStatus, SolverError};
use impm::run::run_scene_with;
use impm::stages::output::OutputPlan;

/// The line: horizontal reference coordinates (all axes but the last).
#[derive(Resource, Clone)]
struct ProfileLine(Option<Vec<f64>>);

struct CsvProfile {
    at: Option<Vec<f64>>,
}

impl Plugin for CsvProfile {
    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        simulation
            .world()
            .insert_resource(ProfileLine(self.at.clone()));
        simulation.add_systems(Hook::Output, write_profile::<D>);
    }
}

/// The output system: points on the line, sorted by reference height, to `profile_NNNN.csv`.
fn write_profile<const D: usize>(
    step: Res<LoadStep>,
    plan: Res<OutputPlan>,
    line: Res<ProfileLine>,
    mut status: ResMut<RunStatus>,
    points: Query<(&PointId, &ReferencePosition<D>, &Position<D>, &Trial<D>)>,
) {
    if !plan.writes(&step) {
        return;
    }
    let vertical = D - 1;
    let at: Vec<f64> = match &line.0 {
        Some(at) => at.clone(),
        None => points
            .iter()
            .min_by_key(|(id, ..)| id.0)
            .map(|(_, x, ..)| x.0.iter().take(vertical).copied().collect())
            .unwrap_or_default(),
    };
    let mut rows: Vec<(f64, f64, f64)> = points
        .iter()
        .filter(|(_, x, ..)| (0..vertical).all(|a| (x.0[a] - at[a]).abs() < 1e-9))
        .map(|(_, x, position, trial)| {
            let sigma = trial.0.cauchy()[(vertical, vertical)];
            (x.0[vertical], position.0[vertical], sigma)
        })
        .collect();
    rows.sort_by(|a, b| a.0.total_cmp(&b.0));
    let path = plan.dir.join(format!("profile_{:04}.csv", step.number));
    let mut text = String::from("reference_height,height,sigma_vv\n");
    for (reference, height, sigma) in &rows {
        text.push_str(&format!("{reference},{height},{sigma}\n"));
    }
    if let Err(e) = std::fs::write(&path, text) {
        status.fail(SolverError::Output {
            step: step.number,
            why: format!("{}: {e}", path.display()),
        });
    }
}

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
    let usage = "usage: csv_profile SCENE OUT_DIR [--set NAME=VALUE]... [--at X[,Z]]";
    let mut args = std::env::args().skip(1);
    let scene = PathBuf::from(args.next().ok_or(usage)?);
    let out = PathBuf::from(args.next().ok_or(usage)?);
    let (mut overrides, mut at) = (Vec::new(), None);
    while let Some(flag) = args.next() {
        let value = args.next().ok_or(usage)?;
        match flag.as_str() {
            "--set" => {
                let (name, value) = value.split_once('=').ok_or(usage)?;
                overrides.push((name.to_string(), value.to_string()));
            }
            "--at" => {
                let coordinates = value
                    .split(',')
                    .map(|c| {
                        c.trim()
                            .parse::<f64>()
                            .map_err(|e| format!("--at {value}: {e}"))
                    })
                    .collect::<Result<Vec<_>, _>>()?;
                at = Some(coordinates);
            }
            _ => return Err(usage.into()),
        }
    }
    let spec = impm::run::load_scene(&scene, &overrides).map_err(|e| e.to_string())?;
    if let Some(at) = &at
        && at.len() + 1 != spec.dim()
    {
        return Err(format!(
            "--at needs {} coordinate(s) in {}D",
            spec.dim() - 1,
            spec.dim()
        ));
    }
    let summary = run_scene_with(&spec, &out, &CsvProfile { at }, |record| {
        eprintln!("step {} (load factor {})", record.step, record.load_factor);
    })
    .map_err(|e| e.to_string())?;
    let mut stdout = std::io::stdout();
    let _ = writeln!(
        stdout,
        "wrote {} profiles to {}/profile_NNNN.csv",
        summary.steps.len() + 1,
        out.display()
    );
    Ok(())
}
