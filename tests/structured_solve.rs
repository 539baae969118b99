//! The Newton backend's structured linear solve (`NewtonSettings::structured_solve`, block
//! elimination of each body's ν and q: `docs/latency.md#structured-linear-solve`) against the
//! LU of the whole Newton matrix: the paper's desk, A1 and the T-bar, step by step, each step
//! solved from the same start with both, the differences of the solutions in the scene's units.
//! Whole file: about 10 s in debug mode.

use ecp::formulations::sensitivity::{SensitivityOptions, StepDifferentiator};
use ecp::formulations::{Scene, Simulation, scenarios};
use ecp::model::{Mcp, McpSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

/// The lead's bound (issue 18): every step's solution within 1e-12 of the LU path's, in the
/// scene's units (`McpScales::variables`).
const AGREEMENT: f64 = 1e-12;

/// Steps `steps` of `scene`; per step both solves from the same warm start. Returns the largest
/// scaled difference, its step and component, and the steps whose iteration counts differ.
fn compare(scene: Scene, steps: usize) -> (f64, usize, String, usize) {
    let mut sim = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
    let mut lu = NewtonSolver::new(NewtonSettings {
        structured_solve: false,
        ..NewtonSettings::default()
    });
    let mut schur = NewtonSolver::new(NewtonSettings {
        structured_solve: true,
        ..NewtonSettings::default()
    })
    .with_profile();
    let (mut worst, mut at, mut name, mut iteration_changes) = (0.0f64, 0, String::new(), 0);
    for step in 1..=steps {
        if sim.finished() {
            break;
        }
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z0 = sim.z().to_vec();
        let problem = sim.step_problem();
        assert!(
            !problem.elimination_groups().is_empty(),
            "the step problem has no elimination groups"
        );
        let a = lu
            .solve(&problem, &z0)
            .unwrap_or_else(|e| panic!("LU, step {step}: {e}"));
        let b = schur
            .solve(&problem, &z0)
            .unwrap_or_else(|e| panic!("block elimination, step {step}: {e}"));
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
        sim.step(&mut lu)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
    }
    // The block elimination did the work (it falls back to the whole LU only on a singular
    // group block or Schur complement).
    let profile = schur.take_profile();
    assert!(
        profile.structured_factorizations * 10 >= profile.lu_factorizations * 9
            && profile.lu_factorizations > 0,
        "{} of {} factorisations by block elimination",
        profile.structured_factorizations,
        profile.lu_factorizations
    );
    (worst, at, name, iteration_changes)
}

fn check(label: &str, scene: Scene, steps: usize) {
    let (worst, step, name, changes) = compare(scene, steps);
    println!(
        "{label}: largest difference {worst:.2e} (step {step}, {name}); iteration counts differ \
         on {changes} steps"
    );
    assert!(
        worst <= AGREEMENT,
        "{label}: {worst:.2e} at step {step} ({name})"
    );
}

#[test]
fn the_desk_steps_agree_with_the_lu_path() {
    check("desk", scenarios::desk(), 400);
}

#[test]
fn a1_steps_agree_with_the_lu_path() {
    check("A1", scenarios::a1_sliding(), 1000);
}

#[test]
fn the_t_bar_steps_agree_with_the_lu_path() {
    check("T-bar", scenarios::t_bar(), 1000);
}

/// The desk's step sensitivities with the reduced Jacobian factorised by block elimination
/// against the LU of the whole matrix, at every 10th step: each column of `dz/dθ` within 1e-12
/// of the LU's, relative to the column's largest entry.
#[test]
fn the_desk_step_sensitivities_agree_with_the_lu_path() {
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut lu = StepDifferentiator::new(SensitivityOptions::default());
    let mut schur = StepDifferentiator::new(SensitivityOptions {
        structured_solve: true,
        ..SensitivityOptions::default()
    });
    let (mut worst, mut at, mut compared) = (0.0f64, 0, 0);
    for step in 1..=400 {
        sim.step(&mut solver)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
        if step % 10 != 0 {
            continue;
        }
        let a = lu.differentiate(&sim).unwrap_or_else(|e| panic!("{e}"));
        let b = schur.differentiate(&sim).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            std::mem::discriminant(&a.solve),
            std::mem::discriminant(&b.solve),
            "step {step}"
        );
        assert_eq!(a.dz.len(), b.dz.len());
        for (x, y) in a.dz.chunks(a.n.max(1)).zip(b.dz.chunks(b.n.max(1))) {
            let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
            for (u, v) in x.iter().zip(y) {
                let d = (u - v).abs() / scale;
                if d > worst {
                    (worst, at) = (d, step);
                }
            }
        }
        compared += 1;
    }
    println!("desk sensitivities: largest difference {worst:.2e} (step {at}), {compared} steps");
    assert_eq!(compared, 40);
    assert!(worst <= AGREEMENT, "{worst:.2e} at step {at}");
}
