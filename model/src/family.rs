//! One-parameter families of an MCP: `F(z; s)` on the same bounds and Jacobian pattern, with
//! `F(·; 1)` the problem's own `F` (`docs/newton.md#a-continuation-in-the-friction-coefficient`).
//!
//! A backend that follows the solutions of `F(z; s) = 0` (in the complementarity sense) from an
//! easy `s` to `s = 1` asks the problem for its family through
//! [`Mcp::friction_family`](crate::Mcp::friction_family): in a contact step, every friction
//! coefficient `μ` scaled by `s`, so that `s = 0` is the frictionless step.

/// A one-parameter family `F(z; s)` of an MCP: the problem's bounds and Jacobian pattern for every
/// `s`, and `F(z; 1) = F(z)` bit for bit.
pub trait McpFamily {
    /// Evaluates `F(z; s)` into `f`.
    fn evaluate_at(&self, s: f64, z: &[f64], f: &mut [f64]);
    /// Evaluates `F(z; s)` and its Jacobian in `z` (stored in the problem's pattern order).
    fn evaluate_with_jacobian_at(&self, s: f64, z: &[f64], f: &mut [f64], values: &mut [f64]);
}
