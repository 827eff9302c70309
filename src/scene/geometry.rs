//! Plane geometry for scene regions (pure functions).

/// Whether `point` lies inside the simple or self-intersecting polygon `vertices` (closed
/// implicitly, last vertex to first), by the even-odd rule: a ray from the point towards +x
/// crosses the boundary an odd number of times. Points exactly on an edge may count either
/// way; seeding points sit at cell-interior lattice positions, so this only matters for
/// polygons drawn through those positions.
pub fn point_in_polygon(point: [f64; 2], vertices: &[[f64; 2]]) -> bool {
    let [x, y] = point;
    let mut inside = false;
    let mut previous = match vertices.last() {
        Some(&last) => last,
        None => return false,
    };
    for &current in vertices {
        let ([x0, y0], [x1, y1]) = (previous, current);
        // the edge straddles the horizontal line through the point (half-open in y, so a
        // vertex on the line is counted once)
        if (y0 > y) != (y1 > y) {
            let crossing = x0 + (y - y0) * (x1 - x0) / (y1 - y0);
            if x < crossing {
                inside = !inside;
            }
        }
        previous = current;
    }
    inside
}

/// Twice the signed area of a polygon (shoelace formula): positive when counter-clockwise.
pub fn polygon_double_area(vertices: &[[f64; 2]]) -> f64 {
    let n = vertices.len();
    (0..n)
        .map(|i| {
            let ([x0, y0], [x1, y1]) = (vertices[i], vertices[(i + 1) % n]);
            x0 * y1 - x1 * y0
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangle_and_concave_polygon() {
        let triangle = [[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]];
        assert!(point_in_polygon([1.0, 1.0], &triangle));
        assert!(!point_in_polygon([2.5, 2.5], &triangle));
        assert!(!point_in_polygon([-0.1, 1.0], &triangle));
        // an L shape (concave): the notch is outside
        let l_shape = [
            [0.0, 0.0],
            [3.0, 0.0],
            [3.0, 1.0],
            [1.0, 1.0],
            [1.0, 3.0],
            [0.0, 3.0],
        ];
        assert!(point_in_polygon([0.5, 2.5], &l_shape));
        assert!(point_in_polygon([2.5, 0.5], &l_shape));
        assert!(!point_in_polygon([2.0, 2.0], &l_shape));
        // clockwise order gives the same answer
        let reversed: Vec<[f64; 2]> = l_shape.iter().rev().copied().collect();
        assert!(!point_in_polygon([2.0, 2.0], &reversed));
        assert!(point_in_polygon([0.5, 0.5], &reversed));
        assert_eq!(polygon_double_area(&l_shape), 2.0 * 5.0);
        assert_eq!(polygon_double_area(&reversed), -2.0 * 5.0);
        assert!(!point_in_polygon([0.5, 0.5], &[]));
    }

    /// The fraction of a fine lattice inside a polygon converges to its area.
    #[test]
    fn lattice_count_matches_the_shoelace_area() {
        let pentagon = [[0.3, 0.1], [2.9, 0.4], [3.6, 2.2], [1.7, 3.9], [0.1, 2.4]];
        let n = 400;
        let h = 4.0 / n as f64;
        let mut count = 0;
        for i in 0..n {
            for j in 0..n {
                let p = [(i as f64 + 0.5) * h, (j as f64 + 0.5) * h];
                count += usize::from(point_in_polygon(p, &pentagon));
            }
        }
        let area = polygon_double_area(&pentagon).abs() / 2.0;
        assert!((count as f64 * h * h - area).abs() < 0.01 * area);
    }
}
