//! Stage 5b for linear FEM: the mesh moves with the body, `x_i += Δu_i` for every active node,
//! after the points were updated. This replaces the MPM grid reset of the node geometry (the
//! grid fields are still cleared by `reset`), so the next step's elements are the current
//! configuration. Timed with the point update.

use bevy_ecs::prelude::*;

use crate::components::GridNode;
use crate::resources::{GridFields, Stage, StageClock};

pub fn advance_mesh<const D: usize>(
    fields: Res<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    mut nodes: Query<&mut GridNode<D>>,
) {
    let _timer = clock.time(Stage::PointUpdate);
    for mut node in nodes.iter_mut() {
        let i = node.index;
        if fields.active[i] {
            node.position += fields.increment[i];
        }
    }
}
