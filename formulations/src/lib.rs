//! Contact formulations of `ecp`: rigid-body geometry and kinematics, and the
//! step problems built on them (`docs/model.md`).

//!
//! ```
//! use ecp_formulations::{scenarios, stepper::Simulation};
//! use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
//!
//! // Scenario A1: a box sliding on the ground at 1 m/s decelerates by μ g h per step.
//! let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap();
//! let mut solver = NewtonSolver::new(NewtonSettings::default());
//! let rec = sim.step(&mut solver).unwrap();
//! assert!(rec.converged && rec.summary.residual <= 1e-10);
//! assert!((rec.bodies[0].v.x - (1.0 - 0.3 * 9.8 * 0.01)).abs() < 1e-9);
//! ```

#![warn(missing_docs)]

pub mod blocks;
pub mod fallback;
pub mod formulation;
pub mod geometry;
pub mod point;
pub mod reduced;
pub mod rotation;
pub mod scenarios;
pub mod sensitivity;
pub mod stepper;
pub mod structure;

pub use fallback::{Fallbacks, StepMethod};
pub use formulation::{Formulation, Stepper, build_stepper};
