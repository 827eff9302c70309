//! Point-level finite-deformation kinematics, internal force and consistent tangent.
//!
//! Pure kernels on nalgebra types; the ECS systems in `stages/` call them per material point.
//!
//! # Kinematics (updated Lagrangian, grid reset every load step)
//! At the start of load step n+1 the grid coincides with the points' configuration x^n. With
//! N_i the basis functions evaluated at x_p^n and ∇_n their gradients with respect to x^n, the
//! displacement increment Δu_i of the control points gives the increment of deformation
//!
//! ```text
//!   Δf = I + Σ_i Δu_i ⊗ ∇_n N_i,    F = Δf F^n,    J = det F,    b = F Fᵀ.
//! ```
//!
//! # Stress and internal force (paper eq. 9)
//! The material gives the Kirchhoff stress τ (`material::Material`); the Cauchy stress is τ/J and
//! the current volume V = J V0, so σ V = τ V0 and
//!
//! ```text
//!   f_int,i = Σ_p V0_p τ_p g_i,    g_i = ∇_x N_i = Δf⁻ᵀ ∇_n N_i.
//! ```
//!
//! # Consistent tangent
//! Differentiating f_int,i with respect to Δu_j (using ∂Δf/∂Δu_j,k = e_k ⊗ ∇_n N_j,
//! ∂b/∂Δu_j,k = e_k ⊗ (b g_j) + (b g_j) ⊗ e_k and ∂Δf⁻¹ = −Δf⁻¹ ∂Δf Δf⁻¹):
//!
//! ```text
//!   K_ij[a][k] = V0 ( Σ_{b,d} g_i[b] c[a][b][k][d] (b g_j)[d]  −  (τ g_j)[a] g_i[k] ),
//! ```
//!
//! with c_abkd = 2 ∂τ_ab/∂b_kd the material's spatial tangent and b the tensor it is taken at
//! (`F Fᵀ` for hyperelastic models, the trial elastic left Cauchy-Green tensor for plastic ones:
//! its derivative with respect to Δu has the same form). The first term is the material
//! stiffness, the second the geometric (initial-stress) stiffness. For a hyperelastic model
//! under dead loads K is the Hessian of the potential energy and is symmetric.
//!
//! # Forces spread to the grid
//! A force F acting at a point with basis values N_i reaches node i as F N_i ([`spread_force`]:
//! body force, point loads); at a boundary point whose support reaches nodes without material,
//! the inactive nodes' share goes to the active ones in proportion ([`spread_over_active`]:
//! tractions). Both keep the resultant exactly (partition of unity).
//!
//! Lower dimensions: in 2D (plane strain) and 1D (uniaxial strain) the out-of-plane stretches
//! are 1; the material works on the 3x3 `b` padded with ones and only the D x D block enters
//! the forces, while the full 3x3 stress is kept for output.

use std::ops::{Index, IndexMut};

use nalgebra::{Matrix3, SMatrix, SVector};

use crate::basis::NodeWeight;
use crate::material::{Material, Tangent};
pub use crate::material::{block, embed};

/// Δf = I + Σ_i Δu_i ⊗ ∇_n N_i over a point's support; `increment(node)` gives Δu of a node.
pub fn increment_gradient<const D: usize>(
    support: &[NodeWeight<D>],
    increment: impl Fn(usize) -> SVector<f64, D>,
) -> SMatrix<f64, D, D> {
    let mut df = SMatrix::<f64, D, D>::identity();
    for w in support {
        df += increment(w.node) * w.gradient.transpose();
    }
    df
}

/// Σ_i Δu_i N_i: the displacement increment at a point (paper eq. 10).
pub fn interpolate<const D: usize>(
    support: &[NodeWeight<D>],
    increment: impl Fn(usize) -> SVector<f64, D>,
) -> SVector<f64, D> {
    support
        .iter()
        .fold(SVector::zeros(), |acc, w| acc + increment(w.node) * w.value)
}

/// Adds `force N_i` to `external_force[i]` for every node i of `support` (the force of one point
/// distributed to the grid, paper eq. 9).
pub fn spread_force<const D: usize>(
    force: &SVector<f64, D>,
    support: &[NodeWeight<D>],
    external_force: &mut (impl IndexMut<usize, Output = SVector<f64, D>> + ?Sized),
) {
    for w in support {
        external_force[w.node] += force * w.value;
    }
}

/// Σ_{i active} N_i over `support`.
pub fn active_weight<const D: usize>(
    support: &[NodeWeight<D>],
    active: &(impl Index<usize, Output = bool> + ?Sized),
) -> f64 {
    support
        .iter()
        .filter(|w| active[w.node])
        .map(|w| w.value)
        .sum()
}

/// Adds `force N_i / Σ_{j active} N_j` to `external_force[i]` for every active node i of
/// `support`. Returns false (and adds nothing) if no node of the support is active.
pub fn spread_over_active<const D: usize>(
    force: &SVector<f64, D>,
    support: &[NodeWeight<D>],
    active: &(impl Index<usize, Output = bool> + ?Sized),
    external_force: &mut (impl IndexMut<usize, Output = SVector<f64, D>> + ?Sized),
) -> bool {
    let total = active_weight(support, active);
    if total <= 0.0 {
        return false;
    }
    for w in support.iter().filter(|w| active[w.node]) {
        external_force[w.node] += force * (w.value / total);
    }
    true
}

/// Checks a material's consistent tangent at one point: the stiffness blocks `K_ij` of
/// [`TrialState::stiffness`] against central finite differences (step `h`) of the point's
/// internal force `V0 τ g_i` with respect to the increments `u_j` of nodes with reference
/// gradients `grads`, from the committed state (`previous`, `committed`). Returns the largest
/// absolute difference and the largest finite-difference entry (the scale to compare with).
/// Every material's tests use it (the built-in ones, the plastic ones at points of each return
/// region, and yours).
pub fn tangent_against_finite_differences<const D: usize, M: Material>(
    material: &M,
    committed: &M::History,
    previous: &SMatrix<f64, D, D>,
    grads: &[SVector<f64, D>],
    increments: &[SVector<f64, D>],
    h: f64,
) -> Result<(f64, f64), KinematicsError> {
    let support: Vec<NodeWeight<D>> = grads
        .iter()
        .enumerate()
        .map(|(node, g)| NodeWeight {
            node,
            value: 0.0,
            gradient: *g,
        })
        .collect();
    let force = |u: &[SVector<f64, D>]| -> Result<Vec<SVector<f64, D>>, KinematicsError> {
        let df = increment_gradient(&support, |n| u[n]);
        let (state, _) = trial_state_with_history(material, committed, previous, &df)?;
        Ok(grads
            .iter()
            .map(|g| state.internal_force(0.7, &state.spatial_gradient(g)))
            .collect())
    };
    let df = increment_gradient(&support, |n| increments[n]);
    let (state, _) = trial_state_with_history(material, committed, previous, &df)?;
    let (mut worst, mut scale) = (0.0f64, 0.0f64);
    for j in 0..grads.len() {
        for k in 0..D {
            let (mut up, mut down) = (increments.to_vec(), increments.to_vec());
            up[j][k] += h;
            down[j][k] -= h;
            let (fp, fm) = (force(&up)?, force(&down)?);
            for (i, g_i) in grads.iter().enumerate() {
                let analytic = state.stiffness(
                    0.7,
                    &state.spatial_gradient(g_i),
                    &state.spatial_gradient(&grads[j]),
                );
                for a in 0..D {
                    let fd = (fp[i][a] - fm[i][a]) / (2.0 * h);
                    worst = worst.max((fd - analytic[(a, k)]).abs());
                    scale = scale.max(fd.abs());
                }
            }
        }
    }
    Ok((worst, scale))
}

/// Why a point's trial state could not be evaluated.
#[derive(Clone, Debug, PartialEq)]
pub enum KinematicsError {
    /// det F <= 0 (the point is inverted) or not finite.
    NonPositiveJacobian(f64),
    /// The increment of deformation is not invertible or not finite.
    SingularIncrement,
    /// The material could not evaluate the stress.
    Material(String),
}

impl std::fmt::Display for KinematicsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            KinematicsError::NonPositiveJacobian(j) => {
                write!(f, "non-positive or non-finite det F = {j:e}")
            }
            KinematicsError::SingularIncrement => {
                write!(f, "the increment of deformation is singular or not finite")
            }
            KinematicsError::Material(why) => write!(f, "material: {why}"),
        }
    }
}

/// The trial state of a point for a given displacement increment.
#[derive(Clone, Debug, PartialEq)]
pub struct TrialState<const D: usize> {
    /// Total deformation gradient F = Δf F^n.
    pub deformation_gradient: SMatrix<f64, D, D>,
    /// Δf⁻¹, which maps step-start gradients to current ones (g = Δf⁻ᵀ ∇_n N).
    pub increment_inverse: SMatrix<f64, D, D>,
    /// J = det F (of the D x D block; out-of-plane stretches are 1).
    pub jacobian: f64,
    /// The left Cauchy-Green tensor the tangent is taken at (D x D block): b = F Fᵀ for
    /// hyperelastic models, the trial elastic one for plastic models.
    pub left_cauchy_green: SMatrix<f64, D, D>,
    /// Kirchhoff stress, full 3x3.
    pub kirchhoff: Matrix3<f64>,
    /// c_abkd = 2 ∂τ_ab/∂b_kd.
    pub tangent: Tangent<D>,
}

impl<const D: usize> TrialState<D> {
    /// The state of a point before its first stress update: F = I, no stress, no tangent.
    pub fn unstressed() -> Self {
        Self {
            deformation_gradient: SMatrix::identity(),
            increment_inverse: SMatrix::identity(),
            jacobian: 1.0,
            left_cauchy_green: SMatrix::identity(),
            kirchhoff: Matrix3::zeros(),
            tangent: [[[[0.0; D]; D]; D]; D],
        }
    }

    /// Cauchy stress σ = τ / J, full 3x3.
    pub fn cauchy(&self) -> Matrix3<f64> {
        self.kirchhoff / self.jacobian
    }

    /// Spatial gradient g = Δf⁻ᵀ ∇_n N of a basis function.
    #[inline]
    pub fn spatial_gradient(&self, reference_gradient: &SVector<f64, D>) -> SVector<f64, D> {
        self.increment_inverse.transpose() * reference_gradient
    }

    /// V0 τ g_i: the point's contribution to the internal force of a node.
    #[inline]
    pub fn internal_force(&self, reference_volume: f64, g_i: &SVector<f64, D>) -> SVector<f64, D> {
        block::<D>(&self.kirchhoff) * g_i * reference_volume
    }

    /// K_ij block: the point's contribution to the tangent coupling nodes i and j
    /// (module docs). `g_i`, `g_j` are spatial gradients.
    #[inline]
    pub fn stiffness(
        &self,
        reference_volume: f64,
        g_i: &SVector<f64, D>,
        g_j: &SVector<f64, D>,
    ) -> SMatrix<f64, D, D> {
        self.stiffness_from(reference_volume, g_i, &self.stiffness_factor(g_j))
    }

    /// The part of K_ij that depends on node j only: `m[a][b][k] = Σ_d c_abkd (b g_j)_d` and
    /// `τ g_j`. Computing it once per node turns the D⁴ work per node pair into D³.
    #[inline]
    pub fn stiffness_factor(&self, g_j: &SVector<f64, D>) -> StiffnessFactor<D> {
        let h_j = self.left_cauchy_green * g_j;
        let c = &self.tangent;
        let material = std::array::from_fn(|a| {
            std::array::from_fn(|b| {
                std::array::from_fn(|k| (0..D).map(|d| c[a][b][k][d] * h_j[d]).sum())
            })
        });
        StiffnessFactor {
            material,
            tau_g: block::<D>(&self.kirchhoff) * g_j,
        }
    }

    /// `K_ij = V0 (Σ_b g_i[b] m_j[a][b][k] − (τ g_j)[a] g_i[k])`.
    #[inline]
    pub fn stiffness_from(
        &self,
        reference_volume: f64,
        g_i: &SVector<f64, D>,
        factor_j: &StiffnessFactor<D>,
    ) -> SMatrix<f64, D, D> {
        SMatrix::from_fn(|a, k| {
            let mut material = 0.0;
            for (b, gib) in g_i.iter().enumerate() {
                material += gib * factor_j.material[a][b][k];
            }
            reference_volume * (material - factor_j.tau_g[a] * g_i[k])
        })
    }
}

/// The node-j factor of a stiffness block (see [`TrialState::stiffness_factor`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StiffnessFactor<const D: usize> {
    pub material: [[[f64; D]; D]; D],
    pub tau_g: SVector<f64, D>,
}

/// Evaluates F = Δf F^n and the material's stress, tangent and trial history from the
/// committed history; fails (never panics) when the deformation is inadmissible.
pub fn trial_state_with_history<const D: usize, M: Material>(
    material: &M,
    committed: &M::History,
    previous_deformation_gradient: &SMatrix<f64, D, D>,
    increment_gradient: &SMatrix<f64, D, D>,
) -> Result<(TrialState<D>, M::History), KinematicsError> {
    if increment_gradient.iter().any(|v| !v.is_finite()) {
        return Err(KinematicsError::SingularIncrement);
    }
    let f = increment_gradient * previous_deformation_gradient;
    // Determinant and inverse through the 3x3 embedding (identity padding leaves both intact),
    // which avoids nalgebra's dimension bounds in const-generic code.
    let jacobian = embed(&f).determinant();
    if jacobian.is_nan() || jacobian <= 0.0 || !jacobian.is_finite() {
        return Err(KinematicsError::NonPositiveJacobian(jacobian));
    }
    let increment_inverse = embed(increment_gradient)
        .try_inverse()
        .map(|inv| block::<D>(&inv))
        .ok_or(KinematicsError::SingularIncrement)?;
    let response = material
        .respond(&f, increment_gradient, committed)
        .map_err(KinematicsError::Material)?;
    let state = TrialState {
        deformation_gradient: f,
        increment_inverse,
        jacobian,
        left_cauchy_green: response.left_cauchy_green,
        kirchhoff: response.kirchhoff,
        tangent: response.tangent,
    };
    Ok((state, response.history))
}

/// [`trial_state_with_history`] with the material evaluated at a modified increment
/// `seen_increment` (`F = Δf̃ F^n`, e.g. F-bar's `Δf̄`), while the state maps gradients with the
/// point's own increment `own_increment` (`g = Δf⁻ᵀ ∇_n N`: the current configuration is the
/// displacement field's). See `components::ModifiedIncrement`.
pub fn trial_state_with_modified_increment<const D: usize, M: Material>(
    material: &M,
    committed: &M::History,
    previous_deformation_gradient: &SMatrix<f64, D, D>,
    own_increment: &SMatrix<f64, D, D>,
    seen_increment: &SMatrix<f64, D, D>,
) -> Result<(TrialState<D>, M::History), KinematicsError> {
    if own_increment.iter().any(|v| !v.is_finite()) {
        return Err(KinematicsError::SingularIncrement);
    }
    let (mut state, history) = trial_state_with_history(
        material,
        committed,
        previous_deformation_gradient,
        seen_increment,
    )?;
    state.increment_inverse = embed(own_increment)
        .try_inverse()
        .map(|inv| block::<D>(&inv))
        .ok_or(KinematicsError::SingularIncrement)?;
    Ok((state, history))
}

/// [`trial_state_with_history`] for a model without history (Hencky elasticity).
pub fn trial_state<const D: usize, M: Material<History = ()>>(
    material: &M,
    previous_deformation_gradient: &SMatrix<f64, D, D>,
    increment_gradient: &SMatrix<f64, D, D>,
) -> Result<TrialState<D>, KinematicsError> {
    trial_state_with_history(
        material,
        &(),
        previous_deformation_gradient,
        increment_gradient,
    )
    .map(|(state, ())| state)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::{BasisKind, BasisScratch, GridBasis};
    use crate::material::Hencky;

    fn material() -> Hencky {
        Hencky::new(1e6, 0.3).unwrap()
    }

    /// The Hencky point tangent against central finite differences, at a stretched, sheared
    /// state with three support functions.
    fn check_tangent<const D: usize>() {
        let grads: Vec<SVector<f64, D>> = (0..3)
            .map(|n| SVector::from_fn(|a, _| 0.3 * (n as f64 + 1.0) - 0.2 * a as f64 + 0.05))
            .collect();
        let u: Vec<SVector<f64, D>> = (0..3)
            .map(|n| SVector::from_fn(|a, _| 0.04 * ((n * 3 + a) as f64).sin()))
            .collect();
        let f_prev =
            SMatrix::<f64, D, D>::from_fn(|a, b| if a == b { 0.9 + 0.05 * a as f64 } else { 0.03 });
        let (worst, scale) =
            tangent_against_finite_differences(&material(), &(), &f_prev, &grads, &u, 1e-7)
                .unwrap();
        assert!(
            worst < 1e-6 * scale,
            "D = {D}: tangent error {worst:e} vs scale {scale:e}"
        );
    }

    /// The check can fail: a tangent whose material part is 10 % off is caught.
    #[test]
    fn a_wrong_tangent_is_caught_by_the_finite_difference_check() {
        #[derive(Clone, Debug, PartialEq)]
        struct OffTangent(Hencky);
        impl Material for OffTangent {
            type History = ();
            const MODEL: &'static str = "off_tangent";
            fn parameters() -> Vec<crate::material::ParameterSpec> {
                Vec::new()
            }
            fn describe() -> &'static str {
                ""
            }
            fn from_parameters(_: &crate::material::MaterialParameters) -> Result<Self, String> {
                Err(String::new())
            }
            fn respond<const D: usize>(
                &self,
                f: &SMatrix<f64, D, D>,
                df: &SMatrix<f64, D, D>,
                h: &(),
            ) -> Result<crate::material::Response<D, ()>, String> {
                let mut response = self.0.respond(f, df, h)?;
                // a tangent that is off by 10 % in its material part
                for a in response.tangent.iter_mut().flatten().flatten().flatten() {
                    *a *= 1.1;
                }
                Ok(response)
            }
            fn stiffness_scale(&self) -> f64 {
                1.0
            }
        }
        let v = nalgebra::Vector2::new;
        let grads = [v(0.3, -0.1), v(-0.2, 0.5)];
        let u = [v(0.02, -0.01), v(0.01, 0.03)];
        let (worst, scale) = tangent_against_finite_differences(
            &OffTangent(material()),
            &(),
            &SMatrix::identity(),
            &grads,
            &u,
            1e-7,
        )
        .unwrap();
        assert!(worst > 1e-3 * scale, "{worst:e} vs {scale:e}");
    }

    #[test]
    fn point_tangent_matches_finite_differences_1d() {
        check_tangent::<1>();
    }

    #[test]
    fn point_tangent_matches_finite_differences_2d() {
        check_tangent::<2>();
    }

    #[test]
    fn point_tangent_matches_finite_differences_3d() {
        check_tangent::<3>();
    }

    #[test]
    fn point_tangent_is_symmetric() {
        let grads = [
            nalgebra::Vector2::new(0.3, -0.1),
            nalgebra::Vector2::new(-0.2, 0.5),
        ];
        let df = SMatrix::<f64, 2, 2>::new(1.05, 0.1, -0.04, 0.93);
        let s = trial_state(&material(), &SMatrix::identity(), &df).unwrap();
        let g: Vec<_> = grads.iter().map(|g| s.spatial_gradient(g)).collect();
        let k01 = s.stiffness(1.0, &g[0], &g[1]);
        let k10 = s.stiffness(1.0, &g[1], &g[0]);
        assert!((k01 - k10.transpose()).norm() < 1e-8 * k01.norm());
    }

    #[test]
    fn inverted_point_is_an_error() {
        let df = SMatrix::<f64, 1, 1>::new(-0.1);
        assert_eq!(
            trial_state(&material(), &SMatrix::identity(), &df).unwrap_err(),
            KinematicsError::NonPositiveJacobian(-0.1)
        );
        let nan = SMatrix::<f64, 1, 1>::new(f64::NAN);
        assert!(trial_state(&material(), &SMatrix::identity(), &nan).is_err());
    }

    #[test]
    fn one_dimensional_stress_is_e_ln_f_over_f() {
        let e = 1e6;
        let m = Hencky::new(e, 0.0).unwrap();
        let s = trial_state(
            &m,
            &SMatrix::<f64, 1, 1>::new(0.8),
            &SMatrix::<f64, 1, 1>::new(0.9),
        )
        .unwrap();
        let f: f64 = 0.72;
        assert!((s.cauchy()[(0, 0)] - e * f.ln() / f).abs() < 1e-6);
    }

    /// The spread force sums to the point force (partition of unity) and its first moment
    /// about the origin reproduces x_p × P: Σ_i N_i x_i = x_p for B-splines with Greville nodes
    /// (linear precision), so a load is placed where the point is.
    #[test]
    fn spread_force_keeps_resultant_and_moment() {
        let basis = GridBasis::<2>::new(
            &[0.0, 0.0],
            &[4.0, 3.0],
            &[4, 3],
            BasisKind::BSpline { order: 2 },
        )
        .unwrap();
        let x = SVector::<f64, 2>::new(2.3, 0.7);
        let mut support = Vec::new();
        basis
            .eval(&x, &mut BasisScratch::default(), &mut support)
            .unwrap();
        let force = SVector::<f64, 2>::new(3.0, -5.0);
        let mut external = vec![SVector::<f64, 2>::zeros(); basis.num_nodes()];
        spread_force(&force, &support, &mut external);
        let resultant: SVector<f64, 2> = external.iter().sum();
        assert!((resultant - force).norm() < 1e-12, "{resultant}");
        let moment: f64 = external
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let xi = basis.node_position(i);
                xi.x * f.y - xi.y * f.x
            })
            .sum();
        let expected = x.x * force.y - x.y * force.x;
        assert!((moment - expected).abs() < 1e-12, "{moment} vs {expected}");
        // only the support nodes receive force
        let loaded = external.iter().filter(|f| f.norm() > 0.0).count();
        assert_eq!(loaded, support.iter().filter(|w| w.value > 0.0).count());
    }

    fn weight(node: usize, value: f64) -> NodeWeight<1> {
        NodeWeight {
            node,
            value,
            gradient: SVector::zeros(),
        }
    }

    #[test]
    fn all_active_is_the_plain_quadrature_and_inactive_shares_go_to_active_nodes() {
        let support = [weight(0, 0.25), weight(1, 0.5), weight(2, 0.25)];
        let force = SVector::<f64, 1>::new(8.0);
        let mut external = vec![SVector::<f64, 1>::zeros(); 3];
        assert!(spread_over_active(
            &force,
            &support,
            &[true; 3],
            &mut external
        ));
        assert_eq!(external, [2.0, 4.0, 2.0].map(SVector::<f64, 1>::new));

        let mut external = vec![SVector::<f64, 1>::zeros(); 3];
        assert!(spread_over_active(
            &force,
            &support,
            &[true, true, false],
            &mut external
        ));
        // 0.25 : 0.5 of the force, resultant kept
        assert!((external[0][0] - 8.0 / 3.0).abs() < 1e-12);
        assert!((external[1][0] - 16.0 / 3.0).abs() < 1e-12);
        assert_eq!(external[2][0], 0.0);

        let mut external = vec![SVector::<f64, 1>::zeros(); 3];
        assert!(!spread_over_active(
            &force,
            &support,
            &[false; 3],
            &mut external
        ));
        assert!(external.iter().all(|f| f[0] == 0.0));
    }
}
