//! The conic subproblem of one outer iteration (`docs/backends.md#conic`): with the contact
//! geometry fixed at the trial point, the end-of-step velocities and contact impulses solve one QP
//! over a product of cones.
//!
//! Primal (velocity) form, one block per body `b` and per contact `c` with a non-empty patch:
//!
//! ```text
//! min  Σ_b ½ (ν_b − ν_free,b)ᵀ M_b (ν_b − ν_free,b)
//! s.t. g_j/h + W_{n,j}ᵀ(ν_b − ν_b^k) + s_c − μ a_c ≥ 0      every patch vertex j      (λ_j)
//!      (a_c, e_t W_tᵀν_b, e_o W_oᵀν_b, e_r W_rᵀν_b) ∈ SOC(4)                         (μ p_n, p_f/e)
//! ```
//!
//! with `W_{n,j} = [n; (v_j − x) × n]` at the patch vertices, `W_t = [t; (a1 − x) × t]`, `W_o = [o;
//! (a1 − x) × o]`, `W_r = [0; n]` at the current ECP (`docs/model.md#newton-euler`), `g_j` the
//! vertex gaps at the trial configuration, and `s_c` the De Saxcé shift `μ ‖E u_T‖` of the trial
//! velocities (Acary, Cadoux, Lemaréchal, Malick 2011), `E = diag(e_t, e_o, e_r)`; `s_c = 0` is
//! Anitescu's relaxation (Anitescu 2006). Its KKT conditions are the discrete Newton–Euler
//! equations `M(ν − ν_free) = Σ_j λ_j W_{n,j} + W_t p_t + W_o p_o + W_r p_r` with `λ_j ≥ 0` (centre
//! of pressure = the ECP) and `‖(p_t/e_t, p_o/e_o, p_r/e_r)‖ ≤ μ Σ_j λ_j`, the friction impulse
//! opposing the slip (maximum dissipation), and complementarity of each `λ_j` with its shifted,
//! linearised gap. At a fixed point (`ν = ν^k`, geometry unchanged, `s_c` equal to the new slip)
//! these are exactly the conditions of `docs/model.md#residual-blocks`.
//!
//! **Anchored contacts** (a body with several loaded contacts, such as the union-of-pieces model of
//! `docs/model.md#union`): the QP's velocities are unique but its impulses are not, and neither is
//! the solution of the step model — how the load is shared between the desk's legs, and where in
//! its foot each leg's centre of pressure lies, are left open (the Jacobian of the step MCP has a
//! 9-dimensional null space on the union desk). The interior-point method returns a different
//! member of that set at each outer iteration; the centre of pressure of each contact becomes its
//! ECP for the next QP, where its friction acts, so the fixed point cycles
//! (`docs/decisions.md#conic-backend-anchor-weights`). Anchored contacts get a proximal term in the
//! dual, centred on the previous iterate: three free variables per contact, `ξ_c ∈ R²` and `ζ_c`,
//! enter each of its vertex rows as `+ b_jᵀξ_c + ζ_c`, with `b_j` the tangential components of `v_j
//! − e_c` (`e_c` the contact's current ECP), at cost `‖ξ_c‖²/(2ρ_m) + ζ_c²/(2ρ_n) + p_{n,c}^k ζ_c`.
//! The KKT conditions give `ξ_c = ρ_m p_{n,c} (CoP_c − e_c)` and `ζ_c = ρ_n (p_{n,c} − p_{n,c}^k)`,
//! i.e. the dual gains `−½ρ_m‖p_{n,c}(CoP_c − e_c)‖² − ½ρ_n (p_{n,c} − p_{n,c}^k)²`: of the
//! impulses that solve the QP, the ones whose centre of pressure stays at the ECP and whose load
//! stays near the previous one. Both terms vanish at a fixed point (the ECP update makes `CoP_c =
//! e_c`, and the load no longer changes), so the fixed point is still exactly
//! `docs/model.md#residual-blocks`; away from it they relax each row by at most what the contact
//! moved in one iteration. This is the proximal point method on the dual (Rockafellar, SIAM J.
//! Control Optim. 14, 1976), restricted to the contact's normal wrench.

use ecp_model::{
    BodyDynamics, ConicPoint, ContactGeometry, ContactImpulses, ContactPartner, PatchVertex,
    StepStructure,
};

use ecp_model::linalg;

use super::mass_factor::{MassFactor, solve6};
use super::min_norm::{PsdRange, Scratch};
use super::qp::{Cone, ConicQp, QpResult};
use crate::union_find::{find, union};

fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn dot6(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The wrench `[d; r × d]` of a unit force `d` applied at lever arm `r`.
fn wrench(d: &[f64; 3], r: &[f64; 3]) -> [f64; 6] {
    let m = cross(r, d);
    [d[0], d[1], d[2], m[0], m[1], m[2]]
}

/// One body a contact acts on, with the contact's wrenches on it: F's `+W`, and for a contact
/// with another dynamic body G, G's `−W` at G's lever arms (equal and opposite impulses,
/// `docs/model.md#impulses-on-both-bodies`).
#[derive(Clone, Debug)]
struct Side {
    body: usize,
    /// Wrenches `W_{n,j}` of the patch vertices on this body.
    normal_wrenches: Vec<[f64; 6]>,
    /// Friction wrenches `W_t, W_o, W_r` at the current ECP on this body.
    friction_wrenches: [[f64; 6]; 3],
}

/// Where one contact sits in the QP.
#[derive(Clone, Debug)]
struct ContactRows {
    /// F, then G when G is a dynamic body.
    sides: Vec<Side>,
    /// Hull indices of the patch vertices, in row order.
    vertices: Vec<usize>,
    /// First row of the vertex rows.
    first_row: usize,
    /// Linearised gap rate of each patch vertex at `ν = 0`: `g_j/h − Σ_sides W_{n,j}ᵀ ν^k` (no
    /// shift).
    gap_rates: Vec<f64>,
    /// The part of the friction rows' relative velocity that is data: `−W_{f,G}ᵀ ν_G` of a G
    /// with prescribed velocity (zero otherwise).
    slip_offset: [f64; 3],
    /// World positions of the patch vertices, in row order.
    positions: Vec<[f64; 3]>,
    /// The contact's geometry (frame, CM), for friction wrenches at another point.
    frame: ContactGeometry,
    /// The proximal anchor of this contact `(ρ_m, ρ_n, p_n^k)`, when anchored.
    anchor: Option<(f64, f64, f64)>,
    /// Ellipsoid semi-axes `(e_t, e_o, e_r)`.
    axes: [f64; 3],
    /// First row of the second-order cone, when μ > 0.
    soc_row: Option<usize>,
    /// Friction coefficient μ.
    mu: f64,
}

/// The QP of one outer iteration and how to read its solution.
#[derive(Default)]
pub(crate) struct StepQp {
    pub qp: ConicQp,
    contacts: Vec<Option<ContactRows>>,
    /// Number of patch vertices in the QP.
    pub patch_vertices: usize,
    /// [`build`]'s storage, kept with the QP so that a warm build grows no vector: the previous
    /// QP's contact rows (their vectors refilled), each contact's friction sides, the anchor
    /// weights and columns, one row's coefficients.
    spare: Vec<ContactRows>,
    friction_sides: Vec<BodyFriction>,
    weights: Vec<Option<(f64, f64)>>,
    anchor_cols: Vec<Option<usize>>,
    coeffs: Vec<(usize, f64)>,
    /// [`anchored_contacts_into`]'s answer and its per-body counts.
    anchored: Vec<bool>,
    per_body: Vec<usize>,
}

/// Storage of the polish ([`StepQp::extract_into`]), kept by the solver across outer
/// iterations and solves so that a warm polish allocates nothing (`docs/latency.md`): each
/// vector is cleared and refilled, never dropped.
#[derive(Default)]
pub(crate) struct PolishWorkspace {
    /// Each body's mass matrix inverted once per polish ([`MassFactor`]).
    factors: Vec<MassFactor>,
    /// `Σ W p` per body.
    wrench_sum: Vec<[f64; 6]>,
    /// The friction wrenches each contact's friction currently acts through, per side.
    current: Vec<Vec<BodyFriction>>,
    /// The impulses before a sweep, in the order [`settled`] reads them.
    before: Vec<f64>,
    /// The impulses before the sweep before, in the same order ([`StepQp::extrapolate`]).
    previous: Vec<f64>,
    /// The impulses one sweep before `previous`, in the same order (the two-mode
    /// extrapolation, [`two_mode_coefficients`]).
    earlier: Vec<f64>,
    /// Each contact's multiplier `η` of its local friction problem at the last sweep (0 before
    /// the first, or when it stuck): the next sweep's Newton iteration starts there
    /// ([`local_friction`]).
    etas: Vec<f64>,
    normal: NormalWorkspace,
    joint: JointWorkspace,
}

/// Storage of [`StepQp::joint_step`]'s Newton iterations: the Delassus matrix and the
/// Jacobian column-major (as [`linalg::DenseLu`] takes them), the rows' values, the residual
/// (then the Newton step) and the LU's workspace, made again only when the size changes.
#[derive(Default)]
struct JointWorkspace {
    kmat: Vec<f64>,
    jac: Vec<f64>,
    v: Vec<f64>,
    step: Vec<f64>,
    lu: Option<linalg::DenseLu>,
}

/// Storage of [`StepQp::correct_normal_impulses`].
#[derive(Default)]
struct NormalWorkspace {
    groups: Groups,
    /// Per group (as `groups` lists them): what stays the same over one polish's sweeps.
    cache: Vec<GroupCache>,
    active: Vec<bool>,
    rates: Vec<f64>,
    nu: Vec<(usize, [f64; 6])>,
    loaded: Vec<usize>,
    pairs: Vec<(usize, usize)>,
}

/// What one group's normal correction computes the same at every sweep of a polish: the QP's
/// rows, the mass matrices and so the vertices' wrenches are fixed for the polish, and the
/// Delassus matrix of a loaded set depends on nothing else. Kept from the polish's first sweep
/// (`fresh`) on; the factorisation is kept for the last loaded set, which the desk's sweeps
/// keep from the first to the last (the same operations on the same numbers: the answers are
/// bitwise those of factoring at every sweep).
#[derive(Default)]
struct GroupCache {
    /// Whether `vertices`, `w` and `minv_w` hold this polish's values.
    ready: bool,
    /// (contact, position in the contact's vertex list) of every vertex of the group.
    vertices: Vec<(usize, usize)>,
    /// The wrenches of each vertex on each body of the group, and `M⁻¹` times them.
    w: Vec<VertexWrenches>,
    minv_w: Vec<VertexWrenches>,
    /// The loaded set `range` factors (indices into `vertices`), when `factored`.
    range_for: Vec<usize>,
    factored: bool,
    range: Option<PsdRange>,
}

/// The bodies coupled by contacts ([`StepQp::groups`]): the first `len` lists of `list` (the
/// lists after them are kept for their storage).
#[derive(Default)]
struct Groups {
    root: Vec<usize>,
    index: Vec<usize>,
    list: Vec<Vec<usize>>,
    len: usize,
}

/// A vertex's wrenches on the bodies it acts on: F, and G when G is dynamic (two at most,
/// [`normal_sides`]), kept inline.
#[derive(Clone, Copy, Default)]
struct VertexWrenches {
    len: usize,
    sides: [(usize, [f64; 6]); 2],
}

impl VertexWrenches {
    fn iter(&self) -> std::slice::Iter<'_, (usize, [f64; 6])> {
        self.sides[..self.len].iter()
    }
}

impl FromIterator<(usize, [f64; 6])> for VertexWrenches {
    fn from_iter<I: IntoIterator<Item = (usize, [f64; 6])>>(iter: I) -> Self {
        let mut out = VertexWrenches::default();
        for side in iter {
            // At most two sides by construction (`normal_sides`): an index past them panics.
            out.sides[out.len] = side;
            out.len += 1;
        }
        out
    }
}

impl<'a> IntoIterator for &'a VertexWrenches {
    type Item = &'a (usize, [f64; 6]);
    type IntoIter = std::slice::Iter<'a, (usize, [f64; 6])>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

/// Friction wrenches `W_t, W_o, W_r` of a contact at its current ECP.
fn friction_wrenches(g: &ContactGeometry) -> [[f64; 6]; 3] {
    friction_wrenches_about(g, &g.center_of_mass)
}

/// [`friction_wrenches`] on a body whose centre of mass is `center` (the partner of a contact).
fn friction_wrenches_about(g: &ContactGeometry, center: &[f64; 3]) -> [[f64; 6]; 3] {
    let arm = sub(&g.ecp, center);
    [
        wrench(&g.tangent, &arm),
        wrench(&g.bitangent, &arm),
        [0.0, 0.0, 0.0, g.normal[0], g.normal[1], g.normal[2]],
    ]
}

/// The dynamic body G of a contact between two bodies, with its centre of mass.
fn dynamic_partner(g: &ContactGeometry) -> Option<(usize, [f64; 3])> {
    match g.partner {
        ContactPartner::Body {
            body,
            center_of_mass,
        } => Some((body, center_of_mass)),
        _ => None,
    }
}

/// `−w` (G's share of an equal and opposite impulse).
fn negated(w: [f64; 6]) -> [f64; 6] {
    w.map(|v| -v)
}

/// The wrenches of patch vertex `v` of contact `g` on each body it acts on: `(F, W_{n,j})` and,
/// for a dynamic G, `(G, −[n; (v_G − x_G) × n])` at G's point of the vertex.
fn normal_sides(g: &ContactGeometry, v: &PatchVertex) -> VertexWrenches {
    let mut out = VertexWrenches {
        len: 1,
        sides: [
            (
                g.body,
                wrench(&g.normal, &sub(&v.position, &g.center_of_mass)),
            ),
            (0, [0.0; 6]),
        ],
    };
    if let Some((b, x)) = dynamic_partner(g) {
        out.sides[1] = (b, negated(wrench(&g.normal, &sub(&v.partner_position, &x))));
        out.len = 2;
    }
    out
}

/// A body and the friction wrenches `W_t, W_o, W_r` of a contact on it.
pub(crate) type BodyFriction = (usize, [[f64; 6]; 3]);

/// The friction wrenches of contact `g` at its ECP on each body it acts on (F's, and G's
/// opposite ones for a dynamic G) into `out` (cleared first: storage kept by the caller), and
/// the data part of the relative slip (a G with prescribed velocity,
/// `docs/model.md#friction-on-the-relative-velocity`).
fn friction_sides_into(g: &ContactGeometry, out: &mut Vec<BodyFriction>) -> [f64; 3] {
    out.clear();
    out.push((g.body, friction_wrenches(g)));
    let mut offset = [0.0; 3];
    match g.partner {
        ContactPartner::HalfSpace => {}
        ContactPartner::Body {
            body,
            center_of_mass,
        } => out.push((
            body,
            friction_wrenches_about(g, &center_of_mass).map(negated),
        )),
        ContactPartner::Prescribed {
            velocity,
            center_of_mass,
        } => {
            let w = friction_wrenches_about(g, &center_of_mass);
            for i in 0..3 {
                offset[i] = -dot6(&w[i], &velocity);
            }
        }
    }
    offset
}

/// Whether every body contact `g` acts on exists.
fn bodies_exist(g: &ContactGeometry, num_bodies: usize) -> bool {
    g.body < num_bodies && dynamic_partner(g).is_none_or(|(b, _)| b < num_bodies && b != g.body)
}

/// The De Saxcé shift `μ ‖E u_T‖` of contact `g` at the velocities `nu` of every body (the slip
/// of F relative to G).
/// `sides` is storage for the contact's friction sides (kept by the caller: a warm step
/// allocates nothing here).
pub(crate) fn de_saxce_shift_with(
    g: &ContactGeometry,
    nu: &[[f64; 6]],
    sides: &mut Vec<BodyFriction>,
) -> f64 {
    let f = g.friction;
    let axes = [f.e_t, f.e_o, f.e_r];
    let offset = friction_sides_into(g, sides);
    let slip: f64 = (0..3)
        .map(|i| {
            let u = sides
                .iter()
                .map(|(b, w)| dot6(&w[i], nu.get(*b).unwrap_or(&[0.0; 6])))
                .sum::<f64>()
                + offset[i];
            (axes[i] * u).powi(2)
        })
        .sum::<f64>()
        .sqrt();
    f.mu * slip
}

/// The proximal anchor of the contacts of bodies with several contacts (see the module doc).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Anchor<'a> {
    /// `ρ_m` relative to the body's mean angular mobility `mean_i 1/M_{ωω,ii}`: weight of the
    /// centre-of-pressure anchor. 0 disables the anchor.
    pub moment: f64,
    /// `ρ_n` relative to the contact's normal mobility `W_n(e)ᵀM⁻¹W_n(e)`: weight of the load
    /// anchor.
    pub load: f64,
    /// The previous iterate's normal impulse `p_{n,c}^k` of every contact; at the first
    /// iteration the warm start's when it nearly solves the step (`conic/mod.rs`,
    /// `WARM_LOADS_RESIDUAL`), otherwise `None`: the load anchor is then a Tikhonov term towards
    /// 0, which picks another member of a non-unique set of loads.
    pub previous_loads: Option<&'a [f64]>,
}

/// Which contacts are anchored: those with a patch on a body (F, or a dynamic G) that has at
/// least two of them.
#[cfg(test)]
pub(crate) fn anchored_contacts(geometry: &[ContactGeometry], num_bodies: usize) -> Vec<bool> {
    let mut out = Vec::new();
    anchored_contacts_into(geometry, num_bodies, &mut Vec::new(), &mut out);
    out
}

/// [`anchored_contacts`] into `out`, with `per_body` the count of patches per body (both
/// cleared first: storage the caller keeps, so that a warm step allocates neither).
pub(crate) fn anchored_contacts_into(
    geometry: &[ContactGeometry],
    num_bodies: usize,
    per_body: &mut Vec<usize>,
    out: &mut Vec<bool>,
) {
    per_body.clear();
    per_body.resize(num_bodies, 0);
    for g in geometry {
        if !g.patch.is_empty() && g.body < num_bodies {
            per_body[g.body] += 1;
            if let Some((b, _)) = dynamic_partner(g).filter(|(b, _)| *b < num_bodies) {
                per_body[b] += 1;
            }
        }
    }
    out.clear();
    out.extend(geometry.iter().map(|g| {
        !g.patch.is_empty()
            && g.body < num_bodies
            && (per_body[g.body] >= 2
                || dynamic_partner(g).is_some_and(|(b, _)| b < num_bodies && per_body[b] >= 2))
    }));
}

/// Whether no body takes part in two of the contacts (as F, or as a dynamic G): then each
/// body's contact wrench is the QP's unique answer, and where a body has several contacts their
/// share of it need not be (a T-bar squeezed between the ground and a gripper's pad).
pub(crate) fn one_contact_per_body(geometry: &[ContactGeometry]) -> bool {
    let bodies = |g: &ContactGeometry| [Some(g.body), dynamic_partner(g).map(|(b, _)| b)];
    geometry.iter().enumerate().all(|(i, a)| {
        let ba = bodies(a);
        geometry[i + 1..].iter().all(|b| {
            let bb = bodies(b);
            !ba.iter()
                .flatten()
                .any(|x| bb.iter().flatten().any(|y| x == y))
        })
    })
}

/// Builds the subproblem at the trial point (geometry from `geometry`, trial velocities
/// `trial`) with the normal shift `shifts[c]` of every contact: the De Saxcé shift (exact
/// mode) or zero (Anitescu's relaxation); with `anchor`, the contacts of bodies with several
/// contacts get the proximal anchor of the module doc. The QP and its contact rows are built in
/// `storage` (emptied first; the solver hands back the last iteration's, so that its vectors,
/// the rows' among them, are refilled instead of allocated anew: same values, same order).
pub(crate) fn build(
    structure: &dyn StepStructure,
    bodies: &[BodyDynamics],
    trial: &[[f64; 6]],
    geometry: &[ContactGeometry],
    shifts: &[f64],
    anchor: Option<Anchor<'_>>,
    storage: StepQp,
) -> StepQp {
    let h = structure.step_length();
    let nb = bodies.len();
    // One friction variable `a` per loaded contact with friction, in contact order (counted,
    // not listed: a list per QP was one more allocation per outer iteration).
    let has_friction_var = |g: &ContactGeometry| !g.patch.is_empty() && g.friction.mu > 0.0;
    let friction_vars = geometry.iter().filter(|g| has_friction_var(g)).count();
    let mut friction_seen = 0;
    // Columns of the anchor variables (ξ_c, ζ_c) of each anchored contact.
    let anchor = anchor.filter(|a| a.moment > 0.0 && a.load > 0.0);
    let StepQp {
        mut qp,
        mut contacts,
        patch_vertices: _,
        mut spare,
        friction_sides: mut sides_of,
        mut weights,
        mut anchor_cols,
        mut coeffs,
        mut anchored,
        mut per_body,
    } = storage;
    // The previous QP's rows, whose vectors the new ones refill.
    spare.extend(contacts.drain(..).flatten());
    weights.clear();
    match anchor {
        Some(a) => {
            anchored_contacts_into(geometry, nb, &mut per_body, &mut anchored);
            weights.extend(anchored.iter().zip(geometry).map(|(&anchored, g)| {
                if !anchored {
                    return None;
                }
                let m = &bodies[g.body].mass;
                let angular = (3..6).map(|i| 1.0 / m[i][i]).sum::<f64>() / 3.0;
                let we = wrench(&g.normal, &sub(&g.ecp, &g.center_of_mass));
                let normal = dot6(&we, &solve6(m, &we));
                let (rho_m, rho_n) = (a.moment * angular, a.load * normal);
                (rho_m > 0.0 && rho_m.is_finite() && rho_n > 0.0 && rho_n.is_finite())
                    .then_some((rho_m, rho_n))
            }));
        }
        None => weights.resize(geometry.len(), None),
    }
    let mut next_col = 6 * nb + friction_vars;
    anchor_cols.clear();
    anchor_cols.extend(weights.iter().map(|w| {
        w.map(|_| {
            next_col += 3;
            next_col - 3
        })
    }));
    qp.reset(next_col);
    for (b, body) in bodies.iter().enumerate() {
        for i in 0..6 {
            for j in i..6 {
                qp.add_p(6 * b + i, 6 * b + j, body.mass[i][j]);
            }
            let mv: f64 = (0..6)
                .map(|j| body.mass[i][j] * body.free_velocity[j])
                .sum();
            qp.q[6 * b + i] = -mv;
        }
    }
    let mut patch_vertices = 0;
    for (c, g) in geometry.iter().enumerate() {
        let a_col = has_friction_var(g).then(|| {
            friction_seen += 1;
            6 * nb + friction_seen - 1
        });
        if g.patch.is_empty() || !bodies_exist(g, nb) {
            contacts.push(None);
            continue;
        }
        let f = g.friction;
        let axes = [f.e_t, f.e_o, f.e_r];
        let slip_offset = friction_sides_into(g, &mut sides_of);
        let friction_sides = &sides_of;
        let s = shifts.get(c).copied().unwrap_or(0.0);
        let first_row = qp.rows();
        let (mut vertices, mut positions, mut gap_rates, mut sides) = match spare.pop() {
            Some(r) => (r.vertices, r.positions, r.gap_rates, r.sides),
            None => Default::default(),
        };
        vertices.clear();
        positions.clear();
        gap_rates.clear();
        // Each side's normal wrenches refilled below; its body and friction wrenches set here.
        sides.truncate(friction_sides.len());
        for (k, &(body, friction_wrenches)) in friction_sides.iter().enumerate() {
            if k == sides.len() {
                sides.push(Side {
                    body,
                    normal_wrenches: Vec::with_capacity(g.patch.len()),
                    friction_wrenches,
                });
            }
            let side = &mut sides[k];
            side.body = body;
            side.friction_wrenches = friction_wrenches;
            side.normal_wrenches.clear();
        }
        for v in &g.patch {
            let ws = normal_sides(g, v);
            coeffs.clear();
            coeffs.extend(
                ws.iter()
                    .flat_map(|(b, w)| (0..6).map(move |i| (6 * b + i, -w[i]))),
            );
            if let Some(a) = a_col {
                coeffs.push((a, f.mu));
            }
            if let Some(col) = anchor_cols[c] {
                // + b_jᵀξ_c + ζ_c (the row is s = b − A x).
                let arm = sub(&v.position, &g.ecp);
                coeffs.push((col, -dot3(&arm, &g.tangent)));
                coeffs.push((col + 1, -dot3(&arm, &g.bitangent)));
                coeffs.push((col + 2, -1.0));
            }
            let mut rate = v.gap / h;
            for (b, w) in &ws {
                rate -= dot6(w, &trial[*b]);
            }
            qp.push_row(&coeffs, rate + s);
            gap_rates.push(rate);
            vertices.push(v.index);
            positions.push(v.position);
            for (side, (_, w)) in sides.iter_mut().zip(ws.iter()) {
                side.normal_wrenches.push(*w);
            }
        }
        if let (Some(col), Some((rho_m, rho_n)), Some(a)) = (anchor_cols[c], weights[c], anchor) {
            qp.add_p(col, col, 1.0 / rho_m);
            qp.add_p(col + 1, col + 1, 1.0 / rho_m);
            qp.add_p(col + 2, col + 2, 1.0 / rho_n);
            qp.q[col + 2] = a
                .previous_loads
                .and_then(|p| p.get(c))
                .copied()
                .unwrap_or(0.0);
        }
        qp.cones.push(Cone::Nonnegative(g.patch.len()));
        patch_vertices += g.patch.len();
        let soc_row = a_col.map(|a| {
            let r0 = qp.push_row(&[(a, -1.0)], 0.0);
            for i in 0..3 {
                coeffs.clear();
                coeffs.extend(
                    friction_sides
                        .iter()
                        .flat_map(|(b, w)| (0..6).map(move |k| (6 * b + k, -axes[i] * w[i][k]))),
                );
                // The data part of the relative slip (a G moved by its schedule).
                qp.push_row(&coeffs, axes[i] * slip_offset[i]);
            }
            qp.cones.push(Cone::SecondOrder(4));
            r0
        });
        contacts.push(Some(ContactRows {
            sides,
            vertices,
            first_row,
            gap_rates,
            slip_offset,
            axes,
            soc_row,
            mu: f.mu,
            positions,
            // Field by field: `..g.clone()` would copy the patch only to drop it.
            frame: ContactGeometry {
                body: g.body,
                normal: g.normal,
                tangent: g.tangent,
                bitangent: g.bitangent,
                center_of_mass: g.center_of_mass,
                gap: g.gap,
                patch: Vec::new(),
                ecp: g.ecp,
                friction: g.friction,
                partner: g.partner,
            },
            anchor: weights[c].map(|(rho_m, rho_n)| {
                let previous = anchor
                    .and_then(|a| a.previous_loads)
                    .and_then(|p| p.get(c))
                    .copied()
                    .unwrap_or(0.0);
                (rho_m, rho_n, previous)
            }),
        }));
    }
    StepQp {
        qp,
        contacts,
        patch_vertices,
        spare,
        friction_sides: sides_of,
        weights,
        anchor_cols,
        coeffs,
        anchored,
        per_body,
    }
}

impl StepQp {
    /// The QP's shape as [`StepQp::extract_into`] reads an answer (variables, rows, and each
    /// contact's vertex rows, their hull vertices and its cone), into `out`: an answer of a QP
    /// with the same layout can be read as if it were this QP's (the outer iteration's reuse of
    /// the previous QP's answer, `conic/mod.rs`).
    pub fn layout_into(&self, out: &mut Vec<usize>) {
        out.clear();
        out.push(self.qp.n);
        out.push(self.qp.rows());
        for rows in &self.contacts {
            match rows {
                None => out.push(usize::MAX),
                Some(r) => {
                    out.push(r.first_row);
                    out.push(r.soc_row.unwrap_or(usize::MAX));
                    out.push(r.vertices.len());
                    out.extend_from_slice(&r.vertices);
                }
            }
        }
    }

    /// Whether no body takes part in two of the QP's contacts (the polish's loads are then
    /// unique but for coplanar vertices of one contact; [`one_contact_per_body`] on the rows).
    fn one_contact_per_body(&self) -> bool {
        let rows: &[Option<ContactRows>] = &self.contacts;
        rows.iter().enumerate().all(|(i, a)| {
            let Some(a) = a else { return true };
            rows[i + 1..].iter().flatten().all(|b| {
                !a.sides
                    .iter()
                    .any(|sa| b.sides.iter().any(|sb| sa.body == sb.body))
            })
        })
    }

    /// Whether some contact has the proximal anchor (a body with several loaded contacts).
    pub fn anchored(&self) -> bool {
        self.contacts
            .iter()
            .any(|r| r.as_ref().is_some_and(|r| r.anchor.is_some()))
    }

    /// Reads velocities and impulses from clarabel's solution.
    ///
    /// The interior-point solution is read consistently with the complementarity it
    /// approximates, so that the accuracy of the mapped-back point is set by the fixed point and
    /// not by the interior-point method's stopping tolerance:
    /// - of each complementary pair (`λ_j`, vertex slack) the smaller entry is zero (active-set
    ///   identification), so the ECP lies exactly on the loaded feature;
    /// - friction: with the normal impulses fixed, each contact's friction impulse is the exact
    ///   solution of its local maximum-dissipation problem (the per-contact problem of the
    ///   Acary–Cadoux / NSGS literature), `min ½ pᵀA p + u₀ᵀp` over the ellipsoid
    ///   `‖E⁻¹p‖ ≤ μ p_n`, `A = W_fᵀM⁻¹W_f`, `u₀` the slip without this contact's friction
    ///   ([`local_friction`]), in Gauss–Seidel sweeps (normal correction, then each contact's
    ///   friction) until they settle, starting from the QP's dual or, for the outer loop's reuse,
    ///   from the previous QP's polished impulses ([`PolishStart`]; sweeps still unsettled after
    ///   [`JOINT_AFTER`] try a joint Newton step on the coupled conditions,
    ///   [`StepQp::joint_step`], which the next sweeps confirm; where every body has one
    ///   contact, sweeps along one mode are extrapolated by Aitken's rule,
    ///   [`StepQp::extrapolate`], and, after [`TWO_MODE_AFTER`] plain sweeps, along two,
    ///   [`two_mode_coefficients`]); it sticks with `u_T = 0`
    ///   exactly or slides with `p_f = −μ p_n E² u_T / ‖E u_T‖` exactly
    ///   (`docs/model.md#friction`); every contact's friction acts at the centre of pressure of
    ///   its corrected normal impulses (the ECP of the assembled point) rather than at the ECP
    ///   the QP was built at: otherwise the ECP lags one outer iteration behind the impulses, the
    ///   fixed point's slowest mode (the desk: 5 QPs per step instead of 2);
    /// - the velocities are recomputed from the impulses by the Newton–Euler equations,
    ///   `ν = ν_free + M⁻¹ Σ W p`, so that the dynamics hold to round-off.
    ///
    /// At a fixed point of the outer iteration these readings coincide with the QP's solution.
    ///
    /// Without `polish` (Anitescu's relaxation, or to measure the plain fixed point) the
    /// impulses are clarabel's duals as they are (only the active-set identification of `λ`).
    ///
    /// The point is written into `out`, whose vectors (the velocities, the contacts and each
    /// contact's vertex impulses) are refilled, not allocated anew.
    ///
    /// Returns whether the sweeps settled (`true` without `polish`): `false` when they ran to
    /// [`MAX_SWEEPS`] unsettled, as they do where the friction's centre of pressure and its
    /// direction chase each other (a table spinning about a point near its centre of
    /// pressure, `docs/latency.md`, wip-conic134), or, with `stop_circling` (the caller
    /// finishes an unsettled point by Newton at once), when they stopped because they circle
    /// ([`Circling`]: 15–20 sweeps instead of the cap's 50 there, wip-conicrob).
    ///
    /// `max_sweeps` caps the sweeps ([`MAX_SWEEPS`] but for the outer loop's trial of the
    /// previous solve's impulses, which gives up sooner and solves the QP instead).
    #[allow(clippy::too_many_arguments)]
    pub fn extract_into(
        &self,
        start: PolishStart<'_>,
        bodies: &[BodyDynamics],
        polish: bool,
        stop_circling: bool,
        max_sweeps: usize,
        work: &mut PolishWorkspace,
        out: &mut ConicPoint,
    ) -> bool {
        let nb = bodies.len();
        let ConicPoint {
            velocities,
            contacts,
        } = out;
        // Each contact's kept vertex impulses, refilled below in contact order.
        contacts.truncate(self.contacts.len());
        let PolishWorkspace {
            factors,
            wrench_sum,
            current,
            before,
            previous,
            earlier,
            etas,
            normal,
            joint,
        } = work;
        // Each body's mass matrix inverted once for the whole polish.
        factors.clear();
        factors.extend(bodies.iter().map(|b| MassFactor::new(&b.mass)));
        wrench_sum.clear();
        wrench_sum.resize(nb, [0.0f64; 6]);
        for (c, rows) in self.contacts.iter().enumerate() {
            if c == contacts.len() {
                contacts.push(ContactImpulses::default());
            }
            let imp = &mut contacts[c];
            let mut vertex_impulses = std::mem::take(&mut imp.vertex_impulses);
            vertex_impulses.clear();
            let Some(rows) = rows else {
                *imp = ContactImpulses {
                    vertex_impulses,
                    ..ContactImpulses::default()
                };
                continue;
            };
            for (k, &j) in rows.vertices.iter().enumerate() {
                let l = match start {
                    PolishStart::Qp(result) => {
                        let row = rows.first_row + k;
                        if result.z[row] > result.s[row] {
                            result.z[row]
                        } else {
                            0.0
                        }
                    }
                    PolishStart::Impulses(previous) => previous
                        .get(c)
                        .and_then(|p| p.vertex_impulses.get(k))
                        .map_or(0.0, |&(_, l)| l),
                };
                vertex_impulses.push((j, l));
                for side in &rows.sides {
                    let w = &side.normal_wrenches[k];
                    for i in 0..6 {
                        wrench_sum[side.body][i] += l * w[i];
                    }
                }
            }
            let mut friction = [0.0; 3];
            if let Some(r0) = rows.soc_row {
                for i in 0..3 {
                    friction[i] = match start {
                        PolishStart::Qp(result) => rows.axes[i] * result.z[r0 + 1 + i],
                        PolishStart::Impulses(previous) => {
                            previous.get(c).map_or(0.0, |p| p.friction[i])
                        }
                    };
                    for side in &rows.sides {
                        for k in 0..6 {
                            wrench_sum[side.body][k] += friction[i] * side.friction_wrenches[i][k];
                        }
                    }
                }
            }
            contacts[c] = ContactImpulses {
                vertex_impulses,
                friction,
                sigma: 0.0,
                normal: rows.frame.normal,
            };
        }
        // The Gauss–Seidel sweeps go on until they settle (MAX_SWEEPS at most): a fixed number
        // leaves a remainder that depends on where they start, i.e. on which QP method produced
        // the duals, and the outer fixed point then converges to a point off the step's solution
        // by that remainder (`a5_drop_tilted` step 16: a loaded vertex 1.2e-12 m deep, natural
        // residual 1.23e-10 > 1e-10, with the dense QPs; `docs/latency.md#conic-backend`).
        let sweeps = if polish { max_sweeps } else { 0 };
        // The friction wrenches each contact's friction currently acts through, per side.
        current.resize_with(self.contacts.len(), Vec::new);
        for (sides, r) in current.iter_mut().zip(&self.contacts) {
            sides.clear();
            if let Some(r) = r {
                sides.extend(r.sides.iter().map(|s| (s.body, s.friction_wrenches)));
            }
        }
        // Plain sweeps since the start or the last extrapolation (`previous` holds the impulses
        // before the sweep before when it is at least 2, `earlier` the ones before those when it
        // is at least 3). Only where every body has one
        // contact, as the desk: with several the loads need not be unique, and which member
        // the sweeps reach depends on their path.
        let mut plain = 0;
        // Whether the sweeps ran to their cap without settling (none asked: settled).
        let mut unsettled = polish;
        let extrapolating = self.one_contact_per_body();
        etas.clear();
        etas.resize(self.contacts.len(), 0.0);
        let mut circling = Circling::default();
        for sweep in 0..sweeps {
            std::mem::swap(earlier, previous);
            std::mem::swap(previous, before);
            before.clear();
            for c in contacts.iter() {
                before.extend(impulse_values(c));
            }
            self.correct_normal_impulses(bodies, factors, contacts, wrench_sum, normal, sweep == 0);
            for (c, (rows, imp)) in self.contacts.iter().zip(contacts.iter_mut()).enumerate() {
                let Some(rows) = rows else { continue };
                if rows.soc_row.is_none() {
                    continue;
                }
                // Remove this contact's friction, then solve its local problem with the friction
                // acting at the centre of pressure of the normal impulses (the ECP a1 of the point
                // that is assembled, `docs/model.md#newton-euler`, `docs/model.md#friction`), which
                // may differ from the ECP the QP was built at until the fixed point converges.
                for (b, wf) in &current[c] {
                    for i in 0..3 {
                        for k in 0..6 {
                            wrench_sum[*b][k] -= imp.friction[i] * wf[i][k];
                        }
                    }
                }
                let mut offset = rows.slip_offset;
                if let Some(cop) = rows.centre_of_pressure(&imp.vertex_impulses) {
                    offset = friction_sides_into(
                        &ContactGeometry {
                            ecp: cop,
                            patch: Vec::new(),
                            ..rows.frame.clone()
                        },
                        &mut current[c],
                    );
                }
                // The local problem on the slip of F relative to G: the Delassus matrix and the
                // slip without this friction summed over the bodies it acts on.
                let mut a = [[0.0; 3]; 3];
                let mut u0 = [0.0; 3];
                for (b, wf) in &current[c] {
                    let body = &bodies[*b];
                    let dv = factors[*b].solve(&wrench_sum[*b]);
                    let mut nu0 = body.free_velocity;
                    for k in 0..6 {
                        nu0[k] += dv[k];
                    }
                    let minv_w: [[f64; 6]; 3] = std::array::from_fn(|j| factors[*b].solve(&wf[j]));
                    for i in 0..3 {
                        u0[i] += dot6(&wf[i], &nu0);
                        for j in 0..3 {
                            a[i][j] += dot6(&wf[i], &minv_w[j]);
                        }
                    }
                }
                for i in 0..3 {
                    u0[i] += offset[i];
                }
                let pn: f64 = imp.vertex_impulses.iter().map(|(_, l)| l).sum();
                let (p, sigma, eta) = local_friction(&a, &u0, &rows.axes, rows.mu * pn, etas[c]);
                etas[c] = eta;
                imp.friction = p;
                imp.sigma = sigma;
                for (b, wf) in &current[c] {
                    for i in 0..3 {
                        for k in 0..6 {
                            wrench_sum[*b][k] += p[i] * wf[i][k];
                        }
                    }
                }
            }
            // Not measured on the first two sweeps (they never count as settled, and the
            // circling test starts later).
            let (change, scale) = if sweep >= 2 {
                impulse_change(before, contacts)
            } else {
                (f64::INFINITY, 0.0)
            };
            if change <= SETTLED * scale {
                unsettled = false;
                break;
            }
            // Sweeps that circle (no smaller change in the last CIRCLE_WINDOW sweeps than half
            // the smallest before them) will not settle by the cap; where the caller finishes
            // such a point by Newton at once, the remaining sweeps are wasted.
            // Out of line, from CIRCLE_FROM on: the desk's polishes settle by sweep 12 and pay
            // for the test only a branch per sweep and a call per sweep past CIRCLE_FROM.
            if stop_circling && sweep >= CIRCLE_FROM && circling.record(sweep, change, scale) {
                break;
            }
            // Sweeps that have not settled by now contract slowly (a steep two-support wedge at
            // μ = 1.18: about 0.85 per sweep, `docs/latency.md#conic-backend`): settle the coupled
            // problem by Newton's method on its active set, which the next sweeps confirm.
            // The joint step after JOINT_AFTER sweeps in a row neither extrapolated nor joint
            // (without extrapolation: after sweeps 10, 20, ...).
            plain += 1;
            if plain >= JOINT_AFTER {
                self.joint_step(bodies, factors, contacts, wrench_sum, current, joint);
                plain = 0;
            } else if extrapolating
                && plain >= 2
                && (self.extrapolate(previous, before, contacts, wrench_sum, current)
                    || (plain >= TWO_MODE_AFTER
                        && self.extrapolate_two_modes(
                            earlier, previous, before, contacts, wrench_sum, current,
                        )))
            {
                plain = 0;
            }
        }
        velocities.clear();
        velocities.extend(bodies.iter().enumerate().map(|(b, body)| {
            let dv = factors[b].solve(&wrench_sum[b]);
            let mut nu = body.free_velocity;
            for i in 0..6 {
                nu[i] += dv[i];
            }
            nu
        }));
        if !polish {
            // σ = ‖E u_T‖ at the new velocities (the relaxation's slip).
            for (rows, imp) in self.contacts.iter().zip(contacts.iter_mut()) {
                if let Some(rows) = rows {
                    imp.sigma = (0..3)
                        .map(|i| {
                            let u = rows
                                .sides
                                .iter()
                                .map(|s| dot6(&s.friction_wrenches[i], &velocities[s.body]))
                                .sum::<f64>()
                                + rows.slip_offset[i];
                            (rows.axes[i] * u).powi(2)
                        })
                        .sum::<f64>()
                        .sqrt();
                }
            }
        }
        !unsettled
    }
}

/// Where [`StepQp::extract_into`] starts: a QP's answer, or the impulses of a point polished against a
/// QP of the same layout ([`StepQp::layout_into`]), in contact and vertex-row order.
#[derive(Clone, Copy)]
pub(crate) enum PolishStart<'a> {
    Qp(&'a QpResult),
    Impulses(&'a [ContactImpulses]),
}

/// Gauss–Seidel sweeps of the polish at most.
pub(crate) const MAX_SWEEPS: usize = 50;

/// Largest contraction per sweep at which the polish extrapolates its sweeps ([`StepQp::extrapolate`]).
const EXTRAPOLATE_RATE: f64 = 0.5;

/// How far the last sweep's change may lie off the line of the change before it, relative to
/// its size, for the polish to extrapolate: the sweeps then follow one mode.
const EXTRAPOLATE_ALIGNMENT: f64 = 5e-2;

/// Plain sweeps in a row after which the polish, where Aitken's one-mode extrapolation does not
/// apply, tries the two-mode one ([`two_mode_coefficients`]; it needs three changes). At 6 the
/// desk's polishes, which settle or extrapolate along one mode sooner, are untouched (at 3–5 the
/// two-mode extrapolation takes some of their sweeps and the desk's digest changes).
const TWO_MODE_AFTER: usize = 6;

/// Largest modulus of a root of the two-mode recurrence ([`two_mode_coefficients`]). The
/// extrapolation needs no contraction (it solves the linear model), but sweeps that grow fast
/// have left the region where the model holds. `056_union_slide` (seed 20270116) needs more
/// than 1.2 (its sweeps grow by up to 1.07); 1.3, 1.5, 2 and no bound give the same.
const TWO_MODE_RATE: f64 = 1.5;

/// Smallest `1 − a − b = (1 − λ₁)(1 − λ₂)` of the two-mode recurrence: its inverse is the
/// extrapolation's gain on the last changes, kept at most 4 (a mode near 1 is left to the
/// sweeps, as [`EXTRAPOLATE_RATE`] does for one mode).
const TWO_MODE_DISTANCE: f64 = 0.25;

/// Unsettled sweeps in a row, none extrapolated, after which the polish tries a joint Newton step
/// ([`StepQp::joint_step`]). The desk's polishes settle in 12 from a QP's duals (about 0.1 per
/// sweep; its four loaded vertices refuse the joint step; 7 or 8 with [`StepQp::extrapolate`])
/// and in 3 from the previous polish's impulses.
const JOINT_AFTER: usize = 10;

/// Newton iterations of a joint step at most.
const JOINT_ITERATIONS: usize = 12;

/// Relative size of the last Newton step at which a joint step has converged.
const JOINT_SETTLED: f64 = 1e-14;

/// An unloaded vertex joins the polish's active set when its gap rate is below `−VIOLATION`
/// times the largest gap rate of its group (at least 1 m/s): far above the round-off of the
/// corrected rows, far below the `135_union_tip` violation (−0.068 m/s).
const VIOLATION: f64 = 1e-9;

/// Relative change of the impulses below which the polish's sweeps have settled.
const SETTLED: f64 = 1e-12;

/// A contact's impulses as [`settled`] compares them: the vertices' `λ`, then the friction.
fn impulse_values(c: &ContactImpulses) -> impl Iterator<Item = f64> + '_ {
    c.vertex_impulses.iter().map(|(_, l)| *l).chain(c.friction)
}

/// A polish sweep's largest change of an impulse and the largest impulse after it (`before`:
/// the [`impulse_values`] of every contact before the sweep, in order); the sweeps have settled
/// when the change is at most `SETTLED` times the largest impulse.
fn impulse_change(before: &[f64], after: &[ContactImpulses]) -> (f64, f64) {
    let mut scale: f64 = 0.0;
    let mut change: f64 = 0.0;
    for (x, y) in before.iter().zip(after.iter().flat_map(impulse_values)) {
        scale = scale.max(y.abs());
        change = change.max((x - y).abs());
    }
    (change, scale)
}

/// The circling test of the polish's sweeps ([`StepQp::extract_into`]'s `stop_circling`): the
/// sweeps' relative changes of the last [`CIRCLE_WINDOW`] sweeps (by sweep number modulo the
/// window) and the smallest one before them, from sweep [`CIRCLE_FROM`] on.
struct Circling {
    recent: [f64; CIRCLE_WINDOW],
    earlier_smallest: f64,
}

impl Default for Circling {
    fn default() -> Self {
        Circling {
            recent: [f64::INFINITY; CIRCLE_WINDOW],
            earlier_smallest: f64::INFINITY,
        }
    }
}

impl Circling {
    /// Records sweep `sweep`'s largest change `change` of an impulse, the largest impulse being
    /// `scale` ([`impulse_change`]), and says whether the sweeps circle: no change in the last
    /// [`CIRCLE_WINDOW`] sweeps below [`CIRCLE_RATIO`] times the smallest of the (at least
    /// [`CIRCLE_EARLIER`]) recorded sweeps before them.
    #[inline(never)]
    fn record(&mut self, sweep: usize, change: f64, scale: f64) -> bool {
        if sweep < CIRCLE_FROM || scale.is_nan() || scale <= 0.0 || !change.is_finite() {
            return false;
        }
        let slot = sweep % CIRCLE_WINDOW;
        if sweep >= CIRCLE_FROM + CIRCLE_WINDOW {
            self.earlier_smallest = self.earlier_smallest.min(self.recent[slot]);
        }
        self.recent[slot] = change / scale;
        sweep + 1 >= CIRCLE_FROM + CIRCLE_WINDOW + CIRCLE_EARLIER
            && self
                .recent
                .iter()
                .all(|&r| r >= CIRCLE_RATIO * self.earlier_smallest)
    }
}

/// The first sweep whose change the circling test ([`StepQp::extract_into`]'s `stop_circling`)
/// records: the desk's polishes settle in 7–12 sweeps and pay for the record only past it.
const CIRCLE_FROM: usize = 5;

/// Sweeps of the circling test's recent window.
const CIRCLE_WINDOW: usize = 10;

/// Sweeps before the recent window that the circling test needs recorded (so the test first
/// runs at sweep `CIRCLE_FROM + CIRCLE_WINDOW + CIRCLE_EARLIER − 1`).
const CIRCLE_EARLIER: usize = 5;

/// The circling test's ratio: sweeps whose changes over the last window stayed at least this
/// fraction of the smallest change before it do not contract (a contraction of ρ per sweep
/// passes it for ρ^10 < 0.5, ρ < 0.93; slower ones would need more than the cap to settle).
const CIRCLE_RATIO: f64 = 0.5;

/// The factor `ρ/(1 − ρ)` of Aitken's extrapolation `x_{k+1} + ρ/(1 − ρ) d₂` of three
/// iterates `x_{k-1}, x_k, x_{k+1}` (`previous`, `before`, `after`), `d₁ = x_k − x_{k-1}`,
/// `d₂ = x_{k+1} − x_k`, when they contract along one mode: `ρ = ⟨d₁, d₂⟩/‖d₁‖²` in
/// `(0, `[`EXTRAPOLATE_RATE`]`]` and `‖d₂ − ρ d₁‖ ≤ `[`EXTRAPOLATE_ALIGNMENT`]` ‖d₂‖`; `None`
/// otherwise (or when the lengths differ).
fn one_mode_factor(
    previous: &[f64],
    before: &[f64],
    after: impl Iterator<Item = f64>,
) -> Option<f64> {
    let (mut d11, mut d12, mut d22) = (0.0, 0.0, 0.0);
    let mut count = 0;
    for ((&a, &b), y) in previous.iter().zip(before).zip(after) {
        let (d1, d2) = (b - a, y - b);
        d11 += d1 * d1;
        d12 += d1 * d2;
        d22 += d2 * d2;
        count += 1;
    }
    if count != before.len() || previous.len() != before.len() || d11 == 0.0 || d22 == 0.0 {
        return None;
    }
    let rate = d12 / d11;
    // ‖d₂ − ρ d₁‖² = ‖d₂‖² − ρ ⟨d₁, d₂⟩ at the least-squares ρ.
    let off = (d22 - rate * d12).max(0.0);
    (rate > 0.0
        && rate <= EXTRAPOLATE_RATE
        && off <= EXTRAPOLATE_ALIGNMENT * EXTRAPOLATE_ALIGNMENT * d22)
        .then(|| rate / (1.0 - rate))
}

/// The coefficients `(α, β)` of the two-mode extrapolation `x_{k+1} + α d₃ + β d₂` of four
/// iterates `x_{k-2}, …, x_{k+1}` (`earlier`, `previous`, `before`, `after`), `d₁ = x_{k-1} −
/// x_{k-2}`, `d₂ = x_k − x_{k-1}`, `d₃ = x_{k+1} − x_k`, when the changes follow one linear
/// recurrence `d₃ = a d₂ + b d₁` (least squares; the fit's remainder at most
/// [`EXTRAPOLATE_ALIGNMENT`] of `‖d₃‖`): the sweeps then move along two modes, the roots `λ` of
/// `λ² − a λ − b` (a rotating pair `r e^{±iθ}` where the normal correction of a table's four
/// legs and the friction at their moving centre of pressure chase each other, `056_union_slide`
/// of seed 20270116: `r` 0.95–1.07, a period of 4–5 sweeps, `docs/latency.md`, wip-conic10x).
/// Summing the recurrence over `n ≥ 3`, the changes to come add up to `S = ((a + b) d₃ + b
/// d₂)/(1 − a − b)`, so `α = (a + b)/(1 − a − b)`, `β = b/(1 − a − b)`: the fixed point of the
/// linear model, also where the sweeps do not contract (`r ≥ 1`), as long as no root is near 1.
/// `None` unless both roots have modulus at most [`TWO_MODE_RATE`] and `1 − a − b ≥`
/// [`TWO_MODE_DISTANCE`], or when `d₁`, `d₂` are (nearly) parallel (one mode: Aitken's) or the
/// lengths differ.
fn two_mode_coefficients(
    earlier: &[f64],
    previous: &[f64],
    before: &[f64],
    after: impl Iterator<Item = f64>,
) -> Option<(f64, f64)> {
    let (mut d11, mut d12, mut d22, mut d13, mut d23, mut d33) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut count = 0;
    for (((&x0, &x1), &x2), x3) in earlier.iter().zip(previous).zip(before).zip(after) {
        let (d1, d2, d3) = (x1 - x0, x2 - x1, x3 - x2);
        d11 += d1 * d1;
        d12 += d1 * d2;
        d22 += d2 * d2;
        d13 += d1 * d3;
        d23 += d2 * d3;
        d33 += d3 * d3;
        count += 1;
    }
    if count != before.len()
        || previous.len() != before.len()
        || earlier.len() != before.len()
        || d33 == 0.0
    {
        return None;
    }
    // The normal equations of min ‖d₃ − a d₂ − b d₁‖: [d₂·d₂ d₂·d₁; d₁·d₂ d₁·d₁] [a; b] = [d₂·d₃; d₁·d₃].
    let det = d22 * d11 - d12 * d12;
    if det.is_nan() || det <= 1e-8 * d22 * d11 {
        return None;
    }
    let a = (d23 * d11 - d13 * d12) / det;
    let b = (d22 * d13 - d12 * d23) / det;
    // The fit's remainder ‖d₃ − a d₂ − b d₁‖² = ‖d₃‖² − a d₂·d₃ − b d₁·d₃ at the least squares.
    let off = (d33 - a * d23 - b * d13).max(0.0);
    if off > EXTRAPOLATE_ALIGNMENT * EXTRAPOLATE_ALIGNMENT * d33 {
        return None;
    }
    let disc = a * a + 4.0 * b;
    let radius = if disc < 0.0 {
        (-b).sqrt()
    } else {
        0.5 * (a.abs() + disc.sqrt())
    };
    let distance = 1.0 - a - b;
    (radius <= TWO_MODE_RATE && distance >= TWO_MODE_DISTANCE && a.is_finite() && b.is_finite())
        .then(|| ((a + b) / distance, b / distance))
}

impl StepQp {
    /// The two-mode extrapolation of the polish's sweeps ([`two_mode_coefficients`]) where
    /// Aitken's one-mode one ([`StepQp::extrapolate`]) does not apply, on the same terms: not
    /// where a load would change sign or an unloaded vertex take load. Returns whether it moved
    /// the impulses.
    fn extrapolate_two_modes(
        &self,
        earlier: &[f64],
        previous: &[f64],
        before: &[f64],
        contacts: &mut [ContactImpulses],
        wrench_sum: &mut [[f64; 6]],
        current: &[Vec<BodyFriction>],
    ) -> bool {
        let after = contacts.iter().flat_map(impulse_values);
        let Some((alpha, beta)) = two_mode_coefficients(earlier, previous, before, after) else {
            return false;
        };
        let step_at = |i: usize, x: f64| alpha * (x - before[i]) + beta * (before[i] - previous[i]);
        self.move_impulses(step_at, before, contacts, wrench_sum, current)
    }

    /// Aitken's extrapolation of the polish's sweeps to the limit of their slowest mode.
    ///
    /// After sweeps `x_{k-1} → x_k → x_{k+1}` (`previous`, `before`, `contacts`) with changes
    /// `d₁ = x_k − x_{k-1}` and `d₂ = x_{k+1} − x_k`: when `d₂ = ρ d₁` up to
    /// [`EXTRAPOLATE_ALIGNMENT`] of `‖d₂‖`, with `0 < ρ ≤` [`EXTRAPOLATE_RATE`], the sweeps are
    /// contracting along one mode by `ρ` per sweep, and their limit is
    /// `x_{k+1} + ρ/(1 − ρ) d₂`. The desk's first polish of a step contracts so by about 0.1 per
    /// sweep from its third sweep on (the normal correction and the friction at the centre of
    /// pressure of the corrected loads, `docs/latency.md`), 12 sweeps to [`SETTLED`]. The
    /// impulses and their wrench sums move to the limit; the sweeps after it decide, by the
    /// same [`settled`] test, when the polish has settled. Not taken when a load would change
    /// sign or an unloaded vertex would take load (the active set stays the sweeps'), nor where
    /// a body has several contacts.
    /// Returns whether it moved the impulses.
    fn extrapolate(
        &self,
        previous: &[f64],
        before: &[f64],
        contacts: &mut [ContactImpulses],
        wrench_sum: &mut [[f64; 6]],
        current: &[Vec<BodyFriction>],
    ) -> bool {
        let after = contacts.iter().flat_map(impulse_values);
        let Some(factor) = one_mode_factor(previous, before, after) else {
            return false;
        };
        self.move_impulses(
            |i, x| factor * (x - before[i]),
            before,
            contacts,
            wrench_sum,
            current,
        )
    }

    /// Moves every impulse `x_i` (in [`impulse_values`] order) by `step_at(i, x_i)` and the
    /// wrench sums with it, for the polish's extrapolations; not at all, returning `false`,
    /// when a load would change sign or an unloaded vertex (zero in `before`) take load (the
    /// active set stays the sweeps').
    fn move_impulses(
        &self,
        step_at: impl Fn(usize, f64) -> f64,
        before: &[f64],
        contacts: &mut [ContactImpulses],
        wrench_sum: &mut [[f64; 6]],
        current: &[Vec<BodyFriction>],
    ) -> bool {
        let mut i = 0;
        for c in contacts.iter() {
            for &(_, l) in &c.vertex_impulses {
                let next = l + step_at(i, l);
                if (l > 0.0) != (next > 0.0) || (l == 0.0) != (before[i] == 0.0) {
                    return false;
                }
                i += 1;
            }
            i += 3;
        }
        let mut i = 0;
        for (c, (rows, imp)) in self.contacts.iter().zip(contacts.iter_mut()).enumerate() {
            for (k, entry) in imp.vertex_impulses.iter_mut().enumerate() {
                let step = step_at(i, entry.1);
                i += 1;
                let Some(rows) = rows else { continue };
                entry.1 += step;
                for side in &rows.sides {
                    let w = &side.normal_wrenches[k];
                    for j in 0..6 {
                        wrench_sum[side.body][j] += step * w[j];
                    }
                }
            }
            for f in 0..3 {
                let step = step_at(i, imp.friction[f]);
                i += 1;
                imp.friction[f] += step;
                for (b, wf) in &current[c] {
                    for j in 0..6 {
                        wrench_sum[*b][j] += step * wf[f][j];
                    }
                }
            }
        }
        true
    }
}

impl ContactRows {
    /// Centre of pressure of the normal impulses `(vertex index, λ)` of this contact (in row
    /// order); `None` without load.
    fn centre_of_pressure(&self, impulses: &[(usize, f64)]) -> Option<[f64; 3]> {
        let mut total = 0.0;
        let mut p = [0.0; 3];
        for (k, &(_, l)) in impulses.iter().enumerate() {
            let (Some(x), true) = (self.positions.get(k), l > 0.0) else {
                continue;
            };
            total += l;
            for i in 0..3 {
                p[i] += l * x[i];
            }
        }
        (total > 0.0 && total.is_finite()).then(|| p.map(|v| v / total))
    }
}

impl StepQp {
    /// Normal part of the active-set polish: with the friction impulses fixed, corrects the
    /// normal impulses of the loaded vertices (`λ_j > 0`) of each body by the minimum-norm step
    /// that makes their linearised gaps `g_j/h + W_{n,j}ᵀ(ν − ν^k)` vanish, where
    /// `ν = ν_free + M⁻¹ Σ W p`: the Delassus system `W_Jᵀ M⁻¹ W_J δλ = −gap` solved by a
    /// pseudo-inverse (four coplanar vertices make it singular; the ECP stays unique). A
    /// correction that would make some `λ_j` negative is scaled back to keep them ≥ 0.
    ///
    /// When the body has anchored contacts (several contacts, module doc), the correction is
    /// not the minimum-norm one but the one that minimises the anchor's penalty
    /// ([`StepQp::anchored_correction`]): the loaded vertices' gaps fix only the body's total
    /// normal wrench, and along the rest (load split, centres of pressure) the QP's own
    /// optimum is decided by the anchor alone, so the polish picks exactly that member instead
    /// of keeping the interior-point method's round-off in those directions.
    ///
    /// `fresh`: the polish's first sweep (the groups and [`GroupCache`] are made again).
    fn correct_normal_impulses(
        &self,
        bodies: &[BodyDynamics],
        factors: &[MassFactor],
        contacts: &mut [ContactImpulses],
        wrench_sum: &mut [[f64; 6]],
        work: &mut NormalWorkspace,
        fresh: bool,
    ) {
        let NormalWorkspace {
            groups,
            cache,
            active,
            rates,
            nu,
            loaded,
            pairs,
        } = work;
        if fresh {
            self.groups(bodies.len(), groups);
            if cache.len() < groups.len {
                cache.resize_with(groups.len, GroupCache::default);
            }
            for gc in cache.iter_mut() {
                gc.ready = false;
                gc.factored = false;
            }
        }
        for (group, gc) in groups.list[..groups.len].iter().zip(cache.iter_mut()) {
            let GroupCache {
                ready,
                vertices,
                w,
                minv_w,
                range_for,
                factored,
                range,
            } = gc;
            // (contact, position in the contact's vertex list) of every vertex of the group.
            if !*ready {
                vertices.clear();
                for (c, rows) in self.contacts.iter().enumerate() {
                    let Some(rows) = rows else { continue };
                    if !group.contains(&rows.sides[0].body) {
                        continue;
                    }
                    vertices.extend((0..contacts[c].vertex_impulses.len()).map(|k| (c, k)));
                }
            }
            // Whether each vertex is in the active set (loaded, or added below because it was
            // violated).
            active.clear();
            active.extend(
                vertices
                    .iter()
                    .map(|&(c, k)| contacts[c].vertex_impulses[k].1 > 0.0),
            );
            if !active.iter().any(|&a| a) {
                continue;
            }
            if !*ready {
                // The wrenches of each vertex on each body of the group.
                w.clear();
                w.extend(vertices.iter().filter_map(|&(c, k)| {
                    self.contacts[c].as_ref().map(|r| {
                        r.sides
                            .iter()
                            .map(|s| (s.body, s.normal_wrenches[k]))
                            .collect::<VertexWrenches>()
                    })
                }));
                minv_w.clear();
                minv_w.extend(w.iter().map(|ws| {
                    ws.iter()
                        .map(|(b, x)| (*b, factors[*b].solve(x)))
                        .collect::<VertexWrenches>()
                }));
                *ready = true;
            }
            if w.len() != vertices.len() {
                continue;
            }
            // Active-set loop (a primal active-set method on the Delassus LCP): correct the active
            // vertices' gaps; a vertex whose impulse would go negative blocks the step and leaves
            // the set; when the step is full, the most violated unloaded vertex (gap rate below
            // zero: the correction pushed it into its partner) joins it. Without it the loaded
            // vertices' correction may drive an unloaded vertex into the floor, a point the QP,
            // which keeps every vertex's row, never gives (`135_union_tip` step 94:
            // -0.068 m/s, `docs/latency.md#conic-backend`).
            let mut just_added: Option<usize> = None;
            // The rates at the current impulses: computed here, then after each full step (the
            // only way to the next pass of the loop).
            self.gap_rates(group, bodies, factors, wrench_sum, vertices, w, nu, rates);
            for _ in 0..2 * vertices.len() + 2 {
                loaded.clear();
                loaded.extend((0..vertices.len()).filter(|&i| active[i]));
                let k = loaded.len();
                if k == 0 {
                    break;
                }
                // The Delassus matrix of the loaded set: Σ over the bodies both vertices act on
                // of w_iᵀ M⁻¹ w_j.
                let delassus = || {
                    let mut d = Scratch::new(k * k);
                    for (a, &i) in loaded.iter().enumerate() {
                        for (b, &j) in loaded.iter().enumerate() {
                            for (bi, wi) in &w[i] {
                                for (bj, mj) in &minv_w[j] {
                                    if bi == bj {
                                        d[a * k + b] += dot6(wi, mj);
                                    }
                                }
                            }
                        }
                    }
                    d
                };
                let mut r = Scratch::new(k);
                for (a, &i) in loaded.iter().enumerate() {
                    r[a] = -rates[i];
                }
                pairs.clear();
                pairs.extend(loaded.iter().map(|&i| vertices[i]));
                let anchored = pairs.iter().any(|&(c, _)| {
                    self.contacts[c]
                        .as_ref()
                        .is_some_and(|r| r.anchor.is_some())
                });
                let mut delta = Scratch::new(k);
                let solved = if anchored {
                    // Kept on the eigendecomposition: the same correction by the null space of
                    // `PsdRange` (tried) agrees to 1e-12 per step, but the union desk's fixed
                    // point then stops elsewhere within its tolerance (loads 4.5e-4 apart by
                    // the end).
                    let d = delassus();
                    let rows = d.chunks_exact(k).map(<[f64]>::to_vec).collect();
                    self.anchored_correction(pairs, contacts, rows, &r)
                        .map(|x| delta.copy_from_slice(&x))
                        .is_some()
                } else {
                    if !*factored || range_for != loaded {
                        *range = PsdRange::new(&delassus(), k);
                        range_for.clone_from(loaded);
                        *factored = true;
                    }
                    range
                        .as_ref()
                        .is_some_and(|range| range.min_norm(&r, &mut delta))
                };
                if !solved {
                    break;
                }
                // Largest step in [0, 1] keeping every λ ≥ 0, and the vertex that blocks it.
                let mut alpha: f64 = 1.0;
                let mut blocking = None;
                for (a, &(c, kk)) in pairs.iter().enumerate() {
                    let l = contacts[c].vertex_impulses[kk].1;
                    if delta[a] < 0.0 && l + delta[a] < 0.0 && l / -delta[a] < alpha {
                        alpha = l / -delta[a];
                        blocking = Some(loaded[a]);
                    }
                }
                if blocking.is_some() && blocking == just_added && alpha == 0.0 {
                    // The added vertex cannot take load along this correction: stop here.
                    break;
                }
                for (a, &(c, kk)) in pairs.iter().enumerate() {
                    let step = alpha * delta[a];
                    let entry = &mut contacts[c].vertex_impulses[kk];
                    entry.1 = (entry.1 + step).max(0.0);
                    for (b, wi) in &w[loaded[a]] {
                        for j in 0..6 {
                            wrench_sum[*b][j] += step * wi[j];
                        }
                    }
                }
                if blocking.is_some() {
                    // As before the loop: the blocking vertex is unloaded, and the next sweep
                    // corrects the rest.
                    break;
                }
                // Full step: the most violated vertex outside the set, if any, joins it.
                self.gap_rates(group, bodies, factors, wrench_sum, vertices, w, nu, rates);
                let scale = rates.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                let worst = (0..vertices.len())
                    .filter(|&i| !active[i])
                    .min_by(|&a, &b| rates[a].total_cmp(&rates[b]));
                match worst {
                    Some(i) if rates[i] < -VIOLATION * scale.max(1.0) => {
                        active[i] = true;
                        just_added = Some(i);
                    }
                    _ => break,
                }
            }
        }
    }

    /// Linearised gap rates `g_j/h + W_{n,j}ᵀ(ν − ν^k)` of `vertices` (wrenches `w`) at the
    /// velocities `ν = ν_free + M⁻¹ Σ W p` of the bodies of `group`, into `rates` (`nu`: the
    /// velocities' storage).
    #[allow(clippy::too_many_arguments)]
    fn gap_rates(
        &self,
        group: &[usize],
        bodies: &[BodyDynamics],
        factors: &[MassFactor],
        wrench_sum: &[[f64; 6]],
        vertices: &[(usize, usize)],
        w: &[VertexWrenches],
        nu: &mut Vec<(usize, [f64; 6])>,
        rates: &mut Vec<f64>,
    ) {
        nu.clear();
        nu.extend(group.iter().map(|&b| {
            let body = &bodies[b];
            let dv = factors[b].solve(&wrench_sum[b]);
            let mut nu = body.free_velocity;
            for i in 0..6 {
                nu[i] += dv[i];
            }
            (b, nu)
        }));
        let velocity = |b: usize| nu.iter().find(|(c, _)| *c == b).map(|(_, v)| *v);
        rates.clear();
        rates.extend(vertices.iter().zip(w).map(|(&(c, kk), ws)| {
            let mut rate = self.contacts[c]
                .as_ref()
                .map_or(0.0, |rows| rows.gap_rates[kk]);
            for (b, wi) in ws {
                rate += dot6(wi, &velocity(*b).unwrap_or([0.0; 6]));
            }
            rate
        }));
    }

    /// The bodies coupled by contacts (connected components of the contact graph), each sorted,
    /// in the order of their smallest body: the loaded vertices of one group share a Delassus
    /// system. A body touching only half-spaces is a group by itself.
    fn groups(&self, num_bodies: usize, out: &mut Groups) {
        let Groups {
            root,
            index,
            list,
            len,
        } = out;
        root.clear();
        root.extend(0..num_bodies);
        for rows in self.contacts.iter().flatten() {
            let first = rows.sides[0].body;
            for side in &rows.sides[1..] {
                union(root, first, side.body);
            }
        }
        *len = 0;
        index.clear();
        index.resize(num_bodies, usize::MAX);
        for b in 0..num_bodies {
            let r = find(root, b);
            if index[r] == usize::MAX {
                index[r] = *len;
                if list.len() == *len {
                    list.push(Vec::new());
                }
                list[*len].clear();
                *len += 1;
            }
            list[index[r]].push(b);
        }
    }
}

impl StepQp {
    /// The correction `δ` of the loaded normal impulses `λ` (list `loaded` of (contact, row))
    /// that solves the Delassus system `D δ = r` (in the least-squares sense, like
    /// [`pseudo_solve`]) and, among its solutions, minimises the anchor penalty
    /// `Σ_c ½ρ_m‖A_c(λ + δ)‖² + ½ρ_n(1_cᵀ(λ + δ) − p_{n,c}^k)²` of the anchored contacts plus
    /// `½τ‖δ‖²` (`A_c`: the tangential lever arms about the contact's ECP; `τ` tiny, for the
    /// load patterns the anchor does not see). Solved as the KKT system
    /// `[Q Uᵣ; Uᵣᵀ 0] [δ; y] = [−g; S⁻¹Uᵣᵀr]` on the range `Uᵣ` of `D = U S Uᵀ`.
    fn anchored_correction(
        &self,
        loaded: &[(usize, usize)],
        contacts: &[ContactImpulses],
        d: Vec<Vec<f64>>,
        r: &[f64],
    ) -> Option<Vec<f64>> {
        let k = loaded.len();
        // Q and g = ∇(anchor penalty) at δ = 0.
        let mut q = vec![vec![0.0; k]; k];
        let mut g = vec![0.0; k];
        let mut groups: Vec<usize> = loaded.iter().map(|&(c, _)| c).collect();
        groups.dedup();
        for &c in &groups {
            let Some(rows) = self.contacts[c].as_ref() else {
                continue;
            };
            let Some((rho_m, rho_n, previous)) = rows.anchor else {
                continue;
            };
            let members: Vec<usize> = (0..k).filter(|&i| loaded[i].0 == c).collect();
            let e = rows.frame.ecp;
            let arms: Vec<[f64; 2]> = members
                .iter()
                .map(|&i| {
                    let x = rows.positions.get(loaded[i].1).copied().unwrap_or(e);
                    let arm = sub(&x, &e);
                    [
                        dot3(&arm, &rows.frame.tangent),
                        dot3(&arm, &rows.frame.bitangent),
                    ]
                })
                .collect();
            let lambda: Vec<f64> = members
                .iter()
                .map(|&i| contacts[c].vertex_impulses[loaded[i].1].1)
                .collect();
            let moment = [0, 1].map(|a| {
                (0..members.len())
                    .map(|m| arms[m][a] * lambda[m])
                    .sum::<f64>()
            });
            let load: f64 = lambda.iter().sum();
            for (mi, &i) in members.iter().enumerate() {
                g[i] += rho_m * (arms[mi][0] * moment[0] + arms[mi][1] * moment[1])
                    + rho_n * (load - previous);
                for (mj, &j) in members.iter().enumerate() {
                    q[i][j] +=
                        rho_m * (arms[mi][0] * arms[mj][0] + arms[mi][1] * arms[mj][1]) + rho_n;
                }
            }
        }
        let scale = (0..k).map(|i| q[i][i]).fold(0.0, f64::max);
        let tau = 1e-8 * if scale > 0.0 { scale } else { 1.0 };
        for i in 0..k {
            q[i][i] += tau;
        }
        // Range of D and the constraint Uᵣᵀδ = S⁻¹Uᵣᵀr.
        let (eig, vecs) = symmetric_eigen(d)?;
        let max_eig = eig.iter().copied().fold(0.0, f64::max);
        let range: Vec<usize> = (0..k).filter(|&m| eig[m] > 1e-12 * max_eig).collect();
        let n = k + range.len();
        let mut a = vec![vec![0.0; n]; n];
        let mut rhs = vec![0.0; n];
        for i in 0..k {
            a[i][..k].copy_from_slice(&q[i]);
            rhs[i] = -g[i];
        }
        for (m, &col) in range.iter().enumerate() {
            for i in 0..k {
                a[i][k + m] = vecs[i][col];
                a[k + m][i] = vecs[i][col];
            }
            rhs[k + m] = (0..k).map(|i| vecs[i][col] * r[i]).sum::<f64>() / eig[col];
        }
        let x = solve_dense(a, rhs)?;
        Some(x[..k].to_vec())
    }
}

/// One unknown of the polish's joint Newton step ([`StepQp::joint_step`]).
#[derive(Clone, Copy)]
enum Unknown {
    /// The normal impulse `λ` of a loaded vertex: (contact, position in its vertex list).
    Vertex(usize, usize),
    /// Component `i` of a contact's friction impulse: (contact, i).
    Friction(usize, usize),
}

impl StepQp {
    /// A joint Newton step of the polish: with the active set of its conditions fixed (the
    /// loaded vertices, each loaded contact's friction sticking or sliding, as the last sweep left
    /// them) and each friction at its current centre of pressure, solves the coupled conditions
    /// the Gauss–Seidel sweeps settle one block at a time, all contacts together:
    ///
    /// ```text
    /// g_j/h + W_{n,j}ᵀ(ν − ν^k) = 0                  every loaded vertex j
    /// u_c = W_{f,c}ᵀ ν + o_c = 0                       sticking contact c
    /// p_c + μ p_{n,c} E² u_c / ‖E u_c‖ = 0             sliding contact c
    /// ```
    ///
    /// with `ν = ν_free + M⁻¹ Σ W p` linear in the unknowns (`K = Wᵀ M⁻¹ W`, the Delassus
    /// matrix of every loaded vertex and friction component). The point is taken only when
    /// Newton's method converges to round-off, every load stays positive, every sticking
    /// friction stays in its cone, and every sliding one keeps its slip; otherwise nothing
    /// changes and the sweeps go on. Loads that are not unique (four coplanar vertices, the
    /// union desk's legs) make the Jacobian singular: refused the same way. Returns whether
    /// the point was taken. Cold and out of line: most polishes settle before it, and the
    /// desk's that do not are refused at once by the loaded-vertex count.
    #[cold]
    #[inline(never)]
    fn joint_step(
        &self,
        bodies: &[BodyDynamics],
        factors: &[MassFactor],
        contacts: &mut [ContactImpulses],
        wrench_sum: &mut [[f64; 6]],
        current: &[Vec<BodyFriction>],
        joint: &mut JointWorkspace,
    ) -> bool {
        // A patch's vertex wrenches `[n; r × n]` span three dimensions at most (the force along
        // n, the moments about two axes in the patch), so a contact with more than three loaded
        // vertices (the desk's legs) has loads that are not unique: refused before any work.
        let unique = self
            .contacts
            .iter()
            .zip(contacts.iter())
            .all(|(rows, imp)| {
                rows.is_none() || imp.vertex_impulses.iter().filter(|(_, l)| *l > 0.0).count() <= 3
            });
        if !unique {
            return false;
        }
        // The unknowns, their wrenches on each body and the starting values.
        let mut unknowns = Vec::new();
        let mut wrenches: Vec<Vec<(usize, [f64; 6])>> = Vec::new();
        let mut x0 = Vec::new();
        // Friction contacts: (contact, first unknown, sliding, ρ = μ p_n, first λ, λ count).
        let mut frictions = Vec::new();
        // The data part of each friction contact's slip at its centre of pressure (as the
        // sweeps compute it; zero but for a G with prescribed velocity).
        let mut offsets = vec![[0.0; 3]; self.contacts.len()];
        let mut sides = Vec::new();
        for (c, rows) in self.contacts.iter().enumerate() {
            let Some(rows) = rows else { continue };
            let first_lambda = unknowns.len();
            for (k, &(_, l)) in contacts[c].vertex_impulses.iter().enumerate() {
                if l > 0.0 {
                    unknowns.push(Unknown::Vertex(c, k));
                    wrenches.push(
                        rows.sides
                            .iter()
                            .map(|s| (s.body, s.normal_wrenches[k]))
                            .collect(),
                    );
                    x0.push(l);
                }
            }
            let count = unknowns.len() - first_lambda;
            if rows.soc_row.is_some() && count > 0 {
                offsets[c] = match rows.centre_of_pressure(&contacts[c].vertex_impulses) {
                    Some(cop) => friction_sides_into(
                        &ContactGeometry {
                            ecp: cop,
                            patch: Vec::new(),
                            ..rows.frame.clone()
                        },
                        &mut sides,
                    ),
                    None => rows.slip_offset,
                };
                frictions.push((
                    c,
                    unknowns.len(),
                    contacts[c].sigma > 0.0,
                    first_lambda,
                    count,
                ));
                for i in 0..3 {
                    unknowns.push(Unknown::Friction(c, i));
                    wrenches.push(current[c].iter().map(|(b, wf)| (*b, wf[i])).collect());
                    x0.push(contacts[c].friction[i]);
                }
            }
        }
        let n = unknowns.len();
        if n == 0 {
            return false;
        }
        // K = Wᵀ M⁻¹ W and the rows' values at the start: gap rates and slips.
        let velocity: Vec<[f64; 6]> = bodies
            .iter()
            .enumerate()
            .map(|(b, body)| {
                let dv = factors[b].solve(&wrench_sum[b]);
                std::array::from_fn(|i| body.free_velocity[i] + dv[i])
            })
            .collect();
        let minv_w: Vec<Vec<(usize, [f64; 6])>> = wrenches
            .iter()
            .map(|ws| ws.iter().map(|(b, w)| (*b, factors[*b].solve(w))).collect())
            .collect();
        let JointWorkspace {
            kmat,
            jac,
            v,
            step: delta,
            lu,
        } = joint;
        // Column-major: `K_rj` at `kmat[j * n + r]`.
        kmat.clear();
        kmat.resize(n * n, 0.0);
        for r in 0..n {
            for j in 0..n {
                for (br, wr) in &wrenches[r] {
                    for (bj, yj) in &minv_w[j] {
                        if br == bj {
                            kmat[j * n + r] += dot6(wr, yj);
                        }
                    }
                }
            }
        }
        if lu.as_ref().is_none_or(|lu| lu.dim() != n) {
            *lu = Some(linalg::DenseLu::new(n));
        }
        let Some(lu) = lu.as_mut() else {
            return false;
        };
        let mut v0: Vec<f64> = wrenches
            .iter()
            .map(|ws| ws.iter().map(|(b, w)| dot6(w, &velocity[*b])).sum())
            .collect();
        for (r, u) in unknowns.iter().enumerate() {
            v0[r] += match *u {
                Unknown::Vertex(c, k) => self.contacts[c].as_ref().map_or(0.0, |r| r.gap_rates[k]),
                Unknown::Friction(c, i) => offsets[c][i],
            };
        }
        let mut x = x0.clone();
        let mut converged = false;
        for _ in 0..JOINT_ITERATIONS {
            // Rows' values at x (linear in x), then the residual and Jacobian.
            v.clear();
            v.extend((0..n).map(|r| {
                v0[r]
                    + (0..n)
                        .map(|j| kmat[j * n + r] * (x[j] - x0[j]))
                        .sum::<f64>()
            }));
            // The residual F, negated below into the Newton step's right-hand side.
            delta.clone_from(v);
            jac.clone_from(kmat);
            for &(c, first, sliding, first_lambda, count) in &frictions {
                if !sliding {
                    continue;
                }
                let Some(rows) = self.contacts[c].as_ref() else {
                    return false;
                };
                let e = rows.axes;
                let q: [f64; 3] = std::array::from_fn(|i| e[i] * v[first + i]);
                let sigma = dot3(&q, &q).sqrt();
                let rho = rows.mu * x[first_lambda..first_lambda + count].iter().sum::<f64>();
                if sigma.is_nan() || sigma <= 0.0 || rho.is_nan() || rho <= 0.0 {
                    return false;
                }
                let qh = q.map(|v| v / sigma);
                // d(E² u/σ)/du = E (I − q̂q̂ᵀ) E / σ, q = E u.
                let t: [[f64; 3]; 3] = std::array::from_fn(|i| {
                    std::array::from_fn(|l| {
                        e[i] * (f64::from(u8::from(i == l)) - qh[i] * qh[l]) * e[l] / sigma
                    })
                });
                let dir: [f64; 3] = std::array::from_fn(|i| e[i] * qh[i]);
                for i in 0..3 {
                    let r = first + i;
                    delta[r] = x[r] + rho * dir[i];
                    for j in 0..n {
                        jac[j * n + r] = rho
                            * (0..3)
                                .map(|l| t[i][l] * kmat[j * n + first + l])
                                .sum::<f64>();
                    }
                    jac[r * n + r] += 1.0;
                    for j in first_lambda..first_lambda + count {
                        jac[j * n + r] += rows.mu * dir[i];
                    }
                }
            }
            for d in delta.iter_mut() {
                *d = -*d;
            }
            if lu.factor(jac).is_err()
                || lu.solve_in_place(delta).is_err()
                || delta.iter().any(|d| !d.is_finite())
            {
                return false;
            }
            let size = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let step = delta.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for j in 0..n {
                x[j] += delta[j];
            }
            if step <= JOINT_SETTLED * size {
                converged = true;
                break;
            }
        }
        if !converged || x.iter().any(|v| !v.is_finite()) {
            return false;
        }
        // The active set must hold at the new point.
        for (j, u) in unknowns.iter().enumerate() {
            if matches!(u, Unknown::Vertex(..)) && x[j] <= 0.0 {
                return false;
            }
        }
        for &(c, first, sliding, first_lambda, count) in &frictions {
            let Some(rows) = self.contacts[c].as_ref() else {
                return false;
            };
            let rho = rows.mu * x[first_lambda..first_lambda + count].iter().sum::<f64>();
            let inside = (0..3)
                .map(|i| (x[first + i] / rows.axes[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            if !sliding && inside > rho * (1.0 + 1e-12) {
                return false;
            }
        }
        // Take the point: the impulses and their wrench sums.
        for (j, u) in unknowns.iter().enumerate() {
            let change = x[j] - x0[j];
            match *u {
                Unknown::Vertex(c, k) => contacts[c].vertex_impulses[k].1 = x[j],
                Unknown::Friction(c, i) => contacts[c].friction[i] = x[j],
            }
            for (b, w) in &wrenches[j] {
                for i in 0..6 {
                    wrench_sum[*b][i] += change * w[i];
                }
            }
        }
        true
    }
}

/// Eigen-decomposition of a symmetric matrix ([`linalg::symmetric_eigen`]): eigenvalues and
/// the eigenvectors as the columns of the second matrix. `None` for a non-finite matrix.
fn symmetric_eigen(d: Vec<Vec<f64>>) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
    let n = d.len();
    let a: Vec<f64> = (0..n)
        .flat_map(|j| d.iter().map(move |row| row[j]))
        .collect();
    let (eig, u) = linalg::symmetric_eigen(&a, n).ok()?;
    let v = (0..n)
        .map(|i| (0..n).map(|j| u[j * n + i]).collect())
        .collect();
    Some((eig, v))
}

/// Solves the dense square system `A x = b` ([`linalg::DenseLu`], partial pivoting); `None`
/// when `A` is numerically singular or the result is not finite.
fn solve_dense(a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    let col: Vec<f64> = (0..n)
        .flat_map(|j| a.iter().map(move |row| row[j]))
        .collect();
    let mut lu = linalg::DenseLu::new(n);
    lu.factor(&col).ok()?;
    lu.solve_in_place(&mut b).ok()?;
    b.iter().all(|v| v.is_finite()).then_some(b)
}

fn solve3(a: &[[f64; 3]; 3], b: &[f64; 3]) -> Option<[f64; 3]> {
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let mut x = [0.0; 3];
    for c in 0..3 {
        let mut m = *a;
        for r in 0..3 {
            m[r][c] = b[r];
        }
        let d = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        x[c] = d / det;
    }
    Some(x)
}

/// The local friction problem of one contact (maximum dissipation with the normal impulse
/// fixed): `min ½ pᵀA p + u₀ᵀp` subject to `‖E⁻¹p‖ ≤ ρ`, `ρ = μ p_n`, `A` symmetric positive
/// definite. Returns the impulse, the slip `σ = ‖E u‖`, `u = u₀ + A p`, and the multiplier `η`
/// below (0 when sticking).
///
/// Sticking when the unconstrained minimiser `−A⁻¹u₀` is inside the ellipsoid (`u = 0`,
/// `σ = 0`). Otherwise the KKT conditions `A p + u₀ + η E⁻² p = 0`, `‖E⁻¹p(η)‖ = ρ` give
/// `p = −ρ E² u / ‖E u‖` with `η = σ/ρ`: the multiplier `η > 0` is found by Newton's method on
/// the secular equation `1/‖E⁻¹p(η)‖ = 1/ρ` (as in Moré–Sorensen trust-region solvers),
/// safeguarded by bisection.
///
/// Newton's iteration starts at `hint`, the multiplier `η` of a neighbouring problem (the same
/// contact at the polish's last sweep), when it is positive. The polish's sweeps change a
/// contact's problem less and less, so the root is near the last one: the bracket is found by
/// a step of `HINT_STEP · hint` from it instead of by growing fourfold from `A`'s scale (three
/// evaluations on the desk), and Newton starts at it instead of at the bracket's middle
/// (`docs/latency.md`, branch wip-conic3x). The root is the same to round-off: the iteration
/// stops on the same tests.
pub(crate) fn local_friction(
    a: &[[f64; 3]; 3],
    u0: &[f64; 3],
    axes: &[f64; 3],
    rho: f64,
    hint: f64,
) -> ([f64; 3], f64, f64) {
    let slip = |p: &[f64; 3]| -> f64 {
        (0..3)
            .map(|i| {
                let u = u0[i] + (0..3).map(|j| a[i][j] * p[j]).sum::<f64>();
                (axes[i] * u).powi(2)
            })
            .sum::<f64>()
            .sqrt()
    };
    if rho.is_nan() || rho <= 0.0 {
        return ([0.0; 3], slip(&[0.0; 3]), 0.0);
    }
    let scaled =
        |p: &[f64; 3]| -> f64 { (0..3).map(|i| (p[i] / axes[i]).powi(2)).sum::<f64>().sqrt() };
    let p_of = |eta: f64| -> Option<[f64; 3]> {
        let mut m = *a;
        for i in 0..3 {
            m[i][i] += eta / (axes[i] * axes[i]);
        }
        solve3(&m, &[-u0[0], -u0[1], -u0[2]])
    };
    let Some(p0) = p_of(0.0) else {
        return ([0.0; 3], slip(&[0.0; 3]), 0.0);
    };
    if scaled(&p0) <= rho {
        return (p0, 0.0, 0.0);
    }
    // ψ(η) = ‖E⁻¹p(η)‖ decreases from ψ(0) > ρ to 0: bracket the root, then Newton on 1/ψ.
    let too_far = |eta: f64| p_of(eta).is_none_or(|p| scaled(&p) > rho);
    let mut lo = 0.0;
    let mut hi = 1.0f64;
    let mut eta = f64::NAN;
    if hint > 0.0 && hint.is_finite() {
        // ψ decreases: the hint bounds the root from one side, a step beyond it (grown
        // fourfold until it does) from the other.
        if too_far(hint) {
            let mut step = HINT_STEP * hint;
            lo = hint;
            hi = hint + step;
            let mut guard = 0;
            while too_far(hi) && guard < 200 {
                lo = hi;
                step *= 4.0;
                hi = lo + step;
                guard += 1;
            }
        } else {
            hi = hint;
        }
        eta = hint.clamp(lo, hi);
    }
    if !(eta >= lo && eta <= hi) || hi <= lo {
        lo = 0.0;
        hi = 1.0;
        let scale_a = (0..3)
            .map(|i| a[i][i] * axes[i] * axes[i])
            .fold(0.0, f64::max);
        if scale_a > 0.0 && scale_a.is_finite() {
            hi = scale_a;
        }
        let mut guard = 0;
        while too_far(hi) && guard < 200 {
            lo = hi;
            hi *= 4.0;
            guard += 1;
        }
        eta = 0.5 * (lo + hi);
    }
    for _ in 0..100 {
        let Some(p) = p_of(eta) else { break };
        let psi = scaled(&p);
        if psi > rho {
            lo = eta;
        } else {
            hi = eta;
        }
        if (psi - rho).abs() <= 1e-15 * rho || hi - lo <= 1e-16 * hi {
            break;
        }
        // dp/dη = −(A + ηD)⁻¹ D p, dψ/dη = (pᵀ D dp/dη)/ψ, D = E⁻².
        let mut m = *a;
        for i in 0..3 {
            m[i][i] += eta / (axes[i] * axes[i]);
        }
        let dp_rhs = [
            -p[0] / (axes[0] * axes[0]),
            -p[1] / (axes[1] * axes[1]),
            -p[2] / (axes[2] * axes[2]),
        ];
        let Some(dp) = solve3(&m, &dp_rhs) else { break };
        let dpsi = (0..3)
            .map(|i| p[i] * dp[i] / (axes[i] * axes[i]))
            .sum::<f64>()
            / psi;
        // Newton on φ(η) = 1/ψ − 1/ρ, φ' = −ψ'/ψ².
        let phi = 1.0 / psi - 1.0 / rho;
        let dphi = -dpsi / (psi * psi);
        let next = eta - phi / dphi;
        eta = if next.is_finite() && next > lo && next < hi {
            next
        } else {
            0.5 * (lo + hi)
        };
    }
    let p = p_of(eta).unwrap_or(p0);
    // Put p exactly on the ellipsoid (the secular equation is solved to round-off anyway).
    let k = rho / scaled(&p);
    let p = if k.is_finite() {
        [p[0] * k, p[1] * k, p[2] * k]
    } else {
        p
    };
    (p, slip(&p), eta)
}

/// The first step beyond a hinted multiplier, relative to it, when the root lies beyond the
/// hint ([`local_friction`]): in a traced polish of the desk the root moved by 3e-7 of itself
/// between sweeps (2.4747064 → 2.4747070 → …); a larger move costs a few more evaluations.
const HINT_STEP: f64 = 1e-3;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_mode_extrapolation_reaches_the_limit_and_refuses_other_sequences() {
        // Three iterates of x_k = x* + ρᵏ v + (ρ/10)ᵏ u (a slow mode and a fast one), ρ = 0.1,
        // from k = 3: the extrapolation lands within 1e-8 of x* while the iterates are 1e-4
        // off (about the desk's first polish from its fourth sweep).
        let limit = [0.3, 0.0, 1.2, -0.4];
        let v = [1.0, 0.0, -0.5, 0.25];
        let u = [0.0, 0.0, 1.0, 1.0];
        let iterate = |rho: f64, k: i32| -> Vec<f64> {
            (0..4)
                .map(|i| limit[i] + rho.powi(k) * v[i] + (rho / 10.0).powi(k) * u[i])
                .collect()
        };
        let (a, b, c) = (iterate(0.1, 3), iterate(0.1, 4), iterate(0.1, 5));
        let factor = one_mode_factor(&a, &b, c.iter().copied()).expect("one mode");
        // ρ estimated 0.10002 (the fast mode's share of d₁, d₂).
        assert!((factor - 0.1 / 0.9).abs() < 1e-4, "factor {factor}");
        for i in 0..4 {
            let x = c[i] + factor * (c[i] - b[i]);
            assert!((x - limit[i]).abs() < 1e-8, "{i}: {x} against {}", limit[i]);
            assert!((c[i] - limit[i]).abs() > 1e-6 || v[i] == 0.0);
        }
        // Too slow (ρ = 0.8 > EXTRAPOLATE_RATE), no contraction (changes of alternating sign),
        // two modes of the same size, and no change at all: refused.
        let (a, b, c) = (iterate(0.8, 3), iterate(0.8, 4), iterate(0.8, 5));
        assert_eq!(one_mode_factor(&a, &b, c.iter().copied()), None);
        let (a, b, c) = (iterate(-0.1, 3), iterate(-0.1, 4), iterate(-0.1, 5));
        assert_eq!(one_mode_factor(&a, &b, c.iter().copied()), None);
        let mixed = |k: i32| -> Vec<f64> {
            (0..4)
                .map(|i| limit[i] + 0.1f64.powi(k) * v[i] + 0.4f64.powi(k) * u[i])
                .collect()
        };
        let (a, b, c) = (mixed(1), mixed(2), mixed(3));
        assert_eq!(one_mode_factor(&a, &b, c.iter().copied()), None);
        assert_eq!(one_mode_factor(&limit, &limit, limit.iter().copied()), None);
        // Lengths that differ: refused.
        assert_eq!(one_mode_factor(&a[..3], &b, c.iter().copied()), None);
    }

    /// The circling test stops sweeps that repeat (a period-5 cycle, as `134_union_slide`'s)
    /// at the first sweep it runs, and sweeps that grow; it lets contracting sweeps run (0.9 per
    /// sweep: 0.9^10 = 0.35 of the smallest change before the window), and stops a
    /// contraction of 0.95 per sweep (0.95^10 = 0.60), which would need about 500 sweeps to
    /// settle from 1e-1 to `SETTLED`.
    #[test]
    fn circling_test_stops_cycles_and_lets_contractions_run() {
        let first_stop = |changes: &dyn Fn(usize) -> f64| {
            let mut c = Circling::default();
            (0..MAX_SWEEPS).find(|&k| c.record(k, changes(k), 2.0))
        };
        let cycle = [3e-2, 1e-2, 5e-2, 2e-2, 4e-2];
        let first_test = CIRCLE_FROM + CIRCLE_WINDOW + CIRCLE_EARLIER - 1;
        assert_eq!(first_test, 19);
        assert_eq!(first_stop(&|k| cycle[k % 5]), Some(first_test));
        assert_eq!(
            first_stop(&|k| 1e-3 * 1.05f64.powi(k as i32)),
            Some(first_test)
        );
        assert_eq!(first_stop(&|k| 1e-1 * 0.9f64.powi(k as i32)), None);
        assert_eq!(
            first_stop(&|k| 1e-1 * 0.95f64.powi(k as i32)),
            Some(first_test)
        );
        // A cycle that an extrapolation breaks at sweep 22 (changes 1e-9 from there): stopped
        // before it only if the test had already fired, which it has at 19.
        assert_eq!(
            first_stop(&|k| if k < 22 { cycle[k % 5] } else { 1e-9 }),
            Some(first_test)
        );
        // No recorded scale (no load), or a change that is not finite: never stops.
        let mut c = Circling::default();
        assert!((0..MAX_SWEEPS).all(|k| !c.record(k, 1e-2, 0.0)));
        let mut c = Circling::default();
        assert!((0..MAX_SWEEPS).all(|k| !c.record(k, f64::NAN, 1.0)));
        // Contracting at 0.93 per sweep (0.93^10 = 0.48: runs), flat from sweep 30: stopped at
        // the first sweep whose window's smallest change is at least half the smallest before
        // it (sweep 31: 0.93^9 = 0.52).
        let stop = first_stop(&|k| 1e-1 * 0.93f64.powi(k.min(30) as i32));
        assert_eq!(stop, Some(31));
    }

    #[test]
    fn two_mode_extrapolation_reaches_the_fixed_point_of_a_rotating_pair() {
        // Iterates of the affine map x ↦ x* + T (x − x*), T a rotation by θ scaled by r on the
        // plane of v, w (the polish's rotating pair, `056_union_slide`: a period of 4–5 sweeps),
        // for r = 0.95 (contracting) and r = 1.07 (growing): x_k = x* + rᵏ (cos kθ v + sin kθ w).
        let limit = [0.07, 0.027, 0.049, 0.099, -0.015, -0.08, -0.012];
        let v = [1.0, -0.5, 0.2, 0.0, 0.3, -1.0, 0.1];
        let w = [0.0, 0.4, -1.0, 0.6, 0.2, 0.1, -0.3];
        let theta = 2.0 * std::f64::consts::PI / 4.5;
        for r in [0.95f64, 1.07] {
            let iterate = |k: i32| -> Vec<f64> {
                let (c, s) = ((k as f64 * theta).cos(), (k as f64 * theta).sin());
                (0..7)
                    .map(|i| limit[i] + 1e-2 * r.powi(k) * (c * v[i] + s * w[i]))
                    .collect()
            };
            let (x0, x1, x2, x3) = (iterate(5), iterate(6), iterate(7), iterate(8));
            // One mode does not describe them.
            assert_eq!(one_mode_factor(&x1, &x2, x3.iter().copied()), None);
            let (alpha, beta) =
                two_mode_coefficients(&x0, &x1, &x2, x3.iter().copied()).expect("two modes");
            // a = 2 r cos θ, b = −r²: α = (a + b)/(1 − a − b), β = b/(1 − a − b).
            let (a, b) = (2.0 * r * theta.cos(), -r * r);
            assert!((alpha - (a + b) / (1.0 - a - b)).abs() < 1e-9, "α {alpha}");
            assert!((beta - b / (1.0 - a - b)).abs() < 1e-9, "β {beta}");
            for i in 0..7 {
                let x = x3[i] + alpha * (x3[i] - x2[i]) + beta * (x2[i] - x1[i]);
                assert!(
                    (x - limit[i]).abs() < 1e-14,
                    "r {r}, {i}: {x} against {}",
                    limit[i]
                );
                assert!((x3[i] - limit[i]).abs() > 1e-4 || (v[i] == 0.0 && w[i] == 0.0));
            }
        }
        let rotating = |r: f64, k: i32| -> Vec<f64> {
            let (c, s) = ((k as f64 * theta).cos(), (k as f64 * theta).sin());
            (0..7)
                .map(|i| limit[i] + r.powi(k) * (c * v[i] + s * w[i]))
                .collect()
        };
        // Growing faster than TWO_MODE_RATE: refused.
        let x: Vec<Vec<f64>> = (0..4).map(|k| rotating(1.6, k)).collect();
        assert_eq!(
            two_mode_coefficients(&x[0], &x[1], &x[2], x[3].iter().copied()),
            None
        );
        // A real mode near 1 (1 − a − b = (1 − λ₁)(1 − λ₂) < TWO_MODE_DISTANCE): refused.
        let slow = |k: i32| -> Vec<f64> {
            (0..7)
                .map(|i| limit[i] + 0.9f64.powi(k) * v[i] + 0.5f64.powi(k) * w[i])
                .collect()
        };
        let x: Vec<Vec<f64>> = (0..4).map(slow).collect();
        assert_eq!(
            two_mode_coefficients(&x[0], &x[1], &x[2], x[3].iter().copied()),
            None
        );
        // Three modes: the two-mode recurrence does not fit (remainder over the alignment).
        let u = [0.5, 0.5, 0.0, -0.5, 1.0, 0.0, 0.2];
        let three = |k: i32| -> Vec<f64> {
            let (c, s) = ((k as f64 * theta).cos(), (k as f64 * theta).sin());
            (0..7)
                .map(|i| {
                    limit[i] + 0.9f64.powi(k) * (c * v[i] + s * w[i]) + (-0.6f64).powi(k) * u[i]
                })
                .collect()
        };
        let x: Vec<Vec<f64>> = (0..4).map(three).collect();
        assert_eq!(
            two_mode_coefficients(&x[0], &x[1], &x[2], x[3].iter().copied()),
            None
        );
        // One mode (d₁, d₂ parallel), no change, and lengths that differ: refused.
        let one =
            |k: i32| -> Vec<f64> { (0..7).map(|i| limit[i] + 0.3f64.powi(k) * v[i]).collect() };
        let x: Vec<Vec<f64>> = (0..4).map(one).collect();
        assert_eq!(
            two_mode_coefficients(&x[0], &x[1], &x[2], x[3].iter().copied()),
            None
        );
        assert_eq!(
            two_mode_coefficients(&limit, &limit, &limit, limit.iter().copied()),
            None
        );
        let x: Vec<Vec<f64>> = (0..4).map(|k| rotating(0.95, k)).collect();
        assert_eq!(
            two_mode_coefficients(&x[0][..6], &x[1], &x[2], x[3].iter().copied()),
            None
        );
    }

    #[test]
    fn local_friction_sticks_or_slides_exactly() {
        let a = [[0.2, 0.01, 0.0], [0.01, 0.3, 0.02], [0.0, 0.02, 0.5]];
        let axes = [1.0, 1.0, 0.1];
        // Small slip: sticks, u = 0.
        let (p, sigma, _) = local_friction(&a, &[0.01, -0.02, 0.001], &axes, 1.0, 0.0);
        assert_eq!(sigma, 0.0);
        for i in 0..3 {
            let u: f64 = 0.01 * [1.0, -2.0, 0.1][i] + (0..3).map(|j| a[i][j] * p[j]).sum::<f64>();
            assert!(u.abs() < 1e-15, "{u}");
        }
        // Large slip: slides, p = −ρ E² u / ‖E u‖.
        let u0 = [1.0, 0.5, 0.3];
        let rho = 0.4;
        let (p, sigma, _) = local_friction(&a, &u0, &axes, rho, 0.0);
        assert!(sigma > 0.0);
        for i in 0..3 {
            let u = u0[i] + (0..3).map(|j| a[i][j] * p[j]).sum::<f64>();
            let want = -rho * axes[i] * axes[i] * u / sigma;
            assert!((p[i] - want).abs() < 1e-14, "{i}: {} vs {want}", p[i]);
        }
    }

    #[test]
    fn local_friction_from_a_hint_finds_the_same_root() {
        let a = [[0.2, 0.01, 0.0], [0.01, 0.3, 0.02], [0.0, 0.02, 0.5]];
        let axes = [1.0, 1.0, 0.1];
        let u0 = [1.0, 0.5, 0.3];
        let rho = 0.4;
        let (p, sigma, eta) = local_friction(&a, &u0, &axes, rho, 0.0);
        // η = σ/ρ at the root (the KKT conditions of the module doc).
        assert!(
            eta > 0.0 && (eta - sigma / rho).abs() <= 1e-13 * eta,
            "{eta} {sigma}"
        );
        // Hints below the root, at it, just above, far above and far below (the bracket grows
        // from the hint): the same impulse and slip to round-off, the same multiplier.
        for hint in [0.5 * eta, eta, eta * (1.0 + 1e-9), 1e3 * eta, 1e-6 * eta] {
            let (ph, sh, eh) = local_friction(&a, &u0, &axes, rho, hint);
            for i in 0..3 {
                assert!(
                    (ph[i] - p[i]).abs() <= 1e-14,
                    "hint {hint}: {ph:?} vs {p:?}"
                );
            }
            assert!(
                (sh - sigma).abs() <= 1e-14 * sigma,
                "hint {hint}: {sh} vs {sigma}"
            );
            assert!(
                (eh - eta).abs() <= 1e-12 * eta,
                "hint {hint}: {eh} vs {eta}"
            );
        }
        // A sticking problem ignores the hint: u = 0, multiplier 0.
        let (_, sigma, eta) = local_friction(&a, &[0.01, -0.02, 0.001], &axes, 1.0, 3.0);
        assert_eq!((sigma, eta), (0.0, 0.0));
    }

    fn contact(body: usize, patch: usize) -> ContactGeometry {
        ContactGeometry {
            body,
            normal: [0.0, 0.0, 1.0],
            tangent: [1.0, 0.0, 0.0],
            bitangent: [0.0, 1.0, 0.0],
            center_of_mass: [0.0; 3],
            gap: 0.0,
            patch: (0..patch)
                .map(|j| ecp_model::PatchVertex {
                    index: j,
                    position: [j as f64, 0.0, 0.0],
                    gap: 0.0,
                    partner_position: [j as f64, 0.0, 0.0],
                })
                .collect(),
            ecp: [0.0; 3],
            friction: ecp_model::ContactFriction {
                mu: 0.2,
                e_t: 1.0,
                e_o: 1.0,
                e_r: 0.1,
            },
            partner: ContactPartner::HalfSpace,
        }
    }

    #[test]
    fn only_bodies_with_several_loaded_contacts_are_anchored() {
        // Body 0: two contacts with a patch (anchored) and one without; body 1: one contact.
        let g = [contact(0, 4), contact(0, 4), contact(0, 0), contact(1, 4)];
        assert_eq!(anchored_contacts(&g, 2), vec![true, true, false, false]);
        // A contact naming a body that does not exist is never anchored.
        assert_eq!(anchored_contacts(&g, 1), vec![true, true, false, false]);
    }
}
