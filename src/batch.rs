//! Batch runs: many independent simulations — N scene files, or one scene over a grid of
//! parameter values (μ, masses, initial states, constant loads: any [`Param`]) — on a rayon
//! pool of a chosen size, gathered in input order. Behind `ecp sweep` and the Python package's
//! `ecp.batch` (`docs/python.md`).
//!
//! **Results are bitwise identical whatever the thread count and from run to run.** Each run is
//! computed from start to end by one thread with its own stepper and solvers, nothing is shared
//! between runs, and the results are put back in input order; the only things that differ are
//! the wall-clock times, which are kept apart ([`JobResult::timing`], `sweep_timing.csv`) and
//! are not results. `tests/batch.rs` runs one batch on 1 and 2 threads and compares the bytes.
//!
//! ```
//! use ecp::batch::{Batch, BatchOptions, Grid};
//!
//! # fn main() -> Result<(), ecp::error::InputError> {
//! let file = ecp::scene::load_scene("scenes/a1_sliding.toml".as_ref())?;
//! let grid = Grid::parse(&["mu=0.1:0.3:3".to_string()], &file.scene)?;
//! let batch = Batch::grid(&file, &grid)?;
//! let options = BatchOptions { threads: Some(2), steps: Some(5), ..BatchOptions::default() };
//! let results = batch.run(&options)?;
//! assert_eq!(results.len(), 3);
//! // More friction, more deceleration: the final velocity falls with μ.
//! let vx: Vec<f64> = results.iter().map(|r| r.summary.final_bodies[0].v.x).collect();
//! assert!(vx[0] > vx[1] && vx[1] > vx[2]);
//! # Ok(())
//! # }
//! ```

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use ecp_formulations::sensitivity::Param;
use ecp_formulations::{BodyState, StepRecord};
use ecp_formulations::{Fallbacks, FormulationRegistry, SimulationBuilder};
use ecp_solvers::Registry;
use rayon::prelude::*;

use crate::backends::{Target, check_combination, make_solver_in};
use crate::error::{InputError, InputErrorKind};
use crate::output::{OutputError, RunSummary};
use crate::run::fallbacks_for;
use crate::scene::SceneFile;

/// The most runs one grid may hold (the product of the axes' lengths).
pub const MAX_GRID_POINTS: usize = 1_000_000;

/// One axis of a parameter grid: a parameter and its values.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    /// The parameter (scene-file names: `mu`, `mass`, `vx0`, `fx`, `mass[1]`, ...).
    pub param: Param,
    /// Its values, in order.
    pub values: Vec<f64>,
}

impl Axis {
    /// Parses `name=start:stop:count` (`count` evenly spaced values from `start` to `stop`, both
    /// included), `name=v1,v2,...` or `name=v`, and checks the parameter against `scene` (a body
    /// index it has, a load that is constant).
    pub fn parse(spec: &str, scene: &ecp_formulations::Scene) -> Result<Axis, InputError> {
        let bad = |kind, message: String| InputError::option("--param", kind, message);
        let Some((name, values)) = spec.split_once('=') else {
            return Err(bad(
                InputErrorKind::InvalidValue,
                format!(
                    "\"{spec}\" is not NAME=VALUES; write e.g. mu=0.1:0.5:9 (9 values from 0.1 \
                     to 0.5) or mu=0.1,0.2,0.4"
                ),
            ));
        };
        let param: Param = name
            .parse()
            .map_err(|e| bad(InputErrorKind::UnknownName, format!("{e}")))?;
        param
            .get(scene)
            .map_err(|e| bad(InputErrorKind::InvalidValue, format!("{e}")))?;
        let number = |text: &str| -> Result<f64, InputError> {
            match text.trim().parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(bad(
                    InputErrorKind::InvalidValue,
                    format!("{name}: \"{}\" is not a finite number", text.trim()),
                )),
            }
        };
        let parts: Vec<&str> = values.split(':').collect();
        let values = match parts.as_slice() {
            [start, stop, count] => {
                let (a, b) = (number(start)?, number(stop)?);
                let n: usize = count.trim().parse().ok().filter(|&n| n >= 1).ok_or_else(|| {
                    bad(
                        InputErrorKind::InvalidValue,
                        format!(
                            "{name}: the count \"{}\" of START:STOP:COUNT must be a whole number \
                             ≥ 1",
                            count.trim()
                        ),
                    )
                })?;
                linspace(a, b, n)
            }
            [list] => list
                .split(',')
                .map(number)
                .collect::<Result<Vec<f64>, _>>()?,
            _ => {
                return Err(bad(
                    InputErrorKind::InvalidValue,
                    format!(
                        "{name}: \"{values}\" is neither START:STOP:COUNT nor a list v1,v2,..."
                    ),
                ));
            }
        };
        Ok(Axis { param, values })
    }
}

/// `n` evenly spaced values from `a` to `b`, both included (`a` alone when `n = 1`), computed as
/// numpy's `linspace` computes them (`k · step + a`, the last value `b` exactly), so that a grid
/// written `mu=0.1:0.5:9` holds the same numbers as `numpy.linspace(0.1, 0.5, 9)`.
pub fn linspace(a: f64, b: f64, n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![a],
        _ => {
            let step = (b - a) / (n - 1) as f64;
            (0..n)
                .map(|k| if k == n - 1 { b } else { k as f64 * step + a })
                .collect()
        }
    }
}

/// A grid of parameter values: the Cartesian product of its axes, the last axis varying
/// fastest.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Grid {
    /// The axes, slowest first.
    pub axes: Vec<Axis>,
}

impl Grid {
    /// Parses `--param` specifications ([`Axis::parse`]); a parameter may appear once.
    pub fn parse(specs: &[String], scene: &ecp_formulations::Scene) -> Result<Grid, InputError> {
        let mut axes: Vec<Axis> = Vec::new();
        for spec in specs {
            let axis = Axis::parse(spec, scene)?;
            if axes.iter().any(|a| a.param == axis.param) {
                return Err(InputError::option(
                    "--param",
                    InputErrorKind::InvalidValue,
                    format!(
                        "parameter \"{}\" has two --param options; give all its values in one",
                        axis.param
                    ),
                ));
            }
            axes.push(axis);
        }
        Ok(Grid { axes })
    }

    /// Number of points (1 for a grid without axes: the scene as it is).
    pub fn len(&self) -> usize {
        self.axes
            .iter()
            .map(|a| a.values.len())
            .fold(1usize, usize::saturating_mul)
    }

    /// True when some axis has no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The points, in order: the last axis varies fastest.
    pub fn points(&self) -> Vec<Vec<(Param, f64)>> {
        let n = self.len();
        let mut points = Vec::with_capacity(n);
        for k in 0..n {
            let mut rest = k;
            let mut point = vec![(Param::Mu, 0.0); self.axes.len()];
            for (i, axis) in self.axes.iter().enumerate().rev() {
                let m = axis.values.len();
                point[i] = (axis.param, axis.values[rest % m]);
                rest /= m;
            }
            points.push(point);
        }
        points
    }
}

/// One run of a batch: a scene file (its parameters already set) and the values that were set.
#[derive(Clone, Debug)]
pub struct Job {
    /// The scene to run.
    pub file: SceneFile,
    /// The parameter values applied to it (empty for a scene run as it is).
    pub params: Vec<(Param, f64)>,
}

/// A list of independent runs.
#[derive(Clone, Debug, Default)]
pub struct Batch {
    /// The runs, in input order.
    pub jobs: Vec<Job>,
}

impl Batch {
    /// Each scene file as it is.
    pub fn scenes(files: impl IntoIterator<Item = SceneFile>) -> Batch {
        Batch {
            jobs: files
                .into_iter()
                .map(|file| Job {
                    file,
                    params: Vec::new(),
                })
                .collect(),
        }
    }

    /// `file` at every point of `grid` (last axis fastest).
    pub fn grid(file: &SceneFile, grid: &Grid) -> Result<Batch, InputError> {
        if grid.len() > MAX_GRID_POINTS {
            return Err(InputError::option(
                "--param",
                InputErrorKind::InvalidValue,
                format!(
                    "the grid has {} points, more than the {MAX_GRID_POINTS} a batch may run; \
                     use fewer values per parameter",
                    grid.len()
                ),
            ));
        }
        Batch::points(file, grid.points())
    }

    /// `file` at each of `points`, in order; every value is checked as the scene checks it (μ ≥
    /// 0, masses > 0, finite values, ...).
    pub fn points(file: &SceneFile, points: Vec<Vec<(Param, f64)>>) -> Result<Batch, InputError> {
        let mut jobs = Vec::with_capacity(points.len());
        for point in points {
            let mut job = file.clone();
            for (param, value) in &point {
                param.set(&mut job.scene, *value).map_err(|e| {
                    InputError::option("--param", InputErrorKind::InvalidValue, e.to_string())
                })?;
            }
            jobs.push(Job {
                file: job,
                params: point,
            });
        }
        Ok(Batch { jobs })
    }

    /// Number of runs.
    pub fn len(&self) -> usize {
        self.jobs.len()
    }

    /// True when there is no run.
    pub fn is_empty(&self) -> bool {
        self.jobs.is_empty()
    }

    /// Runs every job on a pool of `options.threads` threads and returns the results in input
    /// order. A run that fails (a step nothing solves, a scene its formulation refuses) is a
    /// result with its error, not an error of the batch; the error is for options that cannot
    /// run at all (an unknown backend combination, a pool that cannot start).
    pub fn run(&self, options: &BatchOptions) -> Result<Vec<JobResult>, InputError> {
        for job in &self.jobs {
            let formulation = options
                .formulation
                .as_ref()
                .unwrap_or(&job.file.formulation);
            let target = Target::resolve(formulation, &options.formulations)?;
            let name = options.solver.as_deref().unwrap_or(&job.file.solver.name);
            check_combination(&options.registry, name, &target)?;
        }
        if options.threads == Some(0) {
            return Err(InputError::option(
                "--threads",
                InputErrorKind::InvalidValue,
                "the thread count must be at least 1 (leave it out for one per core)",
            ));
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(options.threads.unwrap_or(0))
            .thread_name(|k| format!("ecp-batch-{k}"))
            .build()
            .map_err(|e| {
                InputError::option(
                    "--threads",
                    InputErrorKind::InvalidValue,
                    format!("cannot start the thread pool: {e}"),
                )
            })?;
        Ok(pool.install(|| {
            self.jobs
                .par_iter()
                .enumerate()
                .with_max_len(1)
                .map(|(index, job)| {
                    // A defect in one run is reported in its row, not as the loss of the batch.
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        run_job(index, job, options)
                    }))
                    .unwrap_or_else(|panic| panicked(index, job, panic.as_ref()))
                })
                .collect()
        }))
    }
}

/// Settings shared by every run of a batch; `None` fields take each scene file's choice.
#[derive(Clone, Debug)]
pub struct BatchOptions {
    /// Threads of the pool (`None`: one per core).
    pub threads: Option<usize>,
    /// Stop each run after this many steps (at most its scene's duration).
    pub steps: Option<usize>,
    /// Backend instead of each scene's `[solver] name`, by its name in
    /// [`BatchOptions::registry`].
    pub solver: Option<String>,
    /// The backends by name (the built-in ones unless the caller added its own); every run
    /// builds its solvers from it in its own thread.
    pub registry: Arc<Registry>,
    /// Formulation instead of each scene's, by its name in [`BatchOptions::formulations`].
    pub formulation: Option<String>,
    /// Where formulations are found by name: [`FormulationRegistry::builtin`] by default.
    pub formulations: FormulationRegistry,
    /// Fall back on other backends and substeps as `ecp run` does (`docs/fallbacks.md`).
    pub fallbacks: bool,
    /// Go on after a failed step (the bodies keep their state over it) instead of stopping the
    /// run there.
    pub keep_going: bool,
    /// Keep every step's record in [`JobResult::records`] (memory grows with runs × steps).
    pub records: bool,
}

impl Default for BatchOptions {
    fn default() -> Self {
        BatchOptions {
            threads: None,
            steps: None,
            solver: None,
            registry: Arc::new(Registry::builtin()),
            formulation: None,
            formulations: FormulationRegistry::builtin(),
            fallbacks: true,
            keep_going: false,
            records: false,
        }
    }
}

/// What one run of a batch produced: its summary row, its records if asked for, its error.
#[derive(Clone, Debug)]
pub struct JobResult {
    /// Position in the batch (from 0).
    pub index: usize,
    /// The scene's name.
    pub scene: String,
    /// The parameter values of the run.
    pub params: Vec<(Param, f64)>,
    /// The run's results (no timings).
    pub summary: JobSummary,
    /// Every step's record, when [`BatchOptions::records`] is set. Their `solve_us` and
    /// `summary.time` are timings, not results.
    pub records: Vec<StepRecord>,
    /// Why the run failed or stopped early, if it did (as `ecp run` says it).
    pub error: Option<String>,
    /// Wall-clock times: not results, they differ from run to run.
    pub timing: JobTiming,
}

/// The results of one run, as they appear in a row of `sweep.csv` (`docs/outputs.md`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct JobSummary {
    /// Steps taken.
    pub steps: usize,
    /// Steps asked for.
    pub planned_steps: usize,
    /// Steps that converged.
    pub converged_steps: usize,
    /// Steps that did not (plus a step the stepper refused).
    pub failed_steps: usize,
    /// The first failed step (from 1), if any.
    pub first_failed_step: Option<usize>,
    /// Every body's state after the last step (the initial states when no step was taken).
    pub final_bodies: Vec<BodyState>,
    /// Kinetic plus potential energy after the last step (NaN when no step was taken).
    pub energy: f64,
    /// Worst natural residual of the steps.
    pub max_residual: f64,
    /// Worst penetration of the real bodies (m).
    pub max_penetration: f64,
    /// Mean solver iterations per step.
    pub iterations_mean: f64,
    /// Most solver iterations of a step.
    pub iterations_max: usize,
    /// Steps re-solved once from the active-contact guess.
    pub retries: usize,
    /// Steps solved by a fallback backend.
    pub fallback_backend: usize,
    /// Steps solved in substeps.
    pub fallback_substeps: usize,
}

/// Wall-clock times of one run (not results).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct JobTiming {
    /// The whole run, set-up included (s).
    pub wall_s: f64,
    /// Sum of the steps' solve times (s).
    pub solve_s: f64,
}

fn run_job(index: usize, job: &Job, options: &BatchOptions) -> JobResult {
    let started = Instant::now();
    let file = &job.file;
    let formulation = options.formulation.as_ref().unwrap_or(&file.formulation);
    let mut config = file.solver.clone();
    if let Some(name) = &options.solver {
        config.name = name.trim().to_string();
    }
    let registry = options.registry.as_ref();
    let planned = options
        .steps
        .map_or(file.scene.num_steps(), |n| n.min(file.scene.num_steps()));
    let mut records: Vec<StepRecord> = Vec::with_capacity(planned.min(1 << 16));
    let mut error = None;
    let mut refused = false;
    let setup = (|| -> Result<_, String> {
        let target =
            Target::resolve(formulation, &options.formulations).map_err(|e| e.to_string())?;
        let solver = make_solver_in(registry, &config, &target).map_err(|e| e.to_string())?;
        let fallbacks = if options.fallbacks {
            fallbacks_for(registry, &config, &target).map_err(|e| e.to_string())?
        } else {
            Fallbacks::none()
        };
        let stepper = options
            .formulations
            .create(&target.name)
            .map_err(|e| e.to_string())?;
        let sim = SimulationBuilder::new(file.scene.clone(), stepper)
            .build()
            .map_err(|e| e.to_string())?;
        Ok((solver, fallbacks, sim))
    })();
    match setup {
        Err(e) => error = Some(e),
        Ok((mut solver, mut fallbacks, mut sim)) => {
            let mut taken = 0;
            while taken < planned {
                match sim.step_with(solver.as_mut(), &mut fallbacks) {
                    Ok(rec) => {
                        taken += 1;
                        let stop = !rec.converged && !options.keep_going;
                        if !rec.converged && error.is_none() {
                            error = Some(format!(
                                "step {} (t = {:.4} s) could not be solved: {} (best residual \
                                 {:.3e})",
                                rec.step,
                                rec.t - file.scene.h,
                                rec.summary.termination,
                                rec.summary.residual
                            ));
                        }
                        // The summary needs every step; the iteration traces only when the
                        // records are kept.
                        records.push(if options.records { rec } else { slim(rec) });
                        if stop {
                            break;
                        }
                    }
                    Err(e) => {
                        refused = true;
                        error = Some(format!("step {}: {e}", taken + 1));
                        break;
                    }
                }
            }
        }
    }
    let run = RunSummary::from_records(&file.scene, formulation, &config.name, &records, planned);
    let summary = JobSummary {
        steps: run.steps,
        planned_steps: planned,
        converged_steps: run.converged_steps,
        failed_steps: run.failed_steps + usize::from(refused),
        first_failed_step: run
            .failure
            .as_ref()
            .map(|f| f.step)
            .or(refused.then_some(run.steps + 1)),
        final_bodies: match records.last() {
            Some(r) => r.bodies.clone(),
            None => file.scene.bodies.iter().map(|b| b.initial).collect(),
        },
        energy: records.last().map_or(f64::NAN, |r| r.energy),
        max_residual: run.max_residual,
        max_penetration: run.max_penetration,
        iterations_mean: run.iterations.mean,
        iterations_max: run.iterations.max,
        retries: run.retries,
        fallback_backend: run.fallbacks.backend,
        fallback_substeps: run.fallbacks.substeps,
    };
    let solve_s = records.iter().map(|r| r.solve_us).sum::<f64>() * 1e-6;
    if !options.records {
        records = Vec::new();
    }
    JobResult {
        index,
        scene: file.scene.name.clone(),
        params: job.params.clone(),
        summary,
        records,
        error,
        timing: JobTiming {
            wall_s: started.elapsed().as_secs_f64(),
            solve_s,
        },
    }
}

/// The result of a run that panicked: no step, the panic's message as its error.
fn panicked(index: usize, job: &Job, panic: &(dyn std::any::Any + Send)) -> JobResult {
    let what = panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into());
    JobResult {
        index,
        scene: job.file.scene.name.clone(),
        params: job.params.clone(),
        summary: JobSummary {
            failed_steps: 1,
            first_failed_step: Some(1),
            final_bodies: job.file.scene.bodies.iter().map(|b| b.initial).collect(),
            energy: f64::NAN,
            ..JobSummary::default()
        },
        records: Vec::new(),
        error: Some(format!(
            "internal error in ecp: {what}; please report it with the scene"
        )),
        timing: JobTiming::default(),
    }
}

/// A record without its per-iteration trace (what the summary of a run needs of a step).
fn slim(mut rec: StepRecord) -> StepRecord {
    rec.summary.trace = Vec::new();
    rec
}

/// A column of a batch's table.
#[derive(Clone, Debug, PartialEq)]
pub enum Column {
    /// Numbers.
    F64(Vec<f64>),
    /// Counts.
    U64(Vec<u64>),
    /// Text.
    Str(Vec<String>),
}

/// The body columns of `sweep.csv`, as in `trajectory.csv`.
const BODY_COLUMNS: [&str; 13] = [
    "x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz",
];

/// The results as named columns, one row per run in input order (`docs/outputs.md#sweepcsv`):
/// `index`, `scene`, one column per parameter (named as in scene files; NaN where a run did not
/// set it), the step counts, the final state of every body (`x` … `wz`, suffixed `_b<i>` when a
/// scene has several bodies), `energy`, `max_residual`, `max_penetration`, `iterations_mean`,
/// `iterations_max`, `retries`, `fallback_backend`, `fallback_substeps`, `first_failed_step`
/// (0: none) and `error` (empty: none). No timings: see [`timing_table`].
pub fn table(results: &[JobResult]) -> Vec<(String, Column)> {
    let mut params: Vec<Param> = Vec::new();
    for r in results {
        for (p, _) in &r.params {
            if !params.contains(p) {
                params.push(*p);
            }
        }
    }
    let bodies = results
        .iter()
        .map(|r| r.summary.final_bodies.len())
        .max()
        .unwrap_or(1);
    let u = |f: &dyn Fn(&JobResult) -> usize| -> Column {
        Column::U64(results.iter().map(|r| f(r) as u64).collect())
    };
    let x =
        |f: &dyn Fn(&JobResult) -> f64| -> Column { Column::F64(results.iter().map(f).collect()) };
    let mut cols: Vec<(String, Column)> = vec![
        ("index".into(), u(&|r| r.index)),
        (
            "scene".into(),
            Column::Str(results.iter().map(|r| r.scene.clone()).collect()),
        ),
    ];
    for p in &params {
        let values = results
            .iter()
            .map(|r| {
                r.params
                    .iter()
                    .find(|(q, _)| q == p)
                    .map_or(f64::NAN, |(_, v)| *v)
            })
            .collect();
        cols.push((p.to_string(), Column::F64(values)));
    }
    cols.push(("steps".into(), u(&|r| r.summary.steps)));
    cols.push(("planned_steps".into(), u(&|r| r.summary.planned_steps)));
    cols.push(("converged_steps".into(), u(&|r| r.summary.converged_steps)));
    cols.push(("failed_steps".into(), u(&|r| r.summary.failed_steps)));
    for b in 0..bodies {
        let suffix = if bodies > 1 {
            format!("_b{b}")
        } else {
            String::new()
        };
        for (k, name) in BODY_COLUMNS.iter().enumerate() {
            let values = results
                .iter()
                .map(|r| {
                    r.summary
                        .final_bodies
                        .get(b)
                        .map_or(f64::NAN, |s| state_component(s, k))
                })
                .collect();
            cols.push((format!("{name}{suffix}"), Column::F64(values)));
        }
    }
    cols.push(("energy".into(), x(&|r| r.summary.energy)));
    cols.push(("max_residual".into(), x(&|r| r.summary.max_residual)));
    cols.push(("max_penetration".into(), x(&|r| r.summary.max_penetration)));
    cols.push(("iterations_mean".into(), x(&|r| r.summary.iterations_mean)));
    cols.push(("iterations_max".into(), u(&|r| r.summary.iterations_max)));
    cols.push(("retries".into(), u(&|r| r.summary.retries)));
    cols.push((
        "fallback_backend".into(),
        u(&|r| r.summary.fallback_backend),
    ));
    cols.push((
        "fallback_substeps".into(),
        u(&|r| r.summary.fallback_substeps),
    ));
    cols.push((
        "first_failed_step".into(),
        u(&|r| r.summary.first_failed_step.unwrap_or(0)),
    ));
    cols.push((
        "error".into(),
        Column::Str(
            results
                .iter()
                .map(|r| r.error.clone().unwrap_or_default())
                .collect(),
        ),
    ));
    cols
}

/// Component `k` of a state in the order of [`BODY_COLUMNS`].
fn state_component(s: &BodyState, k: usize) -> f64 {
    match k {
        0..3 => s.x[k],
        3..7 => s.q[k - 3],
        7..10 => s.v[k - 7],
        _ => s.w[k - 10],
    }
}

/// The wall-clock times of the runs (`index`, `wall_s`, `solve_s`): not results, they differ
/// from run to run and with the thread count.
pub fn timing_table(results: &[JobResult]) -> Vec<(String, Column)> {
    vec![
        (
            "index".into(),
            Column::U64(results.iter().map(|r| r.index as u64).collect()),
        ),
        (
            "wall_s".into(),
            Column::F64(results.iter().map(|r| r.timing.wall_s).collect()),
        ),
        (
            "solve_s".into(),
            Column::F64(results.iter().map(|r| r.timing.solve_s).collect()),
        ),
    ]
}

/// Writes named columns as CSV (numbers in Rust's shortest round-trip form, so the file holds
/// the exact values).
pub fn write_csv(path: &Path, columns: &[(String, Column)]) -> Result<(), OutputError> {
    let io = |e: std::io::Error| OutputError {
        path: path.to_path_buf(),
        source: e,
    };
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let mut w = csv::Writer::from_path(path).map_err(|e| io(e.into()))?;
    w.write_record(columns.iter().map(|(name, _)| name.as_str()))
        .map_err(|e| io(e.into()))?;
    let rows = columns.first().map_or(0, |(_, c)| match c {
        Column::F64(v) => v.len(),
        Column::U64(v) => v.len(),
        Column::Str(v) => v.len(),
    });
    for i in 0..rows {
        let row: Vec<String> = columns
            .iter()
            .map(|(_, c)| match c {
                Column::F64(v) => v[i].to_string(),
                Column::U64(v) => v[i].to_string(),
                Column::Str(v) => v[i].clone(),
            })
            .collect();
        w.write_record(&row).map_err(|e| io(e.into()))?;
    }
    w.flush().map_err(io)
}

/// The bytes of every result of `results` (the table and, when kept, every record's numbers,
/// timings excluded), for comparing two batches bit for bit.
pub fn result_bytes(results: &[JobResult]) -> Vec<u8> {
    let mut out = Vec::new();
    for (name, col) in table(results) {
        out.extend_from_slice(name.as_bytes());
        match col {
            Column::F64(v) => v.iter().for_each(|x| out.extend(x.to_le_bytes())),
            Column::U64(v) => v.iter().for_each(|x| out.extend(x.to_le_bytes())),
            Column::Str(v) => v.iter().for_each(|s| {
                out.extend(s.as_bytes());
                out.push(0);
            }),
        }
    }
    for r in results {
        for rec in &r.records {
            let mut push = |x: f64| out.extend(x.to_le_bytes());
            push(rec.t);
            for s in &rec.bodies {
                s.x.iter()
                    .chain(&s.q)
                    .chain(&s.v)
                    .chain(&s.w)
                    .for_each(|&x| push(x));
            }
            for c in &rec.contacts {
                c.a1.iter().chain(&c.a2).for_each(|&x| push(x));
                for x in [c.lg, c.pn, c.pt, c.po, c.pr, c.sigma, c.min_gap] {
                    push(x);
                }
            }
            push(rec.energy);
            push(rec.summary.residual);
            push(rec.summary.iterations as f64);
            out.extend(rec.method.column().as_bytes());
        }
    }
    out
}
