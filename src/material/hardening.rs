//! Isotropic hardening laws of von Mises (and its Tresca form): the yield stress as a function
//! of the accumulated equivalent plastic strain `ε̄_p`, and the scalar Newton iteration of the
//! radial return on a non-linear law.
//!
//! # The laws
//!
//! With the initial (uniaxial) yield stress `σ_y0`:
//!
//! ```text
//! linear                 σ_y(ε̄_p) = σ_y0 + H ε̄_p                                 H ≥ 0
//! voce (saturation)      σ_y(ε̄_p) = σ_y0 + (σ_∞ − σ_y0)(1 − e^{−δ ε̄_p}) + H ε̄_p   σ_∞ ≥ σ_y0, δ > 0, H ≥ 0
//! exponential_softening  σ_y(ε̄_p) = [δ_rem + (1 − δ_rem) e^{−3ξ/ξ_95}] σ_y0,   ξ = √3 ε̄_p
//!                                                                              0 < δ_rem ≤ 1, ξ_95 > 0
//! ```
//!
//! and their slopes `H(ε̄_p) = dσ_y/dε̄_p`: `H`; `(σ_∞ − σ_y0) δ e^{−δ ε̄_p} + H`;
//! `−(1 − δ_rem) σ_y0 (3√3/ξ_95) e^{−3ξ/ξ_95}`.
//!
//! The last is the strain-softening law of sensitive clays of Einav & Randolph (2005,
//! *Combining upper bound and strain path methods for evaluating penetration resistance*,
//! IJNME 63, 1991–2016): `s_u(ξ) = [δ_rem + (1 − δ_rem) e^{−3ξ/ξ_95}] s_u0`, `δ_rem` the ratio
//! of the remoulded to the intact strength (the inverse of the sensitivity), `ξ` the accumulated
//! plastic **engineering** shear strain and `ξ_95` the `ξ` at which 95 % of the degradation has
//! taken place (`e^{−3} ≈ 0.05`). Since `σ_y = √3 s_u` the ratio is the same in `σ_y` and in
//! `s_u`. The shear strain used is `ξ = √3 ε̄_p`: with `ε̄_p = Σ √(2/3) ‖Δε_p‖` and isochoric
//! flow, a plastic simple shear `γ_p` (`ε_p,xy = γ_p/2`) and a plane-strain plastic flow
//! `diag(a, −a, 0)` (maximum engineering shear `γ_p = 2a`) both give `ε̄_p = γ_p/√3`, so `ξ` is
//! the plastic shear strain an engineer reads off a simple-shear or plane-strain test.
//!
//! # The return (de Souza Neto et al., box 7.4, non-linear isotropic hardening)
//!
//! With `q^tr = √6 G ‖dev ε^tr‖` above `σ_y(ε̄_p^n)` the multiplier `Δγ` (`= Δε̄_p`) solves the
//! consistency condition
//!
//! ```text
//! r(Δγ) = q^tr − 3G Δγ − σ_y(ε̄_p^n + Δγ) = 0,     r'(Δγ) = −(3G + H(ε̄_p^n + Δγ))
//! ```
//!
//! by Newton's method from `Δγ = 0`, safeguarded by bisection inside the bracket
//! `[0, q^tr/(3G)]` (`r(0) > 0`, and `r(q^tr/(3G)) = −σ_y < 0` since every law keeps `σ_y > 0`),
//! stopped at `|r| ≤ 1e-12 q^tr` or refused after [`MAX_ITERATIONS`]. The root is unique when
//! `3G + H(ε̄_p) > 0` for every `ε̄_p`: always for the hardening laws, and for the softening one
//! when `3G > (1 − δ_rem) σ_y0 3√3/ξ_95` (its steepest slope is at `ε̄_p = 0`), which the model
//! checks. The iteration is [`decreasing_root`], shared with every other scalar consistency
//! condition (the softening Drucker–Prager cone and apex, `drucker_prager.rs`). The linear law is solved by the first Newton step exactly (`Δγ = r(0)/(3G + H)`),
//! the closed-form return, and stops there. The consistent tangent uses the slope at the
//! returned state, `H(ε̄_p^{n+1})` (von Mises module docs).

/// The largest number of Newton iterations of the consistency condition.
pub const MAX_ITERATIONS: usize = 50;

/// The relative tolerance (of `q^tr`) of the consistency residual.
pub const TOLERANCE: f64 = 1e-12;

/// An isotropic hardening (or softening) law of the yield stress (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum IsotropicHardening {
    /// `σ_y0 + H ε̄_p`.
    Linear { modulus: f64 },
    /// `σ_y0 + (σ_∞ − σ_y0)(1 − e^{−δ ε̄_p}) + H ε̄_p`.
    Voce {
        saturation: f64,
        rate: f64,
        modulus: f64,
    },
    /// `[δ_rem + (1 − δ_rem) e^{−3√3 ε̄_p/ξ_95}] σ_y0` (Einav & Randolph 2005).
    ExponentialSoftening { residual_ratio: f64, xi95: f64 },
}

impl Default for IsotropicHardening {
    /// Perfect plasticity: the linear law with `H = 0`.
    fn default() -> Self {
        Self::Linear { modulus: 0.0 }
    }
}

impl IsotropicHardening {
    /// The laws' words in scenes (`hardening: ".."`).
    pub const WORDS: &'static [&'static str] = &["linear", "voce", "exponential_softening"];

    /// The linear law, or why `modulus` makes none.
    pub fn linear(modulus: f64) -> Result<Self, String> {
        check_modulus(modulus)?;
        Ok(Self::Linear { modulus })
    }

    /// Voce's saturation law to `saturation` (which the model checks against its initial yield
    /// stress), or why it makes none.
    pub fn voce(saturation: f64, rate: f64, modulus: f64) -> Result<Self, String> {
        if !saturation.is_finite() {
            return Err(format!(
                "saturation yield stress sigma_inf must be finite, got {saturation} (voce hardening)"
            ));
        }
        if !(rate > 0.0 && rate.is_finite()) {
            return Err(format!(
                "saturation rate delta must be positive, got {rate} (voce hardening)"
            ));
        }
        check_modulus(modulus)?;
        Ok(Self::Voce {
            saturation,
            rate,
            modulus,
        })
    }

    /// The exponential softening to `residual_ratio` of the initial strength, or why it makes
    /// none.
    pub fn exponential_softening(residual_ratio: f64, xi95: f64) -> Result<Self, String> {
        if !(residual_ratio > 0.0 && residual_ratio <= 1.0) {
            return Err(format!(
                "residual strength ratio residual_ratio must satisfy 0 < residual_ratio <= 1, got {residual_ratio} (exponential_softening)"
            ));
        }
        if !(xi95 > 0.0 && xi95.is_finite()) {
            return Err(format!(
                "xi95 (the plastic shear strain of 95 % of the softening) must be positive, got {xi95} (exponential_softening)"
            ));
        }
        Ok(Self::ExponentialSoftening {
            residual_ratio,
            xi95,
        })
    }

    /// The law's word in scenes.
    pub fn word(&self) -> &'static str {
        match self {
            Self::Linear { .. } => "linear",
            Self::Voce { .. } => "voce",
            Self::ExponentialSoftening { .. } => "exponential_softening",
        }
    }

    /// Whether the yield stress falls with plastic strain somewhere.
    pub fn softens(&self) -> bool {
        matches!(self, Self::ExponentialSoftening { residual_ratio, .. } if *residual_ratio < 1.0)
    }

    /// `σ_y(ε̄_p)` and its slope `H(ε̄_p)` from the initial yield stress `initial` (the same
    /// form as `CohesionHardening::branch`).
    pub fn branch(&self, initial: f64, plastic_strain: f64) -> (f64, f64) {
        match *self {
            Self::Linear { modulus } => (initial + modulus * plastic_strain, modulus),
            Self::Voce {
                saturation,
                rate,
                modulus,
            } => {
                let decay = (-rate * plastic_strain).exp();
                (
                    initial + (saturation - initial) * (1.0 - decay) + modulus * plastic_strain,
                    (saturation - initial) * rate * decay + modulus,
                )
            }
            Self::ExponentialSoftening {
                residual_ratio,
                xi95,
            } => {
                let rate = 3.0 * 3.0f64.sqrt() / xi95;
                let decay = (-rate * plastic_strain).exp();
                (
                    initial * (residual_ratio + (1.0 - residual_ratio) * decay),
                    -initial * (1.0 - residual_ratio) * rate * decay,
                )
            }
        }
    }

    /// The smallest slope over all `ε̄_p ≥ 0` (module docs: the return is unique while
    /// `3G` exceeds its negative).
    pub fn steepest_slope(&self, initial: f64) -> f64 {
        match *self {
            Self::Linear { modulus } => modulus,
            // the exponential part decays: the slope falls towards H
            Self::Voce { modulus, .. } => modulus,
            Self::ExponentialSoftening { .. } => self.branch(initial, 0.0).1,
        }
    }

    /// The multiplier `Δγ` of the radial return and the slope `H` at the returned state
    /// (module docs): the root of `q^tr − stiffness Δγ − σ_y(plastic_strain + Δγ)`, with
    /// `stiffness = 3G` and `q^tr` above `σ_y(plastic_strain)`.
    pub fn radial_return(
        &self,
        initial: f64,
        plastic_strain: f64,
        q_trial: f64,
        stiffness: f64,
    ) -> Result<(f64, f64), String> {
        let root = decreasing_root(
            (0.0, q_trial / stiffness),
            TOLERANCE * q_trial,
            matches!(self, Self::Linear { .. }),
            |increment| {
                let (yield_stress, slope) = self.branch(initial, plastic_strain + increment);
                (
                    q_trial - stiffness * increment - yield_stress,
                    stiffness + slope,
                    slope,
                )
            },
        );
        root.map_err(|failure| match failure {
            RootFailure::NotDecreasing { at, derivative } => format!(
                "the von Mises return with {} hardening has no unique solution: 3G + H = {derivative:e} at eps_p = {:e}",
                self.word(),
                plastic_strain + at
            ),
            RootFailure::NoConvergence { at, residual } => format!(
                "the von Mises return with {} hardening did not converge in {MAX_ITERATIONS} iterations: consistency residual {residual:e} (of q_trial {q_trial:e}) at eps_p = {:e}",
                self.word(),
                plastic_strain + at
            ),
        })
    }
}

/// Why [`decreasing_root`] found no root.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RootFailure {
    /// `−r'(at)` is not positive (NaN included): the root is not unique.
    NotDecreasing { at: f64, derivative: f64 },
    /// No `|r| ≤ tolerance` in [`MAX_ITERATIONS`] steps, or a residual that is not finite.
    NoConvergence { at: f64, residual: f64 },
}

/// The safeguarded Newton iteration of the module docs, shared by every scalar consistency
/// condition (von Mises' radial return here, the softening Drucker–Prager cone and apex in
/// `drucker_prager.rs`): the root in `[lower, upper]` of a decreasing `r` with `r(lower) > 0` and
/// `r(upper) ≤ 0`, from `x = lower`. `evaluate(x)` gives `(r(x), −r'(x), state)`; a Newton step
/// that leaves the bracket is replaced by bisection, the bracket shrinks with the sign of `r`,
/// and the iteration stops at `|r| ≤ tolerance` (absolute), or after the first step if
/// `exact_after_one_step` (a linear `r`, where that step is the closed form). Returns the root
/// and the `state` of its last evaluation; refuses a non-positive `−r'` (the root would not be
/// unique, and the consistent tangent divides by `−r'`).
pub fn decreasing_root<T>(
    (mut lower, mut upper): (f64, f64),
    tolerance: f64,
    exact_after_one_step: bool,
    mut evaluate: impl FnMut(f64) -> (f64, f64, T),
) -> Result<(f64, T), RootFailure> {
    let mut at = lower;
    let (mut residual, mut derivative, _) = evaluate(at);
    for _ in 0..MAX_ITERATIONS {
        // NaN included: not positive
        if derivative.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(RootFailure::NotDecreasing { at, derivative });
        }
        if residual > 0.0 {
            lower = at;
        } else {
            upper = at;
        }
        let newton = at + residual / derivative;
        at = if newton > lower && newton < upper {
            newton
        } else {
            0.5 * (lower + upper)
        };
        let (next_residual, next_derivative, state) = evaluate(at);
        (residual, derivative) = (next_residual, next_derivative);
        if !residual.is_finite() {
            break;
        }
        if exact_after_one_step || residual.abs() <= tolerance {
            return Ok((at, state));
        }
    }
    Err(RootFailure::NoConvergence { at, residual })
}

fn check_modulus(modulus: f64) -> Result<(), String> {
    if !(modulus >= 0.0 && modulus.is_finite()) {
        return Err(format!(
            "hardening modulus H must be zero or positive, got {modulus}"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each law's slope against central differences of its yield stress, and its limits.
    #[test]
    fn the_slopes_are_the_derivatives_and_the_limits_hold() {
        let laws = [
            IsotropicHardening::linear(300.0).unwrap(),
            IsotropicHardening::voce(3.0, 40.0, 10.0).unwrap(),
            IsotropicHardening::exponential_softening(0.3, 0.2).unwrap(),
        ];
        for law in laws {
            for strain in [0.0, 0.01, 0.05, 0.3] {
                let h = 1e-6;
                let (_, slope) = law.branch(2.0, strain + h);
                let fd =
                    (law.branch(2.0, strain + 2.0 * h).0 - law.branch(2.0, strain).0) / (2.0 * h);
                assert!((slope - fd).abs() < 1e-6 * slope.abs().max(1.0), "{law:?}");
            }
        }
        let voce = laws[1];
        assert!((voce.branch(2.0, 10.0).0 - (3.0 + 100.0)).abs() < 1e-12);
        let soft = laws[2];
        // at ξ = √3 ε̄_p = ξ_95, 95 % of the degradation (e^{−3})
        let at95 = soft.branch(2.0, 0.2 / 3.0f64.sqrt()).0;
        assert!((at95 - 2.0 * (0.3 + 0.7 * (-3.0f64).exp())).abs() < 1e-14);
        assert!((soft.branch(2.0, 100.0).0 - 0.6).abs() < 1e-12);
        assert!(soft.softens() && !voce.softens());
        assert_eq!(soft.steepest_slope(2.0), soft.branch(2.0, 0.0).1);
    }

    #[test]
    fn bad_laws_are_refused() {
        assert!(IsotropicHardening::linear(-1.0).is_err());
        assert!(IsotropicHardening::voce(f64::INFINITY, 1.0, 0.0).is_err());
        assert!(IsotropicHardening::voce(3.0, 0.0, 0.0).is_err());
        assert!(IsotropicHardening::voce(3.0, 1.0, f64::NAN).is_err());
        assert!(IsotropicHardening::exponential_softening(0.0, 1.0).is_err());
        assert!(IsotropicHardening::exponential_softening(1.5, 1.0).is_err());
        assert!(IsotropicHardening::exponential_softening(0.5, -1.0).is_err());
        assert!(IsotropicHardening::exponential_softening(1.0, 1.0).is_ok());
    }

    /// The return's multiplier is the root of the consistency condition to its tolerance; the
    /// linear law's is the closed form bit for bit.
    #[test]
    fn the_return_solves_the_consistency_condition() {
        let stiffness = 3.0 * 384.6;
        let laws = [
            IsotropicHardening::linear(300.0).unwrap(),
            IsotropicHardening::voce(3.0, 40.0, 10.0).unwrap(),
            IsotropicHardening::exponential_softening(0.3, 0.2).unwrap(),
        ];
        for law in laws {
            for (start, q_trial) in [(0.0, 2.5), (0.02, 40.0), (0.5, 3.0)] {
                // the return's precondition: a trial above the current yield stress (the
                // linear law's σ_y(0.5) = 152 makes its last pair an elastic trial)
                if q_trial <= law.branch(2.0, start).0 {
                    continue;
                }
                let (increment, slope) = law.radial_return(2.0, start, q_trial, stiffness).unwrap();
                let (yield_stress, h) = law.branch(2.0, start + increment);
                let residual = q_trial - stiffness * increment - yield_stress;
                assert!(residual.abs() <= 1e-12 * q_trial, "{law:?}: {residual:e}");
                assert_eq!(slope, h);
            }
        }
        let excess = 40.0 - (2.0 + 300.0 * 0.02);
        assert_eq!(
            laws[0].radial_return(2.0, 0.02, 40.0, stiffness).unwrap().0,
            excess / (stiffness + 300.0)
        );
        // no unique return: 3G below the softening's steepest slope
        assert!(laws[2].radial_return(2.0, 0.0, 2.5, 1.0).is_err());
    }
}
