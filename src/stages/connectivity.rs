//! Stage 1: basis evaluation and P2G connectivity.
//!
//! At the start of a load step the grid coincides with the points' configuration: every point
//! evaluates the basis functions N_i(x_p) and their gradients at its current position and keeps
//! them for the whole step (`Support`). A node is active when some point's support contains it.
//!
//! [`evaluate_basis`] is the core's default at `Hook::Basis` (linear and B-spline MPM); the
//! methods that weight a point differently provide their own system there (GIMP, CPDI and
//! domain-averaged B-splines: `effects::point_domains`; linear FEM: `effects::fem_mesh`).

use bevy_ecs::prelude::*;

use crate::basis::BasisScratch;
use crate::components::{PointId, Position, Support};
use crate::resources::{Grid, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};

pub fn evaluate_basis<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<BasisScratch>,
    mut points: Query<(&PointId, &Position<D>, &mut Support<D>)>,
) {
    let _timer = clock.time(Stage::Connectivity);
    for (id, position, mut support) in points.iter_mut() {
        if grid
            .0
            .eval(&position.0, &mut scratch, &mut support.0)
            .is_err()
        {
            status.fail(SolverError::PointOutsideGrid {
                point: id.0,
                position: position.0.iter().copied().collect(),
                step: step.number,
            });
            return;
        }
        for w in &support.0 {
            fields.active[w.node] = true;
        }
    }
}
