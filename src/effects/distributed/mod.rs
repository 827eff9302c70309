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
//!   0's folder (`stages::output::ParticlePieces`); [`list_particle_pieces`] (`Hook::Output`)
//!   waits until every piece is written (a collective call that also shares a failed write)
//!   and process 0 lists them in `particles_NNNN.pvtu`, which `particles.pvd` lists. ParaView
//!   reads it as one data set; `impm merge OUT_DIR` writes `particles_NNNN.vtu` from the
//!   pieces (in `point_id` order, the serial file) for tools that do not read `.pvtu`. The grid
//!   and node files are process 0's (the grid is replicated); with `--decompose` they are not
//!   written (each process holds its own nodes), which the run says.
//! * **Failures are collective.** `Hook::Combine` runs after a failed stage too: if a stage
//!   failed on any process, every process fails the iteration (then cuts the step alike, or
//!   stops alike: a failure step cutting cannot recover on one process is one everywhere).
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
//!   by the process that assembles its host, the ghost penalty's faces by process 0
//!   (`distributed::adds_grid_terms`). Their records (reactions) are computed from the whole
//!   state, which every process holds.
//!
//! Not supported with more than one process (refused when the simulation is built): other
//! modules that add to the forces or `K` after the assembly (the follower pressure), which
//! every process would add in full. The check for
//! a body that nothing holds needs all of `K` and is skipped over several processes
//! (`Newton::whole_tangent`): such a body shows as a failed linear solve.

use std::collections::HashMap;

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::components::{AssembledElsewhere, Position};
use crate::distributed::partition::{slab_axis, slab_owners};
use crate::distributed::traffic::{Traffic, counted};
use crate::distributed::{
    Processes, any, decomposed, largest, layer_of, path_of_process_0, processes,
};
use crate::method::StepSystems;
use crate::output::write_pvtu;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    Grid, GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock, Warnings,
};
use crate::scene::{LinearBackend, SceneSpec};
use crate::solver::{PetscSolver, ProcessSum, SharedBlocks};
use crate::stages::output::{OutputPlan, ParticlePieces, WrittenPiece};

pub mod decomposition;
pub mod grid;

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
        let files = if processes.size > 1 {
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
             touch; no checkpoints are written): the stages on points, the assembly and the \
             linear solve (PETSc MPIAIJ, CG or GMRES with GAMG unless petsc_options say \
             otherwise) are split"
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
        if decompose && world.resource::<OutputPlan>().grid_files {
            // each process holds its own nodes' increments and activity, and its own points
            world.resource_mut::<OutputPlan>().grid_files = false;
            world.resource_mut::<Warnings>().0.push(
                "--decompose: the grid and node files (grid_NNNN.vtu, nodes_NNNN.vtu) are not \
                 written: each process holds only the grid nodes and points of its slab, and \
                 writing them in pieces is not done yet; the particle file is written"
                    .to_string(),
            );
        }
        if processes.size > 1 {
            // the pieces go into process 0's folder (the others run in scratch folders)
            let dir = world.resource::<OutputPlan>().dir.clone();
            let dir = std::fs::canonicalize(&dir).unwrap_or(dir);
            world.insert_resource(ParticlePieces {
                piece: processes.rank,
                dir: path_of_process_0(&dir),
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
        let world = simulation.world();
        // the shares of the initial state, for its output (step 0 runs no connectivity)
        if decompose {
            decomposition::count_own_points::<D>(world);
            let mut schedules = world.resource_mut::<Schedules>();
            let step = schedules.entry(Hook::Basis.schedule());
            step.add_systems((
                decomposition::exchange_points::<D>
                    .in_set(StepSystems::Connectivity)
                    .before(Hook::Basis),
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
            simulation.add_systems(Hook::Output, list_particle_pieces);
        }
        if decompose {
            simulation.add_systems(Hook::Loads, decomposition::sum_external_force::<D>);
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
                .add_measure("owned_dofs", move |world, _| numbered(world).map(|n| n.0))
                .add_measure("ghost_nodes", move |world, _| numbered(world).map(|n| n.1))
                .add_measure("local_dofs", move |world, _| numbered(world).map(|n| n.2));
        } else {
            simulation.add_systems(Hook::Connectivity, mark_assembly_share::<D>);
        }
        // what this process sent (process 0's in summary.json), cumulative: `traffic`
        for kind in Traffic::ALL {
            simulation.add_measure(kind.name(), move |_, _| Some(counted(kind) as f64));
        }
        simulation
            .add_systems(Hook::Combine, combine_assembly::<D>)
            .add_measure("assembled_points", move |world, _| {
                share(world).map(|(points, _)| points as f64)
            })
            .add_measure("points_changing_process", move |world, _| {
                share(world).map(|(_, moved)| moved as f64)
            });
    }
}

/// The modules of `Hook::AfterAssembly` that add each of their terms once over the processes,
/// one system each: the ghost penalty (process 0 adds the faces: `distributed::adds_grid_terms`),
/// F-bar (a group's rank-one terms by the process assembling its members) and
/// material-surface conditions (a boundary point's terms by the process assembling its host).
fn adds_once_after_assembly(spec: &SceneSpec) -> usize {
    use crate::effects::{fbar, ghost_penalty, surface_conditions};
    [
        ghost_penalty::GhostPenaltyModule.used_by(spec),
        fbar::FbarModule.used_by(spec),
        surface_conditions::SurfaceConditionsModule.used_by(spec),
    ]
    .into_iter()
    .filter(|&used| used)
    .count()
}

/// Why a scene cannot run over several processes, if it adds after the assembly (`systems`
/// at `Hook::AfterAssembly`) with a module that does not divide its terms among the processes
/// (a module outside the crate; the follower pressure refuses more than one process itself).
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

/// Whether a stage failed on any process (collective); if so every process fails, and alike:
/// a failure step cutting cannot recover on one process is one on every process (otherwise
/// some would cut the step and wait for the others, which stop).
fn share_failure(status: &mut RunStatus, step: usize) -> bool {
    let here = match &status.0 {
        None => 0,
        Some(error) if error.is_recoverable_by_cutting() => 1,
        Some(_) => 2,
    };
    let all = largest(here);
    if all == 0 {
        return false;
    }
    let elsewhere = "a stage failed on another process of the distributed run (process 0 \
                     reports its own failures)";
    match (&status.0, all) {
        (None, _) => status.fail(SolverError::Module {
            step,
            what: elsewhere.to_string(),
            recoverable: all == 1,
        }),
        (Some(error), 2) if here == 1 => {
            status.0 = Some(SolverError::Module {
                step,
                what: format!("{error}; and {elsewhere}, one that cutting the step cannot recover"),
                recoverable: false,
            });
        }
        _ => {}
    }
    true
}

/// Adds `vectors` (one per node) over the processes: with the decomposed grid at its nodes
/// only, over the processes touching each (`grid::sum_at_nodes`, neighbours only); otherwise
/// the whole grid's through the share's PETSc sum. Every process gets the same bits.
fn sum_grid_vectors<const D: usize>(
    share: &mut AssemblyShare,
    decomposed: Option<&grid::DecomposedGrid>,
    vectors: &mut [SVector<f64, D>],
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
    for (vector, values) in vectors.iter_mut().zip(share.buffer.chunks_exact(D)) {
        *vector = SVector::<f64, D>::from_column_slice(values);
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
) {
    let _timer = clock.time(Stage::Assembly);
    if share_failure(&mut status, step.number) {
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

/// After the processes wrote their pieces of the particle file (`ParticlePieces`): whether
/// any failed (then every process fails the step: collective, and it also waits until every
/// piece is written); then process 0 lists the pieces in `particles_NNNN.pvtu` and adds that
/// to `particles.pvd`.
pub fn list_particle_pieces(
    mut pieces: ResMut<ParticlePieces>,
    mut plan: ResMut<OutputPlan>,
    share: Res<AssemblyShare>,
    mut status: ResMut<RunStatus>,
    step: Res<LoadStep>,
) {
    let Some(written) = pieces.written.take() else {
        return; // not an output step (the same on every process)
    };
    if any(written.is_err()) {
        let why = match written {
            Err(why) => why,
            Ok(_) => "a piece of the particle file could not be written by another process \
                      of the distributed run"
                .to_string(),
        };
        status.fail(SolverError::Output {
            step: step.number,
            why,
        });
        return;
    }
    let Ok(WrittenPiece { arrays, .. }) = written else {
        return;
    };
    if share.processes.rank != 0 {
        return;
    }
    let names: Vec<String> = (0..share.processes.size)
        .map(|k| format!("particles_{:04}_p{k}.vtu", step.number))
        .collect();
    let name = format!("particles_{:04}.pvtu", step.number);
    let result = write_pvtu(&pieces.dir.join(&name), &names, &arrays, &[])
        .and_then(|()| plan.particles.push(step.factor, &name));
    if let Err(e) = result {
        status.fail(SolverError::Output {
            step: step.number,
            why: format!("{name}: {e}"),
        });
    }
}
