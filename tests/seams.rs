//! The seams of the architecture that are not exercised by a scene alone: saving and restoring
//! a simulation part by part, and the one-provider rule of replaceable stages.

mod common;

use impm::components::{DeformationGradient, PointId, Position, Trial};
use impm::effects;
use impm::plugin::{Extension, Hook, Plugin};
use impm::run::{Simulation, load_scene};
use impm::scene::SceneSpec;

fn shipped(name: &str, set: &[(&str, &str)]) -> SceneSpec {
    load_scene(&common::shipped_scene(name), &common::overrides(set)).unwrap()
}

/// Every point's position, F and stress, in point order, as bits.
fn state<const D: usize>(sim: &mut Simulation<D>) -> Vec<u64> {
    let mut rows: Vec<_> = sim
        .world
        .query::<(&PointId, &Position<D>, &DeformationGradient<D>, &Trial<D>)>()
        .iter(&sim.world)
        .map(|(id, x, f, t)| {
            let mut bits: Vec<u64> = x.0.iter().map(|v| v.to_bits()).collect();
            bits.extend(f.0.iter().map(|v| v.to_bits()));
            bits.extend(t.0.kirchhoff.iter().map(|v| v.to_bits()));
            (id.0, bits)
        })
        .collect();
    rows.sort_by_key(|(id, _)| *id);
    rows.into_iter().flat_map(|(_, bits)| bits).collect()
}

/// A run saved after `k` steps and restored into a fresh simulation of the same scene ends
/// bit-identical to the uninterrupted run, output files included.
fn restored_run_is_identical<const D: usize>(spec: &SceneSpec, k: usize, tag: &str) {
    let dir = common::temp_dir("seams", tag);
    let mut whole = Simulation::<D>::new(spec, &dir.join("whole")).unwrap();
    whole.write_initial_state().unwrap();
    whole.run(|_| {}).unwrap();

    let mut first = Simulation::<D>::new(spec, &dir.join("second")).unwrap();
    first.write_initial_state().unwrap();
    for _ in 0..k {
        first.step().unwrap();
    }
    let saved = first.save_state();
    assert_eq!(saved.steps_done, k);
    drop(first);
    let mut second = Simulation::<D>::new(spec, &dir.join("second")).unwrap();
    second.restore_state(&saved).unwrap();
    second.run(|_| {}).unwrap();
    assert_eq!(state(&mut whole), state(&mut second), "{tag}");
    let last = format!("particles_{:04}.vtu", spec.load_factors.len());
    let read = |run: &str| std::fs::read(dir.join(run).join(&last)).unwrap();
    assert_eq!(read("whole"), read("second"), "{tag}: {last}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_saved_state_restores_to_a_bit_identical_run() {
    // traction points follow the material: their positions are a module's part
    let footing = shipped("footing_traction.rhai", &[]);
    let names: Vec<String> = {
        let mut sim = Simulation::<2>::new(&footing, &common::temp_dir("seams", "names")).unwrap();
        sim.save_state()
            .parts
            .into_iter()
            .map(|(name, _)| name)
            .collect()
    };
    assert_eq!(names, ["points", "traction points"]);
    restored_run_is_identical::<2>(&footing, 2, "footing");
    // the FEM mesh moves with the body: its node positions are a module's part
    let fem = shipped(
        "column_1d.rhai",
        &[("basis", "fem"), ("ppc", "2"), ("steps", "6")],
    );
    restored_run_is_identical::<1>(&fem, 3, "fem");
    let cpdi = shipped(
        "column_2d.rhai",
        &[("basis", "cpdi"), ("cells", "10"), ("steps", "4")],
    );
    restored_run_is_identical::<2>(&cpdi, 1, "cpdi");
}

#[test]
fn a_saved_state_of_another_scene_is_refused() {
    let footing = shipped("footing_traction.rhai", &[]);
    let column = shipped("column_2d.rhai", &[("cells", "10")]);
    let mut a = Simulation::<2>::new(&footing, &common::temp_dir("seams", "a")).unwrap();
    let saved = a.save_state();
    let mut b = Simulation::<2>::new(&column, &common::temp_dir("seams", "b")).unwrap();
    let error = b.restore_state(&saved).unwrap_err();
    assert!(error.contains("parts"), "{error}");
}

/// A second module providing a replaceable stage (here the basis of a GIMP scene, which the
/// point-domains module provides) is a build error naming both.
#[test]
fn a_replaceable_stage_has_one_provider() {
    struct MyBasis;
    fn my_basis() {}
    impl Plugin for MyBasis {
        fn name(&self) -> &'static str {
            "my basis"
        }
        fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
            simulation.provide(Hook::Basis, "my basis", my_basis);
        }
    }
    let spec = shipped("column_1d.rhai", &[("basis", "gimp")]);
    let modules = effects::built_in().with(MyBasis);
    let error =
        Simulation::<1>::with_modules(&spec, &common::temp_dir("seams", "provider"), &modules)
            .err()
            .unwrap()
            .to_string();
    assert!(
        error.contains("my basis and basis averaged over domains both provide Basis"),
        "{error}"
    );
    // alone (a point-basis scene), it replaces the core's default
    let spec = shipped("column_1d.rhai", &[]);
    let mut sim =
        Simulation::<1>::with_modules(&spec, &common::temp_dir("seams", "alone"), &modules)
            .unwrap();
    let systems = impm::explain::scheduled_systems(&mut sim.world).unwrap();
    let basis: Vec<&str> = systems
        .iter()
        .filter(|s| s.stage.as_deref() == Some("Hook::Basis"))
        .map(|s| s.name.as_str())
        .collect();
    assert_eq!(
        basis,
        ["seams::a_replaceable_stage_has_one_provider::my_basis"]
    );
}
