//! The default `.vtu` encoding: **raw binary appended data**, written by hand.
//!
//! `vtkio` 0.7 writes binary data only inline and base64 encoded; encoding 1M points that way
//! costs about 4 s per step (the scale issue's measurement), most of it in base64 and in the
//! copies `vtkio`'s model needs. Appended raw data is the layout VTK itself writes by default:
//! the XML header lists every array with `format="appended"` and an `offset`, and one
//! `<AppendedData encoding="raw">` block after it holds, for each array in turn, a `UInt64`
//! byte count followed by the array's little-endian bytes. The data never pass through an
//! intermediate copy: each slice is streamed from the caller's buffers into a buffered writer.
//! No crate of the stack writes this format (`vtkio` reads it but cannot write it), hence this
//! small writer; ParaView (VTK 9), `meshio` and [`read_vtu`](super::read_vtu) read it, which the
//! tests check.
//!
//! ```text
//! <VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">
//!   <UnstructuredGrid><Piece NumberOfPoints=".." NumberOfCells="..">
//!     <PointData> <DataArray type="Float64" Name=".." NumberOfComponents=".." format="appended" offset=".."/> ..
//!     <CellData> ..   <Points> ..   <Cells> connectivity (Int64), offsets (Int64), types (UInt8)
//!   </Piece></UnstructuredGrid>
//!   <AppendedData encoding="raw">_[u64 n][n bytes][u64 n][n bytes]..</AppendedData>
//! </VTKFile>
//! ```
//!
//! Nine-component arrays (3x3 tensors, row-major) carry the component names `XX XY XZ YX YY YZ
//! ZX ZY ZZ`, so ParaView's colour bar and component menu read them.

use std::io::{self, Write};

use quick_xml::events::Event;

use super::pvd::escape_attribute;
use super::vtu::{Cells, Field, Stream, VtuContents};

/// Names of the nine components of a row-major 3x3 tensor.
pub const TENSOR_COMPONENT_NAMES: [&str; 9] =
    ["XX", "XY", "XZ", "YX", "YY", "YZ", "ZX", "ZY", "ZZ"];

/// One array of the appended block: how it is declared in the header and where its bytes come
/// from.
struct Array<'a> {
    name: Option<&'a str>,
    vtk_type: &'static str,
    components: usize,
    data: Data<'a>,
}

enum Data<'a> {
    F64(&'a [f64]),
    /// `len` values from a source, checked by the caller's wrapper (count, finiteness).
    Stream {
        len: usize,
        emit: Stream<'a>,
    },
    Points(&'a [[f64; 3]]),
    I64(&'a [u64]),
    Offsets {
        count: usize,
        nodes: u64,
    },
    U8 {
        count: usize,
        value: u8,
    },
}

impl Data<'_> {
    /// Number of bytes of the array.
    fn byte_len(&self) -> usize {
        match self {
            Data::F64(v) => 8 * v.len(),
            Data::Stream { len, .. } => 8 * len,
            Data::Points(p) => 24 * p.len(),
            Data::I64(v) => 8 * v.len(),
            Data::Offsets { count, .. } => 8 * count,
            Data::U8 { count, .. } => *count,
        }
    }

    /// Streams the array's little-endian bytes into `w`: on little-endian machines the caller's
    /// slices are written as they are (no copy), otherwise through a fixed-size staging buffer.
    fn write_to(&self, w: &mut impl Write) -> io::Result<()> {
        const CHUNK: usize = 8192;
        let mut buffer = Vec::with_capacity(8 * CHUNK);
        let mut flush_values = |values: &mut dyn Iterator<Item = [u8; 8]>| -> io::Result<()> {
            loop {
                buffer.clear();
                buffer.extend(values.take(CHUNK).flatten());
                if buffer.is_empty() {
                    return Ok(());
                }
                w.write_all(&buffer)?;
            }
        };
        match self {
            Data::Stream { emit, .. } => emit(&mut |values| write_f64s(w, values)),
            #[cfg(target_endian = "little")]
            Data::F64(v) => w.write_all(bytemuck::cast_slice(v)),
            #[cfg(target_endian = "little")]
            Data::Points(p) => w.write_all(bytemuck::cast_slice(p)),
            // Indices below 2^63 (they were validated to be below the point count) have the same
            // bytes as u64 and as Int64.
            #[cfg(target_endian = "little")]
            Data::I64(v) => w.write_all(bytemuck::cast_slice(v)),
            #[cfg(target_endian = "big")]
            Data::F64(v) => flush_values(&mut v.iter().map(|x| x.to_le_bytes())),
            #[cfg(target_endian = "big")]
            Data::Points(p) => flush_values(&mut p.iter().flatten().map(|x| x.to_le_bytes())),
            #[cfg(target_endian = "big")]
            Data::I64(v) => flush_values(&mut v.iter().map(|i| i.to_le_bytes())),
            Data::Offsets { count, nodes } => {
                flush_values(&mut (1..=*count as u64).map(|c| ((c * nodes) as i64).to_le_bytes()))
            }
            Data::U8 { count, value } => {
                let block = [*value; CHUNK];
                let mut left = *count;
                while left > 0 {
                    let n = left.min(CHUNK);
                    w.write_all(&block[..n])?;
                    left -= n;
                }
                Ok(())
            }
        }
    }
}

/// The little-endian bytes of `values` into `w` (no copy on little-endian machines).
fn write_f64s(w: &mut impl Write, values: &[f64]) -> io::Result<()> {
    #[cfg(target_endian = "little")]
    {
        w.write_all(bytemuck::cast_slice(values))
    }
    #[cfg(target_endian = "big")]
    {
        for chunk in values.chunks(8192) {
            let bytes: Vec<u8> = chunk.iter().flat_map(|x| x.to_le_bytes()).collect();
            w.write_all(&bytes)?;
        }
        Ok(())
    }
}

/// Writes one `.vtu` file with raw appended data to `w`. The input must have been validated
/// (finite values, field lengths, connectivity in range) by the caller.
pub(super) fn write_appended(
    w: &mut impl Write,
    points: &[[f64; 3]],
    cells: &Cells,
    point_data: &[Field],
    cell_data: &[Field],
) -> io::Result<()> {
    write_arrays(
        w,
        points.len(),
        Data::Points(points),
        cells,
        field_arrays(point_data),
        field_arrays(cell_data),
    )
}

/// [`write_appended`] with the coordinates (3 per point) and the point data produced on
/// demand, array after array (`(name, components, source)`), so that no array of the file is
/// held whole in memory. The sources must have been wrapped by the caller to check what they
/// produce (their count and finiteness: `vtu::write_vtu_streamed`).
pub(super) fn write_appended_streamed(
    w: &mut impl Write,
    point_count: usize,
    points: Stream,
    cells: &Cells,
    point_data: &[(&str, usize, Stream)],
) -> io::Result<()> {
    let point_arrays = point_data
        .iter()
        .map(|&(name, components, emit)| Array {
            name: Some(name),
            vtk_type: "Float64",
            components,
            data: Data::Stream {
                len: components * point_count,
                emit,
            },
        })
        .collect();
    let geometry = Data::Stream {
        len: 3 * point_count,
        emit: points,
    };
    write_arrays(w, point_count, geometry, cells, point_arrays, Vec::new())
}

/// The file: the header with every array's offset, then the appended block.
fn write_arrays(
    w: &mut impl Write,
    point_count: usize,
    geometry: Data,
    cells: &Cells,
    point_arrays: Vec<Array>,
    cell_arrays: Vec<Array>,
) -> io::Result<()> {
    let cell_count = cells.count();
    let geometry = [Array {
        name: None,
        vtk_type: "Float64",
        components: 3,
        data: geometry,
    }];
    let topology = [
        Array {
            name: Some("connectivity"),
            vtk_type: "Int64",
            components: 1,
            data: Data::I64(&cells.connectivity),
        },
        Array {
            name: Some("offsets"),
            vtk_type: "Int64",
            components: 1,
            data: Data::Offsets {
                count: cell_count,
                nodes: cells.kind.nodes_per_cell() as u64,
            },
        },
        Array {
            name: Some("types"),
            vtk_type: "UInt8",
            components: 1,
            data: Data::U8 {
                count: cell_count,
                value: cells.kind.vtk_type(),
            },
        },
    ];

    let mut header = String::new();
    let mut offset = 0usize;
    let mut section = |header: &mut String, tag: &str, arrays: &[Array]| {
        header.push_str(&format!("      <{tag}>\n"));
        for a in arrays {
            header.push_str(&declaration(a, offset));
            offset += 8 + a.data.byte_len();
        }
        header.push_str(&format!("      </{tag}>\n"));
    };
    header.push_str(concat!(
        "<?xml version=\"1.0\"?>\n",
        "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" ",
        "header_type=\"UInt64\">\n",
        "  <UnstructuredGrid>\n"
    ));
    header.push_str(&format!(
        "    <Piece NumberOfPoints=\"{point_count}\" NumberOfCells=\"{cell_count}\">\n"
    ));
    section(&mut header, "PointData", &point_arrays);
    section(&mut header, "CellData", &cell_arrays);
    section(&mut header, "Points", &geometry);
    section(&mut header, "Cells", &topology);
    header.push_str("    </Piece>\n  </UnstructuredGrid>\n  <AppendedData encoding=\"raw\">\n   _");
    w.write_all(header.as_bytes())?;

    for a in point_arrays
        .iter()
        .chain(&cell_arrays)
        .chain(&geometry)
        .chain(&topology)
    {
        w.write_all(&(a.data.byte_len() as u64).to_le_bytes())?;
        a.data.write_to(w)?;
    }
    w.write_all(b"\n  </AppendedData>\n</VTKFile>\n")
}

/// The point or cell data fields as appended arrays.
fn field_arrays<'a>(fields: &'a [Field<'a>]) -> Vec<Array<'a>> {
    fields
        .iter()
        .map(|f| Array {
            name: Some(f.name),
            vtk_type: "Float64",
            components: f.components,
            data: Data::F64(f.values),
        })
        .collect()
}

/// The `<DataArray .../>` line of one array at byte `offset` of the appended block.
fn declaration(a: &Array, offset: usize) -> String {
    let mut line = format!("        <DataArray type=\"{}\"", a.vtk_type);
    if let Some(name) = a.name {
        line.push_str(&format!(" Name=\"{}\"", escape_attribute(name)));
    }
    if a.components != 1 {
        line.push_str(&format!(" NumberOfComponents=\"{}\"", a.components));
    }
    if a.components == 9 {
        for (i, c) in TENSOR_COMPONENT_NAMES.iter().enumerate() {
            line.push_str(&format!(" ComponentName{i}=\"{c}\""));
        }
    }
    line.push_str(&format!(" format=\"appended\" offset=\"{offset}\"/>\n"));
    line
}

/// The raw appended block of a `.vtu` file: where its data start (after the `_` marker), if the
/// file has one; `None` for files without raw appended data (inline or base64 appended).
pub(super) fn raw_appended_start(bytes: &[u8]) -> Option<usize> {
    let tag = find(bytes, b"<AppendedData")?;
    let close = tag + find(&bytes[tag..], b">")?;
    let opening = std::str::from_utf8(&bytes[tag..close]).ok()?;
    if !opening.contains("encoding=\"raw\"") {
        return None;
    }
    Some(close + find(&bytes[close..], b"_")? + 1)
}

/// Reads a one-piece UnstructuredGrid `.vtu` file with raw appended data (as
/// [`write_appended`] writes it, and as VTK writes by default with `UInt64` headers): every
/// numeric array is converted to `f64`. `data_start` is [`raw_appended_start`]'s answer.
pub(super) fn read_appended(bytes: &[u8], data_start: usize) -> Result<VtuContents, String> {
    let header = std::str::from_utf8(&bytes[..data_start])
        .map_err(|_| "the XML header is not UTF-8".to_string())?;
    if header.contains("header_type=\"UInt32\"") {
        return Err("UInt32 block headers are not supported (impm writes UInt64)".into());
    }
    if header.contains("compressor=") {
        return Err("compressed appended data are not supported".into());
    }
    let mut reader = quick_xml::Reader::from_str(header);
    let mut section = String::new();
    let mut pieces = 0;
    let mut contents = VtuContents {
        points: Vec::new(),
        point_data: Vec::new(),
        cell_data: Vec::new(),
        cell_count: 0,
        cell_types: Vec::new(),
        connectivity: Vec::new(),
        offsets: Vec::new(),
    };
    loop {
        let element = match reader.read_event() {
            Ok(Event::Start(e)) => {
                let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                if name == "Piece" {
                    pieces += 1;
                }
                if name != "DataArray" {
                    section = name;
                    continue;
                }
                e
            }
            Ok(Event::Empty(e)) if e.name().as_ref() == b"DataArray" => e,
            Ok(Event::Eof) => break,
            Ok(_) => continue,
            // The header ends inside <AppendedData>: anything unparsable there is the end.
            Err(e) => return Err(format!("XML error in the header: {e}")),
        };
        let mut name = String::new();
        let (mut vtk_type, mut components, mut offset) = (String::new(), 1usize, None);
        for attribute in element.attributes() {
            let attribute = attribute.map_err(|e| format!("XML attribute error: {e}"))?;
            let value = attribute
                .unescape_value()
                .map_err(|e| format!("XML attribute error: {e}"))?;
            match attribute.key.as_ref() {
                b"Name" => name = value.into_owned(),
                b"type" => vtk_type = value.into_owned(),
                b"NumberOfComponents" => {
                    components = value
                        .parse()
                        .map_err(|_| format!("bad NumberOfComponents {value:?}"))?
                }
                b"offset" => {
                    offset = Some(
                        value
                            .parse::<usize>()
                            .map_err(|_| format!("bad offset {value:?}"))?,
                    )
                }
                b"format" if value != "appended" => {
                    return Err(format!("array {name:?} is not appended ({value})"));
                }
                _ => {}
            }
        }
        let offset = offset.ok_or_else(|| format!("array {name:?} has no offset"))?;
        let values = block_values(bytes, data_start, offset, &vtk_type)
            .map_err(|e| format!("array {name:?}: {e}"))?;
        if components == 0 || !values.len().is_multiple_of(components) {
            return Err(format!(
                "array {name:?}: {} values are not a whole number of {components}-tuples",
                values.len()
            ));
        }
        match (section.as_str(), name.as_str()) {
            ("PointData", _) => contents.point_data.push((name, components, values)),
            ("CellData", _) => contents.cell_data.push((name, components, values)),
            ("Points", _) if components == 3 => {
                contents.points = values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            }
            ("Points", _) => return Err("point coordinates are not 3D".into()),
            ("Cells", "connectivity") => {
                contents.connectivity = values.iter().map(|&v| v as u64).collect();
            }
            ("Cells", "offsets") => contents.offsets = values.iter().map(|&v| v as u64).collect(),
            ("Cells", "types") => contents.cell_types = values.iter().map(|&v| v as u8).collect(),
            _ => {}
        }
    }
    if pieces != 1 {
        return Err(format!("expected exactly one piece, found {pieces}"));
    }
    contents.cell_count = contents.cell_types.len();
    Ok(contents)
}

/// The values of the appended block at `offset`, converted to `f64`.
fn block_values(
    bytes: &[u8],
    data_start: usize,
    offset: usize,
    vtk_type: &str,
) -> Result<Vec<f64>, String> {
    let truncated = || "the file ends inside its data".to_string();
    let at = data_start.checked_add(offset).ok_or_else(truncated)?;
    let head: [u8; 8] = bytes
        .get(at..at + 8)
        .and_then(|h| h.try_into().ok())
        .ok_or_else(truncated)?;
    let len = usize::try_from(u64::from_le_bytes(head)).map_err(|_| truncated())?;
    let body = bytes
        .get(at + 8..at.saturating_add(8).saturating_add(len))
        .ok_or_else(truncated)?;
    macro_rules! convert {
        ($t:ty) => {
            body.chunks_exact(std::mem::size_of::<$t>())
                .map(|c| <$t>::from_le_bytes(c.try_into().unwrap_or_default()) as f64)
                .collect()
        };
    }
    Ok(match vtk_type {
        "Float64" => convert!(f64),
        "Float32" => convert!(f32),
        "Int64" => convert!(i64),
        "UInt64" => convert!(u64),
        "Int32" => convert!(i32),
        "UInt32" => convert!(u32),
        "UInt8" => body.iter().map(|&b| b as f64).collect(),
        "Int8" => body.iter().map(|&b| b as i8 as f64).collect(),
        other => return Err(format!("unsupported type {other:?}")),
    })
}

/// Position of `needle` in `haystack`.
fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_counts_precede_each_array_and_offsets_add_up() {
        let points = [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]];
        let cells = super::super::vtu::vertex_cells(2);
        let values = [1.5, -2.5];
        let mut bytes = Vec::new();
        write_appended(
            &mut bytes,
            &points,
            &cells,
            &[Field::scalar("m", &values)],
            &[],
        )
        .unwrap();
        let start = find(&bytes, b"encoding=\"raw\">").unwrap();
        let start = start + bytes[start..].iter().position(|&b| b == b'_').unwrap() + 1;
        let head = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
        // m: 2 f64; points: 6 f64; connectivity, offsets: 2 i64; types: 2 u8.
        let sizes = [16, 48, 16, 16, 2];
        let mut at = start;
        for size in sizes {
            assert_eq!(head(at), size);
            at += 8 + size as usize;
        }
        assert_eq!(
            f64::from_le_bytes(bytes[start + 8..start + 16].try_into().unwrap()),
            1.5
        );
        assert_eq!(&bytes[at..at + 1], b"\n");
        let text = String::from_utf8_lossy(&bytes[..start]);
        for offset in [0, 24, 80, 104, 128] {
            assert!(text.contains(&format!("offset=\"{offset}\"")), "{text}");
        }
    }

    #[test]
    fn a_truncated_file_is_an_error_not_a_panic() {
        let points = [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]];
        let cells = super::super::vtu::vertex_cells(2);
        let stress = [0.5; 18];
        let mut bytes = Vec::new();
        write_appended(
            &mut bytes,
            &points,
            &cells,
            &[Field::new("s", 9, &stress)],
            &[],
        )
        .unwrap();
        let start = raw_appended_start(&bytes).unwrap();
        let whole = read_appended(&bytes, start).unwrap();
        assert_eq!(whole.point_field("s").unwrap(), (9, &stress[..]));
        assert_eq!(
            (whole.cell_count, whole.offsets.as_slice()),
            (2, &[1, 2][..])
        );
        for cut in [start + 3, start + 20, bytes.len() - 40] {
            let error = read_appended(&bytes[..cut], start).unwrap_err();
            assert!(error.contains("ends inside its data"), "{error}");
        }
    }
}
