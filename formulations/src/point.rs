//! Point contacts (`docs/model.md#point-contacts`): the classic, geometrically explicit model the
//! paper argues against, kept as a baseline.
//!
//! A fixed set of contact points — the vertices of the convex pieces of each body, coincident
//! ones merged ([`Shape::vertices`](crate::geometry::Shape::vertices)) — each against each
//! half-space. Everything geometric is frozen at the START of the step (Stewart–Trinkle,
//! Anitescu–Potra): the lever arm `r_i = R(Q^u) b_i` of point `i` (body-frame position `b_i`),
//! its wrenches `W_n,i = [n; r_i × n]`, `W_t,i = [t; r_i × t]`, `W_o,i = [o; r_i × o]` and its
//! gap `g_i(q^u)`. The step problem per body and half-space is then
//!
//! - Newton–Euler with every point's wrench, its mass matrix and gyroscopic impulse
//!   at the end of the step as in the hull model (`docs/energy.md`; [`PointNewtonEuler`]);
//! - the kinematic map (`docs/model.md#kinematic-map`, [`KinematicMap`]);
//! - non-penetration of the linearised gap, in velocity units,
//!   `0 ≤ p_n,i ⊥ g_i(q^u)/h + W_n,iᵀ ν ≥ 0` ([`PointNonPenetration`]);
//! - the elliptic maximum-dissipation friction law of `docs/model.md#friction` restricted to the
//!   tangent plane (a point has no torsion): `e_t² μ p_n W_tᵀν + p_t σ = 0`, `e_o² μ p_n W_oᵀν +
//!   p_o σ = 0` ([`PointFrictionDissipation`]) and `0 ≤ μ p_n − ‖(p_t/e_t, p_o/e_o)‖ ⊥ σ ≥ 0`
//!   ([`PointFrictionEllipsoid`]).
//!
//! The artefacts the paper points at show up here (measured in `tests/point_contacts.rs` and
//! the example `point_vs_ecp`):
//! - the load split among the points is not unique when more than three of them touch. In pure
//!   translation the motion still is (the total wrench is, hence the [`centre_of_pressure`] of
//!   a flat patch, which equals the ECP model's ECP), but when the body turns while it slides the corners
//!   slip in different directions, the friction wrench depends on the split, and the motion is
//!   not unique either (the desk: Newton and PATH converge to ω_z 1e-2 rad/s apart);
//! - the gap is linearised: the rotation over a step moves a vertex towards the rotation axis
//!   through the CM, off its linear prediction by `O(h² |ω|² |r|)`. When ω is parallel to the
//!   plane (tipping) that lifts the vertices in contact, which then carry load across a gap;
//!   when ω is tilted from the normal (a spinning body landing) a vertex can end below the plane
//!   ([`penetration`]).
//!
//! ```
//! use ecp_formulations::{point::PointContacts, scenarios};
//! use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
//!
//! // Scenario A1 on its four bottom corners: the same μ g h deceleration as the ECP model.
//! let mut pc = PointContacts::new(scenarios::a1_sliding()).unwrap();
//! let mut solver = NewtonSolver::new(NewtonSettings::default());
//! let rec = pc.step(&mut solver).unwrap();
//! assert!(rec.converged && rec.summary.residual <= 1e-10);
//! assert!((rec.bodies[0].v.x - (1.0 - 0.3 * 9.8 * 0.01)).abs() < 1e-9);
//! ```

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Matrix6, Vector3, Vector4, Vector6};

use ecp_model::{
    BlockMcp, JacobianBlocks, McpSolver, Params, Problem, ResId, ResidualBlock, SolveError,
    Summary, VarBlock, VarId,
};

use crate::blocks::{BodyStepData, ContactFrame, FrictionParams, KinematicMap};
use crate::fallback::StepMethod;
use crate::formulation::{Formulation, Stepper};
use crate::geometry::min_gap;
use crate::rotation::{kinematic_map, quat_normalize, rotation_matrix};
use crate::stepper::{
    BodySpec, BodyState, ContactRecord, Scene, SceneError, StepRecord, body_energy, gaps_and_modes,
    stored_state,
};

/// A point whose gap at the step start is at most this (m) is closed: its impulse starts active.
pub const CLOSED_GAP: f64 = 1e-9;

/// A point whose normal impulse in the previous step was at most this (N s, the order of the
/// solvers' tolerance) carried no load: its warm start is reset (see
/// [`PointContacts::prepare_step`]).
pub const UNLOADED_IMPULSE: f64 = 1e-10;

/// Warm-start slip rate σ (m/s) of an open, unloaded point: any σ ≥ 0 solves its friction
/// rows, and one well away from 0 keeps them regular for Newton.
pub const OPEN_SIGMA: f64 = 1.0;

#[inline]
fn dot6(w: &Vector6<f64>, nu: &[f64]) -> f64 {
    (0..6).map(|k| w[k] * nu[k]).sum()
}

// -------------------------------------------------------------------------------------------
// Residual blocks
// -------------------------------------------------------------------------------------------

/// The wrenches of one contact point, frozen at the start of the step
/// (`docs/model.md#point-contacts`, the `docs/model.md#newton-euler` wrenches with `r = r_i =
/// R(Q^u) b_i` instead of the end-of-step ECP).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointWrenches {
    /// `W_n = [n; r × n]`.
    pub normal: Vector6<f64>,
    /// `W_t = [t; r × t]`.
    pub t: Vector6<f64>,
    /// `W_o = [o; r × o]`.
    pub o: Vector6<f64>,
}

impl PointWrenches {
    /// The wrenches of a point at lever arm `r` (CM → point, world frame) in contact frame `frame`.
    pub fn new(r: &Vector3<f64>, frame: &ContactFrame) -> Self {
        let w = |d: &Vector3<f64>| {
            let m = r.cross(d);
            Vector6::new(d.x, d.y, d.z, m.x, m.y, m.z)
        };
        PointWrenches {
            normal: w(&frame.n),
            t: w(&frame.t),
            o: w(&frame.o),
        }
    }
}

/// Discrete Newton–Euler equations of a body on point contacts (`docs/model.md#newton-euler`,
/// `docs/model.md#point-contacts`): `0 = −M(ν − ν^u) + Σ_i (W_n,i p_n,i + W_t,i p_t,i + W_o,i
/// p_o,i) + p_app + p_vp`, with the wrenches of the start of the step.
///
/// Two forms, by constructor: [`PointNewtonEuler::for_body`], the one the stepper uses, writes
/// the inertial part as the hull model does — the mass matrix and the gyroscopic impulse at the
/// end of the step ([`crate::blocks::NewtonEuler`], `docs/energy.md`), so a step without applied
/// work cannot feed kinetic energy in; it reads `ν` (6), `q` (7) and, per point, `p_n` (1) and
/// `p_f = (p_t, p_o)` (2). [`PointNewtonEuler::new`] takes a given mass matrix and applied
/// impulse, linear in every unknown, and reads `ν` (6) and, per point, `p_n` and `p_f`.
#[derive(Clone, Debug)]
pub struct PointNewtonEuler {
    /// Generalised mass matrix of the plain form (for [`PointNewtonEuler::for_body`], the one of
    /// the start of the step, for reference).
    pub mass: Matrix6<f64>,
    /// Generalised velocity at the start of the step.
    pub nu_start: Vector6<f64>,
    /// Applied impulse over the step: for the plain form whatever was given; for
    /// [`PointNewtonEuler::for_body`] `p_app` (the gyroscopic impulse is in the rows).
    pub impulse: Vector6<f64>,
    /// Wrenches of the points acting on this body, in the order of the blocks read.
    pub wrenches: Vec<PointWrenches>,
    /// What the rows are computed from, when built by [`PointNewtonEuler::for_body`].
    pub body: Option<BodyStepData>,
    sizes: Vec<usize>,
}

impl PointNewtonEuler {
    /// The block for a body with the given point wrenches, mass matrix and applied impulse.
    pub fn new(
        mass: Matrix6<f64>,
        nu_start: Vector6<f64>,
        impulse: Vector6<f64>,
        wrenches: Vec<PointWrenches>,
    ) -> Self {
        let mut sizes = vec![6];
        for _ in &wrenches {
            sizes.extend([1, 2]);
        }
        PointNewtonEuler {
            mass,
            nu_start,
            impulse,
            wrenches,
            body: None,
            sizes,
        }
    }

    /// The block with the end-of-step mass matrix and gyroscopic impulse computed from the
    /// body's data (see [`PointNewtonEuler`]).
    pub fn for_body(body: BodyStepData, wrenches: Vec<PointWrenches>) -> Self {
        let mut ne = Self::new(body.mass_matrix(), body.nu_start, body.impulse(), wrenches);
        ne.sizes.insert(1, 7);
        ne.body = Some(body);
        ne
    }

    /// Index of the first point block among the blocks read.
    fn first_point(&self) -> usize {
        if self.body.is_some() { 2 } else { 1 }
    }
}

impl ResidualBlock for PointNewtonEuler {
    fn name(&self) -> &str {
        "point_newton_euler"
    }
    fn num_residuals(&self) -> usize {
        6
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let nu = Vector6::from_column_slice(x.block(0));
        let mut r = match &self.body {
            Some(b) => {
                let q = x.block(1);
                b.inertial_rows(&nu, &Vector4::new(q[3], q[4], q[5], q[6])) + self.impulse
            }
            None => -self.mass * (nu - self.nu_start) + self.impulse,
        };
        let k0 = self.first_point();
        for (c, w) in self.wrenches.iter().enumerate() {
            let pn = x.block(k0 + 2 * c)[0];
            let pf = x.block(k0 + 1 + 2 * c);
            r += w.normal * pn + w.t * pf[0] + w.o * pf[1];
        }
        out.copy_from_slice(r.as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        match &self.body {
            Some(b) => {
                let nu = Vector6::from_column_slice(x.block(0));
                let q = x.block(1);
                let (dw, dq) = b.inertial_jacobian(&nu, &Vector4::new(q[3], q[4], q[5], q[6]));
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
            None => {
                for j in 0..6 {
                    for i in 0..6 {
                        jac.set(0, i, j, -self.mass[(i, j)]);
                    }
                }
            }
        }
        let k0 = self.first_point();
        for (c, w) in self.wrenches.iter().enumerate() {
            for i in 0..6 {
                jac.set(k0 + 2 * c, i, 0, w.normal[i]);
                jac.set(k0 + 1 + 2 * c, i, 0, w.t[i]);
                jac.set(k0 + 1 + 2 * c, i, 1, w.o[i]);
            }
        }
    }
}

/// Non-penetration of one point with its gap linearised at the start of the step
/// (`docs/model.md#point-contacts`), in velocity units: `0 ≤ p_n ⊥ g(q^u)/h + W_nᵀ ν ≥ 0`.
///
/// `g + h W_nᵀν` is the first-order prediction of the point's end-of-step gap; the true gap
/// differs from it by `O(h² |ω|²)`, which is the baseline's penetration artefact.
/// Reads `ν` (6).
#[derive(Clone, Debug)]
pub struct PointNonPenetration {
    /// Gap `g_i(q^u)` of the point at the start of the step (m, negative when penetrating).
    pub gap: f64,
    /// Step length h (s).
    pub h: f64,
    /// `W_n = [n; r × n]` at the start of the step.
    pub normal_wrench: Vector6<f64>,
}

impl ResidualBlock for PointNonPenetration {
    fn name(&self) -> &str {
        "point_non_penetration"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[6]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        out[0] = self.gap / self.h + dot6(&self.normal_wrench, x.block(0));
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        for k in 0..6 {
            jac.set(0, 0, k, self.normal_wrench[k]);
        }
    }
}

/// Maximum-dissipation friction at one point (`docs/model.md#friction` without the torsion row,
/// `docs/model.md#point-contacts`): `0 = e_t² μ p_n W_tᵀν + p_t σ`, `0 = e_o² μ p_n W_oᵀν + p_o σ`.
///
/// Reads `ν` (6), `p_n` (1), `p_f = (p_t, p_o)` (2), `σ` (1).
#[derive(Clone, Debug)]
pub struct PointFrictionDissipation {
    /// `W_t = [t; r × t]` at the start of the step.
    pub t_wrench: Vector6<f64>,
    /// `W_o = [o; r × o]` at the start of the step.
    pub o_wrench: Vector6<f64>,
    /// Friction parameters (`e_r` is not used: a point has no torsional friction).
    pub friction: FrictionParams,
}

impl PointFrictionDissipation {
    fn scales(&self) -> [f64; 2] {
        let f = &self.friction;
        [f.e_t * f.e_t * f.mu, f.e_o * f.e_o * f.mu]
    }
}

impl ResidualBlock for PointFrictionDissipation {
    fn name(&self) -> &str {
        "point_friction"
    }
    fn num_residuals(&self) -> usize {
        2
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[6, 1, 2, 1]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let nu = x.block(0);
        let pn = x.block(1)[0];
        let pf = x.block(2);
        let sigma = x.block(3)[0];
        let s = self.scales();
        let slip = [dot6(&self.t_wrench, nu), dot6(&self.o_wrench, nu)];
        for i in 0..2 {
            out[i] = s[i] * pn * slip[i] + pf[i] * sigma;
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let nu = x.block(0);
        let pn = x.block(1)[0];
        let pf = x.block(2);
        let sigma = x.block(3)[0];
        let s = self.scales();
        for (i, w) in [self.t_wrench, self.o_wrench].iter().enumerate() {
            for k in 0..6 {
                jac.set(0, i, k, s[i] * pn * w[k]);
            }
            jac.set(1, i, 0, s[i] * dot6(w, nu));
            jac.set(2, i, i, sigma);
            jac.set(3, i, 0, pf[i]);
        }
    }
}

/// The friction ellipse of one point in the cone form of
/// [`FrictionEllipsoid`](crate::blocks::FrictionEllipsoid) (same reason: at `p_n = 0` it bounds
/// the friction impulse by the residual, not by its square root):
/// `0 ≤ μ p_n − ‖(p_t/e_t, p_o/e_o)‖ ⊥ σ ≥ 0`. Reads `p_n` (1), `p_f` (2).
#[derive(Clone, Debug)]
pub struct PointFrictionEllipsoid {
    /// Friction parameters (`e_r` is not used).
    pub friction: FrictionParams,
}

impl ResidualBlock for PointFrictionEllipsoid {
    fn name(&self) -> &str {
        "point_friction_ellipse"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 2]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let f = &self.friction;
        out[0] = f.mu * x.block(0)[0] - ellipse_norm(f, x.block(1)).0;
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let f = &self.friction;
        let (norm, scaled) = ellipse_norm(f, x.block(1));
        jac.set(0, 0, 0, f.mu);
        // At p_f = 0 the norm has the unit ball as generalised gradient; 0 is an element.
        for k in 0..2 {
            let d = if norm > 0.0 { -scaled[k] / norm } else { 0.0 };
            jac.set(1, 0, k, d);
        }
    }
}

/// `‖(p_t/e_t, p_o/e_o)‖` and `(p_t/e_t², p_o/e_o²)` (its gradient times the norm).
fn ellipse_norm(f: &FrictionParams, p: &[f64]) -> (f64, [f64; 2]) {
    let u = [p[0] / f.e_t, p[1] / f.e_o];
    (
        (u[0] * u[0] + u[1] * u[1]).sqrt(),
        [u[0] / f.e_t, u[1] / f.e_o],
    )
}

// -------------------------------------------------------------------------------------------
// Report helpers
// -------------------------------------------------------------------------------------------

/// Centre of pressure of point impulses, `Σ p_n,i a_i / Σ p_n,i` (`docs/model.md#point-contacts`),
/// for the contacts of one body against one half-space; `None` when no point carries load.
///
/// For a flat patch it is fixed by the total contact wrench (moment balance), so it is unique
/// even though the split among the points is not; it is the point model's counterpart of the
/// ECP.
pub fn centre_of_pressure(contacts: &[ContactRecord]) -> Option<Vector3<f64>> {
    let total: f64 = contacts.iter().map(|c| c.pn).sum();
    if total <= 0.0 || !total.is_finite() {
        return None;
    }
    let moment = contacts
        .iter()
        .fold(Vector3::zeros(), |acc, c| acc + c.a1 * c.pn);
    Some(moment / total)
}

/// Penetration at the end of a step: `max(0, −min_gap)` over the records' contacts, i.e. over
/// every vertex of the real bodies against every half-space. For point-contact records this is
/// the max over points of `max(0, −gap)`; for ECP records (hull, union) the same measure, so
/// the two formulations are compared on equal terms.
pub fn penetration(record: &StepRecord) -> f64 {
    record
        .contacts
        .iter()
        .map(|c| (-c.min_gap).max(0.0))
        .fold(0.0, f64::max)
}

// -------------------------------------------------------------------------------------------
// The stepper
// -------------------------------------------------------------------------------------------

/// Handles of one contact point's unknowns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PointVars {
    /// Body index.
    pub body: usize,
    /// Half-space index.
    pub plane: usize,
    /// Index of the point among the body's vertices ([`PointContacts::points`]).
    pub point: usize,
    /// Normal impulse `p_n ≥ 0`.
    pub pn: VarId,
    /// Friction impulses `(p_t, p_o)`, free.
    pub pf: VarId,
    /// Slip rate `σ ≥ 0`.
    pub sigma: VarId,
}

struct PointBody {
    spec: BodySpec,
    /// Contact points, body frame.
    points: Vec<Vector3<f64>>,
    nu: VarId,
    q: VarId,
    newton_euler: ResId,
    kinematic: ResId,
    state: BodyState,
}

/// Per-step residual blocks of one contact point.
#[derive(Clone, Copy)]
struct PointResiduals {
    non_penetration: ResId,
    friction: ResId,
}

/// The point-contact time stepper (`docs/model.md#point-contacts`): the step MCP is built once and
/// its per-step data replaced with [`BlockMcp::replace_residual_block`]; each step warm-starts from
/// the previous one. Records have one [`ContactRecord`] per (point, half-space), body-major and
/// then half-space-major: `a1 = a2` the point at the step end, `lg` its gap, `p_r = 0`.
pub struct PointContacts {
    scene: Scene,
    bodies: Vec<PointBody>,
    contacts: Vec<PointVars>,
    residuals: Vec<PointResiduals>,
    mcp: BlockMcp,
    z: Vec<f64>,
    step: usize,
}

/// Checks the scene like the ECP stepper does and returns the normalised initial states.
fn validate(scene: &Scene) -> Result<Vec<BodyState>, SceneError> {
    // No torsional friction at a point: e_r is not used.
    crate::stepper::validate_parameters(scene, false)?;
    let mut states = Vec::with_capacity(scene.bodies.len());
    for spec in &scene.bodies {
        let mut state = spec.initial;
        state.q = quat_normalize(&state.q).ok_or_else(|| SceneError::Parameter {
            what: format!("{}.orientation", spec.name),
            value: 0.0,
            hint: "the initial quaternion must be non-zero",
        })?;
        let r = rotation_matrix(&state.q);
        for (p, plane) in scene.planes.iter().enumerate() {
            let gap = min_gap(spec.shape.vertices(), &state.x, &r, plane);
            if gap < -CLOSED_GAP {
                return Err(SceneError::InitialPenetration {
                    body: spec.name.clone(),
                    plane: p,
                    depth: -gap,
                });
            }
        }
        states.push(state);
    }
    Ok(states)
}

impl PointContacts {
    /// Validates the scene and builds the point-contact step MCP: per body `ν`, `q`, and per
    /// (half-space, vertex of the body) `p_n`, `(p_t, p_o)`, `σ`.
    pub fn new(scene: Scene) -> Result<Self, SceneError> {
        let points = scene
            .bodies
            .iter()
            .map(|b| b.shape.vertices().to_vec())
            .collect();
        Self::with_points(scene, points)
    }

    /// Like [`PointContacts::new`] with a chosen set of contact points per body (body frame),
    /// for instance only the corners of a desk's feet; `points[b]` are body `b`'s. The records
    /// still measure the gap and the mode over every vertex of the real body, so a vertex left
    /// out of the set shows up as penetration.
    pub fn with_points(scene: Scene, points: Vec<Vec<Vector3<f64>>>) -> Result<Self, SceneError> {
        let not_applicable = |reason: String| SceneError::NotApplicable {
            formulation: Formulation::Point,
            step: None,
            reason,
        };
        if points.len() != scene.bodies.len() {
            return Err(not_applicable(format!(
                "{} point sets were given for {} bodies; give one list of contact points per body",
                points.len(),
                scene.bodies.len()
            )));
        }
        for (spec, pts) in scene.bodies.iter().zip(&points) {
            if pts.is_empty() || pts.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
                return Err(not_applicable(format!(
                    "body '{}': the contact points must be a non-empty list of finite body-frame \
                     points",
                    spec.name
                )));
            }
            // The records hold the same number of contacts per body (the trajectory's columns).
            if pts.len() != points[0].len() {
                return Err(not_applicable(format!(
                    "body '{}' has {} contact points and body '{}' has {}; the point formulation \
                     records one contact per point and needs the same number on every body",
                    scene.bodies[0].name,
                    points[0].len(),
                    spec.name,
                    pts.len()
                )));
            }
        }
        let states = validate(&scene)?;
        let mut problem = Problem::new();
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        let mut contacts = Vec::new();
        let tagged = scene.bodies.len() > 1 || scene.planes.len() > 1;
        for (b, ((spec, state), points)) in scene.bodies.iter().zip(states).zip(points).enumerate()
        {
            let nu = problem.add_variable_block(
                VarBlock::free(format!("{}.nu", spec.name), 6)
                    .with_component_names(["vx", "vy", "vz", "wx", "wy", "wz"]),
            );
            let q = problem.add_variable_block(
                VarBlock::free(format!("{}.q", spec.name), 7)
                    .with_component_names(["x", "y", "z", "qw", "qx", "qy", "qz"]),
            );
            for p in 0..scene.planes.len() {
                for i in 0..points.len() {
                    let tag = if tagged {
                        format!("{}.c{p}.point{i}", spec.name)
                    } else {
                        format!("point{i}")
                    };
                    contacts.push(PointVars {
                        body: b,
                        plane: p,
                        point: i,
                        pn: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.pn"), 1)),
                        pf: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.pf"), 2)
                                .with_component_names(["pt", "po"]),
                        ),
                        sigma: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.sigma"), 1)),
                    });
                }
            }
            bodies.push(PointBody {
                spec: spec.clone(),
                points,
                nu,
                q,
                newton_euler: ResId(0),
                kinematic: ResId(0),
                state,
            });
        }

        // Residual blocks, paired as in `docs/model.md#unknowns` (with the
        // `docs/model.md#point-contacts` unknowns); their data are placeholders until
        // `prepare_step` fills in the start of each step.
        let frame0 = ContactFrame {
            n: Vector3::z(),
            t: Vector3::x(),
            o: Vector3::y(),
        };
        let zero = PointWrenches::new(&Vector3::zeros(), &frame0);
        for (b, body) in bodies.iter_mut().enumerate() {
            let mine: Vec<&PointVars> = contacts.iter().filter(|c| c.body == b).collect();
            let mut reads = vec![body.nu, body.q];
            for c in &mine {
                reads.extend([c.pn, c.pf]);
            }
            let placeholder = BodyStepData {
                mass: body.spec.mass.mass,
                inertia: body.spec.mass.inertia,
                q_start: body.state.q,
                nu_start: Vector6::zeros(),
                wrench: Vector6::zeros(),
                gravity: scene.gravity,
                h: scene.h,
            };
            body.newton_euler = problem.add_residual_block(
                body.nu,
                PointNewtonEuler::for_body(placeholder, vec![zero; mine.len()]),
                &reads,
            )?;
            body.kinematic = problem.add_residual_block(
                body.q,
                KinematicMap {
                    x_start: body.state.x,
                    q_start: body.state.q,
                    h: scene.h,
                },
                &[body.q, body.nu],
            )?;
        }
        let mut residuals = Vec::with_capacity(contacts.len());
        for c in &contacts {
            let nu = bodies[c.body].nu;
            let non_penetration = problem.add_residual_block(
                c.pn,
                PointNonPenetration {
                    gap: 0.0,
                    h: scene.h,
                    normal_wrench: zero.normal,
                },
                &[nu],
            )?;
            let friction = problem.add_residual_block(
                c.pf,
                PointFrictionDissipation {
                    t_wrench: zero.t,
                    o_wrench: zero.o,
                    friction: scene.friction,
                },
                &[nu, c.pn, c.pf, c.sigma],
            )?;
            problem.add_residual_block(
                c.sigma,
                PointFrictionEllipsoid {
                    friction: scene.friction,
                },
                &[c.pn, c.pf],
            )?;
            residuals.push(PointResiduals {
                non_penetration,
                friction,
            });
        }
        let mcp = problem.build()?;
        let mut pc = PointContacts {
            z: vec![0.0; ecp_model::Mcp::dim(&mcp)],
            scene,
            bodies,
            contacts,
            residuals,
            mcp,
            step: 0,
        };
        for b in 0..pc.bodies.len() {
            let s = pc.bodies[b].state;
            pc.put(pc.bodies[b].nu, &[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z]);
        }
        Ok(pc)
    }

    fn put(&mut self, v: VarId, values: &[f64]) {
        let range = self.mcp.range(v);
        self.z[range].copy_from_slice(values);
    }

    fn get(&self, v: VarId) -> &[f64] {
        &self.z[self.mcp.range(v)]
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// The assembled step MCP (its data are those of the last step prepared).
    pub fn mcp(&self) -> &BlockMcp {
        &self.mcp
    }
    /// The current unknown vector (last solution, or the warm start of the next step once
    /// [`PointContacts::prepare_step`] has run).
    pub fn z(&self) -> &[f64] {
        &self.z
    }
    /// Contact handles, in the order of the records' contacts.
    pub fn contacts(&self) -> &[PointVars] {
        &self.contacts
    }
    /// The contact points of body `b` (body frame): the vertices of its convex pieces, coincident
    /// ones merged.
    pub fn points(&self, b: usize) -> &[Vector3<f64>] {
        &self.bodies[b].points
    }
    /// The `ν` and `q` handles of body `b`.
    pub fn body_vars(&self, b: usize) -> (VarId, VarId) {
        (self.bodies[b].nu, self.bodies[b].q)
    }
    /// Current state of body `b`.
    pub fn state(&self, b: usize) -> BodyState {
        self.bodies[b].state
    }
    /// Current time.
    pub fn time(&self) -> f64 {
        self.step as f64 * self.scene.h
    }
    /// Steps taken.
    pub fn steps_taken(&self) -> usize {
        self.step
    }

    /// Gap of contact `i` at the current state (m).
    fn gap(&self, i: usize) -> f64 {
        let c = self.contacts[i];
        let body = &self.bodies[c.body];
        let s = body.state;
        let p = s.x + rotation_matrix(&s.q) * body.points[c.point];
        self.scene.planes[c.plane].value(&p)
    }

    /// Active-contact guess for contact `i` (see `Simulation::contact_guess`): the normal
    /// impulse that carries the body's weight and stops its approach over the step, shared by
    /// the `sharing` points of the same body and half-space that start it, and the friction
    /// impulse on the ellipse opposing the point's current slip with σ its slip rate (a point of
    /// the sliding branch). `p_n = 0` would zero every friction row, where Newton's merit
    /// function has a spurious minimiser.
    fn contact_guess(&mut self, i: usize, sharing: usize) {
        let c = self.contacts[i];
        let body = &self.bodies[c.body];
        let plane = &self.scene.planes[c.plane];
        let s = body.state;
        let r = rotation_matrix(&s.q) * body.points[c.point];
        let n = plane.normal();
        let (h, g) = (self.scene.h, self.scene.gravity);
        let m = body.spec.mass.mass;
        let v_pred = s.v + g * h;
        let pn = ((-m * g.dot(&n) * h).max(0.0) + (-m * v_pred.dot(&n)).max(0.0))
            / sharing.max(1) as f64;
        let (_, t, o) = plane.contact_frame();
        let vel = s.v + s.w.cross(&r);
        let (vt, vo) = (t.dot(&vel), o.dot(&vel));
        let f = self.scene.friction;
        let slip = ((f.e_t * vt).powi(2) + (f.e_o * vo).powi(2)).sqrt();
        let (pf, sigma) = if slip > 1e-12 {
            let k = -f.mu * pn / slip;
            ([k * f.e_t * f.e_t * vt, k * f.e_o * f.e_o * vo], slip)
        } else {
            ([0.0, 0.0], 0.0)
        };
        self.put(c.pn, &[pn]);
        self.put(c.pf, &pf);
        self.put(c.sigma, &[sigma]);
    }

    /// Starts the contacts with `pick[i]` from the active guess, each with an equal share of the
    /// load among the contacts with `share[j]` on the same body and half-space.
    fn guess_active(&mut self, pick: &[bool], share: &[bool]) {
        for i in (0..self.contacts.len()).filter(|&i| pick[i]) {
            let c = self.contacts[i];
            let sharing = self
                .contacts
                .iter()
                .zip(share)
                .filter(|(d, s)| **s && d.body == c.body && d.plane == c.plane)
                .count();
            self.contact_guess(i, sharing);
        }
    }

    /// Updates the per-step data (the body data of the Newton–Euler rows, whose mass matrix and
    /// gyroscopic impulse are those of the end of the step, and the points' wrenches and gaps at
    /// the start of the step) and the warm start: the previous
    /// solution, `q` predicted by the kinematic map, and a fresh start for every point that
    /// carried no load in the previous step (the active guess when it is closed, together with
    /// the other closed points of its body and half-space; `p = 0` and σ = [`OPEN_SIGMA`] when
    /// it is open). After this, `mcp()` and `z()` are the step problem
    /// and its starting point.
    pub fn prepare_step(&mut self) -> Result<(), SceneError> {
        let h = self.scene.h;
        let t_u = self.time();
        for b in 0..self.bodies.len() {
            let body = &self.bodies[b];
            let s = body.state;
            let mp = &body.spec.mass;
            let rot = rotation_matrix(&s.q);
            let load = body.spec.load.at(t_u);
            let mut wrenches = Vec::new();
            let mut updates = Vec::new();
            for (i, c) in self.contacts.iter().enumerate() {
                if c.body != b {
                    continue;
                }
                let plane = &self.scene.planes[c.plane];
                let (n, t, o) = plane.contact_frame();
                let r = rot * body.points[c.point];
                let w = PointWrenches::new(&r, &ContactFrame { n, t, o });
                wrenches.push(w);
                updates.push((
                    self.residuals[i],
                    PointNonPenetration {
                        gap: plane.value(&(s.x + r)),
                        h,
                        normal_wrench: w.normal,
                    },
                    PointFrictionDissipation {
                        t_wrench: w.t,
                        o_wrench: w.o,
                        friction: self.scene.friction,
                    },
                ));
            }
            let nu_start = Vector6::new(s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z);
            let ne = PointNewtonEuler::for_body(
                BodyStepData {
                    mass: mp.mass,
                    inertia: mp.inertia,
                    q_start: s.q,
                    nu_start,
                    wrench: load,
                    gravity: self.scene.gravity,
                    h,
                },
                wrenches,
            );
            let km = KinematicMap {
                x_start: s.x,
                q_start: s.q,
                h,
            };
            let (ne_id, km_id, nu_id, q_id) = (body.newton_euler, body.kinematic, body.nu, body.q);
            self.mcp.replace_residual_block(ne_id, Arc::new(ne))?;
            self.mcp.replace_residual_block(km_id, Arc::new(km))?;
            for (ids, np, fr) in updates {
                self.mcp
                    .replace_residual_block(ids.non_penetration, Arc::new(np))?;
                self.mcp
                    .replace_residual_block(ids.friction, Arc::new(fr))?;
            }
            // Warm start: ν from the previous solution (= ν^u), q predicted by the kinematic map.
            let nu_prev = self.get(nu_id).to_vec();
            let v = Vector3::new(nu_prev[0], nu_prev[1], nu_prev[2]);
            let w = Vector3::new(nu_prev[3], nu_prev[4], nu_prev[5]);
            let x_pred = s.x + v * h;
            let q_pred = s.q + kinematic_map(&s.q) * w * (0.5 * h);
            self.put(
                q_id,
                &[
                    x_pred.x, x_pred.y, x_pred.z, q_pred[0], q_pred[1], q_pred[2], q_pred[3],
                ],
            );
        }
        // Every point that carried no load in the previous step gets a fresh start. A closed one
        // gets the active guess (p_n = 0 kills its friction rows, where Newton's merit has a
        // spurious minimiser), and so do the other closed points of its body and half-space, so
        // that the guessed loads add up to the weight. An open one gets p = 0 and σ = OPEN_SIGMA.
        // An unloaded point's friction rows `p_f σ = 0` and `−‖p_f‖ ⊥ σ` hold for every σ ≥ 0, and
        // a σ well away from 0 keeps their Jacobian (σ I on p_f) regular; left at σ ≈ 0 they are
        // doubly degenerate and Newton crawls
        // (docs/decisions.md#point-contacts-restarting-unloaded-points). Loaded points keep their
        // warm values, even when the curvature of the step left them a hair above the plane
        // (tipping).
        let n = self.contacts.len();
        let closed: Vec<bool> = (0..n).map(|i| self.gap(i) <= CLOSED_GAP).collect();
        let unloaded: Vec<bool> = (0..n)
            .map(|i| self.get(self.contacts[i].pn)[0] <= UNLOADED_IMPULSE)
            .collect();
        let group = |i: usize| (self.contacts[i].body, self.contacts[i].plane);
        let restart: Vec<bool> = (0..n)
            .map(|i| closed[i] && (0..n).any(|j| group(j) == group(i) && closed[j] && unloaded[j]))
            .collect();
        self.guess_active(&restart, &closed);
        for i in (0..n).filter(|&i| !closed[i] && unloaded[i]) {
            let c = self.contacts[i];
            self.put(c.pn, &[0.0]);
            self.put(c.pf, &[0.0, 0.0]);
            self.put(c.sigma, &[OPEN_SIGMA]);
        }
        Ok(())
    }

    /// Advances one step with `solver` (see [`Stepper::step`]): a step that does not converge is
    /// reported as failed and the bodies keep their state at its start.
    pub fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        self.prepare_step()?;
        let started = Instant::now();
        let mut result = solver.solve(&self.mcp, &self.z);
        let mut retried = false;
        if result.is_err() {
            // One deterministic retry from the active guess of every point that is closed or
            // closing (as the ECP stepper does).
            let warm = self.z.clone();
            let (h, g) = (self.scene.h, self.scene.gravity);
            let closing: Vec<bool> = (0..self.contacts.len())
                .map(|i| {
                    let c = self.contacts[i];
                    let s = self.bodies[c.body].state;
                    let approach = -(s.v + g * h).dot(&self.scene.planes[c.plane].normal());
                    self.gap(i) <= approach.max(0.0) * h + CLOSED_GAP
                })
                .collect();
            self.guess_active(&closing, &closing);
            retried = true;
            match solver.solve(&self.mcp, &self.z) {
                Ok(sol) => result = Ok(sol),
                Err(_) => self.z.copy_from_slice(&warm),
            }
        }
        let solve_us = started.elapsed().as_secs_f64() * 1e6;
        let (z, summary, converged) = match result {
            Ok(mut sol) => {
                sol.summary
                    .counters
                    .add(ecp_model::Counter::Retries, usize::from(retried));
                (sol.z, sol.summary, true)
            }
            Err(SolveError::NotConverged { best }) => (best.z, best.summary, false),
            Err(SolveError::InvalidProblem(msg)) => {
                return Err(SceneError::Model(ecp_model::ModelError::Dimension(msg)));
            }
        };
        self.step += 1;
        if converged {
            self.z.copy_from_slice(&z);
            self.commit();
        }
        Ok(self.finish_step(summary, converged, solve_us))
    }

    /// Takes the solution in `z`: the end-of-step state (Q renormalised, also in the warm
    /// start) becomes the current state.
    fn commit(&mut self) {
        for b in 0..self.bodies.len() {
            let (state, q_stored) = stored_state(
                self.get(self.bodies[b].nu),
                self.get(self.bodies[b].q),
                &self.bodies[b].state.q,
            );
            let qr = self.bodies[b].q;
            self.put(qr, &q_stored);
            self.bodies[b].state = state;
        }
    }

    /// The record of the step just taken. A step that did not converge keeps the bodies' state
    /// at its start: its iterate is never taken (`docs/fallbacks.md`).
    fn finish_step(&mut self, summary: Summary, converged: bool, solve_us: f64) -> StepRecord {
        let states: Vec<_> = self.bodies.iter().map(|b| b.state).collect();
        let table = gaps_and_modes(
            &self
                .bodies
                .iter()
                .map(|b| (&b.spec.shape, b.state))
                .collect::<Vec<_>>(),
            &self.scene.planes,
        );
        let mut contacts = Vec::with_capacity(self.contacts.len());
        for c in &self.contacts {
            let body = &self.bodies[c.body];
            let plane = &self.scene.planes[c.plane];
            let s = body.state;
            let a = s.x + rotation_matrix(&s.q) * body.points[c.point];
            let (gap, mode) = table[c.body][c.plane];
            let pf = self.get(c.pf);
            contacts.push(ContactRecord {
                a1: a,
                a2: a,
                lg: plane.value(&a),
                pn: self.get(c.pn)[0],
                pt: pf[0],
                po: pf[1],
                pr: 0.0,
                sigma: self.get(c.sigma)[0],
                min_gap: gap,
                mode,
            });
        }
        StepRecord {
            step: self.step,
            t: self.time(),
            bodies: states,
            contacts,
            energy: self.energy(),
            summary,
            converged,
            solve_us,
            method: if converged {
                StepMethod::Direct
            } else {
                StepMethod::Failed
            },
        }
    }

    /// Kinetic plus potential energy (gravity) of all bodies in the current state.
    pub fn energy(&self) -> f64 {
        self.bodies
            .iter()
            .map(|b| body_energy(&b.spec.mass, &b.state, &self.scene.gravity))
            .sum()
    }
}

impl Stepper for PointContacts {
    fn formulation(&self) -> Formulation {
        Formulation::Point
    }
    fn scene(&self) -> &Scene {
        &self.scene
    }
    fn contacts_per_body(&self) -> usize {
        self.contacts.len() / self.bodies.len().max(1)
    }
    fn state(&self, b: usize) -> BodyState {
        self.bodies[b].state
    }
    fn steps_taken(&self) -> usize {
        self.step
    }
    fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        PointContacts::step(self, solver)
    }
}
