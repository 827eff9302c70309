//! Parallel data sets: the `.pvtu` file over the pieces the processes of a distributed run
//! write, and their merge into one `.vtu`.
//!
//! A `.pvtu` (VTK XML `PUnstructuredGrid`) holds no data: it declares the point and cell
//! arrays (name, type, components) and the points' type, and lists the pieces, each a `.vtu`
//! file relative to the `.pvtu`'s folder:
//!
//! ```text
//! <VTKFile type="PUnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">
//!   <PUnstructuredGrid GhostLevel="0">
//!     <PPointData>
//!       <PDataArray type="Float64" Name="volume" NumberOfComponents="1"/>
//!     </PPointData>
//!     <PPoints><PDataArray type="Float64" NumberOfComponents="3"/></PPoints>
//!     <Piece Source="particles_0001_p0.vtu"/>
//!     <Piece Source="particles_0001_p1.vtu"/>
//!   </PUnstructuredGrid>
//! </VTKFile>
//! ```
//!
//! ParaView reads it (and a `.pvd` listing `.pvtu` files) as one data set; meshio does not,
//! hence [`merge_pieces`] (`impm merge OUT_DIR`): the pieces' points, point and cell arrays
//! merged into one `.vtu`, in the order of a serial run's file:
//!
//! * pieces of vertex cells (the material points, the grid nodes): concatenated, then ordered
//!   by the [`POINT_ID`] or [`NODE_ID`] array when the pieces carry one; a number in two
//!   pieces is refused;
//! * pieces of other cells (the background grid's): each piece carries its vertices' numbers
//!   ([`VERTEX_ID`], a point array) and its cells' ([`CELL_ID`], a cell array) in the whole
//!   lattice. A vertex on the boundary between two pieces is in both (a cell's corners are in
//!   its piece): the merge keeps it once, in vertex-number order, and refuses it if the pieces
//!   disagree on its position or any of its values; the cells are ordered by their numbers,
//!   their corners renumbered, and a cell in two pieces is refused.

use std::io;
use std::path::{Path, PathBuf};

use quick_xml::events::Event;

use super::atomic::write_atomic;
use super::vtu::{CellKind, Cells, Field, VtuContents, read_vtu, vertex_cells, write_vtu};

/// The name of the array by which [`merge_pieces`] orders the merged points.
pub const POINT_ID: &str = "point_id";

/// The array of a grid node's number, by which [`merge_pieces`] orders merged node pieces.
pub const NODE_ID: &str = "node_id";

/// A grid piece's point array: each vertex's number in the whole lattice.
pub const VERTEX_ID: &str = "vertex_id";

/// A grid piece's cell array: each cell's number in the whole lattice.
pub const CELL_ID: &str = "cell_id";

/// Writes (atomically) the `.pvtu` at `path` over `pieces` (file names relative to its
/// folder), declaring the Float64 arrays `point_data` and `cell_data` (`(name, components)`,
/// in file order, as every piece has them). Every piece must exist (`NotFound` otherwise:
/// a `.pvtu` never lists a missing file).
pub fn write_pvtu(
    path: &Path,
    pieces: &[String],
    point_data: &[(String, usize)],
    cell_data: &[(String, usize)],
) -> io::Result<()> {
    let folder = path.parent().unwrap_or(Path::new("."));
    if let Some(missing) = pieces.iter().find(|p| !folder.join(p).is_file()) {
        return Err(io::Error::new(
            io::ErrorKind::NotFound,
            format!(
                "{}: refusing to list the piece {missing}, which does not exist",
                path.display()
            ),
        ));
    }
    let arrays = |tag: &str, arrays: &[(String, usize)]| {
        let mut xml = format!("    <{tag}>\n");
        for (name, components) in arrays {
            xml.push_str(&format!(
                "      <PDataArray type=\"Float64\" Name=\"{}\" NumberOfComponents=\"{components}\"/>\n",
                escape(name)
            ));
        }
        xml.push_str(&format!("    </{tag}>\n"));
        xml
    };
    let mut xml = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PUnstructuredGrid\" version=\"1.0\" \
         byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  \
         <PUnstructuredGrid GhostLevel=\"0\">\n",
    );
    xml.push_str(&arrays("PPointData", point_data));
    xml.push_str(&arrays("PCellData", cell_data));
    xml.push_str(
        "    <PPoints>\n      <PDataArray type=\"Float64\" NumberOfComponents=\"3\"/>\n    \
         </PPoints>\n",
    );
    for piece in pieces {
        xml.push_str(&format!("    <Piece Source=\"{}\"/>\n", escape(piece)));
    }
    xml.push_str("  </PUnstructuredGrid>\n</VTKFile>\n");
    write_atomic(path, xml.as_bytes())
}

/// The pieces a `.pvtu` lists, as paths (relative sources resolved against its folder).
pub fn pvtu_pieces(path: &Path) -> io::Result<Vec<PathBuf>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| io::Error::new(e.kind(), format!("opening {}: {e}", path.display())))?;
    let bad = |why: String| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("reading {}: {why}", path.display()),
        )
    };
    let folder = path.parent().unwrap_or(Path::new("."));
    let mut reader = quick_xml::Reader::from_str(&text);
    let mut pieces = Vec::new();
    let mut parallel = false;
    loop {
        match reader.read_event() {
            Ok(Event::Eof) => break,
            Ok(Event::Start(e) | Event::Empty(e)) => match e.name().as_ref() {
                b"PUnstructuredGrid" => parallel = true,
                b"Piece" => {
                    let source = e
                        .try_get_attribute("Source")
                        .map_err(|e| bad(e.to_string()))?
                        .ok_or_else(|| bad("a <Piece> without Source".to_string()))?;
                    let source = source.unescape_value().map_err(|e| bad(e.to_string()))?;
                    pieces.push(folder.join(source.as_ref()));
                }
                _ => {}
            },
            Ok(_) => {}
            Err(e) => return Err(bad(e.to_string())),
        }
    }
    if !parallel {
        return Err(bad("not a PUnstructuredGrid file".to_string()));
    }
    Ok(pieces)
}

/// The pieces of a `.pvtu` as one data set (see the module docs): pieces of vertex cells
/// concatenated in piece order, then reordered by [`POINT_ID`] or [`NODE_ID`] if the pieces
/// have that array; pieces of other cells merged by their [`VERTEX_ID`] and [`CELL_ID`]
/// arrays. Every piece must have the same arrays with the same components (`InvalidData`
/// otherwise, as for a number in two pieces or a shared vertex the pieces disagree on).
pub fn merge_pieces(pieces: &[VtuContents], what: &str) -> io::Result<VtuContents> {
    let bad = |why: String| io::Error::new(io::ErrorKind::InvalidData, format!("{what}: {why}"));
    let Some(first) = pieces.first() else {
        return Err(bad("no pieces".to_string()));
    };
    let layout = |arrays: &[(String, usize, Vec<f64>)]| -> Vec<(String, usize)> {
        arrays.iter().map(|(n, c, _)| (n.clone(), *c)).collect()
    };
    for (k, piece) in pieces.iter().enumerate() {
        if layout(&piece.point_data) != layout(&first.point_data)
            || layout(&piece.cell_data) != layout(&first.cell_data)
        {
            return Err(bad(format!(
                "piece {k} has other arrays than piece 0: {:?} against {:?}",
                layout(&piece.point_data),
                layout(&first.point_data)
            )));
        }
    }
    let vertices = |piece: &VtuContents| {
        piece.cell_count == piece.points.len()
            && piece.cell_types.iter().all(|&t| t == 1)
            && (piece.connectivity.iter().enumerate()).all(|(i, &p)| p == i as u64)
    };
    if pieces.iter().all(vertices) {
        return merge_point_pieces(pieces, &bad);
    }
    let has = |arrays: &[(String, usize, Vec<f64>)], name: &str| {
        arrays.iter().any(|(n, c, _)| n == name && *c == 1)
    };
    if has(&first.point_data, VERTEX_ID) && has(&first.cell_data, CELL_ID) {
        return merge_cell_pieces(pieces, &bad);
    }
    Err(bad(format!(
        "the pieces are neither one vertex cell per point nor cells with {VERTEX_ID} and \
         {CELL_ID} arrays: they cannot be merged"
    )))
}

/// An empty data set with the arrays of `first`.
fn empty_like(first: &VtuContents) -> VtuContents {
    let empty = |arrays: &[(String, usize, Vec<f64>)]| {
        (arrays.iter())
            .map(|(n, c, _)| (n.clone(), *c, Vec::new()))
            .collect()
    };
    VtuContents {
        points: Vec::new(),
        point_data: empty(&first.point_data),
        cell_data: empty(&first.cell_data),
        cell_count: 0,
        cell_types: Vec::new(),
        connectivity: Vec::new(),
        offsets: Vec::new(),
    }
}

/// The values of one array for entry `i`.
fn row(values: &[f64], components: usize, i: usize) -> &[f64] {
    &values[components * i..components * (i + 1)]
}

/// Pieces of vertex cells: concatenated, then in number order ([`POINT_ID`], [`NODE_ID`]).
fn merge_point_pieces(
    pieces: &[VtuContents],
    bad: &dyn Fn(String) -> io::Error,
) -> io::Result<VtuContents> {
    let mut merged = empty_like(&pieces[0]);
    for piece in pieces {
        merged.points.extend_from_slice(&piece.points);
        for (into, (_, _, values)) in merged.point_data.iter_mut().zip(&piece.point_data) {
            into.2.extend_from_slice(values);
        }
        for (into, (_, _, values)) in merged.cell_data.iter_mut().zip(&piece.cell_data) {
            into.2.extend_from_slice(values);
        }
    }
    let n = merged.points.len();
    let numbers = (merged.point_data.iter())
        .find(|(name, c, _)| (name == POINT_ID || name == NODE_ID) && *c == 1);
    if let Some((name, _, ids)) = numbers {
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| ids[a].total_cmp(&ids[b]));
        if let Some(pair) = order.windows(2).find(|w| ids[w[0]] == ids[w[1]]) {
            return Err(bad(format!(
                "{name} {} is in the pieces twice",
                ids[pair[0]]
            )));
        }
        merged.points = order.iter().map(|&i| merged.points[i]).collect();
        for (_, components, values) in merged
            .point_data
            .iter_mut()
            .chain(merged.cell_data.iter_mut())
        {
            let c = *components;
            *values = (order.iter())
                .flat_map(|&i| row(values, c, i).iter().copied())
                .collect();
        }
    }
    let cells = vertex_cells(n);
    merged.cell_count = n;
    merged.cell_types = vec![1; n];
    merged.offsets = (1..=n as u64).collect();
    merged.connectivity = cells.connectivity;
    Ok(merged)
}

/// Pieces of lattice cells: vertices by [`VERTEX_ID`] (a shared one once, the pieces agreeing
/// on it), cells by [`CELL_ID`].
fn merge_cell_pieces(
    pieces: &[VtuContents],
    bad: &dyn Fn(String) -> io::Error,
) -> io::Result<VtuContents> {
    let numbers = |arrays: &'_ [(String, usize, Vec<f64>)], name: &str| -> Vec<f64> {
        (arrays.iter())
            .find(|(n, _, _)| n == name)
            .map(|(_, _, values)| values.clone())
            .unwrap_or_default()
    };
    let mut merged = empty_like(&pieces[0]);
    // every piece's vertices, (number, piece, index), in number order
    let mut vertices: Vec<(f64, usize, usize)> = Vec::new();
    let mut cells: Vec<(f64, usize, usize)> = Vec::new();
    for (k, piece) in pieces.iter().enumerate() {
        let ids = numbers(&piece.point_data, VERTEX_ID);
        if ids.len() != piece.points.len() {
            return Err(bad(format!(
                "piece {k}: {VERTEX_ID} is not one number per point"
            )));
        }
        vertices.extend(ids.iter().enumerate().map(|(i, &id)| (id, k, i)));
        let ids = numbers(&piece.cell_data, CELL_ID);
        if ids.len() != piece.cell_count || piece.offsets.len() != piece.cell_count {
            return Err(bad(format!(
                "piece {k}: {CELL_ID} is not one number per cell"
            )));
        }
        cells.extend(ids.iter().enumerate().map(|(i, &id)| (id, k, i)));
    }
    vertices.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    cells.sort_by(|a, b| a.0.total_cmp(&b.0));
    // each piece's vertex in the merged file
    let mut place: Vec<Vec<u64>> = pieces.iter().map(|p| vec![0; p.points.len()]).collect();
    let mut kept: Option<(f64, usize, usize)> = None;
    for &(id, k, i) in &vertices {
        if let Some((kept_id, kk, ki)) = kept.filter(|kept| kept.0 == id) {
            let (a, b) = (&pieces[kk], &pieces[k]);
            let same = a.points[ki] == b.points[i]
                && (a.point_data.iter().zip(&b.point_data))
                    .all(|((_, c, x), (_, _, y))| row(x, *c, ki) == row(y, *c, i));
            if !same {
                return Err(bad(format!(
                    "{VERTEX_ID} {kept_id} has other values in piece {k} than in piece {kk}"
                )));
            }
            place[k][i] = (merged.points.len() - 1) as u64;
            continue;
        }
        kept = Some((id, k, i));
        let piece = &pieces[k];
        merged.points.push(piece.points[i]);
        for (into, (_, c, values)) in merged.point_data.iter_mut().zip(&piece.point_data) {
            into.2.extend_from_slice(row(values, *c, i));
        }
        place[k][i] = (merged.points.len() - 1) as u64;
    }
    if let Some(pair) = cells.windows(2).find(|w| w[0].0 == w[1].0) {
        return Err(bad(format!(
            "{CELL_ID} {} is in pieces {} and {}",
            pair[0].0, pair[0].1, pair[1].1
        )));
    }
    for &(_, k, i) in &cells {
        let piece = &pieces[k];
        let start = if i == 0 {
            0
        } else {
            piece.offsets[i - 1] as usize
        };
        let end = piece.offsets[i] as usize;
        let corners = piece.connectivity.get(start..end).ok_or_else(|| {
            bad(format!(
                "piece {k}: cell {i}'s corners are not in its connectivity"
            ))
        })?;
        for &corner in corners {
            let at = place[k].get(corner as usize).ok_or_else(|| {
                bad(format!(
                    "piece {k}: cell {i} has a corner {corner} it has no point for"
                ))
            })?;
            merged.connectivity.push(*at);
        }
        merged.offsets.push(merged.connectivity.len() as u64);
        merged.cell_types.push(piece.cell_types[i]);
        for (into, (_, c, values)) in merged.cell_data.iter_mut().zip(&piece.cell_data) {
            into.2.extend_from_slice(row(values, *c, i));
        }
    }
    merged.cell_count = cells.len();
    Ok(merged)
}

/// Merges the pieces of the `.pvtu` at `pvtu` into the `.vtu` at `out` (atomically); returns
/// the number of points.
pub fn merge_pvtu(pvtu: &Path, out: &Path) -> io::Result<usize> {
    let pieces = pvtu_pieces(pvtu)?
        .iter()
        .map(|piece| read_vtu(piece))
        .collect::<io::Result<Vec<_>>>()?;
    let merged = merge_pieces(&pieces, &pvtu.display().to_string())?;
    fn as_fields(arrays: &[(String, usize, Vec<f64>)]) -> Vec<Field<'_>> {
        arrays
            .iter()
            .map(|(name, components, values)| Field {
                name,
                components: *components,
                values,
            })
            .collect()
    }
    let kind = match merged.cell_types.first() {
        None => Some(CellKind::Vertex),
        Some(&first) => {
            CellKind::from_vtk_type(first).filter(|_| merged.cell_types.iter().all(|&t| t == first))
        }
    };
    let Some(kind) = kind else {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "{}: the pieces' cells are not all of one kind",
                pvtu.display()
            ),
        ));
    };
    write_vtu(
        out,
        &merged.points,
        &Cells {
            kind,
            connectivity: merged.connectivity,
        },
        &as_fields(&merged.point_data),
        &as_fields(&merged.cell_data),
    )?;
    Ok(merged.points.len())
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("impm-pvtu-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Three pieces of points with ids interleaved: the `.pvtu` lists them, and the merge gives
    /// back every point with its arrays, in id order.
    #[test]
    fn pieces_are_listed_and_merged_in_point_id_order() {
        let dir = temp("merge");
        // point i: position (i, 2i, 0), volume 10 + i, stress (i, -i, 0.5 i)
        let ids_of_piece: [&[usize]; 3] = [&[0, 3, 6], &[1, 4], &[2, 5, 7, 8]];
        let mut names = Vec::new();
        for (k, ids) in ids_of_piece.iter().enumerate() {
            let points: Vec<[f64; 3]> = ids
                .iter()
                .map(|&i| [i as f64, 2.0 * i as f64, 0.0])
                .collect();
            let volume: Vec<f64> = ids.iter().map(|&i| 10.0 + i as f64).collect();
            let stress: Vec<f64> = ids
                .iter()
                .flat_map(|&i| [i as f64, -(i as f64), 0.5 * i as f64])
                .collect();
            let id: Vec<f64> = ids.iter().map(|&i| i as f64).collect();
            let name = format!("particles_0001_p{k}.vtu");
            write_vtu(
                &dir.join(&name),
                &points,
                &vertex_cells(points.len()),
                &[
                    Field::scalar("volume", &volume),
                    Field::new("stress", 3, &stress),
                    Field::scalar(POINT_ID, &id),
                ],
                &[],
            )
            .unwrap();
            names.push(name);
        }
        let arrays = [
            ("volume".to_string(), 1),
            ("stress".to_string(), 3),
            (POINT_ID.to_string(), 1),
        ];
        let pvtu = dir.join("particles_0001.pvtu");
        write_pvtu(&pvtu, &names, &arrays, &[]).unwrap();
        let listed = pvtu_pieces(&pvtu).unwrap();
        assert_eq!(
            listed,
            names.iter().map(|n| dir.join(n)).collect::<Vec<_>>()
        );
        let merged_path = dir.join("particles_0001.vtu");
        assert_eq!(merge_pvtu(&pvtu, &merged_path).unwrap(), 9);
        let merged = read_vtu(&merged_path).unwrap();
        for i in 0..9 {
            let x = i as f64;
            assert_eq!(merged.points[i], [x, 2.0 * x, 0.0]);
            assert_eq!(merged.point_field("volume").unwrap().1[i], 10.0 + x);
            assert_eq!(
                &merged.point_field("stress").unwrap().1[3 * i..3 * i + 3],
                &[x, -x, 0.5 * x]
            );
        }
        assert_eq!(merged.cell_count, 9);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_missing_piece_or_different_arrays_are_refused() {
        let dir = temp("refuse");
        let pvtu = dir.join("particles_0000.pvtu");
        let error = write_pvtu(&pvtu, &["gone.vtu".to_string()], &[], &[]).unwrap_err();
        assert_eq!(error.kind(), io::ErrorKind::NotFound);
        assert!(!pvtu.exists());
        let a = [1.0];
        for (name, field) in [("a.vtu", "volume"), ("b.vtu", "mass")] {
            write_vtu(
                &dir.join(name),
                &[[0.0; 3]],
                &vertex_cells(1),
                &[Field::scalar(field, &a)],
                &[],
            )
            .unwrap();
        }
        write_pvtu(
            &pvtu,
            &["a.vtu".to_string(), "b.vtu".to_string()],
            &[("volume".to_string(), 1)],
            &[],
        )
        .unwrap();
        let error = merge_pvtu(&pvtu, &dir.join("merged.vtu")).unwrap_err();
        assert_eq!(error.kind(), io::ErrorKind::InvalidData);
        assert!(
            error.to_string().contains("piece 1 has other arrays"),
            "{error}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A 3 x 1 lattice of quads cut into two pieces (cells 0, 2 and cell 1: each piece holds
    /// its cells' corners, the vertices between the cells in both): the merge gives the whole
    /// lattice's file (points in vertex order, cells in cell order with their corners
    /// renumbered, every array); a cell in two pieces, or a shared vertex whose values differ
    /// between the pieces, is refused.
    #[test]
    fn grid_pieces_merge_into_the_whole_lattice() {
        use crate::output::lattice_cells;
        let dir = temp("grid");
        let whole = lattice_cells(&[3, 1]);
        // vertex v = i + 4 j at (i, j); its value 10 v; cell c's value 100 + c
        let position = |v: usize| [(v % 4) as f64, (v / 4) as f64, 0.0];
        let write_piece = |name: &str, cells: &[usize], tamper: bool| {
            let mut vertices: Vec<usize> = (cells.iter())
                .flat_map(|&c| &whole.connectivity[4 * c..4 * c + 4])
                .map(|&v| v as usize)
                .collect();
            vertices.sort_unstable();
            vertices.dedup();
            let connectivity = (cells.iter())
                .flat_map(|&c| &whole.connectivity[4 * c..4 * c + 4])
                .map(|&v| vertices.binary_search(&(v as usize)).unwrap() as u64)
                .collect();
            let points: Vec<[f64; 3]> = vertices.iter().map(|&v| position(v)).collect();
            let mut value: Vec<f64> = vertices.iter().map(|&v| 10.0 * v as f64).collect();
            if tamper {
                value[0] += 1e-9;
            }
            let ids: Vec<f64> = vertices.iter().map(|&v| v as f64).collect();
            let cell_value: Vec<f64> = cells.iter().map(|&c| 100.0 + c as f64).collect();
            let cell_ids: Vec<f64> = cells.iter().map(|&c| c as f64).collect();
            write_vtu(
                &dir.join(name),
                &points,
                &Cells {
                    kind: CellKind::Quad,
                    connectivity,
                },
                &[
                    Field::scalar("value", &value),
                    Field::scalar(VERTEX_ID, &ids),
                ],
                &[
                    Field::scalar("material_points", &cell_value),
                    Field::scalar(CELL_ID, &cell_ids),
                ],
            )
            .unwrap();
        };
        let points = [("value".to_string(), 1), (VERTEX_ID.to_string(), 1)];
        let cells = [("material_points".to_string(), 1), (CELL_ID.to_string(), 1)];
        let merge = |pieces: &[(&str, &[usize], bool)]| {
            let names: Vec<String> = pieces.iter().map(|p| p.0.to_string()).collect();
            for &(name, cells, tamper) in pieces {
                write_piece(name, cells, tamper);
            }
            let pvtu = dir.join("grid_0001.pvtu");
            write_pvtu(&pvtu, &names, &points, &cells).unwrap();
            merge_pvtu(&pvtu, &dir.join("grid_0001.vtu"))
                .map(|_| read_vtu(&dir.join("grid_0001.vtu")).unwrap())
        };
        let merged = merge(&[("a.vtu", &[0, 2], false), ("b.vtu", &[1], false)]).unwrap();
        assert_eq!(merged.points, (0..8).map(position).collect::<Vec<_>>());
        assert_eq!(merged.connectivity, whole.connectivity);
        assert_eq!(merged.cell_types, vec![CellKind::Quad.vtk_type(); 3]);
        let values: Vec<f64> = (0..8).map(|v| 10.0 * v as f64).collect();
        assert_eq!(merged.point_field("value").unwrap().1, &values[..]);
        assert_eq!(
            merged.cell_field("material_points").unwrap().1,
            &[100.0, 101.0, 102.0]
        );
        let twice = merge(&[("a.vtu", &[0, 2], false), ("b.vtu", &[1, 2], false)]).unwrap_err();
        assert!(
            twice.to_string().contains("cell_id 2 is in pieces 0 and 1"),
            "{twice}"
        );
        let differ = merge(&[("a.vtu", &[0, 2], false), ("b.vtu", &[1], true)]).unwrap_err();
        assert!(
            differ.to_string().contains("vertex_id 1 has other values"),
            "{differ}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A node (or point) number in two vertex pieces is refused, not merged twice.
    #[test]
    fn a_number_in_two_point_pieces_is_refused() {
        let dir = temp("twice");
        for (name, ids) in [("a.vtu", [0.0, 1.0]), ("b.vtu", [1.0, 2.0])] {
            write_vtu(
                &dir.join(name),
                &[[0.0; 3], [1.0, 0.0, 0.0]],
                &vertex_cells(2),
                &[Field::scalar(NODE_ID, &ids)],
                &[],
            )
            .unwrap();
        }
        let pvtu = dir.join("nodes_0001.pvtu");
        let names = ["a.vtu".to_string(), "b.vtu".to_string()];
        write_pvtu(&pvtu, &names, &[(NODE_ID.to_string(), 1)], &[]).unwrap();
        let error = merge_pvtu(&pvtu, &dir.join("nodes_0001.vtu")).unwrap_err();
        assert!(
            error
                .to_string()
                .contains("node_id 1 is in the pieces twice"),
            "{error}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
