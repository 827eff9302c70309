//! Body force: the volume term of the external force (paper eq. 9),
//!
//! ```text
//!   f_ext,i += λ Σ_p m_p b N_i(x_p),
//! ```
//!
//! with b the body force per unit mass at load factor 1 (`body_force([..])` in scenes). The basis
//! values of a point sum to one (partition of unity), so the resultant is exactly λ b Σ_p m_p.

use bevy_ecs::prelude::*;
use nalgebra::SVector;
use rhai::Dynamic;

use super::declarations::LoadSummary;
use crate::components::{Mass, Support};
use crate::mechanics::spread_force;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{GridFields, LoadStep, Stage, StageClock};
use crate::scene::{CallSpec, Located, Resolver, SceneApi, SceneSpec, ScriptError, numbers};

/// The scene's body force per unit mass at load factor 1 (one entry per axis).
#[derive(Clone, Debug, PartialEq)]
pub struct BodyForceSpec(pub Vec<f64>);

/// Where the scene declared its body force (for `impm check`).
#[derive(Clone, Debug, PartialEq)]
struct BodyForceLine(Option<usize>);

/// Body force per unit mass at load factor 1.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct BodyForce<const D: usize>(pub SVector<f64, D>);

/// The module: scheduled when the scene's body force is not zero.
#[derive(Clone, Copy, Debug, Default)]
pub struct BodyForceModule;

impl Plugin for BodyForceModule {
    fn name(&self) -> &'static str {
        "body force"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::args(
            "body_force",
            "body_force([b0, ..])",
            "body force per unit mass at load factor 1, one entry per axis (call once)",
            1,
            |builder, args, at| {
                if let Some(previous) = builder.declared::<BodyForceSpec>().first() {
                    return Err(format!(
                        "body_force(...) was already called{}; call it once",
                        previous.line_note()
                    ));
                }
                let force = numbers(&args[0], "body_force(...): the force per unit mass")?;
                if force.is_empty() {
                    return Err("body_force(...) needs one component per axis, got []".to_string());
                }
                builder.declare(Located::new(BodyForceSpec(force), at));
                Ok(Dynamic::UNIT)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let Some(declared) = scene.declarations::<BodyForceSpec>().first().cloned() else {
            return Ok(());
        };
        if declared.value.0.len() != scene.spec.dim() {
            return Err(ScriptError::at(
                declared.at,
                format!(
                    "body_force(...) has {} components but {}",
                    declared.value.0.len(),
                    scene.grid_note()
                ),
            ));
        }
        scene.spec.set_part(declared.value);
        scene.spec.set_part(BodyForceLine(declared.at.line()));
        Ok(())
    }

    /// The force per unit mass, and the declaration with its total force b Σ ρ₀ V_p over every
    /// material point.
    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let b = spec.part::<BodyForceSpec>()?;
        let mass: f64 = spec
            .bodies
            .iter()
            .map(|body| {
                let density = spec.materials.get(body.material).map_or(0.0, |m| m.density);
                density * body.points.iter().map(|p| p.volume).sum::<f64>()
            })
            .sum();
        let summary = LoadSummary::new(
            spec.part::<BodyForceLine>().and_then(|l| l.0),
            "body_force",
            "material points (all)",
            spec.bodies
                .iter()
                .flat_map(|body| &body.points)
                .map(|p| &p.position[..]),
            b.0.iter().map(|c| c * mass).collect(),
        );
        Some(format!(
            "{:?} per unit mass at load factor 1\n    {}",
            b.0,
            summary.describe()
        ))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<BodyForceSpec>()
            .is_some_and(|b| b.0.iter().any(|&c| c != 0.0))
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        if let Some(b) = simulation.spec().part::<BodyForceSpec>() {
            if b.0.len() != D {
                simulation.fail(format!("body force has {} components in {D}D", b.0.len()));
                return;
            }
            let force = SVector::<f64, D>::from_fn(|a, _| b.0[a]);
            simulation.world().insert_resource(BodyForce(force));
        }
        simulation.add_systems(Hook::Loads, apply_body_force::<D>);
    }
}

pub fn apply_body_force<const D: usize>(
    body_force: Res<BodyForce<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    points: Query<(&Mass, &Support<D>)>,
) {
    let _timer = clock.time(Stage::Loads);
    let acceleration = body_force.0 * step.factor;
    for (mass, support) in points.iter() {
        spread_force(
            &(acceleration * mass.0),
            &support.0,
            &mut fields.external_force,
        );
    }
}
