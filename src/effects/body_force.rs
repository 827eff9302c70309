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

use crate::components::{Mass, Support};
use crate::mechanics::spread_force;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{GridFields, LoadStep, Stage, StageClock};
use crate::scene::SceneSpec;

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

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.body_force
            .as_ref()
            .is_some_and(|b| b.iter().any(|&c| c != 0.0))
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        if let Some(b) = &simulation.spec().body_force {
            if b.len() != D {
                simulation.fail(format!("body force has {} components in {D}D", b.len()));
                return;
            }
            let force = SVector::<f64, D>::from_fn(|a, _| b[a]);
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
