//! The conic subproblem of one outer iteration (solvers.md §3): with the contact geometry fixed
//! at the trial point, the end-of-step velocities and contact impulses solve one QP over a
//! product of cones.
//!
//! Primal (velocity) form, one block per body `b` and per contact `c` with a non-empty patch:
//!
//! ```text
//! min  Σ_b ½ (ν_b − ν_free,b)ᵀ M_b (ν_b − ν_free,b)
//! s.t. g_j/h + W_{n,j}ᵀ(ν_b − ν_b^k) + s_c − μ a_c ≥ 0      every patch vertex j      (λ_j)
//!      (a_c, e_t W_tᵀν_b, e_o W_oᵀν_b, e_r W_rᵀν_b) ∈ SOC(4)                         (μ p_n, p_f/e)
//! ```
//!
//! with `W_{n,j} = [n; (v_j − x) × n]` at the patch vertices, `W_t = [t; (a1 − x) × t]`,
//! `W_o = [o; (a1 − x) × o]`, `W_r = [0; n]` at the current ECP (formulation.md §4.1), `g_j`
//! the vertex gaps at the trial configuration, and `s_c` the De Saxcé shift `μ ‖E u_T‖` of the
//! trial velocities (Acary, Cadoux, Lemaréchal, Malick 2011), `E = diag(e_t, e_o, e_r)`; `s_c = 0`
//! is Anitescu's relaxation (Anitescu 2006). Its KKT conditions are the discrete Newton–Euler
//! equations `M(ν − ν_free) = Σ_j λ_j W_{n,j} + W_t p_t + W_o p_o + W_r p_r` with `λ_j ≥ 0`
//! (centre of pressure = the ECP) and `‖(p_t/e_t, p_o/e_o, p_r/e_r)‖ ≤ μ Σ_j λ_j`, the friction
//! impulse opposing the slip (maximum dissipation), and complementarity of each `λ_j` with its
//! shifted, linearised gap. At a fixed point (`ν = ν^k`, geometry unchanged, `s_c` equal to the
//! new slip) these are exactly the conditions of formulation.md §4.

use ecp_model::{BodyDynamics, ConicPoint, ContactGeometry, ContactImpulses, StepStructure};

use super::qp::{Cone, ConicQp, QpResult};

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

fn dot6(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The wrench `[d; r × d]` of a unit force `d` applied at lever arm `r`.
fn wrench(d: &[f64; 3], r: &[f64; 3]) -> [f64; 6] {
    let m = cross(r, d);
    [d[0], d[1], d[2], m[0], m[1], m[2]]
}

/// Where one contact sits in the QP.
#[derive(Clone, Debug)]
struct ContactRows {
    body: usize,
    /// Hull indices of the patch vertices, in row order.
    vertices: Vec<usize>,
    /// Wrenches `W_{n,j}` of the patch vertices.
    normal_wrenches: Vec<[f64; 6]>,
    /// First row of the vertex rows.
    first_row: usize,
    /// Linearised gap rate of each patch vertex at `ν = 0`: `g_j/h − W_{n,j}ᵀ ν^k` (no shift).
    gap_rates: Vec<f64>,
    /// Friction wrenches `W_t, W_o, W_r` at the current ECP.
    friction_wrenches: [[f64; 6]; 3],
    /// Ellipsoid semi-axes `(e_t, e_o, e_r)`.
    axes: [f64; 3],
    /// First row of the second-order cone, when μ > 0.
    soc_row: Option<usize>,
    /// Friction coefficient μ.
    mu: f64,
}

/// The QP of one outer iteration and how to read its solution.
pub(crate) struct StepQp {
    pub qp: ConicQp,
    contacts: Vec<Option<ContactRows>>,
    /// Number of patch vertices in the QP.
    pub patch_vertices: usize,
}

/// Friction wrenches `W_t, W_o, W_r` of a contact at its current ECP.
fn friction_wrenches(g: &ContactGeometry) -> [[f64; 6]; 3] {
    let arm = sub(&g.ecp, &g.center_of_mass);
    [
        wrench(&g.tangent, &arm),
        wrench(&g.bitangent, &arm),
        [0.0, 0.0, 0.0, g.normal[0], g.normal[1], g.normal[2]],
    ]
}

/// The De Saxcé shift `μ ‖E u_T‖` of contact `g` at velocities `nu` of its body.
pub(crate) fn de_saxce_shift(g: &ContactGeometry, nu: &[f64; 6]) -> f64 {
    let f = g.friction;
    let axes = [f.e_t, f.e_o, f.e_r];
    let w = friction_wrenches(g);
    let slip: f64 = (0..3)
        .map(|i| (axes[i] * dot6(&w[i], nu)).powi(2))
        .sum::<f64>()
        .sqrt();
    f.mu * slip
}

/// Builds the subproblem at the trial point (geometry from `geometry`, trial velocities
/// `trial`) with the normal shift `shifts[c]` of every contact: the De Saxcé shift (exact
/// mode) or zero (Anitescu's relaxation).
pub(crate) fn build(
    structure: &dyn StepStructure,
    bodies: &[BodyDynamics],
    trial: &[[f64; 6]],
    geometry: &[ContactGeometry],
    shifts: &[f64],
) -> StepQp {
    let h = structure.step_length();
    let nb = bodies.len();
    let friction_vars: Vec<usize> = geometry
        .iter()
        .enumerate()
        .filter(|(_, g)| !g.patch.is_empty() && g.friction.mu > 0.0)
        .map(|(c, _)| c)
        .collect();
    let mut qp = ConicQp::new(6 * nb + friction_vars.len());
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
    let mut contacts = Vec::with_capacity(geometry.len());
    let mut patch_vertices = 0;
    for (c, g) in geometry.iter().enumerate() {
        if g.patch.is_empty() || g.body >= nb {
            contacts.push(None);
            continue;
        }
        let b = g.body;
        let f = g.friction;
        let axes = [f.e_t, f.e_o, f.e_r];
        let friction_wrenches = friction_wrenches(g);
        let nu_k = &trial[b];
        let s = shifts.get(c).copied().unwrap_or(0.0);
        let a_col = friction_vars
            .iter()
            .position(|&k| k == c)
            .map(|k| 6 * nb + k);
        let first_row = qp.rows();
        let mut vertices = Vec::with_capacity(g.patch.len());
        let mut gap_rates = Vec::with_capacity(g.patch.len());
        let mut normal_wrenches = Vec::with_capacity(g.patch.len());
        for v in &g.patch {
            let w = wrench(&g.normal, &sub(&v.position, &g.center_of_mass));
            let mut coeffs: Vec<(usize, f64)> = (0..6).map(|i| (6 * b + i, -w[i])).collect();
            if let Some(a) = a_col {
                coeffs.push((a, f.mu));
            }
            let rate = v.gap / h - dot6(&w, nu_k);
            qp.push_row(&coeffs, rate + s);
            gap_rates.push(rate);
            vertices.push(v.index);
            normal_wrenches.push(w);
        }
        qp.cones.push(Cone::Nonnegative(g.patch.len()));
        patch_vertices += g.patch.len();
        let soc_row = a_col.map(|a| {
            let r0 = qp.push_row(&[(a, -1.0)], 0.0);
            for i in 0..3 {
                let coeffs: Vec<(usize, f64)> = (0..6)
                    .map(|k| (6 * b + k, -axes[i] * friction_wrenches[i][k]))
                    .collect();
                qp.push_row(&coeffs, 0.0);
            }
            qp.cones.push(Cone::SecondOrder(4));
            r0
        });
        contacts.push(Some(ContactRows {
            body: b,
            vertices,
            normal_wrenches,
            first_row,
            gap_rates,
            friction_wrenches,
            axes,
            soc_row,
            mu: f.mu,
        }));
    }
    StepQp {
        qp,
        contacts,
        patch_vertices,
    }
}

impl StepQp {
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
    ///   ([`local_friction`]), in two Gauss–Seidel sweeps over the contacts of a body, starting
    ///   from clarabel's dual; it sticks with `u_T = 0` exactly or slides with
    ///   `p_f = −μ p_n E² u_T / ‖E u_T‖` exactly (formulation.md §4.4);
    /// - the velocities are recomputed from the impulses by the Newton–Euler equations,
    ///   `ν = ν_free + M⁻¹ Σ W p`, so that the dynamics hold to round-off.
    ///
    /// At a fixed point of the outer iteration these readings coincide with the QP's solution.
    ///
    /// Without `polish` (Anitescu's relaxation, or to measure the plain fixed point) the
    /// impulses are clarabel's duals as they are (only the active-set identification of `λ`).
    pub fn extract(&self, result: &QpResult, bodies: &[BodyDynamics], polish: bool) -> ConicPoint {
        let nb = bodies.len();
        let mut wrench_sum = vec![[0.0f64; 6]; nb];
        let mut contacts = Vec::with_capacity(self.contacts.len());
        for rows in &self.contacts {
            let Some(rows) = rows else {
                contacts.push(ContactImpulses::default());
                continue;
            };
            let mut vertex_impulses = Vec::with_capacity(rows.vertices.len());
            for (k, (&j, w)) in rows.vertices.iter().zip(&rows.normal_wrenches).enumerate() {
                let row = rows.first_row + k;
                let l = if result.z[row] > result.s[row] {
                    result.z[row]
                } else {
                    0.0
                };
                vertex_impulses.push((j, l));
                for i in 0..6 {
                    wrench_sum[rows.body][i] += l * w[i];
                }
            }
            let mut friction = [0.0; 3];
            if let Some(r0) = rows.soc_row {
                for i in 0..3 {
                    friction[i] = rows.axes[i] * result.z[r0 + 1 + i];
                    for k in 0..6 {
                        wrench_sum[rows.body][k] += friction[i] * rows.friction_wrenches[i][k];
                    }
                }
            }
            contacts.push(ContactImpulses {
                vertex_impulses,
                friction,
                sigma: 0.0,
            });
        }
        let sweeps = if polish { 3 } else { 0 };
        for _sweep in 0..sweeps {
            self.correct_normal_impulses(bodies, &mut contacts, &mut wrench_sum);
            for (rows, imp) in self.contacts.iter().zip(contacts.iter_mut()) {
                let Some(rows) = rows else { continue };
                if rows.soc_row.is_none() {
                    continue;
                }
                let b = rows.body;
                let body = &bodies[b];
                let wf = &rows.friction_wrenches;
                // Remove this contact's friction, then solve its local problem.
                for i in 0..3 {
                    for k in 0..6 {
                        wrench_sum[b][k] -= imp.friction[i] * wf[i][k];
                    }
                }
                let dv = solve6(&body.mass, &wrench_sum[b]);
                let mut nu0 = body.free_velocity;
                for k in 0..6 {
                    nu0[k] += dv[k];
                }
                let minv_w: Vec<[f64; 6]> = wf.iter().map(|w| solve6(&body.mass, w)).collect();
                let mut a = [[0.0; 3]; 3];
                let mut u0 = [0.0; 3];
                for i in 0..3 {
                    u0[i] = dot6(&wf[i], &nu0);
                    for j in 0..3 {
                        a[i][j] = dot6(&wf[i], &minv_w[j]);
                    }
                }
                let pn: f64 = imp.vertex_impulses.iter().map(|(_, l)| l).sum();
                let (p, sigma) = local_friction(&a, &u0, &rows.axes, rows.mu * pn);
                imp.friction = p;
                imp.sigma = sigma;
                for i in 0..3 {
                    for k in 0..6 {
                        wrench_sum[b][k] += p[i] * wf[i][k];
                    }
                }
            }
        }
        let velocities: Vec<[f64; 6]> = bodies
            .iter()
            .enumerate()
            .map(|(b, body)| {
                let dv = solve6(&body.mass, &wrench_sum[b]);
                let mut nu = body.free_velocity;
                for i in 0..6 {
                    nu[i] += dv[i];
                }
                nu
            })
            .collect();
        if !polish {
            // σ = ‖E u_T‖ at the new velocities (the relaxation's slip).
            for (rows, imp) in self.contacts.iter().zip(contacts.iter_mut()) {
                if let Some(rows) = rows {
                    let nu = &velocities[rows.body];
                    imp.sigma = (0..3)
                        .map(|i| (rows.axes[i] * dot6(&rows.friction_wrenches[i], nu)).powi(2))
                        .sum::<f64>()
                        .sqrt();
                }
            }
        }
        ConicPoint {
            velocities,
            contacts,
        }
    }
}

impl StepQp {
    /// Normal part of the active-set polish: with the friction impulses fixed, corrects the
    /// normal impulses of the loaded vertices (`λ_j > 0`) of each body by the minimum-norm step
    /// that makes their linearised gaps `g_j/h + W_{n,j}ᵀ(ν − ν^k)` vanish, where
    /// `ν = ν_free + M⁻¹ Σ W p`: the Delassus system `W_Jᵀ M⁻¹ W_J δλ = −gap` solved by a
    /// pseudo-inverse (four coplanar vertices make it singular; the ECP stays unique). A
    /// correction that would make some `λ_j` negative is scaled back to keep them ≥ 0.
    fn correct_normal_impulses(
        &self,
        bodies: &[BodyDynamics],
        contacts: &mut [ContactImpulses],
        wrench_sum: &mut [[f64; 6]],
    ) {
        for (b, body) in bodies.iter().enumerate() {
            // (contact, position in the contact's vertex list) of every loaded vertex.
            let mut loaded: Vec<(usize, usize)> = Vec::new();
            for (c, rows) in self.contacts.iter().enumerate() {
                let Some(rows) = rows else { continue };
                if rows.body != b {
                    continue;
                }
                for (k, &(_, l)) in contacts[c].vertex_impulses.iter().enumerate() {
                    if l > 0.0 {
                        loaded.push((c, k));
                    }
                }
            }
            if loaded.is_empty() {
                continue;
            }
            let w: Vec<[f64; 6]> = loaded
                .iter()
                .filter_map(|&(c, k)| self.contacts[c].as_ref().map(|r| r.normal_wrenches[k]))
                .collect();
            if w.len() != loaded.len() {
                continue;
            }
            let dv = solve6(&body.mass, &wrench_sum[b]);
            let mut nu = body.free_velocity;
            for i in 0..6 {
                nu[i] += dv[i];
            }
            let minv_w: Vec<[f64; 6]> = w.iter().map(|x| solve6(&body.mass, x)).collect();
            let k = loaded.len();
            let mut d = vec![vec![0.0; k]; k];
            let mut r = vec![0.0; k];
            for i in 0..k {
                for j in 0..k {
                    d[i][j] = dot6(&w[i], &minv_w[j]);
                }
                let (c, kk) = loaded[i];
                let rate = self.contacts[c]
                    .as_ref()
                    .map_or(0.0, |rows| rows.gap_rates[kk]);
                r[i] = -(rate + dot6(&w[i], &nu));
            }
            let Some(delta) = pseudo_solve(d, &r) else {
                continue;
            };
            // Largest step in [0, 1] keeping every λ ≥ 0.
            let mut alpha: f64 = 1.0;
            for (i, &(c, kk)) in loaded.iter().enumerate() {
                let l = contacts[c].vertex_impulses[kk].1;
                if delta[i] < 0.0 && l + delta[i] < 0.0 {
                    alpha = alpha.min(l / -delta[i]);
                }
            }
            for (i, &(c, kk)) in loaded.iter().enumerate() {
                let step = alpha * delta[i];
                let entry = &mut contacts[c].vertex_impulses[kk];
                entry.1 = (entry.1 + step).max(0.0);
                for j in 0..6 {
                    wrench_sum[b][j] += step * w[i][j];
                }
            }
        }
    }
}

/// Minimum-norm solution of the symmetric positive semi-definite system `D x = r` (cyclic
/// Jacobi eigen-decomposition, eigenvalues below `1e-12` of the largest dropped).
fn pseudo_solve(mut d: Vec<Vec<f64>>, r: &[f64]) -> Option<Vec<f64>> {
    let n = r.len();
    let mut v = vec![vec![0.0; n]; n];
    for i in 0..n {
        v[i][i] = 1.0;
    }
    for _sweep in 0..60 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| d[i][j] * d[i][j])
            .sum();
        let diag: f64 = (0..n).map(|i| d[i][i] * d[i][i]).sum();
        if off.is_nan() || off <= 1e-30 * diag {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if d[p][q] == 0.0 {
                    continue;
                }
                let theta = (d[q][q] - d[p][p]) / (2.0 * d[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (dkp, dkq) = (d[k][p], d[k][q]);
                    d[k][p] = c * dkp - s * dkq;
                    d[k][q] = s * dkp + c * dkq;
                }
                for k in 0..n {
                    let (dpk, dqk) = (d[p][k], d[q][k]);
                    d[p][k] = c * dpk - s * dqk;
                    d[q][k] = s * dpk + c * dqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k][p], v[k][q]);
                    v[k][p] = c * vkp - s * vkq;
                    v[k][q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let max_eig = (0..n).map(|i| d[i][i].abs()).fold(0.0, f64::max);
    if max_eig.is_nan() || max_eig <= 0.0 || !max_eig.is_finite() {
        return None;
    }
    let mut x = vec![0.0; n];
    for k in 0..n {
        let e = d[k][k];
        if e > 1e-12 * max_eig {
            let proj: f64 = (0..n).map(|i| v[i][k] * r[i]).sum::<f64>() / e;
            for i in 0..n {
                x[i] += proj * v[i][k];
            }
        }
    }
    if x.iter().all(|v| v.is_finite()) {
        Some(x)
    } else {
        None
    }
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
/// definite. Returns the impulse and the slip `σ = ‖E u‖`, `u = u₀ + A p`.
///
/// Sticking when the unconstrained minimiser `−A⁻¹u₀` is inside the ellipsoid (`u = 0`,
/// `σ = 0`). Otherwise the KKT conditions `A p + u₀ + η E⁻² p = 0`, `‖E⁻¹p(η)‖ = ρ` give
/// `p = −ρ E² u / ‖E u‖` with `η = σ/ρ`: the multiplier `η > 0` is found by Newton's method on
/// the secular equation `1/‖E⁻¹p(η)‖ = 1/ρ` (as in Moré–Sorensen trust-region solvers),
/// safeguarded by bisection.
pub(crate) fn local_friction(
    a: &[[f64; 3]; 3],
    u0: &[f64; 3],
    axes: &[f64; 3],
    rho: f64,
) -> ([f64; 3], f64) {
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
        return ([0.0; 3], slip(&[0.0; 3]));
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
        return ([0.0; 3], slip(&[0.0; 3]));
    };
    if scaled(&p0) <= rho {
        return (p0, 0.0);
    }
    // ψ(η) = ‖E⁻¹p(η)‖ decreases from ψ(0) > ρ to 0: bracket the root, then Newton on 1/ψ.
    let mut lo = 0.0;
    let mut hi = 1.0f64;
    let scale_a = (0..3)
        .map(|i| a[i][i] * axes[i] * axes[i])
        .fold(0.0, f64::max);
    if scale_a > 0.0 && scale_a.is_finite() {
        hi = scale_a;
    }
    let mut guard = 0;
    while p_of(hi).is_none_or(|p| scaled(&p) > rho) && guard < 200 {
        lo = hi;
        hi *= 4.0;
        guard += 1;
    }
    let mut eta = 0.5 * (lo + hi);
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
    (p, slip(&p))
}

/// Solves the 6×6 symmetric positive definite system `M x = r` (Cholesky); a non-positive pivot
/// (not a mass matrix) gives zero, never NaN.
fn solve6(m: &[[f64; 6]; 6], r: &[f64; 6]) -> [f64; 6] {
    let mut l = [[0.0f64; 6]; 6];
    for i in 0..6 {
        for j in 0..=i {
            let mut s = m[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                if s.is_nan() || s <= 0.0 {
                    return [0.0; 6];
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0; 6];
    for i in 0..6 {
        let mut s = r[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; 6];
    for i in (0..6).rev() {
        let mut s = y[i];
        for k in i + 1..6 {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn local_friction_sticks_or_slides_exactly() {
        let a = [[0.2, 0.01, 0.0], [0.01, 0.3, 0.02], [0.0, 0.02, 0.5]];
        let axes = [1.0, 1.0, 0.1];
        // Small slip: sticks, u = 0.
        let (p, sigma) = local_friction(&a, &[0.01, -0.02, 0.001], &axes, 1.0);
        assert_eq!(sigma, 0.0);
        for i in 0..3 {
            let u: f64 = 0.01 * [1.0, -2.0, 0.1][i] + (0..3).map(|j| a[i][j] * p[j]).sum::<f64>();
            assert!(u.abs() < 1e-15, "{u}");
        }
        // Large slip: slides, p = −ρ E² u / ‖E u‖.
        let u0 = [1.0, 0.5, 0.3];
        let rho = 0.4;
        let (p, sigma) = local_friction(&a, &u0, &axes, rho);
        assert!(sigma > 0.0);
        for i in 0..3 {
            let u = u0[i] + (0..3).map(|j| a[i][j] * p[j]).sum::<f64>();
            let want = -rho * axes[i] * axes[i] * u / sigma;
            assert!((p[i] - want).abs() < 1e-14, "{i}: {} vs {want}", p[i]);
        }
    }

    #[test]
    fn pseudo_solve_gives_the_minimum_norm_solution() {
        // Rank 1: D = u uᵀ with u = (1, 1); r = (2, 2) ⇒ x = (1, 1).
        let d = vec![vec![1.0, 1.0], vec![1.0, 1.0]];
        let x = pseudo_solve(d, &[2.0, 2.0]).expect("solvable");
        assert!(
            (x[0] - 1.0).abs() < 1e-12 && (x[1] - 1.0).abs() < 1e-12,
            "{x:?}"
        );
        let d = vec![
            vec![4.0, 1.0, 0.0],
            vec![1.0, 3.0, 0.5],
            vec![0.0, 0.5, 2.0],
        ];
        let r = [1.0, -2.0, 0.5];
        let x = pseudo_solve(d.clone(), &r).expect("solvable");
        for i in 0..3 {
            let dx: f64 = (0..3).map(|j| d[i][j] * x[j]).sum();
            assert!((dx - r[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn solve6_inverts_a_mass_matrix() {
        let mut m = [[0.0; 6]; 6];
        for i in 0..3 {
            m[i][i] = 10.0;
        }
        m[3][3] = 2.0;
        m[4][4] = 3.0;
        m[5][5] = 1.0;
        m[3][4] = 0.5;
        m[4][3] = 0.5;
        let r = [1.0, -2.0, 3.0, 0.5, 0.25, -1.0];
        let x = solve6(&m, &r);
        for i in 0..6 {
            let mx: f64 = (0..6).map(|j| m[i][j] * x[j]).sum();
            assert!((mx - r[i]).abs() < 1e-14);
        }
        m[5][5] = -1.0;
        assert_eq!(solve6(&m, &r), [0.0; 6]);
    }
}
