//! Helpers shared by the residual blocks: small vector views, the contact frame, the inertia
//! parametrisation of the data and the generalised mass matrix.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector4};

use crate::rotation::rotation_matrix;

#[inline]
pub(crate) fn v3(s: &[f64], o: usize) -> Vector3<f64> {
    Vector3::new(s[o], s[o + 1], s[o + 2])
}

#[inline]
pub(crate) fn v4(s: &[f64], o: usize) -> Vector4<f64> {
    Vector4::new(s[o], s[o + 1], s[o + 2], s[o + 3])
}

/// The fixed contact frame of a half-space (n into the body, t and o tangent).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactFrame {
    /// Unit normal of G pointing into F.
    pub n: Vector3<f64>,
    /// First tangent.
    pub t: Vector3<f64>,
    /// Second tangent, `n × t`.
    pub o: Vector3<f64>,
}

/// The inertia entries of the data parametrisation, `(row, col)` in the order of the `inertia`
/// data block ([`super::INERTIA_DATA`]: `I_xx, I_yy, I_zz, I_xy, I_xz, I_yz`; an off-diagonal
/// datum moves both of its entries).
pub const INERTIA_ENTRIES: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];

/// The symmetric unit matrix of inertia datum `k` ([`INERTIA_ENTRIES`]): `∂I_body/∂θ_k`.
pub fn inertia_direction(k: usize) -> Matrix3<f64> {
    let (i, j) = INERTIA_ENTRIES[k];
    let mut e = Matrix3::zeros();
    e[(i, j)] = 1.0;
    e[(j, i)] = 1.0;
    e
}

/// The symmetric body-frame inertia from its six data entries ([`INERTIA_ENTRIES`]).
#[inline]
pub fn inertia_from_entries(d: &[f64]) -> Matrix3<f64> {
    let mut m = Matrix3::zeros();
    for (k, &(i, j)) in INERTIA_ENTRIES.iter().enumerate() {
        m[(i, j)] = d[k];
        m[(j, i)] = d[k];
    }
    m
}

/// The six data entries ([`INERTIA_ENTRIES`]) of a symmetric body-frame inertia.
pub fn inertia_entries(inertia: &Matrix3<f64>) -> [f64; 6] {
    INERTIA_ENTRIES.map(|(i, j)| inertia[(i, j)])
}

/// Generalised mass matrix `diag(m I₃, R I_body Rᵀ)` at orientation `q`
/// (`docs/model.md#newton-euler`).
pub fn mass_matrix(mass: f64, inertia_body: &Matrix3<f64>, q: &Vector4<f64>) -> Matrix6<f64> {
    let r = rotation_matrix(q);
    let iw = r * inertia_body * r.transpose();
    let mut m = Matrix6::zeros();
    for i in 0..3 {
        m[(i, i)] = mass;
        for j in 0..3 {
            m[(3 + i, 3 + j)] = iw[(i, j)];
        }
    }
    m
}

/// Inputs given as slices laid out as one flat vector of variables, as the Jacobian checker
/// does: for evaluating a standalone block in unit tests.
#[cfg(test)]
pub(crate) fn flat(params: &[&[f64]]) -> (Vec<f64>, Vec<ecp_model::InputRange>) {
    let mut z = Vec::new();
    let mut ranges = Vec::new();
    for p in params {
        ranges.push(ecp_model::InputRange::var(z.len(), p.len()));
        z.extend_from_slice(p);
    }
    (z, ranges)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inertia_entries_round_trip() {
        let d = [2.0, 3.0, 4.0, 0.1, -0.2, 0.3];
        let m = inertia_from_entries(&d);
        assert_eq!(m, m.transpose());
        assert_eq!((m[(0, 1)], m[(2, 0)], m[(1, 2)]), (0.1, -0.2, 0.3));
        assert_eq!(inertia_entries(&m), d);
        for k in 0..6 {
            let mut e = [0.0; 6];
            e[k] = 1.0;
            assert_eq!(inertia_direction(k), inertia_from_entries(&e));
        }
    }

    #[test]
    fn mass_matrix_rotates_the_inertia() {
        // A quarter turn about z swaps the x and y moments.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let m = mass_matrix(
            2.0,
            &Matrix3::from_diagonal(&Vector3::new(1.0, 5.0, 7.0)),
            &Vector4::new(s, 0.0, 0.0, s),
        );
        assert_eq!((m[(0, 0)], m[(2, 2)]), (2.0, 2.0));
        assert!((m[(3, 3)] - 5.0).abs() < 1e-14 && (m[(4, 4)] - 1.0).abs() < 1e-14);
        assert!((m[(5, 5)] - 7.0).abs() < 1e-14 && m[(3, 4)].abs() < 1e-14);
    }
}
