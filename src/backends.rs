//! Solver backends by name, as written in scene files and on the command line: the solver
//! settings of a scene, and the one place that builds a solver from them, always through an
//! [`ecp_solvers::Registry`] (the built-in one, or one a caller extended with its own
//! backends, `examples/custom_backend.rs`).

use ecp_model::McpSolver;
use ecp_solvers::registry::{BackendOptions, Registry, RegistryError};

use crate::error::{InputError, InputErrorKind};

pub use ecp_formulations::Formulation;

/// The backend a scene uses when its `[solver]` table names none.
pub const DEFAULT_SOLVER: &str = "newton";

/// Solver choice and settings of a scene (`[solver]`); unset settings keep the backend's
/// documented defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct SolverConfig {
    /// The backend's name in the registry (`newton`, `path`, `conic`, or a user's backend).
    pub name: String,
    /// Tolerance on the natural-map residual.
    pub tolerance: Option<f64>,
    /// Iteration limit per step.
    pub max_iterations: Option<usize>,
}

impl SolverConfig {
    /// The backend `name` with its default settings.
    pub fn named(name: impl Into<String>) -> Self {
        SolverConfig {
            name: name.into(),
            ..SolverConfig::default()
        }
    }
}

impl Default for SolverConfig {
    fn default() -> Self {
        SolverConfig {
            name: DEFAULT_SOLVER.to_string(),
            tolerance: None,
            max_iterations: None,
        }
    }
}

/// Builds the built-in solver of `config` for the hull formulation: [`make_solver_in`] with
/// [`Registry::builtin`].
pub fn make_solver(config: &SolverConfig) -> Result<Box<dyn McpSolver>, InputError> {
    make_solver_in(&Registry::builtin(), config, Formulation::Hull)
}

/// [`make_solver`] for the step problems of `formulation` ([`make_solver_in`] with
/// [`Registry::builtin`]).
pub fn make_solver_for(
    config: &SolverConfig,
    formulation: Formulation,
) -> Result<Box<dyn McpSolver>, InputError> {
    make_solver_in(&Registry::builtin(), config, formulation)
}

/// Builds the solver of `config` from `registry` for the step problems of `formulation`: the
/// backend's documented default settings, with the scene's tolerance and iteration limit where
/// given, validated by the registry. The union formulation's solutions are not isolated
/// ([`BackendOptions::non_isolated_solutions`]; Newton then takes minimum-norm least-squares
/// steps). The command line, the fallbacks of a run and fitting all build their solvers here,
/// so that no path builds a backend with other settings.
pub fn make_solver_in(
    registry: &Registry,
    config: &SolverConfig,
    formulation: Formulation,
) -> Result<Box<dyn McpSolver>, InputError> {
    check_combination(registry, &config.name, formulation)?;
    let options = BackendOptions {
        tolerance: config.tolerance,
        max_iterations: config.max_iterations,
        non_isolated_solutions: formulation == Formulation::Union,
    };
    registry.build(&config.name, &options).map_err(|e| {
        InputError::option(
            "[solver]",
            InputErrorKind::InvalidValue,
            format!("{e}; fix the scene's [solver] table"),
        )
    })
}

/// Checks that `registry` has a backend called `solver` (the error lists the names it has) and
/// that it can solve the step problems of `formulation`: a backend that needs the structural
/// view of an ECP step ([`ecp_model::StepStructure`]), such as the conic one, only solves the
/// formulations that build it (hull and union).
pub fn check_combination(
    registry: &Registry,
    solver: &str,
    formulation: Formulation,
) -> Result<(), InputError> {
    let backend = registry.get(solver).map_err(|e| {
        let kind = match e {
            RegistryError::Unknown { .. } => InputErrorKind::UnknownName,
            _ => InputErrorKind::InvalidValue,
        };
        InputError::option("--solver", kind, e.to_string())
    })?;
    if backend.needs_structure() && !formulation.has_step_structure() {
        let able: Vec<String> = Formulation::ALL
            .into_iter()
            .filter(|f| f.has_step_structure())
            .map(|f| format!("\"{f}\""))
            .collect();
        let others: Vec<String> = registry
            .names()
            .into_iter()
            .filter(|n| registry.get(n).is_ok_and(|b| !b.needs_structure()))
            .map(|n| format!("--solver {n}"))
            .collect();
        return Err(InputError::option(
            "--solver",
            InputErrorKind::UnknownName,
            format!(
                "the {solver} backend cannot solve the {formulation} formulation: it needs the \
                 contact structure of an ECP step, which only {} build; use {} with \
                 --formulation {formulation}",
                able.join(", "),
                others.join(" or ")
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_names_and_impossible_combinations_are_refused_with_the_names() {
        let r = Registry::builtin();
        let e = check_combination(&r, "simplex", Formulation::Hull).unwrap_err();
        assert_eq!(e.kind, InputErrorKind::UnknownName);
        assert!(
            e.message.contains("unknown solver \"simplex\"")
                && e.message.contains("\"newton\", \"path\", \"conic\""),
            "{}",
            e.message
        );
        let e = check_combination(&r, "conic", Formulation::Point).unwrap_err();
        assert!(
            e.message.contains("cannot solve the point formulation")
                && e.message.contains("--solver newton or --solver path"),
            "{}",
            e.message
        );
        check_combination(&r, "conic", Formulation::Union).unwrap();
        let config = SolverConfig {
            tolerance: Some(-1.0),
            ..SolverConfig::named("path")
        };
        let e = make_solver_in(&r, &config, Formulation::Hull)
            .err()
            .unwrap();
        assert!(e.message.contains("`tolerance`"), "{}", e.message);
        assert_eq!(
            make_solver(&SolverConfig::default()).unwrap().name(),
            "newton"
        );
    }
}
