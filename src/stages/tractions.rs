//! Surface tractions (paper eqs. 1 and 9): the Neumann term of the external force,
//!
//! ```text
//!   f_ext,i += λ ∫_ΓN h N_i dΓ  ≈  λ Σ_s h_s A_s N_i(x_s),
//! ```
//!
//! integrated with traction points s: quadrature points seeded on a flat piece of boundary
//! (`traction(...)` in scenes, see `scene::seed_boundary`) that need not align with the grid.
//! Each carries its reference area A_s and the traction h_s (force per unit reference area, of
//! fixed direction: a dead load), and moves with the material ([`update_traction_points`]).
//!
//! Both systems are scheduled only when a scene declares tractions:
//!
//! * [`apply_tractions`] (stage 3, loads): evaluate the basis at x_s and spread λ h_s A_s over
//!   the support ([`spread_over_active`]).
//! * [`update_traction_points`] (stage 5, point update, after the material points):
//!   x_s = x_p + F_p (X_s − X_p), with p the host of s, the material point nearest to it in the
//!   reference configuration. This keeps the traction point on the body's boundary exactly for
//!   any homogeneous deformation of the host's neighbourhood, which interpolating the grid
//!   increment at x_s would not: part of a boundary point's support is grid nodes outside the
//!   body, whose increments are not unknowns (see below).
//!
//! A traction point lies on the body's boundary, where part of its support may be grid nodes
//! that no material point supports (inactive nodes, with no unknown). The force those nodes
//! would receive is given to the active nodes of the support in proportion to their basis
//! values, so the resultant λ h_s A_s is kept exactly; when every support node is active (the
//! usual case: a boundary inside or on the face of a cell with material points) this is exactly
//! the quadrature above. A traction point with no active node in its support is an error.

use bevy_ecs::prelude::*;
use nalgebra::SVector;

use crate::basis::{BasisScratch, NodeWeight};
use crate::components::{DeformationGradient, Position, TractionPoint};
use crate::resources::{Grid, GridFields, LoadStep, RunStatus, SolverError, Stage, StageClock};

/// Σ_{i active} N_i over `support`.
fn active_weight<const D: usize>(support: &[NodeWeight<D>], active: &[bool]) -> f64 {
    support
        .iter()
        .filter(|w| active[w.node])
        .map(|w| w.value)
        .sum()
}

/// Adds `force N_i / Σ_{j active} N_j` to `external_force[i]` for every active node i of
/// `support`. Returns false (and adds nothing) if no node of the support is active.
pub fn spread_over_active<const D: usize>(
    force: &SVector<f64, D>,
    support: &[NodeWeight<D>],
    active: &[bool],
    external_force: &mut [SVector<f64, D>],
) -> bool {
    let total = active_weight(support, active);
    if total <= 0.0 {
        return false;
    }
    for w in support.iter().filter(|w| active[w.node]) {
        external_force[w.node] += force * (w.value / total);
    }
    true
}

/// Stage 3: traction forces λ h_s A_s N_i(x_s) at the start-of-step positions.
pub fn apply_tractions<const D: usize>(
    grid: Res<Grid<D>>,
    step: Res<LoadStep>,
    mut fields: ResMut<GridFields<D>>,
    mut status: ResMut<RunStatus>,
    mut clock: ResMut<StageClock>,
    mut scratch: Local<BasisScratch>,
    mut points: Query<&mut TractionPoint<D>>,
) {
    let _timer = clock.time(Stage::ExternalForce);
    let fields = &mut *fields;
    for mut point in points.iter_mut() {
        let point = &mut *point;
        let fail = |why| SolverError::TractionPoint {
            point: point.id,
            position: point.position.iter().copied().collect(),
            step: step.number,
            why,
        };
        if grid
            .0
            .eval(&point.position, &mut scratch, &mut point.support)
            .is_err()
        {
            status.fail(fail("left the background grid"));
            return;
        }
        let force = point.traction * (point.area * step.factor);
        if !spread_over_active(
            &force,
            &point.support,
            &fields.active,
            &mut fields.external_force,
        ) {
            status.fail(fail(
                "is not next to any material point (no grid node of its support is active); put tractions on a body's boundary",
            ));
            return;
        }
    }
}

/// Stage 5: traction points follow their host material point, x_s = x_p + F_p (X_s − X_p).
pub fn update_traction_points<const D: usize>(
    hosts: Query<(&Position<D>, &DeformationGradient<D>)>,
    mut points: Query<&mut TractionPoint<D>>,
) {
    for mut point in points.iter_mut() {
        if let Ok((x, f)) = hosts.get(point.host) {
            point.position = x.0 + f.0 * point.offset;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn weight(node: usize, value: f64) -> NodeWeight<1> {
        NodeWeight {
            node,
            value,
            gradient: SVector::zeros(),
        }
    }

    #[test]
    fn all_active_is_the_plain_quadrature_and_inactive_shares_go_to_active_nodes() {
        let support = [weight(0, 0.25), weight(1, 0.5), weight(2, 0.25)];
        let force = SVector::<f64, 1>::new(8.0);
        let mut external = vec![SVector::<f64, 1>::zeros(); 3];
        assert!(spread_over_active(
            &force,
            &support,
            &[true; 3],
            &mut external
        ));
        assert_eq!(external, [2.0, 4.0, 2.0].map(SVector::<f64, 1>::new));

        let mut external = vec![SVector::<f64, 1>::zeros(); 3];
        assert!(spread_over_active(
            &force,
            &support,
            &[true, true, false],
            &mut external
        ));
        // 0.25 : 0.5 of the force, resultant kept
        assert!((external[0][0] - 8.0 / 3.0).abs() < 1e-12);
        assert!((external[1][0] - 16.0 / 3.0).abs() < 1e-12);
        assert_eq!(external[2][0], 0.0);

        let mut external = vec![SVector::<f64, 1>::zeros(); 3];
        assert!(!spread_over_active(
            &force,
            &support,
            &[false; 3],
            &mut external
        ));
        assert!(external.iter().all(|f| f[0] == 0.0));
    }
}
