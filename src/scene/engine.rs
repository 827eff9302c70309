//! Running a scene script: the Rhai engine with every registered call (the core's and the
//! modules'), the `--set` overrides, and the resolution of what the script declared.

use std::path::Path;
use std::sync::{Arc, Mutex, PoisonError};

use rhai::{Dynamic, Engine, EvalAltResult, NativeCallContext, Position};

use super::SceneSpec;
use super::builder::{MaterialHandle, Region, Resolver, SceneBuilder};
use super::error::{SceneError, ScriptError};
use super::limits::SceneLimits;
use super::options::Options;
use super::params::{Parameter, apply_overrides, find_parameters};
use super::registry::{CallSpec, Declare, SceneApi};

/// The scene side of a module: the words it adds to the scene language and how it resolves
/// what a script declared with them into its part of the scene. Every `Plugin` is one.
pub trait SceneModule {
    /// Registers the module's calls, options, basis words, models and point fields.
    fn scene_api(&self, _api: &mut SceneApi) {}

    /// Resolves the module's declarations (after the core's parts) into its part of the scene
    /// (`Resolver::spec`'s `set_part`).
    fn resolve(&self, _scene: &mut Resolver) -> Result<(), ScriptError> {
        Ok(())
    }
}

/// The scene language of the core and `modules`.
pub fn scene_api(modules: &[&dyn SceneModule]) -> SceneApi {
    let mut api = SceneApi::default();
    super::calls::register(&mut api);
    for module in modules {
        module.scene_api(&mut api);
    }
    api.finish();
    api
}

/// Runs the scene script at `path` with `--set` overrides `(NAME, VALUE)` applied, in the
/// scene language of the core and `modules`, and returns the resolved scene. The scene name is
/// the file stem. The default [`SceneLimits`] apply.
pub fn load_scene_with(
    path: &Path,
    overrides: &[(String, String)],
    modules: &[&dyn SceneModule],
) -> Result<SceneSpec, SceneError> {
    load_scene_within(path, overrides, modules, &SceneLimits::default())
}

/// [`load_scene_with`] within `limits` (script operations and sizes, basis order, points,
/// memory): a runaway script or an oversized scene ends with the limit it hit.
pub fn load_scene_within(
    path: &Path,
    overrides: &[(String, String)],
    modules: &[&dyn SceneModule],
    limits: &SceneLimits,
) -> Result<SceneSpec, SceneError> {
    let file = path.display().to_string();
    let source = read_script(path, &file)?;
    let api = Arc::new(scene_api(modules));
    let words = Arc::new(api.words().clone());
    let mut builder = SceneBuilder::new(words.clone());
    builder.limits = *limits;
    let state: SharedBuilder = Arc::new(Mutex::new(Some(builder)));
    let mut engine = scene_engine(&state, &api);
    let folder = match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    };
    limits.apply(&mut engine, folder);
    let expected = |name: &str| api.expected(name);
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
        .map_err(|error| ScriptError::from_eval_with(error, &expected).in_file(&file))?;
    // taking the builder out closes the API: predicates run below cannot declare more
    let mut builder = state
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .take()
        .unwrap_or_else(|| SceneBuilder::new(words));
    builder.limits = *limits;
    let name = path.file_stem().map_or_else(
        || "scene".to_string(),
        |stem| stem.to_string_lossy().into_owned(),
    );
    builder
        .resolve(&name, &engine, &ast, modules)
        .map_err(|error| error.in_file(&file))
}

/// The script's parameters (top-level `let NAME = <default>;`), in source order.
pub fn scene_parameters(path: &Path) -> Result<Vec<Parameter>, SceneError> {
    let file = path.display().to_string();
    let source = read_script(path, &file)?;
    Engine::new()
        .compile(&source)
        .map_err(|error| ScriptError::from_parse(&error).in_file(&file))?;
    Ok(find_parameters(&source)
        .into_iter()
        .map(|site| site.parameter)
        .collect())
}

/// The script's text, without a UTF-8 byte-order mark (some editors write one).
fn read_script(path: &Path, file: &str) -> Result<String, SceneError> {
    let text = std::fs::read_to_string(path).map_err(|error| {
        let hint = match error.kind() {
            std::io::ErrorKind::InvalidData => " (the file is not UTF-8 text: save it as UTF-8)",
            std::io::ErrorKind::NotFound => " (check the path)",
            _ => "",
        };
        SceneError::whole_file(file, format!("cannot read the scene script: {error}{hint}"))
    })?;
    Ok(match text.strip_prefix('\u{feff}') {
        Some(rest) => rest.to_string(),
        None => text,
    })
}

type SharedBuilder = Arc<Mutex<Option<SceneBuilder>>>;

/// Runs a call's declaration on the builder with the call's position; its error message
/// becomes a script error at the call. Once the script has run (inside predicates) the
/// builder is gone: only calls that declare nothing (regions) still work.
fn with_builder(
    state: &SharedBuilder,
    api: &Arc<SceneApi>,
    context: &NativeCallContext,
    declare: impl FnOnce(&mut SceneBuilder, Position) -> Result<Dynamic, String>,
) -> Result<Dynamic, Box<EvalAltResult>> {
    let at = context.call_position();
    let mut guard = state.lock().unwrap_or_else(PoisonError::into_inner);
    let result = match guard.as_mut() {
        Some(builder) => declare(builder, at),
        None if matches!(context.fn_name(), "box" | "polygon") => {
            declare(&mut SceneBuilder::new(Arc::new(api.words().clone())), at)
        }
        None => Err(format!(
            "{}(...) cannot be called here (inside a region or node predicate the scene is already complete)",
            context.fn_name()
        )),
    };
    result.map_err(|message| EvalAltResult::ErrorRuntime(message.into(), at).into())
}

/// An engine with every call of `api` registered, declaring into `state`.
fn scene_engine(state: &SharedBuilder, api: &Arc<SceneApi>) -> Engine {
    let mut engine = Engine::new();
    engine.set_strict_variables(true);
    engine.set_fail_on_invalid_map_property(true);
    engine.register_type_with_name::<MaterialHandle>("Material");
    engine.register_type_with_name::<Region>("Region");
    for call in api.calls() {
        register_call(&mut engine, state, api, call);
    }
    engine
}

/// Registers one call with its arity; a map call reads its options by its table first and
/// keeps them for the modules (`SceneBuilder::call_options`).
fn register_call(engine: &mut Engine, state: &SharedBuilder, api: &Arc<SceneApi>, call: &CallSpec) {
    let (state, api) = (state.clone(), api.clone());
    let call = call.clone();
    let name = call.name;
    let run = move |context: NativeCallContext, args: &[Dynamic]| {
        with_builder(&state, &api, &context, |builder, at| {
            let mut located = super::builder::Located::new((), at);
            located.stage = builder.stage();
            builder.calls.push((call.name, located));
            match &call.declare {
                Declare::Options(declare) => {
                    let options = Options::read(call.name, &args[0], &call.options, call.name_key)?;
                    let result = declare(builder, &options, at)?;
                    let mut located = super::builder::Located::new(options, at);
                    located.stage = builder.stage();
                    builder.call_options.push((call.name, located));
                    Ok(result)
                }
                Declare::Args(declare) => declare(builder, args, at),
            }
        })
    };
    match call.arity {
        1 => {
            engine.register_fn(name, move |context: NativeCallContext, a: Dynamic| {
                run(context, &[a])
            });
        }
        2 => {
            engine.register_fn(
                name,
                move |context: NativeCallContext, a: Dynamic, b: Dynamic| run(context, &[a, b]),
            );
        }
        3 => {
            engine.register_fn(
                name,
                move |context: NativeCallContext, a: Dynamic, b: Dynamic, c: Dynamic| {
                    run(context, &[a, b, c])
                },
            );
        }
        _ => {
            engine.register_fn(
                name,
                move |context: NativeCallContext,
                      a: Dynamic,
                      b: Dynamic,
                      c: Dynamic,
                      d: Dynamic| { run(context, &[a, b, c, d]) },
            );
        }
    }
}
