//! Convex hulls of planar point sets: the contact patch seen from above (plots) and the patch
//! polygon of the reduced sliding model.

/// Counter-clockwise convex hull of the finite points of `points` (Andrew's monotone chain).
///
/// Points whose coordinates both differ by at most `length_tol` from the previous point in
/// lexicographic order are dropped as duplicates, and a turn whose cross product is at most
/// `area_tol` is not a corner, so collinear points are dropped: 1 or 2 points come back for
/// degenerate input. The first point is the lexicographically smallest corner.
pub fn convex_hull_2d(mut points: Vec<[f64; 2]>, length_tol: f64, area_tol: f64) -> Vec<[f64; 2]> {
    points.retain(|p| p[0].is_finite() && p[1].is_finite());
    points.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    points.dedup_by(|a, b| (a[0] - b[0]).abs() <= length_tol && (a[1] - b[1]).abs() <= length_tol);
    if points.len() < 3 {
        return points;
    }
    let cross = |o: &[f64; 2], a: &[f64; 2], b: &[f64; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(points.len() + 1);
    for pass in 0..2 {
        let start = hull.len();
        let chain: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(points.iter())
        } else {
            Box::new(points.iter().rev())
        };
        for p in chain {
            while hull.len() >= start + 2
                && cross(&hull[hull.len() - 2], &hull[hull.len() - 1], p) <= area_tol
            {
                hull.pop();
            }
            hull.push(*p);
        }
        // The last point of each chain is the first of the other.
        hull.pop();
    }
    hull
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_with_inner_edge_and_duplicate_points() {
        let pts = vec![
            [0.0, 0.0],
            [1.0, 0.0],
            [1.0, 1.0],
            [0.0, 1.0],
            [0.5, 0.0],
            [0.5, 0.5],
            [1.0, 1.0],
            [f64::NAN, 0.0],
        ];
        let h = convex_hull_2d(pts, 0.0, 0.0);
        assert_eq!(h, vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]);
    }

    #[test]
    fn collinear_and_near_duplicate_points() {
        let line = vec![[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]];
        assert_eq!(convex_hull_2d(line, 0.0, 0.0), vec![[0.0, 0.0], [2.0, 2.0]]);
        // A corner 1e-13 off the line is kept with no tolerance and dropped with one.
        let nearly = vec![[0.0, 0.0], [1.0, 1.0 + 1e-13], [2.0, 2.0]];
        assert_eq!(convex_hull_2d(nearly.clone(), 0.0, 0.0).len(), 3);
        assert_eq!(convex_hull_2d(nearly, 1e-12, 1e-12).len(), 2);
        let twice = vec![[0.0, 0.0], [1e-16, 0.0], [1.0, 0.0], [0.0, 1.0]];
        assert_eq!(convex_hull_2d(twice, 1e-15, 0.0).len(), 3);
    }
}
