//! Linear algebra behind one module: dense and sparse LU and the symmetric eigen-decomposition
//! with faer.
//!
//! faer's API moves between versions, so nothing else in the workspace names it. Both solvers
//! keep their workspaces between factorisations: after the first call, factorising and solving
//! allocate nothing, and the sparse symbolic analysis (fill-reducing ordering, elimination
//! structure) is done once per sparsity pattern.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::lu::partial_pivoting::{factor as pp_factor, solve as pp_solve};
use faer::mat::{MatMut, MatRef};
use faer::sparse::linalg::lu as sp_lu;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Mat, Par};

use crate::pattern::CscPattern;

mod column_tested_lu;
mod schur;
mod simd;
mod small_lu;
mod sparse_cholesky;
mod unit_rows;
pub use column_tested_lu::{ColumnTestedLu, DependentColumn};
pub use schur::SchurLu;
pub(crate) use simd::{add_row_combination, transpose, transpose_checked};
use small_lu::SmallLu;
pub use sparse_cholesky::{SparseCholesky, cholesky_flops};
pub use unit_rows::UnitRowsLu;

/// Largest dimension [`DenseLu`] factorises with its own small-matrix kernel instead of faer's
/// blocked LU (`docs/latency.md`: below it the kernel is faster, above it faer is).
pub const SMALL_DENSE_MAX: usize = 48;

/// From this many right-hand sides on, [`DenseLu::solve_many_in_place`] uses faer's blocked
/// triangular solves on the small kernel's factors too (`docs/latency.md`).
const SMALL_MANY_RHS: usize = 4;

/// Failure of a factorisation or a solve.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LinalgError {
    /// The matrix is singular (or so ill-conditioned that its solution cannot be trusted).
    #[error("matrix is numerically singular (pivot ratio {ratio:.1e})")]
    Singular {
        /// Smallest over largest pivot magnitude.
        ratio: f64,
    },
    /// The matrix or right-hand side holds NaN or infinity.
    #[error("matrix or right-hand side is not finite")]
    NonFinite,
    /// faer reported an error in the symbolic or numeric phase.
    #[error("sparse LU failed: {0}")]
    Factorization(String),
    /// Solve called before a successful factorisation.
    #[error("no valid factorisation")]
    NotFactored,
}

/// Pivot ratio below which a matrix is treated as singular: beyond it an LU solve loses all
/// digits, and the Newton backend switches to its Levenberg–Marquardt safeguard.
pub const SINGULAR_PIVOT_RATIO: f64 = 1e-13;

/// Eigen-decomposition `A = U diag(λ) Uᵀ` of the symmetric `n × n` column-major matrix `a`
/// (faer's self-adjoint eigensolver, which reads the lower triangle): the eigenvalues `λ` in
/// nondecreasing order, and `U` column-major, its columns the unit eigenvectors.
pub fn symmetric_eigen(a: &[f64], n: usize) -> Result<(Vec<f64>, Vec<f64>), LinalgError> {
    if a.len() != n * n {
        return Err(LinalgError::Factorization(format!(
            "matrix has {} entries, expected {n} × {n}",
            a.len()
        )));
    }
    if a.iter().any(|v| !v.is_finite()) {
        return Err(LinalgError::NonFinite);
    }
    let evd = MatRef::from_column_major_slice(a, n, n)
        .self_adjoint_eigen(faer::Side::Lower)
        .map_err(|e| LinalgError::Factorization(format!("eigensolver: {e:?}")))?;
    let eig: Vec<f64> = evd.S().column_vector().iter().copied().collect();
    let u = evd.U();
    let mut vecs = vec![0.0; n * n];
    for j in 0..n {
        for i in 0..n {
            vecs[j * n + i] = u[(i, j)];
        }
    }
    if eig.iter().chain(&vecs).any(|v| !v.is_finite()) {
        return Err(LinalgError::NonFinite);
    }
    Ok((eig, vecs))
}

/// Dense LU with partial pivoting, workspace kept between calls: a small-matrix kernel up to
/// [`SMALL_DENSE_MAX`], faer's blocked LU above.
pub struct DenseLu {
    n: usize,
    small: Option<SmallLu>,
    lu: Mat<f64>,
    perm: Vec<usize>,
    perm_inv: Vec<usize>,
    mem: MemBuffer,
    factored: bool,
}

impl DenseLu {
    /// Workspace for `n × n` matrices.
    pub fn new(n: usize) -> Self {
        if n <= SMALL_DENSE_MAX {
            return DenseLu {
                n,
                small: Some(SmallLu::new(n)),
                lu: Mat::zeros(0, 0),
                perm: vec![0; n],
                perm_inv: vec![0; n],
                mem: MemBuffer::new(StackReq::EMPTY),
                factored: false,
            };
        }
        Self::blocked(n)
    }

    /// Workspace for faer's blocked LU, whatever the size (the benchmarks compare the kernels
    /// with it; [`DenseLu::new`] chooses by size).
    pub fn blocked(n: usize) -> Self {
        let req = StackReq::any_of(&[
            pp_factor::lu_in_place_scratch::<usize, f64>(n, n, Par::Seq, Default::default()),
            pp_solve::solve_in_place_scratch::<usize, f64>(n, 1, Par::Seq),
            pp_solve::solve_transpose_in_place_scratch::<usize, f64>(n, 1, Par::Seq),
        ]);
        DenseLu {
            n,
            small: None,
            lu: Mat::zeros(n, n),
            perm: vec![0; n],
            perm_inv: vec![0; n],
            mem: MemBuffer::new(req),
            factored: false,
        }
    }

    /// Dimension.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Factorises the column-major `n × n` matrix `a`.
    pub fn factor(&mut self, a: &[f64]) -> Result<(), LinalgError> {
        self.factored = false;
        if a.iter().any(|v| !v.is_finite()) {
            return Err(LinalgError::NonFinite);
        }
        match &mut self.small {
            Some(small) => small.storage_mut().copy_from_slice(a),
            None => {
                let n = self.n;
                self.lu.copy_from(MatRef::from_column_major_slice(a, n, n));
            }
        }
        self.eliminate()
    }

    /// Factorises the matrix whose entries in `pattern` are `values` (the others zero): the
    /// same factors as [`DenseLu::factor`] of its dense form, without forming it first for the
    /// small kernel, which takes the entries straight into its storage (`buf`, `n × n`, is the
    /// dense form for faer's blocked LU).
    pub fn factor_in_pattern(
        &mut self,
        pattern: &CscPattern,
        values: &[f64],
        buf: &mut [f64],
    ) -> Result<(), LinalgError> {
        self.factored = false;
        if values.iter().any(|v| !v.is_finite()) {
            return Err(LinalgError::NonFinite);
        }
        match &mut self.small {
            Some(small) => pattern.to_dense(values, small.storage_mut()),
            None => {
                let n = self.n;
                pattern.to_dense(values, buf);
                self.lu
                    .copy_from(MatRef::from_column_major_slice(buf, n, n));
            }
        }
        self.eliminate()
    }

    /// [`DenseLu::factor_in_pattern`] with the dense position of every stored entry given
    /// ([`CscPattern::dense_positions`]): one pass over the entries, which scatters them and
    /// tests them for finiteness together (the Newton iteration's factorisations).
    pub fn factor_scattered(
        &mut self,
        positions: &[usize],
        values: &[f64],
        buf: &mut [f64],
    ) -> Result<(), LinalgError> {
        self.factored = false;
        let target = match &mut self.small {
            Some(small) => {
                small.clear_storage();
                small.storage_mut()
            }
            None => {
                buf.fill(0.0);
                &mut *buf
            }
        };
        // The finiteness test as the entries move: the exponent carries OR-ed, no branch per
        // entry.
        let mut carried = 0u64;
        for (&k, &v) in positions.iter().zip(values) {
            carried |= simd::exponent_carry(v);
            target[k] = v;
        }
        if !simd::carries_finite(carried) {
            return Err(LinalgError::NonFinite);
        }
        if self.small.is_none() {
            let n = self.n;
            self.lu
                .copy_from(MatRef::from_column_major_slice(buf, n, n));
        }
        self.eliminate()
    }

    /// Factorises the `n × n` matrix whose column-major entry `k` is `−values[map[k]]`
    /// (`map` has `n²` entries; the values are finite: the caller checks): every entry of
    /// the small kernel's storage written once, gathered and negated, instead of zeroing it
    /// and scattering the stored entries (the step sensitivities' free block, whose entries
    /// outside the pattern point at a `−0` after the values, [`crate::sensitivity`]).
    pub(crate) fn factor_gathered_negated(
        &mut self,
        map: &[usize],
        values: &[f64],
    ) -> Result<(), LinalgError> {
        self.factored = false;
        let n = self.n;
        assert_eq!(map.len(), n * n, "one position per entry of the matrix");
        match &mut self.small {
            Some(small) => {
                for (a, &q) in small.storage_mut().iter_mut().zip(map) {
                    *a = -values[q];
                }
                self.eliminate()
            }
            None => {
                let dense: Vec<f64> = map.iter().map(|&q| -values[q]).collect();
                self.factor(&dense)
            }
        }
    }

    /// Factorises the loaded matrix in place and judges its pivots.
    fn eliminate(&mut self) -> Result<(), LinalgError> {
        let n = self.n;
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        if let Some(small) = &mut self.small {
            small.eliminate();
            (lo, hi) = small.pivot_magnitude_range((lo, hi));
        } else {
            let stack = MemStack::new(&mut self.mem);
            pp_factor::lu_in_place(
                self.lu.as_mut(),
                &mut self.perm,
                &mut self.perm_inv,
                Par::Seq,
                stack,
                Default::default(),
            );
            for i in 0..n {
                let d = self.lu[(i, i)].abs();
                lo = lo.min(d);
                hi = hi.max(d);
            }
        }
        if n > 0 && (lo.is_nan() || lo <= SINGULAR_PIVOT_RATIO * hi || !lo.is_finite()) {
            return Err(LinalgError::Singular {
                ratio: if hi > 0.0 { lo / hi } else { 0.0 },
            });
        }
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = b` in place (`b` becomes `x`).
    pub fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.solve_impl(b, false)
    }

    /// Solves `Aᵀ x = b` in place.
    pub fn solve_transpose_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.solve_impl(b, true)
    }

    /// Solves `A X = B` in place for the `k` columns of the column-major `n × k` matrix `b`, in
    /// one call (sensitivities: one column per parameter; much cheaper than `k` single solves).
    pub fn solve_many_in_place(&mut self, b: &mut [f64], k: usize) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        let n = self.n;
        check_many_rhs(b.len(), n, k)?;
        if let (Some(small), true) = (&self.small, k < SMALL_MANY_RHS) {
            for col in b.chunks_exact_mut(n.max(1)) {
                small.solve(col);
            }
        } else {
            let mut mem = MemBuffer::new(pp_solve::solve_in_place_scratch::<usize, f64>(
                n,
                k,
                Par::Seq,
            ));
            let rhs = MatMut::from_column_major_slice_mut(b, n, k);
            // Many right-hand sides: faer's blocked triangular solves, also on the small
            // kernel's factors (same storage, its row interchanges as a permutation).
            let lu = match &self.small {
                Some(small) => {
                    small.row_permutation(&mut self.perm, &mut self.perm_inv);
                    MatRef::from_column_major_slice(small.factors(), n, n)
                }
                None => self.lu.as_ref(),
            };
            let perm = faer::perm::PermRef::new_checked(&self.perm, &self.perm_inv, n);
            pp_solve::solve_in_place(lu, lu, perm, rhs, Par::Seq, MemStack::new(&mut mem));
        }
        if b.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(LinalgError::NonFinite)
        }
    }

    /// Solves `A X = B` in place for the `k` columns of the **row-major** `n × k` matrix `b`
    /// with the small kernel's row-oriented solve (its AVX2 loops; the step sensitivities'
    /// many right-hand sides, `docs/latency.md`). Returns `Ok(false)` and leaves `b` alone when
    /// the factors are faer's (above [`SMALL_DENSE_MAX`]). The result is not tested for
    /// finiteness: the caller reads it anyway.
    pub fn solve_rows_in_place(&mut self, b: &mut [f64], k: usize) -> Result<bool, LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        let Some(small) = &self.small else {
            return Ok(false);
        };
        check_many_rhs(b.len(), self.n, k)?;
        if k > 0 {
            small.solve_rows_accumulated(b, k);
        }
        Ok(true)
    }

    /// [`DenseLu::solve_rows_in_place`] on the rows `rows` (`n` of them, ascending) of the
    /// row-major `b` with `k` columns, the other rows untouched (the step sensitivities' free
    /// block solved where its rows lie, `docs/latency.md`). Returns `Ok(false)` and leaves `b`
    /// alone when the factors are faer's or the processor lacks AVX2 (then move the rows
    /// together and call [`DenseLu::solve_rows_in_place`]).
    pub fn solve_mapped_rows_in_place(
        &mut self,
        b: &mut [f64],
        k: usize,
        rows: &[usize],
    ) -> Result<bool, LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        let Some(small) = &self.small else {
            return Ok(false);
        };
        if rows.len() != self.n || rows.last().is_some_and(|&r| (r + 1) * k > b.len()) {
            return Err(LinalgError::Factorization(format!(
                "{} mapped rows of a {}-row right-hand side, expected {} rows",
                rows.len(),
                b.len() / k.max(1),
                self.n
            )));
        }
        Ok(k == 0 || small.solve_mapped_rows_accumulated(b, k, rows))
    }

    fn solve_impl(&mut self, b: &mut [f64], transpose: bool) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        let n = self.n;
        if b.len() != n {
            return Err(LinalgError::Factorization(format!(
                "right-hand side has {} entries, expected {n}",
                b.len()
            )));
        }
        if let Some(small) = &self.small {
            if transpose {
                small.solve_transpose(b);
            } else {
                small.solve(b);
            }
        } else {
            let perm = faer::perm::PermRef::new_checked(&self.perm, &self.perm_inv, n);
            let rhs = MatMut::from_column_major_slice_mut(b, n, 1);
            let stack = MemStack::new(&mut self.mem);
            let lu = self.lu.as_ref();
            if transpose {
                pp_solve::solve_transpose_in_place(lu, lu, perm, rhs, Par::Seq, stack);
            } else {
                pp_solve::solve_in_place(lu, lu, perm, rhs, Par::Seq, stack);
            }
        }
        if b.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(LinalgError::NonFinite)
        }
    }
}

/// Sparse LU (faer, column-approximate-minimum-degree ordering) whose symbolic analysis is
/// computed once for a pattern and reused for every numeric factorisation with that pattern.
pub struct SparseLu {
    pattern: CscPattern,
    symbolic: sp_lu::SymbolicLu<usize>,
    numeric: sp_lu::NumericLu<usize, f64>,
    mem: MemBuffer,
    values: Vec<f64>,
    work: Vec<f64>,
    factored: bool,
}

impl SparseLu {
    /// Symbolic analysis of `pattern`.
    pub fn analyze(pattern: &CscPattern) -> Result<Self, LinalgError> {
        let n = pattern.dim();
        let sym =
            SymbolicSparseColMatRef::new_checked(n, n, pattern.col_ptr(), None, pattern.row_idx());
        let symbolic = sp_lu::factorize_symbolic_lu(sym, Default::default())
            .map_err(|e| LinalgError::Factorization(format!("{e:?}")))?;
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_lu_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
            symbolic.solve_transpose_in_place_scratch::<f64>(1, Par::Seq),
        ]);
        Ok(SparseLu {
            pattern: pattern.clone(),
            symbolic,
            numeric: sp_lu::NumericLu::new(),
            mem: MemBuffer::new(req),
            values: vec![0.0; pattern.nnz()],
            work: vec![0.0; n],
            factored: false,
        })
    }

    /// The pattern this analysis belongs to.
    pub fn pattern(&self) -> &CscPattern {
        &self.pattern
    }

    /// Numeric factorisation of the matrix with this pattern and `values`.
    pub fn factor(&mut self, values: &[f64]) -> Result<(), LinalgError> {
        self.factored = false;
        if values.iter().any(|v| !v.is_finite()) {
            return Err(LinalgError::NonFinite);
        }
        let n = self.pattern.dim();
        self.values.copy_from_slice(values);
        let sym = SymbolicSparseColMatRef::new_checked(
            n,
            n,
            self.pattern.col_ptr(),
            None,
            self.pattern.row_idx(),
        );
        let a = SparseColMatRef::new(sym, &self.values);
        let stack = MemStack::new(&mut self.mem);
        self.symbolic
            .factorize_numeric_lu(&mut self.numeric, a, Par::Seq, stack, Default::default())
            .map_err(|e| match e {
                faer::sparse::linalg::LuError::SymbolicSingular { .. } => {
                    LinalgError::Singular { ratio: 0.0 }
                }
                other => LinalgError::Factorization(format!("{other:?}")),
            })?;
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = b` in place and checks the result (finite, small relative residual), since
    /// a sparse LU does not expose its pivots for a cheap singularity test.
    pub fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.solve_impl(b, false)
    }

    /// Solves `Aᵀ x = b` in place.
    pub fn solve_transpose_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.solve_impl(b, true)
    }

    fn solve_impl(&mut self, b: &mut [f64], transpose: bool) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        let n = self.pattern.dim();
        self.work.copy_from_slice(b);
        let lu = sp_lu::LuRef::new_unchecked(&self.symbolic, &self.numeric);
        let rhs = MatMut::from_column_major_slice_mut(b, n, 1);
        let stack = MemStack::new(&mut self.mem);
        if transpose {
            lu.solve_transpose_in_place_with_conj(faer::Conj::No, rhs, Par::Seq, stack);
        } else {
            lu.solve_in_place_with_conj(faer::Conj::No, rhs, Par::Seq, stack);
        }
        if !b.iter().all(|v| v.is_finite()) {
            return Err(LinalgError::NonFinite);
        }
        // Residual check: ‖A x − b‖∞ ≤ tol (‖A‖ ‖x‖ + ‖b‖).
        let (mut anorm, mut xnorm, mut bnorm) = (0.0f64, 0.0f64, 0.0f64);
        for v in &self.values {
            anorm = anorm.max(v.abs());
        }
        for (x, r) in b.iter().zip(&self.work) {
            xnorm = xnorm.max(x.abs());
            bnorm = bnorm.max(r.abs());
        }
        let mut max_res = 0.0f64;
        let (cp, ri, vals) = (self.pattern.col_ptr(), self.pattern.row_idx(), &self.values);
        if transpose {
            for j in 0..n {
                let mut s = -self.work[j];
                for p in cp[j]..cp[j + 1] {
                    s += vals[p] * b[ri[p]];
                }
                max_res = max_res.max(s.abs());
            }
        } else {
            // Accumulate A x − b in `work` (it holds b).
            for v in self.work.iter_mut() {
                *v = -*v;
            }
            for j in 0..n {
                for p in cp[j]..cp[j + 1] {
                    self.work[ri[p]] += vals[p] * b[j];
                }
            }
            for v in &self.work {
                max_res = max_res.max(v.abs());
            }
        }
        let scale = anorm * xnorm * (n as f64).max(1.0) + bnorm;
        if max_res > 1e-8 * scale.max(f64::MIN_POSITIVE) {
            return Err(LinalgError::Singular {
                ratio: max_res / scale.max(f64::MIN_POSITIVE),
            });
        }
        Ok(())
    }
}

/// A linear solver for matrices in a given [`CscPattern`]: dense LU for small systems, sparse
/// LU for large ones (`docs/backends.md#semismooth-newton`: "chosen by size").
pub enum LinearSolver {
    /// Dense LU on the scattered matrix.
    Dense {
        /// The factorisation workspace.
        lu: Box<DenseLu>,
        /// Dense scatter buffer.
        buf: Vec<f64>,
        /// The pattern the values come in.
        pattern: CscPattern,
        /// The dense (column-major) position of each stored entry.
        positions: Vec<usize>,
        /// The free block's LU of a matrix with unit rows
        /// ([`LinearSolver::factor_with_unit_rows`]); `None` above [`SMALL_DENSE_MAX`].
        unit_rows: Option<Box<UnitRowsLu>>,
        /// Whether the last factorisation is `unit_rows`'.
        unit_rows_used: bool,
    },
    /// Sparse LU with reused symbolic analysis.
    Sparse(Box<SparseLu>),
    /// Block elimination of the problem's elimination groups ([`SchurLu`]), with the dense LU
    /// of the whole matrix for a matrix whose block elimination fails (a singular group block
    /// or Schur complement: the dense LU then gives the verdict).
    Structured {
        /// The block elimination.
        schur: Box<SchurLu>,
        /// The dense solver of the whole matrix.
        dense: Box<LinearSolver>,
        /// Whether the last factorisation is the dense one.
        dense_used: bool,
    },
}

impl LinearSolver {
    /// Chooses dense LU when `n ≤ dense_max`, sparse LU otherwise.
    pub fn for_pattern(pattern: &CscPattern, dense_max: usize) -> Result<Self, LinalgError> {
        let n = pattern.dim();
        if n <= dense_max {
            Ok(LinearSolver::Dense {
                lu: Box::new(DenseLu::new(n)),
                buf: vec![0.0; n * n],
                pattern: pattern.clone(),
                positions: pattern.dense_positions(),
                unit_rows: (n <= SMALL_DENSE_MAX).then(|| Box::new(UnitRowsLu::new(pattern))),
                unit_rows_used: false,
            })
        } else {
            Ok(LinearSolver::Sparse(Box::new(SparseLu::analyze(pattern)?)))
        }
    }
    /// Block elimination of `groups` ([`SchurLu`], falling back to the dense LU when it fails)
    /// when `n ≤ dense_max`, the pattern has the groups' structure and they are not empty;
    /// otherwise as [`LinearSolver::for_pattern`].
    pub fn structured(
        pattern: &CscPattern,
        dense_max: usize,
        groups: &[Vec<usize>],
    ) -> Result<Self, LinalgError> {
        let dense = Self::for_pattern(pattern, dense_max)?;
        if !dense.is_dense() || groups.is_empty() {
            return Ok(dense);
        }
        match SchurLu::analyze(pattern, groups) {
            Some(schur) => Ok(LinearSolver::Structured {
                schur: Box::new(schur),
                dense: Box::new(dense),
                dense_used: false,
            }),
            None => Ok(dense),
        }
    }
    /// True when this solver serves `pattern` (so its analysis can be reused).
    pub fn serves(&self, pattern: &CscPattern) -> bool {
        match self {
            LinearSolver::Dense { pattern: p, .. } => p == pattern,
            LinearSolver::Sparse(s) => s.pattern() == pattern,
            LinearSolver::Structured { dense, .. } => dense.serves(pattern),
        }
    }
    /// True for the dense variant.
    pub fn is_dense(&self) -> bool {
        matches!(self, LinearSolver::Dense { .. })
    }
    /// True for the block elimination.
    pub fn is_structured(&self) -> bool {
        matches!(self, LinearSolver::Structured { .. })
    }
    /// True when the last factorisation was the block elimination's (not the dense fallback's).
    pub fn factored_by_elimination(&self) -> bool {
        matches!(
            self,
            LinearSolver::Structured {
                dense_used: false,
                ..
            }
        )
    }
    /// Factorises the matrix given by `values` in the pattern.
    pub fn factor(&mut self, values: &[f64]) -> Result<(), LinalgError> {
        match self {
            LinearSolver::Dense {
                lu,
                buf,
                positions,
                unit_rows_used,
                ..
            } => {
                *unit_rows_used = false;
                lu.factor_scattered(positions, values, buf)
            }
            LinearSolver::Sparse(s) => s.factor(values),
            LinearSolver::Structured {
                schur,
                dense,
                dense_used,
            } => {
                *dense_used = false;
                match schur.factor(values) {
                    Err(LinalgError::Singular { .. }) => {
                        *dense_used = true;
                        dense.factor(values)
                    }
                    r => r,
                }
            }
        }
    }
    /// Factorises the matrix given by `values` in the pattern whose rows `i` with
    /// `unit_rows[i]` hold only their diagonal entry (the others stored are zero): the dense
    /// variant factorises only the block of the other rows and columns ([`UnitRowsLu`]; the
    /// whole matrix when no row is a unit row, when a unit row holds a nonzero off the
    /// diagonal after all, or above [`SMALL_DENSE_MAX`]); the others as
    /// [`LinearSolver::factor`]. The solves solve with the whole matrix either way; the
    /// singularity verdict is the pivot ratio of the unit rows' diagonals and the block's
    /// pivots together.
    pub fn factor_with_unit_rows(
        &mut self,
        values: &[f64],
        unit_rows: &[bool],
    ) -> Result<(), LinalgError> {
        self.factor_with_unit_rows_of(values, unit_rows, false)
    }
    /// [`LinearSolver::factor_with_unit_rows`] for `values` the caller has found all finite
    /// (Newton's `H`, by the pass that finds its largest magnitude): the free block's load
    /// moves the entries without testing each one (≈ 4 instructions an entry, ≈ 1.4 k a desk
    /// factorisation). The same factors and verdicts as `factor_with_unit_rows` for finite
    /// values; a non-finite one given here is not refused by the load, but its NaN or `∞`
    /// reaches the pivots or the solves' results, which are tested.
    pub fn factor_with_unit_rows_finite(
        &mut self,
        values: &[f64],
        unit_rows: &[bool],
    ) -> Result<(), LinalgError> {
        self.factor_with_unit_rows_of(values, unit_rows, true)
    }
    fn factor_with_unit_rows_of(
        &mut self,
        values: &[f64],
        unit_rows: &[bool],
        known_finite: bool,
    ) -> Result<(), LinalgError> {
        match self {
            LinearSolver::Dense {
                pattern,
                unit_rows: Some(free),
                unit_rows_used,
                ..
            } if unit_rows.len() == pattern.dim() && unit_rows.contains(&true) => {
                *unit_rows_used = false;
                if free.factor(pattern, values, unit_rows, known_finite)? {
                    *unit_rows_used = true;
                    return Ok(());
                }
                self.factor(values)
            }
            _ => self.factor(values),
        }
    }
    /// The unit rows the last factorisation left out of its LU
    /// ([`LinearSolver::factor_with_unit_rows`]; 0 when it factorised the whole matrix).
    pub fn unit_rows_left_out(&self) -> usize {
        match self {
            LinearSolver::Dense {
                unit_rows: Some(free),
                unit_rows_used: true,
                ..
            } => free.unit_rows(),
            _ => 0,
        }
    }
    /// Solves `A x = b` in place.
    pub fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        match self {
            LinearSolver::Dense {
                unit_rows: Some(free),
                unit_rows_used: true,
                ..
            } => free.solve_in_place(b),
            LinearSolver::Dense { lu, .. } => lu.solve_in_place(b),
            LinearSolver::Sparse(s) => s.solve_in_place(b),
            LinearSolver::Structured {
                dense,
                dense_used: true,
                ..
            } => dense.solve_in_place(b),
            LinearSolver::Structured { schur, .. } => schur.solve_in_place(b),
        }
    }
    /// Solves `Aᵀ x = b` in place.
    pub fn solve_transpose_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        match self {
            LinearSolver::Dense {
                unit_rows: Some(free),
                unit_rows_used: true,
                ..
            } => free.solve_transpose_in_place(b),
            LinearSolver::Dense { lu, .. } => lu.solve_transpose_in_place(b),
            LinearSolver::Sparse(s) => s.solve_transpose_in_place(b),
            LinearSolver::Structured {
                dense,
                dense_used: true,
                ..
            } => dense.solve_transpose_in_place(b),
            LinearSolver::Structured { schur, .. } => schur.solve_transpose_in_place(b),
        }
    }
    /// True when [`LinearSolver::solve_rows_in_place`] solves: the dense variant with the small
    /// kernel's factors of the whole matrix.
    pub fn solves_rows(&self) -> bool {
        matches!(self, LinearSolver::Dense { lu, unit_rows_used: false, .. } if lu.small.is_some())
    }
    /// [`DenseLu::solve_rows_in_place`] for the dense variant with the whole matrix's factors
    /// (`Ok(false)`, `b` untouched, for the others).
    pub fn solve_rows_in_place(&mut self, b: &mut [f64], k: usize) -> Result<bool, LinalgError> {
        match self {
            LinearSolver::Dense {
                lu,
                unit_rows_used: false,
                ..
            } => lu.solve_rows_in_place(b, k),
            _ => Ok(false),
        }
    }
    /// Solves `A X = B` in place for the `k` columns of the column-major `n × k` matrix `b`
    /// (dense: one call; sparse: column by column, each with its residual check).
    pub fn solve_many_in_place(&mut self, b: &mut [f64], k: usize) -> Result<(), LinalgError> {
        match self {
            LinearSolver::Dense {
                unit_rows: Some(free),
                unit_rows_used: true,
                pattern,
                ..
            } => {
                check_many_rhs(b.len(), pattern.dim(), k)?;
                let n = pattern.dim().max(1);
                b.chunks_exact_mut(n)
                    .try_for_each(|col| free.solve_in_place(col))
            }
            LinearSolver::Dense { lu, .. } => lu.solve_many_in_place(b, k),
            LinearSolver::Structured {
                dense,
                dense_used: true,
                ..
            } => dense.solve_many_in_place(b, k),
            LinearSolver::Structured { schur, .. } => schur.solve_many_in_place(b, k),
            LinearSolver::Sparse(s) => {
                let n = s.pattern().dim().max(1);
                b.chunks_exact_mut(n)
                    .try_for_each(|col| s.solve_in_place(col))
            }
        }
    }
}

impl std::fmt::Debug for DenseLu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "DenseLu {{ n: {}, factored: {} }}",
            self.n, self.factored
        )
    }
}

impl std::fmt::Debug for SparseLu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "SparseLu {{ n: {}, nnz: {}, factored: {} }}",
            self.pattern.dim(),
            self.pattern.nnz(),
            self.factored
        )
    }
}

impl std::fmt::Debug for LinearSolver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LinearSolver::Dense { lu, .. } => write!(f, "LinearSolver::Dense({lu:?})"),
            LinearSolver::Sparse(s) => write!(f, "LinearSolver::Sparse({s:?})"),
            LinearSolver::Structured { schur, .. } => write!(
                f,
                "LinearSolver::Structured(n: {}, reduced: {})",
                schur.dim(),
                schur.reduced_dim()
            ),
        }
    }
}

/// The check of a many-right-hand-side solve: `b` holds `k` columns of length `n`.
pub(crate) fn check_many_rhs(len: usize, n: usize, k: usize) -> Result<(), LinalgError> {
    if len == n * k {
        Ok(())
    } else {
        Err(LinalgError::Factorization(format!(
            "right-hand side has {len} entries, expected {n} × {k}"
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symmetric_eigen_reconstructs_the_matrix_and_refuses_nan() {
        // Column-major (the matrix is symmetric, so row-major reads the same).
        let a = [4.0, 1.0, 0.0, 1.0, 3.0, 0.5, 0.0, 0.5, 2.0];
        let (eig, u) = symmetric_eigen(&a, 3).expect("finite");
        assert!(eig.windows(2).all(|w| w[0] <= w[1]), "{eig:?}");
        for i in 0..3 {
            for j in 0..3 {
                let r: f64 = (0..3).map(|k| u[k * 3 + i] * eig[k] * u[k * 3 + j]).sum();
                assert!((r - a[j * 3 + i]).abs() < 1e-13, "({i}, {j}): {r}");
            }
        }
        assert_eq!(symmetric_eigen(&[f64::NAN], 1), Err(LinalgError::NonFinite));
        assert!(symmetric_eigen(&[1.0, 2.0], 2).is_err());
    }

    /// The small-matrix kernel and faer's blocked LU give the same solutions to round-off, the
    /// same singularity verdicts, and the same errors.
    /// The gathered, negated factorisation writes the kernel's storage bitwise as zeroing it
    /// and scattering the negated stored entries does, so the factors, interchanges and
    /// solutions are the same bits; entries outside the pattern point at a `−0` slot.
    #[test]
    fn gathered_negated_factors_are_the_scattered_ones() {
        for n in [1, 4, 13, 31] {
            // A pattern of about half the entries, the diagonal stored; values after it, then
            // the `−0` slot.
            let mut values = Vec::new();
            let mut positions = Vec::new();
            let mut map = vec![usize::MAX; n * n];
            for k in 0..n * n {
                let (i, j) = (k % n, k / n);
                if i == j || (i * 5 + j * 3) % 4 < 2 {
                    map[k] = values.len();
                    positions.push(k);
                    let v = ((i * 7 + j * 13) % 11) as f64 - 5.0;
                    values.push(if i == j { v + 20.0 } else { v * 0.37 });
                }
            }
            let slot = values.len();
            values.push(-0.0);
            for m in map.iter_mut().filter(|m| **m == usize::MAX) {
                *m = slot;
            }
            let negated: Vec<f64> = values[..slot].iter().map(|v| -v).collect();
            let (mut gathered, mut scattered) = (DenseLu::new(n), DenseLu::new(n));
            gathered
                .factor_gathered_negated(&map, &values)
                .expect("regular");
            scattered
                .factor_scattered(&positions, &negated, &mut [])
                .expect("regular");
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let (g, s) = (gathered.small.as_ref(), scattered.small.as_ref());
            let (g, s) = (g.expect("small kernel"), s.expect("small kernel"));
            assert_eq!(bits(g.factors()), bits(s.factors()), "n = {n}");
            let b: Vec<f64> = (0..n).map(|i| 1.0 + i as f64).collect();
            let (mut x, mut y) = (b.clone(), b.clone());
            gathered.solve_in_place(&mut x).expect("solved");
            scattered.solve_in_place(&mut y).expect("solved");
            assert_eq!(bits(&x), bits(&y), "n = {n}");
            // And the factors are −A's: A x = −b.
            for i in 0..n {
                let ax: f64 = (0..n)
                    .map(|j| match map[j * n + i] {
                        q if q == slot => 0.0,
                        q => values[q] * x[j],
                    })
                    .sum();
                assert!((ax + b[i]).abs() < 1e-12 * b[i].abs().max(1.0), "n = {n}");
            }
        }
    }

    #[test]
    fn small_kernel_agrees_with_the_blocked_lu() {
        for n in [1, 5, 31, SMALL_DENSE_MAX] {
            let a: Vec<f64> = (0..n * n)
                .map(|k| {
                    let (i, j) = (k % n, k / n);
                    let v = ((i * 7 + j * 13) % 11) as f64 - 5.0;
                    let off = if (i + 2 * j) % 3 == 0 { 0.0 } else { v };
                    off + if i == j { 20.0 } else { 0.0 }
                })
                .collect();
            let (mut small, mut blocked) = (DenseLu::new(n), DenseLu::blocked(n));
            assert!(small.small.is_some() && blocked.small.is_none());
            small.factor(&a).expect("regular");
            blocked.factor(&a).expect("regular");
            let b: Vec<f64> = (0..n).map(|i| 1.0 + i as f64).collect();
            for transpose in [false, true] {
                let (mut x, mut y) = (b.clone(), b.clone());
                if transpose {
                    small.solve_transpose_in_place(&mut x).expect("solved");
                    blocked.solve_transpose_in_place(&mut y).expect("solved");
                } else {
                    small.solve_in_place(&mut x).expect("solved");
                    blocked.solve_in_place(&mut y).expect("solved");
                }
                for (u, v) in x.iter().zip(&y) {
                    assert!(
                        (u - v).abs() <= 1e-13 * v.abs().max(1.0),
                        "n = {n}: {u} vs {v}"
                    );
                }
            }
            let mut one = b.clone();
            small.solve_in_place(&mut one).expect("solved");
            for k in [2, 7] {
                let cols: Vec<f64> = (0..k)
                    .flat_map(|c| b.iter().map(move |v| v * (c + 1) as f64))
                    .collect();
                let mut many = cols.clone();
                small.solve_many_in_place(&mut many, k).expect("solved");
                for (c, col) in many.chunks_exact(n).enumerate() {
                    for (u, v) in col.iter().zip(&one) {
                        let v = v * (c + 1) as f64;
                        assert!(
                            (u - v).abs() <= 1e-13 * v.abs().max(1.0),
                            "k = {k}: {u} vs {v}"
                        );
                    }
                }
            }
        }
        let singular = [1.0, 2.0, 2.0, 4.0];
        assert!(matches!(
            DenseLu::new(2).factor(&singular),
            Err(LinalgError::Singular { .. })
        ));
        assert!(matches!(
            DenseLu::blocked(2).factor(&singular),
            Err(LinalgError::Singular { .. })
        ));
        assert_eq!(
            DenseLu::new(2).factor(&[1.0, f64::NAN, 0.0, 1.0]),
            Err(LinalgError::NonFinite)
        );
        assert_eq!(
            DenseLu::new(2).solve_in_place(&mut [1.0, 2.0]),
            Err(LinalgError::NotFactored)
        );
    }
}
