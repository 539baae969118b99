//! The discrete Newton–Euler equations of a body (`docs/model.md#newton-euler`) and the body data
//! they are computed from.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector4, Vector6};

use ecp_model::{Column, JacobianBlocks, Params, ResidualBlock};

use super::common::{ContactFrame, inertia_direction, inertia_from_entries, mass_matrix, v3, v4};
use super::data::start;
use crate::rotation::{
    rotation_matrix, rotation_matrix_and_derivatives, rotation_matrix_derivatives, skew,
};

/// Sizes of the body data inputs every Newton–Euler block reads, in order: `mass` (1),
/// `inertia` (6), `start` (13), `wrench` (6), `gravity` (3), `h` (1) ([`super::data`]).
pub const BODY_DATA_SIZES: [usize; 6] = [1, 6, 13, 6, 3, 1];

/// Offsets of the body data inputs from the first one ([`BODY_DATA_SIZES`]).
pub mod body_input {
    /// `mass`.
    pub const MASS: usize = 0;
    /// `inertia`.
    pub const INERTIA: usize = 1;
    /// `start`.
    pub const START: usize = 2;
    /// `wrench`.
    pub const WRENCH: usize = 3;
    /// `gravity`.
    pub const GRAVITY: usize = 4;
    /// `h`.
    pub const H: usize = 5;
}

/// What a body's Newton–Euler rows are computed from (`docs/model.md#newton-euler`): its mass
/// properties, its state at the start of the step, the applied load, gravity and the step
/// length, read from the body data inputs ([`BODY_DATA_SIZES`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyStepData {
    /// Mass m.
    pub mass: f64,
    /// Body-frame inertia about the CM (symmetric; parametrised by its six upper entries).
    pub inertia: Matrix3<f64>,
    /// Orientation at the start of the step `Q^u` (the body-frame angular velocity the step
    /// starts from is `R(Q^u)ᵀ ω^u`).
    pub q_start: Vector4<f64>,
    /// Generalised velocity at the start of the step `ν^u = (v^u, ω^u)`.
    pub nu_start: Vector6<f64>,
    /// Applied wrench at the CM, world frame, `(force, torque)`, without gravity.
    pub wrench: Vector6<f64>,
    /// Gravity acceleration.
    pub gravity: Vector3<f64>,
    /// Step length h.
    pub h: f64,
}

impl BodyStepData {
    /// The body data read from the six inputs starting at `k0` ([`BODY_DATA_SIZES`]).
    /// Inlined, and the inputs read as arrays of their sizes: called at every point `F` is
    /// evaluated at, where a call, the copy of its result and a check per entry read cost
    /// more than the reads themselves.
    #[inline(always)]
    pub fn from_inputs(x: Params<'_>, k0: usize) -> Self {
        let s: &[f64; 13] = x.array(k0 + body_input::START);
        let w: &[f64; 6] = x.array(k0 + body_input::WRENCH);
        let v = start::V;
        BodyStepData {
            mass: x.array::<1>(k0 + body_input::MASS)[0],
            inertia: inertia_from_entries(x.array::<6>(k0 + body_input::INERTIA)),
            q_start: v4(s, start::Q),
            nu_start: Vector6::new(s[v], s[v + 1], s[v + 2], s[v + 3], s[v + 4], s[v + 5]),
            wrench: Vector6::new(w[0], w[1], w[2], w[3], w[4], w[5]),
            gravity: v3(x.array::<3>(k0 + body_input::GRAVITY), 0),
            h: x.array::<1>(k0 + body_input::H)[0],
        }
    }

    /// The body data as stored in a prepared step problem's data blocks `d`, with the scene's
    /// `gravity` and `h`; also the CM position at the start of the step (the structural views
    /// of the hull and bodies formulations read both).
    pub fn from_mcp(
        mcp: &ecp_model::BlockMcp,
        d: &super::data::BodyDataIds,
        gravity: Vector3<f64>,
        h: f64,
    ) -> (Self, Vector3<f64>) {
        let s = mcp.data(d.start);
        let data = BodyStepData {
            mass: mcp.data(d.mass)[0],
            inertia: inertia_from_entries(mcp.data(d.inertia)),
            q_start: v4(s, start::Q),
            nu_start: Vector6::from_column_slice(&s[start::V..start::V + 6]),
            wrench: Vector6::from_column_slice(mcp.data(d.wrench)),
            gravity,
            h,
        };
        (data, v3(s, start::X))
    }

    /// The generalised mass matrix `diag(m I, R I_body Rᵀ)` at `Q^u` (the mass matrix of the
    /// start of the step; the rows of [`NewtonEuler`] use the one of the end).
    pub fn mass_matrix(&self) -> Matrix6<f64> {
        mass_matrix(self.mass, &self.inertia, &self.q_start)
    }

    /// The applied impulse `p_app = h [m g + f; τ]` (gravity and the load at `t_u`). The
    /// gyroscopic impulse is not in it: [`NewtonEuler`] writes it at the end of the step, in its
    /// rows.
    pub fn impulse(&self) -> Vector6<f64> {
        let force = self.gravity * self.mass + v3(self.wrench.as_slice(), 0);
        let torque = v3(self.wrench.as_slice(), 3);
        let mut p = Vector6::zeros();
        for i in 0..3 {
            p[i] = self.h * force[i];
            p[3 + i] = self.h * torque[i];
        }
        p
    }

    /// The free-motion velocity (the step's Newton–Euler rows without contact impulses) with the
    /// end-of-step orientation `R1` and the gyroscopic impulse at the trial angular velocity
    /// `w_trial` held fixed: `v^u + p_lin/m` and
    /// `I_w1⁻¹ (R1 I_b R0ᵀ ω^u + p_ang − h ω̃ × (I_w1 ω̃))`, `I_w1 = R1 I_b R1ᵀ`
    /// ([`BodyStepData::inertial_rows`] with the gyroscopic term held at `ω̃`): what a
    /// structure-exploiting backend reads ([`ecp_model::BodyDynamics`]).
    pub fn free_velocity(&self, r1: &Matrix3<f64>, w_trial: &Vector3<f64>) -> Vector6<f64> {
        self.free_velocity_in(r1, &(r1 * self.inertia * r1.transpose()), w_trial)
    }

    /// [`BodyStepData::free_velocity`] with `I_w1 = R1 I_b R1ᵀ` computed by the caller
    /// ([`BodyStepData::dynamics`] needs it too).
    fn free_velocity_in(
        &self,
        r1: &Matrix3<f64>,
        iw1: &Matrix3<f64>,
        w_trial: &Vector3<f64>,
    ) -> Vector6<f64> {
        let impulse = self.impulse();
        let (v0, w0) = (
            self.nu_start.fixed_rows::<3>(0).into_owned(),
            self.nu_start.fixed_rows::<3>(3).into_owned(),
        );
        let r0 = rotation_matrix(&self.q_start);
        let lin = v0 + impulse.fixed_rows::<3>(0) / self.mass;
        let rhs = r1 * (self.inertia * (r0.transpose() * w0)) + impulse.fixed_rows::<3>(3)
            - w_trial.cross(&(iw1 * w_trial)) * self.h;
        // The inertia is validated symmetric positive definite when the scene is built.
        let ang = match iw1.cholesky() {
            Some(ch) => ch.solve(&rhs),
            None => w0,
        };
        Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
    }

    /// The mass matrix `diag(m I₃, R1 I_b R1ᵀ)` at the end-of-step orientation `R1` and the
    /// free-motion velocity ([`BodyStepData::free_velocity`]): the body as a
    /// structure-exploiting backend sees it.
    pub fn dynamics(&self, r1: &Matrix3<f64>, w_trial: &Vector3<f64>) -> ecp_model::BodyDynamics {
        // `I_w1` once for the mass matrix and the free velocity, written straight into rows.
        let iw1 = r1 * self.inertia * r1.transpose();
        let mut mass = [[0.0; 6]; 6];
        for i in 0..3 {
            mass[i][i] = self.mass;
            for j in 0..3 {
                mass[3 + i][3 + j] = iw1[(i, j)];
            }
        }
        let f = self.free_velocity_in(r1, &iw1, w_trial);
        ecp_model::BodyDynamics {
            mass,
            free_velocity: [f[0], f[1], f[2], f[3], f[4], f[5]],
        }
    }

    /// The inertial part of the rows of [`NewtonEuler`] at the end-of-step velocity
    /// `ν = (v, ω)` and orientation `Q` (`R1 = R(Q)`, `R0 = R(Q^u)`, `I_w1 = R1 I_body R1ᵀ`):
    /// `[−m (v − v^u); −I_w1 ω + R1 I_body R0ᵀ ω^u − h ω × (I_w1 ω)]`, to which the applied
    /// impulse ([`BodyStepData::impulse`]) and the contact impulses are added. See
    /// [`NewtonEuler`] and `docs/energy.md`.
    pub fn inertial_rows(&self, nu: &Vector6<f64>, q: &Vector4<f64>) -> Vector6<f64> {
        let r0 = rotation_matrix(&self.q_start);
        let r1 = rotation_matrix(q);
        let (v0, w0) = (
            v3(self.nu_start.as_slice(), 0),
            v3(self.nu_start.as_slice(), 3),
        );
        let (v1, w1) = (v3(nu.as_slice(), 0), v3(nu.as_slice(), 3));
        let lin = -(v1 - v0) * self.mass;
        let l1 = r1 * (self.inertia * (r1.transpose() * w1));
        let carried = r1 * (self.inertia * (r0.transpose() * w0));
        let ang = -l1 + carried - w1.cross(&l1) * self.h;
        Vector6::new(lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
    }

    /// The Jacobian of the angular rows of [`BodyStepData::inertial_rows`] (the translational
    /// ones are `−m (v − v^u)`): with `I_w1 = R1 I_body R1ᵀ` and `L = I_w1 ω`,
    /// `∂/∂ω = −I_w1 − h ([ω]× I_w1 − [L]×)` and, column `k` of `∂/∂Q`,
    /// `−D_k ω + ∂R1_k I_body R0ᵀ ω^u − h ω × (D_k ω)`, with
    /// `D_k = ∂R1_k I_body R1ᵀ + R1 I_body ∂R1_kᵀ`.
    pub fn inertial_jacobian(
        &self,
        nu: &Vector6<f64>,
        q: &Vector4<f64>,
    ) -> (Matrix3<f64>, [Vector3<f64>; 4]) {
        let w1 = v3(nu.as_slice(), 3);
        let r0 = rotation_matrix(&self.q_start);
        let (r1, dr) = rotation_matrix_and_derivatives(q);
        // `R1 I_body` and `I_body R0ᵀ ω^u` once, not per `k`: the same products, so the same
        // numbers (`(R1 I_body) X` is how `R1 * I_body * X` associates).
        let r1_inertia = r1 * self.inertia;
        let iw1 = r1_inertia * r1.transpose();
        let l1 = iw1 * w1;
        let dw = -iw1 - (skew(&w1) * iw1 - skew(&l1)) * self.h;
        let omega0 = r0.transpose() * v3(self.nu_start.as_slice(), 3);
        let inertia_omega0 = self.inertia * omega0;
        let dq = dr.map(|d| {
            let dl = (d * self.inertia * r1.transpose() + r1_inertia * d.transpose()) * w1;
            -dl + d * inertia_omega0 - w1.cross(&dl) * self.h
        });
        (dw, dq)
    }

    /// Writes the derivatives of `inertial_rows + impulse` with respect to the body data inputs
    /// starting at `k0`, those `jac` wants.
    pub fn data_jacobian(
        &self,
        nu: &Vector6<f64>,
        q: &Vector4<f64>,
        k0: usize,
        jac: &mut JacobianBlocks<'_>,
    ) {
        use body_input::*;
        // The Newton iteration wants no data derivative: skip the rotations below.
        if ![MASS, INERTIA, START, WRENCH, GRAVITY, H]
            .iter()
            .any(|&k| jac.wants(k0 + k))
        {
            return;
        }
        let dv = v3(nu.as_slice(), 0) - v3(self.nu_start.as_slice(), 0);
        let w1 = v3(nu.as_slice(), 3);
        let w0 = v3(self.nu_start.as_slice(), 3);
        let h = self.h;
        let r0 = rotation_matrix(&self.q_start);
        let r1 = rotation_matrix(q);
        if jac.wants(k0 + MASS) {
            // −(v − v^u) + h g.
            let dm = -dv + self.gravity * h;
            for i in 0..3 {
                jac.set(k0 + MASS, i, 0, dm[i]);
            }
        }
        if jac.wants(k0 + INERTIA) {
            // E_k = ∂I_b/∂θ_k: the rotational rows
            // −R1 I_b R1ᵀ ω + R1 I_b R0ᵀ ω^u − h ω × (R1 I_b R1ᵀ ω) are linear in I_b.
            for k in 0..6 {
                let e = inertia_direction(k);
                let dl = r1 * (e * (r1.transpose() * w1));
                let col = -dl + r1 * (e * (r0.transpose() * w0)) - w1.cross(&dl) * h;
                for i in 0..3 {
                    jac.set(k0 + INERTIA, 3 + i, k, col[i]);
                }
            }
        }
        if jac.wants(k0 + START) {
            // Start quaternion: only R0 = R(Q^u) in R1 I_b R0ᵀ ω^u.
            let dr = rotation_matrix_derivatives(&self.q_start);
            for (k, d) in dr.iter().enumerate() {
                let col = r1 * (self.inertia * (d.transpose() * w0));
                for i in 0..3 {
                    jac.set(k0 + START, 3 + i, start::Q + k, col[i]);
                }
            }
            // ∂/∂v^u = m I; ∂/∂ω^u = R1 I_b R0ᵀ. The start position does not enter.
            let carry = r1 * self.inertia * r0.transpose();
            for i in 0..3 {
                jac.set(k0 + START, i, start::V + i, self.mass);
                for j in 0..3 {
                    jac.set(k0 + START, 3 + i, start::W + j, carry[(i, j)]);
                }
            }
        }
        if jac.wants(k0 + WRENCH) {
            jac.add_diagonal(k0 + WRENCH, 0, 0, 6, h);
        }
        if jac.wants(k0 + GRAVITY) {
            jac.add_diagonal(k0 + GRAVITY, 0, 0, 3, h * self.mass);
        }
        if jac.wants(k0 + H) {
            // ∂/∂h: the applied impulse over h, and the gyroscopic term −ω × (I_w1 ω).
            let l1 = r1 * (self.inertia * (r1.transpose() * w1));
            let force = self.gravity * self.mass + v3(self.wrench.as_slice(), 0);
            let ang = v3(self.wrench.as_slice(), 3) - w1.cross(&l1);
            for i in 0..3 {
                jac.set(k0 + H, i, 0, force[i]);
                jac.set(k0 + H, 3 + i, 0, ang[i]);
            }
        }
    }

    /// Writes the Jacobian of `inertial_rows + impulse` with respect to `ν` (input 0) and `q`
    /// (input 1).
    fn variable_jacobian(&self, nu: &Vector6<f64>, q: &Vector4<f64>, jac: &mut JacobianBlocks<'_>) {
        let (dw, dq) = self.inertial_jacobian(nu, q);
        // The columns located once ([`JacobianBlocks::columns`]).
        let cv: [Column; 6] = jac.columns(0, 0);
        for i in 0..3 {
            jac.put(cv[i], i, -self.mass);
            for j in 0..3 {
                jac.put(cv[3 + j], 3 + i, dw[(i, j)]);
            }
        }
        let cq: [Column; 4] = jac.columns(1, 3);
        for (col, c) in dq.iter().zip(cq) {
            for i in 0..3 {
                jac.put(c, 3 + i, col[i]);
            }
        }
    }
}

/// Discrete Newton–Euler equations (the paper's eq. (discrete_NE)),
/// `0 = −M^{u+1}(ν^{u+1} − ν^u) + P_c + p_app + p_vp`, with the contact impulse
/// `P_c = Σ_c (W_n p_n + W_t p_t + W_o p_o + W_r p_r)`, `W_n = [n; r × n]`, `r = a1 − x^{u+1}`
/// per contact.
///
/// The mass matrix is that of the **end** of the step, as the paper writes it (`M^{u+1}`), and
/// the gyroscopic impulse is taken at the end-of-step velocity. The rotational rows are the
/// body-frame balance at the end of the step, with `Ω = Rᵀω`, `R0 = R(Q^u)`, `R1 = R(Q^{u+1})`,
/// `I_b` the body-frame inertia: `I_b (Ω^{u+1} − Ω^u) + h Ω^{u+1} × I_b Ω^{u+1} = R1ᵀ τ`, written
/// in the world frame (multiplied by `R1`):
/// `0 = −R1 I_b R1ᵀ ω + R1 I_b R0ᵀ ω^u − h ω × (R1 I_b R1ᵀ ω) + τ`
/// (τ: applied and contact angular impulses). Dotted with `Ω^{u+1}`, the gyroscopic term
/// vanishes and, without applied or contact impulses,
/// `½ Ω^{u+1}·I_b Ω^{u+1} − ½ Ω^u·I_b Ω^u = −½ ΔΩ·I_b ΔΩ ≤ 0`: the step cannot feed kinetic
/// energy in (the explicit term `−h ω^u × (I_w ω^u)` with `M(q^u)` could, by up to a percent
/// a second for a tumbling body; `docs/energy.md`). The translational rows
/// `0 = −m (v − v^u) + h (m g + f) + Σ f_c` with `x^{u+1} = x^u + h v` change kinetic plus
/// potential energy by `−½ m |Δv|²`. The block reads `Q^{u+1}` (the q block) through `R1`,
/// and `R(Q)` is a rotation for every `Q ≠ 0`, so the renormalised stored quaternion has the
/// same `R1`.
///
/// Reads `ν` (6), `q` (7), per contact `a1` (3), `p_n` (1), `p_f = (p_t, p_o, p_r)` (3), and then
/// the body data ([`BODY_DATA_SIZES`], from input [`NewtonEuler::body_data_input`]): `mass`,
/// `inertia`, `start`, `wrench`, `gravity`, `h`.
#[derive(Clone, Debug)]
pub struct NewtonEuler {
    /// Contact frames, one per contact acting on this body.
    pub frames: Vec<ContactFrame>,
    sizes: Vec<usize>,
}

impl NewtonEuler {
    /// The block for a body with the given contacts.
    pub fn new(frames: Vec<ContactFrame>) -> Self {
        let mut sizes = vec![6, 7];
        for _ in &frames {
            sizes.extend([3, 1, 3]);
        }
        sizes.extend(BODY_DATA_SIZES);
        NewtonEuler { frames, sizes }
    }

    /// Index of the first body data input (`mass`).
    pub fn body_data_input(&self) -> usize {
        2 + 3 * self.frames.len()
    }

    /// The body data at `x`.
    #[inline]
    pub fn body(&self, x: Params<'_>) -> BodyStepData {
        BodyStepData::from_inputs(x, self.body_data_input())
    }

    /// Adds the contact impulses `Σ_c W p` to `r`.
    fn add_contacts(&self, x: Params<'_>, r: &mut Vector6<f64>) {
        let pos = v3(x.array::<7>(1), 0);
        for (c, fr) in self.frames.iter().enumerate() {
            let a1 = v3(x.array::<3>(2 + 3 * c), 0);
            let pn = x.array::<1>(3 + 3 * c)[0];
            let pf = x.array::<3>(4 + 3 * c);
            let force = fr.n * pn + fr.t * pf[0] + fr.o * pf[1];
            let torque = (a1 - pos).cross(&force) + fr.n * pf[2];
            for i in 0..3 {
                r[i] += force[i];
                r[3 + i] += torque[i];
            }
        }
    }
}

impl ResidualBlock for NewtonEuler {
    fn name(&self) -> &str {
        "newton_euler"
    }
    fn num_residuals(&self) -> usize {
        6
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let b = self.body(x);
        let nu = Vector6::from(*x.array::<6>(0));
        let mut r = b.inertial_rows(&nu, &v4(x.array::<7>(1), 3)) + b.impulse();
        self.add_contacts(x, &mut r);
        out.copy_from_slice(r.as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let b = self.body(x);
        let nu = Vector6::from(*x.array::<6>(0));
        let q = v4(x.array::<7>(1), 3);
        b.data_jacobian(&nu, &q, self.body_data_input(), jac);
        // The unknowns' derivatives, unless only data are asked for (`∂F/∂θ`).
        if !(0..self.body_data_input()).any(|k| jac.wants(k)) {
            return;
        }
        b.variable_jacobian(&nu, &q, jac);
        let pos = v3(x.array::<7>(1), 0);
        let cx: [Column; 3] = jac.columns(1, 0);
        for (c, fr) in self.frames.iter().enumerate() {
            let a1 = v3(x.array::<3>(2 + 3 * c), 0);
            let pn = x.array::<1>(3 + 3 * c)[0];
            let pf = x.array::<3>(4 + 3 * c);
            let r = a1 - pos;
            let force = fr.n * pn + fr.t * pf[0] + fr.o * pf[1];
            // τ = r × f = −[f]× r ⇒ ∂τ/∂a1 = −[f]×, ∂τ/∂x = [f]×.
            let fx = skew(&force);
            let ca: [Column; 3] = jac.columns(2 + 3 * c, 0);
            for i in 0..3 {
                for j in 0..3 {
                    jac.put_add(ca[j], 3 + i, -fx[(i, j)]);
                    jac.put_add(cx[j], 3 + i, fx[(i, j)]);
                }
            }
            let cf: [Column; 3] = jac.columns(4 + 3 * c, 0);
            let cols = [
                (jac.column(3 + 3 * c, 0), fr.n, r.cross(&fr.n)),
                (cf[0], fr.t, r.cross(&fr.t)),
                (cf[1], fr.o, r.cross(&fr.o)),
                (cf[2], Vector3::zeros(), fr.n),
            ];
            for (col, lin, ang) in cols {
                for i in 0..3 {
                    jac.put(col, i, lin[i]);
                    jac.put(col, 3 + i, ang[i]);
                }
            }
        }
    }
}

/// The Jacobian of the Newton–Euler rows of a body on point contacts, `inertial_rows + impulse`
/// plus terms linear in the point impulses (`crate::point`), with respect to `ν` and `q` (inputs
/// 0 and 1) and the body data from input `k0`.
pub fn body_rows_jacobian(
    b: &BodyStepData,
    nu: &Vector6<f64>,
    q: &Vector4<f64>,
    k0: usize,
    jac: &mut JacobianBlocks<'_>,
) {
    b.variable_jacobian(nu, q, jac);
    b.data_jacobian(nu, q, k0, jac);
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::super::common::flat;
    use super::super::data::start_values;
    use super::*;

    fn frames() -> Vec<ContactFrame> {
        let n = Vector3::new(0.1, -0.2, 1.0).normalize();
        let t = (Vector3::x() - n * n.x).normalize();
        vec![
            ContactFrame {
                n,
                t,
                o: n.cross(&t),
            },
            ContactFrame {
                n: Vector3::z(),
                t: Vector3::x(),
                o: Vector3::y(),
            },
        ]
    }

    #[test]
    fn free_fall_rows_vanish() {
        // No contact, no rotation: ν = ν^u + h g solves the rows.
        let ne = NewtonEuler::new(vec![]);
        let g = [0.0, 0.0, -9.81];
        let h = 0.01;
        let nu = [1.0, 0.0, -9.81 * h, 0.0, 0.0, 0.0];
        let q = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0];
        let s = start_values(
            &Vector3::zeros(),
            &Vector4::new(1.0, 0.0, 0.0, 0.0),
            &Vector3::x(),
            &Vector3::zeros(),
        );
        let inertia = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0];
        let params: [&[f64]; 8] = [&nu, &q, &[2.0], &inertia, &s, &[0.0; 6], &g, &[h]];
        let (z, ranges) = flat(&params);
        let mut out = [0.0; 6];
        ne.evaluate(Params::new(&z, &[], &ranges), &mut out);
        assert!(out.iter().all(|v| v.abs() < 1e-15), "{out:?}");
    }

    #[test]
    fn dynamics_has_the_bits_of_free_velocity_and_the_end_mass_matrix() {
        let b = BodyStepData {
            mass: 2.5,
            inertia: inertia_from_entries(&[0.4, 0.5, 0.6, 0.05, -0.02, 0.03]),
            q_start: Vector4::new(0.8, 0.1, 0.5, -0.3),
            nu_start: Vector6::new(0.4, 0.5, 0.6, -1.0, 0.3, 0.2),
            wrench: Vector6::new(1.0, -2.0, 0.5, 0.1, 0.2, -0.3),
            gravity: Vector3::new(0.1, 0.0, -9.81),
            h: 0.01,
        };
        let r1 = rotation_matrix(&Vector4::new(0.9, 0.2, -0.1, 0.3));
        let w = Vector3::new(1.5, -0.7, 2.0);
        let d = b.dynamics(&r1, &w);
        let f = b.free_velocity(&r1, &w);
        assert_eq!(
            d.free_velocity.map(f64::to_bits),
            [0, 1, 2, 3, 4, 5].map(|i| f[i].to_bits())
        );
        let iw1 = r1 * b.inertia * r1.transpose();
        for i in 0..6 {
            for j in 0..6 {
                let expected = match (i < 3, j < 3) {
                    (true, true) if i == j => b.mass,
                    (false, false) => iw1[(i - 3, j - 3)],
                    _ => 0.0,
                };
                assert_eq!(d.mass[i][j].to_bits(), expected.to_bits(), "({i}, {j})");
            }
        }
    }

    #[test]
    fn jacobian_of_variables_and_data() {
        let ne = NewtonEuler::new(frames());
        let nu = [0.3, -0.5, 0.2, 1.5, -0.7, 2.0];
        let q = [0.1, 0.2, 0.6, 0.9, 0.2, -0.1, 0.3];
        let contact = [
            [0.05, 0.1, 0.0],
            [1.2, 0.0, 0.0],
            [0.3, -0.2, 0.01],
            [0.2, 0.3, 0.1],
            [0.7, 0.0, 0.0],
            [-0.1, 0.2, -0.02],
        ];
        let s = [
            0.1, 0.2, 0.3, 0.8, 0.1, 0.5, -0.3, 0.4, 0.5, 0.6, -1.0, 0.3, 0.2,
        ];
        let inertia = [0.4, 0.5, 0.6, 0.05, -0.02, 0.03];
        let wrench = [1.0, -2.0, 0.5, 0.1, 0.2, -0.3];
        let g = [0.1, 0.0, -9.81];
        let mut params: Vec<&[f64]> = vec![&nu, &q];
        params.extend([&contact[0][..], &contact[1][..1], &contact[2][..]]);
        params.extend([&contact[3][..], &contact[4][..1], &contact[5][..]]);
        params.extend([
            &[2.5][..],
            &inertia[..],
            &s[..],
            &wrench[..],
            &g[..],
            &[0.01][..],
        ]);
        let report = check_residual_block(&ne, &params, &CheckOptions::default()).expect("sizes");
        assert!(report.ok(), "{report}");
        assert_eq!(report.pairs.len(), 14);
        // Every data input has a non-zero derivative somewhere (none is silently ignored).
        let (z, ranges) = flat(&params);
        let sizes = ne.parameter_sizes();
        let cols: usize = sizes.iter().sum();
        let col_pos: Vec<usize> = (0..cols).map(|c| c * 6).collect();
        let mut block_start = vec![0];
        for s in sizes {
            block_start.push(block_start.last().copied().unwrap_or(0) + s);
        }
        let mut dense = vec![0.0; 6 * cols];
        ne.jacobian(
            Params::new(&z, &[], &ranges),
            &mut JacobianBlocks::new(&mut dense, &col_pos, &block_start, 6),
        );
        for k in ne.body_data_input()..sizes.len() {
            let block = &dense[block_start[k] * 6..block_start[k + 1] * 6];
            assert!(
                block.iter().any(|v| *v != 0.0),
                "input {k} has a zero derivative"
            );
        }
    }
}
