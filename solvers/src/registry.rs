//! The backends by name: the one place where the command line, fitting, the fallbacks of a run
//! and the tests get their solvers, so that no path builds a backend with other settings.
//!
//! ```
//! use ecp_solvers::registry::{BackendOptions, Registry};
//!
//! let registry = Registry::builtin();
//! assert_eq!(registry.names(), ["newton", "path", "conic"]);
//! let solver = registry.build("path", &BackendOptions { tolerance: Some(1e-12), ..Default::default() });
//! assert!(solver.is_ok());
//! // Nonsense settings are refused with a message that says which and why.
//! let bad = registry.build("newton", &BackendOptions { tolerance: Some(-1.0), ..Default::default() });
//! assert!(bad.err().unwrap().to_string().contains("tolerance"));
//! ```

use ecp_model::McpSolver;

use crate::conic::{ConicSettings, ConicSolver};
use crate::newton::{NewtonSettings, NewtonSolver};
use crate::path::{PathSettings, PathSolver};
pub use crate::settings::SettingsError;
use crate::smoothing::SmoothingSettings;

/// Why the registry could not give a solver.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RegistryError {
    /// No backend of that name.
    #[error("unknown solver \"{name}\"; the solvers are {known}")]
    Unknown {
        /// The name asked for.
        name: String,
        /// The registered names, quoted and comma-separated.
        known: String,
    },
    /// A backend of that name is registered already.
    #[error("a solver named \"{0}\" is registered already")]
    Duplicate(String),
    /// The settings are out of range.
    #[error(transparent)]
    Settings(#[from] SettingsError),
}

/// What every backend lets a caller choose; `None` keeps the backend's documented default.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BackendOptions {
    /// Natural-residual tolerance per solve.
    pub tolerance: Option<f64>,
    /// Iteration limit per solve.
    pub max_iterations: Option<usize>,
    /// The problems' solutions are not isolated (impulses shared by several contacts of one
    /// body, as in the union-of-pieces formulation): a backend that has a mode for that uses it
    /// (Newton's minimum-norm steps).
    pub non_isolated_solutions: bool,
}

/// A backend the registry can build.
pub trait Backend: Send + Sync {
    /// The name used in scene files, on the command line and in reports.
    fn name(&self) -> &str;
    /// One line on what it is.
    fn description(&self) -> &str;
    /// Whether it needs the structural view of a contact step (`ecp_model::Mcp::structure`);
    /// such a backend refuses problems without one.
    fn needs_structure(&self) -> bool {
        false
    }
    /// A solver with the backend's default settings changed by `options`, validated.
    fn build(&self, options: &BackendOptions) -> Result<Box<dyn McpSolver>, SettingsError>;
}

/// Names of the built-in backends, in the order of [`Registry::builtin`].
pub const BUILTIN: [&str; 3] = ["newton", "path", "conic"];

/// The backends by name, in registration order.
pub struct Registry {
    backends: Vec<Box<dyn Backend>>,
}

impl Registry {
    /// No backend.
    pub fn empty() -> Self {
        Registry {
            backends: Vec::new(),
        }
    }

    /// The built-in backends: `newton`, `path`, `conic`.
    pub fn builtin() -> Self {
        Registry {
            backends: vec![
                Box::new(NewtonBackend),
                Box::new(PathBackend),
                Box::new(ConicBackend),
            ],
        }
    }

    /// Adds `backend`; refuses a name that is taken.
    pub fn register(&mut self, backend: Box<dyn Backend>) -> Result<(), RegistryError> {
        if self.backends.iter().any(|b| b.name() == backend.name()) {
            return Err(RegistryError::Duplicate(backend.name().to_string()));
        }
        self.backends.push(backend);
        Ok(())
    }

    /// Every name, in registration order.
    pub fn names(&self) -> Vec<&str> {
        self.backends.iter().map(|b| b.name()).collect()
    }

    /// The backend called `name`.
    pub fn get(&self, name: &str) -> Result<&dyn Backend, RegistryError> {
        self.backends
            .iter()
            .find(|b| b.name() == name.trim())
            .map(|b| b.as_ref())
            .ok_or_else(|| RegistryError::Unknown {
                name: name.to_string(),
                known: self
                    .names()
                    .iter()
                    .map(|n| format!("\"{n}\""))
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// A solver of the backend called `name`, with `options`.
    pub fn build(
        &self,
        name: &str,
        options: &BackendOptions,
    ) -> Result<Box<dyn McpSolver>, RegistryError> {
        Ok(self.get(name)?.build(options)?)
    }
}

/// The registered names, e.g. `Registry["newton", "path", "conic"]`.
impl std::fmt::Debug for Registry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Registry")?;
        f.debug_list().entries(self.names()).finish()
    }
}

impl Default for Registry {
    fn default() -> Self {
        Self::builtin()
    }
}

struct NewtonBackend;
struct PathBackend;
struct ConicBackend;

/// The smoothing continuation's settings under a user's iteration limit: its stages together
/// iterate no more than the limit allows one attempt.
fn capped_smoothing(
    smoothing: Option<SmoothingSettings>,
    max_iterations: Option<usize>,
) -> Option<SmoothingSettings> {
    smoothing.map(|s| SmoothingSettings {
        stage_iterations: max_iterations.map_or(s.stage_iterations, |n| s.stage_iterations.min(n)),
        max_iterations: max_iterations.or(s.max_iterations),
        ..s
    })
}

impl Backend for NewtonBackend {
    fn name(&self) -> &str {
        "newton"
    }
    fn description(&self) -> &str {
        "semismooth Newton on the Fischer–Burmeister reformulation, with Levenberg–Marquardt and gradient safeguards"
    }
    fn build(&self, o: &BackendOptions) -> Result<Box<dyn McpSolver>, SettingsError> {
        let d = NewtonSettings::default();
        let s = NewtonSettings {
            tolerance: o.tolerance.unwrap_or(d.tolerance),
            max_iterations: o.max_iterations.unwrap_or(d.max_iterations),
            // Minimum-norm steps converge where the solution set is not a point.
            min_norm_step: d.min_norm_step || o.non_isolated_solutions,
            smoothing: capped_smoothing(d.smoothing, o.max_iterations),
            // Where the solutions form a set (the union formulation) the iteration may converge
            // linearly along it; the stall test would cut that progress (measured: the union
            // T-bar of tests/union.rs, step 30, Σ p_n off by 1.3e-8 with it).
            stall_window: if o.non_isolated_solutions {
                0
            } else {
                d.stall_window
            },
            ..d
        };
        s.validate()?;
        Ok(Box::new(NewtonSolver::new(s)))
    }
}

impl Backend for PathBackend {
    fn name(&self) -> &str {
        "path"
    }
    fn description(&self) -> &str {
        "PATH-like Josephy–Newton: Lemke pivoting on each linearisation, path search, watchdog, crash, proximal perturbation"
    }
    fn build(&self, o: &BackendOptions) -> Result<Box<dyn McpSolver>, SettingsError> {
        let d = PathSettings::default();
        let s = PathSettings {
            tolerance: o.tolerance.unwrap_or(d.tolerance),
            max_iterations: o.max_iterations.unwrap_or(d.max_iterations),
            smoothing: capped_smoothing(d.smoothing, o.max_iterations),
            ..d
        };
        s.validate()?;
        Ok(Box::new(PathSolver::new(s)))
    }
}

impl Backend for ConicBackend {
    fn name(&self) -> &str {
        "conic"
    }
    fn description(&self) -> &str {
        "convex subproblems with clarabel over the contact structure (De Saxcé fixed point)"
    }
    fn needs_structure(&self) -> bool {
        true
    }
    fn build(&self, o: &BackendOptions) -> Result<Box<dyn McpSolver>, SettingsError> {
        let s = conic_settings(o);
        s.validate()?;
        Ok(Box::new(ConicSolver::new(s)))
    }
}

/// The conic backend's settings for `o`, as the registry builds them (not yet validated): the
/// defaults with `o`'s tolerance and iteration limit, the Newton polish capped by the latter.
pub fn conic_settings(o: &BackendOptions) -> ConicSettings {
    let d = ConicSettings::default();
    ConicSettings {
        tolerance: o.tolerance.unwrap_or(d.tolerance),
        max_iterations: o.max_iterations.unwrap_or(d.max_iterations),
        newton_polish: o
            .max_iterations
            .map_or(d.newton_polish, |n| d.newton_polish.min(n)),
        ..d
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_names_lookup_and_errors() {
        let mut r = Registry::builtin();
        assert_eq!(r.names(), BUILTIN);
        assert!(r.get("conic").unwrap().needs_structure());
        assert!(!r.get(" path ").unwrap().needs_structure());
        let e = r.build("lemke", &BackendOptions::default()).err().unwrap();
        assert_eq!(
            e.to_string(),
            "unknown solver \"lemke\"; the solvers are \"newton\", \"path\", \"conic\""
        );
        assert_eq!(
            r.register(Box::new(PathBackend)).unwrap_err(),
            RegistryError::Duplicate("path".into())
        );
    }

    #[test]
    fn construction_through_the_registry_validates() {
        let r = Registry::builtin();
        for name in ["newton", "path", "conic"] {
            r.build(name, &BackendOptions::default()).unwrap();
            for (tol, iters) in [(Some(-1e-3), None), (Some(f64::NAN), None), (None, Some(0))] {
                let o = BackendOptions {
                    tolerance: tol,
                    max_iterations: iters,
                    ..Default::default()
                };
                let e = r.build(name, &o).err().expect("refused");
                let text = e.to_string();
                assert!(text.starts_with(name), "{text}");
                let field = if tol.is_some() {
                    "tolerance"
                } else {
                    "max_iterations"
                };
                assert!(text.contains(&format!("`{field}`")), "{text}");
            }
        }
    }
}
