//! Drucker–Prager plasticity at finite strain (perfect, with linear hardening or softening of
//! the cohesion, or with exponential softening of c, φ and ψ), matched to Mohr–Coulomb.
//!
//! Tension positive, `p = ⅓ tr τ`, `J2 = ½ ‖s‖²`; yield function and plastic potential
//!
//! ```text
//! Φ = √J2 + η p − ξ c,      Ψ = √J2 + η̄ p
//! ```
//!
//! with `η, ξ` from the friction angle φ and `η̄` from the dilation angle ψ by one of the usual
//! matchings to Mohr–Coulomb (de Souza Neto et al., sec. 6.4.2):
//!
//! | `matching` | η (η̄ with ψ) | ξ |
//! |---|---|---|
//! | `outer` (compressive meridians) | 6 sin φ / (√3 (3 − sin φ)) | 6 cos φ / (√3 (3 − sin φ)) |
//! | `inner` (tensile meridians) | 6 sin φ / (√3 (3 + sin φ)) | 6 cos φ / (√3 (3 + sin φ)) |
//! | `plane_strain` (same collapse loads in plane strain) | 3 tan φ / √(9 + 12 tan² φ) | 3 / √(9 + 12 tan² φ) |
//!
//! Return in principal logarithmic strain space (`elastoplastic.rs`; de Souza Neto et al.,
//! box 8.9, without hardening). With `e = dev ε^tr`, `N = e/‖e‖`, `√J2^tr = √2 G ‖e‖`,
//! `p^tr = K tr ε^tr`, `A = 1/(G + K η η̄)`:
//!
//! ```text
//! cone    Δγ = A Φ^tr,   s = (1 − Δγ/(√2 ‖e‖)) 2G e,   p = p^tr − K η̄ Δγ      (if √J2^tr ≥ G Δγ)
//!         D = 2G β I_d + 2G (1 − β) N⊗N − A (√2 G N + K η̄ 1) ⊗ (√2 G N + K η 1) + K 1⊗1
//! apex    τ = (ξ c / η) 1,   D = 0                                              (otherwise)
//! ```
//!
//! (`β = 1 − Δγ/(√2 ‖e‖)`, `I_d = I − ⅓ 1⊗1`). `D` is symmetric only for associated flow
//! (`ψ = φ`).
//!
//! **Hardening and softening of the cohesion** (`H`, `c_residual`: `cohesion.rs`,
//! `c(ε̄_p) = max(c + H ε̄_p, c_r)`). The equivalent plastic strain is the usual
//! `Δε̄_p = √(2/3) ‖Δε_p‖`, which on the cone, `Δε_p = Δγ (N/√2 + η̄/3 1)`, is `k Δγ` with
//! `k = √(1/3 + 2η̄²/9)` exactly (de Souza Neto et al., box 8.9, take `ξ Δγ` instead: the same
//! law with `H` scaled by `k/ξ`). With the branch's cohesion `c_n` and slope `h` (0 on the
//! residual branch) the returns stay closed-form (boxes 8.9/8.10 with a linear `c`):
//!
//! ```text
//! cone    A = 1/(G + K η η̄ + ξ k h), Δγ = A Φ^tr(c_n), D as above with this A, Δε̄_p = k Δγ
//! apex    η̄ > 0: q = ξk/(η η̄), Δε_v^p = (p^tr − ξ c_n/η)/(K + q h), p = p^tr − K Δε_v^p,
//!                D = K q h/(K + q h) 1⊗1, Δε̄_p = k Δε_v^p/η̄  (the cone's Δγ = Δε_v^p/η̄)
//!         η̄ = 0, h > 0: p = p^tr (no volumetric flow), the apex hardens to it:
//!                Δγ = (η p^tr/ξ − c_n)/(k h), D = K 1⊗1
//!         η̄ = 0, h ≤ 0: no admissible stress keeps p^tr; the apex p = ξ c(ε̄_p^n + k Δγ)/η
//!                with Δγ = √J2^tr/G (the deviator removed), D = (√2 ξ k h/η) 1⊗N
//! ```
//!
//! The stress is continuous across the cone–apex boundary in each case. The return is unique
//! while `G + K η η̄ + ξ k H > 0` and, for `η, η̄ > 0`, `K η η̄ + ξ k H > 0` (the apex's
//! denominator, which implies the first): a steeper softening is refused
//! ([`DruckerPrager::with_hardening`]). The kink at `c_r` is `CohesionHardening::return_on`'s.
//!
//! **Exponential softening of c, φ and ψ** (`softening_rate`, `c_residual`, `phi_residual`,
//! `psi_residual`: `cohesion.rs`, Yerro, Alonso & Pinyol 2016): `c, φ, ψ` each decay as
//! `x(ε̄_p) = x_r + (x_p − x_r) e^{−η_s ε̄_p}`, so `η, ξ` (through φ), `η̄` and `k` (through ψ)
//! are functions of `ε̄_p` too, with the derivatives `η' = (dη/dφ) φ'` etc. of the matching
//! ([`Matching::slopes`]; outer `dη/dφ = (6/√3) 3 cos φ/(3 − sin φ)²`,
//! `dξ/dφ = (6/√3)(1 − 3 sin φ)/(3 − sin φ)²`; inner the same with `3 + sin φ` and
//! `dξ/dφ = −(6/√3)(1 + 3 sin φ)/(3 + sin φ)²`; plane strain `dη/dφ = 27 sec²φ/D³`,
//! `dξ/dφ = −36 tan φ sec²φ/D³`, `D = √(9 + 12 tan² φ)`) and `k' = 2η̄η̄'/(9k)`. Backward
//! Euler takes every parameter at the end of the step: the unknown is `x = Δε̄_p`,
//! `ε̄ = ε̄_p^n + x`, the multiplier `Δγ = x/k(ε̄)` (increasing in `x` since `k' ≤ 0`), and each
//! return is one scalar equation solved by the safeguarded Newton iteration shared with von
//! Mises (`hardening::decreasing_root`: bisection inside a bracket, `|r| ≤ 1e-12` of the trial's
//! stress scale):
//!
//! ```text
//! x*      the deviator removed: x*/k(ε̄_p^n + x*) = √J2^tr/G   (x* = k √J2^tr/G if ψ does not soften)
//! cone    r(x) = √J2^tr − G Δγ + η (p^tr − K η̄ Δγ) − ξ c = 0 on [0, x*]        (if r(x*) < 0)
//!         s = β 2G e, β = 1 − Δγ/(√2 ‖e‖),   p = p^tr − K η̄ Δγ
//!         D = 2G β I_d + 2G (1 − β) N⊗N + K 1⊗1 − (√2 G Δγ' N + K (η̄' Δγ + η̄ Δγ') 1) ⊗ (√2 G N + K η 1) / (−r')
//!         Δγ' = (1 − x k'/k)/k,  −r' = G Δγ' − η' p + K η (η̄' Δγ + η̄ Δγ') + ξ' c + ξ c'
//! apex    ψ > 0: r(x) = p^tr − K V(x) − A(x) = 0 on [x*, ∞), V = η̄ x/k (= Δε_v^p), A = ξ c/η
//!                p = p^tr − K V,  D = K A'/(K V' + A') 1⊗1
//!         ψ = 0: x = x*, p = A(ε̄_p^n + x*),  D = √2 k A' 1⊗N   (as without softening)
//! ```
//!
//! (`p` in `−r'` the returned mean stress; `N⊗` rows are the flow, `⊗(..)` columns `∂r/∂ε^tr`.) The
//! region test is exact: `r_cone(x*) = η r_apex(x*)`, so the cone root lies in `[0, x*]` when
//! `r_cone(x*) < 0` and the apex root beyond `x*` otherwise (its bracket is widened by doubling;
//! with `ψ_r = 0` the volumetric flow `V` saturates and a trial far in tension may have no apex
//! root: refused, the step is cut). The terms `η' p`, `ξ' c`, `ξ c'`, `η̄'`, `k'` are the
//! softening's in the tangent; without softening they vanish and `D` is the one above. A
//! non-positive `−r'` (the softening outweighs the elastic stiffness: friction softening at a
//! high confinement, `η' p > 0`) makes the root non-unique and is refused where met; the
//! cohesion's slope at `ε̄_p = 0` is checked against the limit of the linear law when the
//! material is built ([`DruckerPrager::with_softening`]). `tangent_is_symmetric` is false once φ
//! or ψ soften (the flow vector carries `η̄'`, `k'`).
//!
//! **In plane strain** (associated flow) the cone carries the in-plane loads of a Mohr–Coulomb
//! soil: with `ε_zz = 0` the flow rule fixes `τ_zz`, and the in-plane stresses at yield obey
//! Mohr–Coulomb with the angle and cohesion that the `plane_strain` row maps to `(η, ξ)`:
//!
//! ```text
//! tan φ' = 3η / √(9 − 12η²),      c' = ξ c √(9 + 12 tan² φ') / 3      (η < √3/2)
//! ```
//!
//! So `plane_strain` gives back φ and c, while the `outer` cone at φ = 20° (30°) is Mohr–Coulomb
//! with φ' = 27.5° (49.1°) and c' = 1.43 c (2.00 c) there: collapse loads several times too high
//! (the strip footing, docs/plasticity.md: 2.4 N_c at φ = 20°). For `η ≥ √3/2` (the outer cone
//! from φ = 36.9°) the cone has no plane-strain limit at all. [`DruckerPrager::plane_strain_mohr_coulomb`]
//! computes `(φ', c')`; a 2D scene that uses another matching is warned
//! (`scene::cone_matching_warnings`).
//!
//! The option was first called `match`, a reserved word in Rhai: `match: ".."` is a syntax
//! error, only the quoted key `"match": ".."` parses. `matching` replaces it; `"match"` stays
//! accepted as its alias so scenes written with it keep running (giving both is an error).

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::cohesion::{CohesionHardening, StrengthSoftening};
use super::elastoplastic::{
    self, PlasticHistory, PrincipalReturn, bulk_and_shear, deviator, deviatoric_projector,
};
use super::hardening::{MAX_ITERATIONS, RootFailure, TOLERANCE, decreasing_root};
use super::{
    Hencky, Material, MaterialParameters, ParameterKind, ParameterSpec, ParameterValue, Range,
    Response,
};

/// The former name of the `matching` option (module docs), still accepted.
pub const MATCHING_ALIAS: &str = "match";

/// How the cone is matched to Mohr–Coulomb (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Matching {
    Outer,
    Inner,
    PlaneStrain,
}

impl Matching {
    pub const WORDS: &'static [&'static str] = &["outer", "inner", "plane_strain"];

    /// `(η, ξ)` of the angle `angle` (radians).
    pub fn coefficients(self, angle: f64) -> (f64, f64) {
        let root3 = 3.0f64.sqrt();
        match self {
            Matching::Outer => {
                let d = root3 * (3.0 - angle.sin());
                (6.0 * angle.sin() / d, 6.0 * angle.cos() / d)
            }
            Matching::Inner => {
                let d = root3 * (3.0 + angle.sin());
                (6.0 * angle.sin() / d, 6.0 * angle.cos() / d)
            }
            Matching::PlaneStrain => {
                let d = (9.0 + 12.0 * angle.tan().powi(2)).sqrt();
                (3.0 * angle.tan() / d, 3.0 / d)
            }
        }
    }

    /// `(dη/dφ, dξ/dφ)` at the angle `angle` (radians; `dη̄/dψ` likewise): the derivatives of
    /// [`Matching::coefficients`] (module docs, "Exponential softening").
    pub fn slopes(self, angle: f64) -> (f64, f64) {
        let (sin, cos) = angle.sin_cos();
        let scale = 6.0 / 3.0f64.sqrt();
        match self {
            Matching::Outer => {
                let d = (3.0 - sin).powi(2);
                (scale * 3.0 * cos / d, scale * (1.0 - 3.0 * sin) / d)
            }
            Matching::Inner => {
                let d = (3.0 + sin).powi(2);
                (scale * 3.0 * cos / d, -scale * (1.0 + 3.0 * sin) / d)
            }
            Matching::PlaneStrain => {
                let tan = angle.tan();
                let d3 = (9.0 + 12.0 * tan * tan).powf(1.5);
                let secant2 = 1.0 + tan * tan;
                (27.0 / d3 * secant2, -36.0 * tan / d3 * secant2)
            }
        }
    }
}

/// The strength parameters of a softening material at one `ε̄_p`, with their derivatives
/// `d/dε̄_p` (module docs, "Exponential softening").
#[derive(Clone, Copy, Debug)]
struct Softened {
    cohesion: f64,
    cohesion_slope: f64,
    eta: f64,
    eta_slope: f64,
    xi: f64,
    xi_slope: f64,
    eta_bar: f64,
    eta_bar_slope: f64,
    /// `k = √(1/3 + 2η̄²/9)`.
    k: f64,
    k_slope: f64,
}

impl Softened {
    /// The apex `A = ξ c/η` and its slope.
    fn apex(&self) -> (f64, f64) {
        let apex = self.xi * self.cohesion / self.eta;
        let slope = (self.xi_slope * self.cohesion + self.xi * self.cohesion_slope) / self.eta
            - apex * self.eta_slope / self.eta;
        (apex, slope)
    }
}

/// Drucker–Prager perfect plasticity (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct DruckerPrager {
    pub elastic: Hencky,
    /// Cohesion `c`.
    pub cohesion: f64,
    /// Friction angle φ in radians.
    pub friction: f64,
    /// Dilation angle ψ in radians.
    pub dilation: f64,
    pub matching: Matching,
    /// `η` of the yield function.
    pub eta: f64,
    /// `ξ` of the yield function.
    pub xi: f64,
    /// `η̄` of the plastic potential.
    pub eta_bar: f64,
    /// The hardening or softening of the cohesion (default: none, perfect plasticity).
    pub hardening: CohesionHardening,
    /// The exponential softening of c, φ and ψ (default: none; module docs).
    pub softening: Option<StrengthSoftening>,
}

impl DruckerPrager {
    /// A Drucker–Prager material (angles in degrees), or why the parameters make none.
    pub fn new(
        elastic: Hencky,
        cohesion: f64,
        friction_degrees: f64,
        dilation_degrees: f64,
        matching: Matching,
    ) -> Result<Self, String> {
        check_strength(cohesion, friction_degrees, dilation_degrees)?;
        let (friction, dilation) = (friction_degrees.to_radians(), dilation_degrees.to_radians());
        let (eta, xi) = matching.coefficients(friction);
        let (eta_bar, _) = matching.coefficients(dilation);
        Ok(Self {
            elastic,
            cohesion,
            friction,
            dilation,
            matching,
            eta,
            xi,
            eta_bar,
            hardening: CohesionHardening::default(),
            softening: None,
        })
    }

    /// The Mohr–Coulomb angle φ' (radians) and cohesion c' whose plane-strain, associated
    /// collapse loads this cone has (module docs, "In plane strain"), or `None` if it has no
    /// plane-strain limit (`η ≥ √3/2`).
    pub fn plane_strain_mohr_coulomb(&self) -> Option<(f64, f64)> {
        let room = 9.0 - 12.0 * self.eta * self.eta;
        if room <= 0.0 {
            return None;
        }
        let tan = 3.0 * self.eta / room.sqrt();
        let cohesion = self.xi * self.cohesion * (9.0 + 12.0 * tan * tan).sqrt() / 3.0;
        Some((tan.atan(), cohesion))
    }

    /// The same material with the cohesion hardening or softening `hardening`, or why it
    /// makes none (a softening steeper than the limit of a unique return, module docs).
    pub fn with_hardening(mut self, hardening: CohesionHardening) -> Result<Self, String> {
        if hardening.softens() {
            let (bulk, shear) = bulk_and_shear(&self.elastic);
            let stiffness = if self.eta > 0.0 && self.eta_bar > 0.0 {
                bulk * self.eta * self.eta_bar
            } else {
                shear
            };
            let limit = -stiffness / (self.xi * self.strain_per_multiplier());
            if hardening.modulus <= limit {
                return Err(format!(
                    "softening modulus H = {} is steeper than this Drucker-Prager material \
                     allows (H > {limit:.6e}: beyond it the return is not unique)",
                    hardening.modulus
                ));
            }
        }
        self.hardening = hardening;
        Ok(self)
    }

    /// The same material with the exponential softening `softening` of c, φ and ψ (module docs),
    /// or why it makes none: with a linear cohesion law besides it, or a cohesion softening at
    /// `ε̄_p = 0` steeper than the limit of [`DruckerPrager::with_hardening`] (the other
    /// softening terms depend on the state: the return refuses a non-unique root where it meets
    /// one).
    pub fn with_softening(mut self, softening: StrengthSoftening) -> Result<Self, String> {
        if self.hardening.modulus != 0.0 {
            return Err(format!(
                "softening_rate and H = {} are two laws of the cohesion: give one",
                self.hardening.modulus
            ));
        }
        let (bulk, shear) = bulk_and_shear(&self.elastic);
        let stiffness = if self.eta > 0.0 && self.eta_bar > 0.0 {
            bulk * self.eta * self.eta_bar
        } else {
            shear
        };
        let steepest = -softening.rate * (self.cohesion - softening.cohesion);
        let limit = -stiffness / (self.xi * self.strain_per_multiplier());
        if steepest < 0.0 && steepest <= limit {
            return Err(format!(
                "softening_rate = {} softens the cohesion at dc/deps_p = {steepest:.6e}, steeper than this Drucker-Prager material allows (> {limit:.6e}: beyond it the return is not unique)",
                softening.rate
            ));
        }
        self.softening = Some(softening);
        Ok(self)
    }

    /// The softened parameters at `plastic_strain` (module docs, "Exponential softening").
    fn softened(&self, law: &StrengthSoftening, plastic_strain: f64) -> Softened {
        let (cohesion, cohesion_slope) = law.decay(self.cohesion, law.cohesion, plastic_strain);
        let (phi, phi_slope) = law.decay(self.friction, law.friction, plastic_strain);
        let (psi, psi_slope) = law.decay(self.dilation, law.dilation, plastic_strain);
        let (eta, xi) = self.matching.coefficients(phi);
        let (eta_phi, xi_phi) = self.matching.slopes(phi);
        let (eta_bar, _) = self.matching.coefficients(psi);
        let eta_bar_slope = self.matching.slopes(psi).0 * psi_slope;
        let k = (1.0 / 3.0 + 2.0 / 9.0 * eta_bar * eta_bar).sqrt();
        Softened {
            cohesion,
            cohesion_slope,
            eta,
            eta_slope: eta_phi * phi_slope,
            xi,
            xi_slope: xi_phi * phi_slope,
            eta_bar,
            eta_bar_slope,
            k,
            k_slope: 2.0 / 9.0 * eta_bar * eta_bar_slope / k,
        }
    }

    /// `k = √(1/3 + 2η̄²/9)`: the equivalent plastic strain per unit multiplier,
    /// `Δε̄_p = k Δγ = √(2/3) ‖Δε_p‖` on the cone (module docs).
    pub fn strain_per_multiplier(&self) -> f64 {
        (1.0 / 3.0 + 2.0 / 9.0 * self.eta_bar * self.eta_bar).sqrt()
    }

    /// The principal-space return from the committed equivalent plastic strain
    /// `plastic_strain` (module docs).
    pub fn return_map(
        &self,
        strain: &Vector3<f64>,
        trial_stress: &Vector3<f64>,
        plastic_strain: f64,
    ) -> Result<PrincipalReturn, String> {
        if let Some(law) = &self.softening {
            return self.softening_return(law, strain, trial_stress, plastic_strain);
        }
        let (bulk, shear) = bulk_and_shear(&self.elastic);
        let j2_trial = 2.0f64.sqrt() * shear * deviator(strain).norm();
        let p_trial = bulk * strain.sum();
        let strength = self.xi * self.hardening.cohesion_at(self.cohesion, plastic_strain);
        let excess = j2_trial + self.eta * p_trial - strength;
        let scale = strength + j2_trial + self.eta * p_trial.abs();
        if excess <= 1e-12 * scale {
            return Ok(PrincipalReturn::elastic(&self.elastic, *trial_stress));
        }
        self.hardening
            .return_on(self.cohesion, plastic_strain, |cohesion, slope| {
                Ok(self.plastic_return(strain, cohesion, slope))
            })
    }

    /// The return with the exponential softening `law` of c, φ, ψ from the committed
    /// `plastic_strain` (module docs, "Exponential softening"): the unknown is `x = Δε̄_p`.
    fn softening_return(
        &self,
        law: &StrengthSoftening,
        strain: &Vector3<f64>,
        trial_stress: &Vector3<f64>,
        plastic_strain: f64,
    ) -> Result<PrincipalReturn, String> {
        let (bulk, shear) = bulk_and_shear(&self.elastic);
        let e = deviator(strain);
        let norm = e.norm();
        let root2 = 2.0f64.sqrt();
        let j2_trial = root2 * shear * norm;
        let p_trial = bulk * strain.sum();
        let start = self.softened(law, plastic_strain);
        let strength = start.xi * start.cohesion;
        let excess = j2_trial + start.eta * p_trial - strength;
        let scale = strength + j2_trial + start.eta * p_trial.abs();
        if excess <= 1e-12 * scale {
            return Ok(PrincipalReturn::elastic(&self.elastic, *trial_stress));
        }
        let tolerance = TOLERANCE * scale;
        let failed = |what: &str, failure: RootFailure| match failure {
            RootFailure::NotDecreasing { at, derivative } => format!(
                "the softening Drucker-Prager {what} has no unique solution at eps_p = {:e}: the consistency condition's slope -r' = {derivative:e} is not positive (the softening of c, phi or psi outweighs the elastic stiffness there: a smaller softening_rate)",
                plastic_strain + at
            ),
            RootFailure::NoConvergence { at, residual } => format!(
                "the softening Drucker-Prager {what} did not converge in {MAX_ITERATIONS} iterations: residual {residual:e} at eps_p = {:e}",
                plastic_strain + at
            ),
        };
        let n = if norm > 0.0 {
            e / norm
        } else {
            Vector3::zeros()
        };
        let one = Vector3::repeat(1.0);
        // x*: the Δε̄_p whose multiplier x/k(ε̄_p^n + x) removes the deviator, Δγ = √J2^tr/G
        let removal = j2_trial / shear;
        let x_star = if norm == 0.0 {
            0.0
        } else if law.dilation < self.dilation {
            let upper = start.k * removal;
            decreasing_root((0.0, upper), TOLERANCE * upper, false, |x| {
                let at = self.softened(law, plastic_strain + x);
                (at.k * removal - x, 1.0 - at.k_slope * removal, ())
            })
            .map_err(|why| failed("deviator removal", why))?
            .0
        } else {
            start.k * removal
        };
        // the cone: r(x) = √J2^tr − G Δγ + η (p^tr − K η̄ Δγ) − ξ c, Δγ = x/k, all at ε̄_p^n + x
        let cone = |x: f64| {
            let at = self.softened(law, plastic_strain + x);
            let multiplier = x / at.k;
            let multiplier_slope = (1.0 - x * at.k_slope / at.k) / at.k;
            let mean = p_trial - bulk * at.eta_bar * multiplier;
            let mean_slope =
                -bulk * (at.eta_bar_slope * multiplier + at.eta_bar * multiplier_slope);
            let residual = j2_trial - shear * multiplier + at.eta * mean - at.xi * at.cohesion;
            let slope = -shear * multiplier_slope + at.eta_slope * mean + at.eta * mean_slope
                - (at.xi_slope * at.cohesion + at.xi * at.cohesion_slope);
            (
                residual,
                -slope,
                (at, multiplier, multiplier_slope, mean, mean_slope, -slope),
            )
        };
        if norm > 0.0 && cone(x_star).0 < 0.0 {
            let (x, (at, multiplier, multiplier_slope, mean, mean_slope, denominator)) =
                decreasing_root((0.0, x_star), tolerance, false, cone)
                    .map_err(|why| failed("cone return", why))?;
            let beta = 1.0 - multiplier / (root2 * norm);
            let flow = n * (root2 * shear * multiplier_slope) - one * mean_slope;
            let normal = n * (root2 * shear) + one * (bulk * at.eta);
            let tangent = deviatoric_projector() * (2.0 * shear * beta)
                + n * n.transpose() * (2.0 * shear * (1.0 - beta))
                - flow * normal.transpose() / denominator
                + Matrix3::from_element(bulk);
            return Ok(PrincipalReturn {
                stress: e.map(|v| mean + 2.0 * shear * beta * v),
                tangent,
                pair_modulus: Some(2.0 * shear * beta),
                yielding: true,
                plastic_strain_increment: Some(x),
            });
        }
        let (mean, tangent, increment) = if self.dilation == 0.0 {
            // ψ ≡ 0: no volumetric flow; the deviator removed (x = x* = k √J2^tr/G, k = √(1/3))
            // and p at the apex there (as without softening, module docs)
            let at = self.softened(law, plastic_strain + x_star);
            let (apex, apex_slope) = at.apex();
            (
                apex,
                one * n.transpose() * (apex_slope * at.k * root2),
                x_star,
            )
        } else {
            // the apex: r(x) = p^tr − K V(x) − A(x), V = η̄ x/k (= Δε_v^p), A = ξ c/η
            let apex = |x: f64| {
                let at = self.softened(law, plastic_strain + x);
                let volumetric = at.eta_bar * x / at.k;
                let volumetric_slope =
                    (at.eta_bar_slope * x + at.eta_bar) / at.k - volumetric * at.k_slope / at.k;
                let (apex, apex_slope) = at.apex();
                let denominator = bulk * volumetric_slope + apex_slope;
                (
                    p_trial - bulk * volumetric - apex,
                    denominator,
                    (p_trial - bulk * volumetric, apex_slope, denominator),
                )
            };
            let mut width = (apex(x_star).0.max(0.0) * start.k / (bulk * start.eta_bar))
                .max(x_star)
                .max(f64::MIN_POSITIVE);
            let mut bracketed = false;
            for _ in 0..200 {
                if apex(x_star + width).0 <= 0.0 {
                    bracketed = true;
                    break;
                }
                width *= 2.0;
            }
            if !bracketed {
                return Err(format!(
                    "the softening Drucker-Prager apex return has no solution from eps_p = {plastic_strain:e}: the trial mean stress {p_trial:e} lies beyond what the plastic dilation left by psi_residual can relieve"
                ));
            }
            let (x, (mean, apex_slope, denominator)) =
                decreasing_root((x_star, x_star + width), tolerance, false, apex)
                    .map_err(|why| failed("apex return", why))?;
            (
                mean,
                Matrix3::from_element(bulk * apex_slope / denominator),
                x,
            )
        };
        Ok(PrincipalReturn {
            stress: Vector3::repeat(mean),
            tangent,
            pair_modulus: Some(0.0),
            yielding: true,
            plastic_strain_increment: Some(increment),
        })
    }

    /// The cone or apex return with the cohesion `cohesion + slope Δε̄_p` (module docs).
    fn plastic_return(&self, strain: &Vector3<f64>, cohesion: f64, slope: f64) -> PrincipalReturn {
        let (bulk, shear) = bulk_and_shear(&self.elastic);
        let e = deviator(strain);
        let norm = e.norm();
        let root2 = 2.0f64.sqrt();
        let j2_trial = root2 * shear * norm;
        let p_trial = bulk * strain.sum();
        let k = self.strain_per_multiplier();
        let excess = j2_trial + self.eta * p_trial - self.xi * cohesion;
        let a = 1.0 / (shear + bulk * self.eta * self.eta_bar + self.xi * k * slope);
        let increment = a * excess;
        let n = if norm > 0.0 {
            e / norm
        } else {
            Vector3::zeros()
        };
        let one = Vector3::repeat(1.0);
        if j2_trial - shear * increment >= 0.0 && norm > 0.0 {
            let beta = 1.0 - increment / (root2 * norm);
            let flow = n * (root2 * shear) + one * (bulk * self.eta_bar);
            let normal = n * (root2 * shear) + one * (bulk * self.eta);
            let tangent = deviatoric_projector() * (2.0 * shear * beta)
                + n * n.transpose() * (2.0 * shear * (1.0 - beta))
                - flow * normal.transpose() * a
                + Matrix3::from_element(bulk);
            let mean = p_trial - bulk * self.eta_bar * increment;
            return PrincipalReturn {
                stress: e.map(|x| mean + 2.0 * shear * beta * x),
                tangent,
                pair_modulus: Some(2.0 * shear * beta),
                yielding: true,
                plastic_strain_increment: Some(k * increment),
            };
        }
        // The apex (only reachable with friction, η > 0: at η = 0, √J2 − G Δγ = ξ c > 0).
        let (mean, tangent, multiplier) = if self.eta_bar > 0.0 {
            // p = p^tr − K Δε_v^p = (ξ/η) c(ε̄_p^n + k Δε_v^p/η̄), Δγ = Δε_v^p/η̄
            let q = self.xi * k / (self.eta * self.eta_bar);
            let volumetric = (p_trial - self.xi * cohesion / self.eta) / (bulk + q * slope);
            let modulus = bulk * q * slope / (bulk + q * slope);
            (
                p_trial - bulk * volumetric,
                Matrix3::from_element(modulus),
                volumetric / self.eta_bar,
            )
        } else if slope > 0.0 {
            // no volumetric flow (ψ = 0), hardening: p = p^tr, the cohesion hardens until the
            // apex reaches it, (ξ/η) c(ε̄_p^n + k Δγ) = p^tr (Δγ > √J2^tr/G here)
            (
                p_trial,
                Matrix3::from_element(bulk),
                (self.eta * p_trial / self.xi - cohesion) / (k * slope),
            )
        } else {
            // no volumetric flow (ψ = 0), perfect or softening: no stress at p^tr is
            // admissible; the apex with the multiplier that removes the deviator,
            // Δγ = √J2^tr/G, and p = (ξ/η) c(ε̄_p^n + k Δγ)
            let multiplier = j2_trial / shear;
            let gain = self.xi * slope * k / self.eta;
            (
                self.xi * (cohesion + slope * k * multiplier) / self.eta,
                one * n.transpose() * (gain * root2),
                multiplier,
            )
        };
        PrincipalReturn {
            stress: Vector3::repeat(mean),
            tangent,
            pair_modulus: Some(0.0),
            yielding: true,
            plastic_strain_increment: Some(k * multiplier),
        }
    }
}

/// The checks shared by the frictional models: `c ≥ 0`, `0 ≤ ψ ≤ φ < 90°`, and some strength.
pub fn check_strength(cohesion: f64, friction: f64, dilation: f64) -> Result<(), String> {
    if !(cohesion >= 0.0 && cohesion.is_finite()) {
        return Err(format!(
            "cohesion c must be zero or positive, got {cohesion}"
        ));
    }
    if !((0.0..90.0).contains(&friction)) {
        return Err(format!(
            "friction angle phi must satisfy 0 <= phi < 90 (degrees), got {friction}"
        ));
    }
    if !((0.0..90.0).contains(&dilation)) {
        return Err(format!(
            "dilation angle psi must satisfy 0 <= psi < 90 (degrees), got {dilation}"
        ));
    }
    if dilation > friction {
        return Err(format!(
            "dilation angle psi = {dilation} must not exceed the friction angle phi = {friction}"
        ));
    }
    if cohesion == 0.0 && friction == 0.0 {
        return Err("c = 0 and phi = 0 leave the material without strength".into());
    }
    Ok(())
}

/// The parameters shared by the frictional models: Hencky's `E`, `nu`, then `c`, `phi`, `psi`.
pub fn strength_parameters() -> Vec<ParameterSpec> {
    let mut parameters = Hencky::parameters();
    parameters.extend([
        ParameterSpec {
            name: "c",
            meaning: "cohesion",
            label: Some("cohesion c"),
            kind: ParameterKind::Number(Range::NonNegative),
            required: true,
        },
        ParameterSpec {
            name: "phi",
            meaning: "friction angle in degrees",
            label: Some("friction angle phi"),
            kind: ParameterKind::Number(Range::ClosedOpen(0.0, 90.0)),
            required: true,
        },
        ParameterSpec {
            name: "psi",
            meaning: "dilation angle in degrees, at most phi (default phi: associated flow)",
            label: Some("dilation angle psi"),
            kind: ParameterKind::Number(Range::ClosedOpen(0.0, 90.0)),
            required: false,
        },
        ParameterSpec {
            name: "H",
            meaning: "linear isotropic hardening (H > 0) or softening (H < 0) modulus of the cohesion, c + H eps_p (default 0: perfect plasticity); softening is mesh-dependent",
            label: Some("cohesion hardening modulus H"),
            kind: ParameterKind::Number(Range::Any),
            required: false,
        },
        ParameterSpec {
            name: "c_residual",
            meaning: "residual cohesion: where the linear softening (H < 0) stops, 0 <= c_residual <= c (default 0; required > 0 when phi = 0), or the residual of the exponential softening (softening_rate; default c: c does not soften)",
            label: Some("residual cohesion c_residual"),
            kind: ParameterKind::Number(Range::NonNegative),
            required: false,
        },
        ParameterSpec {
            name: "softening_rate",
            meaning: "drucker_prager only (mohr_coulomb refuses it: not implemented there): the shape factor eta > 0 of the exponential softening of c, phi and psi to c_residual, phi_residual, psi_residual, x = x_r + (x_p - x_r) exp(-eta eps_p) (Yerro et al. 2016; no H with it; mesh-dependent)",
            label: Some("softening rate softening_rate"),
            kind: ParameterKind::Number(Range::Positive),
            required: false,
        },
        ParameterSpec {
            name: "phi_residual",
            meaning: "drucker_prager only, with softening_rate: residual friction angle in degrees, 0 <= phi_residual <= phi (default phi: phi does not soften)",
            label: Some("residual friction angle phi_residual"),
            kind: ParameterKind::Number(Range::ClosedOpen(0.0, 90.0)),
            required: false,
        },
        ParameterSpec {
            name: "psi_residual",
            meaning: "drucker_prager only, with softening_rate: residual dilation angle in degrees, 0 <= psi_residual <= psi and <= phi_residual (default psi, or phi_residual when psi is not given: associated flow stays associated)",
            label: Some("residual dilation angle psi_residual"),
            kind: ParameterKind::Number(Range::ClosedOpen(0.0, 90.0)),
            required: false,
        },
    ]);
    parameters
}

/// The options of the exponential softening of c, φ, ψ, which only Drucker–Prager has.
pub const SOFTENING_OPTIONS: [&str; 3] = ["softening_rate", "phi_residual", "psi_residual"];

/// The shared parameters read: `(E, nu)` elasticity, `(c, φ, ψ)` (angles in degrees), the
/// cohesion's hardening (`H`, `c_residual`) and the exponential softening of c, φ, ψ
/// (`softening_rate`, `c_residual`, `phi_residual`, `psi_residual`; `cohesion.rs`).
pub struct Strength {
    pub elastic: Hencky,
    pub cohesion: f64,
    pub friction: f64,
    pub dilation: f64,
    pub hardening: CohesionHardening,
    pub softening: Option<StrengthSoftening>,
}

impl Strength {
    /// Whether a strength parameter falls with plastic strain.
    pub fn softens(&self) -> bool {
        self.hardening.softens() || self.softening.is_some()
    }
}

/// The [`Strength`] of the shared parameters.
pub fn read_strength(parameters: &MaterialParameters) -> Result<Strength, String> {
    let elastic = Hencky::from_parameters(parameters)?;
    let cohesion = parameters.number("c")?;
    let friction = parameters.number("phi")?;
    let dilation = parameters.optional_number("psi")?.unwrap_or(friction);
    check_strength(cohesion, friction, dilation)?;
    let modulus = parameters.optional_number("H")?.unwrap_or(0.0);
    let residual = parameters.optional_number("c_residual")?;
    let softening = match parameters.optional_number("softening_rate")? {
        None => {
            if let Some(key) = ["phi_residual", "psi_residual"]
                .into_iter()
                .find(|key| parameters.get(key).is_some())
            {
                return Err(format!(
                    "{key} needs softening_rate (the exponential softening of c, phi and psi): give softening_rate, or leave {key} out"
                ));
            }
            None
        }
        Some(rate) => {
            if modulus != 0.0 {
                return Err(format!(
                    "softening_rate and H = {modulus} are two laws of the cohesion: give one (c_residual is the residual of either)"
                ));
            }
            let phi_residual = parameters
                .optional_number("phi_residual")?
                .unwrap_or(friction);
            let psi_residual = match parameters.optional_number("psi_residual")? {
                Some(given) => given,
                None if parameters.get("psi").is_some() => dilation,
                None => phi_residual,
            };
            Some(StrengthSoftening::new(
                rate,
                (cohesion, friction, dilation),
                (residual.unwrap_or(cohesion), phi_residual, psi_residual),
            )?)
        }
    };
    let hardening = CohesionHardening::new(modulus, residual, cohesion, friction)?;
    Ok(Strength {
        elastic,
        cohesion,
        friction,
        dilation,
        hardening,
        softening,
    })
}

impl Material for DruckerPrager {
    type History = PlasticHistory;
    const MODEL: &'static str = "drucker_prager";

    fn parameters() -> Vec<ParameterSpec> {
        let mut parameters = strength_parameters();
        parameters.extend([
            ParameterSpec {
                name: "matching",
                meaning: "matching to Mohr-Coulomb: outer (compressive meridians, default), inner (tensile meridians) or plane_strain (same plane-strain collapse loads)",
                label: Some("matching to Mohr-Coulomb"),
                kind: ParameterKind::Word(Matching::WORDS),
                required: false,
            },
            ParameterSpec {
                name: MATCHING_ALIAS,
                meaning: "the former name of matching, accepted so older scenes run; match is a reserved word in Rhai, so only the quoted key \"match\": .. parses (write matching)",
                label: Some("matching to Mohr-Coulomb (\"match\")"),
                kind: ParameterKind::Word(Matching::WORDS),
                required: false,
            },
        ]);
        parameters
    }

    fn from_parameters(parameters: &MaterialParameters) -> Result<Self, String> {
        let strength = read_strength(parameters)?;
        let (key, given) = match (parameters.get("matching"), parameters.get(MATCHING_ALIAS)) {
            (Some(_), Some(_)) => {
                return Err("give matching or its former name \"match\", not both".to_string());
            }
            (Some(given), None) => ("matching", Some(given)),
            (None, Some(given)) => (MATCHING_ALIAS, Some(given)),
            (None, None) => ("matching", None),
        };
        let matching = match given {
            None => Matching::Outer,
            Some(ParameterValue::Text(word)) => match word.as_str() {
                "outer" => Matching::Outer,
                "inner" => Matching::Inner,
                "plane_strain" => Matching::PlaneStrain,
                other => {
                    return Err(format!(
                        "{key} must be one of {:?}, got '{other}'",
                        Matching::WORDS
                    ));
                }
            },
            Some(other) => return Err(format!("{key} must be a word, got {other:?}")),
        };
        let model = Self::new(
            strength.elastic,
            strength.cohesion,
            strength.friction,
            strength.dilation,
            matching,
        )?
        .with_hardening(strength.hardening)?;
        match strength.softening {
            Some(softening) => model.with_softening(softening),
            None => Ok(model),
        }
    }

    fn describe() -> &'static str {
        "Drucker-Prager elasto-plasticity at finite strain (perfect, linear hardening/softening of the cohesion down to a residual, or exponential softening of c, phi and psi to residuals; cone and apex returns, associated or not), matched to Mohr-Coulomb"
    }

    elastoplastic::elastoplastic_material_methods!();

    fn tangent_is_symmetric(&self) -> bool {
        // a softening friction or dilation adds dη̄/dε̄_p, dk/dε̄_p to the flow vector only
        self.eta == self.eta_bar
            && self
                .softening
                .is_none_or(|law| law.friction == self.friction && law.dilation == self.dilation)
    }
}

impl elastoplastic::PrincipalReturnMap for DruckerPrager {
    fn elasticity(&self) -> &Hencky {
        &self.elastic
    }

    fn principal_return(
        &self,
        strain: &Vector3<f64>,
        stress: &Vector3<f64>,
        alpha: f64,
    ) -> Result<PrincipalReturn, String> {
        self.return_map(strain, stress, alpha)
    }
}
