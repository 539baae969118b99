//! Per-step cost of a scene with one backend (`docs/latency.md#conic-backend`):
//!
//! ```text
//! cargo run --release --example conic_step_costs -- SCENE.toml [--with conic] [--top N] [--all] [--steps N]
//!     [--conic NAME=VALUE ..] [--trace K] [--trace-conic NAME=VALUE ..]
//! ```
//!
//! steps the scene as the stress suite does (hull formulation, the scene's tolerance, no
//! fallbacks) and prints the total solve time, the outer iterations (QPs for conic), and the
//! `--top` most expensive steps with their iterations and counters; `--all` prints every step; `--steps N` stops after step N.
use std::process::ExitCode;

use ecp::formulations::{FormulationRegistry, SimulationBuilder};
use ecp::model::{Mcp, McpSolver, SolveError};
use ecp::scene::load_scene;
use ecp::solvers::conic::{ConicSettings, ConicSolver};
use ecp::solvers::registry::{self, BackendOptions, Registry};

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{e}");
            ExitCode::from(2)
        }
    }
}

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let (mut path, mut with, mut top, mut all) = (None, "conic".to_string(), 10usize, false);
    let mut trace_step = None;
    let mut last_step = usize::MAX;
    let mut sets = Vec::new();
    let mut trace_sets: Vec<String> = Vec::new();
    let mut formulation = "hull".to_string();
    while let Some(a) = args.next() {
        match a.as_str() {
            "--trace" => trace_step = args.next().and_then(|v| v.parse::<usize>().ok()),
            "--steps" => {
                last_step = args
                    .next()
                    .and_then(|v| v.parse().ok())
                    .unwrap_or(usize::MAX)
            }
            "--with" => with = args.next().unwrap_or_default(),
            "--top" => top = args.next().and_then(|v| v.parse().ok()).unwrap_or(10),
            "--all" => all = true,
            "--formulation" => formulation = args.next().unwrap_or_default(),
            "--conic" => sets.push(args.next().unwrap_or_default()),
            // Settings of the `--trace` step's solve only (after the `--conic` ones).
            "--trace-conic" => trace_sets.push(args.next().unwrap_or_default()),
            _ => path = Some(a),
        }
    }
    let path = path.ok_or("usage: conic_step_costs SCENE.toml [--with B] [--top N] [--all]")?;
    let file = load_scene(std::path::Path::new(&path)).map_err(|e| e.to_string())?;
    let stepper = FormulationRegistry::builtin()
        .create(&formulation)
        .map_err(|e| e.to_string())?;
    let mut sim = SimulationBuilder::new(file.scene.clone(), stepper)
        .build()
        .map_err(|e| e.to_string())?;
    let options = BackendOptions {
        tolerance: file.solver.tolerance,
        max_iterations: file.solver.max_iterations,
        non_isolated_solutions: false,
    };
    let mut driver: Box<dyn McpSolver> = if with == "conic" {
        Box::new(ConicSolver::new(conic_settings(&options, &sets)?))
    } else {
        Registry::builtin()
            .build(&with, &options)
            .map_err(|e| e.to_string())?
    };
    let mut rows = Vec::new();
    let (mut total_us, mut total_it, mut failed) = (0.0, 0usize, 0usize);
    for k in 1..=file.scene.num_steps().min(last_step) {
        if trace_step == Some(k) {
            let all: Vec<String> = sets.iter().chain(&trace_sets).cloned().collect();
            trace(&mut sim, &options, &all)?;
        }
        sim.prepare_step().map_err(|e| e.to_string())?;
        let warm = {
            let mcp = sim.step_problem();
            let z0 = sim.z().to_vec();
            let mut f = vec![0.0; z0.len()];
            mcp.evaluate(&z0, &mut f);
            ecp::model::natural_residual(&z0, &f, mcp.lower(), mcp.upper())
        };
        let rec = sim.step(driver.as_mut()).map_err(|e| e.to_string())?;
        total_us += rec.solve_us;
        total_it += rec.summary.iterations;
        failed += usize::from(!rec.converged);
        let line = format!(
            "step {:4}: {:8.0} us, {:3} it, warm {warm:.2e}, residual {:.2e}, converged {}, {}",
            rec.step,
            rec.solve_us,
            rec.summary.iterations,
            rec.summary.residual,
            rec.converged,
            rec.summary.counters
        );
        if all {
            println!("{line}");
        }
        rows.push((rec.solve_us, line));
    }
    let n = rows.len().max(1);
    println!(
        "{with}: {} steps, {:.1} ms total, {:.2} iterations/step, {failed} failed",
        rows.len(),
        total_us / 1e3,
        total_it as f64 / n as f64
    );
    rows.sort_by(|a, b| b.0.total_cmp(&a.0));
    for (_, line) in rows.iter().take(top) {
        println!("{line}");
    }
    Ok(())
}

/// Solves the prepared step again with a tracing conic solver and prints its outer iterations.
fn trace(
    sim: &mut ecp::formulations::Simulation,
    options: &BackendOptions,
    sets: &[String],
) -> Result<(), String> {
    sim.prepare_step().map_err(|e| e.to_string())?;
    let z0 = sim.z().to_vec();
    let mut solver = ConicSolver::new(ConicSettings {
        trace: true,
        ..conic_settings(options, sets)?
    });
    let problem = sim.step_problem();
    let result = solver.solve(&problem, &z0);
    let sol = match &result {
        Ok(s) => s,
        Err(SolveError::NotConverged { best }) => best,
        Err(e) => return Err(e.to_string()),
    };
    for r in &sol.summary.trace {
        println!(
            "  outer {:3}: residual in {:.3e}, |z_new - z| {:.3e}",
            r.iteration, r.residual, r.direction_norm
        );
    }
    println!(
        "  final residual {:.3e}, worst {:?}",
        sol.summary.residual, sol.summary.worst
    );
    Ok(())
}

/// The conic settings the registry builds, changed by `NAME=VALUE` pairs.
fn conic_settings(o: &BackendOptions, sets: &[String]) -> Result<ConicSettings, String> {
    let mut s = registry::conic_settings(o);
    for kv in sets {
        let (name, value) = kv.split_once('=').ok_or("expected NAME=VALUE")?;
        let f = || value.parse::<f64>().map_err(|e| e.to_string());
        let n = || value.parse::<usize>().map_err(|e| e.to_string());
        let b = || value.parse::<bool>().map_err(|e| e.to_string());
        match name {
            "anchor_moment" => s.anchor_moment = f()?,
            "anchor_load" => s.anchor_load = f()?,
            "anderson_memory" => s.anderson_memory = n()?,
            "polish" => s.polish = b()?,
            "dense_qp" => s.dense_qp = b()?,
            "newton_polish" => s.newton_polish = n()?,
            "max_iterations" => s.max_iterations = n()?,
            "stagnation_window" => s.stagnation_window = n()?,
            "warm_qp" => s.warm_qp = b()?,
            "reuse_qp" => s.reuse_qp = b()?,
            "early_finish_after" => s.early_finish_after = n()?,
            "early_finish_iterations" => s.early_finish_iterations = n()?,
            "walk_finish_after" => s.walk_finish_after = n()?,
            "unanchored_retry" => s.unanchored_retry = b()?,
            "friction_continuation" => s.friction_continuation = n().ok().filter(|&n| n > 0),
            _ => return Err(format!("unknown conic setting {name}")),
        }
    }
    Ok(s)
}
