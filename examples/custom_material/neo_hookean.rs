//! A compressible neo-Hookean solid, written against `impm::material::Material` outside the
//! crate (shared by `examples/custom_material` and `tests/materials.rs`).
//!
//! ```text
//!   τ = μ (b − I) + λ ln J I,        J = √det b,
//!   c_abkd = 2 ∂τ_ab/∂b_kd = μ (δ_ak δ_bd + δ_ad δ_bk) + λ δ_ab (b⁻¹)_kd,
//! ```
//!
//! with the Lamé constants from E and ν. In 1D uniaxial strain (`b = diag(F², 1, 1)`) the Cauchy
//! stress is `σ = (μ (F² − 1) + λ ln F) / F`.

use impm::material::{
    Material, MaterialParameters, ParameterKind, ParameterSpec, Range, Response, Tangent,
};
use nalgebra::{Matrix3, SMatrix};

/// The model: Lamé constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NeoHookean {
    pub lambda: f64,
    pub mu: f64,
}

impl NeoHookean {
    pub fn new(youngs_modulus: f64, poisson_ratio: f64) -> Self {
        let (e, nu) = (youngs_modulus, poisson_ratio);
        Self {
            lambda: e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            mu: e / (2.0 * (1.0 + nu)),
        }
    }

    /// The Cauchy stress of 1D uniaxial strain with stretch `f`.
    pub fn uniaxial_cauchy(&self, f: f64) -> f64 {
        (self.mu * (f * f - 1.0) + self.lambda * f.ln()) / f
    }
}

impl Material for NeoHookean {
    type History = ();
    const MODEL: &'static str = "neo_hookean";

    fn parameters() -> Vec<ParameterSpec> {
        vec![
            ParameterSpec {
                name: "E",
                meaning: "Young's modulus",
                label: Some("Young's modulus E"),
                kind: ParameterKind::Number(Range::Positive),
                required: true,
            },
            ParameterSpec {
                name: "nu",
                meaning: "Poisson's ratio",
                label: Some("Poisson's ratio nu"),
                kind: ParameterKind::Number(Range::Open(-1.0, 0.5)),
                required: true,
            },
        ]
    }

    fn describe() -> &'static str {
        "compressible neo-Hookean solid, τ = μ (b − I) + λ ln J I (examples/custom_material)"
    }

    fn from_parameters(parameters: &MaterialParameters) -> Result<Self, String> {
        Ok(Self::new(parameters.number("E")?, parameters.number("nu")?))
    }

    fn respond<const D: usize>(
        &self,
        deformation_gradient: &SMatrix<f64, D, D>,
        _increment: &SMatrix<f64, D, D>,
        _committed: &(),
    ) -> Result<Response<D, ()>, String> {
        let small = deformation_gradient * deformation_gradient.transpose();
        let mut b = Matrix3::identity();
        for i in 0..D {
            for j in 0..D {
                b[(i, j)] = small[(i, j)];
            }
        }
        let det = b.determinant();
        if !(det > 0.0 && det.is_finite()) {
            return Err(format!("det b = {det:e} is not positive"));
        }
        let b_inverse = b.try_inverse().ok_or("b is singular")?;
        let log_j = 0.5 * det.ln();
        let kirchhoff =
            (b - Matrix3::identity()) * self.mu + Matrix3::identity() * (self.lambda * log_j);
        let delta = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
        let mut tangent: Tangent<D> = [[[[0.0; D]; D]; D]; D];
        for (a, ta) in tangent.iter_mut().enumerate() {
            for (bb, tb) in ta.iter_mut().enumerate() {
                for (k, tk) in tb.iter_mut().enumerate() {
                    for (d, value) in tk.iter_mut().enumerate() {
                        *value = self.mu
                            * (delta(a, k) * delta(bb, d) + delta(a, d) * delta(bb, k))
                            + self.lambda * delta(a, bb) * b_inverse[(k, d)];
                    }
                }
            }
        }
        Ok(Response {
            kirchhoff,
            tangent,
            left_cauchy_green: small,
            history: (),
        })
    }

    fn stiffness_scale(&self) -> f64 {
        self.mu * (3.0 * self.lambda + 2.0 * self.mu) / (self.lambda + self.mu)
    }
}
