//! Stage 7: grid reset (also run after a failed attempt, `RollbackSchedule`). The background grid returns to its undeformed state; nothing carries
//! over to the next load step except what the points hold.

use bevy_ecs::prelude::*;

use crate::resources::{GridFields, Stage, StageClock};

pub fn reset_grid<const D: usize>(
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
) {
    let _timer = clock.time(Stage::ResetGrid);
    fields.reset();
}
