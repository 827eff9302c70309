//! A warning for scenes with a softening material: a softening cohesion (`H < 0` on
//! `drucker_prager` or `mohr_coulomb`, `material::cohesion`), the exponential softening of c, φ
//! and ψ (`softening_rate` on `drucker_prager`, `material::cohesion`) or a softening yield stress
//! (`hardening: "exponential_softening"` on `von_mises`, `material::hardening`).
//!
//! The softening is local (no regularisation: no internal length, no non-local or gradient
//! plastic strain), so once a band softens the discrete problem localises into the narrowest
//! band the grid allows: load–displacement curves past the peak, and the width of the failure
//! zones, depend on the grid (and the basis). A scene is told so once, naming its softening
//! materials, before it runs.

use super::SceneSpec;
use crate::material::drucker_prager::read_strength;
use crate::material::{Material, VonMises};

/// One warning naming every softening material of the scene, or none.
pub fn softening_warnings(spec: &SceneSpec) -> Vec<String> {
    let softening: Vec<String> = spec
        .materials
        .iter()
        .filter(|m| match m.model.as_str() {
            "drucker_prager" | "mohr_coulomb" => {
                read_strength(&m.parameters).is_ok_and(|strength| strength.softens())
            }
            "von_mises" => VonMises::from_parameters(&m.parameters)
                .is_ok_and(|model| model.hardening.softens()),
            _ => false,
        })
        .map(|m| format!("'{}'", m.name))
        .collect();
    if softening.is_empty() {
        return Vec::new();
    }
    vec![format!(
        "material {} soften (H < 0, softening_rate, or exponential_softening) without regularisation: past \
         the peak the results are mesh-dependent (the failure zone localises into the narrowest \
         band the grid allows); compare two resolutions before reading a post-peak curve \
         (docs/plasticity.md, \"Hardening and softening of Drucker-Prager and Mohr-Coulomb\" and \
         \"Non-linear hardening and softening of von Mises\")",
        softening.join(", ")
    )]
}
