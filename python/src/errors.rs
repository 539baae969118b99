//! The package's exceptions and the boundary that turns Rust errors (and, as a last line of
//! defence, panics) into them, with the messages the command line prints.

use std::panic::{AssertUnwindSafe, catch_unwind};

use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use ecp::error::{InputError as RustInputError, InputErrorKind};

create_exception!(
    _ecp,
    InputError,
    PyValueError,
    "Bad input: a scene file or dict, a parameter name or value, an option. The message names the \
     file, the key and the line where there is one, says what is wrong and how to fix it (the same \
     text as the `ecp` command line)."
);
create_exception!(
    _ecp,
    SimulationError,
    PyRuntimeError,
    "A step that no backend, fallback or substep could solve, a formulation that stopped \
     applying, or derivatives that do not exist at this point. A failed step is never taken as an \
     answer: the bodies keep their state at its start."
);
create_exception!(
    _ecp,
    InternalError,
    PyRuntimeError,
    "A defect in ecp (a Rust panic caught at the Python boundary); please report it with the \
     input that caused it."
);

/// An [`InputError`] exception with the message of `e`.
pub fn input(e: impl std::fmt::Display) -> PyErr {
    InputError::new_err(e.to_string())
}

/// A [`SimulationError`] exception with the message of `e`.
pub fn simulation(e: impl std::fmt::Display) -> PyErr {
    SimulationError::new_err(e.to_string())
}

/// An error about an argument of a Python call, shown as the command line shows an option.
pub fn argument(name: &str, kind: InputErrorKind, message: impl Into<String>) -> PyErr {
    input(RustInputError::option(name, kind, message))
}

/// Runs `f`, turning a panic into an [`InternalError`] instead of letting it reach the
/// interpreter as a `BaseException`.
pub fn guard<T>(f: impl FnOnce() -> PyResult<T>) -> PyResult<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(result) => result,
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(InternalError::new_err(format!(
                "internal error in ecp: {what}; please report it with the scene and the call \
                 that caused it"
            )))
        }
    }
}
