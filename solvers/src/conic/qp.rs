//! A small conic QP in clarabel's form, assembled from triplets:
//! `min ½ xᵀPx + qᵀx  s.t.  A x + s = b,  s ∈ K` with K a product of zero, non-negative and
//! second-order cones, and the call into clarabel that never panics.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};

/// One cone of the product K, in row order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Cone {
    /// Equality rows (`s = 0`).
    Zero(usize),
    /// Non-negative rows (`s ≥ 0`).
    Nonnegative(usize),
    /// A second-order cone `s_0 ≥ ‖s_{1..}‖` of the given dimension.
    SecondOrder(usize),
}

/// Problem data of a conic QP, built row by row.
#[derive(Clone, Debug, Default)]
pub(crate) struct ConicQp {
    /// Number of variables.
    pub n: usize,
    /// Upper-triangular entries of P: (row, col, value), row ≤ col.
    pub p: Vec<(usize, usize, f64)>,
    /// Linear cost.
    pub q: Vec<f64>,
    /// Entries of A: (row, col, value).
    pub a: Vec<(usize, usize, f64)>,
    /// Right-hand side, one entry per row.
    pub b: Vec<f64>,
    /// Cones in row order.
    pub cones: Vec<Cone>,
}

/// What clarabel returned.
#[derive(Clone, Debug, Default)]
pub(crate) struct QpResult {
    /// Primal solution.
    pub x: Vec<f64>,
    /// Dual solution (in the dual cone), one entry per row.
    pub z: Vec<f64>,
    /// Slacks (in the cone), one entry per row.
    pub s: Vec<f64>,
    /// Clarabel's status.
    pub status: SolverStatus,
    /// Interior-point iterations.
    pub iterations: u32,
}

impl ConicQp {
    /// An empty problem in `n` variables.
    pub fn new(n: usize) -> Self {
        ConicQp {
            n,
            q: vec![0.0; n],
            ..Default::default()
        }
    }

    /// Empties the problem and makes it one in `n` variables, keeping the storage: the same
    /// problem as [`ConicQp::new`] without its allocations (the backend rebuilds one per outer
    /// iteration).
    pub fn reset(&mut self, n: usize) {
        self.n = n;
        self.p.clear();
        self.q.clear();
        self.q.resize(n, 0.0);
        self.a.clear();
        self.b.clear();
        self.cones.clear();
    }

    /// Number of rows so far.
    pub fn rows(&self) -> usize {
        self.b.len()
    }

    /// Adds `P[i][j] += v` (symmetric; stored in the upper triangle).
    pub fn add_p(&mut self, i: usize, j: usize, v: f64) {
        if v != 0.0 {
            self.p.push((i.min(j), i.max(j), v));
        }
    }

    /// Appends a row `Σ coeffs · x + s = rhs`; returns its index. The caller adds the cone.
    pub fn push_row(&mut self, coeffs: &[(usize, f64)], rhs: f64) -> usize {
        let r = self.b.len();
        for &(j, v) in coeffs {
            if v != 0.0 {
                self.a.push((r, j, v));
            }
        }
        self.b.push(rhs);
        r
    }

    /// Whether every number in the data is finite (clarabel must not see NaN).
    fn is_finite(&self) -> bool {
        self.p.iter().all(|e| e.2.is_finite())
            && self.a.iter().all(|e| e.2.is_finite())
            && self.q.iter().all(|v| v.is_finite())
            && self.b.iter().all(|v| v.is_finite())
    }

    /// Solves with clarabel. `Err` carries a description when the data are not finite, the
    /// cones do not cover the rows, or clarabel rejects the problem or panics.
    pub fn solve(&self, settings: &DefaultSettings<f64>) -> Result<QpResult, String> {
        if !self.is_finite() {
            return Err("the conic subproblem has non-finite data".into());
        }
        let m = self.rows();
        let covered: usize = self
            .cones
            .iter()
            .map(|c| match c {
                Cone::Zero(k) | Cone::Nonnegative(k) | Cone::SecondOrder(k) => *k,
            })
            .sum();
        if covered != m {
            return Err(format!("cones cover {covered} rows of {m}"));
        }
        let (pi, pj, pv) = split(&self.p);
        let p = CscMatrix::new_from_triplets(self.n, self.n, pi, pj, pv);
        let (ai, aj, av) = split(&self.a);
        let a = CscMatrix::new_from_triplets(m, self.n, ai, aj, av);
        let cones: Vec<SupportedConeT<f64>> = self
            .cones
            .iter()
            .map(|c| match *c {
                Cone::Zero(k) => SupportedConeT::ZeroConeT(k),
                Cone::Nonnegative(k) => SupportedConeT::NonnegativeConeT(k),
                Cone::SecondOrder(k) => SupportedConeT::SecondOrderConeT(k),
            })
            .collect();
        let settings = settings.clone();
        let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let mut solver = DefaultSolver::new(&p, &self.q, &a, &self.b, &cones, settings)
                .map_err(|e| format!("clarabel rejected the subproblem: {e}"))?;
            solver.solve();
            let sol = &solver.solution;
            Ok::<QpResult, String>(QpResult {
                x: sol.x.clone(),
                z: sol.z.clone(),
                s: sol.s.clone(),
                status: sol.status,
                iterations: sol.iterations,
            })
        }));
        match run {
            Ok(r) => r,
            Err(_) => Err("clarabel panicked on the subproblem".into()),
        }
    }
}

fn split(t: &[(usize, usize, f64)]) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
    (
        t.iter().map(|e| e.0).collect(),
        t.iter().map(|e| e.1).collect(),
        t.iter().map(|e| e.2).collect(),
    )
}

/// Whether clarabel's status carries a usable solution (full or reduced accuracy).
pub(crate) fn usable(status: SolverStatus) -> bool {
    matches!(status, SolverStatus::Solved | SolverStatus::AlmostSolved)
}

/// A stable numeric code of clarabel's status, for the summary's counters
/// (`"clarabel_status"`): the discriminant of [`SolverStatus`].
pub fn status_code(status: SolverStatus) -> usize {
    status as usize
}
