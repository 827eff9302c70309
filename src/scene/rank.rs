//! A warning for scenes whose tangent stiffness is rank deficient because the material points
//! are too few for the basis across some direction.
//!
//! Along an axis, the points of a body sit at `k` distinct coordinates spanning `m` cells; a
//! B-spline basis of order `q` has `m + q` functions across those cells (linear hats: `m + 1`).
//! The stiffness is an integral sampled at the points: with fewer sampling coordinates than
//! functions (less one, for a support fixing one of them) the variation of the displacement
//! across the axis is not seen by any point, and the tangent is singular. The typical case is a
//! one-cell-wide column of cubic splines with 2 points per cell across: 4 functions, 2 points.
//! The cure is `ppc ≥ (cells + order) / cells` across the axis, or a lower order.

use crate::basis::BasisKind;

use super::{BodySpec, SceneSpec};

/// One warning per body and axis with too few points for the basis (see the module docs).
pub fn rank_warnings(spec: &SceneSpec) -> Vec<String> {
    let extra = match spec.grid.basis {
        BasisKind::BSpline { order } | BasisKind::BSplineDomain { order } => order,
        BasisKind::Linear => 1,
        _ => return Vec::new(),
    };
    let mut warnings = Vec::new();
    for body in &spec.bodies {
        for axis in 0..spec.grid.dim() {
            let Some((distinct, cells)) = points_across(spec, body, axis) else {
                continue;
            };
            let functions = cells + extra;
            if distinct + 1 < functions {
                warnings.push(format!(
                    "body '{}': along axis {axis} its points sit at {distinct} distinct coordinates across {cells} cell(s), where the {} basis has {functions} functions: the tangent stiffness is rank deficient (singular or nearly so) and the run will likely fail; use ppc >= {} along axis {axis} (points x cells >= cells + order - 1), or a lower order",
                    body.name,
                    spec.grid.basis,
                    (functions - 1).div_ceil(cells)
                ));
            }
        }
    }
    warnings
}

/// Along `axis`, the number of distinct coordinates the body's points sit at and the number of
/// grid cells they span (points per cell along the axis: their ratio); `None` for a body
/// without points or a degenerate grid.
pub fn points_across(spec: &SceneSpec, body: &BodySpec, axis: usize) -> Option<(usize, usize)> {
    let grid = &spec.grid;
    let h = (grid.upper[axis] - grid.lower[axis]) / grid.cells[axis] as f64;
    let mut coordinates: Vec<f64> = body
        .points
        .iter()
        .filter_map(|p| p.position.get(axis).copied())
        .collect();
    if coordinates.is_empty() || h.is_nan() || h <= 0.0 {
        return None;
    }
    coordinates.sort_by(f64::total_cmp);
    coordinates.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * h);
    let cell =
        |x: f64| (((x - grid.lower[axis]) / h).floor().max(0.0) as usize).min(grid.cells[axis] - 1);
    let first = cell(coordinates[0]);
    let last = cell(coordinates[coordinates.len() - 1]);
    Some((coordinates.len(), last - first + 1))
}
