//! Josephy–Newton steps: a restart of Newton's plain iteration that sorts out the
//! complementarity branches by pivoting ([`super::NewtonSettings::josephy_newton`],
//! `docs/newton.md#josephy-newton-steps`).
//!
//! Each step solves the MCP linearised at the current point, `F(z_k) + J(z_k)(z − z_k)` with
//! the problem's bounds, by Lemke's method (the pivoting core of the PATH-like backend), and moves
//! towards that solution under a backtracking search on the Fischer–Burmeister merit. The
//! linearisation's solution carries every pair on the branch the linearisation chooses at once —
//! where the semismooth Newton direction of the Fischer–Burmeister map weighs both branches of a
//! pair near its kink and, on a step whose contacts load, unload or change feature, ends in a
//! local minimiser of the merit after a few hundred iterations of restarts.

use ecp_model::mcp::fb_vector;
use ecp_model::{Mcp, natural_residual};

use crate::pivot::{
    AffineMatrix, AffineMcp, AffineStart, Lemke, LemkeSettings, mul_vec_nonzero_columns,
};

/// Where [`josephy_newton_steps`] ended.
pub(super) struct JosephyEnd {
    /// The point of least natural residual met.
    pub z: Vec<f64>,
    /// Its natural residual.
    pub residual: f64,
    /// Active-set Newton steps taken (each one evaluation of `F` and `J` and one LU).
    pub iterations: usize,
}

/// Backtracking halvings tried on a step that does not lower the merit.
const HALVINGS: usize = 6;

/// Proximal terms tried on a linearisation Lemke's method does not solve (1e-8 … 1e-2 of the
/// largest Jacobian entry).
const PROXIMAL_TRIES: usize = 4;

/// The Fischer–Burmeister merit `½‖Φ(z)‖²`.
fn merit(z: &[f64], f: &[f64], lower: &[f64], upper: &[f64], phi: &mut [f64]) -> f64 {
    fb_vector(z, f, lower, upper, phi);
    0.5 * phi.iter().map(|v| v * v).sum::<f64>()
}

/// Up to `max_steps` Josephy–Newton steps from `z0`: each solves the MCP linearised at the
/// current point (`F(z_k) + J(z_k)(z − z_k)`, same bounds) by Lemke's method from the normal-map
/// point `z_k − F(z_k)`, and moves towards its solution with a backtracking search on the
/// Fischer–Burmeister merit; when no length lowers it the step is taken whole (at most
/// [`NO_PROGRESS`] steps in a row without a new best natural residual). Stops at a natural
/// residual of `tolerance`. `None` when the first linearised problem has no solution found.
pub(super) fn josephy_newton_steps(
    mcp: &dyn Mcp,
    z0: &[f64],
    max_steps: usize,
    tolerance: f64,
) -> Option<JosephyEnd> {
    let n = mcp.dim();
    let pattern = mcp.jacobian_pattern().clone();
    let (lower, upper) = (mcp.lower(), mcp.upper());
    let mut z = z0.to_vec();
    let mut f = vec![0.0; n];
    let mut values = vec![0.0; pattern.nnz()];
    let mut jz = vec![0.0; n];
    let mut q = vec![0.0; n];
    let mut x = vec![0.0; n];
    let mut trial = vec![0.0; n];
    let mut f_trial = vec![0.0; n];
    let mut phi = vec![0.0; n];
    let mut lemke = Lemke::new(LemkeSettings::default());
    mcp.evaluate_with_jacobian(&z, &mut f, &mut values);
    let mut residual = natural_residual(&z, &f, lower, upper);
    let mut psi = merit(&z, &f, lower, upper, &mut phi);
    let mut best = JosephyEnd {
        z: z.clone(),
        residual,
        iterations: 0,
    };
    for _ in 0..max_steps {
        // Converged, or a non-finite residual (no step to take from there).
        if residual <= tolerance || residual.is_nan() {
            break;
        }
        mul_vec_nonzero_columns(&pattern, &values, &z, &mut jz);
        for i in 0..n {
            x[i] = z[i] - f[i];
        }
        // A linearisation that Lemke's method does not solve, or whose solution is no descent
        // direction of the merit, gets a proximal term `λ(z − z_k)`, grown until it serves
        // (PATH's perturbation, `PathSettings::proximal_initial`): a shorter step, turned
        // towards the merit's steepest descent.
        let scale = values.iter().fold(1.0f64, |a, v| a.max(v.abs()));
        let mut lambda = 0.0;
        let mut taken = None;
        for _ in 0..=PROXIMAL_TRIES {
            for i in 0..n {
                q[i] = f[i] - jz[i] - lambda * z[i];
            }
            let problem = AffineMcp {
                m: AffineMatrix::Sparse {
                    pattern: &pattern,
                    values: &values,
                },
                q: &q,
                lower,
                upper,
                diagonal_shift: lambda,
            };
            let solved = lemke.solve_affine(&problem, &AffineStart::NormalMap(&x));
            lambda = if lambda == 0.0 {
                1e-8 * scale
            } else {
                100.0 * lambda
            };
            let Ok(lin) = solved else {
                continue;
            };
            best.iterations += 1;
            let mut t = 1.0;
            for _ in 0..=HALVINGS {
                for i in 0..n {
                    trial[i] = z[i] + t * (lin.z[i] - z[i]);
                }
                mcp.evaluate(&trial, &mut f_trial);
                if merit(&trial, &f_trial, lower, upper, &mut phi) < (1.0 - 1e-4 * t) * psi {
                    taken = Some(t);
                    break;
                }
                t *= 0.5;
            }
            if taken.is_some() {
                break;
            }
        }
        let Some(_) = taken else {
            break;
        };
        std::mem::swap(&mut z, &mut trial);
        mcp.evaluate_with_jacobian(&z, &mut f, &mut values);
        residual = natural_residual(&z, &f, lower, upper);
        psi = merit(&z, &f, lower, upper, &mut phi);
        if residual < best.residual {
            best.z.copy_from_slice(&z);
            best.residual = residual;
        }
    }
    (best.iterations > 0).then_some(best)
}

impl super::NewtonSolver {
    /// [`josephy_newton_steps`] from `z0`, then the plain iteration from their best point, folded
    /// into the failed attempts' count and best point as the other attempts of
    /// [`super::NewtonSolver::solve_restarted`] (`Some` when it ends the solve).
    pub(super) fn josephy_attempt(
        &mut self,
        mcp: &dyn Mcp,
        z0: &[f64],
        steps: usize,
        spent: &mut usize,
        best: &mut Box<ecp_model::Solution>,
    ) -> Option<Result<ecp_model::Solution, ecp_model::SolveError>> {
        // An attempt like the others: at most `max_iterations` steps (a step is a Newton
        // iteration on the linearisation), so `max_iterations` keeps bounding every attempt.
        let steps = steps.min(self.settings.max_iterations);
        let end = josephy_newton_steps(mcp, z0, steps, self.settings.tolerance)?;
        if self.settings.trace {
            eprintln!(
                "josephy-newton: {} steps, best natural residual {:.3e}",
                end.iterations, end.residual
            );
        }
        *spent += end.iterations;
        self.attempt = 0;
        let result = self.solve_plain_tallied(mcp, &end.z, "josephy_newton_restarts");
        super::fold_attempt(result, spent, best)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecp_model::FnMcp;

    /// The LCP `0 ≤ z ⊥ M z + q ≥ 0` with `M = [[2, 1], [1, 2]]`, `q = (−1, 1)`: solution
    /// `z = (0.5, 0)`, `w = (0, 1.5)`.
    fn lcp() -> FnMcp {
        ecp_model::mcp_library::lcp(vec![2.0, 1.0, 1.0, 2.0], vec![-1.0, 1.0])
            .expect("a valid LCP")
            .mcp
    }

    #[test]
    fn an_affine_problem_is_solved_by_one_step_from_the_wrong_active_set() {
        // Start on the other branch of both pairs: z₀ = (0, 1), w(z₀) = (0, 3).
        let end = josephy_newton_steps(&lcp(), &[0.0, 1.0], 20, 1e-12).expect("a step");
        assert_eq!(end.iterations, 1);
        assert!((end.z[0] - 0.5).abs() <= 1e-14, "z = {:?}", end.z);
        assert!(end.z[1].abs() <= 1e-14, "z = {:?}", end.z);
        assert!(end.residual <= 1e-14);
    }

    /// Kojima–Josephy from MCPLIB start 3, where the plain iteration stops at a point that is
    /// not a solution: the Josephy–Newton attempt after it reaches a listed solution, with no
    /// other restart.
    #[test]
    fn kojima_josephy_start_3_is_solved_by_the_steps_after_the_plain_iteration() {
        use crate::newton::{NewtonSettings, NewtonSolver};
        use ecp_model::{Counter, McpSolver};
        let p = ecp_model::mcp_library::kojima_josephy();
        let (label, z0) = &p.starts[2];
        assert_eq!(label, "mcplib3");
        let only_plain = NewtonSettings {
            nonmonotone_restart: false,
            smoothing: None,
            damped_restart: None,
            complementary_restart: None,
            early_complementary_restart: None,
            complementary_restart_from_best: None,
            ..NewtonSettings::default()
        };
        let without = NewtonSolver::new(NewtonSettings {
            josephy_newton: None,
            ..only_plain.clone()
        })
        .solve(&p.mcp, z0);
        assert!(without.is_err(), "{without:?}");
        let sol = NewtonSolver::new(only_plain)
            .solve(&p.mcp, z0)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(sol.summary.residual <= 1e-10, "{:e}", sol.summary.residual);
        assert_eq!(
            sol.summary
                .counter(Counter::Custom("josephy_newton_restarts")),
            Some(1)
        );
        let d = p.distance_to_solutions(&sol.z, None);
        assert!(d.is_some_and(|d| d < 1e-8), "{d:?}");
    }

    #[test]
    fn a_solution_takes_no_step() {
        assert!(josephy_newton_steps(&lcp(), &[0.5, 0.0], 20, 1e-12).is_none());
    }
}
