//! The scene under construction: what the script's API calls declared (each with the position
//! of its call), and its resolution into a `SceneSpec` once the whole script has run: the core
//! parts here (grid, materials, bodies, load schedule, solver, output, analytic solution), then
//! every module's part through a [`Resolver`] (its declarations, predicate calls, the grid and
//! the bodies resolved so far).
//!
//! Resolving after the script lets declarations come in any order (`body` before `grid` is
//! fine); every error still points at the call that declared the offending item.

use std::any::{Any, TypeId};
use std::collections::BTreeMap;
use std::sync::Arc;

use rhai::{AST, Dynamic, Engine, FnPtr, Position};

use super::error::ScriptError;
use super::geometry::point_in_polygon;
use super::limits::SceneLimits;
use super::options::{Options, describe, number};
use super::seeding::{Placement, first_point_outside_grid, seed_box, seed_points_placed};
use super::words::{Seeder, Words};
use super::{AnalyticSpec, BodySpec, GridSpec, MaterialSpec, OutputSpec, SceneSpec, SolverSpec};
use crate::material::{Hencky, Material};

/// Largest number of grid nodes accepted (node predicates are called once per node).
pub const MAX_NODES: usize = 100_000_000;
/// Largest number of seeding candidates (grid cells times points per cell) accepted per body.
pub const MAX_SEED_CANDIDATES: usize = 100_000_000;

/// A declaration and the position of the API call that made it.
#[derive(Clone, Debug)]
pub struct Located<T> {
    pub value: T,
    pub at: Position,
    /// The stage the declaration belongs to (`stage(...)`: 0 before the second stage call;
    /// stamped by [`SceneBuilder::declare`] and for map calls' options).
    pub stage: usize,
}

impl<T> Located<T> {
    pub fn new(value: T, at: Position) -> Self {
        Self {
            value,
            at,
            stage: 0,
        }
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
pub struct MaterialHandle {
    pub index: usize,
    pub name: String,
}

/// Where a body is: returned to the script by `box(...)` or `polygon(...)`, or a script
/// predicate on positions.
#[derive(Clone, Debug)]
pub enum Region {
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
pub enum PointsPerCell {
    Uniform(usize),
    PerAxis(Vec<usize>),
}

#[derive(Clone, Debug)]
pub struct BodyDeclaration {
    pub name: String,
    pub material: usize,
    pub region: Region,
    pub points_per_cell: PointsPerCell,
    pub placement: Placement,
}

/// The load factors of the steps: given (`load_steps`, `load_factors([..])`, `load_phases`) or
/// computed by a script function of the step number (`load_factors(n, |k| ..)`).
#[derive(Clone, Debug)]
pub enum LoadSchedule {
    Factors(Vec<f64>),
    Function { steps: usize, function: FnPtr },
}

#[derive(Clone, Debug)]
pub struct ColumnDeclaration {
    pub axis: usize,
    pub height: f64,
    pub material: usize,
    pub body_force: f64,
}

/// `grid(...)`: the grid and, for a basis with a body-fitted mesh, how bodies are seeded.
#[derive(Clone)]
pub struct GridDeclaration {
    pub spec: GridSpec,
    pub seeder: Option<Seeder>,
}

/// Everything the script declared so far.
pub struct SceneBuilder {
    /// The basis words, material models and point fields calls read.
    pub words: Arc<Words>,
    pub grid: Option<Located<GridDeclaration>>,
    pub materials: Vec<Located<MaterialSpec>>,
    pub bodies: Vec<Located<BodyDeclaration>>,
    pub load_schedule: Option<Located<LoadSchedule>>,
    pub solver: Option<Located<SolverSpec>>,
    pub output: Option<Located<OutputSpec>>,
    pub analytic: Option<Located<ColumnDeclaration>>,
    /// The `stage(...)` calls, in order (`scene::stages`).
    pub stages: Vec<Located<super::stages::StageDeclaration>>,
    /// Every call the script made, with the stage it belongs to (checked against the calls
    /// a staged scene can take, `scene::stages`).
    pub calls: Vec<(&'static str, Located<()>)>,
    /// The options of every map call, in call order (modules read the options they added).
    pub call_options: Vec<(&'static str, Located<Options>)>,
    /// Limits on the basis order, points and memory (checked as the scene is declared and
    /// resolved, before anything big is allocated).
    pub limits: SceneLimits,
    /// The modules' declarations, by type.
    store: BTreeMap<TypeId, Box<dyn Any + Send + Sync>>,
}

impl SceneBuilder {
    pub fn new(words: Arc<Words>) -> Self {
        Self {
            words,
            grid: None,
            materials: Vec::new(),
            bodies: Vec::new(),
            load_schedule: None,
            solver: None,
            output: None,
            analytic: None,
            stages: Vec::new(),
            calls: Vec::new(),
            call_options: Vec::new(),
            limits: SceneLimits::default(),
            store: BTreeMap::new(),
        }
    }

    /// Keeps a module's declaration (see [`Resolver::declarations`]).
    #[allow(
        clippy::expect_used,
        reason = "the entry of TypeId::of::<T>() holds a Vec<Located<T>>"
    )]
    pub fn declare<T: Send + Sync + 'static>(&mut self, mut declaration: Located<T>) {
        declaration.stage = self.stage();
        self.store
            .entry(TypeId::of::<T>())
            .or_insert_with(|| Box::new(Vec::<Located<T>>::new()))
            .downcast_mut::<Vec<Located<T>>>()
            .expect("the store is keyed by type")
            .push(declaration);
    }

    /// The stage declarations belong to now: the index of the last `stage(...)` call (0 before
    /// any).
    pub fn stage(&self) -> usize {
        self.stages.len().saturating_sub(1)
    }

    /// The declarations of type `T` so far.
    pub fn declared<T: Send + Sync + 'static>(&self) -> &[Located<T>] {
        self.store
            .get(&TypeId::of::<T>())
            .and_then(|list| list.downcast_ref::<Vec<Located<T>>>())
            .map_or(&[], Vec::as_slice)
    }
}

/// Error unless `slot` is still empty ("grid(...) was already called at line 3").
pub fn ensure_unset<T>(slot: &Option<Located<T>>, function: &str) -> Result<(), String> {
    match slot {
        Some(previous) => Err(format!(
            "{function}(...) was already called{}; call it once",
            previous.line_note()
        )),
        None => Ok(()),
    }
}

/// What a module sees when it resolves its part of the scene.
pub struct Resolver<'a> {
    /// The scene resolved so far (grid, materials, bodies, load factors, core options, and the
    /// parts of the modules resolved before).
    pub spec: &'a mut SceneSpec,
    builder: &'a SceneBuilder,
    engine: &'a Engine,
    ast: &'a AST,
    grid_at: Position,
}

impl Resolver<'_> {
    /// The module's declarations of type `T`, in call order.
    pub fn declarations<T: Send + Sync + 'static>(&self) -> &[Located<T>] {
        self.builder.declared::<T>()
    }

    /// The options of the last call of `name` (e.g. `solver`), if it was called.
    pub fn call_options(&self, name: &str) -> Option<&Located<Options>> {
        self.builder
            .call_options
            .iter()
            .rev()
            .find(|(call, _)| *call == name)
            .map(|(_, options)| options)
    }

    /// The options of every call of `name` (e.g. each `body`), in call order.
    pub fn every_call_options<'s>(
        &'s self,
        name: &'s str,
    ) -> impl Iterator<Item = &'s Located<Options>> + 's {
        self.builder
            .call_options
            .iter()
            .filter(move |(call, _)| *call == name)
            .map(|(_, options)| options)
    }

    /// "the grid is 2-dimensional (declared at line 3)".
    pub fn grid_note(&self) -> String {
        let line = self
            .grid_at
            .line()
            .map(|line| format!(" at line {line}"))
            .unwrap_or_default();
        format!(
            "the grid is {}-dimensional (declared{line})",
            self.spec.dim()
        )
    }

    /// Calls a script predicate on a position (`context` names it in messages).
    pub fn call_predicate(
        &self,
        predicate: &FnPtr,
        position: &[f64],
        declared_at: Position,
        context: &str,
    ) -> Result<bool, ScriptError> {
        call_predicate(
            predicate,
            position,
            self.engine,
            self.ast,
            declared_at,
            context,
        )
    }

    /// Every grid node's position, in node order, or an error at the grid's declaration when
    /// the grid has too many nodes to select from.
    pub fn node_positions(&self) -> Result<Vec<Vec<f64>>, ScriptError> {
        let grid = &self.spec.grid;
        if grid.node_count(MAX_NODES).is_none() {
            return Err(ScriptError::at(
                self.grid_at,
                format!("grid(...): the grid has more than {MAX_NODES} nodes"),
            ));
        }
        grid.node_positions()
            .map_err(|why| ScriptError::at(self.grid_at, format!("grid(...): {why}")))
    }
}

impl SceneBuilder {
    /// The finished scene. `engine` and `ast` are the ones that ran the script (predicates are
    /// script closures); `modules` resolve their parts after the core.
    pub fn resolve(
        self,
        name: &str,
        engine: &Engine,
        ast: &AST,
        modules: &[&dyn super::SceneModule],
    ) -> Result<SceneSpec, ScriptError> {
        let grid = self.grid.clone().ok_or_else(|| {
            ScriptError::unlocated(
                "the scene has no grid: call grid(#{ lower: [..], upper: [..], cells: [..], basis: \"bspline\", order: 2 }) once",
            )
        })?;
        let dim = grid.value.spec.dim();
        let grid_note = format!(
            "the grid is {dim}-dimensional (declared{})",
            grid.line_note()
        );
        if self.bodies.is_empty() {
            return Err(ScriptError::unlocated(
                "the scene has no body: declare at least one with body(#{ name: .., material: .., region: .., ppc: .. })",
            ));
        }
        let bodies = self
            .bodies
            .iter()
            .map(|body| resolve_body(body, &grid, engine, ast, &self.limits))
            .collect::<Result<Vec<_>, _>>()?;
        let points: usize = bodies.iter().map(|body| body.points.len()).sum();
        let spec_grid = &grid.value.spec;
        let nodes = spec_grid.node_count(usize::MAX).unwrap_or(usize::MAX);
        self.limits
            .check_memory(dim, spec_grid.basis.order(), points, nodes)
            .map_err(|why| ScriptError::at(grid.at, why))?;
        let stages = super::stages::resolve_stages(&self)?;
        let (load_factors, schedule_note) = match &stages {
            Some((stages, factors)) => (factors.clone(), format!(" of {} stages", stages.0.len())),
            None => {
                let load_schedule = self.load_schedule.as_ref().ok_or_else(|| {
                    ScriptError::unlocated(
                        "the scene has no load steps: call load_steps(n), load_factors([..]), load_factors(n, |k| ..), load_phases([..]) or stage(#{ name: .., steps: n })",
                    )
                })?;
                (
                    resolve_load_schedule(load_schedule, engine, ast)?,
                    load_schedule.line_note(),
                )
            }
        };
        if let Some(output) = &self.output
            && let Some(beyond) = output
                .value
                .steps
                .iter()
                .flatten()
                .find(|&&step| step > load_factors.len())
        {
            return Err(ScriptError::at(
                output.at,
                format!(
                    "output(...): step {beyond} is beyond the last load step {} (the schedule{} has {} steps); steps are 1..={}, and the last step is always written",
                    load_factors.len(),
                    schedule_note,
                    load_factors.len(),
                    load_factors.len()
                ),
            ));
        }
        let analytic = match &self.analytic {
            None => None,
            Some(column) => Some(resolve_column(column, &self.materials, dim, &grid_note)?),
        };
        let mut spec = SceneSpec {
            name: name.to_string(),
            grid: grid.value.spec.clone(),
            materials: self.materials.iter().map(|m| m.value.clone()).collect(),
            bodies,
            load_factors,
            solver: self
                .solver
                .as_ref()
                .map(|solver| solver.value.clone())
                .unwrap_or_default(),
            output: self
                .output
                .as_ref()
                .map(|output| output.value.clone())
                .unwrap_or_default(),
            analytic,
            parts: Default::default(),
        };
        if let Some((stages, _)) = stages {
            spec.set_part(stages);
        }
        let mut resolver = Resolver {
            spec: &mut spec,
            builder: &self,
            engine,
            ast,
            grid_at: grid.at,
        };
        for module in modules {
            module.resolve(&mut resolver)?;
        }
        Ok(spec)
    }
}

/// The self-weight column of `analytic_column(...)`, for a Hencky material.
fn resolve_column(
    column: &Located<ColumnDeclaration>,
    materials: &[Located<MaterialSpec>],
    dim: usize,
    grid_note: &str,
) -> Result<AnalyticSpec, ScriptError> {
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
    let material = &materials[column.value.material].value;
    let hencky = Hencky::from_parameters(&material.parameters).map_err(|why| {
        ScriptError::at(
            column.at,
            format!(
                "analytic_column(...): the column solution is for Hencky materials; material '{}': {why}",
                material.name
            ),
        )
    })?;
    Ok(AnalyticSpec::Column {
        axis: column.value.axis,
        height: column.value.height,
        density: material.density,
        body_force: column.value.body_force,
        modulus: hencky.constrained_modulus(),
    })
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
pub fn call_predicate(
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
    grid: &Located<GridDeclaration>,
    engine: &Engine,
    ast: &AST,
    limits: &SceneLimits,
) -> Result<BodySpec, ScriptError> {
    let declaration = &body.value;
    let seeder = grid.value.seeder;
    let grid = Located::new(grid.value.spec.clone(), grid.at);
    let dim = grid.value.dim();
    let fail = |message: String| {
        Err(ScriptError::at(
            body.at,
            format!("body '{}': {message}", declaration.name),
        ))
    };
    let points_per_cell = match points_per_axis(&declaration.points_per_cell, &grid.value, limits) {
        Ok(counts) => counts,
        Err(why) => return fail(why),
    };
    let grid_bounds = format!("[{:?} .. {:?}]", grid.value.lower, grid.value.upper);
    let seed = |inside: &mut dyn FnMut(&[f64]) -> Result<bool, ScriptError>| {
        seed_body(
            &grid.value,
            seeder,
            &points_per_cell,
            declaration.placement,
            inside,
        )
    };
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
                // a box is seeded exactly on the lattice; a polygon, or a box for a basis with
                // its own seeding, through the region's predicate
                Region::Box { .. } if seeder.is_none() => Ok(seed_box(
                    &grid.value,
                    &points_per_cell,
                    declaration.placement,
                    &lower,
                    &upper,
                )),
                _ => seed(&mut |x: &[f64]| Ok(shape.contains(x)))?,
            }
        }
        Region::Predicate(predicate) => {
            let context = format!(
                "region predicate of body '{}' declared{}",
                declaration.name,
                body.line_note()
            );
            let mut inside =
                |x: &[f64]| call_predicate(predicate, x, engine, ast, body.at, &context);
            if let Some(position) =
                first_point_outside_grid(&grid.value, &points_per_cell, &mut inside)?
            {
                return fail(format!(
                    "the region contains x = {position:?}, outside the grid {grid_bounds}; material points must lie in the grid (bound the region)"
                ));
            }
            seed(&mut inside)?
        }
    };
    let points = match points {
        Ok(points) => points,
        Err(why) => return fail(why),
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

/// Points per cell along every axis of `grid`, checked: one count per axis, and not more
/// seeding positions than `MAX_SEED_CANDIDATES`.
fn points_per_axis(
    points_per_cell: &PointsPerCell,
    grid: &GridSpec,
    limits: &SceneLimits,
) -> Result<Vec<usize>, String> {
    let dim = grid.dim();
    let counts = match points_per_cell {
        PointsPerCell::Uniform(count) => vec![*count; dim],
        PointsPerCell::PerAxis(counts) if counts.len() == dim => counts.clone(),
        PointsPerCell::PerAxis(counts) => {
            return Err(format!(
                "ppc has {} entries but the grid is {dim}-dimensional",
                counts.len()
            ));
        }
    };
    let candidates = grid
        .cells
        .iter()
        .zip(&counts)
        .try_fold(1usize, |count, (&cells, &ppc)| {
            count.checked_mul(cells.checked_mul(ppc)?)
        });
    match candidates {
        Some(count) if count <= MAX_SEED_CANDIDATES => limits.check_points(count)?,
        _ => {
            return Err(format!(
                "too many seeding positions (grid cells x ppc^D exceeds {MAX_SEED_CANDIDATES})"
            ));
        }
    }
    Ok(counts)
}

/// The body's points: the seeding lattice, or the basis's own seeding (the integration points
/// of a body-fitted mesh: `Err` with the reason when the region does not fit it).
fn seed_body(
    grid: &GridSpec,
    seeder: Option<Seeder>,
    points_per_cell: &[usize],
    placement: Placement,
    inside: &mut dyn FnMut(&[f64]) -> Result<bool, ScriptError>,
) -> Result<Result<Vec<super::PointSeed>, String>, ScriptError> {
    match seeder {
        Some(seed) => seed(grid, points_per_cell, inside),
        None => seed_points_placed(grid, points_per_cell, placement, inside).map(Ok),
    }
}
