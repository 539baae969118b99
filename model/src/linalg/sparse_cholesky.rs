//! Sparse Cholesky factorisation `P A Pᵀ = L Lᵀ` of a symmetric positive definite matrix in a
//! fixed [`CscPattern`], for the Levenberg–Marquardt matrix `HᵀH + λI` of the Newton backend
//! (`docs/newton.md#cheap-levenberg-marquardt-trials`).
//!
//! The fill-reducing ordering (faer's approximate minimum degree), the elimination tree, the
//! pattern of `L` and, for every row of `L`, where each of its entries is stored are computed
//! once per pattern; a numeric factorisation is then the up-looking algorithm (Davis, *Direct
//! Methods for Sparse Linear Systems*, 2006, §4.7) with no search, sort or allocation: its work
//! is its multiplications. faer's own sparse Cholesky permutes the matrix and walks its
//! structures on every call, which on the 170 unknowns of `025_multi_body` costs five times the
//! arithmetic.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMatRef;
use faer::sparse::linalg::amd;

use super::LinalgError;
use crate::pattern::CscPattern;

/// A pivot `d_k` at or below this fraction of the largest diagonal entry of `A` counts as a
/// failure (the matrix is not numerically positive definite): the ratio of the dense Cholesky of
/// the Levenberg–Marquardt system and of the LU's singularity test
/// ([`super::SINGULAR_PIVOT_RATIO`]).
const PIVOT_RATIO: f64 = super::SINGULAR_PIVOT_RATIO;

/// The symbolic factorisation of one pattern: ordering, gather lists and the structure of `L`.
#[derive(Clone, Debug)]
struct Symbolic {
    n: usize,
    /// `fwd[k]`: the original index of the `k`-th pivot.
    fwd: Vec<usize>,
    /// Per permuted column `k`: the entries of the permuted upper triangle (row `i ≤ k`), as
    /// (`i`, position in the caller's values). Column `k`'s entries are
    /// `upper[upper_ptr[k]..upper_ptr[k + 1]]`.
    upper_ptr: Vec<usize>,
    upper: Vec<(usize, usize)>,
    /// `L` by columns, its diagonal first: `l_ptr[j]` is the diagonal's position, the rest of
    /// the column follows in increasing row order; `l_row` the row of each position.
    l_ptr: Vec<usize>,
    l_row: Vec<usize>,
    /// Per row `k` of `L`: its off-diagonal entries in increasing column order, as (column `i`,
    /// position in `L`). Row `k`'s entries are `row[row_ptr[k]..row_ptr[k + 1]]`.
    row_ptr: Vec<usize>,
    row: Vec<(usize, usize)>,
    /// Multiplications and divisions of one numeric factorisation.
    flops: f64,
}

impl Symbolic {
    /// Ordering and structure of the symmetric `pattern` (both triangles given, as the
    /// [`CscPattern`]s of the Newton backend; an entry is taken from the lower triangle).
    fn analyze(pattern: &CscPattern) -> Result<Self, LinalgError> {
        let n = pattern.dim();
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        let mut fwd = vec![0usize; n];
        let mut inv = vec![0usize; n];
        if n > 0 {
            let sym = SymbolicSparseColMatRef::new_checked(n, n, cp, None, ri);
            let mut mem =
                MemBuffer::try_new(amd::order_maybe_unsorted_scratch::<usize>(n, pattern.nnz()))
                    .map_err(|_| LinalgError::Factorization("out of memory (ordering)".into()))?;
            amd::order_maybe_unsorted(
                &mut fwd,
                &mut inv,
                sym,
                amd::Control::default(),
                MemStack::new(&mut mem),
            )
            .map_err(|e| LinalgError::Factorization(format!("ordering: {e:?}")))?;
        }
        // The permuted upper triangle by columns, from the lower triangle's entries.
        let mut count = vec![0usize; n + 1];
        for j in 0..n {
            for &i in &ri[cp[j]..cp[j + 1]] {
                if i >= j {
                    count[inv[i].max(inv[j]) + 1] += 1;
                }
            }
        }
        for k in 0..n {
            count[k + 1] += count[k];
        }
        let upper_ptr = count.clone();
        let mut upper = vec![(0usize, 0usize); upper_ptr[n]];
        let mut next = count;
        for j in 0..n {
            for (p, &i) in ri[cp[j]..cp[j + 1]].iter().enumerate() {
                if i >= j {
                    let (a, b) = (inv[i], inv[j]);
                    let col = a.max(b);
                    upper[next[col]] = (a.min(b), cp[j] + p);
                    next[col] += 1;
                }
            }
        }
        for k in 0..n {
            upper[upper_ptr[k]..upper_ptr[k + 1]].sort_unstable();
        }
        // Elimination tree (Liu's algorithm with path compression, on the upper triangle).
        const NONE: usize = usize::MAX;
        let mut parent = vec![NONE; n];
        let mut ancestor = vec![NONE; n];
        for k in 0..n {
            for &(i0, _) in &upper[upper_ptr[k]..upper_ptr[k + 1]] {
                let mut i = i0;
                while i != NONE && i < k {
                    let next = ancestor[i];
                    ancestor[i] = k;
                    if next == NONE {
                        parent[i] = k;
                    }
                    i = next;
                }
            }
        }
        // Row patterns of L: the reach of each column's entries in the elimination tree.
        let mut mark = vec![NONE; n];
        let mut rows: Vec<Vec<usize>> = vec![Vec::new(); n];
        let mut col_count = vec![0usize; n];
        for k in 0..n {
            mark[k] = k;
            let mut reach = Vec::new();
            for &(i0, _) in &upper[upper_ptr[k]..upper_ptr[k + 1]] {
                let mut i = i0;
                while i < k && mark[i] != k {
                    reach.push(i);
                    mark[i] = k;
                    i = parent[i];
                }
            }
            // Increasing column order is an order in which L(k, ·) can be solved for: L is
            // lower triangular.
            reach.sort_unstable();
            for &i in &reach {
                col_count[i] += 1;
            }
            rows[k] = reach;
        }
        let mut l_ptr = vec![0usize; n + 1];
        for j in 0..n {
            l_ptr[j + 1] = l_ptr[j] + 1 + col_count[j];
        }
        let mut l_row = vec![0usize; l_ptr[n]];
        let mut fill = vec![0usize; n];
        let mut row_ptr = vec![0usize; n + 1];
        let mut row = Vec::with_capacity(l_ptr[n] - n);
        for k in 0..n {
            l_row[l_ptr[k]] = k;
            for &i in &rows[k] {
                fill[i] += 1;
                let dest = l_ptr[i] + fill[i];
                l_row[dest] = k;
                row.push((i, dest));
            }
            row_ptr[k + 1] = row.len();
        }
        // Per column j with c entries below the diagonal: one square root, c divisions, and
        // c(c+1)/2 multiply-subtracts into later columns.
        let flops = col_count
            .iter()
            .map(|&c| {
                let c = c as f64;
                1.0 + c + 0.5 * c * (c + 1.0)
            })
            .sum();
        l_ptr.truncate(n);
        Ok(Symbolic {
            n,
            fwd,
            upper_ptr,
            upper,
            l_ptr,
            l_row,
            row_ptr,
            row,
            flops,
        })
    }
}

/// Multiplications (and divisions) of the Cholesky factorisation of a matrix with this
/// symmetric pattern (both triangles given) in the approximate-minimum-degree ordering: the
/// measure by which the Newton backend chooses the form of its Levenberg–Marquardt system.
pub fn cholesky_flops(pattern: &CscPattern) -> Result<f64, LinalgError> {
    Symbolic::analyze(pattern).map(|s| s.flops)
}

/// Sparse Cholesky factorisation whose ordering and symbolic analysis are computed once for a
/// pattern and reused for every numeric factorisation with it; nothing is allocated after
/// [`SparseCholesky::analyze`].
#[derive(Clone, Debug)]
pub struct SparseCholesky {
    pattern: CscPattern,
    symbolic: Symbolic,
    /// The values of `L` (positions of [`Symbolic::l_ptr`] and [`Symbolic::l_row`]).
    l: Vec<f64>,
    /// Dense work vector of the numeric factorisation and the solve (zero between uses).
    x: Vec<f64>,
    factored: bool,
}

impl SparseCholesky {
    /// Ordering and symbolic analysis of the symmetric `pattern` (both triangles given; the
    /// numeric factorisation reads the lower one).
    pub fn analyze(pattern: &CscPattern) -> Result<Self, LinalgError> {
        let symbolic = Symbolic::analyze(pattern)?;
        Ok(SparseCholesky {
            pattern: pattern.clone(),
            l: vec![0.0; symbolic.l_row.len()],
            x: vec![0.0; symbolic.n],
            symbolic,
            factored: false,
        })
    }

    /// The pattern this analysis belongs to.
    pub fn pattern(&self) -> &CscPattern {
        &self.pattern
    }

    /// Multiplications and divisions of one numeric factorisation ([`cholesky_flops`]).
    pub fn flops(&self) -> f64 {
        self.symbolic.flops
    }

    /// Entries of the factor `L`, its diagonal included.
    pub fn factor_len(&self) -> usize {
        self.l.len()
    }

    /// Numeric factorisation of the matrix with this pattern and `values` (its lower triangle
    /// is read). [`LinalgError::Singular`] when a pivot is at most `1e-13` of the largest
    /// diagonal entry (or not finite): the matrix is not numerically positive definite.
    pub fn factor(&mut self, values: &[f64]) -> Result<(), LinalgError> {
        self.factored = false;
        if values.len() != self.pattern.nnz() {
            return Err(LinalgError::Factorization(format!(
                "{} values for a pattern of {}",
                values.len(),
                self.pattern.nnz()
            )));
        }
        let s = &self.symbolic;
        let largest = self
            .pattern
            .diag_pos()
            .iter()
            .map(|&p| values[p])
            .fold(0.0f64, f64::max);
        let floor = PIVOT_RATIO * largest;
        let (l, x) = (&mut self.l, &mut self.x);
        for k in 0..s.n {
            // x = the permuted upper triangle's column k (rows ≤ k).
            for &(i, p) in &s.upper[s.upper_ptr[k]..s.upper_ptr[k + 1]] {
                x[i] = values[p];
            }
            let mut d = x[k];
            x[k] = 0.0;
            // Solve L(0:k, 0:k) l = x for row k of L, column by column.
            for &(i, dest) in &s.row[s.row_ptr[k]..s.row_ptr[k + 1]] {
                let diag = s.l_ptr[i];
                let lki = x[i] / l[diag];
                x[i] = 0.0;
                for p in diag + 1..dest {
                    x[s.l_row[p]] -= l[p] * lki;
                }
                d -= lki * lki;
                l[dest] = lki;
            }
            // NaN fails `d > floor` as well.
            if d.partial_cmp(&floor) != Some(std::cmp::Ordering::Greater) || !d.is_finite() {
                x.fill(0.0);
                return Err(LinalgError::Singular {
                    ratio: d / largest.max(f64::MIN_POSITIVE),
                });
            }
            l[s.l_ptr[k]] = d.sqrt();
        }
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = b` in place with the last factorisation.
    pub fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        let s = &self.symbolic;
        if b.len() != s.n {
            return Err(LinalgError::Factorization(format!(
                "right-hand side of {} for dimension {}",
                b.len(),
                s.n
            )));
        }
        let (l, y) = (&self.l, &mut self.x);
        for (k, &old) in s.fwd.iter().enumerate() {
            y[k] = b[old];
        }
        let end = |j: usize| s.l_ptr.get(j + 1).copied().unwrap_or(l.len());
        // L z = P b.
        for j in 0..s.n {
            let z = y[j] / l[s.l_ptr[j]];
            y[j] = z;
            for p in s.l_ptr[j] + 1..end(j) {
                y[s.l_row[p]] -= l[p] * z;
            }
        }
        // Lᵀ w = z.
        for j in (0..s.n).rev() {
            let mut t = y[j];
            for p in s.l_ptr[j] + 1..end(j) {
                t -= l[p] * y[s.l_row[p]];
            }
            y[j] = t / l[s.l_ptr[j]];
        }
        for (k, &old) in s.fwd.iter().enumerate() {
            b[old] = y[k];
            y[k] = 0.0;
        }
        if b.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(LinalgError::NonFinite)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `A = MᵀM + I` for a sparse non-symmetric `M`, in a pattern with empty and full columns:
    /// the solve matches `A x = b` to 1e-12 (relative); the factor has no more entries than
    /// the dense lower triangle; an indefinite matrix is refused.
    #[test]
    fn solves_a_sparse_positive_definite_system_and_refuses_an_indefinite_one() {
        let n = 40;
        // M: a diagonal, a few scattered entries and one dense row (row 7).
        let m = |i: usize, j: usize| -> f64 {
            if i == j {
                2.0 + (i % 3) as f64
            } else if i == 7 || (i * 7 + j * 11).is_multiple_of(17) {
                ((i * 37 + j * 13) % 23) as f64 / 7.0 - 1.5
            } else {
                0.0
            }
        };
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                let s: f64 = (0..n).map(|k| m(k, i) * m(k, j)).sum();
                a[j * n + i] = s + if i == j { 1.0 } else { 0.0 };
            }
        }
        let columns: Vec<Vec<usize>> = (0..n)
            .map(|j| (0..n).filter(|&i| a[j * n + i] != 0.0).collect())
            .collect();
        let pattern = CscPattern::from_columns(n, columns).unwrap_or_else(|e| panic!("{e}"));
        let mut values = vec![0.0; pattern.nnz()];
        for j in 0..n {
            for p in pattern.col_ptr()[j]..pattern.col_ptr()[j + 1] {
                values[p] = a[j * n + pattern.row_idx()[p]];
            }
        }
        let x: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        let mut b: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| a[j * n + i] * x[j]).sum())
            .collect();
        let mut c = SparseCholesky::analyze(&pattern).unwrap_or_else(|e| panic!("{e}"));
        assert!(c.factor_len() <= n * (n + 1) / 2);
        c.factor(&values).unwrap_or_else(|e| panic!("{e}"));
        c.solve_in_place(&mut b).unwrap_or_else(|e| panic!("{e}"));
        for (u, v) in b.iter().zip(&x) {
            assert!((u - v).abs() <= 1e-12 * (1.0 + v.abs()), "{u} vs {v}");
        }
        // A negative diagonal entry: not positive definite.
        let d = pattern.diag_pos()[3];
        values[d] = -1.0;
        assert!(matches!(
            c.factor(&values),
            Err(LinalgError::Singular { .. })
        ));
        assert_eq!(c.solve_in_place(&mut b), Err(LinalgError::NotFactored));
    }
}
