//! Running one stress scene with one backend through the same path as `ecp run SCENE --solver S
//! --formulation hull --keep-going`, and measuring the run independently of what the stepper
//! reports: penetration from the recorded poses and the real body's vertices, and the total
//! energy of unforced scenes from the recorded states (see `docs/stress.md`).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use ecp_formulations::{BodyState, Load, Scene, StepRecord};
use nalgebra::Vector3;
use serde::Serialize;

use crate::run::{RunOptions, run_scene};
use crate::scene::load_scene;

use super::generate::quat_to_matrix;

/// Penetration above which a run counts as penetrating (m).
pub const PENETRATION_LIMIT: f64 = 1e-8;

/// Energy rise of an unforced run, relative to its energy scale, above which it counts as
/// gaining energy.
pub const ENERGY_LIMIT: f64 = 1e-6;

/// A contact whose normal impulse is below `PN_FLOOR · m |g| h` counts as carrying none.
pub const PN_FLOOR: f64 = 1e-9;

/// A contact is open when the smallest gap of the real body to its half-space exceeds this (m).
pub const OPEN_GAP: f64 = 1e-9;

/// The default time limit of one run.
pub const TIME_LIMIT: Duration = Duration::from_secs(60);

/// How to run a scene.
#[derive(Clone, Debug)]
pub struct RunConfig {
    /// The backend's (built-in) name.
    pub solver: String,
    /// Stop after this many steps (the scene's duration when `None`).
    pub steps: Option<usize>,
    /// Stop a run that takes longer than this (a timeout).
    pub time_limit: Option<Duration>,
    /// Where `trajectory.csv` and `summary.json` go.
    pub out_dir: PathBuf,
    /// Let the run driver fall back on other backends and substeps (`docs/fallbacks.md`), as
    /// `ecp run` does by default. Off, the run measures the backend by itself.
    pub fallbacks: bool,
}

/// What one run of one scene with one backend measured.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct RunResult {
    /// Scene name.
    pub scene: String,
    /// Scene category (the part of the name after the index, or `file` for other scenes).
    pub category: String,
    /// Backend.
    pub solver: String,
    /// Steps the scene asked for.
    pub planned_steps: usize,
    /// Steps taken.
    pub steps: usize,
    /// Steps the backend did not converge on (plus a step the stepper refused).
    pub failed_steps: usize,
    /// Every planned step was taken and converged, within the time limit.
    pub all_converged: bool,
    /// The run reached its last step (converged or not) within the time limit.
    pub completed: bool,
    /// The run was stopped at the time limit.
    pub timed_out: bool,
    /// A scene that did not load, a run that could not start, or the stepper's error.
    pub error: Option<String>,
    /// The first step that did not converge (from 1).
    pub first_failed_step: Option<usize>,
    /// Why it did not converge.
    pub first_failure: Option<String>,
    /// Largest penetration of any vertex of any body into any half-space over the recorded
    /// steps (m), recomputed from the poses; infinite once a pose is not finite.
    pub max_penetration: f64,
    /// The step of the largest penetration (0 when none).
    pub penetration_step: usize,
    /// No applied load besides gravity.
    pub unforced: bool,
    /// `Σ_b m_b |g| d_b + E_kin(0)` with `d_b` the body's diameter (J).
    pub energy_scale: f64,
    /// `max_k (E_k − E_0)` over the recorded steps, relative to the scale (unforced runs only).
    pub energy_rise: f64,
    /// The same, with the energy changes of the opening steps left out.
    pub energy_rise_outside_openings: f64,
    /// `Σ max(0, E_k − E_{k−1})` over the steps that are not opening steps, relative.
    pub energy_step_gains: f64,
    /// Steps at which a contact that carried `p_n > 0` opens (the loaded step and the next).
    pub opening_steps: usize,
    /// `Σ (E_k − E_{k−1})` over the opening steps, relative.
    pub opening_energy: f64,
    /// Largest energy gain of one opening step, relative.
    pub opening_max_gain: f64,
    /// Wall time of the run (s), outputs included.
    pub wall_s: f64,
    /// Median solve time of one step (µs), the summary's `step_us.median`: the per-step cost of
    /// the backend on this scene, without the outputs (0 when no step ran).
    pub step_us_median: f64,
}

impl RunResult {
    pub(crate) fn empty(scene: &str, category: &str, solver: &str) -> Self {
        RunResult {
            scene: scene.to_string(),
            category: category.to_string(),
            solver: solver.to_string(),
            planned_steps: 0,
            steps: 0,
            failed_steps: 0,
            all_converged: false,
            completed: false,
            timed_out: false,
            error: None,
            first_failed_step: None,
            first_failure: None,
            max_penetration: 0.0,
            penetration_step: 0,
            unforced: false,
            energy_scale: 0.0,
            energy_rise: 0.0,
            energy_rise_outside_openings: 0.0,
            energy_step_gains: 0.0,
            opening_steps: 0,
            opening_energy: 0.0,
            opening_max_gain: 0.0,
            wall_s: 0.0,
            step_us_median: 0.0,
        }
    }

    /// The unforced run gained energy outside the opening steps.
    pub fn gains_energy(&self) -> bool {
        self.unforced && self.energy_rise_outside_openings > ENERGY_LIMIT
    }

    /// The run penetrated more than [`PENETRATION_LIMIT`].
    pub fn penetrates(&self) -> bool {
        self.max_penetration.is_nan() || self.max_penetration > PENETRATION_LIMIT
    }

    /// Every step converged, nothing penetrated, and no unforced energy gain outside openings.
    pub fn passed(&self) -> bool {
        self.all_converged && !self.penetrates() && !self.gains_energy()
    }
}

/// The category of a scene named `<index>_<category>`, or `file`.
pub fn category_of(name: &str) -> String {
    match name.split_once('_') {
        Some((index, rest)) if index.chars().all(|c| c.is_ascii_digit()) => rest.to_string(),
        _ => "file".to_string(),
    }
}

/// Loads the scene file at `path` and runs it with `config` (hull formulation, keep going after
/// failed steps, no plots), then measures the run.
pub fn run_file(path: &Path, config: &RunConfig) -> RunResult {
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("scene")
        .to_string();
    let mut result = RunResult::empty(&stem, &category_of(&stem), &config.solver);
    let file = match load_scene(path) {
        Ok(f) => f,
        Err(e) => {
            result.error = Some(format!("the scene does not load: {e}"));
            return result;
        }
    };
    result.scene = file.scene.name.clone();
    result.category = category_of(&file.scene.name);
    let options = RunOptions {
        out_dir: config.out_dir.clone(),
        solver: Some(config.solver.clone()),
        formulation: Some("hull".into()),
        steps: config.steps,
        plots: false,
        keep_going: true,
        fallbacks: config.fallbacks,
        time_limit: config.time_limit,
        ..RunOptions::default()
    };
    let start = Instant::now();
    let outcome = run_scene(&file, &options, |_| {});
    result.wall_s = start.elapsed().as_secs_f64();
    let outcome = match outcome {
        Ok(o) => o,
        Err(e) => {
            result.error = Some(format!("the run did not start: {e}"));
            return result;
        }
    };
    result.planned_steps = outcome.summary.planned_steps;
    result.steps = outcome.records.len();
    result.failed_steps = outcome.summary.failed_steps;
    result.timed_out = outcome.timed_out;
    result.error = outcome.stepper_error.clone();
    result.completed = result.steps == result.planned_steps && result.error.is_none();
    if result.steps > 0 && outcome.summary.step_us.median.is_finite() {
        result.step_us_median = outcome.summary.step_us.median;
    }
    result.all_converged = result.completed && result.failed_steps == 0 && !result.timed_out;
    if let Some(f) = &outcome.summary.failure {
        result.first_failed_step = Some(f.step);
        result.first_failure = Some(f.reason.clone());
    }
    measure(&file.scene, &outcome.records, &mut result);
    result
}

/// The penetration into the half-spaces and the energy audit of a run's records (the fields
/// of [`RunResult`] from `max_penetration` to `opening_max_gain`; the others are left empty),
/// for runs made outside [`run_file`] (the `bodies` scenes' tests, `tests/user_scenes.rs`).
pub fn measure_records(scene: &Scene, records: &[StepRecord]) -> RunResult {
    let mut result = RunResult::empty(&scene.name, "file", "");
    measure(scene, records, &mut result);
    result
}

/// Penetration and energy of a run's records (fills the corresponding fields of `result`).
fn measure(scene: &Scene, records: &[StepRecord], result: &mut RunResult) {
    let initial: Vec<BodyState> = scene.bodies.iter().map(|b| b.initial).collect();
    result.unforced = scene.bodies.iter().all(|b| matches!(b.load, Load::None));
    result.energy_scale = energy_scale(scene);
    let (mut worst, mut worst_step) = (0.0_f64, 0);
    let mut gaps = Vec::with_capacity(records.len());
    for r in records {
        let g = gaps_of(scene, &r.bodies);
        let pen = g
            .iter()
            .flatten()
            .map(|&x| if x.is_nan() { f64::INFINITY } else { -x })
            .fold(0.0_f64, f64::max);
        if pen > worst {
            worst = pen;
            worst_step = r.step;
        }
        gaps.push(g);
    }
    result.max_penetration = worst;
    result.penetration_step = worst_step;
    if !result.unforced || records.is_empty() {
        return;
    }
    // Energies from the recorded states, E_0 from the initial one.
    let scale = result.energy_scale;
    let e0 = total_energy(scene, &initial);
    let energies: Vec<f64> = records
        .iter()
        .map(|r| total_energy(scene, &r.bodies))
        .collect();
    let opening = opening_steps(scene, records, &gaps);
    let (mut rise, mut rise_out, mut cum_out, mut gains) = (0.0_f64, 0.0_f64, 0.0_f64, 0.0_f64);
    let (mut open_sum, mut open_max) = (0.0_f64, 0.0_f64);
    let mut prev = e0;
    for (k, e) in energies.iter().enumerate() {
        let de = e - prev;
        prev = *e;
        rise = rise.max(e - e0);
        if opening[k] {
            open_sum += de;
            open_max = open_max.max(de);
        } else {
            cum_out += de;
            gains += de.max(0.0);
            rise_out = rise_out.max(cum_out);
        }
    }
    let rel = |x: f64| {
        if x.is_finite() {
            x / scale
        } else {
            f64::INFINITY
        }
    };
    result.energy_rise = rel(rise);
    result.energy_rise_outside_openings = rel(rise_out);
    result.energy_step_gains = rel(gains);
    result.opening_steps = opening.iter().filter(|&&o| o).count();
    result.opening_energy = rel(open_sum);
    result.opening_max_gain = rel(open_max);
}

/// Which steps are opening steps: step `k` carried `p_n > 0` at a contact that is open at the end
/// of step `k + 1` with `p_n = 0` there; both `k` and `k + 1` are marked. The contacts are the
/// per-body, per-half-space records and, with the `bodies` formulation, the contact pairs
/// (`StepRecord::pairs`, by the two names): a pair that has no contact set at step `k + 1` is
/// beyond the reach of the step, so open.
fn opening_steps(scene: &Scene, records: &[StepRecord], gaps: &[Vec<Vec<f64>>]) -> Vec<bool> {
    let planes = scene.planes.len();
    let bodies = scene.bodies.len();
    let floor: Vec<f64> = scene
        .bodies
        .iter()
        .map(|b| PN_FLOOR * b.mass.mass * scene.gravity.norm() * scene.h)
        .collect();
    let mut marks = vec![false; records.len()];
    for k in 0..records.len().saturating_sub(1) {
        let (now, next) = (&records[k], &records[k + 1]);
        let per_body = now.contacts.len() / bodies.max(1);
        for (j, (c, d)) in now.contacts.iter().zip(&next.contacts).enumerate() {
            let b = j.checked_div(per_body).unwrap_or(0);
            let floor = floor.get(b).copied().unwrap_or(0.0);
            // With one contact per (body, half-space) the gap is ours; else the record's.
            let gap_next = if per_body == planes {
                gaps[k + 1][b][j % planes]
            } else {
                d.min_gap
            };
            if c.pn > floor && d.pn <= floor && gap_next > OPEN_GAP {
                marks[k] = true;
                marks[k + 1] = true;
            }
        }
        for c in &now.pairs {
            let floor = scene
                .bodies
                .iter()
                .position(|b| b.name == c.body_a)
                .map_or(0.0, |b| floor[b]);
            if c.pn <= floor {
                continue;
            }
            let opens =
                match (next.pairs.iter()).find(|d| d.body_a == c.body_a && d.body_b == c.body_b) {
                    None => true,
                    Some(d) => d.pn <= floor && d.gap > OPEN_GAP,
                };
            if opens {
                marks[k] = true;
                marks[k + 1] = true;
            }
        }
    }
    marks
}

/// The smallest gap of every body to every half-space, `[body][plane]`, over the vertices of
/// every piece of the real body at `states` (NaN when a pose is not finite).
pub fn gaps_of(scene: &Scene, states: &[BodyState]) -> Vec<Vec<f64>> {
    scene
        .bodies
        .iter()
        .zip(states)
        .map(|(spec, s)| {
            let finite = s.x.iter().chain(s.q.iter()).all(|c| c.is_finite()) && s.q.norm() > 0.0;
            let r = quat_to_matrix(&s.q);
            let world: Vec<Vector3<f64>> = spec
                .shape
                .pieces()
                .iter()
                .flat_map(|p| p.vertices())
                .map(|v| s.x + r * v)
                .collect();
            scene
                .planes
                .iter()
                .map(|plane| {
                    if !finite {
                        return f64::NAN;
                    }
                    let n = plane.normal();
                    world
                        .iter()
                        .map(|w| n.dot(w) - plane.offset())
                        .fold(f64::INFINITY, f64::min)
                })
                .collect()
        })
        .collect()
}

/// The largest penetration `max(0, −gap)` of any vertex of any body at `states` (m).
pub fn penetration(scene: &Scene, states: &[BodyState]) -> f64 {
    gaps_of(scene, states)
        .iter()
        .flatten()
        .map(|&g| if g.is_nan() { f64::INFINITY } else { -g })
        .fold(0.0, f64::max)
}

/// Kinetic plus gravitational potential energy of all bodies at `states`:
/// `Σ ½ m v² + ½ ωᵀ R I Rᵀ ω − m g·x`.
pub fn total_energy(scene: &Scene, states: &[BodyState]) -> f64 {
    scene
        .bodies
        .iter()
        .zip(states)
        .map(|(b, s)| {
            let r = quat_to_matrix(&s.q);
            let iw = r * b.mass.inertia * r.transpose();
            0.5 * b.mass.mass * s.v.norm_squared() + 0.5 * s.w.dot(&(iw * s.w))
                - b.mass.mass * scene.gravity.dot(&s.x)
        })
        .sum()
}

/// The energy scale of a scene: `Σ_b m_b |g| d_b + E_kin(0)`, with `d_b` the largest distance
/// between two vertices of body `b` (its diameter).
pub fn energy_scale(scene: &Scene) -> f64 {
    let g = scene.gravity.norm();
    scene
        .bodies
        .iter()
        .map(|b| {
            let v = b.shape.vertices();
            let mut d = 0.0_f64;
            for (i, p) in v.iter().enumerate() {
                for q in &v[i + 1..] {
                    d = d.max((p - q).norm());
                }
            }
            let s = &b.initial;
            let r = quat_to_matrix(&s.q);
            let iw = r * b.mass.inertia * r.transpose();
            b.mass.mass * g * d
                + 0.5 * b.mass.mass * s.v.norm_squared()
                + 0.5 * s.w.dot(&(iw * s.w))
        })
        .sum()
}
