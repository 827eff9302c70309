//! Stage 1: basis evaluation and P2G connectivity.
//!
//! At the start of a load step the grid coincides with the points' configuration: every point
//! evaluates the basis functions N_i(x_p) and their gradients at its current position and keeps
//! them for the whole step (`Support`). A node is active when some point's support contains it.
//!
//! Two systems, one per kind of basis, so that the point bases (linear, B-spline) keep their
//! lean query: [`evaluate_basis`] evaluates `N_i(x_p)`; [`evaluate_domain_basis`] (GIMP, CPDI,
//! B-splines with `integration: "domain"`) averages the grid functions over the point's domain
//! at the start of the step, built from its `ParticleDomain` and converged
//! `DeformationGradient` (`basis::domain`).

use bevy_ecs::prelude::*;

use crate::basis::{BasisScratch, DomainError, DomainScratch, eval_point_domain};
use crate::components::{DeformationGradient, ParticleDomain, PointId, Position, Support};
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

pub fn evaluate_domain_basis<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<DomainScratch<D>>,
    mut points: Query<(
        &PointId,
        &Position<D>,
        &DeformationGradient<D>,
        &ParticleDomain<D>,
        &mut Support<D>,
    )>,
) {
    let _timer = clock.time(Stage::Connectivity);
    for (id, position, f, domain, mut support) in points.iter_mut() {
        let evaluated = eval_point_domain(
            &grid.0,
            &position.0,
            &f.0,
            &domain.initial_half_lengths,
            &mut scratch,
            &mut support.0,
        );
        if let Err(error) = evaluated {
            status.fail(match error {
                DomainError::Outside(_) => SolverError::PointOutsideGrid {
                    point: id.0,
                    position: position.0.iter().copied().collect(),
                    step: step.number,
                },
                other => SolverError::PointDomain {
                    point: id.0,
                    step: step.number,
                    why: other.to_string(),
                },
            });
            return;
        }
        for w in &support.0 {
            fields.active[w.node] = true;
        }
    }
}
