//! Output stage (optional): moving-least-squares stress recovery.
//!
//! Runs after the point update of a load step and before the files are written, only when the
//! scene asks for it (`stress_recovery(#{ .. })`, [`crate::stages::Effects::stress_recovery`]).
//! It fits, around every material point, a polynomial to the converged Cauchy stresses of the
//! points within `radius_in_cells` times the largest cell size, in the current configuration,
//! and stores its value at the point in [`RecoveredStress`] (kernel and math:
//! [`crate::recovery`]). The raw point stress is left untouched: the output writes both, and the
//! summary reports the eq. 15 error of both.

use bevy_ecs::prelude::*;
use nalgebra::{Matrix3, SVector};

use crate::components::{Position, RecoveredStress, Trial};
use crate::recovery::{MlsSettings, mls_recover};
use crate::resources::{Grid, LoadStep, RunStatus, SolverError, Stage, StageClock, StressRecovery};

pub fn recover_stress<const D: usize>(
    settings: Res<StressRecovery>,
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut points: Query<(&Position<D>, &Trial<D>, &mut RecoveredStress)>,
) {
    let _timer = clock.time(Stage::StressRecovery);
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
