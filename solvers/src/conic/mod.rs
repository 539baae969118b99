//! Convex subproblems with clarabel (`docs/backends.md#conic`): a backend that uses the structure
//! of the contact step instead of treating it as a generic MCP.
//!
//! Each outer iteration fixes the contact geometry at the current end-of-step iterate (gap,
//! contact frame, the vertices of Conv(F) near G, the ECP) and solves one convex QP over a
//! product of cones with clarabel: normal impulses at the patch vertices `≥ 0` (their centre of
//! pressure is the ECP) and the friction wrench in the ellipsoidal second-order cone
//! `‖(p_t/e_t, p_o/e_o, p_r/e_r)‖ ≤ μ Σ p_n`. In velocity form, per body `b` and contact `c`:
//!
//! ```text
//! min  Σ_b ½ (ν_b − ν_free,b)ᵀ M_b (ν_b − ν_free,b)
//! s.t. g_j/h + W_{n,j}ᵀ(ν_b − ν_b^k) + s_c − μ a_c ≥ 0                 every patch vertex j  (dual λ_j)
//!      (a_c, e_t W_tᵀν_b, e_o W_oᵀν_b, e_r W_rᵀν_b) ∈ SOC(4)                                 (dual (μ p_n, p_f/e))
//! ```
//!
//! `W_{n,j} = [n; (v_j − x) × n]`, `W_t = [t; (a1 − x) × t]`, `W_o`, `W_r = [0; n]`
//! (`docs/model.md#newton-euler`), `s_c` the De Saxcé shift. Its KKT conditions are the discrete
//! Newton–Euler equations with `p_n = Σ λ_j` at the centre of pressure, the ellipsoidal
//! friction cone with maximum dissipation, and complementarity of each `λ_j` with the shifted,
//! linearised gap of its vertex: at a fixed point, exactly `docs/model.md#residual-blocks`.
//!
//! - [`ConicMode::Exact`] (default): the De Saxcé / Acary–Cadoux fixed point. The normal
//!   velocity of every patch vertex is shifted by `μ ‖E u_T‖` of the previous iterate
//!   (Acary, Cadoux, Lemaréchal, Malick, CMAME 2011), which makes a fixed point satisfy exact
//!   Coulomb (maximum-dissipation) friction, and the geometry is re-evaluated at the new
//!   end-of-step configuration (geometric implicitness). The iteration stops when the full step
//!   MCP's natural residual (`docs/model.md#mcp`, computed by the model on the mapped-back vector)
//!   is below [`ConicSettings::tolerance`]. Two devices make it converge to 1e-10 in a few
//!   iterations ([`ConicSettings::polish`], [`ConicSettings::anderson_memory`]): each QP's
//!   solution is polished on its identified active set (loaded vertices' linearised gaps made
//!   exactly zero by a minimum-norm correction of their impulses; each contact's friction from
//!   its exact local maximum-dissipation problem), which removes the interior-point stopping
//!   error, and the outer fixed point is Anderson-accelerated. Neither is a Newton step on the
//!   MCP. Where the fixed point stagnates, a semismooth-Newton polish from its best iterate
//!   (and, when that falls short, from the warm start) finishes the step
//!   ([`ConicSettings::newton_polish`]); its last stage, where all else failed, is a
//!   continuation in the friction coefficient ([`ConicSettings::friction_continuation`]).
//! - [`ConicMode::AnitescuRelaxation`]: one QP without the shift, at the warm start's geometry
//!   (Anitescu, Math. Prog. 2006). Convex and cheap, but it is a different model: a sliding
//!   contact separates with normal velocity `μ ‖E u_T‖`, so sliding bodies drift off the
//!   surface. Its summary is labelled (`solver = "conic-anitescu"`, counter
//!   `"anitescu_relaxation" = 1`) and judged like any other point: by the exact step MCP's
//!   natural residual, so a relaxed step that is not an exact solution comes back as
//!   [`SolveError::NotConverged`] with [`Termination::MaxIterations`] (one QP) and the relaxed
//!   point as its best iterate (a time stepper takes it and records the step as not converged).
//!
//! Bodies with several contacts (the union-of-pieces model, `docs/model.md#union`, where each
//! convex piece of the desk or the T-bar has its own contact): the QP's velocities are unique but
//! its impulses are not — how the load is shared between the pieces and where each piece's
//! centre of pressure lies are left open, by the step model itself — and each piece's centre of
//! pressure becomes its ECP, where its friction acts, in the next QP. Left to the interior-point
//! method, the choice changes from one outer iteration to the next and the fixed point cycles.
//! Those contacts are anchored by a proximal term on their normal wrench
//! ([`ConicSettings::anchor_moment`], [`ConicSettings::anchor_load`]; the derivation is in the
//! `step` module), which vanishes at a fixed point; the polish then corrects their impulses
//! towards the same anchored member, and computes their friction at their centres of pressure.
//!
//! The backend needs the MCP's structural view ([`ecp_model::Mcp::structure`],
//! [`ecp_model::StepStructure`]); a generic MCP is rejected with
//! [`SolveError::InvalidProblem`].
//!
//! The closest-point problem between convex sets is a clarabel QP too: [`closest_point`].
//!
//! References: Anitescu (Math. Prog. 105, 2006); Acary, Cadoux, Lemaréchal, Malick (CMAME 200,
//! 2011); Tasora & Anitescu (CMAME 200, 2011); Kaufman, Sueda, James, Pai (SIGGRAPH Asia 2008).

mod anderson;
pub mod closest_point;
mod dense_qp;
mod mass_factor;
mod min_norm;
mod qp;
mod step;

use std::borrow::Cow;
use std::time::Instant;

use clarabel::solver::DefaultSettings;
pub use clarabel::solver::SolverStatus as ClarabelStatus;
pub use qp::status_code;

use ecp_model::{
    Counter, IterationRecord, Mcp, McpSolver, Solution, SolveError, SolveReport, StepKind,
    Termination, finish_solve_into, natural_residual, validate_start,
};

use crate::newton::{NewtonSettings, NewtonSolver};

/// Which model the conic backend solves (`docs/backends.md#conic`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ConicMode {
    /// The exact step model: De Saxcé / Acary–Cadoux fixed point with geometry re-evaluated at
    /// each iterate, stopped on the full natural residual.
    #[default]
    Exact,
    /// Anitescu's convex relaxation, solved once (single shot) at the warm start's geometry.
    /// NOT the step model of `docs/model.md`: sliding contacts drift off the surface.
    AnitescuRelaxation,
}

/// Settings of the conic backend, with documented defaults.
#[derive(Clone, Debug)]
pub struct ConicSettings {
    /// Stop when the natural residual of the mapped-back MCP vector is at most this.
    /// Default `1e-10`, the Newton backend's default.
    pub tolerance: f64,
    /// Limit on outer (fixed-point) iterations, one clarabel QP each. Default 50.
    pub max_iterations: usize,
    /// Stop (stagnated) when the best residual has not improved by 10 % for this many outer
    /// iterations; an iteration that moves the anchored contacts' loads on in the direction of
    /// the one before is not counted (a load walking under the load anchor while the residual
    /// stays flat, `docs/latency.md`, wip-conicheld). Default 20
    /// (`docs/decisions.md#conic-backend-stopping-and-clarabel-settings`).
    pub stagnation_window: usize,
    /// Tolerance band (m) of the contact patch: vertices of Conv(F) with gap at most this, plus
    /// twice the distance they may approach G within the step, enter the QP
    /// ([`ecp_model::StepStructure::contact`]). Default `1e-3`.
    pub patch_band: f64,
    /// The model solved. Default [`ConicMode::Exact`].
    pub mode: ConicMode,
    /// Polish each QP solution on its identified active set (exact mode only): the normal
    /// impulses of the loaded vertices are corrected so that their linearised gaps vanish, and
    /// each contact's friction impulse is the exact solution of its local maximum-dissipation
    /// problem, in three Gauss–Seidel sweeps. This removes the interior-point method's stopping
    /// error (about 1e-9 in the velocities) from the fixed point; it is not a Newton step on the
    /// MCP. Default `true` (`docs/decisions.md#conic-backend-stopping-and-clarabel-settings`).
    pub polish: bool,
    /// Anderson acceleration of the outer fixed point: number of previous iterates mixed
    /// (Walker & Ni 2011); 0 gives the plain De Saxcé / Acary–Cadoux iteration. Default 4.
    pub anderson_memory: usize,
    /// Weight `ρ_m` of the centre-of-pressure anchor of the contacts of bodies with several
    /// contacts (exact mode; the proximal term described in the module doc), relative to the
    /// body's mean angular mobility `mean_i 1/M_{ωω,ii}`. The union-of-pieces model
    /// (`docs/model.md#union`) needs it: without it the per-piece centres of
    /// pressure and loads, which the model does not determine, jump between outer iterations and
    /// the fixed point cycles. The term vanishes at a fixed point; larger values hold the centres
    /// of pressure more firmly. 0 disables both anchors. Default 1000
    /// (`docs/decisions.md#conic-backend-anchor-weights`).
    pub anchor_moment: f64,
    /// Weight `ρ_n` of the load anchor (the same proximal term on each such contact's normal
    /// impulse), relative to the contact's normal mobility `W_nᵀM⁻¹W_n`. Default `0.1`
    /// (`docs/decisions.md#conic-backend-anchor-weights`).
    pub anchor_load: f64,
    /// Semismooth-Newton iterations allowed after the fixed point when it stagnated or reached
    /// its iteration limit (exact mode only), from the fixed point's best iterate, with the Newton
    /// backend's default safeguards (its smoothing continuation included); when that does not
    /// reach the tolerance, as many again from the warm start (the best iterate can lie on
    /// another active set, `docs/latency.md`, wip-conicheld); both starts are first tried with
    /// the plain and non-monotone iterations alone (`docs/latency.md`, wip-conicslow2); reported
    /// in the counter `"newton_polish"`. Default 50 (`docs/stress.md#after-the-robustness-work`); 0: the conic
    /// iteration alone must converge.
    pub newton_polish: usize,
    /// Hand the fixed point's iterate to the semismooth-Newton finish once its natural residual
    /// is at most this (exact mode, with [`ConicSettings::newton_polish`] > 0), with at most
    /// [`ConicSettings::newton_handoff_iterations`] Newton iterations; when they do not reach the
    /// tolerance the fixed point continues from where it was, and the handoff is not tried again
    /// in that solve. The fixed point identifies the contacts' active sets, loads and slip
    /// directions; the finish removes the last digits, which take the fixed point one or two
    /// more QPs. Default `0` (off): it saves a third of the desk's step time at `1e-4`, but on
    /// the stress suite's corner and trough scenes it made the runs several times slower, for
    /// reasons not yet understood (`docs/latency.md#conic-backend`).
    pub newton_handoff: f64,
    /// Newton iterations of one handoff attempt. Default 4.
    pub newton_handoff_iterations: usize,
    /// Once this many outer iterations in a row have not improved the best residual by 10 %
    /// (the stagnation test's count, [`ConicSettings::stagnation_window`]), try the local
    /// Newton finish (`NewtonFinish::Local`, at most
    /// [`ConicSettings::early_finish_iterations`] iterations) once, from the fixed point's best
    /// iterate and then from the warm start, and end the solve with the first that reaches the
    /// tolerance; when neither does, the fixed point goes on as without it. A fixed point that
    /// stalls this early rarely recovers: on the held-out seeds' union slides it sat at a point
    /// of residual 1e-2 that is not the step's solution for the whole window of 20 QPs
    /// (`docs/latency.md`, wip-conicslow2). Needs [`ConicSettings::newton_polish`] > 0; 0 turns
    /// it off. Default 3.
    pub early_finish_after: usize,
    /// Newton iterations of each early finish ([`ConicSettings::early_finish_after`]). Default 10.
    pub early_finish_iterations: usize,
    /// Once this many outer iterations in a row have moved the anchored loads on in one
    /// direction without improving the best residual by 10 % (a load walk, which the stagnation
    /// test counts as progress, `loads_drifting`), try the same local finish as
    /// [`ConicSettings::early_finish_after`] (once per solve, besides that one), from the warm
    /// start first and then from the best iterate. The load anchor lets a load move only a bounded amount per
    /// QP, so a walk can take the fixed point to its iteration limit with a flat residual
    /// (`061_v_trough` of seed 20261226, steps 53–67: 50 QPs each at a residual of 1.2e-5, then a
    /// Newton finish from the best iterate of 24–102 iterations; the local finish from the warm
    /// start converges in about 5). The warm start first: the walk's best iterate lies on the
    /// anchored member the walk is leaving, where the local finish fails (wip-conic061,
    /// `docs/latency.md`). Needs [`ConicSettings::early_finish_after`] > 0; 0 turns it off.
    /// Default 5.
    pub walk_finish_after: usize,
    /// The Newton finish's last stage, run only after every other stage failed (the local and
    /// the safeguarded finish from both starts): from the fixed point's best iterate, then from
    /// the warm start, the plain iteration and then the Newton backend's continuation in the
    /// friction coefficient ([`NewtonSettings::friction_continuation`], this many arc-length
    /// iterations; `docs/newton.md#a-continuation-in-the-friction-coefficient`), in the
    /// problem's units and then in its scene scales. Where the step's solution lies on another
    /// branch than the warm start's (a body wedged in the crease of a V trough), every other
    /// stage stalls near the warm start's branch (`docs/latency.md`, wip-conic022). Needs
    /// [`ConicSettings::newton_polish`] > 0; `None` turns it off. Default `Some(400)`, the Newton
    /// backend's.
    pub friction_continuation: Option<usize>,
    /// When the fixed point and its local Newton finishes have failed and some QP had an
    /// anchored contact, solve once more from the warm start without the anchors
    /// ([`ConicSettings::anchor_moment`], [`ConicSettings::anchor_load`]: both off), before the
    /// safeguarded finishes (which follow when it fails too); its own finishes start from its
    /// best iterate only (from the warm start they would repeat the anchored pass's) and are
    /// the local one. The load anchor lets a contact's load move only a bounded amount per QP;
    /// where the step's loads are unique but far from the warm start's, the fixed point walks
    /// towards them for its whole iteration limit (a body jammed in the corner of a floor and
    /// a wall, μ = 0.9: the loads go from 0.16 to 97 and 102 N·s in one step,
    /// `s20270327_137_corner_wall` step 33, `docs/stress.md`, branch wip-heldout5: every
    /// finish failed, unanchored 14 QPs; `111_corner_wall` step 161 of the same seed: 50 QPs
    /// and 1 837 Newton iterations, unanchored 12 QPs). Runs only where the local finishes
    /// failed, so a step they or the fixed point solved is unchanged. Needs
    /// [`ConicSettings::newton_polish`] > 0. Counted in `"unanchored_passes"` (present only
    /// when some ran). Default `true`.
    pub unanchored_retry: bool,
    /// Solve each outer QP first with the built-in dense interior-point method
    /// (`conic/dense_qp.rs`: Nesterov–Todd scaling updated as CVXOPT does, Mehrotra's
    /// predictor–corrector, the scaled KKT system by the Cholesky factor of its Schur complement
    /// with iterative refinement, dense LU where that falls short) to the same tolerances, and
    /// with clarabel when it does not get there (counter `"clarabel_fallbacks"`) or the QP has
    /// more than 48 variables. It meets clarabel's 1e-12 on every QP of the desk, A1–A6, T-bar
    /// and D1–D6, D8 runs, in about 12 interior-point iterations instead of 16. Default `true`:
    /// the desk step costs about half the instructions of clarabel's, and on the stress suite
    /// every conic run converges with either method (`docs/latency.md#conic-backend`). `false`
    /// solves every QP with clarabel.
    pub dense_qp: bool,
    /// Inexact outer QPs: the QP of an outer iteration whose input has natural residual `r` is
    /// solved to the tolerances `min(factor · r, 1e-6)` (clarabel's `tol_feas`, `tol_gap_abs`,
    /// `tol_gap_rel`), never tighter than [`ConicSettings::clarabel`]'s, which apply once the
    /// residual is small. The polish makes each QP's answer exact on its identified active set,
    /// and the fixed point is still stopped on the natural residual at
    /// [`ConicSettings::tolerance`], so this changes how fast it gets there, not where. `0`: every
    /// QP to clarabel's tolerances. Default `0`: 1e-3 saves about 15 % of the desk's step but
    /// moves A1's ω by 1.5e-9 (`tests/scenarios.rs` allows 1e-9), 1e-2 makes `a5_drop_tilted`
    /// need a Newton polish (`docs/latency.md#conic-backend`).
    pub qp_tolerance_factor: f64,
    /// Before solving the QP of an outer iteration after the first, polish the previous QP's
    /// answer against the new QP's data when both QPs have the same rows (the same patch
    /// vertices and cones), and take that point when its natural residual is at most
    /// [`ConicSettings::tolerance`]: the polish makes it exact on the previous QP's active set,
    /// which is the new QP's when the geometry moved little (the desk's second QP of a step
    /// confirms the first's active set). Otherwise the QP is solved as without it. Not with
    /// anchored contacts (the module doc of `conic/step.rs`): their loads are not unique and
    /// the member the polish reaches depends on the answer it starts from (the union desk's
    /// velocities moved by 4e-8 with it). Tried once per solve at most. Counted in
    /// `"qp_reuses"`. Default `true`: the desk step without its second QP
    /// (`docs/latency.md#the-second-qp-of-a-step-the-first-qps-answer-polished-again-branch-wip-conicwarm-issue-18`).
    pub reuse_qp: bool,
    /// Start the dense QP method ([`ConicSettings::dense_qp`]) from the answer of the last QP it
    /// solved (in this solve or an earlier one) when the new QP has the same shape (variables
    /// and cones) and no body has two contacts: that answer, its slacks and duals pushed into
    /// the cones' interior by a small margin. A warm run that does not meet the tolerances is
    /// solved again from the standard start. The answer meets the same tolerances either way,
    /// but its last digits depend on the QP solved before, so a step solved again after other
    /// steps may differ from its first solution at the tolerance's level. Default `true`: the
    /// desk's QPs take 5.4 interior-point iterations instead of 10.8
    /// (`docs/latency.md#the-conic-desk-steps-qp-warm-started-branch-wip-conicws-issue-18`).
    pub warm_qp: bool,
    /// At a solve's first outer iteration, before its QP: polish the impulses of the previous
    /// solve's answer (kept by the solver when that answer was a polished point) against the
    /// first QP's data, when the QP has the same rows as the one that answer was polished
    /// against ([`ConicSettings::reuse_qp`]'s test) and every body has one contact (their loads
    /// are then unique, as for [`ConicSettings::warm_qp`]); the start is extrapolated from the
    /// two answers before where both had the same active set. When the sweeps settle within
    /// [`WARM_POLISH_SWEEPS`] on the start's active set (the same loaded vertices and sliding
    /// contacts, each contact loaded), the settled point solves that QP's linearised problem
    /// (as the QP's answer polished would), so it is the outer iterate and the QP is not
    /// solved; otherwise the QP is solved as without it. Counted in `"qp_reuses"`. The step's
    /// answer is the same to the sweeps' tolerance (the reference scenes within 1e-12), its
    /// last digits depend on the solve before. Default `true`: the desk step without a QP,
    /// 42 % faster (`docs/latency.md`, wip-conic).
    pub warm_polish: bool,
    /// Record a per-iteration trace in the summary. Default `false`.
    pub trace: bool,
    /// clarabel's settings, passed through. Default [`default_clarabel_settings`]: clarabel's
    /// defaults with `verbose = false`, the tolerances (`tol_gap_abs`, `tol_gap_rel`, `tol_feas`)
    /// at `1e-12` and `tol_ktratio` at `1e-10`, `max_iter = 100`, and `max_step_fraction = 0.9`
    /// (`docs/decisions.md#conic-backend-stopping-and-clarabel-settings`).
    pub clarabel: DefaultSettings<f64>,
}

/// clarabel settings used by default (see [`ConicSettings::clarabel`]).
pub fn default_clarabel_settings() -> DefaultSettings<f64> {
    DefaultSettings {
        verbose: false,
        tol_gap_abs: 1e-12,
        tol_gap_rel: 1e-12,
        tol_feas: 1e-12,
        tol_ktratio: 1e-10,
        max_iter: 100,
        max_step_fraction: 0.9,
        ..DefaultSettings::default()
    }
}

impl Default for ConicSettings {
    fn default() -> Self {
        ConicSettings {
            tolerance: 1e-10,
            max_iterations: 50,
            stagnation_window: 20,
            patch_band: 1e-3,
            mode: ConicMode::Exact,
            anderson_memory: 4,
            polish: true,
            anchor_moment: 1000.0,
            anchor_load: 0.1,
            newton_polish: 50,
            newton_handoff: 0.0,
            newton_handoff_iterations: 4,
            early_finish_after: 3,
            early_finish_iterations: 10,
            walk_finish_after: 5,
            friction_continuation: Some(400),
            unanchored_retry: true,
            dense_qp: true,
            qp_tolerance_factor: 0.0,
            reuse_qp: true,
            warm_qp: true,
            warm_polish: true,
            trace: false,
            clarabel: default_clarabel_settings(),
        }
    }
}

/// The conic backend (`docs/backends.md#conic`). Implements [`McpSolver`] for MCPs that expose a
/// [`ecp_model::StepStructure`] (the time-step MCP of ecp-formulations).
///
/// Counters in the summary: `"clarabel_iterations"` (interior-point iterations, all QPs),
/// `"clarabel_status"` (last status, [`status_code`]), `"patch_vertices"` (vertex rows of the
/// last QP), `"anitescu_relaxation"` (1 in that mode), `"newton_polish"` (Newton iterations
/// after a fixed point that stagnated or hit its limit, 0 unless enabled and needed),
/// `"newton_handoff"` (Newton iterations of the finish of a fixed point that got within
/// [`ConicSettings::newton_handoff`]), `"dense_qp_iterations"` (interior-point iterations of the
/// dense QP method, all QPs, [`ConicSettings::dense_qp`]), `"clarabel_fallbacks"` (QPs it left
/// to clarabel), `"qp_reuses"` (outer iterations that took the previous QP's answer polished
/// again instead of a QP, [`ConicSettings::reuse_qp`]).
pub struct ConicSolver {
    settings: ConicSettings,
    last_status: Option<ClarabelStatus>,
    last_error: Option<String>,
    /// The dense QP method's workspace, kept between QPs and solves.
    dense: dense_qp::DenseQp,
    /// The polish's storage, kept between outer iterations and solves.
    polish: step::PolishWorkspace,
    /// The outer iteration's storage, kept between outer iterations and solves.
    outer: OuterWorkspace,
}

impl ConicSolver {
    /// A solver with the given settings.
    pub fn new(settings: ConicSettings) -> Self {
        ConicSolver {
            settings,
            last_status: None,
            last_error: None,
            dense: dense_qp::DenseQp::default(),
            polish: step::PolishWorkspace::default(),
            outer: OuterWorkspace::default(),
        }
    }
    /// The settings.
    pub fn settings(&self) -> &ConicSettings {
        &self.settings
    }
    /// Mutable settings.
    pub fn settings_mut(&mut self) -> &mut ConicSettings {
        &mut self.settings
    }
    /// clarabel's status of the last QP solved (passes through the reason of a failure).
    pub fn last_clarabel_status(&self) -> Option<ClarabelStatus> {
        self.last_status
    }
    /// Why the last solve's subproblem failed, when it did (clarabel's status, or why clarabel
    /// could not be called: non-finite data, rejected problem).
    pub fn last_subproblem_error(&self) -> Option<&str> {
        self.last_error.as_deref()
    }

    fn label(&self) -> &'static str {
        match self.settings.mode {
            ConicMode::Exact => "conic",
            ConicMode::AnitescuRelaxation => "conic-anitescu",
        }
    }
}

impl ConicSolver {
    /// The QP settings of an outer iteration whose input has natural residual `residual`
    /// ([`ConicSettings::qp_tolerance_factor`]).
    fn qp_settings(settings: &ConicSettings, residual: f64) -> Cow<'_, DefaultSettings<f64>> {
        let k = &settings.clarabel;
        let factor = settings.qp_tolerance_factor;
        let loose = (factor * residual).min(1e-6);
        if factor <= 0.0 || !loose.is_finite() || loose <= k.tol_feas {
            return Cow::Borrowed(k);
        }
        let mut s = k.clone();
        s.tol_feas = loose;
        s.tol_gap_abs = loose.max(k.tol_gap_abs);
        s.tol_gap_rel = loose.max(k.tol_gap_rel);
        Cow::Owned(s)
    }

    /// The semismooth-Newton finish (`finish`) from `z` with at most `max_iterations`
    /// iterations per run: its solution or best point (`None` when Newton refuses the
    /// problem); its evaluations are added to `run`, its iterations to the handoff's count or
    /// the polish's.
    fn newton_finish(
        &self,
        mcp: &dyn Mcp,
        z: &[f64],
        max_iterations: usize,
        finish: NewtonFinish,
        run: &mut Run,
    ) -> Option<Solution> {
        let defaults = NewtonSettings::default();
        let handoff = finish == NewtonFinish::Handoff;
        let safeguarded = finish == NewtonFinish::Safeguarded;
        let continued = finish == NewtonFinish::Continued;
        let mut newton = NewtonSolver::new(NewtonSettings {
            tolerance: self.settings.tolerance,
            max_iterations,
            // Judged by the caller in the problem's own units, so solved in them; the last
            // stage in the scene scales too when that fails (its point judged in the problem's
            // units all the same): `s20270109_087_v_trough` step 140's continuation converges
            // only there (`docs/latency.md`, wip-conic022).
            scene_scales: continued,
            // The polish as measured with the conic backend (chord steps are Newton's desk lever).
            chord_contraction: None,
            // A failed polish falls back on the fixed point's own answer: no last restart.
            complementary_restart_from_best: None,
            // The last stage's one attempt after the plain iteration.
            friction_continuation: if continued {
                self.settings.friction_continuation
            } else {
                None
            },
            // Measured without it (wip-conicslow2): a failed local finish hands back to the
            // fixed point, not to Josephy–Newton steps.
            josephy_newton: None,
            // The handoff and the local finish are local: the plain iteration only. Its
            // safeguards for hard steps (the smoothing continuation, the damped restart) would
            // run on every step whose few local iterations fall short, at many times a QP's
            // cost; the fixed point, or the next start, goes on instead.
            smoothing: if safeguarded {
                defaults.smoothing
            } else {
                None
            },
            damped_restart: if safeguarded {
                defaults.damped_restart
            } else {
                None
            },
            // The local finish is exactly the first attempts of the safeguarded one (the plain
            // and the non-monotone iteration, the early complementary restart), so where it
            // converges the safeguarded finish from the same start returns the same point.
            // Without the continuations the complementary restart runs after the non-monotone
            // iteration, where the safeguarded finish runs its early one (before the first
            // continuation): at the early one's distance.
            // The last stage runs after the safeguarded finish from the same starts: of its
            // attempts only the continuation in the friction coefficient is new.
            complementary_restart: match finish {
                NewtonFinish::Local => defaults.early_complementary_restart,
                NewtonFinish::Continued => None,
                _ => defaults.complementary_restart,
            },
            early_complementary_restart: if continued {
                None
            } else {
                defaults.early_complementary_restart
            },
            nonmonotone_restart: !continued && defaults.nonmonotone_restart,
            // A failed finish hands back to the fixed point (kept as measured: wip-tip070).
            structure_reseed: false,
            ..defaults
        });
        let sol = match newton.solve(mcp, z) {
            Ok(sol) => sol,
            Err(SolveError::NotConverged { best }) => *best,
            Err(SolveError::InvalidProblem(_)) => return None,
        };
        if handoff {
            run.newton_handoff += sol.summary.iterations;
        } else {
            run.newton_polish += sol.summary.iterations;
        }
        run.f_evals += sol.summary.f_evals;
        Some(sol)
    }
}

/// Which semismooth-Newton finish [`ConicSolver::newton_finish`] runs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum NewtonFinish {
    /// [`ConicSettings::newton_handoff`]: the plain iteration with its restarts from the start,
    /// no smoothing continuation, no damped restart.
    Handoff,
    /// The first attempts of the Newton backend's solve: the plain iteration (with its
    /// minimum-norm restart), the non-monotone plain iteration and, near a solution, the early
    /// complementary restart; where they converge, the same point as
    /// [`NewtonFinish::Safeguarded`] from the same start, at a fraction of the cost where they
    /// do not (a safeguarded finish that fails spends 200–600 iterations).
    Local,
    /// The Newton backend's default safeguards (its smoothing continuation and damped and
    /// complementary restarts included).
    Safeguarded,
    /// The last stage ([`ConicSettings::friction_continuation`]): the plain iteration, then the
    /// continuation in the friction coefficient; the other attempts off (the safeguarded finish
    /// ran them from the same starts), in the problem's units and then in its scene scales.
    Continued,
}

/// Book-keeping of one solve.
struct Run {
    started: Instant,
    f_evals: usize,
    clarabel_iterations: usize,
    dense_qp_iterations: usize,
    clarabel_fallbacks: usize,
    status: Option<ClarabelStatus>,
    patch_vertices: usize,
    newton_polish: usize,
    newton_handoff: usize,
    qp_reuses: usize,
    /// Unanchored passes run ([`ConicSettings::unanchored_retry`]).
    unanchored_passes: usize,
    trace: Vec<IterationRecord>,
}

impl McpSolver for ConicSolver {
    fn name(&self) -> &str {
        self.label()
    }

    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let mut out = Solution::default();
        self.solve_into(mcp, z0, &mut out)?;
        Ok(out)
    }

    /// The solve into `out`'s storage: with the outer loop's and the polish's storage kept in
    /// the solver, a warm desk solve allocates nothing here (`tests/step_allocations.rs`; what
    /// is left is the formulation's, `docs/latency.md`). The same point and summary as
    /// [`McpSolver::solve`], which calls it.
    fn solve_into(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        out: &mut Solution,
    ) -> Result<(), SolveError> {
        let mut anchored = false;
        self.solve_pass(mcp, z0, out, Pass::Anchored, &mut anchored)
    }
}

/// Which pass of a solve [`ConicSolver::solve_pass`] runs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Pass {
    /// The solve: anchors as the settings say, finishes from the best iterate and the warm
    /// start.
    Anchored,
    /// [`ConicSettings::unanchored_retry`]: no anchor, finishes from the best iterate only, the
    /// last one the local finish.
    Unanchored,
}

impl ConicSolver {
    /// The unanchored pass from the warm start ([`ConicSettings::unanchored_retry`]): its
    /// solution or best point (`None` when a subproblem or the problem refused it), its work
    /// added to `run`'s counters.
    #[cold]
    #[inline(never)]
    fn unanchored_pass(&mut self, mcp: &dyn Mcp, z0: &[f64], run: &mut Run) -> Option<Solution> {
        let mut out = Solution::default();
        let mut anchored = false;
        let sol = match self.solve_pass(mcp, z0, &mut out, Pass::Unanchored, &mut anchored) {
            Ok(()) => out,
            Err(SolveError::NotConverged { best }) => *best,
            Err(_) => return None,
        };
        let count = |c| sol.summary.counters.get(c).unwrap_or(0);
        run.clarabel_iterations += count(Counter::ClarabelIterations);
        run.dense_qp_iterations += count(Counter::Custom("dense_qp_iterations"));
        run.clarabel_fallbacks += count(Counter::Custom("clarabel_fallbacks"));
        run.newton_polish += count(Counter::NewtonPolish);
        run.newton_handoff += count(Counter::NewtonHandoff);
        run.qp_reuses += count(Counter::Custom("qp_reuses"));
        run.f_evals += sol.summary.f_evals;
        run.unanchored_passes += 1;
        Some(sol)
    }

    /// One pass of the solve (`pass`): the outer fixed point and its Newton finishes into
    /// `out`; `anchored` is set when some QP had an anchored contact.
    fn solve_pass(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        out: &mut Solution,
        pass: Pass,
        anchored_seen: &mut bool,
    ) -> Result<(), SolveError> {
        let unanchored = pass == Pass::Unanchored;
        validate_start(mcp, z0)?;
        self.last_status = None;
        self.last_error = None;
        let Some(structure) = mcp.structure() else {
            return Err(SolveError::InvalidProblem(
                "the conic backend needs the structural view of a contact step \
                 (Mcp::structure, docs/backends.md); this MCP has none: use the Newton or PATH \
                 backend, or pass Simulation::structured_mcp()"
                    .into(),
            ));
        };
        let n = mcp.dim();
        let (lower, upper) = (mcp.lower(), mcp.upper());
        let nb = structure.num_bodies();
        let nc = structure.num_contacts();
        // The mass matrix and the free-motion velocity are those of the step's Newton–Euler
        // rows at a trial end-of-step point (the end-of-step orientation and the gyroscopic
        // impulse at the trial ω, `ecp_model::BodyDynamics`): evaluated at the point the
        // geometry is evaluated at, so the fixed point converges to the step's solution.
        let dynamics = |z: &[f64], out: &mut Vec<ecp_model::BodyDynamics>| {
            out.clear();
            out.extend((0..nb).map(|b| structure.body(b, z)));
        };
        // Taken for the solve and put back at its end (an early return only loses the storage).
        let mut ws = std::mem::take(&mut self.outer);
        let finite = |bodies: &[ecp_model::BodyDynamics]| {
            bodies.iter().all(|b| {
                b.free_velocity
                    .iter()
                    .chain(b.mass.iter().flatten())
                    .all(|v| v.is_finite())
            })
        };
        dynamics(z0, &mut ws.bodies);
        if !finite(&ws.bodies) {
            return Err(SolveError::InvalidProblem(
                "the step's mass matrix or free-motion velocity is not finite".into(),
            ));
        }
        let exact = self.settings.mode == ConicMode::Exact;
        let max_outer = if exact {
            self.settings.max_iterations.max(1)
        } else {
            1
        };
        let mut run = Run {
            started: Instant::now(),
            f_evals: 0,
            clarabel_iterations: 0,
            dense_qp_iterations: 0,
            clarabel_fallbacks: 0,
            status: None,
            patch_vertices: 0,
            newton_polish: 0,
            newton_handoff: 0,
            qp_reuses: 0,
            unanchored_passes: 0,
            trace: Vec::new(),
        };
        let OuterWorkspace {
            f,
            z,
            z_new,
            best_z,
            z_in,
            warm_loads,
            previous_loads,
            geometry,
            new_geometry,
            bodies,
            x,
            g,
            next,
            x_flat,
            g_flat,
            mixed,
            seed,
            qp: qp_storage,
            result,
            layout,
            new_layout,
            anderson,
            point,
            anchored,
            per_body,
            sides,
            drift,
            last_contacts,
            last_layout,
            have_last,
            prev_contacts,
            have_prev,
            start_contacts,
        } = &mut ws;
        zeroed(f, n);
        z.clear();
        z.extend_from_slice(z0);
        mcp.evaluate(z, f);
        run.f_evals += 1;
        // Whether `f` holds `F(z)` (for the summary's judgement without evaluating again).
        let mut f_at_z = true;
        let mut residual = natural_residual(z, f, lower, upper);
        best_z.clone_from(z);
        let mut best_residual = residual;
        let mut since_improvement = 0usize;
        // Outer iterations in a row that did not improve but walked the anchored loads on
        // (`loads_drifting`), for `ConicSettings::walk_finish_after`.
        let mut walk = 0usize;
        let mut stall_reference = residual;
        let mut termination = Termination::MaxIterations;
        let mut iterations = 0;
        zeroed(z_new, n);
        let h = structure.step_length();
        // The fixed-point state: velocities, De Saxcé shifts and ECPs (the ECPs scaled by 1/h to
        // velocity units), in `x` once `have_state`. `z_in` is the full vector the geometry is
        // evaluated at.
        z_in.clone_from(z);
        let mut have_state = false;
        anderson.restart(if exact {
            self.settings.anderson_memory
        } else {
            0
        });
        drift.iteration = None;
        // Whether `previous_loads` holds the previous outer iterate's loads (else the first QP's
        // anchor is centred on `warm_loads`).
        let mut have_loads = false;
        let mut handoff_tried = false;
        let mut early_tried = false;
        let mut walk_tried = false;
        // Whether a QP's polish of this solve ran to its cap unsettled (`StepQp::extract_into`).
        let mut polish_unsettled = false;
        // Whether `result` and `layout` hold the previous QP's answer and shape (this solve's).
        let mut have_answer = false;
        // One reuse per solve at most: where the previous answer's active set is not the new
        // QP's, the trial's polish runs all its sweeps (the stress suite's troughs: 3.5× the
        // wall time when every outer iteration tried it).
        let mut reuse_tried = false;
        // Whether the solve ends on a polished point (`point`, polished against `qp_storage`'s
        // QP): its impulses start the next solve's first polish (`ConicSettings::warm_polish`).
        let mut answer_polished = false;
        // The warm start's normal impulse of every contact (empty when the structure does not
        // say).
        warm_loads.clear();
        if residual <= WARM_LOADS_RESIDUAL {
            for c in 0..nc {
                match structure.normal_impulse(c, z0) {
                    Some(l) => warm_loads.push(l),
                    None => {
                        warm_loads.clear();
                        break;
                    }
                }
            }
        }
        // The stopping test comes before the first QP: a warm start that already solves the step
        // (a body at rest, free flight) costs no QP.
        let outer = if exact && residual <= self.settings.tolerance {
            termination = Termination::Converged;
            0
        } else {
            max_outer
        };
        for it in 0..outer {
            contacts_into(structure, z_in, self.settings.patch_band, geometry);
            if !have_state {
                structure.velocities_into(z_in, &mut x.nu);
                x.shifts.clear();
                x.shifts.extend(geometry.iter().map(|g| {
                    if exact {
                        step::de_saxce_shift_with(g, &x.nu, sides)
                    } else {
                        0.0
                    }
                }));
                x.ecps.clear();
                x.ecps.extend(geometry.iter().map(|g| g.ecp));
            }
            for (g, e) in geometry.iter_mut().zip(&x.ecps) {
                g.ecp = *e;
            }
            // The load anchor's centre: the previous outer iterate's loads, and at the first QP
            // the warm start's (the previous step's answer). Without them the first QP's anchor
            // pulls every load towards 0, and on a statically indeterminate contact (a box
            // wedged in a V trough, held by friction) it returns another member of the solution
            // set, 5e-3 N·s away, which the fixed point then walks back from in about ten QPs
            // (`126_v_trough`, `docs/latency.md#conic-backend`).
            let loads: &[f64] = if have_loads {
                previous_loads
            } else {
                warm_loads
            };
            let anchor = (exact && !unanchored).then_some(step::Anchor {
                moment: self.settings.anchor_moment,
                load: self.settings.anchor_load,
                previous_loads: (!loads.is_empty()).then_some(loads),
            });
            dynamics(z_in, bodies);
            if !finite(bodies) {
                self.last_error = Some(format!(
                    "the mass matrix or free-motion velocity of outer iteration {it} is not finite"
                ));
                termination = Termination::SubproblemFailed;
                break;
            }
            let sub = step::build(
                structure,
                bodies,
                &x.nu,
                geometry,
                &x.shifts,
                anchor,
                std::mem::take(qp_storage),
            );
            run.patch_vertices = sub.patch_vertices;
            *anchored_seen |= sub.anchored();
            // The previous QP's answer polished against this QP's data: when it solves the step,
            // this iteration needs no QP (`ConicSettings::reuse_qp`).
            let polish = exact && self.settings.polish;
            let mut reused = None;
            // The first iteration's QP replaced by the previous solve's impulses polished
            // against its data (`ConicSettings::warm_polish`): a settled polish is that QP's
            // answer polished, to the sweeps' tolerance, whatever it started from, where every
            // body has one contact (its loads unique). Its point is the iterate even when it
            // does not solve the step (the desk's first iterate never does: the geometry moves).
            if it == 0
                && *have_last
                && polish
                && self.settings.warm_polish
                && !sub.anchored()
                && step::one_contact_per_body(geometry)
            {
                sub.layout_into(new_layout);
                if new_layout == last_layout
                    && {
                        extrapolated_start(
                            last_contacts,
                            *have_prev,
                            prev_contacts,
                            start_contacts,
                        );
                        true
                    }
                    && sub.extract_into(
                        step::PolishStart::Impulses(start_contacts),
                        bodies,
                        true,
                        false,
                        WARM_POLISH_SWEEPS,
                        &mut self.polish,
                        point,
                    )
                    && same_active_set(last_contacts, &point.contacts)
                {
                    structure.assemble(point, z_new);
                    mcp.evaluate(z_new, f);
                    f_at_z = false;
                    run.f_evals += 1;
                    reused = Some(natural_residual(z_new, f, lower, upper));
                    // The answer the next iteration's reuse compares against and starts from.
                    std::mem::swap(layout, new_layout);
                    have_answer = true;
                }
            }
            if reused.is_none()
                && have_answer
                && !reuse_tried
                && polish
                && self.settings.reuse_qp
                && !sub.anchored()
            {
                sub.layout_into(new_layout);
                if new_layout == layout {
                    reuse_tried = true;
                    // From the previous QP's polished impulses (`seed`'s: the last iterate, that
                    // QP's point): the sweeps start settled and only follow the data's change
                    // (the desk: 12 sweeps from that QP's raw duals, `docs/latency.md`).
                    sub.extract_into(
                        step::PolishStart::Impulses(&seed.contacts),
                        bodies,
                        true,
                        false,
                        step::MAX_SWEEPS,
                        &mut self.polish,
                        point,
                    );
                    structure.assemble(point, z_new);
                    mcp.evaluate(z_new, f);
                    f_at_z = false;
                    run.f_evals += 1;
                    let reused_residual = natural_residual(z_new, f, lower, upper);
                    if reused_residual <= self.settings.tolerance {
                        reused = Some(reused_residual);
                    }
                }
            }
            // The new iterate: the reused answer (it solves the step, so the convergence test
            // below ends the solve) or this iteration's QP's.
            let new_residual = match reused {
                Some(answer) => {
                    run.qp_reuses += 1;
                    *qp_storage = sub;
                    iterations = it + 1;
                    answer
                }
                None => {
                    let qp_settings =
                        Self::qp_settings(&self.settings, if exact { residual } else { 0.0 });
                    // Not warm where a body has several contacts: their loads need not be
                    // unique, and a warm start keeps the last QP's member of the solution set
                    // where the standard start finds another (`tbar_gripper`'s pad and ground
                    // loads moved by 1.6e-2, `docs/latency.md`).
                    let warm = self.settings.warm_qp && step::one_contact_per_body(geometry);
                    let from_dense = self.settings.dense_qp
                        && self.dense.solve_into(&sub.qp, &qp_settings, warm, result);
                    if self.settings.dense_qp && !from_dense {
                        run.clarabel_fallbacks += 1;
                    }
                    if !from_dense {
                        match sub.qp.solve(&qp_settings) {
                            Ok(r) => *result = r,
                            Err(msg) => {
                                self.last_error = Some(msg);
                                termination = Termination::SubproblemFailed;
                                break;
                            }
                        }
                    }
                    if from_dense {
                        run.dense_qp_iterations += result.iterations as usize;
                    } else {
                        run.clarabel_iterations += result.iterations as usize;
                    }
                    run.status = Some(result.status);
                    self.last_status = Some(result.status);
                    iterations = it + 1;
                    if !qp::usable(result.status) {
                        self.last_error = Some(format!(
                            "clarabel returned {:?} on the QP of outer iteration {it}",
                            result.status
                        ));
                        termination = Termination::SubproblemFailed;
                        break;
                    }
                    // Only where every body has one contact (its loads unique): elsewhere the
                    // fixed point picks a member of the solution set, and a finish would pick
                    // another (the stress suite's troughs and corners took more QPs, measured).
                    let one_contact = step::one_contact_per_body(geometry);
                    // Where an unsettled polish is finished by Newton at once (the early finish
                    // below, not yet tried), its sweeps stop once they circle: the rest of the
                    // cap would not settle them (`134_union_slide` of seed 20270206,
                    // `docs/latency.md`, wip-conicrob).
                    let stop_circling = one_contact
                        && !early_tried
                        && self.settings.early_finish_after > 0
                        && self.settings.newton_polish > 0;
                    let settled = sub.extract_into(
                        step::PolishStart::Qp(result),
                        bodies,
                        polish,
                        stop_circling,
                        step::MAX_SWEEPS,
                        &mut self.polish,
                        point,
                    );
                    polish_unsettled |= !settled && one_contact;
                    // The layout a later reuse compares against, only while one can be tried.
                    if !reuse_tried && polish && self.settings.reuse_qp {
                        sub.layout_into(layout);
                    }
                    have_answer = true;
                    *qp_storage = sub;
                    structure.assemble(point, z_new);
                    mcp.evaluate(z_new, f);
                    run.f_evals += 1;
                    natural_residual(z_new, f, lower, upper)
                }
            };
            if self.settings.trace {
                run.trace.push(IterationRecord {
                    iteration: it,
                    residual,
                    merit: residual,
                    step: StepKind::Conic,
                    step_length: 1.0,
                    direction_norm: max_change(z_new, z),
                });
            }
            std::mem::swap(z, z_new);
            f_at_z = true;
            let previous_residual = residual;
            residual = new_residual;
            if residual.is_finite() && (residual < best_residual || !best_residual.is_finite()) {
                best_residual = residual;
                best_z.copy_from_slice(z);
            }
            if !exact {
                // The relaxation is one QP; the summary judges its point like any other.
                termination = Termination::Converged;
                break;
            }
            if residual <= self.settings.tolerance {
                termination = Termination::Converged;
                answer_polished = polish;
                break;
            }
            if !handoff_tried
                && self.settings.newton_polish > 0
                && residual <= self.settings.newton_handoff
            {
                handoff_tried = true;
                let budget = self
                    .settings
                    .newton_handoff_iterations
                    .min(self.settings.newton_polish);
                if let Some(sol) =
                    self.newton_finish(mcp, z, budget, NewtonFinish::Handoff, &mut run)
                    && sol.summary.residual <= self.settings.tolerance
                {
                    z.copy_from_slice(&sol.z);
                    f_at_z = false;
                    best_z.copy_from_slice(&sol.z);
                    best_residual = sol.summary.residual;
                    termination = Termination::Converged;
                    break;
                }
            }
            if best_residual < 0.9 * stall_reference {
                stall_reference = best_residual;
                since_improvement = 0;
                walk = 0;
            } else if have_loads && {
                // The same flags as the anchors' below (the same `geometry`), into kept storage.
                step::anchored_contacts_into(geometry, nb, per_body, anchored);
                loads_drifting(anchored, point, previous_loads, drift, it)
            } {
                walk += 1;
            } else {
                walk = 0;
                since_improvement += 1;
                if since_improvement >= self.settings.stagnation_window {
                    termination = Termination::Stagnated;
                    break;
                }
            }
            // The early finish (`ConicSettings::early_finish_after`): from the best iterate, then
            // from the warm start, once per solve; after a load walk
            // (`ConicSettings::walk_finish_after`) the other way round, also once per solve. Both
            // leave the fixed point's iterates as they were when they fall short, so a stall
            // after a walk is finished as without the walk's attempt.
            let stall_due = !early_tried && since_improvement >= self.settings.early_finish_after;
            // A polish that did not settle: its point is the sweeps' cycle, off the step's
            // solution, and the fixed point's next QPs circle too (`134_union_slide` of seed
            // 20270206: a table spinning about a point near its centre of pressure, the sweeps
            // turning with period 5; `docs/latency.md`, wip-conic134). The finish then comes at
            // once, from the warm start first.
            let unsettled_due = !early_tried && polish_unsettled;
            let walk_due = !walk_tried
                && self.settings.walk_finish_after > 0
                && walk >= self.settings.walk_finish_after;
            if self.settings.early_finish_after > 0
                && self.settings.newton_polish > 0
                && (stall_due || unsettled_due || walk_due)
            {
                let walk_due = !stall_due && !unsettled_due;
                if walk_due {
                    walk_tried = true;
                } else {
                    early_tried = true;
                }
                let warm_first = walk_due || (unsettled_due && !stall_due);
                let budget = self
                    .settings
                    .early_finish_iterations
                    .min(self.settings.newton_polish);
                // The unanchored pass's finishes from the warm start would be the anchored
                // pass's again.
                let from_warm = !unanchored && z0 != best_z.as_slice();
                let starts = if warm_first {
                    [from_warm.then_some(z0), Some(&best_z[..])]
                } else {
                    [Some(&best_z[..]), from_warm.then_some(z0)]
                };
                for start in starts.into_iter().flatten() {
                    if let Some(sol) =
                        self.newton_finish(mcp, start, budget, NewtonFinish::Local, &mut run)
                        && sol.summary.residual <= self.settings.tolerance
                    {
                        z.copy_from_slice(&sol.z);
                        f_at_z = false;
                        best_residual = sol.summary.residual;
                        termination = Termination::Converged;
                        break;
                    }
                }
                if termination == Termination::Converged {
                    best_z.copy_from_slice(z);
                    break;
                }
            }
            // G(x): the new velocities, the plain De Saxcé update μσ and the new ECPs. An
            // anchored contact left without load keeps its ECP: the closest feature of a
            // separated piece (a corner) would move its friction there, and the contact would
            // cycle between loaded and unloaded.
            contacts_into(structure, z, self.settings.patch_band, new_geometry);
            let anchors =
                !unanchored && self.settings.anchor_moment > 0.0 && self.settings.anchor_load > 0.0;
            if anchors {
                step::anchored_contacts_into(geometry, nb, per_body, anchored);
            }
            g.nu.clone_from(&point.velocities);
            g.shifts.clear();
            g.shifts.extend(
                new_geometry.iter().enumerate().map(|(c, geo)| {
                    geo.friction.mu * point.contacts.get(c).map_or(0.0, |p| p.sigma)
                }),
            );
            g.ecps.clear();
            g.ecps
                .extend(new_geometry.iter().enumerate().map(|(c, geo)| {
                    let unloaded = point
                        .contacts
                        .get(c)
                        .is_none_or(|p| p.vertex_impulses.iter().all(|(_, l)| *l <= 0.0));
                    let is_anchored = anchors && anchored[c];
                    match x.ecps.get(c) {
                        Some(e) if is_anchored && unloaded => *e,
                        _ => geo.ecp,
                    }
                }));
            if residual.is_nan() || residual > 10.0 * previous_residual {
                // The mixing made things worse: restart it from the plain update.
                anderson.reset();
            }
            x.flatten_into(h, x_flat);
            g.flatten_into(h, g_flat);
            anderson.next_into(x_flat, g_flat, mixed);
            next.unflatten_from(mixed, g, h);
            // The next QP's load anchor: this iterate's loads.
            previous_loads.clear();
            previous_loads.extend(
                point
                    .contacts
                    .iter()
                    .map(|p| p.vertex_impulses.iter().map(|(_, l)| l).sum::<f64>()),
            );
            have_loads = !point.contacts.is_empty();
            seed.velocities.clone_from(&next.nu);
            // Swapped, not moved: `point` keeps the old seed's vectors to refill.
            std::mem::swap(&mut seed.contacts, &mut point.contacts);
            structure.assemble(seed, z_in);
            std::mem::swap(x, next);
            have_state = true;
        }
        // The next solve's start (`ConicSettings::warm_polish`): swapped, not copied, so that
        // `point` refills the old start's vectors. A solve that took no outer iteration (its
        // warm start solved the step) leaves the start as it was.
        if answer_polished {
            qp_storage.layout_into(new_layout);
            *have_prev = *have_last && new_layout == last_layout;
            std::mem::swap(prev_contacts, last_contacts);
            std::mem::swap(last_contacts, &mut point.contacts);
            std::mem::swap(last_layout, new_layout);
            *have_last = true;
        } else if iterations > 0 {
            *have_last = false;
            *have_prev = false;
        }
        if exact {
            // Return the best iterate; a later iterate may have been worse.
            if z.iter()
                .zip(best_z.iter())
                .any(|(a, b)| a.to_bits() != b.to_bits())
            {
                z.copy_from_slice(best_z);
                f_at_z = false;
            }
            // Only a fixed point that stagnated or ran out of iterations is finished by Newton;
            // a failed subproblem is reported as such. From the best iterate, and when that
            // falls short from the warm start: the fixed point's best iterate can lie on another
            // active set than the step's solution, where Newton's local convergence fails, and
            // the warm start, the stepper's prediction, may be on the right one
            // (`153_room_corner` of seed 20261201, step 186: an arch spinning flat on the floor on
            // four coplanar vertices; the QPs tip it onto two or three of them and the fixed
            // point cycles between such points, residuals 1.4e-3–7.4e-3; Newton from the best
            // of them stops at 4.9e-6, from the warm start, face contact kept, it converges in 3
            // iterations). Both starts first with the local finish, then both with the
            // safeguarded one: a safeguarded finish from the best iterate that fails costs
            // 200–600 Newton iterations where the warm start's local finish takes 4–10
            // (`056_union_slide` of seed 20261219, `061_v_trough` of seed 20261226,
            // `docs/latency.md`, wip-conicslow2). Where the local finish converges it returns
            // the safeguarded finish's point, so a step changes only where the safeguards from
            // the best iterate would have solved it and the warm start's local finish does.
            if matches!(
                termination,
                Termination::Stagnated | Termination::MaxIterations
            ) && self.settings.newton_polish > 0
                && best_residual.is_finite()
            {
                let from_warm = !unanchored && z0 != best_z.as_slice();
                // The last stage only where both others failed from both starts: a step that
                // converged without it is unchanged.
                // The unanchored pass's own finish is the local one: where that falls short the
                // anchored pass's safeguarded finishes follow.
                let stages: &[NewtonFinish] = if unanchored {
                    &[NewtonFinish::Local]
                } else if self.settings.friction_continuation.is_some() {
                    &[
                        NewtonFinish::Local,
                        NewtonFinish::Safeguarded,
                        NewtonFinish::Continued,
                    ]
                } else {
                    &[NewtonFinish::Local, NewtonFinish::Safeguarded]
                };
                'finish: for &finish in stages {
                    // Between the local and the safeguarded finish: the unanchored pass
                    // (`ConicSettings::unanchored_retry`), a few QPs where the anchor held the
                    // loads back, where the safeguarded finishes cost hundreds of iterations.
                    if finish == NewtonFinish::Safeguarded
                        && !unanchored
                        && *anchored_seen
                        && self.settings.unanchored_retry
                        && let Some(sol) = self.unanchored_pass(mcp, z0, &mut run)
                    {
                        iterations += sol.summary.iterations;
                        if sol.summary.residual < best_residual {
                            z.copy_from_slice(&sol.z);
                            f_at_z = false;
                            best_residual = sol.summary.residual;
                        }
                        if best_residual <= self.settings.tolerance {
                            termination = Termination::Converged;
                            break 'finish;
                        }
                    }
                    for start in [Some(&best_z[..]), from_warm.then_some(z0)]
                        .into_iter()
                        .flatten()
                    {
                        let polished = self.newton_finish(
                            mcp,
                            start,
                            self.settings.newton_polish,
                            finish,
                            &mut run,
                        );
                        if let Some(sol) = polished
                            && sol.summary.residual < best_residual
                        {
                            z.copy_from_slice(&sol.z);
                            f_at_z = false;
                            best_residual = sol.summary.residual;
                        }
                        if best_residual <= self.settings.tolerance {
                            termination = Termination::Converged;
                            break 'finish;
                        }
                    }
                }
            }
        }
        // The relaxation's single QP is reported as the iteration limit (one QP) when its point
        // is not a solution of the exact model.
        let termination = if exact {
            termination
        } else {
            Termination::MaxIterations
        };
        // The summary judges `z` by `F(z)`, evaluated again only when `f` is not at `z`.
        if !f_at_z {
            mcp.evaluate(z, f);
        }
        run.f_evals += usize::from(!f_at_z);
        // The counters into `out`'s, in the order `Counters::from` would push them.
        let mut counters = std::mem::take(&mut out.summary.counters);
        counters.clear();
        for (counter, value) in [
            (Counter::ClarabelIterations, run.clarabel_iterations),
            (Counter::ClarabelStatus, run.status.map_or(0, status_code)),
            (Counter::PatchVertices, run.patch_vertices),
            (
                Counter::AnitescuRelaxation,
                usize::from(self.settings.mode == ConicMode::AnitescuRelaxation),
            ),
            (Counter::NewtonPolish, run.newton_polish),
            (Counter::NewtonHandoff, run.newton_handoff),
            (
                Counter::Custom("dense_qp_iterations"),
                run.dense_qp_iterations,
            ),
            (
                Counter::Custom("clarabel_fallbacks"),
                run.clarabel_fallbacks,
            ),
            (Counter::Custom("qp_reuses"), run.qp_reuses),
        ] {
            counters.set(counter, value);
        }
        if run.unanchored_passes > 0 {
            counters.set(Counter::Custom("unanchored_passes"), run.unanchored_passes);
        }
        let converged = finish_solve_into(
            mcp,
            z,
            f,
            SolveReport {
                solver: self.label(),
                termination,
                tolerance: self.settings.tolerance,
                iterations,
                f_evals: run.f_evals,
                jac_evals: 0,
                started: run.started,
                trace: run.trace,
                counters,
            },
            out,
        );
        self.outer = ws;
        if converged {
            Ok(())
        } else {
            Err(SolveError::NotConverged {
                best: Box::new(std::mem::take(out)),
            })
        }
    }
}

/// The first QP's load anchor is centred on the warm start's loads (the previous step's answer)
/// when the warm start's natural residual is at most this, i.e. the step is close to the
/// previous one: of a non-unique set of loads (a body wedged or pushed into a corner and held by
/// friction) the QP then keeps the member it had. Further away the centre is zero, as before:
/// the union desk's warm starts are at 0.1–1 and its trajectory (which depends on the member,
/// friction acting at each piece's centre of pressure) stays as it was; the stress suite's
/// troughs and corners are at 1e-11–5e-3 (`docs/latency.md#conic-backend`).
const WARM_LOADS_RESIDUAL: f64 = 1e-2;

/// The warm polish's start ([`ConicSettings::warm_polish`]) into `out`: the last answer's
/// impulses, extrapolated linearly from the answer before (`have_prev`) where both load the same
/// vertices and slide alike (the desk's loads follow a smooth forcing, so the start is a step's
/// change squared off, not a step's change); a loaded vertex whose extrapolated load would not be
/// positive keeps its last load, so the start has the last answer's active set.
fn extrapolated_start(
    last: &[ecp_model::ContactImpulses],
    have_prev: bool,
    prev: &[ecp_model::ContactImpulses],
    out: &mut Vec<ecp_model::ContactImpulses>,
) {
    let extrapolate = have_prev && same_active_set(prev, last);
    out.truncate(last.len());
    for (c, l) in last.iter().enumerate() {
        if c == out.len() {
            out.push(ecp_model::ContactImpulses::default());
        }
        let o = &mut out[c];
        o.vertex_impulses.clear();
        o.sigma = l.sigma;
        o.normal = l.normal;
        o.friction = l.friction;
        match prev.get(c).filter(|_| extrapolate) {
            Some(p) => {
                o.vertex_impulses
                    .extend(l.vertex_impulses.iter().zip(&p.vertex_impulses).map(
                        |(&(j, a), &(_, b))| {
                            let x = 2.0 * a - b;
                            (j, if a > 0.0 && x > 0.0 { x } else { a })
                        },
                    ));
                for i in 0..3 {
                    o.friction[i] = 2.0 * l.friction[i] - p.friction[i];
                }
            }
            None => o.vertex_impulses.extend_from_slice(&l.vertex_impulses),
        }
    }
}

/// Whether two points of one layout load the same patch vertices and slide at the same contacts,
/// each contact with some load ([`ConicSettings::warm_polish`]): the previous solve's active set
/// still holds. Where it changed (an impact, a contact starting to slide) the sweeps from the old
/// impulses may stop on a blocked correction short of the QP's answer, and from a contact without
/// load they never load it (the normal correction adds a violated vertex only to a loaded set:
/// `a5_drop_tilted`'s landing took 7 outer iterations instead of 4), so the QP is solved instead.
fn same_active_set(a: &[ecp_model::ContactImpulses], b: &[ecp_model::ContactImpulses]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(a, b)| {
            (a.sigma > 0.0) == (b.sigma > 0.0)
                && a.vertex_impulses.iter().any(|x| x.1 > 0.0)
                && a.vertex_impulses.len() == b.vertex_impulses.len()
                && a.vertex_impulses
                    .iter()
                    .zip(&b.vertex_impulses)
                    .all(|(x, y)| (x.1 > 0.0) == (y.1 > 0.0))
        })
}

/// Every contact of `structure` at `z` into `out` (`StepStructure::contact_into`: the kept
/// contacts' patches refilled, so a warm step allocates none).
fn contacts_into(
    structure: &dyn ecp_model::StepStructure,
    z: &[f64],
    band: f64,
    out: &mut Vec<ecp_model::ContactGeometry>,
) {
    let nc = structure.num_contacts();
    out.truncate(nc);
    for c in 0..nc {
        match out.get_mut(c) {
            Some(g) => structure.contact_into(c, z, band, g),
            None => out.push(structure.contact(c, z, band)),
        }
    }
}

/// The largest entry of `a − b`, in absolute value.
fn max_change(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The state of the outer fixed point: velocities per body, De Saxcé shifts and ECPs per
/// contact.
#[derive(Default)]
struct State {
    nu: Vec<[f64; 6]>,
    shifts: Vec<f64>,
    ecps: Vec<[f64; 3]>,
}

impl State {
    /// One vector in velocity units (ECPs divided by h), for the accelerator, into `v`.
    fn flatten_into(&self, h: f64, v: &mut Vec<f64>) {
        v.clear();
        v.extend(self.nu.iter().flatten().copied());
        v.extend(&self.shifts);
        v.extend(self.ecps.iter().flatten().map(|e| e / h));
    }
    /// The inverse of [`State::flatten_into`], with the shape of `like`; shifts stay ≥ 0.
    fn unflatten_from(&mut self, v: &[f64], like: &State, h: f64) {
        let nb = like.nu.len();
        let nc = like.shifts.len();
        self.nu.clear();
        self.nu.extend((0..nb).map(|b| {
            let mut x = [0.0; 6];
            x.copy_from_slice(&v[6 * b..6 * b + 6]);
            x
        }));
        self.shifts.clear();
        self.shifts.extend((0..nc).map(|c| v[6 * nb + c].max(0.0)));
        self.ecps.clear();
        self.ecps.extend((0..nc).map(|c| {
            let o = 6 * nb + nc + 3 * c;
            [v[o] * h, v[o + 1] * h, v[o + 2] * h]
        }));
    }
}

/// `v` set to `len` zeros (allocates only when it must grow).
fn zeroed(v: &mut Vec<f64>, len: usize) {
    v.clear();
    v.resize(len, 0.0);
}

/// The outer fixed point's storage ([`ConicSolver`]'s `outer`), kept between outer iterations
/// and solves so that a warm solve does not grow its vectors anew: each is cleared and
/// refilled, with the contacts' patches (`StepStructure::contact_into`), the QP's rows
/// (`step::build`) and the polished point among them: a warm desk solve into kept storage
/// allocates nothing (`tests/step_allocations.rs`).
#[derive(Default)]
struct OuterWorkspace {
    /// `F(z)` of the current point.
    f: Vec<f64>,
    /// The mapped-back point of the current QP.
    z_new: Vec<f64>,
    /// The best iterate so far.
    best_z: Vec<f64>,
    /// The point the geometry and the dynamics are evaluated at (the mixed iterate).
    z_in: Vec<f64>,
    /// The warm start's normal impulse per contact (empty when unknown or far).
    warm_loads: Vec<f64>,
    /// The previous outer iterate's normal impulse per contact.
    previous_loads: Vec<f64>,
    /// The contact geometry at `z_in`, and at the new point (for the next shifts and ECPs).
    geometry: Vec<ecp_model::ContactGeometry>,
    new_geometry: Vec<ecp_model::ContactGeometry>,
    /// Mass matrices and free velocities at `z_in`.
    bodies: Vec<ecp_model::BodyDynamics>,
    /// The fixed point's input `x`, its image `G(x)`, and the next input.
    x: State,
    g: State,
    next: State,
    /// `x`, `G(x)` flattened for the accelerator, and its mixed point.
    x_flat: Vec<f64>,
    g_flat: Vec<f64>,
    mixed: Vec<f64>,
    /// The mixed point with the last impulses, assembled into `z_in`.
    seed: ecp_model::ConicPoint,
    /// The QP's storage and its contact rows', handed to `step::build` and taken back.
    qp: step::StepQp,
    /// The QP's answer.
    result: qp::QpResult,
    /// The shape of the QP `result` answers, and of the current one ([`step::StepQp::layout_into`]).
    layout: Vec<usize>,
    new_layout: Vec<usize>,
    anderson: anderson::Anderson,
    /// The current point `z` (the returned one at the end).
    z: Vec<f64>,
    /// The polished point of the current QP (or of the reused answer).
    point: ecp_model::ConicPoint,
    /// Which contacts are anchored, and the patches per body that decide it.
    anchored: Vec<bool>,
    per_body: Vec<usize>,
    /// A contact's friction sides for its first De Saxcé shift.
    sides: Vec<step::BodyFriction>,
    /// The anchored loads' last change, for the stagnation test ([`loads_drifting`]).
    drift: LoadDrift,
    /// The impulses of the last solve's answer when it was a polished point (`have_last`), and
    /// the layout of the QP they were polished against ([`ConicSettings::warm_polish`]).
    last_contacts: Vec<ecp_model::ContactImpulses>,
    last_layout: Vec<usize>,
    have_last: bool,
    /// The answer's impulses of the solve before the last, when polished against a QP of the
    /// same layout (`have_prev`), and the warm polish's start extrapolated from both.
    prev_contacts: Vec<ecp_model::ContactImpulses>,
    have_prev: bool,
    start_contacts: Vec<ecp_model::ContactImpulses>,
}

/// Sweeps at most of the polish of the previous solve's impulses ([`ConicSettings::warm_polish`]).
/// The desk's settle in about 7 (as from the first QP's duals); a trial that needs more gives way to
/// the QP, which a long polish would cost more than.
pub const WARM_POLISH_SWEEPS: usize = 12;

/// The change of the anchored contacts' loads over one outer iteration, kept for the next
/// ([`loads_drifting`]).
#[derive(Default)]
struct LoadDrift {
    /// The outer iteration whose change `change` holds.
    iteration: Option<usize>,
    /// Per contact: its load minus the previous iterate's (0 for a contact not anchored).
    change: Vec<f64>,
}

/// Whether outer iteration `it` moved the anchored contacts' loads (`anchored`) on in the
/// direction of the iteration before (cosine at least [`DRIFT_COSINE`]) by more than
/// [`DRIFT_SIZE`] of their size: progress the residual does not show. The load anchor (a
/// proximal term, `step.rs`) lets a load that must go a long way, e.g. to 0 where a support
/// of a body wedged in a trough unloads, move only a bounded amount per QP; while it does, the
/// residual stays flat (the De Saxcé shift lags by the slip's change), and the stagnation window
/// would stop the fixed point a few QPs before its end (`061_v_trough` of seed 20261201, step 68:
/// 22 QPs at 2.2e-5 while one support's load walked from 0.30 to 0.007 N·s, converged at QP 29).
/// Loads are not in Anderson's state, so it cannot shorten the walk. Records this iteration's
/// change in `drift` for the next call.
fn loads_drifting(
    anchored: &[bool],
    point: &ecp_model::ConicPoint,
    previous_loads: &[f64],
    drift: &mut LoadDrift,
    it: usize,
) -> bool {
    let nc = point.contacts.len().min(previous_loads.len());
    // The last change is comparable when it is the iteration before's, with the same contacts.
    let follows = drift.iteration.is_some_and(|i| i + 1 == it) && drift.change.len() == nc;
    drift.change.resize(nc, 0.0);
    let (mut dot, mut last_norm, mut norm, mut size) = (0.0, 0.0, 0.0, 0.0f64);
    for (c, (p, before)) in point.contacts.iter().zip(previous_loads).enumerate() {
        let load: f64 = p.vertex_impulses.iter().map(|(_, l)| l).sum();
        let d = if anchored.get(c).copied().unwrap_or(false) {
            size = size.max(load.abs());
            load - before
        } else {
            0.0
        };
        let e = if follows { drift.change[c] } else { 0.0 };
        dot += d * e;
        last_norm += e * e;
        norm += d * d;
        drift.change[c] = d;
    }
    drift.iteration = Some(it);
    let (norm, last_norm) = (norm.sqrt(), last_norm.sqrt());
    norm > DRIFT_SIZE * size && last_norm > 0.0 && dot >= DRIFT_COSINE * norm * last_norm
}

/// See [`loads_drifting`]: two successive load changes count as one drift when the angle between
/// them has at least this cosine.
const DRIFT_COSINE: f64 = 0.9;
/// See [`loads_drifting`]: a load change counts when it exceeds this fraction of the largest
/// anchored load.
const DRIFT_SIZE: f64 = 1e-6;

#[cfg(test)]
mod warm_polish_tests {
    use super::same_active_set;
    use ecp_model::ContactImpulses;

    fn contact(loads: &[f64], sigma: f64) -> ContactImpulses {
        ContactImpulses {
            vertex_impulses: loads.iter().copied().enumerate().collect(),
            sigma,
            ..ContactImpulses::default()
        }
    }

    #[test]
    fn the_warm_polish_needs_the_same_loaded_vertices_and_slip_and_some_load() {
        let before = [contact(&[1.0, 0.0, 2.0], 0.1)];
        assert!(same_active_set(&before, &[contact(&[1.5, 0.0, 1.0], 0.3)]));
        // A vertex joined, one left, the contact stuck, the layout differs.
        assert!(!same_active_set(&before, &[contact(&[1.5, 0.2, 1.0], 0.3)]));
        assert!(!same_active_set(&before, &[contact(&[1.5, 0.0, 0.0], 0.3)]));
        assert!(!same_active_set(&before, &[contact(&[1.5, 0.0, 1.0], 0.0)]));
        assert!(!same_active_set(&before, &[contact(&[1.5, 0.0], 0.3)]));
        assert!(!same_active_set(&before, &[]));
        // A contact without load: the sweeps never load it.
        let unloaded = [contact(&[0.0, 0.0], 0.0)];
        assert!(!same_active_set(&unloaded, &unloaded));
    }
}
