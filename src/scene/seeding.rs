//! Material-point seeding on the background grid (pure functions, no script state).
//!
//! Every grid cell holds a regular lattice of `ppc[a]` candidate points along each axis `a`, at
//! the cell-local coordinates `(i + 1/2) / ppc[a]`, `i = 0..ppc[a]`; a candidate becomes a
//! material point if it lies inside the body's region. Each point gets the reference volume
//! `cell volume / (ppc[0] * ... * ppc[D-1])`, so a region made of whole cells is integrated
//! exactly. Points are ordered by their global lattice index, axis 0 fastest.

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

/// Quadrature points of a flat piece of boundary given by `dim` corners (the grid's dimension):
///
/// * 1D: one corner, the end of the bar: one point of area 1 (the bar's unit cross-section);
/// * 2D: a segment from `corners[0]` to `corners[1]`;
/// * 3D: the parallelogram with corner `corners[0]` and edges `corners[1] − corners[0]` and
///   `corners[2] − corners[0]`.
///
/// Each edge e is split into `n = max(1, ceil(per_cell · max_a |e_a| / h_a))` equal parts (h_a =
/// cell size along axis a), so there are about `per_cell` points per cell crossed; the points
/// sit at the part midpoints and carry the part's area (midpoint rule: the areas sum exactly to
/// the segment length / parallelogram area). Returns `(position, area)` pairs, first edge
/// fastest, or `Err(count)` if there would be more than `max_points`.
pub fn seed_boundary(
    grid: &GridSpec,
    corners: &[Vec<f64>],
    per_cell: usize,
    max_points: usize,
) -> Result<Vec<(Vec<f64>, f64)>, usize> {
    let dim = grid.dim();
    let origin = &corners[0];
    let edges: Vec<Vec<f64>> = corners[1..]
        .iter()
        .map(|corner| corner.iter().zip(origin).map(|(c, o)| c - o).collect())
        .collect();
    let parts: Vec<usize> = edges
        .iter()
        .map(|edge| {
            let cells_crossed = (0..dim)
                .map(|axis| {
                    edge[axis].abs() * grid.cells[axis] as f64
                        / (grid.upper[axis] - grid.lower[axis])
                })
                .fold(0.0, f64::max);
            ((per_cell.max(1) as f64 * cells_crossed).ceil() as usize).max(1)
        })
        .collect();
    let area = match edges.len() {
        0 => 1.0,
        1 => norm(&edges[0]),
        _ => {
            let (a, b) = (&edges[0], &edges[1]);
            let cross = [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ];
            norm(&cross)
        }
    };
    let count = parts
        .iter()
        .try_fold(1usize, |count, &n| count.checked_mul(n))
        .unwrap_or(usize::MAX);
    if count > max_points {
        return Err(count);
    }
    let piece = area / count as f64;
    let ranges: Vec<(i64, i64)> = parts.iter().map(|&n| (0, n as i64)).collect();
    let mut points = Vec::with_capacity(count);
    let _ = for_each_index::<std::convert::Infallible>(&ranges, |index| {
        let mut position = origin.clone();
        for (edge, (&i, &n)) in edges.iter().zip(index.iter().zip(&parts)) {
            let t = (i as f64 + 0.5) / n as f64;
            for (x, e) in position.iter_mut().zip(edge) {
                *x += t * e;
            }
        }
        points.push((position, piece));
        Ok(())
    });
    Ok(points)
}

/// For every query position, the index of the nearest of `points` (Euclidean distance, the
/// lowest index among equals), or `None` if `points` is empty.
///
/// The points are bucketed by grid cell; the search visits shells of cells at Chebyshev
/// distance r = 0, 1, 2, ... around the query's cell and stops after shell r once the best
/// distance is at most r · (smallest cell size), since every point in a farther shell is at
/// least that far away.
pub fn nearest_points(
    grid: &GridSpec,
    points: &[&[f64]],
    queries: &[Vec<f64>],
) -> Vec<Option<usize>> {
    use std::collections::HashMap;
    let dim = grid.dim();
    let size: Vec<f64> = (0..dim)
        .map(|axis| (grid.upper[axis] - grid.lower[axis]) / grid.cells[axis] as f64)
        .collect();
    let smallest = size.iter().copied().fold(f64::INFINITY, f64::min);
    let cell_of = |x: &[f64]| -> Vec<i64> {
        (0..dim)
            .map(|axis| ((x[axis] - grid.lower[axis]) / size[axis]).floor() as i64)
            .collect()
    };
    let mut buckets: HashMap<Vec<i64>, Vec<usize>> = HashMap::new();
    for (index, point) in points.iter().enumerate() {
        buckets.entry(cell_of(point)).or_default().push(index);
    }
    let widest = grid.cells.iter().max().copied().unwrap_or(1) as i64 + 2;
    queries
        .iter()
        .map(|query| {
            if points.is_empty() {
                return None;
            }
            let centre = cell_of(query);
            let mut best: Option<(f64, usize)> = None;
            for r in 0..=widest {
                let ranges: Vec<(i64, i64)> = centre.iter().map(|&c| (c - r, c + r + 1)).collect();
                let _ = for_each_index::<std::convert::Infallible>(&ranges, |cell| {
                    let on_shell = cell.iter().zip(&centre).any(|(&c, &m)| (c - m).abs() == r);
                    if !on_shell {
                        return Ok(());
                    }
                    for &index in buckets.get(cell).map_or(&[][..], Vec::as_slice) {
                        let d = norm(
                            &points[index]
                                .iter()
                                .zip(query)
                                .map(|(a, b)| a - b)
                                .collect::<Vec<_>>(),
                        );
                        if best.is_none_or(|(bd, bi)| d < bd || (d == bd && index < bi)) {
                            best = Some((d, index));
                        }
                    }
                    Ok(())
                });
                if best.is_some_and(|(d, _)| d <= r as f64 * smallest) {
                    break;
                }
            }
            best.map(|(_, index)| index)
        })
        .collect()
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
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
fn for_each_index<E>(
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
    fn boundary_points_split_segments_and_parallelograms_by_the_cell_size() {
        // 1D: the end point, unit area
        let points = seed_boundary(&grid(&[0.0], &[2.0], &[4]), &[vec![2.0]], 3, 10).unwrap();
        assert_eq!(points, [(vec![2.0], 1.0)]);
        // 2D: a slanted segment crossing 2 cells along x and 1 along y, 2 per cell -> 4 parts
        let g = grid(&[0.0, 0.0], &[4.0, 4.0], &[4, 4]);
        let points = seed_boundary(&g, &[vec![1.0, 1.0], vec![3.0, 2.0]], 2, 10).unwrap();
        assert_eq!(points.len(), 4);
        let length: f64 = points.iter().map(|(_, a)| a).sum();
        assert!((length - 5f64.sqrt()).abs() < 1e-12);
        assert_eq!(points[0].0, [1.25, 1.125]);
        assert_eq!(points[3].0, [2.75, 1.875]);
        // 3D: a 2 x 1 rectangle in the plane z = 1 with 1 point per cell of size 0.5
        let g = grid(&[0.0, 0.0, 0.0], &[2.0, 2.0, 2.0], &[4, 4, 4]);
        let corners = [
            vec![0.0, 0.0, 1.0],
            vec![2.0, 0.0, 1.0],
            vec![0.0, 1.0, 1.0],
        ];
        let points = seed_boundary(&g, &corners, 1, 8).unwrap();
        assert_eq!(seed_boundary(&g, &corners, 1, 7), Err(8));
        assert_eq!(points.len(), 4 * 2);
        assert!(points.iter().all(|(x, a)| x[2] == 1.0 && *a == 0.25));
        assert_eq!(points[1].0, [0.75, 0.25, 1.0]);
        assert_eq!(points[4].0, [0.25, 0.75, 1.0]);
    }

    #[test]
    fn nearest_points_match_a_brute_force_search() {
        let g = grid(&[0.0, 0.0], &[8.0, 8.0], &[8, 8]);
        // a sparse, irregular cloud: the nearest point is often several cells away
        let cloud: Vec<Vec<f64>> = (0..40)
            .map(|k| {
                let t = k as f64;
                vec![(t * 1.37).rem_euclid(8.0), (t * t * 0.61).rem_euclid(3.0)]
            })
            .collect();
        let points: Vec<&[f64]> = cloud.iter().map(Vec::as_slice).collect();
        let queries: Vec<Vec<f64>> = (0..50)
            .map(|k| {
                vec![
                    (k as f64 * 0.83).rem_euclid(8.0),
                    (k as f64 * 0.157).rem_euclid(8.0),
                ]
            })
            .collect();
        let found = nearest_points(&g, &points, &queries);
        for (query, found) in queries.iter().zip(found) {
            let distance = |i: usize| {
                ((points[i][0] - query[0]).powi(2) + (points[i][1] - query[1]).powi(2)).sqrt()
            };
            let brute = (0..points.len())
                .min_by(|&a, &b| distance(a).total_cmp(&distance(b)))
                .unwrap();
            assert_eq!(distance(found.unwrap()), distance(brute), "{query:?}");
        }
        assert_eq!(nearest_points(&g, &[], &queries[..1]), [None]);
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
}
