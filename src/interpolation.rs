//! Values at a position from values carried by scattered points around it: the weights of a
//! least-squares linear fit (used by `effects::probes` to read a displacement, stress or F at a
//! material reference position).
//!
//! With the points X_k (k = 1..n) around a position X₀ and values f_k, the fit
//! f(X) ≈ a + b · (X − X₀) minimises Σ_k (a + b · (X_k − X₀) − f_k)²; its value at X₀ is a.
//! With p_k = [1, (X_k − X₀)/r] (r scales the offsets, for conditioning) and the normal
//! matrix M = Σ_k p_k p_kᵀ,
//!
//! ```text
//!   a = Σ_k w_k f_k,    w_k = e₁ᵀ M⁻¹ p_k,
//! ```
//!
//! so the weights depend on the positions only and serve every field carried by the points.
//! They sum to one and reproduce linear fields exactly (Σ_k w_k (X_k − X₀) = 0): a homogeneous
//! deformation is read exactly. A field that is not linear over the points is read with an
//! error of the order of its second derivatives times the square of the points' spread (the
//! spread of the k nearest points is about a cell).
//!
//! Written by hand: a (D + 1) × (D + 1) normal system, solved with nalgebra's SVD so that
//! points on a line (2D) or a plane (3D), which do not determine a linear fit, are detected.

use nalgebra::{DMatrix, DVector};

/// The indices of the `count` points nearest to `at` (Euclidean distance), plus any point as
/// near as the last of them (a tie on a regular lattice keeps its symmetry), nearest first.
pub fn nearest_points(points: &[&[f64]], at: &[f64], count: usize) -> Vec<usize> {
    let distance = |x: &[f64]| -> f64 {
        x.iter()
            .zip(at)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt()
    };
    let mut order: Vec<(f64, usize)> = points
        .iter()
        .enumerate()
        .map(|(k, x)| (distance(x), k))
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let Some(&(last, _)) = order.get(count.max(1) - 1).or(order.last()) else {
        return Vec::new();
    };
    let tolerance = 1e-9 * last.max(f64::MIN_POSITIVE);
    order
        .into_iter()
        .take_while(|&(d, _)| d <= last + tolerance)
        .map(|(_, k)| k)
        .collect()
}

/// The weights w_k of the least-squares linear fit through `points` evaluated at `at` (module
/// docs); an error when the points do not determine a linear fit (fewer than D + 1, or all on
/// a line or plane).
pub fn linear_fit_weights(points: &[&[f64]], at: &[f64]) -> Result<Vec<f64>, String> {
    let dim = at.len();
    if points.len() < dim + 1 {
        return Err(format!(
            "{} point(s) do not determine a linear fit in {dim}D (at least {} are needed)",
            points.len(),
            dim + 1
        ));
    }
    let scale = points
        .iter()
        .flat_map(|x| x.iter().zip(at).map(|(a, b)| (a - b).abs()))
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let row = |x: &[f64]| -> DVector<f64> {
        DVector::from_iterator(
            dim + 1,
            std::iter::once(1.0).chain(x.iter().zip(at).map(|(a, b)| (a - b) / scale)),
        )
    };
    let mut normal = DMatrix::<f64>::zeros(dim + 1, dim + 1);
    for x in points {
        let p = row(x);
        normal += &p * p.transpose();
    }
    let svd = normal.clone().svd(true, true);
    let largest = svd.singular_values.max();
    let smallest = svd.singular_values.min();
    if smallest.is_nan() || smallest <= 1e-10 * largest {
        return Err(format!(
            "the {} points lie on a {} and do not determine a linear fit in {dim}D",
            points.len(),
            match dim {
                1 => "single position",
                2 => "line",
                _ => "line or plane",
            }
        ));
    }
    let inverse = svd
        .pseudo_inverse(0.0)
        .map_err(|e| format!("linear fit: {e}"))?;
    Ok(points
        .iter()
        .map(|x| (inverse.row(0) * row(x))[0])
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice() -> Vec<Vec<f64>> {
        let mut points = Vec::new();
        for i in 0..5 {
            for j in 0..4 {
                points.push(vec![0.1 + 0.25 * i as f64, 0.2 + 0.3 * j as f64]);
            }
        }
        points
    }

    #[test]
    fn the_fit_reproduces_a_linear_field_inside_and_outside_the_points() {
        let points = lattice();
        let field = |x: &[f64]| 3.0 - 2.0 * x[0] + 0.7 * x[1];
        for at in [[0.5, 0.6], [1.2, 1.1], [0.0, 0.0]] {
            let near = nearest_points(&points.iter().map(|p| &p[..]).collect::<Vec<_>>(), &at, 8);
            let chosen: Vec<&[f64]> = near.iter().map(|&k| &points[k][..]).collect();
            let w = linear_fit_weights(&chosen, &at).unwrap();
            let value: f64 = chosen.iter().zip(&w).map(|(x, w)| w * field(x)).sum();
            assert!((value - field(&at)).abs() < 1e-12, "{value} at {at:?}");
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn a_quadratic_field_is_read_with_an_error_that_shrinks_like_the_spread_squared() {
        let field = |x: &[f64]| x[0] * x[0] + x[0] * x[1];
        let at = [0.37, 0.41];
        let error = |h: f64| {
            let points: Vec<Vec<f64>> = (0..9)
                .map(|k| {
                    vec![
                        at[0] + h * (k % 3) as f64 - h,
                        at[1] + h * (k / 3) as f64 - 0.5 * h,
                    ]
                })
                .collect();
            let chosen: Vec<&[f64]> = points.iter().map(|p| &p[..]).collect();
            let w = linear_fit_weights(&chosen, &at).unwrap();
            let value: f64 = chosen.iter().zip(&w).map(|(x, w)| w * field(x)).sum();
            (value - field(&at)).abs()
        };
        let (coarse, fine) = (error(0.1), error(0.05));
        assert!(
            coarse > 1e-6,
            "a quadratic field is not read exactly: {coarse}"
        );
        assert!(
            (coarse / fine - 4.0).abs() < 1e-6,
            "ratio {}",
            coarse / fine
        );
    }

    #[test]
    fn ties_are_kept_and_degenerate_points_are_refused() {
        let points = [
            [0.0, 0.0],
            [1.0, 0.0],
            [0.0, 1.0],
            [-1.0, 0.0],
            [0.0, -1.0],
            [2.0, 2.0],
        ];
        let refs: Vec<&[f64]> = points.iter().map(|p| &p[..]).collect();
        assert_eq!(nearest_points(&refs, &[0.0, 0.0], 2), [0, 1, 2, 3, 4]);
        let line = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]];
        let refs: Vec<&[f64]> = line.iter().map(|p| &p[..]).collect();
        assert!(linear_fit_weights(&refs, &[0.5, 0.5]).is_err());
        assert!(linear_fit_weights(&refs[..2], &[0.5, 0.5]).is_err());
    }
}
