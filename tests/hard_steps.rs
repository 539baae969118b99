//! Steps of the stress regression scenes that cost Newton or PATH far more than the other
//! backend (`docs/newton.md#hard-steps`, `docs/path.md#hard-steps`): each is reached by stepping
//! its scene as the stress suite does (hull formulation, the scene's tolerance, no fallbacks),
//! then solved again from its warm start, with the mend and without it.

use std::ops::RangeBounds;
use std::path::{Path, PathBuf};

use ecp::formulations::{
    FormulationRegistry, Simulation, SimulationBuilder, StepRecord, WarmStart,
};
use ecp::model::{Counter, Mcp, McpSolver, ScaledMcp, Solution, SolveError, natural_residual};
use ecp::scene::load_scene;
use ecp::solvers::conic::{ConicSettings, ConicSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};
use ecp::solvers::smoothing::SmoothingSettings;

/// `tests/stress_regressions/NAME.toml`.
fn regression_scene(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/stress_regressions")
        .join(format!("{name}.toml"))
}

/// The tolerance the scene file `path` asks for.
fn scene_tolerance(path: &Path) -> Option<f64> {
    load_scene(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .solver
        .tolerance
}

/// The scene `tests/stress_regressions/NAME.toml` stepped by `driver` (built as the registry
/// builds it) through step `step − 1`, with step `step` prepared; and the scene's tolerance.
fn at_step(name: &str, driver: &mut dyn McpSolver, step: usize) -> (Simulation, Option<f64>) {
    at_step_of(&regression_scene(name), driver, step)
}

/// The scene file `path` (hull formulation) stepped by `driver` through step `step − 1` (every
/// step must converge), with step `step` prepared; and the scene's tolerance. With the warm start
/// from the last step alone ([`WarmStart::Previous`]): each step here was measured on that
/// trajectory and from that start, which the extrapolated warm start (the default since
/// `docs/latency.md#the-extrapolated-warm-start-on-by-default-branch-wip-warmon-issue-18`)
/// would move by round-off or more; and each start solved with the full limits at once (the
/// driver before the start budgets of
/// `docs/latency.md#budgeted-starts-newtons-long-steps-branch-wip-hardsteps-issue-18`, which solve some steps from
/// another start, at another point within the tolerance).
fn at_step_of(path: &Path, driver: &mut dyn McpSolver, step: usize) -> (Simulation, Option<f64>) {
    stepped(path, driver, step, true)
}

/// The scene file `path` on the default simulation's trajectory (extrapolated warm start, start
/// budgets), stepped by `driver` through step `step − 1`, with step `step` prepared.
fn at_default_step(path: &Path, driver: &mut dyn McpSolver, step: usize) -> Simulation {
    stepped(path, driver, step, false).0
}

/// [`at_step_of`] (`recorded`: the plain warm start, no start budgets) or [`at_default_step`].
fn stepped(
    path: &Path,
    driver: &mut dyn McpSolver,
    step: usize,
    recorded: bool,
) -> (Simulation, Option<f64>) {
    let file = load_scene(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let stepper = FormulationRegistry::builtin()
        .create("hull")
        .unwrap_or_else(|e| panic!("{e}"));
    let mut sim = SimulationBuilder::new(file.scene.clone(), stepper)
        .build()
        .unwrap_or_else(|e| panic!("{e}"));
    if recorded {
        sim.set_warm_start(WarmStart::Previous);
        sim.set_start_budget(None);
    } else {
        // The default trajectory on which these steps were measured: the extrapolation of order
        // 2 at most (the default's orders up to 5 reach other states: 061's step 17 converges
        // without the complementary restart there, `docs/latency.md`, branch wip-xorder).
        sim.set_warm_start(WarmStart::Quadratic);
    }
    for k in 1..step {
        let rec = sim.step(driver).unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(
            rec.converged,
            "{}: step {k} did not converge (residual {:e})",
            path.display(),
            rec.summary.residual
        );
    }
    sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
    (sim, file.solver.tolerance)
}

/// Newton's defaults without the Josephy–Newton steps (`NewtonSettings::josephy_newton`): the
/// order of attempts each step below was measured with; with the steps several of them are
/// solved before the attempt a test is about runs (`docs/newton.md#josephy-newton-steps`).
fn main_order() -> NewtonSettings {
    NewtonSettings {
        josephy_newton: None,
        ..NewtonSettings::default()
    }
}

/// Asserts that a solve took a number of iterations in `range`.
fn assert_iterations(sol: &Solution, range: impl RangeBounds<usize> + std::fmt::Debug) {
    assert!(
        range.contains(&sol.summary.iterations),
        "{} iterations, expected {range:?}",
        sol.summary.iterations
    );
}

fn converged(result: Result<Solution, SolveError>) -> Solution {
    match result {
        Ok(sol) => sol,
        Err(SolveError::NotConverged { best }) => panic!(
            "not converged: {} iterations, residual {:e}",
            best.summary.iterations, best.summary.residual
        ),
        Err(e) => panic!("{e}"),
    }
}

/// `075_room_corner` step 12 (h = 10 ms, μ = 0.92, an L-shaped body tossed into a room corner;
/// 70 unknowns): the floor contact's closest point moves 14 cm to an edge while the body's
/// angular velocity changes by 3 rad/s. The monotone Armijo search accepts 1/64 … 1/4 of
/// the Newton steps (the merit is strongly curved along them): the plain iteration is cut by the
/// stall test after 39 iterations and the continuations took 477 more. The non-monotone restart
/// (full Newton steps under the watchdog) solves it in 10.
#[test]
fn newton_room_corner_step_12_nonmonotone_restart() {
    // The trajectory on which the step was measured: Newton before the valley mend of
    // `newton_convex_push_step_74_residual_damping` (the registry's Newton reaches another state).
    let mut driver = NewtonSolver::new(newton_before_valley_mend(None));
    let (sim, tolerance) = at_step("075_room_corner", &mut driver, 12);
    let z0 = sim.z().to_vec();
    let settings = NewtonSettings {
        tolerance: tolerance.unwrap_or(1e-10),
        ..main_order()
    };
    let mended = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings.clone()), &z0));
    assert_iterations(&mended, ..=60);
    assert_eq!(
        mended
            .summary
            .counter(Counter::SmoothingStages)
            .unwrap_or(0),
        0
    );
    let before = converged(sim.solve_step_problem(
        &mut NewtonSolver::new(NewtonSettings {
            nonmonotone_restart: false,
            ..newton_before_valley_mend(tolerance)
        }),
        &z0,
    ));
    assert_iterations(&before, 201..);
    // The same solution (both converged to 1e-10 in the scene's scales), but for the slip
    // rates σ of the two open contacts, which any σ ≥ 0 solves at p_n = 0.
    let problem = sim.step_problem();
    for (i, (a, b)) in mended.z.iter().zip(&before.z).enumerate() {
        let name = problem.component_name(i);
        if !name.contains("sigma") {
            assert!((a - b).abs() <= 1e-8, "{name}: {a:e} against {b:e}");
        }
    }
}

/// Newton as it was before the residual damping, the forgetting of undone steps and the ratio test
/// (`docs/newton.md#linearly-converging-steps`), with the scene's tolerance.
fn newton_before_valley_mend(tolerance: Option<f64>) -> NewtonSettings {
    NewtonSettings {
        tolerance: tolerance.unwrap_or(1e-10),
        lm_residual_damping_after: None,
        forget_undone_steps: false,
        ratio_test: false,
        // Nor the chord steps, which came later and move the trajectory by round-off.
        chord_contraction: None,
        ..main_order()
    }
}

/// `015_convex_push` (h = 6 ms, μ = 0.42, a convex point body pushed along the floor, rocking on
/// an edge that lies flat on it; 53 unknowns) on the trajectory of Newton before the mend. The
/// mend was measured on step 58, where the ECP moved 9 cm along the edge within the step, and the
/// edge's position is only weakly determined (through the torque of `p_n`), so the plain
/// iteration followed a long valley of the merit in Levenberg–Marquardt steps. Moré's damping,
/// starting from `1e-3` of `max diag HᵀH` and falling by at most 3 per step, took a dozen steps
/// of ρ ≈ 1 before the steps reached the length the valley allows; a watchdog excursion of
/// minimum-norm steps then cost the first run the 4 iterations after which the stall test cut
/// it, and the restart without minimum-norm steps replayed the same iterations: 85 in all, 30
/// with `λ = ν‖Φ‖²` after three Levenberg–Marquardt steps and the undone steps forgotten. Since
/// the tipping-edge warm start (`docs/newton.md#a-tipping-edge-predicted-tilted-018_union_tip`)
/// that step starts with the ECP on the edge and takes 4 iterations with either setting; step
/// 74 of the new trajectory is the valley the test keeps (`step_probe --sweep --newton
/// lm_residual_damping_after=none --newton forget_undone_steps=false --newton
/// ratio_test=false`): 85 iterations before the mend, 35 with it.
#[test]
fn newton_convex_push_step_74_residual_damping() {
    let tolerance = scene_tolerance(&regression_scene("015_convex_push"));
    let before = newton_before_valley_mend(tolerance);
    let mut driver = NewtonSolver::new(before.clone());
    let (sim, _) = at_step("015_convex_push", &mut driver, 74);
    let z0 = sim.z().to_vec();
    let mended = converged(sim.solve_step_problem(
        &mut NewtonSolver::new(NewtonSettings {
            tolerance: tolerance.unwrap_or(1e-10),
            ..main_order()
        }),
        &z0,
    ));
    assert_iterations(&mended, ..=40);
    let old = converged(sim.solve_step_problem(&mut NewtonSolver::new(before), &z0));
    assert_iterations(&old, 70..);
    // The same solution (both converged to 1e-10 in the scene's scales).
    let problem = sim.step_problem();
    for (i, (a, b)) in mended.z.iter().zip(&old.z).enumerate() {
        let name = problem.component_name(i);
        assert!((a - b).abs() <= 1e-8, "{name}: {a:e} against {b:e}");
    }
}

/// `023_room_corner` stepped by Newton (the registry's settings with the scene's tolerance,
/// without the ratio test and without `count_cut_stages`: the trajectory these steps were
/// measured on; with the ratio test step 36 ends at another point, and with
/// `count_cut_stages` the steps before 88 do) to `step`, and the settings to solve that step
/// with.
fn room_corner_023_at(step: usize) -> (Simulation, NewtonSettings) {
    let tolerance = scene_tolerance(&regression_scene("023_room_corner"));
    let defaults = main_order();
    let settings = NewtonSettings {
        tolerance: tolerance.unwrap_or(1e-10),
        ratio_test: false,
        // Nor a crawling continuation's stop, which came later and moves the trajectory.
        smoothing: defaults.smoothing.map(|s| SmoothingSettings {
            count_cut_stages: false,
            ..s
        }),
        ..defaults
    };
    let mut driver = NewtonSolver::new(settings.clone());
    let (sim, _) = at_step("023_room_corner", &mut driver, step);
    (sim, settings)
}

/// `023_room_corner` step 36 (109 unknowns, a box in a room corner): the plain iteration's
/// restart without minimum-norm steps converges linearly (residual × 0.96 an iteration, halving
/// within the stall test's 30) and ran its 200 iterations to 1.7e-6 before the non-monotone
/// restart solved the step in 36. The rate test stops it once its rate would need more than
/// 6 times the iterations it has left (at iteration 145): 236 → 181 iterations, the same end
/// point.
#[test]
fn newton_room_corner_023_step_36_rate_test() {
    room_corner_023_mend_keeps_the_point(
        36,
        |s| NewtonSettings {
            slow_rate_test: false,
            ..s
        },
        190,
        220,
    );
}

/// `023_room_corner` step 88: both runs of the plain iteration (with and without minimum-norm
/// steps) end on a stationary point of the merit that is not a solution (natural residual
/// 1.1e-4, Levenberg–Marquardt steps of 1e-8 … 1e-9 at a fixed `Ψ`) and waited there for the
/// stall test's window. The flat-merit test stops each after 10 flat iterations: 265 → 246
/// iterations, the same end point (the continuation solves the step either way).
#[test]
fn newton_room_corner_023_step_88_flat_merit_test() {
    room_corner_023_mend_keeps_the_point(
        88,
        |s| NewtonSettings {
            flat_merit_window: 0,
            ..s
        },
        255,
        260,
    );
}

/// `023_room_corner`'s step `step` solved with today's settings (at most `mended_max`
/// iterations) and with one mend turned off by `without` (at least `before_min`): the mend only
/// stops a run that cannot succeed sooner, so the attempt that solves the step is the same and
/// both runs end at the same point, bit for bit.
fn room_corner_023_mend_keeps_the_point(
    step: usize,
    without: fn(NewtonSettings) -> NewtonSettings,
    mended_max: usize,
    before_min: usize,
) {
    let (sim, settings) = room_corner_023_at(step);
    let z0 = sim.z().to_vec();
    let mended = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings.clone()), &z0));
    assert_iterations(&mended, ..=mended_max);
    let before = converged(sim.solve_step_problem(&mut NewtonSolver::new(without(settings)), &z0));
    assert_iterations(&before, before_min..);
    assert_eq!(mended.z, before.z, "step {step}: the same end point");
}

/// `023_room_corner` step 36 (on the trajectory before the ratio test): after the first Newton
/// steps, full Newton and minimum-norm steps of length 1 … 90 (scene scales) drive the residual
/// of an inactive face from ≈ +20 to −100 … −300 and `Ψ` up by 1e4 … 1e6; the plain iteration
/// crawled in Levenberg–Marquardt steps until the rate test cut it, and the non-monotone restart
/// solved the step: 181 iterations. With the ratio test the plain iteration stops such steps at
/// the first pair that leaves its cone and solves the step in 71
/// (`docs/newton.md#the-ratio-test`).
#[test]
fn newton_room_corner_023_step_36_ratio_test() {
    room_corner_023_mended_by_the_ratio_test(36, 90, 170);
}

/// `023_room_corner` step 88 (on the trajectory before the ratio test): both runs of the plain
/// iteration end on a stationary point of the merit (natural residual 1.1e-4) and the smoothing
/// continuation solves the step: 246 iterations, also with the ratio test gated to the 20th
/// iteration of a run on (the flat-merit test cut the plain runs at 31 and 20). With the ratio
/// test from the first iteration the plain iteration solves it in 28
/// (`docs/newton.md#the-ratio-test`).
#[test]
fn newton_room_corner_023_step_88_ratio_test_from_the_first_iteration() {
    room_corner_023_mended_by_the_ratio_test(88, 40, 200);
}

/// `023_room_corner`'s step `step` with the ratio test: at most `mended_max` iterations, by the
/// plain iteration (no continuation); without it at least `before_min`.
fn room_corner_023_mended_by_the_ratio_test(step: usize, mended_max: usize, before_min: usize) {
    let (sim, settings) = room_corner_023_at(step);
    let z0 = sim.z().to_vec();
    let mended = converged(sim.solve_step_problem(
        &mut NewtonSolver::new(NewtonSettings {
            ratio_test: true,
            ..settings.clone()
        }),
        &z0,
    ));
    assert_iterations(&mended, ..=mended_max);
    assert_eq!(
        mended
            .summary
            .counter(Counter::SmoothingStages)
            .unwrap_or(0),
        0,
        "step {step}: solved by the plain iteration, no continuation"
    );
    let before = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    assert_iterations(&before, before_min..);
}

/// `062_room_corner` step 128: the plain iteration crosses a valley of the merit in
/// Levenberg–Marquardt steps of constant length, its residual falling ~3 % an iteration, and
/// converges abruptly at iteration 87 (2.6e-3 at 30, 9.7e-5 at 81, 1.8e-7 at 84). Its rate at
/// iteration 60 foretold 3.96 times the iterations it had left: the rate test's margin (6) has
/// to let it run (with 2 it was cut at 60 and the step took 109 iterations, at another point).
#[test]
fn newton_room_corner_062_step_128_rate_test_lets_a_valley_finish() {
    let tolerance = scene_tolerance(&regression_scene("062_room_corner"));
    let settings = NewtonSettings {
        tolerance: tolerance.unwrap_or(1e-10),
        ..main_order()
    };
    let mut driver = NewtonSolver::new(settings.clone());
    let (sim, _) = at_step("062_room_corner", &mut driver, 128);
    let z0 = sim.z().to_vec();
    let sol = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings.clone()), &z0));
    assert_iterations(&sol, ..=90);
    let without = converged(sim.solve_step_problem(
        &mut NewtonSolver::new(NewtonSettings {
            slow_rate_test: false,
            ..settings
        }),
        &z0,
    ));
    assert_eq!(sol.z, without.z);
}

/// `018_union_tip` (h = 8 ms, μ = 0.12, an L of two boxes tipped over an edge of its hull by a
/// torque; 32 unknowns): while the body tips, its contact's ECP lies inside the edge, and the
/// predicted pose (the last step's velocity continued) tilts that edge by its second-order error
/// (`h²|ω|²` × its length, 1e-5 … 2e-4 m), so one end of the edge came lowest and the warm start
/// moved `a1` there, up to 37 cm from the solution's, with three face multipliers. The
/// Fischer–Burmeister rows of that vertex hold `a1` on it, and Newton needed the continuation on
/// every step from 27 to 50 (37–899 iterations a step, 9471 in the run against PATH's 677). The
/// warm start now keeps a contact on its edge or face when the predicted lowest point is on that
/// feature and does not penetrate (`docs/newton.md#a-tipping-edge-predicted-tilted-018_union_tip`):
/// 4–7 iterations a step, no restart.
#[test]
fn newton_union_tip_018_tipping_edge_keeps_its_ecp() {
    let path = regression_scene("018_union_tip");
    let settings = NewtonSettings {
        tolerance: scene_tolerance(&path).unwrap_or(1e-10),
        ..main_order()
    };
    let mut driver = NewtonSolver::new(settings.clone());
    let (mut sim, _) = at_step_of(&path, &mut driver, 27);
    // Steps 27–50: the body tips over the edge, then lifts onto a vertex at step 52.
    for k in 27..=50 {
        let rec = sim
            .step(&mut driver)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(
            rec.converged,
            "step {k}: residual {:e}",
            rec.summary.residual
        );
        assert!(
            rec.summary.iterations <= 12,
            "step {k}: {} iterations, expected at most 12",
            rec.summary.iterations
        );
        assert_eq!(
            rec.summary.counter(Counter::SmoothingStages).unwrap_or(0),
            0,
            "step {k}"
        );
    }
    // Step 38 from its warm start: the plain iteration alone.
    let (sim, _) = at_step_of(&path, &mut NewtonSolver::new(settings.clone()), 38);
    let z0 = sim.z().to_vec();
    let sol = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    assert_iterations(&sol, ..=12);
}

/// `012_multi_body` step 475 on PATH's own trajectory (as it was before these settings): every
/// attempt as given cycled at its watchdog (635 iterations, 370 000 pivots, 6 s) before the
/// first attempt in the scene scales converged in 3. With `first_in_both_units` the scaled
/// first attempt runs before the restarts as given.
#[test]
#[ignore = "slow: cargo test --release --test hard_steps -- --ignored path_multi_body_step_475"]
fn path_multi_body_step_475_first_in_both_units() {
    let old = PathSettings {
        first_in_both_units: false,
        watchdog_growth: f64::INFINITY,
        ..PathSettings::default()
    };
    let mut driver = PathSolver::new(old.clone());
    let (sim, tolerance) = at_step("012_multi_body", &mut driver, 475);
    let z0 = sim.z().to_vec();
    let tolerance = tolerance.unwrap_or(1e-10);
    let mended = converged(sim.solve_step_problem(
        &mut PathSolver::new(PathSettings {
            tolerance,
            ..PathSettings::default()
        }),
        &z0,
    ));
    assert_iterations(&mended, ..=250);
    let before = converged(
        sim.solve_step_problem(&mut PathSolver::new(PathSettings { tolerance, ..old }), &z0),
    );
    assert_iterations(&before, 501..);
}

/// `012_multi_body` run as `ecp run` runs it, with PATH: before `first_attempt_pivots` step 1008
/// spent the whole 20 s `time_limit` in its first attempt as given (42 iterations of thousands
/// of pivots each, 32 of the run's 36 s) where the first attempt in the scene scales converges in
/// 7 iterations and 13 pivots. Now no step makes more pivots than the budget (100 per unknown)
/// plus one more Lemke path (at most 50 per unknown) and the scaled attempt's.
#[test]
#[ignore = "slow: cargo test --release --test hard_steps -- --ignored path_multi_body_run_first_attempt_pivots"]
fn path_multi_body_run_first_attempt_pivots() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/stress_regressions/012_multi_body.toml");
    let file = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
    let out = std::env::temp_dir().join(format!("ecp_hard_steps_012_{}", std::process::id()));
    let options = ecp::run::RunOptions {
        out_dir: out.clone(),
        solver: Some("path".to_string()),
        formulation: Some("hull".to_string()),
        plots: false,
        fallbacks: false,
        ..Default::default()
    };
    let n = {
        let (sim, _) = at_step(
            "012_multi_body",
            &mut PathSolver::new(PathSettings::default()),
            1,
        );
        sim.z().len()
    };
    let mut worst = (0usize, 0usize);
    let outcome = ecp::run::run_scene(&file, &options, |rec| {
        assert!(rec.converged, "step {} did not converge", rec.step);
        let pivots = rec.summary.counter(Counter::Pivots).unwrap_or(0);
        if pivots > worst.0 {
            worst = (pivots, rec.step);
        }
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let _ = std::fs::remove_dir_all(&out);
    assert_eq!(outcome.records.len(), file.scene.num_steps());
    let (pivots, step) = worst;
    assert!(
        pivots <= 160 * n,
        "step {step}: {pivots} pivots for {n} unknowns"
    );
}

/// The scene file `path` stepped by the conic backend with `dense_qp` as given through step
/// `step − 1` (every step must converge), with step `step` prepared.
fn conic_at_step(path: &Path, dense_qp: bool, step: usize) -> Simulation {
    let mut driver = ConicSolver::new(ConicSettings {
        tolerance: scene_tolerance(path).unwrap_or(1e-10),
        dense_qp,
        ..ConicSettings::default()
    });
    at_step_of(path, &mut driver, step).0
}

/// `a5_drop_tilted` step 16 (the tilted box tipping on one vertex; `docs/latency.md#conic-backend`):
/// with a fixed three Gauss–Seidel sweeps in the polish, the outer fixed point converged to a
/// point whose loaded vertex was 1.2e-12 m deep (natural residual 1.23e-10, tolerance 1e-10)
/// when the QPs came from the dense method, and stagnated there for 26 QPs; the remainder of
/// the truncated sweeps depended on which QP method produced the duals. With the sweeps run
/// until they settle, both QP methods give the same outer iterates to round-off and converge
/// in 6 QPs, without a Newton polish.
#[test]
fn conic_a5_drop_tilted_step_16_both_qp_methods() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/a5_drop_tilted.toml");
    let sim = conic_at_step(&path, false, 16);
    let z0 = sim.z().to_vec();
    let solve = |dense_qp: bool| {
        converged(sim.solve_step_problem(
            &mut ConicSolver::new(ConicSettings {
                dense_qp,
                newton_polish: 0,
                ..ConicSettings::default()
            }),
            &z0,
        ))
    };
    let (clarabel, dense) = (solve(false), solve(true));
    for sol in [&clarabel, &dense] {
        assert!(
            sol.summary.iterations <= 8,
            "{} outer QPs",
            sol.summary.iterations
        );
    }
    assert_eq!(clarabel.summary.iterations, dense.summary.iterations);
    assert_eq!(
        dense.summary.counter(Counter::Custom("clarabel_fallbacks")),
        Some(0)
    );
    // The same point to round-off (the steps' unknowns are O(1) here).
    let worst = clarabel
        .z
        .iter()
        .zip(&dense.z)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        worst <= 1e-12,
        "the two QP methods' answers differ by {worst:e}"
    );
}

/// `073_ladder` (a ladder against a wall: two contacts of one body, the anchored case) with every
/// QP by the dense method: step 320 failed (the fixed point stagnated at 2.4e-8 from the warm
/// start and from the stepper's retry, also after a Newton polish) and so did every later step (348
/// failed steps). With the settled polish the step converges without a Newton polish (from the
/// plain warm start the fixed point still stagnates, at 1.5e-7: the retry from the
/// active-contact guess solves it, in 4 QPs), and so do the next 20.
#[test]
fn conic_ladder_073_step_320_dense_qps() {
    let path = regression_scene("073_ladder");
    let mut sim = conic_at_step(&path, true, 320);
    let mut solver = ConicSolver::new(ConicSettings {
        tolerance: 1e-10,
        dense_qp: true,
        newton_polish: 0,
        ..ConicSettings::default()
    });
    for k in 320..340 {
        let rec = sim
            .step(&mut solver)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(
            rec.converged && rec.summary.iterations <= 8,
            "step {k}: converged {}, {} outer QPs, residual {:e}",
            rec.converged,
            rec.summary.iterations,
            rec.summary.residual
        );
    }
}

/// `135_union_tip` (a union of pieces tipping over an edge) with the clarabel QPs: step 94 failed
/// after the polish's sweeps were made to settle (the fixed point stalled at residual 3.3e-4 and
/// the Newton polish did not rescue it): the polish corrected only the loaded vertices' gaps and
/// drove the unloaded vertex of the tipping edge into the floor at -0.068 m/s, a point the QP
/// (which keeps every vertex's row) never gives. With the active-set loop in the polish (a
/// violated vertex joins the corrected set) the step converges, and so do the next 5.
#[test]
fn conic_union_tip_135_step_94_active_set_polish() {
    let path = regression_scene("135_union_tip");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let mut sim = conic_at_step(&path, false, 94);
    let mut solver = ConicSolver::new(ConicSettings {
        tolerance,
        ..ConicSettings::default()
    });
    for k in 94..100 {
        let rec = sim
            .step(&mut solver)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(
            rec.converged && rec.summary.residual <= tolerance,
            "step {k}: converged {}, {} outer QPs, residual {:e} (tolerance {tolerance:e})",
            rec.converged,
            rec.summary.iterations,
            rec.summary.residual
        );
    }
}

/// `126_v_trough` (a box wedged in a V trough, held by friction) and `020_corner_wall` (a box
/// pushed into a wall): the body touches two supports, so its contacts carry the conic
/// backend's load anchor, and the loads that solve a step are not unique (the wedge's squeeze,
/// the corner's split between floor and wall). The first QP of a step used to centre the anchor
/// on zero loads: it returned another member of the solution set, millimetres·N·s away from the
/// warm start, and the fixed point walked back from it by the proximal iteration (10 QPs every
/// other step on the trough, 7 per step on the corner). Centred on the warm start's loads, a
/// step close to the previous one takes 1–2 QPs (`docs/latency.md#conic-backend`).
#[test]
fn conic_two_supports_first_qp_anchored_at_the_warm_start() {
    for name in ["126_v_trough", "020_corner_wall"] {
        conic_steps_within(name, 2..=40, 2);
    }
}

/// Steps `steps` of the regression scene `name` with the conic backend (dense QPs, no Newton
/// polish): each converges to the scene's tolerance in at most `max_qps` outer QPs.
fn conic_steps_within(name: &str, steps: std::ops::RangeInclusive<usize>, max_qps: usize) {
    let path = regression_scene(name);
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let mut sim = conic_at_step(&path, true, *steps.start());
    let mut solver = ConicSolver::new(ConicSettings {
        tolerance,
        newton_polish: 0,
        ..ConicSettings::default()
    });
    for k in steps {
        let rec = sim
            .step(&mut solver)
            .unwrap_or_else(|e| panic!("{name} step {k}: {e}"));
        assert!(
            rec.converged && rec.summary.residual <= tolerance,
            "{name} step {k}: converged {}, residual {:e}",
            rec.converged,
            rec.summary.residual
        );
        assert!(
            rec.summary.iterations <= max_qps,
            "{name} step {k}: {} outer QPs, expected at most {max_qps}",
            rec.summary.iterations
        );
    }
}

/// `087_v_trough` steps 4–12 (μ = 1.18, a box sliding along a steep V on one vertex per
/// support; `docs/latency.md#conic-backend`): the polish's Gauss–Seidel sweeps (normal
/// correction, then each contact's friction) contract at about 0.85 per sweep here and stopped
/// at their cap of 50 with a remainder of 1e-9, so the outer fixed point settled at a natural
/// residual of 1.136e-10 against the tolerance 1e-10 and stagnated (24–35 QPs, then the Newton
/// polish; without the Newton polish not converged). With the joint Newton step on the polish's
/// active set after 10 unsettled sweeps each step takes 3 QPs, without a Newton polish.
#[test]
fn conic_v_trough_087_joint_polish() {
    conic_steps_within("087_v_trough", 4..=12, 4);
}

/// `025_multi_body` step 30 (four bodies apart, 170 unknowns: above `dense_max`, so the
/// Levenberg–Marquardt system is not the dense product): one of the three steps that made the
/// run 10× PATH's (`docs/newton.md#cheap-levenberg-marquardt-trials`). Each damping trial was a
/// sparse LU of the augmented 340 × 340 system (1.1 ms against 0.17 ms for the LU of `H`); the
/// product `HᵀH + λI` keeps the bodies' blocks, and its sparse Cholesky needs 3.4e4
/// multiplications. Asserted: every trial is such a Cholesky (none an augmented LU), at most
/// 5e4 multiplications each, and the step needs at most 600 trials (281 measured); with
/// `lm_sparse_product = false`, as before, every trial is an augmented LU; both converge to the
/// same point (to 1e-7 relative: the trials' round-off differs, so the iterates do).
#[test]
fn newton_multi_body_025_step_30_cheap_damping_trials() {
    let tolerance = scene_tolerance(&regression_scene("025_multi_body"));
    let settings = NewtonSettings {
        tolerance: tolerance.unwrap_or(1e-10),
        ..main_order()
    };
    let mut driver = NewtonSolver::new(settings.clone());
    let (sim, _) = at_step("025_multi_body", &mut driver, 30);
    let z0 = sim.z().to_vec();
    assert!(sim.step_problem().dim() > settings.dense_max);

    let mut solver = NewtonSolver::new(settings.clone()).with_profile();
    let cheap = converged(sim.solve_step_problem(&mut solver, &z0));
    let profile = solver.take_profile();
    assert!(
        (100..=600).contains(&profile.lm_trials),
        "{} damping trials",
        profile.lm_trials
    );
    assert_eq!(profile.lm_augmented_factorizations, 0);
    assert!(
        profile.lm_cholesky_flops <= 5e4 * profile.lm_trials as f64,
        "{:e} multiplications in {} trials",
        profile.lm_cholesky_flops,
        profile.lm_trials
    );

    let mut solver = NewtonSolver::new(NewtonSettings {
        lm_sparse_product: false,
        ..settings
    })
    .with_profile();
    let old = converged(sim.solve_step_problem(&mut solver, &z0));
    let profile = solver.take_profile();
    assert!(profile.lm_trials > 0);
    assert_eq!(profile.lm_augmented_factorizations, profile.lm_trials);
    assert_eq!(profile.lm_cholesky_flops, 0.0);
    // The same solution (both converged in the scene's scales), but for the slip rates σ of
    // open contacts, which any σ ≥ 0 solves at p_n = 0, and the multipliers `l` of the hull's
    // faces, which are not unique where the closest point is a vertex or an edge.
    let problem = sim.step_problem();
    for (i, (a, b)) in cheap.z.iter().zip(&old.z).enumerate() {
        let name = problem.component_name(i);
        if !name.contains("sigma") && !name.contains(".l[") {
            assert!(
                (a - b).abs() <= 1e-7 * (1.0 + b.abs()),
                "{name}: {a:e} against {b:e}"
            );
        }
    }
}

/// `087_v_trough` with Newton as `ecp run` steps it (extrapolated warm start, no fallbacks):
/// every step converges, and with every start first within its budget
/// (`docs/latency.md#budgeted-starts-newtons-long-steps-branch-wip-hardsteps-issue-18`) no step takes the
/// hundreds of iterations of main before the budgets (213 at its hardest step, 448 in all;
/// 29 at step 2 and 101 with them, as in the stress suite).
#[test]
fn newton_v_trough_087_budgeted_starts() {
    let path = regression_scene("087_v_trough");
    let file = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
    let out = std::env::temp_dir().join(format!("ecp_hard_steps_087_{}", std::process::id()));
    let options = ecp::run::RunOptions {
        out_dir: out.clone(),
        solver: Some("newton".to_string()),
        formulation: Some("hull".to_string()),
        plots: false,
        fallbacks: false,
        ..Default::default()
    };
    let (mut total, mut worst) = (0usize, (0usize, 0usize));
    let outcome = ecp::run::run_scene(&file, &options, |rec| {
        assert!(rec.converged, "step {} did not converge", rec.step);
        let iterations = rec.summary.iterations;
        total += iterations;
        if iterations > worst.0 {
            worst = (iterations, rec.step);
        }
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let _ = std::fs::remove_dir_all(&out);
    assert_eq!(outcome.records.len(), file.scene.num_steps());
    let (iterations, step) = worst;
    assert!(iterations <= 60, "step {step}: {iterations} iterations");
    assert!(total <= 200, "{total} iterations in all");
}

/// `s20261128_061_v_trough` step 17 (the held-out seed 20261128, `docs/stress.md`; h = 1.5 ms,
/// μ = 0.78, a point body coming to rest in a V trough; 77 unknowns), on the trajectory of the
/// default simulation (extrapolated warm start, budgeted starts) driven by Newton before the
/// complementary restart. At the warm start the second contact carries `p_n` = 5e-10 and slides
/// (`σ` = 8e-4, its friction cone row positive by round-off); every attempt from there stays on
/// that branch and stagnates at a natural residual 1.3 times the tolerance in the scene's scales,
/// the contact unloaded and the body sliding. The solution (PATH's, in 2 936 iterations) loads
/// that contact (`p_n` ≈ 0.2) and sticks. From the complementary start (`σ` and the first
/// contact's `p_n` put on their bound, where `F` is positive) the plain iteration converges in
/// 10 iterations (`docs/newton.md#the-complementary-start`), to a solution with the second
/// contact loaded and sticking.
#[test]
fn newton_v_trough_061_step_17_complementary_restart() {
    let path = regression_scene("s20261128_061_v_trough");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = NewtonSettings {
        tolerance,
        ..main_order()
    };
    let before = NewtonSettings {
        complementary_restart: None,
        early_complementary_restart: None,
        complementary_restart_from_best: None,
        // The structure reseed (wip-tip070) also cures this step: off, to test the restart.
        structure_reseed: false,
        ..settings.clone()
    };
    let sim = at_default_step(&path, &mut NewtonSolver::new(before.clone()), 17);
    let z0 = sim.z().to_vec();
    match sim.solve_step_problem(&mut NewtonSolver::new(before), &z0) {
        Err(SolveError::NotConverged { best }) => assert!(
            best.summary.residual > tolerance,
            "residual {:e}",
            best.summary.residual
        ),
        Ok(sol) => panic!(
            "converged without the complementary restart in {} iterations",
            sol.summary.iterations
        ),
        Err(e) => panic!("{e}"),
    }
    let mended = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    assert_eq!(
        mended
            .summary
            .counter(Counter::Custom("complementary_restarts")),
        Some(1)
    );
    let problem = sim.step_problem();
    // A solution by a check of its own: the natural residual in the scene's scales.
    let scales = problem
        .scales()
        .expect("a step problem has scene scales")
        .clone();
    let scaled = ScaledMcp::new(&problem, &scales).expect("valid scales");
    let zs = scaled.to_scaled(&mended.z);
    let mut f = vec![0.0; zs.len()];
    scaled.evaluate(&zs, &mut f);
    let residual = natural_residual(&zs, &f, scaled.lower(), scaled.upper());
    assert!(
        residual <= tolerance,
        "natural residual {residual:e} in the scene's scales"
    );
    let index = |name: &str| {
        (0..problem.dim())
            .find(|&i| problem.component_name(i) == name)
            .unwrap_or_else(|| panic!("no component {name}"))
    };
    // The second contact is loaded and sticks (before: p_n 4e-7, σ 8e-4). The step has more
    // than one solution: PATH's loads both contacts (p_n 0.20 and 0.20, both sticking); this one
    // leaves the first contact touching without load (p_n ≈ 1e-9) and holds the body by the
    // second (p_n 0.245), which friction allows (μ = 0.78 against slopes of 22.5° and 20.5°).
    assert!(mended.z[index("body.c1.pn[0]")] > 0.1);
    assert!(mended.z[index("body.c1.sigma[0]")].abs() < 1e-8);
}

/// `035_v_trough` step 27 (a T of two boxes sliding into a V trough, 53 unknowns;
/// `docs/newton.md#a-crawling-continuation`): the plain and non-monotone attempts end at a
/// natural residual of 1.1e-6 (1.1e4 times the tolerance), the undamped smoothing continuation
/// then crawls, and the damped attempts solve the step after about 750 iterations in all; the
/// plain iteration from the complementary start solves it in 47. With the complementary restart
/// tried before the continuations (`NewtonSettings::early_complementary_restart`,
/// `docs/newton.md#the-complementary-start-earlier`) the step takes about 300 iterations.
#[test]
fn newton_v_trough_035_step_27_early_complementary_restart() {
    let path = regression_scene("035_v_trough");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = NewtonSettings {
        tolerance,
        ..main_order()
    };
    let late = NewtonSettings {
        early_complementary_restart: None,
        ..settings.clone()
    };
    // The start as recorded: steps 1–26 without the chord steps' round-off floor, which came
    // later and moves the trajectory by round-off; the complementary start's sign tests make
    // this step's restart sensitive to that (from the merged code's own step 26 the early
    // restart is tried and fails: 697 iterations either way, docs/newton.md).
    let sim = at_default_step(
        &path,
        &mut NewtonSolver::new(NewtonSettings {
            chord_round_off_floor: None,
            ..late.clone()
        }),
        27,
    );
    let z0 = sim.z().to_vec();
    let before = converged(sim.solve_step_problem(&mut NewtonSolver::new(late), &z0));
    let early = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    println!(
        "035_v_trough step 27: {} iterations with the late complementary restart, {} with the early one",
        before.summary.iterations, early.summary.iterations
    );
    // Measured: 757 and 294.
    assert_iterations(&before, 600..);
    assert_iterations(&early, ..=400);
    assert_eq!(
        early
            .summary
            .counter(Counter::Custom("complementary_restarts")),
        Some(1)
    );
    assert!(early.summary.residual <= tolerance);
    // The late order never reaches the complementary start: a continuation solves the step.
    assert_eq!(
        before
            .summary
            .counter(Counter::Custom("complementary_restarts")),
        None
    );
}

/// `s20261201_061_v_trough` step 70 (the held-out seed 20261201; a box resting in a V trough,
/// `docs/newton.md#the-complementary-start-from-the-best-point`): every attempt from `z0`, the
/// complementary restarts from `z0` included, ends in a curved valley of the merit at a natural
/// residual of about 1.3e3 times the tolerance (contact 0's point sliding along an edge that lies
/// flat on the 32.5° plane). The complementary start of the failed attempts' best point leaves
/// the valley and the step converges.
#[test]
fn newton_v_trough_s20261201_061_step_70_complementary_restart_from_the_best_point() {
    let path = regression_scene("s20261201_061_v_trough");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = NewtonSettings {
        tolerance,
        ..main_order()
    };
    let sim = at_default_step(&path, &mut NewtonSolver::new(settings.clone()), 70);
    let z0 = sim.z().to_vec();
    let without = sim.solve_step_problem(
        &mut NewtonSolver::new(NewtonSettings {
            complementary_restart_from_best: None,
            ..settings.clone()
        }),
        &z0,
    );
    match without {
        Err(SolveError::NotConverged { best }) => assert!(
            best.summary.residual > 100.0 * tolerance,
            "without the restart from the best point: stalls far above the tolerance, got {:e}",
            best.summary.residual
        ),
        Ok(sol) => panic!(
            "converged without the restart from the best point ({} iterations): the test's premise is gone",
            sol.summary.iterations
        ),
        Err(e) => panic!("{e}"),
    }
    let mended = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    println!(
        "s20261201_061_v_trough step 70: {} iterations, residual {:e}",
        mended.summary.iterations, mended.summary.residual
    );
    assert!(mended.summary.residual <= tolerance);
    assert!(
        mended
            .summary
            .counter(Counter::Custom("complementary_restarts"))
            .is_some_and(|n| n >= 1)
    );
}

/// `s20261212_022_v_trough` step 62 (the held-out seed 20261212; a point body of 18 vertices in a
/// V trough of sides 58.5° and 36°, μ = 0.8, h = 10 ms, 101 unknowns;
/// `docs/newton.md#a-jam-in-the-crease-s20261212_022_v_trough-step-62`): one vertex lies in the
/// trough's crease, so both contacts have the same contact point; the step's solution wedges the
/// body, both normal impulses 6 times the warm start's and tangential impulses of ±1.3 that
/// cancel. Every attempt from the warm start stalls at a natural residual of 2–3e-6 (2e4 times
/// the tolerance): without the continuation in the friction coefficient Newton alone must
/// report the step as failed. With it (`docs/newton.md#a-continuation-in-the-friction-coefficient`)
/// the step converges, its own natural residual in the scene's scales within the tolerance, on
/// the wedging branch (both `p_n` above 1.5, five times the warm start's).
#[test]
fn newton_v_trough_s20261212_022_step_62_jam_in_the_crease() {
    let path = regression_scene("s20261212_022_v_trough");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = NewtonSettings {
        tolerance,
        ..main_order()
    };
    let sim = at_default_step(&path, &mut NewtonSolver::new(settings.clone()), 62);
    let z0 = sim.z().to_vec();
    let without = NewtonSettings {
        friction_continuation: None,
        ..settings.clone()
    };
    match sim.solve_step_problem(&mut NewtonSolver::new(without), &z0) {
        Err(SolveError::NotConverged { best }) => {
            println!(
                "s20261212_022_v_trough step 62 without the continuation: reported as failed, {} \
                 iterations, best residual {:e}",
                best.summary.iterations, best.summary.residual
            );
            assert!(
                best.summary.residual > 100.0 * tolerance,
                "a failed solve whose best point is near the tolerance ({:e})",
                best.summary.residual
            );
        }
        Ok(sol) => panic!(
            "without the continuation Newton returned step 62 ({} iterations, residual {:e}): \
             the test's premise is gone",
            sol.summary.iterations, sol.summary.residual
        ),
        Err(e) => panic!("{e}"),
    }
    let sol = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    println!(
        "s20261212_022_v_trough step 62 with the continuation: {} iterations, residual {:e}",
        sol.summary.iterations, sol.summary.residual
    );
    assert_eq!(
        sol.summary
            .counter(Counter::Custom("friction_continuations")),
        Some(1)
    );
    let problem = sim.step_problem();
    let scales = problem
        .scales()
        .expect("a step problem has scene scales")
        .clone();
    let scaled = ScaledMcp::new(&problem, &scales).expect("valid scales");
    let zs = scaled.to_scaled(&sol.z);
    let mut f = vec![0.0; zs.len()];
    scaled.evaluate(&zs, &mut f);
    let residual = natural_residual(&zs, &f, scaled.lower(), scaled.upper());
    assert!(
        residual <= tolerance,
        "natural residual {residual:e} in the scene's scales"
    );
    for c in &sim.handles().contacts {
        let (before, after) = (
            z0[sim.mcp().offset(c.normal)],
            sol.z[sim.mcp().offset(c.normal)],
        );
        assert!(
            after > 1.5 && after > 5.0 * before,
            "p_n {before} -> {after}: not the wedging branch"
        );
    }
}

/// `s20261226_049_room_corner` step 16 (the held-out seed 20261226; a box tossed into a room
/// corner, three contacts, 67 unknowns, `docs/newton.md#josephy-newton-steps`): the third
/// contact's closest point moves 37 cm to another vertex and the wall contact's `p_n` rises
/// 3.4 → 5.2. The plain iteration stalls at a local minimiser of the merit and the restarts after
/// it (non-monotone, continuation, damped, damped continuation) cost about 430 iterations; the
/// Josephy–Newton steps (the linearised MCP solved by pivoting) solve it in a few after the
/// failed plain run.
#[test]
fn newton_room_corner_s20261226_049_step_16_josephy_newton() {
    let path = regression_scene("s20261226_049_room_corner");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = NewtonSettings {
        tolerance,
        ..NewtonSettings::default()
    };
    let without = NewtonSettings {
        josephy_newton: None,
        ..settings.clone()
    };
    // Main's trajectory (without the steps) up to step 15, the step as the base run met it.
    let sim = at_default_step(&path, &mut NewtonSolver::new(without.clone()), 16);
    let z0 = sim.z().to_vec();
    let before = converged(sim.solve_step_problem(&mut NewtonSolver::new(without), &z0));
    let after = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    println!(
        "s20261226_049_room_corner step 16: {} iterations without the Josephy-Newton steps, {} with",
        before.summary.iterations, after.summary.iterations
    );
    // Measured: 431 and 58.
    assert_iterations(&before, 300..);
    assert_iterations(&after, ..=100);
    assert!(after.summary.residual <= tolerance);
    assert_eq!(
        after
            .summary
            .counter(Counter::Custom("josephy_newton_restarts")),
        Some(1)
    );
}

/// `s20270102_057_union_tip` step 188 (the held-out seed 20270102; a table, a union of five
/// boxes, tipping on an edge of its hull while it spins; one contact, 31 unknowns) from the
/// plain warm start, PATH's full solve in the driver's second pass (`docs/latency.md`,
/// wip-tip057): the step lies past a fold of the branch the last steps followed, so every
/// attempt from the warm start ends at the fold's local minimiser of the merit (natural
/// residual ~4e-6, the ECP 8 cm short of the solution's along the edge and the friction's
/// tangential component reversed) and the smoothing continuation solves the step. At that
/// minimiser the path search accepts `t ≈ 7e-9` of a ~1e-13 path again and again until each
/// attempt's limit; the frozen-iterate stop (`PathSettings::frozen_steps`) ends those attempts
/// after 10 such steps.
#[test]
fn path_union_tip_s20270102_057_step_188_frozen_iterate() {
    let path = regression_scene("s20270102_057_union_tip");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = PathSettings {
        tolerance,
        ..PathSettings::default()
    };
    let without = PathSettings {
        frozen_steps: 0,
        ..settings.clone()
    };
    // The default simulation's trajectory through step 187, then step 188 from the plain warm
    // start (the driver's first retry start after the extrapolated one).
    let file = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
    let stepper = FormulationRegistry::builtin()
        .create("hull")
        .unwrap_or_else(|e| panic!("{e}"));
    let mut sim = SimulationBuilder::new(file.scene.clone(), stepper)
        .build()
        .unwrap_or_else(|e| panic!("{e}"));
    let mut driver = PathSolver::new(settings.clone());
    for k in 1..188 {
        let rec = sim
            .step(&mut driver)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(rec.converged, "step {k} did not converge");
    }
    sim.set_warm_start(WarmStart::Previous);
    sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
    let z0 = sim.z().to_vec();
    let before = converged(sim.solve_step_problem(&mut PathSolver::new(without), &z0));
    let after = converged(sim.solve_step_problem(&mut PathSolver::new(settings), &z0));
    println!(
        "s20270102_057_union_tip step 188: {} iterations without the frozen-iterate stop, {} with",
        before.summary.iterations, after.summary.iterations
    );
    // Measured: 2 249 and 1 285; both solved by the smoothing continuation.
    assert_iterations(&before, 2000..);
    assert_iterations(&after, ..=1500);
    assert!(after.summary.residual <= tolerance);
    // The same solution (PATH polishes to round-off): the ECP at the fold's far side.
    let diff = before
        .z
        .iter()
        .zip(&after.z)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(diff <= 1e-12, "solutions differ by {diff:e}");
}

/// The conic backend with the scene's tolerance and its defaults but the last stage of its
/// Newton finish (`ConicSettings::friction_continuation`) as given.
fn conic_with(tolerance: f64, friction_continuation: Option<usize>) -> ConicSolver {
    ConicSolver::new(ConicSettings {
        tolerance,
        friction_continuation,
        ..ConicSettings::default()
    })
}

/// The conic backend with the scene's tolerance and its defaults but without its two late
/// stages: the Newton finish's continuation in the friction coefficient
/// (`ConicSettings::friction_continuation`) and the unanchored pass after the failed local
/// finishes (`ConicSettings::unanchored_retry`, wip-heldout5, which alone cures
/// `s20270109_087_v_trough` step 140 too).
fn conic_without_late_stages(tolerance: f64) -> ConicSolver {
    ConicSolver::new(ConicSettings {
        tolerance,
        friction_continuation: None,
        unanchored_retry: false,
        ..ConicSettings::default()
    })
}

/// `s20261212_022_v_trough` step 62 with the conic backend alone (the jam in the crease of
/// `newton_v_trough_s20261212_022_step_62_jam_in_the_crease`, on the conic backend's default
/// trajectory): the fixed point stalls at 1.8e-4 and every Newton finish (local and safeguarded,
/// from its best iterate and from the warm start) at 1.6–3.2e-6, near the warm start's branch.
/// Without the finish's last stage the step must be reported as failed; with it (the plain
/// iteration, then the continuation in the friction coefficient, `docs/latency.md`,
/// wip-conic022) it converges to the wedging solution, the one Newton and PATH reach (both `p_n`
/// above 1.5, five times the warm start's), with Newton's velocities from the same start.
#[test]
fn conic_v_trough_s20261212_022_step_62_friction_continuation() {
    let path = regression_scene("s20261212_022_v_trough");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let sim = at_default_step(&path, &mut conic_with(tolerance, Some(400)), 62);
    let z0 = sim.z().to_vec();
    match sim.solve_step_problem(&mut conic_without_late_stages(tolerance), &z0) {
        Err(SolveError::NotConverged { best }) => {
            println!(
                "conic s20261212_022_v_trough step 62 without the last stage: reported as \
                 failed, residual {:e}",
                best.summary.residual
            );
            assert!(
                best.summary.residual > 100.0 * tolerance,
                "a failed solve whose best point is near the tolerance ({:e})",
                best.summary.residual
            );
        }
        Ok(sol) => panic!(
            "without the last stage the conic backend returned step 62 (residual {:e}): the \
             test's premise is gone",
            sol.summary.residual
        ),
        Err(e) => panic!("{e}"),
    }
    let sol = converged(sim.solve_step_problem(&mut conic_with(tolerance, Some(400)), &z0));
    println!(
        "conic s20261212_022_v_trough step 62 with the last stage: {} QPs, {:?} Newton \
         iterations, residual {:e}",
        sol.summary.iterations,
        sol.summary.counter(Counter::NewtonPolish),
        sol.summary.residual
    );
    assert!(sol.summary.residual <= tolerance);
    let mcp = sim.mcp();
    for c in &sim.handles().contacts {
        let (before, after) = (z0[mcp.offset(c.normal)], sol.z[mcp.offset(c.normal)]);
        assert!(
            after > 1.5 && after > 5.0 * before,
            "p_n {before} -> {after}: not the wedging branch"
        );
    }
    // Newton (its own continuation) from the same start: the same velocities to 1e-8 (the
    // unknowns are O(1); the step's loads are not unique in the tangential squeeze).
    let newton = converged(sim.solve_step_problem(
        &mut NewtonSolver::new(NewtonSettings {
            tolerance,
            ..NewtonSettings::default()
        }),
        &z0,
    ));
    for nu in sim.handles().bodies.iter().filter_map(|b| b.nu) {
        for k in 0..6 {
            let i = mcp.offset(nu) + k;
            assert!(
                (sol.z[i] - newton.z[i]).abs() <= 1e-8,
                "velocity {k}: conic {} against Newton {}",
                sol.z[i],
                newton.z[i]
            );
        }
    }
}

/// `s20270109_087_v_trough` step 140 (the held-out seed 20270109; a box of μ = 0.36 sliding along
/// a V trough of sides 37° and 38.5°, h = 3 ms) with the conic backend alone: the fixed point
/// stalls at a natural residual of 4.5e-7 for its 50 QPs, the local and safeguarded Newton
/// finishes from both starts end at 1.6–1.8e-9 (worst row a pose row), from the warm start and
/// from the driver's retry start, so the step failed and, the state not advancing, so did every
/// later one. With the finish's last stage, the continuation in the friction coefficient in the
/// scene scales (`docs/latency.md`, wip-conic022), the step converges (from the retry start's
/// best iterate) with the body's velocity of Newton's and PATH's step 140 on their own
/// trajectories, and the next three steps converge too. The unanchored pass after the failed
/// local finishes (`ConicSettings::unanchored_retry`, wip-heldout5) cures the step alone too,
/// so "without" is without both.
#[test]
fn conic_v_trough_s20270109_087_step_140_friction_continuation() {
    let path = regression_scene("s20270109_087_v_trough");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let mut sim = at_default_step(&path, &mut conic_with(tolerance, Some(400)), 140);
    let without = sim
        .step(&mut conic_without_late_stages(tolerance))
        .unwrap_or_else(|e| panic!("{e}"));
    println!(
        "conic s20270109_087_v_trough step 140 without the last stage: converged {}, residual {:e}",
        without.converged, without.summary.residual
    );
    assert!(
        !without.converged && without.summary.residual > 10.0 * tolerance,
        "without the last stage step 140 converged ({:e}): the test's premise is gone",
        without.summary.residual
    );
    let mut sim = at_default_step(&path, &mut conic_with(tolerance, Some(400)), 140);
    let mut solver = conic_with(tolerance, Some(400));
    for k in 140..=143 {
        let rec = sim
            .step(&mut solver)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(
            rec.converged && rec.summary.residual <= tolerance,
            "step {k}: converged {}, residual {:e}",
            rec.converged,
            rec.summary.residual
        );
        if k == 140 {
            // Newton's and PATH's step 140 (stress --seed 20270109 on main 7b003b0, 1e-13
            // apart): v_x -4.902302726e-3 m/s, v_z 1.450267607e-3 m/s; the state before the
            // step differs from theirs by up to 6e-9 in `v` (measured: 7.5e-11 and 2.1e-11 apart).
            let v = rec.bodies[0].v;
            assert!((v.x + 4.902_302_726e-3).abs() <= 1e-9, "v_x {}", v.x);
            assert!((v.z - 1.450_267_607e-3).abs() <= 1e-9, "v_z {}", v.z);
        }
    }
}

/// `s20270130_014_convex_toss` step 15 (the held-out seed 20270130; a point set tossed with spin
/// landing on the floor, 51 unknowns), run as the stress suite runs it (`ecp run` with PATH, no
/// fallbacks): the driver's budgeted solve fails and the full solve's attempts from the warm
/// start fail before the smoothing continuation solves the step. Those attempts had no pivot
/// budget, so their Lemke paths that do not end ran to Lemke's own limit of 50 pivots per unknown
/// (2 550 each, 67 700 in the step's full solve): 226 iterations, 2.2 s in the stress run. Since
/// every path outside the first attempt's budget stops at 10 pivots per unknown
/// (`docs/path.md#lemke-paths-that-run-to-the-cap`) the step takes 97 iterations; every step
/// converges either way.
#[test]
fn path_convex_toss_s20270130_014_step_15_later_path_cap() {
    let path = regression_scene("s20270130_014_convex_toss");
    let file = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
    let out = std::env::temp_dir().join(format!("ecp_hard_steps_014_{}", std::process::id()));
    let options = ecp::run::RunOptions {
        out_dir: out.clone(),
        solver: Some("path".to_string()),
        formulation: Some("hull".to_string()),
        steps: Some(15),
        plots: false,
        fallbacks: false,
        // The trajectory the step was measured on (the default's extrapolation of order 5
        // reaches step 15 in another state, where it takes 143 iterations; branch wip-xorder).
        warm_start: WarmStart::Quadratic,
        ..Default::default()
    };
    let mut iterations = None;
    let outcome = ecp::run::run_scene(&file, &options, |rec| {
        assert!(rec.converged, "step {} did not converge", rec.step);
        if rec.step == 15 {
            iterations = Some(rec.summary.iterations);
        }
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let _ = std::fs::remove_dir_all(&out);
    assert_eq!(outcome.records.len(), 15);
    let iterations = iterations.unwrap_or_else(|| panic!("no step 15"));
    assert!(
        (60..=130).contains(&iterations),
        "step 15: {iterations} iterations, expected 60..=130 (226 with the paths at 50 per unknown)"
    );
}

/// `s20270213_134_union_slide` step 1 (the held-out seed 20270213; a table, a union of five
/// boxes, of μ = 1.15 set down on its four legs sliding at 1.6 m/s and spinning at 3 rad/s,
/// h = 10 ms, 31 unknowns): PATH solves the step in 10 iterations, but every attempt of Newton
/// in the problem's own units before its last stage (plain, Josephy–Newton, non-monotone,
/// damped, smoothing, damped smoothing) fails: 737 iterations, the best point at a natural
/// residual of 6.5e-4. Two later stages each cure it: the continuation in the friction
/// coefficient (`docs/newton.md#a-continuation-in-the-friction-coefficient`; 1 060 iterations
/// in all, 1 126 with the driver's budgeted start, as in the stress run) and, without it, the
/// attempts again in the scene's scales (the smoothing continuation there; 971). Without both,
/// Newton alone must report the step as failed; with the defaults it converges to PATH's
/// solution.
#[test]
fn newton_union_slide_s20270213_134_step_1_late_stages() {
    let path = regression_scene("s20270213_134_union_slide");
    let defaults = NewtonSettings::default();
    let settings = NewtonSettings {
        tolerance: scene_tolerance(&path).unwrap_or(defaults.tolerance),
        ..defaults
    };
    let sim = at_default_step(&path, &mut NewtonSolver::new(settings.clone()), 1);
    let z0 = sim.z().to_vec();
    let without = NewtonSettings {
        friction_continuation: None,
        scene_scales: false,
        // The structure reseed (wip-tip070) also cures this step (816 iterations): off, as a
        // late stage too.
        structure_reseed: false,
        ..settings.clone()
    };
    match sim.solve_step_problem(&mut NewtonSolver::new(without), &z0) {
        Err(SolveError::NotConverged { best }) => {
            println!(
                "s20270213_134_union_slide step 1 without the late stages: reported as failed, \
                 {} iterations, best residual {:e}",
                best.summary.iterations, best.summary.residual
            );
            assert!(
                best.summary.residual > 100.0 * settings.tolerance,
                "a failed solve whose best point is near the tolerance ({:e})",
                best.summary.residual
            );
        }
        Ok(sol) => panic!(
            "without the late stages Newton returned step 1 ({} iterations, residual {:e}): \
             the test's premise is gone",
            sol.summary.iterations, sol.summary.residual
        ),
        Err(e) => panic!("{e}"),
    }
    let sol = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    println!(
        "s20270213_134_union_slide step 1 with the defaults: {} iterations, residual {:e}",
        sol.summary.iterations, sol.summary.residual
    );
    assert_eq!(
        sol.summary
            .counter(Counter::Custom("friction_continuations")),
        Some(1)
    );
    let reference =
        converged(sim.solve_step_problem(&mut PathSolver::new(PathSettings::default()), &z0));
    assert_iterations(&reference, ..=20);
    let gap = sol
        .z
        .iter()
        .zip(&reference.z)
        .map(|(a, b)| (a - b).abs() / b.abs().max(1.0))
        .fold(0.0, f64::max);
    println!("largest difference from PATH's solution: {gap:e}");
    assert!(
        gap <= 1e-9,
        "Newton's solution differs from PATH's by {gap:e}"
    );
}

/// `s20270320_129_multi_body` step 4 (the held-out seed 20270320; four bodies in their lanes,
/// three resting on faces, 144 unknowns, `docs/stress.md`, branch wip-heldout4): on a resting
/// face `H` is singular (the face's pressure is not a point), so the LU step fails and the
/// minimum-norm step is the one that converges; with that step only up to 120 unknowns (the
/// old limit, `dense_max`) the plain iteration crawled in Levenberg–Marquardt steps and the
/// driver's budgeted start failed on 345 of the 375 steps. `NewtonSettings::min_norm_max`.
#[test]
fn newton_multi_body_s20270320_129_step_4_minimum_norm_above_dense_max() {
    let path = regression_scene("s20270320_129_multi_body");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = NewtonSettings {
        tolerance,
        ..NewtonSettings::default()
    };
    let old_limit = NewtonSettings {
        min_norm_max: settings.dense_max,
        ..settings.clone()
    };
    let sim = at_default_step(&path, &mut NewtonSolver::new(settings.clone()), 4);
    assert!(
        sim.z().len() > settings.dense_max,
        "{} unknowns",
        sim.z().len()
    );
    let z0 = sim.z().to_vec();
    let before = converged(sim.solve_step_problem(&mut NewtonSolver::new(old_limit), &z0));
    let after = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    println!(
        "s20270320_129_multi_body step 4: {} iterations with minimum-norm steps up to 120 unknowns, {} up to 200",
        before.summary.iterations, after.summary.iterations
    );
    // Measured: 36 and 1.
    assert_iterations(&before, 10..);
    assert_iterations(&after, ..=3);
    assert!(after.summary.residual <= tolerance);
    assert!(
        after
            .summary
            .counter(Counter::MinNormSteps)
            .is_some_and(|n| n > 0),
        "{}",
        after.summary.counters
    );
}

/// `s20270320_070_union_tip` step 97 (a chain of five boxes spun to 430 rad/s, 2.1 rad a step,
/// h = 5 ms, landing on a vertex 0.4 m from the warm start's contact point; 38 unknowns):
/// every attempt from the warm start stalls at 7.5e-5 (the old vertex's hull weights), and the
/// solve from the warm start's contacts re-derived by the structure converges
/// (`NewtonSettings::structure_reseed`, `docs/stress.md`, wip-tip070).
#[test]
fn newton_union_tip_s20270320_070_step_97_structure_reseed() {
    let path = regression_scene("s20270320_070_union_tip");
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let settings = NewtonSettings {
        tolerance,
        ..NewtonSettings::default()
    };
    let without = NewtonSettings {
        structure_reseed: false,
        ..settings.clone()
    };
    let sim = at_default_step(&path, &mut NewtonSolver::new(settings.clone()), 97);
    let z0 = sim.z().to_vec();
    let before = sim.solve_step_problem(&mut NewtonSolver::new(without), &z0);
    assert!(
        matches!(before, Err(SolveError::NotConverged { .. })),
        "without the reseed: {:?}",
        before.map(|s| s.summary.iterations)
    );
    let after = converged(sim.solve_step_problem(&mut NewtonSolver::new(settings), &z0));
    println!(
        "s20270320_070_union_tip step 97: {} iterations with the structure reseed",
        after.summary.iterations
    );
    assert!(after.summary.residual <= tolerance);
    assert_eq!(
        after.summary.counter(Counter::Custom("structure_reseed")),
        Some(1),
        "{}",
        after.summary.counters
    );
}

/// The conic backend alone on `scene`'s step `step` after the default simulation up to it: without
/// the unanchored pass (`ConicSettings::unanchored_retry`) the step fails; with it the step takes
/// one unanchored pass and converges, as do the next five. Returns the step's record for the
/// caller's comparison with PATH's and Newton's step.
fn unanchored_pass_cures(scene: &str, step: usize) -> StepRecord {
    let path = regression_scene(scene);
    let tolerance = scene_tolerance(&path).unwrap_or(1e-10);
    let conic = |unanchored_retry| {
        ConicSolver::new(ConicSettings {
            tolerance,
            unanchored_retry,
            ..ConicSettings::default()
        })
    };
    let mut sim = at_default_step(&path, &mut conic(true), step);
    let without = sim
        .step(&mut conic(false))
        .unwrap_or_else(|e| panic!("{e}"));
    println!(
        "conic {scene} step {step} without the unanchored pass: converged {}, residual {:e}",
        without.converged, without.summary.residual
    );
    assert!(
        !without.converged && without.summary.residual > 10.0 * tolerance,
        "without the unanchored pass step {step} converged ({:e}): the test's premise is gone",
        without.summary.residual
    );
    let mut sim = at_default_step(&path, &mut conic(true), step);
    let mut solver = conic(true);
    let mut first = None;
    for k in step..=step + 5 {
        let rec = sim
            .step(&mut solver)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(
            rec.converged && rec.summary.residual <= tolerance,
            "step {k}: converged {}, residual {:e}",
            rec.converged,
            rec.summary.residual
        );
        if k == step {
            assert_eq!(
                rec.summary
                    .counters
                    .get(Counter::Custom("unanchored_passes")),
                Some(1)
            );
            first = Some(rec);
        }
    }
    first.unwrap_or_else(|| panic!("step {step} was not taken"))
}

/// `s20270327_137_corner_wall` step 33 (the held-out seed 20270327; a point set of μ = 0.9
/// sliding at 1.5 m/s into the wall, h = 3 ms) with the conic backend alone: a vertex jams in
/// the corner of floor and wall, and the floor's and the wall's loads go from 0.16 and 0.13 to
/// 97 and 102 N·s in one step. The load anchor lets a load move only a bounded amount per QP, so
/// the anchored fixed point walks for its 50 QPs (natural residual 1.4e-3 to 4.5e-3) and every
/// Newton finish ends at 3.3e-6: the step failed and, the state not advancing, so did every
/// later one (timeout). With the unanchored pass after the failed local finishes
/// (`ConicSettings::unanchored_retry`, `docs/stress.md`, wip-heldout5) the step converges in 14
/// more QPs to Newton's and PATH's step 33, and the next five steps converge too.
#[test]
fn conic_corner_wall_s20270327_137_step_33_unanchored_pass() {
    let rec = unanchored_pass_cures("s20270327_137_corner_wall", 33);
    // PATH's and Newton's step 33 (stress --seed 20270327 on main e674d7c, 4e-14 apart): the
    // state before the step differs from theirs by up to 2.6e-9 (measured: v 1e-10, the loads
    // 1.4e-7 apart).
    let v = rec.bodies[0].v;
    assert!((v.x - 0.237_007_884_770).abs() <= 1e-8, "v_x {}", v.x);
    assert!((v.z - 0.571_901_095_883).abs() <= 1e-8, "v_z {}", v.z);
}

/// `s20270410_048_v_trough` step 253 (the held-out seed 20270410; a box of μ = 0.28 sliding down
/// the 29.5° side of a V trough, h = 1 ms) with the conic backend alone: the box's edge lands on
/// the 43° side at step 252 and at step 253 it wedges into the crease (both contacts lines, the
/// far side's load 0.23 → 0.33 N·s, the spin about y 0.22 → 0.45 rad/s). The anchored fixed
/// point stalls at a natural residual of 2.1e-6 (its iterates cycling 4.2e-4 apart) for its 50
/// QPs and the Newton finishes end at 1.6e-9 (1 178 iterations): the step failed and, the state
/// not advancing, so did every later one (timeout after 384 of 750 steps). Without the anchors
/// the step takes 6 QPs; with the unanchored pass after the failed local finishes
/// (`ConicSettings::unanchored_retry`, wip-heldout5; `docs/stress.md`, wip-heldout6) it
/// converges to Newton's and PATH's step 253, and the next five steps converge too.
#[test]
fn conic_v_trough_s20270410_048_step_253_unanchored_pass() {
    let rec = unanchored_pass_cures("s20270410_048_v_trough", 253);
    // PATH's step 253 (stress --seed 20270410 on main e674d7c; Newton's within 3e-13): the conic
    // state before the step differs from PATH's by up to 2.4e-7 (the spin), measured here: v_x
    // 2.2e-10, v_z 8e-11, ω_y 3.6e-9 apart.
    let (v, w) = (rec.bodies[0].v, rec.bodies[0].w);
    assert!((v.x - 0.026_457_219_165).abs() <= 1e-8, "v_x {}", v.x);
    assert!((v.z - 0.010_590_152_983).abs() <= 1e-8, "v_z {}", v.z);
    assert!((w.y - 0.445_063_937_951).abs() <= 1e-7, "w_y {}", w.y);
}

/// `s20270403_087_v_trough` step 71 (the held-out seed 20270403; a box of 17.9 kg, μ = 0.24,
/// h = 6 ms, sliding along a trough of 25° and 49°; 49 unknowns) as the default simulation's
/// step solves it (extrapolated warm start, start budgets): the extrapolated start's budget is
/// `max(8, 3 recent)` = 8 and the plain iteration from it needs 9 (natural residual 2.2e-4 →
/// 1.2e-7 at the eighth, 1.5e-14 at the ninth). Cut at 8, the budgeted solve went on to its
/// Josephy–Newton attempt (56 Lemke runs, ≈ 16 000 pivots, 0.95 G instructions: 88 % of the
/// run) and the step took 47 iterations. With the grace of a converging budgeted run
/// (`NewtonSettings::budget_grace`, `docs/stress.md`, branch wip-v087) the first solve converges
/// in 9.
#[test]
fn newton_v_trough_s20270403_087_step_71_budget_grace() {
    let path = regression_scene("s20270403_087_v_trough");
    let file = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
    let settings = NewtonSettings {
        tolerance: file.solver.tolerance.unwrap_or(1e-10),
        max_iterations: file.solver.max_iterations.unwrap_or(200),
        ..NewtonSettings::default()
    };
    // The default simulation (extrapolated warm start, start budgets) through step 70, then
    // step 71 by `settings`.
    let step_71 = |step_settings: NewtonSettings| {
        let stepper = FormulationRegistry::builtin()
            .create("hull")
            .unwrap_or_else(|e| panic!("{e}"));
        let mut sim = SimulationBuilder::new(file.scene.clone(), stepper)
            .build()
            .unwrap_or_else(|e| panic!("{e}"));
        let mut driver = NewtonSolver::new(settings.clone());
        for k in 1..71 {
            let rec = sim
                .step(&mut driver)
                .unwrap_or_else(|e| panic!("step {k}: {e}"));
            assert!(rec.converged, "step {k} did not converge");
        }
        let rec = sim
            .step(&mut NewtonSolver::new(step_settings))
            .unwrap_or_else(|e| panic!("step 71: {e}"));
        assert!(rec.converged, "step 71 did not converge");
        rec.summary.iterations
    };
    let without = step_71(NewtonSettings {
        budget_grace: None,
        ..settings.clone()
    });
    let with = step_71(settings.clone());
    println!(
        "s20270403_087_v_trough step 71: {without} iterations without the grace, {with} with it"
    );
    assert!(without >= 30, "without the grace: {without} iterations");
    assert!(with <= 12, "with the grace: {with} iterations");
}
