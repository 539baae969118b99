//! The reduced sliding model (`docs/model.md#reduced`, `docs/reduced-sliding.md`) against the hull
//! model and the analytic scenarios, its refusals, and the Jacobians of its residual blocks.
//!
//! - Desk (`docs/model.md#scenarios`): the reduced and the hull model (Newton) agree to 1e-8 in v,
//!   ω and the ECP at every one of the 400 steps, with the Newton and the PATH backend; at sampled
//!   steps the reduced solution, written in the hull model's unknowns, solves the hull step MCP
//!   (natural residual ≤ 1e-9).
//! - A1, A2, A3, A4 (10° sticks, 25° slides), A6 at 90 N: the discrete answers of
//!   `docs/model.md#scenarios` to 1e-9 in velocities and 1e-8 in ECP offsets, with Newton and PATH,
//!   and the hull model's trajectory to 1e-8.
//! - Refusals: A6 at 110 N stops at the step where the hull model starts to tip; A5 (dropped),
//!   two bodies, two half-spaces, a normal or tilting initial velocity, an unloaded contact are
//!   refused at construction; a load that lifts the body stops the run at the lift-off step.
//! - Property tests: the analytic Jacobians of `ReducedFriction` and `ReducedEllipsoid` against
//!   central differences on random step data.
//!
//! Run time in the test profile: about 0.2 s (`cargo test --test reduced_sliding`).

mod common;

use std::sync::Arc;

use common::strategies::{unit3, vec3};
use ecp::formulations::blocks::{ContactFrame, FrictionParams};
use ecp::formulations::formulation::{Formulation, Stepper, build_stepper};
use ecp::formulations::geometry::{ContactMode, HalfSpace};
use ecp::formulations::reduced::{
    ReducedEllipsoid, ReducedFriction, ReducedSliding, SlidingStepData,
};
use ecp::formulations::rotation::{kinematic_map, rotation_matrix};
use ecp::formulations::scenarios;
use ecp::formulations::stepper::{Load, Scene, SceneError, Simulation, StepRecord};
use ecp::model::{
    CheckOptions, McpSolver, ResidualBlock, check_problem, check_residual_block, residual_of,
};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};
use nalgebra::{Vector3, Vector6};
use proptest::prelude::*;

const G: f64 = 9.8;
const H: f64 = 0.01;

#[derive(Clone, Copy, Debug)]
enum Backend {
    Newton,
    Path,
}

fn solver(b: Backend) -> Box<dyn McpSolver> {
    match b {
        Backend::Newton => Box::new(NewtonSolver::new(NewtonSettings::default())),
        Backend::Path => Box::new(PathSolver::new(PathSettings::default())),
    }
}

/// Every step must converge to the backends' tolerance 1e-10 and keep every vertex above −1e-9.
fn check_steps(name: &str, records: &[StepRecord]) {
    for r in records {
        assert!(
            r.converged && r.summary.residual <= 1e-10,
            "{name}: step {} did not converge: {:?} residual {:.3e}",
            r.step,
            r.summary.termination,
            r.summary.residual
        );
        assert!(
            r.contacts[0].min_gap >= -1e-9,
            "{name}: step {} penetrates {:.3e}",
            r.step,
            r.contacts[0].min_gap
        );
    }
}

fn run_hull(scene: Scene) -> Vec<StepRecord> {
    let name = format!("{} (hull)", scene.name);
    let mut sim = Simulation::new(scene).expect("valid scene");
    let mut s = solver(Backend::Newton);
    let mut out = Vec::new();
    sim.run(s.as_mut(), |r| {
        out.push(r.clone());
        true
    })
    .expect("hull run");
    check_steps(&name, &out);
    out
}

/// Runs the reduced model to the end or to its first refusal.
fn try_reduced(scene: Scene, b: Backend) -> (Vec<StepRecord>, Option<SceneError>) {
    let mut st = ReducedSliding::new(scene).expect("the reduced model applies");
    let mut s = solver(b);
    let mut out = Vec::new();
    while !st.finished() {
        match st.step(s.as_mut()) {
            Ok(r) => out.push(r),
            Err(e) => return (out, Some(e)),
        }
    }
    (out, None)
}

fn run_reduced(scene: Scene, b: Backend) -> Vec<StepRecord> {
    let name = format!("{} (reduced, {b:?})", scene.name);
    let (recs, err) = try_reduced(scene, b);
    if let Some(e) = err {
        panic!("{name}: {e}");
    }
    check_steps(&name, &recs);
    recs
}

/// Largest differences between two runs: (|Δv|, |Δω|, |Δ ECP|, |Δx|) over all steps.
fn max_diffs(a: &[StepRecord], b: &[StepRecord]) -> [f64; 4] {
    assert_eq!(a.len(), b.len());
    let mut d = [0.0f64; 4];
    for (ra, rb) in a.iter().zip(b) {
        let (sa, sb) = (&ra.bodies[0], &rb.bodies[0]);
        d[0] = d[0].max((sa.v - sb.v).amax());
        d[1] = d[1].max((sa.w - sb.w).amax());
        d[2] = d[2].max((ra.contacts[0].a1 - rb.contacts[0].a1).amax());
        d[3] = d[3].max((sa.x - sb.x).amax());
    }
    d
}

fn assert_close(what: &str, got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "{what}: got {got:.15}, want {want:.15} (tolerance {tol:e})"
    );
}

/// The reduced run agrees with the hull run to 1e-8 in v, ω, ECP and x at every step.
fn assert_agrees_with_hull(name: &str, reduced: &[StepRecord], hull: &[StepRecord]) -> [f64; 4] {
    let d = max_diffs(reduced, hull);
    println!(
        "{name}: max |Δv| = {:.2e} m/s, |Δω| = {:.2e} rad/s, |Δ ECP| = {:.2e} m, |Δx| = {:.2e} m",
        d[0], d[1], d[2], d[3]
    );
    for (what, v) in ["v", "ω", "ECP", "x"].iter().zip(d) {
        assert!(
            v <= 1e-8,
            "{name}: reduced and hull differ by {v:.3e} in {what}"
        );
    }
    d
}

// ---------------------------------------------------------------------------------------------
// The desk (`docs/model.md#scenarios`)
// ---------------------------------------------------------------------------------------------

/// The hull model's unknowns at the reduced model's solution of the step from `state_before`
/// (`docs/model.md#unknowns`): ν, q (Q before renormalisation), a1 = a2 = ECP, multiplier 1 on the
/// face of Conv(F) lying on the plane, l_g = 0, the impulses and σ.
fn hull_point(sim: &Simulation, rec: &StepRecord, q_raw: nalgebra::Vector4<f64>) -> Vec<f64> {
    let mcp = sim.mcp();
    let mut z = sim.z().to_vec();
    let c = sim.contacts()[0];
    let s = &rec.bodies[0];
    let k = &rec.contacts[0];
    let put = |z: &mut Vec<f64>, v: ecp::model::VarId, vals: &[f64]| {
        z[mcp.range(v)].copy_from_slice(vals);
    };
    let nu_q = {
        // The body's (ν, q) blocks come first in the stepper's layout.
        let blocks = mcp.variable_blocks();
        assert!(blocks[0].name().ends_with(".nu") && blocks[1].name().ends_with(".q"));
        (ecp::model::VarId(0), ecp::model::VarId(1))
    };
    put(&mut z, nu_q.0, &[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z]);
    put(
        &mut z,
        nu_q.1,
        &[s.x.x, s.x.y, s.x.z, q_raw[0], q_raw[1], q_raw[2], q_raw[3]],
    );
    put(&mut z, c.a1, k.a1.as_slice());
    put(&mut z, c.a2, k.a2.as_slice());
    let n = sim.scene().planes[0].normal();
    let r = rotation_matrix(&q_raw);
    let face = sim.hull(0).most_aligned_face(&(r.transpose() * (-n)));
    let mut l = vec![0.0; sim.hull(0).num_faces()];
    l[face] = 1.0;
    put(&mut z, c.l, &l);
    put(&mut z, c.lg, &[0.0]);
    put(&mut z, c.pn, &[k.pn]);
    put(&mut z, c.pf, &[k.pt, k.po, k.pr]);
    put(&mut z, c.sigma, &[k.sigma]);
    z
}

/// At `steps`, builds the hull step MCP from the reduced model's state (load shifted to the same
/// time) and evaluates its natural residual at the reduced solution written in its unknowns.
fn reduced_solves_hull_step(scene: &Scene, reduced: &[StepRecord], steps: &[usize]) -> f64 {
    let mut worst = 0.0f64;
    for &k in steps {
        // The state at the start of step k (k ≥ 1) and the reduced solution of that step.
        let start = if k == 1 {
            scene.bodies[0].initial
        } else {
            reduced[k - 2].bodies[0]
        };
        let rec = &reduced[k - 1];
        let t0 = (k - 1) as f64 * scene.h;
        let mut sc = scene.clone();
        let load = sc.bodies[0].load.clone();
        sc.bodies[0].load = Load::Function(Arc::new(move |t| load.at(t + t0)));
        sc.bodies[0].initial = start;
        let mut sim = Simulation::new(sc).expect("valid scene");
        sim.prepare_step().expect("step data");
        let q_raw = start.q + kinematic_map(&start.q) * rec.bodies[0].w * (0.5 * scene.h);
        let z = hull_point(&sim, rec, q_raw);
        let res = residual_of(sim.mcp(), &z);
        worst = worst.max(res);
    }
    worst
}

#[test]
fn desk_reduced_agrees_with_hull_at_every_step() {
    let scene = scenarios::desk();
    let hull = run_hull(scene.clone());
    assert_eq!(hull.len(), 400);
    for b in [Backend::Newton, Backend::Path] {
        let reduced = run_reduced(scene.clone(), b);
        assert_eq!(reduced.len(), 400);
        assert_agrees_with_hull(
            &format!("desk, reduced ({b:?}) vs hull (Newton)"),
            &reduced,
            &hull,
        );
        for r in &reduced {
            let c = &r.contacts[0];
            assert_eq!(c.mode, ContactMode::Patch, "step {}", r.step);
            assert_close("desk a1_z", c.a1.z, 0.0, 1e-12);
            // The ECP stays in the 0.5 × 0.5 square (the convex hull of the four feet).
            let local = rotation_matrix(&r.bodies[0].q).transpose() * (c.a1 - r.bodies[0].x);
            assert!(local.x.abs() <= 0.25 + 1e-9 && local.y.abs() <= 0.25 + 1e-9);
        }
        // The desk slides during the whole run (σ > 0): the reduced model is in its domain.
        assert!(reduced.iter().all(|r| r.contacts[0].sigma > 0.0));
        if let Backend::Newton = b {
            let steps: Vec<usize> = (1..=400).step_by(21).collect();
            let res = reduced_solves_hull_step(&scene, &reduced, &steps);
            println!("desk: hull step MCP's natural residual at the reduced solutions ≤ {res:.2e}");
            assert!(
                res <= 1e-9,
                "natural residual {res:.3e} of the hull step MCP"
            );
        }
    }
}

#[test]
fn desk_step_mcp_jacobian_checks() {
    let mut st = ReducedSliding::new(scenarios::desk()).expect("applies");
    let mut s = solver(Backend::Newton);
    for _ in 0..50 {
        st.step(s.as_mut()).expect("step");
    }
    st.prepare_step().expect("step data");
    for report in check_problem(st.mcp(), st.z(), &CheckOptions::default()) {
        assert!(report.ok(), "{report}");
    }
}

// ---------------------------------------------------------------------------------------------
// Analytic scenarios (`docs/model.md#scenarios`)
// ---------------------------------------------------------------------------------------------

fn a1_sliding(b: Backend) {
    let recs = run_reduced(scenarios::a1_sliding(), b);
    let mu_g_h = 0.3 * G * H;
    let mut x = 0.0;
    for r in &recs {
        let k = r.step as f64;
        let want = (1.0 - mu_g_h * k).max(0.0);
        let s = &r.bodies[0];
        assert_close(&format!("A1 v_x at step {}", r.step), s.v.x, want, 1e-9);
        x += H * s.v.x;
        assert_close("A1 x", s.x.x, x, 1e-12);
        assert!(s.v.yz().amax() <= 1e-12 && s.w.amax() <= 1e-12);
        let offset = r.contacts[0].a1.x - s.x.x;
        if want > 0.0 {
            assert_close("A1 ECP offset while sliding", offset, 0.03, 1e-8);
        } else if r.step > 35 {
            assert_close("A1 ECP offset at rest", offset, 0.0, 1e-8);
        }
    }
    assert_eq!(recs.iter().filter(|r| r.bodies[0].v.x > 1e-9).count(), 34);
    assert_agrees_with_hull(
        &format!("A1 ({b:?})"),
        &recs,
        &run_hull(scenarios::a1_sliding()),
    );
}

#[test]
fn a1_sliding_newton() {
    a1_sliding(Backend::Newton);
}

#[test]
fn a1_sliding_path() {
    a1_sliding(Backend::Path);
}

fn a2_push(b: Backend) {
    // 40 N slides: v_x = 1.06 h k, ECP offset μ H.
    let recs = run_reduced(scenarios::a2_push(40.0), b);
    for r in &recs {
        let s = &r.bodies[0];
        assert_close("A2 40 N v_x", s.v.x, 1.06 * H * r.step as f64, 1e-9);
        assert_close("A2 40 N ECP offset", r.contacts[0].a1.x - s.x.x, 0.03, 1e-8);
    }
    // 20 N sticks: p_t = −F h, ECP offset H F / (m g).
    let recs = run_reduced(scenarios::a2_push(20.0), b);
    for r in &recs {
        let s = &r.bodies[0];
        assert!(s.v.amax() <= 1e-9 && s.w.amax() <= 1e-9, "A2 20 N moves");
        assert_close("A2 20 N p_t", r.contacts[0].pt, -20.0 * H, 1e-9);
        assert_close(
            "A2 20 N ECP offset",
            r.contacts[0].a1.x - s.x.x,
            0.1 * 20.0 / (10.0 * G),
            1e-8,
        );
    }
}

#[test]
fn a2_push_newton() {
    a2_push(Backend::Newton);
}

#[test]
fn a2_push_path() {
    a2_push(Backend::Path);
}

fn a3_spin(b: Backend) {
    let recs = run_reduced(scenarios::a3_spin(), b);
    let decel = 0.1 * 0.3 * 10.0 * G / (10.0 / 12.0 * (0.16 + 0.16));
    assert_close("A3 deceleration", decel, 11.025, 1e-12);
    for r in &recs {
        let want = (2.0 - decel * H * r.step as f64).max(0.0);
        let s = &r.bodies[0];
        let c = &r.contacts[0];
        assert_close(&format!("A3 ω_z at step {}", r.step), s.w.z, want, 1e-9);
        assert!(
            s.v.amax() <= 1e-12 && s.x.xy().amax() <= 1e-12,
            "A3 translates"
        );
        assert!(c.pt.abs() <= 1e-12 && c.po.abs() <= 1e-12);
        assert!(
            (c.a1 - s.x).xy().amax() <= 1e-12,
            "A3 ECP off the CM projection"
        );
    }
    assert_eq!(recs.iter().filter(|r| r.bodies[0].w.z > 1e-9).count(), 18);
    assert_agrees_with_hull(
        &format!("A3 ({b:?})"),
        &recs,
        &run_hull(scenarios::a3_spin()),
    );
}

#[test]
fn a3_spin_newton() {
    a3_spin(Backend::Newton);
}

#[test]
fn a3_spin_path() {
    a3_spin(Backend::Path);
}

fn a4_incline(b: Backend) {
    // 10° (tan θ < μ): the reduced model applies and stays on its sticking branch (σ = 0).
    let scene = scenarios::a4_incline(10.0);
    let x0 = scene.bodies[0].initial.x;
    let recs = run_reduced(scene.clone(), b);
    for r in &recs {
        let s = &r.bodies[0];
        assert!(s.v.amax() <= 1e-9 && s.w.amax() <= 1e-9, "A4 10° moves");
        assert!((s.x - x0).amax() <= 1e-9);
        assert!(
            r.contacts[0].sigma <= 1e-9,
            "A4 10° slides at step {}",
            r.step
        );
    }
    assert_agrees_with_hull(&format!("A4 10° ({b:?})"), &recs, &run_hull(scene));
    // 25°: slides down along (−cos θ, 0, −sin θ) with a = g (sin θ − μ cos θ).
    let th = 25f64.to_radians();
    let a = G * (th.sin() - 0.3 * th.cos());
    assert_close("A4 25° acceleration", a, 1.4771, 1e-4);
    let dir = Vector3::new(-th.cos(), 0.0, -th.sin());
    let scene = scenarios::a4_incline(25.0);
    let recs = run_reduced(scene.clone(), b);
    for r in &recs {
        let v = r.bodies[0].v;
        let want = dir * (a * H * r.step as f64);
        assert!(
            (v - want).amax() <= 1e-9,
            "A4 25° step {}: v = {v:?}",
            r.step
        );
    }
    assert_agrees_with_hull(&format!("A4 25° ({b:?})"), &recs, &run_hull(scene));
}

#[test]
fn a4_incline_newton() {
    a4_incline(Backend::Newton);
}

#[test]
fn a4_incline_path() {
    a4_incline(Backend::Path);
}

#[test]
fn a6_below_tipping_threshold_stays_flat() {
    let scene = scenarios::a6_tip(90.0);
    let recs = run_reduced(scene.clone(), Backend::Newton);
    for r in &recs {
        let s = &r.bodies[0];
        assert!(s.v.amax() <= 1e-9 && s.w.amax() <= 1e-9, "A6 90 N moves");
        assert_close(
            "A6 90 N ECP offset",
            r.contacts[0].a1.x - s.x.x,
            0.18367,
            1e-5,
        );
        assert_close(
            "A6 90 N ECP offset (discrete)",
            r.contacts[0].a1.x - s.x.x,
            0.2 * 90.0 / (10.0 * G),
            1e-9,
        );
    }
    assert_agrees_with_hull("A6 90 N", &recs, &run_hull(scene));
}

// ---------------------------------------------------------------------------------------------
// Refusals
// ---------------------------------------------------------------------------------------------

fn refused_at_construction(scene: Scene, words: &[&str]) {
    let name = scene.name.clone();
    match ReducedSliding::new(scene) {
        Err(SceneError::NotApplicable {
            formulation: Formulation::Reduced,
            step: None,
            reason,
        }) => {
            for w in words.iter().chain(&["hull formulation"]) {
                assert!(reason.contains(w), "{name}: reason '{reason}' lacks '{w}'");
            }
        }
        Err(e) => panic!("{name}: refused with the wrong error: {e}"),
        Ok(_) => panic!("{name}: not refused"),
    }
}

#[test]
fn a6_tipping_stops_where_the_hull_model_tips() {
    for b in [Backend::Newton, Backend::Path] {
        let (recs, err) = try_reduced(scenarios::a6_tip(110.0), b);
        let Some(SceneError::NotApplicable {
            formulation: Formulation::Reduced,
            step: Some(k),
            reason,
        }) = err
        else {
            panic!("A6 110 N ({b:?}): not refused: {err:?}");
        };
        assert!(reason.contains("tipping") && reason.contains("hull formulation"));
        assert_eq!(
            recs.len(),
            k - 1,
            "the steps before the refusal are recorded"
        );
        // The hull model: the step where the box leaves the flat patch contact and pitches.
        let hull = run_hull(scenarios::a6_tip(110.0));
        let tips = hull
            .iter()
            .find(|r| r.contacts[0].mode != ContactMode::Patch || r.bodies[0].w.y.abs() > 1e-9)
            .map(|r| r.step)
            .expect("the hull model tips at 110 N");
        assert_eq!(
            k, tips,
            "A6 110 N ({b:?}): refused at step {k}, the hull model tips at {tips}"
        );
        println!("A6 110 N ({b:?}): refused at step {k}: {reason}");
    }
}

#[test]
fn dropped_box_is_refused() {
    refused_at_construction(scenarios::a5_drop(), &["'none'", "face"]);
    refused_at_construction(scenarios::a5_drop_tilted(), &["'none'"]);
}

#[test]
fn two_bodies_and_two_planes_are_refused() {
    let mut scene = scenarios::a1_sliding();
    let mut other = scene.bodies[0].clone();
    other.initial.x.x += 1.0;
    other.name = "box2".into();
    scene.bodies.push(other);
    refused_at_construction(scene.clone(), &["one body", "2"]);
    scene.bodies.pop();
    scene
        .planes
        .push(HalfSpace::new(Vector3::x(), 5.0).expect("plane"));
    refused_at_construction(scene.clone(), &["2 half-spaces"]);
    scene.planes.clear();
    refused_at_construction(scene, &["0 half-spaces"]);
    match build_stepper(scenarios::a5_drop(), Formulation::Reduced) {
        Err(SceneError::NotApplicable { step: None, .. }) => {}
        Err(e) => panic!("build_stepper: wrong error {e}"),
        Ok(_) => panic!("build_stepper: A5 not refused"),
    }
}

#[test]
fn non_planar_or_unloaded_starts_are_refused() {
    let mut scene = scenarios::a1_sliding();
    scene.bodies[0].initial.v.z = -0.1;
    refused_at_construction(scene, &["normal"]);
    let mut scene = scenarios::a1_sliding();
    scene.bodies[0].initial.w.x = 0.2;
    refused_at_construction(scene, &["axis in the plane"]);
    let mut scene = scenarios::a1_sliding();
    scene.gravity = Vector3::zeros();
    refused_at_construction(scene, &["normal impulse"]);
    // Tilted by 5° about x: resting on an edge, not on a face.
    let mut scene = scenarios::a1_sliding();
    let q = ecp::formulations::rotation::quat_from_rpy_deg(5.0, 0.0, 0.0);
    let r = rotation_matrix(&q);
    let low = scene.bodies[0]
        .shape
        .vertices()
        .iter()
        .map(|v| (r * v).z)
        .fold(f64::INFINITY, f64::min);
    scene.bodies[0].initial.q = q;
    scene.bodies[0].initial.x.z = -low;
    refused_at_construction(scene, &["'line'"]);
    // Spin about the normal and sliding along an incline are fine.
    assert!(ReducedSliding::new(scenarios::a3_spin()).is_ok());
    assert!(ReducedSliding::new(scenarios::a4_incline(25.0)).is_ok());
}

#[test]
fn lift_off_stops_the_run() {
    // A vertical pull f_z = 400 t N: the normal impulse h (m g − f_z(t_u)) vanishes at
    // t_u = 98/400 = 0.245 s, the start of step 25.5, i.e. it is ≤ 0 first at step 26 (t_u = 0.25).
    let mut scene = scenarios::a1_sliding();
    scene.bodies[0].load = Load::Function(Arc::new(|t| {
        Vector6::new(0.0, 0.0, 400.0 * t, 0.0, 0.0, 0.0)
    }));
    let (recs, err) = try_reduced(scene, Backend::Newton);
    let Some(SceneError::NotApplicable {
        step: Some(k),
        reason,
        ..
    }) = err
    else {
        panic!("lift-off not refused: {err:?}");
    };
    assert_eq!(k, 26, "{reason}");
    assert_eq!(recs.len(), 25);
    assert!(reason.contains("lift-off") && reason.contains("hull formulation"));
}

// ---------------------------------------------------------------------------------------------
// Jacobians of the residual blocks
// ---------------------------------------------------------------------------------------------

fn plane() -> impl Strategy<Value = HalfSpace> {
    prop_oneof![
        Just(HalfSpace::ground()),
        (-0.8..0.8f64).prop_map(|th| HalfSpace::incline(th).expect("finite angle")),
        unit3().prop_map(|n| HalfSpace::new(n, 0.3).expect("non-zero normal")),
    ]
}

prop_compose! {
    /// Random step data with a loaded contact (p_n > 0) and random momenta, spin inertia (with
    /// tangential parts: inertia not symmetric about n) and friction (μ = 0 included).
    fn step_data()(
        g in plane(),
        mu in prop_oneof![Just(0.0), 0.01..1.5f64],
        e in (0.3..2.0f64, 0.3..2.0f64, 0.01..0.5f64),
        mass in 0.5..20.0f64,
        height in 0.01..1.0f64,
        pn in 0.01..5.0f64,
        tangential in vec3(-5.0, 5.0),
        spin in vec3(-1.0, 1.0),
        jn in 0.05..2.0f64,
        angular in vec3(-3.0, 3.0),
    ) -> SlidingStepData {
        let (n, t, o) = g.contact_frame();
        let tangential = tangential - n * n.dot(&tangential);
        SlidingStepData {
            frame: ContactFrame { n, t, o },
            friction: FrictionParams { mu, e_t: e.0, e_o: e.1, e_r: e.2 },
            mass,
            height,
            momentum: tangential - n * pn,
            spin_inertia: spin - n * n.dot(&spin) + n * jn,
            angular,
        }
    }
}

/// Checks every input of `block` (variables and the `friction` and `sliding` data).
///
/// The rows combine terms of size `size` (`μ p_n` and `‖E⁻¹ p_f‖`, up to 1e4 here; times the
/// row scale for the friction rows), so the round-off of the central differences is about
/// `ε size / step` (1e-5 for 1e4 at step 1e-6), beyond the plain absolute tolerance: it is
/// scaled by `1 + size`. At `μ = 0` the row scale
/// `1/(e_k² μ p_n)` of the friction rows jumps to 1 (`docs/model.md#reduced`), so their μ
/// column has no derivative there: `allow_mu` lets exactly that column fail.
fn check(
    block: &dyn ResidualBlock,
    params: &[&[f64]],
    size: f64,
    allow_mu: Option<usize>,
) -> Result<(), TestCaseError> {
    let opts = CheckOptions {
        abs_tol: CheckOptions::default().abs_tol * (1.0 + size),
        max_listed: 64,
        ..CheckOptions::default()
    };
    let report = check_residual_block(block, params, &opts)
        .map_err(|e| TestCaseError::fail(format!("{e}")))?;
    let cols: usize = block.parameter_sizes().iter().sum();
    prop_assert_eq!(report.entries, block.num_residuals() * cols);
    match allow_mu {
        Some(k) => {
            let others = report
                .worst
                .iter()
                .filter(|e| e.failed && (e.block, e.col) != (k, 0))
                .count();
            prop_assert!(others == 0, "{}", report);
        }
        None => prop_assert!(report.ok(), "{}", report),
    }
    Ok(())
}

/// The size of the terms of the ellipsoid row at `y` (see [`check`]).
fn row_size(data: &SlidingStepData, y: &[f64]) -> f64 {
    let p = data.point(y);
    let f = data.friction;
    let norm = (p.pf[0] / f.e_t)
        .hypot(p.pf[1] / f.e_o)
        .hypot(p.pf[2] / f.e_r);
    (f.mu * p.pn).abs() + norm
}

/// The size of the terms of the friction rows `w_k (c_k p_n s_k + p_k σ)` at `y` (see
/// [`check`]): the row scale `w_k = 1/(e_k² μ p_n)` reaches 1e8 for the smallest `e_r`, `μ` and
/// `p_n` drawn.
fn friction_size(data: &SlidingStepData, y: &[f64], sigma: f64) -> f64 {
    let p = data.point(y);
    let f = data.friction;
    let w = data.row_scales();
    let e = [f.e_t, f.e_o, f.e_r];
    // p_r = n·L − ρ_t p_o + ρ_o p_t cancels: its terms, not its value, set the round-off.
    let l = data.spin_inertia * y[2] - data.angular;
    let pr_terms =
        data.frame.n.dot(&l).abs() + (p.rho[0] * p.pf[1]).abs() + (p.rho[1] * p.pf[0]).abs();
    let pf = [p.pf[0].abs(), p.pf[1].abs(), pr_terms];
    (0..3)
        .map(|k| w[k] * ((e[k] * e[k] * f.mu * p.pn * p.slip[k]).abs() + pf[k] * sigma))
        .fold(row_size(data, y), f64::max)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn reduced_friction_jacobian(
        data in step_data(),
        y in vec3(-3.0, 3.0),
        sigma in prop_oneof![Just(0.0), 0.0..5.0f64],
    ) {
        let (friction, sliding) = (data.friction.values(), data.sliding_values());
        let allow_mu = (data.friction.mu == 0.0).then_some(ReducedFriction::FRICTION);
        check(
            &ReducedFriction { frame: data.frame },
            &[y.as_slice(), &[sigma], &friction, &sliding],
            friction_size(&data, y.as_slice(), sigma),
            allow_mu,
        )?;
    }

    #[test]
    fn reduced_ellipsoid_jacobian(data in step_data(), y in vec3(-3.0, 3.0)) {
        let (friction, sliding) = (data.friction.values(), data.sliding_values());
        check(
            &ReducedEllipsoid { frame: data.frame },
            &[y.as_slice(), &friction, &sliding],
            row_size(&data, y.as_slice()),
            None,
        )?;
    }

    /// The eliminated quantities satisfy the Newton–Euler equations of `docs/model.md#newton-euler`
    /// with `v = v_t t + v_o o`, `ω = ω_n n` and the ECP `r = −H n + ρ_t t + ρ_o o`.
    #[test]
    fn eliminated_impulses_satisfy_newton_euler(data in step_data(), y in vec3(-3.0, 3.0)) {
        let p = data.point(y.as_slice());
        let ContactFrame { n, t, o } = data.frame;
        let v = t * y[0] + o * y[1];
        let f = n * p.pn + t * p.pf[0] + o * p.pf[1];
        let lin = v * data.mass - data.momentum - f;
        let r = n * (-data.height) + t * p.rho[0] + o * p.rho[1];
        let ang = data.spin_inertia * y[2] - data.angular - r.cross(&f) - n * p.pf[2];
        let scale = 1.0 + data.momentum.amax() + data.angular.amax() + f.amax() * (1.0 + r.amax());
        prop_assert!(lin.amax() <= 1e-12 * scale, "linear balance off by {}", lin.amax());
        prop_assert!(ang.amax() <= 1e-12 * scale, "moment balance off by {}", ang.amax());
    }
}
