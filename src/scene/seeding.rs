//! Material-point seeding on the background grid (pure functions, no script state).
//!
//! Every grid cell holds a regular lattice of `ppc[a]` candidate points along each axis `a`, at
//! the cell-local coordinates `(i + 1/2) / ppc[a]`, `i = 0..ppc[a]`; a candidate becomes a
//! material point if it lies inside the body's region. Each point gets the reference volume
//! `cell volume / (ppc[0] * ... * ppc[D-1])`, so a region made of whole cells is integrated
//! exactly. Points are ordered by their global lattice index, axis 0 fastest.
//!
//! Boxes are seeded exactly instead ([`seed_box`]): in every cell the box overlaps, the
//! `ppc` points per axis are spread evenly over the overlap (cell-local coordinates
//! `(i + 1/2) / ppc` of the overlap) and share its volume. A box aligned with the grid gets
//! the lattice points; a box ending inside a cell (a column top at 50.001 on a unit grid)
//! keeps its exact volume, and a thin sliver of material in that cell gets points of tiny
//! volume — the hard case of nearly empty cells, which the solver stabilises.

use super::{GridSpec, PointSeed};

/// Points of the seeding lattice inside the region `inside(position)`.
///
/// `points_per_cell` has one entry per grid axis. The predicate may fail (a script error); the
/// first failure is returned.
pub fn seed_points<E>(
    grid: &GridSpec,
    points_per_cell: &[usize],
    mut inside: impl FnMut(&[f64]) -> Result<bool, E>,
) -> Result<Vec<PointSeed>, E> {
    let lattice = SeedLattice::new(grid, points_per_cell);
    let volume = lattice.point_volume();
    let ranges: Vec<(i64, i64)> = lattice.counts.iter().map(|&count| (0, count)).collect();
    let mut points = Vec::new();
    let mut position = vec![0.0; lattice.dim()];
    for_each_index(&ranges, |index| {
        lattice.position(index, &mut position);
        if inside(&position)? {
            points.push(PointSeed {
                position: position.clone(),
                volume,
            });
        }
        Ok(())
    })?;
    Ok(points)
}

/// Points of an axis-aligned box `[lower, upper]`, seeded exactly (module docs): cells in
/// order, axis 0 fastest, the points of a cell consecutive.
pub fn seed_box(
    grid: &GridSpec,
    points_per_cell: &[usize],
    lower: &[f64],
    upper: &[f64],
) -> Vec<PointSeed> {
    let dim = grid.dim();
    // Per axis: for each cell overlapping the box with positive length, the overlap interval.
    let overlaps: Vec<Vec<(f64, f64)>> = (0..dim)
        .map(|a| {
            let h = (grid.upper[a] - grid.lower[a]) / grid.cells[a] as f64;
            (0..grid.cells[a])
                .filter_map(|c| {
                    let (x0, x1) = (
                        grid.lower[a] + h * c as f64,
                        grid.lower[a] + h * (c + 1) as f64,
                    );
                    let (lo, hi) = (x0.max(lower[a]), x1.min(upper[a]));
                    (hi > lo).then_some((lo, hi))
                })
                .collect()
        })
        .collect();
    let ranges: Vec<(i64, i64)> = overlaps.iter().map(|o| (0, o.len() as i64)).collect();
    let mut points = Vec::new();
    let _ = for_each_index(&ranges, |cell| {
        let intervals: Vec<(f64, f64)> = (0..dim).map(|a| overlaps[a][cell[a] as usize]).collect();
        let volume: f64 = intervals
            .iter()
            .zip(points_per_cell)
            .map(|((lo, hi), &n)| (hi - lo) / n as f64)
            .product();
        let local: Vec<(i64, i64)> = points_per_cell.iter().map(|&n| (0, n as i64)).collect();
        for_each_index(&local, |k| {
            let position = (0..dim)
                .map(|a| {
                    let (lo, hi) = intervals[a];
                    lo + (hi - lo) * (k[a] as f64 + 0.5) / points_per_cell[a] as f64
                })
                .collect();
            points.push(PointSeed { position, volume });
            Ok::<(), ()>(())
        })
    });
    points
}

/// Checks that a region fits in the grid: probes the seeding lattice continued one cell beyond
/// the grid on every side and returns the first probe point outside the grid that the region
/// contains (`None` if there is none).
pub fn first_point_outside_grid<E>(
    grid: &GridSpec,
    points_per_cell: &[usize],
    mut inside: impl FnMut(&[f64]) -> Result<bool, E>,
) -> Result<Option<Vec<f64>>, E> {
    let lattice = SeedLattice::new(grid, points_per_cell);
    let ranges: Vec<(i64, i64)> = lattice
        .counts
        .iter()
        .zip(&lattice.points_per_cell)
        .map(|(&count, &ppc)| (-(ppc as i64), count + ppc as i64))
        .collect();
    let mut found = None;
    let mut position = vec![0.0; lattice.dim()];
    for_each_index(&ranges, |index| {
        if found.is_some() {
            return Ok(());
        }
        let in_grid = index
            .iter()
            .zip(&lattice.counts)
            .all(|(&i, &count)| (0..count).contains(&i));
        if in_grid {
            return Ok(());
        }
        lattice.position(index, &mut position);
        if inside(&position)? {
            found = Some(position.clone());
        }
        Ok(())
    })?;
    Ok(found)
}

/// The global lattice of candidate points: `counts[a] = cells[a] * ppc[a]` along axis `a`.
struct SeedLattice<'a> {
    grid: &'a GridSpec,
    points_per_cell: Vec<usize>,
    counts: Vec<i64>,
}

impl<'a> SeedLattice<'a> {
    fn new(grid: &'a GridSpec, points_per_cell: &[usize]) -> Self {
        let points_per_cell: Vec<usize> = (0..grid.dim())
            .map(|axis| points_per_cell.get(axis).copied().unwrap_or(1).max(1))
            .collect();
        let counts = grid
            .cells
            .iter()
            .zip(&points_per_cell)
            .map(|(&cells, &ppc)| (cells as i64).saturating_mul(ppc as i64))
            .collect();
        Self {
            grid,
            points_per_cell,
            counts,
        }
    }

    fn dim(&self) -> usize {
        self.grid.dim()
    }

    fn cell_size(&self, axis: usize) -> f64 {
        (self.grid.upper[axis] - self.grid.lower[axis]) / self.grid.cells[axis] as f64
    }

    fn point_volume(&self) -> f64 {
        (0..self.dim())
            .map(|axis| self.cell_size(axis) / self.points_per_cell[axis] as f64)
            .product()
    }

    /// Position of lattice point `index`: cell `c = floor(index / ppc)`, local `i = index mod ppc`,
    /// `x = lower + h * (c + (i + 1/2) / ppc)`.
    fn position(&self, index: &[i64], position: &mut [f64]) {
        for axis in 0..self.dim() {
            let ppc = self.points_per_cell[axis] as i64;
            let cell = index[axis].div_euclid(ppc) as f64;
            let local = index[axis].rem_euclid(ppc) as f64;
            position[axis] =
                self.grid.lower[axis] + self.cell_size(axis) * (cell + (local + 0.5) / ppc as f64);
        }
    }
}

/// Calls `visit` for every multi-index in the box `ranges[a].0 <= i[a] < ranges[a].1`, axis 0
/// fastest, stopping at the first error.
pub(super) fn for_each_index<E>(
    ranges: &[(i64, i64)],
    mut visit: impl FnMut(&[i64]) -> Result<(), E>,
) -> Result<(), E> {
    if ranges.iter().any(|(start, end)| start >= end) {
        return Ok(());
    }
    let mut index: Vec<i64> = ranges.iter().map(|(start, _)| *start).collect();
    loop {
        visit(&index)?;
        let mut axis = 0;
        loop {
            if axis == ranges.len() {
                return Ok(());
            }
            index[axis] += 1;
            if index[axis] < ranges[axis].1 {
                break;
            }
            index[axis] = ranges[axis].0;
            axis += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::BasisKind;
    use std::convert::Infallible;

    fn grid(lower: &[f64], upper: &[f64], cells: &[usize]) -> GridSpec {
        GridSpec {
            lower: lower.to_vec(),
            upper: upper.to_vec(),
            cells: cells.to_vec(),
            basis: BasisKind::Linear,
        }
    }

    fn everywhere(_: &[f64]) -> Result<bool, Infallible> {
        Ok(true)
    }

    #[test]
    fn one_dimensional_positions_and_volumes() {
        let points = seed_points(&grid(&[0.0], &[2.0], &[2]), &[2], everywhere).unwrap();
        let positions: Vec<f64> = points.iter().map(|point| point.position[0]).collect();
        assert_eq!(positions, [0.25, 0.75, 1.25, 1.75]);
        assert!(points.iter().all(|point| point.volume == 0.5));
    }

    #[test]
    fn three_dimensional_count_volume_and_order() {
        let grid = grid(&[0.0, 0.0, 0.0], &[1.0, 2.0, 3.0], &[2, 3, 4]);
        let points = seed_points(&grid, &[2, 3, 1], everywhere).unwrap();
        assert_eq!(points.len(), (2 * 2) * (3 * 3) * 4);
        let total: f64 = points.iter().map(|point| point.volume).sum();
        assert!((total - 6.0).abs() < 1e-12);
        // axis 0 fastest
        assert_eq!(points[0].position, [0.125, 1.0 / 9.0 * 2.0 / 2.0, 0.375]);
        assert!(points[1].position[0] > points[0].position[0]);
        assert_eq!(points[1].position[1], points[0].position[1]);
    }

    #[test]
    fn region_selects_points_and_errors_propagate() {
        let grid = grid(&[0.0, 0.0], &[4.0, 4.0], &[4, 4]);
        let disc =
            |x: &[f64]| Ok::<_, Infallible>((x[0] - 2.0).powi(2) + (x[1] - 2.0).powi(2) < 1.0);
        let points = seed_points(&grid, &[2, 2], disc).unwrap();
        assert!(!points.is_empty() && points.len() < 64);
        assert!(points.iter().all(|point| disc(&point.position).unwrap()));
        let failing = |x: &[f64]| if x[0] > 3.0 { Err("boom") } else { Ok(true) };
        assert_eq!(seed_points(&grid, &[1, 1], failing).unwrap_err(), "boom");
    }

    #[test]
    fn probe_finds_regions_leaking_out_of_the_grid() {
        let grid = grid(&[0.0, 0.0], &[4.0, 4.0], &[4, 4]);
        let inside_box =
            |x: &[f64]| Ok::<_, Infallible>(x.iter().all(|&c| (0.0..=4.0).contains(&c)));
        assert_eq!(
            first_point_outside_grid(&grid, &[2, 2], inside_box).unwrap(),
            None
        );
        let too_tall =
            |x: &[f64]| Ok::<_, Infallible>(x[1] < 4.5 && x[1] > 0.0 && x[0] > 0.0 && x[0] < 4.0);
        let leak = first_point_outside_grid(&grid, &[2, 2], too_tall)
            .unwrap()
            .unwrap();
        assert!(leak[1] > 4.0 && leak[1] < 4.5, "{leak:?}");
    }

    #[test]
    fn box_seeding_is_exact_in_volume_and_matches_the_lattice_when_aligned() {
        let grid = grid(&[0.0, 0.0], &[4.0, 3.0], &[4, 3]);
        // aligned: the same points as the lattice seeding of the region
        let mut exact = seed_box(&grid, &[2, 3], &[1.0, 0.0], &[3.0, 2.0]);
        let mut lattice = seed_points(&grid, &[2, 3], |x: &[f64]| {
            Ok::<_, ()>(x[0] >= 1.0 && x[0] <= 3.0 && x[1] <= 2.0)
        })
        .unwrap();
        let key = |p: &PointSeed| (p.position[1].to_bits(), p.position[0].to_bits());
        exact.sort_by_key(key);
        lattice.sort_by_key(key);
        assert_eq!(exact.len(), lattice.len());
        for (a, b) in exact.iter().zip(&lattice) {
            assert!((a.position[0] - b.position[0]).abs() < 1e-12);
            assert!((a.position[1] - b.position[1]).abs() < 1e-12);
            assert!((a.volume - b.volume).abs() < 1e-12);
        }
        // not aligned: exact volume, a sliver cell gets points of tiny volume inside the box
        let sliver = seed_box(&grid, &[2, 2], &[0.0, 0.0], &[4.0, 2.001]);
        let volume: f64 = sliver.iter().map(|p| p.volume).sum();
        assert!((volume - 4.0 * 2.001).abs() < 1e-12, "{volume}");
        let thin: Vec<_> = sliver.iter().filter(|p| p.position[1] > 2.0).collect();
        assert_eq!(thin.len(), 4 * 2 * 2);
        assert!(
            thin.iter()
                .all(|p| p.position[1] < 2.001 && (p.volume - 0.25 * 0.001).abs() < 1e-15)
        );
    }
}
