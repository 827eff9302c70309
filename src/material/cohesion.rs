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
}
