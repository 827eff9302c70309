//! Stage 3: loads of the step, each a system that is scheduled only when the scene uses it.
//!
//! The external force of paper eq. (9) at load factor λ, gathered at the grid nodes i:
//!
//! ```text
//!   f_ext,i = λ ( Σ_p m_p b N_i(x_p)          body force b per unit mass       apply_body_force
//!               + Σ_p P_p N_i(x_p) )          point loads P_p on material points apply_point_loads
//! ```
//!
//! (the surface term ∫_ΓN h N_i dΓ is `tractions.rs`). Every term is a force vector spread over
//! the support of a point with the basis values of the step ([`spread_force`]); the basis values
//! sum to one (partition of unity), so each term's resultant is exactly λ times its total force.
//!
//! Prescribed displacements: the constrained components of a node move by (λ_{n+1} − λ_n) times
//! their prescribed total, before the first Newton iterate, so after the step the node has moved
//! by λ_{n+1} times its prescribed value.

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::basis::NodeWeight;
use crate::components::{Fixity, GridNode, Mass, PointLoad, Support};
use crate::resources::{BodyForce, GridFields, LoadStep, Stage, StageClock};

/// Adds `force N_i` to `external_force[i]` for every node i of `support` (the force of one point
/// distributed to the grid, paper eq. 9).
pub fn spread_force<const D: usize>(
    force: &SVector<f64, D>,
    support: &[NodeWeight<D>],
    external_force: &mut [SVector<f64, D>],
) {
    for w in support {
        external_force[w.node] += force * w.value;
    }
}

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
        spread_force(
            &(acceleration * mass.0),
            &support.0,
            &mut fields.external_force,
        );
    }
}

/// Point loads: f_ext,i += λ P_p N_i(x_p) for every point p that carries a [`PointLoad`].
pub fn apply_point_loads<const D: usize>(
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut clock: ResMut<StageClock>,
    points: Query<(&PointLoad<D>, &Support<D>)>,
) {
    let _timer = clock.time(Stage::ExternalForce);
    for (load, support) in points.iter() {
        spread_force(
            &(load.0 * step.factor),
            &support.0,
            &mut fields.external_force,
        );
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::{BasisKind, BasisScratch, GridBasis};

    /// The spread force sums to the point force (partition of unity) and its first moment
    /// about the origin reproduces x_p × P: Σ_i N_i x_i = x_p for B-splines with Greville nodes
    /// (linear precision), so a load is placed where the point is.
    #[test]
    fn spread_force_keeps_resultant_and_moment() {
        let basis = GridBasis::<2>::new(
            &[0.0, 0.0],
            &[4.0, 3.0],
            &[4, 3],
            BasisKind::BSpline { order: 2 },
        )
        .unwrap();
        let x = SVector::<f64, 2>::new(2.3, 0.7);
        let mut support = Vec::new();
        basis
            .eval(&x, &mut BasisScratch::default(), &mut support)
            .unwrap();
        let force = SVector::<f64, 2>::new(3.0, -5.0);
        let mut external = vec![SVector::<f64, 2>::zeros(); basis.num_nodes()];
        spread_force(&force, &support, &mut external);
        let resultant: SVector<f64, 2> = external.iter().sum();
        assert!((resultant - force).norm() < 1e-12, "{resultant}");
        let moment: f64 = external
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let xi = basis.node_position(i);
                xi.x * f.y - xi.y * f.x
            })
            .sum();
        let expected = x.x * force.y - x.y * force.x;
        assert!((moment - expected).abs() < 1e-12, "{moment} vs {expected}");
        // only the support nodes receive force
        let loaded = external.iter().filter(|f| f.norm() > 0.0).count();
        assert_eq!(loaded, support.iter().filter(|w| w.value > 0.0).count());
    }
}
