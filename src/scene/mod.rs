//! Scene files (TOML): everything a simulation needs — step settings, bodies with their
//! geometry, mass properties, initial state and applied loads, half-spaces, friction, and the
//! solver — in one human-written file. The format is documented in `docs/scene-format.md`.
//!
//! Loading checks everything before anything is simulated: unknown keys, wrong types, values
//! out of range (negative mass, μ < 0, h ≤ 0, NaN, an inertia that is not positive definite),
//! degenerate hulls, expressions that do not parse or are not finite at a step time, unknown
//! solver or formulation names, and bodies that start inside an obstacle. Each problem is an
//! [`InputError`] naming the file, the key and its line.
//!
//! ```
//! let text = r#"
//! [simulation]
//! h = 0.01
//! duration = 0.1
//! [friction]
//! mu = 0.3
//! e_r = 0.1
//! [[half_spaces]]
//! normal = [0, 0, 1]
//! [[bodies]]
//! mass = 10
//! inertia = "uniform"
//! position = [0, 0, 0.1]
//! velocity = [1, 0, 0]
//! [[bodies.pieces]]
//! box = [0.4, 0.4, 0.2]
//! "#;
//! let file = ecp::scene::parse_scene(text, "inline.toml".as_ref()).unwrap();
//! assert_eq!(file.scene.num_steps(), 10);
//! assert_eq!(file.scene.bodies[0].shape.vertices().len(), 8);
//! ```

mod expr;
mod locate;
mod mesh;
mod raw;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ecp_formulations::blocks::FrictionParams;
use ecp_formulations::bodies::overlap::RealPieces;
use ecp_formulations::geometry::{
    ConvexHull, ConvexPiece, GeometryError, HalfSpace, MassProperties, Shape, min_gap,
};
use ecp_formulations::rotation::{quat_from_rpy_deg, quat_normalize, rotation_matrix};
use ecp_formulations::world::{Motion, Obstacle, PairFriction, PoseFn, World};
use ecp_formulations::{BodySpec, BodyState, FormulationRegistry, Load, Scene, Simulation};
use nalgebra::{Matrix3, Vector3, Vector4, Vector6};

pub use expr::TimeExpression;
pub use locate::line_of;

use ecp_solvers::Registry;

use crate::backends::{DEFAULT_SOLVER, SolverConfig};
use crate::error::{InputError, InputErrorKind};
use raw::{RawBody, RawHalfSpace, RawLoad, RawMotion, RawPiece, RawScene};

/// The most steps a scene may ask for (`duration / h`).
pub const MAX_STEPS: usize = 100_000_000;

/// A loaded, validated scene file.
#[derive(Clone, Debug)]
pub struct SceneFile {
    /// Where it was read from.
    pub path: PathBuf,
    /// The physics: bodies, half-spaces, friction, gravity, step and duration.
    pub scene: Scene,
    /// `[solver]`: backend and settings.
    pub solver: SolverConfig,
    /// `simulation.formulation` (default `hull`): a name of
    /// [`FormulationRegistry::builtin`].
    pub formulation: String,
    /// The applied loads as written, per body: `(force, torque)` expressions.
    pub loads: Vec<Option<[TimeExpression; 6]>>,
}

/// Reads and validates the scene file at `path`; its `[solver] name` must be a built-in backend.
pub fn load_scene(path: &Path) -> std::result::Result<SceneFile, InputError> {
    load_scene_in(path, &Registry::builtin())
}

/// Reads and validates the scene file at `path`; its `[solver] name` must be a backend of
/// `registry` (which may hold a user's own backends).
pub fn load_scene_in(
    path: &Path,
    registry: &Registry,
) -> std::result::Result<SceneFile, InputError> {
    let text = std::fs::read_to_string(path).map_err(|e| InputError {
        file: Some(path.to_path_buf()),
        key: None,
        line: None,
        kind: InputErrorKind::FileMissing,
        message: format!(
            "cannot read the scene file ({e}); check the path (scene files are in scenes/, e.g. scenes/desk.toml)"
        ),
    })?;
    parse_scene_in(&text, path, registry)
}

/// Parses and validates scene text; `path` names the file in messages, and relative mesh paths
/// are resolved against its directory. The solver must be a built-in backend.
pub fn parse_scene(text: &str, path: &Path) -> std::result::Result<SceneFile, InputError> {
    parse_scene_in(text, path, &Registry::builtin())
}

/// As [`parse_scene`], with the solver looked up in `registry`.
pub fn parse_scene_in(
    text: &str,
    path: &Path,
    registry: &Registry,
) -> std::result::Result<SceneFile, InputError> {
    let cx = Context {
        doc: text,
        path,
        registry,
    };
    let raw: RawScene = toml::from_str(text).map_err(|e| cx.serde_error(&e))?;
    cx.build(raw)
}

/// Error context: the document and its path, and the backends a `[solver] name` may name.
struct Context<'a> {
    doc: &'a str,
    path: &'a Path,
    registry: &'a Registry,
}

type Result<T> = std::result::Result<T, InputError>;

impl Context<'_> {
    fn err(&self, kind: InputErrorKind, key: &str, message: impl Into<String>) -> InputError {
        InputError {
            file: Some(self.path.to_path_buf()),
            key: Some(key.to_string()),
            line: locate::line_of_key(self.doc, key),
            kind,
            message: message.into(),
        }
    }

    /// Classifies a serde/TOML error and finds its key and line.
    fn serde_error(&self, e: &toml::de::Error) -> InputError {
        let msg = e.message().trim().to_string();
        let syntax = toml::de::DeTable::parse(self.doc).is_err();
        let (kind, hint) = if syntax {
            (
                InputErrorKind::Syntax,
                "the file is not valid TOML; check quotes, brackets and `key = value` pairs",
            )
        } else if msg.starts_with("unknown field") {
            (
                InputErrorKind::UnknownKey,
                "remove the key or fix its spelling (docs/scene-format.md lists every key)",
            )
        } else if msg.starts_with("missing field") {
            (
                InputErrorKind::MissingKey,
                "add the key (docs/scene-format.md lists the required keys)",
            )
        } else {
            (
                InputErrorKind::WrongType,
                "give the value the type docs/scene-format.md states (numbers, [x, y, z] arrays, strings)",
            )
        };
        let span = e.span();
        let line = span.as_ref().map(|s| line_of(self.doc, s.start));
        let mut key = if syntax {
            None
        } else {
            span.as_ref()
                .and_then(|s| locate::key_at(self.doc, s.start))
        };
        // An unknown key's span covers the key itself; name it even at the top level.
        if key.is_none()
            && kind == InputErrorKind::UnknownKey
            && let Some(s) = &span
        {
            key = self.doc.get(s.clone()).map(|k| k.trim().to_string());
        }
        InputError {
            file: Some(self.path.to_path_buf()),
            key,
            line,
            kind,
            message: format!("{msg}; {hint}"),
        }
    }

    fn finite(&self, key: &str, v: f64) -> Result<f64> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err(
                InputErrorKind::InvalidValue,
                key,
                format!("{v} is not a finite number; give a finite value"),
            ))
        }
    }

    fn positive(&self, key: &str, v: f64, what: &str) -> Result<f64> {
        self.finite(key, v)?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(
                InputErrorKind::InvalidValue,
                key,
                format!("{what} must be > 0, got {v}"),
            ))
        }
    }

    fn vec3(&self, key: &str, v: [f64; 3]) -> Result<Vector3<f64>> {
        for (i, c) in v.iter().enumerate() {
            self.finite(key, *c).map_err(|mut e| {
                e.message = format!("component {i} is {c}; every component must be finite");
                e
            })?;
        }
        Ok(Vector3::from(v))
    }

    fn geometry(&self, key: &str, e: GeometryError) -> InputError {
        let kind = match e {
            GeometryError::InvalidMass { .. }
            | GeometryError::AsymmetricInertia { .. }
            | GeometryError::IndefiniteInertia { .. }
            | GeometryError::NonFinite { .. }
            | GeometryError::NonPositiveDimension { .. }
            | GeometryError::ZeroQuaternion { .. }
            | GeometryError::ZeroNormal => InputErrorKind::InvalidValue,
            _ => InputErrorKind::Geometry,
        };
        self.err(kind, key, e.to_string())
    }

    /// An orientation given as a quaternion `(w, x, y, z)` or as roll-pitch-yaw in degrees
    /// (`R = Rz(yaw) Ry(pitch) Rx(roll)`), or the identity.
    fn orientation(
        &self,
        key: &str,
        quat: Option<[f64; 4]>,
        rpy: Option<[f64; 3]>,
    ) -> Result<Vector4<f64>> {
        match (quat, rpy) {
            (Some(_), Some(_)) => Err(self.err(
                InputErrorKind::InvalidValue,
                &format!("{key}rpy_deg"),
                "both `orientation` and `rpy_deg` are given; keep one of them",
            )),
            (Some(q), None) => {
                let k = format!("{key}orientation");
                for c in q {
                    self.finite(&k, c)?;
                }
                quat_normalize(&Vector4::from(q)).ok_or_else(|| {
                    self.err(
                        InputErrorKind::InvalidValue,
                        &k,
                        "the quaternion (w, x, y, z) is zero; give e.g. [1, 0, 0, 0] for no rotation",
                    )
                })
            }
            (None, Some(r)) => {
                let v = self.vec3(&format!("{key}rpy_deg"), r)?;
                Ok(quat_from_rpy_deg(v.x, v.y, v.z))
            }
            (None, None) => Ok(Vector4::new(1.0, 0.0, 0.0, 0.0)),
        }
    }

    fn build(&self, raw: RawScene) -> Result<SceneFile> {
        let name = match raw.name {
            Some(n) if !n.trim().is_empty() => n,
            _ => self
                .path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("scene")
                .to_string(),
        };
        let sim = &raw.simulation;
        let h = self.positive("simulation.h", sim.h, "the step length h (s)")?;
        let duration = self.finite("simulation.duration", sim.duration)?;
        if duration < 0.0 {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                "simulation.duration",
                format!("the duration must be ≥ 0 s, got {duration}"),
            ));
        }
        // A typo such as h = 1e-10 must not turn into a run that never ends or an allocation
        // that aborts.
        let steps = duration / h;
        if steps > MAX_STEPS as f64 {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                "simulation.duration",
                format!(
                    "duration / h = {steps:.3e} steps, more than the {MAX_STEPS} a run may take; \
                     check the units of h and duration (seconds)"
                ),
            ));
        }
        let gravity = self.vec3(
            "simulation.gravity",
            sim.gravity.unwrap_or([0.0, 0.0, -9.8]),
        )?;
        let formulation = match &sim.formulation {
            Some(f) => FormulationRegistry::builtin().resolve(f).map_err(|m| {
                self.err(
                    InputErrorKind::UnknownName,
                    "simulation.formulation",
                    m.to_string(),
                )
            })?,
            None if raw
                .bodies
                .iter()
                .any(|b| b.kind.as_deref().is_some_and(|k| k != "dynamic"))
                || !raw.pair_friction.is_empty() =>
            {
                "bodies".to_string()
            }
            None => "hull".to_string(),
        };

        let fr = &raw.friction;
        let mu = self.finite("friction.mu", fr.mu)?;
        if mu < 0.0 {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                "friction.mu",
                format!("the friction coefficient μ must be ≥ 0, got {mu}"),
            ));
        }
        let friction = FrictionParams {
            mu,
            e_t: self.positive("friction.e_t", fr.e_t.unwrap_or(1.0), "e_t")?,
            e_o: self.positive("friction.e_o", fr.e_o.unwrap_or(1.0), "e_o")?,
            e_r: self.positive("friction.e_r", fr.e_r, "e_r (m)")?,
        };

        let solver = SolverConfig {
            name: match &raw.solver.name {
                Some(n) => self
                    .registry
                    .get(n)
                    .map(|b| b.name().to_string())
                    .map_err(|e| {
                        self.err(InputErrorKind::UnknownName, "solver.name", e.to_string())
                    })?,
                None => DEFAULT_SOLVER.to_string(),
            },
            tolerance: match raw.solver.tolerance {
                Some(t) => Some(self.positive("solver.tolerance", t, "the tolerance")?),
                None => None,
            },
            max_iterations: match raw.solver.max_iterations {
                Some(0) => {
                    return Err(self.err(
                        InputErrorKind::InvalidValue,
                        "solver.max_iterations",
                        "the iteration limit must be ≥ 1",
                    ));
                }
                m => m,
            },
        };

        let planes = raw
            .half_spaces
            .iter()
            .enumerate()
            .map(|(i, p)| self.half_space(i, p))
            .collect::<Result<Vec<_>>>()?;

        if raw.bodies.is_empty() {
            return Err(self.err(
                InputErrorKind::MissingKey,
                "bodies",
                "the scene has no body; add a [[bodies]] table (see docs/scene-format.md)",
            ));
        }
        let num_steps = (duration / h - 1e-9).ceil().max(0.0) as usize;
        let mut bodies = Vec::new();
        let mut body_keys = Vec::new();
        let mut loads = Vec::new();
        let mut obstacles = Vec::new();
        let mut materials = Vec::new();
        let mut names: Vec<(String, String)> = Vec::new();
        for (i, b) in raw.bodies.iter().enumerate() {
            let key = format!("bodies[{i}]");
            let kind = b.kind.as_deref().unwrap_or("dynamic");
            let name = b.name.clone().unwrap_or_else(|| format!("body{i}"));
            match kind {
                "dynamic" => {
                    let (body, load) = self.body(i, b, h, num_steps)?;
                    if let Some(m) = &b.material {
                        materials.push((body.name.clone(), m.clone()));
                    }
                    bodies.push(body);
                    body_keys.push(i);
                    loads.push(load);
                }
                "fixed" | "kinematic" => {
                    obstacles.push(self.obstacle(i, b, kind == "kinematic", h, num_steps)?);
                }
                other => {
                    return Err(self.err(
                        InputErrorKind::InvalidValue,
                        &format!("{key}.kind"),
                        format!(
                            "unknown body kind \"{other}\"; a body is \"dynamic\" (the default), \
                             \"fixed\" or \"kinematic\""
                        ),
                    ));
                }
            }
            names.push((name, format!("{key}.name")));
        }
        let mut plane_names = Vec::new();
        for (p, hs) in raw.half_spaces.iter().enumerate() {
            let name = hs.name.clone().unwrap_or_else(|| format!("half_space{p}"));
            names.push((name.clone(), format!("half_spaces[{p}].name")));
            plane_names.push(name);
        }
        for (i, (n, key)) in names.iter().enumerate() {
            if names[..i].iter().any(|(o, _)| o == n) {
                return Err(self.err(
                    InputErrorKind::InvalidValue,
                    key,
                    format!(
                        "two bodies are named \"{n}\" (bodies and half-spaces share one namespace); give each its own name"
                    ),
                ));
            }
        }
        if bodies.is_empty() {
            return Err(self.err(
                InputErrorKind::MissingKey,
                "bodies",
                "the scene has no dynamic body; add a [[bodies]] table without `kind` (or with \
                 kind = \"dynamic\"), see docs/scene-format.md",
            ));
        }
        for (i, b) in bodies.iter().enumerate() {
            let r = rotation_matrix(&b.initial.q);
            for (p, plane) in planes.iter().enumerate() {
                let gap = min_gap(b.shape.vertices(), &b.initial.x, &r, plane);
                if gap < -1e-9 {
                    return Err(self.err(
                        InputErrorKind::Geometry,
                        &format!("bodies[{}].position", body_keys[i]),
                        format!(
                            "body \"{}\" starts {:.3e} m inside half_spaces[{p}]; move it so that \
                             every vertex is on or above the plane",
                            b.name, -gap
                        ),
                    ));
                }
            }
        }
        let mut pair_friction = Vec::new();
        for (i, pf) in raw.pair_friction.iter().enumerate() {
            let key = format!("pair_friction[{i}]");
            for n in &pf.between {
                let known = names.iter().any(|(o, _)| o == n)
                    || materials.iter().any(|(_, m)| m == n)
                    || obstacles
                        .iter()
                        .any(|o: &Obstacle| o.material.as_deref() == Some(n));
                if !known {
                    let list: Vec<&str> = names.iter().map(|(o, _)| o.as_str()).collect();
                    return Err(self.err(
                        InputErrorKind::UnknownName,
                        &format!("{key}.between"),
                        format!(
                            "\"{n}\" is not a body, half-space or material of the scene; the names \
                             are {}",
                            list.join(", ")
                        ),
                    ));
                }
            }
            let mu = self.finite(&format!("{key}.mu"), pf.mu)?;
            if mu < 0.0 {
                return Err(self.err(
                    InputErrorKind::InvalidValue,
                    &format!("{key}.mu"),
                    format!("the friction coefficient μ must be ≥ 0, got {mu}"),
                ));
            }
            pair_friction.push(PairFriction {
                names: pf.between.clone(),
                friction: FrictionParams {
                    mu,
                    e_t: self.positive(
                        &format!("{key}.e_t"),
                        pf.e_t.unwrap_or(friction.e_t),
                        "e_t",
                    )?,
                    e_o: self.positive(
                        &format!("{key}.e_o"),
                        pf.e_o.unwrap_or(friction.e_o),
                        "e_o",
                    )?,
                    e_r: self.positive(
                        &format!("{key}.e_r"),
                        pf.e_r.unwrap_or(friction.e_r),
                        "e_r (m)",
                    )?,
                },
            });
        }
        let world = World {
            obstacles,
            plane_names,
            materials,
            pair_friction,
            bodies_touch: formulation == "bodies",
        };
        if world.is_multibody() && formulation != "bodies" {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                "simulation.formulation",
                format!(
                    "the scene has fixed or kinematic bodies or friction per pair, which the \
                     {formulation} formulation does not model; use formulation = \"bodies\""
                ),
            ));
        }

        let scene = Scene {
            name,
            bodies,
            planes,
            friction,
            gravity,
            h,
            duration,
            world,
        };
        if scene.world.is_multibody() {
            let states: Vec<BodyState> = scene.bodies.iter().map(|b| b.initial).collect();
            if let Some(o) = RealPieces::of(&scene).deepest_overlap(&scene, &states, 0.0, 1e-9) {
                let i = scene.bodies.iter().position(|b| b.name == o.a).unwrap_or(0);
                return Err(self.err(
                    InputErrorKind::Geometry,
                    &format!("bodies[{}].position", body_keys[i]),
                    format!(
                        "bodies \"{}\" and \"{}\" overlap by {:.3e} m at the start; move them \
                         apart so that they at most touch",
                        o.a, o.b, o.depth
                    ),
                ));
            }
        }
        // Anything the stepper still refuses is reported against the file.
        Simulation::new(scene.clone()).map_err(|e| InputError {
            file: Some(self.path.to_path_buf()),
            key: None,
            line: None,
            kind: InputErrorKind::InvalidValue,
            message: e.to_string(),
        })?;
        Ok(SceneFile {
            path: self.path.to_path_buf(),
            scene,
            solver,
            formulation,
            loads,
        })
    }

    fn half_space(&self, i: usize, p: &RawHalfSpace) -> Result<HalfSpace> {
        let key = format!("half_spaces[{i}]");
        match (p.normal, p.incline_deg) {
            (Some(n), None) => {
                let n = self.vec3(&format!("{key}.normal"), n)?;
                let offset = self.finite(&format!("{key}.offset"), p.offset.unwrap_or(0.0))?;
                HalfSpace::new(n, offset).map_err(|e| self.geometry(&format!("{key}.normal"), e))
            }
            (None, Some(deg)) => {
                if p.offset.is_some() {
                    return Err(self.err(
                        InputErrorKind::InvalidValue,
                        &format!("{key}.offset"),
                        "an incline passes through the origin; remove `offset` or give `normal` and `offset` instead",
                    ));
                }
                let deg = self.finite(&format!("{key}.incline_deg"), deg)?;
                HalfSpace::incline(deg.to_radians())
                    .map_err(|e| self.geometry(&format!("{key}.incline_deg"), e))
            }
            (Some(_), Some(_)) => Err(self.err(
                InputErrorKind::InvalidValue,
                &format!("{key}.incline_deg"),
                "give either `normal` (and `offset`) or `incline_deg`, not both",
            )),
            (None, None) => Err(self.err(
                InputErrorKind::MissingKey,
                &key,
                "a half-space needs `normal = [x, y, z]` (and `offset`, default 0) or `incline_deg`",
            )),
        }
    }

    /// A fixed or kinematic body (`kind = "fixed"` or `"kinematic"`): pieces, pose at t = 0
    /// and, for a kinematic body, its schedule (`[bodies.motion]`).
    fn obstacle(
        &self,
        i: usize,
        b: &RawBody,
        kinematic: bool,
        h: f64,
        num_steps: usize,
    ) -> Result<Obstacle> {
        let key = format!("bodies[{i}]");
        let kind = if kinematic { "kinematic" } else { "fixed" };
        let refuse = |field: &str, why: &str| {
            Err(self.err(
                InputErrorKind::InvalidValue,
                &format!("{key}.{field}"),
                format!("a {kind} body has no `{field}` ({why}); remove it"),
            ))
        };
        if b.mass.is_some() {
            return refuse("mass", "contact does not move it");
        }
        if b.inertia.is_some() {
            return refuse("inertia", "contact does not move it");
        }
        if b.load.is_some() {
            return refuse("load", "contact and loads do not move it");
        }
        if b.velocity.is_some() || b.angular_velocity.is_some() {
            return refuse(
                "velocity",
                "a kinematic body's velocity is its [bodies.motion] schedule",
            );
        }
        if b.pieces.is_empty() {
            return Err(self.err(
                InputErrorKind::MissingKey,
                &format!("{key}.pieces"),
                "a body needs at least one [[bodies.pieces]] (a box, a point set or a mesh)",
            ));
        }
        let pieces = b
            .pieces
            .iter()
            .enumerate()
            .map(|(j, p)| self.piece(&format!("{key}.pieces[{j}]"), p))
            .collect::<Result<Vec<_>>>()?;
        let shape =
            Shape::from_pieces(pieces).map_err(|e| self.geometry(&format!("{key}.pieces"), e))?;
        shape
            .hull()
            .map_err(|e| self.geometry(&format!("{key}.pieces"), e))?;
        let x = self.vec3(&format!("{key}.position"), b.position)?;
        let q = self.orientation(&format!("{key}."), b.orientation, b.rpy_deg)?;
        let motion = match (&b.motion, kinematic) {
            (None, false) => Motion::Fixed { x, q },
            (Some(_), false) => {
                return refuse("motion", "it never moves; use kind = \"kinematic\"");
            }
            (None, true) => {
                return Err(self.err(
                    InputErrorKind::MissingKey,
                    &format!("{key}.motion"),
                    "a kinematic body needs a schedule: [bodies.motion] with `velocity` and/or \
                     `angular_velocity` (constant, world frame), or `displacement` and/or \
                     `rpy_deg` as expressions of t (docs/scene-format.md#kinematic-bodies)",
                ));
            }
            (Some(m), true) => self.motion(&format!("{key}.motion"), m, x, q, h, num_steps)?,
        };
        Ok(Obstacle {
            name: b.name.clone().unwrap_or_else(|| format!("body{i}")),
            shape,
            motion,
            material: b.material.clone(),
        })
    }

    /// A kinematic body's schedule: constant velocities, or a displacement and roll-pitch-yaw
    /// angles as expressions of `t` (checked finite at every step time).
    fn motion(
        &self,
        key: &str,
        m: &RawMotion,
        x0: Vector3<f64>,
        q0: Vector4<f64>,
        h: f64,
        num_steps: usize,
    ) -> Result<Motion> {
        let velocities = m.velocity.is_some() || m.angular_velocity.is_some();
        let expressions = m.displacement.is_some() || m.rpy_deg.is_some();
        match (velocities, expressions) {
            (true, true) => Err(self.err(
                InputErrorKind::InvalidValue,
                key,
                "give either `velocity`/`angular_velocity` or `displacement`/`rpy_deg`, not both",
            )),
            (false, false) => Err(self.err(
                InputErrorKind::MissingKey,
                key,
                "the schedule is empty; give `velocity`, `angular_velocity`, `displacement` or \
                 `rpy_deg`",
            )),
            (true, false) => Ok(Motion::Velocity {
                x0,
                q0,
                v: self.vec3(&format!("{key}.velocity"), m.velocity.unwrap_or([0.0; 3]))?,
                w: self.vec3(
                    &format!("{key}.angular_velocity"),
                    m.angular_velocity.unwrap_or([0.0; 3]),
                )?,
            }),
            (false, true) => {
                let parse = |field: &str, values: &Option<Vec<toml::Value>>| {
                    let k = format!("{key}.{field}");
                    let Some(values) = values else {
                        return Ok(std::array::from_fn(|_| TimeExpression::constant(0.0)));
                    };
                    if values.len() != 3 {
                        return Err(self.err(
                            InputErrorKind::WrongType,
                            &k,
                            format!("{field} needs 3 components, got {}", values.len()),
                        ));
                    }
                    let mut out: [TimeExpression; 3] =
                        std::array::from_fn(|_| TimeExpression::constant(0.0));
                    for (c, v) in values.iter().enumerate() {
                        let e = match v {
                            toml::Value::Float(f) => TimeExpression::constant(self.finite(&k, *f)?),
                            toml::Value::Integer(i) => TimeExpression::constant(*i as f64),
                            toml::Value::String(s) => TimeExpression::parse(s)
                                .map_err(|m| self.err(InputErrorKind::Expression, &k, m))?,
                            other => {
                                return Err(self.err(
                                    InputErrorKind::WrongType,
                                    &k,
                                    format!(
                                        "component {c} is a {}; give a number or a string such \
                                         as \"0.01*sin(2*pi*20*t)\"",
                                        other.type_str()
                                    ),
                                ));
                            }
                        };
                        for step in 0..=num_steps {
                            let t = step as f64 * h;
                            if !e.eval(t).is_finite() {
                                return Err(self.err(
                                    InputErrorKind::Expression,
                                    &k,
                                    format!(
                                        "component {c} = \"{}\" is not finite at t = {t} s",
                                        e.source()
                                    ),
                                ));
                            }
                        }
                        out[c] = e;
                    }
                    Ok(out)
                };
                let d = parse("displacement", &m.displacement)?;
                let a = parse("rpy_deg", &m.rpy_deg)?;
                let pose: PoseFn = Arc::new(move |t: f64| {
                    let dx = Vector3::new(d[0].eval(t), d[1].eval(t), d[2].eval(t));
                    let r = quat_from_rpy_deg(a[0].eval(t), a[1].eval(t), a[2].eval(t));
                    (x0 + dx, ecp_formulations::rotation::quat_mul(&r, &q0))
                });
                Ok(Motion::Pose(pose))
            }
        }
    }

    fn body(
        &self,
        i: usize,
        b: &RawBody,
        h: f64,
        num_steps: usize,
    ) -> Result<(BodySpec, Option<[TimeExpression; 6]>)> {
        let key = format!("bodies[{i}]");
        let name = b.name.clone().unwrap_or_else(|| format!("body{i}"));
        let mass = b.mass.ok_or_else(|| {
            self.err(
                InputErrorKind::MissingKey,
                &key,
                "missing field `mass`; a dynamic body needs `mass` (kg) and `inertia`",
            )
        })?;
        let mass = self.positive(&format!("{key}.mass"), mass, "the mass (kg)")?;
        let inertia = b.inertia.as_ref().ok_or_else(|| {
            self.err(
                InputErrorKind::MissingKey,
                &key,
                "missing field `inertia`; give \"uniform\", [Ixx, Iyy, Izz] or a 3×3 matrix",
            )
        })?;
        if b.motion.is_some() {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                &format!("{key}.motion"),
                "a dynamic body moves by the dynamics; `motion` is for kind = \"kinematic\"",
            ));
        }
        if b.pieces.is_empty() {
            return Err(self.err(
                InputErrorKind::MissingKey,
                &format!("{key}.pieces"),
                "a body needs at least one [[bodies.pieces]] (a box, a point set or a mesh)",
            ));
        }
        let mut pieces = b
            .pieces
            .iter()
            .enumerate()
            .map(|(j, p)| self.piece(&format!("{key}.pieces[{j}]"), p))
            .collect::<Result<Vec<_>>>()?;
        let inertia_key = format!("{key}.inertia");
        let mass_props = match inertia {
            toml::Value::String(s) if s == "uniform" => {
                let boxes = pieces
                    .iter()
                    .map(|p| match p {
                        ConvexPiece::Cuboid {
                            half_extents,
                            center,
                            orientation,
                        } if orientation.fixed_rows::<3>(1).norm()
                            <= 1e-15 * orientation.norm() =>
                        {
                            Some((*half_extents, *center))
                        }
                        _ => None,
                    })
                    .collect::<Option<Vec<_>>>()
                    .ok_or_else(|| {
                        self.err(
                            InputErrorKind::InvalidValue,
                            &inertia_key,
                            "inertia = \"uniform\" is computed for unrotated, non-overlapping box \
                             pieces only; give the inertia about the CM as three principal moments \
                             [Ixx, Iyy, Izz] or a 3×3 matrix",
                        )
                    })?;
                let (props, cm) = MassProperties::uniform_cuboids(mass, &boxes)
                    .map_err(|e| self.geometry(&inertia_key, e))?;
                // The body frame's origin is the CM: re-express the pieces about it.
                for p in &mut pieces {
                    if let ConvexPiece::Cuboid { center, .. } = p {
                        *center -= cm;
                    }
                }
                props
            }
            value => {
                let m = self.inertia_matrix(&inertia_key, value)?;
                MassProperties::new(mass, m).map_err(|e| self.geometry(&inertia_key, e))?
            }
        };
        let shape =
            Shape::from_pieces(pieces).map_err(|e| self.geometry(&format!("{key}.pieces"), e))?;
        shape
            .hull()
            .map_err(|e| self.geometry(&format!("{key}.pieces"), e))?;
        let initial = BodyState {
            x: self.vec3(&format!("{key}.position"), b.position)?,
            q: self.orientation(&format!("{key}."), b.orientation, b.rpy_deg)?,
            v: self.vec3(&format!("{key}.velocity"), b.velocity.unwrap_or([0.0; 3]))?,
            w: self.vec3(
                &format!("{key}.angular_velocity"),
                b.angular_velocity.unwrap_or([0.0; 3]),
            )?,
        };
        let (load, exprs) = match &b.load {
            Some(l) => self.load(&format!("{key}.load"), l, h, num_steps)?,
            None => (Load::None, None),
        };
        Ok((
            BodySpec {
                name,
                mass: mass_props,
                shape,
                initial,
                load,
            },
            exprs,
        ))
    }

    fn inertia_matrix(&self, key: &str, value: &toml::Value) -> Result<Matrix3<f64>> {
        let wrong = || {
            self.err(
                InputErrorKind::WrongType,
                key,
                "give the inertia about the CM (kg m²) as three principal moments [Ixx, Iyy, Izz], \
                 a 3×3 matrix [[..], [..], [..]], or the string \"uniform\" (uniform density over box pieces)",
            )
        };
        let num = |v: &toml::Value| match v {
            toml::Value::Float(f) => Some(*f),
            toml::Value::Integer(i) => Some(*i as f64),
            _ => None,
        };
        let toml::Value::Array(rows) = value else {
            return Err(wrong());
        };
        let m = if rows.len() == 3 && rows.iter().all(|r| num(r).is_some()) {
            let d: Vec<f64> = rows.iter().filter_map(num).collect();
            Matrix3::from_diagonal(&Vector3::new(d[0], d[1], d[2]))
        } else if rows.len() == 3 {
            let mut m = Matrix3::zeros();
            for (r, row) in rows.iter().enumerate() {
                let toml::Value::Array(cols) = row else {
                    return Err(wrong());
                };
                if cols.len() != 3 {
                    return Err(wrong());
                }
                for (c, v) in cols.iter().enumerate() {
                    m[(r, c)] = num(v).ok_or_else(wrong)?;
                }
            }
            m
        } else {
            return Err(wrong());
        };
        if m.iter().any(|x| !x.is_finite()) {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                key,
                "the inertia has a NaN or infinite entry; give finite moments in kg m²",
            ));
        }
        Ok(m)
    }

    fn piece(&self, key: &str, p: &RawPiece) -> Result<ConvexPiece> {
        let center = self.vec3(&format!("{key}.center"), p.center.unwrap_or([0.0; 3]))?;
        let q = self.orientation(&format!("{key}."), p.orientation, p.rpy_deg)?;
        let given = [p.cuboid.is_some(), p.points.is_some(), p.mesh.is_some()];
        if given.iter().filter(|&&g| g).count() != 1 {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                key,
                "a piece is exactly one of `box = [lx, ly, lz]`, `points = [[x, y, z], ...]` or \
                 `mesh = \"file.obj\"`",
            ));
        }
        if p.scale.is_some() && p.mesh.is_none() {
            return Err(self.err(
                InputErrorKind::InvalidValue,
                &format!("{key}.scale"),
                "`scale` applies to meshes only; remove it",
            ));
        }
        if let Some(size) = p.cuboid {
            let k = format!("{key}.box");
            let size = self.vec3(&k, size)?;
            if let Some(bad) = size.iter().find(|&&l| l <= 0.0) {
                return Err(self.err(
                    InputErrorKind::InvalidValue,
                    &k,
                    format!("the box's edge lengths must be > 0 m, got {bad}"),
                ));
            }
            return Ok(ConvexPiece::Cuboid {
                half_extents: size / 2.0,
                center,
                orientation: q,
            });
        }
        let (points, k) = if let Some(points) = &p.points {
            let k = format!("{key}.points");
            let pts = points
                .iter()
                .map(|pt| self.vec3(&k, *pt))
                .collect::<Result<Vec<_>>>()?;
            (pts, k)
        } else {
            let k = format!("{key}.mesh");
            let file = p.mesh.as_deref().unwrap_or_default();
            let resolved = self.path.parent().unwrap_or(Path::new(".")).join(file);
            let scale = self.positive(&format!("{key}.scale"), p.scale.unwrap_or(1.0), "scale")?;
            let pts = mesh::read_mesh_vertices(&resolved)
                .map_err(|m| self.err(InputErrorKind::Mesh, &k, m))?;
            (pts.into_iter().map(|v| v * scale).collect(), k)
        };
        let r = rotation_matrix(&q);
        let points: Vec<Vector3<f64>> = points.iter().map(|v| center + r * v).collect();
        if p.mesh.is_some() {
            // A mesh may have 10⁶ vertices: keep only its hull's extreme vertices, once, so that
            // the shape and every step work with those (the hull is the same).
            let hull = ConvexHull::from_points(&points).map_err(|e| self.geometry(&k, e))?;
            return Ok(ConvexPiece::Points(hull.vertices().to_vec()));
        }
        let piece = ConvexPiece::Points(points);
        piece.validate().map_err(|e| self.geometry(&k, e))?;
        Ok(piece)
    }

    /// `force` and `torque` (world frame, at the CM): three numbers or expressions of `t` each.
    /// Expressions are parsed once and checked finite at every step time.
    fn load(
        &self,
        key: &str,
        l: &RawLoad,
        h: f64,
        num_steps: usize,
    ) -> Result<(Load, Option<[TimeExpression; 6]>)> {
        let mut ex: [TimeExpression; 6] = std::array::from_fn(|_| TimeExpression::constant(0.0));
        for (part, values, offset) in [("force", &l.force, 0), ("torque", &l.torque, 3)] {
            let Some(values) = values else { continue };
            let k = format!("{key}.{part}");
            if values.len() != 3 {
                return Err(self.err(
                    InputErrorKind::WrongType,
                    &k,
                    format!(
                        "{part} needs 3 components (x, y, z), got {}; each is a number or a string expression of t",
                        values.len()
                    ),
                ));
            }
            for (c, v) in values.iter().enumerate() {
                ex[offset + c] = match v {
                    toml::Value::Float(f) => TimeExpression::constant(self.finite(&k, *f)?),
                    toml::Value::Integer(i) => TimeExpression::constant(*i as f64),
                    toml::Value::String(s) => TimeExpression::parse(s)
                        .map_err(|m| self.err(InputErrorKind::Expression, &k, m))?,
                    other => {
                        return Err(self.err(
                            InputErrorKind::WrongType,
                            &k,
                            format!(
                                "component {c} is a {}; give a number or a string such as \"2*sin(pi*t)\"",
                                other.type_str()
                            ),
                        ));
                    }
                };
            }
        }
        // Loads are evaluated at the start of each step, t = k h; check them all now so that a
        // singular expression is bad input, not a failed run.
        for (c, e) in ex.iter().enumerate() {
            let steps = if e.is_constant() { 1 } else { num_steps.max(1) };
            for k in 0..steps {
                let t = k as f64 * h;
                let v = e.eval(t);
                if !v.is_finite() {
                    let part = if c < 3 { "force" } else { "torque" };
                    return Err(self.err(
                        InputErrorKind::Expression,
                        &format!("{key}.{part}"),
                        format!(
                            "component {} = \"{}\" is {v} at t = {t} s (step {}); loads must be finite at every step time",
                            c % 3,
                            e.source(),
                            k + 1
                        ),
                    ));
                }
            }
        }
        if ex.iter().all(|e| e.is_constant()) {
            let w = Vector6::from_iterator(ex.iter().map(|e| e.eval(0.0)));
            let load = if w.iter().all(|&x| x == 0.0) {
                Load::None
            } else {
                Load::Constant(w)
            };
            return Ok((load, Some(ex)));
        }
        let shared = ex.clone();
        let f = Arc::new(move |t: f64| Vector6::from_iterator(shared.iter().map(|e| e.eval(t))));
        Ok((Load::Function(f), Some(ex)))
    }
}

/// A human-readable account of what a scene file builds (for `ecp check`): settings, bodies with
/// mass properties, pieces, hull faces and initial contact, half-spaces, contacts and loads.
pub fn describe(file: &SceneFile) -> String {
    use std::fmt::Write;
    let s = &file.scene;
    let mut out = String::new();
    let v3 = |v: &Vector3<f64>| format!("({:.6}, {:.6}, {:.6})", v.x, v.y, v.z);
    // Writing to a String cannot fail; the results are ignored on purpose.
    let _ = writeln!(out, "scene \"{}\" from {}", s.name, file.path.display());
    let _ = writeln!(
        out,
        "  h = {} s, duration = {} s ({} steps), gravity = {}",
        s.h,
        s.duration,
        s.num_steps(),
        v3(&s.gravity)
    );
    let _ = writeln!(
        out,
        "  formulation {}, solver {} (tolerance {}, max iterations {})",
        file.formulation,
        file.solver.name,
        file.solver
            .tolerance
            .map_or("default".to_string(), |t| format!("{t:e}")),
        file.solver
            .max_iterations
            .map_or("default".to_string(), |m| m.to_string())
    );
    let f = &s.friction;
    let _ = writeln!(
        out,
        "  friction: mu = {}, e_t = {}, e_o = {}, e_r = {} m",
        f.mu, f.e_t, f.e_o, f.e_r
    );
    let _ = writeln!(out, "half-spaces: {}", s.planes.len());
    for (i, p) in s.planes.iter().enumerate() {
        let _ = writeln!(
            out,
            "  [{i}] normal {} . p <= {}",
            v3(&p.normal()),
            p.offset()
        );
    }
    let _ = writeln!(out, "bodies: {}", s.bodies.len());
    for (i, b) in s.bodies.iter().enumerate() {
        let m = &b.mass;
        let _ = writeln!(out, "  [{i}] \"{}\": mass {} kg", b.name, m.mass);
        for r in 0..3 {
            let _ = writeln!(
                out,
                "      inertia row {r}: [{:.6}, {:.6}, {:.6}] kg m^2",
                m.inertia[(r, 0)],
                m.inertia[(r, 1)],
                m.inertia[(r, 2)]
            );
        }
        let _ = writeln!(
            out,
            "      pieces: {} ({} vertices of the real body)",
            b.shape.pieces().len(),
            b.shape.vertices().len()
        );
        for (j, p) in b.shape.pieces().iter().enumerate() {
            let desc = match p {
                ConvexPiece::Cuboid {
                    half_extents,
                    center,
                    ..
                } => format!(
                    "box {} centred at {}",
                    v3(&(half_extents * 2.0)),
                    v3(center)
                ),
                ConvexPiece::Points(pts) => {
                    format!("convex point set, {} extreme points", pts.len())
                }
            };
            let _ = writeln!(out, "        piece {j}: {desc}");
        }
        match b.shape.hull() {
            Ok(hull) => {
                let _ = writeln!(
                    out,
                    "      hull: {} vertices, {} faces, volume {:.6} m^3",
                    hull.vertices().len(),
                    hull.num_faces(),
                    hull.volume()
                );
                for (k, face) in hull.faces().iter().enumerate() {
                    let _ = writeln!(
                        out,
                        "        face {k}: normal {} offset {:.6} ({} corners)",
                        v3(&face.normal),
                        face.offset,
                        face.vertices.len()
                    );
                }
            }
            Err(e) => {
                let _ = writeln!(out, "      hull: {e}");
            }
        }
        let st = &b.initial;
        let _ = writeln!(
            out,
            "      initial: position {}, orientation ({:.6}, {:.6}, {:.6}, {:.6}), velocity {}, angular velocity {}",
            v3(&st.x),
            st.q[0],
            st.q[1],
            st.q[2],
            st.q[3],
            v3(&st.v),
            v3(&st.w)
        );
        let r = rotation_matrix(&st.q);
        let world = ecp_formulations::geometry::world_vertices(b.shape.vertices(), &st.x, &r);
        for (p, plane) in s.planes.iter().enumerate() {
            let gap = min_gap(b.shape.vertices(), &st.x, &r, plane);
            let mode = ecp_formulations::geometry::contact_mode(
                &world,
                plane,
                ecp_formulations::MODE_TOLERANCE,
            );
            let _ = writeln!(
                out,
                "      contact with half-space {p}: initial gap {gap:.6e} m, mode {mode}"
            );
        }
        match file.loads.get(i).and_then(|l| l.as_ref()) {
            Some(ex) => {
                let src: Vec<&str> = ex.iter().map(TimeExpression::source).collect();
                let _ = writeln!(
                    out,
                    "      load (world frame, at the CM): force [{}], torque [{}]",
                    src[..3].join(", "),
                    src[3..].join(", ")
                );
            }
            None => {
                let _ = writeln!(out, "      load: none");
            }
        }
    }
    if file.formulation == "bodies" {
        describe_pairs(s, &mut out);
    } else {
        let _ = writeln!(
            out,
            "contacts: {} (each body against each half-space)",
            s.bodies.len() * s.planes.len()
        );
    }
    let _ = writeln!(out, "ok: the scene is valid");
    out
}

/// The fixed and kinematic bodies, and the pairs the multi-body formulation watches: every
/// dynamic body against every other body and half-space (the overlap check at every step end),
/// with those that have a contact set at t = 0 and their friction.
fn describe_pairs(s: &Scene, out: &mut String) {
    use std::fmt::Write;
    for o in &s.world.obstacles {
        let (x, _) = o.pose_at(0.0);
        let kind = if o.is_fixed() { "fixed" } else { "kinematic" };
        let _ = writeln!(
            out,
            "  {kind} body \"{}\" at ({:.6}, {:.6}, {:.6}), {} pieces",
            o.name,
            x.x,
            x.y,
            x.z,
            o.shape.pieces().len()
        );
    }
    let active: Vec<(String, String)> = match Simulation::with_formulation(s.clone(), "bodies") {
        Ok(sim) => sim
            .formulation_as::<ecp_formulations::bodies::MultiBody>()
            .map(|m| {
                m.pairs()
                    .iter()
                    .map(|k| {
                        let b = match k.g {
                            ecp_formulations::bodies::pairs::Partner::Plane(p) => {
                                s.world.plane_name(p)
                            }
                            ecp_formulations::bodies::pairs::Partner::Body(b) => {
                                s.bodies[b].name.clone()
                            }
                            ecp_formulations::bodies::pairs::Partner::Obstacle(o) => {
                                s.world.obstacles[o].name.clone()
                            }
                        };
                        (s.bodies[k.f].name.clone(), b)
                    })
                    .collect()
            })
            .unwrap_or_default(),
        Err(_) => Vec::new(),
    };
    let mut watched = Vec::new();
    for (f, body) in s.bodies.iter().enumerate() {
        let others = (0..s.planes.len())
            .map(|p| s.world.plane_name(p))
            .chain(s.bodies[..f].iter().map(|b| b.name.clone()))
            .chain(s.world.obstacles.iter().map(|o| o.name.clone()));
        for other in others {
            watched.push((body.name.clone(), other));
        }
    }
    let _ = writeln!(
        out,
        "contacts: {} contact sets at t = 0 (a pair gets one when it can touch within the \
         step); pairs watched for overlap at every step end: {}",
        active.len(),
        watched.len()
    );
    for (a, b) in &watched {
        let fr = s.world.friction_between(a, b, &s.friction);
        let set = if active.contains(&(a.clone(), b.clone())) {
            "contact set at t = 0"
        } else {
            "apart at t = 0"
        };
        let _ = writeln!(out, "  {a} – {b}: μ = {}, {set}", fr.mu);
    }
}
