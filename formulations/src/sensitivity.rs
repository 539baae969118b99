//! Step and trajectory sensitivities by implicit differentiation (`docs/fitting.md`).
//!
//! **Step sensitivities.** At a converged step of a [`Simulation`] of the hull formulation,
//! [`step_sensitivity`] returns the derivatives of the step's solution `z*` — ν, q (before the
//! renormalisation of Q), the ECPs, multipliers and impulses — and of the stored end-of-step
//! state (x, Q renormalised, v, ω) with respect to every **step input** ([`StepInput`]): the friction parameters μ, e_t, e_o,
//! e_r, each body's mass and body-frame inertia (six entries of the symmetric matrix,
//! [`InertiaEntry`]), its start-of-step state `x^u, Q^u, v^u, ω^u`, and the applied wrench of the
//! step (force and torque at the CM, world frame, evaluated at `t_u`). Each step input is a
//! component of a data block of the step problem ([`StepInput::data`],
//! `docs/model.md#data-blocks`), the residual blocks write their derivatives with respect to
//! those in their Jacobians ([`crate::blocks`]), `ecp_model::sensitivity` does
//! the implicit differentiation with the active set, and this module adds what only the
//! formulation knows:
//!
//! - a contact with `p_n` at its bound 0 (separated, or touching without force) has its friction
//!   impulses and σ **held** (`dz = 0`): the ellipsoid's cone forces `p_f = 0` and σ is
//!   undetermined there, while the linearised friction rows vanish
//!   (`docs/model.md#degenerate-cases`), so the implicit function theorem says nothing about them.
//!   Its closest-point unknowns (a1, a2, l, l_g) do not enter the motion rows then, and they need
//!   not be unique (a hull edge parallel to the plane): they are solved in a second stage, with the
//!   motion fixed, so a singular or inconsistent closest-point block cannot spoil the motion
//!   derivatives ([`Degeneracy::SeparatedGeometry`]);
//! - weakly active components (`p_n = 0` touching, `σ = 0` on the stick/slip boundary, a face
//!   multiplier 0 with the ECP on that face's edge) are held at their bound — the one-sided
//!   derivative of the branch that keeps the active set — and reported as [`Degeneracy`]s with
//!   the slope of their residual along that branch; those whose slope is 0 (the gap multiplier
//!   `l_g` of every closed contact) are two-sided and harmless;
//! - a singular reduced Jacobian gets the minimum-norm solution ([`SolveKind::Regularised`]),
//!   reported.
//!
//! **Exact for the hull formulation.** The code reads only the driver's handles (each body's ν
//! and q, each contact's normal impulse, friction and geometry unknowns), so any formulation
//! whose [`Capabilities`](crate::step::Capabilities) say it has sensitivities runs through it.
//! The union formulation's (`docs/model.md#union`) impulses are shared between the pieces and
//! not unique: its reduced Jacobian is singular, and inconsistent for the data columns
//! (`docs/decisions.md#sensitivities-the-hull-formulation-only`), so its derivatives are
//! least-squares guesses, reported as [`Degeneracy::Singular`] at every step, never passed off
//! as exact ([`SensitivitySupport::NotUnique`]). The reduced and point formulations have none
//! ([`SensitivitySupport::None`]: the reduced step holds no ν and q, and the point step's frozen
//! geometry is data derived from the start state); they are refused
//! ([`SensitivityError::Unsupported`]). User forces and terms take part: their unknowns are in
//! `dz`, and their data are columns on request ([`StepInput::Data`],
//! [`StepDifferentiator::differentiate_with`]).
//!
//! **Trajectory gradients.** [`trajectory_gradient`] runs a scene and chains the step
//! sensitivities of the state passed between steps (x, Q normalised, v, ω per body) for a scalar
//! [`TrajectoryLoss`] — [`ReferenceLoss`] (weighted squared differences to a reference
//! trajectory, every step) or [`TerminalPositionLoss`] (the CM at the last step) — and returns
//! `dL/dθ` for the scene parameters ([`Param`]) and `dL/dw_k` for the applied wrench of every
//! step, so any load parametrisation can be chained by the caller. Each step's Jacobian of the
//! next state with respect to the step inputs is formed once (one factorisation and one solve per
//! step input); [`GradientMode::Forward`] carries `dstate/dθ` forward (and, for the wrench
//! gradients, one tangent per past step: cost quadratic in the number of steps), and
//! [`GradientMode::Adjoint`] sweeps back once (cost linear in the steps and independent of the
//! number of parameters). Both give the same numbers to round-off. Every change of the active set
//! between steps and every one-sided or singular step is reported in
//! [`TrajectoryGradient::events`], never hidden.
//!
//! ```
//! use ecp_formulations::{scenarios, sensitivity::*};
//! use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
//!
//! // A1: dL/dμ of the final position of the sliding box after 10 steps.
//! let mut scene = scenarios::a1_sliding();
//! scene.duration = 0.1;
//! let mut solver = NewtonSolver::new(NewtonSettings::default());
//! let loss = TerminalPositionLoss { body: 0, target: nalgebra::Vector3::zeros(), weight: 1.0 };
//! let g = trajectory_gradient(&scene, &[Param::Mu], &loss, &mut solver, GradientMode::Adjoint)
//!     .unwrap();
//! // x_K = h Σ_k (1 − μ g h k) ⇒ dx_K/dμ = −g h² Σ k = −9.8e-4 · 55; L = x_K² + H².
//! let x = g.records.last().unwrap().bodies[0].x.x;
//! assert!((g.gradient[0] - 2.0 * x * (-9.8e-4 * 55.0)).abs() < 1e-9);
//! assert!(g.events.is_empty());
//! ```

use nalgebra::{Vector3, Vector4, Vector6};

use ecp_model::sensitivity::{
    ActiveSetOptions, ComponentStatus, ImplicitDerivative, ImplicitError, ReducedSystem, SolveKind,
    classify_into,
};
use ecp_model::{DataId, DataJacobianWork, Mcp, McpSolver, ModelError};

use crate::record::StepRecord;
use crate::scene::{BodyState, Scene, SceneError};
pub use crate::step::{InertiaEntry, Param, STATE_SIZE, StateComponent};
use crate::step::{ParamError, SensitivitySupport, Simulation};
/// Step inputs per body ([`StepInput`]): mass, inertia (6), x, Q, v, ω, force, torque.
pub const BODY_INPUTS: usize = 26;
/// Step inputs shared by all bodies: μ, e_t, e_o, e_r.
pub const FRICTION_INPUTS: usize = 4;

/// An input of one step: the columns of a [`StepSensitivity`].
///
/// Column layout ([`StepInput::index`]): μ, e_t, e_o, e_r, then per body
/// ([`BODY_INPUTS`] = 26): mass, the six inertia entries, the start-of-step position (3),
/// quaternion (4, the stored unit `Q^u`), velocity (3), angular velocity (3), and the applied
/// force (3) and torque (3) of the step.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StepInput {
    /// μ.
    Mu,
    /// e_t.
    Et,
    /// e_o.
    Eo,
    /// e_r.
    Er,
    /// Mass of a body.
    Mass {
        /// Body index.
        body: usize,
    },
    /// An entry of a body's inertia.
    Inertia {
        /// Body index.
        body: usize,
        /// Which entry.
        entry: InertiaEntry,
    },
    /// Start-of-step CM position `x^u`.
    Position {
        /// Body index.
        body: usize,
        /// 0, 1, 2.
        axis: usize,
    },
    /// Start-of-step quaternion `Q^u` (a component of the 4-vector).
    Orientation {
        /// Body index.
        body: usize,
        /// 0..4 for w, x, y, z.
        component: usize,
    },
    /// Start-of-step velocity `v^u`.
    Velocity {
        /// Body index.
        body: usize,
        /// 0, 1, 2.
        axis: usize,
    },
    /// Start-of-step angular velocity `ω^u`.
    AngularVelocity {
        /// Body index.
        body: usize,
        /// 0, 1, 2.
        axis: usize,
    },
    /// Applied force of the step (at the CM, world frame).
    Force {
        /// Body index.
        body: usize,
        /// 0, 1, 2.
        axis: usize,
    },
    /// Applied torque of the step (world frame).
    Torque {
        /// Body index.
        body: usize,
        /// 0, 1, 2.
        axis: usize,
    },
    /// Component `.1` of data block `.0` of the step problem, a user force's or term's
    /// parameter ([`crate::step::Force::with_data`]): a column only
    /// [`StepDifferentiator::differentiate_with`] adds, not a step input of trajectory
    /// gradients.
    Data(DataId, usize),
}

/// The step input parameter `p` is at every step, if it is one (the initial-state parameters
/// enter through the initial state instead).
fn step_input_of(p: &Param) -> Option<StepInput> {
    Some(match *p {
        Param::Mu => StepInput::Mu,
        Param::Et => StepInput::Et,
        Param::Eo => StepInput::Eo,
        Param::Er => StepInput::Er,
        Param::Mass { body } => StepInput::Mass { body },
        Param::Inertia { body, entry } => StepInput::Inertia { body, entry },
        Param::Load { body, component } if component < 3 => StepInput::Force {
            body,
            axis: component,
        },
        Param::Load { body, component } => StepInput::Torque {
            body,
            axis: component - 3,
        },
        _ => return None,
    })
}

impl StepInput {
    /// Column of this input for a scene of `bodies` bodies (`None` when out of range).
    pub fn index(&self, bodies: usize) -> Option<usize> {
        let (body, offset, len, k) = match *self {
            StepInput::Mu => return Some(0),
            StepInput::Et => return Some(1),
            StepInput::Eo => return Some(2),
            StepInput::Er => return Some(3),
            StepInput::Mass { body } => (body, 0, 1, 0),
            StepInput::Inertia { body, entry } => (body, 1, 6, entry.index()),
            StepInput::Position { body, axis } => (body, 7, 3, axis),
            StepInput::Orientation { body, component } => (body, 10, 4, component),
            StepInput::Velocity { body, axis } => (body, 14, 3, axis),
            StepInput::AngularVelocity { body, axis } => (body, 17, 3, axis),
            StepInput::Force { body, axis } => (body, 20, 3, axis),
            StepInput::Torque { body, axis } => (body, 23, 3, axis),
            StepInput::Data(..) => return None,
        };
        (body < bodies && k < len).then_some(FRICTION_INPUTS + BODY_INPUTS * body + offset + k)
    }

    /// The data block of `sim`'s step problem this input is a component of, and the component
    /// (`docs/model.md#data-blocks`); `None` for a body the scene does not have.
    pub fn data(&self, sim: &Simulation) -> Option<(DataId, usize)> {
        use crate::blocks::data::start;
        let h = sim.handles();
        let body_data = |b: usize| h.bodies.get(b).and_then(|b| b.data);
        Some(match *self {
            StepInput::Mu => (h.friction?, 0),
            StepInput::Et => (h.friction?, 1),
            StepInput::Eo => (h.friction?, 2),
            StepInput::Er => (h.friction?, 3),
            StepInput::Mass { body } => (body_data(body)?.mass, 0),
            StepInput::Inertia { body, entry } => (body_data(body)?.inertia, entry.index()),
            StepInput::Position { body, axis } => (body_data(body)?.start, start::X + axis),
            StepInput::Orientation { body, component } => {
                (body_data(body)?.start, start::Q + component)
            }
            StepInput::Velocity { body, axis } => (body_data(body)?.start, start::V + axis),
            StepInput::AngularVelocity { body, axis } => (body_data(body)?.start, start::W + axis),
            StepInput::Force { body, axis } => (body_data(body)?.wrench, axis),
            StepInput::Torque { body, axis } => (body_data(body)?.wrench, 3 + axis),
            StepInput::Data(block, component) => {
                let size = sim.mcp().data_blocks().get(block.0)?.size();
                (component < size).then_some((block, component))?
            }
        })
    }

    /// Every step input of a scene with `bodies` bodies, in column order.
    pub fn all(bodies: usize) -> Vec<StepInput> {
        let mut v = Vec::with_capacity(FRICTION_INPUTS + BODY_INPUTS * bodies);
        Self::all_into(bodies, &mut v);
        v
    }

    /// [`StepInput::all`] into `v` (cleared first).
    pub fn all_into(bodies: usize, v: &mut Vec<StepInput>) {
        v.clear();
        v.extend([StepInput::Mu, StepInput::Et, StepInput::Eo, StepInput::Er]);
        for body in 0..bodies {
            v.push(StepInput::Mass { body });
            v.extend(
                InertiaEntry::ALL
                    .iter()
                    .map(|&entry| StepInput::Inertia { body, entry }),
            );
            v.extend((0..3).map(|axis| StepInput::Position { body, axis }));
            v.extend((0..4).map(|component| StepInput::Orientation { body, component }));
            v.extend((0..3).map(|axis| StepInput::Velocity { body, axis }));
            v.extend((0..3).map(|axis| StepInput::AngularVelocity { body, axis }));
            v.extend((0..3).map(|axis| StepInput::Force { body, axis }));
            v.extend((0..3).map(|axis| StepInput::Torque { body, axis }));
        }
    }
}

/// Errors of the sensitivity computations.
#[derive(Debug, thiserror::Error)]
pub enum SensitivityError {
    /// No step to differentiate.
    #[error(
        "no step to differentiate: call step_sensitivity right after Simulation::step (prepare_step replaces the step's data)"
    )]
    NoStep,
    /// The step did not converge: its derivatives would be meaningless.
    #[error(
        "step {step} did not converge (natural residual {residual:.3e}); sensitivities need a converged step: try another solver (--solver path) or a smaller h"
    )]
    NotConverged {
        /// The step.
        step: usize,
        /// Its natural residual.
        residual: f64,
    },
    /// A step input names a body the scene does not have.
    #[error("{0}")]
    Param(String),
    /// A parameter name, index or value is wrong.
    #[error(transparent)]
    Parameter(#[from] ParamError),
    /// The formulation has no step sensitivities.
    #[error(
        "the {formulation} formulation has no step sensitivities (its step problem does not hold \
         each body's ν and q as unknowns, or its inputs are not all data blocks); use the hull \
         formulation, or finite differences"
    )]
    Unsupported {
        /// The formulation's name.
        formulation: String,
    },
    /// The loss does not fit the scene (reference length, body index).
    #[error("loss: {0}")]
    Loss(String),
    /// Setting up or stepping the simulation failed.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The implicit differentiation failed.
    #[error(transparent)]
    Implicit(#[from] ImplicitError),
    /// The modelling layer rejected a request.
    #[error("model: {0}")]
    Model(#[from] ModelError),
}

/// Options of the step sensitivities.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct SensitivityOptions {
    /// Active-set classification and degeneracy tolerances.
    pub active_set: ActiveSetOptions,
    /// Factorise the reduced Jacobian by block elimination of each body's ν and q
    /// (`docs/latency.md#structured-linear-solve`) instead of the LU of the whole matrix.
    /// Default `false`.
    pub structured_solve: bool,
    /// Solve the step inputs' columns with faer's blocked triangular solves (the route before
    /// the small kernel's row-oriented solve, `docs/latency.md`; the results differ by
    /// round-off). Default `false`.
    pub blocked_columns: bool,
}

/// A degenerate point met by a step sensitivity (module documentation).
#[derive(Clone, Debug, PartialEq)]
pub enum Degeneracy {
    /// A component at its bound with residual ≈ 0, held at the bound.
    WeaklyActive {
        /// Component name, e.g. `"contact.pn[0]"`.
        component: String,
        /// Index in `z`.
        index: usize,
        /// `max_k |dF_i/dθ_k|` along the held branch.
        slope: f64,
        /// True when the slope is 0 (to the tolerance): the derivative is two-sided.
        two_sided: bool,
    },
    /// A contact with `p_n` at 0: its friction impulses and σ are held.
    FrictionHeld {
        /// Contact index (in [`crate::step::StepHandles::contacts`], the order of the records).
        contact: usize,
    },
    /// The reduced Jacobian is singular: minimum-norm derivative.
    Singular {
        /// Relative residual of the regularised solve (≈ 0: consistent).
        consistency: f64,
    },
    /// The closest-point unknowns (a1, a2, l, l_g) of the contacts with `p_n = 0` are not unique (a
    /// hull edge or face parallel to the plane, `docs/model.md#degenerate-cases`): they got the
    /// minimum-norm derivative. The motion derivatives do not depend on them (they enter
    /// Newton–Euler and friction only through `p_n` and `p_f`, both 0), so a trajectory does not
    /// report this; `consistency` ≫ 0 means the ECP's derivative does not exist (it jumps).
    SeparatedGeometry {
        /// Relative residual of the regularised solve of that sub-block.
        consistency: f64,
    },
}

impl Degeneracy {
    /// True when the derivative is not a plain two-sided derivative here (a one-sided weakly
    /// active component or a singular system): what a trajectory reports as an event.
    pub fn is_reportable(&self) -> bool {
        match self {
            Degeneracy::WeaklyActive { two_sided, .. } => !two_sided,
            Degeneracy::FrictionHeld { .. } | Degeneracy::SeparatedGeometry { .. } => false,
            Degeneracy::Singular { .. } => true,
        }
    }
}

/// The derivatives of one step (module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct StepSensitivity {
    /// The step differentiated (from 1).
    pub step: usize,
    /// The columns: every step input ([`StepInput::all`]).
    pub inputs: Vec<StepInput>,
    /// Number of unknowns `n` of the step problem.
    pub n: usize,
    /// `dz*/d(input)`, `n × inputs.len()`, column-major, in the layout of
    /// [`Simulation::mcp`]: ν, q (Q before renormalisation), ECPs, multipliers, impulses (and
    /// the unknowns of user terms).
    pub dz: Vec<f64>,
    /// Derivatives of the stored end-of-step state, `(13 · bodies) × inputs.len()`,
    /// column-major: per body x, Q (renormalised), v, ω ([`StateComponent`] order; read one
    /// with [`StepSensitivity::d_state`]).
    pub state: Vec<f64>,
    /// The active-set status of every component of `z`.
    pub status: Vec<ComponentStatus>,
    /// Degenerate points met.
    pub degeneracies: Vec<Degeneracy>,
    /// How the reduced system of the motion (and of the closed contacts) was solved.
    pub solve: SolveKind,
}

impl StepSensitivity {
    /// Column of `input`, if the step has it.
    pub fn column(&self, input: StepInput) -> Option<usize> {
        self.inputs.iter().position(|i| *i == input)
    }
    /// `dz*/d(input)` (length `n`), or `None` for an input the scene does not have.
    pub fn dz(&self, input: StepInput) -> Option<&[f64]> {
        let c = self.column(input)?;
        Some(&self.dz[c * self.n..(c + 1) * self.n])
    }
    /// Derivative of `component` of body `body`'s stored end-of-step state with respect to
    /// `input` (`None` for a body, component or input the step does not have).
    pub fn d_state(&self, body: usize, component: StateComponent, input: StepInput) -> Option<f64> {
        let c = self.column(input)?;
        let m = self.state.len() / self.inputs.len().max(1);
        let i = STATE_SIZE * body + component.index()?;
        (i < m).then(|| self.state[c * m + i])
    }
    /// True when no reportable degeneracy was met ([`Degeneracy::is_reportable`]).
    pub fn is_regular(&self) -> bool {
        !self.degeneracies.iter().any(Degeneracy::is_reportable)
    }
}

impl StepSensitivity {
    /// An empty result, for [`StepDifferentiator::differentiate_into`] to fill.
    pub fn empty() -> Self {
        StepSensitivity {
            step: 0,
            inputs: Vec::new(),
            n: 0,
            dz: Vec::new(),
            state: Vec::new(),
            status: Vec::new(),
            degeneracies: Vec::new(),
            solve: SolveKind::Direct,
        }
    }
}

/// Step-sensitivity workspace, reused from step to step (the reduced system keeps its
/// symbolic analysis).
#[derive(Debug, Default)]
pub struct StepDifferentiator {
    options: SensitivityOptions,
    system: ReducedSystem,
    /// `∂F/∂θ` of the step inputs, kept so that its storage is not zeroed twice per call (the
    /// data Jacobian zeroes it itself).
    rhs: Vec<f64>,
    /// The rest of the workspace, kept so that a repeated call allocates nothing.
    work: Work,
}

/// The bookkeeping of [`input_columns`], kept between calls.
#[derive(Debug, Default)]
struct InputColumns {
    /// The data blocks of the inputs, each once.
    wrt: Vec<DataId>,
    /// The column of each block's first component in the data Jacobian.
    first: Vec<usize>,
    /// Each input's column in the data Jacobian.
    at: Vec<usize>,
    /// The data Jacobian's own.
    data: DataJacobianWork,
}

/// [`StepDifferentiator`]'s buffers besides the reduced system and `∂F/∂θ`.
#[derive(Debug, Default)]
struct Work {
    /// `F(z*)`.
    f: Vec<f64>,
    /// The statuses of stage 1 (the held contacts' geometry held too).
    first: Vec<ComponentStatus>,
    /// The components of the held contacts' geometry.
    geometry: Vec<usize>,
    /// Stage 1's derivative.
    stage: ImplicitDerivative,
    /// Per body: ν's and q's offsets, `Q/|Q|` and `|Q|`.
    frames: Vec<(usize, usize, Vector4<f64>, f64)>,
    /// The bookkeeping of [`input_columns`].
    columns: InputColumns,
    /// Component names of earlier results' degeneracies, reused for the new ones.
    names: Vec<String>,
}

impl StepDifferentiator {
    /// A workspace with the given options.
    pub fn new(options: SensitivityOptions) -> Self {
        StepDifferentiator {
            options,
            system: ReducedSystem::new()
                .with_structured_solve(options.structured_solve)
                .with_blocked_columns(options.blocked_columns),
            rhs: Vec::new(),
            work: Work::default(),
        }
    }

    /// The step sensitivities of the last step `sim` took (module documentation).
    pub fn differentiate(&mut self, sim: &Simulation) -> Result<StepSensitivity, SensitivityError> {
        self.differentiate_with(sim, &[])
    }

    /// [`StepDifferentiator::differentiate`] with the columns of `extra` inputs after those of
    /// [`StepInput::all`]: components of the data blocks of user forces and terms
    /// ([`StepInput::Data`]).
    pub fn differentiate_with(
        &mut self,
        sim: &Simulation,
        extra: &[StepInput],
    ) -> Result<StepSensitivity, SensitivityError> {
        let mut out = StepSensitivity::empty();
        self.differentiate_into(sim, extra, &mut out)?;
        Ok(out)
    }

    /// [`StepDifferentiator::differentiate_with`] into `out`, whose vectors (and the component
    /// names of its degeneracies) are reused: a repeated call allocates nothing once they and
    /// the workspace have grown, unless a contact has `p_n` at 0 (the second stage). On an
    /// error `out` holds no valid result.
    pub fn differentiate_into(
        &mut self,
        sim: &Simulation,
        extra: &[StepInput],
        out: &mut StepSensitivity,
    ) -> Result<(), SensitivityError> {
        let unsupported = || SensitivityError::Unsupported {
            formulation: sim.formulation_name().to_string(),
        };
        if sim.capabilities().sensitivities == SensitivitySupport::None {
            return Err(unsupported());
        }
        if sim
            .handles()
            .bodies
            .iter()
            .any(|b| b.nu.is_none() || b.q.is_none())
        {
            return Err(unsupported());
        }
        let last = sim.last_step().ok_or(SensitivityError::NoStep)?;
        let mcp = sim.mcp();
        let n = mcp.dim();
        let z = &last.z;
        let work = &mut self.work;
        let f = &mut work.f;
        f.clear();
        f.resize(n, 0.0);
        mcp.evaluate(z, f);
        if !last.converged {
            return Err(SensitivityError::NotConverged {
                step: last.step,
                residual: ecp_model::natural_residual(z, f, mcp.lower(), mcp.upper()),
            });
        }
        let opts = &self.options.active_set;
        let status = &mut out.status;
        classify_into(z, f, mcp.lower(), mcp.upper(), opts, status);
        for d in out.degeneracies.drain(..) {
            if let Degeneracy::WeaklyActive { component, .. } = d {
                work.names.push(component);
            }
        }
        let degeneracies = &mut out.degeneracies;
        // Contacts with p_n at 0: friction held; their closest-point unknowns (a1, a2, l, l_g)
        // do not enter the motion rows while p_n = p_f = 0, so they are solved in a second
        // stage (below) and cannot spoil the motion derivatives when they are not unique.
        let geometry = &mut work.geometry;
        geometry.clear();
        for (i, c) in sim.handles().contacts.iter().enumerate() {
            let pn = mcp.offset(c.normal);
            if status[pn] != ComponentStatus::Free {
                for k in c.friction.iter().flat_map(|v| mcp.range(*v)) {
                    status[k] = ComponentStatus::Held;
                }
                degeneracies.push(Degeneracy::FrictionHeld { contact: i });
                for v in &c.geometry {
                    geometry.extend(mcp.range(*v));
                }
            }
        }
        let bodies = sim.scene().bodies.len();
        let inputs = &mut out.inputs;
        StepInput::all_into(bodies, inputs);
        inputs.extend_from_slice(extra);
        let p = inputs.len();
        input_columns(sim, z, inputs, &mut self.rhs, &mut work.columns)?;
        let rhs = &self.rhs;
        // Stage 1: everything but the held-contact geometry.
        let first = &mut work.first;
        first.clone_from(status);
        for &i in geometry.iter() {
            first[i] = ComponentStatus::Held;
        }
        let d = &mut work.stage;
        self.system
            .differentiate_into(mcp, z, first, rhs, p, opts, d)?;
        let dz = &mut out.dz;
        // Taken, not copied: `d.dz` gets the kept result's old storage to fill next time.
        std::mem::swap(dz, &mut d.dz);
        if let SolveKind::Regularised { consistency } = d.solve {
            degeneracies.push(Degeneracy::Singular { consistency });
        }
        // Stage 2: the held-contact geometry, the rest fixed at its stage-1 derivative:
        // J_gg dz_g = −(∂F_g/∂θ + J_g· dz₁).
        if !geometry.is_empty() {
            let pattern = mcp.jacobian_pattern().clone();
            let jac = self.system.jacobian_values().to_vec();
            let mut second = vec![ComponentStatus::Held; n];
            for &i in geometry.iter() {
                second[i] = status[i];
            }
            let mut rhs2 = rhs.clone();
            let mut jdz = vec![0.0; n];
            for c in 0..p {
                pattern.mul_vec(&jac, &dz[c * n..(c + 1) * n], &mut jdz);
                for (r, j) in rhs2[c * n..(c + 1) * n].iter_mut().zip(&jdz) {
                    *r += j;
                }
            }
            let d2 = self.system.differentiate(mcp, z, &second, &rhs2, p, opts)?;
            for (a, b) in dz.iter_mut().zip(&d2.dz) {
                *a += b;
            }
            if let SolveKind::Regularised { consistency } = d2.solve {
                degeneracies.push(Degeneracy::SeparatedGeometry { consistency });
            }
            // Slopes along the combined derivative (stage 1 alone holds the contact geometry).
            d.weak = self.system.weak_slopes(mcp, status, dz, rhs, p, opts);
        }
        // Without a second stage stage 1's slopes are those (same status, same derivative).
        for w in &d.weak {
            let mut component = work.names.pop().unwrap_or_default();
            component.clear();
            mcp.write_component_name(w.index, &mut component);
            degeneracies.push(Degeneracy::WeaklyActive {
                component,
                index: w.index,
                slope: w.slope,
                two_sided: w.two_sided,
            });
        }
        // The stored state: x, Q/|Q|, v, ω.
        // Written column by column, body by body: every entry once, no zeroing first.
        let m = STATE_SIZE * bodies;
        let frames = &mut work.frames;
        frames.clear();
        for b in &sim.handles().bodies {
            let (Some(nu_id), Some(q_id)) = (b.nu, b.q) else {
                return Err(unsupported());
            };
            let (nu0, q0) = (mcp.offset(nu_id), mcp.offset(q_id));
            let qraw = Vector4::new(z[q0 + 3], z[q0 + 4], z[q0 + 5], z[q0 + 6]);
            let norm = qraw.norm();
            frames.push((nu0, q0, qraw / norm, norm));
        }
        let state = &mut out.state;
        state.clear();
        state.reserve(m * p);
        for col in dz.chunks_exact(n.max(1)).take(p) {
            for &(nu0, q0, qn, norm) in frames.iter() {
                state.extend_from_slice(&col[q0..q0 + 3]);
                let dq = Vector4::new(col[q0 + 3], col[q0 + 4], col[q0 + 5], col[q0 + 6]);
                let dqn = (dq - qn * qn.dot(&dq)) / norm;
                state.extend_from_slice(dqn.as_slice());
                state.extend_from_slice(&col[nu0..nu0 + 6]);
            }
        }
        out.solve = degeneracies
            .iter()
            .find_map(|d| match d {
                Degeneracy::Singular { consistency } => Some(SolveKind::Regularised {
                    consistency: *consistency,
                }),
                _ => None,
            })
            .unwrap_or(SolveKind::Direct);
        out.step = last.step;
        out.n = n;
        Ok(())
    }
}

/// `∂F/∂θ` at `z` for the step inputs `inputs` into `out` (one column each,
/// `n × inputs.len()`, column-major): the data Jacobian of the data blocks they live in
/// ([`StepInput::data`]).
fn input_columns(
    sim: &Simulation,
    z: &[f64],
    inputs: &[StepInput],
    out: &mut Vec<f64>,
    work: &mut InputColumns,
) -> Result<(), SensitivityError> {
    let mcp = sim.mcp();
    let n = mcp.dim();
    // The data blocks the inputs live in, each once, and the column of each block's first
    // component in the data Jacobian.
    let InputColumns {
        wrt,
        first,
        at,
        data,
    } = work;
    wrt.clear();
    first.clear();
    at.clear();
    let mut p = 0;
    for input in inputs {
        let (d, k) = input.data(sim).ok_or_else(|| {
            SensitivityError::Param(format!(
                "step input {input:?} names a body the scene does not have"
            ))
        })?;
        let slot = match wrt.iter().position(|w| *w == d) {
            Some(slot) => slot,
            None => {
                wrt.push(d);
                first.push(p);
                p += mcp.data(d).len();
                wrt.len() - 1
            }
        };
        at.push(first[slot] + k);
    }
    // The data Jacobian zeroes its output itself: `resize` only keeps the length right.
    out.resize(n * p, 0.0);
    mcp.data_jacobian_with(z, wrt, out, data)?;
    // The step inputs are laid out as their data blocks ([`StepInput::all`]): no reordering.
    if at.iter().copied().eq(0..p) {
        return Ok(());
    }
    let full = std::mem::take(out);
    out.resize(n * inputs.len(), 0.0);
    for (c, &col) in at.iter().enumerate() {
        out[c * n..(c + 1) * n].copy_from_slice(&full[col * n..(col + 1) * n]);
    }
    Ok(())
}

/// The step sensitivities of the last step `sim` took ([`StepDifferentiator::differentiate`]
/// with a fresh workspace; keep a [`StepDifferentiator`] to reuse it across steps).
pub fn step_sensitivity(
    sim: &Simulation,
    options: &SensitivityOptions,
) -> Result<StepSensitivity, SensitivityError> {
    StepDifferentiator::new(*options).differentiate(sim)
}

/// [`step_sensitivity`] with the columns of `extra` inputs (components of user data blocks,
/// [`StepInput::Data`]) after those of [`StepInput::all`].
pub fn step_sensitivity_with(
    sim: &Simulation,
    options: &SensitivityOptions,
    extra: &[StepInput],
) -> Result<StepSensitivity, SensitivityError> {
    StepDifferentiator::new(*options).differentiate_with(sim, extra)
}

/// A scalar loss of a trajectory, a sum of per-step terms of the body states after each step.
pub trait TrajectoryLoss {
    /// Checks that the loss fits `scene` run for `steps` steps; the message says what is wrong.
    fn check(&self, _scene: &Scene, _steps: usize) -> Result<(), String> {
        Ok(())
    }
    /// The term of the step of `record` (of `steps` in all), and its gradient with respect to
    /// the body states after the step, added into `grad` (13 per body: x, Q, v, ω; zeroed by
    /// the caller).
    fn step_term(&self, record: &StepRecord, steps: usize, grad: &mut [f64]) -> f64;
}

/// Weights of the terms of a [`ReferenceLoss`] (all ≥ 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceWeights {
    /// On `|x − x_ref|²` (1/m²).
    pub position: f64,
    /// On `1 − (Q·Q_ref)²` (≈ θ²/4 for a small rotation θ between the two; sign-invariant).
    pub orientation: f64,
    /// On the squared yaw difference, wrapped to (−π, π] (yaw = rotation about world z of the
    /// body x axis, `atan2(2(wz + xy), 1 − 2(y² + z²))`).
    pub yaw: f64,
    /// On `|v − v_ref|²`.
    pub velocity: f64,
    /// On `|ω − ω_ref|²`.
    pub angular_velocity: f64,
}

impl Default for ReferenceWeights {
    /// Position only (weight 1).
    fn default() -> Self {
        ReferenceWeights {
            position: 1.0,
            orientation: 0.0,
            yaw: 0.0,
            velocity: 0.0,
            angular_velocity: 0.0,
        }
    }
}

/// `L = Σ_steps Σ_bodies` of the weighted squared differences to a reference trajectory
/// ([`ReferenceWeights`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceLoss {
    /// Reference states: `reference[k][b]` is body `b` after step `k + 1`.
    pub reference: Vec<Vec<BodyState>>,
    /// Term weights.
    pub weights: ReferenceWeights,
}

impl ReferenceLoss {
    /// From reference states `reference[k][b]` (body `b` after step `k + 1`).
    pub fn new(reference: Vec<Vec<BodyState>>, weights: ReferenceWeights) -> Self {
        ReferenceLoss { reference, weights }
    }
    /// From the records of a run.
    pub fn from_records(records: &[StepRecord], weights: ReferenceWeights) -> Self {
        Self::new(records.iter().map(|r| r.bodies.clone()).collect(), weights)
    }
}

/// Yaw of a unit quaternion and its gradient with respect to (w, x, y, z).
pub fn yaw_and_gradient(q: &Vector4<f64>) -> (f64, Vector4<f64>) {
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    let a = 2.0 * (w * z + x * y);
    let b = 1.0 - 2.0 * (y * y + z * z);
    let da = Vector4::new(2.0 * z, 2.0 * y, 2.0 * x, 2.0 * w);
    let db = Vector4::new(0.0, 0.0, -4.0 * y, -4.0 * z);
    let r2 = a * a + b * b;
    let grad = if r2 > 0.0 {
        (da * b - db * a) / r2
    } else {
        Vector4::zeros()
    };
    (a.atan2(b), grad)
}

/// An angle wrapped to (−π, π].
fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let r = a.rem_euclid(t);
    if r > std::f64::consts::PI { r - t } else { r }
}

impl TrajectoryLoss for ReferenceLoss {
    fn check(&self, scene: &Scene, steps: usize) -> Result<(), String> {
        let w = &self.weights;
        for (name, v) in [
            ("position", w.position),
            ("orientation", w.orientation),
            ("yaw", w.yaw),
            ("velocity", w.velocity),
            ("angular_velocity", w.angular_velocity),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(format!(
                    "weight {name} = {v}: weights must be finite and ≥ 0"
                ));
            }
        }
        if self.reference.len() < steps {
            return Err(format!(
                "the reference has {} steps, the run has {steps}; give a reference as long as the run (or shorten the scene's duration)",
                self.reference.len()
            ));
        }
        let nb = scene.bodies.len();
        if let Some(k) = self.reference[..steps].iter().position(|r| r.len() != nb) {
            return Err(format!(
                "reference step {} has {} bodies, the scene has {nb}",
                k + 1,
                self.reference[k].len()
            ));
        }
        Ok(())
    }

    fn step_term(&self, record: &StepRecord, _steps: usize, grad: &mut [f64]) -> f64 {
        let Some(refs) = record
            .step
            .checked_sub(1)
            .and_then(|k| self.reference.get(k))
        else {
            return 0.0;
        };
        let w = &self.weights;
        let mut total = 0.0;
        for (b, (s, r)) in record.bodies.iter().zip(refs).enumerate() {
            let g = &mut grad[STATE_SIZE * b..STATE_SIZE * (b + 1)];
            let dx = s.x - r.x;
            let dv = s.v - r.v;
            let dw = s.w - r.w;
            let c = s.q.dot(&r.q);
            total += w.position * dx.norm_squared()
                + w.orientation * (1.0 - c * c)
                + w.velocity * dv.norm_squared()
                + w.angular_velocity * dw.norm_squared();
            for i in 0..3 {
                g[i] += 2.0 * w.position * dx[i];
                g[7 + i] += 2.0 * w.velocity * dv[i];
                g[10 + i] += 2.0 * w.angular_velocity * dw[i];
            }
            for i in 0..4 {
                g[3 + i] += -2.0 * w.orientation * c * r.q[i];
            }
            if w.yaw != 0.0 {
                let (ys, gs) = yaw_and_gradient(&s.q);
                let (yr, _) = yaw_and_gradient(&r.q);
                let d = wrap(ys - yr);
                total += w.yaw * d * d;
                for i in 0..4 {
                    g[3 + i] += 2.0 * w.yaw * d * gs[i];
                }
            }
        }
        total
    }
}

/// `L = weight · |x_body − target|²` at the last step (e.g. reach a target at t = 1 s: set the
/// scene's duration to 1 s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TerminalPositionLoss {
    /// Which body's CM.
    pub body: usize,
    /// Target CM position.
    pub target: Vector3<f64>,
    /// Weight (≥ 0).
    pub weight: f64,
}

impl TrajectoryLoss for TerminalPositionLoss {
    fn check(&self, scene: &Scene, steps: usize) -> Result<(), String> {
        if self.body >= scene.bodies.len() {
            return Err(format!(
                "terminal position of body {}, but the scene has {} bodies",
                self.body,
                scene.bodies.len()
            ));
        }
        if !(self.weight >= 0.0 && self.weight.is_finite())
            || self.target.iter().any(|v| !v.is_finite())
        {
            return Err("the weight must be finite and ≥ 0, the target finite".into());
        }
        if steps == 0 {
            return Err("the scene has no steps (duration 0)".into());
        }
        Ok(())
    }

    fn step_term(&self, record: &StepRecord, steps: usize, grad: &mut [f64]) -> f64 {
        if record.step != steps {
            return 0.0;
        }
        let Some(s) = record.bodies.get(self.body) else {
            return 0.0;
        };
        let d = s.x - self.target;
        for i in 0..3 {
            grad[STATE_SIZE * self.body + i] += 2.0 * self.weight * d[i];
        }
        self.weight * d.norm_squared()
    }
}

/// How [`trajectory_gradient`] accumulates the chain of step Jacobians.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum GradientMode {
    /// Carries `dstate/dθ` forward (and one tangent per past step's wrench): good for few
    /// parameters and short runs.
    Forward,
    /// One backward sweep of the adjoint state: cost independent of the number of parameters.
    #[default]
    Adjoint,
}

/// Options of [`trajectory_gradient_with`] and [`trajectory_gradient_of`].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct GradientOptions {
    /// Forward or adjoint accumulation.
    pub mode: GradientMode,
    /// Step-sensitivity options.
    pub sensitivity: SensitivityOptions,
}

/// A mode switch or degeneracy inside the differentiated window.
#[derive(Clone, Debug, PartialEq)]
pub enum ModeEventKind {
    /// A component's active-set status changed since the previous step (a contact opened or
    /// closed, stick ↔ slip, the ECP reached or left a hull edge): the loss is only piecewise
    /// smooth across it.
    ActiveSetChanged {
        /// Component name.
        component: String,
        /// Status at the previous step.
        from: ComponentStatus,
        /// Status at this step.
        to: ComponentStatus,
    },
    /// A reportable degeneracy of the step ([`Degeneracy::is_reportable`]).
    Degenerate(Degeneracy),
}

/// A [`ModeEventKind`] at a step.
#[derive(Clone, Debug, PartialEq)]
pub struct ModeEvent {
    /// The step (from 1).
    pub step: usize,
    /// What happened.
    pub kind: ModeEventKind,
}

/// The result of [`trajectory_gradient`].
#[derive(Clone, Debug)]
pub struct TrajectoryGradient {
    /// The loss.
    pub loss: f64,
    /// The parameters differentiated.
    pub params: Vec<Param>,
    /// `dL/dθ`, one entry per parameter.
    pub gradient: Vec<f64>,
    /// `dL/dw_k`: `wrench_gradient[k][b]` is the derivative with respect to the wrench
    /// `(force, torque)` applied to body `b` over step `k + 1` (evaluated at `t_k = k h`).
    pub wrench_gradient: Vec<Vec<Vector6<f64>>>,
    /// The records of the run.
    pub records: Vec<StepRecord>,
    /// Mode switches and degeneracies inside the window, in step order.
    pub events: Vec<ModeEvent>,
    /// How the gradient was accumulated.
    pub mode: GradientMode,
}

/// One step of `sim`; a step that does not converge is an error.
fn converged_step(
    sim: &mut Simulation,
    solver: &mut dyn McpSolver,
) -> Result<StepRecord, SensitivityError> {
    let rec = sim.step(solver)?;
    if !rec.converged {
        return Err(SensitivityError::NotConverged {
            step: rec.step,
            residual: rec.summary.residual,
        });
    }
    Ok(rec)
}

/// The loss of a run of `scene` with the hull formulation (no derivatives: for derivative-free
/// optimisers), with the records. A step that does not converge is an error.
pub fn trajectory_loss(
    scene: &Scene,
    loss: &dyn TrajectoryLoss,
    solver: &mut dyn McpSolver,
) -> Result<(f64, Vec<StepRecord>), SensitivityError> {
    let mut sim = Simulation::new(scene.clone())?;
    trajectory_loss_of(&mut sim, loss, solver)
}

/// The loss of a run of `sim` from its start ([`Simulation::reset`]: the parameters set on it
/// apply), with the records. A step that does not converge is an error.
pub fn trajectory_loss_of(
    sim: &mut Simulation,
    loss: &dyn TrajectoryLoss,
    solver: &mut dyn McpSolver,
) -> Result<(f64, Vec<StepRecord>), SensitivityError> {
    let steps = sim.scene().num_steps();
    loss.check(sim.scene(), steps)
        .map_err(SensitivityError::Loss)?;
    sim.reset()?;
    let mut grad = vec![0.0; STATE_SIZE * sim.scene().bodies.len()];
    let mut total = 0.0;
    let mut records = Vec::with_capacity(steps);
    while !sim.finished() {
        let rec = converged_step(sim, solver)?;
        total += loss.step_term(&rec, steps, &mut grad);
        records.push(rec);
    }
    Ok((total, records))
}

/// The gradient of `loss` over a run of `scene` with respect to `params` and to the wrench of
/// every step, hull formulation (module documentation).
pub fn trajectory_gradient(
    scene: &Scene,
    params: &[Param],
    loss: &dyn TrajectoryLoss,
    solver: &mut dyn McpSolver,
    mode: GradientMode,
) -> Result<TrajectoryGradient, SensitivityError> {
    trajectory_gradient_with(
        scene,
        params,
        loss,
        solver,
        &GradientOptions {
            mode,
            ..GradientOptions::default()
        },
    )
}

/// [`trajectory_gradient`] with all options (hull formulation).
pub fn trajectory_gradient_with(
    scene: &Scene,
    params: &[Param],
    loss: &dyn TrajectoryLoss,
    solver: &mut dyn McpSolver,
    options: &GradientOptions,
) -> Result<TrajectoryGradient, SensitivityError> {
    let mut sim = Simulation::new(scene.clone())?;
    trajectory_gradient_of(&mut sim, params, loss, solver, options)
}

/// The gradient of `loss` over a run of `sim` from its start ([`Simulation::reset`]: the
/// parameters set on it apply) with respect to `params` and to the wrench of every step, with
/// any formulation that has step sensitivities (module documentation).
pub fn trajectory_gradient_of(
    sim: &mut Simulation,
    params: &[Param],
    loss: &dyn TrajectoryLoss,
    solver: &mut dyn McpSolver,
    options: &GradientOptions,
) -> Result<TrajectoryGradient, SensitivityError> {
    for p in params {
        sim.param(*p)?;
    }
    let steps = sim.scene().num_steps();
    loss.check(sim.scene(), steps)
        .map_err(SensitivityError::Loss)?;
    sim.reset()?;
    let scene = sim.scene().clone();
    let nb = scene.bodies.len();
    let ns = STATE_SIZE * nb;
    let np = params.len();

    // Initial tangent ds₀/dθ (ns × np): the initial-state parameters, through the
    // normalisation of Q that the simulation applies.
    let mut s0 = vec![0.0; ns * np];
    for (j, p) in params.iter().enumerate() {
        let col = &mut s0[j * ns..(j + 1) * ns];
        match *p {
            Param::InitialPosition { body, axis } => col[STATE_SIZE * body + axis] = 1.0,
            Param::InitialVelocity { body, axis } => col[STATE_SIZE * body + 7 + axis] = 1.0,
            Param::InitialAngularVelocity { body, axis } => {
                col[STATE_SIZE * body + 10 + axis] = 1.0;
            }
            Param::InitialOrientation { body, component } => {
                let q = scene.bodies[body].initial.q;
                let norm = q.norm();
                let qn = q / norm;
                for i in 0..4 {
                    let e = if i == component { 1.0 } else { 0.0 };
                    col[STATE_SIZE * body + 3 + i] = (e - qn[i] * qn[component]) / norm;
                }
            }
            _ => {}
        }
    }
    // The step-input column each parameter is at every step.
    let param_cols: Vec<Option<usize>> = params
        .iter()
        .map(|p| step_input_of(p).and_then(|i| i.index(nb)))
        .collect();
    // State component i of body b is step input base(b) + 7 + i (x, Q, v, ω are contiguous).
    let state_col =
        |i: usize| FRICTION_INPUTS + BODY_INPUTS * (i / STATE_SIZE) + 7 + i % STATE_SIZE;
    let wrench_col = |b: usize, c: usize| FRICTION_INPUTS + BODY_INPUTS * b + 20 + c;

    let mut differ = StepDifferentiator::new(options.sensitivity);
    let mut jacobians: Vec<Vec<f64>> = Vec::with_capacity(steps); // ns × pi per step
    let mut loss_grads: Vec<Vec<f64>> = Vec::with_capacity(steps);
    let mut records = Vec::with_capacity(steps);
    let mut events = Vec::new();
    let mut total = 0.0;
    let mut previous: Option<Vec<ComponentStatus>> = None;
    while !sim.finished() {
        let rec = converged_step(sim, solver)?;
        let sens = differ.differentiate(sim)?;
        if let Some(prev) = &previous {
            for (i, (a, b)) in prev.iter().zip(&sens.status).enumerate() {
                if a != b {
                    events.push(ModeEvent {
                        step: rec.step,
                        kind: ModeEventKind::ActiveSetChanged {
                            component: sim.mcp().component_name(i),
                            from: *a,
                            to: *b,
                        },
                    });
                }
            }
        }
        for d in sens.degeneracies.iter().filter(|d| d.is_reportable()) {
            events.push(ModeEvent {
                step: rec.step,
                kind: ModeEventKind::Degenerate(d.clone()),
            });
        }
        let mut g = vec![0.0; ns];
        total += loss.step_term(&rec, steps, &mut g);
        loss_grads.push(g);
        previous = Some(sens.status);
        jacobians.push(sens.state);
        records.push(rec);
    }
    let k_steps = records.len();
    let entry = |jac: &[f64], row: usize, col: usize| jac[col * ns + row];

    let mut gradient = vec![0.0; np];
    let mut wrench_gradient = vec![vec![Vector6::zeros(); nb]; k_steps];
    match options.mode {
        GradientMode::Adjoint => {
            let mut lambda = vec![0.0; ns];
            let mut next = vec![0.0; ns];
            for k in (0..k_steps).rev() {
                let jac = &jacobians[k];
                for (l, g) in lambda.iter_mut().zip(&loss_grads[k]) {
                    *l += g;
                }
                let dot = |col: usize| (0..ns).map(|r| entry(jac, r, col) * lambda[r]).sum::<f64>();
                for (j, c) in param_cols.iter().enumerate() {
                    if let Some(c) = c {
                        gradient[j] += dot(*c);
                    }
                }
                for (b, w) in wrench_gradient[k].iter_mut().enumerate() {
                    for c in 0..6 {
                        w[c] = dot(wrench_col(b, c));
                    }
                }
                for (i, v) in next.iter_mut().enumerate() {
                    *v = dot(state_col(i));
                }
                std::mem::swap(&mut lambda, &mut next);
            }
            for (j, g) in gradient.iter_mut().enumerate() {
                *g += (0..ns).map(|r| s0[j * ns + r] * lambda[r]).sum::<f64>();
            }
        }
        GradientMode::Forward => {
            // Tangents: np parameter columns, then 6 nb columns per past step's wrench.
            let mut tangent = s0.clone();
            let mut cols = np;
            for k in 0..k_steps {
                let jac = &jacobians[k];
                // New tangent = G_s · old + G_θ (parameters) or G_w (this step's wrench).
                let new_cols = cols + 6 * nb;
                let mut updated = vec![0.0; ns * new_cols];
                for c in 0..cols {
                    let old = &tangent[c * ns..(c + 1) * ns];
                    let out = &mut updated[c * ns..(c + 1) * ns];
                    for (i, &o) in old.iter().enumerate() {
                        if o != 0.0 {
                            let sc = state_col(i);
                            for (r, v) in out.iter_mut().enumerate() {
                                *v += entry(jac, r, sc) * o;
                            }
                        }
                    }
                    if c < np
                        && let Some(pc) = param_cols[c]
                    {
                        for (r, v) in out.iter_mut().enumerate() {
                            *v += entry(jac, r, pc);
                        }
                    }
                }
                for b in 0..nb {
                    for w in 0..6 {
                        let c = cols + 6 * b + w;
                        let wc = wrench_col(b, w);
                        for r in 0..ns {
                            updated[c * ns + r] = entry(jac, r, wc);
                        }
                    }
                }
                tangent = updated;
                cols = new_cols;
                // Accumulate g_kᵀ · tangent.
                let g = &loss_grads[k];
                for c in 0..cols {
                    let v: f64 = (0..ns).map(|r| g[r] * tangent[c * ns + r]).sum();
                    if c < np {
                        gradient[c] += v;
                    } else {
                        let w = c - np;
                        let (step, rest) = (w / (6 * nb), w % (6 * nb));
                        wrench_gradient[step][rest / 6][rest % 6] += v;
                    }
                }
            }
        }
    }
    Ok(TrajectoryGradient {
        loss: total,
        params: params.to_vec(),
        gradient,
        wrench_gradient,
        records,
        events,
        mode: options.mode,
    })
}

#[cfg(test)]
mod tests {
    use ecp_solvers::newton::{NewtonSettings, NewtonSolver};

    use super::*;
    use crate::scenarios;
    use crate::step::Force;

    fn newton() -> NewtonSolver {
        NewtonSolver::new(NewtonSettings {
            tolerance: 1e-13,
            ..NewtonSettings::default()
        })
    }

    /// A spring force's stiffness is a column like any step input: in free flight
    /// `v⁺ = (m v + h m g − h k (x − a)) / (m + h² k)` per axis, so
    /// `dv⁺/dk = −h (x − a + h v⁺) / (m + h² k)`; and `dv⁺/dμ = 0` (no contact).
    #[test]
    fn a_user_force_parameter_is_differentiated() {
        let mut scene = scenarios::a1_sliding();
        scene.bodies[0].initial.x.z += 0.5;
        let anchor = Vector3::new(0.3, 0.2, 0.9);
        let k = 150.0;
        let mut sim = Simulation::builder(scene.clone())
            .force(0, Force::spring("tether", k, &anchor))
            .build()
            .unwrap_or_else(|e| panic!("{e}"));
        let rec = sim.step(&mut newton()).unwrap_or_else(|e| panic!("{e}"));
        let dk = StepInput::Data(sim.force_handles()[0].data[0], 0);
        let sens = step_sensitivity_with(&sim, &SensitivityOptions::default(), &[dk])
            .unwrap_or_else(|e| panic!("{e}"));
        let (m, h) = (scene.bodies[0].mass.mass, scene.h);
        let x0 = scene.bodies[0].initial.x;
        for i in 0..3 {
            let v = rec.bodies[0].v[i];
            let want = -h * (x0[i] - anchor[i] + h * v) / (m + h * h * k);
            let got = sens.d_state(0, StateComponent::Velocity(i), dk);
            assert!(
                got.is_some_and(|g| (g - want).abs() <= 1e-12),
                "axis {i}: {got:?} vs {want}"
            );
            let dmu = sens.d_state(0, StateComponent::Velocity(i), StepInput::Mu);
            assert!(dmu.is_some_and(|g| g.abs() <= 1e-15));
        }
        // A component the block does not have is refused.
        let bad = StepInput::Data(sim.force_handles()[0].data[0], 1);
        assert!(step_sensitivity_with(&sim, &SensitivityOptions::default(), &[bad]).is_err());
    }

    /// The formulations without step sensitivities say so.
    #[test]
    fn formulations_without_sensitivities_are_refused() {
        let mut sim = Simulation::with_formulation(scenarios::a1_sliding(), "reduced")
            .unwrap_or_else(|e| panic!("{e}"));
        sim.step(&mut newton()).unwrap_or_else(|e| panic!("{e}"));
        let e = step_sensitivity(&sim, &SensitivityOptions::default());
        assert!(
            matches!(e, Err(SensitivityError::Unsupported { ref formulation }) if formulation == "reduced")
        );
    }

    /// The trajectory gradient of a simulation with parameters set in place is that of a
    /// fresh one built with those values.
    #[test]
    fn gradient_of_a_simulation_uses_its_parameters() {
        let mut scene = scenarios::a1_sliding();
        scene.duration = 0.05;
        let loss = TerminalPositionLoss {
            body: 0,
            target: Vector3::zeros(),
            weight: 1.0,
        };
        let mut sim = Simulation::new(scene.clone()).unwrap_or_else(|e| panic!("{e}"));
        sim.set_param(Param::Mu, 0.25)
            .unwrap_or_else(|e| panic!("{e}"));
        let opts = GradientOptions::default();
        let a = trajectory_gradient_of(&mut sim, &[Param::Mu], &loss, &mut newton(), &opts)
            .unwrap_or_else(|e| panic!("{e}"));
        scene.friction.mu = 0.25;
        let b = trajectory_gradient_with(&scene, &[Param::Mu], &loss, &mut newton(), &opts)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(a.gradient, b.gradient);
        assert_eq!(a.loss, b.loss);
        // x_K = h Σ_k (1 − μ g h k), K = 5: dx_K/dμ = −g h² Σ k = −9.8e-4 · 15.
        let x = a.records[4].bodies[0].x.x;
        assert!((a.gradient[0] - 2.0 * x * (-9.8e-4 * 15.0)).abs() <= 1e-10);
    }
}
