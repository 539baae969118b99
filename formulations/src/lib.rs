//! Contact formulations of `ecp`: rigid-body geometry and kinematics, and the
//! step problems built on them (spec `formulation.md`).

#![warn(missing_docs)]

pub mod blocks;
pub mod geometry;
pub mod rotation;
pub mod scenarios;
pub mod stepper;
