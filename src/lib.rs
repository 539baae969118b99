//! # ecp: rigid-body motion with planar non-convex contact patches
//!
//! Geometrically implicit time stepping with an equivalent contact point (Xie & Chakraborty),
//! built on a small MCP modelling layer ([`model`]) with pluggable backends ([`solvers`]) and
//! the contact physics ([`formulations`]).

#![warn(missing_docs)]

pub use ecp_formulations as formulations;
pub use ecp_model as model;
pub use ecp_solvers as solvers;
