//! Heap allocations of warm-started step solves (`docs/latency.md#allocations`), counted by a
//! global allocator that counts per thread (the test harness runs tests on several threads).
//!
//! The Newton backend's iteration allocates nothing once its workspace has grown: a solve
//! allocates only what it returns (the point, and the summary's backend name, worst-component
//! name and counters), whatever the number of iterations. Whole file: a few seconds in debug
//! mode.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use ecp::formulations::{Simulation, scenarios};
use ecp::solvers::conic::{ConicSettings, ConicSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

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

/// The most a converged Newton solve allocates besides its iterations: the returned point (1),
/// the summary's counters (2: six entries pushed), its backend name (1) and the worst
/// component's name (up to 3: `format!` grows its string piece by piece). One allocation per
/// iteration would exceed it on every solve of two iterations or more.
const NEWTON_SOLVE_ALLOCATIONS_MAX: usize = 7;

#[test]
fn a_warm_newton_step_solve_allocates_only_its_result() {
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut counted = Vec::new();
    for step in 1..=120 {
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z0 = sim.z().to_vec();
        let before = allocations();
        let sol = sim
            .solve_step_problem(&mut solver, &z0)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
        let spent = allocations() - before;
        // The first solves grow the workspace.
        if step > 20 {
            counted.push((step, spent, sol.summary.iterations));
        }
        drop(sol);
        sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
    }
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

/// The whole step (`Simulation::step`: checkpoint, prepared problem, solve, read-out, record)
/// still allocates (`docs/latency.md#allocations`): the checkpoint's copies of the states and
/// `z`, the loads, the solve's result, the `StepRecord`'s vectors and the kept `LastStep`. This
/// pins the count so that it can only fall: measured 35 on the desk, steps 21–120, Newton
/// (`cargo test --test step_allocations -- --nocapture` prints it).
const WHOLE_STEP_ALLOCATIONS_MAX: usize = 35;

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

/// The most a warm conic desk solve allocates (steps 21–80, default settings). The polish
/// keeps its storage in the solver (`conic/step.rs`, `PolishWorkspace`); what is left is the
/// outer iteration's (each QP's geometry and assembly, the returned point and summary, the
/// anchored correction's eigendecomposition). Measured 221 on every solve (it was 697 to 809 before the polish
/// kept its storage): `cargo test --release --test step_allocations -- --nocapture` prints it.
const CONIC_DESK_SOLVE_ALLOCATIONS_MAX: usize = 240;

#[test]
fn a_warm_conic_desk_solve_allocates_a_bounded_number_of_times() {
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = ConicSolver::new(ConicSettings::default());
    let mut most = 0;
    let mut least = usize::MAX;
    for step in 1..=80 {
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z0 = sim.z().to_vec();
        let before = allocations();
        let sol = sim
            .solve_step_problem(&mut solver, &z0)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
        let spent = allocations() - before;
        assert!(
            sol.summary.converged(),
            "step {step}: the conic solve did not converge"
        );
        drop(sol);
        if step > 20 {
            most = most.max(spent);
            least = least.min(spent);
        }
        sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
    }
    println!("warm conic desk solve: {least} to {most} allocations");
    assert!(
        most <= CONIC_DESK_SOLVE_ALLOCATIONS_MAX,
        "{most} allocations"
    );
}
