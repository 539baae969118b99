//! The Newton backend's LU of `H` on its free block (`NewtonSettings::free_block`: the rows of
//! components held at a bound, unit rows of `H`, left out of the LU; `docs/latency.md`,
//! "Newton's Jacobian on its free block") against the LU of the whole `H`: the paper's desk,
//! A1 and the T-bar, step by step, each step solved from the same start with both, the
//! differences of the solutions in the scene's units.

use ecp::formulations::{Scene, Simulation, scenarios};
use ecp::model::{Mcp, McpSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

/// The lead's bound (issue 18): every step's solution within 1e-12 of the whole LU's, in the
/// scene's units (`McpScales::variables`).
const AGREEMENT: f64 = 1e-12;

/// Steps `steps` of `scene`; per step both solves from the same warm start. Returns the largest
/// scaled difference, its step and component, the steps whose iteration counts differ, and the
/// free block's factorisations and all factorisations of the solver with it.
fn compare(scene: Scene, steps: usize) -> (f64, usize, String, usize, usize, usize) {
    let mut sim = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
    let mut whole = NewtonSolver::new(NewtonSettings {
        free_block: false,
        ..NewtonSettings::default()
    })
    .with_profile();
    let mut free = NewtonSolver::new(NewtonSettings::default()).with_profile();
    assert!(free.settings().free_block, "the free block is the default");
    let (mut worst, mut at, mut name, mut iteration_changes) = (0.0f64, 0, String::new(), 0);
    for step in 1..=steps {
        if sim.finished() {
            break;
        }
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z0 = sim.z().to_vec();
        let problem = sim.step_problem();
        let a = whole
            .solve(&problem, &z0)
            .unwrap_or_else(|e| panic!("whole LU, step {step}: {e}"));
        let b = free
            .solve(&problem, &z0)
            .unwrap_or_else(|e| panic!("free block, step {step}: {e}"));
        assert!(
            a.summary.converged() && b.summary.converged(),
            "step {step}"
        );
        let units = problem.scales().map(|s| s.variables.clone());
        for (i, (x, y)) in a.z.iter().zip(&b.z).enumerate() {
            let unit = units.as_ref().map_or(1.0 + x.abs(), |u| u[i]);
            let d = (x - y).abs() / unit;
            if d > worst {
                (worst, at, name) = (d, step, problem.component_name(i));
            }
        }
        if a.summary.iterations != b.summary.iterations {
            iteration_changes += 1;
        }
        sim.step(&mut whole)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
    }
    // The whole LU never leaves rows out.
    assert_eq!(whole.take_profile().free_block_factorizations, 0);
    let p = free.take_profile();
    (
        worst,
        at,
        name,
        iteration_changes,
        p.free_block_factorizations,
        p.lu_factorizations,
    )
}

/// Compares `steps` steps of `scene`; returns the free block's share of the factorisations.
fn check(label: &str, scene: Scene, steps: usize) -> f64 {
    let (worst, step, name, changes, free, all) = compare(scene, steps);
    println!(
        "{label}: largest difference {worst:.2e} (step {step}, {name}); iteration counts differ \
         on {changes} steps; {free} of {all} factorisations on the free block"
    );
    assert!(
        worst <= AGREEMENT,
        "{label}: {worst:.2e} at step {step} ({name})"
    );
    assert!(all > 0, "{label}: no factorisation");
    free as f64 / all as f64
}

#[test]
fn the_desk_steps_on_the_free_block_agree_with_the_whole_lu() {
    // The desk rests on its feet: held components at most steps (5 of 31 at step 100).
    let share = check("desk", scenarios::desk(), 400);
    assert!(share >= 0.9, "{share}");
}

#[test]
fn a1_steps_on_the_free_block_agree_with_the_whole_lu() {
    check("A1", scenarios::a1_sliding(), 1000);
}

#[test]
fn the_t_bar_steps_on_the_free_block_agree_with_the_whole_lu() {
    check("T-bar", scenarios::t_bar(), 1000);
}
