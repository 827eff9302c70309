//! Distributed runs (cargo feature `mpi`): `mpirun -n N impm run SCENE`, the scene unchanged.
//!
//! The first, replicated step of issue 14 (`docs/distributed.md`, `crate::distributed`):
//!
//! * **State: replicated.** Every process holds every point and the whole grid and runs every
//!   stage on all of them (basis, loads, stress update, the point update, output), with the
//!   same numbers; memory per process is that of a serial run.
//! * **Assembly: split in slabs.** At the start of a load step ([`mark_assembly_share`],
//!   `Hook::Connectivity`) the cells are cut into one slab per process along the axis with
//!   the most cells, balanced by points (`distributed::partition`); a process marks the points
//!   of the other slabs [`AssembledElsewhere`], and the core assembly leaves them out. So each
//!   process sums `f_int` and `K` over its own points only.
//! * **Sums and solve: PETSc.** [`combine_assembly`] (`Hook::Combine`) adds the processes'
//!   internal forces through a PETSc vector (`solver::ProcessSum`): every process then forms
//!   the same out-of-balance force, so convergence and step cutting are decided alike
//!   everywhere, from the global residual. The tangent's shares go into one PETSc `MPIAIJ`
//!   matrix inside the linear solver (`PetscSolver::distributed`, which replaces the scene's
//!   `linear` choice: the scene's `petsc_options` are kept when it chose `"petsc"`); the
//!   correction is gathered to every process.
//! * **Particle file in pieces** (more than one process): each process writes the points it
//!   assembled in the step as `particles_NNNN_pK.vtu` (with a `point_id` array) into process
//!   0's folder (`stages::output::ParticlePieces`); [`list_pieces`] (`Hook::Output`)
//!   waits until every piece is written (a collective call that also shares a failed write)
//!   and process 0 lists them in `particles_NNNN.pvtu`, which `particles.pvd` lists. ParaView
//!   reads it as one data set; `impm merge OUT_DIR` writes `particles_NNNN.vtu` from the
//!   pieces (in `point_id` order, the serial file) for tools that do not read `.pvtu`. The grid
//!   and node files are process 0's (the grid is replicated); with `--decompose` each process
//!   holds its own nodes only, and they are in pieces too ([`grid_pieces`]: each node by its
//!   owner, each cell by the process of its cell layer; `grid_NNNN.pvtu`, `nodes_NNNN.pvtu`,
//!   merged by `impm merge` into the serial run's files).
//! * **Failures are collective** (`distributed::failure`). A stage that runs on a process's
//!   own points or files can fail on that process alone; the processes then share it at the
//!   next point where they meet, before any collective call that follows: in every Newton
//!   iteration at `Hook::Combine` (after the stress update and the assembly), after the basis
//!   and DOF stages (`grid::number_decomposed_grid`), after the point update
//!   ([`share_step_failure`], before the reactions' sum), after the step's last stages on
//!   points (before the output), in the output ([`grid_pieces`] before the pieces are
//!   written, [`list_pieces`] after the pieces
//!   are written) and at its end (before the sums over points of the step's records), and
//!   between load steps ([`share_outcome`]: what one process did alone after the step, such
//!   as process 0 writing `summary.json`). These run after a failure too. If any process
//!   failed, every process fails alike: the most severe failure (of the lowest rank) decides
//!   whether the line search shortens the Newton step, the step is cut or the run stops, and
//!   the processes that did not fail take it as theirs, naming the process it came from
//!   (`process K of N failed: ...`), so process 0 reports it and `summary.json` records it.
//! * **Decomposed points** (`impm run --decompose`, [`decomposition`]): each process holds only
//!   its slab's points instead of every point; the exchange moves them at each step start,
//!   and `f_ext` is summed like `f_int`. Scenes with modules that cannot follow their points
//!   are refused. The grid is decomposed too ([`grid`]): each process numbers only the nodes
//!   its points touch, the solver adds its local rows with the global numbers and gives back
//!   its local rows only, the convergence norms and the reactions count each node on its
//!   owner, and the force sums add each node's shares on its owner and send the sum back to
//!   the processes touching the node (`grid::sum_at_nodes`, no whole-grid vector: `ProcessSum`
//!   is the replicated path's). A process may hold no points (more processes than cell layers
//!   with points): it has no DOFs and takes part in every collective call.
//!
//! * **Terms added after the assembly** (`Hook::AfterAssembly`) are added once over the
//!   processes: F-bar's rank-one terms by the process that assembles the group's members (a
//!   group is the F-bar points of one cell, so one slab), a surface condition's boundary point
//!   by the process that assembles its host (with decomposed points, that holds it), the ghost
//!   penalty's faces (replicated: by process 0; decomposed: by the process holding a face's
//!   lower cell, `effects::ghost_penalty`) and the follower pressure's load stiffness by
//!   process 0 (`distributed::adds_grid_terms`). The follower pressure's force is part of
//!   `f_ext`, which the replicated path does not sum (every process forms all of it, and the
//!   right-hand side is the same on every process): every process adds it, and replaces it by
//!   the force at the iterate, in full (`effects::pressure`, "Over several processes"); with
//!   `--decompose` process 0 adds its force before `f_ext` is summed and its load stiffness (it
//!   numbers every node of the parts), and every process follows the force at the iterate at
//!   its own nodes. Their records (reactions) are computed from the whole
//!   state, which every process holds; with decomposed points a surface condition's boundary
//!   points are shared after every step and its records taken from all of them
//!   (`effects::surface_conditions`, "Decomposed points").
//!
//! Not supported with more than one process (refused when the simulation is built): other
//! modules that add to the forces or `K` after the assembly (a module outside the crate), which
//! every process would add in full. The check for
//! a body that nothing holds needs all of `K` and is skipped over several processes
//! (`Newton::whole_tangent`): such a body shows as a failed linear solve.

use std::collections::HashMap;

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::components::{AssembledElsewhere, Position};
use crate::distributed::failure::{self, FailureNote, Severity};
use crate::distributed::partition::{slab_axis, slab_owners};
use crate::distributed::traffic::{Traffic, counted};
use crate::distributed::{
    Processes, RUN_MEASURES, decomposed, layer_of, path_of_process_0, processes, share_failures,
};
use crate::method::{BuiltInOutput, OutputSchedule, StepSchedule, StepSystems};
use crate::node_storage::NodeVec;
use crate::output::write_pvtu;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    CurrentStage, Grid, GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock,
    Warnings,
};
use crate::scene::{LinearBackend, SceneSpec};
use crate::solver::{PetscSolver, ProcessSum, SharedBlocks};
use crate::stages::arc_length::SumFixedLoadsSchedule;
use crate::stages::output::{GridPieces, OutputPlan, ParticlePieces, WrittenPiece};
use bevy_ecs::schedule::{Schedule, SingleThreadedExecutor};

pub mod checkpoint;
pub mod decomposition;
pub mod grid;
pub mod grid_pieces;

/// The module: built when the process is one of a distributed run (`mpirun`).
#[derive(Clone, Copy, Debug, Default)]
pub struct DistributedModule;

/// This process's part of a distributed run.
#[derive(Resource)]
pub struct AssemblyShare {
    pub processes: Processes,
    /// The axis the slabs cut.
    pub axis: usize,
    /// Points this process assembles in the current load step.
    pub points: usize,
    /// Points whose process changed at the start of the current load step (they moved into
    /// another slab, or the slabs were recut).
    pub moved: usize,
    /// The process of every point in the current load step.
    owners: HashMap<Entity, usize>,
    /// The sum of the internal force over the processes.
    sum: ProcessSum,
    /// `f_int` flattened, for the sum.
    buffer: Vec<f64>,
}

impl Plugin for DistributedModule {
    fn name(&self) -> &'static str {
        "distributed"
    }

    fn used_by(&self, _spec: &SceneSpec) -> bool {
        processes().is_some()
    }

    fn applies_to(&self, _spec: &SceneSpec) -> bool {
        processes().is_some()
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let Some(processes) = processes() else {
            return;
        };
        if processes.size > 1 {
            let after_assembly = simulation.systems_at(Hook::AfterAssembly);
            if let Some(why) = refused_after_assembly(simulation.spec(), after_assembly) {
                simulation.fail(format!(
                    "{why}: a distributed run over {} processes would add it once per \
                     process, which is not supported yet; run it with mpirun -n 1 or without \
                     mpirun",
                    processes.size
                ));
                return;
            }
        }
        let decompose = decomposed();
        let spec = simulation.spec();
        let options = match spec.solver.linear {
            LinearBackend::Petsc => spec.solver.petsc_options.clone(),
            _ => String::new(),
        };
        let cells = simulation.world().resource::<Grid<D>>().0.cells_per_axis();
        let axis = slab_axis(&cells);
        let world = simulation.world();
        {
            let solver = if decompose {
                // the local system of the decomposed grid, with the global numbers the
                // numbering gives every step
                let blocks = SharedBlocks::default();
                world.insert_resource(grid::SolverNumbers(blocks.clone()));
                PetscSolver::decomposed(&options, blocks)
            } else {
                PetscSolver::distributed(&options)
            };
            let mut newton = world.resource_mut::<Newton>();
            newton.solver = Box::new(solver);
            // one process assembles every point: its share is all of K
            newton.whole_tangent = processes.size == 1;
        }
        let files = if processes.size > 1 && decompose {
            "each process writes the points it assembles as particles_NNNN_pK.vtu and the grid \
             nodes it owns and cells of its slab as nodes_NNNN_pK.vtu and grid_NNNN_pK.vtu, \
             the .pvtu files list them (ParaView; `impm merge OUT_DIR` writes one .vtu per \
             step for other tools), process 0 writes the other files"
        } else if processes.size > 1 {
            "each process writes the points it assembles as particles_NNNN_pK.vtu, \
             particles_NNNN.pvtu lists them (ParaView; `impm merge OUT_DIR` writes one .vtu per \
             step for other tools), process 0 writes the other files"
        } else {
            "process 0 writes the files"
        };
        let state = if decompose {
            "the points are decomposed (each process holds the points of its slab of cells \
             along axis {axis}, balanced by points, and they move between the processes as \
             they cross slabs; each numbers and assembles only the grid nodes its points \
             touch; each process writes its points' piece of a checkpoint): the stages on points, \
             the assembly and the linear solve (PETSc MPIAIJ, CG or GMRES with GAMG unless \
             petsc_options say otherwise) are split"
        } else {
            "every process holds the whole state (all points and the grid: replicated, not \
             decomposed); only the assembly (slabs of cells along axis {axis}, balanced by \
             points) and the linear solve (PETSc MPIAIJ, CG or GMRES with GAMG unless \
             petsc_options say otherwise) are split"
        };
        world.resource_mut::<Warnings>().0.push(format!(
            "distributed run over {} MPI processes: {}; {files}",
            processes.size,
            state.replace("{axis}", &axis.to_string())
        ));
        if processes.size > 1 {
            // the pieces go into process 0's folder (the others run in scratch folders)
            let dir = world.resource::<OutputPlan>().dir.clone();
            let dir = std::fs::canonicalize(&dir).unwrap_or(dir);
            let dir = path_of_process_0(&dir);
            if decompose {
                // each process holds its own nodes only: the grid and node files in pieces
                world.insert_resource(GridPieces {
                    piece: processes.rank,
                    dir: dir.clone(),
                    ..GridPieces::default()
                });
                world
                    .resource_mut::<Schedules>()
                    .entry(OutputSchedule)
                    .add_systems(
                        grid_pieces::gather_grid_pieces::<D>
                            .after(Hook::PointFields)
                            .before(BuiltInOutput),
                    );
            }
            world.insert_resource(ParticlePieces {
                piece: processes.rank,
                dir,
                written: None,
            });
        }
        world.insert_resource(AssemblyShare {
            processes,
            axis,
            points: 0,
            moved: 0,
            owners: HashMap::new(),
            sum: ProcessSum::default(),
            buffer: Vec::new(),
        });
        if decompose && crate::effects::stages::StagesModule.used_by(simulation.spec()) {
            decomposition::carry_displacement_origins(simulation);
        }
        let ghost_penalty =
            crate::effects::ghost_penalty::GhostPenaltyModule.used_by(simulation.spec());
        let world = simulation.world();
        // the shares of the initial state, for its output (step 0 runs no connectivity)
        if decompose {
            decomposition::count_own_points::<D>(world);
            let mut schedules = world.resource_mut::<Schedules>();
            let step = schedules.entry(Hook::Basis.schedule());
            let exchange = decomposition::exchange_points::<D>
                .in_set(StepSystems::Connectivity)
                .before(Hook::Basis);
            if ghost_penalty {
                // the cells' fill fractions from the points this process holds in the step
                step.add_systems(
                    exchange.before(crate::effects::ghost_penalty::measure_cell_fill::<D>),
                );
            } else {
                step.add_systems(exchange);
            }
            step.add_systems((
                // not in a stage's set: it runs after a failure too, and shares it; the
                // owned nodes, ghosts and global numbers, for the solver and the norms
                grid::number_decomposed_grid::<D>
                    .after(StepSystems::Dofs)
                    .before(StepSystems::Loads),
            ));
            world.init_resource::<grid::DecomposedGrid>();
        } else {
            mark_assembly_share::<D>(world);
        }
        let share = |world: &mut World| {
            world
                .get_resource::<AssemblyShare>()
                .map(|s| (s.points, s.moved))
        };
        if processes.size > 1 {
            // synchronisation points that run after a failure too (`share_step_failure`)
            let mut schedules = simulation.world().resource_mut::<Schedules>();
            schedules.entry(StepSchedule).add_systems((
                share_step_failure
                    .after(Hook::PointUpdate)
                    .before(Hook::AfterStep),
                share_step_failure
                    .after(StepSystems::UpdatePoints)
                    .before(StepSystems::Output),
            ));
            let last = share_step_failure
                .after(StepSystems::Output)
                .before(StepSystems::ResetGrid);
            if decompose {
                // both collective: in one order on every process
                let measure = grid::measure_node_storage::<D>;
                schedules
                    .entry(StepSchedule)
                    .add_systems(last.before(measure));
            } else {
                schedules.entry(StepSchedule).add_systems(last);
            }
            schedules.entry(OutputSchedule).add_systems(
                list_pieces
                    .after(BuiltInOutput)
                    .after(Hook::GridOutput)
                    .before(Hook::Output),
            );
        }
        let [assembled, changing, owned, ghosts, local, .., storage] = RUN_MEASURES;
        if decompose {
            // not in a stage's set: it runs after a failure too, and shares it
            let mut schedules = simulation.world().resource_mut::<Schedules>();
            schedules.entry(StepSchedule).add_systems(
                decomposition::sum_external_force::<D>
                    .after(StepSystems::Loads)
                    .before(StepSystems::Solve),
            );
            // arc-length control with held loads evaluates them again at λ = 0: summed too
            let mut held = Schedule::new(SumFixedLoadsSchedule);
            held.set_executor(SingleThreadedExecutor::new());
            held.add_systems(decomposition::sum_external_force::<D>);
            schedules.insert(held);
            // collective, after the step's last failure share (ordered there)
            schedules.entry(StepSchedule).add_systems(
                grid::measure_node_storage::<D>
                    .after(StepSystems::Output)
                    .before(StepSystems::ResetGrid),
            );
            let numbered = |world: &mut World| {
                let grid = world.get_resource::<grid::DecomposedGrid>()?;
                grid.ownership.as_ref()?;
                Some((
                    grid.owned_dofs as f64,
                    grid.ghost_nodes as f64,
                    grid.local_dofs as f64,
                ))
            };
            simulation
                .add_measure(owned, move |world, _| numbered(world).map(|n| n.0))
                .add_measure(ghosts, move |world, _| numbered(world).map(|n| n.1))
                .add_measure(local, move |world, _| numbered(world).map(|n| n.2))
                .add_measure(storage, move |world, _| {
                    let bytes = world.get_resource::<grid::NodeStorage>()?.largest?;
                    Some(bytes as f64)
                });
        } else {
            simulation.add_systems(Hook::Connectivity, mark_assembly_share::<D>);
        }
        // what this process sent (process 0's in summary.json), cumulative: `traffic`
        for kind in Traffic::ALL {
            simulation.add_measure(kind.name(), move |_, _| Some(counted(kind) as f64));
        }
        simulation
            .add_systems(Hook::Combine, combine_assembly::<D>)
            .add_measure(assembled, move |world, _| {
                share(world).map(|(points, _)| points as f64)
            })
            .add_measure(changing, move |world, _| {
                share(world).map(|(_, moved)| moved as f64)
            });
    }
}

/// The modules of `Hook::AfterAssembly` that add each of their terms once over the processes,
/// one system each: the ghost penalty (process 0 adds the faces, `distributed::adds_grid_terms`;
/// with decomposed points the process holding a face's lower cell),
/// F-bar (a group's rank-one terms by the process assembling its members),
/// material-surface conditions (a boundary point's terms by the process assembling its host)
/// and the follower pressure (its change of the replicated `f_ext` on every process, its load
/// stiffness by process 0).
fn adds_once_after_assembly(spec: &SceneSpec) -> usize {
    use crate::effects::{fbar, ghost_penalty, pressure, surface_conditions};
    [
        ghost_penalty::GhostPenaltyModule.used_by(spec),
        fbar::FbarModule.used_by(spec),
        surface_conditions::SurfaceConditionsModule.used_by(spec),
        pressure::PressureModule.used_by(spec),
    ]
    .into_iter()
    .filter(|&used| used)
    .count()
}

/// Why a scene cannot run over several processes, if it adds after the assembly (`systems`
/// at `Hook::AfterAssembly`) with a module that does not divide its terms among the processes
/// (a module outside the crate).
fn refused_after_assembly(spec: &SceneSpec, systems: usize) -> Option<String> {
    (systems > adds_once_after_assembly(spec)).then(|| {
        "the scene uses a module that adds to the forces or the tangent after the assembly \
         without dividing its terms among the processes"
            .to_string()
    })
}

/// Marks the points of the other processes' slabs [`AssembledElsewhere`] (and unmarks this
/// process's), from the points' positions at the start of the load step; counts the points
/// whose process changed since the last step (the measure `points_changing_process` of
/// summary.json; `assembled_points` is process 0's count).
pub fn mark_assembly_share<const D: usize>(world: &mut World) {
    let (rank, size) = {
        let share = world.resource::<AssemblyShare>();
        (share.processes.rank, share.processes.size)
    };
    let (points, per_slice) = point_slices::<D>(world);
    let owners = slab_owners(&per_slice, size);
    let mut mine = 0;
    let mut moved = 0;
    let mut share = world.resource_mut::<AssemblyShare>();
    let first_step = share.owners.is_empty();
    for &(entity, slice) in &points {
        let before = share.owners.insert(entity, owners[slice]);
        if !first_step && before != Some(owners[slice]) {
            moved += 1;
        }
    }
    share.moved = moved;
    for (entity, slice) in points {
        let mut point = world.entity_mut(entity);
        if owners[slice] == rank {
            mine += 1;
            point.remove::<AssembledElsewhere>();
        } else {
            point.insert(AssembledElsewhere);
        }
    }
    world.resource_mut::<AssemblyShare>().points = mine;
}

/// The cell layer along the slab axis of every point this process holds (a point outside the
/// grid counts in layer 0: the basis stage fails it), and the points in each layer.
fn point_slices<const D: usize>(world: &mut World) -> (Vec<(Entity, usize)>, Vec<usize>) {
    let axis = world.resource::<AssemblyShare>().axis;
    let slices = world.resource::<Grid<D>>().0.cells_per_axis()[axis];
    let mut query = world.query::<(Entity, &Position<D>)>();
    let grid = &world.resource::<Grid<D>>().0;
    let points: Vec<(Entity, usize)> = query
        .iter(world)
        .map(|(entity, x)| (entity, layer_of(grid, axis, &x.0)))
        .collect();
    let mut per_slice = vec![0usize; slices];
    for &(_, slice) in &points {
        per_slice[slice] += 1;
    }
    (points, per_slice)
}

/// Whether a stage failed on any process (collective; `distributed::failure`): if so every
/// process fails, and alike. A process that did not fail takes the deciding failure (the most
/// severe, of the lowest rank) as its own, naming the process it came from; a process that
/// failed less severely takes it on top of its own. So all of them retry the Newton step
/// (the line search, after an inadmissible trial state), cut the load step or stop together,
/// and process 0 reports which process failed and why.
pub(crate) fn share_failure(status: &mut RunStatus, step: usize, iteration: usize) -> bool {
    let mine = status.0.as_ref().map(|error| note_of(error, step));
    let failures = match share_failures(mine.as_ref()) {
        Ok(None) => return false,
        Ok(Some(failures)) => failures,
        Err(why) => {
            status.0 = Some(SolverError::Module {
                step,
                what: format!("sharing a failure between the processes: {why}"),
                recoverable: false,
            });
            return true;
        }
    };
    let size = failures.len();
    let Some((rank, deciding)) = failure::deciding(&failures) else {
        status.0 = Some(SolverError::Module {
            step,
            what: "a process of the distributed run failed, and what failed could not be read"
                .to_string(),
            recoverable: false,
        });
        return true;
    };
    match (&status.0, &mine) {
        (None, _) => status.0 = Some(failure_elsewhere(deciding, rank, size, step, iteration)),
        (Some(error), Some(note)) if note.severity < deciding.severity => {
            let own = error.to_string();
            status.0 = Some(SolverError::Module {
                step,
                what: format!(
                    "{}; and process {rank} of {size} failed: {}",
                    failure::without_step(&own, step),
                    failure::without_step(&deciding.message, step)
                ),
                recoverable: deciding.severity == Severity::Recoverable,
            });
        }
        // this process's own failure decides, and some process did not fail: named like the
        // others' (`process 0 of 2 failed: ...`), so that process 0's report says whose it was;
        // a failure every process had (a step that cannot be solved) is no one process's
        (Some(error), Some(note))
            if processes().is_some_and(|p| p.rank == rank)
                && note.severity != Severity::TrialState
                && failures.iter().any(Option::is_none) =>
        {
            let own = error.to_string();
            status.0 = Some(SolverError::Module {
                step,
                what: format!(
                    "process {rank} of {size} failed: {}",
                    failure::without_step(&own, step)
                ),
                recoverable: note.severity == Severity::Recoverable,
            });
        }
        _ => {}
    }
    true
}

/// A failure as the other processes learn it (`distributed::failure`): an inadmissible trial
/// state (a point's state, a non-finite value outside the linear solve: what the line search
/// shortens the Newton step for), a failure cutting the step may recover, or another.
fn note_of(error: &SolverError, step: usize) -> FailureNote {
    let (severity, point, stage, detail) = match error {
        SolverError::BadPointState { point, why, .. } => {
            (Severity::TrialState, Some(*point), "", why.clone())
        }
        SolverError::NotFinite { stage, what, .. } if *stage != "linear solve" => {
            (Severity::TrialState, None, *stage, what.clone())
        }
        other if other.is_recoverable_by_cutting() => {
            (Severity::Recoverable, None, "", String::new())
        }
        _ => (Severity::Fatal, None, "", String::new()),
    };
    let message = error.to_string();
    FailureNote {
        severity,
        point,
        stage: stage.to_string(),
        detail: if detail.is_empty() {
            failure::without_step(&message, step).to_string()
        } else {
            detail
        },
        message,
    }
}

/// The stages whose non-finite values are inadmissible trial states (`SolverError::NotFinite`
/// keeps its stage as a `&'static str`).
const TRIAL_STAGES: [&str; 4] = [
    "assembly",
    "point update",
    "convergence check",
    "stress recovery",
];

/// The failure of process `rank` of `size` (`deciding`) as this process's own: of the same
/// kind when it is an inadmissible trial state (so this process's line search shortens the
/// step as the failing process's does), else a module's failure saying which process failed
/// and what, recoverable as the deciding one is.
fn failure_elsewhere(
    deciding: &FailureNote,
    rank: usize,
    size: usize,
    step: usize,
    iteration: usize,
) -> SolverError {
    let on = |detail: &str| format!("{detail} (on process {rank} of {size})");
    match deciding.severity {
        Severity::TrialState => match deciding.point {
            Some(point) => SolverError::BadPointState {
                point,
                step,
                iteration,
                why: on(&deciding.detail),
            },
            None => SolverError::NotFinite {
                stage: TRIAL_STAGES
                    .into_iter()
                    .find(|&stage| stage == deciding.stage)
                    .unwrap_or("assembly"),
                what: on(&deciding.detail),
                step,
            },
        },
        severity => SolverError::Module {
            step,
            what: format!(
                "process {rank} of {size} failed: {}",
                failure::without_step(&deciding.message, step)
            ),
            recoverable: severity == Severity::Recoverable,
        },
    }
}

/// Between load steps, and after the initial state (collective in a run over several
/// processes; `Simulation::run`): whether any process failed since the last load step (a step
/// that failed on every process, or what one process did alone after it: writing
/// `summary.json`, `history.csv`, a checkpoint). A failure on any process is every process's,
/// so all of them stop after the same step; one process returns `outcome` as it is.
pub fn share_outcome(
    outcome: Result<(), SolverError>,
    steps_done: usize,
) -> Result<(), SolverError> {
    if processes().is_none_or(|p| p.size < 2) {
        return outcome;
    }
    let mut status = RunStatus(outcome.err());
    share_failure(&mut status, steps_done, 0);
    match status.0 {
        Some(error) => Err(error),
        None => Ok(()),
    }
}

/// A synchronisation point of the load step (collective; runs after a failure too): whether a
/// stage failed on any process since the last one, so that every process goes on, or fails,
/// alike. Placed where a stage that runs on each process's own points or files is followed by
/// a collective call: after the point update (the reactions' sum follows), after the step's
/// last stages on points (the particle pieces' listing follows) and at the end of the output
/// (the sums over points of the step's records follow).
pub fn share_step_failure(mut status: ResMut<RunStatus>, step: Res<LoadStep>, newton: Res<Newton>) {
    share_failure(&mut status, step.number, newton.iterations);
}

/// Adds `vectors` (one per node) over the processes: with the decomposed grid at its nodes
/// only, over the processes touching each (`grid::sum_at_nodes`, neighbours only); otherwise
/// the whole grid's through the share's PETSc sum. Every process gets the same bits.
fn sum_grid_vectors<const D: usize>(
    share: &mut AssemblyShare,
    decomposed: Option<&grid::DecomposedGrid>,
    vectors: &mut NodeVec<SVector<f64, D>>,
) -> Result<(), String> {
    if let Some(grid) = decomposed {
        return grid::sum_at_nodes(grid, vectors);
    }
    share.buffer.clear();
    share
        .buffer
        .extend(vectors.iter().flat_map(|f| f.iter().copied()));
    share
        .sum
        .sum(&mut share.buffer)
        .map_err(|e| e.to_string())?;
    // the whole grid's sums (replicated); a node whose sum it holds already is not written
    for (node, values) in share.buffer.chunks_exact(D).enumerate() {
        let sum = SVector::<f64, D>::from_column_slice(values);
        if vectors[node] != sum {
            vectors[node] = sum;
        }
    }
    Ok(())
}

/// Adds the processes' internal forces (each summed over its own points), so that every
/// process holds the global `f_int`; first, whether a stage failed on any process (then every
/// process fails the iteration). Runs after a failure too (`Hook::Combine`).
pub fn combine_assembly<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    mut share: ResMut<AssemblyShare>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    step: Res<LoadStep>,
    decomposed: Option<Res<grid::DecomposedGrid>>,
    newton: Res<Newton>,
) {
    let _timer = clock.time(Stage::Assembly);
    if share_failure(&mut status, step.number, newton.iterations) {
        return;
    }
    let decomposed = decomposed.as_deref();
    if let Err(why) = sum_grid_vectors(&mut share, decomposed, &mut fields.internal_force) {
        status.fail(SolverError::Module {
            step: step.number,
            what: format!("summing the internal force over the processes: {why}"),
            recoverable: false,
        });
    }
}

/// After the processes wrote their pieces of the particle file (`ParticlePieces`) and, with
/// decomposed points, of the grid and node files (`GridPieces`, [`grid_pieces`]), in an
/// output step: whether any process failed, in the output stages before or writing its pieces
/// (collective; runs after a failure too: then every process fails the step, and alike); then
/// process 0 lists the pieces in `particles_NNNN.pvtu` (and `grid_NNNN.pvtu`,
/// `nodes_NNNN.pvtu`) and adds those to their `.pvd` series, at the serial run's time
/// (`k + λ_k` in stage `k`: `LoadStep::series_time`).
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn list_pieces(
    mut pieces: ResMut<ParticlePieces>,
    mut grid_pieces: Option<ResMut<GridPieces>>,
    mut plan: ResMut<OutputPlan>,
    share: Res<AssemblyShare>,
    mut status: ResMut<RunStatus>,
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    newton: Res<Newton>,
) {
    let written = pieces.written.take();
    let (grid_written, nodes_written) = match grid_pieces.as_deref_mut() {
        Some(grid) => {
            grid.ready = false;
            (grid.grid_written.take(), grid.nodes_written.take())
        }
        None => (None, None),
    };
    if !plan.writes(&step) {
        return; // not an output step (the same on every process)
    }
    // each series' piece as written here, or its failure as this process's
    let mut written_here = |written: Option<Result<WrittenPiece, String>>| match written {
        Some(Ok(piece)) if status.0.is_none() => Some(piece),
        Some(Err(why)) if status.0.is_none() => {
            status.fail(SolverError::Output {
                step: step.number,
                why,
            });
            None
        }
        _ => None,
    };
    let series = [
        ("particles", written_here(written)),
        ("nodes", written_here(nodes_written)),
        ("grid", written_here(grid_written)),
    ];
    if share_failure(&mut status, step.number, newton.iterations) {
        return;
    }
    if share.processes.rank != 0 {
        return;
    }
    for (stem, piece) in series {
        let Some(piece) = piece else {
            continue; // not written in this run (the same on every process)
        };
        let names: Vec<String> = (0..share.processes.size)
            .map(|k| format!("{stem}_{:04}_p{k}.vtu", step.number))
            .collect();
        let name = format!("{stem}_{:04}.pvtu", step.number);
        let time = step.series_time(stage.as_deref());
        let pvd = match stem {
            "particles" => &mut plan.particles,
            "nodes" => &mut plan.nodes,
            _ => &mut plan.grid,
        };
        let result = write_pvtu(
            &pieces.dir.join(&name),
            &names,
            &piece.arrays,
            &piece.cell_arrays,
        )
        .and_then(|()| pvd.push(time, &name));
        if let Err(e) = result {
            status.fail(SolverError::Output {
                step: step.number,
                why: format!("{name}: {e}"),
            });
            return;
        }
    }
}
