//! Saving and restoring the state of a simulation between load steps, part by part.
//!
//! Everything a later step depends on must be restorable: the core's points (position,
//! displacement, deformation gradient, volume), and whatever each module keeps (traction points
//! follow the material; the FEM mesh moves; plastic materials carry history). Each owner
//! registers a [`CheckpointPart`] (`plugin::Extension::checkpoint`): a name and two functions,
//! one that writes its state as numbers and one that reads them back into a world built from the
//! same scene. A saved state is the parts in registration order ([`SavedState`]); restoring it
//! into a fresh simulation of the same scene gives bit-identical results from there on.
//!
//! The parts write plain `f64`s in an order of their own (points in `PointId` order), which keeps
//! them exact (no text round trip) and independent of memory layout.

use bevy_ecs::prelude::*;

use crate::output::PvdSeries;

/// One owner's part of a saved state.
#[derive(Clone, Copy)]
pub struct CheckpointPart {
    pub name: &'static str,
    pub save: fn(&mut World) -> Vec<f64>,
    pub restore: fn(&mut World, &[f64]) -> Result<(), String>,
}

/// The parts registered in a simulation's world, in registration order.
#[derive(Resource, Default, Clone)]
pub struct CheckpointParts(pub Vec<CheckpointPart>);

/// Gives access to the `.pvd` series an owner writes (the core: particles, grid, nodes; a
/// module: its own), so that a resumed run continues each series instead of starting it anew.
pub type SeriesAccess = for<'w> fn(&'w mut World) -> Vec<&'w mut PvdSeries>;

/// The series registered in a simulation's world (`plugin::Extension::series`).
#[derive(Resource, Default, Clone)]
pub struct CheckpointSeries(pub Vec<SeriesAccess>);

/// Every registered series' `(file name, entries)`, in registration order.
pub fn save_series(world: &mut World) -> Vec<(String, Vec<(f64, String)>)> {
    let access = world
        .get_resource::<CheckpointSeries>()
        .cloned()
        .unwrap_or_default();
    let mut saved = Vec::new();
    for series_of in access.0 {
        for series in series_of(world) {
            saved.push((series_file_name(series), series.entries().to_vec()));
        }
    }
    saved
}

/// Gives every registered series of `world` its saved entries (matched by file name) and
/// rewrites its `.pvd` file; a series with nothing saved is left empty.
pub fn restore_series(
    world: &mut World,
    saved: &[(String, Vec<(f64, String)>)],
) -> Result<(), String> {
    let access = world
        .get_resource::<CheckpointSeries>()
        .cloned()
        .unwrap_or_default();
    for series_of in access.0 {
        for series in series_of(world) {
            let name = series_file_name(series);
            let entries = saved
                .iter()
                .find(|(saved_name, _)| *saved_name == name)
                .map(|(_, entries)| entries.clone())
                .unwrap_or_default();
            series
                .restore_entries(entries)
                .map_err(|e| format!("{name}: {e}"))?;
        }
    }
    Ok(())
}

fn series_file_name(series: &PvdSeries) -> String {
    series
        .path()
        .file_name()
        .map(|name| name.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// A saved state: the number of load steps done and every part's numbers.
#[derive(Clone, Debug, PartialEq)]
pub struct SavedState {
    pub steps_done: usize,
    pub parts: Vec<(String, Vec<f64>)>,
}

/// Saves every registered part of `world`.
pub fn save_parts(world: &mut World) -> Vec<(String, Vec<f64>)> {
    let parts = world
        .get_resource::<CheckpointParts>()
        .cloned()
        .unwrap_or_default();
    parts
        .0
        .iter()
        .map(|part| (part.name.to_string(), (part.save)(world)))
        .collect()
}

/// Restores `saved` into `world`, whose registered parts must be the same, in the same order.
pub fn restore_parts(world: &mut World, saved: &[(String, Vec<f64>)]) -> Result<(), String> {
    let parts = world
        .get_resource::<CheckpointParts>()
        .cloned()
        .unwrap_or_default();
    let names: Vec<&str> = parts.0.iter().map(|p| p.name).collect();
    let saved_names: Vec<&str> = saved.iter().map(|(name, _)| name.as_str()).collect();
    if names != saved_names {
        return Err(format!(
            "the saved state has the parts {saved_names:?} but this simulation has {names:?}"
        ));
    }
    for (part, (_, values)) in parts.0.iter().zip(saved) {
        (part.restore)(world, values).map_err(|why| format!("{}: {why}", part.name))?;
    }
    Ok(())
}

/// A part's numbers as `count` records of `size` numbers, or an error if the counts differ.
pub fn records(
    values: &[f64],
    size: usize,
    count: usize,
) -> Result<std::slice::ChunksExact<'_, f64>, String> {
    if values.len() != size * count || size == 0 {
        return Err(format!(
            "{} numbers saved, {} expected ({count} records of {size})",
            values.len(),
            size * count
        ));
    }
    Ok(values.chunks_exact(size))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_check_their_count() {
        let read: Vec<&[f64]> = records(&[1.0, 2.0, 3.0, 4.0], 2, 2).unwrap().collect();
        assert_eq!(read, [[1.0, 2.0], [3.0, 4.0]]);
        assert!(records(&[1.0, 2.0, 3.0], 2, 2).is_err());
    }
}
