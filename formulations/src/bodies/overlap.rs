//! The overlap check at every step end (`docs/model.md#which-pairs`): the real (possibly
//! non-convex) bodies, piece by piece, between every two bodies — not only the pairs that had a
//! contact set — and every dynamic body against every half-space. A contact set left out that
//! should have been there shows up here as an overlap.

use nalgebra::{Vector3, Vector4};

use crate::geometry::{PlacedConvex, min_gap};
use crate::rotation::rotation_matrix;
use crate::scene::{BodyState, Scene};

/// Overlap depth (m) above which two real bodies are reported as overlapping.
pub const OVERLAP_TOLERANCE: f64 = 1e-8;

/// The deepest overlap found.
#[derive(Clone, Debug, PartialEq)]
pub struct Overlap {
    /// The dynamic body.
    pub a: String,
    /// The other body or half-space.
    pub b: String,
    /// Depth (m, > 0).
    pub depth: f64,
}

/// The body-frame vertices of each convex piece of every dynamic body and obstacle of a scene.
#[derive(Clone, Debug, Default)]
pub struct RealPieces {
    bodies: Vec<Vec<Vec<Vector3<f64>>>>,
    obstacles: Vec<Vec<Vec<Vector3<f64>>>>,
}

impl RealPieces {
    /// The pieces of `scene`'s bodies.
    pub fn of(scene: &Scene) -> Self {
        let pieces = |s: &crate::geometry::Shape| s.pieces().iter().map(|p| p.vertices()).collect();
        RealPieces {
            bodies: scene.bodies.iter().map(|b| pieces(&b.shape)).collect(),
            obstacles: scene
                .world
                .obstacles
                .iter()
                .map(|o| pieces(&o.shape))
                .collect(),
        }
    }

    /// The deepest overlap deeper than `tolerance` between the real bodies of `scene` with the
    /// dynamic bodies at `states` and the obstacles at time `t`; `None` when there is none.
    pub fn deepest_overlap(
        &self,
        scene: &Scene,
        states: &[BodyState],
        t: f64,
        tolerance: f64,
    ) -> Option<Overlap> {
        let placed = |pieces: &Vec<Vec<Vector3<f64>>>, x: &Vector3<f64>, q: &Vector4<f64>| {
            let r = rotation_matrix(q);
            pieces
                .iter()
                .map(|p| PlacedConvex::new(p, x, &r))
                .collect::<Vec<_>>()
        };
        let bodies: Vec<Vec<PlacedConvex>> = self
            .bodies
            .iter()
            .zip(states)
            .map(|(p, s)| placed(p, &s.x, &s.q))
            .collect();
        let obstacles: Vec<Vec<PlacedConvex>> = self
            .obstacles
            .iter()
            .zip(&scene.world.obstacles)
            .map(|(p, o)| {
                let (x, q) = o.pose_at(t);
                placed(p, &x, &q)
            })
            .collect();
        let mut worst: Option<Overlap> = None;
        let mut note = |a: &str, b: &str, depth: f64| {
            if depth > tolerance && worst.as_ref().is_none_or(|w| depth > w.depth) {
                worst = Some(Overlap {
                    a: a.to_string(),
                    b: b.to_string(),
                    depth,
                });
            }
        };
        let depth = |a: &[PlacedConvex], b: &[PlacedConvex]| {
            let mut d: f64 = 0.0;
            for pa in a {
                for pb in b {
                    if pa.may_touch(pb, 0.0)
                        && let Some(s) = pa.signed_distance(pb, 0.0)
                    {
                        d = d.max(-s);
                    }
                }
            }
            d
        };
        for (f, (spec, state)) in scene.bodies.iter().zip(states).enumerate() {
            let r = rotation_matrix(&state.q);
            for (p, plane) in scene.planes.iter().enumerate() {
                let gap = min_gap(spec.shape.vertices(), &state.x, &r, plane);
                note(&spec.name, &scene.world.plane_name(p), -gap);
            }
            for g in 0..f {
                note(
                    &spec.name,
                    &scene.bodies[g].name,
                    depth(&bodies[f], &bodies[g]),
                );
            }
            for (k, o) in scene.world.obstacles.iter().enumerate() {
                note(&spec.name, &o.name, depth(&bodies[f], &obstacles[k]));
            }
        }
        worst
    }
}
