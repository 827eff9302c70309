//! Helpers shared by the integration tests: running the shipped scenes, and world-level
//! checks of the assembled tangent and of the schedules.
#![allow(dead_code)] // each test crate uses its own subset
#![allow(clippy::needless_range_loop)] // matrix indices read best as indices

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use bevy_ecs::prelude::World;
use bevy_ecs::schedule::ScheduleLabel;
use bevy_ecs::system::RunSystemOnce;

use impm::material::{Hencky, Material};
use impm::method::{NewtonSchedule, OutputSchedule, RollbackSchedule, StepSchedule};
use impm::resources::{GridFields, Newton};
use impm::run::Simulation;
use impm::run::load_scene;
use impm::solver::NO_DOF;
use impm::stages::{assemble, update_stress};

/// A scene shipped under `scripts/`.
pub fn shipped_scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts")
        .join(name)
}

/// Runs the `impm` binary with `args`.
pub fn impm(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_impm"))
        .args(args)
        .output()
        .expect("impm runs")
}

/// The 1D column scene's path, as a command-line argument.
pub fn column_script() -> String {
    shipped_scene("column_1d.rhai").display().to_string()
}

/// The particle file's fields and their components, as `scripts/check_output.py` takes them
/// (`NAME:COMPONENTS`).
pub const PARTICLE_FIELDS: [&str; 8] = [
    "reference_position:3",
    "reference_volume:1",
    "volume:1",
    "mass:1",
    "displacement:3",
    "cauchy_stress:9",
    "deformation_gradient:9",
    "body:1",
];

/// Numbers the folders of [`temp_dir`] within one test process.
static TEMP_DIRS: AtomicUsize = AtomicUsize::new(0);

/// A fresh (removed, not yet created) folder under the system's temporary folder, unique to
/// this call: the process id tells concurrent test binaries apart and a process-wide counter
/// the tests of one binary, which run in parallel threads (two tests with one `tag` would
/// otherwise share, and clear, one folder).
pub fn temp_dir(prefix: &str, tag: &str) -> PathBuf {
    let call = TEMP_DIRS.fetch_add(1, Ordering::Relaxed);
    let dir =
        std::env::temp_dir().join(format!("impm-{prefix}-{tag}-{}-{call}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// The scene of the script `text` (written to a temporary file named after `tag`, removed
/// after loading), or the loading error as text.
pub fn scene_from_text(
    prefix: &str,
    tag: &str,
    text: &str,
) -> Result<impm::scene::SceneSpec, String> {
    let dir = temp_dir(prefix, tag);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{tag}.rhai"));
    std::fs::write(&path, text).unwrap();
    let spec = load_scene(&path, &[]).map_err(|e| e.to_string());
    let _ = std::fs::remove_dir_all(&dir);
    spec
}

/// `--set` style overrides from pairs.
pub fn overrides(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
    pairs
        .iter()
        .map(|(n, v)| (n.to_string(), v.to_string()))
        .collect()
}

/// The warnings a shipped scene with overrides gets before it runs (`scene::scene_warnings`)
/// that contain `needle`.
pub fn shipped_scene_warnings(name: &str, pairs: &[(&str, &str)], needle: &str) -> Vec<String> {
    let spec = impm::run::load_scene(&shipped_scene(name), &overrides(pairs))
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    impm::scene::scene_warnings(&spec)
        .into_iter()
        .filter(|w| w.contains(needle))
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

/// `q/s_u` after each of the 10 steps of the Tresca strip footing (`scripts/strip_footing.rhai`,
/// `s_u = 10`, linear MPM, pushed to δ/B = 0.05) with further overrides `set`; every step must
/// complete.
pub fn tresca_footing_linear(set: &[(&str, &str)]) -> Vec<f64> {
    let mut all = vec![
        ("material", "tresca"),
        ("su", "10"),
        ("basis", "linear"),
        ("settlement", "0.05"),
        ("steps", "10"),
    ];
    all.extend_from_slice(set);
    let sim = run_shipped::<2>("strip_footing.rhai", &all);
    assert_eq!(sim.summary.steps.len(), 10, "{set:?}");
    sim.summary
        .steps
        .iter()
        .map(|step| step.measure("footing_pressure").unwrap() / 10.0)
        .collect()
}

/// Runs the stress update and the assembly for the current increments; returns the internal
/// force at the free DOFs.
pub fn internal_force(sim: &mut Simulation<2>) -> Vec<f64> {
    internal_force_of::<Hencky>(sim, &|_| {})
}

/// As [`internal_force`], for a scene whose points are all of material model `M`, with
/// `after_assembly` run after the assembly (a module's contributions at `Hook::AfterAssembly`).
pub fn internal_force_of<M: Material>(
    sim: &mut Simulation<2>,
    after_assembly: &dyn Fn(&mut World),
) -> Vec<f64> {
    sim.world.run_system_once(update_stress::<2, M>).unwrap();
    sim.world.run_system_once(assemble::<2>).unwrap();
    after_assembly(&mut sim.world);
    let fields = sim.world.resource::<GridFields<2>>();
    let mut f = vec![0.0; fields.dof_count];
    for (node, dofs) in fields.dofs.written() {
        for (c, &d) in dofs.iter().enumerate() {
            if d != NO_DOF {
                f[d as usize] = fields.internal_force[node][c];
            }
        }
    }
    f
}

/// The grid slot (node, component) of a DOF.
fn slot_of(sim: &Simulation<2>, dof: usize) -> (usize, usize) {
    let fields = sim.world.resource::<GridFields<2>>();
    (0..fields.dofs.len())
        .flat_map(|node| (0..2).map(move |c| (node, c)))
        .find(|&(node, c)| fields.dofs[node][c] == dof as u32)
        .unwrap_or_else(|| panic!("dof {dof} exists"))
}

/// The assembled tangent at the current increments (connectivity and DOFs already done for
/// the step) equals central finite differences of the assembled internal force to 1e-6 of
/// its largest entry, and is symmetric. Returns (max |K - K_fd|, max |K|).
pub fn assert_tangent_matches_finite_differences(sim: &mut Simulation<2>) -> (f64, f64) {
    assert_tangent_matches_finite_differences_of::<Hencky>(sim, &|_| {}, true)
}

/// As [`assert_tangent_matches_finite_differences`], for a scene whose points are all of
/// material model `M`, with `after_assembly` adding a module's contributions after the
/// assembly; the symmetry of K is asserted only when `symmetric`.
pub fn assert_tangent_matches_finite_differences_of<M: Material>(
    sim: &mut Simulation<2>,
    after_assembly: &dyn Fn(&mut World),
    symmetric: bool,
) -> (f64, f64) {
    let f0 = internal_force_of::<M>(sim, after_assembly);
    assert!(f0.iter().all(|v| v.is_finite()));
    let n = f0.len();
    let k: Vec<Vec<f64>> = {
        let newton = sim.world.resource::<Newton>();
        (0..n)
            .map(|r| (0..n).map(|c| newton.matrix.get(r, c)).collect())
            .collect()
    };
    let scale = k.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    let h = 1e-6;
    let mut worst = 0.0f64;
    for col in 0..n {
        let (node, c) = slot_of(sim, col);
        let set = |sim: &mut Simulation<2>, value: f64| {
            sim.world.resource_mut::<GridFields<2>>().increment[node][c] = value;
        };
        let base = sim.world.resource::<GridFields<2>>().increment[node][c];
        set(sim, base + h);
        let fp = internal_force_of::<M>(sim, after_assembly);
        set(sim, base - h);
        let fm = internal_force_of::<M>(sim, after_assembly);
        set(sim, base);
        for row in 0..n {
            let fd = (fp[row] - fm[row]) / (2.0 * h);
            worst = worst.max((fd - k[row][col]).abs());
        }
    }
    assert!(
        worst < 1e-6 * scale,
        "max |K - K_fd| = {worst:e}, scale {scale:e}"
    );
    if symmetric {
        for r in 0..n {
            for c in 0..n {
                assert!((k[r][c] - k[c][r]).abs() < 1e-9 * scale);
            }
        }
    }
    (worst, scale)
}

/// The world's load-step, Newton and output schedules build without ambiguities (they are
/// configured to make any ambiguity an error).
pub fn assert_schedules_unambiguous<const D: usize>(sim: &mut Simulation<D>) {
    for label in [
        StepSchedule.intern(),
        NewtonSchedule.intern(),
        OutputSchedule.intern(),
        RollbackSchedule.intern(),
    ] {
        sim.world.schedule_scope(label, |world, schedule| {
            schedule
                .initialize(world)
                .unwrap_or_else(|e| panic!("{label:?}: {e}"));
        });
    }
}

/// Largest difference between two stress profiles (`(position, stress)` pairs at the same
/// positions) relative to the largest stress of `b`.
pub fn stress_difference(a: &[(f64, f64)], b: &[(f64, f64)]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().map(|p| p.1.abs()).fold(0.0, f64::max);
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            assert_eq!(p.0, q.0);
            (p.1 - q.1).abs() / scale
        })
        .fold(0.0, f64::max)
}

/// The largest load factor of a run's steps, and its first peak: the load factor and the
/// measure `measure` of the last step before the load factor first falls (panics if it never
/// falls: the run did not pass a limit).
pub fn largest_and_first_peak(
    steps: &[impm::records::StepRecord],
    measure: &str,
) -> (f64, (f64, f64)) {
    let largest = steps
        .iter()
        .map(|s| s.load_factor)
        .fold(f64::NEG_INFINITY, f64::max);
    let first_peak = steps
        .windows(2)
        .find(|w| w[1].load_factor < w[0].load_factor)
        .map(|w| (w[0].load_factor, w[0].measure(measure).unwrap()))
        .expect("the load factor falls after a peak");
    (largest, first_peak)
}

/// The staged block of `tests/arc_length_staged.rs` and `tests/stages_switch.rs`: an elastic
/// block 1 × 1 (Hencky `m`, E = 1000, ν = 0.3, density 1; quadratic B-splines, 2 × 2 cells under
/// a row of empty ones, 3 × 3 points per cell), its base on rollers (fix1: vertical), its sides
/// on rollers (fix2). Stage "gravity" brings its weight on in 2 steps by load control; stage
/// "load" (the last) is under the arc when `control` is `arc_length`, else at `factors`.
/// `materials`: lines declaring more materials after `m`; `load`: the load stage's lines.
pub fn staged_block(materials: &str, control: &str, factors: &[f64], load: &str) -> String {
    let factors: Vec<String> = factors.iter().map(|f| format!("{f:?}")).collect();
    let arc = control == "arc_length";
    format!(
        "grid(#{{ lower: [0.0, 0.0], upper: [1.0, 1.5], cells: [2, 3], basis: \"bspline\", order: 2 }});\n\
         const m = material(#{{ name: \"m\", E: 1000.0, nu: 0.3, density: 1.0 }});\n\
         {materials}\
         body(#{{ name: \"block\", material: m, region: box([0.0, 0.0], [1.0, 1.0]), ppc: 3 }});\n\
         fix(|x| x[1] == 0.0, [1]);\n\
         fix(|x| x[0] == 0.0 || x[0] == 1.0, [0]);\n\
         solver(#{{ tolerance: 1e-11, linear: \"direct\"{} }});\n\
         stage(#{{ name: \"gravity\", steps: 2 }});\n\
         body_force([0.0, -10.0]);\n\
         stage(#{{ name: \"load\", load_factors: [{}]{} }});\n\
         {load}",
        if arc {
            ", target_iterations: 3, max_load_factor: 3.0"
        } else {
            ""
        },
        factors.join(", "),
        if arc { ", control: \"arc_length\"" } else { "" },
    )
}

/// Every point's Kirchhoff stress and plastic strain, in `PointId` order, for bodies of the
/// models `A` and `B` (tests of `material_of`): the plastic strain is `strain_a` of an `A`
/// point's committed history, `strain_b` of a `B` point's, `None` for a point of neither.
pub fn point_states<A: Material, B: Material>(
    sim: &mut Simulation<2>,
    strain_a: impl Fn(&A::History) -> f64,
    strain_b: impl Fn(&B::History) -> f64,
) -> Vec<(nalgebra::Matrix3<f64>, Option<f64>)> {
    use impm::components::{PointId, Trial};
    use impm::stages::PointHistory;
    let mut query = sim.world.query::<(
        &PointId,
        &Trial<2>,
        Option<&PointHistory<A>>,
        Option<&PointHistory<B>>,
    )>();
    let mut rows: Vec<_> = query
        .iter(&sim.world)
        .map(|(id, trial, a, b)| {
            let strain = a
                .map(|h| strain_a(&h.committed))
                .or(b.map(|h| strain_b(&h.committed)));
            (id.0, (trial.0.kirchhoff, strain))
        })
        .collect();
    rows.sort_by_key(|row| row.0);
    rows.into_iter().map(|row| row.1).collect()
}

/// A stiff, non-symmetric system (docs/distributed.md, "A stiff, non-symmetric ring"): a
/// quarter ring (1 ≤ r ≤ 2, linear MPM, 10 × 10 cells, 4 × 4 points per cell), von Mises
/// with F-bar, driven radially on its bore by a penalty surface condition (γ = 1e4) to
/// u_r = 0.02 in 3 steps; `solver_call` ends it.
pub fn stiff_ring(solver_call: &str) -> String {
    format!(
        r#"const wall = material(#{{ name: "wall", model: "von_mises", E: 500.0, nu: 0.3, sigma_y: 1.0, density: 1.0 }});
grid(#{{ lower: [0.0, 0.0], upper: [2.5, 2.5], cells: [10, 10], basis: "linear" }});
body(#{{
    name: "wall",
    material: wall,
    region: |x| {{
        let r2 = x[0] * x[0] + x[1] * x[1];
        x[0] >= 0.0 && x[1] >= 0.0 && r2 >= 1.0 && r2 <= 4.0
    }},
    ppc: 4,
    fbar: true,
}});
fix(|x| x[0] == 0.0, [0]);
fix(|x| x[1] == 0.0, [1]);
surface_displace(#{{ on: arc(#{{ centre: [0.0, 0.0], radius: 1.0, from: 0.0, to: 90.0 }}), radial: 0.02, name: "bore" }});
{solver_call}
load_steps(3);
"#
    )
}
