//! The closest (or overlapping) features of two convex hulls at given poses, as a starting
//! point of a contact between two bodies (`docs/model.md#contact-between-two-bodies`, "Starting
//! guesses"): ECPs `a1`, `a2`, separation `d` and face multipliers `l`, `μ` that satisfy the
//! closest-point rows (K1)–(K3) at the closest features.
//!
//! parry3d-f64 finds the closest points (GJK) or, when the hulls overlap, the deepest points and
//! the normal (EPA); the multipliers are the non-negative least-squares combinations of the
//! active faces' gradients, as the half-space stepper's warm start does for a plane.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3, Vector4};
use parry3d_f64::math::{Pose, Vector as PVec};
use parry3d_f64::query::contact;
use parry3d_f64::shape::ConvexPolyhedron;

use super::{ConvexHull, GeometryError};
use crate::rotation::{kinematic_map, quat_normalize, rotation_matrix};

/// A face is active at a point when the point is within this distance of its plane, relative
/// to the larger hull's size (the closest points of GJK/EPA are accurate to far better than
/// this on polytopes).
const ACTIVE_TOL: f64 = 1e-7;

/// A convex hull at a pose: `p_world = x + R p_body`.
#[derive(Clone, Copy, Debug)]
pub struct HullPose<'a> {
    /// The hull, body frame.
    pub hull: &'a ConvexHull,
    /// Position of the body frame's origin (the CM).
    pub x: Vector3<f64>,
    /// Rotation body → world.
    pub rotation: Matrix3<f64>,
}

impl HullPose<'_> {
    fn body_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation.transpose() * (p - self.x)
    }
    /// World gradients `R n̂_i` of the faces and the values `f_i(p)` at world point `p`.
    fn faces_at(&self, p: &Vector3<f64>) -> (Vec<Vector3<f64>>, Vec<f64>) {
        let local = self.body_point(p);
        let faces = self.hull.faces();
        (
            faces.iter().map(|f| self.rotation * f.normal).collect(),
            faces.iter().map(|f| f.value(&local)).collect(),
        )
    }
    fn contains(&self, p: &Vector3<f64>, tol: f64) -> bool {
        self.hull.contains(&self.body_point(p), tol)
    }
    fn size(&self) -> f64 {
        self.hull
            .vertices()
            .iter()
            .map(|v| v.norm())
            .fold(0.0, f64::max)
    }
    fn polyhedron(&self) -> Option<ConvexPolyhedron> {
        let pts: Vec<PVec> = (self.hull.vertices().iter())
            .map(|v| {
                let w = self.x + self.rotation * v;
                PVec::new(w.x, w.y, w.z)
            })
            .collect();
        std::panic::catch_unwind(|| ConvexPolyhedron::from_convex_hull(&pts))
            .ok()
            .flatten()
    }
}

/// The closest features of a pair (F, G): values of the closest-point unknowns of
/// `docs/model.md#contact-between-two-bodies` that satisfy (K1) and (K3) exactly and (K2) to
/// the accuracy of the closest points.
#[derive(Clone, Debug, PartialEq)]
pub struct PairFeatures {
    /// ECP on Conv(F).
    pub a1: Vector3<f64>,
    /// ECP on Conv(G).
    pub a2: Vector3<f64>,
    /// Separation `d ≥ 0` with `a1 − a2 = d ν_G` (the distance over `|ν_G|`; 0 when the hulls
    /// touch or overlap).
    pub d: f64,
    /// Multipliers of F's faces, `Σ l_i ∇f_i = −ν_G` over the faces active at `a1`.
    pub l: Vec<f64>,
    /// Multipliers of G's faces, `Σ μ_j = 1`, non-zero only on faces active at `a2`.
    pub mu: Vec<f64>,
    /// Unit normal `ν_G / |ν_G|`, from G into F.
    pub normal: Vector3<f64>,
    /// Signed distance between the hulls (negative: the depth of an overlap).
    pub distance: f64,
    /// Whether the closest features are a face of each hull (the ECP then starts at F's CM
    /// projected on the contact plane when that lies in both hulls).
    pub face_to_face: bool,
}

/// The closest features of Conv(F) and Conv(G) at the given poses, or, when they overlap, the
/// deepest features and the normal of the overlap (the "deterministic retry" start from the
/// predicted end-of-step poses, [`predicted_pose`]).
///
/// `a2` is the point of Conv(G) closest to F (deepest in F when they overlap), `μ` the
/// non-negative least-squares combination of the gradients of G's faces active there that
/// points along the normal, normalised to sum 1, `l` the combination of F's active faces'
/// gradients equal to `−ν_G`; separated, `d` is the distance over `|ν_G|` and `a1 = a2 + d ν_G`;
/// touching or overlapping, `d = 0` and `a1 = a2` is the midpoint of the two deepest points.
/// When the features are a face of each hull, the ECP moves to F's CM projected on G's face
/// plane if that point (and its image on F) lies in both hulls.
pub fn pair_features(f: &HullPose<'_>, g: &HullPose<'_>) -> Result<PairFeatures, GeometryError> {
    let failed = |hull: &ConvexHull| GeometryError::HullFailed {
        count: hull.vertices().len(),
    };
    let poly_f = f.polyhedron().ok_or_else(|| failed(f.hull))?;
    let poly_g = g.polyhedron().ok_or_else(|| failed(g.hull))?;
    let id = Pose::IDENTITY;
    let c = contact(&id, &poly_g, &id, &poly_f, f64::INFINITY)
        .ok()
        .flatten()
        .filter(|c| c.dist.is_finite())
        .ok_or(GeometryError::NonFinite {
            what: "the closest points of two hulls".into(),
        })?;
    let p_g = Vector3::new(c.point1.x, c.point1.y, c.point1.z);
    let p_f = Vector3::new(c.point2.x, c.point2.y, c.point2.z);
    let normal_hint = Vector3::new(c.normal1.x, c.normal1.y, c.normal1.z);
    let size = f.size().max(g.size()).max(f64::MIN_POSITIVE);
    let tol = ACTIVE_TOL * size;
    let separated = c.dist > tol;
    let (a2, a1_raw) = if separated {
        (p_g, p_f)
    } else {
        let mid = (p_g + p_f) * 0.5;
        (mid, mid)
    };
    // G's faces: μ ≥ 0 on the active ones, Σ μ_j ∇g_j along the normal, Σ μ = 1.
    let dir = if separated {
        (a1_raw - a2).normalize()
    } else {
        normal_hint
    };
    let (grads_g, values_g) = g.faces_at(&p_g);
    let active_tol = tol.max(-c.dist);
    let mu = cone_combination(&grads_g, &values_g, active_tol, &dir);
    let sum: f64 = mu.iter().sum();
    let mu: Vec<f64> = mu.iter().map(|m| m / sum).collect();
    let nu_g: Vector3<f64> = grads_g.iter().zip(&mu).map(|(g, m)| g * *m).sum();
    // F's faces: Σ l_i ∇f_i = −ν_G.
    let (grads_f, values_f) = f.faces_at(&p_f);
    let mut l = cone_combination(&grads_f, &values_f, active_tol, &(-nu_g.normalize()));
    let lsum: Vector3<f64> = grads_f.iter().zip(&l).map(|(g, li)| g * *li).sum();
    // Scale so that the combination has the length of ν_G (exact when the cones are opposite).
    let k = nu_g.norm() / lsum.norm().max(f64::MIN_POSITIVE);
    for li in &mut l {
        *li *= k;
    }
    let rho2 = nu_g.norm_squared();
    let d = if separated {
        ((a1_raw - a2).dot(&nu_g) / rho2).max(0.0)
    } else {
        0.0
    };
    let face_to_face =
        mu.iter().filter(|m| **m > 0.0).count() == 1 && l.iter().filter(|v| **v > 0.0).count() == 1;
    let mut a2 = a2;
    if face_to_face {
        // F's CM on G's face plane through a2.
        let n = nu_g / rho2.sqrt();
        let on_plane = f.x - n * (f.x - p_g).dot(&n);
        let image = on_plane + nu_g * d;
        if g.contains(&on_plane, active_tol) && f.contains(&image, active_tol) {
            a2 = on_plane;
        }
    }
    Ok(PairFeatures {
        a1: a2 + nu_g * d,
        a2,
        d,
        l,
        mu,
        normal: nu_g / rho2.sqrt(),
        distance: c.dist,
        face_to_face,
    })
}

/// The pose a body would reach at the end of a step of length `h` from `(x, Q)` with velocity
/// `(v, ω)` held constant, under the kinematic map of `docs/model.md#kinematic-map` (Q
/// renormalised): the pose [`pair_features`] is evaluated at for the deterministic retry.
/// Returns `None` for a zero or non-finite quaternion.
pub fn predicted_pose(
    x: &Vector3<f64>,
    q: &Vector4<f64>,
    v: &Vector3<f64>,
    w: &Vector3<f64>,
    h: f64,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let q1 = quat_normalize(&(q + kinematic_map(q) * w * (0.5 * h)))?;
    Some((x + v * h, rotation_matrix(&q1)))
}

/// Non-negative multipliers on the faces active within `tol` (value ≥ −tol) whose gradients
/// combine to the direction `dir` in the least-squares sense; when none is positive, 1 on the
/// face whose gradient is most aligned with `dir`.
pub(crate) fn cone_combination(
    grads: &[Vector3<f64>],
    values: &[f64],
    tol: f64,
    dir: &Vector3<f64>,
) -> Vec<f64> {
    let active: Vec<usize> = (0..grads.len()).filter(|&i| values[i] >= -tol).collect();
    let cols: Vec<Vector3<f64>> = active.iter().map(|&i| grads[i]).collect();
    let x = nnls(&cols, dir);
    let mut out = vec![0.0; grads.len()];
    for (&i, xi) in active.iter().zip(&x) {
        out[i] = *xi;
    }
    if out.iter().all(|v| *v <= 0.0) {
        let best = (0..grads.len())
            .max_by(|&a, &b| grads[a].dot(dir).total_cmp(&grads[b].dot(dir)))
            .unwrap_or(0);
        if let Some(v) = out.get_mut(best) {
            *v = 1.0;
        }
    }
    out
}

/// Non-negative least squares `min ‖Σ x_i c_i − b‖, x ≥ 0` (Lawson–Hanson active set), for the
/// few columns of a hull's faces at one point.
fn nnls(cols: &[Vector3<f64>], b: &Vector3<f64>) -> Vec<f64> {
    let k = cols.len();
    let mut x = vec![0.0; k];
    let mut passive = vec![false; k];
    let scale = cols.iter().map(|c| c.norm()).fold(0.0, f64::max) * b.norm();
    let tol = 1e-12 * scale.max(f64::MIN_POSITIVE);
    let combine = |x: &[f64]| -> Vector3<f64> { cols.iter().zip(x).map(|(c, v)| c * *v).sum() };
    for _ in 0..3 * k + 3 {
        let res = b - combine(&x);
        let best = (0..k)
            .filter(|&j| !passive[j])
            .map(|j| (j, cols[j].dot(&res)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((j, w)) if w > tol => passive[j] = true,
            _ => break,
        }
        for _ in 0..3 * k + 3 {
            let s = passive_least_squares(cols, &passive, b);
            if (0..k).all(|i| !passive[i] || s[i] > 0.0) {
                x = s;
                break;
            }
            // Step from x towards s until the first passive component reaches 0.
            let mut alpha = 1.0f64;
            for i in 0..k {
                if passive[i] && s[i] <= 0.0 {
                    alpha = alpha.min(x[i] / (x[i] - s[i]));
                }
            }
            for i in 0..k {
                x[i] += alpha * (s[i] - x[i]);
                if passive[i] && x[i] <= tol {
                    passive[i] = false;
                    x[i] = 0.0;
                }
            }
        }
    }
    x
}

/// The minimum-norm least-squares solution on the passive columns (0 elsewhere).
fn passive_least_squares(cols: &[Vector3<f64>], passive: &[bool], b: &Vector3<f64>) -> Vec<f64> {
    let idx: Vec<usize> = (0..cols.len()).filter(|&i| passive[i]).collect();
    let mut a = DMatrix::<f64>::zeros(3, idx.len());
    for (c, &i) in idx.iter().enumerate() {
        a.set_column(c, &cols[i]);
    }
    let rhs = DVector::from_column_slice(b.as_slice());
    let sol = a
        .svd(true, true)
        .solve(&rhs, 1e-12)
        .unwrap_or_else(|_| DVector::zeros(idx.len()));
    let mut out = vec![0.0; cols.len()];
    for (c, &i) in idx.iter().enumerate() {
        out[i] = sol[c];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Shape;
    use crate::rotation::quat_from_axis_angle;

    fn cuboid(lx: f64, ly: f64, lz: f64) -> ConvexHull {
        Shape::cuboid(lx, ly, lz)
            .and_then(|s| s.hull())
            .unwrap_or_else(|e| panic!("{e}"))
    }

    /// K1–K3 at the features, and the multipliers on active faces only.
    fn assert_kkt(f: &HullPose<'_>, g: &HullPose<'_>, p: &PairFeatures, tol: f64) {
        let (grads_g, values_g) = g.faces_at(&p.a2);
        let (grads_f, values_f) = f.faces_at(&p.a1);
        let nu: Vector3<f64> = grads_g.iter().zip(&p.mu).map(|(g, m)| g * *m).sum();
        let cone: Vector3<f64> = grads_f.iter().zip(&p.l).map(|(g, m)| g * *m).sum();
        assert!((p.a1 - p.a2 - nu * p.d).norm() < 1e-14, "K1 {p:?}");
        assert!(
            (nu + cone).norm() < tol,
            "K2 {:.3e} {p:?}",
            (nu + cone).norm()
        );
        assert!((p.mu.iter().sum::<f64>() - 1.0).abs() < 1e-14, "K3 {p:?}");
        assert!(p.d >= 0.0 && p.mu.iter().chain(&p.l).all(|v| *v >= 0.0));
        for (m, v) in p.mu.iter().zip(&values_g) {
            assert!(*v <= tol && (*m == 0.0 || v.abs() <= tol), "g {v} μ {m}");
        }
        for (l, v) in p.l.iter().zip(&values_f) {
            assert!(*v <= tol && (*l == 0.0 || v.abs() <= tol), "f {v} l {l}");
        }
        assert!((p.normal - nu.normalize()).norm() < 1e-14);
    }

    #[test]
    fn cube_above_a_slab_face_to_face() {
        // B (0.2 cube) 1 mm above A (0.4 × 0.4 × 0.2), offset: the ECP starts under B's CM.
        let (a, b) = (cuboid(0.4, 0.4, 0.2), cuboid(0.2, 0.2, 0.2));
        let g = HullPose {
            hull: &a,
            x: Vector3::new(0.0, 0.0, 0.1),
            rotation: Matrix3::identity(),
        };
        let f = HullPose {
            hull: &b,
            x: Vector3::new(0.1, 0.05, 0.301),
            rotation: Matrix3::identity(),
        };
        let p = pair_features(&f, &g).unwrap_or_else(|e| panic!("{e}"));
        assert!(p.face_to_face, "{p:?}");
        assert!((p.a2 - Vector3::new(0.1, 0.05, 0.2)).norm() < 1e-9, "{p:?}");
        assert!(
            (p.a1 - Vector3::new(0.1, 0.05, 0.201)).norm() < 1e-9,
            "{p:?}"
        );
        assert!((p.d - 1e-3).abs() < 1e-9 && (p.distance - 1e-3).abs() < 1e-9);
        assert!((p.normal - Vector3::z()).norm() < 1e-12);
        assert_kkt(&f, &g, &p, 1e-9);
        // Touching: d = 0, the same ECP.
        let f = HullPose {
            x: Vector3::new(0.1, 0.05, 0.3),
            ..f
        };
        let p = pair_features(&f, &g).unwrap_or_else(|e| panic!("{e}"));
        assert!(p.face_to_face && p.d == 0.0, "{p:?}");
        assert!((p.a1 - Vector3::new(0.1, 0.05, 0.2)).norm() < 1e-9, "{p:?}");
        assert_kkt(&f, &g, &p, 1e-9);
    }

    #[test]
    fn edge_over_edge_and_vertex_features() {
        // Two bars rotated 45° about their long axes, crossing: an edge–edge contact whose
        // normal is the common perpendicular, ν_G on two faces of G, d = distance / |ν_G|.
        let bar = cuboid(0.6, 0.1, 0.1);
        let q45x = quat_from_axis_angle(&Vector3::x(), std::f64::consts::FRAC_PI_4)
            .unwrap_or_else(|| panic!("axis"));
        let qy = quat_from_axis_angle(&Vector3::z(), std::f64::consts::FRAC_PI_2)
            .unwrap_or_else(|| panic!("axis"));
        let r_fixed = rotation_matrix(&q45x);
        let r_top = rotation_matrix(&qy) * r_fixed;
        let half_diag = 0.05 * 2f64.sqrt();
        let g = HullPose {
            hull: &bar,
            x: Vector3::zeros(),
            rotation: r_fixed,
        };
        let gap = 0.05;
        let f = HullPose {
            hull: &bar,
            x: Vector3::new(0.0, 0.01, 2.0 * half_diag + gap),
            rotation: r_top,
        };
        let p = pair_features(&f, &g).unwrap_or_else(|e| panic!("{e}"));
        assert!(!p.face_to_face);
        assert!((p.distance - gap).abs() < 1e-9, "{p:?}");
        assert!((p.normal - Vector3::z()).norm() < 1e-9, "{p:?}");
        assert!((p.d - gap * 2f64.sqrt()).abs() < 1e-8, "{p:?}");
        assert!(
            (p.a2 - Vector3::new(0.0, 0.0, half_diag)).norm() < 1e-9,
            "{p:?}"
        );
        assert_eq!(p.mu.iter().filter(|m| **m > 0.0).count(), 2);
        assert_kkt(&f, &g, &p, 1e-9);
        // A cube tilted onto a vertex above a slab: one face of G, three of F.
        let a = cuboid(0.4, 0.4, 0.2);
        let b = cuboid(0.2, 0.2, 0.2);
        let q = quat_from_axis_angle(&Vector3::new(1.0, -1.0, 0.0), 0.9553166181245093)
            .unwrap_or_else(|| panic!("axis"));
        let r = rotation_matrix(&q);
        let low = b
            .vertices()
            .iter()
            .map(|v| (r * v).z)
            .fold(f64::INFINITY, f64::min);
        let f = HullPose {
            hull: &b,
            x: Vector3::new(0.05, 0.0, 0.2 + 0.02 - low),
            rotation: r,
        };
        let g = HullPose {
            hull: &a,
            x: Vector3::new(0.0, 0.0, 0.1),
            rotation: Matrix3::identity(),
        };
        let p = pair_features(&f, &g).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            (p.distance - 0.02).abs() < 1e-9 && (p.d - 0.02).abs() < 1e-9,
            "{p:?}"
        );
        assert_eq!(p.l.iter().filter(|v| **v > 0.0).count(), 3, "{p:?}");
        assert_kkt(&f, &g, &p, 1e-9);
    }

    #[test]
    fn overlapping_hulls_give_the_deepest_features() {
        let (a, b) = (cuboid(0.4, 0.4, 0.2), cuboid(0.2, 0.2, 0.2));
        let g = HullPose {
            hull: &a,
            x: Vector3::new(0.0, 0.0, 0.1),
            rotation: Matrix3::identity(),
        };
        let f = HullPose {
            hull: &b,
            x: Vector3::new(0.02, 0.0, 0.295),
            rotation: Matrix3::identity(),
        };
        let p = pair_features(&f, &g).unwrap_or_else(|e| panic!("{e}"));
        assert!((p.distance + 0.005).abs() < 1e-9, "{p:?}");
        assert!(p.d == 0.0 && p.a1 == p.a2 && p.face_to_face, "{p:?}");
        assert!((p.normal - Vector3::z()).norm() < 1e-9, "{p:?}");
        // The CM projected on the top face of A.
        assert!((p.a2 - Vector3::new(0.02, 0.0, 0.2)).norm() < 1e-9, "{p:?}");
    }

    #[test]
    fn nnls_matches_known_combinations() {
        let cols = [Vector3::x(), Vector3::y(), Vector3::z(), -Vector3::x()];
        let x = nnls(&cols, &Vector3::new(1.0, 2.0, -3.0));
        assert_eq!(x, vec![1.0, 2.0, 0.0, 0.0]);
        let x = nnls(&cols, &Vector3::new(-0.5, 0.0, 0.0));
        assert_eq!(x, vec![0.0, 0.0, 0.0, 0.5]);
        assert_eq!(nnls(&[], &Vector3::x()), Vec::<f64>::new());
    }

    #[test]
    fn predicted_pose_follows_the_kinematic_map() {
        let q = Vector4::new(1.0, 0.0, 0.0, 0.0);
        let (x, r) = predicted_pose(
            &Vector3::new(1.0, 0.0, 0.0),
            &q,
            &Vector3::new(0.0, 2.0, 0.0),
            &Vector3::new(0.0, 0.0, 0.2),
            0.5,
        )
        .unwrap_or_else(|| panic!("finite"));
        assert!((x - Vector3::new(1.0, 1.0, 0.0)).norm() < 1e-15);
        let angle = (0.05f64).atan() * 2.0;
        assert!((r[(1, 0)] - angle.sin()).abs() < 1e-15);
        assert!(predicted_pose(&x, &Vector4::zeros(), &x, &x, 0.1).is_none());
    }
}
