//! Running a scene file: the time stepper with the chosen backend, writing `trajectory.csv`
//! row by row, then `summary.json` and the plots (`docs/outputs.md`). The `ecp` binary is a thin
//! layer over [`run_scene`] and [`compare_scene`].

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use ecp_formulations::{Fallbacks, FormulationRegistry, SimulationBuilder, StepRecord, WarmStart};
use ecp_solvers::Registry;

use crate::backends::{SolverConfig, Target, check_combination, make_solver_in};
use crate::error::{InputError, InputErrorKind};
use crate::output::{
    CompareReport, CompareRun, ContactsWriter, OutputError, RunSummary, SkippedRun,
    TrajectoryWriter, max_velocity_differences, write_json,
};
use crate::scene::SceneFile;

/// Options of a run; `None` fields take the scene file's choice.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Output directory (created if missing).
    pub out_dir: PathBuf,
    /// Backend instead of the scene's `[solver] name`, by its name in [`RunOptions::registry`].
    pub solver: Option<String>,
    /// Where backends are found by name: [`Registry::builtin`] by default; register a backend
    /// of your own in it to run scenes with it and get the same outputs and plots
    /// (`examples/custom_backend.rs`). The fallbacks come from it too.
    pub registry: Arc<Registry>,
    /// Formulation instead of the scene's, by its name in [`RunOptions::formulations`].
    pub formulation: Option<String>,
    /// Where formulations are found by name: [`FormulationRegistry::builtin`] by default;
    /// register a formulation of your own in it to run scenes with it and get the same outputs
    /// and plots (`examples/custom_formulation.rs`).
    pub formulations: FormulationRegistry,
    /// Stop after this many steps (at most the scene's duration).
    pub steps: Option<usize>,
    /// Write PNG plots into `out_dir/plots`.
    pub plots: bool,
    /// Go on after a step that no backend or fallback could solve, instead of stopping. The
    /// failed step's iterate is never taken: the bodies keep their state at its start.
    pub keep_going: bool,
    /// Try other backends, then substeps, when the backend cannot solve a step
    /// (`docs/fallbacks.md`). On by default.
    pub fallbacks: bool,
    /// Stop the run once it has taken this long (checked between steps); the outcome says so.
    pub time_limit: Option<Duration>,
    /// The steps' warm start ([`WarmStart`]): extrapolated from the last smooth steps by
    /// default (for a backend that converges to round-off, Newton), or from the last step alone.
    pub warm_start: WarmStart,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            out_dir: PathBuf::from("out"),
            solver: None,
            registry: Arc::new(Registry::builtin()),
            formulation: None,
            formulations: FormulationRegistry::builtin(),
            steps: None,
            plots: true,
            keep_going: false,
            fallbacks: true,
            time_limit: None,
            warm_start: WarmStart::default(),
        }
    }
}

impl RunOptions {
    /// The default output directory (`docs/outputs.md`): `out/<scene name>`.
    pub fn default_out_dir(file: &SceneFile) -> PathBuf {
        PathBuf::from("out").join(&file.scene.name)
    }
}

/// What a run produced.
#[derive(Debug)]
pub struct RunOutcome {
    /// The contents of `summary.json`.
    pub summary: RunSummary,
    /// Every step's record, in order.
    pub records: Vec<StepRecord>,
    /// Plot files written.
    pub plots: Vec<PathBuf>,
    /// Why the plots could not be written, if they could not (the run itself is still good).
    pub plot_error: Option<String>,
    /// The stepper's error that ended the run early, if any.
    pub stepper_error: Option<String>,
    /// The run stopped at [`RunOptions::time_limit`] before its last step.
    pub timed_out: bool,
}

impl RunOutcome {
    /// Every step converged and the run reached its end.
    pub fn succeeded(&self) -> bool {
        self.summary.failed_steps == 0 && self.stepper_error.is_none() && !self.timed_out
    }
}

/// Why a run could not produce its outputs.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Bad input (an unavailable backend or formulation, a scene the stepper refuses).
    #[error(transparent)]
    Input(#[from] InputError),
    /// An output file could not be written.
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// The run's backend settings and its formulation.
fn resolve(file: &SceneFile, options: &RunOptions) -> Result<(SolverConfig, Target), InputError> {
    let name = options.formulation.as_ref().unwrap_or(&file.formulation);
    let formulation = Target::resolve(name, &options.formulations)?;
    let mut config = file.solver.clone();
    if let Some(name) = &options.solver {
        config.name = name.trim().to_string();
    }
    check_combination(&options.registry, &config.name, &formulation)?;
    Ok((config, formulation))
}

/// The built-in backends a run falls back on, most robust first.
pub const FALLBACK_ORDER: [&str; 3] = ["path", "newton", "conic"];

/// The default fallbacks of a run with `config` on `formulation`: every other backend of
/// [`FALLBACK_ORDER`] that `registry` has and that can solve the formulation, with the same
/// tolerance and iteration limit, then substeps down to `h/16`. A user's backend is never a
/// fallback by default (it is there to be measured). The driver uses them as far as the
/// formulation's capabilities allow.
pub fn fallbacks_for(
    registry: &Registry,
    config: &SolverConfig,
    formulation: &Target,
) -> Result<Fallbacks, InputError> {
    let mut backends = Vec::new();
    for name in FALLBACK_ORDER {
        if name == config.name
            || registry.get(name).is_err()
            || check_combination(registry, name, formulation).is_err()
        {
            continue;
        }
        let other = SolverConfig {
            name: name.to_string(),
            ..config.clone()
        };
        backends.push(make_solver_in(registry, &other, formulation)?);
    }
    Ok(Fallbacks::new(backends))
}

/// Simulates `file` and writes its outputs into `options.out_dir`. `on_step` sees each record
/// right after its CSV row is on disk (the CLI's progress bar uses it).
pub fn run_scene(
    file: &SceneFile,
    options: &RunOptions,
    mut on_step: impl FnMut(&StepRecord),
) -> Result<RunOutcome, RunError> {
    let start = Instant::now();
    let (config, formulation) = resolve(file, options)?;
    let mut solver = make_solver_in(&options.registry, &config, &formulation)?;
    let mut fallbacks = if options.fallbacks {
        fallbacks_for(&options.registry, &config, &formulation)?
    } else {
        Fallbacks::none()
    };
    let refused = |message: String| InputError {
        file: Some(file.path.clone()),
        key: None,
        line: None,
        kind: InputErrorKind::InvalidValue,
        message,
    };
    let stepper = options
        .formulations
        .create(&formulation.name)
        .map_err(|e| refused(e.to_string()))?;
    let mut sim = SimulationBuilder::new(file.scene.clone(), stepper)
        .build()
        .map_err(|e| refused(e.to_string()))?;
    sim.set_warm_start(options.warm_start);
    let planned = options
        .steps
        .map_or(file.scene.num_steps(), |n| n.min(file.scene.num_steps()));
    let mut csv = TrajectoryWriter::create(
        &options.out_dir.join("trajectory.csv"),
        &file.scene,
        sim.contacts_per_body(),
    )?;
    let mut contacts = ContactsWriter::create(&options.out_dir.join("contacts.csv"))?;
    let mut records = Vec::with_capacity(planned.min(1 << 16));
    let mut stepper_error = None;
    let mut timed_out = false;
    while records.len() < planned {
        if options
            .time_limit
            .is_some_and(|limit| start.elapsed() > limit)
        {
            timed_out = true;
            break;
        }
        match sim.step_with(solver.as_mut(), &mut fallbacks) {
            Ok(rec) => {
                csv.write(&rec)?;
                contacts.write(&rec)?;
                on_step(&rec);
                let stop = !rec.converged && !options.keep_going;
                records.push(rec);
                if stop {
                    break;
                }
            }
            Err(e) => {
                stepper_error = Some(format!("step {}: {e}", records.len() + 1));
                break;
            }
        }
    }
    let mut summary = RunSummary::from_records(
        &file.scene,
        &formulation.name,
        &config.name,
        &records,
        planned,
    );
    if let Some(message) = &stepper_error {
        // The step the stepper refused is a failed step too, though it has no record.
        summary.failed_steps += 1;
        if summary.failure.is_none() {
            summary.failure = Some(crate::output::Failure {
                step: records.len() + 1,
                t: records.len() as f64 * file.scene.h,
                reason: message.clone(),
                residual: f64::INFINITY,
            });
        }
    }
    let (plots, plot_error) = if options.plots && !records.is_empty() {
        match crate::plots::write_plots(&options.out_dir.join("plots"), &file.scene, &records) {
            Ok(p) => (p, None),
            Err(e) => (Vec::new(), Some(e.to_string())),
        }
    } else {
        (Vec::new(), None)
    };
    summary.scene_path = std::path::absolute(&file.path)
        .unwrap_or_else(|_| file.path.clone())
        .display()
        .to_string();
    summary.wall_s = start.elapsed().as_secs_f64();
    write_json(&options.out_dir.join("summary.json"), &summary)?;
    Ok(RunOutcome {
        summary,
        records,
        plots,
        plot_error,
        stepper_error,
        timed_out,
    })
}

/// Runs every (formulation, solver) combination on `file` (each into its own subdirectory of
/// `options.out_dir`, without plots), and writes `compare.json` with the velocity differences
/// against the first run. `on_run` is told each run's label before it starts.
pub fn compare_scene(
    file: &SceneFile,
    solvers: &[String],
    formulations: &[String],
    options: &RunOptions,
    mut on_run: impl FnMut(&str),
) -> Result<CompareReport, RunError> {
    for s in solvers {
        // Unknown names and invalid settings stop the comparison before any run.
        let config = SolverConfig {
            name: s.clone(),
            ..file.solver.clone()
        };
        // Every backend solves the hull formulation.
        make_solver_in(&options.registry, &config, &Target::hull())?;
    }
    let mut runs: Vec<CompareRun> = Vec::new();
    let mut skipped: Vec<SkippedRun> = Vec::new();
    let mut first_error: Option<RunError> = None;
    let mut first: Option<Vec<StepRecord>> = None;
    for f in formulations {
        for s in solvers {
            let label = format!("{f}-{s}");
            let skip = |reason: String| SkippedRun {
                formulation: f.to_string(),
                solver: s.to_string(),
                reason,
            };
            let checked = Target::resolve(f, &options.formulations)
                .and_then(|t| check_combination(&options.registry, s, &t));
            if let Err(e) = checked {
                skipped.push(skip(e.message.clone()));
                continue;
            }
            on_run(&label);
            let run_options = RunOptions {
                out_dir: options.out_dir.join(&label),
                solver: Some(s.clone()),
                formulation: Some(f.clone()),
                plots: false,
                ..options.clone()
            };
            let outcome = match run_scene(file, &run_options, |_| {}) {
                Ok(o) => o,
                // A formulation that refuses the scene (`docs/model.md#reduced`) is reported, and
                // the other combinations still run.
                Err(RunError::Input(e)) => {
                    skipped.push(skip(e.message.clone()));
                    first_error.get_or_insert(RunError::Input(e));
                    continue;
                }
                Err(e) => return Err(e),
            };
            let (max_diff_v, max_diff_w) = match &first {
                Some(reference) => max_velocity_differences(reference, &outcome.records),
                None => (0.0, 0.0),
            };
            if first.is_none() {
                first = Some(outcome.records);
            }
            runs.push(CompareRun {
                summary: outcome.summary,
                max_diff_v,
                max_diff_w,
            });
        }
    }
    if runs.is_empty() {
        return Err(first_error.unwrap_or_else(|| {
            RunError::Input(InputError::option(
                "--solvers",
                InputErrorKind::UnknownName,
                format!(
                    "no combination of the solvers and formulations can run: {}",
                    skipped
                        .iter()
                        .map(|k| format!("{}-{}: {}", k.formulation, k.solver, k.reason))
                        .collect::<Vec<_>>()
                        .join("; ")
                ),
            ))
        }));
    }
    let report = CompareReport {
        scene: file.scene.name.clone(),
        runs,
        skipped,
    };
    write_json(&options.out_dir.join("compare.json"), &report)?;
    Ok(report)
}
