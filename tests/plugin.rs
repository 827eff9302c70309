//! The plugin API: systems added at each hook run where the hook says, show up in the
//! explained schedules, and an ambiguous plugin is a clear build error.

mod common;

use std::path::{Path, PathBuf};

use bevy_ecs::prelude::*;

use impm::components::Position;
use impm::explain::scheduled_systems;
use impm::plugin::{Extension, Hook, Plugin};
use impm::resources::{GridFields, LoadStep, Newton};
use impm::run::Simulation;
use impm::run::load_scene;
use impm::stages::output::OutputPlan;

fn temp_dir(name: &str) -> PathBuf {
    common::temp_dir("plugin", name)
}

/// What each hook saw, in the order the hooks ran.
#[derive(Resource, Default)]
struct Seen(Vec<String>);

struct Probe;

fn at_loads(step: Res<LoadStep>, fields: Res<GridFields<1>>, mut seen: ResMut<Seen>) {
    // the built-in body force is in, nothing is assembled yet (the grid was reset)
    let total: f64 = fields.external_force.iter().map(|f| f[0]).sum();
    let internal = fields.internal_force.iter().any(|f| f[0] != 0.0);
    seen.0.push(format!(
        "loads {} f_ext {:.6} internal {internal}",
        step.number, total
    ));
}

fn before_assembly(newton: Res<Newton>, fields: Res<GridFields<1>>, mut seen: ResMut<Seen>) {
    let internal: f64 = fields.internal_force.iter().map(|f| f[0].abs()).sum();
    seen.0.push(format!(
        "before {} internal {}",
        newton.residuals.len(),
        internal > 0.0
    ));
}

fn after_assembly(newton: Res<Newton>, fields: Res<GridFields<1>>, mut seen: ResMut<Seen>) {
    let internal: f64 = fields.internal_force.iter().map(|f| f[0].abs()).sum();
    seen.0.push(format!(
        "after {} internal {}",
        newton.residuals.len(),
        internal > 0.0
    ));
}

fn after_step(
    step: Res<LoadStep>,
    fields: Res<GridFields<1>>,
    points: Query<&Position<1>>,
    mut seen: ResMut<Seen>,
) {
    // points moved, the grid is not reset yet
    let lowest = points.iter().map(|x| x.0[0]).fold(f64::INFINITY, f64::min);
    let moving = fields.increment.iter().any(|du| du[0] != 0.0);
    seen.0.push(format!(
        "step {} moved {} grid {}",
        step.number,
        lowest < 0.25,
        moving
    ));
}

fn at_output(step: Res<LoadStep>, plan: Res<OutputPlan>, mut seen: ResMut<Seen>) {
    let file = plan.dir.join(format!("particles_{:04}.vtu", step.number));
    seen.0
        .push(format!("output {} file {}", step.number, file.exists()));
}

impl Plugin for Probe {
    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        assert_eq!(D, 1, "the probe is for 1D scenes");
        simulation.world().insert_resource(Seen::default());
        let world = simulation.world();
        assert!(world.contains_resource::<GridFields<1>>());
        simulation
            .add_systems(Hook::Loads, at_loads)
            .add_systems(Hook::BeforeAssembly, before_assembly)
            .add_systems(Hook::AfterAssembly, after_assembly)
            .add_systems(Hook::AfterStep, after_step)
            .add_systems(Hook::Output, at_output);
    }
}

fn column(dir: &Path) -> impm::scene::SceneSpec {
    let path = dir.join("column.rhai");
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(
        &path,
        r#"grid(#{ lower: [0.0], upper: [10.0], cells: [10], basis: "bspline", order: 2 });
const m = material(#{ name: "m", E: 1.0e5, nu: 0.0, density: 1.0 });
body(#{ name: "column", material: m, region: box([0.0], [10.0]), ppc: 2 });
body_force([-100.0]);
fix(|x| x[0] == 0.0);
load_steps(2);
"#,
    )
    .unwrap();
    load_scene(&path, &[]).unwrap()
}

#[test]
fn hooks_run_where_they_say() {
    let dir = temp_dir("hooks");
    let spec = column(&dir);
    let mut sim = Simulation::<1>::new(&spec, &dir.join("out")).unwrap();
    sim.add_plugin(&Probe).unwrap();
    sim.write_initial_state().unwrap();
    sim.run(|_| {}).unwrap();
    let seen = &sim.world.resource::<Seen>().0;
    let iterations: Vec<usize> = sim.summary.steps.iter().map(|s| s.iterations).collect();
    // expected sequence, built from the Newton iteration counts of the summary
    let mut expected = vec!["output 0 file true".to_string()];
    for (k, &n) in iterations.iter().enumerate() {
        let step = k + 1;
        // weight 10 x 100 at load factor step / 2, on the free nodes and the fixed one
        expected.push(format!(
            "loads {step} f_ext {:.6} internal false",
            -500.0 * step as f64
        ));
        // the first assembly of step 1 is of the unstressed state; before the first assembly
        // of a step the internal force is the reset zero, later the previous iteration's
        let assembled = |i: usize| step > 1 || i > 0;
        for i in 0..=n {
            expected.push(format!("before {i} internal {}", i > 0 && assembled(i - 1)));
            expected.push(format!("after {i} internal {}", assembled(i)));
        }
        expected.push(format!("step {step} moved true grid true"));
        expected.push(format!("output {step} file true"));
    }
    assert_eq!(seen, &expected);
}

#[test]
fn plugin_systems_are_listed_at_their_hook_and_ambiguity_is_an_error() {
    let dir = temp_dir("explain");
    let spec = column(&dir);
    let mut sim = Simulation::<1>::new(&spec, &dir.join("out")).unwrap();
    sim.add_plugin(&Probe).unwrap();
    let systems = scheduled_systems(&mut sim.world).unwrap();
    let probe: Vec<(&str, &str)> = systems
        .iter()
        .filter(|s| s.name.starts_with("plugin::"))
        .map(|s| (s.stage.as_deref().unwrap_or("-"), s.name.as_str()))
        .collect();
    assert_eq!(
        probe,
        [
            ("Hook::Loads", "plugin::at_loads"),
            ("Hook::AfterStep", "plugin::after_step"),
            ("Hook::BeforeAssembly", "plugin::before_assembly"),
            ("Hook::AfterAssembly", "plugin::after_assembly"),
            ("Hook::Output", "plugin::at_output"),
        ]
    );

    struct Clash;
    fn push_a(mut fields: ResMut<GridFields<1>>) {
        fields.external_force[0][0] += 1.0;
    }
    fn push_b(mut fields: ResMut<GridFields<1>>) {
        fields.external_force[0][0] += 2.0;
    }
    impl Plugin for Clash {
        fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
            simulation.add_systems(Hook::Loads, (push_a, push_b));
        }
    }
    let mut sim = Simulation::<1>::new(&spec, &dir.join("out2")).unwrap();
    let error = sim.add_plugin(&Clash).unwrap_err().to_string();
    assert!(
        error.contains("a plugin's systems do not fit") && error.contains("push_a"),
        "{error}"
    );
    // ordered, they fit
    struct Ordered;
    impl Plugin for Ordered {
        fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
            simulation.add_systems(Hook::Loads, (push_a, push_b).chain());
        }
    }
    let mut sim = Simulation::<1>::new(&spec, &dir.join("out3")).unwrap();
    sim.add_plugin(&Ordered).unwrap();
    sim.step().unwrap();
}
