//! The LU of a matrix some of whose rows are unit rows, on its free block alone.
//!
//! A row `i` whose only nonzero entry is its diagonal `d_i` (a *unit row*: Newton's `H = D_a +
//! D_b J` at a component held at its bound with `D_b,i = 0`, `docs/latency.md`, "Newton's
//! Jacobian on its free block") makes the matrix, with `U` the unit rows and `F` the others,
//! block lower triangular: `H = [D_U 0; H_FU H_FF]`. So `H x = b` is `x_U = b_U / D_U` and
//! `H_FF x_F = b_F − H_FU x_U`, and only `H_FF` is factorised. Its pivots and the `d_i` are
//! the pivots of an elimination of `H` that takes the unit rows first, so the pivot-ratio
//! verdict ([`super::SINGULAR_PIVOT_RATIO`]) is judged on both together.
//!
//! The lists that gather `H_FF` and `H_FU` from the stored entries are built once per unit-row
//! mask and kept while the mask is the same (the active set changes seldom); the workspace is
//! sized for the whole matrix once, so a new mask allocates nothing.

use super::small_lu::SmallLu;
use super::{LinalgError, SINGULAR_PIVOT_RATIO};
use crate::pattern::CscPattern;

/// The LU of `H_FF` and the entries of `D_U` and `H_FU` of a matrix with unit rows (module
/// documentation), for matrices in one [`CscPattern`] up to [`super::SMALL_DENSE_MAX`]
/// unknowns (the small kernel's).
#[derive(Clone, Debug)]
pub struct UnitRowsLu {
    /// The unit-row mask the lists are built for, when `built`.
    mask: Vec<bool>,
    built: bool,
    /// The free components, ascending: row and column `r` of `H_FF` is component `free[r]`.
    free: Vec<usize>,
    /// The unit rows, ascending.
    unit: Vec<usize>,
    /// The row (and column) of each free component in `H_FF` (unused for a unit one).
    compact: Vec<usize>,
    /// `H_FF`'s stored entries: their position in the values and in the column-major block.
    block: Vec<(usize, usize)>,
    /// `H_FU`'s stored entries: their position in the values, their row in `H_FF` and their
    /// column (a unit component).
    coupling: Vec<(usize, usize, usize)>,
    /// The positions of the unit rows' off-diagonal entries: zero, read to check it.
    off_unit: Vec<usize>,
    /// The positions of the unit rows' diagonal entries, in the order of `unit`.
    diag_pos: Vec<usize>,
    /// The factorised matrix's `D_U` (order of `unit`) and `H_FU` (order of `coupling`).
    diag: Vec<f64>,
    coupling_values: Vec<f64>,
    /// The small kernel's LU of `H_FF`.
    lu: SmallLu,
    /// A gathered free part of a right-hand side.
    work: Vec<f64>,
    factored: bool,
}

impl UnitRowsLu {
    /// Workspace for `n × n` matrices in `pattern` with `nnz` stored entries.
    pub(crate) fn new(pattern: &CscPattern) -> Self {
        let (n, nnz) = (pattern.dim(), pattern.nnz());
        UnitRowsLu {
            mask: Vec::with_capacity(n),
            built: false,
            free: Vec::with_capacity(n),
            unit: Vec::with_capacity(n),
            compact: vec![0; n],
            block: Vec::with_capacity(nnz),
            coupling: Vec::with_capacity(nnz),
            off_unit: Vec::with_capacity(nnz),
            diag_pos: Vec::with_capacity(n),
            diag: Vec::with_capacity(n),
            coupling_values: Vec::with_capacity(nnz),
            lu: SmallLu::new(n),
            work: vec![0.0; n],
            factored: false,
        }
    }

    /// The number of unit rows of the mask last factorised with (the free block has the others).
    pub fn unit_rows(&self) -> usize {
        self.unit.len()
    }

    /// Builds the lists for `mask` (nothing to do when they are built for it already).
    #[inline(never)]
    fn index(&mut self, pattern: &CscPattern, mask: &[bool]) {
        if self.built && self.mask == mask {
            return;
        }
        self.built = true;
        self.mask.clear();
        self.mask.extend_from_slice(mask);
        let n = mask.len();
        self.free.clear();
        self.unit.clear();
        for (i, &m) in mask.iter().enumerate() {
            if m {
                self.unit.push(i);
            } else {
                self.free.push(i);
            }
        }
        let f = self.free.len();
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        self.compact.resize(n, 0);
        for (r, &i) in self.free.iter().enumerate() {
            self.compact[i] = r;
        }
        let compact = &self.compact;
        self.block.clear();
        self.coupling.clear();
        self.off_unit.clear();
        for j in 0..n {
            for q in cp[j]..cp[j + 1] {
                let r = ri[q];
                if mask[r] {
                    if r != j {
                        self.off_unit.push(q);
                    }
                } else if mask[j] {
                    self.coupling.push((q, compact[r], j));
                } else {
                    self.block.push((q, compact[j] * f + compact[r]));
                }
            }
        }
        self.diag_pos.clear();
        let dp = pattern.diag_pos();
        self.diag_pos.extend(self.unit.iter().map(|&i| dp[i]));
        self.lu.resize(f);
    }

    /// Factorises the matrix whose stored entries (in `pattern`) are `values` and whose rows
    /// `mask[i]` are unit rows. `Ok(false)`, nothing factorised, when a unit row holds a
    /// nonzero off-diagonal entry (or a NaN there): the caller factorises the whole matrix.
    /// `NonFinite` for a non-finite entry elsewhere, `Singular` by the pivot ratio of `H_FF`'s
    /// pivots and `D_U` together.
    pub(crate) fn factor(
        &mut self,
        pattern: &CscPattern,
        values: &[f64],
        mask: &[bool],
    ) -> Result<bool, LinalgError> {
        self.factored = false;
        self.index(pattern, mask);
        if !self.off_unit.iter().all(|&q| values[q] == 0.0) {
            return Ok(false);
        }
        let mut finite = true;
        self.diag.clear();
        self.diag.extend(self.diag_pos.iter().map(|&q| {
            finite &= values[q].is_finite();
            values[q]
        }));
        self.coupling_values.clear();
        self.coupling_values
            .extend(self.coupling.iter().map(|&(q, _, _)| {
                finite &= values[q].is_finite();
                values[q]
            }));
        let a = self.lu.storage_mut();
        a.fill(0.0);
        for &(q, k) in &self.block {
            let v = values[q];
            finite &= v.is_finite();
            a[k] = v;
        }
        if !finite {
            return Err(LinalgError::NonFinite);
        }
        self.lu.eliminate();
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for d in self.lu.pivots().chain(self.diag.iter().copied()) {
            lo = lo.min(d.abs());
            hi = hi.max(d.abs());
        }
        if !mask.is_empty() && (lo.is_nan() || lo <= SINGULAR_PIVOT_RATIO * hi || !lo.is_finite())
        {
            return Err(LinalgError::Singular {
                ratio: if hi > 0.0 { lo / hi } else { 0.0 },
            });
        }
        self.factored = true;
        Ok(true)
    }

    /// Solves `H x = b` in place: `x_U = b_U / D_U`, then `H_FF x_F = b_F − H_FU x_U` (the
    /// coupling skipped when `x_U` is zero, as it is at a held component, where `Φ_i = 0`).
    pub(crate) fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.check(b)?;
        let mut coupled = false;
        for (&i, &d) in self.unit.iter().zip(&self.diag) {
            b[i] /= d;
            coupled |= b[i] != 0.0;
        }
        let work = &mut self.work[..self.free.len()];
        for (w, &i) in work.iter_mut().zip(&self.free) {
            *w = b[i];
        }
        if coupled {
            for (&(_, r, j), &v) in self.coupling.iter().zip(&self.coupling_values) {
                work[r] -= v * b[j];
            }
        }
        self.lu.solve(work);
        for (&w, &i) in work.iter().zip(&self.free) {
            b[i] = w;
        }
        finite(b)
    }

    /// Solves `Hᵀ x = b` in place: `H_FFᵀ x_F = b_F`, then `x_U = (b_U − H_FUᵀ x_F) / D_U`.
    pub(crate) fn solve_transpose_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.check(b)?;
        let work = &mut self.work[..self.free.len()];
        for (w, &i) in work.iter_mut().zip(&self.free) {
            *w = b[i];
        }
        self.lu.solve_transpose(work);
        for (&w, &i) in work.iter().zip(&self.free) {
            b[i] = w;
        }
        for (&(_, r, j), &v) in self.coupling.iter().zip(&self.coupling_values) {
            b[j] -= v * work[r];
        }
        for (&i, &d) in self.unit.iter().zip(&self.diag) {
            b[i] /= d;
        }
        finite(b)
    }

    fn check(&self, b: &[f64]) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        if b.len() != self.mask.len() {
            return Err(LinalgError::Factorization(format!(
                "right-hand side has {} entries, expected {}",
                b.len(),
                self.mask.len()
            )));
        }
        Ok(())
    }
}

fn finite(b: &[f64]) -> Result<(), LinalgError> {
    if b.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(LinalgError::NonFinite)
    }
}
