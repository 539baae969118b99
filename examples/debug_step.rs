use ecp::formulations::scenarios;
use ecp::formulations::stepper::Simulation;
use ecp::model::{diagnose, McpSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

fn main() {
    let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap();
    sim.prepare_step().unwrap();
    let mut s = NewtonSettings::default();
    s.trace = true;
    let mut solver = NewtonSolver::new(s);
    let z0 = sim.z().to_vec();
    let (r0, w0) = diagnose(sim.mcp(), &z0);
    let mut zr = z0.clone(); for (i, v) in zr.iter_mut().enumerate() { *v += 0.1 * ((i * 7919 % 13) as f64 / 13.0 - 0.5); }
    let _ = &zr;
    println!("start residual {r0:.3e} worst {w0:?}");
    match solver.solve(sim.mcp(), &z0) {
        Ok(sol) => { for t in &sol.summary.trace { println!("{t:?}"); } println!("ok {:?}", sol.z); }
        Err(e) => { let b = e.best().unwrap(); for t in b.summary.trace.iter().take(60) { println!("{} res {:.3e} merit {:.3e} {:?} t={:.2e} |d|={:.2e}", t.iteration, t.residual, t.merit, t.step, t.step_length, t.direction_norm); } println!("{e}"); 
            for (i, v) in b.z.iter().enumerate() { println!("{} = {v}", ecp::model::Mcp::component_name(sim.mcp(), i)); } }
    }
}

#[allow(dead_code)]
fn check(sim: &Simulation, z: &[f64]) {
    for rep in ecp::model::check_block_mcp(sim.mcp(), z, &ecp::model::CheckOptions::default()) {
        println!("{rep}");
    }
}
