//! Analytic and semi-analytic reference solutions used to verify the solver.
//!
//! - [`SelfWeightColumn`]: the elastic column compressed by its own weight (paper section 3,
//!   eqs. 11-15): stress, stretch and deformed position along the column, and the paper's
//!   volume-weighted stress error measure generalised to any dimension.
//! - [`ThickCylinder`]: the compressible elasto-plastic thick-walled cylinder under internal
//!   pressure (plane strain, von Mises), a 1D radial finite-element reference driven by u(a),
//!   and the fully plastic wall's pressure at finite strain (the curve past the limit).

pub mod column;
pub mod cylinder;

pub use column::SelfWeightColumn;
pub use cylinder::{CylinderResponse, ThickCylinder};
