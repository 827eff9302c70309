//! Stage 3: loads of the step, each a system that is scheduled only when the scene uses it.
//!
//! * Body force (paper eq. 9, last term): f_ext,i = λ Σ_p m_p b N_i(x_p).
//! * Prescribed displacements: the constrained components of a node move by
//!   (λ_{n+1} - λ_n) times their prescribed total, before the first Newton iterate.

use bevy_ecs::prelude::*;

use crate::components::{Fixity, GridNode, Mass, Support};
use crate::resources::{BodyForce, GridFields, LoadStep, Stage, StageClock};

pub fn apply_body_force<const D: usize>(
    body_force: Res<BodyForce<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    points: Query<(&Mass, &Support<D>)>,
) {
    let _timer = clock.time(Stage::ExternalForce);
    let acceleration = body_force.0 * step.factor;
    for (mass, support) in points.iter() {
        for w in &support.0 {
            fields.external_force[w.node] += acceleration * (mass.0 * w.value);
        }
    }
}

pub fn apply_prescribed_displacements<const D: usize>(
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    nodes: Query<(&GridNode<D>, &Fixity<D>)>,
) {
    let _timer = clock.time(Stage::ExternalForce);
    let ramp = step.factor - step.previous_factor;
    for (node, fixity) in nodes.iter() {
        for c in 0..D {
            if fixity.fixed[c] {
                fields.increment[node.index][c] = fixity.prescribed[c] * ramp;
            }
        }
    }
}
