//! Drucker–Prager plasticity at finite strain (perfect, or with linear hardening or softening of
//! the cohesion), matched to Mohr–Coulomb.
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

use super::cohesion::CohesionHardening;
use super::elastoplastic::{
    self, PlasticHistory, PrincipalReturn, bulk_and_shear, deviator, deviatoric_projector,
};
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
            meaning: "residual cohesion softening (H < 0) stops at, 0 <= c_residual <= c (default 0; required > 0 when phi = 0)",
            label: Some("residual cohesion c_residual"),
            kind: ParameterKind::Number(Range::NonNegative),
            required: false,
        },
    ]);
    parameters
}

/// The shared parameters read: `(E, nu)` elasticity, `(c, φ, ψ)` (angles in degrees) and the
/// cohesion's hardening (`H`, `c_residual`).
pub struct Strength {
    pub elastic: Hencky,
    pub cohesion: f64,
    pub friction: f64,
    pub dilation: f64,
    pub hardening: CohesionHardening,
}

/// The [`Strength`] of the shared parameters.
pub fn read_strength(parameters: &MaterialParameters) -> Result<Strength, String> {
    let elastic = Hencky::from_parameters(parameters)?;
    let cohesion = parameters.number("c")?;
    let friction = parameters.number("phi")?;
    let dilation = parameters.optional_number("psi")?.unwrap_or(friction);
    check_strength(cohesion, friction, dilation)?;
    let hardening = CohesionHardening::new(
        parameters.optional_number("H")?.unwrap_or(0.0),
        parameters.optional_number("c_residual")?,
        cohesion,
        friction,
    )?;
    Ok(Strength {
        elastic,
        cohesion,
        friction,
        dilation,
        hardening,
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
        Self::new(
            strength.elastic,
            strength.cohesion,
            strength.friction,
            strength.dilation,
            matching,
        )?
        .with_hardening(strength.hardening)
    }

    fn describe() -> &'static str {
        "Drucker-Prager elasto-plasticity at finite strain (perfect, or linear hardening/softening of the cohesion down to a residual; cone and apex returns, associated or not), matched to Mohr-Coulomb"
    }

    elastoplastic::elastoplastic_material_methods!();

    fn tangent_is_symmetric(&self) -> bool {
        self.eta == self.eta_bar
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
