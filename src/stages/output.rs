//! Output: the state of the points, the grid and its control points as VTK files for ParaView.
//!
//! Files written per output step (`NNNN` = load step, 0 = initial state):
//! * `particles_NNNN.vtu` — one vertex cell per material point with `reference_position`,
//!   `reference_volume`, `volume`, `mass`, `displacement`, `cauchy_stress` (3x3, row-major),
//!   `deformation_gradient` (3x3, row-major) and `body`, then the fields modules add at
//!   `Hook::PointFields` ([`PointFields`]: e.g. `point_load`, `recovered_stress`).
//! * `grid_NNNN.vtu` — [`write_grid`], the default of `Hook::GridOutput`: the background grid
//!   cells, with the displacement increment of the step evaluated at the grid vertices and the
//!   number of material points per cell (a module may provide another grid file: the FEM mesh).
//! * `nodes_NNNN.vtu` — the control points (grid nodes) with `active`, `fixed` (the components
//!   constrained in the step), `displacement_increment`, `external_force` and `internal_force`.
//!
//! and the time series `particles.pvd`, `grid.pvd`, `nodes.pvd` with the load factor as time;
//! modules write their own files at `Hook::Output` (e.g. `tractions_NNNN.vtu`).
//! Every file is written atomically and a series lists a file only once it is complete, so a
//! run that stops leaves valid results behind.

use std::path::PathBuf;

use bevy_ecs::prelude::*;
use nalgebra::{Matrix3, SVector};

use crate::basis::{BasisScratch, GridBasis};
use crate::components::{
    AssembledElsewhere, BodyIndex, DeformationGradient, Displacement, GridNode, Mass, PointId,
    Position, ReferencePosition, ReferenceVolume, Trial, Volume,
};
use crate::mechanics::{embed, interpolate};
use crate::output::{
    CELL_ID, Cells, Field, NODE_ID, POINT_ID, PvdSeries, Sink, StreamedField, VERTEX_ID,
    lattice_cells, vertex_cells, write_vtu, write_vtu_streamed,
};
use crate::resources::{
    CurrentStage, Grid, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock,
};

/// The core's particle fields, in file order, with their meaning (`output(#{ fields: [..] })`
/// picks some; the scene language learns them through the module machinery).
pub const PARTICLE_FIELDS: &[(&str, &str)] = &[
    ("reference_position", "X, the reference position"),
    ("reference_volume", "V0, the reference volume"),
    ("volume", "V = J V0, the current volume"),
    ("mass", "m = ρ0 V0"),
    ("displacement", "u = x − X"),
    (
        "cauchy_stress",
        "σ = τ / J (3x3, row-major: σ_yy is component 4, σ_zz component 8)",
    ),
    ("deformation_gradient", "F (3x3, row-major)"),
    (
        "body",
        "the index of the point's body, in declaration order",
    ),
];

/// Extra point fields of the output step, added by modules at `Hook::PointFields` and written
/// after the core's fields (then cleared).
#[derive(Resource, Default, Debug)]
pub struct PointFields(pub Vec<PointField>);

/// One extra point field: `components` values per point, in point order (`PointId`).
#[derive(Clone, Debug, PartialEq)]
pub struct PointField {
    pub name: &'static str,
    pub components: usize,
    pub values: Vec<f64>,
}

impl PointFields {
    /// Adds a field of `count` points from `(point id, values)` pairs; points not listed get
    /// zeros.
    pub fn add<const C: usize>(
        &mut self,
        name: &'static str,
        count: usize,
        values: impl Iterator<Item = (u32, [f64; C])>,
    ) {
        let mut field = vec![0.0; C * count];
        for (id, value) in values {
            let start = C * id as usize;
            if let Some(slot) = field.get_mut(start..start + C) {
                slot.copy_from_slice(&value);
            }
        }
        self.0.push(PointField {
            name,
            components: C,
            values: field,
        });
    }
}

/// The particle file as one piece of a parallel data set: a distributed run, where each
/// process writes the points it assembles ([`AssembledElsewhere`] points are left out) as
/// `particles_NNNN_pK.vtu` into `dir` (the run's folder), with a `point_id` array; the module
/// that inserts this resource lists the pieces in `particles_NNNN.pvtu` and the `.pvd`
/// (`write_particles` then pushes nothing). A failed write is kept in `written` rather than
/// failing the run here, so that the module can share it with the other processes first.
#[derive(Resource, Debug)]
pub struct ParticlePieces {
    /// This piece's number (the process's rank).
    pub piece: usize,
    /// The folder of the pieces.
    pub dir: PathBuf,
    /// The piece of the last output step, or why it could not be written.
    pub written: Option<Result<WrittenPiece, String>>,
}

/// A piece of a parallel file, as written: its file name and its point and cell arrays
/// `(name, components)`, in file order.
#[derive(Clone, Debug, PartialEq)]
pub struct WrittenPiece {
    pub file: String,
    pub arrays: Vec<(String, usize)>,
    pub cell_arrays: Vec<(String, usize)>,
}

/// The grid and node files as pieces of parallel data sets: a decomposed run
/// (`impm run --decompose`), where each process holds only the grid nodes its own points
/// touch. The module that inserts this resource fills it in before the output of a step
/// (`effects::distributed::grid_pieces`): which nodes and cells this piece writes (every node
/// and cell of the lattice in exactly one piece), every node's increment (from its owner) and
/// the material points per cell (summed over the processes). [`write_nodes`] then writes the
/// piece's nodes as `nodes_NNNN_pK.vtu` with a [`NODE_ID`] array, [`write_grid`] the piece's
/// cells as `grid_NNNN_pK.vtu` with [`VERTEX_ID`] and [`CELL_ID`] arrays, both into `dir`, and
/// the module lists them (`.pvtu`, `.pvd`). A failed write is kept in `grid_written` /
/// `nodes_written`, as [`ParticlePieces::written`].
#[derive(Resource, Debug, Default)]
pub struct GridPieces {
    /// This piece's number (the process's rank).
    pub piece: usize,
    /// The folder of the pieces.
    pub dir: PathBuf,
    /// Whether this piece writes each node of the grid.
    pub nodes: Vec<bool>,
    /// Whether this piece writes each cell of the lattice.
    pub cells: Vec<bool>,
    /// Every node's displacement increment, `D` numbers per node.
    pub increment: Vec<f64>,
    /// The material points in each cell, over every process.
    pub points_per_cell: Vec<f64>,
    /// Whether the fields above are this output step's (set by the module, taken by the
    /// writers: a piece is never written from another step's values).
    pub ready: bool,
    pub grid_written: Option<Result<WrittenPiece, String>>,
    pub nodes_written: Option<Result<WrittenPiece, String>>,
}

/// Run condition: the current step is an output step.
pub fn writes_output(step: Res<LoadStep>, plan: Res<OutputPlan>) -> bool {
    plan.writes(&step)
}

/// Where and when output is written.
#[derive(Resource)]
pub struct OutputPlan {
    pub dir: PathBuf,
    /// Write every n-th step (the initial state and the last step are always written).
    pub every: usize,
    pub last_step: usize,
    /// If set, exactly these steps (and the initial state) are written instead.
    pub steps: Option<Vec<usize>>,
    /// If set, only these particle fields are written.
    pub fields: Option<Vec<String>>,
    /// Whether the grid and node files are written.
    pub grid_files: bool,
    pub particles: PvdSeries,
    pub grid: PvdSeries,
    pub nodes: PvdSeries,
}

impl OutputPlan {
    pub fn new(dir: PathBuf, every: usize, last_step: usize) -> Self {
        Self {
            particles: PvdSeries::new(dir.join("particles.pvd")),
            grid: PvdSeries::new(dir.join("grid.pvd")),
            nodes: PvdSeries::new(dir.join("nodes.pvd")),
            dir,
            every: every.max(1),
            last_step,
            steps: None,
            fields: None,
            grid_files: true,
        }
    }

    /// Whether the state after `step` is written: the initial state and, for a completed step
    /// (never an intermediate sub-step of a cut step), the listed steps if `steps` is set, else
    /// the last step and every n-th step.
    pub fn writes(&self, step: &LoadStep) -> bool {
        let number = step.number;
        if number == 0 {
            return true;
        }
        step.completes_step
            && match &self.steps {
                Some(steps) => steps.contains(&number),
                None => number == self.last_step || number.is_multiple_of(self.every),
            }
    }

    /// Whether the particle field `name` is written.
    pub fn writes_field(&self, name: &str) -> bool {
        self.fields
            .as_ref()
            .is_none_or(|fields| fields.iter().any(|field| field == name))
    }
}

/// Row-major components of a 3x3 tensor.
pub fn row_major(m: &Matrix3<f64>) -> [f64; 9] {
    std::array::from_fn(|k| m[(k / 3, k % 3)])
}

/// A D-vector padded to 3 components.
pub fn pad<const D: usize>(v: &SVector<f64, D>) -> [f64; 3] {
    std::array::from_fn(|k| if k < D { v[k] } else { 0.0 })
}

/// One point as the particle file reads it.
type Particle<'a, const D: usize> = (
    (&'a PointId, bool, Entity),
    &'a Position<D>,
    &'a ReferencePosition<D>,
    &'a ReferenceVolume,
    &'a Volume,
    &'a Mass,
    &'a Displacement<D>,
    &'a DeformationGradient<D>,
    &'a Trial<D>,
    &'a BodyIndex,
);

/// Appends one point's values of an array.
type Values<const D: usize> = fn(&Particle<'_, D>, &mut Vec<f64>);

/// Points per run of values handed to the writer: the only buffer an array needs.
const RUN: usize = 4096;

/// The particle file. Its arrays are produced from the points' components run by run while
/// the file is written ([`write_vtu_streamed`]): besides the points' entities in `PointId`
/// order (16 B per point), no array is held whole in memory (the file is the one the same
/// arrays written whole would give, byte for byte).
#[allow(clippy::type_complexity)]
#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads and writes
pub fn write_particles<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    mut plan: ResMut<OutputPlan>,
    mut extra: ResMut<PointFields>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut pieces: Option<ResMut<ParticlePieces>>,
    points: Query<(
        (&PointId, Has<AssembledElsewhere>, Entity),
        &Position<D>,
        &ReferencePosition<D>,
        &ReferenceVolume,
        &Volume,
        &Mass,
        &Displacement<D>,
        &DeformationGradient<D>,
        &Trial<D>,
        &BodyIndex,
    )>,
) {
    if !plan.writes(&step) {
        return;
    }
    let _timer = clock.time(Stage::Output);
    // the points written (by PointId, over all points) and their entities
    let mut keyed: Vec<(u32, Entity)> = points
        .iter()
        .filter(|row| pieces.is_none() || !row.0.1)
        .map(|row| (row.0.0.0, row.0.2))
        .collect();
    keyed.sort_unstable_by_key(|&(id, _)| id);
    let n = keyed.len();
    let (keyed, query) = (&keyed, &points);
    let stream = |values: Values<D>| {
        move |sink: &mut Sink| {
            let mut run = Vec::with_capacity(9 * RUN);
            for chunk in keyed.chunks(RUN) {
                run.clear();
                for point in query.iter_many(chunk.iter().map(|&(_, entity)| entity)) {
                    values(&point.map_err(std::io::Error::other)?, &mut run);
                }
                sink(&run)?;
            }
            Ok(())
        }
    };
    let coordinates = stream(|p, out| out.extend(pad(&p.1.0)));
    // in the order of PARTICLE_FIELDS
    let columns: [(usize, Values<D>); 8] = [
        (3, |p, out| out.extend(pad(&p.2.0))),
        (1, |p, out| out.push(p.3.0)),
        (1, |p, out| out.push(p.4.0)),
        (1, |p, out| out.push(p.5.0)),
        (3, |p, out| out.extend(pad(&p.6.0))),
        (9, |p, out| out.extend(row_major(&p.8.0.cauchy()))),
        (9, |p, out| out.extend(row_major(&embed(&p.7.0)))),
        (1, |p, out| out.push(p.9.0 as f64)),
    ];
    let columns = columns.map(|(components, values)| (components, stream(values)));
    let mut extra = std::mem::take(&mut extra.0);
    // the fields are indexed by PointId: keep the written points' values (a piece of a
    // distributed run, or the points of a decomposed run, whose ids need not be 0..n)
    let contiguous = keyed.last().is_none_or(|&(id, _)| id as usize + 1 == n);
    for field in &mut extra {
        let c = field.components;
        if !contiguous || field.values.len() != c * n {
            let mut kept = Vec::with_capacity(c * n);
            for &(id, _) in keyed {
                let id = id as usize;
                match field.values.get(c * id..c * (id + 1)) {
                    Some(values) => kept.extend_from_slice(values),
                    None => kept.resize(kept.len() + c, 0.0),
                }
            }
            field.values = kept;
        }
    }
    let extra_values: Vec<_> = extra.iter().map(|field| whole(&field.values)).collect();
    let mut fields: Vec<StreamedField> = PARTICLE_FIELDS
        .iter()
        .zip(&columns)
        .map(|(&(name, _), (components, values))| StreamedField {
            name,
            components: *components,
            values,
        })
        .chain(
            extra
                .iter()
                .zip(&extra_values)
                .map(|(field, values)| StreamedField {
                    name: field.name,
                    components: field.components,
                    values,
                }),
        )
        .collect();
    fields.retain(|field| plan.writes_field(field.name));
    if let Some(pieces) = pieces.as_deref_mut() {
        let point_id = |sink: &mut Sink| {
            for chunk in keyed.chunks(RUN) {
                let ids: Vec<f64> = chunk.iter().map(|&(id, _)| id as f64).collect();
                sink(&ids)?;
            }
            Ok(())
        };
        fields.push(StreamedField {
            name: POINT_ID,
            components: 1,
            values: &point_id,
        });
        let name = format!("particles_{:04}_p{}.vtu", step.number, pieces.piece);
        let arrays = fields
            .iter()
            .map(|f| (f.name.to_string(), f.components))
            .collect();
        let result = write_vtu_streamed(
            &pieces.dir.join(&name),
            n,
            &coordinates,
            &vertex_cells(n),
            &fields,
        );
        pieces.written = Some(match result {
            Ok(()) => Ok(WrittenPiece {
                file: name,
                arrays,
                cell_arrays: Vec::new(),
            }),
            Err(e) => Err(format!("{name}: {e}")),
        });
        return;
    }
    let name = format!("particles_{:04}.vtu", step.number);
    let result = write_vtu_streamed(
        &plan.dir.join(&name),
        n,
        &coordinates,
        &vertex_cells(n),
        &fields,
    )
    .and_then(|()| {
        plan.particles
            .push(step.series_time(stage.as_deref()), &name)
    });
    if let Err(e) = result {
        status.fail(SolverError::Output {
            step: step.number,
            why: format!("{name}: {e}"),
        });
    }
}

/// An array held whole, as a stream of one run.
fn whole(values: &[f64]) -> impl Fn(&mut Sink) -> std::io::Result<()> + '_ {
    move |sink| sink(values)
}

/// The material points in each cell of the lattice (cells numbered axis 0 fastest, as
/// [`lattice_cells`]) of the points at `positions`; a point outside the grid is in none.
pub fn points_per_cell<'a, const D: usize>(
    basis: &GridBasis<D>,
    positions: impl Iterator<Item = &'a SVector<f64, D>>,
) -> Vec<f64> {
    let mut counts = vec![0.0; basis.num_cells()];
    for x in positions {
        if let Ok(cell) = basis.cell_of(x) {
            counts[basis.cell_index(cell)] += 1.0;
        }
    }
    counts
}

/// The default grid file (`Hook::GridOutput`): the background grid, or this process's piece
/// of it ([`GridPieces`]: its cells and their vertices, with their numbers in the whole
/// lattice).
#[allow(clippy::too_many_arguments)]
pub fn write_grid<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    grid: Res<Grid<D>>,
    fields: Res<GridFields<D>>,
    mut plan: ResMut<OutputPlan>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<BasisScratch>,
    mut pieces: Option<ResMut<GridPieces>>,
    positions: Query<&Position<D>>,
) {
    if !plan.writes(&step) || !plan.grid_files {
        return;
    }
    let _timer = clock.time(Stage::Output);
    let basis = &grid.0;
    let cells_per_axis: Vec<usize> = basis.axes.iter().map(|a| a.cells).collect();
    let lattice = lattice_cells(&cells_per_axis);
    let corners = lattice.kind.nodes_per_cell();
    let piece = pieces.as_deref();
    if piece.is_some_and(|p| !p.ready) {
        status.fail(SolverError::Output {
            step: step.number,
            why: "the grid piece's values were not gathered in this step".to_string(),
        });
        return;
    }
    // the cells and vertices written, the points per cell and each node's increment: the
    // whole lattice and this process's fields, or the piece's
    let (cells, vertices, counts): (Vec<usize>, Vec<usize>, Vec<f64>) = match piece {
        None => (
            (0..basis.num_cells()).collect(),
            (0..basis.vertex_count()).collect(),
            points_per_cell(basis, positions.iter().map(|x| &x.0)),
        ),
        Some(p) => {
            let cells: Vec<usize> = (0..basis.num_cells()).filter(|&c| p.cells[c]).collect();
            let mut vertices: Vec<usize> = (cells.iter())
                .flat_map(|&c| &lattice.connectivity[corners * c..corners * (c + 1)])
                .map(|&v| v as usize)
                .collect();
            vertices.sort_unstable();
            vertices.dedup();
            (cells, vertices, p.points_per_cell.clone())
        }
    };
    let node_increment = |node: usize| match piece {
        None => fields.increment[node],
        Some(p) => SVector::<f64, D>::from_fn(|k, _| p.increment[D * node + k]),
    };

    // The grid: vertices, cells, the step's displacement increment evaluated at the vertices.
    let coordinates: Vec<[f64; 3]> = (vertices.iter())
        .map(|&v| pad(&basis.vertex_position(v)))
        .collect();
    let mut increment = Vec::with_capacity(3 * vertices.len());
    let mut weights = Vec::new();
    for &v in &vertices {
        let du = match basis.eval(&basis.vertex_position(v), &mut scratch, &mut weights) {
            Ok(()) => interpolate(&weights, node_increment),
            Err(_) => SVector::zeros(),
        };
        increment.extend(pad(&du));
    }
    let material_points: Vec<f64> = cells.iter().map(|&c| counts[c]).collect();
    let mut point_fields = vec![Field {
        name: "displacement_increment",
        components: 3,
        values: &increment,
    }];
    let mut cell_fields = vec![Field {
        name: "material_points",
        components: 1,
        values: &material_points,
    }];
    let Some(p) = piece else {
        let grid_name = format!("grid_{:04}.vtu", step.number);
        let result = write_vtu(
            &plan.dir.join(&grid_name),
            &coordinates,
            &lattice,
            &point_fields,
            &cell_fields,
        )
        .and_then(|()| {
            plan.grid
                .push(step.series_time(stage.as_deref()), &grid_name)
        });
        if let Err(e) = result {
            status.fail(SolverError::Output {
                step: step.number,
                why: e.to_string(),
            });
        }
        return;
    };
    // a piece: its cells' corners by their place among its vertices, and the numbers of both
    // in the whole lattice
    let connectivity: Vec<u64> = (cells.iter())
        .flat_map(|&c| &lattice.connectivity[corners * c..corners * (c + 1)])
        .map(|&v| vertices.binary_search(&(v as usize)).unwrap_or(0) as u64)
        .collect();
    let vertex_ids: Vec<f64> = vertices.iter().map(|&v| v as f64).collect();
    let cell_ids: Vec<f64> = cells.iter().map(|&c| c as f64).collect();
    point_fields.push(Field::scalar(VERTEX_ID, &vertex_ids));
    cell_fields.push(Field::scalar(CELL_ID, &cell_ids));
    let name = format!("grid_{:04}_p{}.vtu", step.number, p.piece);
    let result = write_vtu(
        &p.dir.join(&name),
        &coordinates,
        &Cells {
            kind: lattice.kind,
            connectivity,
        },
        &point_fields,
        &cell_fields,
    );
    let written = written_piece(result, name, &point_fields, &cell_fields);
    if let Some(pieces) = pieces.as_deref_mut() {
        pieces.grid_written = Some(written);
    }
}

/// The control points (grid nodes) with their constraints and forces: `nodes_NNNN.vtu`, or
/// this process's piece of it ([`GridPieces`]: its nodes, with their numbers).
#[allow(clippy::too_many_arguments)]
pub fn write_nodes<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    fields: Res<GridFields<D>>,
    mut plan: ResMut<OutputPlan>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut pieces: Option<ResMut<GridPieces>>,
    nodes: Query<&GridNode<D>>,
) {
    if !plan.writes(&step) || !plan.grid_files {
        return;
    }
    let _timer = clock.time(Stage::Output);
    let piece = pieces.as_deref();
    if piece.is_some_and(|p| !p.ready) {
        status.fail(SolverError::Output {
            step: step.number,
            why: "the node piece's nodes were not chosen in this step".to_string(),
        });
        return;
    }
    let mut rows: Vec<_> = nodes
        .iter()
        .filter(|node| piece.is_none_or(|p| p.nodes.get(node.index).copied().unwrap_or(false)))
        .collect();
    rows.sort_by_key(|node| node.index);
    let node_positions: Vec<[f64; 3]> = rows.iter().map(|node| pad(&node.position)).collect();
    let mut active = Vec::with_capacity(rows.len());
    let mut fixed = Vec::with_capacity(3 * rows.len());
    let mut node_increment = Vec::with_capacity(3 * rows.len());
    let mut external = Vec::with_capacity(3 * rows.len());
    let mut internal = Vec::with_capacity(3 * rows.len());
    for node in &rows {
        let i = node.index;
        active.push(if fields.active[i] { 1.0 } else { 0.0 });
        fixed.extend(std::array::from_fn::<f64, 3, _>(|c| {
            if c < D && fields.constrained[i][c] {
                1.0
            } else {
                0.0
            }
        }));
        node_increment.extend(pad(&fields.increment[i]));
        external.extend(pad(&fields.external_force[i]));
        internal.extend(pad(&fields.internal_force[i]));
    }
    let node_ids: Vec<f64> = rows.iter().map(|node| node.index as f64).collect();
    let mut arrays = vec![
        Field::scalar("active", &active),
        Field::new("fixed", 3, &fixed),
        Field::new("displacement_increment", 3, &node_increment),
        Field::new("external_force", 3, &external),
        Field::new("internal_force", 3, &internal),
    ];
    let Some(p) = piece else {
        let nodes_name = format!("nodes_{:04}.vtu", step.number);
        let result = write_vtu(
            &plan.dir.join(&nodes_name),
            &node_positions,
            &vertex_cells(rows.len()),
            &arrays,
            &[],
        )
        .and_then(|()| {
            plan.nodes
                .push(step.series_time(stage.as_deref()), &nodes_name)
        });
        if let Err(e) = result {
            status.fail(SolverError::Output {
                step: step.number,
                why: e.to_string(),
            });
        }
        return;
    };
    arrays.push(Field::scalar(NODE_ID, &node_ids));
    let name = format!("nodes_{:04}_p{}.vtu", step.number, p.piece);
    let result = write_vtu(
        &p.dir.join(&name),
        &node_positions,
        &vertex_cells(rows.len()),
        &arrays,
        &[],
    );
    let written = written_piece(result, name, &arrays, &[]);
    if let Some(pieces) = pieces.as_deref_mut() {
        pieces.nodes_written = Some(written);
    }
}

/// A piece of a parallel file as written (`file` with these arrays), or why it could not be.
fn written_piece(
    result: std::io::Result<()>,
    file: String,
    point_fields: &[Field],
    cell_fields: &[Field],
) -> Result<WrittenPiece, String> {
    let layout = |fields: &[Field]| -> Vec<(String, usize)> {
        (fields.iter())
            .map(|f| (f.name.to_string(), f.components))
            .collect()
    };
    match result {
        Ok(()) => Ok(WrittenPiece {
            file,
            arrays: layout(point_fields),
            cell_arrays: layout(cell_fields),
        }),
        Err(e) => Err(format!("{file}: {e}")),
    }
}
