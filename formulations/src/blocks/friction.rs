//! The friction law (`docs/model.md#friction`): maximum power dissipation and the limit
//! ellipsoid, reading μ, e_t, e_o, e_r from the `friction` data block ([`super::FRICTION_DATA`]).

use nalgebra::Vector3;

use ecp_model::{Column, JacobianBlocks, Params, ResidualBlock};

use super::common::{ContactFrame, v3};

/// Friction parameters of one contact (`docs/model.md#friction`): Coulomb coefficient μ and the
/// semi-axes of the limit ellipsoid, `e_t`, `e_o` dimensionless and `e_r` a length (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrictionParams {
    /// Friction coefficient μ ≥ 0.
    pub mu: f64,
    /// Tangential semi-axis along t.
    pub e_t: f64,
    /// Tangential semi-axis along o.
    pub e_o: f64,
    /// Torsional semi-axis (m).
    pub e_r: f64,
}

impl FrictionParams {
    /// The values of a `friction` data block ([`super::FRICTION_DATA`]).
    pub fn values(&self) -> [f64; 4] {
        [self.mu, self.e_t, self.e_o, self.e_r]
    }
    /// From the values of a `friction` data block.
    #[inline]
    pub fn from_slice(d: &[f64]) -> Self {
        FrictionParams {
            mu: d[0],
            e_t: d[1],
            e_o: d[2],
            e_r: d[3],
        }
    }
    fn scales(&self) -> [f64; 3] {
        [
            self.e_t * self.e_t * self.mu,
            self.e_o * self.e_o * self.mu,
            self.e_r * self.e_r * self.mu,
        ]
    }
}

/// Maximum-power-dissipation friction law (`docs/model.md#friction`, paper eq. (friction)):
/// `0 = e_t² μ p_n W_tᵀν + p_t σ`, `0 = e_o² μ p_n W_oᵀν + p_o σ`, `0 = e_r² μ p_n W_rᵀν + p_r σ`.
///
/// Reads `ν` (6), `q` (7, for `r = a1 − x`), `a1` (3), `p_n` (1), `p_f` (3), `σ` (1) and the
/// `friction` data (4).
#[derive(Clone, Debug)]
pub struct FrictionDissipation {
    /// Contact frame.
    pub frame: ContactFrame,
}

impl FrictionDissipation {
    /// Index of the `friction` data input.
    pub const FRICTION: usize = 6;

    /// Slip velocities `(W_tᵀν, W_oᵀν, W_rᵀν)` at the ECP.
    fn slip(&self, nu: &[f64], x: &Vector3<f64>, a1: &Vector3<f64>) -> [f64; 3] {
        let v = v3(nu, 0);
        let w = v3(nu, 3);
        let r = a1 - x;
        let fr = &self.frame;
        [
            fr.t.dot(&v) + r.cross(&fr.t).dot(&w),
            fr.o.dot(&v) + r.cross(&fr.o).dot(&w),
            fr.n.dot(&w),
        ]
    }
}

impl ResidualBlock for FrictionDissipation {
    fn name(&self) -> &str {
        "friction"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[6, 7, 3, 1, 3, 1, 4]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let slip = self.slip(
            x.array::<6>(0),
            &v3(x.array::<7>(1), 0),
            &v3(x.array::<3>(2), 0),
        );
        let pn = x.array::<1>(3)[0];
        let pf = x.array::<3>(4);
        let sigma = x.array::<1>(5)[0];
        let s = FrictionParams::from_slice(x.array::<4>(Self::FRICTION)).scales();
        for i in 0..3 {
            out[i] = s[i] * pn * slip[i] + pf[i] * sigma;
        }
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let nu = x.array::<6>(0);
        let pos = v3(x.array::<7>(1), 0);
        let a1 = v3(x.array::<3>(2), 0);
        let slip = self.slip(nu, &pos, &a1);
        let pn = x.array::<1>(3)[0];
        let pf = x.array::<3>(4);
        let sigma = x.array::<1>(5)[0];
        let f = FrictionParams::from_slice(x.array::<4>(Self::FRICTION));
        if jac.wants(Self::FRICTION) {
            // r_i = e_i² μ p_n slip_i + p_i σ.
            let e = [f.e_t, f.e_o, f.e_r];
            for i in 0..3 {
                jac.set(Self::FRICTION, i, 0, e[i] * e[i] * pn * slip[i]);
                jac.set(Self::FRICTION, i, 1 + i, 2.0 * e[i] * f.mu * pn * slip[i]);
            }
        }
        // The unknowns' derivatives, unless only data are asked for (`∂F/∂θ`).
        if !(0..Self::FRICTION).any(|k| jac.wants(k)) {
            return;
        }
        let s = f.scales();
        let w = v3(nu, 3);
        let r = a1 - pos;
        let fr = &self.frame;
        // The columns located once ([`JacobianBlocks::columns`]).
        let cnu: [Column; 6] = jac.columns(0, 0);
        let cx: [Column; 3] = jac.columns(1, 0);
        let ca: [Column; 3] = jac.columns(2, 0);
        let cf: [Column; 3] = jac.columns(4, 0);
        let (cn, cs) = (jac.column(3, 0), jac.column(5, 0));
        // Rows t and o: slip = d·v + (r × d)·ω, ∂/∂r = d × ω.
        for (row, d) in [(0usize, fr.t), (1, fr.o)] {
            let c = s[row] * pn;
            let rd = r.cross(&d);
            let dr = d.cross(&w);
            for k in 0..3 {
                jac.put(cnu[k], row, c * d[k]);
                jac.put(cnu[3 + k], row, c * rd[k]);
                jac.put(ca[k], row, c * dr[k]);
                jac.put(cx[k], row, -c * dr[k]);
            }
        }
        for k in 0..3 {
            jac.put(cnu[3 + k], 2, s[2] * pn * fr.n[k]);
        }
        for i in 0..3 {
            jac.put(cn, i, s[i] * slip[i]);
            jac.put(cf[i], i, sigma);
            jac.put(cs, i, pf[i]);
        }
    }
}

/// Friction cone (paper eq. (15), `friction_c`), in the cone form
/// `0 ≤ μ p_n − ‖E⁻¹ p_f‖ ⊥ σ ≥ 0` with `E = diag(e_t, e_o, e_r)`. Reads `p_n` (1), `p_f` (3)
/// and the `friction` data (4).
///
/// The paper writes the squared row `μ² p_n² − p_t²/e_t² − p_o²/e_o² − p_r²/e_r²`; for `p_n ≥ 0`
/// both have the same solutions, but only the cone form bounds a spurious friction impulse at
/// `p_n = 0` by the natural residual (`docs/decisions.md#friction-row-in-cone-form`). Its only
/// kink is `p_f = 0`, where the Jacobian uses 0, an element of the generalised gradient.
#[derive(Clone, Copy, Debug, Default)]
pub struct FrictionEllipsoid;

impl FrictionEllipsoid {
    /// Index of the `friction` data input.
    pub const FRICTION: usize = 2;
}

impl ResidualBlock for FrictionEllipsoid {
    fn name(&self) -> &str {
        "friction_ellipsoid"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 3, 4]
    }
    fn jacobian_depends_on(&self, k: usize) -> Option<&[usize]> {
        // `∂/∂p_n = μ`.
        if k == 0 {
            Some(&[Self::FRICTION])
        } else {
            None
        }
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let f = FrictionParams::from_slice(x.array::<4>(Self::FRICTION));
        out[0] = f.mu * x.array::<1>(0)[0] - scaled_norm(&f, x.array::<3>(1)).0;
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let f = FrictionParams::from_slice(x.array::<4>(Self::FRICTION));
        let p = x.array::<3>(1);
        let (norm, scaled) = scaled_norm(&f, p);
        jac.set(0, 0, 0, f.mu);
        // At p = 0 the norm is not differentiable; 0 is an element of its generalised gradient
        // (the unit ball), so the Jacobian stays a valid element for semismooth methods.
        for k in 0..3 {
            let d = if norm > 0.0 { -scaled[k] / norm } else { 0.0 };
            jac.set(1, 0, k, d);
        }
        if jac.wants(Self::FRICTION) {
            // r = μ p_n − ‖u‖, u_k = p_k/e_k: ∂‖u‖/∂e_k = −u_k²/(e_k ‖u‖); at p = 0 the kink, 0
            // (the same element of the generalised gradient as above).
            jac.set(Self::FRICTION, 0, 0, x.array::<1>(0)[0]);
            let e = [f.e_t, f.e_o, f.e_r];
            if norm > 0.0 {
                for k in 0..3 {
                    let u = p[k] / e[k];
                    jac.set(Self::FRICTION, 0, 1 + k, u * u / (e[k] * norm));
                }
            }
        }
    }
}

/// `‖E⁻¹ p‖` with `E = diag(e_t, e_o, e_r)`, and the vector `E⁻² p` (its gradient times the norm).
fn scaled_norm(f: &FrictionParams, p: &[f64]) -> (f64, [f64; 3]) {
    let e = [f.e_t, f.e_o, f.e_r];
    let u = [p[0] / e[0], p[1] / e[1], p[2] / e[2]];
    let norm = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    (norm, [u[0] / e[0], u[1] / e[1], u[2] / e[2]])
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::super::common::flat;
    use super::*;

    const FRICTION: [f64; 4] = [0.4, 1.0, 0.8, 0.05];

    fn frame() -> ContactFrame {
        ContactFrame {
            n: Vector3::z(),
            t: Vector3::x(),
            o: Vector3::y(),
        }
    }

    #[test]
    fn dissipation_rows_at_a_known_point() {
        // Contact below the CM (r = −0.5 e_z), sliding at v = (1, 0, 0), spinning at ω_z = 2.
        let nu = [1.0, 0.0, 0.0, 0.0, 0.0, 2.0];
        let q = [0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0];
        let (a1, pn, pf, sigma) = ([0.0; 3], [2.0], [-0.3, 0.1, 0.02], [0.5]);
        let params: [&[f64]; 7] = [&nu, &q, &a1, &pn, &pf, &sigma, &FRICTION];
        let b = FrictionDissipation { frame: frame() };
        let mut out = [0.0; 3];
        let (z, ranges) = flat(&params);
        b.evaluate(Params::new(&z, &[], &ranges), &mut out);
        // slip = (1, 0, 2): r × t · ω = 0 for r ∥ n.
        let expect = [
            1.0 * 0.4 * 2.0 * 1.0 - 0.3 * 0.5,
            0.64 * 0.4 * 2.0 * 0.0 + 0.1 * 0.5,
            0.0025 * 0.4 * 2.0 * 2.0 + 0.02 * 0.5,
        ];
        for i in 0..3 {
            assert!((out[i] - expect[i]).abs() < 1e-15, "{out:?}");
        }
        let report = check_residual_block(&b, &params, &CheckOptions::default()).expect("sizes");
        assert!(report.ok(), "{report}");
        assert_eq!(report.pairs.len(), 7);
    }

    #[test]
    fn ellipsoid_row_at_a_known_point() {
        let (pn, pf) = ([2.0], [0.3, 0.4, 0.0]);
        let params: [&[f64]; 3] = [&pn, &pf, &FRICTION];
        let (z, ranges) = flat(&params);
        let mut out = [0.0];
        FrictionEllipsoid.evaluate(Params::new(&z, &[], &ranges), &mut out);
        let norm = (0.3f64.powi(2) + (0.4f64 / 0.8).powi(2)).sqrt();
        assert!((out[0] - (0.8 - norm)).abs() < 1e-15);
        let report =
            check_residual_block(&FrictionEllipsoid, &params, &CheckOptions::default()).unwrap();
        assert!(report.ok(), "{report}");
    }
}
