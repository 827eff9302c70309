//! Entities and their components.
//!
//! * A **material point** carries its reference state (`ReferencePosition`, `ReferenceVolume`,
//!   `Mass`, `Elastic`), its converged state at the start of the load step (`Position`,
//!   `Displacement`, `DeformationGradient`, `Volume`), the basis of the step (`Support`) and the
//!   state of the current Newton iterate (`Trial`); with GIMP or CPDI also its initial domain
//!   (`ParticleDomain`).
//! * A **grid node** (a control point of the background basis) carries its index and position
//!   (`GridNode`) and its constraints (`Fixity`). The fields that live on the grid during a load
//!   step (displacement increment, forces, DOF numbers) are dense arrays in `GridFields`, indexed
//!   by node, because every stage gathers and scatters them by node index.
//! * With linear FEM (`basis = "fem"`) the points are integration points and also carry their
//!   element and parent coordinates (`ElementPoint`); the nodes are the mesh nodes, and
//!   `GridNode::position` is their current position (they move with the body).

use bevy_ecs::prelude::*;
use nalgebra::{Matrix3, SMatrix, SVector};

use crate::basis::NodeWeight;
use crate::material::Hencky;
use crate::mechanics::TrialState;

/// Stable index of a material point (its order in the scene and in the output).
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct PointId(pub u32);

/// Current position x_p (converged, start of the load step).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Position<const D: usize>(pub SVector<f64, D>);

/// Reference position X_p.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ReferencePosition<const D: usize>(pub SVector<f64, D>);

/// Total displacement u_p = x_p - X_p.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Displacement<const D: usize>(pub SVector<f64, D>);

/// Converged deformation gradient F^n.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct DeformationGradient<const D: usize>(pub SMatrix<f64, D, D>);

/// Point mass m_p = rho0 V0_p.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Mass(pub f64);

/// Reference volume V0_p.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ReferenceVolume(pub f64);

/// Current volume V_p = J V0_p.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Volume(pub f64);

/// The point's material: Hencky elasticity.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Elastic(pub Hencky);

/// Index of the body the point belongs to (into the scene's bodies).
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct BodyIndex(pub u32);

/// The grid functions supporting the point in this load step: nodes, values N_i(x_p^n) and
/// gradients ∇_n N_i(x_p^n), evaluated once at the start of the step.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct Support<const D: usize>(pub Vec<NodeWeight<D>>);

/// The initial domain of a material point, for the methods whose weights average the grid
/// functions over it (GIMP, CPDI, B-splines with `integration: "domain"`; `basis::domain`):
/// the half-lengths `lp0_k` of the box the point owns at seeding (`h_k / (2 ppc_k)` on the
/// lattice; its share of the overlap where a box region cuts a cell). Spawned only for those
/// methods.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ParticleDomain<const D: usize> {
    pub initial_half_lengths: SVector<f64, D>,
}

/// The point's state at the current Newton iterate (stress, tangent, F).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Trial<const D: usize>(pub TrialState<D>);

/// A force on the material point at load factor 1 (`point_load` in scenes); only points that
/// carry one have this component.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct PointLoad<const D: usize>(pub SVector<f64, D>);

/// A traction point: a quadrature point of the surface term ∫_ΓN h N_i dΓ of paper eq. (9),
/// an entity of its own (not a material point). It carries a piece of boundary of reference
/// area `area` with the traction `traction` (force per unit reference area at load factor 1,
/// fixed direction: a dead load), and moves with the material: it keeps its reference offset
/// from a host material point, deformed with the host's F (x_s = x_p + F_p (X_s − X_p)).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct TractionPoint<const D: usize> {
    /// Index among the scene's traction points (output order).
    pub id: u32,
    /// Current position (converged, start of the load step).
    pub position: SVector<f64, D>,
    pub reference_position: SVector<f64, D>,
    /// The host material point (the nearest one in the reference configuration).
    pub host: Entity,
    /// X_s − X_p: the reference offset from the host.
    pub offset: SVector<f64, D>,
    pub area: f64,
    pub traction: SVector<f64, D>,
    /// The basis at `position` for this load step.
    pub support: Vec<NodeWeight<D>>,
}

/// Stress recovered by moving least squares from the neighbouring points' Cauchy stresses
/// (3x3, as `TrialState::cauchy`). Present only when the scene asks for stress recovery; see
/// [`crate::recovery`] and `stages/recovery.rs`.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct RecoveredStress(pub Matrix3<f64>);

/// A grid node (control point): global index (axis 0 fastest) and position.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct GridNode<const D: usize> {
    pub index: usize,
    pub position: SVector<f64, D>,
}

/// Constraints of a node: which displacement components are prescribed, and the prescribed
/// total displacement at load factor 1 (zero for a plain fixity).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Fixity<const D: usize> {
    pub fixed: [bool; D],
    pub prescribed: SVector<f64, D>,
}

impl<const D: usize> Default for Fixity<D> {
    fn default() -> Self {
        Self {
            fixed: [false; D],
            prescribed: SVector::zeros(),
        }
    }
}

/// Linear FEM only: the element an integration point belongs to and its parent coordinates
/// ξ in `[-1, 1]^D`, both fixed for the whole run (see `fem`).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ElementPoint<const D: usize> {
    pub element: usize,
    pub xi: SVector<f64, D>,
}
