//! Control policies of the solve, pure (no world, no solver): which load factors the driver
//! attempts within a load step ([`LoadStepControl`]), and when a Newton iterate has converged
//! ([`ConvergenceCriterion`]).
//!
//! A load-step policy is a small state machine: the driver asks it for the first attempt of a
//! step, tells it how each attempt ended, and gets the next attempt or the end of the step. The
//! built-in policy is [`StepCutting`]; other policies (arc-length control, which also moves the
//! load factor inside the Newton solve) implement [`LoadStepControl`].
//!
//! # Step cutting
//!
//! The step from λ_n to λ_{n+1} is tried whole. When an attempt fails in a way a smaller step
//! may cure (Newton does not converge or diverges, an inverted point, a singular tangent), the
//! attempt is discarded (the grid is reset; points were not touched) and repeated with half the
//! increment, down to 2^-max_cuts of the step. After a successful sub-step the increment grows
//! back by a factor 2. The last sub-step lands exactly on λ_{n+1}.

/// One attempt: solve from load factor `from` to `to`; `completes_step` when `to` is the step's
/// target (output is written only then).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Attempt {
    pub from: f64,
    pub to: f64,
    pub completes_step: bool,
}

/// A policy for the attempts of one load step.
pub trait LoadStepControl: Send + Sync {
    /// Starts a load step from `start` to `target`; the first attempt.
    fn begin(&mut self, start: f64, target: f64) -> Attempt;
    /// The attempt converged: the next one, or `None` when the step is complete.
    fn succeeded(&mut self, attempt: Attempt) -> Option<Attempt>;
    /// The attempt failed (`recoverable`: a smaller step may succeed): the next attempt, or
    /// `None` to give up.
    fn failed(&mut self, attempt: Attempt, recoverable: bool) -> Option<Attempt>;
    /// How many times the current step was cut.
    fn cuts(&self) -> usize;
}

/// Halve the increment on failure, double it back on success (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct StepCutting {
    pub max_cuts: usize,
    target: f64,
    full: f64,
    level: usize,
    cuts: usize,
}

impl StepCutting {
    pub fn new(max_cuts: usize) -> Self {
        Self {
            max_cuts,
            target: 0.0,
            full: 0.0,
            level: 0,
            cuts: 0,
        }
    }

    /// The attempt from `from` with the increment of the current level.
    fn attempt_from(&self, from: f64) -> Attempt {
        let (full, target) = (self.full, self.target);
        let increment = full / f64::powi(2.0, self.level as i32);
        let completes_step = (from + increment - target).abs() <= 1e-12 * full.abs().max(1e-300)
            || (full > 0.0 && from + increment >= target)
            || (full < 0.0 && from + increment <= target)
            || full == 0.0;
        Attempt {
            from,
            to: if completes_step {
                target
            } else {
                from + increment
            },
            completes_step,
        }
    }
}

impl LoadStepControl for StepCutting {
    fn begin(&mut self, start: f64, target: f64) -> Attempt {
        self.target = target;
        self.full = target - start;
        self.level = 0;
        self.cuts = 0;
        self.attempt_from(start)
    }

    fn succeeded(&mut self, attempt: Attempt) -> Option<Attempt> {
        if attempt.completes_step {
            return None;
        }
        self.level = self.level.saturating_sub(1);
        Some(self.attempt_from(attempt.to))
    }

    fn failed(&mut self, attempt: Attempt, recoverable: bool) -> Option<Attempt> {
        if !recoverable || self.level >= self.max_cuts {
            return None;
        }
        self.level += 1;
        self.cuts += 1;
        Some(self.attempt_from(attempt.from))
    }

    fn cuts(&self) -> usize {
        self.cuts
    }
}

/// The norms of one Newton iterate's forces (over the active nodes): the out-of-balance force
/// at the free DOFs, the external and the internal force; the load factor λ of the iterate;
/// and the largest force of a converged iterate so far, `max(‖f_ext‖, ‖f_int‖)` (kept in a
/// scene that releases a load or support, `resources::LargestForce`; 0 otherwise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResidualNorms {
    pub free: f64,
    pub external: f64,
    pub internal: f64,
    pub load_factor: f64,
    pub largest: f64,
}

/// When a Newton iterate has converged.
pub trait ConvergenceCriterion: Send + Sync {
    /// The measure of an iterate that the tolerance bounds (recorded as its residual).
    fn measure(&self, norms: &ResidualNorms) -> f64;

    /// Whether the iterate with `measure` has converged; `history` holds the step's earlier
    /// measures.
    fn converged(&self, measure: f64, _history: &[f64], tolerance: f64) -> bool {
        measure <= tolerance
    }
}

/// The default criterion: the out-of-balance force at the free DOFs relative to the load
/// scale, the larger of the external and internal force norms brought to a load factor of at
/// least 1:
///
/// ```text
///   ‖f_ext − f_int‖_free · s / max(‖f_ext‖, ‖f_int‖),   s = min(|λ|, 1)  (s = 1 when λ = 0)
/// ```
///
/// (absolute when both norms are zero). For λ ≥ 1 this is the out-of-balance force relative
/// to the current forces; for a small λ it is relative to the forces the load would give at
/// λ = 1 (for proportional loading, `max(‖f_ext‖, ‖f_int‖)/λ`), not to the tiny current ones.
/// Why: the internal force carries a round-off floor of its own (the Hencky logarithm of
/// eigenvalues near 1, positions of magnitude |x|), about 1e-13..1e-12 of the full-load force
/// on the test columns, independent of λ. Relative to the current forces that floor is
/// 1e-6..1e-5 at λ = 1e-6, far above any useful tolerance, and cutting the step makes it worse;
/// relative to the load scale it stays below the default tolerance 1e-9 for any increment.
///
/// **Releases.** A stage that releases a load (`until_stage`: the load ramped down to zero,
/// `(1 − λ) f_end`) can take the body's last load away: at its end `f_ext` is zero and `f_int`
/// is round-off, so the scale above vanishes with them and the measure stays of order 1 however
/// well the iterate balances (Newton did not converge there). In a scene that releases a load
/// or support, the scale has a floor: the largest force a converged iterate carried so far in
/// the run, `F = max over converged iterates of max(‖f_ext‖, ‖f_int‖)` (`ResidualNorms::largest`,
/// kept by `stages::newton` in `resources::LargestForce`, a checkpoint part):
///
/// ```text
///   ‖f_ext − f_int‖_free / max(max(‖f_ext‖, ‖f_int‖)/s, F)
/// ```
///
/// Why this force: the released load was carried at the end of the stage before the release,
/// so `F` is at least its size, and the displacement error Newton leaves is then
/// `tolerance · F / stiffness` in every step, as at the largest load, instead of being
/// required to vanish with the load. Why not the stage's starting force or the reactions: the
/// run's largest force needs no knowledge of stages (one number, updated at every converged
/// iterate), does not shrink when a stage starts from a released state, and the reactions are
/// part of `f_int` already. Where the current scale is at least `F` (loading: always, before a
/// release) the measure is computed exactly as without the floor, bit for bit; a scene that
/// releases nothing keeps no `F` (0) and is computed as before.
#[derive(Clone, Copy, Debug, Default)]
pub struct NormalisedResidual;

impl ConvergenceCriterion for NormalisedResidual {
    fn measure(&self, norms: &ResidualNorms) -> f64 {
        let scale = norms.external.max(norms.internal);
        let lambda = norms.load_factor.abs();
        let to_unit_load = if lambda > 0.0 && lambda < 1.0 {
            lambda
        } else {
            1.0
        };
        if norms.largest > 0.0 && norms.largest * to_unit_load > scale {
            norms.free / norms.largest
        } else if scale > 0.0 {
            norms.free * to_unit_load / scale
        } else {
            norms.free
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs a step whose attempts succeed when their increment is at most `largest`; returns
    /// the attempts (from, to) and whether the step completed.
    fn run(
        control: &mut StepCutting,
        start: f64,
        target: f64,
        largest: f64,
    ) -> (Vec<(f64, f64)>, bool) {
        let mut attempts = Vec::new();
        let mut attempt = control.begin(start, target);
        loop {
            attempts.push((attempt.from, attempt.to));
            let next = if (attempt.to - attempt.from).abs() <= largest + 1e-15 {
                match control.succeeded(attempt) {
                    None => return (attempts, true),
                    next => next,
                }
            } else {
                control.failed(attempt, true)
            };
            match next {
                Some(next) => attempt = next,
                None => return (attempts, false),
            }
        }
    }

    #[test]
    fn a_step_that_converges_is_one_attempt() {
        let mut control = StepCutting::new(8);
        let (attempts, done) = run(&mut control, 0.25, 0.5, 1.0);
        assert_eq!(attempts, [(0.25, 0.5)]);
        assert!(done && control.cuts() == 0);
    }

    #[test]
    fn failures_halve_and_successes_grow_back_to_land_on_the_target() {
        let mut control = StepCutting::new(8);
        // only increments of at most a quarter of the step converge
        let (attempts, done) = run(&mut control, 0.0, 1.0, 0.25);
        assert!(done);
        assert_eq!(
            attempts,
            [
                (0.0, 1.0),
                (0.0, 0.5),
                (0.0, 0.25),
                (0.25, 0.75),
                (0.25, 0.5),
                (0.5, 1.0),
                (0.5, 0.75),
                (0.75, 1.0)
            ]
        );
        assert_eq!(control.cuts(), 4);
    }

    #[test]
    fn gives_up_after_max_cuts_or_an_unrecoverable_failure() {
        let mut control = StepCutting::new(2);
        let (attempts, done) = run(&mut control, 0.0, 1.0, 0.1);
        assert!(!done);
        assert_eq!(attempts, [(0.0, 1.0), (0.0, 0.5), (0.0, 0.25)]);
        let first = control.begin(0.0, 1.0);
        assert_eq!(control.failed(first, false), None);
    }

    #[test]
    fn unloading_steps_are_cut_the_same_way() {
        let mut control = StepCutting::new(8);
        let (attempts, done) = run(&mut control, 1.0, 0.0, 0.5);
        assert!(done);
        assert_eq!(attempts, [(1.0, 0.0), (1.0, 0.5), (0.5, 0.0)]);
    }

    #[test]
    fn the_residual_is_normalised_by_the_larger_force() {
        let norms = ResidualNorms {
            free: 1e-3,
            external: 10.0,
            internal: 20.0,
            load_factor: 1.0,
            largest: 0.0,
        };
        assert_eq!(NormalisedResidual.measure(&norms), 5e-5);
        assert!(NormalisedResidual.converged(5e-5, &[], 1e-4));
        let unloaded = ResidualNorms {
            free: 1e-12,
            external: 0.0,
            internal: 0.0,
            load_factor: 0.0,
            largest: 0.0,
        };
        assert_eq!(NormalisedResidual.measure(&unloaded), 1e-12);
        // at λ = 1e-3 the forces are 1e-3 of the load scale: relative to that scale
        let small = ResidualNorms {
            load_factor: 1e-3,
            ..norms
        };
        assert!((NormalisedResidual.measure(&small) - 5e-8).abs() < 1e-20);
        let beyond = ResidualNorms {
            load_factor: 2.0,
            ..norms
        };
        assert_eq!(NormalisedResidual.measure(&beyond), 5e-5);
    }

    /// In a scene with a release, the run's largest force is the floor of the scale: a
    /// released body (no force left) is measured against it; where the current scale is at
    /// least the floor the measure is the one without it, bit for bit.
    #[test]
    fn a_released_body_is_measured_against_the_largest_force_of_the_run() {
        let released = ResidualNorms {
            free: 1e-9,
            external: 0.0,
            internal: 1e-11,
            load_factor: 1.0,
            largest: 100.0,
        };
        assert!((NormalisedResidual.measure(&released) - 1e-11).abs() < 1e-24);
        let without = ResidualNorms {
            largest: 0.0,
            ..released
        };
        assert!(NormalisedResidual.measure(&without) > 0.09);
        // half released: 50 of the 100 carried, at λ = 0.5 of the release (s = 0.5: scale 100)
        let half = ResidualNorms {
            free: 3e-7,
            external: 50.0,
            internal: 50.0 + 1e-9,
            load_factor: 0.5,
            largest: 100.0,
        };
        let plain = ResidualNorms {
            largest: 0.0,
            ..half
        };
        assert_eq!(
            NormalisedResidual.measure(&half).to_bits(),
            NormalisedResidual.measure(&plain).to_bits()
        );
        // three quarters released: 25 at λ = 0.75, measured against 100 (not 25/0.75)
        let late = ResidualNorms {
            external: 25.0,
            internal: 25.0,
            load_factor: 0.75,
            ..half
        };
        assert!((NormalisedResidual.measure(&late) - 3e-9).abs() < 1e-22);
    }
}
