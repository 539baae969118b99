//! The closest-point QP of the conic backend (`docs/backends.md#conic`) against parry3d-f64.
//!
//! Conv(F) is a random point cloud or a random box at a random pose, given either by its
//! vertices or by its H-representation (the merged faces of ecp's `ConvexHull`); G is the
//! ground, a random tilted half-space, or another random point cloud. The clarabel distance
//! (`closest_points`, and the pure QP form for separated sets) must agree with parry's
//! `query::distance` to 1e-8, and where the closest points are unique (a single closest vertex
//! against a half-space) the points must agree too (to 1e-7). Independently of parry, the answer must
//! carry its own optimality certificate: the plane through the closest points, normal to
//! `p − q`, separates the two sets. Touching and overlapping placements are included (distance
//! 0), where only `closest_points` is checked (the pure QP form is accurate to about
//! √tolerance there, by design; see the module docs).

mod common;

use common::strategies::{unit3, vec3};
use ecp::formulations::geometry::ConvexHull;
use ecp::solvers::conic::closest_point::{ConvexSet, closest_points, closest_points_qp};
use ecp::solvers::conic::default_clarabel_settings;
use nalgebra::{UnitQuaternion, Vector3, Vector4};
use parry3d_f64::math::{Pose, Rot3, Vector as PVec};
use parry3d_f64::query::{self, ClosestPoints};
use parry3d_f64::shape::{ConvexPolyhedron, HalfSpace as PHalfSpace};
use proptest::prelude::*;

type V3 = Vector3<f64>;

/// Agreement with parry.
const TOL: f64 = 1e-8;

fn to_p(v: &V3) -> PVec {
    PVec::new(v.x, v.y, v.z)
}

fn from_p(v: PVec) -> V3 {
    V3::new(v.x, v.y, v.z)
}

fn arr(v: &V3) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn rotation() -> impl Strategy<Value = UnitQuaternion<f64>> {
    (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64)
        .prop_filter("quaternion away from zero", |(a, b, c, d)| {
            (a * a + b * b + c * c + d * d) > 0.01
        })
        .prop_map(|(a, b, c, d)| {
            UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(Vector4::new(b, c, d, a)))
        })
}

/// A body-frame point set: a box with random extents, or 6–16 random points.
fn body_points() -> impl Strategy<Value = Vec<V3>> {
    prop_oneof![
        vec3(0.02, 0.5).prop_map(|e| {
            let mut v = Vec::new();
            for i in 0..8 {
                let s = |k: usize| if (i >> k) & 1 == 1 { 0.5 } else { -0.5 };
                v.push(V3::new(s(0) * e.x, s(1) * e.y, s(2) * e.z));
            }
            v
        }),
        prop::collection::vec(vec3(-0.3, 0.3), 6..16),
    ]
}

/// Points, hull (for the H-representation) and parry polyhedron of a posed body.
struct Posed {
    world: Vec<V3>,
    hrep: Vec<([f64; 3], f64)>,
    poly: ConvexPolyhedron,
}

fn pose_body(points: &[V3], rot: &UnitQuaternion<f64>, x: &V3) -> Option<Posed> {
    let hull = ConvexHull::from_points(points).ok()?;
    let world: Vec<V3> = hull.vertices().iter().map(|v| x + rot * v).collect();
    let hrep = hull
        .faces()
        .iter()
        .map(|f| {
            let n = rot * f.normal;
            (arr(&n), f.offset + n.dot(x))
        })
        .collect();
    let pts: Vec<PVec> = world.iter().map(to_p).collect();
    let poly = ConvexPolyhedron::from_convex_hull(&pts)?;
    Some(Posed { world, hrep, poly })
}

fn identity() -> Pose {
    Pose::from_parts(PVec::ZERO, Rot3::IDENTITY)
}

/// The plane normal to `p − q` through the closest points separates the sets (KKT certificate).
fn separates(p: &V3, q: &V3, a: &[V3], b: &[V3]) -> Result<(), TestCaseError> {
    let d = (p - q).norm();
    if d < 1e-7 {
        return Ok(());
    }
    let u = (p - q) / d;
    // An error ε ≈ 1e-9 in the points tilts the normal by ε/d, which moves vertices up to 1 m
    // away by ε/d.
    let tol = 1e-8 + 2e-9 / d;
    for v in a {
        prop_assert!(
            u.dot(&(v - p)) >= -tol,
            "a vertex of A is beyond p: {}",
            u.dot(&(v - p))
        );
    }
    for w in b {
        prop_assert!(
            u.dot(&(w - q)) <= tol,
            "a vertex of B is beyond q: {}",
            u.dot(&(w - q))
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    /// Conv(F) (vertices and H-representation) against a half-space, vs parry's HalfSpace.
    #[test]
    fn hull_against_half_space(
        points in body_points(),
        rot in rotation(),
        n in prop_oneof![Just(V3::z()), unit3()],
        offset in -0.5..0.5f64,
        lift in prop_oneof![Just(0.0), -0.05..0.6f64],
    ) {
        // Place the body so that its lowest vertex is `lift` above the plane (negative: overlap).
        let Some(probe) = pose_body(&points, &rot, &V3::zeros()) else {
            return Err(TestCaseError::reject("degenerate hull"));
        };
        let low = probe.world.iter().map(|v| n.dot(v)).fold(f64::INFINITY, f64::min);
        let x = n * (offset + lift - low);
        let Some(body) = pose_body(&points, &rot, &x) else {
            return Err(TestCaseError::reject("degenerate hull"));
        };
        let verts: Vec<[f64; 3]> = body.world.iter().map(arr).collect();
        let plane = [(arr(&n), offset)];
        let settings = default_clarabel_settings();
        let by_vertices = closest_points(
            &ConvexSet::Vertices(&verts), &ConvexSet::HalfSpaces(&plane), &settings,
        ).map_err(|e| TestCaseError::fail(format!("{e}")))?;
        let by_faces = closest_points(
            &ConvexSet::HalfSpaces(&body.hrep), &ConvexSet::HalfSpaces(&plane), &settings,
        ).map_err(|e| TestCaseError::fail(format!("{e}")))?;

        let half = PHalfSpace::new(to_p(&n));
        let pose_g = Pose::from_translation(to_p(&(n * offset)));
        let d = query::distance(&identity(), &body.poly, &pose_g, &half)
            .map_err(|_| TestCaseError::fail("distance unsupported"))?
            .distance;
        prop_assert!((by_vertices.distance - d).abs() <= TOL,
            "vertex-set QP {:.15e} vs parry {:.15e}", by_vertices.distance, d);
        prop_assert!((by_faces.distance - d).abs() <= TOL,
            "H-representation QP {:.15e} vs parry {:.15e}", by_faces.distance, d);
        if d > 1e-3 {
            let quadratic = closest_points_qp(
                &ConvexSet::Vertices(&verts), &ConvexSet::HalfSpaces(&plane), &settings,
            ).map_err(|e| TestCaseError::fail(format!("{e}")))?;
            prop_assert!((quadratic.distance - d).abs() <= TOL,
                "QP form {:.15e} vs parry {:.15e}", quadratic.distance, d);
        }

        // Unique closest point: one vertex clearly lowest, and separated.
        let mut gaps: Vec<f64> = body.world.iter().map(|v| n.dot(v) - offset).collect();
        gaps.sort_by(f64::total_cmp);
        if gaps[0] > 1e-6 && gaps[1] - gaps[0] > 1e-4 {
            let cp = query::closest_points(&identity(), &body.poly, &pose_g, &half, 10.0)
                .map_err(|_| TestCaseError::fail("closest_points unsupported"))?;
            let ClosestPoints::WithinMargin(p1, p2) = cp else {
                return Err(TestCaseError::fail(format!("parry says {cp:?}")));
            };
            // Points: the interior-point answer is accurate to about 1e-8 near d = 1e-4, where
            // closest_points switches form (module docs); the distance is checked to 1e-8.
            for r in [&by_vertices, &by_faces] {
                let p = V3::from(r.on_first);
                let q = V3::from(r.on_second);
                prop_assert!((p - from_p(p1)).norm() <= 1e-7, "p {p} vs parry {p1:?}");
                prop_assert!((q - from_p(p2)).norm() <= 1e-7, "q {q} vs parry {p2:?}");
            }
        }
        let p = V3::from(by_vertices.on_first);
        let q = V3::from(by_vertices.on_second);
        prop_assert!(n.dot(&q) - offset <= 1e-9, "q is not in G");
        let ground_pts = [q];
        separates(&p, &q, &body.world, &ground_pts)?;
    }

    /// Two point clouds (convex hulls of vertex sets), vs parry's GJK distance.
    #[test]
    fn hull_against_hull(
        a in body_points(),
        b in body_points(),
        ra in rotation(),
        rb in rotation(),
        dir in unit3(),
        dist in 0.0..0.5f64,
    ) {
        let Some(pa) = pose_body(&a, &ra, &V3::zeros()) else {
            return Err(TestCaseError::reject("degenerate hull"));
        };
        // Push B along `dir` until its support plane is `dist` beyond A's (separated when dist
        // > 0; the sets may still be farther apart, or touch when dist = 0).
        let Some(probe) = pose_body(&b, &rb, &V3::zeros()) else {
            return Err(TestCaseError::reject("degenerate hull"));
        };
        let a_max = pa.world.iter().map(|v| dir.dot(v)).fold(f64::NEG_INFINITY, f64::max);
        let b_min = probe.world.iter().map(|v| dir.dot(v)).fold(f64::INFINITY, f64::min);
        let shift = dir * (a_max - b_min + dist);
        let Some(pb) = pose_body(&b, &rb, &shift) else {
            return Err(TestCaseError::reject("degenerate hull"));
        };
        let va: Vec<[f64; 3]> = pa.world.iter().map(arr).collect();
        let vb: Vec<[f64; 3]> = pb.world.iter().map(arr).collect();
        let r = closest_points(
            &ConvexSet::Vertices(&va), &ConvexSet::Vertices(&vb), &default_clarabel_settings(),
        ).map_err(|e| TestCaseError::fail(format!("{e}")))?;
        let d = query::distance(&identity(), &pa.poly, &identity(), &pb.poly)
            .map_err(|_| TestCaseError::fail("distance unsupported"))?
            .distance;
        prop_assert!((r.distance - d).abs() <= TOL, "QP {:.15e} vs parry {:.15e}", r.distance, d);
        if d > 1e-3 {
            let quadratic = closest_points_qp(
                &ConvexSet::Vertices(&va), &ConvexSet::Vertices(&vb), &default_clarabel_settings(),
            ).map_err(|e| TestCaseError::fail(format!("{e}")))?;
            prop_assert!((quadratic.distance - d).abs() <= TOL,
                "QP form {:.15e} vs parry {:.15e}", quadratic.distance, d);
        }
        prop_assert!(r.distance >= dist - 1e-9, "closer than the separating slab");
        separates(&V3::from(r.on_first), &V3::from(r.on_second), &pa.world, &pb.world)?;
    }
}

#[test]
fn empty_and_non_finite_sets_are_errors() {
    let s = default_clarabel_settings();
    let plane = [([0.0, 0.0, 1.0], 0.0)];
    assert!(
        closest_points(
            &ConvexSet::Vertices(&[]),
            &ConvexSet::HalfSpaces(&plane),
            &s
        )
        .is_err()
    );
    let bad = [[f64::NAN, 0.0, 0.0]];
    assert!(
        closest_points(
            &ConvexSet::Vertices(&bad),
            &ConvexSet::HalfSpaces(&plane),
            &s
        )
        .is_err()
    );
}
