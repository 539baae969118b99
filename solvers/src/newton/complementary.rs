//! The complementary start of Newton's last restart
//! ([`super::NewtonSettings::complementary_restart`], `docs/newton.md#the-complementary-start`).

use ecp_model::{Mcp, Solution, SolveError};

use super::{NewtonSolver, fold_attempt};

impl NewtonSolver {
    /// Whether the failed attempts' best end point lies within `near` times the tolerance (the
    /// gate of [`super::NewtonSettings::complementary_restart`] and of
    /// [`super::NewtonSettings::early_complementary_restart`]; `None`: never).
    pub(super) fn near_enough(&self, best: &Solution, near: Option<f64>) -> bool {
        near.is_some_and(|near| best.summary.residual <= near * self.settings.tolerance)
    }

    /// The plain iteration from the complementary start of `z0` ([`complementary_start`]),
    /// folded into the failed attempts' count and best point as
    /// [`NewtonSolver::solve_restarted`]'s other attempts (`Some` when it ends the solve). Run
    /// with the first attempt's settings (the ratio test and the residual damping are those of
    /// attempt 0; its iterations count there in a profile) and counted as
    /// `complementary_restarts`.
    pub(super) fn complementary_attempt(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        spent: &mut usize,
        best: &mut Box<Solution>,
    ) -> Option<Result<Solution, SolveError>> {
        let start = complementary_start(mcp, z0)?;
        self.attempt = 0;
        let result = self.solve_plain_tallied(mcp, &start, "complementary_restarts");
        fold_attempt(result, spent, best)
    }
}

/// The start `z0` with every component that has a finite bound put on the bound that the sign of
/// `F(z0)` points to: `z_i = l_i` where `F_i(z0) > 0` and `z_i > l_i`, `z_i = u_i` where
/// `F_i(z0) < 0` and `z_i < u_i` — the face of the box on which each pair with that sign of `F`
/// is complementary (MCP conditions, `docs/model.md#mcp`). `None` when no component moves (the
/// start would be `z0` again).
///
/// Where a pair is strictly positive on both sides at `z0` (a slip rate `σ > 0` of a contact whose
/// friction cone row is slack by round-off), the Fischer–Burmeister merit sees an almost
/// satisfied pair, and the iteration from `z0` stays on that branch of the pair; from this start
/// it begins on the other branch (`061_v_trough` of seed 20261128, step 17: a box coming to rest
/// in a V trough, `docs/newton.md#the-complementary-start`).
pub(super) fn complementary_start(mcp: &dyn Mcp, z0: &[f64]) -> Option<Vec<f64>> {
    let mut f = vec![0.0; z0.len()];
    mcp.evaluate(z0, &mut f);
    let (l, u) = (mcp.lower(), mcp.upper());
    let mut z = z0.to_vec();
    let mut moved = false;
    for i in 0..z.len() {
        let bound = if l[i].is_finite() && f[i] > 0.0 && z[i] > l[i] {
            l[i]
        } else if u[i].is_finite() && f[i] < 0.0 && z[i] < u[i] {
            u[i]
        } else {
            continue;
        };
        z[i] = bound;
        moved = true;
    }
    moved.then_some(z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecp_model::FnMcp;

    /// `F(z) = (z_0 − 1, 2 − z_1, z_2)` on `[0, ∞) × (−∞, 3] × ℝ`.
    fn three() -> FnMcp {
        FnMcp::dense(
            vec![0.0, f64::NEG_INFINITY, f64::NEG_INFINITY],
            vec![f64::INFINITY, 3.0, f64::INFINITY],
            |z, f| {
                f[0] = z[0] - 1.0;
                f[1] = 2.0 - z[1];
                f[2] = z[2];
            },
            |_, j| {
                j.fill(0.0);
                j[0] = 1.0;
                j[4] = -1.0;
                j[8] = 1.0;
            },
        )
        .expect("a valid MCP")
    }

    #[test]
    fn each_bounded_component_goes_to_the_bound_its_f_points_to() {
        let mcp = three();
        // F = (1, −0.5, 5): z_0 to its lower bound 0, z_1 to its upper bound 3, the free z_2 stays.
        let z = complementary_start(&mcp, &[2.0, 2.5, 5.0]).expect("two components move");
        assert_eq!(z, vec![0.0, 3.0, 5.0]);
        // F = (−0.5, 1, 5): neither sign points to a bound, nothing moves.
        assert!(complementary_start(&mcp, &[0.5, 1.0, 5.0]).is_none());
        // F = (−1, −1, 5) with z_1 at its upper bound already: nothing moves.
        assert!(complementary_start(&mcp, &[0.0, 3.0, 5.0]).is_none());
    }
}
