//! `ecp.State`: a rigid body's position, orientation and velocities as numpy arrays.

use nalgebra::{Vector3, Vector4};
use numpy::PyArrayDyn;
use pyo3::prelude::*;

use ecp_formulations::BodyState;

use crate::convert::{array, fixed};

/// A rigid body's state (world frame, ``docs/model.md#conventions``): CM ``position`` (3),
/// unit quaternion ``orientation`` (w, x, y, z; body to world), ``velocity`` of the CM (3) and
/// ``angular_velocity`` (3, world frame). Each is returned as a new numpy array.
#[pyclass(module = "ecp", name = "State", frozen)]
#[derive(Clone, Debug)]
pub struct State {
    pub(crate) inner: BodyState,
}

impl From<BodyState> for State {
    fn from(inner: BodyState) -> Self {
        State { inner }
    }
}

#[pymethods]
impl State {
    /// A state; ``orientation`` defaults to the identity, the velocities to zero. The
    /// quaternion is normalised by the simulation.
    #[new]
    #[pyo3(signature = (position, orientation = None, velocity = None, angular_velocity = None))]
    fn new(
        position: &Bound<'_, PyAny>,
        orientation: Option<&Bound<'_, PyAny>>,
        velocity: Option<&Bound<'_, PyAny>>,
        angular_velocity: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<State> {
        let x = Vector3::from(fixed::<3>(position, "position")?);
        let q = match orientation {
            Some(o) => Vector4::from(fixed::<4>(o, "orientation")?),
            None => Vector4::new(1.0, 0.0, 0.0, 0.0),
        };
        let v = match velocity {
            Some(o) => Vector3::from(fixed::<3>(o, "velocity")?),
            None => Vector3::zeros(),
        };
        let w = match angular_velocity {
            Some(o) => Vector3::from(fixed::<3>(o, "angular_velocity")?),
            None => Vector3::zeros(),
        };
        Ok(State {
            inner: BodyState { x, q, v, w },
        })
    }

    /// CM position (m).
    #[getter]
    fn position<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        array(py, &[3], self.inner.x.as_slice().to_vec())
    }

    /// Orientation quaternion (w, x, y, z).
    #[getter]
    fn orientation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        array(py, &[4], self.inner.q.as_slice().to_vec())
    }

    /// CM velocity (m/s).
    #[getter]
    fn velocity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        array(py, &[3], self.inner.v.as_slice().to_vec())
    }

    /// Angular velocity (rad/s, world frame).
    #[getter]
    fn angular_velocity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        array(py, &[3], self.inner.w.as_slice().to_vec())
    }

    /// The 13 numbers ``position, orientation, velocity, angular_velocity`` in one array (the
    /// order of the sensitivities' state).
    fn to_array<'py>(&self, py: Python<'py>) -> Bound<'py, PyArrayDyn<f64>> {
        array(py, &[13], flat(&self.inner).to_vec())
    }

    fn __repr__(&self) -> String {
        let s = &self.inner;
        format!(
            "State(position={:?}, orientation={:?}, velocity={:?}, angular_velocity={:?})",
            s.x.as_slice(),
            s.q.as_slice(),
            s.v.as_slice(),
            s.w.as_slice()
        )
    }

    fn __eq__(&self, other: &State) -> bool {
        self.inner == other.inner
    }
}

/// `x, Q, v, ω` of a state in one array.
pub(crate) fn flat(s: &BodyState) -> [f64; 13] {
    [
        s.x.x, s.x.y, s.x.z, s.q[0], s.q[1], s.q[2], s.q[3], s.v.x, s.v.y, s.v.z, s.w.x, s.w.y,
        s.w.z,
    ]
}
