//! The singleton rows and columns of a square matrix, peeled off in turn: the pivots that need
//! no search, so that only the rest (the *core*) is factorised.
//!
//! A row whose only nonzero entry among the columns still in play lies in column `c` (a
//! *singleton row*) fixes `x_c` by itself; a column whose only nonzero entry among the rows
//! still in play lies in row `r` (a *singleton column*) is fixed by row `r` alone once the others
//! are known. Taking them in turn (each removal can make new ones) gives, with `R₁`/`C₁` the
//! singleton rows' pivots in their order, `R₃`/`C₃` the singleton columns' in reverse order and
//! `R₂`/`C₂` the core, the block lower triangular form
//!
//! ```text
//! P A Q = [ L₁₁  0    0  ]
//!         [ A₂₁  A₂₂  0  ]
//!         [ A₃₁  A₃₂  L₃₃]
//! ```
//!
//! with `L₁₁`, `L₃₃` lower triangular (a singleton row is zero in every column removed after
//! it; a singleton column is zero in every row removed after it). So `A x = b` is a forward
//! substitution on `L₁₁`, the core `A₂₂`, and a forward substitution on `L₃₃`
//! ([`super::ColumnTestedLu`], `docs/latency.md`, branch wip-pathfree).
//!
//! An entry is nonzero by its value (a stored zero of a sparse pattern is zero here, a NaN is
//! nonzero). The peel found for one matrix is kept and checked on the next
//! ([`SingletonPeel::holds`]: only the entries its form needs to be zero are read), since the
//! matrices of one active set share their zeros.

/// A pivot that needs no search: row `row`, column `column`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Pivot {
    pub row: usize,
    pub column: usize,
    /// A singleton column's pivot (else a singleton row's).
    pub by_column: bool,
}

/// The singleton pivots of an `n × n` matrix in the order they were removed, and the core.
#[derive(Clone, Debug, Default)]
pub(crate) struct SingletonPeel {
    n: usize,
    /// Every pivot in the order of removal.
    pivots: Vec<Pivot>,
    /// The core's rows and columns, ascending.
    core_rows: Vec<usize>,
    core_columns: Vec<usize>,
    /// Workspace: the nonzero entries of each row and column still in play, and which are.
    row_count: Vec<u32>,
    column_count: Vec<u32>,
    row_alive: Vec<bool>,
    column_alive: Vec<bool>,
}

impl SingletonPeel {
    /// The pivots in the order of removal.
    pub(crate) fn pivots(&self) -> &[Pivot] {
        &self.pivots
    }

    /// The core's rows, ascending.
    pub(crate) fn core_rows(&self) -> &[usize] {
        &self.core_rows
    }

    /// The core's columns, ascending.
    pub(crate) fn core_columns(&self) -> &[usize] {
        &self.core_columns
    }

    /// Whether the kept peel is one of the column-major `n × n` matrix `a`: the same dimension,
    /// and every entry that its form needs to be zero is zero (the pivots themselves are not
    /// read: a zero one is a dependent column, which the factorisation's test reports). Empty
    /// peels do not hold (a new search may find singletons).
    pub(crate) fn holds(&mut self, a: &[f64], n: usize) -> bool {
        if self.n != n || self.pivots.is_empty() {
            return false;
        }
        self.row_alive.clear();
        self.row_alive.resize(n, true);
        self.column_alive.clear();
        self.column_alive.resize(n, true);
        for p in &self.pivots {
            let ok = if p.by_column {
                let col = &a[p.column * n..(p.column + 1) * n];
                col.iter()
                    .zip(&self.row_alive)
                    .enumerate()
                    .all(|(i, (&v, &alive))| v == 0.0 || !alive || i == p.row)
            } else {
                (0..n).all(|j| {
                    a[j * n + p.row] == 0.0 || !self.column_alive[j] || j == p.column
                })
            };
            if !ok {
                return false;
            }
            self.row_alive[p.row] = false;
            self.column_alive[p.column] = false;
        }
        true
    }

    /// Finds the singleton pivots of the column-major `n × n` matrix `a` anew: singleton rows,
    /// then singleton columns, in turn until neither is left.
    pub(crate) fn find(&mut self, a: &[f64], n: usize) {
        self.n = n;
        self.pivots.clear();
        self.row_count.clear();
        self.row_count.resize(n, 0);
        self.column_count.clear();
        self.row_alive.clear();
        self.row_alive.resize(n, true);
        self.column_alive.clear();
        self.column_alive.resize(n, true);
        for col in a[..n * n].chunks_exact(n) {
            let mut k = 0u32;
            for (rc, &v) in self.row_count.iter_mut().zip(col) {
                let nz = u32::from(v != 0.0);
                *rc += nz;
                k += nz;
            }
            self.column_count.push(k);
        }
        let mut changed = true;
        while changed {
            changed = false;
            for r in 0..n {
                if !self.row_alive[r] || self.row_count[r] != 1 {
                    continue;
                }
                let Some(c) = (0..n).find(|&j| self.column_alive[j] && a[j * n + r] != 0.0) else {
                    continue;
                };
                self.take(a, n, Pivot {
                    row: r,
                    column: c,
                    by_column: false,
                });
                changed = true;
            }
            for c in 0..n {
                if !self.column_alive[c] || self.column_count[c] != 1 {
                    continue;
                }
                let col = &a[c * n..(c + 1) * n];
                let Some(r) = (0..n).find(|&i| self.row_alive[i] && col[i] != 0.0) else {
                    continue;
                };
                self.take(a, n, Pivot {
                    row: r,
                    column: c,
                    by_column: true,
                });
                changed = true;
            }
        }
        self.core_rows.clear();
        self.core_rows
            .extend((0..n).filter(|&i| self.row_alive[i]));
        self.core_columns.clear();
        self.core_columns
            .extend((0..n).filter(|&j| self.column_alive[j]));
    }

    /// Removes the pivot's row and column, and their entries from the other lines' counts.
    fn take(&mut self, a: &[f64], n: usize, p: Pivot) {
        self.pivots.push(p);
        self.row_alive[p.row] = false;
        self.column_alive[p.column] = false;
        let col = &a[p.column * n..(p.column + 1) * n];
        for (i, &v) in col.iter().enumerate() {
            if self.row_alive[i] && v != 0.0 {
                self.row_count[i] -= 1;
            }
        }
        for j in 0..n {
            if self.column_alive[j] && a[j * n + p.row] != 0.0 {
                self.column_count[j] -= 1;
            }
        }
    }
}
