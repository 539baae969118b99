//! What a stepper does when its backend cannot solve a step: the same physics, tried harder.
//!
//! A step whose solve does not reach the tolerance is never taken from its best iterate. The
//! stepper first solves the same step problem with each fallback backend in turn, then splits the
//! step into substeps `h/2, h/4, …` (bisecting only the pieces that fail) that together reach
//! `t_{u+1}`; every piece is judged by the same natural residual as a plain step. When that is
//! exhausted too, the step is reported as failed and the bodies keep the last feasible state, the
//! state at the start of the step (`docs/fallbacks.md`).

use ecp_model::McpSolver;

/// The fallbacks a stepper may use for a step its backend could not solve.
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

/// How a step was solved.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum StepMethod {
    /// By the primary backend, in one piece (the normal case).
    #[default]
    Direct,
    /// By the named fallback backend, in one piece.
    Backend(String),
    /// In `pieces` substeps, the shortest `h / finest`.
    Substeps {
        /// Number of substeps that together cover the step.
        pieces: usize,
        /// Denominator of the shortest substep (2, 4, 8, …).
        finest: usize,
    },
    /// Not solved: the bodies keep the state at the start of the step.
    Failed,
    /// Taken from the backend's point without the natural-residual test, on request
    /// ([`crate::stepper::Simulation::step_unchecked`], for studying relaxed models such as
    /// Anitescu's); never used by the run driver.
    Unchecked,
}

impl StepMethod {
    /// The kind, as counted in `summary.json`: `direct`, `backend`, `substeps` or `failed`.
    pub fn kind(&self) -> &'static str {
        match self {
            StepMethod::Direct => "direct",
            StepMethod::Backend(_) => "backend",
            StepMethod::Substeps { .. } => "substeps",
            StepMethod::Failed => "failed",
            StepMethod::Unchecked => "unchecked",
        }
    }

    /// The `fallback` column of `trajectory.csv`: empty for a direct solve, else
    /// `backend:NAME`, `substeps:PIECES:h/FINEST` or `failed`.
    pub fn column(&self) -> String {
        match self {
            StepMethod::Direct => String::new(),
            StepMethod::Backend(name) => format!("backend:{name}"),
            StepMethod::Substeps { pieces, finest } => format!("substeps:{pieces}:h/{finest}"),
            StepMethod::Failed => "failed".to_string(),
            StepMethod::Unchecked => "unchecked".to_string(),
        }
    }

    /// True when the step passed the natural-residual test (every method but
    /// [`StepMethod::Failed`] and [`StepMethod::Unchecked`]).
    pub fn solved(&self) -> bool {
        !matches!(self, StepMethod::Failed | StepMethod::Unchecked)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_and_kinds() {
        assert_eq!(StepMethod::Direct.column(), "");
        assert_eq!(StepMethod::Backend("path".into()).column(), "backend:path");
        let s = StepMethod::Substeps {
            pieces: 3,
            finest: 4,
        };
        assert_eq!(s.column(), "substeps:3:h/4");
        assert_eq!(s.kind(), "substeps");
        assert!(!StepMethod::Failed.solved());
        assert!(Fallbacks::none().is_empty());
        assert!(!Fallbacks::new(Vec::new()).is_empty());
    }
}

#[cfg(test)]
mod stepper_tests {
    //! The fallbacks on a real step problem, with a backend that fails on purpose.

    use ecp_model::{Mcp, McpSolver, Solution, SolveError, Summary, Termination};
    use ecp_solvers::newton::{NewtonSettings, NewtonSolver};

    use super::{Fallbacks, StepMethod};
    use crate::scenarios;
    use crate::stepper::Simulation;

    /// Newton, except that its first `fail` solves are reported as not converged (with Newton's
    /// own point as the best iterate, so a stepper that took it would move).
    struct Flaky {
        inner: NewtonSolver,
        fail: usize,
        calls: usize,
    }

    impl Flaky {
        fn new(fail: usize) -> Self {
            Flaky {
                inner: NewtonSolver::new(NewtonSettings::default()),
                fail,
                calls: 0,
            }
        }
    }

    impl McpSolver for Flaky {
        fn name(&self) -> &str {
            "flaky"
        }
        fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
            self.calls += 1;
            let result = self.inner.solve(mcp, z0);
            if self.calls > self.fail {
                return result;
            }
            let sol = result?;
            Err(SolveError::NotConverged {
                best: Box::new(Solution {
                    z: sol.z,
                    summary: Summary {
                        termination: Termination::MaxIterations,
                        ..sol.summary
                    },
                }),
            })
        }
    }

    fn newton() -> Box<dyn McpSolver> {
        Box::new(NewtonSolver::new(NewtonSettings::default()))
    }

    #[test]
    fn a_fallback_backend_solves_the_same_step() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap();
        let mut reference = Simulation::new(scenarios::a1_sliding()).unwrap();
        let mut flaky = Flaky::new(usize::MAX);
        let mut fallbacks = Fallbacks::new(vec![newton()]);
        let rec = sim.step_with(&mut flaky, &mut fallbacks).unwrap();
        let plain = reference.step(newton().as_mut()).unwrap();
        assert!(rec.converged);
        assert_eq!(rec.method, StepMethod::Backend("newton".into()));
        assert!((rec.bodies[0].v - plain.bodies[0].v).amax() <= 1e-12);
        // The step problem in the simulation is the step's own: sensitivities can use it.
        assert!(sim.last_step().is_some());
    }

    #[test]
    fn substeps_reach_the_end_of_the_step_with_the_physics_of_a_shorter_step() {
        // The first two solves (the step and its retry from the active-contact guess: A1 rests on
        // the ground) fail; the halves then solve.
        let scene = scenarios::a1_sliding();
        let h = scene.h;
        let mut sim = Simulation::new(scene.clone()).unwrap();
        let mut flaky = Flaky::new(2);
        let mut fallbacks = Fallbacks {
            backends: Vec::new(),
            max_halvings: 3,
        };
        let rec = sim.step_with(&mut flaky, &mut fallbacks).unwrap();
        assert!(rec.converged);
        assert_eq!(
            rec.method,
            StepMethod::Substeps {
                pieces: 2,
                finest: 2
            }
        );
        assert!((rec.t - h).abs() < 1e-15);
        // Two plain steps of h/2 from the same state: the same end state.
        let mut half = Simulation::new(crate::stepper::Scene {
            h: 0.5 * h,
            ..scene
        })
        .unwrap();
        let mut solver = newton();
        half.step(solver.as_mut()).unwrap();
        let two = half.step(solver.as_mut()).unwrap();
        let (a, b) = (rec.bodies[0], two.bodies[0]);
        assert!((a.x - b.x).amax() <= 1e-12, "{:?} vs {:?}", a.x, b.x);
        assert!((a.v - b.v).amax() <= 1e-10, "{:?} vs {:?}", a.v, b.v);
        // A1 decelerates by μ g per unit time: v after h is 1 − μ g h.
        assert!((a.v.x - (1.0 - 0.3 * 9.8 * h)).abs() <= 1e-9);
        // No single step problem holds this step: no sensitivities from it.
        assert!(sim.last_step().is_none());
    }

    #[test]
    fn an_exhausted_step_fails_and_keeps_the_state_at_its_start() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap();
        let start = sim.state(0);
        let mut flaky = Flaky::new(usize::MAX);
        let mut fallbacks = Fallbacks {
            backends: Vec::new(),
            max_halvings: 2,
        };
        let rec = sim.step_with(&mut flaky, &mut fallbacks).unwrap();
        assert!(!rec.converged);
        assert_eq!(rec.method, StepMethod::Failed);
        assert_eq!(rec.bodies[0], start, "a failed iterate must never be taken");
        assert_eq!(sim.state(0), start);
        assert_eq!(sim.steps_taken(), 1);
        // The failed step's summary is the backend's best attempt, reported as not converged.
        assert!(!rec.summary.converged());
        // Solves tried: the step, then 2 halves, each halved again: 1 + 2 + 4 pieces at most,
        // each once or twice (retry); the run goes on from the held state.
        assert!(flaky.calls >= 3);
        let mut good = newton();
        let next = sim.step(good.as_mut()).unwrap();
        assert!(next.converged);
    }

    #[test]
    fn a_plain_step_that_fails_keeps_the_state_too() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap();
        let start = sim.state(0);
        let rec = sim.step(&mut Flaky::new(usize::MAX)).unwrap();
        assert_eq!(rec.method, StepMethod::Failed);
        assert_eq!(rec.bodies[0], start);
    }
}
