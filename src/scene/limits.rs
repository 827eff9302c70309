//! Limits that keep a scene from running forever or eating the machine, checked before anything
//! big is allocated.
//!
//! | limit | default | checked |
//! |---|---|---|
//! | `operations` | 50 000 000 | Rhai operations per evaluation (the script's top level, and each call of a predicate or load function) |
//! | `string` | 10 000 000 | bytes of one script string |
//! | `array` | 1 000 000 | items of one script array |
//! | `map` | 10 000 | entries of one script map |
//! | `depth` | 64 | nested script function calls |
//! | `seconds` | 60 | wall time of the whole scene evaluation (script, predicates, load functions) |
//! | `order` | 20 | basis order of `grid(...)` |
//! | `support` | 10 000 | grid functions nonzero at a point, `(order + 1)^D` |
//! | `points` | 10 000 000 | seeding positions of one body (grid cells × ppc^D) |
//! | `memory` | physical memory, in MB | the estimate of [`memory_estimate`] for the resolved scene |
//!
//! Every limit is raised (or lowered) from the command line with `--limit NAME=VALUE`; each
//! message says which limit was hit, how big the scene would be and how to raise it. `import`
//! is confined to the scene's own folder ([`ConfinedResolver`]). The time limit backs up the
//! others: Rhai checks the size of a map or array by walking it, so a loop growing one item at
//! a time slows down quadratically long before the operation limit.
//!
//! Rhai does not check a map's size when an index assignment adds a key (`m[k] = v` checks the
//! new value, not the map), so the map limit is also checked where the script reads a variable
//! ([`check_map_size`], through `Engine::on_var`): a loop adding keys one by one reads its map
//! on every turn and ends one key past the limit, at the line that reads it. The check counts
//! the entries of the map and of the maps nested in it (as Rhai's own size check does), not
//! those inside arrays; it costs a scope lookup per variable read.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rhai::module_resolvers::FileModuleResolver;
use rhai::{Dynamic, Engine, EvalAltResult, Map, Module, ModuleResolver, Position, Shared};

/// The value a script ends with when it runs out of time.
pub const TIME_LIMIT: &str = "the time limit";

/// The limits of one scene (see the module docs for their meaning and defaults).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneLimits {
    pub operations: u64,
    pub string: usize,
    pub array: usize,
    pub map: usize,
    pub depth: usize,
    pub seconds: u64,
    pub order: usize,
    pub support: usize,
    pub points: usize,
    /// Megabytes.
    pub memory: usize,
}

impl Default for SceneLimits {
    fn default() -> Self {
        Self {
            operations: 50_000_000,
            string: 10_000_000,
            array: 1_000_000,
            map: 10_000,
            depth: 64,
            seconds: 60,
            order: 20,
            support: 10_000,
            points: 10_000_000,
            memory: physical_memory_mb().unwrap_or(16 * 1024),
        }
    }
}

impl SceneLimits {
    /// The names `--limit` accepts.
    pub const NAMES: [&'static str; 10] = [
        "operations",
        "string",
        "array",
        "map",
        "depth",
        "seconds",
        "order",
        "support",
        "points",
        "memory",
    ];

    /// Sets one limit from `NAME=VALUE` (a positive whole number; `memory` in MB).
    pub fn set(&mut self, assignment: &str) -> Result<(), String> {
        let (name, value) = assignment
            .split_once('=')
            .map(|(n, v)| (n.trim(), v.trim()))
            .ok_or_else(|| format!("--limit expects NAME=VALUE, got '{assignment}'"))?;
        let number: u64 = value
            .replace('_', "")
            .parse()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| {
                format!("--limit {name}={value}: the value must be a positive whole number")
            })?;
        let size = usize::try_from(number).unwrap_or(usize::MAX);
        match name {
            "operations" => self.operations = number,
            "string" => self.string = size,
            "array" => self.array = size,
            "map" => self.map = size,
            "depth" => self.depth = size,
            "seconds" => self.seconds = number,
            "order" => self.order = size,
            "support" => self.support = size,
            "points" => self.points = size,
            "memory" => self.memory = size,
            _ => {
                return Err(format!(
                    "--limit {name}: no such limit; the limits are {}",
                    Self::NAMES.join(", ")
                ));
            }
        }
        Ok(())
    }

    /// `--limit` assignments applied to the defaults.
    pub fn from_assignments(assignments: &[String]) -> Result<Self, String> {
        let mut limits = Self::default();
        for assignment in assignments {
            limits.set(assignment)?;
        }
        Ok(limits)
    }

    /// Puts the script limits on `engine` (the time limit counts from now), confines `import`
    /// to `folder`, and sends the script's `print` and `debug` to stderr (where a closed
    /// stream cannot stop the program).
    pub fn apply(&self, engine: &mut Engine, folder: &Path) {
        let deadline = Instant::now() + Duration::from_secs(self.seconds);
        engine.on_progress(move |operations| {
            (operations % 1024 == 0 && Instant::now() > deadline).then(|| Dynamic::from(TIME_LIMIT))
        });
        engine.on_print(|text| {
            let _ = writeln!(std::io::stderr(), "{text}");
        });
        engine.on_debug(|text, _, at| {
            let _ = writeln!(std::io::stderr(), "{at:?}: {text}");
        });
        engine.set_max_operations(self.operations);
        engine.set_max_string_size(self.string);
        engine.set_max_array_size(self.array);
        engine.set_max_map_size(self.map);
        let map_limit = self.map;
        // `on_var` is marked deprecated only as "volatile" (Rhai's note: "This API is NOT
        // deprecated"); returning `None` leaves the variable to the normal lookup.
        #[allow(deprecated)]
        engine.on_var(move |name, _, context| {
            check_map_size(context.scope().get(name), map_limit).map(|()| None)
        });
        engine.set_max_call_levels(self.depth);
        engine.set_module_resolver(ConfinedResolver::new(folder));
    }

    /// Checks the basis order and support size of a grid of dimension `dim`.
    pub fn check_order(&self, order: usize, dim: usize) -> Result<(), String> {
        if order > self.order {
            return Err(format!(
                "grid(...): basis order {order} is above the limit of {}; --limit order={order} raises it (the support of a point is (order + 1)^D grid functions)",
                self.order
            ));
        }
        let support = support_size(order, dim);
        if support > self.support {
            return Err(format!(
                "grid(...): order {order} in {dim}D gives every point {support} grid functions, above the limit of {}; --limit support={support} raises it",
                self.support
            ));
        }
        Ok(())
    }

    /// Checks the seeding positions of one body (grid cells × ppc^D).
    pub fn check_points(&self, candidates: usize) -> Result<(), String> {
        if candidates > self.points {
            return Err(format!(
                "the grid and ppc give {candidates} seeding positions, above the limit of {} points; use fewer cells or points per cell, or raise the limit with --limit points={candidates}",
                self.points
            ));
        }
        Ok(())
    }

    /// Checks the memory estimate of a scene of `points` material points and `nodes` grid
    /// nodes in dimension `dim` with basis order `order`.
    pub fn check_memory(
        &self,
        dim: usize,
        order: usize,
        points: usize,
        nodes: usize,
    ) -> Result<(), String> {
        let megabytes = memory_estimate(dim, order, points, nodes) / (1 << 20);
        if megabytes > self.memory as u128 {
            return Err(format!(
                "the scene would need about {megabytes} MB ({points} points, {nodes} grid nodes, order {order} in {dim}D), more than the limit of {} MB; use fewer points or cells, or raise the limit with --limit memory={megabytes}",
                self.memory
            ));
        }
        Ok(())
    }
}

/// Refuses a variable's value that is a map of more than `limit` entries (its own and those of
/// the maps nested in it), with the error Rhai gives when its own map size check fails.
fn check_map_size(value: Option<&Dynamic>, limit: usize) -> Result<(), Box<EvalAltResult>> {
    match value {
        Some(value) if map_entries(value, limit) > limit => Err(EvalAltResult::ErrorDataTooLarge(
            "Size of object map".to_string(),
            Position::NONE,
        )
        .into()),
        _ => Ok(()),
    }
}

/// Entries of `value` if it is a map, counting the maps nested in it; stops counting past
/// `limit`.
fn map_entries(value: &Dynamic, limit: usize) -> usize {
    let Some(map) = value.read_lock::<Map>() else {
        return 0;
    };
    let mut entries = map.len();
    for nested in map.values() {
        if entries > limit {
            break;
        }
        entries += map_entries(nested, limit - entries);
    }
    entries
}

/// Grid functions nonzero at a point of a basis of order `order` in dimension `dim`,
/// saturating.
pub fn support_size(order: usize, dim: usize) -> usize {
    (0..dim).fold(1usize, |size, _| {
        size.saturating_mul(order.saturating_add(1))
    })
}

/// A lower estimate of the bytes a run needs: per point its state (≈ 400 bytes) and its
/// support's weights and gradients (`(order + 1)^D` × (index, value, D gradient components));
/// per grid node its fields (≈ 20 D numbers) and its `D` rows of the stiffness matrix with
/// `D (2 order + 1)^D` entries each (value and index), doubled for the factorisation. The
/// factorisation's fill-in makes the real figure larger in 2D and 3D.
pub fn memory_estimate(dim: usize, order: usize, points: usize, nodes: usize) -> u128 {
    let (dim, order, points, nodes) = (dim as u128, order as u128, points as u128, nodes as u128);
    let support = (order + 1).pow(dim as u32);
    let per_point = 400 + support * (8 + 8 + 8 * dim);
    let coupled = (2 * order + 1).pow(dim as u32) * dim;
    let per_node = 20 * dim * 8 + dim * coupled * 12 * 2;
    points * per_point + nodes * per_node
}

/// `MemTotal` of `/proc/meminfo`, in MB (Linux only).
fn physical_memory_mb() -> Option<usize> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kilobytes: usize = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kilobytes / 1024)
}

/// `import "name"` resolved only inside the scene's folder (`name.rhai` there or below).
pub struct ConfinedResolver {
    folder: PathBuf,
    files: FileModuleResolver,
}

impl ConfinedResolver {
    pub fn new(folder: &Path) -> Self {
        let folder = folder
            .canonicalize()
            .unwrap_or_else(|_| folder.to_path_buf());
        Self {
            files: FileModuleResolver::new_with_path(&folder),
            folder,
        }
    }
}

impl ModuleResolver for ConfinedResolver {
    fn resolve(
        &self,
        engine: &Engine,
        source: Option<&str>,
        path: &str,
        pos: Position,
    ) -> Result<Shared<Module>, Box<EvalAltResult>> {
        let file = self.folder.join(format!("{path}.rhai"));
        let inside = file
            .canonicalize()
            .ok()
            .filter(|real| real.starts_with(&self.folder));
        let Some(real) = inside else {
            return Err(EvalAltResult::ErrorRuntime(
                format!(
                    "import \"{path}\": a scene may import only .rhai files in its own folder {} (no such file there, or it lies outside)",
                    self.folder.display()
                )
                .into(),
                pos,
            )
            .into());
        };
        let stem = real.with_extension("");
        self.files
            .resolve(engine, source, &stem.to_string_lossy(), pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_are_set_by_name_and_bad_assignments_are_refused() {
        let mut limits = SceneLimits::default();
        limits.set("operations=1000").unwrap();
        limits.set("order = 4").unwrap();
        assert_eq!(limits.operations, 1000);
        assert_eq!(limits.order, 4);
        assert!(
            limits
                .set("order=0")
                .unwrap_err()
                .contains("positive whole")
        );
        assert!(limits.set("speed=3").unwrap_err().contains("no such limit"));
        assert!(limits.set("order").unwrap_err().contains("NAME=VALUE"));
    }

    #[test]
    fn support_and_memory_grow_with_order_and_dimension() {
        assert_eq!(support_size(3, 2), 16);
        assert_eq!(support_size(usize::MAX, 3), usize::MAX);
        let limits = SceneLimits::default();
        assert!(limits.check_order(60, 3).is_err());
        assert!(limits.check_order(3, 3).is_ok());
        // one point of order 1 in 1D: 400 + 2 (8 + 8 + 8) bytes
        assert_eq!(memory_estimate(1, 1, 1, 0), 448);
        assert!(memory_estimate(3, 3, 1000, 1000) > memory_estimate(2, 3, 1000, 1000));
    }
}
