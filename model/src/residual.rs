//! Residual blocks: the pieces of `F` a model is built from (Ceres' cost functions, for MCPs).
//!
//! Two kinds of inputs enter a residual block, and the names keep them apart:
//!
//! - **variable blocks** (the unknowns `z` of the MCP), whose sizes a block declares in
//!   [`ResidualBlock::parameter_sizes`] — "parameter blocks" in Ceres' words, kept for
//!   familiarity — and whose Jacobian it writes in [`ResidualBlock::jacobian`];
//! - **data θ** (model parameters: coefficients such as μ, the mass and inertia, the
//!   start-of-step state, the applied loads), fixed during a solve, which a block declares with
//!   [`ResidualBlock::num_data`] and differentiates in [`ResidualBlock::data_jacobian`]. Their
//!   derivatives are what implicit differentiation of a solution needs (`dz/dθ = −J⁻¹ ∂F/∂θ` on
//!   the free components, [`crate::sensitivity`]).

/// Read-only view of the variable blocks a residual block reads, in the order it declared them.
///
/// Zero-copy: it indexes into the flat unknown vector `z` by precomputed ranges.
#[derive(Clone, Copy, Debug)]
pub struct Params<'a> {
    z: &'a [f64],
    ranges: &'a [(usize, usize)],
}

impl<'a> Params<'a> {
    /// A view of `z` through `(offset, length)` ranges, one per block.
    pub fn new(z: &'a [f64], ranges: &'a [(usize, usize)]) -> Self {
        Params { z, ranges }
    }
    /// Values of the `k`-th block read.
    #[inline]
    pub fn block(&self, k: usize) -> &'a [f64] {
        let (o, l) = self.ranges[k];
        &self.z[o..o + l]
    }
    /// Number of blocks read.
    pub fn len(&self) -> usize {
        self.ranges.len()
    }
    /// True when the residual block reads no variable block.
    pub fn is_empty(&self) -> bool {
        self.ranges.is_empty()
    }
}

/// Write access to the small dense Jacobian blocks `∂r/∂x_k` of one residual block.
///
/// Entry `(i, j)` of block `k` is `∂r_i / ∂(x_k)_j`. The storage behind it is either the
/// assembled sparse Jacobian or a local dense buffer (Jacobian checker); all entries start
/// at zero, so a residual block writes only its structural non-zeros.
#[derive(Debug)]
pub struct JacobianBlocks<'a> {
    values: &'a mut [f64],
    /// For block `k`, column `j`: position of row 0 in `values` is `col_pos[block_start[k] + j]`.
    col_pos: &'a [usize],
    block_start: &'a [usize],
    rows: usize,
}

impl<'a> JacobianBlocks<'a> {
    /// Wraps a value array and its layout. `block_start` has one entry per block plus a final
    /// sentinel; `col_pos[block_start[k] + j] + i` is where entry `(i, j)` of block `k` lives.
    pub fn new(
        values: &'a mut [f64],
        col_pos: &'a [usize],
        block_start: &'a [usize],
        rows: usize,
    ) -> Self {
        JacobianBlocks {
            values,
            col_pos,
            block_start,
            rows,
        }
    }
    /// Number of residual rows.
    pub fn rows(&self) -> usize {
        self.rows
    }
    /// Number of columns of block `k`.
    pub fn cols(&self, k: usize) -> usize {
        self.block_start[k + 1] - self.block_start[k]
    }
    #[inline]
    fn pos(&self, k: usize, i: usize, j: usize) -> usize {
        debug_assert!(i < self.rows && j < self.cols(k));
        self.col_pos[self.block_start[k] + j] + i
    }
    /// Sets entry `(i, j)` of block `k`.
    #[inline]
    pub fn set(&mut self, k: usize, i: usize, j: usize, v: f64) {
        let p = self.pos(k, i, j);
        self.values[p] = v;
    }
    /// Adds to entry `(i, j)` of block `k`.
    #[inline]
    pub fn add(&mut self, k: usize, i: usize, j: usize, v: f64) {
        let p = self.pos(k, i, j);
        self.values[p] += v;
    }
    /// Adds a small row-major matrix `rows × cols` at offset `(i0, j0)` of block `k`.
    pub fn add_row_major(&mut self, k: usize, i0: usize, j0: usize, cols: usize, data: &[f64]) {
        for (r, row) in data.chunks_exact(cols).enumerate() {
            for (c, &v) in row.iter().enumerate() {
                self.add(k, i0 + r, j0 + c, v);
            }
        }
    }
    /// Adds `s` on the diagonal of the square sub-block starting at `(i0, j0)` of size `m`.
    pub fn add_diagonal(&mut self, k: usize, i0: usize, j0: usize, m: usize, s: f64) {
        for d in 0..m {
            self.add(k, i0 + d, j0 + d, s);
        }
    }
}

/// Write access to the dense Jacobian `∂r/∂θ` of one residual block with respect to its data θ
/// (see the module documentation), `rows × num_data`, column-major. It starts zeroed, so a
/// block writes only its non-zeros.
#[derive(Debug)]
pub struct DataJacobian<'a> {
    values: &'a mut [f64],
    rows: usize,
    cols: usize,
}

impl<'a> DataJacobian<'a> {
    /// Wraps a column-major `rows × cols` buffer (`values.len() == rows * cols`).
    pub fn new(values: &'a mut [f64], rows: usize, cols: usize) -> Self {
        debug_assert_eq!(values.len(), rows * cols);
        DataJacobian { values, rows, cols }
    }
    /// Number of residual rows.
    pub fn rows(&self) -> usize {
        self.rows
    }
    /// Number of data θ (columns).
    pub fn cols(&self) -> usize {
        self.cols
    }
    /// Sets entry `(i, k)`: `∂r_i/∂θ_k`.
    #[inline]
    pub fn set(&mut self, i: usize, k: usize, v: f64) {
        debug_assert!(i < self.rows && k < self.cols);
        self.values[k * self.rows + i] = v;
    }
    /// Adds to entry `(i, k)`.
    #[inline]
    pub fn add(&mut self, i: usize, k: usize, v: f64) {
        debug_assert!(i < self.rows && k < self.cols);
        self.values[k * self.rows + i] += v;
    }
    /// Entry `(i, k)`.
    #[inline]
    pub fn get(&self, i: usize, k: usize) -> f64 {
        self.values[k * self.rows + i]
    }
}

/// A block of residual equations `r(x_1, …, x_K)` with an analytic Jacobian.
///
/// The block declares the sizes of the variable blocks it reads; the problem builder binds
/// them (`Problem::add_residual_block`) and pairs the block with a variable block of the same
/// length (`docs/model.md#mcp`). Implementations must be deterministic and free of side effects.
pub trait ResidualBlock: Send + Sync {
    /// Short descriptive name, used in reports.
    fn name(&self) -> &str;
    /// Number of residual rows.
    fn num_residuals(&self) -> usize;
    /// Sizes of the variable blocks read, in order.
    fn parameter_sizes(&self) -> &[usize];
    /// Evaluates the residual into `out` (length `num_residuals`).
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]);
    /// Writes the analytic Jacobian, block by block. `jac` starts zeroed.
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>);
    /// Evaluates residual and Jacobian together; override when they share work.
    fn evaluate_with_jacobian(&self, x: Params<'_>, out: &mut [f64], jac: &mut JacobianBlocks<'_>) {
        self.evaluate(x, out);
        self.jacobian(x, jac);
    }

    /// Number of scalar **data** θ the residual depends on (model parameters, not unknowns:
    /// see the module documentation; not to be confused with the variable blocks of
    /// [`ResidualBlock::parameter_sizes`]). Default 0: a block without declared data is treated
    /// as independent of every model parameter.
    fn num_data(&self) -> usize {
        0
    }
    /// Writes the block's current data θ into `theta` (length [`ResidualBlock::num_data`]).
    fn data(&self, _theta: &mut [f64]) {}
    /// Name of datum `k`, for reports (e.g. `"mu"`, `"q_start.w"`).
    fn data_name(&self, k: usize) -> String {
        format!("theta{k}")
    }
    /// Evaluates the residual at `x` with the data replaced by `theta`. It must agree with
    /// [`ResidualBlock::evaluate`] when `theta` is the block's own data; the Jacobian checker
    /// ([`crate::check_data_jacobian`]) differentiates it by central differences.
    fn evaluate_with_data(&self, x: Params<'_>, _theta: &[f64], out: &mut [f64]) {
        self.evaluate(x, out);
    }
    /// Writes `∂r/∂θ` at `x` and the block's current data. `jac` starts zeroed.
    fn data_jacobian(&self, _x: Params<'_>, _jac: &mut DataJacobian<'_>) {}
}
