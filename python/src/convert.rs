//! Conversions between Python values (numbers, sequences, numpy arrays) and the Rust types, with
//! errors that name the argument.

use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

/// `obj` as a C-ordered float64 array (anything numpy takes: lists, tuples, arrays, scalars):
/// its data and its shape. `what` names the argument in the error.
pub fn f64_array(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<(Vec<f64>, Vec<usize>)> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let array = np
        .call_method1("ascontiguousarray", (obj, "float64"))
        .map_err(|e| {
            PyTypeError::new_err(format!(
                "{what}: expected numbers (a number, a sequence or a numpy array), got {} ({})",
                type_name(obj),
                e.value(py)
            ))
        })?;
    let array = array.cast_into::<PyArrayDyn<f64>>().map_err(|_| {
        PyTypeError::new_err(format!("{what}: expected an array of float64 numbers"))
    })?;
    let shape = array.shape().to_vec();
    let data = array.readonly().as_array().iter().copied().collect();
    Ok((data, shape))
}

/// `obj` as exactly `N` finite numbers.
pub fn fixed<const N: usize>(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<[f64; N]> {
    let (data, shape) = f64_array(obj, what)?;
    if shape.len() != 1 || data.len() != N {
        return Err(PyValueError::new_err(format!(
            "{what}: expected {N} numbers, got an array of shape {shape:?}"
        )));
    }
    if let Some(v) = data.iter().find(|v| !v.is_finite()) {
        return Err(crate::errors::InputError::new_err(format!(
            "{what}: {v} is not a finite number; give finite values"
        )));
    }
    let mut out = [0.0; N];
    out.copy_from_slice(&data);
    Ok(out)
}

/// The Python type name of `obj`, for messages.
pub fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".into())
}

/// A numpy array of `shape` from row-major `data`.
pub fn array<'py>(py: Python<'py>, shape: &[usize], data: Vec<f64>) -> Bound<'py, PyArrayDyn<f64>> {
    match ArrayD::from_shape_vec(IxDyn(shape), data) {
        Ok(a) => a.into_pyarray(py),
        // The callers build `data` with the product of `shape` entries; an empty array keeps a
        // mismatch visible without a panic.
        Err(_) => ArrayD::<f64>::zeros(IxDyn(&[0])).into_pyarray(py),
    }
}

/// A numpy array of integers of `shape` from row-major `data`.
pub fn int_array<'py>(py: Python<'py>, data: Vec<i64>) -> Bound<'py, PyArrayDyn<i64>> {
    let n = data.len();
    match ArrayD::from_shape_vec(IxDyn(&[n]), data) {
        Ok(a) => a.into_pyarray(py),
        Err(_) => ArrayD::<i64>::zeros(IxDyn(&[0])).into_pyarray(py),
    }
}

/// A numpy array of unsigned integers.
pub fn uint_array<'py>(py: Python<'py>, data: Vec<u64>) -> Bound<'py, PyArrayDyn<u64>> {
    let n = data.len();
    match ArrayD::from_shape_vec(IxDyn(&[n]), data) {
        Ok(a) => a.into_pyarray(py),
        Err(_) => ArrayD::<u64>::zeros(IxDyn(&[0])).into_pyarray(py),
    }
}

/// A numpy array of booleans.
pub fn bool_array<'py>(py: Python<'py>, data: Vec<bool>) -> Bound<'py, PyArrayDyn<bool>> {
    let n = data.len();
    match ArrayD::from_shape_vec(IxDyn(&[n]), data) {
        Ok(a) => a.into_pyarray(py),
        Err(_) => ArrayD::<bool>::from_elem(IxDyn(&[0]), false).into_pyarray(py),
    }
}
