//! The extension examples run in the test suite: each example's core is a function, included
//! here as a module and called (the example's `main` only prints what it returns).

use std::path::{Path, PathBuf};

use ecp::formulations::sensitivity::{SensitivityOptions, StepInput, step_sensitivity_with};
use ecp::formulations::{StateComponent, StepRecord};
use ecp::model::Counter;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

#[allow(dead_code)]
#[path = "../examples/custom_block.rs"]
mod custom_block;

#[allow(dead_code)]
#[path = "../examples/custom_formulation.rs"]
mod custom_formulation;

#[allow(dead_code)]
#[path = "../examples/step_in_loop.rs"]
mod step_in_loop;

#[allow(dead_code)]
#[path = "../examples/custom_backend.rs"]
mod custom_backend;

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecp-examples-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// The hardening spring over the floor: floating at `k s + c s³ = m g` (s = L − y) for 1 kg, on
/// the floor with `λ = m g − k L − c L³` for 5 kg (the data changed in place).
#[test]
fn custom_block_is_checked_and_solved() {
    let out = custom_block::run(&[1.0, 5.0]).expect("the example runs");
    let (k, c, g, l) = (100.0, 400.0, 9.8, 0.3);
    let (y, lambda) = out[0];
    let s = l - y;
    assert!((k * s + c * s * s * s - g).abs() <= 1e-10, "y = {y}");
    assert_eq!(lambda, 0.0);
    let (y, lambda) = out[1];
    assert!(y.abs() <= 1e-12, "y = {y}");
    assert!(
        (lambda - (5.0 * g - k * l - c * l * l * l)).abs() <= 1e-10,
        "λ = {lambda}"
    );
}

/// A formulation defined outside the crate runs through `ecp run`'s driver and outputs: the
/// sphere of the box's half height dropped from 0.05 m falls, lands and rests exactly as the hull
/// model's box (no rotation, the contact under the CM), to the solvers' tolerance.
#[test]
fn custom_formulation_runs_through_the_same_driver_and_outputs() {
    let dir = temp_dir("custom-formulation");
    let scene = Path::new("scenes/a5_drop.toml");
    let sphere = custom_formulation::run(scene, custom_formulation::NAME, 0.1, &dir.join("sphere"))
        .expect("sphere run");
    let hull = custom_formulation::run(scene, "hull", 0.1, &dir.join("hull")).expect("hull run");
    assert!(sphere.succeeded() && hull.succeeded());
    assert_eq!(sphere.summary.formulation, custom_formulation::NAME);
    assert_eq!(sphere.records.len(), 50);
    let z = |r: &StepRecord| (r.bodies[0].x.z, r.bodies[0].v.z, r.contacts[0].pn);
    for (a, b) in sphere.records.iter().zip(&hull.records) {
        let ((za, va, pa), (zb, vb, pb)) = (z(a), z(b));
        assert!(
            (za - zb).abs() <= 1e-10 && (va - vb).abs() <= 1e-9 && (pa - pb).abs() <= 1e-9,
            "step {}: sphere ({za}, {va}, {pa}), hull ({zb}, {vb}, {pb})",
            a.step
        );
    }
    let last = sphere.records.last().expect("records");
    assert!((last.bodies[0].x.z - 0.1).abs() <= 1e-12 && last.bodies[0].v.z.abs() <= 1e-9);
    let header = |d: &str| {
        std::fs::read_to_string(dir.join(d).join("trajectory.csv"))
            .expect("trajectory.csv")
            .lines()
            .next()
            .map(str::to_string)
    };
    assert_eq!(header("sphere"), header("hull"));
    let summary = std::fs::read_to_string(dir.join("sphere/summary.json")).expect("summary");
    assert!(summary.contains("\"formulation\": \"sphere\""), "{summary}");
    assert!(!sphere.plots.is_empty() && sphere.plots.iter().all(|p| p.exists()));
    let _ = std::fs::remove_dir_all(dir);
}

/// The desk in a loop: the spring's stiffness is a column of the step sensitivities, and its
/// derivative is the finite difference of the same step (same start state, k ± 1 N/m).
#[test]
fn step_in_loop_sensitivity_matches_the_step_it_describes() {
    let (mut sim, (trace, dmu, dk)) = step_in_loop::run().expect("the example runs");
    assert_eq!(trace.len(), 6);
    // The push drives the desk out, the tether pulls it back once the push stops.
    assert!(trace[3][2] > 0.3 && trace[5][2] < 0.0, "{trace:?}");
    let last = sim.last_step().expect("a last step").clone();
    let block = sim.force_handles()[0].data[0];
    let sens = step_sensitivity_with(
        &sim,
        &SensitivityOptions::default(),
        &[StepInput::Data(block, 0)],
    )
    .expect("sensitivity");
    let vx = StateComponent::Velocity(0);
    assert_eq!(sens.d_state(0, vx, StepInput::Mu), Some(dmu));
    let mut solver = NewtonSolver::new(NewtonSettings {
        tolerance: 1e-13,
        ..NewtonSettings::default()
    });
    let mut vx_at = |k: f64| {
        sim.set_data(block, &[k]).expect("data");
        sim.set_state(0, last.start[0]).expect("state");
        let rec = sim.step(&mut solver).expect("step");
        assert!(rec.converged);
        rec.bodies[0].v.x
    };
    let fd = (vx_at(201.0) - vx_at(199.0)) / 2.0;
    assert!(
        (fd - dk).abs() <= 1e-6 * dk.abs() + 1e-11,
        "dv_x/dk {dk:e}, difference {fd:e}"
    );
}

fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut reader = csv::Reader::from_path(path).expect("trajectory.csv");
    let header = reader
        .headers()
        .expect("header")
        .iter()
        .map(str::to_string)
        .collect();
    let rows = reader
        .records()
        .map(|r| r.expect("row").iter().map(str::to_string).collect())
        .collect();
    (header, rows)
}

/// A user's backend, registered beside the built-in ones, drives the same run driver: the
/// wrapped PATH gives the built-in PATH's trajectory (every column but the solve time, to
/// 1e-12), `summary.json` names the user's backend, the same plots are written, and each step's
/// summary carries the backend's own counter next to PATH's.
#[test]
fn custom_backend_drives_the_same_run_as_a_built_in_one() {
    let dir = temp_dir("custom-backend");
    let (mine, log) =
        custom_backend::run_a1(&dir.join("mine"), custom_backend::NAME).expect("custom run");
    let (path, path_log) = custom_backend::run_a1(&dir.join("path"), "path").expect("path run");
    assert!(mine.succeeded() && path.succeeded());
    assert_eq!(mine.summary.steps, 50);
    assert_eq!(mine.summary.solver, custom_backend::NAME);
    assert!(path_log.is_empty(), "{path_log:?}");
    assert!(log.len() >= 50, "{} solves logged", log.len());
    for line in &log {
        assert!(line.starts_with("logged-path: "), "{line}");
    }
    for (k, r) in mine.records.iter().enumerate() {
        assert_eq!(r.summary.solver, custom_backend::NAME, "step {}", k + 1);
        assert!(r.summary.counter(Counter::Custom("logged_solves")).unwrap() > k);
        assert!(r.summary.counter(Counter::Pivots).is_some());
    }

    let (header, rows) = read_csv(&dir.join("mine/trajectory.csv"));
    let (path_header, path_rows) = read_csv(&dir.join("path/trajectory.csv"));
    assert_eq!(header, path_header);
    assert_eq!(rows.len(), 50);
    assert_eq!(rows.len(), path_rows.len());
    for (k, (a, b)) in rows.iter().zip(&path_rows).enumerate() {
        for ((name, x), y) in header.iter().zip(a).zip(b) {
            if name == "solve_us" {
                continue;
            }
            match (x.parse::<f64>(), y.parse::<f64>()) {
                (Ok(x), Ok(y)) => assert!((x - y).abs() <= 1e-12, "row {k} {name}: {x} vs {y}"),
                _ => assert_eq!(x, y, "row {k} {name}"),
            }
        }
    }

    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("mine/summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    assert_eq!(summary["solver"], custom_backend::NAME);
    assert_eq!(summary["steps"], 50);
    assert_eq!(summary["failed_steps"], 0);

    let names = |o: &ecp::run::RunOutcome| {
        o.plots
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect::<Vec<_>>()
    };
    assert!(!names(&mine).is_empty());
    assert_eq!(names(&mine), names(&path));
    assert!(mine.plots.iter().all(|p| p.exists()));
    let _ = std::fs::remove_dir_all(dir);
}
