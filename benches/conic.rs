//! Benchmarks of the conic backend (`docs/backends.md#conic`): `cargo bench --bench conic`.
//!
//! - one desk step (the 100th, warm-started from the 99th, like `benches/newton.rs`), exact mode
//!   and the Anitescu relaxation;
//! - the whole 400-step desk run;
//! - the closest-point QP between the desk's hull and the ground.

use ecp::formulations::Simulation;
use ecp::formulations::ecp::EcpContacts;
use ecp::formulations::scenarios;
use ecp::model::SolveError;
use ecp::solvers::conic::closest_point::{ConvexSet, closest_points};
use ecp::solvers::conic::{ConicMode, ConicSettings, ConicSolver, default_clarabel_settings};

mod common;

fn main() {
    divan::main();
}

fn desk_at_step_100(mode: ConicMode) -> (Simulation, ConicSolver, Vec<f64>) {
    let mut solver = ConicSolver::new(ConicSettings {
        mode,
        ..ConicSettings::default()
    });
    let (sim, z0) = common::desk_at_step_100(&mut solver);
    (sim, solver, z0)
}

#[divan::bench]
fn desk_step(bencher: divan::Bencher) {
    let (sim, mut solver, z0) = desk_at_step_100(ConicMode::Exact);
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}

/// The same step with every outer iteration solving its QP (`ConicSettings::reuse_qp` off: the
/// default before the second QP of a step was replaced by the first's answer polished again).
#[divan::bench]
fn desk_step_without_reuse(bencher: divan::Bencher) {
    let (sim, mut solver, z0) = desk_at_step_100(ConicMode::Exact);
    solver.settings_mut().reuse_qp = false;
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}

/// The same step with every outer QP solved to clarabel's tolerances
/// (`ConicSettings::qp_tolerance_factor` 0): the default before the inexact QPs.
#[divan::bench]
fn desk_step_exact_qps(bencher: divan::Bencher) {
    let (sim, mut solver, z0) = desk_at_step_100(ConicMode::Exact);
    solver.settings_mut().qp_tolerance_factor = 0.0;
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}

/// The same step with every QP solved first by the dense method (`ConicSettings::dense_qp`, set
/// explicitly: the default since `fcc6fbd`, so this is `desk_step` again;
/// `docs/latency.md#dense-qps-the-default`).
#[divan::bench]
fn desk_step_dense_qp(bencher: divan::Bencher) {
    let (sim, mut solver, z0) = desk_at_step_100(ConicMode::Exact);
    solver.settings_mut().dense_qp = true;
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}

/// The fastest combination measured (not the default: the handoff slows corner scenes,
/// `docs/latency.md#conic-backend`): dense QPs, inexact QPs, Newton handoff at 1e-3.
#[divan::bench]
fn desk_step_dense_handoff(bencher: divan::Bencher) {
    let (sim, mut solver, z0) = desk_at_step_100(ConicMode::Exact);
    let settings = solver.settings_mut();
    settings.dense_qp = true;
    settings.newton_handoff = 1e-3;
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}

#[divan::bench]
fn desk_step_anitescu(bencher: divan::Bencher) {
    let (sim, mut solver, z0) = desk_at_step_100(ConicMode::AnitescuRelaxation);
    // The relaxed point is not a solution of the exact step MCP, so it comes back as
    // NotConverged with the relaxed point as the best iterate: that is the result timed here.
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(SolveError::NotConverged { best }) => best.summary.iterations,
        Err(e) => panic!("desk step (relaxation): {e}"),
    });
}

#[divan::bench(sample_count = 10)]
fn desk_run_400_steps(bencher: divan::Bencher) {
    bencher.bench_local(|| {
        let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
        let mut solver = ConicSolver::new(ConicSettings::default());
        sim.run(&mut solver, |_| true).expect("desk run")
    });
}

#[divan::bench]
fn closest_point_desk_hull_ground(bencher: divan::Bencher) {
    let sim = Simulation::new(scenarios::desk()).expect("desk scene");
    let s = sim.state(0);
    let verts: Vec<[f64; 3]> = sim
        .formulation_as::<EcpContacts>()
        .expect("the hull formulation")
        .hull_of(0)
        .vertices()
        .iter()
        .map(|v| {
            let p = s.x + v;
            [p.x, p.y, p.z + 0.01]
        })
        .collect();
    let ground = [([0.0, 0.0, 1.0], 0.0)];
    let settings = default_clarabel_settings();
    bencher.bench_local(|| {
        match closest_points(
            &ConvexSet::Vertices(&verts),
            &ConvexSet::HalfSpaces(&ground),
            &settings,
        ) {
            Ok(r) => r.distance,
            Err(e) => panic!("closest point: {e}"),
        }
    });
}
