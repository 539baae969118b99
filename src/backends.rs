//! Names of the solver backends, as written in scene files and on the command line, the factory
//! that builds a solver from its name and settings, and the check that a backend can solve a
//! formulation's step problems (asked of the formulation's capabilities).

use std::fmt;
use std::str::FromStr;

use ecp_formulations::{Capabilities, FormulationRegistry};
use ecp_model::McpSolver;
use ecp_solvers::registry::{BackendOptions, Registry};

use crate::error::{InputError, InputErrorKind};

/// A solver backend (`docs/backends.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SolverKind {
    /// Semismooth Newton on the Fischer–Burmeister reformulation
    /// (`docs/backends.md#semismooth-newton`).
    Newton,
    /// PATH-like Josephy–Newton with pivoting and a path search (`docs/backends.md#path-like`).
    Path,
    /// Convex subproblems with clarabel (`docs/backends.md#conic`).
    Conic,
}

impl SolverKind {
    /// Every backend name, in the order of `docs/backends.md`.
    pub const ALL: [SolverKind; 3] = [SolverKind::Newton, SolverKind::Path, SolverKind::Conic];

    /// The name used in files and on the command line.
    pub fn as_str(&self) -> &'static str {
        match self {
            SolverKind::Newton => "newton",
            SolverKind::Path => "path",
            SolverKind::Conic => "conic",
        }
    }
}

/// `Display` as the name, and `FromStr` from the name with an error listing every name.
macro_rules! named {
    ($t:ty, $what:literal) => {
        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.as_str())
            }
        }

        impl FromStr for $t {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                Self::ALL
                    .into_iter()
                    .find(|k| k.as_str() == s.trim())
                    .ok_or_else(|| {
                        format!(
                            concat!("unknown ", $what, " \"{}\"; the ", $what, "s are {}"),
                            s,
                            names(&Self::ALL)
                        )
                    })
            }
        }
    };
}

named!(SolverKind, "solver");

fn names<T: fmt::Display>(items: &[T]) -> String {
    items
        .iter()
        .map(|i| format!("\"{i}\""))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Solver choice and settings of a scene (`[solver]`); unset settings keep the backend's
/// documented defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct SolverConfig {
    /// Which backend.
    pub kind: SolverKind,
    /// Tolerance on the natural-map residual.
    pub tolerance: Option<f64>,
    /// Iteration limit per step.
    pub max_iterations: Option<usize>,
}

impl Default for SolverConfig {
    fn default() -> Self {
        SolverConfig {
            kind: SolverKind::Newton,
            tolerance: None,
            max_iterations: None,
        }
    }
}

/// Builds the solver of `config`: the backend's documented default settings, with the scene's
/// tolerance and iteration limit where given. (A `Result` so that backends with settings that
/// can be invalid fit the same call.)
pub fn make_solver(config: &SolverConfig) -> Result<Box<dyn McpSolver>, InputError> {
    build_solver(config, false)
}

/// [`make_solver`] for the step problems of a formulation with `capabilities`: when its solutions
/// are not isolated (the union formulation), the Newton backend takes minimum-norm
/// least-squares steps ([`ecp_solvers::NewtonSettings::min_norm_step`]). Every solver comes from
/// [`ecp_solvers::Registry`], so the command line, the fallbacks and fitting build each backend
/// the same way.
pub fn make_solver_for(
    config: &SolverConfig,
    capabilities: &Capabilities,
) -> Result<Box<dyn McpSolver>, InputError> {
    build_solver(config, capabilities.non_isolated_solutions)
}

fn build_solver(
    config: &SolverConfig,
    non_isolated_solutions: bool,
) -> Result<Box<dyn McpSolver>, InputError> {
    let options = BackendOptions {
        tolerance: config.tolerance,
        max_iterations: config.max_iterations,
        non_isolated_solutions,
    };
    Registry::builtin()
        .build(config.kind.as_str(), &options)
        .map_err(|e| {
            InputError::option(
                "[solver]",
                InputErrorKind::InvalidValue,
                format!("{e}; fix the scene's [solver] table"),
            )
        })
}

/// Checks that `formulation` is in `formulations` and that `solver` can solve its step problems
/// (the conic backend needs the structural view of an ECP step, [`ecp_model::StepStructure`],
/// [`Capabilities::step_structure`]); returns the formulation's capabilities.
pub fn check_combination(
    solver: SolverKind,
    formulation: &str,
    formulations: &FormulationRegistry,
) -> Result<Capabilities, InputError> {
    let capabilities = formulations.capabilities(formulation).map_err(|e| {
        InputError::option("--formulation", InputErrorKind::UnknownName, e.to_string())
    })?;
    if solver == SolverKind::Conic && !capabilities.step_structure {
        let able = formulations.names_with(|c| c.step_structure);
        return Err(InputError::option(
            "--solver",
            InputErrorKind::UnknownName,
            format!(
                "the conic backend cannot solve the {formulation} formulation: it needs the \
                 contact structure of an ECP step, which only {} build; use --solver newton or \
                 --solver path with --formulation {formulation}",
                names(&able)
            ),
        ));
    }
    Ok(capabilities)
}

/// Parses a formulation name of [`FormulationRegistry::builtin`] (the command line's
/// `--formulation`), with an error that lists the names.
pub fn parse_formulation(name: &str) -> Result<String, String> {
    FormulationRegistry::builtin()
        .resolve(name)
        .map_err(|e| e.to_string())
}
