//! What the driver does when a backend cannot solve a step: the same physics, tried harder
//! (`docs/fallbacks.md`).
//!
//! A step whose solve does not reach the tolerance is never taken from its best iterate. The
//! driver first solves the same step problem with each fallback backend in turn, then splits the
//! step into substeps `h/2, h/4, …` (bisecting only the pieces that fail) that together reach
//! `t_{u+1}`; every piece is judged by the same natural residual as a plain step. When that is
//! exhausted too, the step is reported as failed and the bodies keep the last feasible state, the
//! state at the start of the step. A formulation takes part as far as its
//! [`Capabilities`](super::Capabilities) allow.

use ecp_model::{McpSolver, Solution};

use crate::record::StepMethod;
use crate::scene::SceneError;

/// The fallbacks a simulation may use for a step its backend could not solve.
pub struct Fallbacks {
    /// Other backends that solve the same step problem, tried in order after the primary one.
    pub backends: Vec<Box<dyn McpSolver>>,
    /// How often a failing step may be halved: substeps go down to `h / 2^max_halvings`
    /// (0: no substeps).
    pub max_halvings: u32,
}

impl Fallbacks {
    /// No fallback: a step that its backend cannot solve fails.
    pub fn none() -> Self {
        Fallbacks {
            backends: Vec::new(),
            max_halvings: 0,
        }
    }

    /// The default number of halvings: substeps down to `h/16`.
    pub const DEFAULT_HALVINGS: u32 = 4;

    /// `backends` in order, then substeps down to `h/16`.
    pub fn new(backends: Vec<Box<dyn McpSolver>>) -> Self {
        Fallbacks {
            backends,
            max_halvings: Self::DEFAULT_HALVINGS,
        }
    }

    /// True when there is nothing to fall back on.
    pub fn is_empty(&self) -> bool {
        self.backends.is_empty() && self.max_halvings == 0
    }
}

impl Default for Fallbacks {
    fn default() -> Self {
        Self::none()
    }
}

impl std::fmt::Debug for Fallbacks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = self.backends.iter().map(|b| b.name()).collect();
        f.debug_struct("Fallbacks")
            .field("backends", &names)
            .field("max_halvings", &self.max_halvings)
            .finish()
    }
}

/// What the fallbacks need from the driver: save and restore its state, and solve one span from
/// the current state (taking the solution when it is one).
pub(crate) trait Spans {
    /// A saved state.
    type Checkpoint;
    /// Saves the current state.
    fn checkpoint(&self) -> Self::Checkpoint;
    /// Goes back to a saved state.
    fn restore(&mut self, checkpoint: &Self::Checkpoint);
    /// Prepares `[t0, t0 + h]` from the current state and solves it with `solver`; a solution
    /// is taken (the state moves to the end of the span) and returned as the backend gave it.
    fn solve_span(
        &mut self,
        solver: &mut dyn McpSolver,
        t0: f64,
        h: f64,
    ) -> Result<Option<Solution>, SceneError>;
}

/// How a step was saved by its fallbacks: the solver summary of the last piece, the method, and
/// the solution when one step problem holds the whole step (a fallback backend).
pub(crate) type Rescue = (ecp_model::Summary, StepMethod, Option<Solution>);

/// Tries the fallbacks on the step `[t0, t0 + h]` that `solver` could not solve, from the state
/// saved in `start`: each fallback backend (when `backends`), then substeps (when `substeps`).
/// Returns `None` when everything failed (the state is then back at `start`).
pub(crate) fn rescue<S: Spans>(
    driver: &mut S,
    start: &S::Checkpoint,
    solver: &mut dyn McpSolver,
    fallbacks: &mut Fallbacks,
    (t0, h): (f64, f64),
    (backends, substeps): (bool, bool),
) -> Result<Option<Rescue>, SceneError> {
    if backends {
        for k in 0..fallbacks.backends.len() {
            driver.restore(start);
            if let Some(sol) = driver.solve_span(fallbacks.backends[k].as_mut(), t0, h)? {
                let name = fallbacks.backends[k].name().to_string();
                return Ok(Some((
                    sol.summary.clone(),
                    StepMethod::Backend(name),
                    Some(sol),
                )));
            }
        }
    }
    if substeps && fallbacks.max_halvings > 0 {
        driver.restore(start);
        let mut pieces = Vec::new();
        let mut last = None;
        let mut span = Halving {
            solver,
            fallbacks,
            backends,
        };
        let covered = span.halves(driver, t0, h, 1, &mut pieces, &mut last)?;
        if let (true, Some(s)) = (covered, last) {
            let finest = pieces.iter().copied().max().unwrap_or(1);
            let method = StepMethod::Substeps {
                pieces: pieces.len(),
                finest,
            };
            return Ok(Some((s, method, None)));
        }
    }
    driver.restore(start);
    Ok(None)
}

struct Halving<'a> {
    solver: &'a mut dyn McpSolver,
    fallbacks: &'a mut Fallbacks,
    backends: bool,
}

impl Halving<'_> {
    /// Solves `[t0, t0 + h]` from the current state as two halves, each with the solver then the
    /// fallback backends, bisecting a half again when all fail, down to `depth =
    /// max_halvings`. Appends each accepted piece's denominator (2^depth) to `pieces` and keeps
    /// the last piece's summary in `last`; returns whether the whole span was covered.
    fn halves<S: Spans>(
        &mut self,
        driver: &mut S,
        t0: f64,
        h: f64,
        depth: u32,
        pieces: &mut Vec<usize>,
        last: &mut Option<ecp_model::Summary>,
    ) -> Result<bool, SceneError> {
        let half = 0.5 * h;
        let tries = if self.backends {
            self.fallbacks.backends.len()
        } else {
            0
        };
        for k in 0..2 {
            let ts = t0 + k as f64 * half;
            let before = driver.checkpoint();
            let mut done = false;
            for s in 0..=tries {
                driver.restore(&before);
                let solver: &mut dyn McpSolver = if s == 0 {
                    &mut *self.solver
                } else {
                    self.fallbacks.backends[s - 1].as_mut()
                };
                if let Some(sol) = driver.solve_span(solver, ts, half)? {
                    *last = Some(sol.summary);
                    pieces.push(1 << depth);
                    done = true;
                    break;
                }
            }
            if !done {
                driver.restore(&before);
                if depth >= self.fallbacks.max_halvings
                    || !self.halves(driver, ts, half, depth + 1, pieces, last)?
                {
                    return Ok(false);
                }
            }
        }
        Ok(true)
    }
}
