//! Constitutive models: stress from deformation, and its linearisation for the Newton solver.
//!
//! The finite-deformation framework follows the paper (eqs. 2-3): with the deformation gradient
//! `F = dx/dX` and the left Cauchy-Green tensor `b = F F^T = V^2`, the logarithmic strain is
//! `eps = ln V = 1/2 ln b`, and the Kirchhoff stress `tau = J sigma` is a linear isotropic function
//! of `eps` ([`Hencky`]).
//!
//! # The [`Material`] trait
//!
//! A model answers one question per point and Newton iterate: given the trial deformation
//! (`F = Δf F^n` and the increment `Δf` of the load step) and the history it committed at the
//! end of the last converged step, what are the Kirchhoff stress `τ` (3x3), the spatial tangent
//! `c_abkd = 2 ∂τ_ab/∂b_kd` and the history this iterate would commit ([`Response`])? The
//! tangent is taken with respect to a left Cauchy-Green-like tensor `b` that the response also
//! returns: `b = F Fᵀ` for a hyperelastic model, the trial elastic `b_e = Δf b_e^n Δfᵀ` for
//! elasto-plasticity at finite strain (`F = F_e F_p`); `mechanics` turns `(τ, c, b)` into the
//! internal force and the consistent tangent, so assembly never knows which model it assembles.
//!
//! History is never written by a trial: the stress-update stage keeps the trial history beside
//! the committed one, and only a converged load step commits it (a cut step restarts from the
//! committed state). Models without history use `()`, which costs nothing per point.
//!
//! Every kernel here works on a full 3x3 `b` whatever the dimension `D` of the analysis (plane
//! strain and uniaxial strain simply pass a `b` whose out-of-plane block is the identity), so one
//! model serves 1D, 2D and 3D. The tangent is returned only for the `D` in-plane indices, as a
//! [`Tangent<D>`]. Kernels take plain `nalgebra` arguments and never panic.
//!
//! # Handing a point over to another model (`material_of`)
//!
//! A staged scene may give a body another material at a stage's start
//! (`effects::material_switches`). The old model and the new one need not know each other: the
//! old one says what a point hands over ([`Material::hand_over`]), the new one what it makes of
//! it ([`Material::take_over`]), through a [`CarriedState`]:
//!
//! ```text
//!   always        F_p (3x3, padded)   and   τ_p = τ_old(F_p, h_p)   (the response at Δf = I)
//!   if kept       b_e  (the elastic left Cauchy–Green tensor),   ε̄_p  (accumulated plastic strain)
//!   h_new = take_over(hand_over(h_p, {F_p, τ_p}))
//! ```
//!
//! Contract of `take_over`: the returned history is committed as it is, so the new model's
//! response at `Δf = I` from it is the stress the body goes on from; a model that keeps the
//! stress continuous returns a history whose response is `τ_p` (to round-off), or refuses. What
//! a model cannot take (no `b_e` where it needs one, a plastic strain it would lose, a stress
//! outside its yield surface) is an error, never dropped: the switch stops the run with the
//! `material_of` line. The defaults: `hand_over` gives only `F_p` and `τ_p` (a model without
//! internal variables); `take_over` refuses a carried `ε̄_p > 0` (it would be lost) and builds
//! the rest from `τ_p` by [`Material::history_from_stress`]. The crate's elasto-plastic models
//! hand over `b_e` and `ε̄_p` and take over through `elastoplastic::take_over` (the stress's
//! history, the plastic strain carried, a state on the new surface projected onto it within
//! `elastoplastic::ON_SURFACE_TOLERANCE`).
//!
//! # Models
//!
//! | file | model |
//! |---|---|
//! | [`hencky`] | Hencky elasticity (the paper's model) |
//! | [`elastoplastic`] | the finite-strain elasto-plastic framework shared by the plastic models: `F = F_e F_p`, Hencky in the elastic logarithmic strain, the return map in principal strain space (exponential map), history, output |
//! | [`von_mises`] | von Mises (J2) plasticity, perfect, with linear or Voce hardening or exponential softening (its laws in [`hardening`]); Tresca's undrained soil in plane strain |
//! | [`drucker_prager`] | Drucker–Prager with cone and apex returns, matched to Mohr–Coulomb |
//! | [`mohr_coulomb`] | Mohr–Coulomb with plane, edge and apex returns, optional tension cut-off |
//! | [`spectral`] | eigen-decomposition and the tangent of isotropic functions of `b`, shared |
//!
//! Adding a model: implement [`Material`] (and its parameters' scene description, see
//! `effects::materials`), then register `MaterialModule::<YourModel>` with the other modules;
//! `examples/custom_material/` does it for a compressible neo-Hookean solid outside the crate.

pub mod cohesion;
pub mod drucker_prager;
pub mod elastoplastic;
pub mod hardening;
pub mod hencky;
pub mod mohr_coulomb;
pub mod spectral;
pub mod von_mises;

pub use drucker_prager::DruckerPrager;
pub use elastoplastic::{ON_SURFACE_TOLERANCE, PlasticHistory};
pub use hencky::{Hencky, Tangent};
pub use mohr_coulomb::MohrCoulomb;
pub use von_mises::VonMises;

use std::fmt::Debug;

use nalgebra::{Matrix3, SMatrix};

/// A D x D matrix embedded in 3x3 with the identity in the remaining diagonal (the plane-strain
/// and uniaxial-strain padding of `F`, `Δf` and `b`).
pub fn embed<const D: usize>(m: &SMatrix<f64, D, D>) -> Matrix3<f64> {
    let mut out = Matrix3::identity();
    for a in 0..D {
        for b in 0..D {
            out[(a, b)] = m[(a, b)];
        }
    }
    out
}

/// The top-left D x D block of a 3x3 matrix.
pub fn block<const D: usize>(m: &Matrix3<f64>) -> SMatrix<f64, D, D> {
    SMatrix::from_fn(|a, b| m[(a, b)])
}

pub use crate::parameter::{ParameterKind, ParameterSpec, Range};

/// What a model returns for a trial deformation.
#[derive(Clone, Debug, PartialEq)]
pub struct Response<const D: usize, H> {
    /// Kirchhoff stress τ, full 3x3.
    pub kirchhoff: Matrix3<f64>,
    /// `c_abkd = 2 ∂τ_ab/∂b_kd` for the in-plane indices.
    pub tangent: Tangent<D>,
    /// The tensor `b` (D x D block) the tangent is taken with respect to: `F Fᵀ` for
    /// hyperelastic models, the trial elastic left Cauchy-Green tensor for plastic ones.
    pub left_cauchy_green: SMatrix<f64, D, D>,
    /// The history this iterate would commit if the load step converged here.
    pub history: H,
}

/// What a point hands over from its old model to its new one when its body changes material
/// (module docs, "Handing a point over to another model").
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CarriedState {
    /// The point's deformation gradient `F` (3x3, padded with the identity), which it keeps.
    pub deformation_gradient: Matrix3<f64>,
    /// The old model's Kirchhoff stress τ at the committed state (the response at `Δf = I`).
    pub stress: Matrix3<f64>,
    /// The elastic left Cauchy–Green tensor `b_e` (3x3, symmetric), where the old model keeps
    /// one.
    pub elastic_left_cauchy_green: Option<Matrix3<f64>>,
    /// The accumulated equivalent plastic strain `ε̄_p`, where the old model keeps one.
    pub plastic_strain: Option<f64>,
}

impl CarriedState {
    /// What every point hands over: its `F` and its stress, no internal variables.
    pub fn of_stress(deformation_gradient: Matrix3<f64>, stress: Matrix3<f64>) -> Self {
        Self {
            deformation_gradient,
            stress,
            elastic_left_cauchy_green: None,
            plastic_strain: None,
        }
    }
}

/// A constitutive model (see the module docs).
pub trait Material: Clone + Debug + PartialEq + Send + Sync + 'static {
    /// The state a point carries from one converged load step to the next (`()` if none).
    type History: Clone + Debug + Default + PartialEq + Send + Sync + HistoryValues + 'static;

    /// The model's word in scenes: `material(#{ model: "hencky", .. })`.
    const MODEL: &'static str;

    /// Whether the model carries history (points then get a history component).
    const HAS_HISTORY: bool = std::mem::size_of::<Self::History>() > 0;

    /// The model's parameters (names, meanings, ranges): the scene reads and documents
    /// `material(#{ model: .., .. })` by them.
    fn parameters() -> Vec<ParameterSpec>;

    /// Builds the model from its parameters, checking them (ranges, combinations).
    fn from_parameters(parameters: &MaterialParameters) -> Result<Self, String>;

    /// One line on what the model is (the reference of material models).
    fn describe() -> &'static str;

    /// The point fields the model adds to the output: `(name, components)`, e.g.
    /// `("plastic_strain", 1)`. None by default.
    fn output_fields() -> &'static [(&'static str, usize)] {
        &[]
    }

    /// The values of [`Material::output_fields`] for a point's committed history, appended to
    /// `out` in field order.
    fn output_values(_history: &Self::History, _out: &mut Vec<f64>) {}

    /// The response at the trial state `F = Δf F^n` from the committed history.
    fn respond<const D: usize>(
        &self,
        deformation_gradient: &SMatrix<f64, D, D>,
        increment: &SMatrix<f64, D, D>,
        committed: &Self::History,
    ) -> Result<Response<D, Self::History>, String>;

    /// A stiffness scale of the model (Young's modulus for isotropic models), used for the
    /// default penalty factors of the ghost penalty and of weakly imposed conditions.
    fn stiffness_scale(&self) -> f64;

    /// Whether the consistent tangent of the model is symmetric (hyperelastic and associated
    /// plastic models are; the linear solve must not use Cholesky otherwise).
    fn tangent_is_symmetric(&self) -> bool {
        true
    }

    /// The committed history of a point that carries the Kirchhoff stress `stress` (3x3,
    /// symmetric) before any deformation: the seam of initial stresses (a geostatic `K0`
    /// state). A model whose history cannot hold a stress (hyperelastic ones, whose stress is
    /// a function of `F` alone) says so; a stress the model cannot carry (outside its yield
    /// surface) is an error.
    fn history_from_stress(&self, _stress: &Matrix3<f64>) -> Result<Self::History, String> {
        Err(format!(
            "the '{}' model cannot start from an initial stress (its stress is a function of the deformation alone)",
            Self::MODEL
        ))
    }

    /// What a point of this model with the committed history `committed` hands over when its
    /// body takes another material (module docs): `carried` holds its `F` and stress; a model
    /// adds the internal variables it keeps (`b_e`, `ε̄_p`). By default nothing more.
    fn hand_over(&self, _committed: &Self::History, carried: CarriedState) -> CarriedState {
        carried
    }

    /// The committed history of a point that takes this model with the state `carried` from
    /// its old one (module docs, for the contract), or an error saying what cannot be carried.
    /// By default: a plastic strain `ε̄_p > 0` is refused (this model keeps none: it would be
    /// lost), and the history is [`Material::history_from_stress`] of the stress.
    fn take_over(&self, carried: &CarriedState) -> Result<Self::History, String> {
        if let Some(strain) = carried.plastic_strain.filter(|&e| e > 0.0) {
            return Err(format!(
                "the '{}' model does not take an accumulated plastic strain (Material::take_over): the point's {strain:.6e} would be lost",
                Self::MODEL
            ));
        }
        self.history_from_stress(&carried.stress)
    }
}

/// A point's history as a fixed number of values, for saved states (`checkpoint`).
pub trait HistoryValues: Sized {
    /// How many values one history takes.
    const LEN: usize;
    /// Appends the [`HistoryValues::LEN`] values.
    fn write(&self, out: &mut Vec<f64>);
    /// The history of `values` (exactly `LEN` of them), if they make one.
    fn read(values: &[f64]) -> Option<Self>;
}

/// The six independent values of a symmetric 3×3 tensor in the order histories store them:
/// xx, yy, zz, xy, yz, xz (what [`symmetric_from_values`] reads back).
pub fn symmetric_values(m: &Matrix3<f64>) -> [f64; 6] {
    [
        m[(0, 0)],
        m[(1, 1)],
        m[(2, 2)],
        m[(0, 1)],
        m[(1, 2)],
        m[(0, 2)],
    ]
}

/// The symmetric 3×3 tensor of six values in [`symmetric_values`]' order, if there are six.
pub fn symmetric_from_values(values: &[f64]) -> Option<Matrix3<f64>> {
    let &[xx, yy, zz, xy, yz, xz] = values else {
        return None;
    };
    Some(Matrix3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz))
}

/// No history.
impl HistoryValues for () {
    const LEN: usize = 0;
    fn write(&self, _out: &mut Vec<f64>) {}
    fn read(values: &[f64]) -> Option<Self> {
        values.is_empty().then_some(())
    }
}

/// The parameters of a material as the scene gives them: `E`, `nu`, `phi`... by name.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialParameters(pub Vec<(String, ParameterValue)>);

/// One parameter value.
#[derive(Clone, Debug, PartialEq)]
pub enum ParameterValue {
    Number(f64),
    Text(String),
    Flag(bool),
}

impl MaterialParameters {
    /// Parameters from `(name, number)` pairs.
    pub fn numbers(pairs: &[(&str, f64)]) -> Self {
        Self(
            pairs
                .iter()
                .map(|&(name, value)| (name.to_string(), ParameterValue::Number(value)))
                .collect(),
        )
    }

    pub fn get(&self, name: &str) -> Option<&ParameterValue> {
        self.0.iter().find(|(key, _)| key == name).map(|(_, v)| v)
    }

    /// A number parameter, or an error naming it.
    pub fn number(&self, name: &str) -> Result<f64, String> {
        match self.get(name) {
            Some(ParameterValue::Number(value)) => Ok(*value),
            Some(other) => Err(format!(
                "parameter '{name}' must be a number, got {other:?}"
            )),
            None => Err(format!("missing parameter '{name}'")),
        }
    }

    /// An optional number parameter.
    pub fn optional_number(&self, name: &str) -> Result<Option<f64>, String> {
        match self.get(name) {
            None => Ok(None),
            Some(_) => self.number(name).map(Some),
        }
    }
}
