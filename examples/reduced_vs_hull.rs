//! Time per step of the reduced sliding model against the hull model on the paper's desk
//! (`docs/model.md#scenarios`; the paper reports hull / reduced ≈ 2.4 in MATLAB), and their largest
//! differences in v, ω and the ECP over the 400 steps:
//! `cargo run --release --example reduced_vs_hull [-- --repeat R] [--tolerance T]`
//! (default: 5 runs of each, the backends' default tolerance 1e-10 on the natural residual).
//!
//! Two times per step: the backend's solve (`solve_us` of the step records) and the whole
//! `Stepper::step` call (per-step data, solve, state update and record).

use std::time::Instant;

use ecp::formulations::Simulation;
use ecp::formulations::StepRecord;
use ecp::formulations::scenarios;
use ecp::model::McpSolver;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};

#[derive(Clone, Copy)]
enum Backend {
    Newton,
    Path,
}

impl Backend {
    fn name(self) -> &'static str {
        match self {
            Backend::Newton => "newton",
            Backend::Path => "path",
        }
    }
    fn make(self, tolerance: f64) -> Box<dyn McpSolver> {
        match self {
            Backend::Newton => Box::new(NewtonSolver::new(NewtonSettings {
                tolerance,
                ..NewtonSettings::default()
            })),
            Backend::Path => Box::new(PathSolver::new(PathSettings {
                tolerance,
                ..PathSettings::default()
            })),
        }
    }
}

struct Timing {
    solve_us: Vec<f64>,
    step_us: Vec<f64>,
    iterations: Vec<usize>,
    max_residual: f64,
    records: Vec<StepRecord>,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() { 0.0 } else { v[v.len() / 2] }
}

fn run(
    formulation: &str,
    backend: Backend,
    tolerance: f64,
    repeat: usize,
) -> Result<Timing, Box<dyn std::error::Error>> {
    let mut t = Timing {
        solve_us: Vec::new(),
        step_us: Vec::new(),
        iterations: Vec::new(),
        max_residual: 0.0,
        records: Vec::new(),
    };
    for rep in 0..repeat {
        let mut stepper = Simulation::with_formulation(scenarios::desk(), formulation)?;
        let mut solver = backend.make(tolerance);
        while !stepper.finished() {
            let started = Instant::now();
            let rec = stepper.step(solver.as_mut())?;
            t.step_us.push(started.elapsed().as_secs_f64() * 1e6);
            t.solve_us.push(rec.solve_us);
            t.iterations.push(rec.summary.iterations);
            t.max_residual = t.max_residual.max(rec.summary.residual);
            if !rec.converged {
                eprintln!(
                    "{formulation}/{}: step {} did not converge (residual {:.2e})",
                    backend.name(),
                    rec.step,
                    rec.summary.residual
                );
            }
            if rep == 0 {
                t.records.push(rec);
            }
        }
    }
    Ok(t)
}

fn option<T: std::str::FromStr>(args: &[String], name: &str) -> Result<Option<T>, String> {
    match args.iter().position(|a| a == name) {
        None => Ok(None),
        Some(i) => args
            .get(i + 1)
            .and_then(|s| s.parse().ok())
            .map(Some)
            .ok_or_else(|| format!("{name} needs a number")),
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let repeat = option::<usize>(&args, "--repeat")?.unwrap_or(5).max(1);
    let tolerance = option::<f64>(&args, "--tolerance")?.unwrap_or(1e-10);
    println!(
        "desk, 400 steps, {repeat} runs each, tolerance {tolerance:e}; medians over all steps \
         of all runs"
    );
    println!(
        "{:<8} {:<8} {:>10} {:>10} {:>9} {:>10}",
        "model", "backend", "solve µs", "step µs", "mean it.", "max res."
    );
    let mut reference: Option<Vec<StepRecord>> = None;
    for backend in [Backend::Newton, Backend::Path] {
        let mut medians = Vec::new();
        for f in ["hull", "reduced"] {
            let mut t = run(f, backend, tolerance, repeat)?;
            let it = t.iterations.iter().sum::<usize>() as f64 / t.iterations.len().max(1) as f64;
            let (ms, mt) = (median(&mut t.solve_us), median(&mut t.step_us));
            println!(
                "{:<8} {:<8} {ms:>10.1} {mt:>10.1} {it:>9.2} {:>10.2e}",
                f,
                backend.name(),
                t.max_residual
            );
            medians.push((ms, mt));
            if let Some(r) = &reference {
                let (mut dv, mut dw, mut da) = (0.0f64, 0.0f64, 0.0f64);
                for (a, b) in t.records.iter().zip(r) {
                    dv = dv.max((a.bodies[0].v - b.bodies[0].v).amax());
                    dw = dw.max((a.bodies[0].w - b.bodies[0].w).amax());
                    da = da.max((a.contacts[0].a1 - b.contacts[0].a1).amax());
                }
                println!(
                    "    vs hull/newton: max |Δv| {dv:.2e} m/s, |Δω| {dw:.2e} rad/s, \
                     |Δ ECP| {da:.2e} m"
                );
            } else {
                reference = Some(t.records);
            }
        }
        println!(
            "{}: hull / reduced = {:.2} (solve), {:.2} (whole step)",
            backend.name(),
            medians[0].0 / medians[1].0,
            medians[0].1 / medians[1].1
        );
    }
    Ok(())
}
