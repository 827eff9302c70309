//! Point loads: concentrated forces on material points (paper eq. 9),
//!
//! ```text
//!   f_ext,i += λ Σ_p P_p N_i(x_p),
//! ```
//!
//! for every point p that carries a [`PointLoad`] (`point_load` / `point_load_total` in scenes).
//! The load moves with its point. The output gains the point field `point_load` (λ P, zero on
//! unloaded points).

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::components::{PointId, Support};
use crate::mechanics::spread_force;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{GridFields, LoadStep, Stage, StageClock};
use crate::scene::SceneSpec;
use crate::stages::output::{PointFields, pad};

/// A force on the material point at load factor 1; only points that carry one have it.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct PointLoad<const D: usize>(pub SVector<f64, D>);

/// The module: scheduled when some point carries a non-zero load.
#[derive(Clone, Copy, Debug, Default)]
pub struct PointLoadsModule;

impl Plugin for PointLoadsModule {
    fn name(&self) -> &'static str {
        "point loads"
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.point_loads
            .iter()
            .any(|load| load.force.iter().any(|&c| c != 0.0))
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let entities = simulation.point_entities();
        for load in &simulation.spec().point_loads {
            let Some(&entity) = entities.get(load.point) else {
                simulation.fail(format!(
                    "point load on point {} which does not exist",
                    load.point
                ));
                return;
            };
            if load.force.len() != D {
                simulation.fail(format!(
                    "point load with {} components in {D}D",
                    load.force.len()
                ));
                return;
            }
            let force = SVector::<f64, D>::from_fn(|a, _| load.force[a]);
            simulation
                .world()
                .entity_mut(entity)
                .insert(PointLoad(force));
        }
        simulation
            .add_systems(Hook::Loads, apply_point_loads::<D>)
            .add_systems(Hook::PointFields, point_load_field::<D>);
    }
}

/// f_ext,i += λ P_p N_i(x_p) for every point p that carries a [`PointLoad`].
pub fn apply_point_loads<const D: usize>(
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    points: Query<(&PointLoad<D>, &Support<D>)>,
) {
    let _timer = clock.time(Stage::Loads);
    for (load, support) in points.iter() {
        spread_force(
            &(load.0 * step.factor),
            &support.0,
            &mut fields.external_force,
        );
    }
}

/// The output field `point_load`: λ P on loaded points, zero elsewhere.
fn point_load_field<const D: usize>(
    step: Res<LoadStep>,
    mut out: ResMut<PointFields>,
    all: Query<&PointId>,
    loaded: Query<(&PointId, &PointLoad<D>)>,
) {
    out.add(
        "point_load",
        all.iter().count(),
        loaded
            .iter()
            .map(|(id, load)| (id.0, pad(&(load.0 * step.factor)))),
    );
}
