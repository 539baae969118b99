//! Newton's last restart: a continuation in the friction coefficient
//! ([`super::NewtonSettings::friction_continuation`],
//! `docs/newton.md#a-continuation-in-the-friction-coefficient`).
//!
//! Where every attempt from `z0` fails because the step's solution lies on another branch than
//! the warm start's (a vertex in a trough's crease loaded by both planes: the solution wedges the
//! body, `docs/newton.md#a-jam-in-the-crease-s20261212_022_v_trough-step-62`), the family
//! `F(z; s)` with the friction coefficient scaled by `s` ([`ecp_model::Mcp::friction_family`])
//! joins the two: at a smaller `s` the plain iteration solves the step from `z0`, and the
//! solutions form a curve in `(z, s)` that may turn back (a fold: the warm start's branch ends)
//! before it reaches `s = 1` on the other branch. Following it by arc length (pseudo-arclength
//! continuation, Allgower & Georg, "Introduction to Numerical Continuation Methods", SIAM 2003,
//! §2–3, on the Fischer–Burmeister system `Φ(z; s) = 0`) goes round the fold, where a
//! continuation monotone in `s` stops. `Φ`'s Jacobian in `z` is singular on the whole curve (the
//! face multipliers of a vertex shared by several faces are not unique), so the tangent is the
//! previous one projected on the null space of `[H Φ_s]` and the corrector is the minimum-norm
//! Gauss–Newton step `−[H Φ_s]⁺ Φ` (both by [`MinNorm`]): the Moore–Penrose continuation of
//! Allgower & Georg §3.3, which needs no bordering row and moves no farther than it must along
//! the non-unique directions.
//!
//! Dense: it runs only on problems up to [`super::NewtonSettings::dense_max`] unknowns, and only
//! after every other attempt failed, so a step that any earlier attempt solves is unchanged.

use std::sync::Arc;

use ecp_model::bounds::{BoundKind, classify};
use ecp_model::mcp::fb_vector_of_kinds;
use ecp_model::{CscPattern, Mcp, McpFamily, Solution, SolveError};

use super::min_norm::MinNorm;
use super::{NewtonSolver, fold_attempt, generalized_jacobian_rows};

/// The scales `s` of the friction coefficient tried, in order, for the curve's first point:
/// the plain iteration from `z0` on `F(·; s)`, at most [`START_ITERATIONS`] iterations each.
/// Halving `μ` removes the wedge of the crease step (6 iterations there). Not the frictionless
/// step: there every slip rate's pair is degenerate and the curve was lost at its first step on
/// each stress step measured (`docs/latency.md`, wip-crease).
const START_SCALES: [f64; 2] = [0.5, 0.25];

/// Iteration limit of each start (a start that needs more is not an easy one; the failed starts
/// measured took 40–55 iterations each before the stall test stopped them).
const START_ITERATIONS: usize = 30;

/// Relative rank tolerance of the minimum-norm decompositions of `[H Φ_s]`: smaller singular
/// directions count as the null space (the crease step's smallest nonzero singular value is
/// about 1e-6 of the largest; its non-unique face multipliers give exact zeros).
const RANK_TOLERANCE: f64 = 1e-9;

/// Longest arc-length step (in the scaled unknowns and `s`); the first step is a fifth of it.
const LONGEST_STEP: f64 = 0.05;

/// Step growth after an accepted step, and the shortest step before the continuation gives up.
const GROWTH: f64 = 1.5;
const SHORTEST_STEP: f64 = 1e-10;

/// Corrector iterations per trial step.
const CORRECTOR_ITERATIONS: usize = 12;

/// A corrected point may lie at most this many times the step length (and at least 1e-3) from
/// the point before in any component: a corrector that lands farther has jumped to another
/// branch.
const DRIFT: f64 = 10.0;

/// The central difference of `F` in `s` (exact up to round-off where `F` is affine in `μ`, as the
/// friction cone's rows are).
const DS: f64 = 1e-6;

/// The problem `F(·; s)` of a family, as an MCP (the problem's bounds, pattern and names).
struct AtScale<'a> {
    mcp: &'a dyn Mcp,
    family: &'a dyn McpFamily,
    s: f64,
}

impl Mcp for AtScale<'_> {
    fn dim(&self) -> usize {
        self.mcp.dim()
    }
    fn lower(&self) -> &[f64] {
        self.mcp.lower()
    }
    fn upper(&self) -> &[f64] {
        self.mcp.upper()
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        self.family.evaluate_at(self.s, z, f)
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        self.mcp.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        let mut f = vec![0.0; self.dim()];
        self.family
            .evaluate_with_jacobian_at(self.s, z, &mut f, values)
    }
    fn evaluate_with_jacobian(&self, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        self.family.evaluate_with_jacobian_at(self.s, z, f, values)
    }
    fn write_component_name(&self, i: usize, out: &mut String) {
        self.mcp.write_component_name(i, out)
    }
    fn component_name(&self, i: usize) -> String {
        self.mcp.component_name(i)
    }
    fn elimination_groups(&self) -> &[Vec<usize>] {
        self.mcp.elimination_groups()
    }
}

impl NewtonSolver {
    /// The continuation in the friction coefficient, folded into the failed attempts' count and
    /// best point as [`NewtonSolver::solve_restarted`]'s other attempts (`Some` when it ends the
    /// solve): the curve's first point by the plain iteration on `F(·; s)` from `z0`
    /// ([`START_SCALES`]), the curve followed to `s ≥ 1` ([`follow`]), then the plain iteration
    /// on the problem itself from there; counted as `friction_continuations`, its corrector
    /// iterations as iterations. `None` when the problem has no friction family, is above
    /// `dense_max`, or no start converges.
    pub(super) fn friction_continuation_attempt(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        spent: &mut usize,
        best: &mut Box<Solution>,
    ) -> Option<Result<Solution, SolveError>> {
        let max_iterations = self.settings.friction_continuation?;
        let family = mcp.friction_family()?;
        if mcp.dim() > self.settings.dense_max {
            return None;
        }
        self.attempt = 0;
        let mut start = None;
        let limit = self.settings.max_iterations;
        self.settings.max_iterations = START_ITERATIONS.min(limit);
        for s in START_SCALES {
            // The plain run alone (no minimum-norm restart): a start is cheap or skipped.
            match self.solve_once(&AtScale { mcp, family, s }, z0) {
                Ok(sol) => {
                    *spent += sol.summary.iterations;
                    start = Some((sol.z, s));
                    break;
                }
                Err(SolveError::NotConverged { best }) => *spent += best.summary.iterations,
                Err(_) => break,
            }
        }
        self.settings.max_iterations = limit;
        let (z, s) = start?;
        let tolerance = self.settings.tolerance;
        let (end, curve_iterations) = follow(mcp, family, z, s, max_iterations, tolerance);
        *spent += curve_iterations;
        let end = end?;
        let result = self.solve_plain_tallied(mcp, &end, "friction_continuations");
        fold_attempt(result, spent, best)
    }
}

/// `Φ(z; s)` and the dense column-major `n × (n + 1)` Jacobian `[H Φ_s]` (with a zero last row,
/// so that it is square for [`MinNorm`]) of the Fischer–Burmeister system of `F(·; s)`.
struct Augmented<'a> {
    mcp: &'a dyn Mcp,
    family: &'a dyn McpFamily,
    kinds: Vec<BoundKind>,
    f: Vec<f64>,
    f_plus: Vec<f64>,
    f_minus: Vec<f64>,
    jac: Vec<f64>,
    da: Vec<f64>,
    db: Vec<f64>,
    degenerate: Vec<usize>,
    jv: Vec<f64>,
    phi: Vec<f64>,
    /// Column-major `(n + 1) × (n + 1)`.
    a: Vec<f64>,
}

impl<'a> Augmented<'a> {
    fn new(mcp: &'a dyn Mcp, family: &'a dyn McpFamily) -> Self {
        let n = mcp.dim();
        let kinds = (0..n)
            .map(|i| classify(mcp.lower()[i], mcp.upper()[i]))
            .collect();
        Augmented {
            mcp,
            family,
            kinds,
            f: vec![0.0; n],
            f_plus: vec![0.0; n],
            f_minus: vec![0.0; n],
            jac: vec![0.0; mcp.jacobian_pattern().nnz()],
            da: vec![0.0; n],
            db: vec![0.0; n],
            degenerate: Vec::with_capacity(n),
            jv: vec![0.0; n],
            phi: vec![0.0; n],
            a: vec![0.0; (n + 1) * (n + 1)],
        }
    }

    /// Evaluates `Φ` at `(z, s)` into `phi`; returns `max |Φ_i|` (`∞` when not finite).
    fn residual(&mut self, z: &[f64], s: f64) -> f64 {
        let (l, u) = (self.mcp.lower(), self.mcp.upper());
        self.family.evaluate_at(s, z, &mut self.f);
        fb_vector_of_kinds(z, &self.f, l, u, &self.kinds, &mut self.phi);
        self.phi.iter().fold(0.0, |m: f64, p| {
            if p.is_finite() {
                m.max(p.abs())
            } else {
                f64::INFINITY
            }
        })
    }

    /// Forms `[H Φ_s]` at `(z, s)` (and `Φ` there) and decomposes it into `min_norm`; `false`
    /// when the decomposition fails.
    fn factor(&mut self, z: &[f64], s: f64, min_norm: &mut MinNorm) -> bool {
        let n = z.len();
        let (l, u) = (self.mcp.lower(), self.mcp.upper());
        self.family
            .evaluate_with_jacobian_at(s, z, &mut self.f, &mut self.jac);
        fb_vector_of_kinds(z, &self.f, l, u, &self.kinds, &mut self.phi);
        let pattern = self.mcp.jacobian_pattern();
        // Main's rows: the continuation's path does not start at a kink by extrapolation.
        generalized_jacobian_rows(
            None,
            0.0,
            z,
            &self.f,
            l,
            u,
            &self.kinds,
            pattern,
            &self.jac,
            &mut self.da,
            &mut self.db,
            &mut self.degenerate,
            &mut self.jv,
        );
        self.family.evaluate_at(s + DS, z, &mut self.f_plus);
        self.family.evaluate_at(s - DS, z, &mut self.f_minus);
        let m = n + 1;
        self.a.fill(0.0);
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        for j in 0..n {
            for p in cp[j]..cp[j + 1] {
                let i = ri[p];
                self.a[j * m + i] += self.db[i] * self.jac[p];
            }
            self.a[j * m + j] += self.da[j];
        }
        for i in 0..n {
            self.a[n * m + i] = self.db[i] * (self.f_plus[i] - self.f_minus[i]) / (2.0 * DS);
        }
        min_norm.factor(m, &self.a, RANK_TOLERANCE).is_some()
    }
}

/// Follows the curve `Φ(z; s) = 0` from its point `(z, s)` in the direction of growing `s` until
/// `s ≥ 1` or `max_iterations` decompositions of `[H Φ_s]` (tangents and corrector steps):
/// returns the first point past `s = 1` (`None` when the curve was lost: the corrector failed at
/// the shortest step, `s` fell below 0, the iterations ran out) and the iterations spent.
/// Corrected to `max |Φ| ≤ tolerance`.
fn follow(
    mcp: &dyn Mcp,
    family: &dyn McpFamily,
    mut z: Vec<f64>,
    mut s: f64,
    max_iterations: usize,
    tolerance: f64,
) -> (Option<Vec<f64>>, usize) {
    let n = z.len();
    let mut aug = Augmented::new(mcp, family);
    let mut min_norm = MinNorm::default();
    let mut iterations = 0;
    // The tangent (unit, in (z, s)), first along s.
    let mut t = vec![0.0; n + 1];
    t[n] = 1.0;
    let mut at = vec![0.0; n + 1];
    let mut y = vec![0.0; n];
    let mut d = vec![0.0; n + 1];
    let mut step = LONGEST_STEP / 5.0;
    while iterations < max_iterations {
        iterations += 1;
        if !aug.factor(&z, s, &mut min_norm) {
            return (None, iterations);
        }
        // t − A⁺ A t: the previous tangent on the null space of A = [H Φ_s].
        let m = n + 1;
        at.fill(0.0);
        for j in 0..m {
            for i in 0..n {
                at[i] += aug.a[j * m + i] * t[j];
            }
        }
        if !min_norm.solve_in_place(&mut at) {
            return (None, iterations);
        }
        for (tj, aj) in t.iter_mut().zip(&at) {
            *tj -= aj;
        }
        let norm = t.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm.is_nan() || norm <= 1e-3 {
            // The null space turned away from the curve's direction (or a NaN): lost.
            return (None, iterations);
        }
        t.iter_mut().for_each(|v| *v /= norm);
        let mut accepted = false;
        while step >= SHORTEST_STEP {
            for i in 0..n {
                y[i] = z[i] + step * t[i];
            }
            let mut sy = s + step * t[n];
            let mut converged = false;
            for _ in 0..CORRECTOR_ITERATIONS {
                if aug.residual(&y, sy) <= tolerance {
                    converged = true;
                    break;
                }
                if iterations >= max_iterations {
                    return (None, iterations);
                }
                iterations += 1;
                if !aug.factor(&y, sy, &mut min_norm) {
                    break;
                }
                d[..n].copy_from_slice(&aug.phi);
                d[n] = 0.0;
                if !min_norm.solve_in_place(&mut d) {
                    break;
                }
                for i in 0..n {
                    y[i] -= d[i];
                }
                sy -= d[n];
            }
            let reach = DRIFT * step.max(1e-3);
            if converged && (0..n).all(|i| (y[i] - z[i]).abs() <= reach) {
                z.copy_from_slice(&y);
                s = sy;
                accepted = true;
                step = (step * GROWTH).min(LONGEST_STEP);
                break;
            }
            step *= 0.5;
        }
        if !accepted || s < 0.0 {
            return (None, iterations);
        }
        if s >= 1.0 {
            return (Some(z), iterations);
        }
    }
    (None, iterations)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecp_model::FnMcp;

    /// `F(z; s)` of one free unknown with a fold: `z³ − z − (2s − 1)·k`, `k = 0.6`: the branch
    /// through `z ≈ −1` at `s = 0` ends at a fold (`z = −1/√3`, `2s − 1 = 2/(3√3 k)`) before
    /// `s = 1`, where the only solution is on the other branch, `z ≈ 1.2`.
    struct Cubic;
    const K: f64 = 0.6;
    fn cubic(s: f64, z: &[f64], f: &mut [f64]) {
        f[0] = z[0] * z[0] * z[0] - z[0] - (2.0 * s - 1.0) * K;
    }
    impl McpFamily for Cubic {
        fn evaluate_at(&self, s: f64, z: &[f64], f: &mut [f64]) {
            cubic(s, z, f)
        }
        fn evaluate_with_jacobian_at(&self, s: f64, z: &[f64], f: &mut [f64], v: &mut [f64]) {
            cubic(s, z, f);
            v[0] = 3.0 * z[0] * z[0] - 1.0;
        }
    }
    fn problem() -> FnMcp {
        FnMcp::dense(
            vec![f64::NEG_INFINITY],
            vec![f64::INFINITY],
            |z, f| cubic(1.0, z, f),
            |z, j| j[0] = 3.0 * z[0] * z[0] - 1.0,
        )
        .expect("a valid MCP")
    }

    #[test]
    fn the_curve_is_followed_round_its_fold_to_the_other_branch() {
        let mcp = problem();
        // The point of the curve at s = 0 near −1: z³ − z + 0.6 = 0.
        let mut z = -1.0f64;
        for _ in 0..50 {
            z -= (z * z * z - z + K) / (3.0 * z * z - 1.0);
        }
        let (end, iterations) = follow(&mcp, &Cubic, vec![z], 0.0, 500, 1e-12);
        let end = end.expect("the curve reaches s = 1");
        // Past the fold at s = 0.82 the curve runs back along the middle branch to the other
        // fold (z = 1/√3, s = 0.18), then up the upper branch: the first point past s = 1
        // (at most one step of 0.05 beyond it) is near the only root at s = 1, z = 1.221.
        assert!(end[0] > 1.2 && end[0] < 1.26, "z = {}", end[0]);
        assert!(iterations > 10, "{iterations} iterations");
        // The lower branch, which a continuation monotone in s follows, has no point at s = 1.
        let mut f = [0.0];
        cubic(1.0, &end, &mut f);
        assert!(f[0].abs() < 0.2, "F = {}", f[0]);
        cubic(1.0, &[-1.0 / 3f64.sqrt()], &mut f);
        assert!(
            f[0] < 0.0,
            "the lower branch's highest point lies below F = 0 at s = 1"
        );
    }
}
