//! A warning for scenes that will lock volumetrically: bodies of a material whose plastic flow
//! is isochoric (von Mises / Tresca).
//!
//! Isochoric flow asks every material point to keep its volume, and a low-order displacement
//! field (linear MPM, GIMP, CPDI, B-splines of order 2–3 sampled at the points, linear FEM)
//! cannot deform at constant volume at every point: the body is too stiff and limit loads come
//! out too high, converging slowly with refinement. The cure is F-bar (Coombs et al. 2018,
//! `body(#{ .., fbar: true })`, `effects/fbar.rs`): a body of such a material without it gets a
//! warning rather than a limit load that looks converged. Measured on the shipped Tresca strip
//! footing (E/s_u = 1000, ν = 0.3, quadratic B-splines, δ/B = 0.05) without F-bar: q/s_u =
//! 7.83, 6.74, 6.09, 5.77 at 4, 8, 16, 32 cells across the footing against Prandtl's
//! 2 + π = 5.14 (docs/plasticity.md, which has the F-bar figures).
//!
//! F-bar with B-splines of order 2 or more on plastic bodies gets a warning of its own: on the
//! same footing at 16 cells across B its resistance falls under a growing settlement (5.80 to
//! 5.51 with 73 step cuts; to 2.54 in one step with the Newton line search), which a perfectly
//! plastic soil cannot do: the run converges to a spurious equilibrium and says nothing else
//! about it. Linear MPM and GIMP with F-bar show no such fall at the resolutions measured.

use super::{ScenePart, SceneSpec};

/// The bodies (indices into `SceneSpec::bodies`) that a module treats against volumetric
/// locking (F-bar): they get no locking warning.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LockingTreated(pub Vec<usize>);

/// The material models whose plastic flow is isochoric.
const ISOCHORIC_MODELS: [&str; 1] = ["von_mises"];

/// The built-in plastic material models.
const PLASTIC_MODELS: [&str; 3] = ["von_mises", "drucker_prager", "mohr_coulomb"];

/// Whether `model` is one of the built-in plastic material models (a model of a plugin is
/// taken as not plastic).
pub fn is_plastic_model(model: &str) -> bool {
    PLASTIC_MODELS.contains(&model)
}

/// One warning per material with isochoric plastic flow that a body uses without F-bar, and
/// one per plastic material whose bodies use F-bar with B-splines of order 2 or more.
pub fn locking_warnings(spec: &SceneSpec) -> Vec<String> {
    let mut warnings = Vec::new();
    let treated = spec.part::<LockingTreated>().map_or(&[][..], |t| &t.0[..]);
    for (index, material) in spec.materials.iter().enumerate() {
        let bodies: Vec<&str> = spec
            .bodies
            .iter()
            .enumerate()
            .filter(|(b, body)| body.material == index && !treated.contains(b))
            .map(|(_, body)| body.name.as_str())
            .collect();
        if bodies.is_empty() || !ISOCHORIC_MODELS.contains(&material.model.as_str()) {
            continue;
        }
        warnings.push(format!(
            "material '{}' ({}) flows plastically at constant volume: without F-bar the bodies \
             {bodies:?} lock volumetrically, so limit loads come out too high and converge slowly \
             with refinement (Prandtl's footing with quadratic B-splines: +52% at 4 cells across \
             the footing, +12% at 32); set `fbar: true` in their body(..) calls (see \
             docs/plasticity.md)",
            material.name, material.model
        ));
    }
    let order = spec.grid.basis.order();
    for (index, material) in spec.materials.iter().enumerate() {
        let bodies: Vec<&str> = spec
            .bodies
            .iter()
            .enumerate()
            .filter(|(b, body)| body.material == index && treated.contains(b))
            .map(|(_, body)| body.name.as_str())
            .collect();
        if bodies.is_empty() || order < 2 || !PLASTIC_MODELS.contains(&material.model.as_str()) {
            continue;
        }
        warnings.push(format!(
            "the plastic bodies {bodies:?} (material '{}', {}) use F-bar with B-splines of order \
             {order}: experimental; on Prandtl's footing at 16 cells across it the resistance \
             falls under a growing settlement (a spurious equilibrium, 2.54 s_u against \
             Prandtl's 5.14 in the last step), and the patch average stalls; check limit loads \
             against linear MPM or GIMP with F-bar (see docs/plasticity.md)",
            material.name, material.model
        ));
    }
    warnings
}

/// Warnings a module found about the scene while resolving its declarations (a combination
/// the method is known to get wrong); [`scene_warnings`] lists them after its own. A module
/// appends to it ([`ModuleWarnings::add`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModuleWarnings(pub Vec<String>);

impl ModuleWarnings {
    /// Appends `warnings` to the scene's module warnings.
    pub fn add(spec: &mut SceneSpec, warnings: impl IntoIterator<Item = String>) {
        append_lines(spec, warnings, |part: &mut ModuleWarnings| &mut part.0);
    }
}

/// What a module resolved that the run's log should name before it runs (not a warning: a
/// choice the scene left to the module, e.g. which variant of Nitsche's method a condition
/// uses); appended to like [`ModuleWarnings`], listed by [`scene_notes`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModuleNotes(pub Vec<String>);

impl ModuleNotes {
    /// Appends `notes` to the scene's module notes.
    pub fn add(spec: &mut SceneSpec, notes: impl IntoIterator<Item = String>) {
        append_lines(spec, notes, |part: &mut ModuleNotes| &mut part.0);
    }
}

/// Appends `lines` to the list `lines_of` picks out of the scene's part `P` (created when the
/// first line arrives).
fn append_lines<P: ScenePart + Clone + Default>(
    spec: &mut SceneSpec,
    lines: impl IntoIterator<Item = String>,
    lines_of: impl Fn(&mut P) -> &mut Vec<String>,
) {
    let mut all = spec.part::<P>().cloned().unwrap_or_default();
    lines_of(&mut all).extend(lines);
    if !lines_of(&mut all).is_empty() {
        spec.set_part(all);
    }
}

/// The modules' notes on a scene ([`ModuleNotes`]), for the run's log.
pub fn scene_notes(spec: &SceneSpec) -> Vec<String> {
    spec.part::<ModuleNotes>()
        .map(|notes| notes.0.clone())
        .unwrap_or_default()
}

/// Every warning a scene gets before it runs: rank deficiency (`rank_warnings`), volumetric
/// locking ([`locking_warnings`]), a Drucker–Prager cone's matching in plane strain
/// (`cone_matching_warnings`), softening cohesions (`softening_warnings`) and the modules'
/// ([`ModuleWarnings`]).
pub fn scene_warnings(spec: &SceneSpec) -> Vec<String> {
    let mut warnings = super::rank_warnings(spec);
    warnings.extend(locking_warnings(spec));
    warnings.extend(super::cone_matching_warnings(spec));
    warnings.extend(super::softening_warnings(spec));
    if let Some(module) = spec.part::<ModuleWarnings>() {
        warnings.extend(module.0.iter().cloned());
    }
    warnings
}
