//! Helpers shared by the integration tests that run the shipped scenes.
#![allow(dead_code)] // each test crate uses its own subset

use std::path::{Path, PathBuf};

use impm::scene::load_scene;
use impm::simulation::Simulation;

/// A scene shipped under `scripts/`.
pub fn shipped_scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts")
        .join(name)
}

/// A fresh (removed, not yet created) folder under the system's temporary folder.
pub fn temp_dir(prefix: &str, tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("impm-{prefix}-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// `--set` style overrides from pairs.
pub fn overrides(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|(n, v)| (n.to_string(), v.to_string()))
        .collect()
}

/// Runs a shipped scene with overrides to its last step (panicking with the solver's message
/// if it fails) and removes its output; returns the finished simulation.
pub fn run_shipped<const D: usize>(script: &str, set: &[(&str, &str)]) -> Simulation<D> {
    let spec =
        load_scene(&shipped_scene(script), &overrides(set)).unwrap_or_else(|e| panic!("{e}"));
    let tag: String = set.iter().map(|(n, v)| format!("{n}{v}")).collect();
    let dir = temp_dir(script, &tag);
    let mut sim = Simulation::<D>::new(&spec, &dir).unwrap();
    sim.run(|_| {})
        .unwrap_or_else(|e| panic!("{script} {set:?}: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    sim
}
