//! The finite-strain elasto-plastic framework shared by the plastic models.
//!
//! # Formulation (de Souza Neto, Perić & Owen, *Computational Methods for Plasticity*, ch. 14)
//!
//! The deformation gradient splits multiplicatively, `F = F_e F_p`; the elastic part is Hencky's:
//! the Kirchhoff stress is linear in the elastic logarithmic strain `ε_e = ½ ln b_e`,
//! `b_e = F_e F_eᵀ`, with the bulk modulus `K` and the shear modulus `G`. A point carries the
//! elastic left Cauchy–Green tensor `b_e^n` of the last converged load step and the accumulated
//! equivalent plastic strain `ε̄_p^n` ([`PlasticHistory`]). In a load step with increment `Δf`:
//!
//! ```text
//! elastic predictor   b_e^tr = Δf b_e^n Δfᵀ = Σ_A λ_A n_A n_Aᵀ,   ε^tr_A = ½ ln λ_A
//! trial stress        τ^tr_A = K tr ε^tr + 2G (ε^tr_A − ⅓ tr ε^tr)
//! return map          (τ_A, D_AB = ∂τ_A/∂ε^tr_B) = the small-strain return map of the model
//!                     in principal space, from τ^tr and ε̄_p^n
//! update              τ = Σ_A τ_A n_A n_Aᵀ,   ε_e = D_e⁻¹ τ,   b_e^{n+1} = Σ_A e^{2 ε_e,A} n_A n_Aᵀ
//!                     ε̄_p^{n+1} = ε̄_p^n + √(2/3) ‖ε^tr − ε_e‖   (or the model's Δε̄_p)
//! ```
//!
//! `ε̄_p` is the hardening variable the return map is given, and the `plastic_strain` output: a
//! model whose hardening variable is not `√(2/3) ‖Δε_p‖` (the frictional models' cohesion
//! hardening, `cohesion.rs`: a multiple of the sum of the multipliers) returns its increment
//! (`PrincipalReturn::plastic_strain_increment`), which is then what is accumulated.
//!
//! The exponential map integrates the plastic flow `−½ L_v b_e = Δγ ∂Ψ/∂τ b_e` exactly in
//! direction for isotropic yield functions, so the principal-space return map is the small-strain
//! one, word for word: the eigenvectors of `b_e^tr` are those of `τ` and `b_e^{n+1}`. The
//! response's tangent is `c = 2 ∂τ/∂b_e^tr`, built from the algorithmic principal tangent `D` by
//! [`isotropic_tangent`] (the eigenprojections' derivative is in `spectral.rs`), and it is taken at
//! `b = b_e^tr`. Since `∂b_e^tr/∂Δu_j = e_k ⊗ (b_e^tr g_j) + (b_e^tr g_j) ⊗ e_k`, the same form
//! as for `b = F Fᵀ`, `mechanics` assembles the consistent tangent of the plastic step exactly as
//! for Hencky (`K_ij = V0 (g_i · c · b_e^tr g_j − (τ g_j) ⊗ g_i)`), which the finite-difference
//! tests check at every return region.
//!
//! When `D` is symmetric (associated flow) the stress derives from an incremental potential of
//! `ε^tr` and the assembled tangent is symmetric; non-associated flow makes `D`, and with it the
//! assembled tangent, non-symmetric (`Material::tangent_is_symmetric`).
//!
//! In plane strain (`D = 2`) and uniaxial strain (`D = 1`) `Δf` is padded with ones, and the
//! out-of-plane component of `b_e` evolves with the plastic flow (it is kept in the history).
//!
//! # What a model provides
//!
//! A model is its elastic part ([`Hencky`]) and a principal-space return map: a function of the
//! trial principal strains and stresses and the committed `ε̄_p^n` returning a
//! [`PrincipalReturn`]. [`respond`] does everything else.

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::spectral::{Spectral, isotropic_tangent};
use super::{
    CarriedState, Hencky, HistoryValues, Response, block, embed, symmetric_from_values,
    symmetric_values,
};

/// The history of an elasto-plastic point.
#[derive(Clone, Debug, PartialEq)]
pub struct PlasticHistory {
    /// The elastic left Cauchy–Green tensor `b_e` (3x3, symmetric).
    pub elastic_left_cauchy_green: Matrix3<f64>,
    /// The accumulated equivalent plastic strain `ε̄_p = Σ √(2/3) ‖Δε_p‖`.
    pub plastic_strain: f64,
    /// Whether the point flowed plastically in the step that produced this history.
    pub yielding: bool,
}

impl Default for PlasticHistory {
    /// The undeformed, virgin state: `b_e = I`, no plastic strain.
    fn default() -> Self {
        Self {
            elastic_left_cauchy_green: Matrix3::identity(),
            plastic_strain: 0.0,
            yielding: false,
        }
    }
}

/// `b_e` (6 values: xx, yy, zz, xy, yz, xz), `ε̄_p`, yielding (0 or 1).
impl HistoryValues for PlasticHistory {
    const LEN: usize = 8;

    fn write(&self, out: &mut Vec<f64>) {
        out.extend_from_slice(&symmetric_values(&self.elastic_left_cauchy_green));
        out.extend_from_slice(&[self.plastic_strain, if self.yielding { 1.0 } else { 0.0 }]);
    }

    fn read(values: &[f64]) -> Option<Self> {
        let &[.., plastic_strain, yielding] = values else {
            return None;
        };
        if values.len() != Self::LEN
            || values.iter().any(|v| !v.is_finite())
            || plastic_strain < 0.0
        {
            return None;
        }
        let b = symmetric_from_values(&values[..6])?;
        Spectral::try_new(&b).ok()?;
        Some(Self {
            elastic_left_cauchy_green: b,
            plastic_strain,
            yielding: yielding != 0.0,
        })
    }
}

/// The output fields every plastic model writes: the accumulated equivalent plastic strain and
/// whether the point yielded in the step.
pub const OUTPUT_FIELDS: &[(&str, usize)] = &[("plastic_strain", 1), ("yielding", 1)];

/// The values of [`OUTPUT_FIELDS`] for a history.
pub fn output_values(history: &PlasticHistory, out: &mut Vec<f64>) {
    out.push(history.plastic_strain);
    out.push(if history.yielding { 1.0 } else { 0.0 });
}

/// A model whose plastic correction is a return map in principal logarithmic-strain space over
/// a Hencky elasticity: everything else of its [`Material`](super::Material) implementation is
/// the same for every such model and comes from `elastoplastic_material_methods!`.
pub trait PrincipalReturnMap {
    /// The elasticity of the model.
    fn elasticity(&self) -> &Hencky;

    /// The return of the trial principal state (logarithmic strains, Kirchhoff stresses) with the
    /// committed hardening variable `alpha`.
    fn principal_return(
        &self,
        strain: &Vector3<f64>,
        stress: &Vector3<f64>,
        alpha: f64,
    ) -> Result<PrincipalReturn, String>;
}

/// The methods of [`Material`](super::Material) shared by every [`PrincipalReturnMap`] model:
/// output fields, the response through [`respond`], the stiffness scale and initial stresses
/// through [`history_from_stress`], a body's change of material through [`hand_over`] and
/// [`take_over`]. Used inside `impl Material for Model { .. }`.
macro_rules! elastoplastic_material_methods {
    () => {
        fn output_fields() -> &'static [(&'static str, usize)] {
            elastoplastic::OUTPUT_FIELDS
        }

        fn output_values(history: &PlasticHistory, out: &mut Vec<f64>) {
            elastoplastic::output_values(history, out);
        }

        fn respond<const D: usize>(
            &self,
            _deformation_gradient: &SMatrix<f64, D, D>,
            increment: &SMatrix<f64, D, D>,
            committed: &PlasticHistory,
        ) -> Result<Response<D, PlasticHistory>, String> {
            use elastoplastic::PrincipalReturnMap;
            elastoplastic::respond(self.elasticity(), increment, committed, |e, t, a| {
                self.principal_return(e, t, a)
            })
        }

        fn stiffness_scale(&self) -> f64 {
            use elastoplastic::PrincipalReturnMap;
            self.elasticity().youngs_modulus
        }

        fn history_from_stress(&self, stress: &Matrix3<f64>) -> Result<PlasticHistory, String> {
            use elastoplastic::PrincipalReturnMap;
            elastoplastic::history_from_stress(self.elasticity(), stress, |e, t, a| {
                self.principal_return(e, t, a)
            })
        }

        fn hand_over(
            &self,
            committed: &PlasticHistory,
            carried: super::CarriedState,
        ) -> super::CarriedState {
            elastoplastic::hand_over(committed, carried)
        }

        fn take_over(&self, carried: &super::CarriedState) -> Result<PlasticHistory, String> {
            elastoplastic::take_over(self, carried)
        }
    };
}
pub(super) use elastoplastic_material_methods;

/// What a principal-space return map gives.
#[derive(Clone, Debug, PartialEq)]
pub struct PrincipalReturn {
    /// The principal Kirchhoff stresses `τ_A`.
    pub stress: Vector3<f64>,
    /// The algorithmic tangent `∂τ_A/∂ε^tr_B`.
    pub tangent: Matrix3<f64>,
    /// `(τ_A − τ_B)/(ε^tr_A − ε^tr_B)` if it is the same for every pair (radial returns), which
    /// the tangent then uses instead of the difference quotient.
    pub pair_modulus: Option<f64>,
    /// Whether the return was plastic.
    pub yielding: bool,
    /// The model's equivalent plastic strain increment `Δε̄_p` (its hardening variable's, in
    /// terms of its multipliers), if it defines one; `None`: `√(2/3) ‖ε^tr − ε_e‖`.
    pub plastic_strain_increment: Option<f64>,
}

impl PrincipalReturn {
    /// The elastic answer: `τ^tr` with the elasticity tangent.
    pub fn elastic(elastic: &Hencky, trial_stress: Vector3<f64>) -> Self {
        let (_, shear) = elastic.lame();
        Self {
            stress: trial_stress,
            tangent: elasticity(elastic),
            pair_modulus: Some(2.0 * shear),
            yielding: false,
            plastic_strain_increment: None,
        }
    }
}

/// The principal elasticity matrix `D_e = λ 1⊗1 + 2G I`.
pub fn elasticity(elastic: &Hencky) -> Matrix3<f64> {
    let (lambda, shear) = elastic.lame();
    Matrix3::from_element(lambda) + Matrix3::identity() * (2.0 * shear)
}

/// The bulk and shear moduli `(K, G)`.
pub fn bulk_and_shear(elastic: &Hencky) -> (f64, f64) {
    let (lambda, shear) = elastic.lame();
    (lambda + 2.0 / 3.0 * shear, shear)
}

/// The principal strains of principal stresses, `D_e⁻¹ τ`.
pub fn elastic_strain(elastic: &Hencky, stress: &Vector3<f64>) -> Vector3<f64> {
    let (bulk, shear) = bulk_and_shear(elastic);
    let mean = stress.sum() / 3.0;
    stress.map(|s| (s - mean) / (2.0 * shear) + mean / (3.0 * bulk))
}

/// The history of a point that carries the Kirchhoff stress `τ_0` before any deformation (an
/// initial stress, e.g. geostatic `K0`): on the principal axes of `τ_0`,
/// `b_e = exp(2 D_e⁻¹ τ_0)`, so that the elastic response at `F = I` is `τ_0` exactly, and no
/// plastic strain. A stress outside the yield surface (`return_map` flows plastically from it,
/// with `ε̄_p = 0`) or not symmetric and finite is an error.
pub fn history_from_stress(
    elastic: &Hencky,
    stress: &Matrix3<f64>,
    return_map: impl FnOnce(&Vector3<f64>, &Vector3<f64>, f64) -> Result<PrincipalReturn, String>,
) -> Result<PlasticHistory, String> {
    let scale = stress.amax().max(f64::MIN_POSITIVE);
    if stress.iter().any(|s| !s.is_finite()) || (stress - stress.transpose()).amax() > 1e-12 * scale
    {
        return Err(format!(
            "an initial stress must be finite and symmetric, got {stress:?}"
        ));
    }
    let eigen = stress.symmetric_eigen();
    let principal = eigen.eigenvalues;
    let strain = elastic_strain(elastic, &principal);
    let returned = return_map(&strain, &principal, 0.0)?;
    if returned.yielding {
        return Err(format!(
            "the initial stress with principal values {:?} lies outside the yield surface",
            principal.as_slice()
        ));
    }
    let q = eigen.eigenvectors;
    let stretch = Matrix3::from_diagonal(&strain.map(|e| (2.0 * e).exp()));
    let b = q * stretch * q.transpose();
    Ok(PlasticHistory {
        elastic_left_cauchy_green: (b + b.transpose()) * 0.5,
        plastic_strain: 0.0,
        yielding: false,
    })
}

/// What an elasto-plastic point hands over when its body takes another material: its `b_e`
/// and `ε̄_p` beside the `F` and stress in `carried`.
pub fn hand_over(committed: &PlasticHistory, carried: CarriedState) -> CarriedState {
    CarriedState {
        elastic_left_cauchy_green: Some(committed.elastic_left_cauchy_green),
        plastic_strain: Some(committed.plastic_strain),
        ..carried
    }
}

/// How far (relative to the yield stress there) a stress may lie outside the yield surface of a
/// model a point is switched to and still be taken, projected onto it by the model's return map
/// ([`take_over`]).
pub const ON_SURFACE_TOLERANCE: f64 = 1e-6;

/// The history of a point that takes the elasto-plastic `model` with the state `carried`
/// (`Material::take_over`): the history of its stress, with the plastic strain carried.
///
/// The stress `τ_p` gives `b_e = exp(2 D_e⁻¹ τ_p)` on its principal axes ([`history_from_stress`],
/// which checks `τ_p` against the surface at `ε̄_p = 0`), so the model's response at `Δf = I` is
/// `τ_p` again (to round-off); a carried `ε̄_p > 0` replaces the zero (a hardening model goes on
/// from `σ_y + H ε̄_p`). A point that yielded under its old model lies *on* a surface, and when
/// the new surface passes through it round-off may put it just outside: when the check refuses,
/// or when a plastic strain is carried (the surface then is the one at `ε̄_p`), the history of
/// `τ_p` is built without the check ([`elastic_history_unchecked`]) and the model evaluated at it
/// (`Δf = I`): its return map gives the closest admissible stress `τ_r`, taken when
///
/// ```text
///   ‖τ_r − τ_p‖ ≤ 1e-6 q(τ_r)          (q: the von Mises equivalent stress, the yield stress
///                                     of the new surface at that pressure)
/// ```
///
/// ([`ON_SURFACE_TOLERANCE`]: round-off of the exp/log chain is `~1e-16 E/σ_y` relative), and
/// refused otherwise with the departure. The carried `b_e` is not used: the stress, not the
/// elastic strain, is continuous across a change of elastic constants.
pub fn take_over<M: PrincipalReturnMap>(
    model: &M,
    carried: &CarriedState,
) -> Result<PlasticHistory, String> {
    let elastic = model.elasticity();
    let return_map = |e: &Vector3<f64>, t: &Vector3<f64>, a: f64| model.principal_return(e, t, a);
    let tau = carried.stress;
    let (mut history, refused) = match history_from_stress(elastic, &tau, return_map) {
        Ok(history) => (history, None),
        Err(why) => match elastic_history_unchecked(elastic, &tau, return_map) {
            Some(history) => (history, Some(why)),
            None => return Err(why),
        },
    };
    let strain = carried.plastic_strain.filter(|&e| e > 0.0);
    if let Some(strain) = strain {
        history.plastic_strain = strain;
    }
    if refused.is_none() && strain.is_none() {
        return Ok(history);
    }
    let response = respond::<3>(elastic, &Matrix3::identity(), &history, return_map)
        .map_err(|why| format!("the new model's response at the switch: {why}"))?;
    let projected = response.history;
    if !projected.yielding && refused.is_none() {
        return Ok(history);
    }
    let returned = response.kirchhoff;
    let deviator = returned - Matrix3::identity() * (returned.trace() / 3.0);
    let yield_stress = (1.5 * deviator.norm_squared()).sqrt();
    let departure = (returned - tau).norm();
    if departure <= ON_SURFACE_TOLERANCE * yield_stress {
        return Ok(projected);
    }
    Err(format!(
        "{}: the stress lies outside the new yield surface by {:.3e} of the yield stress there ({:.6e}), beyond the {ON_SURFACE_TOLERANCE:e} within which a state on the surface is projected onto it",
        refused.unwrap_or_else(|| "with the plastic strain carried".to_string()),
        departure / yield_stress.max(f64::MIN_POSITIVE),
        yield_stress
    ))
}

/// The elastic history of the stress `tau` without the yield check of [`history_from_stress`]:
/// `ln b_e = 2 D_e⁻¹ τ = dev τ / G + 2 tr τ / (9K) I` is linear in `τ`, so with two stresses
/// the check accepts, `σ₁ = p₀ I` and `σ₂ = p₀ I + ε dev τ` (`p₀` compressive, where every
/// surface is widest; `ε` halved until accepted),
/// `ln b_e(τ) = (ln b_e(σ₂) − ln b_e(σ₁))/ε + (p/p₀) ln b_e(σ₁)`. `None` when the model accepts
/// no such pair.
pub fn elastic_history_unchecked(
    elastic: &Hencky,
    tau: &Matrix3<f64>,
    return_map: impl Fn(&Vector3<f64>, &Vector3<f64>, f64) -> Result<PrincipalReturn, String>,
) -> Option<PlasticHistory> {
    let history_of = |sigma: &Matrix3<f64>| history_from_stress(elastic, sigma, &return_map).ok();
    let log = |sigma: &Matrix3<f64>| -> Option<Matrix3<f64>> {
        let b = history_of(sigma)?.elastic_left_cauchy_green;
        let eigen = b.symmetric_eigen();
        Some(
            eigen.eigenvectors
                * Matrix3::from_diagonal(&eigen.eigenvalues.map(f64::ln))
                * eigen.eigenvectors.transpose(),
        )
    };
    let mean = tau.trace() / 3.0;
    let deviator = tau - Matrix3::identity() * mean;
    let p0 = -4.0 * tau.norm().max(f64::MIN_POSITIVE.sqrt());
    let first = log(&(Matrix3::identity() * p0))?;
    let (epsilon, second) = (0..40).find_map(|k| {
        let epsilon = 0.5f64.powi(k);
        log(&(Matrix3::identity() * p0 + deviator * epsilon)).map(|l| (epsilon, l))
    })?;
    let ln_b = (second - first) / epsilon + first * (mean / p0);
    let eigen = ln_b.symmetric_eigen();
    let b = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(f64::exp))
        * eigen.eigenvectors.transpose();
    let mut history = history_of(&(Matrix3::identity() * p0))?;
    history.elastic_left_cauchy_green = (b + b.transpose()) * 0.5;
    Some(history)
}

/// The elasto-plastic response (module docs) of a model with elastic part `elastic` and
/// principal-space return map `return_map(trial strains, trial stresses, committed ε̄_p)`.
pub fn respond<const D: usize>(
    elastic: &Hencky,
    increment: &SMatrix<f64, D, D>,
    committed: &PlasticHistory,
    return_map: impl FnOnce(&Vector3<f64>, &Vector3<f64>, f64) -> Result<PrincipalReturn, String>,
) -> Result<Response<D, PlasticHistory>, String> {
    let df = embed(increment);
    let trial = df * committed.elastic_left_cauchy_green * df.transpose();
    let spectral = Spectral::try_new(&trial)?;
    let strain = spectral.log_strains();
    let trial_stress = elasticity(elastic) * strain;
    let returned = return_map(&strain, &trial_stress, committed.plastic_strain)?;
    if returned.stress.iter().any(|s| !s.is_finite()) {
        return Err(format!(
            "the return map gave a non-finite stress {:?} from the trial strains {:?}",
            returned.stress, strain
        ));
    }
    let elastic_strain = elastic_strain(elastic, &returned.stress);
    let plastic_increment = strain - elastic_strain;
    let history = PlasticHistory {
        elastic_left_cauchy_green: spectral.compose(&elastic_strain.map(|e| (2.0 * e).exp())),
        plastic_strain: committed.plastic_strain
            + if returned.yielding {
                returned
                    .plastic_strain_increment
                    .unwrap_or_else(|| (2.0 / 3.0f64).sqrt() * plastic_increment.norm())
            } else {
                0.0
            },
        yielding: returned.yielding,
    };
    let tangent = isotropic_tangent::<D>(
        &spectral,
        &strain,
        &returned.stress,
        &returned.tangent,
        returned.pair_modulus,
    );
    Ok(Response {
        kirchhoff: spectral.compose(&returned.stress),
        tangent,
        left_cauchy_green: block::<D>(&trial),
        history,
    })
}

/// The deviatoric part `e = ε − ⅓ tr ε` of a principal vector.
pub fn deviator(v: &Vector3<f64>) -> Vector3<f64> {
    let mean = v.sum() / 3.0;
    v.map(|x| x - mean)
}

/// The deviatoric projector `I − ⅓ 1⊗1` on principal vectors.
pub fn deviatoric_projector() -> Matrix3<f64> {
    Matrix3::identity() - Matrix3::from_element(1.0 / 3.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn history_values_round_trip_and_reject_nonsense() {
        let history = PlasticHistory {
            elastic_left_cauchy_green: Matrix3::new(
                1.1, 0.05, 0.0, 0.05, 0.9, 0.01, 0.0, 0.01, 1.0,
            ),
            plastic_strain: 0.03,
            yielding: true,
        };
        let mut values = Vec::new();
        history.write(&mut values);
        assert_eq!(values.len(), PlasticHistory::LEN);
        assert_eq!(PlasticHistory::read(&values), Some(history));
        assert_eq!(PlasticHistory::read(&values[..7]), None);
        let mut negative = values.clone();
        negative[0] = -1.0; // b_e not positive definite
        assert_eq!(PlasticHistory::read(&negative), None);
    }

    /// An elastic return gives Hencky's stress and tangent (the framework adds nothing).
    #[test]
    fn an_elastic_return_is_hencky_elasticity() {
        let elastic = Hencky::new(1000.0, 0.25).unwrap();
        let df = SMatrix::<f64, 3, 3>::new(1.1, 0.05, 0.0, -0.02, 0.95, 0.03, 0.01, 0.0, 1.02);
        let response = respond::<3>(&elastic, &df, &PlasticHistory::default(), |_, stress, _| {
            Ok(PrincipalReturn::elastic(&elastic, *stress))
        })
        .unwrap();
        let b = df * df.transpose();
        let (tau, tangent) = elastic.kirchhoff_and_tangent::<3>(&b);
        assert!((response.kirchhoff - tau).amax() < 1e-10 * 1000.0);
        let worst = response
            .tangent
            .as_flattened()
            .as_flattened()
            .iter()
            .flatten()
            .zip(tangent.as_flattened().as_flattened().iter().flatten())
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(worst < 1e-8 * 1000.0, "{worst:e}");
        assert!((response.history.elastic_left_cauchy_green - b).amax() < 1e-12);
        assert_eq!(response.history.plastic_strain, 0.0);
    }
}
