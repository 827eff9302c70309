//! Newton stages 3 and 4: the convergence check and the linear solve. The loop that runs them,
//! `method::solve_load_step`, repeats the Newton schedule until the convergence criterion
//! (`control::ConvergenceCriterion`; by default the normalised out-of-balance force
//!
//! ```text
//!   ‖f_ext − f_int‖_free · min(|λ|, 1) / max(‖f_ext‖, ‖f_int‖)   (norms over all active components)
//! ```
//!
//! relative to the load scale, so that tiny load increments converge; see
//! `control::NormalisedResidual`
//!
//! ) falls below the tolerance, or fails after `max_iterations` linear solves. The solve is the
//! linear-solver layer's (`solver`), told whether the tangent is symmetric. The first residual
//! of a step is the load increment; the residual history is kept for the summary.

use bevy_ecs::prelude::*;

use crate::control::ResidualNorms;
use crate::resources::{
    Convergence, GridFields, LoadStep, Newton, NewtonSettings, RunStatus, SolverError, Stage,
    StageClock,
};
use crate::solver::NO_DOF;

/// Growth of the out-of-balance force over the step's first residual (or over 1, if smaller)
/// that is taken as divergence.
pub const DIVERGENCE_GROWTH: f64 = 1e6;

/// Newton stage 3: out-of-balance force at the free DOFs and the convergence test (by the
/// criterion in [`Convergence`]).
pub fn check_convergence<const D: usize>(
    fields: Res<GridFields<D>>,
    settings: Res<NewtonSettings>,
    criterion: Res<Convergence>,
    step: Res<LoadStep>,
    mut newton: ResMut<Newton>,
    mut status: ResMut<RunStatus>,
) {
    let newton = &mut *newton;
    let (mut free, mut external, mut internal) = (0.0, 0.0, 0.0);
    for (node, dofs) in fields.dofs.iter().enumerate() {
        if !fields.active[node] {
            continue;
        }
        let (fe, fi) = (fields.external_force[node], fields.internal_force[node]);
        external += fe.norm_squared();
        internal += fi.norm_squared();
        for (c, &dof) in dofs.iter().enumerate() {
            if dof != NO_DOF {
                let r = fe[c] - fi[c];
                newton.residual[dof as usize] = r;
                free += r * r;
            }
        }
    }
    let norm = criterion.0.measure(&ResidualNorms {
        free: free.sqrt(),
        external: external.sqrt(),
        internal: internal.sqrt(),
        load_factor: step.factor,
    });
    newton.residuals.push(norm);
    if !norm.is_finite() {
        status.fail(SolverError::NotFinite {
            stage: "convergence check",
            what: format!("out-of-balance force norm {norm}"),
            step: step.number,
        });
        return;
    }
    let (earlier, _) = newton.residuals.split_at(newton.residuals.len() - 1);
    newton.converged = criterion.0.converged(norm, earlier, settings.tolerance);
    // Diverging: the residual has grown by orders of magnitude over the step's first one.
    let first = newton.residuals[0].max(1.0);
    if !newton.converged && newton.residuals.len() > 2 && norm > DIVERGENCE_GROWTH * first {
        status.fail(SolverError::Diverged {
            step: step.number,
            residuals: newton.residuals.clone(),
        });
    }
}

/// Newton stage 4: solve K δ = f_ext − f_int and add δ to the free components of Δu.
pub fn solve_linear_system<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    step: Res<LoadStep>,
    mut newton: ResMut<Newton>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
) {
    let _timer = clock.time(Stage::LinearSolve);
    let newton = &mut *newton;
    newton.iterations += 1;
    match newton
        .solver
        .solve(&newton.matrix, newton.symmetric, &mut newton.residual)
    {
        Ok(kind) => newton.last_solver = kind,
        Err(why) => {
            status.fail(SolverError::LinearSolve {
                step: step.number,
                iteration: newton.iterations,
                why: why.to_string(),
            });
            return;
        }
    }
    let fields = &mut *fields;
    for (node, dofs) in fields.dofs.iter().enumerate() {
        for (c, &dof) in dofs.iter().enumerate() {
            if dof != NO_DOF {
                let delta = newton.residual[dof as usize];
                if !delta.is_finite() {
                    status.fail(SolverError::NotFinite {
                        stage: "linear solve",
                        what: format!("displacement correction of node {node}, component {c}"),
                        step: step.number,
                    });
                    return;
                }
                fields.increment[node][c] += delta;
            }
        }
    }
}
