//! The closest-point rows of a contact between two convex hulls F and G, both possibly moving
//! (`docs/model.md#contact-between-two-bodies`): the choice-free normalisation (K1)–(K4) of the
//! paper's KKT conditions (8)–(12).
//!
//! With `ν_G = Σ_j μ_j ∇g_j(a2) = R_G Σ_j μ_j m̂_j` (a convex combination of G's active face
//! gradients, the outward normal of Conv(G) at `a2`):
//!
//! | row | equation | pairs with | type |
//! |---|---|---|---|
//! | K1 | `0 = a1 − a2 − d ν_G` | `a1` (free) | [`PairAlignment`] |
//! | K2 | `0 = ν_G + Σ_i l_i ∇f_i` | `a2` (free) | [`PairNormalCone`] |
//! | K3 | `0 = Σ_j μ_j − 1` | `d` (free) | [`PairNormalisation`] |
//! | faces of F | `0 ≤ l_i ⊥ −f_i(a1) ≥ 0` | `l` | [`super::HullFaces`] on F's faces and pose |
//! | faces of G | `0 ≤ μ_j ⊥ −g_j(a2) ≥ 0` | `μ` | [`super::HullFaces`] on G's faces and pose |
//! | K4 | `0 ≤ p_n ⊥ d ≥ 0` | `p_n` | [`PairSeparation`] |
//!
//! The poses of F and G are their END-of-step `q` inputs: a variable block for a dynamic body,
//! a data block for a fixed or kinematic one; the blocks are the same either way. The
//! length-valued rows (K1, K4 and the face rows) carry the row scale `s = 1/h` of the half-space
//! rows (`docs/model.md#contact`).

use nalgebra::Vector3;

use ecp_model::{JacobianBlocks, Params, ResidualBlock};

use super::common::v4;
use super::pair_frame::SupportNormal;

/// (K1) `0 = s (a1 − a2 − d ν_G)`, `ν_G = R(Q_G) Σ_j μ_j m̂_j`. Reads `a1` (3), `a2` (3), `d` (1),
/// `μ` (m_G) and G's `q` (7).
#[derive(Clone, Debug)]
pub struct PairAlignment {
    /// G's outward unit face normals `m̂_j` (body frame).
    pub g_normals: Vec<Vector3<f64>>,
    /// Row scale `s > 0` (`docs/model.md#contact`, the 1/h scaling of length-valued rows).
    pub scale: f64,
    sizes: [usize; 5],
}

impl PairAlignment {
    /// Index of the `μ` input.
    pub const MU: usize = 3;
    /// Index of G's `q` input.
    pub const Q_G: usize = 4;

    /// The block for G's face normals and the row scale.
    pub fn new(g_normals: Vec<Vector3<f64>>, scale: f64) -> Self {
        let m = g_normals.len();
        PairAlignment {
            g_normals,
            scale,
            sizes: [3, 3, 1, m, 7],
        }
    }
}

impl ResidualBlock for PairAlignment {
    fn name(&self) -> &str {
        "pair_k1"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let (a1, a2, d) = (x.block(0), x.block(1), x.block(2)[0]);
        let nu = SupportNormal::new(
            &self.g_normals,
            x.block(Self::MU),
            &v4(x.block(Self::Q_G), 3),
        );
        for i in 0..3 {
            out[i] = self.scale * (a1[i] - a2[i] - d * nu.value[i]);
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let s = self.scale;
        let d = x.block(2)[0];
        let nu = SupportNormal::new(
            &self.g_normals,
            x.block(Self::MU),
            &v4(x.block(Self::Q_G), 3),
        );
        jac.add_diagonal(0, 0, 0, 3, s);
        jac.add_diagonal(1, 0, 0, 3, -s);
        for i in 0..3 {
            jac.set(2, i, 0, -s * nu.value[i]);
        }
        // ∂row_i/∂ν_G = −s d e_i.
        let rows = [0, 1, 2].map(|i| (i, Vector3::ith(i, -s * d)));
        nu.add_chain(&self.g_normals, &rows, Self::MU, Self::Q_G, jac);
    }
}

/// (K2) `0 = ν_G + Σ_i l_i ∇f_i`, `∇f_i = R(Q_F) n̂_i`: the normal cones of the two hulls at
/// `a1` and `a2` are opposite. Dimensionless, not scaled (like C2). Reads `μ` (m_G), G's `q`
/// (7), `l` (m_F) and F's `q` (7).
#[derive(Clone, Debug)]
pub struct PairNormalCone {
    /// F's outward unit face normals `n̂_i` (body frame).
    pub f_normals: Vec<Vector3<f64>>,
    /// G's outward unit face normals `m̂_j` (body frame).
    pub g_normals: Vec<Vector3<f64>>,
    sizes: [usize; 4],
}

impl PairNormalCone {
    /// Index of the `μ` input.
    pub const MU: usize = 0;
    /// Index of G's `q` input.
    pub const Q_G: usize = 1;
    /// Index of the `l` input.
    pub const L: usize = 2;
    /// Index of F's `q` input.
    pub const Q_F: usize = 3;

    /// The block for the face normals of F and G.
    pub fn new(f_normals: Vec<Vector3<f64>>, g_normals: Vec<Vector3<f64>>) -> Self {
        let sizes = [g_normals.len(), 7, f_normals.len(), 7];
        PairNormalCone {
            f_normals,
            g_normals,
            sizes,
        }
    }
}

impl ResidualBlock for PairNormalCone {
    fn name(&self) -> &str {
        "pair_k2"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let nu = SupportNormal::new(
            &self.g_normals,
            x.block(Self::MU),
            &v4(x.block(Self::Q_G), 3),
        );
        let cone = SupportNormal::new(
            &self.f_normals,
            x.block(Self::L),
            &v4(x.block(Self::Q_F), 3),
        );
        out.copy_from_slice((nu.value + cone.value).as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let rows = [0, 1, 2].map(|i| (i, Vector3::ith(i, 1.0)));
        let nu = SupportNormal::new(
            &self.g_normals,
            x.block(Self::MU),
            &v4(x.block(Self::Q_G), 3),
        );
        nu.add_chain(&self.g_normals, &rows, Self::MU, Self::Q_G, jac);
        let cone = SupportNormal::new(
            &self.f_normals,
            x.block(Self::L),
            &v4(x.block(Self::Q_F), 3),
        );
        cone.add_chain(&self.f_normals, &rows, Self::L, Self::Q_F, jac);
    }
}

/// (K3) `0 = Σ_j μ_j − 1`: `ν_G` is a convex combination of G's face gradients. Paired with the
/// free separation `d`. Dimensionless, not scaled. Reads `μ` (m_G).
#[derive(Clone, Debug)]
pub struct PairNormalisation {
    sizes: [usize; 1],
}

impl PairNormalisation {
    /// The block for a G with `faces` faces.
    pub fn new(faces: usize) -> Self {
        PairNormalisation { sizes: [faces] }
    }
}

impl ResidualBlock for PairNormalisation {
    fn name(&self) -> &str {
        "pair_k3"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        out[0] = x.block(0).iter().sum::<f64>() - 1.0;
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        for j in 0..self.sizes[0] {
            jac.set(0, 0, j, 1.0);
        }
    }
}

/// (K4) `0 ≤ p_n ⊥ s d ≥ 0`: no impulse unless the hulls touch, and they never overlap
/// (`a1 − a2 = d ν_G` with `d ≥ 0`). Reads `d` (1).
#[derive(Clone, Copy, Debug)]
pub struct PairSeparation {
    /// Row scale `s > 0` (`docs/model.md#contact`, the 1/h scaling of length-valued rows).
    pub scale: f64,
}

impl ResidualBlock for PairSeparation {
    fn name(&self) -> &str {
        "pair_k4"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        out[0] = self.scale * x.block(0)[0];
    }
    fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.set(0, 0, 0, self.scale);
    }
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::super::common::flat;
    use super::*;

    /// A unit cube's faces (body frame): +x, −x, +y, −y, +z, −z.
    fn cube() -> Vec<Vector3<f64>> {
        vec![
            Vector3::x(),
            -Vector3::x(),
            Vector3::y(),
            -Vector3::y(),
            Vector3::z(),
            -Vector3::z(),
        ]
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
        let cols: usize = b.parameter_sizes().iter().sum();
        assert_eq!(report.entries, cols * b.num_residuals());
    }

    #[test]
    fn k_rows_vanish_at_the_closest_points_of_two_cubes() {
        // G at the origin turned a quarter about z (its faces permute, its +z face stays up), F
        // 0.5 above it: a1 on F's bottom face, a2 on G's top, d = 0.5.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let q_g = [0.0, 0.0, 0.0, s, 0.0, 0.0, s];
        let q_f = [0.2, -0.1, 1.5, 1.0, 0.0, 0.0, 0.0];
        let (a1, a2, d) = ([0.2, -0.1, 1.0], [0.2, -0.1, 0.5], [0.5]);
        let mu = [0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        let l = [0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let k1 = PairAlignment::new(cube(), 100.0);
        let r = eval(&k1, &[&a1, &a2, &d, &mu, &q_g]);
        assert!(r.iter().all(|v| v.abs() < 1e-13), "{r:?}");
        let k2 = PairNormalCone::new(cube(), cube());
        let r = eval(&k2, &[&mu, &q_g, &l, &q_f]);
        assert!(r.iter().all(|v| v.abs() < 1e-15), "{r:?}");
        assert_eq!(eval(&PairNormalisation::new(6), &[&mu]), vec![0.0]);
        assert_eq!(eval(&PairSeparation { scale: 100.0 }, &[&d]), vec![50.0]);
        // Off the solution: K1 measures a1 − a2 − d ν_G with ν_G = R_G Σ μ m̂.
        let mu2 = [0.5, 0.0, 0.0, 0.0, 0.5, 0.0];
        let r = eval(&k1, &[&a1, &a2, &d, &mu2, &q_g]);
        // R_G e_x = e_y: ν_G = (0, 0.5, 0.5).
        let want = [0.0, -25.0, 25.0];
        for i in 0..3 {
            assert!((r[i] - want[i]).abs() < 1e-12, "{r:?}");
        }
    }

    #[test]
    fn jacobians_at_a_generic_point() {
        let q_g = [0.3, -0.2, 0.1, 0.9, 0.2, -0.3, 0.1];
        let q_f = [0.1, 0.4, 1.2, 0.7, -0.1, 0.5, 0.3];
        let mu = [0.1, 0.0, 0.4, 0.2, 0.7, 0.05];
        let l = [0.3, 0.2, 0.0, 0.1, 0.6, 1.1];
        let (a1, a2, d) = ([0.2, -0.3, 1.1], [0.1, 0.2, 0.4], [0.35]);
        check(
            &PairAlignment::new(cube(), 50.0),
            &[&a1, &a2, &d, &mu, &q_g],
        );
        let mut tetra = cube();
        tetra.truncate(3);
        tetra.push(Vector3::new(-1.0, -1.0, -1.0).normalize());
        check(
            &PairNormalCone::new(tetra, cube()),
            &[&mu, &q_g, &l[..4], &q_f],
        );
        check(&PairNormalisation::new(6), &[&mu]);
        check(&PairSeparation { scale: 7.0 }, &[&d]);
    }
}
