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

use std::time::Instant;

use nalgebra::{Vector3, Vector4, Vector6};

use ecp_model::{
    BlockMcp, DataBlock, DataId, Input, JacobianBlocks, McpSolver, Params, Problem, ResidualBlock,
    SolveError, Summary, VarBlock, VarId,
};

use crate::blocks::newton_euler::body_rows_jacobian;
use crate::blocks::{
    BODY_DATA_SIZES, BodyDataIds, BodyStepData, ContactFrame, FrictionParams, KinematicMap,
    SceneDataIds, add_body_data, add_scene_data, start_values,
};
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

/// Size of a point's `geometry` data block: its gap and wrenches at the start of the step
/// ([`PointWrenches::geometry_values`]).
pub const POINT_GEOMETRY: usize = 19;

impl PointWrenches {
    /// The values of a point's `geometry` data block: `[g, W_n (6), W_t (6), W_o (6)]`, `g` the
    /// gap at the start of the step.
    pub fn geometry_values(&self, gap: f64) -> [f64; POINT_GEOMETRY] {
        let mut v = [0.0; POINT_GEOMETRY];
        v[0] = gap;
        v[1..7].copy_from_slice(self.normal.as_slice());
        v[7..13].copy_from_slice(self.t.as_slice());
        v[13..19].copy_from_slice(self.o.as_slice());
        v
    }
}

/// Offsets within a point's `geometry` data block.
const GAP: usize = 0;
const WN: usize = 1;
const WT: usize = 7;
const WO: usize = 13;

#[inline]
fn w6(s: &[f64], o: usize) -> Vector6<f64> {
    Vector6::from_column_slice(&s[o..o + 6])
}

/// Discrete Newton–Euler equations of a body on point contacts (`docs/model.md#newton-euler`,
/// `docs/model.md#point-contacts`): `0 = −M(ν − ν^u) + Σ_i (W_n,i p_n,i + W_t,i p_t,i + W_o,i
/// p_o,i) + p_app + p_vp`, with the wrenches of the start of the step and the inertial part as
/// the hull model writes it — the mass matrix and the gyroscopic impulse at the end of the step
/// ([`crate::blocks::NewtonEuler`], `docs/energy.md`), so a step without applied work cannot feed
/// kinetic energy in.
///
/// Reads `ν` (6), `q` (7), the body data ([`BODY_DATA_SIZES`]: `mass`, `inertia`, `start`,
/// `wrench`, `gravity`, `h`) and, per point, `p_n` (1), `p_f = (p_t, p_o)` (2) and its
/// `geometry` data ([`POINT_GEOMETRY`]).
#[derive(Clone, Debug)]
pub struct PointNewtonEuler {
    points: usize,
    sizes: Vec<usize>,
}

impl PointNewtonEuler {
    /// Index of the first body data input.
    pub const BODY_DATA: usize = 2;

    /// The block for a body with `points` contact points.
    pub fn new(points: usize) -> Self {
        let mut sizes = vec![6, 7];
        sizes.extend(BODY_DATA_SIZES);
        for _ in 0..points {
            sizes.extend([1, 2, POINT_GEOMETRY]);
        }
        PointNewtonEuler { points, sizes }
    }

    /// Index of point `c`'s `p_n` input (then `p_f` and its geometry).
    fn point_input(c: usize) -> usize {
        Self::BODY_DATA + BODY_DATA_SIZES.len() + 3 * c
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
        let q = x.block(1);
        let b = BodyStepData::from_inputs(x, Self::BODY_DATA);
        let mut r = b.inertial_rows(&nu, &Vector4::new(q[3], q[4], q[5], q[6])) + b.impulse();
        for c in 0..self.points {
            let k = Self::point_input(c);
            let pn = x.block(k)[0];
            let pf = x.block(k + 1);
            let g = x.block(k + 2);
            r += w6(g, WN) * pn + w6(g, WT) * pf[0] + w6(g, WO) * pf[1];
        }
        out.copy_from_slice(r.as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let nu = Vector6::from_column_slice(x.block(0));
        let q = x.block(1);
        let b = BodyStepData::from_inputs(x, Self::BODY_DATA);
        let qv = Vector4::new(q[3], q[4], q[5], q[6]);
        body_rows_jacobian(&b, &nu, &qv, Self::BODY_DATA, jac);
        for c in 0..self.points {
            let k = Self::point_input(c);
            let g = x.block(k + 2);
            for i in 0..6 {
                jac.set(k, i, 0, g[WN + i]);
                jac.set(k + 1, i, 0, g[WT + i]);
                jac.set(k + 1, i, 1, g[WO + i]);
            }
            if jac.wants(k + 2) {
                let (pn, pf) = (x.block(k)[0], x.block(k + 1));
                for i in 0..6 {
                    jac.set(k + 2, i, WN + i, pn);
                    jac.set(k + 2, i, WT + i, pf[0]);
                    jac.set(k + 2, i, WO + i, pf[1]);
                }
            }
        }
    }
}

/// Non-penetration of one point with its gap linearised at the start of the step
/// (`docs/model.md#point-contacts`), in velocity units: `0 ≤ p_n ⊥ g(q^u)/h + W_nᵀ ν ≥ 0`.
///
/// `g + h W_nᵀν` is the first-order prediction of the point's end-of-step gap; the true gap
/// differs from it by `O(h² |ω|²)`, which is the baseline's penetration artefact.
/// Reads `ν` (6), the point's `geometry` data ([`POINT_GEOMETRY`]: the gap `g_i(q^u)` and
/// `W_n`) and `h` (1).
#[derive(Clone, Copy, Debug, Default)]
pub struct PointNonPenetration;

impl ResidualBlock for PointNonPenetration {
    fn name(&self) -> &str {
        "point_non_penetration"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[6, POINT_GEOMETRY, 1]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let (g, h) = (x.block(1), x.block(2)[0]);
        out[0] = g[GAP] / h + dot6(&w6(g, WN), x.block(0));
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let (nu, g, h) = (x.block(0), x.block(1), x.block(2)[0]);
        for k in 0..6 {
            jac.set(0, 0, k, g[WN + k]);
        }
        if jac.wants(1) {
            jac.set(1, 0, GAP, 1.0 / h);
            for k in 0..6 {
                jac.set(1, 0, WN + k, nu[k]);
            }
        }
        jac.set(2, 0, 0, -g[GAP] / (h * h));
    }
}

/// Maximum-dissipation friction at one point (`docs/model.md#friction` without the torsion row,
/// `docs/model.md#point-contacts`): `0 = e_t² μ p_n W_tᵀν + p_t σ`, `0 = e_o² μ p_n W_oᵀν + p_o σ`.
///
/// Reads `ν` (6), `p_n` (1), `p_f = (p_t, p_o)` (2), `σ` (1), the point's `geometry` data
/// ([`POINT_GEOMETRY`]: `W_t`, `W_o`) and the `friction` data (4; `e_r` is not used: a point has
/// no torsional friction).
#[derive(Clone, Copy, Debug, Default)]
pub struct PointFrictionDissipation;

impl PointFrictionDissipation {
    /// Index of the `geometry` data input.
    pub const GEOMETRY: usize = 4;
    /// Index of the `friction` data input.
    pub const FRICTION: usize = 5;
}

impl ResidualBlock for PointFrictionDissipation {
    fn name(&self) -> &str {
        "point_friction"
    }
    fn num_residuals(&self) -> usize {
        2
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[6, 1, 2, 1, POINT_GEOMETRY, 4]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let nu = x.block(0);
        let pn = x.block(1)[0];
        let pf = x.block(2);
        let sigma = x.block(3)[0];
        let g = x.block(Self::GEOMETRY);
        let s = point_scales(&FrictionParams::from_slice(x.block(Self::FRICTION)));
        let slip = [dot6(&w6(g, WT), nu), dot6(&w6(g, WO), nu)];
        for i in 0..2 {
            out[i] = s[i] * pn * slip[i] + pf[i] * sigma;
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let nu = x.block(0);
        let pn = x.block(1)[0];
        let pf = x.block(2);
        let sigma = x.block(3)[0];
        let g = x.block(Self::GEOMETRY);
        let f = FrictionParams::from_slice(x.block(Self::FRICTION));
        let s = point_scales(&f);
        for (i, o) in [WT, WO].into_iter().enumerate() {
            let w = w6(g, o);
            for k in 0..6 {
                jac.set(0, i, k, s[i] * pn * w[k]);
                jac.set(Self::GEOMETRY, i, o + k, s[i] * pn * nu[k]);
            }
            let slip = dot6(&w, nu);
            jac.set(1, i, 0, s[i] * slip);
            jac.set(2, i, i, sigma);
            jac.set(3, i, 0, pf[i]);
            if jac.wants(Self::FRICTION) {
                let e = [f.e_t, f.e_o][i];
                jac.set(Self::FRICTION, i, 0, e * e * pn * slip);
                jac.set(Self::FRICTION, i, 1 + i, 2.0 * e * f.mu * pn * slip);
            }
        }
    }
}

/// `(e_t² μ, e_o² μ)`.
fn point_scales(f: &FrictionParams) -> [f64; 2] {
    [f.e_t * f.e_t * f.mu, f.e_o * f.e_o * f.mu]
}

/// The friction ellipse of one point in the cone form of
/// [`FrictionEllipsoid`](crate::blocks::FrictionEllipsoid) (same reason: at `p_n = 0` it bounds
/// the friction impulse by the residual, not by its square root):
/// `0 ≤ μ p_n − ‖(p_t/e_t, p_o/e_o)‖ ⊥ σ ≥ 0`. Reads `p_n` (1), `p_f` (2) and the `friction`
/// data (4; `e_r` is not used).
#[derive(Clone, Copy, Debug, Default)]
pub struct PointFrictionEllipsoid;

impl ResidualBlock for PointFrictionEllipsoid {
    fn name(&self) -> &str {
        "point_friction_ellipse"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 2, 4]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let f = FrictionParams::from_slice(x.block(2));
        out[0] = f.mu * x.block(0)[0] - ellipse_norm(&f, x.block(1)).0;
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let f = FrictionParams::from_slice(x.block(2));
        let p = x.block(1);
        let (norm, scaled) = ellipse_norm(&f, p);
        jac.set(0, 0, 0, f.mu);
        // At p_f = 0 the norm has the unit ball as generalised gradient; 0 is an element.
        for k in 0..2 {
            let d = if norm > 0.0 { -scaled[k] / norm } else { 0.0 };
            jac.set(1, 0, k, d);
        }
        if jac.wants(2) {
            // ∂‖u‖/∂e_k = −u_k²/(e_k ‖u‖), u_k = p_k/e_k; 0 at the kink p_f = 0.
            jac.set(2, 0, 0, x.block(0)[0]);
            if norm > 0.0 {
                for (k, e) in [f.e_t, f.e_o].into_iter().enumerate() {
                    let u = p[k] / e;
                    jac.set(2, 0, 1 + k, u * u / (e * norm));
                }
            }
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
    data: BodyDataIds,
    state: BodyState,
}

/// The point-contact time stepper (`docs/model.md#point-contacts`): the step MCP is built once and
/// its per-step data set with [`BlockMcp::set_data`] (the data blocks of
/// `docs/model.md#data-blocks`, and each point's `geometry`); each step warm-starts from
/// the previous one. Records have one [`ContactRecord`] per (point, half-space), body-major and
/// then half-space-major: `a1 = a2` the point at the step end, `lg` its gap, `p_r = 0`.
pub struct PointContacts {
    scene: Scene,
    bodies: Vec<PointBody>,
    contacts: Vec<PointVars>,
    /// The `geometry` data block of each point (parallel to `contacts`).
    geometry: Vec<DataId>,
    mcp: BlockMcp,
    z: Vec<f64>,
    step: usize,
}

/// The name prefix of point `i` of a body against half-space `p` (just `point{i}` in a scene of
/// one body and one half-space).
fn point_tag(tagged: bool, body: &str, p: usize, i: usize) -> String {
    if tagged {
        format!("{body}.c{p}.point{i}")
    } else {
        format!("point{i}")
    }
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
        let scene_data = add_scene_data(&mut problem, &scene.gravity, scene.h, &scene.friction);
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
                    let tag = point_tag(tagged, &spec.name, p, i);
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
            let data = add_body_data(&mut problem, &spec.name, spec.mass.mass, &spec.mass.inertia);
            bodies.push(PointBody {
                spec: spec.clone(),
                points,
                nu,
                q,
                data,
                state,
            });
        }

        // Residual blocks, paired as in `docs/model.md#unknowns` (with the
        // `docs/model.md#point-contacts` unknowns); `prepare_step` sets their per-step data.
        let SceneDataIds {
            gravity,
            h,
            friction,
        } = scene_data;
        let geometry: Vec<DataId> = contacts
            .iter()
            .map(|c| {
                let tag = point_tag(tagged, &bodies[c.body].spec.name, c.plane, c.point);
                problem.add_data_block(DataBlock::new(
                    format!("{tag}.geometry"),
                    [0.0; POINT_GEOMETRY],
                ))
            })
            .collect();
        for (b, body) in bodies.iter().enumerate() {
            let d = body.data;
            let mut reads: Vec<Input> = vec![body.nu.into(), body.q.into()];
            reads.extend([d.mass, d.inertia, d.start, d.wrench, gravity, h].map(Input::from));
            let mut points = 0;
            for (c, g) in contacts.iter().zip(&geometry).filter(|(c, _)| c.body == b) {
                reads.extend([c.pn.into(), c.pf.into(), Input::from(*g)]);
                points += 1;
            }
            problem.add_residual_block(body.nu, PointNewtonEuler::new(points), reads)?;
            problem.add_residual_block(
                body.q,
                KinematicMap,
                &[
                    body.q.into(),
                    body.nu.into(),
                    Input::from(d.start),
                    h.into(),
                ],
            )?;
        }
        for (c, g) in contacts.iter().zip(&geometry) {
            let nu = bodies[c.body].nu;
            let g = Input::from(*g);
            problem.add_residual_block(
                c.pn,
                PointNonPenetration,
                &[nu.into(), g, Input::from(h)],
            )?;
            let vars = [nu, c.pn, c.pf, c.sigma].map(Input::from);
            let mut reads = vars.to_vec();
            reads.extend([g, friction.into()]);
            problem.add_residual_block(c.pf, PointFrictionDissipation, reads)?;
            problem.add_residual_block(
                c.sigma,
                PointFrictionEllipsoid,
                &[c.pn.into(), c.pf.into(), Input::from(friction)],
            )?;
        }
        let mcp = problem.build()?;
        let mut pc = PointContacts {
            z: vec![0.0; ecp_model::Mcp::dim(&mcp)],
            scene,
            bodies,
            contacts,
            geometry,
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
            let rot = rotation_matrix(&s.q);
            let load = body.spec.load.at(t_u);
            let mut updates = Vec::new();
            for (i, c) in self.contacts.iter().enumerate() {
                if c.body != b {
                    continue;
                }
                let plane = &self.scene.planes[c.plane];
                let (n, t, o) = plane.contact_frame();
                let r = rot * body.points[c.point];
                let w = PointWrenches::new(&r, &ContactFrame { n, t, o });
                updates.push((self.geometry[i], w.geometry_values(plane.value(&(s.x + r)))));
            }
            let (data, nu_id, q_id) = (body.data, body.nu, body.q);
            self.mcp
                .set_data(data.start, &start_values(&s.x, &s.q, &s.v, &s.w))?;
            self.mcp.set_data(data.wrench, load.as_slice())?;
            for (g, values) in updates {
                self.mcp.set_data(g, &values)?;
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
