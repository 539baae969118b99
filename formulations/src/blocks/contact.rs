//! The contact conditions C1–C5 between Conv(F) and a half-space G (`docs/model.md#contact`):
//! the closest-point rows (C1–C4) and non-penetration (C5). They depend on the shapes, the
//! half-space and the row scale; C4 and C5 read the half-space's offset as data (the stepper
//! moves the step problem's origin for far scenes, `docs/decisions.md#recentred-origin-for-far-scenes`).

use nalgebra::Vector3;

use ecp_model::{Column, JacobianBlocks, Params, ResidualBlock};

use super::common::{v3, v4};
use crate::rotation::{rotation_matrix, rotation_matrix_and_derivatives};

/// Contact condition C1 (`docs/model.md#contact`): `0 = a1 − a2 − l_g ∇g(a2)`, normalised on the
/// half-space G (whose gradient is its constant normal `n_G`). Reads `a1`, `a2`, `l_g`.
#[derive(Clone, Debug)]
pub struct ClosestPointAlignment {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for ClosestPointAlignment {
    fn name(&self) -> &str {
        "ecp_c1"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 3, 1]
    }
    fn jacobian_depends_on(&self, _k: usize) -> Option<&[usize]> {
        // Linear in every input, with the block's own coefficients.
        Some(&[])
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let (a1, a2) = (x.array::<3>(0), x.array::<3>(1));
        let lg = x.array::<1>(2)[0];
        for i in 0..3 {
            out[i] = self.scale * (a1[i] - a2[i] - lg * self.normal[i]);
        }
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.add_diagonal(0, 0, 0, 3, self.scale);
        jac.add_diagonal(1, 0, 0, 3, -self.scale);
        for i in 0..3 {
            jac.set(2, i, 0, -self.scale * self.normal[i]);
        }
    }
}

/// Contact condition C2 (`docs/model.md#contact`): `0 = ∇g(a2) + Σ_i l_i ∇f_i(a1)` with
/// `∇f_i = R(Q) n̂_i` for the faces of Conv(F). Reads `l` (m) and `q` (7).
#[derive(Clone, Debug)]
pub struct NormalCone {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Outward unit face normals of Conv(F) in the body frame.
    pub face_normals: Vec<Vector3<f64>>,
    sizes: [usize; 2],
}

impl NormalCone {
    /// The block for a hull with the given face normals.
    pub fn new(normal: Vector3<f64>, face_normals: Vec<Vector3<f64>>) -> Self {
        let m = face_normals.len();
        NormalCone {
            normal,
            face_normals,
            sizes: [m, 7],
        }
    }
}

impl ResidualBlock for NormalCone {
    fn name(&self) -> &str {
        "ecp_c2"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let l = x.block(0);
        let r = rotation_matrix(&v4(x.array::<7>(1), 3));
        let mut s = Vector3::zeros();
        for (li, ni) in l.iter().zip(&self.face_normals) {
            s += ni * *li;
        }
        let v = self.normal + r * s;
        out.copy_from_slice(v.as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let l = x.block(0);
        let qv = v4(x.array::<7>(1), 3);
        let (r, dr) = rotation_matrix_and_derivatives(&qv);
        let mut s = Vector3::zeros();
        for (i, (li, ni)) in l.iter().zip(&self.face_normals).enumerate() {
            s += ni * *li;
            let col = r * ni;
            let c = jac.column(0, i);
            for k in 0..3 {
                jac.put(c, k, col[k]);
            }
        }
        let cq: [Column; 4] = jac.columns(1, 3);
        for (d, c) in dr.iter().zip(cq) {
            let col = d * s;
            for k in 0..3 {
                jac.put(c, k, col[k]);
            }
        }
    }
}

/// Contact condition C3 (`docs/model.md#contact`): `0 ≤ l_i ⊥ −f_i(a1) ≥ 0` for every face of
/// Conv(F), `f_i(p) = n̂_iᵀ R(Q)ᵀ (p − x) − d_i`. Reads `a1` (3) and `q` (7).
#[derive(Clone, Debug)]
pub struct HullFaces {
    /// Outward unit face normals in the body frame.
    pub face_normals: Vec<Vector3<f64>>,
    /// Face offsets `d_i` (inside: `n̂_i · p ≤ d_i`).
    pub offsets: Vec<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for HullFaces {
    fn name(&self) -> &str {
        "ecp_c3"
    }
    fn num_residuals(&self) -> usize {
        self.offsets.len()
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 7]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let a1 = v3(x.array::<3>(0), 0);
        let q = x.array::<7>(1);
        let r = rotation_matrix(&v4(q, 3));
        let local = r.transpose() * (a1 - v3(q, 0));
        for (o, (ni, di)) in out
            .iter_mut()
            .zip(self.face_normals.iter().zip(&self.offsets))
        {
            *o = -self.scale * (ni.dot(&local) - di);
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let a1 = v3(x.array::<3>(0), 0);
        let q = x.array::<7>(1);
        let qv = v4(q, 3);
        let (r, dr) = rotation_matrix_and_derivatives(&qv);
        let rel = a1 - v3(q, 0);
        // ∂(−f_i)/∂Q_k = −n̂_iᵀ (∂R/∂Q_k)ᵀ rel = −(∂R/∂Q_k n̂_i) · rel.
        let drt_rel: [Vector3<f64>; 4] = [
            dr[0].transpose() * rel,
            dr[1].transpose() * rel,
            dr[2].transpose() * rel,
            dr[3].transpose() * rel,
        ];
        // The ten columns located once (six faces write sixty entries).
        let ca: [Column; 3] = jac.columns(0, 0);
        let cq: [Column; 7] = jac.columns(1, 0);
        for (i, ni) in self.face_normals.iter().enumerate() {
            let g = r * ni * self.scale;
            for k in 0..3 {
                jac.put(ca[k], i, -g[k]);
                jac.put(cq[k], i, g[k]);
            }
            for (k, d) in drt_rel.iter().enumerate() {
                jac.put(cq[3 + k], i, -self.scale * ni.dot(d));
            }
        }
    }
}

/// Contact condition C4 (`docs/model.md#contact`): `0 ≤ l_g ⊥ −g(a2) ≥ 0`,
/// `g(p) = n_Gᵀ p − c`. Reads `a2` (3) and the half-space's offset c (data, 1).
#[derive(Clone, Debug)]
pub struct HalfSpaceSide {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for HalfSpaceSide {
    fn name(&self) -> &str {
        "ecp_c4"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 1]
    }
    fn jacobian_depends_on(&self, k: usize) -> Option<&[usize]> {
        // Linear in `a` with the block's own coefficients.
        if k == 0 { Some(&[]) } else { None }
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        out[0] = -self.scale * (self.normal.dot(&v3(x.array::<3>(0), 0)) - x.array::<1>(1)[0]);
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        for k in 0..3 {
            jac.set(0, 0, k, -self.scale * self.normal[k]);
        }
        jac.set(1, 0, 0, self.scale);
    }
}

/// Contact condition C5 (`docs/model.md#contact`), non-penetration:
/// `0 ≤ p_n ⊥ g(a1) ≥ 0`. Reads `a1` (3) and the half-space's offset c (data, 1).
#[derive(Clone, Debug)]
pub struct NonPenetration {
    /// Unit outward normal of G.
    pub normal: Vector3<f64>,
    /// Row scale `s > 0` (the rows are `s·r`): makes these length-valued rows commensurate
    /// with the impulse-valued ones, which the merit functions of the backends need. It does not
    /// change the solution set (`docs/model.md#contact`, "Scaling").
    pub scale: f64,
}

impl ResidualBlock for NonPenetration {
    fn name(&self) -> &str {
        "ecp_c5"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[3, 1]
    }
    fn jacobian_depends_on(&self, k: usize) -> Option<&[usize]> {
        // Linear in `a` with the block's own coefficients.
        if k == 0 { Some(&[]) } else { None }
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        out[0] = self.scale * (self.normal.dot(&v3(x.array::<3>(0), 0)) - x.array::<1>(1)[0]);
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        for k in 0..3 {
            jac.set(0, 0, k, self.scale * self.normal[k]);
        }
        jac.set(1, 0, 0, -self.scale);
    }
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::super::common::flat;
    use super::*;

    /// A unit cube's six faces (body frame, offsets 0.5).
    fn cube() -> (Vec<Vector3<f64>>, Vec<f64>) {
        let n = vec![
            Vector3::x(),
            -Vector3::x(),
            Vector3::y(),
            -Vector3::y(),
            Vector3::z(),
            -Vector3::z(),
        ];
        (n, vec![0.5; 6])
    }

    fn eval(b: &dyn ResidualBlock, params: &[&[f64]]) -> Vec<f64> {
        let (z, ranges) = flat(params);
        let mut out = vec![0.0; b.num_residuals()];
        b.evaluate(Params::new(&z, &[], &ranges), &mut out);
        out
    }

    fn check(b: &dyn ResidualBlock, params: &[&[f64]]) {
        let report = check_residual_block(b, params, &CheckOptions::default()).expect("sizes");
        assert!(report.ok(), "{report}");
        assert_eq!(report.pairs.len(), params.len());
    }

    // A tilted cube at x = (0.1, 0, 0.7) above the ground z ≤ 0.1 (normal e_z, offset 0.1).
    const Q: [f64; 7] = [0.1, 0.0, 0.7, 0.98, 0.1, -0.15, 0.05];
    const A1: [f64; 3] = [0.05, 0.1, 0.2];
    const A2: [f64; 3] = [0.05, 0.1, 0.1];

    #[test]
    fn c1_c2_c3_at_a_known_point() {
        let c1 = ClosestPointAlignment {
            normal: Vector3::z(),
            scale: 100.0,
        };
        let r = eval(&c1, &[&A1, &A2, &[0.1]]);
        assert!(r.iter().all(|v| v.abs() < 1e-12), "{r:?}");
        check(&c1, &[&A1, &A2, &[0.3]]);
        let (normals, offsets) = cube();
        let c2 = NormalCone::new(Vector3::z(), normals.clone());
        // Identity orientation, multiplier 1 on the bottom face: −e_z + e_z·... = n_G + R(−e_z).
        let l = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let identity = [0.0, 0.0, 0.7, 1.0, 0.0, 0.0, 0.0];
        let r = eval(&c2, &[&l, &identity]);
        assert!(r.iter().all(|v| v.abs() < 1e-15), "{r:?}");
        check(&c2, &[&[0.2, 0.0, 0.1, 0.0, 0.3, 0.5], &Q]);
        let c3 = HullFaces {
            face_normals: normals,
            offsets,
            scale: 2.0,
        };
        // The cube's centre: −f_i = 0.5 for every face.
        let r = eval(&c3, &[&[0.0, 0.0, 0.7], &identity]);
        assert!(r.iter().all(|v| (v - 1.0).abs() < 1e-15), "{r:?}");
        check(&c3, &[&A1, &Q]);
    }

    #[test]
    fn c4_c5_read_the_offset() {
        let c4 = HalfSpaceSide {
            normal: Vector3::z(),
            scale: 10.0,
        };
        let c5 = NonPenetration {
            normal: Vector3::z(),
            scale: 10.0,
        };
        assert_eq!(eval(&c4, &[&A2, &[0.1]]), vec![0.0]);
        assert!((eval(&c5, &[&A1, &[0.1]])[0] - 1.0).abs() < 1e-14);
        assert!((eval(&c5, &[&A1, &[0.3]])[0] + 1.0).abs() < 1e-14);
        check(&c4, &[&A2, &[0.3]]);
        check(&c5, &[&A1, &[0.3]]);
    }
}
