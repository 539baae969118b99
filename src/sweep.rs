//! `ecp sweep SCENE --param mu=0.1:0.5:9 [--param ...]`: one scene over a grid of parameter
//! values, run as a [`crate::batch`] on every core, written as one table of summaries
//! (`sweep.csv`, one row per grid point, `docs/outputs.md#sweepcsv`) and the runs' wall-clock
//! times apart (`sweep_timing.csv`).

use std::path::PathBuf;
use std::time::Instant;

use crate::batch::{Batch, BatchOptions, Grid, JobResult, table, timing_table, write_csv};
use crate::error::{InputError, InputErrorKind};
use crate::run::RunError;
use crate::scene::SceneFile;

/// What a sweep wrote.
#[derive(Debug)]
pub struct SweepOutcome {
    /// The runs' results, in grid order.
    pub results: Vec<JobResult>,
    /// `sweep.csv`.
    pub table: PathBuf,
    /// `sweep_timing.csv`.
    pub timing: PathBuf,
    /// Wall time of the whole sweep (s).
    pub wall_s: f64,
    /// Threads used.
    pub threads: usize,
}

impl SweepOutcome {
    /// Runs with a failed step or an error.
    pub fn failed_runs(&self) -> usize {
        self.results
            .iter()
            .filter(|r| r.error.is_some() || r.summary.failed_steps > 0)
            .count()
    }
}

/// Runs `file` at every point of the grid given by `params` (`--param` specifications,
/// [`crate::batch::Axis::parse`]) and writes `sweep.csv` and `sweep_timing.csv` into `out_dir`.
pub fn sweep_scene(
    file: &SceneFile,
    params: &[String],
    options: &BatchOptions,
    out_dir: &std::path::Path,
) -> Result<SweepOutcome, RunError> {
    if params.is_empty() {
        return Err(InputError::option(
            "--param",
            InputErrorKind::MissingKey,
            "give at least one --param NAME=START:STOP:COUNT (e.g. --param mu=0.1:0.5:9) or \
             NAME=v1,v2,...",
        )
        .into());
    }
    let started = Instant::now();
    let grid = Grid::parse(params, &file.scene)?;
    let batch = Batch::grid(file, &grid)?;
    let results = batch.run(options)?;
    let table_path = out_dir.join("sweep.csv");
    let timing_path = out_dir.join("sweep_timing.csv");
    write_csv(&table_path, &table(&results))?;
    write_csv(&timing_path, &timing_table(&results))?;
    Ok(SweepOutcome {
        results,
        table: table_path,
        timing: timing_path,
        wall_s: started.elapsed().as_secs_f64(),
        threads: options
            .threads
            .unwrap_or_else(rayon::current_num_threads)
            .min(batch.len().max(1)),
    })
}
