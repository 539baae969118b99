//! What the formulations whose unknowns hold each body's end-of-step `ν` and `q` share: the
//! span's body data, the predicted pose of the warm start, and the state stored from a solution.

use nalgebra::{Matrix3, Vector3, Vector4, Vector6};

use ecp_model::{BlockMcp, ModelError, VarId};

use crate::blocks::{BodyDataIds, start_values};
use crate::rotation::{kinematic_map, quat_normalize, rotation_matrix};
use crate::scene::{BodySpec, BodyState};

/// Writes body data `data` for a span from `state` at `t0`: the start state (`x` relative to
/// `origin`, the step problem's origin) and the applied wrench at `t0`
/// (`docs/model.md#data-blocks`). [`set_body_span_data`] with the wrench evaluated here.
pub fn set_body_data(
    mcp: &mut BlockMcp,
    data: &BodyDataIds,
    spec: &BodySpec,
    state: &BodyState,
    origin: &Vector3<f64>,
    t0: f64,
) -> Result<(), ModelError> {
    set_body_span_data(mcp, data, state, &spec.load.at(t0), origin)
}

/// [`set_body_data`] with the applied wrench at the span's start given, `wrench`: the one the
/// driver evaluated once for the span ([`crate::step::StepContext::wrench`]).
pub fn set_body_span_data(
    mcp: &mut BlockMcp,
    data: &BodyDataIds,
    state: &BodyState,
    wrench: &Vector6<f64>,
    origin: &Vector3<f64>,
) -> Result<(), ModelError> {
    let s = state;
    mcp.set_data(data.start, &start_values(&(s.x - origin), &s.q, &s.v, &s.w))?;
    mcp.set_data(data.wrench, wrench.as_slice())
}

/// The warm start of a body's `q` for a span of length `h` from `state`: the previous
/// solution's `ν` in `z` (= `ν^u`) carried by the kinematic map (`docs/model.md#kinematic-map`),
/// written into `z`; returns the predicted pose (world position, rotation).
pub fn predict_pose(
    mcp: &BlockMcp,
    z: &mut [f64],
    (nu, q): (VarId, VarId),
    state: &BodyState,
    origin: &Vector3<f64>,
    h: f64,
) -> (Vector3<f64>, Matrix3<f64>) {
    let s = state;
    let nu_prev = &z[mcp.range(nu)];
    let v = Vector3::new(nu_prev[0], nu_prev[1], nu_prev[2]);
    let w = Vector3::new(nu_prev[3], nu_prev[4], nu_prev[5]);
    let x_pred = s.x - origin + v * h;
    let q_pred = s.q + kinematic_map(&s.q) * w * (0.5 * h);
    z[mcp.range(q)].copy_from_slice(&[
        x_pred.x, x_pred.y, x_pred.z, q_pred[0], q_pred[1], q_pred[2], q_pred[3],
    ]);
    // The start's rotation only for a zero predicted quaternion (not computed otherwise).
    let r_pred =
        quat_normalize(&q_pred).map_or_else(|| rotation_matrix(&s.q), |q| rotation_matrix(&q));
    (x_pred + origin, r_pred)
}

/// [`store_state`] for every body: `vars[b]` are body `b`'s `(ν, q)` blocks, `states` its state
/// at the start of the span on entry and at its end on return.
pub fn store_states(
    mcp: &BlockMcp,
    z: &mut [f64],
    vars: impl IntoIterator<Item = (VarId, VarId)>,
    states: &mut [BodyState],
    origin: &Vector3<f64>,
) {
    for (v, s) in vars.into_iter().zip(states.iter_mut()) {
        *s = store_state(mcp, z, v, &s.q, origin);
    }
}

/// Whether a contact point `gap` (m) away from a half-space of normal `normal` is closed or
/// closing within a span of length `h` from `state`: the gap is at most the approach of the span
/// under gravity, plus `tolerance` (the test of the deterministic retries,
/// `docs/decisions.md#retry-from-the-active-contact-guess`).
pub fn is_closing(
    gap: f64,
    state: &BodyState,
    gravity: &Vector3<f64>,
    normal: &Vector3<f64>,
    h: f64,
    tolerance: f64,
) -> bool {
    let approach = -(state.v + gravity * h).dot(normal);
    gap <= approach.max(0.0) * h + tolerance
}

/// The state stored at the end of a span from the solution's `ν` and `q` blocks in `z`, with Q
/// renormalised (`docs/model.md#kinematic-map`; `previous` replaces a zero quaternion) and `x`
/// in world coordinates (`origin` added); the renormalised Q is written back into `z` for the
/// warm start of the next span.
pub fn store_state(
    mcp: &BlockMcp,
    z: &mut [f64],
    (nu, q): (VarId, VarId),
    previous: &Vector4<f64>,
    origin: &Vector3<f64>,
) -> BodyState {
    let (nu, qr) = (mcp.range(nu), mcp.range(q));
    let (n, qv) = (&z[nu], &z[qr.clone()]);
    let quat = quat_normalize(&Vector4::new(qv[3], qv[4], qv[5], qv[6])).unwrap_or(*previous);
    let state = BodyState {
        x: Vector3::new(qv[0], qv[1], qv[2]) + origin,
        q: quat,
        v: Vector3::new(n[0], n[1], n[2]),
        w: Vector3::new(n[3], n[4], n[5]),
    };
    z[qr][3..7].copy_from_slice(quat.as_slice());
    state
}
