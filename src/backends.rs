//! Solver backends by name, as written in scene files and on the command line: the solver
//! settings of a scene, and the one place that builds a solver from them, always through an
//! [`ecp_solvers::Registry`] (the built-in one, or one a caller extended with its own
//! backends, `examples/custom_backend.rs`).

use ecp_formulations::ecp::EcpContacts;
use ecp_formulations::{Capabilities, FormulationRegistry, StepFormulation};
use ecp_model::McpSolver;
use ecp_solvers::registry::{BackendOptions, Registry, RegistryError};

use crate::error::{InputError, InputErrorKind};

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

/// The formulation a solver is built for: its name (for messages) and what it can do.
#[derive(Clone, Debug, PartialEq)]
pub struct Target {
    /// The formulation's name.
    pub name: String,
    /// Its capabilities.
    pub capabilities: Capabilities,
}

impl Target {
    /// The hull formulation (the paper's).
    pub fn hull() -> Self {
        let hull = EcpContacts::hull();
        Target {
            name: hull.name().to_string(),
            capabilities: hull.capabilities(),
        }
    }

    /// Formulation `name` of `formulations` (the error lists the names it has).
    pub fn resolve(name: &str, formulations: &FormulationRegistry) -> Result<Self, InputError> {
        let unknown = |e: ecp_formulations::RegistryError| {
            InputError::option("--formulation", InputErrorKind::UnknownName, e.to_string())
        };
        Ok(Target {
            name: formulations.resolve(name).map_err(unknown)?,
            capabilities: formulations.capabilities(name).map_err(unknown)?,
        })
    }
}

/// Builds the built-in solver of `config` for the hull formulation: [`make_solver_in`] with
/// [`Registry::builtin`].
pub fn make_solver(config: &SolverConfig) -> Result<Box<dyn McpSolver>, InputError> {
    make_solver_in(&Registry::builtin(), config, &Target::hull())
}

/// Builds the solver of `config` from `registry` for the step problems of `formulation`: the
/// backend's documented default settings, with the scene's tolerance and iteration limit where
/// given, validated by the registry. A formulation whose solutions are not isolated (the union
/// formulation, [`Capabilities::non_isolated_solutions`]) gets
/// [`BackendOptions::non_isolated_solutions`] (Newton then takes minimum-norm least-squares
/// steps). The command line, the fallbacks of a run and fitting all build their solvers here,
/// so that no path builds a backend with other settings.
pub fn make_solver_in(
    registry: &Registry,
    config: &SolverConfig,
    formulation: &Target,
) -> Result<Box<dyn McpSolver>, InputError> {
    check_combination(registry, &config.name, formulation)?;
    let options = BackendOptions {
        tolerance: config.tolerance,
        max_iterations: config.max_iterations,
        non_isolated_solutions: formulation.capabilities.non_isolated_solutions,
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
/// formulations whose capabilities say they build it ([`Capabilities::step_structure`]: hull and
/// union among the built-in ones).
pub fn check_combination(
    registry: &Registry,
    solver: &str,
    formulation: &Target,
) -> Result<(), InputError> {
    let backend = registry.get(solver).map_err(|e| {
        let kind = match e {
            RegistryError::Unknown { .. } => InputErrorKind::UnknownName,
            _ => InputErrorKind::InvalidValue,
        };
        InputError::option("--solver", kind, e.to_string())
    })?;
    if backend.needs_structure() && !formulation.capabilities.step_structure {
        let able: Vec<String> = FormulationRegistry::builtin()
            .names_with(|c| c.step_structure)
            .into_iter()
            .map(|f| format!("\"{f}\""))
            .collect();
        let others: Vec<String> = registry
            .names()
            .into_iter()
            .filter(|n| registry.get(n).is_ok_and(|b| !b.needs_structure()))
            .map(|n| format!("--solver {n}"))
            .collect();
        let name = &formulation.name;
        return Err(InputError::option(
            "--solver",
            InputErrorKind::UnknownName,
            format!(
                "the {solver} backend cannot solve the {name} formulation: it needs the \
                 contact structure of an ECP step, which only {} build; use {} with \
                 --formulation {name}",
                able.join(", "),
                others.join(" or ")
            ),
        ));
    }
    Ok(())
}

/// Parses a formulation name of [`FormulationRegistry::builtin`] (the command line's
/// `--formulation`), with an error that lists the names.
pub fn parse_formulation(name: &str) -> Result<String, String> {
    FormulationRegistry::builtin()
        .resolve(name)
        .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_names_and_impossible_combinations_are_refused_with_the_names() {
        let r = Registry::builtin();
        let f = FormulationRegistry::builtin();
        let target = |name: &str| Target::resolve(name, &f).unwrap();
        let e = check_combination(&r, "simplex", &Target::hull()).unwrap_err();
        assert_eq!(e.kind, InputErrorKind::UnknownName);
        assert!(
            e.message.contains("unknown solver \"simplex\"")
                && e.message.contains("\"newton\", \"path\", \"conic\""),
            "{}",
            e.message
        );
        let e = check_combination(&r, "conic", &target("point")).unwrap_err();
        assert!(
            e.message.contains("cannot solve the point formulation")
                && e.message.contains("--solver newton or --solver path"),
            "{}",
            e.message
        );
        check_combination(&r, "conic", &target("union")).unwrap();
        let e = Target::resolve("bogus", &f).unwrap_err();
        assert!(e.message.contains("\"reduced\""), "{}", e.message);
        let config = SolverConfig {
            tolerance: Some(-1.0),
            ..SolverConfig::named("path")
        };
        let e = make_solver_in(&r, &config, &Target::hull()).err().unwrap();
        assert!(e.message.contains("`tolerance`"), "{}", e.message);
        assert_eq!(
            make_solver(&SolverConfig::default()).unwrap().name(),
            "newton"
        );
    }
}
