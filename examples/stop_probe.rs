//! One step's Newton iterates, component by component, from its warm start, from the plain
//! start and from the `warm_probe` perturbed starts (`docs/latency.md`, "Newton at the stop of
//! a sliding box: A1 step 35"):
//!
//! ```text
//! cargo run --release --example stop_probe -- SCENE.toml --step K [--perturb EPS]
//!     [--previous] [--kink-band X]
//! ```
//!
//! prints each unknown's name, bounds, warm start, solution and `F` at both, then, for the
//! extrapolated start and the 8 perturbed starts (each entry moved by `±EPS` relative, the sign
//! patterns of `warm_probe`), the pairs within 1e-12 of the kink (`z` at its lower bound and
//! `|F| < 1e-12`) and the trace (residual, step kind, step length). `--previous`: the plain warm
//! start; `--kink-band`: [`NewtonSettings::kink_band`] in step K's solves.
use std::process::ExitCode;

use ecp::formulations::{FormulationRegistry, SimulationBuilder, WarmStart};
use ecp::model::Mcp;
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let (mut path, mut step, mut eps) = (None, 35usize, 1e-15);
    let mut previous = false;
    let mut band = None;
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_default();
        match a.as_str() {
            "--step" => step = value().parse().unwrap_or(35),
            "--perturb" => eps = value().parse().unwrap_or(1e-15),
            "--previous" => previous = true,
            "--kink-band" => band = value().parse().ok(),
            _ => path = Some(a),
        }
    }
    let Some(path) = path else {
        eprintln!(
            "usage: stop_probe SCENE.toml --step K [--perturb EPS] [--previous] [--kink-band X]"
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
    let built = FormulationRegistry::builtin()
        .create(&file.formulation)
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
    sim.set_warm_start(if previous {
        WarmStart::Previous
    } else {
        WarmStart::Extrapolated
    });
    let d = NewtonSettings::default();
    let settings = NewtonSettings {
        tolerance: file.solver.tolerance.unwrap_or(d.tolerance),
        max_iterations: file.solver.max_iterations.unwrap_or(d.max_iterations),
        trace: true,
        ..d
    };
    // The steps before K with the defaults; step K's solves with `--kink-band`.
    let probe = NewtonSettings {
        kink_band: band,
        ..settings.clone()
    };
    let mut solver = NewtonSolver::new(settings.clone());
    for k in 1..step {
        if let Err(e) = sim.step(&mut solver) {
            eprintln!("step {k}: {e}");
            return ExitCode::FAILURE;
        }
    }
    if let Err(e) = sim.prepare_step() {
        eprintln!("step {step}: {e}");
        return ExitCode::FAILURE;
    }
    let z0 = sim.z().to_vec();
    let settings = probe;
    let sol = match sim.solve_step_problem(&mut NewtonSolver::new(settings.clone()), &z0) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::FAILURE;
        }
    };
    let mcp = sim.mcp();
    let n = mcp.dim();
    let (mut f0, mut fs) = (vec![0.0; n], vec![0.0; n]);
    mcp.evaluate(&z0, &mut f0);
    mcp.evaluate(&sol.z, &mut fs);
    println!(
        "{:>3} {:<22} {:>9} {:>9} {:>23} {:>23} {:>10} {:>10}",
        "i", "name", "lo", "up", "z0", "z*", "F(z0)", "F(z*)"
    );
    for i in 0..n {
        println!(
            "{i:3} {:<22} {:9.1e} {:9.1e} {:23.16e} {:23.16e} {:10.2e} {:10.2e}",
            mcp.component_name(i),
            mcp.lower()[i],
            mcp.upper()[i],
            z0[i],
            sol.z[i],
            f0[i],
            fs[i]
        );
    }
    let mut state: u64 = 0x9e37_79b9_7f4a_7c15;
    let mut starts = vec![("start".to_string(), z0.clone())];
    for p in 0..8 {
        let z: Vec<f64> = (z0.iter())
            .map(|v| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let sign = if state & 1 == 0 { 1.0 } else { -1.0 };
                v * (1.0 + sign * eps)
            })
            .collect();
        starts.push((format!("pattern {p}"), z));
    }
    for (label, z) in &starts {
        let diff: Vec<String> = (0..n)
            .filter(|&i| z[i] != z0[i])
            .map(|i| format!("{}{:+.1e}", mcp.component_name(i), z[i] - z0[i]))
            .collect();
        let mut fz = vec![0.0; n];
        mcp.evaluate(z, &mut fz);
        let pairs: Vec<String> = (0..n)
            .filter(|&i| {
                mcp.lower()[i].is_finite()
                    && (z[i] - mcp.lower()[i]).abs() < 1e-12
                    && fz[i].abs() < 1e-12
            })
            .map(|i| {
                format!(
                    "{} (z-l {:.1e}, F {:+.2e})",
                    mcp.component_name(i),
                    z[i] - mcp.lower()[i],
                    fz[i]
                )
            })
            .collect();
        println!(
            "{label}: pairs within 1e-12 of the kink: {}",
            pairs.join(", ")
        );
        let run = sim.solve_step_problem(&mut NewtonSolver::new(settings.clone()), z);
        let summary = match &run {
            Ok(s) => &s.summary,
            Err(e) => match e.best() {
                Some(b) => &b.summary,
                None => continue,
            },
        };
        let trace: Vec<String> = (summary.trace.iter())
            .map(|t| {
                format!(
                    "[{:.1e} {:?} t={:.3} |d|={:.2e}]",
                    t.residual, t.step, t.step_length, t.direction_norm
                )
            })
            .collect();
        println!(
            "{label}: {} iterations, residual {:.1e}; {}",
            summary.iterations,
            summary.residual,
            trace.join(" ")
        );
        if label != "start" {
            println!("   moved: {}", diff.join(" "));
        }
    }
    ExitCode::SUCCESS
}
