//! A linear spring from a body's centre of mass to a fixed anchor: a ready-made user force
//! (`crate::step::Force::spring`), an impulse added to the body's Newton–Euler rows
//! (`docs/model.md#newton-euler`).

use ecp_model::{JacobianBlocks, Params, ResidualBlock};

/// `−h k (x − anchor)` on the translational rows of Newton–Euler, 0 on the rotational ones: the
/// impulse over a span of length `h` of a spring of stiffness `k` (N/m) between the CM at the
/// end of the span `x` and `anchor`.
///
/// Reads, in the input order of a user force: `ν` (6, unused), `q` (7: x, Q), `h` (1), then its
/// data `k` (1) and `anchor` (3, in the step problem's coordinates, world coordinates unless the
/// formulation moved its origin for a far scene, `docs/model.md#far-scenes`).
#[derive(Clone, Copy, Debug, Default)]
pub struct Spring;

impl Spring {
    /// Input index of `q`.
    const Q: usize = 1;
    /// Input index of `h`.
    const H: usize = 2;
    /// Input index of `k`.
    const K: usize = 3;
    /// Input index of the anchor.
    const ANCHOR: usize = 4;
}

impl ResidualBlock for Spring {
    fn name(&self) -> &str {
        "spring"
    }
    fn num_residuals(&self) -> usize {
        6
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[6, 7, 1, 1, 3]
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        let (q, h, k, a) = (
            p.block(Self::Q),
            p.block(Self::H)[0],
            p.block(Self::K)[0],
            p.block(Self::ANCHOR),
        );
        out.fill(0.0);
        for i in 0..3 {
            out[i] = -h * k * (q[i] - a[i]);
        }
    }
    fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let (q, h, k, a) = (
            p.block(Self::Q),
            p.block(Self::H)[0],
            p.block(Self::K)[0],
            p.block(Self::ANCHOR),
        );
        for i in 0..3 {
            jac.set(Self::Q, i, i, -h * k);
            jac.set(Self::H, i, 0, -k * (q[i] - a[i]));
            jac.set(Self::K, i, 0, -h * (q[i] - a[i]));
            jac.set(Self::ANCHOR, i, i, h * k);
        }
    }
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, check_residual_block};

    use super::*;

    #[test]
    fn jacobian_matches_central_differences() {
        let x: [&[f64]; 5] = [
            &[0.1, -0.2, 0.3, 0.0, 0.0, 0.0],
            &[0.4, 0.5, -0.6, 0.9, 0.1, 0.2, 0.3],
            &[0.01],
            &[250.0],
            &[1.0, -1.0, 0.5],
        ];
        let rep = check_residual_block(&Spring, &x, &CheckOptions::default())
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(rep.ok(), "{rep}");
    }
}
