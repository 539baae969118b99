//! The semismooth Newton backend on ordinary scenes of the kinds `examples/newton_robustness.rs`
//! measures (docs/newton.md): every step must converge to the default tolerance (natural
//! residual ≤ 1e-10) with Newton alone, and free flight must take a few iterations.

use ecp::formulations::blocks::FrictionParams;
use ecp::formulations::geometry::{HalfSpace, MassProperties, Shape};
use ecp::formulations::rotation::{quat_from_axis_angle, rotation_matrix};
use ecp::formulations::{BodySpec, BodyState, Load, Scene, Simulation, StepRecord};
use ecp::model::Counter;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use nalgebra::{Vector3, Vector4};

fn box_scene(
    dims: [f64; 3],
    mass: f64,
    q: Vector4<f64>,
    gap: f64,
    v: Vector3<f64>,
    w: Vector3<f64>,
    mu: f64,
    h: f64,
    duration: f64,
) -> Scene {
    let shape = Shape::cuboid(dims[0], dims[1], dims[2]).unwrap_or_else(|e| panic!("{e}"));
    let r = rotation_matrix(&q);
    let lowest = shape
        .vertices()
        .iter()
        .map(|p| (r * p).z)
        .fold(f64::INFINITY, f64::min);
    Scene {
        name: "box".into(),
        bodies: vec![BodySpec {
            name: "box".into(),
            mass: MassProperties::solid_cuboid(mass, dims[0], dims[1], dims[2])
                .unwrap_or_else(|e| panic!("{e}")),
            shape,
            initial: BodyState {
                x: Vector3::new(0.0, 0.0, gap - lowest),
                q,
                v,
                w,
            },
            load: Load::None,
        }],
        planes: vec![HalfSpace::ground()],
        friction: FrictionParams {
            mu,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.1 * dims.iter().copied().fold(f64::INFINITY, f64::min),
        },
        gravity: Vector3::new(0.0, 0.0, -9.8),
        h,
        duration,
        world: Default::default(),
    }
}

fn run(scene: Scene) -> Vec<StepRecord> {
    let mut solver = NewtonSolver::new(NewtonSettings::default());
    let mut sim = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
    let mut records = Vec::new();
    sim.run(&mut solver, |rec| {
        records.push(rec.clone());
        true
    })
    .unwrap_or_else(|e| panic!("{e}"));
    records
}

fn assert_all_converged(name: &str, records: &[StepRecord]) {
    for r in records {
        assert!(
            r.converged && r.summary.residual <= 1e-10,
            "{name}: step {} {:?} after {} iterations, natural residual {:.2e} (worst {:?})",
            r.step,
            r.summary.termination,
            r.summary.iterations,
            r.summary.residual,
            r.summary.worst
        );
        assert_eq!(
            r.summary.counter(Counter::Retries).unwrap_or(0),
            0,
            "{name}: step {} retried",
            r.step
        );
    }
}

/// A box tossed with spin, vertex first, lands and tumbles. Free-flight steps of such boxes
/// used to end at the 200-iteration limit in a spurious minimiser with `p_n > 0`
/// (docs/newton.md). It passed with the Newton work on the start-of-step Newton–Euler rows; with
/// the energy-stable end-of-step rows (docs/energy.md) Newton alone stops at step 17 (natural
/// residual 6.7e-4 in ω_x, the open landing class of docs/newton.md). Run with
/// `cargo test --test newton_robustness -- --ignored`.
#[test]
#[ignore]
fn tossed_spinning_box_converges_every_step() {
    let q = quat_from_axis_angle(&Vector3::new(0.3, -0.8, 0.5), 0.9)
        .unwrap_or_else(|| panic!("non-zero axis"));
    let records = run(box_scene(
        [0.4, 0.3, 0.2],
        2.0,
        q,
        0.05,
        Vector3::new(0.5, -0.3, -0.5),
        Vector3::new(6.0, -4.0, 8.0),
        0.5,
        0.007,
        0.35,
    ));
    assert_all_converged("toss", &records);
    // Free flight: a few Newton iterations per step.
    let free: Vec<&StepRecord> = records
        .iter()
        .filter(|r| r.contacts[0].min_gap > 1e-3)
        .collect();
    assert!(!free.is_empty());
    for r in free {
        assert!(
            r.summary.iterations <= 4,
            "free-flight step {}: {} iterations",
            r.step,
            r.summary.iterations
        );
    }
}

/// The case: a box standing on an edge at gap 0 falls over, h = 1.25 ms, μ = 0.72.
/// Open: the step where the box lands flat on its face (step 176) stalls at natural residual
/// 1.5e-3 in a local minimiser of the merit function (the multipliers of the two opposite side
/// faces at ±2e-4, the kinematic row of q_y unmet); docs/newton.md.
#[test]
#[ignore = "open: Newton stalls on the step where the falling box lands flat (docs/newton.md)"]
fn box_falling_over_from_an_edge_converges_every_step() {
    let q = quat_from_axis_angle(&Vector3::y(), 0.5).unwrap_or_else(|| panic!("unit axis"));
    let records = run(box_scene(
        [0.4, 0.4, 0.2],
        10.0,
        q,
        0.0,
        Vector3::zeros(),
        Vector3::zeros(),
        0.72,
        1.25e-3,
        0.4,
    ));
    assert_all_converged("edge fall", &records);
}
