//! `ecp.batch`: many runs on every core with the interpreter released, results in input order
//! and bitwise independent of the thread count (`ecp::batch`).

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use ecp::batch::{Axis, Batch, BatchOptions, Column, Grid, JobResult, table, timing_table};
use ecp::error::InputErrorKind;
use ecp_formulations::sensitivity::Param;

use crate::convert::{array, f64_array, type_name, uint_array};
use crate::errors::{argument, guard, input};
use crate::records::Trajectory;
use crate::scene::{Scene, param, param_values};

/// The results of a batch, in input order.
///
/// ``table``: one row per run, a dict of columns (numpy arrays; lists of strings for ``scene``
/// and ``error``) that ``pandas.DataFrame`` takes as it is, named as the columns of
/// ``sweep.csv`` (``docs/outputs.md``). These are the results: bitwise the same whatever the
/// thread count. ``timings`` (``index``, ``wall_s``, ``solve_s``) are wall-clock times, not
/// results. ``trajectories`` holds every run's :class:`Trajectory` when the batch kept records.
#[pyclass(module = "ecp", name = "BatchResult", frozen)]
pub struct BatchResult {
    results: Vec<JobResult>,
    contacts_per_body: Vec<usize>,
    threads: usize,
    records: bool,
}

fn columns<'py>(py: Python<'py>, cols: Vec<(String, Column)>) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    for (name, col) in cols {
        match col {
            Column::F64(v) => {
                let n = v.len();
                out.set_item(name, array(py, &[n], v))?;
            }
            Column::U64(v) => out.set_item(name, uint_array(py, v))?,
            Column::Str(v) => out.set_item(name, PyList::new(py, v)?)?,
        }
    }
    Ok(out)
}

#[pymethods]
impl BatchResult {
    fn __len__(&self) -> usize {
        self.results.len()
    }

    /// The results, one row per run (no timings).
    #[getter]
    fn table<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        columns(py, table(&self.results))
    }

    /// Wall-clock times of the runs: not results.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        columns(py, timing_table(&self.results))
    }

    /// Every run's trajectory, in the order of the table's rows (a run that failed before its
    /// first step has an empty one); an empty list unless the batch ran with ``records=True``.
    #[getter]
    fn trajectories(&self) -> Vec<Trajectory> {
        if !self.records {
            return Vec::new();
        }
        self.results
            .iter()
            .zip(&self.contacts_per_body)
            .map(|(r, &cpb)| {
                let bodies = r.summary.final_bodies.len();
                Trajectory::new(r.records.clone(), bodies, cpb)
            })
            .collect()
    }

    /// The error of each run (``None`` for a run that reached its end with every step solved).
    #[getter]
    fn errors(&self) -> Vec<Option<String>> {
        self.results.iter().map(|r| r.error.clone()).collect()
    }

    /// Runs with a failed step or an error.
    #[getter]
    fn failed(&self) -> usize {
        self.results
            .iter()
            .filter(|r| r.error.is_some() || r.summary.failed_steps > 0)
            .count()
    }

    /// Threads the batch ran on.
    #[getter]
    fn threads(&self) -> usize {
        self.threads
    }

    fn __repr__(&self) -> String {
        format!(
            "BatchResult(runs={}, failed={}, threads={})",
            self.results.len(),
            self.failed(),
            self.threads
        )
    }
}

/// Grid axes from a dict `{name: values}` (the last key varies fastest).
fn grid_of(grid: &Bound<'_, PyDict>, scene: &Scene) -> PyResult<Grid> {
    let mut axes: Vec<Axis> = Vec::with_capacity(grid.len());
    for (k, v) in grid.iter() {
        let name: String = k.extract().map_err(|_| {
            PyTypeError::new_err("grid: parameter names must be strings such as \"mu\"")
        })?;
        let p: Param = param(&name, &scene.file.scene)?;
        let (values, shape) = f64_array(&v, &format!("grid[{name:?}]"))?;
        if shape.len() > 1 {
            return Err(argument(
                "grid",
                InputErrorKind::WrongType,
                format!("grid[{name:?}] has shape {shape:?}; give a 1-D list of values"),
            ));
        }
        if values.is_empty() {
            return Err(argument(
                "grid",
                InputErrorKind::InvalidValue,
                format!("grid[{name:?}] has no value; give at least one"),
            ));
        }
        if axes.iter().any(|a| a.param == p) {
            return Err(argument(
                "grid",
                InputErrorKind::InvalidValue,
                format!("parameter {p} appears twice in the grid"),
            ));
        }
        axes.push(Axis { param: p, values });
    }
    Ok(Grid { axes })
}

/// The points of a grid `{name: values}` in batch order (the last key varies fastest), as a
/// list of dicts `{name: value}`: what :func:`batch` runs for ``grid=``, so that a sweep split
/// into chunks (``ecp.ray``) runs the same points in the same order.
#[pyfunction]
pub fn grid_points<'py>(
    py: Python<'py>,
    scene: &Scene,
    grid: &Bound<'py, PyDict>,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let grid = grid_of(grid, scene)?;
    grid.points()
        .into_iter()
        .map(|point| {
            let d = PyDict::new(py);
            for (p, v) in point {
                d.set_item(p.to_string(), v)?;
            }
            Ok(d)
        })
        .collect()
}

/// Runs many simulations at once on ``threads`` threads (default: one per core), with the
/// interpreter released, and returns a :class:`BatchResult` in input order.
///
/// Either ``scenes`` is a list of :class:`Scene` (each run as it is), or one scene with
/// ``grid={"mu": [0.1, 0.2], "fx": [10, 20, 40]}`` (every combination; the last key varies
/// fastest) or ``points=[{"mu": 0.1, "fx": 10}, ...]``. Parameters are those of
/// :meth:`Scene.with_params` (μ, masses, inertia, initial states ``x0`` ... ``wz0``, constant
/// loads ``fx`` ... ``tz``). ``steps`` caps every run; ``solver`` and ``formulation`` override
/// the scenes'; ``fallbacks`` as ``ecp run``; ``keep_going`` runs past failed steps;
/// ``records=True`` keeps every step (``trajectories``).
///
/// The results are bitwise identical whatever ``threads`` is and from run to run: each run is
/// computed by one thread from start to end and nothing is shared between runs.
#[pyfunction]
#[pyo3(signature = (scenes, grid = None, points = None, *, threads = None, steps = None, solver = None, formulation = None, fallbacks = true, keep_going = false, records = false))]
#[allow(clippy::too_many_arguments)]
pub fn batch(
    py: Python<'_>,
    scenes: &Bound<'_, PyAny>,
    grid: Option<&Bound<'_, PyDict>>,
    points: Option<&Bound<'_, PyAny>>,
    threads: Option<usize>,
    steps: Option<usize>,
    solver: Option<&str>,
    formulation: Option<&str>,
    fallbacks: bool,
    keep_going: bool,
    records: bool,
) -> PyResult<BatchResult> {
    let list: Vec<Scene> = if let Ok(s) = scenes.cast::<Scene>() {
        vec![s.get().clone()]
    } else {
        let mut out = Vec::new();
        for item in scenes.try_iter().map_err(|_| {
            PyTypeError::new_err(format!(
                "scenes: expected an ecp.Scene or a list of them, got {}",
                type_name(scenes)
            ))
        })? {
            let item = item?;
            let s = item.cast::<Scene>().map_err(|_| {
                PyTypeError::new_err(format!(
                    "scenes: every item must be an ecp.Scene, got {}",
                    type_name(&item)
                ))
            })?;
            out.push(s.get().clone());
        }
        out
    };
    let batch = match (grid, points) {
        (None, None) => Batch::scenes(list.into_iter().map(|s| s.file)),
        (Some(_), Some(_)) => {
            return Err(argument(
                "grid",
                InputErrorKind::InvalidValue,
                "give grid= or points=, not both",
            ));
        }
        (g, p) => {
            let [scene] = list.as_slice() else {
                return Err(argument(
                    "scenes",
                    InputErrorKind::InvalidValue,
                    format!(
                        "a grid or points run one scene; {} were given (run several scenes \
                         without grid/points)",
                        list.len()
                    ),
                ));
            };
            let point_list = match (g, p) {
                (Some(g), _) => grid_of(g, scene)?.points(),
                (_, Some(p)) => {
                    let mut out = Vec::new();
                    for item in p.try_iter()? {
                        let item = item?;
                        let d = item.cast::<PyDict>().map_err(|_| {
                            PyTypeError::new_err(format!(
                                "points: every point must be a dict {{name: value}}, got {}",
                                type_name(&item)
                            ))
                        })?;
                        out.push(param_values(d, &scene.file.scene)?);
                    }
                    out
                }
                _ => Vec::new(),
            };
            Batch::points(&scene.file, point_list).map_err(input)?
        }
    };
    let options = BatchOptions {
        threads,
        steps,
        solver: solver.map(str::to_string),
        formulation: formulation
            .map(|n| {
                ecp::backends::parse_formulation(n)
                    .map_err(|e| argument("formulation", InputErrorKind::UnknownName, e))
            })
            .transpose()?,
        fallbacks,
        keep_going,
        records,
        ..BatchOptions::default()
    };
    let results = guard(|| py.detach(|| batch.run(&options)).map_err(input))?;
    let contacts_per_body = batch
        .jobs
        .iter()
        .zip(&results)
        .map(|(job, r)| {
            r.records.first().map_or(0, |rec| {
                rec.contacts.len() / job.file.scene.bodies.len().max(1)
            })
        })
        .collect();
    Ok(BatchResult {
        threads: threads
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
        results,
        contacts_per_body,
        records,
    })
}
