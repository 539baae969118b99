//! Errors of the geometry layer.

/// What went wrong while building geometry or mass properties from user data.
///
/// Each message states what is wrong and how to fix it, because these errors
/// usually come from a scene file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    /// A convex hull needs at least four points that span a volume.
    #[error(
        "a convex hull needs at least 4 distinct points, got {count}; \
         give the corners of a solid body (e.g. the 8 corners of a box)"
    )]
    TooFewPoints {
        /// Number of distinct points received.
        count: usize,
    },

    /// A coordinate or parameter is NaN or infinite.
    #[error(
        "{what} is not finite (NaN or infinite); check the scene file for a missing or invalid number"
    )]
    NonFinite {
        /// Which value (e.g. "point 3", "half extents of piece 1").
        what: String,
    },

    /// The points do not span a volume (coincident, collinear or coplanar).
    #[error(
        "the points are {kind}: thickness {thickness:.3e} m for a size of {diameter:.3e} m; \
         a body must have a non-zero volume - give points that are not all in one plane \
         (a flat plate needs a small but real thickness)"
    )]
    Degenerate {
        /// "coincident", "collinear" or "coplanar".
        kind: &'static str,
        /// Extent of the points across their best line/plane.
        thickness: f64,
        /// Size of the point set.
        diameter: f64,
    },

    /// A point set whose convex hull would have more vertices than a step problem can carry
    /// (one multiplier per face): a finely tessellated round body.
    #[error(
        "the convex hull would have at least {count} vertices (after removing duplicates and \
         interior points); at most {limit} are supported, because every face of the hull is an \
         unknown of each time step - simplify the mesh (decimate it to fewer than {limit} \
         vertices, e.g. with MeshLab's quadric edge collapse or Blender's Decimate modifier)"
    )]
    TooManyPoints {
        /// Vertices of the hull; `MAX_HULL_CANDIDATES + 1` when more than
        /// [`MAX_HULL_CANDIDATES`](super::MAX_HULL_CANDIDATES) candidate extreme points were
        /// found (the search stops there).
        count: usize,
        /// The limit, [`MAX_HULL_POINTS`](super::MAX_HULL_POINTS).
        limit: usize,
    },

    /// parry3d could not build the hull although the points looked non-degenerate.
    #[error(
        "the convex hull computation failed for {count} points; the points are probably \
         nearly degenerate or very noisy - weld near-duplicate points and remove noise"
    )]
    HullFailed {
        /// Number of input points.
        count: usize,
    },

    /// A length or half extent is not strictly positive.
    #[error("{what} must be positive, got {value}; give dimensions in metres, all > 0")]
    NonPositiveDimension {
        /// Which dimension.
        what: String,
        /// The offending value.
        value: f64,
    },

    /// A quaternion is zero, so it describes no rotation.
    #[error(
        "{what}: the quaternion is zero; give (w, x, y, z) with at least one non-zero entry, e.g. (1, 0, 0, 0)"
    )]
    ZeroQuaternion {
        /// Where the quaternion was given.
        what: String,
    },

    /// A shape has no pieces.
    #[error("a shape needs at least one convex piece")]
    EmptyShape,

    /// The mass is not strictly positive.
    #[error("the mass must be a positive finite number of kg, got {mass}")]
    InvalidMass {
        /// The offending mass.
        mass: f64,
    },

    /// The inertia matrix is not symmetric.
    #[error(
        "the inertia matrix is not symmetric (largest |I - I^T| entry {asymmetry:.3e}, \
         largest |I| entry {scale:.3e}); give I_xy = I_yx, I_xz = I_zx, I_yz = I_zy"
    )]
    AsymmetricInertia {
        /// Largest absolute entry of `I − Iᵀ`.
        asymmetry: f64,
        /// Largest absolute entry of `I`.
        scale: f64,
    },

    /// The inertia matrix is not positive definite.
    #[error(
        "the inertia matrix is not positive definite (smallest eigenvalue {min_eigenvalue:.3e}); \
         all principal moments must be > 0 - check signs and units (kg m^2)"
    )]
    IndefiniteInertia {
        /// Smallest eigenvalue of the (symmetrised) inertia.
        min_eigenvalue: f64,
    },

    /// The normal of a half-space is zero.
    #[error(
        "the normal of a half-space is zero; give a non-zero normal pointing out of the obstacle"
    )]
    ZeroNormal,
}
