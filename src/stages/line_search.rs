//! Newton stage 4c': globalisation by a backtracking line search
//! (`solver(#{ line_search: true })`; off by default, and then nothing here runs), on the
//! out-of-balance force (`merit: "residual"`, the default) or on Deuflhard's natural level
//! function (`merit: "natural"`, below).
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
//!
//! **The natural level function** (`merit: "natural"`; Deuflhard 2011, *Newton Methods for
//! Nonlinear Problems*, §3.3, the restricted monotonicity test of NLEQ-ERR). ‖r‖ weighs the
//! DOFs by the tangent's scale: where a stiff part (a penalty, the elastic soil) and a soft one
//! (a plastic zone) meet, a step that is right in the soft part can raise ‖r‖ in the stiff part
//! and be rejected, and Armijo then shortens good steps into many load-step cuts. The natural
//! level function measures the residual of a trial in the metric of the tangent K_k of the
//! iterate the step started from, by the simplified Newton correction
//!
//! ```text
//!   δ̄(α) = K_k⁻¹ r(u_k + α δ),        δ = K_k⁻¹ r(u_k)    (so δ̄(0) = δ)
//! ```
//!
//! solved with the factor of K_k the direct solver kept (no new factorisation:
//! `LinearSolver::solve_with_last_factor`). A trial is accepted when
//!
//! ```text
//!   θ(α) = ‖δ̄(α)‖ / ‖δ‖ ≤ 1 − α/4
//! ```
//!
//! (for a linear problem δ̄(α) = (1 − α) δ: the test passes for every α). Otherwise the
//! a-posteriori estimate of the affine-covariant Lipschitz constant,
//! `h = 2 ‖δ̄(α) − (1 − α) δ‖ / (α² ‖δ‖)`, predicts the next step length `α⁺ = 1/h`, with the
//! same safeguards [0.1 α, 0.5 α]. The test is invariant to a scaling of the equations (a
//! penalty's size, the units of force), where the residual test is not. With an iterative
//! linear solver (no factor is kept) or a grid divided among processes, the residual test is
//! used instead and the run warns once.

use bevy_ecs::prelude::*;

use crate::resources::{GridFields, Newton, NewtonSettings, RunStatus, SolverError, Warnings};
use crate::scene::LineSearchMerit;
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

/// Whether the trial at step length `alpha` passes the restricted monotonicity test of the
/// natural level function, `θ = ‖δ̄(α)‖ / ‖δ‖ ≤ 1 − α/4`.
pub fn natural_decrease(alpha: f64, theta: f64) -> bool {
    theta <= 1.0 - 0.25 * alpha
}

/// The next step length after the natural test rejected the trial at `alpha`: `1/h` with the
/// estimate `h = 2 ‖δ̄(α) − (1 − α) δ‖ / (α² ‖δ‖)` (`deviation` = ‖δ̄(α) − (1 − α) δ‖ / ‖δ‖),
/// safeguarded to [0.1 α, 0.5 α].
pub fn natural_shorter_step(alpha: f64, deviation: f64) -> f64 {
    let h = 2.0 * deviation / (alpha * alpha);
    let prediction = if h.is_finite() && h > 0.0 {
        1.0 / h
    } else {
        LONGEST * alpha
    };
    prediction.clamp(SHORTEST * alpha, LONGEST * alpha)
}

/// The line search's state in the current load step (inserted only when the scene asks for a
/// line search), and its counts for the summary.
#[derive(Resource, Default, Debug)]
pub struct LineSearch {
    /// The test of a trial step.
    merit: LineSearchMerit,
    /// The natural test could not be used in this run (said once in the warnings).
    natural_unavailable: bool,
    /// The simplified Newton correction δ̄ of the trial (natural test), by DOF.
    simplified: Vec<f64>,
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
    /// A line search with the test `merit`.
    pub fn new(merit: LineSearchMerit) -> Self {
        Self {
            merit,
            ..Self::default()
        }
    }

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

    /// Keeps the Newton correction δ when the trial under evaluation is the full step
    /// (Δu = start + δ there); later trials reuse it.
    fn keep_correction<const D: usize>(&mut self, fields: &GridFields<D>) {
        if !self.has_correction {
            self.correction.clear();
            self.correction.resize(self.start.len(), 0.0);
            for_free_dofs(fields, |node, c, dof| {
                self.correction[dof] = fields.increment[node][c] - self.start[dof];
            });
            self.has_correction = true;
        }
    }

    /// The natural level function of the trial just evaluated: `Some((θ, ‖δ̄ − (1 − α) δ‖ /
    /// ‖δ‖))`, or `None` when the kept factor cannot be used (then the residual test serves).
    fn natural_measure<const D: usize>(
        &mut self,
        fields: &GridFields<D>,
        newton: &mut Newton,
    ) -> Option<(f64, f64)> {
        if newton.shared_grid.is_some() {
            return None;
        }
        self.keep_correction(fields);
        self.simplified.clear();
        self.simplified.extend_from_slice(&newton.residual);
        if newton
            .solver
            .solve_with_last_factor(&mut self.simplified)?
            .is_err()
        {
            return None;
        }
        let full = self.correction.iter().map(|d| d * d).sum::<f64>().sqrt();
        if full.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let (theta, deviation) = self
            .simplified
            .iter()
            .zip(&self.correction)
            .fold((0.0, 0.0), |(t, d), (s, c)| {
                (t + s * s, d + (s - (1.0 - self.alpha) * c).powi(2))
            });
        Some((theta.sqrt() / full, deviation.sqrt() / full))
    }

    /// Rejects the trial just evaluated (`ratio`: its merit relative to the start's, if it has
    /// one) and puts the iterate at step length `alpha`.
    fn retry_at<const D: usize>(
        &mut self,
        alpha: f64,
        ratio: Option<f64>,
        fields: &mut GridFields<D>,
        newton: &mut Newton,
    ) {
        self.trials.push((self.alpha, ratio));
        self.keep_correction(fields);
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
    mut warnings: ResMut<Warnings>,
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
    if !search.trial_pending(newton.iterations) || newton.converged {
        search.accept(norm, &fields, newton);
        return;
    }
    // the trial's merit relative to the start's, whether it passes, and the next step length
    let natural = match search.merit {
        LineSearchMerit::Natural => {
            let measure = search.natural_measure(&fields, newton);
            if measure.is_none() && !search.natural_unavailable {
                search.natural_unavailable = true;
                warnings.0.push(format!(
                    "load step {}: the line search's natural level function needs the kept \
                     factor of a direct solve on an undivided grid ({}): the residual test \
                     (merit: \"residual\") is used instead in this run",
                    step.number,
                    if newton.shared_grid.is_some() {
                        "this grid is divided among processes"
                    } else {
                        "this linear solver keeps none"
                    }
                ));
            }
            measure
        }
        LineSearchMerit::Residual => None,
    };
    let (ratio, passes, next) = match natural {
        Some((theta, deviation)) => (
            theta,
            natural_decrease(search.alpha, theta),
            natural_shorter_step(search.alpha, deviation),
        ),
        None => (
            norm / search.start_norm,
            sufficient_decrease(search.start_norm, search.alpha, norm),
            shorter_step(search.alpha, search.start_norm, Some(norm)),
        ),
    };
    if passes {
        search.accept(norm, &fields, newton);
        return;
    }
    if search.backtracks >= settings.max_backtracks {
        let mut trials = search.trials.clone();
        trials.push((search.alpha, Some(ratio)));
        status.fail(SolverError::LineSearch {
            step: step.number,
            iteration: newton.iterations,
            backtracks: search.backtracks,
            residuals: newton.residuals.clone(),
            trials,
            natural: natural.is_some(),
        });
        return;
    }
    search.retry_at(next, Some(ratio), &mut fields, newton);
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
    let ratio = norm.map(|n| n / search.start_norm);
    world.resource_mut::<RunStatus>().0 = None;
    world.resource_scope(|world, mut search: Mut<LineSearch>| {
        world.resource_scope(|world, mut fields: Mut<GridFields<D>>| {
            let mut newton = world.resource_mut::<Newton>();
            search.retry_at(alpha, ratio, &mut fields, &mut newton);
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

    #[test]
    fn the_natural_test_accepts_a_linear_problems_steps_and_predicts_from_the_curvature() {
        // linear: δ̄(α) = (1 − α) δ, θ = 1 − α passes at every α, and no deviation
        for alpha in [1.0, 0.5, 0.1] {
            assert!(natural_decrease(alpha, 1.0 - alpha));
        }
        assert!(!natural_decrease(0.5, 0.9));
        assert!(natural_decrease(0.5, 0.875));
        // r(u) = δ0 − u − κ u²/2 in 1D with K = 1 at u = 0 (δ = δ0): δ̄(α) − (1 − α) δ =
        // −κ α² δ0²/2, h = κ δ0, and the prediction 1/h is the step of a sound quadratic model
        let (kappa, delta) = (8.0_f64, 1.0_f64);
        let alpha = 1.0;
        let deviation = (kappa * alpha * alpha * delta * delta / 2.0) / delta;
        let next = natural_shorter_step(alpha, deviation);
        assert!(
            (next - (1.0 / (kappa * delta)).clamp(0.1, 0.5)).abs() < 1e-15,
            "{next}"
        );
        // a huge deviation gives the shortest step, none the longest
        assert!((natural_shorter_step(0.5, 1e9) - 0.05).abs() < 1e-15);
        assert_eq!(natural_shorter_step(0.5, 0.0), 0.25);
        assert_eq!(natural_shorter_step(0.5, f64::NAN), 0.25);
    }
}
