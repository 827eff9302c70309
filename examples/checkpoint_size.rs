//! The size and write time of a run's checkpoint at about 100 000 material points (the 2D
//! column, one cell wide, 6250 cells of cubic B-splines with 4 x 4 points per cell), for the
//! figures in docs/restart.md.
//!
//!   cargo run --release --example checkpoint_size [-- CELLS]
//!
//! Prints the points, the bytes of every checkpoint file and the median wall time of five
//! writes. The figures depend on the machine and on its load: say which when recording them.

use std::path::Path;
use std::time::Instant;

use impm::checkpoint;
use impm::restart::{Checkpoint, RunIdentity};
use impm::run::{Simulation, load_scene};

fn main() -> Result<(), String> {
    let cells = std::env::args().nth(1).unwrap_or_else(|| "6250".into());
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/column_2d.rhai");
    let overrides = vec![
        ("cells".to_string(), cells),
        ("steps".to_string(), "1".to_string()),
    ];
    let spec = load_scene(&scene, &overrides).map_err(|e| e.to_string())?;
    let dir = std::env::temp_dir().join(format!("impm-checkpoint-size-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let mut sim = Simulation::<2>::new(&spec, &dir).map_err(|e| e.to_string())?;
    let points = spec.bodies.iter().map(|b| b.points.len()).sum::<usize>();
    let checkpoint = Checkpoint {
        identity: RunIdentity::of(&scene, &overrides)?,
        steps_done: 0,
        parts: checkpoint::save_parts(&mut sim.world),
        series: checkpoint::save_series(&mut sim.world),
        steps: Vec::new(),
        warnings: Vec::new(),
        pieces: None,
    };
    let mut seconds = Vec::new();
    for _ in 0..5 {
        let start = Instant::now();
        checkpoint.write(&dir)?;
        seconds.push(start.elapsed().as_secs_f64());
    }
    seconds.sort_by(f64::total_cmp);
    println!("points: {points}");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .map_err(|e| e.to_string())?
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().starts_with("checkpoint"))
        .collect();
    names.sort_by_key(|e| e.file_name());
    for entry in names {
        let bytes = entry.metadata().map_err(|e| e.to_string())?.len();
        println!("{}: {bytes} bytes", entry.file_name().to_string_lossy());
    }
    println!(
        "write: median {:.3} s of 5 (min {:.3} s)",
        seconds[2], seconds[0]
    );
    let start = Instant::now();
    let identity = RunIdentity::of(&scene, &overrides)?;
    let read = Checkpoint::read(&dir, &identity)?;
    println!("read: {:.3} s", start.elapsed().as_secs_f64());
    assert_eq!(
        read.parts, checkpoint.parts,
        "the checkpoint reads back bit for bit"
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
