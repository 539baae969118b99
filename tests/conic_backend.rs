//! The conic backend (`docs/backends.md#conic`) on the reference scenarios A1–A6 and the desk
//! (`docs/model.md#scenarios`), loaded from `scenes/`: every step converges to a natural residual ≤
//! 1e-8 (`docs/model.md#mcp`, computed by the model on the mapped-back vector), and the velocities
//! match the semismooth Newton backend's within 1e-6 at every step. The Anitescu relaxation is
//! labelled in its summary and measurably not the exact model (it drifts off the surface on A1),
//! and an MCP without the structural view is rejected.

mod common;

use common::scene;
use ecp::formulations::StepMethod;
use ecp::formulations::{Scene, Simulation, StepRecord};
use ecp::model::{Counter, FnMcp, Mcp, McpSolver, SolveError, Termination};
use ecp::solvers::conic::{ClarabelStatus, ConicMode, ConicSettings, ConicSolver, status_code};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

/// Residual every conic step must reach.
const RESIDUAL: f64 = 1e-8;
/// Largest velocity difference to the Newton backend, per step.
const DV: f64 = 1e-6;
/// Largest difference between a step without contact impulses and the free-motion velocity at
/// its end point (which depends on the end-of-step orientation and angular velocity,
/// `docs/energy.md`).
const FREE: f64 = 1e-12;

fn run(scene: Scene, solver: &mut dyn McpSolver) -> Vec<StepRecord> {
    let mut sim = Simulation::new(scene).expect("valid scene");
    let mut records = Vec::new();
    sim.run(solver, |rec| {
        records.push(rec.clone());
        true
    })
    .expect("simulation runs");
    records
}

/// Runs `name` with the conic backend and, at every step, solves the same step problem (same
/// start state and warm start) with the semismooth Newton backend; checks the conic residual
/// and the velocity difference, and returns the run's numbers.
/// Whenever the conic step has no contact impulse its velocities must also be the free flight
/// `ν_free` at its end point, to `FREE`.
fn check_against_newton(name: &str) {
    let mut sim = Simulation::new(scene(name)).expect("valid scene");
    let mut conic = ConicSolver::new(ConicSettings::default());
    let mut newton = NewtonSolver::new(NewtonSettings::default());
    let mut max_res: f64 = 0.0;
    let mut max_dv: f64 = 0.0;
    let mut max_free: f64 = 0.0;
    let mut outer = 0usize;
    let mut newton_failures = 0usize;
    let mut us: Vec<f64> = Vec::new();
    while !sim.finished() {
        sim.prepare_step().expect("prepare");
        let z0 = sim.z().to_vec();
        let (newton_nu, free) = {
            let view = sim.step_problem();
            let st = view.structure().expect("the ECP step's structure");
            // Newton from the plain warm start can fail where the stepper's own retry (from an
            // active-contact guess) would rescue it: then there is no reference for this step.
            let sol = newton.solve(&view, &z0).ok();
            // The free-motion velocity of the step's rows at the conic solution of the same
            // problem (the mass matrix and the gyroscopic impulse are those of the end of the
            // step, so it depends on the solution).
            let own = ConicSolver::new(ConicSettings::default())
                .solve(&view, &z0)
                .ok();
            let at = own.as_ref().map_or(z0.as_slice(), |s| s.z.as_slice());
            let free: Vec<[f64; 6]> = (0..st.num_bodies())
                .map(|b| st.body(b, at).free_velocity)
                .collect();
            (sol.map(|s| st.velocities(&s.z)), free)
        };
        let c = sim.step(&mut conic).expect("step");
        assert!(
            c.converged && c.summary.residual <= RESIDUAL,
            "{name}: conic step {} did not converge: {} residual {:.3e} worst {:?}",
            c.step,
            c.summary.termination,
            c.summary.residual,
            c.summary.worst
        );
        assert_eq!(c.summary.solver, "conic");
        assert_eq!(
            c.summary.counter(Counter::NewtonPolish).unwrap(),
            0,
            "{name}: step {} needed a Newton polish",
            c.step
        );
        let mut dv: f64 = 0.0;
        for (b, body) in c.bodies.iter().enumerate() {
            let nu = [body.v.x, body.v.y, body.v.z, body.w.x, body.w.y, body.w.z];
            if let Some(newton_nu) = &newton_nu {
                for i in 0..6 {
                    dv = dv.max((nu[i] - newton_nu[b][i]).abs());
                }
            }
            if c.contacts.iter().all(|k| k.pn == 0.0) {
                for i in 0..6 {
                    let off = (nu[i] - free[b][i]).abs();
                    max_free = max_free.max(off);
                    assert!(
                        off <= FREE,
                        "{name}: step {}: no contact impulse but not free flight ({off:.3e})",
                        c.step
                    );
                }
            }
        }
        assert!(
            dv <= DV,
            "{name}: step {}: conic and Newton velocities differ by {dv:.3e} (allowed {DV:.0e})",
            c.step
        );
        if newton_nu.is_none() {
            newton_failures += 1;
        }
        for contact in &c.contacts {
            assert!(
                contact.min_gap >= -1e-9,
                "{name}: step {} penetrates: {:.3e}",
                c.step,
                contact.min_gap
            );
        }
        max_res = max_res.max(c.summary.residual);
        max_dv = max_dv.max(dv);
        outer += c.summary.iterations;
        us.push(c.solve_us);
    }
    let steps = us.len();
    assert!(steps > 0);
    assert!(
        newton_failures * 20 <= steps,
        "{name}: Newton failed on {newton_failures} of {steps} steps: too few references"
    );
    us.sort_by(f64::total_cmp);
    println!(
        "{name}: {steps} steps, max residual {max_res:.2e}, max |dv| vs Newton {max_dv:.2e} \
         ({newton_failures} steps without a Newton reference), max |ν − ν_free| in free \
         flight {max_free:.2e}, \
         mean outer iterations {:.2}, median {:.0} us/step",
        outer as f64 / steps as f64,
        us[steps / 2]
    );
}

#[test]
fn a1_sliding() {
    check_against_newton("a1_sliding");
}

#[test]
fn a2_push_stick() {
    check_against_newton("a2_push_stick");
}

#[test]
fn a2_push_slide() {
    check_against_newton("a2_push_slide");
}

#[test]
fn a3_spin() {
    check_against_newton("a3_spin");
}

#[test]
fn a4_incline_10() {
    check_against_newton("a4_incline_10");
}

#[test]
fn a4_incline_25() {
    check_against_newton("a4_incline_25");
}

#[test]
fn a5_drop() {
    check_against_newton("a5_drop");
}

#[test]
fn a5_drop_tilted() {
    check_against_newton("a5_drop_tilted");
}

#[test]
fn a6_tip_90() {
    check_against_newton("a6_tip_90");
}

#[test]
fn a6_tip_110() {
    check_against_newton("a6_tip_110");
}

#[test]
fn desk() {
    check_against_newton("desk");
}

/// The desk as `ecp compare` runs it: two independent 400-step runs, velocities within 1e-6
/// at every step (the backend's acceptance criterion).
#[test]
fn desk_separate_runs_agree() {
    let conic = run(
        scene("desk"),
        &mut ConicSolver::new(ConicSettings::default()),
    );
    let newton = run(
        scene("desk"),
        &mut NewtonSolver::new(NewtonSettings::default()),
    );
    assert_eq!(conic.len(), 400);
    assert_eq!(newton.len(), 400);
    let mut max_dv: f64 = 0.0;
    for (c, n) in conic.iter().zip(&newton) {
        assert!(
            c.converged && c.summary.residual <= RESIDUAL,
            "step {}",
            c.step
        );
        assert!(n.converged, "Newton step {}", n.step);
        let dv = (c.bodies[0].v - n.bodies[0].v)
            .amax()
            .max((c.bodies[0].w - n.bodies[0].w).amax());
        assert!(dv <= DV, "desk step {}: |dv| = {dv:.3e}", c.step);
        max_dv = max_dv.max(dv);
    }
    println!("desk, separate runs: max |dv| conic vs Newton {max_dv:.2e}");
}

/// The first outer iteration's QP replaced by the previous step's impulses polished against its
/// data (`ConicSettings::warm_polish`, `docs/latency.md`, wip-conic): the desk's steps take no QP
/// once the first is solved (both outer iterations polish, `qp_reuses` 2), and every step is the
/// step computed with the QPs to 1e-12 (positions, velocities, ECP and loads; the polish settles
/// on the same linearised problem's answer from either start).
#[test]
fn desk_warm_polish_replaces_the_first_qp() {
    let warm = run(
        scene("desk"),
        &mut ConicSolver::new(ConicSettings::default()),
    );
    let cold = run(
        scene("desk"),
        &mut ConicSolver::new(ConicSettings {
            warm_polish: false,
            ..ConicSettings::default()
        }),
    );
    assert_eq!(warm.len(), 400);
    assert_eq!(cold.len(), 400);
    let qp_free = warm
        .iter()
        .filter(|r| r.summary.counter(Counter::Custom("dense_qp_iterations")) == Some(0))
        .count();
    assert!(qp_free >= 390, "{qp_free} of 400 desk steps without a QP");
    assert!(
        cold.iter()
            .all(|r| r.summary.counter(Counter::Custom("qp_reuses")) == Some(1)),
        "without the warm polish every desk step solves one QP and reuses its answer once"
    );
    let mut worst: f64 = 0.0;
    for (a, b) in warm.iter().zip(&cold) {
        assert!(
            a.converged && a.summary.residual <= RESIDUAL,
            "step {}",
            a.step
        );
        assert_eq!(
            a.summary.iterations, b.summary.iterations,
            "step {}",
            a.step
        );
        let (x, y) = (&a.bodies[0], &b.bodies[0]);
        let d = (x.x - y.x)
            .amax()
            .max((x.v - y.v).amax())
            .max((x.w - y.w).amax())
            .max((x.q - y.q).amax());
        worst = worst.max(d);
        for (c, e) in a.contacts.iter().zip(&b.contacts) {
            worst = worst.max((c.pn - e.pn).abs());
        }
    }
    assert!(
        worst <= 1e-12,
        "desk with and without the warm polish: {worst:.3e} apart"
    );
}

/// The fixed point alone (the default, `newton_handoff = 0`; no rescue) converges on every desk
/// step, and with the fixed point's iterate handed to a short Newton finish once its residual is
/// ≤ 1e-4 (`docs/latency.md#conic-backend`) the run reaches the same steps: velocities within 1e-8
/// at every step, at least one QP per step, the finish used on the steps in contact.
#[test]
fn desk_handoff_agrees_with_the_fixed_point_alone() {
    let alone = run(
        scene("desk"),
        &mut ConicSolver::new(ConicSettings::default()),
    );
    let handoff = run(
        scene("desk"),
        &mut ConicSolver::new(ConicSettings {
            newton_handoff: 1e-4,
            ..ConicSettings::default()
        }),
    );
    assert_eq!(alone.len(), 400);
    assert_eq!(handoff.len(), 400);
    let mut handed = 0;
    for (a, h) in alone.iter().zip(&handoff) {
        assert!(
            a.converged && a.summary.residual <= RESIDUAL,
            "step {}",
            a.step
        );
        assert_eq!(
            a.summary.counter(Counter::NewtonPolish),
            Some(0),
            "step {}",
            a.step
        );
        assert_eq!(
            a.summary.counter(Counter::NewtonHandoff),
            Some(0),
            "step {}",
            a.step
        );
        assert!(
            h.converged && h.summary.residual <= RESIDUAL,
            "step {}",
            h.step
        );
        assert_eq!(
            h.summary.counter(Counter::NewtonPolish),
            Some(0),
            "step {}",
            h.step
        );
        assert!(h.summary.iterations >= 1, "step {}: no QP", h.step);
        handed += usize::from(h.summary.counter(Counter::NewtonHandoff).unwrap_or(0) > 0);
        let dv = (a.bodies[0].v - h.bodies[0].v)
            .amax()
            .max((a.bodies[0].w - h.bodies[0].w).amax());
        assert!(dv <= 1e-8, "desk step {}: |dv| = {dv:.3e}", a.step);
    }
    assert!(handed > 0, "the handoff was never used");
}

/// Normal drift of A1 over the run: the largest |v_z| and the largest deviation of the CM
/// height from 0.1 m.
fn a1_drift(mode: ConicMode) -> (f64, f64, Vec<StepRecord>) {
    let settings = ConicSettings {
        mode,
        ..ConicSettings::default()
    };
    let mut solver = ConicSolver::new(settings);
    let recs = if mode == ConicMode::AnitescuRelaxation {
        // The relaxation's points do not solve the exact step problem; a plain step would hold
        // the state over them, so take them unchecked to see where the relaxed model goes.
        let mut sim = Simulation::new(scene("a1_sliding")).expect("valid scene");
        (0..sim.scene().num_steps())
            .map(|_| sim.step_unchecked(&mut solver).expect("step"))
            .collect()
    } else {
        run(scene("a1_sliding"), &mut solver)
    };
    let vz = recs
        .iter()
        .map(|r| r.bodies[0].v.z.abs())
        .fold(0.0, f64::max);
    let dz = recs
        .iter()
        .map(|r| (r.bodies[0].x.z - 0.1).abs())
        .fold(0.0, f64::max);
    (vz, dz, recs)
}

#[test]
fn anitescu_relaxation_is_labelled_and_drifts() {
    let (vz, dz, recs) = a1_drift(ConicMode::AnitescuRelaxation);
    for r in &recs {
        assert_eq!(r.summary.solver, "conic-anitescu");
        assert_eq!(r.summary.counter(Counter::AnitescuRelaxation), Some(1));
        assert_eq!(r.summary.iterations, 1, "single shot");
    }
    // Sliding at 1 m/s with μ = 0.3, the relaxed cone lets the box leave the ground with
    // v_z = μ‖u_T‖ ≈ 0.3 m/s in the first step.
    assert!(vz > 0.1, "relaxation drift v_z = {vz:.3e}");
    assert!(dz > 1e-3, "relaxation CM height drift = {dz:.3e}");
    // It is not a solution of the exact step MCP, and says so.
    assert!(recs[0].summary.residual > RESIDUAL);
    assert!(!recs[0].converged);
    assert_eq!(recs[0].method, StepMethod::Unchecked);
    assert_eq!(recs[0].summary.termination, Termination::MaxIterations);
    println!("A1 Anitescu relaxation: max |v_z| {vz:.4e} m/s, max |z − 0.1| {dz:.4e} m");
}

#[test]
fn exact_mode_does_not_drift() {
    let (vz, dz, recs) = a1_drift(ConicMode::Exact);
    assert!(vz <= 1e-8, "exact mode v_z = {vz:.3e}");
    assert!(dz <= 1e-8, "exact mode CM height drift = {dz:.3e}");
    for r in &recs {
        assert_eq!(r.summary.counter(Counter::AnitescuRelaxation), Some(0));
    }
    println!("A1 exact: max |v_z| {vz:.4e} m/s, max |z − 0.1| {dz:.4e} m");
}

#[test]
fn generic_mcp_is_rejected() {
    let mcp = FnMcp::dense(
        vec![0.0],
        vec![f64::INFINITY],
        |z, f| f[0] = z[0] - 1.0,
        |_z, j| j[0] = 1.0,
    )
    .expect("valid");
    let mut solver = ConicSolver::new(ConicSettings::default());
    match solver.solve(&mcp, &[0.0]) {
        Err(SolveError::InvalidProblem(msg)) => assert!(msg.contains("structur"), "{msg}"),
        other => panic!("expected InvalidProblem, got {other:?}"),
    }
    // The bare BlockMcp of a simulation has no structural view either; the structured one does.
    let mut sim = Simulation::new(scene("a1_sliding")).expect("valid");
    sim.prepare_step().expect("prepare");
    assert!(matches!(
        solver.solve(sim.mcp(), sim.z()),
        Err(SolveError::InvalidProblem(_))
    ));
    let sol = solver
        .solve(&sim.step_problem(), sim.z())
        .expect("structured step solves");
    assert_eq!(sol.summary.termination, Termination::Converged);
}

/// clarabel's own status passes through a failed subproblem: one interior-point iteration is
/// not enough for the first QP of A1.
#[test]
fn clarabel_status_passes_through() {
    let mut settings = ConicSettings::default();
    settings.clarabel.max_iter = 1;
    let mut solver = ConicSolver::new(settings);
    let mut sim = Simulation::new(scene("a1_sliding")).expect("valid");
    sim.prepare_step().expect("prepare");
    let z0 = sim.z().to_vec();
    match solver.solve(&sim.step_problem(), &z0) {
        Err(SolveError::NotConverged { best }) => {
            assert_eq!(best.summary.termination, Termination::SubproblemFailed);
            assert_eq!(
                best.summary.counter(Counter::ClarabelStatus).unwrap(),
                status_code(ClarabelStatus::MaxIterations)
            );
            assert_eq!(best.z, z0, "the best point is the start");
            assert!(best.z.iter().all(|v| v.is_finite()));
        }
        other => panic!("expected a subproblem failure, got {other:?}"),
    }
    assert_eq!(
        solver.last_clarabel_status(),
        Some(ClarabelStatus::MaxIterations)
    );
    let msg = solver.last_subproblem_error().expect("a reason");
    assert!(msg.contains("MaxIterations"), "{msg}");
}

/// `tests/stress_regressions/NAME.toml` stepped as the stress suite steps it (hull formulation,
/// the scene's tolerance and iteration limit, the default warm start, the conic backend as the
/// registry builds it, no fallbacks) through step `last`: every step's record.
fn regression_steps(name: &str, last: usize) -> Vec<StepRecord> {
    regression_steps_with(name, last, |_| {})
}

/// [`regression_steps`] with the registry's conic settings changed by `change`.
fn regression_steps_with(
    name: &str,
    last: usize,
    change: impl FnOnce(&mut ConicSettings),
) -> Vec<StepRecord> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/stress_regressions")
        .join(format!("{name}.toml"));
    let file = ecp::scene::load_scene(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    let stepper = ecp::formulations::FormulationRegistry::builtin()
        .create("hull")
        .unwrap_or_else(|e| panic!("{e}"));
    let mut sim = ecp::formulations::SimulationBuilder::new(file.scene.clone(), stepper)
        .build()
        .unwrap_or_else(|e| panic!("{e}"));
    let options = ecp::solvers::registry::BackendOptions {
        tolerance: file.solver.tolerance,
        max_iterations: file.solver.max_iterations,
        non_isolated_solutions: false,
    };
    let mut settings = ecp::solvers::registry::conic_settings(&options);
    change(&mut settings);
    let mut conic = ConicSolver::new(settings);
    (1..=last)
        .map(|k| {
            sim.step(&mut conic)
                .unwrap_or_else(|e| panic!("step {k}: {e}"))
        })
        .collect()
}

/// Every step in `records` converged (a failed step names itself).
fn assert_every_step_converged(name: &str, records: &[StepRecord]) {
    for r in records {
        assert!(
            r.converged,
            "{name} step {}: not converged, residual {:e}, {} outer iterations, {}",
            r.step, r.summary.residual, r.summary.iterations, r.summary.counters
        );
    }
}

/// `s20261201_061_v_trough` (held-out seed 20261201), step 68: a point set on one vertex in the
/// crease of a V trough; one support's load must walk from 0.30 to 0 N·s under the load anchor
/// while the residual stays at 2.2e-5, and the stagnation window stopped the fixed point at 22
/// QPs (the Newton polish then stopped at 1.4e-7; every later step failed the same way). With
/// the drift of the anchored loads counted as progress (`docs/latency.md`, wip-conicheld) the
/// fixed point itself converges (29 QPs measured), without the Newton polish, and so do the
/// steps after it. The drift alone, without the early local finish (`ConicSettings::
/// early_finish_after`), which finishes step 68 by Newton after its third stalled QP.
#[test]
fn held_out_v_trough_061_load_drift_is_progress() {
    let name = "s20261201_061_v_trough";
    let records = regression_steps_with(name, 72, |s| s.early_finish_after = 0);
    assert_every_step_converged(name, &records);
    let step = &records[67];
    assert_eq!(step.step, 68);
    assert_eq!(step.summary.counters.get(Counter::NewtonPolish), Some(0));
    assert!(
        (23..=50).contains(&step.summary.iterations),
        "{} outer iterations",
        step.summary.iterations
    );
}

/// `s20261219_056_union_slide` (held-out seed 20261219), steps 2–10: a table sliding and
/// spinning on one leg's edge. The fixed point stalls at a point of residual 1e-2 that is not the
/// step's solution (a friction row) and ran the stagnation window out (21–39 QPs); the Newton
/// polish from its best iterate then spent 500–650 iterations and failed, and the one from the
/// warm start converged in 4–6 (about 15 ms a step, 123× PATH's run). With the early local
/// finish after 3 stalled QPs and the local finishes tried from both starts before the
/// safeguarded ones (`docs/latency.md`, wip-conicslow2) each step takes 4 QPs and about 35 Newton
/// iterations (measured), and converges.
#[test]
fn held_out_union_slide_056_early_local_finish() {
    let name = "s20261219_056_union_slide";
    let records = regression_steps(name, 10);
    assert_every_step_converged(name, &records);
    for r in &records[1..] {
        let polish = r.summary.counters.get(Counter::NewtonPolish).unwrap_or(0);
        assert!(
            r.summary.iterations <= 6 && polish <= 60,
            "step {}: {} outer iterations, {} Newton polish iterations",
            r.step,
            r.summary.iterations,
            polish
        );
    }
}

/// `s20261226_061_v_trough` (held-out seed 20261226), steps 54–61: a point set in a V trough,
/// a vertex loaded by both sides. After 1–2 QPs the residual sits at about 1.2e-5 while the
/// anchored loads walk on in one direction (`loads_drifting`), so the stagnation window never
/// ends the fixed point: before the walk finish each of these steps took the 50-QP limit (step
/// 56: 41) and then a Newton finish of 24–102 iterations from the best iterate (measured with
/// `walk_finish_after = 0`, `docs/latency.md`, wip-conic061). With the local finish after 5
/// walking QPs, from the warm start first, each converges in 6–8 QPs and 4–10 Newton iterations
/// (measured); the bounds leave a margin and stay far below the old 50 QPs.
#[test]
fn held_out_v_trough_061_s20261226_walk_finish() {
    let name = "s20261226_061_v_trough";
    let records = regression_steps(name, 61);
    assert_every_step_converged(name, &records);
    for r in &records[53..] {
        let polish = r.summary.counters.get(Counter::NewtonPolish).unwrap_or(0);
        assert!(
            r.summary.iterations <= 10 && polish <= 20,
            "step {}: {} outer iterations, {} Newton polish iterations",
            r.step,
            r.summary.iterations,
            polish
        );
    }
}

/// `s20270116_056_union_slide` (held-out seed 20270116): a table (a union of a top and four
/// legs) sliding and spinning on the floor, one contact with its four legs loaded. From step 109
/// the polish's Gauss–Seidel sweeps (the legs' normal correction, then the friction at their
/// moving centre of pressure) turn in a rotating pair of modes (4–5 sweeps a turn, shrinking by
/// 0.95 or growing by up to 1.07 per sweep) that Aitken's one-mode extrapolation does not fit
/// and the joint step refuses (four loaded vertices), so each polish stopped unsettled at 50
/// sweeps and steps 109–382 took 3–15 QPs and up to 23 Newton iterations (measured before). The
/// two-mode extrapolation settles them: every step that takes a QP takes 2 (measured), no
/// Newton finish.
#[test]
fn held_out_union_slide_056_two_mode_polish() {
    let name = "s20270116_056_union_slide";
    let records = regression_steps(name, 400);
    assert_every_step_converged(name, &records);
    for r in &records[108..382] {
        let polish = r.summary.counters.get(Counter::NewtonPolish).unwrap_or(0);
        assert!(
            r.summary.iterations <= 2 && polish == 0,
            "step {}: {} outer iterations, {} Newton polish iterations",
            r.step,
            r.summary.iterations,
            polish
        );
    }
}

/// `s20270206_134_union_slide` (held-out seed 20270206): a table (a union of a top and four
/// legs) sliding and spinning on the floor. From step 426 its translation has slowed so that it
/// spins about a point near its centre of pressure: the friction's direction at the centre of
/// pressure turns with that point, which the friction's moment moves, and the polish's sweeps
/// circle with period 5 without settling (50 sweeps each); the fixed point's QPs circle too, and
/// steps 426–600 took 4–15 QPs and a Newton finish each (measured on main 39f29d5). Since the
/// finish after an unsettled polish (from the warm start first, `docs/latency.md`,
/// wip-conic134) 174 of those 175 steps take one QP (measured; the other 4): asserted at least
/// 170, and every step converges.
#[test]
fn held_out_union_slide_134_finish_after_an_unsettled_polish() {
    let name = "s20270206_134_union_slide";
    let records = regression_steps(name, 600);
    assert_every_step_converged(name, &records);
    let quick = records[425..600]
        .iter()
        .filter(|r| r.summary.iterations <= 2)
        .count();
    assert!(
        quick >= 170,
        "steps 426-600: {quick} of 175 in at most 2 QPs (measured 174; before 0)"
    );
}

/// `s20270206_134_union_slide` again, steps 601–1000: where a polish circles and the finish
/// follows, its sweeps stop once they circle (`conic::step`'s circling test) instead of running
/// to their cap of 50, and the finish starts from a point nearer its start (wip-conicrob,
/// `docs/latency.md`): 552 QPs over those 400 steps (main d1e6447: 927), every step converged.
#[test]
fn held_out_union_slide_134_circling_sweeps_stop() {
    let name = "s20270206_134_union_slide";
    let records = regression_steps(name, 1000);
    assert_every_step_converged(name, &records);
    let qps: usize = records[600..1000]
        .iter()
        .map(|r| r.summary.iterations)
        .sum();
    assert!(
        qps <= 700,
        "steps 601-1000: {qps} QPs (measured 552; main 927)"
    );
}

/// `s20261212_061_v_trough` (held-out seed 20261212): a point set in the crease of a V trough
/// (μ = 1.17), one vertex loaded by both sides, one side sticking, the other spinning. The other
/// side's gap row is a combination of the sticking side's rows, so the polish's joint step has a
/// singular Jacobian and is refused; the sweeps walk along the null direction to their cap at
/// every polish, the fixed point stalls at 1.6e-8 to 4e-7 (a gap row), and from step 20 every
/// step failed (the Newton polishes stopped at 4.7e-10; `docs/latency.md`, wip-conicslow). With
/// the early local finish (wip-conicslow2) the stalled QPs end in a Newton finish after 3 QPs and
/// the run takes another path, on which every step converges (the whole stress run: 0 failed
/// steps of 375, 716 QPs; before: a timeout after 173 steps, 154 failed).
#[test]
fn held_out_v_trough_061_s20261212_crease_vertex() {
    let name = "s20261212_061_v_trough";
    let records = regression_steps(name, 25);
    assert_every_step_converged(name, &records);
}

/// `s20261201_153_room_corner` (held-out seed 20261201), step 186: an arch spinning flat on the
/// floor on four coplanar vertices. The QPs tip it onto two or three of them and the fixed point
/// cycles (residuals 1.4e-3–7.4e-3); the Newton polish from its best iterate stops at 4.9e-6,
/// from the warm start (the face contact kept) it converges in 3 iterations. Steps 180–190 all
/// converge (before: every step from 186 failed).
#[test]
fn held_out_room_corner_153_polish_from_the_warm_start() {
    let name = "s20261201_153_room_corner";
    let records = regression_steps(name, 190);
    assert_every_step_converged(name, &records);
    // The cycle is at `records[186]` (step 187: 5 QPs, 23 Newton iterations) on main 99efdb4
    // already (`conic_step_costs --steps 190 --all`; step 186 takes 2 QPs); this assertion read
    // `records[185]` and failed on main too (wip-conic10x).
    assert!(
        records[186]
            .summary
            .counters
            .get(Counter::NewtonPolish)
            .is_some_and(|n| n > 0)
    );
}
