//! Residual blocks: the pieces of `F` a model is built from (Ceres' cost functions, for MCPs).
//!
//! A residual block reads **inputs**, each bound by the problem builder to either
//!
//! - a **variable block** (unknowns `z` of the MCP), or
//! - a **data block** ([`crate::DataBlock`]: model parameters such as μ, a mass, the start-of-step
//!   state or an applied load, fixed during a solve and changed between solves with
//!   [`crate::BlockMcp::set_data`]).
//!
//! The block declares the sizes of its inputs in [`ResidualBlock::parameter_sizes`] ("parameter
//! blocks" in Ceres' words) and writes `∂r/∂x_k` for **every** input `k`, variable or data, in
//! [`ResidualBlock::jacobian`]. The data derivatives are what the implicit differentiation of a
//! solution needs (`dz/dθ = −J⁻¹ ∂F/∂θ` on the free components, [`crate::sensitivity`]); the
//! assembled MCP Jacobian discards them, and [`JacobianBlocks::wants`] lets a block skip
//! derivatives nobody asked for.

/// Where input `k` of a residual block lives: `len` values at `offset` of the unknowns `z`
/// (a variable block) or of the data vector (a data block).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InputRange {
    /// Whether the input is a variable or a data block.
    pub kind: InputKind,
    /// Offset in `z` or in the data vector.
    pub offset: usize,
    /// Number of values.
    pub len: usize,
}

impl InputRange {
    /// A variable input at `offset` of `z`.
    pub fn var(offset: usize, len: usize) -> Self {
        InputRange {
            kind: InputKind::Variable,
            offset,
            len,
        }
    }
    /// A data input at `offset` of the data vector.
    pub fn data(offset: usize, len: usize) -> Self {
        InputRange {
            kind: InputKind::Data,
            offset,
            len,
        }
    }
}

/// The kind of an input of a residual block.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InputKind {
    /// A variable block (unknowns of the MCP).
    Variable = 0,
    /// A data block (model parameters).
    Data = 1,
}

impl std::fmt::Display for InputKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            InputKind::Variable => "variable",
            InputKind::Data => "data",
        })
    }
}

/// Read-only view of the inputs of a residual block, in the order it declared them.
///
/// Zero-copy: it indexes into the flat unknown vector `z` and the data vector by precomputed
/// ranges.
#[derive(Clone, Copy, Debug)]
pub struct Params<'a> {
    /// `z` and the data, indexed by `InputKind as usize`.
    sources: [&'a [f64]; 2],
    inputs: &'a [InputRange],
}

impl<'a> Params<'a> {
    /// A view of `z` (variable inputs) and `data` (data inputs) through `inputs`.
    #[inline]
    pub fn new(z: &'a [f64], data: &'a [f64], inputs: &'a [InputRange]) -> Self {
        Params {
            sources: [z, data],
            inputs,
        }
    }
    /// Values of input `k`, whichever kind it is.
    #[inline]
    pub fn block(&self, k: usize) -> &'a [f64] {
        let r = self.inputs[k];
        &self.sources[r.kind as usize][r.offset..r.offset + r.len]
    }
    /// Values of input `k` as an array of its declared size `N`: one length check, where a
    /// block reading the slice entry by entry pays one per entry in its hot loops.
    ///
    /// # Panics
    /// If input `k` does not have `N` values (a block reading a size it did not declare; the
    /// problem builder checks the bound sizes against [`ResidualBlock::parameter_sizes`]).
    #[inline]
    pub fn array<const N: usize>(&self, k: usize) -> &'a [f64; N] {
        let b = self.block(k);
        match b.try_into() {
            Ok(a) => a,
            Err(_) => wrong_size(k, b.len(), N),
        }
    }
    /// Number of inputs.
    pub fn len(&self) -> usize {
        self.inputs.len()
    }
    /// True when the residual block reads no input.
    pub fn is_empty(&self) -> bool {
        self.inputs.is_empty()
    }
}

/// The panic of [`Params::array`], out of line: formatted in the hot path, its arguments
/// were stored at every read.
#[cold]
#[inline(never)]
fn wrong_size(k: usize, len: usize, n: usize) -> ! {
    panic!("input {k} has {len} values, not {n}")
}

/// Write access to the small dense Jacobian blocks `∂r/∂x_k` of one residual block, one per
/// input `k` (variable or data).
///
/// Entry `(i, j)` of block `k` is `∂r_i / ∂(x_k)_j`. The storage behind it is the assembled
/// sparse Jacobian, a dense `∂F/∂θ` or a local dense buffer (Jacobian checker); all entries start
/// at zero, so a residual block writes only its structural non-zeros. Writes to an input nobody
/// asked for (the data inputs while the MCP Jacobian is assembled, the variable inputs while
/// `∂F/∂θ` is) are discarded; a block whose derivatives for an input are costly checks
/// [`JacobianBlocks::wants`] first.
#[derive(Debug)]
pub struct JacobianBlocks<'a> {
    values: &'a mut [f64],
    /// For block `k`, column `j`: position of row 0 in `values` is `col_pos[block_start[k] + j]`,
    /// or [`JacobianBlocks::DISCARD`].
    col_pos: &'a [usize],
    block_start: &'a [usize],
    rows: usize,
    /// Whether some column is [`JacobianBlocks::DISCARD`] (false: every write is stored, and the
    /// hot loop of a block without data inputs skips the test).
    discards: bool,
}

impl<'a> JacobianBlocks<'a> {
    /// Marks a column whose writes are discarded (an input not asked for).
    pub const DISCARD: usize = usize::MAX;

    /// Wraps a value array and its layout. `block_start` has one entry per block plus a final
    /// sentinel; `col_pos[block_start[k] + j] + i` is where entry `(i, j)` of block `k` lives,
    /// and a column whose `col_pos` is [`JacobianBlocks::DISCARD`] is not stored.
    pub fn new(
        values: &'a mut [f64],
        col_pos: &'a [usize],
        block_start: &'a [usize],
        rows: usize,
    ) -> Self {
        let discards = col_pos.contains(&Self::DISCARD);
        Self::with_discards(values, col_pos, block_start, rows, discards)
    }

    /// [`JacobianBlocks::new`] with `discards` (whether `col_pos` holds a
    /// [`JacobianBlocks::DISCARD`]) known beforehand.
    pub(crate) fn with_discards(
        values: &'a mut [f64],
        col_pos: &'a [usize],
        block_start: &'a [usize],
        rows: usize,
        discards: bool,
    ) -> Self {
        JacobianBlocks {
            values,
            col_pos,
            block_start,
            rows,
            discards,
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
    /// Whether the derivatives with respect to input `k` are stored (false: writes to block `k`
    /// are discarded, and a block may skip computing them).
    #[inline]
    pub fn wants(&self, k: usize) -> bool {
        let s = self.block_start[k];
        s < self.block_start[k + 1] && (!self.discards || self.col_pos[s] != Self::DISCARD)
    }
    #[inline]
    fn pos(&self, k: usize, i: usize, j: usize) -> Option<usize> {
        debug_assert!(i < self.rows && j < self.cols(k));
        let p = self.col_pos[self.block_start[k] + j];
        if self.discards && p == Self::DISCARD {
            None
        } else {
            Some(p + i)
        }
    }
    /// Sets entry `(i, j)` of block `k`.
    #[inline]
    pub fn set(&mut self, k: usize, i: usize, j: usize, v: f64) {
        if let Some(p) = self.pos(k, i, j) {
            self.values[p] = v;
        }
    }
    /// Adds to entry `(i, j)` of block `k`.
    #[inline]
    pub fn add(&mut self, k: usize, i: usize, j: usize, v: f64) {
        if let Some(p) = self.pos(k, i, j) {
            self.values[p] += v;
        }
    }
    /// Column `j` of block `k`, located once for a block that writes several of its rows
    /// ([`JacobianBlocks::put`]): `set` looks the column up at every entry, which in the hot
    /// loops of the step problem's blocks cost more than the entries' arithmetic.
    #[inline]
    pub fn column(&self, k: usize, j: usize) -> Column {
        debug_assert!(j < self.cols(k));
        Column(self.col_pos[self.block_start[k] + j])
    }
    /// Columns `j0 .. j0 + N` of block `k` ([`JacobianBlocks::column`]).
    #[inline]
    pub fn columns<const N: usize>(&self, k: usize, j0: usize) -> [Column; N] {
        let s = self.block_start[k] + j0;
        debug_assert!(j0 + N <= self.cols(k));
        let cols: &[usize; N] = match self.col_pos[s..s + N].try_into() {
            Ok(c) => c,
            Err(_) => unreachable!("a slice of N positions"),
        };
        cols.map(Column)
    }
    /// Sets row `i` of a located column (as [`JacobianBlocks::set`] sets its entry).
    #[inline]
    pub fn put(&mut self, c: Column, i: usize, v: f64) {
        debug_assert!(i < self.rows);
        if c.0 != Self::DISCARD {
            self.values[c.0 + i] = v;
        }
    }
    /// Adds to row `i` of a located column (as [`JacobianBlocks::add`]).
    #[inline]
    pub fn put_add(&mut self, c: Column, i: usize, v: f64) {
        debug_assert!(i < self.rows);
        if c.0 != Self::DISCARD {
            self.values[c.0 + i] += v;
        }
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

/// A column of a [`JacobianBlocks`] block, located once ([`JacobianBlocks::column`]): where
/// its row 0 lives, or [`JacobianBlocks::DISCARD`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Column(usize);

/// A block of residual equations `r(x_1, …, x_K)` with an analytic Jacobian.
///
/// The block declares the sizes of the inputs it reads; the problem builder binds each to a
/// variable or a data block (`Problem::add_residual_block`) and pairs the block with a variable
/// block of the same length (`docs/model.md#mcp`), or adds its rows to those of another block
/// (`Problem::add_term`). Implementations must be deterministic and free of side effects.
pub trait ResidualBlock: Send + Sync {
    /// Short descriptive name, used in reports.
    fn name(&self) -> &str;
    /// Number of residual rows.
    fn num_residuals(&self) -> usize;
    /// Sizes of the inputs read (variable or data blocks), in order.
    fn parameter_sizes(&self) -> &[usize];
    /// Evaluates the residual into `out` (length `num_residuals`).
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]);
    /// Writes the analytic Jacobian, block by block, for every input (variable or data) that
    /// `jac` [wants](JacobianBlocks::wants). `jac` starts zeroed.
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>);
    /// The inputs `∂r/∂x_k` depends on, when that is fewer than all of them (Ceres' constant
    /// Jacobian blocks): `Some(&[])` when `r` is affine in `x_k` with a constant coefficient,
    /// `Some(&[2, 3])` when the coefficient reads inputs 2 and 3 only. `None` (the default): it
    /// may read any input.
    ///
    /// When every input listed is bound to a data block, `∂r/∂x_k` is constant while the data
    /// are: the assembled MCP writes it once per change of those data blocks and asks
    /// [`ResidualBlock::jacobian`] at each point only for the other inputs (`docs/latency.md`,
    /// "constant Jacobian entries"). The entries of input `k` must then be the same bits at any
    /// values of the inputs not listed; [`crate::check_residual_block`] checks that.
    fn jacobian_depends_on(&self, _k: usize) -> Option<&[usize]> {
        None
    }
    /// Evaluates residual and Jacobian together; override when they share work.
    fn evaluate_with_jacobian(&self, x: Params<'_>, out: &mut [f64], jac: &mut JacobianBlocks<'_>) {
        self.evaluate(x, out);
        self.jacobian(x, jac);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn located_columns_write_where_set_writes() {
        // Two blocks of 2 rows: block 0 with 2 columns, block 1 with 3, its column 1 discarded.
        let d = JacobianBlocks::DISCARD;
        let col_pos = [0, 2, 4, d, 6];
        let block_start = [0, 2, 5];
        let (mut a, mut b) = ([0.5; 8], [0.5; 8]);
        {
            let mut jac = JacobianBlocks::new(&mut a, &col_pos, &block_start, 2);
            for (k, j) in [(0, 0), (0, 1), (1, 0), (1, 1), (1, 2)] {
                for i in 0..2 {
                    jac.set(k, i, j, (10 * k + 3 * j + i) as f64);
                    jac.add(k, i, j, 0.25);
                }
            }
        }
        {
            let mut jac = JacobianBlocks::new(&mut b, &col_pos, &block_start, 2);
            let c0: [Column; 2] = jac.columns(0, 0);
            let c1: [Column; 3] = jac.columns(1, 0);
            assert_eq!(jac.column(1, 2), c1[2]);
            for (k, cols) in [(0, &c0[..]), (1, &c1[..])] {
                for (j, &c) in cols.iter().enumerate() {
                    for i in 0..2 {
                        jac.put(c, i, (10 * k + 3 * j + i) as f64);
                        jac.put_add(c, i, 0.25);
                    }
                }
            }
        }
        assert_eq!(a, b);
        assert_eq!(b[6..], [16.25, 17.25]);
    }

    #[test]
    fn arrays_of_the_declared_sizes() {
        let z = [1.0, 2.0, 3.0, 4.0];
        let data = [5.0];
        let inputs = [InputRange::var(1, 3), InputRange::data(0, 1)];
        let x = Params::new(&z, &data, &inputs);
        assert_eq!(x.array::<3>(0), &[2.0, 3.0, 4.0]);
        assert_eq!(x.array::<1>(1), &[5.0]);
        let wrong = std::panic::catch_unwind(|| x.array::<2>(0)[0]);
        assert!(wrong.is_err());
    }
}
