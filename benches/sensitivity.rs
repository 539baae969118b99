//! Cost of the step sensitivities relative to the step solve :
//! `cargo bench --bench sensitivity`.
//!
//! - `desk_step_solve`: the 100th desk step solved by the Newton backend from its warm start
//!   (as in `--bench newton`);
//! - `desk_step_sensitivity`: the derivatives of that step's solution with respect to all 30
//!   step inputs (friction, mass, inertia, start state, load): one Jacobian and one data-Jacobian
//!   evaluation, one factorisation of the reduced Jacobian (symbolic analysis reused), 30 solves
//!   (as the rows of one matrix by the small kernel, `docs/latency.md`);
//!   `desk_step_sensitivity_blocked_columns` the same with the 30 solves by faer's blocked
//!   triangular solves (`SensitivityOptions::blocked_columns`, the route before);
//! - `desk_100_steps_*`: the first 100 desk steps alone, with the adjoint gradient of a
//!   reference loss for μ and e_r (and every step's wrench), and with the forward one;
//! - `pieces`: the parts of a step sensitivity — the data Jacobian `∂F/∂θ` (30 columns), the
//!   factorisation of the reduced Jacobian (evaluation of J included), the 30 solves.
//!
//! Measured (2-core machine shared with other builds, medians): solve 29 µs, sensitivities
//! 18 µs (0.63 of a solve: data Jacobian 0.9 µs, factorisation 6.4 µs, 30 solves 6.4 µs in
//! one multi-right-hand-side call); 100 desk steps 3.2 ms alone, 5.3–9.5 ms with the adjoint
//! gradient, 9.8–10 ms with the forward one.

use ecp::formulations::scenarios;
use ecp::formulations::sensitivity::{
    GradientMode, Param, ReferenceLoss, ReferenceWeights, SensitivityOptions, StepDifferentiator,
    trajectory_gradient, trajectory_loss,
};
use ecp::formulations::{Scene, Simulation};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

mod common;

fn main() {
    divan::main();
}

#[divan::bench]
fn desk_step_solve(bencher: divan::Bencher) {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let (sim, z0) = common::desk_at_step_100(&mut solver);
    bencher.bench_local(|| match sim.solve_step_problem(&mut solver, &z0) {
        Ok(sol) => sol.summary.iterations,
        Err(e) => panic!("desk step: {e}"),
    });
}

#[divan::bench]
fn desk_step_sensitivity(bencher: divan::Bencher) {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    for _ in 0..100 {
        sim.step(&mut solver).expect("desk step");
    }
    let mut differ = StepDifferentiator::new(SensitivityOptions::default());
    bencher.bench_local(|| match differ.differentiate(&sim) {
        Ok(s) => s.dz.len(),
        Err(e) => panic!("desk sensitivity: {e}"),
    });
}

#[divan::bench]
fn desk_step_sensitivity_blocked_columns(bencher: divan::Bencher) {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    for _ in 0..100 {
        sim.step(&mut solver).expect("desk step");
    }
    let mut differ = StepDifferentiator::new(SensitivityOptions {
        blocked_columns: true,
        ..SensitivityOptions::default()
    });
    bencher.bench_local(|| match differ.differentiate(&sim) {
        Ok(s) => s.dz.len(),
        Err(e) => panic!("desk sensitivity: {e}"),
    });
}

/// The desk's first second (100 steps) and a reference loss on its own trajectory.
fn desk_100() -> (Scene, ReferenceLoss) {
    let mut scene = scenarios::desk();
    scene.duration = 1.0;
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut sim = Simulation::new(scene.clone()).expect("desk");
    let mut records = Vec::new();
    while !sim.finished() {
        records.push(sim.step(&mut solver).expect("desk step"));
    }
    let loss = ReferenceLoss::from_records(&records, ReferenceWeights::default());
    (scene, loss)
}

#[divan::bench(sample_count = 10)]
fn desk_100_steps_run(bencher: divan::Bencher) {
    let (scene, loss) = desk_100();
    bencher.bench_local(|| {
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        trajectory_loss(&scene, &loss, &mut solver)
            .expect("desk run")
            .0
    });
}

fn gradient(bencher: divan::Bencher, mode: GradientMode) {
    let (scene, loss) = desk_100();
    bencher.bench_local(|| {
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        trajectory_gradient(&scene, &[Param::Mu, Param::Er], &loss, &mut solver, mode)
            .expect("desk gradient")
            .loss
    });
}

#[divan::bench(sample_count = 10)]
fn desk_100_steps_adjoint_gradient(bencher: divan::Bencher) {
    gradient(bencher, GradientMode::Adjoint);
}

#[divan::bench(sample_count = 10)]
fn desk_100_steps_forward_gradient(bencher: divan::Bencher) {
    gradient(bencher, GradientMode::Forward);
}

/// The parts of `desk_step_sensitivity`, on the same step.
mod pieces {
    use super::*;
    use ecp::model::Mcp;
    use ecp::model::sensitivity::{ActiveSetOptions, ReducedSystem, classify};

    /// The desk after its 100th step.
    fn setup() -> Simulation {
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
        for _ in 0..100 {
            sim.step(&mut solver).expect("desk step");
        }
        sim
    }

    #[divan::bench]
    fn factor(bencher: divan::Bencher) {
        let sim = setup();
        let z = sim.last_step().unwrap().z.clone();
        let mcp = sim.mcp();
        let mut f = vec![0.0; z.len()];
        mcp.evaluate(&z, &mut f);
        let st = classify(
            &z,
            &f,
            mcp.lower(),
            mcp.upper(),
            &ActiveSetOptions::default(),
        );
        let mut sys = ReducedSystem::new();
        bencher.bench_local(|| sys.factor(mcp, &z, &st).unwrap());
    }

    #[divan::bench]
    fn solve_30(bencher: divan::Bencher) {
        let sim = setup();
        let z = sim.last_step().unwrap().z.clone();
        let mcp = sim.mcp();
        let mut f = vec![0.0; z.len()];
        mcp.evaluate(&z, &mut f);
        let st = classify(
            &z,
            &f,
            mcp.lower(),
            mcp.upper(),
            &ActiveSetOptions::default(),
        );
        let mut sys = ReducedSystem::new();
        sys.factor(mcp, &z, &st).unwrap();
        let rhs = vec![1.0; z.len() * 30];
        bencher.bench_local(|| {
            let mut r = rhs.clone();
            sys.solve_columns(&mut r, 30).unwrap()
        });
    }

    #[divan::bench]
    fn data_jacobian(bencher: divan::Bencher) {
        let sim = setup();
        let z = sim.last_step().unwrap().z.clone();
        let mcp = sim.mcp();
        // The 30 step inputs: friction (4) and the desk's mass, inertia, start state and load.
        let body = sim.handles().bodies[0].data.unwrap();
        let wrt = [
            sim.handles().friction.unwrap(),
            body.mass,
            body.inertia,
            body.start,
            body.wrench,
        ];
        let mut out = vec![0.0; z.len() * 30];
        bencher.bench_local(|| mcp.data_jacobian(&z, &wrt, &mut out).unwrap());
    }
}
