//! The Levenberg–Marquardt system `(HᵀH + λI) d = c` for matrices `H` in a fixed pattern, with
//! the pattern work and the symbolic analysis done once per pattern of `H`
//! (`docs/backends.md#semismooth-newton`, `docs/newton.md#cheap-levenberg-marquardt-trials`).
//!
//! Small systems (`n ≤ dense_max`) form `HᵀH + λI` and factor it densely. Large ones either form
//! the product too and factor it by a sparse Cholesky (fill-reducing ordering), or solve the
//! equivalent augmented system
//!
//! ```text
//! [ I    H  ] [ r ]   [  0 ]
//! [ Hᵀ  −λI ] [ d ] = [ −c ]        (r = −H d, so (HᵀH + λI) d = c)
//! ```
//!
//! by a sparse LU, whichever the symbolic analysis finds cheaper: `HᵀH` couples every two
//! unknowns that share a row of `H`, which on a pile of bodies fills in to a nearly dense matrix
//! (a 20-body bin: 66 % of the run in factoring it by LU, `docs/latency.md#bins`), where the
//! augmented system has about the fill of `H`'s own; on bodies apart (`025_multi_body`: 170
//! unknowns in four groups) the product keeps the groups' blocks, and its Cholesky costs a
//! fraction of the augmented LU, whose partial pivoting on the `−λI` block undoes the ordering.

use ecp_model::CscPattern;
use ecp_model::linalg::{LinalgError, LinearSolver, SparseCholesky, cholesky_flops};

use crate::cholesky::Cholesky;

/// `HᵀH + λI` for matrices `H` in a fixed pattern, with its own linear solver.
pub(crate) struct NormalEquations {
    source: CscPattern,
    form: Form,
    /// The system's values without the damping (`HᵀH`, or the augmented matrix with a zero
    /// block), formed once per `H` by [`NormalEquations::form`].
    base: Vec<f64>,
    values: Vec<f64>,
    solver: Solver,
    /// The dense Cholesky factorisation of the product and its dense matrix, when chosen
    /// instead of the LU (`NewtonSettings::lm_cholesky`).
    cholesky: Option<(Cholesky, Vec<f64>)>,
}

/// The factorisation of the system: LU (dense for the product of small problems, sparse for the
/// augmented system) or the sparse Cholesky of a large product.
enum Solver {
    Lu(LinearSolver),
    Cholesky(Box<SparseCholesky>),
}

impl Solver {
    fn factor(&mut self, values: &[f64]) -> Result<(), LinalgError> {
        match self {
            Solver::Lu(lu) => lu.factor(values),
            Solver::Cholesky(c) => c.factor(values),
        }
    }
    fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        match self {
            Solver::Lu(lu) => lu.solve_in_place(b),
            Solver::Cholesky(c) => c.solve_in_place(b),
        }
    }
}

enum Form {
    /// `HᵀH + λI` itself.
    Product {
        /// Triples (position of H(k,i), position of H(k,j), position of (i,j) in the product);
        /// for the sparse Cholesky only those of the lower triangle (`i ≥ j`), which is all it
        /// reads. 32-bit positions: the triples are the memory traffic of forming `HᵀH`.
        triples: Vec<[u32; 3]>,
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
    /// dense Cholesky when `cholesky`, else by LU); above it, when `sparse_product`, the product
    /// factorised by sparse Cholesky if [`NormalEquations::product_is_cheaper`], else the
    /// augmented system.
    pub(crate) fn new(
        h: &CscPattern,
        dense_max: usize,
        cholesky: bool,
        sparse_product: bool,
    ) -> Result<Self, LinalgError> {
        if h.dim() > dense_max {
            if sparse_product {
                let (columns, triples) = product_columns(h);
                let product = CscPattern::from_columns(h.dim(), columns)
                    .map_err(|e| LinalgError::Factorization(e.to_string()))?;
                let augmented = augmented_pattern(h)?;
                if product_is_cheaper(triples, &product, &augmented)? {
                    return Self::sparse_product(h, product);
                }
            }
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
        let (columns, _) = product_columns(h);
        let pattern = CscPattern::from_columns(h.dim(), columns)
            .map_err(|e| LinalgError::Factorization(e.to_string()))?;
        let solver = Solver::Lu(LinearSolver::for_pattern(&pattern, dense_max)?);
        Self::with_product(h, pattern, solver, false)
    }

    /// The product factorised by sparse Cholesky.
    fn sparse_product(h: &CscPattern, pattern: CscPattern) -> Result<Self, LinalgError> {
        let solver = Solver::Cholesky(Box::new(SparseCholesky::analyze(&pattern)?));
        Self::with_product(h, pattern, solver, true)
    }

    /// The product form for `h` with the product's `pattern`, factorised by `solver`; only its
    /// lower triangle formed when `lower`.
    fn with_product(
        h: &CscPattern,
        pattern: CscPattern,
        solver: Solver,
        lower: bool,
    ) -> Result<Self, LinalgError> {
        let index = |p: usize| {
            u32::try_from(p).map_err(|_| LinalgError::Factorization("product too large".into()))
        };
        // Row lists of H: for each row k, the (column, position) pairs.
        let rows = row_lists(h);
        let mut triples = Vec::new();
        for row in &rows {
            for &(i, pi) in row {
                for &(j, pj) in row {
                    if lower && i < j {
                        continue;
                    }
                    if let Some(pos) = pattern.position(i, j) {
                        triples.push([index(pi)?, index(pj)?, index(pos)?]);
                    }
                }
            }
        }
        Ok(NormalEquations {
            source: h.clone(),
            base: vec![0.0; pattern.nnz()],
            values: vec![0.0; pattern.nnz()],
            form: Form::Product {
                triples,
                diag: pattern.diag_pos().to_vec(),
                pattern,
            },
            solver,
            cholesky: None,
        })
    }

    fn augmented(h: &CscPattern) -> Result<Self, LinalgError> {
        let n = h.dim();
        let (cp, ri) = (h.col_ptr(), h.row_idx());
        let pattern = augmented_pattern(h)?;
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
        let solver = Solver::Lu(LinearSolver::for_pattern(&pattern, 0)?);
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

    /// Whether this system is for `h`'s pattern, factorised as asked (`cholesky` concerns the
    /// dense product only; `sparse_product` the systems above `dense_max`, where it was a
    /// choice).
    pub(crate) fn serves(
        &self,
        h: &CscPattern,
        dense_max: usize,
        cholesky: bool,
        sparse_product: bool,
    ) -> bool {
        if &self.source != h {
            return false;
        }
        if h.dim() <= dense_max {
            return matches!(self.form, Form::Product { .. })
                && matches!(self.solver, Solver::Lu(_))
                && self.cholesky.is_some() == cholesky;
        }
        sparse_product || matches!(self.form, Form::Augmented { .. })
    }

    /// Whether the system is the augmented one (factorised by sparse LU).
    pub(crate) fn is_augmented(&self) -> bool {
        matches!(self.form, Form::Augmented { .. })
    }

    /// The multiplications of one factorisation when the system is the product factorised by
    /// sparse Cholesky.
    pub(crate) fn sparse_cholesky_flops(&self) -> Option<f64> {
        match &self.solver {
            Solver::Cholesky(c) => Some(c.flops()),
            Solver::Lu(_) => None,
        }
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
                for &[pi, pj, pos] in triples {
                    self.base[pos as usize] += h[pi as usize] * h[pj as usize];
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

/// Row lists of `h`: for each row `k`, the (column, position) pairs of its entries.
fn row_lists(h: &CscPattern) -> Vec<Vec<(usize, usize)>> {
    let mut rows: Vec<Vec<(usize, usize)>> = vec![Vec::new(); h.dim()];
    for j in 0..h.dim() {
        for p in h.col_ptr()[j]..h.col_ptr()[j + 1] {
            rows[h.row_idx()[p]].push((j, p));
        }
    }
    rows
}

/// The columns of `HᵀH`'s pattern (unsorted, with duplicates), and the multiplications that
/// form its lower triangle (`Σ_k m_k (m_k + 1) / 2`, `m_k` entries in row `k` of `H`).
fn product_columns(h: &CscPattern) -> (Vec<Vec<usize>>, usize) {
    let rows = row_lists(h);
    let mut columns: Vec<Vec<usize>> = vec![Vec::new(); h.dim()];
    let mut triples = 0;
    for row in &rows {
        triples += row.len() * (row.len() + 1) / 2;
        for &(i, _) in row {
            for &(j, _) in row {
                columns[j].push(i);
            }
        }
    }
    (columns, triples)
}

/// The pattern of the augmented `2n × 2n` system of the module documentation.
fn augmented_pattern(h: &CscPattern) -> Result<CscPattern, LinalgError> {
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
    CscPattern::from_columns(2 * n, columns).map_err(|e| LinalgError::Factorization(e.to_string()))
}

/// Whether one damping trial of the product form costs less than one of the augmented form.
/// The product's cost: forming its lower triangle (`triples` multiplications, once per
/// iteration but counted in full) and its Cholesky's multiplications. The augmented system's:
/// 4 times the multiplications of its symmetric (`LDLᵀ`) factorisation in the same kind of
/// ordering — twice for the LU's arithmetic, twice again for the fill and bookkeeping of the
/// partial pivoting, far below what was measured (faer's LU of the augmented system took 45–50
/// ns per such multiplication on `025_multi_body` and bin20, the sparse Cholesky 2–2.5 ns per
/// multiplication, forming 5–10 ns per triple; `docs/newton.md#cheap-levenberg-marquardt-trials`),
/// so that only a product that fills in much more than the augmented system (a dense row of
/// `H`) keeps the augmented form.
fn product_is_cheaper(
    triples: usize,
    product: &CscPattern,
    augmented: &CscPattern,
) -> Result<bool, LinalgError> {
    let product_cost = triples as f64 + cholesky_flops(product)?;
    Ok(product_cost <= AUGMENTED_COST_FACTOR * cholesky_flops(augmented)?)
}

/// See [`product_is_cheaper`].
const AUGMENTED_COST_FACTOR: f64 = 4.0;

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
                let mut ne = NormalEquations::new(&pattern, dense_max, cholesky, false)
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
    /// A deterministic pseudo-random number in [−1, 1) (xorshift64*).
    fn uniform(state: &mut u64) -> f64 {
        *state ^= *state >> 12;
        *state ^= *state << 25;
        *state ^= *state >> 27;
        let r = state.wrapping_mul(0x2545_f491_4f6c_dd1d);
        (r >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    /// `H` of `groups` independent blocks of `size` unknowns (bodies apart), each column its
    /// diagonal and about `per_column` random rows of its block. With `rank_deficient`, every
    /// fifth column of a block is twice the one before it (same rows), so `H` has rank at most
    /// 4/5 of `n`.
    fn block_matrix(
        groups: usize,
        size: usize,
        per_column: usize,
        seed: u64,
        rank_deficient: bool,
    ) -> (CscPattern, Vec<Vec<(usize, f64)>>) {
        let mut state = seed;
        let n = groups * size;
        let mut columns: Vec<Vec<(usize, f64)>> = Vec::with_capacity(n);
        for j in 0..n {
            let base = j / size * size;
            if rank_deficient && j % 5 == 4 {
                let previous: Vec<(usize, f64)> =
                    columns[j - 1].iter().map(|&(i, v)| (i, 2.0 * v)).collect();
                columns.push(previous);
                continue;
            }
            let mut col = vec![(j, 2.0 + uniform(&mut state))];
            for _ in 0..per_column {
                let i = base + ((uniform(&mut state) + 1.0) * 0.5 * size as f64) as usize % size;
                if col.iter().all(|&(r, _)| r != i) {
                    col.push((i, uniform(&mut state)));
                }
            }
            col.sort_by_key(|&(i, _)| i);
            columns.push(col);
        }
        let pattern = CscPattern::from_columns(
            n,
            columns
                .iter()
                .map(|c| c.iter().map(|&(i, _)| i).collect())
                .collect(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        (pattern, columns)
    }

    /// The values of `columns` in `pattern` (which may hold explicit zeros: the diagonal).
    fn values_in(pattern: &CscPattern, columns: &[Vec<(usize, f64)>]) -> Vec<f64> {
        let mut h = vec![0.0; pattern.nnz()];
        for (j, col) in columns.iter().enumerate() {
            for &(i, v) in col {
                let p = pattern
                    .position(i, j)
                    .unwrap_or_else(|| panic!("({i}, {j})"));
                h[p] = v;
            }
        }
        h
    }

    /// `(HᵀH + λI) x = b` solved straightforwardly: the dense product formed entry by entry
    /// and factorised by dense LU.
    fn dense_solve(n: usize, columns: &[Vec<(usize, f64)>], lambda: f64, b: &[f64]) -> Vec<f64> {
        let mut h = vec![0.0; n * n];
        for (j, col) in columns.iter().enumerate() {
            for &(i, v) in col {
                h[j * n + i] = v;
            }
        }
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                let s: f64 = (0..n).map(|k| h[i * n + k] * h[j * n + k]).sum();
                a[j * n + i] = s + if i == j { lambda } else { 0.0 };
            }
        }
        let mut lu = ecp_model::linalg::DenseLu::new(n);
        lu.factor(&a).unwrap_or_else(|e| panic!("{e}"));
        let mut x = b.to_vec();
        lu.solve_in_place(&mut x).unwrap_or_else(|e| panic!("{e}"));
        x
    }

    /// Above `dense_max`, on bodies apart (four blocks of 40 unknowns), the sparse Cholesky of
    /// the product is chosen and solves `(HᵀH + λI) d = c` as the straightforward dense solve
    /// does, to 1e-12 (relative to the largest component), for a well-posed `H` and a
    /// rank-deficient one (`HᵀH` singular: only `λ` makes the system definite).
    #[test]
    fn sparse_product_agrees_with_the_dense_solve() {
        for (seed, rank_deficient) in [(7u64, false), (11, true)] {
            let (pattern, columns) = block_matrix(4, 40, 5, seed, rank_deficient);
            let n = pattern.dim();
            let h = values_in(&pattern, &columns);
            let mut state = seed + 1;
            let b: Vec<f64> = (0..n).map(|_| uniform(&mut state)).collect();
            let mut ne =
                NormalEquations::new(&pattern, 120, false, true).unwrap_or_else(|e| panic!("{e}"));
            assert!(
                ne.sparse_cholesky_flops().is_some(),
                "the product is chosen"
            );
            for relative in [1e-2, 1.0] {
                let max_diag = ne
                    .factor(&h, |m| relative * m)
                    .unwrap_or_else(|e| panic!("{e}"));
                let lambda = relative * max_diag;
                let mut x = b.clone();
                ne.solve_in_place(&mut x).unwrap_or_else(|e| panic!("{e}"));
                let reference = dense_solve(n, &columns, lambda, &b);
                let scale = reference.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
                for (i, (a, r)) in x.iter().zip(&reference).enumerate() {
                    assert!(
                        (a - r).abs() <= 1e-12 * scale,
                        "rank deficient {rank_deficient}, λ = {relative:e} max diag, \
                         component {i}: {a:e} against {r:e}"
                    );
                }
            }
        }
    }

    /// A dense row of `H` makes `HᵀH` dense: the augmented system is kept there; without
    /// `sparse_product` it is always the augmented system; with a singular product (a zero
    /// column of `H`, `λ = 0`) the sparse Cholesky refuses to factorise.
    #[test]
    fn the_form_follows_the_fill() {
        let n = 150;
        let dense_row: Vec<Vec<usize>> = (0..n).map(|j| vec![j, 3]).collect();
        let pattern = CscPattern::from_columns(n, dense_row).unwrap_or_else(|e| panic!("{e}"));
        let ne = NormalEquations::new(&pattern, 120, false, true).unwrap_or_else(|e| panic!("{e}"));
        assert!(ne.is_augmented());
        let (pattern, columns) = block_matrix(4, 40, 5, 3, false);
        let ne =
            NormalEquations::new(&pattern, 120, false, false).unwrap_or_else(|e| panic!("{e}"));
        assert!(ne.is_augmented());
        let mut ne =
            NormalEquations::new(&pattern, 120, false, true).unwrap_or_else(|e| panic!("{e}"));
        assert!(!ne.is_augmented());
        let mut h = values_in(&pattern, &columns);
        for p in pattern.col_ptr()[17]..pattern.col_ptr()[18] {
            h[p] = 0.0;
        }
        assert!(matches!(
            ne.factor(&h, |_| 0.0),
            Err(LinalgError::Singular { .. })
        ));
        assert!(ne.factor(&h, |m| 1e-6 * m).is_ok());
    }
}
