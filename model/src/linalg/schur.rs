//! Block elimination (Schur complement) for matrices whose unknowns split into groups with a
//! small diagonal block each and the rest (`docs/latency.md#structured-linear-solve`).
//!
//! In a contact step a body's Newton–Euler and kinematic-map rows involve its own `(ν, q)` and
//! the contact unknowns only, so the Jacobian, ordered groups first, is
//!
//! ```text
//! [ A  B ]   A = diag(A_1, …, A_k)   (13 × 13 per body)
//! [ C  D ]   D: the contact unknowns
//! ```
//!
//! and `A x_E + B x_C = b_E`, `C x_E + D x_C = b_C` is solved as `S x_C = b_C − C A⁻¹ b_E` with
//! `S = D − C A⁻¹ B`, then `x_E = A⁻¹ b_E − (A⁻¹ B) x_C`. Each `A_g` and `S` is factorised by
//! the small-matrix LU with partial pivoting; on the desk this replaces one 31 × 31 LU by a
//! 13 × 13 and an 18 × 18 one. Exact in exact arithmetic; in floating point the pivot order
//! differs from the LU of the whole matrix (groups first), so results move by round-off.

use super::small_lu::SmallLu;
use super::{LinalgError, SINGULAR_PIVOT_RATIO, check_many_rhs};
use crate::pattern::CscPattern;

/// Where an unknown sits in the partition.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    /// Group `g`, position `k` within it.
    Group(usize, usize),
    /// Position `k` among the rest.
    Rest(usize),
}

/// One group's diagonal block.
#[derive(Clone, Debug)]
struct Group {
    /// Offset of the group in the concatenated group unknowns.
    offset: usize,
    lu: SmallLu,
    /// `(position in the values, position in the column-major block)`.
    entries: Vec<(usize, usize)>,
}

/// A column of `B` (a rest unknown that appears in some group's rows).
#[derive(Clone, Debug)]
struct Coupling {
    /// Its position among the rest.
    rest: usize,
    /// `(position in the values, position in the concatenated group unknowns)`.
    entries: Vec<(usize, usize)>,
}

/// Factorisation of a matrix in a fixed pattern by block elimination of its groups.
#[derive(Clone, Debug)]
pub struct SchurLu {
    n: usize,
    /// Global indices of the group unknowns, concatenated in group order.
    grouped: Vec<usize>,
    /// Global indices of the rest, in order.
    rest: Vec<usize>,
    groups: Vec<Group>,
    /// Entries of `D`: `(position in the values, position in the column-major S)`.
    d_entries: Vec<(usize, usize)>,
    couplings: Vec<Coupling>,
    /// Entries of `C` by column (grouped unknown): `c_ptr[e]..c_ptr[e + 1]` into `c_rows`
    /// (row among the rest) and `c_pos` (position in the values); `c_vals` their values at
    /// the last factorisation.
    c_ptr: Vec<usize>,
    c_rows: Vec<usize>,
    c_pos: Vec<usize>,
    c_vals: Vec<f64>,
    /// `W = A⁻¹ B`, row-major: `grouped.len()` rows, one column per coupling.
    w: Vec<f64>,
    s: SmallLu,
    /// Work vectors: the grouped and the rest parts of a right-hand side.
    xe: Vec<f64>,
    xc: Vec<f64>,
    /// Work blocks of [`SchurLu::solve_many_in_place`], row-major (grown on first use).
    many_e: Vec<f64>,
    many_c: Vec<f64>,
    factored: bool,
}

impl SchurLu {
    /// The analysis of `pattern` with the given groups (disjoint index lists), or `None` when
    /// the pattern does not have the structure: an index out of range or in two groups, or an
    /// entry coupling two different groups.
    pub fn analyze(pattern: &CscPattern, groups: &[Vec<usize>]) -> Option<Self> {
        let n = pattern.dim();
        let mut slot = vec![None; n];
        let mut grouped = Vec::new();
        let mut built = Vec::with_capacity(groups.len());
        for (g, indices) in groups.iter().enumerate() {
            let offset = grouped.len();
            for (k, &i) in indices.iter().enumerate() {
                if slot.get(i)?.is_some() {
                    return None;
                }
                slot[i] = Some(Slot::Group(g, k));
                grouped.push(i);
            }
            built.push(Group {
                offset,
                lu: SmallLu::new(indices.len()),
                entries: Vec::new(),
            });
        }
        let mut rest = Vec::new();
        for (i, s) in slot.iter_mut().enumerate() {
            if s.is_none() {
                *s = Some(Slot::Rest(rest.len()));
                rest.push(i);
            }
        }
        let slot: Vec<Slot> = slot.into_iter().flatten().collect();
        let (m, ne) = (rest.len(), grouped.len());
        let mut d_entries = Vec::new();
        let mut couplings: Vec<Coupling> = Vec::new();
        let mut c_cols: Vec<Vec<(usize, usize)>> = vec![Vec::new(); ne];
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        for j in 0..n {
            let mut coupling = Coupling {
                rest: 0,
                entries: Vec::new(),
            };
            for p in cp[j]..cp[j + 1] {
                match (slot[ri[p]], slot[j]) {
                    (Slot::Group(g, a), Slot::Group(h, b)) => {
                        if g != h {
                            return None;
                        }
                        let size = groups[g].len();
                        built[g].entries.push((p, b * size + a));
                    }
                    (Slot::Rest(a), Slot::Rest(b)) => d_entries.push((p, b * m + a)),
                    (Slot::Group(g, a), Slot::Rest(b)) => {
                        coupling.rest = b;
                        coupling.entries.push((p, built[g].offset + a));
                    }
                    (Slot::Rest(a), Slot::Group(h, b)) => {
                        c_cols[built[h].offset + b].push((a, p));
                    }
                }
            }
            if !coupling.entries.is_empty() {
                couplings.push(coupling);
            }
        }
        let mut c_ptr = vec![0];
        let (mut c_rows, mut c_pos) = (Vec::new(), Vec::new());
        for col in &c_cols {
            for &(a, p) in col {
                c_rows.push(a);
                c_pos.push(p);
            }
            c_ptr.push(c_rows.len());
        }
        let nc = c_rows.len();
        let w = vec![0.0; ne * couplings.len()];
        Some(SchurLu {
            n,
            grouped,
            rest,
            groups: built,
            d_entries,
            couplings,
            c_ptr,
            c_rows,
            c_pos,
            c_vals: vec![0.0; nc],
            w,
            s: SmallLu::new(m),
            xe: vec![0.0; ne],
            xc: vec![0.0; m],
            many_e: Vec::new(),
            many_c: Vec::new(),
            factored: false,
        })
    }

    /// Dimension of the whole matrix.
    pub fn dim(&self) -> usize {
        self.n
    }

    /// Dimension of the Schur complement (the unknowns outside every group).
    pub fn reduced_dim(&self) -> usize {
        self.rest.len()
    }

    /// Factorises the matrix whose entries in the analysed pattern are `values`. Singular when
    /// the smallest pivot of the group blocks and of `S` together is at most
    /// [`SINGULAR_PIVOT_RATIO`] times the largest (the test [`super::DenseLu`] makes on its own
    /// pivots).
    pub fn factor(&mut self, values: &[f64]) -> Result<(), LinalgError> {
        self.factored = false;
        if values.iter().any(|v| !v.is_finite()) {
            return Err(LinalgError::NonFinite);
        }
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for group in &mut self.groups {
            let a = group.lu.storage_mut();
            a.fill(0.0);
            for &(p, k) in &group.entries {
                a[k] = values[p];
            }
            group.lu.eliminate();
            for d in group.lu.pivots() {
                lo = lo.min(d.abs());
                hi = hi.max(d.abs());
            }
        }
        // A singular group block: no Schur complement to form.
        if !self.grouped.is_empty() && (lo.is_nan() || lo <= SINGULAR_PIVOT_RATIO * hi) {
            return Err(LinalgError::Singular {
                ratio: if hi > 0.0 { lo / hi } else { 0.0 },
            });
        }
        let m = self.rest.len();
        let ne = self.grouped.len();
        for (v, &p) in self.c_vals.iter_mut().zip(&self.c_pos) {
            *v = values[p];
        }
        let s = self.s.storage_mut();
        s.fill(0.0);
        for &(p, k) in &self.d_entries {
            s[k] = values[p];
        }
        // W = A⁻¹ B (row-major, one column per coupled rest unknown), then S −= C W.
        let nc = self.couplings.len();
        self.w.fill(0.0);
        for (c, coupling) in self.couplings.iter().enumerate() {
            for &(p, e) in &coupling.entries {
                self.w[e * nc + c] = values[p];
            }
        }
        for group in &self.groups {
            let size = group_len(&group.lu);
            group.lu.solve_rows(
                &mut self.w[group.offset * nc..(group.offset + size) * nc],
                nc,
            );
        }
        for (e, row) in self.w.chunks_exact(nc.max(1)).enumerate().take(ne) {
            for k in self.c_ptr[e]..self.c_ptr[e + 1] {
                let (r, cv) = (self.c_rows[k], self.c_vals[k]);
                for (coupling, we) in self.couplings.iter().zip(row) {
                    s[coupling.rest * m + r] -= cv * we;
                }
            }
        }
        self.s.eliminate();
        let mut finite = true;
        for d in self.s.pivots() {
            finite &= d.is_finite();
            lo = lo.min(d.abs());
            hi = hi.max(d.abs());
        }
        if !finite {
            // An overflow in S (its entries are not tested one by one).
            return Err(LinalgError::NonFinite);
        }
        if self.n > 0 && (lo.is_nan() || lo <= SINGULAR_PIVOT_RATIO * hi || !lo.is_finite()) {
            return Err(LinalgError::Singular {
                ratio: if hi > 0.0 { lo / hi } else { 0.0 },
            });
        }
        self.factored = true;
        Ok(())
    }

    /// Solves `A x = b` in place.
    pub fn solve_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.check(b)?;
        let m = self.rest.len();
        for (x, &i) in self.xe.iter_mut().zip(&self.grouped) {
            *x = b[i];
        }
        for (x, &i) in self.xc.iter_mut().zip(&self.rest) {
            *x = b[i];
        }
        // y = A⁻¹ b_E; b_C −= C y; x_C = S⁻¹ b_C; x_E = y − W x_C.
        for group in &self.groups {
            let size = group_len(&group.lu);
            group
                .lu
                .solve(&mut self.xe[group.offset..group.offset + size]);
        }
        for (e, &y) in self.xe.iter().enumerate() {
            if y == 0.0 {
                continue;
            }
            for k in self.c_ptr[e]..self.c_ptr[e + 1] {
                self.xc[self.c_rows[k]] -= self.c_vals[k] * y;
            }
        }
        if m > 0 {
            self.s.solve(&mut self.xc);
        }
        let nc = self.couplings.len();
        if nc > 0 {
            for (x, row) in self.xe.iter_mut().zip(self.w.chunks_exact(nc)) {
                let dot: f64 = (self.couplings.iter().zip(row))
                    .map(|(c, w)| w * self.xc[c.rest])
                    .sum();
                *x -= dot;
            }
        }
        self.scatter(b)
    }

    /// Solves `A X = B` in place for the `k` columns of the column-major `n × k` matrix `b`:
    /// the steps of [`SchurLu::solve_in_place`] on all columns at once (row operations on
    /// row-major blocks, so that the columns share each factor entry: a step sensitivity's 30).
    pub fn solve_many_in_place(&mut self, b: &mut [f64], k: usize) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        let n = self.n;
        check_many_rhs(b.len(), n, k)?;
        let (ne, m, nc) = (self.grouped.len(), self.rest.len(), self.couplings.len());
        self.many_e.resize(ne * k, 0.0);
        self.many_c.resize(m * k, 0.0);
        let (ye, yc) = (&mut self.many_e, &mut self.many_c);
        for (col, bc) in b.chunks_exact(n.max(1)).enumerate().take(k) {
            for (r, &i) in self.grouped.iter().enumerate() {
                ye[r * k + col] = bc[i];
            }
            for (r, &i) in self.rest.iter().enumerate() {
                yc[r * k + col] = bc[i];
            }
        }
        for group in &self.groups {
            let size = group_len(&group.lu);
            group
                .lu
                .solve_rows(&mut ye[group.offset * k..(group.offset + size) * k], k);
        }
        for e in 0..ne {
            let row = &ye[e * k..(e + 1) * k];
            for p in self.c_ptr[e]..self.c_ptr[e + 1] {
                let (r, cv) = (self.c_rows[p], self.c_vals[p]);
                for (x, y) in yc[r * k..(r + 1) * k].iter_mut().zip(row) {
                    *x -= cv * y;
                }
            }
        }
        if m > 0 {
            self.s.solve_rows(yc, k);
        }
        if nc > 0 {
            for (e, wrow) in self.w.chunks_exact(nc).enumerate().take(ne) {
                let row = &mut ye[e * k..(e + 1) * k];
                for (coupling, &w) in self.couplings.iter().zip(wrow) {
                    if w == 0.0 {
                        continue;
                    }
                    for (x, y) in row
                        .iter_mut()
                        .zip(&yc[coupling.rest * k..(coupling.rest + 1) * k])
                    {
                        *x -= w * y;
                    }
                }
            }
        }
        for (col, bc) in b.chunks_exact_mut(n.max(1)).enumerate().take(k) {
            for (r, &i) in self.grouped.iter().enumerate() {
                bc[i] = ye[r * k + col];
            }
            for (r, &i) in self.rest.iter().enumerate() {
                bc[i] = yc[r * k + col];
            }
        }
        if b.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(LinalgError::NonFinite)
        }
    }

    /// Solves `Aᵀ x = b` in place.
    pub fn solve_transpose_in_place(&mut self, b: &mut [f64]) -> Result<(), LinalgError> {
        self.check(b)?;
        let m = self.rest.len();
        let ne = self.grouped.len();
        for (x, &i) in self.xe.iter_mut().zip(&self.grouped) {
            *x = b[i];
        }
        for (x, &i) in self.xc.iter_mut().zip(&self.rest) {
            *x = b[i];
        }
        // x_C = S⁻ᵀ (b_C − Wᵀ b_E); x_E = A⁻ᵀ (b_E − Cᵀ x_C).
        let nc = self.couplings.len();
        for (c, coupling) in self.couplings.iter().enumerate() {
            let dot: f64 = (self.xe.iter().enumerate())
                .map(|(e, x)| self.w[e * nc + c] * x)
                .sum();
            self.xc[coupling.rest] -= dot;
        }
        if m > 0 {
            self.s.solve_transpose(&mut self.xc);
        }
        for e in 0..ne {
            let mut sum = 0.0;
            for k in self.c_ptr[e]..self.c_ptr[e + 1] {
                sum += self.c_vals[k] * self.xc[self.c_rows[k]];
            }
            self.xe[e] -= sum;
        }
        for group in &self.groups {
            let size = group_len(&group.lu);
            group
                .lu
                .solve_transpose(&mut self.xe[group.offset..group.offset + size]);
        }
        self.scatter(b)
    }

    fn check(&self, b: &[f64]) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        if b.len() != self.n {
            return Err(LinalgError::Factorization(format!(
                "right-hand side has {} entries, expected {}",
                b.len(),
                self.n
            )));
        }
        Ok(())
    }

    fn scatter(&self, b: &mut [f64]) -> Result<(), LinalgError> {
        for (x, &i) in self.xe.iter().zip(&self.grouped) {
            b[i] = *x;
        }
        for (x, &i) in self.xc.iter().zip(&self.rest) {
            b[i] = *x;
        }
        if b.iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(LinalgError::NonFinite)
        }
    }
}

fn group_len(lu: &SmallLu) -> usize {
    lu.dim()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::DenseLu;

    /// A step-like pattern: two groups of 3 and 2 unknowns, 4 rest unknowns, the groups coupled
    /// to some rest unknowns and the rest to both groups; values deterministic, not diagonally
    /// dominant, so that rows interchange.
    fn step_like() -> (CscPattern, Vec<f64>, Vec<Vec<usize>>) {
        let n = 9;
        let groups = vec![vec![0, 2, 4], vec![5, 6]];
        let in_group = |i: usize| groups.iter().position(|g| g.contains(&i));
        let mut entries = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let keep = match (in_group(i), in_group(j)) {
                    (Some(a), Some(b)) => a == b,
                    _ => (i * 5 + j * 3) % 4 != 0 || i == j,
                };
                if keep {
                    entries.push((i, j));
                }
            }
        }
        let pattern = CscPattern::from_triplets(n, &entries).expect("valid");
        let mut s: u64 = 7;
        let values = (0..pattern.nnz())
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                2.0 * ((s >> 11) as f64 / (1u64 << 53) as f64) - 1.0
            })
            .collect();
        (pattern, values, groups)
    }

    /// Solves and transposed solves agree with the dense LU of the whole matrix to round-off.
    #[test]
    fn block_elimination_agrees_with_the_dense_lu() {
        let (pattern, values, groups) = step_like();
        let n = pattern.dim();
        let mut schur = SchurLu::analyze(&pattern, &groups).expect("structured");
        assert_eq!(schur.reduced_dim(), 4);
        schur.factor(&values).expect("regular");
        let mut dense = vec![0.0; n * n];
        pattern.to_dense(&values, &mut dense);
        let mut lu = DenseLu::new(n);
        lu.factor(&dense).expect("regular");
        let b: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).cos() + 0.2).collect();
        for transpose in [false, true] {
            let (mut x, mut y) = (b.clone(), b.clone());
            if transpose {
                schur.solve_transpose_in_place(&mut x).expect("solved");
                lu.solve_transpose_in_place(&mut y).expect("solved");
            } else {
                schur.solve_in_place(&mut x).expect("solved");
                lu.solve_in_place(&mut y).expect("solved");
            }
            let err = x
                .iter()
                .zip(&y)
                .map(|(u, v)| (u - v).abs() / v.abs().max(1.0))
                .fold(0.0, f64::max);
            assert!(err <= 1e-12, "transpose = {transpose}: {err:.2e}");
        }
        // Three right-hand sides at once give the single solves.
        let k = 3;
        let cols: Vec<f64> = (0..k)
            .flat_map(|c| b.iter().map(move |v| v * (c as f64 + 1.0) - c as f64))
            .collect();
        let mut many = cols.clone();
        schur.solve_many_in_place(&mut many, k).expect("solved");
        for (c, col) in cols.chunks_exact(n).enumerate() {
            let mut one = col.to_vec();
            schur.solve_in_place(&mut one).expect("solved");
            for (u, v) in many[c * n..(c + 1) * n].iter().zip(&one) {
                assert!(
                    (u - v).abs() <= 1e-13 * v.abs().max(1.0),
                    "column {c}: {u} vs {v}"
                );
            }
        }
    }

    #[test]
    fn coupled_groups_and_singular_matrices_are_refused() {
        let (pattern, values, _) = step_like();
        // Unknowns 0 and 1 are coupled through rest entries: as one group's and another's they
        // would couple two groups.
        assert!(SchurLu::analyze(&pattern, &[vec![0], vec![1]]).is_none());
        assert!(SchurLu::analyze(&pattern, &[vec![0, 2], vec![2]]).is_none());
        assert!(SchurLu::analyze(&pattern, &[vec![9]]).is_none());
        // A zero row in the rest: singular, as the dense LU says.
        let mut singular = values.clone();
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        for j in 0..pattern.dim() {
            for p in cp[j]..cp[j + 1] {
                if ri[p] == 3 {
                    singular[p] = 0.0;
                }
            }
        }
        let mut schur = SchurLu::analyze(&pattern, &[vec![0, 2, 4], vec![5, 6]]).expect("ok");
        assert!(matches!(
            schur.factor(&singular),
            Err(LinalgError::Singular { .. })
        ));
        let mut nan = values;
        nan[0] = f64::NAN;
        assert_eq!(schur.factor(&nan), Err(LinalgError::NonFinite));
        assert_eq!(
            schur.solve_in_place(&mut [0.0; 9]),
            Err(LinalgError::NotFactored)
        );
    }
}
