//! Semismooth Newton method on the Fischer–Burmeister reformulation (`docs/backends.md#semismooth-newton`).
//!
//! The MCP is rewritten as `Φ(z) = 0` with `φ(a, b) = √(a² + b²) − a − b`: free components
//! `Φ_i = F_i`; lower bound only `φ(z_i − l_i, F_i)`; upper bound only `−φ(u_i − z_i, −F_i)`;
//! both bounds Billups' composition `φ(z_i − l_i, φ(u_i − z_i, −F_i))`. Each iteration takes an
//! element `H = D_a + D_b J` of the generalised Jacobian (at degenerate pairs the element of
//! De Luca, Facchinei and Kanzow), solves `H d = −Φ`, and accepts the step by an Armijo search on
//! `Ψ = ½‖Φ‖²`. When `H` is singular or `d` fails the descent test `∇Ψᵀd ≤ −ρ‖d‖^p`, it first
//! tries, when enabled ([`NewtonSettings::min_norm_step`], on by default), the
//! minimum-norm least-squares step `d = −H⁺Φ` on dense problems, then a
//! Levenberg–Marquardt step `(HᵀH + λI) d = −HᵀΦ`, and failing that the steepest-descent
//! step `−∇Ψ`. Linear systems use dense LU for small problems and a sparse LU (analysed once per
//! pattern) for large ones.
//!
//! The minimum-norm step is for problems whose solutions are not isolated (`docs/model.md#union`):
//! in the union-of-pieces model the normal impulses and the ECPs of the pieces are not
//! unique, `H` is singular on the whole solution set, and Levenberg–Marquardt, whose damping
//! cannot go below the round-off floor of `HᵀH`, converges linearly (measured on the union
//! desk: 21–176 iterations per step, 12 of 400 steps at the 200-iteration limit). The
//! Gauss–Newton step with the Moore–Penrose inverse converges quadratically to a point of the
//! solution set instead. Near a solution it often has to cross a kink of `Φ` (a face
//! multiplier `l_i = 0` whose face becomes active: the Fischer–Burmeister element of that row
//! ignores the face until the step has crossed it), where `Ψ` rises for one step; a watchdog
//! (Chamberlain, Powell, Lemaréchal, Pedersen, Math. Prog. Study 16, 1982; as in PATH) takes
//! such a step and returns to the point before it when `Ψ` has not fallen below its value there
//! within [`NewtonSettings::watchdog_steps`] steps. Far from a solution
//! ([`NewtonSettings::min_norm_radius`]) the minimum-norm step is only taken when it halves `Ψ`
//! at once, and Levenberg–Marquardt globalises as before. Minimum-norm steps count as Newton
//! steps in the summary, with their own counters `"min_norm_steps"`, `"nonmonotone_steps"`
//! (taken under the watchdog) and `"watchdog_restores"`.
//!
//! References: De Luca, Facchinei, Kanzow, Math. Prog. 75 (1996); Billups, PhD thesis (1995);
//! Munson, Facchinei, Ferris, Fischer, Kanzow, INFORMS J. Computing 13 (2001); Ben-Israel,
//! J. Math. Anal. Appl. 15 (1966) for the Gauss–Newton method with the Moore–Penrose inverse.

use std::sync::Arc;
use std::time::Instant;

use ecp_model::bounds::{BoundKind, classify};
use ecp_model::linalg::LinearSolver;
use ecp_model::mcp::{
    FinalResiduals, fb_vector_of_kinds_squared, fischer_burmeister, worst_component_of_residual,
};
use ecp_model::{
    Counter, CscPattern, IterationRecord, Mcp, McpSolver, Observer, Solution, SolveError,
    SolveReport, StepKind, Termination, finish_solve, finish_solve_with, natural_residual,
    solve_in_scales, validate_start,
};

use crate::normal_equations::NormalEquations;

mod complementary;
mod friction_continuation;

mod josephy;
mod min_norm;
mod profile;
mod ratio;
mod reseed;
use crate::smoothing::{SmoothingSettings, continuation};
use min_norm::MinNorm;
use profile::Clock;
pub use profile::{NewtonProfile, Phase};

/// Settings of the semismooth Newton backend, with documented defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct NewtonSettings {
    /// Stop when the natural residual `‖z − mid(l, u, z − F)‖∞` is at most this. Default `1e-10`.
    pub tolerance: f64,
    /// Iteration limit. Default 200.
    pub max_iterations: usize,
    /// Armijo sufficient-decrease constant σ. Default `1e-4`.
    pub armijo: f64,
    /// Backtracking factor β of the line search. Default `0.5`.
    pub backtrack: f64,
    /// Smallest step length tried before the line search gives up on a direction. Default `1e-12`.
    pub min_step: f64,
    /// Descent test `∇Ψᵀd ≤ −ρ‖d‖^p`: the constant ρ. Default `1e-8`.
    pub descent_rho: f64,
    /// Descent test exponent p (> 2). Default `2.1`.
    pub descent_p: f64,
    /// Initial Levenberg–Marquardt damping, relative to the largest diagonal entry of `HᵀH`.
    /// Default `1e-3`.
    pub lm_initial_damping: f64,
    /// Damping trials per iteration before the backtracking fall-backs. Default 30.
    pub max_lm_trials: usize,
    /// Factorise the Levenberg–Marquardt matrix `HᵀH + λI` of dense problems by Cholesky
    /// instead of LU (half the arithmetic; `HᵀH` is formed once per iteration either way,
    /// `docs/newton.md#wall-time`). Default `false`.
    pub lm_cholesky: bool,
    /// In the plain iteration (not in the restarts after it), from this many
    /// Levenberg–Marquardt iterations of one run on, the damping is
    /// `λ = ν‖Φ‖²` (Yamashita–Fukushima; `ν` adapted by the ratio of actual to predicted
    /// decrease, as Fan and Pan adapt it) instead of Moré's `λ = μ · max diag(HᵀH)`, whose factor
    /// falls by at most 3 per step from [`NewtonSettings::lm_initial_damping`]. Where the plain
    /// iteration has to follow a long valley of the merit (a contact point sliding along an edge
    /// that lies flat on the support, `docs/newton.md#linearly-converging-steps`) Moré's damping
    /// takes a dozen steps of ρ ≈ 1 before the steps reach the length the valley allows. The
    /// first iterations of a run keep Moré's damping, so steps that need few
    /// Levenberg–Marquardt iterations are unchanged. `None` turns it off. Default `Some(3)`.
    pub lm_residual_damping_after: Option<usize>,
    /// Above [`NewtonSettings::dense_max`], solve the Levenberg–Marquardt system as the formed
    /// product `HᵀH + λI` by a sparse Cholesky (fill-reducing ordering, analysed once per
    /// pattern) when its symbolic analysis finds it cheaper than the sparse LU of the augmented
    /// `2n × 2n` system, which is used otherwise (`docs/newton.md#cheap-levenberg-marquardt-trials`:
    /// on `025_multi_body`'s 170 unknowns in four bodies, 0.08 ms a trial instead of 1.1 ms).
    /// `false`: always the augmented system, as before. Problems up to `dense_max` are
    /// unchanged either way. Default `true`.
    pub lm_sparse_product: bool,
    /// Largest dimension solved with dense LU; larger problems use sparse LU. Default 120.
    pub dense_max: usize,
    /// Solve the Newton systems of dense problems by block elimination of the problem's
    /// elimination groups ([`ecp_model::Mcp::elimination_groups`]: a body's Newton–Euler and
    /// kinematic-map unknowns), leaving a dense system in the contact unknowns
    /// (`docs/latency.md#structured-linear-solve`); the LU of the whole matrix for problems
    /// without groups, and for a matrix whose block elimination fails. Default `false`.
    pub structured_solve: bool,
    /// When the LU of `H` is singular or its step fails the descent test, try the
    /// minimum-norm least-squares step `d = −H⁺Φ` (complete orthogonal decomposition, dense
    /// problems only) before the Levenberg–Marquardt safeguard. At the solutions of the
    /// union-of-pieces model `H` is singular on a whole solution set (`docs/model.md#union`);
    /// there this step converges quadratically where Levenberg–Marquardt crawls. Default
    /// `true`: it helps the hull model too (measured on the ordinary scenes of
    /// `examples/newton_robustness.rs`: 244 → 96 failed steps of 5368, most of the gain on a
    /// box thrown into a corner, docs/newton.md). Its non-monotone steps can lead to a worse end
    /// point on isolated but hard steps (a tipping box once in the air, measured on A6 at
    /// 110 N), so a solve that fails after taking them is restarted once without them.
    pub min_norm_step: bool,
    /// Largest dimension on which [`NewtonSettings::min_norm_step`] is taken (its dense QR);
    /// the LU stays sparse above [`NewtonSettings::dense_max`]. Was `dense_max` (120): on
    /// `129_multi_body` of the held-out seed 20270320 (144 unknowns, four bodies, three resting
    /// on faces, where `H` is singular) every step then crawled 20 Levenberg–Marquardt iterations
    /// before the Josephy–Newton restart solved it (80× PATH's instructions); with the step,
    /// one iteration (`docs/stress.md`, branch wip-heldout4). Default 200.
    pub min_norm_max: usize,
    /// Numerical rank of `H` for the minimum-norm step: columns whose remaining norm in the
    /// pivoted QR falls below this times the largest column norm are treated as dependent.
    /// Default `1e-10`.
    pub rank_tolerance: f64,
    /// "Near a solution" for the minimum-norm step: the natural residual is at most this, or `Ψ`
    /// has fallen below `1e-6` of its value at the start. Near a solution the step is taken with
    /// the watchdog and backtracking; farther out only when it halves `Ψ` at once, so that
    /// Levenberg–Marquardt's damping keeps the globalisation (the undamped step led a
    /// separated T-bar step of tests/closest_points.rs into the spurious `p_n > 0` minimiser).
    /// Default `1e-3`.
    pub min_norm_radius: f64,
    /// Watchdog of the minimum-norm steps: a full step that fails the Armijo test is still
    /// taken, and the iteration returns to the point before it when Ψ has not fallen below
    /// its value there within this many steps (0: monotone only). Default 4.
    pub watchdog_steps: usize,
    /// Give a zero column of `H` (a variable that does not enter the linearisation, such as the
    /// slip rate σ of an open contact) its row's scale on the diagonal for the factorisation,
    /// so that the Newton step is taken rather than failing the LU of the whole system
    /// (docs/newton.md). Default `true`.
    pub pin_zero_columns: bool,
    /// Factorise `H` on its free block: the rows of components held at a bound (`D_b,i = 0`,
    /// so row `i` of `H` is `D_a,i e_iᵀ`) are left out of the LU, their step is `−Φ_i / D_a,i`
    /// and the other rows' block is factorised alone
    /// ([`ecp_model::linalg::LinearSolver::factor_with_unit_rows`]; the dense LU only). The
    /// same step up to round-off (`docs/latency.md`, "Newton's Jacobian on its free block").
    /// Default `true`.
    pub free_block: bool,
    /// When the full Newton step fails the Armijo test, backtrack along the Newton direction
    /// (down to [`NewtonSettings::newton_shortest_step`]) and take that step instead of the
    /// Levenberg–Marquardt safeguard's when it lowers Ψ more. Without it, landing steps crawl
    /// with Levenberg–Marquardt steps far from the solution; taken without the comparison,
    /// tiny steps along poor Newton directions stall the spinning T-bar (docs/newton.md).
    /// Default `true`.
    pub newton_line_search: bool,
    /// Shortest step length of that search. Default `1e-4`.
    pub newton_shortest_step: f64,
    /// A solve that reaches the tolerance with a natural residual above this fraction of it
    /// takes one more full Newton step (the minimum-norm step where `H` is singular, in a run
    /// that took steps of the ratio test, dense problems), kept when it lowers the residual:
    /// the local phase is
    /// quadratic, so the step costs one factorisation and usually gains several digits. It
    /// matters where the solution is sensitive to the residual (a spinning box coming to rest:
    /// ω_z off by 6e-9 at natural residual 1.7e-11, docs/newton.md; D5's vertical momentum,
    /// which the ground's normal impulses set: off by 5.2e-12 at a residual of 5.2e-12 in a
    /// ground contact, `docs/newton.md#the-ratio-test`). Default `1e-3`.
    pub polish_below: f64,
    /// After a failed solve, solve again from the start by the smoothing continuation
    /// (`docs/newton.md#smoothing-continuation`, [`crate::smoothing`]): this iteration on the
    /// smoothed natural map `G_μ`, whose zeros keep every complementarity pair strictly inside
    /// (`(z_i − l_i) F_i = μ²`), for `μ = μ₀, θμ₀, θ²μ₀, …` down to the tolerance, each stage
    /// from the last one's point, then on the MCP from there. It gets across the local
    /// minimisers of the Fischer–Burmeister merit where a contact changes its active faces
    /// within a step. `None` turns it off. Default: `SmoothingSettings::default()` with `max_failed_stages = Some(FAILED_STAGES)`
    /// and `count_cut_stages = true`.
    pub smoothing: Option<SmoothingSettings>,
    /// Initial Levenberg–Marquardt damping of the restarts (instead of
    /// [`NewtonSettings::lm_initial_damping`]): after a failed plain iteration, the plain
    /// iteration once more from the start with it, and after a failed smoothing continuation the
    /// continuation once more with it (`docs/newton.md#wall-time` for the order); the best end
    /// point is returned when all fail. Where the
    /// first lightly damped steps from a poor warm start lead into the basin of a spurious
    /// minimiser of the merit (a loaded contact's closest point pulled to another vertex),
    /// heavily damped first steps stay in the solution's basin
    /// (`docs/newton.md#damped-restart`). It runs only after the plain iteration has
    /// failed, so steps the plain iteration solves are unchanged. `None` turns it off. Default `Some(0.1)`.
    pub damped_restart: Option<f64>,
    /// Run the smoothing continuation before the damped plain iteration (instead of after it):
    /// with [`SmoothingSettings::max_failed_stages`] a failing continuation is no longer the
    /// most expensive attempt, and where the plain iteration stalls the continuation usually
    /// solves the step in a few dozen iterations (`docs/newton.md#wall-time`). Dense problems
    /// only (`n ≤ dense_max`): on bin20's 659 unknowns the damped plain iteration solved steps
    /// 8, 9 and 15 where the continuation first took 1215, 520 and 151 iterations, each with a
    /// sparse LU of the augmented Levenberg–Marquardt system. Default `true`.
    pub smoothing_first: bool,
    /// Stall test of one iteration: it stops (`stagnated`) when its best natural residual has
    /// not fallen below [`NewtonSettings::stall_reduction`] times its value this many
    /// iterations earlier, so that a solve stuck far from a solution passes to its restarts
    /// instead of running to [`NewtonSettings::max_iterations`] (`docs/newton.md#wall-time`).
    /// 0 turns it off. Default 30.
    pub stall_window: usize,
    /// The reduction the stall test asks for over [`NewtonSettings::stall_window`] iterations.
    /// Default `0.5`.
    pub stall_reduction: f64,
    /// Rate test of one iteration, with [`NewtonSettings::stall_window`] `W`: from `2W`
    /// iterations of a run on, a run whose best natural residual falls so slowly that, at its
    /// rate over the last `W` iterations, it would need more than 6 times the iterations it has
    /// left to reach the tolerance stops (`stagnated`) and passes to the next attempt (not in
    /// the smoothing continuation). The stall
    /// test passes a run that halves its residual every 30 iterations; such a run ends at
    /// [`NewtonSettings::max_iterations`] far from the tolerance (`023_room_corner` step 36: 200
    /// Levenberg–Marquardt iterations from 5e-1 to 1.7e-6, then the non-monotone restart solves
    /// the step in 36, `docs/newton.md#newtons-hard-steps-in-the-room-corner`). Runs shorter
    /// than `2W` are unchanged. Default `true`.
    pub slow_rate_test: bool,
    /// Flat-merit test of one iteration: from `2K` iterations of a run on (`K` this window), a
    /// run whose lowest `Ψ` has not fallen by 0.1 % over the last `K` iterations stops
    /// (`stagnated`): it sits at a stationary point of the merit that is not a solution
    /// (Levenberg–Marquardt steps of length 1e-9 at a fixed `Ψ`), where the stall test still
    /// waits for the rest of its window (`023_room_corner` steps 79, 88, 89). Runs shorter than
    /// `2K` and the smoothing continuation's runs are unchanged. 0 turns it off. Default 10.
    pub flat_merit_window: usize,
    /// Ratio test in the plain iteration's line search (`docs/newton.md#the-ratio-test`): when
    /// the full Newton step fails the Armijo test, the point where the first
    /// complementarity pair leaves its cone along the step's linearisation (a component reaching
    /// its bound from inside, or the residual of a component at its bound crossing zero) is
    /// taken — when `Ψ` falls there by half the fall the linearisation predicts; when it falls
    /// less, the point competes with the Levenberg–Marquardt step (`018_union_tip` step 50: 145
    /// → 6 iterations); when `Ψ` rises, under the watchdog of
    /// [`NewtonSettings::watchdog_steps`] — before the backtracking and Levenberg–Marquardt. The
    /// Fischer–Burmeister row of an inactive pair linearises to "stay at the bound" and ignores
    /// its residual, so a long step drives the residual of an inactive face far below zero and
    /// `Ψ` up by orders of magnitude; PATH's pivoting stops at the first such event
    /// (`023_room_corner` step 36: 181 iterations with the non-monotone restart, 71 in the plain
    /// iteration with it; step 88: 246 with the continuation, 28). It runs from the first
    /// iteration, along the Newton direction only: a full Newton step that fails the Armijo
    /// test is the situation it describes. Not along the minimum-norm direction (a singular `H`,
    /// a solution set that is not isolated, where a pair's event is no basis change): there it
    /// cut the union T-bar's step 38 from 3 iterations to 227 (`docs/newton.md#the-ratio-test`).
    /// Default `true`.
    pub ratio_test: bool,
    /// After a failed plain iteration, the plain iteration once more from the start in which a
    /// full Newton step that fails the Armijo test is still taken, under the watchdog of
    /// [`NewtonSettings::watchdog_steps`] (back to the point before it when `Ψ` has not fallen
    /// below its value there within that many steps), before the other restarts. Where the
    /// merit is strongly curved along a good Newton direction (a contact moving to another
    /// feature of the hull while the body's rotation changes by radians per second) the
    /// monotone search accepts steps of 1/64 … 1/4 of it and crawls to the solution in 80
    /// iterations or is cut by the stall test, where the full steps converge in ten
    /// (`docs/newton.md#hard-steps`). Only after the plain iteration failed, so every step it
    /// solves is unchanged; on problems above [`NewtonSettings::dense_max`] after the damped
    /// plain iteration too. Default `true`.
    pub nonmonotone_restart: bool,
    /// Steps undone by the watchdog (a failed non-monotone sequence, taken back to its
    /// checkpoint) count neither in the stall test's window nor as minimum-norm steps for the
    /// restart without them ([`NewtonSettings::min_norm_step`]), and the stall test does not
    /// judge a run while such a sequence is open. After a restore the iteration goes on as the
    /// restart would from that point, so the restart replayed the same iterations, and the stall
    /// test had cut the first run 4 iterations before it would have converged
    /// (`docs/newton.md#linearly-converging-steps`). Default `true`.
    pub forget_undone_steps: bool,
    /// After every other attempt from `z0` failed with a best natural residual of at most this
    /// times [`NewtonSettings::tolerance`], the plain iteration once more from the complementary
    /// start: `z0` with every bounded component put on the bound that the sign of `F(z0)` points
    /// to (`z_i = l_i` where `F_i > 0`, `z_i = u_i` where `F_i < 0`). Where a pair is slack on
    /// both sides at `z0` (a slip rate `σ > 0` while the friction cone row is positive by
    /// round-off), every attempt from `z0` stays on that branch of the pair and can end at a
    /// point that is not a solution (`061_v_trough` of seed 20261128, step 17: a box coming to
    /// rest in a V trough, every attempt stagnating at 1.3 times the tolerance; from this start
    /// the plain iteration converges in 10 iterations, `docs/newton.md#the-complementary-start`).
    /// The attempts that ended far from a solution (3.5e4 times the tolerance and more on the
    /// stress scenes) have other causes, and there the start did not help. After every other
    /// attempt failed, so every step they solve is unchanged — unless
    /// [`NewtonSettings::early_complementary_restart`] ran it before the continuations already.
    /// `None` turns it off (the early restart has its own setting).
    /// Default `Some(1e3)`.
    pub complementary_restart: Option<f64>,
    /// The complementary restart ([`NewtonSettings::complementary_restart`]) tried earlier:
    /// when the attempts before the first smoothing continuation (by default the plain and the
    /// non-monotone one) failed with a best natural residual of at most this times
    /// [`NewtonSettings::tolerance`], it runs before that continuation; the later attempts run
    /// only if it fails too, and the late complementary restart is not repeated (it is the same
    /// run). On a step where the undamped
    /// attempts stay on one branch of a pair that is slack on both sides, this cuts the
    /// continuations' hundreds of iterations (`docs/newton.md#the-complementary-start-earlier`).
    /// `None` keeps the complementary restart last. Default `Some(3e4)`.
    pub early_complementary_restart: Option<f64>,
    /// After every attempt failed (the complementary restart from `z0` too) with a best natural
    /// residual of at most this times [`NewtonSettings::tolerance`], the plain iteration once
    /// more from the complementary start of the failed attempts' **best point** rather than of
    /// `z0`. On `061_v_trough` of the held-out seed 20261201, step 70, every attempt ends in a
    /// curved valley of the merit (a contact point sliding along an edge that lies flat on a
    /// plane, floor 1.3e3 times the tolerance) that the attempts from `z0` all enter; the
    /// complementary start of the valley's point leaves it and converges
    /// (`docs/newton.md#the-complementary-start-from-the-best-point`). Runs only where the solve
    /// would otherwise fail, so every step solved without it is unchanged. `None` turns it off
    /// (the conic backend's Newton finish). Default `Some(3e4)`.
    pub complementary_restart_from_best: Option<f64>,
    /// After every other attempt failed, a continuation in the friction coefficient: the plain
    /// iteration from `z0` on the step with `μ` halved (or quartered), then the curve
    /// of the solutions of the family `F(z; s)` with `s μ` ([`ecp_model::Mcp::friction_family`])
    /// followed by arc length to `s = 1`, round the folds where the warm start's branch ends, and
    /// the plain iteration on the step from there (`docs/newton.md#a-continuation-in-the-friction-coefficient`).
    /// The value is the most iterations of the curve (decompositions of `[H Φ_s]`; the crease
    /// step below takes 300). On `022_v_trough` of the held-out seed 20261212,
    /// step 62, a vertex in the trough's crease: the warm start's branch (the body sliding)
    /// ends at `s = 0.82`, the curve turns back to `s = 0.77` and reaches `s = 1` on the branch
    /// that wedges the body, where every other attempt stalls. Runs only where the solve would
    /// otherwise fail, on problems with a friction family of at most
    /// [`NewtonSettings::dense_max`] unknowns. `None` turns it off. Default `Some(400)`.
    pub friction_continuation: Option<usize>,
    /// When the whole solve from `z0` failed (not within an iteration budget), solve once more
    /// from the warm start's contacts re-derived by the problem's structure
    /// ([`ecp_model::StepStructure::assemble`]): the velocities of `z0`, each contact's normal
    /// impulse on its patch's lowest vertex at `z0`'s configuration, so its point is the one
    /// the geometry gives there instead of the warm start's (`newton/reseed.rs`). On a body
    /// spinning 2 rad a step, the warm start's contact point lies on a vertex that has turned
    /// away, and every attempt from it stalls at a local minimiser of the merit
    /// (`s20270320_070_union_tip`, step 97: 2 096 iterations, then 59 from the reseeded start).
    /// Runs only on problems with a structure, only after a failure. Default `true`.
    pub structure_reseed: bool,

    /// After the plain iteration from `z0` failed (in a budgeted run too,
    /// [`McpSolver::set_iteration_budget`]), up to this many Josephy–Newton steps from `z0`
    /// (the MCP linearised at each point solved by Lemke's method, a search on the merit;
    /// `newton/josephy.rs`), then the plain iteration from the best point they met, before the
    /// other attempts. Cures the long steps where contacts load, unload or change their closest
    /// feature: the plain iteration stalls at a local minimiser of the merit, the restarts after
    /// it cost hundreds of iterations (`docs/newton.md#josephy-newton-steps`: the held-out seeds'
    /// room corners 500–650 → under 80 iterations). Runs only after a failed plain run, so every
    /// step that run solves is unchanged. At most `max_iterations` steps, like every attempt.
    /// `None`: off. Default `Some(20)`.
    pub josephy_newton: Option<usize>,
    /// A budgeted run ([`McpSolver::set_iteration_budget`]) whose plain iteration is converging
    /// when its budget is spent — its last iteration lowered the best natural residual by this
    /// factor at least (Newton's local rate, not a stall) — goes on while each iteration keeps
    /// lowering it by this factor, up to [`NewtonSettings::max_iterations`]. The budget is
    /// there to give up cheaply on a start that is not working; a run one iteration short of
    /// converging is working, and stopping it sends the budgeted solve into its Josephy–Newton
    /// attempt (`s20270403_087_v_trough` step 71: 9 plain iterations against a budget of 8, then
    /// 56 Lemke runs, 0.95 G instructions; `docs/stress.md`). `None`: the budget caps the run
    /// exactly. Default `Some(0.1)`.
    pub budget_grace: Option<f64>,
    /// Solve in the problem's scene scales when it has them ([`ecp_model::solve_in_scales`],
    /// `docs/decisions.md#scene-scaled-convergence`). Off for a caller that judges the result
    /// in the problem's own units (the conic backend's Newton finish). Default `true`.
    pub scene_scales: bool,
    /// Chord (simplified Newton) steps: near a solution, the next step solves `H₀ d = −Φ(z)`
    /// with the LU of `H₀` kept from an earlier iterate of the run instead of forming and
    /// factorising `H` at `z` (`docs/latency.md`, section "Chord steps: Newton's desk step with
    /// one factorisation fewer"). Taken only after a step by that LU that lowered the natural
    /// residual by this factor at least, into [`NewtonSettings::min_norm_radius`], when `H₀`
    /// had no pinned columns ([`NewtonSettings::pin_zero_columns`]) and every complementarity
    /// pair is on the branch (`z` at a bound or `F` zero, as the natural residual's `mid`
    /// selects it) it had where `H₀` was formed; the step is kept only when it lowers `Ψ` and
    /// the natural residual by this factor again (or to the round-off floor,
    /// [`NewtonSettings::chord_round_off_floor`]), otherwise the iteration forms and factorises
    /// `H` at `z` at once. A chord step counts as an iteration and a Newton step. It is never
    /// the polish of [`NewtonSettings::polish_below`], so a run stops by the same test as
    /// without it; a run whose last step was a chord step then takes one more (the chord's
    /// polish, kept when it lowers the residual: the chord's rate is linear), but not beyond
    /// the iteration limit, nor at a round-off floor ([`NewtonSettings::chord_round_off_floor`]).
    /// `None` turns it off. Default `Some(1e-3)`.
    pub chord_contraction: Option<f64>,
    /// Chord steps across solves: the first iteration of a solve first tries a chord step
    /// ([`NewtonSettings::chord_contraction`]) on the LU kept from the solver's last solve
    /// (the next time step's problem: the same Jacobian pattern and, on a steady contact, nearly
    /// the same `H`), and the chord steps on that LU go on while each lowers the natural
    /// residual by this factor (instead of `chord_contraction`: that `H` is a step old, so its
    /// rate is slower than that of an `H` formed in the run, and a chord step costs a sixth of a
    /// factorising iteration). Kept only from a solve that converged with that LU as its last
    /// factorisation (no pinned columns, its step a descent step) in one step on it that
    /// reached the round-off floor ([`NewtonSettings::chord_round_off_floor`]), or in no step
    /// on the LU it was given: a nearly linear step (A1's sliding box), whose next step one
    /// chord step on it solves, unlike the desk's (several steps a solve, where chord steps on
    /// a step-old `H` cost more than they save). Only for a problem with the same Jacobian
    /// pattern and the same bound kinds; tried only by the first run of a solve, and after a
    /// try that did not pay (the run factorised after all) not by the next 1, 2, 4, … (at most
    /// 64) solves. The chord step's own tests decide it (every pair on the branch it had where
    /// that `H` was formed, `Ψ` falls, the residual falls by this factor); refused, the
    /// iteration forms and factorises `H` at once. Needs `chord_contraction`. `None`: every
    /// solve factorises first, as before. Default `Some(1e-2)` (measured: `docs/latency.md`,
    /// "Newton's desk step on the LU kept from the step before" and "The A1 step in 2 µs").
    pub chord_across_solves: Option<f64>,
    /// The round-off floor of the chord steps ([`NewtonSettings::chord_contraction`]), in units
    /// of round-off (`f64::EPSILON`) of `‖z‖∞`: the natural residual `z − mid(l, u, z − F)` is a
    /// difference of numbers of that size, so no step lowers it much below. A chord step that
    /// reaches the floor is kept as one that contracts the residual by `chord_contraction` is
    /// (near the floor none does: on the desk 92 of 400 steps refused such a chord step at
    /// 1e-13 and factorised for a full step to the same 1e-16), and a run at the floor takes no
    /// chord's polish. On the desk `‖z‖∞` ≈ 1.5–2 in the scene scales, so the floor is
    /// 1.3e-15–1.8e-15; the second chord step ends at 1e-16–9e-16. Only below
    /// `polish_below · tolerance`, where a run of full steps stops unpolished. `None`: neither.
    /// Default `Some(4.0)`.
    pub chord_round_off_floor: Option<f64>,
    /// The full Newton step taken first: when the full step of an LU direction lowers `Ψ` to
    /// at most this fraction of `Ψ`, it is taken without the descent test
    /// ([`NewtonSettings::descent_rho`]) and the Armijo test, and `∇Ψ = HᵀΦ` is not formed
    /// (with an exact solve `∇Ψᵀd = −2Ψ`, and such a step passes the Armijo test by far). Any
    /// other full step is judged as without it (`∇Ψ` formed then, the same step). Not in the
    /// polish of [`NewtonSettings::polish_below`], nor on an `H` with pinned columns
    /// ([`NewtonSettings::pin_zero_columns`]), and only when `2Ψ ≥ ρ‖d‖^p` (the descent test
    /// with `∇Ψᵀd = −2Ψ`). `None`: `∇Ψ` and the tests before the step, as before. Default
    /// `Some(1e-2)` (`docs/latency.md`, "Newton's desk iteration outside the LU": the same
    /// points on the reference scenes and three stress seeds, ≈ 4 k instructions fewer per desk
    /// step).
    pub fast_full_step: Option<f64>,
    /// The bound held at a pair within round-off of the kink: a component exactly at its bound
    /// (`z = l`, or `z = u`) whose `F` points out of the feasible side by at most this much
    /// (`−band ≤ F < 0` at a lower bound, `0 < F ≤ band` at an upper one) gets the row of
    /// `H` of a pair with `F` on the feasible side, `−e_i` (the element `(ξ, η) = (0, 1)` of
    /// `∂φ(0, 0)`): the Newton step holds `z_i` at its bound. Without it the sign of the
    /// round-off in `F` chooses between that row and `−e_i − 2∇F_i`, a row that asks
    /// `z_i + 2F_i` to stay put: at A1's step 35 (the box stops within the step; the
    /// extrapolated start has `σ = 0` and `μ p_n − ‖E⁻¹p_f‖` = ±5e-16) the first takes the
    /// full step to sticking (1 iteration), the second a cut step, a Levenberg–Marquardt step
    /// and 9 iterations (`docs/latency.md`, "Newton at the stop of a sliding box: A1 step 35").
    /// At an attempt's first iteration only (the warm start), in the units Newton sees `F`
    /// (the scene scales when [`NewtonSettings::scene_scales`]).
    /// `None`: the partial derivatives at the point, whatever the sign. Default `None`.
    pub kink_band: Option<f64>,
    /// Record a per-iteration trace in the summary. Default `false`.
    pub trace: bool,
}

impl Default for NewtonSettings {
    fn default() -> Self {
        NewtonSettings {
            tolerance: 1e-10,
            max_iterations: 200,
            armijo: 1e-4,
            backtrack: 0.5,
            min_step: 1e-12,
            descent_rho: 1e-8,
            descent_p: 2.1,
            lm_initial_damping: 1e-3,
            max_lm_trials: 30,
            lm_cholesky: false,
            lm_residual_damping_after: Some(3),
            lm_sparse_product: true,
            dense_max: 120,
            structured_solve: false,
            min_norm_step: true,
            min_norm_max: 200,
            rank_tolerance: 1e-10,
            min_norm_radius: 1e-3,
            watchdog_steps: 4,
            pin_zero_columns: true,
            free_block: true,
            newton_line_search: true,
            newton_shortest_step: 1e-4,
            polish_below: 1e-3,
            smoothing: Some(SmoothingSettings {
                max_failed_stages: Some(FAILED_STAGES),
                count_cut_stages: true,
                ..SmoothingSettings::default()
            }),
            damped_restart: Some(0.1),
            smoothing_first: true,
            stall_window: 30,
            stall_reduction: 0.5,
            slow_rate_test: true,
            flat_merit_window: 10,
            ratio_test: true,
            nonmonotone_restart: true,
            forget_undone_steps: true,
            complementary_restart: Some(1e3),
            early_complementary_restart: Some(3e4),
            complementary_restart_from_best: Some(3e4),
            friction_continuation: Some(400),
            structure_reseed: true,

            josephy_newton: Some(20),
            budget_grace: Some(0.1),
            scene_scales: true,
            chord_contraction: Some(1e-3),
            chord_across_solves: Some(1e-2),
            chord_round_off_floor: Some(4.0),
            fast_full_step: Some(1e-2),
            kink_band: None,
            trace: false,
        }
    }
}

/// The Newton backend's [`SmoothingSettings::max_failed_stages`]: a continuation that has had
/// this many unconverged stages since its last stage converged at the set reduction stops
/// (`docs/newton.md#wall-time`, `docs/newton.md#a-crawling-continuation`).
pub const FAILED_STAGES: usize = 4;

/// Buffers reused across iterations and solves (no allocation per iteration).
#[derive(Default)]
struct Workspace {
    n: usize,
    f: Vec<f64>,
    phi: Vec<f64>,
    jac: Vec<f64>,
    h: Vec<f64>,
    da: Vec<f64>,
    db: Vec<f64>,
    /// The degenerate pairs of the last [`generalized_jacobian_rows`].
    degenerate: Vec<usize>,
    jv: Vec<f64>,
    hd: Vec<f64>,
    grad: Vec<f64>,
    d: Vec<f64>,
    z: Vec<f64>,
    z_trial: Vec<f64>,
    f_trial: Vec<f64>,
    phi_trial: Vec<f64>,
    z_best: Vec<f64>,
    /// The watchdog's checkpoint (point, F and Φ there).
    z_check: Vec<f64>,
    f_check: Vec<f64>,
    phi_check: Vec<f64>,
    /// Dense copy of `H` for the minimum-norm step (empty for sparse problems).
    dense: Vec<f64>,
    /// Diagonal additions of [`pin_zero_columns`], and its row scales.
    pin: Vec<f64>,
    row_scale: Vec<f64>,
    /// The point, F, Φ and direction of the Newton line search, while the
    /// Levenberg–Marquardt step is tried.
    z_alt: Vec<f64>,
    f_alt: Vec<f64>,
    phi_alt: Vec<f64>,
    d_alt: Vec<f64>,
    /// The unit rows of `H` ([`NewtonSettings::free_block`], [`unit_rows`]).
    unit: Vec<bool>,
    /// The bounds `(l, u)` that `kinds` were classified from, for the next solve's test.
    kind_bounds: Vec<f64>,
    /// The kind of each component's bounds (`classify(l_i, u_i)`), once per solve: `Φ` and
    /// `D_a, D_b` read it at every trial point and iteration.
    kinds: Vec<BoundKind>,
    /// The components whose bounds are not free (`kinds[i] != Free`), in increasing order,
    /// made with `kinds`: a free pair has one branch, so the chord steps' test
    /// ([`same_branches`]) looks at these alone (9 of the desk's 31).
    bounded: Vec<usize>,
    /// For each column of `H`, the position of an entry that showed it is not to be pinned at
    /// the last assembly ([`assemble_h`]): tried first at the next (the same pattern's `H`
    /// moves little between iterations and steps). Reset to the diagonal's positions when the
    /// pattern changes ([`NewtonSolver::prepare`]).
    witness: Vec<usize>,
    /// The positions of `J`'s stored entries in the bounded rows (`bounded`), in stored
    /// order: the entries of `D_b J` that are not `J`'s own ([`assemble_h`]); made with
    /// `bounded` for the pattern of the solve (`scaled_ready`).
    scaled: Vec<usize>,
    scaled_ready: bool,
    /// The point and `F` where the kept LU's `H` was formed, for the chord steps' test of the
    /// pairs' branches ([`pair_branch`], [`NewtonSettings::chord_contraction`]).
    z_lu: Vec<f64>,
    f_lu: Vec<f64>,
    /// The best natural residual after each iteration of a solve, for the stall test (kept
    /// here so that a solve allocates nothing once it has run as many iterations before).
    best_history: Vec<f64>,
    /// The lowest `Ψ` after each iteration, beside `best_history`, for the flat-merit test.
    best_psi_history: Vec<f64>,
    /// The storage of the caller's result ([`McpSolver::solve_into`]), which the next run's
    /// result is written into (empty otherwise: `solve` allocates its result).
    result: Solution,
}

impl Workspace {
    /// Keeps the current point as the watchdog's checkpoint (a non-monotone sequence starts).
    fn save_checkpoint(&mut self) {
        self.z_check.copy_from_slice(&self.z);
        self.f_check.copy_from_slice(&self.f);
        self.phi_check.copy_from_slice(&self.phi);
    }

    /// Opens the watchdog at the current point (merit `psi`) unless it is open already: a step
    /// that raises `Ψ` is about to be taken under it.
    fn open_watchdog(
        &mut self,
        checkpoint: &mut Option<f64>,
        watchdog_count: &mut usize,
        psi: f64,
    ) {
        if checkpoint.is_none() {
            self.save_checkpoint();
            *checkpoint = Some(psi);
            *watchdog_count = 0;
        }
    }

    fn resize(&mut self, n: usize, nnz: usize) {
        // Every buffer is resized together: the same sizes leave them as they are (a pass over
        // 25 vectors at every solve otherwise).
        if self.n == n && self.f.len() == n && self.jac.len() == nnz {
            return;
        }
        self.n = n;
        for v in [
            &mut self.f,
            &mut self.phi,
            &mut self.da,
            &mut self.db,
            &mut self.jv,
            &mut self.hd,
            &mut self.grad,
            &mut self.d,
            &mut self.z,
            &mut self.z_trial,
            &mut self.f_trial,
            &mut self.phi_trial,
            &mut self.z_best,
            &mut self.z_check,
            &mut self.f_check,
            &mut self.phi_check,
            &mut self.pin,
            &mut self.row_scale,
            &mut self.z_alt,
            &mut self.f_alt,
            &mut self.phi_alt,
            &mut self.d_alt,
            &mut self.z_lu,
            &mut self.f_lu,
        ] {
            v.resize(n, 0.0);
        }
        self.degenerate.reserve(n);
        self.jac.resize(nnz, 0.0);
        self.h.resize(nnz, 0.0);
        self.unit.resize(n, false);
    }

    fn resize_dense(&mut self, n: usize, dense: bool) {
        self.dense.resize(if dense { n * n } else { 0 }, 0.0);
    }
}

/// The semismooth Newton backend. Keep one instance for a whole simulation: it reuses the
/// sparse analysis and all buffers while the sparsity pattern stays the same.
pub struct NewtonSolver {
    settings: NewtonSettings,
    ws: Workspace,
    linear: Option<LinearSolver>,
    /// [`NewtonSettings::structured_solve`] when `linear` was chosen.
    linear_structured: bool,
    normal: Option<NormalEquations>,
    min_norm: MinNorm,
    pattern: Option<Arc<CscPattern>>,
    observer: Option<Box<dyn Observer>>,
    /// Counts and phase times, when profiling is on.
    profile: Option<NewtonProfile>,
    /// The attempt running (index into [`NewtonProfile::attempt_iterations`]).
    attempt: usize,
    /// The running attempt takes full Newton steps under the watchdog
    /// ([`NewtonSettings::nonmonotone_restart`]).
    nonmonotone: bool,
    /// Minimum-norm steps of the last run that no watchdog restore undid
    /// ([`NewtonSettings::forget_undone_steps`]).
    min_norm_kept: usize,
    /// A smoothing continuation is running (its stages and its final solve): the rate and
    /// flat-merit tests stay off there, where a stage cut early changes the continuation's path.
    in_continuation: bool,
    /// The iteration budget of the next solves ([`McpSolver::set_iteration_budget`]).
    budget: Option<usize>,
    /// While the budgeted run's plain iteration runs: the full limit up to which it may go on
    /// past its budget while converging ([`NewtonSettings::budget_grace`]).
    grace_limit: Option<usize>,
    /// The next solves' starts are predictions ([`McpSolver::set_start_predicted`]).
    start_predicted: bool,
    /// `linear` holds the LU of an `H` formed at `Workspace::z_lu` by the last solve, which
    /// converged with it (no pinned columns, a descent step): the next solve's first iteration
    /// may take a chord step on it ([`NewtonSettings::chord_across_solves`]). Cleared when the
    /// Jacobian pattern or the bound kinds change, and by every run until it ends converged.
    kept_lu: bool,
    /// When the kept LU is tried ([`NewtonSettings::chord_across_solves`]).
    kept_lu_gate: KeptLuGate,
    /// The last run took an iteration: the next one evaluates `J` with `F` at its start.
    last_iterated: bool,
}

/// Most solves the kept LU waits after tries that did not pay ([`KeptLuGate`]).
const KEPT_LU_MAX_WAIT: u32 = 64;

/// Whether a solve tries the LU kept from the last one ([`NewtonSettings::chord_across_solves`]):
/// a try that did not pay (the run factorised after all, or failed) makes the next `1, 2, 4, …`
/// (at most [`KEPT_LU_MAX_WAIT`]) solves with a kept LU skip it; a try that paid resets the
/// wait. Only the acceptance tests of the chord step decide a result; this decides the cost of
/// refused tries (a chord solve, `F` at its trial point, the residual: ≈ 5 k on A1).
#[derive(Clone, Copy, Debug, Default)]
struct KeptLuGate {
    /// Solves with a kept LU left to skip.
    wait: u32,
    /// The wait set by the last try that did not pay (0 after one that paid).
    backoff: u32,
}

impl KeptLuGate {
    /// Whether this solve tries the kept LU (a skipped solve counts down the wait).
    fn take_turn(&mut self) -> bool {
        if self.wait > 0 {
            self.wait -= 1;
            false
        } else {
            true
        }
    }

    /// The outcome of a try.
    fn record(&mut self, paid: bool) {
        if paid {
            self.backoff = 0;
        } else {
            self.backoff = (2 * self.backoff).clamp(1, KEPT_LU_MAX_WAIT);
            self.wait = self.backoff;
        }
    }
}

impl NewtonSolver {
    /// A solver with the given settings.
    pub fn new(settings: NewtonSettings) -> Self {
        NewtonSolver {
            settings,
            ws: Workspace::default(),
            linear: None,
            linear_structured: false,
            normal: None,
            min_norm: MinNorm::default(),
            pattern: None,
            observer: None,
            profile: None,
            attempt: 0,
            nonmonotone: false,
            min_norm_kept: 0,
            in_continuation: false,
            budget: None,
            grace_limit: None,
            start_predicted: false,
            kept_lu: false,
            kept_lu_gate: KeptLuGate::default(),
            last_iterated: true,
        }
    }
    /// Turns on the profile of factorisations, damping trials and time per phase
    /// ([`NewtonProfile`]; it reads the clock several times per iteration).
    pub fn with_profile(mut self) -> Self {
        self.profile = Some(NewtonProfile::default());
        self
    }
    /// The profile summed since the last call (zero when profiling is off), and a fresh one.
    pub fn take_profile(&mut self) -> NewtonProfile {
        self.profile
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }
    /// Attaches an observer that sees every iteration.
    pub fn with_observer(mut self, observer: Box<dyn Observer>) -> Self {
        self.observer = Some(observer);
        self
    }
    /// The settings.
    pub fn settings(&self) -> &NewtonSettings {
        &self.settings
    }
    /// Mutable settings (e.g. to tighten the tolerance between solves).
    pub fn settings_mut(&mut self) -> &mut NewtonSettings {
        &mut self.settings
    }

    /// Prepares buffers and linear solvers for this problem's pattern (analysis reused when the
    /// pattern is unchanged).
    fn prepare(&mut self, mcp: &dyn Mcp) -> Result<(), SolveError> {
        let pattern = mcp.jacobian_pattern();
        let same = match &self.pattern {
            Some(p) => Arc::ptr_eq(p, pattern) || **p == **pattern,
            None => false,
        };
        let groups = if self.settings.structured_solve {
            mcp.elimination_groups()
        } else {
            &[]
        };
        // The groups come with the pattern (the same problem), but the setting may change.
        let same = same && self.linear_structured == self.settings.structured_solve;
        if !same {
            let lin = LinearSolver::structured(pattern, self.settings.dense_max, groups).map_err(
                |e| SolveError::InvalidProblem(format!("cannot analyse the Jacobian pattern: {e}")),
            )?;
            self.linear = Some(lin);
            // A new pattern: the LU kept from the last solve is of another problem.
            self.kept_lu = false;
            self.linear_structured = self.settings.structured_solve;
            self.normal = None;
            self.pattern = Some(pattern.clone());
        }
        self.ws.resize(mcp.dim(), pattern.nnz());
        // The witnesses are positions in the pattern they were found in: the diagonal's of a
        // new one (every position of column `j` in its pattern, as `assemble_h` asks).
        if !same || self.ws.witness.len() != pattern.diag_pos().len() {
            self.ws.witness.clear();
            self.ws.witness.extend_from_slice(pattern.diag_pos());
            self.ws.scaled_ready = false;
        }
        // The stall test's history holds at most one entry per iteration and the start.
        let history = self.settings.max_iterations.saturating_add(1).min(1 << 16);
        self.ws
            .best_history
            .reserve(history.saturating_sub(self.ws.best_history.len()));
        self.ws
            .best_psi_history
            .reserve(history.saturating_sub(self.ws.best_psi_history.len()));

        let dense = self.settings.min_norm_step && mcp.dim() <= self.settings.min_norm_max;
        self.ws.resize_dense(mcp.dim(), dense);
        Ok(())
    }
}

/// The rate test ([`NewtonSettings::slow_rate_test`]) stops a run whose rate would need more
/// than this many times the iterations it has left: a run that crosses a valley of the merit
/// in Levenberg–Marquardt steps of constant length converges abruptly at its end, faster than
/// its rate foretold (`062_room_corner` step 128: up to 3.96 times, then converged at 87).
const RATE_TEST_MARGIN: f64 = 6.0;

/// The ratio test's point ([`NewtonSettings::ratio_test`]) is taken outright when `Ψ` fell there
/// by at least this fraction of the fall the linearisation predicts: the model held up to the
/// pair's event, so the event is the basis change the step describes. A point that lowers `Ψ`
/// less is compared with the Levenberg–Marquardt step (`018_union_tip` step 50: the event
/// point lowered `Ψ` by 5 % where the linearisation predicted 37 % and Levenberg–Marquardt
/// gave 73 %; taken outright, the step took 145 iterations, compared 6). 0.75 gave the same
/// runs of `023_room_corner`, `087_v_trough`, `135_union_tip` and `025_multi_body`; 0.25 those
/// of `087_v_trough` and `023_room_corner` without the test
/// (`docs/newton.md#a-gate-the-linearisation-held-up-to-the-event`).
const RATIO_MODEL_AGREEMENT: f64 = 0.5;

/// Shortest step length tried along the minimum-norm direction before the Levenberg–Marquardt
/// safeguard takes over (a direction that needs a shorter step is a poor one).
const MIN_NORM_SHORTEST_STEP: f64 = 1.0 / 64.0;

/// Partial derivatives of φ at (a, b); `None` at the kink (0, 0).
#[inline]
fn phi_partials(a: f64, b: f64) -> Option<(f64, f64)> {
    let r = ecp_model::hypot(a, b); // glibc's bits, inline
    if r > 0.0 {
        Some((a / r - 1.0, b / r - 1.0))
    } else {
        None
    }
}

/// An element of ∂φ at the kink: (ξ − 1, η − 1) with ‖(ξ, η)‖ = 1, along direction (a', b').
#[inline]
fn kink_partials(a_dir: f64, b_dir: f64) -> (f64, f64) {
    let r = ecp_model::hypot(a_dir, b_dir); // glibc's bits, inline
    if r > 0.0 && r.is_finite() {
        (a_dir / r - 1.0, b_dir / r - 1.0)
    } else {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        (s - 1.0, s - 1.0)
    }
}

/// Row scalings `D_a, D_b` of `H = D_a + D_b J` (`docs/backends.md#semismooth-newton`);
/// `band` is [`NewtonSettings::kink_band`] (0: off). `degenerate` gets the pairs at the kink
/// (in increasing order), whose rows take the element along `J v`.
///
/// `bounded`: `None` writes every row; `Some(list)` only the listed ones (the components
/// whose kind is not free, in increasing order, [`Workspace::bounded`]), the caller having
/// written a free row's `(D_a, D_b) = (0, 1)` once (they never change): 22 of the desk's 31
/// rows, a store pair and the kinds' test each at every factorisation.
#[allow(clippy::too_many_arguments)]
pub(crate) fn generalized_jacobian_rows(
    bounded: Option<&[usize]>,
    band: f64,
    z: &[f64],
    f: &[f64],
    l: &[f64],
    u: &[f64],
    kinds: &[BoundKind],
    pattern: &CscPattern,
    jac: &[f64],
    ws_da: &mut [f64],
    ws_db: &mut [f64],
    degenerate: &mut Vec<usize>,
    jv: &mut [f64],
) {
    let n = z.len();
    // Cut to one length: no bounds checks in the loop.
    let (f, l, u, kinds) = (&f[..n], &l[..n], &u[..n], &kinds[..n]);
    let (ws_da, ws_db) = (&mut ws_da[..n], &mut ws_db[..n]);
    // First pass: regular components, and list the degenerate ones; their direction v of
    // De Luca–Facchinei–Kanzow is +1 for lower, −1 for upper bounds (`kinds`). The list
    // (a few pairs) replaces a vector of `v` and two more passes over all components.
    degenerate.clear();
    if let Some(list) = bounded {
        debug_assert!((0..n).all(|i| kinds[i] != BoundKind::Free
            || ws_da[i] == 0.0 && ws_db[i] == 1.0
            || list.contains(&i)));
    }
    match bounded {
        None => jacobian_rows_of(0..n, band, (z, f, l, u, kinds), ws_da, ws_db, degenerate),
        Some(list) => jacobian_rows_of(
            list.iter().copied(),
            band,
            (z, f, l, u, kinds),
            ws_da,
            ws_db,
            degenerate,
        ),
    }
    if !degenerate.is_empty() {
        // The direction `v` of a listed pair: only lower and upper bounds are listed.
        let v = |j: usize| {
            if kinds[j] == BoundKind::Lower {
                1.0
            } else {
                -1.0
            }
        };
        // J v over the (few) columns where v is not zero, in increasing order: the other
        // columns add nothing.
        let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
        jv.fill(0.0);
        for &j in degenerate.iter() {
            let vj = v(j);
            for p in cp[j]..cp[j + 1] {
                jv[ri[p]] += jac[p] * vj;
            }
        }
        for &i in degenerate.iter() {
            let (pa, pb) = if v(i) > 0.0 {
                kink_partials(1.0, jv[i])
            } else {
                // Direction z − t e_i: a = u − z grows like t, b = −F like t (J v)_i… with v_i = −1.
                kink_partials(1.0, -jv[i])
            };
            ws_da[i] = pa;
            ws_db[i] = pb;
        }
    }
}

/// `(z, F, l, u, kinds)`, each cut to one length.
type PointAndKinds<'a> = (&'a [f64], &'a [f64], &'a [f64], &'a [f64], &'a [BoundKind]);

/// The rows `i` in `rows` of [`generalized_jacobian_rows`] (every row, or the bounded ones),
/// `(z, F, l, u, kinds)` cut to one length; the pairs at the kink pushed to `degenerate`.
#[inline(always)]
fn jacobian_rows_of(
    rows: impl Iterator<Item = usize>,
    band: f64,
    (z, f, l, u, kinds): PointAndKinds<'_>,
    ws_da: &mut [f64],
    ws_db: &mut [f64],
    degenerate: &mut Vec<usize>,
) {
    for i in rows {
        match kinds[i] {
            BoundKind::Free => {
                ws_da[i] = 0.0;
                ws_db[i] = 1.0;
            }
            // At the bound with `F` out of the feasible side by round-off only: the row of
            // `F ≥ 0` (`NewtonSettings::kink_band`).
            BoundKind::Lower if z[i] == l[i] && f[i] < 0.0 && -f[i] <= band => {
                ws_da[i] = -1.0;
                ws_db[i] = 0.0;
            }
            BoundKind::Upper if z[i] == u[i] && f[i] > 0.0 && f[i] <= band => {
                ws_da[i] = -1.0;
                ws_db[i] = 0.0;
            }
            BoundKind::Lower => match phi_partials(z[i] - l[i], f[i]) {
                Some((pa, pb)) => {
                    ws_da[i] = pa;
                    ws_db[i] = pb;
                }
                None => degenerate.push(i),
            },
            BoundKind::Upper => match phi_partials(u[i] - z[i], -f[i]) {
                // Φ = −φ(u − z, −F) ⇒ ∂Φ/∂z = φ_a + φ_b J.
                Some((pa, pb)) => {
                    ws_da[i] = pa;
                    ws_db[i] = pb;
                }
                None => degenerate.push(i),
            },
            BoundKind::Box => {
                let a2 = u[i] - z[i];
                let b2 = -f[i];
                let (qa, qb) = phi_partials(a2, b2).unwrap_or_else(|| kink_partials(1.0, 1.0));
                let psi = fischer_burmeister(a2, b2);
                let (pa, pb) =
                    phi_partials(z[i] - l[i], psi).unwrap_or_else(|| kink_partials(1.0, 1.0));
                // Φ = φ(z − l, ψ), ψ = φ(u − z, −F): ∂Φ/∂z = (φ_a − φ_b ψ_a) e_i − φ_b ψ_b J_i.
                ws_da[i] = pa - pb * qa;
                ws_db[i] = -pb * qb;
            }
        }
    }
}

/// Marks the unit rows of `H = D_a + D_b J`: the rows with `D_b,i = 0` (a component held at
/// its bound, `F_i` away from 0), whose only entry is the diagonal `D_a,i` (and its pin,
/// [`pin_zero_columns`]). [`NewtonSettings::free_block`] factorises `H` without them. Only
/// the rows in `bounded` ([`Workspace::bounded`]): a free row's `D_b` is 1, its mark `false`
/// written once with it.
fn unit_rows(db: &[f64], bounded: &[usize], unit: &mut [bool]) {
    debug_assert!((0..unit.len()).all(|i| unit[i] == (db[i] == 0.0) || bounded.contains(&i)));
    for &i in bounded {
        unit[i] = db[i] == 0.0;
    }
}

/// Writes `H = D_a + D_b J` into `h` (in `pattern`, the diagonal always stored) and returns the
/// largest magnitude of `H` (NaNs left out) and whether some column may be pinned
/// (`undecided`); `∇Ψ = HᵀΦ` is formed apart ([`gradient`]), only where an iteration needs it.
///
/// A column is not pinned ([`pin_zero_columns`]) when one of its entries is above
/// `ZERO_COLUMN` times that largest (a witness). `witness[j]` is a position in column `j` (of
/// this pattern): the last assembly's witness, tried first; else the diagonal, else the first
/// entry above the threshold, kept as the next witness. When a column has none, `undecided`
/// is true and `col_max[j]` is, for every column, a magnitude that decides its test as before:
/// `|H_jj|` when it is above the threshold, else the first entry above it, else the column's
/// largest magnitude (NaN when the column holds a NaN, which is not pinned). When `undecided`
/// is false no column is pinned and `col_max` is left as it was (the desk's columns: one load
/// and compare each, where the search of the half with a zero diagonal and the tests of all
/// columns' maxima cost ≈ 1 k instructions a step, `docs/latency.md`, branch wip-newtonown).
///
/// `D_b J` in one pass over the stored entries (no per-column set-up), then `D_a` added on the
/// diagonal: `D_b,j J_jj + D_a,j` rounded as the one expression. With `scaled`, the positions
/// of the entries whose row's `D_b` may differ from 1 (every other row's is exactly 1): `J`
/// copied and those entries alone scaled, the same bits. The largest magnitude in four
/// lanes (a maximum does not depend on the order; `a > m` skips a NaN as `f64::max` does).
/// `jac` `None`: `h` holds `J` already and is turned into `H` in place (with `scaled` only):
/// the solver's iteration swaps the two buffers instead of copying `J` (a 3.3 kB `memcpy` a
/// desk iteration).
// `h = D_b · h` written as the product of the copy's path (`D_b · J`), not `h *= D_b`.
#[allow(clippy::too_many_arguments, clippy::assign_op_pattern)]
fn assemble_h(
    pattern: &CscPattern,
    jac: Option<&[f64]>,
    da: &[f64],
    db: &[f64],
    scaled: Option<&[usize]>,
    h: &mut [f64],
    witness: &mut [usize],
    col_max: &mut [f64],
) -> (f64, bool, bool) {
    let (cp, ri, diag) = (pattern.col_ptr(), pattern.row_idx(), pattern.diag_pos());
    let ncols = cp.len() - 1;
    let nnz = cp[ncols];
    let (h, ri) = (&mut h[..nnz], &ri[..nnz]);
    // The rows' `D_b` gathered without a bounds check per entry (two of the nine instructions
    // an entry took): every stored row index of a `CscPattern` is below its dimension
    // (`CscPattern::from_columns` refuses others, and the fields are private), which is
    // `ncols`, the length `db` is cut to here.
    assert_eq!(pattern.dim(), ncols);
    let db = &db[..ncols];
    let row_scale = |r: usize| {
        debug_assert!(r < db.len());
        // SAFETY: `r` is a row index of `pattern`, below `pattern.dim() == db.len()`.
        unsafe { *db.get_unchecked(r) }
    };
    if let Some(positions) = scaled {
        // `D_b,r = 1` exactly in every row but those of the listed positions (the free rows,
        // [`Workspace::scaled`]), and `1 · J_p` is `J_p` to the last bit (signed zeros too; a
        // quiet NaN is itself): `J` copied, the listed entries scaled (on the desk the
        // entries of the 9 bounded rows, a few of the 416 stored).
        debug_assert!((0..nnz).all(|p| db[ri[p]] == 1.0 || positions.contains(&p)));
        if let Some(jac) = jac {
            h.copy_from_slice(&jac[..nnz]);
        }
        for &p in positions {
            h[p] = row_scale(ri[p]) * h[p];
        }
    } else if let Some(jac) = jac {
        let jac = &jac[..nnz];
        // Four entries a turn (a quarter of the loop's own instructions).
        let (mut hc, mut jc, mut rc) = (
            h.chunks_exact_mut(4),
            jac.chunks_exact(4),
            ri.chunks_exact(4),
        );
        for ((hp, v), r) in (&mut hc).zip(&mut jc).zip(&mut rc) {
            hp[0] = row_scale(r[0]) * v[0];
            hp[1] = row_scale(r[1]) * v[1];
            hp[2] = row_scale(r[2]) * v[2];
            hp[3] = row_scale(r[3]) * v[3];
        }
        let rest = (hc.into_remainder().iter_mut())
            .zip(jc.remainder())
            .zip(rc.remainder());
        for ((hp, &v), &r) in rest {
            *hp = row_scale(r) * v;
        }
    } else {
        // In place, every entry scaled (not the solver's path: it lists the positions).
        for (hp, &r) in h.iter_mut().zip(ri) {
            *hp = row_scale(r) * *hp;
        }
    }
    for (&p, &a) in diag.iter().zip(da) {
        h[p] += a;
    }
    let (largest, nan) = largest_magnitude(h);
    // Every stored entry of `H` finite: no NaN, and the largest magnitude not `∞`.
    let finite = !nan && largest.is_finite();
    let threshold = ZERO_COLUMN * largest;
    let witness = &mut witness[..ncols];
    // The kept witnesses first, in a pass of their own (a load and a compare a column): on the
    // same problem's next `H` they nearly always all hold.
    if witness.iter().all(|&w| h[w].abs() > threshold) {
        return (largest, false, finite);
    }
    let mut undecided = false;
    for (j, w) in witness.iter_mut().enumerate() {
        // The kept witness (a position of column `j`: `h[*w]` is one of its entries), then
        // the diagonal, then the column's first entry above the threshold.
        if h[*w].abs() > threshold {
            continue;
        }
        if h[diag[j]].abs() > threshold {
            *w = diag[j];
            continue;
        }
        match h[cp[j]..cp[j + 1]].iter().position(|v| v.abs() > threshold) {
            Some(k) => *w = cp[j] + k,
            None => undecided = true,
        }
    }
    if !undecided {
        return (largest, false, finite);
    }
    for (j, (m, &p)) in col_max[..ncols].iter_mut().zip(diag).enumerate() {
        let d = h[p].abs();
        // A witness above the threshold decides the test (NaN is not above it): the diagonal,
        // else the first such entry; without one, the column's largest (or NaN). The column is
        // cut out only when the diagonal does not decide (its bounds checks cost as much as
        // the test).
        *m = if d > threshold {
            d
        } else {
            let col = &h[cp[j]..cp[j + 1]];
            if let Some(a) = col.iter().map(|v| v.abs()).find(|&a| a > threshold) {
                a
            } else {
                col.iter().fold(0.0, |m: f64, v| {
                    if v.is_nan() || m.is_nan() {
                        f64::NAN
                    } else {
                        m.max(v.abs())
                    }
                })
            }
        };
    }
    (largest, true, finite)
}

/// The largest magnitude of `v` (0 for an empty one, NaNs left out), in lanes: four AVX
/// registers of four where the processor runs AVX, else two SSE2 registers on `x86_64`
/// (`maxpd(a, m)` is `a > m ? a : m`, which skips a NaN `a` as the scalar loop does), the
/// scalar loop elsewhere. A maximum does not depend on the order, and magnitudes have no
/// signed zeros: every version gives the same bits. With it, whether `v` holds a NaN (an
/// unordered compare OR-ed beside each `max`): `v` is all finite when there is none and the
/// largest is finite, and the LU's load need not test each entry again
/// ([`LinearSolver::factor_with_unit_rows_finite`]).
#[inline]
fn largest_magnitude(v: &[f64]) -> (f64, bool) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: the processor runs AVX (checked just above).
            unsafe { largest_magnitude_avx(v) }
        } else {
            largest_magnitude_sse2(v)
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        largest_magnitude_scalar(v)
    }
}

/// [`largest_magnitude`] in SSE2 (the `x86_64` baseline), the same value.
#[cfg(target_arch = "x86_64")]
#[inline]
fn largest_magnitude_sse2(v: &[f64]) -> (f64, bool) {
    use std::arch::x86_64::*;
    let quads = v.len() / 4;
    // SAFETY: SSE2 is part of the `x86_64` baseline; the loads are at `4q .. 4q + 3 < v.len()`.
    let (mut m, mut nan) = unsafe {
        let sign = _mm_set1_pd(-0.0);
        let (mut m0, mut m1) = (_mm_setzero_pd(), _mm_setzero_pd());
        let mut u = _mm_setzero_pd();
        for q in 0..quads {
            let p = v.as_ptr().add(4 * q);
            let (x0, x1) = (_mm_loadu_pd(p), _mm_loadu_pd(p.add(2)));
            m0 = _mm_max_pd(_mm_andnot_pd(sign, x0), m0);
            m1 = _mm_max_pd(_mm_andnot_pd(sign, x1), m1);
            u = _mm_or_pd(u, _mm_cmpunord_pd(x0, x1));
        }
        let mut lanes = [0.0f64; 4];
        _mm_storeu_pd(lanes.as_mut_ptr(), m0);
        _mm_storeu_pd(lanes.as_mut_ptr().add(2), m1);
        (lanes, _mm_movemask_pd(u) != 0)
    };
    for (k, x) in v[4 * quads..].iter().enumerate() {
        let a = x.abs();
        nan |= a.is_nan();
        if a > m[k] {
            m[k] = a;
        }
    }
    (m[0].max(m[1]).max(m[2].max(m[3])), nan)
}

/// [`largest_magnitude`] with AVX: sixteen entries a turn in four registers (`vmaxpd(a, m)` is
/// `a > m ? a : m`, as `maxpd`), then four, then one at a time; the same value (the desk's `H`
/// has 416 stored entries, half the instructions of the SSE2 loop, `docs/latency.md`, branch
/// wip-newtonown). Only called where the processor runs AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn largest_magnitude_avx(v: &[f64]) -> (f64, bool) {
    use std::arch::x86_64::*;
    let n = v.len();
    let p = v.as_ptr();
    let sign = _mm256_set1_pd(-0.0);
    let (mut m0, mut m1, mut m2, mut m3) = (
        _mm256_setzero_pd(),
        _mm256_setzero_pd(),
        _mm256_setzero_pd(),
        _mm256_setzero_pd(),
    );
    // NaN lanes: an unordered compare of two loaded registers is true where either is NaN.
    let (mut u0, mut u1) = (_mm256_setzero_pd(), _mm256_setzero_pd());
    let mut i = 0;
    // SAFETY: every load is at `i .. i + 3 < n` (or `i + 15 < n`), within `v`; unaligned loads
    // need no alignment.
    unsafe {
        while i + 16 <= n {
            let (x0, x1) = (_mm256_loadu_pd(p.add(i)), _mm256_loadu_pd(p.add(i + 4)));
            let (x2, x3) = (
                _mm256_loadu_pd(p.add(i + 8)),
                _mm256_loadu_pd(p.add(i + 12)),
            );
            m0 = _mm256_max_pd(_mm256_andnot_pd(sign, x0), m0);
            m1 = _mm256_max_pd(_mm256_andnot_pd(sign, x1), m1);
            m2 = _mm256_max_pd(_mm256_andnot_pd(sign, x2), m2);
            m3 = _mm256_max_pd(_mm256_andnot_pd(sign, x3), m3);
            u0 = _mm256_or_pd(u0, _mm256_cmp_pd::<_CMP_UNORD_Q>(x0, x1));
            u1 = _mm256_or_pd(u1, _mm256_cmp_pd::<_CMP_UNORD_Q>(x2, x3));
            i += 16;
        }
        while i + 4 <= n {
            let x0 = _mm256_loadu_pd(p.add(i));
            m0 = _mm256_max_pd(_mm256_andnot_pd(sign, x0), m0);
            u0 = _mm256_or_pd(u0, _mm256_cmp_pd::<_CMP_UNORD_Q>(x0, x0));
            i += 4;
        }
    }
    // The accumulators hold no NaN (each `max` keeps its second operand for a NaN `a`).
    let m = _mm256_max_pd(_mm256_max_pd(m0, m1), _mm256_max_pd(m2, m3));
    let mut nan = _mm256_movemask_pd(_mm256_or_pd(u0, u1)) != 0;
    let mut lanes = [0.0f64; 4];
    // SAFETY: `lanes` has room for the four lanes stored.
    unsafe { _mm256_storeu_pd(lanes.as_mut_ptr(), m) };
    for (k, x) in v[i..].iter().enumerate() {
        let a = x.abs();
        nan |= a.is_nan();
        if a > lanes[k] {
            lanes[k] = a;
        }
    }
    let top = |a: f64, b: f64| if b > a { b } else { a };
    (top(top(lanes[0], lanes[1]), top(lanes[2], lanes[3])), nan)
}

/// [`largest_magnitude`] one entry at a time (other targets; the tests' reference).
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn largest_magnitude_scalar(v: &[f64]) -> (f64, bool) {
    let nan = v.iter().any(|x| x.is_nan());
    let mut m = [0.0f64; 4];
    let chunks = v.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        for k in 0..4 {
            let a = c[k].abs();
            if a > m[k] {
                m[k] = a;
            }
        }
    }
    for (k, x) in rest.iter().enumerate() {
        let a = x.abs();
        if a > m[k] {
            m[k] = a;
        }
    }
    (m[0].max(m[1]).max(m[2].max(m[3])), nan)
}

/// `∇Ψ = HᵀΦ` into `grad`: each column's sum `Σ_r H_rj Φ_r` from `+0.0` in stored order (the
/// bits of the sum taken beside the assembly before).
fn gradient(pattern: &CscPattern, h: &[f64], phi: &[f64], grad: &mut [f64]) {
    let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
    let ncols = cp.len() - 1;
    let phi = &phi[..ncols];
    for (j, g) in grad[..ncols].iter_mut().enumerate() {
        let (start, end) = (cp[j], cp[j + 1]);
        let mut s = 0.0;
        for (&v, &r) in h[start..end].iter().zip(&ri[start..end]) {
            s += v * phi[r];
        }
        *g = s;
    }
}

/// Adds to the diagonal of `h` (in `pattern`), for each column whose largest entry is at most
/// [`ZERO_COLUMN`] times the largest entry of `h`, the largest entry of its row (1 when the row
/// is zero too); records the additions in `pin` and returns whether there was any. `pin` holds
/// on entry a magnitude of each column that decides that test (its largest, or its diagonal's
/// when that is above the threshold) and `largest` the largest of `h` ([`assemble_h`]).
fn pin_zero_columns(
    pattern: &CscPattern,
    h: &mut [f64],
    largest: f64,
    pin: &mut [f64],
    row_scale: &mut [f64],
) -> bool {
    let (cp, ri) = (pattern.col_ptr(), pattern.row_idx());
    let n = cp.len() - 1;
    let threshold = ZERO_COLUMN * largest;
    let mut any = false;
    for p in pin.iter_mut() {
        // A NaN column is not below the threshold.
        if *p <= threshold {
            *p = f64::NAN;
            any = true;
        } else {
            *p = 0.0;
        }
    }
    if !any {
        return false;
    }
    // Row scales of the pinned columns' rows (their own index: H is square with the diagonal
    // pairing variable j with row j).
    row_scale.fill(0.0);
    for j in 0..n {
        for p in cp[j]..cp[j + 1] {
            let r = ri[p];
            if pin[r].is_nan() {
                row_scale[r] = row_scale[r].max(h[p].abs());
            }
        }
    }
    for (j, &p) in pattern.diag_pos().iter().enumerate() {
        if pin[j].is_nan() {
            let c = if row_scale[j] > threshold {
                row_scale[j]
            } else {
                1.0
            };
            pin[j] = c;
            h[p] += c;
        }
    }
    true
}

/// A column of `H` whose entries are all below this fraction of `H`'s largest entry counts as
/// zero in [`pin_zero_columns`].
const ZERO_COLUMN: f64 = 1e-13;

/// The branch of a complementarity pair that the natural residual's `mid(l, u, z − F)` selects:
/// 0 when `z` is at (or beyond) its lower bound's side (`z − l ≤ F`), 2 at the upper bound's,
/// 1 where `F` is the residual (free components, strictly inside). The element `D_a + D_b J`
/// of a pair changes continuously while its branch stays the same, and jumps when it changes.
#[inline]
fn pair_branch(z: f64, f: f64, l: f64, u: f64, kind: BoundKind) -> u8 {
    match kind {
        BoundKind::Free => 1,
        BoundKind::Lower => u8::from(z - l > f),
        BoundKind::Upper => 1 + u8::from(u - z <= -f),
        BoundKind::Box => {
            let x = z - f;
            if x <= l {
                0
            } else if x >= u {
                2
            } else {
                1
            }
        }
    }
}

/// Whether every pair is on the same branch ([`pair_branch`]) at `(z, F)` and at `(z₀, F₀)`:
/// a free pair has one branch, so only the pairs in `bounded` (the components whose kind is
/// not free, [`Workspace::bounded`]) are compared, each kind matched once for both points
/// (9 of the desk's 31 pairs, where a pass over all of them tested each free one).
fn same_branches(
    (z, f): (&[f64], &[f64]),
    (z0, f0): (&[f64], &[f64]),
    l: &[f64],
    u: &[f64],
    kinds: &[BoundKind],
    bounded: &[usize],
) -> bool {
    let n = z.len();
    let (f, z0, f0, l, u, kinds) = (&f[..n], &z0[..n], &f0[..n], &l[..n], &u[..n], &kinds[..n]);
    bounded.iter().all(|&i| {
        let kind = kinds[i];
        // A lower bound (every bounded pair of the ECP formulation: the multipliers, `p_n`,
        // `σ ≥ 0`) tested first, with its five values alone: `same_branch`'s arm, without the
        // other kinds' loads and jump.
        if kind == BoundKind::Lower {
            (z[i] - l[i] > f[i]) == (z0[i] - l[i] > f0[i])
        } else {
            same_branch(kind, (z[i], f[i]), (z0[i], f0[i]), l[i], u[i])
        }
    })
}

/// `pair_branch(z, f, l, u, kind) == pair_branch(z0, f0, l, u, kind)`, with `kind` matched once.
#[inline(always)]
fn same_branch(kind: BoundKind, (z, f): (f64, f64), (z0, f0): (f64, f64), l: f64, u: f64) -> bool {
    match kind {
        BoundKind::Free => true,
        BoundKind::Lower => (z - l > f) == (z0 - l > f0),
        BoundKind::Upper => (u - z <= -f) == (u - z0 <= -f0),
        BoundKind::Box => {
            pair_branch(z, f, l, u, BoundKind::Box) == pair_branch(z0, f0, l, u, BoundKind::Box)
        }
    }
}

/// `‖z‖∞`: the size of the numbers the natural residual `z − mid(l, u, z − F)` is a difference
/// of, so its round-off bounds how far a step can lower it
/// ([`NewtonSettings::chord_round_off_floor`]). `‖F‖∞` is no such scale: a component at its
/// bound with a large `F` (90 on the desk) has a residual of exactly zero. NaNs are left out
/// (the residual is finite where it is asked for).
fn round_off_scale(z: &[f64]) -> f64 {
    z.iter().fold(0.0, |m: f64, v| m.max(v.abs()))
}

/// `r ≤ k · round_off_scale(z)`, by a scan that stops at the first component that shows it:
/// for a finite `k > 0` rounding is monotone and no product is NaN, so `k · max_i |z_i|` is the
/// largest of the `k · |z_i|` (and of `k · 0 = 0`, the fold's start); a NaN component shows
/// nothing, as `max` leaves it out. (The settings' check makes `k` positive; any other `k`
/// takes the fold: `0 · ∞` is NaN.)
fn within_round_off(r: f64, k: f64, z: &[f64]) -> bool {
    if k > 0.0 && k.is_finite() {
        r <= 0.0 || z.iter().any(|v| r <= k * v.abs())
    } else {
        r <= k * round_off_scale(z)
    }
}

/// Evaluates the trial point `z + t d` into the workspace's trial buffers; returns `Ψ` there,
/// or `None` when `F` is not finite.
fn try_step(
    mcp: &dyn Mcp,
    ws: &mut Workspace,
    t: f64,
    l: &[f64],
    u: &[f64],
    f_evals: &mut usize,
) -> Option<f64> {
    // Over the three slices together (no bounds checks: the loop runs in vector lanes).
    for ((zt, &z), &d) in ws.z_trial.iter_mut().zip(&ws.z).zip(&ws.d) {
        *zt = z + t * d;
    }
    merit_at_trial(mcp, ws, l, u, f_evals)
}

/// `Ψ` at `ws.z_trial` (`F` and `Φ` there kept in the workspace); `None` when not finite.
fn merit_at_trial(
    mcp: &dyn Mcp,
    ws: &mut Workspace,
    l: &[f64],
    u: &[f64],
    f_evals: &mut usize,
) -> Option<f64> {
    mcp.evaluate(&ws.z_trial, &mut ws.f_trial);
    *f_evals += 1;
    // `Ψ = ½ ‖Φ‖²`, the sum of squares taken beside `Φ` (the bits of `dot(Φ, Φ)`).
    let p = 0.5
        * fb_vector_of_kinds_squared(&ws.z_trial, &ws.f_trial, l, u, &ws.kinds, &mut ws.phi_trial);
    p.is_finite().then_some(p)
}

/// [`try_step`] to the ratio test's event at `t` (component `i`); a component that reaches its
/// bound there is put on it exactly, so the next linearisation sees the pair on its new branch.
fn try_ratio_step(
    mcp: &dyn Mcp,
    ws: &mut Workspace,
    (t, i, on_bound): (f64, usize, bool),
    l: &[f64],
    u: &[f64],
    f_evals: &mut usize,
) -> Option<f64> {
    for k in 0..ws.n {
        ws.z_trial[k] = ws.z[k] + t * ws.d[k];
    }
    if on_bound {
        ws.z_trial[i] = if ws.d[i] < 0.0 { l[i] } else { u[i] };
    }
    merit_at_trial(mcp, ws, l, u, f_evals)
}

/// Whether `a` and `b` hold the same bits (one pass without an exit per entry).
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len()
        && (a.iter().zip(b)).fold(0u64, |acc, (x, y)| acc | (x.to_bits() ^ y.to_bits())) == 0
}

/// `dst = −src` (the Newton and gradient directions' right-hand sides), in vector lanes.
#[inline]
fn negate_into(dst: &mut [f64], src: &[f64]) {
    for (d, &v) in dst.iter_mut().zip(src) {
        *d = -v;
    }
}

/// `Σ a_i b_i` in index order from `−0.0`: what `a.iter().zip(b).map(|(x, y)| x * y).sum()`
/// gives bit for bit, as a plain loop.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut s = -0.0;
    for (x, y) in a.iter().zip(b) {
        s += x * y;
    }
    s
}

/// `a >= rho * nd.powf(p)`, the descent tests' comparison, decided without `powf` where
/// `‖d‖²` and `‖d‖³` decide it (`powf`: ≈ 125 instructions and 0.6 % of a desk step's perf
/// samples). For `1e-90 ≤ nd ≤ 1` and `2 ≤ p ≤ 3`, `nd³ ≤ nd^p ≤ nd²`; `powf` is within an
/// ulp of `nd^p` and each product within half an ulp, so `ρ·powf(nd, p)` is within `4ε` of
/// `ρ·nd²` from below and of `ρ·nd³` from above (all of them normal numbers where taken, at
/// least `1e-290`). A margin of `1e-12` leaves the bound's verdict the exact test's; between
/// the bounds (and for other `p`, `ρ`, `nd`, NaNs) the exact test decides. On the desk `2Ψ` is
/// ≈ 1e-12 and `ρ‖d‖²` ≈ 1e-20: the first bound decides.
fn at_least_rho_pow(a: f64, rho: f64, nd: f64, p: f64) -> bool {
    const SMALLEST: f64 = 1e-290;
    if (2.0..=3.0).contains(&p) && rho > 0.0 && rho.is_finite() && (1e-90..=1.0).contains(&nd) {
        let square = rho * (nd * nd);
        if square >= SMALLEST && a >= square * (1.0 + 1e-12) {
            return true;
        }
        let cube = rho * (nd * nd * nd);
        if cube >= SMALLEST && a < cube * (1.0 - 1e-12) {
            return false;
        }
    }
    a >= rho * nd.powf(p)
}

fn norm2(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

/// One attempt of [`NewtonSolver::solve_restarted`] folded into the run: a solution ends it with
/// every earlier attempt's iterations counted; an attempt that did not converge adds its
/// iterations and is kept as `best` when its residual is lower; any other error ends the run.
fn fold_attempt(
    result: Result<Solution, SolveError>,
    spent: &mut usize,
    best: &mut Box<Solution>,
) -> Option<Result<Solution, SolveError>> {
    match result {
        Ok(mut sol) => {
            sol.summary.iterations += *spent;
            Some(Ok(sol))
        }
        Err(SolveError::NotConverged { best: other }) => {
            *spent += other.summary.iterations;
            if other.summary.residual < best.summary.residual {
                *best = other;
            }
            None
        }
        Err(e) => Some(Err(e)),
    }
}

impl McpSolver for NewtonSolver {
    fn name(&self) -> &str {
        "newton"
    }

    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let mut result = self.solve_from(mcp, z0);
        // Tested by reference and returned from the one variable (no copy of a converged
        // solution): a converged solve costs a branch.
        if self.budget.is_none()
            && self.settings.structure_reseed
            && matches!(result, Err(SolveError::NotConverged { .. }))
        {
            result = self.reseed_attempt(mcp, z0, result);
        }
        result
    }

    /// [`McpSolver::solve`] with `out`'s storage: the first run writes its result there
    /// (`Workspace::result`), so a warm solve that converges in its first run allocates nothing.
    fn solve_into(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        out: &mut Solution,
    ) -> Result<(), SolveError> {
        self.ws.result = std::mem::take(out);
        *out = self.solve(mcp, z0)?;
        Ok(())
    }

    /// Honoured: a budgeted solve is the plain iteration's first run, without the minimum-norm
    /// restart and the other attempts of the full solve (`solve_restarted`), stopped after
    /// `budget` iterations (at most [`NewtonSettings::max_iterations`]).
    fn set_iteration_budget(&mut self, budget: Option<usize>) -> bool {
        self.budget = budget;
        true
    }

    /// Honoured: a predicted start below `polish_below · tolerance` is returned as it stands
    /// only at the round-off floor ([`NewtonSettings::chord_round_off_floor`]; without it,
    /// never), else it takes the polish's full step.
    fn set_start_predicted(&mut self, predicted: bool) -> bool {
        self.start_predicted = predicted;
        true
    }

    /// Near a solution the iteration converges quadratically, far below the tolerance.
    fn converges_to_round_off(&self) -> bool {
        true
    }
}

impl NewtonSolver {
    /// The solve from `z0`, judged in the problem's scene scales when it has them
    /// (`ecp_model::scaling`).
    fn solve_from(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        if !self.settings.scene_scales {
            return self.solve_budgeted(mcp, z0);
        }
        solve_in_scales(mcp, z0, |mcp, z0| self.solve_budgeted(mcp, z0))
    }

    /// [`NewtonSolver::solve_restarted`], or within the iteration budget
    /// ([`McpSolver::set_iteration_budget`]) its first run alone — followed, when it fails, by
    /// the Josephy–Newton attempt ([`NewtonSettings::josephy_newton`]) — the same point when
    /// that run converges, since the first run of `solve_restarted` is that run.
    fn solve_budgeted(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let Some(budget) = self.budget else {
            return self.solve_restarted(mcp, z0);
        };
        let limit = self.settings.max_iterations;
        self.settings.max_iterations = budget.min(limit);
        self.attempt = 0;
        self.grace_limit = self.settings.budget_grace.map(|_| limit);
        let mut result = self.solve_once(mcp, z0);
        self.grace_limit = None;
        if let Err(SolveError::NotConverged { best }) = &result
            && let Some(steps) = self.settings.josephy_newton
        {
            // Within the budget too: on a start whose branches the plain iteration cannot
            // sort out, the Josephy–Newton steps are the cheap way off it, before the driver
            // moves on to its next start (`docs/newton.md#josephy-newton-steps`).
            let mut spent = best.summary.iterations;
            let mut best = best.clone();
            if let Some(done) = self.josephy_attempt(mcp, z0, steps, &mut spent, &mut best) {
                result = done;
            } else {
                best.summary.iterations = spent;
                result = Err(SolveError::NotConverged { best });
            }
        }
        self.settings.max_iterations = limit;
        result
    }
}

impl NewtonSolver {
    /// The attempts from `z0` (`docs/newton.md#wall-time`): the plain iteration; the
    /// Josephy–Newton steps and the plain iteration from their end ([`NewtonSettings::josephy_newton`]); the
    /// non-monotone plain iteration ([`NewtonSettings::nonmonotone_restart`]); the smoothing
    /// continuation; the plain iteration with the damped restart's initial damping (these two
    /// the other way round without [`NewtonSettings::smoothing_first`]); the continuation with
    /// that damping. On problems above `dense_max` the damped plain iteration comes before the
    /// non-monotone one. Then, when those ended near a solution, the plain iteration from the
    /// complementary start ([`NewtonSettings::complementary_restart`]; before the first
    /// continuation when the attempts before it ended nearer,
    /// [`NewtonSettings::early_complementary_restart`]). The first that converges is returned
    /// (its iterations counting the failed attempts'), else the best end point.
    fn solve_restarted(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let damping = self.settings.damped_restart;
        let smoothing = self.settings.smoothing.is_some();
        self.attempt = 0;
        let mut best = match self.solve_plain(mcp, z0) {
            Err(SolveError::NotConverged { best }) => best,
            r => return r,
        };
        let mut spent = best.summary.iterations;
        if let Some(steps) = self.settings.josephy_newton
            && let Some(done) = self.josephy_attempt(mcp, z0, steps, &mut spent, &mut best)
        {
            return done;
        }
        let nonmonotone = Attempt {
            profile: 4,
            runs: self.settings.nonmonotone_restart && self.settings.watchdog_steps > 0,
            kind: AttemptKind::Nonmonotone,
            damped: false,
        };
        let damped_plain = Attempt {
            profile: 1,
            runs: damping.is_some(),
            kind: AttemptKind::Plain,
            damped: true,
        };
        let smoothed = Attempt {
            profile: 2,
            runs: smoothing,
            kind: AttemptKind::Smoothed,
            damped: false,
        };
        let damped_smoothed = Attempt {
            profile: 3,
            runs: smoothing && damping.is_some(),
            kind: AttemptKind::Smoothed,
            damped: true,
        };
        let dense = mcp.dim() <= self.settings.dense_max;
        let mut attempts = [nonmonotone, damped_plain, smoothed, damped_smoothed];
        if self.settings.smoothing_first && dense {
            attempts[1..3].swap(0, 1);
        }
        if !dense {
            // On large problems the damped plain iteration first: each iteration is a sparse
            // LU, and on bin20 (659 unknowns) it solves step 15 in 47 iterations where the
            // non-monotone restart first failed in 79 (`docs/newton.md#hard-steps`).
            attempts[..2].swap(0, 1);
        }
        let mut complementary_tried = false;
        for a in attempts {
            if !a.runs {
                continue;
            }
            if a.kind == AttemptKind::Smoothed
                && !complementary_tried
                && self.near_enough(&best, self.settings.early_complementary_restart)
            {
                complementary_tried = true;
                if let Some(done) = self.complementary_attempt(mcp, z0, &mut spent, &mut best) {
                    return done;
                }
            }
            self.attempt = a.profile;
            let saved = self.settings.lm_initial_damping;
            if a.damped {
                self.settings.lm_initial_damping = damping.unwrap_or(saved);
            }
            let result = match a.kind {
                AttemptKind::Smoothed => self.smoothing_continuation(mcp, z0),
                AttemptKind::Nonmonotone => {
                    // One run, without the minimum-norm restart of `solve_plain`: the attempt
                    // is meant to be cheap, and the later attempts cover what it does not solve.
                    self.nonmonotone = true;
                    let r = self.solve_once(mcp, z0);
                    self.nonmonotone = false;
                    r
                }
                AttemptKind::Plain => self.solve_plain(mcp, z0),
            };
            self.settings.lm_initial_damping = saved;
            if let Some(done) = fold_attempt(result, &mut spent, &mut best) {
                return done;
            }
        }
        if !complementary_tried
            && self.near_enough(&best, self.settings.complementary_restart)
            && let Some(done) = self.complementary_attempt(mcp, z0, &mut spent, &mut best)
        {
            return done;
        }
        if self.near_enough(&best, self.settings.complementary_restart_from_best) {
            // A failed solve only, so the copy's allocation does not touch the steady step.
            let from = best.z.clone();
            if let Some(done) = self.complementary_attempt(mcp, &from, &mut spent, &mut best) {
                return done;
            }
        }
        if let Some(done) = self.friction_continuation_attempt(mcp, z0, &mut spent, &mut best) {
            return done;
        }
        best.summary.iterations = spent;
        Err(SolveError::NotConverged { best })
    }
}

/// What an attempt of [`NewtonSolver::solve_restarted`] runs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum AttemptKind {
    /// The plain iteration ([`NewtonSolver::solve_plain`]).
    Plain,
    /// Full Newton steps under the watchdog ([`NewtonSettings::nonmonotone_restart`]).
    Nonmonotone,
    /// The smoothing continuation.
    Smoothed,
}

/// One attempt of [`NewtonSolver::solve_restarted`].
#[derive(Clone, Copy)]
struct Attempt {
    /// Index into [`NewtonProfile::attempt_iterations`].
    profile: usize,
    /// Whether the settings ask for it.
    runs: bool,
    kind: AttemptKind,
    /// With the damped restart's initial damping.
    damped: bool,
}

impl NewtonSolver {
    /// The plain iteration from `z0`, restarted once without minimum-norm steps when it failed
    /// after taking some (see [`NewtonSettings::min_norm_step`]).
    /// The plain iteration from `z0` as a named restart: a converged result counts one
    /// `Counter::Custom(name)` in its summary, so the caller sees which attempt solved the step.
    fn solve_plain_tallied(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        name: &'static str,
    ) -> Result<Solution, SolveError> {
        self.solve_plain(mcp, z0).map(|mut sol| {
            sol.summary.counters.add(Counter::Custom(name), 1);
            sol
        })
    }

    fn solve_plain(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let first = self.solve_once(mcp, z0);
        let kept = self.min_norm_kept;
        let forget = self.settings.forget_undone_steps;
        let used_min_norm = |summary: &ecp_model::Summary| {
            if forget {
                kept > 0
            } else {
                summary.counter(Counter::MinNormSteps).unwrap_or(0) > 0
            }
        };
        match first {
            // The minimum-norm steps are for non-isolated solution sets; on an isolated but
            // hard step (a light body in free flight near contact) their non-monotone watchdog
            // can end in a worse basin than the monotone safeguards would. One restart from
            // z0 without them (measured: the rotated T-bar free-flight pose of
            // tests/closest_points.rs) keeps both behaviours; the better result is returned.
            Err(SolveError::NotConverged { best })
                if self.settings.min_norm_step && used_min_norm(&best.summary) =>
            {
                self.settings.min_norm_step = false;
                let second = self.solve_once(mcp, z0);
                self.settings.min_norm_step = true;
                match second {
                    Ok(mut sol) => {
                        sol.summary.iterations += best.summary.iterations;
                        sol.summary.counters.add(Counter::MinNormRestarts, 1);
                        Ok(sol)
                    }
                    Err(SolveError::NotConverged { best: other })
                        if other.summary.residual < best.summary.residual =>
                    {
                        Err(SolveError::NotConverged { best: other })
                    }
                    Err(_) => Err(SolveError::NotConverged { best }),
                }
            }
            r => r,
        }
    }

    /// The smoothing continuation from `z0` (see [`NewtonSettings::smoothing`]): the plain
    /// iteration on `G_μ` for decreasing `μ`, then on the MCP itself.
    fn smoothing_continuation(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
    ) -> Result<Solution, SolveError> {
        let saved = self.settings.clone();
        let Some(smoothing) = saved.smoothing else {
            return self.solve_plain(mcp, z0);
        };
        self.settings.max_iterations = smoothing.stage_iterations;
        self.settings.polish_below = 1.0;
        self.in_continuation = true;
        let end = continuation(
            mcp,
            z0,
            &smoothing,
            saved.tolerance,
            |problem, z, tolerance| {
                self.settings.tolerance = tolerance;
                self.solve_plain(problem, z)
            },
            || false,
        );
        self.settings = saved;
        let end = match end {
            Ok(end) => end,
            Err(e) => {
                self.in_continuation = false;
                return Err(e);
            }
        };
        let last = self.solve_plain(mcp, &end.z);
        self.in_continuation = false;
        let tally = |summary: &mut ecp_model::Summary| end.tally(summary, 0);
        match last {
            Ok(mut sol) => {
                tally(&mut sol.summary);
                Ok(sol)
            }
            Err(SolveError::NotConverged { mut best }) => {
                tally(&mut best.summary);
                Err(SolveError::NotConverged { best })
            }
            e => e,
        }
    }
}

impl NewtonSolver {
    /// One solve from `z0` with the current settings (see [`McpSolver::solve`]).
    fn solve_once(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let start = Instant::now();
        validate_start(mcp, z0)?;
        self.prepare(mcp)?;
        // The last solve's LU (`NewtonSettings::chord_across_solves`), taken: only a run that
        // ends converged on an LU of its own keeps one for the next.
        let kept = std::mem::take(&mut self.kept_lu);
        let s = self.settings.clone();
        // The full limit and factor of a budgeted run's grace (`NewtonSettings::budget_grace`),
        // and that limit once the run went past its budget (the rate test's iterations left).
        let grace = self.grace_limit.zip(s.budget_grace);
        let mut grace_cap: Option<usize> = None;
        let n = mcp.dim();
        let (l, u) = (mcp.lower(), mcp.upper());
        let pattern = mcp.jacobian_pattern().clone();
        let ws = &mut self.ws;
        let mut trace = Vec::new();
        let (mut f_evals, mut jac_evals) = (0usize, 0usize);
        let (mut lm_steps, mut gradient_steps, mut newton_steps) = (0usize, 0usize, 0usize);
        let (mut min_norm_steps, mut nonmonotone_steps, mut watchdog_restores) = (0, 0, 0);
        // Watchdog of the non-monotone minimum-norm steps: Ψ at the checkpoint (the point the
        // sequence started from), the steps taken since, and a ceiling: after a restore, no new
        // non-monotone sequence until Ψ has halved.
        let mut checkpoint: Option<f64> = None;
        let mut watchdog_count = 0usize;
        let mut watchdog_ceiling = f64::INFINITY;
        // Minimum-norm steps kept, and those of the running non-monotone sequence (undone when
        // the watchdog restores its checkpoint).
        let (mut min_norm_kept, mut min_norm_pending) = (0usize, 0usize);
        // Taking the final full Newton step after convergence.
        let mut polishing = false;
        // Steps of this run cut by the ratio test (`NewtonSettings::ratio_test`).
        let mut ratio_steps = 0usize;
        // The next iteration may try a chord step (`NewtonSettings::chord_contraction`); the
        // last step was one; the chord's polish was taken.
        // (Both set below: true at the start when the last solve's LU is kept.)
        let (mut chord_ready, mut chord_lu);
        let (mut last_chord, mut chord_polished) = (false, false);
        // The last step taken was by the LU held (its full step, a chord step, the polish).
        let mut last_lu_step = false;
        let mut prof = NewtonProfile::default();
        let mut clock = Clock::new(self.profile.is_some());

        ws.z.copy_from_slice(z0);
        // The bound kinds, with the pattern the key of the kept LU: the same problem's next step
        // has the same kinds.
        // The bounds of the last solve, bit for bit, have its kinds (one vector pass instead of
        // classifying each pair); other bounds may still have them.
        let same_bounds = ws.kind_bounds.len() == 2 * n
            && same_bits(&ws.kind_bounds[..n], l)
            && same_bits(&ws.kind_bounds[n..], u);
        let same_kinds = same_bounds
            || ws.kinds.len() == n
                && (ws.kinds.iter())
                    .zip(l.iter().zip(u))
                    .all(|(k, (&l, &u))| *k == classify(l, u));
        if !same_bounds {
            ws.kind_bounds.clear();
            ws.kind_bounds.extend_from_slice(l);
            ws.kind_bounds.extend_from_slice(u);
        }
        if !same_kinds {
            ws.kinds.clear();
            ws.kinds
                .extend(l.iter().zip(u).map(|(&l, &u)| classify(l, u)));
            ws.bounded.clear();
            (ws.bounded).extend((0..n).filter(|&i| ws.kinds[i] != BoundKind::Free));
            // A free row of `H` is `J`'s: `(D_a, D_b) = (0, 1)`, not a unit row, whatever the
            // point; written here once, the iterations write the bounded rows alone.
            for (i, _) in ws
                .kinds
                .iter()
                .enumerate()
                .filter(|(_, k)| **k == BoundKind::Free)
            {
                (ws.da[i], ws.db[i], ws.unit[i]) = (0.0, 1.0, false);
            }
            ws.scaled_ready = false;
        }
        if !ws.scaled_ready {
            ws.scaled.clear();
            let ri = pattern.row_idx();
            (ws.scaled).extend((0..pattern.nnz()).filter(|&p| ws.kinds[ri[p]] != BoundKind::Free));
            ws.scaled_ready = true;
        }
        // The first iteration tries a chord step on the last solve's LU: only the plain
        // iteration's first run (the restarts after a failed run start afresh).
        // After tries that did not pay, the kept LU waits some solves (`KeptLuGate`).
        let from_kept = kept
            && same_kinds
            && s.chord_across_solves.is_some()
            && s.chord_contraction.is_some()
            && self.attempt == 0
            && !self.nonmonotone
            && !self.in_continuation
            && self.kept_lu_gate.take_turn();
        // `J` at the start only when the first iteration is likely to form `H`: not on the kept
        // LU (a refused chord step evaluates it then), and not after a solve that took no
        // iteration (a step at rest: `J` would be dropped, ≈ 12.7 k of A1's 36.7 k
        // instructions). Otherwise with `F` (`evaluate_with_jacobian` shares the blocks' pass);
        // `F` alone computes the same `F`, and `J` later the same `J`: the points are the same.
        // `F` at the start may be known already (`Mcp::known_value`: the warm start's guard
        // evaluated it there, ≈ 2.6 k instructions on A1): the same bits as evaluating it.
        let mut have_jac = !from_kept && self.last_iterated;
        // `ws.jac` holds `H` since the iteration formed it in place (`assemble_h`), not `J`.
        let mut jac_gone = false;
        let f_known = match (mcp.known_value(&ws.z), have_jac) {
            (Some(f), true) => {
                ws.f.copy_from_slice(f);
                mcp.jacobian(&ws.z, &mut ws.jac);
                true
            }
            (Some(f), false) => {
                ws.f.copy_from_slice(f);
                true
            }
            (None, true) => {
                mcp.evaluate_with_jacobian(&ws.z, &mut ws.f, &mut ws.jac);
                false
            }
            (None, false) => {
                mcp.evaluate(&ws.z, &mut ws.f);
                false
            }
        };
        jac_evals += usize::from(have_jac);
        f_evals += 1;
        // The LU held is of an `H` without pins whose step passed the descent test; it is the
        // last solve's (its chord steps contract by `chord_across_solves`).
        (chord_ready, chord_lu) = (from_kept, from_kept);
        let mut lu_from_last = from_kept;
        // A natural residual at the round-off floor of the point `z`
        // (`NewtonSettings::chord_round_off_floor`), and low enough that a full step's run
        // would stop there unpolished (a floor above that, from a large `‖z‖∞`, is not taken:
        // smaller components may still be resolved further).
        let at_round_off = |r: f64, z: &[f64]| {
            r <= s.polish_below * s.tolerance
                && s.chord_round_off_floor
                    .is_some_and(|ulps| within_round_off(r, ulps * f64::EPSILON, z))
        };
        // The contraction a chord step on the LU held must give.
        let chord_kappa = |from_last: bool| {
            if from_last {
                s.chord_across_solves
            } else {
                s.chord_contraction
            }
        };
        // `Φ` at the start may be known with `F` (`Mcp::known_fb_vector`: the warm start's guard
        // compared its starts by `‖Φ‖`): the same bits, and `Ψ` its sum of squares in the same
        // order as `fb_vector_of_kinds_squared` (≈ 1.4 k instructions on the desk).
        let known_phi = f_known
            .then(|| mcp.known_fb_vector(&ws.z))
            .flatten()
            .filter(|phi| phi.len() == n);
        let mut psi = match known_phi {
            Some(phi) => {
                ws.phi.copy_from_slice(phi);
                0.5 * dot(&ws.phi, &ws.phi)
            }
            None => 0.5 * fb_vector_of_kinds_squared(&ws.z, &ws.f, l, u, &ws.kinds, &mut ws.phi),
        };
        let psi_start = psi;
        let mut residual = natural_residual(&ws.z, &ws.f, l, u);
        // The best point is the iterate `z` itself while this holds (`z_best` is then stale):
        // it is copied only when a step leaves it (a copy per improvement before).
        let mut best_is_z = true;
        let mut best_residual = residual;
        // The best residual after each iteration (index 0: at the start), for the stall test.
        ws.best_history.clear();
        ws.best_history.push(best_residual);
        let mut best_psi = psi;
        ws.best_psi_history.clear();
        ws.best_psi_history.push(best_psi);

        let mut termination = Termination::MaxIterations;
        let mut iterations = 0;
        let mut lm_mu = s.lm_initial_damping;
        let mut lm_growth = 2.0;
        // Levenberg–Marquardt iterations of this run, and ν of the damping λ = ν‖Φ‖² once
        // `lm_residual_damping_after` of them have run.
        let mut lm_run = 0usize;
        let mut lm_nu = 1.0f64;
        if !psi.is_finite() {
            termination = Termination::NonFiniteFunction;
        }
        clock.lap(&mut prof, Phase::Jacobian);

        while termination == Termination::MaxIterations {
            // The chord's polish: one more chord step after a run converged by a chord step.
            let mut chord_polish = false;
            if residual <= s.tolerance {
                // Converged; one more full Newton step when the residual is just below the
                // tolerance (see `NewtonSettings::polish_below`), one more chord step when the
                // last step was one (its rate is linear: it ends a factor above round-off).
                // A predicted start (`McpSolver::set_start_predicted`) is not a point
                // converged to: below the polish bound it stands only at round-off.
                let unproven =
                    iterations == 0 && self.start_predicted && !at_round_off(residual, &ws.z);
                if polishing || (residual <= s.polish_below * s.tolerance && !unproven) {
                    let cap = grace_cap.unwrap_or(s.max_iterations);
                    if !last_chord || chord_polished || iterations >= cap {
                        termination = Termination::Converged;
                        break;
                    }
                    if at_round_off(residual, &ws.z) {
                        // At round-off already: the chord's polish cannot lower it.
                        prof.chord_polishes_skipped += 1;
                        termination = Termination::Converged;
                        break;
                    }
                    if lu_from_last {
                        // The last solve's `H` is a step old: its chord steps are not polished
                        // by another (their rate is slower), but by a full step (`polishing`).
                        chord_ready = false;
                    } else {
                        chord_polish = true;
                    }
                }
                polishing = true;
            }
            if iterations >= s.max_iterations {
                // A budgeted run past its budget goes on while converging
                // (`NewtonSettings::budget_grace`): below the full limit, its last iteration
                // having lowered the best natural residual by the grace factor.
                let h = &ws.best_history;
                let converging = grace.is_some_and(|(limit, kappa)| {
                    iterations < limit && h.len() >= 2 && h[h.len() - 1] <= kappa * h[h.len() - 2]
                });
                if !converging {
                    break;
                }
                grace_cap = grace.map(|(limit, _)| limit);
            }
            let mut accepted = None;
            // A chord step on the kept LU (`NewtonSettings::chord_contraction`): kept when it
            // contracts the natural residual enough, else the iteration goes on as without it.
            let mut chord_residual = None;
            if let Some(kappa) = chord_kappa(lu_from_last)
                && chord_ready
                && same_branches(
                    (&ws.z, &ws.f),
                    (&ws.z_lu, &ws.f_lu),
                    l,
                    u,
                    &ws.kinds,
                    &ws.bounded,
                )
                && let Some(linear) = self.linear.as_mut()
            {
                negate_into(&mut ws.d, &ws.phi);
                if linear.solve_in_place(&mut ws.d).is_ok()
                    && let Some(p) = try_step(mcp, ws, 1.0, l, u, &mut f_evals)
                    && (chord_polish || p < psi)
                {
                    // The polish is kept when it lowers the residual, as the full step's is;
                    // another chord step when it contracts it by `kappa`, or reaches the
                    // round-off floor (near it no step contracts it by `kappa`).
                    let r = natural_residual(&ws.z_trial, &ws.f_trial, l, u);
                    let kept = if chord_polish {
                        r < residual
                    } else {
                        r <= kappa * residual || at_round_off(r, &ws.z_trial)
                    };
                    if kept {
                        accepted = Some((1.0, p));
                        chord_residual = Some(r);
                    }
                }
                if chord_residual.is_some() {
                    prof.chord_steps += 1;
                    chord_polished = chord_polish;
                } else if chord_polish {
                    // Converged already; the polish gained nothing.
                    termination = Termination::Converged;
                    break;
                } else {
                    prof.chord_rejections += 1;
                }
            }
            let chord = chord_residual.is_some();
            if chord_ready && iterations == 0 {
                // The first iteration's chord step is on the last solve's LU.
                if chord {
                    prof.kept_lu_steps += 1;
                } else {
                    prof.kept_lu_refusals += 1;
                }
            }
            // Whether the step taken is the kept LU's full step (a chord step may follow it).
            let mut lu_step = chord;
            let mut newton_ok = false;
            // `∇Ψᵀd` of the Newton direction `d` (set with `newton_ok`, `d` unchanged while it
            // is used).
            let mut newton_slope = 0.0;
            // `grad` holds `∇Ψ = HᵀΦ` of this iteration's `H` (formed when first needed).
            let mut grad_ready = false;
            // `Ψ` at the full Newton step, when it was evaluated first
            // (`NewtonSettings::fast_full_step`; the trial buffers hold that point).
            let mut full_step = None;
            if !chord {
                if !have_jac {
                    mcp.jacobian(&ws.z, &mut ws.jac);
                    jac_evals += 1;
                }
                // H = D_a + D_b J in J's pattern (the diagonal is always stored).
                // At an attempt's start only: a warm start clamps unknowns onto their bounds
                // exactly, with `F` at round-off (A1 step 35); later iterates reach a bound
                // with `F` still moving (held there, d5_collision's step 25 took 8 iterations
                // instead of 6).
                generalized_jacobian_rows(
                    Some(&ws.bounded),
                    if iterations == 0 {
                        s.kink_band.unwrap_or(0.0)
                    } else {
                        0.0
                    },
                    &ws.z,
                    &ws.f,
                    l,
                    u,
                    &ws.kinds,
                    &pattern,
                    &ws.jac,
                    &mut ws.da,
                    &mut ws.db,
                    &mut ws.degenerate,
                    &mut ws.jv,
                );
                // H; `pin` gets the column maxima for the pinning test below, only when some
                // column may be pinned (`undecided`): else no column is, and `pin` is not read.
                // Formed in `J`'s buffer, the buffers swapped (no copy of `J`): `ws.jac` holds
                // no `J` until the next evaluation (`jac_gone`; the ratio test evaluates it
                // again at the same point, the same bits, when it needs `J d`).
                std::mem::swap(&mut ws.jac, &mut ws.h);
                jac_gone = true;
                let (largest, undecided, finite) = assemble_h(
                    &pattern,
                    None,
                    &ws.da,
                    &ws.db,
                    Some(&ws.scaled),
                    &mut ws.h,
                    &mut ws.witness,
                    &mut ws.pin,
                );
                if s.fast_full_step.is_none()
                    || s.pin_zero_columns
                        && undecided
                        && ws.pin.iter().any(|&m| m <= ZERO_COLUMN * largest)
                {
                    // ∇Ψ now: the pins below change `H`'s diagonal and back, not bit for bit.
                    gradient(&pattern, &ws.h, &ws.phi, &mut ws.grad);
                    grad_ready = true;
                }
                clock.lap(&mut prof, Phase::Jacobian);

                // Newton direction, with the DFK descent test.
                let linear = self.linear.as_mut().ok_or_else(|| {
                    SolveError::InvalidProblem("linear solver not prepared".into())
                })?;
                // Variables that do not enter the linearisation (a zero column of H: the slip rate
                // σ of an open contact, where p_n = p_f = 0) get a unit of their row's scale on the
                // diagonal for the factorisation, so the step leaves them where their (consistent)
                // row puts them instead of failing the LU over the whole system.
                let pinned = s.pin_zero_columns
                    && undecided
                    && pin_zero_columns(
                        &pattern,
                        &mut ws.h,
                        largest,
                        &mut ws.pin,
                        &mut ws.row_scale,
                    );
                newton_ok = if s.free_block {
                    unit_rows(&ws.db, &ws.bounded, &mut ws.unit);
                    // `H` found finite by its largest-magnitude pass (before any pins, which
                    // add to it): the free block's load moves it without testing each entry.
                    if finite && !pinned {
                        linear.factor_with_unit_rows_finite(&ws.h, &ws.unit)
                    } else {
                        linear.factor_with_unit_rows(&ws.h, &ws.unit)
                    }
                    .is_ok()
                } else {
                    linear.factor(&ws.h).is_ok()
                };
                if newton_ok && linear.factored_by_elimination() {
                    prof.structured_factorizations += 1;
                }
                if newton_ok && linear.unit_rows_left_out() > 0 {
                    prof.free_block_factorizations += 1;
                }
                if newton_ok && s.chord_contraction.is_some() {
                    ws.z_lu.copy_from_slice(&ws.z);
                    ws.f_lu.copy_from_slice(&ws.f);
                }
                if newton_ok {
                    negate_into(&mut ws.d, &ws.phi);
                    newton_ok = linear.solve_in_place(&mut ws.d).is_ok();
                }
                if pinned {
                    for (j, &p) in pattern.diag_pos().iter().enumerate() {
                        ws.h[p] -= ws.pin[j];
                    }
                }
                if newton_ok
                    && !polishing
                    && !pinned
                    && let Some(fraction) = s.fast_full_step
                {
                    // The full step first: taken when it lowers `Ψ` by `fraction`, without `∇Ψ`
                    // (`NewtonSettings::fast_full_step`); else judged below as without it. Not
                    // on a pinned `H` (singular but for the pins: D5's collision, where the
                    // descent test refuses steps that lower `Ψ` and the non-isolated `σ` follows
                    // the step taken).
                    let p = try_step(mcp, ws, 1.0, l, u, &mut f_evals);
                    // With `∇Ψᵀd = −2Ψ` (an exact solve), the descent test is
                    // `2Ψ ≥ ρ‖d‖^p`: asked of the step too (a long step of an inaccurate solve is
                    // judged by the tests).
                    if let Some(p) = p
                        && p <= fraction * psi
                        && at_least_rho_pow(2.0 * psi, s.descent_rho, norm2(&ws.d), s.descent_p)
                    {
                        accepted = Some((1.0, p));
                        lu_step = true;
                        prof.full_steps_first += 1;
                    } else {
                        full_step = Some(p);
                    }
                }
                if newton_ok && accepted.is_none() {
                    if !grad_ready {
                        gradient(&pattern, &ws.h, &ws.phi, &mut ws.grad);
                        grad_ready = true;
                    }
                    // `∇Ψᵀd`, kept as the slope of the Newton direction's line searches below.
                    newton_slope = dot(&ws.grad, &ws.d);
                    let nd = norm2(&ws.d);
                    // `x ≤ (−ρ)·P` is `−x ≥ ρ·P` (a product's rounding is symmetric).
                    newton_ok = newton_slope.is_finite()
                        && at_least_rho_pow(-newton_slope, s.descent_rho, nd, s.descent_p);
                }
                // A pinned `H` is singular but for the pins (D5's collision): its chord steps
                // end where the next `H`'s LU fails, so its LU is not kept for them.
                chord_lu = newton_ok && !pinned;
                lu_from_last = false;
                prof.lu_factorizations += 1;
                clock.lap(&mut prof, Phase::NewtonDirection);
            }
            let mut kind = StepKind::Newton;
            if polishing && chord {
                // A chord step is no polish: the run stops by the test it stops by without them.
                polishing = false;
            } else if polishing {
                // At a singular `H` (a solution set that is not isolated: the B–C contact height
                // of D5's collision) there is no LU step; the minimum-norm step solves `H d = −Φ`
                // as well where `Φ` is in the range of `H`, so it gains the same digits. Only in
                // a run that took ratio steps: they are what moved its end point; runs without
                // them end where they did (`docs/newton.md#the-ratio-test`).
                let mut polish_ok = newton_ok;
                if !polish_ok && ratio_steps > 0 && !ws.dense.is_empty() {
                    prof.min_norm_factorizations += 1;
                    polish_ok = self.min_norm.step(
                        n > s.dense_max,
                        &pattern,
                        &ws.h,
                        &mut ws.dense,
                        &ws.phi[..n],
                        &mut ws.d[..n],
                        s.rank_tolerance,
                    );
                }
                let better = if polish_ok {
                    try_step(mcp, ws, 1.0, l, u, &mut f_evals)
                        .filter(|_| natural_residual(&ws.z_trial, &ws.f_trial, l, u) < residual)
                } else {
                    None
                };
                match better {
                    Some(p) => {
                        accepted = Some((1.0, p));
                        lu_step = newton_ok;
                    }
                    None => {
                        termination = Termination::Converged;
                        break;
                    }
                }
            }
            let local = residual <= s.min_norm_radius || psi <= 1e-6 * psi_start;
            if newton_ok && accepted.is_none() {
                // The full Newton step, when it decreases Ψ enough (fast local convergence).
                let trial = match full_step {
                    Some(p) => p,
                    None => try_step(mcp, ws, 1.0, l, u, &mut f_evals),
                };
                if let Some(p) = trial {
                    if p <= psi + s.armijo * newton_slope
                        || natural_residual(&ws.z_trial, &ws.f_trial, l, u) <= s.tolerance
                    {
                        accepted = Some((1.0, p));
                        lu_step = true;
                    } else if self.nonmonotone && s.watchdog_steps > 0 && psi < watchdog_ceiling {
                        // The non-monotone restart: the full step, under the watchdog.
                        ws.open_watchdog(&mut checkpoint, &mut watchdog_count, psi);
                        accepted = Some((1.0, p));
                        nonmonotone_steps += 1;
                    }
                }
            }
            // The Armijo search along the Newton direction (De Luca–Facchinei–Kanzow), kept
            // aside: the Levenberg–Marquardt step below is tried too, and the iteration takes
            // whichever lowers Ψ more.
            let mut newton_search = None;
            // Whether `newton_search` holds the ratio test's point (counted when it is taken).
            let mut ratio_candidate = false;
            // The ratio test (`NewtonSettings::ratio_test`): in the plain iteration, a full step
            // that failed the Armijo test is cut at the first pair that leaves its cone along the
            // linearisation. That point is taken when the linearisation held up to it (`Ψ` fell
            // by `RATIO_MODEL_AGREEMENT` of the fall it predicts); when it lowers `Ψ` less, it is
            // a point of the Newton direction's search like the Armijo point (which it
            // replaces), compared with the Levenberg–Marquardt step below, the lower `Ψ` taken;
            // when it raises `Ψ`, it is taken under the watchdog (the kink of Φ the pair
            // crosses, as a pivot).
            let ratio_on = s.ratio_test && self.attempt == 0 && !self.in_continuation;
            if ratio_on && accepted.is_none() && newton_ok {
                if jac_gone {
                    // `J` at `z` again (its buffer holds `H`'s last values): the same point,
                    // the same bits; not counted, as the one evaluation it replaces.
                    mcp.jacobian(&ws.z, &mut ws.jac);
                    jac_gone = false;
                }
                pattern.mul_vec(&ws.jac, &ws.d, &mut ws.jv);
                if let Some(event) = ratio::first_event(&ws.z, &ws.f, &ws.d, &ws.jv, l, u)
                    && let Some(p) = try_ratio_step(mcp, ws, event, l, u, &mut f_evals)
                {
                    // Along the Newton direction the linearisation predicts Φ(t) = (1 − t)Φ,
                    // so Ψ(t) = (1 − t)²Ψ: a fall of (1 − (1 − t)²)Ψ.
                    let predicted = (1.0 - (1.0 - event.0) * (1.0 - event.0)) * psi;
                    if psi - p >= RATIO_MODEL_AGREEMENT * predicted {
                        accepted = Some((event.0, p));
                        ratio_steps += 1;
                    } else if p < psi {
                        newton_search = Some((event.0, p));
                        ratio_candidate = true;
                        ws.z_alt.copy_from_slice(&ws.z_trial);
                        ws.f_alt.copy_from_slice(&ws.f_trial);
                        ws.phi_alt.copy_from_slice(&ws.phi_trial);
                        ws.d_alt.copy_from_slice(&ws.d);
                    } else if s.watchdog_steps > 0 && psi < watchdog_ceiling {
                        ws.open_watchdog(&mut checkpoint, &mut watchdog_count, psi);
                        accepted = Some((event.0, p));
                        nonmonotone_steps += 1;
                        ratio_steps += 1;
                    }
                }
            }
            if accepted.is_none() && newton_ok && s.newton_line_search {
                let slope = newton_slope;
                let mut t = s.backtrack;
                while newton_search.is_none() && t >= s.newton_shortest_step {
                    if let Some(p) = try_step(mcp, ws, t, l, u, &mut f_evals)
                        && (p <= psi + s.armijo * t * slope
                            || natural_residual(&ws.z_trial, &ws.f_trial, l, u) <= s.tolerance)
                    {
                        newton_search = Some((t, p));
                        ws.z_alt.copy_from_slice(&ws.z_trial);
                        ws.f_alt.copy_from_slice(&ws.f_trial);
                        ws.phi_alt.copy_from_slice(&ws.phi_trial);
                        ws.d_alt.copy_from_slice(&ws.d);
                    }
                    t *= s.backtrack;
                }
            }
            clock.lap(&mut prof, Phase::NewtonSearch);
            // Near a solution (natural residual ≤ min_norm_radius, or Ψ down by 1e6 from the
            // start) the minimum-norm step is taken as below. Farther out it is taken only when
            // it decreases Ψ fast (by half at least), without the watchdog or backtracking:
            // there the undamped Gauss–Newton step can follow directions of tiny singular values
            // into the basin of the spurious p_n > 0 minimiser of separated steps (measured on
            // the rotated free-flight T-bar of tests/closest_points.rs), which
            // Levenberg–Marquardt's damping avoids.
            if accepted.is_none() && !newton_ok && !ws.dense.is_empty() {
                // H singular (or its LU step useless): the minimum-norm least-squares step
                // d = −H⁺Φ. It is a descent direction for Ψ (∇Ψᵀd = −‖Hd‖²) unless Φ ⊥ range H.
                prof.min_norm_factorizations += 1;
                if !grad_ready {
                    gradient(&pattern, &ws.h, &ws.phi, &mut ws.grad);
                    grad_ready = true;
                }

                if self.min_norm.step(
                    n > s.dense_max,
                    &pattern,
                    &ws.h,
                    &mut ws.dense,
                    &ws.phi[..n],
                    &mut ws.d[..n],
                    s.rank_tolerance,
                ) {
                    let slope = dot(&ws.grad, &ws.d);
                    if slope < 0.0 {
                        // The full step, judged by Armijo; failing that, taken anyway under
                        // the watchdog (it may cross a kink of Φ towards the right active
                        // set: Ψ rises for a step or two, then falls quadratically); failing
                        // that, backtracking.
                        if let Some(p) = try_step(mcp, ws, 1.0, l, u, &mut f_evals) {
                            let watched = local && s.watchdog_steps > 0 && psi < watchdog_ceiling;
                            if (p <= psi + s.armijo * slope && (local || p <= 0.5 * psi))
                                || natural_residual(&ws.z_trial, &ws.f_trial, l, u) <= s.tolerance
                            {
                                accepted = Some((1.0, p));
                            } else if watched {
                                ws.open_watchdog(&mut checkpoint, &mut watchdog_count, psi);
                                accepted = Some((1.0, p));
                                nonmonotone_steps += 1;
                            }
                        }
                        let mut t = s.backtrack;
                        while local && accepted.is_none() && t >= MIN_NORM_SHORTEST_STEP {
                            if let Some(p) = try_step(mcp, ws, t, l, u, &mut f_evals)
                                && (p <= psi + s.armijo * t * slope
                                    || natural_residual(&ws.z_trial, &ws.f_trial, l, u)
                                        <= s.tolerance)
                            {
                                accepted = Some((t, p));
                            }
                            t *= s.backtrack;
                        }
                        if accepted.is_some() {
                            min_norm_steps += 1;
                            if checkpoint.is_some() {
                                min_norm_pending += 1;
                            } else {
                                min_norm_kept += 1;
                            }
                        }
                    }
                }
            }
            clock.lap(&mut prof, Phase::MinNorm);
            if accepted.is_none() {
                prof.lm_iterations += 1;
                if !grad_ready {
                    gradient(&pattern, &ws.h, &ws.phi, &mut ws.grad);
                    grad_ready = true;
                }

                // Levenberg–Marquardt with an adaptive damping (Moré's update): solve
                // (HᵀH + λI) d = −∇Ψ, accept when the actual decrease of Ψ is a fair share of the
                // decrease predicted by the linear model ½‖Φ + H d‖².
                if self.normal.as_ref().is_none_or(|ne| {
                    !ne.serves(&pattern, s.dense_max, s.lm_cholesky, s.lm_sparse_product)
                }) {
                    self.normal = NormalEquations::new(
                        &pattern,
                        s.dense_max,
                        s.lm_cholesky,
                        s.lm_sparse_product,
                    )
                    .ok();
                }
                // In the plain iteration only: the restarts after it were tuned with Moré's
                // damping (the damped restart is a choice of it), and the non-monotone restart
                // with it solves steps that the plain iteration with either damping does not.
                let residual_damping = self.attempt == 0
                    && s.lm_residual_damping_after
                        .is_some_and(|after| lm_run >= after);
                lm_run += 1;
                if let Some(ne) = self.normal.as_mut() {
                    // HᵀH once per iteration; each damping trial only adds its λ and factorises.
                    let max_diag = ne.form(&ws.h).max(1e-300);
                    for _ in 0..s.max_lm_trials {
                        prof.lm_trials += 1;
                        prof.lm_augmented_factorizations += usize::from(ne.is_augmented());
                        prof.lm_cholesky_flops += ne.sparse_cholesky_flops().unwrap_or(0.0);
                        let lambda = if residual_damping {
                            // Not below the round-off of HᵀH.
                            (lm_nu * 2.0 * psi).max(1e-14 * max_diag)
                        } else {
                            lm_mu * max_diag
                        };
                        let failed = ne.factor_damped(lambda).is_err() || {
                            negate_into(&mut ws.d, &ws.grad);
                            ne.solve_in_place(&mut ws.d).is_err()
                        };
                        if failed {
                            if residual_damping {
                                lm_nu *= 4.0;
                            } else {
                                lm_mu *= lm_growth;
                                lm_growth *= 2.0;
                            }
                            continue;
                        }
                        pattern.mul_vec(&ws.h, &ws.d, &mut ws.hd);
                        let predicted = -(dot(&ws.grad, &ws.d) + 0.5 * dot(&ws.hd, &ws.hd));
                        clock.lap(&mut prof, Phase::LmFactor);
                        let trial = try_step(mcp, ws, 1.0, l, u, &mut f_evals);
                        clock.lap(&mut prof, Phase::LmTrial);
                        match trial {
                            Some(p) if predicted > 0.0 && psi - p >= 1e-4 * predicted => {
                                let rho = (psi - p) / predicted;
                                if residual_damping {
                                    // Fan–Pan's update of ν.
                                    if rho > 0.75 {
                                        lm_nu = (lm_nu / 4.0).max(1e-8);
                                    } else if rho < 0.25 {
                                        lm_nu *= 4.0;
                                    }
                                } else {
                                    lm_mu = (lm_mu
                                        * (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3)))
                                    .max(1e-20);
                                    lm_growth = 2.0;
                                }
                                accepted = Some((1.0, p));
                                kind = StepKind::LevenbergMarquardt;
                                break;
                            }
                            _ if residual_damping => {
                                lm_nu *= 4.0;
                                if lm_nu * 2.0 * psi > 1e20 * max_diag {
                                    break;
                                }
                            }
                            _ => {
                                lm_mu *= lm_growth;
                                lm_growth *= 2.0;
                                if lm_mu > 1e20 {
                                    break;
                                }
                            }
                        }
                    }
                }
            }
            clock.lap(&mut prof, Phase::LmFactor);
            if let Some((t, p)) = newton_search
                && accepted.is_none_or(|(_, q)| p < q)
            {
                std::mem::swap(&mut ws.z_trial, &mut ws.z_alt);
                std::mem::swap(&mut ws.f_trial, &mut ws.f_alt);
                std::mem::swap(&mut ws.phi_trial, &mut ws.phi_alt);
                std::mem::swap(&mut ws.d, &mut ws.d_alt);
                accepted = Some((t, p));
                kind = StepKind::Newton;
                if ratio_candidate {
                    ratio_steps += 1;
                }
            }
            if accepted.is_none() {
                if !grad_ready {
                    gradient(&pattern, &ws.h, &ws.phi, &mut ws.grad);
                }
                // Last resort: Armijo backtracking along the Newton direction, then along −∇Ψ.
                // No allocation in the iteration: the candidates are a fixed pair.
                let candidates = [StepKind::Newton, StepKind::Gradient];
                for k in candidates
                    .into_iter()
                    .filter(|k| newton_ok || *k != StepKind::Newton)
                {
                    if k == StepKind::Newton {
                        negate_into(&mut ws.d, &ws.phi);
                        if let Some(linear) = self.linear.as_mut() {
                            let _ = linear.solve_in_place(&mut ws.d);
                        }
                    } else {
                        negate_into(&mut ws.d, &ws.grad);
                    }
                    let slope = dot(&ws.grad, &ws.d);
                    let mut t = 1.0;
                    while t >= s.min_step {
                        if let Some(p) = try_step(mcp, ws, t, l, u, &mut f_evals)
                            && (p <= psi + s.armijo * t * slope
                                || natural_residual(&ws.z_trial, &ws.f_trial, l, u) <= s.tolerance)
                        {
                            accepted = Some((t, p));
                            break;
                        }
                        t *= s.backtrack;
                    }
                    if accepted.is_some() {
                        kind = k;
                        break;
                    }
                }
            }
            let Some((t, psi_new)) = accepted else {
                termination = Termination::LineSearchFailed;
                break;
            };
            match kind {
                StepKind::Newton => newton_steps += 1,
                StepKind::LevenbergMarquardt => lm_steps += 1,
                _ => gradient_steps += 1,
            }
            if self.observer.is_some() || s.trace {
                let record = IterationRecord {
                    iteration: iterations,
                    residual,
                    merit: psi,
                    step: kind,
                    step_length: t,
                    direction_norm: norm2(&ws.d),
                };
                if let Some(obs) = self.observer.as_mut() {
                    obs.observe(&record);
                }
                if s.trace {
                    trace.push(record);
                }
            }
            iterations += 1;
            std::mem::swap(&mut ws.z, &mut ws.z_trial);
            std::mem::swap(&mut ws.f, &mut ws.f_trial);
            std::mem::swap(&mut ws.phi, &mut ws.phi_trial);
            psi = psi_new;
            let previous = residual;
            residual = chord_residual.unwrap_or_else(|| natural_residual(&ws.z, &ws.f, l, u));
            last_chord = chord;
            last_lu_step = lu_step;
            have_jac = false;
            // A step by the kept LU that contracted the residual fast, near the solution.
            chord_ready = chord_kappa(lu_from_last).is_some_and(|kappa| {
                lu_step
                    && chord_lu
                    && checkpoint.is_none()
                    && residual <= kappa * previous
                    && residual <= s.min_norm_radius
            });
            if residual < best_residual {
                best_residual = residual;
                best_is_z = true;
            } else if best_is_z {
                // The step left the best point: it is the iterate before the step, in `z_trial`
                // since the swap.
                ws.z_best.copy_from_slice(&ws.z_trial);
                best_is_z = false;
            }
            ws.best_history.push(best_residual);
            best_psi = best_psi.min(psi);
            ws.best_psi_history.push(best_psi);
            // The iterations the stall test counts (those undone by a restore are dropped
            // from the history with `forget_undone_steps`).
            let counted = ws.best_history.len() - 1;
            let judged = !(s.forget_undone_steps && checkpoint.is_some());
            // The rate and flat-merit tests end runs that are going to fail before the next
            // attempt; not the continuation's runs.
            let cut_early = judged && !self.in_continuation;
            if judged
                && s.stall_window > 0
                && counted > s.stall_window
                && best_residual > s.stall_reduction * ws.best_history[counted - s.stall_window]
            {
                termination = Termination::Stagnated;
                break;
            }
            if cut_early
                && s.slow_rate_test
                && s.stall_window > 0
                && counted >= 2 * s.stall_window
                && best_residual > s.tolerance
            {
                // The rate over the window (the stall test above ensures it is below 1).
                let rate = (best_residual / ws.best_history[counted - s.stall_window]).ln()
                    / s.stall_window as f64;
                let needed = (s.tolerance / best_residual).ln() / rate;
                let left = grace_cap
                    .unwrap_or(s.max_iterations)
                    .saturating_sub(iterations);
                if needed > RATE_TEST_MARGIN * left as f64 {
                    termination = Termination::Stagnated;
                    break;
                }
            }
            let k = s.flat_merit_window;
            if cut_early
                && k > 0
                && counted >= 2 * k
                && best_residual > s.tolerance
                && best_psi >= (1.0 - 1e-3) * ws.best_psi_history[counted - k]
            {
                termination = Termination::Stagnated;
                break;
            }
            if let Some(psi_check) = checkpoint {
                watchdog_count += 1;
                if psi <= (1.0 - s.armijo) * psi_check || residual <= s.tolerance {
                    checkpoint = None;
                    min_norm_kept += min_norm_pending;
                    min_norm_pending = 0;
                } else if watchdog_count >= s.watchdog_steps {
                    if s.forget_undone_steps {
                        let keep = ws.best_history.len().saturating_sub(watchdog_count).max(1);
                        ws.best_history.truncate(keep);
                        ws.best_psi_history.truncate(keep);
                        best_psi = ws.best_psi_history[keep - 1];
                    }
                    min_norm_pending = 0;
                    if best_is_z {
                        ws.z_best.copy_from_slice(&ws.z);
                        best_is_z = false;
                    }
                    // The sequence failed: back to the checkpoint, monotone steps from there.
                    std::mem::swap(&mut ws.z, &mut ws.z_check);
                    std::mem::swap(&mut ws.f, &mut ws.f_check);
                    std::mem::swap(&mut ws.phi, &mut ws.phi_check);
                    psi = psi_check;
                    residual = natural_residual(&ws.z, &ws.f, l, u);
                    watchdog_ceiling = 0.5 * psi_check;
                    watchdog_restores += 1;
                    checkpoint = None;
                    (chord_ready, last_chord) = (false, false);
                    continue;
                }
            }
            // Whether the step moved `z` (relative) by more than round-off, only where the test
            // needs it: the iterate before the step is in `z_trial` since the swap (a restore
            // `continue`s). The largest move is at most `4ε` exactly when no component's is
            // above it (a NaN one counts in neither), so the scan stops at the first that is.
            let moved = || {
                (ws.z_trial.iter())
                    .zip(&ws.z)
                    .any(|(a, b)| (a - b).abs() / (1.0 + a.abs()) > 4.0 * f64::EPSILON)
            };
            if residual > s.tolerance && !moved() {
                termination = Termination::Stagnated;
            }
            clock.lap(&mut prof, Phase::Other);
        }
        self.min_norm_kept = min_norm_kept + min_norm_pending;
        self.last_iterated = iterations > 0;
        if from_kept {
            // The try paid when the run converged without a factorisation of its own.
            self.kept_lu_gate
                .record(termination == Termination::Converged && prof.lu_factorizations == 0);
        }
        // The LU is worth keeping for the next solve when the run was one step on it that
        // reached the round-off floor (or no step, on the kept LU): the step's problem is
        // nearly linear there, so the next step's is likely solved by one chord step on it. A
        // run that needed several steps (the desk: a full step to 1e-9, then chord steps)
        // keeps none: the next step's residual would need several chord steps on an `H` a step
        // old, which cost more than a factorisation (`docs/latency.md`, branch wip-a1fast).
        let one_lu_step =
            iterations == 0 || (iterations == 1 && last_lu_step && at_round_off(residual, &ws.z));
        if let Some(total) = self.profile.as_mut() {
            prof.runs = 1;
            prof.iterations = iterations;
            prof.attempt_iterations[self.attempt.min(4)] = iterations;
            prof.f_evals = f_evals;
            total.add(&prof);
        }
        // Returning the last iterate: F there is at hand (the iteration keeps `f = F(z)`).
        // (`best_is_z` implies `residual == best_residual`, so the last iterate.)
        let at_last = termination == Termination::Converged || residual <= best_residual;
        let z_out: &[f64] = if at_last || best_is_z {
            &ws.z
        } else {
            &ws.z_best
        };
        // The result in the storage `solve_into` handed over, if any (counters included).
        let mut result = std::mem::take(&mut ws.result);
        let mut counters = std::mem::take(&mut result.summary.counters);
        counters.set_all([
            (Counter::NewtonSteps, newton_steps),
            (Counter::MinNormSteps, min_norm_steps),
            (Counter::NonmonotoneSteps, nonmonotone_steps),
            (Counter::WatchdogRestores, watchdog_restores),
            (Counter::LevenbergMarquardtSteps, lm_steps),
            (Counter::GradientSteps, gradient_steps),
        ]);
        let report = SolveReport {
            solver: "newton",
            termination,
            tolerance: s.tolerance,
            iterations,
            f_evals,
            jac_evals,
            started: start,
            trace,
            counters,
        };
        if !at_last {
            return finish_solve(mcp, z_out.to_vec(), report);
        }
        // Φ at the returned point is at hand too (the iteration keeps `phi = Φ(z)`): its sum of
        // squares, in component order as `fb_residual` sums it, spares the finish that pass. It
        // is `2Ψ` (the iteration keeps `psi = ½ dot(Φ, Φ)`, and halving a sum of at least twice
        // the smallest normal number is exact); the sum again below that, and for a NaN.
        let phi_squared = if psi >= 2.0 * f64::MIN_POSITIVE {
            2.0 * psi
        } else {
            dot(&ws.phi, &ws.phi)
        };
        // `residual` is the natural residual of `(z, F)` (every assignment computes it there),
        // so the worst component is its first occurrence.
        let worst = worst_component_of_residual(z_out, &ws.f, l, u, residual);
        let residuals = FinalResiduals::new(worst, phi_squared);
        if finish_solve_with(mcp, z_out, &residuals, report, &mut result) {
            // Converged on its last LU: kept for the next solve's first iteration.
            self.kept_lu = s.chord_across_solves.is_some() && chord_lu && one_lu_step;
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

    /// `kink_band`: a component at its lower bound with `F` at −5e-16 gets the row of `F ≥ 0`
    /// (`D_a = −1, D_b = 0`) with the band and the partial derivatives `(−1, −2)` without it;
    /// `F` at −1e-13 (outside a band of 1e-14) keeps the derivatives; at an upper bound the
    /// mirror image (`F` at +5e-16); a free component and one off its bound are not touched.
    #[test]
    fn the_kink_band_holds_a_bound_whose_f_is_out_by_round_off_only() {
        let pattern = CscPattern::dense(4);
        let jac = vec![0.0; 16];
        let inf = f64::INFINITY;
        let (l, u) = ([0.0, -inf, 0.0, -inf], [inf, 1.0, inf, inf]);
        let kinds: Vec<BoundKind> = (0..4).map(|i| classify(l[i], u[i])).collect();
        let z = [0.0, 1.0, 1e-3, 2.0];
        let rows = |f: [f64; 4], band: f64| {
            let (mut da, mut db, mut deg, mut jv) =
                (vec![0.0; 4], vec![0.0; 4], Vec::new(), vec![0.0; 4]);
            generalized_jacobian_rows(
                None, band, &z, &f, &l, &u, &kinds, &pattern, &jac, &mut da, &mut db, &mut deg,
                &mut jv,
            );
            (da, db)
        };
        let f = [-5e-16, 5e-16, -5e-16, 3.0];
        let (da, db) = rows(f, 0.0);
        assert_eq!((da[0], db[0]), (-1.0, -2.0));
        assert_eq!((da[1], db[1]), (-1.0, -2.0));
        let (da_b, db_b) = rows(f, 1e-14);
        assert_eq!((da_b[0], db_b[0]), (-1.0, 0.0));
        assert_eq!((da_b[1], db_b[1]), (-1.0, 0.0));
        // Off its bound by 1e-3 and free: the same rows with the band as without.
        assert_eq!((da_b[2], db_b[2]), (da[2], db[2]));
        assert_eq!((da_b[3], db_b[3]), (0.0, 1.0));
        let (da_far, db_far) = rows([-1e-13, 1e-13, 0.0, 0.0], 1e-14);
        assert!((da_far[0] + 1.0).abs() < 1e-15 && (db_far[0] + 2.0).abs() < 1e-15);
        assert!((da_far[1] + 1.0).abs() < 1e-15 && (db_far[1] + 2.0).abs() < 1e-15);
        // Both pairs at the kink (`z` at the bound, `F = 0`): listed, and their rows the
        // element along `J v` with `v = (1, −1, 0, 0)`; `J_rj = 4j + r + 1`, so `(J v)_0 = −4`,
        // `(J v)_1 = −4`: `(1/√17 − 1, ∓4/√17 − 1)` (the upper pair's sign turned).
        let jac: Vec<f64> = (0..16).map(|p| f64::from(p + 1)).collect();
        let (mut da, mut db, mut deg, mut jv) = (vec![0.0; 4], vec![0.0; 4], vec![7], vec![0.0; 4]);
        generalized_jacobian_rows(
            None, 0.0, &z, &[0.0; 4], &l, &u, &kinds, &pattern, &jac, &mut da, &mut db, &mut deg,
            &mut jv,
        );
        assert_eq!(deg, vec![0, 1]);
        let r = 17f64.sqrt();
        let near = |a: f64, b: f64| (a - b).abs() < 1e-15;
        assert!(
            near(da[0], 1.0 / r - 1.0) && near(db[0], -4.0 / r - 1.0),
            "{da:?} {db:?}"
        );
        assert!(
            near(da[1], 1.0 / r - 1.0) && near(db[1], 4.0 / r - 1.0),
            "{da:?} {db:?}"
        );
    }

    /// `generalized_jacobian_rows` over the bounded rows alone (free rows written once, as
    /// the workspace does when it classifies the bounds) gives the bits of every row written,
    /// the same degenerate list and `J v`: every kind, at and off its kinks, with the band.
    #[test]
    fn the_bounded_rows_alone_give_the_rows_of_all() {
        let inf = f64::INFINITY;
        let n = 8;
        let pattern = CscPattern::dense(n);
        let jac: Vec<f64> = (0..n * n).map(|p| f64::from(p as u32 % 7) - 3.0).collect();
        let l = [0.0, -inf, -inf, 0.0, -1.0, -inf, 0.0, 0.0];
        let u = [inf, inf, 1.0, inf, 1.0, inf, inf, 2.0];
        let kinds: Vec<BoundKind> = (0..n).map(|i| classify(l[i], u[i])).collect();
        let bounded: Vec<usize> = (0..n).filter(|&i| kinds[i] != BoundKind::Free).collect();
        let points: [([f64; 8], [f64; 8]); 3] = [
            (
                [0.0, 1.0, 1.0, 0.5, 0.25, -2.0, 0.0, 2.0],
                [0.0, 3.0, 0.0, -1.0, 2.0, 1.0, -5e-16, 0.0],
            ),
            (
                [0.5, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0],
                [1.0, -1.0, 2.0, 0.0, -1.0, 0.0, 0.0, 0.5],
            ),
            ([0.0; 8], [0.0; 8]),
        ];
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        for (z, f) in points {
            for band in [0.0, 1e-14] {
                let (mut da0, mut db0, mut deg0, mut jv0) =
                    (vec![7.0; n], vec![7.0; n], Vec::new(), vec![7.0; n]);
                generalized_jacobian_rows(
                    None, band, &z, &f, &l, &u, &kinds, &pattern, &jac, &mut da0, &mut db0,
                    &mut deg0, &mut jv0,
                );
                let (mut da1, mut db1, mut deg1, mut jv1) =
                    (vec![7.0; n], vec![7.0; n], vec![3], vec![7.0; n]);
                for i in (0..n).filter(|&i| kinds[i] == BoundKind::Free) {
                    (da1[i], db1[i]) = (0.0, 1.0);
                }
                generalized_jacobian_rows(
                    Some(&bounded),
                    band,
                    &z,
                    &f,
                    &l,
                    &u,
                    &kinds,
                    &pattern,
                    &jac,
                    &mut da1,
                    &mut db1,
                    &mut deg1,
                    &mut jv1,
                );
                assert_eq!(bits(&da1), bits(&da0), "{z:?} {f:?} band {band}");
                assert_eq!(bits(&db1), bits(&db0), "{z:?} {f:?} band {band}");
                assert_eq!(deg1, deg0);
                if !deg0.is_empty() {
                    assert_eq!(bits(&jv1), bits(&jv0));
                }
                let (mut unit0, mut unit1) = (vec![true; n], vec![false; n]);
                for (m, &b) in unit0.iter_mut().zip(&db0) {
                    *m = b == 0.0;
                }
                unit_rows(&db1, &bounded, &mut unit1);
                assert_eq!(unit1, unit0);
            }
        }
    }

    /// The flat assembly and the gradient apart give the bits of the plain assembly, column by
    /// column in stored order (`H`, `∇Ψ`, `H`'s largest; the column magnitudes decide the
    /// pinning test as the column maxima do, with a NaN column and a zero one), on patterns
    /// with an odd and an even number of columns, columns with the diagonal first, last and
    /// alone, and columns of different lengths.
    /// `within_round_off` decides as `r ≤ k · round_off_scale(z)` does: every length to 6,
    /// `r` and `k` on both sides of each component's `k · |z_i|`, with NaN, ±∞, ±0.
    #[test]
    fn the_round_off_scan_decides_as_the_largest_component() {
        let values = [
            0.0,
            -0.0,
            1.0,
            -3.0,
            0.5,
            f64::NAN,
            f64::INFINITY,
            -2.5e-310,
        ];
        let ks = [0.0, 4.0 * f64::EPSILON, 1.0, f64::INFINITY, -1.0, f64::NAN];
        let mut decided = [0usize; 2];
        for n in 0..7 {
            for shift in 0..values.len() {
                let z: Vec<f64> = (0..n)
                    .map(|i| values[(i * 3 + shift) % values.len()])
                    .collect();
                for &k in &ks {
                    let scale = round_off_scale(&z);
                    for r in [
                        0.0,
                        1e-16,
                        8.9e-16,
                        8.881784197001252e-16,
                        3.0,
                        f64::INFINITY,
                    ] {
                        for r in [r, r * (1.0 + f64::EPSILON), k * scale] {
                            let want = r <= k * scale;
                            assert_eq!(within_round_off(r, k, &z), want, "{r} {k} {z:?}");
                            decided[usize::from(want)] += 1;
                        }
                    }
                }
            }
        }
        assert!(decided[0] > 100 && decided[1] > 100, "{decided:?}");
    }

    /// `largest_magnitude` (SSE2 lanes on `x86_64`) is the scalar loop's value on every length
    /// to 13 with NaN, ±∞, −0 and ties at every place.
    #[test]
    fn the_largest_magnitude_in_lanes_is_the_scalar_loops() {
        let specials = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -0.0, -7.5, 7.5];
        // Every length to 39: the AVX loop's blocks of sixteen and four, and what is left.
        for n in 0..40 {
            let base: Vec<f64> = (0..n)
                .map(|i| [1.0, -3.0, 0.25, -2.5e-310, 7.5][i % 5])
                .collect();
            let mut cases = vec![base.clone()];
            for k in 0..n {
                for s in specials {
                    let mut v = base.clone();
                    v[k] = s;
                    cases.push(v);
                }
            }
            for v in cases {
                let (got, want) = (largest_magnitude(&v), largest_magnitude_scalar(&v));
                let key = |(m, nan): (f64, bool)| (m.to_bits(), nan);
                assert_eq!(key(got), key(want), "{v:?}");
                assert!(!got.0.is_nan());
                // The NaN flag is whether `v` holds one, wherever it lies.
                assert_eq!(got.1, v.iter().any(|x| x.is_nan()), "{v:?}");
                #[cfg(target_arch = "x86_64")]
                {
                    let sse2 = largest_magnitude_sse2(&v);
                    assert_eq!(key(sse2), key(want), "{v:?}");
                    if std::arch::is_x86_feature_detected!("avx") {
                        // SAFETY: the processor runs AVX.
                        let avx = unsafe { largest_magnitude_avx(&v) };
                        assert_eq!(key(avx), key(want), "{v:?}");
                    }
                }
            }
        }
        assert_eq!(largest_magnitude(&[f64::NAN; 5]), (0.0, true));
        assert_eq!(
            largest_magnitude(&[-1.0, 2.0, f64::NAN, -9.0, 3.0]),
            (9.0, true)
        );
        assert_eq!(largest_magnitude(&[-1.0, 2.0, -9.0, 3.0]), (9.0, false));
    }

    #[test]
    fn the_flat_assembly_and_the_gradient_give_the_bits_of_one_column_at_a_time() {
        fn plain(
            pattern: &CscPattern,
            (jac, da, db, phi): (&[f64], &[f64], &[f64], &[f64]),
            h: &mut [f64],
            grad: &mut [f64],
            col_max: &mut [f64],
        ) -> f64 {
            let (cp, ri, diag) = (pattern.col_ptr(), pattern.row_idx(), pattern.diag_pos());
            let mut largest = 0.0f64;
            for j in 0..cp.len() - 1 {
                let (mut s, mut cmax) = (0.0, 0.0f64);
                for p in cp[j]..cp[j + 1] {
                    let r = ri[p];
                    let mut v = db[r] * jac[p];
                    if p == diag[j] {
                        v = db[r] * jac[p] + da[j];
                    }
                    h[p] = v;
                    s += v * phi[r];
                    cmax = cmax.max(v.abs());
                }
                let nan = (cp[j]..cp[j + 1]).any(|p| h[p].is_nan());
                grad[j] = s;
                largest = largest.max(cmax);
                col_max[j] = if nan { f64::NAN } else { cmax };
            }
            largest
        }
        let mut seed = 11u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for n in [1usize, 2, 5, 8] {
            // Column j holds its diagonal and the rows `(j + k²) % n` for k up to a length
            // that varies with j (from the diagonal alone to the whole column).
            let columns: Vec<Vec<usize>> = (0..n)
                .map(|j| {
                    let mut rows: Vec<usize> =
                        (0..(j * 3) % (n + 1)).map(|k| (j + k * k) % n).collect();
                    rows.push(j);
                    rows.sort_unstable();
                    rows.dedup();
                    rows
                })
                .collect();
            let pattern = CscPattern::from_columns(n, columns).expect("a valid pattern");
            let nnz = pattern.nnz();
            // The witnesses carried from trial to trial (as from iteration to iteration).
            let mut witness = pattern.diag_pos().to_vec();
            for trial in 0..7 {
                let mut jac: Vec<f64> = (0..nnz).map(|_| 4.0 * next() - 2.0).collect();
                let mut da: Vec<f64> = (0..n).map(|_| next() - 1.0).collect();
                let mut db: Vec<f64> = (0..n).map(|_| -next()).collect();
                let phi: Vec<f64> = (0..n).map(|_| 2.0 * next() - 1.0).collect();
                match trial {
                    1 => jac[nnz / 2] = f64::NAN,
                    2 => db[n - 1] = 0.0,
                    3 => jac.iter_mut().for_each(|v| *v *= 1e-20),
                    4 => jac[0] = -0.0,
                    // Signed zeros: `D_b J = −0.0` off the diagonal, `D_a = −0.0` on it.
                    5 => {
                        jac.iter_mut().for_each(|v| *v = 0.0);
                        da[0] = -0.0;
                    }
                    // A zero column (pinned).
                    6 => {
                        let (cp, diag) = (pattern.col_ptr(), pattern.diag_pos());
                        jac[cp[0]..cp[1]].iter_mut().for_each(|v| *v = 0.0);
                        da[0] = 0.0;
                        assert!(diag[0] < cp[1]);
                    }
                    _ => {}
                }
                let (mut h0, mut g0, mut c0) = (vec![0.0; nnz], vec![0.0; n], vec![0.0; n]);
                let (mut h1, mut g1, mut c1) = (vec![0.0; nnz], vec![0.0; n], vec![0.0; n]);
                let want = plain(&pattern, (&jac, &da, &db, &phi), &mut h0, &mut g0, &mut c0);
                let (got, undecided, finite) = assemble_h(
                    &pattern,
                    Some(&jac),
                    &da,
                    &db,
                    None,
                    &mut h1,
                    &mut witness,
                    &mut c1,
                );
                gradient(&pattern, &h1, &phi, &mut g1);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(got.to_bits(), want.to_bits(), "n = {n}, trial {trial}");
                assert_eq!(bits(&h1), bits(&h0), "n = {n}, trial {trial}");
                assert_eq!(bits(&g1), bits(&g0), "n = {n}, trial {trial}");
                assert_eq!(finite, h1.iter().all(|x| x.is_finite()), "trial {trial}");
                // `J` copied and the listed positions alone scaled, every other row's `D_b`
                // exactly 1 (the free rows): the bits of the plain assembly with those `D_b`.
                {
                    let listed = |r: usize| r % 3 != 1;
                    let db1: Vec<f64> = (0..n)
                        .map(|r| if listed(r) { db[r] } else { 1.0 })
                        .collect();
                    let ri = pattern.row_idx();
                    let positions: Vec<usize> = (0..nnz).filter(|&p| listed(ri[p])).collect();
                    let (mut h2, mut g2, mut c2) = (vec![0.0; nnz], vec![0.0; n], vec![0.0; n]);
                    let (mut h3, mut c3) = (vec![7.0; nnz], vec![0.0; n]);
                    let want = plain(&pattern, (&jac, &da, &db1, &phi), &mut h2, &mut g2, &mut c2);
                    let mut w3 = pattern.diag_pos().to_vec();
                    let mut w4 = pattern.diag_pos().to_vec();
                    let (got, undecided, _) = assemble_h(
                        &pattern,
                        Some(&jac),
                        &da,
                        &db1,
                        Some(&positions),
                        &mut h3,
                        &mut w3,
                        &mut c3,
                    );
                    assert_eq!(bits(&h3), bits(&h2), "n = {n}, trial {trial}");
                    assert_eq!(got.to_bits(), want.to_bits(), "n = {n}, trial {trial}");
                    let (mut h4, mut c4) = (vec![0.0; nnz], vec![0.0; n]);
                    let all = assemble_h(
                        &pattern,
                        Some(&jac),
                        &da,
                        &db1,
                        None,
                        &mut h4,
                        &mut w4,
                        &mut c4,
                    );
                    assert_eq!(bits(&h4), bits(&h2), "n = {n}, trial {trial}");
                    assert_eq!((all.0.to_bits(), all.1), (got.to_bits(), undecided));
                    assert_eq!(bits(&c4), bits(&c3));
                    // In place (`J` in `h`, the solver's path), listed positions or all: the
                    // same bits, witnesses and column magnitudes.
                    for listed in [Some(positions.as_slice()), None] {
                        let (mut h5, mut c5) = (jac.clone(), vec![0.0; n]);
                        let mut w5 = pattern.diag_pos().to_vec();
                        let inplace = assemble_h(
                            &pattern, None, &da, &db1, listed, &mut h5, &mut w5, &mut c5,
                        );
                        assert_eq!(bits(&h5), bits(&h2), "n = {n}, trial {trial}");
                        assert_eq!((inplace.0.to_bits(), inplace.1), (got.to_bits(), undecided));
                        assert_eq!((bits(&c5), &w5), (bits(&c3), &w3));
                    }
                }
                // Each column's magnitude decides the pinning test as its largest does (a NaN
                // column is not pinned), and is that largest where the test pins.
                let threshold = ZERO_COLUMN * want;
                let pins = |m: f64| m <= threshold;
                // Each witness is in its column and above the threshold, but where the column
                // has no such entry; without such a column, no column is pinned (and `c1` is
                // not written).
                let cp = pattern.col_ptr();
                let mut none_above = false;
                for (j, &w) in witness.iter().enumerate() {
                    assert!(
                        cp[j] <= w && w < cp[j + 1],
                        "n = {n}, trial {trial}, column {j}"
                    );
                    let above = h1[cp[j]..cp[j + 1]].iter().any(|v| v.abs() > threshold);
                    assert!(!above || h1[w].abs() > threshold, "n = {n}, trial {trial}");
                    none_above |= !above;
                }
                assert_eq!(undecided, none_above, "n = {n}, trial {trial}");
                if trial == 1 {
                    assert!(c0.iter().any(|c| c.is_nan()), "a NaN column");
                }
                if trial == 6 {
                    assert!(undecided, "n = {n}: the zero column has no witness");
                }
                if !undecided {
                    assert!(!c0.iter().any(|&w| pins(w)), "n = {n}, trial {trial}");
                    assert!(c1.iter().all(|&c| c == 0.0), "n = {n}, trial {trial}");
                    continue;
                }
                for (j, (&c, &w)) in c1.iter().zip(&c0).enumerate() {
                    let at = format!("n = {n}, trial {trial}, column {j}");
                    assert_eq!(pins(c), pins(w), "{at}");
                    if pins(w) {
                        assert_eq!(c.to_bits(), w.to_bits(), "{at}");
                    } else if !w.is_nan() {
                        assert!(c > threshold && c <= w, "{at}");
                    }
                }
                if trial == 6 && n > 1 {
                    assert_eq!(c1[0], 0.0, "the zero column is pinned");
                }
            }
        }
    }

    #[test]
    fn the_descent_bounds_decide_as_powf() {
        // Random and edge values of `a`, `nd` near the bounds' margins and the ranges' ends,
        // `p` and `ρ` of the defaults and others: the verdict is the exact test's.
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let specials = [
            0.0,
            -0.0,
            1.0,
            1e-90,
            1e-91,
            1.0 + f64::EPSILON,
            f64::MIN_POSITIVE,
            f64::MAX,
            f64::INFINITY,
            -1.0,
            f64::NAN,
        ];
        let mut cases = 0;
        for &p in &[2.1, 2.0, 3.0, 1.9, 3.5, f64::NAN] {
            for &rho in &[1e-8, 1.0, 1e12, 0.0, -1e-8, f64::INFINITY, f64::NAN] {
                for k in 0..4000 {
                    let nd = if k < specials.len() {
                        specials[k]
                    } else {
                        10f64.powf(-120.0 * next()) * (1.0 + next())
                    };
                    let exact = rho * nd.powf(p);
                    let square = rho * nd * nd;
                    let cube = rho * nd * nd * nd;
                    // `a` at the exact value, an ulp or a tiny factor either side, at the two
                    // bounds and their margins, and random.
                    for a in [
                        exact,
                        f64::from_bits(exact.to_bits().wrapping_add(1)),
                        f64::from_bits(exact.to_bits().wrapping_sub(1)),
                        exact * (1.0 + 1e-13),
                        exact * (1.0 - 1e-13),
                        square,
                        square * (1.0 + 1e-12),
                        square * (1.0 + 2e-12),
                        cube,
                        cube * (1.0 - 1e-12),
                        cube * (1.0 - 2e-12),
                        square * next(),
                        cube * next() * 3.0,
                        specials[k % specials.len()],
                    ] {
                        assert_eq!(
                            at_least_rho_pow(a, rho, nd, p),
                            a >= rho * nd.powf(p),
                            "a = {a:e}, rho = {rho:e}, nd = {nd:e}, p = {p}"
                        );
                        cases += 1;
                    }
                }
            }
        }
        assert!(cases > 1_000_000);
    }

    /// `same_branches` (each kind matched once) agrees with `pair_branch` compared point by
    /// point, for every kind, on both sides of each branch's boundary, at it and with NaNs.
    #[test]
    fn same_branches_agree_with_the_pairs_branches() {
        let inf = f64::INFINITY;
        let bounds = [(-inf, inf), (0.0, inf), (-inf, 1.0), (-1.0, 1.0)];
        let values = [-2.0, -1.0, -0.5, -0.0, 0.0, 0.5, 1.0, 2.0, f64::NAN];
        for &(l, u) in &bounds {
            let kind = classify(l, u);
            for &z in &values {
                for &f in &values {
                    for &(z0, f0) in &[(0.5, 0.25), (-1.0, 1.0), (1.0, -1.0), (0.0, 0.0)] {
                        let want = pair_branch(z, f, l, u, kind) == pair_branch(z0, f0, l, u, kind);
                        let bounded: &[usize] = if kind == BoundKind::Free { &[] } else { &[0] };
                        let got = same_branches(
                            (&[z], &[f]),
                            (&[z0], &[f0]),
                            &[l],
                            &[u],
                            &[kind],
                            bounded,
                        );
                        assert_eq!(got, want, "{kind:?} z {z} f {f} z0 {z0} f0 {f0}");
                    }
                }
            }
        }
        // Vectors of mixed kinds, with the list the workspace makes: the answer of every pair
        // compared (the free ones, left out of the list, included).
        let mut seed = 5u64;
        let mut pick = |k: usize| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as usize % k
        };
        for _ in 0..2000 {
            let n = 1 + pick(9);
            let (mut z, mut f, mut z0, mut f0, mut l, mut u) =
                (vec![], vec![], vec![], vec![], vec![], vec![]);
            for _ in 0..n {
                let (lb, ub) = bounds[pick(bounds.len())];
                l.push(lb);
                u.push(ub);
                z.push(values[pick(values.len())]);
                f.push(values[pick(values.len())]);
                z0.push(values[pick(values.len())]);
                f0.push(values[pick(values.len())]);
            }
            let kinds: Vec<BoundKind> = l.iter().zip(&u).map(|(&a, &b)| classify(a, b)).collect();
            let bounded: Vec<usize> = (0..n).filter(|&i| kinds[i] != BoundKind::Free).collect();
            let want = (0..n).all(|i| {
                pair_branch(z[i], f[i], l[i], u[i], kinds[i])
                    == pair_branch(z0[i], f0[i], l[i], u[i], kinds[i])
            });
            let got = same_branches((&z, &f), (&z0, &f0), &l, &u, &kinds, &bounded);
            assert_eq!(got, want, "{z:?} {f:?} {z0:?} {f0:?} {l:?} {u:?}");
        }
    }

    /// The friction block of an open contact in miniature: `x` free with `F_x = x − 2`, the
    /// friction impulse `p` free with `F_p = σ p` (the friction row at `p_n = 0`), and the slip
    /// rate `σ ≥ 0` with `F_σ = −|p|` (the ellipsoid row at `p_n = 0`). At the start
    /// `(0, 0, 1)` the σ column and the σ row of `H` are zero: σ is undetermined.
    fn open_friction_block() -> FnMcp {
        FnMcp::dense(
            vec![f64::NEG_INFINITY, f64::NEG_INFINITY, 0.0],
            vec![f64::INFINITY; 3],
            |z, f| {
                f[0] = z[0] - 2.0;
                f[1] = z[2] * z[1];
                f[2] = -z[1].abs();
            },
            |z, j| {
                // Column-major 3 × 3.
                j[0] = 1.0;
                j[4] = z[2];
                j[5] = -if z[1] > 0.0 {
                    1.0
                } else if z[1] < 0.0 {
                    -1.0
                } else {
                    0.0
                };
                j[7] = z[1];
            },
        )
        .unwrap_or_else(|e| panic!("valid problem: {e}"))
    }

    /// A smooth MCP with a free component, an inactive lower bound (`z₁ > 0`, `F₁ = 0`) and an
    /// active one (`z₂ = 0`, `F₂ > 0`): from 1e-4 off its solution the first Newton step lands
    /// at a natural residual of ~1e-8, where chord steps take over.
    fn smooth_three() -> FnMcp {
        smooth_three_bounded(0.0)
    }

    /// `smooth_three` with `lower` the last component's lower bound.
    fn smooth_three_bounded(lower: f64) -> FnMcp {
        FnMcp::dense(
            vec![f64::NEG_INFINITY, 0.0, lower],
            vec![f64::INFINITY; 3],
            |z, f| {
                f[0] = z[0] + 0.5 * z[0].sin() + 0.2 * z[1] - 1.0;
                f[1] = z[1] + 0.3 * z[0] * z[0] - 0.8;
                f[2] = 1.0 + z[2] + 0.1 * z[0];
            },
            |z, j| {
                // Column-major 3 × 3.
                j[0] = 1.0 + 0.5 * z[0].cos();
                j[1] = 0.6 * z[0];
                j[2] = 0.1;
                j[3] = 0.2;
                j[4] = 1.0;
                j[8] = 1.0;
            },
        )
        .unwrap_or_else(|e| panic!("valid problem: {e}"))
    }

    /// `F` at the start handed over (`Mcp::known_value`) replaces the solver's first evaluation,
    /// with and without `J` at the start, and the solve returns the same point and summary bit
    /// for bit.
    #[test]
    fn f_at_the_start_handed_over_replaces_the_first_evaluation() {
        let (_, start) = smooth_three_start();
        let inner = smooth_three();
        let mut f = vec![0.0; 3];
        inner.evaluate(&start, &mut f);
        for last_iterated in [true, false] {
            let solve = |known: bool| {
                let z = if known { start.clone() } else { Vec::new() };
                let mcp = KnownAt::new(&inner, z, f.clone());
                let mut solver = NewtonSolver::new(NewtonSettings::default());
                solver.last_iterated = last_iterated;
                let sol = solver.solve(&mcp, &start).unwrap_or_else(|e| panic!("{e}"));
                (sol, mcp.evaluations.get())
            };
            let ((plain, plain_evaluations), (handed, handed_evaluations)) =
                (solve(false), solve(true));
            assert!(plain.summary.iterations >= 1);
            assert_eq!(handed_evaluations + 1, plain_evaluations, "{last_iterated}");
            assert_eq!(handed.z, plain.z);
            assert_eq!(handed.summary.residual, plain.summary.residual);
            assert_eq!(handed.summary.iterations, plain.summary.iterations);
            assert_eq!(handed.summary.f_evals, plain.summary.f_evals);
        }
    }

    /// `smooth_three`'s solution by full Newton steps, and a start 1e-4 away from it.
    fn smooth_three_start() -> (Vec<f64>, Vec<f64>) {
        let exact = NewtonSolver::new(NewtonSettings {
            chord_contraction: None,
            ..NewtonSettings::default()
        })
        .solve(&smooth_three(), &[0.5, 0.5, 0.5])
        .unwrap_or_else(|e| panic!("{e}"))
        .z;
        let start = vec![exact[0] + 1e-4, exact[1] - 1e-4, 1e-4];
        (exact, start)
    }

    #[test]
    fn chord_steps_replace_a_factorisation_and_end_at_round_off() {
        let (exact, start) = smooth_three_start();
        assert!(exact[1] > 0.1 && exact[2].abs() <= 1e-15, "{exact:?}");
        let solve = |chord| {
            let mut solver = NewtonSolver::new(NewtonSettings {
                chord_contraction: chord,
                ..NewtonSettings::default()
            })
            .with_profile();
            let sol = solver
                .solve(&smooth_three(), &start)
                .unwrap_or_else(|e| panic!("{e}"));
            (sol, solver.take_profile())
        };
        let (plain, plain_profile) = solve(None);
        let (chord, chord_profile) = solve(Some(1e-3));
        assert_eq!(plain_profile.chord_steps, 0);
        assert_eq!(plain_profile.lu_factorizations, 2, "{plain_profile:?}");
        // One factorisation, then chord steps, each an iteration and a Newton step.
        assert_eq!(chord_profile.lu_factorizations, 1, "{chord_profile:?}");
        assert!(chord_profile.chord_steps >= 2, "{chord_profile:?}");
        assert_eq!(chord_profile.chord_rejections, 0, "{chord_profile:?}");
        assert_eq!(
            chord.summary.iterations,
            chord_profile.lu_factorizations + chord_profile.chord_steps
        );
        assert_eq!(
            chord.summary.counter(Counter::NewtonSteps),
            Some(chord.summary.iterations)
        );
        // Both at round-off, at the same point within 1e-15.
        for sol in [&plain, &chord] {
            assert_eq!(sol.summary.termination, Termination::Converged);
            assert!(sol.summary.residual <= 1e-15, "{:?}", sol.summary);
        }
        for (a, b) in exact.iter().zip(&chord.z) {
            assert!((a - b).abs() <= 1e-15, "{exact:?} against {:?}", chord.z);
        }
        for (a, b) in plain.z.iter().zip(&chord.z) {
            assert!(
                (a - b).abs() <= 1e-15,
                "{:?} against {:?}",
                plain.z,
                chord.z
            );
        }
    }

    #[test]
    fn a_budget_counts_chord_steps_as_iterations() {
        let (_, start) = smooth_three_start();
        // Without the Josephy–Newton attempt after a failed budgeted run, which would solve it,
        // and without the grace of a converging run (`budget_grace`), which would finish it.
        let mut solver = NewtonSolver::new(NewtonSettings {
            josephy_newton: None,
            budget_grace: None,
            ..NewtonSettings::default()
        });
        let full = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(full.summary.iterations >= 3, "{:?}", full.summary);
        for budget in 1..full.summary.iterations {
            assert!(solver.set_iteration_budget(Some(budget)));
            match solver.solve(&smooth_three(), &start) {
                // Within the tolerance at the limit (without the polishes, as without chord
                // steps).
                Ok(sol) => {
                    assert!(sol.summary.iterations <= budget, "{:?}", sol.summary);
                    assert!(sol.summary.residual <= 1e-10, "{:?}", sol.summary);
                }
                Err(SolveError::NotConverged { best }) => {
                    assert!(best.summary.iterations <= budget, "{:?}", best.summary);
                }
                Err(e) => panic!("{e}"),
            }
        }
        // Within a budget it does not exceed, the unbudgeted point bit for bit.
        assert!(solver.set_iteration_budget(Some(full.summary.iterations)));
        let within = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(within.z, full.z);
        assert_eq!(within.summary.iterations, full.summary.iterations);
    }

    #[test]
    fn a_converging_budgeted_run_finishes_past_its_budget() {
        // `budget_grace`: a budgeted run cut while Newton's rate holds goes on to the
        // unbudgeted run's point, bit for bit (the same iterations); without the grace (and
        // the Josephy–Newton attempt) it fails at its budget.
        let (_, start) = smooth_three_start();
        let settings = NewtonSettings {
            josephy_newton: None,
            ..NewtonSettings::default()
        };
        let mut solver = NewtonSolver::new(settings.clone());
        let full = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        // One iteration: two short of the run's end (the last the polish).
        let budget = 1;
        assert!(full.summary.iterations >= 3, "{:?}", full.summary);
        assert!(solver.set_iteration_budget(Some(budget)));
        let graced = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(graced.z, full.z);
        assert_eq!(graced.summary.iterations, full.summary.iterations);
        let mut strict = NewtonSolver::new(NewtonSettings {
            budget_grace: None,
            ..settings
        });
        assert!(strict.set_iteration_budget(Some(budget)));
        let cut = strict.solve(&smooth_three(), &start);
        assert!(
            matches!(&cut, Err(SolveError::NotConverged { best }) if best.summary.iterations <= budget),
            "{cut:?}"
        );
    }

    #[test]
    fn a_predicted_start_below_the_polish_bound_is_polished_unless_at_round_off() {
        let (exact, _) = smooth_three_start();
        // The solution moved by 2e-14 in `z0`: a natural residual of ≈ 3e-14, below
        // `polish_below · tolerance` (1e-13) and above the round-off floor (4 ulps of ‖z‖∞).
        let start = vec![exact[0] + 2e-14, exact[1], exact[2]];
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        let plain = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(plain.summary.iterations, 0);
        assert_eq!(plain.z, start);
        let r = plain.summary.residual;
        assert!(r > 1e-14 && r <= 1e-13, "{r}");
        // Predicted (`McpSolver::set_start_predicted`): one polish step, to round-off.
        assert!(solver.set_start_predicted(true));
        let polished = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(polished.summary.iterations, 1, "{:?}", polished.summary);
        assert!(polished.summary.residual <= 1e-15, "{:?}", polished.summary);
        assert!((polished.z[0] - exact[0]).abs() <= 1e-15);
        // The solution itself (at round-off) stands.
        let stands = solver
            .solve(&smooth_three(), &exact)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(stands.summary.iterations, 0, "{:?}", stands.summary);
        assert_eq!(stands.z, exact);
        // Unset: as before, bit for bit.
        assert!(solver.set_start_predicted(false));
        let again = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(again.z, plain.z);
        assert_eq!(again.summary.iterations, 0);
    }

    #[test]
    fn a_chord_step_at_the_round_off_floor_ends_the_run_without_the_polish() {
        let (exact, start) = smooth_three_start();
        let solve = |floor, polish_below| {
            let mut solver = NewtonSolver::new(NewtonSettings {
                chord_round_off_floor: floor,
                polish_below,
                ..NewtonSettings::default()
            })
            .with_profile();
            let sol = solver
                .solve(&smooth_three(), &start)
                .unwrap_or_else(|e| panic!("{e}"));
            (sol, solver.take_profile())
        };
        let (polished, polished_profile) = solve(None, 1e-3);
        let (floored, floored_profile) = solve(Some(4.0), 1e-3);
        // Not above `polish_below · tolerance` (here 0): no polish skipped.
        let (unfloored, unfloored_profile) = solve(Some(4.0), 0.0);
        assert_eq!(unfloored_profile.chord_polishes_skipped, 0);
        assert_eq!(unfloored.summary.termination, Termination::Converged);
        assert!(
            unfloored.summary.residual <= 1e-15,
            "{:?}",
            unfloored.summary
        );
        assert_eq!(polished_profile.chord_polishes_skipped, 0);
        assert_eq!(
            floored_profile.chord_polishes_skipped, 1,
            "{floored_profile:?}"
        );
        // The chord's polish not tried: one evaluation fewer (here the polish did not lower the
        // residual, so it was not kept and the iterations are the same), the same
        // factorisations.
        assert_eq!(
            floored.summary.f_evals + 1,
            polished.summary.f_evals,
            "{floored_profile:?} against {polished_profile:?}"
        );
        assert_eq!(floored.summary.iterations, polished.summary.iterations);
        assert_eq!(
            floored_profile.lu_factorizations,
            polished_profile.lu_factorizations
        );
        // The run ends at the floor, 4 units of round-off of ‖z‖∞, and where the polish ends
        // within it.
        let floor = 4.0 * f64::EPSILON * exact.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert_eq!(floored.summary.termination, Termination::Converged);
        assert!(floored.summary.residual <= floor, "{:?}", floored.summary);
        for (a, b) in polished.z.iter().zip(&floored.z) {
            assert!(
                (a - b).abs() <= floor,
                "{:?} against {:?}",
                polished.z,
                floored.z
            );
        }
    }

    /// `smooth_three`'s solution moved by `offset` in its first two components (the third at
    /// its bound): a start one full Newton step solves to round-off when `offset` is small.
    fn near(exact: &[f64], offset: f64) -> Vec<f64> {
        vec![exact[0] + offset, exact[1] - offset, 0.0]
    }

    #[test]
    fn a_chord_step_on_the_last_solves_lu_replaces_the_first_factorisation() {
        let (exact, start) = smooth_three_start();
        let settings = NewtonSettings::default();
        assert_eq!(settings.chord_across_solves, Some(1e-2));
        let mut solver = NewtonSolver::new(settings.clone()).with_profile();
        // From 1e-4 off: a full step to ~1e-8, then chord steps; an LU that needed several
        // steps is not kept, so the next solve factorises (one full step from 1e-9 off).
        let first = solver
            .solve(&smooth_three(), &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(first.summary.iterations >= 2, "{:?}", first.summary);
        solver.take_profile();
        let second = solver
            .solve(&smooth_three(), &near(&exact, 1e-9))
            .unwrap_or_else(|e| panic!("{e}"));
        let p = solver.take_profile();
        assert_eq!((p.kept_lu_steps, p.kept_lu_refusals), (0, 0), "{p:?}");
        assert_eq!(p.lu_factorizations, 1, "{p:?}");
        assert_eq!(second.summary.iterations, 1, "{:?}", second.summary);
        // That run was one step to the round-off floor: its LU is kept, and the next solve
        // of the same problem takes one chord step on it, no factorisation.
        let other = near(&exact, -2e-9);
        let third = solver
            .solve(&smooth_three(), &other)
            .unwrap_or_else(|e| panic!("{e}"));
        let p = solver.take_profile();
        assert_eq!((p.kept_lu_steps, p.kept_lu_refusals), (1, 0), "{p:?}");
        assert_eq!(p.lu_factorizations, 0, "{p:?}");
        assert_eq!(third.summary.iterations, 1, "{p:?}");
        // At round-off, where a solver without the kept LU ends, within 1e-15.
        let fresh = NewtonSolver::new(settings.clone())
            .solve(&smooth_three(), &other)
            .unwrap_or_else(|e| panic!("{e}"));
        for sol in [&first, &second, &third, &fresh] {
            assert_eq!(sol.summary.termination, Termination::Converged);
            assert!(sol.summary.residual <= 1e-15, "{:?}", sol.summary);
        }
        for (a, b) in fresh.z.iter().zip(&third.z) {
            assert!(
                (a - b).abs() <= 1e-15,
                "{:?} against {:?}",
                fresh.z,
                third.z
            );
        }
        // Another pattern in between (a problem of dimension 2): the LU is not kept for it,
        // and the next solve of the first problem factorises first.
        let two = FnMcp::dense(
            vec![f64::NEG_INFINITY; 2],
            vec![f64::INFINITY; 2],
            |z, f| {
                f[0] = 2.0 * z[0] - 1.0;
                f[1] = z[1] + 0.1 * z[0];
            },
            |_, j| {
                j[0] = 2.0;
                j[1] = 0.1;
                j[3] = 1.0;
            },
        )
        .unwrap_or_else(|e| panic!("valid problem: {e}"));
        for mcp in [&two, &smooth_three()] {
            solver
                .solve(mcp, &other[..mcp.dim()])
                .unwrap_or_else(|e| panic!("{e}"));
            let p = solver.take_profile();
            assert_eq!((p.kept_lu_steps, p.kept_lu_refusals), (0, 0), "{p:?}");
            assert!(p.lu_factorizations >= 1, "{p:?}");
        }
        // The same pattern with other bound kinds (the last component free): not kept either.
        solver
            .solve(&smooth_three_bounded(f64::NEG_INFINITY), &other)
            .unwrap_or_else(|e| panic!("{e}"));
        let p = solver.take_profile();
        assert_eq!((p.kept_lu_steps, p.kept_lu_refusals), (0, 0), "{p:?}");
        // Off: every solve factorises first.
        let mut off = NewtonSolver::new(NewtonSettings {
            chord_across_solves: None,
            ..NewtonSettings::default()
        })
        .with_profile();
        for z0 in [near(&exact, 1e-9), other] {
            off.solve(&smooth_three(), &z0)
                .unwrap_or_else(|e| panic!("{e}"));
        }
        let p = off.take_profile();
        assert_eq!((p.kept_lu_steps, p.lu_factorizations), (0, 2), "{p:?}");
    }

    #[test]
    fn a_kept_lu_that_did_not_pay_waits_one_two_four_solves() {
        let mut gate = KeptLuGate::default();
        assert!(gate.take_turn() && gate.take_turn());
        // Tries that did not pay: the next 1, 2, 4 … solves skip it, at most KEPT_LU_MAX_WAIT.
        let mut waits = Vec::new();
        for _ in 0..9 {
            gate.record(false);
            let mut skipped = 0;
            while !gate.take_turn() {
                skipped += 1;
            }
            waits.push(skipped);
        }
        assert_eq!(waits, [1, 2, 4, 8, 16, 32, 64, 64, 64]);
        // A try that paid: the next one is tried at once, and a miss after it waits 1 again.
        gate.record(true);
        assert!(gate.take_turn());
        gate.record(false);
        assert!(!gate.take_turn() && gate.take_turn());
    }

    #[test]
    fn a_refused_try_of_the_kept_lu_makes_the_next_kept_lu_wait() {
        let (exact, _) = smooth_three_start();
        let mut solver = NewtonSolver::new(NewtonSettings::default()).with_profile();
        let mut solve = |z0: &[f64]| {
            let sol = solver
                .solve(&smooth_three(), z0)
                .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(sol.summary.termination, Termination::Converged);
            assert!(sol.summary.residual <= 1e-15, "{:?}", sol.summary);
            let p = solver.take_profile();
            (p.kept_lu_steps, p.kept_lu_refusals, p.lu_factorizations)
        };
        // One full step from 1e-9 off: its LU is kept.
        assert_eq!(solve(&near(&exact, 1e-9)), (0, 0, 1));
        // From 0.2 off (inside the bounds) the chord step on it contracts the residual by less than 1e-2: refused,
        // the run factorises (and, several steps long, keeps no LU).
        let (_, refused, lu) = solve(&near(&exact, -0.2));
        assert_eq!(refused, 1);
        assert!(lu >= 2, "{lu}");
        // One full step again (its LU kept), but the next solve skips the kept LU once.
        assert_eq!(solve(&near(&exact, 1e-9)), (0, 0, 1));
        assert_eq!(solve(&near(&exact, -1e-9)), (0, 0, 1));
        // Then tries it, and it pays: one chord step, no factorisation.
        assert_eq!(solve(&near(&exact, 2e-9)), (1, 0, 0));
    }

    #[test]
    fn a_zero_column_of_h_is_pinned_and_the_newton_step_taken() {
        let sol = NewtonSolver::new(NewtonSettings::default())
            .solve(&open_friction_block(), &[0.0, 0.0, 1.0])
            .unwrap_or_else(|e| panic!("{e}"));
        assert!((sol.z[0] - 2.0).abs() <= 1e-12, "x = {}", sol.z[0]);
        assert!(sol.z[1].abs() <= 1e-12, "p = {}", sol.z[1]);
        // One Newton step solves it.
        assert_eq!(
            sol.summary.counter(Counter::LevenbergMarquardtSteps),
            Some(0)
        );
        assert_eq!(sol.summary.counter(Counter::MinNormSteps), Some(0));
        assert_eq!(sol.summary.counter(Counter::NewtonSteps), Some(1));
        assert_eq!(sol.summary.iterations, 1);
        let unpinned = NewtonSolver::new(NewtonSettings {
            pin_zero_columns: false,
            ..NewtonSettings::default()
        })
        .solve(&open_friction_block(), &[0.0, 0.0, 1.0]);
        let summary = match &unpinned {
            Ok(sol) => &sol.summary,
            Err(SolveError::NotConverged { best }) => &best.summary,
            Err(e) => panic!("{e}"),
        };
        // Without it the LU fails and a safeguard step is taken instead.
        assert!(
            summary
                .counter(Counter::LevenbergMarquardtSteps)
                .unwrap_or(0)
                + summary.counter(Counter::MinNormSteps).unwrap_or(0)
                > 0,
            "{summary:?}"
        );
    }

    /// The full step tried first (`NewtonSettings::fast_full_step`) gives the points, residuals
    /// and iteration counts of the tests first, bit for bit, where it takes steps (counted), on
    /// a pinned `H` (where it is not tried) and from a start far out.
    #[test]
    fn the_full_step_first_gives_the_points_of_the_tests_first() {
        let (_, near) = smooth_three_start();
        let cases: [(FnMcp, Vec<f64>); 4] = [
            (smooth_three(), near),
            (smooth_three(), vec![0.5, 0.5, 0.5]),
            (smooth_three(), vec![3.0, -2.0, 5.0]),
            (open_friction_block(), vec![0.0, 0.0, 1.0]),
        ];
        let mut first_steps = 0;
        for (k, (mcp, start)) in cases.iter().enumerate() {
            let solve = |fast: Option<f64>| {
                let mut solver = NewtonSolver::new(NewtonSettings {
                    fast_full_step: fast,
                    ..NewtonSettings::default()
                })
                .with_profile();
                let sol = solver
                    .solve(mcp, start)
                    .unwrap_or_else(|e| panic!("{k}: {e}"));
                (sol, solver.take_profile())
            };
            let ((tested, tested_profile), (first, profile)) = (solve(None), solve(Some(1e-2)));
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&first.z), bits(&tested.z), "case {k}");
            assert_eq!(
                first.summary.residual.to_bits(),
                tested.summary.residual.to_bits()
            );
            assert_eq!(
                first.summary.iterations, tested.summary.iterations,
                "case {k}"
            );
            assert_eq!(profile.lu_factorizations, tested_profile.lu_factorizations);
            assert_eq!(tested_profile.full_steps_first, 0);
            if k == 3 {
                assert_eq!(
                    profile.full_steps_first, 0,
                    "a pinned H is judged by the tests"
                );
            }
            first_steps += profile.full_steps_first;
        }
        assert!(first_steps >= 3, "{first_steps} full steps first");
    }

    /// Kojima–Josephy from MCPLIB start 3: the plain iteration stops at a point that is not a
    /// solution (the only pair of the MCP suite where it does); the smoothing continuation from
    /// the same start reaches a listed solution.
    #[test]
    fn the_smoothing_continuation_solves_what_the_plain_iteration_does_not() {
        let p = ecp_model::mcp_library::kojima_josephy();
        let (label, z0) = &p.starts[2];
        assert_eq!(label, "mcplib3");
        // Without the non-monotone restart, which solves it too (below), and the Josephy–Newton
        // steps, which solve it first (`josephy::tests`).
        let monotone = NewtonSettings {
            nonmonotone_restart: false,
            josephy_newton: None,
            ..NewtonSettings::default()
        };
        let plain = NewtonSolver::new(NewtonSettings {
            smoothing: None,
            ..monotone.clone()
        })
        .solve(&p.mcp, z0);
        assert!(matches!(plain, Err(SolveError::NotConverged { .. })));
        let sol = NewtonSolver::new(monotone.clone())
            .solve(&p.mcp, z0)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(sol.summary.residual <= 1e-10, "{:e}", sol.summary.residual);
        assert!(sol.summary.counter(Counter::SmoothingStages).unwrap() > 0);
        let d = p.distance_to_solutions(&sol.z, None);
        assert!(d.is_some_and(|d| d < 1e-8), "{d:?}");
        // With an iteration budget the continuation keeps to it: stages of at most 2 iterations
        // stop once 4 are spent (at most 4 − 1 + 2).
        let budget = NewtonSolver::new(NewtonSettings {
            smoothing: Some(SmoothingSettings {
                stage_iterations: 2,
                max_iterations: Some(4),
                ..SmoothingSettings::default()
            }),
            damped_restart: None,
            ..monotone
        })
        .solve(&p.mcp, z0);
        let summary = match budget {
            Ok(sol) => sol.summary,
            Err(SolveError::NotConverged { best }) => best.summary,
            Err(e) => panic!("{e}"),
        };
        let spent = summary.counter(Counter::SmoothingIterations).unwrap();
        assert!((1..=5).contains(&spent), "{spent}");
    }

    /// The same start: the non-monotone restart (full Newton steps under the watchdog) reaches
    /// a listed solution before any continuation runs.
    #[test]
    fn the_nonmonotone_restart_solves_what_the_plain_iteration_does_not() {
        let p = ecp_model::mcp_library::kojima_josephy();
        let z0 = &p.starts[2].1;
        let sol = NewtonSolver::new(NewtonSettings {
            smoothing: None,
            damped_restart: None,
            ..NewtonSettings::default()
        })
        .solve(&p.mcp, z0)
        .unwrap_or_else(|e| panic!("{e}"));
        assert!(sol.summary.residual <= 1e-10, "{:e}", sol.summary.residual);
        assert!(sol.summary.counter(Counter::NonmonotoneSteps).unwrap() > 0);
        let d = p.distance_to_solutions(&sol.z, None);
        assert!(d.is_some_and(|d| d < 1e-8), "{d:?}");
    }

    #[test]
    fn the_final_newton_step_polishes_a_residual_just_below_the_tolerance() {
        // F(x) = x³ + x − 1 (free) from a point whose residual is between 1e-3 of the tolerance
        // and the tolerance: the solve is converged at once, and the final step gains digits.
        let mcp = FnMcp::dense(
            vec![f64::NEG_INFINITY],
            vec![f64::INFINITY],
            |z, f| f[0] = z[0] * z[0] * z[0] + z[0] - 1.0,
            |z, j| j[0] = 3.0 * z[0] * z[0] + 1.0,
        )
        .unwrap_or_else(|e| panic!("valid problem: {e}"));
        let root = 0.682_327_803_828_019_3;
        let start = [root + 2e-11];
        let polished = NewtonSolver::new(NewtonSettings::default())
            .solve(&mcp, &start)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(
            polished.summary.residual <= 1e-15,
            "{:e}",
            polished.summary.residual
        );
        assert_eq!(polished.summary.iterations, 1);
        let plain = NewtonSolver::new(NewtonSettings {
            polish_below: 1.0,
            ..NewtonSettings::default()
        })
        .solve(&mcp, &start)
        .unwrap_or_else(|e| panic!("{e}"));
        assert!(
            plain.summary.residual > 1e-11,
            "{:e}",
            plain.summary.residual
        );
        assert_eq!(plain.summary.iterations, 0);
    }
}
