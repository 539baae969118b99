//! # ecp-solvers: interchangeable MCP backends
//!
//! Every backend implements [`ecp_model::McpSolver`], returns the solution in the MCP's own
//! layout with a [`ecp_model::Summary`], and is judged by the model's natural-map residual.
//!
//! - [`newton`]: semismooth Newton on the Fischer–Burmeister reformulation
//!   (`docs/backends.md#semismooth-newton`).
//! - [`conic`]: convex subproblems with clarabel, using the contact step's structure
//!   (`docs/backends.md#conic`).
//! - [`pivot`]: Lemke's method generalised to bounded variables, for affine MCPs (LCP, mixed
//!   and box-constrained LCP) (`docs/backends.md#path-like`).
//! - [`path`]: the PATH-like solver: Josephy–Newton steps computed by pivoting, a path search
//!   along the piecewise-linear Newton path, a non-monotone watchdog, a crash phase and a
//!   proximal perturbation (`docs/backends.md#path-like`).
//! - [`smoothing`]: the smoothed natural map and the smoothing continuation, the last restart of
//!   the Newton and PATH-like backends (`docs/newton.md#smoothing-continuation`).
//!
//! ```
//! use ecp_model::{FnMcp, McpSolver, residual_of};
//! use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
//!
//! // LCP: 0 ≤ z ⊥ M z + q ≥ 0 with M = [[2, 1], [1, 2]], q = (−1, 1): solution z = (½, 0).
//! let mcp = FnMcp::dense(
//!     vec![0.0; 2],
//!     vec![f64::INFINITY; 2],
//!     |z, f| { f[0] = 2.0 * z[0] + z[1] - 1.0; f[1] = z[0] + 2.0 * z[1] + 1.0; },
//!     |_z, j| { j[0] = 2.0; j[1] = 1.0; j[2] = 1.0; j[3] = 2.0; },
//! ).unwrap();
//! let mut solver = NewtonSolver::new(NewtonSettings::default());
//! let sol = solver.solve(&mcp, &[0.0, 0.0]).unwrap();
//! assert!(residual_of(&mcp, &sol.z) <= 1e-10);
//! assert!((sol.z[0] - 0.5).abs() < 1e-10 && sol.z[1].abs() < 1e-10);
//! ```

#![warn(missing_docs)]

mod cholesky;
pub mod conic;
pub mod newton;
mod normal_equations;
pub mod path;
pub mod pivot;
pub mod registry;
pub mod settings;
pub mod smoothing;
#[cfg(test)]
mod test_support;
mod union_find;

pub use newton::{NewtonSettings, NewtonSolver};
pub use path::{PathSettings, PathSolver};
pub use pivot::{
    AffineMatrix, AffineMcp, AffineStart, AntiCycling, Lemke, LemkeSettings, PivotError, PivotPath,
    PivotSolution,
};
pub use registry::{Backend, BackendOptions, Registry, RegistryError};
pub use settings::SettingsError;
