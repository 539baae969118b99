//! # ecp: rigid-body motion with planar non-convex contact patches
//!
//! Geometrically implicit time stepping with an equivalent contact point (Xie & Chakraborty),
//! built on a small MCP modelling layer ([`model`]) with pluggable backends ([`solvers`]) and
//! the contact physics ([`formulations`]).
//!
//! This crate adds what a user touches first: [`scene`] files, the [`run`] driver that writes
//! `trajectory.csv` and `summary.json` as it goes ([`output`]), [`plots`], and the `ecp`
//! command line.
//!
//! ```
//! use ecp::run::{RunOptions, run_scene};
//!
//! let file = ecp::scene::load_scene("scenes/a1_sliding.toml".as_ref()).unwrap();
//! let out = std::env::temp_dir().join(format!("ecp-doc-{}", std::process::id()));
//! let options = RunOptions { out_dir: out.clone(), steps: Some(5), plots: false, ..RunOptions::default() };
//! let outcome = run_scene(&file, &options, |_| {}).unwrap();
//! assert_eq!(outcome.summary.steps, 5);
//! assert!(out.join("trajectory.csv").exists());
//! # std::fs::remove_dir_all(out).ok();
//! ```

#![warn(missing_docs)]

pub use ecp_formulations as formulations;
pub use ecp_model as model;
pub use ecp_solvers as solvers;

/// The optimisation library behind [`fit`] (its problems implement argmin's traits), re-exported
/// so that a user drives them with the same argmin version.
pub use argmin;

/// What a user of the library touches most: a solve's summary and counters, the solver trait,
/// the registry of backends with its options and errors, and the active-set classification of a
/// solution (`docs/backends.md`).
pub use ecp_model::bounds::{BoundKind, classify as classify_bounds};
pub use ecp_model::sensitivity::{ActiveSetOptions, ComponentStatus, classify};
pub use ecp_model::{Counter, Counters, McpSolver, Solution, SolveError, Summary, Termination};
pub use ecp_solvers::{Backend, BackendOptions, Registry, RegistryError, SettingsError};

pub mod animate;
pub mod backends;
pub mod batch;
pub mod error;
pub mod fit;
pub mod lcp;
pub mod output;
pub mod plots;
pub mod run;
pub mod scene;
pub mod stress;
pub mod sweep;
