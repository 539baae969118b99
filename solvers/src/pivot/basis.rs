//! The basis of the pivotal solver, kept as an explicit inverse of its *Schur block*.
//!
//! In Lemke's method for `M z + q + r + s d = 0` most basis columns are unit vectors (`e_i` for
//! a basic `r_i`); the others are columns of `M` or the covering vector `d`. Order the rows so
//! that the unit columns cover the rows `U` and let `N` be the other `m` rows, `C` the `m`
//! non-unit columns. Then `B x = b` splits into `C_N x_C = b_N` and `x_U = b_U − C_U x_C`: only
//! the `m × m` block `C_N` needs an inverse, and `m` is the number of basic `z` variables (plus
//! `s`), which grows from 1 along the path (Cottle, Pang & Stone, "The Linear Complementarity
//! Problem", §4.10 on implementing pivoting methods; the same partition as the bordered and
//! Schur-complement updates of Bisschop & Meeraus and of Gill, Murray, Saunders & Wright).
//!
//! `C_N⁻¹` is stored explicitly and updated at every pivot in `O(m²)`: a column replaced by
//! another (a rank-one update), a unit column leaving (`C_N` grows by a row and a column, a
//! bordering update), a unit column entering (it shrinks), or a unit column replaced by another
//! (one row of `N` exchanged). A solve costs `O(m² + nm)`, against `O(n²)` for a full tableau
//! or a dense LU of `B`. The caller recomputes the inverse from a fresh LU with partial pivoting
//! of `C_N` periodically and before its final solve, and refines the final solution
//! iteratively, so round-off of the updates does not accumulate.
//!
//! The factorisation is written here rather than taken from faer because basis repair needs to
//! know *which* column is dependent (faer's LU only reports that one is).

/// A basis column: a unit vector `e_row`, or dense values (length `n`, indexed by row).
#[derive(Clone, Copy, Debug)]
pub(crate) enum Column<'a> {
    /// `e_row`.
    Unit(usize),
    /// Dense values.
    Dense(&'a [f64]),
}

/// Outcome of a factorisation that found a (numerically) dependent column.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct DependentColumn {
    /// Basis position of the first dependent non-unit column (in position order).
    pub position: usize,
}

/// Marks "none" in the index maps.
const NONE: usize = usize::MAX;

/// Relative pivot size below which a column is treated as dependent on the ones before it.
pub(crate) const DEPENDENCE_TOLERANCE: f64 = 1e-11;

/// The basis as unit columns plus the explicit inverse of the block `C_N` of the others.
#[derive(Debug, Default)]
pub(crate) struct BasisFactor {
    n: usize,
    /// Number of non-unit columns (and of rows in `N`).
    m: usize,
    /// Basis position of slot `j` (the non-unit columns, `j < m`).
    slot_position: Vec<usize>,
    /// Slot of position `p`, or `NONE` for a unit column.
    position_slot: Vec<usize>,
    /// Row of `N` at row slot `k` (`k < m`).
    slot_row: Vec<usize>,
    /// Row slot of row `i`, or `NONE` when row `i` is covered by a unit column.
    row_slot: Vec<usize>,
    /// Position of the unit column `e_i`, or `NONE`.
    unit_position: Vec<usize>,
    /// Non-unit columns, dense, column-major with leading dimension `n`: slot `j` is
    /// `cols[j n .. (j + 1) n]`.
    cols: Vec<f64>,
    /// Largest magnitude of each slot's column over all `n` rows (the scale of `finish`'s
    /// dependence test), taken when the column is given.
    col_norm: Vec<f64>,
    /// `C_N⁻¹`, column-major with leading dimension `n`: `inv[k n + j] = (C_N⁻¹)_{j k}` (row `j`
    /// is a column slot, column `k` a row slot).
    inv: Vec<f64>,
    /// Updates since the last factorisation.
    updates: usize,
    factored: bool,
    /// `inv` holds `C_N⁻¹` (formed from the LU on the first solve that needs it).
    inverse_ready: bool,
    /// Updates are kept as an eta file over this factorisation (product form) instead of being
    /// applied to `C_N⁻¹`: cheaper for the few pivots of a short path when `m` is close to `n`.
    eta_mode: bool,
    /// Eta file: for update `j`, the position replaced and `B⁻¹ a` (length `n`).
    eta_pos: Vec<usize>,
    eta_val: Vec<f64>,
    /// The processor has AVX2 (the LU's trailing update in four lanes); set by `begin`.
    avx2: bool,
    /// Scratch: `m × m` LU, permutation, and vectors of length `n`.
    lu: Vec<f64>,
    perm: Vec<usize>,
    xc: Vec<f64>,
    t: Vec<f64>,
    g: Vec<f64>,
    copy: Vec<f64>,
}

impl BasisFactor {
    /// Number of updates since the last factorisation.
    pub fn updates(&self) -> usize {
        self.updates
    }

    /// True while updates go to the eta file.
    pub fn eta_mode(&self) -> bool {
        self.eta_mode
    }

    /// Starts a factorisation of an `n × n` basis; give every position's column with
    /// [`BasisFactor::set_unit`] or [`BasisFactor::set_dense`], then call
    /// [`BasisFactor::finish`]. Later updates go to an eta file when `eta_mode`, else to the
    /// explicit inverse of `C_N`.
    pub fn begin(&mut self, n: usize, eta_mode: bool) {
        self.avx2 = avx2_available();
        self.n = n;
        self.m = 0;
        self.factored = false;
        self.inverse_ready = false;
        self.eta_mode = eta_mode;
        self.eta_pos.clear();
        self.eta_val.clear();
        self.updates = 0;
        // The maps read before they are written start at NONE; the rest only need their length.
        for v in [
            &mut self.position_slot,
            &mut self.row_slot,
            &mut self.unit_position,
        ] {
            if v.len() == n {
                v.fill(NONE);
            } else {
                v.clear();
                v.resize(n, NONE);
            }
        }
        for v in [&mut self.slot_position, &mut self.slot_row] {
            if v.len() < n {
                v.resize(n, NONE);
            }
        }
        if self.cols.len() < n * n {
            self.cols.resize(n * n, 0.0);
            self.inv.resize(n * n, 0.0);
        }
        if self.col_norm.len() < n {
            self.col_norm.resize(n, 0.0);
        }
        for v in [&mut self.xc, &mut self.t, &mut self.g] {
            if v.len() < n {
                v.resize(n, 0.0);
            }
        }
    }

    /// Position `p` holds the unit column `e_row`.
    pub fn set_unit(&mut self, p: usize, row: usize) {
        self.unit_position[row] = p;
    }

    /// Position `p` holds the dense column `values` (length `n`). Dense columns must be given
    /// in increasing position order: that is the order in which dependence is judged.
    pub fn set_dense(&mut self, p: usize, values: &[f64]) {
        let (n, j) = (self.n, self.m);
        self.cols[j * n..(j + 1) * n].copy_from_slice(&values[..n]);
        self.col_norm[j] = max_abs(&values[..n]);
        self.slot_position[j] = p;
        self.position_slot[p] = j;
        self.m += 1;
    }

    /// Factorises `C_N` by LU with partial pivoting, its columns in slot order, and stores its
    /// inverse. A column whose largest remaining entry is below `DEPENDENCE_TOLERANCE` times its
    /// norm (over all `n` rows) is reported as dependent on the ones before it.
    pub fn finish(&mut self) -> Result<(), DependentColumn> {
        let (n, m) = (self.n, self.m);
        let mut k = 0;
        for i in 0..n {
            if self.unit_position[i] == NONE {
                if k < n {
                    self.slot_row[k] = i;
                }
                self.row_slot[i] = k;
                k += 1;
            }
        }
        if k != m {
            // Two positions with the same unit column, or too few: cannot be a basis.
            return Err(DependentColumn {
                position: if m > 0 { self.slot_position[m - 1] } else { 0 },
            });
        }
        // C_N, column-major with leading dimension m (every entry is written below). Without
        // unit columns every row is in N, in order: a plain copy.
        if self.lu.len() < m * m {
            self.lu.resize(m * m, 0.0);
        }
        if m == n {
            self.lu[..m * m].copy_from_slice(&self.cols[..n * n]);
        } else {
            for j in 0..m {
                let col = &self.cols[j * n..(j + 1) * n];
                for (a, &row) in self.lu[j * m..(j + 1) * m]
                    .iter_mut()
                    .zip(&self.slot_row[..m])
                {
                    *a = col[row];
                }
            }
        }
        self.perm.clear();
        self.perm.extend(0..m);
        let lu = &mut self.lu[..m * m];
        for k in 0..m {
            let col_norm = self.col_norm[k];
            // Partial pivoting: the first row of the largest magnitude (rows k..m), found as
            // the vectorised maximum and then its first occurrence; the same row as a scan
            // keeping a strictly larger value (NaNs skipped by both).
            let below = &lu[k * m + k..(k + 1) * m];
            let best = max_abs(below);
            let piv = k + below.iter().position(|v| v.abs() == best).unwrap_or(0);
            if best <= DEPENDENCE_TOLERANCE * col_norm.max(f64::MIN_POSITIVE) || !best.is_finite() {
                return Err(DependentColumn {
                    position: self.slot_position[k],
                });
            }
            if piv != k {
                for col in lu.chunks_exact_mut(m) {
                    col.swap(k, piv);
                }
                self.perm.swap(k, piv);
            }
            let d = lu[k * m + k];
            for v in &mut lu[k * m + k + 1..(k + 1) * m] {
                *v /= d;
            }
            let (left, right) = lu.split_at_mut((k + 1) * m);
            let lcol = &left[k * m + k + 1..(k + 1) * m];
            #[cfg(target_arch = "x86_64")]
            if self.avx2 {
                // SAFETY: `avx2` is set only when the processor has AVX2.
                unsafe { eliminate_trailing_avx2(right, lcol, k, m) };
                continue;
            }
            eliminate_trailing(right, lcol, k, m);
        }
        self.factored = true;
        Ok(())
    }

    /// Forms `C_N⁻¹ = U⁻¹ L⁻¹ P` from the LU, column by column (column `k` solves with `P e_k`),
    /// the first time an update or a column solve needs it.
    fn ensure_inverse(&mut self) {
        if self.inverse_ready || !self.factored {
            return;
        }
        let (n, m) = (self.n, self.m);
        let lu = &self.lu;
        for r in 0..m {
            let k = self.perm[r];
            let y = &mut self.inv[k * n..k * n + m];
            y.fill(0.0);
            y[r] = 1.0;
            // Columns before `r` are zero and skipped: the same work as starting at `r`.
            substitute(y, lu, m);
        }
        self.inverse_ready = true;
    }

    /// Factorises the `n × n` matrix whose column `k` (basis position `order[k]`) is
    /// `columns[k n .. (k + 1) n]`, all dense (a plain dense LU for one-off solves with
    /// [`BasisFactor::solve`]); dependence is judged in the given order. The tests' entry: the
    /// PATH-like solver's crash step factorises its reduced Jacobian with
    /// `ecp_model::linalg::ColumnTestedLu`, the same elimination and dependence test.
    #[cfg(test)]
    pub fn factor(
        &mut self,
        n: usize,
        columns: &[f64],
        order: &[usize],
    ) -> Result<(), DependentColumn> {
        self.begin(n, true);
        for (k, &p) in order[..n].iter().enumerate() {
            self.set_dense(p, &columns[k * n..(k + 1) * n]);
        }
        self.finish()
    }

    /// `x_C = C_N⁻¹ b_N` by the LU (`b_N` given in `xc` by row slot, overwritten by `x_C` by
    /// column slot).
    fn lu_solve_block(&mut self) {
        let m = self.m;
        let lu = &self.lu;
        let y = &mut self.g[..m];
        for (r, &k) in self.perm[..m].iter().enumerate() {
            y[r] = self.xc[k];
        }
        let lu = &lu[..m * m];
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the processor has AVX2.
            unsafe { substitute_avx2(y, lu, m) };
            self.xc[..m].copy_from_slice(y);
            return;
        }
        substitute(y, lu, m);
        self.xc[..m].copy_from_slice(y);
    }

    /// `out = B⁻¹ a` (`out` indexed by basis position).
    pub fn solve_column(&mut self, a: Column<'_>, out: &mut [f64]) {
        let by_lu = self.eta_mode || !self.inverse_ready;
        self.solve_with(a, out, by_lu);
        self.apply_etas(out);
    }

    /// `x ← E_k⁻¹ ⋯ E_1⁻¹ x`, the eta file oldest first.
    fn apply_etas(&self, x: &mut [f64]) {
        let n = self.n;
        if self.eta_pos.is_empty() || n == 0 {
            return;
        }
        let x = &mut x[..n];
        for (&p, eta) in self.eta_pos.iter().zip(self.eta_val.chunks_exact(n)) {
            let xp = x[p] / eta[p];
            if xp != 0.0 {
                for (xi, e) in x.iter_mut().zip(eta) {
                    *xi -= e * xp;
                }
            }
            x[p] = xp;
        }
    }

    /// `y_N = C_N⁻ᵀ s` by the LU (`s` in `xc` by column slot, `y_N` written into `t` at the rows
    /// of `N`).
    fn lu_solve_block_transpose(&mut self) {
        let m = self.m;
        let lu = &self.lu;
        let v = &mut self.g[..m];
        v.copy_from_slice(&self.xc[..m]);
        // Uᵀ w = s (forward), then Lᵀ v = w (backward); y = Pᵀ v.
        for c in 0..m {
            let dot: f64 = lu[c * m..c * m + c]
                .iter()
                .zip(&v[..c])
                .map(|(u, w)| u * w)
                .sum();
            v[c] = (v[c] - dot) / lu[c * m + c];
        }
        for c in (0..m).rev() {
            let dot: f64 = lu[c * m + c + 1..(c + 1) * m]
                .iter()
                .zip(&v[c + 1..])
                .map(|(l, t)| l * t)
                .sum();
            v[c] -= dot;
        }
        for (r, &k) in self.perm[..m].iter().enumerate() {
            self.t[self.slot_row[k]] = v[r];
        }
    }

    /// `out = B⁻¹ a`, with `C_N⁻¹` applied by the LU when `by_lu` (only right after a
    /// factorisation), else by the explicit inverse.
    fn solve_with(&mut self, a: Column<'_>, out: &mut [f64], by_lu: bool) {
        if !self.factored {
            return;
        }
        let (n, m) = (self.n, self.m);
        if m == 0 {
            // Every basis column is a unit column (the start of an LCP path, and its eta file's
            // base): `B₀⁻¹ a` is `a` permuted, with no block to solve.
            match a {
                Column::Dense(b) => {
                    for (&p, &v) in self.unit_position[..n].iter().zip(&b[..n]) {
                        out[p] = v;
                    }
                }
                Column::Unit(row) => {
                    out[..n].fill(0.0);
                    out[self.unit_position[row]] = 1.0;
                }
            }
            return;
        }
        if by_lu {
            match a {
                Column::Dense(b) => {
                    for (x, &row) in self.xc[..m].iter_mut().zip(&self.slot_row[..m]) {
                        *x = b[row];
                    }
                }
                Column::Unit(row) => {
                    let k = self.row_slot[row];
                    if k == NONE {
                        out[..n].fill(0.0);
                        out[self.unit_position[row]] = 1.0;
                        return;
                    }
                    self.xc[..m].fill(0.0);
                    self.xc[k] = 1.0;
                }
            }
            self.lu_solve_block();
        }
        let xc = &mut self.xc[..m];
        match a {
            _ if by_lu => {}
            Column::Unit(row) => {
                let k = self.row_slot[row];
                if k == NONE {
                    // e_row is a basis column.
                    out[..n].fill(0.0);
                    out[self.unit_position[row]] = 1.0;
                    return;
                }
                xc.copy_from_slice(&self.inv[k * n..k * n + m]);
            }
            Column::Dense(b) => {
                xc.fill(0.0);
                for (k, &row) in self.slot_row[..m].iter().enumerate() {
                    let bk = b[row];
                    if bk != 0.0 {
                        for (x, v) in xc.iter_mut().zip(&self.inv[k * n..k * n + m]) {
                            *x += bk * v;
                        }
                    }
                }
            }
        }
        // x_U = a_U − C_U x_C. When the unit rows are few (m close to n, the linearisations of
        // the PATH-like solver) and the block fits in cache, only those rows.
        if 2 * (n - m) < n && n <= 128 {
            for (i, &p) in self.unit_position[..n].iter().enumerate() {
                if p != NONE {
                    let mut v = match a {
                        Column::Unit(row) => f64::from(u8::from(row == i)),
                        Column::Dense(b) => b[i],
                    };
                    for (j, &x) in xc.iter().enumerate() {
                        v -= x * self.cols[j * n + i];
                    }
                    out[p] = v;
                }
            }
            for (j, &x) in xc.iter().enumerate() {
                out[self.slot_position[j]] = x;
            }
            return;
        }
        // Otherwise on every row (the N rows are not read).
        let t = &mut self.t[..n];
        match a {
            Column::Unit(row) => {
                t.fill(0.0);
                t[row] = 1.0;
            }
            Column::Dense(b) => t.copy_from_slice(&b[..n]),
        }
        for (j, &x) in xc.iter().enumerate() {
            if x != 0.0 {
                for (ti, c) in t.iter_mut().zip(&self.cols[j * n..(j + 1) * n]) {
                    *ti -= x * c;
                }
            }
        }
        for (i, &p) in self.unit_position[..n].iter().enumerate() {
            if p != NONE {
                out[p] = t[i];
            }
        }
        for (j, &x) in xc.iter().enumerate() {
            out[self.slot_position[j]] = x;
        }
    }

    /// Solves `B x = b` in place (`b` indexed by equation, `x` by basis position): by the LU
    /// right after a factorisation, by the explicit inverse once it is updated.
    pub fn solve(&mut self, b: &mut [f64]) {
        let mut copy = std::mem::take(&mut self.copy);
        copy.clear();
        copy.extend_from_slice(&b[..self.n]);
        let by_lu = self.eta_mode || !self.inverse_ready;
        self.solve_with(Column::Dense(&copy), b, by_lu);
        self.apply_etas(b);
        self.copy = copy;
    }

    /// Solves `Bᵀ y = c` in place (`c` indexed by basis position, `y` by equation).
    pub fn solve_transpose(&mut self, c: &mut [f64]) {
        if !self.factored {
            return;
        }
        let n = self.n;
        // Bᵀ = E_kᵀ ⋯ E_1ᵀ B₀ᵀ: the eta file newest first, each changing only entry p.
        for (j, &p) in self.eta_pos.iter().enumerate().rev() {
            let eta = &self.eta_val[j * n..(j + 1) * n];
            let dot: f64 = c[..n].iter().zip(eta).map(|(a, b)| a * b).sum();
            c[p] = (c[p] - (dot - c[p] * eta[p])) / eta[p];
        }
        let by_lu = self.eta_mode || !self.inverse_ready;
        let m = self.m;
        // y_U = c at the unit positions; s = c_C − C_Uᵀ y_U; y_N = C_N⁻ᵀ s.
        let y = &mut self.t[..n];
        for (i, &p) in self.unit_position[..n].iter().enumerate() {
            y[i] = if p != NONE { c[p] } else { 0.0 };
        }
        let s = &mut self.xc[..m];
        for (j, sj) in s.iter_mut().enumerate() {
            let dot: f64 = self.cols[j * n..(j + 1) * n]
                .iter()
                .zip(y.iter())
                .map(|(a, b)| a * b)
                .sum();
            *sj = c[self.slot_position[j]] - dot;
        }
        if by_lu {
            self.lu_solve_block_transpose();
        } else {
            for k in 0..m {
                let yk: f64 = self.inv[k * n..k * n + m]
                    .iter()
                    .zip(s.iter())
                    .map(|(a, b)| a * b)
                    .sum();
                y[self.slot_row[k]] = yk;
            }
        }
        c[..n].copy_from_slice(&self.t[..n]);
    }

    /// Position `p` now holds `column`, with `alpha = B⁻¹ column` computed with the basis
    /// before the update (`alpha[p]` is the pivot, not 0).
    pub fn update(&mut self, p: usize, column: Column<'_>, alpha: &[f64]) {
        if self.eta_mode {
            self.eta_pos.push(p);
            self.eta_val.extend_from_slice(&alpha[..self.n]);
            self.updates += 1;
            return;
        }
        self.ensure_inverse();
        let n = self.n;
        let m = self.m;
        let piv = alpha[p];
        let slot = self.position_slot[p];
        // alpha restricted to the non-unit slots.
        for j in 0..m {
            self.xc[j] = alpha[self.slot_position[j]];
        }
        match (slot != NONE, column) {
            (true, Column::Dense(values)) => {
                // A column of C replaced: row j of C_N⁻¹ divided by the pivot, the others
                // reduced by it.
                let j = slot;
                for k in 0..m {
                    let col = &mut self.inv[k * n..k * n + m];
                    let f = col[j] / piv;
                    if f != 0.0 {
                        for (v, a) in col.iter_mut().zip(&self.xc[..m]) {
                            *v -= a * f;
                        }
                    }
                    col[j] = f;
                }
                self.cols[j * n..(j + 1) * n].copy_from_slice(&values[..n]);
            }
            (false, Column::Dense(values)) => {
                // e_i leaves, a dense column enters: row i joins N and the column joins C.
                let i = self.row_of_unit(p);
                self.compute_g(i);
                for k in 0..m {
                    let gk = self.g[k] / piv;
                    let col = &mut self.inv[k * n..k * n + m + 1];
                    if gk != 0.0 {
                        for (v, a) in col[..m].iter_mut().zip(&self.xc[..m]) {
                            *v += a * gk;
                        }
                    }
                    col[m] = -gk;
                }
                let col = &mut self.inv[m * n..m * n + m + 1];
                for (v, a) in col[..m].iter_mut().zip(&self.xc[..m]) {
                    *v = -a / piv;
                }
                col[m] = 1.0 / piv;
                self.cols[m * n..(m + 1) * n].copy_from_slice(&values[..n]);
                self.slot_position[m] = p;
                self.position_slot[p] = m;
                self.slot_row[m] = i;
                self.row_slot[i] = m;
                self.unit_position[i] = NONE;
                self.m = m + 1;
            }
            (true, Column::Unit(row)) => {
                // A dense column leaves, e_row enters: row `row` leaves N and slot j leaves C.
                let j = slot;
                let s = self.row_slot[row];
                for k in 0..m {
                    if k == s {
                        continue;
                    }
                    let (pivot_col, col) = two_columns(&mut self.inv, n, m, s, k);
                    let f = col[j] / piv;
                    if f != 0.0 {
                        for (v, a) in col.iter_mut().zip(pivot_col.iter()) {
                            *v -= a * f;
                        }
                    }
                }
                // Remove row j (move the last slot into it) and column s (likewise).
                let last = m - 1;
                for k in 0..m {
                    self.inv[k * n + j] = self.inv[k * n + last];
                }
                if s != last {
                    self.inv.copy_within(last * n..last * n + last, s * n);
                }
                if j != last {
                    self.cols.copy_within(last * n..(last + 1) * n, j * n);
                    let moved = self.slot_position[last];
                    self.slot_position[j] = moved;
                    self.position_slot[moved] = j;
                }
                self.position_slot[p] = NONE;
                if s != last {
                    let moved = self.slot_row[last];
                    self.slot_row[s] = moved;
                    self.row_slot[moved] = s;
                }
                self.row_slot[row] = NONE;
                self.unit_position[row] = p;
                self.m = last;
            }
            (false, Column::Unit(row)) => {
                // e_i leaves and e_row enters: row i takes row `row`'s place in N.
                let i = self.row_of_unit(p);
                let s = self.row_slot[row];
                self.compute_g(i);
                for k in 0..m {
                    if k == s {
                        continue;
                    }
                    let gk = self.g[k] / piv;
                    if gk != 0.0 {
                        let (pivot_col, col) = two_columns(&mut self.inv, n, m, s, k);
                        for (v, a) in col.iter_mut().zip(pivot_col.iter()) {
                            *v += a * gk;
                        }
                    }
                }
                for v in &mut self.inv[s * n..s * n + m] {
                    *v = -*v / piv;
                }
                self.slot_row[s] = i;
                self.row_slot[i] = s;
                self.row_slot[row] = NONE;
                self.unit_position[i] = NONE;
                self.unit_position[row] = p;
            }
        }
        self.updates += 1;
    }

    /// The row of the unit column at position `p`.
    fn row_of_unit(&self, p: usize) -> usize {
        self.unit_position[..self.n]
            .iter()
            .position(|&q| q == p)
            .unwrap_or(0)
    }

    /// `g = C(i, :) C_N⁻¹` (row `i` of the non-unit columns times the inverse), length `m`.
    fn compute_g(&mut self, i: usize) {
        let (n, m) = (self.n, self.m);
        for j in 0..m {
            self.t[j] = self.cols[j * n + i];
        }
        for k in 0..m {
            self.g[k] = self.inv[k * n..k * n + m]
                .iter()
                .zip(&self.t[..m])
                .map(|(a, b)| a * b)
                .sum();
        }
    }
}

/// The trailing update of step `k` of the LU: each column `col` (length `m`) of `right` loses
/// `col[k]` times the multipliers `lcol` below row `k`. Element by element, so the vector
/// widths of the two versions give bitwise the same factors (no fused multiply-add).
#[inline(always)]
fn eliminate_trailing(right: &mut [f64], lcol: &[f64], k: usize, m: usize) {
    for col in right.chunks_exact_mut(m) {
        let a = col[k];
        if a != 0.0 {
            for (c, l) in col[k + 1..].iter_mut().zip(lcol) {
                *c -= a * l;
            }
        }
    }
}

/// [`eliminate_trailing`] compiled for AVX2 (four lanes; the portable build has two). The
/// desk's linearisations factor blocks of about 30 × 30, where this loop is most of the cost.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn eliminate_trailing_avx2(right: &mut [f64], lcol: &[f64], k: usize, m: usize) {
    eliminate_trailing(right, lcol, k, m);
}

/// `y ← U⁻¹ L⁻¹ y` with the `m × m` LU `lu` (column-major, unit lower triangle below the
/// diagonal): forward then backward substitution by columns, each column's update element by
/// element, so the vector widths of [`substitute_avx2`] and the portable build give bitwise
/// the same solution (no fused multiply-add).
#[inline(always)]
fn substitute(y: &mut [f64], lu: &[f64], m: usize) {
    for c in 0..m {
        let yc = y[c];
        if yc != 0.0 {
            for (yi, l) in y[c + 1..].iter_mut().zip(&lu[c * m + c + 1..(c + 1) * m]) {
                *yi -= yc * l;
            }
        }
    }
    for c in (0..m).rev() {
        y[c] /= lu[c * m + c];
        let yc = y[c];
        if yc != 0.0 {
            for (yi, u) in y[..c].iter_mut().zip(&lu[c * m..c * m + c]) {
                *yi -= yc * u;
            }
        }
    }
}

/// [`substitute`] compiled for AVX2 (four lanes; the portable build has two). PATH's crash and
/// chord steps solve with the LU of the desk's reduced Jacobian three times per step, a sixth
/// of the step's instructions in two lanes.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn substitute_avx2(y: &mut [f64], lu: &[f64], m: usize) {
    substitute(y, lu, m);
}

/// `max_i |v_i|` (0 for an empty slice; NaNs skipped), as `fold(0.0, |a, v| a.max(v.abs()))`
/// but in four independent lanes so that it vectorises. The maximum does not depend on the
/// order of the comparisons, so the result is the fold's exactly.
pub(crate) fn max_abs(values: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let mut chunks = values.chunks_exact(4);
    for c in &mut chunks {
        for (a, v) in acc.iter_mut().zip(c) {
            let v = v.abs();
            *a = if v > *a { v } else { *a };
        }
    }
    for v in chunks.remainder() {
        let v = v.abs();
        acc[0] = if v > acc[0] { v } else { acc[0] };
    }
    acc.iter().fold(0.0f64, |a, &v| if v > a { v } else { a })
}

/// Whether the processor has AVX2 (the standard library caches the answer).
fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Columns `s` (read) and `k` (written) of a column-major matrix with leading dimension `n`,
/// `m` entries each (`s ≠ k`).
fn two_columns(a: &mut [f64], n: usize, m: usize, s: usize, k: usize) -> (&[f64], &mut [f64]) {
    if s < k {
        let (lo, hi) = a.split_at_mut(k * n);
        (&lo[s * n..s * n + m], &mut hi[..m])
    } else {
        let (lo, hi) = a.split_at_mut(s * n);
        (&hi[..m], &mut lo[k * n..k * n + m])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `B` column-major from the columns' description.
    fn dense(n: usize, columns: &[Option<Vec<f64>>], units: &[usize]) -> Vec<f64> {
        let mut a = vec![0.0; n * n];
        for p in 0..n {
            match &columns[p] {
                Some(c) => a[p * n..(p + 1) * n].copy_from_slice(c),
                None => a[p * n + units[p]] = 1.0,
            }
        }
        a
    }

    fn check(n: usize, f: &mut BasisFactor, a: &[f64], step: usize) {
        let b: Vec<f64> = (0..n).map(|i| i as f64 - 1.5).collect();
        let mut x = b.clone();
        f.solve(&mut x);
        for i in 0..n {
            let s: f64 = (0..n).map(|p| a[p * n + i] * x[p]).sum();
            assert!(
                (s - b[i]).abs() < 1e-12,
                "step {step}: row {i}: {s} vs {}",
                b[i]
            );
        }
        let c: Vec<f64> = (0..n).map(|i| (i * i) as f64 * 0.1 - 0.7).collect();
        let mut y = c.clone();
        f.solve_transpose(&mut y);
        for p in 0..n {
            let s: f64 = (0..n).map(|i| a[p * n + i] * y[i]).sum();
            assert!(
                (s - c[p]).abs() < 1e-12,
                "transpose step {step}: {s} vs {}",
                c[p]
            );
        }
    }

    /// A basis of unit columns only (`m = 0`, Lemke's start on an LCP) solves by permuting the
    /// right-hand side, bitwise (signed zeros included), at the start and after updates that
    /// bring the block back to `m = 0`.
    #[test]
    fn an_all_unit_basis_solves_by_permutation_bitwise() {
        let n = 5;
        let units = [3, 0, 4, 1, 2];
        let a = [0.5, -1.25, 3.0, -0.0, 7.5];
        for eta_mode in [false, true] {
            let mut f = BasisFactor::default();
            f.begin(n, eta_mode);
            for (p, &row) in units.iter().enumerate() {
                f.set_unit(p, row);
            }
            f.finish().unwrap();
            let mut out = vec![f64::NAN; n];
            f.solve_column(Column::Dense(&a), &mut out);
            for p in 0..n {
                assert_eq!(out[p].to_bits(), a[units[p]].to_bits(), "position {p}");
            }
            f.solve_column(Column::Unit(4), &mut out);
            for p in 0..n {
                assert_eq!(out[p], if units[p] == 4 { 1.0 } else { 0.0 });
            }
            let mut b = a;
            f.solve(&mut b);
            for p in 0..n {
                assert_eq!(b[p].to_bits(), a[units[p]].to_bits(), "solve, position {p}");
            }
            // A dense column replaces e_0 (m = 1), then e_0 comes back (m = 0 again).
            let c = [1.0, 2.0, 0.5, -1.0, 4.0];
            f.solve_column(Column::Dense(&c), &mut out);
            let alpha = out.clone();
            f.update(1, Column::Dense(&c), &alpha);
            f.solve_column(Column::Unit(0), &mut out);
            let alpha = out.clone();
            f.update(1, Column::Unit(0), &alpha);
            f.solve_column(Column::Dense(&a), &mut out);
            for p in 0..n {
                assert!(
                    (out[p] - a[units[p]]).abs() < 1e-14,
                    "after updates, position {p}"
                );
            }
        }
    }

    #[test]
    fn every_kind_of_update_keeps_the_solves_exact() {
        for eta_mode in [false, true] {
            updates_keep_the_solves_exact(eta_mode);
        }
    }

    fn updates_keep_the_solves_exact(eta_mode: bool) {
        let n = 6;
        let dense_col = |seed: usize, dominant: usize| -> Vec<f64> {
            (0..n)
                .map(|i| {
                    if i == dominant {
                        5.0
                    } else {
                        ((seed * 31 + i * 17) % 11) as f64 / 11.0 - 0.5
                    }
                })
                .collect()
        };
        // Start: positions 0 and 2 dense, the others e_1, e_3, e_4, e_5 (N = rows 0 and 2).
        let mut columns: Vec<Option<Vec<f64>>> = vec![None; n];
        let mut units = vec![0; n];
        columns[0] = Some(dense_col(1, 0));
        columns[2] = Some(dense_col(2, 2));
        units[1] = 1;
        units[3] = 3;
        units[4] = 4;
        units[5] = 5;
        let mut f = BasisFactor::default();
        f.begin(n, eta_mode);
        for p in 0..n {
            match &columns[p] {
                Some(c) => f.set_dense(p, c),
                None => f.set_unit(p, units[p]),
            }
        }
        f.finish().unwrap();
        check(n, &mut f, &dense(n, &columns, &units), 0);
        // (position, new column): unit → dense, dense → dense, dense → unit, unit → unit.
        let steps: Vec<(usize, Option<Vec<f64>>, usize)> = vec![
            (3, Some(dense_col(3, 3)), 0),
            (0, Some(dense_col(4, 0)), 0),
            (4, Some(dense_col(5, 4)), 0),
            (2, None, 2),
            (5, None, 0),
            (1, Some(dense_col(6, 1)), 0),
            (3, None, 5),
        ];
        for (step, (p, new, row)) in steps.into_iter().enumerate() {
            let column = match &new {
                Some(c) => Column::Dense(c),
                None => Column::Unit(row),
            };
            let mut alpha = vec![0.0; n];
            f.solve_column(column, &mut alpha);
            assert!(alpha[p].abs() > 1e-3, "step {step}: pivot {}", alpha[p]);
            f.update(p, column, &alpha);
            columns[p] = new;
            units[p] = row;
            check(n, &mut f, &dense(n, &columns, &units), step + 1);
        }
        assert_eq!(f.updates(), 7);
    }

    /// The AVX2 trailing update gives bitwise the factors of the portable one (both subtract
    /// `a · l` element by element, no fused multiply-add) on a 31 × 31 block with zeros.
    #[test]
    fn avx2_trailing_update_gives_the_portable_factors_bitwise() {
        let n = 31;
        let mut runs = Vec::new();
        for avx2 in [false, true] {
            let mut f = BasisFactor::default();
            f.begin(n, false);
            if avx2 && !f.avx2 {
                return; // no AVX2 here: nothing to compare
            }
            f.avx2 = avx2;
            for p in 0..n {
                let col: Vec<f64> = (0..n)
                    .map(|i| {
                        let v = ((p * 37 + i * 11) % 17) as f64 / 7.0 - 1.1;
                        if (p + 2 * i) % 5 == 0 {
                            0.0
                        } else {
                            v + f64::from(u8::from(i == p)) * 3.0
                        }
                    })
                    .collect();
                f.set_dense(p, &col);
            }
            f.finish().unwrap();
            runs.push(
                f.lu[..n * n]
                    .iter()
                    .map(|v| v.to_bits())
                    .collect::<Vec<_>>(),
            );
        }
        assert_eq!(runs[0], runs[1]);
    }

    /// The AVX2 substitution gives bitwise the portable one's solution (the same LU, several
    /// right-hand sides with zeros, so the skipped columns are exercised too).
    #[test]
    fn avx2_substitution_gives_the_portable_solution_bitwise() {
        let n = 29;
        let mut f = BasisFactor::default();
        f.begin(n, false);
        if !f.avx2 {
            return; // no AVX2 here: nothing to compare
        }
        for p in 0..n {
            let col: Vec<f64> = (0..n)
                .map(|i| {
                    let v = ((p * 29 + i * 13) % 19) as f64 / 5.0 - 1.7;
                    v + f64::from(u8::from(i == p)) * 4.0
                })
                .collect();
            f.set_dense(p, &col);
        }
        f.finish().unwrap();
        for r in 0..4 {
            let b: Vec<f64> = (0..n)
                .map(|i| {
                    if (i + r) % 3 == 0 {
                        0.0
                    } else {
                        ((i * 7 + r * 5) % 11) as f64 / 3.0 - 1.3
                    }
                })
                .collect();
            let mut runs = Vec::new();
            for avx2 in [false, true] {
                f.avx2 = avx2;
                let mut x = b.clone();
                f.solve(&mut x);
                runs.push(x.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
                // It is a solve: the residual of B x = b is at round-off.
                let mut worst = 0.0f64;
                for i in 0..n {
                    let mut s = -b[i];
                    for (p, xp) in x.iter().enumerate() {
                        let v = ((p * 29 + i * 13) % 19) as f64 / 5.0 - 1.7;
                        s += (v + f64::from(u8::from(i == p)) * 4.0) * xp;
                    }
                    worst = worst.max(s.abs());
                }
                assert!(worst <= 1e-12, "{worst}");
            }
            assert_eq!(runs[0], runs[1], "right-hand side {r}");
        }
    }

    /// `max_abs` in four lanes gives exactly the sequential fold's maximum, NaNs skipped, on
    /// every length up to 11 (the lanes' remainders) and with −0, ∞ and NaN anywhere.
    #[test]
    fn max_abs_is_the_sequential_folds_maximum() {
        let pool = [
            0.5,
            -2.25,
            f64::NAN,
            -0.0,
            3.0,
            -3.0,
            1e-300,
            f64::NEG_INFINITY,
            7.5,
            -7.5,
            0.0,
        ];
        for len in 0..=pool.len() {
            for shift in 0..pool.len() {
                let v: Vec<f64> = (0..len).map(|i| pool[(i + shift) % pool.len()]).collect();
                let fold = v.iter().fold(0.0f64, |a, x| a.max(x.abs()));
                assert_eq!(max_abs(&v).to_bits(), fold.to_bits(), "{v:?}");
            }
        }
        assert_eq!(max_abs(&[f64::NAN, -4.0, f64::NAN]), 4.0);
        assert_eq!(max_abs(&[]), 0.0);
    }

    /// Partial pivoting takes the first row of the largest magnitude: in column 0 of
    /// `[[1, 0, 2], [−3, 1, 0], [3, 0, 1]]` (rows) rows 1 and 2 tie at 3, and row 1 is the pivot
    /// row; the factors then solve `A x = b` to 1e-15.
    #[test]
    fn lu_pivots_on_the_first_largest_entry() {
        let n = 3;
        // Column-major columns of A.
        let columns = [1.0, -3.0, 3.0, 0.0, 1.0, 0.0, 2.0, 0.0, 1.0];
        let mut f = BasisFactor::default();
        f.factor(n, &columns, &[0, 1, 2]).unwrap();
        assert_eq!(f.perm[0], 1);
        assert_eq!(f.lu[0], -3.0);
        let b = [1.0, 2.0, 3.0];
        let mut x = b;
        f.solve(&mut x);
        for i in 0..n {
            let s: f64 = (0..n).map(|j| columns[j * n + i] * x[j]).sum();
            assert!((s - b[i]).abs() < 1e-15, "row {i}: {s} vs {}", b[i]);
        }
    }

    #[test]
    fn basis_reports_the_dependent_column() {
        let n = 3;
        // Columns e0, (1, 1, 0), (2, 2, 0): the third depends on the second and e0.
        let mut f = BasisFactor::default();
        f.begin(n, false);
        f.set_unit(0, 0);
        f.set_dense(1, &[1.0, 1.0, 0.0]);
        f.set_dense(2, &[2.0, 2.0, 0.0]);
        assert_eq!(f.finish(), Err(DependentColumn { position: 2 }));
    }
}
