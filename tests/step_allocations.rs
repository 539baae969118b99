//! Heap allocations of warm-started step solves (`docs/latency.md#allocations`), counted by a
//! global allocator that counts per thread (the test harness runs tests on several threads).
//!
//! The Newton backend's iteration allocates nothing once its workspace has grown: a solve
//! allocates only what it returns (the point, and the summary's backend name, worst-component
//! name and counters), whatever the number of iterations, and nothing at all into kept storage
//! (`McpSolver::solve_into`); a whole desk step into kept storage (`Simulation::step_into`)
//! allocates nothing with Newton, and with the conic backend. Whole file: a few seconds in debug mode.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use ecp::formulations::{Simulation, StepRecord, scenarios};
use ecp::model::McpSolver;
use ecp::solvers::conic::{ConicSettings, ConicSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};

/// The system allocator, counting the allocations (and reallocations) of each thread.
struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    // `try_with`: the thread's counter may be gone while the thread exits.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
}

// SAFETY: every call is forwarded to `System` with the same arguments.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

/// Desk steps `1..=last` with `solver`: each step's problem is solved once more from the step's
/// warm start while counting allocations (the first 20 solves grow the workspace and are not
/// returned), then stepped. Returns `(step, allocations, iterations)` of steps 21–`last`; every
/// counted solve must converge.
fn warm_desk_solve_allocations(
    solver: &mut dyn McpSolver,
    last: usize,
) -> Vec<(usize, usize, usize)> {
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut counted = Vec::new();
    for step in 1..=last {
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z0 = sim.z().to_vec();
        let before = allocations();
        let sol = sim
            .solve_step_problem(&mut *solver, &z0)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
        let spent = allocations() - before;
        assert!(
            sol.summary.converged(),
            "step {step}: the solve did not converge"
        );
        if step > 20 {
            counted.push((step, spent, sol.summary.iterations));
        }
        drop(sol);
        sim.step(&mut *solver).unwrap_or_else(|e| panic!("{e}"));
    }
    counted
}

/// The most a converged Newton solve allocates besides its iterations: the returned point (1),
/// the summary's counters (2: six entries pushed), its backend name (1) and the worst
/// component's name (up to 3: `format!` grows its string piece by piece). One allocation per
/// iteration would exceed it on every solve of two iterations or more.
const NEWTON_SOLVE_ALLOCATIONS_MAX: usize = 7;

#[test]
fn a_warm_newton_step_solve_allocates_only_its_result() {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let counted = warm_desk_solve_allocations(&mut solver, 120);
    // The bound means something only when solves take several iterations.
    let most = counted.iter().map(|c| c.2).max().unwrap_or(0);
    assert!(most >= 2, "at most {most} iterations per solve");
    for (step, spent, iterations) in counted {
        assert!(
            spent <= NEWTON_SOLVE_ALLOCATIONS_MAX,
            "solve of step {step} ({iterations} iterations): {spent} allocations"
        );
    }
}

/// The whole step into kept storage (`Simulation::step_into`: checkpoint, data, warm start,
/// solve into the kept `Solution`, read-out, the kept `LastStep`, the record) allocates nothing
/// once the first steps have grown that storage: desk steps 21–120 with Newton
/// (`docs/latency.md#allocations`). The record's contents are checked against `step`'s so
/// that the count is of the same work.
#[test]
fn a_whole_desk_step_into_kept_storage_allocates_nothing_with_newton() {
    let newton = || NewtonSolver::new(NewtonSettings::default());
    assert_step_into_allocations("newton", &mut newton(), &mut newton(), 0);
}

/// A1's whole steps into kept storage with Newton allocate nothing either, once the first steps
/// have grown the storage (from step 4; measured 2 allocations at step 2 and 3 at step 3, the
/// first extrapolated warm start, whose guard grows its storage): the sliding steps solved by one chord step on the LU kept from the
/// step before
/// (`NewtonSettings::chord_across_solves`, `docs/latency.md`, branch wip-a1fast), the stop's
/// factorising steps and the steps at rest (no iteration, no `J`). The same records as `step`.
#[test]
fn a_whole_a1_step_into_kept_storage_allocates_nothing_with_newton() {
    let newton = || NewtonSolver::new(NewtonSettings::default());
    let mut solver = newton();
    let mut reference = newton().with_profile();
    let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
    let mut other = Simulation::new(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
    let mut record = StepRecord::default();
    let mut spent = Vec::new();
    for step in 1..=50 {
        let before = allocations();
        sim.step_into(&mut solver, &mut record)
            .unwrap_or_else(|e| panic!("A1 step {step}: {e}"));
        let count = allocations() - before;
        let expected = other
            .step(&mut reference)
            .unwrap_or_else(|e| panic!("A1 step {step}: {e}"));
        assert!(record.converged, "A1 step {step} did not converge");
        assert_eq!(record.bodies, expected.bodies, "A1 step {step}");
        assert_eq!(record.contacts, expected.contacts, "A1 step {step}");
        assert_eq!(record.summary.iterations, expected.summary.iterations);
        spent.push((step, count, record.summary.iterations));
    }
    println!("A1 (step, allocations, iterations): {spent:?}");
    for &(step, count, iterations) in &spent[3..] {
        assert_eq!(count, 0, "A1 step {step} ({iterations} iterations)");
    }
    // The count means something only when the kept LU served: measured 24 chord steps on it
    // (1 refused) and 5 factorisations over the 50 steps (29 factorisations without it).
    let p = reference.take_profile();
    println!(
        "A1 steps 1–50: {} chord steps on the kept LU ({} refused), {} factorisations",
        p.kept_lu_steps, p.kept_lu_refusals, p.lu_factorizations
    );
    assert!(p.kept_lu_steps >= 20, "{p:?}");
    assert!(p.lu_factorizations <= 6, "{p:?}");
}

/// What a whole PATH desk step allocates: measured 0 on steps 21–120 in release since the crash
/// step's right-hand side and the pivoting core's `z`, `w` and path end point live in the
/// workspaces (5 before, `docs/latency.md`, branch wip-pathlean). The margin of 2 is for the
/// debug profile, not measured; one allocation per iteration would exceed it (3 iterations).
const PATH_STEP_ALLOCATIONS_MAX: usize = 2;

/// [`a_whole_desk_step_into_kept_storage_allocates_nothing_with_newton`] with PATH, bounded.
#[test]
fn a_whole_desk_step_into_kept_storage_with_path_allocates_a_bounded_number_of_times() {
    let path = || PathSolver::new(PathSettings::default());
    assert_step_into_allocations("path", &mut path(), &mut path(), PATH_STEP_ALLOCATIONS_MAX);
}

/// Steps the desk to step 120 twice, with `step_into` (one record for every step; allocations
/// counted from step 21) and with `step`, and asserts at most `max` allocations per step and
/// the same records.
fn assert_step_into_allocations(
    name: &str,
    solver: &mut dyn McpSolver,
    reference: &mut dyn McpSolver,
    max: usize,
) {
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut other = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut record = StepRecord::default();
    let mut spent = Vec::new();
    for step in 1..=120 {
        let before = allocations();
        sim.step_into(solver, &mut record)
            .unwrap_or_else(|e| panic!("{name} step {step}: {e}"));
        let after = allocations();
        if step > 20 {
            spent.push((step, after - before, record.summary.iterations));
        }
        let expected = other
            .step(reference)
            .unwrap_or_else(|e| panic!("{name} step {step}: {e}"));
        assert!(record.converged, "{name} step {step} did not converge");
        assert_eq!(record.step, expected.step);
        assert_eq!(record.bodies, expected.bodies, "{name} step {step}");
        assert_eq!(record.contacts, expected.contacts, "{name} step {step}");
        assert_eq!(record.summary.residual, expected.summary.residual);
        assert_eq!(record.summary.iterations, expected.summary.iterations);
        assert_eq!(record.summary.counters, expected.summary.counters);
        assert_eq!(record.summary.worst, expected.summary.worst);
        assert_eq!(record.summary.solver, expected.summary.solver);
        assert_eq!(sim.last_step(), other.last_step(), "{name} step {step}");
    }
    // The bound means something only when the steps iterate.
    let most = spent.iter().map(|s| s.2).max().unwrap_or(0);
    assert!(most >= 2, "{name}: at most {most} iterations per step");
    let worst = spent.iter().map(|s| s.1).max().unwrap_or(0);
    println!("{name}: whole desk step into kept storage, at most {worst} allocations");
    for (step, count, iterations) in spent {
        assert!(
            count <= max,
            "{name} step {step} ({iterations} iterations): {count} allocations, at most {max} allowed"
        );
    }
}

/// The most a whole conic desk step into kept storage allocates (steps 21–120, default
/// settings): measured 0 in release since the conic backend's `solve_into` keeps its point,
/// polished point and counters, and the formulation refills the contacts' patches
/// (`StepStructure::contact_into`) and assembles without heap matrices (109 per solve before,
/// `docs/latency.md`, branch wip-conic4). The margin of 2 is for the debug profile; one
/// allocation per outer iteration or per assembled point would exceed it (2 outer iterations,
/// 3 assembled points per step).
const CONIC_STEP_ALLOCATIONS_MAX: usize = 2;

/// [`a_whole_desk_step_into_kept_storage_allocates_nothing_with_newton`] with the conic backend,
/// bounded.
#[test]
fn a_whole_desk_step_into_kept_storage_with_conic_allocates_a_bounded_number_of_times() {
    let conic = || ConicSolver::new(ConicSettings::default());
    assert_step_into_allocations(
        "conic",
        &mut conic(),
        &mut conic(),
        CONIC_STEP_ALLOCATIONS_MAX,
    );
}

/// `Simulation::step`, which returns a new record, allocates that record's vectors and strings
/// (the states, the contacts, the summary's backend name, worst component's name and counters):
/// measured 5 on the desk, steps 21–120, Newton (35 before the driver kept its storage,
/// `docs/latency.md#allocations`); pinned so that it can only fall
/// (`cargo test --test step_allocations -- --nocapture` prints it).
const WHOLE_STEP_ALLOCATIONS_MAX: usize = 5;

#[test]
fn a_whole_desk_step_allocates_a_bounded_number_of_times() {
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut most = 0;
    for step in 1..=120 {
        let before = allocations();
        let record = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
        let spent = allocations() - before;
        drop(record);
        if step > 20 {
            most = most.max(spent);
        }
    }
    println!("whole desk step: at most {most} allocations");
    assert!(most <= WHOLE_STEP_ALLOCATIONS_MAX, "{most} allocations");
}

/// The most a warm conic desk solve allocates (steps 21–80, default settings): only what it
/// returns, as Newton's ([`NEWTON_SOLVE_ALLOCATIONS_MAX`]): measured 6 in release since the
/// conic backend implements `solve_into` with its outer loop's, polish's and QP's storage kept
/// and the formulation refills the contacts' patches and assembles without heap matrices
/// (branch wip-conic4; 109 before, 131 at wip-conicip, 160 before `step::build` kept its row
/// vectors, 221 before the outer loop kept its storage, 697 to 809 before the polish did):
/// `cargo test [--release] --test step_allocations -- --nocapture` prints it. One allocation
/// per outer iteration would exceed it only with two more iterations; the whole step into kept
/// storage (above) is the strict test. One more than Newton's since the polish's extrapolation
/// (branch wip-conic5): 6 at 59 of the 60 solves, 8 at one (step 62), the source of the two
/// not pinned down (a kept vector's first growth, bounded per run, not per step).
const CONIC_DESK_SOLVE_ALLOCATIONS_MAX: usize = NEWTON_SOLVE_ALLOCATIONS_MAX + 1;

#[test]
fn a_warm_conic_desk_solve_allocates_a_bounded_number_of_times() {
    let mut solver = ConicSolver::new(ConicSettings::default());
    let counted = warm_desk_solve_allocations(&mut solver, 80);
    let most = counted.iter().map(|c| c.1).max().unwrap_or(0);
    let least = counted.iter().map(|c| c.1).min().unwrap_or(usize::MAX);
    println!("warm conic desk solve: {least} to {most} allocations");
    assert!(
        most <= CONIC_DESK_SOLVE_ALLOCATIONS_MAX,
        "{most} allocations"
    );
}

/// The most a repeated desk step sensitivity allocates (`StepDifferentiator::differentiate`
/// after the 100th step, its workspace grown by two calls): the returned `StepSensitivity`'s
/// vectors (its `dz`, state derivatives, inputs, statuses, degeneracies and their component
/// names; 10 in all) — the workspace itself (the reduced system, the LU, the row-major solution,
/// `∂F/∂θ`, the classification's and the data Jacobian's bookkeeping) allocates nothing once
/// grown (`differentiate_into`, below, allocates nothing at all). `cargo test [--release] --test
/// step_allocations -- --nocapture` prints the count; the bound fails if a per-column or
/// per-entry allocation comes back (30 columns).
const DESK_SENSITIVITY_ALLOCATIONS_MAX: usize = 15;

#[test]
fn a_repeated_desk_step_sensitivity_allocates_a_bounded_number_of_times() {
    use ecp::formulations::sensitivity::{SensitivityOptions, StepDifferentiator};
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    for _ in 0..100 {
        sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
    }
    let mut differ = StepDifferentiator::new(SensitivityOptions::default());
    let mut counts = Vec::new();
    for call in 0..6 {
        let before = allocations();
        let s = differ
            .differentiate(&sim)
            .unwrap_or_else(|e| panic!("call {call}: {e}"));
        let spent = allocations() - before;
        assert_eq!(s.dz.len(), s.n * 30);
        drop(s);
        if call >= 2 {
            counts.push(spent);
        }
    }
    println!("repeated desk step sensitivity: {counts:?} allocations per call");
    assert!(
        counts.windows(2).all(|w| w[0] == w[1]),
        "the count changes between calls: {counts:?}"
    );
    assert!(
        counts[0] <= DESK_SENSITIVITY_ALLOCATIONS_MAX,
        "{} allocations",
        counts[0]
    );
}

/// A repeated desk step sensitivity into one kept result
/// (`StepDifferentiator::differentiate_into`) allocates nothing once the result and the
/// workspace have grown (two calls), and gives the same result as `differentiate`.
#[test]
fn a_repeated_desk_step_sensitivity_into_a_kept_result_does_not_allocate() {
    use ecp::formulations::sensitivity::{SensitivityOptions, StepDifferentiator, StepSensitivity};
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    for _ in 0..100 {
        sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
    }
    let mut differ = StepDifferentiator::new(SensitivityOptions::default());
    let mut kept = StepSensitivity::empty();
    let mut counts = Vec::new();
    for call in 0..6 {
        let before = allocations();
        differ
            .differentiate_into(&sim, &[], &mut kept)
            .unwrap_or_else(|e| panic!("call {call}: {e}"));
        let spent = allocations() - before;
        assert_eq!(kept.dz.len(), kept.n * 30);
        if call >= 2 {
            counts.push(spent);
        }
    }
    println!("repeated desk step sensitivity into a kept result: {counts:?} allocations per call");
    assert_eq!(counts, vec![0; 4]);
    let fresh = differ.differentiate(&sim).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(fresh, kept);
}
