//! Benchmarks of the pivotal and PATH-like backends : `cargo bench --bench path`.
//!
//! - Lemke's method on dense random P-matrix LCPs of size 10, 30, 100 and 300 (the matrices of
//!   `mcp_library::random_p_matrix_lcp`, `M = BᵀB + I + (C − Cᵀ)`);
//! - the PATH-like solver on Kojima–Josephy (n = 4) from its first MCPLIB start;
//! - the PATH-like solver on one desk step (the 100th, warm-started), as `benches/newton.rs`
//!   does for Newton.

use ecp::model::mcp_library::{kojima_josephy, random_p_matrix_lcp};
use ecp::model::{Mcp, McpSolver};
use ecp::solvers::path::{PathSettings, PathSolver};
use ecp::solvers::pivot::{Lemke, LemkeSettings};

mod common;

fn main() {
    divan::main();
}

/// The dense LCP data `(M row-major, q)` of `random_p_matrix_lcp(n, seed, false)`, read back from
/// the problem's `F` and `J` (F(z) = Mz + q is affine).
fn dense_lcp(n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let p = random_p_matrix_lcp(n, seed, false);
    let zero = vec![0.0; n];
    let mut q = vec![0.0; n];
    p.mcp.evaluate(&zero, &mut q);
    let mut col_major = vec![0.0; p.mcp.jacobian_pattern().nnz()];
    p.mcp.jacobian(&zero, &mut col_major);
    let mut m = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            m[i * n + j] = col_major[j * n + i];
        }
    }
    (m, q)
}

#[divan::bench(args = [10, 30, 100, 300])]
fn lemke_dense_p_matrix_lcp(bencher: divan::Bencher, n: usize) {
    let (m, q) = dense_lcp(n, 7);
    let mut lemke = Lemke::new(LemkeSettings::default());
    bencher.bench_local(|| match lemke.solve_lcp(&m, &q) {
        Ok(sol) => sol.pivots,
        Err(e) => panic!("n = {n}: {e}"),
    });
}

#[divan::bench]
fn path_kojima_josephy_start1(bencher: divan::Bencher) {
    let p = kojima_josephy();
    let mut solver = PathSolver::new(PathSettings::default());
    bencher.bench_local(|| match solver.solve(&p.mcp, &p.starts[0].1) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("kojima_josephy: {e}"),
    });
}

#[divan::bench]
fn path_desk_step(bencher: divan::Bencher) {
    let mut solver = PathSolver::new(PathSettings::default());
    let (sim, z0) = common::desk_at_step_100(&mut solver);
    bencher.bench_local(|| match solver.solve(sim.mcp(), &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}
