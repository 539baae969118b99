//! Test helpers shared by the backends' unit tests.

use std::cell::Cell;
use std::sync::Arc;

use ecp_model::{CscPattern, FnMcp, Mcp};

/// A problem with `F` at one point known (`Mcp::known_value`), counting its evaluations of
/// `F`: for the tests that a backend takes `F` at the start from the problem.
pub(crate) struct KnownAt<'a> {
    pub(crate) inner: &'a FnMcp,
    pub(crate) z: Vec<f64>,
    pub(crate) f: Vec<f64>,
    pub(crate) evaluations: Cell<usize>,
}

impl<'a> KnownAt<'a> {
    /// `inner` with `f` known at `z` (nowhere when `z` is empty), no evaluation counted yet.
    pub(crate) fn new(inner: &'a FnMcp, z: Vec<f64>, f: Vec<f64>) -> Self {
        KnownAt {
            inner,
            z,
            f,
            evaluations: Cell::new(0),
        }
    }
}

impl Mcp for KnownAt<'_> {
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn lower(&self) -> &[f64] {
        self.inner.lower()
    }
    fn upper(&self) -> &[f64] {
        self.inner.upper()
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        self.evaluations.set(self.evaluations.get() + 1);
        self.inner.evaluate(z, f)
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        self.inner.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        self.inner.jacobian(z, values)
    }
    fn known_value(&self, z: &[f64]) -> Option<&[f64]> {
        (z == self.z.as_slice()).then_some(self.f.as_slice())
    }
}
