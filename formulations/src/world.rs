//! What a scene holds besides its dynamic bodies (`docs/model.md#bodies-touching-bodies`):
//! fixed and kinematic bodies (convex shapes that contact does not move), the names of the
//! half-spaces, and friction per pair of bodies or materials with the scene's friction as the
//! default.
//!
//! A fixed body never moves; a kinematic body's pose is prescribed as a function of time. Both
//! enter the step problem as data: their pose at the end of the span and the velocity that
//! moves them there under the kinematic map (`docs/model.md#kinematic-bodies`).

use std::sync::Arc;

use nalgebra::{Vector3, Vector4};

use crate::blocks::FrictionParams;
use crate::geometry::Shape;
use crate::rotation::{kinematic_map, quat_from_axis_angle, quat_mul, quat_normalize};

/// A pose `(x, Q)` (CM position, unit quaternion body → world) as a function of time.
pub type PoseFn = Arc<dyn Fn(f64) -> (Vector3<f64>, Vector4<f64>) + Send + Sync>;

/// How a non-dynamic body moves.
#[derive(Clone)]
pub enum Motion {
    /// Never moves: the pose `(x, Q)`.
    Fixed {
        /// Position of the body frame's origin.
        x: Vector3<f64>,
        /// Orientation (unit quaternion).
        q: Vector4<f64>,
    },
    /// A velocity schedule: constant linear velocity `v` and angular velocity `w` (world frame)
    /// from the pose `(x0, q0)` at t = 0: `x(t) = x0 + v t`, `Q(t) = exp(w t) ⊗ Q0`.
    Velocity {
        /// Position at t = 0.
        x0: Vector3<f64>,
        /// Orientation at t = 0.
        q0: Vector4<f64>,
        /// Linear velocity.
        v: Vector3<f64>,
        /// Angular velocity (world frame).
        w: Vector3<f64>,
    },
    /// The pose as a function of time (expressions of `t` in scene files).
    Pose(PoseFn),
}

impl std::fmt::Debug for Motion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Motion::Fixed { x, q } => write!(f, "Fixed {{ x: {x:?}, q: {q:?} }}"),
            Motion::Velocity { x0, q0, v, w } => {
                write!(
                    f,
                    "Velocity {{ x0: {x0:?}, q0: {q0:?}, v: {v:?}, w: {w:?} }}"
                )
            }
            Motion::Pose(_) => write!(f, "Pose(..)"),
        }
    }
}

/// A fixed or kinematic body: a shape (a union of convex pieces; Conv of it for contact) whose
/// pose is prescribed.
#[derive(Clone, Debug)]
pub struct Obstacle {
    /// Name (unique among all bodies and half-spaces of the scene).
    pub name: String,
    /// Geometry in the body frame.
    pub shape: Shape,
    /// How it moves.
    pub motion: Motion,
    /// Material name (for friction per pair of materials), if any.
    pub material: Option<String>,
}

impl Obstacle {
    /// Whether the body is fixed (never moves).
    pub fn is_fixed(&self) -> bool {
        matches!(self.motion, Motion::Fixed { .. })
    }

    /// The pose `(x, Q)` at time `t` (Q normalised; the identity if a schedule gives a zero
    /// quaternion, which scene loading refuses).
    pub fn pose_at(&self, t: f64) -> (Vector3<f64>, Vector4<f64>) {
        let id = Vector4::new(1.0, 0.0, 0.0, 0.0);
        match &self.motion {
            Motion::Fixed { x, q } => (*x, *q),
            Motion::Velocity { x0, q0, v, w } => {
                let angle = w.norm() * t;
                let q = match quat_from_axis_angle(w, angle) {
                    Some(r) if angle != 0.0 => quat_mul(&r, q0),
                    _ => *q0,
                };
                (x0 + v * t, quat_normalize(&q).unwrap_or(id))
            }
            Motion::Pose(f) => {
                let (x, q) = f(t);
                (x, quat_normalize(&q).unwrap_or(id))
            }
        }
    }

    /// The span `[t0, t0 + h]` as the step problem sees it: the end pose `(x1, Q1)` and the
    /// velocity `(v, ω)` that moves the body from its pose at `t0` to it under the kinematic map
    /// (`docs/model.md#kinematic-bodies`): `v = (x1 − x0)/h`, `ω = (2/h) E(Q0)ᵀ (Q1 − Q0)`.
    pub fn span(&self, t0: f64, h: f64) -> SpanMotion {
        let (x0, q0) = self.pose_at(t0);
        let (x1, mut q1) = self.pose_at(t0 + h);
        if q1.dot(&q0) < 0.0 {
            q1 = -q1;
        }
        if self.is_fixed() {
            return SpanMotion {
                x0,
                q0,
                x1,
                q1,
                v: Vector3::zeros(),
                w: Vector3::zeros(),
            };
        }
        SpanMotion {
            x0,
            q0,
            x1,
            q1,
            v: (x1 - x0) / h,
            w: kinematic_map(&q0).transpose() * (q1 - q0) * (2.0 / h),
        }
    }
}

/// The motion of a fixed or kinematic body over one span ([`Obstacle::span`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpanMotion {
    /// Position at the start.
    pub x0: Vector3<f64>,
    /// Orientation at the start.
    pub q0: Vector4<f64>,
    /// Position at the end.
    pub x1: Vector3<f64>,
    /// Orientation at the end.
    pub q1: Vector4<f64>,
    /// Linear velocity over the span.
    pub v: Vector3<f64>,
    /// Angular velocity over the span (world frame).
    pub w: Vector3<f64>,
}

/// Friction of the contacts between two named parties: bodies, half-spaces or materials.
#[derive(Clone, Debug, PartialEq)]
pub struct PairFriction {
    /// The two names (order does not matter).
    pub names: [String; 2],
    /// The friction parameters of their contacts.
    pub friction: FrictionParams,
}

/// Everything of a scene besides its dynamic bodies (module documentation). The default is
/// empty: a scene of dynamic bodies on unnamed half-spaces.
#[derive(Clone, Debug, Default)]
pub struct World {
    /// Fixed and kinematic bodies.
    pub obstacles: Vec<Obstacle>,
    /// Names of the half-spaces, in the order of `Scene::planes` (missing names are
    /// `half_space<p>`).
    pub plane_names: Vec<String>,
    /// Materials of the dynamic bodies, by body name.
    pub materials: Vec<(String, String)>,
    /// Friction per pair of bodies, half-spaces or materials; a pair of bodies takes its own
    /// entry first, then its materials', then the scene's friction.
    pub pair_friction: Vec<PairFriction>,
    /// Whether dynamic bodies touch each other (scenes with several dynamic bodies that are
    /// run by the multi-body formulation).
    pub bodies_touch: bool,
}

impl World {
    /// Whether the scene needs the multi-body formulation: it has fixed or kinematic bodies,
    /// pair friction, or dynamic bodies that touch each other.
    pub fn is_multibody(&self) -> bool {
        !self.obstacles.is_empty() || !self.pair_friction.is_empty() || self.bodies_touch
    }

    /// The name of half-space `p`.
    pub fn plane_name(&self, p: usize) -> String {
        self.plane_names
            .get(p)
            .cloned()
            .unwrap_or_else(|| format!("half_space{p}"))
    }

    /// The material of the dynamic body or obstacle named `name`.
    pub fn material_of(&self, name: &str) -> Option<&str> {
        self.materials
            .iter()
            .find(|(b, _)| b == name)
            .map(|(_, m)| m.as_str())
            .or_else(|| {
                self.obstacles
                    .iter()
                    .find(|o| o.name == name)
                    .and_then(|o| o.material.as_deref())
            })
    }

    /// The friction of the contacts between the parties named `a` and `b`: their own entry,
    /// else their materials', else `default`.
    pub fn friction_between(&self, a: &str, b: &str, default: &FrictionParams) -> FrictionParams {
        let find = |x: &str, y: &str| {
            self.pair_friction.iter().find(|p| {
                (p.names[0] == x && p.names[1] == y) || (p.names[0] == y && p.names[1] == x)
            })
        };
        if let Some(p) = find(a, b) {
            return p.friction;
        }
        if let (Some(ma), Some(mb)) = (self.material_of(a), self.material_of(b))
            && let Some(p) = find(ma, mb)
        {
            return p.friction;
        }
        *default
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plate(motion: Motion) -> Obstacle {
        Obstacle {
            name: "plate".into(),
            shape: Shape::cuboid(0.4, 0.4, 0.2).unwrap_or_else(|e| panic!("{e}")),
            motion,
            material: Some("steel".into()),
        }
    }

    #[test]
    fn a_velocity_schedule_moves_by_its_velocity_over_a_span() {
        let w = Vector3::new(0.0, 0.0, 2.0);
        let o = plate(Motion::Velocity {
            x0: Vector3::new(0.0, 0.0, 0.1),
            q0: Vector4::new(1.0, 0.0, 0.0, 0.0),
            v: Vector3::new(0.5, 0.0, 0.0),
            w,
        });
        let s = o.span(0.3, 0.01);
        assert!((s.v - Vector3::new(0.5, 0.0, 0.0)).norm() < 1e-12);
        assert!((s.x1 - Vector3::new(0.155, 0.0, 0.1)).norm() < 1e-12);
        // The kinematic map of ω from Q0 reaches Q1 to second order in h.
        let q1 = s.q0 + kinematic_map(&s.q0) * s.w * 0.005;
        assert!((q1.normalize() - s.q1).norm() < 1e-5, "{q1:?} {:?}", s.q1);
        assert!((s.w - w).norm() < 1e-3, "{:?}", s.w);
        let fixed = plate(Motion::Fixed {
            x: Vector3::zeros(),
            q: Vector4::new(1.0, 0.0, 0.0, 0.0),
        });
        assert_eq!(fixed.span(1.0, 0.01).v, Vector3::zeros());
    }

    #[test]
    fn friction_by_pair_then_material_then_default() {
        let f = |mu| FrictionParams {
            mu,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.1,
        };
        let world = World {
            obstacles: vec![plate(Motion::Fixed {
                x: Vector3::zeros(),
                q: Vector4::new(1.0, 0.0, 0.0, 0.0),
            })],
            plane_names: vec!["ground".into()],
            materials: vec![("B".into(), "wood".into())],
            pair_friction: vec![
                PairFriction {
                    names: ["A".into(), "ground".into()],
                    friction: f(1.0),
                },
                PairFriction {
                    names: ["steel".into(), "wood".into()],
                    friction: f(0.4),
                },
            ],
            bodies_touch: true,
        };
        let d = f(0.3);
        assert_eq!(world.friction_between("ground", "A", &d).mu, 1.0);
        assert_eq!(world.friction_between("B", "plate", &d).mu, 0.4);
        assert_eq!(world.friction_between("B", "ground", &d).mu, 0.3);
        assert_eq!(world.plane_name(3), "half_space3");
    }
}
