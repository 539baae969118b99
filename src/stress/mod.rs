//! The random-scene stress suite: a seeded generator ([`generate()`]) of ordinary scene files of every kind a
//! new user would try, a [`runner`] that runs each with a backend as `ecp run SCENE --solver S
//! --formulation hull --keep-going` does and measures the run independently (convergence,
//! failed steps, penetration from the poses and the real body's vertices, energy of unforced
//! scenes, wall time), and the [`report`] tables. `docs/stress.md` describes the categories, the
//! columns and the command of the full run (`cargo run --release --example stress`).
//!
//! ```
//! let scenes = ecp::stress::generate(7, 13);
//! assert_eq!(scenes.len(), 13);
//! assert_eq!(scenes, ecp::stress::generate(7, 13)); // the same text from the same seed
//! ```

pub mod generate;
pub mod report;
pub mod runner;

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

pub use generate::{Category, StressScene, generate};
pub use runner::{RunConfig, RunResult, measure_records, run_file};

/// The seed of the documented full run.
pub const DEFAULT_SEED: u64 = 20_260_525;

/// The number of scenes of the documented full run (12 of each of the 13 categories).
pub const DEFAULT_COUNT: usize = 156;

/// A run whose wall time exceeds this multiple of PATH's on the same scene is timed again
/// (`docs/stress.md#wall-time-ratios`).
pub const RETIME_RATIO: f64 = 10.0;

/// How many more times such a run and its scene's PATH run are timed, one at a time; each keeps
/// its shortest wall time (the runs are deterministic: only the time is replaced).
pub const RETIME_REPEATS: usize = 2;

/// Settings of a run of many scenes with several backends.
#[derive(Clone, Debug)]
pub struct SuiteOptions {
    /// Output directory: `scenes/` (the scene and mesh files), `runs/<solver>/<scene>/`.
    pub out_dir: PathBuf,
    /// Backends by name (built-in), each run on every scene.
    pub solvers: Vec<String>,
    /// Stop every run after this many steps.
    pub steps: Option<usize>,
    /// Time limit of one run.
    pub time_limit: Option<Duration>,
    /// Runs at once (threads).
    pub jobs: usize,
    /// Run with the driver's fallbacks (`ecp run`'s default) instead of each backend by itself.
    pub fallbacks: bool,
}

impl SuiteOptions {
    /// The run of one scene (file stem `stem`) with one backend under these options.
    fn run_config(&self, solver: &str, stem: &str) -> RunConfig {
        RunConfig {
            solver: solver.to_string(),
            steps: self.steps,
            time_limit: self.time_limit,
            fallbacks: self.fallbacks,
            out_dir: self.out_dir.join("runs").join(solver).join(stem),
        }
    }
}

/// Writes `scenes` into `out_dir/scenes/` and runs each with every backend of `options`;
/// `on_result` sees each result as it arrives. The results come back ordered by scene, then
/// backend in the order given.
pub fn run_suite(
    scenes: &[StressScene],
    options: &SuiteOptions,
    on_result: impl Fn(&RunResult) + Sync,
) -> std::io::Result<Vec<RunResult>> {
    let scene_dir = options.out_dir.join("scenes");
    let paths = scenes
        .iter()
        .map(|s| s.write_to(&scene_dir))
        .collect::<std::io::Result<Vec<PathBuf>>>()?;
    run_paths(&paths, options, on_result)
}

/// Runs the scene files `paths` with every backend of `options` (see [`run_suite`]).
pub fn run_paths(
    paths: &[PathBuf],
    options: &SuiteOptions,
    on_result: impl Fn(&RunResult) + Sync,
) -> std::io::Result<Vec<RunResult>> {
    let jobs: Vec<(usize, &Path, &str)> = paths
        .iter()
        .enumerate()
        .flat_map(|(i, p)| {
            options
                .solvers
                .iter()
                .map(move |s| (i, p.as_path(), s.as_str()))
        })
        .collect();
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<(usize, usize, RunResult)>> = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..options.jobs.max(1) {
            scope.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::SeqCst);
                    let Some(&(i, path, solver)) = jobs.get(k) else {
                        break;
                    };
                    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene");
                    let config = options.run_config(solver, stem);
                    let r = run_file(path, &config);
                    on_result(&r);
                    let order = options.solvers.iter().position(|s| *s == solver);
                    if let Ok(mut all) = results.lock() {
                        all.push((i, order.unwrap_or(0), r));
                    }
                }
            });
        }
    });
    let mut all = results.into_inner().map_err(|_| {
        std::io::Error::other("a run panicked while holding the results; see its message above")
    })?;
    all.sort_by_key(|(i, o, _)| (*i, *o));
    let mut results: Vec<RunResult> = all.into_iter().map(|(_, _, r)| r).collect();
    retime(paths, options, &mut results);
    Ok(results)
}

/// Times again, [`RETIME_REPEATS`] more times each, every run over [`RETIME_RATIO`] × its scene's
/// PATH run (PATH's counted as at least [`report::PATH_WALL_FLOOR_S`], as the criterion counts
/// it) and that PATH run, and keeps each one's shortest wall time: a PATH run of 10 ms is at the
/// mercy of the machine's other work, so one timing decides no ratio.
fn retime(paths: &[PathBuf], options: &SuiteOptions, results: &mut [RunResult]) {
    let per_scene = options.solvers.len();
    let Some(path_order) = options.solvers.iter().position(|s| s == "path") else {
        return;
    };
    for (i, scene) in paths.iter().enumerate() {
        let base = i * per_scene;
        let Some(path_wall) = results.get(base + path_order).map(|r| r.wall_s) else {
            continue;
        };
        let slow: Vec<usize> = (0..per_scene)
            .filter(|&o| o != path_order)
            .filter(|&o| {
                results.get(base + o).is_some_and(|r| {
                    !r.timed_out
                        && r.wall_s > RETIME_RATIO * path_wall.max(report::PATH_WALL_FLOOR_S)
                })
            })
            .collect();
        if slow.is_empty() {
            continue;
        }
        let stem = scene
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("scene");
        for o in std::iter::once(path_order).chain(slow) {
            let solver = &options.solvers[o];
            let config = options.run_config(solver, stem);
            for _ in 0..RETIME_REPEATS {
                let again = run_file(scene, &config);
                let r = &mut results[base + o];
                r.wall_s = r.wall_s.min(again.wall_s);
            }
        }
    }
}
