//! Data blocks: the model parameters a residual block reads besides the unknowns (Ceres' constant
//! parameter blocks; Clarabel's `update_*` data).
//!
//! A **data block** holds named values — a friction coefficient, a mass, the state at the start
//! of a time step, an applied load — that stay fixed while a backend solves the MCP and may change
//! between solves with [`BlockMcp::set_data`](crate::BlockMcp::set_data), without rebuilding the
//! problem: the layout and the sparsity pattern do not depend on data, so every backend's
//! symbolic analysis stays valid. A residual block reads data blocks exactly as it reads variable
//! blocks ([`Input`]), and writes its derivatives with respect to them in the same
//! [`ResidualBlock::jacobian`](crate::ResidualBlock::jacobian): the assembled MCP Jacobian
//! discards them (a block may skip them, [`JacobianBlocks::wants`](crate::JacobianBlocks::wants)),
//! and [`BlockMcp::data_jacobian`](crate::BlockMcp::data_jacobian) assembles `∂F/∂θ` from them,
//! for the implicit differentiation of a solution ([`crate::sensitivity`]). So a block cannot
//! read data without stating their derivatives, and the checker ([`crate::check_problem`])
//! compares those with central differences like any other.
//!
//! ```
//! use ecp_model::*;
//!
//! /// r(x; c) = x − c: with x free, the one-dimensional MCP "x = c".
//! struct Target;
//! impl ResidualBlock for Target {
//!     fn name(&self) -> &str { "target" }
//!     fn num_residuals(&self) -> usize { 1 }
//!     fn parameter_sizes(&self) -> &[usize] { &[1, 1] }
//!     fn evaluate(&self, p: Params<'_>, out: &mut [f64]) { out[0] = p.block(0)[0] - p.block(1)[0]; }
//!     fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
//!         jac.set(0, 0, 0, 1.0);
//!         jac.set(1, 0, 0, -1.0); // ∂r/∂c: discarded in the MCP Jacobian, kept for ∂F/∂θ.
//!     }
//! }
//!
//! let mut problem = Problem::new();
//! let x = problem.add_variable_block(VarBlock::free("x", 1));
//! let c = problem.add_data_block(DataBlock::new("c", [2.0]));
//! problem.add_residual_block(x, Target, &[Input::from(x), Input::from(c)]).unwrap();
//! let mut mcp = problem.build().unwrap();
//!
//! let mut f = [0.0];
//! mcp.evaluate(&[2.0], &mut f);
//! assert_eq!(f[0], 0.0);
//! // New data, same problem: no rebuild, the pattern is unchanged.
//! mcp.set_data(c, &[5.0]).unwrap();
//! mcp.evaluate(&[2.0], &mut f);
//! assert_eq!(f[0], -3.0);
//! // ∂F/∂c, and the checker covers the data input too.
//! let mut dfdc = [0.0];
//! mcp.data_jacobian(&[2.0], &[c], &mut dfdc).unwrap();
//! assert_eq!(dfdc[0], -1.0);
//! assert!(check_problem(&mcp, &[2.0], &CheckOptions::default()).iter().all(|r| r.ok()));
//! ```

use crate::bounds::VarId;
use crate::error::ModelError;

/// Handle of a data block inside a [`Problem`](crate::Problem) and the
/// [`BlockMcp`](crate::BlockMcp) built from it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DataId(pub usize);

/// What input `k` of a residual block is bound to: a variable block (an unknown of the MCP) or a
/// data block (fixed during a solve).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Input {
    /// A variable block.
    Var(VarId),
    /// A data block.
    Data(DataId),
}

impl From<VarId> for Input {
    fn from(v: VarId) -> Self {
        Input::Var(v)
    }
}

impl From<DataId> for Input {
    fn from(d: DataId) -> Self {
        Input::Data(d)
    }
}

/// The inputs a residual block is bound to, in the order of its
/// [`parameter_sizes`](crate::ResidualBlock::parameter_sizes): a slice, array or vector of
/// [`VarId`]s (the common case) or of [`Input`]s (variables and data mixed).
pub trait IntoInputs {
    /// The inputs, in order.
    fn into_inputs(self) -> Vec<Input>;
}

impl<T: Copy + Into<Input>> IntoInputs for &[T] {
    fn into_inputs(self) -> Vec<Input> {
        self.iter().map(|&i| i.into()).collect()
    }
}

impl<T: Copy + Into<Input>, const N: usize> IntoInputs for &[T; N] {
    fn into_inputs(self) -> Vec<Input> {
        self.iter().map(|&i| i.into()).collect()
    }
}

impl<T: Copy + Into<Input>> IntoInputs for &Vec<T> {
    fn into_inputs(self) -> Vec<Input> {
        self.iter().map(|&i| i.into()).collect()
    }
}

impl<T: Into<Input>> IntoInputs for Vec<T> {
    fn into_inputs(self) -> Vec<Input> {
        self.into_iter().map(Into::into).collect()
    }
}

/// A named block of model data (module documentation), like [`VarBlock`](crate::VarBlock) for
/// unknowns: its size is fixed when it is declared, its values may change between solves.
#[derive(Clone, Debug, PartialEq)]
pub struct DataBlock {
    name: String,
    values: Vec<f64>,
    component_names: Option<Vec<String>>,
}

impl DataBlock {
    /// A data block with initial values (its size is their number).
    pub fn new(name: impl Into<String>, values: impl Into<Vec<f64>>) -> Self {
        DataBlock {
            name: name.into(),
            values: values.into(),
            component_names: None,
        }
    }
    /// Names the components (for reports such as "∂F/∂box.start.v.x").
    pub fn with_component_names<S: Into<String>>(
        mut self,
        names: impl IntoIterator<Item = S>,
    ) -> Self {
        self.component_names = Some(names.into_iter().map(Into::into).collect());
        self
    }
    /// The block's name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Number of components.
    pub fn size(&self) -> usize {
        self.values.len()
    }
    /// Current values.
    pub fn values(&self) -> &[f64] {
        &self.values
    }
    /// Name of component `i`: `block.component` or `block[i]`.
    pub fn component_name(&self, i: usize) -> String {
        match &self.component_names {
            Some(names) if i < names.len() => format!("{}.{}", self.name, names[i]),
            _ => format!("{}[{}]", self.name, i),
        }
    }

    /// Checks new `values` for this block: the length and finiteness.
    pub(crate) fn check_values(&self, values: &[f64]) -> Result<(), ModelError> {
        if values.len() != self.size() {
            return Err(ModelError::InvalidBlock {
                block: self.name.clone(),
                reason: format!(
                    "data block of size {} given {} values; a data block keeps the size it was \
                     declared with",
                    self.size(),
                    values.len()
                ),
            });
        }
        if let Some(i) = crate::mcp::first_non_finite(values) {
            return Err(ModelError::InvalidBlock {
                block: self.name.clone(),
                reason: format!(
                    "component {} = {}: data must be finite",
                    self.component_name(i),
                    values[i]
                ),
            });
        }
        Ok(())
    }

    pub(crate) fn set_values(&mut self, values: &[f64]) {
        self.values.copy_from_slice(values);
    }

    pub(crate) fn validate(&self) -> Result<(), ModelError> {
        if let Some(names) = &self.component_names
            && names.len() != self.size()
        {
            return Err(ModelError::InvalidBlock {
                block: self.name.clone(),
                reason: format!(
                    "{} component names given for {} components",
                    names.len(),
                    self.size()
                ),
            });
        }
        self.check_values(&self.values)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::{
        CheckOptions, InputKind, JacobianBlocks, Mcp, ModelError, Params, Problem, ResidualBlock,
        VarBlock, check_problem,
    };

    /// r(x; a, b) = a·x² + b (x of size 1, a and b data); `wrong_b` scales its ∂r/∂b.
    struct Quadratic {
        wrong_b: f64,
    }
    impl ResidualBlock for Quadratic {
        fn name(&self) -> &str {
            "quadratic"
        }
        fn num_residuals(&self) -> usize {
            1
        }
        fn parameter_sizes(&self) -> &[usize] {
            &[1, 2]
        }
        fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
            let (x, d) = (p.block(0)[0], p.block(1));
            out[0] = d[0] * x * x + d[1];
        }
        fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
            let (x, d) = (p.block(0)[0], p.block(1));
            jac.set(0, 0, 0, 2.0 * d[0] * x);
            if jac.wants(1) {
                jac.set(1, 0, 0, x * x);
                jac.set(1, 0, 1, self.wrong_b);
            }
        }
    }

    /// A two-row spring term `−k (x − x_rest)` on a block of size 2, reading y too (a coupling
    /// the paired block does not have, so the term adds pattern entries).
    struct Spring;
    impl ResidualBlock for Spring {
        fn name(&self) -> &str {
            "spring"
        }
        fn num_residuals(&self) -> usize {
            2
        }
        fn parameter_sizes(&self) -> &[usize] {
            &[2, 1, 1]
        }
        fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
            let (x, y, k) = (p.block(0), p.block(1)[0], p.block(2)[0]);
            out[0] = -k * (x[0] - y);
            out[1] = -k * x[1];
        }
        fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
            let (x, y, k) = (p.block(0), p.block(1)[0], p.block(2)[0]);
            jac.set(0, 0, 0, -k);
            jac.set(0, 1, 1, -k);
            jac.set(1, 0, 0, k);
            jac.set(2, 0, 0, -(x[0] - y));
            jac.set(2, 1, 0, -x[1]);
        }
    }

    /// r(x) = x (identity rows, any size).
    struct Identity(Vec<usize>, usize);
    impl ResidualBlock for Identity {
        fn name(&self) -> &str {
            "identity"
        }
        fn num_residuals(&self) -> usize {
            self.1
        }
        fn parameter_sizes(&self) -> &[usize] {
            &self.0
        }
        fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
            out.copy_from_slice(p.block(0));
        }
        fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
            jac.add_diagonal(0, 0, 0, self.1, 1.0);
        }
    }

    fn quadratic_problem(wrong_b: f64) -> (crate::BlockMcp, DataId) {
        let mut p = Problem::new();
        let x = p.add_variable_block(VarBlock::free("x", 1));
        let d = p.add_data_block(DataBlock::new("ab", [3.0, 0.5]).with_component_names(["a", "b"]));
        p.add_residual_block(x, Quadratic { wrong_b }, &[Input::Var(x), Input::Data(d)])
            .expect("bind");
        (p.build().expect("build"), d)
    }

    #[test]
    fn set_data_changes_f_without_rebuild() {
        let (mut mcp, d) = quadratic_problem(1.0);
        let pattern = Arc::clone(mcp.jacobian_pattern());
        let mut f = [0.0];
        mcp.evaluate(&[2.0], &mut f);
        assert_eq!(f[0], 3.0 * 4.0 + 0.5);
        mcp.set_data(d, &[-1.0, 2.0]).expect("set");
        assert_eq!(mcp.data(d), &[-1.0, 2.0]);
        assert_eq!(mcp.data_values(), &[-1.0, 2.0]);
        assert_eq!(mcp.data_blocks()[0].values(), &[-1.0, 2.0]);
        mcp.evaluate(&[2.0], &mut f);
        assert_eq!(f[0], -4.0 + 2.0);
        let mut j = vec![0.0; mcp.jacobian_pattern().nnz()];
        mcp.jacobian(&[2.0], &mut j);
        assert_eq!(j, vec![-4.0]);
        // The very same pattern object: every backend's symbolic analysis stays valid.
        assert!(Arc::ptr_eq(&pattern, mcp.jacobian_pattern()));
        assert_eq!((mcp.num_data(), mcp.data_offset(d)), (2, 0));
    }

    #[test]
    fn set_data_rejects_bad_values_and_ids() {
        let (mut mcp, d) = quadratic_problem(1.0);
        let short = mcp.set_data(d, &[1.0]).expect_err("short");
        assert!(short.to_string().contains("'ab'") && short.to_string().contains("size 2"));
        let nan = mcp.set_data(d, &[1.0, f64::NAN]).expect_err("nan");
        assert!(nan.to_string().contains("ab.b") && nan.to_string().contains("finite"));
        let inf = mcp.set_data(d, &[f64::INFINITY, 0.0]).expect_err("inf");
        assert!(inf.to_string().contains("ab.a"), "{inf}");
        let unknown = mcp.set_data(DataId(7), &[1.0]).expect_err("unknown");
        assert!(unknown.to_string().contains("data #7"), "{unknown}");
        // Nothing changed.
        assert_eq!(mcp.data(d), &[3.0, 0.5]);
    }

    #[test]
    fn build_rejects_bad_data_and_bindings() {
        let mut p = Problem::new();
        let x = p.add_variable_block(VarBlock::free("x", 1));
        let d = p.add_data_block(DataBlock::new("ab", [3.0, f64::NAN]));
        p.add_residual_block(
            x,
            Quadratic { wrong_b: 1.0 },
            &[Input::Var(x), Input::Data(d)],
        )
        .expect("bind");
        let err = p.build().err().expect("NaN data");
        assert!(err.to_string().contains("finite"), "{err}");

        let mut p = Problem::new();
        let x = p.add_variable_block(VarBlock::free("x", 1));
        let small = p.add_data_block(DataBlock::new("a", [3.0]));
        let e = p
            .add_residual_block(
                x,
                Quadratic { wrong_b: 1.0 },
                &[Input::Var(x), Input::Data(small)],
            )
            .expect_err("size");
        assert!(e.to_string().contains("data block 'a' has size 1"), "{e}");
        let e = p
            .add_residual_block(
                x,
                Quadratic { wrong_b: 1.0 },
                &[Input::Var(x), Input::Data(DataId(4))],
            )
            .expect_err("unknown");
        assert!(e.to_string().contains("unknown data block #4"), "{e}");
        let names = p.add_data_block(DataBlock::new("n", [1.0, 2.0]).with_component_names(["a"]));
        p.add_residual_block(
            x,
            Quadratic { wrong_b: 1.0 },
            &[Input::Var(x), Input::Data(names)],
        )
        .expect("bind");
        let e = p.build().err().expect("names");
        assert!(
            e.to_string().contains("1 component names given for 2"),
            "{e}"
        );
    }

    #[test]
    fn data_jacobian_matches_central_differences() {
        let (mut mcp, d) = quadratic_problem(1.0);
        let z = [1.5];
        let mut out = [0.0; 2];
        mcp.data_jacobian(&z, &[d], &mut out).expect("dF/dθ");
        let base = mcp.data(d).to_vec();
        for k in 0..2 {
            let h = 1e-6;
            let mut f = [[0.0]; 2];
            for (s, sign) in [1.0, -1.0].into_iter().enumerate() {
                let mut v = base.clone();
                v[k] += sign * h;
                mcp.set_data(d, &v).expect("set");
                mcp.evaluate(&z, &mut f[s]);
            }
            let fd = (f[0][0] - f[1][0]) / (2.0 * h);
            assert!((out[k] - fd).abs() < 1e-8, "θ{k}: {} vs {fd}", out[k]);
        }
        assert_eq!(out, [2.25, 1.0]);
        // Wrong lengths and unknown or repeated blocks are errors.
        assert!(mcp.data_jacobian(&z, &[d], &mut [0.0; 3]).is_err());
        assert!(mcp.data_jacobian(&[1.0, 2.0], &[d], &mut out).is_err());
        assert!(mcp.data_jacobian(&z, &[DataId(3)], &mut out).is_err());
        assert!(mcp.data_jacobian(&z, &[d, d], &mut [0.0; 4]).is_err());
        // No data asked for: an empty matrix.
        mcp.data_jacobian(&z, &[], &mut []).expect("empty");
    }

    #[test]
    fn checker_flags_a_wrong_data_derivative() {
        let (good, _) = quadratic_problem(1.0);
        let reports = check_problem(&good, &[1.5], &CheckOptions::default());
        assert_eq!(reports.len(), 1);
        assert!(reports[0].ok(), "{}", reports[0]);
        assert_eq!(reports[0].entries, 3);
        let (bad, _) = quadratic_problem(1.25);
        let rep = &check_problem(&bad, &[1.5], &CheckOptions::default())[0];
        assert_eq!(rep.failures, 1, "{rep}");
        let pair = &rep.pairs[1];
        assert_eq!(
            (pair.input.as_str(), pair.kind),
            ("ab", Some(InputKind::Data))
        );
        assert_eq!(pair.failures, 1);
        assert!((pair.max_abs_error - 0.25).abs() < 1e-6, "{rep}");
        assert_eq!(rep.worst[0].location, "quadratic[0] / ab.b (data)");
        assert_eq!(rep.pairs[0].failures, 0);
    }

    /// x (2) paired with identity rows, y (1) paired with identity; a spring term adds to x's
    /// rows and reads y and the stiffness k.
    fn spring_problem() -> (crate::BlockMcp, DataId) {
        let mut p = Problem::new();
        let x = p.add_variable_block(VarBlock::free("x", 2));
        let y = p.add_variable_block(VarBlock::free("y", 1));
        let k = p.add_data_block(DataBlock::new("k", [4.0]));
        p.add_residual_block(x, Identity(vec![2], 2), &[x])
            .expect("x");
        p.add_residual_block(y, Identity(vec![1], 1), &[y])
            .expect("y");
        p.add_term(x, Spring, &[Input::Var(x), Input::Var(y), Input::Data(k)])
            .expect("term");
        (p.build().expect("build"), k)
    }

    #[test]
    fn a_term_adds_to_the_paired_rows() {
        let (mut mcp, k) = spring_problem();
        let z = [1.0, 2.0, 0.5];
        let mut f = [0.0; 3];
        mcp.evaluate(&z, &mut f);
        assert_eq!(f, [1.0 - 4.0 * 0.5, 2.0 - 4.0 * 2.0, 0.5]);
        // The pattern has the term's coupling (rows of x, column y) besides the paired blocks'
        // dense 2×2 and 1×1 blocks.
        let pattern = mcp.jacobian_pattern().clone();
        assert!(pattern.position(0, 2).is_some() && pattern.position(1, 2).is_some());
        assert!(pattern.position(2, 0).is_none());
        assert_eq!(pattern.nnz(), 7);
        let mut j = vec![0.0; pattern.nnz()];
        mcp.jacobian(&z, &mut j);
        let mut dense = vec![0.0; 9];
        pattern.to_dense(&j, &mut dense);
        // Column-major: J = [[1 − k, 0, k], [0, 1 − k, 0], [0, 0, 1]].
        assert_eq!(dense, vec![-3.0, 0.0, 0.0, 0.0, -3.0, 0.0, 4.0, 0.0, 1.0]);
        let (mut f2, mut j2) = ([0.0; 3], vec![0.0; pattern.nnz()]);
        mcp.evaluate_with_jacobian(&z, &mut f2, &mut j2);
        assert_eq!((f2, j2), (f, j));
        // The term's data derivative, and the checker covers the term.
        let mut dk = [0.0; 3];
        mcp.data_jacobian(&z, &[k], &mut dk).expect("dF/dk");
        assert_eq!(dk, [-0.5, -2.0, 0.0]);
        let reports = check_problem(&mcp, &z, &CheckOptions::default());
        assert_eq!(reports.len(), 3);
        assert!(reports.iter().all(|r| r.ok()));
        assert!(
            reports[2].name.contains("a term adding to the rows of x"),
            "{}",
            reports[2]
        );
        mcp.set_data(k, &[0.0]).expect("set");
        mcp.evaluate(&z, &mut f);
        assert_eq!(f, z);
    }

    /// `evaluate_rows_of` fills one variable block's rows, the term's addition included, with
    /// the bits of the whole evaluation, and leaves the other rows as they were.
    #[test]
    fn the_rows_of_one_block_are_those_of_the_whole_evaluation() {
        let (mcp, _) = spring_problem();
        let z = [1.0, 2.0, 0.3];
        let mut all = [0.0; 3];
        mcp.evaluate(&z, &mut all);
        let (x, y) = (crate::VarId(0), crate::VarId(1));
        let mut f = [f64::NAN; 3];
        mcp.evaluate_rows_of(x, &z, &mut f);
        assert_eq!(
            [f[0].to_bits(), f[1].to_bits()],
            [all[0].to_bits(), all[1].to_bits()]
        );
        assert_eq!((f[0], f[1]), (1.0 - 4.0 * (1.0 - 0.3), 2.0 - 4.0 * 2.0));
        assert!(f[2].is_nan());
        let mut f = [f64::NAN; 3];
        mcp.evaluate_rows_of(y, &z, &mut f);
        assert!(f[0].is_nan() && f[1].is_nan());
        assert_eq!(f[2].to_bits(), all[2].to_bits());
    }

    #[test]
    fn terms_keep_the_pairing_rule() {
        // A term alone does not pair a variable block.
        let mut p = Problem::new();
        let x = p.add_variable_block(VarBlock::free("x", 2));
        let y = p.add_variable_block(VarBlock::free("y", 1));
        let k = p.add_data_block(DataBlock::new("k", [4.0]));
        p.add_residual_block(y, Identity(vec![1], 1), &[y])
            .expect("y");
        p.add_term(x, Spring, &[Input::Var(x), Input::Var(y), Input::Data(k)])
            .expect("term");
        match p.build() {
            Err(ModelError::Pairing(msg)) => assert!(msg.contains("'x'"), "{msg}"),
            other => panic!("expected a pairing error, got {:?}", other.err()),
        }
        // A term of the wrong length is refused.
        let mut p = Problem::new();
        let y = p.add_variable_block(VarBlock::free("y", 1));
        let e = p
            .add_term(y, Spring, &[Input::Var(y), Input::Var(y), Input::Data(k)])
            .expect_err("size");
        assert!(matches!(e, ModelError::SizeMismatch { .. }), "{e}");
    }
}
