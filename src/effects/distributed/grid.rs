//! The decomposed grid's ownership and numbering in a run (`impm run --decompose`): every
//! step, after the DOF stage, each process finds the nodes its own points touch and its
//! modules' coupling groups hold (its owned nodes and ghost layer; a ghost-penalty face on a
//! slab boundary reaches one node layer further: `effects::ghost_penalty`), their owners and
//! the global numbers of their DOFs, talking only to the processes that share nodes with it
//! (`distributed::ownership`, whose docs give the rule: the lowest rank touching a node owns
//! it; owned DOFs numbered contiguously per process, offset by the processes before it;
//! ghosts' numbers from their owners).
//!
//! Messages per step (counted as `bytes_grid_numbers`): every process's layer range and
//! owned and ghost counts to all (`3 P` + `3 P` numbers), then the shared nodes and their numbers to
//! the neighbours only (`MPI_Alltoallv`, empty for the others).
//!
//! **What uses it.** The core's DOF stage numbers exactly these nodes (no other process's
//! supports reach it), so its DOFs are this process's local DOFs; this system hands their
//! global block numbers to the linear solver ([`SolverNumbers`], `solver::GlobalBlocks`: the
//! local rows added with global indices, the correction brought back to the local rows) and
//! the owned nodes to the convergence norms (`resources::SharedGrid`: each node counted on
//! its owner, the squares gathered from every process and summed in rank order, so every
//! process decides alike), to the force sums (`f_int` at `Hook::Combine`, `f_ext` after the
//! loads: [`sum_at_nodes`], each node's shares added by its owner and sent back, neighbours
//! only) and to the reactions (`fix`/`displace` measures: each node counted on its owner, the
//! owners' parts added over the processes). It checks that the DOF stage's local DOFs are exactly the owned
//! and ghost DOFs numbered here, and every ghost gets its numbers from its owner with the same
//! free components; a disagreement fails the run on every process (never a wrong answer
//! silently).

use std::collections::BTreeSet;

use bevy_ecs::prelude::*;

use super::{AssemblyShare, share_failure};
use crate::components::Support;
use nalgebra::SVector;

use crate::distributed::ownership::{
    LocalNodes, NONE, Numbering, Ownership, add_shares, offsets, set_sums, shared_messages,
    shares_to_owners, sums_to_sharers,
};
use crate::distributed::traffic::Traffic;
use crate::distributed::{any, exchange_counted, gather_all_counted};
use crate::node_storage::NodeVec;
use crate::resources::{
    Grid, GridFields, LoadStep, Newton, RunStatus, SharedGrid, SolverError, Stage, StageClock,
};
use crate::solver::{GlobalBlocks, NO_DOF, SharedBlocks};

/// The linear solver's view of the numbering (`PetscSolver::decomposed`), refilled every step.
#[derive(Resource)]
pub struct SolverNumbers(pub SharedBlocks);

/// The decomposed grid for the core: the nodes this process owns count in the convergence
/// norms and the reactions here.
struct OwnedNodes {
    /// Whether this process owns each node of the grid (a paged mask, `node_storage`: the
    /// pages of its own nodes; read once per node per Newton iteration).
    owned: NodeVec<bool>,
    /// The DOFs over all processes.
    dofs: usize,
}

impl SharedGrid for OwnedNodes {
    fn owned(&self, node: usize) -> bool {
        self.owned.get(node).copied().unwrap_or(false)
    }

    /// Gathered and summed in rank order: the same bits on every process (an all-reduce may
    /// add in another order on each).
    fn sum(&self, values: &[f64]) -> Result<Vec<f64>, String> {
        let bits: Vec<u64> = values.iter().map(|v| v.to_bits()).collect();
        let all = gather_all_counted(&bits, Traffic::Reductions)?;
        let mut sums = vec![0.0; values.len()];
        for part in &all {
            if part.len() != values.len() {
                return Err(format!(
                    "a process sent {} values to sum, this one {}",
                    part.len(),
                    values.len()
                ));
            }
            for (sum, &bits) in sums.iter_mut().zip(part) {
                *sum += f64::from_bits(bits);
            }
        }
        Ok(sums)
    }

    fn dofs(&self) -> usize {
        self.dofs
    }
}

/// This process's part of the decomposed grid in the current load step.
#[derive(Resource, Default)]
pub struct DecomposedGrid {
    /// The nodes its points touch.
    pub local: LocalNodes,
    pub ownership: Option<Ownership>,
    pub numbering: Option<Numbering>,
    /// Free components of the nodes it owns.
    pub owned_dofs: u64,
    /// Free components of its nodes (owned and ghosts): the DOFs of its local system.
    pub local_dofs: u64,
    /// Ghost nodes summed over the processes (a node counts once per process that touches
    /// it without owning it).
    pub ghost_nodes: usize,
}

/// The system (collective; runs after a failure too, and shares it first).
pub fn number_decomposed_grid<const D: usize>(world: &mut World) {
    let step = world.resource::<LoadStep>().number;
    let iteration = world.resource::<Newton>().iterations;
    if share_failure(&mut world.resource_mut::<RunStatus>(), step, iteration) {
        return;
    }
    let result = world.resource_scope(|world, mut clock: Mut<StageClock>| {
        let _timer = clock.time(Stage::Dofs);
        number::<D>(world)
    });
    // a process's error alone (a message it could not read) is every process's
    let failed = any(result.is_err());
    if failed {
        let what = match result {
            Err(why) => format!("numbering the decomposed grid: {why}"),
            Ok(()) => "numbering the decomposed grid failed on another process".to_string(),
        };
        world.resource_mut::<RunStatus>().fail(SolverError::Module {
            step,
            what,
            recoverable: false,
        });
    }
}

/// The nodes this process's points touch and the nodes a module made active on it (the follower
/// pressure's parts on process 0, which adds their load stiffness: `effects::pressure`; the
/// nodes of the ghost-penalty faces this process adds, which reach one node layer past its
/// points on a slab boundary: `effects::ghost_penalty`), their layers along the slab axis and
/// their free components (from the DOF stage's numbers). Not the coupling groups as such: the
/// pressure's are in every process's pattern, but only process 0 numbers their nodes.
fn local_nodes<const D: usize>(world: &mut World) -> LocalNodes {
    let mut query = world.query::<&Support<D>>();
    let mut nodes: BTreeSet<usize> = query
        .iter(world)
        .flat_map(|support| support.0.iter().map(|w| w.node))
        .collect();
    let axis = world.resource::<AssemblyShare>().axis;
    let grid = &world.resource::<Grid<D>>().0;
    let fields = world.resource::<GridFields<D>>();
    nodes.extend((fields.active.written()).filter_map(|(n, &active)| active.then_some(n)));
    let nodes: Vec<usize> = nodes.into_iter().collect();
    LocalNodes {
        layers: nodes
            .iter()
            .map(|&n| grid.node_multi_index(n)[axis])
            .collect(),
        free: nodes
            .iter()
            .flat_map(|&n| fields.dofs[n].map(|d| d != NO_DOF))
            .collect(),
        nodes,
        components: D,
    }
}

fn number<const D: usize>(world: &mut World) -> Result<(), String> {
    let rank = world.resource::<AssemblyShare>().processes.rank;
    let local = local_nodes::<D>(world);
    let kind = Traffic::GridNumbers;
    let range = match local.layer_range() {
        Some((low, high)) => [1, low as u64, high as u64],
        None => [0, 0, 0],
    };
    let ranges: Vec<Option<(usize, usize)>> = gather_all_counted(&range, kind)?
        .iter()
        .map(|r| match r[..] {
            [1, low, high] => Some((low as usize, high as usize)),
            _ => None,
        })
        .collect();
    let received = exchange_counted(&shared_messages(&local, &ranges, rank), kind)?;
    let ownership = Ownership::new(&local, rank, &received);
    let (dofs, blocks) = ownership.owned_counts(&local);
    let ghosts = Numbering::ghosts(&ownership) as u64;
    let counts = gather_all_counted(&[dofs, blocks, ghosts], kind)?;
    let column = |k: usize| counts.iter().map(|c| c[k]).collect::<Vec<u64>>();
    let (dof_offsets, all_dofs) = offsets(&column(0));
    let (block_offsets, all_blocks) = offsets(&column(1));
    let mut numbering =
        Numbering::owned(&local, &ownership, dof_offsets[rank], block_offsets[rank]);
    let messages = numbering.number_messages(&local, &ownership);
    let received = exchange_counted(&messages, kind)?;
    numbering.receive(&local, &ownership, &received)?;
    // the DOF stage's local DOFs are exactly the owned and ghost ones numbered here
    let fields = world.resource::<GridFields<D>>();
    let numbered = numbering.dofs.iter().filter(|&&n| n != NONE).count();
    let active = fields.active.written().filter(|&(_, &a)| a).count();
    if numbered != fields.dof_count || active != local.nodes.len() {
        return Err(format!(
            "the DOF stage numbered {} DOFs on {active} nodes, the decomposed grid {numbered} \
             on {} nodes",
            fields.dof_count,
            local.nodes.len()
        ));
    }
    let mut owned = NodeVec::new(fields.active.len(), false);
    for (&node, &owner) in local.nodes.iter().zip(&ownership.owner) {
        owned[node] = owner == rank;
    }
    let blocks = GlobalBlocks {
        nodes: local.nodes.clone(),
        blocks: numbering.blocks.clone(),
        first: block_offsets[rank],
        owned: blocks,
        total: all_blocks,
        components: D,
    };
    if let Some(shared) = world.get_resource::<SolverNumbers>() {
        *shared.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(blocks);
    }
    world.resource_mut::<Newton>().shared_grid = Some(Box::new(OwnedNodes {
        owned,
        dofs: all_dofs as usize,
    }));
    world.insert_resource(DecomposedGrid {
        local,
        ownership: Some(ownership),
        numbering: Some(numbering),
        owned_dofs: dofs,
        local_dofs: numbered as u64,
        ghost_nodes: column(2).iter().sum::<u64>() as usize,
    });
    Ok(())
}

/// The largest per-node storage of a process in the current step: the bytes of the core's grid
/// fields (`GridFields::node_storage_bytes`: their written pages and page tables) after the
/// output, before the grid reset frees them (the step's largest: pages are freed only there,
/// and by the DOF stage and the assembly, which write the same nodes again). `None` when the
/// gather failed.
#[derive(Resource, Default)]
pub struct NodeStorage {
    pub largest: Option<u64>,
}

/// Collective (every process, after a failure too): each process's bytes gathered, their
/// largest kept for the step's record (`node_storage_bytes`).
pub fn measure_node_storage<const D: usize>(world: &mut World) {
    let bytes = world.resource::<GridFields<D>>().node_storage_bytes() as u64;
    let largest = gather_all_counted(&[bytes], Traffic::Reductions)
        .ok()
        .and_then(|all| all.iter().filter_map(|b| b.first().copied()).max());
    world.insert_resource(NodeStorage { largest });
}

/// Sums `vectors` (one per node of the whole grid; this process's own points' share at its
/// nodes) over the processes touching each of its nodes (`distributed::ownership`, "Sums at
/// the shared nodes": the shares to the owner, the owner's sum back), so that every process
/// holds at each of its nodes, owned or ghost, `f_i = Σ_p f_i^p` over the processes `p`
/// touching node `i`, the same bits as the owner's. The other nodes are left as they are (no
/// point of this process reaches them). Collective; an error on one process is every
/// process's.
pub fn sum_at_nodes<const D: usize>(
    grid: &DecomposedGrid,
    vectors: &mut NodeVec<SVector<f64, D>>,
) -> Result<(), String> {
    let Some(ownership) = grid.ownership.as_ref() else {
        // the same on every process: the numbering fails the step on all of them alike
        return Err("the decomposed grid is not numbered in this step".to_string());
    };
    let nodes = &grid.local.nodes;
    let mut values: Vec<f64> = (nodes.iter())
        .flat_map(|&n| vectors[n].iter().copied())
        .collect();
    let shares = shares_to_owners(ownership, &values, D);
    let received = exchange_counted(&shares, Traffic::VectorEntries)?;
    // no early return between the two exchanges: every process takes part in both
    let added = add_shares(ownership, &mut values, D, &received);
    let sums = sums_to_sharers(ownership, &values, D);
    let received = exchange_counted(&sums, Traffic::Gathered)?;
    let result = added.and_then(|()| set_sums(ownership, &mut values, D, &received));
    if any(result.is_err()) {
        return Err(result
            .err()
            .unwrap_or_else(|| "summing at the shared nodes failed on another process".into()));
    }
    for (&n, value) in nodes.iter().zip(values.chunks_exact(D)) {
        vectors[n] = SVector::<f64, D>::from_column_slice(value);
    }
    Ok(())
}
