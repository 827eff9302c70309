//! Loads and boundary conditions of the scene API, solved end to end and compared with exact
//! solutions or with invariants (resultants, equilibrium of reactions).

mod common;

use std::path::{Path, PathBuf};

use impm::components::Position;
use impm::effects::point_loads::PointLoads;
use impm::effects::tractions::Tractions;
use impm::output::read_vtu;
use impm::run::Simulation;
use impm::run::load_scene;
use impm::scene::SceneSpec;

fn temp_dir(name: &str) -> PathBuf {
    let dir = common::temp_dir("loads", name);
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
    assert_eq!(spec.part::<PointLoads>().unwrap().0.len(), 1);
    assert_eq!(spec.part::<PointLoads>().unwrap().0[0].point, 19);
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
    assert_eq!(spec.part::<PointLoads>().unwrap().0.len(), 4);
    for load in &spec.part::<PointLoads>().unwrap().0 {
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

/// 1D bar [0, 10] in a longer grid [0, 12] with linear basis and a traction h at its free end.
/// The traction point starts on the grid vertex x = 10 and then moves into the empty cell
/// beyond it, where its load goes to the active end node only: every cell carries exactly
/// σ_e = λ h · cell size / V_e (as for a point load, see above), and the traction point moves
/// with the end of the bar: x_s = x_p + (10 − X_p) F_p for the last material point p.
#[test]
fn traction_on_a_bar_end_gives_the_exact_stresses_and_moves_with_the_end() {
    use impm::components::{DeformationGradient, PointId, Volume};
    use impm::effects::tractions::TractionPoint;
    let dir = temp_dir("traction_bar");
    let spec = scene(
        &dir,
        "traction_bar",
        r#"
grid(#{ lower: [0.0], upper: [12.0], cells: [12], basis: "linear" });
const m = material(#{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 });
body(#{ name: "bar", material: m, region: box([0.0], [10.0]), ppc: 2 });
fix(|x| x[0] == 0.0, [0]);
traction(#{ on: [[10.0]], traction: [200.0] });
load_factors([0.25, 0.75, 1.0]);
"#,
    );
    assert_eq!(spec.part::<Tractions>().unwrap().0.len(), 1);
    assert_eq!(spec.part::<Tractions>().unwrap().0[0].area, 1.0);
    let mut sim = Simulation::<1>::new(&spec, &dir.join("out")).unwrap();
    for (step, lambda) in [(1, 0.25), (2, 0.75), (3, 1.0)] {
        // each point's cell at the start of the step, and the volume every cell holds
        let mut cell_volume = [0.0; 10];
        let mut cell_of = [0usize; 20];
        let mut q = sim.world.query::<(&PointId, &Position<1>, &Volume)>();
        for (id, x, volume) in q.iter(&sim.world) {
            let cell = x.0[0].floor() as usize;
            assert!(cell < 10, "the bar stays in its cells: strain 2 % at most");
            cell_of[id.0 as usize] = cell;
            cell_volume[cell] += volume.0;
        }
        sim.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
        let mut q = sim.world.query::<(&PointId, &impm::components::Trial<1>)>();
        for (id, trial) in q.iter(&sim.world) {
            let sigma = trial.0.cauchy()[(0, 0)];
            let expected = lambda * 200.0 / cell_volume[cell_of[id.0 as usize]];
            assert!(
                (sigma - expected).abs() < 1e-6 * 200.0,
                "step {step}: point {}: σ = {sigma}, expected {expected}",
                id.0
            );
        }
        let (x_last, f_last) = {
            let mut q = sim
                .world
                .query::<(&PointId, &Position<1>, &DeformationGradient<1>)>();
            let (_, x, f) = q.iter(&sim.world).find(|(id, _, _)| id.0 == 19).unwrap();
            (x.0[0], f.0[(0, 0)])
        };
        let traction_x = {
            let mut q = sim.world.query::<&TractionPoint<1>>();
            q.single(&sim.world).unwrap().position[0]
        };
        let end = x_last + 0.25 * f_last;
        assert!(
            (traction_x - end).abs() < 1e-9,
            "step {step}: traction point at {traction_x}, bar end at {end}"
        );
        assert!(traction_x > 10.0);
    }
}

/// 2D block of quadratic B-splines, base on rollers (fixed vertically, one corner node fixed
/// horizontally), under a uniform traction on a top that does not lie on a grid line, pulling
/// up and sideways. The applied force sums to λ h L (midpoint rule, partition of unity), the
/// base reactions balance it, the traction file shows the points and their forces, and a
/// horizontal cut carries the vertical force: the mean σ_yy over a row of points is h_y (ν = 0;
/// the sideways pull bends the block, which the mean removes).
#[test]
fn traction_on_an_unaligned_top_is_balanced_and_written() {
    let dir = temp_dir("traction_block");
    let spec = scene(
        &dir,
        "traction_block",
        r#"
grid(#{ lower: [0.0, 0.0], upper: [3.0, 5.0], cells: [3, 5], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 });
body(#{ name: "block", material: m, region: box([0.0, 0.0], [3.0, 3.5]), ppc: 2 });
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[1] == 0.0 && x[0] == 0.0, [0]);
traction(#{ on: [[0.0, 3.5], [3.0, 3.5]], traction: [10.0, 200.0], per_cell: 3 });
load_steps(2);
"#,
    );
    assert_eq!(spec.part::<Tractions>().unwrap().0.len(), 9);
    let length: f64 = spec
        .part::<Tractions>()
        .unwrap()
        .0
        .iter()
        .map(|t| t.area)
        .sum();
    assert!((length - 3.0).abs() < 1e-12);
    let out = dir.join("out");
    let mut sim = Simulation::<2>::new(&spec, &out).unwrap();
    sim.run(|_| {}).unwrap();
    let total = [30.0, 600.0];
    for (step, lambda) in [(1, 0.5), (2, 1.0)] {
        let file = out.join(format!("nodes_{step:04}.vtu"));
        let applied = node_sum(&file, "external_force", |_, _| true);
        let reaction = node_sum(&file, "internal_force", |_, fixed| fixed[1] == 1.0);
        for c in 0..2 {
            assert!((applied[c] - lambda * total[c]).abs() < 1e-9, "{applied:?}");
            assert!(
                (reaction[c] + lambda * total[c]).abs() < 1e-6 * total[1],
                "step {step}: reaction {reaction:?}"
            );
        }
        let tractions = read_vtu(&out.join(format!("tractions_{step:04}.vtu"))).unwrap();
        assert_eq!(tractions.points.len(), 9);
        let (_, force) = tractions.point_field("force").unwrap();
        let vertical: f64 = force.chunks(3).map(|f| f[1]).sum();
        assert!((vertical - lambda * total[1]).abs() < 1e-9);
        // the points moved up with the top (uniaxial tension, ν = 0)
        assert!(tractions.points.iter().all(|x| x[1] > 3.5));
    }
    assert!(out.join("tractions.pvd").exists());
    let mut q = sim.world.query::<(
        &impm::components::ReferencePosition<2>,
        &impm::components::Trial<2>,
    )>();
    for row in [0.25, 1.25, 2.25] {
        let sigmas: Vec<f64> = q
            .iter(&sim.world)
            .filter(|(reference, _)| reference.0[1] == row)
            .map(|(_, trial)| trial.0.cauchy()[(1, 1)])
            .collect();
        assert_eq!(sigmas.len(), 6);
        let mean = sigmas.iter().sum::<f64>() / 6.0;
        assert!(
            (mean - 200.0).abs() < 0.02 * 200.0,
            "row Y = {row}: mean σ_yy = {mean}"
        );
    }
}

#[test]
fn tractions_off_the_body_or_of_the_wrong_shape_are_errors() {
    let dir = temp_dir("traction_errors");
    let base = r#"grid(#{ lower: [0.0, 0.0], upper: [4.0, 4.0], cells: [4, 4], basis: "linear" });
const m = material(#{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 });
body(#{ name: "b", material: m, region: box([0.0, 0.0], [2.0, 2.0]), ppc: 2 });
fix(|x| x[1] == 0.0, [0, 1]);
load_steps(1);
"#;
    let path = dir.join("t.rhai");
    let write = |line: &str| std::fs::write(&path, format!("{base}{line}\n")).unwrap();
    write("traction(#{ on: [[0.0, 2.0]], traction: [0.0, 1.0] });");
    let error = load_scene(&path, &[]).unwrap_err();
    assert_eq!(error.line, Some(6), "{error}");
    assert!(error.message.contains("'on' has 1 points"), "{error}");
    write("traction(#{ on: [[0.0, 2.0], [5.0, 2.0]], traction: [0.0, 1.0] });");
    let error = load_scene(&path, &[]).unwrap_err();
    assert!(error.message.contains("outside the grid"), "{error}");
    write("traction(#{ on: [[0.0, 2.0], [2.0, 2.0]], tracton: [0.0, 1.0] });");
    let error = load_scene(&path, &[]).unwrap_err();
    assert!(error.message.contains("did you mean 'traction'"), "{error}");
    // FEM has no background grid for traction points
    std::fs::write(
        &path,
        format!(
            "{}traction(#{{ on: [[0.0, 2.0], [2.0, 2.0]], traction: [0.0, 1.0] }});\n",
            base.replace("basis: \"linear\"", "basis: \"fem\"")
        ),
    )
    .unwrap();
    let error = load_scene(&path, &[]).unwrap_err();
    assert_eq!(error.line, Some(6), "{error}");
    assert!(error.message.contains("basis \"fem\""), "{error}");
    // far from the body: a run-time error naming the traction point
    write("traction(#{ on: [[3.2, 3.5], [3.8, 3.5]], traction: [0.0, 1.0] });");
    let spec = load_scene(&path, &[]).unwrap();
    let mut sim = Simulation::<2>::new(&spec, &dir.join("out")).unwrap();
    let error = sim.step().unwrap_err().to_string();
    assert!(
        error.contains("traction point 0") && error.contains("not next to any material point"),
        "{error}"
    );
}

/// Uniaxial stretch of a block by a prescribed displacement δ of its top nodes (ν = 0, rollers
/// on the base and the sides at 0). With ν = 0 the lateral stretch is 1 and the Hencky Cauchy
/// stress is σ_vv = E ln(s) / s for the vertical stretch s; the displacement is u_v = (s − 1) V.
///
/// Grid nodes are where the displacement is prescribed, and the grid is reset every step: in
/// step n the top nodes (at height H) move by (λ_n − λ_{n−1}) δ while the material they carry
/// already spans s_{n−1} H, so the material's stretch follows s_n = s_{n−1} (1 + Δλ_n δ / H)
/// (the linear increment field c v with c H = Δλ δ). The schedule loads, holds and unloads past
/// zero into compression.
///
/// With linear hats every cell's points share one F, so the uniform state is the exact
/// discrete solution at every step (1e-9). With B-splines only step 1 is exact: once the points
/// have moved off their cell-midpoint positions the MPM quadrature no longer integrates the
/// basis exactly and the stress oscillates by a few percent (the quadrature error the paper
/// mentions), so later steps are only required to converge.
fn check_stretch<const D: usize>(text: &str, exact_steps: usize) {
    use impm::components::{Displacement, ReferencePosition, Trial};
    let (height, delta, modulus) = (4.0, 0.2, 1.0e4);
    let dir = temp_dir("stretch");
    let spec = scene(&dir, "stretch", text);
    let mut sim = Simulation::<D>::new(&spec, &dir.join("out")).unwrap();
    let (mut stretch, mut previous) = (1.0, 0.0);
    let vertical = D - 1;
    for (step, &lambda) in spec.load_factors.clone().iter().enumerate() {
        sim.step()
            .unwrap_or_else(|e| panic!("{D}D, step {}: {e}", step + 1));
        stretch *= 1.0 + (lambda - previous) * delta / height;
        previous = lambda;
        if step >= exact_steps {
            continue;
        }
        let expected = modulus * f64::ln(stretch) / stretch;
        let scale = modulus * delta / height;
        let mut q = sim
            .world
            .query::<(&ReferencePosition<D>, &Displacement<D>, &Trial<D>)>();
        for (reference, u, trial) in q.iter(&sim.world) {
            let sigma = trial.0.cauchy();
            for a in 0..3 {
                for b in 0..3 {
                    let exact = if a == vertical && b == vertical {
                        expected
                    } else {
                        0.0
                    };
                    assert!(
                        (sigma[(a, b)] - exact).abs() < 1e-9 * scale,
                        "{D}D, step {}: σ[{a}][{b}] = {}, expected {exact}",
                        step + 1,
                        sigma[(a, b)]
                    );
                }
            }
            for a in 0..D {
                let exact = if a == vertical {
                    (stretch - 1.0) * reference.0[a]
                } else {
                    0.0
                };
                assert!(
                    (u.0[a] - exact).abs() < 1e-9 * delta,
                    "{D}D, step {}: u = {:?}, expected u_{a} = {exact}",
                    step + 1,
                    u.0
                );
            }
        }
    }
    assert!(stretch < 1.0, "the schedule ends in compression");
}

const STRETCH_SCHEDULE: &str =
    "load_phases([#{ to: 1.0, steps: 2 }, #{ to: 1.0, steps: 1 }, #{ to: -0.5, steps: 2 }]);";

#[test]
fn prescribed_displacement_gives_the_analytic_uniaxial_stretch() {
    for (basis, exact_steps) in [
        ("basis: \"linear\"", 5),
        ("basis: \"bspline\", order: 2", 1),
    ] {
        check_stretch::<2>(
            &format!(
                r#"
grid(#{{ lower: [0.0, 0.0], upper: [2.0, 4.0], cells: [2, 4], {basis} }});
const m = material(#{{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 }});
body(#{{ name: "block", material: m, region: box([0.0, 0.0], [2.0, 4.0]), ppc: 2 }});
fix(|x| x[1] == 0.0, [1]);
fix(|x| x[0] == 0.0, [0]);
displace(|x| x[1] == 4.0, [1], [0.2]);
{STRETCH_SCHEDULE}
"#
            ),
            exact_steps,
        );
    }
    check_stretch::<3>(
        &format!(
            r#"
grid(#{{ lower: [0.0, 0.0, 0.0], upper: [1.0, 1.0, 4.0], cells: [1, 1, 2], basis: "linear" }});
const m = material(#{{ name: "m", E: 1.0e4, nu: 0.0, density: 1.0 }});
body(#{{ name: "block", material: m, region: box([0.0, 0.0, 0.0], [1.0, 1.0, 4.0]), ppc: 2 }});
fix(|x| x[2] == 0.0, [2]);
fix(|x| x[0] == 0.0, [0]);
fix(|x| x[1] == 0.0, [1]);
displace(|x| x[2] == 4.0, [2], [0.2]);
{STRETCH_SCHEDULE}
"#
        ),
        5,
    );
}
