//! The extension module `ecp._ecp` of the Python package `ecp` (`docs/python.md`): a thin layer
//! over the root crate `ecp` (scene files, runs, batches, fitting, LCPs) and
//! `ecp-formulations` (simulations, sensitivities). The physics and the solvers stay in Rust;
//! this crate converts arguments and results, releases the interpreter while batches, gradients,
//! fits and comparisons run, and turns errors into Python exceptions with the command line's
//! messages.
//!
//! Built by maturin (`python/pyproject.toml`); the pure-Python modules (`ecp.ray`) and the type
//! stubs are in `python/ecp/`.

use pyo3::prelude::*;

mod batch;
mod convert;
mod errors;
mod records;
mod scene;
mod sensitivity;
mod simulation;
mod state;
mod tools;

/// The extension module: classes, functions and exceptions that `ecp/__init__.py` re-exports.
#[pymodule]
fn _ecp(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("InputError", py.get_type::<errors::InputError>())?;
    m.add("SimulationError", py.get_type::<errors::SimulationError>())?;
    m.add("InternalError", py.get_type::<errors::InternalError>())?;
    m.add_class::<scene::Scene>()?;
    m.add_class::<state::State>()?;
    m.add_class::<records::Summary>()?;
    m.add_class::<records::Trajectory>()?;
    m.add_class::<simulation::Simulation>()?;
    m.add_class::<sensitivity::StepSensitivity>()?;
    m.add_class::<sensitivity::TrajectoryGradient>()?;
    m.add_class::<batch::BatchResult>()?;
    m.add_function(wrap_pyfunction!(scene::_restore_scene, m)?)?;
    m.add_function(wrap_pyfunction!(sensitivity::trajectory_gradient, m)?)?;
    m.add_function(wrap_pyfunction!(batch::batch, m)?)?;
    m.add_function(wrap_pyfunction!(batch::grid_points, m)?)?;
    m.add_function(wrap_pyfunction!(tools::compare, m)?)?;
    m.add_function(wrap_pyfunction!(tools::fit, m)?)?;
    m.add_function(wrap_pyfunction!(tools::lcp, m)?)?;
    Ok(())
}
