//! The kinematic map (`docs/model.md#kinematic-map`).

use nalgebra::Vector4;

use ecp_model::{Column, JacobianBlocks, Params, ResidualBlock};

use super::common::{v3, v4};
use super::data::start;
use crate::rotation::kinematic_map;

/// Kinematic map (`docs/model.md#kinematic-map`): `0 = −x + x^u + h v`,
/// `0 = −Q + Q^u + (h/2) E(Q^u) ω`.
///
/// Reads `q` (7), `ν` (6), and the data `start` (13, [`super::START_DATA`]: x^u and Q^u are used)
/// and `h` (1). Linear in the unknowns.
#[derive(Clone, Copy, Debug, Default)]
pub struct KinematicMap;

impl KinematicMap {
    /// Index of the `start` data input.
    pub const START: usize = 2;
    /// Index of the `h` data input.
    pub const H: usize = 3;
}

impl ResidualBlock for KinematicMap {
    fn name(&self) -> &str {
        "kinematic_map"
    }
    fn num_residuals(&self) -> usize {
        7
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[7, 6, 13, 1]
    }
    fn jacobian_depends_on(&self, k: usize) -> Option<&[usize]> {
        // Linear in the unknowns: `−I` for `q`, `h` and `(h/2) E(Q^u)` for `ν`.
        match k {
            0 => Some(&[]),
            1 => Some(&[Self::START, Self::H]),
            _ => None,
        }
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let q = x.array::<7>(0);
        let nu = x.array::<6>(1);
        let s = x.array::<13>(Self::START);
        let h = x.array::<1>(Self::H)[0];
        for i in 0..3 {
            out[i] = -q[i] + s[start::X + i] + h * nu[i];
        }
        let q_start = v4(s, start::Q);
        let e = kinematic_map(&q_start);
        let w = v3(nu, 3);
        let dq = e * w * (0.5 * h);
        for i in 0..4 {
            out[3 + i] = -q[3 + i] + q_start[i] + dq[i];
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let s = x.array::<13>(Self::START);
        let h = x.array::<1>(Self::H)[0];
        let q_start = v4(s, start::Q);
        // The columns located once ([`JacobianBlocks::columns`]); the diagonals added as
        // `add_diagonal` adds them.
        let cq: [Column; 7] = jac.columns(0, 0);
        for (i, c) in cq.into_iter().enumerate() {
            jac.put_add(c, i, -1.0);
        }
        let cv: [Column; 6] = jac.columns(1, 0);
        for (i, &c) in cv[..3].iter().enumerate() {
            jac.put_add(c, i, h);
        }
        let e = kinematic_map(&q_start);
        for i in 0..4 {
            for j in 0..3 {
                jac.put(cv[3 + j], 3 + i, 0.5 * h * e[(i, j)]);
            }
        }
        let w = v3(x.array::<6>(1), 3);
        if jac.wants(Self::START) {
            jac.add_diagonal(Self::START, 0, start::X, 3, 1.0);
            jac.add_diagonal(Self::START, 3, start::Q, 4, 1.0);
            // E(Q) ω is linear in Q: its derivative along Q_k is E(e_k) ω.
            for k in 0..4 {
                let col = kinematic_map(&Vector4::ith(k, 1.0)) * w * (0.5 * h);
                for i in 0..4 {
                    jac.add(Self::START, 3 + i, start::Q + k, col[i]);
                }
            }
        }
        if jac.wants(Self::H) {
            let nu = x.array::<6>(1);
            let dq = e * w * 0.5;
            for i in 0..3 {
                jac.set(Self::H, i, 0, nu[i]);
            }
            for i in 0..4 {
                jac.set(Self::H, 3 + i, 0, dq[i]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::super::common::flat;
    use super::*;

    #[test]
    fn rows_at_a_known_point_and_jacobian() {
        // From rest at the origin with identity orientation, ν = (1, 2, 3, 0, 0, 2), h = 0.1:
        // x = h v, Q = (1, 0, 0, h ω_z / 2).
        let q = [0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.1];
        let nu = [1.0, 2.0, 3.0, 0.0, 0.0, 2.0];
        let mut s = [0.0; 13];
        s[start::Q] = 1.0;
        let params: [&[f64]; 4] = [&q, &nu, &s, &[0.1]];
        let (z, ranges) = flat(&params);
        let mut out = [0.0; 7];
        KinematicMap.evaluate(Params::new(&z, &[], &ranges), &mut out);
        assert!(out.iter().all(|v| v.abs() < 1e-15), "{out:?}");
        // Jacobian, data included, at a generic point.
        let q = [0.3, -0.2, 0.9, 0.9, 0.2, -0.1, 0.3];
        let nu = [0.5, -1.0, 0.2, 1.5, -0.7, 2.0];
        let s = [
            0.1, 0.2, 0.3, 0.8, 0.1, 0.5, -0.3, 0.4, 0.5, 0.6, -1.0, 0.3, 0.2,
        ];
        let report = check_residual_block(
            &KinematicMap,
            &[&q, &nu, &s, &[0.01]],
            &CheckOptions::default(),
        )
        .expect("sizes");
        assert!(report.ok(), "{report}");
    }
}
