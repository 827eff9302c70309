//! Stage 1: basis evaluation and P2G connectivity.
//!
//! At the start of a load step the grid coincides with the points' configuration: every point
//! evaluates the basis functions N_i(x_p) and their gradients at its current position and keeps
//! them for the whole step (`Support`). A node is active when some point's support contains it.
//!
//! The points are evaluated on all threads (`parallel`), each thread with its own scratch.
//!
//! [`evaluate_basis`] is the core's default at `Hook::Basis` (linear and B-spline MPM); the
//! methods that weight a point differently provide their own system there (GIMP, CPDI and
//! domain-averaged B-splines: `effects::point_domains`; linear FEM: `effects::fem_mesh`).

use bevy_ecs::prelude::*;

use crate::basis::BasisScratch;
use crate::components::{PointId, Position, Support};
use crate::parallel;
use crate::resources::{Grid, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};

pub fn evaluate_basis<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut points: Query<(&PointId, &Position<D>, &mut Support<D>)>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let mut points: Vec<_> = points.iter_mut().collect();
    // One part per thread (`parallel`), each with its scratch and its first point outside.
    let mut parts: Vec<(BasisScratch, Option<u32>)> = std::iter::repeat_with(Default::default)
        .take(parallel::part_count(points.len()))
        .collect();
    parallel::for_each_part(&mut points, &mut parts, |_, part, (scratch, outside)| {
        for (id, position, support) in part.iter_mut() {
            if grid.0.eval(&position.0, scratch, &mut support.0).is_err() {
                *outside = Some(id.0);
                return;
            }
        }
    });
    if let Some(point) = parts.iter().find_map(|(_, outside)| *outside) {
        let position = points
            .iter()
            .find(|(id, ..)| id.0 == point)
            .map(|(_, position, _)| position.0.iter().copied().collect())
            .unwrap_or_default();
        status.fail(SolverError::PointOutsideGrid {
            point,
            position,
            step: step.number,
        });
        return;
    }
    for (_, _, support) in &points {
        for w in &support.0 {
            fields.active[w.node] = true;
        }
    }
}
