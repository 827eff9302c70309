//! Hencky elasticity: Kirchhoff stress linear and isotropic in the logarithmic strain.
//!
//! # Stress
//!
//! With the left Cauchy-Green tensor `b = F F^T = V^2` (paper eq. 3) and its spectral
//! decomposition `b = sum_A lambda_A n_A n_A^T` (`lambda_A > 0`, orthonormal `n_A`):
//!
//! ```text
//! eps = ln V = 1/2 ln b = 1/2 sum_A ln(lambda_A) n_A n_A^T          logarithmic strain
//! tau = lambda tr(eps) I + 2 mu eps                                 Kirchhoff stress
//! sigma = tau / J,   J = det F = sqrt(det b)                        Cauchy stress
//! lambda = E nu / ((1 + nu)(1 - 2 nu)),   mu = E / (2 (1 + nu))     Lame constants
//! ```
//!
//! The kernel always takes a full 3x3 `b`. Plane strain (2D) passes `b = [[b_2x2, 0], [0, 1]]`,
//! uniaxial strain (1D) passes `b = diag(F^2, 1, 1)`; the latter gives
//! `tau_11 = (lambda + 2 mu) ln F`, which for `nu = 0` is the paper's `tau = E ln F` (eqs. 12-13)
//! and `sigma = E ln F / F` (eq. 14).
//!
//! # Tangent
//!
//! [`Hencky::kirchhoff_and_tangent`] also returns `c_abkd = 2 d tau_ab / d b_kd`, taken with
//! respect to a symmetric perturbation of `b` (so `c` is symmetric in `k, d`; it is symmetric in
//! `a, b` because `tau` is). For a symmetric increment `db`, `d tau_ab = 1/2 c_abkd db_kd`.
//! Writing `tau = D : eps` with the isotropic elasticity tensor `D`, `c = D : L` where
//! `L = d ln b / d b` is the derivative of the matrix logarithm:
//!
//! ```text
//! c_abkd = lambda delta_ab (b^-1)_kd + 2 mu L_abkd                  (since sum_a L_aakd = (b^-1)_kd)
//! L_abkd = sum_{A,B} theta_AB n_Aa n_Bb 1/2 (n_Ak n_Bd + n_Ad n_Bk)  (Daleckii-Krein)
//! theta_AA = 1 / lambda_A,   theta_AB = (ln lambda_A - ln lambda_B) / (lambda_A - lambda_B)
//! ```
//!
//! `theta_AB` is the divided difference of `ln` and is evaluated without cancellation: for
//! `|r| < 1e-3`, `r = lambda_small / lambda_large - 1`, by the series
//! `ln(1 + r) / r = 1 - r/2 + r^2/3 - ...` (truncation below 2e-19 relative), otherwise with
//! `ln_1p` or `ln` of the ratio. Equal and repeated eigenvalues (including `b = I`) therefore
//! give exact, smooth results, and the arbitrary choice of eigenvectors inside a repeated
//! eigenspace does not matter because `theta` is constant on it.
//!
//! How a Newton solver uses `c`: with the spatial velocity gradient `l = dF F^-1`,
//! `db = l b + b l^T` and, by the `k, d` symmetry, `d tau_ab = c_abkd b_dm l_km`. For `D < 3` the
//! sums over `d, k, m < D` are exact because `b` is block-diagonal with an identity out-of-plane
//! block and `l` has no out-of-plane part.
//!
//! # Invalid input
//!
//! Only the symmetric part `(b + b^T) / 2` of the argument is used. If `b` has a non-finite entry
//! or an eigenvalue that is not strictly positive (so `F` is singular or inverted), the checked
//! functions ([`Hencky::try_kirchhoff`], [`Hencky::try_kirchhoff_and_tangent`]) return `Err` with
//! a message, and the unchecked ones return stresses and tangents filled with NaN. Nothing panics.

use nalgebra::{Matrix3, SMatrix};

use super::spectral::{Spectral, log_divided_difference};
use super::{Material, MaterialParameters, ParameterKind, ParameterSpec, Range, Response, embed};

/// Spatial tangent `c[a][b][k][d] = 2 d tau_ab / d b_kd` for indices below the dimension `D`.
pub type Tangent<const D: usize> = [[[[f64; D]; D]; D]; D];

/// Isotropic Hencky (logarithmic-strain) elasticity, see the [module docs](self).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hencky {
    /// Young's modulus `E` (> 0).
    pub youngs_modulus: f64,
    /// Poisson's ratio `nu` (-1 < nu < 0.5).
    pub poisson_ratio: f64,
}

/// Hyperelastic: no history, `b = F Fᵀ` (padded to 3x3 in 1D and 2D).
impl Material for Hencky {
    type History = ();
    const MODEL: &'static str = "hencky";

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
        "Hencky elasticity: Kirchhoff stress linear in the logarithmic strain (the paper's model)"
    }

    /// Parameters `E` (Young's modulus) and `nu` (Poisson's ratio).
    fn from_parameters(parameters: &MaterialParameters) -> Result<Self, String> {
        Hencky::new(parameters.number("E")?, parameters.number("nu")?)
    }

    fn respond<const D: usize>(
        &self,
        deformation_gradient: &SMatrix<f64, D, D>,
        _increment: &SMatrix<f64, D, D>,
        _committed: &(),
    ) -> Result<Response<D, ()>, String> {
        let b = deformation_gradient * deformation_gradient.transpose();
        let (kirchhoff, tangent) = self.try_kirchhoff_and_tangent::<D>(&embed(&b))?;
        Ok(Response {
            kirchhoff,
            tangent,
            left_cauchy_green: b,
            history: (),
        })
    }

    fn stiffness_scale(&self) -> f64 {
        self.youngs_modulus
    }
}

impl Hencky {
    /// Checks `E > 0` (finite) and `-1 < nu < 0.5`.
    pub fn new(youngs_modulus: f64, poisson_ratio: f64) -> Result<Self, String> {
        if !(youngs_modulus.is_finite() && youngs_modulus > 0.0) {
            return Err(format!(
                "Young's modulus must be positive and finite, got {youngs_modulus}"
            ));
        }
        if !(poisson_ratio > -1.0 && poisson_ratio < 0.5) {
            return Err(format!(
                "Poisson's ratio must satisfy -1 < nu < 0.5, got {poisson_ratio}"
            ));
        }
        Ok(Self {
            youngs_modulus,
            poisson_ratio,
        })
    }

    /// Lame constants `(lambda, mu)`.
    pub fn lame(&self) -> (f64, f64) {
        let (e, nu) = (self.youngs_modulus, self.poisson_ratio);
        (
            e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            e / (2.0 * (1.0 + nu)),
        )
    }

    /// Constrained (P-wave, 1D uniaxial-strain) modulus `lambda + 2 mu`.
    pub fn constrained_modulus(&self) -> f64 {
        let (lambda, mu) = self.lame();
        lambda + 2.0 * mu
    }

    /// Kirchhoff stress `tau(b)`; NaN-filled if `b` is not finite and positive definite.
    pub fn kirchhoff(&self, b: &Matrix3<f64>) -> Matrix3<f64> {
        self.try_kirchhoff(b)
            .unwrap_or_else(|_| Matrix3::from_element(f64::NAN))
    }

    /// Kirchhoff stress `tau(b)`, or an error if `b` is not finite and positive definite.
    pub fn try_kirchhoff(&self, b: &Matrix3<f64>) -> Result<Matrix3<f64>, String> {
        Ok(self.stress_from(&Spectral::try_new(b)?))
    }

    /// Cauchy stress `sigma = tau / J` with `J = sqrt(det b)`; NaN-filled on invalid `b`.
    pub fn cauchy(&self, b: &Matrix3<f64>) -> Matrix3<f64> {
        match Spectral::try_new(b) {
            Ok(spectral) => self.stress_from(&spectral) / spectral.values.product().sqrt(),
            Err(_) => Matrix3::from_element(f64::NAN),
        }
    }

    /// `tau(b)` and the tangent `c[a][b][k][d] = 2 d tau_ab / d b_kd` (symmetric perturbation of
    /// `b`) for indices `< D`; NaN-filled if `b` is not finite and positive definite.
    /// `D` must be 1, 2 or 3 (checked at compile time).
    pub fn kirchhoff_and_tangent<const D: usize>(
        &self,
        b: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Tangent<D>) {
        self.try_kirchhoff_and_tangent(b).unwrap_or_else(|_| {
            (
                Matrix3::from_element(f64::NAN),
                [[[[f64::NAN; D]; D]; D]; D],
            )
        })
    }

    /// Checked [`Hencky::kirchhoff_and_tangent`]: an error if `b` has a non-finite entry or a
    /// non-positive eigenvalue.
    // Index loops mirror the index notation of the formulas in the module docs.
    #[allow(clippy::needless_range_loop)]
    pub fn try_kirchhoff_and_tangent<const D: usize>(
        &self,
        b: &Matrix3<f64>,
    ) -> Result<(Matrix3<f64>, Tangent<D>), String> {
        const { assert!(D >= 1 && D <= 3, "dimension D must be 1, 2 or 3") };
        let spectral = Spectral::try_new(b)?;
        let tau = self.stress_from(&spectral);

        let (lambda, mu) = self.lame();
        let values = &spectral.values;
        let n = &spectral.vectors; // n[(i, A)] = component i of eigenvector A
        let mut theta = [[0.0; 3]; 3];
        for (p, row) in theta.iter_mut().enumerate() {
            for (q, entry) in row.iter_mut().enumerate() {
                *entry = log_divided_difference(values[p], values[q]);
            }
        }
        let b_inverse = spectral.map(|value| 1.0 / value);

        // L_ijkl = sum_AB theta_AB n_Ai n_Bj sym_kl(n_Ak n_Bl) (L_abkd of the module docs, with
        // i, j, k, l for a, b, k, d so that `b` stays the argument), built for i <= j, k <= l and
        // mirrored, so the minor symmetries hold exactly.
        let log_derivative = |i: usize, j: usize, k: usize, l: usize| {
            let mut sum = 0.0;
            for (p, theta_row) in theta.iter().enumerate() {
                for (q, theta_pq) in theta_row.iter().enumerate() {
                    let outer = n[(i, p)] * n[(j, q)];
                    let inner = 0.5 * (n[(k, p)] * n[(l, q)] + n[(l, p)] * n[(k, q)]);
                    sum += theta_pq * outer * inner;
                }
            }
            sum
        };

        let mut tangent = [[[[0.0; D]; D]; D]; D];
        for i in 0..D {
            for j in i..D {
                for k in 0..D {
                    for l in k..D {
                        let volumetric = if i == j {
                            lambda * b_inverse[(k, l)]
                        } else {
                            0.0
                        };
                        let value = volumetric + 2.0 * mu * log_derivative(i, j, k, l);
                        tangent[i][j][k][l] = value;
                        tangent[j][i][k][l] = value;
                        tangent[i][j][l][k] = value;
                        tangent[j][i][l][k] = value;
                    }
                }
            }
        }
        Ok((tau, tangent))
    }

    /// `tau = lambda tr(eps) I + 2 mu eps` with `eps = 1/2 ln b`.
    fn stress_from(&self, spectral: &Spectral) -> Matrix3<f64> {
        let (lambda, mu) = self.lame();
        let strain = spectral.map(|value| 0.5 * value.ln());
        Matrix3::identity() * (lambda * strain.trace()) + strain * (2.0 * mu)
    }
}

#[cfg(test)]
// Index loops mirror the index notation of the tensors being checked.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Rotation3, Unit, Vector3};

    fn steel_like() -> Hencky {
        Hencky::new(2.0e5, 0.3).unwrap()
    }

    /// Linear-isotropic stress of a given strain: the reference the logarithmic model must match.
    fn linear_stress(material: &Hencky, strain: &Matrix3<f64>) -> Matrix3<f64> {
        let (lambda, mu) = material.lame();
        Matrix3::identity() * (lambda * strain.trace()) + strain * (2.0 * mu)
    }

    fn rotation() -> Matrix3<f64> {
        let axis = Unit::new_normalize(Vector3::new(1.0, -2.0, 0.5));
        Rotation3::from_axis_angle(&axis, 0.7).into_inner()
    }

    /// `b = exp(2 eps)`: an independent route to a `b` whose logarithmic strain is known.
    fn b_from_strain(strain: &Matrix3<f64>) -> Matrix3<f64> {
        (strain * 2.0).exp()
    }

    fn general_strain() -> Matrix3<f64> {
        Matrix3::new(0.10, 0.03, -0.05, 0.03, -0.20, 0.07, -0.05, 0.07, 0.15)
    }

    fn max_abs(m: &Matrix3<f64>) -> f64 {
        m.amax()
    }

    #[test]
    fn rejects_bad_parameters_with_the_value_in_the_message() {
        for e in [0.0, -1.0, f64::INFINITY, f64::NAN] {
            let message = Hencky::new(e, 0.3).unwrap_err();
            assert!(message.contains("Young") && message.contains(&e.to_string()));
        }
        for nu in [-1.0, -1.5, 0.5, 0.7, f64::NAN, f64::INFINITY] {
            let message = Hencky::new(1.0, nu).unwrap_err();
            assert!(message.contains("Poisson") && message.contains(&nu.to_string()));
        }
        assert!(Hencky::new(1.0, -0.99).is_ok());
        assert!(Hencky::new(1.0, 0.499).is_ok());
    }

    #[test]
    fn lame_constants_and_constrained_modulus() {
        let material = Hencky::new(1.0e6, 0.25).unwrap();
        let (lambda, mu) = material.lame();
        assert!((lambda - 4.0e5).abs() < 1e-9);
        assert!((mu - 4.0e5).abs() < 1e-9);
        assert!((material.constrained_modulus() - 1.2e6).abs() < 1e-9);
        let uniaxial = Hencky::new(1.0e6, 0.0).unwrap();
        assert_eq!(uniaxial.lame(), (0.0, 5.0e5));
        assert_eq!(uniaxial.constrained_modulus(), 1.0e6);
    }

    #[test]
    fn undeformed_state_is_stress_free() {
        let (tau, tangent) = steel_like().kirchhoff_and_tangent::<3>(&Matrix3::identity());
        assert_eq!(tau, Matrix3::zeros());
        // ... and the tangent at b = I is the small-strain elasticity tensor.
        let (lambda, mu) = steel_like().lame();
        let delta = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
        for a in 0..3 {
            for b in 0..3 {
                for k in 0..3 {
                    for d in 0..3 {
                        let expected = lambda * delta(a, b) * delta(k, d)
                            + mu * (delta(a, k) * delta(b, d) + delta(a, d) * delta(b, k));
                        assert!((tangent[a][b][k][d] - expected).abs() < 1e-9);
                    }
                }
            }
        }
    }

    #[test]
    fn stress_matches_direct_computation() {
        let material = steel_like();
        let q = rotation();
        let diagonal_strain = Matrix3::from_diagonal(&Vector3::new(0.2, -0.1, 0.05));
        let strain_2d = Matrix3::new(0.12, -0.04, 0.0, -0.04, -0.3, 0.0, 0.0, 0.0, 0.0);
        let strains = [
            diagonal_strain,
            q * diagonal_strain * q.transpose(),
            general_strain(),
            strain_2d,
            Matrix3::from_diagonal(&Vector3::new(-0.4, 0.0, 0.0)),
        ];
        for strain in strains {
            let b = b_from_strain(&strain);
            let expected = linear_stress(&material, &strain);
            let tau = material.kirchhoff(&b);
            assert!(
                (tau - expected).amax() < 1e-12 * max_abs(&expected),
                "{tau} vs {expected}"
            );
        }
        // A diagonal b against the scalar logarithm.
        let b = Matrix3::from_diagonal(&Vector3::new(1.5_f64, 0.6, 2.0));
        let strain = Matrix3::from_diagonal(&b.diagonal().map(|v| 0.5 * v.ln()));
        let expected = linear_stress(&material, &strain);
        assert!((material.kirchhoff(&b) - expected).amax() < 1e-12 * max_abs(&expected));
    }

    #[test]
    fn plane_strain_b_from_a_2x2_deformation_gradient() {
        let material = steel_like();
        let f = Matrix2::new(1.2, 0.3, -0.1, 0.8);
        let b2 = f * f.transpose();
        let b = Matrix3::new(
            b2[(0, 0)],
            b2[(0, 1)],
            0.0,
            b2[(1, 0)],
            b2[(1, 1)],
            0.0,
            0.0,
            0.0,
            1.0,
        );
        let tau = material.kirchhoff(&b);
        // Direct: 2x2 spectral logarithm of b2, out-of-plane strain zero.
        let eigen = b2.symmetric_eigen();
        let mut strain = Matrix3::zeros();
        for (value, n) in eigen
            .eigenvalues
            .iter()
            .zip(eigen.eigenvectors.column_iter())
        {
            let outer = n * n.transpose() * (0.5 * value.ln());
            let mut block = strain.fixed_view_mut::<2, 2>(0, 0);
            block += outer;
        }
        let expected = linear_stress(&material, &strain);
        assert!((tau - expected).amax() < 1e-12 * max_abs(&expected));
        assert_eq!(tau[(0, 2)], 0.0);
        assert_eq!(tau[(1, 2)], 0.0);
    }

    #[test]
    fn uniaxial_strain_gives_constrained_modulus_times_ln_stretch() {
        let material = steel_like();
        let (lambda, _) = material.lame();
        for stretch in [0.3_f64, 0.9, 1.0, 1.1, 2.5] {
            let b = Matrix3::from_diagonal(&Vector3::new(stretch * stretch, 1.0, 1.0));
            let (tau, tangent) = material.kirchhoff_and_tangent::<1>(&b);
            let modulus = material.constrained_modulus();
            let scale = modulus * stretch.ln().abs() + 1e-300;
            assert!((tau[(0, 0)] - modulus * stretch.ln()).abs() <= 1e-14 * scale);
            assert!((tau[(1, 1)] - lambda * stretch.ln()).abs() <= 1e-14 * scale);
            // d tau_11 / d b_11 = modulus / (2 b_11), so c_1111 = modulus / F^2.
            let expected = modulus / (stretch * stretch);
            assert!((tangent[0][0][0][0] - expected).abs() < 1e-13 * expected);
        }
        // The paper's 1D model (nu = 0): tau = E ln F and sigma = E ln F / F (eqs. 13-14).
        let paper = Hencky::new(1.0e6, 0.0).unwrap();
        let stretch = 0.8_f64;
        let b = Matrix3::from_diagonal(&Vector3::new(stretch * stretch, 1.0, 1.0));
        let sigma = paper.cauchy(&b)[(0, 0)];
        let expected = 1.0e6 * stretch.ln() / stretch;
        assert!((sigma - expected).abs() < 1e-12 * expected.abs());
    }

    #[test]
    fn isotropy() {
        let material = steel_like();
        let q = rotation();
        let b = b_from_strain(&general_strain());
        let rotated = material.kirchhoff(&(q * b * q.transpose()));
        let expected = q * material.kirchhoff(&b) * q.transpose();
        assert!((rotated - expected).amax() < 1e-12 * max_abs(&expected));
    }

    #[test]
    fn small_strain_limit_is_linear_elasticity() {
        let material = steel_like();
        let strain = general_strain() * 1e-6;
        let b = Matrix3::identity() + strain * 2.0;
        let expected = linear_stress(&material, &strain);
        // eps = 1/2 ln(I + 2e) = e - e^2 + ..., so the relative difference is O(|e|).
        assert!((material.kirchhoff(&b) - expected).amax() < 1e-5 * max_abs(&expected));
    }

    /// Central differences of `kirchhoff` along the symmetric direction `(e_k e_d^T + e_d e_k^T)/2`
    /// give `c_abkd / 2`; compare for all indices `< D`.
    fn check_tangent<const D: usize>(material: &Hencky, b: &Matrix3<f64>) {
        let (tau, tangent) = material.kirchhoff_and_tangent::<D>(b);
        assert_eq!(tau, material.kirchhoff(b));
        // Small against the smallest eigenvalue, so the eigenvalues move by a tiny fraction.
        let smallest = b.symmetric_eigenvalues().min();
        let step = 1e-5 * smallest;
        let mut scale: f64 = 0.0;
        let mut worst: f64 = 0.0;
        for k in 0..D {
            for d in 0..D {
                let mut direction = Matrix3::zeros();
                direction[(k, d)] += 0.5;
                direction[(d, k)] += 0.5;
                let plus = material.kirchhoff(&(b + direction * step));
                let minus = material.kirchhoff(&(b - direction * step));
                let derivative = (plus - minus) / (2.0 * step);
                for a in 0..D {
                    for bb in 0..D {
                        let analytic = tangent[a][bb][k][d];
                        scale = scale.max(analytic.abs());
                        worst = worst.max((analytic - 2.0 * derivative[(a, bb)]).abs());
                    }
                }
            }
        }
        assert!(
            worst <= 1e-6 * scale,
            "D = {D}: worst difference {worst:e}, scale {scale:e}, b = {b}"
        );
    }

    fn spectral_b(values: [f64; 3]) -> Matrix3<f64> {
        let q = rotation();
        q * Matrix3::from_diagonal(&Vector3::from(values)) * q.transpose()
    }

    #[test]
    fn tangent_matches_finite_differences() {
        let material = steel_like();
        let general = b_from_strain(&general_strain());
        let plane = Matrix3::new(1.4, 0.3, 0.0, 0.3, 0.7, 0.0, 0.0, 0.0, 1.0);
        let uniaxial = Matrix3::from_diagonal(&Vector3::new(0.49, 1.0, 1.0));
        let cases = [
            general,
            spectral_b([1.7, 0.6, 1.1]),
            spectral_b([1.3, 1.3 * (1.0 + 1e-9), 0.8]), // nearly equal
            spectral_b([1.3, 1.3 * (1.0 + 2e-3), 0.8]), // either side of the series switch
            spectral_b([1.3, 1.3 * (1.0 + 5e-4), 0.8]),
            spectral_b([1.2, 1.2, 0.9]),   // exactly repeated
            spectral_b([0.01, 50.0, 1.0]), // widely spread
            Matrix3::identity(),
            Matrix3::identity() * 2.0,
            plane,
            uniaxial,
        ];
        for b in &cases {
            check_tangent::<3>(&material, b);
            check_tangent::<2>(&material, b);
            check_tangent::<1>(&material, b);
        }
        // Plane strain b whose in-plane eigenvalue equals the out-of-plane one (1).
        let touching = Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0);
        check_tangent::<2>(&material, &touching);
    }

    #[test]
    fn tangent_symmetries() {
        let material = steel_like();
        for b in [
            b_from_strain(&general_strain()),
            spectral_b([1.2, 1.2, 0.9]),
        ] {
            let (_, c) = material.kirchhoff_and_tangent::<3>(&b);
            for a in 0..3 {
                for bb in 0..3 {
                    for k in 0..3 {
                        for d in 0..3 {
                            assert_eq!(c[a][bb][k][d], c[bb][a][k][d]);
                            assert_eq!(c[a][bb][k][d], c[a][bb][d][k]);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn tangent_is_smooth_across_coalescing_eigenvalues() {
        let material = steel_like();
        let (_, repeated) = material.kirchhoff_and_tangent::<3>(&spectral_b([1.2, 1.2, 0.9]));
        for gap in [1e-14, 1e-12, 1e-9, 1e-6] {
            let (_, near) =
                material.kirchhoff_and_tangent::<3>(&spectral_b([1.2, 1.2 * (1.0 + gap), 0.9]));
            let mut worst: f64 = 0.0;
            for (x, y) in near
                .as_flattened()
                .as_flattened()
                .iter()
                .flatten()
                .zip(repeated.as_flattened().as_flattened().iter().flatten())
            {
                worst = worst.max((x - y).abs());
            }
            // The tangent is Lipschitz in b: the change is of the order of the gap.
            assert!(worst < 1e-9 * material.youngs_modulus + 10.0 * gap * material.youngs_modulus);
        }
    }

    #[test]
    fn invalid_b_is_an_error_not_a_panic() {
        let material = steel_like();
        let bad = [
            Matrix3::zeros(),
            Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0)),
            Matrix3::from_diagonal(&Vector3::new(1.0, 0.0, 1.0)),
            Matrix3::from_element(f64::NAN),
            Matrix3::identity() * f64::INFINITY,
        ];
        for b in &bad {
            assert!(material.try_kirchhoff(b).is_err());
            let message = material.try_kirchhoff_and_tangent::<2>(b).unwrap_err();
            assert!(message.contains("b"));
            assert!(material.kirchhoff(b).iter().all(|v| v.is_nan()));
            assert!(material.cauchy(b).iter().all(|v| v.is_nan()));
            let (tau, tangent) = material.kirchhoff_and_tangent::<3>(b);
            assert!(tau.iter().all(|v| v.is_nan()));
            assert!(
                tangent
                    .as_flattened()
                    .as_flattened()
                    .iter()
                    .flatten()
                    .all(|v| v.is_nan())
            );
        }
    }

    #[test]
    fn only_the_symmetric_part_of_b_is_used() {
        let material = steel_like();
        let b = b_from_strain(&general_strain());
        let skew = Matrix3::new(0.0, 0.1, 0.0, -0.1, 0.0, 0.2, 0.0, -0.2, 0.0);
        let difference = material.kirchhoff(&(b + skew)) - material.kirchhoff(&b);
        assert!(difference.amax() < 1e-12 * material.kirchhoff(&b).amax());
    }
}
