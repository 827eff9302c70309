//! A warning for 2D (plane-strain) scenes whose Drucker–Prager cone is matched to Mohr–Coulomb
//! by its `outer` or `inner` meridians.
//!
//! Those matchings fit the cone to the Mohr–Coulomb pyramid in triaxial compression or
//! extension; in plane strain, with associated flow, the cone then fails as a Mohr–Coulomb soil
//! of another angle and cohesion (`material::drucker_prager`, "In plane strain"): the outer cone
//! at φ = 20° as φ' = 27.5°, c' = 1.43 c, and from φ = 36.9° not at all. The strip footing of
//! docs/plasticity.md carries 2.4 N_c with it at φ = 20°. A 2D scene gets the equivalent φ' and
//! c' before it runs, and the matching that gives back φ and c (`matching: "plane_strain"`),
//! rather than a collapse load that looks like Mohr–Coulomb's and is not.

use super::SceneSpec;
use crate::material::Material;
use crate::material::drucker_prager::{DruckerPrager, Matching};

/// One warning per Drucker–Prager material of a 2D scene matched other than `plane_strain`.
pub fn cone_matching_warnings(spec: &SceneSpec) -> Vec<String> {
    if spec.dim() != 2 {
        return Vec::new();
    }
    let mut warnings = Vec::new();
    for material in spec
        .materials
        .iter()
        .filter(|m| m.model == "drucker_prager")
    {
        let Ok(cone) = DruckerPrager::from_parameters(&material.parameters) else {
            continue; // its own check names what is wrong with it
        };
        if cone.matching == Matching::PlaneStrain {
            continue;
        }
        let matching = if cone.matching == Matching::Outer {
            "outer"
        } else {
            "inner"
        };
        let strength = match cone.plane_strain_mohr_coulomb() {
            Some((angle, cohesion)) => format!(
                "fails as a Mohr-Coulomb soil with phi' = {:.1} deg and c' = {:.3} (not phi = \
                 {:.1} deg, c = {}), so plane-strain collapse loads come out for that soil",
                angle.to_degrees(),
                cohesion,
                cone.friction.to_degrees(),
                cone.cohesion
            ),
            None => "has no plane-strain collapse load at all (eta >= sqrt(3)/2): nothing \
                     in the plane fails"
                .to_string(),
        };
        warnings.push(format!(
            "material '{}' (drucker_prager, matching {matching}) in plane strain with associated \
             flow {strength}; give `matching: \"plane_strain\"` for the cone whose plane-strain \
             limit loads are Mohr-Coulomb's with phi and c (docs/plasticity.md, \"Drucker-Prager \
             on the footing\")",
            material.name
        ));
    }
    warnings
}
