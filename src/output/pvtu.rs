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
//! concatenated into one `.vtu` (pieces of vertex cells only: the material points), ordered by
//! the `point_id` array when the pieces carry one (the order of a serial run's file).

use std::io;
use std::path::{Path, PathBuf};

use quick_xml::events::Event;

use super::atomic::write_atomic;
use super::vtu::{Field, VtuContents, read_vtu, vertex_cells, write_vtu};

/// The name of the array by which [`merge_pieces`] orders the merged points.
pub const POINT_ID: &str = "point_id";

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

/// The pieces of a `.pvtu` as one data set: points, point and cell arrays concatenated in
/// piece order, then reordered by [`POINT_ID`] if the pieces have that array. Only pieces of
/// vertex cells (one per point, as the material points are written) are merged; every piece
/// must have the same arrays with the same components (`InvalidData` otherwise).
pub fn merge_pieces(pieces: &[VtuContents], what: &str) -> io::Result<VtuContents> {
    let bad = |why: String| io::Error::new(io::ErrorKind::InvalidData, format!("{what}: {why}"));
    let Some(first) = pieces.first() else {
        return Err(bad("no pieces".to_string()));
    };
    let layout = |arrays: &[(String, usize, Vec<f64>)]| -> Vec<(String, usize)> {
        arrays.iter().map(|(n, c, _)| (n.clone(), *c)).collect()
    };
    let mut merged = VtuContents {
        points: Vec::new(),
        point_data: first
            .point_data
            .iter()
            .map(|(n, c, _)| (n.clone(), *c, Vec::new()))
            .collect(),
        cell_data: first
            .cell_data
            .iter()
            .map(|(n, c, _)| (n.clone(), *c, Vec::new()))
            .collect(),
        cell_count: 0,
        cell_types: Vec::new(),
        connectivity: Vec::new(),
        offsets: Vec::new(),
    };
    for (k, piece) in pieces.iter().enumerate() {
        let vertices = piece.cell_count == piece.points.len()
            && piece.cell_types.iter().all(|&t| t == 1)
            && piece
                .connectivity
                .iter()
                .enumerate()
                .all(|(i, &p)| p == i as u64);
        if !vertices {
            return Err(bad(format!(
                "piece {k} is not one vertex cell per point; only point pieces are merged"
            )));
        }
        if layout(&piece.point_data) != layout(&first.point_data)
            || layout(&piece.cell_data) != layout(&first.cell_data)
        {
            return Err(bad(format!(
                "piece {k} has other arrays than piece 0: {:?} against {:?}",
                layout(&piece.point_data),
                layout(&first.point_data)
            )));
        }
        merged.points.extend_from_slice(&piece.points);
        for (into, (_, _, values)) in merged.point_data.iter_mut().zip(&piece.point_data) {
            into.2.extend_from_slice(values);
        }
        for (into, (_, _, values)) in merged.cell_data.iter_mut().zip(&piece.cell_data) {
            into.2.extend_from_slice(values);
        }
    }
    let n = merged.points.len();
    if let Some((_, 1, ids)) = merged.point_data.iter().find(|(n, _, _)| n == POINT_ID) {
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| ids[a].total_cmp(&ids[b]));
        merged.points = order.iter().map(|&i| merged.points[i]).collect();
        for (_, components, values) in merged
            .point_data
            .iter_mut()
            .chain(merged.cell_data.iter_mut())
        {
            let c = *components;
            *values = order
                .iter()
                .flat_map(|&i| values[c * i..c * (i + 1)].iter().copied())
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
    write_vtu(
        out,
        &merged.points,
        &vertex_cells(merged.points.len()),
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
}
