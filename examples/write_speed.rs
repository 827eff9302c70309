//! Output benchmark: the time to write one `particles_NNNN.vtu` step of N material points in
//! each `.vtu` encoding, with the fields a run writes (position, reference position, reference
//! volume, volume, mass, displacement, Cauchy stress 3x3, deformation gradient 3x3, body: 31
//! doubles per point), and the ratio against the baseline (inline base64 through `vtkio`, what
//! impm wrote before the appended writer) measured in the same process.
//!
//! ```text
//! cargo run --release --example write_speed -- [POINTS] [FOLDER]
//! ```
//!
//! `POINTS` defaults to 1,000,000, `FOLDER` to a new folder under the system temp folder (the
//! files are removed at the end). Each encoding is written three times; the best time is shown
//! (the page cache absorbs the writes, as it does in a run: this is the cost the solver waits
//! for, not the disk's sustained rate).

use std::path::PathBuf;
use std::time::Instant;

use impm::output::{Encoding, Field, read_vtu, vertex_cells, write_vtu_with};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let n: usize = match args.next() {
        Some(text) => text
            .parse()
            .map_err(|_| format!("POINTS: not a count: {text}"))?,
        None => 1_000_000,
    };
    let folder = match args.next() {
        Some(folder) => PathBuf::from(folder),
        None => std::env::temp_dir().join(format!("impm-write-speed-{}", std::process::id())),
    };
    std::fs::create_dir_all(&folder)?;

    // A sheared, stretched block of points with smooth fields (all finite, all distinct).
    let side = (n as f64).sqrt().ceil() as usize;
    let position: Vec<[f64; 3]> = (0..n)
        .map(|p| {
            let (i, j) = ((p % side) as f64, (p / side) as f64);
            [0.01 * i + 0.001 * j, 0.012 * j, 0.0]
        })
        .collect();
    let ramp = |components: usize, scale: f64| -> Vec<f64> {
        (0..components * n)
            .map(|k| scale * (1.0 + (k as f64 * 1e-6).sin()))
            .collect()
    };
    let (reference, displacement) = (ramp(3, 1.0), ramp(3, 1e-3));
    let (reference_volume, volume, mass, body) =
        (ramp(1, 1e-4), ramp(1, 1.1e-4), ramp(1, 0.2), vec![0.0; n]);
    let (stress, deformation) = (ramp(9, -1e5), ramp(9, 1.0));
    let fields = [
        Field::new("reference_position", 3, &reference),
        Field::scalar("reference_volume", &reference_volume),
        Field::scalar("volume", &volume),
        Field::scalar("mass", &mass),
        Field::new("displacement", 3, &displacement),
        Field::new("cauchy_stress", 9, &stress),
        Field::new("deformation_gradient", 9, &deformation),
        Field::scalar("body", &body),
    ];
    let cells = vertex_cells(n);

    println!(
        "writing {n} points, 31 doubles each ({:.0} MB of values)",
        248e-6 * n as f64
    );
    println!(
        "{:<14} {:>10} {:>10} {:>10} {:>12} {:>10}",
        "encoding", "write s", "MB", "MB/s", "vs base64", "read s"
    );
    let encodings = [
        ("inline base64", Encoding::InlineBase64),
        ("appended raw", Encoding::AppendedRaw),
        ("zlib level 1", Encoding::Zlib { level: 1 }),
    ];
    let mut baseline = None;
    for (label, encoding) in encodings {
        let path = folder.join(format!("particles_{label}.vtu").replace(' ', "_"));
        let mut best = f64::INFINITY;
        for _ in 0..3 {
            let start = Instant::now();
            write_vtu_with(&path, &position, &cells, &fields, &[], encoding)?;
            best = best.min(start.elapsed().as_secs_f64());
        }
        let megabytes = std::fs::metadata(&path)?.len() as f64 * 1e-6;
        let start = Instant::now();
        let back = read_vtu(&path)?;
        let read = start.elapsed().as_secs_f64();
        if back.points.len() != n || back.point_field("cauchy_stress") != Some((9, &stress[..])) {
            return Err(format!("{label}: the file does not read back as written").into());
        }
        let base = *baseline.get_or_insert(best);
        println!(
            "{label:<14} {best:>10.3} {megabytes:>10.1} {:>10.0} {:>11.2}x {read:>10.3}",
            megabytes / best,
            base / best
        );
        std::fs::remove_file(&path)?;
    }
    let _ = std::fs::remove_dir(&folder);
    Ok(())
}
