//! The Rhai front end: runs a scene script with the scene API registered and returns the
//! resolved `SceneSpec`.
//!
//! # Scene API (brief reference; the full one is `docs/scene-api.md`)
//!
//! Numbers may be written as integers or floats everywhere (`E: 1000000` and `E: 1e6` are the
//! same); counts must be whole numbers. Option maps accept only the keys listed (a misspelt key
//! is an error naming the allowed ones). Declarations can come in any order; each error points
//! at the line of the call that caused it.
//!
//! | call | meaning |
//! |------|---------|
//! | `grid(#{ lower: [..], upper: [..], cells: [..], basis: "linear" \| "bspline" \| "gimp" \| "cpdi" \| "fem", order: q, gimp: "stretched" \| "fixed", integration: "points" \| "domain" })` | background grid; the dimension (1, 2, 3) is the array length. `basis`: `"linear"` standard MPM (hat functions), `"bspline"` B-splines of `order` q >= 1 (required), `"gimp"` GIMP (hats averaged over the point's box domain), `"cpdi"` CPDI1 (hats averaged from the corners of the point's domain carried by F), `"fem"` linear finite elements on the body-fitted mesh of grid cells (see `fem`). `gimp` (GIMP only, default `"stretched"`): `"stretched"` domain half-lengths follow the diagonal of F (cpGIMP), `"fixed"` domains keep their initial size (uGIMP). `integration` (B-splines only, default `"points"`): `"points"` evaluates the basis at the material points, `"domain"` averages it over each point's box domain, stretched like cpGIMP's (`basis::averaged`). `order` is ignored except for B-splines. A point's domain is the box of its seeding share (`h / ppc` per axis); GIMP clips domains to the grid, CPDI stops with an error naming the point when a domain corner leaves it. Call once. |
//! | `material(#{ name: "..", E: .., nu: .., density: .. })` | linear-elastic Hencky material (E > 0, -1 < nu < 0.5, density > 0); returns a handle |
//! | `box([lo..], [hi..])` | an axis-aligned box region (bounds included) |
//! | `polygon([[x, y], ..])` | a 2D polygon region (at least 3 vertices, any orientation, even-odd rule) |
//! | `body(#{ name: "..", material: m, region: box(..), polygon(..) or \|x\| pred, ppc: n or [n0, n1, ..], placement: "uniform" \| "gauss" })` | material points: `ppc` per cell per direction at cell-local `(i + 1/2) / ppc`, kept where the region holds; volume = cell volume / points per cell. With `placement: "gauss"` (optional) the points sit at the Gauss–Legendre points of each cell with volumes from the Gauss weights. The region must lie inside the grid. With `basis: "fem"` the region must be made of whole grid cells (the elements) and `ppc` is the number of Gauss points per direction. |
//! | `body_force([..])` | body force per unit mass at load factor 1 (one entry per axis) |
//! | `fix(\|x\| pred, [components])` | fix the listed displacement components (0-based axes) of every grid node whose position satisfies `pred` (a roller: one component) |
//! | `fix(\|x\| pred)` | full fixity: every component |
//! | `displace(\|x\| pred, [components], [values])` | prescribe displacements (values at load factor 1, ramped with the load factor) |
//! | `point_load(\|x\| pred, [force])` | a force (at load factor 1) on every material point whose reference position satisfies `pred` |
//! | `point_load_total(\|x\| pred, [force])` | a total force shared by the selected points in proportion to their volume |
//! | `traction(#{ on: [corners..], traction: [h..], per_cell: n })` | surface traction h (force per unit reference area at load factor 1) on a flat piece of boundary: 1D `on: [[x]]`, 2D a segment `on: [[x0, y0], [x1, y1]]`, 3D a parallelogram `on: [c0, c1, c2]` (edges c1 − c0, c2 − c0); `per_cell` (default 2) traction points per cell crossed |
//! | `load_steps(n)` / `load_factors([..])` | load schedule: factors k/n, k = 1..n, or an explicit list |
//! | `load_factors(n, \|k\| ..)` | n steps whose factors a function of the step number k = 1..n gives (k is a float, so `k / n` is not an integer division) |
//! | `load_phases([#{ to: λ, steps: n }, ..])` | phases from λ = 0: each goes linearly to `to` in `steps` equal steps (loading, holding: same `to`, unloading) |
//! | `solver(#{ tolerance: .., max_iterations: .., max_step_cuts: .., ghost_penalty: .. })` | Newton controls (optional; defaults 1e-9, 30, 8) |
//! | `output(#{ every: n, steps: [..], fields: [..], grid: bool })` | optional: write every n-th step or the listed steps (plus the initial state; `every` also the last step), only the named particle fields, with or without the grid and node files |
//! | `analytic_column(#{ axis: a, height: L0, material: m, body_force: b })` | declare the self-weight column solution (paper eqs. 11-14) for error reports |
//! | `stress_recovery(#{ order: m, radius: r })` | moving-least-squares stress recovery after every step (optional; defaults `order: 2`, `radius: 2.5` cell sizes): writes `recovered_stress` beside `cauchy_stress` and reports `error_recovered` |
//!
//! Node predicates see the control-point positions (Greville abscissae; grid vertices for
//! linear), with the first and last node of each axis exactly on the grid bounds. A predicate
//! that selects no node is an error. Top-level `let` statements are parameters that `--set`
//! can override (see `params`); use `const` for derived values that are not meant to be set.

use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};

use rhai::{Dynamic, Engine, EvalAltResult, NativeCallContext, Position};

use super::builder::{
    BodyDeclaration, ColumnDeclaration, ConstraintDeclaration, LoadSchedule, Located, MAX_NODES,
    MaterialHandle, PointLoadDeclaration, PointLoadShare, PointsPerCell, Region, SceneBuilder,
    TractionDeclaration, checked_node_count, ensure_unset,
};
use super::error::{SceneError, ScriptError};
use super::geometry::polygon_double_area;
use super::options::{
    OptionMap, array_of, describe, function, number, numbers, string, whole_number, whole_numbers,
};
use super::params::{Parameter, apply_overrides, find_parameters};
use super::seeding::Placement;
use super::{GridSpec, MaterialSpec, OutputSpec, RecoverySpec, SceneSpec, SolverSpec};
use crate::basis::{BasisKind, GimpDomain};
use crate::stages::output::PARTICLE_FIELDS;

/// The point fields modules add (checked by `output(#{ fields: .. })`).
const MODULE_FIELDS: &[&str] = &["recovered_stress", "point_load"];

/// The scene API functions and how they are called (used in "wrong arguments" messages).
pub(crate) const API_SIGNATURES: &[(&str, &str)] = &[
    (
        "grid",
        "grid(#{ lower: [..], upper: [..], cells: [..], basis: \"linear\" | \"bspline\" | \"gimp\" | \"cpdi\" | \"fem\", order: q, gimp: \"stretched\" | \"fixed\" })",
    ),
    (
        "material",
        "material(#{ name: \"..\", E: .., nu: .., density: .. })",
    ),
    ("box", "box([lower..], [upper..])"),
    ("polygon", "polygon([[x0, y0], [x1, y1], [x2, y2], ..])"),
    (
        "body",
        "body(#{ name: \"..\", material: m, region: box(..) or |x| .., ppc: n })",
    ),
    ("body_force", "body_force([b0, ..])"),
    (
        "fix",
        "fix(|x| predicate, [components]) or fix(|x| predicate)",
    ),
    (
        "displace",
        "displace(|x| predicate, [components], [values])",
    ),
    (
        "point_load",
        "point_load(|x| predicate, [force components])",
    ),
    (
        "point_load_total",
        "point_load_total(|x| predicate, [total force components])",
    ),
    (
        "traction",
        "traction(#{ on: [[x0, y0], [x1, y1]], traction: [hx, hy], per_cell: n })",
    ),
    ("load_steps", "load_steps(n)"),
    (
        "load_factors",
        "load_factors([f1, f2, ..]) or load_factors(n, |k| factor of step k)",
    ),
    (
        "load_phases",
        "load_phases([#{ to: 1.0, steps: 10 }, #{ to: 1.0, steps: 2 }, #{ to: 0.0, steps: 5 }])",
    ),
    (
        "solver",
        "solver(#{ tolerance: .., max_iterations: .., max_step_cuts: .., ghost_penalty: .. })",
    ),
    (
        "output",
        "output(#{ every: n, steps: [..], fields: [..], grid: true })",
    ),
    (
        "analytic_column",
        "analytic_column(#{ axis: a, height: L0, material: m, body_force: b })",
    ),
    (
        "stress_recovery",
        "stress_recovery(#{ order: m, radius: r })",
    ),
];

/// Runs the scene script at `path` with `--set` overrides `(NAME, VALUE)` applied and returns
/// the resolved scene. The scene name is the file stem.
pub fn load_scene(path: &Path, overrides: &[(String, String)]) -> Result<SceneSpec, SceneError> {
    let file = path.display().to_string();
    let source = read_script(path, &file)?;
    let state: SharedBuilder = Arc::new(Mutex::new(Some(SceneBuilder::default())));
    let engine = scene_engine(&state);
    // syntax errors are reported against the script as written, before any override
    engine
        .compile(&source)
        .map_err(|error| ScriptError::from_parse(&error).in_file(&file))?;
    let script = apply_overrides(&source, &find_parameters(&source), overrides)
        .map_err(|message| SceneError::whole_file(&file, message))?;
    let ast = engine
        .compile(&script)
        .map_err(|error| ScriptError::from_parse(&error).in_file(&file))?;
    engine
        .run_ast(&ast)
        .map_err(|error| ScriptError::from_eval(error).in_file(&file))?;
    // taking the builder out closes the API: predicates run below cannot declare more
    let builder = state
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .take()
        .unwrap_or_default();
    let name = path.file_stem().map_or_else(
        || "scene".to_string(),
        |stem| stem.to_string_lossy().into_owned(),
    );
    builder
        .resolve(&name, &engine, &ast)
        .map_err(|error| error.in_file(&file))
}

/// The script's parameters (top-level `let NAME = <default>;`), in source order.
pub fn scene_parameters(path: &Path) -> Result<Vec<Parameter>, SceneError> {
    let file = path.display().to_string();
    let source = read_script(path, &file)?;
    let engine = scene_engine(&Arc::new(Mutex::new(None)));
    engine
        .compile(&source)
        .map_err(|error| ScriptError::from_parse(&error).in_file(&file))?;
    Ok(find_parameters(&source)
        .into_iter()
        .map(|site| site.parameter)
        .collect())
}

fn read_script(path: &Path, file: &str) -> Result<String, SceneError> {
    std::fs::read_to_string(path).map_err(|error| {
        SceneError::whole_file(file, format!("cannot read the scene script: {error}"))
    })
}

type SharedBuilder = Arc<Mutex<Option<SceneBuilder>>>;

/// Runs `declare` on the builder with the call's position; its error message becomes a script
/// error at the call.
fn with_builder<T>(
    state: &SharedBuilder,
    context: &NativeCallContext,
    declare: impl FnOnce(&mut SceneBuilder, Position) -> Result<T, String>,
) -> Result<T, Box<EvalAltResult>> {
    let at = context.call_position();
    let mut guard = state.lock().unwrap_or_else(PoisonError::into_inner);
    let result = match guard.as_mut() {
        Some(builder) => declare(builder, at),
        None => Err(format!(
            "{}(...) cannot be called here (inside a region or node predicate the scene is already complete)",
            context.fn_name()
        )),
    };
    result.map_err(|message| EvalAltResult::ErrorRuntime(message.into(), at).into())
}

/// An engine with the scene API registered, declaring into `state`.
fn scene_engine(state: &SharedBuilder) -> Engine {
    let mut engine = Engine::new();
    engine.set_strict_variables(true);
    engine.set_fail_on_invalid_map_property(true);
    engine.register_type_with_name::<MaterialHandle>("Material");
    engine.register_type_with_name::<Region>("Region");

    let register_unary =
        |engine: &mut Engine,
         name: &'static str,
         declare: fn(&mut SceneBuilder, Dynamic, Position) -> Result<(), String>| {
            let state = state.clone();
            engine.register_fn(
                name,
                move |context: NativeCallContext, argument: Dynamic| {
                    with_builder(&state, &context, |builder, at| {
                        declare(builder, argument, at)
                    })
                },
            );
        };
    register_unary(&mut engine, "grid", declare_grid);
    register_unary(&mut engine, "body", declare_body);
    register_unary(&mut engine, "body_force", declare_body_force);
    register_unary(&mut engine, "load_steps", declare_load_steps);
    register_unary(&mut engine, "load_factors", declare_load_factors);
    register_unary(&mut engine, "load_phases", declare_load_phases);
    register_unary(&mut engine, "solver", declare_solver);
    register_unary(&mut engine, "output", declare_output);
    register_unary(&mut engine, "analytic_column", declare_analytic_column);
    register_unary(&mut engine, "traction", declare_traction);
    register_unary(&mut engine, "stress_recovery", declare_stress_recovery);

    let material_state = state.clone();
    engine.register_fn(
        "material",
        move |context: NativeCallContext, options: Dynamic| {
            with_builder(&material_state, &context, |builder, at| {
                declare_material(builder, options, at)
            })
        },
    );
    engine.register_fn(
        "box",
        |context: NativeCallContext, lower: Dynamic, upper: Dynamic| {
            make_box(&lower, &upper).map_err(|message| -> Box<EvalAltResult> {
                EvalAltResult::ErrorRuntime(message.into(), context.call_position()).into()
            })
        },
    );
    engine.register_fn(
        "polygon",
        |context: NativeCallContext, vertices: Dynamic| {
            make_polygon(&vertices).map_err(|message| -> Box<EvalAltResult> {
                EvalAltResult::ErrorRuntime(message.into(), context.call_position()).into()
            })
        },
    );
    let fix_state = state.clone();
    engine.register_fn(
        "fix",
        move |context: NativeCallContext, selector: Dynamic, components: Dynamic| {
            with_builder(&fix_state, &context, |builder, at| {
                declare_constraint(builder, "fix", &selector, &components, None, at)
            })
        },
    );
    let function_schedule_state = state.clone();
    engine.register_fn(
        "load_factors",
        move |context: NativeCallContext, steps: Dynamic, function_value: Dynamic| {
            with_builder(&function_schedule_state, &context, |builder, at| {
                declare_load_function(builder, &steps, &function_value, at)
            })
        },
    );
    let fix_all_state = state.clone();
    engine.register_fn(
        "fix",
        move |context: NativeCallContext, selector: Dynamic| {
            with_builder(&fix_all_state, &context, |builder, at| {
                declare_constraint(builder, "fix", &selector, &Dynamic::UNIT, None, at)
            })
        },
    );
    let displace_state = state.clone();
    engine.register_fn(
        "displace",
        move |context: NativeCallContext,
              selector: Dynamic,
              components: Dynamic,
              values: Dynamic| {
            with_builder(&displace_state, &context, |builder, at| {
                declare_constraint(
                    builder,
                    "displace",
                    &selector,
                    &components,
                    Some(&values),
                    at,
                )
            })
        },
    );
    for (name, share) in [
        ("point_load", PointLoadShare::Each),
        ("point_load_total", PointLoadShare::Total),
    ] {
        let point_load_state = state.clone();
        engine.register_fn(
            name,
            move |context: NativeCallContext, selector: Dynamic, force: Dynamic| {
                with_builder(&point_load_state, &context, |builder, at| {
                    declare_point_load(builder, name, share, &selector, &force, at)
                })
            },
        );
    }
    engine
}

fn declare_grid(builder: &mut SceneBuilder, options: Dynamic, at: Position) -> Result<(), String> {
    ensure_unset(&builder.grid, "grid")?;
    let options = OptionMap::new(
        "grid",
        options,
        &[
            "lower",
            "upper",
            "cells",
            "basis",
            "order",
            "gimp",
            "integration",
        ],
    )?;
    let lower = numbers(&options.required("lower")?, &options.subject("lower"))?;
    let upper = numbers(&options.required("upper")?, &options.subject("upper"))?;
    let cells = whole_numbers(&options.required("cells")?, &options.subject("cells"), 1)?;
    let dim = cells.len();
    if !(1..=3).contains(&dim) || lower.len() != dim || upper.len() != dim {
        return Err(format!(
            "grid(...): lower, upper and cells must have the same length 1, 2 or 3 (the dimension), got {}, {} and {}",
            lower.len(),
            upper.len(),
            dim
        ));
    }
    if let Some(axis) = (0..dim).find(|&axis| upper[axis] <= lower[axis]) {
        return Err(format!(
            "grid(...): upper[{axis}] = {} must be greater than lower[{axis}] = {}",
            upper[axis], lower[axis]
        ));
    }
    if let Some(axis) = (0..dim).find(|&axis| !(upper[axis] - lower[axis]).is_finite()) {
        return Err(format!(
            "grid(...): the extent along axis {axis} is not finite"
        ));
    }
    // validated whatever the basis, so that a misspelt variant is caught; used by "gimp" only
    let gimp_domain = match options.optional("gimp") {
        None => GimpDomain::Stretched,
        Some(value) => match string(&value, &options.subject("gimp"))?.as_str() {
            "stretched" => GimpDomain::Stretched,
            "fixed" => GimpDomain::Fixed,
            other => {
                return Err(format!(
                    "grid(...): option 'gimp' must be \"stretched\" (domains follow the deformation, cpGIMP) or \"fixed\" (domains keep their initial size, uGIMP), got {other:?}"
                ));
            }
        },
    };
    let domain_integration = match options.optional("integration") {
        None => false,
        Some(value) => match string(&value, &options.subject("integration"))?.as_str() {
            "points" => false,
            "domain" => true,
            other => {
                return Err(format!(
                    "grid(...): option 'integration' must be \"points\" (the basis at the material points) or \"domain\" (B-splines averaged over the points' domains), got {other:?}"
                ));
            }
        },
    };
    let basis_name = string(&options.required("basis")?, &options.subject("basis"))?;
    if domain_integration && basis_name != "bspline" {
        return Err(format!(
            "grid(...): integration \"domain\" is an option of basis \"bspline\" (for the hat functions it is basis \"gimp\"), got basis {basis_name:?}"
        ));
    }
    let basis = match basis_name.as_str() {
        // order is ignored: linear hat functions are order 1 by definition
        "linear" => BasisKind::Linear,
        // linear finite elements on the body-fitted mesh; order ignored like "linear"
        "fem" => BasisKind::Fem,
        "bspline" => {
            let order = options.optional("order").ok_or_else(|| {
                "grid(...): basis \"bspline\" needs option 'order' (1 linear, 2 quadratic, 3 cubic, ...)"
                    .to_string()
            })?;
            let order = whole_number(&order, &options.subject("order"), 1)?;
            if domain_integration {
                BasisKind::BSplineDomain { order }
            } else {
                BasisKind::BSpline { order }
            }
        }
        "gimp" => BasisKind::Gimp {
            domain: gimp_domain,
        },
        "cpdi" => BasisKind::Cpdi,
        other => {
            return Err(format!(
                "grid(...): option 'basis' must be \"linear\", \"bspline\", \"gimp\", \"cpdi\" or \"fem\", got {other:?}"
            ));
        }
    };
    let grid = GridSpec {
        lower,
        upper,
        cells,
        basis,
    };
    if checked_node_count(&grid).is_none() {
        return Err(format!(
            "grid(...): {:?} cells with basis order {} make more than {MAX_NODES} grid nodes",
            grid.cells,
            basis.order()
        ));
    }
    builder.grid = Some(Located::new(grid, at));
    Ok(())
}

fn declare_material(
    builder: &mut SceneBuilder,
    options: Dynamic,
    at: Position,
) -> Result<MaterialHandle, String> {
    let options = OptionMap::new("material", options, &["name", "E", "nu", "density"])?;
    let name = string(&options.required("name")?, &options.subject("name"))?;
    if let Some(previous) = builder
        .materials
        .iter()
        .find(|material| material.value.name == name)
    {
        return Err(format!(
            "material(...): a material named '{name}' was already declared{}",
            previous.line_note()
        ));
    }
    let youngs_modulus = number(&options.required("E")?, &options.subject("E"))?;
    let poisson_ratio = number(&options.required("nu")?, &options.subject("nu"))?;
    let density = number(&options.required("density")?, &options.subject("density"))?;
    if youngs_modulus <= 0.0 {
        return Err(format!(
            "material '{name}': Young's modulus E must be positive, got {youngs_modulus}"
        ));
    }
    if !(poisson_ratio > -1.0 && poisson_ratio < 0.5) {
        return Err(format!(
            "material '{name}': Poisson's ratio nu must satisfy -1 < nu < 0.5, got {poisson_ratio}"
        ));
    }
    if density <= 0.0 {
        return Err(format!(
            "material '{name}': density must be positive, got {density}"
        ));
    }
    let index = builder.materials.len();
    builder.materials.push(Located::new(
        MaterialSpec::hencky(&name, youngs_modulus, poisson_ratio, density),
        at,
    ));
    Ok(MaterialHandle { index, name })
}

fn material_handle(value: &Dynamic, subject: &str) -> Result<MaterialHandle, String> {
    value
        .flatten_clone()
        .try_cast::<MaterialHandle>()
        .ok_or_else(|| {
            format!(
                "{subject} must be a material returned by material(#{{ .. }}), got {}",
                describe(value)
            )
        })
}

fn make_box(lower: &Dynamic, upper: &Dynamic) -> Result<Region, String> {
    let lower = numbers(lower, "box(...): lower corner")?;
    let upper = numbers(upper, "box(...): upper corner")?;
    if lower.len() != upper.len() || lower.is_empty() {
        return Err(format!(
            "box(...): the corners must have the same (non-zero) number of coordinates, got {} and {}",
            lower.len(),
            upper.len()
        ));
    }
    if let Some(axis) = (0..lower.len()).find(|&axis| upper[axis] < lower[axis]) {
        return Err(format!(
            "box(...): upper[{axis}] = {} is below lower[{axis}] = {}",
            upper[axis], lower[axis]
        ));
    }
    Ok(Region::Box { lower, upper })
}

fn make_polygon(vertices: &Dynamic) -> Result<Region, String> {
    let subject = "polygon(...): the vertices";
    let vertices = array_of(
        vertices,
        subject,
        "points like [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]",
        numbers,
    )?;
    if vertices.len() < 3 {
        return Err(format!(
            "{subject} must be at least 3 points, got {}",
            vertices.len()
        ));
    }
    let vertices = vertices
        .iter()
        .enumerate()
        .map(|(index, vertex)| match vertex.as_slice() {
            &[x, y] => Ok([x, y]),
            _ => Err(format!(
                "{subject}[{index}] must have 2 coordinates (polygons are 2D), got {vertex:?}"
            )),
        })
        .collect::<Result<Vec<_>, _>>()?;
    if polygon_double_area(&vertices) == 0.0 {
        return Err(format!(
            "{subject} enclose no area (collinear or repeated points)"
        ));
    }
    Ok(Region::Polygon(vertices))
}

fn declare_body(builder: &mut SceneBuilder, options: Dynamic, at: Position) -> Result<(), String> {
    let options = OptionMap::new(
        "body",
        options,
        &["name", "material", "region", "ppc", "placement"],
    )?;
    let name = string(&options.required("name")?, &options.subject("name"))?;
    if let Some(previous) = builder.bodies.iter().find(|body| body.value.name == name) {
        return Err(format!(
            "body(...): a body named '{name}' was already declared{}",
            previous.line_note()
        ));
    }
    let material = material_handle(&options.required("material")?, &options.subject("material"))?;
    let region_value = options.required("region")?;
    let region = if region_value.is::<Region>() {
        region_value.cast::<Region>()
    } else if region_value.is_fnptr() {
        Region::Predicate(function(&region_value, &options.subject("region"))?)
    } else {
        return Err(format!(
            "{} must be box([..], [..]), polygon([..]) or a predicate |x| .. on the position, got {}",
            options.subject("region"),
            describe(&region_value)
        ));
    };
    let ppc_value = options.required("ppc")?;
    let points_per_cell = if ppc_value.is_array() {
        PointsPerCell::PerAxis(whole_numbers(&ppc_value, &options.subject("ppc"), 1)?)
    } else {
        PointsPerCell::Uniform(whole_number(&ppc_value, &options.subject("ppc"), 1)?)
    };
    let placement = match options.optional("placement") {
        None => Placement::Uniform,
        Some(value) => match string(&value, &options.subject("placement"))?.as_str() {
            "uniform" => Placement::Uniform,
            "gauss" => Placement::Gauss,
            other => {
                return Err(format!(
                    "{} must be \"uniform\" or \"gauss\", got {other:?}",
                    options.subject("placement")
                ));
            }
        },
    };
    builder.bodies.push(Located::new(
        BodyDeclaration {
            name,
            material: material.index,
            region,
            points_per_cell,
            placement,
        },
        at,
    ));
    Ok(())
}

fn declare_body_force(
    builder: &mut SceneBuilder,
    force: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_unset(&builder.body_force, "body_force")?;
    let force = numbers(&force, "body_force(...): the force per unit mass")?;
    if force.is_empty() {
        return Err("body_force(...) needs one component per axis, got []".to_string());
    }
    builder.body_force = Some(Located::new(force, at));
    Ok(())
}

fn declare_constraint(
    builder: &mut SceneBuilder,
    function_name: &'static str,
    selector: &Dynamic,
    components: &Dynamic,
    values: Option<&Dynamic>,
    at: Position,
) -> Result<(), String> {
    let selector = function(
        selector,
        &format!("{function_name}(...): the first argument"),
    )?;
    let components_subject = format!("{function_name}(...): the components");
    // fix(|x| ..) without components: all of them, known once the grid is
    let all_components = components.is_unit();
    let components = if all_components {
        Vec::new()
    } else {
        whole_numbers(components, &components_subject, 0)?
    };
    if components.is_empty() && !all_components {
        return Err(format!(
            "{components_subject} must list at least one axis index, got []"
        ));
    }
    if let Some(duplicate) = components
        .iter()
        .enumerate()
        .find_map(|(index, component)| components[..index].contains(component).then_some(component))
    {
        return Err(format!("{components_subject} list {duplicate} twice"));
    }
    let values = match values {
        None => vec![0.0; components.len()],
        Some(values) => {
            let values = numbers(values, &format!("{function_name}(...): the values"))?;
            if values.len() != components.len() {
                return Err(format!(
                    "{function_name}(...): {} components but {} values; give one value per component",
                    components.len(),
                    values.len()
                ));
            }
            values
        }
    };
    builder.constraints.push(Located::new(
        ConstraintDeclaration {
            function: function_name,
            selector,
            components,
            values,
        },
        at,
    ));
    Ok(())
}

fn declare_point_load(
    builder: &mut SceneBuilder,
    function_name: &'static str,
    share: PointLoadShare,
    selector: &Dynamic,
    force: &Dynamic,
    at: Position,
) -> Result<(), String> {
    let selector = function(
        selector,
        &format!("{function_name}(...): the first argument"),
    )?;
    let force = numbers(force, &format!("{function_name}(...): the force"))?;
    builder.point_loads.push(Located::new(
        PointLoadDeclaration {
            function: function_name,
            selector,
            force,
            share,
        },
        at,
    ));
    Ok(())
}

fn declare_traction(
    builder: &mut SceneBuilder,
    options: Dynamic,
    at: Position,
) -> Result<(), String> {
    let options = OptionMap::new("traction", options, &["on", "traction", "per_cell"])?;
    let corners = array_of(
        &options.required("on")?,
        &options.subject("on"),
        "points like [[0.0, 1.0], [2.0, 1.0]]",
        numbers,
    )?;
    let traction = numbers(&options.required("traction")?, &options.subject("traction"))?;
    let per_cell = match options.optional("per_cell") {
        Some(value) => whole_number(&value, &options.subject("per_cell"), 1)?,
        None => 2,
    };
    if per_cell > 1000 {
        return Err(format!(
            "{} must be at most 1000, got {per_cell}",
            options.subject("per_cell")
        ));
    }
    builder.tractions.push(Located::new(
        TractionDeclaration {
            corners,
            traction,
            per_cell,
        },
        at,
    ));
    Ok(())
}

fn ensure_no_load_schedule(builder: &SceneBuilder) -> Result<(), String> {
    match &builder.load_schedule {
        Some(previous) => Err(format!(
            "the load schedule was already set{}; call one of load_steps, load_factors or load_phases once",
            previous.line_note()
        )),
        None => Ok(()),
    }
}

fn declare_load_steps(
    builder: &mut SceneBuilder,
    steps: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_no_load_schedule(builder)?;
    let steps = whole_number(&steps, "load_steps(...): the number of steps", 1)?;
    if steps > MAX_STEPS {
        return Err(format!("load_steps(...): {steps} steps is too many"));
    }
    let factors = (1..=steps).map(|step| step as f64 / steps as f64).collect();
    builder.load_schedule = Some(Located::new(LoadSchedule::Factors(factors), at));
    Ok(())
}

fn declare_load_factors(
    builder: &mut SceneBuilder,
    factors: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_no_load_schedule(builder)?;
    let factors = numbers(&factors, "load_factors(...): the load factors")?;
    if factors.is_empty() {
        return Err("load_factors(...) needs at least one load factor, got []".to_string());
    }
    builder.load_schedule = Some(Located::new(LoadSchedule::Factors(factors), at));
    Ok(())
}

/// Largest number of load steps a schedule may have.
const MAX_STEPS: usize = 10_000_000;

fn declare_load_function(
    builder: &mut SceneBuilder,
    steps: &Dynamic,
    function_value: &Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_no_load_schedule(builder)?;
    let steps = whole_number(steps, "load_factors(...): the number of steps", 1)?;
    if steps > MAX_STEPS {
        return Err(format!("load_factors(...): {steps} steps is too many"));
    }
    let function = function_value.flatten_clone();
    if !function.is_fnptr() {
        return Err(format!(
            "load_factors(...): the second argument must be a function of the step like |k| k / 10.0, got {}",
            describe(&function)
        ));
    }
    builder.load_schedule = Some(Located::new(
        LoadSchedule::Function {
            steps,
            function: function.cast::<rhai::FnPtr>(),
        },
        at,
    ));
    Ok(())
}

/// Load factors of phases that start at λ = 0 and each go linearly to their `to` in `steps`
/// equal steps.
pub(crate) fn phase_factors(phases: &[(f64, usize)]) -> Vec<f64> {
    let mut factors = Vec::new();
    let mut start = 0.0;
    for &(to, steps) in phases {
        factors.extend((1..=steps).map(|k| start + (to - start) * k as f64 / steps as f64));
        start = to;
    }
    factors
}

fn declare_load_phases(
    builder: &mut SceneBuilder,
    phases: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_no_load_schedule(builder)?;
    let phases = array_of(
        &phases,
        "load_phases(...): the phases",
        "option maps like #{ to: 1.0, steps: 10 }",
        |phase, subject| {
            let options = OptionMap::new("load_phases", phase.clone(), &["to", "steps"])?;
            let to = number(&options.required("to")?, &format!("{subject}: option 'to'"))?;
            let steps = whole_number(
                &options.required("steps")?,
                &format!("{subject}: option 'steps'"),
                1,
            )?;
            Ok((to, steps))
        },
    )?;
    if phases.is_empty() {
        return Err("load_phases(...) needs at least one phase, got []".to_string());
    }
    let total = phases
        .iter()
        .try_fold(0usize, |total, (_, steps)| total.checked_add(*steps));
    if total.is_none_or(|total| total > MAX_STEPS) {
        return Err(format!("load_phases(...): more than {MAX_STEPS} steps"));
    }
    builder.load_schedule = Some(Located::new(
        LoadSchedule::Factors(phase_factors(&phases)),
        at,
    ));
    Ok(())
}

fn declare_solver(
    builder: &mut SceneBuilder,
    options: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_unset(&builder.solver, "solver")?;
    let options = OptionMap::new(
        "solver",
        options,
        &[
            "tolerance",
            "max_iterations",
            "max_step_cuts",
            "ghost_penalty",
        ],
    )?;
    let mut solver = SolverSpec::default();
    if let Some(tolerance) = options.optional("tolerance") {
        solver.tolerance = number(&tolerance, &options.subject("tolerance"))?;
        if solver.tolerance <= 0.0 {
            return Err(format!(
                "{} must be positive, got {}",
                options.subject("tolerance"),
                solver.tolerance
            ));
        }
    }
    if let Some(iterations) = options.optional("max_iterations") {
        solver.max_iterations = whole_number(&iterations, &options.subject("max_iterations"), 1)?;
    }
    if let Some(gamma) = options.optional("ghost_penalty") {
        solver.ghost_penalty = number(&gamma, &options.subject("ghost_penalty"))?;
        if !(solver.ghost_penalty >= 0.0 && solver.ghost_penalty.is_finite()) {
            return Err(format!(
                "{} must be zero (off) or positive, got {}",
                options.subject("ghost_penalty"),
                solver.ghost_penalty
            ));
        }
    }
    if let Some(cuts) = options.optional("max_step_cuts") {
        solver.max_step_cuts = whole_number(&cuts, &options.subject("max_step_cuts"), 0)?;
    }
    builder.solver = Some(Located::new(solver, at));
    Ok(())
}

fn declare_output(
    builder: &mut SceneBuilder,
    options: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_unset(&builder.output, "output")?;
    let options = OptionMap::new("output", options, &["every", "steps", "fields", "grid"])?;
    let mut output = OutputSpec::default();
    if let Some(every) = options.optional("every") {
        output.every = whole_number(&every, &options.subject("every"), 1)?;
    }
    if let Some(steps) = options.optional("steps") {
        if options.optional("every").is_some() {
            return Err("output(...): give 'every' or 'steps', not both".to_string());
        }
        output.steps = Some(whole_numbers(&steps, &options.subject("steps"), 1)?);
    }
    if let Some(fields) = options.optional("fields") {
        let fields = array_of(
            &fields,
            &options.subject("fields"),
            "field names like [\"displacement\", \"cauchy_stress\"]",
            string,
        )?;
        let known: Vec<&str> = PARTICLE_FIELDS
            .iter()
            .chain(MODULE_FIELDS)
            .copied()
            .collect();
        if let Some(unknown) = fields.iter().find(|field| !known.contains(&field.as_str())) {
            return Err(format!(
                "{}: unknown particle field {unknown:?}; the fields are: {}",
                options.subject("fields"),
                known.join(", ")
            ));
        }
        output.fields = Some(fields);
    }
    if let Some(grid) = options.optional("grid") {
        output.grid = grid.as_bool().map_err(|_| {
            format!(
                "{} must be true or false, got {}",
                options.subject("grid"),
                describe(&grid)
            )
        })?;
    }
    builder.output = Some(Located::new(output, at));
    Ok(())
}

fn declare_analytic_column(
    builder: &mut SceneBuilder,
    options: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_unset(&builder.analytic, "analytic_column")?;
    let options = OptionMap::new(
        "analytic_column",
        options,
        &["axis", "height", "material", "body_force"],
    )?;
    let axis = whole_number(&options.required("axis")?, &options.subject("axis"), 0)?;
    let height = number(&options.required("height")?, &options.subject("height"))?;
    if height <= 0.0 {
        return Err(format!(
            "{} must be positive, got {height}",
            options.subject("height")
        ));
    }
    let material = material_handle(&options.required("material")?, &options.subject("material"))?;
    let body_force = number(
        &options.required("body_force")?,
        &options.subject("body_force"),
    )?;
    builder.analytic = Some(Located::new(
        ColumnDeclaration {
            axis,
            height,
            material: material.index,
            body_force,
        },
        at,
    ));
    Ok(())
}

fn declare_stress_recovery(
    builder: &mut SceneBuilder,
    options: Dynamic,
    at: Position,
) -> Result<(), String> {
    ensure_unset(&builder.recovery, "stress_recovery")?;
    let options = OptionMap::new("stress_recovery", options, &["order", "radius"])?;
    let mut recovery = RecoverySpec::default();
    if let Some(order) = options.optional("order") {
        recovery.order = whole_number(&order, &options.subject("order"), 0)?;
        if recovery.order > 4 {
            return Err(format!(
                "{} must be at most 4, got {}",
                options.subject("order"),
                recovery.order
            ));
        }
    }
    if let Some(radius) = options.optional("radius") {
        recovery.radius_in_cells = number(&radius, &options.subject("radius"))?;
        if recovery.radius_in_cells <= 0.0 {
            return Err(format!(
                "{} (in cell sizes) must be positive, got {}",
                options.subject("radius"),
                recovery.radius_in_cells
            ));
        }
    }
    builder.recovery = Some(Located::new(recovery, at));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{AnalyticSpec, NodeConstraint};
    use std::path::PathBuf;

    fn shipped(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scripts")
            .join(name)
    }

    /// Writes an inline script to a per-process temporary directory.
    fn inline_script(name: &str, text: &str) -> PathBuf {
        let directory =
            std::env::temp_dir().join(format!("impm-scene-tests-{}", std::process::id()));
        std::fs::create_dir_all(&directory).unwrap();
        let path = directory.join(format!("{name}.rhai"));
        std::fs::write(&path, text).unwrap();
        path
    }

    fn set(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(name, value)| (name.to_string(), value.to_string()))
            .collect()
    }

    fn total_volume(scene: &SceneSpec) -> f64 {
        scene
            .bodies
            .iter()
            .flat_map(|body| &body.points)
            .map(|point| point.volume)
            .sum()
    }

    fn assert_close(actual: f64, expected: f64) {
        assert!(
            (actual - expected).abs() <= 1e-9 * expected.abs().max(1.0),
            "{actual} != {expected}"
        );
    }

    /// Loads an inline script expected to fail; returns the error.
    fn failure(name: &str, text: &str) -> SceneError {
        let path = inline_script(name, text);
        let error = load_scene(&path, &[]).expect_err("the script should fail");
        assert!(
            error.to_string().starts_with(&path.display().to_string()),
            "{error}"
        );
        error
    }

    /// A valid 1D scene with `replace` substituted for the line that starts with `key`.
    fn scene_1d_with(key: &str, replace: &str) -> String {
        let lines = [
            "let cells = 10;",
            "grid(#{ lower: [0.0], upper: [10.0], cells: [cells], basis: \"bspline\", order: 2 });",
            "const m = material(#{ name: \"m\", E: 1e6, nu: 0.0, density: 1.0 });",
            "body(#{ name: \"bar\", material: m, region: box([0.0], [10.0]), ppc: 2 });",
            "fix(|x| x[0] == 0.0, [0]);",
            "load_steps(2);",
        ];
        lines
            .iter()
            .map(|line| if line.starts_with(key) { replace } else { line })
            .collect::<Vec<_>>()
            .join("\n")
    }

    #[test]
    fn column_1d_defaults() {
        let scene = load_scene(&shipped("column_1d.rhai"), &[]).unwrap();
        assert_eq!(scene.name, "column_1d");
        assert_eq!(scene.dim(), 1);
        assert_eq!(scene.grid.cells, [50]);
        assert_eq!(scene.grid.basis, BasisKind::BSpline { order: 3 });
        assert_eq!(scene.bodies.len(), 1);
        assert_eq!(scene.bodies[0].points.len(), 50 * 4);
        assert_close(total_volume(&scene), 50.0);
        assert_eq!(scene.materials[0].stiffness, 1e6);
        assert_eq!(scene.materials[0].density, 1.0);
        assert_eq!(scene.body_force, Some(vec![-800.0]));
        assert_eq!(
            scene.constraints,
            [NodeConstraint {
                node: 0,
                component: 0,
                value: 0.0
            }]
        );
        assert_eq!(scene.load_factors.len(), 20);
        assert_eq!(scene.load_factors[0], 0.05);
        assert_eq!(scene.load_factors[19], 1.0);
        assert_eq!(
            scene.analytic,
            Some(AnalyticSpec::Column {
                axis: 0,
                height: 50.0,
                density: 1.0,
                body_force: -800.0,
                modulus: 1e6
            })
        );
        assert_eq!(scene.solver, SolverSpec::default());
        assert_eq!(scene.output, OutputSpec::default());
    }

    #[test]
    fn column_2d_defaults() {
        let scene = load_scene(&shipped("column_2d.rhai"), &[]).unwrap();
        assert_eq!(scene.dim(), 2);
        assert_eq!(scene.grid.cells, [1, 50]);
        assert_eq!(scene.grid.upper, [1.0, 50.0]);
        assert_eq!(scene.bodies[0].points.len(), 50 * 4 * 4);
        assert_close(total_volume(&scene), 50.0);
        assert_eq!(scene.body_force, Some(vec![0.0, -800.0]));
        // cubic B-splines: 1 + 3 = 4 nodes across, 50 + 3 = 53 up; axis 0 fastest
        let (across, up) = (4, 53);
        let mut expected: Vec<NodeConstraint> = Vec::new();
        for row in 0..up {
            for column in 0..across {
                let node = row * across + column;
                if column == 0 || column == across - 1 {
                    expected.push(NodeConstraint {
                        node,
                        component: 0,
                        value: 0.0,
                    });
                }
                if row == 0 {
                    expected.push(NodeConstraint {
                        node,
                        component: 1,
                        value: 0.0,
                    });
                }
            }
        }
        assert_eq!(scene.constraints, expected);
        assert!(matches!(
            scene.analytic,
            Some(AnalyticSpec::Column { axis: 1, .. })
        ));
    }

    #[test]
    fn column_3d_defaults() {
        let scene = load_scene(&shipped("column_3d.rhai"), &[]).unwrap();
        assert_eq!(scene.dim(), 3);
        assert_eq!(scene.grid.cells, [1, 1, 50]);
        assert_eq!(scene.bodies[0].points.len(), 50 * 4 * 4 * 4);
        assert_close(total_volume(&scene), 50.0);
        assert_eq!(scene.body_force, Some(vec![0.0, 0.0, -800.0]));
        let across = 4;
        let count = |component: usize| {
            scene
                .constraints
                .iter()
                .filter(|c| c.component == component)
                .count()
        };
        assert_eq!(count(2), across * across);
        assert_eq!(count(0), 2 * across * 53);
        assert_eq!(count(1), 2 * across * 53);
        for constraint in &scene.constraints {
            let (i, j, k) = (
                constraint.node % across,
                constraint.node / across % across,
                constraint.node / (across * across),
            );
            let on_face = match constraint.component {
                0 => i == 0 || i == across - 1,
                1 => j == 0 || j == across - 1,
                _ => k == 0,
            };
            assert!(on_face, "{constraint:?}");
        }
        assert!(matches!(
            scene.analytic,
            Some(AnalyticSpec::Column { axis: 2, .. })
        ));
    }

    #[test]
    fn overrides_change_the_scene() {
        let path = shipped("column_1d.rhai");
        let scene = load_scene(&path, &set(&[("cells", "10")])).unwrap();
        assert_eq!(scene.grid.cells, [10]);
        assert_eq!(scene.bodies[0].points.len(), 40);
        assert_close(total_volume(&scene), 50.0);

        let scene = load_scene(&path, &set(&[("basis", "linear")])).unwrap();
        assert_eq!(scene.grid.basis, BasisKind::Linear);
        assert_eq!(
            scene.bodies[0].points.len(),
            50,
            "linear defaults to one point per cell"
        );

        let scene = load_scene(&path, &set(&[("body_force", "-200"), ("steps", "5")])).unwrap();
        assert_eq!(scene.body_force, Some(vec![-200.0]));
        assert!(matches!(
            scene.analytic,
            Some(AnalyticSpec::Column {
                body_force: -200.0,
                ..
            })
        ));
        assert_eq!(scene.load_factors, [0.2, 0.4, 0.6, 0.8, 1.0]);

        let scene = load_scene(
            &shipped("column_2d.rhai"),
            &set(&[("cells", "10"), ("order", "2")]),
        )
        .unwrap();
        assert_eq!(scene.grid.upper, [5.0, 50.0]);
        assert_eq!(scene.grid.basis, BasisKind::BSpline { order: 2 });
        assert_eq!(scene.bodies[0].points.len(), 10 * 16);
        assert_close(total_volume(&scene), 250.0);

        // a width that is not a round number: the side nodes must still be found exactly
        for cells in 1..=13 {
            let cells_text = cells.to_string();
            let scene =
                load_scene(&shipped("column_2d.rhai"), &set(&[("cells", &cells_text)])).unwrap();
            let nodes_up = cells + 3;
            assert_eq!(scene.constraints.len(), 2 * nodes_up + 4, "cells = {cells}");
        }
    }

    #[test]
    fn unknown_override_lists_the_parameters() {
        let error = load_scene(&shipped("column_1d.rhai"), &set(&[("cels", "10")])).unwrap_err();
        assert_eq!(error.line, None);
        let text = error.to_string();
        assert!(
            text.contains("column_1d.rhai: --set cels=10: there is no parameter 'cels'"),
            "{text}"
        );
        assert!(
            text.contains("cells, basis, order, gimp, ppc, body_force, steps, placement, integration, recovery"),
            "{text}"
        );
    }

    #[test]
    fn scene_parameters_lists_the_column_parameters() {
        for script in ["column_1d.rhai", "column_2d.rhai", "column_3d.rhai"] {
            let parameters = scene_parameters(&shipped(script)).unwrap();
            let listed: Vec<(&str, &str)> = parameters
                .iter()
                .map(|p| (p.name.as_str(), p.default.as_str()))
                .collect();
            assert_eq!(
                listed,
                [
                    ("cells", "50"),
                    ("basis", "\"bspline\""),
                    ("order", "3"),
                    ("gimp", "\"stretched\""),
                    (
                        "ppc",
                        "if basis == \"linear\" { 1 } else if basis == \"gimp\" || basis == \"cpdi\" { 2 } else { 4 }"
                    ),
                    ("body_force", "-800.0"),
                    ("steps", "20"),
                    ("placement", "\"uniform\""),
                    ("integration", "\"points\""),
                    ("recovery", "\"none\""),
                ],
                "{script}"
            );
            let text = std::fs::read_to_string(shipped(script)).unwrap();
            let cells_line = 1 + text
                .lines()
                .position(|line| line.starts_with("let cells"))
                .unwrap();
            assert_eq!(parameters[0].line, cells_line, "{script}");
            assert!(
                parameters
                    .windows(2)
                    .all(|pair| pair[1].line == pair[0].line + 1)
            );
        }
    }

    #[test]
    fn syntax_error_points_at_the_line() {
        let error = failure(
            "syntax",
            "let cells = 10;\n\ngrid(#{ lower: [0.0] upper: [1.0] });\n",
        );
        assert_eq!(error.line, Some(3), "{error}");
        assert!(error.message.starts_with("syntax error"), "{error}");
    }

    #[test]
    fn override_keeps_line_numbers_of_later_errors() {
        let text = "let cells = 10;\nlet ppc = if cells > 5 {\n  2\n} else {\n  1\n};\nlet broken = 1;\ngrid(#{ lower: [0.0], upper: [1.0], cells: [cells], basis: \"spline\" });\n";
        let path = inline_script("lines", text);
        let error = load_scene(&path, &set(&[("ppc", "3")])).unwrap_err();
        assert_eq!(error.line, Some(8), "{error}");
        assert!(
            error
                .message
                .contains("\"linear\", \"bspline\", \"gimp\", \"cpdi\" or \"fem\", got \"spline\""),
            "{error}"
        );
    }

    #[test]
    fn unknown_key_names_the_allowed_keys() {
        let error = failure(
            "unknown_key",
            &scene_1d_with(
                "grid",
                "\n\ngrid(#{ lower: [0.0], upper: [10.0], cels: [10], basis: \"linear\" });",
            ),
        );
        assert_eq!(error.line, Some(4), "{error}");
        assert!(
            error
                .message
                .contains("unknown option 'cels' (did you mean 'cells'?)")
                && error.message.contains("lower, upper, cells, basis, order"),
            "{error}"
        );
    }

    #[test]
    fn order_zero_and_zero_cells_are_rejected() {
        let error = failure(
            "order_zero",
            &scene_1d_with(
                "grid",
                "grid(#{ lower: [0.0], upper: [10.0], cells: [10], basis: \"bspline\", order: 0 });",
            ),
        );
        assert_eq!(error.line, Some(2), "{error}");
        assert!(
            error
                .message
                .contains("'order' must be a whole number >= 1, got integer 0"),
            "{error}"
        );

        let path = inline_script("zero_cells", &scene_1d_with("#", ""));
        let error = load_scene(&path, &set(&[("cells", "0")])).unwrap_err();
        assert_eq!(error.line, Some(2), "{error}");
        assert!(
            error
                .message
                .contains("'cells'[0] must be a whole number >= 1, got integer 0"),
            "{error}"
        );
    }

    #[test]
    fn gimp_and_cpdi_scene_words() {
        let grid_with = |options: &str| {
            format!("grid(#{{ lower: [0.0], upper: [10.0], cells: [cells], {options} }});")
        };
        let cases = [
            (
                "basis: \"gimp\"",
                BasisKind::Gimp {
                    domain: GimpDomain::Stretched,
                },
            ),
            (
                "basis: \"gimp\", gimp: \"fixed\"",
                BasisKind::Gimp {
                    domain: GimpDomain::Fixed,
                },
            ),
            (
                "basis: \"gimp\", gimp: \"stretched\", order: 3",
                BasisKind::Gimp {
                    domain: GimpDomain::Stretched,
                },
            ),
            ("basis: \"cpdi\"", BasisKind::Cpdi),
            (
                "basis: \"bspline\", order: 2, gimp: \"fixed\"",
                BasisKind::BSpline { order: 2 },
            ),
        ];
        for (k, (options, expected)) in cases.into_iter().enumerate() {
            let text = scene_1d_with("grid", &grid_with(options));
            let scene = load_scene(&inline_script(&format!("words{k}"), &text), &[]).unwrap();
            assert_eq!(scene.grid.basis, expected, "{options}");
            // 10 cells of 1, ppc 2: the points own boxes of side 0.5
            assert!(
                scene.bodies[0]
                    .points
                    .iter()
                    .all(|point| point.half_lengths == [0.25]),
                "{options}"
            );
        }
        let error = failure(
            "gimp_variant",
            &scene_1d_with("grid", &grid_with("basis: \"gimp\", gimp: \"ugimp\"")),
        );
        assert_eq!(error.line, Some(2), "{error}");
        assert!(
            error
                .message
                .contains("option 'gimp' must be \"stretched\" (domains follow the deformation, cpGIMP) or \"fixed\""),
            "{error}"
        );
        let error = failure(
            "gimp_type",
            &scene_1d_with("grid", &grid_with("basis: \"cpdi\", gimp: 1")),
        );
        assert_eq!(error.line, Some(2), "{error}");
        assert!(error.message.contains("'gimp' must be a string"), "{error}");
    }

    #[test]
    fn integration_domain_averages_bsplines_and_is_checked() {
        let grid_with = |options: &str| {
            format!("grid(#{{ lower: [0.0], upper: [10.0], cells: [cells], {options} }});")
        };
        let path = inline_script(
            "integration",
            &scene_1d_with(
                "grid",
                &grid_with("basis: \"bspline\", order: 2, integration: \"domain\""),
            ),
        );
        let scene = load_scene(&path, &[]).unwrap();
        assert_eq!(scene.grid.basis, BasisKind::BSplineDomain { order: 2 });
        assert!(scene.grid.basis.uses_point_domain());
        for (name, options, expected) in [
            (
                "integration_gimp",
                "basis: \"gimp\", integration: \"domain\"",
                "integration \"domain\" is an option of basis \"bspline\"",
            ),
            (
                "integration_word",
                "basis: \"bspline\", order: 2, integration: \"exact\"",
                "option 'integration' must be \"points\" (the basis at the material points) or \"domain\"",
            ),
        ] {
            let error = failure(name, &scene_1d_with("grid", &grid_with(options)));
            assert_eq!(error.line, Some(2), "{error}");
            assert!(error.message.contains(expected), "{error}");
        }
    }

    #[test]
    fn shipped_columns_run_gimp_and_cpdi_with_two_points_per_cell() {
        for basis in ["gimp", "cpdi"] {
            for script in ["column_1d.rhai", "column_2d.rhai", "column_3d.rhai"] {
                let scene = load_scene(&shipped(script), &set(&[("basis", basis), ("cells", "4")]))
                    .unwrap();
                assert!(scene.grid.basis.uses_point_domain());
                let dim = scene.dim();
                // cells of 12.5 (one across in 2D/3D), 2 points per cell per axis
                for point in &scene.bodies[0].points {
                    assert!(
                        point.half_lengths.iter().all(|l| (l - 3.125).abs() < 1e-12),
                        "{script}: {:?}",
                        point.half_lengths
                    );
                }
                assert_eq!(scene.bodies[0].points.len(), 4 * (1 << dim), "{script}");
            }
        }
    }

    #[test]
    fn invalid_materials_are_rejected_at_their_line() {
        let error = failure(
            "negative_e",
            &scene_1d_with(
                "const m",
                "const m = material(#{ name: \"m\", E: -5, nu: 0.0, density: 1.0 });",
            ),
        );
        assert_eq!((error.line, error.column), (Some(3), Some(11)), "{error}");
        assert!(
            error
                .message
                .contains("Young's modulus E must be positive, got -5"),
            "{error}"
        );

        let error = failure(
            "nu_half",
            &scene_1d_with(
                "const m",
                "const m = material(#{ name: \"m\", E: 1e6, nu: 0.5, density: 1.0 });",
            ),
        );
        assert_eq!(error.line, Some(3), "{error}");
        assert!(error.message.contains("-1 < nu < 0.5, got 0.5"), "{error}");
    }

    #[test]
    fn bodies_outside_the_grid_are_rejected() {
        let error = failure(
            "box_outside",
            &scene_1d_with(
                "body",
                "body(#{ name: \"bar\", material: m, region: box([0.0], [12.0]), ppc: 2 });",
            ),
        );
        assert_eq!(error.line, Some(4), "{error}");
        assert!(
            error.message.contains("body 'bar'") && error.message.contains("not inside the grid"),
            "{error}"
        );

        let error = failure(
            "closure_outside",
            &scene_1d_with(
                "body",
                "body(#{ name: \"bar\", material: m, region: |x| x[0] < 10.5, ppc: 2 });",
            ),
        );
        assert_eq!(error.line, Some(4), "{error}");
        assert!(
            error.message.contains("body 'bar'") && error.message.contains("outside the grid"),
            "{error}"
        );

        let error = failure(
            "empty_body",
            &scene_1d_with(
                "body",
                "body(#{ name: \"bar\", material: m, region: |x| x[0] > 20.0, ppc: 2 });",
            ),
        );
        assert_eq!(error.line, Some(4), "{error}");
        assert!(
            error.message.contains("body 'bar': no material points"),
            "{error}"
        );
    }

    #[test]
    fn runtime_error_in_a_predicate_reports_the_closure_line() {
        let error = failure(
            "closure_error",
            &scene_1d_with(
                "fix",
                "fix(|x| {\n    let y = x[0];\n    x[3] > y\n}, [0]);",
            ),
        );
        assert_eq!(error.line, Some(7), "{error}");
        assert!(
            error.message.contains("out of bounds") && error.message.contains("fix(...) at line 5"),
            "{error}"
        );

        let error = failure(
            "region_error",
            &scene_1d_with(
                "body",
                "body(#{ name: \"bar\", material: m, region: |x| x[1] < 1.0, ppc: 2 });",
            ),
        );
        assert_eq!(error.line, Some(4), "{error}");
        assert!(
            error.message.contains("region predicate of body 'bar'"),
            "{error}"
        );
    }

    #[test]
    fn predicates_selecting_nothing_or_returning_non_booleans_are_rejected() {
        let error = failure(
            "no_node",
            &scene_1d_with("fix", "fix(|x| x[0] < -1.0, [0]);"),
        );
        assert_eq!(error.line, Some(5), "{error}");
        assert!(error.message.contains("selects no grid node"), "{error}");

        let error = failure("not_bool", &scene_1d_with("fix", "fix(|x| x[0], [0]);"));
        assert_eq!(error.line, Some(5), "{error}");
        assert!(
            error
                .message
                .contains("must return true or false, got float 0.0"),
            "{error}"
        );
    }

    #[test]
    fn missing_and_repeated_declarations() {
        let error = failure("no_grid", &scene_1d_with("grid", ""));
        assert_eq!(error.line, None);
        assert!(error.message.contains("no grid"), "{error}");
        let error = failure("no_steps", &scene_1d_with("load_steps", ""));
        assert!(error.message.contains("no load steps"), "{error}");
        let error = failure("no_body", &scene_1d_with("body", ""));
        assert!(error.message.contains("no body"), "{error}");
        let mut text = scene_1d_with("#", "");
        text.push_str("\ngrid(#{ lower: [0.0], upper: [1.0], cells: [1], basis: \"linear\" });");
        let error = failure("grid_twice", &text);
        assert_eq!(error.line, Some(7), "{error}");
        assert!(
            error
                .message
                .contains("grid(...) was already called at line 2"),
            "{error}"
        );
    }

    #[test]
    fn wrong_types_say_what_was_expected() {
        let error = failure(
            "wrong_type",
            &scene_1d_with("load_steps", "load_steps(\"ten\");"),
        );
        assert_eq!(error.line, Some(6), "{error}");
        assert!(
            error
                .message
                .contains("must be a whole number >= 1, got string \"ten\""),
            "{error}"
        );
        let error = failure("wrong_arity", &scene_1d_with("fix", "fix();"));
        assert_eq!(error.line, Some(5), "{error}");
        assert!(
            error
                .message
                .contains("expected fix(|x| predicate, [components]) or fix(|x| predicate)"),
            "{error}"
        );
        let error = failure("wrong_first", &scene_1d_with("fix", "fix([0]);"));
        assert_eq!(error.line, Some(5), "{error}");
        assert!(
            error
                .message
                .contains("fix(...): the first argument must be a function of the position"),
            "{error}"
        );
        let error = failure(
            "wrong_material",
            &scene_1d_with(
                "body",
                "body(#{ name: \"bar\", material: \"m\", region: box([0.0], [10.0]), ppc: 2 });",
            ),
        );
        assert!(
            error
                .message
                .contains("must be a material returned by material"),
            "{error}"
        );
    }

    #[test]
    fn displacements_load_factors_solver_and_output() {
        let mut text = scene_1d_with("fix", "displace(|x| x[0] == 10.0, [0], [-1]);");
        text = text.replace("load_steps(2);", "load_factors([0.5, 1, 1.5]);");
        text.push_str("\nfix(|x| x[0] == 0.0, [0]);\nsolver(#{ tolerance: 1e-6, max_iterations: 12.0 });\noutput(#{ every: 2 });");
        let scene = load_scene(&inline_script("displace", &text), &[]).unwrap();
        // quadratic B-splines on 10 cells: 12 nodes, the last at x = 10
        assert_eq!(
            scene.constraints,
            [
                NodeConstraint {
                    node: 0,
                    component: 0,
                    value: 0.0
                },
                NodeConstraint {
                    node: 11,
                    component: 0,
                    value: -1.0
                },
            ]
        );
        assert_eq!(scene.load_factors, [0.5, 1.0, 1.5]);
        assert_eq!(
            scene.solver,
            SolverSpec {
                tolerance: 1e-6,
                max_iterations: 12,
                max_step_cuts: 8,
                ghost_penalty: 0.0,
            }
        );
        assert_eq!(scene.output.every, 2);
        assert_eq!(scene.body_force, None);
    }

    #[test]
    fn polygons_seed_inside_and_are_checked() {
        let text = "grid(#{ lower: [0.0, 0.0], upper: [4.0, 4.0], cells: [4, 4], basis: \"linear\" });\nconst m = material(#{ name: \"m\", E: 1e6, nu: 0.0, density: 1.0 });\nbody(#{ name: \"wedge\", material: m, region: polygon([[0.0, 0.0], [4.0, 0.0], [0, 4]]), ppc: 2 });\nfix(|x| x[1] == 0.0);\nload_steps(1);\n";
        let scene = load_scene(&inline_script("polygon", text), &[]).unwrap();
        let points = &scene.bodies[0].points;
        // lattice points with x + y < 4 (none lies on the hypotenuse): 8 x 8 lattice, spacing
        // 0.5 from 0.25: pairs (i, j) with i + j < 7, i.e. 28
        assert_eq!(points.len(), 28);
        assert!(points.iter().all(|p| p.position[0] + p.position[1] < 4.0));
        // fix(|x| ..) fixes every component of the 5 bottom nodes
        assert_eq!(scene.constraints.len(), 10);

        let error = failure("polygon_3d", &text.replace("[0, 4]]", "[0, 4, 1]]"));
        assert_eq!(error.line, Some(3), "{error}");
        assert!(error.message.contains("must have 2 coordinates"), "{error}");
        let error = failure("polygon_out", &text.replace("[0, 4]]", "[0, 5]]"));
        assert!(error.message.contains("not inside the grid"), "{error}");
        let error = failure("polygon_flat", &text.replace("[0, 4]]", "[2, 0]]"));
        assert!(error.message.contains("enclose no area"), "{error}");
    }

    #[test]
    fn several_bodies_keep_their_materials_and_order() {
        let text = "grid(#{ lower: [0.0, 0.0], upper: [2.0, 4.0], cells: [2, 4], basis: \"bspline\", order: 2 });\nconst soft = material(#{ name: \"soft\", E: 1e3, nu: 0.2, density: 1.0 });\nconst hard = material(#{ name: \"hard\", E: 1e6, nu: 0.3, density: 3.0 });\nbody(#{ name: \"base\", material: hard, region: box([0.0, 0.0], [2.0, 2.0]), ppc: 2 });\nbody(#{ name: \"top\", material: soft, region: |x| x[1] > 2.0 && x[1] < 3.0 && x[0] > 0.0 && x[0] < 2.0, ppc: [1, 3] });\nfix(|x| x[1] == 0.0);\nload_steps(1);\n";
        let scene = load_scene(&inline_script("bodies", text), &[]).unwrap();
        assert_eq!(scene.materials.len(), 2);
        assert_eq!(scene.bodies.len(), 2);
        assert_eq!((scene.bodies[0].material, scene.bodies[1].material), (1, 0));
        assert_eq!(scene.bodies[0].points.len(), 2 * 2 * 4);
        assert_eq!(scene.bodies[1].points.len(), 2 * 3);
        assert_close(total_volume(&scene), 4.0 + 2.0);
        let error = failure(
            "same_body",
            &text.replace("name: \"top\"", "name: \"base\""),
        );
        assert_eq!(error.line, Some(5), "{error}");
        assert!(
            error.message.contains("already declared at line 4"),
            "{error}"
        );
    }

    #[test]
    fn load_schedules_from_functions_and_phases() {
        let function = scene_1d_with("load_steps", "load_factors(4, |k| (k / 4) ** 2);");
        let scene = load_scene(&inline_script("function", &function), &[]).unwrap();
        assert_eq!(scene.load_factors, [1.0 / 16.0, 0.25, 9.0 / 16.0, 1.0]);
        let function = scene_1d_with(
            "load_steps",
            "let n = 4;\nload_factors(n, |k| if k <= 2 { k / n } else { 0.5 });",
        );
        let scene = load_scene(&inline_script("function_if", &function), &[]).unwrap();
        assert_eq!(scene.load_factors, [0.25, 0.5, 0.5, 0.5]);

        let phases = scene_1d_with(
            "load_steps",
            "load_phases([#{ to: 1.0, steps: 4 }, #{ to: 1, steps: 2 }, #{ to: -0.5, steps: 3 }]);",
        );
        let scene = load_scene(&inline_script("phases", &phases), &[]).unwrap();
        assert_eq!(
            scene.load_factors,
            [0.25, 0.5, 0.75, 1.0, 1.0, 1.0, 0.5, 0.0, -0.5]
        );

        let error = failure(
            "function_error",
            &scene_1d_with(
                "load_steps",
                "load_factors(3, |k| {\n  if k == 2 { \"two\" } else { 1.0 }\n});",
            ),
        );
        assert_eq!(error.line, Some(6), "{error}");
        assert!(
            error
                .message
                .contains("load factor function of load_factors(...) at line 6 must be a number, got string \"two\" for step k = 2"),
            "{error}"
        );
        let error = failure(
            "function_runtime",
            &scene_1d_with(
                "load_steps",
                "load_factors(3, |k| {\n  let a = [1.0];\n  a[k.to_int()]\n});",
            ),
        );
        assert_eq!(error.line, Some(8), "{error}");
        assert!(error.message.contains("out of bounds"), "{error}");
        let error = failure(
            "phase_key",
            &scene_1d_with("load_steps", "load_phases([#{ to: 1.0, step: 4 }]);"),
        );
        assert!(error.message.contains("did you mean 'steps'"), "{error}");
        let error = failure(
            "two_schedules",
            &format!(
                "{}\nload_phases([#{{ to: 1.0, steps: 4 }}]);",
                scene_1d_with("#", "")
            ),
        );
        assert!(error.message.contains("already set at line 6"), "{error}");
    }

    #[test]
    fn output_control_is_validated() {
        let text = format!(
            "{}\noutput(#{{ steps: [1, 2], fields: [\"displacement\", \"cauchy_stress\"], grid: false }});",
            scene_1d_with("#", "")
        );
        let scene = load_scene(&inline_script("output", &text), &[]).unwrap();
        assert_eq!(scene.output.steps, Some(vec![1, 2]));
        assert_eq!(
            scene.output.fields,
            Some(vec![
                "displacement".to_string(),
                "cauchy_stress".to_string()
            ])
        );
        assert!(!scene.output.grid);
        let error = failure("bad_field", &text.replace("\"displacement\"", "\"stress\""));
        assert_eq!(error.line, Some(7), "{error}");
        assert!(
            error
                .message
                .contains("unknown particle field \"stress\"; the fields are: reference_position"),
            "{error}"
        );
        let error = failure(
            "every_and_steps",
            &text.replace("steps: [1, 2]", "every: 2, steps: [1]"),
        );
        assert!(
            error.message.contains("'every' or 'steps', not both"),
            "{error}"
        );
    }

    #[test]
    fn runtime_errors_in_point_selectors_point_inside_the_closure() {
        let text = scene_1d_with(
            "fix",
            "fix(|x| x[0] == 0.0);\npoint_load(|x| {\n  x[1] > 2.0\n}, [1.0]);",
        );
        let error = failure("selector_error", &text);
        assert_eq!(error.line, Some(7), "{error}");
        assert!(
            error.message.contains("out of bounds")
                && error
                    .message
                    .contains("point selector of point_load(...) at line 6"),
            "{error}"
        );
        let text = scene_1d_with(
            "fix",
            "fix(|x| x[0] == 0.0);\npoint_load_total(|x| 1.0, [1.0]);",
        );
        let error = failure("selector_not_bool", &text);
        assert_eq!(error.line, Some(6), "{error}");
        assert!(
            error
                .message
                .contains("must return true or false, got float 1.0"),
            "{error}"
        );
    }
}
