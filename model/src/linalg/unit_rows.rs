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

use super::simd::{all_finite, carries_finite, exponent_carry};
use super::small_lu::{SmallLu, magnitude_range};
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
    /// The number of stored entries of the pattern the lists are built for: every position
    /// in `block`, `coupling`, `off_unit` and `diag_pos` is below it (checked when built), so
    /// that a factorisation checks the values' length once instead of each read.
    nnz: usize,
    /// `H_FF`'s stored entries: their position in the values and in the column-major block
    /// (below `free.len()²`, the kernel's storage, checked when built).
    block: Vec<(usize, usize)>,
    /// `H_FU`'s stored entries: their position in the values, their row (a free component)
    /// and their column (a unit component).
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
    /// The free components in the order of the factors' row interchanges
    /// ([`SmallLu::row_order`]): the solves gather the right-hand side by it.
    order: Vec<usize>,
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
            nnz,
            block: Vec::with_capacity(nnz),
            coupling: Vec::with_capacity(nnz),
            off_unit: Vec::with_capacity(nnz),
            diag_pos: Vec::with_capacity(n),
            diag: Vec::with_capacity(n),
            coupling_values: Vec::with_capacity(nnz),
            lu: SmallLu::new(n),
            order: vec![0; n],
            work: vec![0.0; n],
            factored: false,
        }
    }

    /// The number of unit rows of the mask last factorised with (the free block has the others).
    pub fn unit_rows(&self) -> usize {
        self.unit.len()
    }

    /// Builds the lists for `mask` (nothing to do when they are built for it already). Not
    /// inlined: a new mask is rare, and the factorisation's loop stays short.
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
                    self.coupling.push((q, r, j));
                } else {
                    self.block.push((q, compact[j] * f + compact[r]));
                }
            }
        }
        self.diag_pos.clear();
        let dp = pattern.diag_pos();
        self.diag_pos.extend(self.unit.iter().map(|&i| dp[i]));
        self.lu.resize(f);
        self.order.resize(f, 0);
        // The invariants of `factor`'s unchecked reads and writes (a pattern's positions
        // satisfy them; a failure here is a malformed pattern, not a user's input).
        let nnz = pattern.nnz();
        self.nnz = nnz;
        assert!(
            self.block.iter().all(|&(q, k)| q < nnz && k < f * f)
                && self.coupling.iter().all(|&(q, _, _)| q < nnz)
                && self.off_unit.iter().chain(&self.diag_pos).all(|&q| q < nnz),
            "a stored entry's position outside the pattern"
        );
    }

    /// Factorises the matrix whose stored entries (in `pattern`) are `values` and whose rows
    /// `mask[i]` are unit rows. `Ok(false)`, nothing factorised, when a unit row holds a
    /// nonzero off-diagonal entry (or a NaN there): the caller factorises the whole matrix.
    /// `NonFinite` for a non-finite entry elsewhere, `Singular` by the pivot ratio of `H_FF`'s
    /// pivots and `D_U` together. `known_finite`: the caller has found every value finite, and
    /// `H_FF`'s entries are moved without the test (`LinearSolver::factor_with_unit_rows_finite`).
    pub(crate) fn factor(
        &mut self,
        pattern: &CscPattern,
        values: &[f64],
        mask: &[bool],
        known_finite: bool,
    ) -> Result<bool, LinalgError> {
        self.factored = false;
        self.index(pattern, mask);
        let Some(values) = values.get(..self.nnz) else {
            return Err(LinalgError::Factorization(format!(
                "{} values for a pattern of {} stored entries",
                values.len(),
                self.nnz
            )));
        };
        // SAFETY (the reads and writes below): every position in the lists is below
        // `self.nnz = values.len()`, and every block position below `free.len()²`, the
        // kernel's storage (`index` checks both when it builds the lists).
        let at = |q: usize| unsafe { *values.get_unchecked(q) };
        // A unit row's off-diagonal entries are zero (a NaN is not: the whole LU refuses it).
        if !self.off_unit.iter().all(|&q| at(q) == 0.0) {
            return Ok(false);
        }
        // Every other entry is tested for finiteness as it is moved: the exponent carries
        // OR-ed, no branch per entry (`simd::exponent_carry`).
        let mut carried = 0u64;
        self.diag.clear();
        self.diag.extend(self.diag_pos.iter().map(|&q| {
            carried |= exponent_carry(at(q));
            at(q)
        }));
        self.coupling_values.clear();
        self.coupling_values
            .extend(self.coupling.iter().map(|&(q, _, _)| {
                carried |= exponent_carry(at(q));
                at(q)
            }));
        self.lu.clear_storage();
        let a = self.lu.storage_mut();
        if known_finite {
            // Loads and stores alone (the test is the caller's).
            for &(q, k) in &self.block {
                // SAFETY: as above.
                unsafe { *a.get_unchecked_mut(k) = at(q) };
            }
        } else {
            for &(q, k) in &self.block {
                let v = at(q);
                carried |= exponent_carry(v);
                // SAFETY: as above.
                unsafe { *a.get_unchecked_mut(k) = v };
            }
        }
        if !carries_finite(carried) {
            return Err(LinalgError::NonFinite);
        }
        self.lu.eliminate();
        let range = self.lu.pivot_magnitude_range((f64::INFINITY, 0.0));
        let (lo, hi) = self.diag.iter().copied().fold(range, magnitude_range);
        if !mask.is_empty() && (lo.is_nan() || lo <= SINGULAR_PIVOT_RATIO * hi || !lo.is_finite()) {
            return Err(LinalgError::Singular {
                ratio: if hi > 0.0 { lo / hi } else { 0.0 },
            });
        }
        self.lu.row_order(&self.free, &mut self.order);
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
        // `b_F − H_FU x_U` where `b_F` lies (a unit entry `b[j]` is not changed by it).
        if coupled {
            for (&(_, i, j), &v) in self.coupling.iter().zip(&self.coupling_values) {
                b[i] -= v * b[j];
            }
        }
        // Gathered in the order of the factors' interchanges, solved, written back.
        self.lu
            .solve_mapped(b, &self.order, &self.free, &mut self.work);
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
        for (&(_, i, j), &v) in self.coupling.iter().zip(&self.coupling_values) {
            b[j] -= v * b[i];
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
    if all_finite(b) {
        Ok(())
    } else {
        Err(LinalgError::NonFinite)
    }
}

#[cfg(test)]
mod tests {
    use crate::linalg::{DenseLu, LinalgError, LinearSolver};
    use crate::pattern::CscPattern;

    /// A dense `n × n` column-major matrix with a strong diagonal and unit rows `unit`
    /// (diagonal `−1 − i`, the rest of the row zero, one of them `−0`).
    fn matrix(n: usize, unit: &[usize], seed: u64) -> Vec<f64> {
        let mut x = seed;
        let mut a = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let v = ((x >> 11) as f64 / (1u64 << 53) as f64) - 0.5;
                a[j * n + i] = if i == j { 4.0 + v } else { v };
            }
        }
        for &i in unit {
            for j in 0..n {
                a[j * n + i] = if j == i { -1.0 - i as f64 } else { 0.0 };
            }
            a[((i + 1) % n) * n + i] = -0.0;
        }
        a
    }

    fn whole_solve(a: &[f64], b: &[f64], transpose: bool) -> Vec<f64> {
        let n = b.len();
        let mut lu = DenseLu::new(n);
        lu.factor(a).unwrap_or_else(|e| panic!("{e}"));
        let mut x = b.to_vec();
        if transpose {
            lu.solve_transpose_in_place(&mut x)
        } else {
            lu.solve_in_place(&mut x)
        }
        .unwrap_or_else(|e| panic!("{e}"));
        x
    }

    fn mask(n: usize, unit: &[usize]) -> Vec<bool> {
        (0..n).map(|i| unit.contains(&i)).collect()
    }

    fn assert_close(x: &[f64], y: &[f64], tol: f64) {
        for (u, v) in x.iter().zip(y) {
            assert!(
                (u - v).abs() <= tol * (1.0 + v.abs()),
                "{x:?} against {y:?}"
            );
        }
    }

    #[test]
    fn the_free_block_solves_as_the_whole_matrix() {
        let n = 9;
        let pattern = CscPattern::dense(n);
        let mut solver = LinearSolver::for_pattern(&pattern, 120).unwrap_or_else(|e| panic!("{e}"));
        // Two masks in turn: the lists are rebuilt for each and kept while it is the same.
        for (seed, unit) in [(1, vec![1, 4, 8]), (2, vec![0, 5]), (3, vec![0, 5])] {
            let a = matrix(n, &unit, seed);
            solver
                .factor_with_unit_rows(&a, &mask(n, &unit))
                .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(solver.unit_rows_left_out(), unit.len());
            assert!(!solver.solves_rows());
            // A right-hand side zero on the unit rows (a held component's Φ) and one that is
            // not (a chord step's: the coupling `H_FU x_U` enters).
            let mut b: Vec<f64> = (0..n).map(|i| 1.0 + i as f64 * 0.25).collect();
            for held in [true, false] {
                if held {
                    for &i in &unit {
                        b[i] = 0.0;
                    }
                } else {
                    for &i in &unit {
                        b[i] = 0.5 + i as f64;
                    }
                }
                for transpose in [false, true] {
                    let mut x = b.clone();
                    if transpose {
                        solver.solve_transpose_in_place(&mut x)
                    } else {
                        solver.solve_in_place(&mut x)
                    }
                    .unwrap_or_else(|e| panic!("{e}"));
                    assert_close(&x, &whole_solve(&a, &b, transpose), 1e-14);
                    if held && !transpose {
                        for &i in &unit {
                            assert_eq!(x[i], 0.0);
                        }
                    }
                }
            }
            // Many right-hand sides: each column as solved alone.
            let mut many: Vec<f64> = b.iter().chain(&b).map(|v| v * 2.0).collect();
            solver
                .solve_many_in_place(&mut many, 2)
                .unwrap_or_else(|e| panic!("{e}"));
            let mut one: Vec<f64> = b.iter().map(|v| v * 2.0).collect();
            solver
                .solve_in_place(&mut one)
                .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(&many[..n], &one[..]);
            assert_eq!(&many[n..], &one[..]);
        }
    }

    /// The solve as it was before the mapped solve (`docs/latency.md`, branch wip-lukernel):
    /// `b_U / D_U`, `b_F` gathered in its own order, `− H_FU x_U`, the kernel's solve with its
    /// interchanges, the free part scattered back.
    fn gathered_solve(lu: &super::UnitRowsLu, b: &mut [f64]) {
        for (&i, &d) in lu.unit.iter().zip(&lu.diag) {
            b[i] /= d;
        }
        let mut work: Vec<f64> = lu.free.iter().map(|&i| b[i]).collect();
        if lu.unit.iter().any(|&i| b[i] != 0.0) {
            for (&(_, i, j), &v) in lu.coupling.iter().zip(&lu.coupling_values) {
                work[lu.compact[i]] -= v * b[j];
            }
        }
        lu.lu.solve(&mut work);
        for (&w, &i) in work.iter().zip(&lu.free) {
            b[i] = w;
        }
    }

    /// The mapped solve gives bitwise the gathered solve's numbers, for right-hand sides zero
    /// and nonzero on the unit rows, on matrices whose free block interchanges rows.
    #[test]
    fn the_mapped_solve_is_bitwise_the_gathered_solve() {
        let n = 12;
        let pattern = CscPattern::dense(n);
        let mut lu = super::UnitRowsLu::new(&pattern);
        let mut interchanged = false;
        for (seed, unit) in [(11, vec![0, 3, 4, 10]), (12, vec![5]), (13, vec![1, 11])] {
            let mut a = matrix(n, &unit, seed);
            // A weak diagonal in the free block, so that its rows interchange.
            for j in (0..n).filter(|j| !unit.contains(j)) {
                a[j * n + j] *= 0.01;
            }
            assert_eq!(lu.factor(&pattern, &a, &mask(n, &unit), false), Ok(true));
            // The load without the finiteness test (values known finite): the same factors.
            let mut known = super::UnitRowsLu::new(&pattern);
            assert_eq!(known.factor(&pattern, &a, &mask(n, &unit), true), Ok(true));
            interchanged |= lu.order != lu.free;
            for held in [true, false] {
                let b: Vec<f64> = (0..n)
                    .map(|i| {
                        if held && unit.contains(&i) {
                            0.0
                        } else {
                            (i as f64 * 1.3).sin()
                        }
                    })
                    .collect();
                let (mut x, mut y, mut w) = (b.clone(), b.clone(), b.clone());
                lu.solve_in_place(&mut x).unwrap_or_else(|e| panic!("{e}"));
                gathered_solve(&lu, &mut y);
                known
                    .solve_in_place(&mut w)
                    .unwrap_or_else(|e| panic!("{e}"));
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&x), bits(&y), "seed {seed}, held {held}");
                assert_eq!(bits(&w), bits(&x), "seed {seed}, held {held}");
            }
        }
        assert!(interchanged);
        // Fewer values than the pattern stores: refused, not read past.
        let a = matrix(n, &[2], 14);
        assert!(matches!(
            lu.factor(&pattern, &a[..n * n - 1], &mask(n, &[2]), false),
            Err(LinalgError::Factorization(_))
        ));
    }

    #[test]
    fn a_unit_row_that_is_not_falls_back_to_the_whole_matrix() {
        let n = 6;
        let pattern = CscPattern::dense(n);
        let mut solver = LinearSolver::for_pattern(&pattern, 120).unwrap_or_else(|e| panic!("{e}"));
        let unit = [2, 3];
        let mut a = matrix(n, &unit, 7);
        // Row 3 holds an entry off its diagonal: not a unit row after all.
        a[5 * n + 3] = 0.125;
        solver
            .factor_with_unit_rows(&a, &mask(n, &unit))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(solver.unit_rows_left_out(), 0);
        assert!(solver.solves_rows());
        let b: Vec<f64> = (0..n).map(|i| i as f64 - 2.0).collect();
        let mut x = b.clone();
        solver
            .solve_in_place(&mut x)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(x, whole_solve(&a, &b, false));
        // No unit row: the whole matrix, bitwise `factor`'s.
        solver
            .factor_with_unit_rows(&a, &[false; 6])
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(solver.unit_rows_left_out(), 0);
    }

    #[test]
    fn singular_and_non_finite_matrices_are_refused() {
        let n = 5;
        let pattern = CscPattern::dense(n);
        let mut solver = LinearSolver::for_pattern(&pattern, 120).unwrap_or_else(|e| panic!("{e}"));
        let unit = [1];
        let m = mask(n, &unit);
        // A zero diagonal in a unit row: the whole matrix is singular.
        let mut a = matrix(n, &unit, 3);
        a[n + 1] = 0.0;
        assert!(matches!(
            solver.factor_with_unit_rows(&a, &m),
            Err(LinalgError::Singular { .. })
        ));
        let mut x = vec![1.0; n];
        assert_eq!(solver.solve_in_place(&mut x), Err(LinalgError::NotFactored));
        // A unit row's diagonal tiny beside the block's pivots: the ratio sees both.
        a[n + 1] = 1e-15;
        assert!(matches!(
            solver.factor_with_unit_rows(&a, &m),
            Err(LinalgError::Singular { .. })
        ));
        // Two equal free columns: the free block is singular.
        let mut a = matrix(n, &unit, 4);
        for i in 0..n {
            a[3 * n + i] = a[2 * n + i];
        }
        assert!(matches!(
            solver.factor_with_unit_rows(&a, &m),
            Err(LinalgError::Singular { .. })
        ));
        // A NaN in the free block, in the coupling, in a unit row.
        for k in [2 * n + 3, n + 3, 4 * n + 1] {
            let mut a = matrix(n, &unit, 5);
            a[k] = f64::NAN;
            assert_eq!(
                solver.factor_with_unit_rows(&a, &m),
                Err(LinalgError::NonFinite),
                "{k}"
            );
        }
    }
}
