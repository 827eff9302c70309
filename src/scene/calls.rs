//! The core's scene calls: the grid and its point bases, materials, regions, bodies, the
//! load-step schedule, solver and output controls, and the analytic column. Modules register
//! theirs beside these (`effects/`); all of them are read through one registry (`registry.rs`).

use rhai::{Dynamic, Position};

use super::builder::{
    BodyDeclaration, ColumnDeclaration, GridDeclaration, LoadSchedule, Located, MAX_NODES,
    MaterialHandle, PointsPerCell, Region, SceneBuilder, ensure_unset,
};
use super::geometry::polygon_double_area;
use super::options::{
    Choice, Kind, OptionSpec, Options, Range, array_of, describe, numbers, whole_number,
};
use super::registry::{CallSpec, SceneApi};
use super::schedule::{MAX_STEPS, equal_steps, phase_factors};
use super::seeding::Placement;
use super::words::{BasisWord, ModelSpec};
use super::{
    GridSpec, LineSearchMerit, LinearBackend, MaterialSpec, OutputSpec, Preconditioning, SolverSpec,
};
use crate::basis::BasisKind;
use crate::basis::axis::{MIN_CELL_RESOLUTION, unresolved_grid_line};
use crate::material::{Hencky, Material, MaterialParameters, ParameterValue};
use crate::solver::Smoother;

/// Registers the core's calls and the point bases (linear, B-spline).
pub fn register(api: &mut SceneApi) {
    api.call(grid_call())
        .call(material_call())
        .call(CallSpec::args(
            "box",
            "box([lower..], [upper..])",
            "an axis-aligned box region (bounds included)",
            2,
            |_, args, _| make_box(&args[0], &args[1]).map(Dynamic::from),
        ))
        .call(CallSpec::args(
            "polygon",
            "polygon([[x0, y0], [x1, y1], [x2, y2], ..])",
            "a 2D polygon region (at least 3 vertices, any orientation, even-odd rule)",
            1,
            |_, args, _| make_polygon(&args[0]).map(Dynamic::from),
        ))
        .call(body_call())
        .call(CallSpec::args(
            "load_steps",
            "load_steps(n)",
            "load schedule: n equal steps to load factor 1 (factors k/n, k = 1..n)",
            1,
            declare_load_steps,
        ))
        .call(CallSpec::args(
            "load_factors",
            "load_factors([f1, f2, ..])",
            "load schedule: the load factor at the end of each step",
            1,
            declare_load_factors,
        ))
        .call(CallSpec::args(
            "load_factors",
            "load_factors(n, |k| factor of step k)",
            "load schedule: n steps whose factors a function of the step number k = 1..n gives (k is a float, so `k / n` is not an integer division)",
            2,
            declare_load_function,
        ))
        .call(CallSpec::args(
            "load_phases",
            "load_phases([#{ to: 1.0, steps: 10 }, #{ to: 1.0, steps: 2 }, #{ to: 0.0, steps: 5 }])",
            "load schedule in phases from λ = 0: each goes linearly to `to` in `steps` equal steps (loading, holding: the same `to`, unloading)",
            1,
            declare_load_phases,
        ))
        .call(super::stages::stage_call())
        .call(solver_call())
        .call(output_call())
        .call(analytic_column_call());
    api.word(BasisWord {
        word: "linear",
        doc: "standard MPM: linear hat functions on the grid vertices (`order` is ignored)",
        kind: |_| Ok(BasisKind::Linear),
        seeder: None,
    })
    .word(BasisWord {
        word: "bspline",
        doc: "B-spline MPM of order q >= 1 (`order`, required): the paper's method",
        kind: bspline_kind,
        seeder: None,
    });
}

fn grid_call() -> CallSpec {
    CallSpec::options(
        "grid",
        "the background grid; its dimension (1, 2 or 3) is the length of the arrays; call once",
        vec![
            OptionSpec::required("lower", Kind::Numbers, "lower corner"),
            OptionSpec::required("upper", Kind::Numbers, "upper corner"),
            OptionSpec::required("cells", Kind::Wholes { min: 1 }, "cells per axis"),
            // the choices are the registered basis words (`SceneApi::finish`)
            OptionSpec::required(
                "basis",
                Kind::Choice(Vec::new()),
                "the basis, see **Bases**",
            ),
            OptionSpec::new(
                "order",
                Kind::Whole { min: 1, max: None },
                "B-spline order q (required for \"bspline\", ignored otherwise)",
            ),
        ],
        declare_grid,
    )
}

fn bspline_kind(options: &Options) -> Result<BasisKind, String> {
    let order = options.whole("order").ok_or_else(|| {
        "grid(...): basis \"bspline\" needs option 'order' (1 linear, 2 quadratic, 3 cubic, ...)"
            .to_string()
    })?;
    Ok(BasisKind::BSpline { order })
}

fn declare_grid(
    builder: &mut SceneBuilder,
    options: &Options,
    at: Position,
) -> Result<Dynamic, String> {
    ensure_unset(&builder.grid, "grid")?;
    let lower = options.numbers("lower").unwrap_or_default().to_vec();
    let upper = options.numbers("upper").unwrap_or_default().to_vec();
    let cells = options.wholes("cells").unwrap_or_default().to_vec();
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
    for axis in 0..dim {
        if let Some((line, coordinate, resolution)) =
            unresolved_grid_line(lower[axis], upper[axis], cells[axis])
        {
            let size = (upper[axis] - lower[axis]) / cells[axis] as f64;
            return Err(format!(
                "grid(...): grid line {line} of axis {axis} lies at {coordinate}, where double precision resolves only {resolution:e}, {:.1e} of the cell size {size}: positions inside a cell would keep fewer than {} significant digits and the stresses would be wrong. Place the scene near the origin (subtract {} from every coordinate along axis {axis}; the results do not depend on where the scene lies)",
                resolution / size,
                MIN_CELL_RESOLUTION.log10().round(),
                lower[axis]
            ));
        }
    }
    let word = options.text("basis").unwrap_or_default();
    let basis = builder
        .words
        .basis
        .iter()
        .find(|w| w.word == word)
        .ok_or_else(|| format!("grid(...): no basis {word:?}"))?
        .clone();
    let mut kind = (basis.kind)(options)?;
    for refine in &builder.words.refinements {
        kind = refine(kind, options)?;
    }
    builder.limits.check_order(kind.order(), dim)?;
    let spec = GridSpec {
        lower,
        upper,
        cells,
        basis: kind,
    };
    if spec.node_count(MAX_NODES).is_none() {
        return Err(format!(
            "grid(...): {:?} cells with basis order {} make more than {MAX_NODES} grid nodes",
            spec.cells,
            kind.order()
        ));
    }
    builder.grid = Some(Located::new(
        GridDeclaration {
            spec,
            seeder: basis.seeder,
        },
        at,
    ));
    Ok(Dynamic::UNIT)
}

fn material_call() -> CallSpec {
    CallSpec::options(
        "material",
        "a material of a model (default `\"hencky\"`) with the model's parameters (see **Material models**); returns a handle for bodies",
        vec![
            OptionSpec::required("name", Kind::Text, "a name unique among the materials"),
            OptionSpec::new(
                "model",
                Kind::Choice(Vec::new()),
                "the constitutive model, see **Material models** (default \"hencky\")",
            ),
            OptionSpec::required("density", Kind::Number(Range::Positive), "reference mass density ρ0")
                .labelled("density"),
        ],
        declare_material,
    )
    .named_by("name")
}

fn declare_material(
    builder: &mut SceneBuilder,
    options: &Options,
    at: Position,
) -> Result<Dynamic, String> {
    let name = options.text("name").unwrap_or_default().to_string();
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
    let model_word = options.text("model").unwrap_or(Hencky::MODEL);
    let model = builder
        .words
        .models
        .iter()
        .find(|m| m.model == model_word)
        .ok_or_else(|| format!("material '{name}': no model {model_word:?}"))?
        .clone();
    let mut parameters = MaterialParameters::default();
    for (key, value) in options.entries() {
        if matches!(*key, "name" | "model" | "density") {
            continue;
        }
        if !model.parameters.iter().any(|p| p.key == *key) {
            return Err(format!(
                "material '{name}': '{key}' is not a parameter of model \"{model_word}\" (its parameters: {})",
                parameter_names(&model)
            ));
        }
        let value = match value {
            super::options::OptionValue::Number(x) => ParameterValue::Number(*x),
            super::options::OptionValue::Whole(n) => ParameterValue::Number(*n as f64),
            super::options::OptionValue::Text(t) => ParameterValue::Text(t.clone()),
            super::options::OptionValue::Flag(b) => ParameterValue::Flag(*b),
            other => return Err(format!("material '{name}': '{key}' cannot be {other:?}")),
        };
        parameters.0.push((key.to_string(), value));
    }
    if let Some(missing) = model
        .parameters
        .iter()
        .find(|p| p.required && parameters.get(p.key).is_none())
    {
        return Err(format!(
            "material '{name}': model \"{model_word}\" needs parameter '{}' (its parameters: {})",
            missing.key,
            parameter_names(&model)
        ));
    }
    let stiffness =
        (model.check)(&parameters).map_err(|why| format!("material '{name}': {why}"))?;
    let index = builder.materials.len();
    builder.materials.push(Located::new(
        MaterialSpec {
            name: name.clone(),
            model: model_word.to_string(),
            parameters,
            density: options.number("density").unwrap_or_default(),
            stiffness,
        },
        at,
    ));
    Ok(Dynamic::from(MaterialHandle { index, name }))
}

fn parameter_names(model: &ModelSpec) -> String {
    model
        .parameters
        .iter()
        .map(|p| p.key)
        .collect::<Vec<_>>()
        .join(", ")
}

/// A material handle, or an error naming what was given.
pub fn material_handle(value: &Dynamic, subject: &str) -> Result<MaterialHandle, String> {
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

fn body_call() -> CallSpec {
    CallSpec::options(
        "body",
        "material points of one material in a region, `ppc` per cell per direction at cell-local `(i + 1/2) / ppc` (volume = cell volume / points per cell), kept where the region holds; the region must lie inside the grid. With `placement: \"gauss\"` the points sit at the Gauss–Legendre points of each cell, with volumes from the Gauss weights. A basis with a body-fitted mesh seeds its own points (FEM: Gauss points of the whole cells)",
        vec![
            OptionSpec::required("name", Kind::Text, "a name unique among the bodies"),
            OptionSpec::required(
                "material",
                Kind::Value { what: "m" },
                "a material returned by material(..)",
            ),
            OptionSpec::required(
                "region",
                Kind::Value {
                    what: "box(..), polygon(..) or |x| ..",
                },
                "where the body is: a box, a polygon or a predicate on the position",
            ),
            OptionSpec::required(
                "ppc",
                Kind::WholeOrWholes { min: 1 },
                "points per cell per direction",
            ),
            OptionSpec::new(
                "placement",
                Kind::Choice(vec![
                    Choice {
                        word: "uniform",
                        meaning: None,
                    },
                    Choice {
                        word: "gauss",
                        meaning: None,
                    },
                ]),
                "where the points of a cell sit (default \"uniform\")",
            ),
        ],
        declare_body,
    )
}

fn declare_body(
    builder: &mut SceneBuilder,
    options: &Options,
    at: Position,
) -> Result<Dynamic, String> {
    let name = options.text("name").unwrap_or_default().to_string();
    if let Some(previous) = builder.bodies.iter().find(|body| body.value.name == name) {
        return Err(format!(
            "body(...): a body named '{name}' was already declared{}",
            previous.line_note()
        ));
    }
    let material = material_handle(
        options.value("material").unwrap_or(&Dynamic::UNIT),
        &options.subject_of("material"),
    )?;
    let region_value = options.value("region").cloned().unwrap_or(Dynamic::UNIT);
    let region = if region_value.is::<Region>() {
        region_value.cast::<Region>()
    } else if region_value.is_fnptr() {
        Region::Predicate(super::options::function(
            &region_value,
            &options.subject_of("region"),
        )?)
    } else {
        return Err(format!(
            "{} must be box([..], [..]), polygon([..]) or a predicate |x| .. on the position, got {}",
            options.subject_of("region"),
            describe(&region_value)
        ));
    };
    let points_per_cell = match options.get("ppc") {
        Some(super::options::OptionValue::Wholes(counts)) => PointsPerCell::PerAxis(counts.clone()),
        Some(super::options::OptionValue::Whole(count)) => PointsPerCell::Uniform(*count),
        _ => PointsPerCell::Uniform(1),
    };
    let placement = match options.text("placement") {
        Some("gauss") => Placement::Gauss,
        _ => Placement::Uniform,
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
    Ok(Dynamic::UNIT)
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
    args: &[Dynamic],
    at: Position,
) -> Result<Dynamic, String> {
    ensure_no_load_schedule(builder)?;
    let steps = whole_number(&args[0], "load_steps(...): the number of steps", 1)?;
    if steps > MAX_STEPS {
        return Err(format!("load_steps(...): {steps} steps is too many"));
    }
    builder.load_schedule = Some(Located::new(LoadSchedule::Factors(equal_steps(steps)), at));
    Ok(Dynamic::UNIT)
}

fn declare_load_factors(
    builder: &mut SceneBuilder,
    args: &[Dynamic],
    at: Position,
) -> Result<Dynamic, String> {
    ensure_no_load_schedule(builder)?;
    let factors = numbers(&args[0], "load_factors(...): the load factors")?;
    if factors.is_empty() {
        return Err("load_factors(...) needs at least one load factor, got []".to_string());
    }
    builder.load_schedule = Some(Located::new(LoadSchedule::Factors(factors), at));
    Ok(Dynamic::UNIT)
}

fn declare_load_function(
    builder: &mut SceneBuilder,
    args: &[Dynamic],
    at: Position,
) -> Result<Dynamic, String> {
    ensure_no_load_schedule(builder)?;
    let steps = whole_number(&args[0], "load_factors(...): the number of steps", 1)?;
    if steps > MAX_STEPS {
        return Err(format!("load_factors(...): {steps} steps is too many"));
    }
    let function = args[1].flatten_clone();
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
    Ok(Dynamic::UNIT)
}

/// The options of one phase of `load_phases`.
fn phase_table() -> Vec<OptionSpec> {
    vec![
        OptionSpec::required(
            "to",
            Kind::Number(Range::Any),
            "load factor at the phase's end",
        ),
        OptionSpec::required("steps", Kind::Whole { min: 1, max: None }, "equal steps"),
    ]
}

fn declare_load_phases(
    builder: &mut SceneBuilder,
    args: &[Dynamic],
    at: Position,
) -> Result<Dynamic, String> {
    ensure_no_load_schedule(builder)?;
    let table = phase_table();
    let phases = array_of(
        &args[0],
        "load_phases(...): the phases",
        "option maps like #{ to: 1.0, steps: 10 }",
        |phase, _| {
            let options = Options::read("load_phases", phase, &table, None)?;
            Ok((
                options.number("to").unwrap_or_default(),
                options.whole("steps").unwrap_or(1),
            ))
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
    Ok(Dynamic::UNIT)
}

fn solver_call() -> CallSpec {
    CallSpec::options(
        "solver",
        "Newton and load-step controls (optional)",
        vec![
            OptionSpec::new(
                "tolerance",
                Kind::Number(Range::Positive),
                "convergence tolerance on the normalised out-of-balance force (default 1e-9)",
            ),
            OptionSpec::new(
                "max_iterations",
                Kind::Whole { min: 1, max: None },
                "Newton iterations per attempt (default 30)",
            ),
            OptionSpec::new(
                "max_step_cuts",
                Kind::Whole { min: 0, max: None },
                "how many times in a row a load step may be halved when Newton fails (default 8): the smallest sub-step is 2^-n of the step; each converged sub-step doubles the next, so a step may be cut more often in all",
            ),
            OptionSpec::new(
                "linear",
                Kind::Choice(vec![
                    Choice {
                        word: "direct",
                        meaning: Some("sparse Cholesky, LU where the tangent is not symmetric"),
                    },
                    Choice {
                        word: "iterative",
                        meaning: Some(
                            "preconditioned CG, BiCGSTAB where the tangent is not symmetric \
                             (relative tolerance 1e-10)",
                        ),
                    },
                    Choice {
                        word: "auto",
                        meaning: Some(
                            "by the dimension and the DOFs of each system, as measured: direct in \
                             1D, in 2D below 75 000 DOFs and in 3D below 2 000; CG with \
                             multigrid in 2D and CG with Jacobi in 3D above; an iterative solve \
                             that fails is repeated by the direct solver, which is then kept \
                             (summary.json: linear_backend says which and why)",
                        ),
                    },
                    Choice {
                        word: "petsc",
                        meaning: Some(
                            "PETSc's solvers (builds with the cargo feature `petsc` only): CG, \
                             GMRES where the tangent is not symmetric, with algebraic multigrid \
                             (GAMG) given the rigid-body modes; relative tolerance 1e-10, both \
                             changed by `petsc_options`",
                        ),
                    },
                ]),
                "backend of the linear solves (default \"auto\")",
            ),
            OptionSpec::new(
                "petsc_options",
                Kind::Text,
                "options for PETSc's options database (linear: \"petsc\"), in PETSc's \
                 command-line syntax, e.g. \"-ksp_type cg -pc_type gamg\" or \"-pc_type hypre\"; \
                 `impm run --petsc-options` adds to them and wins",
            ),
            OptionSpec::new(
                "preconditioner",
                Kind::Choice(vec![
                    Choice {
                        word: "multigrid",
                        meaning: Some(
                            "smoothed-aggregation algebraic multigrid with the rigid-body modes, \
                             one V-cycle: iterations nearly independent of the grid",
                        ),
                    },
                    Choice {
                        word: "jacobi",
                        meaning: Some(
                            "the inverse diagonal: cheap, but iterations grow with the cells \
                             along the body",
                        ),
                    },
                ]),
                "preconditioner of linear: \"iterative\" (default \"multigrid\")",
            ),
            OptionSpec::new(
                "smoother",
                Kind::Choice(vec![
                    Choice {
                        word: "chebyshev",
                        meaning: Some(
                            "a Chebyshev polynomial of degree 2 in the inverse diagonal times \
                             the tangent, before and after the coarse correction: runs on every \
                             thread",
                        ),
                    },
                    Choice {
                        word: "gauss_seidel",
                        meaning: Some(
                            "one forward and one backward Gauss-Seidel sweep: a little stronger \
                             per sweep, but on one thread",
                        ),
                    },
                ]),
                "smoother of the multigrid preconditioner (linear: \"iterative\"; default \
                 \"chebyshev\", measured faster in docs/performance.md)",
            ),
            OptionSpec::new(
                "inexact",
                Kind::Flag,
                "inexact Newton (linear: \"iterative\", or \"auto\" when it solves iteratively): each linear solve only as accurate as \
                 an Eisenstat-Walker forcing term asks, loose far from the solution and tight \
                 near it (default false)",
            ),
            OptionSpec::new(
                "line_search",
                Kind::Flag,
                "backtracking line search on the out-of-balance force (Armijo, safeguarded \
                 parabolic steps): the full Newton step is tried first and shortened only where \
                 it does not reduce ‖f_ext − f_int‖ enough or a point's state becomes \
                 inadmissible (det F ≤ 0); `merit: \"natural\"` judges the trials by the \
                 natural level function instead; summary.json counts the shortened steps \
                 (default false)",
            ),
            OptionSpec::new(
                "max_backtracks",
                Kind::Whole {
                    min: 1,
                    max: Some(50),
                },
                "most shortenings of one Newton step by the line search, after which the \
                 attempt fails and the load step is cut (default 10)",
            ),
            OptionSpec::new(
                "merit",
                Kind::Choice(vec![
                    Choice {
                        word: "residual",
                        meaning: Some(
                            "Armijo's sufficient decrease of ‖f_ext − f_int‖ (the default)",
                        ),
                    },
                    Choice {
                        word: "natural",
                        meaning: Some(
                            "Deuflhard's natural level function: the simplified Newton \
                             correction ‖K_k⁻¹ r(u_k + α δ)‖ must fall below (1 − α/4) ‖δ‖, \
                             solved with the kept factor of the step's tangent; insensitive to \
                             the tangent's scaling (a stiff penalty or a soft plastic zone) \
                             where ‖r‖ is not. Needs the direct solver and an undivided grid: \
                             elsewhere the residual test is used, with a warning",
                        ),
                    },
                ]),
                "the test a trial step of the line search must pass (line_search: true; \
                 default \"residual\")",
            ),
        ],
        |builder, options, at| {
            ensure_unset(&builder.solver, "solver")?;
            let default = SolverSpec::default();
            let solver = SolverSpec {
                tolerance: options.number("tolerance").unwrap_or(default.tolerance),
                max_iterations: options
                    .whole("max_iterations")
                    .unwrap_or(default.max_iterations),
                max_step_cuts: options
                    .whole("max_step_cuts")
                    .unwrap_or(default.max_step_cuts),
                linear: match (options.text("linear"), options.text("preconditioner")) {
                    (Some("iterative"), Some("jacobi")) => {
                        LinearBackend::Iterative(Preconditioning::Jacobi)
                    }
                    (Some("iterative"), _) => LinearBackend::Iterative(Preconditioning::Multigrid(
                        match options.text("smoother") {
                            Some("gauss_seidel") => Smoother::GaussSeidel,
                            _ => Smoother::default(),
                        },
                    )),
                    (_, Some(_)) => {
                        return Err("solver(...): 'preconditioner' applies to \
                                    linear: \"iterative\" only"
                            .to_string());
                    }
                    (Some("direct"), _) => LinearBackend::Direct,
                    (Some("petsc"), _) if cfg!(feature = "petsc") => LinearBackend::Petsc,
                    (Some("petsc"), _) => {
                        return Err(format!(
                            "solver(...): linear: \"petsc\" needs PETSc, but {}",
                            super::WITHOUT_PETSC
                        ));
                    }
                    _ => LinearBackend::Auto,
                },
                inexact: options.flag("inexact").unwrap_or(false),
                petsc_options: options.text("petsc_options").unwrap_or("").to_string(),
                line_search: options.flag("line_search").unwrap_or(false),
                max_backtracks: options
                    .whole("max_backtracks")
                    .unwrap_or(default.max_backtracks),
                merit: match options.text("merit") {
                    Some("natural") => LineSearchMerit::Natural,
                    _ => LineSearchMerit::Residual,
                },
            };
            if options.text("smoother").is_some()
                && !matches!(
                    solver.linear,
                    LinearBackend::Iterative(Preconditioning::Multigrid(_))
                )
            {
                return Err(
                    "solver(...): 'smoother' applies to linear: \"iterative\" with \
                            the multigrid preconditioner only"
                        .to_string(),
                );
            }
            for option in ["max_backtracks", "merit"] {
                if options.has(option) && !solver.line_search {
                    return Err(format!(
                        "solver(...): '{option}' applies to line_search: true only"
                    ));
                }
            }
            if options.text("petsc_options").is_some() && solver.linear != LinearBackend::Petsc {
                return Err(
                    "solver(...): 'petsc_options' applies to linear: \"petsc\" only".to_string(),
                );
            }
            if solver.inexact && solver.linear == LinearBackend::Direct {
                return Err(
                    "solver(...): 'inexact' applies to linear: \"iterative\" or \"auto\" \
                            only (a direct solve is exact)"
                        .to_string(),
                );
            }
            builder.solver = Some(Located::new(solver, at));
            Ok(Dynamic::UNIT)
        },
    )
}

fn output_call() -> CallSpec {
    CallSpec::options(
        "output",
        "what is written (optional): every n-th step or the listed steps (plus the initial state; with `every` also the last step), only the named point fields, with or without the grid and node files",
        vec![
            OptionSpec::new(
                "every",
                Kind::Whole { min: 1, max: None },
                "write every n-th step",
            ),
            OptionSpec::new(
                "steps",
                Kind::Wholes { min: 1 },
                "write exactly these steps (not with `every`)",
            ),
            OptionSpec::new(
                "fields",
                Kind::Value {
                    what: "[\"displacement\", ..]",
                },
                "the point fields to write (default: all the scene has), see **Point fields**",
            ),
            OptionSpec::new(
                "grid",
                Kind::Flag,
                "write the grid and node files (default true)",
            ),
        ],
        declare_output,
    )
}

fn declare_output(
    builder: &mut SceneBuilder,
    options: &Options,
    at: Position,
) -> Result<Dynamic, String> {
    ensure_unset(&builder.output, "output")?;
    let mut output = OutputSpec::default();
    if let Some(every) = options.whole("every") {
        output.every = every;
    }
    if let Some(steps) = options.wholes("steps") {
        if options.has("every") {
            return Err("output(...): give 'every' or 'steps', not both".to_string());
        }
        output.steps = Some(steps.to_vec());
    }
    if let Some(fields) = options.value("fields") {
        let fields = array_of(
            fields,
            &options.subject_of("fields"),
            "field names like [\"displacement\", \"cauchy_stress\"]",
            super::options::string,
        )?;
        let known: Vec<&str> = builder
            .words
            .fields
            .iter()
            .map(|field| field.name)
            .collect();
        if let Some(unknown) = fields.iter().find(|field| !known.contains(&field.as_str())) {
            return Err(format!(
                "{}: unknown particle field {unknown:?}; the fields are: {}",
                options.subject_of("fields"),
                known.join(", ")
            ));
        }
        output.fields = Some(fields);
    }
    if let Some(grid) = options.flag("grid") {
        output.grid = grid;
    }
    builder.output = Some(Located::new(output, at));
    Ok(Dynamic::UNIT)
}

fn analytic_column_call() -> CallSpec {
    CallSpec::options(
        "analytic_column",
        "declares the self-weight column solution (paper eqs. 11-14) for error reports (eq. 15, `error` in summary.json)",
        vec![
            OptionSpec::required(
                "axis",
                Kind::Whole { min: 0, max: None },
                "the column's axis",
            ),
            OptionSpec::required(
                "height",
                Kind::Number(Range::Positive),
                "its initial height L0 (base at reference coordinate 0)",
            ),
            OptionSpec::required(
                "material",
                Kind::Value { what: "m" },
                "its material (a Hencky material)",
            ),
            OptionSpec::required(
                "body_force",
                Kind::Number(Range::Any),
                "body force per unit mass along the axis at load factor 1",
            ),
        ],
        |builder, options, at| {
            ensure_unset(&builder.analytic, "analytic_column")?;
            let material = material_handle(
                options.value("material").unwrap_or(&Dynamic::UNIT),
                &options.subject_of("material"),
            )?;
            builder.analytic = Some(Located::new(
                ColumnDeclaration {
                    axis: options.whole("axis").unwrap_or_default(),
                    height: options.number("height").unwrap_or_default(),
                    material: material.index,
                    body_force: options.number("body_force").unwrap_or_default(),
                },
                at,
            ));
            Ok(Dynamic::UNIT)
        },
    )
}
