//! The step sensitivities' θ columns solved by the small kernel's row-oriented solve (the
//! default) against faer's blocked triangular solves (`SensitivityOptions::blocked_columns`,
//! the route before it: `docs/latency.md#the-desk-step-sensitivity-by-rows-branch-wip-sensfast-issue-18`),
//! on the paper's desk and the T-bar at every 10th step, A1 at every other: every column of `dz/dθ` and of the
//! state derivatives within 1e-12 of the blocked route's, relative to the largest entry of the
//! column of `dz/dθ`; the same statuses, degeneracies and solve kind. Whole file: a few
//! seconds in debug.

use ecp::formulations::sensitivity::{
    Degeneracy, SensitivityOptions, StepDifferentiator, StepSensitivity,
};
use ecp::formulations::{Scene, Simulation, scenarios};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

/// The lead's bound (issue 18): results unchanged to 1e-12.
const AGREEMENT: f64 = 1e-12;

/// Largest difference of the columns of `a` and `b` against the blocked route's, relative to
/// the largest magnitude of that column of `dz/dθ` (`a` is `n × p`; `state`, `m × p`, is read
/// from the same columns, so its differences are relative to the same scale: a state column
/// that is zero up to round-off is judged against its `dz` column, not against its own noise).
fn column_difference(a: &StepSensitivity, b: &StepSensitivity) -> f64 {
    assert_eq!((a.dz.len(), a.state.len()), (b.dz.len(), b.state.len()));
    let (n, p) = (a.n.max(1), a.inputs.len().max(1));
    let m = (a.state.len() / p).max(1);
    let mut worst = 0.0f64;
    for c in 0..a.inputs.len() {
        let (x, y) = (&a.dz[c * n..(c + 1) * n], &b.dz[c * n..(c + 1) * n]);
        let (u, v) = (&a.state[c * m..(c + 1) * m], &b.state[c * m..(c + 1) * m]);
        let scale = x.iter().fold(0.0f64, |s, v| s.max(v.abs())).max(1e-300);
        for (e, f) in x.iter().zip(y).chain(u.iter().zip(v)) {
            worst = worst.max((e - f).abs() / scale);
        }
    }
    worst
}

/// The degeneracies with their slopes compared to round-off, the rest exactly.
fn same_degeneracies(a: &StepSensitivity, b: &StepSensitivity, label: &str) {
    assert_eq!(a.degeneracies.len(), b.degeneracies.len(), "{label}");
    for (x, y) in a.degeneracies.iter().zip(&b.degeneracies) {
        match (x, y) {
            (
                Degeneracy::WeaklyActive {
                    index: i,
                    slope: s,
                    two_sided: t,
                    ..
                },
                Degeneracy::WeaklyActive {
                    index: j,
                    slope: r,
                    two_sided: u,
                    ..
                },
            ) => {
                assert_eq!((i, t), (j, u), "{label}");
                assert!(
                    (s - r).abs() <= AGREEMENT * s.abs().max(1.0),
                    "{label}: slope {s:e} against {r:e}"
                );
            }
            _ => assert_eq!(
                std::mem::discriminant(x),
                std::mem::discriminant(y),
                "{label}"
            ),
        }
    }
}

/// Every `every`-th of the first `steps` steps of `scene`; returns the largest relative column
/// difference and the number of steps compared.
fn check(label: &str, scene: Scene, steps: usize, every: usize) -> (f64, usize) {
    let mut sim = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut rows = StepDifferentiator::new(SensitivityOptions::default());
    let mut blocked = StepDifferentiator::new(SensitivityOptions {
        blocked_columns: true,
        ..SensitivityOptions::default()
    });
    let (mut worst, mut at, mut compared) = (0.0f64, 0, 0);
    for step in 1..=steps {
        if sim.finished() {
            break;
        }
        sim.step(&mut solver)
            .unwrap_or_else(|e| panic!("{label} step {step}: {e}"));
        if step % every != 0 {
            continue;
        }
        let a = blocked
            .differentiate(&sim)
            .unwrap_or_else(|e| panic!("{label} step {step}: {e}"));
        let b = rows
            .differentiate(&sim)
            .unwrap_or_else(|e| panic!("{label} step {step}: {e}"));
        let at_step = format!("{label} step {step}");
        assert_eq!(a.status, b.status, "{at_step}");
        assert_eq!(
            std::mem::discriminant(&a.solve),
            std::mem::discriminant(&b.solve),
            "{at_step}"
        );
        same_degeneracies(&a, &b, &at_step);
        let d = column_difference(&a, &b);
        if d > worst {
            (worst, at) = (d, step);
        }
        compared += 1;
    }
    println!("{label}: largest column difference {worst:.2e} (step {at}), {compared} steps");
    assert!(worst <= AGREEMENT, "{label}: {worst:.2e} at step {at}");
    (worst, compared)
}

#[test]
fn the_desk_sensitivities_by_rows_agree_with_the_blocked_solves() {
    let (worst, compared) = check("desk", scenarios::desk(), 400, 10);
    assert_eq!(compared, 40);
    // Different arithmetic: the routes are not bitwise the same, so the comparison compares.
    assert!(worst > 0.0, "the two routes gave bitwise the same columns");
}

#[test]
fn a1_sensitivities_by_rows_agree_with_the_blocked_solves() {
    // A1 slides to rest within its 55 steps: every other step.
    let (_, compared) = check("A1", scenarios::a1_sliding(), 400, 2);
    assert!(compared >= 20, "{compared} steps compared");
}

#[test]
fn the_t_bar_sensitivities_by_rows_agree_with_the_blocked_solves() {
    let (_, compared) = check("T-bar", scenarios::t_bar(), 400, 10);
    assert!(compared >= 10, "{compared} steps compared");
}
