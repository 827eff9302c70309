//! World resources: the grid, the load step, the Newton state, diagnostics and errors.

use std::time::{Duration, Instant};

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::basis::GridBasis;
use crate::fem::Mesh;
use crate::sparse::{LinearSystem, NO_DOF};

/// The background grid and its basis.
#[derive(Resource, Clone, Debug)]
pub struct Grid<const D: usize>(pub GridBasis<D>);

/// Linear FEM only: the body-fitted mesh (element topology, reference node positions). The
/// current node positions are the `GridNode` positions.
#[derive(Resource, Clone, Debug)]
pub struct FemMesh<const D: usize>(pub Mesh<D>);

/// Dense fields on the grid nodes during a load step, indexed by node (see `components`).
/// Reset after every load step.
#[derive(Resource, Clone, Debug)]
pub struct GridFields<const D: usize> {
    /// Nodes supported by at least one material point this step.
    pub active: Vec<bool>,
    /// DOF number of each component (`NO_DOF` if fixed or inactive).
    pub dofs: Vec<[u32; D]>,
    /// Displacement increment Δu of the step (the unknown).
    pub increment: Vec<SVector<f64, D>>,
    /// External force at the current load factor.
    pub external_force: Vec<SVector<f64, D>>,
    /// Internal force at the current iterate.
    pub internal_force: Vec<SVector<f64, D>>,
    /// Number of free DOFs.
    pub dof_count: usize,
}

impl<const D: usize> GridFields<D> {
    pub fn new(nodes: usize) -> Self {
        Self {
            active: vec![false; nodes],
            dofs: vec![[NO_DOF; D]; nodes],
            increment: vec![SVector::zeros(); nodes],
            external_force: vec![SVector::zeros(); nodes],
            internal_force: vec![SVector::zeros(); nodes],
            dof_count: 0,
        }
    }

    /// Grid reset: the grid returns to its undeformed state and holds no fields.
    pub fn reset(&mut self) {
        self.active.fill(false);
        self.dofs.fill([NO_DOF; D]);
        self.increment.fill(SVector::zeros());
        self.external_force.fill(SVector::zeros());
        self.internal_force.fill(SVector::zeros());
        self.dof_count = 0;
    }
}

/// Settings of the MLS stress recovery (inserted only when the scene asks for it).
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct StressRecovery {
    /// Total degree of the fitted polynomial.
    pub order: usize,
    /// Support radius as a multiple of the largest cell size of the grid.
    pub radius_in_cells: f64,
}

/// The load step being solved.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct LoadStep {
    /// 1-based step number (0 = initial state).
    pub number: usize,
    /// Load factor at the end of the step.
    pub factor: f64,
    /// Load factor at the start of the step (of the sub-step, when the step is cut).
    pub previous_factor: f64,
    /// Whether this (sub-)step reaches the step's target load factor: output is written then.
    pub completes_step: bool,
}

/// Solver controls.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct NewtonSettings {
    pub tolerance: f64,
    pub max_iterations: usize,
}

/// Body force per unit mass at load factor 1.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct BodyForce<const D: usize>(pub SVector<f64, D>);

/// The state of the Newton loop of the current step.
#[derive(Resource, Default)]
pub struct Newton {
    pub system: LinearSystem,
    /// Out-of-balance force f_ext - f_int at the free DOFs; overwritten by the correction.
    pub residual: Vec<f64>,
    /// Normalised residual norm of each iterate (the first is before any solve).
    pub residuals: Vec<f64>,
    pub converged: bool,
    /// Linear solves done in this step.
    pub iterations: usize,
}

impl Newton {
    /// Prepares for a new load step (buffers keep their capacity).
    pub fn begin_step(&mut self) {
        self.residuals.clear();
        self.converged = false;
        self.iterations = 0;
    }
}

/// Why a run stopped.
#[derive(Clone, Debug, PartialEq)]
pub enum SolverError {
    /// A point left the background grid.
    PointOutsideGrid {
        point: u32,
        position: Vec<f64>,
        step: usize,
    },
    /// A point's domain (GIMP, CPDI, domain-integrated B-splines) cannot be used: a corner left
    /// the grid, or it inverted.
    PointDomain {
        point: u32,
        step: usize,
        why: String,
    },
    /// A point's deformation became inadmissible (det F <= 0, not finite...).
    BadPointState {
        point: u32,
        step: usize,
        iteration: usize,
        why: String,
    },
    /// A non-finite value appeared in a stage.
    NotFinite {
        stage: &'static str,
        what: String,
        step: usize,
    },
    /// The linear solve failed.
    LinearSolve {
        step: usize,
        iteration: usize,
        why: String,
    },
    /// Newton did not reach the tolerance.
    NotConverged {
        step: usize,
        residuals: Vec<f64>,
        tolerance: f64,
    },
    /// The out-of-balance force grew by orders of magnitude: Newton is diverging.
    Diverged { step: usize, residuals: Vec<f64> },
    /// The step could not be solved even after cutting it `cuts` times.
    CuttingFailed {
        step: usize,
        cuts: usize,
        last: Box<SolverError>,
    },
    /// Writing results failed.
    Output { step: usize, why: String },
    /// A traction point left the grid, or has no grid node with material points in its
    /// support, so its force cannot act on the body.
    TractionPoint {
        point: u32,
        position: Vec<f64>,
        step: usize,
        why: &'static str,
    },
}

impl std::fmt::Display for SolverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SolverError::PointOutsideGrid {
                point,
                position,
                step,
            } => write!(
                f,
                "load step {step}: material point {point} left the background grid (at {position:?})"
            ),
            SolverError::PointDomain { point, step, why } => write!(
                f,
                "load step {step}: the domain of material point {point} cannot be used: {why}"
            ),
            SolverError::BadPointState {
                point,
                step,
                iteration,
                why,
            } => write!(
                f,
                "load step {step}, Newton iteration {iteration}: material point {point}: {why}"
            ),
            SolverError::NotFinite { stage, what, step } => {
                write!(
                    f,
                    "load step {step}: non-finite value in stage '{stage}': {what}"
                )
            }
            SolverError::LinearSolve {
                step,
                iteration,
                why,
            } => {
                write!(f, "load step {step}, Newton iteration {iteration}: {why}")
            }
            SolverError::NotConverged {
                step,
                residuals,
                tolerance,
            } => {
                write!(
                    f,
                    "load step {step}: Newton did not converge to {tolerance:e} in {} iterations; residuals:",
                    residuals.len().saturating_sub(1)
                )?;
                for (k, r) in residuals.iter().enumerate() {
                    write!(f, "\n  iteration {k:3}: {r:.3e}")?;
                }
                Ok(())
            }
            SolverError::Diverged { step, residuals } => {
                write!(f, "load step {step}: Newton diverged; residuals:")?;
                for (k, r) in residuals.iter().enumerate() {
                    write!(f, "\n  iteration {k:3}: {r:.3e}")?;
                }
                Ok(())
            }
            SolverError::CuttingFailed { step, cuts, last } => write!(
                f,
                "load step {step}: failed after cutting the step {cuts} times; last attempt: {last}"
            ),
            SolverError::Output { step, why } => {
                write!(f, "load step {step}: writing output failed: {why}")
            }
            SolverError::TractionPoint {
                point,
                position,
                step,
                why,
            } => write!(
                f,
                "load step {step}: traction point {point} at {position:?} {why}"
            ),
        }
    }
}

impl std::error::Error for SolverError {}

impl SolverError {
    /// Whether a smaller load step may succeed where this failure happened: Newton failures
    /// and inadmissible or non-finite iterates are; points leaving the grid and output
    /// failures are not.
    pub fn is_recoverable_by_cutting(&self) -> bool {
        matches!(
            self,
            SolverError::NotConverged { .. }
                | SolverError::Diverged { .. }
                | SolverError::BadPointState { .. }
                | SolverError::LinearSolve { .. }
                | SolverError::NotFinite { .. }
        )
    }
}

/// The first error raised by a stage; later stages of the step do not run once it is set.
#[derive(Resource, Default, Debug)]
pub struct RunStatus(pub Option<SolverError>);

impl RunStatus {
    /// Records `error` unless an earlier one is already recorded.
    pub fn fail(&mut self, error: SolverError) {
        if self.0.is_none() {
            self.0 = Some(error);
        }
    }
}

/// Run condition: no stage has failed.
pub fn no_failure(status: Res<RunStatus>) -> bool {
    status.0.is_none()
}

/// The stages whose time is measured, in schedule order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stage {
    Connectivity,
    Dofs,
    ExternalForce,
    StressUpdate,
    Assembly,
    LinearSolve,
    PointUpdate,
    GridReset,
    StressRecovery,
    Output,
}

impl Stage {
    pub const ALL: [Stage; 10] = [
        Stage::Connectivity,
        Stage::Dofs,
        Stage::ExternalForce,
        Stage::StressUpdate,
        Stage::Assembly,
        Stage::LinearSolve,
        Stage::PointUpdate,
        Stage::GridReset,
        Stage::StressRecovery,
        Stage::Output,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Stage::Connectivity => "connectivity",
            Stage::Dofs => "dofs",
            Stage::ExternalForce => "external_force",
            Stage::StressUpdate => "stress_update",
            Stage::Assembly => "assembly",
            Stage::LinearSolve => "linear_solve",
            Stage::PointUpdate => "point_update",
            Stage::GridReset => "grid_reset",
            Stage::StressRecovery => "stress_recovery",
            Stage::Output => "output",
        }
    }
}

/// Time spent per stage in the current load step (reset by the driver each step).
#[derive(Resource, Default, Debug, Clone)]
pub struct StageClock {
    pub seconds: [Duration; Stage::ALL.len()],
}

impl StageClock {
    /// Starts timing `stage`; the time is added when the guard drops.
    pub fn time(&mut self, stage: Stage) -> StageTimer<'_> {
        StageTimer {
            clock: self,
            stage,
            start: Instant::now(),
        }
    }

    pub fn get(&self, stage: Stage) -> Duration {
        self.seconds[stage as usize]
    }
}

/// Adds the elapsed time to its stage when dropped.
pub struct StageTimer<'a> {
    clock: &'a mut StageClock,
    stage: Stage,
    start: Instant,
}

impl Drop for StageTimer<'_> {
    fn drop(&mut self) {
        self.clock.seconds[self.stage as usize] += self.start.elapsed();
    }
}
