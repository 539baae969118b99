//! Parameter fitting with argmin (`docs/fitting.md`): the trajectory loss of a scene against a
//! reference `trajectory.csv`, exposed as an argmin problem ([`CostFunction`] and [`Gradient`])
//! so that any argmin solver can drive it, and the driver behind `ecp fit` ([`fit`]).
//!
//! The parameters are the [`Param`]s of the sensitivities (`mu`, `e_t`, `e_o`, `e_r`, `mass`,
//! `i_xx`, ..., named as in scene files), and the gradient is the adjoint trajectory gradient of
//! [`ecp_formulations::sensitivity`] (or central finite differences, `--gradient fd`).
//!
//! The optimisation variables are **coordinates relative to the start**. A parameter that must
//! be positive (μ, e_t, e_o, e_r, a mass, a diagonal inertia entry) is `θ_i = θ0_i · exp(u_i)`:
//! it stays positive whatever step a solver tries, and parameters of different units (μ is 0.2,
//! a mass 15 kg) get comparable scales. Any other parameter (an off-diagonal inertia entry, an
//! initial state, a constant load) is `θ_i = θ0_i + s_i u_i` with `s_i = |θ0_i|`, or 1 when
//! `θ0_i = 0`. So `u = 0` is the scene's own values.
//!
//! The loss is the [`ReferenceLoss`] of the sensitivities: a sum over the fitted steps and the
//! bodies of weighted squared differences to the reference states,
//!
//! `L(θ) = Σ_{k=1..N} Σ_b [ w_x‖x_k − x̂_k‖² + w_q(1 − (Q_k·Q̂_k)²) + w_ψ(ψ_k − ψ̂_k)² + w_v‖v_k − v̂_k‖² + w_ω‖ω_k − ω̂_k‖² ]`
//!
//! with the default weights of `ecp fit`, `w_v = 1 s²/m²` and `w_ω = 1 s²` (the others 0): μ and
//! e_r act on the velocities first, and positions, their integrals, add nothing for noise-free
//! data ([`default_weights`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use argmin::core::{CostFunction, Executor, Gradient, State, TerminationStatus};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::neldermead::NelderMead;
use argmin::solver::quasinewton::LBFGS;
use ecp_formulations::rotation::{kinematic_map, quat_normalize};
use ecp_formulations::sensitivity::{
    GradientMode, GradientOptions, ModeEvent, Param, ReferenceLoss, ReferenceWeights, STATE_SIZE,
    TrajectoryLoss, trajectory_gradient_with,
};
use ecp_formulations::stepper::{BodyState, Scene, StepRecord};
use nalgebra::{Vector3, Vector4};
use serde::Serialize;

use ecp_solvers::Registry;

use crate::backends::{Formulation, SolverConfig, make_solver_in};
use crate::error::{InputError, InputErrorKind};

/// Parses a comma-separated list of parameter names (`mu,e_r`, `mass[1]`; [`Param`]'s names)
/// and checks each against `scene` (body index, a load that is a function of time);
/// duplicates are refused.
pub fn parse_params(list: &[String], scene: &Scene) -> Result<Vec<Param>, InputError> {
    let bad = |msg: String| InputError::option("--params", InputErrorKind::UnknownName, msg);
    let mut params: Vec<Param> = Vec::new();
    for name in list.iter().flat_map(|s| s.split(',')) {
        if name.trim().is_empty() {
            continue;
        }
        let p: Param = name.parse().map_err(|e| bad(format!("{e}")))?;
        p.get(scene).map_err(|e| bad(format!("{e}")))?;
        if params.contains(&p) {
            return Err(bad(format!(
                "parameter \"{p}\" is listed twice; name each parameter once"
            )));
        }
        params.push(p);
    }
    if params.is_empty() {
        return Err(bad(
            "no parameter to fit; name at least one, e.g. --params mu,e_r (the parameters are \
             mu, e_t, e_o, e_r, mass, i_xx, i_yy, i_zz, ...)"
                .into(),
        ));
    }
    Ok(params)
}

/// Overrides parameter values of `scene` from `name=value` pairs (`mu=0.286,e_r=0.07`): the
/// start of a fit other than the scene file's values (`ecp fit --start`).
pub fn apply_start(scene: &mut Scene, text: &str) -> Result<(), InputError> {
    let bad = |msg: String| InputError::option("--start", InputErrorKind::InvalidValue, msg);
    for item in text.split(',').filter(|s| !s.trim().is_empty()) {
        let Some((name, value)) = item.split_once('=') else {
            return Err(bad(format!(
                "\"{item}\" is not name=value; write e.g. --start mu=0.286,e_r=0.07"
            )));
        };
        let p: Param = name.parse().map_err(|e| bad(format!("{e}")))?;
        let v: f64 = value.trim().parse().map_err(|_| {
            bad(format!(
                "the value of {p}, \"{}\", is not a number",
                value.trim()
            ))
        })?;
        p.set(scene, v).map_err(|e| bad(e.to_string()))?;
    }
    Ok(())
}

/// How a parameter maps to its optimisation coordinate (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Coordinate {
    /// `θ = θ0 · exp(u)`: parameters that must stay positive.
    Log,
    /// `θ = θ0 + scale · u`.
    Linear {
        /// `|θ0|`, or 1 when `θ0 = 0`.
        scale: f64,
    },
}

impl Coordinate {
    /// The coordinate of parameter `p` starting at `start`.
    pub fn of(p: &Param, start: f64) -> Self {
        let positive = match p {
            Param::Mu | Param::Et | Param::Eo | Param::Er | Param::Mass { .. } => true,
            Param::Inertia { entry, .. } => {
                let (i, j) = entry.position();
                i == j
            }
            _ => false,
        };
        if positive {
            Coordinate::Log
        } else {
            Coordinate::Linear {
                scale: if start != 0.0 { start.abs() } else { 1.0 },
            }
        }
    }

    /// `θ(u)`.
    pub fn value(&self, start: f64, u: f64) -> f64 {
        match *self {
            Coordinate::Log => start * u.exp(),
            Coordinate::Linear { scale } => start + scale * u,
        }
    }

    /// `u(θ)`.
    pub fn coordinate(&self, start: f64, value: f64) -> f64 {
        match *self {
            Coordinate::Log => (value / start).ln(),
            Coordinate::Linear { scale } => (value - start) / scale,
        }
    }

    /// `dθ/du` at `u`.
    pub fn derivative(&self, start: f64, u: f64) -> f64 {
        match *self {
            Coordinate::Log => start * u.exp(),
            Coordinate::Linear { scale } => scale,
        }
    }
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

    /// Checks the reference against `scene`: at least one row, no more rows than the scene has
    /// steps, row `k` at `t = k h`, and the first row reachable from the scene's initial state
    /// (`x_1 − h v_1 = x_0` and `Q_1 ≈ Q_0 + h/2 E(Q_0) ω_1`, the kinematic map of
    /// `docs/model.md#kinematic-map`, which holds whatever the parameters) — so a reference made
    /// from another scene is refused before anything is fitted.
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

/// Reads the body states of a `trajectory.csv` (`docs/outputs.md`) written for a scene with
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
                "the header has no column \"t\"; a trajectory.csv (docs/outputs.md) starts with \
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

/// The loss weights of `ecp fit`: `w_v = 1` (s²/m²) and `w_ω = 1` (s²), the others 0.
pub fn default_weights() -> ReferenceWeights {
    ReferenceWeights {
        position: 0.0,
        orientation: 0.0,
        yaw: 0.0,
        velocity: 1.0,
        angular_velocity: 1.0,
    }
}

/// Parses loss weights `v=1,w=1,x=0,q=0,yaw=0` (velocity, angular velocity, position,
/// orientation, yaw; any subset, the others keep [`default_weights`]).
pub fn parse_weights(text: &str) -> Result<ReferenceWeights, InputError> {
    let bad = |msg: String| InputError::option("--weights", InputErrorKind::InvalidValue, msg);
    let mut w = default_weights();
    for item in text.split(',').filter(|s| !s.trim().is_empty()) {
        let Some((k, v)) = item.split_once('=') else {
            return Err(bad(format!(
                "\"{item}\" is not key=value; write e.g. --weights v=1,w=1,x=0"
            )));
        };
        let value: f64 = match v.trim().parse() {
            Ok(x) if x >= 0.0 && f64::is_finite(x) => x,
            _ => {
                return Err(bad(format!(
                    "weight {} = \"{}\" must be a finite number ≥ 0",
                    k.trim(),
                    v.trim()
                )));
            }
        };
        match k.trim() {
            "x" => w.position = value,
            "q" => w.orientation = value,
            "yaw" => w.yaw = value,
            "v" => w.velocity = value,
            "w" => w.angular_velocity = value,
            other => {
                return Err(bad(format!(
                    "unknown weight \"{other}\"; the weights are x (position), q \
                     (orientation), yaw, v (velocity) and w (angular velocity)"
                )));
            }
        }
    }
    if w.position + w.orientation + w.yaw + w.velocity + w.angular_velocity <= 0.0 {
        return Err(bad(
            "every weight is zero, so the loss would be 0; give one > 0".into(),
        ));
    }
    Ok(w)
}

/// How the gradient of the loss is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GradientMethod {
    /// The adjoint trajectory gradient (one backward sweep over the step sensitivities;
    /// hull and union formulations).
    #[default]
    Adjoint,
    /// The forward trajectory gradient (tangents carried along; same numbers as the adjoint).
    Forward,
    /// Central finite differences over re-simulations (2 extra runs per parameter), step
    /// [`FD_STEP`] in the coordinates `u`.
    Fd,
}

impl GradientMethod {
    /// The name used on the command line and in reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            GradientMethod::Adjoint => "adjoint",
            GradientMethod::Forward => "forward",
            GradientMethod::Fd => "fd",
        }
    }
}

/// Step of the central differences in the coordinates `u` (a relative step of 1e-5 for the
/// log-coordinates): balances truncation (∝ δ²) against the step solver's residual (∝ 1/δ).
pub const FD_STEP: f64 = 1e-5;

/// Why a loss evaluation failed.
#[derive(Clone, Debug, thiserror::Error)]
pub enum FitError {
    /// Bad input (scene, reference, parameter names, options).
    #[error(transparent)]
    Input(#[from] InputError),
    /// A step of the simulation did not converge, or could not be set up or differentiated, at
    /// these parameters.
    #[error(
        "the simulation at {params} failed: {reason} (if these parameters are far from the \
         start, the optimiser went there: try a start closer to the solution or fewer --steps)"
    )]
    Simulation {
        /// The parameters, `name = value, ...`.
        params: String,
        /// What the solver, the stepper or the sensitivities said.
        reason: String,
    },
    /// The optimiser itself failed.
    #[error("the optimiser failed: {0}")]
    Optimiser(String),
}

/// Counters of a [`TrajectoryProblem`], shared with the fitting driver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct EvalCounts {
    /// Loss evaluations (calls of [`CostFunction::cost`] not answered from the cache).
    pub cost_evals: usize,
    /// Gradient evaluations (calls of [`Gradient::gradient`] not answered from the cache).
    pub gradient_evals: usize,
    /// Simulations of the whole window, those of finite differences and of the analytic
    /// gradients included.
    pub simulations: usize,
}

#[derive(Default)]
struct Shared {
    counts: EvalCounts,
    /// Last point evaluated: `(u, loss, dL/du)`.
    cache: Option<(Vec<f64>, f64, Option<Vec<f64>>)>,
    /// Mode switches and degeneracies of the last analytic gradient.
    events: Vec<ModeEvent>,
    /// Whether a solver asked for a gradient (then the cost comes with one, see
    /// [`TrajectoryProblem::cost`](CostFunction::cost)).
    gradient_asked: bool,
    /// The last evaluation error (argmin's L-BFGS turns an error inside its line search into a
    /// termination reason; the driver reads the cause here).
    last_error: Option<FitError>,
}

/// The trajectory loss of a scene against a reference as an argmin problem over the
/// coordinates `u` (module docs): `cost(u) = scale · L(θ(u))` and its gradient
/// `scale · dL/du`, with `Param = Vec<f64>`.
///
/// ```no_run
/// use argmin::core::{Executor, State};
/// use argmin::solver::linesearch::MoreThuenteLineSearch;
/// use argmin::solver::quasinewton::LBFGS;
/// use ecp::fit::{TrajectoryProblem, read_reference};
/// use ecp_formulations::sensitivity::Param;
///
/// let file = ecp::scene::load_scene("scenes/desk.toml".as_ref()).unwrap();
/// let reference = read_reference("out/desk/trajectory.csv".as_ref(), 1).unwrap();
/// let problem = TrajectoryProblem::new(&file, reference, vec![Param::Mu, Param::Er]).unwrap();
/// let solver = LBFGS::new(MoreThuenteLineSearch::new(), 7);
/// let result = Executor::new(problem.clone(), solver)
///     .configure(|s| s.param(vec![0.0, 0.0]).max_iters(50))
///     .run()
///     .unwrap();
/// let u = result.state.get_best_param().unwrap();
/// println!("mu, e_r = {:?}", problem.values_at(u));
/// ```
#[derive(Clone)]
pub struct TrajectoryProblem {
    scene: Scene,
    formulation: Formulation,
    solver: SolverConfig,
    registry: Arc<Registry>,
    params: Vec<Param>,
    coordinates: Vec<Coordinate>,
    start: Vec<f64>,
    reference: ReferenceTrajectory,
    loss: ReferenceLoss,
    gradient: GradientMethod,
    scale: f64,
    shared: Arc<Mutex<Shared>>,
}

impl TrajectoryProblem {
    /// The problem of fitting `params` of the scene file's scene (its solver and formulation)
    /// to `reference` (checked against the scene), from the scene's values, with
    /// [`default_weights`] and adjoint gradients. The scene's duration is cut to the
    /// reference's length.
    pub fn new(
        file: &crate::scene::SceneFile,
        reference: ReferenceTrajectory,
        params: Vec<Param>,
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
        params: Vec<Param>,
    ) -> Result<Self, FitError> {
        reference.check_against(&scene)?;
        let registry = Arc::new(Registry::builtin());
        make_solver_in(&registry, &solver, formulation)?;
        scene.duration = reference.steps() as f64 * scene.h;
        let mut start = Vec::with_capacity(params.len());
        let mut coordinates = Vec::with_capacity(params.len());
        for p in &params {
            let bad = |message: String| {
                InputError::option("--params", InputErrorKind::InvalidValue, message)
            };
            let v = p.get(&scene).map_err(|e| bad(e.to_string()))?;
            let c = Coordinate::of(p, v);
            if c == Coordinate::Log && !(v.is_finite() && v > 0.0) {
                return Err(bad(format!(
                    "parameter {p} starts at {v} in the scene; it is fitted in log-coordinates \
                     (so that it stays positive) and needs a positive start value: set one in \
                     the scene file, e.g. a small positive μ instead of 0"
                ))
                .into());
            }
            start.push(v);
            coordinates.push(c);
        }
        let loss = ReferenceLoss::new(reference.states.clone(), default_weights());
        Ok(TrajectoryProblem {
            scene,
            formulation,
            solver,
            registry,
            params,
            coordinates,
            start,
            reference,
            loss,
            gradient: GradientMethod::default(),
            scale: 1.0,
            shared: Arc::new(Mutex::new(Shared::default())),
        })
    }

    /// The one-step problem (the step loss): fit `params` so that one step of `scene` from the
    /// body states `start` ends at `target` (the states one step `h` later, e.g. two
    /// consecutive rows of a measured trajectory).
    pub fn for_step(
        mut scene: Scene,
        formulation: Formulation,
        solver: SolverConfig,
        start: &[BodyState],
        target: &[BodyState],
        params: Vec<Param>,
    ) -> Result<Self, FitError> {
        if start.len() != scene.bodies.len() || target.len() != scene.bodies.len() {
            return Err(FitError::Optimiser(format!(
                "the step problem needs one start and one target state per body: the scene has \
                 {} bodies, {} start and {} target states were given",
                scene.bodies.len(),
                start.len(),
                target.len()
            )));
        }
        for (body, s) in scene.bodies.iter_mut().zip(start) {
            body.initial = *s;
        }
        scene.duration = scene.h;
        let reference = ReferenceTrajectory {
            path: PathBuf::from("<step target>"),
            times: vec![scene.h],
            states: vec![target.to_vec()],
        };
        Self::from_scene(scene, formulation, solver, reference, params)
    }

    /// Takes the solver (the scene's `[solver] name`) from `registry`, which may hold a user's
    /// own backends, instead of [`Registry::builtin`].
    pub fn with_registry(mut self, registry: Arc<Registry>) -> Result<Self, FitError> {
        make_solver_in(&registry, &self.solver, self.formulation)?;
        self.registry = registry;
        Ok(self)
    }

    /// Uses these loss weights.
    pub fn with_weights(mut self, weights: ReferenceWeights) -> Self {
        self.loss.weights = weights;
        self.shared().cache = None;
        self
    }

    /// Uses this gradient method; the analytic ones need the hull or union formulation (the
    /// step sensitivities differentiate the ECP step).
    pub fn with_gradient(mut self, gradient: GradientMethod) -> Result<Self, FitError> {
        if gradient != GradientMethod::Fd && !self.formulation.has_step_structure() {
            return Err(InputError::option(
                "--gradient",
                InputErrorKind::UnknownName,
                format!(
                    "the {} gradient differentiates the ECP step, which the {} formulation does \
                     not build; use --gradient fd, or --formulation hull or union",
                    gradient.as_str(),
                    self.formulation
                ),
            )
            .into());
        }
        self.gradient = gradient;
        self.shared().cache = None;
        Ok(self)
    }

    /// Multiplies the cost (and gradient) argmin sees by `scale` (> 0): the fitting driver
    /// uses it so that the first L-BFGS step, `−scale·∇L`, moves no coordinate by more than
    /// 0.1 (argmin's L-BFGS takes the plain gradient as its first direction, step 1).
    pub fn with_cost_scale(mut self, scale: f64) -> Self {
        self.scale = scale;
        self
    }

    /// The cost scale argmin sees.
    pub fn cost_scale(&self) -> f64 {
        self.scale
    }

    /// The fitted parameters.
    pub fn params(&self) -> &[Param] {
        &self.params
    }

    /// Their coordinates.
    pub fn coordinates(&self) -> &[Coordinate] {
        &self.coordinates
    }

    /// The parameters' start values θ0 (the scene's).
    pub fn start(&self) -> &[f64] {
        &self.start
    }

    /// The gradient method.
    pub fn gradient_method(&self) -> GradientMethod {
        self.gradient
    }

    /// Steps in the fitted window.
    pub fn steps(&self) -> usize {
        self.reference.steps()
    }

    /// The parameter values at coordinates `u`.
    pub fn values_at(&self, u: &[f64]) -> Vec<f64> {
        (0..self.start.len())
            .map(|i| self.coordinates[i].value(self.start[i], u[i]))
            .collect()
    }

    /// The coordinates of parameter values `theta`.
    pub fn coordinates_of(&self, theta: &[f64]) -> Vec<f64> {
        (0..self.start.len())
            .map(|i| self.coordinates[i].coordinate(self.start[i], theta[i]))
            .collect()
    }

    /// Counters so far.
    pub fn counts(&self) -> EvalCounts {
        self.shared().counts
    }

    /// Mode switches and degeneracies reported by the last analytic gradient.
    pub fn mode_events(&self) -> Vec<ModeEvent> {
        self.shared().events.clone()
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
            .map(|(p, v)| format!("{p} = {v}"))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The scene at parameter values `theta`.
    pub fn scene_at(&self, theta: &[f64]) -> Result<Scene, FitError> {
        let mut scene = self.scene.clone();
        for (p, v) in self.params.iter().zip(theta) {
            p.set(&mut scene, *v).map_err(|e| FitError::Simulation {
                params: self.describe(theta),
                reason: e.to_string(),
            })?;
        }
        Ok(scene)
    }

    /// Simulates the window at parameter values `theta` (any formulation).
    pub fn simulate(&self, theta: &[f64]) -> Result<Vec<StepRecord>, FitError> {
        self.shared().counts.simulations += 1;
        let scene = self.scene_at(theta)?;
        let fail = |step: usize, reason: String| FitError::Simulation {
            params: self.describe(theta),
            reason: format!("step {step} (t = {:.4} s): {reason}", step as f64 * scene.h),
        };
        let mut stepper = ecp_formulations::build_stepper(scene.clone(), self.formulation)
            .map_err(|e| fail(0, e.to_string()))?;
        let mut solver = make_solver_in(&self.registry, &self.solver, self.formulation)?;
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

    /// The loss of simulated `records`.
    pub fn loss_of(&self, records: &[StepRecord]) -> f64 {
        let n = records.len();
        let mut scratch = vec![0.0; STATE_SIZE * self.scene.bodies.len()];
        records
            .iter()
            .map(|r| self.loss.step_term(r, n, &mut scratch))
            .sum()
    }

    /// The (unscaled) loss L at coordinates `u`.
    pub fn loss(&self, u: &[f64]) -> Result<f64, FitError> {
        self.check_len(u)?;
        let records = self.simulate(&self.values_at(u))?;
        Ok(self.loss_of(&records))
    }

    /// The (unscaled) loss and its gradient with respect to `u`
    /// (`dL/du_i = dL/dθ_i · dθ_i/du_i`).
    pub fn loss_and_gradient(&self, u: &[f64]) -> Result<(f64, Vec<f64>), FitError> {
        self.check_len(u)?;
        let theta = self.values_at(u);
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
            GradientMethod::Adjoint | GradientMethod::Forward => {
                self.shared().counts.simulations += 1;
                let scene = self.scene_at(&theta)?;
                let mut solver = make_solver_in(&self.registry, &self.solver, self.formulation)?;
                let options = GradientOptions {
                    mode: if self.gradient == GradientMethod::Forward {
                        GradientMode::Forward
                    } else {
                        GradientMode::Adjoint
                    },
                    formulation: self.formulation,
                    ..GradientOptions::default()
                };
                let g = trajectory_gradient_with(
                    &scene,
                    &self.params,
                    &self.loss,
                    solver.as_mut(),
                    &options,
                )
                .map_err(|e| FitError::Simulation {
                    params: self.describe(&theta),
                    reason: e.to_string(),
                })?;
                self.shared().events = g.events;
                let grad = (0..u.len())
                    .map(|i| g.gradient[i] * self.coordinates[i].derivative(self.start[i], u[i]))
                    .collect();
                Ok((g.loss, grad))
            }
        }
    }

    fn check_len(&self, u: &[f64]) -> Result<(), FitError> {
        if u.len() != self.params.len() || u.iter().any(|x| !x.is_finite()) {
            return Err(FitError::Optimiser(format!(
                "the coordinate vector {u:?} should have {} finite entries, one per parameter",
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
        match &self.shared().cache {
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

    /// `scale · L(θ(u))`. Once the solver has asked for a gradient (it is gradient-based), and
    /// with an analytic gradient method, the gradient is computed and cached with the loss: it
    /// costs little more than the simulation, and line searches ask for both at each trial
    /// point. A derivative-free solver only pays for simulations.
    fn cost(&self, u: &Self::Param) -> Result<f64, argmin::core::Error> {
        if let Some((c, _)) = self.cached(u, false) {
            return Ok(self.scale * c);
        }
        let eager = self.gradient != GradientMethod::Fd && self.shared().gradient_asked;
        let (c, g) = if !eager {
            (self.record(self.loss(u))?, None)
        } else {
            let (c, g) = self.record(self.loss_and_gradient(u))?;
            self.shared().counts.gradient_evals += 1;
            (c, Some(g))
        };
        let mut shared = self.shared();
        shared.counts.cost_evals += 1;
        shared.cache = Some((u.clone(), c, g));
        Ok(self.scale * c)
    }
}

impl Gradient for TrajectoryProblem {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;

    /// `scale · dL/du`.
    fn gradient(&self, u: &Self::Param) -> Result<Vec<f64>, argmin::core::Error> {
        self.shared().gradient_asked = true;
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

/// Counters, mode events and the last evaluation error of a [`TrajectoryProblem`], readable
/// after argmin has consumed the problem.
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
    /// Euclidean norm of dL/du at the fitted values (the coordinates of the module docs),
    /// from the adjoint gradient where the formulation has one, else from the problem's method
    /// (absent for Nelder–Mead on a formulation without step sensitivities).
    pub gradient_norm: Option<f64>,
    /// Mode switches and reportable degeneracies inside the window at the fitted values (the
    /// loss is only piecewise smooth across them); 0 when none, or when not computed.
    pub mode_events: usize,
    /// The first of them, described.
    pub first_mode_event: Option<String>,
    /// `lbfgs` or `nelder-mead`.
    pub method: Method,
    /// How L-BFGS's gradients were computed (`null` for Nelder–Mead).
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
    let counts = monitor.counts();
    // Diagnostics at the best point, outside the optimiser's counts: the loss, the gradient
    // (adjoint where the formulation has step sensitivities) and the mode events.
    let diagnostics = if problem.formulation.has_step_structure() {
        problem.clone().with_gradient(GradientMethod::Adjoint)?
    } else {
        problem.clone().with_gradient(GradientMethod::Fd)?
    };
    let (cost, gradient_norm, events) = match diagnostics.loss_and_gradient(&best_u) {
        Ok((c, g)) => (
            c,
            Some(g.iter().map(|x| x * x).sum::<f64>().sqrt()),
            diagnostics.mode_events(),
        ),
        // The best point was evaluated before, so this only fails if the gradient does.
        Err(_) => (diagnostics.loss(&best_u)?, None, Vec::new()),
    };
    let theta = problem.values_at(&best_u);
    let named = |values: &[f64]| -> BTreeMap<String, f64> {
        problem
            .params()
            .iter()
            .zip(values)
            .map(|(p, v)| (p.to_string(), *v))
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
        mode_events: events.len(),
        first_mode_event: events
            .first()
            .map(|e| format!("step {}: {:?}", e.step, e.kind)),
        method: options.method,
        gradient: (options.method == Method::Lbfgs).then_some(problem.gradient),
        termination,
        steps: problem.steps(),
        counts,
        error,
    })
}

fn termination_text(status: &TerminationStatus) -> String {
    match status {
        TerminationStatus::Terminated(reason) => reason.to_string(),
        TerminationStatus::NotTerminated => "not terminated".into(),
    }
}
