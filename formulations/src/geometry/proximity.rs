//! Proximity of convex point sets at given poses, with parry3d-f64: axis-aligned bounding boxes
//! (the broad phase of `docs/model.md#which-pairs`) and the signed distance of two convex
//! polytopes (GJK, EPA when they overlap: the narrow phase and the end-of-step overlap check).

use nalgebra::{Matrix3, Vector3};
use parry3d_f64::bounding_volume::{Aabb, BoundingVolume};
use parry3d_f64::math::{Pose, Vector as PVec};
use parry3d_f64::query::contact;
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
    pub fn signed_distance(&self, other: &PlacedConvex, prediction: f64) -> Option<f64> {
        let (a, b) = (self.polyhedron.as_ref()?, other.polyhedron.as_ref()?);
        let id = Pose::IDENTITY;
        contact(&id, a, &id, b, prediction.max(0.0))
            .ok()
            .flatten()
            .map(|c| c.dist)
            .filter(|d| d.is_finite())
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
