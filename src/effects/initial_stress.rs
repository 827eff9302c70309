//! Geostatic initial stresses: `initial_stress(#{ K0: .., unit_weight: γ, surface: z_s })`
//! gives every material point, before the first load step, the `K0` state of soil under its
//! own weight below a horizontal surface at height `z_s` (the last axis is vertical):
//!
//! ```text
//!   σ_v = −γ (z_s − z),    σ_h = K0 σ_v    (tension positive; every horizontal direction,
//!                                           the out-of-plane one in plane strain included),
//! ```
//!
//! zero above the surface. Before any deformation the Kirchhoff stress equals the Cauchy
//! stress, and each point's committed history is `Material::history_from_stress(σ)` (the
//! elastic left Cauchy–Green tensor `b_e = exp(2 D_e⁻¹ σ)` of the plastic models): the material
//! returns `σ` at `F = I`. It is applied by each material's module (`materials.rs`); a model
//! whose stress is a function of `F` alone (Hencky) cannot carry it, and a state outside a yield
//! surface is rejected: both with the line of the call.
//!
//! The stresses are in equilibrium with the weight `γ` per unit volume, `∂σ_v/∂z = γ`, with
//! a free surface: held in full from the first step on, `body_force([0, .., −γ/ρ0],
//! #{ held: true })`, the internal and external forces balance (up to the points' quadrature
//! of the weight and the stress), so the body stays put while the other loads of the scene
//! follow the schedule (a footing pushed into the soil: `scripts/strip_footing.rhai
//! --set weight=true`). A weight that ramps with the load factor would not balance it.

use nalgebra::Matrix3;
use rhai::Dynamic;

use crate::parameter::Range;
use crate::plugin::{Extension, Plugin};
use crate::scene::{
    CallSpec, Kind, Located, OptionSpec, Options, Resolver, SceneApi, SceneSpec, ScriptError,
};

/// The scene's geostatic state.
#[derive(Clone, Debug, PartialEq)]
pub struct InitialStressSpec {
    /// Lateral earth pressure coefficient at rest, `σ_h / σ_v`.
    pub k0: f64,
    /// Weight per unit volume γ.
    pub unit_weight: f64,
    /// Height of the horizontal ground surface (coordinate along the last axis).
    pub surface: f64,
    /// " (line N)" of the call, for messages.
    pub line_note: String,
}

impl InitialStressSpec {
    /// The stress at height `z` in a scene of dimension `dim` (vertical axis `dim − 1`).
    pub fn stress_at(&self, z: f64, dim: usize) -> Matrix3<f64> {
        let vertical = -self.unit_weight * (self.surface - z).max(0.0);
        let mut stress = Matrix3::identity() * (self.k0 * vertical);
        stress[(dim - 1, dim - 1)] = vertical;
        stress
    }
}

/// The module: the scene word; the materials' modules apply it.
#[derive(Clone, Copy, Debug, Default)]
pub struct InitialStressModule;

impl Plugin for InitialStressModule {
    fn name(&self) -> &'static str {
        "initial stress"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::options(
            "initial_stress",
            "geostatic initial stresses of every body (call once): σ_v = −γ (z_s − z) below the surface z_s (last axis vertical, tension positive), σ_h = K0 σ_v in every horizontal direction; the points' models must carry a stress in their history (the plastic ones)",
            vec![
                OptionSpec::required(
                    "K0",
                    Kind::Number(Range::NonNegative),
                    "lateral earth pressure coefficient at rest, σ_h / σ_v",
                ),
                OptionSpec::required(
                    "unit_weight",
                    Kind::Number(Range::Positive),
                    "weight per unit volume γ (ρ0 g of the body force that balances it)",
                ),
                OptionSpec::required(
                    "surface",
                    Kind::Number(Range::Any),
                    "height of the horizontal ground surface (coordinate along the last axis)",
                ),
            ],
            |builder, options: &Options, at| {
                if let Some(previous) = builder.declared::<InitialStressSpec>().first() {
                    return Err(format!(
                        "initial_stress(...) was already called{}; call it once",
                        previous.line_note()
                    ));
                }
                let mut spec = InitialStressSpec {
                    k0: options.number("K0").unwrap_or_default(),
                    unit_weight: options.number("unit_weight").unwrap_or_default(),
                    surface: options.number("surface").unwrap_or_default(),
                    line_note: String::new(),
                };
                spec.line_note = Located::new((), at).line_note();
                builder.declare(Located::new(spec, at));
                Ok(Dynamic::UNIT)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let Some(declared) = scene.declarations::<InitialStressSpec>().first().cloned() else {
            return Ok(());
        };
        for body in &scene.spec.bodies {
            let model = scene
                .spec
                .materials
                .get(body.material)
                .map_or("", |m| m.model.as_str());
            if model == "hencky" {
                return Err(ScriptError::at(
                    declared.at,
                    format!(
                        "initial_stress(...): body '{}' is of the hyperelastic model 'hencky', whose stress is a function of the deformation alone: it cannot start from an initial stress (use a plastic model)",
                        body.name
                    ),
                ));
            }
        }
        scene.spec.set_part(declared.value);
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        spec.part::<InitialStressSpec>().map(|s| {
            format!(
                "K0 = {}, γ = {}, surface at {}",
                s.k0, s.unit_weight, s.surface
            )
        })
    }

    /// Used by a scene that calls `initial_stress(..)` (so `impm check --explain` lists it);
    /// it schedules nothing itself: the materials' modules apply the stresses when they build.
    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<InitialStressSpec>().is_some()
    }

    fn build<const D: usize>(&self, _simulation: &mut Extension<'_, D>) {}
}
