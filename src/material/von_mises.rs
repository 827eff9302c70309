//! von Mises (J2) plasticity at finite strain, perfect or with linear isotropic hardening.
//!
//! Yield function in principal Kirchhoff stresses (`q = √(3/2) ‖s‖`, `s` the deviator):
//!
//! ```text
//! Φ(τ, ε̄_p) = q − (σ_y + H ε̄_p)
//! ```
//!
//! Radial return (de Souza Neto et al., box 7.3) in principal logarithmic strain space
//! (`elastoplastic.rs`): with `e = dev ε^tr`, `N = e/‖e‖`, `q^tr = √6 G ‖e‖`,
//!
//! ```text
//! Δγ = Φ^tr / (3G + H),   β = 1 − 3G Δγ / q^tr,   τ = K tr ε^tr 1 + 2G β e,   ε̄_p += Δγ
//! D  = K 1⊗1 + 2G β (I − ⅓ 1⊗1) + (2G (1 − β) − 6G²/(3G + H)) N⊗N
//! ```
//!
//! The flow is associated and isochoric; the tangent is symmetric.
//!
//! **Tresca's undrained soil.** In plane strain the von Mises material at yield carries the
//! in-plane shear strength `s_u = σ_y/√3` (the out-of-plane stress is the mean of the in-plane
//! ones at plastic flow), so `s_u: ..` instead of `sigma_y` gives the undrained (Tresca) soil of
//! the classic plane-strain benchmarks (`σ_y = √3 s_u`). In 3D the two criteria differ.

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::elastoplastic::{
    self, PlasticHistory, PrincipalReturn, bulk_and_shear, deviator, deviatoric_projector,
};
use super::{Hencky, Material, MaterialParameters, ParameterKind, ParameterSpec, Range, Response};

/// von Mises plasticity with linear isotropic hardening (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VonMises {
    pub elastic: Hencky,
    /// Initial yield stress `σ_y` (uniaxial).
    pub yield_stress: f64,
    /// Hardening modulus `H`: the yield stress grows by `H ε̄_p`.
    pub hardening: f64,
}

impl VonMises {
    /// A von Mises material, or why the parameters make none.
    pub fn new(elastic: Hencky, yield_stress: f64, hardening: f64) -> Result<Self, String> {
        if !(yield_stress > 0.0 && yield_stress.is_finite()) {
            return Err(format!("yield stress must be positive, got {yield_stress}"));
        }
        if !(hardening >= 0.0 && hardening.is_finite()) {
            return Err(format!(
                "hardening modulus H must be zero or positive, got {hardening}"
            ));
        }
        Ok(Self {
            elastic,
            yield_stress,
            hardening,
        })
    }

    /// The principal-space radial return (module docs).
    pub fn return_map(
        &self,
        strain: &Vector3<f64>,
        trial_stress: &Vector3<f64>,
        plastic_strain: f64,
    ) -> PrincipalReturn {
        let (bulk, shear) = bulk_and_shear(&self.elastic);
        let e = deviator(strain);
        let norm = e.norm();
        let q_trial = 6.0f64.sqrt() * shear * norm;
        let radius = self.yield_stress + self.hardening * plastic_strain;
        let excess = q_trial - radius;
        if excess <= 1e-12 * radius {
            return PrincipalReturn::elastic(&self.elastic, *trial_stress);
        }
        let increment = excess / (3.0 * shear + self.hardening);
        let beta = 1.0 - 3.0 * shear * increment / q_trial;
        let mean = bulk * strain.sum();
        let n = e / norm;
        let tangent = Matrix3::from_element(bulk)
            + deviatoric_projector() * (2.0 * shear * beta)
            + n * n.transpose()
                * (2.0 * shear * (1.0 - beta)
                    - 6.0 * shear * shear / (3.0 * shear + self.hardening));
        PrincipalReturn {
            stress: e.map(|x| mean + 2.0 * shear * beta * x),
            tangent,
            pair_modulus: Some(2.0 * shear * beta),
            yielding: true,
            plastic_strain_increment: None,
        }
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
                meaning: "linear isotropic hardening modulus (default 0: perfect plasticity)",
                label: Some("hardening modulus H"),
                kind: ParameterKind::Number(Range::NonNegative),
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
        Self::new(
            elastic,
            yield_stress,
            parameters.optional_number("H")?.unwrap_or(0.0),
        )
    }

    fn describe() -> &'static str {
        "von Mises (J2) elasto-plasticity at finite strain (Hencky elasticity, exponential map), perfect or with linear isotropic hardening; s_u gives Tresca's undrained soil in plane strain"
    }

    elastoplastic::elastoplastic_material_methods!();
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
        Ok(self.return_map(strain, stress, alpha))
    }
}
