//! Newton stage 1: the trial state of every point for the current displacement increment:
//! Δf = I + Σ Δu_i ⊗ ∇_n N_i, F = Δf F^n, and the Hencky stress and tangent (`mechanics`).

use bevy_ecs::prelude::*;

use crate::components::{DeformationGradient, Elastic, PointId, Support, Trial};
use crate::mechanics::{increment_gradient, trial_state};
use crate::resources::{GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock};

pub fn update_stress<const D: usize>(
    fields: Res<GridFields<D>>,
    step: Res<LoadStep>,
    newton: Res<Newton>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut points: Query<(
        &PointId,
        &Support<D>,
        &DeformationGradient<D>,
        &Elastic,
        &mut Trial<D>,
    )>,
) {
    let _timer = clock.time(Stage::StressUpdate);
    for (id, support, f, material, mut trial) in points.iter_mut() {
        let df = increment_gradient(&support.0, |node| fields.increment[node]);
        match trial_state(&material.0, &f.0, &df) {
            Ok(state) => trial.0 = state,
            Err(why) => {
                status.fail(SolverError::BadPointState {
                    point: id.0,
                    step: step.number,
                    iteration: newton.iterations,
                    why: why.to_string(),
                });
                return;
            }
        }
    }
}
