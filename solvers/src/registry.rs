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

/// A setting out of its range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{backend} setting `{setting}` = {value} is invalid: {hint}")]
pub struct SettingsError {
    /// The backend.
    pub backend: &'static str,
    /// The setting's field name.
    pub setting: &'static str,
    /// Its value, as written.
    pub value: String,
    /// The valid range.
    pub hint: &'static str,
}

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

impl Default for Registry {
    fn default() -> Self {
        Self::builtin()
    }
}

fn check(
    backend: &'static str,
    setting: &'static str,
    value: impl std::fmt::Display,
    ok: bool,
    hint: &'static str,
) -> Result<(), SettingsError> {
    if ok {
        Ok(())
    } else {
        Err(SettingsError {
            backend,
            setting,
            value: value.to_string(),
            hint,
        })
    }
}

const TOLERANCE_HINT: &str = "the tolerance must be a finite number > 0 (default 1e-10)";
const ITERATIONS_HINT: &str = "the iteration limit must be at least 1";
const FRACTION_HINT: &str = "must lie strictly between 0 and 1";
const POSITIVE_HINT: &str = "must be a finite number > 0";

fn positive(v: f64) -> bool {
    v.is_finite() && v > 0.0
}

fn fraction(v: f64) -> bool {
    v > 0.0 && v < 1.0
}

impl NewtonSettings {
    /// Checks every setting's range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let n = "newton";
        check(
            n,
            "tolerance",
            self.tolerance,
            positive(self.tolerance),
            TOLERANCE_HINT,
        )?;
        check(
            n,
            "max_iterations",
            self.max_iterations,
            self.max_iterations >= 1,
            ITERATIONS_HINT,
        )?;
        check(
            n,
            "armijo",
            self.armijo,
            fraction(self.armijo),
            FRACTION_HINT,
        )?;
        check(
            n,
            "backtrack",
            self.backtrack,
            fraction(self.backtrack),
            FRACTION_HINT,
        )?;
        check(
            n,
            "min_step",
            self.min_step,
            fraction(self.min_step),
            FRACTION_HINT,
        )?;
        check(
            n,
            "descent_rho",
            self.descent_rho,
            positive(self.descent_rho),
            POSITIVE_HINT,
        )?;
        check(
            n,
            "descent_p",
            self.descent_p,
            self.descent_p.is_finite() && self.descent_p > 2.0,
            "must be a finite number > 2 (the De Luca–Facchinei–Kanzow descent test)",
        )?;
        check(
            n,
            "lm_initial_damping",
            self.lm_initial_damping,
            positive(self.lm_initial_damping),
            POSITIVE_HINT,
        )?;
        check(
            n,
            "rank_tolerance",
            self.rank_tolerance,
            fraction(self.rank_tolerance),
            FRACTION_HINT,
        )?;
        check(
            n,
            "min_norm_radius",
            self.min_norm_radius,
            positive(self.min_norm_radius),
            POSITIVE_HINT,
        )
    }
}

impl PathSettings {
    /// Checks every setting's range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let n = "path";
        check(
            n,
            "tolerance",
            self.tolerance,
            positive(self.tolerance),
            TOLERANCE_HINT,
        )?;
        check(
            n,
            "max_iterations",
            self.max_iterations,
            self.max_iterations >= 1,
            ITERATIONS_HINT,
        )?;
        check(
            n,
            "sufficient_decrease",
            self.sufficient_decrease,
            fraction(self.sufficient_decrease),
            FRACTION_HINT,
        )?;
        check(
            n,
            "backtrack",
            self.backtrack,
            fraction(self.backtrack),
            FRACTION_HINT,
        )?;
        check(
            n,
            "proximal_initial",
            self.proximal_initial,
            positive(self.proximal_initial),
            POSITIVE_HINT,
        )?;
        check(
            n,
            "proximal_growth",
            self.proximal_growth,
            self.proximal_growth.is_finite() && self.proximal_growth > 1.0,
            "must be a finite number > 1",
        )?;
        check(
            n,
            "proximal_reduction",
            self.proximal_reduction,
            fraction(self.proximal_reduction),
            FRACTION_HINT,
        )?;
        check(
            n,
            "proximal_max",
            self.proximal_max,
            positive(self.proximal_max) && self.proximal_max >= self.proximal_initial,
            "must be finite and at least proximal_initial",
        )?;
        check(
            n,
            "restart_proximal",
            self.restart_proximal,
            positive(self.restart_proximal),
            POSITIVE_HINT,
        )?;
        check(
            n,
            "time_limit",
            self.time_limit,
            self.time_limit > 0.0 && !self.time_limit.is_nan(),
            "the time limit must be > 0 seconds (inf for none)",
        )
    }
}

impl ConicSettings {
    /// Checks every setting's range.
    pub fn validate(&self) -> Result<(), SettingsError> {
        let n = "conic";
        check(
            n,
            "tolerance",
            self.tolerance,
            positive(self.tolerance),
            TOLERANCE_HINT,
        )?;
        check(
            n,
            "max_iterations",
            self.max_iterations,
            self.max_iterations >= 1,
            ITERATIONS_HINT,
        )?;
        check(
            n,
            "patch_band",
            self.patch_band,
            positive(self.patch_band),
            POSITIVE_HINT,
        )?;
        check(
            n,
            "anchor_moment",
            self.anchor_moment,
            self.anchor_moment.is_finite() && self.anchor_moment >= 0.0,
            "must be a finite number ≥ 0",
        )?;
        check(
            n,
            "anchor_load",
            self.anchor_load,
            self.anchor_load.is_finite() && self.anchor_load >= 0.0,
            "must be a finite number ≥ 0",
        )
    }
}

struct NewtonBackend;
struct PathBackend;
struct ConicBackend;

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
        let d = ConicSettings::default();
        let s = ConicSettings {
            tolerance: o.tolerance.unwrap_or(d.tolerance),
            max_iterations: o.max_iterations.unwrap_or(d.max_iterations),
            ..d
        };
        s.validate()?;
        Ok(Box::new(ConicSolver::new(s)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_names_lookup_and_errors() {
        let mut r = Registry::builtin();
        assert_eq!(r.names(), ["newton", "path", "conic"]);
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
    fn defaults_validate_and_nonsense_is_refused() {
        NewtonSettings::default().validate().unwrap();
        PathSettings::default().validate().unwrap();
        ConicSettings::default().validate().unwrap();
        let r = Registry::builtin();
        for name in ["newton", "path", "conic"] {
            for (tol, iters) in [(Some(-1e-3), None), (Some(f64::NAN), None), (None, Some(0))] {
                let o = BackendOptions {
                    tolerance: tol,
                    max_iterations: iters,
                    ..Default::default()
                };
                let e = r.build(name, &o).err().expect("refused");
                let text = e.to_string();
                assert!(text.starts_with(name), "{text}");
                assert!(
                    text.contains("tolerance") || text.contains("max_iterations"),
                    "{text}"
                );
            }
        }
        let bad = NewtonSettings {
            backtrack: 1.5,
            ..Default::default()
        };
        assert_eq!(bad.validate().unwrap_err().setting, "backtrack");
        for time_limit in [0.0, -1.0, f64::NAN, f64::NEG_INFINITY] {
            let bad = PathSettings {
                time_limit,
                ..Default::default()
            };
            assert_eq!(bad.validate().unwrap_err().setting, "time_limit");
        }
        PathSettings {
            time_limit: f64::INFINITY,
            ..Default::default()
        }
        .validate()
        .unwrap();
    }
}
