//! A dense primal-dual interior-point method for the conic backend's small QPs
//! (`docs/latency.md#conic-backend`): `min ½ xᵀPx + qᵀx  s.t.  A x + s = b,  s ∈ K`, K a product
//! of non-negative orthants and second-order cones, as [`super::qp::ConicQp`] holds it.
//!
//! The step QP has 7 variables and 8 rows on the desk; clarabel's sparse machinery (equilibration,
//! sparse LDLᵀ, iterative refinement, its homogeneous embedding) spends about 6 µs per iteration
//! on it. This is the textbook infeasible-start method with Nesterov–Todd scaling and Mehrotra's
//! predictor–corrector (Vandenberghe, "The CVXOPT linear and quadratic cone program solvers",
//! 2010, §§ 3–5), on dense matrices: one Cholesky factorisation of `P + AᵀW⁻²A` per iteration.
//!
//! It stops by clarabel's own tests (relative primal and dual residuals at most `tol_feas`,
//! absolute or relative duality gap at most `tol_gap_abs`/`tol_gap_rel`), on the unscaled data,
//! so its answer meets the same tolerances; when it does not get there (iteration limit, a
//! factorisation that fails, a zero cone, a problem too large to be worth a dense solve) it
//! returns `None` and the caller solves the QP with clarabel.

use clarabel::solver::{DefaultSettings, SolverStatus};

use super::qp::{Cone, ConicQp, QpResult};

/// Largest number of variables solved densely (the step QP of one body has 7 to ~20).
pub(crate) const MAX_VARIABLES: usize = 48;

/// Fraction of the largest step to the cone's boundary taken: 0.99, as clarabel's and CVXOPT's
/// defaults (the backend's 0.9 for clarabel, `docs/decisions.md`, would cost about twice the
/// iterations here: the gap falls by at most that fraction per iteration).
const STEP_FRACTION: f64 = 0.99;

/// Iterations without a better iterate after which the method stops.
const STALL_ITERATIONS: u32 = 2;

/// `K = P + AᵀW⁻²A` and its Cholesky factor.
struct Factored<'a> {
    p: &'a [f64],
    matrix: &'a [f64],
    factor: &'a [f64],
}

impl Factored<'_> {
    /// Solves `K x = rhs` in place, with one step of iterative refinement (K's condition grows
    /// like the ratio of the largest to the smallest `z_i/s_i` as the method converges).
    fn solve(&self, x: &mut [f64]) {
        let n = x.len();
        let rhs = x.to_vec();
        cholesky_solve(self.factor, n, x);
        let kx = mat_vec(self.matrix, x, n, n);
        let mut r: Vec<f64> = (0..n).map(|i| rhs[i] - kx[i]).collect();
        cholesky_solve(self.factor, n, &mut r);
        for i in 0..n {
            x[i] += r[i];
        }
    }
}

/// One cone of K: first row, dimension, second-order or not.
#[derive(Clone, Copy, Debug)]
struct Block {
    first: usize,
    dim: usize,
    soc: bool,
}

/// The Nesterov–Todd scaling of one cone at `(s, z)`: `W` (symmetric), `W⁻¹`, `λ = W z = W⁻¹ s`.
struct Scaling {
    /// `W` of each block, dense `dim × dim` (row-major), in block order.
    w: Vec<Vec<f64>>,
    /// `W⁻¹` of each block.
    w_inv: Vec<Vec<f64>>,
    /// `W²` of each block.
    w_squared: Vec<Vec<f64>>,
    /// `λ`, one entry per row.
    lambda: Vec<f64>,
}

/// Solves `qp` with the dense interior-point method, or `None` (the caller falls back to
/// clarabel). The answer, when there is one, meets `settings`' tolerances.
pub(crate) fn solve(qp: &ConicQp, settings: &DefaultSettings<f64>) -> Option<QpResult> {
    let n = qp.n;
    let m = qp.rows();
    if n == 0 || n > MAX_VARIABLES || m == 0 {
        return None;
    }
    let mut blocks = Vec::with_capacity(qp.cones.len());
    let mut row = 0;
    for cone in &qp.cones {
        match *cone {
            Cone::Zero(_) => return None,
            Cone::Nonnegative(k) => {
                for _ in 0..k {
                    blocks.push(Block {
                        first: row,
                        dim: 1,
                        soc: false,
                    });
                    row += 1;
                }
            }
            Cone::SecondOrder(k) => {
                blocks.push(Block {
                    first: row,
                    dim: k,
                    soc: k > 1,
                });
                row += k;
            }
        }
    }
    if row != m {
        return None;
    }
    let mut p = vec![0.0; n * n];
    for &(i, j, v) in &qp.p {
        p[i * n + j] += v;
        if i != j {
            p[j * n + i] += v;
        }
    }
    let mut a = vec![0.0; m * n];
    for &(i, j, v) in &qp.a {
        a[i * n + j] += v;
    }
    let (q, b) = (&qp.q, &qp.b);
    if !p.iter().chain(&a).chain(q).chain(b).all(|v| v.is_finite()) {
        return None;
    }
    let degree = blocks.len() as f64;

    // Starting point (Vandenberghe 2010, § 5.3): the least-squares point of the equalities,
    // s and z shifted into the interior of K.
    let mut k = p.clone();
    add_at_a(&mut k, &a, m, n);
    let mut x: Vec<f64> = (0..n)
        .map(|j| -q[j] + (0..m).map(|i| a[i * n + j] * b[i]).sum::<f64>())
        .collect();
    cholesky(&mut k, n)?;
    cholesky_solve(&k, n, &mut x);
    let ax = mat_vec(&a, &x, m, n);
    let mut s: Vec<f64> = (0..m).map(|i| b[i] - ax[i]).collect();
    let mut z: Vec<f64> = s.iter().map(|v| -v).collect();
    shift_into_cone(&mut s, &blocks);
    shift_into_cone(&mut z, &blocks);

    let norm_b = inf_norm(b);
    let norm_q = inf_norm(q);
    // (score, iteration) of the best iterate: the method stops when it no longer improves.
    let mut best: (f64, u32) = (f64::INFINITY, 0);
    for iteration in 0..settings.max_iter {
        let ax = mat_vec(&a, &x, m, n);
        let px = mat_vec(&p, &x, n, n);
        let atz = mat_t_vec(&a, &z, m, n);
        let rx: Vec<f64> = (0..n).map(|j| px[j] + q[j] + atz[j]).collect();
        let rz: Vec<f64> = (0..m).map(|i| ax[i] + s[i] - b[i]).collect();
        let xpx = dot(&x, &px);
        let cost_primal = 0.5 * xpx + dot(q, &x);
        let cost_dual = -0.5 * xpx - dot(b, &z);
        let gap_abs = (cost_primal - cost_dual).abs();
        let gap_rel = gap_abs / cost_primal.abs().min(cost_dual.abs()).max(1.0);
        let (nx, ns, nz) = (inf_norm(&x), inf_norm(&s), inf_norm(&z));
        let res_primal = inf_norm(&rz) / (norm_b + nx + ns).max(1.0);
        let res_dual = inf_norm(&rx) / (norm_q + nx + nz).max(1.0);
        if !(res_primal.is_finite() && res_dual.is_finite() && gap_abs.is_finite()) {
            return None;
        }
        let score = (res_primal / settings.tol_feas)
            .max(res_dual / settings.tol_feas)
            .max((gap_abs / settings.tol_gap_abs).min(gap_rel / settings.tol_gap_rel));
        if score <= 1.0 {
            return Some(QpResult {
                x,
                z,
                s,
                status: SolverStatus::Solved,
                iterations: iteration,
            });
        }
        if score < best.0 {
            best = (score, iteration);
        } else if score > 10.0 * best.0 || iteration >= best.1 + STALL_ITERATIONS {
            // Lost its digits (near-degenerate cone entries, sliding friction with tiny torsion,
            // make the eliminated system lose the dual residual's last digits): clarabel solves
            // the QP.
            return None;
        }
        let scaling = nt_scaling(&s, &z, &blocks)?;
        // K = P + Aᵀ W⁻² A, factored once for the predictor and the corrector.
        let mut kkt = p.clone();
        let h = inverse_squares(&scaling, &blocks);
        add_at_h_a(&mut kkt, &a, &h, &blocks, n);
        let unfactored = kkt.clone();
        cholesky(&mut kkt, n)?;
        let kkt = Factored {
            p: &p,
            matrix: &unfactored,
            factor: &kkt,
        };
        let mu = dot(&s, &z) / degree;
        let lambda = &scaling.lambda;
        // Predictor (affine scaling): λ∘(W⁻¹ds + W dz) = −λ∘λ, i.e. t = −λ.
        let t_aff: Vec<f64> = lambda.iter().map(|v| -v).collect();
        let (_, ds_a, dz_a) = newton_direction(&kkt, &a, &h, &scaling, &blocks, &rx, &rz, &t_aff);
        let alpha_a = step_length(&s, &ds_a, &blocks).min(step_length(&z, &dz_a, &blocks));
        let alpha_a = alpha_a.min(1.0);
        let sigma = (1.0 - alpha_a).clamp(0.0, 1.0).powi(3);
        // Corrector: λ∘(W⁻¹ds + W dz) = −λ∘λ − (W⁻¹ds_a)∘(W dz_a) + σμe.
        let ds_scaled = apply_blocks(&scaling.w_inv, &ds_a, &blocks);
        let dz_scaled = apply_blocks(&scaling.w, &dz_a, &blocks);
        let mut r = jordan_product(lambda, lambda, &blocks);
        let cross = jordan_product(&ds_scaled, &dz_scaled, &blocks);
        for i in 0..m {
            r[i] = -r[i] - cross[i];
        }
        for blk in &blocks {
            r[blk.first] += sigma * mu;
        }
        let t = jordan_divide(lambda, &r, &blocks)?;
        let (dx, ds, dz) = newton_direction(&kkt, &a, &h, &scaling, &blocks, &rx, &rz, &t);
        let alpha_max = step_length(&s, &ds, &blocks).min(step_length(&z, &dz, &blocks));
        let alpha = (STEP_FRACTION * alpha_max).min(1.0);
        if !(alpha.is_finite() && alpha > 0.0) {
            return None;
        }
        for j in 0..n {
            x[j] += alpha * dx[j];
        }
        for i in 0..m {
            s[i] += alpha * ds[i];
            z[i] += alpha * dz[i];
        }
    }
    None
}

/// Solves `P x + Aᵀy = r1`, `A x − W² y = r2` by elimination: `y = W⁻²(A x − r2)`,
/// `(P + AᵀW⁻²A) x = r1 + AᵀW⁻² r2`.
fn eliminate(
    kkt: &Factored<'_>,
    a: &[f64],
    h: &[Vec<f64>],
    blocks: &[Block],
    r1: &[f64],
    r2: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let n = r1.len();
    let m = r2.len();
    let hr2 = apply_blocks(h, r2, blocks);
    let athr2 = mat_t_vec(a, &hr2, m, n);
    let mut x: Vec<f64> = (0..n).map(|j| r1[j] + athr2[j]).collect();
    kkt.solve(&mut x);
    let ax = mat_vec(a, &x, m, n);
    let v: Vec<f64> = (0..m).map(|i| ax[i] - r2[i]).collect();
    (x, apply_blocks(h, &v, blocks))
}

/// The direction of the linearised KKT system with right-hand side `t` of the scaled
/// complementarity rows: `P dx + Aᵀdz = −r_x`, `A dx + ds = −r_z`, `W⁻¹ds + W dz = t`.
fn newton_direction(
    kkt: &Factored<'_>,
    a: &[f64],
    h: &[Vec<f64>],
    scaling: &Scaling,
    blocks: &[Block],
    rx: &[f64],
    rz: &[f64],
    t: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = rx.len();
    let m = rz.len();
    // The augmented system [P Aᵀ; A −W²] [dx; dz] = [−r_x; −r_z − W t], by elimination of dz
    // (dz = W⁻²(A dx + r_z + W t)), then refined twice on the augmented system itself: the
    // elimination loses the dual residual's digits once W⁻² spans many orders of magnitude.
    let wt = apply_blocks(&scaling.w, t, blocks);
    let r1: Vec<f64> = rx.iter().map(|v| -v).collect();
    let r2: Vec<f64> = (0..m).map(|i| -rz[i] - wt[i]).collect();
    let (mut dx, mut dz) = eliminate(kkt, a, h, blocks, &r1, &r2);
    for _ in 0..2 {
        let pdx = mat_vec(kkt.p, &dx, n, n);
        let atdz = mat_t_vec(a, &dz, m, n);
        let adx = mat_vec(a, &dx, m, n);
        let w2dz = apply_blocks(&scaling.w_squared, &dz, blocks);
        let e1: Vec<f64> = (0..n).map(|j| r1[j] - pdx[j] - atdz[j]).collect();
        let e2: Vec<f64> = (0..m).map(|i| r2[i] - adx[i] + w2dz[i]).collect();
        let (cx, cz) = eliminate(kkt, a, h, blocks, &e1, &e2);
        for j in 0..n {
            dx[j] += cx[j];
        }
        for i in 0..m {
            dz[i] += cz[i];
        }
    }
    // ds from the primal rows themselves (not W(t − W dz), the same in exact arithmetic), so
    // that the primal residual falls by exactly (1 − α).
    let adx = mat_vec(a, &dx, m, n);
    let ds: Vec<f64> = (0..m).map(|i| -rz[i] - adx[i]).collect();
    (dx, ds, dz)
}

/// The Nesterov–Todd scaling at `(s, z)` in the interior of K (Vandenberghe 2010, § 4); `None`
/// when a point has left the interior.
fn nt_scaling(s: &[f64], z: &[f64], blocks: &[Block]) -> Option<Scaling> {
    let mut w = Vec::with_capacity(blocks.len());
    let mut w_inv = Vec::with_capacity(blocks.len());
    let mut lambda = vec![0.0; s.len()];
    for blk in blocks {
        let (o, d) = (blk.first, blk.dim);
        if !blk.soc {
            let (si, zi) = (s[o], z[o]);
            if si.is_nan() || zi.is_nan() || si <= 0.0 || zi <= 0.0 {
                return None;
            }
            let wi = (si / zi).sqrt();
            w.push(vec![wi]);
            w_inv.push(vec![1.0 / wi]);
            lambda[o] = (si * zi).sqrt();
            continue;
        }
        let ss = &s[o..o + d];
        let zz = &z[o..o + d];
        let s_det = soc_det(ss);
        let z_det = soc_det(zz);
        if s_det.is_nan() || z_det.is_nan() || s_det <= 0.0 || z_det <= 0.0 || ss[0] <= 0.0 {
            return None;
        }
        let (s_norm, z_norm) = (s_det.sqrt(), z_det.sqrt());
        let sb: Vec<f64> = ss.iter().map(|v| v / s_norm).collect();
        let zb: Vec<f64> = zz.iter().map(|v| v / z_norm).collect();
        let gamma = ((1.0 + dot(&sb, &zb)) / 2.0).sqrt();
        // w̄ = (s̄ + J z̄)/(2γ), w̄ᵀJw̄ = 1.
        let mut wb: Vec<f64> = (0..d)
            .map(|i| if i == 0 { sb[0] + zb[0] } else { sb[i] - zb[i] })
            .collect();
        for v in &mut wb {
            *v /= 2.0 * gamma;
        }
        let beta = (s_det / z_det).sqrt().sqrt();
        // W = β [w̄₀ w̄₁ᵀ; w̄₁ I + w̄₁w̄₁ᵀ/(1 + w̄₀)], W⁻¹ = β⁻¹ J (W/β) J.
        let mut wm = vec![0.0; d * d];
        let mut wi = vec![0.0; d * d];
        for i in 0..d {
            for j in 0..d {
                let v = if i == 0 && j == 0 {
                    wb[0]
                } else if i == 0 {
                    wb[j]
                } else if j == 0 {
                    wb[i]
                } else {
                    f64::from(u8::from(i == j)) + wb[i] * wb[j] / (1.0 + wb[0])
                };
                let sign = if (i == 0) != (j == 0) { -1.0 } else { 1.0 };
                wm[i * d + j] = beta * v;
                wi[i * d + j] = sign * v / beta;
            }
        }
        for i in 0..d {
            lambda[o + i] = (0..d).map(|j| wm[i * d + j] * zz[j]).sum();
        }
        w.push(wm);
        w_inv.push(wi);
    }
    let w_squared = blocks
        .iter()
        .zip(&w)
        .map(|(blk, wb)| square(wb, blk.dim))
        .collect();
    Some(Scaling {
        w,
        w_inv,
        w_squared,
        lambda,
    })
}

/// `W⁻²` of each block.
fn inverse_squares(scaling: &Scaling, blocks: &[Block]) -> Vec<Vec<f64>> {
    blocks
        .iter()
        .zip(&scaling.w_inv)
        .map(|(blk, wi)| square(wi, blk.dim))
        .collect()
}

/// The square of a symmetric `d × d` matrix.
fn square(w: &[f64], d: usize) -> Vec<f64> {
    let mut h = vec![0.0; d * d];
    for i in 0..d {
        for j in 0..d {
            h[i * d + j] = (0..d).map(|k| w[i * d + k] * w[k * d + j]).sum();
        }
    }
    h
}

/// `x ↦` the block-diagonal matrix `mats` times `x`.
fn apply_blocks(mats: &[Vec<f64>], x: &[f64], blocks: &[Block]) -> Vec<f64> {
    let mut y = vec![0.0; x.len()];
    for (blk, mat) in blocks.iter().zip(mats) {
        let (o, d) = (blk.first, blk.dim);
        for i in 0..d {
            y[o + i] = (0..d).map(|j| mat[i * d + j] * x[o + j]).sum();
        }
    }
    y
}

/// `K += AᵀA` (`A` dense `m × n`, row-major).
fn add_at_a(k: &mut [f64], a: &[f64], m: usize, n: usize) {
    for i in 0..m {
        let row = &a[i * n..(i + 1) * n];
        for r in 0..n {
            if row[r] == 0.0 {
                continue;
            }
            for c in 0..n {
                k[r * n + c] += row[r] * row[c];
            }
        }
    }
}

/// `K += Aᵀ H A` with `H` block diagonal: `Σ_blocks A_bᵀ H_b A_b`.
fn add_at_h_a(k: &mut [f64], a: &[f64], h: &[Vec<f64>], blocks: &[Block], n: usize) {
    for (blk, hb) in blocks.iter().zip(h) {
        let (o, d) = (blk.first, blk.dim);
        // G = H_b A_b (d × n).
        let mut g = vec![0.0; d * n];
        for i in 0..d {
            for kk in 0..d {
                let hik = hb[i * d + kk];
                if hik == 0.0 {
                    continue;
                }
                let row = &a[(o + kk) * n..(o + kk + 1) * n];
                for c in 0..n {
                    g[i * n + c] += hik * row[c];
                }
            }
        }
        for i in 0..d {
            let row = &a[(o + i) * n..(o + i + 1) * n];
            for r in 0..n {
                if row[r] == 0.0 {
                    continue;
                }
                for c in 0..n {
                    k[r * n + c] += row[r] * g[i * n + c];
                }
            }
        }
    }
}

/// `s₀² − ‖s₁‖²` of a second-order cone entry.
fn soc_det(s: &[f64]) -> f64 {
    let r = s[1..].iter().map(|v| v * v).sum::<f64>().sqrt();
    (s[0] - r) * (s[0] + r)
}

/// Moves `s` into the interior of K by a multiple of the identity element when it is not
/// inside by a margin (Vandenberghe 2010, § 5.3).
fn shift_into_cone(s: &mut [f64], blocks: &[Block]) {
    let outside = blocks
        .iter()
        .map(|blk| {
            let v = &s[blk.first..blk.first + blk.dim];
            if blk.soc {
                v[1..].iter().map(|x| x * x).sum::<f64>().sqrt() - v[0]
            } else {
                -v[0]
            }
        })
        .fold(f64::NEG_INFINITY, f64::max);
    let scale = inf_norm(s).max(1.0);
    if outside >= -1e-8 * scale {
        for blk in blocks {
            s[blk.first] += 1.0 + outside;
        }
    }
}

/// The Jordan product `u ∘ v` per block (`(uᵀv, u₀v₁ + v₀u₁)` on a second-order cone).
fn jordan_product(u: &[f64], v: &[f64], blocks: &[Block]) -> Vec<f64> {
    let mut out = vec![0.0; u.len()];
    for blk in blocks {
        let (o, d) = (blk.first, blk.dim);
        out[o] = (0..d).map(|i| u[o + i] * v[o + i]).sum();
        for i in 1..d {
            out[o + i] = u[o] * v[o + i] + v[o] * u[o + i];
        }
    }
    out
}

/// `t` with `λ ∘ t = r` per block; `None` when `λ` is not in the interior.
fn jordan_divide(lambda: &[f64], r: &[f64], blocks: &[Block]) -> Option<Vec<f64>> {
    let mut t = vec![0.0; r.len()];
    for blk in blocks {
        let (o, d) = (blk.first, blk.dim);
        let l = &lambda[o..o + d];
        if d == 1 {
            t[o] = r[o] / l[0];
            continue;
        }
        let det = soc_det(l);
        if det.is_nan() || det <= 0.0 || l[0] <= 0.0 {
            return None;
        }
        let l1r1: f64 = (1..d).map(|i| l[i] * r[o + i]).sum();
        let t0 = (l[0] * r[o] - l1r1) / det;
        t[o] = t0;
        for i in 1..d {
            t[o + i] = (r[o + i] - t0 * l[i]) / l[0];
        }
    }
    t.iter().all(|v| v.is_finite()).then_some(t)
}

/// The largest `α ≥ 0` with `s + α ds` in K (infinite when the ray stays inside).
fn step_length(s: &[f64], ds: &[f64], blocks: &[Block]) -> f64 {
    let mut alpha = f64::INFINITY;
    for blk in blocks {
        let (o, d) = (blk.first, blk.dim);
        if d == 1 {
            if ds[o] < 0.0 {
                alpha = alpha.min(-s[o] / ds[o]);
            }
            continue;
        }
        // f(α) = det(s + α ds) = aα² + bα + c, c > 0: its first positive root.
        let sv = &s[o..o + d];
        let dv = &ds[o..o + d];
        let qa = soc_det(dv);
        let qb = 2.0 * (sv[0] * dv[0] - (1..d).map(|i| sv[i] * dv[i]).sum::<f64>());
        let qc = soc_det(sv);
        let root = first_positive_root(qa, qb, qc);
        alpha = alpha.min(root);
        // The ray must also keep s₀ + α ds₀ > 0 (the other nappe of det > 0).
        if dv[0] < 0.0 {
            alpha = alpha.min(-sv[0] / dv[0]);
        }
    }
    alpha
}

/// The smallest positive root of `aα² + bα + c` with `c > 0`; infinity when there is none.
fn first_positive_root(a: f64, b: f64, c: f64) -> f64 {
    if c <= 0.0 {
        return 0.0;
    }
    let disc = b * b - 4.0 * a * c;
    if a == 0.0 {
        return if b < 0.0 { -c / b } else { f64::INFINITY };
    }
    if disc < 0.0 {
        return f64::INFINITY;
    }
    // Stable roots: q = −(b + sign(b)√disc)/2, roots q/a and c/q.
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    let mut best = f64::INFINITY;
    for r in [q / a, if q != 0.0 { c / q } else { f64::INFINITY }] {
        if r > 0.0 && r < best {
            best = r;
        }
    }
    best
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn inf_norm(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

/// `A x` for `A` dense `rows × cols`, row-major.
fn mat_vec(a: &[f64], x: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    (0..rows)
        .map(|i| dot(&a[i * cols..(i + 1) * cols], x))
        .collect()
}

/// `Aᵀ y` for `A` dense `rows × cols`, row-major.
fn mat_t_vec(a: &[f64], y: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    let mut out = vec![0.0; cols];
    for i in 0..rows {
        if y[i] == 0.0 {
            continue;
        }
        for j in 0..cols {
            out[j] += a[i * cols + j] * y[i];
        }
    }
    out
}

/// In-place Cholesky factorisation `K = L Lᵀ` (L in the lower triangle); `None` when `K` is not
/// numerically positive definite.
fn cholesky(k: &mut [f64], n: usize) -> Option<()> {
    for j in 0..n {
        let mut d = k[j * n + j];
        for p in 0..j {
            d -= k[j * n + p] * k[j * n + p];
        }
        if d.is_nan() || d <= 0.0 {
            return None;
        }
        let d = d.sqrt();
        k[j * n + j] = d;
        for i in j + 1..n {
            let mut v = k[i * n + j];
            for p in 0..j {
                v -= k[i * n + p] * k[j * n + p];
            }
            k[i * n + j] = v / d;
        }
    }
    Some(())
}

/// Solves `L Lᵀ x = rhs` in place with the factor of [`cholesky`].
fn cholesky_solve(l: &[f64], n: usize, x: &mut [f64]) {
    for i in 0..n {
        let mut v = x[i];
        for p in 0..i {
            v -= l[i * n + p] * x[p];
        }
        x[i] = v / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut v = x[i];
        for p in i + 1..n {
            v -= l[p * n + i] * x[p];
        }
        x[i] = v / l[i * n + i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conic::default_clarabel_settings;

    fn soc_block() -> Vec<Block> {
        vec![Block {
            first: 0,
            dim: 4,
            soc: true,
        }]
    }

    #[test]
    fn nt_scaling_maps_z_and_s_to_the_same_point() {
        let s = [2.0, 0.3, -0.5, 1.0];
        let z = [1.5, -0.2, 0.4, 0.1];
        let blocks = soc_block();
        let sc = nt_scaling(&s, &z, &blocks).expect("interior");
        let wz = apply_blocks(&sc.w, &z, &blocks);
        let wis = apply_blocks(&sc.w_inv, &s, &blocks);
        let back = apply_blocks(&sc.w, &wis, &blocks);
        for i in 0..4 {
            assert!((wz[i] - wis[i]).abs() < 1e-14, "{wz:?} vs {wis:?}");
            assert!((back[i] - s[i]).abs() < 1e-14, "W W⁻¹ s = {back:?}");
            assert!((wz[i] - sc.lambda[i]).abs() < 1e-14);
        }
        let t = jordan_divide(&sc.lambda, &s, &blocks).expect("interior");
        let lt = jordan_product(&sc.lambda, &t, &blocks);
        for i in 0..4 {
            assert!((lt[i] - s[i]).abs() < 1e-14, "{lt:?}");
        }
    }

    #[test]
    fn step_length_stops_on_the_cone_boundary() {
        let blocks = soc_block();
        let s = [1.0, 0.0, 0.0, 0.0];
        let ds = [0.0, 1.0, 0.0, 0.0];
        // ‖α e₁‖ = 1 at α = 1.
        assert!((step_length(&s, &ds, &blocks) - 1.0).abs() < 1e-15);
        let ds = [1.0, 0.5, 0.0, 0.0];
        assert_eq!(step_length(&s, &ds, &blocks), f64::INFINITY);
    }

    /// A step-like QP: `min ½‖x − x_f‖²_M` with four vertex rows coupled to a friction cone
    /// through `a` (the layout of `conic::step::build`), solved here and by clarabel.
    fn step_like(sticking: bool) -> ConicQp {
        let mut qp = ConicQp::new(7);
        let mass = [2.0, 2.0, 2.0, 0.3, 0.4, 0.5];
        let free = if sticking {
            [0.01, 0.0, -0.5, 0.0, 0.02, 0.0]
        } else {
            [1.0, 0.2, -0.5, 0.1, 0.0, 0.3]
        };
        for i in 0..6 {
            qp.add_p(i, i, mass[i]);
            qp.q[i] = -mass[i] * free[i];
        }
        let mu = 0.3;
        for (vx, vy) in [(0.5, 0.4), (-0.5, 0.4), (-0.5, -0.4), (0.5, -0.4)] {
            // W_n = [n; r × n], n = e_z, r = (vx, vy, −0.2).
            let w = [0.0, 0.0, 1.0, vy, -vx, 0.0];
            let mut coeffs: Vec<(usize, f64)> = (0..6).map(|i| (i, -w[i])).collect();
            coeffs.push((6, mu));
            qp.push_row(&coeffs, 0.001);
        }
        qp.cones.push(Cone::Nonnegative(4));
        qp.push_row(&[(6, -1.0)], 0.0);
        qp.push_row(&[(0, -1.0), (4, 0.2)], 0.0);
        qp.push_row(&[(1, -1.0), (3, -0.2)], 0.0);
        qp.push_row(&[(5, -0.1)], 0.0);
        qp.cones.push(Cone::SecondOrder(4));
        qp
    }

    #[test]
    fn agrees_with_clarabel_on_step_like_qps() {
        let settings = default_clarabel_settings();
        for sticking in [true, false] {
            let qp = step_like(sticking);
            // The sliding QP loses its last digits here: it is left to clarabel.
            if !sticking {
                assert!(solve(&qp, &settings).is_none());
                continue;
            }
            let dense = solve(&qp, &settings).expect("the dense method converges");
            assert_eq!(dense.status, SolverStatus::Solved);
            let reference = qp
                .solve(&default_clarabel_settings())
                .expect("clarabel solves it");
            assert_eq!(reference.status, SolverStatus::Solved);
            for (a, b) in dense.x.iter().zip(&reference.x) {
                assert!(
                    (a - b).abs() < 1e-9,
                    "x: {:?} vs {:?}",
                    dense.x,
                    reference.x
                );
            }
            for (a, b) in dense.z.iter().zip(&reference.z) {
                assert!(
                    (a - b).abs() < 1e-9,
                    "z: {:?} vs {:?}",
                    dense.z,
                    reference.z
                );
            }
            assert!(dense.iterations < 40, "{} iterations", dense.iterations);
        }
    }

    #[test]
    fn refuses_zero_cones_and_infeasible_problems() {
        let settings = default_clarabel_settings();
        let mut qp = ConicQp::new(1);
        qp.add_p(0, 0, 1.0);
        qp.push_row(&[(0, 1.0)], 1.0);
        qp.cones.push(Cone::Zero(1));
        assert!(solve(&qp, &settings).is_none());
        // x ≥ 1 and x ≤ −1: no answer, so clarabel is asked (and reports it).
        let mut qp = ConicQp::new(1);
        qp.add_p(0, 0, 1.0);
        qp.push_row(&[(0, -1.0)], -1.0);
        qp.push_row(&[(0, 1.0)], -1.0);
        qp.cones.push(Cone::Nonnegative(2));
        assert!(solve(&qp, &settings).is_none());
    }
}
