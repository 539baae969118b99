//! Residual blocks of the step problem (`docs/model.md#residual-blocks`), named after the paper.
//!
//! Each block is paired with the variable block of the same length listed in
//! `docs/model.md#unknowns` and carries its analytic Jacobian; every one is checked against central
//! differences by the model's Jacobian checker (unit tests here and property tests in `tests/`).
//!
//! Blocks whose residual depends on model parameters also declare them as **data θ**
//! ([`ResidualBlock::num_data`]; not the variable blocks of `parameter_sizes`) and write
//! `∂r/∂θ` analytically, for the step sensitivities of [`crate::sensitivity`]:
//!
//! | block | data θ |
//! |---|---|
//! | [`NewtonEuler`] built by [`NewtonEuler::for_body`] | [`NEWTON_EULER_DATA`]: m, I_body (6), Q^u (4), v^u, ω^u, applied force and torque |
//! | [`NewtonEuler`] built by [`NewtonEuler::new`] | ν^u (6) and the impulse `p_app + p_vp` (6) |
//! | [`KinematicMap`] | [`KINEMATIC_MAP_DATA`]: x^u (3), Q^u (4) |
//! | [`FrictionDissipation`], [`FrictionEllipsoid`] | [`FRICTION_DATA`]: μ, e_t, e_o, e_r |
//!
//! The contact-geometry blocks (C1–C5) depend only on the shapes, the half-spaces and the row
//! scale, which are not differentiated; they declare no data.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector4, Vector6};

use ecp_model::{DataJacobian, JacobianBlocks, Params, ResidualBlock};

use crate::rotation::{kinematic_map, rotation_matrix, rotation_matrix_derivatives};

#[inline]
fn v3(s: &[f64], o: usize) -> Vector3<f64> {
    Vector3::new(s[o], s[o + 1], s[o + 2])
}
#[inline]
fn v4(s: &[f64], o: usize) -> Vector4<f64> {
    Vector4::new(s[o], s[o + 1], s[o + 2], s[o + 3])
}

/// Friction parameters of one contact (`docs/model.md#friction`): Coulomb coefficient μ and the
/// semi-axes of the limit ellipsoid, `e_t`, `e_o` dimensionless and `e_r` a length (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionParams {
    /// Friction coefficient μ ≥ 0.
    pub mu: f64,
    /// Tangential semi-axis along t.
    pub e_t: f64,
    /// Tangential semi-axis along o.
    pub e_o: f64,
    /// Torsional semi-axis (m).
    pub e_r: f64,
}

/// The fixed contact frame of a half-space (n into the body, t and o tangent).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactFrame {
    /// Unit normal of G pointing into F.
    pub n: Vector3<f64>,
    /// First tangent.
    pub t: Vector3<f64>,
    /// Second tangent, `n × t`.
    pub o: Vector3<f64>,
}

/// Names of the data θ of a [`NewtonEuler`] block built by [`NewtonEuler::for_body`], in order:
/// mass, the six entries of the symmetric body-frame inertia (the parametrisation of
/// [`BodyStepData::inertia`]: `I_xx, I_yy, I_zz, I_xy, I_xz, I_yz`, an off-diagonal datum moving
/// both of its entries), the start-of-step quaternion, linear and angular velocity, and the
/// applied force and torque at the CM (world frame, without gravity).
pub const NEWTON_EULER_DATA: [&str; 23] = [
    "mass",
    "I_xx",
    "I_yy",
    "I_zz",
    "I_xy",
    "I_xz",
    "I_yz",
    "q_start.w",
    "q_start.x",
    "q_start.y",
    "q_start.z",
    "v_start.x",
    "v_start.y",
    "v_start.z",
    "w_start.x",
    "w_start.y",
    "w_start.z",
    "force.x",
    "force.y",
    "force.z",
    "torque.x",
    "torque.y",
    "torque.z",
];

/// Names of the data θ of a [`NewtonEuler`] block built by [`NewtonEuler::new`]: `ν^u` and the
/// applied impulse `p_app + p_vp`.
pub const NEWTON_EULER_PLAIN_DATA: [&str; 12] = [
    "v_start.x",
    "v_start.y",
    "v_start.z",
    "w_start.x",
    "w_start.y",
    "w_start.z",
    "impulse.fx",
    "impulse.fy",
    "impulse.fz",
    "impulse.tx",
    "impulse.ty",
    "impulse.tz",
];

/// The inertia entries of the data parametrisation, `(row, col)` in the order of
/// [`NEWTON_EULER_DATA`] (`I_xx, I_yy, I_zz, I_xy, I_xz, I_yz`).
pub const INERTIA_ENTRIES: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];

/// The symmetric unit matrix of inertia datum `k` ([`INERTIA_ENTRIES`]): `∂I_body/∂θ_k`.
pub fn inertia_direction(k: usize) -> Matrix3<f64> {
    let (i, j) = INERTIA_ENTRIES[k];
    let mut e = Matrix3::zeros();
    e[(i, j)] = 1.0;
    e[(j, i)] = 1.0;
    e
}

/// What a body's Newton–Euler block is computed from (`docs/model.md#newton-euler`): its mass
/// properties, its state at the start of the step and the applied load. These are the block's
/// data θ ([`NEWTON_EULER_DATA`]); gravity and the step length are fixed.
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
    /// The generalised mass matrix `diag(m I, R I_body Rᵀ)` at `Q^u` (the mass matrix of the
    /// start of the step; the rows of [`NewtonEuler::for_body`] use the one of the end).
    pub fn mass_matrix(&self) -> Matrix6<f64> {
        mass_matrix(self.mass, &self.inertia, &self.q_start)
    }

    /// The applied impulse `p_app = h [m g + f; τ]` (gravity and the load at `t_u`). The
    /// gyroscopic impulse is not in it: [`NewtonEuler::for_body`] writes it at the end of the
    /// step, in its rows.
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

    /// The inertial part of the rows of [`NewtonEuler::for_body`] at the end-of-step velocity
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
        let r1 = rotation_matrix(q);
        let iw1 = r1 * self.inertia * r1.transpose();
        let l1 = iw1 * w1;
        let dw = -iw1 - (crate::rotation::skew(&w1) * iw1 - crate::rotation::skew(&l1)) * self.h;
        let omega0 = r0.transpose() * v3(self.nu_start.as_slice(), 3);
        let dr = rotation_matrix_derivatives(q);
        let dq = dr.map(|d| {
            let dl = (d * self.inertia * r1.transpose() + r1 * self.inertia * d.transpose()) * w1;
            -dl + d * (self.inertia * omega0) - w1.cross(&dl) * self.h
        });
        (dw, dq)
    }

    /// Writes the data θ ([`NEWTON_EULER_DATA`]).
    fn write(&self, theta: &mut [f64]) {
        theta[0] = self.mass;
        for (k, (i, j)) in INERTIA_ENTRIES.iter().enumerate() {
            theta[1 + k] = self.inertia[(*i, *j)];
        }
        theta[7..11].copy_from_slice(self.q_start.as_slice());
        theta[11..17].copy_from_slice(self.nu_start.as_slice());
        theta[17..23].copy_from_slice(self.wrench.as_slice());
    }

    /// A copy with the data θ replaced.
    fn with_theta(&self, theta: &[f64]) -> Self {
        let mut d = *self;
        d.mass = theta[0];
        for (k, (i, j)) in INERTIA_ENTRIES.iter().enumerate() {
            d.inertia[(*i, *j)] = theta[1 + k];
            d.inertia[(*j, *i)] = theta[1 + k];
        }
        d.q_start = v4(theta, 7);
        d.nu_start = Vector6::from_column_slice(&theta[11..17]);
        d.wrench = Vector6::from_column_slice(&theta[17..23]);
        d
    }
}

/// Discrete Newton–Euler equations (the paper's eq. (discrete_NE)),
/// `0 = −M^{u+1}(ν^{u+1} − ν^u) + P_c + p_app + p_vp`, with the contact impulse
/// `P_c = Σ_c (W_n p_n + W_t p_t + W_o p_o + W_r p_r)`, `W_n = [n; r × n]`, `r = a1 − x^{u+1}`
/// per contact.
///
/// Two forms, by constructor:
///
/// - [`NewtonEuler::for_body`], the one the steppers use: the mass matrix of the **end** of the
///   step, as the paper writes it (`M^{u+1}`), and the gyroscopic impulse at the end-of-step
///   velocity. The rotational rows are the body-frame balance at the end of the step, with
///   `Ω = Rᵀω`, `R0 = R(Q^u)`, `R1 = R(Q^{u+1})`, `I_b` the body-frame inertia:
///   `I_b (Ω^{u+1} − Ω^u) + h Ω^{u+1} × I_b Ω^{u+1} = R1ᵀ τ`, written in the world frame
///   (multiplied by `R1`):
///   `0 = −R1 I_b R1ᵀ ω + R1 I_b R0ᵀ ω^u − h ω × (R1 I_b R1ᵀ ω) + τ`
///   (τ: applied and contact angular impulses). Dotted with `Ω^{u+1}`, the gyroscopic term
///   vanishes and, without applied or contact impulses,
///   `½ Ω^{u+1}·I_b Ω^{u+1} − ½ Ω^u·I_b Ω^u = −½ ΔΩ·I_b ΔΩ ≤ 0`: the step cannot feed kinetic
///   energy in (the explicit term `−h ω^u × (I_w ω^u)` with `M(q^u)` could, by up to a percent
///   a second for a tumbling body; `docs/energy.md`). The translational rows
///   `0 = −m (v − v^u) + h (m g + f) + Σ f_c` with `x^{u+1} = x^u + h v` change kinetic plus
///   potential energy by `−½ m |Δv|²`. The block reads `Q^{u+1}` (the q block) through `R1`,
///   and `R(Q)` is a rotation for every `Q ≠ 0`, so the renormalised stored quaternion has the
///   same `R1`. Its data θ are [`NEWTON_EULER_DATA`].
/// - [`NewtonEuler::new`]: a given mass matrix and applied impulse, linear in ν,
///   `0 = −M (ν − ν^u) + Σ_c W p + p` (data θ [`NEWTON_EULER_PLAIN_DATA`]).
///
/// Reads `ν` (6), `q` (7), and per contact `a1` (3), `p_n` (1), `p_f = (p_t, p_o, p_r)` (3).
#[derive(Clone, Debug)]
pub struct NewtonEuler {
    /// The mass matrix of the plain form; for [`NewtonEuler::for_body`] the one of the start
    /// of the step, `diag(m I, R(Q^u) I_body R(Q^u)ᵀ)`, for reference (its rows use `M^{u+1}`).
    pub mass: Matrix6<f64>,
    /// Generalised velocity at the start of the step.
    pub nu_start: Vector6<f64>,
    /// Applied impulse over the step: for the plain form whatever was given (gravity, loads
    /// and possibly an explicit gyroscopic term); for [`NewtonEuler::for_body`] `p_app`
    /// (gravity and the load; the gyroscopic impulse is in the rows).
    pub impulse: Vector6<f64>,
    /// Contact frames, one per contact acting on this body.
    pub frames: Vec<ContactFrame>,
    /// What the rows are computed from, when built by [`NewtonEuler::for_body`].
    pub body: Option<BodyStepData>,
    sizes: Vec<usize>,
}

impl NewtonEuler {
    /// Builds the block for a body with the given contacts from its mass matrix, start velocity
    /// and applied impulse; its data θ are then `ν^u` and the impulse
    /// ([`NEWTON_EULER_PLAIN_DATA`]).
    pub fn new(
        mass: Matrix6<f64>,
        nu_start: Vector6<f64>,
        impulse: Vector6<f64>,
        frames: Vec<ContactFrame>,
    ) -> Self {
        let mut sizes = vec![6, 7];
        for _ in &frames {
            sizes.extend([3, 1, 3]);
        }
        NewtonEuler {
            mass,
            nu_start,
            impulse,
            frames,
            body: None,
            sizes,
        }
    }

    /// Builds the energy-stable rows (mass matrix and gyroscopic term at the end of the step,
    /// see [`NewtonEuler`]) from the body's mass properties, start-of-step state and load; its
    /// data θ are those of [`NEWTON_EULER_DATA`], so the step sensitivities reach the mass, the
    /// inertia, the start state and the load.
    pub fn for_body(body: BodyStepData, frames: Vec<ContactFrame>) -> Self {
        let mut ne = Self::new(body.mass_matrix(), body.nu_start, body.impulse(), frames);
        ne.body = Some(body);
        ne
    }

    /// Adds the contact impulses `Σ_c W p` to `r`.
    fn add_contacts(&self, x: Params<'_>, r: &mut Vector6<f64>) {
        let pos = v3(x.block(1), 0);
        for (c, fr) in self.frames.iter().enumerate() {
            let a1 = v3(x.block(2 + 3 * c), 0);
            let pn = x.block(3 + 3 * c)[0];
            let pf = x.block(4 + 3 * c);
            let force = fr.n * pn + fr.t * pf[0] + fr.o * pf[1];
            let torque = (a1 - pos).cross(&force) + fr.n * pf[2];
            for i in 0..3 {
                r[i] += force[i];
                r[3 + i] += torque[i];
            }
        }
    }

    /// The residual of the plain form for given mass matrix, start velocity and impulse.
    fn residual(
        &self,
        mass: &Matrix6<f64>,
        nu_start: &Vector6<f64>,
        impulse: &Vector6<f64>,
        x: Params<'_>,
        out: &mut [f64],
    ) {
        let nu = Vector6::from_column_slice(x.block(0));
        let mut r = -mass * (nu - nu_start) + impulse;
        self.add_contacts(x, &mut r);
        out.copy_from_slice(r.as_slice());
    }

    /// The residual of the body form for given body data.
    fn body_residual(&self, b: &BodyStepData, x: Params<'_>, out: &mut [f64]) {
        let nu = Vector6::from_column_slice(x.block(0));
        let mut r = b.inertial_rows(&nu, &v4(x.block(1), 3)) + b.impulse();
        self.add_contacts(x, &mut r);
        out.copy_from_slice(r.as_slice());
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
        match &self.body {
            Some(b) => self.body_residual(b, x, out),
            None => self.residual(&self.mass, &self.nu_start, &self.impulse, x, out),
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        match &self.body {
            None => {
                for j in 0..6 {
                    for i in 0..6 {
                        jac.set(0, i, j, -self.mass[(i, j)]);
                    }
                }
            }
            Some(b) => {
                let nu = Vector6::from_column_slice(x.block(0));
                let (dw, dq) = b.inertial_jacobian(&nu, &v4(x.block(1), 3));
                for i in 0..3 {
                    jac.set(0, i, i, -b.mass);
                    for j in 0..3 {
                        jac.set(0, 3 + i, 3 + j, dw[(i, j)]);
                    }
                }
                for (k, col) in dq.iter().enumerate() {
                    for i in 0..3 {
                        jac.set(1, 3 + i, 3 + k, col[i]);
                    }
                }
            }
        }
        let pos = v3(x.block(1), 0);
        for (c, fr) in self.frames.iter().enumerate() {
            let a1 = v3(x.block(2 + 3 * c), 0);
            let pn = x.block(3 + 3 * c)[0];
            let pf = x.block(4 + 3 * c);
            let r = a1 - pos;
            let force = fr.n * pn + fr.t * pf[0] + fr.o * pf[1];
            // τ = r × f = −[f]× r ⇒ ∂τ/∂a1 = −[f]×, ∂τ/∂x = [f]×.
            let fx = crate::rotation::skew(&force);
            for i in 0..3 {
                for j in 0..3 {
                    jac.add(2 + 3 * c, 3 + i, j, -fx[(i, j)]);
                    jac.add(1, 3 + i, j, fx[(i, j)]);
                }
            }
            let cols = [
                (3 + 3 * c, 0, fr.n, r.cross(&fr.n)),
                (4 + 3 * c, 0, fr.t, r.cross(&fr.t)),
                (4 + 3 * c, 1, fr.o, r.cross(&fr.o)),
                (4 + 3 * c, 2, Vector3::zeros(), fr.n),
            ];
            for (k, j, lin, ang) in cols {
                for i in 0..3 {
                    jac.set(k, i, j, lin[i]);
                    jac.set(k, 3 + i, j, ang[i]);
                }
            }
        }
    }
    fn num_data(&self) -> usize {
        if self.body.is_some() {
            NEWTON_EULER_DATA.len()
        } else {
            NEWTON_EULER_PLAIN_DATA.len()
        }
    }
    fn data(&self, theta: &mut [f64]) {
        match &self.body {
            Some(b) => b.write(theta),
            None => {
                theta[..6].copy_from_slice(self.nu_start.as_slice());
                theta[6..12].copy_from_slice(self.impulse.as_slice());
            }
        }
    }
    fn data_name(&self, k: usize) -> String {
        let names: &[&str] = if self.body.is_some() {
            &NEWTON_EULER_DATA
        } else {
            &NEWTON_EULER_PLAIN_DATA
        };
        names
            .get(k)
            .map_or_else(|| format!("theta{k}"), |s| (*s).to_string())
    }
    fn evaluate_with_data(&self, x: Params<'_>, theta: &[f64], out: &mut [f64]) {
        match &self.body {
            Some(b) => self.body_residual(&b.with_theta(theta), x, out),
            None => {
                let nu_start = Vector6::from_column_slice(&theta[..6]);
                let impulse = Vector6::from_column_slice(&theta[6..12]);
                self.residual(&self.mass, &nu_start, &impulse, x, out);
            }
        }
    }
    fn data_jacobian(&self, x: Params<'_>, jac: &mut DataJacobian<'_>) {
        let Some(b) = &self.body else {
            // r = −M (ν − ν^u) + p: ∂r/∂ν^u = M, ∂r/∂p = I.
            for j in 0..6 {
                for i in 0..6 {
                    jac.set(i, j, self.mass[(i, j)]);
                }
                jac.set(j, 6 + j, 1.0);
            }
            return;
        };
        let nu = x.block(0);
        let dv = v3(nu, 0) - v3(b.nu_start.as_slice(), 0);
        let w1 = v3(nu, 3);
        let w0 = v3(b.nu_start.as_slice(), 3);
        let h = b.h;
        let r0 = rotation_matrix(&b.q_start);
        let r1 = rotation_matrix(&v4(x.block(1), 3));
        // Mass: −(v − v^u) + h g.
        let dm = -dv + b.gravity * h;
        for i in 0..3 {
            jac.set(i, 0, dm[i]);
        }
        // Inertia entries, E_k = ∂I_b/∂θ_k: the rotational rows
        // −R1 I_b R1ᵀ ω + R1 I_b R0ᵀ ω^u − h ω × (R1 I_b R1ᵀ ω) are linear in I_b.
        for k in 0..6 {
            let e = inertia_direction(k);
            let dl = r1 * (e * (r1.transpose() * w1));
            let col = -dl + r1 * (e * (r0.transpose() * w0)) - w1.cross(&dl) * h;
            for i in 0..3 {
                jac.set(3 + i, 1 + k, col[i]);
            }
        }
        // Start quaternion: only R0 = R(Q^u) in R1 I_b R0ᵀ ω^u.
        let dr = rotation_matrix_derivatives(&b.q_start);
        for (k, d) in dr.iter().enumerate() {
            let col = r1 * (b.inertia * (d.transpose() * w0));
            for i in 0..3 {
                jac.set(3 + i, 7 + k, col[i]);
            }
        }
        // Start velocity: ∂/∂v^u = m I; start angular velocity: ∂/∂ω^u = R1 I_b R0ᵀ.
        let carry = r1 * b.inertia * r0.transpose();
        for i in 0..3 {
            jac.set(i, 11 + i, b.mass);
            for j in 0..3 {
                jac.set(3 + i, 14 + j, carry[(i, j)]);
            }
        }
        // Applied force and torque: h I.
        for i in 0..6 {
            jac.set(i, 17 + i, h);
        }
    }
}

/// Kinematic map (`docs/model.md#kinematic-map`): `0 = −x + x^u + h v`, `0 = −Q + Q^u + (h/2)
/// E(Q^u) ω`.
///
/// Reads `q` (7) and `ν` (6). Linear in the unknowns.
#[derive(Clone, Debug)]
pub struct KinematicMap {
    /// Position at the start of the step.
    pub x_start: Vector3<f64>,
    /// Orientation at the start of the step (unit quaternion, scalar first).
    pub q_start: Vector4<f64>,
    /// Step length h.
    pub h: f64,
}

impl ResidualBlock for KinematicMap {
    fn name(&self) -> &str {
        "kinematic_map"
    }
    fn num_residuals(&self) -> usize {
        7
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[7, 6]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let q = x.block(0);
        let nu = x.block(1);
        for i in 0..3 {
            out[i] = -q[i] + self.x_start[i] + self.h * nu[i];
        }
        let e = kinematic_map(&self.q_start);
        let w = v3(nu, 3);
        let dq = e * w * (0.5 * self.h);
        for i in 0..4 {
            out[3 + i] = -q[3 + i] + self.q_start[i] + dq[i];
        }
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.add_diagonal(0, 0, 0, 7, -1.0);
        jac.add_diagonal(1, 0, 0, 3, self.h);
        let e = kinematic_map(&self.q_start);
        for i in 0..4 {
            for j in 0..3 {
                jac.set(1, 3 + i, 3 + j, 0.5 * self.h * e[(i, j)]);
            }
        }
    }
    fn num_data(&self) -> usize {
        KINEMATIC_MAP_DATA.len()
    }
    fn data(&self, theta: &mut [f64]) {
        theta[..3].copy_from_slice(self.x_start.as_slice());
        theta[3..7].copy_from_slice(self.q_start.as_slice());
    }
    fn data_name(&self, k: usize) -> String {
        KINEMATIC_MAP_DATA
            .get(k)
            .map_or_else(|| format!("theta{k}"), |s| (*s).to_string())
    }
    fn evaluate_with_data(&self, x: Params<'_>, theta: &[f64], out: &mut [f64]) {
        let km = KinematicMap {
            x_start: v3(theta, 0),
            q_start: v4(theta, 3),
            h: self.h,
        };
        km.evaluate(x, out);
    }
    fn data_jacobian(&self, x: Params<'_>, jac: &mut DataJacobian<'_>) {
        for i in 0..7 {
            jac.set(i, i, 1.0);
        }
        // E(Q) ω is linear in Q: its derivative along Q_k is E(e_k) ω.
        let w = v3(x.block(1), 3);
        for k in 0..4 {
            let col = kinematic_map(&Vector4::ith(k, 1.0)) * w * (0.5 * self.h);
            for i in 0..4 {
                jac.add(3 + i, 3 + k, col[i]);
            }
        }
    }
}

/// Names of the data θ of a [`KinematicMap`] block: the start-of-step position and quaternion.
pub const KINEMATIC_MAP_DATA: [&str; 7] = [
    "x_start.x",
    "x_start.y",
    "x_start.z",
    "q_start.w",
    "q_start.x",
    "q_start.y",
    "q_start.z",
];

/// Names of the data θ of the friction blocks ([`FrictionDissipation`], [`FrictionEllipsoid`]).
pub const FRICTION_DATA: [&str; 4] = ["mu", "e_t", "e_o", "e_r"];

impl FrictionParams {
    fn write(&self, theta: &mut [f64]) {
        theta[..4].copy_from_slice(&[self.mu, self.e_t, self.e_o, self.e_r]);
    }
    fn from_theta(theta: &[f64]) -> Self {
        FrictionParams {
            mu: theta[0],
            e_t: theta[1],
            e_o: theta[2],
            e_r: theta[3],
        }
    }
}

fn friction_data_name(k: usize) -> String {
    FRICTION_DATA
        .get(k)
        .map_or_else(|| format!("theta{k}"), |s| (*s).to_string())
}

/// Contact condition C1 (`docs/model.md#contact`): `0 = a1 − a2 − l_g ∇g(a2)`, normalised on the
/// half-space G (whose gradient is its constant normal `n_G`). Reads `a1`, `a2`, `l_g`.
#[derive(Clone, Debug)]
pub struct ClosestPointAlignment {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for ClosestPointAlignment {
    fn name(&self) -> &str {
        "ecp_c1"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 3, 1]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let (a1, a2, lg) = (x.block(0), x.block(1), x.block(2)[0]);
        for i in 0..3 {
            out[i] = self.scale * (a1[i] - a2[i] - lg * self.normal[i]);
        }
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.add_diagonal(0, 0, 0, 3, self.scale);
        jac.add_diagonal(1, 0, 0, 3, -self.scale);
        for i in 0..3 {
            jac.set(2, i, 0, -self.scale * self.normal[i]);
        }
    }
}

/// Contact condition C2 (`docs/model.md#contact`): `0 = ∇g(a2) + Σ_i l_i ∇f_i(a1)` with
/// `∇f_i = R(Q) n̂_i` for the faces of Conv(F). Reads `l` (m) and `q` (7).
#[derive(Clone, Debug)]
pub struct NormalCone {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Outward unit face normals of Conv(F) in the body frame.
    pub face_normals: Vec<Vector3<f64>>,
    sizes: [usize; 2],
}

impl NormalCone {
    /// The block for a hull with the given face normals.
    pub fn new(normal: Vector3<f64>, face_normals: Vec<Vector3<f64>>) -> Self {
        let m = face_normals.len();
        NormalCone {
            normal,
            face_normals,
            sizes: [m, 7],
        }
    }
}

impl ResidualBlock for NormalCone {
    fn name(&self) -> &str {
        "ecp_c2"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let l = x.block(0);
        let r = rotation_matrix(&v4(x.block(1), 3));
        let mut s = Vector3::zeros();
        for (li, ni) in l.iter().zip(&self.face_normals) {
            s += ni * *li;
        }
        let v = self.normal + r * s;
        out.copy_from_slice(v.as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let l = x.block(0);
        let qv = v4(x.block(1), 3);
        let r = rotation_matrix(&qv);
        let dr = rotation_matrix_derivatives(&qv);
        let mut s = Vector3::zeros();
        for (i, (li, ni)) in l.iter().zip(&self.face_normals).enumerate() {
            s += ni * *li;
            let col = r * ni;
            for k in 0..3 {
                jac.set(0, k, i, col[k]);
            }
        }
        for (j, d) in dr.iter().enumerate() {
            let col = d * s;
            for k in 0..3 {
                jac.set(1, k, 3 + j, col[k]);
            }
        }
    }
}

/// Contact condition C3 (`docs/model.md#contact`): `0 ≤ l_i ⊥ −f_i(a1) ≥ 0` for every face of
/// Conv(F), `f_i(p) = n̂_iᵀ R(Q)ᵀ (p − x) − d_i`. Reads `a1` (3) and `q` (7).
#[derive(Clone, Debug)]
pub struct HullFaces {
    /// Outward unit face normals in the body frame.
    pub face_normals: Vec<Vector3<f64>>,
    /// Face offsets `d_i` (inside: `n̂_i · p ≤ d_i`).
    pub offsets: Vec<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for HullFaces {
    fn name(&self) -> &str {
        "ecp_c3"
    }
    fn num_residuals(&self) -> usize {
        self.offsets.len()
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 7]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let a1 = v3(x.block(0), 0);
        let q = x.block(1);
        let r = rotation_matrix(&v4(q, 3));
        let local = r.transpose() * (a1 - v3(q, 0));
        for (i, (ni, di)) in self.face_normals.iter().zip(&self.offsets).enumerate() {
            out[i] = -self.scale * (ni.dot(&local) - di);
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let a1 = v3(x.block(0), 0);
        let q = x.block(1);
        let qv = v4(q, 3);
        let r = rotation_matrix(&qv);
        let dr = rotation_matrix_derivatives(&qv);
        let rel = a1 - v3(q, 0);
        // ∂(−f_i)/∂Q_k = −n̂_iᵀ (∂R/∂Q_k)ᵀ rel = −(∂R/∂Q_k n̂_i) · rel.
        let drt_rel: [Vector3<f64>; 4] = [
            dr[0].transpose() * rel,
            dr[1].transpose() * rel,
            dr[2].transpose() * rel,
            dr[3].transpose() * rel,
        ];
        for (i, ni) in self.face_normals.iter().enumerate() {
            let g = r * ni * self.scale;
            for k in 0..3 {
                jac.set(0, i, k, -g[k]);
                jac.set(1, i, k, g[k]);
            }
            for (k, d) in drt_rel.iter().enumerate() {
                jac.set(1, i, 3 + k, -self.scale * ni.dot(d));
            }
        }
    }
}

/// Contact condition C4 (`docs/model.md#contact`): `0 ≤ l_g ⊥ −g(a2) ≥ 0`,
/// `g(p) = n_Gᵀ p − c`. Reads `a2`.
#[derive(Clone, Debug)]
pub struct HalfSpaceSide {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Offset c of G.
    pub offset: f64,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for HalfSpaceSide {
    fn name(&self) -> &str {
        "ecp_c4"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        out[0] = -self.scale * (self.normal.dot(&v3(x.block(0), 0)) - self.offset);
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        for k in 0..3 {
            jac.set(0, 0, k, -self.scale * self.normal[k]);
        }
    }
}

/// Contact condition C5 (`docs/model.md#contact`), non-penetration:
/// `0 ≤ p_n ⊥ g(a1) ≥ 0`. Reads `a1`.
#[derive(Clone, Debug)]
pub struct NonPenetration {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Offset c of G.
    pub offset: f64,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for NonPenetration {
    fn name(&self) -> &str {
        "ecp_c5"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        out[0] = self.scale * (self.normal.dot(&v3(x.block(0), 0)) - self.offset);
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        for k in 0..3 {
            jac.set(0, 0, k, self.scale * self.normal[k]);
        }
    }
}

/// Maximum-power-dissipation friction law (`docs/model.md#friction`, paper eq. (friction)):
/// `0 = e_t² μ p_n W_tᵀν + p_t σ`, `0 = e_o² μ p_n W_oᵀν + p_o σ`, `0 = e_r² μ p_n W_rᵀν + p_r σ`.
///
/// Reads `ν` (6), `q` (7, for `r = a1 − x`), `a1` (3), `p_n` (1), `p_f` (3), `σ` (1).
#[derive(Clone, Debug)]
pub struct FrictionDissipation {
    /// Contact frame.
    pub frame: ContactFrame,
    /// Friction parameters.
    pub friction: FrictionParams,
}

impl FrictionDissipation {
    /// Slip velocities `(W_tᵀν, W_oᵀν, W_rᵀν)` at the ECP.
    fn slip(&self, nu: &[f64], x: &Vector3<f64>, a1: &Vector3<f64>) -> [f64; 3] {
        let v = v3(nu, 0);
        let w = v3(nu, 3);
        let r = a1 - x;
        let fr = &self.frame;
        [
            fr.t.dot(&v) + r.cross(&fr.t).dot(&w),
            fr.o.dot(&v) + r.cross(&fr.o).dot(&w),
            fr.n.dot(&w),
        ]
    }
    fn scales(&self) -> [f64; 3] {
        let f = &self.friction;
        [
            f.e_t * f.e_t * f.mu,
            f.e_o * f.e_o * f.mu,
            f.e_r * f.e_r * f.mu,
        ]
    }
}

impl ResidualBlock for FrictionDissipation {
    fn name(&self) -> &str {
        "friction"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[6, 7, 3, 1, 3, 1]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let slip = self.slip(x.block(0), &v3(x.block(1), 0), &v3(x.block(2), 0));
        let pn = x.block(3)[0];
        let pf = x.block(4);
        let sigma = x.block(5)[0];
        let s = self.scales();
        for i in 0..3 {
            out[i] = s[i] * pn * slip[i] + pf[i] * sigma;
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let nu = x.block(0);
        let pos = v3(x.block(1), 0);
        let a1 = v3(x.block(2), 0);
        let slip = self.slip(nu, &pos, &a1);
        let pn = x.block(3)[0];
        let pf = x.block(4);
        let sigma = x.block(5)[0];
        let s = self.scales();
        let w = v3(nu, 3);
        let r = a1 - pos;
        let fr = &self.frame;
        // Rows t and o: slip = d·v + (r × d)·ω, ∂/∂r = d × ω.
        for (row, d) in [(0usize, fr.t), (1, fr.o)] {
            let c = s[row] * pn;
            let rd = r.cross(&d);
            let dr = d.cross(&w);
            for k in 0..3 {
                jac.set(0, row, k, c * d[k]);
                jac.set(0, row, 3 + k, c * rd[k]);
                jac.set(2, row, k, c * dr[k]);
                jac.set(1, row, k, -c * dr[k]);
            }
        }
        for k in 0..3 {
            jac.set(0, 2, 3 + k, s[2] * pn * fr.n[k]);
        }
        for i in 0..3 {
            jac.set(3, i, 0, s[i] * slip[i]);
            jac.set(4, i, i, sigma);
            jac.set(5, i, 0, pf[i]);
        }
    }
    fn num_data(&self) -> usize {
        FRICTION_DATA.len()
    }
    fn data(&self, theta: &mut [f64]) {
        self.friction.write(theta);
    }
    fn data_name(&self, k: usize) -> String {
        friction_data_name(k)
    }
    fn evaluate_with_data(&self, x: Params<'_>, theta: &[f64], out: &mut [f64]) {
        let b = FrictionDissipation {
            frame: self.frame,
            friction: FrictionParams::from_theta(theta),
        };
        b.evaluate(x, out);
    }
    fn data_jacobian(&self, x: Params<'_>, jac: &mut DataJacobian<'_>) {
        // r_i = e_i² μ p_n slip_i + p_i σ.
        let slip = self.slip(x.block(0), &v3(x.block(1), 0), &v3(x.block(2), 0));
        let pn = x.block(3)[0];
        let f = &self.friction;
        let e = [f.e_t, f.e_o, f.e_r];
        for i in 0..3 {
            jac.set(i, 0, e[i] * e[i] * pn * slip[i]);
            jac.set(i, 1 + i, 2.0 * e[i] * f.mu * pn * slip[i]);
        }
    }
}

/// Friction cone (paper eq. (15), `friction_c`), in the cone form
/// `0 ≤ μ p_n − ‖E⁻¹ p_f‖ ⊥ σ ≥ 0` with `E = diag(e_t, e_o, e_r)`. Reads `p_n` (1), `p_f` (3).
///
/// The paper writes the squared row `μ² p_n² − p_t²/e_t² − p_o²/e_o² − p_r²/e_r²`; for `p_n ≥ 0`
/// both have the same solutions, but only the cone form bounds a spurious friction impulse at
/// `p_n = 0` by the natural residual (`docs/decisions.md#friction-row-in-cone-form`). Its only
/// kink is `p_f = 0`, where the Jacobian uses 0, an element of the generalised gradient.
#[derive(Clone, Debug)]
pub struct FrictionEllipsoid {
    /// Friction parameters.
    pub friction: FrictionParams,
}

impl ResidualBlock for FrictionEllipsoid {
    fn name(&self) -> &str {
        "friction_ellipsoid"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 3]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let f = &self.friction;
        out[0] = f.mu * x.block(0)[0] - scaled_norm(f, x.block(1)).0;
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let f = &self.friction;
        let (norm, scaled) = scaled_norm(f, x.block(1));
        jac.set(0, 0, 0, f.mu);
        // At p = 0 the norm is not differentiable; 0 is an element of its generalised gradient
        // (the unit ball), so the Jacobian stays a valid element for semismooth methods.
        for k in 0..3 {
            let d = if norm > 0.0 { -scaled[k] / norm } else { 0.0 };
            jac.set(1, 0, k, d);
        }
    }
    fn num_data(&self) -> usize {
        FRICTION_DATA.len()
    }
    fn data(&self, theta: &mut [f64]) {
        self.friction.write(theta);
    }
    fn data_name(&self, k: usize) -> String {
        friction_data_name(k)
    }
    fn evaluate_with_data(&self, x: Params<'_>, theta: &[f64], out: &mut [f64]) {
        let b = FrictionEllipsoid {
            friction: FrictionParams::from_theta(theta),
        };
        b.evaluate(x, out);
    }
    fn data_jacobian(&self, x: Params<'_>, jac: &mut DataJacobian<'_>) {
        // r = μ p_n − ‖u‖, u_k = p_k/e_k: ∂‖u‖/∂e_k = −u_k²/(e_k ‖u‖); at p = 0 the kink, 0
        // (the same element of the generalised gradient as the variable Jacobian uses).
        let f = &self.friction;
        let p = x.block(1);
        let (norm, _) = scaled_norm(f, p);
        jac.set(0, 0, x.block(0)[0]);
        let e = [f.e_t, f.e_o, f.e_r];
        if norm > 0.0 {
            for k in 0..3 {
                let u = p[k] / e[k];
                jac.set(0, 1 + k, u * u / (e[k] * norm));
            }
        }
    }
}

/// `‖E⁻¹ p‖` with `E = diag(e_t, e_o, e_r)`, and the vector `E⁻² p` (its gradient times the norm).
fn scaled_norm(f: &FrictionParams, p: &[f64]) -> (f64, [f64; 3]) {
    let e = [f.e_t, f.e_o, f.e_r];
    let u = [p[0] / e[0], p[1] / e[1], p[2] / e[2]];
    let norm = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    (norm, [u[0] / e[0], u[1] / e[1], u[2] / e[2]])
}

/// Generalised mass matrix `diag(m I₃, R I_body Rᵀ)` at orientation `q`
/// (`docs/model.md#newton-euler`).
pub fn mass_matrix(mass: f64, inertia_body: &Matrix3<f64>, q: &Vector4<f64>) -> Matrix6<f64> {
    let r = rotation_matrix(q);
    let iw = r * inertia_body * r.transpose();
    let mut m = Matrix6::zeros();
    for i in 0..3 {
        m[(i, i)] = mass;
        for j in 0..3 {
            m[(3 + i, 3 + j)] = iw[(i, j)];
        }
    }
    m
}
