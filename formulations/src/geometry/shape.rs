//! Body shapes as unions of convex pieces (`docs/model.md#contact`, `docs/model.md#union`;
//! scenarios A–C).

use nalgebra::{Vector3, Vector4};

use super::error::GeometryError;
use super::hull::ConvexHull;
use super::mass::{check_half_extents, check_length, t_bar_boxes};
use super::points::{VERTEX_MERGE_TOL, dedupe_points};
use crate::rotation::rotation_matrix;

/// One convex piece of a body, in the body frame.
///
/// The union-of-pieces model (`docs/model.md#union`) gives each piece its own contact;
/// the hull model uses only the union's vertices and hull.
#[derive(Debug, Clone, PartialEq)]
pub enum ConvexPiece {
    /// A box: corners `center + R(orientation) (±hx, ±hy, ±hz)`.
    Cuboid {
        /// Half edge lengths (m), all > 0.
        half_extents: Vector3<f64>,
        /// Centre of the box in the body frame (m).
        center: Vector3<f64>,
        /// Orientation of the box in the body frame, quaternion `(w, x, y, z)`,
        /// non-zero (need not be unit).
        orientation: Vector4<f64>,
    },
    /// The convex hull of these body-frame points (at least 4, spanning a volume).
    Points(Vec<Vector3<f64>>),
}

impl ConvexPiece {
    /// Axis-aligned box piece with the given half extents and centre (not validated
    /// until it is put into a [`Shape`]).
    pub fn cuboid(half_extents: Vector3<f64>, center: Vector3<f64>) -> Self {
        ConvexPiece::Cuboid {
            half_extents,
            center,
            orientation: Vector4::new(1.0, 0.0, 0.0, 0.0),
        }
    }

    /// Checks the piece: finite values, positive half extents, non-zero
    /// orientation, or for a point set, a hull with a volume.
    pub fn validate(&self) -> Result<(), GeometryError> {
        match self {
            ConvexPiece::Cuboid {
                half_extents,
                center,
                orientation,
            } => {
                check_half_extents("a cuboid piece", half_extents)?;
                if !center.iter().all(|c| c.is_finite()) {
                    return Err(GeometryError::NonFinite {
                        what: "the centre of a cuboid piece".into(),
                    });
                }
                if !orientation.iter().all(|c| c.is_finite()) {
                    return Err(GeometryError::NonFinite {
                        what: "the orientation of a cuboid piece".into(),
                    });
                }
                if orientation.norm_squared() == 0.0 {
                    return Err(GeometryError::ZeroQuaternion {
                        what: "orientation of a cuboid piece".into(),
                    });
                }
                Ok(())
            }
            ConvexPiece::Points(points) => ConvexHull::from_points(points).map(|_| ()),
        }
    }

    /// Corners of the piece in the body frame (for `Points`, the points as stored).
    pub fn vertices(&self) -> Vec<Vector3<f64>> {
        match self {
            ConvexPiece::Cuboid {
                half_extents: h,
                center,
                orientation,
            } => {
                let r = rotation_matrix(orientation);
                let mut out = Vec::with_capacity(8);
                for sx in [-1.0, 1.0] {
                    for sy in [-1.0, 1.0] {
                        for sz in [-1.0, 1.0] {
                            out.push(center + r * Vector3::new(sx * h.x, sy * h.y, sz * h.z));
                        }
                    }
                }
                out
            }
            ConvexPiece::Points(points) => points.clone(),
        }
    }

    /// Convex hull of this piece alone (for the union-of-pieces model, `docs/model.md#union`).
    pub fn hull(&self) -> Result<ConvexHull, GeometryError> {
        self.validate()?;
        ConvexHull::from_points(&self.vertices())
    }
}

/// A body's geometry in its BODY frame (origin at the centre of mass): a
/// union of convex pieces, possibly non-convex as a whole.
///
/// Its [`vertices`](Shape::vertices) are those of the real body, used for the
/// minimum gap and the contact mode (`docs/model.md#invariants`, scenario C); its
/// [`hull`](Shape::hull) is Conv(F), whose faces enter the step problem
/// (`docs/model.md#contact`, Proposition 1).
#[derive(Debug, Clone, PartialEq)]
pub struct Shape {
    pieces: Vec<ConvexPiece>,
    vertices: Vec<Vector3<f64>>,
}

/// Desk of scenario B: top side (m).
const DESK_TOP: f64 = 0.5;
/// Desk: top slab thickness (m).
const DESK_SLAB: f64 = 0.05;
/// Desk: leg length (m).
const DESK_LEG: f64 = 0.85;
/// Desk: square leg cross-section side (m).
const DESK_FOOT: f64 = 0.06;

impl Shape {
    /// Shape from convex pieces, validated. A `Points` piece is reduced to the
    /// extreme vertices of its hull, so only real corners count as vertices.
    pub fn from_pieces(pieces: Vec<ConvexPiece>) -> Result<Shape, GeometryError> {
        if pieces.is_empty() {
            return Err(GeometryError::EmptyShape);
        }
        let mut checked = Vec::with_capacity(pieces.len());
        for piece in pieces {
            piece.validate()?;
            checked.push(match piece {
                ConvexPiece::Points(points) => {
                    ConvexPiece::Points(ConvexHull::from_points(&points)?.vertices().to_vec())
                }
                cuboid => cuboid,
            });
        }
        Ok(Self::from_valid_pieces(checked))
    }

    /// Builds the shape from pieces already known to be valid.
    fn from_valid_pieces(pieces: Vec<ConvexPiece>) -> Shape {
        let all: Vec<Vector3<f64>> = pieces.iter().flat_map(ConvexPiece::vertices).collect();
        let vertices = dedupe_points(&all, VERTEX_MERGE_TOL);
        Shape { pieces, vertices }
    }

    /// Solid box with edge lengths `lx, ly, lz` (m), centred at the origin
    /// (scenario A's box is `cuboid(0.4, 0.4, 0.2)`).
    pub fn cuboid(lx: f64, ly: f64, lz: f64) -> Result<Shape, GeometryError> {
        for (what, l) in [("lx", lx), ("ly", ly), ("lz", lz)] {
            check_length(what, l)?;
        }
        Ok(Self::from_valid_pieces(vec![ConvexPiece::cuboid(
            Vector3::new(lx, ly, lz) / 2.0,
            Vector3::zeros(),
        )]))
    }

    /// The desk of scenario B: a 0.5 × 0.5 m top slab 0.05 m thick on four
    /// 0.85 m legs of 0.06 × 0.06 m cross-section whose outer faces are flush
    /// with the top's edges. Total height 0.9 m; the origin is at mid-height
    /// (CM height H = 0.45 m per the spec), so the feet are at z = −0.45 and the
    /// top at z = +0.45. Pieces: the top, then the four legs. Hull: the
    /// 0.5 × 0.5 × 0.9 box.
    pub fn desk() -> Shape {
        let half_h = (DESK_SLAB + DESK_LEG) / 2.0;
        let top = ConvexPiece::cuboid(
            Vector3::new(DESK_TOP / 2.0, DESK_TOP / 2.0, DESK_SLAB / 2.0),
            Vector3::new(0.0, 0.0, half_h - DESK_SLAB / 2.0),
        );
        let c = DESK_TOP / 2.0 - DESK_FOOT / 2.0;
        let leg_half = Vector3::new(DESK_FOOT / 2.0, DESK_FOOT / 2.0, DESK_LEG / 2.0);
        let mut pieces = vec![top];
        for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)] {
            pieces.push(ConvexPiece::cuboid(
                leg_half,
                Vector3::new(sx * c, sy * c, -half_h + DESK_LEG / 2.0),
            ));
        }
        Self::from_valid_pieces(pieces)
    }

    /// The T-bar of scenario C, lying flat: crossbar 0.20 m along body y,
    /// 0.05 m along x, 0.05 m thick; stem 0.15 m along +x from the crossbar,
    /// 0.05 m wide and thick. The origin is the uniform-density CM: the
    /// crossbar's outer face is at x ≈ −0.0679 m, the stem tip at x ≈ +0.1321 m,
    /// z = 0 at mid-thickness. Pieces: crossbar, stem. Hull: 8 faces.
    /// Matching mass properties: [`MassProperties::t_bar`](super::MassProperties::t_bar).
    pub fn t_bar() -> Shape {
        Self::from_valid_pieces(
            t_bar_boxes()
                .into_iter()
                .map(|(h, c)| ConvexPiece::cuboid(h, c))
                .collect(),
        )
    }

    /// The convex pieces (body frame).
    pub fn pieces(&self) -> &[ConvexPiece] {
        &self.pieces
    }

    /// All piece vertices with duplicates (closer than
    /// [`VERTEX_MERGE_TOL`](super::VERTEX_MERGE_TOL)) removed: the vertices of
    /// the real, possibly non-convex body (body frame).
    pub fn vertices(&self) -> &[Vector3<f64>] {
        &self.vertices
    }

    /// Conv(F) of the whole body (`docs/model.md#contact`).
    pub fn hull(&self) -> Result<ConvexHull, GeometryError> {
        ConvexHull::from_points(&self.vertices)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rotation::quat_from_rpy_deg;

    fn extents(points: &[Vector3<f64>]) -> (Vector3<f64>, Vector3<f64>) {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        for p in points {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
        (lo, hi)
    }

    #[test]
    fn cuboid_shape() {
        let s = Shape::cuboid(0.4, 0.4, 0.2).unwrap();
        assert_eq!(s.vertices().len(), 8);
        let h = s.hull().unwrap();
        assert_eq!(h.num_faces(), 6);
        assert!(Shape::cuboid(0.4, -0.4, 0.2).is_err());
        assert!(Shape::cuboid(0.4, f64::NAN, 0.2).is_err());
    }

    #[test]
    fn desk_geometry() {
        let s = Shape::desk();
        assert_eq!(s.pieces().len(), 5);
        // 8 top corners + 4 × 8 leg corners − 4 shared corners under the top.
        assert_eq!(s.vertices().len(), 36);
        let (lo, hi) = extents(s.vertices());
        assert!((lo - Vector3::new(-0.25, -0.25, -0.45)).norm() < 1e-12);
        assert!((hi - Vector3::new(0.25, 0.25, 0.45)).norm() < 1e-12);
        let h = s.hull().unwrap();
        assert_eq!(h.num_faces(), 6);
        assert_eq!(h.vertices().len(), 8);
        let (lo, hi) = extents(h.vertices());
        assert!((hi - lo - Vector3::new(0.5, 0.5, 0.9)).norm() < 1e-12);
        assert!((h.volume() - 0.5 * 0.5 * 0.9).abs() < 1e-12);
        for v in s.vertices() {
            assert!(h.contains(v, 1e-12));
        }
        let feet = s
            .vertices()
            .iter()
            .filter(|v| (v.z + 0.45).abs() < 1e-12)
            .count();
        assert_eq!(feet, 16);
    }

    #[test]
    fn t_bar_geometry() {
        let s = Shape::t_bar();
        let (lo, hi) = extents(s.vertices());
        assert!(
            (lo.x + 0.0679).abs() < 1e-4,
            "crossbar edge at x = {}",
            lo.x
        );
        // Exact: (0.0005 · 0.025 + 0.000375 · 0.125) / 0.000875 = 0.0678571…
        assert!((lo.x + 0.059375 / 0.875).abs() < 1e-12);
        assert!((hi.x - lo.x - 0.2).abs() < 1e-12);
        assert!((hi.y - 0.1).abs() < 1e-12 && (lo.y + 0.1).abs() < 1e-12);
        assert!((hi.z - 0.025).abs() < 1e-12 && (lo.z + 0.025).abs() < 1e-12);
        let h = s.hull().unwrap();
        assert_eq!(h.num_faces(), 8);
        let slanted = h
            .faces()
            .iter()
            .filter(|f| f.normal.x.abs() > 1e-9 && f.normal.y.abs() > 1e-9)
            .count();
        assert_eq!(slanted, 2);
        for v in s.vertices() {
            assert!(h.contains(v, 1e-12));
        }
    }

    #[test]
    fn pieces_are_validated() {
        assert!(matches!(
            Shape::from_pieces(vec![]),
            Err(GeometryError::EmptyShape)
        ));
        let bad = ConvexPiece::cuboid(Vector3::new(0.1, 0.0, 0.1), Vector3::zeros());
        assert!(matches!(
            Shape::from_pieces(vec![bad]),
            Err(GeometryError::NonPositiveDimension { .. })
        ));
        let nan = ConvexPiece::cuboid(Vector3::repeat(0.1), Vector3::new(0.0, f64::NAN, 0.0));
        assert!(matches!(
            Shape::from_pieces(vec![nan]),
            Err(GeometryError::NonFinite { .. })
        ));
        let zero_q = ConvexPiece::Cuboid {
            half_extents: Vector3::repeat(0.1),
            center: Vector3::zeros(),
            orientation: Vector4::zeros(),
        };
        assert!(matches!(
            Shape::from_pieces(vec![zero_q]),
            Err(GeometryError::ZeroQuaternion { .. })
        ));
        let flat = ConvexPiece::Points(vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(1.0, 1.0, 0.0),
        ]);
        assert!(matches!(
            Shape::from_pieces(vec![flat]),
            Err(GeometryError::Degenerate { .. })
        ));
    }

    #[test]
    fn rotated_piece_and_point_piece() {
        let rotated = ConvexPiece::Cuboid {
            half_extents: Vector3::new(0.2, 0.1, 0.05),
            center: Vector3::new(1.0, 0.0, 0.0),
            orientation: quat_from_rpy_deg(10.0, 20.0, 30.0) * 3.0,
        };
        let h = rotated.hull().unwrap();
        assert_eq!(h.num_faces(), 6);
        assert!((h.volume() - 0.4 * 0.2 * 0.1).abs() < 1e-13);
        // A point piece with an interior point: only the 4 corners are kept.
        let tet = ConvexPiece::Points(vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.0, 1.0, 0.0),
            Vector3::new(0.0, 0.0, 1.0),
            Vector3::new(0.1, 0.1, 0.1),
        ]);
        let s = Shape::from_pieces(vec![rotated, tet]).unwrap();
        assert_eq!(s.vertices().len(), 12);
        assert_eq!(s.pieces().len(), 2);
    }
}
