//! von Mises (J2) plasticity at finite strain: perfect, with linear, saturating (Voce) or
//! non-linear isotropic hardening, or with exponential strain softening to a residual.
//!
//! Yield function in principal Kirchhoff stresses (`q = √(3/2) ‖s‖`, `s` the deviator):
//!
//! ```text
//! Φ(τ, ε̄_p) = q − σ_y(ε̄_p)
//! ```
//!
//! with the hardening law `σ_y(ε̄_p)` and its slope `H(ε̄_p)` of `hardening.rs` (linear
//! `σ_y0 + H ε̄_p`, the default; `voce`; `exponential_softening`, Einav & Randolph's law of
//! sensitive clays).
//!
//! Radial return (de Souza Neto et al., boxes 7.3 and 7.4) in principal logarithmic strain space
//! (`elastoplastic.rs`): with `e = dev ε^tr`, `N = e/‖e‖`, `q^tr = √6 G ‖e‖`, the multiplier
//! `Δγ` (`= Δε̄_p`) the root of `q^tr − 3G Δγ − σ_y(ε̄_p^n + Δγ) = 0` (closed form
//! `Φ^tr / (3G + H)` for the linear law; a safeguarded scalar Newton otherwise,
//! `IsotropicHardening::radial_return`), and `H = H(ε̄_p^n + Δγ)`:
//!
//! ```text
//! β = 1 − 3G Δγ / q^tr,   τ = K tr ε^tr 1 + 2G β e,   ε̄_p += Δγ
//! D  = K 1⊗1 + 2G β (I − ⅓ 1⊗1) + (2G (1 − β) − 6G²/(3G + H)) N⊗N
//! ```
//!
//! The flow is associated and isochoric; the tangent is symmetric. A softening law is refused
//! when the return would not be unique (`3G + H > 0` must hold at its steepest, `ε̄_p = 0`), and
//! a scene with one is warned that softening is mesh-dependent (`scene::softening_warnings`).
//!
//! **Tresca's undrained soil.** In plane strain the von Mises material at yield carries the
//! in-plane shear strength `s_u = σ_y/√3` (the out-of-plane stress is the mean of the in-plane
//! ones at plastic flow), so `s_u: ..` instead of `sigma_y` gives the undrained (Tresca) soil of
//! the classic plane-strain benchmarks (`σ_y = √3 s_u`). In 3D the two criteria differ. The
//! softening law is a ratio of the initial strength, so it reads the same in `s_u` and `σ_y`;
//! `sigma_inf` (Voce) is a uniaxial yield stress like `sigma_y` (`√3` times a shear strength).

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::elastoplastic::{
    self, PlasticHistory, PrincipalReturn, bulk_and_shear, deviator, deviatoric_projector,
};
use super::hardening::IsotropicHardening;
use super::{
    Hencky, Material, MaterialParameters, ParameterKind, ParameterSpec, ParameterValue, Range,
    Response,
};

/// von Mises plasticity with isotropic hardening or softening (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VonMises {
    pub elastic: Hencky,
    /// Initial yield stress `σ_y0` (uniaxial).
    pub yield_stress: f64,
    /// The hardening law `σ_y(ε̄_p)` (default linear, `H = 0`: perfect plasticity).
    pub hardening: IsotropicHardening,
}

impl VonMises {
    /// A von Mises material with linear hardening `H ε̄_p`, or why the parameters make none.
    pub fn new(elastic: Hencky, yield_stress: f64, hardening: f64) -> Result<Self, String> {
        Self::with_law(
            elastic,
            yield_stress,
            IsotropicHardening::linear(hardening)?,
        )
    }

    /// A von Mises material with the hardening law `law`, or why it makes none (a softening
    /// steeper than a unique return allows, module docs).
    pub fn with_law(
        elastic: Hencky,
        yield_stress: f64,
        law: IsotropicHardening,
    ) -> Result<Self, String> {
        if !(yield_stress > 0.0 && yield_stress.is_finite()) {
            return Err(format!("yield stress must be positive, got {yield_stress}"));
        }
        if let IsotropicHardening::Voce { saturation, .. } = law
            && saturation < yield_stress
        {
            return Err(format!(
                "saturation yield stress sigma_inf = {saturation} is below the initial yield stress {yield_stress} (voce hardening saturates above it)"
            ));
        }
        let (_, shear) = bulk_and_shear(&elastic);
        let steepest = law.steepest_slope(yield_stress);
        if 3.0 * shear + steepest <= 0.0 {
            return Err(format!(
                "the {} softening is steeper than this material allows: its slope {steepest:.6e} at eps_p = 0 must exceed -3G = {:.6e} (a larger xi95 or residual_ratio; beyond it the return is not unique)",
                law.word(),
                -3.0 * shear
            ));
        }
        Ok(Self {
            elastic,
            yield_stress,
            hardening: law,
        })
    }

    /// The principal-space radial return (module docs).
    pub fn return_map(
        &self,
        strain: &Vector3<f64>,
        trial_stress: &Vector3<f64>,
        plastic_strain: f64,
    ) -> Result<PrincipalReturn, String> {
        let (bulk, shear) = bulk_and_shear(&self.elastic);
        let e = deviator(strain);
        let norm = e.norm();
        let q_trial = 6.0f64.sqrt() * shear * norm;
        let (radius, _) = self.hardening.branch(self.yield_stress, plastic_strain);
        let excess = q_trial - radius;
        if excess <= 1e-12 * radius {
            return Ok(PrincipalReturn::elastic(&self.elastic, *trial_stress));
        }
        let (increment, slope) = self.hardening.radial_return(
            self.yield_stress,
            plastic_strain,
            q_trial,
            3.0 * shear,
        )?;
        let beta = 1.0 - 3.0 * shear * increment / q_trial;
        let mean = bulk * strain.sum();
        let n = e / norm;
        let tangent = Matrix3::from_element(bulk)
            + deviatoric_projector() * (2.0 * shear * beta)
            + n * n.transpose()
                * (2.0 * shear * (1.0 - beta) - 6.0 * shear * shear / (3.0 * shear + slope));
        Ok(PrincipalReturn {
            stress: e.map(|x| mean + 2.0 * shear * beta * x),
            tangent,
            pair_modulus: Some(2.0 * shear * beta),
            yielding: true,
            plastic_strain_increment: None,
        })
    }
}

impl Material for VonMises {
    type History = PlasticHistory;
    const MODEL: &'static str = "von_mises";

    fn parameters() -> Vec<ParameterSpec> {
        let mut parameters = Hencky::parameters();
        parameters.extend([
            ParameterSpec {
                name: "sigma_y",
                meaning: "uniaxial yield stress (give it or s_u)",
                label: Some("yield stress sigma_y"),
                kind: ParameterKind::Number(Range::Positive),
                required: false,
            },
            ParameterSpec {
                name: "s_u",
                meaning: "undrained shear strength: sigma_y = sqrt(3) s_u, Tresca's soil in plane strain (give it or sigma_y)",
                label: Some("undrained shear strength s_u"),
                kind: ParameterKind::Number(Range::Positive),
                required: false,
            },
            ParameterSpec {
                name: "H",
                meaning: "linear isotropic hardening modulus, sigma_y + H eps_p (default 0: perfect plasticity); with hardening: \"voce\" the linear term added to the saturation",
                label: Some("hardening modulus H"),
                kind: ParameterKind::Number(Range::NonNegative),
                required: false,
            },
            ParameterSpec {
                name: "hardening",
                meaning: "the hardening law: linear (default, H), voce (saturation: sigma_inf, delta, H) or exponential_softening (to a residual: residual_ratio, xi95; Einav & Randolph 2005, mesh-dependent)",
                label: Some("hardening law"),
                kind: ParameterKind::Word(IsotropicHardening::WORDS),
                required: false,
            },
            ParameterSpec {
                name: "sigma_inf",
                meaning: "voce: the saturation yield stress (uniaxial, at least sigma_y), sigma_y + (sigma_inf - sigma_y)(1 - exp(-delta eps_p)) + H eps_p",
                label: Some("saturation yield stress sigma_inf"),
                kind: ParameterKind::Number(Range::Positive),
                required: false,
            },
            ParameterSpec {
                name: "delta",
                meaning: "voce: the saturation rate, per unit eps_p",
                label: Some("saturation rate delta"),
                kind: ParameterKind::Number(Range::Positive),
                required: false,
            },
            ParameterSpec {
                name: "residual_ratio",
                meaning: "exponential_softening: the remoulded (residual) strength as a ratio of the initial one, 0 < residual_ratio <= 1 (1/sensitivity)",
                label: Some("residual strength ratio residual_ratio"),
                kind: ParameterKind::Number(Range::Positive),
                required: false,
            },
            ParameterSpec {
                name: "xi95",
                meaning: "exponential_softening: the accumulated plastic shear strain xi = sqrt(3) eps_p at which 95 % of the softening has taken place; strength [r + (1 - r) exp(-3 xi/xi95)] s_u",
                label: Some("xi95"),
                kind: ParameterKind::Number(Range::Positive),
                required: false,
            },
        ]);
        parameters
    }

    fn from_parameters(parameters: &MaterialParameters) -> Result<Self, String> {
        let elastic = Hencky::from_parameters(parameters)?;
        let yield_stress = match (
            parameters.optional_number("sigma_y")?,
            parameters.optional_number("s_u")?,
        ) {
            (Some(sigma_y), None) => sigma_y,
            (None, Some(s_u)) => 3.0f64.sqrt() * s_u,
            (Some(_), Some(_)) => {
                return Err(
                    "give the yield stress sigma_y or the undrained strength s_u, not both".into(),
                );
            }
            (None, None) => {
                return Err("missing parameter 'sigma_y' (or 's_u')".into());
            }
        };
        Self::with_law(elastic, yield_stress, read_law(parameters)?)
    }

    fn describe() -> &'static str {
        "von Mises (J2) elasto-plasticity at finite strain (Hencky elasticity, exponential map), perfect, with linear or Voce isotropic hardening, or softening exponentially to a residual (sensitive clay); s_u gives Tresca's undrained soil in plane strain"
    }

    elastoplastic::elastoplastic_material_methods!();
}

/// The hardening law of the parameters (`hardening` and its own parameters; the others' refused,
/// so a parameter that would be ignored is an error).
fn read_law(parameters: &MaterialParameters) -> Result<IsotropicHardening, String> {
    let word = match parameters.get("hardening") {
        None => "linear",
        Some(ParameterValue::Text(word)) => word.as_str(),
        Some(other) => return Err(format!("hardening must be a word, got {other:?}")),
    };
    let own: &[&str] = match word {
        "linear" => &["H"],
        "voce" => &["sigma_inf", "delta", "H"],
        "exponential_softening" => &["residual_ratio", "xi95"],
        other => {
            return Err(format!(
                "hardening must be one of {:?}, got '{other}'",
                IsotropicHardening::WORDS
            ));
        }
    };
    for name in ["H", "sigma_inf", "delta", "residual_ratio", "xi95"] {
        if !own.contains(&name) && parameters.get(name).is_some() {
            let of = match name {
                "H" => "hardening: \"linear\" or \"voce\"",
                "sigma_inf" | "delta" => "hardening: \"voce\"",
                _ => "hardening: \"exponential_softening\"",
            };
            return Err(format!(
                "{name} is a parameter of {of}, not of hardening: \"{word}\""
            ));
        }
    }
    let required = |name: &str| {
        parameters
            .optional_number(name)?
            .ok_or_else(|| format!("hardening: \"{word}\" needs the parameter '{name}'"))
    };
    let modulus = parameters.optional_number("H")?.unwrap_or(0.0);
    match word {
        "voce" => IsotropicHardening::voce(required("sigma_inf")?, required("delta")?, modulus),
        "exponential_softening" => IsotropicHardening::exponential_softening(
            required("residual_ratio")?,
            required("xi95")?,
        ),
        _ => IsotropicHardening::linear(modulus),
    }
}

impl elastoplastic::PrincipalReturnMap for VonMises {
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
