//! Benchmarks of the multi-body formulation (`docs/latency.md#bins`): `cargo bench --bench bodies`.
//!
//! - `bin_step(n)`: one warm-started step of a bin of `n` parts, n = 1, 2, 5, 10, 20, 50 — the
//!   first `n` parts of `scenes/bin50.toml` (the lowest layers first) settled, every part at rest
//!   on the floor or on the part below it, solved by Newton. The step's problem is prepared
//!   (pairs chosen, problem built) outside the timed part, so this is the solve alone;
//! - `bin_whole_step(n)`: the settled bin's next step as a run takes it (`Simulation::step`: the
//!   pairs chosen, the problem prepared, the solve, the read-out, the overlap check and the
//!   records), one after another from the settled state (it stays at rest): what `mj_step` does
//!   for MuJoCo (`benches/mujoco_bin.py --state settled`);
//! - `bin_step_falling(n)`: the same at step 14 of the bin50 run (t = 0.14 s: the lowest layer
//!   landed, the upper ones falling), n = 20, 50.
//!
//! Both start from a state checked in as `benches/bin50_states.csv` (`benches/common/bin_state.rs`:
//! the settled stack, and the run's state at the end of step 11) and take two steps with Newton
//! before the timed one, so that it is warm-started from its predecessor's solution as in a run.

use ecp::formulations::Simulation;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

#[path = "common/bin_state.rs"]
mod bin_state;

use bin_state::{FALLING, SETTLED};

/// Steps taken from the stored state before the timed one (their solutions warm-start it).
const LEAD_STEPS: usize = 2;

fn main() {
    divan::main();
}

/// The first `n` parts of the bin `LEAD_STEPS` steps after the stored state `from`, with the next
/// step prepared: the simulation, the step's warm start and the solver.
fn bin_at(n: usize, from: &str) -> (Simulation, Vec<f64>, NewtonSolver) {
    let scene = bin_state::bin_from(n, from).unwrap_or_else(|e| panic!("bin{n}: {e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut sim = Simulation::with_formulation(scene, "bodies").expect("bin scene");
    for k in 1..=LEAD_STEPS {
        let r = sim.step(&mut solver).expect("step");
        assert!(
            r.converged,
            "bin{n}: step {k} from the stored state {from:?} did not converge"
        );
    }
    sim.prepare_step().expect("prepare");
    let z0 = sim.z().to_vec();
    (sim, z0, solver)
}

#[divan::bench(args = [1, 2, 5, 10, 20, 50], sample_count = 20)]
fn bin_step(bencher: divan::Bencher, n: usize) {
    let (sim, z0, mut solver) = bin_at(n, SETTLED);
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("bin{n} step: {e}"),
    });
}

#[divan::bench(args = [1, 2, 5, 10, 20, 50], sample_count = 20)]
fn bin_whole_step(bencher: divan::Bencher, n: usize) {
    let (mut sim, _, mut solver) = bin_at(n, SETTLED);
    bencher.bench_local(|| match sim.step(&mut solver) {
        Ok(r) if r.converged => r.summary.iterations,
        Ok(r) => panic!("bin{n}: step {} did not converge", r.step),
        Err(e) => panic!("bin{n} step: {e}"),
    });
}

#[divan::bench(args = [20, 50], sample_count = 20)]
fn bin_step_falling(bencher: divan::Bencher, n: usize) {
    let (sim, z0, mut solver) = bin_at(n, FALLING);
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("bin{n} falling step: {e}"),
    });
}
