//! Seeding for linear FEM (`basis = "fem"`): the integration points of the body-fitted mesh
//! (pure functions, no script state).
//!
//! A grid cell is an element when the body's region holds at every probe of the cell: its
//! centre, the 2^D points near its corners (parent coordinates ±(1 - 10⁻⁶)) and its Gauss
//! points. A cell where the region holds at none of them is not part of the body; a cell where
//! it holds at some but not all is covered only partly, which FEM cannot represent (it needs a
//! body-fitted mesh): that is an error naming the cell. Features of a region smaller than a
//! cell that miss every probe (a hole inside one cell) are not detected.
//!
//! Every element gets the tensor-product Gauss–Legendre rule with `gauss_points[k]` points
//! along axis k (see `crate::quadrature`): point `x_k = lower_k + h_k (c_k + (1 + ξ_k) / 2)` and
//! volume `w Π_k h_k / 2` (the weight times the reference Jacobian). Points are ordered cell by
//! cell (axis 0 fastest), and within a cell by Gauss point (axis 0 fastest), so the points of
//! one element are consecutive.

use super::seeding::for_each_index;
use super::{GridSpec, PointSeed};
use crate::quadrature::gauss_legendre;

/// Parent coordinate of the probes near the corners of a cell.
const NEAR_CORNER: f64 = 1.0 - 1e-6;

/// A grid cell the region covers only partly.
#[derive(Clone, Debug, PartialEq)]
pub struct PartialCell {
    /// Cell multi-index.
    pub cell: Vec<usize>,
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

impl PartialCell {
    pub fn message(&self) -> String {
        format!(
            "basis \"fem\" needs a body-fitted mesh, but the region covers grid cell {:?} (from {:?} to {:?}) only partly; make the region a union of whole grid cells",
            self.cell, self.lower, self.upper
        )
    }
}

/// The integration points of the cells the region `inside(position)` covers, with
/// `gauss_points[k]` Gauss points along axis k; `Ok(Err(..))` for the first cell it covers
/// only partly. The predicate may fail (a script error); the first failure is returned.
pub fn seed_element_points<E>(
    grid: &GridSpec,
    gauss_points: &[usize],
    mut inside: impl FnMut(&[f64]) -> Result<bool, E>,
) -> Result<Result<Vec<PointSeed>, PartialCell>, E> {
    let dim = grid.dim();
    let spacing: Vec<f64> = (0..dim)
        .map(|k| (grid.upper[k] - grid.lower[k]) / grid.cells[k] as f64)
        .collect();
    let rules: Vec<(Vec<f64>, Vec<f64>)> = (0..dim)
        .map(|k| gauss_legendre(gauss_points.get(k).copied().unwrap_or(1).max(1)))
        .collect();
    let rule_ranges: Vec<(i64, i64)> = rules.iter().map(|(p, _)| (0, p.len() as i64)).collect();
    // (ξ, weight, half the point's share of the cell per axis: w_k h_k / 4, as w sums to 2)
    let mut gauss: Vec<(Vec<f64>, f64, Vec<f64>)> = Vec::new();
    for_each_index(&rule_ranges, |g| {
        let xi = (0..dim).map(|k| rules[k].0[g[k] as usize]).collect();
        let weight: f64 = (0..dim).map(|k| rules[k].1[g[k] as usize]).product();
        let half_lengths = (0..dim)
            .map(|k| 0.25 * rules[k].1[g[k] as usize] * spacing[k])
            .collect();
        gauss.push((xi, weight, half_lengths));
        Ok::<_, E>(())
    })?;
    let jacobian: f64 = spacing.iter().map(|h| h / 2.0).product();
    let mut probes: Vec<Vec<f64>> = vec![vec![0.0; dim]];
    probes.extend((0..1usize << dim).map(|corner| {
        (0..dim)
            .map(|k| {
                if (corner >> k) & 1 == 1 {
                    NEAR_CORNER
                } else {
                    -NEAR_CORNER
                }
            })
            .collect()
    }));
    probes.extend(gauss.iter().map(|(xi, _, _)| xi.clone()));

    let cell_ranges: Vec<(i64, i64)> = grid.cells.iter().map(|&c| (0, c as i64)).collect();
    let mut points = Vec::new();
    let mut partial = None;
    let mut position = vec![0.0; dim];
    for_each_index(&cell_ranges, |cell| {
        if partial.is_some() {
            return Ok(());
        }
        let place = |xi: &[f64], position: &mut [f64]| {
            for k in 0..dim {
                position[k] = grid.lower[k] + spacing[k] * (cell[k] as f64 + 0.5 * (1.0 + xi[k]));
            }
        };
        let mut covered = 0;
        for xi in &probes {
            place(xi, &mut position);
            if inside(&position)? {
                covered += 1;
            }
        }
        if covered == probes.len() {
            for (xi, weight, half_lengths) in &gauss {
                place(xi, &mut position);
                points.push(PointSeed {
                    position: position.clone(),
                    volume: weight * jacobian,
                    half_lengths: half_lengths.clone(),
                });
            }
        } else if covered > 0 {
            let corner = |offset: f64| -> Vec<f64> {
                (0..dim)
                    .map(|k| grid.lower[k] + spacing[k] * (cell[k] as f64 + offset))
                    .collect()
            };
            partial = Some(PartialCell {
                cell: cell.iter().map(|&c| c as usize).collect(),
                lower: corner(0.0),
                upper: corner(1.0),
            });
        }
        Ok(())
    })?;
    Ok(match partial {
        Some(cell) => Err(cell),
        None => Ok(points),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::BasisKind;
    use std::convert::Infallible;

    fn grid(lower: &[f64], upper: &[f64], cells: &[usize]) -> GridSpec {
        crate::scene::seeding::tests::grid_of(lower, upper, cells, BasisKind::Fem)
    }

    fn in_box(lower: &[f64], upper: &[f64]) -> impl Fn(&[f64]) -> Result<bool, Infallible> {
        let (lower, upper) = (lower.to_vec(), upper.to_vec());
        move |x| {
            Ok(x.iter()
                .zip(lower.iter().zip(&upper))
                .all(|(&c, (&lo, &hi))| lo <= c && c <= hi))
        }
    }

    #[test]
    fn one_point_per_element_at_the_centres() {
        let g = grid(&[0.0], &[2.0], &[4]);
        let points = seed_element_points(&g, &[1], in_box(&[0.0], &[2.0]))
            .unwrap()
            .unwrap();
        let x: Vec<f64> = points.iter().map(|p| p.position[0]).collect();
        assert_eq!(x, [0.25, 0.75, 1.25, 1.75]);
        assert!(points.iter().all(|p| p.volume == 0.5));
    }

    #[test]
    fn gauss_points_of_the_covered_cells_integrate_their_volume() {
        // the box covers cells x in [1, 3], y in [0, 1] of a 4x2 grid of 0.5 x 0.5 cells
        let g = grid(&[0.0, 0.0], &[2.0, 1.0], &[4, 2]);
        let points = seed_element_points(&g, &[2, 3], in_box(&[0.5, 0.0], &[1.5, 1.0]))
            .unwrap()
            .unwrap();
        assert_eq!(points.len(), 4 * 6);
        let volume: f64 = points.iter().map(|p| p.volume).sum();
        assert!((volume - 1.0).abs() < 1e-14);
        // first element: cell (1, 0), Gauss points axis 0 fastest
        let a = 0.25 / 3f64.sqrt();
        assert!((points[0].position[0] - (0.75 - a)).abs() < 1e-15);
        assert!((points[1].position[0] - (0.75 + a)).abs() < 1e-15);
        assert_eq!(points[0].position[1], points[1].position[1]);
        // ∫ x dV over the covered region [0.5, 1.5] x [0, 1] is exact
        let moment: f64 = points.iter().map(|p| p.volume * p.position[0]).sum();
        assert!((moment - 1.0).abs() < 1e-14);
    }

    #[test]
    fn partly_covered_cells_are_reported() {
        let g = grid(&[0.0, 0.0], &[2.0, 2.0], &[2, 2]);
        let partial = seed_element_points(&g, &[1, 1], in_box(&[0.0, 0.0], &[2.0, 1.5]))
            .unwrap()
            .unwrap_err();
        assert_eq!(partial.cell, [0, 1]);
        assert_eq!(
            (partial.lower.clone(), partial.upper.clone()),
            (vec![0.0, 1.0], vec![1.0, 2.0])
        );
        assert!(partial.message().contains("body-fitted mesh"));
        // a region boundary close to a cell face is still caught near the corners
        let g1 = grid(&[0.0], &[10.0], &[10]);
        let near = seed_element_points(&g1, &[2], in_box(&[0.0], &[9.99]));
        assert_eq!(near.unwrap().unwrap_err().cell, [9]);
        // strict inequalities on the faces are fine
        let strict = |x: &[f64]| Ok::<_, Infallible>(x[0] > 0.0 && x[0] < 4.0);
        assert_eq!(
            seed_element_points(&g1, &[2], strict)
                .unwrap()
                .unwrap()
                .len(),
            8
        );
        // predicate errors propagate
        let failing = |_: &[f64]| Err::<bool, _>("boom");
        assert_eq!(seed_element_points(&g1, &[1], failing).unwrap_err(), "boom");
    }
}
