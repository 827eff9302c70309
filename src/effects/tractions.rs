//! Surface tractions (paper eqs. 1 and 9): the Neumann term of the external force,
//!
//! ```text
//!   f_ext,i += λ ∫_ΓN h N_i dΓ  =  λ Σ_s h_s A_s N̄_is,     N̄_is = (1/|Γ_s|) ∫_Γs N_i dΓ,
//! ```
//!
//! integrated with traction points s seeded on a flat piece of boundary (`traction(...)` in
//! scenes, see `scene::seed_boundary`) that need not align with the grid. Each carries its
//! share Γ_s of the piece (a part of it: its reference area A_s and half-edges), the traction
//! h_s (force per unit reference area, of fixed direction: a dead load), and moves with the
//! material ([`update_traction_points`]); its weights are the basis averaged over the share
//! as the host's F has deformed it (`basis::surface`), exact wherever the shares lie against
//! the knot lines (the basis sampled at the point, the midpoint rule, is not, and a side of a
//! body moving into a new column of cells turns that error into a wrong stress next to it).
//!
//! **Point loads at any position** (`point_load_at(#{ at, force })`) are load points of the
//! same kind: a point of unit "area" carrying the force P at a reference position X that need
//! not be a material point, f_ext,i += λ P N_i(x), moving with the material like a traction
//! point (its host is the material point nearest to X). A point load on a material point
//! (`point_load`) is the special case X = X_p.
//!
//! Both take `held: true` to apply the load in full from the first load step on (λ replaced by
//! 1, `resources::Ramp::Held`) while the other loads follow the schedule. In a staged scene
//! both take `until_stage: "s"`: released at the start of the later stage s, ramped down over
//! it from the value at the end of the stage before and absent after it,
//! `f = (1 − λ_s) f_end` (`declarations::released_factor`, [`TractionPoint::factor`]).
//!
//! Systems, added only when a scene declares tractions:
//!
//! * [`apply_tractions`] (`Hook::Loads`): average the basis over the share and spread
//!   λ h_s A_s over the support (`mechanics::spread_over_active`).
//! * [`update_traction_points`] (`Hook::PointUpdate`, after the material points):
//!   x_s = x_p + F_p (X_s − X_p), with p the host of s, the material point nearest to it in the
//!   reference configuration. This keeps the traction point on the body's boundary exactly for
//!   any homogeneous deformation of the host's neighbourhood, which interpolating the grid
//!   increment at x_s would not: part of a boundary point's support is grid nodes outside the
//!   body, whose increments are not unknowns (see below).
//! * [`write_tractions`] (`Hook::Output`): `tractions_NNNN.vtu` (one vertex per traction point
//!   with `reference_position`, `area`, `traction` λ h and `force` λ h A) and `tractions.pvd`,
//!   through [`LoadPointOutput`] (which the pressure's points use too).
//!
//! A traction point lies on the body's boundary, where part of its support may be grid nodes
//! that no material point supports (inactive nodes, with no unknown). The force those nodes
//! would receive is given to the active nodes of the support in proportion to their basis
//! values, so the resultant λ h_s A_s is kept exactly; when every support node is active (the
//! usual case: a boundary inside or on the face of a cell with material points) this is exactly
//! the quadrature above. A traction point with no active node in its support is an error.
//! Tractions act through the background grid's basis, so they do not apply to linear FEM.
//!
//! With linear FEM (`basis: "fem"`) a point load at a position is spread by its host's element
//! instead: N̂_i = N_a(ξ_p) + ∇N_a(x_p) · (x − x_p), the first-order expansion of the host
//! integration point's shape functions (the weights of [`host_weights`]). They sum to one and
//! reproduce linear functions, so the nodal forces have the load's resultant and moment exactly
//! (statically equivalent); they differ from N_a(x) only by the bilinear term of the element,
//! a self-equilibrated nodal pattern whose effect is local (Saint-Venant).

use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;
use nalgebra::SVector;

use rhai::Dynamic;

use super::arc_length::add_load_system;
use super::carried_points::{carried_point, restore_positions, save_positions};
use super::declarations::{
    LoadSummary, held_option, keep_largest_force, released_factor, until_stage_of,
    until_stage_option,
};
use super::probes::material_point_near;
use crate::basis::{BasisKind, NodeWeight, SurfaceScratch};
use crate::checkpoint::CheckpointPart;
use crate::components::{DeformationGradient, Position, ReferencePosition, Support};
use crate::mechanics::spread_over_active;
use crate::output::{Field, PvdSeries, vertex_cells, write_vtu};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    CurrentStage, Grid, GridFields, LoadStep, Ramp, RunStatus, SolverError, Stage, StageClock,
};
use crate::scene::{
    CallSpec, Kind, Located, OptionSpec, Options, PartRule, Resolver, SceneApi, SceneSpec,
    ScriptError, seed_surface,
};
use crate::stages::output::{OutputPlan, pad};

/// A traction point: a quadrature point of the surface term ∫_ΓN h N_i dΓ of paper eq. (9),
/// an entity of its own (not a material point). It carries a piece of boundary of reference
/// area `area` with the traction `traction` (force per unit reference area at load factor 1,
/// fixed direction: a dead load), and moves with the material: it keeps its reference offset
/// from a host material point, deformed with the host's F (x_s = x_p + F_p (X_s − X_p)).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct TractionPoint<const D: usize> {
    /// Index among the scene's traction points (output order).
    pub id: u32,
    /// Current position (converged, start of the load step).
    pub position: SVector<f64, D>,
    pub reference_position: SVector<f64, D>,
    /// The host material point (the nearest one in the reference configuration).
    pub host: Entity,
    /// X_s − X_p: the reference offset from the host.
    pub offset: SVector<f64, D>,
    pub area: f64,
    /// The half-edges of its share of the surface in the reference configuration (none for a
    /// load point); deformed with the host's F, like the offset.
    pub half_edges: Vec<SVector<f64, D>>,
    pub traction: SVector<f64, D>,
    /// Ramped with the load factor, or held in full from the first step (`held: true`).
    pub ramp: Ramp,
    /// The stage whose start releases it (`until_stage`), if any.
    pub until: Option<usize>,
    /// The basis averaged over the share (`basis::surface`) for this load step.
    pub support: Vec<NodeWeight<D>>,
}

/// A quadrature point of a surface traction (paper eqs. 1 and 9: the Neumann term
/// ∫_ΓN h N_i dΓ): a piece of boundary of reference area (length in 2D, 1 in 1D) `area` at
/// `position`, carrying the traction `traction` (force per unit reference area at load factor
/// 1). It adds λ h A N_i(x_s) to the external force and moves with the material: with the
/// deformation of its host, the nearest material point (`host`, a global point index).
#[derive(Clone, Debug, PartialEq)]
pub struct TractionPointSpec {
    pub position: Vec<f64>,
    pub area: f64,
    /// The half-edges of its share of the surface (`scene::BoundarySeed`; none for a load
    /// point).
    pub half_edges: Vec<Vec<f64>>,
    pub traction: Vec<f64>,
    pub host: usize,
    /// Ramped with the load factor, or held in full from the first step (`held: true`).
    pub ramp: Ramp,
    /// The stage whose start releases it (`until_stage`), if any.
    pub until: Option<usize>,
}

/// The traction points of every `traction(...)` of the scene.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tractions(pub Vec<TractionPointSpec>);

/// `traction(...)`: a traction on a flat piece of boundary given by its corners.
#[derive(Clone, Debug)]
struct TractionDeclaration {
    corners: Vec<Vec<f64>>,
    traction: Vec<f64>,
    per_cell: usize,
    ramp: Ramp,
    until: Option<String>,
}

/// `point_load_at(...)`: a force at a reference position, carried by a load point.
#[derive(Clone, Debug)]
struct PointLoadAtDeclaration {
    at: Vec<f64>,
    force: Vec<f64>,
    ramp: Ramp,
    until: Option<String>,
}

/// The load points of the scene's `point_load_at(...)`: traction points of unit area whose
/// traction is the force (module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointLoadsAt(pub Vec<TractionPointSpec>);

/// Each `traction` and `point_load_at` as `impm check` lists it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LoadPointDeclarations(pub Vec<LoadSummary>);

/// How load points get their weights: the basis at the point (MPM), or the host's element
/// expanded to the point (linear FEM, module docs).
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadPointWeights {
    Basis,
    Host,
}

/// Why tractions do not apply to linear FEM.
const NOT_WITH_FEM: &str = "tractions are applied through the background grid's basis; basis \"fem\" has a body-fitted mesh instead (use point_load_total on the boundary points)";

/// The `tractions.pvd` series.
#[derive(Resource)]
pub struct TractionSeries(pub PvdSeries);

/// The module: scheduled when a scene declares a non-zero traction (MPM bases only).
#[derive(Clone, Copy, Debug, Default)]
pub struct TractionsModule;

impl Plugin for TractionsModule {
    fn name(&self) -> &'static str {
        "tractions"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(CallSpec::options(
            "traction",
            "surface traction h (force per unit reference area at load factor 1, a dead load) on a flat piece of boundary that need not follow the grid; carried by traction points that move with the material",
            vec![
                OptionSpec::required(
                    "on",
                    Kind::Points,
                    "the piece of boundary: 1D `[[x]]`, 2D a segment `[[x0, y0], [x1, y1]]`, 3D a parallelogram `[c0, c1, c2]` (edges c1 − c0, c2 − c0)",
                ),
                OptionSpec::required("traction", Kind::Numbers, "the traction h, one entry per axis"),
                OptionSpec::new(
                    "per_cell",
                    Kind::Whole {
                        min: 1,
                        max: Some(1000),
                    },
                    "traction points per cell crossed (default 2)",
                ),
                held_option(),
                until_stage_option(),
            ],
            |builder, options: &Options, at| {
                builder.declare(Located::new(
                    TractionDeclaration {
                        corners: options.points("on").unwrap_or_default().to_vec(),
                        traction: options.numbers("traction").unwrap_or_default().to_vec(),
                        per_cell: options.whole("per_cell").unwrap_or(2),
                        ramp: Ramp::staged(options.flag("held").unwrap_or(false), builder.stage()),
                        until: options.text("until_stage").map(str::to_string),
                    },
                    at,
                ));
                Ok(Dynamic::UNIT)
            },
        ));
        api.call(CallSpec::options(
            "point_load_at",
            "a force (at load factor 1, a dead load) at a reference position that need not be a material point, spread through the basis like a traction and carried by the material (with basis \"fem\": by the element of the nearest integration point)",
            vec![
                OptionSpec::required(
                    "at",
                    Kind::Numbers,
                    "the reference position, one entry per axis (in or on the body, within a cell of its material points)",
                ),
                OptionSpec::required("force", Kind::Numbers, "the force P, one entry per axis"),
                held_option(),
                until_stage_option(),
            ],
            |builder, options: &Options, at| {
                builder.declare(Located::new(
                    PointLoadAtDeclaration {
                        at: options.numbers("at").unwrap_or_default().to_vec(),
                        force: options.numbers("force").unwrap_or_default().to_vec(),
                        ramp: Ramp::staged(options.flag("held").unwrap_or(false), builder.stage()),
                        until: options.text("until_stage").map(str::to_string),
                    },
                    at,
                ));
                Ok(Dynamic::UNIT)
            },
        ));
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        if let Some(first) = scene.declarations::<TractionDeclaration>().first()
            && scene.spec.grid.basis == BasisKind::Fem
        {
            return Err(ScriptError::at(
                first.at,
                format!("traction(...): {NOT_WITH_FEM}"),
            ));
        }
        let mut summaries = Vec::new();
        let points = resolve_tractions(scene, &mut summaries)?;
        if !points.is_empty() {
            scene.spec.set_part(Tractions(points));
        }
        let loads = resolve_point_loads_at(scene, &mut summaries)?;
        if !loads.is_empty() {
            scene.spec.set_part(PointLoadsAt(loads));
        }
        if !summaries.is_empty() {
            scene.spec.set_part(LoadPointDeclarations(summaries));
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let mut parts = Vec::new();
        if let Some(points) = spec.part::<Tractions>() {
            let area: f64 = points.0.iter().map(|p| p.area).sum();
            parts.push(format!(
                "{} traction points on a boundary of reference area (length) {}",
                points.0.len(),
                (area * 1e9).round() / 1e9
            ));
        }
        if let Some(loads) = spec.part::<PointLoadsAt>() {
            parts.push(format!("{} point loads at positions", loads.0.len()));
        }
        let mut text = parts.join("; ");
        for declaration in spec
            .part::<LoadPointDeclarations>()
            .map_or(&[][..], |d| &d.0)
        {
            text += "\n    ";
            text += &declaration.describe();
        }
        (!parts.is_empty()).then_some(text)
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        load_point_specs(spec).any(|point| point.traction.iter().any(|&c| c != 0.0))
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis != BasisKind::Fem || spec.part::<PointLoadsAt>().is_some()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let fem = simulation.spec().grid.basis == BasisKind::Fem;
        if fem && simulation.spec().part::<Tractions>().is_some() {
            simulation.fail(NOT_WITH_FEM);
            return;
        }
        if let Err(why) = spawn_traction_points(simulation) {
            simulation.fail(why);
            return;
        }
        simulation.world().insert_resource(if fem {
            LoadPointWeights::Host
        } else {
            LoadPointWeights::Basis
        });
        if load_point_specs(simulation.spec()).any(|point| point.until.is_some()) {
            keep_largest_force(simulation);
        }
        let dir = simulation.world().resource::<OutputPlan>().dir.clone();
        simulation
            .world()
            .insert_resource(TractionSeries(PvdSeries::new(dir.join("tractions.pvd"))));
        simulation
            .checkpoint(CheckpointPart {
                name: "traction points",
                save: save_positions::<D, TractionPoint<D>>,
                restore: restore_positions::<D, TractionPoint<D>>,
            })
            .series(|world| vec![&mut world.resource_mut::<TractionSeries>().into_inner().0]);
        add_load_system(simulation, apply_tractions::<D>);
        simulation
            .add_systems(Hook::PointUpdate, update_traction_points::<D>)
            .add_systems(Hook::Output, write_tractions::<D>);
    }
}

/// The scene's load points: the traction points, then the point loads at positions.
fn load_point_specs(spec: &SceneSpec) -> impl Iterator<Item = &TractionPointSpec> {
    let tractions = spec.part::<Tractions>().map_or(&[][..], |t| &t.0);
    let loads = spec.part::<PointLoadsAt>().map_or(&[][..], |l| &l.0);
    tractions.iter().chain(loads)
}

/// Spawns the scene's traction points (entities with a [`TractionPoint`] only).
fn spawn_traction_points<const D: usize>(simulation: &mut Extension<'_, D>) -> Result<(), String> {
    let vector = |values: &[f64], what: &str| {
        if values.len() != D {
            return Err(format!(
                "traction point {what} with {} components in {D}D",
                values.len()
            ));
        }
        Ok(SVector::<f64, D>::from_fn(|a, _| values[a]))
    };
    let entities = simulation.point_entities();
    let spec = simulation.spec();
    let world = simulation.world();
    let mut batch = Vec::new();
    for (id, point) in load_point_specs(spec).enumerate() {
        let position = vector(&point.position, "position")?;
        let host = *entities
            .get(point.host)
            .ok_or_else(|| format!("traction point host {} does not exist", point.host))?;
        let host_position = world
            .get::<ReferencePosition<D>>(host)
            .ok_or("traction point host is not a material point")?
            .0;
        let half_edges = point
            .half_edges
            .iter()
            .map(|edge| vector(edge, "share"))
            .collect::<Result<_, _>>()?;
        batch.push(TractionPoint {
            id: id as u32,
            position,
            reference_position: position,
            host,
            offset: position - host_position,
            area: point.area,
            half_edges,
            traction: vector(&point.traction, "traction")?,
            ramp: point.ramp,
            until: point.until,
            support: Vec::new(),
        });
    }
    world.spawn_batch(batch);
    Ok(())
}

carried_point!(TractionPoint);

impl<const D: usize> TractionPoint<D> {
    /// The factor of its load in `step` of stage `stage`: its stage's λ, 1 when held, ramped
    /// down over the stage that releases it and 0 after (`declarations::released_factor`).
    pub fn factor(&self, step: &LoadStep, stage: usize) -> f64 {
        released_factor(step, self.ramp, self.until, stage)
    }
}

/// The weights N_a(x_p) + ∇N_a(x_p) · `offset` of a host's support expanded to a point at
/// x_p + `offset` (module docs: load points with linear FEM). They sum to one when the host's
/// do, and reproduce linear functions.
pub fn host_weights<const D: usize>(
    host: &[NodeWeight<D>],
    offset: &SVector<f64, D>,
) -> Vec<NodeWeight<D>> {
    host.iter()
        .map(|w| NodeWeight {
            node: w.node,
            value: w.value + w.gradient.dot(offset),
            gradient: w.gradient,
        })
        .collect()
}

/// Traction forces λ h_s A_s N̄_is with the basis averaged over each point's share at the start
/// of the step (its half-edges deformed by the host's F).
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn apply_tractions<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    weights: Res<LoadPointWeights>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<(SurfaceScratch<D>, Vec<SVector<f64, D>>)>,
    hosts: Query<(&Support<D>, &Position<D>, &DeformationGradient<D>)>,
    mut points: Query<&mut TractionPoint<D>>,
) {
    let _timer = clock.time(Stage::Loads);
    let (scratch, half_edges) = &mut *scratch;
    let fields = &mut *fields;
    let stage = stage.map_or(0, |s| s.0);
    for mut point in points.iter_mut() {
        let point = &mut *point;
        if *weights == LoadPointWeights::Host {
            let Ok((host, x, _)) = hosts.get(point.host) else {
                status.fail(SolverError::Module {
                    step: step.number,
                    what: format!("load point {} has lost its host material point", point.id),
                    recoverable: false,
                });
                return;
            };
            point.support = host_weights(&host.0, &(point.position - x.0));
            let force = point.traction * (point.area * point.factor(&step, stage));
            spread_over_active(
                &force,
                &point.support,
                &fields.active,
                &mut fields.external_force,
            );
            continue;
        }
        let fail = |why: &str| SolverError::Module {
            step: step.number,
            what: format!(
                "traction point {} at {:?} {why}",
                point.id,
                point.position.iter().copied().collect::<Vec<_>>()
            ),
            recoverable: false,
        };
        half_edges.clear();
        if let Ok((_, _, f)) = hosts.get(point.host) {
            half_edges.extend(point.half_edges.iter().map(|edge| f.0 * edge));
        }
        half_edges.resize(point.half_edges.len(), SVector::zeros());
        if grid
            .0
            .eval_surface_average(&point.position, half_edges, scratch, &mut point.support)
            .is_err()
        {
            status.fail(fail("left the background grid"));
            return;
        }
        let force = point.traction * (point.area * point.factor(&step, stage));
        if !spread_over_active(
            &force,
            &point.support,
            &fields.active,
            &mut fields.external_force,
        ) {
            status.fail(fail(
                "is not next to any material point (no grid node of its support is active); put tractions on a body's boundary",
            ));
            return;
        }
    }
}

/// Traction points follow their host material point, x_s = x_p + F_p (X_s − X_p).
pub fn update_traction_points<const D: usize>(
    hosts: Query<(&Position<D>, &DeformationGradient<D>)>,
    mut points: Query<&mut TractionPoint<D>>,
) {
    for mut point in points.iter_mut() {
        if let Ok((x, f)) = hosts.get(point.host) {
            point.position = x.0 + f.0 * point.offset;
        }
    }
}

/// `tractions_NNNN.vtu` and its series.
pub fn write_tractions<const D: usize>(
    mut output: LoadPointOutput,
    mut series: ResMut<TractionSeries>,
    points: Query<&TractionPoint<D>>,
) {
    output.write(&mut series.0, "tractions", |step, stage| {
        let mut rows: Vec<&TractionPoint<D>> = points.iter().collect();
        rows.sort_by_key(|point| point.id);
        let n = rows.len();
        let positions = rows.iter().map(|point| pad(&point.position)).collect();
        let mut reference = Vec::with_capacity(3 * n);
        let mut area = Vec::with_capacity(n);
        let mut traction = Vec::with_capacity(3 * n);
        let mut force = Vec::with_capacity(3 * n);
        for point in &rows {
            reference.extend(pad(&point.reference_position));
            area.push(point.area);
            let factor = point.factor(step, stage);
            traction.extend(pad(&(point.traction * factor)));
            force.extend(pad(&(point.traction * (point.area * factor))));
        }
        let columns = vec![
            ("reference_position", 3, reference),
            ("area", 1, area),
            ("traction", 3, traction),
            ("force", 3, force),
        ];
        (positions, columns)
    });
}

/// One step's point arrays of a load points' file: (name, components, values).
pub type Columns = Vec<(&'static str, usize, Vec<f64>)>;

/// What a writer of load points (traction points, pressure points) reads and writes besides
/// its points and its series.
#[derive(SystemParam)]
pub struct LoadPointOutput<'w> {
    step: Res<'w, LoadStep>,
    stage: Option<Res<'w, CurrentStage>>,
    plan: Res<'w, OutputPlan>,
    status: ResMut<'w, RunStatus>,
    clock: ResMut<'w, StageClock>,
}

impl LoadPointOutput<'_> {
    /// At an output step: `STEM_NNNN.vtu` in the output folder, one vertex per point of
    /// `rows(step, stage)` (their positions and point arrays), listed in `series` (`STEM.pvd`)
    /// at the step's series time. A file that cannot be written fails the run
    /// (`SolverError::Output`); the files already written stay valid.
    pub fn write(
        &mut self,
        series: &mut PvdSeries,
        stem: &str,
        rows: impl FnOnce(&LoadStep, usize) -> (Vec<[f64; 3]>, Columns),
    ) {
        if !self.plan.writes(&self.step) {
            return;
        }
        let _timer = self.clock.time(Stage::Output);
        let stage = self.stage.as_deref();
        let (positions, columns) = rows(&self.step, stage.map_or(0, |s| s.0));
        let fields: Vec<Field> = columns
            .iter()
            .map(|(name, components, values)| Field::new(name, *components, values))
            .collect();
        let name = format!("{stem}_{:04}.vtu", self.step.number);
        let result = write_vtu(
            &self.plan.dir.join(&name),
            &positions,
            &vertex_cells(positions.len()),
            &fields,
            &[],
        )
        .and_then(|()| series.push(self.step.series_time(stage), &name));
        if let Err(e) = result {
            self.status.fail(SolverError::Output {
                step: self.step.number,
                why: format!("{name}: {e}"),
            });
        }
    }
}

/// Traction points of every `traction(...)` (`scene::seed_surface`); the traction must have
/// one component per axis. Adds each declaration's summary to `summaries`.
fn resolve_tractions(
    scene: &Resolver,
    summaries: &mut Vec<LoadSummary>,
) -> Result<Vec<TractionPointSpec>, ScriptError> {
    let grid = &scene.spec.grid;
    let material_points = scene.spec.material_point_positions();
    let mut points = Vec::new();
    for declaration in scene.declarations::<TractionDeclaration>() {
        let traction = &declaration.value;
        let fail =
            |message: String| ScriptError::at(declaration.at, format!("traction(...): {message}"));
        if traction.traction.len() != grid.dim() {
            return Err(fail(format!(
                "option 'traction' has {} components but the grid is {}-dimensional",
                traction.traction.len(),
                grid.dim()
            )));
        }
        let seeded = seed_surface(
            grid,
            &material_points,
            &traction.corners,
            traction.per_cell,
            PartRule::Shares(1),
            "traction points",
        )
        .map_err(fail)?;
        let until = until_stage_of(
            scene.spec,
            "traction",
            traction.until.as_deref(),
            declaration.stage,
            declaration.at,
        )?;
        let area: f64 = seeded.iter().map(|seed| seed.area).sum();
        summaries.push(
            LoadSummary::new(
                declaration.at.line(),
                "traction",
                "traction points",
                seeded.iter().map(|seed| &seed.position[..]),
                traction.traction.iter().map(|c| c * area).collect(),
            )
            .in_stage(scene.spec, traction.ramp.stage())
            .released(scene.spec, until),
        );
        points.extend(seeded.into_iter().map(|seed| TractionPointSpec {
            position: seed.position,
            area: seed.area,
            half_edges: seed.half_edges,
            traction: traction.traction.clone(),
            host: seed.host,
            ramp: traction.ramp,
            until,
        }));
    }
    Ok(points)
}

/// The load point of every `point_load_at(...)`: hosted by the nearest material point, which
/// must be within a cell (the largest cell size) of the position. Adds each declaration's
/// summary to `summaries`.
fn resolve_point_loads_at(
    scene: &Resolver,
    summaries: &mut Vec<LoadSummary>,
) -> Result<Vec<TractionPointSpec>, ScriptError> {
    let dim = scene.spec.dim();
    let mut loads = Vec::new();
    for declaration in scene.declarations::<PointLoadAtDeclaration>() {
        let load = &declaration.value;
        let fail = |message: String| {
            ScriptError::at(declaration.at, format!("point_load_at(...): {message}"))
        };
        for (what, values) in [("at", &load.at), ("force", &load.force)] {
            if values.len() != dim {
                return Err(fail(format!(
                    "'{what}' has {} components but the grid is {dim}-dimensional",
                    values.len()
                )));
            }
        }
        let host = material_point_near(scene.spec, &load.at).map_err(fail)?;
        let until = until_stage_of(
            scene.spec,
            "point_load_at",
            load.until.as_deref(),
            declaration.stage,
            declaration.at,
        )?;
        summaries.push(
            LoadSummary::new(
                declaration.at.line(),
                "point_load_at",
                "load point",
                std::iter::once(&load.at[..]),
                load.force.clone(),
            )
            .in_stage(scene.spec, load.ramp.stage())
            .released(scene.spec, until),
        );
        loads.push(TractionPointSpec {
            position: load.at.clone(),
            area: 1.0,
            half_edges: Vec::new(),
            traction: load.force.clone(),
            host,
            ramp: load.ramp,
            until,
        });
    }
    Ok(loads)
}
