//! The driver: builds the world from a scene and runs its load steps.
//!
//! ```text
//! build world (nodes, points, resources, schedules)     Simulation::new
//! write the initial state                              Simulation::write_initial_state
//! for each load step k = 1..n:                          Simulation::step
//!     run the LoadStep schedule (connectivity, DOFs, loads, Newton, G2P, output, reset)
//!     record iterations, residuals, stage times, error  -> summary.json
//! ```

use std::path::{Path, PathBuf};
use std::time::Instant;

use bevy_ecs::prelude::*;
use nalgebra::{SMatrix, SVector};

use crate::analytic::SelfWeightColumn;
use crate::basis::{BasisKind, GridBasis};
use crate::components::*;
use crate::material::Hencky;
use crate::mechanics::TrialState;
use crate::resources::*;
use crate::scene::{AnalyticSpec, SceneSpec};
use crate::stages::output::OutputPlan;
use crate::stages::{Effects, LoadStep as LoadStepSchedule, WriteOutput, add_schedules};
use crate::summary::{StepRecord, Summary};

/// Why a simulation could not be built from a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildError(pub String);

impl std::fmt::Display for BuildError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BuildError {}

/// A simulation of dimension `D`: the world and its schedules.
pub struct Simulation<const D: usize> {
    pub world: World,
    pub spec: SceneSpec,
    pub summary: Summary,
    steps_done: usize,
}

/// The effects a scene uses, which decide the systems in its schedules.
pub fn effects_of(spec: &SceneSpec) -> Effects {
    Effects {
        body_force: spec
            .body_force
            .as_ref()
            .is_some_and(|b| b.iter().any(|&c| c != 0.0)),
        point_loads: spec
            .point_loads
            .iter()
            .any(|load| load.force.iter().any(|&c| c != 0.0)),
        tractions: spec
            .tractions
            .iter()
            .any(|point| point.traction.iter().any(|&c| c != 0.0)),
        prescribed_displacements: spec.constraints.iter().any(|c| c.value != 0.0),
    }
}

impl<const D: usize> Simulation<D> {
    /// Builds the world for `spec`, writing results to `out_dir`.
    pub fn new(spec: &SceneSpec, out_dir: &Path) -> Result<Self, BuildError> {
        if spec.dim() != D {
            return Err(BuildError(format!(
                "scene is {}D, simulation is {D}D",
                spec.dim()
            )));
        }
        let basis = GridBasis::<D>::new(
            &spec.grid.lower,
            &spec.grid.upper,
            &spec.grid.cells,
            spec.grid.basis,
        )
        .map_err(BuildError)?;
        std::fs::create_dir_all(out_dir).map_err(|e| {
            BuildError(format!(
                "cannot create the output folder {}: {e}",
                out_dir.display()
            ))
        })?;
        let mut world = World::new();

        // Grid nodes (control points) and their constraints.
        let mut fixities = vec![Fixity::<D>::default(); basis.num_nodes()];
        for c in &spec.constraints {
            let fixity = fixities.get_mut(c.node).ok_or_else(|| {
                BuildError(format!("constraint on node {} outside the grid", c.node))
            })?;
            if c.component >= D {
                return Err(BuildError(format!(
                    "constraint on component {} in {D}D",
                    c.component
                )));
            }
            fixity.fixed[c.component] = true;
            fixity.prescribed[c.component] = c.value;
        }
        world.spawn_batch(
            fixities
                .into_iter()
                .enumerate()
                .map(|(index, fixity)| {
                    (
                        GridNode {
                            index,
                            position: basis.node_position(index),
                        },
                        fixity,
                    )
                })
                .collect::<Vec<_>>(),
        );

        // Material points.
        let mut id = 0u32;
        for (body_index, body) in spec.bodies.iter().enumerate() {
            let material_spec = spec
                .materials
                .get(body.material)
                .ok_or_else(|| BuildError(format!("body '{}' names no material", body.name)))?;
            let material =
                Hencky::new(material_spec.youngs_modulus, material_spec.poisson_ratio)
                    .map_err(|e| BuildError(format!("material '{}': {e}", material_spec.name)))?;
            let undeformed = TrialState::<D>::undeformed(&material);
            let mut batch = Vec::with_capacity(body.points.len());
            for seed in &body.points {
                if seed.position.len() != D {
                    return Err(BuildError(format!(
                        "body '{}': point of dimension {}",
                        body.name,
                        seed.position.len()
                    )));
                }
                let x = SVector::<f64, D>::from_fn(|a, _| seed.position[a]);
                batch.push((
                    (
                        PointId(id),
                        Position(x),
                        ReferencePosition(x),
                        Displacement(SVector::<f64, D>::zeros()),
                    ),
                    (
                        DeformationGradient(SMatrix::<f64, D, D>::identity()),
                        Mass(material_spec.density * seed.volume),
                    ),
                    (
                        ReferenceVolume(seed.volume),
                        Volume(seed.volume),
                        Elastic(material),
                        BodyIndex(body_index as u32),
                    ),
                    (Support::<D>::default(), Trial(undeformed.clone())),
                ));
                id += 1;
            }
            world.spawn_batch(batch);
        }
        if id == 0 {
            return Err(BuildError("the scene has no material points".into()));
        }
        let point_entities = point_entities(&mut world, spec.point_count());
        insert_point_loads::<D>(&mut world, spec, &point_entities)?;
        spawn_traction_points::<D>(&mut world, spec, &point_entities)?;

        // Resources.
        let effects = effects_of(spec);
        if let Some(b) = &spec.body_force {
            if b.len() != D {
                return Err(BuildError(format!(
                    "body force has {} components in {D}D",
                    b.len()
                )));
            }
            world.insert_resource(BodyForce(SVector::<f64, D>::from_fn(|a, _| b[a])));
        }
        world.insert_resource(GridFields::<D>::new(basis.num_nodes()));
        world.insert_resource(Grid(basis));
        world.insert_resource(LoadStep::default());
        world.insert_resource(NewtonSettings {
            tolerance: spec.solver.tolerance,
            max_iterations: spec.solver.max_iterations,
        });
        world.insert_resource(Newton::default());
        world.insert_resource(RunStatus::default());
        world.insert_resource(StageClock::default());
        world.insert_resource(OutputPlan::from_spec(
            out_dir.to_path_buf(),
            &spec.output,
            spec.load_factors.len(),
        ));
        add_schedules::<D>(&mut world, effects);

        let summary = Summary::new(
            spec,
            id as usize,
            world.resource::<GridFields<D>>().active.len(),
            out_dir,
        );
        Ok(Self {
            world,
            spec: spec.clone(),
            summary,
            steps_done: 0,
        })
    }

    /// Number of load steps done.
    pub fn steps_done(&self) -> usize {
        self.steps_done
    }

    /// Writes the initial state (step 0) and the summary.
    pub fn write_initial_state(&mut self) -> Result<(), SolverError> {
        *self.world.resource_mut::<LoadStep>() = LoadStep::default();
        self.world.run_schedule(WriteOutput);
        self.take_failure()?;
        self.summary
            .write()
            .map_err(|e| SolverError::Output { step: 0, why: e })
    }

    /// Solves the next load step. On failure the error is also recorded in the summary.
    pub fn step(&mut self) -> Result<&StepRecord, SolverError> {
        let number = self.steps_done + 1;
        let factor = self.spec.load_factors[number - 1];
        let previous_factor = if number == 1 {
            0.0
        } else {
            self.spec.load_factors[number - 2]
        };
        *self.world.resource_mut::<LoadStep>() = LoadStep {
            number,
            factor,
            previous_factor,
        };
        *self.world.resource_mut::<StageClock>() = StageClock::default();
        let start = Instant::now();
        self.world.run_schedule(LoadStepSchedule);
        let wall = start.elapsed().as_secs_f64();
        let newton = self.world.resource::<Newton>();
        let mut record = StepRecord {
            step: number,
            load_factor: factor,
            iterations: newton.iterations,
            residuals: newton.residuals.clone(),
            converged: newton.converged,
            dofs: newton.system.size(),
            seconds: self.world.resource::<StageClock>().clone(),
            wall_seconds: wall,
            error: None,
        };
        if let Err(e) = self.take_failure() {
            self.summary.fail(record, &e);
            let _ = self.summary.write();
            return Err(e);
        }
        record.error = self.analytic_error(factor);
        self.steps_done = number;
        self.summary.push(record);
        self.summary.write().map_err(|e| SolverError::Output {
            step: number,
            why: e,
        })?;
        Ok(self.summary.steps.last().expect("just pushed"))
    }

    /// Runs all remaining load steps, calling `on_step` after each.
    pub fn run(&mut self, mut on_step: impl FnMut(&StepRecord)) -> Result<(), SolverError> {
        while self.steps_done < self.spec.load_factors.len() {
            let record = self.step()?;
            on_step(record);
        }
        self.summary.finish();
        self.summary.write().map_err(|e| SolverError::Output {
            step: self.steps_done,
            why: e,
        })
    }

    fn take_failure(&mut self) -> Result<(), SolverError> {
        match self.world.resource_mut::<RunStatus>().0.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// The scene's analytic error measure (paper eq. 15) at load factor `factor`, if declared.
    pub fn analytic_error(&mut self, factor: f64) -> Option<f64> {
        let AnalyticSpec::Column {
            axis,
            height,
            density,
            body_force,
            modulus,
        } = self.spec.analytic.clone()?;
        let column = SelfWeightColumn {
            density,
            body_force: body_force * factor,
            height,
            modulus,
        };
        let mut query = self
            .world
            .query::<(&ReferencePosition<D>, &ReferenceVolume, &Trial<D>)>();
        let points: Vec<(f64, f64, f64)> = query
            .iter(&self.world)
            .map(|(x, v, t)| (x.0[axis], v.0, t.0.cauchy()[(axis, axis)]))
            .collect();
        Some(column.error(points))
    }

    /// Points' (reference coordinate, Cauchy stress component) along `axis`, sorted by the
    /// reference coordinate. For tests and studies.
    pub fn stress_profile(&mut self, axis: usize) -> Vec<(f64, f64)> {
        let mut query = self.world.query::<(&ReferencePosition<D>, &Trial<D>)>();
        let mut out: Vec<(f64, f64)> = query
            .iter(&self.world)
            .map(|(x, t)| (x.0[axis], t.0.cauchy()[(axis, axis)]))
            .collect();
        out.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }
}

/// The entity of every material point, indexed by `PointId`.
fn point_entities(world: &mut World, count: usize) -> Vec<Entity> {
    let mut entities = vec![Entity::PLACEHOLDER; count];
    for (entity, id) in world.query::<(Entity, &PointId)>().iter(world) {
        entities[id.0 as usize] = entity;
    }
    entities
}

/// Gives the points named by the scene's point loads a [`PointLoad`] component.
fn insert_point_loads<const D: usize>(
    world: &mut World,
    spec: &SceneSpec,
    entities: &[Entity],
) -> Result<(), BuildError> {
    for load in &spec.point_loads {
        let entity = *entities.get(load.point).ok_or_else(|| {
            BuildError(format!(
                "point load on point {} which does not exist",
                load.point
            ))
        })?;
        if load.force.len() != D {
            return Err(BuildError(format!(
                "point load with {} components in {D}D",
                load.force.len()
            )));
        }
        let force = SVector::<f64, D>::from_fn(|a, _| load.force[a]);
        world.entity_mut(entity).insert(PointLoad(force));
    }
    Ok(())
}

/// Spawns the scene's traction points (entities with a [`TractionPoint`] only).
fn spawn_traction_points<const D: usize>(
    world: &mut World,
    spec: &SceneSpec,
    entities: &[Entity],
) -> Result<(), BuildError> {
    let vector = |values: &[f64], what: &str| {
        if values.len() != D {
            return Err(BuildError(format!(
                "traction point {what} with {} components in {D}D",
                values.len()
            )));
        }
        Ok(SVector::<f64, D>::from_fn(|a, _| values[a]))
    };
    let mut batch = Vec::with_capacity(spec.tractions.len());
    for (id, point) in spec.tractions.iter().enumerate() {
        let position = vector(&point.position, "position")?;
        let host = *entities.get(point.host).ok_or_else(|| {
            BuildError(format!("traction point host {} does not exist", point.host))
        })?;
        let host_position = world
            .get::<ReferencePosition<D>>(host)
            .ok_or_else(|| BuildError("traction point host is not a material point".into()))?
            .0;
        batch.push(TractionPoint {
            id: id as u32,
            position,
            reference_position: position,
            host,
            offset: position - host_position,
            area: point.area,
            traction: vector(&point.traction, "traction")?,
            support: Vec::new(),
        });
    }
    world.spawn_batch(batch);
    Ok(())
}

/// A human name for a basis.
pub fn basis_name(kind: BasisKind) -> String {
    match kind {
        BasisKind::Linear => "linear".into(),
        BasisKind::BSpline { order } => format!("bspline(q={order})"),
    }
}

/// Runs a whole scene in dimension `spec.dim()`, writing to `out_dir` (with plugins:
/// [`crate::plugin::run_scene_with`]).
pub fn run_scene(
    spec: &SceneSpec,
    out_dir: &Path,
    on_step: impl FnMut(&StepRecord),
) -> Result<Summary, RunError> {
    crate::plugin::run_scene_with(spec, out_dir, &(), on_step)
}

/// A failed run.
#[derive(Debug)]
pub enum RunError {
    Build(BuildError),
    Solve(SolverError),
}

impl std::fmt::Display for RunError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunError::Build(e) => write!(f, "cannot set up the simulation: {e}"),
            RunError::Solve(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for RunError {}

/// The default output folder of a scene: `out/<scene name>/`.
pub fn default_output_dir(spec: &SceneSpec) -> PathBuf {
    Path::new("out").join(&spec.name)
}
