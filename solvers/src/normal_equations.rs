//! The normal-equations matrix `HᵀH + λI` in a sparse pattern computed once per pattern of `H`,
//! for the Levenberg–Marquardt safeguard (`docs/backends.md#semismooth-newton`).

use ecp_model::CscPattern;
use ecp_model::linalg::{LinalgError, LinearSolver};

/// `HᵀH + λI` for matrices `H` in a fixed pattern, with its own linear solver.
pub(crate) struct NormalEquations {
    source: CscPattern,
    /// Triples (position of H(k,i), position of H(k,j), position of (i,j) in the product).
    triples: Vec<(usize, usize, usize)>,
    values: Vec<f64>,
    diag: Vec<usize>,
    solver: LinearSolver,
}

impl NormalEquations {
    pub(crate) fn new(h: &CscPattern, dense_max: usize) -> Result<Self, LinalgError> {
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
            triples,
            values: vec![0.0; pattern.nnz()],
            diag: pattern.diag_pos().to_vec(),
            solver,
        })
    }

    pub(crate) fn serves(&self, h: &CscPattern) -> bool {
        &self.source == h
    }

    /// Factorises `HᵀH + λI` and returns the largest diagonal of `HᵀH` (for scaling λ).
    pub(crate) fn factor(
        &mut self,
        h: &[f64],
        lambda: impl Fn(f64) -> f64,
    ) -> Result<f64, LinalgError> {
        self.values.fill(0.0);
        for &(pi, pj, pos) in &self.triples {
            self.values[pos] += h[pi] * h[pj];
        }
        let max_diag = self
            .diag
            .iter()
            .map(|&p| self.values[p])
            .fold(0.0, f64::max);
        let l = lambda(max_diag);
        for &p in &self.diag {
            self.values[p] += l;
        }
        self.solver.factor(&self.values)?;
        Ok(max_diag)
    }

    pub(crate) fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.solver.solve_in_place(b)
    }
}
