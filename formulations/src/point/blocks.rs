//! The residual blocks of the point-contact model (`docs/model.md#point-contacts`): Newton–Euler
//! with the wrenches of fixed contact points, the linearised non-penetration row, and the
//! elliptic friction law without torsion; each point's gap and wrenches, frozen at the start of
//! the step, are a `geometry` data block ([`POINT_GEOMETRY`]).

use nalgebra::{Vector3, Vector4, Vector6};

use ecp_model::{JacobianBlocks, Params, ResidualBlock};

use crate::blocks::newton_euler::body_rows_jacobian;
use crate::blocks::{BODY_DATA_SIZES, BodyStepData, ContactFrame, FrictionParams};
use crate::record::ContactRecord;

#[inline]
fn dot6(w: &Vector6<f64>, nu: &[f64]) -> f64 {
    (0..6).map(|k| w[k] * nu[k]).sum()
}

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
