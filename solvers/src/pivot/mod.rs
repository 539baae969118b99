//! A pivotal solver for affine MCPs: Lemke's method generalised to bounded variables
//! (`docs/backends.md#path-like`).
//!
//! The affine MCP is: find `l ≤ z ≤ u` with `w = M z + q` and, for each `i`, `w_i ≥ 0` at
//! `z_i = l_i`, `w_i ≤ 0` at `z_i = u_i`, `w_i = 0` strictly inside. This covers the LCP
//! (`l = 0`, `u = ∞`), the mixed LCP with free variables and the box-constrained LCP.
//!
//! **Formulation.** As in PATH (Dirkse & Ferris, Optim. Methods & Software 5, 1995), the
//! problem is written with Robinson's normal map: `x = z + r`, `z = π_{[l,u]}(x)`, and
//! `L(x) = M z + q + r = 0`. Each index is in one of three states: `z_i` *basic* strictly inside
//! its box (`r_i = 0`), at its lower bound (`r_i ≤ 0` basic), or at its upper bound (`r_i ≥ 0`
//! basic). Lemke's method adds an artificial variable `s` with a *covering vector* `d`,
//! `M z + q + r + s d = 0`, chosen so that a known point `x₀` solves it at `s = 1`, and follows
//! the piecewise-linear curve of solutions as `s` is driven to 0. Each piece is a basis of `n`
//! columns (`M e_i` for a basic `z_i`, `e_i` for a basic `r_i`, `d` for `s`); at a breakpoint a
//! basic variable reaches a bound and leaves, and its complement enters (the complementary
//! pivot rule, Cottle, Pang & Stone, "The Linear Complementarity Problem", §4.4; bounded
//! variables as in Rutherford's MLCP pivoting and Dirkse & Ferris). The curve either reaches
//! `s = 0` (a solution) or leaves on an unbounded edge, a *ray termination*.
//!
//! **Start.** [`AffineStart::Classical`] puts every bounded variable at a bound, free variables
//! at a given value, and uses the covering vector `d_i = c` at lower bounds, `−c` at upper
//! bounds, with `c` large enough that the start is strictly feasible — Lemke's classical
//! scheme, for which ray termination on an LCP with a copositive-plus `M` proves the LCP
//! infeasible (Cottle, Pang & Stone, Thm. 4.4.13). [`AffineStart::NormalMap`] starts from any
//! point `x₀` with `d = −L(x₀)`, so the path runs from `x₀` to the solution; the PATH-like
//! solver uses it to trace the Newton path from its iterate.
//!
//! **Numerics.** The ratio test has a pivot tolerance and treats candidates within a
//! degeneracy tolerance as ties; ties are broken by the lexicographic rule (the minimum-ratio
//! test on `[x_B, B⁻¹]`, which prevents cycling, Cottle, Pang & Stone §4.9), or, when that is
//! switched off, by the largest pivot. The basis is kept as its unit columns plus the explicit
//! inverse of the block of the others, updated at every pivot and recomputed from an LU
//! periodically (module `basis`, `docs/backends.md#lemke-speed`).

pub(crate) mod basis;

use std::time::Instant;

use ecp_model::bounds::{BoundKind, classify};
use ecp_model::{
    Counter, Counters, CscPattern, Mcp, McpSolver, Solution, SolveError, SolveReport, Termination,
    finish_solve, mid, natural_residual, validate_start,
};

use basis::{BasisFactor, Column, max_abs};

/// How ties in Lemke's ratio test are broken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AntiCycling {
    /// The lexicographic minimum-ratio rule (Cottle, Pang & Stone §4.9): among tied leaving
    /// candidates, the lexicographically smallest row of `[x_B, B⁻¹]` scaled by the pivot.
    /// Provably prevents cycling under degeneracy.
    Lexicographic,
    /// The largest pivot among ties (numerically the safest choice, but it can cycle on
    /// degenerate problems). Offered to show what the lexicographic rule prevents.
    LargestPivot,
}

/// Settings of [`Lemke`], with documented defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct LemkeSettings {
    /// A basic variable blocks the entering one only when its rate of change is at least this
    /// times the largest rate (relative pivot tolerance). Default `1e-9`.
    pub pivot_tolerance: f64,
    /// Ratios within `degeneracy_tolerance · (1 + θ_min)` of the minimum are ties, broken by
    /// the [`AntiCycling`] rule. Default `1e-9`.
    pub degeneracy_tolerance: f64,
    /// Pivot limit; `0` means `max(1000, 50 n)`. Default `0`.
    pub max_pivots: usize,
    /// Recompute the basis inverse from a fresh LU after this many updates. Default 50.
    pub refactorization_period: usize,
    /// Tie-breaking rule of the ratio test. Default [`AntiCycling::Lexicographic`].
    pub anti_cycling: AntiCycling,
    /// Natural-residual tolerance used by the [`McpSolver`] implementation to accept a solution
    /// of the (assumed affine) MCP. Default `1e-10`, as the other backends.
    pub tolerance: f64,
}

impl Default for LemkeSettings {
    fn default() -> Self {
        LemkeSettings {
            pivot_tolerance: 1e-9,
            degeneracy_tolerance: 1e-9,
            max_pivots: 0,
            refactorization_period: 50,
            anti_cycling: AntiCycling::Lexicographic,
            tolerance: 1e-10,
        }
    }
}

/// The matrix `M` of an affine MCP.
#[derive(Clone, Copy, Debug)]
pub enum AffineMatrix<'a> {
    /// Dense `n × n`, row-major (`values[i * n + j] = M_ij`).
    DenseRowMajor {
        /// Dimension.
        n: usize,
        /// `n²` entries.
        values: &'a [f64],
    },
    /// Dense `n × n`, column-major (`values[j * n + i] = M_ij`), like [`ecp_model::FnMcp::dense`].
    DenseColumnMajor {
        /// Dimension.
        n: usize,
        /// `n²` entries.
        values: &'a [f64],
    },
    /// Sparse, in a [`CscPattern`] (the layout of an [`Mcp`]'s Jacobian).
    Sparse {
        /// The pattern.
        pattern: &'a CscPattern,
        /// Values in the pattern's order.
        values: &'a [f64],
    },
}

impl AffineMatrix<'_> {
    /// Dimension `n`.
    pub fn dim(&self) -> usize {
        match self {
            AffineMatrix::DenseRowMajor { n, .. } | AffineMatrix::DenseColumnMajor { n, .. } => *n,
            AffineMatrix::Sparse { pattern, .. } => pattern.dim(),
        }
    }

    fn value_count_ok(&self) -> Result<(), String> {
        match self {
            AffineMatrix::DenseRowMajor { n, values }
            | AffineMatrix::DenseColumnMajor { n, values } => {
                if values.len() != n * n {
                    return Err(format!(
                        "M has {} entries, expected {n}×{n} = {}",
                        values.len(),
                        n * n
                    ));
                }
                Ok(())
            }
            AffineMatrix::Sparse { pattern, values } => {
                if values.len() != pattern.nnz() {
                    return Err(format!(
                        "M has {} values, its pattern {} entries",
                        values.len(),
                        pattern.nnz()
                    ));
                }
                Ok(())
            }
        }
    }

    fn values(&self) -> &[f64] {
        match self {
            AffineMatrix::DenseRowMajor { values, .. }
            | AffineMatrix::DenseColumnMajor { values, .. }
            | AffineMatrix::Sparse { values, .. } => values,
        }
    }

    /// Writes column `j` of `M + shift·I` into the dense vector `out`.
    #[inline]
    fn column(&self, j: usize, shift: f64, out: &mut [f64]) {
        match *self {
            AffineMatrix::DenseRowMajor { n, values } => {
                // Entry j of each row (rows of length n > j: the check leaves the loop).
                for (o, row) in out.iter_mut().zip(values.chunks_exact(n)) {
                    *o = row[j];
                }
            }
            AffineMatrix::DenseColumnMajor { n, values } => {
                out.copy_from_slice(&values[j * n..(j + 1) * n]);
            }
            AffineMatrix::Sparse { pattern, values } => {
                out.fill(0.0);
                let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
                let range = cp[j]..cp[j + 1];
                for (&i, &v) in ri[range.clone()].iter().zip(&values[range]) {
                    out[i] = v;
                }
            }
        }
        out[j] += shift;
    }

    /// `out = (M + shift·I) z`, bitwise as [`AffineMatrix::mul`], for a `z` with many zeros
    /// (a solution, whose nonbasic components are 0): a dense row-major row is summed over the
    /// nonzero `z_j` only (listed in `nonzero`). Leaving out the exact ±0 products changes a
    /// sum at most in the sign of a zero result (a nonzero partial sum plus ±0 is itself; a
    /// zero one plus `t` is `t`), so a row whose sum is 0 is summed again in full.
    fn mul_solution(&self, z: &[f64], shift: f64, out: &mut [f64], nonzero: &mut Vec<usize>) {
        let AffineMatrix::DenseRowMajor { n, values } = *self else {
            return self.mul(z, shift, out);
        };
        nonzero.clear();
        nonzero.extend((0..n).filter(|&j| z[j] != 0.0));
        if nonzero.is_empty() || 2 * nonzero.len() > n {
            return self.mul(z, shift, out);
        }
        for (i, o) in out[..n].iter_mut().enumerate() {
            let row = &values[i * n..(i + 1) * n];
            let s: f64 = nonzero.iter().map(|&j| row[j] * z[j]).sum();
            *o = if s == 0.0 {
                row.iter().zip(z).map(|(a, b)| a * b).sum()
            } else {
                s
            };
        }
        if shift != 0.0 {
            for (o, zi) in out.iter_mut().zip(z) {
                *o += shift * zi;
            }
        }
    }

    /// `out = (M + shift·I) z`.
    fn mul(&self, z: &[f64], shift: f64, out: &mut [f64]) {
        if z.iter().all(|&v| v == 0.0) {
            // Lemke's classical start of an LCP and its right-hand sides: z = 0.
            out.fill(0.0);
            return;
        }
        match *self {
            AffineMatrix::DenseRowMajor { n, values } => {
                for i in 0..n {
                    out[i] = values[i * n..(i + 1) * n]
                        .iter()
                        .zip(z)
                        .map(|(a, b)| a * b)
                        .sum();
                }
            }
            AffineMatrix::DenseColumnMajor { n, values } => {
                out.fill(0.0);
                for j in 0..n {
                    let zj = z[j];
                    if zj != 0.0 {
                        for (o, a) in out.iter_mut().zip(&values[j * n..(j + 1) * n]) {
                            *o += a * zj;
                        }
                    }
                }
            }
            AffineMatrix::Sparse { pattern, values } => {
                mul_vec_nonzero_columns(pattern, values, z, out)
            }
        }
        if shift != 0.0 {
            for (o, zi) in out.iter_mut().zip(z) {
                *o += shift * zi;
            }
        }
    }
}

/// An affine MCP `(M + shift·I, q, l, u)`: find `l ≤ z ≤ u` complementary to `w = M z + q`
/// (with the shift added to `M`'s diagonal, the proximal term of the PATH-like solver).
#[derive(Clone, Copy, Debug)]
pub struct AffineMcp<'a> {
    /// The matrix `M`.
    pub m: AffineMatrix<'a>,
    /// The constant `q` (length `n`).
    pub q: &'a [f64],
    /// Lower bounds (`−∞` allowed).
    pub lower: &'a [f64],
    /// Upper bounds (`+∞` allowed).
    pub upper: &'a [f64],
    /// Added to every diagonal entry of `M` (proximal perturbation `M + λI`). Usually 0.
    pub diagonal_shift: f64,
}

/// Where Lemke's path starts.
#[derive(Clone, Copy, Debug)]
pub enum AffineStart<'a> {
    /// Lemke's classical start: bounded variables at a bound (lower if finite), free variables
    /// at the given values (0 when `None`), covering vector `±c` on the bounded rows.
    Classical {
        /// Values of the free variables at the start (length `n`; other entries ignored).
        free_values: Option<&'a [f64]>,
    },
    /// Start from the normal-map point `x₀` (`z₀ = π(x₀)`, `r₀ = x₀ − z₀`) with covering
    /// vector `d = −L(x₀)`: the path runs from `x₀` (at `s = 1`) to the solution (at `s = 0`).
    /// The states (active set) of the first basis are read off `x₀`.
    NormalMap(&'a [f64]),
}

/// A solution of an affine MCP found by [`Lemke`].
#[derive(Clone, Debug, PartialEq)]
pub struct PivotSolution {
    /// The solution `z` (within the bounds).
    pub z: Vec<f64>,
    /// `w = M z + q` (with the diagonal shift, if any).
    pub w: Vec<f64>,
    /// Pivots (basis changes and bound flips) taken.
    pub pivots: usize,
    /// Natural-map residual `‖z − mid(l, u, z − w)‖∞` of `(z, w)`.
    pub residual: f64,
    /// Basis refactorisations (the first factorisation included).
    pub refactorizations: usize,
}

/// Why the pivotal solver stopped without a solution.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PivotError {
    /// The complementary path left on an unbounded edge before the artificial variable reached 0.
    #[error(
        "Lemke's method ended on a ray after {pivots} pivots (artificial variable still at {artificial:.3e}): no solution was reached from this start. For an LCP whose M is copositive-plus (e.g. positive semidefinite) this proves the LCP infeasible; otherwise check the data, or regularise M (add λI)"
    )]
    RayTermination {
        /// Pivots taken.
        pivots: usize,
        /// Value of the artificial variable `s` where the ray starts (0 < s, 1 at the start).
        artificial: f64,
    },
    /// The pivot limit was reached (a very long or cycling path).
    #[error(
        "Lemke's method stopped after {pivots} pivots without a solution: raise LemkeSettings::max_pivots, and keep the lexicographic anti-cycling rule on for degenerate problems"
    )]
    MaxPivots {
        /// Pivots taken.
        pivots: usize,
    },
    /// The input is malformed (sizes, NaN, empty box).
    #[error("invalid affine MCP: {0}")]
    InvalidInput(String),
    /// A basis matrix is numerically singular.
    #[error(
        "the basis became numerically singular after {pivots} pivots ({detail}): the block of M of the free or interior variables is (nearly) singular; regularise M (add λI) or fix some variables at bounds"
    )]
    SingularBasis {
        /// Pivots taken.
        pivots: usize,
        /// Which column was dependent.
        detail: String,
    },
}

/// The piecewise-linear path traced by the pivots: the breakpoints `(x_k, s_k)` in normal-map
/// coordinates, from the start (`s = 1`) to the end point (`s = 0` for a solution, or where
/// the path stopped). The PATH-like solver searches along it (Ralph's path search).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PivotPath {
    n: usize,
    xs: Vec<f64>,
    ss: Vec<f64>,
}

impl PivotPath {
    /// An empty path.
    pub fn new() -> Self {
        Self::default()
    }
    /// Number of breakpoints (start and end included).
    pub fn len(&self) -> usize {
        self.ss.len()
    }
    /// True when no breakpoint has been recorded.
    pub fn is_empty(&self) -> bool {
        self.ss.is_empty()
    }
    /// Breakpoint `k`: the normal-map point `x_k` and the artificial variable `s_k` (`None`
    /// when `k ≥ len()`).
    pub fn breakpoint(&self, k: usize) -> Option<(&[f64], f64)> {
        let s = *self.ss.get(k)?;
        Some((self.xs.get(k * self.n..(k + 1) * self.n)?, s))
    }
    /// Smallest artificial value reached (0 when the path reached a solution).
    pub fn min_artificial(&self) -> f64 {
        self.ss.iter().copied().fold(f64::INFINITY, f64::min)
    }
    fn clear(&mut self, n: usize) {
        self.n = n;
        self.xs.clear();
        self.ss.clear();
    }
    fn push(&mut self, x: &[f64], s: f64) {
        self.xs.extend_from_slice(x);
        self.ss.push(s);
    }

    /// The point of the path where the artificial variable first (in path order) equals
    /// `1 − t`, written into `out`: Ralph's path `p(t)`, with `L(p(t)) = (1 − t) L(x₀)`. `t` is
    /// clamped to what the path reached; returns the `t` used. `out` must have the path's
    /// dimension (otherwise it is left unchanged and 0 is returned).
    pub fn point_at(&self, t: f64, out: &mut [f64]) -> f64 {
        if self.is_empty() || out.len() != self.n || t.is_nan() {
            return 0.0;
        }
        let t = t.clamp(0.0, 1.0 - self.min_artificial().clamp(0.0, 1.0));
        let level = 1.0 - t;
        for k in 0..self.len() - 1 {
            let (Some((x0, s0)), Some((x1, s1))) = (self.breakpoint(k), self.breakpoint(k + 1))
            else {
                break;
            };
            let (lo, hi) = if s0 <= s1 { (s0, s1) } else { (s1, s0) };
            if level >= lo && level <= hi {
                let theta = if (s1 - s0).abs() > 0.0 {
                    ((level - s0) / (s1 - s0)).clamp(0.0, 1.0)
                } else {
                    // A segment at constant s (bound flip at a degenerate point): its start.
                    0.0
                };
                for i in 0..self.n {
                    out[i] = x0[i] + theta * (x1[i] - x0[i]);
                }
                return t;
            }
        }
        // Not reached (round-off at the end): the last point.
        if let Some((x, _)) = self.breakpoint(self.len() - 1) {
            out.copy_from_slice(x);
        }
        t
    }
}

/// Variable codes: `z_i` is `i`, `r_i` is `n + i`, the artificial `s` is `2n`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// `z_i` basic (inside its box, or free).
    Basic,
    /// `z_i` at its lower bound; `r_i ≤ 0` basic (or entering).
    Lower,
    /// `z_i` at its upper bound; `r_i ≥ 0` basic (or entering).
    Upper,
}

/// Lemke's method for affine MCPs with bounded variables. Keep one instance to reuse its
/// buffers across solves.
#[derive(Debug)]
pub struct Lemke {
    settings: LemkeSettings,
    factor: BasisFactor,
    basis: Vec<usize>,
    position: Vec<Option<usize>>,
    state: Vec<State>,
    xb: Vec<f64>,
    zbar: Vec<f64>,
    d: Vec<f64>,
    alpha: Vec<f64>,
    delta: Vec<f64>,
    col: Vec<f64>,
    entering_col: Vec<f64>,
    rhs: Vec<f64>,
    row: Vec<f64>,
    lex_best: Vec<f64>,
    x: Vec<f64>,
    z: Vec<f64>,
    r: Vec<f64>,
    ties: Vec<usize>,
    ratios: Vec<f64>,
    /// Indices of the nonzero components of the solution (`AffineMatrix::mul_solution`).
    nonzero: Vec<usize>,
    /// Bounds of the basic variable at each position.
    lo_b: Vec<f64>,
    hi_b: Vec<f64>,
    lcp_bounds: (Vec<f64>, Vec<f64>),
    refactorizations: usize,
    /// Wall-clock instant after which the pivot loop stops with [`PivotError::MaxPivots`] (the
    /// per-solve budget of a caller such as the PATH-like solver); `None` for no limit.
    deadline: Option<std::time::Instant>,
    /// Pivots a path may make at most, below `LemkeSettings::max_pivots` (`set_pivot_cap`).
    pivot_cap: Option<usize>,
}

/// The entering column's kind, kept over the ratio test (its values stay in `entering_col`).
#[derive(Clone, Copy)]
enum ColumnKind {
    Unit(usize),
    Dense,
}

/// Internal result of the ratio test.
enum Block {
    /// The basic variable at this position leaves.
    Basic(usize),
    /// The entering variable reaches its own opposite bound first.
    Own,
}

impl Lemke {
    /// A solver with the given settings.
    pub fn new(settings: LemkeSettings) -> Self {
        Lemke {
            settings,
            factor: BasisFactor::default(),
            basis: Vec::new(),
            position: Vec::new(),
            state: Vec::new(),
            xb: Vec::new(),
            zbar: Vec::new(),
            d: Vec::new(),
            alpha: Vec::new(),
            delta: Vec::new(),
            col: Vec::new(),
            entering_col: Vec::new(),
            rhs: Vec::new(),
            row: Vec::new(),
            lex_best: Vec::new(),
            x: Vec::new(),
            z: Vec::new(),
            r: Vec::new(),
            ties: Vec::new(),
            ratios: Vec::new(),
            nonzero: Vec::new(),
            lo_b: Vec::new(),
            hi_b: Vec::new(),
            lcp_bounds: (Vec::new(), Vec::new()),
            refactorizations: 0,
            deadline: None,
            pivot_cap: None,
        }
    }

    /// The settings.
    pub fn settings(&self) -> &LemkeSettings {
        &self.settings
    }

    /// Mutable settings.
    pub fn settings_mut(&mut self) -> &mut LemkeSettings {
        &mut self.settings
    }

    /// Caps the pivots of each later path (`None`: only `LemkeSettings::max_pivots`); a path
    /// that reaches the cap ends with [`PivotError::MaxPivots`], as at `max_pivots`.
    pub fn set_pivot_cap(&mut self, cap: Option<usize>) {
        self.pivot_cap = cap;
    }

    /// Sets (or clears) the wall-clock instant after which pivoting stops as if the pivot limit
    /// had been reached; the limit is checked every 16 pivots.
    pub fn set_deadline(&mut self, deadline: Option<std::time::Instant>) {
        self.deadline = deadline;
    }

    /// Solves the LCP `0 ≤ z ⊥ M z + q ≥ 0` (`n = q.len()`, `m_row_major` the `n × n` matrix
    /// by rows) with Lemke's classical start (covering vector `e`).
    pub fn solve_lcp(
        &mut self,
        m_row_major: &[f64],
        q: &[f64],
    ) -> Result<PivotSolution, PivotError> {
        self.lcp(m_row_major, q, true)
    }

    /// As [`Lemke::solve_lcp`], with `z` and `w = M z + q` written into the caller's slices
    /// (length `n`) instead of new vectors: a warm solver allocates nothing, as a C solver that
    /// writes into its caller's arrays. The returned [`PivotSolution`] has empty `z` and `w`;
    /// the slices are written only when the LCP is solved.
    pub fn solve_lcp_into(
        &mut self,
        m_row_major: &[f64],
        q: &[f64],
        z: &mut [f64],
        w: &mut [f64],
    ) -> Result<PivotSolution, PivotError> {
        let n = q.len();
        if z.len() != n || w.len() != n {
            return Err(PivotError::InvalidInput(format!(
                "z has {} and w {} entries, q has {n}",
                z.len(),
                w.len()
            )));
        }
        let sol = self.lcp(m_row_major, q, false)?;
        // `run` leaves the solution in the workspace (`self.z`, `self.r`).
        z.copy_from_slice(&self.z[..n]);
        w.copy_from_slice(&self.r[..n]);
        Ok(sol)
    }

    fn lcp(
        &mut self,
        m_row_major: &[f64],
        q: &[f64],
        want_solution: bool,
    ) -> Result<PivotSolution, PivotError> {
        let n = q.len();
        // The bounds of an LCP (0 and +∞), kept between solves: written only when n changes.
        let (mut lower, mut upper) = std::mem::take(&mut self.lcp_bounds);
        if lower.len() != n {
            lower.clear();
            lower.resize(n, 0.0);
            upper.clear();
            upper.resize(n, f64::INFINITY);
        }
        let problem = AffineMcp {
            m: AffineMatrix::DenseRowMajor {
                n,
                values: m_row_major,
            },
            q,
            lower: &lower,
            upper: &upper,
            diagonal_shift: 0.0,
        };
        let result = self.run(
            &problem,
            &AffineStart::Classical { free_values: None },
            None,
            want_solution,
        );
        self.lcp_bounds = (lower, upper);
        result
    }

    /// Solves a box-constrained affine MCP (LCP, mixed LCP, box LCP) from `start`.
    pub fn solve_affine(
        &mut self,
        problem: &AffineMcp<'_>,
        start: &AffineStart<'_>,
    ) -> Result<PivotSolution, PivotError> {
        self.run(problem, start, None, true)
    }

    /// As [`Lemke::solve_affine`], and records the breakpoints of the path in `path` (also
    /// when the method fails: then the path ends where it stopped).
    pub fn solve_affine_with_path(
        &mut self,
        problem: &AffineMcp<'_>,
        start: &AffineStart<'_>,
        path: &mut PivotPath,
    ) -> Result<PivotSolution, PivotError> {
        self.run(problem, start, Some(path), true)
    }

    /// As [`Lemke::solve_affine_with_path`] for a caller that needs only the path, the pivot
    /// count and the residual: the returned `z` and `w` are empty (nothing is allocated).
    pub(crate) fn trace_path(
        &mut self,
        problem: &AffineMcp<'_>,
        start: &AffineStart<'_>,
        path: &mut PivotPath,
    ) -> Result<PivotSolution, PivotError> {
        self.run(problem, start, Some(path), false)
    }

    fn validate(problem: &AffineMcp<'_>, start: &AffineStart<'_>) -> Result<(), PivotError> {
        let n = problem.q.len();
        let bad = |s: String| Err(PivotError::InvalidInput(s));
        if problem.m.dim() != n {
            return bad(format!(
                "M is {0}×{0} but q has {n} entries",
                problem.m.dim()
            ));
        }
        problem
            .m
            .value_count_ok()
            .map_err(PivotError::InvalidInput)?;
        if problem.lower.len() != n || problem.upper.len() != n {
            return bad(format!(
                "bounds have {} and {} entries, q has {n}",
                problem.lower.len(),
                problem.upper.len()
            ));
        }
        // A branch-free scan first (it vectorises); the position only for the message.
        let values = problem.m.values();
        if !all_finite(values)
            && let Some(k) = values.iter().position(|v| !v.is_finite())
        {
            return bad(format!("entry {k} of M is {}", values[k]));
        }
        if let Some(i) = problem.q.iter().position(|v| !v.is_finite()) {
            return bad(format!("q[{i}] = {} is not finite", problem.q[i]));
        }
        if !problem.diagonal_shift.is_finite() {
            return bad("the diagonal shift is not finite".into());
        }
        // An empty or NaN box (l > u, a NaN, l = +∞ or u = −∞): a branch-free scan first (`|`,
        // not `||`); the index only for the message.
        let empty = |l: f64, u: f64| {
            l.is_nan() | u.is_nan() | (l > u) | (l == f64::INFINITY) | (u == f64::NEG_INFINITY)
        };
        let (lower, upper) = (&problem.lower[..n], &problem.upper[..n]);
        if lower
            .iter()
            .zip(upper)
            .fold(false, |acc, (&l, &u)| acc | empty(l, u))
            && let Some(i) = (0..n).find(|&i| empty(lower[i], upper[i]))
        {
            let (l, u) = (lower[i], upper[i]);
            return bad(format!("bounds of z[{i}] are [{l}, {u}]: empty or NaN"));
        }
        match start {
            AffineStart::Classical {
                free_values: Some(v),
            } => {
                if v.len() != n {
                    return bad(format!("{} free values given for n = {n}", v.len()));
                }
                if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                    return bad(format!("free value {i} is not finite"));
                }
            }
            AffineStart::NormalMap(x0) => {
                if x0.len() != n {
                    return bad(format!("start point has {} entries for n = {n}", x0.len()));
                }
                if let Some(i) = x0.iter().position(|x| !x.is_finite()) {
                    return bad(format!("start point entry {i} is not finite"));
                }
            }
            AffineStart::Classical { free_values: None } => {}
        }
        Ok(())
    }

    fn resize(&mut self, n: usize) {
        self.basis.resize(n, 0);
        // A warm solver of the same size refills in place (cheaper than clear and resize).
        if self.position.len() == 2 * n + 1 && self.state.len() == n {
            self.position.fill(None);
            self.state.fill(State::Lower);
        } else {
            self.position.clear();
            self.position.resize(2 * n + 1, None);
            self.state.clear();
            self.state.resize(n, State::Lower);
        }
        // Every entry of these is written before it is read: only their length matters.
        for v in [
            &mut self.xb,
            &mut self.zbar,
            &mut self.d,
            &mut self.alpha,
            &mut self.delta,
            &mut self.col,
            &mut self.entering_col,
            &mut self.rhs,
            &mut self.row,
            &mut self.lex_best,
            &mut self.x,
            &mut self.z,
            &mut self.r,
            &mut self.ratios,
            &mut self.lo_b,
            &mut self.hi_b,
        ] {
            if v.len() != n {
                v.resize(n, 0.0);
            }
        }
        self.refactorizations = 0;
    }

    /// Column of variable `v` (`z_i`, `r_i` or `s`) into `out`.
    #[inline(always)]
    fn var_column(&self, problem: &AffineMcp<'_>, v: usize, out: &mut [f64]) {
        let n = problem.q.len();
        if v < n {
            problem.m.column(v, problem.diagonal_shift, out);
        } else if v < 2 * n {
            out.fill(0.0);
            out[v - n] = 1.0;
        } else {
            out.copy_from_slice(&self.d);
        }
    }

    /// The column of variable `v`: `e_i` for `r_i`, else its dense values written into `buf`.
    #[inline]
    fn column_of<'b>(&self, problem: &AffineMcp<'_>, v: usize, buf: &'b mut [f64]) -> Column<'b> {
        let n = problem.q.len();
        if v >= n && v < 2 * n {
            Column::Unit(v - n)
        } else {
            self.var_column(problem, v, buf);
            Column::Dense(buf)
        }
    }

    /// Factorises the current basis (unit columns first, so that a dependent column is always a
    /// `z` column, or `s`); later updates go to an eta file when `eta_mode`, else to the
    /// explicit inverse of the basis's Schur block.
    fn refactor(
        &mut self,
        problem: &AffineMcp<'_>,
        pivots: usize,
        eta_mode: bool,
    ) -> Result<(), PivotError> {
        let n = problem.q.len();
        self.factor.begin(n, eta_mode);
        let mut col = std::mem::take(&mut self.col);
        for p in 0..n {
            match self.column_of(problem, self.basis[p], &mut col) {
                Column::Unit(row) => self.factor.set_unit(p, row),
                Column::Dense(values) => self.factor.set_dense(p, values),
            }
        }
        self.col = col;
        let result = self.factor.finish();
        self.refactorizations += 1;
        result.map_err(|dep| {
            let v = self.basis[dep.position];
            PivotError::SingularBasis {
                pivots,
                detail: if v < n {
                    format!("column of z[{v}] depends on the others")
                } else {
                    "column of the artificial variable depends on the others".into()
                },
            }
        })
    }

    /// `rhs = −q − Σ_{z_i nonbasic} M e_i z̄_i − s d` (with `s` when it is nonbasic).
    fn compute_rhs(&mut self, problem: &AffineMcp<'_>, s_nonbasic: f64) {
        let n = problem.q.len();
        for ((z, st), zbar) in self.z[..n]
            .iter_mut()
            .zip(&self.state[..n])
            .zip(&self.zbar[..n])
        {
            *z = if *st == State::Basic { 0.0 } else { *zbar };
        }
        let mut mz = std::mem::take(&mut self.rhs);
        problem.m.mul(&self.z, problem.diagonal_shift, &mut mz);
        for ((r, q), d) in mz[..n].iter_mut().zip(&problem.q[..n]).zip(&self.d[..n]) {
            *r = -q - *r - s_nonbasic * d;
        }
        self.rhs = mz;
    }

    /// Iterative refinement of the basic solution `x_B` (as the pivots updated it): the
    /// residual `rhs − B x_B`, computed from the data, is solved for a correction, which removes
    /// the round-off the updates accumulated; a second step when the first correction was not
    /// negligible.
    fn refine(&mut self, problem: &AffineMcp<'_>) {
        let n = problem.q.len();
        let mut x = std::mem::take(&mut self.xb);
        let mut res = std::mem::take(&mut self.row);
        let mut col = std::mem::take(&mut self.col);
        for _ in 0..2 {
            res.copy_from_slice(&self.rhs);
            for p in 0..n {
                if x[p] != 0.0 {
                    match self.column_of(problem, self.basis[p], &mut col) {
                        Column::Unit(row) => res[row] -= x[p],
                        Column::Dense(c) => {
                            for (r, c) in res.iter_mut().zip(c) {
                                *r -= c * x[p];
                            }
                        }
                    }
                }
            }
            self.factor.solve(&mut res);
            if !all_finite(&res) {
                break;
            }
            let (mut dmax, mut xmax) = (0.0f64, 0.0f64);
            for (xi, d) in x.iter_mut().zip(&res) {
                *xi += d;
                // Maxima of absolute values (no NaN here): a compare and select is `f64::max`.
                let (da, xa) = (d.abs(), xi.abs());
                dmax = if da > dmax { da } else { dmax };
                xmax = if xa > xmax { xa } else { xmax };
            }
            if dmax <= 1e-14 * xmax {
                break;
            }
        }
        self.xb = x;
        self.row = res;
        self.col = col;
    }

    /// Bounds `[lo, hi]` of the basic variable `v`.
    #[inline(always)]
    fn var_bounds(&self, problem: &AffineMcp<'_>, v: usize) -> (f64, f64) {
        let n = problem.q.len();
        if v < n {
            (problem.lower[v], problem.upper[v])
        } else if v < 2 * n {
            let i = v - n;
            if problem.lower[i] == problem.upper[i] {
                (f64::NEG_INFINITY, f64::INFINITY)
            } else {
                match self.state[i] {
                    State::Upper => (0.0, f64::INFINITY),
                    _ => (f64::NEG_INFINITY, 0.0),
                }
            }
        } else {
            (0.0, f64::INFINITY)
        }
    }

    /// Normal-map point `x = z + r` of the current basic solution.
    fn current_x(&mut self, n: usize) {
        let (state, zbar, xb) = (&self.state[..n], &self.zbar[..n], &self.xb[..n]);
        let (z, r, x) = (&mut self.z[..n], &mut self.r[..n], &mut self.x[..n]);
        let position = &self.position[..2 * n];
        for i in 0..n {
            let (zi, ri) = match state[i] {
                State::Basic => (position[i].map_or(zbar[i], |p| xb[p]), 0.0),
                _ => (zbar[i], position[n + i].map_or(0.0, |p| xb[p])),
            };
            z[i] = zi;
            r[i] = ri;
            x[i] = zi + ri;
        }
    }

    fn run(
        &mut self,
        problem: &AffineMcp<'_>,
        start: &AffineStart<'_>,
        mut path: Option<&mut PivotPath>,
        want_solution: bool,
    ) -> Result<PivotSolution, PivotError> {
        Self::validate(problem, start)?;
        let n = problem.q.len();
        self.resize(n);
        if let Some(p) = path.as_deref_mut() {
            p.clear(n);
        }
        let (l, u) = (problem.lower, problem.upper);

        // Start point (z₀, r₀) and covering vector d = −(M z₀ + q + r₀).
        match start {
            AffineStart::NormalMap(x0) => {
                for i in 0..n {
                    let x = x0[i];
                    let (st, zi) = match classify(l[i], u[i]) {
                        BoundKind::Free => (State::Basic, x),
                        _ if l[i] == u[i] => (State::Lower, l[i]),
                        _ if x < l[i] => (State::Lower, l[i]),
                        _ if x > u[i] => (State::Upper, u[i]),
                        _ if x == l[i] && l[i].is_finite() => (State::Lower, l[i]),
                        _ if x == u[i] && u[i].is_finite() => (State::Upper, u[i]),
                        _ => (State::Basic, x),
                    };
                    self.state[i] = st;
                    self.zbar[i] = zi;
                    self.z[i] = zi;
                    self.r[i] = x - zi;
                }
                problem.m.mul(&self.z, problem.diagonal_shift, &mut self.d);
                for i in 0..n {
                    self.d[i] = -(self.d[i] + problem.q[i] + self.r[i]);
                }
            }
            AffineStart::Classical { free_values } => {
                for i in 0..n {
                    let (st, zi) = match classify(l[i], u[i]) {
                        BoundKind::Free => (State::Basic, free_values.map_or(0.0, |v| v[i])),
                        BoundKind::Lower | BoundKind::Box => (State::Lower, l[i]),
                        BoundKind::Upper => (State::Upper, u[i]),
                    };
                    self.state[i] = st;
                    self.zbar[i] = zi;
                    self.z[i] = zi;
                }
                // g = M z₀ + q; c makes r₀ = −g − c·σ strictly feasible (|r₀| ≥ 1 on the
                // right side), so the covering vector on the bounded rows is c·σ.
                let mut g = std::mem::take(&mut self.d);
                problem.m.mul(&self.z, problem.diagonal_shift, &mut g);
                let mut c: f64 = 1.0;
                let (state, q) = (&self.state[..n], &problem.q[..n]);
                let (l, u) = (&l[..n], &u[..n]);
                for i in 0..n {
                    g[i] += q[i];
                    match state[i] {
                        State::Lower if l[i] != u[i] => c = c.max(1.0 - g[i]),
                        State::Upper => c = c.max(1.0 + g[i]),
                        _ => {}
                    }
                }
                for ((r, g), st) in self.r[..n].iter_mut().zip(&mut g[..n]).zip(state) {
                    let (ri, di) = match st {
                        State::Basic => (0.0, -*g),
                        State::Lower => (-*g - c, c),
                        State::Upper => (-*g + c, -c),
                    };
                    *r = ri;
                    *g = di;
                }
                self.d = g;
            }
        }
        if let Some(p) = path.as_deref_mut() {
            // x is read only for the path until `current_x` rewrites it.
            for i in 0..n {
                self.x[i] = self.z[i] + self.r[i];
            }
            p.push(&self.x, 1.0);
        }

        // The starting basis: position i holds z_i (basic) or r_i.
        for i in 0..n {
            let v = if self.state[i] == State::Basic {
                i
            } else {
                n + i
            };
            self.basis[i] = v;
            self.position[v] = Some(i);
            self.xb[i] = if v < n { self.z[i] } else { self.r[i] };
            (self.lo_b[i], self.hi_b[i]) = self.var_bounds(problem, v);
        }
        let dnorm = max_abs(&self.d);
        let mut pivots = 0usize;
        // When d = 0 the start solves the problem already.
        if dnorm > 0.0 {
            // A path starts with an eta file over the first factorisation: most paths (the
            // linearisations of the PATH-like solver) end within a few pivots.
            self.refactor(problem, pivots, true)?;
            self.pivot_loop(problem, &mut pivots, path.as_deref_mut())?;
            // The solution at s = 0, from the right-hand side recomputed from the data and the
            // basis inverse (refreshed at least every `refactorization_period` pivots), with a
            // step of iterative refinement.
            self.compute_rhs(problem, 0.0);
            self.refine(problem);
        }
        self.current_x(n);
        // z and w in the workspace (`self.z`, `self.r`), copied out only when the caller wants
        // the solution: the PATH-like solver reads the path, and allocates nothing here.
        let mut z = std::mem::take(&mut self.z);
        let mut w = std::mem::take(&mut self.r);
        for i in 0..n {
            z[i] = mid(l[i], u[i], z[i]);
        }
        problem
            .m
            .mul_solution(&z, problem.diagonal_shift, &mut w, &mut self.nonzero);
        for i in 0..n {
            w[i] += problem.q[i];
        }
        if let Some(p) = path {
            // The end point, recomputed cleanly (normal-map coordinates x = z − w).
            for i in 0..n {
                self.x[i] = z[i] - w[i];
            }
            if p.len() > 1 {
                p.xs.truncate((p.len() - 1) * n);
                p.ss.pop();
            }
            p.push(&self.x, 0.0);
        }
        let residual = natural_residual(&z, &w, l, u);
        let (z_out, w_out) = if want_solution {
            (z.clone(), w.clone())
        } else {
            (Vec::new(), Vec::new())
        };
        self.z = z;
        self.r = w;
        if !residual.is_finite() {
            return Err(PivotError::SingularBasis {
                pivots,
                detail: "the final basic solution is not finite".into(),
            });
        }
        Ok(PivotSolution {
            z: z_out,
            w: w_out,
            pivots,
            residual,
            refactorizations: self.refactorizations,
        })
    }

    fn pivot_loop(
        &mut self,
        problem: &AffineMcp<'_>,
        pivots: &mut usize,
        mut path: Option<&mut PivotPath>,
    ) -> Result<(), PivotError> {
        let n = problem.q.len();
        let max_pivots = if self.settings.max_pivots == 0 {
            1000usize.max(50 * n)
        } else {
            self.settings.max_pivots
        };
        let max_pivots = self.pivot_cap.map_or(max_pivots, |c| max_pivots.min(c));
        let s_var = 2 * n;
        // The artificial variable enters first, decreasing from 1.
        let mut entering = s_var;
        let mut dir = -1.0f64;
        let mut s_nonbasic = 1.0f64;
        loop {
            if *pivots >= max_pivots
                || (*pivots % 16 == 15
                    && self
                        .deadline
                        .is_some_and(|d| std::time::Instant::now() >= d))
            {
                return Err(PivotError::MaxPivots { pivots: *pivots });
            }
            // alpha = B⁻¹ a_e; the basic variables move by delta = −dir·alpha per unit step.
            let mut alpha = std::mem::take(&mut self.alpha);
            let mut col = std::mem::take(&mut self.entering_col);
            let column = self.column_of(problem, entering, &mut col);
            self.factor.solve_column(column, &mut alpha);
            if !all_finite(&alpha) {
                self.alpha = alpha;
                self.entering_col = col;
                return Err(PivotError::SingularBasis {
                    pivots: *pivots,
                    detail: "a basis solve produced a non-finite value".into(),
                });
            }
            // The largest rate `max |δ_p|` (the scale of the ratio test's tolerances) in the same
            // pass: `|δ_p| = |α_p|` as `dir = ±1`, and a maximum does not depend on the order.
            let mut dmax = 0.0f64;
            for (d, &a) in self.delta[..n].iter_mut().zip(&alpha[..n]) {
                *d = -dir * a;
                // A compare and select: `f64::max` exactly on absolute values (`alpha` is finite).
                let a = d.abs();
                dmax = if a > dmax { a } else { dmax };
            }
            self.alpha = alpha;
            let column = match column {
                Column::Unit(row) => ColumnKind::Unit(row),
                Column::Dense(_) => ColumnKind::Dense,
            };
            self.entering_col = col;

            // Entering variable's own range: z between its bounds, s down to 0.
            let own = if entering < n {
                let i = entering;
                let range = problem.upper[i] - problem.lower[i];
                if range.is_finite() {
                    range
                } else {
                    f64::INFINITY
                }
            } else if entering == s_var {
                s_nonbasic
            } else {
                f64::INFINITY
            };
            let (theta, block) = self.ratio_test(problem, own, dmax, pivots)?;

            // Move to the breakpoint.
            for (x, d) in self.xb[..n].iter_mut().zip(&self.delta[..n]) {
                *x += theta * d;
            }
            let entering_value = if entering < n {
                self.zbar[entering] + dir * theta
            } else if entering == s_var {
                s_nonbasic + dir * theta
            } else {
                dir * theta
            };
            *pivots += 1;
            let mut finished = false;
            match block {
                Block::Own => {
                    if entering == s_var {
                        finished = true;
                        s_nonbasic = 0.0;
                    } else {
                        // z_i crossed its box: it sits at the other bound, and r_i enters.
                        let i = entering;
                        if dir > 0.0 {
                            self.state[i] = State::Upper;
                            self.zbar[i] = problem.upper[i];
                            dir = 1.0;
                        } else {
                            self.state[i] = State::Lower;
                            self.zbar[i] = problem.lower[i];
                            dir = -1.0;
                        }
                        entering = n + i;
                    }
                }
                Block::Basic(p) => {
                    let leaving = self.basis[p];
                    let leaving_delta = self.delta[p];
                    // Basis change: position p now holds the entering variable.
                    let column = match column {
                        ColumnKind::Unit(row) => Column::Unit(row),
                        ColumnKind::Dense => Column::Dense(&self.entering_col),
                    };
                    self.factor.update(p, column, &self.alpha);
                    self.basis[p] = entering;
                    self.position[leaving] = None;
                    self.position[entering] = Some(p);
                    self.xb[p] = entering_value;
                    // A basic variable's bounds do not change while it is basic (an r_i's side
                    // is fixed by its z_i's state before r_i enters).
                    (self.lo_b[p], self.hi_b[p]) = self.var_bounds(problem, entering);
                    if entering < n {
                        self.state[entering] = State::Basic;
                    } else if entering == s_var {
                        s_nonbasic = 0.0;
                    }
                    if leaving == s_var {
                        finished = true;
                    } else if leaving < n {
                        // z_i reached a bound: fix it there, r_i enters away from 0.
                        let i = leaving;
                        if leaving_delta < 0.0 {
                            self.state[i] = State::Lower;
                            self.zbar[i] = problem.lower[i];
                            dir = -1.0;
                        } else {
                            self.state[i] = State::Upper;
                            self.zbar[i] = problem.upper[i];
                            dir = 1.0;
                        }
                        entering = n + i;
                    } else {
                        // r_i reached 0: z_i enters, moving into the box from its bound.
                        let i = leaving - n;
                        dir = if self.state[i] == State::Upper {
                            -1.0
                        } else {
                            1.0
                        };
                        entering = i;
                    }
                    // A longer path switches to the explicit inverse (updated in O(m²) per
                    // pivot), refreshed every `refactorization_period` pivots.
                    let period = if self.factor.eta_mode() {
                        ETA_PIVOTS.min(self.settings.refactorization_period)
                    } else {
                        self.settings.refactorization_period
                    };
                    if !finished && self.factor.updates() >= period {
                        self.refactor(problem, *pivots, false)?;
                        self.compute_rhs(problem, s_nonbasic);
                        let mut rhs = std::mem::take(&mut self.rhs);
                        self.factor.solve(&mut rhs);
                        self.xb.copy_from_slice(&rhs);
                        self.rhs = rhs;
                    }
                }
            }
            if let Some(path) = path.as_deref_mut() {
                self.current_x(n);
                let s = match self.position[s_var] {
                    Some(p) => self.xb[p],
                    None => s_nonbasic,
                };
                path.push(&self.x, if finished { 0.0 } else { s.max(0.0) });
            }
            if finished {
                return Ok(());
            }
        }
    }

    /// The ratio test: the step `θ` and what blocks, `dmax = max_p |δ_p|`. Ties go to the
    /// artificial variable, then to the anti-cycling rule.
    fn ratio_test(
        &mut self,
        problem: &AffineMcp<'_>,
        own: f64,
        dmax: f64,
        pivots: &usize,
    ) -> Result<(f64, Block), PivotError> {
        let n = problem.q.len();
        let s_var = 2 * n;
        // Rates below `noise` are round-off of zero and never block; rates below `tol` block
        // only when no larger pivot ties with them (a small pivot is still better than letting a
        // variable leave its bounds). The artificial variable blocks at any negative rate, so
        // that it never passes 0.
        let tol = self.settings.pivot_tolerance * dmax;
        let noise = NOISE * dmax;
        // Each basic variable's ratio, once; infinite when it does not block (an infinite
        // bound gives an infinite ratio by itself).
        let mut theta_min = own;
        let s_position = self.position[s_var].unwrap_or(usize::MAX);
        let (delta, xb) = (&self.delta[..n], &self.xb[..n]);
        let (lo_b, hi_b) = (&self.lo_b[..n], &self.hi_b[..n]);
        for (p, r) in self.ratios[..n].iter_mut().enumerate() {
            let dp = delta[p];
            let cutoff = if p == s_position { 0.0 } else { noise };
            let t = if dp < -cutoff {
                (xb[p] - lo_b[p]).max(0.0) / -dp
            } else if dp > cutoff {
                (hi_b[p] - xb[p]).max(0.0) / dp
            } else {
                f64::INFINITY
            };
            *r = t;
            theta_min = theta_min.min(t);
        }
        let ratio = |me: &Self, p: usize| -> Option<f64> {
            let t = me.ratios[p];
            t.is_finite().then_some(t)
        };
        if !theta_min.is_finite() {
            let artificial = match self.position[s_var] {
                Some(p) => self.xb[p],
                None => 1.0,
            };
            return Err(PivotError::RayTermination {
                pivots: *pivots,
                artificial,
            });
        }
        let cut = theta_min + self.settings.degeneracy_tolerance * (1.0 + theta_min);
        self.ties.clear();
        for (p, &t) in self.ratios[..n].iter().enumerate() {
            if t.is_finite() && t <= cut {
                self.ties.push(p);
            }
        }
        let own_tied = own <= cut;
        // When a tie has a pivot of at least `tol`, the ties with smaller pivots (other than
        // the artificial variable) are dropped; usually there are none to drop.
        let keep = |p: usize| self.delta[p].abs() >= tol || self.basis[p] == s_var;
        if self.ties.iter().any(|&p| self.delta[p].abs() >= tol)
            && !self.ties.iter().all(|&p| keep(p))
        {
            let delta = &self.delta;
            let basis = &self.basis;
            self.ties
                .retain(|&p| delta[p].abs() >= tol || basis[p] == s_var);
        }
        // The artificial variable leaves whenever it may: that ends the path at a solution.
        if let Some(&p) = self.ties.iter().find(|&&p| self.basis[p] == s_var) {
            return Ok((ratio(self, p).unwrap_or(theta_min), Block::Basic(p)));
        }
        if self.ties.is_empty() {
            return Ok((own, Block::Own));
        }
        if self.ties.len() == 1 && !own_tied {
            let p = self.ties[0];
            return Ok((ratio(self, p).unwrap_or(theta_min), Block::Basic(p)));
        }
        let choice = match self.settings.anti_cycling {
            AntiCycling::LargestPivot => {
                let mut best: Option<usize> = None;
                for &p in &self.ties {
                    if best.is_none_or(|b| self.delta[p].abs() > self.delta[b].abs()) {
                        best = Some(p);
                    }
                }
                match best {
                    Some(p) => Block::Basic(p),
                    None => Block::Own,
                }
            }
            AntiCycling::Lexicographic => self.lexicographic_choice(own_tied),
        };
        let theta = match choice {
            Block::Basic(p) => ratio(self, p).unwrap_or(theta_min),
            Block::Own => own,
        };
        // The chosen variable lands exactly on its bound; the other tied ones end up within
        // the degeneracy tolerance of theirs (as in Harris's ratio test).
        Ok((theta, choice))
    }

    /// Lexicographic minimum among the tied candidates: the vector
    /// `[θ_p, −sign(δ_p) (B⁻¹)_{p,:} / |δ_p|]` (the ratio of the ε-perturbed right-hand side
    /// `b + (ε, ε², …)`); the entering variable's own bound has `[θ, 0, …, 0]`.
    fn lexicographic_choice(&mut self, own_tied: bool) -> Block {
        let ties = std::mem::take(&mut self.ties);
        let mut best: Option<usize> = None;
        let mut row = std::mem::take(&mut self.row);
        let mut best_row = std::mem::take(&mut self.lex_best);
        if own_tied {
            best_row.fill(0.0);
        }
        let mut have_best = own_tied;
        for &p in &ties {
            row.fill(0.0);
            row[p] = 1.0;
            self.factor.solve_transpose(&mut row);
            let scale = -self.delta[p].signum() / self.delta[p].abs();
            for v in row.iter_mut() {
                *v *= scale;
            }
            if !have_best || lex_less(&row, &best_row) {
                best_row.copy_from_slice(&row);
                best = Some(p);
                have_best = true;
            }
        }
        self.row = row;
        self.lex_best = best_row;
        self.ties = ties;
        match best {
            Some(p) => Block::Basic(p),
            None => Block::Own,
        }
    }
}

/// `y = A x` for `A` stored in `pattern`, skipping the columns where `x_j = 0`: bitwise the
/// same as [`CscPattern::mul_vec`] for finite values (a sum started at +0 never becomes −0, so
/// adding the skipped ±0 products changes nothing).
pub(crate) fn mul_vec_nonzero_columns(
    pattern: &CscPattern,
    values: &[f64],
    x: &[f64],
    y: &mut [f64],
) {
    y.fill(0.0);
    let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
    for (j, &xj) in x.iter().enumerate() {
        if xj != 0.0 {
            // Rows and values zipped: no bounds checks on them in the loop.
            let range = cp[j]..cp[j + 1];
            for (&i, &v) in ri[range.clone()].iter().zip(&values[range]) {
                y[i] += v * xj;
            }
        }
    }
}

/// True when no entry is NaN or infinite: `v · 0` is NaN exactly there (±0 elsewhere), and a
/// sum is NaN once one of its terms is. Four independent sums, so that the loop vectorises to
/// a multiply and an add per four entries (the exponent bits' test took about three times the
/// instructions: PATH tests every Jacobian it evaluates, `docs/latency.md`, branch
/// wip-pathdesk3).
pub(crate) fn all_finite(values: &[f64]) -> bool {
    let mut acc = [0.0f64; 4];
    let mut chunks = values.chunks_exact(4);
    for c in &mut chunks {
        for (a, v) in acc.iter_mut().zip(c) {
            *a += v * 0.0;
        }
    }
    let rest = chunks.remainder().iter().fold(0.0, |a, v| a + v * 0.0);
    acc[0] + acc[1] + acc[2] + acc[3] + rest == 0.0
}

/// Pivots kept in an eta file before a path switches to the explicit inverse of the Schur
/// block: the eta file costs `O(k n)` per solve after `k` pivots, forming the inverse `O(m³)`
/// once (`docs/decisions.md#pivoting-basis-as-the-inverse-of-its-schur-block`).
const ETA_PIVOTS: usize = 8;

/// Relative size of a rate of change below which it is round-off of zero.
const NOISE: f64 = 1e-14;

/// `a <_lex b`, treating entries equal up to round-off relative to the vectors' size.
fn lex_less(a: &[f64], b: &[f64]) -> bool {
    let scale = a
        .iter()
        .chain(b)
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    for (x, y) in a.iter().zip(b) {
        if (x - y).abs() > 1e-12 * scale {
            return x < y;
        }
    }
    false
}

/// `Lemke` as an MCP backend for problems whose `F` is affine: `F` and `J` are evaluated once
/// at the (projected) start, the affine MCP `F(z₀) + J (z − z₀)` is solved from Lemke's
/// classical start, and the answer is verified with the model's natural residual (so a
/// non-affine `F` is reported as not converged, never silently accepted).
impl McpSolver for Lemke {
    fn name(&self) -> &str {
        "lemke"
    }

    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let start = Instant::now();
        validate_start(mcp, z0)?;
        let n = mcp.dim();
        let (l, u) = (mcp.lower(), mcp.upper());
        let pattern = mcp.jacobian_pattern().clone();
        let zs: Vec<f64> = (0..n).map(|i| mid(l[i], u[i], z0[i])).collect();
        let mut f = vec![0.0; n];
        let mut jac = vec![0.0; pattern.nnz()];
        mcp.evaluate_with_jacobian(&zs, &mut f, &mut jac);
        let mut jz = vec![0.0; n];
        pattern.mul_vec(&jac, &zs, &mut jz);
        let q: Vec<f64> = (0..n).map(|i| f[i] - jz[i]).collect();
        let problem = AffineMcp {
            m: AffineMatrix::Sparse {
                pattern: &pattern,
                values: &jac,
            },
            q: &q,
            lower: l,
            upper: u,
            diagonal_shift: 0.0,
        };
        let outcome = if jac.iter().chain(&q).all(|v| v.is_finite()) {
            self.solve_affine(
                &problem,
                &AffineStart::Classical {
                    free_values: Some(&zs),
                },
            )
        } else {
            Err(PivotError::InvalidInput(
                "F or J is not finite at the start".into(),
            ))
        };
        let (z, pivots, refactorizations, termination) = match outcome {
            Ok(sol) => (sol.z, sol.pivots, sol.refactorizations, None),
            Err(e) => {
                let t = match e {
                    PivotError::RayTermination { .. } => Termination::RayTermination,
                    PivotError::MaxPivots { .. } => Termination::MaxIterations,
                    PivotError::InvalidInput(_) => Termination::NonFiniteFunction,
                    PivotError::SingularBasis { .. } => Termination::SubproblemFailed,
                };
                let p = match e {
                    PivotError::RayTermination { pivots, .. }
                    | PivotError::MaxPivots { pivots }
                    | PivotError::SingularBasis { pivots, .. } => pivots,
                    PivotError::InvalidInput(_) => 0,
                };
                (zs.clone(), p, self.refactorizations, Some(t))
            }
        };
        // A solved affine model of a non-affine F (or a solve that lost accuracy) is reported as
        // stagnated by `finish_solve`, which judges the point by the model's natural residual.
        finish_solve(
            mcp,
            z,
            SolveReport {
                solver: "lemke",
                termination: termination.unwrap_or(Termination::Converged),
                tolerance: self.settings.tolerance,
                iterations: 1,
                f_evals: 1,
                jac_evals: 1,
                started: start,
                trace: Vec::new(),
                counters: Counters::from([
                    (Counter::Pivots, pivots),
                    (Counter::Refactorizations, refactorizations),
                ]),
            },
        )
    }
}

#[cfg(test)]
mod tests;
