//! A library of standard MCP test problems with known solutions and analytic Jacobians.
//!
//! Every backend of ecp is judged on the same problems: small nonlinear complementarity
//! problems from MCPLIB (Dirkse & Ferris, "MCPLIB: a collection of nonlinear mixed
//! complementarity problems", Optim. Methods & Software 5, 1995; used in Billups, Dirkse &
//! Ferris, "A comparison of large scale mixed complementarity problem solvers", Comput. Optim.
//! Appl. 7, 1997), classic LCPs (Murty's), random P-matrix LCPs (dense and sparse), problems
//! designed here to exercise one difficulty each (box constraints with both bounds active,
//! non-strictly-complementary solutions), and the one-contact friction NCP of
//! `docs/model.md#friction` in its three regimes (sticking, sliding, separated).
//!
//! Each [`TestProblem`] carries its standard starting points and, where they are known in
//! closed form, its solutions; every listed solution has a natural residual below `1e-12`
//! (unit tests) and every analytic Jacobian agrees with central differences.
//!
//! ```
//! use ecp_model::mcp_library::{kojima_shindo, suite};
//! use ecp_model::residual_of;
//!
//! let p = kojima_shindo();
//! for z in &p.solutions {
//!     assert!(residual_of(&p.mcp, z) <= 1e-12);
//! }
//! assert!(suite().len() >= 10);
//! ```

#![allow(clippy::needless_range_loop)] // dense numerical kernels read best with explicit indices

use std::fmt;
use std::sync::Arc;

use crate::error::ModelError;
use crate::mcp::{FnMcp, Mcp};
use crate::pattern::CscPattern;

const INF: f64 = f64::INFINITY;

/// One test problem: the MCP, the literature's starting points and the known solutions.
///
/// Problems are built fresh by each constructor (an [`FnMcp`] owns closures and cannot be
/// cloned), so tests and benchmarks may take them by value.
pub struct TestProblem {
    /// Short identifier, e.g. `"kojima_josephy"`; unique within [`suite`].
    pub name: String,
    /// The problem, with an analytic Jacobian.
    pub mcp: FnMcp,
    /// Standard starting points, labelled (the label says where the point comes from).
    pub starts: Vec<(String, Vec<f64>)>,
    /// Known solutions (several when the problem has several, empty when none is known in
    /// closed form or the solution set is not a finite set of points; `note` says which).
    pub solutions: Vec<Vec<f64>>,
    /// Source, and what is special about the problem (degenerate, boxed, non-unique, ...).
    pub note: &'static str,
}

impl TestProblem {
    /// Number of unknowns.
    pub fn dim(&self) -> usize {
        self.mcp.dim()
    }

    /// Distance (∞-norm) from `z` to the nearest listed solution, comparing only the
    /// components in `components` (all when `None`); `None` when no solution is listed.
    pub fn distance_to_solutions(&self, z: &[f64], components: Option<&[usize]>) -> Option<f64> {
        self.solutions
            .iter()
            .map(|s| {
                let diff = |i: usize| match (s.get(i), z.get(i)) {
                    (Some(a), Some(b)) => (a - b).abs(),
                    _ => INF,
                };
                match components {
                    Some(c) => c.iter().map(|&i| diff(i)).fold(0.0, f64::max),
                    None => (0..s.len().max(z.len())).map(diff).fold(0.0, f64::max),
                }
            })
            .reduce(f64::min)
    }
}

impl fmt::Debug for TestProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TestProblem")
            .field("name", &self.name)
            .field("n", &self.dim())
            .field(
                "starts",
                &self
                    .starts
                    .iter()
                    .map(|(l, _)| l.as_str())
                    .collect::<Vec<_>>(),
            )
            .field("solutions", &self.solutions)
            .field("note", &self.note)
            .finish()
    }
}

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

/// splitmix64 (Steele, Lea & Flood 2014): a tiny, deterministic generator, so that random
/// problems are reproducible from a seed without a dependency.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `[0, 1)` with 53 random bits.
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    /// Uniform in `[a, b)`.
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.unit()
    }
    /// Uniform index in `0..n` (`n > 0`).
    fn index(&mut self, n: usize) -> usize {
        ((self.next_u64() >> 11) % n as u64) as usize
    }
}

/// Builds a dense [`FnMcp`] from bounds that are valid by construction.
fn dense(
    lower: Vec<f64>,
    upper: Vec<f64>,
    f: impl Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
    jac: impl Fn(&[f64], &mut [f64]) + Send + Sync + 'static,
) -> FnMcp {
    match FnMcp::dense(lower, upper, f, jac) {
        Ok(m) => m,
        Err(e) => unreachable!("built-in problem has valid bounds: {e}"),
    }
}

fn names(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

fn labelled(list: &[(&str, &[f64])]) -> Vec<(String, Vec<f64>)> {
    list.iter()
        .map(|(l, z)| (l.to_string(), z.to_vec()))
        .collect()
}

// ---------------------------------------------------------------------------------------------
// MCPLIB: Kojima–Josephy and Kojima–Shindo
// ---------------------------------------------------------------------------------------------

/// The two 4-variable NCPs from Kojima's example differ only in three coefficients:
/// `F2 = 2x1² + x1 + x2² + b23·x3 + 2x4 − 2`, `F3 = 3x1² + x1x2 + 2x2² + 2x3 + b34·x4 + c3`.
fn kojima_family(b23: f64, b34: f64, c3: f64) -> FnMcp {
    dense(
        vec![0.0; 4],
        vec![INF; 4],
        move |x, f| {
            let (x1, x2, x3, x4) = (x[0], x[1], x[2], x[3]);
            f[0] = 3.0 * x1 * x1 + 2.0 * x1 * x2 + 2.0 * x2 * x2 + x3 + 3.0 * x4 - 6.0;
            f[1] = 2.0 * x1 * x1 + x1 + x2 * x2 + b23 * x3 + 2.0 * x4 - 2.0;
            f[2] = 3.0 * x1 * x1 + x1 * x2 + 2.0 * x2 * x2 + 2.0 * x3 + b34 * x4 + c3;
            f[3] = x1 * x1 + 3.0 * x2 * x2 + 2.0 * x3 + 3.0 * x4 - 3.0;
        },
        move |x, j| {
            let (x1, x2) = (x[0], x[1]);
            // Rows of J, stored column-major: entry (i, k) at k*4 + i.
            let rows = [
                [6.0 * x1 + 2.0 * x2, 2.0 * x1 + 4.0 * x2, 1.0, 3.0],
                [4.0 * x1 + 1.0, 2.0 * x2, b23, 2.0],
                [6.0 * x1 + x2, x1 + 4.0 * x2, 2.0, b34],
                [2.0 * x1, 6.0 * x2, 2.0, 3.0],
            ];
            for (i, row) in rows.iter().enumerate() {
                for (k, v) in row.iter().enumerate() {
                    j[k * 4 + i] = *v;
                }
            }
        },
    )
}

/// The eight starting points of the AMPL version of MCPLIB's `josephy.mod` and `kojshin.mod`
/// (the `xinit` table, columns 1–8).
fn kojima_starts() -> Vec<(String, Vec<f64>)> {
    labelled(&[
        ("mcplib1", &[0.0, 0.0, 0.0, 0.0]),
        ("mcplib2", &[1.0, 1.0, 1.0, 1.0]),
        ("mcplib3", &[100.0, 100.0, 100.0, 100.0]),
        ("mcplib4", &[1.0, 0.0, 1.0, 0.0]),
        ("mcplib5", &[1.0, 0.0, 0.0, 0.0]),
        ("mcplib6", &[0.0, 1.0, 1.0, 0.0]),
        ("mcplib7", &[0.0, 1.0, 0.0, 1.0]),
        ("mcplib8", &[1.25, 0.0, 0.0, 0.5]),
    ])
}

/// MCPLIB `josephy`: Kojima's NCP as given by Josephy (1979), n = 4.
///
/// `F1 = 3x1² + 2x1x2 + 2x2² + x3 + 3x4 − 6`, `F2 = 2x1² + x1 + x2² + 3x3 + 2x4 − 2`,
/// `F3 = 3x1² + x1x2 + 2x2² + 2x3 + 3x4 − 1`, `F4 = x1² + 3x2² + 2x3 + 3x4 − 3`, `0 ≤ x ⊥ F ≥ 0`.
/// Unique, strictly complementary solution `(√6/2, 0, 0, 1/2)` (checked here by enumerating all
/// 16 active sets). Note: `(1, 0, 3, 0)` is *not* a solution of this problem (`F3 = 8` there);
/// it is the second solution of [`kojima_shindo`].
pub fn kojima_josephy() -> TestProblem {
    TestProblem {
        name: "kojima_josephy".into(),
        mcp: kojima_family(3.0, 3.0, -1.0).with_names(names(&["x1", "x2", "x3", "x4"])),
        starts: kojima_starts(),
        solutions: vec![vec![6f64.sqrt() / 2.0, 0.0, 0.0, 0.5]],
        note: "MCPLIB josephy (Dirkse & Ferris 1995; AMPL josephy.mod data A, B, c): Kojima's \
               example via Josephy (1979). NCP, n = 4, unique strictly complementary solution \
               (sqrt(6)/2, 0, 0, 1/2). Starts: the 8 xinit columns of the AMPL MCPLIB file.",
    }
}

/// MCPLIB `kojshin`: Kojima & Shindo (J. Oper. Res. Soc. Japan 29, 1986), n = 4.
///
/// As [`kojima_josephy`] but `F2 = … + 10x3 + …` and `F3 = 3x1² + x1x2 + 2x2² + 2x3 + 9x4 − 9`.
/// Two solutions: the degenerate `(√6/2, 0, 0, 1/2)` (`x3 = 0` and `F3 = 0`) and the
/// nondegenerate `(1, 0, 3, 0)`; no others (checked by enumerating the active sets).
pub fn kojima_shindo() -> TestProblem {
    TestProblem {
        name: "kojima_shindo".into(),
        mcp: kojima_family(10.0, 9.0, -9.0).with_names(names(&["x1", "x2", "x3", "x4"])),
        starts: kojima_starts(),
        solutions: vec![
            vec![6f64.sqrt() / 2.0, 0.0, 0.0, 0.5],
            vec![1.0, 0.0, 3.0, 0.0],
        ],
        note: "MCPLIB kojshin (Dirkse & Ferris 1995; Kojima & Shindo 1986). NCP, n = 4, two \
               solutions: (sqrt(6)/2, 0, 0, 1/2) is degenerate (x3 = 0 and F3 = 0), (1, 0, 3, 0) \
               is strictly complementary. Starts: the 8 xinit columns of the AMPL MCPLIB file.",
    }
}

// ---------------------------------------------------------------------------------------------
// Mathiesen's Walrasian equilibrium
// ---------------------------------------------------------------------------------------------

/// Mathiesen's Walrasian equilibrium (Math. Prog. 37, 1987), price normalisation
/// `p1 + p2 + p3 = 1` (the "sum" form, as in MCPLIB `mathisum`).
///
/// Three goods, one activity `y` producing good 1 from goods 2 and 3 (technology
/// `a = (1, −1, −1)`), one Cobb–Douglas consumer with budget shares `s = (0.9, 0.1, 0)` and
/// endowment `b = (0, 5, 3)`, demand `x_i = s_i (p·b) / p_i`. Unknowns `z = (y, p1, p2, p3) ≥ 0`:
///
/// - `F_y  = p2 + p3 − p1` (unit cost minus revenue ≥ 0 ⊥ y ≥ 0),
/// - `F_p1 = p1 + p2 + p3 − 1` (the normalisation replaces the market of good 1, which is
///   implied by Walras' law),
/// - `F_p2 = 5 − y − 0.1 (5 p2 + 3 p3) / p2` (excess supply of good 2),
/// - `F_p3 = 3 − y` (good 3 is not consumed).
///
/// Unique solution `y = 3`, `p = (6, 1, 5)/12`.
///
/// Demand is defined for positive prices only, so `F_p2` (and its Jacobian row) is NaN for
/// `p2 ≤ 0`, as a modelling system reports a domain error: a solver must backtrack into
/// `p2 > 0`. Without this, `F_p2 = 4.5 − y − 0.3 p3/p2 → +∞` as `p2 → 0⁻`, and the natural
/// residual tends to 0 at the non-solution `(3, 1/2, 0, 1/2)` (a pole, not an equilibrium).
pub fn mathiesen() -> TestProblem {
    let mcp = dense(
        vec![0.0; 4],
        vec![INF; 4],
        |z, f| {
            let (y, p1, p2, p3) = (z[0], z[1], z[2], z[3]);
            f[0] = p2 + p3 - p1;
            f[1] = p1 + p2 + p3 - 1.0;
            f[2] = excess_supply_good2(y, p2, p3);
            f[3] = 3.0 - y;
        },
        |z, j| {
            let (p2, p3) = (z[2], z[3]);
            let n = 4;
            // F_y
            j[n] = -1.0;
            j[2 * n] = 1.0;
            j[3 * n] = 1.0;
            // F_p1
            j[n + 1] = 1.0;
            j[2 * n + 1] = 1.0;
            j[3 * n + 1] = 1.0;
            // F_p2 = 4.5 − y − 0.3 p3 / p2
            let [dy, dp2, dp3] = excess_supply_good2_gradient(p2, p3);
            j[2] = dy;
            j[2 * n + 2] = dp2;
            j[3 * n + 2] = dp3;
            // F_p3
            j[3] = -1.0;
        },
    )
    .with_names(names(&["y", "p1", "p2", "p3"]));
    TestProblem {
        name: "mathiesen_sum".into(),
        mcp,
        starts: labelled(&[
            ("uniform_prices", &[1.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0]),
            ("ones", &[1.0, 1.0, 1.0, 1.0]),
            ("no_activity", &[0.0, 0.5, 0.25, 0.25]),
        ]),
        solutions: vec![vec![3.0, 0.5, 1.0 / 12.0, 5.0 / 12.0]],
        note: "Mathiesen (Math. Prog. 37, 1987) Walrasian model, data as in GAMS EMP model \
               mopec_mathiesen (a = (1,-1,-1), shares (0.9,0.1,0), endowment (0,5,3)); prices \
               normalised to sum 1 in place of the market of good 1, like MCPLIB mathisum (the \
               MCPLIB file itself could not be consulted; this is a reconstruction). NCP, n = 4, \
               unique solution y = 3, p = (6,1,5)/12. F_p2 has a pole at p2 = 0 and is NaN (domain \
               error) for p2 <= 0, otherwise the natural residual would vanish at the pole \
               (3, 1/2, 0, 1/2). Starts are ours.",
    }
}

/// Excess supply of good 2 in Mathiesen's model, `5 − y − 0.1 (5 p2 + 3 p3)/p2`; NaN (a domain
/// error) unless `p2 > 0`.
fn excess_supply_good2(y: f64, p2: f64, p3: f64) -> f64 {
    if p2 > 0.0 {
        5.0 - y - 0.1 * (5.0 * p2 + 3.0 * p3) / p2
    } else {
        f64::NAN
    }
}

/// Gradient of [`excess_supply_good2`] with respect to `(y, p2, p3)` (NaN unless `p2 > 0`).
fn excess_supply_good2_gradient(p2: f64, p3: f64) -> [f64; 3] {
    if p2 > 0.0 {
        [-1.0, 0.3 * p3 / (p2 * p2), -0.3 / p2]
    } else {
        [f64::NAN; 3]
    }
}

/// Mathiesen's model with good 1 as numeraire (`p1 = 1`, as in MCPLIB `mathinum`):
/// `z = (y, p2, p3) ≥ 0`, `F = (p2 + p3 − 1, 5 − y − 0.1(5p2 + 3p3)/p2, 3 − y)`.
/// Unique solution `(3, 1/6, 5/6)`; `F_p2` is NaN for `p2 ≤ 0` (domain error, see
/// [`mathiesen`], which also describes the model).
pub fn mathiesen_numeraire() -> TestProblem {
    let mcp = dense(
        vec![0.0; 3],
        vec![INF; 3],
        |z, f| {
            let (y, p2, p3) = (z[0], z[1], z[2]);
            f[0] = p2 + p3 - 1.0;
            f[1] = excess_supply_good2(y, p2, p3);
            f[2] = 3.0 - y;
        },
        |z, j| {
            let (p2, p3) = (z[1], z[2]);
            let n = 3;
            j[n] = 1.0;
            j[2 * n] = 1.0;
            let [dy, dp2, dp3] = excess_supply_good2_gradient(p2, p3);
            j[1] = dy;
            j[n + 1] = dp2;
            j[2 * n + 1] = dp3;
            j[2] = -1.0;
        },
    )
    .with_names(names(&["y", "p2", "p3"]));
    TestProblem {
        name: "mathiesen_numeraire".into(),
        mcp,
        starts: labelled(&[
            ("ones", &[1.0, 1.0, 1.0]),
            ("no_activity", &[0.0, 0.5, 0.5]),
            ("far", &[5.0, 0.1, 2.0]),
        ]),
        solutions: vec![vec![3.0, 1.0 / 6.0, 5.0 / 6.0]],
        note: "Mathiesen (Math. Prog. 37, 1987) Walrasian model with good 1 as numeraire \
               (p1 = 1, market of good 1 dropped by Walras' law), like MCPLIB mathinum \
               (reconstruction; the MCPLIB file could not be consulted). NCP, n = 3, unique \
               solution (y, p2, p3) = (3, 1/6, 5/6). F_p2 is NaN (domain error) for p2 <= 0. \
               Starts are ours.",
    }
}

/// The "Mathiesen problem" of the NCP literature (Pang & Gabriel, Math. Prog. 60, 1993; also
/// used by Kanzow and others): Mathiesen's model with shifted price denominators,
///
/// `F1 = −x2 + x3 + x4`, `F2 = x1 − (4.5x3 + 2.7x4)/(x2 + 1)`,
/// `F3 = 5 − x1 − (0.5x3 + 0.3x4)/(x3 + 1)`, `F4 = 3 − x1`, `0 ≤ x ⊥ F ≥ 0`.
///
/// Its solution set is the segment `{(λ, 0, 0, 0) : 0 ≤ λ ≤ 3}` (checked here by enumerating
/// the active sets), so `solutions` is empty: a solver's answer must be judged by its residual
/// and by lying on the segment. Both end points are degenerate.
pub fn mathiesen_pang_gabriel() -> TestProblem {
    let mcp = dense(
        vec![0.0; 4],
        vec![INF; 4],
        |x, f| {
            let (x1, x2, x3, x4) = (x[0], x[1], x[2], x[3]);
            f[0] = -x2 + x3 + x4;
            f[1] = x1 - (4.5 * x3 + 2.7 * x4) / (x2 + 1.0);
            f[2] = 5.0 - x1 - (0.5 * x3 + 0.3 * x4) / (x3 + 1.0);
            f[3] = 3.0 - x1;
        },
        |x, j| {
            let (x2, x3, x4) = (x[1], x[2], x[3]);
            let n = 4;
            let d2 = x2 + 1.0;
            let d3 = x3 + 1.0;
            // F1
            j[n] = -1.0;
            j[2 * n] = 1.0;
            j[3 * n] = 1.0;
            // F2
            j[1] = 1.0;
            j[n + 1] = (4.5 * x3 + 2.7 * x4) / (d2 * d2);
            j[2 * n + 1] = -4.5 / d2;
            j[3 * n + 1] = -2.7 / d2;
            // F3
            j[2] = -1.0;
            j[2 * n + 2] = -(0.5 - 0.3 * x4) / (d3 * d3);
            j[3 * n + 2] = -0.3 / d3;
            // F4
            j[3] = -1.0;
        },
    );
    TestProblem {
        name: "mathiesen_pang_gabriel".into(),
        mcp,
        starts: labelled(&[
            ("ones", &[1.0, 1.0, 1.0, 1.0]),
            ("beyond_segment", &[4.0, 1.0, 1.0, 1.0]),
            ("high_prices", &[0.5, 2.0, 2.0, 2.0]),
        ]),
        solutions: vec![],
        note: "The Mathiesen NCP as stated by Pang & Gabriel (Math. Prog. 60, 1993) and used in \
               later NCP papers (formula reconstructed from the literature, not from an MCPLIB \
               file). n = 4. Solution set: the segment (lambda, 0, 0, 0), 0 <= lambda <= 3 (not \
               isolated; end points degenerate), hence no listed solutions. Starts are ours.",
    }
}

// ---------------------------------------------------------------------------------------------
// LCPs
// ---------------------------------------------------------------------------------------------

/// A dense LCP `0 ≤ z ⊥ M z + q ≥ 0`, with `m` the row-major `n × n` matrix `M`.
///
/// The generic builder the other LCPs use; starting points `0` and `1`, no listed solution.
/// Fails when `m` is not `n × n` for `n = q.len()` or when an entry is not finite.
pub fn lcp(m: Vec<f64>, q: Vec<f64>) -> Result<TestProblem, ModelError> {
    let n = q.len();
    if m.len() != n * n {
        return Err(ModelError::Dimension(format!(
            "LCP: M has {} entries, q has {n}, so M should have {}",
            m.len(),
            n * n
        )));
    }
    if let Some(i) = m.iter().position(|v| !v.is_finite()) {
        return Err(ModelError::InvalidBlock {
            block: "lcp".into(),
            reason: format!("M[{}][{}] = {} is not finite", i / n, i % n, m[i]),
        });
    }
    if let Some(i) = q.iter().position(|v| !v.is_finite()) {
        return Err(ModelError::InvalidBlock {
            block: "lcp".into(),
            reason: format!("q[{i}] = {} is not finite", q[i]),
        });
    }
    // Column-major copy for the Jacobian.
    let mut m_col = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            m_col[j * n + i] = m[i * n + j];
        }
    }
    let mcp = FnMcp::dense(
        vec![0.0; n],
        vec![INF; n],
        move |z, f| {
            for (i, (fi, qi)) in f.iter_mut().zip(&q).enumerate() {
                let row = &m[i * n..(i + 1) * n];
                *fi = qi + row.iter().zip(z).map(|(a, b)| a * b).sum::<f64>();
            }
        },
        move |_z, j| j.copy_from_slice(&m_col),
    )?;
    Ok(TestProblem {
        name: "lcp".into(),
        mcp,
        starts: vec![("zero".into(), vec![0.0; n]), ("ones".into(), vec![1.0; n])],
        solutions: vec![],
        note: "Dense LCP 0 <= z _|_ Mz + q >= 0 built by mcp_library::lcp.",
    })
}

/// Murty's LCP (Murty, "Computational complexity of complementary pivot methods", Math. Prog.
/// Study 7, 1978): `M` upper triangular with 1 on the diagonal and 2 above, `q = −1`.
///
/// `M` is a P-matrix, so the solution is unique: `z = e_n` (`w = Mz + q = (1, …, 1, 0)`).
/// The matrix of Murty's exponential examples for complementary pivoting; as an NCP test with
/// `q = −1` it is the "Murty problem" used as a test in the NCP literature.
pub fn murty(n: usize) -> TestProblem {
    let mut m = vec![0.0; n * n];
    for i in 0..n {
        m[i * n + i] = 1.0;
        for j in i + 1..n {
            m[i * n + j] = 2.0;
        }
    }
    let mut p = match lcp(m, vec![-1.0; n]) {
        Ok(p) => p,
        Err(e) => unreachable!("Murty's data is valid: {e}"),
    };
    let mut e_n = vec![0.0; n];
    if let Some(last) = e_n.last_mut() {
        *last = 1.0;
    }
    p.name = format!("murty_{n}");
    p.solutions = vec![e_n];
    p.note = "Murty (1978) LCP: M upper triangular, 1 on the diagonal, 2 above, q = -1. \
              P-matrix, unique solution e_n; the matrix of Murty's exponential examples for \
              complementary pivoting. Starts 0 and 1.";
    p
}

/// A random LCP `0 ≤ z ⊥ M z + q ≥ 0` with `M` a P-matrix, deterministic from `seed`.
///
/// Dense: `M = BᵀB + I + (C − Cᵀ)` with `B, C` uniform in `[−1, 1]/√n` (positive definite,
/// hence P). Sparse: three random off-diagonal entries per row uniform in `[−1, 1]`, diagonal
/// `Σ|off-diagonal| + U[0.5, 1.5]` (strictly row-diagonally dominant with positive diagonal,
/// hence P), Jacobian in a [`CscPattern`] so that `n = 1000` stays sparse. `q` uniform in
/// `[−2, 2]`. The solution is unique (P-matrix) but not known in closed form, so `solutions`
/// is empty. Starts: `0` and a random point in `[0, 2]ⁿ`.
pub fn random_p_matrix_lcp(n: usize, seed: u64, sparse: bool) -> TestProblem {
    let mut rng = SplitMix64(seed ^ 0x5EED_5EED_5EED_5EED);
    let mut p = if sparse {
        sparse_p_lcp(n, &mut rng)
    } else {
        let s = 1.0 / (n.max(1) as f64).sqrt();
        let b: Vec<f64> = (0..n * n).map(|_| s * rng.range(-1.0, 1.0)).collect();
        let c: Vec<f64> = (0..n * n).map(|_| s * rng.range(-1.0, 1.0)).collect();
        let mut m = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                let btb: f64 = (0..n).map(|k| b[k * n + i] * b[k * n + j]).sum();
                let eye = if i == j { 1.0 } else { 0.0 };
                m[i * n + j] = btb + eye + c[i * n + j] - c[j * n + i];
            }
        }
        let q: Vec<f64> = (0..n).map(|_| rng.range(-2.0, 2.0)).collect();
        match lcp(m, q) {
            Ok(p) => p,
            Err(e) => unreachable!("random data is finite: {e}"),
        }
    };
    let random_start: Vec<f64> = (0..n).map(|_| rng.range(0.0, 2.0)).collect();
    p.name = format!(
        "random_p_lcp_{}_n{n}_s{seed}",
        if sparse { "sparse" } else { "dense" }
    );
    p.starts = vec![
        ("zero".into(), vec![0.0; n]),
        ("random".into(), random_start),
    ];
    p.solutions = vec![];
    p.note = if sparse {
        "Random sparse P-matrix LCP (strictly diagonally dominant, positive diagonal, 3 \
         off-diagonals per row), deterministic from the seed (splitmix64). Unique solution, \
         not known in closed form."
    } else {
        "Random dense P-matrix LCP, M = B'B + I + (C - C') (positive definite), deterministic \
         from the seed (splitmix64). Unique solution, not known in closed form."
    };
    p
}

fn sparse_p_lcp(n: usize, rng: &mut SplitMix64) -> TestProblem {
    // Rows: (column, value) off-diagonal entries.
    let mut entries: Vec<(usize, usize, f64)> = Vec::with_capacity(4 * n);
    for i in 0..n {
        let mut cols: Vec<usize> = Vec::new();
        if n > 1 {
            for _ in 0..3 {
                let j = rng.index(n - 1);
                let j = if j >= i { j + 1 } else { j };
                if !cols.contains(&j) {
                    cols.push(j);
                }
            }
        }
        let mut row_sum = 0.0;
        for &j in &cols {
            let v = rng.range(-1.0, 1.0);
            row_sum += f64::abs(v);
            entries.push((i, j, v));
        }
        entries.push((i, i, row_sum + rng.range(0.5, 1.5)));
    }
    let q: Vec<f64> = (0..n).map(|_| rng.range(-2.0, 2.0)).collect();
    let pairs: Vec<(usize, usize)> = entries.iter().map(|&(i, j, _)| (i, j)).collect();
    let pattern = match CscPattern::from_triplets(n, &pairs) {
        Ok(p) => Arc::new(p),
        Err(e) => unreachable!("indices are in range: {e}"),
    };
    let mut values = vec![0.0; pattern.nnz()];
    for &(i, j, v) in &entries {
        if let Some(pos) = pattern.position(i, j) {
            values[pos] += v;
        }
    }
    let values = Arc::new(values);
    let (pf, vf) = (pattern.clone(), values.clone());
    let mcp = FnMcp::sparse(
        vec![0.0; n],
        vec![INF; n],
        pattern,
        move |z, f| {
            f.copy_from_slice(&q);
            let (cp, ri) = (pf.col_ptr(), pf.row_idx());
            for j in 0..z.len() {
                for p in cp[j]..cp[j + 1] {
                    f[ri[p]] += vf[p] * z[j];
                }
            }
        },
        move |_z, jac| jac.copy_from_slice(&values),
    );
    let mcp = match mcp {
        Ok(m) => m,
        Err(e) => unreachable!("sizes agree: {e}"),
    };
    TestProblem {
        name: String::new(),
        mcp,
        starts: vec![],
        solutions: vec![],
        note: "",
    }
}

// ---------------------------------------------------------------------------------------------
// Designed problems: both bounds active, degenerate solution
// ---------------------------------------------------------------------------------------------

/// `F(z) = f* + M (z − z*) + ½ (z − z*)³` (componentwise cube): strongly monotone when the
/// symmetric part of `M` is positive definite, so `z*` is the unique solution whenever
/// `(z*, f*)` satisfies the complementarity conditions.
fn manufactured(
    lower: Vec<f64>,
    upper: Vec<f64>,
    z_star: Vec<f64>,
    f_star: Vec<f64>,
    m: Vec<f64>, // row-major
) -> FnMcp {
    let n = z_star.len();
    let (zs, ms) = (z_star.clone(), m.clone());
    dense(
        lower,
        upper,
        move |z, f| {
            for i in 0..n {
                let di = z[i] - z_star[i];
                let mut s = f_star[i] + 0.5 * di * di * di;
                for j in 0..n {
                    s += m[i * n + j] * (z[j] - z_star[j]);
                }
                f[i] = s;
            }
        },
        move |z, jac| {
            for i in 0..n {
                for j in 0..n {
                    jac[j * n + i] = ms[i * n + j];
                }
                let di = z[i] - zs[i];
                jac[i * n + i] += 1.5 * di * di;
            }
        },
    )
}

/// A box-constrained MCP whose solution has components at the lower bound, at the upper bound,
/// strictly inside a box, at a one-sided upper bound, at a one-sided lower bound and free.
///
/// `n = 6`, `l = (0, −1, −2, −∞, 1, −∞)`, `u = (1, 1, 2, 3, ∞, ∞)`,
/// `F(z) = F* + M(z − z*) + ½(z − z*)³` with `M = 3I + (tridiagonal skew ±1) + 0.5(e₀e₅ᵀ + e₅e₀ᵀ)`
/// (symmetric part positive definite ⇒ `F` strongly monotone ⇒ unique solution),
/// `z* = (0, 1, 0.5, 3, 1, −0.25)`, `F(z*) = (2, −1.5, 0, −0.5, 1, 0)`: strictly complementary.
pub fn box_both_bounds() -> TestProblem {
    let n = 6;
    let lower = vec![0.0, -1.0, -2.0, -INF, 1.0, -INF];
    let upper = vec![1.0, 1.0, 2.0, 3.0, INF, INF];
    let z_star = vec![0.0, 1.0, 0.5, 3.0, 1.0, -0.25];
    let f_star = vec![2.0, -1.5, 0.0, -0.5, 1.0, 0.0];
    let mut m = vec![0.0; n * n];
    for i in 0..n {
        m[i * n + i] = 3.0;
        if i + 1 < n {
            m[i * n + i + 1] = 1.0;
            m[(i + 1) * n + i] = -1.0;
        }
    }
    m[5] += 0.5;
    m[5 * n] += 0.5;
    let mcp = manufactured(lower, upper, z_star.clone(), f_star, m)
        .with_names(names(&["lo", "up", "mid", "up_only", "lo_only", "free"]));
    TestProblem {
        name: "box_both_bounds".into(),
        mcp,
        starts: labelled(&[
            ("midpoint", &[0.5, 0.0, 0.0, 0.0, 2.0, 0.0]),
            ("lower", &[0.0, -1.0, -2.0, 0.0, 1.0, 0.0]),
            ("upper", &[1.0, 1.0, 2.0, 3.0, 5.0, 0.0]),
            ("outside", &[5.0, -5.0, 5.0, 10.0, -3.0, 7.0]),
        ]),
        solutions: vec![z_star],
        note: "Designed here: boxed MCP, n = 6, strongly monotone (F = F* + M d + d^3/2), unique \
               strictly complementary solution (0, 1, 0.5, 3, 1, -0.25) with one component at a \
               box's lower bound, one at a box's upper bound, one inside a box, one at a one-sided \
               upper bound, one at a one-sided lower bound, one free. The 'outside' start \
               violates the bounds on purpose.",
    }
}

/// An NCP with a unique but not strictly complementary solution: `z_i = 0` and `F_i(z) = 0`
/// for two components, so the Fischer–Burmeister reformulation is not differentiable there.
///
/// `n = 5`, `z* = (0, 1, 0, 2, 0)`, `F(z*) = (0, 0, 2, 0, 0)` (components 0 and 4 degenerate),
/// `F(z) = F* + M(z − z*) + ½(z − z*)³` with `M = 4I + K`, `K` skew-symmetric, so `F` is
/// strongly monotone and `z*` is the only solution.
pub fn degenerate() -> TestProblem {
    let n = 5;
    let z_star = vec![0.0, 1.0, 0.0, 2.0, 0.0];
    let f_star = vec![0.0, 0.0, 2.0, 0.0, 0.0];
    #[rustfmt::skip]
    let m = vec![
         4.0,  1.0,  0.0,  0.0,  1.0,
        -1.0,  4.0,  1.0,  0.0,  0.0,
         0.0, -1.0,  4.0,  1.0,  0.0,
         0.0,  0.0, -1.0,  4.0,  1.0,
        -1.0,  0.0,  0.0, -1.0,  4.0,
    ];
    let mcp = manufactured(vec![0.0; n], vec![INF; n], z_star.clone(), f_star, m);
    TestProblem {
        name: "degenerate".into(),
        mcp,
        starts: labelled(&[
            ("zero", &[0.0; 5]),
            ("ones", &[1.0; 5]),
            ("far", &[5.0, 5.0, 5.0, 5.0, 5.0]),
        ]),
        solutions: vec![z_star],
        note: "Designed here: NCP, n = 5, strongly monotone (F = F* + (4I + K) d + d^3/2, K skew), \
               unique solution (0, 1, 0, 2, 0) with F = (0, 0, 2, 0, 0): components 0 and 4 are \
               degenerate (z_i = 0 and F_i = 0).",
    }
}

// ---------------------------------------------------------------------------------------------
// One-contact friction NCP (`docs/model.md#friction`)
// ---------------------------------------------------------------------------------------------

/// Which contact regime [`one_contact_friction`] is set up to produce.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrictionRegime {
    /// In contact, tangential push inside the friction ellipsoid: no slip, `σ = 0`.
    Sticking,
    /// In contact, the friction impulse cannot stop the body: slip, impulse on the ellipsoid.
    Sliding,
    /// The gap stays open: `p_n = 0`, no friction, `σ` undetermined.
    Separated,
}

/// Fixed data of the one-contact problem.
struct FrictionData {
    mass: f64,
    inertia: f64,
    h: f64,
    g: f64,
    mu: f64,
    e_t: f64,
    e_o: f64,
    e_r: f64,
    /// Start velocities (v_t0, v_o0, w0, v_n0).
    v0: [f64; 4],
    /// Applied tangential forces and torque about the normal (f_t, f_o, τ_n).
    force: [f64; 3],
    gap: f64,
}

impl FrictionData {
    fn new(regime: FrictionRegime) -> Self {
        let (mass, inertia) = (2.0, 0.08);
        // Isotropic in the plane, e_r = e·√(I_n/m): the ellipsoid is similar to the kinetic
        // metric, so the maximum-dissipation slip is parallel to the frictionless velocity
        // and the sliding solution has a closed form.
        let e = 1.0;
        let (v0, force, gap) = match regime {
            FrictionRegime::Sticking => ([0.01, -0.005, 0.02, 0.0], [1.0, -0.5, 0.01], 0.0),
            FrictionRegime::Sliding => ([0.3, -0.4, 1.0, -0.05], [2.0, 0.0, 0.1], 0.0),
            FrictionRegime::Separated => ([0.3, -0.4, 1.0, -0.5], [2.0, 0.0, 0.1], 0.05),
        };
        FrictionData {
            mass,
            inertia,
            h: 0.01,
            g: 9.8,
            mu: 0.5,
            e_t: e,
            e_o: e,
            e_r: e * (inertia / mass).sqrt(),
            v0,
            force,
            gap,
        }
    }

    /// Generalised masses (m, m, I_n) of the tangential unknowns.
    fn masses(&self) -> [f64; 3] {
        [self.mass, self.mass, self.inertia]
    }

    /// `a = D v0 + h f`: the tangential momentum the contact must act on.
    fn momentum(&self) -> [f64; 3] {
        let d = self.masses();
        [0, 1, 2].map(|k| d[k] * self.v0[k] + self.h * self.force[k])
    }

    /// The exact solution (a representative one when separated), derived in the doc of
    /// [`one_contact_friction`].
    fn solution(&self, regime: FrictionRegime) -> Vec<f64> {
        let d = self.masses();
        let a = self.momentum();
        let e2 = [
            self.e_t * self.e_t,
            self.e_o * self.e_o,
            self.e_r * self.e_r,
        ];
        let (v_n, p_n) = match regime {
            FrictionRegime::Separated => (self.v0[3] - self.h * self.g, 0.0),
            _ => {
                let v_n = -self.gap / self.h;
                (
                    v_n,
                    self.mass * (v_n - self.v0[3]) + self.h * self.mass * self.g,
                )
            }
        };
        let (v, p, sigma) = match regime {
            FrictionRegime::Sticking => ([0.0; 3], a.map(|x| -x), 0.0),
            FrictionRegime::Separated => ([0, 1, 2].map(|k| a[k] / d[k]), [0.0; 3], 0.0),
            FrictionRegime::Sliding => {
                let v_free = [0, 1, 2].map(|k| a[k] / d[k]);
                let s = (0..3)
                    .map(|k| e2[k] * v_free[k] * v_free[k])
                    .sum::<f64>()
                    .sqrt();
                let c = self.mu * p_n * e2[0] / self.mass;
                let sigma = s - c;
                let v = v_free.map(|x| x * sigma / s);
                let p = [0, 1, 2].map(|k| -self.mu * p_n * e2[k] * v[k] / sigma);
                (v, p, sigma)
            }
        };
        vec![v[0], v[1], v[2], v_n, p[0], p[1], p[2], sigma, p_n]
    }
}

/// The one-contact friction NCP of `docs/model.md#friction` with fixed data: a body of mass
/// `m = 2` kg and inertia `I_n = 0.08` kg m² about the contact normal, one contact with the
/// ground, a velocity-level step `h = 0.01` s, `g = 9.8`, `μ = 0.5`, `e_t = e_o = 1`,
/// `e_r = √(I_n/m) = 0.2` m.
///
/// Unknowns `z = (v_t, v_o, w_n, v_n, p_t, p_o, p_r, σ, p_n)`, the first seven free, `σ ≥ 0`,
/// `p_n ≥ 0`. Rows (row `i` pairs with `z_i`), with `D = (m, m, I_n)`, applied `(f_t, f_o, τ_n)`:
///
/// - `D_k (v_k − v_k0) − h f_k − p_k = 0` (k = t, o, r), `m (v_n − v_n0) + h m g − p_n = 0`;
/// - `e_k² μ p_n v_k + p_k σ = 0` (k = t, o, r);
/// - `μ² p_n² − p_t²/e_t² − p_o²/e_o² − p_r²/e_r² ≥ 0 ⊥ σ ≥ 0`;
/// - `v_n + gap/h ≥ 0 ⊥ p_n ≥ 0`.
///
/// Exact solutions, with `a_k = D_k v_k0 + h f_k` and `E_k = e_k²` (note `E_k/D_k = 1/m` for
/// all k with this data):
///
/// - **Sticking** (gap 0, small push): `v = 0`, `v_n = 0`, `p_n = m(h g − v_n0)`, `p = −a`,
///   strictly inside the ellipsoid, `σ = 0` (strictly complementary).
/// - **Sliding** (gap 0, body already moving): with `v_free = a/D`, `s = ‖E^{1/2} v_free‖` and
///   `c = μ p_n e_t²/m`, the slip is `v = v_free (s − c)/s`, `σ = s − c > 0`,
///   `p_k = −μ p_n E_k v_k / σ` (on the ellipsoid, opposite to the slip in the `E` metric).
/// - **Separated** (gap 0.05 m): `p_n = 0`, `v_n = v_n0 − h g`, `v = a/D`, `p = 0`; every
///   `σ ≥ 0` solves the problem (the friction rows vanish identically), so the solution set
///   is a ray; the listed representative has `σ = 0`.
pub fn one_contact_friction(regime: FrictionRegime) -> TestProblem {
    let d = FrictionData::new(regime);
    let solution = d.solution(regime);
    let v0 = d.v0;
    let starts = vec![
        ("zero".to_string(), vec![0.0; 9]),
        (
            "start_velocities".to_string(),
            vec![v0[0], v0[1], v0[2], v0[3], 0.0, 0.0, 0.0, 0.0, 0.0],
        ),
        (
            "resting_weight".to_string(),
            vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, d.mass * d.g * d.h],
        ),
    ];
    let (name, note) = match regime {
        FrictionRegime::Sticking => (
            "one_contact_friction_sticking",
            "Friction NCP of docs/model.md, one contact, fixed data (m = 2, I_n = 0.08, \
             h = 0.01, mu = 0.5, e = (1, 1, 0.2)). Sticking: v = 0, p = -(D v0 + h f) strictly \
             inside the ellipsoid, sigma = 0, p_n = m g h. Unique, strictly complementary.",
        ),
        FrictionRegime::Sliding => (
            "one_contact_friction_sliding",
            "Friction NCP of docs/model.md, one contact, fixed data. Sliding and spinning: \
             sigma = s - c > 0, v = v_free (s - c)/s, impulse on the ellipsoid opposite to the \
             slip (closed form because e_r^2/I_n = e_t^2/m). Unique.",
        ),
        FrictionRegime::Separated => (
            "one_contact_friction_separated",
            "Friction NCP of docs/model.md, one contact, fixed data. Separated (gap 0.05): \
             p_n = 0, p = 0, free flight; sigma is undetermined (every sigma >= 0 solves it: the \
             solution set is a ray, not a point), the listed solution is the representative \
             sigma = 0; compare all components except sigma (index 7). Jacobian singular there.",
        ),
    };
    let mcp = friction_mcp(d).with_names(names(&[
        "v_t", "v_o", "w_n", "v_n", "p_t", "p_o", "p_r", "sigma", "p_n",
    ]));
    TestProblem {
        name: name.into(),
        mcp,
        starts,
        solutions: vec![solution],
        note,
    }
}

/// Index of `σ` in the one-contact friction problem's unknowns (the component that is not
/// unique in the separated regime).
pub const FRICTION_SIGMA: usize = 7;

fn friction_mcp(d: FrictionData) -> FnMcp {
    let n = 9;
    let mut lower = vec![-INF; n];
    let upper = vec![INF; n];
    lower[7] = 0.0;
    lower[8] = 0.0;
    let dm = d.masses();
    let e2 = [d.e_t * d.e_t, d.e_o * d.e_o, d.e_r * d.e_r];
    let (mass, h, g, mu, gap, v0, force) = (d.mass, d.h, d.g, d.mu, d.gap, d.v0, d.force);
    dense(
        lower,
        upper,
        move |z, f| {
            let (sigma, p_n) = (z[7], z[8]);
            for k in 0..3 {
                f[k] = dm[k] * (z[k] - v0[k]) - h * force[k] - z[4 + k];
                f[4 + k] = e2[k] * mu * p_n * z[k] + z[4 + k] * sigma;
            }
            f[3] = mass * (z[3] - v0[3]) + h * mass * g - p_n;
            f[7] = mu * mu * p_n * p_n - (0..3).map(|k| z[4 + k] * z[4 + k] / e2[k]).sum::<f64>();
            f[8] = z[3] + gap / h;
        },
        move |z, j| {
            let (sigma, p_n) = (z[7], z[8]);
            let mut set = |row: usize, col: usize, v: f64| j[col * n + row] = v;
            for k in 0..3 {
                set(k, k, dm[k]);
                set(k, 4 + k, -1.0);
                set(4 + k, k, e2[k] * mu * p_n);
                set(4 + k, 4 + k, sigma);
                set(4 + k, 7, z[4 + k]);
                set(4 + k, 8, e2[k] * mu * z[k]);
                set(7, 4 + k, -2.0 * z[4 + k] / e2[k]);
            }
            set(3, 3, mass);
            set(3, 8, -1.0);
            set(7, 8, 2.0 * mu * mu * p_n);
            set(8, 3, 1.0);
        },
    )
}

// ---------------------------------------------------------------------------------------------
// The suite
// ---------------------------------------------------------------------------------------------

/// Every problem above, at the sizes the solver tests use: the MCPLIB problems, the three
/// Mathiesen variants, `murty(10)`, the designed box and degenerate problems, random P-matrix
/// LCPs (dense `n = 10` and `30`, sparse `n = 100`) and the three friction regimes.
pub fn suite() -> Vec<TestProblem> {
    vec![
        kojima_josephy(),
        kojima_shindo(),
        mathiesen(),
        mathiesen_numeraire(),
        mathiesen_pang_gabriel(),
        murty(10),
        box_both_bounds(),
        degenerate(),
        random_p_matrix_lcp(10, 1, false),
        random_p_matrix_lcp(30, 2, false),
        random_p_matrix_lcp(100, 3, true),
        one_contact_friction(FrictionRegime::Sticking),
        one_contact_friction(FrictionRegime::Sliding),
        one_contact_friction(FrictionRegime::Separated),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{CheckOptions, check_mcp, residual_of};

    fn extra_problems() -> Vec<TestProblem> {
        vec![
            murty(1),
            murty(3),
            murty(50),
            random_p_matrix_lcp(1, 7, false),
            random_p_matrix_lcp(12, 8, true),
        ]
    }

    #[test]
    fn problems_known_solutions_have_tiny_residual() {
        for p in suite().into_iter().chain(extra_problems()) {
            for z in &p.solutions {
                assert_eq!(z.len(), p.dim(), "{}", p.name);
                let r = residual_of(&p.mcp, z);
                assert!(r <= 1e-12, "{}: residual {r:e} at {z:?}", p.name);
            }
            for (label, z) in &p.starts {
                assert_eq!(z.len(), p.dim(), "{} start {label}", p.name);
            }
        }
    }

    #[test]
    fn problems_names_are_unique() {
        let mut names: Vec<String> = suite().into_iter().map(|p| p.name).collect();
        let n = names.len();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), n);
    }

    #[test]
    fn problems_jacobians_match_finite_differences() {
        let mut rng = SplitMix64(42);
        for p in suite().into_iter().chain(extra_problems()) {
            let random: Vec<f64> = (0..p.dim()).map(|_| rng.range(0.2, 1.5)).collect();
            let mut points: Vec<(String, Vec<f64>)> = p.starts.clone();
            points.push(("random".into(), random));
            for (i, s) in p.solutions.iter().enumerate() {
                points.push((format!("solution{i}"), s.clone()));
            }
            for (label, z) in &points {
                let report = check_mcp(&p.mcp, z, &CheckOptions::default());
                assert!(report.ok(), "{} at {label}: {report}", p.name);
            }
        }
    }

    #[test]
    fn problems_kojima_josephy_literature_point_is_not_a_solution() {
        // (1, 0, 3, 0) solves Kojima–Shindo but not Kojima–Josephy (F3 = 8 with x3 = 3).
        let p = kojima_josephy();
        assert!(residual_of(&p.mcp, &[1.0, 0.0, 3.0, 0.0]) > 1.0);
        let mut f = [0.0; 4];
        p.mcp.evaluate(&[1.0, 0.0, 3.0, 0.0], &mut f);
        assert_eq!(f, [0.0, 10.0, 8.0, 4.0]);
    }

    #[test]
    fn problems_kojima_shindo_first_solution_is_degenerate() {
        let p = kojima_shindo();
        let mut f = [0.0; 4];
        p.mcp.evaluate(&p.solutions[0], &mut f);
        assert_eq!(p.solutions[0][2], 0.0);
        assert!(f[2].abs() < 1e-14, "F3 = {}", f[2]);
    }

    #[test]
    fn problems_mathiesen_pang_gabriel_segment_solves() {
        let p = mathiesen_pang_gabriel();
        for lambda in [0.0, 0.5, 1.0, 2.25, 3.0] {
            assert!(residual_of(&p.mcp, &[lambda, 0.0, 0.0, 0.0]) <= 1e-15);
        }
        assert!(residual_of(&p.mcp, &[3.5, 0.0, 0.0, 0.0]) >= 0.5);
    }

    #[test]
    fn problems_mathiesen_pole_is_a_domain_error() {
        // Approaching p2 = 0 from below would make the natural residual vanish at a pole, so
        // F_p2 is undefined (NaN) for p2 <= 0 and finite for p2 > 0.
        let num = mathiesen_numeraire();
        let mut f = [0.0; 3];
        for p2 in [-1e-9, 0.0, -1.0] {
            num.mcp.evaluate(&[3.0, p2, 1.0], &mut f);
            assert!(f[1].is_nan() && f[0].is_finite() && f[2].is_finite());
        }
        num.mcp.evaluate(&[3.0, 1e-300, 1.0], &mut f);
        assert!(f[1].is_finite() || f[1] == f64::NEG_INFINITY);
        let sum = mathiesen();
        let mut f = [0.0; 4];
        sum.mcp.evaluate(&[3.0, 0.5, -1e-9, 0.5], &mut f);
        assert!(f[2].is_nan());
        let mut jac = vec![0.0; 16];
        sum.mcp.jacobian(&[3.0, 0.5, 0.0, 0.5], &mut jac);
        assert!(jac[2 * 4 + 2].is_nan());
    }

    #[test]
    fn problems_degenerate_has_degenerate_components() {
        let p = degenerate();
        let z = &p.solutions[0];
        let mut f = vec![0.0; p.dim()];
        p.mcp.evaluate(z, &mut f);
        assert!(z[0] == 0.0 && f[0] == 0.0 && z[4] == 0.0 && f[4] == 0.0);
    }

    #[test]
    fn problems_box_solution_hits_every_bound_kind() {
        let p = box_both_bounds();
        let z = &p.solutions[0];
        let (l, u) = (p.mcp.lower(), p.mcp.upper());
        assert_eq!(z[0], l[0]);
        assert_eq!(z[1], u[1]);
        assert!(l[2] < z[2] && z[2] < u[2]);
        assert_eq!(z[3], u[3]);
        assert_eq!(z[4], l[4]);
        assert!(l[5].is_infinite() && u[5].is_infinite());
    }

    #[test]
    fn problems_friction_regimes_are_as_designed() {
        let stick = one_contact_friction(FrictionRegime::Sticking);
        let z = &stick.solutions[0];
        let d = FrictionData::new(FrictionRegime::Sticking);
        let inside = z[4] * z[4] / (d.e_t * d.e_t)
            + z[5] * z[5] / (d.e_o * d.e_o)
            + z[6] * z[6] / (d.e_r * d.e_r);
        assert!(inside < 0.5 * (d.mu * z[8]).powi(2), "not strictly inside");
        assert_eq!(z[FRICTION_SIGMA], 0.0);
        assert!(z[8] > 0.0);

        let slide = one_contact_friction(FrictionRegime::Sliding);
        let z = &slide.solutions[0];
        let d = FrictionData::new(FrictionRegime::Sliding);
        assert!(z[FRICTION_SIGMA] > 0.1 && z[8] > 0.0);
        let on = z[4] * z[4] / (d.e_t * d.e_t)
            + z[5] * z[5] / (d.e_o * d.e_o)
            + z[6] * z[6] / (d.e_r * d.e_r);
        assert!(
            (on - (d.mu * z[8]).powi(2)).abs() < 1e-14,
            "not on the ellipsoid"
        );
        // Friction opposes the slip: p·v < 0.
        assert!(z[4] * z[0] + z[5] * z[1] + z[6] * z[2] < 0.0);

        let sep = one_contact_friction(FrictionRegime::Separated);
        let mut z = sep.solutions[0].clone();
        assert_eq!(z[8], 0.0);
        for sigma in [0.0, 0.3, 7.0] {
            z[FRICTION_SIGMA] = sigma;
            assert!(residual_of(&sep.mcp, &z) <= 1e-12, "sigma = {sigma}");
        }
    }

    #[test]
    fn problems_sparse_lcp_stays_sparse() {
        let p = random_p_matrix_lcp(1000, 11, true);
        let nnz = p.mcp.jacobian_pattern().nnz();
        assert!(nnz <= 4 * 1000, "nnz = {nnz}");
        let mut vals = vec![0.0; nnz];
        p.mcp.jacobian(&p.starts[0].1, &mut vals);
        // Strict diagonal dominance by rows.
        let pat = p.mcp.jacobian_pattern().clone();
        let mut off = vec![0.0; 1000];
        let mut diag = vec![0.0; 1000];
        for j in 0..1000 {
            for k in pat.col_ptr()[j]..pat.col_ptr()[j + 1] {
                let i = pat.row_idx()[k];
                if i == j {
                    diag[i] = vals[k];
                } else {
                    off[i] += vals[k].abs();
                }
            }
        }
        assert!((0..1000).all(|i| diag[i] > off[i]));
    }

    #[test]
    fn problems_random_lcp_is_deterministic_and_seed_dependent() {
        let a = random_p_matrix_lcp(8, 5, false);
        let b = random_p_matrix_lcp(8, 5, false);
        let c = random_p_matrix_lcp(8, 6, false);
        let z = vec![0.3; 8];
        let (mut fa, mut fb, mut fc) = (vec![0.0; 8], vec![0.0; 8], vec![0.0; 8]);
        a.mcp.evaluate(&z, &mut fa);
        b.mcp.evaluate(&z, &mut fb);
        c.mcp.evaluate(&z, &mut fc);
        assert_eq!(fa, fb);
        assert_ne!(fa, fc);
        assert_eq!(a.starts[1].1, b.starts[1].1);
    }

    #[test]
    fn problems_dense_random_matrix_is_positive_definite() {
        // xᵀMx = xᵀ(BᵀB + I)x ≥ ‖x‖² for every x: check on a few vectors.
        let p = random_p_matrix_lcp(10, 1, false);
        let n = 10;
        let mut jac = vec![0.0; n * n];
        p.mcp.jacobian(&vec![0.0; n], &mut jac);
        let mut rng = SplitMix64(3);
        for _ in 0..50 {
            let x: Vec<f64> = (0..n).map(|_| rng.range(-1.0, 1.0)).collect();
            let mut q = 0.0;
            for i in 0..n {
                for j in 0..n {
                    q += x[i] * jac[j * n + i] * x[j];
                }
            }
            let nx: f64 = x.iter().map(|v| v * v).sum();
            assert!(q >= nx - 1e-12);
        }
    }

    #[test]
    fn problems_lcp_rejects_bad_input() {
        assert!(matches!(
            lcp(vec![1.0; 3], vec![0.0; 2]),
            Err(ModelError::Dimension(_))
        ));
        assert!(lcp(vec![1.0, f64::NAN, 0.0, 1.0], vec![0.0; 2]).is_err());
        assert!(lcp(vec![1.0], vec![f64::INFINITY]).is_err());
        let p = lcp(vec![2.0, 1.0, 1.0, 2.0], vec![-1.0, 1.0]).unwrap();
        assert!(residual_of(&p.mcp, &[0.5, 0.0]) == 0.0);
        assert_eq!(p.distance_to_solutions(&[0.5, 0.0], None), None);
    }

    #[test]
    fn problems_distance_to_solutions() {
        let p = kojima_shindo();
        let d = p
            .distance_to_solutions(&[1.0, 0.0, 3.0 + 1e-3, 0.0], None)
            .unwrap();
        assert!((d - 1e-3).abs() < 1e-12);
        let d = p
            .distance_to_solutions(&[1.0, 5.0, 3.0, 0.0], Some(&[0, 2, 3]))
            .unwrap();
        assert_eq!(d, 0.0);
    }
}
