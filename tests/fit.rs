//! Parameter fitting (`docs/fitting.md`): `ecp::fit` recovers the desk's μ and e_r from a
//! noise-free reference, and `ecp fit` refuses bad input with exit status 2.
//!
//! The recovery runs on the first 50 steps of the desk (0.5 s) to stay quick in debug mode;
//! the full 400-step fit is measured with the release binary (docs/fitting.md).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use ecp::backends::SolverConfig;
use ecp::fit::{
    Coordinate, FitOptions, GradientMethod, Method, ReferenceTrajectory, TrajectoryProblem, fit,
    parse_params, parse_weights, read_reference,
};
use ecp_formulations::scenarios;
use ecp_formulations::sensitivity::Param;

/// Steps of the desk used by the in-process fits.
const STEPS: usize = 50;

fn desk(steps: usize) -> ecp_formulations::Scene {
    let mut scene = scenarios::desk();
    scene.duration = steps as f64 * scene.h;
    scene
}

/// The reference made with the desk's true values (μ = 0.22, e_r = 0.1).
fn desk_reference(steps: usize) -> ReferenceTrajectory {
    let scene = desk(steps);
    let mut sim = ecp_formulations::Simulation::new(scene).unwrap();
    let mut solver =
        ecp::backends::make_solver(&SolverConfig::default()).expect("default solver builds");
    let records: Vec<_> = (0..steps)
        .map(|_| {
            let r = sim.step(solver.as_mut()).unwrap();
            assert!(r.converged);
            r
        })
        .collect();
    ReferenceTrajectory::from_records(&records)
}

/// The desk 30 % off: μ = 0.22·1.3, e_r = 0.1·0.7.
fn desk_off(steps: usize) -> ecp_formulations::Scene {
    let mut scene = desk(steps);
    scene.friction.mu = 0.22 * 1.3;
    scene.friction.e_r = 0.1 * 0.7;
    scene
}

fn problem(gradient: GradientMethod) -> TrajectoryProblem {
    TrajectoryProblem::from_scene(
        desk_off(STEPS),
        "hull",
        SolverConfig::default(),
        desk_reference(STEPS),
        vec![Param::Mu, Param::Er],
    )
    .unwrap()
    .with_gradient(gradient)
    .unwrap()
}

/// L-BFGS with the adjoint gradients recovers μ to 1e-6 and e_r to 1e-5 from a start 30 % off
/// (on 50 steps).
#[test]
fn lbfgs_recovers_desk_mu_and_e_r() {
    let report = fit(problem(GradientMethod::Adjoint), &FitOptions::default()).unwrap();
    let mu = report.params["mu"];
    let e_r = report.params["e_r"];
    assert!(
        (mu - 0.22).abs() <= 1e-6,
        "mu = {mu}, error {:.2e}; report {report:?}",
        mu - 0.22
    );
    assert!(
        (e_r - 0.1).abs() <= 1e-5,
        "e_r = {e_r}, error {:.2e}; report {report:?}",
        e_r - 0.1
    );
    assert!(report.cost < 1e-12 * report.start_cost, "{report:?}");
    assert!(report.error.is_none(), "{report:?}");
    // The desk slides on its four feet throughout: no mode switch in the window.
    assert_eq!(report.mode_events, 0, "{report:?}");
    // Each analytic evaluation is one simulation with its sensitivities.
    assert_eq!(report.counts.simulations, report.counts.cost_evals);
}

/// The gradient argmin sees is the chain rule through the log-coordinates: adjoint and central
/// differences agree to 1e-6 relative at the start (30 % off, far from mode switches).
#[test]
fn adjoint_gradient_matches_finite_differences_in_coordinates() {
    let u = [0.0, 0.0];
    let (la, ga) = problem(GradientMethod::Adjoint)
        .loss_and_gradient(&u)
        .unwrap();
    let (lf, gf) = problem(GradientMethod::Fd).loss_and_gradient(&u).unwrap();
    assert!((la - lf).abs() <= 1e-12 * la, "loss {la} vs {lf}");
    for (a, f) in ga.iter().zip(&gf) {
        assert!(
            (a - f).abs() <= 1e-6 * a.abs().max(1e-3 * la),
            "{ga:?} vs {gf:?}"
        );
    }
    let forward = problem(GradientMethod::Forward)
        .loss_and_gradient(&u)
        .unwrap()
        .1;
    for (a, f) in ga.iter().zip(&forward) {
        assert!((a - f).abs() <= 1e-10 * a.abs(), "{ga:?} vs {forward:?}");
    }
}

/// The one-step problem: μ and e_r from one step of the desk (its start state and the state
/// 10 ms later) by L-BFGS.
#[test]
fn one_step_problem_recovers_mu_and_e_r() {
    let reference = desk_reference(1);
    let start = vec![scenarios::desk().bodies[0].initial];
    let p = TrajectoryProblem::for_step(
        desk_off(1),
        "hull",
        SolverConfig::default(),
        &start,
        &reference.states[0],
        vec![Param::Mu, Param::Er],
    )
    .unwrap();
    let report = fit(p, &FitOptions::default()).unwrap();
    assert!((report.params["mu"] - 0.22).abs() <= 1e-6, "{report:?}");
    assert!((report.params["e_r"] - 0.1).abs() <= 1e-5, "{report:?}");
    assert_eq!(report.steps, 1);
}

/// Nelder–Mead (no gradients) gets close too, with a looser tolerance (argmin's simplex stalls
/// near 1e-6 relative, crates.md).
#[test]
fn nelder_mead_approaches_desk_mu_and_e_r() {
    let options = FitOptions {
        method: Method::NelderMead,
        max_iters: 200,
        ..FitOptions::default()
    };
    let report = fit(problem(GradientMethod::Adjoint), &options).unwrap();
    let mu = report.params["mu"];
    let e_r = report.params["e_r"];
    assert!((mu - 0.22).abs() <= 1e-4, "mu = {mu}; {report:?}");
    assert!((e_r - 0.1).abs() <= 1e-3, "e_r = {e_r}; {report:?}");
    assert_eq!(report.gradient, None);
    assert_eq!(report.counts.gradient_evals, 0, "no gradients: {report:?}");
    assert_eq!(report.counts.simulations, report.counts.cost_evals);
}

/// The loss is zero at the true values and positive 30 % off; the argmin cost is the scaled
/// loss; log-coordinates map back to the parameters.
#[test]
fn loss_vanishes_at_the_reference_parameters() {
    let p = problem(GradientMethod::Adjoint);
    assert_eq!(p.coordinates(), &[Coordinate::Log, Coordinate::Log]);
    let u_true = p.coordinates_of(&[0.22, 0.1]);
    let at_true = p.loss(&u_true).unwrap();
    assert!(at_true < 1e-20, "loss at the true values {at_true:e}");
    let at_start = p.loss(&[0.0, 0.0]).unwrap();
    assert!(at_start > 1e-6, "loss at the start {at_start:e}");
    let back = p.values_at(&u_true);
    assert!((back[0] - 0.22).abs() < 1e-15 && (back[1] - 0.1).abs() < 1e-15);
    use argmin::core::CostFunction;
    let scaled = p.clone().with_cost_scale(2.0);
    assert_eq!(scaled.cost(&vec![0.0, 0.0]).unwrap(), 2.0 * at_start);
}

#[test]
fn parameter_names_parse_and_unknown_ones_list_the_names() {
    let scene = scenarios::desk();
    let ps = parse_params(&["mu,e_r".into(), "mass".into()], &scene).unwrap();
    assert_eq!(ps, vec![Param::Mu, Param::Er, Param::Mass { body: 0 }]);
    let e = parse_params(&["mu,friction".into()], &scene)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("friction") && e.contains("e_r") && e.contains("i_zz"),
        "{e}"
    );
    assert!(parse_params(&["mu,mu".into()], &scene).is_err());
    assert!(parse_params(&["mass[3]".into()], &scene).is_err());
    assert!(parse_params(&["mu[1]".into()], &scene).is_err());
    // The desk's load is a function of time: no constant-load parameter.
    let e = parse_params(&["fx".into()], &scene)
        .unwrap_err()
        .to_string();
    assert!(e.contains("function of time"), "{e}");
    // Signed parameters get linear coordinates.
    assert_eq!(
        Coordinate::of(&Param::InitialVelocity { body: 0, axis: 0 }, -0.3),
        Coordinate::Linear { scale: 0.3 }
    );
    let w = parse_weights("x=2,w=0.5").unwrap();
    assert_eq!(
        (w.position, w.angular_velocity, w.velocity),
        (2.0, 0.5, 1.0)
    );
    assert!(parse_weights("v=-1").is_err());
    assert!(parse_weights("speed=1").is_err());
    assert!(parse_weights("v=0,w=0").is_err());
}

// ---- the command line ----

fn ecp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ecp"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("the ecp binary runs")
}

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecp-fit-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// `ecp run SCENE --steps N` into `dir`; returns the trajectory.csv path.
fn reference_file(scene: &str, steps: usize, dir: &Path) -> PathBuf {
    let out = ecp(&[
        "run",
        scene,
        "--steps",
        &steps.to_string(),
        "--no-plots",
        "--quiet",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir.join("trajectory.csv")
}

fn assert_bad_input(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one paragraph: {err}");
    for n in needles {
        assert!(err.contains(n), "expected {n:?} in: {err}");
    }
}

/// A small fit through the command line: JSON with the documented fields, read from the
/// trajectory.csv that `ecp run` wrote (20 steps, start 30 % off, L-BFGS).
#[test]
fn cli_fits_from_a_run_and_prints_json() {
    let dir = temp_dir("ok");
    let reference = reference_file("scenes/desk.toml", 20, &dir);
    let off = dir.join("desk_off.toml");
    let text = std::fs::read_to_string("scenes/desk.toml")
        .unwrap()
        .replace("mu = 0.22", "mu = 0.286")
        .replace("e_r = 0.1", "e_r = 0.07");
    std::fs::write(&off, text).unwrap();
    let out = ecp(&[
        "fit",
        off.to_str().unwrap(),
        "--reference",
        reference.to_str().unwrap(),
        "--params",
        "mu,e_r",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_str(stdout.trim()).expect("JSON on stdout");
    let mu = json["params"]["mu"].as_f64().unwrap();
    let e_r = json["params"]["e_r"].as_f64().unwrap();
    assert!((mu - 0.22).abs() < 1e-6, "{json}");
    assert!((e_r - 0.1).abs() < 1e-5, "{json}");
    assert!(json["cost"].as_f64().unwrap() >= 0.0);
    assert!(json["iterations"].as_u64().unwrap() >= 1);
    assert!(json["wall_s"].as_f64().unwrap() > 0.0);
    assert_eq!(json["method"], "lbfgs");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cli_refuses_bad_input() {
    let dir = temp_dir("bad");
    let reference = reference_file("scenes/desk.toml", 5, &dir);
    let r = reference.to_str().unwrap();
    // Unknown parameter: the list of names.
    let out = ecp(&[
        "fit",
        "scenes/desk.toml",
        "--reference",
        r,
        "--params",
        "mu,grip",
    ]);
    assert_bad_input(&out, &["grip", "mu, e_t, e_o, e_r, mass, i_xx"]);
    // Missing reference file.
    let out = ecp(&[
        "fit",
        "scenes/desk.toml",
        "--reference",
        "no/such/trajectory.csv",
        "--params",
        "mu",
    ]);
    assert_bad_input(&out, &["no/such/trajectory.csv", "ecp run"]);
    // A CSV that is not a trajectory.
    let junk = dir.join("junk.csv");
    std::fs::write(&junk, "a,b\n1,2\n").unwrap();
    let out = ecp(&[
        "fit",
        "scenes/desk.toml",
        "--reference",
        junk.to_str().unwrap(),
        "--params",
        "mu",
    ]);
    assert_bad_input(&out, &["junk.csv", "\"t\""]);
    // A number that is not one.
    let text = std::fs::read_to_string(&reference).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let mut fields: Vec<String> = lines[2].split(',').map(String::from).collect();
    fields[8] = "fast".into();
    lines[2] = fields.join(",");
    let broken = dir.join("broken.csv");
    std::fs::write(&broken, lines.join("\n")).unwrap();
    let out = ecp(&[
        "fit",
        "scenes/desk.toml",
        "--reference",
        broken.to_str().unwrap(),
        "--params",
        "mu",
    ]);
    assert_bad_input(&out, &["line 3", "vx", "fast"]);
    // A reference from another scene (the sliding box).
    let a1 = reference_file("scenes/a1_sliding.toml", 5, &dir.join("a1"));
    let out = ecp(&[
        "fit",
        "scenes/desk.toml",
        "--reference",
        a1.to_str().unwrap(),
        "--params",
        "mu",
    ]);
    assert_bad_input(&out, &["another scene"]);
    // Times that do not match the scene's steps (a row missing).
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    lines.remove(2);
    let gap = dir.join("gap.csv");
    std::fs::write(&gap, lines.join("\n")).unwrap();
    let out = ecp(&[
        "fit",
        "scenes/desk.toml",
        "--reference",
        gap.to_str().unwrap(),
        "--params",
        "mu",
    ]);
    assert_bad_input(&out, &["row 2", "t = 0.03", "t = 0.02"]);
    // Bad option values.
    let out = ecp(&[
        "fit",
        "scenes/desk.toml",
        "--reference",
        r,
        "--params",
        "mu",
        "--weights",
        "v=-2",
    ]);
    assert_bad_input(&out, &["--weights"]);
    // A parameter that starts at zero cannot be fitted in log-coordinates.
    let zero = dir.join("zero_mu.toml");
    std::fs::write(
        &zero,
        std::fs::read_to_string("scenes/desk.toml")
            .unwrap()
            .replace("mu = 0.22", "mu = 0.0"),
    )
    .unwrap();
    let out = ecp(&[
        "fit",
        zero.to_str().unwrap(),
        "--reference",
        r,
        "--params",
        "mu",
    ]);
    assert_bad_input(&out, &["mu", "positive start value"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The reference reader gives back exactly what the trajectory writer wrote (shortest
/// round-trip floats).
#[test]
fn reference_reads_back_the_writer_exactly() {
    let dir = temp_dir("read");
    let path = dir.join("trajectory.csv");
    let scene = desk(3);
    let mut sim = ecp_formulations::Simulation::new(scene.clone()).unwrap();
    let mut solver = ecp::backends::make_solver(&SolverConfig::default()).unwrap();
    let mut writer = ecp::output::TrajectoryWriter::create(&path, &scene, 1).unwrap();
    let mut records = Vec::new();
    for _ in 0..3 {
        let rec = sim.step(solver.as_mut()).unwrap();
        writer.write(&rec).unwrap();
        records.push(rec);
    }
    drop(writer);
    let reference = read_reference(&path, 1).unwrap();
    assert_eq!(reference.steps(), 3);
    for (a, r) in reference.states.iter().zip(&records) {
        assert_eq!(a, &r.bodies);
    }
    for (t, r) in reference.times.iter().zip(&records) {
        assert_eq!(*t, r.t);
    }
    reference.check_against(&scene).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

/// A simulation that fails during the fit (here at the start: one Newton iteration per step) is
/// not bad input: exit status 1 and one message naming the parameters, no panic.
#[test]
fn cli_reports_a_failed_simulation_with_exit_status_1() {
    let dir = temp_dir("fail");
    let reference = reference_file("scenes/desk.toml", 5, &dir);
    let scene = dir.join("one_iteration.toml");
    std::fs::write(
        &scene,
        std::fs::read_to_string("scenes/desk.toml")
            .unwrap()
            .replace("tolerance = 1e-10", "tolerance = 1e-10\nmax_iterations = 1"),
    )
    .unwrap();
    let out = ecp(&[
        "fit",
        scene.to_str().unwrap(),
        "--reference",
        reference.to_str().unwrap(),
        "--params",
        "mu,e_r",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        err.contains("mu = 0.22, e_r = 0.1") && err.contains("did not converge"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Any argmin solver drives the problem: L-BFGS with the Hager–Zhang line search, straight
/// from argmin's `Executor`, with the cost scaled so that the first step is moderate and the
/// line search's steps bounded (unbounded, its bracketing phase tries e_r = e^{huge} = inf,
/// which is an evaluation error, reported as the termination reason).
#[test]
fn argmin_drives_the_problem_directly() {
    use argmin::core::{Executor, State};
    use argmin::solver::linesearch::HagerZhangLineSearch;
    use argmin::solver::quasinewton::LBFGS;
    let p = problem(GradientMethod::Adjoint);
    let (_, g0) = p.loss_and_gradient(&[0.0, 0.0]).unwrap();
    let gmax = g0.iter().fold(0.0f64, |m, g| m.max(g.abs()));
    let p = p.with_cost_scale(0.1 / gmax);
    let line_search = HagerZhangLineSearch::new().with_bounds(0.0, 10.0).unwrap();
    let solver = LBFGS::new(line_search, 7)
        .with_tolerance_grad(1e-12)
        .unwrap()
        .with_tolerance_cost(0.0)
        .unwrap();
    let result = Executor::new(p.clone(), solver)
        .configure(|s| s.param(vec![0.0, 0.0]).max_iters(60))
        .run()
        .unwrap();
    let theta = p.values_at(result.state.get_best_param().unwrap());
    assert!(
        (theta[0] - 0.22).abs() <= 1e-6,
        "{theta:?} {:?} {:?}",
        result.state.get_termination_status(),
        p.monitor().last_error()
    );
    assert!((theta[1] - 0.1).abs() <= 1e-5, "{theta:?}");
    assert!(p.counts().cost_evals > 0 && p.monitor().last_error().is_none());
}
