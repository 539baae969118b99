//! The normal and the contact frame of a contact between two bodies as functions of the unknowns
//! (`docs/model.md#contact-between-two-bodies`).
//!
//! Between F and a half-space the frame `(n, t, o)` is a constant. Between two hulls the normal
//! is `n = ν_G / |ν_G|` with `ν_G = Σ_j μ_j ∇g_j = R_G Σ_j μ_j m̂_j`, the outward normal of Conv(G)
//! at `a2`, so it moves with the face multipliers `μ` and with G's end-of-step orientation; the
//! tangents follow it smoothly: `t` is the Gram–Schmidt projection of a reference axis `r`
//! (data, chosen per contact per step, [`reference_axis`]) on the plane normal to `n`, and
//! `o = n × t`. No branch can flip inside a step, and every derivative is exact.

use nalgebra::{Matrix3, Vector3, Vector4};

use ecp_model::JacobianBlocks;

use crate::rotation::{rotation_matrix_and_derivatives, skew};

/// Below this length `ν_G` (or the projected reference axis) has no direction: the frame falls
/// back to a fixed one with zero derivatives rather than divide by zero. At a solution
/// `|ν_G| ≥ cos` of the largest angle between G's active faces, so it never comes near.
const DEGENERATE: f64 = 1e-12;

/// The coordinate axis least aligned with `normal` (the smallest `|n_i|`, ties to the lower
/// index): the reference axis of a contact's frame for a step whose normal is predicted to be
/// `normal` (`docs/decisions.md#frame-of-a-contact-between-two-bodies`). Its angle with the
/// normal is at least `acos(1/√3) ≈ 54.7°`, so the frame stays smooth while the normal turns by
/// less than that within the step. For the ground (`n = e_z`) it is `e_x`, which gives the
/// frame `(e_z, e_x, e_y)` of the half-space.
pub fn reference_axis(normal: &Vector3<f64>) -> Vector3<f64> {
    let a = normal.abs();
    let i = if a.x <= a.y && a.x <= a.z {
        0
    } else if a.y <= a.z {
        1
    } else {
        2
    };
    Vector3::ith(i, 1.0)
}

/// `ν_G = R(Q_G) Σ_j μ_j m̂_j`: the convex combination of G's face gradients that (K1)–(K3)
/// normalise, with what its derivatives need.
#[derive(Clone, Debug)]
pub struct SupportNormal {
    /// `ν_G` (world frame).
    pub value: Vector3<f64>,
    /// `R(Q_G)`.
    pub rotation: Matrix3<f64>,
    /// `Σ_j μ_j m̂_j` (G's body frame).
    local: Vector3<f64>,
    /// `∂R/∂Q_k`.
    dr: [Matrix3<f64>; 4],
}

impl SupportNormal {
    /// `ν_G` for G's body-frame face normals `normals`, multipliers `mu` and end-of-step
    /// quaternion `q` (any non-zero norm).
    pub fn new(normals: &[Vector3<f64>], mu: &[f64], q: &Vector4<f64>) -> Self {
        let mut local = Vector3::zeros();
        for (m, w) in normals.iter().zip(mu) {
            local += m * *w;
        }
        let (rotation, dr) = rotation_matrix_and_derivatives(q);
        SupportNormal {
            value: rotation * local,
            rotation,
            local,
            dr,
        }
    }

    /// `∂ν_G/∂Q_k`.
    pub fn d_quaternion(&self, k: usize) -> Vector3<f64> {
        self.dr[k] * self.local
    }

    /// Writes the chain rule of rows that depend on the unknowns through `ν_G`: given, for each
    /// row `i` listed, the gradient `g_i = ∂row_i/∂ν_G`, adds `g_i · R m̂_j` to column `j` of
    /// input `k_mu` (the multipliers μ) and `g_i · ∂R/∂Q_k Σμm̂` to column `3 + k` of input
    /// `k_q` (G's q, whose position columns do not enter `ν_G`).
    pub fn add_chain(
        &self,
        normals: &[Vector3<f64>],
        rows: &[(usize, Vector3<f64>)],
        k_mu: usize,
        k_q: usize,
        jac: &mut JacobianBlocks<'_>,
    ) {
        if jac.wants(k_mu) {
            for (j, m) in normals.iter().enumerate() {
                let col = self.rotation * m;
                for (i, g) in rows {
                    jac.add(k_mu, *i, j, g.dot(&col));
                }
            }
        }
        if jac.wants(k_q) {
            for k in 0..4 {
                let col = self.d_quaternion(k);
                for (i, g) in rows {
                    jac.add(k_q, *i, 3 + k, g.dot(&col));
                }
            }
        }
    }
}

/// The contact frame `(n, t, o)` of a contact between two bodies, as a function of `ν_G` and the
/// reference axis `r`, with its exact derivatives:
///
/// - `n = ν_G / |ν_G|`;
/// - `t = u / |u|`, `u = r − (n·r) n` (Gram–Schmidt of `r` against `n`);
/// - `o = n × t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairFrame {
    /// Unit normal of G pointing into F.
    pub n: Vector3<f64>,
    /// First tangent.
    pub t: Vector3<f64>,
    /// Second tangent, `n × t`.
    pub o: Vector3<f64>,
    /// `∂n/∂ν_G = (I − n nᵀ)/|ν_G|`.
    pub dn: Matrix3<f64>,
    /// `∂t/∂ν_G = P (−(n·r) I − n rᵀ) ∂n/∂ν_G`, `P = (I − t tᵀ)/|u|`.
    pub dt: Matrix3<f64>,
    /// `∂o/∂ν_G = [n]× ∂t/∂ν_G − [t]× ∂n/∂ν_G`.
    pub d_o: Matrix3<f64>,
    /// `∂t/∂r = P (I − n nᵀ)`.
    pub dt_axis: Matrix3<f64>,
    /// `∂o/∂r = [n]× ∂t/∂r`.
    pub do_axis: Matrix3<f64>,
}

impl PairFrame {
    /// The frame of `ν_G` with reference axis `axis`.
    ///
    /// Degenerate inputs (`|ν_G|` or `|u|` below 1e-12, which no solution has) give a fixed
    /// right-handed frame and zero derivatives, never NaN.
    pub fn new(nu_g: &Vector3<f64>, axis: &Vector3<f64>) -> Self {
        let rho = nu_g.norm();
        let (n, dn) = if rho > DEGENERATE && rho.is_finite() {
            let n = nu_g / rho;
            (n, (Matrix3::identity() - n * n.transpose()) / rho)
        } else {
            (Vector3::z(), Matrix3::zeros())
        };
        let nr = n.dot(axis);
        let u = axis - n * nr;
        let len = u.norm();
        if !(len > DEGENERATE && len.is_finite()) {
            // r ∥ n: any tangent will do; the least aligned axis is exactly orthogonal enough.
            let seed = reference_axis(&n);
            let t = (seed - n * n.dot(&seed)).normalize();
            return PairFrame {
                n,
                t,
                o: n.cross(&t),
                dn,
                dt: Matrix3::zeros(),
                d_o: -skew(&t) * dn,
                dt_axis: Matrix3::zeros(),
                do_axis: Matrix3::zeros(),
            };
        }
        let t = u / len;
        let p = (Matrix3::identity() - t * t.transpose()) / len;
        let du_dn = -Matrix3::identity() * nr - n * axis.transpose();
        let dt = p * du_dn * dn;
        let dt_axis = p * (Matrix3::identity() - n * n.transpose());
        let (sn, st) = (skew(&n), skew(&t));
        PairFrame {
            n,
            t,
            o: n.cross(&t),
            dn,
            dt,
            d_o: sn * dt - st * dn,
            dt_axis,
            do_axis: sn * dt_axis,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rotation::rotation_matrix;

    fn frame_fd(nu: &Vector3<f64>, axis: &Vector3<f64>) -> [[Matrix3<f64>; 3]; 2] {
        // Central differences of (n, t, o) with respect to ν_G and to r, column by column.
        let mut out = [[Matrix3::zeros(); 3]; 2];
        let h = 1e-6;
        for (which, base) in [nu, axis].into_iter().enumerate() {
            for j in 0..3 {
                let mut p = *base;
                let mut m = *base;
                p[j] += h;
                m[j] -= h;
                let (fp, fm) = if which == 0 {
                    (PairFrame::new(&p, axis), PairFrame::new(&m, axis))
                } else {
                    (PairFrame::new(nu, &p), PairFrame::new(nu, &m))
                };
                for (k, (a, b)) in [(fp.n, fm.n), (fp.t, fm.t), (fp.o, fm.o)]
                    .into_iter()
                    .enumerate()
                {
                    out[which][k].set_column(j, &((a - b) / (2.0 * h)));
                }
            }
        }
        out
    }

    #[test]
    fn frame_is_orthonormal_with_exact_derivatives() {
        let cases = [
            (Vector3::new(0.1, -0.3, 0.9), Vector3::x()),
            (Vector3::new(2.0, 0.5, -0.4), Vector3::new(0.0, 1.0, 0.2)),
            (Vector3::new(-0.2, 0.1, 0.05), Vector3::new(0.3, 0.4, 0.5)),
        ];
        for (nu, axis) in cases {
            let f = PairFrame::new(&nu, &axis);
            let m = Matrix3::from_columns(&[f.n, f.t, f.o]);
            assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-14);
            assert!((m.determinant() - 1.0).abs() < 1e-14);
            assert!((f.n - nu.normalize()).norm() < 1e-15);
            // t lies in the plane of n and r, on r's side.
            assert!(f.t.dot(&axis) > 0.0 && f.t.dot(&f.n.cross(&axis)).abs() < 1e-14);
            let fd = frame_fd(&nu, &axis);
            let analytic = [
                [f.dn, f.dt, f.d_o],
                [Matrix3::zeros(), f.dt_axis, f.do_axis],
            ];
            for w in 0..2 {
                for k in 0..3 {
                    let err = (fd[w][k] - analytic[w][k]).abs().max();
                    assert!(err < 1e-8, "input {w}, vector {k}: error {err:.3e}");
                }
            }
        }
    }

    #[test]
    fn ground_frame_matches_the_half_space_frame() {
        let n = Vector3::z();
        let axis = reference_axis(&n);
        assert_eq!(axis, Vector3::x());
        let f = PairFrame::new(&(n * 0.7), &axis);
        assert_eq!((f.n, f.t, f.o), (n, Vector3::x(), Vector3::y()));
        // Least aligned, ties to the lower index.
        assert_eq!(reference_axis(&Vector3::new(-0.42, 0.0, 0.9)), Vector3::y());
        assert_eq!(reference_axis(&Vector3::new(1.0, 0.3, 0.3)), Vector3::y());
        assert_eq!(reference_axis(&Vector3::new(0.5, 0.6, 0.1)), Vector3::z());
    }

    #[test]
    fn degenerate_inputs_give_a_finite_frame() {
        for (nu, axis) in [
            (Vector3::zeros(), Vector3::x()),
            (Vector3::new(0.0, 0.0, 2.0), Vector3::new(0.0, 0.0, 5.0)),
        ] {
            let f = PairFrame::new(&nu, &axis);
            let m = Matrix3::from_columns(&[f.n, f.t, f.o]);
            assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-14);
            for d in [f.dn, f.dt, f.d_o, f.dt_axis, f.do_axis] {
                assert!(d.iter().all(|v| v.is_finite()));
            }
        }
    }

    #[test]
    fn support_normal_derivatives() {
        let normals = [Vector3::z(), Vector3::x(), -Vector3::y()];
        let mu = [0.5, 0.3, 0.2];
        let q = Vector4::new(0.9, 0.2, -0.3, 0.1) * 1.3;
        let s = SupportNormal::new(&normals, &mu, &q);
        let h = 1e-6;
        for k in 0..4 {
            let (mut qp, mut qm) = (q, q);
            qp[k] += h;
            qm[k] -= h;
            let fd = (SupportNormal::new(&normals, &mu, &qp).value
                - SupportNormal::new(&normals, &mu, &qm).value)
                / (2.0 * h);
            assert!((fd - s.d_quaternion(k)).norm() < 1e-8);
        }
        let local = normals[0] * 0.5 + normals[1] * 0.3 + normals[2] * 0.2;
        assert!((s.value - rotation_matrix(&q) * local).norm() < 1e-15);
    }
}
