//! Repeats one warm-started step solve (or step sensitivity) `N` times, for instruction counts
//! under callgrind (`docs/latency.md#profile`), which the machine's load does not disturb:
//!
//! ```text
//! cargo build --release --example step_latency
//! valgrind --tool=callgrind target/release/examples/step_latency desk-newton 1000
//! ```
//!
//! A third argument `schur` solves with `NewtonSettings::structured_solve` on (the block
//! elimination, `docs/latency.md#structured-linear-solve`), `lu` (the default) with it off.
//!
//! The cases are those of the benchmarks: `desk-newton`, `desk-path`, `a1-newton`,
//! `tbar-newton`, `a1-path`, `tbar-path` (PATH on A1's 20th and the T-bar's 340th step), `desk-sensitivity` (the 100th desk step's sensitivities into one kept result, `StepDifferentiator::differentiate_into`; `desk-sensitivity-time` times each call and prints the median and a digest of `dz`), and
//! `desk-conic` (the conic backend's defaults: every QP by clarabel), `desk-conic-dense` (the
//! QPs by the dense method first, `ConicSettings::dense_qp`). The
//! difference of two runs' totals over the difference of their `N` is the cost of one solve,
//! without the set-up. `desk-steps` takes the desk's first `N` whole steps with Newton
//! (`Simulation::step`: checkpoint, data, solve, read-out, record), so `(Ir(120) − Ir(20)) / 100`
//! is the mean whole step over steps 21–120; `desk-steps-into` the same with
//! `Simulation::step_into` and one kept record, `desk-steps-profile` prints the Newton profile's counts over
//! the steps (factorisations, chord steps, those on the last solve's LU), `desk-steps-main` takes
//! them without `NewtonSettings::chord_across_solves` and `chord_round_off_floor` (main's Newton
//! before branch wip-lukeep), `desk-steps-kept` with chord steps on the last solve's LU
//! (`chord_across_solves: Some(1e-2)`, the default since branch wip-a1fast, whose rule keeps no
//! LU from the desk's runs: the defaults' digest), `desk-steps-previous` with
//! `WarmStart::Previous` (the plain warm start; main's digest before the extrapolated default).
//! `desk-steps-path` takes the desk's whole steps with PATH's defaults (polished, so
//! extrapolated warm starts), `desk-steps-path-previous` from the plain warm start,
//! `desk-steps-path-unpolished` with `PathSettings::polish_below = 1` (main's PATH before the
//! polish: the plain warm start). `desk-steps-conic` takes the desk's whole steps with the conic
//! backend's defaults (`desk-steps-conic-into`: with `Simulation::step_into` and one kept record).
//! `desk-steps-path-kept` with `PathSettings::chord_across_solves`.
//! `a1-steps` takes A1's first `N` whole steps with Newton, as `desk-steps`; `a1-steps-path`
//! and `tbar-steps-path` A1's and the T-bar's with PATH (`-kept`: with `chord_across_solves`).
//! All of them print a digest of the records' bits. Prints the last solve's iterations so the work cannot be optimised away.

use ecp::formulations::sensitivity::{SensitivityOptions, StepDifferentiator, StepSensitivity};
use ecp::formulations::{Scene, Simulation, WarmStart, scenarios};
use ecp::model::McpSolver;
use ecp::solvers::conic::{ConicSettings, ConicSolver};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};

/// `scene` after `k - 1` steps with `solver`, with step `k` prepared (as `benches/common`).
fn at_step(scene: Scene, k: usize, solver: &mut dyn McpSolver) -> (Simulation, Vec<f64>) {
    let mut sim = Simulation::new(scene).expect("scene");
    for _ in 1..k {
        sim.step(solver).expect("step");
    }
    sim.prepare_step().expect("prepare");
    let z0 = sim.z().to_vec();
    (sim, z0)
}

fn repeat(solver: &mut dyn McpSolver, scene: Scene, k: usize, n: usize) -> usize {
    let (sim, z0) = at_step(scene, k, solver);
    let mut iterations = 0;
    let mut counts = String::new();
    for _ in 0..n {
        match solver.solve(sim.mcp(), &z0) {
            Ok(sol) => {
                iterations = sol.summary.iterations;
                if counts.is_empty() {
                    // The work of one solve (PATH's crash steps, path steps and pivots).
                    counts = format!("{:?}", sol.summary.counters);
                }
            }
            Err(e) => panic!("step {k}: {e}"),
        }
    }
    println!("counters of the last solve: {counts}");
    iterations
}

/// As [`repeat`], for the conic backend (which needs the step's structural view).
fn repeat_structured(solver: &mut dyn McpSolver, scene: Scene, k: usize, n: usize) -> usize {
    let (sim, z0) = at_step(scene, k, solver);
    let view = sim.step_problem();
    let mut iterations = 0;
    for _ in 0..n {
        match solver.solve(&view, &z0) {
            Ok(sol) => iterations = sol.summary.iterations,
            Err(e) => panic!("step {k}: {e}"),
        }
    }
    iterations
}

/// A hash of the bits of every number of the records (states, contacts, residual, iterations):
/// equal digests mean bit-for-bit equal trajectories. `.1` is the last step's iterations.
#[derive(Default)]
struct Digest(u64, usize);

impl Digest {
    fn mix(&mut self, bits: u64) {
        // FNV-1a over the 8 bytes.
        for b in bits.to_le_bytes() {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn add(&mut self, rec: &ecp::formulations::StepRecord) {
        if self.0 == 0 {
            self.0 = 0xcbf2_9ce4_8422_2325;
        }
        for b in &rec.bodies {
            for v in b.x.iter().chain(&b.q).chain(&b.v).chain(&b.w) {
                self.mix(v.to_bits());
            }
        }
        for c in &rec.contacts {
            for v in c.a1.iter().chain(&c.a2) {
                self.mix(v.to_bits());
            }
            for v in [c.lg, c.pn, c.pt, c.po, c.pr, c.sigma, c.min_gap] {
                self.mix(v.to_bits());
            }
        }
        self.mix(rec.summary.residual.to_bits());
        self.mix(rec.summary.iterations as u64);
        self.1 = rec.summary.iterations;
    }
}

/// The desk after 100 steps with Newton, and a differentiator for its step (both with
/// `structured_solve` as given).
fn desk_sensitivity_at_step_100(structured_solve: bool) -> (Simulation, StepDifferentiator) {
    let mut solver = NewtonSolver::new(NewtonSettings {
        structured_solve,
        ..NewtonSettings::default()
    });
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    for _ in 0..100 {
        sim.step(&mut solver).expect("desk step");
    }
    let differ = StepDifferentiator::new(SensitivityOptions {
        structured_solve,
        ..SensitivityOptions::default()
    });
    (sim, differ)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (case, n, linear) = match args.as_slice() {
        [_, case, n, rest @ ..] if rest.len() <= 1 => match n.parse::<usize>() {
            Ok(n) => (case.as_str(), n, rest.first().map_or("lu", String::as_str)),
            Err(_) => {
                eprintln!("step_latency: N must be a count of repetitions, got {n:?}");
                std::process::exit(2);
            }
        },
        _ => {
            eprintln!(
                "usage: step_latency <desk-newton|desk-path|a1-newton|a1-path|tbar-newton|tbar-path|desk-sensitivity|desk-sensitivity-time|\
                 desk-conic|desk-conic-dense|desk-steps|desk-steps-profile|desk-steps-main|desk-steps-kept|desk-steps-conic|desk-steps-conic-into|desk-steps-previous|desk-steps-into|desk-steps-path|\
                 desk-steps-path-previous|desk-steps-path-unpolished|desk-steps-path-kept|a1-steps|a1-steps-path[-kept]|tbar-steps-path[-kept]> N [lu|schur]"
            );
            std::process::exit(2);
        }
    };
    let structured_solve = match linear {
        "lu" => false,
        "schur" => true,
        other => {
            eprintln!("step_latency: the linear solve is lu or schur, got {other:?}");
            std::process::exit(2);
        }
    };
    let newton = || {
        NewtonSolver::new(NewtonSettings {
            structured_solve,
            ..NewtonSettings::default()
        })
    };
    let out = match case {
        "desk-newton" => repeat(&mut newton(), scenarios::desk(), 100, n),
        "desk-path" => repeat(
            &mut PathSolver::new(PathSettings::default()),
            scenarios::desk(),
            100,
            n,
        ),
        "a1-newton" => repeat(&mut newton(), scenarios::a1_sliding(), 20, n),
        "a1-path" => repeat(
            &mut PathSolver::new(PathSettings::default()),
            scenarios::a1_sliding(),
            20,
            n,
        ),
        "tbar-path" => repeat(
            &mut PathSolver::new(PathSettings::default()),
            scenarios::t_bar(),
            340,
            n,
        ),
        "desk-conic" => repeat_structured(
            &mut ConicSolver::new(ConicSettings::default()),
            scenarios::desk(),
            100,
            n,
        ),
        "desk-conic-dense" => repeat_structured(
            &mut ConicSolver::new(ConicSettings {
                dense_qp: true,
                ..ConicSettings::default()
            }),
            scenarios::desk(),
            100,
            n,
        ),
        "tbar-newton" => repeat(&mut newton(), scenarios::t_bar(), 340, n),
        "desk-steps" => {
            let mut solver = newton();
            let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
            let mut digest = Digest::default();
            for _ in 0..n {
                digest.add(&sim.step(&mut solver).expect("desk step"));
            }
            println!("desk-steps x{n}: record digest {:016x}", digest.0);
            digest.1
        }
        "desk-steps-conic" | "desk-steps-conic-into" => {
            // The conic backend's defaults, whole steps (its QPs warm-started across steps, so
            // one solve repeated is not representative: `docs/latency.md`).
            let mut solver = ConicSolver::new(ConicSettings::default());
            let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
            let mut digest = Digest::default();
            let mut record = ecp::formulations::StepRecord::default();
            for _ in 0..n {
                if case == "desk-steps-conic" {
                    digest.add(&sim.step(&mut solver).expect("desk step"));
                } else {
                    sim.step_into(&mut solver, &mut record).expect("desk step");
                    digest.add(&record);
                }
            }
            println!("{case} x{n}: record digest {:016x}", digest.0);
            digest.1
        }
        "desk-steps-profile" | "desk-steps-main" | "desk-steps-kept" => {
            // `-profile`: the defaults, with the Newton profile's counts over the N steps;
            // `-main`: without chord steps across solves and the chord's polish always taken
            // (main's Newton before branch wip-lukeep: its digest).
            let mut solver = if case == "desk-steps-main" {
                NewtonSolver::new(NewtonSettings {
                    structured_solve,
                    chord_across_solves: None,
                    chord_round_off_floor: None,
                    ..NewtonSettings::default()
                })
            } else if case == "desk-steps-kept" {
                NewtonSolver::new(NewtonSettings {
                    structured_solve,
                    chord_across_solves: Some(1e-2),
                    ..NewtonSettings::default()
                })
            } else {
                newton().with_profile()
            };
            let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
            let mut digest = Digest::default();
            for _ in 0..n {
                digest.add(&sim.step(&mut solver).expect("desk step"));
            }
            println!("{case} x{n}: record digest {:016x}", digest.0);
            let p = solver.take_profile();
            if case == "desk-steps-profile" {
                println!(
                    "iterations {}, LU factorisations {}, chord steps {} (refused {}), \
                     on the last solve's LU {} (refused {}), chord's polishes skipped {}",
                    p.iterations,
                    p.lu_factorizations,
                    p.chord_steps,
                    p.chord_rejections,
                    p.kept_lu_steps,
                    p.kept_lu_refusals,
                    p.chord_polishes_skipped
                );
            }
            digest.1
        }
        "desk-steps-previous" => {
            let mut solver = newton();
            let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
            sim.set_warm_start(WarmStart::Previous);
            let mut digest = Digest::default();
            for _ in 0..n {
                digest.add(&sim.step(&mut solver).expect("desk step"));
            }
            println!("desk-steps-previous x{n}: record digest {:016x}", digest.0);
            digest.1
        }
        "desk-steps-into" => {
            let mut solver = newton();
            let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
            let mut digest = Digest::default();
            let mut record = ecp::formulations::StepRecord::default();
            for _ in 0..n {
                sim.step_into(&mut solver, &mut record).expect("desk step");
                digest.add(&record);
            }
            println!("desk-steps-into x{n}: record digest {:016x}", digest.0);
            digest.1
        }
        "desk-steps-path"
        | "desk-steps-path-previous"
        | "desk-steps-path-unpolished"
        | "desk-steps-path-kept" => {
            // PATH's defaults (polished, so extrapolated warm starts), from the plain warm
            // start, and without the polish (`polish_below = 1`: the plain warm start).
            let mut solver = PathSolver::new(PathSettings {
                polish_below: if case == "desk-steps-path-unpolished" {
                    1.0
                } else {
                    PathSettings::default().polish_below
                },
                chord_across_solves: case == "desk-steps-path-kept",
                ..PathSettings::default()
            });
            let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
            if case == "desk-steps-path-previous" {
                sim.set_warm_start(WarmStart::Previous);
            }
            let mut digest = Digest::default();
            for _ in 0..n {
                digest.add(&sim.step(&mut solver).expect("desk step"));
            }
            println!("{case} x{n}: record digest {:016x}", digest.0);
            digest.1
        }
        "a1-steps" => {
            // A1's first `N` whole steps with Newton (sliding to about step 36, then at rest;
            // past its 50 steps the box stays at rest), as `desk-steps`.
            let mut solver = newton();
            let mut sim = Simulation::new(scenarios::a1_sliding()).expect("A1 scene");
            let mut digest = Digest::default();
            for _ in 0..n {
                digest.add(&sim.step(&mut solver).expect("A1 step"));
            }
            println!("a1-steps x{n}: record digest {:016x}", digest.0);
            digest.1
        }
        "a1-steps-path" | "a1-steps-path-kept" | "tbar-steps-path" | "tbar-steps-path-kept" => {
            // A1's or the T-bar's first `N` whole steps with PATH's defaults, and with chord
            // steps on the LU kept from the last solve (`-kept`), as `desk-steps-path`.
            let mut solver = PathSolver::new(PathSettings {
                chord_across_solves: case.ends_with("-kept"),
                ..PathSettings::default()
            });
            let scene = if case.starts_with("a1") {
                scenarios::a1_sliding()
            } else {
                scenarios::t_bar()
            };
            let mut sim = Simulation::new(scene).expect("scene");
            let mut digest = Digest::default();
            for _ in 0..n {
                digest.add(&sim.step(&mut solver).expect("step"));
            }
            println!("{case} x{n}: record digest {:016x}", digest.0);
            digest.1
        }
        "desk-sensitivity" => {
            let (sim, mut differ) = desk_sensitivity_at_step_100(structured_solve);
            // Into one kept result, as a caller differentiating every step would.
            let mut sens = StepSensitivity::empty();
            for _ in 0..n {
                differ
                    .differentiate_into(&sim, &[], &mut sens)
                    .expect("sensitivity");
            }
            sens.dz.len()
        }
        "desk-sensitivity-time" => {
            // The same calls, each timed: the median in microseconds, and a digest of the
            // last result's `dz` bits, to compare builds by.
            let (sim, mut differ) = desk_sensitivity_at_step_100(structured_solve);
            let mut sens = StepSensitivity::empty();
            let mut times = Vec::with_capacity(n);
            for _ in 0..n {
                let start = std::time::Instant::now();
                differ
                    .differentiate_into(&sim, &[], &mut sens)
                    .expect("sensitivity");
                times.push(start.elapsed().as_secs_f64() * 1e6);
            }
            times.sort_by(f64::total_cmp);
            let mut digest = Digest::default();
            for v in &sens.dz {
                digest.mix(v.to_bits());
            }
            println!(
                "desk-sensitivity-time x{n}: median {:.3} us, fastest {:.3} us, digest {:016x}",
                times.get(n / 2).copied().unwrap_or(f64::NAN),
                times.first().copied().unwrap_or(f64::NAN),
                digest.0
            );
            sens.dz.len()
        }
        other => {
            eprintln!("unknown case {other}");
            std::process::exit(2);
        }
    };
    println!("{case} x{n}: {out}");
}
