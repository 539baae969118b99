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

use super::SmallLu;

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
    lu: SmallLu,
    /// The largest magnitude of each column as given (the scale of the pivot test).
    norms: Vec<f64>,
    factored: bool,
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
    pub fn factor(&mut self, tolerance: f64) -> Result<(), DependentColumn> {
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

    /// Solves `A x = b` in place with the last factorisation (`b` of length `n`; untouched when
    /// the last factorisation failed).
    pub fn solve(&self, b: &mut [f64]) {
        if self.factored {
            self.lu.solve(b);
        }
    }

    /// The labels `rows[0..n]` of the rows of the matrix given (a caller's component of each
    /// row) in the order of the last factorisation's row interchanges: `order[i] = rows[r]`
    /// where row `i` of `P A` is row `r` of `A`. A caller that gathers its right-hand side by
    /// this list solves with [`ColumnTestedLu::solve_interchanged`]; it is the same list until
    /// the next factorisation.
    ///
    /// # Panics
    /// When `rows` holds fewer than [`ColumnTestedLu::dim`] labels (a caller's bug).
    pub fn row_order(&self, rows: &[usize], order: &mut Vec<usize>) {
        order.resize(self.lu.dim(), 0);
        self.lu.row_order(rows, order);
    }

    /// Solves `A x = c` in place where `b` holds `c` gathered in the order of the factors'
    /// interchanges ([`ColumnTestedLu::row_order`]: `b[i] = c[r]` for the row `r` of `A` in
    /// row `i` of `P A`); `x` comes back in the natural order (`b[j] = x_j`). Bitwise [`ColumnTestedLu::solve`]'s solution: the gather
    /// does the interchanges that the solve would do on `c` (the same numbers moved), and the
    /// substitutions are the same; it saves the `n` interchanges per solve of a caller that
    /// gathers `c` anyway (PATH's crash and chord steps). Untouched when the last
    /// factorisation failed.
    pub fn solve_interchanged(&self, b: &mut [f64]) {
        if self.factored {
            self.lu.solve_interchanged(b);
        }
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

    /// A gathered right-hand side solved without interchanges gives bitwise the solution of
    /// the plain solve, on matrices whose factorisation interchanges rows, with zero, `−0`,
    /// tiny and huge entries in the matrix and the right-hand side (the skipped columns).
    #[test]
    fn interchanged_solves_are_bitwise_the_plain_solves() {
        let mut s: u64 = 7;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut lu = ColumnTestedLu::new();
        let mut interchanged = 0;
        for n in 1..=40 {
            for kind in 0..4 {
                let a: Vec<f64> = (0..n * n)
                    .map(|k| {
                        let u = next();
                        let diag = k % (n + 1) == 0;
                        match kind {
                            // Mostly zero, signed zeros, a diagonal that does not dominate.
                            0 if !diag && u < 0.6 => {
                                if u < 0.3 {
                                    -0.0
                                } else {
                                    0.0
                                }
                            }
                            2 => (2.0 * u - 1.0) * if k % 3 == 0 { 1e-150 } else { 1e150 },
                            _ => 2.0 * u - 1.0 + if diag { 0.1 } else { 0.0 },
                        }
                    })
                    .collect();
                load(&mut lu, &a);
                if lu.factor(1e-13).is_err() {
                    continue;
                }
                let identity: Vec<usize> = (0..n).collect();
                let mut rows = Vec::new();
                lu.row_order(&identity, &mut rows);
                interchanged += rows.iter().enumerate().filter(|(i, r)| *i != **r).count();
                for rhs in 0..3 {
                    let c: Vec<f64> = (0..n)
                        .map(|i| match (rhs, i % 3) {
                            (0, _) => next() - 0.5,
                            (1, 0) => -0.0,
                            (1, 1) => 0.0,
                            (2, _) if i != n / 2 => 0.0,
                            _ => next() + 1e-300,
                        })
                        .collect();
                    let mut plain = c.clone();
                    lu.solve(&mut plain);
                    let mut gathered: Vec<f64> = rows.iter().map(|&r| c[r]).collect();
                    lu.solve_interchanged(&mut gathered);
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(
                        bits(&gathered),
                        bits(&plain),
                        "n = {n}, kind {kind}, rhs {rhs}"
                    );
                }
            }
        }
        assert!(
            interchanged > 100,
            "too few interchanges tested: {interchanged}"
        );
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
        lu.solve_interchanged(&mut b);
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
