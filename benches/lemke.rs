//! Lemke's method (the pivoting core of the PATH-like backend) on dense LCPs with a symmetric
//! positive definite `M`: `cargo bench --bench lemke`.
//!
//! The instances are [`ecp::lcp::random_lcp`] with seed 1 at n = 10, 30, 100, 300, the files
//! that `cargo run --release --example lcp_instances` writes for `ecp lcp --repeat N` and for
//! Siconos' Lemke (`benches/siconos_lemke.py`); one solver is reused across iterations (warm),
//! as a time stepper reuses it. The table against Siconos is in
//! `docs/backends.md#lemke-speed`.

use ecp::lcp::random_lcp;
use ecp::solvers::pivot::{Lemke, LemkeSettings};

fn main() {
    divan::main();
}

#[divan::bench(args = [10, 30, 100, 300])]
fn lemke_spd_lcp(bencher: divan::Bencher, n: usize) {
    let lcp = random_lcp(n, 1);
    let mut lemke = Lemke::new(LemkeSettings::default());
    bencher.bench_local(|| match lemke.solve_lcp(&lcp.m, &lcp.q) {
        Ok(sol) => sol.pivots,
        Err(e) => panic!("n = {n}: {e}"),
    });
}
