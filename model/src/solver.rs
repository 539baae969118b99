//! Solver traits, reports and errors shared by every backend (`docs/backends.md`).

use std::time::{Duration, Instant};

use crate::counters::{Counter, Counters};
use crate::mcp::{FinalResiduals, Mcp, WorstComponent, final_residuals, write_worst_component};

/// Why a solve stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// The natural residual reached the tolerance.
    Converged,
    /// The iteration limit was reached.
    MaxIterations,
    /// No step along any search direction decreased the merit function enough.
    LineSearchFailed,
    /// The iterate stopped moving (step below the minimum) without converging.
    Stagnated,
    /// The problem function returned NaN or infinity at every trial point.
    NonFiniteFunction,
    /// An affine subproblem ended on a ray (pivotal methods): no solution found along the path.
    RayTermination,
    /// An inner solver (linear algebra or a conic program) failed.
    SubproblemFailed,
}

impl Termination {
    /// A short lower-case label for reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            Termination::Converged => "converged",
            Termination::MaxIterations => "max_iterations",
            Termination::LineSearchFailed => "line_search_failed",
            Termination::Stagnated => "stagnated",
            Termination::NonFiniteFunction => "non_finite_function",
            Termination::RayTermination => "ray_termination",
            Termination::SubproblemFailed => "subproblem_failed",
        }
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How a search direction was obtained in one iteration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepKind {
    /// Generalised Newton step `H d = −Φ`.
    Newton,
    /// Levenberg–Marquardt step `(HᵀH + λI) d = −HᵀΦ`.
    LevenbergMarquardt,
    /// Steepest descent on the merit function.
    Gradient,
    /// Pivotal (path) step of a PATH-like method.
    Path,
    /// Projected Newton step of a crash phase.
    Crash,
    /// Outer iteration of a convex-subproblem method.
    Conic,
}

/// One line of a solve's per-iteration trace.
#[derive(Clone, Debug, PartialEq)]
pub struct IterationRecord {
    /// Iteration number, from 0.
    pub iteration: usize,
    /// Natural residual at the start of the iteration.
    pub residual: f64,
    /// Merit function at the start of the iteration (backend-specific, e.g. `½‖Φ‖²`).
    pub merit: f64,
    /// Kind of direction taken.
    pub step: StepKind,
    /// Step length accepted.
    pub step_length: f64,
    /// Norm of the direction.
    pub direction_norm: f64,
}

/// Receives every iteration of a solve (argmin-style observer), e.g. for logging.
pub trait Observer: Send {
    /// Called once per iteration, after the step is accepted.
    fn observe(&mut self, record: &IterationRecord);
}

/// What happened in a solve: the counters and numbers a user needs to trust (or not) the result.
#[derive(Debug, PartialEq)]
pub struct Summary {
    /// Backend name.
    pub solver: String,
    /// Why it stopped.
    pub termination: Termination,
    /// Outer iterations taken.
    pub iterations: usize,
    /// Evaluations of `F`.
    pub f_evals: usize,
    /// Evaluations of `J`.
    pub jac_evals: usize,
    /// Natural-map residual of the returned point (computed by the model, `docs/model.md#mcp`).
    pub residual: f64,
    /// Fischer–Burmeister residual `‖Φ‖₂` of the returned point.
    pub fb_residual: f64,
    /// Component with the largest natural residual, if any.
    pub worst: Option<WorstComponent>,
    /// Wall-clock time of the solve.
    pub time: Duration,
    /// Per-iteration trace (empty unless requested in the settings).
    pub trace: Vec<IterationRecord>,
    /// Counters specific to the backend (for example [`Counter::Pivots`]), and the stepper's
    /// [`Counter::Retries`].
    pub counters: Counters,
}

/// No solve yet: an empty backend name, not converged, infinite residuals; storage for
/// [`McpSolver::solve_into`] to fill.
impl Default for Summary {
    fn default() -> Self {
        Summary {
            solver: String::new(),
            termination: Termination::MaxIterations,
            iterations: 0,
            f_evals: 0,
            jac_evals: 0,
            residual: f64::INFINITY,
            fb_residual: f64::INFINITY,
            worst: None,
            time: Duration::ZERO,
            trace: Vec::new(),
            counters: Counters::new(),
        }
    }
}

/// `clone_from` reuses the storage of the strings, the trace and the counters (a step record
/// refilled every step allocates nothing).
impl Clone for Summary {
    fn clone(&self) -> Self {
        Summary {
            solver: self.solver.clone(),
            termination: self.termination,
            iterations: self.iterations,
            f_evals: self.f_evals,
            jac_evals: self.jac_evals,
            residual: self.residual,
            fb_residual: self.fb_residual,
            worst: self.worst.clone(),
            time: self.time,
            trace: self.trace.clone(),
            counters: self.counters.clone(),
        }
    }
    fn clone_from(&mut self, source: &Self) {
        self.solver.clone_from(&source.solver);
        self.termination = source.termination;
        self.iterations = source.iterations;
        self.f_evals = source.f_evals;
        self.jac_evals = source.jac_evals;
        self.residual = source.residual;
        self.fb_residual = source.fb_residual;
        self.worst.clone_from(&source.worst);
        self.time = source.time;
        self.trace.clone_from(&source.trace);
        self.counters.clone_from(&source.counters);
    }
}

impl Summary {
    /// True when the solve converged.
    pub fn converged(&self) -> bool {
        self.termination == Termination::Converged
    }

    /// Value of a counter, `None` when this solve did not report it.
    pub fn counter(&self, counter: Counter) -> Option<usize> {
        self.counters.get(counter)
    }

    /// One line, as Ceres' `BriefReport`: solver, termination, iterations, natural residual and
    /// time, e.g. `newton: converged after 3 iterations, natural residual 1.2e-12, 41.0 µs`.
    pub fn brief_report(&self) -> String {
        format!(
            "{}: {} after {} iteration{}, natural residual {:.1e}, {}",
            self.solver,
            self.termination,
            self.iterations,
            if self.iterations == 1 { "" } else { "s" },
            self.residual,
            format_duration(self.time)
        )
    }

    /// Every field, one per line, as Ceres' `FullReport`: the brief report's numbers, the
    /// evaluations, both residuals, the worst component, every counter and the trace's length.
    pub fn full_report(&self) -> String {
        let mut lines = vec![
            format!("solver              {}", self.solver),
            format!("termination         {}", self.termination),
            format!("iterations          {}", self.iterations),
            format!("F evaluations       {}", self.f_evals),
            format!("J evaluations       {}", self.jac_evals),
            format!("natural residual    {:.3e}", self.residual),
            format!("FB residual         {:.3e}", self.fb_residual),
            match &self.worst {
                Some(w) => format!(
                    "worst component     {} (index {}, {:.3e})",
                    w.name, w.index, w.value
                ),
                None => "worst component     none".to_string(),
            },
            format!("time                {}", format_duration(self.time)),
            format!(
                "trace               {} record{}",
                self.trace.len(),
                if self.trace.len() == 1 { "" } else { "s" }
            ),
        ];
        if self.counters.is_empty() {
            lines.push("counters            none".to_string());
        } else {
            lines.push("counters".to_string());
            for (c, v) in self.counters.iter() {
                lines.push(format!("  {:<18}{v}", c.as_str()));
            }
        }
        lines.join("\n")
    }
}

/// `12.3 µs`, `4.56 ms` or `7.89 s`.
fn format_duration(d: Duration) -> String {
    let s = d.as_secs_f64();
    if s < 1e-3 {
        format!("{:.1} µs", s * 1e6)
    } else if s < 1.0 {
        format!("{:.2} ms", s * 1e3)
    } else {
        format!("{s:.2} s")
    }
}

/// A point returned by a backend with its summary. The default is empty storage for
/// [`McpSolver::solve_into`].
#[derive(Debug, Default, PartialEq)]
pub struct Solution {
    /// The unknowns in the MCP's own layout.
    pub z: Vec<f64>,
    /// What happened.
    pub summary: Summary,
}

/// `clone_from` reuses the storage.
impl Clone for Solution {
    fn clone(&self) -> Self {
        Solution {
            z: self.z.clone(),
            summary: self.summary.clone(),
        }
    }
    fn clone_from(&mut self, source: &Self) {
        self.z.clone_from(&source.z);
        self.summary.clone_from(&source.summary);
    }
}

/// Why a solve failed. Every failure carries the best iterate found (never NaN).
#[derive(Debug, thiserror::Error)]
pub enum SolveError {
    /// The backend stopped without reaching the tolerance; `best` is its best point.
    #[error("{solver} did not converge ({reason}): natural residual {residual:.3e} after {iterations} iterations{worst}",
        solver = .best.summary.solver,
        reason = .best.summary.termination,
        residual = .best.summary.residual,
        iterations = .best.summary.iterations,
        worst = .best.summary.worst.as_ref().map(|w| format!(", worst at {} ({:.3e})", w.name, w.value)).unwrap_or_default())]
    NotConverged {
        /// The best iterate (smallest merit) and its summary.
        best: Box<Solution>,
    },
    /// The problem or starting point is malformed (dimension, NaN start, empty bounds).
    #[error("invalid problem: {0}")]
    InvalidProblem(String),
}

impl SolveError {
    /// The best iterate, when the failure happened during the iterations.
    pub fn best(&self) -> Option<&Solution> {
        match self {
            SolveError::NotConverged { best } => Some(best),
            SolveError::InvalidProblem(_) => None,
        }
    }
}

/// A backend: anything that solves an [`Mcp`] from a starting point.
///
/// Backends keep state between solves (factorisation analyses, workspaces), hence `&mut self`:
/// a time stepper reuses one solver for every step.
pub trait McpSolver {
    /// Short name (`"newton"`, `"path"`, `"conic"`).
    fn name(&self) -> &str;
    /// Solves `mcp` from `z0`. Converged ⇒ `Ok`; otherwise the best iterate in the error.
    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError>;
    /// [`McpSolver::solve`] into storage the caller keeps across solves (a time stepper's):
    /// converged ⇒ `Ok` and `out` holds the solution; otherwise the error carries the best
    /// iterate and `out`'s contents are unspecified. The default moves `solve`'s result into
    /// `out`; a backend overrides it to reuse `out`'s storage (the Newton and PATH backends
    /// allocate nothing in a warm solve once their workspaces and `out` have grown,
    /// `docs/latency.md#allocations`). The same point and summary as `solve`, bit for bit.
    fn solve_into(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        out: &mut Solution,
    ) -> Result<(), SolveError> {
        *out = self.solve(mcp, z0)?;
        Ok(())
    }
    /// Caps the iterations of the next solves at `budget` until it is set again (`None`: the
    /// backend's own limits and restarts). A budgeted solve is the backend's first attempt
    /// alone, stopped after `budget` iterations (in each system of units it tries,
    /// [`crate::scaling::solve_in_scales`], so at most twice `budget` in all): for a caller that has a cheaper second start
    /// when a cheap first one fails (the driver's extrapolated warm start,
    /// `docs/latency.md#the-extrapolated-warm-start-on-by-default-branch-wip-warmon-issue-18`).
    /// A solve that converges within the budget gives the same point as without it. (The Newton
    /// backend with `NewtonSettings::josephy_newton` on, its default, follows a failed budgeted
    /// run with at most `budget` Josephy–Newton steps and one more budgeted run from their end:
    /// `docs/newton.md#josephy-newton-steps`; and a run still converging fast when its budget
    /// is spent goes on while it does, `NewtonSettings::budget_grace`.) Returns whether the backend honours budgets; the
    /// default does not (and ignores `budget`).
    fn set_iteration_budget(&mut self, budget: Option<usize>) -> bool {
        let _ = budget;
        false
    }
    /// Marks the starts of the next solves, until it is set again, as predictions (`true`: a
    /// time step's extrapolated warm start) or not. A backend that honours it returns a
    /// predicted start as it stands only when its natural residual is at the round-off floor
    /// of the point; a start below its polish bound but above that floor takes one polish
    /// step, as a start just below the tolerance does. An extrapolation's miss is not the
    /// round-off of the last answer, so accepting it anywhere below the polish bound would
    /// move results by up to that bound's effect on the unknowns (the T-bar with PATH: 1.16e-12
    /// at a start of residual 9.9e-14, `docs/latency.md`, branch wip-xorder2). Returns whether
    /// the backend honours it; the default does not (and ignores it).
    fn set_start_predicted(&mut self, predicted: bool) -> bool {
        let _ = predicted;
        false
    }
    /// Whether the backend's converged point does not depend on its starting point beyond
    /// round-off: it converges fast enough near a solution to end far below its tolerance
    /// (semismooth Newton: quadratically, to ~1e-16), so that two starts of one step give the
    /// same answer within 1e-12 (PATH with its polish likewise). A backend that stops at its
    /// tolerance (conic, PATH without its polish) may end
    /// anywhere within it. The driver extrapolates warm starts only for such backends. The
    /// default is `false`.
    fn converges_to_round_off(&self) -> bool {
        false
    }
}

/// Validates a starting point against a problem: dimension and finiteness.
pub fn validate_start(mcp: &dyn Mcp, z0: &[f64]) -> Result<(), SolveError> {
    if z0.len() != mcp.dim() {
        return Err(SolveError::InvalidProblem(format!(
            "starting point has {} entries, problem has {}",
            z0.len(),
            mcp.dim()
        )));
    }
    if let Some(i) = crate::mcp::first_non_finite(z0) {
        return Err(SolveError::InvalidProblem(format!(
            "starting point entry {} ({}) is not finite",
            i,
            mcp.component_name(i)
        )));
    }
    Ok(())
}

/// What a backend knows when it stops, handed to [`finish_solve`].
#[derive(Clone, Debug)]
pub struct SolveReport {
    /// Backend name for the summary.
    pub solver: &'static str,
    /// The backend's own reason for stopping.
    pub termination: Termination,
    /// Tolerance on the natural residual.
    pub tolerance: f64,
    /// Iterations taken.
    pub iterations: usize,
    /// Evaluations of `F` so far.
    pub f_evals: usize,
    /// Evaluations of `J` so far.
    pub jac_evals: usize,
    /// When the solve started.
    pub started: Instant,
    /// Per-iteration trace.
    pub trace: Vec<IterationRecord>,
    /// Backend counters.
    pub counters: Counters,
}

/// Judges a backend's final point `z` by the model's natural residual (`docs/model.md#mcp`), the
/// one rule for every backend, and builds the [`Solution`] or the
/// [`SolveError::NotConverged`] that carries it.
///
/// A point within the tolerance has converged whatever the backend thought; a backend that
/// claimed convergence on a point that is not within it is reported as stagnated.
pub fn finish_solve(
    mcp: &dyn Mcp,
    z: Vec<f64>,
    report: SolveReport,
) -> Result<Solution, SolveError> {
    // One evaluation of F serves both residuals.
    let mut f = vec![0.0; z.len()];
    mcp.evaluate(&z, &mut f);
    let mut report = report;
    report.f_evals += 1;
    finish_solve_at(mcp, z, &f, report)
}

/// [`finish_solve`] for a backend that has `F(z)` at hand in `f` (its last evaluation, at the
/// point it returns): the same judgement without evaluating `F` again.
pub fn finish_solve_at(
    mcp: &dyn Mcp,
    z: Vec<f64>,
    f: &[f64],
    report: SolveReport,
) -> Result<Solution, SolveError> {
    let mut summary = Summary::default();
    let residuals = final_residuals(&z, f, mcp.lower(), mcp.upper());
    judge(mcp, &residuals, report, &mut summary);
    let solution = Solution { z, summary };
    if solution.summary.converged() {
        Ok(solution)
    } else {
        Err(SolveError::NotConverged {
            best: Box::new(solution),
        })
    }
}

/// [`finish_solve_at`] into `out`, reusing its storage: the point, the backend's name and the
/// worst component's name are copied in, `report`'s counters and trace moved in (a backend
/// that builds them in the `Counters` and trace it takes from `out` reuses theirs too). So a
/// backend that keeps its result's storage across solves allocates nothing here. Returns
/// whether the point converged; the summary is the one [`finish_solve_at`] would give.
pub fn finish_solve_into(
    mcp: &dyn Mcp,
    z: &[f64],
    f: &[f64],
    report: SolveReport,
    out: &mut Solution,
) -> bool {
    let residuals = final_residuals(z, f, mcp.lower(), mcp.upper());
    finish_solve_with(mcp, z, &residuals, report, out)
}

/// [`finish_solve_into`] for a backend that has the residuals of `z` at hand (computed by
/// [`final_residuals`] or bit for bit as it does, at `z`): the same summary without another
/// pass over the components.
pub fn finish_solve_with(
    mcp: &dyn Mcp,
    z: &[f64],
    residuals: &FinalResiduals,
    report: SolveReport,
    out: &mut Solution,
) -> bool {
    out.z.clear();
    out.z.extend_from_slice(z);
    judge(mcp, residuals, report, &mut out.summary);
    out.summary.converged()
}

/// The one judgement of [`finish_solve_at`], [`finish_solve_into`] and [`finish_solve_with`]:
/// fills `summary` from the residuals of the final point and the backend's `report`.
fn judge(mcp: &dyn Mcp, residuals: &FinalResiduals, report: SolveReport, summary: &mut Summary) {
    let residual = residuals.natural;
    write_worst_component(mcp, residuals.worst, &mut summary.worst);
    let termination = if residual <= report.tolerance {
        Termination::Converged
    } else if report.termination == Termination::Converged {
        Termination::Stagnated
    } else {
        report.termination
    };
    summary.solver.clear();
    summary.solver.push_str(report.solver);
    summary.termination = termination;
    summary.iterations = report.iterations;
    summary.f_evals = report.f_evals;
    summary.jac_evals = report.jac_evals;
    summary.residual = residual;
    summary.fb_residual = residuals.fb_residual();
    summary.time = report.started.elapsed();
    summary.trace = report.trace;
    summary.counters = report.counters;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary() -> Summary {
        Summary {
            solver: "path".into(),
            termination: Termination::Converged,
            iterations: 3,
            f_evals: 7,
            jac_evals: 3,
            residual: 1.25e-12,
            fb_residual: 2.5e-12,
            worst: Some(WorstComponent {
                index: 4,
                value: 1.25e-12,
                name: "contact.p_n[0]".into(),
            }),
            time: Duration::from_nanos(41_040),
            trace: Vec::new(),
            counters: Counters::from([(Counter::Pivots, 12), (Counter::Custom("hits"), 2)]),
        }
    }

    #[test]
    fn brief_report_is_one_line_with_the_key_numbers() {
        let mut s = summary();
        assert_eq!(
            s.brief_report(),
            "path: converged after 3 iterations, natural residual 1.2e-12, 41.0 µs"
        );
        s.termination = Termination::MaxIterations;
        s.iterations = 1;
        s.time = Duration::from_millis(1500);
        assert_eq!(
            s.brief_report(),
            "path: max_iterations after 1 iteration, natural residual 1.2e-12, 1.50 s"
        );
    }

    #[test]
    fn full_report_lists_every_field_and_counter() {
        let s = summary();
        let text = s.full_report();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 13, "{text}");
        assert_eq!(lines[0], "solver              path");
        assert_eq!(lines[3], "F evaluations       7");
        assert_eq!(lines[4], "J evaluations       3");
        assert_eq!(lines[6], "FB residual         2.500e-12");
        assert_eq!(
            lines[7],
            "worst component     contact.p_n[0] (index 4, 1.250e-12)"
        );
        assert_eq!(lines[8], "time                41.0 µs");
        assert_eq!(lines[9], "trace               0 records");
        assert_eq!(lines[11], "  pivots            12");
        assert_eq!(lines[12], "  hits              2");
        let bare = Summary {
            worst: None,
            counters: Counters::new(),
            time: Duration::from_micros(2500),
            ..summary()
        };
        let text = bare.full_report();
        assert!(text.contains("worst component     none"), "{text}");
        assert!(text.contains("counters            none"), "{text}");
        assert!(text.contains("time                2.50 ms"), "{text}");
    }
}
