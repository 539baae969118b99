//! Solver traits, reports and errors shared by every backend (`docs/backends.md`).

use std::time::{Duration, Instant};

use crate::mcp::{Mcp, WorstComponent, diagnose, fb_residual};

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
#[derive(Clone, Debug, PartialEq)]
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
    /// Counters specific to the backend (for example `"lm_steps"`, `"pivots"`).
    pub counters: Vec<(&'static str, usize)>,
}

impl Summary {
    /// True when the solve converged.
    pub fn converged(&self) -> bool {
        self.termination == Termination::Converged
    }
    /// Value of a backend counter, 0 if absent.
    pub fn counter(&self, name: &str) -> usize {
        self.counters
            .iter()
            .find(|(n, _)| *n == name)
            .map_or(0, |(_, v)| *v)
    }
}

/// A point returned by a backend with its summary.
#[derive(Clone, Debug, PartialEq)]
pub struct Solution {
    /// The unknowns in the MCP's own layout.
    pub z: Vec<f64>,
    /// What happened.
    pub summary: Summary,
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
    if let Some(i) = z0.iter().position(|v| !v.is_finite()) {
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
    pub counters: Vec<(&'static str, usize)>,
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
    let (residual, worst) = diagnose(mcp, &z);
    let mut f = vec![0.0; z.len()];
    mcp.evaluate(&z, &mut f);
    let termination = if residual <= report.tolerance {
        Termination::Converged
    } else if report.termination == Termination::Converged {
        Termination::Stagnated
    } else {
        report.termination
    };
    let summary = Summary {
        solver: report.solver.into(),
        termination,
        iterations: report.iterations,
        // `diagnose` and the FB residual each evaluate F once.
        f_evals: report.f_evals + 2,
        jac_evals: report.jac_evals,
        residual,
        fb_residual: fb_residual(&z, &f, mcp.lower(), mcp.upper()),
        worst,
        time: report.started.elapsed(),
        trace: report.trace,
        counters: report.counters,
    };
    let solution = Solution { z, summary };
    if solution.summary.converged() {
        Ok(solution)
    } else {
        Err(SolveError::NotConverged {
            best: Box::new(solution),
        })
    }
}
