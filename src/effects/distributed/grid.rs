//! The decomposed grid's ownership and numbering in a run (`impm run --decompose`): every
//! step, after the DOF stage, each process finds the nodes its own points touch (its owned
//! nodes and ghost layer), their owners and the global numbers of their DOFs, talking only
//! to the processes that share nodes with it (`distributed::ownership`, whose docs give the
//! rule: the lowest rank touching a node owns it; owned DOFs numbered contiguously per
//! process, offset by the processes before it; ghosts' numbers from their owners).
//!
//! Messages per step (counted as `bytes_grid_numbers`): every process's layer range and
//! owned and ghost counts to all (`3 P` + `3 P` numbers), then the shared nodes and their numbers to
//! the neighbours only (`MPI_Alltoallv`, empty for the others).
//!
//! **Where it stands.** The core still numbers and assembles the replicated grid
//! (`decomposition::agree_on_grid`): this numbering is computed and **checked against it at
//! every step** — the owned DOFs summed over the processes must equal the replicated
//! grid's DOFs and the owned blocks its nodes with a free component, and every ghost must get
//! its numbers from its owner with the same free components — but the assembly, the PETSc
//! matrix and the correction do not use it yet (`docs/distributed.md`, "Not done yet"). A
//! disagreement fails the run on every process (never a wrong answer silently).

use std::collections::BTreeSet;

use bevy_ecs::prelude::*;

use super::{AssemblyShare, share_failure};
use crate::components::Support;
use crate::distributed::ownership::{LocalNodes, Numbering, Ownership, offsets, shared_messages};
use crate::distributed::traffic::Traffic;
use crate::distributed::{any, exchange_counted, gather_all_counted};
use crate::resources::{Grid, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};
use crate::solver::NO_DOF;

/// This process's part of the decomposed grid in the current load step.
#[derive(Resource, Default)]
pub struct DecomposedGrid {
    /// The nodes its points touch.
    pub local: LocalNodes,
    pub ownership: Option<Ownership>,
    pub numbering: Option<Numbering>,
    /// Free components of the nodes it owns.
    pub owned_dofs: u64,
    /// Ghost nodes summed over the processes (a node counts once per process that touches
    /// it without owning it).
    pub ghost_nodes: usize,
}

/// The system (collective; runs after a failure too, and shares it first).
pub fn number_decomposed_grid<const D: usize>(world: &mut World) {
    let step = world.resource::<LoadStep>().number;
    if share_failure(&mut world.resource_mut::<RunStatus>(), step) {
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

/// The nodes this process's points touch, their layers along the slab axis and their free
/// components (from the DOF stage's numbers).
fn local_nodes<const D: usize>(world: &mut World) -> LocalNodes {
    let mut query = world.query::<&Support<D>>();
    let nodes: BTreeSet<usize> = query
        .iter(world)
        .flat_map(|support| support.0.iter().map(|w| w.node))
        .collect();
    let axis = world.resource::<AssemblyShare>().axis;
    let grid = &world.resource::<Grid<D>>().0;
    let fields = world.resource::<GridFields<D>>();
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
    // the replicated grid's numbering, which every process holds alike
    let fields = world.resource::<GridFields<D>>();
    let replicated_blocks = (fields.dofs.iter())
        .filter(|dofs| dofs.iter().any(|&d| d != NO_DOF))
        .count() as u64;
    if all_dofs != fields.dof_count as u64 || all_blocks != replicated_blocks {
        return Err(format!(
            "the processes own {all_dofs} DOFs in {all_blocks} nodes, the replicated grid has \
             {} in {replicated_blocks}",
            fields.dof_count
        ));
    }
    world.insert_resource(DecomposedGrid {
        local,
        ownership: Some(ownership),
        numbering: Some(numbering),
        owned_dofs: dofs,
        ghost_nodes: column(2).iter().sum::<u64>() as usize,
    });
    Ok(())
}
