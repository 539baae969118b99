//! Benchmarks of the semismooth Newton backend (`docs/backends.md#semismooth-newton`):
//! `cargo bench --bench newton`.
//!
//! - Kojima–Josephy (n = 4) from its first MCPLIB start;
//! - random P-matrix LCPs of size 10 and 100 (dense) and 1000 (sparse);
//! - one desk step (the 100th, warm-started) and the whole 400-step desk run.

use ecp::formulations::Simulation;
use ecp::formulations::scenarios;
use ecp::model::McpSolver;
use ecp::model::mcp_library::{TestProblem, kojima_josephy, random_p_matrix_lcp};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

mod common;

fn main() {
    divan::main();
}

fn solve(p: &TestProblem, solver: &mut NewtonSolver) -> f64 {
    let z0 = &p.starts[0].1;
    match solver.solve(&p.mcp, z0) {
        Ok(sol) => sol.summary.residual,
        Err(e) => panic!("{}: {e}", p.name),
    }
}

#[divan::bench]
fn kojima_josephy_start1(bencher: divan::Bencher) {
    let p = kojima_josephy();
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    bencher.bench_local(|| solve(&p, &mut solver));
}

#[divan::bench(args = [(10, false), (100, false), (1000, true)])]
fn p_matrix_lcp(bencher: divan::Bencher, (n, sparse): (usize, bool)) {
    let p = random_p_matrix_lcp(n, 7, sparse);
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    bencher.bench_local(|| solve(&p, &mut solver));
}

#[divan::bench]
fn desk_step(bencher: divan::Bencher) {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let (sim, z0) = common::desk_at_step_100(&mut solver);
    bencher.bench_local(|| match solver.solve(sim.mcp(), &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}

#[divan::bench(sample_count = 10)]
fn desk_run_400_steps(bencher: divan::Bencher) {
    bencher.bench_local(|| {
        let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        sim.run(&mut solver, |_| true).expect("desk run")
    });
}
