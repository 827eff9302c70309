//! A block with a free side squeezed in plane strain (2D) or with free sides (3D) under a dead
//! traction: the exact state is homogeneous, and the bases that integrate a homogeneous state
//! exactly (cpGIMP, B-splines with `integration: "domain"`) must keep it while the free sides
//! move into new cells. This needs the traction integrated exactly against the grid's current
//! cells (`basis::surface`): sampled at the carried points it gave a failed run at step 4 (8
//! cells). (The same block under a smooth platen, `surface_displace`, still samples the basis
//! at its boundary points and is not exact: docs/boundaries.md, "Free sides".)

mod common;

use impm::components::Trial;
use impm::run::{Simulation, load_scene};

const E: f64 = 1.0e4;
const NU: f64 = 0.3;

/// A unit block on rollers at its base and on the symmetry plane(s) x = 0 (and y = 0 in 3D),
/// free on the other side(s), loaded on its top by a dead traction of 1000 per reference area.
fn scene<const D: usize>() -> String {
    let (upper, cells, top, fixes) = match D {
        2 => (
            "[1.5, 1.25]",
            "[cells * 3 / 2, cells * 5 / 4]",
            "[[0.0, 1.0], [1.0, 1.0]]",
            "fix(|x| x[1] == 0.0, [1]);\nfix(|x| x[0] == 0.0, [0]);",
        ),
        _ => (
            "[1.5, 1.5, 1.25]",
            "[cells * 3 / 2, cells * 3 / 2, cells * 5 / 4]",
            "[[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]",
            "fix(|x| x[2] == 0.0, [2]);\nfix(|x| x[0] == 0.0, [0]);\nfix(|x| x[1] == 0.0, [1]);",
        ),
    };
    let lower = if D == 2 {
        "[0.0, 0.0]"
    } else {
        "[0.0, 0.0, 0.0]"
    };
    let unit = if D == 2 {
        "[1.0, 1.0]"
    } else {
        "[1.0, 1.0, 1.0]"
    };
    let traction = if D == 2 {
        "[0.0, -1000.0]"
    } else {
        "[0.0, 0.0, -1000.0]"
    };
    format!(
        r#"
let cells = 4;
let basis = "bspline";
let integration = "domain";
const soft = material(#{{ name: "soft", E: {E}, nu: {NU}, density: 1.0 }});
grid(#{{ lower: {lower}, upper: {upper}, cells: {cells}, basis: basis, order: 2, integration: integration }});
body(#{{ name: "block", material: soft, region: box({lower}, {unit}), ppc: 2 }});
{fixes}
traction(#{{ on: {top}, traction: {traction} }});
load_steps(5);
"#
    )
}

fn run<const D: usize>(name: &str, set: &[(&str, &str)]) -> Simulation<D> {
    let dir = common::temp_dir("free_sides", name);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}.rhai"));
    std::fs::write(&path, scene::<D>()).unwrap();
    let spec = load_scene(&path, &common::overrides(set)).unwrap_or_else(|e| panic!("{e}"));
    let mut sim = Simulation::<D>::new(&spec, &dir.join("out")).unwrap_or_else(|e| panic!("{e}"));
    sim.run(|_| {})
        .unwrap_or_else(|e| panic!("{name} {set:?}: {e}"));
    sim
}

/// The largest departure of the points' Cauchy stresses from one homogeneous state with
/// σ_lateral = 0 (relative to |σ_vertical|), and the vertical stress of the first point and its
/// lateral stretch.
fn departure<const D: usize>(sim: &mut Simulation<D>) -> (f64, f64, f64) {
    let v = D - 1;
    let mut q = sim.world.query::<&Trial<D>>();
    let states: Vec<_> = q
        .iter(&sim.world)
        .map(|t| (t.0.cauchy(), t.0.deformation_gradient[(0, 0)]))
        .collect();
    let (first, stretch) = states[0];
    let vertical = first[(v, v)];
    let mut worst = 0.0f64;
    for (sigma, _) in &states {
        for a in 0..D {
            for b in 0..D {
                let exact = if a == v && b == v { vertical } else { 0.0 };
                worst = worst.max((sigma[(a, b)] - exact).abs() / vertical.abs());
            }
        }
    }
    (worst, vertical, stretch)
}

/// The Hencky state under a dead traction t per reference area on the top of a block free to
/// expand laterally (plane strain in 2D: σ_xx = 0, ε_zz = 0; in 3D: σ_xx = σ_yy = 0): the
/// vertical log strain ε solves M ε = t e^{ε} (τ_v = J σ_v and J σ_v = e^{ε} t, the force t A0
/// over the current area), M = E / (1 − ν²) in plane strain and E in 3D; returns
/// (σ_v = −t / (lateral stretch)^(D−1), lateral stretch).
fn hencky_under_traction(t: f64, dim: usize) -> (f64, f64) {
    let modulus = if dim == 2 { E / (1.0 - NU * NU) } else { E };
    let lateral_ratio = if dim == 2 { NU / (1.0 - NU) } else { NU };
    let mut strain = -t / modulus;
    for _ in 0..50 {
        let residual = modulus * strain + t * strain.exp();
        strain -= residual / (modulus + t * strain.exp());
    }
    let lateral = (-lateral_ratio * strain).exp();
    (-t / lateral.powi(dim as i32 - 1), lateral)
}

/// Runs the block under the dead traction and checks every point against the exact Hencky
/// state (1e-9 relative), printing the figures.
fn check_traction<const D: usize>(name: &str, set: &[(&str, &str)]) {
    let mut sim = run::<D>(name, set);
    let (worst, vertical, stretch) = departure(&mut sim);
    let (exact, exact_stretch) = hencky_under_traction(1000.0, D);
    println!(
        "{D}D traction, {set:?}: departure {worst:.1e}, σ_v {vertical:.9} (exact {exact:.9}), stretch {stretch:.9} (exact {exact_stretch:.9})"
    );
    assert!(worst < 1e-9, "{name}: {worst:e}");
    assert!(
        ((vertical - exact) / exact).abs() < 1e-9,
        "{vertical} {exact}"
    );
    assert!(
        (stretch - exact_stretch).abs() < 1e-9,
        "{stretch} {exact_stretch}"
    );
}

#[test]
fn a_squeezed_block_with_free_sides_stays_homogeneous() {
    for (basis, integration) in [("bspline", "domain"), ("gimp", "points")] {
        for cells in ["4", "8"] {
            let set = [
                ("cells", cells),
                ("basis", basis),
                ("integration", integration),
            ];
            check_traction::<2>(&format!("traction_{basis}_{cells}"), &set);
        }
    }
    // 3D, free on two sides: the traction's faces stay parallel to the grid
    check_traction::<3>("traction_3d", &[("cells", "4")]);
}
