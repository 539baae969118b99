//! Heap allocations of warm-started step solves (`docs/latency.md#allocations`), counted by a
//! global allocator that counts per thread (the test harness runs tests on several threads).
//!
//! The Newton backend's iteration allocates nothing once its workspace has grown: a solve
//! allocates only what it returns (the point, and the summary's backend name, worst-component
//! name and counters) and the one evaluation of `F` of its final residuals, whatever the number
//! of iterations. Whole file: a few seconds in debug mode.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use ecp::formulations::{Simulation, scenarios};
use ecp::model::McpSolver;
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

/// What a converged Newton solve allocates besides its iterations: the returned point, the
/// summary's backend name, the worst component's name and the counters, and `F` at the
/// returned point for its residuals.
const NEWTON_SOLVE_ALLOCATIONS: usize = 5;

#[test]
fn a_warm_newton_step_solve_allocates_only_its_result() {
    let mut sim = Simulation::new(scenarios::desk()).unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut per_solve = Vec::new();
    let mut iterations = Vec::new();
    for step in 1..=120 {
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z0 = sim.z().to_vec();
        let before = allocations();
        let sol = sim
            .solve_step_problem(&mut solver, &z0)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
        let spent = allocations() - before;
        // The first solves grow the workspace (and the stall test's history, up to the most
        // iterations seen).
        if step > 20 {
            per_solve.push(spent);
            iterations.push(sol.summary.iterations);
        }
        drop(sol);
        sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
    }
    let (lo, hi) = (
        iterations.iter().min().copied().unwrap_or(0),
        iterations.iter().max().copied().unwrap_or(0),
    );
    // The check means something only when the iteration counts differ between the solves.
    assert!(lo < hi, "iterations {lo}..{hi}");
    for (k, &a) in per_solve.iter().enumerate() {
        assert_eq!(
            a,
            NEWTON_SOLVE_ALLOCATIONS,
            "solve of step {} ({} iterations): {a} allocations",
            k + 21,
            iterations[k]
        );
    }
}
