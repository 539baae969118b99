//! Benchmarks of the semismooth Newton backend (`docs/backends.md#semismooth-newton`):
//! `cargo bench --bench newton`.
//!
//! - Kojima–Josephy (n = 4) from its first MCPLIB start;
//! - random P-matrix LCPs of size 10 and 100 (dense) and 1000 (sparse);
//! - one desk step (the 100th, warm-started) and the whole 400-step desk run;
//! - one step of A1 and of the T-bar (warm-started);
//! - dense LU (factor and solve) at step-problem sizes, the small-matrix kernel against faer's
//!   blocked LU.

use ecp::formulations::Simulation;
use ecp::formulations::scenarios;
use ecp::model::McpSolver;
use ecp::model::linalg::DenseLu;
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

/// Dense LU, factor and one solve, on a step-like matrix (a third of the entries zero, a
/// dominant diagonal): the small-matrix kernel [`DenseLu::new`] chooses up to
/// `SMALL_DENSE_MAX`, against faer's blocked LU at the same sizes.
#[divan::bench(args = [(16, false), (16, true), (31, false), (31, true), (48, false), (48, true), (64, false), (64, true)])]
fn dense_lu(bencher: divan::Bencher, (n, blocked): (usize, bool)) {
    let a: Vec<f64> = (0..n * n)
        .map(|k| {
            let (i, j) = (k % n, k / n);
            let off = if (i + 2 * j) % 3 == 0 {
                0.0
            } else {
                ((i * 7 + j * 13) % 11) as f64 - 5.0
            };
            off + if i == j { 4.0 * n as f64 } else { 0.0 }
        })
        .collect();
    let mut lu = if blocked {
        DenseLu::blocked(n)
    } else {
        DenseLu::new(n)
    };
    let mut b = vec![1.0; n];
    bencher.bench_local(|| {
        lu.factor(&a).expect("regular");
        b.fill(1.0);
        lu.solve_in_place(&mut b).expect("solved");
        b[0]
    });
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

/// A step of A1 (the 20th: a box sliding on the ground, one contact) and of the T-bar (the
/// 340th, t = 3.4 s: pushed and twisted, sliding and turning in surface contact), warm-started.
#[divan::bench(args = ["a1", "tbar"])]
fn scenario_step(bencher: divan::Bencher, name: &str) {
    let (scene, k) = match name {
        "a1" => (scenarios::a1_sliding(), 20),
        _ => (scenarios::t_bar(), 340),
    };
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let (sim, z0) = common::at_step(scene, k, &mut solver);
    bencher.bench_local(|| match solver.solve(sim.mcp(), &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("{name} step: {e}"),
    });
}

/// [`desk_step`] and [`scenario_step`] with the block elimination of each body's ν and q
/// instead of the LU of the whole Newton matrix (`NewtonSettings::structured_solve`,
/// `docs/latency.md#structured-linear-solve`).
#[divan::bench(args = ["desk", "a1", "tbar"])]
fn step_block_elimination(bencher: divan::Bencher, name: &str) {
    let (scene, k) = match name {
        "desk" => (scenarios::desk(), 100),
        "a1" => (scenarios::a1_sliding(), 20),
        _ => (scenarios::t_bar(), 340),
    };
    let mut solver = NewtonSolver::new(NewtonSettings {
        structured_solve: true,
        ..NewtonSettings::default()
    });
    let (sim, z0) = common::at_step(scene, k, &mut solver);
    bencher.bench_local(|| match solver.solve(sim.mcp(), &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("{name} step: {e}"),
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
