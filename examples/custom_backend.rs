//! A backend of your own, registered beside the built-in ones, driving the same run as
//! `ecp run`: the same `trajectory.csv`, `summary.json` and plots.
//!
//! ```text
//! cargo run --example custom_backend            # outputs in a temporary directory
//! cargo run --example custom_backend -- OUT_DIR
//! ```
//!
//! The backend, `logged-path`, wraps the PATH-like solver: every solve goes to PATH and its
//! one-line report ([`ecp::model::Summary::brief_report`]) is kept in a log that the program
//! reads after the run, and the summary carries a counter of the backend's own,
//! `Counter::Custom("logged_solves")`. Any [`McpSolver`] fits the same way: implement
//! [`Backend`] (name, description, `build` from [`BackendOptions`] with validated settings),
//! register it in a [`Registry`], and name it in [`RunOptions::solver`]
//! (`docs/backends.md#your-own-backend`). A wrapper forwards what the driver asks of a
//! backend (`set_iteration_budget`, `converges_to_round_off`), or the driver treats it as a
//! backend without budgets that stops at its tolerance (the plain warm start).

use std::error::Error;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use ecp::model::{Counter, Mcp, McpSolver, Solution, SolveError, Summary};
use ecp::run::{RunOptions, RunOutcome, run_scene};
use ecp::scene::load_scene_in;
use ecp::solvers::{Backend, BackendOptions, PathSettings, PathSolver, Registry, SettingsError};

/// The name the backend is registered under.
pub const NAME: &str = "logged-path";

/// One-line reports of every solve, shared between the backend and the program.
pub type Log = Arc<Mutex<Vec<String>>>;

/// PATH, with a log of every solve and a counter of its own.
pub struct LoggedPath {
    inner: PathSolver,
    log: Log,
    solves: usize,
}

impl LoggedPath {
    fn note(&mut self, summary: &mut Summary) {
        summary.solver = NAME.to_string();
        summary
            .counters
            .set(Counter::Custom("logged_solves"), self.solves);
        if let Ok(mut log) = self.log.lock() {
            log.push(summary.brief_report());
        }
    }
}

impl McpSolver for LoggedPath {
    fn name(&self) -> &str {
        NAME
    }

    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        self.solves += 1;
        match self.inner.solve(mcp, z0) {
            Ok(mut sol) => {
                self.note(&mut sol.summary);
                Ok(sol)
            }
            Err(SolveError::NotConverged { mut best }) => {
                self.note(&mut best.summary);
                Err(SolveError::NotConverged { best })
            }
            Err(e) => Err(e),
        }
    }

    // What the driver asks of a backend before a step, forwarded, so that the run is PATH's:
    // budgeted starts and, since PATH ends at round-off, the extrapolated warm start.
    fn set_iteration_budget(&mut self, budget: Option<usize>) -> bool {
        self.inner.set_iteration_budget(budget)
    }

    fn converges_to_round_off(&self) -> bool {
        self.inner.converges_to_round_off()
    }
}

/// How the registry builds [`LoggedPath`]: PATH's defaults with the scene's tolerance and
/// iteration limit, validated like the built-in backends' settings.
pub struct LoggedPathBackend {
    /// Where every solver built by this backend writes.
    pub log: Log,
}

impl Backend for LoggedPathBackend {
    fn name(&self) -> &str {
        NAME
    }
    fn description(&self) -> &str {
        "the PATH-like solver, with a log of every solve's one-line report"
    }
    fn build(&self, o: &BackendOptions) -> Result<Box<dyn McpSolver>, SettingsError> {
        let d = PathSettings::default();
        let settings = PathSettings {
            tolerance: o.tolerance.unwrap_or(d.tolerance),
            max_iterations: o.max_iterations.unwrap_or(d.max_iterations),
            ..d
        };
        settings.validate()?;
        Ok(Box::new(LoggedPath {
            inner: PathSolver::new(settings),
            log: Arc::clone(&self.log),
            solves: 0,
        }))
    }
}

/// Runs `scenes/a1_sliding.toml` with `solver` (a built-in name or [`NAME`]) from the built-in
/// registry extended with [`LoggedPathBackend`], writing the outputs into `out_dir`; returns
/// the run and the backend's log.
pub fn run_a1(out_dir: &Path, solver: &str) -> Result<(RunOutcome, Vec<String>), Box<dyn Error>> {
    let log: Log = Arc::default();
    let mut registry = Registry::builtin();
    registry.register(Box::new(LoggedPathBackend {
        log: Arc::clone(&log),
    }))?;
    let file = load_scene_in(Path::new("scenes/a1_sliding.toml"), &registry)?;
    let options = RunOptions {
        out_dir: out_dir.to_path_buf(),
        solver: Some(solver.to_string()),
        registry: Arc::new(registry),
        ..RunOptions::default()
    };
    let outcome = run_scene(&file, &options, |_| {})?;
    let lines = log.lock().map(|l| l.clone()).unwrap_or_default();
    Ok((outcome, lines))
}

fn main() -> Result<(), Box<dyn Error>> {
    let out = std::env::args().nth(1).map_or_else(
        || std::env::temp_dir().join(format!("ecp-custom-backend-{}", std::process::id())),
        PathBuf::from,
    );
    let (outcome, log) = run_a1(&out, NAME)?;
    let s = &outcome.summary;
    println!(
        "{}: {} steps with {} ({} failed), {} solves logged; outputs in {}",
        s.scene,
        s.steps,
        s.solver,
        s.failed_steps,
        log.len(),
        out.display()
    );
    for line in log.iter().take(3) {
        println!("  {line}");
    }
    if let Some(last) = outcome.records.last() {
        println!("last step's full report:\n{}", last.summary.full_report());
    }
    if !outcome.succeeded() {
        return Err(format!("the run failed: {:?}", s.failure).into());
    }
    Ok(())
}
