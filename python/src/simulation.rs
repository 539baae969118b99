//! `ecp.Simulation`: a running simulation of a scene with a backend and a formulation, stepped
//! from Python, with its state, parameters and step sensitivities.

use pyo3::prelude::*;
use pyo3::types::PyDict;

use ecp::backends::{SolverConfig, Target, check_combination, make_solver_in};
use ecp::error::InputErrorKind;
use ecp::run::fallbacks_for;
use ecp_formulations::sensitivity::{Param, SensitivityOptions, StepDifferentiator};
use ecp_formulations::step::SensitivitySupport;
use ecp_formulations::{
    BodyState, Fallbacks, FormulationRegistry, Simulation as EcpSimulation, SimulationBuilder,
    StepRecord,
};
use ecp_model::McpSolver;
use ecp_solvers::Registry;
use nalgebra::{Vector3, Vector4};

use crate::convert::fixed;
use crate::errors::{argument, guard, input, simulation};
use crate::records::{Summary, Trajectory};
use crate::scene::{Scene, param};
use crate::sensitivity::StepSensitivity;
use crate::state::State;

/// A simulation of a :class:`Scene`: ``step()``, ``run(steps)``, the bodies' ``state`` and
/// ``states``, ``set_state``, ``set_param``, the last step's ``summary`` and its
/// ``step_sensitivity()``.
///
/// ``solver`` (``newton``, ``path``, ``conic``) and ``formulation`` (``hull``, ``union``,
/// ``reduced``, ``point``) default to the scene's. With ``fallbacks`` (the default, as
/// ``ecp run``), a step the backend cannot solve is tried with the other backends, then in
/// substeps (``docs/fallbacks.md``). A step that still fails raises :class:`SimulationError`
/// and the bodies keep their state at its start: a failed step is never an answer.
///
/// A simulation belongs to the thread that made it and holds the interpreter while it steps;
/// for many runs at once use :func:`ecp.batch`, which releases it and uses every core.
#[pyclass(module = "ecp", name = "Simulation", unsendable)]
pub struct Simulation {
    /// The scene as the user sees it: parameters set, loads in absolute time.
    scene: Scene,
    formulation: String,
    config: SolverConfig,
    with_fallbacks: bool,
    /// The step driver: it sets parameters in its data blocks in place.
    engine: EcpSimulation,
    solver: Box<dyn McpSolver>,
    fallbacks: Fallbacks,
    differentiator: StepDifferentiator,
    last: Option<StepRecord>,
}

impl Simulation {
    fn steps_taken(&self) -> usize {
        self.engine.steps_taken()
    }

    fn time(&self) -> f64 {
        self.engine.time()
    }

    fn current_states(&self) -> Vec<BodyState> {
        self.engine.states().to_vec()
    }

    /// One step; the caller keeps the record in `last`.
    fn advance(&mut self) -> PyResult<StepRecord> {
        self.last = None;
        self.engine
            .step_with(self.solver.as_mut(), &mut self.fallbacks)
            .map_err(|e| simulation(format!("step {}: {e}", self.engine.steps_taken() + 1)))
    }

    fn failure(&self, rec: &StepRecord) -> String {
        format!(
            "step {} (t = {:.4} s) could not be solved {}: {} (best residual {:.3e}); the bodies \
             keep their state at its start; try a smaller h{}",
            rec.step,
            rec.t - self.scene.file.scene.h,
            if self.with_fallbacks {
                "by its backend or any fallback"
            } else {
                "by its backend (fallbacks off)"
            },
            rec.summary.termination,
            rec.summary.residual,
            if self.with_fallbacks {
                ""
            } else {
                " or the fallbacks (fallbacks=True)"
            }
        )
    }

    fn contacts_per_body(&self) -> usize {
        self.engine.contacts_per_body()
    }
}

/// A failed step as a `SimulationError` with `summary` and, for a run, `trajectory` attached.
fn failed_step(
    py: Python<'_>,
    message: String,
    summary: Summary,
    trajectory: Option<Trajectory>,
) -> PyErr {
    let err = simulation(message);
    let value = err.value(py);
    let _ = value.setattr("summary", summary);
    if let Some(t) = trajectory {
        let _ = value.setattr("trajectory", t);
    }
    err
}

#[pymethods]
impl Simulation {
    #[new]
    #[pyo3(signature = (scene, solver = None, formulation = None, *, fallbacks = true, tolerance = None, max_iterations = None))]
    fn new(
        scene: &Scene,
        solver: Option<&str>,
        formulation: Option<&str>,
        fallbacks: bool,
        tolerance: Option<f64>,
        max_iterations: Option<usize>,
    ) -> PyResult<Simulation> {
        guard(|| {
            let mut config = scene.file.solver.clone();
            if let Some(name) = solver {
                config.name = name.trim().to_string();
            }
            if let Some(t) = tolerance {
                if !(t.is_finite() && t > 0.0) {
                    return Err(argument(
                        "tolerance",
                        InputErrorKind::InvalidValue,
                        format!("the tolerance must be a finite number > 0, not {t}"),
                    ));
                }
                config.tolerance = Some(t);
            }
            if max_iterations.is_some() {
                config.max_iterations = max_iterations;
            }
            let formulations = FormulationRegistry::builtin();
            let name = formulation.unwrap_or(&scene.file.formulation);
            let target = Target::resolve(name, &formulations).map_err(|e| {
                argument(
                    "formulation",
                    InputErrorKind::UnknownName,
                    e.message.clone(),
                )
            })?;
            let registry = Registry::builtin();
            check_combination(&registry, &config.name, &target).map_err(input)?;
            let backend = make_solver_in(&registry, &config, &target).map_err(input)?;
            let fallback_set = if fallbacks {
                fallbacks_for(&registry, &config, &target).map_err(input)?
            } else {
                Fallbacks::none()
            };
            let stepper = formulations
                .create(&target.name)
                .map_err(|e| argument("formulation", InputErrorKind::UnknownName, e.to_string()))?;
            let engine = SimulationBuilder::new(scene.file.scene.clone(), stepper)
                .build()
                .map_err(input)?;
            Ok(Simulation {
                scene: scene.clone(),
                formulation: target.name,
                config,
                with_fallbacks: fallbacks,
                engine,
                solver: backend,
                fallbacks: fallback_set,
                differentiator: StepDifferentiator::new(SensitivityOptions::default()),
                last: None,
            })
        })
    }

    /// Advances one step and returns its :class:`Summary`. Raises :class:`SimulationError` when
    /// the step cannot be solved (the bodies keep their state at its start; the error's
    /// ``summary`` describes the attempt).
    fn step(&mut self, py: Python<'_>) -> PyResult<Summary> {
        guard(|| {
            let rec = self.advance()?;
            let summary = Summary::from(&rec);
            self.last = Some(rec.clone());
            if !rec.converged {
                return Err(failed_step(py, self.failure(&rec), summary, None));
            }
            Ok(summary)
        })
    }

    /// Runs ``steps`` steps (default: to the end of the scene's duration) and returns them as a
    /// :class:`Trajectory`. A step that cannot be solved raises :class:`SimulationError` whose
    /// ``trajectory`` holds the steps so far (the failed one last); with ``keep_going=True`` the
    /// run goes on instead and the failed steps are marked in ``converged``.
    #[pyo3(signature = (steps = None, *, keep_going = false))]
    fn run(
        &mut self,
        py: Python<'_>,
        steps: Option<usize>,
        keep_going: bool,
    ) -> PyResult<Trajectory> {
        guard(|| {
            let remaining = self
                .scene
                .file
                .scene
                .num_steps()
                .saturating_sub(self.steps_taken());
            let n = steps.unwrap_or(remaining);
            let mut records = Vec::with_capacity(n.min(1 << 16));
            for _ in 0..n {
                let rec = match self.advance() {
                    Ok(rec) => rec,
                    Err(e) => {
                        let value = e.value(py);
                        let _ = value.setattr(
                            "trajectory",
                            Trajectory::new(
                                records,
                                self.scene.file.scene.bodies.len(),
                                self.contacts_per_body(),
                            ),
                        );
                        return Err(e);
                    }
                };
                let failed = !rec.converged && !keep_going;
                let message = failed.then(|| (self.failure(&rec), Summary::from(&rec)));
                records.push(rec);
                if let Some((message, summary)) = message {
                    self.last = records.last().cloned();
                    let trajectory = Trajectory::new(
                        records,
                        self.scene.file.scene.bodies.len(),
                        self.contacts_per_body(),
                    );
                    return Err(failed_step(py, message, summary, Some(trajectory)));
                }
            }
            self.last = records.last().cloned();
            Ok(Trajectory::new(
                records,
                self.scene.file.scene.bodies.len(),
                self.contacts_per_body(),
            ))
        })
    }

    /// The first body's state.
    #[getter]
    fn state(&self) -> State {
        State::from(self.engine.state(0))
    }

    /// Every body's state, in the scene's order.
    #[getter]
    fn states(&self) -> Vec<State> {
        self.current_states().into_iter().map(State::from).collect()
    }

    /// Replaces a body's state: a :class:`State`, or keyword arrays for the parts to change
    /// (``sim.set_state(velocity=[1, 0, 0])``); the quaternion is normalised. A state that
    /// penetrates a half-space is accepted: the next step's contact conditions resolve it.
    #[pyo3(signature = (state = None, *, body = 0, position = None, orientation = None, velocity = None, angular_velocity = None))]
    fn set_state(
        &mut self,
        state: Option<&State>,
        body: usize,
        position: Option<&Bound<'_, PyAny>>,
        orientation: Option<&Bound<'_, PyAny>>,
        velocity: Option<&Bound<'_, PyAny>>,
        angular_velocity: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let bodies = self.scene.file.scene.bodies.len();
        if body >= bodies {
            return Err(argument(
                "body",
                InputErrorKind::InvalidValue,
                format!(
                    "body index {body} is out of range: the scene has {bodies} bod{}",
                    if bodies == 1 { "y" } else { "ies" }
                ),
            ));
        }
        let mut s = state.map_or_else(|| self.engine.state(body), |s| s.inner);
        if let Some(p) = position {
            s.x = Vector3::from(fixed::<3>(p, "position")?);
        }
        if let Some(o) = orientation {
            s.q = Vector4::from(fixed::<4>(o, "orientation")?);
        }
        if let Some(v) = velocity {
            s.v = Vector3::from(fixed::<3>(v, "velocity")?);
        }
        if let Some(w) = angular_velocity {
            s.w = Vector3::from(fixed::<3>(w, "angular_velocity")?);
        }
        guard(|| {
            self.engine.set_state(body, s).map_err(input)?;
            self.last = None;
            Ok(())
        })
    }

    /// Sets a parameter for the steps to come: ``mu``, ``e_t``, ``e_o``, ``e_r``, ``mass``,
    /// ``i_xx`` ... ``i_yz``, a constant load ``fx`` ... ``tz`` (a body other than 0 as
    /// ``mass[1]``); the initial state ``x0`` ... ``wz0`` only before the first step (use
    /// :meth:`set_state` after). Checked as the scene checks it.
    fn set_param(&mut self, name: &str, value: f64) -> PyResult<()> {
        guard(|| {
            let p = param(name, &self.scene.file.scene)?;
            let initial = matches!(
                p,
                Param::InitialPosition { .. }
                    | Param::InitialOrientation { .. }
                    | Param::InitialVelocity { .. }
                    | Param::InitialAngularVelocity { .. }
            );
            if initial && self.steps_taken() > 0 {
                return Err(argument(
                    "name",
                    InputErrorKind::InvalidValue,
                    format!(
                        "{p} is a parameter of the initial state, and the simulation is past it \
                         ({} steps taken); change the current state with set_state",
                        self.steps_taken()
                    ),
                ));
            }
            let scene = self.scene.with(&[(p, value)])?;
            // In place: the driver writes the parameter into its data block (an initial-state
            // parameter takes effect at the reset, which is still t = 0).
            self.engine
                .set_param(p, value)
                .map_err(|e| argument("value", InputErrorKind::InvalidValue, e.to_string()))?;
            if initial {
                self.engine.reset().map_err(input)?;
            }
            self.scene = scene;
            self.last = None;
            Ok(())
        })
    }

    /// The step sensitivities of the last step (hull formulation; the union formulation's are
    /// reported singular): derivatives of the step's solution and of the end-of-step state with
    /// respect to every step input, with the degeneracies met (``docs/fitting.md``).
    fn step_sensitivity(&mut self) -> PyResult<StepSensitivity> {
        guard(|| {
            if self.engine.capabilities().sensitivities == SensitivitySupport::None {
                return Err(simulation(format!(
                    "the {} formulation has no step sensitivities; use formulation=\"hull\"",
                    self.formulation
                )));
            }
            let s = self
                .differentiator
                .differentiate(&self.engine)
                .map_err(simulation)?;
            Ok(StepSensitivity::new(
                s,
                0,
                self.scene.file.scene.bodies.len(),
            ))
        })
    }

    /// The last step's :class:`Summary` (``None`` before the first step and after
    /// ``set_param``).
    #[getter]
    fn summary(&self) -> Option<Summary> {
        self.last.as_ref().map(Summary::from)
    }

    /// Current time (s).
    #[getter(time)]
    fn py_time(&self) -> f64 {
        self.time()
    }

    /// Steps taken so far.
    #[getter(steps_taken)]
    fn py_steps_taken(&self) -> usize {
        self.steps_taken()
    }

    /// True once the scene's duration is covered.
    #[getter]
    fn finished(&self) -> bool {
        self.steps_taken() >= self.scene.file.scene.num_steps()
    }

    /// The scene being simulated, with the parameters set so far.
    #[getter]
    fn scene(&self) -> Scene {
        self.scene.clone()
    }

    /// The backend's name.
    #[getter]
    fn solver(&self) -> String {
        self.config.name.clone()
    }

    /// The formulation's name.
    #[getter]
    fn formulation(&self) -> String {
        self.formulation.clone()
    }

    /// Contacts per body in every step record.
    #[getter(contacts_per_body)]
    fn py_contacts_per_body(&self) -> usize {
        self.contacts_per_body()
    }

    fn __repr__(&self) -> String {
        format!(
            "Simulation(scene={:?}, solver={:?}, formulation={:?}, steps_taken={}, time={})",
            self.scene.file.scene.name,
            self.config.name,
            self.formulation,
            self.steps_taken(),
            self.time()
        )
    }

    /// Current parameter values as a dict ``{name: value}`` for the given names.
    fn get_params<'py>(&self, py: Python<'py>, names: Vec<String>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        for name in names {
            let p = param(&name, &self.scene.file.scene)?;
            let v = p
                .get(&self.scene.file.scene)
                .map_err(|e| argument("names", InputErrorKind::InvalidValue, e.to_string()))?;
            out.set_item(name, v)?;
        }
        Ok(out)
    }
}
