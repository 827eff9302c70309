//! Newton stage 2: internal force and consistent tangent (see `mechanics` for the formulas).
//!
//! Every point adds V0 τ g_i to the internal force of its support nodes and the blocks K_ij to
//! the tangent. When K is symmetric (`Newton::symmetric`: hyperelastic and associated plastic
//! models) only j >= i is computed and the transpose is added for the mirror block; otherwise
//! (non-associated plasticity) every block K_ij is computed. The node-j factor of K_ij is
//! computed once per node. Consecutive points with the same support (the points of a cell)
//! form a group: their blocks are summed in a dense
//! buffer, and the group's sum is scattered into the sparse values once, at positions cached
//! for the group; so the inner loop is D³ multiply-adds and D² additions per pair, and the
//! scattered writes are paid per cell rather than per point.
//!
//! The colouring is made once per load step and kept in [`ColouringCache`] for the step's
//! Newton iterations: the supports are evaluated at the step's start and do not change until
//! the next step (or the rerun of a cut step), whose DOF stage rebuilds the tangent's pattern
//! (`SparseMatrix::generation`). The cache is keyed on that generation, on the number of points
//! assembled, and on whether any point's `Support` was written since the assembly last ran
//! (change detection): any of them differing recomputes it. A colouring is a pure function of
//! the supports in query order, so the cached one equals the one recomputed, and the sums are
//! bit-identical to colouring every iteration.
//!
//! Points marked [`AssembledElsewhere`] are left out: in a distributed run each process sums
//! the points of its own block of cells, and `Hook::Combine` adds the processes' sums.
//!
//! Threads (`parallel`): the points are put in colour order (`colouring`: slabs of cells, two
//! colours, so that two slabs of one colour share no node), and
//! the threads share the blocks of one colour at a time, adding straight into the one internal
//! force and the one array of tangent values ([`parallel::for_each_colour`]). No copy of the
//! sums per thread; the internal force and the tangent are bit-identical for any thread count,
//! because every entry receives its terms in the colouring's order. Where the supports cannot be
//! coloured (fewer than `colouring::MIN_SLABS` slabs: supports that are not compact in the
//! grid's numbering, such as an FEM mesh's, or a grid a few supports wide), the points are cut
//! into one contiguous part per
//! thread, each part sums into its own internal force and copy of the tangent values, and the
//! copies are added in part order: bit-identical for a given thread count, equal to round-off
//! across counts. Where the points are too few to be split at all (under twice
//! `parallel::grain`: the paper's small columns) they are summed in one part, in query order,
//! with no colouring: the same sums for every thread count.

use bevy_ecs::prelude::*;
use nalgebra::{SMatrix, SVector};

use crate::colouring::{self, Colouring};
use crate::components::{AssembledElsewhere, ReferenceVolume, Support, Trial};
use crate::mechanics::StiffnessFactor;
use crate::node_storage::NodeVec;
use crate::parallel::{self, Disjoint};
use crate::resources::{
    Grid, GridFields, LoadStep, Newton, RunStatus, SolverError, Stage, StageClock,
};
use crate::solver::SparseMatrix;

/// A point as the assembly reads it.
type PointItem<'a, const D: usize> = (&'a Support<D>, &'a Trial<D>, &'a ReferenceVolume);

/// Where a part adds the internal force and the tangent values it sums.
trait Sums<const D: usize> {
    fn add_force(&mut self, node: usize, force: SVector<f64, D>);
    fn add_value(&mut self, k: usize, value: f64);
}

/// A part's own arrays (the fallback without colours; the first part's are the grid's and the
/// system's).
struct OwnSums<'a, const D: usize> {
    force: &'a mut [SVector<f64, D>],
    values: &'a mut [f64],
}

impl<const D: usize> Sums<D> for OwnSums<'_, D> {
    #[inline]
    fn add_force(&mut self, node: usize, force: SVector<f64, D>) {
        self.force[node] += force;
    }
    #[inline]
    fn add_value(&mut self, k: usize, value: f64) {
        self.values[k] += value;
    }
}

/// The one internal force and the one array of tangent values, shared by the threads. Made
/// only in [`assemble_coloured`], whose parts are runs of blocks of one colour
/// ([`parallel::for_each_colour`]): the supports of two such blocks share no node, so two
/// threads never add to one node's force, nor to one entry of K (whose row and column nodes
/// are both in the adding point's support).
struct SharedSums<'s, 'a, const D: usize> {
    force: &'s Disjoint<'a, SVector<f64, D>>,
    values: &'s Disjoint<'a, f64>,
}

impl<const D: usize> Sums<D> for SharedSums<'_, '_, D> {
    #[inline]
    fn add_force(&mut self, node: usize, force: SVector<f64, D>) {
        // SAFETY: see `SharedSums`: no other thread adds at this node during the colour.
        unsafe { self.force.update(node, |f| *f += force) }
    }
    #[inline]
    fn add_value(&mut self, k: usize, value: f64) {
        // SAFETY: see `SharedSums`: no other thread adds at this entry during the colour.
        unsafe { self.values.update(k, |v| *v += value) }
    }
}

/// Scratch memory of the assembly, kept between iterations.
#[derive(Default)]
pub struct AssemblyScratch<const D: usize> {
    gradients: Vec<SVector<f64, D>>,
    factors: Vec<StiffnessFactor<D>>,
    /// Support nodes for which `starts` was computed.
    cached_nodes: Vec<usize>,
    /// Block positions for the pairs (i, j) and (j, i), j >= i, in loop order.
    starts: Vec<([usize; D], [usize; D])>,
    /// The blocks K_ij (j >= i, loop order) summed over the points of the current group.
    blocks: Vec<SMatrix<f64, D, D>>,
    /// Whether K is symmetric: only j >= i is computed and mirrored; otherwise every (i, j).
    symmetric: bool,
}

impl<const D: usize> AssemblyScratch<D> {
    /// The first node j of the blocks K_ij computed for node i.
    fn first_partner(&self, i: usize) -> usize {
        if self.symmetric { i } else { 0 }
    }

    fn cache_block_positions(
        &mut self,
        nodes: impl Iterator<Item = usize>,
        dofs: &NodeVec<[u32; D]>,
        system: &SparseMatrix,
        symmetric: bool,
    ) {
        self.symmetric = symmetric;
        self.cached_nodes.clear();
        self.cached_nodes.extend(nodes);
        self.starts.clear();
        self.blocks.clear();
        let m = self.cached_nodes.len();
        for i in 0..m {
            let dofs_i = &dofs[self.cached_nodes[i]];
            for j in self.first_partner(i)..m {
                let dofs_j = &dofs[self.cached_nodes[j]];
                self.starts.push((
                    system.block_starts(dofs_i, dofs_j),
                    system.block_starts(dofs_j, dofs_i),
                ));
                self.blocks.push(SMatrix::zeros());
            }
        }
    }

    /// Adds the group's summed blocks (and, if symmetric, their transposes for j != i) to the
    /// sparse values (laid out as the system's) and clears them.
    fn flush(&mut self, dofs: &NodeVec<[u32; D]>, sums: &mut impl Sums<D>) {
        let m = self.cached_nodes.len();
        let mut pair = 0;
        for i in 0..m {
            let dofs_i = &dofs[self.cached_nodes[i]];
            for j in self.first_partner(i)..m {
                let (starts_ij, starts_ji) = &self.starts[pair];
                let k = &mut self.blocks[pair];
                SparseMatrix::add_block_with(starts_ij, dofs_i, k, |k, v| sums.add_value(k, v));
                if self.symmetric && j != i {
                    let dofs_j = &dofs[self.cached_nodes[j]];
                    let kt = k.transpose();
                    SparseMatrix::add_block_with(starts_ji, dofs_j, &kt, |k, v| {
                        sums.add_value(k, v)
                    });
                }
                *k = SMatrix::zeros();
                pair += 1;
            }
        }
    }
}

/// One thread's part of the assembly: its scratch, and (only without colours) the internal
/// force and tangent values it sums (the first part sums straight into the grid's and the
/// system's).
#[derive(Default)]
pub struct AssemblyPart<const D: usize> {
    scratch: AssemblyScratch<D>,
    internal_force: Vec<SVector<f64, D>>,
    values: Vec<f64>,
}

/// The colouring of the current load step's points, kept through its Newton iterations
/// (module docs), with counts of how often it was made and reused and the time spent making it.
#[derive(Resource, Debug, Default)]
pub struct ColouringCache {
    /// The pattern generation and the number of points the colouring was made for.
    key: Option<(u64, usize)>,
    colouring: Option<Colouring>,
    /// Colourings computed (one per load step, and per rerun of a cut step).
    pub computed: u64,
    /// Assemblies that used the cached colouring.
    pub reused: u64,
    /// Time spent computing colourings.
    pub seconds: std::time::Duration,
    /// Colour every assembly anew, as before the cache (for comparisons; off by default).
    pub recolour_every_assembly: bool,
}

impl ColouringCache {
    /// The colouring for `key` (pattern generation, number of points): the cached one when the
    /// key is the cached one's and `changed` is false, else `make()`'s, which is then cached.
    pub fn get(
        &mut self,
        key: (u64, usize),
        changed: bool,
        make: impl FnOnce() -> Option<Colouring>,
    ) -> Option<&Colouring> {
        if changed || self.recolour_every_assembly || self.key != Some(key) {
            let start = std::time::Instant::now();
            self.colouring = make();
            self.seconds += start.elapsed();
            self.key = Some(key);
            self.computed += 1;
        } else {
            self.reused += 1;
        }
        self.colouring.as_ref()
    }

    /// The cached colouring (`None` before the first assembly and where there is none).
    pub fn colouring(&self) -> Option<&Colouring> {
        self.colouring.as_ref()
    }
}

#[allow(clippy::too_many_arguments)]
pub fn assemble<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    mut newton: ResMut<Newton>,
    mut clock: ResMut<StageClock>,
    mut status: ResMut<RunStatus>,
    step: Res<LoadStep>,
    grid: Res<Grid<D>>,
    mut parts: Local<Vec<AssemblyPart<D>>>,
    mut cache: ResMut<ColouringCache>,
    points: Query<(&Support<D>, &Trial<D>, &ReferenceVolume), Without<AssembledElsewhere>>,
    supports: Query<Ref<Support<D>>, Without<AssembledElsewhere>>,
) {
    let _timer = clock.time(Stage::Assembly);
    let GridFields {
        dofs,
        internal_force,
        ..
    } = &mut *fields;
    let symmetric = newton.symmetric;
    let mut points: Vec<_> = points.iter().collect();
    // The nodes the points' supports reach, in the order the points first touch them: the
    // internal force is summed in an array of these (its place for each node), then put into
    // the grid's (`GridFields` is paged, `node_storage`: a process sums what it touches).
    let mut place = NodeVec::new(dofs.len(), u32::MAX);
    let mut nodes: Vec<usize> = Vec::new();
    for (support, ..) in &points {
        for w in &support.0 {
            if place[w.node] == u32::MAX {
                place[w.node] = nodes.len() as u32;
                nodes.push(w.node);
            }
        }
    }
    let mut force = vec![SVector::<f64, D>::zeros(); nodes.len()];
    // Too few points for two parts on any thread count: the plain loop, as on one thread.
    let colouring = if parallel::can_split(points.len()) {
        let key = (newton.matrix.generation(), points.len());
        let changed = supports.iter().any(|support| support.is_changed());
        cache.get(key, changed, || colour(&grid, &points))
    } else {
        None
    };
    parts.resize_with(parallel::part_count(points.len()), Default::default);
    newton.matrix.with_values_apart(|system, values| {
        let target = (&*dofs, &place, system, symmetric);
        match colouring {
            Some(colouring) => {
                // Only the fallback keeps copies: free any an earlier step made.
                for part in parts.iter_mut() {
                    part.internal_force = Vec::new();
                    part.values = Vec::new();
                }
                assemble_coloured(&points, colouring, target, &mut parts, &mut force, values)
            }
            None => assemble_in_parts(&mut points, target, &mut parts, &mut force, values),
        }
    });
    internal_force.reset();
    for (&node, f) in nodes.iter().zip(&force) {
        internal_force[node] = *f;
    }
    // Guard: a non-finite internal force is reported here, at the node where it appears.
    if let Some(node) = (nodes.iter().zip(&force))
        .filter(|(_, f)| f.iter().any(|c| !c.is_finite()))
        .map(|(&node, _)| node)
        .min()
    {
        status.fail(SolverError::NotFinite {
            stage: "assembly",
            what: format!("internal force of grid node {node}"),
            step: step.number,
        });
    }
}

/// The points' colouring (`colouring`) on the grid's node numbering, `None` without one.
fn colour<const D: usize>(grid: &Grid<D>, points: &[PointItem<'_, D>]) -> Option<Colouring> {
    colouring::colour_points(grid.0.nodes_per_axis(), points.len(), |p| {
        points[p].0.0.iter().map(|w| w.node)
    })
}

/// The DOF numbers, each node's place in the summed internal force, the system (for its
/// pattern) and whether K is symmetric.
type Target<'a, const D: usize> = (
    &'a NodeVec<[u32; D]>,
    &'a NodeVec<u32>,
    &'a SparseMatrix,
    bool,
);

/// The threads share one internal force and one array of values, colour after colour (module
/// docs).
fn assemble_coloured<const D: usize>(
    points: &[PointItem<'_, D>],
    colouring: &Colouring,
    (dofs, place, system, symmetric): Target<'_, D>,
    parts: &mut [AssemblyPart<D>],
    internal_force: &mut [SVector<f64, D>],
    values: &mut [f64],
) {
    let ordered: Vec<PointItem<'_, D>> = colouring
        .order
        .iter()
        .map(|&p| points[p as usize])
        .collect();
    parallel::fill(internal_force, SVector::zeros());
    parallel::fill(values, 0.0);
    let (force, values) = (Disjoint::new(internal_force), Disjoint::new(values));
    let mut scratches: Vec<&mut AssemblyScratch<D>> =
        parts.iter_mut().map(|part| &mut part.scratch).collect();
    parallel::for_each_colour(
        &ordered,
        &colouring.block_start,
        &colouring.colour_start,
        &mut scratches,
        |points, scratch| {
            let mut sums = SharedSums {
                force: &force,
                values: &values,
            };
            assemble_points(points, (dofs, place, system, symmetric), scratch, &mut sums);
        },
    );
}

/// The fallback: one contiguous part of the points per thread, each summing into its own
/// internal force and values (the first part into the grid's and the system's); the parts are
/// added in order afterwards, so a given thread count gives bit-identical sums.
fn assemble_in_parts<const D: usize>(
    points: &mut [PointItem<'_, D>],
    (dofs, place, system, symmetric): Target<'_, D>,
    parts: &mut [AssemblyPart<D>],
    internal_force: &mut [SVector<f64, D>],
    values: &mut [f64],
) {
    #[allow(clippy::expect_used, reason = "parallel::part_count is at least 1")]
    let (first, others) = parts.split_first_mut().expect("at least one part");
    for part in others.iter_mut() {
        part.internal_force
            .resize(internal_force.len(), SVector::zeros());
        part.values.resize(values.len(), 0.0);
    }
    let mut targets: Vec<_> =
        std::iter::once((&mut first.scratch, &mut internal_force[..], &mut values[..]))
            .chain(others.iter_mut().map(|part| {
                (
                    &mut part.scratch,
                    &mut part.internal_force[..],
                    &mut part.values[..],
                )
            }))
            .collect();
    parallel::for_each_part(points, &mut targets, |_, points, target| {
        let (scratch, force, values) = target;
        force.fill(SVector::zeros());
        values.fill(0.0);
        let mut sums = OwnSums { force, values };
        assemble_points(points, (dofs, place, system, symmetric), scratch, &mut sums);
    });
    let forces: Vec<&[_]> = others.iter().map(|p| &p.internal_force[..]).collect();
    parallel::add_parts(internal_force, &forces);
    let others: Vec<&[f64]> = others.iter().map(|p| &p.values[..]).collect();
    parallel::add_parts(values, &others);
}

/// Sums the internal force and tangent blocks of `points` (consecutive points with the same
/// support form a group, see the module docs) into `sums`.
fn assemble_points<const D: usize>(
    points: &[PointItem<'_, D>],
    (dofs, place, system, symmetric): Target<'_, D>,
    scratch: &mut AssemblyScratch<D>,
    sums: &mut impl Sums<D>,
) {
    scratch.cached_nodes.clear();
    for (support, trial, volume) in points {
        let (state, v0, support) = (&trial.0, volume.0, &support.0);
        if !scratch
            .cached_nodes
            .iter()
            .copied()
            .eq(support.iter().map(|w| w.node))
        {
            scratch.flush(dofs, sums);
            scratch.cache_block_positions(support.iter().map(|w| w.node), dofs, system, symmetric);
        }
        scratch.gradients.clear();
        scratch
            .gradients
            .extend(support.iter().map(|w| state.spatial_gradient(&w.gradient)));
        scratch.factors.clear();
        scratch
            .factors
            .extend(scratch.gradients.iter().map(|g| state.stiffness_factor(g)));
        let mut pair = 0;
        for (i, wi) in support.iter().enumerate() {
            let g_i = &scratch.gradients[i];
            sums.add_force(place[wi.node] as usize, state.internal_force(v0, g_i));
            for factor_j in &scratch.factors[scratch.first_partner(i)..] {
                scratch.blocks[pair] += state.stiffness_from(v0, g_i, factor_j);
                pair += 1;
            }
        }
    }
    scratch.flush(dofs, sums);
}
