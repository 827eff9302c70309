//! Stage 5: G2P update of the material points after convergence (paper eq. 10):
//! x_p += Σ Δu_i N_i(x_p), u_p += Σ Δu_i N_i(x_p), F_p = Δf F_p, V_p = J V0_p.

use bevy_ecs::prelude::*;

use crate::components::{
    DeformationGradient, Displacement, PointId, Position, ReferenceVolume, Support, Trial, Volume,
};
use crate::mechanics::interpolate;
use crate::resources::{GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};

#[allow(clippy::type_complexity)]
pub fn update_points<const D: usize>(
    fields: Res<GridFields<D>>,
    step: Res<LoadStep>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut points: Query<(
        &PointId,
        &Support<D>,
        &Trial<D>,
        &ReferenceVolume,
        &mut Position<D>,
        &mut Displacement<D>,
        &mut DeformationGradient<D>,
        &mut Volume,
    )>,
) {
    let _timer = clock.time(Stage::UpdatePoints);
    for (id, support, trial, v0, mut x, mut u, mut f, mut v) in points.iter_mut() {
        let du = interpolate(&support.0, |node| fields.increment[node]);
        if du.iter().any(|c| !c.is_finite()) {
            status.fail(SolverError::NotFinite {
                stage: "point update",
                what: format!("displacement increment of point {}", id.0),
                step: step.number,
            });
            return;
        }
        x.0 += du;
        u.0 += du;
        f.0 = trial.0.deformation_gradient;
        v.0 = trial.0.jacobian * v0.0;
    }
}
