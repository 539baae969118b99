//! The output files of `docs/outputs.md`: `trajectory.csv` (written and flushed row by row, so a
//! failed or interrupted run keeps what it computed), `summary.json` and `compare.json`.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use ecp_formulations::{Scene, StepMethod, StepRecord};
use serde::Serialize;

/// An I/O failure on an output file.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {}: {source}; check that the directory is writable and the disk is not full", path.display())]
pub struct OutputError {
    /// The file or directory.
    pub path: PathBuf,
    /// The underlying error.
    pub source: std::io::Error,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `trajectory.csv`: the header at creation, then one flushed row per step.
pub struct TrajectoryWriter {
    path: PathBuf,
    out: csv::Writer<BufWriter<File>>,
}

impl TrajectoryWriter {
    /// Creates (truncates) `path` and writes the header for `scene`'s bodies with
    /// `contacts_per_body` contacts each ([`ecp_formulations::Simulation::contacts_per_body`]).
    pub fn create(
        path: &Path,
        scene: &Scene,
        contacts_per_body: usize,
    ) -> Result<Self, OutputError> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        }
        let file = File::create(path).map_err(io_err(path))?;
        let mut out = csv::Writer::from_writer(BufWriter::new(file));
        let header = StepRecord::csv_header(scene.bodies.len(), contacts_per_body);
        let mut w = TrajectoryWriter {
            path: path.to_path_buf(),
            out: {
                out.write_record(&header).map_err(|e| OutputError {
                    path: path.to_path_buf(),
                    source: e.into(),
                })?;
                out
            },
        };
        w.flush()?;
        Ok(w)
    }

    /// Appends one step's row and flushes it to disk.
    pub fn write(&mut self, record: &StepRecord) -> Result<(), OutputError> {
        self.out
            .write_record(record.csv_fields())
            .map_err(|e| OutputError {
                path: self.path.clone(),
                source: e.into(),
            })?;
        self.flush()
    }

    fn flush(&mut self) -> Result<(), OutputError> {
        self.out.flush().map_err(io_err(&self.path))
    }
}

/// The columns of `contacts.csv` (`docs/outputs.md#contactscsv`).
pub const CONTACTS_COLUMNS: [&str; 20] = [
    "step", "t", "body_a", "body_b", "a1_x", "a1_y", "a1_z", "a2_x", "a2_y", "a2_z", "n_x", "n_y",
    "n_z", "pn", "pt", "po", "pr", "sigma", "gap", "mode",
];

/// Writes `contacts.csv`: one flushed row per step and active contact between named bodies
/// ([`StepRecord::pairs`]), in long format (`docs/outputs.md#contactscsv`).
pub struct ContactsWriter {
    path: PathBuf,
    out: csv::Writer<BufWriter<File>>,
}

impl ContactsWriter {
    /// Creates (truncates) `path` and writes the header.
    pub fn create(path: &Path) -> Result<Self, OutputError> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        }
        let file = File::create(path).map_err(io_err(path))?;
        let mut w = ContactsWriter {
            path: path.to_path_buf(),
            out: csv::Writer::from_writer(BufWriter::new(file)),
        };
        w.row(CONTACTS_COLUMNS.iter().map(|c| c.to_string()).collect())?;
        w.flush()?;
        Ok(w)
    }

    fn row(&mut self, fields: Vec<String>) -> Result<(), OutputError> {
        self.out.write_record(fields).map_err(|e| OutputError {
            path: self.path.clone(),
            source: e.into(),
        })
    }

    /// Appends the rows of one step and flushes them to disk.
    pub fn write(&mut self, record: &StepRecord) -> Result<(), OutputError> {
        for p in &record.pairs {
            let mut f = vec![
                record.step.to_string(),
                format!("{}", record.t),
                p.body_a.clone(),
                p.body_b.clone(),
            ];
            for v in [
                p.a1.x, p.a1.y, p.a1.z, p.a2.x, p.a2.y, p.a2.z, p.normal.x, p.normal.y, p.normal.z,
                p.pn, p.pt, p.po, p.pr, p.sigma, p.gap,
            ] {
                f.push(format!("{v:e}"));
            }
            f.push(p.mode.as_str().to_string());
            self.row(f)?;
        }
        self.flush()
    }

    fn flush(&mut self) -> Result<(), OutputError> {
        self.out.flush().map_err(io_err(&self.path))
    }
}

/// One contact pair of `summary.json` (`docs/outputs.md#summaryjson`).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct PairSummary {
    /// The dynamic body.
    pub body_a: String,
    /// The other body or half-space.
    pub body_b: String,
    /// Steps at which the pair had a contact set.
    pub active_steps: usize,
    /// Steps at which it carried a normal impulse.
    pub loaded_steps: usize,
    /// Largest normal impulse (N s).
    pub max_pn: f64,
    /// Its contact mode at each change (`none` while it has no contact set).
    pub mode_sequence: Vec<ModeChange>,
}

impl PairSummary {
    /// The pairs of `records`, in order of first appearance.
    pub fn of(records: &[StepRecord]) -> Vec<PairSummary> {
        let mut out: Vec<PairSummary> = Vec::new();
        for r in records {
            for p in &r.pairs {
                if !out
                    .iter()
                    .any(|s| s.body_a == p.body_a && s.body_b == p.body_b)
                {
                    out.push(PairSummary {
                        body_a: p.body_a.clone(),
                        body_b: p.body_b.clone(),
                        ..Default::default()
                    });
                }
            }
            for s in &mut out {
                let found = r
                    .pairs
                    .iter()
                    .find(|p| p.body_a == s.body_a && p.body_b == s.body_b);
                let mode = match found {
                    Some(p) => {
                        s.active_steps += 1;
                        if p.pn > 0.0 {
                            s.loaded_steps += 1;
                        }
                        s.max_pn = s.max_pn.max(p.pn);
                        p.mode.as_str()
                    }
                    None => "none",
                };
                if s.mode_sequence.last().is_none_or(|last| last.mode != mode) {
                    s.mode_sequence.push(ModeChange {
                        t: r.t,
                        mode: mode.to_string(),
                    });
                }
            }
        }
        out
    }
}

/// Order statistics of the solve time per step (µs).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct TimeStats {
    /// Fastest step.
    pub min: f64,
    /// Median step.
    pub median: f64,
    /// Mean.
    pub mean: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Slowest step.
    pub max: f64,
}

impl TimeStats {
    /// Statistics of `values` (all zero when empty).
    pub fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let rank = |p: f64| v[((p * n as f64).ceil() as usize).clamp(1, n) - 1];
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
        TimeStats {
            min: v[0],
            median,
            mean: v.iter().sum::<f64>() / n as f64,
            p95: rank(0.95),
            max: v[n - 1],
        }
    }
}

/// Mean and maximum iterations per step.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct IterationStats {
    /// Mean over steps.
    pub mean: f64,
    /// Maximum over steps.
    pub max: usize,
}

/// A change of contact mode.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ModeChange {
    /// Time at the end of the step where the new mode is first seen.
    pub t: f64,
    /// `patch`, `line`, `point` or `none`.
    pub mode: String,
}

/// The state of a body at the end of the run.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct FinalState {
    /// Body name.
    pub name: String,
    /// CM position (m).
    pub position: [f64; 3],
    /// Unit quaternion `(w, x, y, z)`.
    pub orientation: [f64; 4],
    /// Linear velocity (m/s).
    pub velocity: [f64; 3],
    /// Angular velocity (rad/s), world frame.
    pub angular_velocity: [f64; 3],
}

/// Where a run stopped without converging.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Failure {
    /// Step index (from 1).
    pub step: usize,
    /// Time at the start of the failed step.
    pub t: f64,
    /// Why (the solver's termination, or the stepper's error).
    pub reason: String,
    /// Natural residual of the best iterate (`null` in JSON when the step has no iterate).
    pub residual: f64,
}

/// How many steps needed which fallback (`summary.json`'s `fallbacks`).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct FallbackCounts {
    /// Steps solved in one piece by a fallback backend.
    pub backend: usize,
    /// Steps solved in substeps.
    pub substeps: usize,
    /// Steps no fallback could solve (the bodies kept their state at the step's start).
    pub failed: usize,
    /// Steps solved by each fallback backend, by name.
    pub by_backend: std::collections::BTreeMap<String, usize>,
}

impl FallbackCounts {
    /// The counts over `records`.
    pub fn of(records: &[StepRecord]) -> Self {
        let mut c = FallbackCounts::default();
        for r in records {
            match &r.method {
                StepMethod::Direct => {}
                StepMethod::Backend(name) => {
                    c.backend += 1;
                    *c.by_backend.entry(name.clone()).or_default() += 1;
                }
                StepMethod::Substeps { .. } => c.substeps += 1,
                StepMethod::Failed | StepMethod::Unchecked => c.failed += 1,
            }
        }
        c
    }
}

/// `summary.json` (`docs/outputs.md`), plus a few extra fields.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct RunSummary {
    /// Scene name.
    pub scene: String,
    /// Contact formulation.
    pub formulation: String,
    /// Solver backend.
    pub solver: String,
    /// Step length (s).
    pub h: f64,
    /// Steps taken (converged or not).
    pub steps: usize,
    /// Steps that converged.
    pub converged_steps: usize,
    /// Steps that did not converge.
    pub failed_steps: usize,
    /// Wall time of the whole run (s), output included.
    pub wall_s: f64,
    /// Wall time per step (µs): the records' `solve_us` (the step without its record, the CSV
    /// rows and the progress output; `docs/outputs.md#summaryjson`).
    pub step_us: TimeStats,
    /// Solver iterations per step.
    pub iterations: IterationStats,
    /// Worst natural-map residual over the steps.
    pub max_residual: f64,
    /// Max over steps and vertices of the real body of `max(0, −gap)` (m).
    pub max_penetration: f64,
    /// Contact mode of the first contact (body 0, half-space 0), at each change.
    pub mode_sequence: Vec<ModeChange>,
    /// Final state of body 0.
    #[serde(rename = "final")]
    pub final_state: FinalState,
    /// Final state of every body.
    pub final_bodies: Vec<FinalState>,
    /// Steps the stepper re-solved once from its active-contact guess.
    pub retries: usize,
    /// Steps that needed a fallback, by kind (`docs/fallbacks.md`).
    pub fallbacks: FallbackCounts,
    /// The first failure, if any.
    pub failure: Option<Failure>,
    /// Steps the scene asked for (the run may stop earlier on a failure or `--steps`).
    pub planned_steps: usize,
    /// Every contact pair between named bodies (the multi-body formulation), with its mode
    /// sequence.
    pub pairs: Vec<PairSummary>,
    /// The scene file the run read, as an absolute path where it can be made one; `ecp animate`
    /// reads the geometry from it (`docs/outputs.md#animationgif`). Empty when the summary was
    /// not made by a run of a scene file.
    pub scene_path: String,
}

impl RunSummary {
    /// The summary of `records` of a run of `scene` (`wall_s` is filled in by the caller).
    pub fn from_records(
        scene: &Scene,
        formulation: &str,
        solver: &str,
        records: &[StepRecord],
        planned_steps: usize,
    ) -> Self {
        let times: Vec<f64> = records.iter().map(|r| r.solve_us).collect();
        let iters: Vec<usize> = records.iter().map(|r| r.summary.iterations).collect();
        let converged = records.iter().filter(|r| r.converged).count();
        let mut modes: Vec<ModeChange> = Vec::new();
        for r in records {
            if let Some(c) = r.contacts.first() {
                let m = c.mode.as_str();
                if modes.last().is_none_or(|last| last.mode != m) {
                    modes.push(ModeChange {
                        t: r.t,
                        mode: m.to_string(),
                    });
                }
            }
        }
        let final_bodies: Vec<FinalState> = match records.last() {
            Some(r) => r
                .bodies
                .iter()
                .zip(&scene.bodies)
                .map(|(s, spec)| FinalState {
                    name: spec.name.clone(),
                    position: s.x.into(),
                    orientation: s.q.into(),
                    velocity: s.v.into(),
                    angular_velocity: s.w.into(),
                })
                .collect(),
            None => scene
                .bodies
                .iter()
                .map(|spec| FinalState {
                    name: spec.name.clone(),
                    position: spec.initial.x.into(),
                    orientation: spec.initial.q.into(),
                    velocity: spec.initial.v.into(),
                    angular_velocity: spec.initial.w.into(),
                })
                .collect(),
        };
        RunSummary {
            scene_path: String::new(),
            scene: scene.name.clone(),
            formulation: formulation.to_string(),
            solver: solver.to_string(),
            h: scene.h,
            steps: records.len(),
            converged_steps: converged,
            failed_steps: records.len() - converged,
            wall_s: 0.0,
            step_us: TimeStats::of(&times),
            iterations: IterationStats {
                mean: if iters.is_empty() {
                    0.0
                } else {
                    iters.iter().sum::<usize>() as f64 / iters.len() as f64
                },
                max: iters.iter().copied().max().unwrap_or(0),
            },
            max_residual: records
                .iter()
                .map(|r| r.summary.residual)
                .fold(0.0, f64::max),
            max_penetration: records
                .iter()
                .flat_map(|r| r.contacts.iter().map(|c| (-c.min_gap).max(0.0)))
                .fold(0.0, f64::max),
            mode_sequence: modes,
            final_state: final_bodies.first().cloned().unwrap_or_default(),
            final_bodies,
            retries: records
                .iter()
                .filter_map(|r| r.summary.counter(ecp_model::Counter::Retries))
                .sum(),
            fallbacks: FallbackCounts::of(records),
            failure: records.iter().find(|r| !r.converged).map(|r| Failure {
                step: r.step,
                t: r.t - scene.h,
                reason: r.summary.termination.to_string(),
                residual: r.summary.residual,
            }),
            planned_steps,
            pairs: PairSummary::of(records),
        }
    }
}

/// Writes `value` as pretty JSON to `path`.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), OutputError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    }
    let text = serde_json::to_string_pretty(value).map_err(|e| OutputError {
        path: path.to_path_buf(),
        source: e.into(),
    })?;
    std::fs::write(path, text + "\n").map_err(io_err(path))
}

/// One run of `compare.json`: the summary fields plus the differences against the first run.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct CompareRun {
    /// The run's summary (flattened into the object).
    #[serde(flatten)]
    pub summary: RunSummary,
    /// Max over common steps of `|v − v_first|` (m/s, any component, any body).
    pub max_diff_v: f64,
    /// Max over common steps of `|ω − ω_first|` (rad/s).
    pub max_diff_w: f64,
}

/// `compare.json`.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct CompareReport {
    /// Scene name.
    pub scene: String,
    /// One entry per (formulation, solver), in the order run.
    pub runs: Vec<CompareRun>,
    /// Combinations that could not run (the conic backend with a formulation that has no step
    /// structure, a formulation that does not apply to the scene), with the reason.
    pub skipped: Vec<SkippedRun>,
}

/// A combination of `compare` that did not run, and why.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct SkippedRun {
    /// Contact formulation.
    pub formulation: String,
    /// Solver backend.
    pub solver: String,
    /// Why it did not run.
    pub reason: String,
}

/// Max over common steps and bodies of the absolute differences in linear and angular velocity.
pub fn max_velocity_differences(a: &[StepRecord], b: &[StepRecord]) -> (f64, f64) {
    let mut dv: f64 = 0.0;
    let mut dw: f64 = 0.0;
    for (ra, rb) in a.iter().zip(b) {
        for (sa, sb) in ra.bodies.iter().zip(&rb.bodies) {
            dv = dv.max((sa.v - sb.v).amax());
            dw = dw.max((sa.w - sb.w).amax());
        }
    }
    (dv, dw)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_stats_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        let s = TimeStats::of(&v);
        assert_eq!((s.min, s.max, s.p95), (1.0, 100.0, 95.0));
        assert_eq!(s.median, 50.5);
        assert_eq!(s.mean, 50.5);
        assert_eq!(TimeStats::of(&[]), TimeStats::default());
    }
}
