//! Parameter fitting with argmin (issue #8, item 4): the trajectory loss of a scene against a
//! reference `trajectory.csv`, exposed as an argmin problem ([`CostFunction`] and [`Gradient`])
//! so that any argmin solver can drive it, and the driver behind `ecp fit` ([`fit`]).
//!
//! The optimisation variables are **log-coordinates relative to the start**: parameter `i` is
//! `θ_i = θ0_i · exp(u_i)`, so `u = 0` is the scene's own values, every parameter stays positive
//! whatever step a solver tries (μ ≥ 0, e_r > 0, masses > 0), and parameters of different units
//! (μ is 0.2, a mass 15 kg) get comparable scales.
//!
//! The loss (the tracking loss of `docs/fitting.md`) compares the simulated body states after
//! each step with the reference rows:
//!
//! `L(θ) = 1/(2N) Σ_{k=1..N} Σ_b [ w_x‖x_k − x̂_k‖² + w_q‖Q_k − Q̂_k‖² + w_v‖v_k − v̂_k‖² + w_ω‖ω_k − ω̂_k‖² ]`
//!
//! with the default weights `w_v = 1 s²/m²`, `w_ω = 1 s²`, `w_x = w_q = 0` (μ and e_r act on
//! the velocities first; positions are their integrals and add nothing for noise-free data).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use argmin::core::{CostFunction, Executor, Gradient, State, TerminationStatus};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::neldermead::NelderMead;
use argmin::solver::quasinewton::LBFGS;
use ecp_formulations::rotation::{kinematic_map, quat_normalize};
use ecp_formulations::stepper::{BodyState, Scene, StepRecord};
use nalgebra::{Vector3, Vector4};
use serde::Serialize;

use crate::backends::{Formulation, SolverConfig, make_solver};
use crate::error::{InputError, InputErrorKind};

/// A scene parameter that can be fitted, named as in scene files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitParam {
    /// Friction coefficient μ (`[friction] mu`, formulation.md §4.4).
    Mu,
    /// Tangential semi-axis e_t of the friction ellipsoid (`[friction] e_t`).
    Et,
    /// Tangential semi-axis e_o (`[friction] e_o`).
    Eo,
    /// Torsional semi-axis e_r, in metres (`[friction] e_r`).
    Er,
    /// Mass of body `b` (`bodies[b].mass`).
    Mass(usize),
    /// Diagonal entry `(axis, axis)` of the body-frame inertia of body `b` (`bodies[b].inertia`).
    Inertia(usize, usize),
}

/// The names `ecp fit --params` accepts (a body suffix `_b<i>` selects a body other than 0).
pub const PARAM_NAMES: [&str; 7] = [
    "mu",
    "e_t",
    "e_o",
    "e_r",
    "mass",
    "inertia_xx",
    "inertia_yy",
];

/// Every accepted name, for error messages (`inertia_zz` included).
fn all_param_names() -> String {
    let mut names: Vec<&str> = PARAM_NAMES.to_vec();
    names.push("inertia_zz");
    names.join(", ")
}

impl FitParam {
    /// Parses a parameter name as written on the command line: `mu`, `e_t`, `e_o`, `e_r`,
    /// `mass`, `inertia_xx`, `inertia_yy`, `inertia_zz`, the body ones optionally suffixed
    /// `_b<i>` (body `i`, default 0). `bodies` is the scene's number of bodies.
    pub fn parse(name: &str, bodies: usize) -> Result<Self, String> {
        let name = name.trim();
        let unknown = || {
            format!(
                "unknown parameter \"{name}\"; the parameters that can be fitted are {} \
                 (mass and inertia take a body suffix _b<i> in scenes with several bodies)",
                all_param_names()
            )
        };
        let (base, body) = match name.rsplit_once("_b") {
            Some((base, idx)) if !idx.is_empty() && idx.bytes().all(|c| c.is_ascii_digit()) => {
                (base, Some(idx.parse::<usize>().map_err(|_| unknown())?))
            }
            _ => (name, None),
        };
        let b = body.unwrap_or(0);
        let p = match base {
            "mu" => FitParam::Mu,
            "e_t" => FitParam::Et,
            "e_o" => FitParam::Eo,
            "e_r" => FitParam::Er,
            "mass" => FitParam::Mass(b),
            "inertia_xx" => FitParam::Inertia(b, 0),
            "inertia_yy" => FitParam::Inertia(b, 1),
            "inertia_zz" => FitParam::Inertia(b, 2),
            _ => return Err(unknown()),
        };
        match p {
            FitParam::Mass(b) | FitParam::Inertia(b, _) if b >= bodies => Err(format!(
                "parameter \"{name}\" names body {b}, but the scene has {bodies} bod{}",
                if bodies == 1 { "y" } else { "ies" }
            )),
            FitParam::Mu | FitParam::Et | FitParam::Eo | FitParam::Er if body.is_some() => {
                Err(format!(
                    "parameter \"{name}\": friction parameters are shared by every contact and \
                     take no body suffix; write \"{base}\""
                ))
            }
            p => Ok(p),
        }
    }

    /// The name used in reports (the inverse of [`FitParam::parse`]; body 0 has no suffix).
    pub fn name(&self) -> String {
        let suffix = |b: usize| {
            if b == 0 {
                String::new()
            } else {
                format!("_b{b}")
            }
        };
        match *self {
            FitParam::Mu => "mu".into(),
            FitParam::Et => "e_t".into(),
            FitParam::Eo => "e_o".into(),
            FitParam::Er => "e_r".into(),
            FitParam::Mass(b) => format!("mass{}", suffix(b)),
            FitParam::Inertia(b, a) => {
                format!("inertia_{}{}", ["xx", "yy", "zz"][a.min(2)], suffix(b))
            }
        }
    }

    /// The parameter's value in `scene`.
    pub fn get(&self, scene: &Scene) -> f64 {
        match *self {
            FitParam::Mu => scene.friction.mu,
            FitParam::Et => scene.friction.e_t,
            FitParam::Eo => scene.friction.e_o,
            FitParam::Er => scene.friction.e_r,
            FitParam::Mass(b) => scene.bodies[b].mass.mass,
            FitParam::Inertia(b, a) => scene.bodies[b].mass.inertia[(a, a)],
        }
    }

    /// Sets the parameter in `scene`.
    pub fn set(&self, scene: &mut Scene, value: f64) {
        match *self {
            FitParam::Mu => scene.friction.mu = value,
            FitParam::Et => scene.friction.e_t = value,
            FitParam::Eo => scene.friction.e_o = value,
            FitParam::Er => scene.friction.e_r = value,
            FitParam::Mass(b) => scene.bodies[b].mass.mass = value,
            FitParam::Inertia(b, a) => scene.bodies[b].mass.inertia[(a, a)] = value,
        }
    }
}

/// Parses a comma-separated list of parameter names (`mu,e_r`); duplicates are refused.
pub fn parse_params(list: &[String], bodies: usize) -> Result<Vec<FitParam>, InputError> {
    let bad = |msg: String| InputError::option("--params", InputErrorKind::UnknownName, msg);
    let mut params: Vec<FitParam> = Vec::new();
    for name in list.iter().flat_map(|s| s.split(',')) {
        if name.trim().is_empty() {
            continue;
        }
        let p = FitParam::parse(name, bodies).map_err(bad)?;
        if params.contains(&p) {
            return Err(bad(format!(
                "parameter \"{}\" is listed twice; name each parameter once",
                p.name()
            )));
        }
        params.push(p);
    }
    if params.is_empty() {
        return Err(bad(format!(
            "no parameter to fit; name at least one, e.g. --params mu,e_r (the parameters are {})",
            all_param_names()
        )));
    }
    Ok(params)
}

/// A reference trajectory: the body states of a `trajectory.csv`, one row per step.
#[derive(Clone, Debug)]
pub struct ReferenceTrajectory {
    /// Where it was read from.
    pub path: PathBuf,
    /// Time of each row (end of step `k`, `k = 1..`).
    pub times: Vec<f64>,
    /// `states[k][b]`: body `b` after step `k + 1`.
    pub states: Vec<Vec<BodyState>>,
}

impl ReferenceTrajectory {
    /// Number of steps (rows).
    pub fn steps(&self) -> usize {
        self.times.len()
    }

    /// The first `steps` rows only (a shorter fit on the same reference).
    pub fn truncated(mut self, steps: usize) -> Self {
        self.times.truncate(steps);
        self.states.truncate(steps);
        self
    }

    /// The reference made from simulated step records (for tests and for fitting to a run
    /// made in the same program).
    pub fn from_records(records: &[StepRecord]) -> Self {
        ReferenceTrajectory {
            path: PathBuf::from("<records>"),
            times: records.iter().map(|r| r.t).collect(),
            states: records.iter().map(|r| r.bodies.clone()).collect(),
        }
    }

    /// Checks the reference against `scene`: at least one row, no more rows than the scene
    /// has steps, row `k` at `t = k h`, and the first row reachable from the scene's initial
    /// state (`x_1 − h v_1 = x_0` and `Q_1 ≈ Q_0 + h/2 E(Q_0) ω_1`, the kinematic map of
    /// formulation.md §4.2, which holds whatever the parameters) — so a reference made from
    /// another scene is refused before anything is fitted.
    pub fn check_against(&self, scene: &Scene) -> Result<(), InputError> {
        let err = |message: String| InputError {
            file: Some(self.path.clone()),
            key: None,
            line: None,
            kind: InputErrorKind::InvalidValue,
            message,
        };
        let n = self.steps();
        if n == 0 {
            return Err(err(
                "the reference has a header but no rows; make it with `ecp run SCENE.toml` \
                 (it writes out/<scene>/trajectory.csv)"
                    .into(),
            ));
        }
        let planned = scene.num_steps();
        if n > planned {
            return Err(err(format!(
                "the reference has {n} rows but the scene '{}' has only {planned} steps \
                 (duration {} s, h = {} s); it was made from another scene, or use a scene with \
                 a longer duration",
                scene.name, scene.duration, scene.h
            )));
        }
        for (k, t) in self.times.iter().enumerate() {
            let want = (k + 1) as f64 * scene.h;
            if (t - want).abs() > 1e-9 * want.max(1.0) {
                return Err(InputError {
                    line: Some(k + 2),
                    ..err(format!(
                        "row {} has t = {t} but step {} of the scene '{}' ends at t = {want} \
                         (h = {} s); the reference must have one row per step from the first, \
                         made with the scene's step length",
                        k + 1,
                        k + 1,
                        scene.name,
                        scene.h
                    ))
                });
            }
        }
        let h = scene.h;
        for (b, spec) in scene.bodies.iter().enumerate() {
            let Some(first) = self.states[0].get(b) else {
                return Err(err(format!(
                    "the reference has {} bod{} but the scene '{}' has {}",
                    self.states[0].len(),
                    if self.states[0].len() == 1 {
                        "y"
                    } else {
                        "ies"
                    },
                    scene.name,
                    scene.bodies.len()
                )));
            };
            let x0 = first.x - first.v * h;
            let q0 = quat_normalize(&spec.initial.q).unwrap_or(spec.initial.q);
            let q1 = q0 + kinematic_map(&q0) * first.w * (0.5 * h);
            let q1 = quat_normalize(&q1).unwrap_or(q1);
            let dq = (q1 - first.q).norm().min((q1 + first.q).norm());
            let dx = (x0 - spec.initial.x).norm();
            if dx > 1e-6 || dq > 1e-6 {
                return Err(err(format!(
                    "the reference does not start from the initial state of body '{}' of scene \
                     '{}': its first row implies the start position [{:.6}, {:.6}, {:.6}] \
                     (x − h v), the scene has [{:.6}, {:.6}, {:.6}] (orientation mismatch \
                     {dq:.2e}); was it made from another scene?",
                    spec.name,
                    scene.name,
                    x0.x,
                    x0.y,
                    x0.z,
                    spec.initial.x.x,
                    spec.initial.x.y,
                    spec.initial.x.z,
                )));
            }
        }
        Ok(())
    }
}

/// Reads the body states of a `trajectory.csv` (interfaces.md) written for a scene with
/// `bodies` bodies: columns `t`, then `x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz` of each body (plain
/// names for one body, else suffixed `_b<i>`; plain names are also accepted with a `_b0` suffix
/// for a single body). Other columns are ignored.
pub fn read_reference(path: &Path, bodies: usize) -> Result<ReferenceTrajectory, InputError> {
    let err = |kind: InputErrorKind, line: Option<usize>, message: String| InputError {
        file: Some(path.to_path_buf()),
        key: None,
        line,
        kind,
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| {
        err(
            InputErrorKind::FileMissing,
            None,
            format!(
                "cannot read the reference trajectory ({e}); make one with `ecp run SCENE.toml`, \
                 which writes out/<scene>/trajectory.csv"
            ),
        )
    })?;
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_reader(text.as_bytes());
    let header: Vec<String> = reader
        .headers()
        .map_err(|e| {
            err(
                InputErrorKind::Syntax,
                Some(1),
                format!("the CSV header does not parse ({e})"),
            )
        })?
        .iter()
        .map(|s| s.trim().to_string())
        .collect();
    let find = |name: &str| header.iter().position(|h| h == name);
    let Some(t_col) = find("t") else {
        return Err(err(
            InputErrorKind::MissingKey,
            Some(1),
            format!(
                "the header has no column \"t\"; a trajectory.csv (interfaces.md) starts with \
                 t,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,... (found: {})",
                header.join(",")
            ),
        ));
    };
    const STATE: [&str; 13] = [
        "x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz",
    ];
    let mut cols: Vec<[usize; 13]> = Vec::with_capacity(bodies);
    for b in 0..bodies {
        let mut idx = [0usize; 13];
        for (i, c) in STATE.iter().enumerate() {
            let suffixed = format!("{c}_b{b}");
            let found = if bodies == 1 {
                find(c).or_else(|| find(&suffixed))
            } else {
                find(&suffixed)
            };
            idx[i] = found.ok_or_else(|| {
                err(
                    InputErrorKind::MissingKey,
                    Some(1),
                    format!(
                        "the header has no column \"{}\" for body {b}; the scene has {bodies} \
                         bod{}, so the reference must have been made from a scene with as many \
                         bodies (found: {})",
                        if bodies == 1 { c.to_string() } else { suffixed },
                        if bodies == 1 { "y" } else { "ies" },
                        header.join(",")
                    ),
                )
            })?;
        }
        cols.push(idx);
    }
    let mut times = Vec::new();
    let mut states = Vec::new();
    for (r, row) in reader.records().enumerate() {
        let line = r + 2;
        let row = row.map_err(|e| {
            err(
                InputErrorKind::Syntax,
                Some(line),
                format!("the row does not parse ({e})"),
            )
        })?;
        let num = |c: usize| -> Result<f64, InputError> {
            let field = row.get(c).unwrap_or("").trim();
            match field.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => Err(err(
                    InputErrorKind::WrongType,
                    Some(line),
                    format!(
                        "column \"{}\" holds \"{field}\", which is not a finite number",
                        header[c]
                    ),
                )),
            }
        };
        times.push(num(t_col)?);
        let mut row_states = Vec::with_capacity(bodies);
        for idx in &cols {
            let v: Vec<f64> = idx.iter().map(|&c| num(c)).collect::<Result<_, _>>()?;
            row_states.push(BodyState {
                x: Vector3::new(v[0], v[1], v[2]),
                q: Vector4::new(v[3], v[4], v[5], v[6]),
                v: Vector3::new(v[7], v[8], v[9]),
                w: Vector3::new(v[10], v[11], v[12]),
            });
        }
        states.push(row_states);
    }
    Ok(ReferenceTrajectory {
        path: path.to_path_buf(),
        times,
        states,
    })
}

/// Weights of the tracking loss (module docs): position (1/m²), orientation quaternion (1),
/// linear velocity (s²/m²) and angular velocity (s²).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TrackingWeights {
    /// `w_x`.
    pub position: f64,
    /// `w_q`.
    pub orientation: f64,
    /// `w_v`.
    pub velocity: f64,
    /// `w_ω`.
    pub angular_velocity: f64,
}

impl Default for TrackingWeights {
    fn default() -> Self {
        TrackingWeights {
            position: 0.0,
            orientation: 0.0,
            velocity: 1.0,
            angular_velocity: 1.0,
        }
    }
}

impl TrackingWeights {
    /// Parses `v=1,w=1,x=0,q=0` (any subset; the others keep their defaults).
    pub fn parse(text: &str) -> Result<Self, InputError> {
        let bad = |msg: String| InputError::option("--weights", InputErrorKind::InvalidValue, msg);
        let mut w = TrackingWeights::default();
        for item in text.split(',').filter(|s| !s.trim().is_empty()) {
            let Some((k, v)) = item.split_once('=') else {
                return Err(bad(format!(
                    "\"{item}\" is not key=value; write e.g. --weights v=1,w=1,x=0,q=0"
                )));
            };
            let value: f64 = match v.trim().parse() {
                Ok(x) if x >= 0.0 && f64::is_finite(x) => x,
                _ => {
                    return Err(bad(format!(
                        "weight {k} = \"{v}\" must be a finite number ≥ 0"
                    )));
                }
            };
            match k.trim() {
                "x" => w.position = value,
                "q" => w.orientation = value,
                "v" => w.velocity = value,
                "w" => w.angular_velocity = value,
                other => {
                    return Err(bad(format!(
                        "unknown weight \"{other}\"; the weights are x (position), q \
                         (orientation), v (velocity) and w (angular velocity)"
                    )));
                }
            }
        }
        if w.position + w.orientation + w.velocity + w.angular_velocity <= 0.0 {
            return Err(bad("every weight is zero; the loss would be 0".into()));
        }
        Ok(w)
    }

    /// The tracking loss of simulated `records` against the reference (module docs).
    pub fn loss(&self, records: &[StepRecord], reference: &ReferenceTrajectory) -> f64 {
        let n = reference.steps().max(1) as f64;
        let mut sum = 0.0;
        for (rec, want) in records.iter().zip(&reference.states) {
            for (s, r) in rec.bodies.iter().zip(want) {
                sum += self.position * (s.x - r.x).norm_squared()
                    + self.orientation * (s.q - r.q).norm_squared()
                    + self.velocity * (s.v - r.v).norm_squared()
                    + self.angular_velocity * (s.w - r.w).norm_squared();
            }
        }
        0.5 * sum / n
    }
}

/// How the gradient of the loss is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GradientMethod {
    /// Central finite differences over re-simulations (2 extra runs per parameter), relative
    /// step 1e-5 in each parameter.
    #[default]
    Fd,
}

impl GradientMethod {
    /// The name used on the command line and in reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            GradientMethod::Fd => "fd",
        }
    }
}

/// Relative step of the central differences (in log-coordinates): balances truncation
/// (∝ δ²) against the solver's residual tolerance 1e-10 (∝ 1/δ).
pub const FD_STEP: f64 = 1e-5;

/// Why a loss evaluation failed.
#[derive(Clone, Debug, thiserror::Error)]
pub enum FitError {
    /// Bad input (scene, reference, parameter names, options).
    #[error(transparent)]
    Input(#[from] InputError),
    /// A step of the simulation did not converge, or could not be set up, at these parameters.
    #[error(
        "step {step} (t = {t:.4} s) of the simulation at {params} failed: {reason}; the optimiser \
         tried parameters where the step solver does not converge — try --solver with another \
         backend, a start closer to the solution, or fewer --steps"
    )]
    StepFailed {
        /// Step index, from 1.
        step: usize,
        /// Time at the end of the step.
        t: f64,
        /// The parameters, `name = value, ...`.
        params: String,
        /// What the solver or the stepper said.
        reason: String,
    },
    /// The optimiser itself failed.
    #[error("the optimiser failed: {0}")]
    Optimiser(String),
}

/// Counters of a [`TrajectoryProblem`], shared with the fitting driver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct EvalCounts {
    /// Calls of [`CostFunction::cost`] that were not answered from the cache.
    pub cost_evals: usize,
    /// Calls of [`Gradient::gradient`] that were not answered from the cache.
    pub gradient_evals: usize,
    /// Simulations of the whole trajectory (including those of finite differences).
    pub simulations: usize,
}

#[derive(Default)]
struct Shared {
    counts: EvalCounts,
    /// Last point evaluated: `(u, loss, gradient)`.
    cache: Option<(Vec<f64>, f64, Option<Vec<f64>>)>,
    /// The last evaluation error (argmin's L-BFGS turns a line-search error into a termination
    /// reason; the driver reads the cause here).
    last_error: Option<FitError>,
}

/// The trajectory loss of a scene against a reference as an argmin problem over the
/// log-coordinates `u` (module docs): `cost(u) = scale · L(θ0 ∘ exp(u))`, and its gradient.
///
/// ```no_run
/// use argmin::core::{CostFunction, Executor, State};
/// use argmin::solver::linesearch::MoreThuenteLineSearch;
/// use argmin::solver::quasinewton::LBFGS;
/// use ecp::fit::{FitParam, ReferenceTrajectory, TrajectoryProblem};
///
/// let file = ecp::scene::load_scene("scenes/desk.toml".as_ref()).unwrap();
/// let reference = ecp::fit::read_reference("out/desk/trajectory.csv".as_ref(), 1).unwrap();
/// let problem = TrajectoryProblem::new(&file, reference, vec![FitParam::Mu, FitParam::Er]).unwrap();
/// let solver = LBFGS::new(MoreThuenteLineSearch::new(), 7);
/// let result = Executor::new(problem, solver)
///     .configure(|s| s.param(vec![0.0, 0.0]).max_iters(50))
///     .run()
///     .unwrap();
/// println!("{:?}", result.state.get_best_param());
/// ```
#[derive(Clone)]
pub struct TrajectoryProblem {
    scene: Scene,
    formulation: Formulation,
    solver: SolverConfig,
    params: Vec<FitParam>,
    start: Vec<f64>,
    reference: ReferenceTrajectory,
    weights: TrackingWeights,
    gradient: GradientMethod,
    scale: f64,
    shared: Arc<Mutex<Shared>>,
}

impl TrajectoryProblem {
    /// The problem of fitting `params` of the scene file's scene (its solver and formulation)
    /// to `reference` (checked against the scene), from the scene's values, default weights and
    /// finite-difference gradients. The scene's duration is cut to the reference's length.
    pub fn new(
        file: &crate::scene::SceneFile,
        reference: ReferenceTrajectory,
        params: Vec<FitParam>,
    ) -> Result<Self, FitError> {
        Self::from_scene(
            file.scene.clone(),
            file.formulation,
            file.solver.clone(),
            reference,
            params,
        )
    }

    /// As [`TrajectoryProblem::new`], from a [`Scene`], a formulation and a solver.
    pub fn from_scene(
        mut scene: Scene,
        formulation: Formulation,
        solver: SolverConfig,
        reference: ReferenceTrajectory,
        params: Vec<FitParam>,
    ) -> Result<Self, FitError> {
        reference.check_against(&scene)?;
        crate::backends::check_combination(solver.kind, formulation)?;
        make_solver(&solver)?;
        scene.duration = reference.steps() as f64 * scene.h;
        let start: Vec<f64> = params.iter().map(|p| p.get(&scene)).collect();
        for (p, v) in params.iter().zip(&start) {
            if !(v.is_finite() && *v > 0.0) {
                return Err(InputError::option(
                    "--params",
                    InputErrorKind::InvalidValue,
                    format!(
                        "parameter {} starts at {v} in the scene; fitting works in \
                         log-coordinates and needs a positive start value (set it in the scene \
                         file, e.g. a small positive μ instead of 0)",
                        p.name()
                    ),
                )
                .into());
            }
        }
        Ok(TrajectoryProblem {
            scene,
            formulation,
            solver,
            params,
            start,
            reference,
            weights: TrackingWeights::default(),
            gradient: GradientMethod::default(),
            scale: 1.0,
            shared: Arc::new(Mutex::new(Shared::default())),
        })
    }

    /// Uses these loss weights.
    pub fn with_weights(mut self, weights: TrackingWeights) -> Self {
        self.weights = weights;
        self.shared().cache = None;
        self
    }

    /// Uses this gradient method.
    pub fn with_gradient(mut self, gradient: GradientMethod) -> Self {
        self.gradient = gradient;
        self.shared().cache = None;
        self
    }

    /// Multiplies the cost (and gradient) argmin sees by `scale` (> 0): the fitting driver
    /// uses it so that the first L-BFGS step, `−scale·∇L`, changes no parameter by more than
    /// 10 % (argmin's L-BFGS starts with the plain gradient as step).
    pub fn with_cost_scale(mut self, scale: f64) -> Self {
        self.scale = scale;
        self
    }

    /// The cost scale argmin sees.
    pub fn cost_scale(&self) -> f64 {
        self.scale
    }

    /// The fitted parameters.
    pub fn params(&self) -> &[FitParam] {
        &self.params
    }

    /// The parameters' start values θ0 (the scene's).
    pub fn start(&self) -> &[f64] {
        &self.start
    }

    /// The parameter values at log-coordinates `u`: `θ0 ∘ exp(u)`.
    pub fn values_at(&self, u: &[f64]) -> Vec<f64> {
        self.start
            .iter()
            .zip(u)
            .map(|(t0, ui)| t0 * ui.exp())
            .collect()
    }

    /// The log-coordinates of parameter values `theta`.
    pub fn coordinates_of(&self, theta: &[f64]) -> Vec<f64> {
        self.start
            .iter()
            .zip(theta)
            .map(|(t0, t)| (t / t0).ln())
            .collect()
    }

    /// Counters so far.
    pub fn counts(&self) -> EvalCounts {
        self.shared().counts
    }

    /// A handle on the counters and the last error that outlives the problem (argmin takes
    /// the problem by value).
    pub fn monitor(&self) -> FitMonitor {
        FitMonitor(Arc::clone(&self.shared))
    }

    fn shared(&self) -> MutexGuard<'_, Shared> {
        // A poisoned lock only means another evaluation panicked; the data are counters.
        self.shared.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn describe(&self, theta: &[f64]) -> String {
        self.params
            .iter()
            .zip(theta)
            .map(|(p, v)| format!("{} = {v}", p.name()))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The scene at parameter values `theta`.
    pub fn scene_at(&self, theta: &[f64]) -> Scene {
        let mut scene = self.scene.clone();
        for (p, v) in self.params.iter().zip(theta) {
            p.set(&mut scene, *v);
        }
        scene
    }

    /// Simulates the reference's steps at parameter values `theta`.
    pub fn simulate(&self, theta: &[f64]) -> Result<Vec<StepRecord>, FitError> {
        self.shared().counts.simulations += 1;
        let scene = self.scene_at(theta);
        let fail = |step: usize, reason: String| FitError::StepFailed {
            step,
            t: step as f64 * scene.h,
            params: self.describe(theta),
            reason,
        };
        let mut stepper = ecp_formulations::build_stepper(scene.clone(), self.formulation)
            .map_err(|e| fail(0, e.to_string()))?;
        let mut solver = make_solver(&self.solver)?;
        let n = self.reference.steps();
        let mut records = Vec::with_capacity(n);
        for k in 1..=n {
            let rec = stepper
                .step(solver.as_mut())
                .map_err(|e| fail(k, e.to_string()))?;
            if !rec.converged {
                return Err(fail(
                    k,
                    format!(
                        "the step solver did not converge (residual {:.3e} after {} iterations)",
                        rec.summary.residual, rec.summary.iterations
                    ),
                ));
            }
            records.push(rec);
        }
        Ok(records)
    }

    /// The (unscaled) loss L at log-coordinates `u`.
    pub fn loss(&self, u: &[f64]) -> Result<f64, FitError> {
        self.check_len(u)?;
        let theta = self.values_at(u);
        let records = self.simulate(&theta)?;
        Ok(self.weights.loss(&records, &self.reference))
    }

    /// The (unscaled) loss and its gradient with respect to `u` (dL/du_i = θ_i dL/dθ_i).
    pub fn loss_and_gradient(&self, u: &[f64]) -> Result<(f64, Vec<f64>), FitError> {
        self.check_len(u)?;
        match self.gradient {
            GradientMethod::Fd => {
                let loss = match self.cached(u, false) {
                    Some((c, _)) => c,
                    None => self.loss(u)?,
                };
                let mut grad = vec![0.0; u.len()];
                for i in 0..u.len() {
                    let mut up = u.to_vec();
                    up[i] += FD_STEP;
                    let mut dn = u.to_vec();
                    dn[i] -= FD_STEP;
                    grad[i] = (self.loss(&up)? - self.loss(&dn)?) / (2.0 * FD_STEP);
                }
                Ok((loss, grad))
            }
        }
    }

    fn check_len(&self, u: &[f64]) -> Result<(), FitError> {
        if u.len() != self.params.len() || u.iter().any(|x| !x.is_finite()) {
            return Err(FitError::Optimiser(format!(
                "the parameter vector has {} entries ({:?}), the problem fits {} finite ones",
                u.len(),
                u,
                self.params.len()
            )));
        }
        Ok(())
    }

    fn record<T>(&self, result: Result<T, FitError>) -> Result<T, argmin::core::Error> {
        result.map_err(|e| {
            self.shared().last_error = Some(e.clone());
            argmin::core::Error::new(e)
        })
    }

    fn cached(&self, u: &[f64], need_gradient: bool) -> Option<(f64, Option<Vec<f64>>)> {
        let shared = self.shared();
        match &shared.cache {
            Some((cu, c, g)) if cu.as_slice() == u && (!need_gradient || g.is_some()) => {
                Some((*c, g.clone()))
            }
            _ => None,
        }
    }
}

impl CostFunction for TrajectoryProblem {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, u: &Self::Param) -> Result<f64, argmin::core::Error> {
        if let Some((c, _)) = self.cached(u, false) {
            return Ok(self.scale * c);
        }
        let c = self.record(self.loss(u))?;
        let mut shared = self.shared();
        shared.counts.cost_evals += 1;
        shared.cache = Some((u.clone(), c, None));
        Ok(self.scale * c)
    }
}

impl Gradient for TrajectoryProblem {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;

    fn gradient(&self, u: &Self::Param) -> Result<Vec<f64>, argmin::core::Error> {
        if let Some((_, Some(g))) = self.cached(u, true) {
            return Ok(g.iter().map(|x| self.scale * x).collect());
        }
        let (c, g) = self.record(self.loss_and_gradient(u))?;
        let mut shared = self.shared();
        shared.counts.gradient_evals += 1;
        shared.cache = Some((u.clone(), c, Some(g.clone())));
        Ok(g.iter().map(|x| self.scale * x).collect())
    }
}

/// Counters and the last evaluation error of a [`TrajectoryProblem`], readable after argmin
/// has consumed the problem.
#[derive(Clone)]
pub struct FitMonitor(Arc<Mutex<Shared>>);

impl FitMonitor {
    fn lock(&self) -> MutexGuard<'_, Shared> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
    /// Counters so far.
    pub fn counts(&self) -> EvalCounts {
        self.lock().counts
    }
    /// The last evaluation error, if any.
    pub fn last_error(&self) -> Option<FitError> {
        self.lock().last_error.clone()
    }
}

/// The optimisation method of `ecp fit`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
pub enum Method {
    /// argmin's L-BFGS (memory 7) with the More–Thuente line search, on the loss gradient.
    #[default]
    #[value(name = "lbfgs")]
    #[serde(rename = "lbfgs")]
    Lbfgs,
    /// argmin's Nelder–Mead simplex (no gradients); initial simplex of ±10 % steps.
    #[value(name = "nelder-mead")]
    #[serde(rename = "nelder-mead")]
    NelderMead,
}

impl Method {
    /// The name used on the command line and in reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            Method::Lbfgs => "lbfgs",
            Method::NelderMead => "nelder-mead",
        }
    }
}

/// Settings of [`fit`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// The optimiser.
    pub method: Method,
    /// Iteration limit of the optimiser.
    pub max_iters: u64,
    /// L-BFGS: stop when the scaled gradient norm is below this (the scaled gradient starts at
    /// norm ≥ 0.1, see [`TrajectoryProblem::with_cost_scale`]); Nelder–Mead: stop when the
    /// standard deviation of the simplex's scaled costs (the start's cost is 1) is below this.
    pub tolerance: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            method: Method::Lbfgs,
            max_iters: 100,
            tolerance: 1e-12,
        }
    }
}

/// The result of [`fit`] (printed as JSON by `ecp fit`).
#[derive(Clone, Debug, Serialize)]
pub struct FitReport {
    /// Fitted values by name.
    pub params: BTreeMap<String, f64>,
    /// Start values by name.
    pub start: BTreeMap<String, f64>,
    /// The loss L at the fitted values (unscaled).
    pub cost: f64,
    /// The loss at the start.
    pub start_cost: f64,
    /// Optimiser iterations.
    pub iterations: u64,
    /// Wall time of the whole fit, seconds.
    pub wall_s: f64,
    /// Euclidean norm of dL/du at the fitted values (log-coordinates; L-BFGS only).
    pub gradient_norm: Option<f64>,
    /// `lbfgs` or `nelder-mead`.
    pub method: Method,
    /// How gradients were computed (`null` for Nelder–Mead).
    pub gradient: Option<GradientMethod>,
    /// Why the optimiser stopped.
    pub termination: String,
    /// Steps in the fitted window.
    pub steps: usize,
    /// Evaluation counters.
    #[serde(flatten)]
    pub counts: EvalCounts,
    /// The evaluation error that ended the optimisation, if one did.
    pub error: Option<String>,
}

/// Fits the problem's parameters from the start values (`u = 0`) with `options.method`.
///
/// L-BFGS: the cost is scaled so that the first step changes no parameter by more than 10 %
/// ([`TrajectoryProblem::with_cost_scale`]); it stops when the scaled gradient norm falls below
/// `options.tolerance`, at `options.max_iters`, or when the line search can make no more
/// progress (the loss is then flat to the solver's precision). Nelder–Mead: the cost is scaled
/// to 1 at the start; initial simplex `u = 0` and `u = 0.1 e_i` (+10.5 % on each parameter).
///
/// An evaluation that fails (a step that does not converge at the trial parameters) ends the
/// optimisation; the report then carries the best point so far and the error in `error`.
pub fn fit(problem: TrajectoryProblem, options: &FitOptions) -> Result<FitReport, FitError> {
    let started = Instant::now();
    let n = problem.params().len();
    let monitor = problem.monitor();
    let u0 = vec![0.0; n];
    let map_err = |e: argmin::core::Error| match e.downcast::<FitError>() {
        Ok(fe) => fe,
        Err(e) => FitError::Optimiser(e.to_string()),
    };
    let (problem, best_u, iterations, termination, start_cost) = match options.method {
        Method::Lbfgs => {
            let (l0, g0) = problem.loss_and_gradient(&u0)?;
            let gmax = g0.iter().fold(0.0f64, |m, g| m.max(g.abs()));
            let scale = if gmax > 0.0 { 0.1 / gmax } else { 1.0 };
            let problem = problem.with_cost_scale(scale);
            // Seed the cache with the evaluation just made (argmin's init asks for it again).
            {
                let mut shared = problem.shared();
                shared.cache = Some((u0.clone(), l0, Some(g0)));
                shared.counts.cost_evals += 1;
                shared.counts.gradient_evals += 1;
            }
            let solver = LBFGS::new(MoreThuenteLineSearch::new(), 7)
                .with_tolerance_grad(options.tolerance)
                .and_then(|s| s.with_tolerance_cost(0.0))
                .map_err(map_err)?;
            let result = Executor::new(problem.clone(), solver)
                .configure(|s| s.param(u0.clone()).max_iters(options.max_iters))
                .run()
                .map_err(map_err)?;
            let state = result.state;
            let best = state.get_best_param().cloned().unwrap_or(u0);
            let term = termination_text(state.get_termination_status());
            (problem, best, state.get_iter(), term, l0)
        }
        Method::NelderMead => {
            let l0 = problem.loss(&u0)?;
            let scale = if l0 > 0.0 { 1.0 / l0 } else { 1.0 };
            let problem = problem.with_cost_scale(scale);
            {
                let mut shared = problem.shared();
                shared.cache = Some((u0.clone(), l0, None));
                shared.counts.cost_evals += 1;
            }
            let mut simplex = vec![u0.clone()];
            for i in 0..n {
                let mut v = u0.clone();
                v[i] = 0.1;
                simplex.push(v);
            }
            let solver = NelderMead::new(simplex)
                .with_sd_tolerance(options.tolerance)
                .map_err(map_err)?;
            let result = Executor::new(problem.clone(), solver)
                .configure(|s| s.max_iters(options.max_iters))
                .run()
                .map_err(map_err)?;
            let state = result.state;
            let best = state.get_best_param().cloned().unwrap_or(u0);
            let term = termination_text(state.get_termination_status());
            (problem, best, state.get_iter(), term, l0)
        }
    };
    let error = monitor.last_error().map(|e| e.to_string());
    // The loss (and, for L-BFGS, the gradient) at the best point: usually cached.
    let (cost, gradient_norm) = match options.method {
        Method::Lbfgs => {
            let g = Gradient::gradient(&problem, &best_u).map_err(map_err)?;
            let c = CostFunction::cost(&problem, &best_u).map_err(map_err)?;
            let s = problem.cost_scale();
            (c / s, Some(g.iter().map(|x| x * x).sum::<f64>().sqrt() / s))
        }
        Method::NelderMead => {
            let c = CostFunction::cost(&problem, &best_u).map_err(map_err)?;
            (c / problem.cost_scale(), None)
        }
    };
    let theta = problem.values_at(&best_u);
    let named = |values: &[f64]| -> BTreeMap<String, f64> {
        problem
            .params()
            .iter()
            .zip(values)
            .map(|(p, v)| (p.name(), *v))
            .collect()
    };
    Ok(FitReport {
        params: named(&theta),
        start: named(problem.start()),
        cost,
        start_cost,
        iterations,
        wall_s: started.elapsed().as_secs_f64(),
        gradient_norm,
        method: options.method,
        gradient: (options.method == Method::Lbfgs).then_some(problem.gradient),
        termination,
        steps: problem.reference.steps(),
        counts: monitor.counts(),
        error,
    })
}

fn termination_text(status: &TerminationStatus) -> String {
    match status {
        TerminationStatus::Terminated(reason) => reason.to_string(),
        TerminationStatus::NotTerminated => "not terminated".into(),
    }
}
