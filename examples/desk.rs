//! Runs the paper's desk example (`docs/model.md#scenarios`) with the semismooth Newton backend and
//! prints a short summary: `cargo run --release --example desk`.

use ecp::formulations::Simulation;
use ecp::formulations::scenarios;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scene = scenarios::desk();
    let mut sim = Simulation::new(scene)?;
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut times = Vec::new();
    let mut iterations = Vec::new();
    let mut max_pen: f64 = 0.0;
    let mut max_res: f64 = 0.0;
    let mut converged = 0;
    let verbose = std::env::args().any(|a| a == "--verbose");
    sim.run(&mut solver, |rec| {
        times.push(rec.solve_us);
        iterations.push(rec.summary.iterations);
        max_res = max_res.max(rec.summary.residual);
        converged += usize::from(rec.converged);
        for c in &rec.contacts {
            max_pen = max_pen.max(-c.min_gap);
        }
        if verbose {
            let b = &rec.bodies[0];
            let c = &rec.contacts[0];
            println!(
                "t={:.2} x=({:.5},{:.5},{:.6}) v=({:.6},{:.6},{:.2e}) wz={:.6} ecp=({:.5},{:.5},{:.2e}) pn={:.5} it={} res={:.1e} mode={}",
                rec.t, b.x.x, b.x.y, b.x.z, b.v.x, b.v.y, b.v.z, b.w.z, c.a1.x, c.a1.y, c.a1.z, c.pn,
                rec.summary.iterations, rec.summary.residual, c.mode
            );
        }
        true
    })?;
    times.sort_by(f64::total_cmp);
    let steps = times.len();
    let median = if steps > 0 { times[steps / 2] } else { 0.0 };
    let mean_it = iterations.iter().sum::<usize>() as f64 / steps.max(1) as f64;
    let s = sim.state(0);
    println!("desk: {steps} steps, {converged} converged, max natural residual {max_res:.2e}");
    println!(
        "max penetration {max_pen:.2e} m, median step {median:.1} µs, mean iterations {mean_it:.2}"
    );
    println!(
        "final x = ({:.6}, {:.6}, {:.6}), v = ({:.6}, {:.6}, {:.6}), wz = {:.6}",
        s.x.x, s.x.y, s.x.z, s.v.x, s.v.y, s.v.z, s.w.z
    );
    Ok(())
}
