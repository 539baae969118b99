//! The PATH-like solver: Josephy–Newton steps computed by pivoting, with a path search
//! (`docs/backends.md#path-like`).
//!
//! The MCP is written with Robinson's normal map `F_N(x) = F(π(x)) + x − π(x)`, `π` the
//! projection onto `[l, u]`: `z = π(x)` solves the MCP iff `F_N(x) = 0`. At the iterate `x_k`
//! (with `z_k = π(x_k)`), the linearisation `L_k(x) = F(z_k) + J(z_k)(π(x) − z_k) + x − π(x)` is
//! the normal map of an affine MCP. Lemke's method ([`crate::pivot`]) started at `x_k` with the
//! covering vector `−F_N(x_k)` follows the homotopy `L_k(p(t)) = (1 − t) F_N(x_k)` from `t = 0`
//! (the iterate) to `t = 1` (the Josephy–Newton point), and its breakpoints are kept, so that the
//! step can be shortened *along that piecewise-linear path* (Ralph's path search, Math. OR 19,
//! 1994) rather than along a straight line, which would leave the pieces of the normal map.
//! A point `p(t)` is accepted when `‖F_N(p(t))‖₂ ≤ (1 − σt) ‖F_N(x_c)‖₂`.
//!
//! Around this, as in PATH (Dirkse & Ferris, Optim. Methods & Software 5, 1995):
//!
//! - a **non-monotone watchdog**: full Newton points are taken without the decrease test for up
//!   to `watchdog` iterations after the last checkpoint (the best point); if none of them
//!   decreases the merit enough, the solver returns to the checkpoint and searches along its path;
//! - a **crash phase**: projected Newton steps on the reduced system of the variables that the
//!   projection `π(z − F)` leaves inside their bounds, to guess the active set before pivoting;
//! - a **proximal perturbation**: when the linearised problem has a singular basis, ends on a
//!   ray or its path search fails, `J` is replaced by `J + λI` (the path still starts at `x_k`,
//!   since the linearisation agrees with `F_N` there), and `λ` is reduced again after progress.
//!
//! After a failed first attempt, a second one from the start point uses a *guarded* watchdog
//! (no non-monotone steps and no relaxation of `λ` after a step the path search had to shorten,
//! until a full Newton step is accepted), then come the restarts. A wall-clock budget per solve
//! (`time_limit`) bounds all of it, the pivoting included (docs/path.md).
//!
//! A trial point is accepted only where `F` and its Jacobian are finite: a non-finite value (a
//! model evaluated outside its domain) fails the trial like an insufficient decrease, so the
//! search backtracks along the path, perturbs the linearisation, and after a failed attempt goes
//! on to the restarts. Only a start point where `F` or `J` is not finite ends the solve at once.
//!
//! After every accepted point, `x` is reset to the normal-map point of `z = π(x)` with the
//! smallest merit (`x_i = l_i − F_i` where `z_i = l_i`, `F_i > 0`, likewise at upper bounds,
//! `x_i = z_i` elsewhere); the merit is then the norm of the natural-map-like vector with the
//! outward components of `F` at active bounds removed.

use std::sync::Arc;
use std::time::Instant;

use ecp_model::linalg::ColumnTestedLu;
use ecp_model::mcp::fb_component;
use ecp_model::{
    Counter, CscPattern, IterationRecord, Mcp, McpScales, McpSolver, Observer, ScalesUsage,
    Solution, SolveError, SolveReport, StepKind, Termination, finish_solve, finish_solve_into, mid,
    natural_residual, solve_in_scales, validate_start,
};

use crate::pivot::basis::DEPENDENCE_TOLERANCE;
use crate::pivot::{
    AffineMatrix, AffineMcp, AffineStart, Lemke, LemkeSettings, PivotError, PivotPath,
    mul_vec_nonzero_columns,
};
use crate::smoothing::{SmoothingSettings, continuation};

mod valley;
use valley::Stall;

/// Settings of the PATH-like solver, with documented defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct PathSettings {
    /// Stop when the natural residual `‖z − mid(l, u, z − F)‖∞` is at most this. Default `1e-10`.
    pub tolerance: f64,
    /// Limit on major iterations (crash steps and pivotal steps together). Default 200.
    pub max_iterations: usize,
    /// Projected Newton steps of the crash phase before the first pivotal step; 0 disables the
    /// crash. The crash also stops when the active set repeats or the merit stops decreasing.
    /// Default 50.
    pub crash_iterations: usize,
    /// Non-monotone watchdog: full Newton points accepted without sufficient decrease after the
    /// last checkpoint before returning to it. 0 makes the method monotone. Default 5.
    pub watchdog: usize,
    /// The watchdog takes a Newton point without sufficient decrease only while its merit is at
    /// most this times the checkpoint's. Without the bound, on steps whose linearisation is
    /// nearly singular (`012_multi_body` steps 1008–1009, h = 1 ms) the watchdog took Newton
    /// points with merits 1e20–1e49 times the checkpoint's, five in a row from each return to
    /// the checkpoint, each one's Lemke path hundreds of pivots long, until the attempt's
    /// iterations ran out (`docs/path.md#hard-steps`). Default `1e6`.
    pub watchdog_growth: f64,
    /// Sufficient-decrease constant σ of the path search, `‖F_N(p(t))‖ ≤ (1 − σt)‖F_N(x_c)‖`.
    /// Default `1e-4`.
    pub sufficient_decrease: f64,
    /// Backtracking factor β along the path (`t = β^j t_max`). Default `0.5`.
    pub backtrack: f64,
    /// Backtracking steps along the path before the search gives up; 0 disables the path search
    /// (only full Newton points are tried). Default 30.
    pub max_path_backtracks: usize,
    /// First proximal perturbation `λ`, relative to `max(1, max |J_ij|)`. Default `1e-4`.
    pub proximal_initial: f64,
    /// Factor by which `λ` grows after each failure of the linearised problem. Default 10.
    pub proximal_growth: f64,
    /// Factor by which `λ` shrinks after an accepted step (below `1e-12` relative it is set to
    /// 0). Default `0.1`.
    pub proximal_reduction: f64,
    /// Largest relative `λ` tried before giving up. Default `1e8`.
    pub proximal_max: f64,
    /// Restarts from the starting point after a failed attempt (PATH restarts with other
    /// settings): monotone, no crash, proximal term on from the first step. Default 2.
    pub restarts: usize,
    /// After a failed first attempt, one more attempt from the start point with a *guarded*
    /// watchdog before the restarts: once the path search has had to shorten a step (after a
    /// return to the checkpoint), the iteration stays monotone and keeps its proximal term until
    /// a full Newton step is accepted again. The unguarded watchdog can cycle near contact
    /// changes, returning to a checkpoint that each time moved by a tiny step along its path and
    /// leaving it again along the same diverging Newton points (docs/path.md). Default `true`.
    pub guarded_watchdog: bool,
    /// Relative proximal term of the first restart (×10 for each further one). Default `1e-2`.
    pub restart_proximal: f64,
    /// After every other attempt failed, one more from the start point whose path search and
    /// watchdog judge points by the Fischer–Burmeister merit `‖Φ_FB(z)‖₂` instead of the normal
    /// map's `‖F_N(x)‖₂` (PATH's `merit_function fischer`, Ferris, Kanzow & Munson, Math. Prog.
    /// 86, 1999). The two merits have different stationary points: where the normal-map merit
    /// stops a path search at a point that is not a solution, the other one usually does not
    /// (docs/path.md). Default `true`.
    pub fischer_restart: bool,
    /// After every other attempt failed, one more from the best point found (the natural
    /// residual's smallest), with the default settings. Default `true`.
    pub best_point_restart: bool,
    /// An attempt stops (`Stagnated`) once `stall_window` iterations have passed without its
    /// natural residual falling below [`PathSettings::stall_ratio`] times the best one at the
    /// start of that window. On the floor of a valley of the merit (`022_v_trough` of seed
    /// 20261212, two loaded contacts on a trough's sides) every attempt either fails its path
    /// search or cycles at the watchdog until [`PathSettings::max_iterations`]; the stop hands
    /// the step to the next attempt and to the smoothing continuation, which solves it, sooner
    /// (`docs/path.md#the-valley-of-the-v-troughs`). Off by default: it also stops attempts
    /// that would have converged, and those steps then cost more (window 40: two steps of the
    /// held-out seeds 155 → 220 and 161 → 203 iterations; window 20: +224 on the documented
    /// seed), though it shortens the longest steps (728 → 402, 633 → 448). On the seven stress
    /// seeds every window from 20 to 80 lowers their total and the longest step (1 395 → 704 at
    /// 20) but lengthens other steps, some past 200 iterations (`docs/latency.md`, branch
    /// wip-pathstall). `0` for no such stop. Default 0.
    pub stall_window: usize,
    /// The factor by which an attempt's natural residual must fall within
    /// [`PathSettings::stall_window`] iterations, in `(0, 1)`. Default `0.5`.
    pub stall_ratio: f64,
    /// An attempt stops (`Stagnated`) after this many consecutive accepted steps that each
    /// moved the iterate by at most [`FROZEN_STEP`] of its size, above the tolerance, whatever
    /// the proximal term (`docs/latency.md`, branch wip-tip057). At a local minimiser of the
    /// merit that is no solution (a fold of the step's solution branch: `057_union_tip` of
    /// seed 20270102, step 188) the path search accepts `t ≈ 7e-9` of a path that the
    /// proximal term keeps ~1e-13 long, the iterate, its linearisation and `λ` stay the same,
    /// and each attempt repeats that step until its iteration limit (1 091 of the step's
    /// 2 249 iterations). `0` for no such stop. Default 10.
    pub frozen_steps: usize,
    /// When every attempt failed, the smoothing continuation from the start point
    /// ([`crate::smoothing`], `docs/path.md`): one attempt of at most
    /// `stage_iterations` on each smoothed natural map `G_μ` for `μ = μ₀, θμ₀, …` down to the
    /// tolerance, then every attempt again from its end point. `None` turns it off. Default
    /// `SmoothingSettings::default()` with Newton's give-up of a crawling continuation
    /// (`max_failed_stages = Some(`[`crate::newton::FAILED_STAGES`]`)`, `count_cut_stages`): on
    /// `022_v_trough` of seed 20261212, step 62, the continuation as given lost the path at the
    /// valley's floor and took about 70 stages of 30 iterations before the one in the scene
    /// scales solved the step (`docs/path.md#the-valley-of-the-v-troughs`).
    pub smoothing: Option<SmoothingSettings>,
    /// Settings of the inner pivotal solver (pivot tolerances, limit, refactorisation period,
    /// anti-cycling rule).
    pub lemke: LemkeSettings,
    /// Wall-clock budget of one solve (all attempts and restarts together), in seconds; when
    /// it runs out, the solve stops with the best point found and `max_iterations` (the pivot
    /// loop of the linearised problem is cut short too). `f64::INFINITY` for no limit.
    /// Default 20.
    pub time_limit: f64,
    /// On a problem with scene scales ([`ecp_model::solve_in_scales`]), run the first attempt in
    /// both systems of units (as given and in the scales, in `solve_in_scales`' order) before
    /// the other attempts in either. Without it every attempt runs in the first system before
    /// any in the second; on a step at h = 1 ms (`012_multi_body` step 475, 121 unknowns) every
    /// attempt as given cycled at its watchdog (635 iterations, 370 000 pivots, 6 s) where the
    /// first attempt in the scales converges in 3 (`docs/path.md#hard-steps`). Default `true`.
    pub first_in_both_units: bool,
    /// When [`PathSettings::first_in_both_units`] splits the first attempt, each of its two
    /// halves (as given, in the scales) stops once it has made this many pivots per unknown
    /// (`first_attempt_pivots · n` in all), so that one system of units cannot spend the whole
    /// [`PathSettings::time_limit`] before the other is tried. A first attempt that converges
    /// makes a few pivots per unknown; on `012_multi_body` step 1008 (121 unknowns) the attempt
    /// as given ran 42 iterations of thousands of pivots each into the 20 s limit, where the one
    /// in the scales converges in 7 iterations and 13 pivots (`docs/path.md#hard-steps`). While
    /// the budget lasts, each Lemke path of the attempt also stops at 3 pivots per unknown or
    /// at what is left of the budget, so no path overruns it (a longer path was a cycling one on
    /// `038_multi_body`). The later attempts have no pivot budget; each of their paths stops at
    /// 10 pivots per unknown. `0` for none. Default `100`.
    pub first_attempt_pivots: usize,
    /// An attempt that reaches the tolerance with a natural residual above this fraction of it
    /// takes up to two more full Newton steps from its end point (the crash phase's projected
    /// step; where its reduced Jacobian is singular, the same with a proximal shift from
    /// `1e-10 · max|J|`), each kept when its point meets the tolerance too, the second only
    /// after a first that gained a digit (no more at the residual's round-off floor), as
    /// `NewtonSettings::polish_below` does for Newton; where the LU of the last crash step or
    /// polish is kept, chord steps on it come first (`docs/latency.md`, branch wip-pathdesk).
    /// Below `1.0` the backend reports
    /// [`McpSolver::converges_to_round_off`], so the driver extrapolates its warm starts: the
    /// 21 reference scenes end within 6.4e-13 of the plain warm start's answer but the T-bar
    /// (2.25e-12, Newton's own 2.66e-12), and the stress suite takes 3.7 % fewer iterations
    /// (`docs/latency.md`, branch wip-pathwarm2). `1.0` turns it off (main's PATH before it,
    /// which stops anywhere within the tolerance). Default `1e-3`.
    pub polish_below: f64,
    /// Chord steps on the LU kept from the last solve: a solve that converged with the LU of
    /// its last crash step or polish (`J_II` and its active set) keeps it, keyed by the
    /// problem's dimension, Jacobian pattern and system of units (as given or in the scene
    /// scales, with the scales' values); the next solve's first attempt on the same key takes
    /// chord steps on it before any Jacobian (`PathSolver::chord_target`: the same active
    /// set, the crash phase's decrease and contraction tests, or the polish's). Default `false`
    /// (`docs/latency.md`, branch wip-pathfast of issue 18).
    pub chord_across_solves: bool,
    /// Record a per-iteration trace in the summary. Default `false`.
    pub trace: bool,
}

impl Default for PathSettings {
    fn default() -> Self {
        PathSettings {
            tolerance: 1e-10,
            max_iterations: 200,
            crash_iterations: 50,
            watchdog: 5,
            watchdog_growth: 1e6,
            sufficient_decrease: 1e-4,
            backtrack: 0.5,
            max_path_backtracks: 30,
            proximal_initial: 1e-4,
            proximal_growth: 10.0,
            proximal_reduction: 0.1,
            proximal_max: 1e8,
            restarts: 2,
            restart_proximal: 1e-2,
            guarded_watchdog: true,
            fischer_restart: true,
            best_point_restart: true,
            stall_window: 0,
            stall_ratio: 0.5,
            frozen_steps: 10,
            // Newton's give-up of a crawling continuation (`docs/newton.md#a-crawling-continuation`).
            smoothing: Some(SmoothingSettings {
                max_failed_stages: Some(crate::newton::FAILED_STAGES),
                count_cut_stages: true,
                ..SmoothingSettings::default()
            }),
            lemke: LemkeSettings::default(),
            time_limit: 20.0,
            first_in_both_units: true,
            first_attempt_pivots: 100,
            polish_below: 1e-3,
            chord_across_solves: false,
            trace: false,
        }
    }
}

/// The polish's first proximal shift where `J_II` is singular, relative to `max(1, max|J|)`:
/// far smaller than the main loop's (`PathSettings::proximal_initial`), since it scales the
/// polished point's error (`λ / (σ + λ)` per step along a direction of singular value `σ`).
const POLISH_SHIFT_MIN: f64 = 1e-10;

/// The polish's largest relative shift: beyond it a step would gain next to nothing.
const POLISH_SHIFT_MAX: f64 = 1e-8;

/// A step that moves the normal-map point by at most this fraction of its size (at least 1)
/// leaves the iterate where it was ([`PathSettings::frozen_steps`]): 4 500 ulps, far below any
/// step that makes progress and above the ~1e-13 steps of a proximal path at a fold
/// (`057_union_tip` of seed 20270102, step 188).
pub const FROZEN_STEP: f64 = 1e-12;

/// Pivots per unknown a Lemke path of the first attempt may make while it has a pivot budget
/// (`PathSettings::first_attempt_pivots`). A path that ends (a solution, a ray, a singular
/// basis) does so within about one pivot per unknown, and the others cycle to any cap: in the
/// PATH runs of seeds 20270123 and 20270130 (`docs/stress.md`), 99.9 % of 196 589 ending paths
/// within 0.83 pivots per unknown, 5 of them above 3 (at most 8.6), while the 806 paths cut at
/// the former cap of 10 per unknown made 41–57 % of all pivots and the longest steps (0.5–3 s).
/// A path stopped at the cap still gives its partial path (`docs/path.md`, 038).
const FIRST_ATTEMPT_PATH_PIVOTS: usize = 3;

/// Pivots per unknown a Lemke path may make outside the first attempt's budget (the later
/// attempts; every attempt when `PathSettings::first_attempt_pivots` is 0), instead of Lemke's
/// own limit of 50 per unknown: on the same seeds the later attempts' ending paths end within
/// 1.3 per unknown, and their paths that ran to 50 per unknown made `014_convex_toss` step 15
/// of seed 20270130 cost 67 700 pivots and 196 iterations, where 10 per unknown solve it in
/// 5 900 and 57 (`docs/path.md#lemke-paths-that-run-to-the-cap`).
const LATER_ATTEMPT_PATH_PIVOTS: usize = 10;

/// A chord step of the polish (a step on a kept LU) is kept when it lowers the natural residual
/// by at least this factor (below `polish_below · tolerance`: when it lowers it at all).
const POLISH_CHORD_CONTRACTION: f64 = 1e-2;

/// Chord steps per polish at most (the chord's polish included); then full steps.
const POLISH_CHORD_STEPS: usize = 4;

/// The chord's polish (one more chord step after one that ended below `polish_below ·
/// tolerance`) is taken only above this fraction of that bound: below it the point is at
/// round-off (a chord step contracts by its rate, so the next one moves it by less).
const POLISH_CHORD_FLOOR: f64 = 1e-2;

/// A predicted start ([`McpSolver::set_start_predicted`]) is returned as it stands when its
/// natural residual is within this many units of round-off of `‖z‖∞` (Newton's
/// `NewtonSettings::chord_round_off_floor` default).
const START_ROUND_OFF_ULPS: f64 = 4.0;

/// Whether the natural residual `r` at `z` is at the round-off floor of `z`
/// ([`START_ROUND_OFF_ULPS`]).
fn at_round_off(r: f64, z: &[f64]) -> bool {
    let scale = z.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    r <= START_ROUND_OFF_ULPS * f64::EPSILON * scale
}

/// A full crash step that lowers the natural residual by this factor is followed by a chord
/// step on its LU (as Newton's `chord_contraction`): close enough to the solution that the
/// Jacobian's change over the step is small. A step that gains less (far from the solution, or
/// across a kink) keeps the full steps.
const CRASH_CHORD_CONTRACTION: f64 = 1e-3;

/// A point of the iteration: normal-map point `x`, `z = π(x)`, `F(z)`, merit `‖F_N(x)‖₂`.
#[derive(Clone, Debug, Default)]
struct Point {
    x: Vec<f64>,
    z: Vec<f64>,
    f: Vec<f64>,
    merit: f64,
    /// Scratch of [`normal_point`]: the squares of `F_N`'s components, summed in order after
    /// the branch-free pass.
    squares: Vec<f64>,
    /// The natural residual of `z` and `f` once taken ([`Point::natural_residual`]; `None`
    /// after each evaluation): the step tests and the acceptance of a point share it.
    residual: Option<f64>,
}

impl Point {
    fn resize(&mut self, n: usize) {
        self.x.resize(n, 0.0);
        self.z.resize(n, 0.0);
        self.f.resize(n, 0.0);
        self.squares.resize(n, 0.0);
    }
    fn copy_from(&mut self, other: &Point) {
        self.x.copy_from_slice(&other.x);
        self.z.copy_from_slice(&other.z);
        self.f.copy_from_slice(&other.f);
        self.merit = other.merit;
        self.residual = other.residual;
    }
    /// `‖z − mid(l, u, z − F)‖∞`, taken once per evaluation.
    fn natural_residual(&mut self, l: &[f64], u: &[f64]) -> f64 {
        *self
            .residual
            .get_or_insert_with(|| natural_residual(&self.z, &self.f, l, u))
    }
}

/// Where the crash target's `J_II` comes from in the stored Jacobian: for each inactive column
/// in `inactive`'s order, the stored entries of its inactive rows (position in the values, row
/// in `J_II`) in the order stored. Built for one pattern (held, so its address cannot be
/// reused) and one inactive set, and kept while both are the same: the active set seldom
/// changes within a solve or from one step to the next, and the gather then needs neither the
/// rows' slots nor a test per stored entry (`docs/latency.md`, branch wip-pathfree).
#[derive(Default)]
struct GatherMap {
    pattern: Option<Arc<CscPattern>>,
    inactive: Vec<usize>,
    /// `(position, row)` of `J_II`'s stored entries, column after column, each column padded
    /// to a multiple of four entries by repeating its last.
    entries: Vec<(usize, usize)>,
    /// Column `k` has `quads[k]` fours of `entries`.
    quads: Vec<usize>,
    /// The pattern's stored entries when built: every position is below it (the gather's
    /// unchecked reads rest on it, [`gather_reduced`]).
    nnz: usize,
}

impl GatherMap {
    /// Whether the map is built for `pattern` (the problem's `arc`) and `inactive`.
    fn holds(&self, arc: &Arc<CscPattern>, pattern: &CscPattern, inactive: &[usize]) -> bool {
        std::ptr::eq(&**arc, pattern)
            && self.pattern.as_ref().is_some_and(|p| Arc::ptr_eq(p, arc))
            && self.inactive == inactive
    }

    /// Builds the map for `inactive` (ascending) from `slot` (each variable's row in `J_II`,
    /// `usize::MAX` for an active one); kept for `arc` when it is `pattern`'s.
    fn build(
        &mut self,
        arc: &Arc<CscPattern>,
        pattern: &CscPattern,
        inactive: &[usize],
        slot: &[usize],
    ) {
        self.pattern = std::ptr::eq(&**arc, pattern).then(|| Arc::clone(arc));
        self.inactive.clear();
        self.inactive.extend_from_slice(inactive);
        self.entries.clear();
        self.quads.clear();
        self.nnz = pattern.nnz();
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        for &j in inactive {
            let first = self.entries.len();
            for q in cp[j]..cp[j + 1] {
                let r = slot[ri[q]];
                if r != usize::MAX {
                    self.entries.push((q, r));
                }
            }
            // Padded to whole fours by the column's last entry again (the same value written
            // to the same place, its magnitude already counted): the gather's loop then has no
            // remainder, whose varying length per column was mispredicted.
            if let Some(&last) = self.entries[first..].last() {
                while !(self.entries.len() - first).is_multiple_of(4) {
                    self.entries.push(last);
                }
            }
            self.quads.push((self.entries.len() - first) / 4);
        }
    }
}

/// What an LU kept across solves was formed for ([`PathSettings::chord_across_solves`]).
struct KeptKey {
    /// Solved as given (not in the scene scales).
    as_given: bool,
    pattern: Arc<CscPattern>,
}

/// Counters reported in the summary.
#[derive(Clone, Copy, Debug, Default)]
struct Counters {
    pivots: usize,
    crash_steps: usize,
    path_steps: usize,
    nonmonotone_steps: usize,
    watchdog_restores: usize,
    proximal_perturbations: usize,
    path_backtracks: usize,
    ray_terminations: usize,
    restarts: usize,
    guarded_attempts: usize,
    fischer_attempts: usize,
    best_point_restarts: usize,
    time_limit_reached: usize,
}

/// What a solve accumulates over its attempts.
struct Run {
    trace: Vec<IterationRecord>,
    counters: Counters,
    f_evals: usize,
    jac_evals: usize,
    iterations: usize,
    best_residual: f64,
}

/// The next proximal perturbation: the first one, or the last one grown.
fn next_lambda(lambda: f64, s: &PathSettings, scale: f64) -> f64 {
    if lambda == 0.0 {
        s.proximal_initial * scale
    } else {
        lambda * s.proximal_growth
    }
}

/// The PATH-like backend. Keep one instance for a whole simulation: it reuses its buffers and
/// the pivotal solver's workspace.
pub struct PathSolver {
    settings: PathSettings,
    lemke: Lemke,
    path: PivotPath,
    current: Point,
    trial: Point,
    checkpoint: Point,
    best_z: Vec<f64>,
    /// `F` at `best_z` (the final residuals need no evaluation of their own).
    best_f: Vec<f64>,
    /// The best point so far is `current` itself, not yet copied into `best_z` and `best_f`
    /// ([`PathSolver::keep_best`]): a run of ever better points (the desk's every step) copies
    /// only the last one.
    best_in_current: bool,
    jac: Vec<f64>,
    /// The Jacobian at `trial`, evaluated by the acceptance test; it becomes `jac` when the
    /// trial is accepted.
    trial_jac: Vec<f64>,
    /// Whether `trial_jac` holds the Jacobian at `trial` (not needed at a converged trial).
    trial_has_jac: bool,
    q: Vec<f64>,
    jz: Vec<f64>,
    step_x: Vec<f64>,
    /// Row of the reduced crash system of each variable (`usize::MAX` when not in it).
    reduced_slot: Vec<usize>,
    /// The gather of `J_II` ([`GatherMap`]), kept while the pattern and the inactive set are
    /// the same.
    gather: GatherMap,
    /// Right-hand side and solution of the reduced crash system.
    crash_rhs: Vec<f64>,
    rhs: Vec<f64>,
    inactive: Vec<usize>,
    active_prev: Vec<i8>,
    active: Vec<i8>,
    /// The LU of the last crash target's reduced matrix (`J_II + shift·I`, rows and columns in
    /// `inactive`'s order, for the active set in `active`).
    factor: ColumnTestedLu,
    /// The components of `factor`'s rows (`inactive`) in the order of its row interchanges
    /// ([`ColumnTestedLu::row_order`]): the crash and chord steps gather their right-hand
    /// sides by it.
    crash_order: Vec<usize>,
    /// `factor` holds the LU of the reduced matrix of a crash target that was taken as a full
    /// step (`t = 1`) in this attempt, with no path step since: the polish may take chord steps
    /// on it ([`PathSolver::chord_target`]).
    kept_lu: bool,
    /// The last crash step was accepted without the Jacobian at its point: a chord step is to
    /// follow ([`PathSolver::crash_step`]).
    jac_deferred: bool,
    /// The key of the LU kept from the last solve ([`PathSettings::chord_across_solves`]):
    /// `factor`, `active` and `inactive` are its crash target's when `Some`.
    kept_key: Option<KeptKey>,
    /// The scales of the kept LU's system (`d_x` then `d_f`; empty as given).
    kept_scales: Vec<f64>,
    /// The next attempt may start on the LU kept from the last solve.
    lu_from_last_solve: bool,
    observer: Option<Box<dyn Observer>>,
    /// End of the current solve's wall-clock budget (`PathSettings::time_limit`).
    deadline: Option<Instant>,
    /// Pivots an attempt may make (`PathSettings::first_attempt_pivots`); `None` for no limit.
    pivot_budget: Option<usize>,
    /// The current attempt judges points by the Fischer–Burmeister merit
    /// ([`PathSettings::fischer_restart`]).
    fischer: bool,
    /// The storage of the caller's result ([`McpSolver::solve_into`]), which the next run's
    /// result is written into (empty otherwise: `solve` allocates its result).
    result: Solution,
    /// The iteration budget of the next solves ([`McpSolver::set_iteration_budget`]).
    iteration_budget: Option<usize>,
    /// The next solves' starts are predictions ([`McpSolver::set_start_predicted`]).
    start_predicted: bool,
    /// The dimension and Jacobian entries the buffers were last sized for
    /// ([`PathSolver::resize`]).
    sized: Option<(usize, usize)>,
}

impl PathSolver {
    /// Makes the trial point current and returns its natural residual, keeping the best point
    /// seen (shared by crash and path steps). The trial's Jacobian, when the acceptance test
    /// evaluated it, becomes the current one (see [`PathSolver::trial_usable`]).
    fn accept_trial(&mut self, l: &[f64], u: &[f64], best_residual: &mut f64) -> f64 {
        std::mem::swap(&mut self.current, &mut self.trial);
        if self.trial_has_jac {
            std::mem::swap(&mut self.jac, &mut self.trial_jac);
        }
        let residual = self.current.natural_residual(l, u);
        if residual < *best_residual {
            *best_residual = residual;
            self.best_in_current = true;
        } else if self.best_in_current {
            // The point before (in `trial` now, until the next evaluation) stays the best.
            self.best_z.copy_from_slice(&self.trial.z);
            self.best_f.copy_from_slice(&self.trial.f);
            self.best_in_current = false;
        }
        residual
    }

    /// Copies the best point into `best_z` and `best_f` where it is still `current` only
    /// ([`PathSolver::best_in_current`]), before `current` is overwritten.
    fn keep_best(&mut self) {
        if self.best_in_current {
            self.best_z.copy_from_slice(&self.current.z);
            self.best_f.copy_from_slice(&self.current.f);
            self.best_in_current = false;
        }
    }

    /// The best point of the attempts so far and `F` there: `best_z` and `best_f`, or
    /// `current`'s while it is the best ([`PathSolver::best_in_current`]).
    fn best_point(&self) -> (&[f64], &[f64]) {
        if self.best_in_current {
            (&self.current.z, &self.current.f)
        } else {
            (&self.best_z, &self.best_f)
        }
    }

    /// Takes the trial point as a crash step of length `t` (a chord step has 1): recorded for
    /// the observer and the trace, counted as an iteration and a crash step, and made current
    /// ([`PathSolver::accept_trial`]); returns its natural residual. The record (and the
    /// step's norm, which only it uses) is skipped when neither the trace (`traced`) nor an
    /// observer takes it.
    #[allow(clippy::too_many_arguments)]
    fn take_crash_step(
        &mut self,
        t: f64,
        residual: f64,
        iterations: &mut usize,
        counters: &mut Counters,
        (l, u, best_residual): (&[f64], &[f64], &mut f64),
        traced: bool,
        record: &mut impl FnMut(usize, f64, f64, StepKind, f64, f64, &mut Option<Box<dyn Observer>>),
    ) -> f64 {
        if traced || self.observer.is_some() {
            let norm = norm_inf_diff(&self.trial.x, &self.current.x);
            record(
                *iterations,
                residual,
                self.current.merit,
                StepKind::Crash,
                t,
                norm,
                &mut self.observer,
            );
        }
        *iterations += 1;
        counters.crash_steps += 1;
        self.accept_trial(l, u, best_residual)
    }

    /// A solver with the given settings.
    pub fn new(settings: PathSettings) -> Self {
        let lemke = Lemke::new(settings.lemke.clone());
        PathSolver {
            settings,
            lemke,
            path: PivotPath::new(),
            current: Point::default(),
            trial: Point::default(),
            checkpoint: Point::default(),
            best_z: Vec::new(),
            best_f: Vec::new(),
            best_in_current: false,
            jac: Vec::new(),
            trial_jac: Vec::new(),
            trial_has_jac: false,
            q: Vec::new(),
            jz: Vec::new(),
            step_x: Vec::new(),
            reduced_slot: Vec::new(),
            gather: GatherMap::default(),
            crash_rhs: Vec::new(),
            rhs: Vec::new(),
            inactive: Vec::new(),
            active_prev: Vec::new(),
            active: Vec::new(),
            result: Solution::default(),
            factor: ColumnTestedLu::new(),
            crash_order: Vec::new(),
            kept_lu: false,
            jac_deferred: false,
            kept_key: None,
            kept_scales: Vec::new(),
            lu_from_last_solve: false,
            observer: None,
            deadline: None,
            pivot_budget: None,
            fischer: false,
            iteration_budget: None,
            start_predicted: false,
            sized: None,
        }
    }
    /// Whether the wall-clock budget of the current solve is spent.
    fn out_of_time(&self) -> bool {
        self.deadline.is_some_and(|d| Instant::now() >= d)
    }

    /// Attaches an observer that sees every iteration.
    pub fn with_observer(mut self, observer: Box<dyn Observer>) -> Self {
        self.observer = Some(observer);
        self
    }
    /// The settings.
    pub fn settings(&self) -> &PathSettings {
        &self.settings
    }
    /// Mutable settings (the inner pivotal solver picks up `lemke` at the next solve).
    pub fn settings_mut(&mut self) -> &mut PathSettings {
        &mut self.settings
    }

    fn resize(&mut self, n: usize, nnz: usize) {
        // Every solve of a simulation has the same sizes: nothing to do then.
        if self.sized == Some((n, nnz)) {
            return;
        }
        self.sized = Some((n, nnz));
        self.current.resize(n);
        self.trial.resize(n);
        self.checkpoint.resize(n);
        for v in [
            &mut self.best_z,
            &mut self.best_f,
            &mut self.q,
            &mut self.jz,
            &mut self.step_x,
            &mut self.rhs,
        ] {
            v.resize(n, 0.0);
        }
        self.jac.resize(nnz, 0.0);
        self.trial_jac.resize(nnz, 0.0);
        self.active.resize(n, 0);
        self.active_prev.resize(n, 0);
    }
}

/// The normal-map point of `z` with the smallest merit, and that merit `‖F_N(x)‖₂`:
/// `x_i = l_i − F_i` where `z_i = l_i` and `F_i > 0`, `x_i = u_i − F_i` where `z_i = u_i` and
/// `F_i < 0`, `x_i = z_i` elsewhere. Non-finite `F` gives `+∞`.
///
/// Two passes: `x` and the squares of `F_N = F + x − z` without a branch per component (the
/// bounds' tests select, so the loop runs in vector lanes; the branches it replaces were
/// mispredicted often enough to make this one of PATH's larger items in time, `docs/latency.md`,
/// branch wip-path), then the squares summed in component order from `0.0`: the same numbers
/// as the loop with `s += c · c`, bit for bit.
fn normal_point(p: &mut Point, l: &[f64], u: &[f64]) {
    let n = p.z.len();
    let Point {
        x, z, f, squares, ..
    } = p;
    let z = &z[..];
    normal_point_squares(&mut x[..n], &mut squares[..n], z, &f[..n], &l[..n], &u[..n]);
    let s = squares[..n].iter().fold(0.0, |s, c2| s + c2);
    p.merit = if s.is_finite() {
        s.sqrt()
    } else {
        f64::INFINITY
    };
}

/// [`normal_point`]'s first pass, compiled for AVX2 where the processor has it (the same
/// operations on the same numbers in either build: each lane is one component's).
fn normal_point_squares(x: &mut [f64], sq: &mut [f64], z: &[f64], f: &[f64], l: &[f64], u: &[f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2.
        unsafe { normal_point_squares_avx2(x, sq, z, f, l, u) };
        return;
    }
    normal_point_squares_with(x, sq, z, f, l, u);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn normal_point_squares_avx2(
    x: &mut [f64],
    sq: &mut [f64],
    z: &[f64],
    f: &[f64],
    l: &[f64],
    u: &[f64],
) {
    normal_point_squares_with(x, sq, z, f, l, u);
}

#[inline(always)]
fn normal_point_squares_with(
    x: &mut [f64],
    sq: &mut [f64],
    z: &[f64],
    f: &[f64],
    l: &[f64],
    u: &[f64],
) {
    for ((x, sq), ((&z, &f), (&l, &u))) in
        (x.iter_mut().zip(sq.iter_mut())).zip(z.iter().zip(f).zip(l.iter().zip(u)))
    {
        // `&` and selects, not `&&` and branches.
        let at_lower = (z <= l) & (f > 0.0);
        let at_upper = (z >= u) & (f < 0.0);
        let xl = l - f;
        let xu = u - f;
        let v = if at_lower {
            xl
        } else if at_upper {
            xu
        } else {
            z
        };
        *x = v;
        let c = f + v - z;
        *sq = c * c;
    }
}

/// Evaluates `F` at `z = π(x)` for the point's `x`, and sets its normal-map point and merit
/// (the Fischer–Burmeister merit `‖Φ_FB(z)‖₂` instead when `fischer`).
fn evaluate_at(mcp: &dyn Mcp, p: &mut Point, f_evals: &mut usize, fischer: bool) {
    evaluate_projected(mcp, p, f_evals, fischer, None);
}

/// [`evaluate_at`], or at an attempt's start `z = π(z0)` when `start` is `Some(z0)`: then `F`
/// is taken from the problem where it holds it for that `z` already (`Mcp::known_value`: a time
/// step's warm start, whose guard evaluated `F` there; the same bits as evaluating it), and the
/// point is as if `x` had been set to `z0` first. Counted as an evaluation either way.
fn evaluate_projected(
    mcp: &dyn Mcp,
    p: &mut Point,
    f_evals: &mut usize,
    fischer: bool,
    start: Option<&[f64]>,
) {
    let (l, u) = (mcp.lower(), mcp.upper());
    let n = p.x.len();
    // From the start `z0` itself, not from a copy of it in `x`: where `F` is finite, the
    // normal point overwrites every component of `x` anyway.
    let from = start.unwrap_or(&p.x);
    project(&mut p.z[..n], &from[..n], &l[..n], &u[..n]);
    match start.and_then(|_| mcp.known_value(&p.z)) {
        Some(f) => p.f.copy_from_slice(f),
        None => mcp.evaluate(&p.z, &mut p.f),
    }
    p.residual = None;
    *f_evals += 1;
    if all_finite(&p.f) {
        normal_point(p, l, u);
        if fischer {
            let s: f64 = (0..p.z.len())
                .map(|i| fb_component(p.z[i], p.f[i], l[i], u[i]).powi(2))
                .sum();
            p.merit = if s.is_finite() {
                s.sqrt()
            } else {
                f64::INFINITY
            };
        }
    } else {
        // `x` as the caller set it, the start where it came from there.
        if let Some(z0) = start {
            p.x.copy_from_slice(z0);
        }
        p.merit = f64::INFINITY;
    }
}

/// [`crate::pivot::all_finite`] compiled for AVX2 where the processor has it: four lanes per
/// instruction instead of two on the Jacobian's 400 entries the desk tests every step. The
/// verdict does not depend on the order of the sums (any NaN term makes the sum NaN).
fn all_finite(values: &[f64]) -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2.
        return unsafe { all_finite_avx2(values) };
    }
    crate::pivot::all_finite(values)
}

/// [`all_finite`] with AVX2: sixteen entries a turn in four registers (one chain of vector
/// adds, three cycles each, through the Jacobian's 400 entries held the test up), then four,
/// then one at a time. Only called where the processor runs AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn all_finite_avx2(values: &[f64]) -> bool {
    use std::arch::x86_64::*;
    let n = values.len();
    let p = values.as_ptr();
    let zero = _mm256_setzero_pd();
    let (mut a0, mut a1, mut a2, mut a3) = (zero, zero, zero, zero);
    let mut i = 0;
    // SAFETY: every load is at `i .. i + 3 < n` (or `i + 15 < n`), within `values`; unaligned
    // loads need no alignment.
    unsafe {
        while i + 16 <= n {
            a0 = _mm256_add_pd(a0, _mm256_mul_pd(_mm256_loadu_pd(p.add(i)), zero));
            a1 = _mm256_add_pd(a1, _mm256_mul_pd(_mm256_loadu_pd(p.add(i + 4)), zero));
            a2 = _mm256_add_pd(a2, _mm256_mul_pd(_mm256_loadu_pd(p.add(i + 8)), zero));
            a3 = _mm256_add_pd(a3, _mm256_mul_pd(_mm256_loadu_pd(p.add(i + 12)), zero));
            i += 16;
        }
        while i + 4 <= n {
            a0 = _mm256_add_pd(a0, _mm256_mul_pd(_mm256_loadu_pd(p.add(i)), zero));
            i += 4;
        }
    }
    let a = _mm256_add_pd(_mm256_add_pd(a0, a1), _mm256_add_pd(a2, a3));
    let mut lanes = [0.0f64; 4];
    // SAFETY: `lanes` has room for the four lanes stored.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), a) };
    let rest = values[i..].iter().fold(0.0, |a, v| a + v * 0.0);
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]) + rest == 0.0
}

/// The crash target's `J_II` from the stored Jacobian `jac` by `map` (built for this pattern and
/// inactive set) into `reduced` (`ni × ni`, column after column, `ni = map.inactive.len()`),
/// and each column's largest magnitude into `norms`. `jac` is finite (tested before).
///
/// The storage is zeroed in one pass of vector stores, then the stored entries are scattered
/// by unchecked reads: the column-by-column `fill` (a `memset` call per column) and the two
/// bounds checks per entry were about a third of the crash target's instructions
/// (`docs/latency.md`, branch wip-path of the fifteenth session). The same values land in the
/// same places, and the largest magnitudes are the same numbers.
fn gather_reduced(reduced: &mut [f64], norms: &mut [f64], map: &GatherMap, jac: &[f64]) {
    let ni = map.inactive.len();
    // What the unchecked reads and writes below rest on: every row in the map is below `ni`
    // (rows of `J_II`), every position below `map.nnz` (positions of the pattern's entries).
    assert!(
        reduced.len() == ni * ni
            && norms.len() == ni
            && map.quads.len() == ni
            && jac.len() >= map.nnz,
        "gather map of another system"
    );
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2; the map's bounds are checked above.
        unsafe { gather_reduced_avx2(reduced, norms, map, jac) };
        return;
    }
    // SAFETY: the map's bounds are checked above.
    unsafe { gather_reduced_with(reduced, norms, map, jac) };
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gather_reduced_avx2(
    reduced: &mut [f64],
    norms: &mut [f64],
    map: &GatherMap,
    jac: &[f64],
) {
    // SAFETY: the caller's.
    unsafe { gather_reduced_with(reduced, norms, map, jac) };
}

/// [`gather_reduced`]'s body.
///
/// # Safety
/// `map`'s rows are below `norms.len()` (`ni`), its positions below `jac.len()`, and `reduced`
/// is `ni × ni`.
#[inline(always)]
unsafe fn gather_reduced_with(
    reduced: &mut [f64],
    norms: &mut [f64],
    map: &GatherMap,
    jac: &[f64],
) {
    let ni = norms.len();
    // A zero the compiler cannot see: a loop storing a known zero becomes a `memset` call
    // (a `rep stosb` over `ni²` entries, or one call per column), this one vector stores.
    let zero = std::hint::black_box(0.0f64);
    for v in reduced.iter_mut() {
        *v = zero;
    }
    // The columns' entries in whole fours, one after the other ([`GatherMap::build`]).
    let mut quads = map.entries.chunks_exact(4);
    for ((col, norm), &count) in (reduced.chunks_exact_mut(ni))
        .zip(norms.iter_mut())
        .zip(&map.quads)
    {
        // `J` is finite here: one `maxsd` per entry, not `f64::max`'s NaN tests. Four running
        // maxima, not one: one chain of `maxsd` (four cycles each) through a column's entries
        // held up the loop. The largest of non-negative finite numbers is the same number in
        // any order.
        let mut m = [0.0f64; 4];
        for e in quads.by_ref().take(count) {
            for (m, &(q, r)) in m.iter_mut().zip(e) {
                // SAFETY: `q < jac.len()`, `r < ni = col.len()` (the map's).
                let v = unsafe { *jac.get_unchecked(q) };
                unsafe { *col.get_unchecked_mut(r) = v };
                let a = v.abs();
                *m = if a > *m { a } else { *m };
            }
        }
        let larger = |a: f64, b: f64| if a > b { a } else { b };
        *norm = larger(larger(m[0], m[1]), larger(m[2], m[3]));
    }
}

/// `z = mid(l, u, x)` component by component, compiled for AVX2 where the processor has it
/// (four lanes per instruction instead of two; `mid` is the same function on the same numbers
/// in either build).
fn project(z: &mut [f64], x: &[f64], l: &[f64], u: &[f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2.
        unsafe { project_avx2(z, x, l, u) };
        return;
    }
    project_with(z, x, l, u);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn project_avx2(z: &mut [f64], x: &[f64], l: &[f64], u: &[f64]) {
    project_with(z, x, l, u);
}

#[inline(always)]
fn project_with(z: &mut [f64], x: &[f64], l: &[f64], u: &[f64]) {
    // Zipped slices: no bounds check per component.
    for ((z, &x), (&l, &u)) in z.iter_mut().zip(x).zip(l.iter().zip(u)) {
        *z = mid(l, u, x);
    }
}

fn norm_inf_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

impl PathSolver {
    /// The second half of the acceptance test of a trial point whose merit is finite: unless
    /// the trial already solves the problem to `tolerance`, its Jacobian (needed for the next
    /// step) is evaluated into `trial_jac` and must be finite. A trial where it is not fails
    /// like one without enough decrease.
    fn trial_usable(&mut self, mcp: &dyn Mcp, tolerance: f64, jac_evals: &mut usize) -> bool {
        self.trial_has_jac = false;
        if !self.trial.merit.is_finite() {
            return false;
        }
        let (l, u) = (mcp.lower(), mcp.upper());
        if self.trial.natural_residual(l, u) <= tolerance {
            return true;
        }
        mcp.jacobian(&self.trial.z, &mut self.trial_jac);
        *jac_evals += 1;
        self.trial_has_jac = all_finite(&self.trial_jac);
        self.trial_has_jac
    }

    /// The Jacobian at a point accepted without it (a crash step that put it off for a chord
    /// step, [`PathSolver::crash_step`]), evaluated into `self.jac` once the chord steps are
    /// over. Where it is finite, `true`. Where it is not, the full step's acceptance test
    /// ([`PathSolver::trial_usable`]) would have refused the point: the iteration goes back to
    /// the point before that step (kept in `checkpoint`, its Jacobian finite but no longer in
    /// `self.jac`), `residual` becomes its natural residual, and `false` is returned. The best
    /// point kept so far is left as it is (its `F` is finite, which is all it needs).
    fn settle_deferred_jacobian(
        &mut self,
        mcp: &dyn Mcp,
        residual: &mut f64,
        jac_evals: &mut usize,
    ) -> bool {
        mcp.jacobian(&self.current.z, &mut self.jac);
        *jac_evals += 1;
        if all_finite(&self.jac) {
            return true;
        }
        self.keep_best();
        self.current.copy_from(&self.checkpoint);
        *residual = self.current.natural_residual(mcp.lower(), mcp.upper());
        false
    }

    /// One projected Newton step of the crash phase from `self.current` (whose Jacobian is in
    /// `self.jac`): Newton on the variables left inside by `π(z − F)`, the others fixed at their
    /// bounds, then a projected backtracking search. Returns the accepted step length.
    fn crash_step(
        &mut self,
        mcp: &dyn Mcp,
        pattern: &CscPattern,
        tolerance: f64,
        residual: f64,
        f_evals: &mut usize,
        jac_evals: &mut usize,
    ) -> Option<f64> {
        self.jac_deferred = false;
        if !self.crash_target(mcp, pattern, 0.0) {
            return None;
        }
        let n = mcp.dim();
        // Projected arc z(t) = π(z + t (target − z)), accepted on the path-search test.
        let sigma = self.settings.sufficient_decrease;
        let mut t = 1.0;
        for _ in 0..6 {
            for ((x, &z), &b) in (self.trial.x[..n].iter_mut())
                .zip(&self.current.z[..n])
                .zip(&self.step_x[..n])
            {
                *x = z + t * (b - z);
            }
            evaluate_at(mcp, &mut self.trial, f_evals, self.fischer);
            if self.trial.merit <= (1.0 - sigma * t) * self.current.merit {
                // A full step that contracted the residual fast: the next step is a chord step
                // on this LU, which needs no Jacobian at the trial. The current point (whose
                // Jacobian is finite) is kept in `checkpoint` (by the caller, once the trial is
                // taken) in case that Jacobian, evaluated only when the chord step is refused,
                // is not finite.
                // Only with the polish on: `polish_below = 1` is PATH before it, bit for bit.
                if t == 1.0
                    && self.kept_lu
                    && self.settings.polish_below < 1.0
                    && self.trial.merit.is_finite()
                {
                    let (l, u) = (mcp.lower(), mcp.upper());
                    let r = self.trial.natural_residual(l, u);
                    if r > tolerance && r <= CRASH_CHORD_CONTRACTION * residual {
                        self.trial_has_jac = false;
                        self.jac_deferred = true;
                        return Some(t);
                    }
                }
                if self.trial_usable(mcp, tolerance, jac_evals) {
                    // A shortened step leaves the kept LU's point far behind: no chord steps.
                    self.kept_lu &= t == 1.0;
                    return Some(t);
                }
            }
            t *= 0.5;
        }
        None
    }

    /// The target of a projected Newton step from `self.current` (whose Jacobian is in
    /// `self.jac`) into `self.step_x`: the variables left inside by `π(z − F)` by Newton's
    /// equations with `J_II + shift·I` (a proximal term; `0` for Newton's own), the others at
    /// their bounds. `false` when that reduced matrix is singular or the step is not finite.
    fn crash_target(&mut self, mcp: &dyn Mcp, pattern: &CscPattern, shift: f64) -> bool {
        self.kept_lu = false;
        let n = mcp.dim();
        let (l, u) = (mcp.lower(), mcp.upper());
        let cur = &self.current;
        // Active set from the projection π(z − F): −1 lower, +1 upper, 0 inside. Target: active
        // components at their bounds; inactive ones by the reduced Newton system
        // J_II Δ_I = −F_I − J_IA (b_A − z_A). One pass over zipped slices (no bounds checks,
        // the fields not reloaded per component). The inactive components are listed by
        // writing every index and advancing past the inactive ones (no `push`, whose length
        // and capacity were reloaded from `self` per component).
        self.inactive.resize(n, 0);
        let listed = &mut self.inactive[..n];
        let mut ni = 0;
        // The bits of every `b − z`, or-ed.
        let mut bits = 0u64;
        let cur_zf = cur.z[..n].iter().zip(&cur.f[..n]);
        let targets = (self.active[..n].iter_mut())
            .zip(&mut self.step_x[..n])
            .zip(&mut self.jz[..n]);
        for (i, (((active, target), jz), ((&z, &f), (&li, &ui)))) in targets
            .zip(cur_zf.zip(l[..n].iter().zip(&u[..n])))
            .enumerate()
        {
            let y = z - f;
            let (kind, b) = if y <= li {
                (-1, li)
            } else if y >= ui {
                (1, ui)
            } else {
                (0, z)
            };
            // `ni <= i < n`.
            listed[ni] = i;
            ni += usize::from(kind == 0);
            *active = kind;
            *target = b;
            let d = b - z;
            *jz = d;
            bits |= d.to_bits();
        }
        // Some `b − z` other than `±0` (a NaN included): a bit set besides the sign's.
        let moves = bits << 1 != 0;
        self.inactive.truncate(ni);
        if ni > 0 {
            // rhs = −F − J (b − z), restricted to I (`b − z` is zero on I and wherever z is at
            // its bound already, so most columns are skipped). Where no component moves to
            // its bound (the desk's every step), `J (b − z)` is `+0` throughout and
            // `−F_i − (+0)` is `−F_i` bit for bit: neither the product nor its zeroing is
            // needed.
            if moves {
                mul_vec_nonzero_columns(pattern, &self.jac, &self.jz, &mut self.rhs);
            }
            // J_II gathered straight from the pattern (no dense copy of the whole J), by the
            // map of this pattern and inactive set.
            let arc = mcp.jacobian_pattern();
            if !self.gather.holds(arc, pattern, &self.inactive) {
                self.reduced_slot.clear();
                self.reduced_slot.resize(n, usize::MAX);
                for (k, &i) in self.inactive.iter().enumerate() {
                    self.reduced_slot[i] = k;
                }
                self.gather
                    .build(arc, pattern, &self.inactive, &self.reduced_slot);
            }
            // Straight into the LU's storage, with each column's largest magnitude, the scale
            // of the dependence test.
            let (reduced, norms) = self.factor.storage_mut(ni);
            gather_reduced(reduced, norms, &self.gather, &self.jac);
            if shift != 0.0 {
                for (k, (col, norm)) in reduced
                    .chunks_exact_mut(ni)
                    .zip(norms.iter_mut())
                    .enumerate()
                {
                    col[k] += shift;
                    *norm = col.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                }
            }
            if self.factor.factor(DEPENDENCE_TOLERANCE).is_err() {
                return false;
            }
            self.factor.row_order(&self.inactive, &mut self.crash_order);
            if !self.reduced_newton_step(moves, false) {
                return false;
            }
        }
        self.kept_lu = true;
        true
    }

    /// The target of a chord step from `self.current` into `self.step_x`: the crash target's
    /// equations `J_II Δ_I = −F_I` with the kept LU of an earlier point's `J_II`
    /// (`self.factor`, [`PathSolver::kept_lu`]) instead of the current one, so no Jacobian and
    /// no factorisation. Taken only where it is that target's own system: the projection
    /// `π(z − F)` leaves the same variables inside as where the LU was formed, and every other
    /// one is at its bound already (so `J_IA (b_A − z_A) = 0`). `false` otherwise, or when the
    /// step is not finite. Its convergence is linear (rate `‖J₀⁻¹(J − J₀)‖`), so the polish
    /// keeps a chord step only on a test of its own residual.
    fn chord_target(&mut self, mcp: &dyn Mcp) -> bool {
        if !self.kept_lu {
            return false;
        }
        let n = mcp.dim();
        let (l, u) = (mcp.lower(), mcp.upper());
        let cur = &self.current;
        // The test and the trial's `x = z` (its active components; the step writes the
        // others) in one pass, not a test and then a copy: the trial is written afresh before
        // it is evaluated when the chord step is refused.
        let mut same = true;
        for ((x, (&active, (&z, &f))), (&l, &u)) in (self.trial.x[..n].iter_mut())
            .zip(
                self.active[..n]
                    .iter()
                    .zip(cur.z[..n].iter().zip(&cur.f[..n])),
            )
            .zip(l[..n].iter().zip(&u[..n]))
        {
            let y = z - f;
            same &= match active {
                -1 => (y <= l) & (z == l),
                1 => (y >= u) & (z == u),
                _ => (y > l) & (y < u),
            };
            *x = z;
        }
        if !same {
            return false;
        }
        self.reduced_newton_step(false, true)
    }

    /// The inactive components of a crash or chord target: `x_I = z_I + Δ_I` with
    /// `J_II Δ_I = −F_I − r_I` on the LU in `self.factor`, where `r = self.rhs` (`J (b − z)`)
    /// when `with_rhs`, else 0 (a chord step: every active component is at its bound already),
    /// into `self.trial.x` when `into_trial` (a chord step's point), else into `self.step_x`.
    /// `false`, leaving `x_I` as it was, when `Δ` is not finite.
    fn reduced_newton_step(&mut self, with_rhs: bool, into_trial: bool) -> bool {
        let (cur, inactive) = (&self.current, &self.inactive[..]);
        // Of one length, so that one bounds check per index serves both.
        let (f, rhs) = (&cur.f[..], &self.rhs[..cur.f.len()]);
        let b = &mut self.crash_rhs;
        b.clear();
        // Gathered in the order of the LU's row interchanges (`crash_order`), so that the
        // solve does no interchanges; `Δ_I` comes back in `inactive`'s order, bitwise the
        // plain solve's.
        let order = &self.crash_order[..];
        debug_assert_eq!(order.len(), inactive.len());
        if with_rhs {
            b.extend(order.iter().map(|&i| -f[i] - rhs[i]));
        } else {
            b.extend(order.iter().map(|&i| -f[i]));
        }
        if !b.is_empty() {
            self.factor.solve_interchanged(b);
        }
        // The vector test (`all_finite`: the same verdict as a test per entry).
        let finite = all_finite(b);
        if finite {
            let z = &cur.z[..];
            let x = if into_trial {
                &mut self.trial.x[..z.len()]
            } else {
                &mut self.step_x[..z.len()]
            };
            for (&i, &d) in inactive.iter().zip(b.iter()) {
                x[i] = z[i] + d;
            }
        }
        finite
    }

    /// Solves the linearised problem at `self.current` with proximal term `lambda` and records
    /// its path in `self.path`; returns the path's reach `t_max` (0 when it failed at the start).
    fn newton_path(
        &mut self,
        pattern: &CscPattern,
        lower: &[f64],
        upper: &[f64],
        lambda: f64,
        counters: &mut Counters,
    ) -> Result<f64, PivotError> {
        let n = self.current.z.len();
        // q = F(z_k) − (J + λI) z_k, so that the affine map is F(z_k) + (J + λI)(z − z_k).
        mul_vec_nonzero_columns(pattern, &self.jac, &self.current.z, &mut self.jz);
        for i in 0..n {
            self.q[i] = self.current.f[i] - self.jz[i] - lambda * self.current.z[i];
        }
        let problem = AffineMcp {
            m: AffineMatrix::Sparse {
                pattern,
                values: &self.jac,
            },
            q: &self.q,
            lower,
            upper,
            diagonal_shift: lambda,
        };
        let result = self.lemke.trace_path(
            &problem,
            &AffineStart::NormalMap(&self.current.x),
            &mut self.path,
        );
        let reach = if self.path.is_empty() {
            0.0
        } else {
            (1.0 - self.path.min_artificial()).clamp(0.0, 1.0)
        };
        match result {
            Ok(sol) => {
                counters.pivots += sol.pivots;
                Ok(1.0)
            }
            Err(e) => {
                match &e {
                    PivotError::RayTermination { pivots, .. } => {
                        counters.ray_terminations += 1;
                        counters.pivots += pivots;
                    }
                    PivotError::MaxPivots { pivots } | PivotError::SingularBasis { pivots, .. } => {
                        counters.pivots += pivots
                    }
                    PivotError::InvalidInput(_) => {}
                }
                // A partial path that got somewhere is still a descent path (Dirkse & Ferris).
                if reach > 1e-8 && !matches!(e, PivotError::InvalidInput(_)) {
                    Ok(reach)
                } else {
                    Err(e)
                }
            }
        }
    }

    /// One attempt from `z0` with settings `s` (a restart uses modified settings), accumulating
    /// into `run`; the best point found is kept in `self.best_z`. Returns why it stopped.
    fn attempt(
        &mut self,
        mcp: &dyn Mcp,
        pattern: &CscPattern,
        z0: &[f64],
        s: &PathSettings,
        initial_lambda: f64,
        guarded: bool,
        run: &mut Run,
    ) -> Termination {
        let n = mcp.dim();
        let (l, u) = (mcp.lower(), mcp.upper());
        let Run {
            trace,
            counters,
            f_evals,
            jac_evals,
            iterations,
            best_residual,
        } = run;
        let iterations_at_start = *iterations;
        let pivots_at_start = counters.pivots;
        // The LU kept from the last solve, for the first attempt only.
        self.kept_lu = std::mem::take(&mut self.lu_from_last_solve)
            && initial_lambda == 0.0
            && !guarded
            && !self.fischer
            && s.polish_below < 1.0;

        // Start: z = π(z0), x its normal-map point; `F` there may be known already (a time
        // step's warm start).
        self.keep_best();
        evaluate_projected(mcp, &mut self.current, f_evals, self.fischer, Some(z0));
        let mut residual = self.current.natural_residual(l, u);
        if residual < *best_residual {
            *best_residual = residual;
            self.best_in_current = true;
        }
        // A predicted start (`McpSolver::set_start_predicted`) below the polish bound is not a
        // point converged to: it takes the polish unless it is at round-off.
        let mut polish_start = self.start_predicted
            && residual <= s.polish_below * s.tolerance
            && !at_round_off(residual, &self.current.z);
        let mut termination = if self.current.merit.is_finite() {
            Termination::MaxIterations
        } else {
            Termination::NonFiniteFunction
        };
        let mut have_jac = false;
        let mut record = |iteration: usize,
                          residual: f64,
                          merit: f64,
                          step: StepKind,
                          t: f64,
                          norm: f64,
                          observer: &mut Option<Box<dyn Observer>>| {
            let rec = IterationRecord {
                iteration,
                residual,
                merit,
                step,
                step_length: t,
                direction_norm: norm,
            };
            if let Some(obs) = observer.as_mut() {
                obs.observe(&rec);
            }
            if s.trace {
                trace.push(rec);
            }
        };

        // A chord step ended the crash phase within the tolerance: the polish takes one more
        // chord step even below `polish_below · tolerance` (see the polish).
        let mut chord_landed = false;
        // Crash phase: projected Newton steps while they decrease the merit and the active set
        // keeps changing.
        if termination == Termination::MaxIterations && residual > s.tolerance && n > 0 {
            self.active_prev.fill(2);
            // Set by a full crash step that contracted the residual by `CRASH_CHORD_CONTRACTION`
            // (`crash_step`): the next step is a chord step on its LU, and the Jacobian at the
            // new point is evaluated only if that chord step is refused. On the LU kept from the
            // last solve the first step is a chord step, from the start (kept in `checkpoint`).
            let mut chord_next = self.kept_lu;
            if chord_next {
                self.checkpoint.copy_from(&self.current);
            }
            for _ in 0..s.crash_iterations {
                if *iterations - iterations_at_start >= s.max_iterations || self.out_of_time() {
                    break;
                }
                if chord_next {
                    if self.chord_target(mcp) {
                        evaluate_at(mcp, &mut self.trial, f_evals, self.fischer);
                        let chorded = self.trial.natural_residual(l, u);
                        let sigma = s.sufficient_decrease;
                        if self.trial.merit <= (1.0 - sigma) * self.current.merit
                            && chorded <= POLISH_CHORD_CONTRACTION * residual
                        {
                            self.trial_has_jac = false;
                            residual = self.take_crash_step(
                                1.0,
                                residual,
                                iterations,
                                counters,
                                (l, u, best_residual),
                                s.trace,
                                &mut record,
                            );
                            if residual <= s.tolerance {
                                chord_landed = true;
                                break;
                            }
                            continue;
                        }
                    }
                    // Refused: a full crash step from here (which sets `chord_next` again),
                    // with the Jacobian put off before.
                    self.kept_lu = false;
                    chord_next = false;
                    have_jac = self.settle_deferred_jacobian(mcp, &mut residual, jac_evals);
                    if !have_jac {
                        // Back at the last point with a finite Jacobian: on to the Newton
                        // paths from there.
                        break;
                    }
                }
                if !have_jac {
                    mcp.jacobian(&self.current.z, &mut self.jac);
                    *jac_evals += 1;
                    have_jac = true;
                }
                if !all_finite(&self.jac) {
                    break;
                }
                let Some(t) =
                    self.crash_step(mcp, pattern, s.tolerance, residual, f_evals, jac_evals)
                else {
                    break;
                };
                chord_next = self.jac_deferred;
                have_jac = self.trial_has_jac;
                residual = self.take_crash_step(
                    t,
                    residual,
                    iterations,
                    counters,
                    (l, u, best_residual),
                    s.trace,
                    &mut record,
                );
                if chord_next {
                    // The point before the step (in `trial` since it was taken, whole: `x`,
                    // `z`, `F`, merit, residual) is the checkpoint a refused chord step goes
                    // back to: moved there, not copied; `trial` is written afresh before it is
                    // read again.
                    std::mem::swap(&mut self.checkpoint, &mut self.trial);
                }
                if residual <= s.tolerance {
                    break;
                }
                if chord_next {
                    continue;
                }
                let same = self.active == self.active_prev;
                self.active_prev.copy_from_slice(&self.active);
                if same && t == 1.0 {
                    break;
                }
            }
            // The crash phase ended on its step limit (`crash_iterations`) right after a point
            // accepted without its Jacobian: the main loop's first Newton path needs it, and a
            // non-finite one is the acceptance test's refusal of that point, not a non-finite
            // problem (which would end the solve without its restarts). When the iteration
            // budget or the time limit ended it, the main loop stops before it needs `J`
            // (`max_iterations`, `time_limit_reached`), so none is evaluated.
            if chord_next
                && residual > s.tolerance
                && *iterations - iterations_at_start < s.max_iterations
                && !self.out_of_time()
            {
                have_jac = self.settle_deferred_jacobian(mcp, &mut residual, jac_evals);
            }
        }

        // Main loop: Newton paths by pivoting, watchdog and path search.
        let jscale = |jac: &[f64]| jac.iter().fold(1.0f64, |m, v| m.max(v.abs()));
        let mut lambda = 0.0f64;
        let mut first_lambda = initial_lambda;
        // Not when the loop below stops at once (the crash phase converged, the desk's every
        // step): nothing after it reads the checkpoint.
        let converged = residual <= s.tolerance;
        if termination == Termination::MaxIterations && !converged {
            self.checkpoint.copy_from(&self.current);
        }
        let mut since_checkpoint = 0usize;
        let mut checkpoint_lambda = 0.0f64;
        // Set after a return to the checkpoint: the next step must pass the monotone path
        // search there (no more non-monotone steps until one does).
        let mut monotone = false;
        let mut stall = Stall::new(s, residual, *iterations);
        // Consecutive accepted steps that left the iterate where it was (`frozen_steps`).
        let mut frozen = 0usize;
        while termination == Termination::MaxIterations {
            if residual <= s.tolerance {
                termination = Termination::Converged;
                break;
            }
            if stall.stalled(residual, *iterations) {
                termination = Termination::Stagnated;
                break;
            }
            if *iterations - iterations_at_start >= s.max_iterations {
                break;
            }
            // A path step moves the point by pivoting: the crash phase's LU is left behind.
            self.kept_lu = false;
            if self
                .pivot_budget
                .is_some_and(|b| counters.pivots - pivots_at_start >= b)
            {
                break;
            }
            // Under the budget each path stops at FIRST_ATTEMPT_PATH_PIVOTS per unknown and at
            // what is left of the budget, otherwise at LATER_ATTEMPT_PATH_PIVOTS per unknown:
            // paths either end within a few pivots per unknown or cycle to the cap (on
            // `038_multi_body` the cycling ones were 93 % of all pivots, `docs/path.md`, 038).
            let cap = match self.pivot_budget {
                Some(b) => {
                    (b - (counters.pivots - pivots_at_start)).min(FIRST_ATTEMPT_PATH_PIVOTS * n)
                }
                None => LATER_ATTEMPT_PATH_PIVOTS * n,
            };
            self.lemke.set_pivot_cap(Some(cap));
            if self.out_of_time() {
                counters.time_limit_reached = 1;
                break;
            }
            if !have_jac {
                mcp.jacobian(&self.current.z, &mut self.jac);
                *jac_evals += 1;
            }
            if !all_finite(&self.jac) {
                termination = Termination::NonFiniteFunction;
                break;
            }
            let mut scale = jscale(&self.jac);
            if first_lambda > 0.0 {
                // A restart with the proximal term on from the first step.
                lambda = first_lambda * scale;
                checkpoint_lambda = lambda;
                first_lambda = 0.0;
            }
            // The Newton path, perturbed proximally until the linearised problem is solvable.
            let reach = loop {
                match self.newton_path(pattern, l, u, lambda, counters) {
                    Ok(reach) => break Some(reach),
                    Err(_) if self.out_of_time() => break None,
                    Err(_) => {
                        lambda = next_lambda(lambda, s, scale);
                        counters.proximal_perturbations += 1;
                        if lambda > s.proximal_max * scale {
                            break None;
                        }
                    }
                }
            };
            let Some(t_max) = reach else {
                if self.out_of_time() {
                    counters.time_limit_reached = 1;
                } else {
                    termination = Termination::SubproblemFailed;
                }
                break;
            };
            let reference = self.checkpoint.merit;
            let merit_k = self.current.merit;
            // The full step: the end of the path.
            let t_full = self.try_path_point(mcp, t_max, f_evals);
            let sigma = s.sufficient_decrease;
            let mut accepted: Option<f64> = None;
            let decrease = self.trial.merit <= (1.0 - sigma * t_full) * reference;
            // A Newton point whose merit is orders of magnitude above the checkpoint's is the
            // linearisation of a nearly singular Jacobian, not a step across a kink: the
            // watchdog does not take it (`PathSettings::watchdog_growth`).
            let watchdog_open = !monotone
                && since_checkpoint < s.watchdog
                && self.trial.merit <= s.watchdog_growth * reference;
            let usable =
                (decrease || watchdog_open) && self.trial_usable(mcp, s.tolerance, jac_evals);
            if decrease && usable {
                accepted = Some(t_full);
                since_checkpoint = 0;
            } else if watchdog_open && usable {
                // Non-monotone: accept the Newton point and see where it leads.
                accepted = Some(t_full);
                since_checkpoint += 1;
                counters.nonmonotone_steps += 1;
            } else {
                if since_checkpoint > 0 {
                    // The watchdog expired: back to the checkpoint, and search along its path.
                    counters.watchdog_restores += 1;
                    self.keep_best();
                    self.current.copy_from(&self.checkpoint);
                    since_checkpoint = 0;
                    monotone = true;
                    mcp.jacobian(&self.current.z, &mut self.jac);
                    *jac_evals += 1;
                    have_jac = true;
                    // The proximal term and its scale belong to the checkpoint, not to the
                    // abandoned excursion.
                    scale = jscale(&self.jac);
                    lambda = checkpoint_lambda;
                    if self.newton_path(pattern, l, u, lambda, counters).is_err() {
                        lambda = next_lambda(lambda, s, scale);
                        counters.proximal_perturbations += 1;
                        if lambda > s.proximal_max * scale {
                            termination = Termination::SubproblemFailed;
                            break;
                        }
                        continue;
                    }
                }
                let t_max = (1.0 - self.path.min_artificial()).clamp(0.0, 1.0);
                let mut t = t_max;
                for _ in 0..s.max_path_backtracks {
                    if self.out_of_time() {
                        break;
                    }
                    t *= s.backtrack;
                    counters.path_backtracks += 1;
                    let used = self.try_path_point(mcp, t, f_evals);
                    if self.trial.merit <= (1.0 - sigma * used) * self.current.merit
                        && self.trial_usable(mcp, s.tolerance, jac_evals)
                    {
                        accepted = Some(used);
                        break;
                    }
                }
                if accepted.is_none() && self.out_of_time() {
                    counters.time_limit_reached = 1;
                    break;
                }
                if accepted.is_none() {
                    // No decrease along this path: perturb the linearisation and try again.
                    lambda = next_lambda(lambda, s, scale);
                    counters.proximal_perturbations += 1;
                    if lambda > s.proximal_max * scale || s.max_path_backtracks == 0 {
                        termination = Termination::LineSearchFailed;
                        break;
                    }
                    have_jac = true;
                    continue;
                }
            }
            let Some(t) = accepted else {
                termination = Termination::LineSearchFailed;
                break;
            };
            // Guarded watchdog: a step shortened by the path search means the linearisation is
            // poor here, so stay monotone (after a return to the checkpoint) and keep the
            // proximal term until a full Newton step is accepted; otherwise the watchdog takes
            // the same diverging Newton points again from a barely moved checkpoint.
            let full_step = !guarded || t >= t_full;
            if full_step {
                monotone = false;
            }
            let norm = norm_inf_diff(&self.trial.x, &self.current.x);
            record(
                *iterations,
                residual,
                merit_k,
                StepKind::Path,
                t,
                norm,
                &mut self.observer,
            );
            *iterations += 1;
            counters.path_steps += 1;
            have_jac = self.trial_has_jac;
            residual = self.accept_trial(l, u, best_residual);
            if self.current.merit < self.checkpoint.merit
                && (since_checkpoint == 0 || self.current.merit <= (1.0 - sigma) * reference)
            {
                self.checkpoint.copy_from(&self.current);
                since_checkpoint = 0;
                checkpoint_lambda = lambda;
            }
            // Progress: relax the proximal term.
            if lambda > 0.0 && full_step {
                lambda *= s.proximal_reduction;
                if lambda < 1e-12 * scale {
                    lambda = 0.0;
                }
            }
            let xnorm = self.current.x.iter().fold(1.0f64, |m, v| m.max(v.abs()));
            if residual > s.tolerance && norm <= 4.0 * f64::EPSILON * xnorm && lambda == 0.0 {
                termination = Termination::Stagnated;
            }
            frozen = if norm <= FROZEN_STEP * xnorm {
                frozen + 1
            } else {
                0
            };
            if residual > s.tolerance && s.frozen_steps > 0 && frozen >= s.frozen_steps {
                termination = Termination::Stagnated;
            }
        }
        // The polish (`PathSettings::polish_below`): up to two full Newton steps from a point
        // that meets the tolerance above round-off level. Each is kept when its point meets
        // the tolerance too, not only when the residual falls: near round-off (1e-12 on A5's
        // free fall) the residual no longer ranks points, and keeping the end point of one
        // start and the Newton point of another would leave the answer start-dependent.
        //
        // Chord steps first: while the crash phase's (or the last polish's) LU is kept and the
        // active set is its own, a step on it (`chord_target`: one solve and one evaluation, no
        // Jacobian, no factorisation) is kept when it lowers the residual by
        // `POLISH_CHORD_CONTRACTION`; a chord step that ends below `polish_below · tolerance`
        // is followed by one more (the chord's rate is linear: without it the polish would stop
        // anywhere below that bound, not at round-off), kept when it lowers the residual. A
        // refused chord step falls back to the full step.
        let mut polishes = 0;
        let mut chords = 0;
        let mut chord_last = chord_landed;
        while residual <= s.tolerance && n > 0 {
            let above =
                residual > s.polish_below * s.tolerance || std::mem::take(&mut polish_start);
            // The chord's polish only above a floor: a chord step that ended far below the
            // bound is at round-off already (the desk: 2e-16).
            if !above
                && (!chord_last || residual <= POLISH_CHORD_FLOOR * s.polish_below * s.tolerance)
            {
                break;
            }
            // The clock after the tests above, which end the polish without a step (the
            // desk's every step): a reading costs about as much as a pass over the unknowns.
            // Neither test's state is read after the loop, so a spent budget still ends it
            // before any step, as when the clock was read first.
            if self.out_of_time() {
                break;
            }
            chord_last = false;
            if chords < POLISH_CHORD_STEPS && self.chord_target(mcp) {
                evaluate_at(mcp, &mut self.trial, f_evals, self.fischer);
                let chorded = self.trial.natural_residual(l, u);
                let bound = if above {
                    POLISH_CHORD_CONTRACTION * residual
                } else {
                    residual
                };
                if self.trial.merit.is_finite() && chorded <= s.tolerance && chorded <= bound {
                    chords += 1;
                    self.trial_has_jac = false;
                    residual = self.take_crash_step(
                        1.0,
                        residual,
                        iterations,
                        counters,
                        (l, u, best_residual),
                        s.trace,
                        &mut record,
                    );
                    have_jac = false;
                    chord_last = above;
                    continue;
                }
            }
            // No chord step (or a refused one): the kept LU is done with.
            self.kept_lu = false;
            if !above || polishes == 2 {
                break;
            }
            polishes += 1;
            if !have_jac {
                mcp.jacobian(&self.current.z, &mut self.jac);
                *jac_evals += 1;
            }
            // The crash phase's Newton target; where the reduced Jacobian is singular (a body in
            // free fall: its idle contact unknowns) the same with a small proximal shift, which
            // leaves the solution's undetermined components where they are. One factorisation
            // of `J_II` each: the Newton path of the main loop (a Lemke path per shift, as the
            // polish first took) cost twice as much per polish on the stress suite.
            let mut stepped = false;
            if all_finite(&self.jac) {
                let mut scale = 0.0;
                let mut shift = 0.0;
                loop {
                    if self.crash_target(mcp, pattern, shift) {
                        self.trial.x.copy_from_slice(&self.step_x);
                        stepped = true;
                        break;
                    }
                    if shift == 0.0 {
                        scale = self.jac.iter().fold(1.0f64, |m, v| m.max(v.abs()));
                        shift = POLISH_SHIFT_MIN * scale;
                    } else {
                        shift *= s.proximal_growth;
                    }
                    if shift > POLISH_SHIFT_MAX * scale {
                        break;
                    }
                }
            }
            if stepped {
                evaluate_at(mcp, &mut self.trial, f_evals, self.fischer);
                let polished = self.trial.natural_residual(l, u);
                if self.trial.merit.is_finite() && polished <= s.tolerance {
                    self.trial_has_jac = false;
                    let before = residual;
                    residual = self.take_crash_step(
                        1.0,
                        residual,
                        iterations,
                        counters,
                        (l, u, best_residual),
                        s.trace,
                        &mut record,
                    );
                    have_jac = false;
                    // A step that did not gain a digit ended at the residual's round-off floor
                    // (1.1e-13 on the stress suite's `138_ladder` at rest): another gains nothing.
                    if residual > 0.1 * before {
                        break;
                    }
                    continue;
                }
            }
            break;
        }
        if termination == Termination::Converged || residual <= *best_residual {
            *best_residual = residual;
            self.best_in_current = true;
        }
        // The best point is in `best_z` and `best_f`, or still `current` itself
        // (`best_in_current`): copied by the next attempt's start, if there is one, not here
        // (a solve that converges in its first attempt, the desk's every one, reports it from
        // `current`, [`PathSolver::best_point`]).
        if residual <= s.tolerance {
            Termination::Converged
        } else {
            termination
        }
    }

    /// Evaluates the path point at `t` into `self.trial`.
    fn try_path_point(&mut self, mcp: &dyn Mcp, t: f64, f_evals: &mut usize) -> f64 {
        let used = self.path.point_at(t, &mut self.trial.x);
        evaluate_at(mcp, &mut self.trial, f_evals, self.fischer);
        used
    }
}

impl McpSolver for PathSolver {
    fn name(&self) -> &str {
        "path"
    }

    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        // Judged in the problem's scene scales when it has them (`ecp_model::scaling`).
        // `McpScales::usage`'s verdict is `Unscaled` exactly when the scales are all 1 or not
        // valid; the problem may keep it from one solve to the next (`Mcp::scales_usage`).
        let scaled = mcp
            .scales_usage()
            .is_some_and(|(_, usage)| usage != ScalesUsage::Unscaled);
        // The system of units `solve_in_scales` hands over: the problem itself (as given) or
        // its scaled form, whose scales are the problem's (the key of a kept LU).
        let outer = mcp;
        let units = |inner: &dyn Mcp| {
            (!std::ptr::addr_eq(inner, outer))
                .then(|| outer.scales())
                .flatten()
        };
        if self.iteration_budget.is_some() {
            return solve_in_scales(mcp, z0, |mcp, z0| {
                self.solve_unscaled(mcp, z0, Attempts::First, units(mcp))
            });
        }
        if !(scaled && self.settings.first_in_both_units) {
            return solve_in_scales(mcp, z0, |mcp, z0| {
                self.solve_unscaled(mcp, z0, Attempts::All, units(mcp))
            });
        }
        // The first attempt in both systems of units (`PathSettings::first_in_both_units`),
        // then the other attempts in both.
        let first = solve_in_scales(mcp, z0, |mcp, z0| {
            self.solve_unscaled(mcp, z0, Attempts::First, units(mcp))
        });
        let Err(SolveError::NotConverged { best: first }) = first else {
            return first;
        };
        let rest = solve_in_scales(mcp, z0, |mcp, z0| {
            self.solve_unscaled(mcp, z0, Attempts::Rest, units(mcp))
        });
        match rest {
            Ok(mut sol) => {
                sol.summary.iterations += first.summary.iterations;
                Ok(sol)
            }
            Err(SolveError::NotConverged { mut best }) => {
                best.summary.iterations += first.summary.iterations;
                if first.summary.residual < best.summary.residual {
                    let iterations = best.summary.iterations;
                    best = first;
                    best.summary.iterations = iterations;
                }
                Err(SolveError::NotConverged { best })
            }
            e => e,
        }
    }

    /// [`McpSolver::solve`] with `out`'s storage: the first run writes its result there
    /// (`PathSolver::result`), so a warm solve that converges in its first run allocates
    /// nothing once its workspace has grown.
    fn solve_into(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        out: &mut Solution,
    ) -> Result<(), SolveError> {
        // `out`'s storage into `result` by a swap (`result` is empty between solves), not by
        // `take`, which copied the whole `Solution` through the stack twice.
        std::mem::swap(&mut self.result, out);
        match self.solve(mcp, z0) {
            Ok(sol) => {
                *out = sol;
                Ok(())
            }
            Err(e) => {
                // As `take` left it.
                *out = Solution::default();
                Err(e)
            }
        }
    }

    /// Honoured: a budgeted solve is the first attempt alone (in the problem's scene scales),
    /// stopped after `budget` iterations (at most [`PathSettings::max_iterations`]).
    fn set_iteration_budget(&mut self, budget: Option<usize>) -> bool {
        self.iteration_budget = budget;
        true
    }

    /// Honoured: a predicted start below `polish_below · tolerance` is returned as it stands
    /// only at the round-off floor (`START_ROUND_OFF_ULPS`), else it takes the polish's steps.
    fn set_start_predicted(&mut self, predicted: bool) -> bool {
        self.start_predicted = predicted;
        true
    }

    /// With the polish on ([`PathSettings::polish_below`] below 1, the default), a converged
    /// attempt ends with full Newton steps below the tolerance, as Newton's does.
    fn converges_to_round_off(&self) -> bool {
        self.settings.polish_below < 1.0
    }
}

/// Which attempts of a solve [`PathSolver::solve_unscaled`] runs
/// ([`PathSettings::first_in_both_units`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Attempts {
    /// Every attempt: the first, the guarded one, the restarts, the smoothing continuation.
    All,
    /// The first attempt only.
    First,
    /// Every attempt but the first.
    Rest,
}

impl PathSolver {
    /// [`McpSolver::solve`] on `mcp` as given: the `which` attempts, within a budget of
    /// [`PathSettings::time_limit`] of their own.
    fn solve_unscaled(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        which: Attempts,
        scales: Option<&McpScales>,
    ) -> Result<Solution, SolveError> {
        // The LU kept from the last solve (`PathSettings::chord_across_solves`), for this
        // solve's first attempt when it was formed for the same problem in the same units.
        let kept = self.kept_key.take();
        self.lu_from_last_solve = self.settings.chord_across_solves
            && which != Attempts::Rest
            && kept.is_some_and(|k| self.same_key(&k, mcp, scales));
        let result = self.solve_attempts_and_continuation(mcp, z0, which);
        self.lu_from_last_solve = false;
        if self.settings.chord_across_solves && self.kept_lu && result.is_ok() {
            self.kept_scales.clear();
            if let Some(sc) = scales {
                self.kept_scales.extend_from_slice(&sc.variables);
                self.kept_scales.extend_from_slice(&sc.rows);
            }
            self.kept_key = Some(KeptKey {
                as_given: scales.is_none(),
                pattern: mcp.jacobian_pattern().clone(),
            });
        }
        result
    }

    /// Whether the LU kept under `key` was formed for `mcp` in the same units: the same
    /// Jacobian pattern (so the same dimension) and system (as given, or scaled by the same
    /// scales).
    fn same_key(&self, key: &KeptKey, mcp: &dyn Mcp, scales: Option<&McpScales>) -> bool {
        let p = mcp.jacobian_pattern();
        let same_pattern = Arc::ptr_eq(&key.pattern, p)
            || (key.pattern.col_ptr() == p.col_ptr() && key.pattern.row_idx() == p.row_idx());
        same_pattern
            && match scales {
                None => key.as_given,
                Some(sc) => {
                    !key.as_given
                        && self.kept_scales.len() == sc.variables.len() + sc.rows.len()
                        && self.kept_scales[..sc.variables.len()] == sc.variables[..]
                        && self.kept_scales[sc.variables.len()..] == sc.rows[..]
                }
            }
    }

    /// [`PathSolver::solve_unscaled`]'s attempts and smoothing continuation.
    fn solve_attempts_and_continuation(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        which: Attempts,
    ) -> Result<Solution, SolveError> {
        let started = Instant::now();
        validate_start(mcp, z0)?;
        self.deadline = if self.settings.time_limit.is_finite() {
            started.checked_add(std::time::Duration::from_secs_f64(self.settings.time_limit))
        } else {
            None
        };
        self.lemke.set_deadline(self.deadline);
        self.pivot_budget = (which == Attempts::First && self.settings.first_attempt_pivots > 0)
            .then(|| self.settings.first_attempt_pivots.saturating_mul(mcp.dim()));
        self.lemke.set_pivot_cap(None);
        let max_iterations = (self.iteration_budget).map_or(self.settings.max_iterations, |b| {
            b.min(self.settings.max_iterations)
        });
        let s = match which {
            Attempts::First => PathSettings {
                max_iterations,
                guarded_watchdog: false,
                restarts: 0,
                fischer_restart: false,
                best_point_restart: false,
                smoothing: None,
                ..self.settings.clone()
            },
            _ => self.settings.clone(),
        };
        let first = self.solve_attempts(mcp, z0, &s, started, which == Attempts::Rest);
        let (Some(smoothing), Err(SolveError::NotConverged { best })) = (s.smoothing, &first)
        else {
            return first;
        };
        if self.out_of_time() {
            return first;
        }
        // The smoothing continuation (see `PathSettings::smoothing`): each stage one attempt of
        // at most `stage_iterations`, then every attempt from its end point.
        let stage = PathSettings {
            max_iterations: smoothing.stage_iterations,
            guarded_watchdog: false,
            restarts: 0,
            fischer_restart: false,
            best_point_restart: false,
            smoothing: None,
            ..s.clone()
        };
        let deadline = self.deadline;
        let end = continuation(
            mcp,
            z0,
            &smoothing,
            s.tolerance,
            |problem, z, tolerance| {
                let st = PathSettings {
                    tolerance,
                    ..stage.clone()
                };
                self.solve_attempts(problem, z, &st, started, false)
            },
            || deadline.is_some_and(|d| Instant::now() >= d),
        )?;
        let last = self.solve_attempts(mcp, &end.z, &s, started, false);
        let previous = best.summary.iterations;
        let tally = |summary: &mut ecp_model::Summary| end.tally(summary, previous);
        match last {
            Ok(mut sol) => {
                tally(&mut sol.summary);
                Ok(sol)
            }
            Err(SolveError::NotConverged { mut best }) => {
                tally(&mut best.summary);
                match first {
                    Err(SolveError::NotConverged { best: old })
                        if old.summary.residual <= best.summary.residual =>
                    {
                        Err(SolveError::NotConverged { best: old })
                    }
                    _ => Err(SolveError::NotConverged { best }),
                }
            }
            e => e,
        }
    }
}

impl PathSolver {
    /// Every attempt of one solve from `z0` with settings `s` (the first, the guarded one, the
    /// restarts), within the deadline already set; `started` is the solve's start. With
    /// `skip_first` the first attempt is taken as failed without running it (it ran before,
    /// [`PathSettings::first_in_both_units`]).
    fn solve_attempts(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        s: &PathSettings,
        started: Instant,
        skip_first: bool,
    ) -> Result<Solution, SolveError> {
        if *self.lemke.settings() != s.lemke {
            *self.lemke.settings_mut() = s.lemke.clone();
        }
        let n = mcp.dim();
        // Borrowed, not cloned: the clone and its drop are two atomic operations a solve.
        let pattern: &CscPattern = mcp.jacobian_pattern();
        self.resize(n, pattern.nnz());
        self.fischer = false;
        self.best_in_current = false;
        let mut run = Run {
            trace: Vec::new(),
            counters: Counters::default(),
            f_evals: 0,
            jac_evals: 0,
            iterations: 0,
            best_residual: f64::INFINITY,
        };
        let mut termination = if skip_first {
            Termination::MaxIterations
        } else {
            self.attempt(mcp, pattern, z0, s, 0.0, false, &mut run)
        };
        // A second attempt with the guarded watchdog (see `PathSettings::guarded_watchdog`).
        if s.guarded_watchdog
            && termination != Termination::Converged
            && termination != Termination::NonFiniteFunction
            && !self.out_of_time()
        {
            run.counters.guarded_attempts += 1;
            let t = self.attempt(mcp, pattern, z0, s, 0.0, true, &mut run);
            if t == Termination::Converged || run.best_residual <= s.tolerance {
                termination = Termination::Converged;
            }
        }
        // Restarts from the start point, as PATH does after a failure: monotone, without the
        // crash, with the proximal term on from the first step (which keeps the Newton points of
        // singular or nearly singular linearisations close to the iterate).
        let mut restarts = 0;
        while termination != Termination::Converged
            && termination != Termination::NonFiniteFunction
            && restarts < s.restarts
            && !self.out_of_time()
        {
            // Built here, not before the loop: a converged solve (the desk's every one) needs
            // no copy of the settings.
            let restart = PathSettings {
                crash_iterations: 0,
                watchdog: 0,
                proximal_reduction: 1.0,
                ..s.clone()
            };
            restarts += 1;
            run.counters.restarts += 1;
            let lambda0 = s.restart_proximal * (10f64).powi(restarts as i32 - 1);
            let t = self.attempt(mcp, pattern, z0, &restart, lambda0, false, &mut run);
            if t == Termination::Converged || run.best_residual <= s.tolerance {
                termination = Termination::Converged;
            }
        }
        // The Fischer–Burmeister attempt, then the attempt from the best point.
        if s.fischer_restart
            && termination != Termination::Converged
            && termination != Termination::NonFiniteFunction
            && !self.out_of_time()
        {
            run.counters.fischer_attempts += 1;
            self.fischer = true;
            let t = self.attempt(mcp, pattern, z0, s, 0.0, true, &mut run);
            self.fischer = false;
            if t == Termination::Converged || run.best_residual <= s.tolerance {
                termination = Termination::Converged;
            }
        }
        if s.best_point_restart
            && termination != Termination::Converged
            && termination != Termination::NonFiniteFunction
            && run.best_residual.is_finite()
            && !self.out_of_time()
        {
            run.counters.best_point_restarts += 1;
            self.keep_best();
            let best = self.best_z.clone();
            let t = self.attempt(mcp, pattern, &best, s, 0.0, true, &mut run);
            if t == Termination::Converged || run.best_residual <= s.tolerance {
                termination = Termination::Converged;
            }
        }
        let Run {
            trace,
            counters,
            f_evals,
            jac_evals,
            iterations,
            best_residual,
            ..
        } = run;
        // The result in the storage `solve_into` handed over, if any (counters included).
        let mut result = std::mem::take(&mut self.result);
        let mut reported = std::mem::take(&mut result.summary.counters);
        reported.set_all([
            (Counter::Pivots, counters.pivots),
            (Counter::CrashSteps, counters.crash_steps),
            (Counter::PathSteps, counters.path_steps),
            (Counter::NonmonotoneSteps, counters.nonmonotone_steps),
            (Counter::WatchdogRestores, counters.watchdog_restores),
            (Counter::PathBacktracks, counters.path_backtracks),
            (
                Counter::ProximalPerturbations,
                counters.proximal_perturbations,
            ),
            (Counter::RayTerminations, counters.ray_terminations),
            (Counter::Restarts, counters.restarts),
            (Counter::GuardedAttempts, counters.guarded_attempts),
            (Counter::FischerAttempts, counters.fischer_attempts),
            (Counter::BestPointRestarts, counters.best_point_restarts),
            (Counter::TimeLimitReached, counters.time_limit_reached),
        ]);
        let report = SolveReport {
            solver: "path",
            termination,
            tolerance: s.tolerance,
            iterations,
            f_evals,
            jac_evals,
            started,
            trace,
            counters: reported,
        };
        // `best_f` is F at `best_z` once a finite residual made the point this solve's best.
        let (best_z, best_f) = self.best_point();
        if !best_residual.is_finite() {
            return finish_solve(mcp, best_z.to_vec(), report);
        }
        if finish_solve_into(mcp, best_z, best_f, report, &mut result) {
            Ok(result)
        } else {
            Err(SolveError::NotConverged {
                best: Box::new(result),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::KnownAt;
    use ecp_model::FnMcp;
    use ecp_model::mcp_library::{box_both_bounds, kojima_shindo};
    use std::sync::Mutex;

    #[test]
    fn path_polish_ends_every_start_at_the_same_point() {
        // On by default; every start of the Kojima–Shindo problem ends within 1e-12 of the
        // first start's point, and the backend says so (off, `polish_below = 1`, it does not).
        assert!(
            !PathSolver::new(PathSettings {
                polish_below: 1.0,
                ..PathSettings::default()
            })
            .converges_to_round_off()
        );
        let p = kojima_shindo();
        let mut solver = PathSolver::new(PathSettings::default());
        assert!(solver.converges_to_round_off());
        let first = solver.solve(&p.mcp, &p.starts[0].1).unwrap();
        for (label, z0) in &p.starts {
            let sol = solver.solve(&p.mcp, z0).unwrap();
            assert!(sol.summary.residual <= 1e-10, "{label}");
            // Kojima–Shindo has two solutions: compare the starts that end at the first's.
            if sol
                .z
                .iter()
                .zip(&first.z)
                .all(|(a, b)| (a - b).abs() < 1e-6)
            {
                for (a, b) in sol.z.iter().zip(&first.z) {
                    assert!((a - b).abs() <= 1e-12, "{label}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn a_predicted_start_below_the_polish_bound_is_polished_unless_at_round_off() {
        // `z0 = 1 + 1.5e-14` misses the root by a residual of ≈ 4.5e-14: below `polish_below ·
        // tolerance` (1e-13), so a start returned as it stands, but 50 ulps above round-off.
        let p = shifted_root(0.0);
        let start = [1.0 + 1.5e-14, 0.0];
        let mut solver = PathSolver::new(PathSettings::default());
        let plain = solver.solve(&p, &start).unwrap();
        assert_eq!(plain.summary.iterations, 0);
        assert_eq!(plain.z, start);
        let r = plain.summary.residual;
        assert!(r > 1e-14 && r <= 1e-13, "{r}");
        // Predicted (`McpSolver::set_start_predicted`): polished to the root.
        assert!(solver.set_start_predicted(true));
        let polished = solver.solve(&p, &start).unwrap();
        assert!(polished.summary.iterations >= 1, "{:?}", polished.summary);
        assert!(polished.summary.residual <= 2e-15, "{:?}", polished.summary);
        assert!((polished.z[0] - 1.0).abs() <= 1e-15, "{:?}", polished.z);
        // At round-off (the root itself) a predicted start stands.
        let exact = solver.solve(&p, &[1.0, 0.0]).unwrap();
        assert_eq!(exact.summary.iterations, 0);
        assert_eq!(exact.z, [1.0, 0.0]);
        // Unset: as before.
        assert!(solver.set_start_predicted(false));
        let again = solver.solve(&p, &start).unwrap();
        assert_eq!(again.z, plain.z);
        assert_eq!(again.summary.iterations, 0);
    }

    #[test]
    fn path_polish_takes_chord_steps_on_the_crash_steps_lu() {
        // `z0² + z0 = 2` (free) and `z1 ≥ 0` with `F1 = z1 + 1 + z0/10 > 0` (at its bound), from
        // `z0 = 1 + 1e-6`: the crash step lands at a residual of about 3e-13, within the
        // tolerance but above `polish_below · tolerance`. The polish then steps on the crash
        // step's LU (`J_II` at the start): one Jacobian in the whole solve, where a full polish
        // takes a second; and it ends at round-off, at the root, as the full polish did.
        let p = shifted_root(0.0);
        let mut solver = PathSolver::new(PathSettings::default());
        let sol = solver.solve(&p, &[1.0 + 1e-6, 0.0]).unwrap();
        assert_eq!(sol.summary.jac_evals, 1, "{:?}", sol.summary);
        // Round-off of `F0`'s terms (of size 2): a few ulps of 2.
        assert!(sol.summary.residual <= 2e-15, "{}", sol.summary.residual);
        assert!((sol.z[0] - 1.0).abs() <= 1e-15, "{}", sol.z[0]);
        assert_eq!(sol.z[1], 0.0);
    }

    /// `z0² + z0 = 2 + p` (free) and `z1 ≥ 0` with `F1 = z1 + 1 + z0/10 > 0` (at its bound).
    fn shifted_root(p: f64) -> FnMcp {
        FnMcp::dense(
            vec![f64::NEG_INFINITY, 0.0],
            vec![f64::INFINITY; 2],
            move |z, f| {
                f[0] = z[0] * z[0] + z[0] - 2.0 - p;
                f[1] = z[1] + 1.0 + 0.1 * z[0];
            },
            |z, j| {
                j[0] = 2.0 * z[0] + 1.0;
                j[1] = 0.1;
                j[2] = 0.0;
                j[3] = 1.0;
            },
        )
        .unwrap()
    }

    /// A problem with scene scales (`Mcp::scales`), so that it is solved in them.
    struct WithScales(FnMcp, ecp_model::McpScales);
    impl Mcp for WithScales {
        fn dim(&self) -> usize {
            self.0.dim()
        }
        fn lower(&self) -> &[f64] {
            self.0.lower()
        }
        fn upper(&self) -> &[f64] {
            self.0.upper()
        }
        fn evaluate(&self, z: &[f64], f: &mut [f64]) {
            self.0.evaluate(z, f)
        }
        fn jacobian_pattern(&self) -> &Arc<CscPattern> {
            self.0.jacobian_pattern()
        }
        fn jacobian(&self, z: &[f64], values: &mut [f64]) {
            self.0.jacobian(z, values)
        }
        fn scales(&self) -> Option<&ecp_model::McpScales> {
            Some(&self.1)
        }
    }

    #[test]
    fn path_chord_steps_on_the_last_solves_lu_in_the_same_units_only() {
        let root = |p: f64| (-1.0 + (9.0f64 + 4.0 * p).sqrt()) / 2.0;
        let settings = PathSettings {
            chord_across_solves: true,
            ..PathSettings::default()
        };
        // As given: the second solve (the root moved by 3e-4) takes chord steps on the first
        // solve's LU and no Jacobian; it ends at the root to round-off all the same.
        let mut solver = PathSolver::new(settings.clone());
        let first = solver.solve(&shifted_root(0.0), &[1.1, 0.0]).unwrap();
        assert!(first.summary.jac_evals >= 1);
        let second = solver.solve(&shifted_root(1e-3), &first.z).unwrap();
        assert_eq!(second.summary.jac_evals, 0, "{:?}", second.summary);
        assert!(second.summary.iterations >= 2);
        assert!((second.z[0] - root(1e-3)).abs() <= 4.0 * f64::EPSILON);
        assert!(
            second.summary.residual <= 2e-15,
            "{}",
            second.summary.residual
        );
        // Off (the default), the same solve evaluates the Jacobian and ends at the same root.
        let mut plain = PathSolver::new(PathSettings::default());
        plain.solve(&shifted_root(0.0), &[1.1, 0.0]).unwrap();
        let again = plain.solve(&shifted_root(1e-3), &first.z).unwrap();
        assert!(again.summary.jac_evals >= 1);
        assert!((again.z[0] - second.z[0]).abs() <= 4.0 * f64::EPSILON);
        // In scene scales far from SI (`2²¹`, solved in them) whose scaled `J_II` is the same
        // number as the one given (`d_x = d_f` on `z0`): the LU of the system as given is not
        // used there (it would pass the chord's tests), but that of an earlier scaled solve is.
        let scaled = |p: f64| {
            let d = 2_097_152.0;
            WithScales(
                shifted_root(p),
                ecp_model::McpScales {
                    variables: vec![d, 1.0],
                    rows: vec![d, 1.0],
                },
            )
        };
        let mut solver = PathSolver::new(settings);
        let first = solver.solve(&shifted_root(0.0), &[1.1, 0.0]).unwrap();
        let in_scales = solver.solve(&scaled(1e-3), &first.z).unwrap();
        assert!(in_scales.summary.jac_evals >= 1, "{:?}", in_scales.summary);
        // The tolerance is judged in the scales (`F / 2²¹`): 1e-10 there is 2e-4 here.
        assert!(in_scales.summary.converged());
        assert!((in_scales.z[0] - root(1e-3)).abs() <= 1e-6);
        let next = solver.solve(&scaled(2e-3), &in_scales.z).unwrap();
        assert_eq!(next.summary.jac_evals, 0, "{:?}", next.summary);
        assert!(next.summary.converged());
        assert!((next.z[0] - root(2e-3)).abs() <= 1e-6);
    }

    /// `F` at the start handed over (`Mcp::known_value`) replaces the attempt's first
    /// evaluation, and the solve returns the same point and summary bit for bit; `F` known at
    /// another point is not taken.
    #[test]
    fn path_takes_f_at_the_start_when_the_problem_holds_it() {
        let start = vec![1.2, 0.3];
        let inner = shifted_root(0.0);
        let mut f = vec![0.0; 2];
        inner.evaluate(&start, &mut f);
        let solve = |known_at: &[f64]| {
            let mcp = KnownAt::new(&inner, known_at.to_vec(), f.clone());
            let sol = PathSolver::new(PathSettings::default())
                .solve(&mcp, &start)
                .unwrap_or_else(|e| panic!("{e}"));
            (sol, mcp.evaluations.get())
        };
        let (plain, plain_evaluations) = solve(&[]);
        let (handed, handed_evaluations) = solve(&start);
        let (elsewhere, elsewhere_evaluations) = solve(&[1.2, 0.30000000000000004]);
        // z = (1, 0): z0² + z0 − 2 = 0, and F_1 = 1.1 > 0 at the bound.
        assert!(
            (plain.z[0] - 1.0).abs() <= 1e-15 && plain.z[1] == 0.0,
            "{:?}",
            plain.z
        );
        assert!(
            plain.summary.iterations >= 2,
            "{}",
            plain.summary.iterations
        );
        assert_eq!(handed_evaluations + 1, plain_evaluations);
        assert_eq!(elsewhere_evaluations, plain_evaluations);
        for sol in [&handed, &elsewhere] {
            assert_eq!(sol.z, plain.z);
            assert_eq!(sol.summary.residual, plain.summary.residual);
            assert_eq!(sol.summary.iterations, plain.summary.iterations);
            assert_eq!(sol.summary.f_evals, plain.summary.f_evals);
        }
    }

    /// A small generator for the tests below (xorshift64*).
    fn draws(seed: u64) -> impl FnMut() -> u64 {
        let mut x = seed.max(1);
        move || {
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            x.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
    }

    /// Values of every kind a Jacobian, a point or a bound may hold (finite unless `wild`).
    fn value(next: &mut impl FnMut() -> u64, wild: bool) -> f64 {
        let pick = next() % if wild { 14 } else { 10 };
        let unit = (next() >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        match pick {
            0 => 0.0,
            1 => -0.0,
            2 => unit * 1e-300,
            3 => unit * 1e300,
            4 => 5e-324,
            5 => -f64::MAX,
            6..=9 => unit * 8.0,
            10 => f64::NAN,
            11 => f64::INFINITY,
            12 => f64::NEG_INFINITY,
            _ => -f64::NAN,
        }
    }

    #[test]
    fn gathered_reduced_matrix_is_the_plain_scatter_bitwise() {
        let mut next = draws(0x9e37_79b9);
        for trial in 0..300 {
            let n = 1 + (next() % 40) as usize;
            let density = 1 + next() % 6;
            let mut entries = Vec::new();
            for j in 0..n {
                for i in 0..n {
                    if i == j || next() % 8 < density {
                        entries.push((i, j));
                    }
                }
            }
            let pattern = Arc::new(CscPattern::from_triplets(n, &entries).unwrap());
            let jac: Vec<f64> = (0..pattern.nnz())
                .map(|_| value(&mut next, false))
                .collect();
            let inactive: Vec<usize> = (0..n)
                .filter(|_| !next().is_multiple_of(4) || trial % 7 == 0)
                .collect();
            let ni = inactive.len();
            let mut slot = vec![usize::MAX; n];
            for (k, &i) in inactive.iter().enumerate() {
                slot[i] = k;
            }
            // The plain scatter: zeros, then each stored entry of an inactive row and column.
            let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
            let mut expected = vec![0.0; ni * ni];
            for (k, &j) in inactive.iter().enumerate() {
                for q in cp[j]..cp[j + 1] {
                    if slot[ri[q]] != usize::MAX {
                        expected[k * ni + slot[ri[q]]] = jac[q];
                    }
                }
            }
            let expected_norms: Vec<f64> = expected
                .chunks(ni.max(1))
                .take(ni)
                .map(|c| c.iter().fold(0.0f64, |m, v| m.max(v.abs())))
                .collect();
            let mut map = GatherMap::default();
            map.build(&pattern, &pattern, &inactive, &slot);
            assert!(map.holds(&pattern, &pattern, &inactive));
            // Storage that held something else, as the LU's does.
            let mut reduced = vec![f64::NAN; ni * ni];
            let mut norms = vec![-1.0; ni];
            gather_reduced(&mut reduced, &mut norms, &map, &jac);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&reduced), bits(&expected), "trial {trial}");
            assert_eq!(bits(&norms), bits(&expected_norms), "trial {trial}");
            // The portable build too.
            reduced.fill(7.0);
            // SAFETY: the map was built for this pattern and inactive set.
            unsafe { gather_reduced_with(&mut reduced, &mut norms, &map, &jac) };
            assert_eq!(bits(&reduced), bits(&expected), "trial {trial}, portable");
            assert_eq!(
                bits(&norms),
                bits(&expected_norms),
                "trial {trial}, portable"
            );
        }
    }

    #[test]
    fn all_finite_in_four_sums_is_the_plain_verdict() {
        let mut next = draws(0x51ed_270b);
        for len in 0..70 {
            let finite: Vec<f64> = (0..len).map(|_| value(&mut next, false)).collect();
            assert!(all_finite(&finite), "{len}");
            assert!(crate::pivot::all_finite(&finite));
            for k in 0..len {
                for bad in [f64::NAN, -f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                    let mut v = finite.clone();
                    v[k] = bad;
                    assert!(!all_finite(&v), "{bad} at {k} of {len}");
                }
            }
        }
    }

    #[test]
    fn projection_is_mid_bitwise() {
        let mut next = draws(0x2545_f491);
        for len in 0..40 {
            for _ in 0..20 {
                let x: Vec<f64> = (0..len).map(|_| value(&mut next, true)).collect();
                let mut l: Vec<f64> = (0..len).map(|_| value(&mut next, true)).collect();
                let mut u: Vec<f64> = (0..len).map(|_| value(&mut next, true)).collect();
                for (l, u) in l.iter_mut().zip(&mut u) {
                    if *l > *u {
                        std::mem::swap(l, u);
                    }
                }
                let expected: Vec<u64> =
                    (0..len).map(|i| mid(l[i], u[i], x[i]).to_bits()).collect();
                let mut z = vec![1.5; len];
                project(&mut z, &x, &l, &u);
                let got: Vec<u64> = z.iter().map(|v| v.to_bits()).collect();
                assert_eq!(got, expected, "{len}");
                project_with(&mut z, &x, &l, &u);
                let got: Vec<u64> = z.iter().map(|v| v.to_bits()).collect();
                assert_eq!(got, expected, "{len}, portable");
            }
        }
    }

    #[test]
    fn start_evaluated_from_z0_is_the_copy_then_evaluation() {
        // F finite at the start (the normal point overwrites `x`) and not (`x` is the start).
        for (start, fine) in [(vec![1.2, -0.3], true), (vec![-5.0, 2.0], false)] {
            let inner = FnMcp::dense(
                vec![f64::NEG_INFINITY, 0.0],
                vec![f64::INFINITY, 1.0],
                |z, f| {
                    f[0] = if z[0] < -1.0 {
                        f64::NAN
                    } else {
                        z[0] * z[0] - 1.0
                    };
                    f[1] = z[1] - 0.5 + z[0];
                },
                |z, j| {
                    j[0] = 2.0 * z[0];
                    j[1] = 1.0;
                    j[2] = 0.0;
                    j[3] = 1.0;
                },
            )
            .unwrap();
            let run = |from_start: bool| {
                let mut p = Point::default();
                p.resize(2);
                p.x.copy_from_slice(&[9.0, 9.0]);
                let mut evals = 0;
                if from_start {
                    evaluate_projected(&inner, &mut p, &mut evals, false, Some(&start));
                } else {
                    p.x.copy_from_slice(&start);
                    evaluate_at(&inner, &mut p, &mut evals, false);
                }
                (p, evals)
            };
            let (a, ea) = run(true);
            let (b, eb) = run(false);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(ea, eb);
            assert_eq!(bits(&a.x), bits(&b.x));
            assert_eq!(bits(&a.z), bits(&b.z));
            assert_eq!(bits(&a.f), bits(&b.f));
            assert_eq!(a.merit.to_bits(), b.merit.to_bits());
            assert_eq!(a.merit.is_finite(), fine);
            if !fine {
                assert_eq!(a.x, start);
            }
        }
    }

    #[test]
    fn path_normal_point_projects_back_and_measures_the_merit() {
        let l = [0.0, 0.0, f64::NEG_INFINITY];
        let u = [1.0, f64::INFINITY, f64::INFINITY];
        let mut p = Point::default();
        p.resize(3);
        // z0 at its lower bound with F pushing outwards, z1 at its bound with F pulling inwards,
        // z2 free.
        p.z.copy_from_slice(&[0.0, 0.0, 2.0]);
        p.f.copy_from_slice(&[3.0, -2.0, 0.5]);
        normal_point(&mut p, &l, &u);
        assert_eq!(p.x, vec![-3.0, 0.0, 2.0]);
        for i in 0..3 {
            assert_eq!(mid(l[i], u[i], p.x[i]), p.z[i]);
        }
        // F_N = F + x − z = (0, −2, 0.5).
        assert!((p.merit - (4.0f64 + 0.25).sqrt()).abs() < 1e-15);
    }

    /// The branch-free normal point gives the bits of the loop it replaced (`x` and the merit)
    /// with the portable and the AVX2 pass: components at either bound with `F` of either sign
    /// and zero, free, boxed and one-sided, `±0`, tiny and huge values, every length 0–13.
    #[test]
    fn normal_point_is_the_branching_loop_bitwise() {
        fn branching(z: &[f64], f: &[f64], l: &[f64], u: &[f64]) -> (Vec<f64>, f64) {
            let mut x = vec![0.0; z.len()];
            let mut s = 0.0;
            for i in 0..z.len() {
                x[i] = if z[i] <= l[i] && f[i] > 0.0 {
                    l[i] - f[i]
                } else if z[i] >= u[i] && f[i] < 0.0 {
                    u[i] - f[i]
                } else {
                    z[i]
                };
                let c = f[i] + x[i] - z[i];
                s += c * c;
            }
            (
                x,
                if s.is_finite() {
                    s.sqrt()
                } else {
                    f64::INFINITY
                },
            )
        }
        let inf = f64::INFINITY;
        let bounds = [
            (0.0, inf),
            (-inf, inf),
            (-1.0, 2.0),
            (-inf, 3.0),
            (-0.0, 0.0),
            (1e-300, 1e300),
        ];
        let values = [
            0.0, -0.0, 1.0, -1.0, 2.0, 3.0, -2.5, 1e-300, -1e300, 1e200, 0.1,
        ];
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = |m: usize| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % m as u64) as usize
        };
        for n in 0..14 {
            for _ in 0..200 {
                let (mut l, mut u, mut z, mut f) = (vec![], vec![], vec![], vec![]);
                for _ in 0..n {
                    let (lo, hi) = bounds[next(bounds.len())];
                    l.push(lo);
                    u.push(hi);
                    // z at a bound half of the time (where the normal point differs from z).
                    z.push(match next(4) {
                        0 => lo,
                        1 => hi,
                        _ => mid(lo, hi, values[next(values.len())]),
                    });
                    f.push(values[next(values.len())]);
                }
                let (want_x, want_merit) = branching(&z, &f, &l, &u);
                for avx2 in [false, true] {
                    let mut p = Point::default();
                    p.resize(n);
                    p.z.copy_from_slice(&z);
                    p.f.copy_from_slice(&f);
                    if avx2 {
                        #[cfg(target_arch = "x86_64")]
                        let has_avx2 = std::arch::is_x86_feature_detected!("avx2");
                        #[cfg(not(target_arch = "x86_64"))]
                        let has_avx2 = false;
                        if !has_avx2 {
                            continue;
                        }
                        normal_point(&mut p, &l, &u);
                    } else {
                        normal_point_squares_with(&mut p.x, &mut p.squares, &z, &f, &l, &u);
                        let s = p.squares.iter().fold(0.0, |s, c2| s + c2);
                        p.merit = if s.is_finite() { s.sqrt() } else { inf };
                    }
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&p.x), bits(&want_x), "{z:?} {f:?} {l:?} {u:?}");
                    assert_eq!(p.merit.to_bits(), want_merit.to_bits());
                }
            }
        }
    }

    /// `F(z) = z³ − 1`, free: `J(0) = 0`, so the linearisation at the start has no basis.
    fn cubic() -> FnMcp {
        FnMcp::dense(
            vec![f64::NEG_INFINITY],
            vec![f64::INFINITY],
            |z, f| f[0] = z[0] * z[0] * z[0] - 1.0,
            |z, j| j[0] = 3.0 * z[0] * z[0],
        )
        .unwrap()
    }

    #[test]
    fn path_polish_shifts_a_singular_reduced_jacobian() {
        // `z0² + z0 = 2` and an idle free unknown `z1` (F₁ ≡ 0, J singular), from a start that
        // meets the tolerance (residual 3e-11): the crash target's `J_II` is singular, so the
        // polish solves it with the proximal shift; `z0` ends at round-off, `z1` where it was.
        let p = FnMcp::dense(
            vec![f64::NEG_INFINITY; 2],
            vec![f64::INFINITY; 2],
            |z, f| {
                f[0] = z[0] * z[0] + z[0] - 2.0;
                f[1] = 0.0;
            },
            |z, j| {
                j.fill(0.0);
                j[0] = 2.0 * z[0] + 1.0;
            },
        )
        .unwrap();
        let z0 = [1.0 + 1e-11, 0.25];
        let sol = PathSolver::new(PathSettings::default())
            .solve(&p, &z0)
            .unwrap();
        assert!((sol.z[0] - 1.0).abs() <= 4.0 * f64::EPSILON, "{}", sol.z[0]);
        assert_eq!(sol.z[1], 0.25);
        assert!(sol.summary.residual <= 1e-15, "{}", sol.summary.residual);
        assert_eq!(sol.summary.iterations, 1);
        // Without the polish the start is the answer.
        let unpolished = PathSolver::new(PathSettings {
            polish_below: 1.0,
            ..PathSettings::default()
        })
        .solve(&p, &z0)
        .unwrap();
        assert_eq!(unpolished.z, z0.to_vec());
        assert_eq!(unpolished.summary.iterations, 0);
    }

    #[test]
    fn path_proximal_perturbation_handles_a_singular_jacobian() {
        let settings = PathSettings {
            crash_iterations: 0,
            restarts: 0,
            ..PathSettings::default()
        };
        let sol = PathSolver::new(settings.clone())
            .solve(&cubic(), &[0.0])
            .unwrap();
        assert!((sol.z[0] - 1.0).abs() < 1e-10);
        assert!(sol.summary.counter(Counter::ProximalPerturbations).unwrap() > 0);
        // Without the perturbation (λ capped at 0) the first linearisation is unsolvable.
        let err = PathSolver::new(PathSettings {
            proximal_max: 0.0,
            ..settings
        })
        .solve(&cubic(), &[0.0])
        .unwrap_err();
        let best = err.best().unwrap();
        assert_eq!(best.summary.termination, Termination::SubproblemFailed);
        assert_eq!(best.z, vec![0.0]);
    }

    #[test]
    fn path_watchdog_returns_to_the_checkpoint() {
        // Kojima–Shindo from MCPLIB start 6: the full Newton points blow up, the watchdog brings
        // the iteration back to its best point, and the path search continues from there.
        let p = kojima_shindo();
        let sol = PathSolver::new(PathSettings::default())
            .solve(&p.mcp, &p.starts[5].1)
            .unwrap();
        assert!(sol.summary.residual <= 1e-10);
        assert!(sol.summary.counter(Counter::WatchdogRestores).unwrap() > 0);
        assert!(sol.summary.counter(Counter::NonmonotoneSteps).unwrap() > 0);
    }

    #[test]
    fn path_crash_phase_finds_the_active_set() {
        let p = box_both_bounds();
        let mut solver = PathSolver::new(PathSettings::default());
        for (label, z0) in &p.starts {
            let sol = solver.solve(&p.mcp, z0).unwrap();
            assert!(
                sol.summary.counter(Counter::CrashSteps).unwrap() > 0,
                "{label}"
            );
            assert!(p.distance_to_solutions(&sol.z, None).unwrap() < 1e-10);
        }
    }

    struct Count(Arc<Mutex<usize>>);
    impl Observer for Count {
        fn observe(&mut self, _record: &IterationRecord) {
            if let Ok(mut c) = self.0.lock() {
                *c += 1;
            }
        }
    }

    #[test]
    fn path_observer_sees_every_iteration() {
        let seen = Arc::new(Mutex::new(0));
        let p = kojima_shindo();
        let mut solver =
            PathSolver::new(PathSettings::default()).with_observer(Box::new(Count(seen.clone())));
        let sol = solver.solve(&p.mcp, &p.starts[0].1).unwrap();
        assert_eq!(*seen.lock().unwrap(), sol.summary.iterations);
        assert!(sol.summary.trace.is_empty());
    }

    #[test]
    fn path_non_finite_start_is_reported_not_iterated() {
        let mcp = FnMcp::dense(
            vec![0.0],
            vec![f64::INFINITY],
            |z, f| f[0] = if z[0] > 0.0 { z[0] - 1.0 } else { f64::NAN },
            |_z, j| j[0] = 1.0,
        )
        .unwrap();
        let err = PathSolver::new(PathSettings::default())
            .solve(&mcp, &[0.0])
            .unwrap_err();
        let best = err.best().unwrap();
        assert_eq!(best.summary.termination, Termination::NonFiniteFunction);
        assert!(best.z.iter().all(|v| v.is_finite()));
    }

    /// `F(z) = √z + z − 2` on `z ≥ 0` (solution `z = 1`); `F` is not defined (NaN) below the
    /// box and its Jacobian `1/(2√z) + 1` is infinite at the bound `z = 0`, which is where the
    /// projection puts the Newton point from a start far to the right.
    fn sqrt_at_the_bound() -> FnMcp {
        FnMcp::dense(
            vec![0.0],
            vec![f64::INFINITY],
            |z, f| f[0] = z[0].sqrt() + z[0] - 2.0,
            |z, j| j[0] = 0.5 / z[0].sqrt() + 1.0,
        )
        .unwrap()
    }

    #[test]
    fn path_non_finite_jacobian_at_a_trial_point_is_a_failed_trial() {
        // Both the crash step and the Newton path end at z = 0 (J = +∞ there): the trial must be
        // refused and the step shortened instead of stopping with a non-finite function value.
        for crash_iterations in [0, 50] {
            let sol = PathSolver::new(PathSettings {
                crash_iterations,
                ..PathSettings::default()
            })
            .solve(&sqrt_at_the_bound(), &[100.0])
            .unwrap_or_else(|e| panic!("crash {crash_iterations}: {e}"));
            assert!((sol.z[0] - 1.0).abs() < 1e-10, "{:?}", sol.z);
            assert!(sol.summary.converged());
        }
        // The start itself at z = 0 has an infinite Jacobian: reported, not iterated.
        let err = PathSolver::new(PathSettings::default())
            .solve(&sqrt_at_the_bound(), &[0.0])
            .unwrap_err();
        let best = err.best().unwrap();
        assert_eq!(best.summary.termination, Termination::NonFiniteFunction);
    }

    /// `F(z) = e + 10⁻³ e²`, `e = z − 1`, free (root `z = 1`), whose Jacobian is not finite
    /// for `1e-9 < e < 2e-5` (a model outside its domain there); from `z = 1.1` the full crash
    /// step lands at `e ≈ 1.0e-5` (residual 1e-4 of the start's, so the next step is a chord
    /// step and the Jacobian is put off), the chord step at `e ≈ 2.0e-9`, the next at
    /// `e ≈ 4e-13`, within the tolerance. When `pause` is set, `F` there sleeps that long.
    fn deferred_jacobian_not_finite(pause: Option<std::time::Duration>) -> FnMcp {
        let bad = |z: f64| (1e-9..2e-5).contains(&(z - 1.0));
        FnMcp::dense(
            vec![f64::NEG_INFINITY],
            vec![f64::INFINITY],
            move |z, f| {
                let e = z[0] - 1.0;
                if let Some(p) = pause.filter(|_| bad(z[0])) {
                    std::thread::sleep(p);
                }
                f[0] = e + 1e-3 * e * e;
            },
            move |z, j| {
                j[0] = if bad(z[0]) {
                    f64::NAN
                } else {
                    1.0 + 2e-3 * (z[0] - 1.0)
                };
            },
        )
        .unwrap()
    }

    #[test]
    fn path_crash_limit_after_a_deferred_jacobian_goes_back_not_fails() {
        let p = deferred_jacobian_not_finite(None);
        // With the crash phase's default limit the chord steps end within the tolerance: one
        // Jacobian (at the start) in the whole solve.
        let sol = PathSolver::new(PathSettings::default())
            .solve(&p, &[1.1])
            .unwrap();
        assert_eq!(sol.summary.jac_evals, 1, "{:?}", sol.summary);
        assert_eq!(sol.summary.counter(Counter::PathSteps).unwrap(), 0);
        // The crash phase's limit ends it after the deferred crash step (1) or after its chord
        // step (2): the Jacobian there is not finite, so the iteration goes back to the start
        // and the Newton paths solve it (their path search backs off the bad points). Before,
        // the main loop met that Jacobian and the solve ended with `NonFiniteFunction`.
        for crash_iterations in [1, 2] {
            let sol = PathSolver::new(PathSettings {
                crash_iterations,
                ..PathSettings::default()
            })
            .solve(&p, &[1.1])
            .unwrap_or_else(|e| panic!("crash {crash_iterations}: {e}"));
            assert_eq!(sol.summary.termination, Termination::Converged);
            assert_eq!(
                sol.summary.counter(Counter::CrashSteps).unwrap(),
                crash_iterations
            );
            assert!(sol.summary.counter(Counter::PathSteps).unwrap() > 0);
            assert_eq!(sol.summary.counter(Counter::Restarts).unwrap(), 0);
            // Polished: the root to a few ulps.
            assert!((sol.z[0] - 1.0).abs() <= 4.0 * f64::EPSILON, "{}", sol.z[0]);
        }
    }

    #[test]
    fn path_budget_or_time_limit_mid_chord_is_reported_as_such() {
        // An iteration budget that ends the solve after the deferred crash step (1) or its
        // chord step (2): `max_iterations`, at the chord sequence's last point (its `F` is
        // finite), and no Jacobian evaluated where it was put off.
        let p = deferred_jacobian_not_finite(None);
        for (budget, error) in [(1, 1e-5), (2, 2e-9)] {
            let mut solver = PathSolver::new(PathSettings::default());
            solver.set_iteration_budget(Some(budget));
            let err = solver.solve(&p, &[1.1]).unwrap_err();
            let best = err.best().unwrap();
            assert_eq!(best.summary.termination, Termination::MaxIterations);
            assert_eq!(best.summary.iterations, budget);
            assert_eq!(best.summary.jac_evals, 1);
            // Where the chord sequence stood: e ≈ 1.0e-5, then ≈ 2.0e-9 (within 1 %).
            let e = best.z[0] - 1.0;
            assert!((e - error).abs() <= 0.01 * error, "{budget}: {e}");
        }
        // A time limit that runs out during the deferred crash step's evaluation (`F` sleeps
        // 0.2 s there, the limit is 0.05 s): `max_iterations` with the time limit counted, no
        // Jacobian where it was put off, no restarts.
        let p = deferred_jacobian_not_finite(Some(std::time::Duration::from_millis(200)));
        let err = PathSolver::new(PathSettings {
            time_limit: 0.05,
            ..PathSettings::default()
        })
        .solve(&p, &[1.1])
        .unwrap_err();
        let best = err.best().unwrap();
        assert_eq!(best.summary.termination, Termination::MaxIterations);
        assert_eq!(best.summary.counter(Counter::TimeLimitReached).unwrap(), 1);
        assert_eq!(best.summary.counter(Counter::Restarts).unwrap(), 0);
        assert!(best.summary.jac_evals <= 1, "{:?}", best.summary);
    }

    #[test]
    fn path_guarded_watchdog_breaks_the_checkpoint_cycle() {
        // Kojima–Josephy from MCPLIB start 6, without crash and restarts, 60 iterations per
        // attempt: the unguarded watchdog keeps leaving its checkpoint along diverging Newton
        // points after each short monotone step and runs out of iterations; the guarded attempt
        // stays monotone with its proximal term after a shortened step and converges.
        let p = ecp_model::mcp_library::kojima_josephy();
        let (label, z0) = &p.starts[5];
        assert_eq!(label, "mcplib6");
        let settings = PathSettings {
            crash_iterations: 0,
            restarts: 0,
            max_iterations: 60,
            guarded_watchdog: false,
            fischer_restart: false,
            best_point_restart: false,
            smoothing: None,
            // The diverging Newton points without the bound of the test below.
            watchdog_growth: f64::INFINITY,
            ..PathSettings::default()
        };
        let err = PathSolver::new(settings.clone())
            .solve(&p.mcp, z0)
            .unwrap_err();
        let best = err.best().unwrap();
        assert_eq!(best.summary.termination, Termination::MaxIterations);
        assert!(best.summary.counter(Counter::WatchdogRestores).unwrap() > 0);
        let sol = PathSolver::new(PathSettings {
            guarded_watchdog: true,
            ..settings
        })
        .solve(&p.mcp, z0)
        .unwrap();
        assert!(sol.summary.residual <= 1e-10);
        assert_eq!(sol.summary.counter(Counter::GuardedAttempts).unwrap(), 1);
        assert!(p.distance_to_solutions(&sol.z, None).unwrap() < 1e-8);
    }

    /// The cycle of the test above comes from Newton points far above the checkpoint's merit:
    /// with `watchdog_growth` (the default 1e6) the watchdog does not take them, and the
    /// unguarded first attempt converges by itself (docs/path.md#hard-steps).
    #[test]
    fn path_watchdog_growth_breaks_the_checkpoint_cycle() {
        let p = ecp_model::mcp_library::kojima_josephy();
        let z0 = &p.starts[5].1;
        let sol = PathSolver::new(PathSettings {
            crash_iterations: 0,
            restarts: 0,
            max_iterations: 60,
            guarded_watchdog: false,
            fischer_restart: false,
            best_point_restart: false,
            smoothing: None,
            ..PathSettings::default()
        })
        .solve(&p.mcp, z0)
        .unwrap();
        assert!(sol.summary.residual <= 1e-10);
        assert!(sol.summary.iterations <= 60);
        assert_eq!(sol.summary.counter(Counter::GuardedAttempts).unwrap(), 0);
        assert!(p.distance_to_solutions(&sol.z, None).unwrap() < 1e-8);
    }

    /// The configuration of the first test above without the guard or the growth bound, which
    /// fails: the smoothing
    /// continuation solves it by itself and lands on the problem's solution.
    #[test]
    fn path_smoothing_continuation_solves_what_the_plain_attempt_does_not() {
        let p = ecp_model::mcp_library::kojima_josephy();
        let z0 = &p.starts[5].1;
        let plain = PathSettings {
            crash_iterations: 0,
            restarts: 0,
            max_iterations: 60,
            guarded_watchdog: false,
            fischer_restart: false,
            best_point_restart: false,
            smoothing: None,
            watchdog_growth: f64::INFINITY,
            ..PathSettings::default()
        };
        let smoothed = PathSolver::new(PathSettings {
            smoothing: Some(SmoothingSettings::default()),
            ..plain
        })
        .solve(&p.mcp, z0)
        .unwrap();
        assert!(smoothed.summary.residual <= 1e-10);
        assert!(smoothed.summary.counter(Counter::SmoothingStages).unwrap() > 0);
        assert!(p.distance_to_solutions(&smoothed.z, None).unwrap() < 1e-8);
    }

    #[test]
    fn path_time_limit_stops_the_solve_with_its_best_point() {
        // Kojima–Shindo needs several pivotal steps from MCPLIB start 1; with a budget spent
        // before the first one, the solve stops at once (no restarts) and reports it.
        let p = kojima_shindo();
        let z0 = &p.starts[0].1;
        let err = PathSolver::new(PathSettings {
            time_limit: 1e-9,
            ..PathSettings::default()
        })
        .solve(&p.mcp, z0)
        .unwrap_err();
        let best = err.best().unwrap();
        assert_eq!(best.summary.termination, Termination::MaxIterations);
        assert_eq!(best.summary.counter(Counter::TimeLimitReached).unwrap(), 1);
        assert_eq!(best.summary.counter(Counter::Restarts).unwrap(), 0);
        assert_eq!(best.summary.iterations, 0);
        // The same solve without a budget converges and does not report one.
        let sol = PathSolver::new(PathSettings {
            time_limit: f64::INFINITY,
            ..PathSettings::default()
        })
        .solve(&p.mcp, z0)
        .unwrap();
        assert!(sol.summary.residual <= 1e-10);
        assert_eq!(sol.summary.counter(Counter::TimeLimitReached).unwrap(), 0);
    }

    #[test]
    fn path_empty_problem_converges() {
        let mcp = FnMcp::dense(vec![], vec![], |_z, _f| {}, |_z, _j| {}).unwrap();
        let sol = PathSolver::new(PathSettings::default())
            .solve(&mcp, &[])
            .unwrap();
        assert!(sol.z.is_empty() && sol.summary.converged());
    }

    /// `F` at the start handed over (`Mcp::known_value`) replaces the start's evaluation of
    /// every Kojima–Shindo start that is inside the bounds (its `π(x₀)` is the start itself),
    /// and the solve returns the same point, residual, iterations and `f_evals` bit for bit.
    #[test]
    fn f_at_the_start_handed_over_replaces_the_start_evaluation() {
        let p = kojima_shindo();
        let mut handed_over = 0;
        for (label, z0) in &p.starts {
            let mut f = vec![0.0; z0.len()];
            p.mcp.evaluate(z0, &mut f);
            let solve = |known: bool| {
                let z = if known { z0.clone() } else { Vec::new() };
                let mcp = KnownAt::new(&p.mcp, z, f.clone());
                let sol = PathSolver::new(PathSettings::default())
                    .solve(&mcp, z0)
                    .unwrap_or_else(|e| panic!("{label}: {e}"));
                (sol, mcp.evaluations.get())
            };
            let ((plain, plain_evaluations), (handed, handed_evaluations)) =
                (solve(false), solve(true));
            let inside = z0.iter().all(|v| *v >= 0.0);
            assert_eq!(
                handed_evaluations + usize::from(inside),
                plain_evaluations,
                "{label}"
            );
            handed_over += usize::from(inside);
            assert!(plain.summary.residual <= 1e-10, "{label}");
            assert_eq!(handed.z, plain.z, "{label}");
            assert_eq!(handed.summary.residual, plain.summary.residual, "{label}");
            assert_eq!(
                handed.summary.iterations, plain.summary.iterations,
                "{label}"
            );
            assert_eq!(handed.summary.f_evals, plain.summary.f_evals, "{label}");
        }
        assert!(handed_over >= 2, "{handed_over}");
    }
}
