//! The residual blocks of the reduced sliding model (`docs/reduced-sliding.md`, equations
//! (R1)–(R11)): the step data [`SlidingStepData`], the impulses, ECP offset and slip of a
//! candidate velocity ([`SlidingPoint`]), and the two blocks [`ReducedFriction`] and
//! [`ReducedEllipsoid`].

use nalgebra::Vector3;

use ecp_model::{JacobianBlocks, Params};

use crate::blocks::{ContactFrame, FrictionParams};

/// The per-step data of the reduced sliding model (docs/reduced-sliding.md, (R1)–(R3)): the
/// contact frame, friction, mass, CM height and the known momenta at the start of the step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlidingStepData {
    /// Contact frame `(n, t, o)` of the half-space (n into the body).
    pub frame: ContactFrame,
    /// Friction parameters μ, `e_t`, `e_o`, `e_r`.
    pub friction: FrictionParams,
    /// Mass m.
    pub mass: f64,
    /// Height H of the CM above the plane, `g(x^u)` (R3): `r·n = −H` at the end of the step.
    pub height: f64,
    /// Linear momentum plus applied impulse, `P = m v^u + h (m g + f_app(t_u))` (R1).
    pub momentum: Vector3<f64>,
    /// `J = I_w n` with `I_w = R(Q^u) I_body R(Q^u)ᵀ` (R2): the angular momentum per unit spin
    /// about n.
    pub spin_inertia: Vector3<f64>,
    /// Angular momentum plus applied angular impulse,
    /// `C = I_w ω^u + h τ_app(t_u) − h ω^u × (I_w ω^u)` (R2, the gyroscopic term explicit).
    pub angular: Vector3<f64>,
}

/// Components of the `sliding` data block of the reduced model: the fields of
/// [`SlidingStepData`] besides the frame and friction.
pub const SLIDING_DATA: [&str; 11] = [
    "mass",
    "height",
    "momentum.x",
    "momentum.y",
    "momentum.z",
    "spin_inertia.x",
    "spin_inertia.y",
    "spin_inertia.z",
    "angular.x",
    "angular.y",
    "angular.z",
];

/// The impulses, ECP offset and slip of a candidate `y = (v_t, v_o, ω_n)` (R4)–(R9), with
/// their derivatives with respect to `y` (entry `[k][j]` is `∂(·)_k/∂y_j`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlidingPoint {
    /// Normal impulse `p_n` (R4), independent of `y`.
    pub pn: f64,
    /// Friction impulses `(p_t, p_o, p_r)` (R5, R7).
    pub pf: [f64; 3],
    /// In-plane ECP offset from the CM's projection, `(ρ_t, ρ_o)` (R6).
    pub rho: [f64; 2],
    /// Slip at the ECP `(W_tᵀν, W_oᵀν, W_rᵀν)` (R8).
    pub slip: [f64; 3],
    /// `∂p_f/∂y`.
    pub d_pf: [[f64; 3]; 3],
    /// `∂ρ/∂y`.
    pub d_rho: [[f64; 2]; 3],
    /// `∂slip/∂y`.
    pub d_slip: [[f64; 3]; 3],
}

impl SlidingStepData {
    /// The step data with frame `frame` from the values of a `friction` data block and a
    /// `sliding` one ([`SLIDING_DATA`]).
    pub fn from_data(frame: ContactFrame, friction: &[f64], sliding: &[f64]) -> Self {
        let v = |o: usize| Vector3::new(sliding[o], sliding[o + 1], sliding[o + 2]);
        SlidingStepData {
            frame,
            friction: FrictionParams::from_slice(friction),
            mass: sliding[0],
            height: sliding[1],
            momentum: v(2),
            spin_inertia: v(5),
            angular: v(8),
        }
    }

    /// The values of the `sliding` data block ([`SLIDING_DATA`]).
    pub fn sliding_values(&self) -> [f64; 11] {
        let (p, j, c) = (self.momentum, self.spin_inertia, self.angular);
        [
            self.mass,
            self.height,
            p.x,
            p.y,
            p.z,
            j.x,
            j.y,
            j.z,
            c.x,
            c.y,
            c.z,
        ]
    }

    /// The derivatives of `p_n`, `p_f` and the slip at `y` (the point `p`) along a change `d` of
    /// the data (its frame is not used): the tangent of (R4)–(R8).
    fn point_tangent(
        &self,
        y: &[f64],
        p: &SlidingPoint,
        d: &SlidingStepData,
    ) -> (f64, [f64; 3], [f64; 3]) {
        let ContactFrame { n, t, o } = self.frame;
        let (vt, vo, wn) = (y[0], y[1], y[2]);
        let (pt, po) = (p.pf[0], p.pf[1]);
        let [rho_t, rho_o] = p.rho;
        let hh = self.height;
        let dpn = -n.dot(&d.momentum);
        let dpt = d.mass * vt - t.dot(&d.momentum);
        let dpo = d.mass * vo - o.dot(&d.momentum);
        let dl = d.spin_inertia * wn - d.angular;
        let drho_o = (t.dot(&dl) - d.height * po - hh * dpo - rho_o * dpn) / p.pn;
        let drho_t = (-(o.dot(&dl) + d.height * pt + hh * dpt) - rho_t * dpn) / p.pn;
        let dpr = n.dot(&dl) - drho_t * po - rho_t * dpo + drho_o * pt + rho_o * dpt;
        (dpn, [dpt, dpo, dpr], [-wn * drho_o, wn * drho_t, 0.0])
    }

    /// Data direction `k` of the reduced blocks' data inputs as a unit change: the four friction
    /// parameters, then the eleven components of [`SLIDING_DATA`].
    fn unit_direction(&self, k: usize) -> SlidingStepData {
        let mut friction = [0.0; 4];
        let mut sliding = [0.0; 11];
        if k < 4 {
            friction[k] = 1.0;
        } else {
            sliding[k - 4] = 1.0;
        }
        SlidingStepData::from_data(self.frame, &friction, &sliding)
    }

    /// The normal impulse fixed by the normal balance with `v·n = 0` (R4): `p_n = −n·P`.
    pub fn normal_impulse(&self) -> f64 {
        -self.frame.n.dot(&self.momentum)
    }

    /// Impulses, ECP offset and slip at `y = (v_t, v_o, ω_n)`, and their derivatives.
    /// Needs `p_n > 0` (the stepper refuses the step otherwise); with `p_n = 0` the offsets are
    /// not finite.
    pub fn point(&self, y: &[f64]) -> SlidingPoint {
        let ContactFrame { n, t, o } = self.frame;
        let (m, hh) = (self.mass, self.height);
        let pn = self.normal_impulse();
        let (vt, vo, wn) = (y[0], y[1], y[2]);
        // (R5) tangential balance.
        let pt = m * vt - t.dot(&self.momentum);
        let po = m * vo - o.dot(&self.momentum);
        // (R2) moment balance: L = ω_n J − C = r × f_c + n p_r.
        let l = self.spin_inertia * wn - self.angular;
        let (jt, jo, jn) = (
            t.dot(&self.spin_inertia),
            o.dot(&self.spin_inertia),
            n.dot(&self.spin_inertia),
        );
        // (R6) tilting-moment balances about t and o give the ECP offset.
        let rho_o = (t.dot(&l) - hh * po) / pn;
        let rho_t = -(o.dot(&l) + hh * pt) / pn;
        // (R7) spin balance about n gives the torsional impulse.
        let pr = n.dot(&l) - rho_t * po + rho_o * pt;
        let d_pt = [m, 0.0, 0.0];
        let d_po = [0.0, m, 0.0];
        let d_rho_o = [0.0, -hh * m / pn, jt / pn];
        let d_rho_t = [-hh * m / pn, 0.0, -jo / pn];
        let mut d_pr = [0.0; 3];
        for j in 0..3 {
            d_pr[j] = -(d_rho_t[j] * po + rho_t * d_po[j]) + d_rho_o[j] * pt + rho_o * d_pt[j];
        }
        d_pr[2] += jn;
        // (R8) slip of the body point at the ECP: v + ω × r = v + ω_n (ρ_t o − ρ_o t).
        let slip = [vt - wn * rho_o, vo + wn * rho_t, wn];
        let mut d_slip = [[0.0; 3]; 3];
        for j in 0..3 {
            d_slip[0][j] = -wn * d_rho_o[j];
            d_slip[1][j] = wn * d_rho_t[j];
        }
        d_slip[0][0] += 1.0;
        d_slip[0][2] -= rho_o;
        d_slip[1][1] += 1.0;
        d_slip[1][2] += rho_t;
        d_slip[2][2] = 1.0;
        let mut d_rho = [[0.0; 2]; 3];
        for j in 0..3 {
            d_rho[j] = [d_rho_t[j], d_rho_o[j]];
        }
        SlidingPoint {
            pn,
            pf: [pt, po, pr],
            rho: [rho_t, rho_o],
            slip,
            d_pf: [d_pt, d_po, d_pr],
            d_rho,
            d_slip,
        }
    }

    fn friction_scales(&self) -> [f64; 3] {
        let f = &self.friction;
        [
            f.e_t * f.e_t * f.mu,
            f.e_o * f.e_o * f.mu,
            f.e_r * f.e_r * f.mu,
        ]
    }

    /// Row scales `w_k = 1/(e_k² μ p_n)` of (R10) (1 when `μ p_n = 0`): the rows become
    /// `s_k + p_k σ/(e_k² μ p_n)`, in slip units, with the same solutions.
    pub fn row_scales(&self) -> [f64; 3] {
        let pn = self.normal_impulse();
        self.friction_scales().map(|c| {
            let w = 1.0 / (c * pn);
            if w.is_finite() && w > 0.0 { w } else { 1.0 }
        })
    }
}

/// Maximum-dissipation rows of the reduced model (R10), paired with `y = (v_t, v_o, ω_n)`:
/// `0 = w_k (e_k² μ p_n s_k(y) + p_k(y) σ)` for `k = t, o, r`, with the impulses and the slip at
/// the ECP eliminated through (R4)–(R8). Reads `y` (3), `σ` (1) and the `friction` (4) and
/// `sliding` ([`SLIDING_DATA`]) data.
///
/// The row scale `w_k = 1/(e_k² μ p_n)` ([`SlidingStepData::row_scales`]) does not change the
/// solutions; it puts the rows in slip units, so that a natural residual r bounds the slip error
/// of a sticking step by r (`docs/decisions.md#reduced-model-friction-rows-in-slip-units`).
#[derive(Clone, Debug)]
pub struct ReducedFriction {
    /// Contact frame `(n, t, o)` of the half-space.
    pub frame: ContactFrame,
}

impl ReducedFriction {
    /// Index of the `friction` data input (the `sliding` one follows).
    pub const FRICTION: usize = 2;
}

impl ecp_model::ResidualBlock for ReducedFriction {
    fn name(&self) -> &str {
        "reduced_friction"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 1, 4, 11]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let k = Self::FRICTION;
        let data = SlidingStepData::from_data(self.frame, x.block(k), x.block(k + 1));
        let p = data.point(x.block(0));
        let sigma = x.block(1)[0];
        let s = data.friction_scales();
        let w = data.row_scales();
        for k in 0..3 {
            out[k] = w[k] * (s[k] * p.pn * p.slip[k] + p.pf[k] * sigma);
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let kf = Self::FRICTION;
        let data = SlidingStepData::from_data(self.frame, x.block(kf), x.block(kf + 1));
        let y = x.block(0);
        let p = data.point(y);
        let sigma = x.block(1)[0];
        let s = data.friction_scales();
        let w = data.row_scales();
        for k in 0..3 {
            for j in 0..3 {
                jac.set(
                    0,
                    k,
                    j,
                    w[k] * (s[k] * p.pn * p.d_slip[k][j] + p.d_pf[k][j] * sigma),
                );
            }
            jac.set(1, k, 0, w[k] * p.pf[k]);
        }
        // Data: r_k = w_k (c_k p_n s_k + p_k σ), c_k = e_k² μ, w_k = 1/(c_k p_n) (the constant 1
        // where that is not a positive number), along each unit change of the data.
        let f = data.friction;
        let e = [f.e_t, f.e_o, f.e_r];
        for dir in 0..15 {
            let (input, col) = if dir < 4 {
                (kf, dir)
            } else {
                (kf + 1, dir - 4)
            };
            if !jac.wants(input) {
                continue;
            }
            let d = data.unit_direction(dir);
            let de = [d.friction.e_t, d.friction.e_o, d.friction.e_r];
            let (dpn, dpf, dslip) = data.point_tangent(y, &p, &d);
            for k in 0..3 {
                let ds = 2.0 * e[k] * de[k] * f.mu + e[k] * e[k] * d.friction.mu;
                let raw = 1.0 / (s[k] * p.pn);
                let dw = if raw.is_finite() && raw > 0.0 {
                    -w[k] * w[k] * (ds * p.pn + s[k] * dpn)
                } else {
                    0.0
                };
                let inner = s[k] * p.pn * p.slip[k] + p.pf[k] * sigma;
                let d_inner = ds * p.pn * p.slip[k]
                    + s[k] * dpn * p.slip[k]
                    + s[k] * p.pn * dslip[k]
                    + dpf[k] * sigma;
                jac.set(input, k, col, dw * inner + w[k] * d_inner);
            }
        }
    }
}

/// Friction ellipsoid of the reduced model in its cone form (R11), paired with σ:
/// `0 ≤ μ p_n − ‖E⁻¹ p_f(y)‖ ⊥ σ ≥ 0`, `E = diag(e_t, e_o, e_r)` — the row of
/// [`crate::blocks::FrictionEllipsoid`] with the impulses eliminated. Reads `y` (3) and the
/// `friction` (4) and `sliding` ([`SLIDING_DATA`]) data.
#[derive(Clone, Debug)]
pub struct ReducedEllipsoid {
    /// Contact frame `(n, t, o)` of the half-space.
    pub frame: ContactFrame,
}

impl ReducedEllipsoid {
    /// Index of the `friction` data input (the `sliding` one follows).
    pub const FRICTION: usize = 1;
}

impl ecp_model::ResidualBlock for ReducedEllipsoid {
    fn name(&self) -> &str {
        "reduced_ellipsoid"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 4, 11]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let k = Self::FRICTION;
        let data = SlidingStepData::from_data(self.frame, x.block(k), x.block(k + 1));
        let p = data.point(x.block(0));
        out[0] = data.friction.mu * p.pn - scaled_norm(&data.friction, &p.pf).0;
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let kf = Self::FRICTION;
        let data = SlidingStepData::from_data(self.frame, x.block(kf), x.block(kf + 1));
        let y = x.block(0);
        let p = data.point(y);
        let (norm, g) = scaled_norm(&data.friction, &p.pf);
        // At p_f = 0 the norm has the unit ball as generalised gradient; 0 is an element of it
        // (as in FrictionEllipsoid).
        if norm > 0.0 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|k| g[k] * p.d_pf[k][j]).sum();
                jac.set(0, 0, j, -d / norm);
            }
        }
        let f = data.friction;
        let e = [f.e_t, f.e_o, f.e_r];
        for dir in 0..15 {
            let (input, col) = if dir < 4 {
                (kf, dir)
            } else {
                (kf + 1, dir - 4)
            };
            if !jac.wants(input) {
                continue;
            }
            let d = data.unit_direction(dir);
            let (dpn, dpf, _) = data.point_tangent(y, &p, &d);
            let de = [d.friction.e_t, d.friction.e_o, d.friction.e_r];
            // ‖u‖ with u_k = p_k/e_k: d‖u‖ = Σ u_k du_k / ‖u‖ (0 at the kink p_f = 0).
            let dnorm = if norm > 0.0 {
                (0..3)
                    .map(|k| {
                        let u = p.pf[k] / e[k];
                        u * (dpf[k] / e[k] - p.pf[k] * de[k] / (e[k] * e[k]))
                    })
                    .sum::<f64>()
                    / norm
            } else {
                0.0
            };
            jac.set(input, 0, col, d.friction.mu * p.pn + f.mu * dpn - dnorm);
        }
    }
}

/// `‖E⁻¹ p‖` and `E⁻² p` (its gradient times the norm).
fn scaled_norm(f: &FrictionParams, p: &[f64; 3]) -> (f64, [f64; 3]) {
    let e = [f.e_t, f.e_o, f.e_r];
    let u = [p[0] / e[0], p[1] / e[1], p[2] / e[2]];
    let norm = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    (norm, [u[0] / e[0], u[1] / e[1], u[2] / e[2]])
}
