//! Points that are carried by the material but are not material points — traction and load
//! points (`tractions.rs`), pressure points (`pressure.rs`), boundary points
//! (`surface_conditions.rs`) — keep their current
//! position from one load step to the next; their checkpoint part is that position, saved and
//! restored in the order of their ids.

use bevy_ecs::component::Mutable;
use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::checkpoint;

/// A point carried by the material, numbered 0, 1, ... among its kind.
pub trait CarriedPoint<const D: usize>: Component<Mutability = Mutable> {
    fn id(&self) -> u32;
    fn position_mut(&mut self) -> &mut SVector<f64, D>;
    fn position(&self) -> SVector<f64, D>;
}

/// Implements [`CarriedPoint`] for a point component generic over `D` with the fields
/// `id: u32` and `position: SVector<f64, D>`.
macro_rules! carried_point {
    ($point:ident) => {
        impl<const D: usize> $crate::effects::carried_points::CarriedPoint<D> for $point<D> {
            fn id(&self) -> u32 {
                self.id
            }
            fn position(&self) -> nalgebra::SVector<f64, D> {
                self.position
            }
            fn position_mut(&mut self) -> &mut nalgebra::SVector<f64, D> {
                &mut self.position
            }
        }
    };
}
pub(crate) use carried_point;

/// The points' positions, in id order (a `CheckpointPart::save`).
pub fn save_positions<const D: usize, P: CarriedPoint<D>>(world: &mut World) -> Vec<f64> {
    let mut points: Vec<(u32, SVector<f64, D>)> = world
        .query::<&P>()
        .iter(world)
        .map(|p| (p.id(), p.position()))
        .collect();
    points.sort_by_key(|(id, _)| *id);
    points.iter().flat_map(|(_, x)| x.iter().copied()).collect()
}

/// Restores what [`save_positions`] saved (a `CheckpointPart::restore`).
pub fn restore_positions<const D: usize, P: CarriedPoint<D>>(
    world: &mut World,
    values: &[f64],
) -> Result<(), String> {
    let mut query = world.query::<&mut P>();
    let count = query.iter(world).len();
    let records: Vec<&[f64]> = checkpoint::records(values, D, count)?.collect();
    for mut point in query.iter_mut(world) {
        let id = point.id() as usize;
        let record = records
            .get(id)
            .ok_or_else(|| format!("point id {id} beyond the {count} saved"))?;
        *point.position_mut() = SVector::from_column_slice(record);
    }
    Ok(())
}
