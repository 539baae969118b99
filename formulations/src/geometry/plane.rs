//! The fixed half-space G and state-only queries against it: gap, contact frame and contact mode
//! (`docs/model.md#newton-euler`, `docs/model.md#contact`, `docs/model.md#invariants`; scenario C).

use std::fmt;

use nalgebra::{Matrix3, Vector3};

use super::error::GeometryError;
use super::points::{VERTEX_MERGE_TOL, dedupe_points};

/// A fixed obstacle G = { p : normal·p − offset ≤ 0 } (`docs/model.md#contact`,
/// `g(p) = n_Gᵀ p − c`). The unit normal points out of G, into the body's side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HalfSpace {
    normal: Vector3<f64>,
    offset: f64,
}

impl HalfSpace {
    /// Half-space `{ p : normal·p ≤ offset }`. The normal need not be unit:
    /// both `normal` and `offset` are divided by `|normal|`, which keeps the set
    /// and makes `g` a signed distance. Zero or non-finite input is an error.
    pub fn new(normal: Vector3<f64>, offset: f64) -> Result<Self, GeometryError> {
        if !(normal.iter().all(|c| c.is_finite()) && offset.is_finite()) {
            return Err(GeometryError::NonFinite {
                what: "the normal or offset of a half-space".into(),
            });
        }
        let len = normal.norm();
        if len == 0.0 {
            return Err(GeometryError::ZeroNormal);
        }
        Ok(HalfSpace {
            normal: normal / len,
            offset: offset / len,
        })
    }

    /// The flat ground z ≤ 0: normal `e_z`, offset 0 (`docs/model.md#contact`).
    pub fn ground() -> Self {
        HalfSpace {
            normal: Vector3::z(),
            offset: 0.0,
        }
    }

    /// The incline of scenario A4 through the origin, rising towards +x:
    /// normal `(−sin θ, 0, cos θ)` for `theta_rad` = θ. Errors on non-finite θ.
    pub fn incline(theta_rad: f64) -> Result<Self, GeometryError> {
        if !theta_rad.is_finite() {
            return Err(GeometryError::NonFinite {
                what: "the incline angle".into(),
            });
        }
        let (s, c) = theta_rad.sin_cos();
        Ok(HalfSpace {
            normal: Vector3::new(-s, 0.0, c),
            offset: 0.0,
        })
    }

    /// Unit normal `n_G` (= `∇g`), pointing from G into the body's side.
    pub fn normal(&self) -> Vector3<f64> {
        self.normal
    }

    /// Offset `c` in `g(p) = n_G·p − c`.
    pub fn offset(&self) -> f64 {
        self.offset
    }

    /// `g(p) = n_G·p − c`: the signed distance of `p` to the plane, > 0 outside G.
    pub fn value(&self, p: &Vector3<f64>) -> f64 {
        self.normal.dot(p) - self.offset
    }

    /// Orthogonal projection of `p` onto the plane `g = 0` (the warm start of
    /// `a2`, `docs/model.md#stepper`).
    pub fn project(&self, p: &Vector3<f64>) -> Vector3<f64> {
        p - self.normal * self.value(p)
    }

    /// Right-handed contact frame `(n, t, o)` for the wrenches of `docs/model.md#newton-euler`:
    /// `n` = the normal; `t` = `e_x` projected onto the plane and normalised
    /// (`e_y` if `|e_x·n| > 0.9`); `o = n × t`. Ground: `(e_z, e_x, e_y)`;
    /// incline θ: `t = (cos θ, 0, sin θ)` (up the slope), `o = e_y`.
    pub fn contact_frame(&self) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let n = self.normal;
        let seed = if n.x.abs() > 0.9 {
            Vector3::y()
        } else {
            Vector3::x()
        };
        let t = (seed - n * n.dot(&seed)).normalize();
        let o = n.cross(&t);
        (n, t, o)
    }
}

/// Contact mode of a body against a plane, from the state alone (scenario C).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ContactMode {
    /// Three or more touching vertices, not collinear (surface contact).
    Patch,
    /// Two touching vertices, or more all on one line (edge / two-point contact).
    Line,
    /// One touching vertex.
    Point,
    /// No vertex touches.
    None,
}

impl ContactMode {
    /// Lower-case name as written to result files: "patch", "line", "point", "none".
    pub fn as_str(&self) -> &'static str {
        match self {
            ContactMode::Patch => "patch",
            ContactMode::Line => "line",
            ContactMode::Point => "point",
            ContactMode::None => "none",
        }
    }
}

impl fmt::Display for ContactMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Classifies the contact of a body with `plane` from its world-frame
/// vertices (those of the real, non-convex body; scenario C uses tol = 1e-7).
///
/// A vertex touches when `g ≤ tol` (penetrating vertices count too).
/// Coincident vertices are merged first. Touching vertices that all lie within
/// `tol` of one point give `Point`; within `tol` of one line, `Line`;
/// otherwise `Patch`.
pub fn contact_mode(world_vertices: &[Vector3<f64>], plane: &HalfSpace, tol: f64) -> ContactMode {
    let touching: Vec<Vector3<f64>> = world_vertices
        .iter()
        .filter(|p| plane.value(p) <= tol)
        .copied()
        .collect();
    mode_of_touching(&dedupe_points(&touching, VERTEX_MERGE_TOL), tol)
}

/// [`contact_mode`] of a body with body-frame vertices `body_vertices` at CM position `x` and
/// rotation `r`, the touching vertices gathered in `touching`, whose storage is reused
/// (allocation-free once it has grown: the records of every step). The same mode.
pub fn contact_mode_at(
    body_vertices: &[Vector3<f64>],
    pose: (&Vector3<f64>, &Matrix3<f64>),
    plane: &HalfSpace,
    tol: f64,
    touching: &mut Vec<Vector3<f64>>,
) -> ContactMode {
    gap_and_mode_at(body_vertices, pose, plane, tol, touching).1
}

/// [`min_gap`] and [`contact_mode_at`] together, from one pass over the vertices' world
/// positions (a contact record needs both): the same numbers as the two calls.
pub fn gap_and_mode_at(
    body_vertices: &[Vector3<f64>],
    pose: (&Vector3<f64>, &Matrix3<f64>),
    plane: &HalfSpace,
    tol: f64,
    touching: &mut Vec<Vector3<f64>>,
) -> (f64, ContactMode) {
    gap_and_mode_merging::<true>(body_vertices, pose, plane, tol, touching)
}

/// [`gap_and_mode_at`] for vertices whose [`VertexSpacing`] is `spacing`: the touching vertices'
/// merge tests are skipped where the spacing shows no two world vertices can merge
/// ([`VertexSpacing::never_merge_at`]; 120 pairs on a desk record). The same numbers.
pub fn gap_and_mode_spaced(
    body_vertices: &[Vector3<f64>],
    spacing: &VertexSpacing,
    pose: (&Vector3<f64>, &Matrix3<f64>),
    plane: &HalfSpace,
    tol: f64,
    touching: &mut Vec<Vector3<f64>>,
) -> (f64, ContactMode) {
    if spacing.count != body_vertices.len() {
        gap_and_mode_merging::<true>(body_vertices, pose, plane, tol, touching)
    } else if spacing.never_merge_at(pose.0) {
        gap_and_mode_bounded::<false>(body_vertices, spacing.extent, pose, plane, tol, touching)
    } else {
        gap_and_mode_bounded::<true>(body_vertices, spacing.extent, pose, plane, tol, touching)
    }
}

/// [`gap_and_mode_merging`] that skips the world position of every vertex whose gap provably
/// can be neither the least nor within `tol` (a desk at rest: its 24 vertices off the floor).
/// `extent` bounds the vertices' coordinates (`VertexSpacing::extent`). The same numbers.
///
/// The bound: `b = (Rᵀn)·v` (computed), so that `g = n·(x + R v) − c ≈ lift + b` with
/// `lift = n·x − c`. With `U = ‖x‖₁ + 3 extent Σ|R_ij|` (at least `‖x‖∞ + 3 max|R| extent`,
/// which bounds every term), the computed `g` and `lift + b` are each within about 60 units of
/// round-off of `U` (and 2 of `|c|`) of the exact value (dot products of three terms,
/// `|n| = 1`); `margin` = 1e-13 (U + |c| + |tol|), over 15 times both together, also covers
/// the round-off of the thresholds' own sums. A vertex with `b > (tol − lift) + 2 margin`
/// has `g > tol`: it does not touch. The first pass skips those; if a kept vertex touches,
/// the skipped ones are above its gap too, so the least gap and the touching points are
/// those of every vertex. Otherwise a second pass from the start keeps besides the vertices
/// with `b ≤ lowest + 3 margin`: a vertex above that has its gap above that of the vertex of
/// the least bound (kept), so it is not the least. Either way the vertices kept are computed
/// as before and in the same order: the touching points, their merges and the mode are the
/// same, and the least gap the same bits (a skipped gap is above it, so `min` with it would
/// have returned the other operand; ties, ±0 among them, are all kept, in order). NaN bounds
/// are never skipped; a non-finite `lift` or margin (non-finite input) takes every vertex.
#[inline(always)]
fn gap_and_mode_bounded<const MERGE: bool>(
    body_vertices: &[Vector3<f64>],
    extent: f64,
    (x, r): (&Vector3<f64>, &Matrix3<f64>),
    plane: &HalfSpace,
    tol: f64,
    touching: &mut Vec<Vector3<f64>>,
) -> (f64, ContactMode) {
    let w = r.tr_mul(&plane.normal);
    let lift = plane.normal.dot(x) - plane.offset;
    let size = x.abs().sum() + 3.0 * r.abs().sum() * extent + plane.offset.abs() + tol.abs();
    let margin = 1e-13 * size + f64::MIN_POSITIVE;
    if !(lift.is_finite() && margin.is_finite()) {
        return gap_and_mode_merging::<MERGE>(body_vertices, (x, r), plane, tol, touching);
    }
    let near = (tol - lift) + 2.0 * margin;
    let pose = (x, r);
    let mut gap = gap_of_kept::<MERGE>(body_vertices, &w, near, pose, plane, tol, touching);
    // Neither is NaN here (`min` passes NaN over; a NaN `tol` made the margin NaN above).
    if gap > tol {
        let lowest = body_vertices
            .iter()
            .map(|v| w.dot(v))
            .fold(f64::INFINITY, |m, b| if b < m { b } else { m });
        let cut = (lowest + 3.0 * margin).max(near);
        gap = gap_of_kept::<MERGE>(body_vertices, &w, cut, pose, plane, tol, touching);
    }
    // Every computed world coordinate is within `size` (to round-off).
    let mode = if size <= 1e75 {
        mode_of_touching_moderate(touching, tol)
    } else {
        mode_of_touching(touching, tol)
    };
    (gap, mode)
}

/// The pass of [`gap_and_mode_bounded`]: the vertices with `w·v ≤ cut` (or NaN) as
/// `gap_and_mode_merging` takes them; their least gap. Copies of `w`, `x` and `R` stay in
/// registers across the pushes.
#[inline(always)]
fn gap_of_kept<const MERGE: bool>(
    body_vertices: &[Vector3<f64>],
    w: &Vector3<f64>,
    cut: f64,
    (x, r): (&Vector3<f64>, &Matrix3<f64>),
    plane: &HalfSpace,
    tol: f64,
    touching: &mut Vec<Vector3<f64>>,
) -> f64 {
    let (w, x, r, plane) = (*w, *x, *r, *plane);
    touching.clear();
    let mut gap = f64::INFINITY;
    for v in body_vertices {
        if w.dot(v) > cut {
            continue;
        }
        let p = x + r * v;
        let g = plane.value(&p);
        gap = gap.min(g);
        if g <= tol && !(MERGE && touching.iter().any(|q| merges(q, &p))) {
            touching.push(p);
        }
    }
    gap
}

/// [`gap_and_mode_at`], the merge tests made only when `MERGE`.
#[inline(always)]
fn gap_and_mode_merging<const MERGE: bool>(
    body_vertices: &[Vector3<f64>],
    (x, r): (&Vector3<f64>, &Matrix3<f64>),
    plane: &HalfSpace,
    tol: f64,
    touching: &mut Vec<Vector3<f64>>,
) -> (f64, ContactMode) {
    touching.clear();
    let mut gap = f64::INFINITY;
    for v in body_vertices {
        // The world vertex of `world_vertices`, merged as `dedupe_points` merges.
        let p = x + r * v;
        let g = plane.value(&p);
        gap = gap.min(g);
        if g <= tol && !(MERGE && touching.iter().any(|q| merges(q, &p))) {
            touching.push(p);
        }
    }
    (gap, mode_of_touching(touching, tol))
}

/// How far apart a body's vertices are (body frame): the least distance between two of them
/// and their largest coordinate. Decides when the world positions `x + R v` of no two of them
/// can merge ([`VERTEX_MERGE_TOL`]), whatever the rotation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VertexSpacing {
    least: f64,
    extent: f64,
    count: usize,
}

impl VertexSpacing {
    /// Above this many vertices the spacing is not computed (its pairs grow as the square);
    /// such a body keeps its merge tests.
    pub const MAX_VERTICES: usize = 256;

    /// The spacing of `vertices` (body frame); least distance 0 (every merge test made) for
    /// more than [`Self::MAX_VERTICES`] of them.
    pub fn of(vertices: &[Vector3<f64>]) -> Self {
        let mut least = f64::INFINITY;
        if vertices.len() <= Self::MAX_VERTICES {
            for (i, a) in vertices.iter().enumerate() {
                for b in &vertices[i + 1..] {
                    least = least.min((a - b).norm());
                }
            }
        } else {
            least = 0.0;
        }
        let extent = vertices.iter().fold(0.0, |m: f64, v| m.max(v.amax()));
        VertexSpacing {
            least,
            extent,
            count: vertices.len(),
        }
    }

    /// Whether no two of the vertices' world positions `x + R v`, as computed, can be within
    /// [`VERTEX_MERGE_TOL`] at position `x` and any rotation `R` (of a unit quaternion).
    /// Each computed world coordinate is off by at most a few units of round-off of
    /// `‖x‖∞ + 3 extent` (2⁻⁵³ each; `R`'s entries at most 1 to round-off), and `R` keeps
    /// lengths to a relative 1e-15; the margin `1e-14 (‖x‖∞ + 3 extent)` covers twice that by
    /// far, and the least distance must exceed twice the tolerance besides. False for
    /// non-finite `x`.
    pub fn never_merge_at(&self, x: &Vector3<f64>) -> bool {
        let round_off = 1e-14 * (x.amax() + 3.0 * self.extent);
        x.iter().all(|c| c.is_finite()) && self.least > 2.0 * VERTEX_MERGE_TOL + round_off
    }
}

/// Whether `q` and `p` merge as one vertex: `|q − p| ≤ VERTEX_MERGE_TOL`. A coordinate more than
/// twice the tolerance apart decides it without the norm (the first one tested alone, the
/// cheapest test): the computed norm is at least that coordinate's difference to within a
/// relative 2⁻⁵², so it could not be within the tolerance.
#[inline]
fn merges(q: &Vector3<f64>, p: &Vector3<f64>) -> bool {
    const APART: f64 = 2.0 * VERTEX_MERGE_TOL;
    if (q.x - p.x).abs() > APART {
        return false;
    }
    let d = q - p;
    if d.amax() > APART {
        return false;
    }
    d.norm() <= VERTEX_MERGE_TOL
}

/// The mode of the touching vertices `touching` (merged, in order): see [`contact_mode`].
fn mode_of_touching(touching: &[Vector3<f64>], tol: f64) -> ContactMode {
    let Some(p0) = touching.first().copied() else {
        return ContactMode::None;
    };
    let far = |f: &dyn Fn(&Vector3<f64>) -> f64| {
        touching.iter().map(|p| (*p, f(p))).fold(
            (p0, 0.0),
            |best, cur| if cur.1 > best.1 { cur } else { best },
        )
    };
    let (p1, spread) = far(&|p| (p - p0).norm());
    if spread <= tol {
        return ContactMode::Point;
    }
    let u = (p1 - p0) / spread;
    let off_line = |p: &Vector3<f64>| {
        let r = p - p0;
        (r - u * u.dot(&r)).norm()
    };
    // The largest distance from the line (from 0, NaN passed over) is within `tol` exactly
    // when none is above it: the first point above decides (on the desk, one of the first few
    // of its sixteen touching vertices).
    if 0.0 <= tol && !touching.iter().any(|p| off_line(p) > tol) {
        ContactMode::Line
    } else {
        ContactMode::Patch
    }
}

/// [`mode_of_touching`] of touching points whose coordinates are at most 1e75 in magnitude (no
/// square below overflows), deciding `Patch` from the first three points alone where they
/// prove it (a desk at rest: three corners of a leg), without the pass for the farthest point.
///
/// Why that is the same mode: with `r_a`, `r_b` the second and third points less the first,
/// and any unit direction `û`, `|r_a × r_b| ≤ |r_a| d_b + |r_b| d_a + d_a d_b` (`d` the distance
/// from the line through the first point along `û`), so if `|r_a × r_b| > s (|r_a| + |r_b| + s)`
/// one of `d_a`, `d_b` exceeds `s`. `mode_of_touching`'s line runs along its computed `u`,
/// a unit vector to a few units of round-off; its computed distance of a point `r` is then
/// within about 25 units of round-off of `|r|` of the exact one, so `s = tol + 1e-14 (|r_a| +
/// |r_b|)` makes one computed distance exceed `tol`: `Patch`, as the spread (at least `|r_a|`,
/// the same computed norm) exceeds `tol` too. The computed cross product's norm is within
/// about 12 units of round-off of `|r_a| |r_b|` of the exact one: the `1e-14 |r_a| |r_b|` term
/// and the factor `1 + 1e-13` cover that and the bound's own round-off. Lengths below 1e-100
/// (products near underflow), a negative or NaN `tol`, or fewer than three points: the full
/// test.
fn mode_of_touching_moderate(touching: &[Vector3<f64>], tol: f64) -> ContactMode {
    if let [p0, a, b, ..] = touching {
        let (ra, rb) = (a - p0, b - p0);
        let (na, nb) = (ra.norm(), rb.norm());
        let s = tol + 1e-14 * (na + nb);
        let bound = (1.0 + 1e-13) * s * (na + nb + s) + 1e-14 * na * nb;
        if tol >= 0.0
            && (na > tol || nb > tol)
            && na.min(nb) >= 1e-100
            && ra.cross(&rb).norm() > bound
        {
            return ContactMode::Patch;
        }
    }
    mode_of_touching(touching, tol)
}

/// World-frame positions `x + R v` of body-frame vertices `v`, for a body at
/// CM position `x` with rotation `r` (body → world).
pub fn world_vertices(
    body_vertices: &[Vector3<f64>],
    x: &Vector3<f64>,
    r: &Matrix3<f64>,
) -> Vec<Vector3<f64>> {
    body_vertices.iter().map(|v| x + r * v).collect()
}

/// Minimum gap `min_v g(x + R v)` over body-frame vertices (`docs/model.md#invariants`: it must
/// stay ≥ −1e-9 at every step end). `+∞` for an empty vertex list.
pub fn min_gap(
    shape_vertices_body: &[Vector3<f64>],
    x: &Vector3<f64>,
    r: &Matrix3<f64>,
    plane: &HalfSpace,
) -> f64 {
    shape_vertices_body
        .iter()
        .map(|v| plane.value(&(x + r * v)))
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Shape;
    use crate::rotation::{quat_from_rpy_deg, rotation_matrix};

    /// Uniform numbers in [−0.5, 0.5) from a 64-bit LCG seeded with `seed` (the tests' random
    /// point sets, reproducible).
    fn uniform_centred(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    const TOL: f64 = 1e-7;

    /// Mode of `shape` at orientation (roll, pitch, yaw) in degrees, lowered
    /// onto the ground (min gap 0) and then lifted by `lift`.
    fn mode(shape: &Shape, rpy: (f64, f64, f64), lift: f64) -> ContactMode {
        let r = rotation_matrix(&quat_from_rpy_deg(rpy.0, rpy.1, rpy.2));
        let ground = HalfSpace::ground();
        let gap = min_gap(shape.vertices(), &Vector3::zeros(), &r, &ground);
        let x = Vector3::new(0.3, -0.1, lift - gap);
        assert!((min_gap(shape.vertices(), &x, &r, &ground) - lift).abs() < 1e-15);
        contact_mode(&world_vertices(shape.vertices(), &x, &r), &ground, TOL)
    }

    #[test]
    fn box_modes() {
        let b = Shape::cuboid(0.4, 0.4, 0.2).unwrap();
        assert_eq!(mode(&b, (0.0, 0.0, 37.0), 0.0), ContactMode::Patch);
        assert_eq!(mode(&b, (0.0, 0.0, 0.0), 5e-8), ContactMode::Patch);
        assert_eq!(mode(&b, (0.0, 0.0, 0.0), -1e-3), ContactMode::Patch);
        assert_eq!(mode(&b, (0.0, 30.0, 10.0), 0.0), ContactMode::Line);
        assert_eq!(mode(&b, (20.0, 10.0, 0.0), 0.0), ContactMode::Point);
        assert_eq!(mode(&b, (0.0, 0.0, 0.0), 1e-3), ContactMode::None);
        assert_eq!(mode(&b, (20.0, 10.0, 0.0), 2e-7), ContactMode::None);
    }

    #[test]
    fn desk_and_t_bar_modes() {
        let desk = Shape::desk();
        let r = Matrix3::identity();
        let x = Vector3::new(0.0, 0.0, 0.45);
        let world = world_vertices(desk.vertices(), &x, &r);
        let touching = world.iter().filter(|p| p.z.abs() <= TOL).count();
        assert_eq!(touching, 16);
        assert_eq!(
            contact_mode(&world, &HalfSpace::ground(), TOL),
            ContactMode::Patch
        );
        // Tilted onto two feet: their outer edges are collinear.
        assert_eq!(mode(&desk, (5.0, 0.0, 0.0), 0.0), ContactMode::Line);
        assert_eq!(mode(&desk, (5.0, 3.0, 0.0), 0.0), ContactMode::Point);

        let t = Shape::t_bar();
        assert_eq!(mode(&t, (0.0, 0.0, 0.0), 0.0), ContactMode::Patch);
        // Rolled about x: two corners of the crossbar's end touch.
        assert_eq!(mode(&t, (10.0, 0.0, 0.0), 0.0), ContactMode::Line);
        // Pitched about y: the crossbar's outer bottom edge or the stem tip's edge.
        assert_eq!(mode(&t, (0.0, 10.0, 0.0), 0.0), ContactMode::Line);
        assert_eq!(mode(&t, (0.0, -10.0, 0.0), 0.0), ContactMode::Line);
        assert_eq!(mode(&t, (5.0, 10.0, 0.0), 0.0), ContactMode::Point);
    }

    /// One pass gives `min_gap` and `contact_mode_at`'s numbers: the desk and the T-bar at
    /// poses that touch (patch, line, point), that do not, and a body with coincident vertices
    /// and vertices a merge tolerance apart.
    #[test]
    fn gap_and_mode_in_one_pass_are_those_of_the_two_queries() {
        let ground = HalfSpace::ground();
        let p = Vector3::new(0.1, 0.2, 0.0);
        let merged = [
            p,
            p,
            p + Vector3::new(1e-12, 0.0, 0.0),
            p + Vector3::new(3e-12, 0.0, 0.0),
            p + Vector3::new(0.0, 1.5e-12, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        let mut touching = Vec::new();
        let (gap, mode) = gap_and_mode_at(
            &merged,
            (&Vector3::zeros(), &Matrix3::identity()),
            &ground,
            TOL,
            &mut touching,
        );
        assert_eq!(gap.to_bits(), 0f64.to_bits());
        let low: Vec<_> = merged.iter().filter(|v| v.z <= TOL).copied().collect();
        assert_eq!(touching, dedupe_points(&low, VERTEX_MERGE_TOL));
        assert!(touching.len() >= 2 && touching.len() < low.len());
        assert_eq!(mode, contact_mode(&merged, &ground, TOL));
        for shape in [Shape::desk(), Shape::t_bar()] {
            for (rpy, lift) in [
                ((0.0, 0.0, 0.0), 0.0),
                ((5.0, 0.0, 0.0), 0.0),
                ((5.0, 3.0, 0.0), 0.0),
                ((5.0, 3.0, 0.0), 1e-3),
                ((0.0, 10.0, 20.0), -1e-8),
            ] {
                let r = rotation_matrix(&quat_from_rpy_deg(rpy.0, rpy.1, rpy.2));
                let lowest = min_gap(shape.vertices(), &Vector3::zeros(), &r, &ground);
                let x = Vector3::new(0.3, -0.1, lift - lowest);
                let (gap, mode) =
                    gap_and_mode_at(shape.vertices(), (&x, &r), &ground, TOL, &mut touching);
                let expected = min_gap(shape.vertices(), &x, &r, &ground);
                assert_eq!(gap.to_bits(), expected.to_bits(), "{rpy:?}");
                let world = world_vertices(shape.vertices(), &x, &r);
                assert_eq!(mode, contact_mode(&world, &ground, TOL), "{rpy:?}");
            }
        }
    }

    /// The records' merge tests skipped where the spacing allows: the desk's and the T-bar's
    /// vertices (least distances 0.05 m both) at poses that touch and far from the origin
    /// give the bits of `gap_and_mode_at` and its touching vertices; vertices a merge
    /// tolerance apart, or a position too far for the margin, keep the tests.
    #[test]
    fn spaced_gap_and_mode_are_those_with_the_merge_tests() {
        let ground = HalfSpace::ground();
        let desk = VertexSpacing::of(Shape::desk().vertices());
        assert!((desk.least - 0.05).abs() < 1e-12, "{desk:?}");
        assert!((VertexSpacing::of(Shape::t_bar().vertices()).least - 0.05).abs() < 1e-12);
        assert!(desk.never_merge_at(&Vector3::new(0.0, 0.0, 0.5)));
        assert!(desk.never_merge_at(&Vector3::new(1e6, 0.0, 0.5)));
        assert!(!desk.never_merge_at(&Vector3::new(1e14, 0.0, 0.5)));
        assert!(!desk.never_merge_at(&Vector3::new(f64::NAN, 0.0, 0.5)));
        let p = Vector3::new(0.1, 0.2, 0.0);
        let close = [
            p,
            p + Vector3::new(0.5e-12, 0.0, 0.0),
            p + Vector3::new(0.0, 1.5e-12, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        assert!(!VertexSpacing::of(&close).never_merge_at(&Vector3::zeros()));
        let (mut kept, mut skipped) = (Vec::new(), Vec::new());
        let mut skips = 0;
        for shape in [Shape::desk(), Shape::t_bar()] {
            let v = shape.vertices();
            let spacing = VertexSpacing::of(v);
            for (rpy, lift) in [
                ((0.0, 0.0, 0.0), 0.0),
                ((5.0, 0.0, 0.0), 0.0),
                ((5.0, 3.0, 0.0), 1e-3),
                ((0.0, 10.0, 20.0), -1e-8),
            ] {
                let r = rotation_matrix(&quat_from_rpy_deg(rpy.0, rpy.1, rpy.2));
                let lowest = min_gap(v, &Vector3::zeros(), &r, &ground);
                for far in [0.0, 1e3, 1e14] {
                    let x = Vector3::new(0.3 + far, -0.1, lift - lowest);
                    let a = gap_and_mode_at(v, (&x, &r), &ground, TOL, &mut kept);
                    let b = gap_and_mode_spaced(v, &spacing, (&x, &r), &ground, TOL, &mut skipped);
                    assert_eq!((a.0.to_bits(), a.1), (b.0.to_bits(), b.1), "{rpy:?} {far}");
                    assert_eq!(kept, skipped, "{rpy:?} {far}");
                    skips += usize::from(spacing.never_merge_at(&x));
                }
            }
        }
        assert_eq!(skips, 16);
        let a = gap_and_mode_at(
            &close,
            (&Vector3::zeros(), &Matrix3::identity()),
            &ground,
            TOL,
            &mut kept,
        );
        let spacing = VertexSpacing::of(&close);
        let pose = (&Vector3::zeros(), &Matrix3::identity());
        let b = gap_and_mode_spaced(&close, &spacing, pose, &ground, TOL, &mut skipped);
        assert_eq!((a.0.to_bits(), a.1, &kept), (b.0.to_bits(), b.1, &skipped));
        assert_eq!(kept.len(), 2);
    }

    /// The bounded pass skips only vertices that can be neither the least gap nor touching:
    /// its gap, mode and touching points are those of `gap_and_mode_at` (every vertex) bit for
    /// bit, on the desk, the T-bar, random point clouds and clouds with near-coincident points
    /// (the merge tests), at random and level poses on three planes, far from the origin, with
    /// the lowest vertex a few units of round-off around the tolerance and around 0, tolerances
    /// 1e-7, 0 and −1, and non-finite positions.
    #[test]
    fn bounded_gap_and_mode_are_those_of_every_vertex() {
        fn bits(points: &[Vector3<f64>]) -> Vec<[u64; 3]> {
            points
                .iter()
                .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
                .collect()
        }
        let mut next = uniform_centred(11);
        let planes = [
            HalfSpace::ground(),
            HalfSpace::incline(0.3).expect("finite angle"),
            HalfSpace::new(Vector3::new(0.2, -0.5, 1.0), 0.7).expect("non-zero normal"),
        ];
        let mut shapes = vec![
            Shape::desk().vertices().to_vec(),
            Shape::t_bar().vertices().to_vec(),
        ];
        for k in 0..6 {
            shapes.push(
                (0..3 + 5 * k)
                    .map(|_| Vector3::new(next(), next(), next()))
                    .collect(),
            );
        }
        // Pairs closer than the merge tolerance, and level ties (a flat face at z = −0.25).
        let mut close: Vec<Vector3<f64>> = (0..8)
            .map(|_| Vector3::new(next(), next(), -0.25))
            .collect();
        close.push(close[0] + Vector3::new(3e-13, 0.0, 0.0));
        close.push(close[3] + Vector3::new(0.0, -2e-13, 1e-13));
        close.push(Vector3::new(0.0, 0.0, 0.4));
        shapes.push(close);
        let (mut all, mut bounded) = (Vec::new(), Vec::new());
        let (mut cases, mut touched, mut modes) = (0, 0, [0usize; 4]);
        for v in &shapes {
            let spacing = VertexSpacing::of(v);
            for (k, plane) in planes.iter().enumerate() {
                let n = plane.normal();
                for pose in 0..12 {
                    let r = if pose < 3 {
                        Matrix3::identity()
                    } else {
                        let (a, b, c) = (360.0 * next(), 360.0 * next(), 360.0 * next());
                        rotation_matrix(&quat_from_rpy_deg(a, b, c))
                    };
                    let far = [0.0, 1e3, 1e7][pose % 3];
                    let (t, _, o) = plane.contact_frame();
                    let along = t * (far + next()) + o * next();
                    // Place the lowest vertex at `target` (as computed), then step `x` by a
                    // few units of round-off along the normal around it.
                    for target in [TOL, 0.0, 1e-3] {
                        let lowest = min_gap(v, &along, &r, plane);
                        let base = along + n * (target - lowest);
                        for ulps in -3i32..=3 {
                            let x = base + n * (f64::from(ulps) * f64::EPSILON * (1.0 + far));
                            for tol in [TOL, 0.0, -1.0] {
                                let a = gap_and_mode_at(v, (&x, &r), plane, tol, &mut all);
                                let pose = (&x, &r);
                                let b = gap_and_mode_spaced(
                                    v,
                                    &spacing,
                                    pose,
                                    plane,
                                    tol,
                                    &mut bounded,
                                );
                                let what =
                                    format!("plane {k}, target {target}, ulps {ulps}, tol {tol}");
                                assert_eq!((a.0.to_bits(), a.1), (b.0.to_bits(), b.1), "{what}");
                                assert_eq!(bits(&all), bits(&bounded), "{what}");
                                cases += 1;
                                touched += usize::from(a.0 == tol);
                                modes[a.1 as usize] += 1;
                            }
                        }
                    }
                }
            }
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300] {
                for x in [Vector3::new(bad, 0.0, 0.1), Vector3::new(0.1, 0.2, bad)] {
                    let r = Matrix3::identity();
                    let a = gap_and_mode_at(v, (&x, &r), &planes[2], TOL, &mut all);
                    let b =
                        gap_and_mode_spaced(v, &spacing, (&x, &r), &planes[2], TOL, &mut bounded);
                    assert_eq!((a.0.to_bits(), a.1), (b.0.to_bits(), b.1), "{x:?}");
                    assert_eq!(bits(&all), bits(&bounded), "{x:?}");
                }
            }
        }
        // The lowest vertex exactly at the tolerance in some cases, and every mode met.
        assert!(cases > 5000 && touched > 20, "{cases} {touched}");
        assert!(modes.iter().all(|&m| m > 50), "{modes:?}");
    }

    /// The three-point `Patch` gives the mode of the full test: random sets near a point, a
    /// line and a plane at scales 1e-9 to 1e6, triangles whose height is a relative 1e-12 to
    /// 0.1 around the tolerance (the line then along another, farther point or the first two),
    /// and tolerances 1e-7, 0, −1 and NaN.
    #[test]
    fn three_points_decide_a_patch_as_the_full_test() {
        let mut next = uniform_centred(5);
        let mut modes = [0usize; 4];
        for case in 0..4000 {
            let scale = [1e-9, 1e-3, 1.0, 1e6][case % 4];
            let off = [0.0, 5e-8, 2e-7, 0.3][(case / 4) % 4] * scale;
            let shift = Vector3::new(next(), next(), next()) * [0.0, 1.0, 1e3][(case / 16) % 3];
            let mut points: Vec<Vector3<f64>> = (0..1 + case % 11)
                .map(|_| {
                    let t = next() * scale;
                    shift + Vector3::new(t, 0.5 * t + off * next(), off * next())
                })
                .collect();
            if case % 5 == 0 && points.len() >= 3 {
                // A triangle of height `h` near the tolerance: the first two points on the
                // x axis, the third above their middle.
                let h = TOL * (1.0 + [1e-12, -1e-12, 1e-6, -1e-6, 0.1, -0.1][(case / 5) % 6]);
                let l = [2.0 * TOL, 1e-3, 1.0][(case / 30) % 3];
                points[0] = shift;
                points[1] = shift + Vector3::new(l, 0.0, 0.0);
                points[2] = shift + Vector3::new(0.5 * l, h, 0.0);
            }
            for tol in [TOL, 0.0, -1.0, f64::NAN] {
                let mode = mode_of_touching_moderate(&points, tol);
                assert_eq!(
                    mode,
                    mode_of_touching(&points, tol),
                    "case {case}, tol {tol}"
                );
                modes[mode as usize] += 1;
            }
        }
        assert!(modes[..3].iter().all(|&m| m > 100), "{modes:?}");
    }

    /// The line test stops at the first point off the line: the mode of the largest distance
    /// (the fold over every point, as before) on point sets near a line, a point and a plane,
    /// with NaN points and tolerances 0, 1e-7 and −1.
    #[test]
    fn the_first_point_off_the_line_decides_as_the_largest() {
        fn by_largest(touching: &[Vector3<f64>], tol: f64) -> ContactMode {
            let Some(p0) = touching.first().copied() else {
                return ContactMode::None;
            };
            let far = |f: &dyn Fn(&Vector3<f64>) -> f64| {
                touching
                    .iter()
                    .map(|p| (*p, f(p)))
                    .fold(
                        (p0, 0.0),
                        |best, cur| if cur.1 > best.1 { cur } else { best },
                    )
            };
            let (p1, spread) = far(&|p| (p - p0).norm());
            if spread <= tol {
                return ContactMode::Point;
            }
            let u = (p1 - p0) / spread;
            let (_, off_line) = far(&|p| {
                let r = p - p0;
                (r - u * u.dot(&r)).norm()
            });
            if off_line <= tol {
                ContactMode::Line
            } else {
                ContactMode::Patch
            }
        }
        let mut next = uniform_centred(7);
        let mut modes = [0usize; 4];
        for case in 0..400 {
            let off = [0.0, 5e-8, 2e-7, 0.3][case % 4];
            let along = if case % 8 < 4 { 1.0 } else { 1e-8 };
            let mut points: Vec<Vector3<f64>> = (0..1 + case % 9)
                .map(|_| {
                    let t = next();
                    Vector3::new(along * t, along * 0.5 * t + off * next(), off * next())
                })
                .collect();
            if case % 13 == 0 {
                points.push(Vector3::new(f64::NAN, 0.0, 0.0));
            }
            for tol in [0.0, TOL, -1.0] {
                let mode = mode_of_touching(&points, tol);
                assert_eq!(mode, by_largest(&points, tol), "case {case}, tol {tol}");
                modes[mode as usize] += 1;
            }
        }
        assert!(modes[..3].iter().all(|&m| m > 20), "{modes:?}");
    }

    #[test]
    fn mode_names() {
        let names: Vec<_> = [
            ContactMode::Patch,
            ContactMode::Line,
            ContactMode::Point,
            ContactMode::None,
        ]
        .iter()
        .map(|m| m.to_string())
        .collect();
        assert_eq!(names, ["patch", "line", "point", "none"]);
    }

    #[test]
    fn coincident_vertices_are_one_point() {
        let p = Vector3::new(0.1, 0.2, 0.0);
        let v = [
            p,
            p,
            p + Vector3::new(1e-9, 0.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
        ];
        assert_eq!(
            contact_mode(&v, &HalfSpace::ground(), TOL),
            ContactMode::Point
        );
        assert_eq!(
            contact_mode(&[], &HalfSpace::ground(), TOL),
            ContactMode::None
        );
        assert_eq!(
            min_gap(&[], &p, &Matrix3::identity(), &HalfSpace::ground()),
            f64::INFINITY
        );
    }

    #[test]
    fn ground_frame() {
        let (n, t, o) = HalfSpace::ground().contact_frame();
        assert_eq!((n, t, o), (Vector3::z(), Vector3::x(), Vector3::y()));
    }

    #[test]
    fn incline_frame_and_resting_box() {
        let th = 25f64.to_radians();
        let g = HalfSpace::incline(th).unwrap();
        let (n, t, o) = g.contact_frame();
        assert!((n - Vector3::new(-th.sin(), 0.0, th.cos())).norm() < 1e-15);
        assert!((t - Vector3::new(th.cos(), 0.0, th.sin())).norm() < 1e-15);
        assert!((o - Vector3::y()).norm() < 1e-15);
        assert!((n.cross(&t).dot(&o) - 1.0).abs() < 1e-15);
        // Scenario A4: box rotated by −θ about y, CM at H n_G, rests flat.
        let b = Shape::cuboid(0.4, 0.4, 0.2).unwrap();
        let r = rotation_matrix(&quat_from_rpy_deg(0.0, -25.0, 0.0));
        let x = n * 0.1;
        assert!(min_gap(b.vertices(), &x, &r, &g).abs() < 1e-15);
        let w = world_vertices(b.vertices(), &x, &r);
        assert_eq!(contact_mode(&w, &g, TOL), ContactMode::Patch);
        assert!(HalfSpace::incline(f64::NAN).is_err());
    }

    #[test]
    fn half_space_construction() {
        let h = HalfSpace::new(Vector3::new(0.0, 0.0, 2.0), 1.0).unwrap();
        assert_eq!(h.normal(), Vector3::z());
        assert_eq!(h.offset(), 0.5);
        assert_eq!(h.value(&Vector3::new(3.0, 4.0, 1.5)), 1.0);
        assert_eq!(
            h.project(&Vector3::new(3.0, 4.0, 1.5)),
            Vector3::new(3.0, 4.0, 0.5)
        );
        assert!(matches!(
            HalfSpace::new(Vector3::zeros(), 0.0),
            Err(GeometryError::ZeroNormal)
        ));
        assert!(matches!(
            HalfSpace::new(Vector3::new(f64::NAN, 0.0, 1.0), 0.0),
            Err(GeometryError::NonFinite { .. })
        ));
        // A near-vertical plane uses e_y as the tangent seed.
        let (n, t, o) = HalfSpace::new(Vector3::x(), 0.0).unwrap().contact_frame();
        assert_eq!(t, Vector3::y());
        assert!((n.cross(&t) - o).norm() < 1e-15);
    }
}
