//! Which pairs get a contact set for a step (`docs/model.md#which-pairs`): a dynamic body with
//! a half-space or another body (dynamic, fixed or kinematic) when they can touch by the end of
//! the step — for a half-space, the lowest vertex of the hull within the reach; for two bodies,
//! a broad phase on bounding boxes, then a narrow phase on the hulls' signed distance, both with
//! parry3d-f64 ([`crate::geometry::PlacedConvex`]).

use nalgebra::{Matrix3, Vector3};

use crate::geometry::{HalfSpace, PlacedConvex, min_gap};
use crate::rotation::rotation_matrix;
use crate::scene::{BodyState, Scene};
use crate::world::Obstacle;

/// The other party of a contact whose F is a dynamic body. Ordered: half-spaces, then dynamic
/// bodies, then fixed and kinematic bodies (the order of the contacts in the step problem).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Partner {
    /// Half-space `p` of the scene.
    Plane(usize),
    /// Dynamic body `b` (always before F in scene order).
    Body(usize),
    /// Fixed or kinematic body `k` of `Scene::world`.
    Obstacle(usize),
}

/// A contact set: dynamic body `f` (F) and its partner (G).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct PairKey {
    /// The dynamic body F.
    pub f: usize,
    /// G.
    pub g: Partner,
}

/// The reach of a step: a pair gets a contact set when its hulls are at most
/// `factor · h (|v_rel| + |ω_F| r_F + |ω_G| r_G) + margin` apart at the step start, with each
/// dynamic body's velocity taken after gravity acts for the step (`docs/model.md#which-pairs`).
/// The defaults are `factor = 2`, `margin = 1e-3` m; studies and tests may shrink them (an
/// under-estimated reach must be caught by the overlap check).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// Safety factor on the distance the step can close.
    pub factor: f64,
    /// Distance added to every reach (m).
    pub margin: f64,
}

impl Default for Reach {
    fn default() -> Self {
        Reach {
            factor: 2.0,
            margin: 1e-3,
        }
    }
}

/// One body (dynamic or not) at the start of a step, as the pair selection sees it.
#[derive(Clone, Debug)]
pub struct Placed {
    /// Its hull at the start pose.
    pub hull: PlacedConvex,
    /// Linear velocity over the step.
    pub v: Vector3<f64>,
    /// Angular velocity.
    pub w: Vector3<f64>,
    /// Radius of its hull about its CM.
    pub radius: f64,
    /// Its hull's vertices (world frame).
    pub vertices: Vec<Vector3<f64>>,
}

/// Places a hull (body-frame vertices) at `(x, R)` with the given motion.
pub fn place(
    vertices: &[Vector3<f64>],
    x: &Vector3<f64>,
    r: &Matrix3<f64>,
    v: Vector3<f64>,
    w: Vector3<f64>,
) -> Placed {
    Placed {
        hull: PlacedConvex::new(vertices, x, r),
        v,
        w,
        radius: vertices.iter().map(|p| p.norm()).fold(0.0, f64::max),
        vertices: vertices.iter().map(|p| x + r * p).collect(),
    }
}

/// The dynamic bodies (hull vertices `hulls[b]`) at `states` and the obstacles (hull vertices
/// `obstacle_hulls[k]`) at `t0`, each with its motion over a step of length `h`.
pub fn place_all(
    scene: &Scene,
    states: &[BodyState],
    hulls: &[Vec<Vector3<f64>>],
    obstacle_hulls: &[Vec<Vector3<f64>>],
    t0: f64,
    h: f64,
) -> (Vec<Placed>, Vec<Placed>) {
    let bodies = states
        .iter()
        .zip(hulls)
        .map(|(s, verts)| {
            let r = rotation_matrix(&s.q);
            place(verts, &s.x, &r, s.v + scene.gravity * h, s.w)
        })
        .collect();
    let obstacles = scene
        .world
        .obstacles
        .iter()
        .zip(obstacle_hulls)
        .map(|(o, verts): (&Obstacle, _)| {
            let span = o.span(t0, h);
            place(verts, &span.x0, &rotation_matrix(&span.q0), span.v, span.w)
        })
        .collect();
    (bodies, obstacles)
}

/// The contact sets of a step, sorted: a dynamic body F with a half-space when its hull's lowest
/// vertex is at most the reach above it, and with an earlier dynamic body or an obstacle G when
/// their bounding boxes grown by the reach intersect and their hulls are at most the reach apart.
pub fn select_pairs(
    planes: &[HalfSpace],
    bodies: &[Placed],
    obstacles: &[Placed],
    h: f64,
    reach: &Reach,
) -> Vec<PairKey> {
    let mut keys = Vec::new();
    let reach_of = |closing: f64| reach.factor * h * closing + reach.margin;
    let within = |a: &Placed, b: &Placed| {
        let r = reach_of((a.v - b.v).norm() + a.w.norm() * a.radius + b.w.norm() * b.radius);
        a.hull.may_touch(&b.hull, r) && a.hull.signed_distance(&b.hull, r).is_some()
    };
    let identity = nalgebra::Matrix3::identity();
    for (f, a) in bodies.iter().enumerate() {
        for (p, plane) in planes.iter().enumerate() {
            let gap = min_gap(&a.vertices, &Vector3::zeros(), &identity, plane);
            if gap <= reach_of(a.v.norm() + a.w.norm() * a.radius) {
                keys.push(PairKey {
                    f,
                    g: Partner::Plane(p),
                });
            }
        }
        for (g, b) in bodies[..f].iter().enumerate() {
            if within(a, b) {
                keys.push(PairKey {
                    f,
                    g: Partner::Body(g),
                });
            }
        }
        for (k, b) in obstacles.iter().enumerate() {
            if within(a, b) {
                keys.push(PairKey {
                    f,
                    g: Partner::Obstacle(k),
                });
            }
        }
    }
    keys.sort();
    keys
}
