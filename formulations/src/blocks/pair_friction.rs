//! Friction of a contact between two bodies (`docs/model.md#contact-between-two-bodies`): the
//! maximum-dissipation rows of `docs/model.md#friction` on the RELATIVE velocity of F with
//! respect to G at the ECP, in the frame of the unknown normal ([`super::PairFrame`]). The cone
//! row is the half-space's [`super::FrictionEllipsoid`], reading the pair's friction data.

use nalgebra::{Matrix3, Vector3};

use ecp_model::{JacobianBlocks, Params, ResidualBlock};

use super::common::{v3, v4};
use super::friction::FrictionParams;
use super::pair_frame::{PairFrame, SupportNormal};

/// The relative motion of F with respect to G at the ECP: `v_rel = v_F + ω_F × (a1 − x_F) − v_G −
/// ω_G × (a2 − x_G)` and `ω_rel = ω_F − ω_G`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelativeVelocity {
    /// Relative linear velocity at the ECP.
    pub v: Vector3<f64>,
    /// Relative angular velocity.
    pub w: Vector3<f64>,
    /// F's angular velocity `ω_F`.
    pub w_f: Vector3<f64>,
    /// G's angular velocity `ω_G`.
    pub w_g: Vector3<f64>,
    /// F's lever `a1 − x_F`.
    pub r_f: Vector3<f64>,
    /// G's lever `a2 − x_G`.
    pub r_g: Vector3<f64>,
}

impl RelativeVelocity {
    /// From F's and G's `ν` and `q` and the ECPs `a1`, `a2` (slices as the blocks read them).
    pub fn new(
        nu_f: &[f64],
        q_f: &[f64],
        nu_g: &[f64],
        q_g: &[f64],
        a1: &[f64],
        a2: &[f64],
    ) -> Self {
        let (w_f, w_g) = (v3(nu_f, 3), v3(nu_g, 3));
        let r_f = v3(a1, 0) - v3(q_f, 0);
        let r_g = v3(a2, 0) - v3(q_g, 0);
        RelativeVelocity {
            v: v3(nu_f, 0) + w_f.cross(&r_f) - v3(nu_g, 0) - w_g.cross(&r_g),
            w: w_f - w_g,
            w_f,
            w_g,
            r_f,
            r_g,
        }
    }

    /// The slip `(t·v_rel, o·v_rel, n·ω_rel)` in `frame`: `W_tᵀν`, `W_oᵀν`, `W_rᵀν` of
    /// `docs/model.md#friction` for the relative motion.
    pub fn slip(&self, frame: &PairFrame) -> [f64; 3] {
        [
            frame.t.dot(&self.v),
            frame.o.dot(&self.v),
            frame.n.dot(&self.w),
        ]
    }
}

/// Maximum-power-dissipation rows on the relative motion (paper (14), `docs/model.md#friction`):
/// `0 = e_t² μ p_n t·v_rel + p_t σ`, `0 = e_o² μ p_n o·v_rel + p_o σ`,
/// `0 = e_r² μ p_n n·ω_rel + p_r σ`, with `(n, t, o)` the [`PairFrame`] of
/// `ν_G = R_G Σ_j μ_j m̂_j` and the reference axis.
///
/// Reads, in order ([`PairFriction::NU_F`] …): F's `ν` (6) and `q` (7), G's `ν` (6) and `q` (7)
/// (variables for a dynamic body, data for a fixed or kinematic one), `a1` (3), `a2` (3), `μ`
/// (m_G), `p_n` (1), `p_f` (3), `σ` (1), the pair's `friction` data (4: μ, e_t, e_o, e_r) and
/// its reference `axis` data (3).
#[derive(Clone, Debug)]
pub struct PairFriction {
    /// G's outward unit face normals `m̂_j` (body frame).
    pub g_normals: Vec<Vector3<f64>>,
    sizes: [usize; 12],
}

impl PairFriction {
    /// Index of F's `ν`.
    pub const NU_F: usize = 0;
    /// Index of F's `q`.
    pub const Q_F: usize = 1;
    /// Index of G's `ν`.
    pub const NU_G: usize = 2;
    /// Index of G's `q`.
    pub const Q_G: usize = 3;
    /// Index of `a1`.
    pub const A1: usize = 4;
    /// Index of `a2`.
    pub const A2: usize = 5;
    /// Index of `μ` (G's face multipliers).
    pub const MU: usize = 6;
    /// Index of `p_n`.
    pub const PN: usize = 7;
    /// Index of `p_f = (p_t, p_o, p_r)`.
    pub const PF: usize = 8;
    /// Index of `σ`.
    pub const SIGMA: usize = 9;
    /// Index of the `friction` data.
    pub const FRICTION: usize = 10;
    /// Index of the reference `axis` data.
    pub const AXIS: usize = 11;

    /// The block for G's face normals.
    pub fn new(g_normals: Vec<Vector3<f64>>) -> Self {
        let m = g_normals.len();
        PairFriction {
            g_normals,
            sizes: [6, 7, 6, 7, 3, 3, m, 1, 3, 1, 4, 3],
        }
    }

    fn frame(&self, x: Params<'_>) -> (SupportNormal, PairFrame) {
        let nu = SupportNormal::new(
            &self.g_normals,
            x.block(Self::MU),
            &v4(x.block(Self::Q_G), 3),
        );
        let frame = PairFrame::new(&nu.value, &v3(x.block(Self::AXIS), 0));
        (nu, frame)
    }

    fn relative(x: Params<'_>) -> RelativeVelocity {
        RelativeVelocity::new(
            x.block(Self::NU_F),
            x.block(Self::Q_F),
            x.block(Self::NU_G),
            x.block(Self::Q_G),
            x.block(Self::A1),
            x.block(Self::A2),
        )
    }
}

/// `e_t² μ`, `e_o² μ`, `e_r² μ`.
fn scales(f: &FrictionParams) -> [f64; 3] {
    [
        f.e_t * f.e_t * f.mu,
        f.e_o * f.e_o * f.mu,
        f.e_r * f.e_r * f.mu,
    ]
}

impl ResidualBlock for PairFriction {
    fn name(&self) -> &str {
        "pair_friction"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let (_, frame) = self.frame(x);
        let slip = Self::relative(x).slip(&frame);
        let pn = x.block(Self::PN)[0];
        let pf = x.block(Self::PF);
        let sigma = x.block(Self::SIGMA)[0];
        let s = scales(&FrictionParams::from_slice(x.block(Self::FRICTION)));
        for i in 0..3 {
            out[i] = s[i] * pn * slip[i] + pf[i] * sigma;
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let (nu, frame) = self.frame(x);
        let rel = Self::relative(x);
        let slip = rel.slip(&frame);
        let pn = x.block(Self::PN)[0];
        let pf = x.block(Self::PF);
        let sigma = x.block(Self::SIGMA)[0];
        let f = FrictionParams::from_slice(x.block(Self::FRICTION));
        let s = scales(&f);
        if jac.wants(Self::FRICTION) {
            let e = [f.e_t, f.e_o, f.e_r];
            for i in 0..3 {
                jac.set(Self::FRICTION, i, 0, e[i] * e[i] * pn * slip[i]);
                jac.set(Self::FRICTION, i, 1 + i, 2.0 * e[i] * f.mu * pn * slip[i]);
            }
        }
        for i in 0..3 {
            jac.set(Self::PN, i, 0, s[i] * slip[i]);
            jac.set(Self::PF, i, i, sigma);
            jac.set(Self::SIGMA, i, 0, pf[i]);
        }
        let c = [s[0] * pn, s[1] * pn, s[2] * pn];
        // Rows t and o: d·v_rel with d·(ω × r) = r·(d × ω), so ∂/∂a1 = d × ω_F = −∂/∂x_F and
        // ∂/∂a2 = −d × ω_G = −∂/∂x_G.
        for (row, d) in [(0usize, frame.t), (1, frame.o)] {
            let (arm_f, arm_g) = (rel.r_f.cross(&d), rel.r_g.cross(&d));
            let (lever_f, lever_g) = (d.cross(&rel.w_f), d.cross(&rel.w_g));
            for k in 0..3 {
                jac.set(Self::NU_F, row, k, c[row] * d[k]);
                jac.set(Self::NU_F, row, 3 + k, c[row] * arm_f[k]);
                jac.set(Self::NU_G, row, k, -c[row] * d[k]);
                jac.set(Self::NU_G, row, 3 + k, -c[row] * arm_g[k]);
                jac.set(Self::A1, row, k, c[row] * lever_f[k]);
                jac.set(Self::Q_F, row, k, -c[row] * lever_f[k]);
                jac.set(Self::A2, row, k, -c[row] * lever_g[k]);
                jac.set(Self::Q_G, row, k, c[row] * lever_g[k]);
            }
        }
        for k in 0..3 {
            jac.set(Self::NU_F, 2, 3 + k, c[2] * frame.n[k]);
            jac.set(Self::NU_G, 2, 3 + k, -c[2] * frame.n[k]);
        }
        // Through the frame: ∂(d·v)/∂ν_G = (∂d/∂ν_G)ᵀ v, and the same for the axis.
        let through = |m: &Matrix3<f64>, v: &Vector3<f64>, c: f64| m.transpose() * v * c;
        let rows = [
            (0, through(&frame.dt, &rel.v, c[0])),
            (1, through(&frame.d_o, &rel.v, c[1])),
            (2, through(&frame.dn, &rel.w, c[2])),
        ];
        nu.add_chain(&self.g_normals, &rows, Self::MU, Self::Q_G, jac);
        if jac.wants(Self::AXIS) {
            let rows = [
                through(&frame.dt_axis, &rel.v, c[0]),
                through(&frame.do_axis, &rel.v, c[1]),
            ];
            for (i, g) in rows.iter().enumerate() {
                for k in 0..3 {
                    jac.set(Self::AXIS, i, k, g[k]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::super::common::{ContactFrame, flat};
    use super::super::friction::FrictionDissipation;
    use super::*;

    const FRICTION: [f64; 4] = [0.4, 1.0, 0.8, 0.05];

    fn eval(b: &dyn ResidualBlock, params: &[&[f64]]) -> Vec<f64> {
        let (z, ranges) = flat(params);
        let mut out = vec![0.0; b.num_residuals()];
        b.evaluate(Params::new(&z, &[], &ranges), &mut out);
        out
    }

    fn faces() -> Vec<Vector3<f64>> {
        vec![Vector3::z(), -Vector3::z(), Vector3::x()]
    }

    #[test]
    fn no_slip_when_f_moves_with_g() {
        // G turns at ω about an axis through x_G and translates; F follows rigidly; a1 = a2.
        let (x_g, x_f) = (Vector3::new(0.1, 0.2, 0.0), Vector3::new(0.3, -0.1, 0.5));
        let (v_g, w) = (Vector3::new(0.5, -0.2, 0.1), Vector3::new(0.3, -1.0, 2.0));
        let v_f = v_g + w.cross(&(x_f - x_g));
        let nu_f = [v_f.x, v_f.y, v_f.z, w.x, w.y, w.z];
        let nu_g = [v_g.x, v_g.y, v_g.z, w.x, w.y, w.z];
        let q_f = [x_f.x, x_f.y, x_f.z, 0.9, 0.1, 0.2, -0.3];
        let q_g = [x_g.x, x_g.y, x_g.z, 0.8, -0.3, 0.1, 0.2];
        let a = [0.25, 0.0, 0.3];
        let (mu, pn, pf, sigma) = ([0.6, 0.0, 0.4], [2.0], [0.3, -0.2, 0.01], [0.7]);
        let b = PairFriction::new(faces());
        let params: [&[f64]; 12] = [
            &nu_f,
            &q_f,
            &nu_g,
            &q_g,
            &a,
            &a,
            &mu,
            &pn,
            &pf,
            &sigma,
            &FRICTION,
            &[0.0, 1.0, 0.0],
        ];
        let r = eval(&b, &params);
        for i in 0..3 {
            assert!((r[i] - pf[i] * sigma[0]).abs() < 1e-14, "{r:?}");
        }
        let report = check_residual_block(&b, &params, &CheckOptions::default()).expect("sizes");
        assert!(report.ok(), "{report}");
        assert_eq!(
            report.entries,
            3 * (6 + 7 + 6 + 7 + 3 + 3 + 3 + 1 + 3 + 1 + 4 + 3)
        );
    }

    #[test]
    fn reduces_to_the_half_space_rows_on_a_fixed_one_face_body() {
        // G: the ground as a one-face body at rest (ν_G = 0, identity pose), μ = 1: the rows of
        // FrictionDissipation with the frame (e_z, e_x, e_y).
        let nu_f = [1.0, -0.3, 0.2, 0.4, -0.5, 2.0];
        let q_f = [0.0, 0.1, 0.5, 0.9, 0.1, 0.2, -0.3];
        let (a1, pn, pf, sigma) = ([0.05, -0.1, 0.0], [2.0], [-0.3, 0.1, 0.02], [0.5]);
        let q_g = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let pair = eval(
            &PairFriction::new(vec![Vector3::z()]),
            &[
                &nu_f,
                &q_f,
                &[0.0; 6],
                &q_g,
                &a1,
                &a1,
                &[1.0],
                &pn,
                &pf,
                &sigma,
                &FRICTION,
                &[1.0, 0.0, 0.0],
            ],
        );
        let frame = ContactFrame {
            n: Vector3::z(),
            t: Vector3::x(),
            o: Vector3::y(),
        };
        let half = eval(
            &FrictionDissipation { frame },
            &[&nu_f, &q_f, &a1, &pn, &pf, &sigma, &FRICTION],
        );
        for i in 0..3 {
            assert!((pair[i] - half[i]).abs() < 1e-15, "{pair:?} {half:?}");
        }
    }
}
