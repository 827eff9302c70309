//! Newton stage 4c': globalisation by a backtracking line search on the out-of-balance force
//! (`solver(#{ line_search: true })`; off by default, and then nothing here runs).
//!
//! After the solve `K δ = r(u_k)` the full step `u_k + δ` is evaluated as usual (stress
//! update, assembly, convergence check). The merit function is the squared out-of-balance
//! force at the free DOFs,
//!
//! ```text
//!   φ(α) = ‖r(u_k + α δ)‖²,    φ'(0) = −2 r_k · K δ = −2 ‖r_k‖²   (K the consistent tangent)
//! ```
//!
//! so δ is a descent direction of φ whether or not K is symmetric (non-associated flow, F-bar
//! and follower loads have no potential energy that could serve instead). The step is accepted
//! when it decreases the residual sufficiently (Armijo on ‖r‖, c = 1e-4):
//!
//! ```text
//!   ‖r(u_k + α δ)‖ ≤ (1 − c α) ‖r_k‖
//! ```
//!
//! otherwise α is replaced by the minimiser of the parabola through φ(0), φ'(0) and φ(α),
//! safeguarded to [0.1 α, 0.5 α] (Kelley 1995, *Iterative methods for linear and nonlinear
//! equations*, §8.2–8.3: the Newton–Armijo iteration with parabolic line search):
//!
//! ```text
//!   α⁺ = α² φ(0) / (φ(α) − φ(0) + 2 α φ(0)),    clamped to [0.1 α, 0.5 α]
//! ```
//!
//! and `u_k + α⁺ δ` is evaluated (no linear solve: δ is kept). A trial at which a point's state
//! becomes inadmissible (det F ≤ 0, a failed return, a non-finite value) or the residual
//! explodes is shortened the same way (α/2, or the parabola's 0.1 α for an explosion) instead
//! of failing the attempt. After `max_backtracks` shortenings of one Newton iteration the
//! attempt fails ([`SolverError::LineSearch`], recoverable: the load-step control then cuts the
//! step). A converged trial is always accepted.
//!
//! The full step is always tried first, so where it already decreases the residual (Newton's
//! quadratic phase, a well-behaved elastic step) the iteration is exactly Newton's: same
//! iterates, same counts. Rejected trials are not Newton iterations: they are left out of the
//! residual history and counted separately (`Newton::iterations` counts linear solves).

use bevy_ecs::prelude::*;

use crate::resources::{GridFields, Newton, NewtonSettings, RunStatus, SolverError};
use crate::solver::NO_DOF;

/// Sufficient-decrease constant c of the Armijo condition.
pub const ARMIJO: f64 = 1e-4;

/// The safeguards of the parabolic backtracking: α⁺ ∈ [SHORTEST α, LONGEST α].
const SHORTEST: f64 = 0.1;
const LONGEST: f64 = 0.5;

/// Whether the trial with residual norm `norm` at step length `alpha` from an iterate with
/// residual norm `start` decreases the residual enough (Armijo).
pub fn sufficient_decrease(start: f64, alpha: f64, norm: f64) -> bool {
    norm <= (1.0 - ARMIJO * alpha) * start
}

/// The next step length after the trial at `alpha` was rejected: the minimiser of the parabola
/// through φ(0) = `start`², φ'(0) = −2 `start`², φ(α) = `norm`², safeguarded to
/// [0.1 α, 0.5 α]; α/2 when the trial has no (finite) residual.
pub fn shorter_step(alpha: f64, start: f64, norm: Option<f64>) -> f64 {
    let Some(norm) = norm.filter(|n| n.is_finite()) else {
        return LONGEST * alpha;
    };
    let (phi0, phi) = (start * start, norm * norm);
    let curvature = phi - phi0 + 2.0 * alpha * phi0;
    let minimiser = if curvature > 0.0 {
        alpha * alpha * phi0 / curvature
    } else {
        LONGEST * alpha
    };
    minimiser.clamp(SHORTEST * alpha, LONGEST * alpha)
}

/// The line search's state in the current load step (inserted only when the scene asks for a
/// line search), and its counts for the summary.
#[derive(Resource, Default, Debug)]
pub struct LineSearch {
    /// ‖r‖ at the accepted iterate the current correction starts from.
    start_norm: f64,
    /// The free components of Δu at that iterate, by DOF.
    start: Vec<f64>,
    /// The Newton correction δ by DOF (taken at the first shortening).
    correction: Vec<f64>,
    has_correction: bool,
    /// The step length of the trial under evaluation.
    alpha: f64,
    /// Shortenings of the current Newton iteration.
    backtracks: usize,
    /// The rejected trials of the current Newton iteration: step length and ‖r‖ / ‖r_k‖
    /// (`None`: no residual, the point states were inadmissible).
    trials: Vec<(f64, Option<f64>)>,
    /// `Newton::iterations` when the last iterate was accepted; `None` before the step's first.
    accepted_at: Option<usize>,
    /// Length of `Newton::residuals` with the accepted iterate.
    accepted_residuals: usize,
    /// The last evaluation was rejected: the Newton loop evaluates the shorter step next.
    pub backtracking: bool,
    /// Newton iterations of the current attempt that took a step shorter than the full one.
    pub shortened: usize,
    /// Rejected trials (evaluations without a linear solve) in the current attempt.
    pub rejected: usize,
}

impl LineSearch {
    /// Forgets the previous attempt (called when a load step's Newton solve begins).
    pub fn begin_step(&mut self) {
        self.accepted_at = None;
        self.has_correction = false;
        self.backtracking = false;
        self.backtracks = 0;
        self.trials.clear();
        self.alpha = 1.0;
        self.shortened = 0;
        self.rejected = 0;
    }

    /// Whether the last evaluation was a trial step (a correction was applied since the last
    /// accepted iterate).
    fn trial_pending(&self, iterations: usize) -> bool {
        self.accepted_at.is_some_and(|at| iterations > at)
    }

    /// Accepts the current iterate (residual norm `norm`): the next correction starts here.
    fn accept<const D: usize>(&mut self, norm: f64, fields: &GridFields<D>, newton: &Newton) {
        if self.trial_pending(newton.iterations) && self.alpha < 1.0 {
            self.shortened += 1;
        }
        self.start_norm = norm;
        self.start.clear();
        self.start.resize(newton.residual.len(), 0.0);
        for_free_dofs(fields, |node, c, dof| {
            self.start[dof] = fields.increment[node][c];
        });
        self.has_correction = false;
        self.alpha = 1.0;
        self.backtracks = 0;
        self.trials.clear();
        self.accepted_at = Some(newton.iterations);
        self.accepted_residuals = newton.residuals.len();
    }

    /// Rejects the trial just evaluated (residual norm `norm`, if it has one) and puts the
    /// iterate at step length `alpha`.
    fn retry_at<const D: usize>(
        &mut self,
        alpha: f64,
        norm: Option<f64>,
        fields: &mut GridFields<D>,
        newton: &mut Newton,
    ) {
        self.trials
            .push((self.alpha, norm.map(|n| n / self.start_norm)));
        if !self.has_correction {
            // the rejected trial was the full step: Δu = start + δ
            self.correction.clear();
            self.correction.resize(self.start.len(), 0.0);
            for_free_dofs(fields, |node, c, dof| {
                self.correction[dof] = fields.increment[node][c] - self.start[dof];
            });
            self.has_correction = true;
        }
        self.alpha = alpha;
        self.backtracks += 1;
        self.rejected += 1;
        self.backtracking = true;
        newton.residuals.truncate(self.accepted_residuals);
        newton.converged = false;
        let (start, correction) = (&self.start, &self.correction);
        let GridFields {
            dofs, increment, ..
        } = fields;
        for (node, node_dofs) in dofs.written() {
            for (c, &dof) in node_dofs.iter().enumerate() {
                if dof != NO_DOF {
                    let dof = dof as usize;
                    increment[node][c] = start[dof] + alpha * correction[dof];
                }
            }
        }
    }
}

/// Calls `f(node, component, dof)` for every free component.
fn for_free_dofs<const D: usize>(fields: &GridFields<D>, mut f: impl FnMut(usize, usize, usize)) {
    for (node, dofs) in fields.dofs.written() {
        for (c, &dof) in dofs.iter().enumerate() {
            if dof != NO_DOF {
                f(node, c, dof as usize);
            }
        }
    }
}

/// ‖r‖ at the free DOFs. On a grid split among processes (`Newton::shared_grid`, a decomposed
/// run) each process holds its own nodes' residual: each DOF counts on its node's owner and the
/// squares are summed over the processes (collective), so every process judges a trial alike
/// (a process's own norm would let one accept the trial another rejects, and then wait for
/// it). Serially the sum runs over the DOFs in their order, as `‖r‖` of the whole vector.
fn residual_norm<const D: usize>(fields: &GridFields<D>, newton: &Newton) -> Result<f64, String> {
    let shared = newton.shared_grid.as_deref();
    let mut squares = 0.0;
    for_free_dofs(fields, |node, _, dof| {
        if shared.is_none_or(|s| s.owned(node)) {
            squares += newton.residual[dof] * newton.residual[dof];
        }
    });
    if let Some(shared) = shared {
        squares = shared.sum(&[squares])?.first().copied().unwrap_or(f64::NAN);
    }
    Ok(squares.sqrt())
}

/// `Hook::Convergence` (after the convergence check, before the solve; added by
/// `effects::line_search`): accepts the iterate just
/// evaluated or rejects it and puts the shorter step in its place (see the module docs).
pub fn judge_iterate<const D: usize>(
    mut search: ResMut<LineSearch>,
    settings: Res<NewtonSettings>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut status: ResMut<RunStatus>,
    step: Res<crate::resources::LoadStep>,
) {
    let (search, newton) = (&mut *search, &mut *newton);
    search.backtracking = false;
    if status.0.is_some() {
        // the convergence check failed (a non-finite or diverging residual): the set's run
        // condition was evaluated before it; `retry_after_failure` decides what to do
        return;
    }
    let norm = match residual_norm(&fields, newton) {
        Ok(norm) => norm,
        Err(why) => {
            status.fail(SolverError::Module {
                step: step.number,
                what: format!("the line search's residual norm over the processes: {why}"),
                recoverable: false,
            });
            return;
        }
    };
    let rejected = search.trial_pending(newton.iterations)
        && !newton.converged
        && !sufficient_decrease(search.start_norm, search.alpha, norm);
    if !rejected {
        search.accept(norm, &fields, newton);
        return;
    }
    if search.backtracks >= settings.max_backtracks {
        let mut trials = search.trials.clone();
        trials.push((search.alpha, Some(norm / search.start_norm)));
        status.fail(SolverError::LineSearch {
            step: step.number,
            iteration: newton.iterations,
            backtracks: search.backtracks,
            residuals: newton.residuals.clone(),
            trials,
        });
        return;
    }
    let alpha = shorter_step(search.alpha, search.start_norm, Some(norm));
    search.retry_at(alpha, Some(norm), &mut fields, newton);
}

/// Run condition of the linear solve: the line search (if any) accepted the iterate.
pub fn iterate_accepted(search: Option<Res<LineSearch>>) -> bool {
    search.is_none_or(|s| !s.backtracking)
}

/// Prepares the line search (if any) for a load step's Newton solve.
pub fn begin_step(world: &mut World) {
    if let Some(mut search) = world.get_resource_mut::<LineSearch>() {
        search.begin_step();
    }
}

/// Whether the last Newton schedule run rejected its trial (the loop evaluates the shorter
/// step next, without counting an iteration).
pub fn is_backtracking(world: &World) -> bool {
    world
        .get_resource::<LineSearch>()
        .is_some_and(|s| s.backtracking)
}

/// After a failed Newton schedule run: when the failure happened while evaluating a trial step
/// (an inadmissible or non-finite point state, an exploding residual) and shortenings are
/// left, forgets the failure and puts the shorter step in place; returns whether it did.
pub fn retry_after_failure<const D: usize>(world: &mut World) -> bool {
    let Some(search) = world.get_resource::<LineSearch>() else {
        return false;
    };
    let newton = world.resource::<Newton>();
    let max_backtracks = world.resource::<NewtonSettings>().max_backtracks;
    if !search.trial_pending(newton.iterations) || search.backtracks >= max_backtracks {
        return false;
    }
    let norm = match &world.resource::<RunStatus>().0 {
        Some(SolverError::BadPointState { .. }) => None,
        Some(SolverError::NotFinite { stage, .. }) if *stage != "linear solve" => None,
        Some(SolverError::Diverged { .. }) => {
            let fields = world.resource::<GridFields<D>>();
            // every process diverged alike (the convergence check's norms are global)
            match residual_norm(fields, newton) {
                Ok(norm) => Some(norm),
                Err(_) => return false,
            }
        }
        _ => return false,
    };
    let alpha = shorter_step(search.alpha, search.start_norm, norm);
    world.resource_mut::<RunStatus>().0 = None;
    world.resource_scope(|world, mut search: Mut<LineSearch>| {
        world.resource_scope(|world, mut fields: Mut<GridFields<D>>| {
            let mut newton = world.resource_mut::<Newton>();
            search.retry_at(alpha, norm, &mut fields, &mut newton);
        });
    });
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_full_step_is_kept_where_it_decreases_the_residual() {
        assert!(sufficient_decrease(1.0, 1.0, 0.5));
        assert!(sufficient_decrease(1.0, 1.0, 1.0 - 2e-4));
        assert!(!sufficient_decrease(1.0, 1.0, 1.0 - 0.5e-4));
        assert!(!sufficient_decrease(1.0, 0.5, 1.0));
    }

    #[test]
    fn the_parabola_is_minimised_within_its_safeguards() {
        // φ(α) = (1 − α)² ‖r0‖² + κ α² ‖r0‖²: the exact parabola, minimiser 1 / (1 + κ)
        let start = 2.0_f64;
        for kappa in [0.5, 1.5, 3.0, 20.0] {
            let alpha = 1.0_f64;
            let phi = ((1.0 - alpha).powi(2) + kappa * alpha * alpha) * start * start;
            let next = shorter_step(alpha, start, Some(phi.sqrt()));
            let expected = (1.0 / (1.0 + kappa)).clamp(0.1, 0.5);
            assert!((next - expected).abs() < 1e-14, "κ = {kappa}: {next}");
        }
        // a residual that explodes: the shortest step allowed
        assert!((shorter_step(0.5, 1.0, Some(1e8)) - 0.05).abs() < 1e-15);
        // no residual (an inverted point): half the step
        assert_eq!(shorter_step(0.5, 1.0, None), 0.25);
        assert_eq!(shorter_step(0.5, 1.0, Some(f64::NAN)), 0.25);
    }
}
