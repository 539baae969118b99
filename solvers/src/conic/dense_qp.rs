//! A dense primal-dual interior-point method for the conic backend's small QPs
//! (`docs/latency.md#conic-backend`): `min ½ xᵀPx + qᵀx  s.t.  A x + s = b,  s ∈ K`, K a product
//! of non-negative orthants and second-order cones, as [`super::qp::ConicQp`] holds it.
//!
//! The step QP has 7 variables and 8 rows on the desk; clarabel's sparse machinery (equilibration,
//! sparse LDLᵀ, iterative refinement, its homogeneous embedding) spends about 6 µs per iteration
//! on it. This is the textbook infeasible-start method with Nesterov–Todd scaling and Mehrotra's
//! predictor–corrector (Vandenberghe, "The CVXOPT linear and quadratic cone program solvers",
//! 2010, §§ 3–5) on dense matrices, with the choices that let it reach clarabel's 1e-12 on
//! sliding contacts, where the friction cone's `s` and `z` both approach its boundary
//! (`docs/latency.md#a-dense-qp-method-that-meets-clarabels-tolerances-branch-wip-conicqp-issues-18-and-15`):
//!
//! - each Newton system is CVXOPT's scaled KKT system `[P Ãᵀ; Ã −I]`, `Ã = W⁻¹A`, unknowns
//!   `dx` and `W dz`, refined on itself until its componentwise backward error is at round-off
//!   (not the unscaled `[P Aᵀ; A −W²]`, whose residual is in the units of `s`);
//! - it is solved by the Cholesky factor of its Schur complement `P + ÃᵀÃ` (`n × n`, 7 × 7 on
//!   the desk) and only when that is not positive definite or its refined solve stays above
//!   round-off (a body's velocity fixed by loaded rows of size 1e6 while its mass is of size
//!   1: `d5_collision`), by LU on the whole `(n + m)²` system for the rest of the QP;
//! - the Nesterov–Todd scaling is updated from the scaled step rather than recomputed from
//!   `s` and `z` (CVXOPT's `update_scaling`), and step lengths are taken in the scaled space;
//!   `W x`, `W⁻¹ x` are applied in the arrow (product) form rather than as dense matrices.
//!
//! It stops by clarabel's own tests (relative primal and dual residuals at most `tol_feas`,
//! absolute or relative duality gap at most `tol_gap_abs`/`tol_gap_rel`), on the unscaled data,
//! so its answer meets the same tolerances; when it does not get there (iteration limit, no
//! progress, a singular system, a zero cone, a problem too large to be worth a dense solve) it
//! returns `None` and the caller solves the QP with clarabel.
//!
//! The workspace ([`DenseQp`]) is kept by the backend between QPs: after the first QP of a
//! shape, an iteration allocates nothing.

use clarabel::solver::{DefaultSettings, SolverStatus};

use super::qp::{Cone, ConicQp, QpResult};

/// Largest number of variables solved densely (the step QP of one body has 7 to ~20).
pub(crate) const MAX_VARIABLES: usize = 48;

/// Largest size `n + m` of the augmented system solved densely: its LU costs `⅔(n + m)³`.
const MAX_KKT: usize = 96;

/// Fraction of the largest step to the cone's boundary taken: 0.995 (clarabel's and CVXOPT's
/// defaults are 0.99; the backend's 0.9 for clarabel, `docs/decisions.md`, would cost about
/// twice the iterations here: the gap falls by at most that fraction per iteration). 0.995 takes
/// the desk's QPs from 12.4 to 10.7 iterations (A6 110° 8.8 → 8.1; A5 tilted 9.0 → 9.5, T-bar
/// 9.9 → 10.1, D5 14.6 → 16.8) and moves the conic trajectories by at most 7e-13 (the settled
/// polish makes the answer independent of the QP's last digits;
/// `docs/latency.md#the-conic-desk-step-against-newtons-time-and-instructions-branch-wip-conicratio-issue-18`).
const STEP_FRACTION: f64 = 0.995;

/// Iterations without a better iterate after which the method stops, once its score (the
/// largest ratio of a residual or the gap to its tolerance) is below `STALL_SCORE`. Far from the
/// solution the infeasible-start iterates may worsen for a few iterations (the residuals fall
/// while the gap grows); only the iteration limit stops them there.
const STALL_ITERATIONS: u32 = 3;
const STALL_SCORE: f64 = 1e6;

/// Iterations at most (clarabel's limit applies when it is smaller); the method takes 6–12.
const MAX_ITERATIONS: u32 = 40;

/// The warm start's margin into the cones' interior, relative to the scale of `s` (the largest
/// entry of `s` and `b`) and of `z` (its largest entry). On the desk's QPs (400 steps), interior-point iterations per QP: standard start 10.8;
/// warm with 1e-1 5.6, 1e-2 5.4, 1e-3 6.0, 1e-4 5.6, 1e-6 6.4 (`docs/latency.md`). Too small a
/// margin leaves the start near the boundary, where the first steps are short; too large one
/// starts far from the answer.
const WARM_MARGIN: f64 = 1e-2;

/// Steps of iterative refinement of each KKT solve at most.
const REFINEMENT_STEPS: usize = 3;

/// Componentwise backward error of a KKT solve at which its refinement stops.
const BACKWARD_ERROR: f64 = 4.0 * f64::EPSILON;

/// Backward error above which a refined solve by the Schur complement is not trusted.
const SCHUR_BACKWARD_ERROR: f64 = 1e-14;

/// One cone of K: first row, dimension, second-order or not.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Block {
    first: usize,
    dim: usize,
    soc: bool,
}

/// The method's workspace: dense data, iterate, scaling, the factored KKT system and the
/// directions. Kept between QPs; its vectors only grow.
#[derive(Default)]
pub(crate) struct DenseQp {
    n: usize,
    m: usize,
    blocks: Vec<Block>,
    /// `P`, dense `n × n`, row-major.
    p: Vec<f64>,
    /// `A`, dense `m × n`, row-major.
    a: Vec<f64>,
    x: Vec<f64>,
    s: Vec<f64>,
    z: Vec<f64>,
    rx: Vec<f64>,
    rz: Vec<f64>,
    /// The scaling, per row: `√(s/z)` on a non-negative row; the normalised scaling point `w̄`
    /// (`w̄ᵀJw̄ = 1`) on a second-order cone, whose `W = η (2w̄w̄ᵀ − J)^{½}`.
    w: Vec<f64>,
    /// `η` of each second-order block, at its first row (1 on a non-negative row, where `w`
    /// carries the scale).
    eta: Vec<f64>,
    /// `λ = W z = W⁻¹ s`.
    lambda: Vec<f64>,
    /// The lower Cholesky factor of the Schur complement `P + ÃᵀÃ` (`n × n`, row-major) by
    /// which the scaled KKT system is solved.
    chol: Vec<f64>,
    /// The reciprocals of `chol`'s diagonal: the substitutions multiply by them
    /// ([`schur_solve`]).
    chol_inv_diag: Vec<f64>,
    /// Right-hand side, solution, residual and correction of the scaled KKT system, `n + m`
    /// each (the `x` rows first).
    rhs: Vec<f64>,
    sol: Vec<f64>,
    res: Vec<f64>,
    corr: Vec<f64>,
    /// Whether this QP's KKT systems are solved by [`DenseQp::lu`] (once the Schur complement
    /// was not numerically positive definite).
    use_lu: bool,
    /// The LU factors with partial pivoting of the whole `(n + m)²` scaled KKT matrix,
    /// row-major, and the row permutation: the fallback when the Schur complement's Cholesky
    /// fails (sized on first use).
    lu: Vec<f64>,
    pivots: Vec<usize>,
    dx: Vec<f64>,
    ds: Vec<f64>,
    dz: Vec<f64>,
    /// `W⁻¹ds` and `W dz` of the affine direction.
    u_affine: Vec<f64>,
    v_affine: Vec<f64>,
    /// `W⁻¹A`, dense `m × n`, row-major.
    scaled_a: Vec<f64>,
    /// Temporaries of length `m` and `n`.
    t: Vec<f64>,
    u: Vec<f64>,
    v: Vec<f64>,
    px: Vec<f64>,
    /// The last QP's answer and shape: the start of the next QP of the same shape when
    /// warm starts are asked for ([`DenseQp::solve_into`]).
    warm: WarmStart,
    /// Iterations of the last run of [`DenseQp::solve_densely`], whether it succeeded or not,
    /// and whether it started warm.
    spent: u32,
    started_warm: bool,
}

/// The answer of the last QP solved densely and its shape (`n` and the cones), kept for the
/// warm start of the next QP of that shape.
#[derive(Default)]
struct WarmStart {
    valid: bool,
    n: usize,
    blocks: Vec<Block>,
    x: Vec<f64>,
    s: Vec<f64>,
    z: Vec<f64>,
}

/// The file named by the environment variable `ECP_DENSE_QP_AUDIT`, read once: when it is set,
/// [`DenseQp::solve`] audits instead of solving (`DenseQp::audit`).
fn audit_file() -> Option<&'static std::path::Path> {
    static FILE: std::sync::OnceLock<Option<std::path::PathBuf>> = std::sync::OnceLock::new();
    FILE.get_or_init(|| std::env::var_os("ECP_DENSE_QP_AUDIT").map(Into::into))
        .as_deref()
}

/// `f(n)` with `n` a constant in the usual sizes, 7 and 8 variables (one body with one or two
/// friction cones): the kernels are inlined into each arm and their loops over `n` unrolled,
/// which removes the mispredicted exits of short loops of varying length (the Schur factor alone
/// had a fifth of the desk step's mispredicted branches,
/// `docs/latency.md#the-conic-desk-step-against-newtons-time-and-instructions-branch-wip-conicratio-issue-18`). The same
/// operations in the same order: the answers are the same to the bit.
#[inline(always)]
fn with_size<R>(n: usize, f: impl FnOnce(usize) -> R) -> R {
    match n {
        7 => f(7),
        8 => f(8),
        _ => f(n),
    }
}

/// Whether every entry of `v` is finite, without a branch per entry (`x − x` is 0 for a finite
/// `x`, NaN otherwise): the early exits of `iter().all(..)` over the QP's short vectors were a
/// fiftieth of the conic desk step's time (`docs/latency.md`, branch wip-conic3x).
#[allow(clippy::eq_op)] // `x − x` is the test itself: 0, or NaN for an infinite or NaN `x`.
fn all_finite(v: &[f64]) -> bool {
    v.iter().fold(0.0, |acc, &x| acc + (x - x)) == 0.0
}

/// `v` set to `len` zeros (allocates only when it must grow).
fn zeroed(v: &mut Vec<f64>, len: usize) {
    v.clear();
    v.resize(len, 0.0);
}

impl DenseQp {
    /// Solves `qp` into `out` (its vectors refilled, not reallocated), or returns `false` (the
    /// caller falls back to clarabel). The answer, when there is one, meets `settings`'
    /// tolerances.
    ///
    /// With `warm`, a QP of the same shape as the last one solved here starts from that QP's
    /// answer pushed into the cones' interior ([`DenseQp::warm_start`]); when that run does not
    /// meet the tolerances, the QP is solved again from the standard start. `out.iterations`
    /// counts both runs.
    pub(crate) fn solve_into(
        &mut self,
        qp: &ConicQp,
        settings: &DefaultSettings<f64>,
        warm: bool,
        out: &mut QpResult,
    ) -> bool {
        if let Some(path) = audit_file() {
            self.audit(qp, settings, path);
            return false;
        }
        let mut solved = self.solve_densely(qp, settings, warm);
        let mut iterations = self.spent;
        if solved.is_none() && self.started_warm {
            // The warm run failed (not only a QP this method refuses): the standard start.
            solved = self.solve_densely(qp, settings, false);
            iterations += self.spent;
        }
        self.warm.valid = solved.is_some() && self.m > 0;
        if self.warm.valid {
            self.warm.n = self.n;
            self.warm.blocks.clone_from(&self.blocks);
            self.warm.x.clone_from(&self.x);
            self.warm.s.clone_from(&self.s);
            self.warm.z.clone_from(&self.z);
        }
        if solved.is_none() {
            return false;
        }
        for (to, from) in [
            (&mut out.x, &self.x),
            (&mut out.z, &self.z),
            (&mut out.s, &self.s),
        ] {
            to.clear();
            to.extend_from_slice(from);
        }
        out.status = SolverStatus::Solved;
        out.iterations = iterations;
        true
    }

    /// [`DenseQp::solve_into`] into a new result.
    #[cfg(test)]
    pub(crate) fn solve(
        &mut self,
        qp: &ConicQp,
        settings: &DefaultSettings<f64>,
    ) -> Option<QpResult> {
        let mut out = QpResult::default();
        self.solve_into(qp, settings, false, &mut out)
            .then_some(out)
    }

    /// Measurement only (the coverage table of `docs/latency.md#conic-backend`): solves `qp`
    /// by this method and by clarabel, appends `n m dense clarabel` to `path` (`dense` the
    /// method's iterations or `fell_back`, `clarabel` clarabel's iterations and status); the
    /// caller then follows clarabel's answers.
    fn audit(&mut self, qp: &ConicQp, settings: &DefaultSettings<f64>, path: &std::path::Path) {
        use std::io::Write;
        let dense = self
            .solve_densely(qp, settings, false)
            .map_or("fell_back".to_string(), |iterations| iterations.to_string());
        let clarabel = qp.solve(settings).map_or("error".to_string(), |r| {
            format!("{} {:?}", r.iterations, r.status)
        });
        let line = format!("{} {} {dense} {clarabel}\n", qp.n, qp.rows());
        if let Ok(mut f) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
        {
            // A measurement aid: a failed write only loses a line of the table.
            let _ = f.write_all(line.as_bytes());
        }
    }

    /// The method itself ([`DenseQp::solve_into`] without the audit): its iterations, the
    /// answer in `x`, `z`, `s`; the iterations run, also when it fails, in `spent`. With
    /// `warm` and the last answer of the same shape kept, it starts from that answer.
    fn solve_densely(
        &mut self,
        qp: &ConicQp,
        settings: &DefaultSettings<f64>,
        warm: bool,
    ) -> Option<u32> {
        self.spent = 0;
        self.started_warm = false;
        let warm = warm && self.warm.valid;
        if !self.load(qp) {
            return None;
        }
        let (n, m) = (self.n, self.m);
        if m == 0 {
            return self.unconstrained(qp);
        }
        if warm && self.warm.n == n && self.warm.blocks == self.blocks && self.warm_start(qp) {
            self.started_warm = true;
        } else {
            self.start(qp)?;
        }
        let (q, b) = (&qp.q, &qp.b);
        let degree = self.blocks.len() as f64;
        let norm_b = inf_norm(b);
        let norm_q = inf_norm(q);
        // (score, iteration) of the best iterate: the method stops when it no longer improves.
        let mut best: (f64, u32) = (f64::INFINITY, 0);
        for iteration in 0..settings.max_iter.min(MAX_ITERATIONS) {
            // r_x = P x + q + Aᵀz, r_z = A x + s − b.
            mat_vec(&self.p, &self.x, n, &mut self.px);
            self.rx.copy_from_slice(&self.px);
            for j in 0..n {
                self.rx[j] += q[j];
            }
            mat_t_vec_add(&self.a, &self.z, n, &mut self.rx);
            mat_vec(&self.a, &self.x, n, &mut self.rz);
            for i in 0..m {
                self.rz[i] += self.s[i] - b[i];
            }
            let xpx = dot(&self.x, &self.px);
            let cost_primal = 0.5 * xpx + dot(q, &self.x);
            let cost_dual = -0.5 * xpx - dot(b, &self.z);
            let gap_abs = (cost_primal - cost_dual).abs();
            let gap_rel = gap_abs / cost_primal.abs().min(cost_dual.abs()).max(1.0);
            let (nx, ns, nz) = (inf_norm(&self.x), inf_norm(&self.s), inf_norm(&self.z));
            let res_primal = inf_norm(&self.rz) / (norm_b + nx + ns).max(1.0);
            let res_dual = inf_norm(&self.rx) / (norm_q + nx + nz).max(1.0);
            if !(res_primal.is_finite() && res_dual.is_finite() && gap_abs.is_finite()) {
                return None;
            }
            let score = (res_primal / settings.tol_feas)
                .max(res_dual / settings.tol_feas)
                .max((gap_abs / settings.tol_gap_abs).min(gap_rel / settings.tol_gap_rel));
            self.spent = iteration;
            if score <= 1.0 {
                return Some(iteration);
            }
            if score < best.0 {
                best = (score, iteration);
            } else if best.0 < STALL_SCORE
                && (score > 10.0 * best.0 || iteration >= best.1 + STALL_ITERATIONS)
            {
                // Near the solution and no longer improving: round-off has the last digits.
                return None;
            }
            if (iteration == 0 && !self.scale()) || !self.factor() {
                return None;
            }
            let mu = dot(&self.s, &self.z) / degree;
            // Predictor (affine scaling): λ∘(W⁻¹ds + W dz) = −λ∘λ, i.e. W⁻¹ds + W dz = −λ.
            for i in 0..m {
                self.t[i] = -self.lambda[i];
            }
            self.direction(true)?;
            std::mem::swap(&mut self.u, &mut self.u_affine);
            std::mem::swap(&mut self.v, &mut self.v_affine);
            // Step lengths in the scaled space (`λ + α W⁻¹ds`, `λ + α W dz`), where the
            // iterate's distance to the cone's boundary is of its own size; in the original
            // coordinates a sliding contact's `s` and `z` are within round-off of it.
            let alpha_a = self.scaled_step_length(true).min(1.0);
            let sigma = (1.0 - alpha_a).clamp(0.0, 1.0).powi(3);
            // Corrector: λ∘(W⁻¹ds + W dz) = −λ∘λ − (W⁻¹ds_a)∘(W dz_a) + σμe.
            for blk in &self.blocks {
                // −(λ∘λ + u∘v) + σμe: the Jordan product's first row is the inner product, the
                // others x₀yᵢ + y₀xᵢ.
                let (o, d) = (blk.first, blk.dim);
                let (l, u, v) = (&self.lambda, &self.u_affine, &self.v_affine);
                let first: f64 = (0..d)
                    .map(|i| l[o + i] * l[o + i] + u[o + i] * v[o + i])
                    .sum();
                self.res[o] = sigma * mu - first;
                for i in 1..d {
                    self.res[o + i] = -(2.0 * l[o] * l[o + i] + u[o] * v[o + i] + v[o] * u[o + i]);
                }
            }
            if !jordan_divide(&self.lambda, &self.res[..m], &self.blocks, &mut self.t) {
                return None;
            }
            self.direction(false)?;
            let alpha_max = self.scaled_step_length(false);
            let alpha = (STEP_FRACTION * alpha_max).min(1.0);

            if !(alpha.is_finite() && alpha > 0.0) {
                return None;
            }
            if !self.update_scaling(alpha) {
                return None;
            }
            for j in 0..n {
                self.x[j] += alpha * self.dx[j];
            }
            for i in 0..m {
                self.s[i] += alpha * self.ds[i];
                self.z[i] += alpha * self.dz[i];
            }
        }
        self.spent = settings.max_iter.min(MAX_ITERATIONS);
        None
    }

    /// Reads the problem into the dense workspace; `false` when it is not for this method.
    fn load(&mut self, qp: &ConicQp) -> bool {
        let (n, m) = (qp.n, qp.rows());
        if n == 0 || n > MAX_VARIABLES || n + m > MAX_KKT {
            return false;
        }
        self.blocks.clear();
        let mut row = 0;
        for cone in &qp.cones {
            match *cone {
                Cone::Zero(_) => return false,
                Cone::Nonnegative(k) => {
                    for _ in 0..k {
                        self.blocks.push(Block {
                            first: row,
                            dim: 1,
                            soc: false,
                        });
                        row += 1;
                    }
                }
                Cone::SecondOrder(k) => {
                    self.blocks.push(Block {
                        first: row,
                        dim: k,
                        soc: k > 1,
                    });
                    row += k;
                }
            }
        }
        if row != m || qp.q.len() != n {
            return false;
        }
        self.n = n;
        self.m = m;
        zeroed(&mut self.p, n * n);
        for &(i, j, v) in &qp.p {
            if i >= n || j >= n {
                return false;
            }
            self.p[i * n + j] += v;
            if i != j {
                self.p[j * n + i] += v;
            }
        }
        zeroed(&mut self.a, m * n);
        zeroed(&mut self.scaled_a, m * n);
        for &(i, j, v) in &qp.a {
            if i >= m || j >= n {
                return false;
            }
            self.a[i * n + j] += v;
        }
        let finite = self
            .p
            .iter()
            .chain(&self.a)
            .chain(&qp.q)
            .chain(&qp.b)
            .all(|v| v.is_finite());
        if !finite {
            return false;
        }
        let k = n + m;
        for v in [&mut self.x, &mut self.dx, &mut self.rx, &mut self.px] {
            zeroed(v, n);
        }
        for v in [
            &mut self.s,
            &mut self.z,
            &mut self.rz,
            &mut self.w,
            &mut self.eta,
            &mut self.lambda,
            &mut self.ds,
            &mut self.dz,
            &mut self.u_affine,
            &mut self.v_affine,
            &mut self.t,
            &mut self.u,
            &mut self.v,
        ] {
            zeroed(v, m);
        }
        for v in [&mut self.rhs, &mut self.sol, &mut self.res, &mut self.corr] {
            zeroed(v, k);
        }
        zeroed(&mut self.chol, n * n);
        zeroed(&mut self.chol_inv_diag, n);
        self.use_lu = false;
        true
    }

    /// The QP without rows: `P x = −q` (0 iterations, `x` the answer).
    fn unconstrained(&mut self, qp: &ConicQp) -> Option<u32> {
        let n = self.n;
        // With no rows the Schur complement is P itself.
        if !self.factor() {
            return None;
        }
        for j in 0..n {
            self.rhs[j] = -qp.q[j];
        }
        if !self.solve_refined() {
            return None;
        }
        self.x.copy_from_slice(&self.sol[..n]);
        // Its optimality: the residual of P x + q relative to the data.
        mat_vec(&self.p, &self.x, n, &mut self.px);
        let r = (0..n)
            .map(|j| (self.px[j] + qp.q[j]).abs())
            .fold(0.0, f64::max);
        (r <= 1e-14 * (inf_norm(&qp.q) + inf_norm(&self.px)).max(1.0)).then_some(0)
    }

    /// Starting point (Vandenberghe 2010, § 5.3): `x` minimises `½xᵀPx + qᵀx + ½‖Ax − b‖²`
    /// (the augmented system with `W = I`), `s = b − Ax` and `z = −s`, each shifted into the
    /// interior of K.
    fn start(&mut self, qp: &ConicQp) -> Option<()> {
        let (n, m) = (self.n, self.m);
        for blk in &self.blocks {
            self.eta[blk.first] = 1.0;
            for r in blk.first..blk.first + blk.dim {
                self.w[r] = if blk.soc { 0.0 } else { 1.0 };
            }
            if blk.soc {
                self.w[blk.first] = 1.0;
            }
        }
        if !self.factor() {
            return None;
        }
        for j in 0..n {
            self.rhs[j] = -qp.q[j];
        }
        self.rhs[n..n + m].copy_from_slice(&qp.b);
        if !self.solve_refined() {
            return None;
        }
        self.x.copy_from_slice(&self.sol[..n]);
        mat_vec(&self.a, &self.x, n, &mut self.s);
        for i in 0..m {
            self.s[i] = qp.b[i] - self.s[i];
            self.z[i] = -self.s[i];
        }
        shift_into_cone(&mut self.s, &self.blocks);
        shift_into_cone(&mut self.z, &self.blocks);
        Some(())
    }

    /// The warm start: the last QP's answer `(x, s, z)` (the same shape), with `s` and `z`
    /// pushed into the interior of K by [`WARM_MARGIN`] times their scale, so that the first
    /// scaling is finite and the iterate is centred at a small `μ` (Yildirim & Wright, SIAM J.
    /// Optim. 2002; Gondzio & Grothey 2008: a point on the boundary makes the first steps tiny).
    /// `false` (nothing changed) when the last answer's `s` and `b`, or its `z`, are all zero:
    /// no scale for a margin.
    fn warm_start(&mut self, qp: &ConicQp) -> bool {
        // The slacks' scale is that of `b` too: a sticking contact's answer has every slack at
        // round-off (all rows active), and a margin relative to them alone left the start on
        // the boundary (25 iterations instead of 8 after a 1e-5 change of `b`).
        let scale_s = inf_norm(&self.warm.s).max(inf_norm(&qp.b));
        let scale_z = inf_norm(&self.warm.z);
        if !(scale_s > 0.0 && scale_z > 0.0 && scale_s.is_finite() && scale_z.is_finite()) {
            return false;
        }
        self.x.copy_from_slice(&self.warm.x);
        self.s.copy_from_slice(&self.warm.s);
        self.z.copy_from_slice(&self.warm.z);
        push_into_cone(&mut self.s, &self.blocks, WARM_MARGIN * scale_s);
        push_into_cone(&mut self.z, &self.blocks, WARM_MARGIN * scale_z);
        true
    }

    /// The Nesterov–Todd scaling at `(s, z)` (the first iteration): the update below from the
    /// identity scaling; `false` when a point is not in the interior.
    fn scale(&mut self) -> bool {
        for blk in &self.blocks {
            let o = blk.first;
            self.eta[o] = 1.0;
            self.w[o] = 1.0;
            for i in o + 1..o + blk.dim {
                self.w[i] = 0.0;
            }
            for i in o..o + blk.dim {
                self.u[i] = self.s[i];
                self.v[i] = self.z[i];
            }
        }
        self.rescale()
    }

    /// Moves the scaling to the new iterate `(s + α ds, z + α dz)` without recomputing it from
    /// `s` and `z` (CVXOPT's update, Vandenberghe 2010, § 4): in the current scaling the new
    /// iterate is `s̃ = λ + α W⁻¹ds`, `z̃ = λ + α W dz` (`u`, `v` hold `W⁻¹ds`, `W dz`), of the
    /// size of `λ` and well inside K.
    /// Near the solution a sliding contact's `s` and `z` lie within 1e-12 of the friction cone's
    /// boundary, where `(s₀ − ‖s₁‖)(s₀ + ‖s₁‖)` keeps only a few correct digits: a scaling
    /// recomputed from them lost centrality and the method stalled at a gap of 1e-11.
    fn update_scaling(&mut self, alpha: f64) -> bool {
        for i in 0..self.m {
            self.u[i] = self.lambda[i] + alpha * self.u[i];
            self.v[i] = self.lambda[i] + alpha * self.v[i];
        }
        self.rescale()
    }

    /// The largest step `α` with `λ + α u` and `λ + α v` in K (`u = W⁻¹ds`, `v = W dz` of
    /// the affine direction when `affine`).
    fn scaled_step_length(&self, affine: bool) -> f64 {
        let (u, v) = if affine {
            (&self.u_affine, &self.v_affine)
        } else {
            (&self.u, &self.v)
        };
        step_length(&self.lambda, u, &self.blocks).min(step_length(&self.lambda, v, &self.blocks))
    }

    /// The scaling `W⁺ = W W̃` and `λ⁺` from the current `W` and the new iterate in its scaling,
    /// `s̃` in `u` and `z̃` in `v` (overwritten): CVXOPT's `misc.update_scaling`. On a
    /// non-negative row `d⁺ = d √(s̃/z̃)`, `λ⁺ = √(s̃ z̃)`. On a second-order cone, with
    /// `W = β (2vvᵀ − J)`, `vᵀJv = 1`, `a = ‖s̃‖_J`, `b = ‖z̃‖_J`, `ŝ = s̃/a`, `ẑ = z̃/b`,
    /// `c = √((1 + ŝᵀẑ)/2)`, `q = (ŝ + Jẑ)/(2c)` (the scaling point of `(ŝ, ẑ)`): the new
    /// scaling point is `(2vvᵀ − J) q`, `v⁺` its square root, `β⁺ = β √(a/b)`, and `λ⁺` the
    /// closed form below.
    fn rescale(&mut self) -> bool {
        for blk in &self.blocks {
            let (o, d) = (blk.first, blk.dim);
            let (st, zt) = (&mut self.u[o..o + d], &mut self.v[o..o + d]);
            if !blk.soc {
                if !(st[0] > 0.0 && zt[0] > 0.0) {
                    return false;
                }
                self.w[o] *= (st[0] / zt[0]).sqrt();
                self.lambda[o] = (st[0] * zt[0]).sqrt();
                continue;
            }
            let a = soc_det(st).sqrt();
            let b = soc_det(zt).sqrt();
            if !(a > 0.0 && b > 0.0 && st[0] > 0.0 && zt[0] > 0.0) {
                return false;
            }
            for i in 0..d {
                st[i] /= a;
                zt[i] /= b;
            }
            let c = ((1.0 + dot(st, zt)) / 2.0).sqrt();
            let v = &mut self.w[o..o + d];
            let vs = dot(v, st);
            let vz = v[0] * zt[0] - dot(&v[1..], &zt[1..]);
            let vq = (vs + vz) / (2.0 * c);
            let vu = vs - vz;
            let w0 = 2.0 * v[0] * vq - (st[0] + zt[0]) / (2.0 * c);
            let dd = (v[0] * vu - st[0] / 2.0 + zt[0] / 2.0) / (w0 + 1.0);
            let l = &mut self.lambda[o..o + d];
            let root = (a * b).sqrt();
            l[0] = root * c;
            let (cv, cs, cz) = (
                2.0 * (-dd * vq + 0.5 * vu),
                0.5 * (1.0 - dd / c),
                0.5 * (1.0 + dd / c),
            );
            for i in 1..d {
                l[i] = root * (cv * v[i] + cs * st[i] + cz * zt[i]);
            }
            // v := (2vvᵀ − J) q, then its square root (v + e)/√(2(v₀ + 1)).
            v[0] = 2.0 * vq * v[0] - (st[0] + zt[0]) / (2.0 * c);
            for i in 1..d {
                v[i] = 2.0 * vq * v[i] + (st[i] - zt[i]) / (2.0 * c);
            }
            v[0] += 1.0;
            let scale = 1.0 / (2.0 * v[0]).sqrt();
            for x in v.iter_mut() {
                *x *= scale;
            }
            self.eta[o] *= (a / b).sqrt();
            if !(self.eta[o].is_finite() && all_finite(v)) {
                return false;
            }
        }
        true
    }

    /// Writes `Ã = W⁻¹A` at the current scaling into `scaled_a`: the matrix of CVXOPT's scaled
    /// KKT system `[P Ãᵀ; Ã −I]`, whose unknowns are `dx` and `W dz`. The unscaled
    /// `[P Aᵀ; A −W²]` has the same solution, but its rows are in the units of `s`: once `W`
    /// spans twelve orders of magnitude, a residual of round-off size there is not small in the
    /// scaled space where the complementarity rows live, and the direction left the cone.
    /// A non-negative row is divided by its `w`; a second-order block is
    /// `β⁻¹(2Jv (Jv)ᵀA_b − JA_b)` (the arrow form of `W⁻¹`, `O(d)` per column).
    fn assemble(&mut self) {
        let n = self.n;
        let (a, scaled) = (&self.a, &mut self.scaled_a);
        for blk in &self.blocks {
            let (o, d) = (blk.first, blk.dim);
            let rows = o * n..(o + d) * n;
            let (a_b, s_b) = (&a[rows.clone()], &mut scaled[rows]);
            if !blk.soc {
                let inv = 1.0 / self.w[o];
                for (t, x) in s_b.iter_mut().zip(a_b) {
                    *t = inv * x;
                }
                continue;
            }
            let v = &self.w[o..o + d];
            let inv = 1.0 / self.eta[o];
            // c_j = 2 (Jv)ᵀ A_b[:, j] = 2 (v₀ a₀ⱼ − Σᵢ vᵢ aᵢⱼ), in `s_b`'s first row for now.
            let (head, tail) = a_b.split_at(n);
            for (cj, &a0) in s_b[..n].iter_mut().zip(head) {
                *cj = v[0] * a0;
            }
            for (i, row) in tail.chunks_exact(n).enumerate() {
                let vi = v[i + 1];
                for (cj, &x) in s_b[..n].iter_mut().zip(row) {
                    *cj -= vi * x;
                }
            }
            let (first, rest) = s_b.split_at_mut(n);
            for cj in first.iter_mut() {
                *cj *= 2.0;
            }
            for (i, (out, row)) in rest
                .chunks_exact_mut(n)
                .zip(tail.chunks_exact(n))
                .enumerate()
            {
                let vi = v[i + 1];
                for ((t, &x), &cj) in out.iter_mut().zip(row).zip(first.iter()) {
                    *t = inv * (x - cj * vi);
                }
            }
            for (cj, &a0) in first.iter_mut().zip(head) {
                *cj = inv * (*cj * v[0] - a0);
            }
        }
    }

    /// Assembles `Ã` at the current scaling and factors the scaled KKT system: by the Cholesky
    /// factor of its Schur complement, or, once that is not numerically positive definite in
    /// this QP, by LU on the whole system.
    fn factor(&mut self) -> bool {
        self.assemble();
        if !self.use_lu && self.factor_schur() {
            return true;
        }
        self.use_lu = true;
        self.factor_lu()
    }

    /// LU with partial pivoting of `[P Ãᵀ; Ã −I]` into `lu`; `false` when it is singular.
    /// The Schur complement `P + ÃᵀÃ` loses a body's mass to round-off when loaded vertex rows
    /// of size `‖Ã‖² ≈ 1e13` fix its velocity (`d5_collision`: a pivot of `−4e-3` for a
    /// diagonal of `3e13`); the augmented matrix, of entries `‖Ã‖`, keeps it.
    fn factor_lu(&mut self) -> bool {
        let (n, m) = (self.n, self.m);
        let k = n + m;
        zeroed(&mut self.lu, k * k);
        self.pivots.clear();
        self.pivots.resize(k, 0);
        let lu = &mut self.lu;
        for r in 0..n {
            lu[r * k..r * k + n].copy_from_slice(&self.p[r * n..(r + 1) * n]);
            for i in 0..m {
                lu[r * k + n + i] = self.scaled_a[i * n + r];
            }
        }
        for i in 0..m {
            let row = (n + i) * k;
            lu[row..row + n].copy_from_slice(&self.scaled_a[i * n..(i + 1) * n]);
            lu[row + n + i] = -1.0;
        }
        lu_in_place(lu, &mut self.pivots, k)
    }

    /// Solves the factored scaled KKT system in place (`v` of length `n + m`).
    fn kkt_solve(&self, v: &mut [f64]) {
        if self.use_lu {
            lu_solve(&self.lu, &self.pivots, self.n + self.m, v);
        } else {
            with_size(self.n, |n| {
                schur_solve(&self.chol, &self.chol_inv_diag, &self.scaled_a, n, v)
            });
        }
    }

    /// The Cholesky factor of `P + ÃᵀÃ` (lower triangle of `chol`); `false` when it is not
    /// numerically positive definite. This replaces the LU of the `(n + m)²` augmented system:
    /// `⅓n³` instead of `⅔(n + m)³`, and `ÃᵀÃ` skips the zeros of `A`.
    fn factor_schur(&mut self) -> bool {
        let m = self.m;
        let factored = with_size(self.n, |n| {
            schur_factor(&self.p, &self.scaled_a, n, m, &mut self.chol)
        });
        // Reciprocals once per factor, so that the substitutions' chains (each entry waits
        // for the one before) multiply instead of divide.
        let n = self.n;
        for (i, inv) in self.chol_inv_diag.iter_mut().enumerate() {
            *inv = 1.0 / self.chol[i * n + i];
        }
        factored
    }

    /// `sol` solving the scaled KKT system `K sol = rhs`, `K = [P Ãᵀ; Ã −I]`, refined on `K`
    /// while its residual falls and is above round-off: the Schur complement squares the
    /// condition of `Ã`, whose loaded vertex rows are scaled by up to 1e6 near the solution, so
    /// the first solve may miss the last digits the refinement recovers.
    fn solve_refined(&mut self) -> bool {
        if self.refine() <= SCHUR_BACKWARD_ERROR || self.use_lu {
            return true;
        }
        // The Schur complement lost digits its refinement cannot recover (`d5_collision`: a
        // backward error of 1e-7 after three steps, and the dual residual grew from 1e-17 to
        // 2e-8 over the iterations): this QP goes on with the LU of the whole system.
        self.use_lu = true;
        if !self.factor_lu() {
            return false;
        }
        self.refine();
        true
    }

    /// `sol` solving the factored scaled KKT system `K sol = rhs` once, without refinement.
    fn solve_unrefined(&mut self) {
        let k = self.n + self.m;
        let mut sol = std::mem::take(&mut self.sol);
        sol[..k].copy_from_slice(&self.rhs[..k]);
        self.kkt_solve(&mut sol[..k]);
        self.sol = sol;
    }

    /// [`DenseQp::solve_refined`] with the current factors; returns the final backward error.
    fn refine(&mut self) -> f64 {
        let (n, m) = (self.n, self.m);
        let k = n + m;
        self.solve_unrefined();
        let mut last = f64::INFINITY;
        let mut steps = 0;
        for _ in 0..=REFINEMENT_STEPS {
            let berr = with_size(n, |n| {
                kkt_residual(
                    &self.p,
                    &self.scaled_a,
                    n,
                    &self.sol[..k],
                    &self.rhs[..k],
                    &mut self.res[..k],
                )
            });
            steps += 1;
            if berr <= BACKWARD_ERROR || berr >= 0.5 * last || steps > REFINEMENT_STEPS {
                last = berr;
                break;
            }
            last = berr;
            let mut corr = std::mem::take(&mut self.corr);
            corr[..k].copy_from_slice(&self.res[..k]);
            self.kkt_solve(&mut corr[..k]);
            self.corr = corr;
            for (x, c) in self.sol[..k].iter_mut().zip(&self.corr[..k]) {
                *x += c;
            }
        }
        last
    }

    /// The direction of `P dx + Aᵀdz = −r_x`, `A dx + ds = −r_z`, `W⁻¹ds + W dz = t`: `dx`,
    /// `u = W⁻¹ds` and `v = W dz` from the scaled system
    /// `[P Ãᵀ; Ã −I][dx; v] = [−r_x; −W⁻¹r_z − t]`, `u = t − v`; and, unless `affine`, `dz` and
    /// `ds` (from the primal rows, so that the primal residual falls by exactly `1 − α`).
    fn direction(&mut self, affine: bool) -> Option<()> {
        let (n, m) = (self.n, self.m);
        let k = n + m;
        for blk in &self.blocks {
            apply_w(blk, &self.w, &self.eta, &self.rz, &mut self.u, true);
        }
        for j in 0..n {
            self.rhs[j] = -self.rx[j];
        }
        for i in 0..m {
            self.rhs[n + i] = -self.u[i] - self.t[i];
        }
        // The affine direction only sets the centring σ and the corrector's second-order
        // term: one solve without refinement is enough (the combined direction, which moves
        // the residuals, is refined).
        if affine {
            self.solve_unrefined();
        } else if !self.solve_refined() {
            return None;
        }
        if !all_finite(&self.sol[..k]) {
            return None;
        }
        self.dx.copy_from_slice(&self.sol[..n]);
        self.v.copy_from_slice(&self.sol[n..k]);
        for i in 0..m {
            self.u[i] = self.t[i] - self.v[i];
        }
        if !affine {
            for blk in &self.blocks {
                apply_w(blk, &self.w, &self.eta, &self.v, &mut self.dz, true);
            }
            mat_vec(&self.a, &self.dx, n, &mut self.ds);
            for i in 0..m {
                self.ds[i] = -self.rz[i] - self.ds[i];
            }
        }
        Some(())
    }
}

/// `y = W x` (or `W⁻¹ x`) on one block: on a second-order cone `W x = β (2v(vᵀx) − Jx)` and
/// `W⁻¹ x = β⁻¹ (2Jv((Jv)ᵀx) − Jx)` (`vᵀJv = 1`).
fn apply_w(blk: &Block, w: &[f64], eta: &[f64], x: &[f64], y: &mut [f64], inverse: bool) {
    let (o, d) = (blk.first, blk.dim);
    if !blk.soc {
        y[o] = if inverse { x[o] / w[o] } else { w[o] * x[o] };
        return;
    }
    let v = &w[o..o + d];
    let xv = &x[o..o + d];
    let v1x1: f64 = (1..d).map(|i| v[i] * xv[i]).sum();
    let (sign, scale) = if inverse {
        (-1.0, 1.0 / eta[o])
    } else {
        (1.0, eta[o])
    };
    // (Jv)ᵀx = v₀x₀ − v₁ᵀx₁; Jv = (v₀, −v₁).
    let vx = 2.0 * (v[0] * xv[0] + sign * v1x1);
    y[o] = scale * (vx * v[0] - xv[0]);
    for i in 1..d {
        y[o + i] = scale * (sign * vx * v[i] + xv[i]);
    }
}

/// The lower Cholesky factor of the Schur complement `P + ÃᵀÃ` of the scaled KKT system into
/// `chol` ([`DenseQp::factor_schur`]); `false` when it is not numerically positive definite.
#[inline(always)]
fn schur_factor(p: &[f64], scaled_a: &[f64], n: usize, m: usize, chol: &mut [f64]) -> bool {
    let h = &mut chol[..n * n];
    for (i, row) in h.chunks_exact_mut(n).enumerate() {
        row[..=i].copy_from_slice(&p[i * n..i * n + i + 1]);
    }
    // The test for zero entries stays: without it the factor cost 7.5 k more instructions per
    // desk solve for 41 fewer mispredicted branches (`docs/latency.md`).
    for r in scaled_a[..m * n].chunks_exact(n) {
        for (i, &ai) in r.iter().enumerate() {
            if ai == 0.0 {
                continue;
            }
            for (hij, &aj) in h[i * n..i * n + i + 1].iter_mut().zip(r) {
                *hij += ai * aj;
            }
        }
    }
    cholesky_in_place(h, n)
}

/// Cholesky factorisation `H = LLᵀ` in place of the lower triangle of `h` (`n × n`,
/// row-major; the upper triangle is not read); `false` when a pivot is not positive beyond
/// round-off of the largest diagonal entry.
#[inline(always)]
fn cholesky_in_place(h: &mut [f64], n: usize) -> bool {
    let scale = (0..n).map(|i| h[i * n + i]).fold(0.0f64, f64::max);
    if !(scale > 0.0 && scale.is_finite()) {
        return false;
    }
    let tiny = scale * f64::EPSILON * f64::EPSILON;
    for j in 0..n {
        let (head, tail) = h.split_at_mut((j + 1) * n);
        let row_j = &mut head[j * n..];
        let d = row_j[j] - dot(&row_j[..j], &row_j[..j]);
        if !(d > tiny && d.is_finite()) {
            return false;
        }
        let l = d.sqrt();
        row_j[j] = l;
        for row_i in tail.chunks_exact_mut(n) {
            row_i[j] = (row_i[j] - dot(&row_i[..j], &row_j[..j])) / l;
        }
    }
    true
}

/// LU factorisation with partial pivoting of the `k × k` row-major `lu` in place, the row
/// interchanges in `pivots`; `false` when it is singular.
fn lu_in_place(lu: &mut [f64], pivots: &mut [usize], k: usize) -> bool {
    let scale = lu.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(scale > 0.0 && scale.is_finite()) {
        return false;
    }
    for c in 0..k {
        let (mut piv, mut best) = (c, lu[c * k + c].abs());
        for r in c + 1..k {
            let v = lu[r * k + c].abs();
            if v > best {
                (piv, best) = (r, v);
            }
        }
        if best.is_nan() || best <= scale * f64::EPSILON * f64::EPSILON {
            return false;
        }
        pivots[c] = piv;
        if piv != c {
            for j in 0..k {
                lu.swap(c * k + j, piv * k + j);
            }
        }
        let d = lu[c * k + c];
        for r in c + 1..k {
            let f = lu[r * k + c] / d;
            lu[r * k + c] = f;
            if f != 0.0 {
                for j in c + 1..k {
                    lu[r * k + j] -= f * lu[c * k + j];
                }
            }
        }
    }
    true
}

/// Solves `LU x = v` in place from [`lu_in_place`]'s factors.
fn lu_solve(lu: &[f64], pivots: &[usize], k: usize, v: &mut [f64]) {
    for c in 0..k {
        v.swap(c, pivots[c]);
    }
    for r in 0..k {
        v[r] -= dot(&lu[r * k..r * k + r], &v[..r]);
    }
    for r in (0..k).rev() {
        let acc = v[r] - dot(&lu[r * k + r + 1..(r + 1) * k], &v[r + 1..k]);
        v[r] = acc / lu[r * k + r];
    }
}

/// Solves the scaled KKT system `[P Ãᵀ; Ã −I][x; y] = [f; g]` in place (`v = [f; g]`, length
/// `n + m`) by the Schur complement's factor `L`: `LLᵀx = f + Ãᵀg`, `y = Ãx − g`.
///
/// The substitutions go by columns of `L` (an entry, once known, is subtracted from all those
/// after it) and multiply by the diagonal's reciprocals `inv_diag`: each entry then waits for
/// the one before by a product and a difference only, where the inner products by rows and the
/// divisions made the solve a chain of 2n divisions (a tenth of the conic desk step's time,
/// `docs/latency.md`, branch wip-conic3x).
#[inline(always)]
fn schur_solve(chol: &[f64], inv_diag: &[f64], scaled_a: &[f64], n: usize, v: &mut [f64]) {
    let (x, y) = v.split_at_mut(n);
    let inv_diag = &inv_diag[..n];
    // No test for zero `g`: a zero adds nothing (the same sums), and the test was a mispredicted
    // branch (with the residual's below, 300 per desk solve).
    for (&g, row) in y.iter().zip(scaled_a.chunks_exact(n)) {
        for (xj, &a) in x.iter_mut().zip(row) {
            *xj += a * g;
        }
    }
    // L w = x, column by column of L.
    for j in 0..n {
        let xj = x[j] * inv_diag[j];
        x[j] = xj;
        for i in j + 1..n {
            x[i] -= chol[i * n + j] * xj;
        }
    }
    // Lᵀ x = w, column by column of Lᵀ (rows of L, contiguous).
    for i in (0..n).rev() {
        let xi = x[i] * inv_diag[i];
        x[i] = xi;
        for (xj, &lij) in x[..i].iter_mut().zip(&chol[i * n..i * n + i]) {
            *xj -= lij * xi;
        }
    }
    for (g, row) in y.iter_mut().zip(scaled_a.chunks_exact(n)) {
        *g = dot(row, x) - *g;
    }
}

/// The residual `res = rhs − K v` of the scaled KKT system `K = [P Ãᵀ; Ã −I]` and its
/// componentwise backward error `maxᵢ |resᵢ| / (|K||v| + |rhs|)ᵢ` (Oettli–Prager, the test of
/// LAPACK's refinement): round-off level (a few ε) when `v` is as good as the data allow.
#[inline(always)]
fn kkt_residual(
    p: &[f64],
    scaled_a: &[f64],
    n: usize,
    v: &[f64],
    rhs: &[f64],
    res: &mut [f64],
) -> f64 {
    let (x, y) = v.split_at(n);
    let m = y.len();
    let (rx, ry) = res.split_at_mut(n);
    let mut berr = 0.0f64;
    // x rows: P x + Ãᵀy, by columns of Ãᵀ (rows of Ã) for the contiguous layout.
    let mut scale = [0.0f64; MAX_VARIABLES];
    let scale = &mut scale[..n];
    for ((r, s), (row, &b)) in rx
        .iter_mut()
        .zip(scale.iter_mut())
        .zip(p[..n * n].chunks_exact(n).zip(&rhs[..n]))
    {
        let (mut acc, mut abs) = (b, b.abs());
        for (&pij, &xj) in row.iter().zip(x) {
            acc -= pij * xj;
            abs += (pij * xj).abs();
        }
        *r = acc;
        *s = abs;
    }
    // No test for zero `yi` (see `schur_solve`).
    for (row, &yi) in scaled_a[..m * n].chunks_exact(n).zip(y) {
        for ((r, s), &a) in rx.iter_mut().zip(scale.iter_mut()).zip(row) {
            *r -= a * yi;
            *s += (a * yi).abs();
        }
    }
    // Branch-free: a zero residual gives 0 (or NaN for a zero scale, which `max` ignores).
    for (r, s) in rx.iter().zip(scale.iter()) {
        berr = berr.max(r.abs() / s);
    }
    for ((r, row), (&yi, &b)) in ry
        .iter_mut()
        .zip(scaled_a.chunks_exact(n))
        .zip(y.iter().zip(&rhs[n..]))
    {
        let (mut acc, mut abs) = (b + yi, b.abs() + yi.abs());
        for (&a, &xj) in row.iter().zip(x) {
            acc -= a * xj;
            abs += (a * xj).abs();
        }
        *r = acc;
        berr = berr.max(acc.abs() / abs);
    }
    berr
}

/// `s₀² − ‖s₁‖²` of a second-order cone entry, as `(s₀ − ‖s₁‖)(s₀ + ‖s₁‖)`.
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

/// Raises every cone's entry of `s` so that it is inside K by at least `margin`: a
/// non-negative row to `margin`, a second-order cone's `s₀` to `‖s₁‖ + margin`.
fn push_into_cone(s: &mut [f64], blocks: &[Block], margin: f64) {
    for blk in blocks {
        let v = &mut s[blk.first..blk.first + blk.dim];
        let r = if blk.soc {
            v[1..].iter().map(|x| x * x).sum::<f64>().sqrt()
        } else {
            0.0
        };
        v[0] = v[0].max(r + margin);
    }
}

/// `t` with `λ ∘ t = r` per block; `false` when `λ` is not in the interior.
fn jordan_divide(lambda: &[f64], r: &[f64], blocks: &[Block], t: &mut [f64]) -> bool {
    for blk in blocks {
        let (o, d) = (blk.first, blk.dim);
        let l = &lambda[o..o + d];
        if d == 1 {
            t[o] = r[o] / l[0];
            continue;
        }
        let det = soc_det(l);
        if det.is_nan() || det <= 0.0 || l[0] <= 0.0 {
            return false;
        }
        let l1r1: f64 = (1..d).map(|i| l[i] * r[o + i]).sum();
        let t0 = (l[0] * r[o] - l1r1) / det;
        t[o] = t0;
        for i in 1..d {
            t[o + i] = (r[o + i] - t0 * l[i]) / l[0];
        }
    }
    all_finite(t)
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

/// `y = A x` for `A` dense with `cols` columns, row-major, `y.len()` rows.
fn mat_vec(a: &[f64], x: &[f64], cols: usize, y: &mut [f64]) {
    for (i, yi) in y.iter_mut().enumerate() {
        *yi = dot(&a[i * cols..(i + 1) * cols], x);
    }
}

/// `out += Aᵀ y` for `A` dense with `cols` columns, row-major, `y.len()` rows.
fn mat_t_vec_add(a: &[f64], y: &[f64], cols: usize, out: &mut [f64]) {
    for (i, &yi) in y.iter().enumerate() {
        if yi == 0.0 {
            continue;
        }
        for j in 0..cols {
            out[j] += a[i * cols + j] * yi;
        }
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

    /// A workspace holding `(s, z)` on one second-order cone of dimension 4.
    fn workspace(s: &[f64; 4], z: &[f64; 4]) -> DenseQp {
        let mut qp = ConicQp::new(1);
        qp.add_p(0, 0, 1.0);
        for i in 0..4 {
            qp.push_row(&[(0, if i == 0 { 1.0 } else { 0.0 })], 0.0);
        }
        qp.cones.push(Cone::SecondOrder(4));
        let mut ws = DenseQp::default();
        assert!(ws.load(&qp));
        ws.s.copy_from_slice(s);
        ws.z.copy_from_slice(z);
        ws
    }

    fn apply(ws: &DenseQp, x: &[f64], inverse: bool) -> [f64; 4] {
        let mut y = [0.0; 4];
        apply_w(&ws.blocks[0], &ws.w, &ws.eta, x, &mut y, inverse);
        y
    }

    #[test]
    fn scaling_maps_z_and_s_to_lambda() {
        let (s, z) = ([2.0, 0.3, -0.5, 1.0], [1.5, -0.2, 0.4, 0.1]);
        let mut ws = workspace(&s, &z);
        assert!(ws.scale());
        let (wz, wis) = (apply(&ws, &z, false), apply(&ws, &s, true));
        let back = apply(&ws, &wis, false);
        for i in 0..4 {
            assert!(
                (wz[i] - ws.lambda[i]).abs() < 1e-14,
                "W z {wz:?}, λ {:?}",
                ws.lambda
            );
            assert!(
                (wis[i] - ws.lambda[i]).abs() < 1e-14,
                "W⁻¹s {wis:?}, λ {:?}",
                ws.lambda
            );
            assert!((back[i] - s[i]).abs() < 1e-14, "W W⁻¹ s = {back:?}");
        }
    }

    /// The update from the scaled step agrees with the scaling computed afresh at the new point.
    #[test]
    fn updated_scaling_is_the_scaling_of_the_new_point() {
        let (s, z) = ([2.0, 0.3, -0.5, 1.0], [1.5, -0.2, 0.4, 0.1]);
        let (ds, dz) = ([-0.5, 0.2, 0.1, -0.3], [0.2, 0.1, -0.2, 0.05]);
        let alpha = 0.7;
        let mut ws = workspace(&s, &z);
        assert!(ws.scale());
        let (u, v) = (apply(&ws, &ds, true), apply(&ws, &dz, false));
        ws.u.copy_from_slice(&u);
        ws.v.copy_from_slice(&v);
        assert!(ws.update_scaling(alpha));
        let s1: Vec<f64> = (0..4).map(|i| s[i] + alpha * ds[i]).collect();
        let z1: Vec<f64> = (0..4).map(|i| z[i] + alpha * dz[i]).collect();
        let mut fresh = workspace(&[s1[0], s1[1], s1[2], s1[3]], &[z1[0], z1[1], z1[2], z1[3]]);
        assert!(fresh.scale());
        for i in 0..4 {
            assert!(
                (ws.w[i] - fresh.w[i]).abs() < 1e-13,
                "{:?} vs {:?}",
                ws.w,
                fresh.w
            );
            assert!((ws.lambda[i] - fresh.lambda[i]).abs() < 1e-13);
        }
        assert!((ws.eta[0] - fresh.eta[0]).abs() < 1e-13);
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

    /// Sticking and sliding (the friction cone's `s` and `z` both on its boundary at the
    /// solution, where the method used to lose its last digits): solved to clarabel's 1e-12
    /// tolerances, in fewer iterations than clarabel takes, and the velocities and friction
    /// impulse agree with clarabel's to 1e-9 sticking, 1e-6 sliding (√1e-12). Two answers within the
    /// 1e-12 tolerances differ by that much: along the friction cone's boundary the gap grows
    /// only quadratically with the distance to the solution. (The vertex impulses are not
    /// unique: four loaded vertices of a rigid body.)
    #[test]
    fn agrees_with_clarabel_on_step_like_qps() {
        let settings = default_clarabel_settings();
        let mut ws = DenseQp::default();
        for sticking in [true, false] {
            let qp = step_like(sticking);
            let tolerance = if sticking { 1e-9 } else { 1e-6 };
            let dense = ws
                .solve(&qp, &settings)
                .expect("the dense method converges");
            assert_eq!(dense.status, SolverStatus::Solved);
            let reference = qp.solve(&settings).expect("clarabel solves it");
            assert_eq!(reference.status, SolverStatus::Solved);
            for (a, b) in dense.x.iter().zip(&reference.x).take(6) {
                assert!(
                    (a - b).abs() < tolerance,
                    "sticking {sticking}: x {:?} vs {:?}",
                    dense.x,
                    reference.x
                );
            }
            // The friction cone's dual (the friction impulse) is unique.
            for (a, b) in dense.z.iter().zip(&reference.z).skip(4) {
                assert!(
                    (a - b).abs() < tolerance,
                    "sticking {sticking}: z {:?} vs {:?}",
                    dense.z,
                    reference.z
                );
            }
            assert!(
                dense.iterations < reference.iterations,
                "{} iterations, clarabel {}",
                dense.iterations,
                reference.iterations
            );
        }
    }

    /// A QP warm-started from the answer of a QP of the same shape whose data differ by 1 %
    /// (the next step's QP) meets the same tolerances in fewer iterations than from the
    /// standard start, and its answer agrees with the cold one as two answers within the
    /// tolerances do (1e-9 sticking, 1e-6 sliding, as against clarabel above). A QP of
    /// another shape is not warm-started.
    #[test]
    fn warm_start_from_a_neighbouring_qp() {
        let settings = default_clarabel_settings();
        for sticking in [true, false] {
            let tolerance = if sticking { 1e-9 } else { 1e-6 };
            let mut next = step_like(sticking);
            for q in next.q.iter_mut() {
                *q *= 1.01;
            }
            next.b[0] += 1e-5;
            let mut cold_ws = DenseQp::default();
            let mut cold = QpResult::default();
            assert!(cold_ws.solve_into(&next, &settings, true, &mut cold));
            assert!(!cold_ws.started_warm, "nothing to start from yet");
            let mut ws = DenseQp::default();
            let mut first = QpResult::default();
            assert!(ws.solve_into(&step_like(sticking), &settings, true, &mut first));
            let mut warm = QpResult::default();
            assert!(ws.solve_into(&next, &settings, true, &mut warm));
            assert!(ws.started_warm);
            assert_eq!(warm.status, SolverStatus::Solved);
            assert!(
                warm.iterations + 2 <= cold.iterations,
                "sticking {sticking}: warm {} iterations, cold {}",
                warm.iterations,
                cold.iterations
            );
            for (a, b) in warm.x.iter().zip(&cold.x).take(6) {
                assert!((a - b).abs() < tolerance, "{:?} vs {:?}", warm.x, cold.x);
            }
            for (a, b) in warm.z.iter().zip(&cold.z).skip(4) {
                assert!((a - b).abs() < tolerance, "{:?} vs {:?}", warm.z, cold.z);
            }
        }
        // Another shape (one friction cone fewer): the standard start.
        let mut ws = DenseQp::default();
        let mut out = QpResult::default();
        assert!(ws.solve_into(&step_like(true), &settings, true, &mut out));
        let mut other = ConicQp::new(2);
        other.add_p(0, 0, 1.0);
        other.add_p(1, 1, 1.0);
        other.q = vec![1.0, -1.0];
        other.push_row(&[(0, -1.0)], 0.0);
        other.cones.push(Cone::Nonnegative(1));
        assert!(ws.solve_into(&other, &settings, true, &mut out));
        assert!(!ws.started_warm);
        assert!(
            out.x[0].abs() < 1e-9 && (out.x[1] - 1.0).abs() < 1e-9,
            "{:?}",
            out.x
        );
    }

    #[test]
    fn all_finite_refuses_infinities_and_nan() {
        assert!(all_finite(&[]));
        assert!(all_finite(&[1.0, -0.0, f64::MAX, f64::MIN_POSITIVE]));
        for bad in [f64::INFINITY, f64::NEG_INFINITY, f64::NAN] {
            assert!(!all_finite(&[1.0, bad, 2.0]), "{bad}");
        }
    }

    #[test]
    fn schur_solve_by_columns_solves_the_kkt_system() {
        // [P Ãᵀ; Ã −I][x; y] = [f; g] with P = diag(2, 3, 4) and Ã 2 × 3: the substitutions by
        // columns with reciprocals against the residual of the system itself.
        let n = 3;
        let p = [2.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 4.0];
        let a = [1.0, 2.0, 0.0, 0.0, -1.0, 3.0];
        let mut chol = [0.0; 9];
        assert!(schur_factor(&p, &a, n, 2, &mut chol));
        let inv: Vec<f64> = (0..n).map(|i| 1.0 / chol[i * n + i]).collect();
        let rhs = [1.0, -2.0, 0.5, 0.25, -1.0];
        let mut v = rhs;
        schur_solve(&chol, &inv, &a, n, &mut v);
        let mut res = [0.0; 5];
        let berr = kkt_residual(&p, &a, n, &v, &rhs, &mut res);
        assert!(berr <= 1e-14, "{berr}");
        assert!(res.iter().all(|r| r.abs() <= 1e-14), "{res:?}");
    }

    #[test]
    fn solves_a_qp_without_rows() {
        let mut qp = ConicQp::new(2);
        qp.add_p(0, 0, 2.0);
        qp.add_p(1, 1, 4.0);
        qp.add_p(0, 1, 1.0);
        qp.q = vec![-1.0, 2.0];
        let r = DenseQp::default()
            .solve(&qp, &default_clarabel_settings())
            .expect("solved");
        // [2 1; 1 4] x = [1; −2]: x = (6/7, −5/7).
        assert!((r.x[0] - 6.0 / 7.0).abs() < 1e-15 && (r.x[1] + 5.0 / 7.0).abs() < 1e-15);
    }

    #[test]
    fn refuses_zero_cones_and_infeasible_problems() {
        let settings = default_clarabel_settings();
        let mut ws = DenseQp::default();
        let mut qp = ConicQp::new(1);
        qp.add_p(0, 0, 1.0);
        qp.push_row(&[(0, 1.0)], 1.0);
        qp.cones.push(Cone::Zero(1));
        assert!(ws.solve(&qp, &settings).is_none());
        // x ≥ 1 and x ≤ −1: no answer, so clarabel is asked (and reports it).
        let mut qp = ConicQp::new(1);
        qp.add_p(0, 0, 1.0);
        qp.push_row(&[(0, -1.0)], -1.0);
        qp.push_row(&[(0, 1.0)], -1.0);
        qp.cones.push(Cone::Nonnegative(2));
        assert!(ws.solve(&qp, &settings).is_none());
    }
}
