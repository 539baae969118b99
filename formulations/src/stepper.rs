//! The time stepper (`docs/model.md#stepper`): builds the step MCP once, updates its per-step data,
//! warm-starts, solves with any backend, renormalises Q, and records every step.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Vector3, Vector4, Vector6};

use ecp_model::{
    BlockMcp, DataId, Input, McpSolver, Problem, ResId, SolveError, Summary, VarBlock, VarId,
};

use crate::blocks::{
    BodyDataIds, ClosestPointAlignment, ContactFrame, FrictionDissipation, FrictionEllipsoid,
    FrictionParams, HalfSpaceSide, HullFaces, KinematicMap, NewtonEuler, NonPenetration,
    NormalCone, SceneDataIds, add_body_data, add_plane_data, add_scene_data, start_values,
};
use crate::fallback::{Fallbacks, StepMethod};
use crate::formulation::{Formulation, Stepper};
use crate::geometry::{
    ContactMode, ConvexHull, GeometryError, HalfSpace, MassProperties, Shape, contact_mode,
    min_gap, world_vertices,
};
use crate::rotation::{kinematic_map, quat_normalize, rotation_matrix};

/// Tolerance on a vertex's distance to the plane for the contact mode (`docs/model.md#scenarios`).
pub const MODE_TOLERANCE: f64 = 1e-7;

/// Row scale of the length-valued contact rows (C1, C3–C5) is `GEOMETRY_SCALE / h`.
/// See `docs/model.md#contact` and `docs/decisions.md#geometry-rows-scaled-by-1h`.
pub const GEOMETRY_SCALE: f64 = 1.0;

/// Position, orientation and velocities of a rigid body (world frame, `docs/model.md#conventions`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyState {
    /// Centre of mass.
    pub x: Vector3<f64>,
    /// Orientation, unit quaternion (w, x, y, z), body → world.
    pub q: Vector4<f64>,
    /// Linear velocity of the CM.
    pub v: Vector3<f64>,
    /// Angular velocity (world frame).
    pub w: Vector3<f64>,
}

impl BodyState {
    /// At rest at `x` with identity orientation.
    pub fn at_rest(x: Vector3<f64>) -> Self {
        BodyState {
            x,
            q: Vector4::new(1.0, 0.0, 0.0, 0.0),
            v: Vector3::zeros(),
            w: Vector3::zeros(),
        }
    }
}

/// A wrench applied at the centre of mass, world frame: `(force, torque)` as a function of time.
pub type WrenchFn = Arc<dyn Fn(f64) -> Vector6<f64> + Send + Sync>;

/// Applied load on a body (besides gravity).
#[derive(Clone, Default)]
pub enum Load {
    /// No applied load.
    #[default]
    None,
    /// A constant wrench `(f_x, f_y, f_z, τ_x, τ_y, τ_z)` at the CM, world frame.
    Constant(Vector6<f64>),
    /// A time-dependent wrench, evaluated at the start of each step `t_u`.
    Function(WrenchFn),
}

impl Load {
    /// The wrench at time `t`.
    pub fn at(&self, t: f64) -> Vector6<f64> {
        match self {
            Load::None => Vector6::zeros(),
            Load::Constant(w) => *w,
            Load::Function(f) => f(t),
        }
    }
}

impl std::fmt::Debug for Load {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Load::None => write!(f, "Load::None"),
            Load::Constant(w) => write!(f, "Load::Constant({:?})", w.as_slice()),
            Load::Function(_) => write!(f, "Load::Function(..)"),
        }
    }
}

/// A rigid body of a scene: mass properties, geometry (union of convex pieces) and initial state.
#[derive(Clone, Debug)]
pub struct BodySpec {
    /// Name used in reports.
    pub name: String,
    /// Mass and body-frame inertia about the CM.
    pub mass: MassProperties,
    /// Geometry in the body frame (origin at the CM).
    pub shape: Shape,
    /// State at t = 0.
    pub initial: BodyState,
    /// Applied load.
    pub load: Load,
}

/// Everything a simulation needs: bodies, fixed half-spaces, friction, gravity, step.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Scene name (used for output folders).
    pub name: String,
    /// The bodies.
    pub bodies: Vec<BodySpec>,
    /// Fixed half-spaces; every body has one contact with each.
    pub planes: Vec<HalfSpace>,
    /// Friction parameters (all contacts).
    pub friction: FrictionParams,
    /// Gravity acceleration vector.
    pub gravity: Vector3<f64>,
    /// Step length h.
    pub h: f64,
    /// Simulated duration.
    pub duration: f64,
}

impl Scene {
    /// Number of steps covering the duration.
    pub fn num_steps(&self) -> usize {
        (self.duration / self.h - 1e-9).ceil().max(0.0) as usize
    }
}

/// Errors in setting up a simulation.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// Bad geometry or mass properties.
    #[error("body '{body}': {source}")]
    Geometry {
        /// Body name.
        body: String,
        /// The geometric problem.
        source: GeometryError,
    },
    /// A parameter is out of range.
    #[error("{what} = {value} is invalid: {hint}")]
    Parameter {
        /// Which parameter.
        what: String,
        /// Its value.
        value: f64,
        /// How to fix it.
        hint: &'static str,
    },
    /// The initial state penetrates a half-space.
    #[error(
        "body '{body}' starts {depth:.3e} m inside half-space #{plane}; move it up so that every vertex is on or above the plane"
    )]
    InitialPenetration {
        /// Body name.
        body: String,
        /// Plane index.
        plane: usize,
        /// Penetration depth.
        depth: f64,
    },
    /// The formulation does not apply to this scene or state (`docs/model.md#other-formulations`:
    /// the reduced sliding model needs the whole patch sliding, for instance).
    #[error("the {formulation} formulation does not apply{at}: {reason}", at = step.map(|s| format!(" at step {s}")).unwrap_or_default())]
    NotApplicable {
        /// The formulation.
        formulation: crate::formulation::Formulation,
        /// The step at which it stopped applying (`None`: the scene as given).
        step: Option<usize>,
        /// Why, and what to do instead.
        reason: String,
    },
    /// The modelling layer rejected the problem.
    #[error("model: {0}")]
    Model(#[from] ecp_model::ModelError),
}

/// The state stored at the end of a step from the solution's ν and q blocks, with Q renormalised
/// (`docs/model.md#kinematic-map`; `fallback` replaces a zero quaternion), and the q block with the
/// renormalised Q for the warm start of the next step.
pub(crate) fn stored_state(
    nu: &[f64],
    q: &[f64],
    fallback: &Vector4<f64>,
) -> (BodyState, [f64; 7]) {
    let quat = quat_normalize(&Vector4::new(q[3], q[4], q[5], q[6])).unwrap_or(*fallback);
    let state = BodyState {
        x: Vector3::new(q[0], q[1], q[2]),
        q: quat,
        v: Vector3::new(nu[0], nu[1], nu[2]),
        w: Vector3::new(nu[3], nu[4], nu[5]),
    };
    (
        state,
        [q[0], q[1], q[2], quat[0], quat[1], quat[2], quat[3]],
    )
}

/// Kinetic plus gravitational potential energy of one body in `state` (`docs/model.md#invariants`).
pub(crate) fn body_energy(mass: &MassProperties, state: &BodyState, gravity: &Vector3<f64>) -> f64 {
    let r = rotation_matrix(&state.q);
    let iw = r * mass.inertia * r.transpose();
    0.5 * mass.mass * state.v.norm_squared() + 0.5 * state.w.dot(&(iw * state.w))
        - mass.mass * gravity.dot(&state.x)
}

/// Minimum gap and contact mode of every body (at `states`) against every plane, indexed
/// `[body][plane]`: computed once per step and shared by all the contacts of a (body, plane)
/// pair (one per piece in the union formulation, one per point in the point formulation).
pub(crate) fn gaps_and_modes(
    bodies: &[(&Shape, BodyState)],
    planes: &[HalfSpace],
) -> Vec<Vec<(f64, ContactMode)>> {
    bodies
        .iter()
        .map(|(shape, s)| {
            let r = rotation_matrix(&s.q);
            let verts = world_vertices(shape.vertices(), &s.x, &r);
            planes
                .iter()
                .map(|plane| {
                    (
                        min_gap(shape.vertices(), &s.x, &r, plane),
                        contact_mode(&verts, plane, MODE_TOLERANCE),
                    )
                })
                .collect()
        })
        .collect()
}

/// The scene checks every formulation shares: step, duration, friction (`e_r` only when the
/// formulation has torsional friction) and gravity.
pub(crate) fn validate_parameters(scene: &Scene, torsion: bool) -> Result<(), SceneError> {
    if !(scene.h > 0.0 && scene.h.is_finite()) {
        return Err(SceneError::Parameter {
            what: "h".into(),
            value: scene.h,
            hint: "the step length must be a positive number of seconds",
        });
    }
    if !(scene.duration >= 0.0 && scene.duration.is_finite()) {
        return Err(SceneError::Parameter {
            what: "duration".into(),
            value: scene.duration,
            hint: "the duration must be a non-negative number of seconds",
        });
    }
    let f = scene.friction;
    let mut checks = vec![
        ("mu", f.mu, false),
        ("e_t", f.e_t, true),
        ("e_o", f.e_o, true),
    ];
    if torsion {
        checks.push(("e_r", f.e_r, true));
    }
    for (what, v, positive) in checks {
        if !v.is_finite() || v < 0.0 || (positive && v == 0.0) {
            return Err(SceneError::Parameter {
                what: what.into(),
                value: v,
                hint: "friction parameters must be finite, μ ≥ 0 and e_t, e_o, e_r > 0",
            });
        }
    }
    if scene.gravity.iter().any(|g| !g.is_finite()) {
        return Err(SceneError::Parameter {
            what: "gravity".into(),
            value: f64::NAN,
            hint: "gravity must be a finite vector",
        });
    }
    Ok(())
}

/// Fraction of a body's extent along a plane's normal within which a piece's lowest point must
/// lie, above the body's lowest point, for the piece to get a contact in the union formulation.
/// See `docs/decisions.md#union_reach`.
pub const UNION_REACH: f64 = 0.25;

/// The pieces of `spec` that get a contact in the union formulation (`docs/model.md#union`: one
/// contact per convex piece that can touch a half-space): for some plane, the piece's lowest
/// vertex at the initial state is within [`UNION_REACH`] of the body's extent along the normal
/// above the body's lowest vertex. For the desk that is the four legs, for the T-bar both bars
/// (`docs/decisions.md#union_reach`).
pub fn union_pieces(spec: &BodySpec, state: &BodyState, planes: &[HalfSpace]) -> Vec<usize> {
    let r = rotation_matrix(&state.q);
    let pieces = spec.shape.pieces();
    let mut chosen = vec![false; pieces.len()];
    for plane in planes {
        let heights: Vec<f64> = pieces
            .iter()
            .map(|p| min_gap(&p.vertices(), &state.x, &r, plane))
            .collect();
        let all: Vec<f64> = world_vertices(spec.shape.vertices(), &state.x, &r)
            .iter()
            .map(|v| plane.value(v))
            .collect();
        let lo = all.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = all.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let reach = UNION_REACH * (hi - lo);
        for (k, h) in heights.iter().enumerate() {
            if *h <= lo + reach {
                chosen[k] = true;
            }
        }
    }
    (0..pieces.len()).filter(|&k| chosen[k]).collect()
}

/// Handles of one contact's variable blocks.
#[derive(Clone, Copy, Debug)]
pub struct ContactVars {
    /// Body index.
    pub body: usize,
    /// Half-space index.
    pub plane: usize,
    /// The convex piece of the body this contact belongs to (union formulation,
    /// `docs/model.md#union`); `None` for the hull formulation, whose contact is Conv(F) itself.
    pub piece: Option<usize>,
    /// ECP on Conv(F).
    pub a1: VarId,
    /// ECP on G.
    pub a2: VarId,
    /// Face multipliers of Conv(F).
    pub l: VarId,
    /// Multiplier of G.
    pub lg: VarId,
    /// Normal impulse.
    pub pn: VarId,
    /// Friction impulses (p_t, p_o, p_r).
    pub pf: VarId,
    /// Slip magnitude σ.
    pub sigma: VarId,
}

pub(crate) struct BodyData {
    pub(crate) spec: BodySpec,
    pub(crate) hull: ConvexHull,
    pub(crate) nu: VarId,
    pub(crate) q: VarId,
    newton_euler: ResId,
    kinematic: ResId,
    frames: Vec<ContactFrame>,
    pub(crate) state: BodyState,
    /// The body's data blocks (`docs/model.md#data-blocks`).
    pub(crate) data: BodyDataIds,
}

/// Per-contact values at the end of a step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactRecord {
    /// ECP on Conv(F) (`a1`).
    pub a1: Vector3<f64>,
    /// ECP on G (`a2`).
    pub a2: Vector3<f64>,
    /// Gap multiplier `l_g` (the distance while separated).
    pub lg: f64,
    /// Normal impulse.
    pub pn: f64,
    /// Friction impulse along t.
    pub pt: f64,
    /// Friction impulse along o.
    pub po: f64,
    /// Torsional friction impulse.
    pub pr: f64,
    /// Slip magnitude.
    pub sigma: f64,
    /// Minimum gap over the vertices of the real body.
    pub min_gap: f64,
    /// Contact mode from the state (`docs/model.md#scenarios`).
    pub mode: ContactMode,
}

/// Everything recorded for one step (the rows of `trajectory.csv`, `docs/outputs.md`).
#[derive(Clone, Debug)]
pub struct StepRecord {
    /// Step index, from 1.
    pub step: usize,
    /// Time at the end of the step.
    pub t: f64,
    /// Body states at the end of the step.
    pub bodies: Vec<BodyState>,
    /// Contacts (body-major, then plane).
    pub contacts: Vec<ContactRecord>,
    /// Kinetic plus potential energy of all bodies.
    pub energy: f64,
    /// Solver summary (of the best iterate when the step did not converge).
    pub summary: Summary,
    /// Whether the step was solved (by its backend or a fallback). A step that was not keeps
    /// the bodies' state at its start (`docs/fallbacks.md`).
    pub converged: bool,
    /// Wall time of the solve in microseconds (every attempt, fallbacks included).
    pub solve_us: f64,
    /// How the step was solved: directly, by a fallback backend, in substeps, or not at all.
    pub method: StepMethod,
}

/// The `trajectory.csv` columns of one body and one contact (`docs/outputs.md`).
pub const TRAJECTORY_COLUMNS: [&str; 28] = [
    "t",
    "x",
    "y",
    "z",
    "qw",
    "qx",
    "qy",
    "qz",
    "vx",
    "vy",
    "vz",
    "wx",
    "wy",
    "wz",
    "ecp_x",
    "ecp_y",
    "ecp_z",
    "pn",
    "pt",
    "po",
    "pr",
    "sigma",
    "min_gap",
    "mode",
    "iterations",
    "residual",
    "solve_us",
    "fallback",
];

impl StepRecord {
    /// The header row of `trajectory.csv` for `bodies` bodies with `contacts_per_body` contacts
    /// each (`docs/outputs.md`): one body and one contact use the plain names; more append columns
    /// suffixed `_b<i>` (body fields) and `_b<i>_c<j>` (contact fields).
    pub fn csv_header(bodies: usize, contacts_per_body: usize) -> Vec<String> {
        let single = bodies == 1 && contacts_per_body == 1;
        let mut cols = vec!["t".to_string()];
        for b in 0..bodies {
            let sb = if single {
                String::new()
            } else {
                format!("_b{b}")
            };
            for c in &TRAJECTORY_COLUMNS[1..14] {
                cols.push(format!("{c}{sb}"));
            }
            for j in 0..contacts_per_body {
                let sc = if single {
                    String::new()
                } else {
                    format!("{sb}_c{j}")
                };
                for c in &TRAJECTORY_COLUMNS[14..24] {
                    cols.push(format!("{c}{sc}"));
                }
            }
        }
        for c in &TRAJECTORY_COLUMNS[24..] {
            cols.push((*c).to_string());
        }
        cols
    }

    /// This record as the fields of a `trajectory.csv` row, in [`StepRecord::csv_header`] order.
    pub fn csv_fields(&self) -> Vec<String> {
        let mut f = vec![format!("{}", self.t)];
        let per_body = if self.bodies.is_empty() {
            0
        } else {
            self.contacts.len() / self.bodies.len()
        };
        for (b, s) in self.bodies.iter().enumerate() {
            for v in [
                s.x.x, s.x.y, s.x.z, s.q[0], s.q[1], s.q[2], s.q[3], s.v.x, s.v.y, s.v.z, s.w.x,
                s.w.y, s.w.z,
            ] {
                f.push(format!("{v:e}"));
            }
            for c in &self.contacts[b * per_body..(b + 1) * per_body] {
                for v in [
                    c.a1.x, c.a1.y, c.a1.z, c.pn, c.pt, c.po, c.pr, c.sigma, c.min_gap,
                ] {
                    f.push(format!("{v:e}"));
                }
                f.push(c.mode.as_str().to_string());
            }
        }
        f.push(self.summary.iterations.to_string());
        f.push(format!("{:e}", self.summary.residual));
        f.push(format!("{:.3}", self.solve_us));
        f.push(self.method.column());
        f
    }
}

/// A running simulation: the step MCP (built once), the warm start and the current state.
pub struct Simulation {
    pub(crate) scene: Scene,
    pub(crate) bodies: Vec<BodyData>,
    pub(crate) contacts: Vec<ContactVars>,
    pub(crate) mcp: BlockMcp,
    /// The convex set of each contact (parallel to `contacts`): Conv(F) for the hull
    /// formulation, the piece's hull for the union formulation.
    pub(crate) contact_hulls: Vec<ConvexHull>,
    formulation: Formulation,
    z: Vec<f64>,
    step: usize,
    t: f64,
    /// The scene-wide data blocks (`docs/model.md#data-blocks`).
    pub(crate) scene_data: SceneDataIds,
    /// The last step taken, while its step problem is still the one in `mcp`.
    last: Option<LastStep>,
    /// Origin of the step problem's coordinates: positions in `z` and in the blocks are relative
    /// to it (world = origin + z). Zero until a body moves farther than [`RECENTRE_DISTANCE`]
    /// from it, so that a scene far from the world origin is solved as precisely as the same
    /// scene near it.
    origin: Vector3<f64>,
    /// The offset data block of each half-space, the only data that hold an absolute position
    /// besides the bodies' start positions.
    plane_data: Vec<DataId>,
    /// The half-spaces in the step problem's coordinates (relative to `origin`).
    pub(crate) step_planes: Vec<HalfSpace>,
}

/// Distance (m, any axis) from the step problem's origin beyond which the stepper moves the
/// origin to the bodies' centroid. Round-off in the position rows grows with the coordinates'
/// size (about 2e-16·|x|, amplified by the 1/h row scale), so far from the origin a step could
/// not reach the tolerance; within this distance the loss is below 1e-11.
/// See `docs/decisions.md#recentred-origin-for-far-scenes`.
pub const RECENTRE_DISTANCE: f64 = 100.0;

/// The last step a [`Simulation`] took, as the step sensitivities need it: the step's data
/// stay in [`Simulation::mcp`] until the next [`Simulation::prepare_step`], which clears this.
#[derive(Clone, Debug, PartialEq)]
pub struct LastStep {
    /// The step's index, from 1.
    pub step: usize,
    /// Time at the start of the step, `t_u` (the loads were evaluated there).
    pub t_start: f64,
    /// Body states at the start of the step.
    pub start: Vec<BodyState>,
    /// Applied wrench of each body at `t_u`, `(force, torque)` at the CM, world frame.
    pub wrenches: Vec<Vector6<f64>>,
    /// The solution as the backend returned it (the end-of-step `Q` not yet renormalised).
    pub z: Vec<f64>,
    /// Whether the step converged.
    pub converged: bool,
}

impl Simulation {
    /// Validates the scene and builds the step MCP of the hull formulation (the paper's).
    pub fn new(scene: Scene) -> Result<Self, SceneError> {
        Self::with_formulation(scene, Formulation::Hull)
    }

    /// Validates the scene and builds the step MCP of `formulation`, which must be
    /// [`Formulation::Hull`] (one contact between Conv(F) and each half-space) or
    /// [`Formulation::Union`] (`docs/model.md#union`: one contact, with its own ECP, multipliers,
    /// impulses and friction ellipsoid, between each convex piece of F and each half-space).
    /// The other formulations have their own steppers ([`crate::build_stepper`]).
    pub fn with_formulation(scene: Scene, formulation: Formulation) -> Result<Self, SceneError> {
        if !matches!(formulation, Formulation::Hull | Formulation::Union) {
            return Err(SceneError::NotApplicable {
                formulation,
                step: None,
                reason: "the ECP stepper builds the hull and union formulations only; use \
                         ecp_formulations::build_stepper for the others"
                    .into(),
            });
        }
        validate_parameters(&scene, true)?;

        let mut problem = Problem::new();
        let scene_data = add_scene_data(&mut problem, &scene.gravity, scene.h, &scene.friction);
        let plane_data: Vec<DataId> = (scene.planes.iter().enumerate())
            .map(|(p, plane)| add_plane_data(&mut problem, p, plane.offset()))
            .collect();
        let mut bodies = Vec::new();
        let mut contacts = Vec::new();
        let mut contact_hulls = Vec::new();
        for (b, spec) in scene.bodies.iter().enumerate() {
            let hull = spec.shape.hull().map_err(|source| SceneError::Geometry {
                body: spec.name.clone(),
                source,
            })?;
            let mut state = spec.initial;
            state.q = quat_normalize(&state.q).ok_or_else(|| SceneError::Parameter {
                what: format!("{}.orientation", spec.name),
                value: 0.0,
                hint: "the initial quaternion must be non-zero",
            })?;
            let r = rotation_matrix(&state.q);
            for (p, plane) in scene.planes.iter().enumerate() {
                let gap = min_gap(spec.shape.vertices(), &state.x, &r, plane);
                if gap < -1e-9 {
                    return Err(SceneError::InitialPenetration {
                        body: spec.name.clone(),
                        plane: p,
                        depth: -gap,
                    });
                }
            }
            let nu = problem.add_variable_block(
                VarBlock::free(format!("{}.nu", spec.name), 6)
                    .with_component_names(["vx", "vy", "vz", "wx", "wy", "wz"]),
            );
            let q = problem.add_variable_block(
                VarBlock::free(format!("{}.q", spec.name), 7)
                    .with_component_names(["x", "y", "z", "qw", "qx", "qy", "qz"]),
            );
            // The convex sets that get a contact: Conv(F), or every piece (union).
            let sets: Vec<(Option<usize>, ConvexHull)> = match formulation {
                Formulation::Union => {
                    let mut sets = Vec::new();
                    for i in union_pieces(spec, &state, &scene.planes) {
                        let piece = &spec.shape.pieces()[i];
                        let h = piece.hull().map_err(|source| SceneError::Geometry {
                            body: format!("{} (piece {i})", spec.name),
                            source,
                        })?;
                        sets.push((Some(i), h));
                    }
                    sets
                }
                _ => vec![(None, hull.clone())],
            };
            let mut frames = Vec::new();
            for (p, plane) in scene.planes.iter().enumerate() {
                for (piece, set) in &sets {
                    let m = set.num_faces();
                    let mut tag = if scene.planes.len() > 1 || scene.bodies.len() > 1 {
                        format!("{}.c{}", spec.name, p)
                    } else {
                        "contact".to_string()
                    };
                    if let Some(i) = piece {
                        tag = format!("{tag}.piece{i}");
                    }
                    let cv = ContactVars {
                        body: b,
                        plane: p,
                        piece: *piece,
                        a1: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.a1"), 3)
                                .with_component_names(["x", "y", "z"]),
                        ),
                        a2: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.a2"), 3)
                                .with_component_names(["x", "y", "z"]),
                        ),
                        l: problem.add_variable_block(VarBlock::nonnegative(format!("{tag}.l"), m)),
                        lg: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.lg"), 1)),
                        pn: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.pn"), 1)),
                        pf: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.pf"), 3)
                                .with_component_names(["pt", "po", "pr"]),
                        ),
                        sigma: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.sigma"), 1)),
                    };
                    let (n, t, o) = plane.contact_frame();
                    frames.push(ContactFrame { n, t, o });
                    contacts.push(cv);
                    contact_hulls.push(set.clone());
                }
            }
            let data = add_body_data(&mut problem, &spec.name, spec.mass.mass, &spec.mass.inertia);
            bodies.push(BodyData {
                spec: spec.clone(),
                hull,
                nu,
                q,
                newton_euler: ResId(0),
                kinematic: ResId(0),
                frames,
                state,
                data,
            });
        }

        // Residual blocks (`docs/model.md#residual-blocks`), paired as in `docs/model.md#unknowns`,
        // reading the data blocks of `docs/model.md#data-blocks`; `prepare_span` sets the
        // per-step data.
        let SceneDataIds {
            gravity,
            h: step_length,
            friction,
        } = scene_data;
        for (b, body) in bodies.iter_mut().enumerate() {
            let mine: Vec<(&ContactVars, &ConvexHull)> = contacts
                .iter()
                .zip(&contact_hulls)
                .filter(|(c, _)| c.body == b)
                .collect();
            let mut reads: Vec<Input> = vec![body.nu.into(), body.q.into()];
            for (c, _) in &mine {
                reads.extend([c.a1, c.pn, c.pf].map(Input::from));
            }
            let d = body.data;
            reads.extend(
                [d.mass, d.inertia, d.start, d.wrench, gravity, step_length].map(Input::from),
            );
            body.newton_euler = problem.add_residual_block(
                body.nu,
                NewtonEuler::new(body.frames.clone()),
                reads,
            )?;
            body.kinematic = problem.add_residual_block(
                body.q,
                KinematicMap,
                &[
                    body.q.into(),
                    body.nu.into(),
                    Input::from(d.start),
                    step_length.into(),
                ],
            )?;
            // Length-valued rows in velocity units (1/h): a penetration of h·Δv then weighs
            // like a velocity error Δv (`docs/model.md#contact`,
            // docs/decisions.md#geometry-rows-scaled-by-1h).
            let scale = GEOMETRY_SCALE / scene.h;
            for ((c, set), frame) in mine.iter().zip(&body.frames) {
                let normals: Vec<Vector3<f64>> = set.faces().iter().map(|f| f.normal).collect();
                let offsets: Vec<f64> = set.faces().iter().map(|f| f.offset).collect();
                let ng = scene.planes[c.plane].normal();
                problem.add_residual_block(
                    c.a1,
                    ClosestPointAlignment { normal: ng, scale },
                    &[c.a1, c.a2, c.lg],
                )?;
                problem.add_residual_block(
                    c.a2,
                    NormalCone::new(ng, normals.clone()),
                    &[c.l, body.q],
                )?;
                problem.add_residual_block(
                    c.l,
                    HullFaces {
                        face_normals: normals,
                        offsets,
                        scale,
                    },
                    &[c.a1, body.q],
                )?;
                let offset = Input::from(plane_data[c.plane]);
                problem.add_residual_block(
                    c.lg,
                    HalfSpaceSide { normal: ng, scale },
                    &[c.a2.into(), offset],
                )?;
                problem.add_residual_block(
                    c.pn,
                    NonPenetration { normal: ng, scale },
                    &[c.a1.into(), offset],
                )?;
                let vars = [body.nu, body.q, c.a1, c.pn, c.pf, c.sigma];
                let mut reads: Vec<Input> = vars.map(Input::from).to_vec();
                reads.push(friction.into());
                problem.add_residual_block(c.pf, FrictionDissipation { frame: *frame }, reads)?;
                problem.add_residual_block(
                    c.sigma,
                    FrictionEllipsoid,
                    &[c.pn.into(), c.pf.into(), Input::from(friction)],
                )?;
            }
        }
        let mcp = problem.build()?;
        let mut sim = Simulation {
            z: vec![0.0; ecp_model::Mcp::dim(&mcp)],
            scene,
            bodies,
            contacts,
            contact_hulls,
            formulation,
            mcp,
            step: 0,
            t: 0.0,
            scene_data,
            last: None,
            origin: Vector3::zeros(),
            plane_data,
            step_planes: Vec::new(),
        };
        sim.step_planes = sim.scene.planes.clone();
        sim.recentre_if_far()?;
        sim.initial_guess();
        Ok(sim)
    }

    /// First-step guess (`docs/model.md#stepper`): for each contact, `a1` on Conv(F) nearest to G
    /// and its projection `a2`, the gap as `l_g`, multiplier 1 on the face most anti-parallel to
    /// `n_G`. Where the body already touches G, the impulses start active (see
    /// [`Self::contact_guess`]).
    fn initial_guess(&mut self) {
        for b in 0..self.bodies.len() {
            let (nu, s) = (self.bodies[b].nu, self.bodies[b].state);
            self.put(nu, &[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z]);
        }
        for i in 0..self.contacts.len() {
            self.contact_guess(i, false);
        }
    }

    /// Guess for one contact's unknowns from the current state.
    ///
    /// `a1` is the centroid of the hull vertices nearest to G (a face centre, an edge midpoint or a
    /// vertex), `a2` its projection, `l_g` the gap, multiplier 1 on the face most anti-parallel to
    /// `n_G`. When the contact is closed (gap ≤ 1e-9) or `force_active` is set, the normal impulse
    /// starts at the value that carries the weight and stops the approach velocity over the step,
    /// and the friction impulse on the ellipsoid opposing the current slip with σ the slip rate — a
    /// point of the sliding branch of `docs/model.md#friction`. Otherwise impulses and σ start at
    /// 0. Starting active matters: `p_n = 0` zeroes every friction row, and the merit function of a
    /// Newton method has a spurious minimiser near "free fall with zero impulses".
    fn contact_guess(&mut self, i: usize, force_active: bool) {
        let s = self.bodies[self.contacts[i].body].state;
        self.contact_guess_at(i, force_active, &s.x, &rotation_matrix(&s.q));
    }

    /// [`Self::contact_guess`] with the closest points taken at the pose `(x, r)` (the
    /// velocities are the current state's).
    fn contact_guess_at(
        &mut self,
        i: usize,
        force_active: bool,
        x: &Vector3<f64>,
        r: &nalgebra::Matrix3<f64>,
    ) {
        let c = &self.contacts[i];
        let body = &self.bodies[c.body];
        let set = &self.contact_hulls[i];
        let plane = &self.scene.planes[c.plane];
        let s = body.state;
        let ng = plane.normal();
        let (a1, gmin, l) = closest_point_guess(set, plane, x, r);
        let a2 = plane.project(&a1);
        let gap = gmin.max(0.0);
        let f = self.scene.friction;
        let (mut pn, mut pf, mut sigma) = (0.0, [0.0; 3], self.open_contact_sigma(i));
        if gap <= 1e-9 || force_active {
            let m = body.spec.mass.mass;
            let h = self.scene.h;
            let v_pred = s.v + self.scene.gravity * h;
            pn = (-m * self.scene.gravity.dot(&ng) * h).max(0.0) + (-m * v_pred.dot(&ng)).max(0.0);
            let (_, t, o) = plane.contact_frame();
            let rr = a1 - s.x;
            let vt = t.dot(&s.v) + rr.cross(&t).dot(&s.w);
            let vo = o.dot(&s.v) + rr.cross(&o).dot(&s.w);
            let wn = ng.dot(&s.w);
            let slip = ((f.e_t * vt).powi(2) + (f.e_o * vo).powi(2) + (f.e_r * wn).powi(2)).sqrt();
            if slip > 1e-12 {
                let k = -f.mu * pn / slip;
                pf = [
                    k * f.e_t * f.e_t * vt,
                    k * f.e_o * f.e_o * vo,
                    k * f.e_r * f.e_r * wn,
                ];
                sigma = slip;
            }
        }
        let c = self.contacts[i];
        let o = self.origin;
        self.put(c.a1, (a1 - o).as_slice());
        self.put(c.a2, (a2 - o).as_slice());
        self.put(c.l, &l);
        self.put(c.lg, &[gap]);
        self.put(c.pn, &[pn]);
        self.put(c.pf, &pf);
        self.put(c.sigma, &[sigma]);
    }

    /// The slip rate σ of the warm start of an open contact (`p_n = 0`): the slip speed of the
    /// body at its ECP, `(e_t² v_t² + e_o² v_o² + e_r² ω_n²)^½`, and at least the speed gravity
    /// gives in one step, `|g| h`.
    ///
    /// With `p_n = 0` every σ ≥ 0 solves the friction law, but σ = 0 together with `p_n = 0`
    /// zeroes the whole linearisation of the friction rows `e² μ p_n W ν + p_f σ`: the friction
    /// impulse is then free at first order, the Newton matrix is singular, and its safeguard
    /// steps move `p_f` and `p_n` off zero into a spurious minimiser of the merit function
    /// (docs/newton.md). With σ > 0 the rows pin `p_f` to 0.
    fn open_contact_sigma(&self, i: usize) -> f64 {
        let c = &self.contacts[i];
        let s = self.bodies[c.body].state;
        let plane = &self.scene.planes[c.plane];
        let (ng, t, o) = plane.contact_frame();
        let a1 = self.get(c.a1);
        let rr = Vector3::new(a1[0], a1[1], a1[2]) - s.x;
        let f = self.scene.friction;
        let vt = t.dot(&s.v) + rr.cross(&t).dot(&s.w);
        let vo = o.dot(&s.v) + rr.cross(&o).dot(&s.w);
        let wn = ng.dot(&s.w);
        let slip = ((f.e_t * vt).powi(2) + (f.e_o * vo).powi(2) + (f.e_r * wn).powi(2)).sqrt();
        let floor = self.scene.gravity.norm() * self.scene.h;
        if slip.is_finite() && slip > floor {
            slip
        } else if floor > 0.0 {
            floor
        } else {
            1.0
        }
    }

    fn put(&mut self, v: VarId, values: &[f64]) {
        let range = self.mcp.range(v);
        self.z[range].copy_from_slice(values);
    }

    fn get(&self, v: VarId) -> &[f64] {
        &self.z[self.mcp.range(v)]
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// The assembled step MCP (its data are those of the last step prepared).
    pub fn mcp(&self) -> &BlockMcp {
        &self.mcp
    }
    /// The step MCP together with its structural view (`docs/backends.md#conic`): the problem every
    /// backend is given by [`Simulation::step`]; structure-exploiting backends (the conic one)
    /// need this rather than [`Simulation::mcp`].
    pub fn structured_mcp(&self) -> crate::structure::StepView<'_> {
        crate::structure::StepView::new(self)
    }
    /// The current unknown vector (last solution, or the warm start of the next step). Its
    /// positions are relative to [`Simulation::origin`] (zero unless the scene is far from the
    /// world origin).
    pub fn z(&self) -> &[f64] {
        &self.z
    }
    /// Contact handles.
    pub fn contacts(&self) -> &[ContactVars] {
        &self.contacts
    }
    /// Current state of body `b`.
    pub fn state(&self, b: usize) -> BodyState {
        self.bodies[b].state
    }
    /// Convex hull of body `b`.
    pub fn hull(&self, b: usize) -> &ConvexHull {
        &self.bodies[b].hull
    }
    /// The convex set of contact `i` ([`Simulation::contacts`]): Conv(F) of its body for the
    /// hull formulation, its piece's hull for the union formulation.
    pub fn contact_hull(&self, i: usize) -> &ConvexHull {
        &self.contact_hulls[i]
    }
    /// The formulation of this step problem (hull or union).
    pub fn formulation(&self) -> Formulation {
        self.formulation
    }
    /// Current time.
    pub fn time(&self) -> f64 {
        self.t
    }
    /// Replaces the current state of body `b` (its quaternion is normalised), for example to
    /// restart a step from a perturbed state (finite differences, model-predictive control).
    /// Unlike [`Simulation::new`] it accepts a state that penetrates a half-space: the next
    /// step's contact conditions resolve it. The warm start of the next step keeps the previous
    /// solution's impulses.
    pub fn set_state(&mut self, b: usize, state: BodyState) -> Result<(), SceneError> {
        let name = match self.bodies.get(b) {
            Some(body) => body.spec.name.clone(),
            None => {
                return Err(SceneError::Parameter {
                    what: format!("body index {b}"),
                    value: b as f64,
                    hint: "the body index must be less than the number of bodies",
                });
            }
        };
        let finite = state
            .x
            .iter()
            .chain(&state.v)
            .chain(&state.w)
            .all(|v| v.is_finite());
        let q = quat_normalize(&state.q);
        match q {
            Some(q) if finite => {
                self.bodies[b].state = BodyState { q, ..state };
                Ok(())
            }
            _ => Err(SceneError::Parameter {
                what: format!("{name}.state"),
                value: f64::NAN,
                hint: "the state must be finite with a non-zero quaternion",
            }),
        }
    }
    /// The last step taken, while the step problem in [`Simulation::mcp`] is still its own
    /// (`None` before the first step and after [`Simulation::prepare_step`]).
    pub fn last_step(&self) -> Option<&LastStep> {
        self.last.as_ref()
    }
    /// The handles of body `b`'s velocity `ν` and configuration `q` blocks.
    pub fn body_vars(&self, b: usize) -> (VarId, VarId) {
        (self.bodies[b].nu, self.bodies[b].q)
    }
    /// The residual blocks of body `b`: its Newton–Euler and kinematic-map blocks.
    pub fn body_blocks(&self, b: usize) -> (ResId, ResId) {
        (self.bodies[b].newton_euler, self.bodies[b].kinematic)
    }
    /// The data blocks of body `b` (`docs/model.md#data-blocks`): mass, inertia, start state and
    /// applied wrench of the step prepared last (`None` for a body the scene does not have).
    pub fn body_data(&self, b: usize) -> Option<BodyDataIds> {
        self.bodies.get(b).map(|body| body.data)
    }
    /// The scene-wide data blocks (`docs/model.md#data-blocks`): gravity, step length, friction.
    pub fn scene_data(&self) -> SceneDataIds {
        self.scene_data
    }
    /// The offset data block of half-space `p` (in the step problem's coordinates; `None` for a
    /// half-space the scene does not have).
    pub fn plane_data(&self, p: usize) -> Option<DataId> {
        self.plane_data.get(p).copied()
    }
    /// Steps taken.
    pub fn steps_taken(&self) -> usize {
        self.step
    }
    /// True once the scene's duration is covered.
    pub fn finished(&self) -> bool {
        self.step >= self.scene.num_steps()
    }

    /// Updates the per-step data blocks (`docs/model.md#data-blocks`: each body's start state and
    /// applied wrench at t_u, and the step length) with [`BlockMcp::set_data`] — the problem and
    /// its pattern are unchanged — and the warm start. After this, `mcp()` and `z()` are the step
    /// problem and its starting point.
    pub fn prepare_step(&mut self) -> Result<(), SceneError> {
        self.recentre_if_far()?;
        self.prepare_span(self.t, self.scene.h)
    }

    /// [`Simulation::prepare_step`] for the span `[t0, t0 + h]` from the current state: a whole
    /// step, or a substep of a step its backend could not solve ([`Fallbacks`]).
    fn prepare_span(&mut self, t0: f64, h: f64) -> Result<(), SceneError> {
        self.last = None;
        let o = self.origin;
        // Per body: the predicted position (world frame) and rotation.
        let mut motion = Vec::with_capacity(self.bodies.len());
        self.mcp.set_data(self.scene_data.h, &[h])?;
        for b in 0..self.bodies.len() {
            let body = &self.bodies[b];
            let s = body.state;
            let load = body.spec.load.at(t0);
            let (data, nu_id, q_id) = (body.data, body.nu, body.q);
            self.mcp
                .set_data(data.start, &start_values(&(s.x - o), &s.q, &s.v, &s.w))?;
            self.mcp.set_data(data.wrench, load.as_slice())?;
            // Warm start: ν from the previous solution (= ν^u), q predicted by the kinematic map.
            let nu_prev: Vec<f64> = self.get(nu_id).to_vec();
            let w = Vector3::new(nu_prev[3], nu_prev[4], nu_prev[5]);
            let v = Vector3::new(nu_prev[0], nu_prev[1], nu_prev[2]);
            let x_pred = s.x - o + v * h;
            let q_pred = s.q + kinematic_map(&s.q) * w * (0.5 * h);
            let q_guess = [
                x_pred.x, x_pred.y, x_pred.z, q_pred[0], q_pred[1], q_pred[2], q_pred[3],
            ];
            self.put(q_id, &q_guess);
            let r_pred =
                quat_normalize(&q_pred).map_or(rotation_matrix(&s.q), |q| rotation_matrix(&q));
            motion.push((x_pred + o, r_pred));
        }
        // Contacts that ended the last step open (p_n = 0): the closest-point unknowns start at
        // the closest points of the predicted pose (a1, a2, l_g, and face multipliers l that
        // satisfy C2 there, see `closest_point_guess`) when that pose is still separated; σ stays > 0
        // (see `open_contact_sigma`: the solution leaves σ free, and σ = 0 makes the friction
        // rows' linearisation vanish at the warm start).
        for i in 0..self.contacts.len() {
            let c = self.contacts[i];
            let m = self.bodies[c.body].spec.mass.mass;
            let open_pn = 1e-12 * m * (self.scene.gravity.norm() * h).max(f64::MIN_POSITIVE);
            if self.get(c.pn)[0] > open_pn {
                continue;
            }
            let (x1, r1) = motion[c.body];
            let plane = self.scene.planes[c.plane];
            let (a1, gap, l) = closest_point_guess(&self.contact_hulls[i], &plane, &x1, &r1);
            if !a1.iter().all(|v| v.is_finite()) {
                continue;
            }
            if gap > 0.0 {
                let a2 = plane.project(&a1);
                self.put(c.a1, (a1 - o).as_slice());
                self.put(c.a2, (a2 - o).as_slice());
                self.put(c.lg, &[gap]);
                self.put(c.l, &l);
                let sigma = self.open_contact_sigma(i);
                if self.get(c.sigma)[0] < sigma {
                    self.put(c.sigma, &[sigma]);
                }
            } else {
                // The predicted pose penetrates: the contact closes within the step.
                self.contact_guess_at(i, true, &x1, &r1);
            }
        }
        Ok(())
    }

    /// Solves the prepared span of length `h` with `solver` from the warm start in `z`, with one
    /// deterministic retry from the active-contact guess of every contact that is closed or
    /// closing (a warm start from a separated step is a poor start for a landing step;
    /// `docs/decisions.md#retry-from-the-active-contact-guess`). On
    /// success `z` holds the solution; on failure it is left at the warm start.
    fn solve_prepared(
        &mut self,
        solver: &mut dyn McpSolver,
        h: f64,
    ) -> Result<ecp_model::Solution, SolveError> {
        let result = solver.solve(&self.structured_mcp(), &self.z);
        if result.is_ok() {
            return result;
        }
        let warm = self.z.clone();
        for i in 0..self.contacts.len() {
            let c = self.contacts[i];
            let body = &self.bodies[c.body];
            let plane = &self.scene.planes[c.plane];
            let r = rotation_matrix(&body.state.q);
            let gap = min_gap(self.contact_hulls[i].vertices(), &body.state.x, &r, plane);
            let approach = -(body.state.v + self.scene.gravity * h).dot(&plane.normal());
            if gap <= approach.max(0.0) * h + 1e-9 {
                self.contact_guess(i, true);
            }
        }
        match solver.solve(&self.structured_mcp(), &self.z) {
            Ok(mut sol) => {
                sol.summary.counters.add(ecp_model::Counter::Retries, 1);
                Ok(sol)
            }
            Err(e) => {
                self.z.copy_from_slice(&warm);
                // Report the first attempt's best iterate when it was the better one.
                Err(match (result, e) {
                    (
                        Err(SolveError::NotConverged { best: a }),
                        SolveError::NotConverged { best: b },
                    ) => SolveError::NotConverged {
                        best: if a.summary.residual <= b.summary.residual {
                            a
                        } else {
                            b
                        },
                    },
                    (_, e) => e,
                })
            }
        }
    }

    /// Takes the solution `z` of the prepared span: the end-of-span state (Q renormalised, also
    /// in the warm start) becomes the current state.
    fn commit(&mut self, z: &[f64]) {
        self.z.copy_from_slice(z);
        for b in 0..self.bodies.len() {
            let (state, q_stored) = stored_state(
                self.get(self.bodies[b].nu),
                self.get(self.bodies[b].q),
                &self.bodies[b].state.q,
            );
            let qr = self.bodies[b].q;
            self.put(qr, &q_stored);
            self.bodies[b].state = BodyState {
                x: state.x + self.origin,
                ..state
            };
        }
    }

    /// Moves the step problem's origin to the bodies' centroid when a body is farther than
    /// [`RECENTRE_DISTANCE`] from it: the positions in the warm start and the half-spaces'
    /// offset data are shifted (the start positions follow in `prepare_span`); nothing else holds
    /// an absolute position.
    fn recentre_if_far(&mut self) -> Result<(), SceneError> {
        let far = self
            .bodies
            .iter()
            .map(|b| (b.state.x - self.origin).amax())
            .fold(0.0, f64::max);
        if far <= RECENTRE_DISTANCE || self.bodies.is_empty() {
            return Ok(());
        }
        let centroid = self
            .bodies
            .iter()
            .fold(Vector3::zeros(), |acc, b| acc + b.state.x)
            / self.bodies.len() as f64;
        if !centroid.iter().all(|c| c.is_finite()) {
            return Ok(());
        }
        let shift = centroid - self.origin;
        for b in 0..self.bodies.len() {
            let range = self.mcp.range(self.bodies[b].q);
            for k in 0..3 {
                self.z[range.start + k] -= shift[k];
            }
        }
        for i in 0..self.contacts.len() {
            let c = self.contacts[i];
            for v in [c.a1, c.a2] {
                let range = self.mcp.range(v);
                for k in 0..3 {
                    self.z[range.start + k] -= shift[k];
                }
            }
        }
        self.origin = centroid;
        for (p, plane) in self.scene.planes.iter().enumerate() {
            let n = plane.normal();
            self.step_planes[p] =
                HalfSpace::new(n, plane.offset() - n.dot(&centroid)).map_err(|source| {
                    SceneError::Geometry {
                        body: format!("half-space #{p}"),
                        source,
                    }
                })?;
            self.mcp
                .set_data(self.plane_data[p], &[self.step_planes[p].offset()])?;
        }
        Ok(())
    }

    /// Origin of the step problem's coordinates: the positions in [`Simulation::z`] and in the
    /// step problem are relative to it. It is zero unless a body went farther than
    /// [`RECENTRE_DISTANCE`] from the world origin.
    pub fn origin(&self) -> Vector3<f64> {
        self.origin
    }

    fn checkpoint(&self) -> (Vec<BodyState>, Vec<f64>) {
        (
            self.bodies.iter().map(|b| b.state).collect(),
            self.z.clone(),
        )
    }

    fn restore(&mut self, checkpoint: &(Vec<BodyState>, Vec<f64>)) {
        for (body, state) in self.bodies.iter_mut().zip(&checkpoint.0) {
            body.state = *state;
        }
        self.z.copy_from_slice(&checkpoint.1);
    }

    /// Advances one step with `solver` and no fallback. A step that does not converge is
    /// reported as failed and the bodies keep their state at its start (`docs/fallbacks.md`);
    /// the caller decides whether to go on.
    pub fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        self.step_with(solver, &mut Fallbacks::none())
    }

    /// Advances one step with `solver`; when it cannot solve the step, with the `fallbacks`:
    /// each fallback backend on the same step problem, then substeps (bisecting only the pieces
    /// that fail, down to `h / 2^max_halvings`), each piece tried with `solver` and then each
    /// fallback backend. Every accepted piece passed the backend's natural-residual test. When
    /// everything fails the step is reported as failed ([`StepMethod::Failed`]) and the bodies
    /// keep their state at its start.
    pub fn step_with(
        &mut self,
        solver: &mut dyn McpSolver,
        fallbacks: &mut Fallbacks,
    ) -> Result<StepRecord, SceneError> {
        let (t0, h) = (self.t, self.scene.h);
        let started = Instant::now();
        // Before the checkpoint: the origin stays put within a step and its fallbacks.
        self.recentre_if_far()?;
        let start = self.checkpoint();
        self.prepare_span(t0, h)?;
        let wrenches: Vec<Vector6<f64>> = self.bodies.iter().map(|b| b.spec.load.at(t0)).collect();
        let first = self.solve_prepared(solver, h);
        let (summary, method, z_last) = match first {
            Ok(sol) => {
                self.commit(&sol.z);
                (sol.summary, StepMethod::Direct, Some(sol.z))
            }
            Err(SolveError::InvalidProblem(msg)) => {
                return Err(SceneError::Model(ecp_model::ModelError::Dimension(msg)));
            }
            Err(SolveError::NotConverged { best }) => {
                let mut solved = None;
                for k in 0..fallbacks.backends.len() {
                    self.restore(&start);
                    self.prepare_span(t0, h)?;
                    if let Ok(sol) = self.solve_prepared(fallbacks.backends[k].as_mut(), h) {
                        self.commit(&sol.z);
                        let name = fallbacks.backends[k].name().to_string();
                        solved = Some((sol.summary, StepMethod::Backend(name), Some(sol.z)));
                        break;
                    }
                }
                if solved.is_none() && fallbacks.max_halvings > 0 {
                    self.restore(&start);
                    let mut pieces = Vec::new();
                    let mut last_summary = None;
                    let ok = self.solve_halves(
                        solver,
                        fallbacks,
                        t0,
                        h,
                        1,
                        &mut pieces,
                        &mut last_summary,
                    )?;
                    if let (true, Some(s)) = (ok, last_summary) {
                        let finest = pieces.iter().copied().max().unwrap_or(1);
                        solved = Some((
                            s,
                            StepMethod::Substeps {
                                pieces: pieces.len(),
                                finest,
                            },
                            None,
                        ));
                    }
                }
                match solved {
                    Some(s) => s,
                    None => {
                        // Exhausted: never take an infeasible iterate; keep the last feasible
                        // state, the one at the start of the step.
                        self.restore(&start);
                        (best.summary, StepMethod::Failed, None)
                    }
                }
            }
        };
        let solve_us = started.elapsed().as_secs_f64() * 1e6;
        let converged = method.solved();
        self.step += 1;
        self.t = self.step as f64 * self.scene.h;
        // The step problem in `mcp` is this step's own only when it was solved in one piece.
        self.last = z_last.map(|z| LastStep {
            step: self.step,
            t_start: t0,
            start: start.0,
            wrenches,
            z,
            converged,
        });
        Ok(self.record(summary, converged, solve_us, method))
    }

    /// Takes one step with `solver` and takes its point **whether or not it solves the step
    /// problem**: for studying a relaxed model (the conic backend's Anitescu mode) whose points
    /// are not solutions of this one. The record says so: `converged` is the backend's verdict
    /// and a point that failed it is marked [`StepMethod::Unchecked`]. The run driver never
    /// calls this.
    pub fn step_unchecked(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        let (t0, h) = (self.t, self.scene.h);
        let started = Instant::now();
        self.recentre_if_far()?;
        self.prepare_span(t0, h)?;
        let (z, summary, method) = match solver.solve(&self.structured_mcp(), &self.z) {
            Ok(sol) => (sol.z, sol.summary, StepMethod::Direct),
            Err(SolveError::NotConverged { best }) => (best.z, best.summary, StepMethod::Unchecked),
            Err(SolveError::InvalidProblem(msg)) => {
                return Err(SceneError::Model(ecp_model::ModelError::Dimension(msg)));
            }
        };
        self.commit(&z);
        self.step += 1;
        self.t = self.step as f64 * self.scene.h;
        let solve_us = started.elapsed().as_secs_f64() * 1e6;
        Ok(self.record(summary, method.solved(), solve_us, method))
    }

    /// Solves `[t0, t0 + h]` from the current state as two halves, each with `solver` then the
    /// fallback backends, bisecting a half again when all fail, down to `depth =
    /// max_halvings`. Appends each accepted piece's denominator (2^depth) to `pieces`; returns
    /// whether the whole span was covered.
    #[allow(clippy::too_many_arguments)]
    fn solve_halves(
        &mut self,
        solver: &mut dyn McpSolver,
        fallbacks: &mut Fallbacks,
        t0: f64,
        h: f64,
        depth: u32,
        pieces: &mut Vec<usize>,
        last: &mut Option<Summary>,
    ) -> Result<bool, SceneError> {
        let half = 0.5 * h;
        for k in 0..2 {
            let ts = t0 + k as f64 * half;
            let before = self.checkpoint();
            let mut done = false;
            for s in 0..=fallbacks.backends.len() {
                self.restore(&before);
                self.prepare_span(ts, half)?;
                let result = if s == 0 {
                    self.solve_prepared(solver, half)
                } else {
                    self.solve_prepared(fallbacks.backends[s - 1].as_mut(), half)
                };
                if let Ok(sol) = result {
                    self.commit(&sol.z);
                    *last = Some(sol.summary);
                    pieces.push(1 << depth);
                    done = true;
                    break;
                }
            }
            if !done {
                self.restore(&before);
                if depth >= fallbacks.max_halvings
                    || !self.solve_halves(solver, fallbacks, ts, half, depth + 1, pieces, last)?
                {
                    return Ok(false);
                }
            }
        }
        Ok(true)
    }

    /// The record of the step just taken, from the current state and `z`.
    fn record(
        &mut self,
        summary: Summary,
        converged: bool,
        solve_us: f64,
        method: StepMethod,
    ) -> StepRecord {
        let states: Vec<BodyState> = self.bodies.iter().map(|b| b.state).collect();
        let table = gaps_and_modes(
            &self
                .bodies
                .iter()
                .map(|b| (&b.spec.shape, b.state))
                .collect::<Vec<_>>(),
            &self.scene.planes,
        );
        let mut contacts = Vec::with_capacity(self.contacts.len());
        for c in &self.contacts {
            let (gap, mode) = table[c.body][c.plane];
            let a1 = self.get(c.a1);
            let a2 = self.get(c.a2);
            let pf = self.get(c.pf);
            contacts.push(ContactRecord {
                a1: Vector3::new(a1[0], a1[1], a1[2]) + self.origin,
                a2: Vector3::new(a2[0], a2[1], a2[2]) + self.origin,
                lg: self.get(c.lg)[0],
                pn: self.get(c.pn)[0],
                pt: pf[0],
                po: pf[1],
                pr: pf[2],
                sigma: self.get(c.sigma)[0],
                min_gap: gap,
                mode,
            });
        }
        let energy = self.energy();
        StepRecord {
            step: self.step,
            t: self.t,
            bodies: states,
            contacts,
            energy,
            summary,
            converged,
            solve_us,
            method,
        }
    }

    /// Kinetic plus potential energy (gravity) of all bodies in the current state.
    pub fn energy(&self) -> f64 {
        self.bodies
            .iter()
            .map(|b| body_energy(&b.spec.mass, &b.state, &self.scene.gravity))
            .sum()
    }

    /// Runs the remaining steps, calling `on_step` after each (outputs can be written as the run
    /// goes). Stops early when `on_step` returns `false`.
    pub fn run(
        &mut self,
        solver: &mut dyn McpSolver,
        mut on_step: impl FnMut(&StepRecord) -> bool,
    ) -> Result<usize, SceneError> {
        let mut failed = 0;
        while !self.finished() {
            let rec = self.step(solver)?;
            failed += usize::from(!rec.converged);
            if !on_step(&rec) {
                break;
            }
        }
        Ok(failed)
    }
}

impl Stepper for Simulation {
    fn formulation(&self) -> Formulation {
        self.formulation
    }
    fn scene(&self) -> &Scene {
        &self.scene
    }
    fn contacts_per_body(&self) -> usize {
        self.contacts.len() / self.bodies.len().max(1)
    }
    fn state(&self, b: usize) -> BodyState {
        self.bodies[b].state
    }
    fn steps_taken(&self) -> usize {
        self.step
    }
    fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        Simulation::step(self, solver)
    }
    fn step_with(
        &mut self,
        solver: &mut dyn McpSolver,
        fallbacks: &mut Fallbacks,
    ) -> Result<StepRecord, SceneError> {
        Simulation::step_with(self, solver, fallbacks)
    }
    fn supports_fallbacks(&self) -> bool {
        true
    }
}

/// The closest points of Conv(F) at pose `(x, r)` to the half-space: `a1` the centroid of the
/// hull's vertices nearest to G (a face centre, an edge midpoint or a vertex), the gap there,
/// and face multipliers `l ≥ 0` of the faces through `a1` with `Σ l_i n̂_i = −Rᵀ n_G` (the
/// closest-point condition C2 of the paper's KKT system), found as the non-negative
/// least-squares combination of at most three of those faces' normals. When no such
/// combination fits (rounding at a nearly parallel face), multiplier 1 on the face most
/// anti-parallel to `n_G`.
///
/// Only one face with multiplier 1 at a vertex or an edge leaves C2 unsatisfiable by the
/// multipliers the Fischer–Burmeister Newton matrix treats as active, which makes that matrix
/// singular at the warm start (measured on tossed boxes, docs/newton.md).
pub(crate) fn closest_point_guess(
    set: &ConvexHull,
    plane: &HalfSpace,
    x: &Vector3<f64>,
    r: &nalgebra::Matrix3<f64>,
) -> (Vector3<f64>, f64, Vec<f64>) {
    let ng = plane.normal();
    let dir_body = r.transpose() * (-ng);
    let verts = set.vertices();
    let gaps: Vec<f64> = verts.iter().map(|v| plane.value(&(x + r * v))).collect();
    let gmin = gaps.iter().copied().fold(f64::INFINITY, f64::min);
    let mut a1_body = Vector3::zeros();
    let mut count: f64 = 0.0;
    for (v, g) in verts.iter().zip(&gaps) {
        if *g <= gmin + 1e-6 {
            a1_body += v;
            count += 1.0;
        }
    }
    a1_body /= f64::max(count, 1.0);
    let a1 = x + r * a1_body;
    let mut l = vec![0.0; set.num_faces()];
    let size = verts
        .iter()
        .map(|v| v.norm())
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let through: Vec<usize> = set
        .faces()
        .iter()
        .enumerate()
        .filter(|(_, f)| f.value(&a1_body).abs() <= 1e-9 * size)
        .map(|(i, _)| i)
        .collect();
    match face_cone_multipliers(set, &through, &dir_body) {
        Some(best) => {
            for (i, li) in best {
                l[i] = li;
            }
        }
        None => l[set.most_aligned_face(&dir_body)] = 1.0,
    }
    (a1, gmin, l)
}

/// Non-negative `l` over at most three of the faces `through` with `Σ l_i n̂_i = dir` (to
/// 1e-9), the one with the fewest faces; `None` when there is none (or too many faces to try).
fn face_cone_multipliers(
    set: &ConvexHull,
    through: &[usize],
    dir: &Vector3<f64>,
) -> Option<Vec<(usize, f64)>> {
    if through.is_empty() || through.len() > 16 {
        return None;
    }
    let faces = set.faces();
    let k = through.len();
    let fits = |idx: &[usize]| -> Option<Vec<(usize, f64)>> {
        let cols: Vec<Vector3<f64>> = idx.iter().map(|&i| faces[i].normal).collect();
        let m = cols.len();
        // Normal equations of the m ≤ 3 columns.
        let mut a = nalgebra::DMatrix::<f64>::zeros(m, m);
        let mut b = nalgebra::DVector::<f64>::zeros(m);
        for p in 0..m {
            b[p] = cols[p].dot(dir);
            for q in 0..m {
                a[(p, q)] = cols[p].dot(&cols[q]);
            }
        }
        let sol = a.lu().solve(&b)?;
        if sol.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return None;
        }
        let fit: Vector3<f64> = cols.iter().zip(sol.iter()).map(|(c, s)| c * *s).sum();
        ((fit - dir).norm() <= 1e-9).then(|| idx.iter().copied().zip(sol.iter().copied()).collect())
    };
    for i in 0..k {
        if let Some(s) = fits(&[through[i]]) {
            return Some(s);
        }
    }
    for i in 0..k {
        for j in i + 1..k {
            if let Some(s) = fits(&[through[i], through[j]]) {
                return Some(s);
            }
        }
    }
    for i in 0..k {
        for j in i + 1..k {
            for m in j + 1..k {
                if let Some(s) = fits(&[through[i], through[j], through[m]]) {
                    return Some(s);
                }
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecp_model::Mcp;

    /// A 0.4 × 0.3 × 0.2 m box, 2 kg, tossed with spin, its lowest vertex 0.1 m above the
    /// ground (no other vertex as low: the closest feature of Conv(F) is a vertex).
    fn tossed_box() -> Scene {
        let axis = Vector3::new(0.3, -0.8, 0.5);
        let q = crate::rotation::quat_from_axis_angle(&axis, 0.9)
            .unwrap_or_else(|| panic!("non-zero axis"));
        let shape = Shape::cuboid(0.4, 0.3, 0.2).unwrap_or_else(|e| panic!("{e}"));
        let r = rotation_matrix(&q);
        let lowest = shape
            .vertices()
            .iter()
            .map(|v| (r * v).z)
            .fold(f64::INFINITY, f64::min);
        Scene {
            name: "toss".into(),
            bodies: vec![BodySpec {
                name: "box".into(),
                mass: MassProperties::solid_cuboid(2.0, 0.4, 0.3, 0.2)
                    .unwrap_or_else(|e| panic!("{e}")),
                shape,
                initial: BodyState {
                    x: Vector3::new(0.0, 0.0, 0.1 - lowest),
                    q,
                    v: Vector3::new(0.5, -0.3, 1.0),
                    w: Vector3::new(6.0, -4.0, 8.0),
                },
                load: Load::None,
            }],
            planes: vec![HalfSpace::ground()],
            friction: FrictionParams {
                mu: 0.5,
                e_t: 1.0,
                e_o: 1.0,
                e_r: 0.02,
            },
            gravity: Vector3::new(0.0, 0.0, -9.8),
            h: 0.007,
            duration: 0.1,
        }
    }

    /// The warm start of an open contact: the closest-point conditions C1–C4 hold at the
    /// predicted pose (C2 with the multipliers of the three faces through the lowest vertex),
    /// the friction rows vanish, and σ > 0.
    #[test]
    fn open_contact_warm_start_meets_the_closest_point_conditions() {
        let mut sim = Simulation::new(tossed_box()).unwrap_or_else(|e| panic!("{e}"));
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z = sim.z().to_vec();
        let mcp = sim.mcp();
        let mut f = vec![0.0; mcp.dim()];
        mcp.evaluate(&z, &mut f);
        let c = sim.contacts()[0];
        let l = &z[mcp.range(c.l)];
        assert_eq!(l.iter().filter(|v| **v > 0.0).count(), 3, "l = {l:?}");
        // C2 rows are paired with a2, C1 rows with a1; C3 and C4 rows with l and l_g.
        for (what, var) in [("C1", c.a1), ("C2", c.a2), ("friction", c.pf)] {
            for i in mcp.range(var) {
                assert!(
                    f[i].abs() <= 1e-12,
                    "{what}: {} = {:e}",
                    mcp.component_name(i),
                    f[i]
                );
            }
        }
        for i in mcp.range(c.l).chain(mcp.range(c.lg)) {
            // Complementarity: multiplier 0 or row 0, both non-negative.
            assert!(z[i] >= 0.0 && f[i] >= -1e-12 && (z[i] * f[i]).abs() <= 1e-12);
        }
        assert!(z[mcp.range(c.sigma)][0] > 0.0);
        // The closest point is the lowest vertex at the predicted pose.
        let (_, qv) = sim.body_vars(0);
        let q = &z[mcp.range(qv)];
        let x = Vector3::new(q[0], q[1], q[2]);
        let rq = quat_normalize(&Vector4::new(q[3], q[4], q[5], q[6]))
            .map(|q| rotation_matrix(&q))
            .unwrap_or_else(|| panic!("non-zero quaternion"));
        let lowest = sim
            .hull(0)
            .vertices()
            .iter()
            .map(|v| (x + rq * v).z)
            .fold(f64::INFINITY, f64::min);
        let a1 = &z[mcp.range(c.a1)];
        assert!(
            (a1[2] - lowest).abs() <= 1e-12,
            "a1 {a1:?}, lowest {lowest}"
        );
    }
}
