//! Linear isotropic hardening or softening of the cohesion of the frictional models
//! (Drucker–Prager, Mohr–Coulomb), with a residual cohesion that bounds softening.
//!
//! # The law
//!
//! With the accumulated equivalent plastic strain `ε̄_p` (each model defines its increment in
//! terms of its plastic multipliers, in its module docs) and the modulus `H`:
//!
//! ```text
//! c(ε̄_p) = c + H ε̄_p                     H ≥ 0 (hardening; H = 0: perfect plasticity)
//! c(ε̄_p) = max(c + H ε̄_p, c_r)           H < 0 (softening), c_r = c_residual, default 0
//! ```
//!
//! The law is piecewise linear, so a return from `ε̄_p^n` with the cohesion `c_n = c(ε̄_p^n)` and
//! the slope `h` of the branch `ε̄_p^n` lies on (`H`, or 0 once at `c_r`) is exact as long as the
//! returned `ε̄_p^{n+1}` stays on that branch: the models' returns are linear in their multipliers
//! for a linear `c(ε̄_p)`. [`CohesionHardening::return_on`] handles the kink: it returns with
//! `(c_n, H)`, and if `c_n + H Δε̄_p` passes below `c_r` it returns again with `(c_r, 0)`, the
//! return of the material that is at its residual strength from the start (the residual of the
//! piecewise-linear consistency condition is continuous and decreasing in the multiplier when
//! the models' softening limits hold, so the second return is the solution on the kinked law).
//!
//! # Defaults and bad input
//!
//! Without `c_residual` softening stops at `c = 0` (a cohesion never turns negative); a
//! frictionless soil (`φ = 0`) would then lose all its strength, so with `φ = 0` and `H < 0` a
//! positive `c_residual` is required. `c_residual` must be finite, at least 0 and at most `c`; it
//! has no effect for `H ≥ 0`. A too steep softening (`H` below the models' limits, where the
//! return stops being unique) is refused by the models.
//!
//! # Exponential softening of c, φ and ψ (Drucker–Prager only)
//!
//! [`StrengthSoftening`] is the law of Yerro, Alonso & Pinyol (2016, *Run-out of landslides in
//! brittle soils*, Computers and Geotechnics 80, 427–439): each strength parameter decays from
//! its peak `x_p` to its residual `x_r` with the accumulated equivalent plastic strain,
//!
//! ```text
//! x(ε̄_p) = x_r + (x_p − x_r) e^{−η ε̄_p},    x'(ε̄_p) = −η (x_p − x_r) e^{−η ε̄_p},    x ∈ {c, φ, ψ}
//! ```
//!
//! with one shape factor `η > 0` (`softening_rate`) and `c_residual`, `phi_residual`,
//! `psi_residual` (defaults: the peak, no softening of that parameter; `psi_residual` defaults to
//! `phi_residual` when `psi` is not given, so associated flow stays associated). Refused: a
//! residual above its peak, `ψ_r > φ_r`, a negative residual, `c_r = φ_r = 0` (no strength
//! left), a rate that is not positive and finite, a rate with every residual at its peak (it
//! would do nothing), a residual angle without a rate, and a rate with a linear `H ≠ 0` (two laws
//! of one cohesion). The return with it is Drucker–Prager's (`drucker_prager.rs`); Mohr–Coulomb
//! refuses the options (not implemented there).

use super::elastoplastic::PrincipalReturn;

/// The hardening of the cohesion `c`: `c(ε̄_p) = max(c + H ε̄_p, floor)` (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CohesionHardening {
    /// `H`: positive hardens, negative softens, zero is perfect plasticity.
    pub modulus: f64,
    /// `c_residual`: the cohesion softening stops at (default: 0).
    pub residual: Option<f64>,
}

impl CohesionHardening {
    /// The law with modulus `modulus` and residual `residual` for a material with initial
    /// cohesion `cohesion` and friction angle `friction_degrees`, or why it makes none.
    pub fn new(
        modulus: f64,
        residual: Option<f64>,
        cohesion: f64,
        friction_degrees: f64,
    ) -> Result<Self, String> {
        if !modulus.is_finite() {
            return Err(format!(
                "hardening modulus H must be a finite number, got {modulus}"
            ));
        }
        if let Some(r) = residual {
            if !(r >= 0.0 && r.is_finite()) {
                return Err(format!(
                    "residual cohesion c_residual must be zero or positive, got {r}"
                ));
            }
            if r > cohesion {
                return Err(format!(
                    "residual cohesion c_residual = {r} exceeds the cohesion c = {cohesion}: \
                     softening lowers c towards c_residual"
                ));
            }
        }
        if modulus < 0.0 && friction_degrees == 0.0 && residual.unwrap_or(0.0) <= 0.0 {
            return Err(format!(
                "softening (H = {modulus} < 0) of a frictionless material (phi = 0) needs a \
                 positive residual cohesion c_residual: at c = 0 it has no strength left"
            ));
        }
        Ok(Self { modulus, residual })
    }

    /// Whether the cohesion softens (`H < 0`).
    pub fn softens(&self) -> bool {
        self.modulus < 0.0
    }

    /// The cohesion softening stops at: `c_residual` (default 0) when `H < 0`, none otherwise.
    pub fn floor(&self) -> f64 {
        if self.softens() {
            self.residual.unwrap_or(0.0)
        } else {
            f64::NEG_INFINITY
        }
    }

    /// The smallest cohesion the law reaches from `cohesion`: the floor if it softens.
    pub fn lowest(&self, cohesion: f64) -> f64 {
        if self.softens() {
            self.floor()
        } else {
            cohesion
        }
    }

    /// `c(ε̄_p)` and the slope `dc/dε̄_p` of the branch at `ε̄_p` (the residual branch, slope 0,
    /// from where `c + H ε̄_p` reaches the floor on).
    pub fn branch(&self, cohesion: f64, plastic_strain: f64) -> (f64, f64) {
        let linear = cohesion + self.modulus * plastic_strain;
        if linear <= self.floor() {
            (self.floor(), 0.0)
        } else {
            (linear, self.modulus)
        }
    }

    /// `c(ε̄_p)`.
    pub fn cohesion_at(&self, cohesion: f64, plastic_strain: f64) -> f64 {
        self.branch(cohesion, plastic_strain).0
    }

    /// The return from the committed `plastic_strain` (module docs, the kink): `solve(c_n, h)`
    /// is the model's plastic return with the cohesion `c_n + h Δε̄_p`, giving its
    /// `plastic_strain_increment` `Δε̄_p`.
    pub fn return_on(
        &self,
        cohesion: f64,
        plastic_strain: f64,
        solve: impl Fn(f64, f64) -> Result<PrincipalReturn, String>,
    ) -> Result<PrincipalReturn, String> {
        let (start, slope) = self.branch(cohesion, plastic_strain);
        let returned = solve(start, slope)?;
        let increment = returned.plastic_strain_increment.unwrap_or(0.0);
        if slope < 0.0 && start + slope * increment < self.floor() {
            return solve(self.floor(), 0.0);
        }
        Ok(returned)
    }
}

/// Exponential softening of the cohesion, the friction angle and the dilation angle to their
/// residuals (module docs). Angles in radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StrengthSoftening {
    /// `η` of `e^{−η ε̄_p}`: the scene's `softening_rate`.
    pub rate: f64,
    /// `c_r`.
    pub cohesion: f64,
    /// `φ_r` (radians).
    pub friction: f64,
    /// `ψ_r` (radians).
    pub dilation: f64,
}

impl StrengthSoftening {
    /// The law with rate `rate` from the peaks `(c, φ, ψ)` to the residuals `(c_r, φ_r, ψ_r)`
    /// (angles in degrees), or why it makes none (module docs).
    pub fn new(
        rate: f64,
        peak: (f64, f64, f64),
        residual: (f64, f64, f64),
    ) -> Result<Self, String> {
        let (c, phi, psi) = peak;
        let (c_r, phi_r, psi_r) = residual;
        if !(rate > 0.0 && rate.is_finite()) {
            return Err(format!(
                "softening_rate must be positive and finite, got {rate}"
            ));
        }
        if !(c_r >= 0.0 && c_r.is_finite()) {
            return Err(format!(
                "residual cohesion c_residual must be zero or positive, got {c_r}"
            ));
        }
        if c_r > c {
            return Err(format!(
                "residual cohesion c_residual = {c_r} exceeds the cohesion c = {c}: softening lowers c towards c_residual"
            ));
        }
        if !(phi_r >= 0.0 && phi_r.is_finite()) {
            return Err(format!(
                "residual friction angle phi_residual must be zero or positive (degrees), got {phi_r}"
            ));
        }
        if phi_r > phi {
            return Err(format!(
                "residual friction angle phi_residual = {phi_r} exceeds the friction angle phi = {phi}: softening lowers phi towards phi_residual"
            ));
        }
        if !(psi_r >= 0.0 && psi_r.is_finite()) {
            return Err(format!(
                "residual dilation angle psi_residual must be zero or positive (degrees), got {psi_r}"
            ));
        }
        if psi_r > psi {
            return Err(format!(
                "residual dilation angle psi_residual = {psi_r} exceeds the dilation angle psi = {psi}: softening lowers psi towards psi_residual"
            ));
        }
        if psi_r > phi_r {
            return Err(format!(
                "residual dilation angle psi_residual = {psi_r} exceeds the residual friction angle phi_residual = {phi_r} (give psi_residual <= phi_residual)"
            ));
        }
        if c_r == 0.0 && phi_r == 0.0 {
            return Err(
                "c_residual = 0 and phi_residual = 0 leave the softened material without strength"
                    .into(),
            );
        }
        if c_r == c && phi_r == phi && psi_r == psi {
            return Err(format!(
                "softening_rate = {rate} without a residual below its peak (c_residual, phi_residual or psi_residual) softens nothing"
            ));
        }
        Ok(Self {
            rate,
            cohesion: c_r,
            friction: phi_r.to_radians(),
            dilation: psi_r.to_radians(),
        })
    }

    /// `x(ε̄_p)` and `x'(ε̄_p)` of the parameter with peak `peak` and residual `residual`.
    pub fn decay(&self, peak: f64, residual: f64, plastic_strain: f64) -> (f64, f64) {
        let drop = (peak - residual) * (-self.rate * plastic_strain).exp();
        (residual + drop, -self.rate * drop)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_law_is_linear_down_to_its_floor() {
        let soft = CohesionHardening::new(-50.0, Some(2.0), 10.0, 30.0).unwrap();
        assert_eq!(soft.branch(10.0, 0.1), (5.0, -50.0));
        assert_eq!(soft.branch(10.0, 0.2), (2.0, 0.0));
        assert_eq!(soft.cohesion_at(10.0, 1.0), 2.0);
        let floor0 = CohesionHardening::new(-50.0, None, 10.0, 30.0).unwrap();
        assert_eq!(floor0.cohesion_at(10.0, 1.0), 0.0);
        let hard = CohesionHardening::new(50.0, Some(2.0), 10.0, 30.0).unwrap();
        assert_eq!(hard.branch(10.0, 1.0), (60.0, 50.0));
        assert_eq!(hard.lowest(10.0), 10.0);
    }

    #[test]
    fn bad_laws_are_refused() {
        assert!(CohesionHardening::new(f64::NAN, None, 1.0, 30.0).is_err());
        assert!(CohesionHardening::new(-1.0, Some(2.0), 1.0, 30.0).is_err());
        assert!(CohesionHardening::new(-1.0, Some(-0.5), 1.0, 30.0).is_err());
        assert!(CohesionHardening::new(-1.0, Some(f64::INFINITY), 1.0, 30.0).is_err());
        assert!(CohesionHardening::new(-1.0, None, 1.0, 0.0).is_err());
        assert!(CohesionHardening::new(-1.0, Some(0.5), 1.0, 0.0).is_ok());
    }

    #[test]
    fn the_strength_decays_exponentially_to_its_residual() {
        let law = StrengthSoftening::new(8.0, (10.0, 30.0, 10.0), (2.0, 20.0, 0.0)).unwrap();
        assert_eq!(law.decay(10.0, 2.0, 0.0), (10.0, -64.0));
        let (value, slope) = law.decay(10.0, 2.0, 0.25);
        assert!((value - (2.0 + 8.0 * (-2.0f64).exp())).abs() < 1e-14);
        let h = 1e-6;
        let fd = (law.decay(10.0, 2.0, 0.25 + h).0 - law.decay(10.0, 2.0, 0.25 - h).0) / (2.0 * h);
        assert!((slope - fd).abs() < 1e-7 * slope.abs());
        assert!((law.decay(10.0, 2.0, 100.0).0 - 2.0).abs() < 1e-14);
        assert!((law.friction - 20f64.to_radians()).abs() < 1e-15);
    }

    #[test]
    fn bad_strength_softening_is_refused() {
        let peak = (10.0, 30.0, 10.0);
        let bad = [
            (0.0, (2.0, 20.0, 0.0), "softening_rate"),
            (-1.0, (2.0, 20.0, 0.0), "softening_rate"),
            (f64::INFINITY, (2.0, 20.0, 0.0), "softening_rate"),
            (8.0, (12.0, 20.0, 0.0), "c_residual"),
            (8.0, (-1.0, 20.0, 0.0), "c_residual"),
            (8.0, (2.0, 35.0, 0.0), "phi_residual"),
            (8.0, (2.0, -1.0, 0.0), "phi_residual"),
            (8.0, (2.0, 20.0, 12.0), "psi_residual"),
            (8.0, (2.0, 5.0, 8.0), "psi_residual"),
            (8.0, (0.0, 0.0, 0.0), "without strength"),
            (8.0, (10.0, 30.0, 10.0), "softens nothing"),
        ];
        for (rate, residual, word) in bad {
            let error = StrengthSoftening::new(rate, peak, residual).unwrap_err();
            assert!(error.contains(word), "{rate} {residual:?}: {error}");
        }
        assert!(StrengthSoftening::new(8.0, peak, (10.0, 30.0, 5.0)).is_ok());
        assert!(StrengthSoftening::new(8.0, peak, (0.0, 30.0, 10.0)).is_ok());
    }
}
