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

use std::sync::Arc;

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
/// rewrites its `.pvd` file; a series with nothing saved is left empty. Nothing on a process
/// other than 0 of a distributed run: it runs into a scratch folder of its own, which holds
/// none of the files the series list (process 0's series are the run's).
pub fn restore_series(
    world: &mut World,
    saved: &[(String, Vec<(f64, String)>)],
) -> Result<(), String> {
    if !crate::distributed::writes_run_files() {
        return Ok(());
    }
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

/// How an owner writes its state on one material point (see [`PointStatePart`]).
pub type PackPoint = dyn Fn(EntityRef<'_>, &mut Vec<f64>) + Send + Sync;

/// How an owner gives a point of a body (its `BodyIndex`) the state its [`PackPoint`] wrote.
pub type UnpackPoint =
    dyn Fn(&mut EntityWorldMut<'_>, u32, &[f64]) -> Result<(), String> + Send + Sync;

/// One owner's state on a single material point: what must travel with a point that moves to
/// another process (`distributed::respawn`). A [`CheckpointPart`] saves every point at once
/// into a world built from the same scene, whose points already carry every module's
/// components; a point that arrives from another process is spawned with the core's components
/// only, so here each owner also gives back what it derives from the point's body (a material
/// model, an F-bar marker) and what it recomputes every step (at a neutral value). Registered
/// with `plugin::Extension::point_state`.
#[derive(Clone)]
pub struct PointStatePart {
    pub name: &'static str,
    /// Appends the point's state (possibly nothing).
    pub pack: Arc<PackPoint>,
    /// Gives the point its components from exactly what `pack` wrote and its body.
    pub unpack: Arc<UnpackPoint>,
}

/// The point-state parts registered in a simulation's world, in registration order.
#[derive(Resource, Default, Clone)]
pub struct PointStateParts(pub Vec<PointStatePart>);

/// Every registered owner's state on the point `entity`: for each part, in registration
/// order, the number of its values and then the values.
pub fn pack_point_state(world: &World, entity: Entity) -> Result<Vec<f64>, String> {
    let point = world
        .get_entity(entity)
        .map_err(|_| format!("entity {entity} does not exist"))?;
    let mut values = Vec::new();
    for part in world
        .get_resource::<PointStateParts>()
        .map_or(&[][..], |parts| &parts.0)
    {
        let start = values.len();
        values.push(0.0);
        (part.pack)(point, &mut values);
        values[start] = (values.len() - start - 1) as f64;
    }
    Ok(values)
}

/// Gives the point `entity` of body `body` every owner's state from `values`, as
/// [`pack_point_state`] wrote it in a world built from the same scene.
pub fn unpack_point_state(
    world: &mut World,
    entity: Entity,
    body: u32,
    mut values: &[f64],
) -> Result<(), String> {
    let parts = world
        .get_resource::<PointStateParts>()
        .cloned()
        .unwrap_or_default();
    let mut point = world
        .get_entity_mut(entity)
        .map_err(|_| format!("entity {entity} does not exist"))?;
    for part in &parts.0 {
        let (&length, rest) = values
            .split_first()
            .ok_or_else(|| format!("{}: no state left for it", part.name))?;
        let length = length as usize;
        if rest.len() < length {
            return Err(format!(
                "{}: {length} values announced, {} left",
                part.name,
                rest.len()
            ));
        }
        (part.unpack)(&mut point, body, &rest[..length])
            .map_err(|why| format!("{}: {why}", part.name))?;
        values = &rest[length..];
    }
    if values.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "{} values left over after every part",
            values.len()
        ))
    }
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
    restore_parts_except(world, saved, &[])
}

/// [`restore_parts`] but for the parts named in `carried`, which `saved` leaves out and which
/// are restored otherwise (a checkpoint in pieces: the points' records carry them,
/// `effects::distributed::checkpoint`); every carried part must be registered.
pub fn restore_parts_except(
    world: &mut World,
    saved: &[(String, Vec<f64>)],
    carried: &[String],
) -> Result<(), String> {
    let parts = world
        .get_resource::<CheckpointParts>()
        .cloned()
        .unwrap_or_default();
    let registered: Vec<&str> = parts.0.iter().map(|p| p.name).collect();
    if let Some(unknown) = carried
        .iter()
        .find(|name| !registered.contains(&name.as_str()))
    {
        return Err(format!(
            "the saved state's points carry the part '{unknown}' but this simulation has the \
             parts {registered:?}"
        ));
    }
    let parts: Vec<&CheckpointPart> = parts
        .0
        .iter()
        .filter(|part| !carried.iter().any(|name| name == part.name))
        .collect();
    let names: Vec<&str> = parts.iter().map(|p| p.name).collect();
    let saved_names: Vec<&str> = saved.iter().map(|(name, _)| name.as_str()).collect();
    if names != saved_names {
        return Err(format!(
            "the saved state has the parts {saved_names:?} but this simulation has {names:?}"
        ));
    }
    for (part, (_, values)) in parts.into_iter().zip(saved) {
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
