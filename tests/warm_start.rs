//! The warm start of a step (`Simulation::set_warm_start`,
//! `docs/latency.md#the-extrapolated-warm-start-on-by-default-branch-wip-warmon-issue-18`):
//! `Previous` is main's before the extrapolation, bit for bit; `Extrapolated`, the default, takes
//! fewer Newton iterations on the desk and ends where `Previous` ends, solves an extrapolated
//! start within an iteration budget and, when that fails, again from the plain warm start;
//! PATH, polished by default, extrapolates too, and without its polish keeps `Previous`'s steps.

use ecp::formulations::{BodyState, Simulation, StepRecord, WarmStart, scenarios};
use ecp::model::{Counter, Mcp, McpSolver, Solution, SolveError};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};

/// The desk's first `steps` steps with `solver`: every record (each step must converge).
fn desk_records(
    warm_start: Option<WarmStart>,
    solver: &mut dyn McpSolver,
    steps: usize,
) -> Vec<StepRecord> {
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    if let Some(w) = warm_start {
        sim.set_warm_start(w);
    }
    (1..=steps)
        .map(|k| {
            let rec = sim.step(solver).unwrap_or_else(|e| panic!("step {k}: {e}"));
            assert!(rec.converged, "step {k} did not converge");
            rec
        })
        .collect()
}

/// The desk's first `steps` steps with Newton: total iterations and the final states.
fn desk_run(warm_start: Option<WarmStart>, steps: usize) -> (usize, Vec<[f64; 13]>) {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let records = desk_records(warm_start, &mut solver, steps);
    let iterations = records.iter().map(|r| r.summary.iterations).sum();
    let last = records.last().expect("at least one step");
    (iterations, states(&last.bodies))
}

/// Position, orientation, velocity and angular velocity of each body.
fn states(bodies: &[BodyState]) -> Vec<[f64; 13]> {
    bodies
        .iter()
        .map(|s| {
            let mut v = [0.0; 13];
            v[..3].copy_from_slice(s.x.as_slice());
            v[3..7].copy_from_slice(s.q.as_slice());
            v[7..10].copy_from_slice(s.v.as_slice());
            v[10..].copy_from_slice(s.w.as_slice());
            v
        })
        .collect()
}

/// FNV-1a over the bits of every number of the records (states, contacts, residual,
/// iterations), as `examples/step_latency.rs desk-steps` computes it.
fn digest(records: &[StepRecord]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut mix = |bits: u64| {
        for b in bits.to_le_bytes() {
            h = (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for rec in records {
        for b in &rec.bodies {
            for v in b.x.iter().chain(&b.q).chain(&b.v).chain(&b.w) {
                mix(v.to_bits());
            }
        }
        for c in &rec.contacts {
            for v in c.a1.iter().chain(&c.a2) {
                mix(v.to_bits());
            }
            for v in [c.lg, c.pn, c.pt, c.po, c.pr, c.sigma, c.min_gap] {
                mix(v.to_bits());
            }
        }
        mix(rec.summary.residual.to_bits());
        mix(rec.summary.iterations as u64);
    }
    h
}

#[test]
fn previous_warm_start_is_the_plain_warm_start_bit_for_bit() {
    // The digest of main's (`4742ec5`) default, the plain warm start: `step_latency desk-steps
    // 400` there, with Newton's iteration of then (no chord steps, which move the iterates by
    // round-off: `docs/latency.md`, "Chord steps").
    let mut solver = NewtonSolver::new(NewtonSettings {
        chord_contraction: None,
        ..NewtonSettings::default()
    });
    let records = desk_records(Some(WarmStart::Previous), &mut solver, 400);
    assert_eq!(digest(&records), 0x32c9_b2ab_5ff7_3057);
    // With the default's chord steps, their polish always taken: `step_latency
    // desk-steps-previous 400` on wip-chord.
    let mut solver = NewtonSolver::new(NewtonSettings {
        chord_round_off_floor: None,
        ..NewtonSettings::default()
    });
    let records = desk_records(Some(WarmStart::Previous), &mut solver, 400);
    assert_eq!(digest(&records), 0x8f68_6621_54ea_b684);
    // The default (the chord steps' round-off floor, which moves the end points by round-off):
    // `step_latency desk-steps-previous 400` on wip-lukeep.
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let records = desk_records(Some(WarmStart::Previous), &mut solver, 400);
    assert_eq!(digest(&records), 0xe1af_b0f8_efa2_b565);
}

#[test]
fn extrapolated_warm_start_is_the_default_and_saves_desk_iterations() {
    const STEPS: usize = 60;
    let sim = Simulation::new(scenarios::desk()).expect("desk scene");
    assert_eq!(sim.warm_start(), WarmStart::Extrapolated);
    let (default_its, default_states) = desk_run(None, STEPS);
    let (extrapolated_its, extrapolated_states) = desk_run(Some(WarmStart::Extrapolated), STEPS);
    assert_eq!(default_its, extrapolated_its);
    assert_eq!(default_states, extrapolated_states);
    let (plain_its, plain_states) = desk_run(Some(WarmStart::Previous), STEPS);
    // Measured: 3.0 → 2.0 mean iterations over 400 steps (warm_probe); demand a 20 % cut.
    assert!(
        (extrapolated_its as f64) < 0.8 * plain_its as f64,
        "{extrapolated_its} iterations extrapolated, {plain_its} plain"
    );
    for (a, b) in extrapolated_states.iter().zip(&plain_states) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-12, "state {x} vs {y}");
        }
    }
}

#[test]
fn path_polished_by_default_extrapolates_and_ends_where_the_plain_start_ends() {
    // PATH's polish (`PathSettings::polish_below`, on by default) ends each converged attempt
    // with full Newton steps, so the driver extrapolates its warm starts: fewer iterations on the
    // desk (measured 3 → 2 per step), every state within 1e-12 of the plain warm start's.
    const STEPS: usize = 60;
    let mut path = PathSolver::new(PathSettings::default());
    assert!(path.converges_to_round_off());
    let default = desk_records(None, &mut path, STEPS);
    let mut path = PathSolver::new(PathSettings::default());
    let previous = desk_records(Some(WarmStart::Previous), &mut path, STEPS);
    let its = |r: &[StepRecord]| r.iter().map(|r| r.summary.iterations).sum::<usize>();
    assert!(
        (its(&default) as f64) < 0.8 * its(&previous) as f64,
        "{} iterations extrapolated, {} plain",
        its(&default),
        its(&previous)
    );
    for (a, b) in default.iter().zip(&previous) {
        for (x, y) in states(&a.bodies)
            .iter()
            .flatten()
            .zip(states(&b.bodies).iter().flatten())
        {
            assert!((x - y).abs() <= 1e-12, "step {}: {x} vs {y}", a.step);
        }
    }
}

#[test]
fn path_without_the_polish_keeps_the_plain_warm_starts() {
    // Without the polish PATH stops anywhere within its tolerance, so an extrapolated start
    // would move its results (by up to 3.3e-9): the driver extrapolates only for a backend that
    // converges to round-off, and the default's steps are `Previous`'s bit for bit.
    const STEPS: usize = 60;
    let unpolished = || {
        PathSolver::new(PathSettings {
            polish_below: 1.0,
            ..PathSettings::default()
        })
    };
    let mut path = unpolished();
    assert!(!path.converges_to_round_off());
    let default = desk_records(None, &mut path, STEPS);
    let mut path = unpolished();
    let previous = desk_records(Some(WarmStart::Previous), &mut path, STEPS);
    assert_eq!(digest(&default), digest(&previous));
}

/// Newton whose budgeted solves ([`McpSolver::set_iteration_budget`]) are cut after one
/// iteration, so that every extrapolated attempt on the desk (two iterations) fails; it logs the
/// budget asked for and the iterations of every solve.
struct OneIterationBudget {
    newton: NewtonSolver,
    budget: Option<usize>,
    /// `(budget, iterations)` of each solve.
    log: Vec<(Option<usize>, usize)>,
}

impl McpSolver for OneIterationBudget {
    fn name(&self) -> &str {
        "newton"
    }
    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let result = self.newton.solve(mcp, z0);
        let iterations = match &result {
            Ok(sol) => sol.summary.iterations,
            Err(SolveError::NotConverged { best }) => best.summary.iterations,
            Err(SolveError::InvalidProblem(_)) => 0,
        };
        self.log.push((self.budget, iterations));
        result
    }
    fn set_iteration_budget(&mut self, budget: Option<usize>) -> bool {
        self.budget = budget;
        self.newton.set_iteration_budget(budget.map(|_| 1))
    }
    fn converges_to_round_off(&self) -> bool {
        true
    }
}

/// Newton's defaults with budgets that cap the iterations exactly: without the Josephy–Newton
/// attempt after a failed budgeted run (`NewtonSettings::josephy_newton`, on by default, which adds
/// up to its steps and one more budgeted run) and the grace of a converging run
/// (`NewtonSettings::budget_grace`), so that the driver's protocol and the budget's
/// contract are tested as such.
fn strict_budget() -> NewtonSettings {
    NewtonSettings {
        josephy_newton: None,
        budget_grace: None,
        ..NewtonSettings::default()
    }
}

#[test]
fn a_missed_extrapolation_is_solved_again_from_the_plain_warm_start_and_counted() {
    const STEPS: usize = 40;
    let mut solver = OneIterationBudget {
        newton: NewtonSolver::new(strict_budget()),
        budget: None,
        log: Vec::new(),
    };
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    // The extrapolated attempt's protocol alone: without the start budgets, which would also
    // cut every other start at this wrapper's one iteration
    // (`docs/latency.md#budgeted-starts-newtons-long-steps-branch-wip-hardsteps-issue-18`).
    sim.set_start_budget(None);
    let (mut restarted, mut plain_its) = (0, 0);
    // The iterations of the smooth steps since the last restart (the driver's history).
    let mut recent: Vec<usize> = Vec::new();
    for k in 1..=STEPS {
        let before = solver.log.len();
        let rec = sim
            .step(&mut solver)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(rec.converged, "step {k} did not converge");
        let solves = &solver.log[before..];
        let retries = rec.summary.counter(Counter::Retries).unwrap_or(0);
        match solves {
            // Budgeted from the extrapolated start and cut (one iteration in each system of
            // units), then solved from the plain warm start with the full limits.
            [(Some(budget), cut), (None, plain)] => {
                // max(8, 3 × the most iterations of the last (up to three) smooth steps).
                let last3 = &recent[recent.len().saturating_sub(3)..];
                let expected = (3 * last3.iter().max().copied().unwrap_or(0)).max(8);
                assert_eq!(*budget, expected, "step {k}, recent {recent:?}");
                assert!((1..=2).contains(cut), "step {k}: {cut}");
                assert_eq!(retries, 1, "step {k}");
                // Both attempts counted.
                assert_eq!(rec.summary.iterations, cut + plain, "step {k}");
                restarted += 1;
                recent.clear();
            }
            [(None, its)] => {
                assert_eq!(retries, 0, "step {k}");
                assert_eq!(rec.summary.iterations, *its, "step {k}");
                plain_its += its;
                if (1..=5).contains(its) {
                    recent.push(*its);
                } else {
                    recent.clear();
                }
            }
            other => panic!("step {k}: solves {other:?}"),
        }
    }
    // After a restart the history starts again: two plain steps, then an extrapolated attempt.
    assert!(restarted >= 8, "{restarted} restarts in {STEPS} steps");
    assert!(plain_its > 0);
    // The restarts end where the plain warm start ends.
    let (_, plain_states) = desk_run(Some(WarmStart::Previous), STEPS);
    for (a, b) in states(sim.states()).iter().zip(&plain_states) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-12, "state {x} vs {y}");
        }
    }
}

#[test]
fn newton_and_path_honour_an_iteration_budget() {
    // The desk's step 100 from its plain warm start: Newton and PATH take 3 iterations.
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    sim.set_warm_start(WarmStart::Previous);
    let mut newton = NewtonSolver::new(NewtonSettings::default());
    for k in 1..100 {
        let rec = sim
            .step(&mut newton)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(rec.converged, "step {k}");
    }
    sim.prepare_step().expect("step 100");
    let z0 = sim.z().to_vec();
    let backends: Vec<Box<dyn McpSolver>> = vec![
        Box::new(NewtonSolver::new(strict_budget())),
        Box::new(PathSolver::new(PathSettings::default())),
    ];
    for mut solver in backends {
        let name = solver.name().to_string();
        let full = sim
            .solve_step_problem(solver.as_mut(), &z0)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(full.summary.iterations >= 2, "{name}");
        assert!(solver.set_iteration_budget(Some(1)), "{name}");
        match sim.solve_step_problem(solver.as_mut(), &z0) {
            // One iteration in each system of units at most.
            Err(SolveError::NotConverged { best }) => {
                assert!(
                    best.summary.iterations <= 2,
                    "{name}: {}",
                    best.summary.iterations
                )
            }
            other => panic!("{name}: {other:?}"),
        }
        // Within a budget it does not reach, the same point and iterations, bit for bit.
        solver.set_iteration_budget(Some(full.summary.iterations + 5));
        let within = sim
            .solve_step_problem(solver.as_mut(), &z0)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(within.z, full.z, "{name}");
        assert_eq!(within.summary.iterations, full.summary.iterations, "{name}");
        solver.set_iteration_budget(None);
        let again = sim
            .solve_step_problem(solver.as_mut(), &z0)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(again.z, full.z, "{name}");
    }
    // With the Josephy–Newton attempt (the default) a failed budgeted run is followed by its
    // steps and one more budgeted run, each attempt within the budget: here one iteration each,
    // which does not solve the step (one iteration in each system of units at most, per attempt).
    // Without the grace of a converging run, which would finish it (below).
    let mut newton = NewtonSolver::new(NewtonSettings {
        budget_grace: None,
        ..NewtonSettings::default()
    });
    assert!(newton.set_iteration_budget(Some(1)));
    match sim.solve_step_problem(&mut newton, &z0) {
        Err(SolveError::NotConverged { best }) => {
            assert!(best.summary.iterations <= 6, "{}", best.summary.iterations)
        }
        other => panic!("newton with the Josephy-Newton attempt: {other:?}"),
    }
    // With the defaults (`NewtonSettings::budget_grace`): the run that its one iteration leaves
    // converging at Newton's rate goes on, the unbudgeted run to the bit (fresh solvers: no
    // LU kept from an earlier solve).
    let full = sim
        .solve_step_problem(&mut NewtonSolver::new(NewtonSettings::default()), &z0)
        .unwrap_or_else(|e| panic!("newton: {e}"));
    let mut newton = NewtonSolver::new(NewtonSettings::default());
    assert!(newton.set_iteration_budget(Some(1)));
    let graced = sim
        .solve_step_problem(&mut newton, &z0)
        .unwrap_or_else(|e| panic!("newton with the grace: {e}"));
    assert_eq!(graced.z, full.z);
    assert_eq!(graced.summary.iterations, full.summary.iterations);
    // A backend that does not honour budgets says so.
    let mut conic =
        ecp::solvers::conic::ConicSolver::new(ecp::solvers::conic::ConicSettings::default());
    assert!(!conic.set_iteration_budget(Some(1)));
    assert!(!conic.converges_to_round_off());
}

/// The start budgets (`docs/latency.md#budgeted-starts-newtons-long-steps-branch-wip-hardsteps-issue-18`): the
/// first step's warm start is first solved within the start budget (20), and, cut short of it
/// (this wrapper's one iteration in each system of units), solved again at once with the full
/// limits from the same start, both attempts counted, as one retry.
#[test]
fn a_start_cut_short_of_its_budget_is_solved_again_with_the_full_limits() {
    let mut solver = OneIterationBudget {
        newton: NewtonSolver::new(strict_budget()),
        budget: None,
        log: Vec::new(),
    };
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    let rec = sim.step(&mut solver).expect("step 1");
    assert!(rec.converged);
    match solver.log[..] {
        [(Some(20), cut), (None, full)] => {
            assert!((1..=2).contains(&cut), "{cut}");
            assert_eq!(rec.summary.iterations, cut + full);
            assert_eq!(rec.summary.counter(Counter::Retries), Some(1));
        }
        ref other => panic!("solves {other:?}"),
    }
}

/// The guard's `F` at the warm start it chose is handed to the backend (`Mcp::known_value`,
/// `docs/latency.md#the-a1-step-under-2-µs-the-guards-f-handed-over-branch-wip-a1two-issue-18`),
/// and `Φ` there (`Mcp::known_fb_vector`, branch wip-newtonbook): on A1's step 4 (a
/// quadratically extrapolated start, at round-off) they are `F` and `fb_vector` of it bit for
/// bit; a start one ulp away, or the step problem after a parameter is set, gets neither.
#[test]
fn the_guards_f_at_the_warm_start_is_handed_over_for_that_start_only() {
    let mut sim = Simulation::new(scenarios::a1_sliding()).expect("A1 scene");
    let mut newton = NewtonSolver::new(NewtonSettings::default());
    for k in 1..=3 {
        let rec = sim
            .step(&mut newton)
            .unwrap_or_else(|e| panic!("step {k}: {e}"));
        assert!(rec.converged, "step {k} did not converge");
    }
    sim.prepare_step().expect("step 4 prepared");
    let z0 = sim.z().to_vec();
    let mut f = vec![0.0; z0.len()];
    sim.mcp().evaluate(&z0, &mut f);
    let problem = sim.step_problem();
    let known = problem
        .known_value(&z0)
        .expect("F at the extrapolated start");
    assert_eq!(
        known.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        f.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    let mut phi = vec![f64::NAN; z0.len()];
    ecp::model::fb_vector(&z0, &f, sim.mcp().lower(), sim.mcp().upper(), &mut phi);
    let known_phi = problem
        .known_fb_vector(&z0)
        .expect("Φ at the extrapolated start");
    assert_eq!(
        known_phi.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        phi.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
    // The extrapolated start solves A1's step 4 to round-off (its motion is quadratic).
    let residual = ecp::model::natural_residual(&z0, &f, sim.mcp().lower(), sim.mcp().upper());
    assert!(residual < 1e-13, "{residual:e}");
    let mut moved = z0.clone();
    moved[0] = f64::from_bits(moved[0].to_bits() + 1);
    assert!(problem.known_value(&moved).is_none());
    assert!(problem.known_fb_vector(&moved).is_none());
    sim.set_param(ecp::formulations::Param::Mu, 0.3)
        .expect("μ set");
    assert!(sim.step_problem().known_value(&z0).is_none());
    assert!(sim.step_problem().known_fb_vector(&z0).is_none());
}

/// [`WarmStart::Quadratic`] (at most three smooth steps handed over) is the default of before the
/// extrapolation's orders up to 5 bit for bit (`step_latency desk-steps 400` on `7d1cb73`:
/// `28e77963fba1fc23`); the default takes fewer Newton iterations on the desk (120 steps: 190
/// against 378, `docs/latency.md`, branch wip-xorder) and ends within 1e-12 of it.
#[test]
fn quadratic_warm_start_is_the_order_2_default_bit_for_bit() {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let records = desk_records(Some(WarmStart::Quadratic), &mut solver, 400);
    assert_eq!(digest(&records), 0x28e7_7963_fba1_fc23);
    const STEPS: usize = 120;
    let (quadratic_its, quadratic_states) = desk_run(Some(WarmStart::Quadratic), STEPS);
    let (its, states) = desk_run(None, STEPS);
    assert!(
        10 * its < 7 * quadratic_its,
        "{its} iterations against {quadratic_its}"
    );
    for (a, b) in states.iter().zip(&quadratic_states) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-12, "{x} against {y}");
        }
    }
}
