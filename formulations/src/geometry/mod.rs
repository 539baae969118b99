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
//! - [`PlacedConvex`]: bounding boxes and signed distances of convex sets at given poses (the
//!   broad and narrow phases of the multi-body formulation, and its overlap check).
//!
//! All public types use nalgebra; parry3d-f64 (glam based) is used only
//! inside [`ConvexHull::from_points`], [`pair_features`] and [`PlacedConvex`].

mod error;
mod hull;
mod mass;
mod pair_features;
mod plane;
mod points;
mod polygon;
mod proximity;
mod shape;

pub use error::GeometryError;
pub use hull::{ConvexHull, Face, prune_to_extreme_candidates};
pub use mass::MassProperties;
pub(crate) use pair_features::cone_combination;
pub use pair_features::{HullPose, PairFeatures, pair_features, predicted_pose};
pub use plane::{
    ContactMode, HalfSpace, VertexSpacing, contact_mode, contact_mode_at, gap_and_mode_at,
    gap_and_mode_spaced, min_gap, world_vertices,
};
pub use points::{FLATNESS_TOL, MAX_HULL_CANDIDATES, MAX_HULL_POINTS, VERTEX_MERGE_TOL};
pub use polygon::convex_hull_2d;
pub use proximity::PlacedConvex;
pub use shape::{ConvexPiece, Shape};
