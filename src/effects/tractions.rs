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
//! **Decomposed points** (`mpirun -n N impm run SCENE --decompose`; `docs/distributed.md`): a
//! load point lives on the process that holds its host (found by the host's `PointId`,
//! [`TractionPoint::host_id`]). When the simulation is built each process spawns the load
//! points of its hosts and keeps the scene's load points ([`LoadPointTemplates`]); at every
//! step start, after the exchange of material points, [`follow_hosts`] despawns the load
//! points whose host left and spawns those whose host arrived, at `x_p + F_p (X_s − X_p)`
//! from the host's arrived state: the position the old process gave it at the last point
//! update, bit for bit (the same expression on the same numbers). A load point's support may
//! reach grid nodes that no point of its process touches but a point of another process does
//! (it lies in another slab than its host): serially such a node is active and takes its
//! share, so here too — [`active_elsewhere`] finds these nodes over the processes (a gather
//! of the candidates and a sum of where they are active, every step) and the forces at them
//! are sent to their owners (`send_to_owners`), which add them before `f_ext` is summed
//! over the processes. The tractions file gathers every process's load points (rows of exact
//! bits) and process 0 writes it; a checkpoint saves every load point's position (process 0
//! holds every host while it saves, so a load point it does not hold is placed from its
//! host). `load_points_changing_process` in summary.json counts the load points that arrived
//! at a process at the step's start, over all processes.
//!
//! With linear FEM (`basis: "fem"`) a point load at a position is spread by its host's element
//! instead: N̂_i = N_a(ξ_p) + ∇N_a(x_p) · (x − x_p), the first-order expansion of the host
//! integration point's shape functions (the weights of [`host_weights`]). They sum to one and
//! reproduce linear functions, so the nodal forces have the load's resultant and moment exactly
//! (statically equivalent); they differ from N_a(x) only by the bilinear term of the element,
//! a self-equilibrated nodal pattern whose effect is local (Saint-Venant).

use std::borrow::Cow;
use std::collections::{BTreeSet, HashMap, HashSet};

use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemParam;
use nalgebra::{SMatrix, SVector};

use rhai::Dynamic;

use super::arc_length::add_load_system;
use super::carried_points::{carried_point, restore_positions, save_positions};
use super::declarations::{
    LoadSummary, grouped, held_option, keep_largest_force, released_factor, until_stage_of,
    until_stage_option,
};
use super::probes::material_point_near;
use crate::basis::{BasisKind, NodeWeight, SurfaceScratch};
use crate::checkpoint::CheckpointPart;
use crate::components::{DeformationGradient, PointId, Position, Support};
use crate::mechanics::spread_over_active;
use crate::node_storage::NodeVec;
use crate::output::{Field, PvdSeries, vertex_cells, write_vtu};
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    CurrentStage, Grid, GridFields, LoadStep, Newton, Ramp, RunStatus, SolverError, Stage,
    StageClock,
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
    /// The host's `PointId`: how it is found again when it is spawned anew or moves to
    /// another process (decomposed points, module docs).
    pub host_id: u32,
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
        let declarations = spec.part::<LoadPointDeclarations>();
        for declaration in grouped(declarations.map_or(&[][..], |d| &d.0)) {
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
                save: save_load_point_positions::<D>,
                restore: restore_positions::<D, TractionPoint<D>>,
            })
            .series(|world| vec![&mut world.resource_mut::<TractionSeries>().into_inner().0]);
        add_load_system(simulation, apply_tractions::<D>);
        if crate::distributed::decomposed() {
            // the load points that arrived at the step's start, summed over the processes
            // (collective: every process records the same steps, in the same order)
            let moved = crate::distributed::RUN_MEASURES[5];
            simulation.world().init_resource::<LoadPointsArrived>();
            simulation
                .add_systems(Hook::Connectivity, follow_hosts::<D>)
                .add_measure(moved, |world, _| {
                    let mut arrived = [world.resource::<LoadPointsArrived>().0 as f64];
                    crate::distributed::sum_over_points(&mut arrived);
                    Some(arrived[0])
                });
        }
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

/// Every load point of the scene, in id order, with its host's `PointId` and no host entity
/// (the host's reference position is its seed's, as the core spawns it).
fn load_points<const D: usize>(spec: &SceneSpec) -> Result<Vec<TractionPoint<D>>, String> {
    let vector = |values: &[f64], what: &str| {
        if values.len() != D {
            return Err(format!(
                "traction point {what} with {} components in {D}D",
                values.len()
            ));
        }
        Ok(SVector::<f64, D>::from_fn(|a, _| values[a]))
    };
    let seeds = spec.material_point_positions();
    load_point_specs(spec)
        .enumerate()
        .map(|(id, point)| {
            let position = vector(&point.position, "position")?;
            let host = seeds
                .get(point.host)
                .ok_or_else(|| format!("traction point host {} does not exist", point.host))?;
            let half_edges = point
                .half_edges
                .iter()
                .map(|edge| vector(edge, "share"))
                .collect::<Result<_, _>>()?;
            Ok(TractionPoint {
                id: id as u32,
                position,
                reference_position: position,
                host: Entity::PLACEHOLDER,
                host_id: point.host as u32,
                offset: position - vector(host, "host")?,
                area: point.area,
                half_edges,
                traction: vector(&point.traction, "traction")?,
                ramp: point.ramp,
                until: point.until,
                support: Vec::new(),
            })
        })
        .collect()
}

/// Spawns the load points whose host this process holds (entities with a [`TractionPoint`]
/// only): all of them, but in a decomposed run; there the scene's load points are kept
/// ([`LoadPointTemplates`]) for the hosts that arrive later.
fn spawn_traction_points<const D: usize>(simulation: &mut Extension<'_, D>) -> Result<(), String> {
    let points = load_points::<D>(simulation.spec())?;
    let entities = simulation.point_entities();
    let decomposed = crate::distributed::decomposed();
    let mut batch = Vec::with_capacity(points.len());
    for point in &points {
        match entities.get(point.host_id as usize) {
            Some(&host) if host != Entity::PLACEHOLDER => batch.push(TractionPoint {
                host,
                ..point.clone()
            }),
            // another process's host (decomposed points)
            _ if decomposed => {}
            _ => {
                return Err(format!(
                    "traction point host {} is not spawned",
                    point.host_id
                ));
            }
        }
    }
    let world = simulation.world();
    world.spawn_batch(batch);
    if decomposed {
        world.insert_resource(LoadPointTemplates(points));
    }
    Ok(())
}

/// The load points' positions in id order (a `CheckpointPart::save`): in a decomposed run
/// process 0 saves while it holds every material point but only its own load points
/// (`effects::distributed::checkpoint`), so a load point it does not hold is at
/// `x_p + F_p (X_s − X_p)` of its host, the position its process gave it at the last point
/// update ([`update_traction_points`]); a load point with neither is left out, which the
/// restore refuses (a count that does not match).
fn save_load_point_positions<const D: usize>(world: &mut World) -> Vec<f64> {
    let Some(templates) = world.get_resource::<LoadPointTemplates<D>>() else {
        return save_positions::<D, TractionPoint<D>>(world);
    };
    let templates = templates.0.clone();
    let held: HashMap<u32, SVector<f64, D>> = world
        .query::<&TractionPoint<D>>()
        .iter(world)
        .map(|point| (point.id, point.position))
        .collect();
    let hosts = host_states::<D>(world);
    templates
        .iter()
        .filter_map(|point| {
            held.get(&point.id).copied().or_else(|| {
                let (_, x, f) = hosts.get(&point.host_id)?;
                Some(x + f * point.offset)
            })
        })
        .flat_map(|x| x.iter().copied().collect::<Vec<_>>())
        .collect()
}

/// The load points that arrived at this process at the current step's start ([`follow_hosts`]).
#[derive(Resource, Default)]
pub struct LoadPointsArrived(pub usize);

/// The material points this process holds by `PointId`: entity, position and F.
fn host_states<const D: usize>(
    world: &mut World,
) -> HashMap<u32, (Entity, SVector<f64, D>, SMatrix<f64, D, D>)> {
    world
        .query::<(Entity, &PointId, &Position<D>, &DeformationGradient<D>)>()
        .iter(world)
        .map(|(entity, id, x, f)| (id.0, (entity, x.0, f.0)))
        .collect()
}

/// The scene's load points, in id order, in a decomposed run ([`follow_hosts`] spawns a load
/// point from it when its host arrives).
#[derive(Resource)]
pub struct LoadPointTemplates<const D: usize>(pub Vec<TractionPoint<D>>);

/// Decomposed points (module docs): after the step start's exchange of material points
/// (`Hook::Connectivity`), this process holds exactly the load points whose hosts it holds,
/// linked to their hosts' entities (a point the exchange moved, or spawned anew, has a new
/// one). A load point whose host left goes with it: it is despawned here and spawned on the
/// host's new process at `x_p + F_p (X_s − X_p)` from the host's arrived state, which is
/// the position its old process gave it at the last point update
/// ([`update_traction_points`]). When any load point left or arrived, every load point here
/// is spawned anew in id order (the order [`apply_tractions`] adds their forces in, as
/// serially).
pub fn follow_hosts<const D: usize>(world: &mut World) {
    let hosts = host_states::<D>(world);
    let mut held: Vec<(Entity, TractionPoint<D>)> = world
        .query::<(Entity, &TractionPoint<D>)>()
        .iter(world)
        .map(|(entity, point)| (entity, point.clone()))
        .collect();
    let before = held.len();
    held.retain(|(_, point)| hosts.contains_key(&point.host_id));
    let departed = before - held.len();
    let present: HashSet<u32> = held.iter().map(|(_, point)| point.id).collect();
    let arrived: Vec<TractionPoint<D>> = world
        .resource::<LoadPointTemplates<D>>()
        .0
        .iter()
        .filter(|point| !present.contains(&point.id))
        .filter_map(|point| {
            let &(host, x, f) = hosts.get(&point.host_id)?;
            Some(TractionPoint {
                host,
                position: x + f * point.offset,
                ..point.clone()
            })
        })
        .collect();
    world.resource_mut::<LoadPointsArrived>().0 = arrived.len();
    if departed == 0 && arrived.is_empty() {
        for (entity, point) in held {
            let host = hosts[&point.host_id].0;
            if let Some(mut point) = world.get_mut::<TractionPoint<D>>(entity) {
                point.host = host;
            }
        }
        return;
    }
    let entities: Vec<Entity> = world
        .query_filtered::<Entity, With<TractionPoint<D>>>()
        .iter(world)
        .collect();
    for entity in entities {
        world.despawn(entity);
    }
    let mut points: Vec<TractionPoint<D>> = held
        .into_iter()
        .map(|(_, point)| TractionPoint {
            host: hosts[&point.host_id].0,
            ..point
        })
        .chain(arrived)
        .collect();
    points.sort_by_key(|point| point.id);
    world.spawn_batch(points);
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
/// of the step (its half-edges deformed by the host's F). With decomposed points a node of a
/// support that no point of this process touches may be active on another process: such
/// nodes count as active, and their forces go to their owners ([`active_elsewhere`],
/// `send_to_owners`; module docs).
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn apply_tractions<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    weights: Res<LoadPointWeights>,
    newton: Res<Newton>,
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
    let fail = |point: &TractionPoint<D>, why: &str| SolverError::Module {
        step: step.number,
        what: format!(
            "traction point {} at {:?} {why}",
            point.id,
            point.position.iter().copied().collect::<Vec<_>>()
        ),
        recoverable: false,
    };
    // every point's weights for this step (the first failure stops here)
    let mut failure = None;
    for mut point in points.iter_mut() {
        let point = &mut *point;
        if *weights == LoadPointWeights::Host {
            let Ok((host, x, _)) = hosts.get(point.host) else {
                failure = Some(SolverError::Module {
                    step: step.number,
                    what: format!("load point {} has lost its host material point", point.id),
                    recoverable: false,
                });
                break;
            };
            point.support = host_weights(&host.0, &(point.position - x.0));
            continue;
        }
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
            failure = Some(fail(point, "left the background grid"));
            break;
        }
    }
    // decomposed points: the support nodes active on another process only (collective: every
    // process takes part, a failed one too)
    let elsewhere = match newton.shared_grid.as_deref() {
        Some(_) => {
            let candidates: BTreeSet<usize> = (points.iter())
                .flat_map(|point| point.support.iter().map(|w| w.node))
                .filter(|&node| !fields.active[node])
                .collect();
            let active = &fields.active;
            active_elsewhere(
                &candidates,
                |node| active.get(node).copied().unwrap_or(false),
                crate::distributed::gather_over_points,
                crate::distributed::sum_over_points,
            )
        }
        None => Ok(BTreeSet::new()),
    };
    let elsewhere = match elsewhere {
        Ok(nodes) => nodes,
        Err(why) => {
            status.fail(SolverError::Module {
                step: step.number,
                what: format!("finding the traction points' nodes on other processes: {why}"),
                recoverable: false,
            });
            return;
        }
    };
    // this process's forces at those nodes, kept apart from its own
    let remote: Vec<usize> = (elsewhere.iter().copied())
        .filter(|&node| !fields.active[node])
        .collect();
    let kept: Vec<SVector<f64, D>> = remote
        .iter()
        .map(|&node| fields.external_force[node])
        .collect();
    let active: Cow<NodeVec<bool>> = if elsewhere.is_empty() {
        Cow::Borrowed(&fields.active)
    } else {
        let mut active = fields.active.clone();
        for &node in &elsewhere {
            active[node] = true;
        }
        Cow::Owned(active)
    };
    for point in points.iter() {
        if failure.is_some() {
            break;
        }
        let force = point.traction * (point.area * point.factor(&step, stage));
        let spread =
            spread_over_active(&force, &point.support, &*active, &mut fields.external_force);
        if !spread && *weights == LoadPointWeights::Basis {
            failure = Some(fail(
                point,
                "is not next to any material point (no grid node of its support is active); put tractions on a body's boundary",
            ));
        }
    }
    if !elsewhere.is_empty() {
        let forces: Vec<(usize, SVector<f64, D>)> = (remote.iter().zip(&kept))
            .map(|(&node, &kept)| {
                let force = fields.external_force[node] - kept;
                fields.external_force[node] = kept;
                (node, force)
            })
            .collect();
        let owned = |node: usize| newton.shared_grid.as_deref().is_some_and(|s| s.owned(node));
        if let Err(why) = send_to_owners(&forces, owned, &mut fields.external_force) {
            failure.get_or_insert(SolverError::Module {
                step: step.number,
                what: format!("sending traction forces to other processes: {why}"),
                recoverable: false,
            });
        }
    }
    if let Some(failure) = failure {
        status.fail(failure);
    }
}

/// Of the support nodes `candidates` that no point of this process touches (decomposed
/// points), the nodes some point of another process touches: every process's candidates
/// gathered to all (`gather`, rank order), each counted on every process where it is active
/// (`active`), the counts summed over the processes (`sum`). Collective; the same set on every
/// process. Serially (one process, nothing to gather from others) the candidates are inactive
/// everywhere: none.
pub fn active_elsewhere(
    candidates: &BTreeSet<usize>,
    active: impl Fn(usize) -> bool,
    gather: impl FnOnce(&[u64]) -> Result<Vec<u64>, String>,
    sum: impl FnOnce(&mut [f64]),
) -> Result<BTreeSet<usize>, String> {
    let mine: Vec<u64> = candidates.iter().map(|&node| node as u64).collect();
    let mut all = gather(&mine)?;
    all.sort_unstable();
    all.dedup();
    if all.is_empty() {
        return Ok(BTreeSet::new());
    }
    let mut counts: Vec<f64> = all
        .iter()
        .map(|&node| if active(node as usize) { 1.0 } else { 0.0 })
        .collect();
    sum(&mut counts);
    Ok((all.iter().zip(&counts))
        .filter(|&(_, &count)| count > 0.0)
        .map(|(&node, _)| node as usize)
        .collect())
}

/// Every process's traction forces at nodes it does not hold (`forces`: node and force, from
/// [`active_elsewhere`]'s nodes) gathered to all; each node's owner (`owned`) adds them to its
/// share of `external_force`, which the sum over the processes then adds to the others' (the
/// decomposed `f_ext` sum after the loads). Collective.
fn send_to_owners<const D: usize>(
    forces: &[(usize, SVector<f64, D>)],
    owned: impl Fn(usize) -> bool,
    external_force: &mut NodeVec<SVector<f64, D>>,
) -> Result<(), String> {
    let rows: Vec<u64> = forces
        .iter()
        .flat_map(|(node, force)| {
            std::iter::once(*node as u64).chain(force.iter().map(|c| c.to_bits()))
        })
        .collect();
    let all = crate::distributed::gather_over_points(&rows)?;
    if all.len() % (D + 1) != 0 {
        return Err(format!("{} numbers are not rows of {}", all.len(), D + 1));
    }
    for row in all.chunks_exact(D + 1) {
        let node = row[0] as usize;
        if owned(node) {
            let force = SVector::<f64, D>::from_fn(|a, _| f64::from_bits(row[1 + a]));
            let slot = external_force
                .get_mut(node)
                .ok_or_else(|| format!("node {node} outside the grid"))?;
            *slot += force;
        }
    }
    Ok(())
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

/// `tractions_NNNN.vtu` and its series. With decomposed points every process's load points
/// are gathered first (`gather_rows`; collective: every process writes at the same steps).
pub fn write_tractions<const D: usize>(
    mut output: LoadPointOutput,
    mut series: ResMut<TractionSeries>,
    points: Query<&TractionPoint<D>>,
) {
    let (step, stage) = (*output.step, output.stage.as_deref().map_or(0, |s| s.0));
    let mut rows: Vec<LoadPointRow<D>> = points
        .iter()
        .map(|point| LoadPointRow::of(point, &step, stage))
        .collect();
    if crate::distributed::decomposed() && output.writes() {
        match gather_rows(&rows) {
            Ok(all) => rows = all,
            Err(why) => {
                output.status.fail(SolverError::Output {
                    step: step.number,
                    why: format!("gathering the traction points of every process: {why}"),
                });
                return;
            }
        }
    }
    output.write(&mut series.0, "tractions", |_, _| {
        rows.sort_by_key(|row| row.id);
        let n = rows.len();
        let positions = rows.iter().map(|row| pad(&row.position)).collect();
        let mut reference = Vec::with_capacity(3 * n);
        let mut area = Vec::with_capacity(n);
        let mut traction = Vec::with_capacity(3 * n);
        let mut force = Vec::with_capacity(3 * n);
        for row in &rows {
            reference.extend(pad(&row.reference_position));
            area.push(row.area);
            traction.extend(pad(&row.traction));
            force.extend(pad(&row.force));
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

/// A load point as its file shows it: `traction` is λ h at the step's factor, `force` λ h A.
#[derive(Clone, Debug, PartialEq)]
struct LoadPointRow<const D: usize> {
    id: u32,
    position: SVector<f64, D>,
    reference_position: SVector<f64, D>,
    area: f64,
    traction: SVector<f64, D>,
    force: SVector<f64, D>,
}

impl<const D: usize> LoadPointRow<D> {
    /// Numbers per row: id, position, reference position, area, traction, force.
    const LENGTH: usize = 2 + 4 * D;

    fn of(point: &TractionPoint<D>, step: &LoadStep, stage: usize) -> Self {
        let factor = point.factor(step, stage);
        Self {
            id: point.id,
            position: point.position,
            reference_position: point.reference_position,
            area: point.area,
            traction: point.traction * factor,
            force: point.traction * (point.area * factor),
        }
    }
}

/// Every process's rows, gathered to all (exact: the numbers' bits; identity outside a
/// decomposed run).
fn gather_rows<const D: usize>(rows: &[LoadPointRow<D>]) -> Result<Vec<LoadPointRow<D>>, String> {
    let mut numbers = Vec::with_capacity(rows.len() * LoadPointRow::<D>::LENGTH);
    for row in rows {
        numbers.push(u64::from(row.id));
        numbers.extend(row.position.iter().map(|c| c.to_bits()));
        numbers.extend(row.reference_position.iter().map(|c| c.to_bits()));
        numbers.push(row.area.to_bits());
        numbers.extend(row.traction.iter().map(|c| c.to_bits()));
        numbers.extend(row.force.iter().map(|c| c.to_bits()));
    }
    let all = crate::distributed::gather_over_points(&numbers)?;
    if all.len() % LoadPointRow::<D>::LENGTH != 0 {
        return Err(format!(
            "{} numbers are not rows of {}",
            all.len(),
            LoadPointRow::<D>::LENGTH
        ));
    }
    let vector = |bits: &[u64]| SVector::<f64, D>::from_fn(|a, _| f64::from_bits(bits[a]));
    Ok(all
        .chunks_exact(LoadPointRow::<D>::LENGTH)
        .map(|row| LoadPointRow {
            id: row[0] as u32,
            position: vector(&row[1..]),
            reference_position: vector(&row[1 + D..]),
            area: f64::from_bits(row[1 + 2 * D]),
            traction: vector(&row[2 + 2 * D..]),
            force: vector(&row[2 + 3 * D..]),
        })
        .collect())
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
    /// Whether this step writes the files.
    pub fn writes(&self) -> bool {
        self.plan.writes(&self.step)
    }

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

#[cfg(test)]
mod tests {
    use super::*;

    /// Three processes' active nodes on a row of 12 nodes, and the support nodes of their
    /// load points that they do not hold: a node held by another process is found (by every
    /// process, the same set), a node no process holds is not, and one process alone finds
    /// none.
    #[test]
    fn support_nodes_held_by_another_process_are_found_by_every_process() {
        let active: [Vec<usize>; 3] = [vec![0, 1, 2, 3, 4], vec![4, 5, 6, 7], vec![8, 9]];
        let candidates: [BTreeSet<usize>; 3] = [
            BTreeSet::from([5, 6, 11]), // 5, 6 on process 1; 11 nowhere
            BTreeSet::from([3, 8, 10]), // 3 on process 0, 8 on process 2; 10 nowhere
            BTreeSet::new(),
        ];
        let gathered: Vec<u64> = candidates
            .iter()
            .flat_map(|c| c.iter().map(|&n| n as u64))
            .collect();
        let found: Vec<BTreeSet<usize>> = (0..3)
            .map(|rank| {
                active_elsewhere(
                    &candidates[rank],
                    |node| active[rank].contains(&node),
                    |_| Ok(gathered.clone()),
                    // each process's count for the gathered (sorted, distinct) nodes, summed
                    |counts| {
                        let mut nodes = gathered.clone();
                        nodes.sort_unstable();
                        nodes.dedup();
                        assert_eq!(counts.len(), nodes.len());
                        for (count, node) in counts.iter_mut().zip(&nodes) {
                            *count = (0..3)
                                .filter(|&p| active[p].contains(&(*node as usize)))
                                .count() as f64;
                        }
                    },
                )
                .unwrap()
            })
            .collect();
        for set in &found {
            assert_eq!(*set, BTreeSet::from([3, 5, 6, 8]));
        }
        // one process: its candidates are inactive everywhere
        let alone = active_elsewhere(
            &BTreeSet::from([7, 9]),
            |node| node < 5,
            |local| Ok(local.to_vec()),
            |_| {},
        )
        .unwrap();
        assert!(alone.is_empty());
    }
}
