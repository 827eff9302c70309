//! XML UnstructuredGrid (`.vtu`) files: writing with validation, cell helpers, reading back.

use std::io::{self, BufReader};
use std::path::Path;

use vtkio::model::{
    Attribute, Attributes, ByteOrder, CellType, DataSet, UnstructuredGridPiece, Version,
    VertexNumbers, Vtk,
};
use vtkio::xml::Compressor;

use super::atomic::write_atomic_with;

/// A named array of point or cell data: `values.len() == components * count`, where `count` is
/// the number of points (point data) or cells (cell data). Values of one point (cell) are
/// contiguous: a 3x3 tensor is 9 components in row-major order, a vector 3 components.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Field<'a> {
    /// Array name shown in ParaView; must be non-empty and unique among the point (cell) data.
    pub name: &'a str,
    /// Number of components per point (cell), at least 1.
    pub components: usize,
    /// `components * count` values, point (cell) major.
    pub values: &'a [f64],
}

impl<'a> Field<'a> {
    /// A field with `components` values per point (cell).
    pub fn new(name: &'a str, components: usize, values: &'a [f64]) -> Self {
        Field {
            name,
            components,
            values,
        }
    }

    /// A one-component field.
    pub fn scalar(name: &'a str, values: &'a [f64]) -> Self {
        Field::new(name, 1, values)
    }
}

/// The cell types this module writes (all cells of one file are of one kind).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CellKind {
    /// `VTK_VERTEX` (1 node): one per material point.
    Vertex,
    /// `VTK_LINE` (2 nodes): 1D grid cells.
    Line,
    /// `VTK_QUAD` (4 nodes, counter-clockwise): 2D grid cells.
    Quad,
    /// `VTK_HEXAHEDRON` (8 nodes: bottom face counter-clockwise, then the top face): 3D grid cells.
    Hexahedron,
}

impl CellKind {
    /// Number of nodes of one cell.
    pub fn nodes_per_cell(self) -> usize {
        match self {
            CellKind::Vertex => 1,
            CellKind::Line => 2,
            CellKind::Quad => 4,
            CellKind::Hexahedron => 8,
        }
    }

    /// The VTK cell type id (1, 3, 9, 12).
    pub fn vtk_type(self) -> u8 {
        self.cell_type() as u8
    }

    /// The kind of a VTK cell type id, if it is one of these.
    pub fn from_vtk_type(id: u8) -> Option<Self> {
        [
            CellKind::Vertex,
            CellKind::Line,
            CellKind::Quad,
            CellKind::Hexahedron,
        ]
        .into_iter()
        .find(|kind| kind.vtk_type() == id)
    }

    fn cell_type(self) -> CellType {
        match self {
            CellKind::Vertex => CellType::Vertex,
            CellKind::Line => CellType::Line,
            CellKind::Quad => CellType::Quad,
            CellKind::Hexahedron => CellType::Hexahedron,
        }
    }
}

/// Cells of one kind: `connectivity` lists `kind.nodes_per_cell()` point indices per cell, in VTK
/// node ordering.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cells {
    pub kind: CellKind,
    pub connectivity: Vec<u64>,
}

impl Cells {
    /// Number of complete cells in `connectivity`.
    pub fn count(&self) -> usize {
        self.connectivity.len() / self.kind.nodes_per_cell()
    }
}

/// One `VTK_VERTEX` cell per point (for material points): cell `i` is point `i`.
pub fn vertex_cells(count: usize) -> Cells {
    Cells {
        kind: CellKind::Vertex,
        connectivity: (0..count as u64).collect(),
    }
}

/// Cells of a structured lattice with `cells[a]` cells along axis `a` (1 to 3 axes), whose
/// `prod(cells[a] + 1)` vertices are numbered axis-0 fastest
/// (vertex `(i, j, k)` is `i + (n0 + 1) * (j + (n1 + 1) * k)`), cells also numbered axis-0
/// fastest: `VTK_LINE` in 1D, `VTK_QUAD` (counter-clockwise) in 2D, `VTK_HEXAHEDRON` in 3D.
///
/// Never panics: for an invalid `cells` (no entries, more than 3, or a lattice whose size
/// overflows) it returns an empty set of vertex cells; use [`try_lattice_cells`] to get an error
/// instead.
pub fn lattice_cells(cells: &[usize]) -> Cells {
    try_lattice_cells(cells).unwrap_or(Cells {
        kind: CellKind::Vertex,
        connectivity: Vec::new(),
    })
}

/// [`lattice_cells`] with an `InvalidInput` error for a `cells` slice without 1 to 3 entries or
/// a lattice too large to index.
pub fn try_lattice_cells(cells: &[usize]) -> io::Result<Cells> {
    let too_large = || invalid(format!("lattice of {cells:?} cells is too large to index"));
    let (kind, n) = match *cells {
        [a] => (CellKind::Line, [a, 0, 0]),
        [a, b] => (CellKind::Quad, [a, b, 0]),
        [a, b, c] => (CellKind::Hexahedron, [a, b, c]),
        _ => {
            return Err(invalid(format!(
                "a lattice has 1 to 3 axes, got {} ({cells:?})",
                cells.len()
            )));
        }
    };
    // Vertex counts per axis and the total number of vertices and connectivity entries.
    let mut vertex_total: usize = 1;
    let mut cell_total: usize = 1;
    for &c in cells {
        vertex_total = vertex_total
            .checked_mul(c.checked_add(1).ok_or_else(too_large)?)
            .ok_or_else(too_large)?;
        cell_total = cell_total.checked_mul(c).ok_or_else(too_large)?;
    }
    let entries = cell_total
        .checked_mul(kind.nodes_per_cell())
        .ok_or_else(too_large)?;
    if u64::try_from(vertex_total).is_err() {
        return Err(too_large());
    }
    let sx = n[0] as u64 + 1;
    let sy = n[1] as u64 + 1;
    let v = |i: usize, j: usize, k: usize| i as u64 + sx * (j as u64 + sy * k as u64);
    let mut connectivity = Vec::with_capacity(entries);
    match kind {
        CellKind::Line => connectivity.extend((0..n[0]).flat_map(|i| [v(i, 0, 0), v(i + 1, 0, 0)])),
        CellKind::Quad => {
            for j in 0..n[1] {
                for i in 0..n[0] {
                    connectivity.extend([
                        v(i, j, 0),
                        v(i + 1, j, 0),
                        v(i + 1, j + 1, 0),
                        v(i, j + 1, 0),
                    ]);
                }
            }
        }
        CellKind::Hexahedron => {
            for k in 0..n[2] {
                for j in 0..n[1] {
                    for i in 0..n[0] {
                        connectivity.extend([
                            v(i, j, k),
                            v(i + 1, j, k),
                            v(i + 1, j + 1, k),
                            v(i, j + 1, k),
                            v(i, j, k + 1),
                            v(i + 1, j, k + 1),
                            v(i + 1, j + 1, k + 1),
                            v(i, j + 1, k + 1),
                        ]);
                    }
                }
            }
        }
        CellKind::Vertex => {}
    }
    Ok(Cells { kind, connectivity })
}

/// Pads flat `dim`-dimensional coordinates (`coords.len() == dim * count`, `dim` in 1..=3) to 3D
/// points with zeros.
pub fn pad_points(coords: &[f64], dim: usize) -> io::Result<Vec<[f64; 3]>> {
    if !(1..=3).contains(&dim) {
        return Err(invalid(format!(
            "point dimension must be 1, 2 or 3, got {dim}"
        )));
    }
    if !coords.len().is_multiple_of(dim) {
        return Err(invalid(format!(
            "{} coordinates are not a whole number of {dim}D points",
            coords.len()
        )));
    }
    Ok(coords
        .chunks_exact(dim)
        .map(|c| {
            let mut p = [0.0; 3];
            p[..dim].copy_from_slice(c);
            p
        })
        .collect())
}

/// How the binary data of a `.vtu` file are encoded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Encoding {
    /// Uncompressed raw binary appended data (the default: fastest to write and to read).
    #[default]
    AppendedRaw,
    /// Uncompressed inline base64 through `vtkio` (what impm wrote before; kept as the
    /// baseline of the output benchmark).
    InlineBase64,
    /// Inline base64 with `vtkZLibDataCompressor` at the given level (1 fastest .. 9 smallest;
    /// clamped to 1..=9), through `vtkio`.
    Zlib { level: u32 },
}

/// Writes an XML UnstructuredGrid `.vtu` file atomically, as raw appended data (see the module
/// docs):
/// `points` (3D), `cells`, and Float64 point and cell data arrays.
///
/// Returns an `InvalidInput` error, writing nothing, if a field's length is not
/// `components * count`, a name is empty or repeated, a cell refers to a missing point, or any
/// coordinate or value is NaN or infinite (the message names the field and the index).
pub fn write_vtu(
    path: &Path,
    points: &[[f64; 3]],
    cells: &Cells,
    point_data: &[Field],
    cell_data: &[Field],
) -> io::Result<()> {
    write_vtu_with(
        path,
        points,
        cells,
        point_data,
        cell_data,
        Encoding::AppendedRaw,
    )
}

/// Values produced on demand for [`write_vtu_streamed`]: called once while the file is
/// written, it passes every value of its array, in order, to the sink in runs of any length,
/// and returns the sink's first error as it is.
pub type Stream<'a> = &'a dyn Fn(&mut Sink) -> io::Result<()>;

/// Where a [`Stream`] passes its values.
pub type Sink<'s> = dyn FnMut(&[f64]) -> io::Result<()> + 's;

/// A point data array produced on demand ([`Stream`]): `components` values per point.
#[derive(Clone, Copy)]
pub struct StreamedField<'a> {
    pub name: &'a str,
    pub components: usize,
    pub values: Stream<'a>,
}

/// [`write_vtu`] (raw appended data) for `point_count` points whose coordinates (3 per point)
/// and point data are produced on demand, array after array, so that no array is held whole
/// in memory: the file is byte for byte the one [`write_vtu`] writes from the same values.
///
/// The names, component counts and cells are checked before anything is written; the values
/// as they are produced: a NaN or infinity (named with its index, as in [`write_vtu`]) or a
/// source that produces more or fewer values than `components * point_count` is an
/// `InvalidInput` error, and the file is not written (the partial file is discarded).
pub fn write_vtu_streamed(
    path: &Path,
    point_count: usize,
    points: Stream,
    cells: &Cells,
    point_data: &[StreamedField],
) -> io::Result<()> {
    validate_cells(cells, point_count)?;
    for (n, f) in point_data.iter().enumerate() {
        let earlier = point_data[..n].iter().map(|g| g.name);
        validate_declaration("point", n, f.name, f.components, earlier)?;
    }
    let coordinates = |sink: &mut Sink| {
        checked(points, 3 * point_count, "the coordinates", sink, |i, x| {
            format!(
                "point {} has a non-finite coordinate {x} (axis {})",
                i / 3,
                i % 3
            )
        })
    };
    let sources: Vec<_> = point_data
        .iter()
        .map(|f| {
            move |sink: &mut Sink| {
                let what = format!("point data field {:?}", f.name);
                checked(f.values, f.components * point_count, &what, sink, |i, x| {
                    non_finite_message("point", f.name, f.components, i, x)
                })
            }
        })
        .collect();
    let arrays: Vec<(&str, usize, Stream)> = point_data
        .iter()
        .zip(&sources)
        .map(|(f, source)| (f.name, f.components, source as Stream))
        .collect();
    write_atomic_with(path, |w| {
        super::appended::write_appended_streamed(w, point_count, &coordinates, cells, &arrays)
    })
}

/// Passes `values` on to `sink`, checking that they are finite (`non_finite(index, value)`
/// names the first that is not) and that there are exactly `expected` of them.
fn checked(
    values: Stream,
    expected: usize,
    what: &str,
    sink: &mut Sink,
    non_finite: impl Fn(usize, f64) -> String,
) -> io::Result<()> {
    let mut at = 0usize;
    values(&mut |run: &[f64]| {
        if run.len() > expected - at {
            return Err(invalid(format!(
                "{what} produced more than the {expected} values expected"
            )));
        }
        if let Some(i) = run.iter().position(|x| !x.is_finite()) {
            return Err(invalid(non_finite(at + i, run[i])));
        }
        at += run.len();
        sink(run)
    })?;
    if at != expected {
        return Err(invalid(format!(
            "{what} produced {at} values, expected {expected}"
        )));
    }
    Ok(())
}

/// [`write_vtu`] with a choice of [`Encoding`].
pub fn write_vtu_with(
    path: &Path,
    points: &[[f64; 3]],
    cells: &Cells,
    point_data: &[Field],
    cell_data: &[Field],
    encoding: Encoding,
) -> io::Result<()> {
    validate(points, cells, point_data, cell_data)?;
    if encoding == Encoding::AppendedRaw {
        return write_atomic_with(path, |w| {
            super::appended::write_appended(w, points, cells, point_data, cell_data)
        });
    }

    let cell_count = cells.count();
    let nodes = cells.kind.nodes_per_cell() as u64;
    let attributes = |fields: &[Field]| -> Vec<Attribute> {
        fields
            .iter()
            .map(|f| {
                // `components` was validated to fit (it divides a slice length, and > 0).
                Attribute::generic(f.name, f.components as u32).with_data(f.values.to_vec())
            })
            .collect()
    };
    let vtk = Vtk {
        version: Version::Auto,
        title: String::new(),
        byte_order: ByteOrder::LittleEndian,
        file_path: None,
        data: DataSet::inline(UnstructuredGridPiece {
            points: points
                .iter()
                .flatten()
                .copied()
                .collect::<Vec<f64>>()
                .into(),
            cells: vtkio::model::Cells {
                cell_verts: VertexNumbers::XML {
                    connectivity: cells.connectivity.clone(),
                    offsets: (1..=cell_count as u64).map(|c| c * nodes).collect(),
                },
                types: vec![cells.kind.cell_type(); cell_count],
            },
            data: Attributes {
                point: attributes(point_data),
                cell: attributes(cell_data),
            },
        }),
    };
    let (compressor, level) = match encoding {
        Encoding::AppendedRaw | Encoding::InlineBase64 => (Compressor::None, 0),
        Encoding::Zlib { level } => (Compressor::ZLib, level.clamp(1, 9)),
    };
    let file = vtk
        .try_into_xml_format(compressor, level)
        .map_err(|e| io::Error::other(format!("vtkio could not encode {}: {e}", path.display())))?;
    write_atomic_with(path, |w| {
        // vtkio reports a failed write as a formatting error: keep the real one (a full disk)
        let mut writer = KeepingError {
            inner: w,
            error: None,
        };
        file.write(&mut writer).map_err(|e| {
            writer
                .error
                .take()
                .unwrap_or_else(|| io::Error::other(format!("vtkio: {e}")))
        })
    })
}

/// A writer that keeps the first error of the writer it wraps.
struct KeepingError<'a, W: io::Write> {
    inner: &'a mut W,
    error: Option<io::Error>,
}

impl<W: io::Write> io::Write for KeepingError<'_, W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.inner.write(buf).inspect_err(|e| {
            if self.error.is_none() {
                self.error = Some(io::Error::new(e.kind(), e.to_string()));
            }
        })
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// Checks everything [`write_vtu`] promises to reject.
fn validate(
    points: &[[f64; 3]],
    cells: &Cells,
    point_data: &[Field],
    cell_data: &[Field],
) -> io::Result<()> {
    for (p, xyz) in points.iter().enumerate() {
        if let Some(axis) = xyz.iter().position(|x| !x.is_finite()) {
            return Err(invalid(format!(
                "point {p} has a non-finite coordinate {} (axis {axis}): {xyz:?}",
                xyz[axis]
            )));
        }
    }
    validate_cells(cells, points.len())?;
    validate_fields("point", points.len(), point_data)?;
    validate_fields("cell", cells.count(), cell_data)
}

/// The connectivity: whole cells, every entry one of the `point_count` points.
fn validate_cells(cells: &Cells, point_count: usize) -> io::Result<()> {
    let nodes = cells.kind.nodes_per_cell();
    if !cells.connectivity.len().is_multiple_of(nodes) {
        return Err(invalid(format!(
            "{:?} cells have {nodes} nodes each, but the connectivity has {} entries",
            cells.kind,
            cells.connectivity.len()
        )));
    }
    if let Some((i, &node)) = cells
        .connectivity
        .iter()
        .enumerate()
        .find(|&(_, &node)| node >= point_count as u64)
    {
        return Err(invalid(format!(
            "connectivity entry {i} (cell {}) refers to point {node}, but there are only {point_count} points",
            i / nodes,
        )));
    }
    Ok(())
}

/// Field `n`'s name (non-empty, not one of the `earlier` names) and component count.
fn validate_declaration<'a>(
    what: &str,
    n: usize,
    name: &str,
    components: usize,
    mut earlier: impl Iterator<Item = &'a str>,
) -> io::Result<()> {
    if name.is_empty() {
        return Err(invalid(format!("{what} data field #{n} has an empty name")));
    }
    if earlier.any(|g| g == name) {
        return Err(invalid(format!(
            "{what} data field {name:?} appears more than once"
        )));
    }
    if components == 0 || u32::try_from(components).is_err() {
        return Err(invalid(format!(
            "{what} data field {name:?} has an invalid component count {components}"
        )));
    }
    Ok(())
}

/// The message for a NaN or infinite `value` at index `i` of a field.
fn non_finite_message(what: &str, name: &str, components: usize, i: usize, value: f64) -> String {
    format!(
        "{what} data field {name:?} has a non-finite value {value} at index {i} ({what} {}, component {})",
        i / components,
        i % components
    )
}

fn validate_fields(what: &str, count: usize, fields: &[Field]) -> io::Result<()> {
    for (n, f) in fields.iter().enumerate() {
        let earlier = fields[..n].iter().map(|g| g.name);
        validate_declaration(what, n, f.name, f.components, earlier)?;
        if f.components.checked_mul(count) != Some(f.values.len()) {
            return Err(invalid(format!(
                "{what} data field {:?} has {} values, expected {} components x {count} {what}s = {}",
                f.name,
                f.values.len(),
                f.components,
                f.components.saturating_mul(count)
            )));
        }
        if let Some(i) = f.values.iter().position(|x| !x.is_finite()) {
            let message = non_finite_message(what, f.name, f.components, i, f.values[i]);
            return Err(invalid(message));
        }
    }
    Ok(())
}

fn invalid(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

fn invalid_data(path: &Path, message: impl std::fmt::Display) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("reading {}: {message}", path.display()),
    )
}

/// What [`read_vtu`] returns: the contents of a one-piece `.vtu` file as `f64`.
#[derive(Clone, Debug, PartialEq)]
pub struct VtuContents {
    /// Point coordinates.
    pub points: Vec<[f64; 3]>,
    /// Point data arrays: `(name, components, values)`, in file order.
    pub point_data: Vec<(String, usize, Vec<f64>)>,
    /// Cell data arrays: `(name, components, values)`, in file order.
    pub cell_data: Vec<(String, usize, Vec<f64>)>,
    /// Number of cells.
    pub cell_count: usize,
    /// VTK cell type id of each cell (see [`CellKind::vtk_type`]).
    pub cell_types: Vec<u8>,
    /// Point indices of all cells, concatenated.
    pub connectivity: Vec<u64>,
    /// End of each cell in `connectivity` (as in the VTK XML format).
    pub offsets: Vec<u64>,
}

impl VtuContents {
    /// The point data array called `name`: `(components, values)`.
    pub fn point_field(&self, name: &str) -> Option<(usize, &[f64])> {
        find(&self.point_data, name)
    }

    /// The cell data array called `name`: `(components, values)`.
    pub fn cell_field(&self, name: &str) -> Option<(usize, &[f64])> {
        find(&self.cell_data, name)
    }
}

fn find<'a>(arrays: &'a [(String, usize, Vec<f64>)], name: &str) -> Option<(usize, &'a [f64])> {
    arrays
        .iter()
        .find(|(n, _, _)| n == name)
        .map(|(_, c, v)| (*c, v.as_slice()))
}

/// Reads a one-piece XML UnstructuredGrid file (as written by [`write_vtu`], compressed or not)
/// back as `f64`: for tests and tools. A malformed file gives an `InvalidData` error.
pub fn read_vtu(path: &Path) -> io::Result<VtuContents> {
    let bytes = std::fs::read(path)
        .map_err(|e| io::Error::new(e.kind(), format!("opening {}: {e}", path.display())))?;
    // vtkio 0.7 cannot read raw appended data (the default encoding): those files are read here.
    if let Some(start) = super::appended::raw_appended_start(&bytes) {
        return super::appended::read_appended(&bytes, start).map_err(|e| invalid_data(path, e));
    }
    // vtkio can panic on some malformed inputs (e.g. truncated base64 headers): report it as an
    // error rather than taking the caller down.
    let parsed = std::panic::catch_unwind(move || {
        let vtk = Vtk::parse_xml(BufReader::new(bytes.as_slice())).map_err(|e| e.to_string())?;
        let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
            return Err("not an UnstructuredGrid file".to_string());
        };
        let count = pieces.len();
        let [piece] = <[_; 1]>::try_from(pieces)
            .map_err(|_| format!("expected exactly one piece, found {count}"))?;
        piece
            .into_loaded_piece_data(None)
            .map_err(|e| e.to_string())
    })
    .map_err(|_| invalid_data(path, "vtkio panicked while parsing the file"))?
    .map_err(|e| invalid_data(path, e))?;

    let coords: Vec<f64> = parsed
        .points
        .cast_into()
        .ok_or_else(|| invalid_data(path, "point coordinates are not numeric"))?;
    if !coords.len().is_multiple_of(3) {
        return Err(invalid_data(path, "point coordinates are not 3D"));
    }
    let points = coords.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let arrays = |attributes: Vec<Attribute>| -> io::Result<Vec<(String, usize, Vec<f64>)>> {
        attributes
            .into_iter()
            .filter_map(|a| match a {
                Attribute::DataArray(d) => Some(d),
                Attribute::Field { .. } => None,
            })
            .map(|d| {
                let values = d.data.cast_into::<f64>().ok_or_else(|| {
                    invalid_data(path, format!("array {:?} is not numeric", d.name))
                })?;
                Ok((d.name, d.elem.num_comp() as usize, values))
            })
            .collect()
    };
    let cell_count = parsed.cells.num_cells();
    let cell_types = parsed.cells.types.iter().map(|&t| t as u8).collect();
    let (connectivity, offsets) = parsed.cells.cell_verts.into_xml();
    Ok(VtuContents {
        points,
        point_data: arrays(parsed.data.point)?,
        cell_data: arrays(parsed.data.cell)?,
        cell_count,
        cell_types,
        connectivity,
        offsets,
    })
}

#[cfg(test)]
mod tests {
    use super::super::atomic::test_dir::TestDir;
    use super::*;

    /// Deterministic, distinct test values.
    fn ramp(len: usize, scale: f64) -> Vec<f64> {
        (0..len).map(|i| scale * (i as f64 + 0.25) - 1.0).collect()
    }

    /// Vertices of a unit-spaced lattice, axis-0 fastest (as `lattice_cells` numbers them).
    fn lattice_points(cells: &[usize]) -> Vec<[f64; 3]> {
        let mut n = [1usize; 3];
        for (a, &c) in cells.iter().enumerate() {
            n[a] = c + 1;
        }
        let mut pts = Vec::new();
        for k in 0..n[2] {
            for j in 0..n[1] {
                for i in 0..n[0] {
                    pts.push([i as f64, j as f64 * 0.5, k as f64 * 0.25]);
                }
            }
        }
        pts
    }

    fn round_trip(label: &str, points: &[[f64; 3]], cells: &Cells, encoding: Encoding) {
        let dir = TestDir::new(label);
        let path = dir.path().join(format!("{label}_0000.vtu"));
        let np = points.len();
        let nc = cells.count();
        let density = ramp(np, 0.5);
        let stress = ramp(9 * np, -1.5e6);
        let velocity = ramp(3 * np, 1e-9);
        let volume = ramp(nc, 3.0);
        let cell_tensor = ramp(9 * nc, 7.0);
        let point_data = [
            Field::scalar("density", &density),
            Field::new("cauchy_stress", 9, &stress),
            Field::new("velocity", 3, &velocity),
        ];
        let cell_data = [
            Field::scalar("volume", &volume),
            Field::new("cell_tensor", 9, &cell_tensor),
        ];
        write_vtu_with(&path, points, cells, &point_data, &cell_data, encoding).unwrap();
        assert_eq!(dir.file_names(), vec![format!("{label}_0000.vtu")]);

        let back = read_vtu(&path).unwrap();
        assert_eq!(back.points, points);
        assert_eq!(back.cell_count, nc);
        assert_eq!(back.cell_types, vec![cells.kind.vtk_type(); nc]);
        assert_eq!(back.connectivity, cells.connectivity);
        let nodes = cells.kind.nodes_per_cell() as u64;
        assert_eq!(
            back.offsets,
            (1..=nc as u64).map(|c| c * nodes).collect::<Vec<_>>()
        );
        let names: Vec<&str> = back.point_data.iter().map(|a| a.0.as_str()).collect();
        assert_eq!(names, ["density", "cauchy_stress", "velocity"]);
        for f in &point_data {
            assert_eq!(
                back.point_field(f.name),
                Some((f.components, f.values)),
                "{}",
                f.name
            );
        }
        for f in &cell_data {
            assert_eq!(
                back.cell_field(f.name),
                Some((f.components, f.values)),
                "{}",
                f.name
            );
        }
    }

    #[test]
    fn vertex_cells_round_trip() {
        let points: Vec<[f64; 3]> = (0..10)
            .map(|i| {
                [
                    i as f64 * 0.1,
                    (i * i) as f64 * 1e-3,
                    -1.0 / (i as f64 + 1.0),
                ]
            })
            .collect();
        let cells = vertex_cells(points.len());
        assert_eq!(cells.count(), 10);
        round_trip("vertex", &points, &cells, Encoding::AppendedRaw);
        round_trip("vertex-base64", &points, &cells, Encoding::InlineBase64);
        round_trip("vertex-zlib", &points, &cells, Encoding::Zlib { level: 1 });
    }

    #[test]
    fn line_cells_round_trip() {
        let cells = lattice_cells(&[4]);
        assert_eq!(cells.kind, CellKind::Line);
        assert_eq!(cells.connectivity, [0, 1, 1, 2, 2, 3, 3, 4]);
        round_trip("line", &lattice_points(&[4]), &cells, Encoding::AppendedRaw);
    }

    #[test]
    fn quad_cells_round_trip() {
        let cells = lattice_cells(&[3, 2]);
        assert_eq!(cells.kind, CellKind::Quad);
        assert_eq!(cells.count(), 6);
        // First cell counter-clockwise from (0,0); second cell along axis 0; first of row 2.
        assert_eq!(&cells.connectivity[..8], &[0, 1, 5, 4, 1, 2, 6, 5]);
        assert_eq!(&cells.connectivity[12..16], &[4, 5, 9, 8]);
        round_trip(
            "quad",
            &lattice_points(&[3, 2]),
            &cells,
            Encoding::AppendedRaw,
        );
        round_trip(
            "quad-zlib",
            &lattice_points(&[3, 2]),
            &cells,
            Encoding::Zlib { level: 6 },
        );
    }

    #[test]
    fn quads_are_counter_clockwise() {
        let points = lattice_points(&[3, 2]);
        let cells = lattice_cells(&[3, 2]);
        for quad in cells.connectivity.chunks_exact(4) {
            let p: Vec<[f64; 3]> = quad.iter().map(|&i| points[i as usize]).collect();
            // Shoelace formula: positive signed area = counter-clockwise.
            let area: f64 = (0..4)
                .map(|a| {
                    let b = (a + 1) % 4;
                    p[a][0] * p[b][1] - p[b][0] * p[a][1]
                })
                .sum();
            assert!(area > 0.0, "{quad:?} is not counter-clockwise");
        }
    }

    #[test]
    fn hexahedron_cells_round_trip() {
        let dims = [2, 3, 2];
        let cells = lattice_cells(&dims);
        assert_eq!(cells.kind, CellKind::Hexahedron);
        assert_eq!(cells.count(), 12);
        // Vertices per axis 3, 4, 3: the first hexahedron.
        assert_eq!(&cells.connectivity[..8], &[0, 1, 4, 3, 12, 13, 16, 15]);
        let points = lattice_points(&dims);
        // Every hexahedron has positive volume with VTK's ordering: the bottom face (0,1,2,3)
        // counter-clockwise seen from the top (node 4 side).
        for hex in cells.connectivity.chunks_exact(8) {
            let p = |n: usize| points[hex[n] as usize];
            let d = |a: [f64; 3], b: [f64; 3]| [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let (u, v, w) = (d(p(0), p(1)), d(p(0), p(3)), d(p(0), p(4)));
            let triple = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
                + u[2] * (v[0] * w[1] - v[1] * w[0]);
            assert!(triple > 0.0, "{hex:?} is inverted");
        }
        round_trip("hexahedron", &points, &cells, Encoding::AppendedRaw);
    }

    #[test]
    fn empty_data_set_round_trips() {
        let dir = TestDir::new("empty");
        let path = dir.path().join("particles_0000.vtu");
        write_vtu(
            &path,
            &[],
            &vertex_cells(0),
            &[Field::new("cauchy_stress", 9, &[])],
            &[],
        )
        .unwrap();
        let back = read_vtu(&path).unwrap();
        assert!(back.points.is_empty());
        assert_eq!(back.cell_count, 0);
        assert_eq!(back.point_field("cauchy_stress"), Some((9, &[][..])));
    }

    #[test]
    fn names_with_xml_special_characters_round_trip() {
        let dir = TestDir::new("names");
        let path = dir.path().join("names.vtu");
        let values = [1.0, 2.0];
        let name = "sigma <yy> & \"quoted\" 'x'";
        write_vtu(
            &path,
            &[[0.0; 3], [1.0, 0.0, 0.0]],
            &vertex_cells(2),
            &[Field::scalar(name, &values)],
            &[],
        )
        .unwrap();
        let back = read_vtu(&path).unwrap();
        assert_eq!(back.point_field(name), Some((1, &values[..])));
    }

    #[test]
    fn replaces_an_existing_file() {
        let dir = TestDir::new("replace");
        let path = dir.path().join("p.vtu");
        let points = [[0.0; 3], [1.0, 2.0, 3.0]];
        write_vtu(
            &path,
            &points,
            &vertex_cells(2),
            &[Field::scalar("a", &[1.0, 2.0])],
            &[],
        )
        .unwrap();
        write_vtu(
            &path,
            &points,
            &vertex_cells(2),
            &[Field::scalar("a", &[3.0, 4.0])],
            &[],
        )
        .unwrap();
        assert_eq!(
            read_vtu(&path).unwrap().point_field("a"),
            Some((1, &[3.0, 4.0][..]))
        );
        assert_eq!(dir.file_names(), vec!["p.vtu".to_string()]);
    }

    /// Writes with `point_data`/`cell_data` over 3 points / 3 vertex cells and expects an
    /// `InvalidInput` error whose message contains every string of `expect`, and no file.
    fn expect_rejected(
        points: &[[f64; 3]],
        cells: &Cells,
        point_data: &[Field],
        cell_data: &[Field],
        expect: &[&str],
    ) {
        let dir = TestDir::new("reject");
        let path = dir.path().join("bad.vtu");
        let err = write_vtu(&path, points, cells, point_data, cell_data).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput, "{err}");
        let msg = err.to_string();
        for e in expect {
            assert!(msg.contains(e), "message {msg:?} lacks {e:?}");
        }
        assert!(
            dir.file_names().is_empty(),
            "left files behind: {:?}",
            dir.file_names()
        );
    }

    const THREE: [[f64; 3]; 3] = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

    /// A stream of `values` in runs of `run` values (not whole points).
    fn in_runs(values: &[f64], run: usize) -> impl Fn(&mut Sink) -> io::Result<()> + '_ {
        move |sink| values.chunks(run).try_for_each(sink)
    }

    #[test]
    fn streamed_arrays_write_the_same_bytes_and_are_checked() {
        let dir = TestDir::new("streamed");
        let (whole, streamed) = (
            dir.path().join("whole.vtu"),
            dir.path().join("streamed.vtu"),
        );
        let stress = ramp(27, 0.37);
        let mass = ramp(3, 1.5);
        let fields = [
            Field::new("cauchy_stress", 9, &stress),
            Field::scalar("mass", &mass),
        ];
        write_vtu(&whole, &THREE, &vertex_cells(3), &fields, &[]).unwrap();
        let coordinates: Vec<f64> = THREE.iter().flatten().copied().collect();
        let (xyz, s, m) = (
            in_runs(&coordinates, 4),
            in_runs(&stress, 5),
            in_runs(&mass, 1),
        );
        let streams = [
            StreamedField {
                name: "cauchy_stress",
                components: 9,
                values: &s,
            },
            StreamedField {
                name: "mass",
                components: 1,
                values: &m,
            },
        ];
        write_vtu_streamed(&streamed, 3, &xyz, &vertex_cells(3), &streams).unwrap();
        assert_eq!(
            std::fs::read(&whole).unwrap(),
            std::fs::read(&streamed).unwrap()
        );

        let bad = dir.path().join("bad.vtu");
        let mut nan = stress.clone();
        nan[13] = f64::NAN;
        let n = in_runs(&nan, 5);
        let short = in_runs(&mass[..2], 1);
        let cases: [(StreamedField, &[&str]); 2] = [
            (
                StreamedField {
                    name: "cauchy_stress",
                    components: 9,
                    values: &n,
                },
                &["cauchy_stress", "NaN", "index 13", "point 1, component 4"],
            ),
            (
                StreamedField {
                    name: "mass",
                    components: 1,
                    values: &short,
                },
                &["\"mass\"", "produced 2 values, expected 3"],
            ),
        ];
        for (field, expect) in cases {
            let err = write_vtu_streamed(&bad, 3, &xyz, &vertex_cells(3), &[field]).unwrap_err();
            assert_eq!(err.kind(), io::ErrorKind::InvalidInput, "{err}");
            for e in expect {
                assert!(err.to_string().contains(e), "{err} lacks {e:?}");
            }
            assert!(!bad.exists());
        }
        let mut names = dir.file_names();
        names.sort();
        assert_eq!(names, ["streamed.vtu", "whole.vtu"]);
    }

    #[test]
    fn wrong_point_field_length_is_rejected() {
        let nine = [0.0; 26];
        expect_rejected(
            &THREE,
            &vertex_cells(3),
            &[Field::new("cauchy_stress", 9, &nine)],
            &[],
            &["cauchy_stress", "26 values", "9 components x 3 points = 27"],
        );
    }

    #[test]
    fn wrong_cell_field_length_is_rejected() {
        expect_rejected(
            &THREE,
            &vertex_cells(3),
            &[],
            &[Field::scalar("volume", &[1.0; 4])],
            &["cell data field \"volume\"", "4 values"],
        );
    }

    #[test]
    fn nan_in_point_field_is_rejected_with_its_index() {
        let mut stress = [0.5; 27];
        stress[13] = f64::NAN;
        expect_rejected(
            &THREE,
            &vertex_cells(3),
            &[Field::new("cauchy_stress", 9, &stress)],
            &[],
            &["cauchy_stress", "NaN", "index 13", "point 1, component 4"],
        );
    }

    #[test]
    fn infinity_in_cell_field_is_rejected() {
        expect_rejected(
            &THREE,
            &vertex_cells(3),
            &[],
            &[Field::scalar("volume", &[1.0, f64::INFINITY, 1.0])],
            &["volume", "inf", "index 1"],
        );
    }

    #[test]
    fn nan_coordinate_is_rejected() {
        let mut points = THREE;
        points[2][1] = f64::NAN;
        expect_rejected(
            &points,
            &vertex_cells(3),
            &[],
            &[],
            &["point 2", "NaN", "axis 1"],
        );
    }

    #[test]
    fn bad_cells_are_rejected() {
        expect_rejected(
            &THREE,
            &vertex_cells(4),
            &[],
            &[],
            &["refers to point 3", "only 3 points"],
        );
        let partial = Cells {
            kind: CellKind::Quad,
            connectivity: vec![0, 1, 2],
        };
        expect_rejected(&THREE, &partial, &[], &[], &["4 nodes each", "3 entries"]);
    }

    #[test]
    fn bad_names_and_components_are_rejected() {
        let v = [1.0; 3];
        expect_rejected(
            &THREE,
            &vertex_cells(3),
            &[Field::scalar("", &v)],
            &[],
            &["empty name"],
        );
        expect_rejected(
            &THREE,
            &vertex_cells(3),
            &[Field::scalar("a", &v), Field::scalar("a", &v)],
            &[],
            &["\"a\" appears more than once"],
        );
        expect_rejected(
            &THREE,
            &vertex_cells(3),
            &[Field::new("z", 0, &[])],
            &[],
            &["component count 0"],
        );
    }

    #[test]
    fn lattice_cells_of_invalid_shapes_do_not_panic() {
        assert_eq!(lattice_cells(&[]).connectivity, Vec::<u64>::new());
        assert_eq!(lattice_cells(&[1, 1, 1, 1]).connectivity, Vec::<u64>::new());
        assert_eq!(
            lattice_cells(&[usize::MAX, 2]).connectivity,
            Vec::<u64>::new()
        );
        assert!(try_lattice_cells(&[]).is_err());
        assert!(
            try_lattice_cells(&[1, 2, 3, 4])
                .unwrap_err()
                .to_string()
                .contains("1 to 3 axes")
        );
        assert!(try_lattice_cells(&[usize::MAX / 2, usize::MAX / 2]).is_err());
        assert_eq!(lattice_cells(&[0, 5]).count(), 0);
    }

    #[test]
    fn pad_points_pads_with_zeros() {
        assert_eq!(
            pad_points(&[1.0, 2.0, 3.0, 4.0], 2).unwrap(),
            [[1.0, 2.0, 0.0], [3.0, 4.0, 0.0]]
        );
        assert_eq!(pad_points(&[5.0], 1).unwrap(), [[5.0, 0.0, 0.0]]);
        assert!(pad_points(&[1.0, 2.0, 3.0], 2).is_err());
        assert!(pad_points(&[1.0], 4).is_err());
    }

    #[test]
    fn reading_garbage_is_an_error() {
        let dir = TestDir::new("garbage");
        let path = dir.path().join("garbage.vtu");
        std::fs::write(&path, b"<VTKFile type=\"UnstructuredGrid\"><oops").unwrap();
        assert_eq!(
            read_vtu(&path).unwrap_err().kind(),
            io::ErrorKind::InvalidData
        );
        assert_eq!(
            read_vtu(&dir.path().join("missing.vtu"))
                .unwrap_err()
                .kind(),
            io::ErrorKind::NotFound
        );
    }
}
