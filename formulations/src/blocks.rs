//! Residual blocks of the step problem (formulation.md §4), named after the paper.
//!
//! Each block is paired with the variable block of the same length listed in formulation.md §3
//! and carries its analytic Jacobian; every one is checked against central differences by the
//! model's Jacobian checker (unit tests here and property tests in `tests/`).

use nalgebra::{Matrix3, Matrix6, Vector3, Vector4, Vector6};

use ecp_model::{JacobianBlocks, Params, ResidualBlock};

use crate::rotation::{kinematic_map, rotation_matrix, rotation_matrix_derivatives};

#[inline]
fn v3(s: &[f64], o: usize) -> Vector3<f64> {
    Vector3::new(s[o], s[o + 1], s[o + 2])
}
#[inline]
fn v4(s: &[f64], o: usize) -> Vector4<f64> {
    Vector4::new(s[o], s[o + 1], s[o + 2], s[o + 3])
}

/// Friction parameters of one contact (formulation.md §4.4): Coulomb coefficient μ and the
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

/// Discrete Newton–Euler equations (formulation.md §4.1, paper eq. (discrete_NE)):
/// `0 = −M(q^u)(ν − ν^u) + Σ_c (W_n p_n + W_t p_t + W_o p_o + W_r p_r) + p_app + p_vp`,
/// with `W_n = [n; r × n]`, `r = a1 − x^{u+1}` per contact.
///
/// Reads `ν` (6), `q` (7), and per contact `a1` (3), `p_n` (1), `p_f = (p_t, p_o, p_r)` (3).
#[derive(Clone, Debug)]
pub struct NewtonEuler {
    /// Generalised mass matrix at the start of the step, `diag(m I, R I_body Rᵀ)`.
    pub mass: Matrix6<f64>,
    /// Generalised velocity at the start of the step.
    pub nu_start: Vector6<f64>,
    /// Applied impulse over the step (gravity, loads and the gyroscopic term), `p_app + p_vp`.
    pub impulse: Vector6<f64>,
    /// Contact frames, one per contact acting on this body.
    pub frames: Vec<ContactFrame>,
    sizes: Vec<usize>,
}

impl NewtonEuler {
    /// Builds the block for a body with the given contacts.
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
            sizes,
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
        let nu = Vector6::from_column_slice(x.block(0));
        let pos = v3(x.block(1), 0);
        let mut r = -self.mass * (nu - self.nu_start) + self.impulse;
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
        out.copy_from_slice(r.as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        for j in 0..6 {
            for i in 0..6 {
                jac.set(0, i, j, -self.mass[(i, j)]);
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
}

/// Kinematic map (formulation.md §4.2): `0 = −x + x^u + h v`, `0 = −Q + Q^u + (h/2) E(Q^u) ω`.
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
}

/// Contact condition C1 (formulation.md §4.3): `0 = a1 − a2 − l_g ∇g(a2)`, normalised on the
/// half-space G (whose gradient is its constant normal `n_G`). Reads `a1`, `a2`, `l_g`.
#[derive(Clone, Debug)]
pub struct ClosestPointAlignment {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (formulation.md §4.3, "Scaling").
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

/// Contact condition C2 (formulation.md §4.3): `0 = ∇g(a2) + Σ_i l_i ∇f_i(a1)` with
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

/// Contact condition C3 (formulation.md §4.3): `0 ≤ l_i ⊥ −f_i(a1) ≥ 0` for every face of
/// Conv(F), `f_i(p) = n̂_iᵀ R(Q)ᵀ (p − x) − d_i`. Reads `a1` (3) and `q` (7).
#[derive(Clone, Debug)]
pub struct HullFaces {
    /// Outward unit face normals in the body frame.
    pub face_normals: Vec<Vector3<f64>>,
    /// Face offsets `d_i` (inside: `n̂_i · p ≤ d_i`).
    pub offsets: Vec<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (formulation.md §4.3, "Scaling").
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

/// Contact condition C4 (formulation.md §4.3): `0 ≤ l_g ⊥ −g(a2) ≥ 0`,
/// `g(p) = n_Gᵀ p − c`. Reads `a2`.
#[derive(Clone, Debug)]
pub struct HalfSpaceSide {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Offset c of G.
    pub offset: f64,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (formulation.md §4.3, "Scaling").
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

/// Contact condition C5 (formulation.md §4.3), non-penetration:
/// `0 ≤ p_n ⊥ g(a1) ≥ 0`. Reads `a1`.
#[derive(Clone, Debug)]
pub struct NonPenetration {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Offset c of G.
    pub offset: f64,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (formulation.md §4.3, "Scaling").
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

/// Maximum-power-dissipation friction law (formulation.md §4.4, paper eq. (friction)):
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
}

/// Friction ellipsoid slack (formulation.md §4.4, paper eq. (friction_c)), in its cone form
/// `0 ≤ μ p_n − ‖E⁻¹ p_f‖ ⊥ σ ≥ 0` with `E = diag(e_t, e_o, e_r)`. Reads `p_n` (1), `p_f` (3).
///
/// The paper writes the squared row `μ² p_n² − p_t²/e_t² − p_o²/e_o² − p_r²/e_r²`. For `p_n ≥ 0`
/// both rows have the same sign and the same zeros, so the MCP has the same solutions; but at
/// `p_n = 0` (separated, or lifting off) the squared row only bounds the friction impulse by
/// `|p_f| ≤ √r` for a natural residual `r`, so a step accepted at `r = 1e-10` could carry a
/// spurious `p_f ≈ 1e-5` (measured: ω off by 9e-6 rad/s in the free fall of scenario A5 tilted
/// with the Newton backend). The cone form bounds it by `r`. Its only kink is `p_f = 0`, where
/// the Jacobian uses 0, an element of the generalised gradient.
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
}

/// `‖E⁻¹ p‖` with `E = diag(e_t, e_o, e_r)`, and the vector `E⁻² p` (its gradient times the norm).
fn scaled_norm(f: &FrictionParams, p: &[f64]) -> (f64, [f64; 3]) {
    let e = [f.e_t, f.e_o, f.e_r];
    let u = [p[0] / e[0], p[1] / e[1], p[2] / e[2]];
    let norm = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    (norm, [u[0] / e[0], u[1] / e[1], u[2] / e[2]])
}

/// Generalised mass matrix `diag(m I₃, R I_body Rᵀ)` at orientation `q` (formulation.md §4.1).
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
