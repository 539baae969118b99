//! Step sensitivities and trajectory gradients as numpy arrays, with their degeneracy reports
//! (`docs/fitting.md`).

use nalgebra::{Vector3, Vector4};
use numpy::PyArrayDyn;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use ecp::backends::{Target, make_solver_in};
use ecp::error::InputErrorKind;
use ecp_formulations::BodyState;
use ecp_formulations::sensitivity::{
    Degeneracy, GradientMode, GradientOptions, InertiaEntry, ModeEvent, ModeEventKind, Param,
    ReferenceLoss, ReferenceWeights, StepInput, TerminalPositionLoss, TrajectoryLoss,
    trajectory_gradient_of,
};
use ecp_formulations::step::SensitivitySupport;
use ecp_formulations::{FormulationRegistry, SimulationBuilder};

use crate::convert::{array, f64_array, fixed, type_name};
use crate::errors::{argument, guard, simulation};
use crate::records::Trajectory;
use crate::scene::{Scene, param};

/// The name of a step input (a column of a step sensitivity): ``mu``, ``e_t``, ``e_o``,
/// ``e_r``, then per body ``mass``, ``i_xx`` ... ``i_yz``, the start-of-step state ``x`` ...
/// ``wz`` and the step's wrench ``fx`` ... ``tz``; a body other than 0 suffixed ``[b]``.
pub(crate) fn input_name(input: &StepInput) -> String {
    let (name, body): (String, Option<usize>) = match *input {
        StepInput::Mu => ("mu".into(), None),
        StepInput::Et => ("e_t".into(), None),
        StepInput::Eo => ("e_o".into(), None),
        StepInput::Er => ("e_r".into(), None),
        StepInput::Mass { body } => ("mass".into(), Some(body)),
        StepInput::Inertia { body, entry } => {
            let k = InertiaEntry::ALL
                .iter()
                .position(|e| *e == entry)
                .unwrap_or(0);
            (
                format!("i_{}", ["xx", "yy", "zz", "xy", "xz", "yz"][k]),
                Some(body),
            )
        }
        StepInput::Position { body, axis } => (["x", "y", "z"][axis % 3].into(), Some(body)),
        StepInput::Orientation { body, component } => {
            (["qw", "qx", "qy", "qz"][component % 4].into(), Some(body))
        }
        StepInput::Velocity { body, axis } => (["vx", "vy", "vz"][axis % 3].into(), Some(body)),
        StepInput::AngularVelocity { body, axis } => {
            (["wx", "wy", "wz"][axis % 3].into(), Some(body))
        }
        StepInput::Force { body, axis } => (["fx", "fy", "fz"][axis % 3].into(), Some(body)),
        StepInput::Torque { body, axis } => (["tx", "ty", "tz"][axis % 3].into(), Some(body)),
        StepInput::Data(d, k) => (format!("data{}[{k}]", d.0), None),
    };
    match body {
        Some(b) if b > 0 => format!("{name}[{b}]"),
        _ => name,
    }
}

/// A degeneracy as a dict: ``kind`` and its fields.
fn degeneracy<'py>(py: Python<'py>, d: &Degeneracy) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    match d {
        Degeneracy::WeaklyActive {
            component,
            index,
            slope,
            two_sided,
        } => {
            out.set_item("kind", "weakly_active")?;
            out.set_item("component", component)?;
            out.set_item("index", index)?;
            out.set_item("slope", slope)?;
            out.set_item("two_sided", two_sided)?;
        }
        Degeneracy::FrictionHeld { contact } => {
            out.set_item("kind", "friction_held")?;
            out.set_item("contact", contact)?;
        }
        Degeneracy::Singular { consistency } => {
            out.set_item("kind", "singular")?;
            out.set_item("consistency", consistency)?;
        }
        Degeneracy::SeparatedGeometry { consistency } => {
            out.set_item("kind", "separated_geometry")?;
            out.set_item("consistency", consistency)?;
        }
    }
    out.set_item("reportable", d.is_reportable())?;
    Ok(out)
}

/// A mode event as a dict: ``step``, ``kind`` (``active_set_changed`` or ``degenerate``) and
/// its fields.
fn event<'py>(py: Python<'py>, e: &ModeEvent) -> PyResult<Bound<'py, PyDict>> {
    let out = match &e.kind {
        ModeEventKind::ActiveSetChanged {
            component,
            from,
            to,
        } => {
            let d = PyDict::new(py);
            d.set_item("kind", "active_set_changed")?;
            d.set_item("component", component)?;
            d.set_item("from", from.as_str())?;
            d.set_item("to", to.as_str())?;
            d
        }
        ModeEventKind::Degenerate(deg) => {
            let d = degeneracy(py, deg)?;
            d.set_item("degeneracy", d.get_item("kind")?)?;
            d.set_item("kind", "degenerate")?;
            d
        }
    };
    out.set_item("step", e.step)?;
    Ok(out)
}

/// The derivatives of one step (``docs/fitting.md``): ``dz`` (unknowns × inputs) and
/// ``d_state`` (13 per body × inputs: x, Q renormalised, v, ω), columns named by ``inputs``;
/// ``degeneracies`` lists the degenerate points met (one-sided or singular derivatives are never
/// passed off as exact), ``is_regular`` is False when one of them is reportable.
#[pyclass(module = "ecp", name = "StepSensitivity", frozen)]
pub struct StepSensitivity {
    inner: ecp_formulations::sensitivity::StepSensitivity,
    step: usize,
    bodies: usize,
}

impl StepSensitivity {
    pub(crate) fn new(
        inner: ecp_formulations::sensitivity::StepSensitivity,
        step_offset: usize,
        bodies: usize,
    ) -> Self {
        StepSensitivity {
            step: inner.step + step_offset,
            inner,
            bodies,
        }
    }

    /// A column-major `rows × cols` matrix as a C-ordered numpy array.
    fn matrix<'py>(
        py: Python<'py>,
        data: &[f64],
        rows: usize,
        cols: usize,
    ) -> Bound<'py, PyArrayDyn<f64>> {
        let mut out = vec![0.0; rows * cols];
        for c in 0..cols {
            for r in 0..rows {
                out[r * cols + c] = data[c * rows + r];
            }
        }
        array(py, &[rows, cols], out)
    }
}

#[pymethods]
impl StepSensitivity {
    /// The step differentiated (from 1).
    #[getter]
    fn step(&self) -> usize {
        self.step
    }

    /// The column names (step inputs).
    #[getter]
    fn inputs(&self) -> Vec<String> {
        self.inner.inputs.iter().map(input_name).collect()
    }

    /// ``dz*/d(input)``: unknowns of the step problem × inputs.
    #[getter]
    fn dz<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        Self::matrix(py, &self.inner.dz, self.inner.n, self.inner.inputs.len())
    }

    /// Derivatives of the end-of-step state: (13 · bodies) × inputs.
    #[getter]
    fn d_state<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        Self::matrix(
            py,
            &self.inner.state,
            13 * self.bodies,
            self.inner.inputs.len(),
        )
    }

    /// The column of ``d_state`` for the input ``name`` (e.g. ``"mu"``, ``"vx"``, ``"fx[1]"``).
    fn d_state_by(&self, py: Python<'_>, name: &str) -> PyResult<Py<PyArrayDyn<f64>>> {
        let k = self
            .inner
            .inputs
            .iter()
            .position(|i| input_name(i) == name)
            .ok_or_else(|| {
                argument(
                    "name",
                    InputErrorKind::UnknownName,
                    format!(
                        "no step input \"{name}\"; the inputs are {}",
                        self.inputs().join(", ")
                    ),
                )
            })?;
        let rows = 13 * self.bodies;
        Ok(array(
            py,
            &[rows],
            self.inner.state[k * rows..(k + 1) * rows].to_vec(),
        )
        .unbind())
    }

    /// The active-set status of every unknown (``free``, ``active``, ``weakly_active``,
    /// ``held``).
    #[getter]
    fn status(&self) -> Vec<&'static str> {
        self.inner.status.iter().map(|s| s.as_str()).collect()
    }

    /// The degenerate points met, as dicts with a ``kind`` and a ``reportable`` flag.
    #[getter]
    fn degeneracies<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.inner
            .degeneracies
            .iter()
            .map(|d| degeneracy(py, d))
            .collect()
    }

    /// True when no reportable degeneracy was met.
    #[getter]
    fn is_regular(&self) -> bool {
        self.inner.is_regular()
    }

    /// How the reduced system was solved: ``direct`` or ``regularised``.
    #[getter]
    fn solve(&self) -> &'static str {
        match self.inner.solve {
            ecp_model::sensitivity::SolveKind::Direct => "direct",
            ecp_model::sensitivity::SolveKind::Regularised { .. } => "regularised",
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "StepSensitivity(step={}, unknowns={}, inputs={}, regular={})",
            self.step,
            self.inner.n,
            self.inner.inputs.len(),
            if self.inner.is_regular() {
                "True"
            } else {
                "False"
            }
        )
    }
}

/// The gradient of a trajectory loss (:func:`trajectory_gradient`).
#[pyclass(module = "ecp", name = "TrajectoryGradient", frozen)]
pub struct TrajectoryGradient {
    loss: f64,
    params: Vec<String>,
    gradient: Vec<f64>,
    wrench: Vec<f64>,
    steps: usize,
    bodies: usize,
    events: Vec<ModeEvent>,
    trajectory: Py<Trajectory>,
    mode: GradientMode,
}

#[pymethods]
impl TrajectoryGradient {
    /// The loss L.
    #[getter]
    fn loss(&self) -> f64 {
        self.loss
    }

    /// The parameters differentiated, in order.
    #[getter]
    fn params(&self) -> Vec<String> {
        self.params.clone()
    }

    /// ``dL/dθ``, one entry per parameter.
    #[getter]
    fn gradient<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        array(py, &[self.gradient.len()], self.gradient.clone())
    }

    /// ``dL/dw_k``: steps × bodies × 6, the derivative with respect to the wrench (force,
    /// torque at the CM, world frame) applied to each body over each step.
    #[getter]
    fn wrench_gradient<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        array(py, &[self.steps, self.bodies, 6], self.wrench.clone())
    }

    /// Mode switches and reportable degeneracies inside the window (the loss is only piecewise
    /// smooth across them), as dicts with ``step`` and ``kind``.
    #[getter]
    fn events<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.events.iter().map(|e| event(py, e)).collect()
    }

    /// The run the gradient was computed on.
    #[getter]
    fn trajectory(&self, py: Python<'_>) -> Py<Trajectory> {
        self.trajectory.clone_ref(py)
    }

    /// ``adjoint`` or ``forward``.
    #[getter]
    fn mode(&self) -> &'static str {
        match self.mode {
            GradientMode::Adjoint => "adjoint",
            GradientMode::Forward => "forward",
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "TrajectoryGradient(loss={:e}, params={:?}, gradient={:?}, events={})",
            self.loss,
            self.params,
            self.gradient,
            self.events.len()
        )
    }
}

/// Reference states `[step][body]` from a :class:`Trajectory` or a dict of arrays.
pub(crate) fn reference_states(
    obj: &Bound<'_, PyAny>,
    bodies: usize,
    weights: Option<&ReferenceWeights>,
) -> PyResult<Vec<Vec<BodyState>>> {
    if let Ok(t) = obj.cast::<Trajectory>() {
        return Ok(t.get().records.iter().map(|r| r.bodies.clone()).collect());
    }
    let Ok(d) = obj.cast::<PyDict>() else {
        return Err(PyTypeError::new_err(format!(
            "reference: expected an ecp.Trajectory or a dict of arrays (position, orientation, \
             velocity, angular_velocity: steps × bodies × 3 or 4, or steps × 3 or 4 for one \
             body), got {}",
            type_name(obj)
        )));
    };
    let parts = [
        ("position", 3usize, weights.map(|w| w.position)),
        ("orientation", 4, weights.map(|w| w.orientation.max(w.yaw))),
        ("velocity", 3, weights.map(|w| w.velocity)),
        ("angular_velocity", 3, weights.map(|w| w.angular_velocity)),
    ];
    let mut arrays: Vec<Option<Vec<f64>>> = Vec::new();
    let mut steps: Option<usize> = None;
    for (name, width, weight) in parts {
        match d.get_item(name)? {
            Some(v) => {
                let what = format!("reference[\"{name}\"]");
                let (data, shape) = f64_array(&v, &what)?;
                let ok = match shape.as_slice() {
                    [k, w] => bodies == 1 && *w == width && steps.is_none_or(|s| s == *k),
                    [k, b, w] => *b == bodies && *w == width && steps.is_none_or(|s| s == *k),
                    _ => false,
                };
                if !ok {
                    return Err(argument(
                        "reference",
                        InputErrorKind::WrongType,
                        format!(
                            "{what} has shape {shape:?}; expected steps × {bodies} × {width}{} \
                             with the same number of steps for every part",
                            if bodies == 1 {
                                format!(" (or steps × {width})")
                            } else {
                                String::new()
                            }
                        ),
                    ));
                }
                if data.iter().any(|x| !x.is_finite()) {
                    return Err(argument(
                        "reference",
                        InputErrorKind::InvalidValue,
                        format!("{what} has a non-finite entry; give finite values"),
                    ));
                }
                steps = Some(shape[0]);
                arrays.push(Some(data));
            }
            None if weight.is_some_and(|w| w > 0.0) => {
                return Err(argument(
                    "reference",
                    InputErrorKind::MissingKey,
                    format!("the loss weighs {name} but the reference has no \"{name}\" array"),
                ));
            }
            None => arrays.push(None),
        }
    }
    let Some(k) = steps else {
        return Err(argument(
            "reference",
            InputErrorKind::MissingKey,
            "the reference has none of position, orientation, velocity, angular_velocity",
        ));
    };
    let get = |part: usize, width: usize, step: usize, body: usize, c: usize| -> f64 {
        arrays[part]
            .as_ref()
            .map_or(if part == 1 && c == 0 { 1.0 } else { 0.0 }, |a| {
                a[(step * bodies + body) * width + c]
            })
    };
    Ok((0..k)
        .map(|s| {
            (0..bodies)
                .map(|b| BodyState {
                    x: Vector3::from_fn(|c, _| get(0, 3, s, b, c)),
                    q: Vector4::from_fn(|c, _| get(1, 4, s, b, c)),
                    v: Vector3::from_fn(|c, _| get(2, 3, s, b, c)),
                    w: Vector3::from_fn(|c, _| get(3, 3, s, b, c)),
                })
                .collect()
        })
        .collect())
}

/// Loss weights from a dict (`position`, `orientation`, `yaw`, `velocity`, `angular_velocity`,
/// all ≥ 0); the default is `ecp fit`'s (velocity and angular velocity 1).
pub(crate) fn weights(obj: Option<&Bound<'_, PyDict>>) -> PyResult<ReferenceWeights> {
    let mut w = ecp::fit::default_weights();
    let Some(d) = obj else {
        return Ok(w);
    };
    for (k, v) in d.iter() {
        let name: String = k.extract()?;
        let value: f64 = v.extract().map_err(|_| {
            PyTypeError::new_err(format!(
                "weights[{name:?}]: expected a number, got {}",
                type_name(&v)
            ))
        })?;
        if !(value.is_finite() && value >= 0.0) {
            return Err(argument(
                "weights",
                InputErrorKind::InvalidValue,
                format!("weight {name} = {value}: weights must be finite and ≥ 0"),
            ));
        }
        match name.as_str() {
            "position" | "x" => w.position = value,
            "orientation" | "q" => w.orientation = value,
            "yaw" => w.yaw = value,
            "velocity" | "v" => w.velocity = value,
            "angular_velocity" | "w" => w.angular_velocity = value,
            _ => {
                return Err(argument(
                    "weights",
                    InputErrorKind::UnknownKey,
                    format!(
                        "unknown weight \"{name}\"; the weights are position, orientation, yaw, \
                         velocity, angular_velocity"
                    ),
                ));
            }
        }
    }
    Ok(w)
}

/// The gradient of a trajectory loss with respect to scene parameters and to every step's
/// applied wrench, by implicit differentiation of each step chained by an adjoint (or forward)
/// sweep (``docs/fitting.md``).
///
/// The loss is either the weighted squared distance to a ``reference`` trajectory (an
/// :class:`ecp.Trajectory` or a dict of arrays ``position``, ``orientation``, ``velocity``,
/// ``angular_velocity``; ``weights`` as for ``ecp fit``, default velocity and angular velocity
/// 1), run for as many steps as the reference has, or the squared distance of body ``body``'s
/// final CM to ``target`` times ``weight`` after ``steps`` steps (default: the scene's
/// duration). Mode switches and degenerate steps inside the window are in ``events``.
#[pyfunction]
#[pyo3(signature = (scene, params, *, reference = None, weights = None, target = None, body = 0, weight = 1.0, steps = None, mode = "adjoint", solver = None, formulation = None))]
#[allow(clippy::too_many_arguments)]
pub fn trajectory_gradient(
    py: Python<'_>,
    scene: &Scene,
    params: Vec<String>,
    reference: Option<&Bound<'_, PyAny>>,
    weights: Option<&Bound<'_, PyDict>>,
    target: Option<&Bound<'_, PyAny>>,
    body: usize,
    weight: f64,
    steps: Option<usize>,
    mode: &str,
    solver: Option<&str>,
    formulation: Option<&str>,
) -> PyResult<TrajectoryGradient> {
    let mut rust_scene = scene.file.scene.clone();
    let parsed: Vec<Param> = params
        .iter()
        .map(|n| param(n, &rust_scene))
        .collect::<PyResult<_>>()?;
    let mode = match mode {
        "adjoint" => GradientMode::Adjoint,
        "forward" => GradientMode::Forward,
        other => {
            return Err(argument(
                "mode",
                InputErrorKind::UnknownName,
                format!(
                    "unknown gradient mode \"{other}\"; the modes are \"adjoint\", \"forward\""
                ),
            ));
        }
    };
    let formulations = FormulationRegistry::builtin();
    let formulation_target = Target::resolve(
        formulation.unwrap_or(&scene.file.formulation),
        &formulations,
    )
    .map_err(|e| {
        argument(
            "formulation",
            InputErrorKind::UnknownName,
            e.message.clone(),
        )
    })?;
    if formulation_target.capabilities.sensitivities == SensitivitySupport::None {
        return Err(argument(
            "formulation",
            InputErrorKind::InvalidValue,
            format!(
                "the {} formulation has no step sensitivities; use \"hull\"",
                formulation_target.name
            ),
        ));
    }
    let mut config = scene.file.solver.clone();
    if let Some(name) = solver {
        config.name = name.trim().to_string();
    }
    let bodies = rust_scene.bodies.len();
    let h = rust_scene.h;
    let limit = |n: usize| -> PyResult<f64> {
        if n == 0 {
            return Err(argument(
                "steps",
                InputErrorKind::InvalidValue,
                "differentiate at least one step",
            ));
        }
        Ok(n as f64 * h)
    };
    let loss: Box<dyn TrajectoryLoss + Send + Sync> = match (reference, target) {
        (Some(reference), None) => {
            let w = self::weights(weights)?;
            let mut states = reference_states(reference, bodies, Some(&w))?;
            if let Some(n) = steps {
                states.truncate(n);
            }
            rust_scene.duration = limit(states.len())?;
            Box::new(ReferenceLoss::new(states, w))
        }
        (None, Some(target)) => {
            if weights.is_some() {
                return Err(argument(
                    "weights",
                    InputErrorKind::InvalidValue,
                    "weights go with a reference; a target loss has one weight (weight=...)",
                ));
            }
            if body >= bodies {
                return Err(argument(
                    "body",
                    InputErrorKind::InvalidValue,
                    format!("body index {body} is out of range: the scene has {bodies}"),
                ));
            }
            if let Some(n) = steps {
                rust_scene.duration = limit(n)?;
            }
            Box::new(TerminalPositionLoss {
                body,
                target: Vector3::from(fixed::<3>(target, "target")?),
                weight,
            })
        }
        _ => {
            return Err(argument(
                "reference",
                InputErrorKind::MissingKey,
                "give either reference=... (a trajectory to match) or target=[x, y, z] (where \
                 body `body` should end)",
            ));
        }
    };
    let options = GradientOptions {
        mode,
        ..GradientOptions::default()
    };
    let result = guard(|| {
        py.detach(|| {
            let mut solver = make_solver_in(
                &ecp_solvers::Registry::builtin(),
                &config,
                &formulation_target,
            )
            .map_err(|e| e.to_string())?;
            let stepper = formulations
                .create(&formulation_target.name)
                .map_err(|e| e.to_string())?;
            let mut sim = SimulationBuilder::new(rust_scene.clone(), stepper)
                .build()
                .map_err(|e| e.to_string())?;
            trajectory_gradient_of(&mut sim, &parsed, loss.as_ref(), solver.as_mut(), &options)
                .map_err(|e| e.to_string())
        })
        .map_err(simulation)
    })?;
    let steps = result.wrench_gradient.len();
    let mut wrench = Vec::with_capacity(steps * bodies * 6);
    for k in &result.wrench_gradient {
        for b in 0..bodies {
            match k.get(b) {
                Some(w) => wrench.extend_from_slice(w.as_slice()),
                None => wrench.extend([0.0; 6]),
            }
        }
    }
    let contacts_per_body = result
        .records
        .first()
        .map_or(0, |r| r.contacts.len() / bodies.max(1));
    Ok(TrajectoryGradient {
        loss: result.loss,
        params: parsed.iter().map(|p| p.to_string()).collect(),
        gradient: result.gradient,
        wrench,
        steps,
        bodies,
        events: result.events,
        trajectory: Py::new(
            py,
            Trajectory::new(result.records, bodies, contacts_per_body),
        )?,
        mode: result.mode,
    })
}
