//! The smoothed natural map of an MCP and the smoothing continuation built on it, the last
//! restart of the semismooth Newton and PATH-like backends (`docs/newton.md#smoothing-continuation`).
//!
//! The MCP's solutions are the zeros of the natural map `G(z) = z − mid(l, u, z − F(z))`. With
//! `x = z − F(z)` and `mid(l, u, x) = x + (l − x)₊ − (x − u)₊`, replacing the plus function by
//! the Chen–Harker–Kanzow–Smale smoothing `p_μ(t) = (t + √(t² + 4μ²)) / 2` gives
//!
//! ```text
//! G_μ(z) = F(z) − p_μ(l − x) + p_μ(x − u),        G_0 = G,
//! ∂G_μ/∂z = (1 − c) J + c I,   c_i = p_μ'(l_i − x_i) + p_μ'(x_i − u_i) ∈ (0, 1) for finite bounds,
//! ```
//!
//! with the terms of an infinite bound left out (a free component is `G_i = F_i`). For a lower
//! bound only, `G_μ,i = 0` means `z_i − l_i > 0`, `F_i > 0` and `(z_i − l_i) F_i = μ²`: every
//! complementarity pair is strictly inside, as on an interior-point method's central path, and
//! `G_μ` is smooth. Its zeros move continuously to a solution of the MCP as `μ → 0` (Chen &
//! Mangasarian, Comput. Optim. Appl. 5, 1996; Kanzow, SIAM J. Matrix Anal. Appl. 17, 1996;
//! Qi, Sun & Zhou, Math. Prog. 87, 2000).
//!
//! [`Smoothed`] is `G_μ` written as an MCP with every component free, so a backend's own
//! iteration solves it (for free components the Fischer–Burmeister function of the Newton
//! backend is `F` itself, and the PATH-like backend's pivoting reduces to a Newton step).
//! [`continuation`] solves `G_μ = 0` for `μ = μ₀, θμ₀, θ²μ₀, …`, each stage from the last one's
//! point, until `μ` reaches the backend's tolerance; the backend then solves the MCP itself from
//! the end point. Where the backend alone stops at a point that is not a solution — a local
//! minimiser of its merit function, typically where a contact changes its active faces within
//! a step — the path of smoothed solutions leads past it: all the complementarity pairs are
//! strictly inside along the path, and active sets change continuously rather than across a kink.

use std::cell::RefCell;
use std::sync::Arc;

use ecp_model::{CscPattern, Mcp, Solution, SolveError, natural_residual};

/// Settings of the [`continuation`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SmoothingSettings {
    /// `μ₀` relative to the natural residual at the start. Default `1`.
    pub start: f64,
    /// The reduction θ of `μ` from one stage to the next, in `(0, 1)`. Default `0.5`
    /// (`docs/newton.md#smoothing-continuation`).
    pub reduction: f64,
    /// A stage stops when `‖G_μ‖∞` is at most this times `μ`. Default `0.1`.
    pub stage_tolerance: f64,
    /// Iteration limit of each stage. Default 30.
    pub stage_iterations: usize,
    /// Cuts of the reduction in a row (`θ ← √θ` after a stage that did not converge) before
    /// the continuation goes on from an unconverged stage. Default 4.
    pub max_cuts: usize,
    /// Limit on the iterations of all stages together; `None` (default): only the stages'
    /// own limits. The registry sets it to a user's `max_iterations`, so that a backend built
    /// with an iteration limit keeps to it in the continuation too.
    pub max_iterations: Option<usize>,
    /// Give up after this many stages in a row that did not converge and were kept (no cut of
    /// the reduction left): the continuation has lost the path, and its remaining stages would
    /// each run to [`SmoothingSettings::stage_iterations`] (`docs/newton.md#wall-time`); with
    /// [`SmoothingSettings::count_cut_stages`], this many unconverged stages of any kind.
    /// `None` (default): go on to the last stage. The Newton and PATH-like backends set it.
    pub max_failed_stages: Option<usize>,
    /// With [`SmoothingSettings::max_failed_stages`]: count every stage that did not converge,
    /// cut back or kept, since the last stage that converged with the set
    /// [`SmoothingSettings::reduction`] (a stage that converged only after cuts does not reset
    /// the count). A continuation that alternates failed stages and short converged ones
    /// crawls along the path at 30 iterations a stage (`035_v_trough` step 27,
    /// `docs/newton.md#a-crawling-continuation`). Default `false`; the Newton and PATH-like
    /// backends set it.
    pub count_cut_stages: bool,
}

impl Default for SmoothingSettings {
    fn default() -> Self {
        SmoothingSettings {
            start: 1.0,
            reduction: 0.5,
            stage_tolerance: 0.1,
            stage_iterations: 30,
            max_cuts: 4,
            max_iterations: None,
            max_failed_stages: None,
            count_cut_stages: false,
        }
    }
}

/// The largest reduction the cuts make (`θ ≤ 0.9`): a continuation that needs shorter steps
/// than that goes on from an unconverged stage instead.
const MAX_REDUCTION: f64 = 0.9;

/// Stages of one continuation at most (the plain schedule from `μ₀ = 1` to `1e-10` with
/// `θ = 0.5` takes 34).
const MAX_STAGES: usize = 100;

/// Where the continuation ended: the point of its last stage, the number of stages and the
/// iterations they took.
pub struct ContinuationEnd {
    /// The last stage's point.
    pub z: Vec<f64>,
    /// Stages solved (or attempted).
    pub stages: usize,
    /// Iterations of all stages.
    pub iterations: usize,
}

impl ContinuationEnd {
    /// Adds the continuation's iterations (and `earlier` ones of the attempts before it) and its
    /// counters to the summary of the solve that finished from its point.
    pub fn tally(&self, summary: &mut ecp_model::Summary, earlier: usize) {
        summary.iterations += self.iterations + earlier;
        summary
            .counters
            .add(ecp_model::Counter::SmoothingStages, self.stages);
        summary
            .counters
            .add(ecp_model::Counter::SmoothingIterations, self.iterations);
    }
}

/// Solves `G_μ = 0` for decreasing `μ` from `μ₀` down to `tolerance`, from `z0`, each stage by
/// `stage(problem, start, stage_tolerance)` (the backend's own iteration limited to
/// [`SmoothingSettings::stage_iterations`]); `out_of_time` ends it early. An invalid problem
/// ends it with the error.
///
/// The reduction adapts, as in path following: a stage that does not converge is abandoned,
/// and the continuation goes back to the last converged stage with the reduction `θ ← √θ` (a
/// smaller step along the path); after [`SmoothingSettings::max_cuts`] such cuts in a row, when
/// the cut would make `θ` larger than 0.9, or when no stage has converged yet, it keeps the
/// stage's point and goes on with `θ`. A stage that converges lets `θ` return towards its
/// setting (`θ ← θ²`, not below it). At most 100 stages.
pub fn continuation(
    mcp: &dyn Mcp,
    z0: &[f64],
    settings: &SmoothingSettings,
    tolerance: f64,
    mut stage: impl FnMut(&dyn Mcp, &[f64], f64) -> Result<Solution, SolveError>,
    out_of_time: impl Fn() -> bool,
) -> Result<ContinuationEnd, SolveError> {
    let mut f = vec![0.0; mcp.dim()];
    mcp.evaluate(z0, &mut f);
    let r0 = natural_residual(z0, &f, mcp.lower(), mcp.upper());
    let mut mu = settings.start * r0;
    let mut end = ContinuationEnd {
        z: z0.to_vec(),
        stages: 0,
        iterations: 0,
    };
    // The last converged stage: its μ and point.
    let mut good: Option<(f64, Vec<f64>)> = None;
    let mut theta = settings.reduction;
    let mut cuts = 0usize;
    // Unconverged stages kept in a row, or with `count_cut_stages` all unconverged stages since
    // the last stage converged with the set reduction.
    let mut failed = 0usize;
    let within_budget = |iterations: usize| settings.max_iterations.is_none_or(|m| iterations < m);
    while mu.is_finite()
        && mu > tolerance
        && end.stages < MAX_STAGES
        && within_budget(end.iterations)
        && !out_of_time()
    {
        let problem = Smoothed::new(mcp, mu);
        let start = good.as_ref().map_or(&end.z, |g| &g.1).clone();
        let result = stage(&problem, &start, settings.stage_tolerance * mu);
        end.stages += 1;
        let (converged, z) = match result {
            Ok(sol) => {
                end.iterations += sol.summary.iterations;
                (true, sol.z)
            }
            Err(SolveError::NotConverged { best }) => {
                end.iterations += best.summary.iterations;
                (false, best.z)
            }
            Err(e) => return Err(e),
        };
        let cut_back = !converged
            && good.is_some()
            && cuts < settings.max_cuts
            && theta.sqrt() <= MAX_REDUCTION;
        if settings.count_cut_stages {
            // A stage that converged only after cuts (θ above its setting) does not reset it.
            if converged && theta <= settings.reduction {
                failed = 0;
            } else if !converged {
                failed += 1;
            }
        } else if converged {
            failed = 0;
        } else if !cut_back {
            failed += 1;
        }
        let lost = settings
            .max_failed_stages
            .is_some_and(|m| failed >= m.max(1));
        match &good {
            Some((mu_good, _)) if cut_back => {
                if lost {
                    // `end.z` is the last converged stage's point.
                    break;
                }
                // Back to the last converged stage, a shorter step along the path.
                cuts += 1;
                theta = theta.sqrt();
                mu = mu_good * theta;
                continue;
            }
            _ => {}
        }
        if converged {
            cuts = 0;
            theta = (theta * theta).max(settings.reduction);
            good = Some((mu, z.clone()));
        } else {
            good = None;
        }
        end.z = z;
        mu *= theta;
        if lost {
            break;
        }
    }
    Ok(end)
}

/// `p_μ(t)` and `p_μ'(t)`.
#[inline]
fn plus(t: f64, mu: f64) -> (f64, f64) {
    let r = ecp_model::hypot(t, 2.0 * mu); // glibc's bits, inline
    if r > 0.0 {
        (0.5 * (t + r), 0.5 * (1.0 + t / r))
    } else {
        (0.0, 0.5)
    }
}

/// `G_μ` of `mcp` as an MCP with free components (see the module documentation).
pub struct Smoothed<'a> {
    mcp: &'a dyn Mcp,
    mu: f64,
    lower: Vec<f64>,
    upper: Vec<f64>,
    /// `F` at the point of the last Jacobian (the Jacobian of `G_μ` needs it).
    f: RefCell<Vec<f64>>,
}

impl<'a> Smoothed<'a> {
    /// `G_μ` of `mcp` (`μ = 0`: the natural map itself).
    pub fn new(mcp: &'a dyn Mcp, mu: f64) -> Self {
        let n = mcp.dim();
        Smoothed {
            mcp,
            mu,
            lower: vec![f64::NEG_INFINITY; n],
            upper: vec![f64::INFINITY; n],
            f: RefCell::new(vec![0.0; n]),
        }
    }

    /// `G_μ,i` from `z_i` and `F_i`, and the weight `c_i` of its Jacobian row.
    #[inline]
    fn component(&self, i: usize, z: f64, f: f64) -> (f64, f64) {
        let (l, u) = (self.mcp.lower()[i], self.mcp.upper()[i]);
        let x = z - f;
        let (mut g, mut c) = (f, 0.0);
        if l.is_finite() {
            let (p, dp) = plus(l - x, self.mu);
            g -= p;
            c += dp;
        }
        if u.is_finite() {
            let (p, dp) = plus(x - u, self.mu);
            g += p;
            c += dp;
        }
        (g, c)
    }
}

impl Mcp for Smoothed<'_> {
    fn dim(&self) -> usize {
        self.mcp.dim()
    }
    fn lower(&self) -> &[f64] {
        &self.lower
    }
    fn upper(&self) -> &[f64] {
        &self.upper
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        self.mcp.evaluate(z, f);
        for i in 0..z.len() {
            f[i] = self.component(i, z[i], f[i]).0;
        }
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        self.mcp.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        let mut f = self.f.borrow_mut();
        self.mcp.evaluate_with_jacobian(z, &mut f, values);
        self.scale_jacobian(z, &f, values);
    }
    fn evaluate_with_jacobian(&self, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        self.mcp.evaluate_with_jacobian(z, f, values);
        self.scale_jacobian(z, f, values);
        for i in 0..z.len() {
            f[i] = self.component(i, z[i], f[i]).0;
        }
    }
    fn component_name(&self, i: usize) -> String {
        self.mcp.component_name(i)
    }
    fn write_component_name(&self, i: usize, out: &mut String) {
        self.mcp.write_component_name(i, out)
    }
}

impl Smoothed<'_> {
    /// Turns the values of `J` at `z` (with `F(z) = f`) into those of `∂G_μ/∂z`.
    fn scale_jacobian(&self, z: &[f64], f: &[f64], values: &mut [f64]) {
        let pattern = self.mcp.jacobian_pattern();
        let rows = pattern.row_idx();
        let c: Vec<f64> = (0..z.len())
            .map(|i| self.component(i, z[i], f[i]).1)
            .collect();
        for (v, &r) in values.iter_mut().zip(rows) {
            *v *= 1.0 - c[r];
        }
        for (j, &p) in pattern.diag_pos().iter().enumerate() {
            values[p] += c[j];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecp_model::FnMcp;

    /// The LCP `0 ≤ z ⊥ z − 1 ≥ 0`.
    fn one_dimensional_lcp() -> FnMcp {
        FnMcp::dense(
            vec![0.0],
            vec![f64::INFINITY],
            |z, f| f[0] = z[0] - 1.0,
            |_z, j| j[0] = 1.0,
        )
        .unwrap_or_else(|e| panic!("{e}"))
    }

    /// A stage's report: 3 iterations, stopped at the limit (`finish_solve` judges the point).
    fn three_iterations() -> ecp_model::SolveReport {
        ecp_model::SolveReport {
            solver: "test",
            termination: ecp_model::Termination::MaxIterations,
            tolerance: 0.0,
            iterations: 3,
            f_evals: 0,
            jac_evals: 0,
            started: std::time::Instant::now(),
            trace: Vec::new(),
            counters: ecp_model::Counters::new(),
        }
    }

    /// A continuation whose stages never converge runs to its last stage without
    /// `max_failed_stages`, and stops after that many stages with it.
    #[test]
    fn a_continuation_that_lost_the_path_stops_after_max_failed_stages() {
        use ecp_model::finish_solve;
        let mcp = one_dimensional_lcp();
        // A stage that takes 3 iterations and fails (its point: the start).
        let failing = |problem: &dyn Mcp, z: &[f64], _tol: f64| {
            let report = three_iterations();
            match finish_solve(problem, z.to_vec(), report) {
                Ok(sol) => Err(SolveError::NotConverged {
                    best: Box::new(sol),
                }),
                e => e,
            }
        };
        let run = |max_failed_stages| {
            let settings = SmoothingSettings {
                max_failed_stages,
                ..SmoothingSettings::default()
            };
            continuation(&mcp, &[5.0], &settings, 1e-10, failing, || false)
                .unwrap_or_else(|e| panic!("{e}"))
        };
        // μ₀ = 4 (the natural residual at 5) halves each stage down to 1e-10: 36 stages.
        let all = run(None);
        assert_eq!(all.stages, 36);
        assert_eq!(all.iterations, 3 * 36);
        let cut = run(Some(4));
        assert_eq!(cut.stages, 4);
        assert_eq!(cut.iterations, 12);
    }

    /// A continuation that crawls — every stage at the set reduction fails, every shorter one
    /// after a cut converges — goes on to its last stage without `max_failed_stages` or without
    /// `count_cut_stages` (no unconverged stage is ever kept), and with both stops after that
    /// many failed stages, at the last converged stage's point
    /// (`docs/newton.md#a-crawling-continuation`).
    #[test]
    fn a_crawling_continuation_stops_after_max_failed_stages() {
        use ecp_model::finish_solve;
        use std::cell::Cell;
        let mcp = one_dimensional_lcp();
        let run = |max_failed_stages, count_cut_stages| {
            // Stage k (from 1) takes 3 iterations, converges when k is odd and fails when k is
            // even; each converged stage's point is its number, a failed one's the start.
            let calls = Cell::new(0usize);
            let crawling = |problem: &dyn Mcp, z: &[f64], _tol: f64| {
                calls.set(calls.get() + 1);
                let k = calls.get();
                let report = three_iterations();
                let point = if k % 2 == 1 {
                    vec![k as f64]
                } else {
                    z.to_vec()
                };
                match finish_solve(problem, point, report) {
                    Ok(sol) => Ok(sol),
                    Err(SolveError::NotConverged { best }) if k % 2 == 1 => Ok(*best),
                    e => e,
                }
            };
            let settings = SmoothingSettings {
                max_failed_stages,
                count_cut_stages,
                ..SmoothingSettings::default()
            };
            continuation(&mcp, &[5.0], &settings, 1e-10, crawling, || false)
                .unwrap_or_else(|e| panic!("{e}"))
        };
        // μ₀ = 4; a pair of stages (failed at θ = 0.5, converged at θ = √0.5) multiplies μ by
        // √0.5, so μ reaches 1e-10 after 70 pairs of stages, more than the 100 stages allowed.
        let all = run(None, true);
        assert_eq!(all.stages, 100);
        assert_eq!(all.iterations, 300);
        // Counting kept stages only, no failed stage is ever kept: to the last stage as well.
        let kept = run(Some(4), false);
        assert_eq!(kept.stages, 100);
        // Stages 2, 4, 6 and 8 fail: it stops at stage 8, at stage 7's point.
        let cut = run(Some(4), true);
        assert_eq!(cut.stages, 8);
        assert_eq!(cut.iterations, 24);
        assert_eq!(cut.z, vec![7.0]);
    }

    /// The LCP `0 ≤ z ⊥ z − 1 ≥ 0` smoothed: `G_μ = 0` at `z (z − 1) = μ²`, i.e.
    /// `z = (1 + √(1 + 4μ²)) / 2`, and the Jacobian matches a central difference.
    #[test]
    fn smoothed_natural_map_of_a_one_dimensional_lcp() {
        let mcp = one_dimensional_lcp();
        let mu = 0.3;
        let s = Smoothed::new(&mcp, mu);
        let root = 0.5 * (1.0 + (1.0 + 4.0 * mu * mu).sqrt());
        let mut g = [0.0];
        s.evaluate(&[root], &mut g);
        assert!(g[0].abs() <= 1e-15, "{}", g[0]);
        let (z, eps) = (0.4, 1e-6);
        let (mut gp, mut gm, mut j) = ([0.0], [0.0], [0.0]);
        s.evaluate(&[z + eps], &mut gp);
        s.evaluate(&[z - eps], &mut gm);
        s.jacobian(&[z], &mut j);
        assert!(
            (j[0] - (gp[0] - gm[0]) / (2.0 * eps)).abs() <= 1e-9,
            "{}",
            j[0]
        );
        // μ = 0: the natural map min(z, z − 1).
        let s0 = Smoothed::new(&mcp, 0.0);
        s0.evaluate(&[0.4], &mut g);
        assert!((g[0] - (0.4f64).min(-0.6)).abs() <= 1e-15);
    }
}
