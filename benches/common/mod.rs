//! Set-up shared by the benchmarks.

use ecp::formulations::Simulation;
use ecp::formulations::scenarios;
use ecp::model::McpSolver;

/// The desk after 99 steps with `solver`, with the 100th step prepared: the simulation and the
/// warm start of that step, so every backend is timed on the same step problem.
pub fn desk_at_step_100(solver: &mut dyn McpSolver) -> (Simulation, Vec<f64>) {
    at_step(scenarios::desk(), 100, solver)
}

/// `scene` after `k - 1` steps with `solver`, with step `k` prepared: the simulation and the
/// warm start of that step.
#[allow(dead_code)] // not every benchmark uses every scene
pub fn at_step(
    scene: ecp::formulations::Scene,
    k: usize,
    solver: &mut dyn McpSolver,
) -> (Simulation, Vec<f64>) {
    let mut sim = Simulation::new(scene).expect("scene");
    for _ in 1..k {
        sim.step(solver).expect("step");
    }
    sim.prepare_step().expect("prepare");
    let z0 = sim.z().to_vec();
    (sim, z0)
}
