//! Probes: the displacement (and, when asked, the Cauchy stress and the deformation gradient)
//! at a material reference position X₀, recorded after every converged step
//! (`probe(#{ name, at })`), as columns of `history.csv` and keys of `summary.json`:
//! `NAME_displacement_x`, `NAME_stress_xy`, `NAME_F_xy`, ...
//!
//! A probe follows the material at X₀, which need not be a material point: the value there is
//! interpolated from the material points nearest to X₀ in the reference configuration (the
//! `neighbours` nearest, plus any as near as the last of them) by a least-squares linear fit
//! in the reference coordinates (`interpolation::linear_fit_weights`):
//!
//! ```text
//!   f(X₀) ≈ Σ_k w_k f_k,     w_k = e₁ᵀ M⁻¹ p_k,   M = Σ_k p_k p_kᵀ,   p_k = [1, X_k − X₀],
//! ```
//!
//! with f_k = u_p = x_p − X_p (− u_0,p after a stage that zeroes the displacements,
//! `effects::stages`), the point's Cauchy stress σ_p or its F_p. The neighbours and
//! their weights are fixed at the start (reference positions do not change), so a probe costs a
//! few products per step. The fit is exact for linear fields (a homogeneous deformation is read
//! exactly, inside or outside the points' hull); otherwise its error is of the order of the
//! field's second derivatives times the square of the neighbours' spread (about a cell). At a
//! free end (a cantilever's tip) the fit extrapolates from inside the body, which is what a
//! user would do by hand with the last columns of points, but without the bias of taking the
//! nearest point's value.
//!
//! A probe farther than one cell (the largest cell size) from every material point is an error:
//! it names no material position.
//!
//! The neighbours are named by `PointId`. After every converged step ([`read_probes`],
//! `Hook::AfterStep`) each neighbour's numbers (`u_p`, and σ_p, F_p where asked) are read
//! from the process that holds it: with decomposed points (`impm run --decompose`) a
//! neighbour may be on another process, and `distributed::numbers_of_points` sums every
//! process's numbers, each neighbour's coming from its one holder and zeros from the others.
//! The numbers arrive exactly and every process adds `Σ_k w_k f_k` in the serial order, so a
//! decomposed run records the serial run's values bit for bit (`tests/mpi.rs`).

use bevy_ecs::prelude::*;
use nalgebra::SVector;
use rhai::Dynamic;

use crate::components::{DeformationGradient, PointId, Position, ReferencePosition, Trial};
use crate::effects::stages::DisplacementOrigin;
use crate::interpolation::{linear_fit_weights, nearest_points};
use crate::plugin::{Extension, Hook, Plugin};
use crate::scene::{
    CallSpec, Kind, Located, OptionSpec, Options, Resolver, SceneApi, SceneSpec, ScriptError,
};

use super::surface_conditions::AXES;

/// One resolved `probe(...)`.
#[derive(Clone, Debug, PartialEq)]
pub struct ProbeSpec {
    pub name: String,
    pub line: Option<usize>,
    /// The reference position X₀.
    pub at: Vec<f64>,
    /// (global point index, weight w_k) of the neighbours.
    pub weights: Vec<(usize, f64)>,
    /// Also record the Cauchy stress.
    pub stress: bool,
    /// Also record the deformation gradient.
    pub deformation_gradient: bool,
}

/// The scene's probes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Probes(pub Vec<ProbeSpec>);

/// `probe(...)` as declared.
#[derive(Clone, Debug)]
struct ProbeDeclaration {
    name: String,
    at: Vec<f64>,
    neighbours: Option<usize>,
    stress: bool,
    deformation_gradient: bool,
}

/// The default number of neighbours: 2 · 2^D (two cells' worth of points at 2 points per cell
/// and direction), enough to determine the fit (D + 1) with room for irregular seeding.
pub fn default_neighbours(dim: usize) -> usize {
    2 << dim
}

/// The module: built when the scene declares a probe.
#[derive(Clone, Copy, Debug, Default)]
pub struct ProbesModule;

impl Plugin for ProbesModule {
    fn name(&self) -> &'static str {
        "probes"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::options(
            "probe",
            "records the displacement (and optionally the Cauchy stress and F) of the material at a reference position after every converged step, interpolated by a least-squares linear fit over the nearest material points (exact for linear fields), as NAME_displacement_x, NAME_stress_xy, NAME_F_xy, ... in history.csv and summary.json",
            vec![
                OptionSpec::required("name", Kind::Text, "names the recorded columns (a word)"),
                OptionSpec::required(
                    "at",
                    Kind::Numbers,
                    "the reference position X₀, one entry per axis (within a cell of the body's material points)",
                ),
                OptionSpec::new(
                    "neighbours",
                    Kind::Whole {
                        min: 2,
                        max: Some(1000),
                    },
                    "how many of the nearest material points the fit uses (default 2·2^D; ties with the last are added)",
                ),
                OptionSpec::new(
                    "stress",
                    Kind::Flag,
                    "also record the Cauchy stress: NAME_stress_xx, _yy, _zz and the shear components of the grid's axes (default false)",
                ),
                OptionSpec::new(
                    "F",
                    Kind::Flag,
                    "also record the deformation gradient: NAME_F_xx, NAME_F_xy, ... (default false)",
                ),
            ],
            |builder, options: &Options, at| {
                builder.declare(Located::new(
                    ProbeDeclaration {
                        name: options.text("name").unwrap_or_default().to_string(),
                        at: options.numbers("at").unwrap_or_default().to_vec(),
                        neighbours: options.whole("neighbours"),
                        stress: options.flag("stress").unwrap_or(false),
                        deformation_gradient: options.flag("F").unwrap_or(false),
                    },
                    at,
                ));
                Ok(Dynamic::UNIT)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let probes = resolve_probes(scene)?;
        if !probes.is_empty() {
            scene.spec.set_part(Probes(probes));
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let probes = &spec.part::<Probes>()?.0;
        let lines: Vec<String> = probes
            .iter()
            .map(|p| {
                let line = p.line.map(|l| format!("line {l}: ")).unwrap_or_default();
                let mut what = vec!["displacement"];
                if p.stress {
                    what.push("stress");
                }
                if p.deformation_gradient {
                    what.push("F");
                }
                format!(
                    "{line}probe '{}' at {:?}: {} from {} material points",
                    p.name,
                    p.at,
                    what.join(", "),
                    p.weights.len()
                )
            })
            .collect();
        Some(lines.join("\n"))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<Probes>().is_some()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        let points: usize = spec.bodies.iter().map(|body| body.points.len()).sum();
        let probes = spec.part::<Probes>().map_or(Vec::new(), |p| p.0.clone());
        for probe in &probes {
            if let Some(&(point, _)) = probe.weights.iter().find(|&&(point, _)| point >= points) {
                simulation.fail(format!(
                    "probe '{}': point {point} does not exist",
                    probe.name
                ));
                return;
            }
        }
        let readings = ProbeReadings::<D>::new(&probes);
        let layout = readings.layout;
        simulation.world().insert_resource(readings);
        simulation.add_systems(Hook::AfterStep, read_probes::<D>);
        for (index, probe) in probes.iter().enumerate() {
            for (axis, axis_name) in AXES.iter().enumerate().take(D) {
                let key = format!("{}_displacement_{axis_name}", probe.name);
                simulation.add_measure(key, move |world, _| probe_value::<D>(world, index, axis));
            }
            if probe.stress {
                for (a, b) in stress_components(D) {
                    let key = format!("{}_stress_{}{}", probe.name, AXES[a], AXES[b]);
                    let at = layout.stress(a, b);
                    simulation.add_measure(key, move |world, _| probe_value::<D>(world, index, at));
                }
            }
            if probe.deformation_gradient {
                for (a, row) in AXES.iter().enumerate().take(D) {
                    for (b, column) in AXES.iter().enumerate().take(D) {
                        let key = format!("{}_F_{row}{column}", probe.name);
                        let at = layout.deformation_gradient(a, b);
                        simulation
                            .add_measure(key, move |world, _| probe_value::<D>(world, index, at));
                    }
                }
            }
        }
    }
}

/// Where a neighbour's numbers are in [`ProbeReadings::values`]: its displacement (`D`
/// numbers), then, when some probe records them, its Cauchy stress (9, row by row) and its
/// deformation gradient (`D²`, row by row).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadingLayout {
    pub dim: usize,
    pub stress: bool,
    pub deformation_gradient: bool,
}

impl ReadingLayout {
    /// Numbers per neighbour.
    pub fn width(self) -> usize {
        self.dim
            + 9 * usize::from(self.stress)
            + self.dim * self.dim * usize::from(self.deformation_gradient)
    }

    /// The stress component σ_ab.
    pub fn stress(self, a: usize, b: usize) -> usize {
        self.dim + 3 * a + b
    }

    /// The component F_ab.
    pub fn deformation_gradient(self, a: usize, b: usize) -> usize {
        self.dim + 9 * usize::from(self.stress) + self.dim * a + b
    }
}

/// Every probe's neighbours (by `PointId`, probe after probe) and their numbers at the last
/// converged step ([`read_probes`]); a probe's value is `Σ_k w_k f_k` over its neighbours in
/// the resolved order (`probe_value`), the serial run's sum.
#[derive(Resource, Clone, Debug)]
pub struct ProbeReadings<const D: usize> {
    pub layout: ReadingLayout,
    /// Per probe: its first neighbour's place in `values`, and the weights.
    pub probes: Vec<(usize, Vec<f64>)>,
    /// The neighbours' places in `values`, by `PointId` (a point may neighbour several probes).
    pub places: std::collections::HashMap<u32, Vec<usize>>,
    /// Per neighbour: its numbers (`layout`), `None` where no process holds it.
    pub values: Vec<Option<Vec<f64>>>,
}

impl<const D: usize> ProbeReadings<D> {
    fn new(probes: &[ProbeSpec]) -> Self {
        let layout = ReadingLayout {
            dim: D,
            stress: probes.iter().any(|p| p.stress),
            deformation_gradient: probes.iter().any(|p| p.deformation_gradient),
        };
        let mut places: std::collections::HashMap<u32, Vec<usize>> = Default::default();
        let mut first = 0;
        let probes = probes
            .iter()
            .map(|probe| {
                for (k, &(point, _)) in probe.weights.iter().enumerate() {
                    places.entry(point as u32).or_default().push(first + k);
                }
                let weights = probe.weights.iter().map(|&(_, w)| w).collect::<Vec<f64>>();
                first += weights.len();
                (first - weights.len(), weights)
            })
            .collect();
        Self {
            layout,
            probes,
            places,
            values: Vec::new(),
        }
    }
}

/// What [`read_probes`] reads of a held point.
type ProbedPoint<'a, const D: usize> = (
    &'a PointId,
    &'a Position<D>,
    &'a ReferencePosition<D>,
    Option<&'a DisplacementOrigin<D>>,
    &'a Trial<D>,
    &'a DeformationGradient<D>,
);

/// After a converged step: every probe neighbour's displacement (less its stage's origin),
/// stress and F, from the process that holds it (`distributed::numbers_of_points`: with
/// decomposed points a neighbour may be on another process; the numbers arrive exactly, so
/// every process records the serial run's values).
pub fn read_probes<const D: usize>(
    mut readings: ResMut<ProbeReadings<D>>,
    points: Query<ProbedPoint<D>>,
) {
    let readings = &mut *readings;
    let layout = readings.layout;
    let count: usize = readings.probes.iter().map(|(_, w)| w.len()).sum();
    let mut held: Vec<Option<Vec<f64>>> = vec![None; count];
    for (id, x, reference, origin, trial, f) in points.iter() {
        let Some(places) = readings.places.get(&id.0) else {
            continue;
        };
        let origin = origin.map_or_else(SVector::zeros, |o| o.0);
        let mut numbers: Vec<f64> = (x.0 - reference.0 - origin).iter().copied().collect();
        if layout.stress {
            let cauchy = trial.0.cauchy();
            numbers.extend((0..3).flat_map(|a| (0..3).map(move |b| cauchy[(a, b)])));
        }
        if layout.deformation_gradient {
            numbers.extend((0..D).flat_map(|a| (0..D).map(move |b| f.0[(a, b)])));
        }
        for &place in places {
            held[place] = Some(numbers.clone());
        }
    }
    readings.values =
        crate::distributed::numbers_of_points(count, layout.width(), |k, out| match &held[k] {
            Some(numbers) => {
                out.copy_from_slice(numbers);
                true
            }
            None => false,
        });
}

/// Probe `index`'s value of the number `at` of its neighbours' ([`ReadingLayout`]): `Σ_k w_k
/// f_k` in the neighbours' order; `None` before the first reading or where a neighbour is
/// held by no process.
fn probe_value<const D: usize>(world: &mut World, index: usize, at: usize) -> Option<f64> {
    let readings = world.get_resource::<ProbeReadings<D>>()?;
    let (first, weights) = readings.probes.get(index)?;
    let mut value = 0.0;
    for (k, w) in weights.iter().enumerate() {
        value += w * readings.values.get(first + k)?.as_ref()?[at];
    }
    Some(value)
}

/// The recorded stress components: the three normal ones (the out-of-plane σ_zz of plane strain
/// included) and the shear components among the grid's axes.
pub fn stress_components(dim: usize) -> Vec<(usize, usize)> {
    let mut components = vec![(0, 0), (1, 1), (2, 2)];
    for a in 0..dim {
        for b in a + 1..dim {
            components.push((a, b));
        }
    }
    components
}

/// The material point nearest to the reference position `at` (global index), which must be
/// within a cell (the largest cell size) of it: else `at` names no material position.
pub fn material_point_near(spec: &SceneSpec, at: &[f64]) -> Result<usize, String> {
    let grid = &spec.grid;
    let cell = (0..grid.dim())
        .map(|a| (grid.upper[a] - grid.lower[a]) / grid.cells[a] as f64)
        .fold(0.0, f64::max);
    let positions = spec.material_point_positions();
    let Some(&nearest) = nearest_points(&positions, at, 1).first() else {
        return Err("the scene has no material points".into());
    };
    let distance = positions[nearest]
        .iter()
        .zip(at)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt();
    if distance > cell {
        return Err(format!(
            "{at:?} is {distance:.4} from the nearest material point, farther than a cell ({cell}): it is not in or on a body"
        ));
    }
    Ok(nearest)
}

/// The `count` material points nearest to the reference position `at` (and any as near as the
/// last) with the weights of their least-squares linear fit at `at` (module docs): the value of
/// a field carried by the points there is Σ_k w_k f_k. Also used by the surface conditions'
/// material check (`surface_conditions.rs`).
pub fn fit_weights(
    positions: &[&[f64]],
    at: &[f64],
    count: usize,
) -> Result<Vec<(usize, f64)>, String> {
    let near = nearest_points(positions, at, count);
    let chosen: Vec<&[f64]> = near.iter().map(|&k| positions[k]).collect();
    let weights = linear_fit_weights(&chosen, at)
        .map_err(|why| format!("the {} nearest material points: {why}", chosen.len()))?;
    Ok(near.into_iter().zip(weights).collect())
}

/// Every `probe(...)` with its neighbours and weights.
fn resolve_probes(scene: &Resolver) -> Result<Vec<ProbeSpec>, ScriptError> {
    let dim = scene.spec.dim();
    let positions = scene.spec.material_point_positions();
    let mut probes: Vec<ProbeSpec> = Vec::new();
    for declaration in scene.declarations::<ProbeDeclaration>() {
        let probe = &declaration.value;
        let fail =
            |message: String| ScriptError::at(declaration.at, format!("probe(...): {message}"));
        let name = &probe.name;
        if name.is_empty() || name.contains(|c: char| c.is_whitespace() || c == ',') {
            return Err(fail(format!(
                "name {name:?} must be a non-empty word without spaces or commas"
            )));
        }
        if probes.iter().any(|p| &p.name == name) {
            return Err(fail(format!("there are two probes named '{name}'")));
        }
        if probe.at.len() != dim {
            return Err(fail(format!(
                "'at' has {} components but the grid is {dim}-dimensional",
                probe.at.len()
            )));
        }
        material_point_near(scene.spec, &probe.at).map_err(fail)?;
        let count = probe.neighbours.unwrap_or(default_neighbours(dim));
        let weights = fit_weights(&positions, &probe.at, count)
            .map_err(|why| fail(format!("{why}; give more 'neighbours'")))?;
        probes.push(ProbeSpec {
            name: name.clone(),
            line: declaration.at.line(),
            at: probe.at.clone(),
            weights,
            stress: probe.stress,
            deformation_gradient: probe.deformation_gradient,
        });
    }
    Ok(probes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stress_components_are_the_normal_ones_and_the_shears_of_the_grid() {
        assert_eq!(stress_components(1), [(0, 0), (1, 1), (2, 2)]);
        assert_eq!(stress_components(2), [(0, 0), (1, 1), (2, 2), (0, 1)]);
        assert_eq!(stress_components(3).len(), 6);
    }
}
