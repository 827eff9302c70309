//! # Output: VTK files for ParaView
//!
//! Pure functions over plain data (slices of coordinates and named arrays); this module knows
//! nothing about the solver. Everything it writes is written **atomically** (to a temporary file
//! in the same folder, then renamed over the target), so a reader such as ParaView polling the
//! output folder never sees a half-written file, and a series file never lists a missing file.
//!
//! ## Files a run produces
//!
//! ```text
//! OUT_DIR/
//!   particles.pvd        ParaView collection: one <DataSet timestep=.. file=..> per step
//!   particles_0000.vtu   material points of step 0 (one VTK_VERTEX cell per point)
//!   particles_0001.vtu   ...
//!   grid.pvd             collection of the background-grid files
//!   grid_0000.vtu        background grid of step 0 (VTK_LINE / VTK_QUAD / VTK_HEXAHEDRON cells)
//!   grid_0001.vtu        ...
//! ```
//!
//! A distributed run over several processes writes the particles in pieces instead
//! (`particles_NNNN_pK.vtu`, one per process, listed by `particles_NNNN.pvtu`, which
//! `particles.pvd` lists; see `pvtu.rs` and `impm merge`).
//!
//! Open `particles.pvd` (and `grid.pvd`) in ParaView to get the whole time series.
//! The numbering `NNNN` is the solver's output counter, zero-padded to four digits (see
//! [`step_file_name`]); the `.pvd` files store names relative to their own folder, so an output
//! folder can be moved or copied as a whole.
//!
//! ## Format
//!
//! `.vtu` files are VTK XML `UnstructuredGrid` files: version 1.0, little endian, `UInt64`
//! headers. By default ([`write_vtu`], [`Encoding::AppendedRaw`]) the arrays are **raw binary
//! appended data**, the layout VTK writes itself, streamed by a small writer of our own
//! (`appended.rs`: `vtkio` writes only inline base64) — the fastest to write and to read, and
//! read by ParaView, meshio and [`read_vtu`]. Zlib-compressed output (inline base64 through
//! `vtkio`, also read by ParaView and meshio, about 5x smaller and several times slower to
//! write) is available with [`write_vtu_with`] and [`Encoding::Zlib`]. LZ4 is deliberately
//! not offered (meshio cannot read vtkio's LZ4 files). Coordinates and all arrays are `Float64`
//! (connectivity and offsets `Int64`, cell types `UInt8`); points are always 3D (pad 1D/2D
//! coordinates with zeros, e.g. with [`pad_points`]).
//! A 3x3 tensor is a 9-component array in row-major order (`xx xy xz yx yy yz zx zy zz`), which
//! ParaView shows as a tensor; component 4 is `yy`. In the default encoding its components are
//! named `XX XY .. ZZ` in the file, which ParaView's component menu and colour bar show.

//! Every writer validates its input and returns an [`std::io::Error`] of kind
//! [`InvalidInput`](std::io::ErrorKind::InvalidInput) with a message naming the offending field
//! (and, for a NaN or infinity, the index) instead of panicking; nothing is written then.
//!
//! The companion script `scripts/check_output.py` (run with ParaView's `pvpython`) opens an
//! output folder the way a person would and checks it.

mod appended;
mod atomic;
mod folder;
mod pvd;
mod pvtu;
mod vtu;

pub use atomic::write_atomic;
pub use folder::{FolderLock, clear_after_step, clear_earlier_run, is_checkpoint_data};
pub use pvd::PvdSeries;
pub use pvtu::{
    CELL_ID, NODE_ID, POINT_ID, VERTEX_ID, merge_pieces, merge_pvtu, pvtu_pieces, write_pvtu,
};
pub use vtu::{
    CellKind, Cells, Encoding, Field, Sink, Stream, StreamedField, VtuContents, lattice_cells,
    pad_points, read_vtu, try_lattice_cells, vertex_cells, write_vtu, write_vtu_streamed,
    write_vtu_with,
};

/// The conventional name of the file of output step `step` of a series `stem`:
/// `step_file_name("particles", 7) == "particles_0007.vtu"` (more digits once `step` > 9999).
pub fn step_file_name(stem: &str, step: usize) -> String {
    format!("{stem}_{step:04}.vtu")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// Writes a small run in the documented layout: 3 steps of 10 material points
    /// (`cauchy_stress` and `deformation_gradient` 9 components, `displacement` 3, `volume` 1)
    /// and of a background grid of `dims` cells of size 0.25 (`mass` 1, `displacement` 3;
    /// cell data `cell_id` 1).
    fn write_sample_run(out: &Path, dims: &[usize], encoding: Encoding) -> std::io::Result<()> {
        let mut particles = PvdSeries::new(out.join("particles.pvd"));
        let mut grid = PvdSeries::new(out.join("grid.pvd"));
        let grid_cells = try_lattice_cells(dims)?;
        let mut n = [1usize; 3];
        for (a, &c) in dims.iter().enumerate() {
            n[a] = c + 1;
        }
        let grid_points: Vec<[f64; 3]> = (0..n[2])
            .flat_map(|k| {
                (0..n[1]).flat_map(move |j| {
                    (0..n[0]).map(move |i| [i as f64 * 0.25, j as f64 * 0.25, k as f64 * 0.25])
                })
            })
            .collect();
        for step in 0..3 {
            let time = step as f64 * 0.5;
            let stretch = 1.0 + 0.1 * time;
            let reference: Vec<[f64; 3]> = (0..10)
                .map(|p| [0.1 + 0.08 * p as f64, 0.2 + 0.04 * (p % 5) as f64, 0.0])
                .collect();
            let points: Vec<[f64; 3]> = reference
                .iter()
                .map(|x| [x[0], x[1] * stretch, 0.0])
                .collect();
            let displacement: Vec<f64> = points
                .iter()
                .zip(&reference)
                .flat_map(|(x, r)| [x[0] - r[0], x[1] - r[1], 0.0])
                .collect();
            let gradient: Vec<f64> = (0..10)
                .flat_map(|_| [1.0, 0.0, 0.0, 0.0, stretch, 0.0, 0.0, 0.0, 1.0])
                .collect();
            // sigma_yy grows along x so that a picture shows a gradient.
            let stress: Vec<f64> = reference
                .iter()
                .flat_map(|x| {
                    let yy = 1e6 * time * (1.0 + x[0]);
                    [0.3 * yy, 0.0, 0.0, 0.0, yy, 0.0, 0.0, 0.0, 0.3 * yy]
                })
                .collect();
            let volume = vec![0.01; 10];
            let name = step_file_name("particles", step);
            write_vtu_with(
                &out.join(&name),
                &points,
                &vertex_cells(points.len()),
                &[
                    Field::new("cauchy_stress", 9, &stress),
                    Field::new("deformation_gradient", 9, &gradient),
                    Field::new("displacement", 3, &displacement),
                    Field::scalar("volume", &volume),
                ],
                &[],
                encoding,
            )?;
            particles.push(time, &name)?;

            let mass: Vec<f64> = (0..grid_points.len()).map(|n| (n % 7) as f64).collect();
            let grid_disp: Vec<f64> = grid_points
                .iter()
                .flat_map(|x| [0.0, x[1] * (stretch - 1.0), 0.0])
                .collect();
            let cell_id: Vec<f64> = (0..grid_cells.count()).map(|c| c as f64).collect();
            let name = step_file_name("grid", step);
            write_vtu_with(
                &out.join(&name),
                &grid_points,
                &grid_cells,
                &[
                    Field::scalar("mass", &mass),
                    Field::new("displacement", 3, &grid_disp),
                ],
                &[Field::scalar("cell_id", &cell_id)],
                encoding,
            )?;
            grid.push(time, &name)?;
        }
        Ok(())
    }

    /// The sample runs read back. With `IMPM_OUTPUT_SAMPLE_DIR` set they are left in that
    /// folder for `scripts/check_output.py`: an uncompressed run with a 4x3 quad grid in it, a
    /// zlib-compressed run with a 2x2x2 hexahedron grid in its subfolder `zlib-hex`.
    #[test]
    fn sample_run_layout() {
        let temp = atomic::test_dir::TestDir::new("sample");
        let out = match std::env::var_os("IMPM_OUTPUT_SAMPLE_DIR") {
            Some(dir) => std::path::PathBuf::from(dir),
            None => temp.path().to_path_buf(),
        };
        let runs: [(&Path, &[usize], Encoding, usize, usize); 2] = [
            (&out, &[4, 3], Encoding::AppendedRaw, 20, 12),
            (
                &out.join("zlib-hex"),
                &[2, 2, 2],
                Encoding::Zlib { level: 1 },
                27,
                8,
            ),
        ];
        for (folder, dims, encoding, grid_points, grid_cells) in runs {
            std::fs::create_dir_all(folder).unwrap();
            write_sample_run(folder, dims, encoding).unwrap();
            for step in 0..3 {
                let p = read_vtu(&folder.join(step_file_name("particles", step))).unwrap();
                assert_eq!(p.points.len(), 10);
                assert_eq!(p.point_field("cauchy_stress").unwrap().0, 9);
                let g = read_vtu(&folder.join(step_file_name("grid", step))).unwrap();
                assert_eq!((g.points.len(), g.cell_count), (grid_points, grid_cells));
            }
        }
    }

    #[test]
    fn step_file_names_are_zero_padded() {
        assert_eq!(step_file_name("particles", 0), "particles_0000.vtu");
        assert_eq!(step_file_name("grid", 42), "grid_0042.vtu");
        assert_eq!(step_file_name("grid", 12345), "grid_12345.vtu");
    }
}
