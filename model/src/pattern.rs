//! Compressed sparse column pattern of an MCP Jacobian.
//!
//! The pattern always contains the diagonal, so that the Newton matrix `D_a + D_b J`
//! has the same pattern as `J` and the symbolic analysis of its LU factorisation is done
//! once per pattern (DEVELOPERS.md: pattern analysis happens once and is reused).

use crate::error::ModelError;

/// Sparsity pattern of a square `n × n` matrix in compressed sparse column form,
/// row indices sorted within each column, diagonal always present.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CscPattern {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    diag_pos: Vec<usize>,
}

impl CscPattern {
    /// Builds a pattern from per-column row lists (unsorted, duplicates allowed);
    /// the diagonal is added where missing.
    pub fn from_columns(n: usize, mut columns: Vec<Vec<usize>>) -> Result<Self, ModelError> {
        if columns.len() != n {
            return Err(ModelError::Pattern(format!(
                "{} columns given for a {n}×{n} matrix",
                columns.len()
            )));
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        let mut diag_pos = Vec::with_capacity(n);
        col_ptr.push(0);
        for (j, col) in columns.iter_mut().enumerate() {
            col.push(j);
            col.sort_unstable();
            col.dedup();
            if let Some(&r) = col.last()
                && r >= n
            {
                return Err(ModelError::Pattern(format!(
                    "row index {r} out of range in column {j} (n = {n})"
                )));
            }
            let start = row_idx.len();
            let d = col.binary_search(&j).unwrap_or(0);
            diag_pos.push(start + d);
            row_idx.extend_from_slice(col);
            col_ptr.push(row_idx.len());
        }
        Ok(CscPattern {
            n,
            col_ptr,
            row_idx,
            diag_pos,
        })
    }

    /// The fully dense pattern (every entry present), for small problems given by closures.
    pub fn dense(n: usize) -> Self {
        let columns = (0..n).map(|_| (0..n).collect()).collect();
        // A dense pattern is always valid.
        match Self::from_columns(n, columns) {
            Ok(p) => p,
            Err(_) => unreachable!("dense pattern is valid"),
        }
    }

    /// Builds a pattern from (row, column) pairs.
    pub fn from_triplets(n: usize, entries: &[(usize, usize)]) -> Result<Self, ModelError> {
        let mut columns = vec![Vec::new(); n];
        for &(i, j) in entries {
            if i >= n || j >= n {
                return Err(ModelError::Pattern(format!(
                    "entry ({i}, {j}) out of range (n = {n})"
                )));
            }
            columns[j].push(i);
        }
        Self::from_columns(n, columns)
    }

    /// Matrix dimension.
    pub fn dim(&self) -> usize {
        self.n
    }
    /// Number of stored entries.
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }
    /// Column pointers (length `n + 1`).
    pub fn col_ptr(&self) -> &[usize] {
        &self.col_ptr
    }
    /// Row indices, sorted within each column.
    pub fn row_idx(&self) -> &[usize] {
        &self.row_idx
    }
    /// Position of the diagonal entry of each column in the value array.
    pub fn diag_pos(&self) -> &[usize] {
        &self.diag_pos
    }
    /// Position of entry `(i, j)` in the value array, if stored.
    pub fn position(&self, i: usize, j: usize) -> Option<usize> {
        let s = *self.col_ptr.get(j)?;
        let e = self.col_ptr[j + 1];
        self.row_idx[s..e].binary_search(&i).ok().map(|p| s + p)
    }

    /// Scatters values stored in this pattern into a dense column-major `n × n` array.
    pub fn to_dense(&self, values: &[f64], out: &mut [f64]) {
        out.fill(0.0);
        for j in 0..self.n {
            for p in self.col_ptr[j]..self.col_ptr[j + 1] {
                out[j * self.n + self.row_idx[p]] = values[p];
            }
        }
    }

    /// The position in a dense column-major `n × n` array of each stored entry, in storage
    /// order (a scatter without the column loop: `out[positions[p]] = values[p]`).
    pub fn dense_positions(&self) -> Vec<usize> {
        let mut positions = Vec::with_capacity(self.nnz());
        for j in 0..self.n {
            for &r in &self.row_idx[self.col_ptr[j]..self.col_ptr[j + 1]] {
                positions.push(j * self.n + r);
            }
        }
        positions
    }

    /// `y = A x` for `A` stored in this pattern.
    pub fn mul_vec(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        for j in 0..self.n {
            let xj = x[j];
            for p in self.col_ptr[j]..self.col_ptr[j + 1] {
                y[self.row_idx[p]] += values[p] * xj;
            }
        }
    }

    /// `y = Aᵀ x` for `A` stored in this pattern.
    pub fn mul_transpose_vec(&self, values: &[f64], x: &[f64], y: &mut [f64]) {
        for j in 0..self.n {
            let mut s = 0.0;
            for p in self.col_ptr[j]..self.col_ptr[j + 1] {
                s += values[p] * x[self.row_idx[p]];
            }
            y[j] = s;
        }
    }
}
