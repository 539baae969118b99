//! `ecp.compare`, `ecp.fit` and `ecp.lcp`: the command line's `compare`, `fit` and `lcp` as
//! functions returning what the command prints (as Python objects).

use std::path::PathBuf;

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use ecp::error::{InputError as RustInputError, InputErrorKind};
use ecp::fit::{
    FitError, FitOptions, GradientMethod, Method, ReferenceTrajectory, TrajectoryProblem,
};
use ecp::lcp::{Lcp, solve_lcp};
use ecp::run::{RunError, RunOptions, compare_scene};
use ecp_solvers::Registry;

use crate::convert::{array, f64_array};
use crate::errors::{argument, guard, input, simulation};
use crate::scene::{Scene, param};
use crate::sensitivity::{reference_states, weights};

/// A serde value as a Python object (through JSON, the form the command line prints).
fn to_python<'py>(py: Python<'py>, value: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| {
        crate::errors::InternalError::new_err(format!("cannot encode a report: {e}"))
    })?;
    py.import("json")?.call_method1("loads", (text,))
}

/// Runs every combination of ``solvers`` (default: newton, path, conic) and ``formulations``
/// (default: hull) on ``scene`` and returns the report of ``ecp compare`` (``compare.json``,
/// ``docs/outputs.md``) as a dict. The runs' files go to ``out`` (default: a temporary directory,
/// removed afterwards).
#[pyfunction]
#[pyo3(signature = (scene, solvers = None, formulations = None, *, steps = None, out = None))]
pub fn compare<'py>(
    py: Python<'py>,
    scene: &Scene,
    solvers: Option<Vec<String>>,
    formulations: Option<Vec<String>>,
    steps: Option<usize>,
    out: Option<PathBuf>,
) -> PyResult<Bound<'py, PyAny>> {
    let solvers: Vec<String> = solvers.unwrap_or_else(|| {
        let registry = Registry::builtin();
        registry.names().iter().map(|n| n.to_string()).collect()
    });
    let formulations: Vec<String> = match formulations {
        Some(list) => list
            .iter()
            .map(|n| {
                ecp::backends::parse_formulation(n)
                    .map_err(|e| argument("formulations", InputErrorKind::UnknownName, e))
            })
            .collect::<PyResult<_>>()?,
        None => vec!["hull".to_string()],
    };
    let temporary = out.is_none();
    let out_dir = out.unwrap_or_else(|| {
        std::env::temp_dir().join(format!(
            "ecp-compare-{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos())
        ))
    });
    let options = RunOptions {
        out_dir: out_dir.clone(),
        steps,
        plots: false,
        ..RunOptions::default()
    };
    let file = &scene.file;
    let report = guard(|| {
        py.detach(|| compare_scene(file, &solvers, &formulations, &options, |_| {}))
            .map_err(|e| match e {
                RunError::Input(e) => input(e),
                other => simulation(other),
            })
    });
    if temporary {
        let _ = std::fs::remove_dir_all(&out_dir);
    }
    to_python(py, &report?)
}

/// A reference trajectory for fitting: a path to a ``trajectory.csv``, an
/// :class:`ecp.Trajectory` or a dict of arrays.
fn reference(obj: &Bound<'_, PyAny>, scene: &Scene) -> PyResult<ReferenceTrajectory> {
    let bodies = scene.file.scene.bodies.len();
    if let Ok(path) = obj.extract::<PathBuf>() {
        return ecp::fit::read_reference(&path, bodies).map_err(input);
    }
    let states = reference_states(obj, bodies, None)?;
    let h = scene.file.scene.h;
    Ok(ReferenceTrajectory {
        path: PathBuf::from("<reference>"),
        times: (1..=states.len()).map(|k| k as f64 * h).collect(),
        states,
    })
}

/// Fits scene parameters so that the simulated trajectory matches ``reference`` (a
/// ``trajectory.csv`` path, an :class:`ecp.Trajectory` or a dict of arrays) starting from the
/// scene's values, as ``ecp fit`` does, and returns its report (``params``, ``cost``,
/// ``iterations``, ``termination``, ...) as a dict. ``method``: ``lbfgs`` (on exact gradients,
/// ``gradient="adjoint"``, or ``forward``, ``fd``) or ``nelder-mead``; ``weights`` as for
/// :func:`trajectory_gradient`.
#[pyfunction]
#[pyo3(signature = (scene, reference, params, *, method = "lbfgs", gradient = "adjoint", weights = None, steps = None, max_iters = None, tolerance = None, solver = None, formulation = None))]
#[allow(clippy::too_many_arguments)]
pub fn fit<'py>(
    py: Python<'py>,
    scene: &Scene,
    reference: &Bound<'py, PyAny>,
    params: Vec<String>,
    method: &str,
    gradient: &str,
    weights: Option<&Bound<'py, PyDict>>,
    steps: Option<usize>,
    max_iters: Option<u64>,
    tolerance: Option<f64>,
    solver: Option<&str>,
    formulation: Option<&str>,
) -> PyResult<Bound<'py, PyAny>> {
    let method = match method {
        "lbfgs" => Method::Lbfgs,
        "nelder-mead" | "nelder_mead" => Method::NelderMead,
        other => {
            return Err(argument(
                "method",
                InputErrorKind::UnknownName,
                format!("unknown method \"{other}\"; the methods are \"lbfgs\", \"nelder-mead\""),
            ));
        }
    };
    let gradient = match gradient {
        "adjoint" => GradientMethod::Adjoint,
        "forward" => GradientMethod::Forward,
        "fd" => GradientMethod::Fd,
        other => {
            return Err(argument(
                "gradient",
                InputErrorKind::UnknownName,
                format!(
                    "unknown gradient \"{other}\"; the gradients are \"adjoint\", \"forward\", \"fd\""
                ),
            ));
        }
    };
    if let Some(t) = tolerance
        && !(t.is_finite() && t >= 0.0)
    {
        return Err(argument(
            "tolerance",
            InputErrorKind::InvalidValue,
            format!("the tolerance must be a finite number ≥ 0, not {t}"),
        ));
    }
    if steps == Some(0) {
        return Err(argument(
            "steps",
            InputErrorKind::InvalidValue,
            "fit at least one step (steps=1 or more)",
        ));
    }
    let parsed = params
        .iter()
        .map(|n| param(n, &scene.file.scene))
        .collect::<PyResult<Vec<_>>>()?;
    if parsed.is_empty() {
        return Err(argument(
            "params",
            InputErrorKind::UnknownName,
            "no parameter to fit; name at least one, e.g. params=[\"mu\", \"e_r\"]",
        ));
    }
    let w = self::weights(weights)?;
    let mut reference = self::reference(reference, scene)?;
    if let Some(n) = steps {
        reference = reference.truncated(n);
    }
    let mut config = scene.file.solver.clone();
    if let Some(name) = solver {
        config.name = name.trim().to_string();
    }
    let formulation = match formulation {
        Some(name) => ecp::backends::parse_formulation(name)
            .map_err(|e| argument("formulation", InputErrorKind::UnknownName, e))?,
        None => scene.file.formulation.clone(),
    };
    let options = FitOptions {
        method,
        max_iters: max_iters.unwrap_or(match method {
            Method::Lbfgs => 100,
            Method::NelderMead => 400,
        }),
        tolerance: tolerance.unwrap_or(FitOptions::default().tolerance),
    };
    let rust_scene = scene.file.scene.clone();
    let report = guard(|| {
        py.detach(|| {
            TrajectoryProblem::from_scene(rust_scene, &formulation, config, reference, parsed)
                .and_then(|p| p.with_weights(w).with_gradient(gradient))
                .and_then(|p| ecp::fit::fit(p, &options))
        })
        .map_err(|e| match e {
            FitError::Input(e) => input(e),
            other => simulation(other),
        })
    })?;
    to_python(py, &report)
}

/// Solves the linear complementarity problem ``0 ≤ z ⊥ M z + q ≥ 0`` with Lemke's method, as
/// ``ecp lcp`` does, and returns ``{"status", "z", "w", "pivots", "solve_us", "residual",
/// "error"}`` (``z`` and ``w`` as numpy arrays, empty when there is no solution; ``status`` is
/// ``solved``, ``ray_termination``, ``max_pivots`` or ``singular_basis``).
#[pyfunction]
pub fn lcp<'py>(
    py: Python<'py>,
    m: &Bound<'py, PyAny>,
    q: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let bad = |key: &str, message: String| {
        input(RustInputError {
            file: None,
            key: Some(key.to_string()),
            line: None,
            kind: InputErrorKind::InvalidValue,
            message,
        })
    };
    let (q, q_shape) = f64_array(q, "q").map_err(|e| {
        PyTypeError::new_err(format!("q: expected a vector of numbers ({})", e.value(py)))
    })?;
    let (m, m_shape) = f64_array(m, "M").map_err(|e| {
        PyTypeError::new_err(format!("M: expected a matrix of numbers ({})", e.value(py)))
    })?;
    if q_shape.len() != 1 {
        return Err(bad(
            "q",
            format!("q has shape {q_shape:?}; it must be a vector"),
        ));
    }
    let n = q.len();
    if n == 0 {
        return Err(bad("q", "q is empty; give at least one component".into()));
    }
    if m_shape.len() != 2 || m_shape[0] != n || m_shape[1] != n {
        return Err(bad(
            "M",
            format!("M has shape {m_shape:?} but q has {n} components; M must be {n} × {n}"),
        ));
    }
    if m.iter().chain(&q).any(|v| !v.is_finite()) {
        return Err(bad("M", "M or q has a non-finite entry".into()));
    }
    let problem = Lcp { m, q };
    let report = guard(|| Ok(py.detach(|| solve_lcp(&problem))))?;
    let out = PyDict::new(py);
    out.set_item("status", &report.status)?;
    out.set_item("z", array(py, &[report.z.len()], report.z.clone()))?;
    out.set_item("w", array(py, &[report.w.len()], report.w.clone()))?;
    out.set_item("pivots", report.pivots)?;
    out.set_item("solve_us", report.solve_us)?;
    out.set_item("residual", report.residual)?;
    out.set_item("error", report.error.clone())?;
    Ok(out)
}
