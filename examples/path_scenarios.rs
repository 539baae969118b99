//! Runs the analytic scenarios A1–A6 and the desk (`docs/model.md#scenarios`) with the PATH-like
//! backend and, for comparison, with semismooth Newton, and prints a Markdown table per backend:
//! steps converged to the default tolerance, largest natural residual, mean iterations, median
//! solve time per step.
//!
//! ```text
//! cargo run --release --example path_scenarios
//! ```

use ecp::formulations::scenarios;
use ecp::formulations::stepper::{Scene, Simulation};
use ecp::model::{Counter, McpSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};

/// What one run of a scene produced.
struct Outcome {
    steps: usize,
    converged: usize,
    max_residual: f64,
    mean_iterations: f64,
    median_us: f64,
    pivots: usize,
    retries: usize,
}

fn run(scene: Scene, solver: &mut dyn McpSolver) -> Result<Outcome, Box<dyn std::error::Error>> {
    let mut sim = Simulation::new(scene)?;
    let mut times = Vec::new();
    let (mut iterations, mut converged, mut pivots, mut retries) = (0usize, 0usize, 0, 0);
    let mut max_residual: f64 = 0.0;
    sim.run(solver, |rec| {
        times.push(rec.solve_us);
        iterations += rec.summary.iterations;
        converged += usize::from(rec.converged && rec.summary.residual <= 1e-10);
        max_residual = max_residual.max(rec.summary.residual);
        pivots += rec.summary.counter(Counter::Pivots).unwrap_or(0);
        retries += rec.summary.counter(Counter::Retries).unwrap_or(0);
        true
    })?;
    times.sort_by(f64::total_cmp);
    let steps = times.len();
    Ok(Outcome {
        steps,
        converged,
        max_residual,
        mean_iterations: iterations as f64 / steps.max(1) as f64,
        median_us: if steps > 0 { times[steps / 2] } else { 0.0 },
        pivots,
        retries,
    })
}

fn scenes() -> Vec<(&'static str, Scene)> {
    vec![
        ("A1 sliding", scenarios::a1_sliding()),
        ("A2 push 20 N", scenarios::a2_push(20.0)),
        ("A2 push 40 N", scenarios::a2_push(40.0)),
        ("A3 spin", scenarios::a3_spin()),
        ("A4 incline 10°", scenarios::a4_incline(10.0)),
        ("A4 incline 25°", scenarios::a4_incline(25.0)),
        ("A5 drop", scenarios::a5_drop()),
        ("A5 tilted drop", scenarios::a5_drop_tilted()),
        ("A6 tip 90 N", scenarios::a6_tip(90.0)),
        ("A6 tip 110 N", scenarios::a6_tip(110.0)),
        ("desk", scenarios::desk()),
    ]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut path = PathSolver::new(PathSettings::default());
    // Without the crash phase every step is taken by pivoting (the crash alone solves many
    // warm-started steps).
    let mut path_pivoting = PathSolver::new(PathSettings {
        crash_iterations: 0,
        ..PathSettings::default()
    });
    let mut newton = NewtonSolver::new(NewtonSettings::default());
    let backends: [(&str, &mut dyn McpSolver); 3] = [
        ("path", &mut path),
        ("path without crash", &mut path_pivoting),
        ("newton", &mut newton),
    ];
    for (name, solver) in backends {
        println!("### {name}");
        println!();
        println!(
            "| scene | converged / steps | max residual | mean iterations | median step (µs) | pivots | retries |"
        );
        println!("|---|---:|---:|---:|---:|---:|---:|");
        let (mut all, mut ok) = (0, 0);
        for (label, scene) in scenes() {
            let o = run(scene, solver)?;
            all += o.steps;
            ok += o.converged;
            println!(
                "| {label} | {} / {} | {:.2e} | {:.2} | {:.1} | {} | {} |",
                o.converged,
                o.steps,
                o.max_residual,
                o.mean_iterations,
                o.median_us,
                o.pivots,
                o.retries
            );
        }
        println!();
        println!("{name}: {ok} of {all} steps converged to natural residual ≤ 1e-10.");
        println!();
    }
    Ok(())
}
