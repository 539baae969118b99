//! Mass and body-frame inertia (`docs/model.md#newton-euler`: `M = diag(m I₃, R I_body Rᵀ)`).

use nalgebra::{Matrix3, Vector3};

use super::error::GeometryError;

/// Relative tolerance of the inertia symmetry check.
const SYMMETRY_TOL: f64 = 1e-9;

/// Mass and inertia about the centre of mass, in the body frame.
///
/// Built only through validating constructors, so the Newton–Euler block can
/// rely on `m > 0` and a symmetric positive definite `I_body`.
#[derive(Debug, Clone, PartialEq)]
pub struct MassProperties {
    /// Mass `m` (kg), positive and finite.
    pub mass: f64,
    /// Inertia `I_body` about the CM in body axes (kg m²), symmetric positive definite.
    pub inertia: Matrix3<f64>,
}

impl MassProperties {
    /// Validates user-given mass properties: `mass` finite and > 0, `inertia`
    /// finite, symmetric to 1e-9 relative and positive definite.
    ///
    /// The stored inertia is the exact symmetric part `(I + Iᵀ)/2`.
    pub fn new(mass: f64, inertia: Matrix3<f64>) -> Result<Self, GeometryError> {
        if !(mass.is_finite() && mass > 0.0) {
            return Err(GeometryError::InvalidMass { mass });
        }
        if !inertia.iter().all(|c| c.is_finite()) {
            return Err(GeometryError::NonFinite {
                what: "an entry of the inertia matrix".into(),
            });
        }
        let scale = inertia.abs().max();
        let asymmetry = (inertia - inertia.transpose()).abs().max();
        if asymmetry > SYMMETRY_TOL * scale {
            return Err(GeometryError::AsymmetricInertia { asymmetry, scale });
        }
        let sym = (inertia + inertia.transpose()) * 0.5;
        let min_eigenvalue = sym.symmetric_eigenvalues().min();
        if min_eigenvalue.is_nan() || min_eigenvalue <= 0.0 || sym.cholesky().is_none() {
            return Err(GeometryError::IndefiniteInertia { min_eigenvalue });
        }
        Ok(MassProperties { mass, inertia: sym })
    }

    /// Uniform solid box with edge lengths `lx, ly, lz` (m), CM at its centre:
    /// `I = m/12 diag(ly²+lz², lx²+lz², lx²+ly²)` (scenarios A, B).
    pub fn solid_cuboid(mass: f64, lx: f64, ly: f64, lz: f64) -> Result<Self, GeometryError> {
        for (what, l) in [("lx", lx), ("ly", ly), ("lz", lz)] {
            check_length(what, l)?;
        }
        let k = mass / 12.0;
        Self::new(
            mass,
            Matrix3::from_diagonal(&Vector3::new(
                k * (ly * ly + lz * lz),
                k * (lx * lx + lz * lz),
                k * (lx * lx + ly * ly),
            )),
        )
    }

    /// Uniform-density union of non-overlapping axis-aligned boxes, each
    /// given as `(half_extents, center)` in a common frame.
    ///
    /// The mass is shared by volume. Returns the mass properties about the
    /// combined CM (parallel-axis theorem) and the CM's position in the
    /// input frame, so a body such as the T-bar (scenario C) can be
    /// re-centred on its CM.
    pub fn uniform_cuboids(
        mass: f64,
        boxes: &[(Vector3<f64>, Vector3<f64>)],
    ) -> Result<(Self, Vector3<f64>), GeometryError> {
        if boxes.is_empty() {
            return Err(GeometryError::EmptyShape);
        }
        if !(mass.is_finite() && mass > 0.0) {
            return Err(GeometryError::InvalidMass { mass });
        }
        for (i, (h, c)) in boxes.iter().enumerate() {
            check_half_extents(&format!("box {i}"), h)?;
            if !c.iter().all(|x| x.is_finite()) {
                return Err(GeometryError::NonFinite {
                    what: format!("the centre of box {i}"),
                });
            }
        }
        let (cm, masses) = volume_weighted_centroid(mass, boxes);
        let mut inertia = Matrix3::zeros();
        for ((h, c), mi) in boxes.iter().zip(masses) {
            let (hx2, hy2, hz2) = (h.x * h.x, h.y * h.y, h.z * h.z);
            let own =
                Matrix3::from_diagonal(&Vector3::new(hy2 + hz2, hx2 + hz2, hx2 + hy2)) * (mi / 3.0);
            let d = c - cm;
            let shift = (Matrix3::identity() * d.norm_squared() - d * d.transpose()) * mi;
            inertia += own + shift;
        }
        Ok((Self::new(mass, inertia)?, cm))
    }

    /// Mass properties of the T-bar of scenario C (uniform density, two
    /// boxes), about its CM in the body frame of [`Shape::t_bar`](super::Shape::t_bar).
    pub fn t_bar(mass: f64) -> Result<Self, GeometryError> {
        Ok(Self::uniform_cuboids(mass, &t_bar_boxes())?.0)
    }
}

/// Volume-weighted centroid of boxes `(half_extents, center)` and each box's share of `mass`.
pub(super) fn volume_weighted_centroid(
    mass: f64,
    boxes: &[(Vector3<f64>, Vector3<f64>)],
) -> (Vector3<f64>, Vec<f64>) {
    let vols: Vec<f64> = boxes.iter().map(|(h, _)| 8.0 * h.x * h.y * h.z).collect();
    let total: f64 = vols.iter().sum();
    let masses: Vec<f64> = vols.iter().map(|v| mass * v / total).collect();
    let cm = boxes
        .iter()
        .zip(&vols)
        .map(|((_, c), v)| c * (v / total))
        .sum();
    (cm, masses)
}

/// A length must be finite and > 0.
pub(super) fn check_length(what: &str, l: f64) -> Result<(), GeometryError> {
    if !l.is_finite() {
        return Err(GeometryError::NonFinite { what: what.into() });
    }
    if l <= 0.0 {
        return Err(GeometryError::NonPositiveDimension {
            what: what.into(),
            value: l,
        });
    }
    Ok(())
}

/// All three half extents must be finite and > 0.
pub(super) fn check_half_extents(what: &str, h: &Vector3<f64>) -> Result<(), GeometryError> {
    for (axis, v) in ["x", "y", "z"].iter().zip(h.iter()) {
        check_length(&format!("the {axis} half extent of {what}"), *v)?;
    }
    Ok(())
}

/// T-bar of scenario C: crossbar length along body y (m).
const TBAR_CROSS_LEN: f64 = 0.20;
/// T-bar: stem length along +x (m).
const TBAR_STEM_LEN: f64 = 0.15;
/// T-bar: width of both bars, and thickness (m).
const TBAR_WIDTH: f64 = 0.05;

/// The T-bar's two boxes `(half_extents, center)` about its uniform-density CM.
pub(super) fn t_bar_boxes() -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let w = TBAR_WIDTH;
    // Frame with the crossbar's outer edge at x = 0, mid-thickness at z = 0.
    let boxes = [
        (
            Vector3::new(w / 2.0, TBAR_CROSS_LEN / 2.0, w / 2.0),
            Vector3::new(w / 2.0, 0.0, 0.0),
        ),
        (
            Vector3::new(TBAR_STEM_LEN / 2.0, w / 2.0, w / 2.0),
            Vector3::new(w + TBAR_STEM_LEN / 2.0, 0.0, 0.0),
        ),
    ];
    let (cm, _) = volume_weighted_centroid(1.0, &boxes);
    boxes.iter().map(|(h, c)| (*h, c - cm)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solid_cuboid_values() {
        let mp = MassProperties::solid_cuboid(10.0, 0.4, 0.4, 0.2).unwrap();
        assert!((mp.inertia[(2, 2)] - 0.266_666_666_666_666_7).abs() < 1e-15);
        let desk = MassProperties::solid_cuboid(15.0, 0.5, 0.5, 0.9).unwrap();
        assert!((desk.inertia[(0, 0)] - 1.325).abs() < 1e-14);
        assert!((desk.inertia[(1, 1)] - 1.325).abs() < 1e-14);
        assert!((desk.inertia[(2, 2)] - 0.625).abs() < 1e-14);
        assert!(MassProperties::solid_cuboid(1.0, 0.0, 1.0, 1.0).is_err());
        assert!(MassProperties::solid_cuboid(-1.0, 1.0, 1.0, 1.0).is_err());
    }

    #[test]
    fn uniform_cuboids_single_box_equals_solid_cuboid() {
        let c = Vector3::new(0.3, -0.2, 1.0);
        let (mp, cm) =
            MassProperties::uniform_cuboids(7.0, &[(Vector3::new(0.2, 0.1, 0.05), c)]).unwrap();
        let solid = MassProperties::solid_cuboid(7.0, 0.4, 0.2, 0.1).unwrap();
        assert!((cm - c).norm() < 1e-15);
        assert!((mp.inertia - solid.inertia).abs().max() < 1e-15);
        assert_eq!(mp.mass, 7.0);
    }

    #[test]
    fn uniform_cuboids_two_halves_equal_whole() {
        // A 0.4 x 0.2 x 0.1 box split in two along x.
        let h = Vector3::new(0.1, 0.1, 0.05);
        let boxes = [
            (h, Vector3::new(-0.1, 0.0, 0.0)),
            (h, Vector3::new(0.1, 0.0, 0.0)),
        ];
        let (mp, cm) = MassProperties::uniform_cuboids(3.0, &boxes).unwrap();
        let solid = MassProperties::solid_cuboid(3.0, 0.4, 0.2, 0.1).unwrap();
        assert!(cm.norm() < 1e-16);
        assert!((mp.inertia - solid.inertia).abs().max() < 1e-15);
    }

    #[test]
    fn t_bar_mass_properties() {
        let mp = MassProperties::t_bar(2.0).unwrap();
        assert_eq!(mp.mass, 2.0);
        // Products of inertia vanish: the T is symmetric in y and z.
        assert!(mp.inertia[(0, 1)].abs() < 1e-15 && mp.inertia[(0, 2)].abs() < 1e-15);
        // Hand computation: crossbar 8/7 kg, stem 6/7 kg, CM 0.0678571 m from the crossbar edge.
        let (m1, m2) = (2.0 * 8.0 / 14.0, 2.0 * 6.0 / 14.0);
        let xc = (m1 * 0.025 + m2 * 0.125) / 2.0;
        let izz = m1 / 12.0 * (0.05f64.powi(2) + 0.2f64.powi(2))
            + m1 * (xc - 0.025).powi(2)
            + m2 / 12.0 * (0.15f64.powi(2) + 0.05f64.powi(2))
            + m2 * (0.125 - xc).powi(2);
        assert!((mp.inertia[(2, 2)] - izz).abs() < 1e-15);
    }

    #[test]
    fn inertia_validation() {
        let good = Matrix3::new(1.0, 0.1, 0.0, 0.1, 2.0, 0.0, 0.0, 0.0, 3.0);
        assert!(MassProperties::new(1.0, good).is_ok());
        let mut nonsym = good;
        nonsym[(0, 1)] = 0.2;
        assert!(matches!(
            MassProperties::new(1.0, nonsym),
            Err(GeometryError::AsymmetricInertia { .. })
        ));
        let indefinite = Matrix3::new(1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(matches!(
            MassProperties::new(1.0, indefinite),
            Err(GeometryError::IndefiniteInertia { .. })
        ));
        assert!(matches!(
            MassProperties::new(1.0, Matrix3::zeros()),
            Err(GeometryError::IndefiniteInertia { .. })
        ));
        assert!(matches!(
            MassProperties::new(0.0, good),
            Err(GeometryError::InvalidMass { .. })
        ));
        assert!(matches!(
            MassProperties::new(f64::NAN, good),
            Err(GeometryError::InvalidMass { .. })
        ));
        let mut nan = good;
        nan[(2, 2)] = f64::INFINITY;
        assert!(matches!(
            MassProperties::new(1.0, nan),
            Err(GeometryError::NonFinite { .. })
        ));
    }
}
