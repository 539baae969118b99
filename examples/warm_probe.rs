//! How far each step's warm start misses the solution, and the Newton residual per iteration
//! from it (`docs/latency.md#an-extrapolated-warm-start-branch-wip-warmx-issue-18`):
//!
//! ```text
//! cargo run --release --example warm_probe -- SCENE.toml [--from K] [--to K] [--formulation F] [--extrapolated]
//! ```
//!
//! runs the scene with the Newton backend (the scene file's tolerance and iteration limit, no
//! fallbacks) and prints, for steps `K` in `[from, to]`, the natural residual at the start of
//! each iteration and of the returned point, and the largest difference between the warm start
//! and the solution per kind of unknown (the variable blocks' name suffixes: `nu`, `q`, `a1`,
//! `pn`, …). Then the mean iterations over all steps. `--extrapolated` turns on
//! [`WarmStart::Extrapolated`] (the default since
//! `docs/latency.md#the-extrapolated-warm-start-on-by-default-branch-wip-warmon-issue-18`; without
//! it the probe runs [`WarmStart::Previous`]). `--perturb EPS` also solves each printed step from
//! its warm start with every entry moved by `±EPS` relative (8 fixed sign patterns, with a
//! Newton solver of its own) and prints those solves' iterations: how sensitive the step is to
//! round-off in its start.
use std::collections::BTreeMap;
use std::process::ExitCode;

use ecp::formulations::{FormulationRegistry, SimulationBuilder, WarmStart};
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let (mut path, mut from, mut to, mut formulation) = (None, 1usize, 0usize, None);
    let mut warm_start = WarmStart::Previous;
    let mut perturb: Option<f64> = None;
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_default();
        match a.as_str() {
            "--from" => from = value().parse().unwrap_or(1),
            "--to" => to = value().parse().unwrap_or(0),
            "--formulation" => formulation = Some(value()),
            "--extrapolated" => warm_start = WarmStart::Extrapolated,
            "--perturb" => perturb = value().parse().ok(),
            _ => path = Some(a),
        }
    }
    let Some(path) = path else {
        eprintln!(
            "usage: warm_probe SCENE.toml [--from K] [--to K] [--formulation F] [--extrapolated]"
        );
        return ExitCode::from(2);
    };
    let file = match load_scene(std::path::Path::new(&path)) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    let name = formulation.unwrap_or_else(|| file.formulation.clone());
    let built = FormulationRegistry::builtin()
        .create(&name)
        .map_err(|e| e.to_string())
        .and_then(|f| {
            SimulationBuilder::new(file.scene.clone(), f)
                .build()
                .map_err(|e| e.to_string())
        });
    let mut sim = match built {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    sim.set_warm_start(warm_start);
    let d = NewtonSettings::default();
    let mut solver = NewtonSolver::new(NewtonSettings {
        tolerance: file.solver.tolerance.unwrap_or(d.tolerance),
        max_iterations: file.solver.max_iterations.unwrap_or(d.max_iterations),
        trace: true,
        ..d
    });
    let steps = file.scene.num_steps();
    let to = if to == 0 { steps } else { to.min(steps) };
    let (mut iterations, mut failed) = (0usize, 0usize);
    for k in 1..=steps {
        // The warm start is idempotent: `step` prepares the same starting point again.
        let z0 = match sim.prepare_step() {
            Ok(()) => sim.z().to_vec(),
            Err(e) => {
                eprintln!("step {k}: {e}");
                return ExitCode::FAILURE;
            }
        };
        let perturbed = perturb
            .filter(|_| (from..=to).contains(&k))
            .map(|eps| perturbed_iterations(&sim, &z0, eps, &file.solver));
        let rec = match sim.step(&mut solver) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("step {k}: {e}");
                return ExitCode::FAILURE;
            }
        };
        iterations += rec.summary.iterations;
        failed += usize::from(!rec.converged);
        if k < from || k > to {
            continue;
        }
        let mcp = sim.mcp();
        let mut miss: BTreeMap<String, f64> = BTreeMap::new();
        for (i, block) in mcp.variable_blocks().iter().enumerate() {
            let kind = block.name().rsplit('.').next().unwrap_or("").to_string();
            let r = mcp.range(ecp::model::VarId(i));
            let m = (r.clone())
                .map(|j| (z0[j] - sim.z()[j]).abs())
                .fold(0.0, f64::max);
            let e = miss.entry(kind).or_insert(0.0);
            *e = e.max(m);
        }
        let trace: Vec<String> = (rec.summary.trace.iter())
            .map(|t| format!("{:.1e}", t.residual))
            .collect();
        let miss: Vec<String> = miss.iter().map(|(k, v)| format!("{k} {v:.1e}")).collect();
        if let Some(its) = perturbed {
            println!("step {k:4} from perturbed starts: iterations {its:?}");
        }
        println!(
            "step {k:4} {} iters {} retries {} residuals [{}] -> {:.1e}; warm start off by: {}",
            if rec.converged { "ok  " } else { "FAIL" },
            rec.summary.iterations,
            (rec.summary.counters)
                .get(ecp::model::Counter::Retries)
                .unwrap_or(0),
            trace.join(" "),
            rec.summary.residual,
            miss.join(", ")
        );
    }
    println!(
        "{steps} steps, {failed} failed, mean iterations {:.3}",
        iterations as f64 / steps as f64
    );
    ExitCode::SUCCESS
}

/// The iterations of Newton (the scene's tolerance and limit) on the prepared step from `z0`
/// with every entry scaled by `1 ± eps`, for 8 fixed sign patterns (`None`: not converged).
fn perturbed_iterations(
    sim: &ecp::formulations::Simulation,
    z0: &[f64],
    eps: f64,
    settings: &ecp::backends::SolverConfig,
) -> Vec<Option<usize>> {
    let d = NewtonSettings::default();
    let mut newton = NewtonSolver::new(NewtonSettings {
        tolerance: settings.tolerance.unwrap_or(d.tolerance),
        max_iterations: settings.max_iterations.unwrap_or(d.max_iterations),
        ..d
    });
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    (0..8)
        .map(|_| {
            let z: Vec<f64> = (z0.iter())
                .map(|v| {
                    // xorshift64: a fixed sequence of signs.
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    let sign = if state & 1 == 0 { 1.0 } else { -1.0 };
                    v * (1.0 + sign * eps)
                })
                .collect();
            sim.solve_step_problem(&mut newton, &z)
                .ok()
                .map(|sol| sol.summary.iterations)
        })
        .collect()
}
