//! Where the Newton backend's time goes, step by step (`docs/newton.md#wall-time`):
//!
//! ```text
//! cargo run --release --example newton_probe -- SCENE.toml [--formulation F] [--steps N]
//!     [--min-ms X] [--set NAME=VALUE ..] [--verbose] [--dump FILE]
//! ```
//!
//! runs the scene with the Newton backend alone (no fallbacks, going on past failed steps, as
//! the stress suite does; formulation `hull` unless given, `scene` for the scene file's own),
//! with the solver's profile on ([`NewtonSolver::with_profile`]), and prints every step whose
//! solve took at least `--min-ms` (default 5): iterations by attempt, LU and QR factorisations,
//! damping trials, evaluations of `F` and the time per phase (with `--verbose` also the last
//! attempt's counters); then the totals. `--dump` writes every step's body states (x, q, v, ω),
//! one line a step, to compare the trajectories of two variants. `--set` changes
//! a Newton setting from its default (see `set` below for the names), to compare variants.
use std::process::ExitCode;

use ecp::formulations::{FormulationRegistry, SimulationBuilder};
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonProfile, NewtonSettings, NewtonSolver, Phase};

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let (mut path, mut formulation, mut steps, mut min_ms) = (None, "hull".to_string(), None, 5.0);
    let mut sets = Vec::new();
    let mut verbose = false;
    let mut dump = None;
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_default();
        match a.as_str() {
            "--formulation" => formulation = value(),
            "--steps" => steps = value().parse().ok(),
            "--min-ms" => min_ms = value().parse().unwrap_or(min_ms),
            "--set" => sets.push(value()),
            "--verbose" => verbose = true,
            "--dump" => dump = Some(value()),
            _ => path = Some(a),
        }
    }
    let Some(path) = path else {
        eprintln!("usage: newton_probe SCENE.toml [--formulation F] [--steps N] [--min-ms X]");
        return ExitCode::from(2);
    };
    let file = match load_scene(std::path::Path::new(&path)) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    if formulation == "scene" {
        formulation = file.formulation.clone();
    }
    let stepper = match FormulationRegistry::builtin().create(&formulation) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    let mut sim = match SimulationBuilder::new(file.scene.clone(), stepper).build() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    let d = NewtonSettings::default();
    let mut settings = NewtonSettings {
        tolerance: file.solver.tolerance.unwrap_or(d.tolerance),
        max_iterations: file.solver.max_iterations.unwrap_or(d.max_iterations),
        ..d
    };
    for kv in &sets {
        if let Err(e) = set(&mut settings, kv) {
            eprintln!("--set {kv}: {e}");
            return ExitCode::from(2);
        }
    }
    let mut solver = NewtonSolver::new(settings).with_profile();
    let planned = steps.map_or(file.scene.num_steps(), |n: usize| {
        n.min(file.scene.num_steps())
    });
    let names: Vec<&str> = Phase::ALL.iter().map(|p| p.name()).collect();
    println!(
        "step  ms  conv  iters[plain,damped,smooth,dsmooth,nonmonotone]  lu  qr  lm_iters  lm_trials  f_evals  ms: {}",
        names.join(" ")
    );
    let (mut total, mut failed, mut wall) = (NewtonProfile::default(), 0usize, 0.0f64);
    let mut states = String::new();
    for step in 1..=planned {
        let rec = match sim.step(&mut solver) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("step {step}: {e}");
                return ExitCode::FAILURE;
            }
        };
        let p = solver.take_profile();
        let ms = rec.solve_us * 1e-3;
        wall += ms;
        failed += usize::from(!rec.converged);
        if ms >= min_ms || !rec.converged {
            let phases: Vec<String> =
                p.ns.iter()
                    .map(|n| format!("{:.1}", *n as f64 * 1e-6))
                    .collect();
            println!(
                "{step:4} {ms:7.1} {} {:?} {} {} {} {} {}  {}",
                rec.converged,
                p.attempt_iterations,
                p.lu_factorizations,
                p.min_norm_factorizations,
                p.lm_iterations,
                p.lm_trials,
                p.f_evals,
                phases.join(" ")
            );
            if verbose {
                println!(
                    "      {} (residual {:.1e})",
                    rec.summary.counters, rec.summary.residual
                );
            }
        }
        total.add(&p);
        if dump.is_some() {
            for b in &rec.bodies {
                for v in
                    b.x.iter()
                        .chain(b.q.iter())
                        .chain(b.v.iter())
                        .chain(b.w.iter())
                {
                    states.push_str(&format!("{v:e} "));
                }
            }
            states.push('\n');
        }
    }
    if let Some(file) = &dump
        && let Err(e) = std::fs::write(file, &states)
    {
        eprintln!("{file}: {e}");
        return ExitCode::FAILURE;
    }
    let phases: Vec<String> = total
        .ns
        .iter()
        .map(|n| format!("{:.1}", *n as f64 * 1e-6))
        .collect();
    println!(
        "total: {planned} steps, {failed} failed, {wall:.1} ms in solves; iterations {:?}, lu {}, qr {}, lm_iters {}, lm_trials {} (augmented LU {}, sparse Cholesky {:.3e} flops), f_evals {}; ms: {}",
        total.attempt_iterations,
        total.lu_factorizations,
        total.min_norm_factorizations,
        total.lm_iterations,
        total.lm_trials,
        total.lm_augmented_factorizations,
        total.lm_cholesky_flops,
        total.f_evals,
        phases.join(" ")
    );
    if failed > 0 {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

/// Applies `NAME=VALUE` to `s`.
fn set(s: &mut NewtonSettings, kv: &str) -> Result<(), String> {
    let (name, value) = kv.split_once('=').ok_or("expected NAME=VALUE")?;
    let f = || value.parse::<f64>().map_err(|e| e.to_string());
    let n = || value.parse::<usize>().map_err(|e| e.to_string());
    let b = || value.parse::<bool>().map_err(|e| e.to_string());
    let smoothing =
        |s: &mut NewtonSettings| s.smoothing.get_or_insert_with(Default::default).to_owned();
    match name {
        "max_lm_trials" => s.max_lm_trials = n()?,
        "lm_residual_damping_after" => s.lm_residual_damping_after = value.parse::<usize>().ok(),
        "lm_initial_damping" => s.lm_initial_damping = f()?,
        "lm_cholesky" => s.lm_cholesky = b()?,
        "lm_sparse_product" => s.lm_sparse_product = b()?,
        "stall_window" => s.stall_window = n()?,
        "slow_rate_test" => s.slow_rate_test = b()?,
        "flat_merit_window" => s.flat_merit_window = n()?,
        "ratio_test" => s.ratio_test = b()?,
        "stall_reduction" => s.stall_reduction = f()?,
        "nonmonotone_restart" => s.nonmonotone_restart = b()?,
        "forget_undone_steps" => s.forget_undone_steps = b()?,
        "complementary_restart" => s.complementary_restart = value.parse::<f64>().ok(),
        "early_complementary_restart" => s.early_complementary_restart = value.parse::<f64>().ok(),
        "complementary_restart_from_best" => {
            s.complementary_restart_from_best = value.parse::<f64>().ok()
        }
        "watchdog_steps" => s.watchdog_steps = n()?,
        "newton_shortest_step" => s.newton_shortest_step = f()?,
        "min_norm_step" => s.min_norm_step = b()?,
        "kink_band" => s.kink_band = value.parse::<f64>().ok(),
        "smoothing_first" => s.smoothing_first = b()?,
        "damped_restart" => s.damped_restart = value.parse::<f64>().ok(),
        "smoothing" => {
            if !b()? {
                s.smoothing = None;
            }
        }
        "stage_iterations" => {
            let mut m = smoothing(s);
            m.stage_iterations = n()?;
            s.smoothing = Some(m);
        }
        "reduction" => {
            let mut m = smoothing(s);
            m.reduction = f()?;
            s.smoothing = Some(m);
        }
        "max_failed_stages" => {
            let mut m = smoothing(s);
            m.max_failed_stages = value.parse::<usize>().ok();
            s.smoothing = Some(m);
        }
        "stage_tolerance" => {
            let mut m = smoothing(s);
            m.stage_tolerance = f()?;
            s.smoothing = Some(m);
        }
        _ => return Err(format!("unknown setting {name}")),
    }
    Ok(())
}
