//! The scenes users will want (`docs/bodies.md#scenes`): `scenes/tbar_gripper.toml`,
//! `scenes/parts_feeder.toml` and `scenes/bin20.toml` run to the end through `ecp run`'s path
//! (the driver's fallbacks allowed, and counted) with every step converged; no two real bodies
//! overlap by more than 1e-8 m at any step end (checked here from the recorded poses, piece by
//! piece, between every two bodies, besides the stepper's own check), and no body dips more than
//! 1e-8 m into the ground; and the unforced bin gains no energy except at the steps where a
//! loaded contact opens (`docs/model.md#bodies-scenarios`, counted as `src/stress` counts them).
//!
//! The bins and the path runs take longer than the default suite allows; they are ignored here
//! and run in release:
//!
//! ```text
//! cargo test --release -p ecp --test user_scenes -- --include-ignored --nocapture
//! ```

use std::path::Path;

use ecp::formulations::Simulation;
use ecp::formulations::bodies::overlap::RealPieces;
use ecp::formulations::{StepMethod, StepRecord};
use ecp::run::{RunOptions, run_scene};
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::stress::measure_records;
use ecp::stress::runner::penetration;

#[path = "../benches/common/bin_state.rs"]
mod bin_state;

/// Penetration allowed between two real bodies and into a half-space (m).
const PENETRATION: f64 = 1e-8;

/// Relative energy (of `stress::runner::energy_scale`) a step may gain outside the opening
/// steps: round-off.
const ENERGY_GAIN: f64 = 1e-9;

struct Checked {
    records: Vec<StepRecord>,
    fallback_steps: usize,
}

/// Runs `scenes/<name>.toml` with `backend` as `ecp run` does and checks convergence and
/// penetration at every step; prints the counts the docs report.
fn run_checked(name: &str, backend: &str) -> Checked {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(format!("{name}.toml"));
    let file = load_scene(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    let dir = std::env::temp_dir().join(format!(
        "ecp-user-scenes-{name}-{backend}-{}",
        std::process::id()
    ));
    let options = RunOptions {
        out_dir: dir.clone(),
        solver: Some(backend.to_string()),
        plots: false,
        ..RunOptions::default()
    };
    let outcome =
        run_scene(&file, &options, |_| {}).unwrap_or_else(|e| panic!("{name}, {backend}: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        outcome.succeeded(),
        "{name}, {backend}: {} failed steps, {:?}",
        outcome.summary.failed_steps,
        outcome.stepper_error
    );
    let scene = &file.scene;
    let steps = (scene.duration / scene.h - 1e-9).ceil() as usize;
    assert_eq!(outcome.records.len(), steps, "{name}, {backend}");
    let pieces = RealPieces::of(scene);
    let (mut worst, mut fallback_steps, mut pairs_max) = (0.0_f64, 0, 0);
    for r in &outcome.records {
        assert!(r.converged, "{name}, {backend}: step {}", r.step);
        if r.method != StepMethod::Direct {
            fallback_steps += 1;
        }
        pairs_max = pairs_max.max(r.pairs.len());
        if let Some(o) = pieces.deepest_overlap(scene, &r.bodies, r.t, 0.0) {
            worst = worst.max(o.depth);
            assert!(
                o.depth <= PENETRATION,
                "{name}, {backend}: step {}: {} and {} overlap by {:e} m",
                r.step,
                o.a,
                o.b,
                o.depth
            );
        }
        let ground = penetration(scene, &r.bodies);
        assert!(
            ground <= PENETRATION,
            "{name}, step {}: {ground:e} m",
            r.step
        );
    }
    let us: Vec<f64> = outcome.records.iter().map(|r| r.solve_us).collect();
    eprintln!(
        "{name}, {backend}: {steps} steps converged, {fallback_steps} by a fallback, deepest \
         overlap {worst:.2e} m, at most {pairs_max} contact sets, mean solve {:.0} µs",
        us.iter().sum::<f64>() / us.len() as f64
    );
    Checked {
        records: outcome.records,
        fallback_steps,
    }
}

/// The unforced bin: no step gains energy except the opening steps.
fn bin(name: &str, backend: &str) {
    let run = run_checked(name, backend);
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(format!("{name}.toml"));
    let scene = load_scene(&path).unwrap_or_else(|e| panic!("{e}")).scene;
    let m = measure_records(&scene, &run.records);
    assert!(m.unforced, "{name} has a load");
    eprintln!(
        "{name}, {backend}: {} opening steps (Σ ΔE {:.2e}, largest gain {:.2e} of the scale \
         {:.2} J); gains outside them {:.2e}; fallback steps {}",
        m.opening_steps,
        m.opening_energy,
        m.opening_max_gain,
        m.energy_scale,
        m.energy_step_gains,
        run.fallback_steps
    );
    assert!(
        m.energy_step_gains <= ENERGY_GAIN,
        "{name}, {backend}: the steps that open no loaded contact gain {:e} of the energy scale",
        m.energy_step_gains
    );
    // Settled: the parts are at rest at the end.
    let last = run.records.last().unwrap_or_else(|| panic!("no steps"));
    let vmax = last
        .bodies
        .iter()
        .map(|b| b.v.norm().max(b.w.norm() * 0.1))
        .fold(0.0, f64::max);
    assert!(
        vmax < 1e-3,
        "{name}, {backend}: still moving at the end ({vmax} m/s)"
    );
}

#[test]
fn tbar_gripper_newton() {
    let run = run_checked("tbar_gripper", "newton");
    // The back pad pushes the bar 0.15 m along x, then along a 45° arc of radius 0.2 m: at the
    // end the bar lies flush against the pad, turned by 45°, its CM 5 mm (the clearance) ahead
    // of the gripper frame's origin c = (0.15 + 0.2 sin 45°, 0.2 (1 − cos 45°)).
    let last = run.records.last().unwrap_or_else(|| panic!("no steps"));
    let s = &last.bodies[0];
    let r = std::f64::consts::FRAC_1_SQRT_2;
    let want = nalgebra::Vector3::new(
        0.15 + 0.2 * r - 0.005 * r,
        0.2 * (1.0 - r) - 0.005 * r,
        0.025,
    );
    let yaw = 2.0 * s.q[3].atan2(s.q[0]);
    eprintln!(
        "tbar_gripper: final CM {:?}, yaw {:.4}°",
        s.x,
        yaw.to_degrees()
    );
    assert!((s.x - want).norm() < 1e-3, "{:?} vs {want:?}", s.x);
    assert!(
        (yaw.to_degrees() - 45.0).abs() < 0.1,
        "yaw {}°",
        yaw.to_degrees()
    );
}

#[test]
#[ignore = "release: cargo test --release -p ecp --test user_scenes -- --include-ignored"]
fn tbar_gripper_path() {
    run_checked("tbar_gripper", "path");
}

#[test]
fn parts_feeder_newton() {
    let run = run_checked("parts_feeder", "newton");
    // Every part creeps along −x, the same for all (stick and slip do not depend on the mass
    // or the footprint); none leaves the plate's top (z unchanged) or turns.
    let first = &run.records[0];
    let last = run.records.last().unwrap_or_else(|| panic!("no steps"));
    let moved: Vec<f64> = (first.bodies.iter().zip(&last.bodies))
        .map(|(a, b)| b.x.x - a.x.x)
        .collect();
    eprintln!("parts_feeder: moved along x {moved:?} m in 4 s");
    for ((a, b), dx) in first.bodies.iter().zip(&last.bodies).zip(&moved) {
        assert!((-0.03..-0.01).contains(dx), "{dx}");
        assert!((dx - moved[0]).abs() < 1e-6, "{dx} vs {}", moved[0]);
        assert!(
            (b.x.z - a.x.z).abs() < 1e-9 && (b.q - a.q).norm() < 1e-9,
            "{a:?} {b:?}"
        );
    }
}

#[test]
#[ignore = "release: cargo test --release -p ecp --test user_scenes -- --include-ignored"]
fn parts_feeder_path() {
    run_checked("parts_feeder", "path");
}

#[test]
#[ignore = "release: cargo test --release -p ecp --test user_scenes -- --include-ignored"]
fn bin20_newton() {
    bin("bin20", "newton");
}

#[test]
#[ignore = "release: cargo test --release -p ecp --test user_scenes -- --include-ignored"]
fn bin20_path() {
    bin("bin20", "path");
}

/// The bin states the bodies benchmarks start from (`benches/bin50_states.csv`) fit the scene:
/// every part named as in `scenes/bin50.toml`, in order, with a unit quaternion, no two real
/// bodies overlapping and nothing in the ground by more than 1e-8 m; the settled stack at rest,
/// and a step from it converges and moves no part by more than 1 µm.
#[test]
fn bin50_states_fit_the_scene() {
    let scene = bin_state::bin50();
    let pieces = RealPieces::of(&scene);
    for label in [bin_state::FALLING, bin_state::SETTLED] {
        let states = bin_state::states_at(label).unwrap_or_else(|e| panic!("{e}"));
        let names: Vec<&str> = states.iter().map(|(n, _)| n.as_str()).collect();
        let want: Vec<&str> = scene.bodies.iter().map(|b| b.name.as_str()).collect();
        assert_eq!(names, want, "{label}");
        let states: Vec<_> = states.into_iter().map(|(_, s)| s).collect();
        for (b, s) in scene.bodies.iter().zip(&states) {
            assert!(
                (s.q.norm() - 1.0).abs() < 1e-12,
                "{label}: {} |q| = {}",
                b.name,
                s.q.norm()
            );
        }
        // The walls are fixed: any time will do.
        if let Some(o) = pieces.deepest_overlap(&scene, &states, 0.0, PENETRATION) {
            panic!("{label}: {} and {} overlap by {:e} m", o.a, o.b, o.depth);
        }
        let ground = penetration(&scene, &states);
        assert!(
            ground <= PENETRATION,
            "{label}: {ground:e} m into the ground"
        );
    }
    let settled = bin_state::bin_from(50, bin_state::SETTLED).unwrap_or_else(|e| panic!("{e}"));
    let vmax = settled
        .bodies
        .iter()
        .map(|b| b.initial.v.norm() + b.initial.w.norm())
        .fold(0.0, f64::max);
    assert!(vmax == 0.0, "the settled bin moves ({vmax})");
    let start: Vec<_> = settled.bodies.iter().map(|b| b.initial.x).collect();
    let mut sim = Simulation::with_formulation(settled, "bodies").unwrap_or_else(|e| panic!("{e}"));
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let r = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
    assert!(r.converged, "the step after the settled state");
    let moved = r
        .bodies
        .iter()
        .zip(&start)
        .map(|(s, x)| (s.x - x).norm())
        .fold(0.0, f64::max);
    assert!(
        moved < 1e-4,
        "a part moved {moved} m in the step after the settled state"
    );
}
