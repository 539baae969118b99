//! Runs the PATH-like backend and semismooth Newton on every (problem, start) pair of the
//! standard MCP test suite (`ecp_model::mcp_library::suite`) and prints a Markdown table side by
//! side: iterations, natural residual (computed by the model) and wall time, plus PATH's pivots.
//!
//! ```text
//! cargo run --release --example path_suite
//! ```
//!
//! Times are the best of `REPEATS` solves, so that one-off allocation and cache effects do not
//! dominate the microsecond-scale solves.

use std::time::{Duration, Instant};

use ecp_model::mcp_library::suite;
use ecp_model::{Counter, McpSolver, Solution, SolveError, residual_of};
use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
use ecp_solvers::path::{PathSettings, PathSolver};

const REPEATS: usize = 20;

/// One backend's result on one pair.
struct Cell {
    converged: bool,
    iterations: usize,
    residual: f64,
    time: Duration,
    pivots: usize,
}

fn measure(
    solver: &mut dyn McpSolver,
    p: &ecp_model::mcp_library::TestProblem,
    z0: &[f64],
) -> Cell {
    let mut best = Duration::MAX;
    let mut last: Option<Result<Solution, SolveError>> = None;
    for _ in 0..REPEATS {
        let t = Instant::now();
        let r = solver.solve(&p.mcp, z0);
        best = best.min(t.elapsed());
        last = Some(r);
    }
    let (converged, sol) = match &last {
        Some(Ok(s)) => (true, Some(s)),
        Some(Err(e)) => (false, e.best()),
        None => (false, None),
    };
    Cell {
        converged,
        iterations: sol.map_or(0, |s| s.summary.iterations),
        residual: sol.map_or(f64::INFINITY, |s| residual_of(&p.mcp, &s.z)),
        time: best,
        pivots: sol.map_or(0, |s| s.summary.counter(Counter::Pivots).unwrap_or(0)),
    }
}

fn main() {
    let mut path = PathSolver::new(PathSettings::default());
    let mut newton = NewtonSolver::new(NewtonSettings::default());
    let (mut pairs, mut tight_path, mut tight_newton) = (0usize, 0usize, 0usize);
    let (mut time_path, mut time_newton) = (Duration::ZERO, Duration::ZERO);
    println!(
        "| problem | n | start | PATH it | PATH pivots | PATH residual | PATH µs | Newton it | Newton residual | Newton µs |"
    );
    println!("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|");
    let mark = |c: &Cell| if c.converged { "" } else { " (**failed**)" };
    for p in suite() {
        for (label, start) in &p.starts {
            pairs += 1;
            let a = measure(&mut path, &p, start);
            let b = measure(&mut newton, &p, start);
            tight_path += usize::from(a.residual <= 1e-10);
            tight_newton += usize::from(b.residual <= 1e-10);
            time_path += a.time;
            time_newton += b.time;
            println!(
                "| {} | {} | {} | {} | {} | {:.1e}{} | {:.1} | {} | {:.1e}{} | {:.1} |",
                p.name,
                p.dim(),
                label,
                a.iterations,
                a.pivots,
                a.residual,
                mark(&a),
                a.time.as_secs_f64() * 1e6,
                b.iterations,
                b.residual,
                mark(&b),
                b.time.as_secs_f64() * 1e6,
            );
        }
    }
    println!();
    println!(
        "Solved to natural residual ≤ 1e-10: PATH {tight_path} of {pairs} pairs ({:.1} %), Newton {tight_newton} of {pairs} ({:.1} %).",
        100.0 * tight_path as f64 / pairs.max(1) as f64,
        100.0 * tight_newton as f64 / pairs.max(1) as f64
    );
    println!(
        "Total of the best-of-{REPEATS} times: PATH {:.0} µs, Newton {:.0} µs.",
        time_path.as_secs_f64() * 1e6,
        time_newton.as_secs_f64() * 1e6
    );
}
