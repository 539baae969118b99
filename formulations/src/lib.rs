//! Contact formulations of `ecp`: rigid-body geometry and kinematics, the residual blocks of the
//! physics, the step problems built on them (`docs/model.md`) and the one driver that runs them.
//!
//! The modules form a one-way tree (`docs/architecture.md`): each imports only those above it.
//!
//! | layer | modules |
//! |---|---|
//! | geometry | [`rotation`], [`geometry`] |
//! | residual blocks | [`blocks`] |
//! | what is simulated and recorded | [`scene`], [`record`] |
//! | the driver | [`step`]: [`StepFormulation`], [`Simulation`], fallbacks, params, user terms |
//! | formulations | [`ecp`] (hull, union), [`reduced`], [`point`] |
//! | by name | [`registry`] |
//! | derivatives | [`sensitivity`] |
//! | reference scenes | [`scenarios`] |
//!
//! ```
//! use ecp_formulations::{Simulation, scenarios};
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
pub mod bodies;
pub mod ecp;
pub mod geometry;
pub mod point;
pub mod record;
pub mod reduced;
pub mod registry;
pub mod rotation;
pub mod scenarios;
pub mod scene;
pub mod sensitivity;
pub mod step;
pub mod world;

pub use record::{ContactRecord, MODE_TOLERANCE, PairRecord, StepMethod, StepRecord};
pub use registry::{FormulationRegistry, RegistryError};
pub use scene::{BodySpec, BodyState, Load, Scene, SceneError};
pub use step::{
    Capabilities, Fallbacks, Force, Param, Simulation, SimulationBuilder, StateComponent,
    StepFormulation, Term, WarmStart,
};
