//! The Levenberg–Marquardt system `(HᵀH + λI) d = c` for matrices `H` in a fixed pattern, with
//! the pattern work and the symbolic analysis done once per pattern of `H`
//! (`docs/backends.md#semismooth-newton`).
//!
//! Small systems (`n ≤ dense_max`) form `HᵀH + λI` and factor it densely. Large ones solve the
//! equivalent augmented system
//!
//! ```text
//! [ I    H  ] [ r ]   [  0 ]
//! [ Hᵀ  −λI ] [ d ] = [ −c ]        (r = −H d, so (HᵀH + λI) d = c)
//! ```
//!
//! whose sparse LU has about the fill of `H`'s own, where `HᵀH` couples every two unknowns that
//! share a row of `H` and fills in to a nearly dense matrix on multi-body step problems (a
//! 20-body bin: 66 % of the run in factoring it, `docs/latency.md#bins`).

use ecp_model::CscPattern;
use ecp_model::linalg::{LinalgError, LinearSolver};

/// `HᵀH + λI` for matrices `H` in a fixed pattern, with its own linear solver.
pub(crate) struct NormalEquations {
    source: CscPattern,
    form: Form,
    values: Vec<f64>,
    solver: LinearSolver,
}

enum Form {
    /// `HᵀH + λI` itself.
    Product {
        /// Triples (position of H(k,i), position of H(k,j), position of (i,j) in the product).
        triples: Vec<(usize, usize, usize)>,
        diag: Vec<usize>,
    },
    /// The augmented `2n × 2n` system of the module documentation.
    Augmented {
        n: usize,
        /// For each entry `p` of `H`, (row `k`, column `j`): the positions of `K(k, n + j)` and
        /// `K(n + j, k)`.
        places: Vec<(usize, usize)>,
        /// Positions of the identity block's diagonal.
        identity: Vec<usize>,
        /// Positions of the `−λI` block's diagonal.
        damping: Vec<usize>,
        /// Column ranges of `H` (for the column norms, the diagonal of `HᵀH`).
        col_ptr: Vec<usize>,
        rhs: Vec<f64>,
    },
}

impl NormalEquations {
    pub(crate) fn new(h: &CscPattern, dense_max: usize) -> Result<Self, LinalgError> {
        if h.dim() > dense_max {
            Self::augmented(h)
        } else {
            Self::product(h, dense_max)
        }
    }

    fn product(h: &CscPattern, dense_max: usize) -> Result<Self, LinalgError> {
        let n = h.dim();
        // Row lists of H: for each row k, the (column, position) pairs.
        let mut rows: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
        for j in 0..n {
            for p in h.col_ptr()[j]..h.col_ptr()[j + 1] {
                rows[h.row_idx()[p]].push((j, p));
            }
        }
        let mut columns: Vec<Vec<usize>> = vec![Vec::new(); n];
        for row in &rows {
            for &(i, _) in row {
                for &(j, _) in row {
                    columns[j].push(i);
                }
            }
        }
        let pattern = CscPattern::from_columns(n, columns)
            .map_err(|e| LinalgError::Factorization(e.to_string()))?;
        let mut triples = Vec::new();
        for row in &rows {
            for &(i, pi) in row {
                for &(j, pj) in row {
                    if let Some(pos) = pattern.position(i, j) {
                        triples.push((pi, pj, pos));
                    }
                }
            }
        }
        let solver = LinearSolver::for_pattern(&pattern, dense_max)?;
        Ok(NormalEquations {
            source: h.clone(),
            form: Form::Product {
                triples,
                diag: pattern.diag_pos().to_vec(),
            },
            values: vec![0.0; pattern.nnz()],
            solver,
        })
    }

    fn augmented(h: &CscPattern) -> Result<Self, LinalgError> {
        let n = h.dim();
        let (cp, ri) = (h.col_ptr(), h.row_idx());
        // Column k < n: the identity's (k, k) and Hᵀ's row k below, (n + j) for H(k, j) ≠ 0.
        // Column n + j: H's column j above, (k) for H(k, j) ≠ 0, and −λ at (n + j, n + j).
        let mut columns: Vec<Vec<usize>> = (0..2 * n).map(|c| vec![c]).collect();
        for j in 0..n {
            for &k in &ri[cp[j]..cp[j + 1]] {
                columns[k].push(n + j);
                columns[n + j].push(k);
            }
        }
        let pattern = CscPattern::from_columns(2 * n, columns)
            .map_err(|e| LinalgError::Factorization(e.to_string()))?;
        let missing = || LinalgError::Factorization("augmented pattern".to_string());
        let mut places = Vec::with_capacity(ri.len());
        for j in 0..n {
            for &k in &ri[cp[j]..cp[j + 1]] {
                let top = pattern.position(k, n + j).ok_or_else(missing)?;
                let bottom = pattern.position(n + j, k).ok_or_else(missing)?;
                places.push((top, bottom));
            }
        }
        let diag = pattern.diag_pos();
        let solver = LinearSolver::for_pattern(&pattern, 0)?;
        Ok(NormalEquations {
            source: h.clone(),
            form: Form::Augmented {
                n,
                places,
                identity: diag[..n].to_vec(),
                damping: diag[n..].to_vec(),
                col_ptr: cp.to_vec(),
                rhs: vec![0.0; 2 * n],
            },
            values: vec![0.0; pattern.nnz()],
            solver,
        })
    }

    pub(crate) fn serves(&self, h: &CscPattern) -> bool {
        &self.source == h
    }

    /// Factorises `HᵀH + λI` (or its augmented system) and returns the largest diagonal of
    /// `HᵀH` (for scaling λ).
    pub(crate) fn factor(
        &mut self,
        h: &[f64],
        lambda: impl Fn(f64) -> f64,
    ) -> Result<f64, LinalgError> {
        self.values.fill(0.0);
        let max_diag = match &self.form {
            Form::Product { triples, diag } => {
                for &(pi, pj, pos) in triples {
                    self.values[pos] += h[pi] * h[pj];
                }
                let max_diag = diag.iter().map(|&p| self.values[p]).fold(0.0, f64::max);
                let l = lambda(max_diag);
                for &p in diag {
                    self.values[p] += l;
                }
                max_diag
            }
            Form::Augmented {
                places,
                identity,
                damping,
                col_ptr,
                ..
            } => {
                for (&(top, bottom), &v) in places.iter().zip(h) {
                    self.values[top] = v;
                    self.values[bottom] = v;
                }
                let max_diag = col_ptr
                    .windows(2)
                    .map(|w| h[w[0]..w[1]].iter().map(|v| v * v).sum::<f64>())
                    .fold(0.0, f64::max);
                let l = lambda(max_diag);
                for &p in identity {
                    self.values[p] = 1.0;
                }
                for &p in damping {
                    self.values[p] = -l;
                }
                max_diag
            }
        };
        self.solver.factor(&self.values)?;
        Ok(max_diag)
    }

    /// Solves `(HᵀH + λI) x = b` in place with the last factorisation.
    pub(crate) fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        match &mut self.form {
            Form::Product { .. } => self.solver.solve_in_place(b),
            Form::Augmented { n, rhs, .. } => {
                let n = *n;
                rhs[..n].fill(0.0);
                for (r, v) in rhs[n..].iter_mut().zip(b.iter()) {
                    *r = -v;
                }
                self.solver.solve_in_place(rhs)?;
                b.copy_from_slice(&rhs[n..]);
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The augmented system gives the same `(HᵀH + λI)⁻¹ b` as the formed product, to 1e-12
    /// (relative), on a sparse, non-symmetric `H` with a zero diagonal entry.
    #[test]
    fn augmented_system_agrees_with_the_product() {
        let n = 30;
        let columns: Vec<Vec<usize>> = (0..n)
            .map(|j| {
                (0..n)
                    .filter(|&i| {
                        if i == j {
                            j % 7 != 3
                        } else {
                            (i * 5 + j * 3) % 7 < 2
                        }
                    })
                    .collect()
            })
            .collect();
        let pattern = CscPattern::from_columns(n, columns).unwrap_or_else(|e| panic!("{e}"));
        let h: Vec<f64> = (0..pattern.nnz())
            .map(|p| ((p * 37 % 23) as f64 - 11.0) / 7.0)
            .collect();
        let b: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
        for lambda in [1e-6, 1e-2, 1.0] {
            let solve = |dense_max: usize| {
                let mut ne =
                    NormalEquations::new(&pattern, dense_max).unwrap_or_else(|e| panic!("{e}"));
                let d = ne
                    .factor(&h, |m| lambda * m)
                    .unwrap_or_else(|e| panic!("{e}"));
                let mut x = b.clone();
                ne.solve_in_place(&mut x).unwrap_or_else(|e| panic!("{e}"));
                (d, x)
            };
            let (d1, x1) = solve(n); // the product, dense
            let (d2, x2) = solve(0); // the augmented system, sparse
            assert!((d1 - d2).abs() <= 1e-12 * d1, "{d1} {d2}");
            let scale = x1.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            for (a, c) in x1.iter().zip(&x2) {
                assert!((a - c).abs() <= 1e-10 * scale, "λ = {lambda}: {a} vs {c}");
            }
        }
    }
}
