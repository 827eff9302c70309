//! A custom boundary condition written by a plugin: elastic springs under a body.
//!
//! Demonstrates the plugin API (`impm::plugin`): the plugin gives the material points near the
//! base (reference height below `--base`) a `Spring` component and adds a bevy system at
//! `Hook::AfterAssembly`, which adds the springs' force and stiffness to what the built-in
//! assembly computed, in every Newton iteration:
//!
//! ```text
//!   u_p = u_p^n + Σ_i Δu_i N_i(x_p)         the point's displacement at the iterate
//!   f_int,i += k u_p N_i(x_p)               the spring pulls the point back
//!   K_ij    += k N_i(x_p) N_j(x_p) I        its consistent tangent
//! ```
//!
//! Springs on material points move with the material and need no grid node on the boundary.
//! At equilibrium they carry the whole load: Σ_p k u_p = λ W (the internal force of the stresses
//! sums to zero over the nodes, the basis being a partition of unity). The example prints that
//! balance after the run.
//!
//!   cargo run --release --example spring_support -- examples/spring_column.rhai out/spring
//!
//! Arguments: SCENE OUT_DIR [--set NAME=VALUE]... [--stiffness K] [--base HEIGHT].

use std::path::PathBuf;

use bevy_ecs::prelude::*;
use nalgebra::SMatrix;

use impm::components::{Displacement, Mass, ReferencePosition, Support};
use impm::effects::body_force::BodyForceSpec;
use impm::mechanics::interpolate;
use impm::plugin::{Extension, Hook, Plugin};
use impm::resources::{GridFields, Newton};
use impm::run::Simulation;

/// A linear spring between a material point and its reference position.
#[derive(Component, Clone, Copy)]
struct Spring {
    stiffness: f64,
}

struct SpringSupport {
    stiffness: f64,
    /// Points with a reference height (last coordinate) below this get a spring.
    base: f64,
}

impl Plugin for SpringSupport {
    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let world = simulation.world();
        let base_points: Vec<Entity> = world
            .query::<(Entity, &ReferencePosition<D>)>()
            .iter(world)
            .filter(|(_, x)| x.0[D - 1] < self.base)
            .map(|(entity, _)| entity)
            .collect();
        for entity in base_points {
            world.entity_mut(entity).insert(Spring {
                stiffness: self.stiffness,
            });
        }
        simulation.add_systems(Hook::AfterAssembly, add_springs::<D>);
    }
}

/// Springs into the internal force and the tangent of the current Newton iterate.
fn add_springs<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    points: Query<(&Spring, &Support<D>, &Displacement<D>)>,
) {
    let fields = &mut *fields;
    for (spring, support, converged) in points.iter() {
        let u = converged.0 + interpolate(&support.0, |node| fields.increment[node]);
        for wi in &support.0 {
            fields.internal_force[wi.node] += u * (spring.stiffness * wi.value);
            for wj in &support.0 {
                let block =
                    SMatrix::<f64, D, D>::identity() * (spring.stiffness * wi.value * wj.value);
                newton
                    .matrix
                    .add_block(&fields.dofs[wi.node], &fields.dofs[wj.node], &block);
            }
        }
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
    let usage =
        "usage: spring_support SCENE OUT_DIR [--set NAME=VALUE]... [--stiffness K] [--base HEIGHT]";
    let mut args = std::env::args().skip(1);
    let scene = PathBuf::from(args.next().ok_or(usage)?);
    let out = PathBuf::from(args.next().ok_or(usage)?);
    let (mut overrides, mut stiffness, mut base) = (Vec::new(), 1.0e6, 0.5);
    while let Some(flag) = args.next() {
        let value = args.next().ok_or(usage)?;
        let number = || {
            value
                .parse::<f64>()
                .map_err(|e| format!("{flag} {value}: {e}"))
        };
        match flag.as_str() {
            "--set" => {
                let (name, value) = value.split_once('=').ok_or(usage)?;
                overrides.push((name.to_string(), value.to_string()));
            }
            "--stiffness" => stiffness = number()?,
            "--base" => base = number()?,
            _ => return Err(usage.into()),
        }
    }
    let spec = impm::run::load_scene(&scene, &overrides).map_err(|e| e.to_string())?;
    let plugin = SpringSupport { stiffness, base };
    match spec.dim() {
        1 => run_in::<1>(&spec, &out, &plugin),
        2 => run_in::<2>(&spec, &out, &plugin),
        3 => run_in::<3>(&spec, &out, &plugin),
        d => Err(format!("dimension {d} is not supported")),
    }
}

/// Runs the scene with springs and prints the balance of spring forces and weight.
fn run_in<const D: usize>(
    spec: &impm::scene::SceneSpec,
    out: &std::path::Path,
    plugin: &SpringSupport,
) -> Result<(), String> {
    let mut sim = Simulation::<D>::new(spec, out).map_err(|e| e.to_string())?;
    sim.add_plugin(plugin).map_err(|e| e.to_string())?;
    let springs = sim.world.query::<&Spring>().iter(&sim.world).count();
    if springs == 0 {
        return Err(format!("no material point below --base {}", plugin.base));
    }
    sim.write_initial_state().map_err(|e| e.to_string())?;
    sim.run(|record| {
        eprintln!(
            "step {} (load factor {}): {} iterations",
            record.step, record.load_factor, record.iterations
        )
    })
    .map_err(|e| e.to_string())?;

    let gravity = spec
        .part::<BodyForceSpec>()
        .map(|b| b.0.clone())
        .unwrap_or_default();
    let factor = spec.load_factors.last().copied().unwrap_or(0.0);
    let vertical = D - 1;
    let weight: f64 = sim
        .world
        .query::<&Mass>()
        .iter(&sim.world)
        .map(|m| m.0 * gravity.get(vertical).copied().unwrap_or(0.0) * factor)
        .sum();
    let (spring_force, settlement) = sim
        .world
        .query::<(&Spring, &Displacement<D>)>()
        .iter(&sim.world)
        .fold((0.0, 0.0f64), |(force, lowest), (spring, u)| {
            (
                force - spring.stiffness * u.0[vertical],
                lowest.min(u.0[vertical]),
            )
        });
    println!(
        "springs: {springs} points, stiffness {} each",
        plugin.stiffness
    );
    println!("base settlement: {settlement:.6e}");
    println!("spring force {:.6e}, weight {:.6e}", spring_force, -weight);
    println!("spring force / weight = {:.9}", spring_force / -weight);
    Ok(())
}
