//! Constitutive models: stress from deformation, and its linearisation for the Newton solver.
//!
//! The finite-deformation framework follows the paper (eqs. 2-3): with the deformation gradient
//! `F = dx/dX` and the left Cauchy-Green tensor `b = F F^T = V^2`, the logarithmic strain is
//! `eps = ln V = 1/2 ln b`, and the Kirchhoff stress `tau = J sigma` is a linear isotropic function
//! of `eps` ([`Hencky`]).
//!
//! Every kernel here works on a full 3x3 `b` whatever the dimension `D` of the analysis (plane
//! strain and uniaxial strain simply pass a `b` whose out-of-plane block is the identity), so one
//! model serves 1D, 2D and 3D. The tangent is returned only for the `D` in-plane indices, as a
//! [`Tangent<D>`].
//!
//! Kernels take plain `nalgebra` arguments and never panic: invalid input (a `b` that is not
//! positive definite, or non-finite) gives `Err` from the `try_` variants and NaN-filled results
//! from the unchecked ones.

pub mod hencky;

pub use hencky::{Hencky, Tangent};
