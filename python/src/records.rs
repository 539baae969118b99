//! Step records as Python objects: `ecp.Summary` (one step) and `ecp.Trajectory` (a run, as
//! numpy arrays and as the columns of `trajectory.csv`).

use numpy::PyArrayDyn;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use ecp_formulations::StepRecord;

use crate::convert::{array, bool_array, int_array};
use crate::state::{State, flat};

/// The summary of one step: how it was solved and how well.
#[pyclass(module = "ecp", name = "Summary", frozen, get_all)]
#[derive(Clone, Debug)]
pub struct Summary {
    /// The step's index, from 1.
    pub step: usize,
    /// Time at the end of the step (s).
    pub t: f64,
    /// Whether the step passed the natural-residual test (a failed step keeps the state at its
    /// start: it is never an answer).
    pub converged: bool,
    /// Natural-map residual of the accepted point (or of the best attempt of a failed step).
    pub residual: f64,
    /// Solver iterations.
    pub iterations: usize,
    /// Function evaluations.
    pub f_evals: usize,
    /// The backend that solved it (the primary one unless ``method`` names a fallback).
    pub solver: String,
    /// Why the solver stopped.
    pub termination: String,
    /// How the step was solved: ``direct``, ``backend``, ``substeps``, ``failed``.
    pub method: String,
    /// The ``fallback`` column of ``trajectory.csv`` (empty for a direct solve).
    pub fallback: String,
    /// Kinetic plus potential energy after the step (J).
    pub energy: f64,
    /// Wall time of the step's solve (µs): a timing, not a result.
    pub solve_us: f64,
}

impl From<&StepRecord> for Summary {
    fn from(r: &StepRecord) -> Self {
        Summary {
            step: r.step,
            t: r.t,
            converged: r.converged,
            residual: r.summary.residual,
            iterations: r.summary.iterations,
            f_evals: r.summary.f_evals,
            solver: r.summary.solver.clone(),
            termination: r.summary.termination.to_string(),
            method: r.method.kind().to_string(),
            fallback: r.method.column(),
            energy: r.energy,
            solve_us: r.solve_us,
        }
    }
}

#[pymethods]
impl Summary {
    fn __repr__(&self) -> String {
        format!(
            "Summary(step={}, t={}, converged={}, residual={:.3e}, iterations={}, solver={:?}, \
             method={:?})",
            self.step,
            self.t,
            if self.converged { "True" } else { "False" },
            self.residual,
            self.iterations,
            self.solver,
            self.method
        )
    }
}

/// A run's step records, as numpy arrays (first axis: the steps).
///
/// ``position`` (steps × bodies × 3), ``orientation`` (× 4), ``velocity``, ``angular_velocity``,
/// ``t``, ``energy``, ``residual``, ``iterations``, ``converged``, and per contact ``ecp``
/// (steps × contacts × 3, the equivalent contact point), ``pn``, ``pt``, ``po``, ``pr``,
/// ``sigma``, ``min_gap``. :meth:`columns` gives the columns of ``trajectory.csv``
/// (``docs/outputs.md``) as a dict that ``pandas.DataFrame`` takes as it is. ``solve_us`` is a
/// timing, not a result.
#[pyclass(module = "ecp", name = "Trajectory", frozen)]
pub struct Trajectory {
    pub(crate) records: Vec<StepRecord>,
    pub(crate) bodies: usize,
    pub(crate) contacts_per_body: usize,
}

impl Trajectory {
    pub(crate) fn new(records: Vec<StepRecord>, bodies: usize, contacts_per_body: usize) -> Self {
        Trajectory {
            records,
            bodies,
            contacts_per_body,
        }
    }

    fn per_body<'py>(
        &self,
        py: Python<'py>,
        width: usize,
        f: impl Fn(&ecp_formulations::BodyState) -> Vec<f64>,
    ) -> Bound<'py, PyArrayDyn<f64>> {
        let mut data = Vec::with_capacity(self.records.len() * self.bodies * width);
        for r in &self.records {
            for b in 0..self.bodies {
                match r.bodies.get(b) {
                    Some(s) => data.extend(f(s)),
                    None => data.extend(std::iter::repeat_n(f64::NAN, width)),
                }
            }
        }
        array(py, &[self.records.len(), self.bodies, width], data)
    }

    fn contacts(&self) -> usize {
        self.bodies * self.contacts_per_body
    }

    fn per_contact<'py>(
        &self,
        py: Python<'py>,
        f: impl Fn(&ecp_formulations::ContactRecord) -> f64,
    ) -> Bound<'py, PyArrayDyn<f64>> {
        let n = self.contacts();
        let mut data = Vec::with_capacity(self.records.len() * n);
        for r in &self.records {
            for c in 0..n {
                data.push(r.contacts.get(c).map_or(f64::NAN, &f));
            }
        }
        array(py, &[self.records.len(), n], data)
    }

    fn scalar<'py>(
        &self,
        py: Python<'py>,
        f: impl Fn(&StepRecord) -> f64,
    ) -> Bound<'py, PyArrayDyn<f64>> {
        array(
            py,
            &[self.records.len()],
            self.records.iter().map(f).collect(),
        )
    }
}

#[pymethods]
impl Trajectory {
    fn __len__(&self) -> usize {
        self.records.len()
    }

    /// Number of bodies.
    #[getter]
    fn num_bodies(&self) -> usize {
        self.bodies
    }

    /// Contacts per body (one per half-space; per piece and half-space for ``union``; per
    /// vertex for ``point``).
    #[getter]
    fn contacts_per_body(&self) -> usize {
        self.contacts_per_body
    }

    /// Time at the end of each step (s).
    #[getter]
    fn t<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.scalar(py, |r| r.t)
    }

    /// Step indices, from 1.
    #[getter]
    fn step<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<i64>> {
        int_array(py, self.records.iter().map(|r| r.step as i64).collect())
    }

    /// CM positions, steps × bodies × 3.
    #[getter]
    fn position<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_body(py, 3, |s| s.x.as_slice().to_vec())
    }

    /// Orientations (w, x, y, z), steps × bodies × 4.
    #[getter]
    fn orientation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_body(py, 4, |s| s.q.as_slice().to_vec())
    }

    /// CM velocities, steps × bodies × 3.
    #[getter]
    fn velocity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_body(py, 3, |s| s.v.as_slice().to_vec())
    }

    /// Angular velocities (world frame), steps × bodies × 3.
    #[getter]
    fn angular_velocity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_body(py, 3, |s| s.w.as_slice().to_vec())
    }

    /// Every body's 13 state numbers, steps × bodies × 13.
    #[getter]
    fn states<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_body(py, 13, |s| flat(s).to_vec())
    }

    /// Energy after each step (J).
    #[getter]
    fn energy<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.scalar(py, |r| r.energy)
    }

    /// Natural residual of each step.
    #[getter]
    fn residual<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.scalar(py, |r| r.summary.residual)
    }

    /// Solver iterations of each step.
    #[getter]
    fn iterations<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<i64>> {
        int_array(
            py,
            self.records
                .iter()
                .map(|r| r.summary.iterations as i64)
                .collect(),
        )
    }

    /// Whether each step converged.
    #[getter]
    fn converged<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<bool>> {
        bool_array(py, self.records.iter().map(|r| r.converged).collect())
    }

    /// The ``fallback`` column of each step (empty: solved directly).
    #[getter]
    fn fallback(&self) -> Vec<String> {
        self.records.iter().map(|r| r.method.column()).collect()
    }

    /// Wall time of each step's solve (µs): a timing, not a result.
    #[getter]
    fn solve_us<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.scalar(py, |r| r.solve_us)
    }

    /// The equivalent contact point of each contact, steps × contacts × 3 (world frame).
    #[getter]
    fn ecp<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        let n = self.contacts();
        let mut data = Vec::with_capacity(self.records.len() * n * 3);
        for r in &self.records {
            for c in 0..n {
                match r.contacts.get(c) {
                    Some(c) => data.extend_from_slice(c.a1.as_slice()),
                    None => data.extend([f64::NAN; 3]),
                }
            }
        }
        array(py, &[self.records.len(), n, 3], data)
    }

    /// Normal impulse of each contact (N·s), steps × contacts.
    #[getter]
    fn pn<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_contact(py, |c| c.pn)
    }

    /// Tangential friction impulse along t.
    #[getter]
    fn pt<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_contact(py, |c| c.pt)
    }

    /// Tangential friction impulse along o.
    #[getter]
    fn po<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_contact(py, |c| c.po)
    }

    /// Torsional friction impulse.
    #[getter]
    fn pr<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_contact(py, |c| c.pr)
    }

    /// Slip-rate multiplier σ.
    #[getter]
    fn sigma<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_contact(py, |c| c.sigma)
    }

    /// Minimum gap of the real body's vertices to the half-space (m).
    #[getter]
    fn min_gap<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        self.per_contact(py, |c| c.min_gap)
    }

    /// Contact mode of each contact (``patch``, ``line``, ``point``, ``none``), steps ×
    /// contacts.
    #[getter]
    fn mode(&self) -> Vec<Vec<String>> {
        self.records
            .iter()
            .map(|r| {
                r.contacts
                    .iter()
                    .map(|c| c.mode.as_str().to_string())
                    .collect()
            })
            .collect()
    }

    /// The last state of every body.
    #[getter]
    fn final_states(&self) -> Vec<State> {
        self.records
            .last()
            .map(|r| r.bodies.iter().map(|s| State::from(*s)).collect())
            .unwrap_or_default()
    }

    /// Each step's :class:`Summary`.
    fn summaries(&self) -> Vec<Summary> {
        self.records.iter().map(Summary::from).collect()
    }

    /// The columns of ``contacts.csv`` (``docs/outputs.md#contactscsv``): one entry per step and
    /// active contact between two named bodies (the ``bodies`` formulation; empty for the
    /// others), as a dict of 1-D numpy arrays (lists of strings for ``body_a``, ``body_b`` and
    /// ``mode``) that ``pandas.DataFrame`` takes as it is.
    #[pyo3(name = "contacts")]
    fn contacts_table<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let rows: Vec<(&StepRecord, &ecp_formulations::PairRecord)> = self
            .records
            .iter()
            .flat_map(|r| r.pairs.iter().map(move |p| (r, p)))
            .collect();
        let k = rows.len();
        let out = PyDict::new(py);
        let steps: Vec<i64> = rows.iter().map(|(r, _)| r.step as i64).collect();
        out.set_item("step", int_array(py, steps))?;
        out.set_item(
            "t",
            array(py, &[k], rows.iter().map(|(r, _)| r.t).collect()),
        )?;
        let names = |f: fn(&ecp_formulations::PairRecord) -> &str| -> Vec<String> {
            rows.iter().map(|(_, p)| f(p).to_string()).collect()
        };
        out.set_item("body_a", names(|p| p.body_a.as_str()))?;
        out.set_item("body_b", names(|p| p.body_b.as_str()))?;
        type Field = fn(&ecp_formulations::PairRecord) -> f64;
        let fields: [(&str, Field); 15] = [
            ("a1_x", |p| p.a1.x),
            ("a1_y", |p| p.a1.y),
            ("a1_z", |p| p.a1.z),
            ("a2_x", |p| p.a2.x),
            ("a2_y", |p| p.a2.y),
            ("a2_z", |p| p.a2.z),
            ("n_x", |p| p.normal.x),
            ("n_y", |p| p.normal.y),
            ("n_z", |p| p.normal.z),
            ("pn", |p| p.pn),
            ("pt", |p| p.pt),
            ("po", |p| p.po),
            ("pr", |p| p.pr),
            ("sigma", |p| p.sigma),
            ("gap", |p| p.gap),
        ];
        for (name, f) in fields {
            out.set_item(
                name,
                array(py, &[k], rows.iter().map(|(_, p)| f(p)).collect()),
            )?;
        }
        out.set_item("mode", names(|p| p.mode.as_str()))?;
        Ok(out)
    }

    /// The columns of ``trajectory.csv`` (``docs/outputs.md``), names as in its header: a dict
    /// of 1-D numpy arrays (lists of strings for ``mode`` and ``fallback``) that
    /// ``pandas.DataFrame`` takes as it is.
    fn columns<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let header = StepRecord::csv_header(self.bodies, self.contacts_per_body);
        let k = self.records.len();
        let out = PyDict::new(py);
        let mut index = 0;
        let put_f64 = |name: &str, values: Vec<f64>| -> PyResult<()> {
            out.set_item(name, array(py, &[k], values))
        };
        put_f64(&header[index], self.records.iter().map(|r| r.t).collect())?;
        index += 1;
        for b in 0..self.bodies {
            for c in 0..13 {
                let values = self
                    .records
                    .iter()
                    .map(|r| r.bodies.get(b).map_or(f64::NAN, |s| flat(s)[c]))
                    .collect();
                put_f64(&header[index], values)?;
                index += 1;
            }
            for j in 0..self.contacts_per_body {
                let ci = b * self.contacts_per_body + j;
                let fields: [fn(&ecp_formulations::ContactRecord) -> f64; 9] = [
                    |c| c.a1.x,
                    |c| c.a1.y,
                    |c| c.a1.z,
                    |c| c.pn,
                    |c| c.pt,
                    |c| c.po,
                    |c| c.pr,
                    |c| c.sigma,
                    |c| c.min_gap,
                ];
                for f in fields {
                    let values = self
                        .records
                        .iter()
                        .map(|r| r.contacts.get(ci).map_or(f64::NAN, f))
                        .collect();
                    put_f64(&header[index], values)?;
                    index += 1;
                }
                let modes: Vec<String> = self
                    .records
                    .iter()
                    .map(|r| {
                        r.contacts
                            .get(ci)
                            .map_or(String::new(), |c| c.mode.as_str().to_string())
                    })
                    .collect();
                out.set_item(&header[index], modes)?;
                index += 1;
            }
        }
        out.set_item(
            &header[index],
            int_array(
                py,
                self.records
                    .iter()
                    .map(|r| r.summary.iterations as i64)
                    .collect(),
            ),
        )?;
        out.set_item(
            &header[index + 1],
            array(
                py,
                &[k],
                self.records.iter().map(|r| r.summary.residual).collect(),
            ),
        )?;
        out.set_item(
            &header[index + 2],
            array(py, &[k], self.records.iter().map(|r| r.solve_us).collect()),
        )?;
        out.set_item(&header[index + 3], self.fallback())?;
        Ok(out)
    }

    fn __repr__(&self) -> String {
        format!(
            "Trajectory(steps={}, bodies={}, contacts_per_body={})",
            self.records.len(),
            self.bodies,
            self.contacts_per_body
        )
    }
}
