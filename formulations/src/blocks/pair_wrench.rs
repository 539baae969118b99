//! The contact impulse of a contact between two bodies in their Newton–Euler rows (paper (1),
//! (2), (16), (18); `docs/model.md#contact-between-two-bodies`): equal and opposite,
//! `+W(F, a1) p` on F and `−W(G, a2) p` on G, each about its own CM. These are terms
//! (`ecp_model::Problem::add_term`) added to the rows of [`super::NewtonEuler`] of each DYNAMIC
//! body of the pair; a fixed or kinematic body has no Newton–Euler rows and gets none.

use nalgebra::{Matrix3, Vector3};

use ecp_model::{JacobianBlocks, Params, ResidualBlock};

use super::common::{v3, v4};
use super::pair_frame::{PairFrame, SupportNormal};
use crate::rotation::skew;

/// Which body of the pair a [`PairWrench`] acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PairSide {
    /// F, the body that carries `a1` and whose faces have the multipliers `l`: `+W(F, a1) p`.
    F,
    /// G, whose faces define the normal: `−W(G, a2) p`.
    G,
}

/// The contact impulse of one pair contact on one of its bodies: `±[f; r × f + n p_r]` with
/// `f = n p_n + t p_t + o p_o` (`W_n = [n; r × n]`, `W_t = [t; r × t]`, `W_o = [o; r × o]`,
/// `W_r = [0; n]`, paper (2)), `(n, t, o)` the [`PairFrame`] of the pair, `r = a1 − x_F` (+, on
/// F) or `r = a2 − x_G` (−, on G). Impulse units, like the Newton–Euler rows it adds to.
///
/// Reads, on F: `a1` (3), F's `q` (7), `μ` (m_G), G's `q` (7), `p_n` (1), `p_f` (3) and the
/// reference `axis` data (3); on G: `a2` (3), `μ` (m_G), G's `q` (7), `p_n`, `p_f`, `axis`
/// (G's `q` gives both its lever and the normal, [`PairWrench::inputs`]).
#[derive(Clone, Debug)]
pub struct PairWrench {
    /// The body whose rows this term adds to.
    pub side: PairSide,
    /// G's outward unit face normals `m̂_j` (body frame).
    pub g_normals: Vec<Vector3<f64>>,
    sizes: Vec<usize>,
}

/// Input indices of a [`PairWrench`] (they differ by side).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairWrenchInputs {
    /// The ECP on this body (`a1` on F, `a2` on G).
    pub point: usize,
    /// This body's `q` (for its CM `x`).
    pub q_body: usize,
    /// `μ`.
    pub mu: usize,
    /// G's `q` (for the normal).
    pub q_g: usize,
    /// `p_n`.
    pub pn: usize,
    /// `p_f`.
    pub pf: usize,
    /// The reference axis (data).
    pub axis: usize,
}

impl PairWrench {
    /// The term on `side` for G's face normals.
    pub fn new(side: PairSide, g_normals: Vec<Vector3<f64>>) -> Self {
        let m = g_normals.len();
        let sizes = match side {
            PairSide::F => vec![3, 7, m, 7, 1, 3, 3],
            PairSide::G => vec![3, m, 7, 1, 3, 3],
        };
        PairWrench {
            side,
            g_normals,
            sizes,
        }
    }

    /// Where each input is.
    pub fn inputs(&self) -> PairWrenchInputs {
        match self.side {
            PairSide::F => PairWrenchInputs {
                point: 0,
                q_body: 1,
                mu: 2,
                q_g: 3,
                pn: 4,
                pf: 5,
                axis: 6,
            },
            PairSide::G => PairWrenchInputs {
                point: 0,
                q_body: 2,
                mu: 1,
                q_g: 2,
                pn: 3,
                pf: 4,
                axis: 5,
            },
        }
    }

    fn sign(&self) -> f64 {
        match self.side {
            PairSide::F => 1.0,
            PairSide::G => -1.0,
        }
    }

    fn parts(&self, x: Params<'_>) -> Parts {
        let k = self.inputs();
        let nu = SupportNormal::new(&self.g_normals, x.block(k.mu), &v4(x.block(k.q_g), 3));
        let frame = PairFrame::new(&nu.value, &v3(x.block(k.axis), 0));
        let pn = x.block(k.pn)[0];
        let pf = v3(x.block(k.pf), 0);
        let force = frame.n * pn + frame.t * pf[0] + frame.o * pf[1];
        let r = v3(x.block(k.point), 0) - v3(x.block(k.q_body), 0);
        Parts {
            nu,
            frame,
            pn,
            pf,
            force,
            r,
        }
    }
}

struct Parts {
    nu: SupportNormal,
    frame: PairFrame,
    pn: f64,
    pf: Vector3<f64>,
    force: Vector3<f64>,
    r: Vector3<f64>,
}

impl ResidualBlock for PairWrench {
    fn name(&self) -> &str {
        match self.side {
            PairSide::F => "pair_wrench_f",
            PairSide::G => "pair_wrench_g",
        }
    }
    fn num_residuals(&self) -> usize {
        6
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let p = self.parts(x);
        let torque = p.r.cross(&p.force) + p.frame.n * p.pf[2];
        let s = self.sign();
        for i in 0..3 {
            out[i] = s * p.force[i];
            out[3 + i] = s * torque[i];
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let k = self.inputs();
        let p = self.parts(x);
        let s = self.sign();
        let fr = &p.frame;
        // τ = r × f = −[f]× r: ∂τ/∂point = −[f]×, ∂τ/∂x = [f]×.
        let fx = skew(&p.force) * s;
        for i in 0..3 {
            for j in 0..3 {
                jac.add(k.point, 3 + i, j, -fx[(i, j)]);
                jac.add(k.q_body, 3 + i, j, fx[(i, j)]);
            }
        }
        let cols = [
            (k.pn, 0, fr.n, p.r.cross(&fr.n)),
            (k.pf, 0, fr.t, p.r.cross(&fr.t)),
            (k.pf, 1, fr.o, p.r.cross(&fr.o)),
            (k.pf, 2, Vector3::zeros(), fr.n),
        ];
        for (input, j, lin, ang) in cols {
            for i in 0..3 {
                jac.set(input, i, j, s * lin[i]);
                jac.set(input, 3 + i, j, s * ang[i]);
            }
        }
        // Through the frame: ∂f/∂ν_G = p_n ∂n + p_t ∂t + p_o ∂o, ∂τ/∂ν_G = [r]× ∂f/∂ν_G + p_r ∂n.
        let rx = skew(&p.r);
        let df: Matrix3<f64> = fr.dn * p.pn + fr.dt * p.pf[0] + fr.d_o * p.pf[1];
        let dtau = rx * df + fr.dn * p.pf[2];
        let rows: Vec<(usize, Vector3<f64>)> = (0..6)
            .map(|i| {
                let row = if i < 3 { df.row(i) } else { dtau.row(i - 3) };
                (i, row.transpose() * s)
            })
            .collect();
        p.nu.add_chain(&self.g_normals, &rows, k.mu, k.q_g, jac);
        if jac.wants(k.axis) {
            let df_axis = fr.dt_axis * p.pf[0] + fr.do_axis * p.pf[1];
            let dtau_axis = rx * df_axis;
            for i in 0..3 {
                for j in 0..3 {
                    jac.set(k.axis, i, j, s * df_axis[(i, j)]);
                    jac.set(k.axis, 3 + i, j, s * dtau_axis[(i, j)]);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::super::common::{ContactFrame, flat};
    use super::super::newton_euler::NewtonEuler;
    use super::*;

    fn eval(b: &dyn ResidualBlock, params: &[&[f64]]) -> Vec<f64> {
        let (z, ranges) = flat(params);
        let mut out = vec![0.0; b.num_residuals()];
        b.evaluate(Params::new(&z, &[], &ranges), &mut out);
        out
    }

    fn faces() -> Vec<Vector3<f64>> {
        vec![Vector3::z(), Vector3::new(0.0, 0.6, 0.8), -Vector3::x()]
    }

    #[test]
    fn equal_and_opposite_impulses() {
        let q_f = [0.3, -0.1, 0.6, 0.9, 0.1, 0.2, -0.3];
        let q_g = [0.1, 0.2, 0.0, 0.8, -0.3, 0.1, 0.2];
        let a = [0.25, 0.05, 0.3];
        let (mu, pn, pf, axis) = ([0.6, 0.4, 0.0], [2.0], [0.3, -0.2, 0.01], [1.0, 0.0, 0.0]);
        let on_f = PairWrench::new(PairSide::F, faces());
        let on_g = PairWrench::new(PairSide::G, faces());
        let wf = eval(&on_f, &[&a, &q_f, &mu, &q_g, &pn, &pf, &axis]);
        let wg = eval(&on_g, &[&a, &mu, &q_g, &pn, &pf, &axis]);
        // Forces cancel exactly; the angular impulses about the world origin cancel too.
        let (x_f, x_g) = (
            Vector3::new(q_f[0], q_f[1], q_f[2]),
            Vector3::new(q_g[0], q_g[1], q_g[2]),
        );
        let (ff, fg) = (
            Vector3::new(wf[0], wf[1], wf[2]),
            Vector3::new(wg[0], wg[1], wg[2]),
        );
        assert_eq!(ff, -fg);
        let lf = Vector3::new(wf[3], wf[4], wf[5]) + x_f.cross(&ff);
        let lg = Vector3::new(wg[3], wg[4], wg[5]) + x_g.cross(&fg);
        assert!((lf + lg).norm() < 1e-14, "{lf} {lg}");
        // The normal pushes F away from G along ν_G / |ν_G|, with p_n.
        let frame = PairFrame::new(
            &SupportNormal::new(
                &faces(),
                &mu,
                &nalgebra::Vector4::new(q_g[3], q_g[4], q_g[5], q_g[6]),
            )
            .value,
            &Vector3::x(),
        );
        assert!((ff.dot(&frame.n) - pn[0]).abs() < 1e-14);
        for (b, params) in [
            (&on_f, vec![&a[..], &q_f, &mu, &q_g, &pn, &pf, &axis]),
            (&on_g, vec![&a[..], &mu, &q_g, &pn, &pf, &axis]),
        ] {
            let report = check_residual_block(b, &params, &CheckOptions::default()).expect("sizes");
            assert!(report.ok(), "{report}");
        }
    }

    #[test]
    fn matches_the_newton_euler_contact_impulse_on_a_half_space() {
        // G = the ground as a one-face body, μ = 1, axis e_x: the frame (e_z, e_x, e_y) of the
        // half-space and the same impulse as NewtonEuler's contact part.
        let nu = [0.3, -0.5, 0.2, 1.5, -0.7, 2.0];
        let q = [0.1, 0.2, 0.6, 0.9, 0.2, -0.1, 0.3];
        let (a1, pn, pf) = ([0.05, 0.1, 0.0], [1.2], [0.3, -0.2, 0.01]);
        let q_g = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let term = eval(
            &PairWrench::new(PairSide::F, vec![Vector3::z()]),
            &[&a1, &q, &[1.0], &q_g, &pn, &pf, &[1.0, 0.0, 0.0]],
        );
        let frame = ContactFrame {
            n: Vector3::z(),
            t: Vector3::x(),
            o: Vector3::y(),
        };
        let body: [&[f64]; 6] = [
            &[2.0],
            &[0.4, 0.5, 0.6, 0.0, 0.0, 0.0],
            &[
                0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            ],
            &[0.0; 6],
            &[0.0; 3],
            &[0.01],
        ];
        let mut with: Vec<&[f64]> = vec![&nu, &q, &a1, &pn, &pf];
        with.extend(body);
        let mut without: Vec<&[f64]> = vec![&nu, &q];
        without.extend(body);
        let a = eval(&NewtonEuler::new(vec![frame]), &with);
        let b = eval(&NewtonEuler::new(vec![]), &without);
        for i in 0..6 {
            assert!(
                (a[i] - b[i] - term[i]).abs() < 1e-14,
                "row {i}: {} vs {}",
                a[i] - b[i],
                term[i]
            );
        }
    }
}
