//! The reduced sliding model (`docs/model.md#reduced`; Xie & Chakraborty 2018b): a body sliding
//! with a whole face of Conv(F) on one fixed half-space, in planar motion (in-plane translation and
//! spin about the plane normal). The derivation is in `docs/reduced-sliding.md`; equation numbers
//! (R1)–(R14) below refer to it.
//!
//! With planar motion (`v·n = 0`, `ω = ω_n n`) the normal balance fixes `p_n` (R4), the two
//! tilting-moment balances fix the ECP's in-plane offset `ρ` (R6), Newton–Euler gives the
//! friction impulses as functions of the velocities (R5, R7), and the step of the hull model
//! (`docs/model.md`) reduces to four equations in `(v_t, v_o, ω_n, σ)`: the three
//! maximum-dissipation rows (R10) and the friction ellipsoid in its cone form (R11) — the same
//! form as [`crate::blocks::FrictionEllipsoid`], so the two models have the same solution set.
//! The step MCP has four unknowns and two residual blocks, [`ReducedFriction`] and
//! [`ReducedEllipsoid`], built once; they read the `friction` data block and the step's
//! `sliding` data block ([`SLIDING_DATA`]: (R1)–(R3)), which is updated per step with
//! [`BlockMcp::set_data`].
//!
//! The model applies while the body stays in that planar sliding (or sticking) motion:
//! [`ReducedSliding::new`] refuses scenes it does not describe and [`ReducedSliding`]'s
//! [`Stepper::step`] stops with [`SceneError::NotApplicable`] at the step where the normal
//! impulse would vanish (lift-off) or the ECP would leave the convex hull of the contact patch
//! (tipping). Sticking (`σ = 0`) is a branch of the same complementarity problem and needs no
//! special handling.

use std::time::Instant;

use nalgebra::{Vector3, Vector4};

use ecp_model::{
    BlockMcp, DataBlock, DataId, Input, JacobianBlocks, McpSolver, Params, Problem, SolveError,
    Summary, VarBlock, VarId,
};

use crate::blocks::{ContactFrame, FRICTION_DATA, FrictionParams};
use crate::fallback::StepMethod;
use crate::formulation::{Formulation, Stepper};
use crate::geometry::{
    ContactMode, HalfSpace, contact_mode, convex_hull_2d, min_gap, world_vertices,
};
use crate::rotation::{kinematic_map, quat_normalize, rotation_matrix};
use crate::stepper::{
    BodySpec, BodyState, ContactRecord, MODE_TOLERANCE, Scene, SceneError, StepRecord,
};

/// Distance to the plane (m) within which a vertex of the body belongs to the contact patch at
/// construction.
pub const PATCH_TOLERANCE: f64 = 1e-9;

/// How far (m) the ECP may lie outside the convex hull of the contact patch before the step is
/// refused as tipping (R14). Round-off of the ECP is ~1e-15 m on the reference scenes; the hull
/// model keeps a tipping body's ECP on the hull's edge to ~1e-9 (`docs/model.md#scenarios`).
pub const ECP_TOLERANCE: f64 = 1e-9;

/// Relative tolerance on the initial velocity's normal component and the initial angular
/// velocity's tangential component (m/s and rad/s, relative to `max(1, |v|)`, `max(1, |ω|)`).
pub const PLANAR_TOLERANCE: f64 = 1e-9;

const NOT_APPLICABLE_HINT: &str = "use the hull formulation (--formulation hull), which handles \
                                   every contact mode";

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

/// The convex hull of the contact patch as a polygon in the body frame (R14): 2-D coordinates
/// in an orthonormal basis `(u1, u2)` of the contact face, counter-clockwise.
#[derive(Clone, Debug)]
struct PatchPolygon {
    u1: Vector3<f64>,
    u2: Vector3<f64>,
    corners: Vec<[f64; 2]>,
}

impl PatchPolygon {
    /// The polygon of the body-frame points `patch` of a face with body-frame normal `nb`.
    fn new(patch: &[Vector3<f64>], nb: &Vector3<f64>) -> Self {
        let seed = if nb.x.abs() > 0.9 {
            Vector3::y()
        } else {
            Vector3::x()
        };
        let u1 = (seed - nb * nb.dot(&seed)).normalize();
        let u2 = nb.cross(&u1);
        let pts: Vec<[f64; 2]> = patch.iter().map(|p| [p.dot(&u1), p.dot(&u2)]).collect();
        PatchPolygon {
            u1,
            u2,
            // Duplicates within 1e-15 m merged, collinear points dropped.
            corners: convex_hull_2d(pts, 1e-15, 0.0),
        }
    }

    /// Largest signed distance (m) of the body-frame point `p` (projected on the face) beyond
    /// the polygon's edges: ≤ 0 inside, the distance to the nearest edge line outside.
    fn outside_distance(&self, p: &Vector3<f64>) -> f64 {
        let q = [p.dot(&self.u1), p.dot(&self.u2)];
        let k = self.corners.len();
        let mut worst = f64::NEG_INFINITY;
        for i in 0..k {
            let a = self.corners[i];
            let b = self.corners[(i + 1) % k];
            let e = [b[0] - a[0], b[1] - a[1]];
            let len = (e[0] * e[0] + e[1] * e[1]).sqrt();
            if len <= 1e-15 {
                continue;
            }
            // Outward normal of a counter-clockwise polygon's edge.
            let d = (e[1] * (q[0] - a[0]) - e[0] * (q[1] - a[1])) / len;
            worst = worst.max(d);
        }
        worst
    }
}

/// The reduced sliding model as a time stepper (`docs/model.md#reduced`): one body with a face of
/// Conv(F) on one half-space, sliding or sticking in planar motion. Its step MCP has the four
/// unknowns `(v_t, v_o, ω_n, σ)`; its [`StepRecord`]s have the shape of the hull stepper's.
pub struct ReducedSliding {
    scene: Scene,
    body: BodySpec,
    plane: HalfSpace,
    frame: ContactFrame,
    patch: PatchPolygon,
    mcp: BlockMcp,
    velocity: VarId,
    sigma: VarId,
    /// The `sliding` data block ([`SLIDING_DATA`]), set per step.
    sliding: DataId,
    data: SlidingStepData,
    z: Vec<f64>,
    /// Friction impulses `(p_t, p_o, p_r)` of the last step taken (the warm start's impulses).
    impulses: Option<[f64; 3]>,
    state: BodyState,
    step: usize,
}

impl ReducedSliding {
    /// Validates that the reduced model describes `scene` and builds its step MCP.
    ///
    /// Refuses with [`SceneError::NotApplicable`] (`step: None`): more or fewer than one body or
    /// one half-space; a body not resting with a face of Conv(F) on the plane (fewer than three
    /// non-collinear vertices within [`PATCH_TOLERANCE`]); an initial velocity with a normal
    /// component or an angular velocity with a tangential one ([`PLANAR_TOLERANCE`]); a contact
    /// that is not loaded at t = 0 (normal impulse ≤ 0). Bad parameters and penetration are
    /// [`SceneError::Parameter`] and [`SceneError::InitialPenetration`], as for the hull stepper.
    pub fn new(scene: Scene) -> Result<Self, SceneError> {
        let refuse = |reason: String| SceneError::NotApplicable {
            formulation: Formulation::Reduced,
            step: None,
            reason: format!("{reason}; {NOT_APPLICABLE_HINT}"),
        };
        if scene.bodies.len() != 1 {
            return Err(refuse(format!(
                "the reduced sliding model describes one body, the scene has {}",
                scene.bodies.len()
            )));
        }
        if scene.planes.len() != 1 {
            return Err(refuse(format!(
                "the reduced sliding model describes one contact with one half-space, the scene \
                 has {} half-spaces",
                scene.planes.len()
            )));
        }
        crate::stepper::validate_parameters(&scene, true)?;
        let body = scene.bodies[0].clone();
        // Conv(F) must exist, as for the hull stepper (a flat body has none).
        body.shape.hull().map_err(|source| SceneError::Geometry {
            body: body.name.clone(),
            source,
        })?;
        let plane = scene.planes[0];
        let (n, t, o) = plane.contact_frame();
        let frame = ContactFrame { n, t, o };

        let mut state = body.initial;
        state.q = quat_normalize(&state.q).ok_or_else(|| SceneError::Parameter {
            what: format!("{}.orientation", body.name),
            value: 0.0,
            hint: "the initial quaternion must be non-zero",
        })?;
        if body
            .initial
            .x
            .iter()
            .chain(body.initial.v.iter())
            .chain(body.initial.w.iter())
            .any(|c| !c.is_finite())
        {
            return Err(SceneError::Parameter {
                what: format!("{}.initial state", body.name),
                value: f64::NAN,
                hint: "the initial position and velocities must be finite",
            });
        }
        let r = rotation_matrix(&state.q);
        let gap = min_gap(body.shape.vertices(), &state.x, &r, &plane);
        if gap < -PATCH_TOLERANCE {
            return Err(SceneError::InitialPenetration {
                body: body.name.clone(),
                plane: 0,
                depth: -gap,
            });
        }
        // (R12) patch contact: a face of Conv(F) on the plane.
        let world = world_vertices(body.shape.vertices(), &state.x, &r);
        let mode = contact_mode(&world, &plane, PATCH_TOLERANCE);
        if mode != ContactMode::Patch {
            return Err(refuse(format!(
                "body '{}' does not rest with a face of its convex hull on the half-space (its \
                 contact is '{mode}': fewer than three non-collinear vertices within {:e} m of \
                 the plane, lowest vertex {gap:.3e} m above it)",
                body.name, PATCH_TOLERANCE
            )));
        }
        // (R13) planar motion.
        let vn = state.v.dot(&n);
        if vn.abs() > PLANAR_TOLERANCE * state.v.norm().max(1.0) {
            return Err(refuse(format!(
                "body '{}' starts with a velocity of {vn:.3e} m/s along the plane normal; the \
                 reduced model needs planar motion (an impact or lift-off is not sliding)",
                body.name
            )));
        }
        let w_tan = (state.w - n * state.w.dot(&n)).norm();
        if w_tan > PLANAR_TOLERANCE * state.w.norm().max(1.0) {
            return Err(refuse(format!(
                "body '{}' starts with an angular velocity of {w_tan:.3e} rad/s about an axis \
                 in the plane; the reduced model needs spin about the plane normal only \
                 (tilting is not sliding)",
                body.name
            )));
        }
        let patch: Vec<Vector3<f64>> = body
            .shape
            .vertices()
            .iter()
            .filter(|v| plane.value(&(state.x + r * *v)) <= PATCH_TOLERANCE)
            .copied()
            .collect();
        let nb = r.transpose() * n;
        let patch = PatchPolygon::new(&patch, &nb);

        let mut problem = Problem::new();
        let velocity = problem.add_variable_block(
            VarBlock::free(format!("{}.velocity", body.name), 3)
                .with_component_names(["vt", "vo", "wn"]),
        );
        let sigma =
            problem.add_variable_block(VarBlock::nonnegative(format!("{}.sigma", body.name), 1));
        let data = SlidingStepData {
            frame,
            friction: scene.friction,
            mass: body.mass.mass,
            height: plane.value(&state.x),
            momentum: Vector3::zeros(),
            spin_inertia: Vector3::zeros(),
            angular: Vector3::zeros(),
        };
        let friction = problem.add_data_block(
            DataBlock::new("friction", scene.friction.values()).with_component_names(FRICTION_DATA),
        );
        let sliding = problem.add_data_block(
            DataBlock::new(format!("{}.sliding", body.name), data.sliding_values())
                .with_component_names(SLIDING_DATA),
        );
        let (f, sl) = (Input::from(friction), Input::from(sliding));
        problem.add_residual_block(
            velocity,
            ReducedFriction { frame },
            &[velocity.into(), sigma.into(), f, sl],
        )?;
        problem.add_residual_block(sigma, ReducedEllipsoid { frame }, &[velocity.into(), f, sl])?;
        let mcp = problem.build()?;
        let dim = ecp_model::Mcp::dim(&mcp);
        let mut stepper = ReducedSliding {
            scene,
            body,
            plane,
            frame,
            patch,
            mcp,
            velocity,
            sigma,
            sliding,
            data,
            z: vec![0.0; dim],
            impulses: None,
            state,
            step: 0,
        };
        // (R4) the contact must be loaded at the first step.
        let first = stepper.data_at_start();
        let pn = first.normal_impulse();
        if pn.is_nan() || pn <= 0.0 {
            return Err(refuse(format!(
                "the normal impulse of the first step would be {pn:.3e} N s: gravity and the \
                 applied load do not press body '{}' onto the half-space",
                stepper.body.name
            )));
        }
        stepper.prepare_step()?;
        stepper.sliding_guess();
        Ok(stepper)
    }

    /// The data (R1)–(R3) of the step from the current state at `t_u`.
    fn data_at_start(&self) -> SlidingStepData {
        let s = self.state;
        let h = self.scene.h;
        let mp = &self.body.mass;
        let r = rotation_matrix(&s.q);
        let iw = r * mp.inertia * r.transpose();
        let load = self.body.load.at(self.time());
        let force = self.scene.gravity * mp.mass + load.fixed_rows::<3>(0).into_owned();
        let torque = load.fixed_rows::<3>(3).into_owned() - s.w.cross(&(iw * s.w));
        SlidingStepData {
            frame: self.frame,
            friction: self.scene.friction,
            mass: mp.mass,
            height: self.plane.value(&s.x),
            momentum: s.v * mp.mass + force * h,
            spin_inertia: iw * self.frame.n,
            angular: iw * s.w + torque * h,
        }
    }

    /// Warm start on the sliding branch from the current velocities: `y` from the state, σ the
    /// slip rate at the CM's projection `‖E s‖` (what the friction rows give on the ellipsoid).
    fn sliding_guess(&mut self) {
        let s = self.state;
        let ContactFrame { n, t, o } = self.frame;
        let y = [t.dot(&s.v), o.dot(&s.v), n.dot(&s.w)];
        let f = self.scene.friction;
        let sigma =
            ((f.e_t * y[0]).powi(2) + (f.e_o * y[1]).powi(2) + (f.e_r * y[2]).powi(2)).sqrt();
        self.put(self.velocity, &y);
        self.put(self.sigma, &[sigma]);
    }

    fn put(&mut self, v: VarId, values: &[f64]) {
        let range = self.mcp.range(v);
        self.z[range].copy_from_slice(values);
    }

    fn get(&self, v: VarId) -> &[f64] {
        &self.z[self.mcp.range(v)]
    }

    /// The assembled step MCP (its data are those of the last step prepared): unknowns
    /// `(v_t, v_o, ω_n, σ)`.
    pub fn mcp(&self) -> &BlockMcp {
        &self.mcp
    }

    /// The current unknown vector (last solution, or the warm start of the next step).
    pub fn z(&self) -> &[f64] {
        &self.z
    }

    /// The data (R1)–(R3) of the step last prepared.
    pub fn step_data(&self) -> &SlidingStepData {
        &self.data
    }

    /// The step's impulses, ECP offset and slip at the unknowns `z` of [`ReducedSliding::mcp`].
    pub fn point_at(&self, z: &[f64]) -> SlidingPoint {
        self.data.point(&z[self.mcp.range(self.velocity)])
    }

    /// Updates the per-step data (R1)–(R3) at `t_u` (the `sliding` data block); the
    /// warm start is the previous solution. Refuses the step (lift-off) when the normal impulse
    /// (R4) would be ≤ 0.
    pub fn prepare_step(&mut self) -> Result<(), SceneError> {
        let data = self.data_at_start();
        let pn = data.normal_impulse();
        if pn.is_nan() || pn <= 0.0 {
            return Err(SceneError::NotApplicable {
                formulation: Formulation::Reduced,
                step: Some(self.step + 1),
                reason: format!(
                    "lift-off: the normal impulse would be {pn:.3e} N s at t = {:.6} s (the \
                     applied load no longer presses body '{}' onto the half-space); {}",
                    self.time(),
                    self.body.name,
                    NOT_APPLICABLE_HINT
                ),
            });
        }
        self.data = data;
        self.mcp.set_data(self.sliding, &data.sliding_values())?;
        if let Some(pf) = self.impulses {
            self.warm_start_from_impulses(pf);
        }
        Ok(())
    }

    /// Warm start from the previous solution's impulses and σ: the velocities `y` at which
    /// (R5) and (R7) give the previous step's friction impulses (`v_t`, `v_o` exactly, `ω_n` by
    /// one Newton step on (R7), exact when J ∥ n). The hull stepper's warm start carries the
    /// previous impulses as unknowns; here they are functions of y, and starting from the
    /// previous *velocities* would start from the previous impulses minus the change of the
    /// applied load (`docs/decisions.md#reduced-model-warm-start-from-the-previous-impulses`).
    fn warm_start_from_impulses(&mut self, pf: [f64; 3]) {
        let d = &self.data;
        let ContactFrame { t, o, .. } = d.frame;
        let mut y = [
            (t.dot(&d.momentum) + pf[0]) / d.mass,
            (o.dot(&d.momentum) + pf[1]) / d.mass,
            self.get(self.velocity)[2],
        ];
        let p = d.point(&y);
        let slope = p.d_pf[2][2];
        let next = y[2] + (pf[2] - p.pf[2]) / slope;
        if next.is_finite() {
            y[2] = next;
        }
        if y.iter().all(|v| v.is_finite()) {
            self.put(self.velocity, &y);
        }
    }

    /// Current time.
    pub fn time(&self) -> f64 {
        self.step as f64 * self.scene.h
    }

    /// Advances one step with `solver` (see [`Stepper::step`]).
    pub fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        self.prepare_step()?;
        let warm = self.z.clone();
        let started = Instant::now();
        let mut result = solver.solve(&self.mcp, &self.z);
        let mut retries = 0;
        if result.is_err() {
            // Deterministic retries: from rest on the sticking branch, then on the sliding
            // branch from the start-of-step velocities.
            for guess in 0..2 {
                if guess == 0 {
                    self.z.iter_mut().for_each(|v| *v = 0.0);
                } else {
                    self.sliding_guess();
                }
                retries += 1;
                if let Ok(sol) = solver.solve(&self.mcp, &self.z) {
                    result = Ok(sol);
                    break;
                }
            }
            self.z.copy_from_slice(&warm);
        }
        let solve_us = started.elapsed().as_secs_f64() * 1e6;
        let (z, summary, converged) = match result {
            Ok(mut sol) => {
                sol.summary
                    .counters
                    .add(ecp_model::Counter::Retries, retries);
                (sol.z, sol.summary, true)
            }
            Err(SolveError::NotConverged { best }) => (best.z, best.summary, false),
            Err(SolveError::InvalidProblem(msg)) => {
                return Err(SceneError::Model(ecp_model::ModelError::Dimension(msg)));
            }
        };
        if !converged {
            // Never take a failed iterate: keep the state at the start of the step.
            self.step += 1;
            let s0 = self.state;
            let r = rotation_matrix(&s0.q);
            let verts = world_vertices(self.body.shape.vertices(), &s0.x, &r);
            // No impulses were taken; the ECP is reported below the CM.
            let a1 = s0.x - self.frame.n * self.data.height;
            let contact = ContactRecord {
                a1,
                a2: a1,
                lg: 0.0,
                pn: 0.0,
                pt: 0.0,
                po: 0.0,
                pr: 0.0,
                sigma: 0.0,
                min_gap: min_gap(self.body.shape.vertices(), &s0.x, &r, &self.plane),
                mode: contact_mode(&verts, &self.plane, MODE_TOLERANCE),
            };
            return Ok(StepRecord {
                step: self.step,
                t: self.time(),
                bodies: vec![s0],
                contacts: vec![contact],
                energy: self.energy(),
                summary,
                converged,
                solve_us,
                method: StepMethod::Failed,
            });
        }
        self.finish_step(z, summary, converged, solve_us)
    }

    /// Takes the solution `z`: refuses it when the ECP leaves the patch (R14), else advances the
    /// state with the kinematic map exactly as the hull stepper does and records the step.
    fn finish_step(
        &mut self,
        z: Vec<f64>,
        summary: Summary,
        converged: bool,
        solve_us: f64,
    ) -> Result<StepRecord, SceneError> {
        let h = self.scene.h;
        let p = self.point_at(&z);
        let y = &z[self.mcp.range(self.velocity)];
        let ContactFrame { n, t, o } = self.frame;
        let s0 = self.state;
        let v = t * y[0] + o * y[1];
        let w = n * y[2];
        let x = s0.x + v * h;
        // (R9) kinematic map with ω = ω_n n, then renormalised (`docs/model.md#kinematic-map`).
        let q_raw: Vector4<f64> = s0.q + kinematic_map(&s0.q) * w * (0.5 * h);
        let q = quat_normalize(&q_raw).unwrap_or(s0.q);
        let r = rotation_matrix(&q);
        let rho = t * p.rho[0] + o * p.rho[1];
        let a1 = x - n * self.data.height + rho;
        // (R14) the ECP must stay in the convex hull of the patch, which moves with the body.
        let outside = self.patch.outside_distance(&(r.transpose() * (a1 - x)));
        if outside.is_nan() || outside > ECP_TOLERANCE {
            let solve_note = if converged {
                String::new()
            } else {
                format!(
                    " (the step's solve did not converge: natural residual {:.3e})",
                    summary.residual
                )
            };
            return Err(SceneError::NotApplicable {
                formulation: Formulation::Reduced,
                step: Some(self.step + 1),
                reason: format!(
                    "tipping: the ECP that balances the tilting moments would lie {outside:.3e} m \
                     outside the convex hull of the contact patch (tolerance {ECP_TOLERANCE:e} m) \
                     at t = {:.6} s, so body '{}' would tip over the patch's edge{solve_note}; {}",
                    self.time() + h,
                    self.body.name,
                    NOT_APPLICABLE_HINT
                ),
            });
        }
        self.z.copy_from_slice(&z);
        self.impulses = Some(p.pf);
        let state = BodyState { x, q, v, w };
        self.state = state;
        self.step += 1;
        let verts = world_vertices(self.body.shape.vertices(), &x, &r);
        let contact = ContactRecord {
            a1,
            a2: a1,
            lg: 0.0,
            pn: p.pn,
            pt: p.pf[0],
            po: p.pf[1],
            pr: p.pf[2],
            sigma: self.get(self.sigma)[0],
            min_gap: min_gap(self.body.shape.vertices(), &x, &r, &self.plane),
            mode: contact_mode(&verts, &self.plane, MODE_TOLERANCE),
        };
        Ok(StepRecord {
            step: self.step,
            t: self.time(),
            bodies: vec![state],
            contacts: vec![contact],
            energy: self.energy(),
            summary,
            converged,
            solve_us,
            method: StepMethod::Direct,
        })
    }

    /// Kinetic plus potential energy (gravity) in the current state, as the hull stepper computes
    /// it.
    pub fn energy(&self) -> f64 {
        crate::stepper::body_energy(&self.body.mass, &self.state, &self.scene.gravity)
    }
}

impl Stepper for ReducedSliding {
    fn formulation(&self) -> Formulation {
        Formulation::Reduced
    }
    fn scene(&self) -> &Scene {
        &self.scene
    }
    fn contacts_per_body(&self) -> usize {
        1
    }
    fn state(&self, _b: usize) -> BodyState {
        self.state
    }
    fn steps_taken(&self) -> usize {
        self.step
    }
    fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        ReducedSliding::step(self, solver)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_polygon_distances() {
        let pts = [
            Vector3::new(-0.25, -0.25, -0.45),
            Vector3::new(0.25, -0.25, -0.45),
            Vector3::new(0.25, 0.25, -0.45),
            Vector3::new(-0.25, 0.25, -0.45),
            Vector3::new(0.0, 0.25, -0.45),
            Vector3::new(0.1, 0.1, -0.45),
        ];
        let poly = PatchPolygon::new(&pts, &Vector3::new(0.0, 0.0, -1.0));
        assert_eq!(poly.corners.len(), 4);
        let d = poly.outside_distance(&Vector3::new(0.0, 0.0, -0.45));
        assert!((d + 0.25).abs() < 1e-15, "{d}");
        let d = poly.outside_distance(&Vector3::new(0.3, 0.1, -0.45));
        assert!((d - 0.05).abs() < 1e-15, "{d}");
    }
}
