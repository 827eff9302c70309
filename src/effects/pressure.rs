//! A follower pressure on a curved boundary (2D): `pressure(#{ on: arc(#{ centre, radius,
//! from, to }), pressure: p })`, a pressure p (force per unit current length at load factor 1)
//! that acts normal to the *current* boundary and pushes into the body, such as the internal
//! pressure of a thick-walled cylinder. Unlike `traction(...)` (a dead load of fixed direction,
//! `tractions.rs`) its force follows the deformation, so it depends on the unknowns and adds a
//! load-stiffness term to the tangent.
//!
//! # Seeding
//!
//! The arc (centre c, radius R, angles θ₀ → θ₁) is cut into m equal parts (`per_cell` parts per
//! cell of arc length, m ≥ 1), with vertices V_k = c + R (cos θ_k, sin θ_k), k = 0..m, and a
//! load point M_k at the midpoint of each part's arc. All 2m + 1 points are carried by the
//! material like traction points: each has a host, the material point nearest to it in the
//! reference configuration (within a cell of it). Which side of the arc the body is on is read
//! from the hosts (all on one side, or the scene line is refused); the sign s = ±1 makes the
//! force push into the body for p > 0.
//!
//! # The force: the current chord of each part
//!
//! Part k carries the force of the pressure on the current segment between its vertices,
//!
//! ```text
//!   f_k = λ s p Q (x_{k+1} − x_k),      Q = [[0, 1], [−1, 0]]  (a quarter turn clockwise),
//! ```
//!
//! spread over the grid through the basis at its load point, f_ext,i += N_i(m_k) f_k (over the
//! active nodes of the support, as for traction points: the resultant is kept exactly). This
//! is p n dΓ integrated over the polygon through the carried vertices, which converges to the
//! arc's as m² (the chord of a part against its arc). It was chosen over the host-deformed
//! normal n dΓ = J F⁻ᵀ N dΓ₀ because the sum telescopes: the resultant is
//! λ s p Q (x_m − x_0), the pressure times the current chord of the whole arc, *exactly*, in
//! any configuration (the pressure on a closed curve has zero resultant, on an open one it is
//! p times the chord rotated), while J F⁻ᵀ N of the hosts makes it depend on the host's
//! gradient of a possibly coarse field and is exact only for homogeneous deformations.
//!
//! # Carrying, and the load stiffness
//!
//! During a load step the grid moves with the material (updated Lagrangian). A carried point
//! at x⁰ at the start of the step, hosted by the material point p at x_p, moves with the host's
//! displacement increment and its gradient,
//!
//! ```text
//!   x(Δu) = x⁰ + Σ_j ŵ_j Δu_j,     ŵ_j = N_j(x_p) + ∇N_j(x_p) · (x⁰ − x_p)
//! ```
//!
//! (`tractions::host_weights`): exactly the update x_p + Δf_p (x⁰ − x_p) of the host's
//! neighbourhood, linear in Δu. Every Newton iteration evaluates f_k at the current vertices,
//! and the tangent K = ∂f_int/∂Δu − ∂f_ext/∂Δu receives
//!
//! ```text
//!   K_(i,a)(j,b) −= λ s p N_i(m_k) (ŵ_j(V_{k+1}) − ŵ_j(V_k)) Q_ab
//! ```
//!
//! for every part k: the exact derivative (f_k is linear in Δu). It is not symmetric, so the
//! module marks the tangent non-symmetric. The nodes of a part's load point and of its
//! vertices' hosts are coupled in the sparsity pattern (`GridFields::couplings`). When the step
//! converges the carried points move to x(Δu).
//!
//! # With the load control and with arc-length control
//!
//! The loads stage adds f at the start-of-step configuration; from then on each iteration
//! replaces it (`Hook::AfterAssembly`) by f at the iterate: f_ext += λ (f̂_p(Δu) − f̂_p(Δu_prev)),
//! where f̂_p is the pressure's force at λ = 1. Under arc-length control (`stages::arc_length`)
//! the reference load f̂ must be the loads at λ = 1 *in the current configuration* (the
//! derivative of the residual with respect to λ): the same change is added to the arc's f̂
//! ([`ArcLength::change_reference`]), and λ is the iterate's.
//!
//! # Stages
//!
//! A pressure declared in stage k follows that stage's load factor, is held in full (its p;
//! its force still follows the boundary) in the stages after it, and with `until_stage: "s"`
//! is ramped down over stage s (`declarations::released_factor`). With `held: true` it is
//! applied in full (factor 1) from its stage's first step on while the other loads follow λ
//! (`resources::Ramp::Held` / `HeldFrom`, as `body_force` and `traction` spell it), e.g. an
//! inner pressure kept while a second load ramps. The parts of the
//! declarations that share a stage and a release form a group ([`PressureGroup`]) whose force
//! is kept and scaled by the group's factor; a scene without stages has one group, and its
//! factor is λ, as before. Under arc-length control in stage k each group's factor is affine in
//! λ, c = c₀ + λ c₁ ([`PressureGroup::split`]): the change of its force with the iterate goes
//! to the arc's f_fixed times c₀ and to its f̂ times c₁. [`apply_pressure`] is a load system of
//! the arc's second evaluation at λ = 0 (`effects::arc_length::add_load_system`).
//!
//! # Over several processes
//!
//! In a distributed run with replicated state (`mpirun`, without `--decompose`;
//! `effects::distributed`) every process holds every point, so every carried point and its
//! host, and `f_ext` is not summed over the processes: each process forms all of it, and the
//! right-hand side is the same on every process. So every process adds the pressure's force
//! and replaces it by the force at the iterate in full, as a serial run does. The tangent is a
//! sum of the processes' shares (each assembles its own points): the load stiffness is added
//! by process 0 alone (`distributed::adds_grid_terms`), once.
//!
//! With decomposed points (`--decompose`) a process holds only its slab's material points, a
//! part ties its load point to its vertices' hosts, which may be on other processes, and the
//! grid's vectors are local (owned and ghost nodes), `f_ext` summed over the processes after
//! the loads. Every process holds every carried point (a few per cell of arc) with its host's
//! `PointId` ([`PressurePoint::host_id`]):
//!
//! * at each step start, after the exchange of material points, [`find_pressure_weights`]
//!   links the points to the hosts this process holds, and finds the ŵ of those;
//! * [`share_pressure_weights`] (before the DOF stage; collective, outside the stages' sets:
//!   it shares a failure first) gathers every point's ŵ to all (exact bits), finds the load
//!   points' spread weights over the nodes active on any process (the supports are evaluated
//!   on every process at the same positions, their activity summed over the processes: the
//!   serial weights), pushes the coupling groups, and on process 0 makes every node of every
//!   group active, so that its DOF stage and the decomposed grid number them all
//!   (`effects::distributed::grid`: the local nodes are the supports' and the active ones);
//! * [`move_to_iterate`] (`Hook::Kinematics`, where every process meets before anything in
//!   the iteration can fail) forms x(Δu) on the host's process and shares it
//!   (`distributed::numbers_of_points`: the holder's numbers exactly), so every process holds
//!   every point's position at the iterate, and the point update moves every point there;
//! * at the loads process 0 alone adds λ f̂_p(0) (then `f_ext` is summed); after the assembly
//!   every process adds the change λ (f̂_p(Δu) − f̂_p(Δu_prev)) at its own nodes, where `f_ext`
//!   holds the sum already, and process 0 adds the load stiffness, once (it numbers all the
//!   parts' nodes; its share of K is summed with the others').
//!
//! Arc-length control is refused under `--decompose` (its own refusal), so the pressure's
//! change of the arc's f̂ there is never needed.
//!
//! Systems, added only when a scene declares a pressure: [`find_pressure_weights`]
//! (`Hook::Connectivity`), [`share_pressure_weights`] (decomposed points only),
//! [`move_to_iterate`] (`Hook::Kinematics`), [`apply_pressure`] (`Hook::Loads`; with held
//! loads under the arc also at λ = 0), [`follow_pressure`]
//! (`Hook::AfterAssembly`), [`carry_pressure_points`] (`Hook::PointUpdate`),
//! [`write_pressure`] (`Hook::Output`): `pressure_NNNN.vtu` (one vertex per part at its load
//! point, with the current chord's unit normal into the body, its length, λ p and the part's
//! force λ s p Q (x_{k+1} − x_k), [`PartOutput`]) and `pressure.pvd`, written as the traction
//! points' series is (`tractions::LoadPointOutput`).

use std::collections::{BTreeSet, HashMap, HashSet};

use bevy_ecs::prelude::*;
use nalgebra::SVector;
use rhai::Dynamic;

use super::arc_length::add_load_system;
use super::carried_points::{carried_point, restore_positions, save_positions};
use super::declarations::{
    LoadSummary, held_option, keep_largest_force, released_factor, until_stage_of,
    until_stage_option,
};
use super::tractions::{LoadPointOutput, host_weights};
use crate::basis::{BasisKind, BasisScratch, NodeWeight};
use crate::checkpoint::CheckpointPart;
use crate::components::{PointId, Position, Support};
use crate::method::{StepSchedule, StepSystems};
use crate::node_storage::NodeVec;
use crate::output::PvdSeries;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    CurrentStage, Grid, GridFields, LoadStep, Newton, Ramp, RunStatus, SolverError, Stage,
    StageClock,
};
use crate::scene::{
    CallSpec, GridSpec, Kind, Located, OptionSpec, Options, Range, Resolver, SceneApi, SceneSpec,
    ScriptError, nearest_points,
};
use crate::solver::NO_DOF;
use crate::stages::arc_length::ArcLength;
use crate::stages::output::{OutputPlan, pad};

/// `arc(#{ centre, radius, from, to })`: a circular arc in 2D, angles in degrees
/// counter-clockwise from the x axis.
#[derive(Clone, Debug, PartialEq)]
pub struct ArcShape {
    pub centre: [f64; 2],
    pub radius: f64,
    pub from: f64,
    pub to: f64,
}

impl ArcShape {
    /// The point at angle `degrees`.
    pub fn point(&self, degrees: f64) -> [f64; 2] {
        let t = degrees.to_radians();
        [
            self.centre[0] + self.radius * t.cos(),
            self.centre[1] + self.radius * t.sin(),
        ]
    }

    /// The arc's length.
    pub fn length(&self) -> f64 {
        self.radius * (self.to - self.from).abs().to_radians()
    }

    /// The vertices of `parts` equal parts (`parts + 1` points) and the midpoints of the parts'
    /// arcs (`parts` points), in the arc's direction.
    pub fn divide(&self, parts: usize) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let step = (self.to - self.from) / parts as f64;
        let vertices = (0..=parts)
            .map(|k| self.point(self.from + k as f64 * step))
            .collect();
        let midpoints = (0..parts)
            .map(|k| self.point(self.from + (k as f64 + 0.5) * step))
            .collect();
        (vertices, midpoints)
    }

    /// The number of equal parts that give `per_cell` parts per `cell` of its length (at least
    /// one), refused above `limit`.
    pub fn parts(&self, per_cell: usize, cell: f64, limit: usize) -> Result<usize, String> {
        let wanted = (per_cell as f64 * self.length() / cell).ceil().max(1.0);
        if wanted > limit as f64 {
            return Err(format!(
                "{wanted} parts of the arc exceed the limit of {limit}; lower per_cell"
            ));
        }
        Ok(wanted as usize)
    }
}

/// The hosts of points on an arc: for each of `points` the nearest of `material_points`,
/// which must lie within `reach`; a point outside the grid is refused first, each refusal
/// naming the point.
pub fn arc_hosts(
    grid: &GridSpec,
    material_points: &[&[f64]],
    points: &[Vec<f64>],
    reach: f64,
) -> Result<Vec<usize>, String> {
    if let Some(x) = points
        .iter()
        .find(|x| (0..2).any(|a| x[a] < grid.lower[a] || x[a] > grid.upper[a]))
    {
        return Err(format!(
            "the arc's point {x:?} is outside the grid [{:?} .. {:?}]",
            grid.lower, grid.upper
        ));
    }
    let hosts = nearest_points(grid, material_points, points);
    points
        .iter()
        .zip(hosts)
        .map(|(x, host)| {
            let host = host.ok_or("the scene has no material points")?;
            let p = material_points[host];
            let distance = (p[0] - x[0]).hypot(p[1] - x[1]);
            if distance > reach {
                return Err(format!(
                    "the arc's point {x:?} is {distance:.3e} from the nearest material point, farther than a cell: put the arc on a body's boundary"
                ));
            }
            Ok(host)
        })
        .collect()
}

/// `pressure(...)` as declared.
#[derive(Clone, Debug)]
struct PressureDeclaration {
    arc: ArcShape,
    pressure: f64,
    per_cell: usize,
    /// The stage it belongs to (λ of that stage, held after it).
    ramp: Ramp,
    /// `until_stage`: the stage whose start releases it, by name.
    until: Option<String>,
}

/// A carried point of a pressure: its reference position and host (a global point index).
#[derive(Clone, Debug, PartialEq)]
pub struct CarriedSpec {
    pub position: [f64; 2],
    pub host: usize,
}

/// One part of a pressure arc: its vertices and load point (indices among the scene's pressure
/// points), s p, the pressure signed so that s p Q (x_end − x_start) pushes into the body, the
/// side s = ±1 of the body (s Q (x_end − x_start) points into it) and the group of its load
/// factor ([`Pressures::groups`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Part {
    pub start: usize,
    pub end: usize,
    pub load_point: usize,
    pub pressure: f64,
    pub side: f64,
    pub group: usize,
}

/// How the pressures of a group follow the load factor: the stage they belong to (its λ in
/// it, held in full after it) and the stage whose start releases them, if any
/// (`declarations::released_factor`). A scene without stages has one group, λ itself.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PressureGroup {
    pub ramp: Ramp,
    pub until: Option<usize>,
}

impl PressureGroup {
    /// The factor of the group's pressures in `step` of stage `stage`.
    pub fn factor(&self, step: &LoadStep, stage: usize) -> f64 {
        released_factor(step, self.ramp, self.until, stage)
    }

    /// Its factor as f_fixed + λ f̂ splits it under arc-length control: (the factor at λ = 0,
    /// its change from λ = 0 to 1). Every factor is affine in λ.
    pub fn split(&self, step: &LoadStep, stage: usize) -> (f64, f64) {
        let at = |factor: f64| self.factor(&LoadStep { factor, ..*step }, stage);
        let held = at(0.0);
        (held, at(1.0) - held)
    }
}

/// The scene's pressures: every carried point (vertices and load points), every part and the
/// groups of their load factors.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pressures {
    pub points: Vec<CarriedSpec>,
    pub parts: Vec<Part>,
    pub groups: Vec<PressureGroup>,
    pub summaries: Vec<LoadSummary>,
}

/// A vertex or load point of a pressure arc, carried by the material (module docs).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct PressurePoint<const D: usize> {
    pub id: u32,
    /// Current position (converged, start of the load step).
    pub position: SVector<f64, D>,
    /// The host material point's entity (`Entity::PLACEHOLDER` while another process holds
    /// it: decomposed points, module docs).
    pub host: Entity,
    /// The host's `PointId`: how it is found again when it is spawned anew or moves to
    /// another process (decomposed points).
    pub host_id: u32,
}

carried_point!(PressurePoint);

/// The pressure's state during a load step.
#[derive(Resource, Debug, Default)]
pub struct PressureLoad<const D: usize> {
    pub parts: Vec<Part>,
    pub groups: Vec<PressureGroup>,
    /// Start-of-step positions of the carried points, by id.
    pub start: Vec<SVector<f64, D>>,
    /// The carried points' positions at the current iterate, x(Δu), by id
    /// ([`move_to_iterate`]).
    pub positions: Vec<SVector<f64, D>>,
    /// ŵ_j of every carried point, by id (module docs).
    pub carry: Vec<Vec<(usize, f64)>>,
    /// Whether this process holds each carried point's host (every point but with decomposed
    /// points), by id: it finds the point's ŵ and its position at the iterate.
    pub hosted: Vec<bool>,
    /// N_i(m_k) / Σ_active N of every part's load point, over the active nodes.
    pub spread: Vec<Vec<(usize, f64)>>,
    /// f̂_p by node, per group: the pressures' forces at factor 1 now included in the external
    /// force (each group's times its factor).
    pub added: Vec<NodeVec<SVector<f64, D>>>,
}

/// The `pressure.pvd` series.
#[derive(Resource)]
pub struct PressureSeries(pub PvdSeries);

/// A quarter turn clockwise, Q t (2D; zero in other dimensions, where no pressure is built).
fn turn<const D: usize>(t: &SVector<f64, D>) -> SVector<f64, D> {
    let mut n = SVector::zeros();
    if D == 2 {
        n[0] = t[1];
        n[1] = -t[0];
    }
    n
}

/// x(Δu) = x⁰ + Σ_j ŵ_j Δu_j.
pub fn carried_position<const D: usize>(
    start: &SVector<f64, D>,
    carry: &[(usize, f64)],
    increment: &(impl std::ops::Index<usize, Output = SVector<f64, D>> + ?Sized),
) -> SVector<f64, D> {
    carry
        .iter()
        .fold(*start, |x, &(node, w)| x + increment[node] * w)
}

/// The force of one part at λ = 1: s p Q (x_end − x_start).
pub fn part_force<const D: usize>(part: &Part, positions: &[SVector<f64, D>]) -> SVector<f64, D> {
    turn(&(positions[part.end] - positions[part.start])) * part.pressure
}

/// What `pressure_NNNN.vtu` shows of one part at its group's load factor `factor`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartOutput<const D: usize> {
    /// n = s Q t / |t| of the current chord t = x_end − x_start: the unit normal into the body.
    pub normal: SVector<f64, D>,
    /// |t|, the current chord's length.
    pub length: f64,
    /// λ p (positive pushes into the body).
    pub pressure: f64,
    /// λ p |t| n = λ s p Q t, the part's force ([`part_force`] times λ).
    pub force: SVector<f64, D>,
}

/// The part's [`PartOutput`] at the positions of the carried points.
pub fn part_output<const D: usize>(
    part: &Part,
    positions: &[SVector<f64, D>],
    factor: f64,
) -> PartOutput<D> {
    let chord = positions[part.end] - positions[part.start];
    let length = chord.norm();
    PartOutput {
        normal: turn(&chord) * (part.side / length),
        length,
        pressure: factor * part.pressure * part.side,
        force: part_force(part, positions) * factor,
    }
}

/// Adds every part's force at λ = 1, spread over its load point's active nodes, to `nodes`.
pub fn add_pressure_forces<const D: usize>(
    parts: &[Part],
    spread: &[Vec<(usize, f64)>],
    positions: &[SVector<f64, D>],
    nodes: &mut [SVector<f64, D>],
) {
    for (part, spread) in parts.iter().zip(spread) {
        let force = part_force(part, positions);
        for &(node, w) in spread {
            nodes[node] += force * w;
        }
    }
}

/// Every part's force at factor 1, spread over its load point's active nodes, summed by group:
/// one vector by node per group (in part order within a group, as [`add_pressure_forces`]).
pub fn group_forces<const D: usize>(
    parts: &[Part],
    groups: usize,
    spread: &[Vec<(usize, f64)>],
    positions: &[SVector<f64, D>],
    nodes: usize,
) -> Vec<NodeVec<SVector<f64, D>>> {
    let mut forces = vec![NodeVec::new(nodes, SVector::zeros()); groups];
    for (part, spread) in parts.iter().zip(spread) {
        let force = part_force(part, positions);
        for &(node, w) in spread {
            forces[part.group][node] += force * w;
        }
    }
    forces
}

/// Calls `add(i, a, j, b, value)` for every entry of −λ ∂f_ext/∂Δu (module docs): node i,
/// component a of the force; node j, component b of the increment; `factors` is λ of each
/// group (the parts' [`Part::group`]).
pub fn pressure_tangent<const D: usize>(
    parts: &[Part],
    spread: &[Vec<(usize, f64)>],
    carry: &[Vec<(usize, f64)>],
    factors: &[f64],
    mut add: impl FnMut(usize, usize, usize, usize, f64),
) {
    let q = |a: usize, b: usize| match (a, b) {
        (0, 1) => 1.0,
        (1, 0) => -1.0,
        _ => 0.0,
    };
    for (part, spread) in parts.iter().zip(spread) {
        let factor = factors[part.group];
        let ends = [(part.end, 1.0), (part.start, -1.0)];
        for &(i, n_i) in spread {
            for &(vertex, sign) in &ends {
                for &(j, w_j) in &carry[vertex] {
                    let scale = -factor * part.pressure * n_i * w_j * sign;
                    for (a, b) in [(0, 1), (1, 0)] {
                        if a < D && b < D {
                            add(i, a, j, b, scale * q(a, b));
                        }
                    }
                }
            }
        }
    }
}

/// The module: scheduled when a scene declares a non-zero pressure.
#[derive(Clone, Copy, Debug, Default)]
pub struct PressureModule;

fn arc_call() -> CallSpec {
    CallSpec::options(
        "arc",
        "a circular arc in 2D (for pressure(...)): centre, radius and the angles from and to, in degrees counter-clockwise from the x axis",
        vec![
            OptionSpec::required("centre", Kind::Numbers, "the centre [x, y]"),
            OptionSpec::required("radius", Kind::Number(Range::Positive), "the radius"),
            OptionSpec::required(
                "from",
                Kind::Number(Range::Any),
                "the first angle (degrees)",
            ),
            OptionSpec::required(
                "to",
                Kind::Number(Range::Any),
                "the last angle (degrees), not equal to `from`, at most 360 from it",
            ),
        ],
        |_, options: &Options, _| {
            let centre = options.numbers("centre").unwrap_or_default();
            let [x, y] = centre else {
                return Err(format!(
                    "arc(...): 'centre' has {} coordinates; an arc is 2D: give [x, y]",
                    centre.len()
                ));
            };
            let from = options.number("from").unwrap_or(0.0);
            let to = options.number("to").unwrap_or(0.0);
            if from == to || (to - from).abs() > 360.0 {
                return Err(format!(
                    "arc(...): the angles from {from} to {to} (degrees) must differ by more than 0 and at most 360"
                ));
            }
            Ok(Dynamic::from(ArcShape {
                centre: [*x, *y],
                radius: options.number("radius").unwrap_or(1.0),
                from,
                to,
            }))
        },
    )
}

impl Plugin for PressureModule {
    fn name(&self) -> &'static str {
        "pressure"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.call(arc_call());
        api.call(CallSpec::options(
            "pressure",
            "a follower pressure on a curved boundary (2D): force p per unit current length at load factor 1, normal to the current boundary and pushing into the body, with its load stiffness in the tangent (non-symmetric); carried by points that move with the material",
            vec![
                OptionSpec::required(
                    "on",
                    Kind::Value {
                        what: "arc(#{ centre, radius, from, to })",
                    },
                    "the boundary: an arc on a body's boundary (the body on either side)",
                ),
                OptionSpec::required(
                    "pressure",
                    Kind::Number(Range::Any),
                    "the pressure p (positive pushes into the body)",
                ),
                OptionSpec::new(
                    "per_cell",
                    Kind::Whole {
                        min: 1,
                        max: Some(1000),
                    },
                    "equal parts of the arc per cell of its length (default 2)",
                ),
                held_option(),
                until_stage_option(),
            ],
            |builder, options: &Options, at| {
                let on = options.value("on").cloned().unwrap_or(Dynamic::UNIT);
                let Some(arc) = on.try_cast::<ArcShape>() else {
                    return Err(
                        "pressure(...): option 'on' must be an arc(#{ centre, radius, from, to })"
                            .to_string(),
                    );
                };
                builder.declare(Located::new(
                    PressureDeclaration {
                        arc,
                        pressure: options.number("pressure").unwrap_or(0.0),
                        per_cell: options.whole("per_cell").unwrap_or(2),
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
        let mut pressures = Pressures::default();
        for declaration in scene.declarations::<PressureDeclaration>() {
            let fail = |message: String| {
                ScriptError::at(declaration.at, format!("pressure(...): {message}"))
            };
            if scene.spec.grid.basis == BasisKind::Fem {
                return Err(fail(
                    "a pressure is applied through the background grid's basis; basis \"fem\" has none"
                        .into(),
                ));
            }
            let until = until_stage_of(
                scene.spec,
                "pressure",
                declaration.value.until.as_deref(),
                declaration.stage,
                declaration.at,
            )?;
            let group = PressureGroup {
                ramp: declaration.value.ramp,
                until,
            };
            let group = match pressures.groups.iter().position(|g| *g == group) {
                Some(index) => index,
                None => {
                    pressures.groups.push(group);
                    pressures.groups.len() - 1
                }
            };
            let material_points = scene.spec.material_point_positions();
            seed_pressure(
                &scene.spec.grid,
                &material_points,
                &declaration.value,
                declaration.at.line(),
                group,
                &mut pressures,
            )
            .map_err(fail)?;
            if let Some(summary) = pressures.summaries.pop() {
                let mut summary = summary.in_stage(scene.spec, declaration.value.ramp.stage());
                if declaration.value.ramp.is_held() {
                    summary.factor += ", held in full from the stage's first step";
                }
                pressures
                    .summaries
                    .push(summary.released(scene.spec, until));
            }
        }
        if !pressures.parts.is_empty() {
            scene.spec.set_part(pressures);
        }
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        let pressures = spec.part::<Pressures>()?;
        let mut text = format!(
            "{} parts of arcs carrying a follower pressure ({} carried points)",
            pressures.parts.len(),
            pressures.points.len()
        );
        for summary in &pressures.summaries {
            text += "\n    ";
            text += &summary.describe();
        }
        Some(text)
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<Pressures>()
            .is_some_and(|p| p.parts.iter().any(|part| part.pressure != 0.0))
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis != BasisKind::Fem && spec.dim() == 2
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let Some(pressures) = simulation.spec().part::<Pressures>() else {
            return;
        };
        if D != 2 {
            simulation.fail("pressure(...) on an arc needs a 2D grid");
            return;
        }
        let entities = simulation.point_entities();
        // with decomposed points every process holds every pressure point, and the hosts of
        // its own slab (module docs)
        let decomposed = crate::distributed::decomposed();
        let mut batch = Vec::new();
        for (id, point) in pressures.points.iter().enumerate() {
            let host = match entities.get(point.host) {
                Some(&host) if host != Entity::PLACEHOLDER => host,
                _ if decomposed => Entity::PLACEHOLDER,
                _ => {
                    simulation.fail(format!("pressure point host {} does not exist", point.host));
                    return;
                }
            };
            batch.push(PressurePoint::<D> {
                id: id as u32,
                position: SVector::from_fn(|a, _| point.position[a]),
                host,
                host_id: point.host as u32,
            });
        }
        let load = PressureLoad::<D> {
            parts: pressures.parts.clone(),
            groups: pressures.groups.clone(),
            ..Default::default()
        };
        let releases = pressures.groups.iter().any(|g| g.until.is_some());
        simulation.world().spawn_batch(batch);
        simulation.world().insert_resource(load);
        let dir = simulation.world().resource::<OutputPlan>().dir.clone();
        simulation
            .world()
            .insert_resource(PressureSeries(PvdSeries::new(dir.join("pressure.pvd"))));
        if releases {
            keep_largest_force(simulation);
        }
        simulation
            .nonsymmetric_tangent()
            .checkpoint(CheckpointPart {
                name: "pressure points",
                save: save_positions::<D, PressurePoint<D>>,
                restore: restore_positions::<D, PressurePoint<D>>,
            })
            .series(|world| vec![&mut world.resource_mut::<PressureSeries>().into_inner().0])
            .add_systems(Hook::Connectivity, find_pressure_weights::<D>);
        // under arc-length control with held loads also evaluated at λ = 0 (f_fixed)
        add_load_system(simulation, apply_pressure::<D>);
        if decomposed {
            // collective, outside the stages' sets (it shares a failure first)
            let mut schedules = simulation.world().resource_mut::<Schedules>();
            schedules.entry(StepSchedule).add_systems(
                share_pressure_weights::<D>
                    .after(StepSystems::Connectivity)
                    .before(StepSystems::Dofs),
            );
        }
        simulation
            .add_systems(Hook::Kinematics, move_to_iterate::<D>)
            .add_systems(Hook::AfterAssembly, follow_pressure::<D>)
            .add_systems(Hook::PointUpdate, carry_pressure_points::<D>)
            .add_systems(Hook::Output, write_pressure::<D>);
    }
}

/// Seeds one `pressure(...)` into `pressures` (module docs): the parts, their vertices and load
/// points with their hosts, and the side of the body.
fn seed_pressure(
    grid: &GridSpec,
    material_points: &[&[f64]],
    declaration: &PressureDeclaration,
    line: Option<usize>,
    group: usize,
    pressures: &mut Pressures,
) -> Result<(), String> {
    if grid.dim() != 2 {
        return Err(format!(
            "a pressure on an arc needs a 2D grid, this one is {}-dimensional",
            grid.dim()
        ));
    }
    let arc = &declaration.arc;
    let cell = (0..2)
        .map(|a| (grid.upper[a] - grid.lower[a]) / grid.cells[a] as f64)
        .fold(f64::INFINITY, f64::min);
    let largest_cell = (0..2)
        .map(|a| (grid.upper[a] - grid.lower[a]) / grid.cells[a] as f64)
        .fold(0.0, f64::max);
    let parts = arc.parts(
        declaration.per_cell,
        cell,
        crate::scene::MAX_SEED_CANDIDATES,
    )?;
    let (vertices, midpoints) = arc.divide(parts);
    let queries: Vec<Vec<f64>> = vertices
        .iter()
        .chain(&midpoints)
        .map(|x| x.to_vec())
        .collect();
    let found = arc_hosts(grid, material_points, &queries, largest_cell)?;
    // the body's side: s Q (V_{k+1} − V_k) must point towards the load points' hosts
    let base = pressures.points.len();
    let (mut towards, mut away) = (0, 0);
    for k in 0..parts {
        let t = [
            vertices[k + 1][0] - vertices[k][0],
            vertices[k + 1][1] - vertices[k][1],
        ];
        let host = material_points[found[parts + 1 + k]];
        let side = t[1] * (host[0] - midpoints[k][0]) - t[0] * (host[1] - midpoints[k][1]);
        if side > 0.0 {
            towards += 1;
        } else if side < 0.0 {
            away += 1;
        }
    }
    if towards > 0 && away > 0 || towards + away == 0 {
        return Err(format!(
            "material points lie on both sides of the arc ({towards} parts have their nearest point on one side, {away} on the other): put the arc on a body's boundary"
        ));
    }
    let sign = if towards > 0 { 1.0 } else { -1.0 };
    let pressure = sign * declaration.pressure;
    pressures.points.extend(
        vertices
            .iter()
            .chain(&midpoints)
            .zip(&found)
            .map(|(x, &host)| CarriedSpec { position: *x, host }),
    );
    pressures.parts.extend((0..parts).map(|k| Part {
        start: base + k,
        end: base + k + 1,
        load_point: base + parts + 1 + k,
        pressure,
        side: sign,
        group,
    }));
    let chord = [
        vertices[parts][0] - vertices[0][0],
        vertices[parts][1] - vertices[0][1],
    ];
    pressures.summaries.push(LoadSummary::new(
        line,
        "pressure",
        "pressure load points",
        midpoints.iter().map(|x| &x[..]),
        vec![pressure * chord[1], -pressure * chord[0]],
    ));
    Ok(())
}

/// Connectivity (start of the step): the carried points' host weights ŵ, the load points'
/// spread weights over the active nodes, and the coupling of each part's nodes. With
/// decomposed points only the ŵ of the points whose hosts this process holds (found by their
/// `PointId`s after the step start's exchange); [`share_pressure_weights`] does the rest.
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn find_pressure_weights<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut load: ResMut<PressureLoad<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<(BasisScratch, Vec<NodeWeight<D>>)>,
    hosts: Query<(&Support<D>, &Position<D>)>,
    held: Query<(Entity, &PointId)>,
    mut points: Query<&mut PressurePoint<D>>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let (load, fields) = (&mut *load, &mut *fields);
    let decomposed = crate::distributed::decomposed();
    if decomposed {
        // the hosts this process holds, by `PointId` (the exchange may have spawned them anew)
        let entities: HashMap<u32, Entity> = held.iter().map(|(e, id)| (id.0, e)).collect();
        for mut point in points.iter_mut() {
            point.host = entities
                .get(&point.host_id)
                .copied()
                .unwrap_or(Entity::PLACEHOLDER);
        }
    }
    let mut rows: Vec<&PressurePoint<D>> = points.iter().collect();
    rows.sort_by_key(|point| point.id);
    let fail = |what: String| SolverError::Module {
        step: step.number,
        what,
        recoverable: false,
    };
    load.start = rows.iter().map(|point| point.position).collect();
    load.positions = load.start.clone();
    load.carry.clear();
    load.hosted.clear();
    for point in &rows {
        let Ok((support, x)) = hosts.get(point.host) else {
            if decomposed {
                // another process's (shared by `share_pressure_weights`)
                load.carry.push(Vec::new());
                load.hosted.push(false);
                continue;
            }
            status.fail(fail(format!(
                "pressure point {} has lost its host material point",
                point.id
            )));
            return;
        };
        let weights = host_weights(&support.0, &(point.position - x.0));
        load.carry
            .push(weights.iter().map(|w| (w.node, w.value)).collect());
        load.hosted.push(true);
    }
    if decomposed {
        return;
    }
    let active = &fields.active;
    let spread = spread_weights(&grid.0, &load.parts, &load.start, &mut scratch, |node| {
        active[node]
    });
    match spread {
        Ok(spread) => load.spread = spread,
        Err(why) => {
            status.fail(fail(why));
            return;
        }
    }
    fields.couplings.extend(coupling_groups(load));
}

/// The spread weights of every part's load point at `start` (the carried points' positions
/// by id): N_i(m_k) / Σ_active N over the support's nodes that are `active`. An error names a
/// load point outside the grid or with no active node.
pub fn spread_weights<const D: usize>(
    grid: &crate::basis::GridBasis<D>,
    parts: &[Part],
    start: &[SVector<f64, D>],
    (scratch, support): &mut (BasisScratch, Vec<NodeWeight<D>>),
    active: impl Fn(usize) -> bool,
) -> Result<Vec<Vec<(usize, f64)>>, String> {
    let mut spread = Vec::with_capacity(parts.len());
    for part in parts {
        let x = start[part.load_point];
        let at = || x.iter().copied().collect::<Vec<_>>();
        if grid.eval(&x, scratch, support).is_err() {
            return Err(format!(
                "pressure load point at {:?} left the background grid",
                at()
            ));
        }
        let total: f64 = support
            .iter()
            .filter(|w| active(w.node))
            .map(|w| w.value)
            .sum();
        if total <= 0.0 {
            return Err(format!(
                "pressure load point at {:?} is not next to any material point (no node of its support is active)",
                at()
            ));
        }
        spread.push(
            support
                .iter()
                .filter(|w| active(w.node))
                .map(|w| (w.node, w.value / total))
                .collect(),
        );
    }
    Ok(spread)
}

/// The nodes of each part coupled in the tangent: its load point's spread nodes and its
/// vertices' hosts' support nodes (the ŵ), sorted.
fn coupling_groups<const D: usize>(load: &PressureLoad<D>) -> Vec<Vec<usize>> {
    (load.parts.iter().zip(&load.spread))
        .map(|(part, spread)| {
            let mut group: Vec<usize> = spread.iter().map(|&(node, _)| node).collect();
            for vertex in [part.start, part.end] {
                group.extend(load.carry[vertex].iter().map(|&(node, _)| node));
            }
            group.sort_unstable();
            group.dedup();
            group
        })
        .collect()
}

/// Decomposed points (module docs), after the connectivity and before the DOF stage
/// (collective: not in a stage's set, it runs after a failure too and shares it first): every
/// process's ŵ gathered to all (exact bits; each carried point's from the process holding its
/// host), the load points' spread weights over the nodes active on any process (the same on
/// every process), the parts' coupling groups, and on process 0, which adds the load
/// stiffness, every node of every group made active, so that its DOF stage numbers them all.
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn share_pressure_weights<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    newton: Res<Newton>,
    mut load: ResMut<PressureLoad<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<(BasisScratch, Vec<NodeWeight<D>>)>,
) {
    #[cfg(feature = "mpi")]
    let failed =
        crate::effects::distributed::share_failure(&mut status, step.number, newton.iterations);
    #[cfg(not(feature = "mpi"))]
    let failed = {
        let _ = &newton; // never scheduled without the feature (no decomposed points)
        status.0.is_some()
    };
    if failed {
        return;
    }
    let _timer = clock.time(Stage::Connectivity);
    let (load, fields) = (&mut *load, &mut *fields);
    let fail = |what: String| SolverError::Module {
        step: step.number,
        what,
        recoverable: false,
    };
    if let Err(why) = share_carry(load) {
        status.fail(fail(format!(
            "sharing the pressure points' host weights between the processes: {why}"
        )));
        return;
    }
    // the nodes of the load points' supports active on any process (every process evaluates
    // the same supports at the same positions)
    let mut candidates = BTreeSet::new();
    for part in &load.parts {
        let (scratch, support) = &mut *scratch;
        if grid
            .0
            .eval(&load.start[part.load_point], scratch, support)
            .is_ok()
        {
            candidates.extend(support.iter().map(|w| w.node));
        }
    }
    let candidates: Vec<usize> = candidates.into_iter().collect();
    let mut counts: Vec<f64> = (candidates.iter())
        .map(|&node| f64::from(u8::from(fields.active[node])))
        .collect();
    crate::distributed::sum_over_points(&mut counts);
    let anywhere: HashSet<usize> = (candidates.iter().zip(&counts))
        .filter(|&(_, &count)| count > 0.0)
        .map(|(&node, _)| node)
        .collect();
    let spread = spread_weights(&grid.0, &load.parts, &load.start, &mut scratch, |node| {
        anywhere.contains(&node)
    });
    match spread {
        Ok(spread) => load.spread = spread,
        Err(why) => {
            status.fail(fail(why));
            return;
        }
    }
    let groups = coupling_groups(load);
    if crate::distributed::adds_grid_terms() {
        for &node in groups.iter().flatten() {
            fields.active[node] = true;
        }
    }
    fields.couplings.extend(groups);
}

/// Every carried point's ŵ from the process that holds its host, to every process (an
/// all-gather of rows `id, count, (node, weight bits) × count`; identity when the points are
/// not decomposed). Each point must come from exactly one process.
fn share_carry<const D: usize>(load: &mut PressureLoad<D>) -> Result<(), String> {
    let mut rows = Vec::new();
    for (id, carry) in load.carry.iter().enumerate() {
        if load.hosted[id] {
            rows.push(id as u64);
            rows.push(carry.len() as u64);
            for &(node, w) in carry {
                rows.extend([node as u64, w.to_bits()]);
            }
        }
    }
    let all = crate::distributed::gather_over_points(&rows)?;
    let mut found = vec![0usize; load.carry.len()];
    let mut rest = &all[..];
    while let [id, count, tail @ ..] = rest {
        let (id, count) = (*id as usize, *count as usize);
        if tail.len() < 2 * count || id >= found.len() {
            return Err(format!("a broken row of host weights for point {id}"));
        }
        found[id] += 1;
        load.carry[id] = tail[..2 * count]
            .chunks_exact(2)
            .map(|pair| (pair[0] as usize, f64::from_bits(pair[1])))
            .collect();
        rest = &tail[2 * count..];
    }
    if let Some(id) = found.iter().position(|&n| n != 1) {
        return Err(format!(
            "pressure point {id}'s host is held by {} processes, not one",
            found[id]
        ));
    }
    Ok(())
}

/// Before the stress update of every Newton iteration: the carried points' positions at the
/// iterate, x(Δu) = x⁰ + Σ_j ŵ_j Δu_j, each found by the process that holds its host (which
/// holds the increments at its host's support) and, with decomposed points, shared with the
/// others (`distributed::numbers_of_points`: the holder's numbers exactly).
pub fn move_to_iterate<const D: usize>(
    step: Res<LoadStep>,
    mut load: ResMut<PressureLoad<D>>,
    fields: Res<GridFields<D>>,
    mut status: ResMut<RunStatus>,
) {
    let load = &mut *load;
    let found = crate::distributed::numbers_of_points(load.start.len(), D, |id, numbers| {
        if !load.hosted[id] {
            return false;
        }
        let x = carried_position(&load.start[id], &load.carry[id], &fields.increment);
        numbers.copy_from_slice(x.as_slice());
        true
    });
    for (id, numbers) in found.into_iter().enumerate() {
        let Some(numbers) = numbers else {
            status.fail(SolverError::Module {
                step: step.number,
                what: format!("pressure point {id}'s position at the iterate is on no process"),
                recoverable: false,
            });
            return;
        };
        load.positions[id] = SVector::from_column_slice(&numbers);
    }
}

/// Loads: the pressure's force at the start-of-step configuration, λ f̂_p(0) (each group's λ:
/// its stage's, held after it, ramped down over the stage that releases it).
pub fn apply_pressure<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut load: ResMut<PressureLoad<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
) {
    let _timer = clock.time(Stage::Loads);
    let load = &mut *load;
    let stage = stage.map_or(0, |s| s.0);
    load.added = group_forces(
        &load.parts,
        load.groups.len(),
        &load.spread,
        &load.start,
        fields.external_force.len(),
    );
    if crate::distributed::decomposed() && !crate::distributed::adds_grid_terms() {
        return; // process 0 adds it for all (`f_ext` is summed over the processes next)
    }
    for (group, added) in load.groups.iter().zip(&load.added) {
        let factor = group.factor(&step, stage);
        for (node, added) in added.written() {
            fields.external_force[node] += added * factor;
        }
    }
}

/// After the assembly of every Newton iteration: the force at the iterate replaces the one the
/// external force holds (and, in a step under arc-length control, the arc's f̂ and f_fixed
/// follow: each group's change split as its factor splits, `PressureGroup::split`), and the
/// load stiffness −λ ∂f̂_p/∂Δu joins the tangent (module docs).
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn follow_pressure<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut load: ResMut<PressureLoad<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
    arc: Option<ResMut<ArcLength<D>>>,
) {
    let _timer = clock.time(Stage::Assembly);
    let (load, fields) = (&mut *load, &mut *fields);
    let stage = stage.map_or(0, |s| s.0);
    let now = group_forces(
        &load.parts,
        load.groups.len(),
        &load.spread,
        &load.positions,
        fields.external_force.len(),
    );
    let nodes = fields.external_force.len();
    let (mut reference, mut held) = (
        NodeVec::new(nodes, SVector::zeros()),
        NodeVec::new(nodes, SVector::zeros()),
    );
    let mut any_held = false;
    let mut factors = Vec::with_capacity(load.groups.len());
    for ((group, now), added) in load.groups.iter().zip(&now).zip(&load.added) {
        let factor = group.factor(&step, stage);
        factors.push(factor);
        let (at_zero, slope) = group.split(&step, stage);
        any_held |= at_zero != 0.0;
        // the nodes either spread reaches (the others' change is zero)
        let reached: BTreeSet<usize> = (now.written().chain(added.written()))
            .map(|(node, _)| node)
            .collect();
        for node in reached {
            let change = now[node] - added[node];
            if fields.active[node] {
                // with decomposed points this process's nodes, whose `f_ext` holds the sum
                fields.external_force[node] += change * factor;
            }
            reference[node] += change * slope;
            held[node] += change * at_zero;
        }
    }
    if let Some(mut arc) = arc
        && arc.controls(step.number)
    {
        arc.change_reference(&reference, &fields.dofs);
        if any_held {
            arc.change_fixed(&held);
        }
    }
    load.added = now;
    if !crate::distributed::adds_grid_terms() {
        return; // process 0 adds the load stiffness for all (the shares of K are summed)
    }
    let dofs = &fields.dofs;
    pressure_tangent::<D>(
        &load.parts,
        &load.spread,
        &load.carry,
        &factors,
        |i, a, j, b, value| {
            let (row, col) = (dofs[i][a], dofs[j][b]);
            if row != NO_DOF && col != NO_DOF {
                newton.matrix.add(row, col, value);
            }
        },
    );
}

/// Point update: the carried points move to x(Δu) of the converged step (the last iterate's
/// positions, [`move_to_iterate`]: with decomposed points every process moves every point).
pub fn carry_pressure_points<const D: usize>(
    load: Res<PressureLoad<D>>,
    mut points: Query<&mut PressurePoint<D>>,
) {
    for mut point in points.iter_mut() {
        if let Some(x) = load.positions.get(point.id as usize) {
            point.position = *x;
        }
    }
}

/// `pressure_NNNN.vtu` and its series: one vertex per part at its load point's current
/// position, with the part's `normal`, `length`, `pressure` and `force` ([`PartOutput`]).
pub fn write_pressure<const D: usize>(
    mut output: LoadPointOutput,
    load: Res<PressureLoad<D>>,
    mut series: ResMut<PressureSeries>,
    points: Query<&PressurePoint<D>>,
) {
    output.write(&mut series.0, "pressure", |step, stage| {
        let mut positions = vec![SVector::<f64, D>::zeros(); points.iter().len()];
        for point in &points {
            positions[point.id as usize] = point.position;
        }
        let n = load.parts.len();
        let mut at = Vec::with_capacity(n);
        let (mut normal, mut force) = (Vec::with_capacity(3 * n), Vec::with_capacity(3 * n));
        let (mut length, mut pressure) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for part in &load.parts {
            let factor = load.groups[part.group].factor(step, stage);
            let row = part_output(part, &positions, factor);
            at.push(pad(&positions[part.load_point]));
            normal.extend(pad(&row.normal));
            length.push(row.length);
            pressure.push(row.pressure);
            force.extend(pad(&row.force));
        }
        let columns = vec![
            ("normal", 3, normal),
            ("length", 1, length),
            ("pressure", 1, pressure),
            ("force", 3, force),
        ];
        (at, columns)
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two parts on three vertices, load points with a few nodes each; vertices carried by
    /// overlapping node sets.
    /// Parts, spread weights, carry weights, start positions.
    type Example = (
        Vec<Part>,
        Vec<Vec<(usize, f64)>>,
        Vec<Vec<(usize, f64)>>,
        Vec<SVector<f64, 2>>,
    );

    fn example() -> Example {
        let parts = vec![
            Part {
                start: 0,
                end: 1,
                load_point: 3,
                pressure: 2.5,
                side: 1.0,
                group: 0,
            },
            Part {
                start: 1,
                end: 2,
                load_point: 4,
                pressure: 2.5,
                side: 1.0,
                group: 0,
            },
        ];
        let spread = vec![vec![(0, 0.2), (1, 0.5), (2, 0.3)], vec![(2, 0.6), (3, 0.4)]];
        let carry = vec![
            vec![(0, 0.7), (1, 0.4), (4, -0.1)],
            vec![(1, 0.3), (2, 0.9), (3, -0.2)],
            vec![(2, 0.25), (3, 0.5), (4, 0.25)],
            vec![(0, 1.0)],
            vec![(3, 1.0)],
        ];
        let start = vec![
            SVector::from([1.0, 0.0]),
            SVector::from([0.7, 0.7]),
            SVector::from([0.0, 1.0]),
            SVector::from([0.9, 0.4]),
            SVector::from([0.4, 0.9]),
        ];
        (parts, spread, carry, start)
    }

    fn forces(
        (parts, spread, carry, start): &Example,
        increment: &[SVector<f64, 2>],
    ) -> Vec<SVector<f64, 2>> {
        let positions: Vec<_> = start
            .iter()
            .zip(carry)
            .map(|(x, c)| carried_position(x, c, increment))
            .collect();
        let mut nodes = vec![SVector::zeros(); 5];
        add_pressure_forces(parts, spread, &positions, &mut nodes);
        nodes
    }

    /// The load stiffness is −λ ∂f̂/∂Δu: against central differences of the force at an
    /// arbitrary increment (the force is linear in Δu, so they agree to round-off).
    #[test]
    fn the_load_stiffness_matches_finite_differences_of_the_force() {
        let data = example();
        let increment: Vec<SVector<f64, 2>> = (0..5)
            .map(|k| SVector::from([0.03 * k as f64 - 0.05, 0.02 * (k * k) as f64 * 0.1]))
            .collect();
        let factor = 1.7;
        let mut k = [[0.0; 10]; 10];
        pressure_tangent::<2>(&data.0, &data.1, &data.2, &[factor], |i, a, j, b, v| {
            k[2 * i + a][2 * j + b] += v
        });
        let h = 1e-6;
        let (mut worst, mut scale) = (0.0f64, 0.0f64);
        for j in 0..5 {
            for b in 0..2 {
                let (mut plus, mut minus) = (increment.clone(), increment.clone());
                plus[j][b] += h;
                minus[j][b] -= h;
                let (fp, fm) = (forces(&data, &plus), forces(&data, &minus));
                for i in 0..5 {
                    for a in 0..2 {
                        let fd = -factor * (fp[i][a] - fm[i][a]) / (2.0 * h);
                        worst = worst.max((fd - k[2 * i + a][2 * j + b]).abs());
                        scale = scale.max(fd.abs());
                    }
                }
            }
        }
        assert!(scale > 0.1, "{scale}");
        assert!(worst < 1e-9 * scale, "{worst:e} against {scale:e}");
    }

    /// The resultant of a uniform pressure on an open arc is p times its chord turned a quarter
    /// (exactly, in any configuration): the quarter arc of radius 2, in its reference and in a
    /// deformed configuration.
    #[test]
    fn the_resultant_is_the_pressure_times_the_chord() {
        let arc = ArcShape {
            centre: [0.0, 0.0],
            radius: 2.0,
            from: 0.0,
            to: 90.0,
        };
        for parts in [1, 7, 64] {
            let (vertices, _) = arc.divide(parts);
            let part_list: Vec<Part> = (0..parts)
                .map(|k| Part {
                    start: k,
                    end: k + 1,
                    load_point: 0,
                    pressure: 3.0,
                    side: 1.0,
                    group: 0,
                })
                .collect();
            let spread: Vec<Vec<(usize, f64)>> =
                (0..parts).map(|k| vec![(k, 0.25), (k + 1, 0.75)]).collect();
            let reference: Vec<SVector<f64, 2>> =
                vertices.iter().map(|x| SVector::from(*x)).collect();
            // a deformation: stretched, sheared and swirled
            let deformed: Vec<SVector<f64, 2>> = reference
                .iter()
                .map(|x| {
                    SVector::from([
                        1.3 * x[0] + 0.2 * x[1] + 0.1 * x[1].sin(),
                        0.9 * x[1] + 0.05 * x[0] * x[0],
                    ])
                })
                .collect();
            for positions in [&reference, &deformed] {
                let mut nodes = vec![SVector::zeros(); parts + 1];
                add_pressure_forces(&part_list, &spread, positions, &mut nodes);
                let resultant: SVector<f64, 2> = nodes.iter().sum();
                let chord = positions[parts] - positions[0];
                let expected = SVector::from([3.0 * chord[1], -3.0 * chord[0]]);
                assert!(
                    (resultant - expected).norm() < 1e-13,
                    "{resultant} {expected}"
                );
            }
            let mut nodes = vec![SVector::zeros(); parts + 1];
            add_pressure_forces(&part_list, &spread, &reference, &mut nodes);
            let magnitude = nodes.iter().sum::<SVector<f64, 2>>().norm();
            assert!(
                (magnitude - 3.0 * 2.0 * 2f64.sqrt()).abs() < 1e-13,
                "{magnitude}"
            );
        }
    }

    #[test]
    fn an_arc_is_divided_into_equal_parts() {
        let arc = ArcShape {
            centre: [1.0, -1.0],
            radius: 0.5,
            from: 90.0,
            to: -90.0,
        };
        let (v, m) = arc.divide(4);
        assert_eq!((v.len(), m.len()), (5, 4));
        assert!((v[0][0] - 1.0).abs() < 1e-15 && (v[0][1] + 0.5).abs() < 1e-15);
        assert!((v[4][1] + 1.5).abs() < 1e-15);
        assert!((m[0][0] - (1.0 + 0.5 * 22.5f64.to_radians().sin())).abs() < 1e-15);
        assert!((arc.length() - 0.5 * std::f64::consts::PI).abs() < 1e-15);
    }
}
