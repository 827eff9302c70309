//! Linear FEM (`basis = "fem"`) through the MPM stages: the statically determinate 1D column
//! to round-off, second-order convergence of the tip, 2D/3D against 1D, patch tests on
//! distorted meshes, the tangent against finite differences and the assembled force against
//! an independent total-Lagrangian FEM computation, output and scene errors.

mod common;

use std::path::PathBuf;

use bevy_ecs::system::RunSystemOnce;
use nalgebra::{Matrix3, SMatrix, SVector};

use impm::analytic::SelfWeightColumn;
use impm::components::{DeformationGradient, GridNode, ReferencePosition, Trial};
use impm::effects::fem_mesh::{
    ElementPoint, FemMesh, evaluate_element_basis, move_reference_nodes,
};
use impm::effects::grid_constraints::{NodeConstraint, NodeConstraints};
use impm::fem::{shape_function, tensor_gauss_rule};
use impm::material::Hencky;
use impm::mechanics::{embed, trial_state};
use impm::resources::{GridFields, LoadStep};
use impm::run::Simulation;
use impm::run::load_scene;
use impm::scene::SceneSpec;
use impm::solver::NO_DOF;
use impm::stages::number_dofs;

fn temp_dir(tag: &str) -> PathBuf {
    common::temp_dir("fem", tag)
}

/// A path for a scene file of its own (in a fresh folder).
fn scene_path(tag: &str) -> PathBuf {
    let dir = common::temp_dir("fem-scene", tag);
    std::fs::create_dir_all(&dir).unwrap();
    dir.join("scene.rhai")
}

/// A shipped column scene with `basis = fem` and the given overrides.
fn column_scene(file: &str, set: &[(&str, &str)]) -> SceneSpec {
    let mut set = set.to_vec();
    set.push(("basis", "fem"));
    load_scene(&common::shipped_scene(file), &common::overrides(&set)).unwrap()
}

/// The column's analytic solution at load factor 1.
fn column_solution(spec: &SceneSpec) -> SelfWeightColumn {
    let Some(impm::scene::AnalyticSpec::Column {
        height,
        density,
        body_force,
        modulus,
        ..
    }) = spec.analytic
    else {
        panic!("the column scene declares its solution")
    };
    SelfWeightColumn {
        density,
        body_force,
        height,
        modulus,
    }
}

/// Runs a simulation to the end in a temporary folder (removed afterwards).
fn solve<const D: usize>(spec: &SceneSpec, tag: &str) -> Simulation<D> {
    let dir = temp_dir(tag);
    let mut sim = Simulation::<D>::new(spec, &dir).unwrap();
    sim.run(|_| {}).unwrap_or_else(|e| panic!("{tag}: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    sim
}

/// Current position along `axis` of the mesh nodes with the largest reference coordinate
/// along `axis` (the top of a column), averaged.
fn top_position<const D: usize>(sim: &mut Simulation<D>, axis: usize) -> f64 {
    let reference = sim
        .world
        .resource::<FemMesh<D>>()
        .0
        .reference_positions
        .clone();
    let top = reference.iter().fold(f64::MIN, |m, x| m.max(x[axis]));
    let mut nodes = sim.world.query::<&GridNode<D>>();
    let heights: Vec<f64> = nodes
        .iter(&sim.world)
        .filter(|n| reference[n.index][axis] == top)
        .map(|n| n.position[axis])
        .collect();
    heights.iter().sum::<f64>() / heights.len() as f64
}

/// The 1D column is statically determinate: with one Gauss point per element the Cauchy
/// stress at every element centre is the analytic one to round-off (here to 1e-10 of the
/// base stress W), for W = 10000, 40000 and 400000.
#[test]
fn column_1d_stress_at_element_centres_is_exact() {
    for body_force in ["-200", "-800", "-8000"] {
        let mut spec = column_scene(
            "column_1d.rhai",
            &[("ppc", "1"), ("cells", "50"), ("body_force", body_force)],
        );
        spec.solver.tolerance = 1e-11;
        let column = column_solution(&spec);
        let mut sim = solve::<1>(&spec, &format!("exact{body_force}"));
        let profile = sim.stress_profile(0);
        assert_eq!(profile.len(), 50);
        let worst = profile
            .iter()
            .map(|&(x, sigma)| (sigma - column.stress(x)).abs())
            .fold(0.0, f64::max);
        let relative = worst / column.weight();
        eprintln!("b_f = {body_force}: max |σ - σ_A| / W = {relative:.2e}");
        assert!(relative < 1e-10, "b_f = {body_force}: {relative:e}");
        // the centres are the element midpoints of the reference mesh
        for (k, (x, _)) in profile.iter().enumerate() {
            assert!((x - (k as f64 + 0.5)).abs() < 1e-12);
        }
    }
}

/// A load step too big for Newton is cut (main's step cutting); the mesh advances once per
/// converged sub-step and the result is still exact (W = 1.5e6, base stretch ≈ 0.45).
#[test]
fn column_1d_with_a_cut_step_stays_exact() {
    let mut spec = column_scene(
        "column_1d.rhai",
        &[("ppc", "1"), ("body_force", "-30000"), ("steps", "1")],
    );
    spec.solver.tolerance = 1e-11;
    let column = column_solution(&spec);
    let mut sim = solve::<1>(&spec, "cut");
    let step = &sim.summary.steps[0];
    assert!(step.cuts >= 1 && step.converged, "{step:?}");
    let worst = sim
        .stress_profile(0)
        .iter()
        .map(|&(x, sigma)| (sigma - column.stress(x)).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-10 * column.weight(), "{worst:e}");
    let tip = top_position(&mut sim, 0);
    assert!(tip > 0.0 && tip < column.height, "{tip}");
}

/// Element stretches are exact at the centres, so the tip x(L0) = Σ F(X_c) h is the midpoint
/// rule of ∫ F dX: second order in h.
#[test]
fn column_1d_tip_converges_at_second_order() {
    let mut errors = Vec::new();
    let mut exact = 0.0;
    for cells in [5, 10, 20, 40] {
        let cells = cells.to_string();
        let mut spec = column_scene(
            "column_1d.rhai",
            &[("ppc", "1"), ("cells", &cells), ("body_force", "-8000")],
        );
        spec.solver.tolerance = 1e-11;
        let column = column_solution(&spec);
        exact = column.position(column.height);
        let mut sim = solve::<1>(&spec, &format!("tip{cells}"));
        errors.push((top_position(&mut sim, 0) - exact).abs());
    }
    let rates: Vec<f64> = errors.windows(2).map(|e| (e[0] / e[1]).log2()).collect();
    eprintln!("tip errors {errors:?} (x(L0) = {exact}), rates {rates:.4?}");
    assert!(
        errors[0] > 1e-4,
        "the coarse error must be well above round-off"
    );
    for rate in rates {
        assert!((rate - 2.0).abs() < 0.02, "rate {rate}");
    }
}

/// Stress and tip of a 2D/3D one-cell-wide FEM column against 1D FEM, 2 Gauss points per
/// direction: every point at a height has the 1D stress, to round-off.
fn assert_matches_1d<const D: usize>(file: &str, set: &[(&str, &str)]) {
    let mut spec_1d = column_scene("column_1d.rhai", set);
    let mut spec = column_scene(file, set);
    spec_1d.solver.tolerance = 1e-11;
    spec.solver.tolerance = 1e-11;
    let mut one = solve::<1>(&spec_1d, &format!("{file}-1d"));
    let mut many = solve::<D>(&spec, file);
    let (profile_1d, profile) = (one.stress_profile(0), many.stress_profile(D - 1));
    let per_height = profile.len() / profile_1d.len();
    assert_eq!(per_height, 1 << (D - 1), "{file}: points per height");
    let scale = column_solution(&spec).weight();
    let mut worst = 0.0f64;
    for (k, chunk) in profile.chunks(per_height).enumerate() {
        for &(x, sigma) in chunk {
            assert!((x - profile_1d[k].0).abs() < 1e-12, "{file}: heights");
            worst = worst.max((sigma - profile_1d[k].1).abs() / scale);
        }
    }
    let (tip_1d, tip) = (top_position(&mut one, 0), top_position(&mut many, D - 1));
    eprintln!("{file}: max stress difference {worst:.2e} W, tips {tip_1d} vs {tip}");
    assert!(
        worst < 1e-10,
        "{file}: stress differs from 1D by {worst:e} W"
    );
    assert!((tip - tip_1d).abs() < 1e-10 * tip_1d.abs());
    let (e1, e) = (
        one.summary.final_error().unwrap(),
        many.summary.final_error().unwrap(),
    );
    assert!(
        (e - e1).abs() <= 1e-8 * e1,
        "eq. 15: 1D {e1:e}, {file} {e:e}"
    );
}

#[test]
fn column_2d_agrees_with_1d() {
    assert_matches_1d::<2>(
        "column_2d.rhai",
        &[("ppc", "2"), ("cells", "20"), ("body_force", "-8000")],
    );
}

#[test]
fn column_3d_agrees_with_1d() {
    assert_matches_1d::<3>(
        "column_3d.rhai",
        &[
            ("ppc", "2"),
            ("cells", "10"),
            ("body_force", "-8000"),
            ("steps", "5"),
        ],
    );
}

/// A block of 2^D elements on [0, 2]^D (2 Gauss points per direction), written as a scene.
fn block_scene(dim: usize, tag: &str) -> SceneSpec {
    let zeros = vec!["0.0"; dim].join(", ");
    let twos = vec!["2.0"; dim].join(", ");
    let cells = vec!["2"; dim].join(", ");
    let text = format!(
        "grid(#{{ lower: [{zeros}], upper: [{twos}], cells: [{cells}], basis: \"fem\" }});\n\
         const m = material(#{{ name: \"m\", E: 1000.0, nu: 0.3, density: 1.0 }});\n\
         body(#{{ name: \"block\", material: m, region: box([{zeros}], [{twos}]), ppc: 2 }});\n\
         load_factors([0.5, 1.0]);\n"
    );
    let path = scene_path(tag);
    std::fs::write(&path, text).unwrap();
    let spec = load_scene(&path, &[]).unwrap();
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
    spec
}

/// F = R(θ) diag(λ), R a rotation in the 0-1 plane (identity in 1D).
fn rotated_stretch<const D: usize>(stretches: [f64; 3], angle: f64) -> SMatrix<f64, D, D> {
    let mut f = SMatrix::<f64, D, D>::from_fn(|a, b| if a == b { stretches[a] } else { 0.0 });
    if D >= 2 {
        let (s, c) = angle.sin_cos();
        let mut r = SMatrix::<f64, D, D>::identity();
        r[(0, 0)] = c;
        r[(0, 1)] = -s;
        r[(1, 0)] = s;
        r[(1, 1)] = c;
        f = r * f;
    }
    f
}

/// Patch test: the boundary nodes of a 2^D-element block with a distorted interior node follow
/// the homogeneous deformation x = F X (a rotated stretch, ramped over two load steps, so the
/// mesh advances once in between). Every integration point must then carry F and the Hencky
/// stress σ = R diag(σ_i) Rᵀ with σ_i = (λ Σ_k ln λ_k + 2 μ ln λ_i) / Π_k λ_k (plane strain,
/// out-of-plane stretches 1), and the interior node must land at F X.
fn patch_test<const D: usize>() {
    let (e, nu) = (1000.0, 0.3);
    let (lame, mu) = (
        e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
        e / (2.0 * (1.0 + nu)),
    );
    let stretches = [1.2, 0.85, 1.1];
    let angle = if D > 1 { 0.4 } else { 0.0 };
    let f = rotated_stretch::<D>(stretches, angle);

    let mut spec = block_scene(D, &format!("patch{D}"));
    let vertices = 3usize.pow(D as u32);
    let centre = vertices / 2;
    let position =
        |node: usize| SVector::<f64, D>::from_fn(|k, _| ((node / 3usize.pow(k as u32)) % 3) as f64);
    spec.set_part(NodeConstraints(
        (0..vertices)
            .filter(|&node| node != centre)
            .flat_map(|node| {
                let u = (f - SMatrix::<f64, D, D>::identity()) * position(node);
                (0..D).map(move |component| NodeConstraint {
                    node,
                    component,
                    value: u[component],
                })
            })
            .collect(),
    ));
    let dir = temp_dir(&format!("patch{D}"));
    let mut sim = Simulation::<D>::new(&spec, &dir).unwrap();
    let distortion = SVector::<f64, D>::from_fn(|k, _| [0.15, -0.1, 0.07][k]);
    move_reference_nodes(&mut sim.world, |node, _| {
        if node == centre {
            distortion
        } else {
            SVector::zeros()
        }
    })
    .unwrap();
    sim.write_initial_state().unwrap();
    sim.run(|_| {}).unwrap();

    let log_sum: f64 = stretches[..D].iter().map(|l: &f64| l.ln()).sum();
    let volume_ratio: f64 = stretches[..D].iter().product();
    let principal = Matrix3::from_fn(|a, b| {
        if a != b {
            0.0
        } else {
            let own = if a < D { stretches[a].ln() } else { 0.0 };
            (lame * log_sum + 2.0 * mu * own) / volume_ratio
        }
    });
    let rotation = embed(&rotated_stretch::<D>([1.0; 3], angle));
    let expected = rotation * principal * rotation.transpose();
    let mut points = sim
        .world
        .query::<(&ReferencePosition<D>, &DeformationGradient<D>, &Trial<D>)>();
    let (mut count, mut worst) = (0, 0.0f64);
    for (x, gradient, trial) in points.iter(&sim.world) {
        assert!(
            (gradient.0 - f).norm() < 1e-12,
            "F at {:?}: {}",
            x.0,
            gradient.0
        );
        let sigma = trial.0.cauchy();
        worst = worst.max((sigma - expected).norm() / expected.norm());
        assert!(
            (sigma - expected).norm() < 1e-10 * expected.norm(),
            "D = {D}: σ at {:?} = {sigma} vs {expected}",
            x.0
        );
        count += 1;
    }
    assert_eq!(
        count,
        (1 << D) * (1 << D),
        "2^D elements x 2^D Gauss points"
    );
    eprintln!("patch test {D}D: max |σ - σ_Hencky| / |σ_Hencky| = {worst:.2e}");
    let interior = sim
        .world
        .query::<&GridNode<D>>()
        .iter(&sim.world)
        .find(|n| n.index == centre)
        .unwrap()
        .position;
    let expected_interior = f * (position(centre) + distortion);
    assert!(
        (interior - expected_interior).norm() < 1e-12,
        "{interior} vs {expected_interior}"
    );

    // The deformed mesh is the grid output: mesh nodes at their current positions.
    let grid = impm::output::read_vtu(&dir.join("grid_0002.vtu")).unwrap();
    assert_eq!((grid.points.len(), grid.cell_count), (vertices, 1 << D));
    let node = grid.points[centre];
    for k in 0..D {
        assert!((node[k] - expected_interior[k]).abs() < 1e-12);
    }
    let (components, displacement) = grid.point_field("displacement").unwrap();
    assert_eq!(components, 3);
    for k in 0..D {
        let reference = position(centre)[k] + distortion[k];
        assert!((displacement[3 * centre + k] - (expected_interior[k] - reference)).abs() < 1e-12);
    }
    let particles = impm::output::read_vtu(&dir.join("particles_0002.vtu")).unwrap();
    assert_eq!(particles.points.len(), count);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn patch_test_2d_distorted_quadrilaterals() {
    patch_test::<2>();
}

#[test]
fn patch_test_1d_and_3d() {
    patch_test::<1>();
    patch_test::<3>();
}

/// A 2D FEM world on a distorted mesh of 3x3 elements, after one solved load step (so F^n is
/// not I and the mesh has moved), at the start of the second step with a large trial increment.
fn deformed_world(tag: &str) -> Simulation<2> {
    let text = "grid(#{ lower: [0.0, 0.0], upper: [4.0, 4.0], cells: [4, 4], basis: \"fem\" });\n\
                const m = material(#{ name: \"m\", E: 1000.0, nu: 0.3, density: 1.0 });\n\
                body(#{ name: \"b\", material: m, region: box([0.0, 0.0], [3.0, 3.0]), ppc: 2 });\n\
                body_force([0.0, -40.0]);\n\
                fix(|x| x[1] == 0.0, [0, 1]);\n\
                load_factors([1.0, 2.0]);\n";
    let path = scene_path(tag);
    std::fs::write(&path, text).unwrap();
    let spec = load_scene(&path, &[]).unwrap();
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
    let mut sim = Simulation::<2>::new(&spec, &temp_dir(tag)).unwrap();
    // move the four interior nodes of the 3x3-element body (vertices (1..=2, 1..=2))
    move_reference_nodes(&mut sim.world, |node, _| {
        let (i, j) = (node % 5, node / 5);
        if (1..=2).contains(&i) && (1..=2).contains(&j) {
            SVector::<f64, 2>::new(0.12 * (i as f64 - 1.5), -0.1 + 0.05 * i as f64 * j as f64)
        } else {
            SVector::zeros()
        }
    })
    .unwrap();
    sim.step().unwrap();
    *sim.world.resource_mut::<LoadStep>() = LoadStep {
        number: 2,
        factor: 2.0,
        previous_factor: 1.0,
        completes_step: true,
    };
    sim.world
        .run_system_once(evaluate_element_basis::<2>)
        .unwrap();
    sim.world.run_system_once(number_dofs::<2>).unwrap();
    // a large, smooth increment: rotation by 0.3 rad plus stretch about the base
    let positions: Vec<_> = sim
        .world
        .query::<&GridNode<2>>()
        .iter(&sim.world)
        .map(|n| (n.index, n.position))
        .collect();
    let mut fields = sim.world.resource_mut::<GridFields<2>>();
    let (s, c) = 0.3f64.sin_cos();
    for (node, x) in positions {
        let du = SVector::<f64, 2>::new(
            (c - 1.0) * x[0] - s * x[1] + 0.05 * x[0],
            s * x[0] + (c - 1.0) * x[1] - 0.08 * x[1],
        );
        for k in 0..2 {
            if fields.dofs[node][k] != NO_DOF {
                fields.increment[node][k] = du[k];
            }
        }
    }
    sim
}

/// The assembled FEM force is the total-Lagrangian FEM integral computed from scratch:
/// f_a = Σ_elements Σ_gauss w det J_0 P ∇_X N_a with F = (Σ x_a ⊗ ∇_ξ N_a)(Σ X_a ⊗ ∇_ξ N_a)⁻¹
/// from the reference and current (= moved + Δu) node positions, P = τ(F) F⁻ᵀ — which checks
/// that the MPM stages (multiplicative F, step-start basis) are exactly linear FEM.
#[test]
fn assembled_force_is_the_total_lagrangian_fem_force() {
    let mut sim = deformed_world("tl");
    common::internal_force(&mut sim);
    let assembled = sim.world.resource::<GridFields<2>>().internal_force.clone();
    let mesh = sim.world.resource::<FemMesh<2>>().0.clone();
    let fields = sim.world.resource::<GridFields<2>>().clone();
    let mut current = mesh.reference_positions.clone();
    for node in sim.world.query::<&GridNode<2>>().iter(&sim.world) {
        current[node.index] = node.position + fields.increment[node.index];
    }
    let material = Hencky::new(1000.0, 0.3).unwrap();
    let mut expected = vec![SVector::<f64, 2>::zeros(); current.len()];
    for e in 0..mesh.element_count() {
        let nodes = mesh.element_nodes(e);
        for (xi, weight) in tensor_gauss_rule([2, 2]) {
            let (mut j0, mut j) = (SMatrix::<f64, 2, 2>::zeros(), SMatrix::<f64, 2, 2>::zeros());
            for (a, &n) in nodes.iter().enumerate() {
                let grad = shape_function(a, &xi).1;
                j0 += mesh.reference_positions[n] * grad.transpose();
                j += current[n] * grad.transpose();
            }
            let j0_inverse = j0.try_inverse().unwrap();
            let f = j * j0_inverse;
            let tau = trial_state(&material, &SMatrix::identity(), &f)
                .unwrap()
                .kirchhoff;
            let p =
                tau.fixed_view::<2, 2>(0, 0).into_owned() * f.try_inverse().unwrap().transpose();
            for (a, &n) in nodes.iter().enumerate() {
                let grad_x0 = j0_inverse.transpose() * shape_function(a, &xi).1;
                expected[n] += p * grad_x0 * (weight * j0.determinant());
            }
        }
    }
    let scale = expected.iter().fold(0.0f64, |m, f| m.max(f.norm()));
    assert!(scale > 1.0, "a meaningful force: {scale}");
    let mut worst = 0.0f64;
    for (node, (a, b)) in assembled.iter().zip(&expected).enumerate() {
        worst = worst.max((a - b).norm() / scale);
        assert!((a - b).norm() < 1e-11 * scale, "node {node}: {a} vs {b}");
    }
    eprintln!("assembled vs total-Lagrangian FEM force: max difference {worst:.2e} of the largest");
}

/// The assembled FEM tangent equals central finite differences of the assembled internal
/// force, on the distorted, deformed mesh, and is symmetric.
#[test]
fn fem_tangent_matches_finite_differences() {
    let mut sim = deformed_world("fd");
    let dofs = sim.world.resource::<GridFields<2>>().dof_count;
    assert!(dofs >= 20, "{dofs} DOFs");
    let (worst, scale) = common::assert_tangent_matches_finite_differences(&mut sim);
    eprintln!("max |K - K_fd| = {worst:.2e}, scale {scale:.2e}");
}

#[test]
fn fem_schedules_have_no_ambiguities_and_newton_converges_quadratically() {
    let spec = column_scene(
        "column_2d.rhai",
        &[("ppc", "2"), ("cells", "10"), ("body_force", "-8000")],
    );
    let out = temp_dir("ambiguity");
    let mut sim = Simulation::<2>::new(&spec, &out).unwrap();
    common::assert_schedules_unambiguous(&mut sim);
    sim.run(|_| {}).unwrap();
    let mut checked = 0;
    for step in &sim.summary.steps {
        for pair in step.residuals.windows(2) {
            if pair[0] < 1e-2 && pair[1] > 1e-13 {
                let order = pair[1].ln() / pair[0].ln();
                assert!(order >= 1.8, "step {}: {:?}", step.step, step.residuals);
                checked += 1;
            }
        }
    }
    assert!(checked >= 10, "{checked} iterates in the asymptotic range");
    // integration points keep their element and parent coordinates
    let mut points = sim.world.query::<&ElementPoint<2>>();
    assert!(
        points
            .iter(&sim.world)
            .all(|p| p.xi.iter().all(|x| x.abs() < 1.0))
    );
    let _ = std::fs::remove_dir_all(out);
}

#[test]
fn scenes_must_be_body_fitted_for_fem() {
    let text = "let cells = 4;\n\
                grid(#{ lower: [0.0, 0.0], upper: [4.0, 4.0], cells: [cells, cells], basis: \"fem\" });\n\
                const m = material(#{ name: \"m\", E: 1e6, nu: 0.3, density: 1.0 });\n\
                body(#{ name: \"block\", material: m, region: box([0.0, 0.0], [2.5, 2.0]), ppc: 2 });\n\
                load_steps(1);\n";
    let path = scene_path("partial");
    std::fs::write(&path, text).unwrap();
    let error = load_scene(&path, &[]).unwrap_err();
    assert_eq!(error.line, Some(4), "{error}");
    assert!(
        error.message.contains("body 'block'")
            && error.message.contains("needs a body-fitted mesh")
            && error.message.contains("grid cell [2, 0]"),
        "{error}"
    );
    // with 8 cells per axis the same box is made of whole cells: 5 x 4 elements, 2x2 points
    let spec = load_scene(&path, &[("cells".into(), "8".into())]).unwrap();
    assert_eq!(spec.bodies[0].points.len(), 5 * 4 * 4);
    let volume: f64 = spec.bodies[0].points.iter().map(|p| p.volume).sum();
    assert!((volume - 5.0).abs() < 1e-12);
    // the ghost penalty of nearly empty MPM cells has no meaning on a body-fitted mesh
    std::fs::write(
        &path,
        format!("{text}solver(#{{ ghost_penalty: 0.01 }});\n"),
    )
    .unwrap();
    let error = load_scene(&path, &[("cells".into(), "8".into())]).unwrap_err();
    assert_eq!(error.line, Some(6), "{error}");
    assert!(error.message.contains("ghost_penalty"), "{error}");
    let _ = std::fs::remove_dir_all(path.parent().unwrap());
}
