//! The one step driver of every formulation (`docs/model.md#stepper`): [`Simulation`] owns the
//! formulation, the step problem (built once, its data set per span), the iterate `z`, the
//! states, time, the warm start, the deterministic retry, the fallbacks and substeps, the
//! records, and the last step for the sensitivities. A formulation
//! ([`StepFormulation`]) supplies only what is its own.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Vector3, Vector6};

use ecp_model::{
    BlockMcp, CscPattern, DataId, Mcp, McpFamily, McpSolver, ModelError, Problem, Solution,
    SolveError, StepStructure, Summary,
};

use super::fallback::{Fallbacks, Spans, rescue};
use super::formulation::{Capabilities, Prepared, QUADRATIC, StepContext, StepFormulation};
use super::handles::StepHandles;
use super::history::History;
use super::params::{Param, ParamError};
use super::terms::{Force, ForceHandles, Term, add_force};
use crate::record::{StepMethod, StepRecord, body_energy};
use crate::scene::{BodyState, Scene, SceneError, initial_states};

/// The most iterations of a step that [`StepContext::history`] keeps (measured on the stress
/// suite: extrapolating after steps of 9 and 131 iterations, an impact settling, cost 1653
/// iterations against 1, `docs/latency.md#an-extrapolated-warm-start-branch-wip-warmx-issue-18`).
const SMOOTH_ITERATIONS: usize = 5;

/// The default iteration budget of the first solve from each start of a step other than an
/// extrapolated warm start ([`Simulation::set_start_budget`]): a start that has not solved the
/// step within it is left for the next start, and taken again with the backend's full limits
/// only when no start solves the step within its budget.
const START_BUDGET: usize = 20;

/// The iteration budget of a solve from an extrapolated warm start, from the most iterations
/// `recent` of the smooth steps it extrapolates: `max(8, 3 recent)`. When the attempt does not
/// converge within it, the step is solved again from the warm start without extrapolation,
/// first within the start budget ([`Simulation::set_start_budget`]), then with the backend's
/// full limits (`docs/latency.md#the-extrapolated-warm-start-on-by-default-branch-wip-warmon-issue-18`).
fn extrapolation_budget(recent: usize) -> usize {
    (3 * recent).max(8)
}

/// The context of the span `[t0, t0 + h]` of `step` from the states `start` (the bodies'
/// applied `wrenches` at `t0`, [`StepContext::wrenches`]), for a step problem
/// of dimension `dim` whose origin is `origin`: with the kept `history` of smooth steps when the
/// span is a whole step of `scene` and `warm_start` extrapolates ([`History::iterates`]). The
/// one construction of a span's context for its data, warm start and retry starts.
fn span_context<'a>(
    (scene, warm_start, history): (&'a Scene, WarmStart, &'a History),
    origin: Vector3<f64>,
    step: usize,
    (start, t0, h, wrenches): (&'a [BodyState], f64, f64, &'a [Vector6<f64>]),
    dim: usize,
) -> StepContext<'a> {
    let whole_step = h == scene.h && warm_start != WarmStart::Previous;
    let mut history = history.iterates(whole_step, &origin, dim);
    if warm_start == WarmStart::Quadratic
        && let Some(it) = &mut history
    {
        // At most three steps: the extrapolations of orders 1 and 2 alone.
        it.truncate(2);
    }
    StepContext {
        scene,
        states: start,
        t0,
        h,
        step,
        history,
        wrenches,
    }
}

/// The last step a [`Simulation`] took, as the step sensitivities need it: the step's data
/// stay in [`Simulation::mcp`] until the next step is prepared, which clears this.
#[derive(Clone, Debug, PartialEq)]
pub struct LastStep {
    /// The step's index, from 1.
    pub step: usize,
    /// Time at the start of the step, `t_u` (the loads were evaluated there).
    pub t_start: f64,
    /// Body states at the start of the step.
    pub start: Vec<BodyState>,
    /// Applied wrench of each body at `t_u`, `(force, torque)` at the CM, world frame.
    pub wrenches: Vec<Vector6<f64>>,
    /// The solution as the backend returned it (the end-of-step `Q` not yet renormalised).
    pub z: Vec<f64>,
    /// Whether the step converged.
    pub converged: bool,
}

/// A simulation being built: the scene, the formulation, and the user's forces and terms
/// ([`super::terms`]). [`Simulation::builder`] starts one with the hull formulation.
pub struct SimulationBuilder {
    scene: Scene,
    formulation: Box<dyn StepFormulation>,
    forces: Vec<(usize, Force)>,
    terms: Vec<Box<dyn Term>>,
}

impl SimulationBuilder {
    /// A builder for `scene` stepped by `formulation`.
    pub fn new(scene: Scene, formulation: Box<dyn StepFormulation>) -> Self {
        SimulationBuilder {
            scene,
            formulation,
            forces: Vec::new(),
            terms: Vec::new(),
        }
    }

    /// Steps the scene with `formulation` instead.
    pub fn formulation(mut self, formulation: Box<dyn StepFormulation>) -> Self {
        self.formulation = formulation;
        self
    }

    /// Adds `force` to body `body`'s Newton–Euler rows ([`Force`]: sign, units and inputs).
    pub fn force(mut self, body: usize, force: Force) -> Self {
        self.forces.push((body, force));
        self
    }

    /// Adds an extra part of the step problem with its own unknowns ([`Term`]).
    pub fn term(mut self, term: impl Term + 'static) -> Self {
        self.terms.push(Box::new(term));
        self
    }

    /// Validates the scene, builds the step problem and the first step's starting point.
    pub fn build(self) -> Result<Simulation, SceneError> {
        let states = initial_states(&self.scene)?;
        let mut formulation = self.formulation;
        let mut terms = self.terms;
        let built = assemble(
            &self.scene,
            formulation.as_mut(),
            &states,
            &self.forces,
            &mut terms,
        )?;
        let mut sim = Simulation {
            z: vec![0.0; built.mcp.dim()],
            scene: self.scene,
            formulation,
            forces: self.forces,
            terms,
            mcp: built.mcp,
            handles: built.handles,
            force_handles: built.forces,
            states,
            initial_changed: false,
            step: 0,
            t: 0.0,
            last: None,
            warm_start: WarmStart::default(),
            start_budget: Some(START_BUDGET),
            kept: Kept::default(),
            start_value: false,
        };
        sim.start()?;
        Ok(sim)
    }
}

/// A running simulation of one scene with one formulation (module documentation).
pub struct Simulation {
    scene: Scene,
    formulation: Box<dyn StepFormulation>,
    forces: Vec<(usize, Force)>,
    terms: Vec<Box<dyn Term>>,
    mcp: BlockMcp,
    handles: StepHandles,
    force_handles: Vec<ForceHandles>,
    z: Vec<f64>,
    states: Vec<BodyState>,
    /// An initial-state parameter changed since the step problem was built: [`Simulation::reset`]
    /// builds it again (a formulation may derive its unknowns from the initial state).
    initial_changed: bool,
    step: usize,
    t: f64,
    /// The last step taken, while its step problem is still the one in `mcp`.
    last: Option<LastStep>,
    /// Whether a step's warm start may extrapolate from the last steps ([`WarmStart`]).
    warm_start: WarmStart,
    /// The iteration budget of each start's first solve ([`Simulation::set_start_budget`]).
    start_budget: Option<usize>,
    /// Storage reused from step to step.
    kept: Kept,
    /// The formulation's `F` at the warm start ([`StepFormulation::warm_start_value`]) still
    /// holds: no data, parameter or state set and no step begun since the span was prepared.
    start_value: bool,
}

/// The warm start of a step ([`Simulation::set_warm_start`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum WarmStart {
    /// The formulation's warm start from the last step's solution alone
    /// ([`StepContext::history`] is `None`): every step as before the extrapolation.
    Previous,
    /// The default: the formulation may extrapolate from the iterates of the last smooth steps
    /// (`docs/latency.md#an-extrapolated-warm-start-branch-wip-warmx-issue-18`), for a backend
    /// whose answer does not depend on its start ([`McpSolver::converges_to_round_off`]:
    /// Newton, PATH with its polish; conic keeps [`WarmStart::Previous`]'s steps), within an
    /// iteration budget
    /// with a restart from the plain warm start
    /// (`docs/latency.md#the-extrapolated-warm-start-on-by-default-branch-wip-warmon-issue-18`):
    /// fewer iterations on smooth motion.
    #[default]
    Extrapolated,
    /// [`WarmStart::Extrapolated`] from at most the last three smooth steps (the formulation's
    /// extrapolation of order 2 at most): the default before the orders up to 5
    /// (`docs/latency.md`, branch wip-xorder), whose trajectories it reproduces bit for bit
    /// (`tests/hard_steps.rs` reaches steps measured on them).
    Quadratic,
}

/// What a step writes into storage kept across steps, so that a step allocates nothing once
/// it has grown (`docs/latency.md#allocations`): the checkpoint, the loads, the backend's result
/// ([`McpSolver::solve_into`]), a [`LastStep`] no longer current, and the iterates of the last
/// (up to six) smooth steps ([`StepContext::history`]).
#[derive(Default)]
struct Kept {
    checkpoint: Checkpoint,
    wrenches: Vec<Vector6<f64>>,
    /// The bodies' applied wrenches at the start of the span prepared last
    /// ([`StepContext::wrenches`]).
    span_wrenches: Vec<Vector6<f64>>,
    solution: Solution,
    last: Option<LastStep>,
    history: History,
    /// The last prepared span's first solve was from a predicted start
    /// ([`McpSolver::set_start_predicted`], honoured by the backend): a solve of 0 iterations
    /// there returned a start at round-off.
    predicted: bool,
}

/// The states and `z` at the start of a step, for going back to it.
type Checkpoint = (Vec<BodyState>, Vec<f64>);

struct Built {
    mcp: BlockMcp,
    handles: StepHandles,
    forces: Vec<ForceHandles>,
}

/// Builds the step problem of `formulation` for the bodies at `states`, with the user's forces
/// and terms after the formulation's blocks.
fn assemble(
    scene: &Scene,
    formulation: &mut dyn StepFormulation,
    states: &[BodyState],
    forces: &[(usize, Force)],
    terms: &mut [Box<dyn Term>],
) -> Result<Built, SceneError> {
    let mut problem = Problem::new();
    let handles = formulation.build(scene, states, &mut problem)?;
    if (!forces.is_empty() || !terms.is_empty()) && !formulation.capabilities().user_terms {
        return Err(SceneError::NotApplicable {
            formulation: formulation.name().to_string(),
            step: None,
            reason: "its step problem has no ν and q unknowns per body, so user forces and terms \
                     cannot join it; use the hull, union or point formulation"
                .into(),
        });
    }
    let name = formulation.name().to_string();
    let forces = forces
        .iter()
        .map(|(b, f)| add_force(&mut problem, &handles, &name, *b, f))
        .collect::<Result<Vec<_>, _>>()?;
    for term in terms.iter_mut() {
        term.build(&handles, &mut problem)?;
    }
    Ok(Built {
        mcp: problem.build()?,
        handles,
        forces,
    })
}

/// Whether `a` and `b` hold the same bits (without an exit per entry).
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len()
        && (a.iter())
            .zip(b)
            .fold(true, |same, (x, y)| same & (x.to_bits() == y.to_bits()))
}

/// The step problem as the backends see it ([`Simulation::step_problem`]): the assembled MCP
/// with the formulation's structural view, if it has one ([`StepFormulation::structure`]).
pub struct StepProblem<'a> {
    mcp: &'a BlockMcp,
    structure: Option<&'a dyn StepStructure>,
    /// The scene scales and their verdict ([`StepFormulation::scales_usage`]).
    scales: Option<(&'a ecp_model::McpScales, ecp_model::ScalesUsage)>,
    /// The scene's `friction` data block (μ first), when the problem reads it: the friction
    /// family ([`Mcp::friction_family`]) scales that μ.
    friction: Option<DataId>,
    /// The warm start and `F` there, when the formulation evaluated it
    /// ([`StepFormulation::warm_start_value`]) on the step problem as it still is.
    start: Option<(&'a [f64], &'a [f64])>,
    /// `Φ` at that start, when the formulation computed it too
    /// ([`StepFormulation::warm_start_fb_vector`]); only with `start`.
    start_phi: Option<&'a [f64]>,
}

impl StepProblem<'_> {
    /// The problem's data with the scene's μ scaled by `s` (allocated: only a backend's
    /// continuation, after a failed solve, asks for it).
    fn data_at(&self, s: f64, friction: DataId) -> Vec<f64> {
        let mut data = self.mcp.data_values().to_vec();
        data[self.mcp.data_offset(friction)] *= s;
        data
    }
}

/// `F(z; s)`: the step with the scene's friction coefficient `s μ`
/// (`docs/newton.md#a-continuation-in-the-friction-coefficient`); `s = 1` is the step itself,
/// bit for bit. Friction given per pair of bodies keeps its own μ.
impl McpFamily for StepProblem<'_> {
    fn evaluate_at(&self, s: f64, z: &[f64], f: &mut [f64]) {
        match self.friction {
            Some(friction) if s != 1.0 => {
                self.mcp
                    .evaluate_with_data(&self.data_at(s, friction), z, f)
            }
            _ => self.mcp.evaluate(z, f),
        }
    }
    fn evaluate_with_jacobian_at(&self, s: f64, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        match self.friction {
            Some(friction) if s != 1.0 => {
                self.mcp
                    .evaluate_with_jacobian_with_data(&self.data_at(s, friction), z, f, values)
            }
            _ => self.mcp.evaluate_with_jacobian(z, f, values),
        }
    }
}

impl Mcp for StepProblem<'_> {
    fn dim(&self) -> usize {
        self.mcp.dim()
    }
    fn lower(&self) -> &[f64] {
        self.mcp.lower()
    }
    fn upper(&self) -> &[f64] {
        self.mcp.upper()
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        self.mcp.evaluate(z, f)
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        self.mcp.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        self.mcp.jacobian(z, values)
    }
    fn evaluate_with_jacobian(&self, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        self.mcp.evaluate_with_jacobian(z, f, values)
    }
    /// `F` at the warm start, for that start's bits only.
    fn known_value(&self, z: &[f64]) -> Option<&[f64]> {
        let (start, f) = self.start?;
        same_bits(start, z).then_some(f)
    }
    /// `Φ` at the warm start, for that start's bits only (with its `F`).
    fn known_fb_vector(&self, z: &[f64]) -> Option<&[f64]> {
        let (start, _) = self.start?;
        let phi = self.start_phi?;
        (phi.len() == z.len() && same_bits(start, z)).then_some(phi)
    }
    fn component_name(&self, i: usize) -> String {
        self.mcp.component_name(i)
    }
    fn write_component_name(&self, i: usize, out: &mut String) {
        self.mcp.write_component_name(i, out)
    }
    fn structure(&self) -> Option<&dyn StepStructure> {
        self.structure
    }
    fn scales(&self) -> Option<&ecp_model::McpScales> {
        self.scales.map(|(s, _)| s)
    }
    fn scales_usage(&self) -> Option<(&ecp_model::McpScales, ecp_model::ScalesUsage)> {
        self.scales
    }
    fn elimination_groups(&self) -> &[Vec<usize>] {
        self.mcp.elimination_groups()
    }
    fn friction_family(&self) -> Option<&dyn McpFamily> {
        self.friction.map(|_| self as &dyn McpFamily)
    }
}

/// The iterations an attempt that did not converge spent (0 for other errors).
fn attempt_iterations(e: &SolveError) -> usize {
    match e {
        SolveError::NotConverged { best } => best.summary.iterations,
        _ => 0,
    }
}

/// `out`, solved after `retries` attempts that spent `spent` iterations, with them counted.
fn finish(out: &mut Solution, retries: usize, spent: usize) -> Result<(), SolveError> {
    out.summary
        .counters
        .add(ecp_model::Counter::Retries, retries);
    out.summary.iterations += spent;
    Ok(())
}

/// Keeps the better of two failed solves (the smaller natural residual, the first on a tie).
fn better_failure(a: SolveError, b: SolveError) -> SolveError {
    match (a, b) {
        (SolveError::NotConverged { best: a }, SolveError::NotConverged { best: b }) => {
            SolveError::NotConverged {
                best: if a.summary.residual <= b.summary.residual {
                    a
                } else {
                    b
                },
            }
        }
        (_, b) => b,
    }
}

/// Copies the values of `old`'s data blocks into the blocks of `new` with the same name and size
/// (user data survives a rebuild).
fn carry_data(old: &BlockMcp, new: &mut BlockMcp) -> Result<(), ModelError> {
    let names: HashMap<&str, usize> = old
        .data_blocks()
        .iter()
        .enumerate()
        .map(|(i, d)| (d.name(), i))
        .collect();
    let targets: Vec<(DataId, DataId)> = new
        .data_blocks()
        .iter()
        .enumerate()
        .filter_map(|(i, d)| {
            let j = *names.get(d.name())?;
            (old.data_blocks()[j].size() == d.size()).then_some((DataId(j), DataId(i)))
        })
        .collect();
    for (from, to) in targets {
        new.set_data(to, old.data(from))?;
    }
    Ok(())
}

impl Simulation {
    /// A builder for `scene` stepped by `formulation`, for user forces and terms
    /// ([`SimulationBuilder`]).
    pub fn builder_with(scene: Scene, formulation: Box<dyn StepFormulation>) -> SimulationBuilder {
        SimulationBuilder::new(scene, formulation)
    }

    /// The starting point of the first step for the current states.
    fn start(&mut self) -> Result<(), SceneError> {
        self.kept.history.clear();
        self.start_value = false;
        self.z.iter_mut().for_each(|v| *v = 0.0);
        let ctx = StepContext {
            scene: &self.scene,
            states: &self.states,
            t0: self.t,
            h: self.scene.h,
            step: self.step + 1,
            history: None,
            wrenches: &[],
        };
        self.formulation
            .initial_guess(&ctx, &mut self.mcp, &mut self.z)?;
        for term in &self.terms {
            term.initial_guess(&self.mcp, &mut self.z);
        }
        Ok(())
    }

    /// Builds the step problem again for the current states (the formulation asked for it, or
    /// the initial state changed); data carry over by name, and, when `carry_z`, the iterate
    /// by variable-block name.
    fn rebuild(&mut self, carry_z: bool) -> Result<(), SceneError> {
        self.start_value = false;
        let built = assemble(
            &self.scene,
            self.formulation.as_mut(),
            &self.states,
            &self.forces,
            &mut self.terms,
        )?;
        let mut mcp = built.mcp;
        carry_data(&self.mcp, &mut mcp)?;
        let mut z = vec![0.0; mcp.dim()];
        if carry_z {
            let old: HashMap<&str, usize> = self
                .mcp
                .variable_blocks()
                .iter()
                .enumerate()
                .map(|(i, v)| (v.name(), i))
                .collect();
            for (i, v) in mcp.variable_blocks().iter().enumerate() {
                if let Some(&j) = old.get(v.name()) {
                    let (from, to) = (
                        self.mcp.range(ecp_model::VarId(j)),
                        mcp.range(ecp_model::VarId(i)),
                    );
                    if from.len() == to.len() {
                        z[to].copy_from_slice(&self.z[from]);
                    }
                }
            }
        }
        // The iterates kept hold for the new problem only when its unknowns are laid out as before.
        let same_layout = carry_z
            && mcp.variable_blocks().len() == self.mcp.variable_blocks().len()
            && (mcp.variable_blocks().iter().enumerate()).all(|(i, v)| {
                let id = ecp_model::VarId(i);
                v.name() == self.mcp.variable_blocks()[i].name()
                    && mcp.range(id) == self.mcp.range(id)
            });
        if !same_layout {
            self.kept.history.clear();
        }
        self.mcp = mcp;
        self.z = z;
        self.handles = built.handles;
        self.force_handles = built.forces;
        self.last = None;
        Ok(())
    }

    /// The scene (with the parameters set last).
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// The formulation.
    pub fn formulation(&self) -> &dyn StepFormulation {
        self.formulation.as_ref()
    }
    /// The formulation as its own type, when it is a `T` (for the accessors only a formulation
    /// has, e.g. the ECP formulation's contacts).
    pub fn formulation_as<T: StepFormulation>(&self) -> Option<&T> {
        let any: &dyn std::any::Any = self.formulation.as_ref();
        any.downcast_ref::<T>()
    }
    /// The formulation's name.
    pub fn formulation_name(&self) -> &str {
        self.formulation.name()
    }
    /// What the formulation can do.
    pub fn capabilities(&self) -> Capabilities {
        self.formulation.capabilities()
    }
    /// The assembled step problem (its data are those of the span prepared last).
    pub fn mcp(&self) -> &BlockMcp {
        &self.mcp
    }
    /// The handles of the step problem: each body's unknowns and data, the scene's data, the
    /// contacts.
    pub fn handles(&self) -> &StepHandles {
        &self.handles
    }
    /// The handles of the user forces, in the order they were added.
    pub fn force_handles(&self) -> &[ForceHandles] {
        &self.force_handles
    }
    /// The current unknown vector (last solution, or the warm start of the next step once
    /// prepared). Its positions are relative to [`Simulation::origin`].
    pub fn z(&self) -> &[f64] {
        &self.z
    }
    /// The values of variable block `v` in [`Simulation::z`] (a user term's unknowns, a body's ν).
    pub fn values(&self, v: ecp_model::VarId) -> &[f64] {
        &self.z[self.mcp.range(v)]
    }
    /// Origin of the step problem's coordinates (world frame): zero unless the formulation moved
    /// it for a scene far from the world origin (`docs/model.md#far-scenes`).
    pub fn origin(&self) -> Vector3<f64> {
        self.formulation.origin()
    }
    /// Current state of body `b`.
    pub fn state(&self, b: usize) -> BodyState {
        self.states[b]
    }
    /// Current states of every body.
    pub fn states(&self) -> &[BodyState] {
        &self.states
    }
    /// Current time.
    pub fn time(&self) -> f64 {
        self.t
    }
    /// Steps taken.
    pub fn steps_taken(&self) -> usize {
        self.step
    }
    /// True once the scene's duration is covered.
    pub fn finished(&self) -> bool {
        self.step >= self.scene.num_steps()
    }
    /// Contacts per body in every [`StepRecord`] (the columns of `trajectory.csv`).
    pub fn contacts_per_body(&self) -> usize {
        self.formulation.contacts_per_body()
    }
    /// Kinetic plus potential energy (gravity) of all bodies in the current state.
    pub fn energy(&self) -> f64 {
        self.scene
            .bodies
            .iter()
            .zip(&self.states)
            .map(|(b, s)| body_energy(&b.mass, s, &self.scene.gravity))
            .sum()
    }
    /// The last step taken, while the step problem in [`Simulation::mcp`] is still its own
    /// (`None` before the first step, after a step solved in substeps, and once the next step
    /// is prepared).
    pub fn last_step(&self) -> Option<&LastStep> {
        self.last.as_ref()
    }

    /// Replaces the current state of body `b` (its quaternion is normalised), for example to
    /// restart a step from a perturbed state (finite differences, model-predictive control).
    /// Unlike building a simulation it accepts a state that penetrates a half-space: the next
    /// step's contact conditions resolve it. The warm start of the next step keeps the previous
    /// solution's impulses.
    pub fn set_state(&mut self, b: usize, state: BodyState) -> Result<(), SceneError> {
        let name = match self.scene.bodies.get(b) {
            Some(body) => body.name.clone(),
            None => {
                return Err(SceneError::Parameter {
                    what: format!("body index {b}"),
                    value: b as f64,
                    hint: "the body index must be less than the number of bodies",
                });
            }
        };
        let finite = state
            .x
            .iter()
            .chain(&state.v)
            .chain(&state.w)
            .all(|v| v.is_finite());
        match crate::rotation::quat_normalize(&state.q) {
            Some(q) if finite => {
                self.states[b] = BodyState { q, ..state };
                self.kept.history.clear();
                self.start_value = false;
                Ok(())
            }
            _ => Err(SceneError::Parameter {
                what: format!("{name}.state"),
                value: f64::NAN,
                hint: "the state must be finite with a non-zero quaternion",
            }),
        }
    }

    /// The value of parameter `p` in the scene being simulated.
    pub fn param(&self, p: Param) -> Result<f64, ParamError> {
        p.get(&self.scene)
    }

    /// Sets parameter `p` (checked as the scene's own values are) in the scene and in the step
    /// problem's data block that holds it, in place: no rebuild, the backends' analyses stay
    /// valid. μ, e_t, e_o, e_r, masses and inertias act from the next step; a constant load from
    /// the next step (its `wrench` data are written per step); an initial-state parameter at the
    /// next [`Simulation::reset`].
    pub fn set_param(&mut self, p: Param, value: f64) -> Result<(), ParamError> {
        p.set(&mut self.scene, value)?;
        if let Some((d, values)) = p.data(&self.scene, &self.handles) {
            // The handles come from this step problem, and the values have its block's size.
            self.mcp
                .set_data(d, &values)
                .map_err(|e| ParamError::Name(format!("parameter {p}: {e}")))?;
        }
        if p.is_initial_state() {
            self.initial_changed = true;
        }
        // The step problem no longer holds the last step's data.
        self.last = None;
        self.kept.history.clear();
        self.start_value = false;
        Ok(())
    }

    /// Chooses the warm start of the next steps ([`WarmStart`]; `Extrapolated` by default).
    pub fn set_warm_start(&mut self, warm_start: WarmStart) {
        self.warm_start = warm_start;
    }

    /// Sets the iteration budget within which each start of a step (the warm start, then the
    /// formulation's retry starts) is first solved, before each is solved again with the
    /// backend's full limits when none solved the step within it (`Some(20)` by default,
    /// `docs/latency.md#budgeted-starts-newtons-long-steps-branch-wip-hardsteps-issue-18`). `None`: each start
    /// is solved with the full limits at once, as before the budgets (an extrapolated warm
    /// start keeps its own budget). Backends that do not honour budgets
    /// ([`McpSolver::set_iteration_budget`]) always solve each start once, fully.
    pub fn set_start_budget(&mut self, budget: Option<usize>) {
        self.start_budget = budget;
    }

    /// The warm start of the next steps ([`Simulation::set_warm_start`]).
    pub fn warm_start(&self) -> WarmStart {
        self.warm_start
    }

    /// Sets the values of data block `d` of the step problem (a user force's or term's
    /// parameters) between steps.
    pub fn set_data(&mut self, d: DataId, values: &[f64]) -> Result<(), ModelError> {
        self.mcp.set_data(d, values)?;
        self.last = None;
        self.kept.history.clear();
        self.start_value = false;
        Ok(())
    }

    /// Back to t = 0 and the scene's initial states, with the parameters set since: the first
    /// step's starting point again, the step problem kept (built again only when an
    /// initial-state parameter changed).
    pub fn reset(&mut self) -> Result<(), SceneError> {
        self.states = initial_states(&self.scene)?;
        self.step = 0;
        self.t = 0.0;
        self.last = None;
        if self.initial_changed {
            self.rebuild(false)?;
            self.initial_changed = false;
        }
        self.start()
    }

    /// Once per step, before its checkpoint: the formulation's [`StepFormulation::begin_step`],
    /// with one rebuild when it asks for it.
    fn begin_step(&mut self) -> Result<(), SceneError> {
        self.start_value = false;
        for pass in 0..2 {
            let ctx = StepContext {
                scene: &self.scene,
                states: &self.states,
                t0: self.t,
                h: self.scene.h,
                step: self.step + 1,
                history: None,
                wrenches: &[],
            };
            match self
                .formulation
                .begin_step(&ctx, &mut self.mcp, &mut self.z)?
            {
                Prepared::Ready => return Ok(()),
                Prepared::Rebuild if pass == 0 => self.rebuild(true)?,
                Prepared::Rebuild => break,
            }
        }
        Err(SceneError::NotApplicable {
            formulation: self.formulation.name().to_string(),
            step: Some(self.step + 1),
            reason: "the formulation asked for a rebuild of the step problem it had just built"
                .into(),
        })
    }

    /// Whether a step solved by `solver` may start from an extrapolated warm start: the setting
    /// ([`WarmStart::Extrapolated`]) and a backend whose answer does not depend on its start
    /// beyond round-off ([`McpSolver::converges_to_round_off`]); with any other backend the
    /// steps are main's, bit for bit (PATH without its polish stops anywhere within its
    /// tolerance, and a different start moved its results by up to 3.3e-9).
    fn extrapolates(&self, solver: &dyn McpSolver) -> bool {
        self.warm_start != WarmStart::Previous && solver.converges_to_round_off()
    }

    /// Sets the data of the span `[t0, t0 + h]` from `start` (the states at its start) and the
    /// warm start in `z`.
    fn prepare_span(&mut self, start: &[BodyState], t0: f64, h: f64) -> Result<(), SceneError> {
        // Its storage serves the next `LastStep`.
        if let Some(last) = self.last.take() {
            self.kept.last = Some(last);
        }
        // The loads at `t0`, once for the span's data, its starts and its `LastStep`.
        let mut wrenches = std::mem::take(&mut self.kept.span_wrenches);
        wrenches.clear();
        wrenches.extend(self.scene.bodies.iter().map(|b| b.load.at(t0)));
        let ctx = span_context(
            (&self.scene, self.warm_start, &self.kept.history),
            self.formulation.origin(),
            self.step + 1,
            (start, t0, h, &wrenches),
            self.z.len(),
        );
        self.start_value = false;
        let data = self.formulation.update_data(&ctx, &mut self.mcp);
        if data.is_ok() {
            self.formulation.warm_start(&ctx, &self.mcp, &mut self.z);
            self.start_value = true;
        }
        self.kept.span_wrenches = wrenches;
        data
    }

    /// Prepares the next step: the formulation's per-step adjustments, the step's data
    /// ([`BlockMcp::set_data`]: the problem and its pattern are unchanged) and the warm start.
    /// After this, [`Simulation::mcp`] and [`Simulation::z`] are the step problem and its
    /// starting point ([`Simulation::solve_step_problem`] solves it as a step would).
    pub fn prepare_step(&mut self) -> Result<(), SceneError> {
        self.begin_step()?;
        let start = self.states.clone();
        self.prepare_span(&start, self.t, self.scene.h)
    }

    /// Solves the prepared step problem from `z0` with `solver` as a step does (through the
    /// formulation's structural view), without retries and without taking the result.
    pub fn solve_step_problem(
        &self,
        solver: &mut dyn McpSolver,
        z0: &[f64],
    ) -> Result<Solution, SolveError> {
        solver.solve(&self.step_problem(), z0)
    }

    /// The prepared step problem as every backend is given it: [`Simulation::mcp`] with the
    /// formulation's structural view (structure-exploiting backends, the conic one, need it).
    pub fn step_problem(&self) -> StepProblem<'_> {
        StepProblem {
            mcp: &self.mcp,
            structure: self.formulation.structure(),
            scales: self.formulation.scales_usage(self.mcp.dim()),
            friction: self.handles.friction,
            start: self
                .start_value
                .then(|| self.formulation.warm_start_value())
                .flatten(),
            start_phi: self
                .start_value
                .then(|| self.formulation.warm_start_fb_vector())
                .flatten(),
        }
    }

    /// Solves the prepared span with `solver` from the warm start in `z`, then from each of the
    /// formulation's deterministic second starts ([`StepFormulation::retry_start`],
    /// `docs/decisions.md#retry-from-the-active-contact-guess`) until one solves it. On success
    /// `z` holds the solution's start, and the summary counts the retries; on failure `z` is
    /// left at the warm start and the error carries the best attempt.
    fn solve_prepared(
        &mut self,
        start: &[BodyState],
        t0: f64,
        h: f64,
        solver: &mut dyn McpSolver,
    ) -> Result<Solution, SolveError> {
        let mut sol = Solution::default();
        self.solve_prepared_into(start, t0, h, solver, &mut sol)
            .map(|()| sol)
    }

    /// [`Simulation::solve_prepared`] into `out` ([`McpSolver::solve_into`]).
    fn solve_prepared_into(
        &mut self,
        start: &[BodyState],
        t0: f64,
        h: f64,
        solver: &mut dyn McpSolver,
        out: &mut Solution,
    ) -> Result<(), SolveError> {
        // Two passes over the starts: each first within a budget, since a start that misses
        // (an extrapolation past an event the last steps did not announce, a warm start on the
        // wrong side of a kink) costs hundreds of iterations where another start costs a few;
        // then each with the backend's full limits, so that every step solved before the
        // budgets is still solved (`docs/latency.md#budgeted-starts-newtons-long-steps-branch-wip-hardsteps-issue-18`).
        // Every attempt's iterations are counted in the summary of the solve that succeeds,
        // and every attempt after the first as a retry.
        let extrapolated = self.formulation.warm_start_extrapolated();
        let first_budget = if extrapolated {
            Some(extrapolation_budget(self.kept.history.recent_iterations()))
        } else {
            self.start_budget
        };
        let budgeted = first_budget.is_some() && solver.set_iteration_budget(first_budget);
        // A start extrapolated beyond the quadratic is a prediction: the backend returns it as
        // it stands only at round-off, else polishes it (`McpSolver::set_start_predicted`).
        // Orders 1–2 continue polynomial motion to round-off (A1's constant deceleration: its
        // starts at 1–8 ulps of `‖z‖∞` polished cost 29 → 39 Newton iterations over 50 steps)
        // and are kept as they were; the retry starts are not predictions.
        let predicted = extrapolated
            && self.formulation.warm_start_order() > QUADRATIC
            && solver.set_start_predicted(true);
        self.kept.predicted = predicted;
        let first = solver.solve_into(&self.step_problem(), &self.z, out);
        if budgeted {
            solver.set_iteration_budget(None);
        }
        if predicted {
            solver.set_start_predicted(false);
        }
        let mut failure = match first {
            Ok(()) => return Ok(()),
            Err(e) => e,
        };
        let mut spent = attempt_iterations(&failure);
        let warm = self.z.clone();
        let mut retries = 0;
        let mut tried: Vec<Vec<f64>> = Vec::new();
        // The budgeted pass (when the backend honours budgets), then the full one; the first
        // start is taken again with the full limits unless it was extrapolated (whose full
        // solve the plain warm start, the first retry start, replaces).
        let both = [self.start_budget, None];
        let passes = match self.start_budget {
            Some(_) if budgeted => &both[..],
            _ => &both[1..],
        };
        // A first start that stopped short of its budget (stagnated, or failed its line search)
        // is solved at once with the full limits, as before the budgets: its later attempts
        // (the minimum-norm, non-monotone and smoothing restarts) are cheap there and find
        // the solution to round-off, where another start may stop at the tolerance (D5 step 24:
        // 1.8e-15 from the warm start in 11 iterations, 4.4e-11 from the active-contact guess).
        let early = budgeted && !extrapolated && first_budget.is_some_and(|b| spent < b);
        for (pass, &budget) in passes.iter().enumerate() {
            solver.set_iteration_budget(budget);
            let retake = if early { pass == 0 } else { pass == 1 };
            if retake && budgeted && !extrapolated {
                self.z.copy_from_slice(&warm);
                retries += 1;
                solver.set_iteration_budget(None);
                match solver.solve_into(&self.step_problem(), &self.z, out) {
                    Ok(()) => return finish(out, retries, spent),
                    Err(e) => {
                        solver.set_iteration_budget(budget);
                        spent += attempt_iterations(&e);
                        failure = better_failure(failure, e);
                    }
                }
            }
            let mut attempt = 0;
            tried.clear();
            tried.push(warm.clone());
            loop {
                let ctx = span_context(
                    (&self.scene, self.warm_start, &self.kept.history),
                    self.formulation.origin(),
                    self.step + 1,
                    (start, t0, h, &self.kept.span_wrenches),
                    self.z.len(),
                );
                if !self
                    .formulation
                    .retry_start(attempt, &ctx, &self.mcp, &mut self.z)
                {
                    break;
                }
                attempt += 1;
                // A start already taken in this pass fails again the same way (the solve is
                // deterministic): before the first step has history the active-contact guess
                // can be the warm start itself. Only with budgets: a backend without them keeps
                // the driver's earlier sequence, every start solved once.
                if budgeted && tried.iter().any(|t| t[..] == self.z[..]) {
                    continue;
                }
                tried.push(self.z.clone());
                retries += 1;
                match solver.solve_into(&self.step_problem(), &self.z, out) {
                    Ok(()) => {
                        solver.set_iteration_budget(None);
                        return finish(out, retries, spent);
                    }
                    Err(e) => {
                        spent += attempt_iterations(&e);
                        failure = better_failure(failure, e);
                    }
                }
            }
        }
        solver.set_iteration_budget(None);
        if let SolveError::NotConverged { best } = &mut failure {
            best.summary.iterations = spent;
        }
        self.z.copy_from_slice(&warm);
        Err(failure)
    }

    /// Takes the solution `z` of the span that started from `start`: the end-of-span states
    /// become the current states. When the formulation refuses the solution, the caller restores
    /// its checkpoint.
    fn take(&mut self, start: &[BodyState], t0: f64, h: f64, z: &[f64]) -> Result<(), SceneError> {
        let ctx = StepContext {
            scene: &self.scene,
            states: start,
            t0,
            h,
            step: self.step + 1,
            history: None,
            wrenches: &[],
        };
        self.z.copy_from_slice(z);
        self.formulation
            .read_out(&ctx, &self.mcp, &mut self.z, &mut self.states)
    }

    /// Advances one step with `solver` and no fallback. A step that does not converge is
    /// reported as failed and the bodies keep their state at its start (`docs/fallbacks.md`);
    /// the caller decides whether to go on. An error means the step could not be set up or its
    /// solution was refused (a formulation whose assumptions stopped holding).
    pub fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        self.step_with(solver, &mut Fallbacks::none())
    }

    /// [`Simulation::step`] into `record`, whose storage is reused: with a backend that
    /// implements [`McpSolver::solve_into`] without allocating (Newton), a warm step of a
    /// single-body scene allocates nothing once the first steps have grown the storage
    /// (`docs/latency.md#allocations`). The same step and record as `step`, bit for bit; on an
    /// error `record`'s contents are unspecified.
    pub fn step_into(
        &mut self,
        solver: &mut dyn McpSolver,
        record: &mut StepRecord,
    ) -> Result<(), SceneError> {
        self.step_with_into(solver, &mut Fallbacks::none(), record)
    }

    /// Advances one step with `solver`; when it cannot solve the step, with the `fallbacks`, as
    /// far as the formulation's [`Capabilities`] allow: each fallback backend on the same step
    /// problem, then substeps (bisecting only the pieces that fail, down to
    /// `h / 2^max_halvings`), each piece tried with `solver` and then each fallback backend.
    /// Every accepted piece passed the backend's natural-residual test. When everything fails
    /// the step is reported as failed ([`StepMethod::Failed`]) and the bodies keep their state
    /// at its start.
    pub fn step_with(
        &mut self,
        solver: &mut dyn McpSolver,
        fallbacks: &mut Fallbacks,
    ) -> Result<StepRecord, SceneError> {
        let mut record = StepRecord::default();
        self.step_with_into(solver, fallbacks, &mut record)?;
        Ok(record)
    }

    /// [`Simulation::step_with`] into `record` (as [`Simulation::step_into`]; the fallbacks
    /// allocate).
    pub fn step_with_into(
        &mut self,
        solver: &mut dyn McpSolver,
        fallbacks: &mut Fallbacks,
        record: &mut StepRecord,
    ) -> Result<(), SceneError> {
        let (t0, h) = (self.t, self.scene.h);
        let started = Instant::now();
        // Before the checkpoint: what the formulation adjusts once per step stays put within the
        // step and its fallbacks.
        self.begin_step()?;
        let mut start = std::mem::take(&mut self.kept.checkpoint);
        start.0.clone_from(&self.states);
        start.1.clone_from(&self.z);
        let mut solution = std::mem::take(&mut self.kept.solution);
        let taken = self.advance(
            &start,
            (t0, h),
            started,
            (solver, fallbacks),
            &mut solution,
            record,
        );
        self.kept.checkpoint = start;
        self.kept.solution = solution;
        taken
    }

    /// The step of [`Simulation::step_with_into`] from its checkpoint `start`, the backend's
    /// result in `solution`.
    fn advance(
        &mut self,
        start: &Checkpoint,
        (t0, h): (f64, f64),
        started: Instant,
        (solver, fallbacks): (&mut dyn McpSolver, &mut Fallbacks),
        solution: &mut Solution,
        record: &mut StepRecord,
    ) -> Result<(), SceneError> {
        if !self.extrapolates(solver) {
            self.kept.history.clear();
        }
        self.prepare_span(&start.0, t0, h)?;
        // The step's loads for its `LastStep` (those of the span just prepared, at `t0`).
        self.kept.wrenches.clone_from(&self.kept.span_wrenches);
        // `summary`: the record's when it is not `solution`'s; `whole`: `solution` solved the
        // whole step in one piece.
        let (summary, method, whole): (Option<Summary>, StepMethod, bool) =
            match self.solve_prepared_into(&start.0, t0, h, solver, solution) {
                Ok(()) => {
                    self.take_or_restore(start, t0, h, &solution.z)?;
                    (None, StepMethod::Direct, true)
                }
                Err(SolveError::InvalidProblem(msg)) => {
                    self.restore(start);
                    return Err(SceneError::Model(ModelError::Dimension(msg)));
                }
                Err(SolveError::NotConverged { best }) => {
                    let caps = self.formulation.capabilities();
                    let allowed = (caps.fallback_backends, caps.substeps);
                    let rescued = rescue(self, start, solver, fallbacks, (t0, h), allowed)
                        .inspect_err(|_| self.restore(start))?;
                    match rescued {
                        Some((summary, method, Some(sol))) => {
                            *solution = sol;
                            (Some(summary), method, true)
                        }
                        Some((summary, method, None)) => (Some(summary), method, false),
                        // Exhausted: never take an infeasible iterate; keep the last feasible
                        // state, the one at the start of the step.
                        None => (Some(best.summary), StepMethod::Failed, false),
                    }
                }
            };
        let converged = method.solved();
        self.step += 1;
        self.t = self.step as f64 * self.scene.h;
        // The step problem in `mcp` is this step's own only when it was solved in one piece.
        if whole {
            let mut last = self.kept.last.take().unwrap_or_else(|| LastStep {
                step: 0,
                t_start: 0.0,
                start: Vec::new(),
                wrenches: Vec::new(),
                z: Vec::new(),
                converged: false,
            });
            last.step = self.step;
            last.t_start = t0;
            last.start.clone_from(&start.0);
            std::mem::swap(&mut last.wrenches, &mut self.kept.wrenches);
            last.z.clone_from(&solution.z);
            last.converged = converged;
            self.last = Some(last);
        }
        // A smooth step: solved by `solver` from the warm start itself, in at least one and at
        // most `SMOOTH_ITERATIONS` iterations. A warm start returned as it was is not
        // extrapolated from: at rest the extrapolation of round-off, taken unrefined step after
        // step, drifts (the T-bar at rest, ω off by up to 1.7e-12 after 8 steps of 0 iterations;
        // its residual stays below the tolerance). A step that took more iterations was an
        // event (an impact settling, a change of feature), which the next steps do not continue.
        // Except a predicted start returned as it stood (`Kept::predicted`): the backend took it
        // only at round-off, an answer as refined as a polished one; clearing the history after
        // it cost the next steps their order-5 start (PATH's `056_union_slide`: 0, 5, 3, 2, 1
        // iterations while the history refilled).
        let retried = (solution.summary.counters)
            .get(ecp_model::Counter::Retries)
            .is_some_and(|n| n > 0);
        let iterations = solution.summary.iterations;
        let easy = (1..=SMOOTH_ITERATIONS).contains(&iterations)
            || (iterations == 0 && self.kept.predicted);
        if self.extrapolates(solver) && whole && method == StepMethod::Direct && !retried && easy {
            let origin = self.formulation.origin();
            self.kept.history.push(&self.z, origin, iterations);
        } else {
            self.kept.history.clear();
        }
        // The step's time: all of it but its record (the contact records and the energy are
        // outputs, `docs/outputs.md#summaryjson`).
        let solve_us = started.elapsed().as_secs_f64() * 1e6;
        let summary = summary.as_ref().unwrap_or(&solution.summary);
        self.record_into(summary, converged, solve_us, method, record);
        Ok(())
    }

    /// [`Simulation::take`], restoring the step's checkpoint when the formulation refuses the
    /// solution.
    fn take_or_restore(
        &mut self,
        start: &Checkpoint,
        t0: f64,
        h: f64,
        z: &[f64],
    ) -> Result<(), SceneError> {
        self.take(&start.0, t0, h, z)
            .inspect_err(|_| self.restore(start))
    }

    /// Takes one step with `solver` and takes its point **whether or not it solves the step
    /// problem**: for studying a relaxed model (the conic backend's Anitescu mode) whose points
    /// are not solutions of this one. The record says so: `converged` is the backend's verdict
    /// and a point that failed it is marked [`StepMethod::Unchecked`]. The run driver never
    /// calls this.
    pub fn step_unchecked(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        let (t0, h) = (self.t, self.scene.h);
        let started = Instant::now();
        self.begin_step()?;
        let start = self.checkpoint();
        if !self.extrapolates(solver) {
            self.kept.history.clear();
        }
        self.prepare_span(&start.0, t0, h)?;
        let (z, summary, method) = match self.solve_step_problem(solver, &self.z) {
            Ok(sol) => (sol.z, sol.summary, StepMethod::Direct),
            Err(SolveError::NotConverged { best }) => (best.z, best.summary, StepMethod::Unchecked),
            Err(SolveError::InvalidProblem(msg)) => {
                return Err(SceneError::Model(ModelError::Dimension(msg)));
            }
        };
        self.take_or_restore(&start, t0, h, &z)?;
        self.kept.history.clear();
        self.step += 1;
        self.t = self.step as f64 * self.scene.h;
        let solve_us = started.elapsed().as_secs_f64() * 1e6;
        Ok(self.record(summary, method.solved(), solve_us, method))
    }

    /// Runs the remaining steps with `solver`, calling `on_step` after each (outputs can be
    /// written as the run goes); stops early when `on_step` returns `false`. Returns the number
    /// of steps that did not converge.
    pub fn run(
        &mut self,
        solver: &mut dyn McpSolver,
        on_step: impl FnMut(&StepRecord) -> bool,
    ) -> Result<usize, SceneError> {
        self.run_with(solver, &mut Fallbacks::none(), on_step)
    }

    /// [`Simulation::run`] with fallbacks ([`Simulation::step_with`]).
    pub fn run_with(
        &mut self,
        solver: &mut dyn McpSolver,
        fallbacks: &mut Fallbacks,
        mut on_step: impl FnMut(&StepRecord) -> bool,
    ) -> Result<usize, SceneError> {
        let mut failed = 0;
        let mut rec = StepRecord::default();
        while !self.finished() {
            self.step_with_into(solver, fallbacks, &mut rec)?;
            failed += usize::from(!rec.converged);
            if !on_step(&rec) {
                break;
            }
        }
        Ok(failed)
    }

    /// The record of the step just taken, from the current states and `z`.
    fn record(
        &self,
        summary: Summary,
        converged: bool,
        solve_us: f64,
        method: StepMethod,
    ) -> StepRecord {
        let mut record = StepRecord::default();
        self.record_into(&summary, converged, solve_us, method, &mut record);
        record
    }

    /// [`Simulation::record`] into `out`, reusing its storage.
    fn record_into(
        &self,
        summary: &Summary,
        converged: bool,
        solve_us: f64,
        method: StepMethod,
        out: &mut StepRecord,
    ) {
        out.contacts.clear();
        self.formulation.contact_records(
            &self.scene,
            &self.states,
            converged,
            &self.mcp,
            &self.z,
            &mut out.contacts,
        );
        out.pairs.clear();
        self.formulation
            .pair_records(&self.scene, converged, &self.mcp, &self.z, &mut out.pairs);
        out.step = self.step;
        out.t = self.t;
        out.bodies.clone_from(&self.states);
        out.energy = self.energy();
        out.summary.clone_from(summary);
        out.converged = converged;
        out.solve_us = solve_us;
        out.method = method;
    }
}

impl Spans for Simulation {
    type Checkpoint = Checkpoint;

    fn checkpoint(&self) -> Self::Checkpoint {
        (self.states.clone(), self.z.clone())
    }

    fn restore(&mut self, checkpoint: &Self::Checkpoint) {
        self.states.copy_from_slice(&checkpoint.0);
        self.z.copy_from_slice(&checkpoint.1);
    }

    fn solve_span(
        &mut self,
        solver: &mut dyn McpSolver,
        t0: f64,
        h: f64,
    ) -> Result<Option<Solution>, SceneError> {
        if !self.extrapolates(solver) {
            self.kept.history.clear();
        }
        let start = self.states.clone();
        self.prepare_span(&start, t0, h)?;
        match self.solve_prepared(&start, t0, h, solver) {
            Ok(sol) => {
                self.take(&start, t0, h, &sol.z)?;
                Ok(Some(sol))
            }
            Err(_) => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    //! The driver on real step problems: reset and parameters against fresh simulations, the
    //! fallbacks with a backend that fails on purpose, and a rebuild asked by a formulation.

    use ecp_model::{Mcp, McpSolver, Solution, SolveError, Summary, Termination};
    use ecp_solvers::newton::{NewtonSettings, NewtonSolver};

    use super::*;
    use crate::ecp::EcpContacts;
    use crate::point::PointContacts;
    use crate::record::ContactRecord;
    use crate::scenarios;
    use crate::step::{InertiaEntry, StateComponent};

    fn newton() -> Box<dyn McpSolver> {
        Box::new(NewtonSolver::new(NewtonSettings::default()))
    }

    fn run(sim: &mut Simulation, steps: usize) -> Vec<StepRecord> {
        let mut solver = newton();
        (0..steps)
            .map(|_| sim.step(solver.as_mut()).unwrap_or_else(|e| panic!("{e}")))
            .collect()
    }

    /// Bit for bit: states, contacts and the solver's iterations.
    fn assert_same(a: &[StepRecord], b: &[StepRecord]) {
        assert_eq!(a.len(), b.len());
        for (ra, rb) in a.iter().zip(b) {
            assert_eq!(ra.bodies, rb.bodies, "step {}", ra.step);
            assert_eq!(ra.contacts, rb.contacts, "step {}", ra.step);
            assert_eq!(
                ra.summary.iterations, rb.summary.iterations,
                "step {}",
                ra.step
            );
            assert!(ra.converged && rb.converged);
        }
    }

    #[test]
    fn reset_replays_the_run_bit_for_bit() {
        let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
        let first = run(&mut sim, 15);
        sim.reset().unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((sim.steps_taken(), sim.time()), (0, 0.0));
        assert!(sim.last_step().is_none());
        assert_same(&first, &run(&mut sim, 15));
    }

    #[test]
    fn parameters_set_in_place_give_the_run_of_a_fresh_simulation() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
        run(&mut sim, 3);
        let pattern = Arc::clone(sim.mcp().jacobian_pattern());
        let ixy = Param::Inertia {
            body: 0,
            entry: InertiaEntry::Xy,
        };
        let changes = [
            (Param::Mu, 0.2),
            (Param::Er, 0.05),
            (Param::Mass { body: 0 }, 12.0),
            (ixy, 0.01),
            (
                Param::Load {
                    body: 0,
                    component: 0,
                },
                5.0,
            ),
        ];
        let mut scene = scenarios::a1_sliding();
        for (p, v) in changes {
            sim.set_param(p, v).unwrap_or_else(|e| panic!("{e}"));
            p.set(&mut scene, v).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(sim.param(p), Ok(v));
        }
        sim.reset().unwrap_or_else(|e| panic!("{e}"));
        // The same step problem: no rebuild, the backends' analyses stay valid.
        assert!(Arc::ptr_eq(&pattern, sim.mcp().jacobian_pattern()));
        let mut fresh = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
        assert_same(&run(&mut fresh, 10), &run(&mut sim, 10));
        // A refused value changes nothing.
        assert!(sim.set_param(Param::Mu, -1.0).is_err());
        assert_eq!(sim.param(Param::Mu), Ok(0.2));
    }

    #[test]
    fn an_initial_state_parameter_takes_effect_at_reset() {
        let vx = Param::initial(0, StateComponent::Velocity(0));
        for name in ["hull", "union", "point"] {
            let f = |s| crate::registry::FormulationRegistry::builtin().create(s);
            let builder =
                |scene| SimulationBuilder::new(scene, f(name).unwrap_or_else(|e| panic!("{e}")));
            let mut sim = builder(scenarios::a1_sliding())
                .build()
                .unwrap_or_else(|e| panic!("{e}"));
            sim.set_param(vx, 0.5).unwrap_or_else(|e| panic!("{e}"));
            // Not before the reset: the run in progress keeps its state.
            assert_eq!(sim.state(0).v.x, 1.0);
            sim.reset().unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(sim.state(0).v.x, 0.5);
            let mut scene = scenarios::a1_sliding();
            scene.bodies[0].initial.v.x = 0.5;
            let mut fresh = builder(scene).build().unwrap_or_else(|e| panic!("{e}"));
            assert_same(&run(&mut fresh, 5), &run(&mut sim, 5));
        }
    }

    /// Newton, except that its first `fail` solves are reported as not converged (with Newton's
    /// own point as the best iterate, so a driver that took it would move).
    struct Flaky {
        inner: NewtonSolver,
        fail: usize,
        calls: usize,
    }

    impl Flaky {
        fn new(fail: usize) -> Self {
            Flaky {
                inner: NewtonSolver::new(NewtonSettings::default()),
                fail,
                calls: 0,
            }
        }
    }

    impl McpSolver for Flaky {
        fn name(&self) -> &str {
            "flaky"
        }
        fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
            self.calls += 1;
            let result = self.inner.solve(mcp, z0);
            if self.calls > self.fail {
                return result;
            }
            let sol = result?;
            Err(SolveError::NotConverged {
                best: Box::new(Solution {
                    z: sol.z,
                    summary: Summary {
                        termination: Termination::MaxIterations,
                        ..sol.summary
                    },
                }),
            })
        }
    }

    #[test]
    fn a_fallback_backend_solves_the_same_step() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
        let mut reference =
            Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
        let mut flaky = Flaky::new(usize::MAX);
        let mut fallbacks = Fallbacks::new(vec![newton()]);
        let rec = sim
            .step_with(&mut flaky, &mut fallbacks)
            .unwrap_or_else(|e| panic!("{e}"));
        let plain = reference
            .step(newton().as_mut())
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(rec.converged);
        assert_eq!(rec.method, StepMethod::Backend("newton".into()));
        assert!((rec.bodies[0].v - plain.bodies[0].v).amax() <= 1e-12);
        // The step problem in the simulation is the step's own: sensitivities can use it.
        assert!(sim.last_step().is_some());
    }

    /// The first two solves (the step and its retry from the active-contact guess: A1 rests on
    /// the ground) fail; the halves then solve — with the hull and the point formulation.
    #[test]
    fn substeps_reach_the_end_of_the_step_with_the_physics_of_a_shorter_step() {
        let scene = scenarios::a1_sliding();
        let h = scene.h;
        for name in ["hull", "point"] {
            let make = |scene: Scene| {
                let f = crate::registry::FormulationRegistry::builtin()
                    .create(name)
                    .unwrap_or_else(|e| panic!("{e}"));
                SimulationBuilder::new(scene, f)
                    .build()
                    .unwrap_or_else(|e| panic!("{e}"))
            };
            let mut sim = make(scene.clone());
            let mut flaky = Flaky::new(2);
            let mut fallbacks = Fallbacks {
                backends: Vec::new(),
                max_halvings: 3,
            };
            let rec = sim
                .step_with(&mut flaky, &mut fallbacks)
                .unwrap_or_else(|e| panic!("{e}"));
            assert!(rec.converged);
            assert_eq!(
                rec.method,
                StepMethod::Substeps {
                    pieces: 2,
                    finest: 2
                },
                "{name}"
            );
            assert!((rec.t - h).abs() < 1e-15);
            // Two plain steps of h/2 from the same state: the same end state.
            let mut half = make(Scene {
                h: 0.5 * h,
                ..scene.clone()
            });
            let mut solver = newton();
            half.step(solver.as_mut()).unwrap_or_else(|e| panic!("{e}"));
            let two = half.step(solver.as_mut()).unwrap_or_else(|e| panic!("{e}"));
            let (a, b) = (rec.bodies[0], two.bodies[0]);
            assert!(
                (a.x - b.x).amax() <= 1e-12,
                "{name}: {:?} vs {:?}",
                a.x,
                b.x
            );
            assert!(
                (a.v - b.v).amax() <= 1e-10,
                "{name}: {:?} vs {:?}",
                a.v,
                b.v
            );
            // A1 decelerates by μ g per unit time: v after h is 1 − μ g h.
            assert!((a.v.x - (1.0 - 0.3 * 9.8 * h)).abs() <= 1e-9, "{name}");
            // No single step problem holds this step: no sensitivities from it.
            assert!(sim.last_step().is_none());
        }
    }

    #[test]
    fn an_exhausted_step_fails_and_keeps_the_state_at_its_start() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
        let start = sim.state(0);
        let mut flaky = Flaky::new(usize::MAX);
        let mut fallbacks = Fallbacks {
            backends: Vec::new(),
            max_halvings: 2,
        };
        let rec = sim
            .step_with(&mut flaky, &mut fallbacks)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(!rec.converged);
        assert_eq!(rec.method, StepMethod::Failed);
        assert_eq!(rec.bodies[0], start, "a failed iterate must never be taken");
        assert_eq!(sim.state(0), start);
        assert_eq!(sim.steps_taken(), 1);
        // The failed step's summary is the backend's best attempt, reported as not converged.
        assert!(!rec.summary.converged());
        // Solves tried: the step and its retry, then 2 halves, each halved again.
        assert!(flaky.calls >= 3);
        let next = sim
            .step(newton().as_mut())
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(next.converged);
    }

    #[test]
    fn a_plain_step_that_fails_keeps_the_state_too() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
        let start = sim.state(0);
        let rec = sim
            .step(&mut Flaky::new(usize::MAX))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(rec.method, StepMethod::Failed);
        assert_eq!(rec.bodies[0], start);
    }

    #[test]
    fn a_solved_retry_is_counted() {
        let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
        // The first solve fails; the retry from the active-contact guess solves the step.
        let rec = sim
            .step(&mut Flaky::new(1))
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(rec.method, StepMethod::Direct);
        assert_eq!(rec.summary.counter(ecp_model::Counter::Retries), Some(1));
        assert!((rec.bodies[0].v.x - (1.0 - 0.3 * 9.8 * 0.01)).abs() <= 1e-9);
    }

    /// The hull formulation, asking for a rebuild of its step problem at step 3.
    struct RebuildAtThree(EcpContacts);

    impl StepFormulation for RebuildAtThree {
        fn name(&self) -> &str {
            "rebuild-at-three"
        }
        fn capabilities(&self) -> Capabilities {
            self.0.capabilities()
        }
        fn build(
            &mut self,
            scene: &Scene,
            states: &[BodyState],
            problem: &mut Problem,
        ) -> Result<StepHandles, SceneError> {
            self.0.build(scene, states, problem)
        }
        fn contacts_per_body(&self) -> usize {
            self.0.contacts_per_body()
        }
        fn initial_guess(
            &mut self,
            ctx: &StepContext<'_>,
            mcp: &mut BlockMcp,
            z: &mut [f64],
        ) -> Result<(), SceneError> {
            self.0.initial_guess(ctx, mcp, z)
        }
        fn begin_step(
            &mut self,
            ctx: &StepContext<'_>,
            mcp: &mut BlockMcp,
            z: &mut [f64],
        ) -> Result<Prepared, SceneError> {
            self.0.begin_step(ctx, mcp, z)?;
            // Asked once: the driver calls begin_step again after the rebuild.
            let asked = ctx.step == 3 && mcp.data_blocks().iter().all(|d| d.name() != "marker");
            Ok(if asked {
                Prepared::Rebuild
            } else {
                Prepared::Ready
            })
        }
        fn update_data(
            &mut self,
            ctx: &StepContext<'_>,
            mcp: &mut BlockMcp,
        ) -> Result<(), SceneError> {
            self.0.update_data(ctx, mcp)
        }
        fn warm_start(&mut self, ctx: &StepContext<'_>, mcp: &BlockMcp, z: &mut [f64]) {
            self.0.warm_start(ctx, mcp, z)
        }
        fn warm_start_extrapolated(&self) -> bool {
            self.0.warm_start_extrapolated()
        }
        fn warm_start_order(&self) -> usize {
            self.0.warm_start_order()
        }
        fn retry_start(
            &mut self,
            attempt: usize,
            ctx: &StepContext<'_>,
            mcp: &BlockMcp,
            z: &mut [f64],
        ) -> bool {
            self.0.retry_start(attempt, ctx, mcp, z)
        }
        fn read_out(
            &mut self,
            ctx: &StepContext<'_>,
            mcp: &BlockMcp,
            z: &mut [f64],
            states: &mut [BodyState],
        ) -> Result<(), SceneError> {
            self.0.read_out(ctx, mcp, z, states)
        }
        fn contact_records(
            &self,
            scene: &Scene,
            states: &[BodyState],
            solved: bool,
            mcp: &BlockMcp,
            z: &[f64],
            out: &mut Vec<ContactRecord>,
        ) {
            self.0.contact_records(scene, states, solved, mcp, z, out)
        }
        fn structure(&self) -> Option<&dyn StepStructure> {
            self.0.structure()
        }
    }

    /// A term that only declares a data block named `marker`, so the rebuilt problem can be
    /// told from the first one.
    struct Marker {
        built: usize,
    }

    impl Term for Marker {
        fn name(&self) -> &str {
            "marker"
        }
        fn build(&mut self, _: &StepHandles, problem: &mut Problem) -> Result<(), SceneError> {
            self.built += 1;
            if self.built > 1 {
                problem.add_data_block(ecp_model::DataBlock::new("marker", [1.0]));
            }
            Ok(())
        }
    }

    /// A rebuild in the middle of a run carries the iterate over by name: the run is the run
    /// without it, bit for bit.
    #[test]
    fn a_rebuild_carries_the_iterate_over() {
        let scene = scenarios::desk();
        let mut plain = Simulation::new(scene.clone()).unwrap_or_else(|e| panic!("{e}"));
        let mut rebuilt =
            SimulationBuilder::new(scene, Box::new(RebuildAtThree(EcpContacts::hull())))
                .term(Marker { built: 0 })
                .build()
                .unwrap_or_else(|e| panic!("{e}"));
        let before = Arc::clone(rebuilt.mcp().jacobian_pattern());
        let records = run(&mut rebuilt, 6);
        assert!(!Arc::ptr_eq(&before, rebuilt.mcp().jacobian_pattern()));
        assert!(
            rebuilt
                .mcp()
                .data_blocks()
                .iter()
                .any(|d| d.name() == "marker")
        );
        assert_same(&run(&mut plain, 6), &records);
    }

    #[test]
    fn user_terms_need_the_bodies_unknowns() {
        let scene = scenarios::a1_sliding();
        let e = SimulationBuilder::new(scene, Box::new(crate::reduced::ReducedSliding::new()))
            .term(Marker { built: 0 })
            .build()
            .err()
            .map(|e| e.to_string());
        assert!(e.is_some_and(|m| m.contains("user forces and terms")));
        let points =
            SimulationBuilder::new(scenarios::a1_sliding(), Box::new(PointContacts::new()))
                .term(Marker { built: 0 })
                .build();
        assert!(points.is_ok());
    }
}
