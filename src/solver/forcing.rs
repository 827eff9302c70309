//! Inexact Newton: how accurately each linear solve needs to be done (Eisenstat & Walker 1996,
//! "Choosing the forcing terms in an inexact Newton method", choice 2).
//!
//! Newton's correction solves `K δ = r` only to a relative residual `η_k` (the forcing term):
//! far from the solution a rough direction is as good as an exact one, and an iterative
//! backend saves most of its iterations there. With `‖F_k‖` the out-of-balance force of iterate
//! `k`,
//!
//! ```text
//!   η_k = γ (‖F_k‖ / ‖F_{k−1}‖)^α,      γ = 0.9, α = 2,   η_0 = η_max
//!   η_k ← max(η_k, γ η_{k−1}^α)  if γ η_{k−1}^α > 0.1       (no sudden tightening)
//!   η_k ← min(η_k, η_max),  η_max = 0.1
//!   η_k ← max(η_k, ½ τ / ‖F_k‖)                              (no over-solving at the end)
//!   η_k ← max(η_k, η_min)                                    (the solver's own tolerance)
//! ```
//!
//! with `τ` Newton's tolerance on the same (normalised) norm. With `α = 2` the forcing terms
//! shrink like the residual once Newton converges quadratically, so its local rate is kept
//! (Eisenstat & Walker, theorem 2.3); the last safeguard stops asking the solve for more than
//! the Newton tolerance can see (Kelley 1995, §6.3).

/// The forcing-term parameters (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EisenstatWalker {
    pub gamma: f64,
    pub alpha: f64,
    pub eta_max: f64,
}

impl Default for EisenstatWalker {
    fn default() -> Self {
        Self {
            gamma: 0.9,
            alpha: 2.0,
            eta_max: 0.1,
        }
    }
}

impl EisenstatWalker {
    /// The forcing term of the iterate whose residual is the last of `residuals` (the step's
    /// history so far, normalised norms), after `previous` (the last forcing term, `None` for
    /// the step's first solve), for Newton tolerance `tolerance` and the solver's own relative
    /// tolerance `eta_min`.
    pub fn forcing_term(
        &self,
        residuals: &[f64],
        previous: Option<f64>,
        tolerance: f64,
        eta_min: f64,
    ) -> f64 {
        let Some(&current) = residuals.last() else {
            return eta_min;
        };
        let mut eta = match (previous, residuals.len()) {
            (Some(previous), n) if n >= 2 && residuals[n - 2] > 0.0 => {
                let ratio = current / residuals[n - 2];
                let eta = self.gamma * ratio.powf(self.alpha);
                let floor = self.gamma * previous.powf(self.alpha);
                if floor > 0.1 { eta.max(floor) } else { eta }
            }
            _ => self.eta_max,
        };
        eta = eta.min(self.eta_max);
        if current > 0.0 {
            eta = eta.max(0.5 * tolerance / current);
        }
        if eta.is_finite() {
            eta.clamp(eta_min, self.eta_max.max(eta_min))
        } else {
            eta_min
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_solve_is_loose_and_the_terms_follow_the_squared_reduction() {
        let ew = EisenstatWalker::default();
        assert_eq!(ew.forcing_term(&[1.0], None, 1e-9, 1e-10), 0.1);
        // reduction by 1e-2: 0.9 * 1e-4
        let eta = ew.forcing_term(&[1.0, 1e-2], Some(0.1), 1e-9, 1e-10);
        assert!((eta - 0.9e-4).abs() < 1e-15, "{eta}");
        // a stalled residual is capped at η_max
        assert_eq!(ew.forcing_term(&[1.0, 0.9], Some(0.1), 1e-9, 1e-10), 0.1);
    }

    #[test]
    fn near_the_tolerance_the_solve_is_not_asked_for_more_than_newton_sees() {
        let ew = EisenstatWalker::default();
        // residual 1e-7, tolerance 1e-9: η ≥ 0.5e-9 / 1e-7 = 5e-3 although the ratio says 9e-11
        let eta = ew.forcing_term(&[1.0, 1e-2, 1e-7], Some(1e-4), 1e-9, 1e-10);
        assert!((eta - 5e-3).abs() < 1e-15, "{eta}");
        // never below the solver's own tolerance
        assert_eq!(ew.forcing_term(&[1.0, 0.0], Some(1e-4), 1e-9, 1e-10), 1e-10);
    }
}
