//! Newton stages 3 and 4: the convergence check and the linear solve. The loop that runs them,
//! `method::solve_load_step`, repeats the Newton schedule until the convergence criterion
//! (`control::ConvergenceCriterion`; by default the normalised out-of-balance force
//!
//! ```text
//!   ‖f_ext − f_int‖_free · min(|λ|, 1) / max(‖f_ext‖, ‖f_int‖)   (norms over all active components)
//! ```
//!
//! relative to the load scale, so that tiny load increments converge; in a scene that
//! releases a load, with the run's largest converged force as the scale's floor, kept here in
//! `resources::LargestForce`; see `control::NormalisedResidual`
//!
//! ) falls below the tolerance, or fails after `max_iterations` linear solves. The solve is the
//! linear-solver layer's (`solver`), told whether the tangent is symmetric; with
//! `solver(#{ inexact: true })` an iterative solve stops at the Eisenstat–Walker forcing term
//! (`solver::EisenstatWalker`). The first residual of a step is the load increment; the
//! residual history and the Krylov iterations of each solve are kept for the summary.

use bevy_ecs::prelude::*;

use crate::basis::GridBasis;
use crate::components::{BodyIndex, Support};
use crate::control::ResidualNorms;
use crate::resources::{BodyNames, Grid, LargestForce};
use crate::resources::{
    Convergence, GridFields, LoadStep, Newton, NewtonSettings, RunStatus, SolverError, Stage,
    StageClock, Warnings,
};
use crate::solver::EisenstatWalker;
use crate::solver::modes::{is_zero_energy, rigid_modes, span_has_zero_energy};
use crate::solver::{NO_DOF, SparseMatrix};

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
    largest: Option<ResMut<LargestForce>>,
) {
    let newton = &mut *newton;
    let (mut free, mut external, mut internal) = (0.0, 0.0, 0.0);
    let shared = newton.shared_grid.as_deref();
    for (node, dofs) in fields.dofs.written() {
        if !fields.active[node] {
            continue;
        }
        let counts = shared.is_none_or(|s| s.owned(node));
        let (fe, fi) = (fields.external_force[node], fields.internal_force[node]);
        if counts {
            external += fe.norm_squared();
            internal += fi.norm_squared();
        }
        for (c, &dof) in dofs.iter().enumerate() {
            if dof != NO_DOF {
                let r = fe[c] - fi[c];
                newton.residual[dof as usize] = r;
                if counts {
                    free += r * r;
                }
            }
        }
    }
    // a grid split among processes: the squares summed over them
    if let Some(shared) = shared {
        let sums = shared.sum(&[free, external, internal]).and_then(|sums| {
            <[f64; 3]>::try_from(sums).map_err(|s| format!("{} sums of 3 norms", s.len()))
        });
        match sums {
            Ok(sums) => [free, external, internal] = sums,
            Err(why) => {
                status.fail(SolverError::Module {
                    step: step.number,
                    what: format!("summing the convergence norms over the processes: {why}"),
                    recoverable: false,
                });
                return;
            }
        }
    }
    let (external, internal) = (external.sqrt(), internal.sqrt());
    let norm = criterion.0.measure(&ResidualNorms {
        free: free.sqrt(),
        external,
        internal,
        load_factor: step.factor,
        largest: largest.as_ref().map_or(0.0, |l| l.0),
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
    if let Some(mut largest) = largest.filter(|_| newton.converged) {
        largest.0 = largest.0.max(external.max(internal));
    }
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
/// What the solver changed on its own (`LinearSolver::take_notice`: PETSc's fallback from its
/// failed default) becomes a run warning.
///
/// Before the run's first solve (at zero stress, where rigid rotations cost no energy either)
/// and after a failed solve, the bodies are checked for rigid motions the tangent does not
/// resist ([`crate::solver::modes`]): a body that nothing holds is reported as such at once,
/// whatever module holds the others, instead of as a singular tangent after every step cut.
/// (Not in a distributed run: there the check would need all of K, which no process holds,
/// `Newton::whole_tangent`.)
#[allow(clippy::too_many_arguments)]
pub fn solve_linear_system<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    step: Res<LoadStep>,
    mut newton: ResMut<Newton>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    points: Query<(&BodyIndex, &Support<D>)>,
    grid: Res<Grid<D>>,
    names: Option<Res<BodyNames>>,
    settings: Res<NewtonSettings>,
    mut warnings: ResMut<Warnings>,
) {
    let _timer = clock.time(Stage::LinearSolve);
    let newton = &mut *newton;
    let first_solve = step.number == 1 && step.previous_factor == 0.0 && newton.iterations == 0;
    let whole_tangent = newton.whole_tangent;
    let not_held = |rotations: bool| {
        if !whole_tangent {
            return None;
        }
        let names = names.as_ref().map_or(&[][..], |n| &n.0[..]);
        body_not_held(&points, &grid.0, &fields, &newton.matrix, names, rotations)
    };
    if first_solve && let Some((body, modes)) = not_held(true) {
        status.fail(SolverError::NotHeld {
            step: step.number,
            body,
            modes,
        });
        return;
    }
    newton.iterations += 1;
    if settings.inexact
        && let Some(eta_min) = newton.solver.tolerance()
    {
        let eta = EisenstatWalker::default().forcing_term(
            &newton.residuals,
            newton.forcing,
            settings.tolerance,
            eta_min,
        );
        newton.forcing = Some(eta);
        newton.solver.request_tolerance(eta);
    }
    let solved = newton
        .solver
        .solve(&newton.matrix, newton.symmetric, &mut newton.residual);
    if let Some(notice) = newton.solver.take_notice() {
        warnings
            .0
            .push(format!("load step {}: {notice}", step.number));
    }
    match solved {
        Ok(kind) => {
            newton.last_solver = kind;
            if let Some(iterations) = newton.solver.last_iterations() {
                newton.linear_iterations.push(iterations);
            }
        }
        Err(why) => {
            status.fail(match not_held(false) {
                Some((body, modes)) => SolverError::NotHeld {
                    step: step.number,
                    body,
                    modes,
                },
                None => SolverError::LinearSolve {
                    step: step.number,
                    iteration: newton.iterations,
                    why: why.to_string(),
                },
            });
            return;
        }
    }
    let fields = &mut *fields;
    for (node, dofs) in fields.dofs.written() {
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

/// The first body (or, if none alone, all of them together) whose rigid motions include a
/// zero-energy mode of the tangent: `("body 'name' is", modes)`.
fn body_not_held<const D: usize>(
    points: &Query<(&BodyIndex, &Support<D>)>,
    grid: &GridBasis<D>,
    fields: &GridFields<D>,
    matrix: &SparseMatrix,
    names: &[String],
    rotations: bool,
) -> Option<(String, Vec<String>)> {
    if matrix.size() == 0 {
        return None;
    }
    let mut nodes: Vec<Vec<usize>> = Vec::new();
    for (body, support) in points.iter() {
        let index = body.0 as usize;
        if nodes.len() <= index {
            nodes.resize(index + 1, Vec::new());
        }
        nodes[index].extend(support.0.iter().map(|w| w.node));
    }
    for list in &mut nodes {
        list.sort_unstable();
        list.dedup();
    }
    let position = |node: usize| grid.node_position(node);
    let free_modes = |nodes: &[usize]| -> Vec<String> {
        let modes = rigid_modes(nodes, &position, &fields.dofs, matrix.size(), rotations);
        let alone: Vec<String> = modes
            .iter()
            .filter(|mode| is_zero_energy(matrix, &mode.values))
            .map(|mode| mode.name.clone())
            .collect();
        if alone.is_empty() && span_has_zero_energy(matrix, &modes) {
            return vec!["rotating about the point where it is held".to_string()];
        }
        alone
    };
    for (index, body_nodes) in nodes.iter().enumerate() {
        let modes = free_modes(body_nodes);
        if !modes.is_empty() {
            let name = names.get(index).map_or(index.to_string(), |n| n.clone());
            return Some((format!("body '{name}' is"), modes));
        }
    }
    let mut all: Vec<usize> = nodes.concat();
    all.sort_unstable();
    all.dedup();
    let modes = free_modes(&all);
    (!modes.is_empty()).then(|| ("the bodies are".to_string(), modes))
}
