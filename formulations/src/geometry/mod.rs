//! Body geometry for the contact formulations (`docs/model.md#contact`,
//! `docs/model.md#scenarios`).
//!
//! - [`ConvexHull`]: the H-representation (merged faces) of Conv(F), whose
//!   faces give the constraints `f_i` of the closest-point problem;
//! - [`Shape`]: a body as a union of convex pieces in its body frame (origin
//!   at the centre of mass), possibly non-convex, with the scenario bodies;
//! - [`MassProperties`]: validated mass and body-frame inertia;
//! - [`HalfSpace`], [`contact_mode`], [`min_gap`]: the fixed half-space G and
//!   the state-only queries on it;
//! - [`convex_hull_2d`]: the convex hull of a planar point set (a contact patch);
//! - [`pair_features`]: the closest (or overlapping) features of two hulls at given poses, the
//!   starting point of a contact between two bodies.
//!
//! All public types use nalgebra; parry3d-f64 (glam based) is used only
//! inside [`ConvexHull::from_points`] and [`pair_features`].

mod error;
mod hull;
mod mass;
mod pair_features;
mod plane;
mod polygon;
mod shape;

pub use error::GeometryError;
pub use hull::{ConvexHull, Face, prune_to_extreme_candidates};
pub use mass::MassProperties;
pub use pair_features::{HullPose, PairFeatures, pair_features, predicted_pose};
pub use plane::{ContactMode, HalfSpace, contact_mode, min_gap, world_vertices};
pub use polygon::convex_hull_2d;
pub use shape::{ConvexPiece, Shape};

/// Distance below which two vertices are treated as the same point (m).
///
/// Shapes built from touching pieces (the desk's legs under its top) share
/// corners up to rounding; see [`Shape::vertices`].
pub const VERTEX_MERGE_TOL: f64 = 1e-12;

/// Relative thickness (thickness / diameter) below which a point set is
/// rejected as flat by [`ConvexHull::from_points`].
pub const FLATNESS_TOL: f64 = 1e-9;

/// Largest number of vertices of a hull built by [`ConvexHull::from_points`]
/// (`docs/scene-format.md`, meshes). The hull of `k` points has up to `2k − 4` faces and each
/// face is an unknown of every time step, so a finely tessellated round body is refused with a
/// message asking for a simplified mesh rather than made into a huge step problem.
/// See `docs/decisions.md#mesh-limits`.
pub const MAX_HULL_POINTS: usize = 2000;

/// Largest number of candidate extreme points (left after interior points and exact
/// duplicates are removed) that [`ConvexHull::from_points`] hands to the hull algorithm; more
/// are refused at once, since their hull would almost surely exceed [`MAX_HULL_POINTS`].
pub const MAX_HULL_CANDIDATES: usize = 20_000;

/// Removes points closer than `tol` to an earlier point, keeping first occurrences.
fn dedupe_points(points: &[nalgebra::Vector3<f64>], tol: f64) -> Vec<nalgebra::Vector3<f64>> {
    let mut out: Vec<nalgebra::Vector3<f64>> = Vec::with_capacity(points.len());
    for p in points {
        if !out.iter().any(|q| (q - p).norm() <= tol) {
            out.push(*p);
        }
    }
    out
}
