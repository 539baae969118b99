//! What a formulation supplies to the step driver ([`super::Simulation`]): its step problem
//! (variables, data and residual blocks, built once), the data of each span, a warm start, optional
//! deterministic second starts after a failed solve, the read-out of a solution, and its
//! [`Capabilities`]. Everything else — the iterate, the states, time, retries, fallbacks,
//! substeps, records, sensitivities — is the driver's, the same for every formulation.
//!
//! A span is a whole step or, when the driver falls back on substeps, a part of one: every method
//! that sees a [`StepContext`] must use its `t0` and `h`, not the scene's step.

use std::any::Any;

use nalgebra::{Vector3, Vector6};

use ecp_model::{BlockMcp, Problem, StepStructure};

use super::handles::StepHandles;
use super::history::Iterates;
use crate::record::{ContactRecord, PairRecord};

/// The highest order of extrapolation ([`StepFormulation::warm_start_order`]) whose start the
/// driver takes as before the order-5 start (branch wip-xorder): a polynomial motion of degree
/// 2 at most continued to round-off.
pub const QUADRATIC: usize = 2;
use crate::scene::{BodyState, Scene, SceneError};

/// How exact the step sensitivities of a formulation are (`docs/fitting.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SensitivitySupport {
    /// Exact derivatives of the step's solution (the hull formulation).
    Exact,
    /// The step's solution is not unique (shared impulses): the derivatives are minimum-norm
    /// least-squares guesses, reported as singular at every step where they are.
    NotUnique,
    /// No step sensitivities: the step's unknowns do not hold each body's ν and q.
    None,
}

/// What a formulation can do, asked by the command line, the registry and the driver instead of
/// matching names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Capabilities {
    /// The step problem comes with a structural view ([`StepFormulation::structure`]), which
    /// structure-exploiting backends (the conic one) need.
    pub step_structure: bool,
    /// A step its backend cannot solve may be solved by other backends
    /// ([`super::Fallbacks::backends`]).
    pub fallback_backends: bool,
    /// A step may be split into substeps `h/2, h/4, …` ([`super::Fallbacks::max_halvings`]).
    pub substeps: bool,
    /// Each body's ν and q blocks and Newton–Euler rows are in the step problem
    /// ([`super::BodyHandles`]): user forces and terms can join it.
    pub user_terms: bool,
    /// How exact the step sensitivities are.
    pub sensitivities: SensitivitySupport,
    /// The step's solutions are not isolated (the impulses of several contacts of one body are
    /// shared): Newton backends should take minimum-norm steps.
    pub non_isolated_solutions: bool,
}

/// The span being stepped: the scene, the bodies' states at its start, its start time and
/// length, and the step it belongs to.
#[derive(Clone, Copy, Debug)]
pub struct StepContext<'a> {
    /// The scene (with the parameters set last, [`super::Simulation::set_param`]).
    pub scene: &'a Scene,
    /// Body states at the start of the span (world frame).
    pub states: &'a [BodyState],
    /// Start time of the span, `t_u` for a whole step (loads are evaluated there).
    pub t0: f64,
    /// Length of the span: the scene's `h`, or a substep's.
    pub h: f64,
    /// The step the span belongs to, from 1.
    pub step: usize,
    /// The iterates after the read-out of the last steps before this span (two to six,
    /// `history::KEPT`, newest first), when the span is a whole step and they were solved
    /// directly, in one piece, from their warm start in 1–5 iterations (or in 0 from a predicted
    /// start, which the backend took only at round-off: `McpSolver::set_start_predicted`), no
    /// retry, no fallback, in the same origin, with no state, parameter or data set since.
    /// What a warm start may extrapolate from
    /// (`docs/latency.md#an-extrapolated-warm-start-branch-wip-warmx-issue-18`); `None` otherwise.
    pub history: Option<Iterates<'a>>,
    /// Each body's applied wrench at `t0` ([`crate::scene::Load::at`]), evaluated once for the
    /// span by the driver (a scene file's load is an expression evaluated per component); empty
    /// where the driver does not set the span's data ([`StepContext::wrench`] then evaluates it).
    pub wrenches: &'a [Vector6<f64>],
}

impl StepContext<'_> {
    /// Body `b`'s applied wrench at `t0`, `(force, torque)` at the CM, world frame: the one
    /// evaluated for the span ([`StepContext::wrenches`]), else its load at `t0`.
    pub fn wrench(&self, b: usize) -> Vector6<f64> {
        match self.wrenches.get(b) {
            Some(w) => *w,
            None => self.scene.bodies[b].load.at(self.t0),
        }
    }
}

/// Whether the step problem built last still fits ([`StepFormulation::begin_step`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prepared {
    /// The step problem fits the states: go on.
    Ready,
    /// The formulation's unknowns changed (a contact appeared or vanished): the driver builds the
    /// step problem again with [`StepFormulation::build`] and carries the iterate over by
    /// variable-block name.
    Rebuild,
}

/// A contact formulation: what makes the step problem of one model (`docs/model.md`). The driver
/// ([`super::Simulation`]) owns the problem, the iterate `z` and the states and calls, per step:
/// [`begin_step`](Self::begin_step) once, then for each span
/// [`update_data`](Self::update_data), [`warm_start`](Self::warm_start), the solve (through
/// [`structure`](Self::structure) when there is one), [`retry_start`](Self::retry_start) after
/// a failed solve, and [`read_out`](Self::read_out) of a solution; then
/// [`contact_records`](Self::contact_records).
///
/// A formulation keeps only what it derives from the scene (hulls, handles, frames); the scene
/// and the states come with every call, so that parameters set on the driver reach it.
pub trait StepFormulation: Any + Send {
    /// The name in scene files, on the command line and in reports.
    fn name(&self) -> &str;
    /// What the formulation can do.
    fn capabilities(&self) -> Capabilities;
    /// Validates `scene` (refusing, with a [`SceneError`] that says why, a scene the formulation
    /// does not apply to) and declares the step problem for the bodies at `states`: variable
    /// blocks, data blocks and residual blocks. Returns the handles the driver, user terms and
    /// sensitivities bind to. Called again (on the same object) when the driver rebuilds, so it
    /// resets whatever it derived before.
    fn build(
        &mut self,
        scene: &Scene,
        states: &[BodyState],
        problem: &mut Problem,
    ) -> Result<StepHandles, SceneError>;
    /// Contacts per body in every record (the columns of `trajectory.csv`).
    fn contacts_per_body(&self) -> usize;
    /// The starting point of the first step, written into `z` (zero on entry), with
    /// `ctx.states` the initial states; also called by [`super::Simulation::reset`].
    fn initial_guess(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<(), SceneError>;
    /// Once per step, before the driver's checkpoint: adjust what holds for the whole step (the
    /// hull formulation moves its origin here) or ask for a rebuild.
    fn begin_step(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<Prepared, SceneError> {
        let _ = (ctx, mcp, z);
        Ok(Prepared::Ready)
    }
    /// Writes the span's data (start states, loads at `t0`, the span length, …) with
    /// [`BlockMcp::set_data`]; refuses a state where the formulation stops applying.
    fn update_data(&mut self, ctx: &StepContext<'_>, mcp: &mut BlockMcp) -> Result<(), SceneError>;
    /// The warm start of the span, from the previous solution in `z`.
    fn warm_start(&mut self, ctx: &StepContext<'_>, mcp: &BlockMcp, z: &mut [f64]);
    /// Whether the last [`StepFormulation::warm_start`] extrapolated from
    /// [`StepContext::history`] (the driver then solves it within an iteration budget,
    /// `docs/latency.md#the-extrapolated-warm-start-on-by-default-branch-wip-warmon-issue-18`,
    /// and [`StepFormulation::retry_start`]'s first start should be the warm start without
    /// extrapolation). The default is `false`.
    fn warm_start_extrapolated(&self) -> bool {
        false
    }
    /// The order of the extrapolation the last [`StepFormulation::warm_start`] took (the degree
    /// of its polynomial in the steps: 1, 2 or 5 for the hull formulation), 0 when it did not
    /// extrapolate. Above [`QUADRATIC`] the start is a prediction of a smooth motion, not a
    /// polynomial one continued to round-off: the driver has the backend return it as it
    /// stands only at round-off ([`ecp_model::McpSolver::set_start_predicted`]). The default
    /// is 0.
    fn warm_start_order(&self) -> usize {
        0
    }
    /// The start the last [`StepFormulation::warm_start`] wrote and `F` there, when it evaluated
    /// `F` at that start on the step problem it was given (the extrapolated warm start's guard
    /// does): the driver hands it to the backend ([`ecp_model::Mcp::known_value`]), which then
    /// skips that evaluation. The default is `None`.
    fn warm_start_value(&self) -> Option<(&[f64], &[f64])> {
        None
    }
    /// `Φ` (the Fischer–Burmeister reformulation, [`ecp_model::fb_vector`]) at the start of
    /// [`StepFormulation::warm_start_value`], when the formulation computed it there from that
    /// `F` (the guard compares its starts by `‖Φ‖`): the driver hands it to the backend with
    /// `F` ([`ecp_model::Mcp::known_fb_vector`]). The default is `None`.
    fn warm_start_fb_vector(&self) -> Option<&[f64]> {
        None
    }
    /// A deterministic second start after a failed solve: modify `z` (as the previous attempt
    /// left it) and return `true` to have the span solved again, `false` when there is no
    /// further start. `attempt` counts from 0.
    fn retry_start(
        &mut self,
        attempt: usize,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
    ) -> bool {
        let _ = (attempt, ctx, mcp, z);
        false
    }
    /// Takes the solution `z` of the span: writes the end-of-span states (world frame, `Q`
    /// renormalised) and may adjust `z` (it is the next warm start). An error refuses the
    /// solution (the formulation stopped applying); the driver then keeps the states at the
    /// step's start.
    fn read_out(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        states: &mut [BodyState],
    ) -> Result<(), SceneError>;
    /// The records of every contact (body-major) for the bodies at `states`, from `z`;
    /// `solved` is false for a step that failed (then `states` are the step's start states
    /// and `z` the iterate at its start).
    fn contact_records(
        &self,
        scene: &Scene,
        states: &[BodyState],
        solved: bool,
        mcp: &BlockMcp,
        z: &[f64],
        out: &mut Vec<ContactRecord>,
    );
    /// The records of the active contacts between named bodies (`contacts.csv`,
    /// `docs/outputs.md#contactscsv`), from `z` at the end of a step; none by default.
    fn pair_records(
        &self,
        scene: &Scene,
        solved: bool,
        mcp: &BlockMcp,
        z: &[f64],
        out: &mut Vec<PairRecord>,
    ) {
        let _ = (scene, solved, mcp, z, out);
    }
    /// Origin of the step problem's coordinates (world frame): positions in `z` and in the
    /// position-valued data are relative to it. Zero unless the formulation moves it (the hull
    /// formulation does for scenes far from the world origin, `docs/model.md#far-scenes`).
    fn origin(&self) -> Vector3<f64> {
        Vector3::zeros()
    }
    /// The structural view of the span's step problem, for structure-exploiting backends; it
    /// must be valid after [`update_data`](Self::update_data) until the next span.
    fn structure(&self) -> Option<&dyn StepStructure> {
        None
    }
    /// The scene scales of the span's step problem (`docs/decisions.md#scene-scaled-convergence`):
    /// the units in which backends judge its natural residual. Valid after
    /// [`update_data`](Self::update_data) until the next span; `None`: judged as given.
    fn scales(&self) -> Option<&ecp_model::McpScales> {
        None
    }
    /// [`StepFormulation::scales`] with their verdict for a step problem of dimension `n`
    /// ([`ecp_model::McpScales::usage`]). The default computes it; a formulation that keeps
    /// its scales across spans may keep the verdict with them.
    fn scales_usage(&self, n: usize) -> Option<(&ecp_model::McpScales, ecp_model::ScalesUsage)> {
        self.scales().map(|s| (s, s.usage(n)))
    }
}
