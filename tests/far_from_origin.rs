//! Coordinates far from the origin: a scene moved by 1e6 along every axis gives the same
//! stresses, point by point, as the scene at the origin (to 1e-7 of the largest stress); a
//! scene moved so far that its cells are not resolved in double precision is refused with
//! the axis and the grid line, instead of running to wrong stresses.

use std::path::PathBuf;

use impm::components::{PointId, Trial};
use impm::run::{Simulation, load_scene};

mod common;

/// The 2D self-weight column of `scripts/column_2d.rhai` (coarser), placed at `shift` along
/// both axes; every coordinate of the scene is written relative to `shift`.
const SHIFTED_COLUMN: &str = r#"let shift = 0.0;
let basis = "bspline";
let order = 3;
let ppc = 4;
const height = 50.0;
const width = 5.0;
const soil = material(#{ name: "column", E: 1.0e6, nu: 0.0, density: 1.0 });
grid(#{ lower: [shift, shift], upper: [shift + width, shift + height], cells: [1, 10],
        basis: basis, order: order });
body(#{ name: "column", material: soil, region: box([shift, shift], [shift + width, shift + height]), ppc: ppc });
body_force([0.0, -800.0]);
fix(|x| x[1] == shift, [1]);
fix(|x| x[0] == shift || x[0] == shift + width, [0]);
traction(#{ on: [[shift, shift + height], [shift + width, shift + height]], traction: [0.0, -2000.0], per_cell: 3 });
load_steps(4);
"#;

/// The scene written into a folder of the test's own (`test`): the tests run in parallel and
/// each clears its folder first, so a shared one could vanish under another test.
fn scene_file(test: &str) -> PathBuf {
    let dir = common::temp_dir("far", &format!("scene-{test}"));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("shifted_column.rhai");
    std::fs::write(&path, SHIFTED_COLUMN).unwrap();
    path
}

/// The Kirchhoff stresses of every point (by point id) after the last step.
fn final_stresses(scene: &std::path::Path, set: &[(&str, &str)]) -> Vec<[f64; 3]> {
    let spec = load_scene(scene, &common::overrides(set)).unwrap_or_else(|e| panic!("{e}"));
    let tag: String = set.iter().map(|(n, v)| format!("{n}{v}")).collect();
    let dir = common::temp_dir("far", &tag);
    let mut sim = Simulation::<2>::new(&spec, &dir).unwrap_or_else(|e| panic!("{e}"));
    sim.run(|_| {}).unwrap_or_else(|e| panic!("{set:?}: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    let mut stresses: Vec<(u32, [f64; 3])> = sim
        .world
        .query::<(&PointId, &Trial<2>)>()
        .iter(&sim.world)
        .map(|(id, trial)| {
            let tau = trial.0.kirchhoff;
            (id.0, [tau[(0, 0)], tau[(1, 1)], tau[(0, 1)]])
        })
        .collect();
    stresses.sort_by_key(|&(id, _)| id);
    stresses.into_iter().map(|(_, s)| s).collect()
}

/// max |σ_shifted - σ_origin| / max |σ_origin| over every point and component.
fn relative_difference(origin: &[[f64; 3]], shifted: &[[f64; 3]]) -> f64 {
    assert_eq!(origin.len(), shifted.len(), "same points");
    let scale = origin.iter().flatten().fold(0.0_f64, |m, s| m.max(s.abs()));
    assert!(scale > 0.0, "the column is stressed");
    let diff = origin
        .iter()
        .flatten()
        .zip(shifted.iter().flatten())
        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    diff / scale
}

#[test]
fn a_scene_moved_by_a_million_gives_the_same_stresses() {
    let scene = scene_file("moved");
    let bases = [
        ("bspline", "3", "4"),
        ("gimp", "1", "2"),
        ("cpdi", "1", "2"),
        ("linear", "1", "1"),
    ];
    for (basis, order, ppc) in bases {
        let set = |shift| {
            vec![
                ("basis", basis),
                ("order", order),
                ("ppc", ppc),
                ("shift", shift),
            ]
        };
        let origin = final_stresses(&scene, &set("0.0"));
        let shifted = final_stresses(&scene, &set("1.0e6"));
        let difference = relative_difference(&origin, &shifted);
        eprintln!("{basis}: moved by 1e6, the stresses differ by {difference:.2e} of the largest");
        assert!(
            difference < 1e-7,
            "{basis}: stresses differ by {difference:e} of the largest"
        );
    }
}

/// Farther out the round-off grows with the spacing of doubles at the scene, `ulp(x)`,
/// relative to the cell size h = 5: the difference stays within a small multiple of
/// `ulp(x) / h` up to the farthest grid the scene accepts.
#[test]
fn round_off_far_out_stays_proportional_to_the_spacing_of_doubles() {
    let scene = scene_file("round_off");
    let set = |shift| vec![("shift", shift)];
    let origin = final_stresses(&scene, &set("0.0"));
    for shift in ["1.0e8", "1.0e10"] {
        let shifted = final_stresses(&scene, &set(shift));
        let difference = relative_difference(&origin, &shifted);
        let far: f64 = shift.parse::<f64>().unwrap() + 50.0;
        let bound = 10.0 * impm::basis::axis::spacing_of_doubles_at(far) / 5.0;
        eprintln!(
            "moved by {shift}: the stresses differ by {difference:.2e} of the largest (bound {bound:.1e})"
        );
        assert!(
            difference < bound,
            "moved by {shift}: {difference:e} > {bound:e}"
        );
    }
}

/// A grid whose cells are not resolved at its position (the issue's grid at 1e16, where
/// doubles are 2 apart and the cells 5 wide) is refused at the `grid(...)` line, naming the
/// axis, the grid line and what to do; it used to run to exit 0 with wrong stresses.
#[test]
fn a_grid_too_far_out_for_its_cells_is_refused_with_the_grid_line() {
    let scene = scene_file("refused");
    for shift in ["1.0e11", "1.0e16"] {
        let error = load_scene(&scene, &common::overrides(&[("shift", shift)]))
            .err()
            .unwrap_or_else(|| panic!("a grid at {shift} is refused"))
            .to_string();
        for fragment in [
            "shifted_column.rhai:8",
            "grid line 1 of axis 0",
            "double precision resolves only",
            "Place the scene near the origin",
        ] {
            assert!(error.contains(fragment), "{shift}: {fragment:?} in {error}");
        }
    }
}
