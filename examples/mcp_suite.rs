//! Runs the semismooth Newton backend on every (problem, start) pair of the standard MCP test
//! suite (`ecp_model::mcp_library::suite`) and prints a Markdown table.
//!
//! ```text
//! cargo run --release --example mcp_suite
//! ```

use ecp_model::mcp_library::suite;
use ecp_model::{McpSolver, residual_of};
use ecp_solvers::newton::{NewtonSettings, NewtonSolver};

fn main() {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut pairs = 0usize;
    let mut tight = 0usize;
    println!(
        "| problem | n | start | converged | iterations | F evals | J evals | natural residual | time (µs) |"
    );
    println!("|---|---:|---|:---:|---:|---:|---:|---:|---:|");
    for p in suite() {
        for (label, start) in &p.starts {
            pairs += 1;
            let result = solver.solve(&p.mcp, start);
            let (converged, solution) = match &result {
                Ok(s) => (true, Some(s)),
                Err(e) => (false, e.best()),
            };
            let residual = solution.map_or(f64::INFINITY, |s| residual_of(&p.mcp, &s.z));
            if residual <= 1e-10 {
                tight += 1;
            }
            match solution {
                Some(s) => {
                    let sm = &s.summary;
                    println!(
                        "| {} | {} | {} | {} | {} | {} | {} | {:.2e} | {:.1} |",
                        p.name,
                        p.dim(),
                        label,
                        if converged { "yes" } else { "**no**" },
                        sm.iterations,
                        sm.f_evals,
                        sm.jac_evals,
                        residual,
                        sm.time.as_secs_f64() * 1e6
                    );
                }
                None => {
                    let why = result.err().map(|e| e.to_string()).unwrap_or_default();
                    println!(
                        "| {} | {} | {} | **no** ({why}) | – | – | – | – | – |",
                        p.name,
                        p.dim(),
                        label
                    );
                }
            }
        }
    }
    println!();
    println!(
        "Solved to natural residual ≤ 1e-10: {tight} of {pairs} pairs ({:.1} %).",
        100.0 * tight as f64 / pairs.max(1) as f64
    );
}
