//! # ecp-model: the modelling layer of ecp
//!
//! The vocabulary every other crate of ecp speaks: a time step of a contact simulation is a
//! mixed complementarity problem (MCP) declared as **variable blocks** ([`VarBlock`] with
//! [`Bounds`]) paired with **residual blocks** ([`ResidualBlock`]) that carry analytic
//! Jacobians and read named **data blocks** ([`DataBlock`]: model parameters, changed between
//! solves with [`BlockMcp::set_data`] without rebuilding), assembled by a [`Problem`] into one
//! [`Mcp`] with a sparse Jacobian, and handed to any backend implementing [`McpSolver`]. Every
//! backend is judged by the same number, the natural-map residual ([`natural_residual`]). The
//! [`checker`] compares analytic Jacobians, with respect to variables and data, with central
//! differences, like Ceres' gradient checker.
//!
//! ```
//! use ecp_model::*;
//!
//! /// r(x, s) = x − s·1: x is free, s is a multiplier; with the block below this is the
//! /// one-dimensional MCP "find x with x = 2".
//! struct Equation;
//! impl ResidualBlock for Equation {
//!     fn name(&self) -> &str { "equation" }
//!     fn num_residuals(&self) -> usize { 1 }
//!     fn parameter_sizes(&self) -> &[usize] { &[1] }
//!     fn evaluate(&self, p: Params<'_>, out: &mut [f64]) { out[0] = p.block(0)[0] - 2.0; }
//!     fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) { jac.set(0, 0, 0, 1.0); }
//! }
//!
//! let mut problem = Problem::new();
//! let x = problem.add_variable_block(VarBlock::free("x", 1));
//! problem.add_residual_block(x, Equation, &[x]).unwrap();
//! let mcp = problem.build().unwrap();
//!
//! // Check the analytic Jacobian, then judge a candidate point.
//! for report in check_problem(&mcp, &[0.5], &CheckOptions::default()) {
//!     assert!(report.ok(), "{report}");
//! }
//! assert_eq!(residual_of(&mcp, &[2.0]), 0.0);
//! ```

#![warn(missing_docs)]

pub mod bounds;
pub mod checker;
pub mod counters;
pub mod data;
pub mod error;
pub mod family;
pub mod hypot;
pub mod linalg;
pub mod mcp;
/// Standard MCP test problems (MCPLIB, LCPs, friction NCPs) for judging backends: enabled by
/// the `test-problems` feature (off by default; the workspace's tests, examples and benches
/// turn it on).
#[cfg(any(test, feature = "test-problems"))]
pub mod mcp_library;
pub mod pattern;
pub mod problem;
pub mod residual;
pub mod scaling;
pub mod sensitivity;
pub mod solver;
pub mod structure;

pub use bounds::{BoundKind, Bounds, VarBlock};
pub use checker::{
    BlockPairCheck, CheckOptions, EntryCheck, JacobianReport, check_mcp, check_problem,
    check_residual_block,
};
pub use counters::{Counter, Counters};
pub use data::{DataBlock, DataId, Input, IntoInputs};
pub use error::ModelError;
pub use family::McpFamily;
pub use hypot::hypot;
pub use mcp::{
    FinalResiduals, FnMcp, Mcp, WorstComponent, diagnose, diagnose_values, diagnose_values_into,
    fb_component, fb_residual, fb_residual_into, fb_residual_of_rows, fb_vector, final_residuals,
    fischer_burmeister, mid, natural_residual, residual_of, worst_component,
    worst_component_of_residual, write_worst_component,
};
pub use pattern::CscPattern;
pub use problem::{BlockMcp, DataJacobianWork, Problem, ResId, VarId};
pub use residual::{Column, InputKind, InputRange, JacobianBlocks, Params, ResidualBlock};
pub use scaling::{McpScales, ScaledMcp, ScalesUsage, far_from_si, power_of_two, solve_in_scales};
pub use solver::{
    IterationRecord, McpSolver, Observer, Solution, SolveError, SolveReport, StepKind, Summary,
    Termination, finish_solve, finish_solve_at, finish_solve_into, finish_solve_with,
    validate_start,
};
pub use structure::{
    BodyDynamics, ConicPoint, ContactFriction, ContactGeometry, ContactImpulses, ContactPartner,
    PatchVertex, StepStructure,
};
