//! Analytic and semi-analytic reference solutions used to verify the solver.
//!
//! - [`SelfWeightColumn`]: the elastic column compressed by its own weight (paper section 3,
//!   eqs. 11-15): stress, stretch and deformed position along the column, and the paper's
//!   volume-weighted stress error measure generalised to any dimension.

pub mod column;

pub use column::SelfWeightColumn;
