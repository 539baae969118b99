//! Helpers shared by the backends' MCP-suite tests: run every (problem, start) pair of
//! `ecp_model::mcp_library::suite()` and check a returned point against the known solutions.

#![allow(dead_code)]

use ecp_model::mcp_library::{FRICTION_SIGMA, TestProblem, suite};
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

/// Verdict on every (problem, start) pair of the suite for one backend.
pub struct Verdict {
    /// Pairs run.
    pub pairs: usize,
    /// Wrong answers: a returned point that is not a solution, or an error without a finite
    /// best iterate.
    pub failures: Vec<String>,
    /// Pairs that ended in an error (with a finite best iterate).
    pub unsolved: Vec<String>,
    /// Pairs whose point misses the default tolerance 1e-10.
    pub misses: Vec<String>,
}

/// Runs the suite with `solver` (whose summaries must name it `name`) and judges every pair: a
/// returned point must have natural residual ≤ `solution_tol` and be a known solution.
pub fn judge_suite(solver: &mut dyn McpSolver, name: &str, solution_tol: f64) -> Verdict {
    let mut v = Verdict {
        pairs: 0,
        failures: Vec::new(),
        unsolved: Vec::new(),
        misses: Vec::new(),
    };
    for (p, runs) in run_suite(solver) {
        for run in runs {
            v.pairs += 1;
            let tag = format!("{} from {}", run.problem, run.start);
            if exceeds(run.residual, 1e-10) {
                v.misses
                    .push(format!("{tag}: residual {:.3e}", run.residual));
            }
            match &run.result {
                Err(e) => {
                    let finite = e.best().is_some_and(|b| b.z.iter().all(|x| x.is_finite()));
                    if !finite {
                        v.failures
                            .push(format!("{tag}: error without a finite best iterate: {e}"));
                    }
                    v.unsolved.push(format!("{tag}: {e}"));
                }
                Ok(sol) => {
                    if sol.summary.solver != name {
                        v.failures
                            .push(format!("{tag}: summary names {}", sol.summary.solver));
                    } else if exceeds(run.residual, solution_tol) {
                        v.failures
                            .push(format!("{tag}: natural residual {:.3e}", run.residual));
                    } else if let Err(why) = check_solution(&p, &sol.z, run.residual) {
                        v.failures.push(format!("{tag}: {why}"));
                    }
                }
            }
        }
    }
    v
}

/// The scene of `scenes/<name>.toml` (the integration tests run the shipped files).
pub fn scene(name: &str) -> ecp::formulations::Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(format!("{name}.toml"));
    match ecp::scene::load_scene(&path) {
        Ok(file) => file.scene,
        Err(e) => panic!("{e}"),
    }
}

/// Proptest strategies shared by the geometry and Jacobian property tests.
pub mod strategies {
    use nalgebra::{Vector3, Vector4};
    use proptest::prelude::*;

    /// A vector with components in `[lo, hi)`.
    pub fn vec3(lo: f64, hi: f64) -> impl Strategy<Value = Vector3<f64>> {
        (lo..hi, lo..hi, lo..hi).prop_map(|(a, b, c)| Vector3::new(a, b, c))
    }

    /// A uniformly-ish distributed unit vector.
    pub fn unit3() -> impl Strategy<Value = Vector3<f64>> {
        vec3(-1.0, 1.0)
            .prop_filter("direction away from zero", |v| v.norm() > 0.1)
            .prop_map(|v| v.normalize())
    }

    /// A unit quaternion (scalar first).
    pub fn unit_quat() -> impl Strategy<Value = Vector4<f64>> {
        (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64)
            .prop_map(|(a, b, c, d)| Vector4::new(a, b, c, d))
            .prop_filter("quaternion away from zero", |q| q.norm() > 0.1)
            .prop_map(|q| q.normalize())
    }
}
