//! Proximity of convex point sets at given poses, with parry3d-f64: axis-aligned bounding boxes
//! (the broad phase of `docs/model.md#which-pairs`) and the signed distance of two convex
//! polytopes (GJK, EPA when they overlap: the narrow phase and the end-of-step overlap check).

use nalgebra::{Matrix3, Vector3};
use parry3d_f64::bounding_volume::{Aabb, BoundingVolume};
use parry3d_f64::math::{Pose, Vector as PVec};
use parry3d_f64::query::{contact, distance};
use parry3d_f64::shape::ConvexPolyhedron;

/// A convex point set placed in the world: its points `x + R p`, their bounding box and their
/// convex polyhedron (`None` for a degenerate set, which no query then reports).
#[derive(Clone)]
pub struct PlacedConvex {
    aabb: Aabb,
    polyhedron: Option<ConvexPolyhedron>,
}

impl std::fmt::Debug for PlacedConvex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PlacedConvex {{ aabb: {:?} }}", self.aabb)
    }
}

impl PlacedConvex {
    /// The convex hull of body-frame `points` at the pose `(x, R)`.
    pub fn new(points: &[Vector3<f64>], x: &Vector3<f64>, rotation: &Matrix3<f64>) -> Self {
        let world: Vec<PVec> = points
            .iter()
            .map(|p| {
                let w = x + rotation * p;
                PVec::new(w.x, w.y, w.z)
            })
            .collect();
        let aabb = Aabb::from_points(world.iter().copied());
        // parry panics on some degenerate inputs; such a set has no volume to overlap with.
        let polyhedron = std::panic::catch_unwind(|| ConvexPolyhedron::from_convex_hull(&world))
            .ok()
            .flatten();
        PlacedConvex { aabb, polyhedron }
    }

    /// Whether the bounding boxes, each grown by `margin / 2`, intersect (the broad phase).
    pub fn may_touch(&self, other: &PlacedConvex, margin: f64) -> bool {
        let m = 0.5 * margin.max(0.0);
        self.aabb.loosened(m).intersects(&other.aabb.loosened(m))
    }

    /// The signed distance to `other` when it is at most `prediction` (negative: the depth of
    /// an overlap); `None` when they are farther apart or a set is degenerate.
    ///
    /// parry's `contact` can answer "apart" for two polytopes whose faces touch within
    /// round-off (issue 16: a cube resting on another, `Ok(None)` even with a prediction of
    /// 1 m, and the right answer with the arguments swapped). A pair dropped that way is a
    /// missed contact set, so an "apart" is checked with GJK's `distance`, then `contact` is
    /// asked again the other way round; when that fails too, the GJK distance (0 for
    /// intersecting sets) is returned rather than nothing.
    pub fn signed_distance(&self, other: &PlacedConvex, prediction: f64) -> Option<f64> {
        let (a, b) = (self.polyhedron.as_ref()?, other.polyhedron.as_ref()?);
        let id = Pose::IDENTITY;
        let prediction = prediction.max(0.0);
        let finite = |r: Result<Option<parry3d_f64::query::Contact>, _>| {
            r.ok().flatten().map(|c| c.dist).filter(|d| d.is_finite())
        };
        if let Some(d) = finite(contact(&id, a, &id, b, prediction)) {
            return Some(d);
        }
        let gjk = distance(&id, a, &id, b)
            .ok()
            .map(|d| d.distance)
            .filter(|d| d.is_finite() && *d <= prediction)?;
        finite(contact(&id, b, &id, a, prediction)).or(Some(gjk))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(x: Vector3<f64>) -> PlacedConvex {
        let mut pts = Vec::new();
        for sx in [-0.1, 0.1] {
            for sy in [-0.1, 0.1] {
                for sz in [-0.1, 0.1] {
                    pts.push(Vector3::new(sx, sy, sz));
                }
            }
        }
        PlacedConvex::new(&pts, &x, &Matrix3::identity())
    }

    #[test]
    fn distance_overlap_and_broad_phase() {
        let a = cube(Vector3::zeros());
        let b = cube(Vector3::new(0.25, 0.0, 0.0));
        assert!(!a.may_touch(&b, 0.04) && a.may_touch(&b, 0.06));
        let d = a.signed_distance(&b, 0.1).unwrap_or(f64::NAN);
        assert!((d - 0.05).abs() < 1e-12, "{d}");
        assert!(a.signed_distance(&b, 0.01).is_none());
        let c = cube(Vector3::new(0.19, 0.0, 0.0));
        let d = a.signed_distance(&c, 0.0).unwrap_or(f64::NAN);
        assert!((d + 0.01).abs() < 1e-12, "{d}");
        let touching = cube(Vector3::new(0.0, 0.0, 0.2));
        let d = a.signed_distance(&touching, 0.0).unwrap_or(f64::NAN);
        assert!(d.abs() < 1e-12, "{d}");
    }
}

#[cfg(test)]
mod issue16 {
    use super::*;

    /// Cube C resting on cube B at step 53 of the pile scene (issue 16): parry's `contact(C, B)`
    /// answers "apart" even with a 1 m prediction; the narrow phase must still see them touch.
    #[test]
    fn touching_cubes_that_parry_calls_apart() {
        let c = [
            [-0.210440000003636, -0.2499999996360523, 0.19999999999997878],
            [
                -0.2104400000036456,
                -0.24999999963608915,
                0.3999999999999788,
            ],
            [
                -0.2104399995246815,
                -0.04999999963605227,
                0.20000000000001567,
            ],
            [
                -0.21043999952469117,
                -0.04999999963608913,
                0.4000000000000157,
            ],
            [
                -0.010440000003635971,
                -0.2500000001150067,
                0.1999999999999884,
            ],
            [
                -0.010440000003645603,
                -0.2500000001150436,
                0.3999999999999884,
            ],
            [
                -0.010439999524681512,
                -0.05000000011500673,
                0.2000000000000253,
            ],
            [
                -0.010439999524691143,
                -0.05000000011504359,
                0.40000000000002534,
            ],
        ];
        let b = [
            [
                -0.19200000000023082,
                -0.25000000000635186,
                -3.649858193455202e-14,
            ],
            [
                -0.19200000000023187,
                -0.25000000000642886,
                0.1999999999999635,
            ],
            [
                -0.1919999999997396,
                -0.05000000000635184,
                4.0495384823202585e-14,
            ],
            [
                -0.1919999999997406,
                -0.05000000000642883,
                0.2000000000000405,
            ],
            [
                0.007999999999769178,
                -0.2500000000068431,
                -3.547162563677375e-14,
            ],
            [
                0.007999999999768151,
                -0.2500000000069201,
                0.19999999999996454,
            ],
            [
                0.008000000000260424,
                -0.050000000006843084,
                4.1522341120980855e-14,
            ],
            [
                0.008000000000259397,
                -0.05000000000692008,
                0.20000000000004153,
            ],
        ];
        let placed = |p: &[[f64; 3]]| {
            let v: Vec<Vector3<f64>> = p.iter().map(|q| Vector3::new(q[0], q[1], q[2])).collect();
            PlacedConvex::new(&v, &Vector3::zeros(), &Matrix3::identity())
        };
        let (c, b) = (placed(&c), placed(&b));
        for prediction in [0.0, 1e-3, 1.0] {
            let d = c.signed_distance(&b, prediction).unwrap_or(f64::NAN);
            assert!(d.abs() < 1e-12, "prediction {prediction}: {d}");
            let d = b.signed_distance(&c, prediction).unwrap_or(f64::NAN);
            assert!(d.abs() < 1e-12, "prediction {prediction}: {d}");
        }
        // Still "apart" when they are: C lifted by 0.01 m is farther than a 1e-3 prediction.
        let lifted: Vec<[f64; 3]> = [-0.21, -0.01]
            .into_iter()
            .flat_map(|x| [-0.25, -0.05].map(|y| (x, y)))
            .flat_map(|(x, y)| [0.21, 0.41].map(|z| [x, y, z]))
            .collect();
        let lifted = placed(&lifted);
        assert!(lifted.signed_distance(&b, 1e-3).is_none());
        let d = lifted.signed_distance(&b, 0.1).unwrap_or(f64::NAN);
        assert!((d - 0.01).abs() < 1e-9, "{d}");
    }
}
