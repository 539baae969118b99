//! Convex hull of a body as an intersection of half-spaces (`docs/model.md#contact`).

use nalgebra::Vector3;
use parry3d_f64::math::Vector as PVec;
use parry3d_f64::shape::ConvexPolyhedron;

use super::error::GeometryError;
use super::points::{
    FLATNESS_TOL, MAX_HULL_CANDIDATES, MAX_HULL_POINTS, VERTEX_MERGE_TOL, dedupe_points,
};

/// Two faces whose unit normals satisfy `n1·n2 > 1 − PLANE_DUP_TOL` (and whose
/// offsets agree) are the same plane and are merged.
const PLANE_DUP_TOL: f64 = 1e-9;

/// One face of a [`ConvexHull`], in the body frame: the constraint
/// `f(p) = normal·p − offset ≤ 0` of `docs/model.md#contact` (before the body pose is applied).
#[derive(Debug, Clone, PartialEq)]
pub struct Face {
    /// Outward unit normal `n̂_i` (body frame).
    pub normal: Vector3<f64>,
    /// Offset `d_i`: points of the hull satisfy `normal·p ≤ offset`.
    pub offset: f64,
    /// Indices into [`ConvexHull::vertices`] of the face's corners, ordered
    /// counter-clockwise seen from outside (right-handed about `normal`).
    pub vertices: Vec<usize>,
}

impl Face {
    /// Signed distance `normal·p − offset` of a body-frame point to the face's
    /// plane (≤ 0 inside).
    pub fn value(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) - self.offset
    }
}

/// Conv(F) in the body frame: its extreme vertices and its faces, with
/// coplanar triangles merged into one polygonal face each.
///
/// `docs/model.md#contact` requires merged faces: duplicate planes would make the face
/// multipliers `l_i` non-unique for no reason. A box has 6 faces, the desk 6,
/// the T-bar 8. Every stored vertex satisfies every face to rounding.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvexHull {
    vertices: Vec<Vector3<f64>>,
    faces: Vec<Face>,
    volume: f64,
    /// The largest distance of a vertex from the body origin ([`ConvexHull::radius`]).
    radius: f64,
}

fn to_parry(v: &Vector3<f64>) -> PVec {
    PVec::new(v.x, v.y, v.z)
}

fn from_parry(v: PVec) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

/// Size of a point set: the diagonal of its axis-aligned bounding box.
fn diameter(points: &[Vector3<f64>]) -> f64 {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (hi - lo).norm()
}

/// Index and value of the maximum of `f` over `points` (`points` non-empty).
fn argmax(points: &[Vector3<f64>], f: impl Fn(&Vector3<f64>) -> f64) -> (usize, f64) {
    points
        .iter()
        .enumerate()
        .map(|(i, p)| (i, f(p)))
        .fold((0, f64::NEG_INFINITY), |best, cur| {
            if cur.1 > best.1 { cur } else { best }
        })
}

/// Rejects point sets that do not span a volume.
///
/// Picks a far pair, then the point farthest from their line, then the point
/// farthest from the plane of the three. Any plane through a point of the set
/// has some point at least half the set's minimum width away, so a set whose
/// minimum width exceeds `2·FLATNESS_TOL·diameter` always passes.
fn check_not_flat(points: &[Vector3<f64>], diam: f64) -> Result<(), GeometryError> {
    let tol = FLATNESS_TOL * diam;
    let p0 = points[0];
    let (i1, d01) = argmax(points, |p| (p - p0).norm());
    if d01 <= tol || diam == 0.0 {
        return Err(GeometryError::Degenerate {
            kind: "coincident",
            thickness: d01,
            diameter: diam,
        });
    }
    let u = (points[i1] - p0) / d01;
    let (i2, dl) = argmax(points, |p| {
        let r = p - p0;
        (r - u * u.dot(&r)).norm()
    });
    if dl <= tol {
        return Err(GeometryError::Degenerate {
            kind: "collinear",
            thickness: dl,
            diameter: diam,
        });
    }
    let n = u.cross(&(points[i2] - p0)).normalize();
    let (_, dp) = argmax(points, |p| n.dot(&(p - p0)).abs());
    if dp <= tol {
        return Err(GeometryError::Degenerate {
            kind: "coplanar",
            thickness: dp,
            diameter: diam,
        });
    }
    Ok(())
}

/// Point sets up to this size go to the hull as they are; larger ones are first pruned with
/// [`prune_to_extreme_candidates`] and rid of exact duplicates.
const PRUNE_ABOVE: usize = 256;

/// Relative distance (× the point set's size) within which a point outside the inner polytope of
/// [`prune_to_extreme_candidates`] still counts as on it and is dropped.
const PRUNE_TOL: f64 = 1e-12;

/// Unit directions of the inner polytope: the 26 of a cube's faces, edges and corners, and 38
/// spread over the sphere by the golden-angle spiral.
fn prune_directions() -> Vec<Vector3<f64>> {
    let mut dirs = Vec::with_capacity(64);
    for x in [-1.0, 0.0, 1.0] {
        for y in [-1.0, 0.0, 1.0] {
            for z in [-1.0f64, 0.0, 1.0] {
                let d = Vector3::new(x, y, z);
                if d != Vector3::zeros() {
                    dirs.push(d.normalize());
                }
            }
        }
    }
    let k = 38;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..k {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / k as f64;
        let r = (1.0 - z * z).sqrt();
        let a = golden * i as f64;
        dirs.push(Vector3::new(r * a.cos(), r * a.sin(), z));
    }
    dirs
}

/// Indices of the points that can be extreme points of the set's convex hull, in their
/// original order: a cheap filter before the hull of a large mesh.
///
/// The points that maximise `d·p` over a fixed set of 64 directions `d` are extreme points;
/// their hull (the *inner polytope*) lies inside the hull of the whole set. A point inside the
/// inner polytope, or outside it by at most `10⁻¹²` × the set's size, is dropped: the hull of
/// what is kept then contains every dropped point to that distance, and equals the full hull
/// exactly whenever no point lies that close outside a face of the inner polytope. Points on
/// the surface of a finely subdivided box are dropped as well as interior ones. Non-finite
/// coordinates, or an inner polytope that is flat, keep every point.
pub fn prune_to_extreme_candidates(points: &[Vector3<f64>]) -> Vec<usize> {
    let all = || (0..points.len()).collect::<Vec<usize>>();
    if points.is_empty() || !points.iter().all(|p| p.iter().all(|c| c.is_finite())) {
        return all();
    }
    let dirs = prune_directions();
    let mut best = vec![(0usize, f64::NEG_INFINITY); dirs.len()];
    for (i, p) in points.iter().enumerate() {
        for (b, d) in best.iter_mut().zip(&dirs) {
            let v = d.dot(p);
            if v > b.1 {
                *b = (i, v);
            }
        }
    }
    let mut inner_idx: Vec<usize> = best.iter().map(|b| b.0).collect();
    inner_idx.sort_unstable();
    inner_idx.dedup();
    let inner_pts: Vec<Vector3<f64>> = inner_idx.iter().map(|&i| points[i]).collect();
    let Ok(inner) = ConvexHull::from_points(&inner_pts) else {
        return all();
    };
    let tol = PRUNE_TOL * diameter(points);
    let mut is_inner = vec![false; points.len()];
    for &i in &inner_idx {
        is_inner[i] = true;
    }
    (0..points.len())
        .filter(|&i| is_inner[i] || inner.faces.iter().any(|f| f.value(&points[i]) > tol))
        .collect()
}

/// The points of `idx` without exact repetitions (same coordinates bit for bit, after `-0.0`
/// is read as `0.0`), first occurrences kept, in their original order; `None` as soon as more
/// than `limit` distinct points are found.
fn without_exact_duplicates(
    points: &[Vector3<f64>],
    idx: &[usize],
    limit: usize,
) -> Option<Vec<Vector3<f64>>> {
    let mut seen = std::collections::HashSet::with_capacity(idx.len().min(limit + 1));
    let mut out = Vec::new();
    for &i in idx {
        let p = points[i];
        let key = [p.x, p.y, p.z].map(|c| if c == 0.0 { 0u64 } else { c.to_bits() });
        if seen.insert(key) {
            out.push(p);
            if out.len() > limit {
                return None;
            }
        }
    }
    Some(out)
}

/// Sorts `idx` counter-clockwise about `normal` around the centroid of the points.
fn order_ccw(idx: &mut [usize], vertices: &[Vector3<f64>], normal: &Vector3<f64>) {
    if idx.len() < 3 {
        return;
    }
    let c = idx.iter().map(|&i| vertices[i]).sum::<Vector3<f64>>() / idx.len() as f64;
    // Any unit vector perpendicular to the normal serves as the angle origin.
    let seed = if normal.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let a = (seed - normal * normal.dot(&seed)).normalize();
    let b = normal.cross(&a);
    let angle = |i: usize| {
        let r = vertices[i] - c;
        r.dot(&b).atan2(r.dot(&a))
    };
    idx.sort_by(|&i, &j| angle(i).total_cmp(&angle(j)));
}

/// Area of a face polygon whose vertices are ordered counter-clockwise.
fn face_area(face: &Face, vertices: &[Vector3<f64>]) -> f64 {
    let k = face.vertices.len();
    let mut s = Vector3::zeros();
    for j in 0..k {
        // Relative to the first corner, to avoid cancellation far from the origin.
        let p = vertices[face.vertices[j]] - vertices[face.vertices[0]];
        let q = vertices[face.vertices[(j + 1) % k]] - vertices[face.vertices[0]];
        s += p.cross(&q);
    }
    0.5 * face.normal.dot(&s)
}

impl ConvexHull {
    /// Convex hull of a point set (body frame), as vertices plus merged faces.
    ///
    /// Points closer than [`VERTEX_MERGE_TOL`](super::VERTEX_MERGE_TOL) are
    /// merged first. Errors: fewer than 4 distinct points, a non-finite
    /// coordinate, or a set that is coincident, collinear or coplanar
    /// (thickness below [`FLATNESS_TOL`](super::FLATNESS_TOL) × size).
    /// Interior and face points are dropped; only extreme vertices are kept.
    ///
    /// A set of more than 256 points (a mesh) is first reduced to the candidates of
    /// [`prune_to_extreme_candidates`] without exact duplicates. More than
    /// [`MAX_HULL_CANDIDATES`](super::MAX_HULL_CANDIDATES) candidates, or a hull with more
    /// than [`MAX_HULL_POINTS`](super::MAX_HULL_POINTS) vertices, are refused
    /// ([`GeometryError::TooManyPoints`]).
    pub fn from_points(points: &[Vector3<f64>]) -> Result<ConvexHull, GeometryError> {
        if let Some(i) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(GeometryError::NonFinite {
                what: format!("a coordinate of point {i}"),
            });
        }
        let pruned;
        let points = if points.len() > PRUNE_ABOVE {
            let candidates = prune_to_extreme_candidates(points);
            pruned = without_exact_duplicates(points, &candidates, MAX_HULL_CANDIDATES).ok_or(
                GeometryError::TooManyPoints {
                    count: MAX_HULL_CANDIDATES + 1,
                    limit: MAX_HULL_POINTS,
                },
            )?;
            &pruned[..]
        } else {
            points
        };
        let pts = dedupe_points(points, VERTEX_MERGE_TOL);
        if pts.len() < 4 {
            return Err(GeometryError::TooFewPoints { count: pts.len() });
        }
        let diam = diameter(&pts);
        check_not_flat(&pts, diam)?;

        let ppts: Vec<PVec> = pts.iter().map(to_parry).collect();
        // parry signals failure with `None`; guard against a panic on
        // pathological input too, so a bad scene file cannot abort the program.
        let poly = std::panic::catch_unwind(|| ConvexPolyhedron::from_convex_hull(&ppts))
            .ok()
            .flatten()
            .ok_or(GeometryError::HullFailed { count: pts.len() })?;

        if poly.points().len() > MAX_HULL_POINTS {
            return Err(GeometryError::TooManyPoints {
                count: poly.points().len(),
                limit: MAX_HULL_POINTS,
            });
        }
        let vertices: Vec<Vector3<f64>> = poly.points().iter().map(|p| from_parry(*p)).collect();
        let adj = poly.vertices_adj_to_face();
        let mut faces: Vec<Face> = Vec::with_capacity(poly.faces().len());
        for f in poly.faces() {
            let first = f.first_vertex_or_edge as usize;
            let count = f.num_vertices_or_edges as usize;
            let idx: Vec<usize> = adj
                .get(first..first + count)
                .ok_or(GeometryError::HullFailed { count: pts.len() })?
                .iter()
                .map(|&i| i as usize)
                .collect();
            let normal = from_parry(f.normal);
            let len = normal.norm();
            if !(len.is_finite() && len > 0.0) || idx.len() < 3 {
                return Err(GeometryError::HullFailed { count: pts.len() });
            }
            let normal = normal / len;
            // Tightest plane with this normal: every vertex is inside exactly.
            let (_, offset) = argmax(&vertices, |p| normal.dot(p));
            faces.push(Face {
                normal,
                offset,
                vertices: idx,
            });
        }

        // Defensive: merge faces that are the same plane (parry merges coplanar
        // triangles itself, but a duplicate would make multipliers non-unique).
        let offset_tol = PLANE_DUP_TOL * diam.max(1.0);
        let mut merged: Vec<Face> = Vec::with_capacity(faces.len());
        for f in faces {
            match merged.iter_mut().find(|g| {
                g.normal.dot(&f.normal) > 1.0 - PLANE_DUP_TOL
                    && (g.offset - f.offset).abs() <= offset_tol
            }) {
                Some(g) => {
                    for i in f.vertices {
                        if !g.vertices.contains(&i) {
                            g.vertices.push(i);
                        }
                    }
                }
                None => merged.push(f),
            }
        }
        for f in &mut merged {
            order_ccw(&mut f.vertices, &vertices, &f.normal);
        }

        // Sanity: every input point must lie inside the hull.
        let inside_tol = FLATNESS_TOL * diam;
        if pts
            .iter()
            .any(|p| merged.iter().any(|f| f.value(p) > inside_tol))
        {
            return Err(GeometryError::HullFailed { count: pts.len() });
        }

        // Sum of pyramids from the vertex centroid (not the origin: no cancellation).
        let centroid = vertices.iter().sum::<Vector3<f64>>() / vertices.len() as f64;
        let volume: f64 = merged
            .iter()
            .map(|f| f.value(&centroid).abs() * face_area(f, &vertices) / 3.0)
            .sum();
        if !(volume.is_finite() && volume > 0.0) {
            return Err(GeometryError::Degenerate {
                kind: "coplanar",
                thickness: 0.0,
                diameter: diam,
            });
        }

        let radius = vertices.iter().map(|v| v.norm()).fold(0.0, f64::max);
        Ok(ConvexHull {
            vertices,
            faces: merged,
            volume,
            radius,
        })
    }

    /// Extreme vertices of the hull (body frame).
    pub fn vertices(&self) -> &[Vector3<f64>] {
        &self.vertices
    }

    /// Faces of the hull, one per distinct plane (body frame).
    pub fn faces(&self) -> &[Face] {
        &self.faces
    }

    /// Number of faces `m`: the number of multipliers `l_i` in the step problem
    /// (`docs/model.md#unknowns`).
    pub fn num_faces(&self) -> usize {
        self.faces.len()
    }

    /// Volume enclosed by the hull (m³).
    pub fn volume(&self) -> f64 {
        self.volume
    }

    /// The largest distance of a vertex from the body origin (m): the hull's size, the scale
    /// of the tolerance of "on a face" in the warm start's closest-point guesses.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// A vertex maximising `dir·p` (body frame). Used for the first-step
    /// warm start, `a1` = support point towards G (`docs/model.md#stepper`).
    pub fn support_point(&self, dir: &Vector3<f64>) -> Vector3<f64> {
        let (i, _) = argmax(&self.vertices, |p| dir.dot(p));
        self.vertices[i]
    }

    /// Index of the face whose outward normal is most aligned with `dir`
    /// (body frame). With `dir = −Rᵀ n_G` this is the face most anti-parallel
    /// to the plane normal, which gets multiplier 1 in the warm start (`docs/model.md#stepper`).
    pub fn most_aligned_face(&self, dir: &Vector3<f64>) -> usize {
        self.faces
            .iter()
            .enumerate()
            .map(|(i, f)| (i, f.normal.dot(dir)))
            .fold((0, f64::NEG_INFINITY), |best, cur| {
                if cur.1 > best.1 { cur } else { best }
            })
            .0
    }

    /// Whether the body-frame point `p` satisfies every face within `tol`:
    /// `normal·p − offset ≤ tol` for all faces.
    pub fn contains(&self, p: &Vector3<f64>, tol: f64) -> bool {
        self.faces.iter().all(|f| f.value(p) <= tol)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rotation::{quat_from_rpy_deg, rotation_matrix};

    fn box_corners(hx: f64, hy: f64, hz: f64) -> Vec<Vector3<f64>> {
        let mut v = Vec::new();
        for sx in [-1.0, 1.0] {
            for sy in [-1.0, 1.0] {
                for sz in [-1.0, 1.0] {
                    v.push(Vector3::new(sx * hx, sy * hy, sz * hz));
                }
            }
        }
        v
    }

    fn check_hull(h: &ConvexHull, tol: f64) {
        for f in h.faces() {
            assert!((f.normal.norm() - 1.0).abs() < 1e-14);
            for v in h.vertices() {
                assert!(f.value(v) <= tol, "vertex outside face by {}", f.value(v));
            }
            for &i in &f.vertices {
                assert!(f.value(&h.vertices()[i]).abs() <= tol);
            }
        }
        for (i, f) in h.faces().iter().enumerate() {
            for g in &h.faces()[i + 1..] {
                assert!(f.normal.dot(&g.normal) < 1.0 - 1e-6, "duplicate plane");
            }
        }
    }

    #[test]
    fn box_has_six_faces() {
        let h = ConvexHull::from_points(&box_corners(0.2, 0.2, 0.1)).unwrap();
        assert_eq!(h.num_faces(), 6);
        assert_eq!(h.vertices().len(), 8);
        check_hull(&h, 1e-12);
        for f in h.faces() {
            assert_eq!(f.vertices.len(), 4);
        }
        assert!((h.volume() - 0.4 * 0.4 * 0.2).abs() < 1e-14);
        assert_eq!(
            h.support_point(&Vector3::new(1.0, 2.0, -3.0)),
            Vector3::new(0.2, 0.2, -0.1)
        );
        let bottom = h.most_aligned_face(&-Vector3::z());
        assert!((h.faces()[bottom].normal + Vector3::z()).norm() < 1e-14);
        assert!((h.faces()[bottom].offset - 0.1).abs() < 1e-15);
        assert!(h.contains(&Vector3::new(0.2, 0.0, 0.0), 1e-12));
        assert!(!h.contains(&Vector3::new(0.2 + 1e-9, 0.0, 0.0), 1e-12));
    }

    #[test]
    fn face_vertices_are_counter_clockwise() {
        let h = ConvexHull::from_points(&box_corners(1.0, 2.0, 3.0)).unwrap();
        for f in h.faces() {
            let a = face_area(f, h.vertices());
            assert!(a > 0.0);
        }
    }

    #[test]
    fn rotated_offset_box_with_extra_points() {
        let r = rotation_matrix(&quat_from_rpy_deg(20.0, -35.0, 71.0));
        let c = Vector3::new(1e3, -2.0, 5.0);
        let mut pts: Vec<_> = box_corners(0.3, 0.1, 0.05)
            .iter()
            .map(|p| c + r * p)
            .collect();
        // Face centres, an edge midpoint, an interior point and repeated corners.
        pts.push(c + r * Vector3::new(0.3, 0.0, 0.0));
        pts.push(c + r * Vector3::new(0.0, 0.1, 0.05));
        pts.push(c);
        let copy = pts[..8].to_vec();
        pts.extend(copy);
        let h = ConvexHull::from_points(&pts).unwrap();
        assert_eq!(h.num_faces(), 6);
        assert_eq!(h.vertices().len(), 8);
        check_hull(&h, 1e-12);
        assert!((h.volume() - 0.6 * 0.2 * 0.1).abs() < 1e-12);
        for p in &pts {
            assert!(h.contains(p, 1e-12));
        }
    }

    #[test]
    fn degenerate_inputs_are_rejected() {
        let flat: Vec<_> = box_corners(1.0, 1.0, 0.0);
        assert!(matches!(
            ConvexHull::from_points(&flat),
            Err(GeometryError::Degenerate {
                kind: "coplanar",
                ..
            })
        ));
        let nearly_flat: Vec<_> = box_corners(1.0, 1.0, 1e-11);
        assert!(matches!(
            ConvexHull::from_points(&nearly_flat),
            Err(GeometryError::Degenerate {
                kind: "coplanar",
                ..
            })
        ));
        let line: Vec<_> = (0..6)
            .map(|i| Vector3::new(1.0, 2.0, 3.0) * i as f64)
            .collect();
        assert!(matches!(
            ConvexHull::from_points(&line),
            Err(GeometryError::Degenerate {
                kind: "collinear",
                ..
            })
        ));
        let few = box_corners(1.0, 1.0, 1.0)[..3].to_vec();
        assert!(matches!(
            ConvexHull::from_points(&few),
            Err(GeometryError::TooFewPoints { count: 3 })
        ));
        let same = vec![Vector3::new(1.0, 1.0, 1.0); 5];
        assert!(matches!(
            ConvexHull::from_points(&same),
            Err(GeometryError::TooFewPoints { count: 1 })
        ));
        let mut nan = box_corners(1.0, 1.0, 1.0);
        nan[3].y = f64::NAN;
        let err = ConvexHull::from_points(&nan).unwrap_err();
        assert!(matches!(err, GeometryError::NonFinite { .. }));
        assert!(err.to_string().contains("point 3"));
    }

    #[test]
    fn tetrahedron() {
        let pts = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        let h = ConvexHull::from_points(&pts).unwrap();
        assert_eq!(h.num_faces(), 4);
        check_hull(&h, 1e-15);
        assert!((h.volume() - 1.0 / 6.0).abs() < 1e-15);
    }

    /// Deterministic pseudo-random numbers in [−1, 1).
    fn lcg(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        }
    }

    /// Vertices of parry's hull of all the points, without any pruning.
    fn parry_hull_vertices(points: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let ppts: Vec<PVec> = points.iter().map(to_parry).collect();
        ConvexPolyhedron::from_convex_hull(&ppts)
            .unwrap()
            .points()
            .iter()
            .map(|p| from_parry(*p))
            .collect()
    }

    fn same_point_sets(a: &[Vector3<f64>], b: &[Vector3<f64>], tol: f64) -> bool {
        a.len() == b.len()
            && a.iter().all(|p| b.iter().any(|q| (p - q).amax() <= tol))
            && b.iter().all(|p| a.iter().any(|q| (p - q).amax() <= tol))
    }

    #[test]
    fn box_with_interior_and_repeated_points_is_pruned_to_its_corners() {
        let r = rotation_matrix(&quat_from_rpy_deg(10.0, 20.0, 30.0));
        let c = Vector3::new(0.5, -1.0, 2.0);
        let corners: Vec<_> = box_corners(0.2, 0.15, 0.1)
            .iter()
            .map(|p| c + r * p)
            .collect();
        let mut rnd = lcg(7);
        let mut pts = Vec::new();
        for _ in 0..5000 {
            let p = Vector3::new(0.2 * rnd(), 0.15 * rnd(), 0.1 * rnd());
            pts.push(c + r * p);
        }
        // Every corner three times, interleaved with the interior points.
        for k in 0..3 {
            for (j, q) in corners.iter().enumerate() {
                pts.insert(k * 1000 + j * 7, *q);
            }
        }
        let kept = prune_to_extreme_candidates(&pts);
        assert!(kept.len() < 30, "{} candidates kept", kept.len());
        let h = ConvexHull::from_points(&pts).unwrap();
        assert_eq!(h.vertices().len(), 8);
        assert_eq!(h.num_faces(), 6);
        check_hull(&h, 1e-12);
        assert!(same_point_sets(h.vertices(), &corners, 1e-15));
        assert!((h.volume() - 0.4 * 0.3 * 0.2).abs() < 1e-14);
        for p in &pts {
            assert!(h.contains(p, 1e-12));
        }
    }

    #[test]
    fn pruning_keeps_every_extreme_point_of_a_random_cloud() {
        // Points in a ball: a few hundred of the 20 000 are extreme points.
        let mut rnd = lcg(11);
        let mut pts = Vec::new();
        while pts.len() < 20_000 {
            let p = Vector3::new(rnd(), rnd(), rnd());
            if p.norm() <= 1.0 {
                pts.push(Vector3::new(3.0, 2.0, 1.0).component_mul(&p));
            }
        }
        let full = parry_hull_vertices(&pts);
        let kept = prune_to_extreme_candidates(&pts);
        assert!(kept.len() < pts.len() / 4, "{} kept", kept.len());
        for v in &full {
            assert!(
                kept.iter().any(|&i| pts[i] == *v),
                "extreme point {v:?} dropped"
            );
        }
        let h = ConvexHull::from_points(&pts).unwrap();
        assert!(same_point_sets(h.vertices(), &full, 0.0));
        // Every point of the full set, pruned or not, is inside the hull.
        for p in &pts {
            assert!(h.contains(p, 1e-12));
        }
    }

    #[test]
    fn surface_points_of_a_tiled_box_are_dropped() {
        let mut pts = Vec::new();
        let k = 20;
        for i in 0..=k {
            for j in 0..=k {
                let (a, b) = (
                    2.0 * i as f64 / k as f64 - 1.0,
                    2.0 * j as f64 / k as f64 - 1.0,
                );
                for s in [-1.0, 1.0] {
                    pts.push(Vector3::new(s * 0.2, 0.15 * a, 0.1 * b));
                    pts.push(Vector3::new(0.2 * a, s * 0.15, 0.1 * b));
                    pts.push(Vector3::new(0.2 * a, 0.15 * b, s * 0.1));
                }
            }
        }
        let kept = prune_to_extreme_candidates(&pts);
        let h = ConvexHull::from_points(&pts).unwrap();
        assert_eq!(h.vertices().len(), 8);
        assert_eq!(h.num_faces(), 6);
        assert!(kept.len() < 30, "{} kept", kept.len());
    }

    #[test]
    fn too_many_extreme_points_are_refused_with_the_limit() {
        // A Fibonacci sphere: every point is an extreme point.
        let n = MAX_HULL_POINTS + 1;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let pts: Vec<_> = (0..n)
            .map(|i| {
                let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let a = golden * i as f64;
                Vector3::new(r * a.cos(), r * a.sin(), z)
            })
            .collect();
        let err = ConvexHull::from_points(&pts).unwrap_err();
        assert_eq!(
            err,
            GeometryError::TooManyPoints {
                count: n,
                limit: MAX_HULL_POINTS
            }
        );
        assert!(err.to_string().contains("decimate"), "{err}");
        // Exactly the limit, some points repeated: accepted, every point a vertex.
        let mut fewer = pts[..MAX_HULL_POINTS].to_vec();
        fewer.extend_from_slice(&pts[..100]);
        let h = ConvexHull::from_points(&fewer).unwrap();
        assert_eq!(h.vertices().len(), MAX_HULL_POINTS);
    }
}
