//! Bodies touching bodies (`docs/model.md#bodies-touching-bodies`): the scene files
//! `scenes/d1_stack.toml` … `scenes/d8_edge_on_edge.toml` run by the multi-body formulation
//! with Newton, PATH and the conic backend, against the exact answers of `docs/model.md#scenarios`
//! (velocities 1e-9, ECPs 1e-8, impulses 1e-9; every step must converge, and the overlap check
//! between every two real bodies runs at every step end); a reach that leaves a pair out is
//! caught; the scene-file errors of the multi-body format; `contacts.csv` and `summary.json`.

use std::path::Path;

use ecp::formulations::bodies::MultiBody;
use ecp::formulations::bodies::pairs::Reach;
use ecp::formulations::{
    PairRecord, SceneError, Simulation, SimulationBuilder, StepMethod, StepRecord,
};
use ecp::model::{Counter, McpSolver};
use ecp::run::{RunOptions, run_scene};
use ecp::scene::{load_scene, parse_scene};
use ecp::solvers::{BackendOptions, Registry};
use nalgebra::Vector3;

const G: f64 = 9.8;
const H: f64 = 0.01;

fn solver(name: &str) -> Box<dyn McpSolver> {
    Registry::builtin()
        .build(name, &BackendOptions::default())
        .expect("builtin backend")
}

fn scene(name: &str) -> ecp::formulations::Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(format!("{name}.toml"));
    let file = load_scene(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(file.formulation, "bodies", "{name}");
    file.scene
}

/// Runs `scene` with `backend` for `steps` steps (all of it when `None`), every step converged.
fn run(scene: ecp::formulations::Scene, backend: &str, steps: Option<usize>) -> Vec<StepRecord> {
    let name = scene.name.clone();
    let mut sim = Simulation::with_formulation(scene, "bodies").unwrap_or_else(|e| panic!("{e}"));
    let mut s = solver(backend);
    let mut out = Vec::new();
    while !sim.finished() && steps.is_none_or(|n| out.len() < n) {
        let rec = sim
            .step(s.as_mut())
            .unwrap_or_else(|e| panic!("{name}, {backend}: {e}"));
        assert!(
            rec.converged,
            "{name}, {backend}: step {} did not converge ({})",
            rec.step, rec.summary.termination
        );
        out.push(rec);
    }
    let iters: Vec<usize> = out.iter().map(|r| r.summary.iterations).collect();
    let us: f64 = out.iter().map(|r| r.solve_us).sum::<f64>() / out.len().max(1) as f64;
    // The conic backend's own fixed point, or its Newton finish after a stagnated one.
    let polished = out
        .iter()
        .filter(|r| r.summary.counters.get(Counter::NewtonPolish).unwrap_or(0) > 0)
        .count();
    eprintln!(
        "{name}, {backend}: {} steps, iterations mean {:.2} max {}, solve {us:.0} µs per step, \
         {polished} steps finished by the Newton polish",
        out.len(),
        iters.iter().sum::<usize>() as f64 / iters.len().max(1) as f64,
        iters.iter().max().copied().unwrap_or(0)
    );
    out
}

fn pair<'a>(r: &'a StepRecord, a: &str, b: &str) -> &'a PairRecord {
    r.pairs
        .iter()
        .find(|p| p.body_a == a && p.body_b == b)
        .unwrap_or_else(|| panic!("step {}: no contact {a}–{b} in {:?}", r.step, r.pairs))
}

fn close(what: &str, got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "{what}: got {got:.15}, want {want:.15} (tolerance {tol:e})"
    );
}

fn near(what: &str, got: &Vector3<f64>, want: &Vector3<f64>, tol: f64) {
    assert!(
        (got - want).norm() <= tol,
        "{what}: got {got:?}, want {want:?} (tolerance {tol:e})"
    );
}

fn friction_free(p: &PairRecord, at: &str) {
    let f = p.pt.abs().max(p.po.abs()).max(p.pr.abs());
    assert!(f <= 1e-9, "{at}: friction impulse {f:.3e} on {p:?}");
}

fn at_rest(r: &StepRecord, at: &str) {
    for (b, s) in r.bodies.iter().enumerate() {
        assert!(
            s.v.norm() <= 1e-9 && s.w.norm() <= 1e-9,
            "{at}: body {b} moves: v {} ω {}",
            s.v,
            s.w
        );
    }
}

// ---------------------------------------------------------------------------------------------
// D1, D2: stacks at rest
// ---------------------------------------------------------------------------------------------

fn stack(name: &str, backend: &str, b_xy: (f64, f64)) {
    let recs = run(scene(name), backend, None);
    assert_eq!(recs.len(), 100);
    for r in &recs {
        let at = format!("{name}, {backend}, step {}", r.step);
        at_rest(r, &at);
        let top = pair(r, "B", "A");
        let bottom = pair(r, "A", "ground");
        close(&format!("{at}: p_n(B–A)"), top.pn, 1.0 * G * H, 1e-9);
        close(
            &format!("{at}: p_n(A–ground)"),
            bottom.pn,
            3.0 * G * H,
            1e-9,
        );
        near(
            &format!("{at}: ECP(B–A)"),
            &top.a1,
            &Vector3::new(b_xy.0, b_xy.1, 0.2),
            1e-8,
        );
        near(
            &format!("{at}: ECP(A–ground)"),
            &bottom.a1,
            &Vector3::new(b_xy.0 / 3.0, b_xy.1 / 3.0, 0.0),
            1e-8,
        );
        near(&format!("{at}: normal"), &top.normal, &Vector3::z(), 1e-9);
        friction_free(top, &at);
        friction_free(bottom, &at);
        assert_eq!(top.mode.as_str(), "patch", "{at}");
    }
}

#[test]
fn d1_stack_newton() {
    stack("d1_stack", "newton", (0.0, 0.0));
}

#[test]
fn d1_stack_conic() {
    stack("d1_stack", "conic", (0.0, 0.0));
}

#[test]
fn d1_stack_path() {
    stack("d1_stack", "path", (0.0, 0.0));
}

#[test]
fn d2_offset_stack_newton() {
    stack("d2_offset_stack", "newton", (0.1, 0.05));
}

#[test]
fn d2_offset_stack_conic() {
    stack("d2_offset_stack", "conic", (0.1, 0.05));
}

#[test]
fn d2_offset_stack_path() {
    stack("d2_offset_stack", "path", (0.1, 0.05));
}

// ---------------------------------------------------------------------------------------------
// D3: a block sliding on a block
// ---------------------------------------------------------------------------------------------

fn block_on_block(backend: &str) {
    let recs = run(scene("d3_block_on_block"), backend, None);
    let dv = 0.3 * G * H;
    let mut slid = 0;
    for r in &recs {
        let k = r.step as f64;
        let at = format!("d3, {backend}, step {}", r.step);
        let (a, b) = (&r.bodies[0], &r.bodies[1]);
        assert!(a.v.norm() <= 1e-9 && a.w.norm() <= 1e-9, "{at}: A moves");
        near(
            &format!("{at}: A"),
            &a.x,
            &Vector3::new(0.0, 0.0, 0.1),
            1e-9,
        );
        let vx = (1.0 - dv * k).max(0.0);
        close(&format!("{at}: v_x(B)"), b.v.x, vx, 1e-9);
        assert!(b.v.y.abs() <= 1e-9 && b.v.z.abs() <= 1e-9 && b.w.norm() <= 1e-9);
        let top = pair(r, "B", "A");
        let ground = pair(r, "A", "ground");
        close(&format!("{at}: p_n(B–A)"), top.pn, G * H, 1e-9);
        close(
            &format!("{at}: p_n(A–ground)"),
            ground.pn,
            3.0 * G * H,
            1e-9,
        );
        if 1.0 - dv * k > 0.0 {
            slid += 1;
            close(
                &format!("{at}: ECP(B–A) ahead"),
                top.a1.x - b.x.x,
                0.03,
                1e-8,
            );
            close(
                &format!("{at}: ECP(A–ground)"),
                ground.a1.x,
                (b.x.x + 0.09) / 3.0,
                1e-8,
            );
        } else if 1.0 - dv * (k - 1.0) <= 0.0 {
            // At rest (after the step at which B sticks): under B's CM and the combined CM.
            close(&format!("{at}: ECP(B–A)"), top.a1.x, b.x.x, 1e-8);
            close(
                &format!("{at}: ECP(A–ground)"),
                ground.a1.x,
                b.x.x / 3.0,
                1e-8,
            );
        }
    }
    assert_eq!(slid, 34, "B slides for 34 steps");
}

#[test]
fn d3_block_on_block_newton() {
    block_on_block("newton");
}

#[test]
fn d3_block_on_block_conic() {
    block_on_block("conic");
}

#[test]
fn d3_block_on_block_path() {
    block_on_block("path");
}

// ---------------------------------------------------------------------------------------------
// D4: the conveyor
// ---------------------------------------------------------------------------------------------

fn conveyor(backend: &str) {
    let recs = run(scene("d4_conveyor"), backend, Some(30));
    for r in &recs {
        let k = r.step as f64;
        let at = format!("d4, {backend}, step {}", r.step);
        let b = &r.bodies[0];
        let vx = (0.3 * G * H * k).min(0.5);
        close(&format!("{at}: v_x"), b.v.x, vx, 1e-9);
        assert!(b.v.y.abs() <= 1e-9 && b.v.z.abs() <= 1e-9 && b.w.norm() <= 1e-9);
        let p = pair(r, "B", "A");
        close(&format!("{at}: p_n"), p.pn, G * H, 1e-9);
        // Moment balance: the friction impulse m Δv at 0.1 m below the CM against p_n = m g h.
        let dv = vx - (0.3 * G * H * (k - 1.0)).min(0.5);
        close(
            &format!("{at}: ECP behind the CM"),
            p.a1.x - b.x.x,
            -0.1 * dv / (G * H),
            1e-8,
        );
        close(&format!("{at}: ECP height"), p.a1.z, 0.2, 1e-8);
    }
    // Sticks at step 18: 0.3 g h · 18 = 0.529 > 0.5.
    close(
        "v_x at step 17",
        recs[16].bodies[0].v.x,
        0.3 * G * H * 17.0,
        1e-9,
    );
    close("v_x at step 18", recs[17].bodies[0].v.x, 0.5, 1e-9);
}

#[test]
fn d4_conveyor_newton() {
    conveyor("newton");
}

#[test]
fn d4_conveyor_conic() {
    conveyor("conic");
}

#[test]
fn d4_conveyor_path() {
    conveyor("path");
}

// ---------------------------------------------------------------------------------------------
// D5: an inelastic collision
// ---------------------------------------------------------------------------------------------

fn kinetic(r: &StepRecord, masses: &[f64]) -> f64 {
    r.bodies
        .iter()
        .zip(masses)
        .map(|(s, m)| 0.5 * m * s.v.norm_squared())
        .sum()
}

fn collision(backend: &str) {
    let recs = run(scene("d5_collision"), backend, None);
    let mut energy = 0.5;
    for r in &recs {
        let at = format!("d5, {backend}, step {}", r.step);
        let (b, c) = (&r.bodies[0], &r.bodies[1]);
        let momentum = b.v + c.v;
        near(
            &format!("{at}: momentum"),
            &momentum,
            &Vector3::new(1.0, 0.0, 0.0),
            1e-12,
        );
        let (vb, vc) = if r.step <= 10 { (0.0, 1.0) } else { (0.5, 0.5) };
        close(&format!("{at}: v_x(B)"), b.v.x, vb, 1e-9);
        close(&format!("{at}: v_x(C)"), c.v.x, vc, 1e-9);
        let e = kinetic(r, &[1.0, 1.0]);
        assert!(e <= energy + 1e-12, "{at}: kinetic energy {e} > {energy}");
        energy = e;
    }
    assert_eq!(recs.len(), 30);
}

#[test]
fn d5_collision_newton() {
    collision("newton");
}

#[test]
fn d5_collision_conic() {
    collision("conic");
}

#[test]
fn d5_collision_path() {
    collision("path");
}

/// A reach that is too short leaves the colliding pair out: C (thrown at 1.5 m/s, so that it
/// would pass into B within one step) overlaps B at a step end, and the overlap check between
/// every two real bodies fails the step. With the default reach the same scene runs.
#[test]
fn a_pair_left_out_is_caught_by_the_overlap_check() {
    let mut s = scene("d5_collision");
    s.bodies[1].initial.v = Vector3::new(1.5, 0.0, 0.0);
    let blind = Reach {
        factor: 0.0,
        margin: 0.0,
    };
    let mut sim = SimulationBuilder::new(s.clone(), Box::new(MultiBody::with_reach(blind)))
        .build()
        .unwrap_or_else(|e| panic!("{e}"));
    let mut newton = solver("newton");
    let mut caught = None;
    while !sim.finished() {
        match sim.step(newton.as_mut()) {
            Ok(r) => assert!(r.converged),
            Err(e) => {
                caught = Some(e);
                break;
            }
        }
    }
    match caught {
        Some(SceneError::Overlap {
            a, b, depth, step, ..
        }) => {
            assert_eq!((a.as_str(), b.as_str()), ("C", "B"));
            assert!(depth > 1e-3, "{depth}");
            assert_eq!(step, Some(7));
        }
        other => panic!("the missed pair was not caught: {other:?}"),
    }
    let recs = run(s, "newton", None);
    let (b, c) = (&recs.last().expect("steps").bodies[0], &recs[29].bodies[1]);
    close("B after the impact", b.v.x, 0.75, 1e-9);
    close("C after the impact", c.v.x, 0.75, 1e-9);
}

// ---------------------------------------------------------------------------------------------
// D6: a fixed body equals a half-space
// ---------------------------------------------------------------------------------------------

fn incline_body(backend: &str) {
    let recs = run(scene("d6_incline_body"), backend, None);
    let a4 = load_scene(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/a4_incline_25.toml"))
        .unwrap_or_else(|e| panic!("{e}"));
    let mut sim = Simulation::new(a4.scene).unwrap_or_else(|e| panic!("{e}"));
    let mut s = solver(backend);
    let mut worst: f64 = 0.0;
    for r in &recs {
        let want = sim.step(s.as_mut()).unwrap_or_else(|e| panic!("{e}"));
        assert!(want.converged);
        let (g, w) = (&r.bodies[0], &want.bodies[0]);
        let p = pair(r, "box", "incline");
        let c = &want.contacts[0];
        for (what, err) in [
            ("x", (g.x - w.x).norm()),
            ("q", (g.q - w.q).norm()),
            ("v", (g.v - w.v).norm()),
            ("w", (g.w - w.w).norm()),
            ("ECP", (p.a1 - c.a1).norm()),
            ("p_n", (p.pn - c.pn).abs()),
        ] {
            assert!(
                err <= 1e-9,
                "d6, {backend}, step {}: {what} differs from A4 by {err:.3e}",
                r.step
            );
            worst = worst.max(err);
        }
    }
    // The box slid: a = g (sin θ − μ cos θ).
    let a = G * (25f64.to_radians().sin() - 0.3 * 25f64.to_radians().cos());
    close("speed after 1 s", recs[99].bodies[0].v.norm(), a, 1e-6);
    eprintln!("d6, {backend}: largest difference from A4 {worst:.3e}");
}

#[test]
fn d6_incline_body_newton() {
    incline_body("newton");
}

#[test]
fn d6_incline_body_conic() {
    incline_body("conic");
}

#[test]
fn d6_incline_body_path() {
    incline_body("path");
}

// ---------------------------------------------------------------------------------------------
// D7: a tower of five cubes
// ---------------------------------------------------------------------------------------------

fn tower(backend: &str) {
    let recs = run(scene("d7_tower"), backend, None);
    assert_eq!(recs.len(), 50);
    for r in &recs {
        let at = format!("d7, {backend}, step {}", r.step);
        at_rest(r, &at);
        for k in 1..=5 {
            // The k-th contact from the top: B(6−k) on B(5−k), the last on the ground.
            let upper = format!("B{}", 6 - k);
            let lower = if k == 5 {
                "ground".to_string()
            } else {
                format!("B{}", 5 - k)
            };
            let p = pair(r, &upper, &lower);
            close(
                &format!("{at}: p_n({upper}–{lower})"),
                p.pn,
                k as f64 * G * H,
                1e-9,
            );
            friction_free(p, &at);
        }
    }
}

#[test]
fn d7_tower_newton() {
    tower("newton");
}

#[test]
fn d7_tower_conic() {
    tower("conic");
}

#[test]
fn d7_tower_path() {
    tower("path");
}

// ---------------------------------------------------------------------------------------------
// D8: edge on edge
// ---------------------------------------------------------------------------------------------

/// The long edge of a bar (rotated 45° about its long axis, body-frame x) nearest to the world
/// point `p`: a point on it and its direction.
fn nearest_edge(
    x: &Vector3<f64>,
    q: &nalgebra::Vector4<f64>,
    p: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let r = ecp::formulations::rotation::rotation_matrix(q);
    let axis = r * Vector3::x();
    let mut best = (f64::INFINITY, Vector3::zeros());
    for (sy, sz) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        let point = x + r * Vector3::new(0.0, 0.05 * sy, 0.05 * sz);
        let rel = p - point;
        let d = (rel - axis * axis.dot(&rel)).norm();
        if d < best.0 {
            best = (d, point);
        }
    }
    (best.1, axis)
}

fn edge_on_edge(backend: &str) {
    let s = scene("d8_edge_on_edge");
    let fixed = &s.world.obstacles[0];
    let (xf, qf) = fixed.pose_at(0.0);
    let recs = run(s.clone(), backend, None);
    let mut energy = recs[0].energy + 1.0;
    let (mut contact_steps, mut left) = (0, false);
    for r in &recs {
        let at = format!("d8, {backend}, step {}", r.step);
        assert!(
            r.energy <= energy + 1e-9,
            "{at}: energy {} > {energy}",
            r.energy
        );
        energy = r.energy;
        let Some(p) = r
            .pairs
            .iter()
            .find(|p| p.body_a == "bar" && p.body_b == "fixed_bar")
        else {
            left |= contact_steps > 0;
            continue;
        };
        if p.pn <= 0.0 {
            if contact_steps == 0 {
                assert!(p.normal.z.abs() >= 1.0 - 1e-9, "{at}: normal {}", p.normal);
            } else {
                left = true;
            }
            continue;
        }
        contact_steps += 1;
        let b = &r.bodies[0];
        let (_, ef) = nearest_edge(&xf, &qf, &p.a2);
        let (_, eb) = nearest_edge(&b.x, &b.q, &p.a1);
        let mut perp = ef.cross(&eb).normalize();
        if perp.dot(&p.normal) < 0.0 {
            perp = -perp;
        }
        near(&format!("{at}: normal"), &p.normal, &perp, 1e-9);
        assert_eq!(p.mode.as_str(), "point", "{at}");
    }
    assert!(
        contact_steps >= 3,
        "{backend}: {contact_steps} contact steps"
    );
    assert!(left, "{backend}: the bar never left the fixed bar");
    let last = &recs.last().expect("steps").bodies[0];
    assert!(
        last.x.z < xf.z,
        "{backend}: the bar did not fall off: {}",
        last.x
    );
}

#[test]
fn d8_edge_on_edge_newton() {
    edge_on_edge("newton");
}

#[test]
fn d8_edge_on_edge_conic() {
    edge_on_edge("conic");
}

#[test]
fn d8_edge_on_edge_path() {
    edge_on_edge("path");
}

// ---------------------------------------------------------------------------------------------
// Scene files: errors of the multi-body format
// ---------------------------------------------------------------------------------------------

const BASE: &str = r#"
[simulation]
h = 0.01
duration = 0.1
formulation = "bodies"
[friction]
mu = 0.3
e_r = 0.1
[[half_spaces]]
name = "ground"
normal = [0, 0, 1]
[[bodies]]
name = "A"
mass = 2
inertia = "uniform"
position = [0, 0, 0.1]
[[bodies.pieces]]
box = [0.4, 0.4, 0.2]
"#;

fn error_of(extra: &str) -> ecp::error::InputError {
    let text = format!("{BASE}{extra}");
    match parse_scene(&text, Path::new("bad.toml")) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e,
    }
}

#[test]
fn a_kinematic_body_without_a_schedule_is_refused_with_its_key_and_line() {
    let e = error_of(
        "[[bodies]]\nname = \"plate\"\nkind = \"kinematic\"\nposition = [1, 0, 0.1]\n\
         [[bodies.pieces]]\nbox = [0.4, 0.4, 0.2]\n",
    );
    assert_eq!(e.key.as_deref(), Some("bodies[1].motion"), "{e}");
    assert!(e.message.contains("schedule"), "{e}");
    assert!(e.to_string().contains("bad.toml"), "{e}");
}

#[test]
fn a_pair_friction_naming_an_unknown_body_is_refused() {
    let e = error_of("[[pair_friction]]\nbetween = [\"A\", \"Z\"]\nmu = 0.5\n");
    assert_eq!(e.key.as_deref(), Some("pair_friction[0].between"), "{e}");
    assert!(e.message.contains("\"Z\""), "{e}");
    assert_eq!(e.line, Some(20), "{e}");
}

#[test]
fn bodies_overlapping_at_the_start_are_refused() {
    let e = error_of(
        "[[bodies]]\nname = \"B\"\nmass = 1\ninertia = \"uniform\"\nposition = [0, 0, 0.29]\n\
         [[bodies.pieces]]\nbox = [0.2, 0.2, 0.2]\n",
    );
    assert_eq!(e.key.as_deref(), Some("bodies[1].position"), "{e}");
    assert!(e.message.contains("overlap by 1.000e-2 m"), "{e}");
}

#[test]
fn a_multibody_scene_with_the_hull_formulation_is_refused() {
    let text = format!("{BASE}[[pair_friction]]\nbetween = [\"A\", \"ground\"]\nmu = 0.5\n")
        .replace("formulation = \"bodies\"", "formulation = \"hull\"");
    let e = parse_scene(&text, Path::new("bad.toml")).err();
    let e = e.unwrap_or_else(|| panic!("accepted"));
    assert_eq!(e.key.as_deref(), Some("simulation.formulation"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Outputs
// ---------------------------------------------------------------------------------------------

/// `ecp run` of D1: `contacts.csv` has the contract's columns and one row per step and active
/// contact (2 contacts × 100 steps: B has no contact set with the ground, 0.2 m below it),
/// `summary.json` one entry per pair with its modes.
#[test]
fn run_writes_contacts_and_pairs() {
    let dir = std::env::temp_dir().join(format!("ecp-bodies-run-{}", std::process::id()));
    let file = load_scene(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/d1_stack.toml"))
        .unwrap_or_else(|e| panic!("{e}"));
    let options = ecp::run::RunOptions {
        out_dir: dir.clone(),
        plots: false,
        ..Default::default()
    };
    let out = ecp::run::run_scene(&file, &options, |_| {}).unwrap_or_else(|e| panic!("{e}"));
    assert!(out.succeeded());
    let text = std::fs::read_to_string(dir.join("contacts.csv")).unwrap_or_else(|e| panic!("{e}"));
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(
            "step,t,body_a,body_b,a1_x,a1_y,a1_z,a2_x,a2_y,a2_z,n_x,n_y,n_z,pn,pt,po,pr,sigma,gap,mode"
        )
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 200);
    assert!(rows[0].starts_with("1,0.01,A,ground,"), "{}", rows[0]);
    let top: Vec<&str> = rows[1].split(',').collect();
    assert_eq!(&top[..4], ["1", "0.01", "B", "A"]);
    close(
        "p_n in contacts.csv",
        top[13].parse().unwrap_or(f64::NAN),
        0.098,
        1e-9,
    );
    assert_eq!(top[19], "patch");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("summary.json")).unwrap_or_else(|e| panic!("{e}")),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let pairs = summary["pairs"].as_array().cloned().unwrap_or_default();
    assert_eq!(pairs.len(), 2, "{summary}");
    assert_eq!(pairs[1]["body_a"], "B");
    assert_eq!(pairs[1]["loaded_steps"], 100);
    assert_eq!(pairs[1]["mode_sequence"][0]["mode"], "patch");
    let header = std::fs::read_to_string(dir.join("trajectory.csv")).unwrap_or_default();
    assert!(
        header.starts_with("t,x_b0,"),
        "{}",
        &header[..40.min(header.len())]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The conic backend runs a multi-body scene through `ecp run` (`--solver conic`): every step
/// converged, by the conic backend itself (no fallback).
#[test]
fn the_conic_backend_runs_a_multibody_scene() {
    let file = load_scene(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/d1_stack.toml"))
        .unwrap_or_else(|e| panic!("{e}"));
    let out_dir = std::env::temp_dir().join(format!("ecp-bodies-conic-{}", std::process::id()));
    let options = ecp::run::RunOptions {
        out_dir: out_dir.clone(),
        solver: Some("conic".into()),
        plots: false,
        steps: Some(10),
        ..Default::default()
    };
    let outcome = ecp::run::run_scene(&file, &options, |_| {}).unwrap_or_else(|e| panic!("{e}"));
    assert!(outcome.succeeded(), "{:?}", outcome.stepper_error);
    assert_eq!(outcome.records.len(), 10);
    for r in &outcome.records {
        assert!(r.converged, "step {}", r.step);
        assert_eq!(r.method, StepMethod::Direct, "step {}", r.step);
        assert_eq!(r.summary.solver, "conic", "step {}", r.step);
    }
    let _ = std::fs::remove_dir_all(&out_dir);
}

/// `ecp check` lists the pairs the overlap check watches and those with a contact set at t = 0.
#[test]
fn check_prints_the_watched_pairs() {
    let file =
        load_scene(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/d3_block_on_block.toml"))
            .unwrap_or_else(|e| panic!("{e}"));
    let text = ecp::scene::describe(&file);
    assert!(
        text.contains("pairs watched for overlap at every step end: 3"),
        "{text}"
    );
    assert!(
        text.contains("  A – ground: μ = 1, contact set at t = 0"),
        "{text}"
    );
    assert!(
        text.contains("  B – ground: μ = 0.3, apart at t = 0"),
        "{text}"
    );
    assert!(
        text.contains("  B – A: μ = 0.3, contact set at t = 0"),
        "{text}"
    );
}

// ---------------------------------------------------------------------------------------------
// Step sensitivities through body–body and kinematic contacts
// ---------------------------------------------------------------------------------------------

use ecp::formulations::StateComponent;
use ecp::formulations::sensitivity::{SensitivityOptions, StepInput, step_sensitivity_with};
use ecp::formulations::world::Motion;

/// The data block named `name` of `sim`'s step problem.
fn data_block(sim: &Simulation, name: &str) -> ecp::model::DataId {
    let i = sim
        .mcp()
        .data_blocks()
        .iter()
        .position(|d| d.name() == name)
        .unwrap_or_else(|| panic!("no data block {name}"));
    ecp::model::DataId(i)
}

/// `v_x` of body `b` after the first step of `scene`, with Newton at a tight tolerance.
fn first_vx(scene: ecp::formulations::Scene, b: usize) -> f64 {
    let mut sim = Simulation::with_formulation(scene, "bodies").unwrap_or_else(|e| panic!("{e}"));
    let mut newton =
        ecp::solvers::newton::NewtonSolver::new(ecp::solvers::newton::NewtonSettings {
            tolerance: 1e-13,
            ..Default::default()
        });
    let r = sim.step(&mut newton).unwrap_or_else(|e| panic!("{e}"));
    assert!(r.converged);
    r.bodies[b].v.x
}

/// The first step's `∂v_x(b)/∂input` and its central finite difference, `perturb` moving the
/// scene's input by `e`.
fn check_derivative(
    scene: &ecp::formulations::Scene,
    b: usize,
    input: impl Fn(&Simulation) -> StepInput,
    perturb: impl Fn(&mut ecp::formulations::Scene, f64),
    want: f64,
) {
    let mut sim =
        Simulation::with_formulation(scene.clone(), "bodies").unwrap_or_else(|e| panic!("{e}"));
    let mut newton =
        ecp::solvers::newton::NewtonSolver::new(ecp::solvers::newton::NewtonSettings {
            tolerance: 1e-13,
            ..Default::default()
        });
    sim.step(&mut newton).unwrap_or_else(|e| panic!("{e}"));
    let inp = input(&sim);
    let sens = step_sensitivity_with(&sim, &SensitivityOptions::default(), &[inp])
        .unwrap_or_else(|e| panic!("{e}"));
    let d = sens
        .d_state(b, StateComponent::Velocity(0), inp)
        .unwrap_or_else(|| panic!("no column"));
    let e = 1e-6;
    let (mut up, mut down) = (scene.clone(), scene.clone());
    perturb(&mut up, e);
    perturb(&mut down, -e);
    let fd = (first_vx(up, b) - first_vx(down, b)) / (2.0 * e);
    close(
        &format!("{}: ∂v_x/∂{inp:?} against FD", scene.name),
        d,
        fd,
        1e-6,
    );
    close(&format!("{}: ∂v_x/∂{inp:?}", scene.name), d, want, 1e-6);
}

/// D4's first step (B slips on the moving plate): `∂v_x/∂μ = g h`, nothing from B's mass or
/// the plate's speed (it slips), 1 from B's initial velocity; each against central differences.
#[test]
fn sensitivities_through_a_kinematic_contact() {
    let s = scene("d4_conveyor");
    check_derivative(&s, 0, |_| StepInput::Mu, |s, e| s.friction.mu += e, G * H);
    check_derivative(
        &s,
        0,
        |_| StepInput::Mass { body: 0 },
        |s, e| s.bodies[0].mass.mass += e,
        0.0,
    );
    check_derivative(
        &s,
        0,
        |sim| StepInput::Data(data_block(sim, "A.nu"), 0),
        |s, e| {
            if let Motion::Velocity { v, .. } = &mut s.world.obstacles[0].motion {
                v.x += e;
            }
        },
        0.0,
    );
}

/// D3's first step (B slides on A, μ(B–A) = 0.3 of its own): `∂v_x(B)/∂μ(B–A) = −g h` through
/// the pair's friction block, 0 from the scene's μ (no contact uses it), 1 from B's initial
/// velocity; each against central differences.
#[test]
fn sensitivities_through_a_body_body_contact() {
    let s = scene("d3_block_on_block");
    check_derivative(
        &s,
        1,
        |sim| StepInput::Data(data_block(sim, "B~A.friction"), 0),
        |s, e| s.world.pair_friction[1].friction.mu += e,
        -G * H,
    );
    check_derivative(&s, 1, |_| StepInput::Mu, |s, e| s.friction.mu += e, 0.0);
    check_derivative(
        &s,
        1,
        |_| StepInput::Velocity { body: 1, axis: 0 },
        |s, e| s.bodies[1].initial.v.x += e,
        1.0,
    );
}

/// One pair's μ changed between steps through its data block: D3's B, sliding on A, decelerates
/// by 0.3 g h per step, then by 0.1 g h once `B~A.friction` says μ = 0.1.
#[test]
fn one_pairs_friction_set_between_steps() {
    let mut sim = Simulation::with_formulation(scene("d3_block_on_block"), "bodies")
        .unwrap_or_else(|e| panic!("{e}"));
    let mut newton = solver("newton");
    let r = sim.step(newton.as_mut()).unwrap_or_else(|e| panic!("{e}"));
    close("step 1", r.bodies[1].v.x, 1.0 - 0.3 * G * H, 1e-9);
    let block = data_block(&sim, "B~A.friction");
    sim.set_data(block, &[0.1, 1.0, 1.0, 0.1])
        .unwrap_or_else(|e| panic!("{e}"));
    for k in 2..=5 {
        let r = sim.step(newton.as_mut()).unwrap_or_else(|e| panic!("{e}"));
        let want = 1.0 - 0.3 * G * H - 0.1 * G * H * (k - 1) as f64;
        close(&format!("step {k}"), r.bodies[1].v.x, want, 1e-9);
    }
}

// ---------------------------------------------------------------------------------------------
// Issue 16: the 8-body pile (a wall, a pusher, six boxes, one stacked, an L)
// ---------------------------------------------------------------------------------------------

/// The pile of issue 16 (`tests/bodies_regressions/pile.toml`) to its end as `ecp run` runs it
/// (Newton with the driver's fallbacks: step 62 is solved only by the h/2 substeps), every step
/// converged and no two bodies overlapping (the step-end check): at step 53 parry's narrow phase
/// called C resting on B "apart" and C sank into B. At the end, C still rests on B and E on D,
/// all moving with the pusher. Slow (~2.5 min in release, the bulk in the step solved by
/// substeps); run with `cargo test --release -p ecp --test bodies -- --ignored pile --nocapture`.
#[test]
#[ignore = "slow (about 70 s in release): cargo test --release -p ecp --test bodies -- --ignored pile"]
fn issue16_pile_runs_to_the_end() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bodies_regressions/pile.toml");
    let file = load_scene(&path).unwrap_or_else(|e| panic!("pile: {e}"));
    let dir = std::env::temp_dir().join(format!("ecp-pile-{}", std::process::id()));
    let options = RunOptions {
        out_dir: dir.clone(),
        solver: Some("newton".to_string()),
        plots: false,
        ..RunOptions::default()
    };
    let outcome = run_scene(&file, &options, |_| {}).unwrap_or_else(|e| panic!("pile: {e}"));
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        outcome.succeeded(),
        "pile: {} failed steps, {:?}",
        outcome.summary.failed_steps,
        outcome.stepper_error
    );
    let recs = &outcome.records;
    assert_eq!(recs.len(), 120);
    assert!(recs.iter().all(|r| r.converged));
    let fallbacks = recs
        .iter()
        .filter(|r| r.method != StepMethod::Direct)
        .count();
    eprintln!("pile, newton: 120 steps converged, {fallbacks} by a fallback");
    let end = &recs.last().expect("steps").bodies;
    let (b, c, d, e) = (&end[1], &end[2], &end[3], &end[4]);
    close("C on B", c.x.z - b.x.z, 0.2, 1e-9);
    close("E on D", e.x.z - d.x.z, 0.125, 1e-9);
    for (name, s) in [("B", b), ("C", c), ("D", d), ("E", e)] {
        close(name, s.v.x, 0.4, 1e-6);
    }
}

/// The scenes users will want (`docs/bodies.md`) with the conic backend alone (no fallback,
/// keep going, at most 600 s each): steps converged, Newton-polish steps, step times and the
/// deepest penetration, printed for `docs/bodies.md#the-conic-backend`; asserts that every step
/// of the gripper and the feeder converged (bin20 does not). Run with
/// `cargo test -p ecp --test bodies -- --ignored user_scenes_with_the_conic_backend --nocapture`.
#[test]
#[ignore = "slow (minutes): cargo test -p ecp --test bodies -- --ignored user_scenes_with_the_conic_backend --nocapture"]
fn user_scenes_with_the_conic_backend() {
    let mut failed = Vec::new();
    for name in ["tbar_gripper", "parts_feeder", "bin20"] {
        let file = load_scene(
            &Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("scenes")
                .join(format!("{name}.toml")),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let out_dir = std::env::temp_dir().join(format!("ecp-conic-{name}-{}", std::process::id()));
        let options = ecp::run::RunOptions {
            out_dir: out_dir.clone(),
            solver: Some("conic".into()),
            plots: false,
            fallbacks: false,
            keep_going: true,
            time_limit: Some(std::time::Duration::from_secs(600)),
            ..Default::default()
        };
        let o = ecp::run::run_scene(&file, &options, |_| {}).unwrap_or_else(|e| panic!("{e}"));
        let s = &o.summary;
        let polished = o
            .records
            .iter()
            .filter(|r| r.summary.counters.get(Counter::NewtonPolish).unwrap_or(0) > 0)
            .count();
        let overlap = o.stepper_error.clone().unwrap_or_default();
        // The smallest gap of a contact pair at a step end (negative: the hulls overlap).
        let pair_gap = o
            .records
            .iter()
            .flat_map(|r| r.pairs.iter().map(|p| p.gap))
            .fold(f64::INFINITY, f64::min);
        eprintln!(
            "{name}, conic: {} of {} steps, {} converged, {} failed, {polished} finished by the \
             Newton polish, wall {:.1} s ({:.1} steps/s), step median {:.0} µs p95 {:.0} µs max \
             {:.0} µs, max penetration {:.3e} m, smallest pair gap {pair_gap:.3e} m, timed out {}, \
             stepper error '{overlap}'",
            s.steps,
            s.planned_steps,
            s.converged_steps,
            s.failed_steps,
            s.wall_s,
            s.steps as f64 / s.wall_s,
            s.step_us.median,
            s.step_us.p95,
            s.step_us.max,
            s.max_penetration,
            o.timed_out,
        );
        // bin20 is measured, not asserted: its landing steps fail (docs/bodies.md).
        if !o.succeeded() && name != "bin20" {
            failed.push(name);
        }
        let _ = std::fs::remove_dir_all(&out_dir);
    }
    assert!(failed.is_empty(), "not every step converged: {failed:?}");
}
