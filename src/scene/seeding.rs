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
//!
//! With [`Placement::Gauss`] the `ppc[a]` points of a cell sit at the Gauss–Legendre points of
//! the cell along each axis instead, and each point's volume is the cell volume times the
//! product of its Gauss weights (on `[0, 1]`, summing to 1).
//!
//! Every point also gets the box it owns (`PointSeed::half_lengths`, the initial particle
//! domain of GIMP and CPDI): its share of the cell (or of the overlap) along each axis, centred
//! on it. With the uniform placement the boxes tile the body; with the Gauss placement they
//! have the right volumes but, centred on points that are not at the centres of their shares,
//! overlap a little and leave small gaps. The points then integrate every
//! polynomial of degree `2 ppc − 1` per cell exactly in the reference configuration (the
//! regular lattice, a composite midpoint rule, only degree 1), which removes most of the
//! integration error in the cells next to a boundary, where the B-spline functions are not
//! the shifted copies of each other whose errors cancel (see `docs/results.md`).

use super::{GridSpec, MAX_SEED_CANDIDATES, PointSeed};
use crate::quadrature::gauss_legendre_unit;

/// Where the points of a cell are placed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Placement {
    /// Regular lattice at cell-local `(i + 1/2) / ppc`, equal volumes.
    #[default]
    Uniform,
    /// Gauss–Legendre points of the cell, volumes from the Gauss weights.
    Gauss,
}

/// Points of the seeding lattice inside the region `inside(position)`.
///
/// `points_per_cell` has one entry per grid axis. The predicate may fail (a script error); the
/// first failure is returned.
pub fn seed_points<E>(
    grid: &GridSpec,
    points_per_cell: &[usize],
    inside: impl FnMut(&[f64]) -> Result<bool, E>,
) -> Result<Vec<PointSeed>, E> {
    seed_points_placed(grid, points_per_cell, Placement::Uniform, inside)
}

/// [`seed_points`] with the points of each cell placed by `placement`.
pub fn seed_points_placed<E>(
    grid: &GridSpec,
    points_per_cell: &[usize],
    placement: Placement,
    mut inside: impl FnMut(&[f64]) -> Result<bool, E>,
) -> Result<Vec<PointSeed>, E> {
    let mut lattice = SeedLattice::new(grid, points_per_cell);
    lattice.place(placement);
    let ranges: Vec<(i64, i64)> = lattice.counts.iter().map(|&count| (0, count)).collect();
    let mut points = Vec::new();
    let mut position = vec![0.0; lattice.dim()];
    for_each_index(&ranges, |index| {
        lattice.position(index, &mut position);
        if inside(&position)? {
            points.push(PointSeed {
                position: position.clone(),
                volume: lattice.volume(index),
                half_lengths: lattice.half_lengths(index),
            });
        }
        Ok(())
    })?;
    Ok(points)
}

/// Points of an axis-aligned box `[lower, upper]`, seeded exactly (module docs): in every
/// cell the box overlaps, the points of `placement` mapped onto the overlap, sharing its
/// volume. Cells in order, axis 0 fastest, the points of a cell consecutive.
pub fn seed_box(
    grid: &GridSpec,
    points_per_cell: &[usize],
    placement: Placement,
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
    // Per axis: cell-local coordinates in [0, 1] and weights summing to 1.
    let rules: Vec<Vec<(f64, f64)>> = points_per_cell
        .iter()
        .map(|&n| match placement {
            Placement::Uniform => (0..n)
                .map(|i| ((i as f64 + 0.5) / n as f64, 1.0 / n as f64))
                .collect(),
            Placement::Gauss => gauss_legendre_unit(n),
        })
        .collect();
    let ranges: Vec<(i64, i64)> = overlaps.iter().map(|o| (0, o.len() as i64)).collect();
    let local: Vec<(i64, i64)> = points_per_cell.iter().map(|&n| (0, n as i64)).collect();
    let mut points = Vec::new();
    let _ = for_each_index(&ranges, |cell| {
        let intervals: Vec<(f64, f64)> = (0..dim).map(|a| overlaps[a][cell[a] as usize]).collect();
        for_each_index(&local, |k| {
            let mut position = Vec::with_capacity(dim);
            let mut half_lengths = Vec::with_capacity(dim);
            let mut volume = 1.0;
            for (a, &(lo, hi)) in intervals.iter().enumerate() {
                let (s, w) = rules[a][k[a] as usize];
                position.push(lo + (hi - lo) * s);
                volume *= (hi - lo) * w;
                half_lengths.push(0.5 * (hi - lo) * w);
            }
            points.push(PointSeed {
                position,
                volume,
                half_lengths,
            });
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

/// How the points of a part of a flat piece of boundary are placed ([`seed_boundary`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PartRule {
    /// `k` equal shares per edge, a point at the centre of each, weighted by the basis
    /// averaged over its share (tractions).
    Shares(usize),
    /// The `k`-point Gauss rule per edge, the basis sampled at the points (surface conditions).
    Gauss(usize),
}

/// A quadrature point of a flat piece of boundary and its *share* of it: the segment (2D) or
/// parallelogram (3D) it stands for, centred at the point with the half-edges `half_edges`
/// (none in 1D). Its weights are the grid's functions averaged over the share
/// (`basis::surface`), so the shares' sum integrates them exactly wherever the shares lie.
#[derive(Clone, Debug, PartialEq)]
pub struct BoundarySeed {
    pub position: Vec<f64>,
    /// Reference area of the share (length in 2D, 1 in 1D).
    pub area: f64,
    pub half_edges: Vec<Vec<f64>>,
}

/// Quadrature points of a flat piece of boundary given by `dim` corners (the grid's dimension):
///
/// * 1D: one corner, the end of the bar: one point of area 1 (the bar's unit cross-section);
/// * 2D: a segment from `corners[0]` to `corners[1]`;
/// * 3D: the parallelogram with corner `corners[0]` and edges `corners[1] − corners[0]` and
///   `corners[2] − corners[0]`.
///
/// Each edge e is split into `n = max(1, ceil(per_cell · max_a |e_a| / h_a))` equal parts (h_a =
/// cell size along axis a), so there are about `per_cell` parts per cell crossed. With
/// [`PartRule::Shares`]`(k)` every part is cut into `k` equal shares along each edge, a point at
/// the centre of each share carrying it (its area and half-edges); with [`PartRule::Gauss`]`(k)`
/// the points sit at the `k`-point Gauss–Legendre points of each part along each edge and carry
/// its area times their weights, and no share (the basis is sampled at them). The areas sum
/// exactly to the segment length / parallelogram area. Returns the points first edge fastest,
/// or `Err(count)` if there would be more than `max_points`.
pub fn seed_boundary(
    grid: &GridSpec,
    corners: &[Vec<f64>],
    per_cell: usize,
    rule: PartRule,
    max_points: usize,
) -> Result<Vec<BoundarySeed>, usize> {
    let (shares, gauss) = match rule {
        PartRule::Shares(k) => (k.max(1), None),
        PartRule::Gauss(k) => (1, Some(gauss_legendre_unit(k.max(1)))),
    };
    let per_part = gauss.as_ref().map_or(1, |g| g.len());
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
            ((per_cell.max(1) as f64 * cells_crossed).ceil() as usize).max(1) * shares
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
        .try_fold(1usize, |count, &n| count.checked_mul(n * per_part))
        .unwrap_or(usize::MAX);
    if count > max_points {
        return Err(count);
    }
    let share_area = area / parts.iter().product::<usize>() as f64;
    let half_edges: Vec<Vec<f64>> = edges
        .iter()
        .zip(&parts)
        .map(|(edge, &n)| edge.iter().map(|e| 0.5 * e / n as f64).collect())
        .collect();
    // (part, point) along each edge: index = part * per_part + g
    let ranges: Vec<(i64, i64)> = parts.iter().map(|&n| (0, (n * per_part) as i64)).collect();
    let mut points = Vec::with_capacity(count);
    let _ = for_each_index::<std::convert::Infallible>(&ranges, |index| {
        let mut position = origin.clone();
        let mut weight = 1.0;
        for (edge, (&k, &n)) in edges.iter().zip(index.iter().zip(&parts)) {
            let (i, g) = (k as usize / per_part, k as usize % per_part);
            let (u, w) = gauss.as_ref().map_or((0.5, 1.0), |rule| rule[g]);
            let t = (i as f64 + u) / n as f64;
            weight *= w;
            for (x, e) in position.iter_mut().zip(edge) {
                *x += t * e;
            }
        }
        points.push(BoundarySeed {
            position,
            area: share_area * weight,
            half_edges: if gauss.is_some() {
                Vec::new()
            } else {
                half_edges.clone()
            },
        });
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
    /// Per axis, the cell-local coordinate in [0, 1] and the volume fraction of each point.
    local: Vec<Vec<(f64, f64)>>,
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
        let local = points_per_cell
            .iter()
            .map(|&ppc| {
                (0..ppc)
                    .map(|i| ((i as f64 + 0.5) / ppc as f64, 1.0 / ppc as f64))
                    .collect()
            })
            .collect();
        Self {
            grid,
            points_per_cell,
            counts,
            local,
        }
    }

    /// Places the points of a cell by `placement`.
    fn place(&mut self, placement: Placement) {
        if placement == Placement::Gauss {
            self.local = self
                .points_per_cell
                .iter()
                .map(|&ppc| gauss_legendre_unit(ppc))
                .collect();
        }
    }

    /// Reference volume of lattice point `index`.
    fn volume(&self, index: &[i64]) -> f64 {
        (0..self.dim())
            .map(|axis| {
                let local = index[axis].rem_euclid(self.points_per_cell[axis] as i64) as usize;
                self.cell_size(axis) * self.local[axis][local].1
            })
            .product()
    }

    /// Half the side lengths of the box of lattice point `index`: half its share of the cell
    /// along each axis (`h / (2 ppc)` for the uniform placement).
    fn half_lengths(&self, index: &[i64]) -> Vec<f64> {
        (0..self.dim())
            .map(|axis| {
                let local = index[axis].rem_euclid(self.points_per_cell[axis] as i64) as usize;
                0.5 * self.cell_size(axis) * self.local[axis][local].1
            })
            .collect()
    }

    fn dim(&self) -> usize {
        self.grid.dim()
    }

    fn cell_size(&self, axis: usize) -> f64 {
        (self.grid.upper[axis] - self.grid.lower[axis]) / self.grid.cells[axis] as f64
    }

    /// Position of lattice point `index`: cell `c = floor(index / ppc)`, local `i = index mod ppc`,
    /// `x = lower + h * (c + (i + 1/2) / ppc)`.
    fn position(&self, index: &[i64], position: &mut [f64]) {
        for axis in 0..self.dim() {
            let ppc = self.points_per_cell[axis] as i64;
            let cell = index[axis].div_euclid(ppc) as f64;
            let local = self.local[axis][index[axis].rem_euclid(ppc) as usize].0;
            position[axis] = self.grid.lower[axis] + self.cell_size(axis) * (cell + local);
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
pub(crate) mod tests {
    use super::*;
    use crate::basis::BasisKind;
    use std::convert::Infallible;

    /// A grid of `basis` (for the seeding tests here and in `fem_seeding`).
    pub(crate) fn grid_of(
        lower: &[f64],
        upper: &[f64],
        cells: &[usize],
        basis: BasisKind,
    ) -> GridSpec {
        GridSpec {
            lower: lower.to_vec(),
            upper: upper.to_vec(),
            cells: cells.to_vec(),
            basis,
        }
    }

    fn grid(lower: &[f64], upper: &[f64], cells: &[usize]) -> GridSpec {
        grid_of(lower, upper, cells, BasisKind::Linear)
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
    fn gauss_placement_positions_and_volumes() {
        let grid = grid(&[0.0, 0.0], &[2.0, 3.0], &[2, 3]);
        let points = seed_points_placed(&grid, &[3, 2], Placement::Gauss, everywhere).unwrap();
        assert_eq!(points.len(), 6 * 3 * 2);
        let total: f64 = points.iter().map(|p| p.volume).sum();
        assert!((total - 6.0).abs() < 1e-12);
        // first point: first Gauss point of the first cell along each axis
        let g3 = gauss_legendre_unit(3);
        let g2 = gauss_legendre_unit(2);
        assert!((points[0].position[0] - g3[0].0).abs() < 1e-15);
        assert!((points[0].position[1] - g2[0].0).abs() < 1e-15);
        assert!((points[0].volume - g3[0].1 * g2[0].1).abs() < 1e-15);
        // x^5 y^3 over the box is integrated exactly (degree 5 in x with 3 points, 3 in y with 2)
        let sum: f64 = points
            .iter()
            .map(|p| p.volume * p.position[0].powi(5) * p.position[1].powi(3))
            .sum();
        let exact = (2f64.powi(6) / 6.0) * (3f64.powi(4) / 4.0);
        assert!((sum - exact).abs() < 1e-10 * exact, "{sum} vs {exact}");
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
        let points = seed_boundary(
            &grid(&[0.0], &[2.0], &[4]),
            &[vec![2.0]],
            3,
            PartRule::Shares(1),
            10,
        )
        .unwrap();
        assert_eq!(points.len(), 1);
        assert_eq!((&points[0].position[..], points[0].area), (&[2.0][..], 1.0));
        assert!(points[0].half_edges.is_empty());
        // 2D: a slanted segment crossing 2 cells along x and 1 along y, 2 per cell -> 4 parts
        let g = grid(&[0.0, 0.0], &[4.0, 4.0], &[4, 4]);
        let points = seed_boundary(
            &g,
            &[vec![1.0, 1.0], vec![3.0, 2.0]],
            2,
            PartRule::Shares(1),
            10,
        )
        .unwrap();
        assert_eq!(points.len(), 4);
        let length: f64 = points.iter().map(|p| p.area).sum();
        assert!((length - 5f64.sqrt()).abs() < 1e-12);
        assert_eq!(points[0].position, [1.25, 1.125]);
        assert_eq!(points[3].position, [2.75, 1.875]);
        // each share reaches its neighbour's: half-edges of a quarter of the segment, halved
        assert_eq!(points[0].half_edges, [vec![0.25, 0.125]]);
        // two shares per part: 8 points, at the centres of eighths
        let halves = seed_boundary(
            &g,
            &[vec![1.0, 1.0], vec![3.0, 2.0]],
            2,
            PartRule::Shares(2),
            10,
        )
        .unwrap();
        assert_eq!(halves.len(), 8);
        assert_eq!(halves[0].position, [1.125, 1.0625]);
        assert_eq!(halves[0].half_edges, [vec![0.125, 0.0625]]);
        // the 2-point Gauss rule per part: the points of the old rule, the basis sampled there
        let gauss = seed_boundary(
            &g,
            &[vec![1.0, 1.0], vec![3.0, 2.0]],
            2,
            PartRule::Gauss(2),
            10,
        )
        .unwrap();
        assert_eq!(gauss.len(), 8);
        let t = 0.5 - 0.5 / 3f64.sqrt();
        assert!((gauss[0].position[0] - (1.0 + 0.5 * t)).abs() < 1e-15);
        assert!(
            (gauss[0].area - 5f64.sqrt() / 8.0).abs() < 1e-15 && gauss[0].half_edges.is_empty()
        );
        // 3D: a 2 x 1 rectangle in the plane z = 1 with 1 point per cell of size 0.5
        let g = grid(&[0.0, 0.0, 0.0], &[2.0, 2.0, 2.0], &[4, 4, 4]);
        let corners = [
            vec![0.0, 0.0, 1.0],
            vec![2.0, 0.0, 1.0],
            vec![0.0, 1.0, 1.0],
        ];
        let points = seed_boundary(&g, &corners, 1, PartRule::Shares(1), 8).unwrap();
        assert_eq!(
            seed_boundary(&g, &corners, 1, PartRule::Shares(1), 7),
            Err(8)
        );
        assert_eq!(points.len(), 4 * 2);
        assert!(
            points
                .iter()
                .all(|p| p.position[2] == 1.0 && p.area == 0.25)
        );
        assert_eq!(points[1].position, [0.75, 0.25, 1.0]);
        assert_eq!(points[4].position, [0.25, 0.75, 1.0]);
        assert_eq!(
            points[4].half_edges,
            [vec![0.25, 0.0, 0.0], vec![0.0, 0.25, 0.0]]
        );
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

    #[test]
    fn box_seeding_is_exact_in_volume_and_matches_the_lattice_when_aligned() {
        let grid = grid(&[0.0, 0.0], &[4.0, 3.0], &[4, 3]);
        // aligned: the same points as the lattice seeding of the region
        let mut exact = seed_box(&grid, &[2, 3], Placement::Uniform, &[1.0, 0.0], &[3.0, 2.0]);
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
            assert_eq!(a.half_lengths.len(), 2);
            for (la, lb) in a.half_lengths.iter().zip(&b.half_lengths) {
                assert!((la - lb).abs() < 1e-12);
            }
        }
        // the boxes of the points: half of (1/2, 2/3) per axis
        assert!(
            lattice
                .iter()
                .all(|p| (p.half_lengths[0] - 0.25).abs() < 1e-15
                    && (p.half_lengths[1] - 1.0 / 6.0).abs() < 1e-15)
        );
        // not aligned: exact volume, a sliver cell gets points of tiny volume inside the box
        let sliver = seed_box(
            &grid,
            &[2, 2],
            Placement::Uniform,
            &[0.0, 0.0],
            &[4.0, 2.001],
        );
        let volume: f64 = sliver.iter().map(|p| p.volume).sum();
        assert!((volume - 4.0 * 2.001).abs() < 1e-12, "{volume}");
        let thin: Vec<_> = sliver.iter().filter(|p| p.position[1] > 2.0).collect();
        assert_eq!(thin.len(), 4 * 2 * 2);
        assert!(
            thin.iter()
                .all(|p| p.position[1] < 2.001 && (p.volume - 0.25 * 0.001).abs() < 1e-15)
        );
        // their boxes: a quarter cell across, a quarter of the sliver high
        assert!(thin.iter().all(|p| (p.half_lengths[0] - 0.25).abs() < 1e-15
            && (p.half_lengths[1] - 0.00025).abs() < 1e-12));
        // every box has the point's volume, also with the Gauss placement
        let gauss = seed_box(&grid, &[3, 2], Placement::Gauss, &[0.0, 0.0], &[4.0, 2.5]);
        for p in sliver.iter().chain(&gauss) {
            let box_volume: f64 = p.half_lengths.iter().map(|l| 2.0 * l).product();
            assert!((box_volume - p.volume).abs() < 1e-14, "{p:?}");
        }
    }
}

/// A quadrature point of a flat piece of a body's boundary (see [`seed_surface`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfacePointSeed {
    pub position: Vec<f64>,
    /// Reference area (length in 2D, 1 in 1D) the point carries.
    pub area: f64,
    /// The half-edges of its share of the surface (`BoundarySeed`).
    pub half_edges: Vec<Vec<f64>>,
    /// The material point nearest to it in the reference configuration (global index): its
    /// host, whose deformation it follows.
    pub host: usize,
}

/// The quadrature points of a flat piece of boundary given by its corners (`on: [...]` of
/// `traction(...)` and of the surface conditions; see [`seed_boundary`] for the shapes and
/// `rule`), each with its share (if any) and its host material point. `points` names the points in messages ("traction points").
/// Errors (to be located at the declaring call): corners of the wrong number or dimension,
/// outside the grid, of zero extent, or too many points.
pub fn seed_surface(
    grid: &GridSpec,
    material_points: &[&[f64]],
    corners: &[Vec<f64>],
    per_cell: usize,
    rule: PartRule,
    points: &str,
) -> Result<Vec<SurfacePointSeed>, String> {
    let dim = grid.dim();
    let shape = [
        "the end point of the bar",
        "the two ends of a segment",
        "three corners of a parallelogram (corner, corner + edge 1, corner + edge 2)",
    ];
    if corners.len() != dim {
        return Err(format!(
            "option 'on' has {} points but the grid is {dim}-dimensional: give {dim}, {}",
            corners.len(),
            shape[dim - 1]
        ));
    }
    if let Some(corner) = corners.iter().find(|corner| corner.len() != dim) {
        return Err(format!(
            "the point {corner:?} of option 'on' has {} coordinates, the grid is {dim}-dimensional",
            corner.len()
        ));
    }
    let (lower, upper) = (&grid.lower, &grid.upper);
    let outside = |x: &[f64]| (0..dim).any(|axis| x[axis] < lower[axis] || x[axis] > upper[axis]);
    if let Some(corner) = corners.iter().find(|corner| outside(corner)) {
        return Err(format!(
            "the point {corner:?} is outside the grid [{lower:?} .. {upper:?}]"
        ));
    }
    if dim == 3 {
        // the fourth corner (corner 1 + corner 2 − corner 0) must be in the grid too
        let c = corners;
        let fourth: Vec<f64> = (0..3).map(|a| c[1][a] + c[2][a] - c[0][a]).collect();
        if outside(&fourth) {
            return Err(format!(
                "the parallelogram's fourth corner {fourth:?} is outside the grid [{lower:?} .. {upper:?}]"
            ));
        }
    }
    let seeded =
        seed_boundary(grid, corners, per_cell, rule, MAX_SEED_CANDIDATES).map_err(|count| {
            format!("{count} {points} exceed the limit of {MAX_SEED_CANDIDATES}; lower per_cell")
        })?;
    if seeded.iter().all(|seed| seed.area == 0.0) {
        return Err(
            "the boundary piece has zero length or area (repeated or collinear points)".into(),
        );
    }
    let positions: Vec<Vec<f64>> = seeded.iter().map(|seed| seed.position.clone()).collect();
    let hosts = nearest_points(grid, material_points, &positions);
    Ok(seeded
        .into_iter()
        .zip(hosts)
        .map(|(seed, host)| SurfacePointSeed {
            position: seed.position,
            area: seed.area,
            half_edges: seed.half_edges,
            // bodies are resolved first and have points
            host: host.unwrap_or_default(),
        })
        .collect())
}
