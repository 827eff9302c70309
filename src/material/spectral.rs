//! Spectral machinery shared by the models: the eigen-decomposition of a left Cauchy-Green
//! tensor, the divided difference of the logarithm, and the spatial tangent of any isotropic
//! function of `b` given through its principal values.
//!
//! # Isotropic functions of `b` and their tangent
//!
//! With `b = Σ_A λ_A n_A n_Aᵀ`, the principal logarithmic strains `ε_A = ½ ln λ_A` and a
//! Kirchhoff stress coaxial with `b`, `τ = Σ_A τ_A(ε) n_A n_Aᵀ` (Hencky elasticity, and every
//! isotropic elasto-plastic return map in principal logarithmic strain space), the
//! derivative of `τ` along a symmetric `db` has a part along the eigenprojections and a part
//! from their rotation (the eigenvectors move by `dn_A = Σ_{B≠A} n_B (n_Bᵀ db n_A)/(λ_A − λ_B)`):
//!
//! ```text
//! dτ = Σ_AB (∂τ_A/∂ε_B)(1/(2λ_B)) (n_Bᵀ db n_B) n_A n_Aᵀ + Σ_{A≠B} θ_AB n_A n_Aᵀ db n_B n_Bᵀ
//! θ_AB = (τ_A − τ_B)/(λ_A − λ_B) = g_AB · ½ (ln λ_A − ln λ_B)/(λ_A − λ_B),
//! g_AB = (τ_A − τ_B)/(ε_A − ε_B)
//! ```
//!
//! so that, with the algorithmic principal tangent `D_AB = ∂τ_A/∂ε_B`,
//!
//! ```text
//! c_abkd = 2 ∂τ_ab/∂b_kd = Σ_AB (D_AB/λ_B) n_Aa n_Ab n_Bk n_Bd
//!                        + Σ_{A≠B} g_AB L(λ_A, λ_B) n_Aa n_Bb ½(n_Ak n_Bd + n_Ad n_Bk)
//! ```
//!
//! with `L(x, y) = (ln x − ln y)/(x − y)` ([`log_divided_difference`], exact at and near
//! `x = y`). For Hencky elasticity `D = λ 1⊗1 + 2μ I` and `g_AB = 2μ`, which gives the tangent
//! of `hencky.rs` (tested below). Where two principal strains coincide, `g_AB` is the limit
//! `D_AA − D_AB` (isotropy makes `D_AA = D_BB` and `D_AB = D_BA` there, and the symmetrised
//! form is used); a return map that knows `g` in closed form (every radial return scales the
//! deviatoric trial stress, `g = 2μβ`) passes it, which avoids the cancellation of
//! `(τ_A − τ_B)/(ε_A − ε_B)` at nearly equal strains altogether.
//!
//! `c` is symmetric in `a, b` and in `k, d`; it has the major symmetry only when `D` is
//! symmetric (hyperelasticity, associated plasticity).

use nalgebra::{Matrix3, SymmetricEigen, Vector3};

use super::Tangent;

/// Eigen-decomposition `b = Σ_A values[A] vectors.column(A) vectors.column(A)ᵀ` of a symmetric
/// positive definite `b`.
#[derive(Clone, Debug, PartialEq)]
pub struct Spectral {
    pub values: Vector3<f64>,
    pub vectors: Matrix3<f64>,
}

impl Spectral {
    /// Decomposes the symmetric part of `b`, or explains why it is not a valid `F Fᵀ`.
    pub fn try_new(b: &Matrix3<f64>) -> Result<Self, String> {
        if b.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "left Cauchy-Green tensor b has a non-finite entry: {b:?}"
            ));
        }
        let symmetric = (b + b.transpose()) * 0.5;
        // A finite symmetric 3x3 matrix converges in a few sweeps; the cap only guards the loop.
        let eigen = SymmetricEigen::try_new(symmetric, f64::EPSILON, 1000)
            .ok_or_else(|| format!("eigen-decomposition of b did not converge: {symmetric:?}"))?;
        if let Some(bad) = eigen
            .eigenvalues
            .iter()
            .find(|&&v| v <= 0.0 || !v.is_finite())
        {
            return Err(format!(
                "left Cauchy-Green tensor b must be positive definite (det F > 0), \
                 but it has eigenvalue {bad:e}: {symmetric:?}"
            ));
        }
        Ok(Self {
            values: eigen.eigenvalues,
            vectors: eigen.eigenvectors,
        })
    }

    /// `Σ_A f(values[A]) n_A n_Aᵀ`.
    pub fn map(&self, f: impl Fn(f64) -> f64) -> Matrix3<f64> {
        self.compose(&self.values.map(f))
    }

    /// `Σ_A principal[A] n_A n_Aᵀ`: the tensor with these principal values on the eigenvectors.
    pub fn compose(&self, principal: &Vector3<f64>) -> Matrix3<f64> {
        let mut out = Matrix3::zeros();
        for (value, n) in principal.iter().zip(self.vectors.column_iter()) {
            out += n * n.transpose() * *value;
        }
        out
    }

    /// The principal logarithmic strains `½ ln λ_A`.
    pub fn log_strains(&self) -> Vector3<f64> {
        self.values.map(|value| 0.5 * value.ln())
    }
}

/// Divided difference of the logarithm, `(ln x - ln y) / (x - y)` for `x, y > 0`, with its limit
/// `1 / x` at `x = y`; accurate to a few ulps for all positive arguments and symmetric in them.
pub fn log_divided_difference(x: f64, y: f64) -> f64 {
    let (small, large) = if x <= y { (x, y) } else { (y, x) };
    let difference = small - large; // exact when small >= large / 2 (Sterbenz)
    let r = difference / large; // small / large - 1, in (-1, 0]
    if r > -1e-3 {
        // ln(1 + r) / r = sum_k (-r)^k / (k + 1); the first omitted term is below 1.5e-19.
        let series =
            1.0 + r * (-1.0 / 2.0 + r * (1.0 / 3.0 + r * (-1.0 / 4.0 + r * (1.0 / 5.0 - r / 6.0))));
        series / large
    } else if small >= 0.5 * large {
        r.ln_1p() / difference
    } else {
        (small / large).ln() / difference
    }
}

/// Principal strains closer than this (absolute, in logarithmic strain) count as coinciding in
/// the rotation part of the tangent: `g_AB` is then the limit `D_AA − D_AB`.
const COINCIDING_STRAINS: f64 = 1e-12;

/// `c_abkd = 2 ∂τ_ab/∂b_kd` for indices below `D` of the coaxial stress with principal values
/// `stress` at the principal logarithmic strains `strain` of `spectral`, whose principal
/// tangent is `principal_tangent[A][B] = ∂τ_A/∂ε_B` (module docs). `pair_modulus` is
/// `(τ_A − τ_B)/(ε_A − ε_B)` if the caller knows it is the same for every pair; otherwise it is
/// taken from the stresses.
// Index loops mirror the index notation of the formula in the module docs.
#[allow(clippy::needless_range_loop)]
pub fn isotropic_tangent<const D: usize>(
    spectral: &Spectral,
    strain: &Vector3<f64>,
    stress: &Vector3<f64>,
    principal_tangent: &Matrix3<f64>,
    pair_modulus: Option<f64>,
) -> Tangent<D> {
    const { assert!(D >= 1 && D <= 3, "dimension D must be 1, 2 or 3") };
    let (values, n) = (&spectral.values, &spectral.vectors);
    let jac = principal_tangent;
    // rotation coefficients g_AB L(λ_A, λ_B), A ≠ B (symmetric in A, B)
    let mut rotation = [[0.0; 3]; 3];
    for p in 0..3 {
        for q in 0..3 {
            if p == q {
                continue;
            }
            let g = pair_modulus.unwrap_or_else(|| {
                let gap = strain[p] - strain[q];
                if gap.abs() > COINCIDING_STRAINS {
                    (stress[p] - stress[q]) / gap
                } else {
                    0.5 * ((jac[(p, p)] - jac[(p, q)]) + (jac[(q, q)] - jac[(q, p)]))
                }
            });
            rotation[p][q] = g * log_divided_difference(values[p], values[q]);
        }
    }
    let mut tangent = [[[[0.0; D]; D]; D]; D];
    for a in 0..D {
        for b in a..D {
            for k in 0..D {
                for d in k..D {
                    let mut sum = 0.0;
                    for p in 0..3 {
                        let outer = n[(a, p)] * n[(b, p)];
                        for q in 0..3 {
                            sum += jac[(p, q)] / values[q] * outer * n[(k, q)] * n[(d, q)];
                            if p != q {
                                let spin = 0.5 * (n[(a, p)] * n[(b, q)] + n[(b, p)] * n[(a, q)]);
                                let inner = 0.5 * (n[(k, p)] * n[(d, q)] + n[(d, p)] * n[(k, q)]);
                                sum += rotation[p][q] * spin * inner;
                            }
                        }
                    }
                    tangent[a][b][k][d] = sum;
                    tangent[b][a][k][d] = sum;
                    tangent[a][b][d][k] = sum;
                    tangent[b][a][d][k] = sum;
                }
            }
        }
    }
    tangent
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::Hencky;
    use nalgebra::{Rotation3, Unit};

    fn spectral_b(values: [f64; 3]) -> Matrix3<f64> {
        let axis = Unit::new_normalize(Vector3::new(1.0, -2.0, 0.5));
        let q = Rotation3::from_axis_angle(&axis, 0.7).into_inner();
        q * Matrix3::from_diagonal(&Vector3::from(values)) * q.transpose()
    }

    /// Hencky's tangent is the isotropic tangent with D = λ 1⊗1 + 2μ I, whether the pair
    /// modulus 2μ is passed or taken from the stresses (also at coinciding eigenvalues).
    #[test]
    fn the_isotropic_tangent_of_hencky_elasticity_is_hencky_s_tangent() {
        let material = Hencky::new(2.0e5, 0.3).unwrap();
        let (lambda, mu) = material.lame();
        let elasticity = Matrix3::from_element(lambda) + Matrix3::identity() * (2.0 * mu);
        for values in [
            [1.7, 0.6, 1.1],
            [1.2, 1.2, 0.9],
            [1.0, 1.0, 1.0],
            [0.3, 2.0, 2.0],
        ] {
            let b = spectral_b(values);
            let (tau, expected) = material.kirchhoff_and_tangent::<3>(&b);
            let spectral = Spectral::try_new(&b).unwrap();
            let strain = spectral.log_strains();
            let stress = elasticity * strain;
            assert!((spectral.compose(&stress) - tau).amax() < 1e-9 * material.youngs_modulus);
            for pair in [Some(2.0 * mu), None] {
                let c = isotropic_tangent::<3>(&spectral, &strain, &stress, &elasticity, pair);
                let worst = c
                    .as_flattened()
                    .as_flattened()
                    .iter()
                    .flatten()
                    .zip(expected.as_flattened().as_flattened().iter().flatten())
                    .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
                assert!(worst < 1e-6 * mu, "{values:?} {pair:?}: {worst:e}");
            }
        }
    }

    #[test]
    fn log_divided_difference_is_accurate_and_symmetric() {
        for (x, y) in [
            (2.0, 3.0),
            (1.0, 1.0 + 1e-4),
            (1.0, 1.0 + 1e-2),
            (1e-3, 7.0),
            (5.0, 5.0),
        ] {
            let value = log_divided_difference(x, y);
            assert_eq!(value, log_divided_difference(y, x));
            let reference = if x == y {
                1.0 / x
            } else if (x - y).abs() > 0.1 * y {
                (x.ln() - y.ln()) / (x - y)
            } else {
                // Cancellation-free reference for close arguments: the mean of 1/t over [x, y]
                // by 2000-panel Simpson.
                let panels = 2000;
                let h = (y - x) / panels as f64;
                let mut sum = 1.0 / x + 1.0 / y;
                for i in 1..panels {
                    let t = x + h * i as f64;
                    sum += if i % 2 == 1 { 4.0 } else { 2.0 } / t;
                }
                sum * h / 3.0 / (y - x)
            };
            assert!(
                (value - reference).abs() < 1e-9 * reference,
                "{x}, {y}: {value} vs {reference}"
            );
        }
        // Continuity at the series switch (r = -1e-3) to rounding.
        let below = log_divided_difference(1.0 - 1e-3 * (1.0 + 1e-12), 1.0);
        let above = log_divided_difference(1.0 - 1e-3 * (1.0 - 1e-12), 1.0);
        assert!((below - above).abs() < 1e-14);
    }
}
