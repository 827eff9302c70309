//! Moving-least-squares stress recovery (optional, `stress_recovery(#{ .. })` in scenes).
//!
//! After the point update of every load step ([`recover_stress`], `Hook::AfterStep`) a
//! polynomial is fitted, around every material point, to the converged Cauchy stresses of the
//! points within `radius_in_cells` times the largest cell size, in the current configuration,
//! and its value at the point is kept in [`RecoveredStress`] (kernel and math: `recovery`). The
//! raw point stress is left untouched: the output writes both (`recovered_stress`, at
//! `Hook::PointFields`), and a scene with an analytic column also reports the eq. 15 error of
//! the recovered stress (`error_recovered` in `summary.json`).

use bevy_ecs::prelude::*;
use nalgebra::{Matrix3, SVector};

use crate::components::{PointId, Position, ReferencePosition, ReferenceVolume, Trial};
use crate::plugin::{Extension, Hook, Plugin};
use crate::recovery::{MlsSettings, mls_recover};
use crate::resources::{Grid, LoadStep, RunStatus, SolverError, Stage, StageClock};
use rhai::Dynamic;

use crate::scene::{
    CallSpec, FieldSpec, Kind, Located, OptionSpec, Range, Resolver, SceneApi, SceneSpec,
    ScriptError, ensure_unset,
};
use crate::stages::output::{PointFields, row_major};

/// Stress recovered from the neighbouring points' Cauchy stresses (3x3, as
/// `TrialState::cauchy`).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct RecoveredStress(pub Matrix3<f64>);

/// Settings of the recovery.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct StressRecovery {
    /// Total degree of the fitted polynomial.
    pub order: usize,
    /// Support radius as a multiple of the largest cell size of the grid.
    pub radius_in_cells: f64,
}

/// The scene's stress recovery (`stress_recovery(#{ .. })`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecoverySpec {
    /// Total degree of the fitted polynomial (0, 1, 2, ...).
    pub order: usize,
    /// Support radius as a multiple of the largest cell size.
    pub radius_in_cells: f64,
}

impl Default for RecoverySpec {
    fn default() -> Self {
        Self {
            order: 2,
            radius_in_cells: 2.5,
        }
    }
}

/// The module.
#[derive(Clone, Copy, Debug, Default)]
pub struct StressRecoveryModule;

impl Plugin for StressRecoveryModule {
    fn name(&self) -> &'static str {
        "stress recovery"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::options(
            "stress_recovery",
            "moving-least-squares stress recovery after every step (optional): writes `recovered_stress` beside `cauchy_stress` and reports `error_recovered` with an analytic column; call once",
            vec![
                OptionSpec::new(
                    "order",
                    Kind::Whole {
                        min: 0,
                        max: Some(4),
                    },
                    "total degree of the fitted polynomial (default 2)",
                ),
                OptionSpec::new(
                    "radius",
                    Kind::Number(Range::Positive),
                    "support radius in cell sizes (default 2.5)",
                ),
            ],
            |builder, options, at| {
                let previous = builder.declared::<RecoverySpec>().first().cloned();
                ensure_unset(&previous, "stress_recovery")?;
                let default = RecoverySpec::default();
                builder.declare(Located::new(
                    RecoverySpec {
                        order: options.whole("order").unwrap_or(default.order),
                        radius_in_cells: options.number("radius").unwrap_or(default.radius_in_cells),
                    },
                    at,
                ));
                Ok(Dynamic::UNIT)
            },
        ))
        .word(FieldSpec {
            name: "recovered_stress",
            doc: "the MLS-recovered Cauchy stress (3x3, row-major); with stress_recovery(..)",
        });
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        if let Some(recovery) = scene.declarations::<RecoverySpec>().first().cloned() {
            scene.spec.set_part(recovery.value);
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        spec.part::<RecoverySpec>()
            .map(|r| format!("order {}, radius {} cell sizes", r.order, r.radius_in_cells))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<RecoverySpec>().is_some()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        let settings = spec.part::<RecoverySpec>().copied().unwrap_or_default();
        let analytic = spec.analytic.clone();
        let world = simulation.world();
        world.insert_resource(StressRecovery {
            order: settings.order,
            radius_in_cells: settings.radius_in_cells,
        });
        let points: Vec<Entity> = world
            .query_filtered::<Entity, With<PointId>>()
            .iter(world)
            .collect();
        world.insert_batch(
            points
                .into_iter()
                .map(|entity| (entity, RecoveredStress(Matrix3::zeros()))),
        );
        simulation
            .point_state(
                "stress recovery",
                |_, _| {},
                |point, _, _| {
                    point.insert(RecoveredStress(Matrix3::zeros()));
                    Ok(())
                },
            )
            .add_systems(Hook::AfterStep, recover_stress::<D>)
            .add_systems(Hook::PointFields, recovered_stress_field);
        if let Some(analytic) = analytic {
            simulation.add_measure("error_recovered", move |world, factor| {
                let (column, axis) = analytic.column_at(factor);
                let mut query =
                    world.query::<(&ReferencePosition<D>, &ReferenceVolume, &RecoveredStress)>();
                let points: Vec<(f64, f64, f64)> = query
                    .iter(world)
                    .map(|(x, v, s)| (x.0[axis], v.0, s.0[(axis, axis)]))
                    .collect();
                Some(column.error(points))
            });
        }
    }
}

pub fn recover_stress<const D: usize>(
    settings: Res<StressRecovery>,
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut points: Query<(&Position<D>, &Trial<D>, &mut RecoveredStress)>,
) {
    let _timer = clock.time(Stage::Output);
    let cell = grid.0.axes.iter().fold(0.0f64, |m, a| m.max(a.spacing()));
    let mut positions: Vec<SVector<f64, D>> = Vec::new();
    let mut stresses = Vec::new();
    for (x, trial, _) in points.iter() {
        positions.push(x.0);
        let sigma = trial.0.cauchy();
        stresses.extend(sigma.iter().copied());
    }
    let mut recovered = Vec::new();
    let mls = MlsSettings {
        order: settings.order,
        radius: settings.radius_in_cells * cell,
    };
    if let Err(why) = mls_recover(&positions, &stresses, 9, mls, &mut recovered) {
        status.fail(SolverError::NotFinite {
            stage: "stress recovery",
            what: why,
            step: step.number,
        });
        return;
    }
    // The query iterates in the same order as above (no structural change in between).
    for (k, (_, _, mut out)) in points.iter_mut().enumerate() {
        out.0 = Matrix3::from_column_slice(&recovered[9 * k..9 * k + 9]);
    }
}

/// The output field `recovered_stress` (3x3, row-major).
fn recovered_stress_field(
    mut out: ResMut<PointFields>,
    points: Query<(&PointId, &RecoveredStress)>,
) {
    out.add(
        "recovered_stress",
        points.iter().count(),
        points.iter().map(|(id, s)| (id.0, row_major(&s.0))),
    );
}
