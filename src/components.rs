//! Entities and their components.
//!
//! The core's components; modules add their own (a material's `PointMaterial`, a point load,
//! a traction point, a GIMP domain, an FEM element... see `effects/` and `material/`).
//!
//! * A **material point** carries its reference state (`ReferencePosition`, `ReferenceVolume`,
//!   `Mass`, `BodyIndex`), its converged state at the start of the load step (`Position`,
//!   `Displacement`, `DeformationGradient`, `Volume`), the basis of the step (`Support`) and the
//!   state of the current Newton iterate (`Trial`).
//! * A **grid node** (a control point of the background basis) carries its index and position
//!   (`GridNode`). The fields that live on the grid during a load step (displacement increment,
//!   forces, constrained components, DOF numbers) are vectors in `GridFields`, indexed by
//!   node, because every stage gathers and scatters them by node index; they are paged
//!   (`node_storage::NodeVec`: memory for the pages of nodes written), so a decomposed run's
//!   process holds its own nodes' only. The `GridNode` entities are the whole grid's on every
//!   process.

use bevy_ecs::prelude::*;
use nalgebra::{SMatrix, SVector};

use crate::basis::NodeWeight;
use crate::distributed::migration::PointRecord;
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

/// Index of the body the point belongs to (into the scene's bodies).
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct BodyIndex(pub u32);

/// The grid functions supporting the point in this load step: nodes, values N_i(x_p^n) and
/// gradients ∇_n N_i(x_p^n), evaluated once at the start of the step.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct Support<const D: usize>(pub Vec<NodeWeight<D>>);

/// The point's state at the current Newton iterate (stress, tangent, F).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Trial<const D: usize>(pub TrialState<D>);

/// A grid node (control point): global index (axis 0 fastest) and position.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct GridNode<const D: usize> {
    pub index: usize,
    pub position: SVector<f64, D>,
}

/// The increment of deformation the point's material sees in the current Newton iterate when
/// it is not the point's own `Δf = I + Σ Δu_i ⊗ ∇_n N_i`: set by a module at `Hook::Kinematics`
/// (F-bar averages the volume change over the points of a cell). The stress update then
/// evaluates the material at `F = Δf̃ F^n` with `Δf̃` this increment, while the spatial
/// gradients `g = Δf⁻ᵀ ∇_n N` stay those of the point's own `Δf`
/// (`mechanics::trial_state_with_modified_increment`); the G2P update stores that `F` as the
/// point's. A module that sets it adds the tangent terms the modification brings (at
/// `Hook::AfterAssembly`).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ModifiedIncrement<const D: usize>(pub SMatrix<f64, D, D>);

/// A point this process holds but another process assembles (a distributed run, where each
/// process assembles the points of its block of cells): the core's assembly leaves it out.
/// Sparse-set storage, so that marking points does not move them between tables (the order
/// in which the other stages and the output visit points stays that of a serial run).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[component(storage = "SparseSet")]
pub struct AssembledElsewhere;

/// The core's components of a material point, as one bundle ([`core_point`]).
pub type CorePoint<const D: usize> = (
    (PointId, Position<D>, ReferencePosition<D>, Displacement<D>),
    (DeformationGradient<D>, Mass),
    (ReferenceVolume, Volume, BodyIndex),
    (Support<D>, Trial<D>),
);

/// A material point's core components in the state `point` describes (its `history`, the
/// modules' part, is not read: `checkpoint::unpack_point_state` gives it back). The stress is
/// that of no deformation until the next stress update recomputes it from `F` and the history.
pub fn core_point<const D: usize>(point: &PointRecord<D>) -> CorePoint<D> {
    (
        (
            PointId(point.id),
            Position(point.position),
            ReferencePosition(point.reference_position),
            Displacement(point.displacement),
        ),
        (
            DeformationGradient(point.deformation_gradient),
            Mass(point.mass),
        ),
        (
            ReferenceVolume(point.reference_volume),
            Volume(point.volume),
            BodyIndex(point.body),
        ),
        (
            Support::<D>::default(),
            Trial(TrialState::<D>::unstressed()),
        ),
    )
}
