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

use crate::cholesky::Cholesky;

/// `HᵀH + λI` for matrices `H` in a fixed pattern, with its own linear solver.
pub(crate) struct NormalEquations {
    source: CscPattern,
    form: Form,
    /// The system's values without the damping (`HᵀH`, or the augmented matrix with a zero
    /// block), formed once per `H` by [`NormalEquations::form`].
    base: Vec<f64>,
    values: Vec<f64>,
    solver: LinearSolver,
    /// The dense Cholesky factorisation of the product and its dense matrix, when chosen
    /// instead of the LU (`NewtonSettings::lm_cholesky`).
    cholesky: Option<(Cholesky, Vec<f64>)>,
}

enum Form {
    /// `HᵀH + λI` itself.
    Product {
        /// Triples (position of H(k,i), position of H(k,j), position of (i,j) in the product).
        triples: Vec<(usize, usize, usize)>,
        diag: Vec<usize>,
        /// The product's pattern.
        pattern: CscPattern,
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
    /// The system for `H`'s pattern: the formed product when `n ≤ dense_max` (factorised by
    /// dense Cholesky when `cholesky`, else by LU), else the augmented system.
    pub(crate) fn new(
        h: &CscPattern,
        dense_max: usize,
        cholesky: bool,
    ) -> Result<Self, LinalgError> {
        if h.dim() > dense_max {
            Self::augmented(h)
        } else {
            let mut ne = Self::product(h, dense_max)?;
            if cholesky {
                let n = h.dim();
                ne.cholesky = Some((Cholesky::default(), vec![0.0; n * n]));
            }
            Ok(ne)
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
                pattern: pattern.clone(),
            },
            base: vec![0.0; pattern.nnz()],
            values: vec![0.0; pattern.nnz()],
            solver,
            cholesky: None,
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
            base: vec![0.0; pattern.nnz()],
            values: vec![0.0; pattern.nnz()],
            solver,
            cholesky: None,
        })
    }

    /// Whether this system is for `h`'s pattern, factorised as asked.
    pub(crate) fn serves(&self, h: &CscPattern, cholesky: bool) -> bool {
        &self.source == h
            && (self.cholesky.is_some() == cholesky || matches!(self.form, Form::Augmented { .. }))
    }

    /// Factorises `HᵀH + λI` (or its augmented system) and returns the largest diagonal of
    /// `HᵀH` (for scaling λ). The same as [`NormalEquations::form`] then
    /// [`NormalEquations::factor_damped`].
    #[cfg(test)]
    pub(crate) fn factor(
        &mut self,
        h: &[f64],
        lambda: impl Fn(f64) -> f64,
    ) -> Result<f64, LinalgError> {
        let max_diag = self.form(h);
        self.factor_damped(lambda(max_diag))?;
        Ok(max_diag)
    }

    /// Forms the undamped system of `h` (`HᵀH`, or the augmented matrix with a zero damping
    /// block) and returns the largest diagonal of `HᵀH`. Each damping trial of one iteration
    /// then only adds its `λ` and factorises ([`NormalEquations::factor_damped`]).
    pub(crate) fn form(&mut self, h: &[f64]) -> f64 {
        self.base.fill(0.0);
        match &self.form {
            Form::Product { triples, diag, .. } => {
                for &(pi, pj, pos) in triples {
                    self.base[pos] += h[pi] * h[pj];
                }
                diag.iter().map(|&p| self.base[p]).fold(0.0, f64::max)
            }
            Form::Augmented {
                places,
                identity,
                col_ptr,
                ..
            } => {
                for (&(top, bottom), &v) in places.iter().zip(h) {
                    self.base[top] = v;
                    self.base[bottom] = v;
                }
                for &p in identity {
                    self.base[p] = 1.0;
                }
                col_ptr
                    .windows(2)
                    .map(|w| h[w[0]..w[1]].iter().map(|v| v * v).sum::<f64>())
                    .fold(0.0, f64::max)
            }
        }
    }

    /// Factorises the last formed system with damping `λ` (absolute).
    pub(crate) fn factor_damped(&mut self, l: f64) -> Result<(), LinalgError> {
        self.values.copy_from_slice(&self.base);
        match &self.form {
            Form::Product { diag, pattern, .. } => {
                for &p in diag {
                    self.values[p] += l;
                }
                if let Some((cholesky, dense)) = &mut self.cholesky {
                    pattern.to_dense(&self.values, dense);
                    return if cholesky.factor(pattern.dim(), dense) {
                        Ok(())
                    } else {
                        Err(LinalgError::Singular { ratio: 0.0 })
                    };
                }
            }
            Form::Augmented { damping, .. } => {
                for &p in damping {
                    self.values[p] = -l;
                }
            }
        }
        self.solver.factor(&self.values)
    }

    /// Solves `(HᵀH + λI) x = b` in place with the last factorisation.
    pub(crate) fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        match &mut self.form {
            Form::Product { .. } => match &self.cholesky {
                Some((cholesky, _)) => {
                    if cholesky.solve_in_place(b) {
                        Ok(())
                    } else {
                        Err(LinalgError::NonFinite)
                    }
                }
                None => self.solver.solve_in_place(b),
            },
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
            let solve = |dense_max: usize, cholesky: bool| {
                let mut ne = NormalEquations::new(&pattern, dense_max, cholesky)
                    .unwrap_or_else(|e| panic!("{e}"));
                let d = ne
                    .factor(&h, |m| lambda * m)
                    .unwrap_or_else(|e| panic!("{e}"));
                let mut x = b.clone();
                ne.solve_in_place(&mut x).unwrap_or_else(|e| panic!("{e}"));
                (d, x)
            };
            let (d1, x1) = solve(n, false); // the product, dense LU
            let (d2, x2) = solve(0, false); // the augmented system, sparse
            let (d3, x3) = solve(n, true); // the product, dense Cholesky
            assert!((d1 - d2).abs() <= 1e-12 * d1, "{d1} {d2}");
            assert_eq!(d1, d3);
            let scale = x1.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            for ((a, c), e) in x1.iter().zip(&x2).zip(&x3) {
                assert!((a - c).abs() <= 1e-10 * scale, "λ = {lambda}: {a} vs {c}");
                assert!((a - e).abs() <= 1e-10 * scale, "λ = {lambda}: {a} vs {e}");
            }
        }
    }
}
