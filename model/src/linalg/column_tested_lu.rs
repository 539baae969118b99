//! A dense LU with partial pivoting on the small kernel ([`super::SmallLu`]) whose pivots are
//! tested against their own columns: column `k` is dependent on the ones before it when its
//! pivot `|U_kk|` is at most `tolerance` times the largest magnitude of the column as given.
//! This is the dependence test of the pivoting core's basis LU (`ecp-solvers`' `pivot::basis`),
//! which a pivot ratio over the whole matrix ([`super::DenseLu`]'s `SINGULAR_PIVOT_RATIO`) is
//! not: a scaled problem's columns may differ by many orders of magnitude.
//!
//! The PATH-like solver's crash step factorises its reduced Jacobian `J_II` with it, written
//! straight into the factor's storage, at a dimension that changes with the active set
//! (`docs/latency.md`, branch wip-pathdesk3). The elimination, the pivot choice (the first
//! entry of largest magnitude) and the substitutions are the basis LU's operations in the same
//! order, so the factors and solutions are the same numbers.
//!
//! With [`ColumnTestedLu::set_peel`] the singleton rows and columns are taken first
//! ([`super::singleton_peel`]): their pivots need no search, and only the rest, the core, is
//! eliminated, with partial pivoting (`docs/latency.md`, branch wip-pathfree). Every pivot,
//! a singleton's and the core's, is tested against its own column's largest magnitude as given.

use super::SmallLu;
use super::singleton_peel::SingletonPeel;

/// Column `column` (0-based, in the matrix's column order) is numerically dependent on the
/// columns before it (the first such column).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DependentColumn {
    /// The first dependent column.
    pub column: usize,
}

/// A dense `n × n` LU with partial pivoting, any `n`, on storage kept between calls: give the
/// matrix with [`ColumnTestedLu::storage_mut`], factorise it with
/// [`ColumnTestedLu::factor`], solve with [`ColumnTestedLu::solve`].
#[derive(Clone, Debug)]
pub struct ColumnTestedLu {
    /// The matrix as given and, without a peel, its factors.
    lu: SmallLu,
    /// The largest magnitude of each column as given (the scale of the pivot test).
    norms: Vec<f64>,
    factored: bool,
    /// Take the singleton rows and columns first ([`ColumnTestedLu::set_peel`]).
    peel_on: bool,
    /// The singleton pivots of the last factorisation, when `peeled`.
    peel: SingletonPeel,
    peeled: bool,
    /// The core's LU (`lu` keeps the matrix as given for the singletons' substitutions).
    core: SmallLu,
    /// Workspace of the solves: the solution by columns, the core's right-hand side.
    x: Vec<f64>,
    y: Vec<f64>,
}

impl Default for ColumnTestedLu {
    fn default() -> Self {
        Self::new()
    }
}

impl ColumnTestedLu {
    /// An empty LU (dimension 0); its storage grows to the largest dimension given.
    pub fn new() -> Self {
        ColumnTestedLu {
            lu: SmallLu::new(0),
            norms: Vec::new(),
            factored: false,
            peel_on: false,
            peel: SingletonPeel::default(),
            peeled: false,
            core: SmallLu::new(0),
            x: Vec::new(),
            y: Vec::new(),
        }
    }

    /// Takes the singleton rows and columns first (`true`), or factorises the whole matrix as
    /// the basis LU does (`false`, the default). Applies from the next factorisation.
    pub fn set_peel(&mut self, on: bool) {
        self.peel_on = on;
    }

    /// The number of pivots of the last factorisation taken as singletons (0 without a peel).
    pub fn singleton_pivots(&self) -> usize {
        if self.peeled {
            self.peel.pivots().len()
        } else {
            0
        }
    }

    /// Dimension of the last matrix given.
    pub fn dim(&self) -> usize {
        self.lu.dim()
    }

    /// The column-major `n × n` storage of the next factorisation and the largest magnitude
    /// of each of its `n` columns (the scales of [`ColumnTestedLu::factor`]'s test), which the
    /// caller fills (every entry: they are unspecified until written). Allocates only when `n`
    /// is larger than every dimension before.
    pub fn storage_mut(&mut self, n: usize) -> (&mut [f64], &mut [f64]) {
        self.factored = false;
        self.lu.resize(n);
        self.norms.resize(n, 0.0);
        (self.lu.storage_mut(), &mut self.norms)
    }

    /// Factorises the matrix in the storage in place. `Err` names the first column whose pivot
    /// is at most `tolerance` times that column's largest magnitude as given (or not finite):
    /// then no solve is possible.
    ///
    /// With a peel ([`ColumnTestedLu::set_peel`]) the column named is the first dependent one
    /// in the order of elimination: the singleton rows', the core's, the singleton columns'.
    pub fn factor(&mut self, tolerance: f64) -> Result<(), DependentColumn> {
        self.peeled = false;
        if self.peel_on {
            let n = self.lu.dim();
            let a = self.lu.storage_mut();
            if !self.peel.holds(a, n) {
                self.peel.find(a, n);
            }
            if !self.peel.pivots().is_empty() {
                return self.factor_peeled(tolerance);
            }
        }
        self.lu.eliminate();
        // The pivot at step `k` is `U_kk`, the first entry of largest magnitude of what was
        // left of column `k`.
        for (k, (d, norm)) in self.lu.pivots().zip(&self.norms).enumerate() {
            let d = d.abs();
            if d <= tolerance * norm.max(f64::MIN_POSITIVE) || !d.is_finite() {
                return Err(DependentColumn { column: k });
            }
        }
        self.factored = true;
        Ok(())
    }

    /// [`ColumnTestedLu::factor`] with the singleton pivots of `self.peel`: the core gathered
    /// into its own LU and eliminated; the matrix as given is kept for the substitutions.
    fn factor_peeled(&mut self, tolerance: f64) -> Result<(), DependentColumn> {
        let n = self.lu.dim();
        let a = self.lu.storage_mut();
        let dependent =
            |d: f64, norm: f64| d.abs() <= tolerance * norm.max(f64::MIN_POSITIVE) || !d.is_finite();
        let (rows, columns) = (self.peel.core_rows(), self.peel.core_columns());
        let m = rows.len();
        self.core.resize(m);
        let core = self.core.storage_mut();
        for (dst, &j) in core.chunks_exact_mut(m.max(1)).zip(columns) {
            let col = &a[j * n..(j + 1) * n];
            for (d, &i) in dst.iter_mut().zip(rows) {
                *d = col[i];
            }
        }
        let pivots = self.peel.pivots();
        for p in pivots.iter().filter(|p| !p.by_column) {
            if dependent(a[p.column * n + p.row], self.norms[p.column]) {
                return Err(DependentColumn { column: p.column });
            }
        }
        if m > 0 {
            self.core.eliminate();
            for (d, &j) in self.core.pivots().zip(columns) {
                if dependent(d, self.norms[j]) {
                    return Err(DependentColumn { column: j });
                }
            }
        }
        for p in pivots.iter().filter(|p| p.by_column) {
            if dependent(a[p.column * n + p.row], self.norms[p.column]) {
                return Err(DependentColumn { column: p.column });
            }
        }
        self.x.resize(n, 0.0);
        self.y.resize(m, 0.0);
        self.peeled = true;
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = b` in place with the last factorisation (`b` of length `n`; untouched when
    /// the last factorisation failed).
    pub fn solve(&mut self, b: &mut [f64]) {
        if !self.factored {
            return;
        }
        if !self.peeled {
            self.lu.solve(b);
            return;
        }
        // `P A Q = [L₁₁ 0 0; A₂₁ A₂₂ 0; A₃₁ A₃₂ L₃₃]` (`super::singleton_peel`): `x_C₁` by
        // forward substitution, then the core, then `x_C₃` (the singleton columns' pivots in
        // reverse order of removal). `x` is by columns; a column not solved yet is 0, and its
        // entry in the rows used so far is 0 too.
        let n = self.lu.dim();
        let a = self.lu.factors();
        let x = &mut self.x[..n];
        x.fill(0.0);
        let pivots = self.peel.pivots();
        // A singleton row is zero in every column but the singleton rows' before it.
        for p in pivots.iter().filter(|p| !p.by_column) {
            let s = (0..n).fold(b[p.row], |s, j| s - a[j * n + p.row] * x[j]);
            x[p.column] = s / a[p.column * n + p.row];
        }
        let (rows, columns) = (self.peel.core_rows(), self.peel.core_columns());
        if !rows.is_empty() {
            let y = &mut self.y[..rows.len()];
            for (yi, &i) in y.iter_mut().zip(rows) {
                *yi = b[i];
            }
            // `b_R₂ − A₂₁ x_C₁`, a column of `A₂₁` at a time.
            for p in pivots.iter().filter(|p| !p.by_column) {
                let xj = x[p.column];
                if xj != 0.0 {
                    let col = &a[p.column * n..(p.column + 1) * n];
                    for (yi, &i) in y.iter_mut().zip(rows) {
                        *yi -= col[i] * xj;
                    }
                }
            }
            self.core.solve(y);
            for (&yi, &j) in y.iter().zip(columns) {
                x[j] = yi;
            }
        }
        for p in pivots.iter().rev().filter(|p| p.by_column) {
            let s = (0..n)
                .filter(|&j| j != p.column)
                .fold(b[p.row], |s, j| s - a[j * n + p.row] * x[j]);
            x[p.column] = s / a[p.column * n + p.row];
        }
        b[..n].copy_from_slice(x);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Column-major `A` of the tests: well conditioned, a pivot interchange at the first step.
    fn matrix() -> Vec<f64> {
        vec![
            1.0, 4.0, 2.0, //
            3.0, 1.0, 5.0, //
            2.0, 2.0, 7.0,
        ]
    }

    /// Gives `a` (column-major, `n × n`) to `lu` with its columns' norms.
    fn load(lu: &mut ColumnTestedLu, a: &[f64]) {
        let n = (a.len() as f64).sqrt() as usize;
        let (storage, norms) = lu.storage_mut(n);
        storage.copy_from_slice(a);
        for (norm, col) in norms.iter_mut().zip(a.chunks_exact(n)) {
            *norm = col.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        }
    }

    fn mul(a: &[f64], x: &[f64]) -> Vec<f64> {
        let n = x.len();
        (0..n)
            .map(|i| (0..n).map(|j| a[j * n + i] * x[j]).sum())
            .collect()
    }

    #[test]
    fn column_tested_lu_solves_and_keeps_its_storage_across_dimensions() {
        let mut lu = ColumnTestedLu::new();
        let a = matrix();
        let x = [1.0, -2.0, 0.5];
        for n in [3, 1, 3] {
            let sub: Vec<f64> = if n == 3 { a.clone() } else { vec![4.0] };
            load(&mut lu, &sub);
            lu.factor(1e-11).unwrap();
            assert_eq!(lu.dim(), n);
            let mut b = mul(&sub, &x[..n]);
            lu.solve(&mut b);
            for (bi, xi) in b.iter().zip(&x[..n]) {
                assert!((bi - xi).abs() <= 1e-15, "{b:?}");
            }
        }
    }

    #[test]
    fn column_tested_lu_judges_each_column_by_its_own_scale() {
        // Column 2 = column 0 + column 1: dependent, whatever the scales.
        let mut lu = ColumnTestedLu::new();
        let a = [1.0, 2.0, 0.0, 0.0, 1.0, 3.0, 1.0, 3.0, 3.0];
        load(&mut lu, &a);
        assert_eq!(lu.factor(1e-11), Err(DependentColumn { column: 2 }));
        // A failed factorisation solves nothing.
        let mut b = [1.0, 2.0, 3.0];
        lu.solve(&mut b);
        assert_eq!(b, [1.0, 2.0, 3.0]);
        // Columns scaled by 1e-20 and 1e20: the pivot ratio is 1e-40, yet every column is
        // independent of the others, and the solution is exact to round-off.
        let mut s = matrix();
        for v in &mut s[0..3] {
            *v *= 1e-20;
        }
        for v in &mut s[6..9] {
            *v *= 1e20;
        }
        load(&mut lu, &s);
        lu.factor(1e-11).unwrap();
        let x = [1e20, -2.0, 0.5e-20];
        let mut b = mul(&s, &x);
        lu.solve(&mut b);
        for (bi, xi) in b.iter().zip(&x) {
            assert!((bi - xi).abs() <= 1e-14 * xi.abs(), "{b:?}");
        }
        // A non-finite entry fails the test.
        let mut nan = matrix();
        nan[0] = f64::NAN;
        load(&mut lu, &nan);
        assert!(lu.factor(1e-11).is_err());
    }
}
