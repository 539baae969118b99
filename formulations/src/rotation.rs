//! Quaternion kinematics (`docs/model.md#conventions`, `docs/model.md#kinematic-map`).
//!
//! Quaternions are stored scalar-first, `Q = (w, x, y, z)`, as a
//! [`Vector4<f64>`], and rotate body-frame vectors into the world frame.
//! The rotation matrix uses the *homogeneous* formula, so it is a proper
//! rotation for every non-zero `Q`, unit or not: the step solver can treat the
//! four components of `Q` as free unknowns and the geometry at the end of a
//! step is exactly the geometry of the renormalised quaternion stored
//! afterwards.

use nalgebra::{Matrix3, Matrix4x3, Vector3, Vector4};

/// The skew-symmetric cross-product matrix `[v]×`, with `[v]× u = v × u`.
///
/// Used for `R(Q)`, the kinematic map `E(Q)` and the contact wrenches
/// `r × n` (`docs/model.md#newton-euler`, `docs/model.md#kinematic-map`).
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Rotation matrix (body → world) of a possibly non-unit quaternion `Q = (w, x, y, z)`: `R(Q) =
/// ((w² − |v|²) I + 2 v vᵀ + 2 w [v]×) / |Q|²`, `v = (x, y, z)` (`docs/model.md#conventions`).
///
/// `R(Q) = R(Q/|Q|)` for every `Q ≠ 0`, so the result is always orthonormal
/// with determinant 1. For `Q = 0` the result is non-finite (NaN); callers
/// that take `Q` from user input should check it with [`quat_normalize`].
pub fn rotation_matrix(q: &Vector4<f64>) -> Matrix3<f64> {
    let w = q[0];
    let v = Vector3::new(q[1], q[2], q[3]);
    let s = q.norm_squared();
    let n = Matrix3::identity() * (w * w - v.norm_squared())
        + v * v.transpose() * 2.0
        + skew(&v) * (2.0 * w);
    n / s
}

/// Exact partial derivatives `∂R/∂q_k` of [`rotation_matrix`] for
/// `k = w, x, y, z` (in that order), including the derivative of the
/// `1/|Q|²` factor.
///
/// Needed for the Jacobian of the non-penetration conditions (`docs/model.md#contact`),
/// where `∇f_i = R(Q) n̂_i` depends on the unknown end-of-step quaternion.
/// With `R = N(Q)/s`, `s = |Q|²`: `∂R/∂q_k = (∂N/∂q_k − 2 q_k R)/s`.
pub fn rotation_matrix_derivatives(q: &Vector4<f64>) -> [Matrix3<f64>; 4] {
    rotation_matrix_and_derivatives(q).1
}

/// [`rotation_matrix`] and [`rotation_matrix_derivatives`] together: the derivatives are built
/// from `R`, so a caller that needs both computes `R` once (the same bits as the two calls).
#[inline]
pub fn rotation_matrix_and_derivatives(q: &Vector4<f64>) -> (Matrix3<f64>, [Matrix3<f64>; 4]) {
    let w = q[0];
    let v = Vector3::new(q[1], q[2], q[3]);
    let s = q.norm_squared();
    let r = rotation_matrix(q);
    let id = Matrix3::identity();

    // ∂N/∂w = 2 w I + 2 [v]×
    let dn_dw = id * (2.0 * w) + skew(&v) * 2.0;
    let mut out = [(dn_dw - r * (2.0 * w)) / s; 4];
    for i in 0..3 {
        let e = Vector3::ith(i, 1.0);
        // ∂N/∂v_i = −2 v_i I + 2 (e_i vᵀ + v e_iᵀ) + 2 w [e_i]×
        let dn = id * (-2.0 * v[i])
            + (e * v.transpose() + v * e.transpose()) * 2.0
            + skew(&e) * (2.0 * w);
        out[i + 1] = (dn - r * (2.0 * v[i])) / s;
    }
    (r, out)
}

/// Kinematic map `E(Q)` with `Q̇ = ½ E(Q) ω` for the WORLD-frame angular
/// velocity ω (`docs/model.md#kinematic-map`): `ẇ = −½ ω·v`, `v̇ = ½ (w ω + ω × v)`, hence
/// `E = [−vᵀ; w I − [v]×]`. Equivalent to `Q̇ = ½ [0; ω] ⊗ Q`.
pub fn kinematic_map(q: &Vector4<f64>) -> Matrix4x3<f64> {
    let w = q[0];
    let v = Vector3::new(q[1], q[2], q[3]);
    let lower = Matrix3::identity() * w - skew(&v);
    let mut e = Matrix4x3::zeros();
    e.fixed_view_mut::<1, 3>(0, 0).copy_from(&(-v.transpose()));
    e.fixed_view_mut::<3, 3>(1, 0).copy_from(&lower);
    e
}

/// Hamilton product `a ⊗ b` of scalar-first quaternions.
///
/// `R(a ⊗ b) = R(a) R(b)`: `b` is applied first. Used to compose orientations
/// in scene set-up (e.g. the tilted drop of scenario A5).
pub fn quat_mul(a: &Vector4<f64>, b: &Vector4<f64>) -> Vector4<f64> {
    let (aw, ax, ay, az) = (a[0], a[1], a[2], a[3]);
    let (bw, bx, by, bz) = (b[0], b[1], b[2], b[3]);
    Vector4::new(
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )
}

/// Unit quaternion for a rotation by `angle` radians (right-hand rule) about
/// `axis`, which need not be unit length.
///
/// Returns `None` if the axis is zero or any input is non-finite (there is
/// no meaningful rotation to return).
pub fn quat_from_axis_angle(axis: &Vector3<f64>, angle: f64) -> Option<Vector4<f64>> {
    let n = axis.norm();
    if !(n.is_finite() && n > 0.0 && angle.is_finite()) {
        return None;
    }
    let a = axis / n;
    let (s, c) = (0.5 * angle).sin_cos();
    Some(Vector4::new(c, s * a.x, s * a.y, s * a.z))
}

/// Unit quaternion for roll/pitch/yaw angles in DEGREES, with
/// `R = Rz(yaw) Ry(pitch) Rx(roll)` (roll applied first, about the world x
/// axis). This is how scene files state initial orientations.
pub fn quat_from_rpy_deg(roll: f64, pitch: f64, yaw: f64) -> Vector4<f64> {
    let half = |deg: f64| (0.5 * deg.to_radians()).sin_cos();
    let (sr, cr) = half(roll);
    let (sp, cp) = half(pitch);
    let (sy, cy) = half(yaw);
    let qx = Vector4::new(cr, sr, 0.0, 0.0);
    let qy = Vector4::new(cp, 0.0, sp, 0.0);
    let qz = Vector4::new(cy, 0.0, 0.0, sy);
    quat_mul(&qz, &quat_mul(&qy, &qx))
}

/// `Q/|Q|`, or `None` when `Q` is zero or not finite.
///
/// The time stepper renormalises the end-of-step quaternion with this
/// (`docs/model.md#kinematic-map`); a `None` means the step produced garbage and must be rejected.
pub fn quat_normalize(q: &Vector4<f64>) -> Option<Vector4<f64>> {
    let n = q.norm();
    if n.is_finite() && n > 0.0 {
        Some(q / n)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Quaternion, UnitQuaternion};

    /// Small deterministic generator, so the tests need no extra crates.
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64) / ((1u64 << 53) as f64) * 2.0 - 1.0
        }
        fn quat(&mut self) -> Vector4<f64> {
            // Non-unit, scale between ~0.3 and ~3.
            let q = Vector4::new(self.next(), self.next(), self.next(), self.next());
            let scale = 0.3 + 2.7 * (self.next() + 1.0) / 2.0;
            q.normalize() * scale
        }
    }

    #[test]
    fn rotation_is_proper_for_non_unit_quaternions() {
        let mut rng = Lcg(7);
        for _ in 0..200 {
            let q = rng.quat();
            let r = rotation_matrix(&q);
            let err = (r.transpose() * r - Matrix3::identity()).abs().max();
            assert!(err < 1e-14, "RᵀR − I = {err}");
            assert!((r.determinant() - 1.0).abs() < 1e-14);
        }
    }

    #[test]
    fn matches_nalgebra_for_unit_quaternions() {
        let mut rng = Lcg(11);
        for _ in 0..100 {
            let q = rng.quat().normalize();
            let uq = UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
            let expected = uq.to_rotation_matrix().into_inner();
            assert!((rotation_matrix(&q) - expected).abs().max() < 1e-14);
        }
    }

    #[test]
    fn rotation_and_derivatives_together_are_the_same_bits() {
        let mut rng = Lcg(5);
        let bits = |m: &Matrix3<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let mut qs: Vec<Vector4<f64>> = (0..50).map(|_| rng.quat()).collect();
        // Exact zeros and a negative zero, where signed zeros could differ.
        qs.push(Vector4::new(1.0, 0.0, 0.0, 0.0));
        qs.push(Vector4::new(-0.0, 0.0, -1.0, 0.0));
        for q in qs {
            let (r, d) = rotation_matrix_and_derivatives(&q);
            assert_eq!(bits(&r), bits(&rotation_matrix(&q)));
            for (a, b) in d.iter().zip(rotation_matrix_derivatives(&q).iter()) {
                assert_eq!(bits(a), bits(b));
            }
        }
    }

    #[test]
    fn derivatives_match_central_differences() {
        let mut rng = Lcg(3);
        for _ in 0..50 {
            let q = rng.quat();
            let d = rotation_matrix_derivatives(&q);
            for (k, dk) in d.iter().enumerate() {
                let h = 1e-6;
                let mut qp = q;
                let mut qm = q;
                qp[k] += h;
                qm[k] -= h;
                let fd = (rotation_matrix(&qp) - rotation_matrix(&qm)) / (2.0 * h);
                let scale = dk.abs().max().max(1.0 / q.norm());
                let err = (fd - dk).abs().max() / scale;
                assert!(err < 1e-7, "k = {k}: relative error {err}");
            }
        }
    }

    #[test]
    fn kinematic_map_matches_quaternion_product() {
        let mut rng = Lcg(5);
        for _ in 0..50 {
            let q = rng.quat();
            let w = Vector3::new(rng.next(), rng.next(), rng.next()) * 3.0;
            let lhs = kinematic_map(&q) * w * 0.5;
            let rhs = quat_mul(&Vector4::new(0.0, w.x, w.y, w.z), &q) * 0.5;
            assert!((lhs - rhs).abs().max() < 1e-14);
        }
    }

    #[test]
    fn kinematic_map_gives_world_frame_rate() {
        // d/dt R(Q) = [ω]× R for world-frame ω.
        let mut rng = Lcg(9);
        let q = rng.quat().normalize();
        let w = Vector3::new(0.3, -1.2, 0.7);
        let qdot = kinematic_map(&q) * w * 0.5;
        let d = rotation_matrix_derivatives(&q);
        let rdot = (0..4).fold(Matrix3::zeros(), |acc, k| acc + d[k] * qdot[k]);
        let expected = skew(&w) * rotation_matrix(&q);
        assert!((rdot - expected).abs().max() < 1e-13);
    }

    #[test]
    fn skew_is_cross_product() {
        let a = Vector3::new(1.0, -2.0, 0.5);
        let b = Vector3::new(0.3, 0.4, -2.0);
        assert!((skew(&a) * b - a.cross(&b)).norm() < 1e-15);
    }

    #[test]
    fn rpy_composition() {
        let (roll, pitch, yaw) = (20.0_f64, 10.0_f64, -35.0_f64);
        let q = quat_from_rpy_deg(roll, pitch, yaw);
        assert!((q.norm() - 1.0).abs() < 1e-15);
        let rx = rotation_matrix(&quat_from_axis_angle(&Vector3::x(), roll.to_radians()).unwrap());
        let ry = rotation_matrix(&quat_from_axis_angle(&Vector3::y(), pitch.to_radians()).unwrap());
        let rz = rotation_matrix(&quat_from_axis_angle(&Vector3::z(), yaw.to_radians()).unwrap());
        assert!((rotation_matrix(&q) - rz * ry * rx).abs().max() < 1e-14);
        let na = nalgebra::Rotation3::from_euler_angles(
            roll.to_radians(),
            pitch.to_radians(),
            yaw.to_radians(),
        );
        assert!((rotation_matrix(&q) - na.into_inner()).abs().max() < 1e-14);
        // Rotation of −θ about y maps the body z axis to the incline normal
        // (−sin θ, 0, cos θ) (scenario A4).
        let th = 25.0_f64;
        let r = rotation_matrix(&quat_from_rpy_deg(0.0, -th, 0.0));
        let n = Vector3::new(-th.to_radians().sin(), 0.0, th.to_radians().cos());
        assert!((r * Vector3::z() - n).norm() < 1e-15);
    }

    #[test]
    fn axis_angle_and_quat_mul() {
        let qa = quat_from_axis_angle(&Vector3::new(0.0, 0.0, 2.0), std::f64::consts::FRAC_PI_2)
            .unwrap();
        let r = rotation_matrix(&qa);
        assert!((r * Vector3::x() - Vector3::y()).norm() < 1e-15);
        let qb = quat_from_axis_angle(&Vector3::new(1.0, 1.0, 0.0), 0.7).unwrap();
        let prod = rotation_matrix(&quat_mul(&qa, &qb));
        assert!(
            (prod - rotation_matrix(&qa) * rotation_matrix(&qb))
                .abs()
                .max()
                < 1e-15
        );
        assert!(quat_from_axis_angle(&Vector3::zeros(), 1.0).is_none());
        assert!(quat_from_axis_angle(&Vector3::x(), f64::NAN).is_none());
    }

    #[test]
    fn normalize_rejects_zero() {
        assert!(quat_normalize(&Vector4::zeros()).is_none());
        assert!(quat_normalize(&Vector4::new(f64::NAN, 0.0, 0.0, 1.0)).is_none());
        let q = quat_normalize(&Vector4::new(2.0, 0.0, 0.0, 0.0)).unwrap();
        assert_eq!(q, Vector4::new(1.0, 0.0, 0.0, 0.0));
    }
}
