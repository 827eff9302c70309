//! The core's world resources: the grid, the load step, the Newton state, diagnostics and
//! errors. Modules add their own (`effects/`).

use std::time::{Duration, Instant};

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::basis::GridBasis;
use crate::control::{ConvergenceCriterion, NormalisedResidual};
use crate::node_storage::NodeVec;
use crate::solver::{DirectSolver, LinearSolver, NO_DOF, SolverKind, SparseMatrix};

/// The background grid and its basis.
#[derive(Resource, Clone, Debug)]
pub struct Grid<const D: usize>(pub GridBasis<D>);

/// Fields on the grid nodes during a load step, indexed by global node (see `components`),
/// stored in pages allocated when written (`node_storage::NodeVec`: a decomposed run's process
/// holds the pages of the nodes it touches, not the whole grid). Reset after every load step.
#[derive(Resource, Clone, Debug)]
pub struct GridFields<const D: usize> {
    /// Nodes supported by at least one material point this step.
    pub active: NodeVec<bool>,
    /// Components whose displacement a module prescribes (set at `Hook::Constraints`; kept
    /// through the grid reset, so that the initial output shows them): they get no DOF.
    pub constrained: NodeVec<[bool; D]>,
    /// Groups of nodes coupled in the tangent beyond the points' supports (e.g. the two cells
    /// of a ghost-penalty face, the points of an F-bar cell), added by modules at
    /// `Hook::Connectivity`; their blocks are added at `Hook::AfterAssembly`.
    pub couplings: Vec<Vec<usize>>,
    /// DOF number of each component (`NO_DOF` if fixed or inactive).
    pub dofs: NodeVec<[u32; D]>,
    /// Displacement increment Δu of the step (the unknown).
    pub increment: NodeVec<SVector<f64, D>>,
    /// External force at the current load factor.
    pub external_force: NodeVec<SVector<f64, D>>,
    /// Internal force at the current iterate.
    pub internal_force: NodeVec<SVector<f64, D>>,
    /// Number of free DOFs.
    pub dof_count: usize,
}

impl<const D: usize> GridFields<D> {
    pub fn new(nodes: usize) -> Self {
        Self {
            active: NodeVec::new(nodes, false),
            constrained: NodeVec::new(nodes, [false; D]),
            couplings: Vec::new(),
            dofs: NodeVec::new(nodes, [NO_DOF; D]),
            increment: NodeVec::new(nodes, SVector::zeros()),
            external_force: NodeVec::new(nodes, SVector::zeros()),
            internal_force: NodeVec::new(nodes, SVector::zeros()),
            dof_count: 0,
        }
    }

    /// Grid reset: the grid returns to its undeformed state and holds no fields.
    pub fn reset(&mut self) {
        self.active.reset();
        self.couplings.clear();
        self.dofs.reset();
        self.increment.reset();
        self.external_force.reset();
        self.internal_force.reset();
        self.dof_count = 0;
    }

    /// The bytes of the per-node fields this process holds (their written pages and page
    /// tables; `constrained` included, which the reset keeps).
    pub fn node_storage_bytes(&self) -> usize {
        self.active.bytes()
            + self.constrained.bytes()
            + self.dofs.bytes()
            + self.increment.bytes()
            + self.external_force.bytes()
            + self.internal_force.bytes()
    }
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

impl LoadStep {
    /// The factor a load of the given [`Ramp`] is applied with in this step of a scene without
    /// stages: the step's load factor λ, or 1 for a held load.
    pub fn factor_of(&self, ramp: Ramp) -> f64 {
        self.factor_in(ramp, 0)
    }

    /// The factor a load of the given [`Ramp`] is applied with in this step of stage `stage`
    /// (`scene::stages`; λ is the stage's own load factor, from 0 to 1 over the stage): a load
    /// of stage k is absent before stage k, follows λ in it (or is held in full from its start)
    /// and is held at its final value after it.
    pub fn factor_in(&self, ramp: Ramp, stage: usize) -> f64 {
        let (own, held) = match ramp {
            Ramp::Schedule => (0, false),
            Ramp::Held => (0, true),
            Ramp::Stage(k) => (k, false),
            Ramp::HeldFrom(k) => (k, true),
        };
        match stage.cmp(&own) {
            std::cmp::Ordering::Less => 0.0,
            std::cmp::Ordering::Equal if !held => self.factor,
            _ => 1.0,
        }
    }
}

impl LoadStep {
    /// The time of the step's files in the `.pvd` series: `stage + λ` with λ the stage's own
    /// load factor, so that the time increases over a staged run whose stages' factors stay
    /// within [0, 1] (ParaView's time slider then runs through the stages in turn; λ itself
    /// restarts in every stage). A scene without stages is stage 0: the time is λ, as ever.
    pub fn series_time(&self, stage: Option<&CurrentStage>) -> f64 {
        match stage {
            Some(stage) if stage.0 > 0 => stage.0 as f64 + self.factor,
            _ => self.factor,
        }
    }
}

/// The stage the load step belongs to (`scene::stages`; 0 in a scene without stages): set by
/// the driver before each step. The `.pvd` series' time is [`LoadStep::series_time`].
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CurrentStage(pub usize);

/// How a load follows the load schedule: ramped with the load factor λ (the default), or held
/// at its full value from the first step on (`held: true` in scenes: the weight that balances
/// a geostatic initial stress while a footing is pushed). In a scene with stages a load
/// declared in stage k > 0 is `Stage(k)` or `HeldFrom(k)` (`Schedule` and `Held` are stage 0's).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Ramp {
    #[default]
    Schedule,
    Held,
    /// Absent before stage k, ramped over it, held in full after it.
    Stage(usize),
    /// Absent before stage k, held in full from its first step on.
    HeldFrom(usize),
}

impl Ramp {
    /// `Held` when `held`, else `Schedule`.
    pub fn held_if(held: bool) -> Self {
        Self::staged(held, 0)
    }

    /// The ramp of a load declared in stage `stage`, held or following the stage's schedule.
    pub fn staged(held: bool, stage: usize) -> Self {
        match (held, stage) {
            (false, 0) => Self::Schedule,
            (true, 0) => Self::Held,
            (false, k) => Self::Stage(k),
            (true, k) => Self::HeldFrom(k),
        }
    }

    /// The stage the load belongs to.
    pub fn stage(self) -> usize {
        match self {
            Self::Schedule | Self::Held => 0,
            Self::Stage(k) | Self::HeldFrom(k) => k,
        }
    }

    /// Whether the load is held in full from the start of its stage.
    pub fn is_held(self) -> bool {
        matches!(self, Self::Held | Self::HeldFrom(_))
    }
}

/// Solver controls.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct NewtonSettings {
    pub tolerance: f64,
    pub max_iterations: usize,
    /// Inexact Newton: the linear solves' tolerance follows Eisenstat–Walker forcing terms.
    pub inexact: bool,
    /// Most shortenings of one Newton step by the line search (`stages::line_search`; it runs
    /// only when its resource is inserted).
    pub max_backtracks: usize,
}

/// When a Newton iterate has converged (`control::NormalisedResidual` by default).
#[derive(Resource)]
pub struct Convergence(pub Box<dyn ConvergenceCriterion>);

impl Default for Convergence {
    fn default() -> Self {
        Self(Box::new(NormalisedResidual))
    }
}

/// The largest force the bodies carried at a converged Newton iterate so far,
/// `max(‖f_ext‖, ‖f_int‖)` over the active nodes: the floor of the convergence criterion's
/// force scale in a scene that releases a load or support (`control::NormalisedResidual`,
/// `effects::declarations::keep_largest_force`; absent otherwise: the criterion as before).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct LargestForce(pub f64);

/// The state of the Newton loop of the current step.
#[derive(Resource)]
pub struct Newton {
    /// The tangent K of the current iterate.
    pub matrix: SparseMatrix,
    /// Solves K δ = r (the faer direct solver by default).
    pub solver: Box<dyn LinearSolver>,
    /// Whether K is symmetric: true unless a module or material says otherwise (then no
    /// symmetric method such as Cholesky is used).
    pub symmetric: bool,
    /// How the last system was solved.
    pub last_solver: SolverKind,
    /// Out-of-balance force f_ext - f_int at the free DOFs; overwritten by the correction.
    pub residual: Vec<f64>,
    /// Normalised residual norm of each iterate (the first is before any solve).
    pub residuals: Vec<f64>,
    /// Krylov iterations of each linear solve of the step (iterative backends only).
    pub linear_iterations: Vec<usize>,
    /// The forcing term of the last linear solve (inexact Newton), `None` before the step's first.
    pub forcing: Option<f64>,
    pub converged: bool,
    /// Linear solves done in this step.
    pub iterations: usize,
    /// Whether `matrix` is all of K. False in a distributed run, where each process holds only
    /// the sum over the points it assembles (the linear solver adds the processes' shares):
    /// the checks that need all of K (a body that nothing holds, `solver::modes`) are skipped.
    pub whole_tangent: bool,
    /// The grid split among processes (a distributed run's decomposed grid,
    /// `effects::distributed::grid`): how the convergence norms are summed, the whole
    /// problem's DOFs; `None`: this process numbers the whole grid.
    pub shared_grid: Option<Box<dyn SharedGrid>>,
}

/// A grid split among processes (the decomposed grid of a distributed run): each process
/// numbers only its nodes' DOFs, so the convergence norms count each node once, on the
/// process that owns it (a ghost node's force is also on its owner), summed over the
/// processes, and the step's DOF count is the processes' owned DOFs summed.
pub trait SharedGrid: Send + Sync {
    /// Whether this process owns `node` (its norms count here).
    fn owned(&self, node: usize) -> bool;
    /// The sums over the processes of `values` (collective; the same bits on every process:
    /// the convergence norms' squares, the reactions of the owned nodes).
    fn sum(&self, values: &[f64]) -> Result<Vec<f64>, String>;
    /// The DOFs of the whole problem (this process's are `Newton::matrix`'s).
    fn dofs(&self) -> usize;
}

impl Default for Newton {
    fn default() -> Self {
        Self {
            matrix: SparseMatrix::default(),
            solver: Box::new(DirectSolver::default()),
            symmetric: true,
            last_solver: SolverKind::None,
            residual: Vec::new(),
            residuals: Vec::new(),
            linear_iterations: Vec::new(),
            forcing: None,
            converged: false,
            iterations: 0,
            whole_tangent: true,
            shared_grid: None,
        }
    }
}

impl Newton {
    /// Prepares for a new load step (buffers keep their capacity).
    pub fn begin_step(&mut self) {
        self.residuals.clear();
        self.linear_iterations.clear();
        self.forcing = None;
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
    /// The line search shortened a Newton step `backtracks` times without enough decrease of
    /// the out-of-balance force (`stages::line_search`).
    LineSearch {
        step: usize,
        iteration: usize,
        backtracks: usize,
        residuals: Vec<f64>,
        /// The rejected trials of the last Newton step: step length α and ‖r(α)‖ / ‖r(0)‖,
        /// or θ(α) = ‖δ̄(α)‖ / ‖δ‖ under the natural test (`None`: a point's state was
        /// inadmissible).
        trials: Vec<(f64, Option<f64>)>,
        /// Whether the trials were judged by the natural level function.
        natural: bool,
    },
    /// The step could not be solved even after cutting it `cuts` times.
    CuttingFailed {
        step: usize,
        cuts: usize,
        last: Box<SolverError>,
    },
    /// Writing results failed.
    Output { step: usize, why: String },
    /// A body's rigid motion is a zero-energy mode of the tangent: nothing holds it
    /// (`solver::modes`).
    NotHeld {
        step: usize,
        body: String,
        modes: Vec<String>,
    },
    /// A module's stage failed (e.g. a traction point left the grid, a GIMP or CPDI domain
    /// cannot be used); `recoverable` if a smaller load step may succeed.
    Module {
        step: usize,
        what: String,
        recoverable: bool,
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
            SolverError::LineSearch {
                step,
                iteration,
                backtracks,
                residuals,
                trials,
                natural,
            } => {
                let (what, ratio) = if *natural {
                    (
                        "the natural level function (the simplified Newton correction)",
                        "‖K⁻¹r(α)‖ / ‖K⁻¹r(0)‖",
                    )
                } else {
                    ("the out-of-balance force", "‖r(α)‖ / ‖r(0)‖")
                };
                write!(
                    f,
                    "load step {step}: the line search shortened Newton step {iteration} \
                     {backtracks} times without reducing {what} enough; its trials (step \
                     length α: {ratio} − 1, which a consistent tangent makes about −α for \
                     short steps):"
                )?;
                for (alpha, ratio) in trials {
                    match ratio {
                        Some(ratio) => write!(f, " {alpha:.2e}: {:+.2e}", ratio - 1.0)?,
                        None => write!(f, " {alpha:.2e}: inadmissible")?,
                    }
                }
                if let Some(&(alpha, Some(ratio))) = trials.last()
                    && ratio > 1.0 - 0.5 * alpha
                {
                    write!(
                        f,
                        "\n  even the shortest step did not reduce ‖r‖: either the correction is \
                         so large (a nearly singular tangent) that the residual's curvature \
                         dominates at that length (then ‖r(α)‖ / ‖r(0)‖ − 1 falls like α² \
                         from trial to trial), or the tangent is not the derivative of the \
                         residual there (then like α)"
                    )?;
                }
                write!(f, "\nresiduals:")?;
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
            SolverError::NotHeld { step, body, modes } => write!(
                f,
                "load step {step}: {body} not held: the tangent stiffness is singular, nothing \
                 stops it {}; add fix(...) or displace(...) on its nodes (or a surface condition, \
                 see docs/boundaries.md)",
                modes.join(", nor ")
            ),
            SolverError::Module { step, what, .. } => write!(f, "load step {step}: {what}"),
        }
    }
}

impl std::error::Error for SolverError {}

impl SolverError {
    /// Whether a smaller load step may succeed where this failure happened: Newton failures
    /// and inadmissible or non-finite iterates are; points leaving the grid and output
    /// failures are not.
    pub fn is_recoverable_by_cutting(&self) -> bool {
        match self {
            SolverError::Module { recoverable, .. } => *recoverable,
            other => matches!(
                other,
                SolverError::NotConverged { .. }
                    | SolverError::Diverged { .. }
                    | SolverError::LineSearch { .. }
                    | SolverError::BadPointState { .. }
                    | SolverError::LinearSolve { .. }
                    | SolverError::NotFinite { .. }
            ),
        }
    }
}

/// The bodies' names, in declaration order (`BodyIndex`), for messages.
#[derive(Resource, Default, Debug)]
pub struct BodyNames(pub Vec<String>);

/// Warnings raised by modules during a step (e.g. a grid-node `displace` whose material no
/// longer follows it): the driver prints them and keeps them in `summary.json`.
#[derive(Resource, Default, Debug)]
pub struct Warnings(pub Vec<String>);

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

/// The stages whose time is measured: the stages of `method.rs` (`StepSystems`, and
/// `NewtonSystems` inside the solve), with the same names. A module's systems count to the
/// stage their hook belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stage {
    Connectivity,
    Dofs,
    Loads,
    StressUpdate,
    Assembly,
    LinearSolve,
    UpdatePoints,
    Output,
    ResetGrid,
}

impl Stage {
    pub const ALL: [Stage; 9] = [
        Stage::Connectivity,
        Stage::Dofs,
        Stage::Loads,
        Stage::StressUpdate,
        Stage::Assembly,
        Stage::LinearSolve,
        Stage::UpdatePoints,
        Stage::Output,
        Stage::ResetGrid,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Stage::Connectivity => "connectivity",
            Stage::Dofs => "dofs",
            Stage::Loads => "loads",
            Stage::StressUpdate => "stress_update",
            Stage::Assembly => "assembly",
            Stage::LinearSolve => "linear_solve",
            Stage::UpdatePoints => "update_points",
            Stage::Output => "output",
            Stage::ResetGrid => "reset_grid",
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
