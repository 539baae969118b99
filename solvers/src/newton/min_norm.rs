//! Minimum-norm least-squares solutions of `H d = b` for a square, possibly singular dense `H`:
//! the generalised Newton step of the semismooth Newton backend when `H` is rank-deficient
//! (`docs/model.md#union`: at the solutions of the union-of-pieces model the impulses and the
//! per-piece ECPs are not unique, so `H` is singular on the whole solution set).
//!
//! A complete orthogonal decomposition, as LAPACK's `xGELSY` computes it (Golub & Van Loan,
//! "Matrix Computations", 4th ed., §5.4.2 and §5.5.2): Householder QR with column pivoting
//! `H P = Q [R₁₁ R₁₂; 0 R₂₂]`, stopped at the numerical rank `r` (the largest remaining column
//! norm below `tol · |R₀₀|`, so `R₂₂` is dropped), then `[R₁₁ R₁₂] = [T 0] Wᵀ` by Householder
//! reflections from the right. The minimum-norm solution of `min ‖H d − b‖` is
//! `d = P W [T⁻¹ (Qᵀ b)₁..r; 0]`.
//!
//! When `H` is nonsingular this is the Newton step; when the system is consistent with a
//! solution set of constant rank (the union model), the iteration `d = −H⁺Φ` is the
//! Gauss–Newton method with the Moore–Penrose inverse, which converges quadratically to a point
//! of the solution set (Ben-Israel, J. Math. Anal. Appl. 15, 1966; Nashed & Chen, Numer. Math.
//! 66, 1993), where Levenberg–Marquardt with a damping floor converges linearly.
//!
//! Written here, like the pivotal solver's basis factorisation, because it needs the numerical
//! rank and the pivot order, and allocates nothing after the first call.

use crate::union_find::{find, union};

/// The decomposition of one matrix and the buffers to solve with it.
#[derive(Debug, Default)]
pub(crate) struct MinNorm {
    n: usize,
    /// Column-major `n × n`: R (and T) on and above the diagonal, the QR reflectors below it,
    /// the right reflectors in columns `r..n` of rows `0..r`.
    a: Vec<f64>,
    /// Scalars of the left (QR) reflectors.
    tau: Vec<f64>,
    /// Scalars of the right reflectors.
    tau_right: Vec<f64>,
    /// Column `k` of `H P` is column `perm[k]` of `H`.
    perm: Vec<usize>,
    /// Partial column norms (current and at the last recomputation).
    norms: Vec<f64>,
    norms_ref: Vec<f64>,
    work: Vec<f64>,
    rank: usize,
    factored: bool,
    /// [`MinNorm::newton_step_by_blocks`]: each unknown's block (the union–find root), the
    /// unknowns in block order, one block's right-hand side, each unknown's index in its block.
    block_of: Vec<usize>,
    order: Vec<usize>,
    rhs: Vec<f64>,
    local: Vec<usize>,
}

impl MinNorm {
    /// Decomposes the column-major `n × n` matrix `h`, treating as zero everything beyond the
    /// first column whose remaining norm is at most `rel_tol` times the largest column norm.
    /// Returns the numerical rank; `None` when `h` holds a non-finite entry.
    pub(crate) fn factor(&mut self, n: usize, h: &[f64], rel_tol: f64) -> Option<usize> {
        self.factored = false;
        if h.len() != n * n || h.iter().any(|v| !v.is_finite()) {
            return None;
        }
        self.n = n;
        self.a.clear();
        self.a.extend_from_slice(h);
        self.tau.clear();
        self.tau.resize(n, 0.0);
        self.tau_right.clear();
        self.tau_right.resize(n, 0.0);
        self.perm.clear();
        self.perm.extend(0..n);
        self.work.clear();
        self.work.resize(n, 0.0);
        self.norms.clear();
        let a = &mut self.a;
        self.norms
            .extend((0..n).map(|j| norm(&a[j * n..(j + 1) * n])));
        self.norms_ref.clone_from(&self.norms);
        let largest = self.norms.iter().copied().fold(0.0, f64::max);
        let threshold = rel_tol * largest;
        let mut rank = n;
        for k in 0..n {
            // Pivot: the remaining column of largest norm.
            let mut p = k;
            for j in k + 1..n {
                if self.norms[j] > self.norms[p] {
                    p = j;
                }
            }
            if self.norms[p] <= threshold {
                rank = k;
                break;
            }
            if p != k {
                for i in 0..n {
                    a.swap(k * n + i, p * n + i);
                }
                self.perm.swap(k, p);
                self.norms.swap(k, p);
                self.norms_ref.swap(k, p);
            }
            // Householder reflector zeroing a[k+1.., k].
            let col = &mut a[k * n..(k + 1) * n];
            let alpha = col[k];
            let xnorm = norm(&col[k + 1..]);
            if xnorm == 0.0 {
                self.tau[k] = 0.0;
            } else {
                let beta = -alpha.signum() * alpha.hypot(xnorm);
                self.tau[k] = (beta - alpha) / beta;
                let scale = 1.0 / (alpha - beta);
                for v in &mut col[k + 1..] {
                    *v *= scale;
                }
                col[k] = beta;
            }
            let tau = self.tau[k];
            // Apply it to the remaining columns and downdate their norms.
            let (head, tail) = a.split_at_mut((k + 1) * n);
            let v = &head[k * n + k + 1..(k + 1) * n];
            if tau != 0.0 {
                dots(v, tail, n, k + 1, &mut self.work);
            }
            for (jj, col) in tail.chunks_exact_mut(n).enumerate() {
                let j = k + 1 + jj;
                let (top, below) = col[k..].split_at_mut(1);
                if tau != 0.0 {
                    let w = tau * (top[0] + self.work[jj]);
                    top[0] -= w;
                    for (x, vi) in below.iter_mut().zip(v) {
                        *x -= w * vi;
                    }
                }
                if self.norms[j] > 0.0 {
                    let t = top[0] / self.norms[j];
                    let t = (1.0 - t * t).max(0.0);
                    let ratio = self.norms[j] / self.norms_ref[j];
                    if t * ratio * ratio <= 1e-8 {
                        // Cancellation: recompute (LAPACK xLAQP2's safeguard).
                        self.norms[j] = norm(below);
                        self.norms_ref[j] = self.norms[j];
                    } else {
                        self.norms[j] *= t.sqrt();
                    }
                }
            }
        }
        // [R₁₁ R₁₂] = [T 0] Wᵀ: reflectors from the right, last row first, each acting on
        // coordinate k and the trailing coordinates r..n.
        if rank < n {
            for k in (0..rank).rev() {
                let alpha = a[k * n + k];
                let mut xnorm = 0.0f64;
                for j in rank..n {
                    xnorm = xnorm.hypot(a[j * n + k]);
                }
                if xnorm == 0.0 {
                    self.tau_right[k] = 0.0;
                    continue;
                }
                let beta = -alpha.signum() * alpha.hypot(xnorm);
                let tau = (beta - alpha) / beta;
                let scale = 1.0 / (alpha - beta);
                for j in rank..n {
                    a[j * n + k] *= scale;
                }
                a[k * n + k] = beta;
                self.tau_right[k] = tau;
                // Rows above k: row ← row − τ (row · v) vᵀ, v = (1 at k, a[k, r..n]).
                for i in 0..k {
                    let mut w = a[k * n + i];
                    for j in rank..n {
                        w += a[j * n + i] * a[j * n + k];
                    }
                    w *= tau;
                    a[k * n + i] -= w;
                    for j in rank..n {
                        a[j * n + i] -= w * a[j * n + k];
                    }
                }
            }
        }
        self.rank = rank;
        self.factored = true;
        Some(rank)
    }

    /// The numerical rank found by the last [`MinNorm::factor`].
    #[cfg(test)]
    pub(crate) fn rank(&self) -> usize {
        self.rank
    }

    /// The minimum-norm Newton step `d = −H⁺Φ` of a sparse `H` (`values` in `pattern`), through
    /// the dense scratch `dense`: decomposes `H` and solves into `d`. Returns `false` when the
    /// decomposition or the solve fails (`d` then unspecified).
    pub(crate) fn newton_step(
        &mut self,
        pattern: &ecp_model::CscPattern,
        values: &[f64],
        dense: &mut [f64],
        phi: &[f64],
        d: &mut [f64],
        rel_tol: f64,
    ) -> bool {
        pattern.to_dense(values, dense);
        if self.factor(phi.len(), dense, rel_tol).is_none() {
            return false;
        }
        for (di, fi) in d.iter_mut().zip(phi) {
            *di = -fi;
        }
        self.solve_in_place(d)
    }

    /// The minimum-norm Newton step of the semismooth Newton backend: on the whole matrix
    /// ([`MinNorm::newton_step`]) up to `NewtonSettings::dense_max` unknowns, as it was measured
    /// there; above it (`by_blocks`) block by block ([`MinNorm::newton_step_by_blocks`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn step(
        &mut self,
        by_blocks: bool,
        pattern: &ecp_model::CscPattern,
        values: &[f64],
        dense: &mut [f64],
        phi: &[f64],
        d: &mut [f64],
        rel_tol: f64,
    ) -> bool {
        if by_blocks {
            self.newton_step_by_blocks(pattern, values, dense, phi, d, rel_tol)
        } else {
            self.newton_step(pattern, values, dense, phi, d, rel_tol)
        }
    }

    /// [`MinNorm::newton_step`] block by block: the unknowns fall into the connected components
    /// of the pattern's graph (bodies that touch neither each other nor a common body), `H` is
    /// block diagonal in them, and the minimum-norm solution of a block-diagonal system is that
    /// of each block (each block's numerical rank relative to its own largest column). On a
    /// problem of several independent bodies this is far cheaper than the whole matrix's
    /// decomposition (`s20270320_129_multi_body`: four blocks of 36 for one of 144, 1/16 of the
    /// work). With one block, [`MinNorm::newton_step`] itself.
    pub(crate) fn newton_step_by_blocks(
        &mut self,
        pattern: &ecp_model::CscPattern,
        values: &[f64],
        dense: &mut [f64],
        phi: &[f64],
        d: &mut [f64],
        rel_tol: f64,
    ) -> bool {
        let n = phi.len();
        let (col_ptr, row_idx) = (pattern.col_ptr(), pattern.row_idx());
        // Union–find over the unknowns, an edge for each stored entry.
        let mut root = std::mem::take(&mut self.block_of);
        root.clear();
        root.extend(0..n);
        for j in 0..n {
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                union(&mut root, i, j);
            }
        }
        for i in 0..n {
            root[i] = find(&mut root, i);
        }
        if root.iter().all(|&r| r == root[0]) {
            self.block_of = root;
            return self.newton_step(pattern, values, dense, phi, d, rel_tol);
        }
        let mut order = std::mem::take(&mut self.order);
        order.clear();
        order.extend(0..n);
        // By block (the smallest unknown of each), in index order within a block.
        order.sort_unstable_by_key(|&i| (root[i], i));
        let mut rhs = std::mem::take(&mut self.rhs);
        let mut local = std::mem::take(&mut self.local);
        local.clear();
        local.resize(n, 0);
        let mut ok = true;
        let mut start = 0;
        while ok && start < n {
            let r = root[order[start]];
            let end = start + order[start..].iter().take_while(|&&i| root[i] == r).count();
            let block = &order[start..end];
            let m = block.len();
            for (k, &i) in block.iter().enumerate() {
                local[i] = k;
            }
            // The block's columns, column-major `m × m` (its entries' rows are in the block).
            let h = &mut dense[..m * m];
            h.fill(0.0);
            for (k, &j) in block.iter().enumerate() {
                for p in col_ptr[j]..col_ptr[j + 1] {
                    h[k * m + local[row_idx[p]]] = values[p];
                }
            }
            rhs.clear();
            rhs.extend(block.iter().map(|&i| -phi[i]));
            ok = self.factor(m, h, rel_tol).is_some() && self.solve_in_place(&mut rhs);
            for (&i, &v) in block.iter().zip(rhs.iter()) {
                d[i] = v;
            }
            start = end;
        }
        self.order = order;
        self.rhs = rhs;
        self.local = local;
        self.block_of = root;
        ok
    }

    /// Overwrites `b` with the minimum-norm least-squares solution of `H d = b`. Returns `false`
    /// (leaving `b` unspecified) without a valid decomposition or when the result is not finite.
    pub(crate) fn solve_in_place(&mut self, b: &mut [f64]) -> bool {
        let (n, r) = (self.n, self.rank);
        if !self.factored || b.len() != n {
            return false;
        }
        let a = &self.a;
        // c = Qᵀ b (only the first r entries matter).
        for k in 0..r {
            let tau = self.tau[k];
            if tau == 0.0 {
                continue;
            }
            let mut w = b[k];
            for i in k + 1..n {
                w += a[k * n + i] * b[i];
            }
            w *= tau;
            b[k] -= w;
            for i in k + 1..n {
                b[i] -= w * a[k * n + i];
            }
        }
        // u = [T⁻¹ c₁..r; 0].
        let u = &mut self.work;
        u.fill(0.0);
        for k in (0..r).rev() {
            let mut s = b[k];
            for j in k + 1..r {
                s -= a[j * n + k] * u[j];
            }
            u[k] = s / a[k * n + k];
        }
        // y = W u = Z_{r−1} ⋯ Z₀ u: apply Z₀ first.
        if r < n {
            for k in 0..r {
                let tau = self.tau_right[k];
                if tau == 0.0 {
                    continue;
                }
                let mut w = u[k];
                for j in r..n {
                    w += a[j * n + k] * u[j];
                }
                w *= tau;
                u[k] -= w;
                for j in r..n {
                    u[j] -= w * a[j * n + k];
                }
            }
        }
        // d = P y.
        for k in 0..n {
            b[self.perm[k]] = u[k];
        }
        b.iter().all(|v| v.is_finite())
    }
}

/// Dot product with four partial sums (lets the compiler use SIMD lanes).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            acc[l] += x[l] * y[l];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// `out[q] = dot(v, column q of cols from row off)` for every column of the column-major
/// `cols` (stride `n`), each summed exactly as [`dot`] sums it (the same partial sums in the
/// same order, so the factorisation is bitwise that of one [`dot`] a column), four columns at
/// a time: one column's four partial sums are a chain of dependent additions that leaves the
/// floating-point units idle, four columns' sums are independent (`docs/newton.md#the-cost-of-a-minimum-norm-step`).
fn dots(v: &[f64], cols: &[f64], n: usize, off: usize, out: &mut [f64]) {
    let m = v.len();
    let full = m - m % 4;
    let count = cols.len() / n;
    let col = |q: usize| &cols[q * n + off..q * n + off + m];
    let mut q = 0;
    while q + 4 <= count {
        let (c0, c1, c2, c3) = (col(q), col(q + 1), col(q + 2), col(q + 3));
        let mut acc = [[0.0f64; 4]; 4];
        for ((((x, y0), y1), y2), y3) in v[..full]
            .chunks_exact(4)
            .zip(c0[..full].chunks_exact(4))
            .zip(c1[..full].chunks_exact(4))
            .zip(c2[..full].chunks_exact(4))
            .zip(c3[..full].chunks_exact(4))
        {
            for l in 0..4 {
                acc[0][l] += x[l] * y0[l];
                acc[1][l] += x[l] * y1[l];
                acc[2][l] += x[l] * y2[l];
                acc[3][l] += x[l] * y3[l];
            }
        }
        for (p, c) in [c0, c1, c2, c3].into_iter().enumerate() {
            // The remainder as `dot` adds it.
            let tail: f64 = v[full..].iter().zip(&c[full..]).map(|(x, y)| x * y).sum();
            let a = acc[p];
            out[q + p] = (a[0] + a[1]) + (a[2] + a[3]) + tail;
        }
        q += 4;
    }
    for q in q..count {
        out[q] = dot(v, col(q));
    }
}

fn norm(v: &[f64]) -> f64 {
    // Scaled sum of squares: the columns of H span many orders of magnitude.
    let m = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if m == 0.0 || !m.is_finite() {
        return m;
    }
    m * v.iter().map(|x| (x / m) * (x / m)).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn matvec(n: usize, a: &[f64], x: &[f64]) -> Vec<f64> {
        (0..n)
            .map(|i| (0..n).map(|j| a[j * n + i] * x[j]).sum())
            .collect()
    }

    #[test]
    fn nonsingular_system_is_solved_exactly() {
        // Column-major 3 × 3.
        let a = [4.0, 1.0, 0.5, -2.0, 3.0, 1.0, 0.0, 1.0, 5.0];
        let x = [1.0, -2.0, 0.5];
        let mut b = matvec(3, &a, &x);
        let mut s = MinNorm::default();
        assert_eq!(s.factor(3, &a, 1e-12), Some(3));
        assert!(s.solve_in_place(&mut b));
        for i in 0..3 {
            assert!((b[i] - x[i]).abs() < 1e-14, "{b:?}");
        }
    }

    #[test]
    fn rank_deficient_consistent_system_gets_the_minimum_norm_solution() {
        // H = u vᵀ + w yᵀ (rank 2 in R⁴); b = H x₀ for some x₀. The minimum-norm solution lies
        // in the row space span(v, y) and solves H d = b exactly.
        let u = [1.0, 2.0, 0.0, -1.0];
        let v = [0.5, -1.0, 2.0, 1.0];
        let w = [0.0, 1.0, 1.0, 3.0];
        let y = [1.0, 1.0, 0.0, -2.0];
        let n = 4;
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[j * n + i] = u[i] * v[j] + w[i] * y[j];
            }
        }
        let x0 = [0.3, -0.7, 1.1, 2.0];
        let b0 = matvec(n, &a, &x0);
        let mut d = b0.clone();
        let mut s = MinNorm::default();
        assert_eq!(s.factor(n, &a, 1e-12), Some(2));
        assert_eq!(s.rank(), 2);
        assert!(s.solve_in_place(&mut d));
        let hd = matvec(n, &a, &d);
        for i in 0..n {
            assert!((hd[i] - b0[i]).abs() < 1e-13, "{hd:?} vs {b0:?}");
        }
        // d ⟂ null(H): null(H) = {z : v·z = 0, y·z = 0}. Project d on it: d must equal its
        // component in span(v, y), i.e. d = α v + β y.
        let gram = [[dot(&v, &v), dot(&v, &y)], [dot(&v, &y), dot(&y, &y)]];
        let rhs = [dot(&v, &d), dot(&y, &d)];
        let det = gram[0][0] * gram[1][1] - gram[0][1] * gram[1][0];
        let alpha = (rhs[0] * gram[1][1] - rhs[1] * gram[0][1]) / det;
        let beta = (gram[0][0] * rhs[1] - gram[1][0] * rhs[0]) / det;
        for i in 0..n {
            assert!((d[i] - (alpha * v[i] + beta * y[i])).abs() < 1e-13, "{d:?}");
        }
    }

    #[test]
    fn inconsistent_system_gets_the_least_squares_solution() {
        // H = diag(2, 0): min ‖H d − b‖ with b = (4, 1) gives d = (2, 0).
        let a = [2.0, 0.0, 0.0, 0.0];
        let mut b = [4.0, 1.0];
        let mut s = MinNorm::default();
        assert_eq!(s.factor(2, &a, 1e-12), Some(1));
        assert!(s.solve_in_place(&mut b));
        assert!((b[0] - 2.0).abs() < 1e-15 && b[1] == 0.0, "{b:?}");
    }

    /// The four-column dot products are bitwise those of [`dot`], for every remainder length.
    #[test]
    fn dots_are_bitwise_dot() {
        for m in 0..11 {
            let n = m + 3;
            let v: Vec<f64> = (0..m).map(|i| (i as f64 * 0.37).sin() * 1e3).collect();
            let cols: Vec<f64> = (0..7 * n).map(|i| (i as f64 * 1.3).cos() / 7.0).collect();
            let mut out = vec![0.0; 7];
            dots(&v, &cols, n, 2, &mut out);
            for q in 0..7 {
                let expected = dot(&v, &cols[q * n + 2..q * n + 2 + m]);
                assert_eq!(out[q].to_bits(), expected.to_bits(), "m {m}, column {q}");
            }
        }
    }

    /// A block-diagonal `H` of two singular blocks interleaved (unknowns 0, 2, 4 and 1, 3), in a
    /// sparse pattern: the step by blocks is the whole matrix's minimum-norm step (to round-off),
    /// and with one block it is that step bit for bit.
    #[test]
    fn steps_by_blocks_are_the_whole_matrix_step() {
        // Block A (0, 2, 4): rank 2 (its third column the sum of the first two); block B (1, 3):
        // rank 1.
        let n = 5;
        let mut h = vec![0.0; n * n];
        let a = [[2.0, 1.0, 3.0], [1.0, -1.0, 0.0], [0.5, 2.0, 2.5]]; // a[row][col]
        let ia = [0, 2, 4];
        for (r, &i) in ia.iter().enumerate() {
            for (c, &j) in ia.iter().enumerate() {
                h[j * n + i] = a[r][c];
            }
        }
        let ib = [1, 3];
        let b = [[1.0, 2.0], [2.0, 4.0]];
        for (r, &i) in ib.iter().enumerate() {
            for (c, &j) in ib.iter().enumerate() {
                h[j * n + i] = b[r][c];
            }
        }
        let entries: Vec<(usize, usize)> = (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .filter(|&(i, j)| h[j * n + i] != 0.0)
            .collect();
        let pattern = ecp_model::CscPattern::from_triplets(n, &entries).expect("pattern");
        let mut values = vec![0.0; pattern.nnz()];
        for j in 0..n {
            for p in pattern.col_ptr()[j]..pattern.col_ptr()[j + 1] {
                values[p] = h[j * n + pattern.row_idx()[p]];
            }
        }
        let phi = [0.3, -1.0, 0.7, 0.2, -0.4];
        let mut dense = vec![0.0; n * n];
        let (mut whole, mut blocks) = (vec![0.0; n], vec![0.0; n]);
        let mut m = MinNorm::default();
        assert!(m.newton_step(&pattern, &values, &mut dense, &phi, &mut whole, 1e-10));
        assert!(m.newton_step_by_blocks(&pattern, &values, &mut dense, &phi, &mut blocks, 1e-10));
        for i in 0..n {
            assert!(
                (whole[i] - blocks[i]).abs() <= 1e-13,
                "{i}: {whole:?} {blocks:?}"
            );
        }
        // One block (a full pattern): the whole matrix's step itself.
        let full = ecp_model::CscPattern::dense(n);
        let mut fv = vec![0.0; full.nnz()];
        for j in 0..n {
            for p in full.col_ptr()[j]..full.col_ptr()[j + 1] {
                fv[p] = h[j * n + full.row_idx()[p]] + 1e-3;
            }
        }
        assert!(m.newton_step(&full, &fv, &mut dense, &phi, &mut whole, 1e-10));
        assert!(m.newton_step_by_blocks(&full, &fv, &mut dense, &phi, &mut blocks, 1e-10));
        assert!(
            whole
                .iter()
                .zip(&blocks)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
    }

    #[test]
    fn non_finite_matrix_is_refused() {
        let mut s = MinNorm::default();
        assert_eq!(s.factor(1, &[f64::NAN], 1e-12), None);
        let mut b = [1.0];
        assert!(!s.solve_in_place(&mut b));
    }
}
