//! Benchmarks of the multi-body formulation (`docs/latency.md#bins`): `cargo bench --bench bodies`.
//!
//! - `bin_step(n)`: one warm-started step of a bin of `n` parts, n = 1, 2, 5, 10, 20, 50 — the
//!   first `n` parts of `scenes/bin50.toml` (the lowest layers first), at step 150 (t = 1.5 s:
//!   settled, every part resting on the floor or on others), solved by Newton. The step's problem is prepared
//!   (pairs chosen, problem built) outside the timed part, so this is the solve alone;
//! - `bin_step_falling(n)`: the same at step 30 (t = 0.3 s: the lower layers landing, the upper
//!   ones falling), n = 20, 50.

use std::path::Path;

use ecp::formulations::Simulation;
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

fn main() {
    divan::main();
}

/// The first `n` parts of `scenes/bin50.toml` (the walls and the ground kept).
fn bin(n: usize) -> ecp::formulations::Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/bin50.toml");
    let mut scene = load_scene(&path).expect("scenes/bin50.toml").scene;
    scene.bodies.truncate(n);
    scene.name = format!("bin{n}");
    scene
}

fn bin_at(n: usize, k: usize) -> (Simulation, Vec<f64>, NewtonSolver) {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut sim = Simulation::with_formulation(bin(n), "bodies").expect("bin scene");
    for _ in 1..k {
        let r = sim.step(&mut solver).expect("step");
        assert!(r.converged, "bin{n}: step {} did not converge", r.step);
    }
    sim.prepare_step().expect("prepare");
    let z0 = sim.z().to_vec();
    (sim, z0, solver)
}

#[divan::bench(args = [1, 2, 5, 10, 20, 50], sample_count = 20)]
fn bin_step(bencher: divan::Bencher, n: usize) {
    let (sim, z0, mut solver) = bin_at(n, 150);
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("bin{n} step: {e}"),
    });
}

#[divan::bench(args = [20, 50], sample_count = 20)]
fn bin_step_falling(bencher: divan::Bencher, n: usize) {
    let (sim, z0, mut solver) = bin_at(n, 30);
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("bin{n} falling step: {e}"),
    });
}
