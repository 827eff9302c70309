//! Why the weights of a point's domain cannot be evaluated: shared by the domain kernels
//! (`gimp`, `averaged`, `cpdi`) and their dispatcher (`domain`).

use std::fmt;

use super::axis::OutsideGrid;

/// Why a point's domain weights could not be evaluated.
#[derive(Clone, Debug, PartialEq)]
pub enum DomainError {
    /// The point itself is outside the grid.
    Outside(OutsideGrid),
    /// A corner of the point's CPDI domain is outside the grid (beyond round-off).
    CornerOutside { corner: Vec<f64>, axis: usize },
    /// The domain is inverted or degenerate.
    Degenerate(String),
}

impl fmt::Display for DomainError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DomainError::Outside(outside) => write!(f, "{outside}"),
            DomainError::CornerOutside { corner, axis } => write!(
                f,
                "the corner {corner:?} of its CPDI domain is outside the background grid along \
                 axis {axis}; the grid must contain the points' domains (enlarge it)"
            ),
            DomainError::Degenerate(why) => f.write_str(why),
        }
    }
}

impl std::error::Error for DomainError {}
