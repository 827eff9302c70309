//! The grid and node files of a decomposed run in pieces (`mpirun -n N impm run SCENE
//! --decompose`, `N > 1`): each process holds only the grid nodes its own points touch, so
//! each writes its piece of `nodes_NNNN.vtu` and `grid_NNNN.vtu` (`stages::output::GridPieces`),
//! process 0 lists them in `nodes_NNNN.pvtu` and `grid_NNNN.pvtu`, which `nodes.pvd` and
//! `grid.pvd` list (`super::list_pieces`), and `impm merge OUT_DIR` writes the serial run's
//! files from them (`output::merge_pieces`).
//!
//! **Who writes what** ([`gather_grid_pieces`], before the output's files, in an output
//! step; collective, it shares a failure first):
//!
//! * a node is written by its owner (`distributed::ownership`: the lowest rank touching it),
//!   with its global number (`node_id`): no node twice. A node no process's points touch
//!   (inactive in the serial run: `active` 0, no DOF, zero increment and forces) is written
//!   by process 0 from its own fields, which hold the serial values there (it never numbered
//!   the node; it marks their constraints
//!   for the output: `grid_constraints::mark_untouched_fixity`). So the merged
//!   node file has every node of the serial file, in its order (`node_id`), and the same
//!   values: each node's from the process that summed its forces and solved for it;
//! * a cell of the lattice is written by the process of its cell layer along the slab axis,
//!   the layers balanced by the points in them at the output (`distributed::partition`'s
//!   rule), with its corners; a corner on the boundary between two pieces is in both, with
//!   the same values (ParaView shows the pieces as one grid; the merge keeps it once). The
//!   grid file's values are sums over the processes: the displacement increment at a vertex
//!   `Δu(v) = Σ_i N_i(v) Δu_i` needs nodes no point of the writing process touches (a cell
//!   beside the slab boundary), and a cell's material points may be on two processes (a
//!   point moves in the step, and changes process only at the next step's start).
//!
//! **Messages.** One all-reduce per output step of `(1 + D)` numbers per node (1 where the
//! process owns the node, then its increment there; zeros elsewhere) and one number per cell
//! (its points on the process): every node's increment arrives from its owner alone, so the
//! sums are the owners' values bit for bit, and the owner flags' sum (1 at a node some
//! process touches, 0 elsewhere) tells process 0 which nodes no one owns and checks that no
//! node has two owners (the run fails then, naming the node: never a node written twice).
//! This is a whole-lattice vector per process and output step, as `GridFields` is already
//! (not neighbours only: a later step, `docs/distributed.md`).

use bevy_ecs::prelude::*;

use super::AssemblyShare;
use super::grid::DecomposedGrid;
use super::share_failure;
use crate::components::Position;
use crate::distributed::partition::slab_owners;
use crate::distributed::sum_all;
use crate::resources::{
    Grid, GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock,
};
use crate::stages::output::{GridPieces, OutputPlan, points_per_cell};

/// The pieces' nodes, cells and values of this output step (see the module docs).
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn gather_grid_pieces<const D: usize>(
    mut pieces: ResMut<GridPieces>,
    plan: Res<OutputPlan>,
    share: Res<AssemblyShare>,
    decomposed: Res<DecomposedGrid>,
    fields: Res<GridFields<D>>,
    grid: Res<Grid<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    step: Res<LoadStep>,
    newton: Res<Newton>,
    positions: Query<&Position<D>>,
) {
    pieces.ready = false;
    if !plan.writes(&step) || !plan.grid_files {
        return; // the same on every process
    }
    if share_failure(&mut status, step.number, newton.iterations) {
        return;
    }
    let _timer = clock.time(Stage::Output);
    let (rank, size) = (share.processes.rank, share.processes.size);
    let basis = &grid.0;
    let nodes = basis.num_nodes();
    let cells = basis.num_cells();
    let width = 1 + D;
    let mut values = vec![0.0; width * nodes + cells];
    let mut owned_here = vec![false; nodes];
    if let Some(ownership) = decomposed.ownership.as_ref() {
        for (&n, &owner) in decomposed.local.nodes.iter().zip(&ownership.owner) {
            if owner == rank {
                owned_here[n] = true;
                values[width * n] = 1.0;
                for k in 0..D {
                    values[width * n + 1 + k] = fields.increment[n][k];
                }
            }
        }
    }
    let own_points = points_per_cell(basis, positions.iter().map(|x| &x.0));
    values[width * nodes..].copy_from_slice(&own_points);
    sum_all(&mut values);
    // the same sums on every process: a node with two owners fails every process alike
    if let Some(n) = (0..nodes).find(|&n| !matches!(values[width * n], 0.0 | 1.0)) {
        status.fail(SolverError::Output {
            step: step.number,
            why: format!(
                "the node pieces: grid node {n} is owned by {} processes",
                values[width * n]
            ),
        });
        return;
    }
    pieces.nodes = (0..nodes)
        .map(|n| owned_here[n] || (rank == 0 && values[width * n] == 0.0))
        .collect();
    pieces.increment = (0..nodes)
        .flat_map(|n| values[width * n + 1..width * (n + 1)].iter().copied())
        .collect();
    pieces.points_per_cell = values[width * nodes..].to_vec();
    // the cells: slabs of cell layers along the share's axis, balanced by their points
    let axis = share.axis;
    let layer = |c: usize| basis.cell_multi_index(c)[axis];
    let mut per_layer = vec![0usize; basis.cells_per_axis()[axis]];
    for (c, &count) in pieces.points_per_cell.iter().enumerate() {
        per_layer[layer(c)] += count as usize;
    }
    let owners = slab_owners(&per_layer, size);
    pieces.cells = (0..cells).map(|c| owners[layer(c)] == rank).collect();
    pieces.ready = true;
}
