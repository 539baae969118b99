//! The basis factorisation of the pivotal solver: a dense LU with partial pivoting, updated by
//! the product form of the inverse (one eta column per pivot) and refactorised periodically.
//!
//! Lemke's method changes one column of the basis `B` per pivot. Refactorising from scratch each
//! time costs `O(n³)`; an explicit inverse updated by rank-one formulas loses accuracy. The
//! product form keeps `B₀ = P⁻¹LU` from the last refactorisation and the eta matrices
//! `E₁ … E_k` of the pivots since then (`B_k = B₀ E₁ ⋯ E_k`, `E_j` the identity with one column
//! replaced by `B_{j−1}⁻¹ a_j`), so each solve costs `O(n² + kn)`, and the LU is recomputed
//! every `period` pivots to bound the growth of the eta file and of round-off (Chvátal,
//! "Linear Programming", ch. 24; Cottle, Pang & Stone, "The Linear Complementarity Problem",
//! §4.10 on implementing pivoting methods).
//!
//! The factorisation is written here rather than taken from faer because basis repair needs to
//! know *which* column is dependent (faer's LU only reports that one is).

/// Outcome of a factorisation that found a (numerically) dependent column.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct DependentColumn {
    /// Position, in the order the columns were given, of the first dependent column.
    pub column: usize,
}

/// Dense LU of a basis matrix with an eta file of updates.
#[derive(Debug, Default)]
pub(crate) struct BasisFactor {
    n: usize,
    /// `L` (unit, below the diagonal) and `U` of `P A`, column-major, where `A` holds the
    /// columns in factorisation order.
    lu: Vec<f64>,
    /// Row permutation: row `k` of `P A` is row `perm[k]` of `A`.
    perm: Vec<usize>,
    /// Factorisation column `k` is basis position `order[k]`.
    order: Vec<usize>,
    /// Eta file: for update `j`, the basis position replaced and the column `B⁻¹ a` (length n).
    eta_pos: Vec<usize>,
    eta_val: Vec<f64>,
    work: Vec<f64>,
    factored: bool,
}

/// Relative pivot size below which a column is treated as dependent on the ones before it.
const DEPENDENCE_TOLERANCE: f64 = 1e-11;

impl BasisFactor {
    /// Number of updates since the last factorisation.
    pub fn updates(&self) -> usize {
        self.eta_pos.len()
    }

    /// Factorises the matrix whose column `order[k]` (a basis position) is `columns[k]`
    /// (dense, length `n` each, stored contiguously: `columns[k * n .. (k + 1) * n]`).
    ///
    /// Columns are eliminated in the given order with partial pivoting by rows; a column whose
    /// largest remaining entry is below `DEPENDENCE_TOLERANCE` times its norm is reported as
    /// dependent on the earlier ones (so callers put the columns that can never be dependent,
    /// such as unit columns, first).
    pub fn factor(
        &mut self,
        n: usize,
        columns: &[f64],
        order: &[usize],
    ) -> Result<(), DependentColumn> {
        self.n = n;
        self.factored = false;
        self.eta_pos.clear();
        self.eta_val.clear();
        self.lu.clear();
        self.lu.extend_from_slice(&columns[..n * n]);
        self.order.clear();
        self.order.extend_from_slice(order);
        self.perm.clear();
        self.perm.extend(0..n);
        // Norms of the original columns: dependence is judged relative to them.
        self.work.clear();
        self.work.extend((0..n).map(|k| {
            columns[k * n..(k + 1) * n]
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()))
        }));
        let lu = &mut self.lu;
        for k in 0..n {
            let col_norm = self.work[k];
            // Partial pivoting within column k.
            let mut piv = k;
            let mut best = 0.0f64;
            for i in k..n {
                let v = lu[k * n + i].abs();
                if v > best {
                    best = v;
                    piv = i;
                }
            }
            if best <= DEPENDENCE_TOLERANCE * col_norm.max(f64::MIN_POSITIVE) || !best.is_finite() {
                return Err(DependentColumn { column: k });
            }
            if piv != k {
                for j in 0..n {
                    lu.swap(j * n + k, j * n + piv);
                }
                self.perm.swap(k, piv);
            }
            let d = lu[k * n + k];
            for i in k + 1..n {
                lu[k * n + i] /= d;
            }
            // Right-looking update of the trailing columns: contiguous axpys.
            let (left, right) = lu.split_at_mut((k + 1) * n);
            let lcol = &left[k * n + k + 1..k * n + n];
            for j in 0..n - k - 1 {
                let col = &mut right[j * n..(j + 1) * n];
                let a = col[k];
                if a != 0.0 {
                    for (c, l) in col[k + 1..].iter_mut().zip(lcol) {
                        *c -= a * l;
                    }
                }
            }
        }
        self.factored = true;
        Ok(())
    }

    /// Solves `B x = b` in place (`b` indexed by equation, `x` by basis position).
    pub fn solve(&mut self, b: &mut [f64]) {
        if !self.factored {
            return;
        }
        let n = self.n;
        let lu = &self.lu;
        let y = &mut self.work;
        for k in 0..n {
            y[k] = b[self.perm[k]];
        }
        // L y = P b (unit lower), then U v = y.
        for k in 0..n {
            let yk = y[k];
            if yk != 0.0 {
                for (yi, l) in y[k + 1..].iter_mut().zip(&lu[k * n + k + 1..(k + 1) * n]) {
                    *yi -= yk * l;
                }
            }
        }
        for k in (0..n).rev() {
            y[k] /= lu[k * n + k];
            let yk = y[k];
            if yk != 0.0 {
                for (yi, u) in y[..k].iter_mut().zip(&lu[k * n..k * n + k]) {
                    *yi -= yk * u;
                }
            }
        }
        for k in 0..n {
            b[self.order[k]] = y[k];
        }
        // Eta file, oldest first: x ← E_j⁻¹ x.
        for (j, &p) in self.eta_pos.iter().enumerate() {
            let eta = &self.eta_val[j * n..(j + 1) * n];
            let xp = b[p] / eta[p];
            if xp != 0.0 {
                for (i, (bi, e)) in b.iter_mut().zip(eta).enumerate() {
                    if i != p {
                        *bi -= e * xp;
                    }
                }
            }
            b[p] = xp;
        }
    }

    /// Solves `Bᵀ y = c` in place (`c` indexed by basis position, `y` by equation).
    pub fn solve_transpose(&mut self, c: &mut [f64]) {
        if !self.factored {
            return;
        }
        let n = self.n;
        // Eta file, newest first: Bᵀ = E_kᵀ ⋯ E_1ᵀ B₀ᵀ, and E_jᵀ w = c changes only entry p.
        for (j, &p) in self.eta_pos.iter().enumerate().rev() {
            let eta = &self.eta_val[j * n..(j + 1) * n];
            let mut s = c[p];
            for (i, (ci, e)) in c.iter().zip(eta).enumerate() {
                if i != p {
                    s -= e * ci;
                }
            }
            c[p] = s / eta[p];
        }
        // B₀ = A Qᵀ with A = Pᵀ L U: Aᵀ y = Qᵀ c.
        let lu = &self.lu;
        let v = &mut self.work;
        for k in 0..n {
            v[k] = c[self.order[k]];
        }
        // Uᵀ w = v (forward), then Lᵀ t = w (backward), y = Pᵀ t.
        for k in 0..n {
            let s: f64 = lu[k * n..k * n + k]
                .iter()
                .zip(&v[..k])
                .map(|(u, w)| u * w)
                .sum();
            v[k] = (v[k] - s) / lu[k * n + k];
        }
        for k in (0..n).rev() {
            let s: f64 = lu[k * n + k + 1..(k + 1) * n]
                .iter()
                .zip(&v[k + 1..])
                .map(|(l, t)| l * t)
                .sum();
            v[k] -= s;
        }
        for k in 0..n {
            c[self.perm[k]] = v[k];
        }
    }

    /// Records that basis position `p` now holds the column `a` with `alpha = B⁻¹ a` (computed
    /// with the factorisation before the update).
    pub fn update(&mut self, p: usize, alpha: &[f64]) {
        self.eta_pos.push(p);
        self.eta_val.extend_from_slice(&alpha[..self.n]);
    }
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
    fn basis_solves_match_the_matrix_after_updates() {
        let n = 5;
        // Column-major, diagonally dominant.
        let mut a: Vec<f64> = (0..n * n)
            .map(|k| ((k * 7919 % 13) as f64 - 6.0) / 6.0)
            .collect();
        for i in 0..n {
            a[i * n + i] += 4.0;
        }
        let order: Vec<usize> = (0..n).rev().collect();
        // Factor with the columns given in reversed order.
        let mut cols = vec![0.0; n * n];
        for k in 0..n {
            cols[k * n..(k + 1) * n].copy_from_slice(&a[order[k] * n..(order[k] + 1) * n]);
        }
        let mut f = BasisFactor::default();
        f.factor(n, &cols, &order).unwrap();
        for step in 0..3 {
            // Replace column p by a new column.
            let p = (2 * step + 1) % n;
            // Independent new columns (dominant entry at row p).
            let new: Vec<f64> = (0..n)
                .map(|i| {
                    if i == p {
                        5.0
                    } else {
                        0.3 * (i + step) as f64 - 0.5
                    }
                })
                .collect();
            let mut alpha = new.clone();
            f.solve(&mut alpha);
            f.update(p, &alpha);
            a[p * n..(p + 1) * n].copy_from_slice(&new);
            let b: Vec<f64> = (0..n).map(|i| i as f64 - 1.5).collect();
            let mut x = b.clone();
            f.solve(&mut x);
            let ax = matvec(n, &a, &x);
            for i in 0..n {
                assert!((ax[i] - b[i]).abs() < 1e-12, "step {step}: {ax:?} vs {b:?}");
            }
            // Transpose: Aᵀ y = c.
            let c: Vec<f64> = (0..n).map(|i| (i * i) as f64 * 0.1 - 0.7).collect();
            let mut y = c.clone();
            f.solve_transpose(&mut y);
            for j in 0..n {
                let s: f64 = (0..n).map(|i| a[j * n + i] * y[i]).sum();
                assert!(
                    (s - c[j]).abs() < 1e-12,
                    "transpose step {step}: {s} vs {}",
                    c[j]
                );
            }
        }
        assert_eq!(f.updates(), 3);
    }

    #[test]
    fn basis_reports_the_dependent_column() {
        let n = 3;
        // Columns e0, (1, 1, 0), (2, 2, 0): the third depends on the first two.
        let cols = vec![1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 2.0, 2.0, 0.0];
        let mut f = BasisFactor::default();
        assert_eq!(
            f.factor(n, &cols, &[0, 1, 2]),
            Err(DependentColumn { column: 2 })
        );
    }
}
