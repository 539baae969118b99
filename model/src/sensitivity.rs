//! Sensitivities of an MCP solution by implicit differentiation with the active set.
//!
//! At a solution `z*` of the MCP `(l, u, F(·; θ))` (`docs/model.md#mcp`) each component is
//!
//! - **free** (`l_i < z_i < u_i`, so `F_i = 0`): its row of the implicit function theorem is
//!   `J_i dz + ∂F_i/∂θ dθ = 0`;
//! - **strongly active** (at a bound with `F_i` strictly away from 0, of the right sign): a small
//!   change of θ keeps it at the bound, `dz_i = 0`;
//! - **weakly active** (at a bound with `F_i ≈ 0`: `p_n = 0` at a touching contact, `σ = 0` on
//!   the stick/slip boundary, a face multiplier 0 with the ECP on that face's edge): the solution
//!   map has a kink there and only one-sided derivatives exist. **Choice made here: they are held
//!   at the bound like the strongly active ones** (`dz_i = 0`, the derivative of the branch that
//!   keeps the active set), and each is reported with the largest derivative `|dF_i/dθ_k|` of its
//!   residual along that branch. When that slope is zero (to a tolerance) the branch never leaves
//!   the bound to first order and the derivative is two-sided after all — the gap multiplier
//!   `l_g` of every closed contact is such a case; otherwise the derivative is one-sided, valid
//!   for the perturbations that make `F_i ≥ 0` (`≤ 0` at an upper bound), and the caller should
//!   report it;
//! - **held** by the caller, who knows more than the bounds say (a separated contact's friction
//!   impulses, `≡ 0` by the ellipsoid's cone, [`ComponentStatus::Held`]).
//!
//! Held rows become unit rows, the others stay rows of `J`: the **reduced matrix** `A`, with the
//! sparsity pattern of `J` (whose diagonal is always stored), so the linear solver's symbolic
//! analysis is done once and reused for every step and every active set. Then
//! `dz/dθ = −A⁻¹ P ∂F/∂θ` where `P` zeroes the held rows.
//!
//! **The free block.** Since `dz_h = 0` for the held components, that is `A_ff dz_f = −b_f` on
//! the free rows and columns alone; with the small dense kernel (below) only `A_ff` is
//! factorised, its entries gathered from `J` by a list built once per held mask, and the whole
//! `A` is formed only for the regularised fallback
//! (`docs/latency.md#the-desk-step-sensitivity-on-the-free-block-allocation-free-branch-wip-sensfast2-issue-18`).
//!
//! **Singular `A`** (non-unique multipliers, an ECP free to slide over a face parallel to the
//! plane, impulses shared between pieces): the solve falls back to the minimum-norm solution by
//! iterated Tikhonov regularisation, `x ← x + (AᵀA + λI)⁻¹ Aᵀ (b − A x)` eight times from 0
//! with `λ = 1e-10 max diag(AᵀA)` (dense, with [`DenseLu`]), which converges to the
//! minimum-norm solution of a consistent system on every well-determined mode and leaves the
//! null space at 0. [`SolveKind::Regularised`] reports it with the relative residual
//! `‖b − A x‖∞ / ‖b‖∞` of the worst column: near 0 means the system was consistent (the
//! undetermined components got their minimum-norm derivative, the determined ones are exact);
//! large means no derivative exists (a mode switch) and the numbers are a least-squares guess.
//!
//! **Why not the backend's factorisation.** Backends factorise the matrix of their own method
//! (Newton: the Fischer–Burmeister Jacobian at the last iterate but one, possibly a
//! Levenberg–Marquardt normal matrix; PATH: a Lemke basis; conic: a KKT system), behind the
//! [`crate::McpSolver`] trait. At a strictly complementary solution the Fischer–Burmeister
//! Jacobian is exactly `A` (its derivative at `(0, F > 0)` is `(1, 0)`, at `(z > 0, 0)` it is
//! `(0, 1)`), but evaluated at `z*`, not at the previous iterate; so this module factorises `A`
//! once at `z*` — one numeric factorisation per step, reusing the symbolic analysis — and solves
//! every θ column (or, for gradients, one transposed system) with it.
//!
//! **The θ columns together.** With the small dense kernel (up to
//! [`crate::linalg::SMALL_DENSE_MAX`] unknowns) the `p` columns are solved as the rows of one
//! row-major `n × p` matrix by the kernel's row-oriented triangular solves (each solution row
//! accumulated across up to 32 columns in vector registers, the free rows solved where they
//! lie), and the weak components' slopes are formed from that row-major solution, one vector
//! loop per stored entry of a weak row
//! (`docs/latency.md#the-desk-step-sensitivity-by-rows-branch-wip-sensfast-issue-18`, and the
//! section of branch wip-sens3). The results differ from faer's blocked solves, kept behind
//! [`ReducedSystem::with_blocked_columns`], by round-off only.

use std::sync::Arc;

use crate::linalg::{
    DenseLu, LinalgError, LinearSolver, add_row_combination, transpose, transpose_checked,
};
use crate::mcp::Mcp;
use crate::pattern::CscPattern;

/// How a component of `z` sits at a solution (module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ComponentStatus {
    /// Strictly between its bounds: its row of `J` is kept.
    Free,
    /// At a bound with its residual strictly of the complementary sign: `dz_i = 0`.
    Active,
    /// At a bound with residual ≈ 0 (degenerate): held at the bound, `dz_i = 0`, reported.
    WeaklyActive,
    /// Held by the caller (`dz_i = 0`) for a reason the bounds do not show.
    Held,
}

impl ComponentStatus {
    /// True when `dz_i = 0` is imposed (every status but [`ComponentStatus::Free`]).
    pub fn is_held(&self) -> bool {
        !matches!(self, ComponentStatus::Free)
    }
    /// A short lower-case label for reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            ComponentStatus::Free => "free",
            ComponentStatus::Active => "active",
            ComponentStatus::WeaklyActive => "weakly_active",
            ComponentStatus::Held => "held",
        }
    }
}

impl std::fmt::Display for ComponentStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Tolerances of the active-set classification and of the degeneracy report.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActiveSetOptions {
    /// A component is at a bound when `|z_i − bound| ≤ tolerance`, and weakly active when also
    /// `|F_i| ≤ tolerance`. Absolute, in the units of `z` and `F`; it must exceed the accuracy of
    /// the solve (the steppers' natural residuals are ≤ 1e-10). Default `1e-8`.
    pub tolerance: f64,
    /// A weakly active component is two-sided when its residual's slope along the held branch,
    /// `max_k |dF_i/dθ_k|`, is at most this times `max(1, max_k ‖∂F/∂θ_k‖∞)`. Default `1e-8`.
    pub two_sided_tolerance: f64,
}

impl Default for ActiveSetOptions {
    fn default() -> Self {
        ActiveSetOptions {
            tolerance: 1e-8,
            two_sided_tolerance: 1e-8,
        }
    }
}

/// Classifies every component of a solution `z` with residual `f` and bounds `lower, upper`
/// (module documentation). Components whose residual has the wrong sign at a bound (not a
/// solution to the tolerance) count as weakly active, so they are reported, not hidden.
pub fn classify(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    opts: &ActiveSetOptions,
) -> Vec<ComponentStatus> {
    let mut status = Vec::with_capacity(z.len());
    classify_into(z, f, lower, upper, opts, &mut status);
    status
}

/// [`classify`] into `status` (cleared first; no allocation once it has the capacity).
pub fn classify_into(
    z: &[f64],
    f: &[f64],
    lower: &[f64],
    upper: &[f64],
    opts: &ActiveSetOptions,
    status: &mut Vec<ComponentStatus>,
) {
    let tol = opts.tolerance;
    status.clear();
    status.extend((0..z.len()).map(|i| {
        let (l, u) = (lower[i], upper[i]);
        if l == u {
            return ComponentStatus::Active;
        }
        let at_lower = l.is_finite() && z[i] - l <= tol;
        let at_upper = u.is_finite() && u - z[i] <= tol;
        if at_lower {
            if f[i] > tol {
                ComponentStatus::Active
            } else {
                ComponentStatus::WeaklyActive
            }
        } else if at_upper {
            if -f[i] > tol {
                ComponentStatus::Active
            } else {
                ComponentStatus::WeaklyActive
            }
        } else {
            ComponentStatus::Free
        }
    }));
}

/// How the reduced system was solved.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SolveKind {
    /// LU of the reduced matrix.
    Direct,
    /// The reduced matrix is singular: minimum-norm solution by iterated Tikhonov
    /// regularisation (module documentation).
    Regularised {
        /// Largest relative residual `‖b − A x‖∞ / ‖b‖∞` over the solved columns: ≈ 0 for a
        /// consistent system, large when no derivative exists.
        consistency: f64,
    },
}

/// A weakly active component held at its bound, with the slope of its residual along the held
/// branch (module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeakComponent {
    /// Index in `z`.
    pub index: usize,
    /// `max_k |dF_i/dθ_k|` along the held branch.
    pub slope: f64,
    /// True when the slope is zero to the tolerance: the derivative is two-sided.
    pub two_sided: bool,
}

/// The derivative `dz/dθ` of a solution, with what the caller must know to trust it.
#[derive(Clone, Debug, PartialEq)]
pub struct ImplicitDerivative {
    /// `dz/dθ`, `n × p`, column-major (column `k` is `dz/dθ_k`).
    pub dz: Vec<f64>,
    /// Number of columns `p`.
    pub columns: usize,
    /// The weakly active components, each with its slope.
    pub weak: Vec<WeakComponent>,
    /// How the reduced system was solved.
    pub solve: SolveKind,
}

impl Default for ImplicitDerivative {
    /// No columns, solved directly: storage for [`ReducedSystem::differentiate_into`].
    fn default() -> Self {
        ImplicitDerivative {
            dz: Vec::new(),
            columns: 0,
            weak: Vec::new(),
            solve: SolveKind::Direct,
        }
    }
}

/// Failure of a sensitivity computation.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ImplicitError {
    /// Dimensions do not match the problem.
    #[error("sensitivity: {0}")]
    Dimension(String),
    /// The Jacobian or a right-hand side is not finite at the solution.
    #[error(
        "sensitivity: the Jacobian or ∂F/∂θ is not finite at the solution; the step did not converge to a finite point"
    )]
    NonFinite,
    /// Even the regularised system could not be solved.
    #[error("sensitivity: the reduced system could not be solved: {0}")]
    Linear(#[from] LinalgError),
}

/// Reduced-system workspace, kept between calls (module documentation): the Jacobian values,
/// the reduced matrix and the linear solver whose symbolic analysis belongs to the pattern.
#[derive(Default)]
pub struct ReducedSystem {
    linear: Option<LinearSolver>,
    pattern: Option<Arc<CscPattern>>,
    /// `J(z*)` in the pattern's order, then one `−0`: the zero slot of the free block's
    /// gather ([`FreeSystem::dense`]).
    jac: Vec<f64>,
    reduced: Vec<f64>,
    held: Vec<bool>,
    dense_max: usize,
    /// Block elimination of the problem's elimination groups ([`LinearSolver::structured`]).
    structured: bool,
    regularised: Option<Regularised>,
    work: Vec<f64>,
    /// Solve the θ columns with faer's blocked triangular solves (module documentation).
    blocked_columns: bool,
    /// The row-major `n × p` solution of the last [`ReducedSystem::solve_columns`] by rows,
    /// valid while `rows_for` is `Some(p)`.
    rows: Vec<f64>,
    rows_for: Option<usize>,
    /// Largest magnitude in the right-hand side of that solve (before its sign change).
    rhs_max: f64,
    /// The pattern by rows: row `i`'s stored entries `(column, position)` are
    /// `row_entries[row_ptr[i]..row_ptr[i + 1]]`, columns ascending.
    row_ptr: Vec<usize>,
    row_entries: Vec<(usize, usize)>,
    /// One row of `p` residual slopes per weak component.
    slope_rows: Vec<f64>,
    /// The free block `A_ff` of the reduced matrix and its LU (module documentation).
    free: FreeSystem,
    /// The last factorisation is the free block's ([`ReducedSystem::factor`]).
    free_factored: bool,
}

/// The free block `A_ff` of the reduced matrix, the rows and columns of the free components:
/// the held rows are unit rows and the held components' derivatives are 0, so `A dz = −P b`
/// is `A_ff dz_f = −b_f`, `dz_h = 0`. Its entries are gathered from `J(z*)` through the
/// pattern, by a list built once per held mask (the active set changes seldom).
#[derive(Default)]
struct FreeSystem {
    /// The held mask the lists are built for, when `built`.
    held: Vec<bool>,
    built: bool,
    /// The free components, ascending: row and column `r` of `A_ff` is component `index[r]`.
    index: Vec<usize>,
    /// Every entry of the dense column-major `f × f` matrix `A_ff` as a position in the values
    /// of `J` ([`ReducedSystem`]'s `jac`), the entries outside the pattern as its zero slot
    /// `nnz`: the kernel's storage is written entry by entry, without zeroing it first.
    dense: Vec<usize>,
    /// The small kernel's LU of `A_ff`.
    lu: Option<DenseLu>,
    /// A gathered right-hand side.
    work: Vec<f64>,
}

impl FreeSystem {
    /// Builds the lists for `held` (nothing to do when they are built for it already).
    fn index(&mut self, pattern: &CscPattern, held: &[bool]) {
        if self.built && self.held == held {
            return;
        }
        self.built = true;
        self.held.clear();
        self.held.extend_from_slice(held);
        let n = held.len();
        self.index.clear();
        self.index.extend((0..n).filter(|&i| !held[i]));
        let f = self.index.len();
        // The row (and column) of each component in A_ff, `usize::MAX` for a held one.
        let mut compact = vec![usize::MAX; n];
        for (r, &i) in self.index.iter().enumerate() {
            compact[i] = r;
        }
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        self.dense.clear();
        self.dense.resize(f * f, pattern.nnz());
        for (j, &c) in compact.iter().enumerate() {
            if c == usize::MAX {
                continue;
            }
            for q in cp[j]..cp[j + 1] {
                let r = compact[ri[q]];
                if r != usize::MAX {
                    self.dense[c * f + r] = q;
                }
            }
        }
        if self.lu.as_ref().is_none_or(|lu| lu.dim() != f) {
            self.lu = Some(DenseLu::new(f));
        }
    }

    /// Factorises `−A_ff` with the values `jac` of `J(z*)` followed by its zero slot `−0`
    /// (finite: the caller checks; map built by [`FreeSystem::index`]): its solves give
    /// `−A_ff⁻¹ b` bit for bit but for the signs of zeros (the same pivots; every operation
    /// of the elimination and the solves commutes with negation), so `dz = −A⁻¹ P ∂F/∂θ`
    /// needs no negation pass. The slot's `−0` lands as `+0`, so the kernel's storage is
    /// bitwise what zeroing it and scattering the entries gave.
    fn factor(&mut self, jac: &[f64]) -> Result<(), LinalgError> {
        let lu = self.lu.as_mut().ok_or(LinalgError::NotFactored)?;
        lu.factor_gathered_negated(&self.dense, jac)
    }
}

/// The fallback of a singular reduced matrix: `A` dense and an LU of `AᵀA + λI`.
struct Regularised {
    a: Vec<f64>,
    lu: DenseLu,
}

/// Iterations of the regularised solve (module documentation).
const TIKHONOV_ITERATIONS: usize = 8;
/// `λ` relative to the largest diagonal entry of `AᵀA`.
const TIKHONOV_LAMBDA: f64 = 1e-10;

impl std::fmt::Debug for ReducedSystem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ReducedSystem {{ n: {}, regularised: {} }}",
            self.held.len(),
            self.regularised.is_some()
        )
    }
}

impl ReducedSystem {
    /// An empty workspace; dense LU up to 120 unknowns, sparse LU above (like the Newton
    /// backend).
    pub fn new() -> Self {
        Self::with_dense_max(120)
    }

    /// An empty workspace choosing dense LU up to `dense_max` unknowns.
    pub fn with_dense_max(dense_max: usize) -> Self {
        ReducedSystem {
            dense_max,
            ..Default::default()
        }
    }

    /// Solves by block elimination of the problem's elimination groups
    /// ([`crate::Mcp::elimination_groups`], `docs/latency.md#structured-linear-solve`) when
    /// `on`: held rows are unit rows, so the reduced matrix keeps the groups' structure.
    pub fn with_structured_solve(mut self, on: bool) -> Self {
        if self.structured != on {
            self.linear = None;
        }
        self.structured = on;
        self
    }

    /// Solves the θ columns of [`ReducedSystem::solve_columns`] with faer's blocked triangular
    /// solves when `on` (the route before the row-oriented kernel, kept to compare against;
    /// the results differ by round-off). Default off.
    pub fn with_blocked_columns(mut self, on: bool) -> Self {
        self.blocked_columns = on;
        self
    }

    /// The Jacobian values `J(z*)` of the last [`ReducedSystem::factor`], in the pattern's order.
    pub fn jacobian_values(&self) -> &[f64] {
        &self.jac[..self.jac.len().saturating_sub(1)]
    }

    /// True when the last factorisation fell back to the regularised solve.
    pub fn is_regularised(&self) -> bool {
        self.regularised.is_some()
    }

    /// Evaluates `J` at the solution `z`, builds the reduced matrix for `status` and factorises
    /// it (falling back to the regularised form when it is singular).
    pub fn factor(
        &mut self,
        mcp: &dyn Mcp,
        z: &[f64],
        status: &[ComponentStatus],
    ) -> Result<(), ImplicitError> {
        let n = mcp.dim();
        if z.len() != n || status.len() != n {
            return Err(ImplicitError::Dimension(format!(
                "z has {} entries and status {}, the problem has {n}",
                z.len(),
                status.len()
            )));
        }
        self.rows_for = None;
        let pattern = mcp.jacobian_pattern();
        let reuse = self
            .pattern
            .as_ref()
            .is_some_and(|p| Arc::ptr_eq(p, pattern) || **p == **pattern);
        if !reuse || self.linear.is_none() {
            let groups = if self.structured {
                mcp.elimination_groups()
            } else {
                &[]
            };
            self.linear = Some(LinearSolver::structured(pattern, self.dense_max, groups)?);
            self.pattern = Some(pattern.clone());
            self.index_rows(pattern);
            self.free.built = false;
        }
        let nnz = pattern.nnz();
        self.jac.resize(nnz + 1, 0.0);
        self.jac[nnz] = -0.0;
        mcp.jacobian(z, &mut self.jac[..nnz]);
        if !all_finite(&self.jac[..nnz]) {
            return Err(ImplicitError::NonFinite);
        }
        self.held.clear();
        self.held
            .extend(status.iter().map(ComponentStatus::is_held));
        self.regularised = None;
        self.free_factored = false;
        let linear = self.linear.as_ref().ok_or(LinalgError::NotFactored)?;
        if !self.blocked_columns && linear.solves_rows() {
            // The free block alone (module documentation); the whole reduced matrix is formed
            // only for the regularised fallback.
            self.free.index(pattern, &self.held);
            return match self.free.factor(&self.jac) {
                Ok(()) => {
                    self.free_factored = true;
                    Ok(())
                }
                Err(LinalgError::Singular { .. }) => {
                    self.form_reduced(pattern);
                    self.regularise()
                }
                Err(e) => Err(e.into()),
            };
        }
        self.form_reduced(pattern);
        let linear = self.linear.as_mut().ok_or(LinalgError::NotFactored)?;
        match linear.factor(&self.reduced) {
            Ok(()) => Ok(()),
            Err(LinalgError::Singular { .. }) => self.regularise(),
            Err(e) => Err(e.into()),
        }
    }

    /// The reduced matrix `A` in the pattern's order: the rows of `J(z*)`, unit rows for the
    /// held components.
    fn form_reduced(&mut self, pattern: &CscPattern) {
        let n = pattern.dim();
        self.reduced.clear();
        self.reduced.extend_from_slice(&self.jac[..pattern.nnz()]);
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        for j in 0..n {
            for p in cp[j]..cp[j + 1] {
                if self.held[ri[p]] {
                    self.reduced[p] = 0.0;
                }
            }
        }
        for (i, &p) in pattern.diag_pos().iter().enumerate() {
            if self.held[i] {
                self.reduced[p] = 1.0;
            }
        }
    }

    /// The pattern by rows (`row_ptr`, `row_entries`), for the weak rows' slopes.
    fn index_rows(&mut self, pattern: &CscPattern) {
        let n = pattern.dim();
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        self.row_ptr.clear();
        self.row_ptr.resize(n + 1, 0);
        for &i in ri {
            self.row_ptr[i + 1] += 1;
        }
        for i in 0..n {
            self.row_ptr[i + 1] += self.row_ptr[i];
        }
        let mut next = self.row_ptr[..n].to_vec();
        self.row_entries.clear();
        self.row_entries.resize(ri.len(), (0, 0));
        for j in 0..n {
            for q in cp[j]..cp[j + 1] {
                let i = ri[q];
                self.row_entries[next[i]] = (j, q);
                next[i] += 1;
            }
        }
    }

    /// Builds the regularised fallback from the current reduced matrix.
    fn regularise(&mut self) -> Result<(), ImplicitError> {
        self.free_factored = false;
        let pattern = self.pattern.as_ref().ok_or(LinalgError::NotFactored)?;
        let n = pattern.dim();
        let mut a = vec![0.0; n * n];
        pattern.to_dense(&self.reduced, &mut a);
        // Held components are 0 exactly: drop their columns from the free rows, so the matrix
        // is block-diagonal (free block, identity) and the least-squares fit of an inconsistent
        // free block cannot move them.
        for j in (0..n).filter(|&j| self.held[j]) {
            for i in (0..n).filter(|&i| !self.held[i]) {
                a[j * n + i] = 0.0;
            }
        }
        // N = AᵀA + λI, column-major (symmetric).
        let mut normal = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..=j {
                let s: f64 = (0..n).map(|k| a[i * n + k] * a[j * n + k]).sum();
                normal[j * n + i] = s;
                normal[i * n + j] = s;
            }
        }
        let max_diag = (0..n).map(|i| normal[i * n + i]).fold(0.0, f64::max);
        let lambda = TIKHONOV_LAMBDA * max_diag.max(f64::MIN_POSITIVE);
        for i in 0..n {
            normal[i * n + i] += lambda;
        }
        let mut lu = DenseLu::new(n);
        lu.factor(&normal)?;
        self.regularised = Some(Regularised { a, lu });
        Ok(())
    }

    /// Solves `A x = b` in place (regularised when `A` is singular); returns the relative
    /// residual of the regularised solve (0 for a direct one).
    fn solve_one(&mut self, b: &mut [f64]) -> Result<f64, ImplicitError> {
        if self.free_factored {
            self.solve_free(b, false)?;
            return Ok(0.0);
        }
        if self.regularised.is_none() {
            let linear = self.linear.as_mut().ok_or(LinalgError::NotFactored)?;
            self.work.clear();
            self.work.extend_from_slice(b);
            match linear.solve_in_place(b) {
                Ok(()) => return Ok(0.0),
                // A sparse LU reports near-singularity only when solving.
                Err(LinalgError::Singular { .. }) => {
                    b.copy_from_slice(&self.work);
                    self.regularise()?;
                }
                Err(e) => return Err(e.into()),
            }
        }
        let reg = self.regularised.as_mut().ok_or(LinalgError::NotFactored)?;
        let n = b.len();
        let rhs = b.to_vec();
        let bnorm = rhs.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut x = vec![0.0; n];
        let mut r = rhs.clone();
        let mut step = vec![0.0; n];
        for _ in 0..TIKHONOV_ITERATIONS {
            // step = N⁻¹ Aᵀ r
            for (j, s) in step.iter_mut().enumerate() {
                *s = (0..n).map(|k| reg.a[j * n + k] * r[k]).sum();
            }
            reg.lu.solve_in_place(&mut step)?;
            for (xi, si) in x.iter_mut().zip(&step) {
                *xi += si;
            }
            residual(&reg.a, &x, &rhs, &mut r);
        }
        let rnorm = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        b.copy_from_slice(&x);
        Ok(if bnorm > 0.0 { rnorm / bnorm } else { rnorm })
    }

    /// With the free block's factors: `A x = b` (`x_h = b_h`, `A_ff x_f = b_f − A_fh b_h`), or
    /// when `transpose`, `P A⁻ᵀ b` (`A_ffᵀ x_f = b_f`, `x_h = 0`), in place.
    fn solve_free(&mut self, b: &mut [f64], transpose: bool) -> Result<(), ImplicitError> {
        let pattern = self.pattern.as_ref().ok_or(LinalgError::NotFactored)?;
        let fs = &mut self.free;
        if !transpose {
            let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
            for j in 0..b.len() {
                let bj = b[j];
                if !self.held[j] || bj == 0.0 {
                    continue;
                }
                for q in cp[j]..cp[j + 1] {
                    if !self.held[ri[q]] {
                        b[ri[q]] -= self.jac[q] * bj;
                    }
                }
            }
        }
        fs.work.clear();
        fs.work.extend(fs.index.iter().map(|&i| b[i]));
        if !fs.index.is_empty() {
            let lu = fs.lu.as_mut().ok_or(LinalgError::NotFactored)?;
            if transpose {
                lu.solve_transpose_in_place(&mut fs.work)?;
            } else {
                lu.solve_in_place(&mut fs.work)?;
            }
        }
        if transpose {
            b.fill(0.0);
        }
        // The factors are −A_ff's.
        for (&i, &v) in fs.index.iter().zip(&fs.work) {
            b[i] = -v;
        }
        Ok(())
    }

    /// `dz/dθ = −A⁻¹ P ∂F/∂θ` for the `p` columns of `rhs` (`∂F/∂θ`, `n × p` column-major),
    /// overwritten by the result; returns how the system was solved. Call after
    /// [`ReducedSystem::factor`].
    pub fn solve_columns(&mut self, rhs: &mut [f64], p: usize) -> Result<SolveKind, ImplicitError> {
        let n = self.held.len();
        if rhs.len() != n * p {
            return Err(ImplicitError::Dimension(format!(
                "right-hand side has {} entries, expected {n} × {p}",
                rhs.len()
            )));
        }
        self.rows_for = None;
        if self.free_factored && (n == 0 || p == 0) {
            return Ok(SolveKind::Direct);
        }
        if self.by_rows(p) {
            return self.solve_columns_by_rows(None, rhs, p);
        }
        if rhs.iter().any(|v| !v.is_finite()) {
            return Err(ImplicitError::NonFinite);
        }
        for col in rhs.chunks_exact_mut(n.max(1)).take(p) {
            for (v, &h) in col.iter_mut().zip(&self.held) {
                *v = if h { 0.0 } else { -*v };
            }
        }
        if self.regularised.is_none() {
            // All columns in one call; a sparse LU reports near-singularity only when solving,
            // then the columns are solved again, regularised.
            let linear = self.linear.as_mut().ok_or(LinalgError::NotFactored)?;
            self.work.clear();
            self.work.extend_from_slice(rhs);
            match linear.solve_many_in_place(rhs, p) {
                Ok(()) => return Ok(SolveKind::Direct),
                Err(LinalgError::Singular { .. }) => {
                    rhs.copy_from_slice(&self.work);
                    self.regularise()?;
                }
                Err(e) => return Err(e.into()),
            }
        }
        let mut worst = 0.0f64;
        for col in rhs.chunks_exact_mut(n.max(1)).take(p) {
            worst = worst.max(self.solve_one(col)?);
        }
        Ok(self.kind(worst))
    }

    /// True when [`ReducedSystem::solve_columns`] of `p` columns goes by rows (the small
    /// kernel's factors, not regularised, not `blocked_columns`).
    fn by_rows(&self, p: usize) -> bool {
        self.regularised.is_none()
            && !self.blocked_columns
            && !self.held.is_empty()
            && p > 0
            && (self.free_factored || self.linear.as_ref().is_some_and(LinearSolver::solves_rows))
    }

    /// [`ReducedSystem::solve_columns`] by the small kernel's row-oriented solve: the columns
    /// (held rows zeroed) transposed into the row-major `rows`, solved there, negated and
    /// copied back; `rows` keeps the solution for the weak slopes. The columns are read from
    /// `src` when given (`n × p`, then `rhs` is only written), else from `rhs`.
    fn solve_columns_by_rows(
        &mut self,
        src: Option<&[f64]>,
        rhs: &mut [f64],
        p: usize,
    ) -> Result<SolveKind, ImplicitError> {
        let n = self.held.len();
        // Transposed without the sign change: solving `A x = −b` gives `−x` of `A x = b` bit
        // for bit but for the signs of zeros (every operation of the solve commutes with
        // negation), so the sign goes on the way back. The same pass tests finiteness and
        // finds the largest magnitude (the weak slopes' scale).
        self.rows.resize(n * p, 0.0);
        let rows = &mut self.rows[..n * p];
        let (max, finite) = transpose_checked(src.unwrap_or(rhs), n, p, rows);
        if !finite {
            return Err(ImplicitError::NonFinite);
        }
        if self.free_factored {
            // The free rows solved where they lie, by −A_ff's factors (the sign is in them),
            // the held rows then 0; without the mapped kernel (no AVX2) the free rows are
            // moved up to the first `f` rows (in place: `index[r] ≥ r`), solved, and moved
            // back down (backwards: `index[r] ≥ r` again).
            let index = &self.free.index;
            let f = index.len();
            let lu = self.free.lu.as_mut().ok_or(LinalgError::NotFactored)?;
            if f > 0 && lu.solve_mapped_rows_in_place(rows, p, index)? {
                for (dst, &h) in rows.chunks_exact_mut(p).zip(&self.held) {
                    if h {
                        dst.fill(0.0);
                    }
                }
            } else {
                for (r, &i) in index.iter().enumerate() {
                    if i != r {
                        rows.copy_within(i * p..(i + 1) * p, r * p);
                    }
                }
                if f > 0 && !lu.solve_rows_in_place(&mut rows[..f * p], p)? {
                    return Err(LinalgError::NotFactored.into());
                }
                let mut r = f;
                for i in (0..n).rev() {
                    if r > 0 && index[r - 1] == i {
                        r -= 1;
                        if r != i {
                            rows.copy_within(r * p..(r + 1) * p, i * p);
                        }
                    } else {
                        rows[i * p..(i + 1) * p].fill(0.0);
                    }
                }
            }
            // Finiteness tested in the transpose back (below).
        } else {
            for (dst, &h) in rows.chunks_exact_mut(p).zip(&self.held) {
                if h {
                    dst.fill(0.0);
                }
            }
            let linear = self.linear.as_mut().ok_or(LinalgError::NotFactored)?;
            if !linear.solve_rows_in_place(rows, p)? {
                return Err(LinalgError::NotFactored.into());
            }
            if !negate(rows) {
                return Err(LinalgError::NonFinite.into());
            }
        }
        if self.free_factored {
            if !transpose_checked(rows, p, n, rhs).1 {
                return Err(LinalgError::NonFinite.into());
            }
        } else {
            transpose(rows, p, n, rhs);
        }
        self.rhs_max = max;
        self.rows_for = Some(p);
        Ok(SolveKind::Direct)
    }

    /// The adjoint of [`ReducedSystem::solve_columns`]: overwrites `g` by `μ = P A⁻ᵀ g`, so that
    /// for every θ column `b = ∂F/∂θ_k`, `gᵀ dz/dθ_k = −μᵀ b`. One transposed solve gives the
    /// gradient of a scalar `gᵀ z` with respect to any number of parameters. In the regularised
    /// case it is the exact transpose of the iterated map, so both routes agree to round-off.
    pub fn solve_transpose(&mut self, g: &mut [f64]) -> Result<SolveKind, ImplicitError> {
        let n = self.held.len();
        if g.len() != n {
            return Err(ImplicitError::Dimension(format!(
                "adjoint right-hand side has {} entries, expected {n}",
                g.len()
            )));
        }
        if g.iter().any(|v| !v.is_finite()) {
            return Err(ImplicitError::NonFinite);
        }
        if self.free_factored {
            self.solve_free(g, true)?;
            return Ok(SolveKind::Direct);
        }
        if self.regularised.is_none() {
            let linear = self.linear.as_mut().ok_or(LinalgError::NotFactored)?;
            self.work.clear();
            self.work.extend_from_slice(g);
            match linear.solve_transpose_in_place(g) {
                Ok(()) => {
                    for (v, &h) in g.iter_mut().zip(&self.held) {
                        if h {
                            *v = 0.0;
                        }
                    }
                    return Ok(SolveKind::Direct);
                }
                Err(LinalgError::Singular { .. }) => {
                    g.copy_from_slice(&self.work);
                    self.regularise()?;
                }
                Err(e) => return Err(e.into()),
            }
        }
        let reg = self.regularised.as_mut().ok_or(LinalgError::NotFactored)?;
        // Tᵀ g = Σ_j Mᵀ (I − Aᵀ Mᵀ)^j g with Mᵀ = A N⁻¹ (N symmetric).
        let mut y = g.to_vec();
        let mut acc = vec![0.0; n];
        let mut t = vec![0.0; n];
        let mut s = vec![0.0; n];
        for _ in 0..TIKHONOV_ITERATIONS {
            s.copy_from_slice(&y);
            reg.lu.solve_in_place(&mut s)?;
            for (i, ti) in t.iter_mut().enumerate() {
                *ti = (0..n).map(|k| reg.a[k * n + i] * s[k]).sum();
            }
            for (a, ti) in acc.iter_mut().zip(&t) {
                *a += ti;
            }
            for (j, yj) in y.iter_mut().enumerate() {
                *yj -= (0..n).map(|k| reg.a[j * n + k] * t[k]).sum::<f64>();
            }
        }
        for ((v, a), &h) in g.iter_mut().zip(&acc).zip(&self.held) {
            *v = if h { 0.0 } else { *a };
        }
        Ok(SolveKind::Regularised { consistency: 0.0 })
    }

    fn kind(&self, worst: f64) -> SolveKind {
        if self.regularised.is_some() {
            SolveKind::Regularised { consistency: worst }
        } else {
            SolveKind::Direct
        }
    }

    /// The whole implicit derivative at a solution: classifies nothing itself (give it the
    /// `status` of [`classify`], adjusted with [`ComponentStatus::Held`] where the caller knows
    /// better), factorises, solves the `p` columns of `dfdtheta` (`∂F/∂θ`, `n × p`
    /// column-major) and measures the slope of every weakly active component.
    pub fn differentiate(
        &mut self,
        mcp: &dyn Mcp,
        z: &[f64],
        status: &[ComponentStatus],
        dfdtheta: &[f64],
        p: usize,
        opts: &ActiveSetOptions,
    ) -> Result<ImplicitDerivative, ImplicitError> {
        let mut out = ImplicitDerivative::default();
        self.differentiate_into(mcp, z, status, dfdtheta, p, opts, &mut out)?;
        Ok(out)
    }

    /// [`ReducedSystem::differentiate`] into `out`, whose vectors are reused: no allocation
    /// once they and the workspace have grown (with the small kernel).
    #[allow(clippy::too_many_arguments)]
    pub fn differentiate_into(
        &mut self,
        mcp: &dyn Mcp,
        z: &[f64],
        status: &[ComponentStatus],
        dfdtheta: &[f64],
        p: usize,
        opts: &ActiveSetOptions,
        out: &mut ImplicitDerivative,
    ) -> Result<(), ImplicitError> {
        self.factor(mcp, z, status)?;
        out.columns = p;
        if self.by_rows(p) && dfdtheta.len() == self.held.len() * p {
            // Read straight from `dfdtheta`: every entry of `dz` is written by the solve.
            self.rows_for = None;
            out.dz.resize(dfdtheta.len(), 0.0);
            out.solve = self.solve_columns_by_rows(Some(dfdtheta), &mut out.dz, p)?;
        } else {
            out.dz.clear();
            out.dz.extend_from_slice(dfdtheta);
            out.solve = self.solve_columns(&mut out.dz, p)?;
        }
        if self.rows_for == Some(p) {
            self.weak_slopes_by_rows(mcp, status, dfdtheta, p, opts, &mut out.weak);
        } else {
            out.weak = self.weak_slopes(mcp, status, &out.dz, dfdtheta, p, opts);
        }
        Ok(())
    }
}

impl ReducedSystem {
    /// The slope `max_k |dF_i/dθ_k|`, `dF = J(z*) dz + ∂F/∂θ`, of every weakly active component
    /// of `status` along a derivative `dz` (`n × p`), with `J(z*)` from the last
    /// [`ReducedSystem::factor`]. [`ReducedSystem::differentiate`] calls it; call it again when
    /// the derivative is assembled from several solves with the same `J(z*)`.
    pub fn weak_slopes(
        &self,
        mcp: &dyn Mcp,
        status: &[ComponentStatus],
        dz: &[f64],
        dfdtheta: &[f64],
        p: usize,
        opts: &ActiveSetOptions,
    ) -> Vec<WeakComponent> {
        let n = mcp.dim();
        let mut weak = weak_components(status);
        if weak.is_empty() || self.jac.len() != mcp.jacobian_pattern().nnz() + 1 {
            return weak;
        }
        // The weak rows of J(z*), gathered once: (which weak component, column, value).
        let pattern = mcp.jacobian_pattern();
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        // Each row's weak component, if any (looked up once per stored entry).
        let mut slot = vec![usize::MAX; n];
        for (w, c) in weak.iter().enumerate() {
            slot[c.index] = w;
        }
        let mut rows = Vec::new();
        for j in 0..n {
            for q in cp[j]..cp[j + 1] {
                let w = slot[ri[q]];
                if w != usize::MAX {
                    rows.push((w, j, self.jac[q]));
                }
            }
        }
        let mut scale = 1.0f64;
        let mut df = vec![0.0; weak.len()];
        for k in 0..p {
            let col = &dfdtheta[k * n..(k + 1) * n];
            let dzk = &dz[k * n..(k + 1) * n];
            scale = scale.max(col.iter().fold(0.0f64, |m, v| m.max(v.abs())));
            for (d, w) in df.iter_mut().zip(&weak) {
                *d = col[w.index];
            }
            for &(w, j, v) in &rows {
                df[w] += v * dzk[j];
            }
            for (w, d) in weak.iter_mut().zip(&df) {
                w.slope = w.slope.max(d.abs());
            }
        }
        for w in weak.iter_mut() {
            w.two_sided = w.slope <= opts.two_sided_tolerance * scale;
        }
        weak
    }
}

impl ReducedSystem {
    /// [`ReducedSystem::weak_slopes`] along the row-major solution the last
    /// [`ReducedSystem::solve_columns`] kept (`rows_for == Some(p)`, its right-hand side
    /// `dfdtheta`): per weak row, `dF_i = ∂F_i/∂θ + J_i dz` for all `p` columns at once, one
    /// vector loop per stored entry of the row. Bitwise the same slopes as `weak_slopes` of the
    /// same `dz`: every `dF_ik` gets the same products in the same order (columns ascending).
    fn weak_slopes_by_rows(
        &mut self,
        mcp: &dyn Mcp,
        status: &[ComponentStatus],
        dfdtheta: &[f64],
        p: usize,
        opts: &ActiveSetOptions,
        weak: &mut Vec<WeakComponent>,
    ) {
        let n = mcp.dim();
        weak_components_into(status, weak);
        if weak.is_empty()
            || self.jac.len() != mcp.jacobian_pattern().nnz() + 1
            || self.row_ptr.len() != n + 1
        {
            return;
        }
        let scale = self.rhs_max.max(1.0);
        self.slope_rows.resize(weak.len() * p, 0.0);
        let rows = &self.rows[..n * p];
        for (w, y) in weak.iter_mut().zip(self.slope_rows.chunks_exact_mut(p)) {
            let i = w.index;
            for (k, v) in y.iter_mut().enumerate() {
                *v = dfdtheta[k * n + i];
            }
            let entries = &self.row_entries[self.row_ptr[i]..self.row_ptr[i + 1]];
            add_row_combination(y, rows, entries, &self.jac);
            w.slope = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            w.two_sided = w.slope <= opts.two_sided_tolerance * scale;
        }
    }
}

/// True when every entry of `v` is finite, in four independent lanes (vector loops): `x · 0` is
/// ±0 for a finite `x` and NaN otherwise.
fn all_finite(v: &[f64]) -> bool {
    let mut nan = [0.0f64; 4];
    let mut chunks = v.chunks_exact(4);
    for c in &mut chunks {
        for k in 0..4 {
            nan[k] += c[k] * 0.0;
        }
    }
    for &x in chunks.remainder() {
        nan[0] += x * 0.0;
    }
    nan.iter().all(|x| *x == 0.0)
}

/// Negates `v` in place; true when every entry is finite (lanes as [`all_finite`]).
fn negate(v: &mut [f64]) -> bool {
    let mut nan = [0.0f64; 4];
    let mut chunks = v.chunks_exact_mut(4);
    for c in &mut chunks {
        for k in 0..4 {
            c[k] = -c[k];
            nan[k] += c[k] * 0.0;
        }
    }
    for x in chunks.into_remainder() {
        *x = -*x;
        nan[0] += *x * 0.0;
    }
    nan.iter().all(|x| *x == 0.0)
}

/// `r = b − A x` for a dense column-major `A`.
fn residual(a: &[f64], x: &[f64], b: &[f64], r: &mut [f64]) {
    let n = b.len();
    r.copy_from_slice(b);
    for (j, xj) in x.iter().enumerate() {
        if *xj != 0.0 {
            for i in 0..n {
                r[i] -= a[j * n + i] * xj;
            }
        }
    }
}

/// The weakly active components of `status`, each with slope 0 and two-sided until
/// [`ReducedSystem::weak_slopes`] (or its row-major twin) measures them.
fn weak_components(status: &[ComponentStatus]) -> Vec<WeakComponent> {
    let mut weak = Vec::new();
    weak_components_into(status, &mut weak);
    weak
}

/// [`weak_components`] into `weak` (cleared first).
fn weak_components_into(status: &[ComponentStatus], weak: &mut Vec<WeakComponent>) {
    weak.clear();
    weak.extend(
        status
            .iter()
            .enumerate()
            .filter(|(_, s)| **s == ComponentStatus::WeaklyActive)
            .map(|(index, _)| WeakComponent {
                index,
                slope: 0.0,
                two_sided: true,
            }),
    );
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::mcp::FnMcp;

    /// A deterministic stream of numbers in `[-0.5, 0.5)` (a 64-bit LCG), for the random matrices
    /// of the tests below.
    fn uniform_in_half(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// An `n`-component MCP on `[0, ∞)ⁿ` with `F = 0` and the constant column-major Jacobian
    /// `jac`: the reduced systems of the tests below, built from a given matrix.
    fn constant_jacobian(jac: &[f64]) -> FnMcp {
        let n = (jac.len() as f64).sqrt() as usize;
        let j = jac.to_vec();
        FnMcp::dense(
            vec![0.0; n],
            vec![f64::INFINITY; n],
            |_z: &[f64], f: &mut [f64]| f.fill(0.0),
            move |_z: &[f64], out: &mut [f64]| out.copy_from_slice(&j),
        )
        .unwrap()
    }

    /// F(z; θ) = M z + q(θ) with q = (θ₀, θ₁ − 1, 2): a 3-component LCP whose first component
    /// is free-solved, the second at its bound and the third strongly active.
    fn lcp(m: [[f64; 3]; 3]) -> FnMcp {
        let mm = m;
        FnMcp::dense(
            vec![0.0; 3],
            vec![f64::INFINITY; 3],
            move |z: &[f64], f: &mut [f64]| {
                for i in 0..3 {
                    f[i] = (0..3).map(|j| mm[i][j] * z[j]).sum();
                }
            },
            move |_z: &[f64], jac: &mut [f64]| {
                for j in 0..3 {
                    for i in 0..3 {
                        jac[j * 3 + i] = mm[i][j];
                    }
                }
            },
        )
        .unwrap()
    }

    #[test]
    fn classify_tells_free_active_weak() {
        let z = [1.0, 0.0, 0.0, 0.5, 0.0];
        let f = [0.0, 2.0, 1e-12, 0.0, -1e-3];
        let lo = [f64::NEG_INFINITY, 0.0, 0.0, 0.0, 0.0];
        let up = [f64::INFINITY; 5];
        let s = classify(&z, &f, &lo, &up, &ActiveSetOptions::default());
        use ComponentStatus::*;
        assert_eq!(s, vec![Free, Active, WeaklyActive, Free, WeaklyActive]);
    }

    /// F = M z + q with M = 2I + offdiag, q = (−2θ, 1, −1): z₁ at its bound (F₁ = 1 > 0),
    /// z₀, z₂ free; dz/dθ on the free part is −M_ff⁻¹ ∂q_f/∂θ.
    #[test]
    fn derivative_matches_reduced_inverse() {
        let m = [[2.0, 0.5, 0.3], [0.1, 2.0, 0.0], [0.4, 0.2, 3.0]];
        let mcp = lcp(m);
        // Solve the free 2×2 system for z₀, z₂ with q = (−2, ·, −1): [2 .3; .4 3] z = (2, 1).
        let det = 2.0 * 3.0 - 0.3 * 0.4;
        let z0 = (2.0 * 3.0 - 0.3 * 1.0) / det;
        let z2 = (2.0 * 1.0 - 0.4 * 2.0) / det;
        let z = [z0, 0.0, z2];
        let status = [
            ComponentStatus::Free,
            ComponentStatus::Active,
            ComponentStatus::Free,
        ];
        // ∂F/∂θ for q₀ = −2θ: column (−2, 0, 0); a second column ∂q₁ = 1 (held row).
        let dfdtheta = [-2.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let mut sys = ReducedSystem::new();
        let d = sys
            .differentiate(
                &mcp,
                &z,
                &status,
                &dfdtheta,
                2,
                &ActiveSetOptions::default(),
            )
            .unwrap();
        assert_eq!(d.solve, SolveKind::Direct);
        // [2 .3; .4 3] dz = (2, 0) ⇒ dz₀ = 6/det, dz₂ = −0.8/det.
        assert!((d.dz[0] - 6.0 / det).abs() < 1e-14);
        assert_eq!(d.dz[1], 0.0);
        assert!((d.dz[2] + 0.8 / det).abs() < 1e-14);
        assert!(d.dz[3..].iter().all(|v| *v == 0.0));
        // The adjoint gives the same gradient of g·z.
        let g = [0.7, -0.2, 1.3];
        let mut mu = g.to_vec();
        sys.solve_transpose(&mut mu).unwrap();
        for k in 0..2 {
            let fwd: f64 = (0..3).map(|i| g[i] * d.dz[k * 3 + i]).sum();
            let adj: f64 = -(0..3).map(|i| mu[i] * dfdtheta[k * 3 + i]).sum::<f64>();
            assert!((fwd - adj).abs() < 1e-14, "{fwd} vs {adj}");
        }
    }

    /// A singular reduced matrix (a zero row and column pair) falls back to the minimum-norm
    /// solution, and the adjoint is its exact transpose.
    #[test]
    fn singular_system_gets_minimum_norm_and_matching_adjoint() {
        let m = [[2.0, 0.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 3.0]];
        let mcp = FnMcp::dense(
            vec![f64::NEG_INFINITY; 3],
            vec![f64::INFINITY; 3],
            move |z: &[f64], f: &mut [f64]| {
                for i in 0..3 {
                    f[i] = (0..3).map(|j| m[i][j] * z[j]).sum();
                }
            },
            move |_z: &[f64], jac: &mut [f64]| {
                for j in 0..3 {
                    for i in 0..3 {
                        jac[j * 3 + i] = m[i][j];
                    }
                }
            },
        )
        .unwrap();
        let status = [ComponentStatus::Free; 3];
        let dfdtheta = [1.0, 0.0, 2.0];
        let mut sys = ReducedSystem::new();
        let d = sys
            .differentiate(
                &mcp,
                &[0.0; 3],
                &status,
                &dfdtheta,
                1,
                &ActiveSetOptions::default(),
            )
            .unwrap();
        // Consistent: [2 1; 1 3] (dz₀, dz₂) = −(1, 2) ⇒ (−0.2, −0.6); dz₁ undetermined → 0.
        match d.solve {
            SolveKind::Regularised { consistency } => assert!(consistency < 1e-12),
            other => panic!("expected the regularised solve, got {other:?}"),
        }
        assert!((d.dz[0] + 0.2).abs() < 1e-12, "{:?}", d.dz);
        assert!(d.dz[1].abs() < 1e-12, "{:?}", d.dz);
        assert!((d.dz[2] + 0.6).abs() < 1e-12, "{:?}", d.dz);
        let g = [0.3, 5.0, -1.0];
        let mut mu = g.to_vec();
        sys.solve_transpose(&mut mu).unwrap();
        let fwd: f64 = (0..3).map(|i| g[i] * d.dz[i]).sum();
        let adj: f64 = -(0..3).map(|i| mu[i] * dfdtheta[i]).sum::<f64>();
        assert!((fwd - adj).abs() < 1e-13, "{fwd} vs {adj}");
    }

    /// The θ columns by the small kernel's rows against faer's blocked solves: the same
    /// derivative to round-off, and the weak slopes formed from the row-major solution bitwise
    /// those of [`ReducedSystem::weak_slopes`] on the same derivative.
    #[test]
    fn columns_by_rows_agree_with_the_blocked_solves() {
        let (n, p) = (13, 9);
        let mut next = uniform_in_half(3);
        // J: a third of the off-diagonal entries zero, a dominant diagonal.
        let jac: Vec<f64> = (0..n * n)
            .map(|q| {
                let v = next();
                if q % n == q / n {
                    4.0 + v
                } else if v.abs() < 0.17 {
                    0.0
                } else {
                    v
                }
            })
            .collect();
        let dfdtheta: Vec<f64> = (0..n * p)
            .map(|q| if q % 4 == 1 { 0.0 } else { next() * 3.0 })
            .collect();
        let mcp = constant_jacobian(&jac);
        use ComponentStatus::*;
        let status: Vec<ComponentStatus> = (0..n)
            .map(|i| [Free, WeaklyActive, Free, Active, Held][i % 5])
            .collect();
        let opts = ActiveSetOptions::default();
        let z = vec![0.0; n];
        let mut rows = ReducedSystem::new();
        let a = rows
            .differentiate(&mcp, &z, &status, &dfdtheta, p, &opts)
            .unwrap();
        let mut blocked = ReducedSystem::new().with_blocked_columns(true);
        let b = blocked
            .differentiate(&mcp, &z, &status, &dfdtheta, p, &opts)
            .unwrap();
        assert_eq!((a.solve, b.solve), (SolveKind::Direct, SolveKind::Direct));
        for (x, y) in a.dz.chunks(n).zip(b.dz.chunks(n)) {
            let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (u, v) in x.iter().zip(y) {
                assert!((u - v).abs() <= 1e-14 * scale, "{u} against {v}");
            }
        }
        assert_eq!(a.weak.len(), 3);
        assert!(a.weak.iter().all(|w| w.slope > 0.0));
        let by_columns = rows.weak_slopes(&mcp, &status, &a.dz, &dfdtheta, p, &opts);
        for (u, v) in a.weak.iter().zip(&by_columns) {
            assert_eq!((u.index, u.two_sided), (v.index, v.two_sided));
            assert_eq!(u.slope.to_bits(), v.slope.to_bits());
        }
    }

    /// The free block alone against the whole reduced matrix (faer's route) where the whole
    /// matrix's partial pivoting takes free rows into held columns (entries of magnitude 2 to 6
    /// there, above the unit rows' 1): the same derivative to round-off, the held rows exactly
    /// 0, and the adjoint through the free block the transpose of the forward solve.
    #[test]
    fn the_free_block_gives_the_whole_reduced_systems_derivative() {
        let (n, p) = (11, 7);
        let mut next = uniform_in_half(11);
        use ComponentStatus::*;
        let status: Vec<ComponentStatus> = (0..n)
            .map(|i| [Free, Active, Free, Held, Free, Free, WeaklyActive][i % 7])
            .collect();
        let jac: Vec<f64> = (0..n * n)
            .map(|q| {
                let (i, j) = (q % n, q / n);
                let v = next();
                if i == j {
                    3.0 + v
                } else if status[j].is_held() {
                    4.0 * v + 2.0f64.copysign(v)
                } else {
                    v
                }
            })
            .collect();
        let dfdtheta: Vec<f64> = (0..n * p).map(|_| next()).collect();
        let mcp = constant_jacobian(&jac);
        let opts = ActiveSetOptions::default();
        let z = vec![0.0; n];
        let mut free = ReducedSystem::new();
        let a = free
            .differentiate(&mcp, &z, &status, &dfdtheta, p, &opts)
            .unwrap();
        assert!(free.free_factored);
        let mut whole = ReducedSystem::new().with_blocked_columns(true);
        let b = whole
            .differentiate(&mcp, &z, &status, &dfdtheta, p, &opts)
            .unwrap();
        assert!(!whole.free_factored);
        assert_eq!((a.solve, b.solve), (SolveKind::Direct, SolveKind::Direct));
        for (x, y) in a.dz.chunks(n).zip(b.dz.chunks(n)) {
            let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(scale > 0.1);
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                assert!((u - v).abs() <= 1e-14 * scale, "{u} against {v}");
                if status[i].is_held() {
                    assert_eq!(*u, 0.0);
                }
            }
        }
        for (u, v) in a.weak.iter().zip(&b.weak) {
            assert_eq!(u.index, v.index);
            assert!((u.slope - v.slope).abs() <= 1e-13 * v.slope.max(1.0));
        }
        // gᵀ dz/dθ_k = −μᵀ ∂F/∂θ_k with μ from the free block's transpose solve.
        let g: Vec<f64> = (0..n).map(|i| 1.0 + 0.1 * i as f64).collect();
        let mut mu = g.clone();
        free.solve_transpose(&mut mu).unwrap();
        let mut mu_whole = g.clone();
        whole.solve_transpose(&mut mu_whole).unwrap();
        for k in 0..p {
            let fwd: f64 = (0..n).map(|i| g[i] * a.dz[k * n + i]).sum();
            let adj: f64 = -(0..n).map(|i| mu[i] * dfdtheta[k * n + i]).sum::<f64>();
            assert!(
                (fwd - adj).abs() < 1e-13 * fwd.abs().max(1.0),
                "{fwd} vs {adj}"
            );
        }
        for (u, v) in mu.iter().zip(&mu_whole) {
            assert!((u - v).abs() < 1e-13 * v.abs().max(1.0), "{u} vs {v}");
        }
    }

    /// A weakly active component whose residual moves along the held branch is one-sided; one
    /// whose residual does not is two-sided.
    #[test]
    fn weak_components_are_measured() {
        // F₀ = z₀ − θ (free, z₀ = θ = 1), F₁ = z₁ + z₀ − 1 (z₁ = 0, F₁ = 0: weak, slope 1),
        // F₂ = z₂ (z₂ = 0, F₂ = 0: weak, slope 0).
        let mcp = FnMcp::dense(
            vec![f64::NEG_INFINITY, 0.0, 0.0],
            vec![f64::INFINITY; 3],
            |z: &[f64], f: &mut [f64]| {
                f[0] = z[0] - 1.0;
                f[1] = z[1] + z[0] - 1.0;
                f[2] = z[2];
            },
            |_z: &[f64], jac: &mut [f64]| {
                jac.fill(0.0);
                jac[0] = 1.0; // (0,0)
                jac[1] = 1.0; // (1,0)
                jac[4] = 1.0; // (1,1)
                jac[8] = 1.0; // (2,2)
            },
        )
        .unwrap();
        let z = [1.0, 0.0, 0.0];
        let mut f = [0.0; 3];
        mcp.evaluate(&z, &mut f);
        let opts = ActiveSetOptions::default();
        let status = classify(&z, &f, mcp.lower(), mcp.upper(), &opts);
        let mut sys = ReducedSystem::new();
        let d = sys
            .differentiate(&mcp, &z, &status, &[-1.0, 0.0, 0.0], 1, &opts)
            .unwrap();
        assert_eq!(d.dz, vec![1.0, 0.0, 0.0]);
        assert_eq!(d.weak.len(), 2);
        assert!(!d.weak[0].two_sided && (d.weak[0].slope - 1.0).abs() < 1e-15);
        assert!(d.weak[1].two_sided && d.weak[1].slope == 0.0);
    }
}
