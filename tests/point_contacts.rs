//! The point-contact baseline (`docs/model.md#point-contacts`, `ecp::formulations::point`) against
//! the ECP model (the paper's hull formulation) on the scenarios of `docs/model.md#scenarios`:
//!
//! - every residual block of the point model is checked against central differences with the
//!   model's Jacobian checker, on random states (proptest) and on the assembled step MCPs;
//! - A1: the point model decelerates by μ g h per step like the ECP model (to 1e-9), and the
//!   centre of pressure of its corner impulses is the ECP (to 1e-8); the load split among the
//!   four corners is not unique (a second solution is exhibited, and the split a solver returns
//!   depends on its starting point), only its pair sums are;
//! - the artefact the paper argues about: with the gap linearised at the start of the step, a
//!   spinning tilted drop ends steps with a vertex below the plane (the hull model: ≤ 1e-9), and
//!   in A6 at 110 N the pivot edge carries load across a gap;
//! - the desk: the point model (16 foot corners among its 36 vertices) runs, carries the weight
//!   on the feet only, and its difference from the ECP model is reported.

mod common;

use common::strategies::{unit_quat, unit3, vec3};

use ecp::backends::{SolverConfig, make_solver};
use ecp::formulations::blocks::{
    BodyStepData, ContactFrame, FrictionParams, inertia_entries, start_values,
};
use ecp::formulations::geometry::{ContactMode, HalfSpace};
use ecp::formulations::point::{
    POINT_GEOMETRY, PointContacts, PointFrictionDissipation, PointFrictionEllipsoid,
    PointNewtonEuler, PointNonPenetration, PointWrenches, centre_of_pressure,
};
use ecp::formulations::record::penetration;
use ecp::formulations::rotation::{kinematic_map, rotation_matrix};
use ecp::formulations::scenarios;
use ecp::formulations::{Scene, SceneError, Simulation, StepRecord};
use ecp::model::VarId;
use ecp::model::{
    CheckOptions, McpSolver, ResidualBlock, check_problem, check_residual_block, residual_of,
};
use nalgebra::{Matrix3, Vector3, Vector6};
use proptest::prelude::*;

type V3 = Vector3<f64>;

/// `scene` stepped by the point formulation.
fn point_sim(scene: Scene) -> Result<Simulation, SceneError> {
    Simulation::builder(scene)
        .formulation(Box::new(PointContacts::new()))
        .build()
}

/// `scene` stepped by the point formulation with the contact points `points`.
fn point_sim_with(scene: Scene, points: Vec<Vec<V3>>) -> Result<Simulation, SceneError> {
    Simulation::builder(scene)
        .formulation(Box::new(PointContacts::with_points(points)))
        .build()
}

/// The point formulation of `sim`.
fn point_of(sim: &Simulation) -> &PointContacts {
    sim.formulation_as::<PointContacts>()
        .expect("the point formulation")
}

/// Body `b`'s `ν` and `q` blocks.
fn body_vars(sim: &Simulation, b: usize) -> (VarId, VarId) {
    let h = &sim.handles().bodies[b];
    (h.nu.expect("ν"), h.q.expect("q"))
}

const G: f64 = 9.8;
const H: f64 = 0.01;

// ---------------------------------------------------------------------------------------------
// Jacobians
// ---------------------------------------------------------------------------------------------

fn half_space() -> impl Strategy<Value = HalfSpace> {
    prop_oneof![
        Just(HalfSpace::ground()),
        (-0.8..0.8f64).prop_map(|th| HalfSpace::incline(th).expect("finite angle")),
        (unit3(), -1.0..1.0f64).prop_map(|(n, c)| HalfSpace::new(n, c).expect("unit normal")),
    ]
}

fn frame_of(g: &HalfSpace) -> ContactFrame {
    let (n, t, o) = g.contact_frame();
    ContactFrame { n, t, o }
}

/// Impulse-like value that is exactly 0 a good share of the time.
fn maybe_zero(hi: f64) -> impl Strategy<Value = f64> {
    prop_oneof![Just(0.0), 0.0..hi]
}

/// One point's data: lever arm, half-space, `p_n`, `(p_t, p_o)` (exactly 0 sometimes), σ.
#[derive(Clone, Debug)]
struct PointDraw {
    r: V3,
    plane: HalfSpace,
    pn: f64,
    pf: [f64; 2],
    sigma: f64,
}

fn point_draw() -> impl Strategy<Value = PointDraw> {
    (
        vec3(-1.0, 1.0),
        half_space(),
        maybe_zero(20.0),
        prop_oneof![
            Just([0.0, 0.0]),
            (-5.0..5.0f64, -5.0..5.0f64).prop_map(|(a, b)| [a, b])
        ],
        maybe_zero(5.0),
    )
        .prop_map(|(r, plane, pn, pf, sigma)| PointDraw {
            r,
            plane,
            pn,
            pf,
            sigma,
        })
}

/// A random body state with up to three points.
#[derive(Clone, Debug)]
struct Case {
    nu: [f64; 6],
    nu_start: [f64; 6],
    impulse: [f64; 6],
    mass: f64,
    inertia: V3,
    q_start: nalgebra::Vector4<f64>,
    gap: f64,
    h: f64,
    friction: FrictionParams,
    points: Vec<PointDraw>,
}

fn six(lo: f64, hi: f64) -> impl Strategy<Value = [f64; 6]> {
    (vec3(lo, hi), vec3(lo, hi)).prop_map(|(a, b)| [a.x, a.y, a.z, b.x, b.y, b.z])
}

fn case() -> impl Strategy<Value = Case> {
    (
        (six(-3.0, 3.0), six(-3.0, 3.0), six(-5.0, 5.0)),
        (0.5..20.0f64, vec3(0.01, 2.0), unit_quat()),
        (
            prop_oneof![Just(0.0), -1e-3..1.0f64],
            prop_oneof![Just(0.01), 1e-3..0.05f64],
        ),
        (maybe_zero(1.5), 0.5..2.0f64, 0.5..2.0f64),
        prop::collection::vec(point_draw(), 1..4),
    )
        .prop_map(
            |(
                (nu, nu_start, impulse),
                (mass, inertia, q_start),
                (gap, h),
                (mu, e_t, e_o),
                points,
            )| {
                Case {
                    nu,
                    nu_start,
                    impulse,
                    mass,
                    inertia,
                    q_start,
                    gap,
                    h,
                    friction: FrictionParams {
                        mu,
                        e_t,
                        e_o,
                        e_r: 0.1,
                    },
                    points,
                }
            },
        )
}

/// Checks `block` at `params` with the default options: every entry compared, all within
/// tolerance.
fn check(block: &dyn ResidualBlock, params: &[&[f64]]) -> Result<(), TestCaseError> {
    let report = check_residual_block(block, params, &CheckOptions::default())
        .map_err(|e| TestCaseError::fail(format!("checker rejected {}: {e}", block.name())))?;
    let cols: usize = block.parameter_sizes().iter().sum();
    prop_assert_eq!(report.entries, block.num_residuals() * cols);
    prop_assert!(report.ok(), "{}", report);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Newton–Euler with one to three points (wrenches of real contact frames), the linearised
    /// non-penetration, the friction rows and the friction ellipse of every point, at random
    /// states with `p_n = 0`, `p_f = 0` and `σ = 0` among them.
    #[test]
    fn point_blocks_match_central_differences(case in case()) {
        let wrenches: Vec<PointWrenches> = case
            .points
            .iter()
            .map(|p| PointWrenches::new(&p.r, &frame_of(&p.plane)))
            .collect();
        let pns: Vec<[f64; 1]> = case.points.iter().map(|p| [p.pn]).collect();
        let sigmas: Vec<[f64; 1]> = case.points.iter().map(|p| [p.sigma]).collect();
        // Mass matrix and gyroscopic impulse at the end of the step: the block reads the
        // configuration q (7); its end orientation is the start one turned by the kinematic map.
        let body = BodyStepData {
            mass: case.mass,
            inertia: Matrix3::from_diagonal(&case.inertia),
            q_start: case.q_start,
            nu_start: Vector6::from_row_slice(&case.nu_start),
            wrench: Vector6::from_row_slice(&case.impulse),
            gravity: Vector3::new(0.0, 0.0, -9.8),
            h: case.h,
        };
        let q_end = case.q_start
            + kinematic_map(&case.q_start) * Vector3::new(case.nu[3], case.nu[4], case.nu[5])
                * (0.5 * case.h);
        let q = [0.1, -0.2, 0.3, q_end[0], q_end[1], q_end[2], q_end[3]];
        let nu0 = &case.nu_start;
        let start = start_values(
            &V3::new(0.1, 0.2, 0.3),
            &case.q_start,
            &V3::new(nu0[0], nu0[1], nu0[2]),
            &V3::new(nu0[3], nu0[4], nu0[5]),
        );
        let (mass, inertia, gravity, h) =
            ([body.mass], inertia_entries(&body.inertia), [0.0, 0.0, -9.8], [case.h]);
        let geometry: Vec<[f64; POINT_GEOMETRY]> =
            wrenches.iter().map(|w| w.geometry_values(case.gap)).collect();
        let mut params: Vec<&[f64]> =
            vec![&case.nu, &q, &mass, &inertia, &start, &case.impulse, &gravity, &h];
        for ((p, pn), g) in case.points.iter().zip(&pns).zip(&geometry) {
            params.push(pn);
            params.push(&p.pf);
            params.push(g);
        }
        check(&PointNewtonEuler::new(case.points.len()), &params)?;
        let friction = case.friction.values();
        for ((p, g), (pn, sigma)) in case.points.iter().zip(&geometry).zip(pns.iter().zip(&sigmas)) {
            check(&PointNonPenetration, &[&case.nu, g, &h])?;
            check(&PointFrictionDissipation, &[&case.nu, pn, &p.pf, sigma, g, &friction])?;
            check(&PointFrictionEllipsoid, &[pn, &p.pf, &friction])?;
        }
    }
}

/// The wrenches are those of `docs/model.md#newton-euler` at the point: `W_n = [n; r × n]`, and the
/// three directions are orthonormal in their force parts.
#[test]
fn point_wrenches_are_the_contact_wrenches() {
    let g = HalfSpace::incline(0.3).expect("finite angle");
    let f = frame_of(&g);
    let r = V3::new(0.2, -0.1, -0.3);
    let w = PointWrenches::new(&r, &f);
    for (col, d) in [(w.normal, f.n), (w.t, f.t), (w.o, f.o)] {
        let force = col.fixed_rows::<3>(0).into_owned();
        let moment = col.fixed_rows::<3>(3).into_owned();
        assert!((force - d).norm() < 1e-15);
        assert!((moment - r.cross(&d)).norm() < 1e-15);
    }
}

/// The A1 box with a second half-space (a tilted wall): every point has two contacts, so
/// Newton–Euler reads 16 point impulses.
fn two_plane_scene() -> Scene {
    let mut scene = scenarios::a1_sliding();
    scene.name = "box_and_wall".into();
    scene
        .planes
        .push(HalfSpace::new(V3::new(-1.0, 0.2, 0.3), -0.5).expect("non-zero normal"));
    scene
}

fn point_scenes() -> Vec<Scene> {
    vec![
        scenarios::a1_sliding(),
        scenarios::a4_incline(25.0),
        scenarios::a5_drop_tilted(),
        scenarios::a6_tip(110.0),
        scenarios::desk(),
        two_plane_scene(),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

    /// Every residual block of the assembled point-contact MCP of several scenes, at random
    /// perturbations of the first step's warm start.
    #[test]
    fn assembled_point_mcp_matches_central_differences(
        noise in prop::collection::vec(-1.0..1.0f64, 160),
        scale in prop_oneof![Just(1e-3), 0.01..0.5f64],
    ) {
        for scene in point_scenes() {
            let name = scene.name.clone();
            let mut pc = point_sim(scene).expect("valid scene");
            pc.prepare_step().expect("step data");
            let mut z = pc.z().to_vec();
            prop_assert!(z.len() <= noise.len(), "{}: {} unknowns", name, z.len());
            for (zi, d) in z.iter_mut().zip(&noise) {
                *zi += scale * d * (1.0 + zi.abs());
            }
            let reports = check_problem(pc.mcp(), &z, &CheckOptions::default());
            prop_assert_eq!(reports.len(), pc.mcp().num_residual_blocks());
            for rep in &reports {
                prop_assert!(rep.ok(), "{}:\n{}", name, rep);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Runs
// ---------------------------------------------------------------------------------------------

fn solver(kind: &str) -> Box<dyn McpSolver> {
    make_solver(&SolverConfig {
        name: kind.into(),
        ..SolverConfig::default()
    })
    .expect("backend available")
}

/// Runs `stepper` for at most `steps` steps; every step must converge to ≤ 1e-10.
fn run(stepper: &mut Simulation, kind: &str, steps: usize) -> Vec<StepRecord> {
    let name = format!(
        "{} ({}, {kind})",
        stepper.scene().name,
        stepper.formulation_name()
    );
    let mut s = solver(kind);
    let mut records = Vec::new();
    while !stepper.finished() && records.len() < steps {
        let rec = stepper.step(s.as_mut()).expect("step set up");
        assert!(
            rec.converged && rec.summary.residual <= 1e-10,
            "{name}: step {} did not converge: {:?} residual {:.3e}",
            rec.step,
            rec.summary.termination,
            rec.summary.residual
        );
        records.push(rec);
    }
    records
}

fn run_point(scene: Scene, kind: &str, steps: usize) -> Vec<StepRecord> {
    run(&mut point_sim(scene).expect("valid scene"), kind, steps)
}

fn run_hull(scene: Scene, kind: &str, steps: usize) -> Vec<StepRecord> {
    run(
        &mut Simulation::new(scene).expect("valid scene"),
        kind,
        steps,
    )
}

fn max_penetration(records: &[StepRecord]) -> f64 {
    records.iter().map(penetration).fold(0.0, f64::max)
}

fn assert_close(what: &str, got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "{what}: got {got:.15}, want {want:.15} (tolerance {tol:e})"
    );
}

// ---------------------------------------------------------------------------------------------
// Records and set-up
// ---------------------------------------------------------------------------------------------

/// One record per (point, plane), body-major; `a1 = a2` the point at the step end, `lg` its
/// gap, no torsional impulse; `min_gap` the smallest point gap; built by name.
#[test]
fn records_have_one_contact_per_point() {
    let mut stepper =
        Simulation::with_formulation(scenarios::a1_sliding(), "point").expect("point stepper");
    assert_eq!(stepper.formulation_name(), "point");
    assert_eq!(stepper.contacts_per_body(), 8);
    let mut s = solver("newton");
    let rec = stepper.step(s.as_mut()).expect("step");
    assert_eq!(rec.contacts.len(), 8);
    let state = stepper.state(0);
    let r = rotation_matrix(&state.q);
    let pc = point_of(&stepper);
    let min_lg = rec
        .contacts
        .iter()
        .map(|c| c.lg)
        .fold(f64::INFINITY, f64::min);
    for (c, b) in rec.contacts.iter().zip(pc.points(0)) {
        assert!((c.a1 - (state.x + r * b)).norm() < 1e-15);
        assert_eq!(c.a1, c.a2);
        assert_close("gap", c.lg, c.a1.z, 1e-15);
        assert_eq!(c.pr, 0.0);
        assert_eq!(c.min_gap, min_lg);
        assert_eq!(c.mode, ContactMode::Patch);
    }
    let header = StepRecord::csv_header(1, stepper.contacts_per_body());
    assert_eq!(header.len(), rec.csv_fields().len());

    let desk = point_sim(scenarios::desk()).expect("valid desk");
    assert_eq!(desk.contacts_per_body(), 36, "the desk's 36 piece vertices");
    let feet = point_of(&desk)
        .points(0)
        .iter()
        .filter(|p| (p.z + 0.45).abs() < 1e-12)
        .count();
    assert_eq!(feet, 16, "16 foot corners");
}

/// The report helpers on hand-made records: the centre of pressure is the p_n-weighted mean of
/// the points (none without load), the penetration the deepest vertex (0 when all are above).
#[test]
fn centre_of_pressure_and_penetration_helpers() {
    let mut rec = run_point(scenarios::a1_sliding(), "newton", 1).remove(0);
    for c in rec.contacts.iter_mut() {
        c.pn = 0.0;
        c.min_gap = 0.0;
    }
    assert_eq!(centre_of_pressure(&rec.contacts), None);
    rec.contacts[0].pn = 1.0;
    rec.contacts[1].pn = 3.0;
    let (a, b) = (rec.contacts[0].a1, rec.contacts[1].a1);
    let cop = centre_of_pressure(&rec.contacts).expect("loaded");
    assert!((cop - (a + b * 3.0) / 4.0).norm() < 1e-15);
    assert_eq!(penetration(&rec), 0.0);
    rec.contacts[2].min_gap = -2e-3;
    rec.contacts[3].min_gap = -1e-3;
    assert_eq!(penetration(&rec), 2e-3);
}

#[test]
fn bad_set_up_is_refused_with_a_reason() {
    let mut scene = scenarios::a1_sliding();
    scene.bodies[0].initial.x.z = 0.05;
    match point_sim(scene) {
        Err(SceneError::InitialPenetration { depth, .. }) => {
            assert_close("depth", depth, 0.05, 1e-12)
        }
        other => panic!(
            "expected an initial-penetration error, got {:?}",
            other.err()
        ),
    }
    let err = point_sim_with(scenarios::a1_sliding(), vec![])
        .err()
        .expect("no point set");
    assert!(
        err.to_string()
            .contains("one list of contact points per body"),
        "{err}"
    );
    let err = point_sim_with(
        scenarios::a1_sliding(),
        vec![vec![V3::new(f64::NAN, 0.0, 0.0)]],
    )
    .err()
    .expect("NaN point");
    assert!(err.to_string().contains("finite"), "{err}");
    let mut scene = scenarios::a1_sliding();
    scene.friction.e_t = 0.0;
    let err = point_sim(scene).err().expect("e_t = 0");
    assert!(err.to_string().contains("e_t"), "{err}");
}

// ---------------------------------------------------------------------------------------------
// A1: same motion, centre of pressure = ECP, non-unique split
// ---------------------------------------------------------------------------------------------

/// Corners of the A1 box's bottom face: their contact indices, and the sign `s_i = sign(x_i y_i)`
/// of the "diagonal" load mode, which changes no force and no moment
/// (`Σ s_i = Σ s_i x_i = Σ s_i y_i = 0`).
fn bottom_corners(pc: &Simulation) -> Vec<(usize, f64)> {
    point_of(pc)
        .points(0)
        .iter()
        .enumerate()
        .filter(|(_, b)| b.z < 0.0)
        .map(|(i, b)| (i, (b.x * b.y).signum()))
        .collect()
}

/// Scenario A1 with Newton and PATH against the ECP model with Newton: `v_x^k = 1 − μ g h k` to 1e-9 while sliding, 0 after (to 1e-8, see
/// below); the centre of
/// pressure of the corner impulses equals the ECP model's ECP to 1e-8 at every step (measured:
/// 5e-11), and the front pair carries `N (1/2 + μ H / L) = 0.5635` N s of `N = m g h = 0.98`
/// (moment balance: `(front − rear) L/2 = N μ H`), left and right pairs `N/2` each, to 1e-9.
#[test]
fn a1_point_model_decelerates_like_the_ecp_model() {
    let hull = run_hull(scenarios::a1_sliding(), "newton", usize::MAX);
    for kind in ["newton", "path"] {
        a1_against_hull(kind, &hull);
    }
}

fn a1_against_hull(kind: &str, hull: &[StepRecord]) {
    let points = run_point(scenarios::a1_sliding(), kind, usize::MAX);
    assert_eq!(points.len(), 50);
    let n_total = 10.0 * G * H;
    let mut stopped = false;
    let mut worst_cop: f64 = 0.0;
    for (p, e) in points.iter().zip(hull) {
        let analytic = 1.0 - 0.3 * G * H * p.step as f64;
        stopped |= analytic < 0.0;
        let vx = if stopped { 0.0 } else { analytic };
        let b = &p.bodies[0];
        // At rest σ = 0, and a friction-row residual of 1e-10 allows a slip of
        // 1e-10 / (μ e² p_n) ≈ 1.4e-9 m/s per corner (p_n ≈ 0.245 N s): 1e-8 there.
        let tol = if stopped { 1e-8 } else { 1e-9 };
        assert_close(&format!("A1 point v_x, step {}", p.step), b.v.x, vx, tol);
        // A residual of 1e-10 in a corner's friction row allows a slip error of
        // 1e-10 / (μ e² p_n) ≈ 1.7e-9 m/s (p_n ≈ 0.2 N s), i.e. |ω| up to ~1e-8 rad/s.
        assert!(
            b.w.norm() <= 1e-8 && b.v.z.abs() <= 1e-9,
            "step {}: A1 point model rotates or lifts: ω {:?}, v_z {:.3e}",
            p.step,
            b.w,
            b.v.z
        );
        let cop = centre_of_pressure(&p.contacts).expect("loaded");
        let ecp = e.contacts[0].a1;
        worst_cop = worst_cop.max((cop - ecp).norm());
        assert!(
            (cop - ecp).norm() <= 1e-8,
            "step {}: centre of pressure {cop:?} vs ECP {ecp:?}",
            p.step
        );
        let pair = |f: &dyn Fn(&V3) -> bool| -> f64 {
            p.contacts
                .iter()
                .filter(|c| f(&(c.a1 - b.x)))
                .map(|c| c.pn)
                .sum()
        };
        assert_close("total normal impulse", pair(&|_| true), n_total, 1e-9);
        assert_close("left pair", pair(&|r| r.y > 0.0), n_total / 2.0, 1e-9);
        if !stopped {
            assert_close("front pair", pair(&|r| r.x > 0.0), 0.5635, 1e-9);
            assert_close(
                "front pair (formula)",
                pair(&|r| r.x > 0.0),
                n_total * (0.5 + 0.3 * 0.1 / 0.4),
                1e-9,
            );
        }
    }
    assert!(stopped, "A1 never came to rest");
    println!("A1 ({kind}): max |centre of pressure − ECP| = {worst_cop:.3e} m");
    let first = &points[0].contacts;
    let split: Vec<String> = first
        .iter()
        .filter(|c| c.a1.z.abs() < 1e-9)
        .map(|c| {
            format!(
                "({:+.1}, {:+.1}): {:.5}",
                c.a1.x - points[0].bodies[0].x.x,
                c.a1.y,
                c.pn
            )
        })
        .collect();
    println!("A1 step 1 corner impulses ({kind}): {}", split.join(", "));
}

/// The corner split of one A1 step is not unique. From a Newton solution of step 1, moving
/// `α = 0.1` N s along the diagonal mode `s_i` (with each corner's friction impulse scaled with
/// its `p_n`, which keeps its friction rows) gives another point with natural residual ≤ 1e-10
/// and the same ν: a second solution of the same MCP. A solver started from the other split
/// ends at another split (measured: Newton moves a corner by 0.208 N s, unloading it; PATH keeps
/// the shifted split, 0.1 N s; asserted > 0.05), with the same motion to 1e-9.
#[test]
fn a1_corner_split_is_not_unique() {
    let mut pc = point_sim(scenarios::a1_sliding()).expect("valid");
    pc.prepare_step().expect("step data");
    let warm = pc.z().to_vec();
    let corners = bottom_corners(&pc);
    assert_eq!(corners.len(), 4);
    let mcp = pc.mcp();
    let (nu, _) = body_vars(&pc, 0);
    let nu_range = mcp.range(nu);
    let pn_of = |z: &[f64], i: usize| z[mcp.range(point_of(&pc).contacts()[i].pn)][0];

    // Solved tighter than the default 1e-10: shifting the split scales a corner's friction rows
    // (and their residual) by up to (p_n + α)/p_n ≈ 1.5.
    let mut newton = make_solver(&SolverConfig {
        name: "newton".into(),
        tolerance: Some(1e-13),
        ..SolverConfig::default()
    })
    .expect("backend available");
    let first = newton.solve(mcp, &warm).expect("step 1 converges to 1e-13");
    assert!(residual_of(mcp, &first.z) <= 1e-13);

    // The diagonal mode: a second exact solution.
    let alpha = 0.1;
    let shift = |z: &[f64]| -> Vec<f64> {
        let mut z = z.to_vec();
        for &(i, s) in &corners {
            let c = point_of(&pc).contacts()[i];
            let pn = z[mcp.range(c.pn)][0];
            let k = (pn + alpha * s) / pn;
            z[mcp.range(c.pn)][0] = pn + alpha * s;
            for v in &mut z[mcp.range(c.pf)] {
                *v *= k;
            }
        }
        z
    };
    let second = shift(&first.z);
    let r2 = residual_of(mcp, &second);
    assert!(r2 <= 1e-10, "shifted split has residual {r2:.3e}");
    for &(i, s) in &corners {
        assert_close(
            "shifted p_n",
            pn_of(&second, i) - pn_of(&first.z, i),
            alpha * s,
            1e-15,
        );
        assert!(pn_of(&second, i) > 0.05, "the shifted split stays feasible");
    }

    // Started from the shifted split, both backends stay near it: same ν, different split.
    let start = shift(&warm);
    for kind in ["newton", "path"] {
        let sol = solver(kind)
            .solve(mcp, &start)
            .expect("converges from the shifted start");
        assert!(residual_of(mcp, &sol.z) <= 1e-10);
        for k in nu_range.clone() {
            assert_close(&format!("{kind}: ν[{k}]"), sol.z[k], first.z[k], 1e-9);
        }
        let diff = corners
            .iter()
            .map(|&(i, _)| (pn_of(&sol.z, i) - pn_of(&first.z, i)).abs())
            .fold(0.0, f64::max);
        println!("{kind} from the shifted start: max corner p_n difference {diff:.4e} N s");
        assert!(
            diff > 0.05,
            "{kind}: the split did not follow the start ({diff:.3e})"
        );
    }
}

/// Scenario A3 (spinning in place) on the four corners: a point has no torsional friction, so
/// the spin is braked by the corners' sliding friction at their lever arm `|r| = 0.2√2` m instead
/// of the ellipsoid's `e_r = 0.1` m: `ω_z^k = 2 − (μ m g |r| / I_zz) h k` (deceleration
/// 31.18 rad/s², 2.83 times the ECP model's 11.025) until it would change sign, then 0; no
/// translation. The same lever-arm effect makes the desk's point model spin down faster than
/// the ECP model (`desk_point_model_first_second`).
#[test]
fn a3_point_model_brakes_the_spin_by_corner_friction() {
    let izz: f64 = 10.0 / 12.0 * (0.16 + 0.16);
    let lever = 0.2 * 2f64.sqrt();
    let decel = 0.3 * 10.0 * G * lever / izz;
    assert_close("A3 point-model deceleration", decel, 31.18, 5e-3);
    let mut stopped = false;
    for kind in ["newton", "path"] {
        for r in run_point(scenarios::a3_spin(), kind, usize::MAX) {
            let analytic = 2.0 - decel * H * r.step as f64;
            stopped = analytic < 0.0;
            let b = &r.bodies[0];
            // As in A1: 1e-8 at rest, where σ = 0 and a friction-row residual of 1e-10
            // allows a slip of ~1e-9 m/s.
            let (wz, tol) = if stopped {
                (0.0, 1e-8)
            } else {
                (analytic, 1e-9)
            };
            assert_close(
                &format!("A3 point ω_z ({kind}), step {}", r.step),
                b.w.z,
                wz,
                tol,
            );
            assert!(b.v.norm() <= 1e-8, "A3 point model translates: {}", b.v);
        }
    }
    assert!(stopped, "A3 point model never stopped spinning");
}

// ---------------------------------------------------------------------------------------------
// The artefacts of the linearised gap
// ---------------------------------------------------------------------------------------------

/// The A5 tilted drop spinning about the vertical at `w_z` rad/s.
fn spinning_tilted_drop(w_z: f64) -> Scene {
    let mut scene = scenarios::a5_drop_tilted();
    scene.name = format!("a5_drop_tilted_spin_{w_z}");
    scene.bodies[0].initial.w = V3::new(0.0, 0.0, w_z);
    scene
}

/// The tilted A5 drop spinning at ω_z = 10 rad/s: the ECP model (PATH) keeps every vertex above
/// −1e-9; the point model ends steps with a vertex up to 4.68e-4 m below the plane with both
/// backends (measured; asserted ≥ 4e-4 m, i.e. a margin of 4e-4 m over the hull model). At the
/// worst step the offending vertex's LINEARISED end gap `g + h W_nᵀν` is ≥ −1e-9 (the solver
/// met the model), and the penetration is the linearisation error of the rotation, bounded by
/// `((1 − cos θ') + (θ − sin θ')) |r|` with `θ = h|ω|`, `θ' = 2 atan(θ/2)` (the angle of the
/// quaternion update). A vertex moves towards the rotation axis through the CM, so it ends below
/// its linear prediction only when ω is tilted from the normal: the plain tilted drop and the
/// A6 tipping (ω parallel to the plane) show no penetration (≤ 1e-9, asserted).
#[test]
fn linearised_gap_lets_a_spinning_vertex_go_below_the_plane() {
    let scene = spinning_tilted_drop(10.0);
    let hull = run_hull(scene.clone(), "path", usize::MAX);
    let hull_pen = max_penetration(&hull);
    assert!(hull_pen <= 1e-9, "hull model penetrates {hull_pen:.3e}");
    for kind in ["newton", "path"] {
        let point = run_point(scene.clone(), kind, usize::MAX);
        let (worst, pen) = point
            .iter()
            .enumerate()
            .map(|(k, r)| (k, penetration(r)))
            .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        println!(
            "spinning tilted drop ({kind}): point penetration {pen:.4e} m at step {}, hull {hull_pen:.3e} m",
            worst + 1
        );
        assert!(
            pen >= 4e-4 && pen - hull_pen >= 4e-4,
            "{kind}: point penetration {pen:.3e}"
        );
        assert!(worst > 0, "the first step starts from the given state");
        // The offending vertex, from the start state of its step and the solved ν.
        let start = point[worst - 1].bodies[0];
        let end = point[worst].bodies[0];
        let pc = point_sim(scene.clone()).expect("valid");
        let c = point[worst]
            .contacts
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.lg.total_cmp(&b.1.lg))
            .map(|(i, _)| i)
            .expect("contacts");
        let r = rotation_matrix(&start.q) * point_of(&pc).points(0)[c];
        let n = V3::z();
        let g0 = (start.x + r).z;
        let linearised = g0 + H * (n.dot(&end.v) + r.cross(&n).dot(&end.w));
        assert!(
            linearised >= -1e-9,
            "{kind}: linearised gap {linearised:.3e}"
        );
        let theta = H * end.w.norm();
        let theta_q = 2.0 * (theta / 2.0).atan();
        let bound = ((1.0 - theta_q.cos()) + (theta - theta_q.sin())) * r.norm();
        let err = linearised - point[worst].contacts[c].lg;
        assert!(
            err <= bound + 1e-12,
            "{kind}: linearisation error {err:.3e} above its bound {bound:.3e}"
        );
    }
    for scene in [scenarios::a5_drop_tilted(), scenarios::a6_tip(110.0)] {
        let pen = max_penetration(&run_point(scene.clone(), "path", usize::MAX));
        assert!(
            pen <= 1e-9,
            "{}: point model penetrates {pen:.3e}",
            scene.name
        );
    }
}

/// A6 at 110 N: both models tip over the front edge. The ECP model keeps the ECP on the plane
/// (`|a1_z| ≤ 1e-12`, no vertex below −1e-9) while it carries load. The point model's pivot
/// corners carry load (p_n > 0.1 N s) across a growing gap: the curvature of the rotation lifts
/// them above their linearised position, up to 5.10e-4 m (measured with PATH; asserted
/// ≥ 4.5e-4 m), and the pivot's load is transmitted through the air.
#[test]
fn a6_point_model_carries_load_across_a_gap() {
    let point = run_point(scenarios::a6_tip(110.0), "path", usize::MAX);
    let hull = run_hull(scenarios::a6_tip(110.0), "path", usize::MAX);
    let mut gap_under_load: f64 = 0.0;
    for (p, e) in point.iter().zip(&hull) {
        for c in &p.contacts {
            if c.pn > 0.1 {
                gap_under_load = gap_under_load.max(c.lg);
            }
        }
        let c = &e.contacts[0];
        if c.pn > 0.0 {
            assert!(
                c.a1.z.abs() <= 1e-12,
                "hull ECP off the plane: {:.3e}",
                c.a1.z
            );
            assert!(
                c.min_gap >= -1e-9 && c.min_gap <= 1e-9,
                "hull gap {:.3e}",
                c.min_gap
            );
        }
    }
    println!("A6 110 N: largest gap of a point carrying > 0.1 N s: {gap_under_load:.4e} m");
    assert!(
        gap_under_load >= 4.5e-4,
        "gap under load {gap_under_load:.3e}"
    );
    // Both tip: pitch rate grows past 5 rad/s by t = 0.45 s.
    assert!(point[44].bodies[0].w.y > 5.0 && hull[44].bodies[0].w.y > 5.0);
}

// ---------------------------------------------------------------------------------------------
// The desk
// ---------------------------------------------------------------------------------------------

/// When the body turns while it slides, the corners slip in different directions, so the
/// friction wrench depends on how the load is split, and the split is not unique: neither is
/// the motion. The desk's first step, solved from the same warm start by Newton (without its
/// Josephy–Newton steps, which find PATH's member) and by PATH:
/// both converge (≤ 1e-10) but their ω_z differ by 1.5e-4 rad/s (measured; asserted > 1e-5),
/// far beyond what a residual of 1e-10 allows (~1e-9). Which member Newton reaches depends on
/// its path: 9.9e-3 when this test was written, 2.1e-3 before Newton's minimum-norm step ran
/// above 120 unknowns (this problem has 157; `docs/stress.md`, branch wip-heldout4). The ECP model has one contact and one
/// friction law per patch, and its two backends agree to 1e-13 (example `point_vs_ecp`).
#[test]
fn desk_point_model_motion_depends_on_the_load_split() {
    let mut pc = point_sim(scenarios::desk()).expect("valid desk");
    pc.prepare_step().expect("step data");
    let start = pc.z().to_vec();
    let (nu, _) = body_vars(&pc, 0);
    let mcp = pc.mcp();
    // Newton on its plain iteration and restarts (the Josephy–Newton steps off): they solve the
    // linearised problem by pivoting, as PATH does, and then land on PATH's member of the set.
    let mut newton =
        ecp::solvers::newton::NewtonSolver::new(ecp::solvers::newton::NewtonSettings {
            josephy_newton: None,
            ..Default::default()
        });
    let a = newton.solve(mcp, &start).expect("Newton converges");
    let b = solver("path").solve(mcp, &start).expect("PATH converges");
    assert!(residual_of(mcp, &a.z) <= 1e-10 && residual_of(mcp, &b.z) <= 1e-10);
    let (wa, wb) = (a.z[mcp.range(nu)][5], b.z[mcp.range(nu)][5]);
    println!(
        "desk step 1: ω_z = {wa:.6} (Newton), {wb:.6} (PATH), difference {:.3e}",
        wa - wb
    );
    assert!(
        (wa - wb).abs() > 1e-5,
        "the two backends found the same motion"
    );
    let split = |z: &[f64]| -> Vec<f64> {
        point_of(&pc)
            .contacts()
            .iter()
            .map(|c| z[mcp.range(c.pn)][0])
            .collect()
    };
    let total = |v: &[f64]| v.iter().sum::<f64>();
    // Both carry the weight (v_z = 0 in both), with different splits.
    assert_close("Newton total", total(&split(&a.z)), 15.0 * G * H, 1e-9);
    assert_close("PATH total", total(&split(&b.z)), 15.0 * G * H, 1e-9);
}

/// The desk's first `steps` steps with both models (Newton): the point model converges at
/// every step, keeps every vertex above −1e-9, stays flat (`v_z`, `ω_x`, `ω_y` ≤ 1e-9), carries
/// exactly the weight `m g h = 1.47` N s (to 1e-9) on the 16 foot corners only, with its centre
/// of pressure inside the patch's hull (the 0.5 × 0.5 m square); prints max |Δv|, |Δω| against
/// the ECP model (measured over 100 steps: 2.4e-2 m/s, 0.31 rad/s; over 400: 2.6e-2, 0.31
/// with Newton, 3.0e-2, 0.43 with PATH — the point model's motion is not unique, see above —
/// mostly the corners' lever arm braking the spin harder than `e_r = 0.1` m, as in A3).
fn desk_against_hull(steps: usize) {
    let point = run_point(scenarios::desk(), "newton", steps);
    let hull = run_hull(scenarios::desk(), "newton", steps);
    let (mut dv, mut dw): (f64, f64) = (0.0, 0.0);
    for (p, e) in point.iter().zip(&hull) {
        let b = &p.bodies[0];
        assert!(penetration(p) <= 1e-9, "step {}: penetration", p.step);
        assert!(
            b.v.z.abs() <= 1e-9 && b.w.x.abs() <= 1e-9 && b.w.y.abs() <= 1e-9,
            "step {}: the desk tilts: v {:?} ω {:?}",
            p.step,
            b.v,
            b.w
        );
        let total: f64 = p.contacts.iter().map(|c| c.pn).sum();
        assert_close("desk weight", total, 15.0 * G * H, 1e-9);
        for c in &p.contacts {
            if c.pn > 1e-9 {
                assert!(
                    c.a1.z.abs() <= 1e-9,
                    "step {}: a point off the floor is loaded",
                    p.step
                );
            }
        }
        let cop = centre_of_pressure(&p.contacts).expect("loaded");
        let local = rotation_matrix(&b.q).transpose() * (cop - b.x);
        assert!(
            local.x.abs() <= 0.25 + 1e-9 && local.y.abs() <= 0.25 + 1e-9,
            "step {}: centre of pressure outside the patch hull: {local:?}",
            p.step
        );
        dv = dv.max((b.v - e.bodies[0].v).norm());
        dw = dw.max((b.w - e.bodies[0].w).norm());
    }
    println!(
        "desk, {} steps: point vs ECP model max |Δv| = {dv:.4e} m/s, max |Δω| = {dw:.4e} rad/s",
        point.len()
    );
}

/// The desk's first 100 steps (1 s).
#[test]
fn desk_point_model_first_second() {
    desk_against_hull(100);
}

/// The whole desk run (400 steps; 25 s in the test profile):
/// `cargo test --test point_contacts -- --ignored desk_point_model_whole_run`.
#[test]
#[ignore]
fn desk_point_model_whole_run() {
    desk_against_hull(400);
}
