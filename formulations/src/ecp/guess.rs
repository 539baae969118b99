//! Starting points of an ECP contact's unknowns (`docs/model.md#stepper`): the closest points of
//! Conv(F) to the half-space at a pose, with face multipliers that satisfy the closest-point
//! condition there, and impulses that start active where the contact is closed.

use std::cell::Cell;

use nalgebra::{Matrix3, Vector3};

use ecp_model::BlockMcp;

use super::Rotations;
use super::layout::Layout;
use crate::geometry::{ConvexHull, Face, HalfSpace};
use crate::scene::{BodyState, Scene};
use crate::step::Iterates;

/// In the hull and union formulations' warm start, a closed contact's closest-point unknowns
/// follow the closest feature of the predicted pose when its `a1`, carried with the body, ends
/// up more than this above the lowest point of Conv(F) there (m; the band
/// [`closest_point_guess`] averages the lowest vertices over).
pub const FEATURE_SWITCH: f64 = 1e-6;

/// The closest points of Conv(F) at pose `(x, r)` to the half-space: `a1` the centroid of the
/// hull's vertices nearest to G (a face centre, an edge midpoint or a vertex), the gap there,
/// and face multipliers `l ≥ 0` of the faces through `a1` with `Σ l_i n̂_i = −Rᵀ n_G` (the
/// closest-point condition C2 of the paper's KKT system, paper (9)), found as the non-negative
/// least-squares combination of at most three of those faces' normals. When no such
/// combination fits (rounding at a nearly parallel face), multiplier 1 on the face most
/// anti-parallel to `n_G`.
///
/// Only one face with multiplier 1 at a vertex or an edge leaves C2 unsatisfiable by the
/// multipliers the Fischer–Burmeister Newton matrix treats as active, which makes that matrix
/// singular at the warm start (measured on tossed boxes, `docs/newton.md`).
pub fn closest_point_guess(
    set: &ConvexHull,
    plane: &HalfSpace,
    x: &Vector3<f64>,
    r: &Matrix3<f64>,
) -> (Vector3<f64>, f64, Vec<f64>) {
    let mut l = Vec::new();
    let (a1, gmin) = closest_point_guess_into(set, plane, x, r, &mut l);
    (a1, gmin, l)
}

/// [`closest_point_guess`] with the face multipliers written into `l`, whose storage is reused:
/// allocation-free once `l` has grown (the warm start of every step,
/// `docs/latency.md#allocations`). Returns `a1` and the gap.
pub fn closest_point_guess_into(
    set: &ConvexHull,
    plane: &HalfSpace,
    x: &Vector3<f64>,
    r: &Matrix3<f64>,
    l: &mut Vec<f64>,
) -> (Vector3<f64>, f64) {
    let (a1_body, gmin) = lowest_feature(set, plane, x, r);
    let a1 = x + r * a1_body;
    face_multipliers_into(set, plane, r, &a1_body, l);
    (a1, gmin)
}

/// The first half of [`closest_point_guess_into`]: `a1` in body coordinates (the centroid of
/// the vertices nearest to G at pose `(x, r)`) and the gap.
fn lowest_feature(
    set: &ConvexHull,
    plane: &HalfSpace,
    x: &Vector3<f64>,
    r: &Matrix3<f64>,
) -> (Vector3<f64>, f64) {
    let verts = set.vertices();
    let gap = |v: &Vector3<f64>| plane.value(&(x + r * v));
    // Each vertex's gap is read twice: kept on the stack for the hulls of up to `KEPT_GAPS`
    // vertices, computed twice (the same number) for larger ones.
    let mut kept = [0.0; KEPT_GAPS];
    let gaps = &mut kept[..verts.len().min(KEPT_GAPS)];
    let mut gmin = f64::INFINITY;
    for (k, v) in verts.iter().enumerate() {
        let g = gap(v);
        if let Some(slot) = gaps.get_mut(k) {
            *slot = g;
        }
        gmin = gmin.min(g);
    }
    let mut a1_body = Vector3::zeros();
    let mut count: f64 = 0.0;
    for (k, v) in verts.iter().enumerate() {
        let g = gaps.get(k).copied().unwrap_or_else(|| gap(v));
        if g <= gmin + 1e-6 {
            a1_body += v;
            count += 1.0;
        }
    }
    a1_body /= f64::max(count, 1.0);
    (a1_body, gmin)
}

/// The second half of [`closest_point_guess_into`]: the face multipliers at `a1_body` (body
/// coordinates) of the pose of rotation `r`, written into `l`.
fn face_multipliers_into(
    set: &ConvexHull,
    plane: &HalfSpace,
    r: &Matrix3<f64>,
    a1_body: &Vector3<f64>,
    l: &mut Vec<f64>,
) {
    let dir_body = r.transpose() * (-plane.normal());
    l.clear();
    l.resize(set.num_faces(), 0.0);
    let size = set.radius().max(f64::MIN_POSITIVE);
    // The faces through `a1`; more than `MAX_CONE_FACES` are not tried.
    let mut through = [0usize; MAX_CONE_FACES];
    let mut k = 0;
    for (i, f) in set.faces().iter().enumerate() {
        if f.value(a1_body).abs() <= 1e-9 * size {
            if k < MAX_CONE_FACES {
                through[k] = i;
            }
            k += 1;
        }
    }
    let found = if k <= MAX_CONE_FACES {
        face_cone_multipliers(set, &through[..k], &dir_body)
    } else {
        None
    };
    match found {
        Some((best, m)) => {
            for &(i, li) in &best[..m] {
                l[i] = li;
            }
        }
        None => l[set.most_aligned_face(&dir_body)] = 1.0,
    }
}

/// The most vertices of a hull whose gaps [`closest_point_guess_into`] keeps rather than computes
/// twice (the desk's and the T-bar's Conv(F) have fewer; tested).
const KEPT_GAPS: usize = 32;

/// The most faces through `a1` whose combinations [`face_cone_multipliers`] tries.
const MAX_CONE_FACES: usize = 16;

/// Non-negative `l` over at most three of the faces `through` with `Σ l_i n̂_i = dir` (to
/// 1e-9), the one with the fewest faces, as `(face, l_i)` pairs (the first `m` of the array);
/// `None` when there is none (or too many faces to try).
fn face_cone_multipliers(
    set: &ConvexHull,
    through: &[usize],
    dir: &Vector3<f64>,
) -> Option<([(usize, f64); 3], usize)> {
    if through.is_empty() || through.len() > MAX_CONE_FACES {
        return None;
    }
    let faces = set.faces();
    let k = through.len();
    for i in 0..k {
        if let Some(s) = cone_fit_1(faces, [through[i]], dir) {
            return Some(s);
        }
    }
    for i in 0..k {
        for j in i + 1..k {
            if let Some(s) = cone_fit_2(faces, [through[i], through[j]], dir) {
                return Some(s);
            }
        }
    }
    for i in 0..k {
        for j in i + 1..k {
            for m in j + 1..k {
                if let Some(s) = cone_fit_3(faces, [through[i], through[j], through[m]], dir) {
                    return Some(s);
                }
            }
        }
    }
    None
}

/// `cone_fit_M(faces, idx, dir)`: the non-negative combination of the normals of the `M ≤ 3`
/// faces `idx` that equals `dir` (to 1e-9), from the normal equations in fixed-size matrices;
/// `None` when it is not one.
macro_rules! cone_fit {
    ($name:ident, $m:literal) => {
        fn $name(
            faces: &[Face],
            idx: [usize; $m],
            dir: &Vector3<f64>,
        ) -> Option<([(usize, f64); 3], usize)> {
            let cols: [Vector3<f64>; $m] = idx.map(|i| faces[i].normal);
            // Normal equations of the M ≤ 3 columns.
            let mut a = nalgebra::SMatrix::<f64, $m, $m>::zeros();
            let mut b = nalgebra::SVector::<f64, $m>::zeros();
            for p in 0..$m {
                b[p] = cols[p].dot(dir);
                for q in 0..$m {
                    a[(p, q)] = cols[p].dot(&cols[q]);
                }
            }
            let sol = a.lu().solve(&b)?;
            if sol.iter().any(|v| !v.is_finite() || *v < 0.0) {
                return None;
            }
            let fit: Vector3<f64> = cols.iter().zip(sol.iter()).map(|(c, s)| c * *s).sum();
            if (fit - dir).norm() > 1e-9 {
                return None;
            }
            let mut out = [(0, 0.0); 3];
            for p in 0..$m {
                out[p] = (idx[p], sol[p]);
            }
            Some((out, $m))
        }
    };
}

cone_fit!(cone_fit_1, 1);
cone_fit!(cone_fit_2, 2);
cone_fit!(cone_fit_3, 3);

/// What the guesses of one step read: the layout, the scene, the states at the span's start
/// and the step problem (for the ranges of the unknowns).
pub(crate) struct Guess<'a> {
    pub(crate) layout: &'a Layout,
    pub(crate) scene: &'a Scene,
    pub(crate) states: &'a [BodyState],
    pub(crate) mcp: &'a BlockMcp,
    /// Storage for the face multipliers of [`closest_point_guess_into`], kept by the
    /// formulation across steps (taken and put back around each use).
    pub(crate) faces: &'a Cell<Vec<f64>>,
    /// The rotations of the bodies' states, kept by the formulation.
    pub(crate) rotations: &'a Rotations,
}

impl Guess<'_> {
    /// The slip rate σ of the warm start of an open contact `i` (`p_n = 0`): the slip speed of
    /// the body at its ECP, `(e_t² v_t² + e_o² v_o² + e_r² ω_n²)^½`, and at least the speed
    /// gravity gives in one step, `|g| h`.
    ///
    /// With `p_n = 0` every σ ≥ 0 solves the friction law, but σ = 0 together with `p_n = 0`
    /// zeroes the whole linearisation of the friction rows `e² μ p_n W ν + p_f σ`: the friction
    /// impulse is then free at first order, the Newton matrix is singular, and its safeguard
    /// steps move `p_f` and `p_n` off zero into a spurious minimiser of the merit function
    /// (`docs/newton.md`). With σ > 0 the rows pin `p_f` to 0.
    pub(crate) fn open_contact_sigma(&self, i: usize, z: &[f64]) -> f64 {
        let c = &self.layout.contacts[i];
        let s = self.states[c.body];
        let plane = &self.scene.planes[c.plane];
        let (ng, t, o) = plane.contact_frame();
        let a1 = &z[self.mcp.range(c.a1)];
        let rr = Vector3::new(a1[0], a1[1], a1[2]) - s.x;
        let f = self.scene.friction;
        let vt = t.dot(&s.v) + rr.cross(&t).dot(&s.w);
        let vo = o.dot(&s.v) + rr.cross(&o).dot(&s.w);
        let wn = ng.dot(&s.w);
        let slip = ((f.e_t * vt).powi(2) + (f.e_o * vo).powi(2) + (f.e_r * wn).powi(2)).sqrt();
        let floor = self.scene.gravity.norm() * self.scene.h;
        if slip.is_finite() && slip > floor {
            slip
        } else if floor > 0.0 {
            floor
        } else {
            1.0
        }
    }

    /// Guess for contact `i`'s unknowns from its body's state, with the closest points taken at
    /// the pose `(x, r)`.
    ///
    /// `a1` is the centroid of the hull vertices nearest to G (a face centre, an edge midpoint
    /// or a vertex), `a2` its projection, `l_g` the gap, face multipliers from
    /// [`closest_point_guess`]. When the contact is closed (gap ≤ 1e-9) or `force_active` is
    /// set, the normal impulse starts at the value that carries the weight and stops the
    /// approach velocity over the step, and the friction impulse on the ellipsoid opposing the
    /// current slip with σ the slip rate — a point of the sliding branch of
    /// `docs/model.md#friction`. Otherwise impulses and σ start at 0 (σ at
    /// [`Guess::open_contact_sigma`]). Starting active matters: `p_n = 0` zeroes every friction
    /// row, and the merit function of a Newton method has a spurious minimiser near "free fall
    /// with zero impulses".
    pub(crate) fn contact_at(
        &self,
        i: usize,
        force_active: bool,
        (x, r): (&Vector3<f64>, &Matrix3<f64>),
        z: &mut [f64],
    ) {
        let c = self.layout.contacts[i];
        let set = &self.layout.contact_hulls[i];
        let plane = &self.scene.planes[c.plane];
        let s = self.states[c.body];
        let ng = plane.normal();
        let mut l = self.faces.take();
        let (a1, gmin) = closest_point_guess_into(set, plane, x, r, &mut l);
        let a2 = plane.project(&a1);
        let gap = gmin.max(0.0);
        let f = self.scene.friction;
        let (mut pn, mut pf, mut sigma) = (0.0, [0.0; 3], self.open_contact_sigma(i, z));
        if gap <= 1e-9 || force_active {
            let m = self.scene.bodies[c.body].mass.mass;
            let h = self.scene.h;
            let v_pred = s.v + self.scene.gravity * h;
            pn = (-m * self.scene.gravity.dot(&ng) * h).max(0.0) + (-m * v_pred.dot(&ng)).max(0.0);
            let (_, t, o) = plane.contact_frame();
            let rr = a1 - s.x;
            let vt = t.dot(&s.v) + rr.cross(&t).dot(&s.w);
            let vo = o.dot(&s.v) + rr.cross(&o).dot(&s.w);
            let wn = ng.dot(&s.w);
            let slip = ((f.e_t * vt).powi(2) + (f.e_o * vo).powi(2) + (f.e_r * wn).powi(2)).sqrt();
            if slip > 1e-12 {
                let k = -f.mu * pn / slip;
                pf = [
                    k * f.e_t * f.e_t * vt,
                    k * f.e_o * f.e_o * vo,
                    k * f.e_r * f.e_r * wn,
                ];
                sigma = slip;
            }
        }
        let o = self.layout.origin;
        let mcp = self.mcp;
        z[mcp.range(c.a1)].copy_from_slice((a1 - o).as_slice());
        z[mcp.range(c.a2)].copy_from_slice((a2 - o).as_slice());
        z[mcp.range(c.l)].copy_from_slice(&l);
        self.faces.set(l);
        z[mcp.range(c.lg)][0] = gap;
        z[mcp.range(c.pn)][0] = pn;
        z[mcp.range(c.pf)].copy_from_slice(&pf);
        z[mcp.range(c.sigma)][0] = sigma;
    }

    /// The warm start of a contact `i` that ended the last step closed (`p_n > 0`) when the
    /// body's predicted pose `(x1, r1)` brings another feature of Conv(F) lowest: the
    /// closest-point unknowns (`a1`, `a2`, `l_g`, the face multipliers) move to the closest
    /// points of the predicted pose, the impulses stay. The test: the warm start's `a1`, carried
    /// rigidly to the predicted pose, lies more than [`FEATURE_SWITCH`] above the predicted
    /// pose's lowest point, unless that point lies on the contact's own feature (every face
    /// through the warm `a1`) and above the support: the prediction then only lifts and tilts the
    /// feature the contact stays on ([`lowest_on_feature`]).
    ///
    /// Without it, a box rocking from one edge onto the opposite one, or landing flat on the face
    /// next to the edge it stood on, starts every backend with the ECP on the old edge, up to
    /// the width of the face from the solution's; Newton's merit function has a local minimiser
    /// there (`docs/newton.md#smoothing-continuation`). Returns whether the unknowns moved.
    pub(crate) fn follow_closest_feature(
        &self,
        i: usize,
        (x1, r1): (&Vector3<f64>, &Matrix3<f64>),
        z: &mut [f64],
    ) -> bool {
        // By reference: the contact's and the state's copies were most of this test's moves.
        let c = &self.layout.contacts[i];
        let o = self.layout.origin;
        let s = &self.states[c.body];
        let plane = &self.scene.planes[c.plane];
        let hull = &self.layout.contact_hulls[i];
        // `closest_point_guess_into` in its two halves: the face multipliers only when the
        // unknowns move.
        let (a1p_body, gap) = lowest_feature(hull, plane, x1, r1);
        let a1p = x1 + r1 * a1p_body;
        let mcp = self.mcp;
        let warm = &z[mcp.range(c.a1)];
        let warm = Vector3::new(warm[0], warm[1], warm[2]) + o;
        let r0 = self.rotations.of(c.body, &s.q);
        // The warm `a1` in body coordinates, then carried rigidly to the predicted pose.
        let warm_in_body = r0.transpose() * (warm - s.x);
        let carried = x1 + r1 * warm_in_body;
        let finite = a1p.iter().all(|v| v.is_finite()) && gap.is_finite();
        // Not when the predicted pose lifts the contact's own feature off the support and only
        // tilts it (a body tipping over an edge): the contact stays on that feature.
        let lifted_and_tilted =
            || gap >= 0.0 && lowest_on_feature(hull, &warm_in_body, &(r1.transpose() * (a1p - x1)));
        let moved = finite && plane.value(&carried) > gap + FEATURE_SWITCH && !lifted_and_tilted();
        if moved {
            let mut l = self.faces.take();
            face_multipliers_into(hull, plane, r1, &a1p_body, &mut l);
            let a2 = plane.project(&a1p);
            z[mcp.range(c.a1)].copy_from_slice((a1p - o).as_slice());
            z[mcp.range(c.a2)].copy_from_slice((a2 - o).as_slice());
            z[mcp.range(c.lg)][0] = gap.max(0.0);
            z[mcp.range(c.l)].copy_from_slice(&l);
            self.faces.set(l);
        }
        moved
    }

    /// [`Guess::contact_at`] at the body's state.
    pub(crate) fn contact(&self, i: usize, force_active: bool, z: &mut [f64]) {
        let b = self.layout.contacts[i].body;
        let s = self.states[b];
        let r = self.rotations.of(b, &s.q);
        self.contact_at(i, force_active, (&s.x, &r), z);
    }
}

/// The highest order of the hull formulation's extrapolated warm start: the polynomial through
/// the last six steps' iterates (measured on the desk, orders 2–5: 3.1, 2.3, 1.6, 1.4 Newton
/// iterations a step; `docs/latency.md`, branch wip-xorder).
pub(crate) const MAX_ORDER: usize = 5;

/// The most iterates [`Past`] reads: the extrapolation of order [`MAX_ORDER`].
const PAST: usize = MAX_ORDER + 1;

/// The last steps' iterates an extrapolation reads (newest first) and its order: the polynomial
/// of degree `order` through `z_k, …, z_{k−order}`, taken one step on.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Past<'a> {
    z: [&'a [f64]; PAST],
    /// How many of `z` are iterates (from `z_k` back); the others repeat `z_k`.
    depth: usize,
    order: usize,
}

impl<'a> Past<'a> {
    /// The iterates `it`, extrapolated at the highest order they allow (at most [`MAX_ORDER`]).
    pub(crate) fn new(it: &Iterates<'a>) -> Self {
        let depth = it.depth().min(PAST);
        let z = std::array::from_fn(|back| it.at(back).unwrap_or(it.last));
        Past {
            z,
            depth,
            order: depth - 1,
        }
    }

    /// `z_k`, the last step's iterate.
    pub(crate) fn newest(&self) -> &'a [f64] {
        self.z[0]
    }

    /// The extrapolation's order.
    pub(crate) fn order(&self) -> usize {
        self.order
    }

    /// The same iterates extrapolated at order `order` (at most the highest they allow).
    pub(crate) fn with_order(self, order: usize) -> Self {
        Past {
            order: order.clamp(1, self.depth - 1),
            ..self
        }
    }

    /// How far the extrapolation of order `order` from the steps before the last one missed the
    /// last one's iterate over `range` (the largest difference), `None` when there are not the
    /// `order + 2` iterates it needs.
    pub(crate) fn miss(&self, order: usize, range: std::ops::Range<usize>) -> Option<f64> {
        if order == 0 || order + 2 > self.depth {
            return None;
        }
        // Each iterate's entries of `range`, sliced once (no bounds checks in the loop).
        let n = range.len();
        let [a, b, c, d, e, f] = self.z.map(|v| &v[range.clone()][..n]);
        let mut worst: f64 = 0.0;
        for j in 0..n {
            // The older iterates one step back: `z_{k−1}` newest.
            let v = [b[j], c[j], d[j], e[j], f[j], 0.0];
            let miss = (extrapolated(order, &v) - a[j]).abs();
            // NaN counts as the worst miss.
            worst = if miss.is_nan() {
                f64::INFINITY
            } else {
                worst.max(miss)
            };
        }
        Some(worst)
    }
}

/// The polynomial extrapolation of order `order` (1 to 5) from values `v[0]` (newest), `v[1]`, …
/// one step apart, one step on: `2 a − b`, `3 a − 3 b + c`, `4 a − 6 b + 4 c − d`,
/// `5 a − 10 b + 10 c − 5 d + e`, `6 a − 15 b + 20 c − 15 d + 6 e − f` (the first two as they
/// always were, for their bits).
#[inline(always)]
fn extrapolated(order: usize, v: &[f64; PAST]) -> f64 {
    let [a, b, c, d, e, f] = *v;
    match order {
        0 => a,
        1 => 2.0 * a - b,
        2 => 3.0 * (a - b) + c,
        3 => 4.0 * (a - b) - 2.0 * (b - 2.0 * c) - d,
        4 => 5.0 * (a - d) - 10.0 * (b - c) + e,
        _ => 6.0 * (a + e) - 15.0 * (b + d) + 20.0 * c - f,
    }
}

/// The unknowns `range` of `z` extrapolated from the last steps' iterates `past` at its order:
/// at constant rate, `2 z_k − z_{k−1}`, at constant change of rate, `3 z_k − 3 z_{k−1} +
/// z_{k−2}`, or at order 3, `4 z_k − 6 z_{k−1} + 4 z_{k−2} − z_{k−3}` (clamped at 0 when
/// `nonnegative`). On a smooth step the last step's values miss the solution by O(h), the
/// extrapolations of order p by O(h^{p+1}): fewer Newton iterations where the convergence is
/// quadratic (`docs/latency.md#an-extrapolated-warm-start-branch-wip-warmx-issue-18`, and
/// branch wip-xorder for order 3).
#[inline]
pub(crate) fn extrapolate(
    z: &mut [f64],
    range: std::ops::Range<usize>,
    past: &Past<'_>,
    nonnegative: bool,
) {
    let out = &mut z[range.clone()];
    // Each iterate's entries of `range`, sliced once: the loops below run without bounds checks
    // (and in vector lanes, each lane the operations of `extrapolated` in their order).
    let z = past.z.map(|v| &v[range.clone()]);
    match past.order {
        0 => extrapolate_entries::<0>(out, z, nonnegative),
        1 => extrapolate_entries::<1>(out, z, nonnegative),
        2 => extrapolate_entries::<2>(out, z, nonnegative),
        3 => extrapolate_entries::<3>(out, z, nonnegative),
        4 => extrapolate_entries::<4>(out, z, nonnegative),
        _ => extrapolate_entries::<5>(out, z, nonnegative),
    }
}

/// `out[j]` the extrapolation of order `ORDER` from `z[0][j]` (newest), `z[1][j]`, … (each of
/// `out`'s length), clamped at 0 when `nonnegative`: one loop per order, reading only the
/// iterates it needs.
#[inline(always)]
fn extrapolate_entries<const ORDER: usize>(out: &mut [f64], z: [&[f64]; PAST], nonnegative: bool) {
    let n = out.len();
    let [a, b, c, d, e, f] = z.map(|v| &v[..n]);
    if nonnegative {
        for j in 0..n {
            out[j] = extrapolated(ORDER, &[a[j], b[j], c[j], d[j], e[j], f[j]]).max(0.0);
        }
    } else {
        for j in 0..n {
            out[j] = extrapolated(ORDER, &[a[j], b[j], c[j], d[j], e[j], f[j]]);
        }
    }
}

/// `z`'s entries `range` clamped at 0: [`extrapolate`] with `nonnegative` as a second pass (the
/// same numbers: the clamp of each extrapolated value).
#[inline]
pub(crate) fn clamp_nonnegative(z: &mut [f64], range: std::ops::Range<usize>) {
    for v in &mut z[range] {
        *v = v.max(0.0);
    }
}

/// Whether the lowest point `low` of Conv(F) at the predicted pose lies on every face of the hull
/// through the warm start's `a1` (both in body coordinates): the contact's feature (an edge, a
/// face) stays lowest, and only its tilt in the predicted pose made one end of it lower than
/// the carried `a1`. The predicted pose continues the last step's velocity, which for a body
/// tipping over an edge that lies flat on the support is a second-order error: it lifts the edge
/// and tilts it (`018_union_tip`, steps 27–52: the lower end 8e-6 … 7e-4 m above the support,
/// the carried `a1` 1e-6 … 6e-4 m above that, against [`FEATURE_SWITCH`]), while the solution
/// keeps the edge flat with `a1` inside it, up to 37 cm from its end
/// (`docs/newton.md#a-tipping-edge-predicted-tilted-018_union_tip`).
fn lowest_on_feature(hull: &ConvexHull, warm: &Vector3<f64>, low: &Vector3<f64>) -> bool {
    let size = hull.radius().max(f64::MIN_POSITIVE);
    let on = |f: &Face, p: &Vector3<f64>| f.value(p).abs() <= 1e-9 * size;
    let mut through = 0usize;
    for f in hull.faces() {
        if on(f, warm) {
            through += 1;
            if !on(f, low) {
                return false;
            }
        }
    }
    through > 0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The box `[−1, 1]³`.
    fn cube() -> ConvexHull {
        let mut v = Vec::new();
        for x in [-1.0, 1.0] {
            for y in [-1.0, 1.0] {
                for z in [-1.0, 1.0] {
                    v.push(Vector3::new(x, y, z));
                }
            }
        }
        ConvexHull::from_points(&v).unwrap_or_else(|e| panic!("{e}"))
    }

    /// `closest_point_guess_into` as it was, each vertex's gap computed twice and the size from
    /// the vertices: the reference of the kept gaps and the hull's radius.
    fn closest_point_guess_by_recomputing(
        set: &ConvexHull,
        plane: &HalfSpace,
        x: &Vector3<f64>,
        r: &Matrix3<f64>,
    ) -> (Vector3<f64>, f64, Vec<f64>) {
        let verts = set.vertices();
        let gap = |v: &Vector3<f64>| plane.value(&(x + r * v));
        let gmin = verts.iter().map(gap).fold(f64::INFINITY, f64::min);
        let mut a1_body = Vector3::zeros();
        let mut count: f64 = 0.0;
        for v in verts {
            if gap(v) <= gmin + 1e-6 {
                a1_body += v;
                count += 1.0;
            }
        }
        a1_body /= f64::max(count, 1.0);
        let size = verts
            .iter()
            .map(|v| v.norm())
            .fold(0.0, f64::max)
            .max(f64::MIN_POSITIVE);
        assert_eq!(
            size.to_bits(),
            set.radius().max(f64::MIN_POSITIVE).to_bits()
        );
        let mut l = Vec::new();
        face_multipliers_into(set, plane, r, &a1_body, &mut l);
        (x + r * a1_body, gmin, l)
    }

    /// The kept gaps give the numbers of the gaps computed twice, bit for bit: the cube, the
    /// desk and the T-bar (fewer vertices than `KEPT_GAPS`) and a 40-sided prism (more), at
    /// poses resting on a face, on an edge and on a vertex.
    #[test]
    fn kept_gaps_give_the_guess_of_recomputed_ones() {
        use crate::geometry::Shape;
        use crate::rotation::{quat_from_rpy_deg, rotation_matrix};
        let prism: Vec<Vector3<f64>> = (0..40)
            .flat_map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 40.0;
                [-0.1, 0.1].map(|z| Vector3::new(0.3 * a.cos(), 0.3 * a.sin(), z))
            })
            .collect();
        let prism = ConvexHull::from_points(&prism).unwrap_or_else(|e| panic!("{e}"));
        assert!(prism.vertices().len() > KEPT_GAPS);
        let desk = Shape::desk().hull().unwrap_or_else(|e| panic!("{e}"));
        let t_bar = Shape::t_bar().hull().unwrap_or_else(|e| panic!("{e}"));
        assert!(desk.vertices().len() <= KEPT_GAPS && t_bar.vertices().len() <= KEPT_GAPS);
        let ground = HalfSpace::ground();
        for hull in [cube(), desk, t_bar, prism] {
            for rpy in [(0.0, 0.0, 0.0), (30.0, 0.0, 10.0), (20.0, 10.0, 5.0)] {
                let r = rotation_matrix(&quat_from_rpy_deg(rpy.0, rpy.1, rpy.2));
                let x = Vector3::new(0.2, -0.1, 1.5);
                let mut l = vec![7.0; 3];
                let (a1, gap) = closest_point_guess_into(&hull, &ground, &x, &r, &mut l);
                let (a1_ref, gap_ref, l_ref) =
                    closest_point_guess_by_recomputing(&hull, &ground, &x, &r);
                assert_eq!(a1.map(f64::to_bits), a1_ref.map(f64::to_bits), "{rpy:?}");
                assert_eq!(gap.to_bits(), gap_ref.to_bits());
                assert_eq!(l, l_ref);
                assert!(l.iter().any(|&li| li > 0.0));
            }
        }
    }

    /// The iterates `z` (newest first) as [`Iterates`].
    fn iterates(z: &[Vec<f64>]) -> Iterates<'_> {
        Iterates {
            last: &z[0],
            before: &z[1],
            older: z.get(2).map(Vec::as_slice),
            earlier: [3, 4, 5].map(|k| z.get(k).map(Vec::as_slice)),
            serial: (0, 0),
        }
    }

    /// The extrapolation of order p is exact on polynomials of degree at most p (to round-off)
    /// and misses one of degree p + 1: the binomial coefficients of each order, checked.
    #[test]
    fn each_order_extrapolates_polynomials_of_its_degree_exactly() {
        for order in 1..PAST {
            for degree in 0..=order + 1 {
                let f = |t: f64| {
                    (0..=degree)
                        .map(|k| (0.3 + k as f64) * t.powi(k as i32))
                        .sum()
                };
                // z_k at t = 0, z_{k−b} at t = −b; the extrapolation is the value at t = 1.
                let z: Vec<Vec<f64>> = (0..=order).map(|b| vec![f(-(b as f64))]).collect();
                let past = Past::new(&iterates(&z)).with_order(order);
                assert_eq!(past.order(), order);
                let mut out = [0.0];
                extrapolate(&mut out, 0..1, &past, false);
                let exact = (out[0] - f(1.0)).abs() <= 1e-12 * f(1.0).abs().max(1.0);
                assert_eq!(
                    exact,
                    degree <= order,
                    "order {order} degree {degree}: {}",
                    out[0]
                );
            }
        }
    }

    /// On a smooth periodic motion (the desk's load, ω = 2π rad/s, h = 0.01, with a third
    /// harmonic) each order of extrapolation misses the next value by less than the one below
    /// it, the highest the hull formulation uses by a factor of at least 100 below the
    /// quadratic one's (branch wip-xorder); and the miss of the last step (`Past::miss`) is the
    /// extrapolation's from the steps before it.
    #[test]
    fn higher_orders_miss_a_smooth_periodic_motion_less() {
        let (w, h) = (std::f64::consts::TAU, 0.01);
        let f = |t: f64| (w * t).sin() + 0.2 * (3.0 * w * t + 0.4).cos() - 0.05 * t;
        let mut worst = [0.0f64; PAST];
        for k in 10..110 {
            let t = k as f64 * h;
            let z: Vec<Vec<f64>> = (0..PAST).map(|b| vec![f(t - b as f64 * h)]).collect();
            for order in 1..PAST {
                let past = Past::new(&iterates(&z)).with_order(order);
                let mut out = [0.0];
                extrapolate(&mut out, 0..1, &past, false);
                worst[order] = worst[order].max((out[0] - f(t + h)).abs());
                // The last step's miss: the same order from one step back.
                if order + 2 <= PAST {
                    let back: Vec<Vec<f64>> = z[1..].to_vec();
                    let earlier = Past::new(&iterates(&back)).with_order(order);
                    let mut pred = [0.0];
                    extrapolate(&mut pred, 0..1, &earlier, false);
                    let miss = past.miss(order, 0..1).unwrap_or(f64::NAN);
                    assert_eq!(miss.to_bits(), (pred[0] - z[0][0]).abs().to_bits());
                }
            }
        }
        for order in 2..PAST {
            assert!(worst[order] < worst[order - 1], "{worst:?}");
        }
        assert!(worst[MAX_ORDER] < 1e-2 * worst[2], "{worst:?}");
        assert_eq!(PAST, MAX_ORDER + 1);
    }

    #[test]
    fn the_lowest_point_on_the_contacts_edge_or_face_is_on_its_feature() {
        let h = cube();
        // `a1` inside the edge y = z = −1; an end of that edge, then a vertex off it.
        let edge = Vector3::new(0.3, -1.0, -1.0);
        assert!(lowest_on_feature(&h, &edge, &Vector3::new(1.0, -1.0, -1.0)));
        assert!(!lowest_on_feature(&h, &edge, &Vector3::new(1.0, 1.0, -1.0)));
        // The face z = −1: its vertices and edges are on it, the top face's are not.
        let face = Vector3::new(0.2, 0.1, -1.0);
        assert!(lowest_on_feature(&h, &face, &Vector3::new(-1.0, 1.0, -1.0)));
        assert!(lowest_on_feature(&h, &face, &Vector3::new(0.0, 1.0, -1.0)));
        assert!(!lowest_on_feature(&h, &face, &Vector3::new(0.0, 1.0, 1.0)));
        // A point on no face (inside the hull) has no feature.
        assert!(!lowest_on_feature(
            &h,
            &Vector3::zeros(),
            &Vector3::new(1.0, 1.0, 1.0)
        ));
    }
}
