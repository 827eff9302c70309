//! meshio (the Python mesh I/O library many post-processing scripts use) reads every `.vtu` a
//! run writes, with every field, to the last bit: a 2D scene with tractions (particles, grid,
//! nodes, traction points) and a 3D one are run, each file is read by meshio in a Python
//! process that prints its arrays as JSON (Python's float repr round-trips exactly) and compared
//! with impm's own reader. Where `python3` with meshio is missing the test prints why it is
//! skipped and passes, unless `IMPM_REQUIRE_MESHIO` is set (`.ci/run` installs meshio and sets
//! it).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use impm::output::read_vtu;
use impm::run::{load_scene, run_scene};

/// Prints `{file: {"points": [...], "point_data": {name: [...]}, "cell_data": {...}}}` for the
/// `.vtu` files named on the command line, as meshio reads them.
const READ_WITH_MESHIO: &str = r#"
import json, sys
import meshio
out = {}
for path in sys.argv[1:]:
    mesh = meshio.read(path)
    out[path] = {
        "points": mesh.points.ravel().tolist(),
        "point_data": {k: v.ravel().tolist() for k, v in mesh.point_data.items()},
        "cell_data": {k: [x for block in v for x in block.ravel().tolist()]
                      for k, v in mesh.cell_data.items()},
        "cells": sum(len(block.data) for block in mesh.cells),
    }
json.dump(out, sys.stdout)
"#;

fn meshio_available() -> bool {
    Command::new("python3")
        .args(["-c", "import meshio"])
        .output()
        .is_ok_and(|o| o.status.success())
}

fn run(scene: &str, set: &[(&str, &str)]) -> PathBuf {
    let out = common::temp_dir("meshio", scene.trim_end_matches(".rhai"));
    let spec = load_scene(&common::shipped_scene(scene), &common::overrides(set)).unwrap();
    run_scene(&spec, &out, |_| {}).unwrap();
    out
}

fn as_f64s(value: &serde_json::Value) -> Vec<f64> {
    value
        .as_array()
        .expect("a JSON array")
        .iter()
        .map(|x| x.as_f64().expect("a number"))
        .collect()
}

/// Every `.vtu` file of `out` reads the same through meshio as through impm's reader; returns
/// the number of files and of arrays compared.
fn compare_folder(out: &Path) -> (usize, usize) {
    let mut files: Vec<PathBuf> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "vtu"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no .vtu in {}", out.display());
    let output = Command::new("python3")
        .arg("-c")
        .arg(READ_WITH_MESHIO)
        .args(&files)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "meshio failed:\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let read: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let mut arrays = 0;
    for file in &files {
        let ours = read_vtu(file).unwrap();
        let theirs = &read[file.to_str().unwrap()];
        let name = file.display();
        let points: Vec<f64> = ours.points.iter().flatten().copied().collect();
        assert_eq!(as_f64s(&theirs["points"]), points, "{name}: points");
        assert_eq!(
            theirs["cells"].as_u64(),
            Some(ours.cell_count as u64),
            "{name}"
        );
        for (kind, ours) in [
            ("point_data", &ours.point_data),
            ("cell_data", &ours.cell_data),
        ] {
            let theirs = theirs[kind].as_object().unwrap();
            assert_eq!(theirs.len(), ours.len(), "{name}: {kind} arrays");
            for (field, _, values) in ours {
                let read = theirs
                    .get(field)
                    .unwrap_or_else(|| panic!("{name}: meshio lacks {kind} {field:?}"));
                assert_eq!(&as_f64s(read), values, "{name}: {kind} {field:?}");
                arrays += 1;
            }
        }
    }
    (files.len(), arrays)
}

#[test]
fn meshio_reads_every_file_and_field_of_2d_and_3d_runs() {
    if !meshio_available() {
        assert!(
            std::env::var_os("IMPM_REQUIRE_MESHIO").is_none(),
            "IMPM_REQUIRE_MESHIO is set but python3 cannot import meshio"
        );
        eprintln!("skipped: python3 with meshio is not installed (pip install meshio)");
        return;
    }
    for (scene, overrides) in [
        ("footing_traction.rhai", &[("steps", "2")][..]),
        (
            "block_3d_traction.rhai",
            &[("cells", "2"), ("steps", "1")][..],
        ),
    ] {
        let out = run(scene, overrides);
        let (files, arrays) = compare_folder(&out);
        // particles, grid and nodes of the initial state and of each step, and traction points
        assert!(files >= 6, "{scene}: only {files} files");
        assert!(arrays >= 30, "{scene}: only {arrays} arrays");
        eprintln!("{scene}: meshio read {files} files, {arrays} arrays, all equal");
        let _ = std::fs::remove_dir_all(&out);
    }
}
