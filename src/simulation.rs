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
use nalgebra::{Matrix3, SMatrix, SVector};

use crate::analytic::SelfWeightColumn;
use crate::basis::{BasisKind, GridBasis};
use crate::components::*;
use crate::material::Hencky;
use crate::mechanics::TrialState;
use crate::plugin::Plugin;
use crate::resources::*;
use crate::scene::{AnalyticSpec, PointSeed, SceneSpec};
use crate::stages::output::OutputPlan;
use crate::stages::{Effects, LoadStep as LoadStepSchedule, WriteOutput, add_schedules};
use crate::summary::{StepRecord, SubstepRecord, Summary};

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
        ghost_penalty: spec.solver.ghost_penalty > 0.0,
        stress_recovery: spec.recovery.is_some(),
        fem_mesh: spec.grid.basis == BasisKind::Fem,
        point_domains: spec.grid.basis.uses_point_domain(),
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
            let spawned: Vec<Entity> = world.spawn_batch(batch).collect();
            if spec.grid.basis.uses_point_domain() {
                let domains = body
                    .points
                    .iter()
                    .map(|seed| particle_domain::<D>(&body.name, seed))
                    .collect::<Result<Vec<_>, _>>()?;
                world.insert_batch(spawned.iter().copied().zip(domains));
            }
            if spec.recovery.is_some() {
                world.insert_batch(
                    spawned
                        .into_iter()
                        .map(|entity| (entity, RecoveredStress(Matrix3::zeros()))),
                );
            }
        }
        if id == 0 {
            return Err(BuildError("the scene has no material points".into()));
        }
        let point_entities = point_entities(&mut world, spec.point_count());
        insert_point_loads::<D>(&mut world, spec, &point_entities)?;
        spawn_traction_points::<D>(&mut world, spec, &point_entities)?;

        // Resources.
        let effects = effects_of(spec);
        if effects.fem_mesh && effects.tractions {
            return Err(BuildError(
                "tractions act through the background grid's basis; a finite-element mesh (basis fem) has none".into(),
            ));
        }
        if effects.fem_mesh && effects.ghost_penalty {
            return Err(BuildError(
                "the ghost penalty stabilises nearly empty MPM cells; a finite-element mesh (basis fem) has none".into(),
            ));
        }
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
        if effects.fem_mesh {
            crate::fem::attach_mesh::<D>(&mut world).map_err(BuildError)?;
        }
        world.insert_resource(LoadStep::default());
        world.insert_resource(NewtonSettings {
            tolerance: spec.solver.tolerance,
            max_iterations: spec.solver.max_iterations,
        });
        world.insert_resource(Newton::default());
        if let Some(recovery) = spec.recovery {
            world.insert_resource(StressRecovery {
                order: recovery.order,
                radius_in_cells: recovery.radius_in_cells,
            });
        }
        world.insert_resource(RunStatus::default());
        world.insert_resource(StageClock::default());
        world.insert_resource(OutputPlan::from_spec(
            out_dir.to_path_buf(),
            &spec.output,
            spec.load_factors.len(),
        ));
        if effects.ghost_penalty {
            let modulus = spec
                .materials
                .iter()
                .map(|m| m.youngs_modulus)
                .fold(0.0, f64::max);
            world.insert_resource(crate::stages::ghost::GhostPenalty {
                gamma_modulus: spec.solver.ghost_penalty * modulus,
                faces: Vec::new(),
            });
        }
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

    /// Solves the next load step, cutting it when Newton fails.
    ///
    /// Load-step cutting: the step from λ_n to λ_{n+1} is tried whole; when Newton does not
    /// converge, diverges, meets an inadmissible point (det F <= 0) or a singular tangent, the
    /// grid is reset (points are only updated after convergence, so nothing else needs undoing)
    /// and the attempt is repeated with half the increment, down to 2^-max_step_cuts of the
    /// step. After a successful sub-step the increment grows back by a factor 2. Output is
    /// written only when the step's target load factor is reached. On failure the error is
    /// also recorded in the summary.
    pub fn step(&mut self) -> Result<&StepRecord, SolverError> {
        let number = self.steps_done + 1;
        let target = self.spec.load_factors[number - 1];
        let start_factor = if number == 1 {
            0.0
        } else {
            self.spec.load_factors[number - 2]
        };
        let full = target - start_factor;
        let max_cuts = self.spec.solver.max_step_cuts;
        *self.world.resource_mut::<StageClock>() = StageClock::default();
        let start = Instant::now();
        let mut record = StepRecord {
            step: number,
            load_factor: target,
            iterations: 0,
            residuals: Vec::new(),
            converged: false,
            dofs: 0,
            seconds: StageClock::default(),
            wall_seconds: 0.0,
            error: None,
            cuts: 0,
            substeps: Vec::new(),
            error_recovered: None,
        };
        let (mut from, mut level) = (start_factor, 0usize);
        loop {
            let increment = full / f64::powi(2.0, level as i32);
            // The last sub-step lands exactly on the target.
            let completes_step = (from + increment - target).abs()
                <= 1e-12 * full.abs().max(1e-300)
                || (full > 0.0 && from + increment >= target)
                || (full < 0.0 && from + increment <= target)
                || full == 0.0;
            let to = if completes_step {
                target
            } else {
                from + increment
            };
            *self.world.resource_mut::<LoadStep>() = LoadStep {
                number,
                factor: to,
                previous_factor: from,
                completes_step,
            };
            self.world.run_schedule(LoadStepSchedule);
            let newton = self.world.resource::<Newton>();
            let mut attempt = SubstepRecord {
                from,
                to,
                iterations: newton.iterations,
                residuals: newton.residuals.clone(),
                converged: newton.converged,
                failure: None,
            };
            record.iterations += newton.iterations;
            record.dofs = newton.system.size();
            match self.take_failure() {
                Ok(()) => {
                    record.residuals = attempt.residuals.clone();
                    record.converged = true;
                    record.substeps.push(attempt);
                    if completes_step {
                        break;
                    }
                    from = to;
                    level = level.saturating_sub(1);
                }
                Err(e) => {
                    attempt.failure = Some(e.to_string());
                    record.residuals = attempt.residuals.clone();
                    record.substeps.push(attempt);
                    let recoverable = e.is_recoverable_by_cutting();
                    if !recoverable || level >= max_cuts {
                        let error = if recoverable && record.cuts > 0 {
                            SolverError::CuttingFailed {
                                step: number,
                                cuts: record.cuts,
                                last: Box::new(e),
                            }
                        } else {
                            e
                        };
                        record.seconds = self.world.resource::<StageClock>().clone();
                        record.wall_seconds = start.elapsed().as_secs_f64();
                        self.summary.fail(record, &error);
                        let _ = self.summary.write();
                        return Err(error);
                    }
                    // Undo the failed attempt on the grid and retry with half the increment.
                    self.world.resource_mut::<GridFields<D>>().reset();
                    level += 1;
                    record.cuts += 1;
                }
            }
        }
        record.seconds = self.world.resource::<StageClock>().clone();
        record.wall_seconds = start.elapsed().as_secs_f64();
        record.error = self.analytic_error(target);
        record.error_recovered = self.analytic_error_recovered(target);
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

    /// The scene's analytic column at load factor `factor` and its axis, if declared.
    fn analytic_column(&self, factor: f64) -> Option<(SelfWeightColumn, usize)> {
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
        Some((column, axis))
    }

    /// The scene's analytic error measure (paper eq. 15) at load factor `factor`, if declared.
    pub fn analytic_error(&mut self, factor: f64) -> Option<f64> {
        let (column, axis) = self.analytic_column(factor)?;
        let mut query = self
            .world
            .query::<(&ReferencePosition<D>, &ReferenceVolume, &Trial<D>)>();
        let points: Vec<(f64, f64, f64)> = query
            .iter(&self.world)
            .map(|(x, v, t)| (x.0[axis], v.0, t.0.cauchy()[(axis, axis)]))
            .collect();
        Some(column.error(points))
    }

    /// Eq. 15 of the MLS-recovered stress at load factor `factor`, if the scene declares an
    /// analytic solution and asks for stress recovery.
    pub fn analytic_error_recovered(&mut self, factor: f64) -> Option<f64> {
        self.spec.recovery?;
        let (column, axis) = self.analytic_column(factor)?;
        let mut query = self
            .world
            .query::<(&ReferencePosition<D>, &ReferenceVolume, &RecoveredStress)>();
        let points: Vec<(f64, f64, f64)> = query
            .iter(&self.world)
            .map(|(x, v, s)| (x.0[axis], v.0, s.0[(axis, axis)]))
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

/// The initial domain of a seeded point: the box it owns.
fn particle_domain<const D: usize>(
    body: &str,
    seed: &PointSeed,
) -> Result<ParticleDomain<D>, BuildError> {
    if seed.half_lengths.len() != D
        || seed
            .half_lengths
            .iter()
            .any(|&l| !(l > 0.0 && l.is_finite()))
    {
        return Err(BuildError(format!(
            "body '{body}': the point at {:?} has domain half-lengths {:?}, not {D} positive lengths",
            seed.position, seed.half_lengths
        )));
    }
    Ok(ParticleDomain {
        initial_half_lengths: SVector::from_fn(|k, _| seed.half_lengths[k]),
    })
}

/// Runs a whole scene in dimension `spec.dim()`, writing to `out_dir` (with a plugin:
/// [`crate::plugin::run_scene_with`]).
pub fn run_scene(
    spec: &SceneSpec,
    out_dir: &Path,
    on_step: impl FnMut(&StepRecord),
) -> Result<Summary, RunError> {
    crate::plugin::run_scene_with(spec, out_dir, &(), on_step)
}

/// Like [`run_scene`], but also returns the summary of a run that failed after it was built
/// (its completed steps and the failed one), as studies record failed runs.
pub fn run_scene_keeping_summary(
    spec: &SceneSpec,
    out_dir: &Path,
    on_step: impl FnMut(&StepRecord),
) -> (Option<Summary>, Result<(), RunError>) {
    run_scene_keeping_summary_with(spec, out_dir, &(), on_step)
}

/// [`run_scene_keeping_summary`] with a plugin (see [`crate::plugin`]).
pub fn run_scene_keeping_summary_with(
    spec: &SceneSpec,
    out_dir: &Path,
    plugin: &impl Plugin,
    on_step: impl FnMut(&StepRecord),
) -> (Option<Summary>, Result<(), RunError>) {
    match spec.dim() {
        1 => run_in::<1>(spec, out_dir, plugin, on_step),
        2 => run_in::<2>(spec, out_dir, plugin, on_step),
        3 => run_in::<3>(spec, out_dir, plugin, on_step),
        d => (
            None,
            Err(RunError::Build(BuildError(format!(
                "dimension {d} is not supported (1, 2 or 3)"
            )))),
        ),
    }
}

fn run_in<const D: usize>(
    spec: &SceneSpec,
    out_dir: &Path,
    plugin: &impl Plugin,
    on_step: impl FnMut(&StepRecord),
) -> (Option<Summary>, Result<(), RunError>) {
    let mut sim = match Simulation::<D>::new(spec, out_dir) {
        Ok(sim) => sim,
        Err(e) => return (None, Err(RunError::Build(e))),
    };
    if let Err(e) = sim.add_plugin(plugin) {
        return (None, Err(RunError::Build(e)));
    }
    let result = sim
        .write_initial_state()
        .and_then(|()| sim.run(on_step))
        .map_err(RunError::Solve);
    (Some(sim.summary), result)
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
