//! Residual blocks: the pieces of `F` a model is built from (Ceres' cost functions, for MCPs).

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

/// A block of residual equations `r(x_1, …, x_K)` with an analytic Jacobian.
///
/// The block declares the sizes of the variable blocks it reads; the problem builder binds
/// them (`Problem::add_residual_block`) and pairs the block with a variable block of the same
/// length (formulation.md §2). Implementations must be deterministic and free of side effects.
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
}
