//! Helpers shared by the backends' MCP-suite tests: run every (problem, start) pair of
//! `ecp_model::problems::suite()` and check a returned point against the known solutions.

#![allow(dead_code)]

use ecp_model::problems::{FRICTION_SIGMA, TestProblem, suite};
use ecp_model::{McpSolver, Solution, SolveError, residual_of};

/// Outcome of one (problem, start) solve, judged by the model's residual, not the summary.
pub struct Run {
    /// Problem name.
    pub problem: String,
    /// Start label.
    pub start: String,
    /// Natural residual of the returned point (or the best iterate).
    pub residual: f64,
    /// What the solver returned.
    pub result: Result<Solution, SolveError>,
}

pub fn run_suite(solver: &mut dyn McpSolver) -> Vec<(TestProblem, Vec<Run>)> {
    suite()
        .into_iter()
        .map(|p| {
            let runs = p
                .starts
                .iter()
                .map(|(label, start)| {
                    let result = solver.solve(&p.mcp, start);
                    let z = match &result {
                        Ok(s) => Some(&s.z),
                        Err(e) => e.best().map(|b| &b.z),
                    };
                    let residual = z.map_or(f64::INFINITY, |z| residual_of(&p.mcp, z));
                    Run {
                        problem: p.name.clone(),
                        start: label.clone(),
                        residual,
                        result,
                    }
                })
                .collect();
            (p, runs)
        })
        .collect()
}

/// `value > tol`, counting NaN as exceeding.
pub fn exceeds(value: f64, tol: f64) -> bool {
    value.is_nan() || value > tol
}

/// Checks that `z` (natural residual `residual`) is one of the problem's solutions; `Err`
/// says why not.
pub fn check_solution(p: &TestProblem, z: &[f64], residual: f64) -> Result<(), String> {
    match p.name.as_str() {
        // σ is undetermined when separated: compare the unique components only. There the
        // σ row `μ²p_n² − Σ p_k²/e_k²` is quadratic in the friction impulses with zero gradient
        // at the solution, so a natural residual r only gives |p_k| ≤ e_k √r and velocity
        // errors ≤ e_k √r / D_k (at most e_r / I_n = 0.2 / 0.08 = 2.5 times √r with this data):
        // there is no linear error bound, hence the √r term.
        "one_contact_friction_separated" => {
            let comps: Vec<usize> = (0..p.dim()).filter(|&i| i != FRICTION_SIGMA).collect();
            let d = p
                .distance_to_solutions(z, Some(&comps))
                .unwrap_or(f64::INFINITY);
            let tol = 1e-6 + 5.0 * residual.sqrt();
            if exceeds(d, tol) {
                return Err(format!(
                    "distance {d:.3e} to the solution (σ excluded), allowed {tol:.3e}"
                ));
            }
            if z[FRICTION_SIGMA] < -1e-10 {
                return Err(format!("σ = {} < 0", z[FRICTION_SIGMA]));
            }
            Ok(())
        }
        // Solution set: the segment (λ, 0, 0, 0), 0 ≤ λ ≤ 3.
        "mathiesen_pang_gabriel" => {
            let off = z[1..].iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if off > 1e-6 || z[0] < -1e-6 || z[0] > 3.0 + 1e-6 {
                return Err(format!(
                    "{z:?} is not on the segment (λ, 0, 0, 0), λ ∈ [0, 3]"
                ));
            }
            Ok(())
        }
        _ => match p.distance_to_solutions(z, None) {
            Some(d) if d > 1e-6 => Err(format!("distance {d:.3e} to the nearest known solution")),
            _ => Ok(()),
        },
    }
}
