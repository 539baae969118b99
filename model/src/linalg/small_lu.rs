//! Dense LU with partial pivoting for small matrices, on storage kept between calls.
//!
//! The step problems that dominate (one body, a few contacts: 20–70 unknowns) are solved several
//! times per step; at that size a general blocked LU spends more time dispatching than computing
//! (`docs/latency.md`). This kernel is the textbook right-looking elimination on a column-major
//! matrix (LAPACK's `getf2`): the same pivot choice as a blocked LU (largest magnitude in the
//! column, the first one on ties), so the factors agree to round-off. It skips the update of a
//! column whose entry in the pivot row is zero, which pays on the step problems' Jacobians
//! (a third full).

#[cfg(target_arch = "x86_64")]
use super::simd::Avx2;
use super::simd::{Lanes, Portable, avx2_available};

/// The factors `P A = L U` of a square matrix: `L` (unit diagonal, below) and `U` (on and above
/// the diagonal) in one column-major array, and the row interchanges.
#[derive(Clone, Debug)]
pub(crate) struct SmallLu {
    n: usize,
    a: Vec<f64>,
    /// Row `k` was interchanged with row `piv[k] ≥ k` at elimination step `k`.
    piv: Vec<usize>,
    /// The vector loops run with AVX2 (the processor has it; bitwise the same results).
    avx2: bool,
}

impl SmallLu {
    pub(crate) fn new(n: usize) -> Self {
        SmallLu {
            n,
            a: vec![0.0; n * n],
            piv: vec![0; n],
            avx2: avx2_available(),
        }
    }

    /// Makes it an `n × n` LU on the storage it has (no allocation up to the largest `n` it
    /// held: the free block of a matrix with unit rows, [`super::UnitRowsLu`], PATH's crash
    /// step, [`super::ColumnTestedLu`]): the storage's entries, and the factors, are then
    /// unspecified until the caller writes them and eliminates.
    pub(crate) fn resize(&mut self, n: usize) {
        self.n = n;
        self.a.resize(n * n, 0.0);
        self.piv.resize(n, 0);
    }

    /// Dimension `n`.
    pub(crate) fn dim(&self) -> usize {
        self.n
    }

    /// Factorises the column-major `n × n` matrix `src` (finite: the caller checks). A zero
    /// pivot column is left unreduced; the caller's pivot-ratio test reports the matrix singular.
    #[cfg(test)]
    pub(crate) fn factor(&mut self, src: &[f64]) {
        self.a.copy_from_slice(src);
        self.eliminate();
    }

    /// The column-major `n × n` storage the next [`SmallLu::eliminate`] factorises in place: a
    /// caller fills it directly (a sparse matrix scattered into it) instead of copying a dense
    /// matrix in.
    pub(crate) fn storage_mut(&mut self) -> &mut [f64] {
        &mut self.a
    }

    /// Sets every entry of [`SmallLu::storage_mut`] to `+0` (before a sparse matrix is
    /// scattered into it).
    pub(crate) fn clear_storage(&mut self) {
        self.a.fill(0.0);
    }

    /// Factorises the matrix in [`SmallLu::storage_mut`] in place (finite: the caller checks).
    pub(crate) fn eliminate(&mut self) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the processor has AVX2.
            unsafe { eliminate_avx2(self.n, &mut self.a, &mut self.piv) };
            return;
        }
        eliminate_with::<Portable>(self.n, &mut self.a, &mut self.piv);
    }

    /// `L` and `U` in one column-major array (`L` below the diagonal, unit diagonal implied).
    pub(crate) fn factors(&self) -> &[f64] {
        &self.a
    }

    /// The row permutation of the factors as `perm[i]` = the row of `A` in row `i` of `P A`, and
    /// its inverse.
    pub(crate) fn row_permutation(&self, perm: &mut [usize], perm_inv: &mut [usize]) {
        for (i, p) in perm.iter_mut().enumerate() {
            *p = i;
        }
        for (k, &p) in self.piv.iter().enumerate() {
            perm.swap(k, p);
        }
        for (i, &p) in perm.iter().enumerate() {
            perm_inv[p] = i;
        }
    }

    /// The diagonal of `U` (every `n + 1`-th entry of the `n × n` storage: no index
    /// arithmetic or bounds check per pivot).
    pub(crate) fn pivots(&self) -> impl Iterator<Item = f64> + '_ {
        self.a[..self.n * self.n]
            .iter()
            .step_by(self.n + 1)
            .copied()
    }

    /// `range` widened by the magnitudes of `U`'s pivots ([`magnitude_range`]): the smallest and
    /// the largest, NaN pivots passed over, for a pivot-ratio verdict.
    pub(crate) fn pivot_magnitude_range(&self, range: (f64, f64)) -> (f64, f64) {
        self.pivots().fold(range, magnitude_range)
    }

    /// Solves `A x = b` in place.
    pub(crate) fn solve(&self, b: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the processor has AVX2.
            unsafe { solve_avx2(self.n, &self.a, &self.piv, b) };
            return;
        }
        solve_with::<Portable>(self.n, &self.a, &self.piv, b);
    }

    /// [`SmallLu::solve`] of a right-hand side whose row interchanges are done already: `b`
    /// holds `P c` (`b[i] = c[order[i]]` with `order` [`SmallLu::row_order`] of the rows
    /// `0..n`, as a caller gathers it) and gets `x` with `A x = c`. The same substitutions as
    /// [`SmallLu::solve`], so bitwise its solution; a caller that gathers `c` anyway saves the
    /// `n` interchanges per solve (PATH's crash step, [`super::ColumnTestedLu`]).
    pub(crate) fn solve_interchanged(&self, b: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the processor has AVX2.
            unsafe { substitute_avx2(self.n, &self.a, b) };
            return;
        }
        substitute_with::<Portable>(self.n, &self.a, b);
    }

    /// The rows `rows[0..n]` of a longer vector in the order of `P b` (the factors' row
    /// interchanges applied to them): `order[i] = rows[perm[i]]` with
    /// [`SmallLu::row_permutation`]'s `perm`. The gather list of [`SmallLu::solve_mapped`],
    /// computed once per factorisation instead of interchanging the right-hand side's entries
    /// at every solve.
    pub(crate) fn row_order(&self, rows: &[usize], order: &mut [usize]) {
        let n = self.n;
        order[..n].copy_from_slice(&rows[..n]);
        for (k, &p) in self.piv.iter().enumerate() {
            order.swap(k, p);
        }
    }

    /// Solves `A x = c` for the entries `c_i = b[rows[i]]` of a longer vector `b`, the
    /// solution written back to the same entries (`x_i` into `b[rows[i]]`), the other entries
    /// untouched; `order` is [`SmallLu::row_order`] of `rows`, `work` holds at least `n`
    /// entries. The gather of `P c` replaces the row interchanges and the scatter is done in
    /// the back substitution as each `x_i` is final: bitwise [`SmallLu::solve`] of the gathered
    /// `c` (the same operations on the same numbers; the interchanges only move them). The
    /// free block of a matrix with unit rows ([`super::UnitRowsLu`]).
    pub(crate) fn solve_mapped(
        &self,
        b: &mut [f64],
        order: &[usize],
        rows: &[usize],
        work: &mut [f64],
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the processor has AVX2.
            unsafe { solve_mapped_avx2(self.n, &self.a, b, order, rows, work) };
            return;
        }
        solve_mapped_with::<Portable>(self.n, &self.a, b, order, rows, work);
    }

    /// Solves `A X = B` in place for the `k` columns of the row-major `n × k` matrix `b`:
    /// row operations on whole rows, so that a few right-hand sides share each factor entry
    /// (the block elimination's `A⁻¹ B`, [`super::SchurLu`]).
    pub(crate) fn solve_rows(&self, b: &mut [f64], k: usize) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the processor has AVX2.
            unsafe { solve_rows_avx2(self.n, &self.a, &self.piv, b, k) };
            return;
        }
        solve_rows_with::<Portable>(self.n, &self.a, &self.piv, b, k);
    }

    /// [`SmallLu::solve_rows`] with each row's sum kept in registers: row `r` of the solution
    /// is its right-hand side minus the factor-weighted earlier (forward) or later (backward)
    /// solution rows, accumulated across up to 32 columns in AVX2 registers and stored once
    /// ("left-looking"), instead of every factor entry loading and storing a whole row.
    /// Bitwise [`SmallLu::solve_rows`]' results: every entry gets the same products, each
    /// rounded before its subtraction, in the same order (forward ascending, backward
    /// descending), and the same skips (a zero factor entry; in the forward pass a solution row
    /// that is zero), but for the signs of zeros when `k > 32` (the zero-row skip is judged per
    /// strip of 32 columns). The step sensitivities' many right-hand sides
    /// (`docs/latency.md`); without AVX2 or above 64 unknowns it is [`SmallLu::solve_rows`].
    pub(crate) fn solve_rows_accumulated(&self, b: &mut [f64], k: usize) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 && self.n <= 64 && b.len() >= self.n * k {
            let mut map = [0usize; 64];
            for (r, m) in map.iter_mut().enumerate() {
                *m = r;
            }
            // SAFETY: `avx2` is set only when the processor has AVX2; `b` holds `n × k` entries
            // and the map is the identity.
            unsafe { solve_rows_accumulated_avx2(self.n, &self.a, &self.piv, b, k, &map) };
            return;
        }
        self.solve_rows(b, k);
    }

    /// [`SmallLu::solve_rows_accumulated`] on the rows `rows[0] < rows[1] < …` (`n` of them)
    /// of the row-major `b` with `k` columns, the other rows untouched: the sensitivities' free
    /// rows solved where they lie, without moving them together first. False (nothing done)
    /// without AVX2, above 64 unknowns, or when `rows` is not `n` ascending rows of `b`.
    pub(crate) fn solve_mapped_rows_accumulated(
        &self,
        b: &mut [f64],
        k: usize,
        rows: &[usize],
    ) -> bool {
        let ascending = rows.windows(2).all(|w| w[0] < w[1]);
        let within = rows.last().is_none_or(|&r| (r + 1) * k <= b.len());
        #[cfg(target_arch = "x86_64")]
        if self.avx2 && self.n <= 64 && rows.len() == self.n && ascending && within {
            // SAFETY: `avx2` is set only when the processor has AVX2; every mapped row is a
            // distinct row of `b`.
            unsafe { solve_rows_accumulated_avx2(self.n, &self.a, &self.piv, b, k, rows) };
            return true;
        }
        let _ = (ascending, within);
        false
    }

    /// Solves `Aᵀ x = b` in place: `Uᵀ y = b`, `Lᵀ w = y`, `x = Pᵀ w`.
    pub(crate) fn solve_transpose(&self, b: &mut [f64]) {
        let n = self.n;
        let a = &self.a;
        for k in 0..n {
            let col = &a[k * n..k * n + k];
            let dot: f64 = col.iter().zip(&b[..k]).map(|(u, y)| u * y).sum();
            b[k] = (b[k] - dot) / a[k * n + k];
        }
        for k in (0..n).rev() {
            let col = &a[k * n + k + 1..(k + 1) * n];
            let dot: f64 = col.iter().zip(&b[k + 1..]).map(|(l, w)| l * w).sum();
            b[k] -= dot;
        }
        for (k, &p) in self.piv.iter().enumerate().rev() {
            b.swap(k, p);
        }
    }
}

/// `(lo, hi)` widened by `|d|`: bitwise `(lo.min(|d|), hi.max(|d|))` when neither `lo` nor
/// `hi` is NaN (a pivot-ratio fold from `(∞, +0)`): a NaN `|d|` leaves both as `f64::min` and
/// `f64::max` do, and a magnitude is never `−0`, so equal operands have the same bits. One
/// `minsd` and one `maxsd`, without `f64::min`/`max`'s NaN tests on the fold's serial chain.
#[inline(always)]
pub(crate) fn magnitude_range((lo, hi): (f64, f64), d: f64) -> (f64, f64) {
    let m = d.abs();
    (if m < lo { m } else { lo }, if m > hi { m } else { hi })
}

/// Right-looking elimination with partial pivoting (LAPACK's `getf2`), the update of a column
/// skipped when its pivot-row entry is zero. A zero pivot column is left unreduced.
#[inline(always)]
fn eliminate_with<L: Lanes>(n: usize, a: &mut [f64], piv: &mut [usize]) {
    for k in 0..n {
        let p = k + L::first_largest_magnitude(&a[k * n + k..(k + 1) * n]);
        piv[k] = p;
        if p != k {
            for col in a.chunks_exact_mut(n) {
                col.swap(k, p);
            }
        }
        let pivot = a[k * n + k];
        if pivot == 0.0 {
            continue;
        }
        let (head, tail) = a.split_at_mut((k + 1) * n);
        let lk = &mut head[k * n + k + 1..(k + 1) * n];
        L::div(lk, pivot);
        for col in tail.chunks_exact_mut(n) {
            let akj = col[k];
            if akj == 0.0 {
                continue;
            }
            L::sub_scaled(&mut col[k + 1..], lk, akj);
        }
    }
}

/// Row interchanges, then `L y = P b` and `U x = y` by columns, a column skipped where its
/// entry of the right-hand side is zero.
#[inline(always)]
fn solve_with<L: Lanes>(n: usize, a: &[f64], piv: &[usize], b: &mut [f64]) {
    for (k, &p) in piv.iter().enumerate() {
        b.swap(k, p);
    }
    substitute_with::<L>(n, a, b);
}

/// `L y = b` and `U x = y` by columns on `b = P c` (interchanged already), a column skipped
/// where its entry of the right-hand side is zero.
#[inline(always)]
fn substitute_with<L: Lanes>(n: usize, a: &[f64], b: &mut [f64]) {
    forward_with::<L>(n, a, b);
    backward_with::<L>(n, a, b, |_, _| {});
}

/// `L y = b` by columns on the first `n` entries of `x`, a column skipped where `y_k` is zero.
/// Indexed without bounds checks after one check of the lengths (the per-column checks and
/// index arithmetic were a fifth of a desk solve's instructions). The next entry `y_{k+1}`, the
/// only one the next step waits for, is updated first and carried in a register; the rest of
/// the column in vectors aligned to its end, so that each load lies within one store of the
/// step before (`docs/latency.md`, branch wip-lu). Every entry gets the same operations in the
/// same order as in the plain column loop.
#[inline(always)]
fn forward_with<L: Lanes>(n: usize, a: &[f64], x: &mut [f64]) {
    assert!(
        x.len() >= n && a.len() >= n * n,
        "an n × n factor and n entries"
    );
    if n == 0 {
        return;
    }
    // SAFETY: `k < n ≤ x.len()`, `k + 1 < n` where it is read, and column `k` below the
    // diagonal, `k n + k + 1 .. (k + 1) n`, lies within `a`'s `n²` entries.
    unsafe {
        let mut yk = *x.get_unchecked(0);
        for k in 0..n {
            *x.get_unchecked_mut(k) = yk;
            if k + 1 == n {
                break;
            }
            let next = *x.get_unchecked(k + 1);
            if yk != 0.0 {
                let l = a.get_unchecked(k * n + k + 1..(k + 1) * n);
                let updated = next - *l.get_unchecked(0) * yk;
                L::sub_scaled_from_end(x.get_unchecked_mut(k + 2..n), l.get_unchecked(1..), yk);
                yk = updated;
            } else {
                yk = next;
            }
        }
    }
}

/// `U x = y` by columns on the first `n` entries of `x`, `done(k, x_k)` called as each `x_k` is
/// final, a column skipped where `x_k` is zero. Indexed as [`forward_with`], and likewise the
/// next entry `w_{k−1}`, which the next division waits for, updated first and carried in a
/// register (the rest in vectors from the start, whose boundaries the steps share).
#[inline(always)]
fn backward_with<L: Lanes>(n: usize, a: &[f64], x: &mut [f64], mut done: impl FnMut(usize, f64)) {
    assert!(
        x.len() >= n && a.len() >= n * n,
        "an n × n factor and n entries"
    );
    if n == 0 {
        return;
    }
    // SAFETY: `k < n ≤ x.len()`, `k ≥ 1` where `k − 1` is read, and column `k` on and above the
    // diagonal, `k n ..= k n + k`, lies within `a`'s `n²` entries.
    unsafe {
        let mut wk = *x.get_unchecked(n - 1);
        for k in (0..n).rev() {
            let xk = wk / *a.get_unchecked(k * n + k);
            *x.get_unchecked_mut(k) = xk;
            done(k, xk);
            if k == 0 {
                break;
            }
            let prev = *x.get_unchecked(k - 1);
            if xk != 0.0 {
                let u = a.get_unchecked(k * n..k * n + k);
                wk = prev - *u.get_unchecked(k - 1) * xk;
                L::sub_scaled(x.get_unchecked_mut(..k - 1), u.get_unchecked(..k - 1), xk);
            } else {
                wk = prev;
            }
        }
    }
}

/// [`solve_with`] on `c_i = b[rows[i]]`: `P c` gathered into `work` by `order`
/// ([`SmallLu::row_order`]), `L y = P c` and `U x = y` by columns (the same loops), each `x_k`
/// stored to `b[rows[k]]` as the back substitution finishes it.
#[inline(always)]
fn solve_mapped_with<L: Lanes>(
    n: usize,
    a: &[f64],
    b: &mut [f64],
    order: &[usize],
    rows: &[usize],
    work: &mut [f64],
) {
    let (work, rows) = (&mut work[..n], &rows[..n]);
    for (w, &i) in work.iter_mut().zip(&order[..n]) {
        *w = b[i];
    }
    forward_with::<L>(n, a, work);
    backward_with::<L>(n, a, work, |k, xk| b[rows[k]] = xk);
}

/// [`solve_with`] for the `k` columns of a row-major `n × k` matrix, by whole rows.
#[inline(always)]
fn solve_rows_with<L: Lanes>(n: usize, a: &[f64], piv: &[usize], b: &mut [f64], k: usize) {
    for (r, &p) in piv.iter().enumerate() {
        if p != r {
            for c in 0..k {
                b.swap(r * k + c, p * k + c);
            }
        }
    }
    for r in 0..n {
        let (head, tail) = b.split_at_mut((r + 1) * k);
        let row = &head[r * k..];
        if row.iter().all(|v| *v == 0.0) {
            continue;
        }
        for (l, below) in a[r * n + r + 1..(r + 1) * n]
            .iter()
            .zip(tail.chunks_exact_mut(k))
        {
            if *l != 0.0 {
                L::sub_scaled(below, row, *l);
            }
        }
    }
    for r in (0..n).rev() {
        let (head, tail) = b.split_at_mut(r * k);
        let row = &mut tail[..k];
        L::div(row, a[r * n + r]);
        for (u, above) in a[r * n..r * n + r].iter().zip(head.chunks_exact_mut(k)) {
            if *u != 0.0 {
                L::sub_scaled(above, row, *u);
            }
        }
    }
}

// The same loops compiled for AVX2, entered only when the processor has it (`SmallLu::avx2`).

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn eliminate_avx2(n: usize, a: &mut [f64], piv: &mut [usize]) {
    eliminate_with::<Avx2>(n, a, piv);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn solve_avx2(n: usize, a: &[f64], piv: &[usize], b: &mut [f64]) {
    solve_with::<Avx2>(n, a, piv, b);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn substitute_avx2(n: usize, a: &[f64], b: &mut [f64]) {
    substitute_with::<Avx2>(n, a, b);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn solve_mapped_avx2(
    n: usize,
    a: &[f64],
    b: &mut [f64],
    order: &[usize],
    rows: &[usize],
    work: &mut [f64],
) {
    solve_mapped_with::<Avx2>(n, a, b, order, rows, work);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn solve_rows_avx2(n: usize, a: &[f64], piv: &[usize], b: &mut [f64], k: usize) {
    solve_rows_with::<Avx2>(n, a, piv, b, k);
}

/// [`SmallLu::solve_rows_accumulated`] with AVX2 on the rows `map[0..n]` of `b`: the row
/// interchanges, then strips of up to 32 columns (eight registers, the last one holding the
/// strip's remaining columns).
///
/// # Safety
/// The processor has AVX2, `n ≤ 64`, `a` holds `n × n` entries, `map` holds at least `n`
/// ascending rows and `b` at least `(map[n − 1] + 1) × k` entries.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn solve_rows_accumulated_avx2(
    n: usize,
    a: &[f64],
    piv: &[usize],
    b: &mut [f64],
    k: usize,
    map: &[usize],
) {
    for (r, &p) in piv.iter().enumerate() {
        if p != r {
            // `p > r`, so `map[p] > map[r]`: row `map[r]` is in the first half, row `map[p]`
            // starts the second.
            let (head, tail) = b.split_at_mut(map[p] * k);
            head[map[r] * k..(map[r] + 1) * k].swap_with_slice(&mut tail[..k]);
        }
    }
    let mut c0 = 0;
    while c0 < k {
        let width = (k - c0).min(32);
        // SAFETY: as the caller's; columns `c0..c0 + width` are within every row.
        unsafe {
            // The last register's lanes as a constant: two or one of them by 128-bit or
            // scalar loads and stores, which forward to the next row's loads (a masked
            // store does not), four by whole ones; three masked.
            let tail = width - 4 * (width.div_ceil(4) - 1);
            macro_rules! strip {
                ($($w:literal)*) => {
                    match (width.div_ceil(4), tail) {
                        $(
                            ($w, 4) => accumulated_strip::<$w, 4>(n, a, b, k, map, c0, width),
                            ($w, 2) => accumulated_strip::<$w, 2>(n, a, b, k, map, c0, width),
                            ($w, 1) => accumulated_strip::<$w, 1>(n, a, b, k, map, c0, width),
                            ($w, _) => accumulated_strip::<$w, 0>(n, a, b, k, map, c0, width),
                        )*
                        _ => accumulated_strip::<1, 0>(n, a, b, k, map, c0, width),
                    }
                };
            }
            strip!(8 7 6 5 4 3 2);
        }
        c0 += width;
    }
}

/// The forward and backward solves of the columns `c0..c0 + width` (`W` registers, the last
/// one holding `width − 4 (W − 1)` lanes) of the row-major `b`, interchanged already. The last
/// register moves by whole loads and stores when `T = 4`, by 128-bit ones when `T = 2`, by
/// scalar ones when `T = 1` (its other lanes 0), masked when `T = 0` (a masked store does not
/// forward to the next row's loads; `docs/latency.md`, branch wip-sens5): the same lanes get
/// the same operations whichever way.
///
/// # Safety
/// As [`solve_rows_accumulated_avx2`], with `4 (W − 1) < width ≤ 4 W`, `c0 + width ≤ k`, and
/// `T` 0 or `width − 4 (W − 1)`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn accumulated_strip<const W: usize, const T: usize>(
    n: usize,
    a: &[f64],
    b: &mut [f64],
    k: usize,
    map: &[usize],
    c0: usize,
    width: usize,
) {
    use std::arch::x86_64::*;
    let lanes = (width - 4 * (W - 1)) as i64;
    let last = _mm256_set_epi64x(
        -((lanes > 3) as i64),
        -((lanes > 2) as i64),
        -((lanes > 1) as i64),
        -1,
    );
    let (ap, bp) = (a.as_ptr(), b.as_mut_ptr());
    // SAFETY: rows `map[r]`, `r < n`, of `b`, columns `c0 + 4v + lane < c0 + width ≤ k` (the
    // masked lanes are neither read nor written); factor entries `j n + r < n²`.
    unsafe {
        // The last register: `T` lanes (0: masked, whatever the width), the others 0.
        let tail_load = |p: *const f64| match T {
            4 => _mm256_loadu_pd(p),
            2 => _mm256_zextpd128_pd256(_mm_loadu_pd(p)),
            1 => _mm256_zextpd128_pd256(_mm_load_sd(p)),
            _ => _mm256_maskload_pd(p, last),
        };
        let tail_store = |p: *mut f64, x: __m256d| match T {
            4 => _mm256_storeu_pd(p, x),
            2 => _mm_storeu_pd(p, _mm256_castpd256_pd128(x)),
            1 => _mm_store_sd(p, _mm256_castpd256_pd128(x)),
            _ => _mm256_maskstore_pd(p, last, x),
        };
        let load = |row: *const f64, acc: &mut [__m256d; W]| {
            for (v, x) in acc.iter_mut().enumerate().take(W - 1) {
                *x = _mm256_loadu_pd(row.add(4 * v));
            }
            acc[W - 1] = tail_load(row.add(4 * (W - 1)));
        };
        // acc −= row · s, each product rounded before the subtraction (as `Lanes::sub_scaled`).
        let sub_scaled = |acc: &mut [__m256d; W], row: *const f64, s: f64| {
            let s4 = _mm256_set1_pd(s);
            for (v, x) in acc.iter_mut().enumerate().take(W - 1) {
                *x = _mm256_sub_pd(*x, _mm256_mul_pd(_mm256_loadu_pd(row.add(4 * v)), s4));
            }
            let y = tail_load(row.add(4 * (W - 1)));
            acc[W - 1] = _mm256_sub_pd(acc[W - 1], _mm256_mul_pd(y, s4));
        };
        let store = |row: *mut f64, acc: &[__m256d; W]| {
            for (v, x) in acc.iter().enumerate().take(W - 1) {
                _mm256_storeu_pd(row.add(4 * v), *x);
            }
            tail_store(row.add(4 * (W - 1)), acc[W - 1]);
        };
        let mut acc = [_mm256_setzero_pd(); W];
        // Bit `j`: row `j` of `L⁻¹ P b` has a nonzero (or NaN) entry in the strip.
        let mut nonzero = 0u64;
        for r in 0..n {
            let row = bp.add(map[r] * k + c0);
            load(row, &mut acc);
            for j in 0..r {
                let l = *ap.add(j * n + r);
                if l != 0.0 && (nonzero >> j) & 1 != 0 {
                    sub_scaled(&mut acc, bp.add(map[j] * k + c0), l);
                }
            }
            store(row, &acc);
            let zero = _mm256_setzero_pd();
            let mut any = _mm256_cmp_pd::<_CMP_NEQ_UQ>(acc[0], zero);
            for x in acc.iter().skip(1) {
                any = _mm256_or_pd(any, _mm256_cmp_pd::<_CMP_NEQ_UQ>(*x, zero));
            }
            if _mm256_movemask_pd(any) != 0 {
                nonzero |= 1 << r;
            }
        }
        for r in (0..n).rev() {
            let row = bp.add(map[r] * k + c0);
            load(row, &mut acc);
            for j in (r + 1..n).rev() {
                let u = *ap.add(j * n + r);
                if u != 0.0 {
                    sub_scaled(&mut acc, bp.add(map[j] * k + c0), u);
                }
            }
            let d4 = _mm256_set1_pd(*ap.add(r * n + r));
            for x in acc.iter_mut() {
                *x = _mm256_div_pd(*x, d4);
            }
            store(row, &acc);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic dense matrix with entries in [-1, 1] and a third of them zero.
    fn matrix(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed;
        (0..n * n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let u = (s >> 11) as f64 / (1u64 << 53) as f64;
                if u < 0.33 { 0.0 } else { 2.0 * u - 1.0 }
            })
            .collect()
    }

    fn mul(a: &[f64], x: &[f64], n: usize, transpose: bool) -> Vec<f64> {
        (0..n)
            .map(|i| {
                (0..n)
                    .map(|j| {
                        let aij = if transpose {
                            a[i * n + j]
                        } else {
                            a[j * n + i]
                        };
                        aij * x[j]
                    })
                    .sum()
            })
            .collect()
    }

    #[test]
    fn solves_and_transposed_solves_reproduce_the_right_hand_side() {
        for (n, seed) in [(1, 1), (2, 2), (7, 3), (31, 4), (64, 5)] {
            let a = matrix(n, seed);
            let mut lu = SmallLu::new(n);
            lu.factor(&a);
            let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin() + 0.5).collect();
            for transpose in [false, true] {
                let mut b = mul(&a, &x, n, transpose);
                if transpose {
                    lu.solve_transpose(&mut b);
                } else {
                    lu.solve(&mut b);
                }
                let err = b
                    .iter()
                    .zip(&x)
                    .map(|(u, v)| (u - v).abs())
                    .fold(0.0, f64::max);
                assert!(
                    err < 1e-10,
                    "n = {n}, transpose = {transpose}: error {err:.2e}"
                );
            }
            // Three right-hand sides as the rows of a row-major matrix.
            let b = mul(&a, &x, n, false);
            let mut rows: Vec<f64> = b.iter().flat_map(|v| [*v, 2.0 * v, -v]).collect();
            lu.solve_rows(&mut rows, 3);
            for (i, v) in x.iter().enumerate() {
                for (c, f) in [1.0, 2.0, -1.0].iter().enumerate() {
                    let err = (rows[i * 3 + c] - f * v).abs();
                    assert!(err < 1e-10, "n = {n}, rows: error {err:.2e}");
                }
            }
        }
    }

    /// The textbook elimination without skipping zero multipliers, for comparison.
    fn reference_factors(a: &[f64], n: usize) -> (Vec<f64>, Vec<usize>) {
        let mut a = a.to_vec();
        let mut piv = vec![0; n];
        for k in 0..n {
            let mut p = k;
            for i in k + 1..n {
                if a[k * n + i].abs() > a[k * n + p].abs() {
                    p = i;
                }
            }
            piv[k] = p;
            for j in 0..n {
                a.swap(j * n + k, j * n + p);
            }
            let pivot = a[k * n + k];
            if pivot == 0.0 {
                continue;
            }
            for i in k + 1..n {
                a[k * n + i] /= pivot;
            }
            for j in k + 1..n {
                for i in k + 1..n {
                    a[j * n + i] -= a[k * n + i] * a[j * n + k];
                }
            }
        }
        (a, piv)
    }

    /// Skipping the columns whose pivot-row entry is zero (a step problem's Jacobian is a third
    /// full) changes no factor: the same operations in the same order on every other entry.
    #[test]
    fn skipped_zero_updates_give_the_factors_of_the_full_elimination() {
        for (n, seed, keep) in [(7, 3, 0.2), (31, 4, 0.15), (31, 6, 0.4), (48, 5, 0.1)] {
            // Mostly zero, with a diagonal that does not dominate, so that rows interchange.
            let mut s: u64 = seed;
            let a: Vec<f64> = (0..n * n)
                .map(|k| {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    let u = (s >> 11) as f64 / (1u64 << 53) as f64;
                    let diag = k % (n + 1) == 0;
                    if diag || u < keep {
                        2.0 * u - 1.0 + 0.1
                    } else {
                        0.0
                    }
                })
                .collect();
            let mut lu = SmallLu::new(n);
            lu.factor(&a);
            let (factors, piv) = reference_factors(&a, n);
            assert_eq!(lu.piv, piv, "n = {n}");
            for (x, y) in lu.factors().iter().zip(&factors) {
                assert!(x == y, "n = {n}: {x} vs {y}");
            }
        }
    }

    /// The pivot-ratio fold by plain comparisons is bitwise `f64::min`/`max`'s, NaN pivots
    /// passed over, and `pivots` is the diagonal.
    #[test]
    fn magnitude_range_is_the_min_max_fold() {
        let values = [
            1.0,
            -0.0,
            0.0,
            f64::NAN,
            -f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MIN_POSITIVE / 4.0,
            -3.5e300,
            2.0,
            -2.0,
        ];
        let bits = |(lo, hi): (f64, f64)| (lo.to_bits(), hi.to_bits());
        for start in 0..values.len() {
            for len in 0..=values.len() {
                let seq: Vec<f64> = (0..len)
                    .map(|i| values[(start + 3 * i) % values.len()])
                    .collect();
                let plain = seq.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), d| {
                    (lo.min(d.abs()), hi.max(d.abs()))
                });
                let fast = seq
                    .iter()
                    .copied()
                    .fold((f64::INFINITY, 0.0), magnitude_range);
                assert_eq!(bits(fast), bits(plain), "{seq:?}");
            }
        }
        for n in [0, 1, 2, 7, 31] {
            let a = matrix(n, n as u64 + 11);
            let mut lu = SmallLu::new(n);
            lu.factor(&a);
            let diagonal: Vec<f64> = (0..n).map(|i| lu.a[i * n + i]).collect();
            assert_eq!(lu.pivots().collect::<Vec<_>>(), diagonal);
        }
    }

    /// The substitutions (the next entry carried in a register, vectors from the end or the
    /// start) give bitwise the plain column loops' solution: interchanges, then `L y = P b`
    /// and `U x = y` by columns, a column skipped where its entry is zero.
    #[test]
    fn substitutions_are_bitwise_the_plain_column_loops() {
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for n in 0..=40 {
            for (seed, keep) in [(3, 0.35), (6, 0.15), (7, 1.0)] {
                let a = awkward_matrix(n, seed * 1000 + n as u64, keep);
                for avx2 in [false, avx2_available()] {
                    let mut lu = SmallLu::new(n);
                    lu.avx2 = avx2;
                    lu.factor(&a);
                    let late: Vec<f64> = (0..n)
                        .map(|i| match i % 4 {
                            0 => -0.0,
                            1 if i < n / 2 => 0.0,
                            _ => 1.0 - 0.1 * i as f64,
                        })
                        .collect();
                    for b in [spread_rhs(n), unit_rhs(n), late] {
                        let mut reference = b.clone();
                        for (k, &p) in lu.piv.iter().enumerate() {
                            reference.swap(k, p);
                        }
                        let f = &lu.a;
                        for k in 0..n {
                            let yk = reference[k];
                            if yk != 0.0 {
                                for i in k + 1..n {
                                    reference[i] -= f[k * n + i] * yk;
                                }
                            }
                        }
                        for k in (0..n).rev() {
                            reference[k] /= f[k * n + k];
                            let xk = reference[k];
                            if xk != 0.0 {
                                for i in 0..k {
                                    reference[i] -= f[k * n + i] * xk;
                                }
                            }
                        }
                        let mut x = b.clone();
                        lu.solve(&mut x);
                        assert_eq!(bits(&x), bits(&reference), "n = {n}, seed {seed}, {avx2}");
                    }
                }
            }
        }
    }

    #[test]
    fn pivoting_takes_the_largest_entry_of_the_column() {
        // [[1, 2], [3, 4]] column-major: the first pivot is 3 (row 1).
        let mut lu = SmallLu::new(2);
        lu.factor(&[1.0, 3.0, 2.0, 4.0]);
        assert_eq!(lu.piv, vec![1, 1]);
        let d: Vec<f64> = lu.pivots().collect();
        assert_eq!(d[0], 3.0);
        assert!((d[1] - (2.0 - 4.0 / 3.0)).abs() < 1e-15);
    }

    #[test]
    fn a_zero_column_leaves_a_zero_pivot() {
        let mut lu = SmallLu::new(2);
        lu.factor(&[0.0, 0.0, 1.0, 2.0]);
        assert!(lu.pivots().any(|d| d == 0.0));
    }

    /// A matrix with entries in [-1, 1], `1 − keep` of them zero, some columns zero or repeated
    /// (singular, zero pivots) and some entries tiny or huge (row interchanges, fill-in).
    fn awkward_matrix(n: usize, seed: u64, keep: f64) -> Vec<f64> {
        let mut s = seed;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut a: Vec<f64> = (0..n * n)
            .map(|_| {
                let u = next();
                if u >= keep {
                    return 0.0;
                }
                let v = 2.0 * next() - 1.0;
                match (next() * 10.0) as u32 {
                    0 => v * 1e-9,
                    1 => v * 1e7,
                    _ => v,
                }
            })
            .collect();
        if n > 3 && seed.is_multiple_of(3) {
            // A zero column and a repeated one.
            let (z, r) = ((seed as usize) % n, (seed as usize + 1) % n);
            a[z * n..(z + 1) * n].fill(0.0);
            let src = a[((r + 1) % n) * n..((r + 1) % n + 1) * n].to_vec();
            a[r * n..(r + 1) * n].copy_from_slice(&src);
        }
        a
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The AVX2 loops give bitwise the factors, interchanges and solutions of the portable ones
    /// (the same operations on each entry in the same order, no fused multiply-add), on regular,
    /// singular and zero-pivot matrices of every size the kernel serves.
    #[test]
    fn avx2_loops_give_bitwise_the_portable_results() {
        if !avx2_available() {
            eprintln!("no AVX2 on this processor: only the portable loops run");
            return;
        }
        let mut cases = 0;
        for n in 1..=48 {
            for (seed, keep) in [(3, 0.35), (4, 0.8), (6, 0.15), (7, 1.0)] {
                let a = awkward_matrix(n, seed * 1000 + n as u64, keep);
                let mut fast = SmallLu::new(n);
                let mut plain = SmallLu::new(n);
                plain.avx2 = false;
                assert!(fast.avx2);
                fast.factor(&a);
                plain.factor(&a);
                assert_eq!(fast.piv, plain.piv, "n = {n}, seed {seed}");
                assert_eq!(bits(&fast.a), bits(&plain.a), "n = {n}, seed {seed}");
                // Zeros spread, a unit vector, zeros at the start (the substitutions skip the
                // columns of zero entries).
                let (rhs, unit) = (spread_rhs(n), unit_rhs(n));
                let late: Vec<f64> = (0..n)
                    .map(|i| if i < n / 3 { 0.0 } else { 1.0 - 0.1 * i as f64 })
                    .collect();
                let identity: Vec<usize> = (0..n).collect();
                let mut order = vec![0; n];
                fast.row_order(&identity, &mut order);
                for b in [&rhs, &unit, &late] {
                    let (mut x, mut y) = (b.clone(), b.clone());
                    fast.solve(&mut x);
                    plain.solve(&mut y);
                    assert_eq!(bits(&x), bits(&y), "solve, n = {n}, seed {seed}");
                    // Gathered in the interchanges' order, solved without them: the same bits
                    // with both loops.
                    let gathered: Vec<f64> = order.iter().map(|&r| b[r]).collect();
                    let (mut u, mut v) = (gathered.clone(), gathered);
                    fast.solve_interchanged(&mut u);
                    plain.solve_interchanged(&mut v);
                    assert_eq!(bits(&u), bits(&y), "interchanged, n = {n}, seed {seed}");
                    assert_eq!(bits(&v), bits(&y), "interchanged, n = {n}, seed {seed}");
                }
                for k in [1, 3, 4, 5, 8, 9, 16, 30, 32] {
                    let rows: Vec<f64> = (0..n * k)
                        .map(|i| {
                            if i % 7 == 2 {
                                0.0
                            } else {
                                (i as f64 * 0.3).sin()
                            }
                        })
                        .collect();
                    let (mut x, mut y) = (rows.clone(), rows.clone());
                    let mut z = rows.clone();
                    fast.solve_rows(&mut x, k);
                    plain.solve_rows(&mut y, k);
                    fast.solve_rows_accumulated(&mut z, k);
                    assert_eq!(bits(&x), bits(&y), "rows, n = {n}, k = {k}, seed {seed}");
                    assert_eq!(
                        bits(&z),
                        bits(&y),
                        "accumulated, n = {n}, k = {k}, seed {seed}"
                    );
                    // The same rows spread out (every third row of a taller matrix, the
                    // others marked with NaN): the same bits there, the others untouched.
                    let map: Vec<usize> = (0..n).map(|r| 3 * r + 1).collect();
                    let mut spread = vec![f64::NAN; (3 * n + 1) * k];
                    for (r, &m) in map.iter().enumerate() {
                        spread[m * k..(m + 1) * k].copy_from_slice(&rows[r * k..(r + 1) * k]);
                    }
                    assert!(fast.solve_mapped_rows_accumulated(&mut spread, k, &map));
                    for (i, row) in spread.chunks_exact(k).enumerate() {
                        match map.iter().position(|&m| m == i) {
                            Some(r) => assert_eq!(bits(row), bits(&y[r * k..(r + 1) * k])),
                            None => assert!(row.iter().all(|v| v.is_nan())),
                        }
                    }
                }
                cases += 1;
            }
        }
        assert_eq!(cases, 48 * 4);
    }

    /// A right-hand side of size `n` with a zero at every fourth entry (from the second).
    fn spread_rhs(n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| {
                if i % 4 == 1 {
                    0.0
                } else {
                    (i as f64 * 0.7).cos()
                }
            })
            .collect()
    }

    /// The unit vector of size `n` at `n / 2`.
    fn unit_rhs(n: usize) -> Vec<f64> {
        (0..n).map(|i| f64::from(u8::from(i == n / 2))).collect()
    }

    /// The solve on mapped entries (the right-hand side gathered in the order of the
    /// interchanges, the solution scattered by the back substitution) gives bitwise
    /// [`SmallLu::solve`]'s solution of the gathered entries and leaves the other entries
    /// alone, portable and AVX2, on regular, singular and zero-pivot matrices of sizes 1–40,
    /// with right-hand sides whose zeros the substitutions skip. Also: the storage cleared
    /// holds `+0` everywhere.
    #[test]
    fn mapped_solves_give_bitwise_the_solves_of_the_gathered_entries() {
        let mut interchanged = 0;
        for n in 1..=40 {
            for (seed, keep) in [(3, 0.35), (4, 0.8), (6, 0.15), (7, 1.0)] {
                let a = awkward_matrix(n, seed * 100 + n as u64, keep);
                // Every other entry of a vector of `2 n + 1`, one in three shifted by one.
                let rows: Vec<usize> = (0..n).map(|r| 2 * r + usize::from(r % 3 == 0)).collect();
                for avx2 in [false, avx2_available()] {
                    let mut lu = SmallLu::new(n);
                    lu.avx2 = avx2;
                    lu.factor(&a);
                    interchanged += lu.piv.iter().enumerate().filter(|(k, p)| k != *p).count();
                    let mut order = vec![0; n];
                    lu.row_order(&rows, &mut order);
                    let (spread, unit) = (spread_rhs(n), unit_rhs(n));
                    for c in [&spread, &unit] {
                        let mut expected = c.clone();
                        lu.solve(&mut expected);
                        let mut b: Vec<f64> = (0..2 * n + 1).map(|i| 100.0 + i as f64).collect();
                        for (&i, &v) in rows.iter().zip(c.iter()) {
                            b[i] = v;
                        }
                        let mut work = vec![f64::NAN; n];
                        lu.solve_mapped(&mut b, &order, &rows, &mut work);
                        for (i, v) in b.iter().enumerate() {
                            match rows.iter().position(|&r| r == i) {
                                Some(k) => assert_eq!(
                                    v.to_bits(),
                                    expected[k].to_bits(),
                                    "n = {n}, seed {seed}, AVX2 {avx2}, entry {k}"
                                ),
                                None => assert_eq!(*v, 100.0 + i as f64),
                            }
                        }
                    }
                    lu.clear_storage();
                    assert!(lu.storage_mut().iter().all(|v| v.to_bits() == 0));
                }
            }
        }
        assert!(interchanged > 0);
    }

    /// Small integers (exact cancellations: zero pivots, zero pivot-row entries before and
    /// after an update), `−0` entries, NaN and infinities, zero and repeated columns, sizes
    /// 1–40: the AVX2 loops give bitwise the factors and interchanges of the portable ones.
    /// The cases are counted from the factors and must all occur: a zero pivot, a `−0` that
    /// skips an update, an interchange, NaN factors.
    #[test]
    fn avx2_loops_give_bitwise_the_portable_factors_on_exact_cases() {
        if !avx2_available() {
            eprintln!("no AVX2 on this processor: only the portable loops run");
            return;
        }
        let mut s = 17u64;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            s >> 33
        };
        let mut seen = [0usize; 4];
        for n in 1..=40 {
            for round in 0..12 {
                let mut a: Vec<f64> = (0..n * n)
                    .map(|_| match next() % 10 {
                        0..=3 => 0.0,
                        4 => -0.0,
                        r => r as f64 - 7.0,
                    })
                    .collect();
                if n > 2 {
                    match round % 6 {
                        // A column repeated (a zero pivot where the elimination reaches it).
                        1 | 2 => {
                            let (c, d) = ((next() as usize) % n, (next() as usize) % n);
                            let src = a[d * n..(d + 1) * n].to_vec();
                            a[c * n..(c + 1) * n].copy_from_slice(&src);
                        }
                        3 => {
                            let c = (next() as usize) % n;
                            a[c * n..(c + 1) * n].fill(if round % 2 == 0 { 0.0 } else { -0.0 });
                        }
                        4 => a[(next() as usize) % (n * n)] = f64::NAN,
                        5 => a[(next() as usize) % (n * n)] = f64::INFINITY,
                        _ => {}
                    }
                }
                let mut fast = SmallLu::new(n);
                let mut plain = SmallLu::new(n);
                plain.avx2 = false;
                fast.factor(&a);
                plain.factor(&a);
                assert_eq!(fast.piv, plain.piv, "n = {n}, round {round}");
                assert_eq!(bits(&fast.a), bits(&plain.a), "n = {n}, round {round}");
                let u = |i: usize, j: usize| plain.a[j * n + i];
                seen[0] += (0..n).filter(|&k| u(k, k) == 0.0).count();
                let negative_zero = (-0.0f64).to_bits();
                seen[1] += (0..n)
                    .filter(|&k| u(k, k) != 0.0)
                    .filter(|&k| (k + 1..n).any(|j| u(k, j).to_bits() == negative_zero))
                    .count();
                seen[2] += plain
                    .piv
                    .iter()
                    .enumerate()
                    .filter(|(k, p)| k != *p)
                    .count();
                seen[3] += usize::from(plain.a.iter().any(|x| x.is_nan()));
            }
        }
        assert!(seen.iter().all(|&c| c > 0), "cases not exercised: {seen:?}");
    }
}
