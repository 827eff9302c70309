//! The words of the scene language beyond its calls: the grid's bases, the material models
//! and the point fields of the output. Modules add them (through the registry); the calls
//! that use them (`grid`, `material`, `output`) read them while the script runs.

use super::error::ScriptError;
use super::options::{OptionSpec, Options};
use super::{GridSpec, PointSeed};
use crate::basis::BasisKind;
use crate::material::MaterialParameters;

/// The basis words, material models and point fields of a scene language.
#[derive(Clone, Default)]
pub struct Words {
    pub basis: Vec<BasisWord>,
    pub refinements: Vec<BasisRefinement>,
    pub models: Vec<ModelSpec>,
    pub fields: Vec<FieldSpec>,
}

/// A word of the grid's `basis` option and how it makes the basis from the grid's options.
#[derive(Clone)]
pub struct BasisWord {
    pub word: &'static str,
    pub doc: &'static str,
    pub kind: fn(&Options) -> Result<BasisKind, String>,
    /// How bodies are seeded, if not on the points-per-cell lattice (a body-fitted mesh).
    pub seeder: Option<Seeder>,
}

/// Seeds a body for a basis with its own points: the grid, points per cell per axis and the
/// region; `Ok(Err(why))` when the region does not fit the basis.
pub type Seeder = fn(
    &GridSpec,
    &[usize],
    &mut dyn FnMut(&[f64]) -> Result<bool, ScriptError>,
) -> Result<Result<Vec<PointSeed>, String>, ScriptError>;

/// Something [`Words`] holds (`SceneApi::word` adds it).
pub trait Word {
    fn add_to(self, words: &mut Words);
}

impl Word for BasisWord {
    fn add_to(self, words: &mut Words) {
        words.basis.push(self);
    }
}

impl Word for BasisRefinement {
    fn add_to(self, words: &mut Words) {
        words.refinements.push(self);
    }
}

impl Word for ModelSpec {
    fn add_to(self, words: &mut Words) {
        words.models.push(self);
    }
}

impl Word for FieldSpec {
    fn add_to(self, words: &mut Words) {
        words.fields.push(self);
    }
}

/// Changes the basis a word made from the grid's other options (`integration: "domain"`
/// turns B-splines into domain-averaged ones), or rejects the combination.
pub type BasisRefinement = fn(BasisKind, &Options) -> Result<BasisKind, String>;

/// A material model: its word (`material(#{ model: .. })`) and its parameters.
#[derive(Clone)]
pub struct ModelSpec {
    pub model: &'static str,
    pub doc: &'static str,
    pub parameters: Vec<OptionSpec>,
    /// Builds the model from its parameters to check them (ranges, combinations); its stiffness
    /// scale (Young's modulus).
    pub check: fn(&MaterialParameters) -> Result<f64, String>,
}

/// A point field a module adds to `particles_NNNN.vtu`.
#[derive(Clone, Copy, Debug)]
pub struct FieldSpec {
    pub name: &'static str,
    pub doc: &'static str,
}
