//! Loads and boundary conditions of the scene API, solved end to end and compared with exact
//! solutions or with invariants (resultants, equilibrium of reactions).

use std::path::{Path, PathBuf};

use impm::components::Position;
use impm::output::read_vtu;
use impm::scene::{SceneSpec, load_scene};
use impm::simulation::Simulation;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("impm-loads-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Loads a scene written inline.
fn scene(dir: &Path, name: &str, text: &str) -> SceneSpec {
    let path = dir.join(format!("{name}.rhai"));
    std::fs::write(&path, text).unwrap();
    load_scene(&path, &[]).unwrap_or_else(|e| panic!("{e}"))
}

/// Sum of a 3-component node field over the nodes `keep` accepts.
fn node_sum(file: &Path, field: &str, keep: impl Fn(usize, &[f64]) -> bool) -> [f64; 3] {
    let nodes = read_vtu(file).unwrap();
    let (_, fixed) = nodes.point_field("fixed").unwrap();
    let (components, values) = nodes.point_field(field).unwrap();
    assert_eq!(components, 3);
    let mut sum = [0.0; 3];
    for (node, value) in values.chunks(3).enumerate() {
        if keep(node, &fixed[3 * node..3 * node + 3]) {
            for c in 0..3 {
                sum[c] += value[c];
            }
        }
    }
    sum
}

/// 1D bar with linear (hat) basis, fixed at x = 0, a point load P on the point at x = 9.75 (in
/// the last cell). With hat functions every cell e has one F, its points integrate the internal
/// force as σ_e V_e / h (V_e = the volume its points carry at the start of the step, h = cell
/// size), and equilibrium at the nodes gives exactly: σ_e = λ P h / V_e in every cell left of the
/// loaded one, and σ_e = λ P N_10(x_p) h / V_e in the loaded cell, where N_10(x_p) = x_p − 9 is
/// the share of the load on the end node at the loaded point's start-of-step position. In step 1
/// V_e = h; in step 2 the points carry the stretched volume J V0 (the MPM quadrature), which
/// the expected value must include. Checked over two steps, so λ scaling and the moving point
/// count.
#[test]
fn point_load_on_a_bar_gives_the_exact_stresses() {
    use impm::components::{PointId, ReferencePosition, Volume};
    let dir = temp_dir("bar");
    let spec = scene(
        &dir,
        "bar",
        r#"
grid(#{ lower: [0.0], upper: [10.0], cells: [10], basis: "linear" });
const m = material(#{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 });
body(#{ name: "bar", material: m, region: box([0.0], [10.0]), ppc: 2 });
fix(|x| x[0] == 0.0, [0]);
point_load(|x| x[0] > 9.7, [100.0]);
load_steps(2);
"#,
    );
    assert_eq!(spec.point_loads.len(), 1);
    assert_eq!(spec.point_loads[0].point, 19);
    let mut sim = Simulation::<1>::new(&spec, &dir.join("out")).unwrap();
    let force = 100.0;
    for (step, lambda) in [(1, 0.5), (2, 1.0)] {
        // start of the step: each point's cell (by reference position: no point crosses a cell
        // here, which the cell of its current position confirms), the cells' volumes, the
        // loaded point's position
        let mut cell_volume = [0.0; 10];
        let mut loaded_x = f64::NAN;
        let mut q = sim
            .world
            .query::<(&PointId, &Position<1>, &ReferencePosition<1>, &Volume)>();
        for (id, x, reference, volume) in q.iter(&sim.world) {
            let cell = reference.0[0].floor() as usize;
            assert_eq!(x.0[0].floor() as usize, cell, "no cell crossing");
            cell_volume[cell] += volume.0;
            if id.0 == 19 {
                loaded_x = x.0[0];
            }
        }
        sim.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
        for (reference, sigma) in sim.stress_profile(0) {
            let cell = reference.floor() as usize;
            let share = if cell < 9 { 1.0 } else { loaded_x - 9.0 };
            let expected = lambda * force * share / cell_volume[cell];
            assert!(
                (sigma - expected).abs() < 1e-6 * force,
                "step {step}: point at X = {reference}: σ = {sigma}, expected {expected}"
            );
        }
    }
}

/// 2D block fixed at its base with a total point load shared over its top row of points: the
/// external force on the grid sums to λ P (partition of unity) and the internal forces at the
/// fixed nodes (the reactions the supports take) sum to −λ P: Σ_i f_int,i = 0 (the basis
/// gradients sum to zero) and f_int = f_ext at the free nodes. At every step of a non-uniform
/// schedule, including unloading.
#[test]
fn point_load_total_is_balanced_by_the_reactions() {
    let dir = temp_dir("block");
    let spec = scene(
        &dir,
        "block",
        r#"
grid(#{ lower: [0.0, 0.0], upper: [4.0, 6.0], cells: [4, 6], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1.0e4, nu: 0.3, density: 1.0 });
body(#{ name: "block", material: m, region: box([1.0, 0.0], [3.0, 4.0]), ppc: 2 });
fix(|x| x[1] == 0.0, [0, 1]);
point_load_total(|x| x[1] > 3.7, [30.0, -50.0]);
load_factors([0.25, 1.0, 0.5]);
"#,
    );
    // the top row of points: 2 cells x 2 points across
    assert_eq!(spec.point_loads.len(), 4);
    for load in &spec.point_loads {
        assert_eq!(load.force, [7.5, -12.5]);
    }
    let out = dir.join("out");
    let mut sim = Simulation::<2>::new(&spec, &out).unwrap();
    sim.run(|_| {}).unwrap();
    for (step, lambda) in [(1, 0.25), (2, 1.0), (3, 0.5)] {
        let file = out.join(format!("nodes_{step:04}.vtu"));
        let applied = node_sum(&file, "external_force", |_, _| true);
        assert!((applied[0] - 30.0 * lambda).abs() < 1e-9, "{applied:?}");
        assert!((applied[1] + 50.0 * lambda).abs() < 1e-9, "{applied:?}");
        let reaction = node_sum(&file, "internal_force", |_, fixed| fixed[1] == 1.0);
        let tolerance = 1e-6 * 50.0;
        assert!(
            (reaction[0] + 30.0 * lambda).abs() < tolerance
                && (reaction[1] - 50.0 * lambda).abs() < tolerance,
            "step {step}: reaction {reaction:?}, expected −λP = {:?}",
            [-30.0 * lambda, 50.0 * lambda]
        );
    }
}

#[test]
fn point_load_selecting_no_point_names_the_line() {
    let dir = temp_dir("none");
    let path = dir.join("none.rhai");
    std::fs::write(
        &path,
        r#"grid(#{ lower: [0.0], upper: [10.0], cells: [10], basis: "linear" });
const m = material(#{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 });
body(#{ name: "bar", material: m, region: box([0.0], [10.0]), ppc: 2 });
fix(|x| x[0] == 0.0, [0]);
point_load(|x| x[0] == 10.0, [100.0]);
load_steps(2);
"#,
    )
    .unwrap();
    let error = load_scene(&path, &[]).unwrap_err();
    assert_eq!(error.line, Some(5), "{error}");
    assert!(
        error.message.contains("selects no material point"),
        "{error}"
    );
    std::fs::write(
        &path,
        std::fs::read_to_string(&path)
            .unwrap()
            .replace("[100.0]", "[100.0, 1.0]"),
    )
    .unwrap();
    let error = load_scene(&path, &[]).unwrap_err();
    assert_eq!(error.line, Some(5), "{error}");
    assert!(
        error.message.contains("the force has 2 components"),
        "{error}"
    );
}
