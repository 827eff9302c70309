//! The decomposed grid's ownership and numbering (issue 14, `docs/distributed.md`): which
//! process owns each node, and the global numbers of the DOFs, computed from each process's
//! own nodes and messages to the processes beside it only.
//!
//! **A process's nodes** are the nodes its points' supports touch (the active nodes of its
//! own points): they reach exactly as far as the basis support, so they are the owned nodes
//! plus the ghost layer. Each node has its layer `ℓ` along the slab axis (its index along
//! that axis).
//!
//! **Who touches what.** Process `r`'s nodes lie in the layers `[a_r, b_r]` (its smallest and
//! largest node layer; every process learns every other's pair, `2 P` numbers). A node of
//! process `s` can be a node of `r` only if its layer is in `[a_r, b_r]`, so `s` sends `r` the
//! nodes of its own in `[a_r, b_r]` ([`shared_messages`]): with slabs along one axis and
//! supports `q + 1` nodes wide, that is the `q` node layers at the boundary with each
//! neighbour, and nothing to the processes further away (unless a slab is thinner than a
//! support). Process `r` then knows, for each of its nodes, every process that touches it.
//!
//! **The owner** of a node is the lowest rank among the processes that touch it
//! ([`Ownership::new`]): every process touching it computes the same owner from the same
//! set, with no further message. (The slabs are in rank order along the axis, so the lower
//! process owns the nodes at a slab boundary.)
//!
//! **Numbering.** Process `r` numbers the free components of the nodes it owns contiguously,
//! node-major in node order: global DOF number `o_r + k`, with `o_r = Σ_{s<r} n_s` the
//! offset of the process (an exclusive scan of the owned counts `n_s`, [`offsets`]). The
//! owned nodes with any free component ("blocks": PETSc's padded whole-node rows, the
//! constrained components being uncoupled rows) are numbered the same way, `B_r + j`. The
//! owner sends each process that touches an owned node its numbers ([`Numbering::number_messages`]), and
//! the process fills in its ghosts ([`Numbering::receive`]), checking that every ghost got
//! numbers from its owner and that the owner's free components are its own.
//!
//! Over all processes this numbers every DOF of the serial run exactly once (the union of
//! the processes' nodes is the serial run's active nodes, each with one owner), which the
//! tests below check against a serial numbering, and a run checks at every step against the
//! count of the replicated grid (`effects::distributed::grid`).
//!
//! **Sums at the shared nodes** (the force sums `f_int`, `f_ext` of a decomposed grid): each
//! process holds its own points' share of a per-node quantity at its nodes (`width` numbers
//! per node, in the order of `LocalNodes::nodes`). A node's sum is its owner's: every
//! process touching the node but not owning it sends its share to the owner
//! ([`shares_to_owners`]), the owner adds them to its own in rank order ([`add_shares`]) and
//! sends the sums back to those processes ([`sums_to_sharers`], [`set_sums`]), so every
//! process holds the same bits at each of its nodes, and nothing leaves the neighbours.
//! A message holds no node numbers: sender and receiver list the nodes they share in the
//! same order (both keep them sorted), and a message of another length is an error.

/// No number: an inactive or constrained component, or a node with no free component.
pub const NONE: u64 = u64::MAX;

/// The nodes of one process and their free components (what the core's DOF stage found on
/// its own points' nodes).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LocalNodes {
    /// The nodes, in increasing order.
    pub nodes: Vec<usize>,
    /// Each node's layer along the slab axis.
    pub layers: Vec<usize>,
    /// Each node's free components, `components` flags per node.
    pub free: Vec<bool>,
    /// Components per node (`D`).
    pub components: usize,
}

impl LocalNodes {
    /// The smallest and largest layer of the nodes, if any.
    pub fn layer_range(&self) -> Option<(usize, usize)> {
        let low = self.layers.iter().min()?;
        let high = self.layers.iter().max()?;
        Some((*low, *high))
    }

    fn free_of(&self, i: usize) -> &[bool] {
        &self.free[i * self.components..(i + 1) * self.components]
    }
}

/// What this process sends every process `s`: its nodes in `s`'s layer range `ranges[s]`
/// (nothing to itself, nor to a process without nodes).
pub fn shared_messages(
    local: &LocalNodes,
    ranges: &[Option<(usize, usize)>],
    rank: usize,
) -> Vec<Vec<u64>> {
    ranges
        .iter()
        .enumerate()
        .map(|(s, range)| match range {
            Some((low, high)) if s != rank => (local.nodes.iter().zip(&local.layers))
                .filter(|&(_, layer)| (low..=high).contains(&layer))
                .map(|(&node, _)| node as u64)
                .collect(),
            _ => Vec::new(),
        })
        .collect()
}

/// Each node's owner, and the nodes this process shares with each other process.
#[derive(Clone, Debug, PartialEq)]
pub struct Ownership {
    pub rank: usize,
    /// The owner of each of the process's nodes (its index in `LocalNodes::nodes`).
    pub owner: Vec<usize>,
    /// For every process, the indices of this process's nodes it touches too (empty for this
    /// process and for processes that share none).
    pub shared: Vec<Vec<usize>>,
}

impl Ownership {
    /// From the nodes every other process sent ([`shared_messages`], by source rank): the
    /// owner of a node is the lowest rank touching it.
    pub fn new(local: &LocalNodes, rank: usize, received: &[Vec<u64>]) -> Self {
        let mut owner = vec![rank; local.nodes.len()];
        let mut shared = vec![Vec::new(); received.len()];
        for (s, message) in received.iter().enumerate().filter(|&(s, _)| s != rank) {
            for &node in message {
                if let Ok(i) = local.nodes.binary_search(&(node as usize)) {
                    shared[s].push(i);
                    owner[i] = owner[i].min(s);
                }
            }
            shared[s].sort_unstable();
            shared[s].dedup();
        }
        Self {
            rank,
            owner,
            shared,
        }
    }

    /// The processes this one shares nodes with.
    pub fn neighbours(&self) -> Vec<usize> {
        (self.shared.iter().enumerate())
            .filter(|(_, nodes)| !nodes.is_empty())
            .map(|(s, _)| s)
            .collect()
    }

    /// The free components (DOFs) and the nodes with any free component (blocks) this
    /// process owns.
    pub fn owned_counts(&self, local: &LocalNodes) -> (u64, u64) {
        let (mut dofs, mut blocks) = (0u64, 0u64);
        for i in (0..local.nodes.len()).filter(|&i| self.owner[i] == self.rank) {
            let free = local.free_of(i).iter().filter(|&&f| f).count() as u64;
            dofs += free;
            blocks += u64::from(free > 0);
        }
        (dofs, blocks)
    }
}

/// Every process's offset from the processes' counts, in rank order: the exclusive scan
/// `o_r = Σ_{s<r} n_s`, and the total.
pub fn offsets(counts: &[u64]) -> (Vec<u64>, u64) {
    let mut at = 0;
    let offsets = counts
        .iter()
        .map(|&n| {
            let offset = at;
            at += n;
            offset
        })
        .collect();
    (offsets, at)
}

/// The global numbers of a process's nodes.
#[derive(Clone, Debug, PartialEq)]
pub struct Numbering {
    /// The global DOF number of each component of each node (`components` per node;
    /// [`NONE`] for a constrained one).
    pub dofs: Vec<u64>,
    /// The global block (whole node) number of each node ([`NONE`] without a free
    /// component).
    pub blocks: Vec<u64>,
    /// Whether each node's numbers are known (owned, or received from its owner).
    pub known: Vec<bool>,
}

impl Numbering {
    /// Numbers the owned nodes' free components from `dof_offset` and their blocks from
    /// `block_offset`, node-major in node order; ghosts stay unknown.
    pub fn owned(
        local: &LocalNodes,
        ownership: &Ownership,
        dof_offset: u64,
        block_offset: u64,
    ) -> Self {
        let n = local.nodes.len();
        let mut numbering = Self {
            dofs: vec![NONE; n * local.components],
            blocks: vec![NONE; n],
            known: vec![false; n],
        };
        let (mut dof, mut block) = (dof_offset, block_offset);
        for i in (0..n).filter(|&i| ownership.owner[i] == ownership.rank) {
            numbering.known[i] = true;
            let free = local.free_of(i);
            for (c, _) in free.iter().enumerate().filter(|&(_, &f)| f) {
                numbering.dofs[i * local.components + c] = dof;
                dof += 1;
            }
            if free.contains(&true) {
                numbering.blocks[i] = block;
                block += 1;
            }
        }
        numbering
    }

    /// What this process sends every other: for each shared node it owns, the node, its
    /// block and its components' numbers (`2 + components` numbers).
    pub fn number_messages(&self, local: &LocalNodes, ownership: &Ownership) -> Vec<Vec<u64>> {
        let d = local.components;
        (ownership.shared.iter())
            .map(|nodes| {
                let mut message = Vec::new();
                for &i in nodes
                    .iter()
                    .filter(|&&i| ownership.owner[i] == ownership.rank)
                {
                    message.push(local.nodes[i] as u64);
                    message.push(self.blocks[i]);
                    message.extend(&self.dofs[i * d..(i + 1) * d]);
                }
                message
            })
            .collect()
    }

    /// Fills in the ghosts from their owners' messages (by source rank). Errors when a
    /// message is not whole, when numbers come from a process that does not own the node,
    /// when the owner's free components differ from this process's, or when a ghost got no
    /// numbers.
    pub fn receive(
        &mut self,
        local: &LocalNodes,
        ownership: &Ownership,
        received: &[Vec<u64>],
    ) -> Result<(), String> {
        let d = local.components;
        for (s, message) in received.iter().enumerate() {
            if message.len() % (2 + d) != 0 {
                return Err(format!(
                    "process {s} sent {} numbers for nodes of {} numbers each",
                    message.len(),
                    2 + d
                ));
            }
            for record in message.chunks_exact(2 + d) {
                let node = record[0] as usize;
                let Ok(i) = local.nodes.binary_search(&node) else {
                    return Err(format!("process {s} numbered node {node}, not one of ours"));
                };
                if ownership.owner[i] != s {
                    return Err(format!(
                        "process {s} numbered node {node}, owned by process {}",
                        ownership.owner[i]
                    ));
                }
                let numbers = &record[2..];
                let agree = (local.free_of(i).iter().zip(numbers)).all(|(&f, &n)| f == (n != NONE));
                if !agree {
                    return Err(format!(
                        "node {node}: its free components differ between process {s} and \
                         process {}",
                        ownership.rank
                    ));
                }
                self.blocks[i] = record[1];
                self.dofs[i * d..(i + 1) * d].copy_from_slice(numbers);
                self.known[i] = true;
            }
        }
        match self.known.iter().position(|&k| !k) {
            Some(i) => Err(format!(
                "node {} (owned by process {}) got no numbers from its owner",
                local.nodes[i], ownership.owner[i]
            )),
            None => Ok(()),
        }
    }

    /// The ghosts: nodes numbered by another process.
    pub fn ghosts(ownership: &Ownership) -> usize {
        (ownership.owner.iter())
            .filter(|&&o| o != ownership.rank)
            .count()
    }
}

/// The nodes shared with `s` (indices in `LocalNodes::nodes`, sorted) that `owner` owns.
fn shared_owned_by(ownership: &Ownership, s: usize, owner: usize) -> Vec<usize> {
    (ownership.shared.get(s).into_iter().flatten())
        .copied()
        .filter(|&i| ownership.owner[i] == owner)
        .collect()
}

/// The values of `nodes` (`width` each).
fn values_of(nodes: &[usize], values: &[f64], width: usize) -> Vec<f64> {
    (nodes.iter())
        .flat_map(|&i| values[i * width..(i + 1) * width].iter().copied())
        .collect()
}

/// The nodes a message from (or to) `s` lists, checked against its length.
fn message_nodes(
    ownership: &Ownership,
    s: usize,
    owner: usize,
    message: &[f64],
    width: usize,
) -> Result<Vec<usize>, String> {
    let nodes = shared_owned_by(ownership, s, owner);
    if message.len() != nodes.len() * width {
        return Err(format!(
            "process {s} sent {} values for {} shared nodes of {width} values each",
            message.len(),
            nodes.len()
        ));
    }
    Ok(nodes)
}

/// What this process sends each process `s`: its shares at the nodes `s` owns.
pub fn shares_to_owners(ownership: &Ownership, values: &[f64], width: usize) -> Vec<Vec<f64>> {
    (0..ownership.shared.len())
        .map(|s| values_of(&shared_owned_by(ownership, s, s), values, width))
        .collect()
}

/// Adds the shares received (by source rank, added in rank order) to the nodes this process
/// owns.
pub fn add_shares(
    ownership: &Ownership,
    values: &mut [f64],
    width: usize,
    received: &[Vec<f64>],
) -> Result<(), String> {
    let add = |values: &mut [f64], share: &[f64]| {
        for (value, add) in values.iter_mut().zip(share) {
            *value += add;
        }
    };
    receive_values(
        ownership,
        values,
        width,
        received,
        Some(ownership.rank),
        add,
    )
}

/// What this process sends each process `s`: the sums at the nodes it owns that `s` touches.
pub fn sums_to_sharers(ownership: &Ownership, values: &[f64], width: usize) -> Vec<Vec<f64>> {
    (0..ownership.shared.len())
        .map(|s| {
            values_of(
                &shared_owned_by(ownership, s, ownership.rank),
                values,
                width,
            )
        })
        .collect()
}

/// Sets the nodes other processes own to the sums their owners sent (by source rank).
pub fn set_sums(
    ownership: &Ownership,
    values: &mut [f64],
    width: usize,
    received: &[Vec<f64>],
) -> Result<(), String> {
    let set = |values: &mut [f64], sum: &[f64]| values.copy_from_slice(sum);
    receive_values(ownership, values, width, received, None, set)
}

/// Applies each message received (by source rank `s`, in rank order) to the nodes shared
/// with `s` that `owner` owns (`None`: `s` itself), `width` values per node.
fn receive_values(
    ownership: &Ownership,
    values: &mut [f64],
    width: usize,
    received: &[Vec<f64>],
    owner: Option<usize>,
    mut apply: impl FnMut(&mut [f64], &[f64]),
) -> Result<(), String> {
    for (s, message) in received.iter().enumerate() {
        let owner = owner.unwrap_or(s);
        let nodes = message_nodes(ownership, s, owner, message, width)?;
        for (&i, part) in nodes.iter().zip(message.chunks_exact(width)) {
            apply(&mut values[i * width..(i + 1) * width], part);
        }
    }
    Ok(())
}

/// The whole procedure for processes simulated in one (the messages handed over in memory):
/// each process's ownership and numbering, for tests and the docs' examples.
pub fn number_all(processes: &[LocalNodes]) -> Result<Vec<(Ownership, Numbering)>, String> {
    let ranges: Vec<_> = processes.iter().map(LocalNodes::layer_range).collect();
    let sent: Vec<Vec<Vec<u64>>> = (processes.iter().enumerate())
        .map(|(r, local)| shared_messages(local, &ranges, r))
        .collect();
    let received_by = |r: usize, sent: &[Vec<Vec<u64>>]| -> Vec<Vec<u64>> {
        sent.iter().map(|from| from[r].clone()).collect()
    };
    let ownerships: Vec<Ownership> = (processes.iter().enumerate())
        .map(|(r, local)| Ownership::new(local, r, &received_by(r, &sent)))
        .collect();
    let counts: Vec<(u64, u64)> = (ownerships.iter().zip(processes))
        .map(|(o, local)| o.owned_counts(local))
        .collect();
    let (dof_offsets, _) = offsets(&counts.iter().map(|c| c.0).collect::<Vec<_>>());
    let (block_offsets, _) = offsets(&counts.iter().map(|c| c.1).collect::<Vec<_>>());
    let mut numberings: Vec<Numbering> = (0..processes.len())
        .map(|r| {
            Numbering::owned(
                &processes[r],
                &ownerships[r],
                dof_offsets[r],
                block_offsets[r],
            )
        })
        .collect();
    let sent: Vec<Vec<Vec<u64>>> = (0..processes.len())
        .map(|r| numberings[r].number_messages(&processes[r], &ownerships[r]))
        .collect();
    for r in 0..processes.len() {
        numberings[r].receive(&processes[r], &ownerships[r], &received_by(r, &sent))?;
    }
    Ok(ownerships.into_iter().zip(numberings).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// A 2D grid of `nx × ny` cells with quadratic B-splines (`nx + 2` × `ny + 2` nodes; a
    /// cell's support is the 3 × 3 nodes from its index), slabs of cell rows along axis 1
    /// given by their first rows, the nodes of the bottom row fixed in both components and
    /// of the left column in x: each process's nodes are the supports of its cells.
    fn slabs(nx: usize, ny: usize, cuts: &[usize]) -> Vec<LocalNodes> {
        let nodes_x = nx + 2;
        let mut processes = Vec::new();
        for (r, &first) in cuts.iter().enumerate() {
            let end = cuts.get(r + 1).copied().unwrap_or(ny);
            let mut nodes = std::collections::BTreeSet::new();
            for cy in first..end {
                for cx in 0..nx {
                    for j in 0..3 {
                        for i in 0..3 {
                            nodes.insert((cy + j) * nodes_x + cx + i);
                        }
                    }
                }
            }
            let nodes: Vec<usize> = nodes.into_iter().collect();
            let layers = nodes.iter().map(|n| n / nodes_x).collect();
            let free = nodes
                .iter()
                .flat_map(|n| {
                    let (i, j) = (n % nodes_x, n / nodes_x);
                    [i != 0 && j != 0, j != 0]
                })
                .collect();
            processes.push(LocalNodes {
                nodes,
                layers,
                free,
                components: 2,
            });
        }
        processes
    }

    /// The serial numbering of the union of the processes' nodes (node-major in node order),
    /// as the core's DOF stage numbers it: (node, component) → number.
    fn serial(processes: &[LocalNodes]) -> BTreeMap<(usize, usize), u64> {
        let mut free = BTreeMap::new();
        for local in processes {
            for (i, &node) in local.nodes.iter().enumerate() {
                free.insert(node, local.free_of(i).to_vec());
            }
        }
        let mut numbers = BTreeMap::new();
        for (node, free) in free {
            for (c, f) in free.into_iter().enumerate() {
                if f {
                    let next = numbers.len() as u64;
                    numbers.insert((node, c), next);
                }
            }
        }
        numbers
    }

    #[test]
    fn every_dof_is_numbered_once_contiguously_per_process() {
        for cuts in [vec![0], vec![0, 3], vec![0, 2, 5], vec![0, 1, 2, 3]] {
            let processes = slabs(4, 6, &cuts);
            let serial = serial(&processes);
            let numbered = number_all(&processes).unwrap();
            // every (node, component) of the serial run gets one global number, the same on
            // every process holding the node, and the numbers are 0..serial count
            let mut global: BTreeMap<(usize, usize), u64> = BTreeMap::new();
            let mut owned_ranges = Vec::new();
            for (local, (ownership, numbering)) in processes.iter().zip(&numbered) {
                let mut owned = Vec::new();
                for (i, &node) in local.nodes.iter().enumerate() {
                    for c in 0..2 {
                        let n = numbering.dofs[i * 2 + c];
                        assert_eq!(n != NONE, local.free_of(i)[c], "node {node} c {c}");
                        if n == NONE {
                            continue;
                        }
                        if let Some(&before) = global.get(&(node, c)) {
                            assert_eq!(before, n, "node {node} numbered differently");
                        }
                        global.insert((node, c), n);
                        if ownership.owner[i] == ownership.rank {
                            owned.push(n);
                        }
                    }
                }
                owned_ranges.push(owned);
            }
            assert_eq!(global.len(), serial.len(), "cuts {cuts:?}");
            let mut all: Vec<u64> = global.values().copied().collect();
            all.sort_unstable();
            assert_eq!(all, (0..serial.len() as u64).collect::<Vec<_>>());
            // owned numbers: contiguous, in rank order
            let mut next = 0;
            for owned in owned_ranges {
                assert_eq!(owned, (next..next + owned.len() as u64).collect::<Vec<_>>());
                next += owned.len() as u64;
            }
            // one process numbers as the serial run does
            if cuts.len() == 1 {
                assert_eq!(global, serial);
            }
        }
    }

    #[test]
    fn the_lowest_rank_touching_a_node_owns_it_and_only_neighbours_talk() {
        let processes = slabs(3, 6, &[0, 2, 4]);
        let ranges: Vec<_> = processes.iter().map(LocalNodes::layer_range).collect();
        // node layers: cells 0..2 touch node rows 0..=3, 2..4 rows 2..=5, 4..6 rows 4..=7
        assert_eq!(ranges, vec![Some((0, 3)), Some((2, 5)), Some((4, 7))]);
        let messages = shared_messages(&processes[0], &ranges, 0);
        assert!(messages[0].is_empty() && messages[2].is_empty());
        // process 0 sends its node rows 2 and 3 to process 1: 2 × 5 nodes
        assert_eq!(messages[1].len(), 10);
        let numbered = number_all(&processes).unwrap();
        for (r, (ownership, _)) in numbered.iter().enumerate() {
            let neighbours: Vec<usize> = [r.checked_sub(1), Some(r + 1)]
                .into_iter()
                .flatten()
                .filter(|&s| s < 3)
                .collect();
            assert_eq!(ownership.neighbours(), neighbours);
            for (i, &node) in processes[r].nodes.iter().enumerate() {
                let row = node / 5;
                // rows 2, 3 are shared by 0 and 1; rows 4, 5 by 1 and 2
                let expected = match row {
                    0..=3 => 0,
                    4 | 5 => 1,
                    _ => 2,
                };
                assert_eq!(ownership.owner[i], expected, "process {r} node {node}");
            }
        }
        // ghosts: the two shared node rows below each process but the first
        let ghosts: Vec<usize> = numbered.iter().map(|(o, _)| Numbering::ghosts(o)).collect();
        assert_eq!(ghosts, vec![0, 10, 10]);
    }

    #[test]
    fn a_slab_thinner_than_a_support_reaches_past_its_neighbour() {
        // one cell row each: a support spans 3 node rows, so process 0 and process 2 share
        // node row 2
        let processes = slabs(2, 3, &[0, 1, 2]);
        let numbered = number_all(&processes).unwrap();
        assert_eq!(numbered[0].0.neighbours(), vec![1, 2]);
        assert_eq!(numbered[2].0.neighbours(), vec![0, 1]);
    }

    #[test]
    fn disagreements_and_missing_numbers_are_errors() {
        let processes = slabs(3, 4, &[0, 2]);
        let ranges: Vec<_> = processes.iter().map(LocalNodes::layer_range).collect();
        let sent: Vec<Vec<Vec<u64>>> = (0..2)
            .map(|r| shared_messages(&processes[r], &ranges, r))
            .collect();
        let ownership = Ownership::new(&processes[1], 1, &[sent[0][1].clone(), Vec::new()]);
        let mut numbering = Numbering::owned(&processes[1], &ownership, 0, 0);
        // nothing from the owner: the ghosts are unknown
        let missing =
            numbering
                .clone()
                .receive(&processes[1], &ownership, &[Vec::new(), Vec::new()]);
        assert!(missing.unwrap_err().contains("got no numbers"));
        // the owner's free components differ (a fixed component numbered)
        let owner = Ownership::new(&processes[0], 0, &[Vec::new(), sent[1][0].clone()]);
        let mut first = Numbering::owned(&processes[0], &owner, 0, 0);
        let i = processes[0]
            .nodes
            .binary_search(&ownership_first_ghost(&processes[1], &ownership))
            .unwrap();
        first.dofs[i * 2] = 999;
        first.dofs[i * 2 + 1] = NONE;
        let message = first.number_messages(&processes[0], &owner);
        let differs = numbering.receive(&processes[1], &ownership, &[message[1].clone(), vec![]]);
        assert!(differs.unwrap_err().contains("free components differ"));
        // numbers from a process that does not own the node
        let mut numbering = Numbering::owned(&processes[1], &ownership, 0, 0);
        let wrong = numbering.receive(&processes[1], &ownership, &[vec![], vec![0, 0, 0, 0]]);
        assert!(wrong.is_err());
        // a message that is not whole
        let broken = numbering.receive(&processes[1], &ownership, &[vec![1, 2, 3], vec![]]);
        assert!(broken.unwrap_err().contains("numbers for nodes of 4"));
    }

    fn ownership_first_ghost(local: &LocalNodes, ownership: &Ownership) -> usize {
        let i = (0..local.nodes.len())
            .find(|&i| ownership.owner[i] != ownership.rank && local.free_of(i).iter().all(|&f| f))
            .unwrap();
        local.nodes[i]
    }

    /// Sums at the shared nodes, processes simulated in one: each process's share at a node
    /// is a number of its own (`1000 r + node + c / 2`, exact in binary), and after the two
    /// exchanges every process holds, at each of its nodes, the sum over the processes
    /// touching it; a message of the wrong length is an error.
    #[test]
    fn shares_at_shared_nodes_add_up_on_every_process_touching_the_node() {
        for cuts in [vec![0], vec![0, 3], vec![0, 2, 4], vec![0, 1, 2]] {
            let processes = slabs(3, 6, &cuts);
            let numbered = number_all(&processes).unwrap();
            let ownerships: Vec<&Ownership> = numbered.iter().map(|(o, _)| o).collect();
            let share =
                |r: usize, node: usize, c: usize| 1000.0 * r as f64 + node as f64 + c as f64 / 2.0;
            let mut values: Vec<Vec<f64>> = (processes.iter().enumerate())
                .map(|(r, local)| {
                    (local.nodes.iter())
                        .flat_map(|&n| (0..2).map(move |c| share(r, n, c)))
                        .collect()
                })
                .collect();
            let mut expected: BTreeMap<(usize, usize), f64> = BTreeMap::new();
            for (r, local) in processes.iter().enumerate() {
                for &n in &local.nodes {
                    for c in 0..2 {
                        *expected.entry((n, c)).or_default() += share(r, n, c);
                    }
                }
            }
            let received_by = |r: usize, sent: &[Vec<Vec<f64>>]| -> Vec<Vec<f64>> {
                sent.iter().map(|from| from[r].clone()).collect()
            };
            let sent: Vec<Vec<Vec<f64>>> = (0..processes.len())
                .map(|r| shares_to_owners(ownerships[r], &values[r], 2))
                .collect();
            for r in 0..processes.len() {
                add_shares(ownerships[r], &mut values[r], 2, &received_by(r, &sent)).unwrap();
            }
            let sent: Vec<Vec<Vec<f64>>> = (0..processes.len())
                .map(|r| sums_to_sharers(ownerships[r], &values[r], 2))
                .collect();
            for r in 0..processes.len() {
                set_sums(ownerships[r], &mut values[r], 2, &received_by(r, &sent)).unwrap();
            }
            for (r, local) in processes.iter().enumerate() {
                for (i, &n) in local.nodes.iter().enumerate() {
                    for c in 0..2 {
                        assert_eq!(
                            values[r][i * 2 + c],
                            expected[&(n, c)],
                            "cuts {cuts:?} process {r} node {n}"
                        );
                    }
                }
            }
            if cuts.len() > 1 {
                // a share too few from process 1 to process 0
                let mut short = shares_to_owners(ownerships[1], &values[1], 2);
                short[0].pop();
                let wrong = add_shares(
                    ownerships[0],
                    &mut values[0],
                    2,
                    &[vec![], short[0].clone()],
                );
                assert!(wrong.unwrap_err().contains("shared nodes"), "{cuts:?}");
            }
        }
    }

    #[test]
    fn offsets_are_an_exclusive_scan() {
        assert_eq!(offsets(&[3, 0, 5, 2]), (vec![0, 3, 3, 8], 10));
        assert_eq!(offsets(&[]), (vec![], 0));
    }
}
