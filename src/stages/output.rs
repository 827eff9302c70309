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

use crate::basis::BasisScratch;
use crate::components::{
    AssembledElsewhere, BodyIndex, DeformationGradient, Displacement, GridNode, Mass, PointId,
    Position, ReferencePosition, ReferenceVolume, Trial, Volume,
};
use crate::mechanics::{embed, interpolate};
use crate::output::{
    Field, POINT_ID, PvdSeries, Sink, StreamedField, lattice_cells, vertex_cells, write_vtu,
    write_vtu_streamed,
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

/// A piece of the particle file, as written: its file name and its arrays `(name,
/// components)`, in file order.
#[derive(Clone, Debug, PartialEq)]
pub struct WrittenPiece {
    pub file: String,
    pub arrays: Vec<(String, usize)>,
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
            Ok(()) => Ok(WrittenPiece { file: name, arrays }),
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

/// The default grid file (`Hook::GridOutput`): the background grid.
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
    positions: Query<&Position<D>>,
) {
    if !plan.writes(&step) || !plan.grid_files {
        return;
    }
    let _timer = clock.time(Stage::Output);
    let basis = &grid.0;

    // The grid: vertices, cells, the step's displacement increment evaluated at the vertices.
    let vertices: Vec<[f64; 3]> = (0..basis.vertex_count())
        .map(|v| pad(&basis.vertex_position(v)))
        .collect();
    let mut increment = Vec::with_capacity(3 * vertices.len());
    let mut weights = Vec::new();
    for v in 0..basis.vertex_count() {
        let du = match basis.eval(&basis.vertex_position(v), &mut scratch, &mut weights) {
            Ok(()) => interpolate(&weights, |node| fields.increment[node]),
            Err(_) => SVector::zeros(),
        };
        increment.extend(pad(&du));
    }
    let mut points_per_cell = vec![0.0; basis.num_cells()];
    let cells_per_axis: Vec<usize> = basis.axes.iter().map(|a| a.cells).collect();
    for x in positions.iter() {
        if let Ok(cell) = basis.cell_of(&x.0) {
            let mut index = 0;
            for a in (0..D).rev() {
                index = index * cells_per_axis[a] + cell[a];
            }
            points_per_cell[index] += 1.0;
        }
    }
    let grid_name = format!("grid_{:04}.vtu", step.number);
    let grid_result = write_vtu(
        &plan.dir.join(&grid_name),
        &vertices,
        &lattice_cells(&cells_per_axis),
        &[Field {
            name: "displacement_increment",
            components: 3,
            values: &increment,
        }],
        &[Field {
            name: "material_points",
            components: 1,
            values: &points_per_cell,
        }],
    );
    let result = grid_result.and_then(|()| {
        plan.grid
            .push(step.series_time(stage.as_deref()), &grid_name)
    });
    if let Err(e) = result {
        status.fail(SolverError::Output {
            step: step.number,
            why: e.to_string(),
        });
    }
}

/// The control points (grid nodes) with their constraints and forces: `nodes_NNNN.vtu`.
pub fn write_nodes<const D: usize>(
    step: Res<LoadStep>,
    stage: Option<Res<CurrentStage>>,
    fields: Res<GridFields<D>>,
    mut plan: ResMut<OutputPlan>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    nodes: Query<&GridNode<D>>,
) {
    if !plan.writes(&step) || !plan.grid_files {
        return;
    }
    let _timer = clock.time(Stage::Output);
    let mut rows: Vec<_> = nodes.iter().collect();
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
    let nodes_name = format!("nodes_{:04}.vtu", step.number);
    let nodes_result = write_vtu(
        &plan.dir.join(&nodes_name),
        &node_positions,
        &vertex_cells(rows.len()),
        &[
            Field {
                name: "active",
                components: 1,
                values: &active,
            },
            Field {
                name: "fixed",
                components: 3,
                values: &fixed,
            },
            Field {
                name: "displacement_increment",
                components: 3,
                values: &node_increment,
            },
            Field {
                name: "external_force",
                components: 3,
                values: &external,
            },
            Field {
                name: "internal_force",
                components: 3,
                values: &internal,
            },
        ],
        &[],
    );
    let result = nodes_result.and_then(|()| {
        plan.nodes
            .push(step.series_time(stage.as_deref()), &nodes_name)
    });
    if let Err(e) = result {
        status.fail(SolverError::Output {
            step: step.number,
            why: e.to_string(),
        });
    }
}
