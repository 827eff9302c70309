//! The scene under construction: what the script's API calls declared (each with the position
//! of its call), and `resolve`, which turns the declarations into a `SceneSpec` once the whole
//! script has run: it checks what needs the grid (dimensions, component indices), evaluates
//! region and node predicates, seeds points and selects constrained nodes.
//!
//! Resolving after the script lets declarations come in any order (`body` before `grid` is
//! fine); every error still points at the call that declared the offending item.

use std::collections::BTreeMap;

use rhai::{AST, Dynamic, Engine, FnPtr, Position};

use super::error::ScriptError;
use super::fem_seeding::{PartialCell, seed_element_points};
use super::geometry::point_in_polygon;
use super::options::{describe, number};
use super::seeding::{
    Placement, first_point_outside_grid, nearest_points, seed_boundary, seed_box,
    seed_points_placed,
};
use super::{
    AnalyticSpec, BodySpec, GridSpec, MaterialSpec, NodeConstraint, OutputSpec, PointLoadSpec,
    PointSeed, RecoverySpec, SceneSpec, SolverSpec, TractionPointSpec,
};
use crate::basis::{BasisKind, control_points_1d};
use crate::material::{Hencky, Material};

/// Largest number of grid nodes accepted (node predicates are called once per node).
pub(crate) const MAX_NODES: usize = 100_000_000;
/// Largest number of seeding candidates (grid cells times points per cell) accepted per body.
pub(crate) const MAX_SEED_CANDIDATES: usize = 100_000_000;

/// A declaration and the position of the API call that made it.
#[derive(Clone, Debug)]
pub(crate) struct Located<T> {
    pub value: T,
    pub at: Position,
}

impl<T> Located<T> {
    pub fn new(value: T, at: Position) -> Self {
        Self { value, at }
    }

    /// "at line N" for messages (empty if unknown).
    pub fn line_note(&self) -> String {
        self.at
            .line()
            .map(|line| format!(" at line {line}"))
            .unwrap_or_default()
    }
}

/// A handle on a material, returned to the script by `material(...)`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct MaterialHandle {
    pub index: usize,
    pub name: String,
}

/// Where a body is: returned to the script by `box(...)` or `polygon(...)`, or a script
/// predicate on positions.
#[derive(Clone, Debug)]
pub(crate) enum Region {
    /// Axis-aligned box, bounds included.
    Box { lower: Vec<f64>, upper: Vec<f64> },
    /// A 2D polygon (even-odd rule, see `geometry::point_in_polygon`).
    Polygon(Vec<[f64; 2]>),
    /// A script function `|x| -> bool` of the position array.
    Predicate(FnPtr),
}

impl Region {
    fn describe(&self) -> String {
        match self {
            Region::Box { lower, upper } => format!("box({lower:?}, {upper:?})"),
            Region::Polygon(vertices) => format!("polygon({vertices:?})"),
            Region::Predicate(_) => "region predicate".to_string(),
        }
    }

    /// The bounding box of a shape (`None` for a predicate).
    fn bounds(&self) -> Option<(Vec<f64>, Vec<f64>)> {
        match self {
            Region::Box { lower, upper } => Some((lower.clone(), upper.clone())),
            Region::Polygon(vertices) => Some(
                (0..2)
                    .map(|axis| {
                        vertices
                            .iter()
                            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                                (lo.min(v[axis]), hi.max(v[axis]))
                            })
                    })
                    .unzip(),
            ),
            Region::Predicate(_) => None,
        }
    }

    /// Whether a shape contains `x` (false for a predicate, which is called instead).
    fn contains(&self, x: &[f64]) -> bool {
        match self {
            Region::Box { lower, upper } => x
                .iter()
                .zip(lower.iter().zip(upper))
                .all(|(&c, (&lo, &hi))| lo <= c && c <= hi),
            Region::Polygon(vertices) => point_in_polygon([x[0], x[1]], vertices),
            Region::Predicate(_) => false,
        }
    }
}

/// Points per cell: the same along every axis, or one count per axis.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum PointsPerCell {
    Uniform(usize),
    PerAxis(Vec<usize>),
}

#[derive(Clone, Debug)]
pub(crate) struct BodyDeclaration {
    pub name: String,
    pub material: usize,
    pub region: Region,
    pub points_per_cell: PointsPerCell,
    pub placement: Placement,
}

/// `fix` (values all zero) or `displace`: components of every node the selector accepts.
#[derive(Clone, Debug)]
pub(crate) struct ConstraintDeclaration {
    /// The API function that declared it, for messages.
    pub function: &'static str,
    pub selector: FnPtr,
    /// The constrained components; empty = all of them (full fixity, `fix(|x| ..)`).
    pub components: Vec<usize>,
    /// One prescribed displacement (at load factor 1) per component.
    pub values: Vec<f64>,
}

/// How a point load's force is given to the points its selector picks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PointLoadShare {
    /// Every selected point carries the whole force (`point_load`).
    Each,
    /// The force is the total, shared in proportion to reference volume (`point_load_total`).
    Total,
}

/// `point_load` / `point_load_total`: a force on the material points whose reference position
/// the selector accepts.
#[derive(Clone, Debug)]
pub(crate) struct PointLoadDeclaration {
    pub function: &'static str,
    pub selector: FnPtr,
    pub force: Vec<f64>,
    pub share: PointLoadShare,
}

/// The load factors of the steps: given (`load_steps`, `load_factors([..])`, `load_phases`) or
/// computed by a script function of the step number (`load_factors(n, |k| ..)`).
#[derive(Clone, Debug)]
pub(crate) enum LoadSchedule {
    Factors(Vec<f64>),
    Function { steps: usize, function: FnPtr },
}

/// `traction(...)`: a traction on a flat piece of boundary given by its corners.
#[derive(Clone, Debug)]
pub(crate) struct TractionDeclaration {
    pub corners: Vec<Vec<f64>>,
    pub traction: Vec<f64>,
    pub per_cell: usize,
}

#[derive(Clone, Debug)]
pub(crate) struct ColumnDeclaration {
    pub axis: usize,
    pub height: f64,
    pub material: usize,
    pub body_force: f64,
}

/// Everything the script declared so far.
#[derive(Debug, Default)]
pub(crate) struct SceneBuilder {
    pub grid: Option<Located<GridSpec>>,
    pub materials: Vec<Located<MaterialSpec>>,
    pub bodies: Vec<Located<BodyDeclaration>>,
    pub body_force: Option<Located<Vec<f64>>>,
    pub constraints: Vec<Located<ConstraintDeclaration>>,
    pub point_loads: Vec<Located<PointLoadDeclaration>>,
    pub tractions: Vec<Located<TractionDeclaration>>,
    pub load_schedule: Option<Located<LoadSchedule>>,
    pub solver: Option<Located<SolverSpec>>,
    pub output: Option<Located<OutputSpec>>,
    pub analytic: Option<Located<ColumnDeclaration>>,
    pub recovery: Option<Located<RecoverySpec>>,
}

/// Error unless `slot` is still empty ("grid(...) was already called at line 3").
pub(crate) fn ensure_unset<T>(slot: &Option<Located<T>>, function: &str) -> Result<(), String> {
    match slot {
        Some(previous) => Err(format!(
            "{function}(...) was already called{}; call it once",
            previous.line_note()
        )),
        None => Ok(()),
    }
}

impl SceneBuilder {
    /// The finished scene. `engine` and `ast` are the ones that ran the script (predicates are
    /// script closures).
    pub fn resolve(self, name: &str, engine: &Engine, ast: &AST) -> Result<SceneSpec, ScriptError> {
        let grid = self.grid.ok_or_else(|| {
            ScriptError::unlocated(
                "the scene has no grid: call grid(#{ lower: [..], upper: [..], cells: [..], basis: \"bspline\", order: 2 }) once",
            )
        })?;
        let dim = grid.value.dim();
        let grid_note = format!(
            "the grid is {dim}-dimensional (declared{})",
            grid.line_note()
        );

        if let Some(body_force) = &self.body_force
            && body_force.value.len() != dim
        {
            return Err(ScriptError::at(
                body_force.at,
                format!(
                    "body_force(...) has {} components but {grid_note}",
                    body_force.value.len()
                ),
            ));
        }

        if self.bodies.is_empty() {
            return Err(ScriptError::unlocated(
                "the scene has no body: declare at least one with body(#{ name: .., material: .., region: .., ppc: .. })",
            ));
        }
        let bodies = self
            .bodies
            .iter()
            .map(|body| resolve_body(body, &grid, engine, ast))
            .collect::<Result<Vec<_>, _>>()?;

        let constraints = resolve_constraints(&self.constraints, &grid, engine, ast)?;
        let point_loads = resolve_point_loads(&self.point_loads, &bodies, dim, engine, ast)?;
        if let Some(solver) = &self.solver
            && solver.value.ghost_penalty > 0.0
            && grid.value.basis == BasisKind::Fem
        {
            return Err(ScriptError::at(
                solver.at,
                "solver(...): ghost_penalty stabilises nearly empty MPM cells; basis \"fem\" has a body-fitted mesh without such cells (remove ghost_penalty)",
            ));
        }
        if let Some(traction) = self.tractions.first()
            && grid.value.basis == BasisKind::Fem
        {
            return Err(ScriptError::at(
                traction.at,
                "traction(...): tractions are applied through the background grid's basis; basis \"fem\" has a body-fitted mesh instead (use point_load_total on the boundary points)",
            ));
        }
        let tractions = resolve_tractions(&self.tractions, &grid, &bodies)?;

        let load_schedule = self.load_schedule.ok_or_else(|| {
            ScriptError::unlocated(
                "the scene has no load steps: call load_steps(n), load_factors([..]), load_factors(n, |k| ..) or load_phases([..])",
            )
        })?;
        let load_factors = resolve_load_schedule(&load_schedule, engine, ast)?;

        let analytic = match &self.analytic {
            None => None,
            Some(column) => {
                if column.value.axis >= dim {
                    return Err(ScriptError::at(
                        column.at,
                        format!(
                            "analytic_column(...): axis {} does not exist, {grid_note} (axes 0..{})",
                            column.value.axis,
                            dim - 1
                        ),
                    ));
                }
                let material = &self.materials[column.value.material].value;
                Some(AnalyticSpec::Column {
                    axis: column.value.axis,
                    height: column.value.height,
                    density: material.density,
                    body_force: column.value.body_force,
                    modulus: Hencky::from_parameters(&material.parameters)
                        .map_err(|why| {
                            ScriptError::at(
                                column.at,
                                format!(
                                    "analytic_column(...): the column solution is for Hencky materials; material '{}': {why}",
                                    material.name
                                ),
                            )
                        })?
                        .constrained_modulus(),
                })
            }
        };

        Ok(SceneSpec {
            name: name.to_string(),
            grid: grid.value,
            materials: self
                .materials
                .into_iter()
                .map(|material| material.value)
                .collect(),
            bodies,
            body_force: self.body_force.map(|body_force| body_force.value),
            constraints,
            point_loads,
            tractions,
            load_factors,
            solver: self.solver.map(|solver| solver.value).unwrap_or_default(),
            output: self.output.map(|output| output.value).unwrap_or_default(),
            analytic,
            recovery: self.recovery.map(|recovery| recovery.value),
        })
    }
}

/// Grid node (control point) positions, global index with axis 0 fastest. The end nodes of
/// every axis are set exactly to the grid bounds, so predicates like `x[0] == 0.0` or
/// `x[1] == height` are reliable there.
pub(crate) fn node_positions(grid: &GridSpec) -> Vec<Vec<f64>> {
    let order = grid.basis.order();
    let axes: Vec<Vec<f64>> = (0..grid.dim())
        .map(|axis| {
            let (lower, upper) = (grid.lower[axis], grid.upper[axis]);
            let mut points = control_points_1d(lower, upper, grid.cells[axis], order);
            if let Some(first) = points.first_mut() {
                *first = lower;
            }
            if let Some(last) = points.last_mut() {
                *last = upper;
            }
            points
        })
        .collect();
    let count: usize = axes.iter().map(Vec::len).product();
    (0..count)
        .map(|node| {
            let mut rest = node;
            axes.iter()
                .map(|points| {
                    let coordinate = points[rest % points.len()];
                    rest /= points.len();
                    coordinate
                })
                .collect()
        })
        .collect()
}

/// Number of nodes of the grid, if it is at most `MAX_NODES`.
pub(crate) fn checked_node_count(grid: &GridSpec) -> Option<usize> {
    let order = grid.basis.order();
    grid.cells
        .iter()
        .try_fold(1usize, |count, &cells| {
            count.checked_mul(cells.checked_add(order)?)
        })
        .filter(|&count| count <= MAX_NODES)
}

/// The load factors of a schedule; a function is called for k = 1..=steps and must return a
/// finite number each time. k is passed as a float (1.0, 2.0, ...) so that `k / n` divides as
/// the user means even when n is an integer (Rhai divides integers by integers exactly).
fn resolve_load_schedule(
    schedule: &Located<LoadSchedule>,
    engine: &Engine,
    ast: &AST,
) -> Result<Vec<f64>, ScriptError> {
    match &schedule.value {
        LoadSchedule::Factors(factors) => Ok(factors.clone()),
        LoadSchedule::Function { steps, function } => {
            let context = format!(
                "load factor function of load_factors(...){}",
                schedule.line_note()
            );
            (1..=*steps)
                .map(|step| {
                    let value = function
                        .call::<Dynamic>(engine, ast, (step as rhai::FLOAT,))
                        .map_err(|error| {
                            let mut error = ScriptError::from_eval(error).with_context(&context);
                            if error.position.is_none() {
                                error.position = schedule.at;
                            }
                            error
                        })?;
                    number(&value, &format!("the {context}")).map_err(|message| {
                        ScriptError::at(schedule.at, format!("{message} for step k = {step}"))
                    })
                })
                .collect()
        }
    }
}

/// Calls a script predicate on a position; it must return a boolean.
fn call_predicate(
    predicate: &FnPtr,
    position: &[f64],
    engine: &Engine,
    ast: &AST,
    declared_at: Position,
    context: &str,
) -> Result<bool, ScriptError> {
    let argument: rhai::Array = position.iter().map(|&x| Dynamic::from_float(x)).collect();
    let result = predicate
        .call::<Dynamic>(engine, ast, (argument,))
        .map_err(|error| {
            let mut error = ScriptError::from_eval(error).with_context(context);
            if error.position.is_none() {
                error.position = declared_at;
            }
            error
        })?;
    result.as_bool().map_err(|_| {
        ScriptError::at(
            declared_at,
            format!(
                "the {context} must return true or false, got {} for x = {position:?}",
                describe(&result)
            ),
        )
    })
}

fn resolve_body(
    body: &Located<BodyDeclaration>,
    grid: &Located<GridSpec>,
    engine: &Engine,
    ast: &AST,
) -> Result<BodySpec, ScriptError> {
    let declaration = &body.value;
    let dim = grid.value.dim();
    let fail = |message: String| {
        Err(ScriptError::at(
            body.at,
            format!("body '{}': {message}", declaration.name),
        ))
    };
    let points_per_cell = match &declaration.points_per_cell {
        PointsPerCell::Uniform(count) => vec![*count; dim],
        PointsPerCell::PerAxis(counts) if counts.len() == dim => counts.clone(),
        PointsPerCell::PerAxis(counts) => {
            return fail(format!(
                "ppc has {} entries but the grid is {dim}-dimensional",
                counts.len()
            ));
        }
    };
    let candidates = grid
        .value
        .cells
        .iter()
        .zip(&points_per_cell)
        .try_fold(1usize, |count, (&cells, &ppc)| {
            count.checked_mul(cells.checked_mul(ppc)?)
        });
    if candidates.is_none_or(|count| count > MAX_SEED_CANDIDATES) {
        return fail(format!(
            "too many seeding positions (grid cells x ppc^D exceeds {MAX_SEED_CANDIDATES})"
        ));
    }
    let grid_bounds = format!("[{:?} .. {:?}]", grid.value.lower, grid.value.upper);
    let points = match &declaration.region {
        shape @ (Region::Box { .. } | Region::Polygon(_)) => {
            let (lower, upper) = shape.bounds().unwrap_or_default();
            if lower.len() != dim {
                return fail(format!(
                    "{} has {} coordinates but the grid is {dim}-dimensional",
                    shape.describe(),
                    lower.len()
                ));
            }
            let outside = (0..dim).any(|axis| {
                let tolerance = 1e-12 * (grid.value.upper[axis] - grid.value.lower[axis]).abs();
                lower[axis] < grid.value.lower[axis] - tolerance
                    || upper[axis] > grid.value.upper[axis] + tolerance
            });
            if outside {
                return fail(format!(
                    "region {} is not inside the grid {grid_bounds}; material points must lie in the grid",
                    shape.describe()
                ));
            }
            match shape {
                Region::Polygon(_) => {
                    let inside = |x: &[f64]| Ok::<_, ScriptError>(shape.contains(x));
                    seed_body(&grid.value, &points_per_cell, declaration.placement, inside)?
                }
                _ if grid.value.basis == BasisKind::Fem => {
                    let inside = |x: &[f64]| Ok::<_, ScriptError>(shape.contains(x));
                    seed_element_points(&grid.value, &points_per_cell, inside)?
                }
                _ => Ok(seed_box(
                    &grid.value,
                    &points_per_cell,
                    declaration.placement,
                    &lower,
                    &upper,
                )),
            }
        }
        Region::Predicate(predicate) => {
            let context = format!(
                "region predicate of body '{}' declared{}",
                declaration.name,
                body.line_note()
            );
            let inside = |x: &[f64]| call_predicate(predicate, x, engine, ast, body.at, &context);
            if let Some(position) = first_point_outside_grid(&grid.value, &points_per_cell, inside)?
            {
                return fail(format!(
                    "the region contains x = {position:?}, outside the grid {grid_bounds}; material points must lie in the grid (bound the region)"
                ));
            }
            seed_body(&grid.value, &points_per_cell, declaration.placement, inside)?
        }
    };
    let points = match points {
        Ok(points) => points,
        Err(partial) => return fail(partial.message()),
    };
    if points.is_empty() {
        return fail(format!(
            "no material points: the {} contains none of the seeding positions (ppc = {points_per_cell:?} per cell) of the grid {grid_bounds}",
            declaration.region.describe()
        ));
    }
    Ok(BodySpec {
        name: declaration.name.clone(),
        material: declaration.material,
        points,
    })
}

/// The body's points: the seeding lattice for MPM, the integration points of the covered cells
/// for FEM (`Err` for a cell the region covers only partly).
fn seed_body(
    grid: &GridSpec,
    points_per_cell: &[usize],
    placement: Placement,
    inside: impl FnMut(&[f64]) -> Result<bool, ScriptError>,
) -> Result<Result<Vec<PointSeed>, PartialCell>, ScriptError> {
    if grid.basis == BasisKind::Fem {
        seed_element_points(grid, points_per_cell, inside)
    } else {
        seed_points_placed(grid, points_per_cell, placement, inside).map(Ok)
    }
}

fn resolve_constraints(
    declarations: &[Located<ConstraintDeclaration>],
    grid: &Located<GridSpec>,
    engine: &Engine,
    ast: &AST,
) -> Result<Vec<NodeConstraint>, ScriptError> {
    if declarations.is_empty() {
        return Ok(Vec::new());
    }
    let dim = grid.value.dim();
    if checked_node_count(&grid.value).is_none() {
        return Err(ScriptError::at(
            grid.at,
            format!("grid(...): the grid has more than {MAX_NODES} nodes"),
        ));
    }
    let nodes = node_positions(&grid.value);
    // (node, component) -> (value, line of the declaring call)
    let mut prescribed: BTreeMap<(usize, usize), (f64, Position)> = BTreeMap::new();
    for declaration in declarations {
        let mut constraint = declaration.value.clone();
        if constraint.components.is_empty() {
            constraint.components = (0..dim).collect();
            constraint.values = vec![0.0; dim];
        }
        let function = constraint.function;
        if let Some(&component) = constraint.components.iter().find(|&&c| c >= dim) {
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): component {component} does not exist, the grid is {dim}-dimensional (components 0..{})",
                    dim - 1
                ),
            ));
        }
        let context = format!(
            "node predicate of {function}(...){}",
            declaration.line_note()
        );
        let mut selected = 0usize;
        for (node, position) in nodes.iter().enumerate() {
            if !call_predicate(
                &constraint.selector,
                position,
                engine,
                ast,
                declaration.at,
                &context,
            )? {
                continue;
            }
            selected += 1;
            for (&component, &value) in constraint.components.iter().zip(&constraint.values) {
                if let Some(&(previous, previous_at)) = prescribed.get(&(node, component))
                    && previous != value
                {
                    let previous_line = previous_at
                        .line()
                        .map(|line| format!(" at line {line}"))
                        .unwrap_or_default();
                    return Err(ScriptError::at(
                        declaration.at,
                        format!(
                            "{function}(...): component {component} of the node at {position:?} is already prescribed to {previous}{previous_line}, not {value}"
                        ),
                    ));
                }
                prescribed.insert((node, component), (value, declaration.at));
            }
        }
        if selected == 0 {
            let ranges: Vec<String> = (0..dim)
                .map(|axis| {
                    format!(
                        "x[{axis}] in [{}, {}]",
                        grid.value.lower[axis], grid.value.upper[axis]
                    )
                })
                .collect();
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): the predicate selects no grid node (nodes have {}; compare with a tolerance if needed)",
                    ranges.join(", ")
                ),
            ));
        }
    }
    Ok(prescribed
        .into_iter()
        .map(|((node, component), (value, _))| NodeConstraint {
            node,
            component,
            value,
        })
        .collect())
}

/// Point loads on the seeded points: each declaration's selector is called with the reference
/// position of every point (body after body, seeding order, which is the global point index);
/// several loads on one point add up.
fn resolve_point_loads(
    declarations: &[Located<PointLoadDeclaration>],
    bodies: &[BodySpec],
    dim: usize,
    engine: &Engine,
    ast: &AST,
) -> Result<Vec<PointLoadSpec>, ScriptError> {
    let mut forces: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for declaration in declarations {
        let load = &declaration.value;
        let function = load.function;
        if load.force.len() != dim {
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): the force has {} components but the grid is {dim}-dimensional",
                    load.force.len()
                ),
            ));
        }
        let context = format!(
            "point selector of {function}(...){}",
            declaration.line_note()
        );
        let mut selected = Vec::new();
        let points = bodies.iter().flat_map(|body| &body.points).enumerate();
        for (index, point) in points {
            if call_predicate(
                &load.selector,
                &point.position,
                engine,
                ast,
                declaration.at,
                &context,
            )? {
                selected.push((index, point.volume));
            }
        }
        if selected.is_empty() {
            return Err(ScriptError::at(
                declaration.at,
                format!(
                    "{function}(...): the predicate selects no material point (it is called with the reference position of every point; points sit inside their cells, not on cell faces)"
                ),
            ));
        }
        let total_volume: f64 = selected.iter().map(|(_, volume)| volume).sum();
        for (index, volume) in selected {
            let scale = match load.share {
                PointLoadShare::Each => 1.0,
                PointLoadShare::Total => volume / total_volume,
            };
            let force = forces.entry(index).or_insert_with(|| vec![0.0; dim]);
            for (sum, component) in force.iter_mut().zip(&load.force) {
                *sum += scale * component;
            }
        }
    }
    Ok(forces
        .into_iter()
        .map(|(point, force)| PointLoadSpec { point, force })
        .collect())
}

/// Traction points of every `traction(...)`: the corners must match the grid's dimension and
/// lie in the grid (so every point does).
fn resolve_tractions(
    declarations: &[Located<TractionDeclaration>],
    grid: &Located<GridSpec>,
    bodies: &[BodySpec],
) -> Result<Vec<TractionPointSpec>, ScriptError> {
    let dim = grid.value.dim();
    let material_points: Vec<&[f64]> = bodies
        .iter()
        .flat_map(|body| &body.points)
        .map(|point| point.position.as_slice())
        .collect();
    let mut points = Vec::new();
    for declaration in declarations {
        let traction = &declaration.value;
        let fail = |message: String| {
            Err(ScriptError::at(
                declaration.at,
                format!("traction(...): {message}"),
            ))
        };
        let shape = [
            "the end point of the bar",
            "the two ends of a segment",
            "three corners of a parallelogram (corner, corner + edge 1, corner + edge 2)",
        ];
        if traction.corners.len() != dim {
            return fail(format!(
                "option 'on' has {} points but the grid is {dim}-dimensional: give {dim}, {}",
                traction.corners.len(),
                shape[dim - 1]
            ));
        }
        if let Some(corner) = traction.corners.iter().find(|corner| corner.len() != dim) {
            return fail(format!(
                "the point {corner:?} of option 'on' has {} coordinates, the grid is {dim}-dimensional",
                corner.len()
            ));
        }
        if traction.traction.len() != dim {
            return fail(format!(
                "option 'traction' has {} components but the grid is {dim}-dimensional",
                traction.traction.len()
            ));
        }
        let (lower, upper) = (&grid.value.lower, &grid.value.upper);
        if let Some(corner) = traction.corners.iter().find(|corner| {
            (0..dim).any(|axis| corner[axis] < lower[axis] || corner[axis] > upper[axis])
        }) {
            return fail(format!(
                "the point {corner:?} is outside the grid [{lower:?} .. {upper:?}]"
            ));
        }
        if dim == 3 {
            // the fourth corner (corner 1 + corner 2 − corner 0) must be in the grid too
            let c = &traction.corners;
            let fourth: Vec<f64> = (0..3).map(|a| c[1][a] + c[2][a] - c[0][a]).collect();
            if (0..dim).any(|axis| fourth[axis] < lower[axis] || fourth[axis] > upper[axis]) {
                return fail(format!(
                    "the parallelogram's fourth corner {fourth:?} is outside the grid [{lower:?} .. {upper:?}]"
                ));
            }
        }
        let seeded = match seed_boundary(
            &grid.value,
            &traction.corners,
            traction.per_cell,
            MAX_SEED_CANDIDATES,
        ) {
            Ok(seeded) => seeded,
            Err(count) => {
                return fail(format!(
                    "{count} traction points exceed the limit of {MAX_SEED_CANDIDATES}; lower per_cell"
                ));
            }
        };
        if seeded.iter().all(|(_, area)| *area == 0.0) {
            return fail(
                "the boundary piece has zero length or area (repeated or collinear points)"
                    .to_string(),
            );
        }
        let positions: Vec<Vec<f64>> = seeded
            .iter()
            .map(|(position, _)| position.clone())
            .collect();
        let hosts = nearest_points(&grid.value, &material_points, &positions);
        for ((position, area), host) in seeded.into_iter().zip(hosts) {
            points.push(TractionPointSpec {
                position,
                area,
                traction: traction.traction.clone(),
                // bodies are resolved first and have points
                host: host.unwrap_or_default(),
            });
        }
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_positions_axis_zero_fastest_with_exact_ends() {
        let grid = GridSpec {
            lower: vec![0.0, 0.0],
            upper: vec![0.1, 1.0],
            cells: vec![1, 3],
            basis: BasisKind::BSpline { order: 3 },
        };
        let nodes = node_positions(&grid);
        assert_eq!(nodes.len(), 4 * 6);
        assert_eq!(nodes[0], [0.0, 0.0]);
        assert_eq!(nodes[3], [0.1, 0.0]);
        assert_eq!(nodes[4][1], nodes[5][1]);
        assert_eq!(nodes[23], [0.1, 1.0]);
        assert_eq!(checked_node_count(&grid), Some(24));
    }
}
