//! What a simulation is given (`docs/model.md#conventions`): the bodies with their mass
//! properties, shapes, initial states and loads, the fixed half-spaces, friction, gravity and the
//! step; the errors of setting it up, and the checks every formulation shares.

use std::sync::Arc;

use nalgebra::{Vector3, Vector4, Vector6};

use crate::blocks::FrictionParams;
use crate::geometry::{GeometryError, HalfSpace, MassProperties, Shape, min_gap};
use crate::rotation::{quat_normalize, rotation_matrix};
use crate::world::World;

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
    /// Fixed and kinematic bodies, half-space names, friction per pair
    /// (`docs/model.md#bodies-touching-bodies`); empty for a scene of dynamic bodies on
    /// half-spaces.
    pub world: World,
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
        /// The formulation's name.
        formulation: String,
        /// The step at which it stopped applying (`None`: the scene as given).
        step: Option<usize>,
        /// Why, and what to do instead.
        reason: String,
    },
    /// Two real bodies overlap at the end of a step (or at the start of the simulation): a
    /// contact the step problem should have had was left out, or the scene starts in an
    /// overlap (`docs/model.md#which-pairs`).
    #[error(
        "bodies '{a}' and '{b}' overlap by {depth:.3e} m {at}; {hint}",
        at = step.map(|s| format!("at the end of step {s}")).unwrap_or_else(|| "at the start".into())
    )]
    Overlap {
        /// One body (dynamic).
        a: String,
        /// The other body or half-space.
        b: String,
        /// Penetration depth (m).
        depth: f64,
        /// The step (`None`: the initial state).
        step: Option<usize>,
        /// What to do.
        hint: &'static str,
    },
    /// The modelling layer rejected the problem.
    #[error("model: {0}")]
    Model(#[from] ecp_model::ModelError),
}

/// The scene checks every formulation shares: step, duration, friction (`e_r` only when the
/// formulation has torsional friction) and gravity; and a scene with fixed or kinematic bodies,
/// pair friction or touching bodies is refused (only the multi-body formulation models them,
/// [`validate_scene_parameters`]).
pub fn validate_parameters(scene: &Scene, torsion: bool) -> Result<(), SceneError> {
    if scene.world.is_multibody() {
        return Err(SceneError::NotApplicable {
            formulation: "chosen".into(),
            step: None,
            reason: "the scene has fixed or kinematic bodies, friction per pair or bodies that \
                     touch each other, which only the `bodies` formulation models; set \
                     simulation.formulation = \"bodies\" (or --formulation bodies)"
                .into(),
        });
    }
    validate_scene_parameters(scene, torsion)
}

/// [`validate_parameters`] without the refusal of multi-body scenes, and with every pair
/// friction checked.
pub fn validate_scene_parameters(scene: &Scene, torsion: bool) -> Result<(), SceneError> {
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
    let pairs = scene.world.pair_friction.iter().map(|p| p.friction);
    let mut checks = Vec::new();
    for f in std::iter::once(scene.friction).chain(pairs) {
        checks.extend([
            ("mu", f.mu, false),
            ("e_t", f.e_t, true),
            ("e_o", f.e_o, true),
        ]);
        if torsion {
            checks.push(("e_r", f.e_r, true));
        }
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

/// The bodies' states at t = 0: the scene's initial states with each quaternion normalised.
pub fn initial_states(scene: &Scene) -> Result<Vec<BodyState>, SceneError> {
    scene
        .bodies
        .iter()
        .map(|spec| {
            let q = quat_normalize(&spec.initial.q).ok_or_else(|| SceneError::Parameter {
                what: format!("{}.orientation", spec.name),
                value: 0.0,
                hint: "the initial quaternion must be non-zero",
            })?;
            Ok(BodyState { q, ..spec.initial })
        })
        .collect()
}

/// Refuses a body of `scene` that starts more than `tolerance` (m) inside a half-space.
pub fn check_penetration(
    scene: &Scene,
    states: &[BodyState],
    tolerance: f64,
) -> Result<(), SceneError> {
    for (spec, state) in scene.bodies.iter().zip(states) {
        check_body_penetration(spec, state, &scene.planes, tolerance)?;
    }
    Ok(())
}

/// Refuses body `spec` at `state` when it is more than `tolerance` (m) inside one of `planes`.
pub fn check_body_penetration(
    spec: &BodySpec,
    state: &BodyState,
    planes: &[HalfSpace],
    tolerance: f64,
) -> Result<(), SceneError> {
    let r = rotation_matrix(&state.q);
    for (p, plane) in planes.iter().enumerate() {
        let gap = min_gap(spec.shape.vertices(), &state.x, &r, plane);
        if gap < -tolerance {
            return Err(SceneError::InitialPenetration {
                body: spec.name.clone(),
                plane: p,
                depth: -gap,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(initial: BodyState) -> Scene {
        let shape = Shape::cuboid(0.2, 0.2, 0.2).unwrap_or_else(|e| panic!("{e}"));
        Scene {
            name: "cube".into(),
            bodies: vec![BodySpec {
                name: "cube".into(),
                mass: MassProperties::solid_cuboid(1.0, 0.2, 0.2, 0.2)
                    .unwrap_or_else(|e| panic!("{e}")),
                shape,
                initial,
                load: Load::None,
            }],
            planes: vec![HalfSpace::ground()],
            friction: FrictionParams {
                mu: 0.5,
                e_t: 1.0,
                e_o: 1.0,
                e_r: 0.01,
            },
            gravity: Vector3::new(0.0, 0.0, -9.8),
            h: 0.01,
            duration: 0.1,
            world: World::default(),
        }
    }

    #[test]
    fn steps_cover_the_duration_without_a_spurious_last_step() {
        let mut scene = cube(BodyState::at_rest(Vector3::new(0.0, 0.0, 0.1)));
        assert_eq!(scene.num_steps(), 10);
        scene.duration = 0.105;
        assert_eq!(scene.num_steps(), 11);
        scene.duration = 0.0;
        assert_eq!(scene.num_steps(), 0);
    }

    #[test]
    fn initial_states_normalise_and_refuse_a_zero_quaternion() {
        let mut s = BodyState::at_rest(Vector3::new(0.0, 0.0, 0.1));
        s.q = Vector4::new(2.0, 0.0, 0.0, 0.0);
        let states = initial_states(&cube(s)).unwrap_or_else(|e| panic!("{e}"));
        assert!((states[0].q - Vector4::new(1.0, 0.0, 0.0, 0.0)).norm() < 1e-15);
        s.q = Vector4::zeros();
        let e = initial_states(&cube(s)).err().map(|e| e.to_string());
        assert!(e.is_some_and(|m| m.contains("non-zero")));
    }

    #[test]
    fn penetration_beyond_the_tolerance_is_refused() {
        let scene = cube(BodyState::at_rest(Vector3::new(0.0, 0.0, 0.1 - 2e-9)));
        let states = initial_states(&scene).unwrap_or_else(|e| panic!("{e}"));
        assert!(check_penetration(&scene, &states, 1e-9).is_err());
        assert!(check_penetration(&scene, &states, 1e-8).is_ok());
    }

    #[test]
    fn parameters_are_checked() {
        let mut scene = cube(BodyState::at_rest(Vector3::new(0.0, 0.0, 0.1)));
        assert!(validate_parameters(&scene, true).is_ok());
        scene.friction.e_r = 0.0;
        assert!(validate_parameters(&scene, true).is_err());
        assert!(validate_parameters(&scene, false).is_ok());
        scene.h = -1.0;
        assert!(validate_parameters(&scene, false).is_err());
    }
}
