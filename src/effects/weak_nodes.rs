//! Weak nodes: DOFs that only the tips of point domains reach, removed by extension
//! (`solver(#{ weak_nodes: ε })`, off by default; MPM bases only).
//!
//! A node that a point's support barely reaches gets a DOF whose force and stiffness vanish
//! with the overlap: the tip of a GIMP domain heaved a depth `d` over a grid line gives the
//! node beyond it a weight ∝ d², a stiffness ∝ d², and Newton a correction ∝ 1/d there — a
//! nearly singular direction (docs/plasticity.md, "GIMP with F-bar: why Newton fails"). As
//! extended B-splines and cell aggregation do in cut-cell methods, such a node's value is not
//! left free but expressed through interior nodes.
//!
//! # Which nodes are weak
//! A node's *share* of the material is its lumped volume over a full cell's,
//!
//! ```text
//!   s_i = Σ_p S_ip V_p / h^D     (a node inside the material: s_i = 1 for linear hats and GIMP)
//! ```
//!
//! and an active node with `s_i < ε` is weak. The share, not the largest `S_ip`, because it is
//! what the node's force and stiffness scale with: a node reached a little by many points is
//! held as well as one reached much by one, and a point's volume counts (GIMP's weights of a
//! heaved tip are ∝ d² whatever the point).
//!
//! # The extension
//! For every weak node `i` the grid direction `±e_a` is taken whose next two nodes `j` (the
//! neighbour) and `k` (the one beyond) are active and not weak, the one whose `j` has the
//! largest share (inward, into the material); the node's displacement is extrapolated
//! linearly from them along that line,
//!
//! ```text
//!   u_i = (1 + s) u_j − s u_k,    s = (x_i − x_j)·e_a / (x_j − x_k)·e_a    (2 u_j − u_k on a uniform grid)
//! ```
//!
//! which keeps linear completeness: an affine field on the interior nodes is reproduced at the
//! weak ones. Where only `j` qualifies the node is tied to it, `u_i = u_j` (the partition of
//! unity is kept); where neither does, or a component of a master is constrained while the
//! weak node's is free, that component stays as it was and is counted in `weak_nodes_left`
//! (a warning names the first step with any).
//!
//! Written `u = T u'` (`u'` the DOFs of the nodes that are not weak, `T` the identity on them
//! and the rows above for the weak ones), Newton solves the transformed system
//!
//! ```text
//!   K' = Tᵀ K T,    r' = Tᵀ r,    δ = T δ'
//! ```
//!
//! `K'` and `r'` are formed in place: every entry of `K` in a weak row or column is moved onto
//! the masters' rows and columns (`K'_ab += c_a c_b K_ij`), the weak DOF keeps a decoupled
//! diagonal (the mean of the others' |K_ii|, so that iterative solvers see a scale they know)
//! with a zero right-hand side, and the weak node's out-of-balance force moves onto its masters
//! (`f_int` there is set to `f_ext`, its masters' `f_int` lowered by `c_m r_i`), so the
//! convergence check, the line search and the solver all see `r'`. After every solve the weak
//! nodes' increments are set from their masters' (`u = T u'`), so the stress update and the G2P
//! update see the extended field. `K'` is the exact derivative of `r'(u')` when `K` is that of
//! `r(u)` (`tests/fbar_gimp.rs`).
//!
//! # Systems and seams
//! * [`find_weak_nodes`] (`Hook::Constraints`, after the connectivity and the grid
//!   constraints): the shares, the weak nodes and their masters, and for each a coupling group
//!   (the node, the nodes it couples with, its masters and those of its weak neighbours), so
//!   that the pattern holds every entry of `K'`;
//! * [`extend_system`] (`Hook::AfterAssembly`, after every other module's terms: the module is
//!   built last but one): `K'` and `r'`;
//! * [`extend_increments`] (`Hook::AfterLinearSolve`): `u = T u'`.
//!
//! Measures `weak_nodes` (weak nodes of the step) and `weak_nodes_left` (their components not
//! extended). Not for distributed runs (the transform needs the summed system, after
//! `Hook::Combine`) nor with arc-length control (its second right-hand side is not
//! transformed): a scene asking for either is refused.

use std::ops::Index;

use bevy_ecs::prelude::*;

use crate::basis::{BasisKind, GridBasis};
use crate::components::{Support, Volume};
use crate::node_storage::NodeVec;
use crate::plugin::{Extension, Hook, Plugin};
use crate::resources::{
    Grid, GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock, Warnings,
};
use crate::scene::{Kind, OptionSpec, Range, Resolver, SceneApi, SceneSpec, ScriptError};
use crate::solver::{NO_DOF, SparseMatrix};
use crate::stages::arc_length::ArcLengthSpec;

/// The scene's share below which a node is weak (`solver(#{ weak_nodes: ε })`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeakNodesSpec {
    pub epsilon: f64,
}

/// A weak node's extension: `u_node = Σ c_m u_m` over `masters`, for the components marked.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeTie<const D: usize> {
    pub node: usize,
    pub masters: Vec<(usize, f64)>,
    /// The components extended (free at the node and at every master).
    pub components: [bool; D],
}

/// The weak nodes of the current load step.
#[derive(Resource, Clone, Debug)]
pub struct WeakNodes<const D: usize> {
    pub epsilon: f64,
    pub ties: Vec<NodeTie<D>>,
    /// Weak nodes found this step.
    pub count: usize,
    /// Components of weak nodes that could not be extended.
    pub left: usize,
    warned: bool,
}

/// Why weak nodes do not apply to linear FEM.
const NOT_WITH_FEM: &str = "weak_nodes removes nodes that point domains barely reach; basis \"fem\" has a body-fitted mesh without such nodes (remove weak_nodes)";

/// The module.
#[derive(Clone, Copy, Debug, Default)]
pub struct WeakNodesModule;

impl Plugin for WeakNodesModule {
    fn name(&self) -> &'static str {
        "weak nodes"
    }

    fn scene_api(&self, api: &mut SceneApi) {
        api.extend(
            "solver",
            OptionSpec::new(
                "weak_nodes",
                Kind::Number(Range::Closed(0.0, 1.0)),
                "extend the DOFs of nodes whose share of the material (Σ S_ip V_p over a full cell's volume) is below ε inward, by linear extrapolation from the next two nodes (0 = off, the default; MPM bases only)",
            ),
        );
    }

    fn resolve(&self, scene: &mut Resolver) -> Result<(), ScriptError> {
        let Some(options) = scene.call_options("solver") else {
            return Ok(());
        };
        let epsilon = options.value.number("weak_nodes").unwrap_or(0.0);
        if epsilon <= 0.0 {
            return Ok(());
        }
        if !self.applies_to(scene.spec) {
            return Err(ScriptError::at(
                options.at,
                format!("solver(...): {NOT_WITH_FEM}"),
            ));
        }
        if scene.spec.part::<ArcLengthSpec>().is_some() {
            return Err(ScriptError::at(
                options.at,
                "solver(...): weak_nodes does not transform arc-length control's reference load: use it with load control".to_string(),
            ));
        }
        scene.spec.set_part(WeakNodesSpec { epsilon });
        Ok(())
    }

    fn describe(&self, spec: &SceneSpec) -> Option<String> {
        spec.part::<WeakNodesSpec>()
            .map(|w| format!("ε = {}", w.epsilon))
    }

    fn used_by(&self, spec: &SceneSpec) -> bool {
        spec.part::<WeakNodesSpec>().is_some()
    }

    fn applies_to(&self, spec: &SceneSpec) -> bool {
        spec.grid.basis != BasisKind::Fem
    }

    fn build<const D: usize>(&self, simulation: &mut Extension<'_, D>) {
        let spec = simulation.spec();
        let Some(weak) = spec.part::<WeakNodesSpec>().copied() else {
            return;
        };
        if !self.applies_to(spec) {
            simulation.fail(NOT_WITH_FEM);
            return;
        }
        #[cfg(feature = "mpi")]
        if crate::distributed::processes().is_some_and(|p| p.size > 1) {
            simulation.fail("weak_nodes is not available in distributed runs");
            return;
        }
        simulation.world().insert_resource(WeakNodes::<D> {
            epsilon: weak.epsilon,
            ties: Vec::new(),
            count: 0,
            left: 0,
            warned: false,
        });
        simulation
            .add_systems(Hook::Constraints, find_weak_nodes::<D>)
            .add_systems(Hook::AfterAssembly, extend_system::<D>)
            .add_systems(Hook::AfterLinearSolve, extend_increments::<D>)
            .add_measure("weak_nodes", |world, _| {
                world.get_resource::<WeakNodes<D>>().map(|w| w.count as f64)
            })
            .add_measure("weak_nodes_left", |world, _| {
                world.get_resource::<WeakNodes<D>>().map(|w| w.left as f64)
            });
    }
}

/// Every node's share of the material, `Σ_p S_ip V_p / h^D` (paged: the nodes the points touch).
pub fn material_shares<'a, const D: usize>(
    grid: &GridBasis<D>,
    points: impl Iterator<Item = (&'a Support<D>, f64)>,
) -> NodeVec<f64> {
    let cell_volume: f64 = grid.axes.iter().map(|a| a.spacing()).product();
    let mut share = NodeVec::new(grid.num_nodes(), 0.0);
    for (support, volume) in points {
        for w in &support.0 {
            share[w.node] += w.value * volume / cell_volume;
        }
    }
    share
}

/// The extension of every weak node (active, share below `epsilon`) and the number of their
/// components left free (no masters, or a master's component constrained where theirs is not).
pub fn find_ties<const D: usize>(
    grid: &GridBasis<D>,
    active: &NodeVec<bool>,
    constrained: &(impl Index<usize, Output = [bool; D]> + ?Sized),
    share: &(impl Index<usize, Output = f64> + ?Sized),
    epsilon: f64,
) -> (Vec<NodeTie<D>>, usize, usize) {
    let weak = |node: usize| active[node] && share[node] < epsilon;
    let strong = |node: usize| active[node] && share[node] >= epsilon;
    let counts = grid.nodes_per_axis();
    let step = |node: usize, axis: usize, up: bool| -> Option<usize> {
        let mut multi = grid.node_multi_index(node);
        if up {
            (multi[axis] + 1 < counts[axis]).then(|| {
                multi[axis] += 1;
                grid.node_index(multi)
            })
        } else {
            (multi[axis] > 0).then(|| {
                multi[axis] -= 1;
                grid.node_index(multi)
            })
        }
    };
    let (mut ties, mut count, mut left) = (Vec::new(), 0, 0);
    let weak_nodes = active.written().filter(|&(n, _)| weak(n)).map(|(n, _)| n);
    for node in weak_nodes {
        count += 1;
        // (share of j, masters) of the best direction with two masters, else with one
        let mut best: Option<(f64, Vec<(usize, f64)>)> = None;
        let mut tie: Option<(f64, usize)> = None;
        for axis in 0..D {
            for up in [false, true] {
                let Some(j) = step(node, axis, up).filter(|&j| strong(j)) else {
                    continue;
                };
                match step(j, axis, up).filter(|&k| strong(k)) {
                    Some(k) if best.as_ref().is_none_or(|b| share[j] > b.0) => {
                        let (xi, xj, xk) = (
                            grid.node_position(node)[axis],
                            grid.node_position(j)[axis],
                            grid.node_position(k)[axis],
                        );
                        let s = (xi - xj) / (xj - xk);
                        best = Some((share[j], vec![(j, 1.0 + s), (k, -s)]));
                    }
                    Some(_) => {}
                    None if tie.is_none_or(|t| share[j] > t.0) => tie = Some((share[j], j)),
                    None => {}
                }
            }
        }
        let masters = match (best, tie) {
            (Some((_, masters)), _) => masters,
            (None, Some((_, j))) => vec![(j, 1.0)],
            (None, None) => {
                left += (0..D).filter(|&c| !constrained[node][c]).count();
                continue;
            }
        };
        let components = std::array::from_fn(|c| {
            !constrained[node][c] && masters.iter().all(|&(m, _)| !constrained[m][c])
        });
        left += (0..D)
            .filter(|&c| !constrained[node][c] && !components[c])
            .count();
        ties.push(NodeTie {
            node,
            masters,
            components,
        });
    }
    (ties, count, left)
}

/// The coupling group of each tie: its node, every node that shares a support or a coupling
/// group with it, its masters and the masters of its weak neighbours.
fn coupling_groups<'a, const D: usize>(
    ties: &[NodeTie<D>],
    nodes: usize,
    supports: impl Iterator<Item = &'a Support<D>>,
    couplings: &[Vec<usize>],
) -> Vec<Vec<usize>> {
    let mut tie_of = NodeVec::new(nodes, usize::MAX);
    for (t, tie) in ties.iter().enumerate() {
        tie_of[tie.node] = t;
    }
    let mut groups: Vec<Vec<usize>> = ties.iter().map(|t| vec![t.node]).collect();
    let mut add_neighbours = |members: &mut dyn Iterator<Item = usize>| {
        let members: Vec<usize> = members.collect();
        for &a in &members {
            if tie_of[a] != usize::MAX {
                groups[tie_of[a]].extend(&members);
            }
        }
    };
    for support in supports {
        add_neighbours(&mut support.0.iter().map(|w| w.node));
    }
    for group in couplings {
        add_neighbours(&mut group.iter().copied());
    }
    for group in &mut groups {
        let neighbours = group.clone();
        for n in neighbours {
            if tie_of[n] != usize::MAX {
                group.extend(ties[tie_of[n]].masters.iter().map(|&(m, _)| m));
            }
        }
        group.sort_unstable();
        group.dedup();
    }
    groups
}

/// `Hook::Constraints`: the weak nodes of the step, their extensions and coupling groups.
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn find_weak_nodes<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut weak: ResMut<WeakNodes<D>>,
    mut fields: ResMut<GridFields<D>>,
    mut warnings: ResMut<Warnings>,
    mut clock: ResMut<StageClock>,
    points: Query<(&Support<D>, &Volume)>,
) {
    let _timer = clock.time(Stage::Connectivity);
    let share = material_shares(&grid.0, points.iter().map(|(s, v)| (s, v.0)));
    let (ties, count, left) = find_ties(
        &grid.0,
        &fields.active,
        &fields.constrained,
        &share,
        weak.epsilon,
    );
    let groups = coupling_groups(
        &ties,
        fields.active.len(),
        points.iter().map(|(s, _)| s),
        &fields.couplings,
    );
    fields.couplings.extend(groups);
    if left > 0 && !weak.warned {
        weak.warned = true;
        warnings.0.push(format!(
            "load step {}: {left} components of weak nodes (share of the material below {}) have no two active nodes inward to be extended from and stay free: Newton may stall there (measure weak_nodes_left)",
            step.number, weak.epsilon
        ));
    }
    *weak = WeakNodes {
        ties,
        count,
        left,
        ..weak.clone()
    };
}

/// A weak DOF and its masters' DOFs with their coefficients.
#[derive(Clone, Debug, PartialEq)]
pub struct DofTie {
    pub dof: usize,
    pub masters: Vec<(usize, f64)>,
}

/// The DOF ties of the node ties (their extended components).
pub fn dof_ties<const D: usize>(
    ties: &[NodeTie<D>],
    dofs: &(impl std::ops::Index<usize, Output = [u32; D]> + ?Sized),
) -> Vec<DofTie> {
    let mut out = Vec::new();
    for tie in ties {
        for c in (0..D).filter(|&c| tie.components[c]) {
            out.push(DofTie {
                dof: dofs[tie.node][c] as usize,
                masters: tie
                    .masters
                    .iter()
                    .map(|&(m, coeff)| (dofs[m][c] as usize, coeff))
                    .collect(),
            });
        }
    }
    out.retain(|t| t.dof != NO_DOF as usize);
    out
}

/// `K ← Tᵀ K T` in place, the weak DOFs decoupled with the mean |diagonal| of the others;
/// `Err((row, col))` names an entry of `K'` the pattern lacks.
pub fn transform_tangent(matrix: &mut SparseMatrix, ties: &[DofTie]) -> Result<(), (usize, usize)> {
    let n = matrix.size();
    let mut tie_of = vec![usize::MAX; n];
    for (t, tie) in ties.iter().enumerate() {
        tie_of[tie.dof] = t;
    }
    matrix.with_values_apart(|m, values| {
        let (col_ptr, row_idx) = m.pattern();
        let position = |row: usize, col: usize| {
            row_idx[col_ptr[col]..col_ptr[col + 1]]
                .binary_search(&row)
                .map(|k| col_ptr[col] + k)
                .map_err(|_| (row, col))
        };
        let mut moved = Vec::new();
        let (mut diagonal, mut diagonals) = (0.0, 0usize);
        for col in 0..n {
            for k in col_ptr[col]..col_ptr[col + 1] {
                let row = row_idx[k];
                if tie_of[row] != usize::MAX || tie_of[col] != usize::MAX {
                    if values[k] != 0.0 {
                        moved.push((row, col, values[k]));
                    }
                    values[k] = 0.0;
                } else if row == col {
                    diagonal += values[k].abs();
                    diagonals += 1;
                }
            }
        }
        let one = |d: usize| [(d, 1.0)];
        let expand = |d: usize| -> Vec<(usize, f64)> {
            match tie_of[d] {
                usize::MAX => one(d).to_vec(),
                t => ties[t].masters.clone(),
            }
        };
        for (row, col, value) in moved {
            for (r, cr) in expand(row) {
                for (c, cc) in expand(col) {
                    values[position(r, c)?] += cr * cc * value;
                }
            }
        }
        let scale = if diagonals > 0 {
            diagonal / diagonals as f64
        } else {
            1.0
        };
        for tie in ties {
            values[position(tie.dof, tie.dof)?] = scale;
        }
        Ok(())
    })
}

/// `r ← Tᵀ r` on the grid's forces: the weak node's out-of-balance force moves onto its
/// masters (their `f_int` lowered by `c_m r_i`) and its own `f_int` is set to `f_ext`.
pub fn transform_forces<const D: usize>(fields: &mut GridFields<D>, ties: &[NodeTie<D>]) {
    for tie in ties {
        for c in (0..D).filter(|&c| tie.components[c]) {
            let i = tie.node;
            let r = fields.external_force[i][c] - fields.internal_force[i][c];
            fields.internal_force[i][c] = fields.external_force[i][c];
            for &(m, coeff) in &tie.masters {
                fields.internal_force[m][c] -= coeff * r;
            }
        }
    }
}

/// `u = T u'`: the weak nodes' increments from their masters'.
pub fn apply_extension<const D: usize>(fields: &mut GridFields<D>, ties: &[NodeTie<D>]) {
    for tie in ties {
        for c in (0..D).filter(|&c| tie.components[c]) {
            fields.increment[tie.node][c] = tie
                .masters
                .iter()
                .map(|&(m, coeff)| coeff * fields.increment[m][c])
                .sum();
        }
    }
}

/// `Hook::AfterAssembly`: `K' = Tᵀ K T` and `r' = Tᵀ r`.
pub fn extend_system<const D: usize>(
    weak: Res<WeakNodes<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
) {
    let _timer = clock.time(Stage::Assembly);
    if weak.ties.is_empty() {
        return;
    }
    let ties = dof_ties(&weak.ties, &fields.dofs);
    if let Err((row, col)) = transform_tangent(&mut newton.matrix, &ties) {
        status.fail(SolverError::Module {
            step: step.number,
            what: format!(
                "weak nodes: the extended tangent's entry ({row}, {col}) is not in the sparsity pattern"
            ),
            recoverable: false,
        });
        return;
    }
    transform_forces(&mut fields, &weak.ties);
}

/// `Hook::AfterLinearSolve`: `u = T u'`.
pub fn extend_increments<const D: usize>(
    weak: Res<WeakNodes<D>>,
    mut fields: ResMut<GridFields<D>>,
) {
    apply_extension(&mut fields, &weak.ties);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4 × 3 node grid of linear hats, 3 × 2 unit cells.
    fn grid() -> GridBasis<2> {
        GridBasis::<2>::from_spec(&crate::basis::GridSpec {
            lower: vec![0.0, 0.0],
            upper: vec![3.0, 2.0],
            cells: vec![3, 2],
            basis: BasisKind::Linear,
        })
        .unwrap()
    }

    /// Where only the neighbour inward is active and not weak, the node is tied to it
    /// (`u_i = u_j`); where no neighbour is, its free components are counted as left, and a
    /// constrained component of a master leaves that component free.
    #[test]
    fn nodes_without_two_masters_are_tied_or_left() {
        let grid = grid();
        let n = grid.num_nodes();
        let node = |x, y| grid.node_index([x, y]);
        let mut active = vec![false; n];
        let mut share = vec![0.0; n];
        // (0, 2) weak above (0, 1), whose node below is inactive: a tie
        for (x, y, s) in [(0, 2, 1e-6), (0, 1, 0.5), (3, 0, 1e-6), (3, 1, 1e-6)] {
            active[node(x, y)] = true;
            share[node(x, y)] = s;
        }
        let mut constrained = vec![[false; 2]; n];
        constrained[node(0, 1)][0] = true;
        let active = NodeVec::from_values(&active, false);
        let (ties, count, left) = find_ties(&grid, &active, &constrained, &share, 1e-3);
        // (3, 0) and (3, 1) are weak with no strong neighbour: 4 components left; (0, 2)'s
        // x component is left because its master's is constrained
        assert_eq!((count, left, ties.len()), (3, 5, 1));
        assert_eq!(ties[0].node, node(0, 2));
        assert_eq!(ties[0].masters, vec![(node(0, 1), 1.0)]);
        assert_eq!(ties[0].components, [false, true]);
    }

    /// On a 4 × 3 node grid whose top row is barely reached, the top nodes are extrapolated
    /// from the two rows below (2 u_j − u_k), the others are not weak.
    #[test]
    fn top_row_is_extrapolated_from_the_two_rows_below() {
        let grid = grid();
        let n = grid.num_nodes();
        let share: Vec<f64> = (0..n)
            .map(|i| {
                if grid.node_multi_index(i)[1] == 2 {
                    1e-6
                } else {
                    0.5
                }
            })
            .collect();
        let (ties, count, left) = find_ties(
            &grid,
            &NodeVec::from_values(&vec![true; n], false),
            &vec![[false; 2]; n],
            &share,
            1e-3,
        );
        assert_eq!((count, left, ties.len()), (4, 0, 4));
        for tie in &ties {
            let [x, y] = grid.node_multi_index(tie.node);
            assert_eq!(y, 2);
            let j = grid.node_index([x, 1]);
            let k = grid.node_index([x, 0]);
            assert_eq!(tie.masters, vec![(j, 2.0), (k, -1.0)]);
        }
    }
}
