//! The random-scene stress suite (docs/stress.md): the generator's guarantees, the independent
//! measures of the runner, a fast subset of the suite (one short scene per category with PATH
//! and Newton), and the regression scenes of `tests/stress_regressions/`.
//!
//! The full run is `cargo run --release --example stress`; its summary is in docs/stress.md.

use std::path::{Path, PathBuf};
use std::time::Duration;

use ecp::formulations::BodyState;
use ecp::stress::runner::{ENERGY_LIMIT, PENETRATION_LIMIT, penetration, total_energy};
use ecp::stress::{Category, DEFAULT_COUNT, DEFAULT_SEED, RunConfig, RunResult, generate};
use nalgebra::{Vector3, Vector4};

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ecp-stress-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

/// The documented suite: at least 150 scenes, every category at least 11 times, meshes in OBJ
/// and STL and in millimetres, several-body scenes, forced and unforced ones, parameters in
/// the ranges; the same text from the same seed; every scene loads (so no body starts
/// inside an obstacle), and the bodies of the touching categories start exactly touching.
#[test]
fn generator_covers_every_category_deterministically() {
    let scenes = generate(DEFAULT_SEED, DEFAULT_COUNT);
    assert!(scenes.len() >= 150);
    assert_eq!(scenes, generate(DEFAULT_SEED, DEFAULT_COUNT));
    assert_ne!(scenes[0].toml, generate(DEFAULT_SEED + 1, 1)[0].toml);
    for c in Category::ALL {
        let n = scenes.iter().filter(|s| s.category == c).count();
        assert!(n >= 11, "{c}: {n} scenes");
    }
    let files: Vec<&String> = scenes
        .iter()
        .flat_map(|s| s.files.iter().map(|f| &f.0))
        .collect();
    assert!(files.iter().any(|f| f.ends_with(".obj")));
    assert!(files.iter().any(|f| f.ends_with(".stl")));
    assert!(scenes.iter().any(|s| s.toml.contains("scale = 0.001")));
    assert!(scenes.iter().any(|s| s.unforced) && scenes.iter().any(|s| !s.unforced));
    let dir = temp_dir("gen");
    for s in &scenes {
        let path = s.write_to(&dir).expect("writes");
        let file = ecp::scene::load_scene(&path).unwrap_or_else(|e| panic!("{}: {e}", s.name));
        let sc = &file.scene;
        assert!((1e-3..=1e-2).contains(&sc.h), "{}: h = {}", s.name, sc.h);
        assert!((0.5..=2.0).contains(&sc.duration), "{}", s.name);
        assert!((0.1..=1.2).contains(&sc.friction.mu), "{}", s.name);
        assert_eq!(
            s.unforced,
            file.loads.iter().all(|l| l.is_none()),
            "{}: unforced flag",
            s.name
        );
        if s.category == Category::MultiBody {
            assert!(sc.bodies.len() >= 2, "{}", s.name);
        }
        let initial: Vec<BodyState> = sc.bodies.iter().map(|b| b.initial).collect();
        let gaps = ecp::stress::runner::gaps_of(sc, &initial);
        let lowest = gaps.iter().flatten().copied().fold(f64::INFINITY, f64::min);
        assert!(lowest >= -1e-12, "{}: starts {lowest:e} m inside", s.name);
        if matches!(
            s.category,
            Category::ConvexPush | Category::UnionRest | Category::UnionTip | Category::Ladder
        ) {
            assert!(lowest <= 1e-12, "{}: starts {lowest:e} m above", s.name);
        }
    }
    std::fs::remove_dir_all(dir).ok();
}

/// The penetration is recomputed from the pose and the body's vertices: a 0.4 × 0.2 × 0.1 box
/// turned 90° about x and sunk 0.01 m penetrates the floor by 0.01 m (to 1e-15).
#[test]
fn independent_penetration_of_a_sunk_box() {
    let text = "[simulation]\nh = 0.01\nduration = 0.1\n[friction]\nmu = 0.3\ne_r = 0.1\n\
                [[half_spaces]]\nnormal = [0, 0, 1]\n[[bodies]]\nmass = 1\ninertia = \"uniform\"\n\
                position = [0, 0, 0.05]\n[[bodies.pieces]]\nbox = [0.4, 0.2, 0.1]\n";
    let file = ecp::scene::parse_scene(text, "box.toml".as_ref()).expect("parses");
    let half = std::f64::consts::FRAC_1_SQRT_2;
    // Turned 90° about x: the 0.2 m edge is vertical, so the CM is 0.1 m above the floor.
    let state = BodyState {
        x: Vector3::new(0.3, -0.2, 0.09),
        q: Vector4::new(half, half, 0.0, 0.0),
        v: Vector3::zeros(),
        w: Vector3::zeros(),
    };
    let pen = penetration(&file.scene, &[state]);
    assert!((pen - 0.01).abs() <= 1e-15, "penetration {pen:e}");
    let above = BodyState {
        x: Vector3::new(0.0, 0.0, 0.11),
        ..state
    };
    assert_eq!(penetration(&file.scene, &[above]), 0.0);
}

/// The runner's energy (from the recorded states) agrees with the stepper's own to 1e-12 of
/// the scene's energy at every step of a tossed, spinning body.
#[test]
fn independent_energy_matches_the_stepper() {
    let scene = generate(DEFAULT_SEED, 2)
        .pop()
        .expect("the second scene is a toss");
    assert_eq!(scene.category, Category::ConvexToss);
    let dir = temp_dir("energy");
    let path = scene.write_to(&dir).expect("writes");
    let file = ecp::scene::load_scene(&path).expect("loads");
    let options = ecp::run::RunOptions {
        out_dir: dir.join("run"),
        solver: Some("path".into()),
        steps: Some(20),
        plots: false,
        keep_going: true,
        ..ecp::run::RunOptions::default()
    };
    let outcome = ecp::run::run_scene(&file, &options, |_| {}).expect("runs");
    let scale = ecp::stress::runner::energy_scale(&file.scene);
    for r in &outcome.records {
        let e = total_energy(&file.scene, &r.bodies);
        assert!(
            (e - r.energy).abs() <= 1e-12 * scale,
            "step {}: {e} vs the stepper's {}",
            r.step,
            r.energy
        );
    }
    std::fs::remove_dir_all(dir).ok();
}

/// Steps of each run of the fast subset.
const FAST_STEPS: usize = 40;

/// Runs the first scene of each category in `cats` with `solver` for [`FAST_STEPS`] steps.
fn fast_subset(solver: &str, cats: &[Category]) -> Vec<RunResult> {
    let dir = temp_dir(&format!("fast-{solver}"));
    let scenes = generate(DEFAULT_SEED, Category::ALL.len());
    let mut out = Vec::new();
    for s in scenes.iter().filter(|s| cats.contains(&s.category)) {
        let path = s.write_to(&dir.join("scenes")).expect("writes");
        let config = RunConfig {
            solver: solver.to_string(),
            steps: Some(FAST_STEPS),
            time_limit: Some(Duration::from_secs(600)),
            out_dir: dir.join("runs").join(&s.name),
            fallbacks: false,
        };
        out.push(ecp::stress::run_file(&path, &config));
    }
    std::fs::remove_dir_all(dir).ok();
    out
}

/// Every run converged at every step, penetrates at most [`PENETRATION_LIMIT`], and no unforced
/// run gains more than [`ENERGY_LIMIT`] of its energy scale outside opening steps.
fn assert_passed(results: &[RunResult]) {
    let bad: Vec<String> = results
        .iter()
        .filter(|r| !r.passed())
        .map(|r| {
            format!(
                "{} {}: {} of {} steps failed (first {:?}: {:?}), error {:?}, penetration {:e} m, \
                 energy rise {:e}",
                r.scene,
                r.solver,
                r.failed_steps,
                r.steps,
                r.first_failed_step,
                r.first_failure,
                r.error,
                r.max_penetration,
                r.energy_rise_outside_openings
            )
        })
        .collect();
    assert!(
        bad.is_empty(),
        "runs that did not pass:\n{}",
        bad.join("\n")
    );
    for r in results {
        assert_eq!(r.steps, FAST_STEPS.min(r.planned_steps), "{}", r.scene);
        assert!(r.max_penetration <= PENETRATION_LIMIT);
        assert!(!r.unforced || r.energy_rise_outside_openings <= ENERGY_LIMIT);
    }
}

#[test]
fn fast_subset_path() {
    assert_passed(&fast_subset("path", &Category::ALL));
}

/// Newton on the first scene of every category. `000_convex_drop` (one landing step on a new
/// face) failed here until the smoothing continuation and the warm start that follows the
/// closest feature (docs/newton.md#smoothing-continuation).
#[test]
fn fast_subset_newton() {
    assert_passed(&fast_subset("newton", &Category::ALL));
}

/// The conic backend on the first scene of every category: `000_convex_drop` stagnated at step
/// 8 until the Newton finish from the fixed point's best iterate (docs/stress.md).
#[test]
fn fast_subset_conic() {
    assert_passed(&fast_subset("conic", &Category::ALL));
}

/// The (scene, backend) rows of `manifest.csv` whose failure with that backend alone is open (no
/// cure yet): `regressions` asserts that they still fail *and say so* (failed steps or a timeout
/// reported, never a point passed off as a step's answer), and tells which to drop from here once
/// one passes. Empty since the last row, the conic backend on `s20261212_022_v_trough` (a vertex
/// in the crease of a V trough loaded by both sides,
/// `docs/newton.md#a-jam-in-the-crease-s20261212_022_v_trough-step-62`), was cured by the conic
/// Newton finish's continuation in the friction coefficient (`docs/latency.md`, wip-conic022), as
/// Newton's row was by Newton's (`docs/newton.md#a-continuation-in-the-friction-coefficient`);
/// the same stage cures the conic backend on `s20270102_057_union_tip` (a table tipping on an
/// edge past a fold of its solution branch, `docs/latency.md`, wip-tip057).
/// Kept: a regression scene added while its failure is still open is listed here.
/// `s20270320_070_union_tip` with Newton (held-out seed 20270320, `docs/stress.md`, branch
/// wip-heldout4): a chain spun to 430 rad/s by its load lands at step 97 on a vertex far from
/// the warm start's contact point; every attempt stalls at a natural residual of 7.5e-5, steps
/// 97–100 fail (the state kept) and step 101 converges; PATH solves step 97 in 7 iterations.
/// Cured on branch wip-tip070 (`NewtonSettings::structure_reseed`: the solve again from the
/// warm start's contacts re-derived by the structure), so out of the list.
/// Open since the fifteenth session (`docs/stress.md`, run 67): `s20270417_022_v_trough` with
/// Newton and PATH and `s20270424_022_v_trough` with PATH, bodies of μ > 1 wedged in a V trough
/// (the conic backend converges every step of both).
const OPEN: &[(&str, &str)] = &[
    ("s20270417_022_v_trough", "newton"),
    ("s20270417_022_v_trough", "path"),
    ("s20270424_022_v_trough", "path"),
];

/// The regression scenes of `tests/stress_regressions/` (every generated scene that ever
/// failed with some backend), each run to its end with the backends `manifest.csv` lists for it
/// (only the scenes whose name contains `$ECP_STRESS_ONLY`, when set); the rows of [`OPEN`] must
/// still fail, reported as failures.
fn regressions(solver: &str) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/stress_regressions");
    let manifest = std::fs::read_to_string(dir.join("manifest.csv")).expect("manifest.csv");
    let out = temp_dir(&format!("regr-{solver}"));
    // `ECP_STRESS_ONLY=TEXT` keeps the scenes whose name contains TEXT.
    let only = std::env::var("ECP_STRESS_ONLY").ok();
    let mut results = Vec::new();
    let mut open = Vec::new();
    for line in manifest.lines().skip(1) {
        let mut cols = line.split(',');
        let (Some(scene), Some(backend)) = (cols.next(), cols.next()) else {
            continue;
        };
        if backend != solver || only.as_deref().is_some_and(|o| !scene.contains(o)) {
            continue;
        }
        let config = RunConfig {
            solver: solver.to_string(),
            steps: None,
            time_limit: Some(ecp::stress::runner::TIME_LIMIT),
            out_dir: out.join(scene),
            fallbacks: false,
        };
        let result = ecp::stress::run_file(&dir.join(format!("{scene}.toml")), &config);
        if OPEN.contains(&(scene, solver)) {
            open.push((scene.to_string(), result));
        } else {
            results.push(result);
        }
    }
    std::fs::remove_dir_all(out).ok();
    // An open row that passes, or fails without a failed step or a timeout, has changed.
    let cured: Vec<&str> = open
        .iter()
        .filter(|(_, r)| r.passed() || (r.failed_steps == 0 && !r.timed_out))
        .map(|(scene, _)| scene.as_str())
        .collect();
    assert!(
        cured.is_empty(),
        "open regression scenes that no longer report a failure with {solver} (cured? then drop them from OPEN): {cured:?}"
    );
    let bad: Vec<String> = results
        .iter()
        .filter(|r| !r.passed())
        .map(|r| {
            format!(
                "{} {}: {} failed steps (first {:?}), timeout {}, error {:?}, penetration {:e} m, energy rise {:e}",
                r.scene,
                r.solver,
                r.failed_steps,
                r.first_failed_step,
                r.timed_out,
                r.error,
                r.max_penetration,
                r.energy_rise_outside_openings
            )
        })
        .collect();
    assert!(
        bad.is_empty(),
        "regression scenes that fail:\n{}",
        bad.join("\n")
    );
}

/// Passes since the damped restart of docs/newton.md; `s20261128_061_v_trough` (a scene of the
/// held-out seed 20261128, docs/stress.md), on which Newton alone stagnated from step 12, since
/// the complementary restart (`docs/newton.md#the-complementary-start`);
/// `s20261201_061_v_trough` (held-out seed 20261201), on which Newton alone stagnated from step
/// 70, since the complementary restart from the best point
/// (`docs/newton.md#the-complementary-start-from-the-best-point`). About 30 s: heavy, so
/// ignored. Run with
/// `cargo test --release --test stress regressions_newton -- --ignored`.
#[test]
#[ignore]
fn regressions_newton() {
    regressions("newton");
}

/// Passes since the robustness work of docs/stress.md (about a minute: heavy, so ignored). Run
/// with `cargo test --release --test stress regressions_path -- --ignored`.
#[test]
#[ignore]
fn regressions_path() {
    regressions("path");
}

/// Passes since the held-out seed's two conic scenes were mended (`s20261201_061_v_trough`,
/// `s20261201_153_room_corner`, docs/stress.md; about 15 s); `s20270327_137_corner_wall` (a
/// point set jammed in the corner of floor and wall, held-out seed 20270327) since the
/// unanchored pass after the failed local finishes (`ConicSettings::unanchored_retry`, branch
/// wip-heldout5); `s20270410_048_v_trough` (a box wedging into a trough's crease, held-out
/// seed 20270410, branch wip-heldout6) since the same pass. Run with
/// `cargo test --release --test stress regressions_conic -- --ignored`.
#[test]
#[ignore]
fn regressions_conic() {
    regressions("conic");
}

/// The regression scenes with the default settings of `ecp run` (Newton with the run driver's
/// fallbacks: the other backends, then substeps), each run past the first step at which any
/// backend failed on it (plus 5 steps), keeping the scenes `keep` accepts (given that step; `None`
/// for a run that timed out): every step must be solved, no vertex may sink below a half-space by
/// more than 1e-8 m, and an unforced scene must not gain energy — what a user gets on the scenes
/// that once failed. The per-backend runs without fallbacks are `regressions_newton`,
/// `regressions_path` and `regressions_conic` (ignored).
fn regressions_with_default_settings(keep: impl Fn(&str, Option<usize>) -> bool) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/stress_regressions");
    let manifest = std::fs::read_to_string(dir.join("manifest.csv")).expect("manifest.csv");
    let only = std::env::var("ECP_STRESS_ONLY").ok();
    // Scene → the latest first failing step over its backends (a timeout: the whole run).
    let mut scenes: std::collections::BTreeMap<String, Option<usize>> = Default::default();
    for line in manifest.lines().skip(1) {
        let mut cols = line.split(',');
        let (Some(scene), Some(_), Some(step)) = (cols.next(), cols.next(), cols.next()) else {
            continue;
        };
        if only.as_deref().is_some_and(|o| !scene.contains(o)) {
            continue;
        }
        let step = step.parse::<usize>().ok();
        let entry = scenes.entry(scene.to_string()).or_insert(Some(0));
        *entry = match (*entry, step) {
            (Some(a), Some(b)) => Some(a.max(b)),
            _ => None,
        };
    }
    scenes.retain(|scene, step| keep(scene, *step));
    assert!(!scenes.is_empty(), "no regression scene selected");
    let out = temp_dir("regr-default");
    let mut bad = Vec::new();
    for (scene, step) in &scenes {
        let config = RunConfig {
            solver: "newton".into(),
            steps: step.map(|s| s + 5),
            time_limit: Some(ecp::stress::runner::TIME_LIMIT),
            out_dir: out.join(scene),
            fallbacks: true,
        };
        let r = ecp::stress::run_file(&dir.join(format!("{scene}.toml")), &config);
        if !r.passed() {
            bad.push(format!(
                "{scene}: {} failed steps (first {:?}), timeout {}, error {:?}, penetration {:e} m, energy rise {:e}",
                r.failed_steps,
                r.first_failed_step,
                r.timed_out,
                r.error,
                r.max_penetration,
                r.energy_rise_outside_openings
            ));
        }
    }
    std::fs::remove_dir_all(out).ok();
    assert!(
        bad.is_empty(),
        "regression scenes that fail with the default settings:\n{}",
        bad.join("\n")
    );
}

/// Scenes whose steps take seconds each with today's backends (`062_room_corner`: PATH spends
/// minutes on one step); they run in the late test.
const SLOW_SCENES: [&str; 1] = ["062_room_corner"];

/// The regression scenes that failed within their first 100 steps (75 of 105), with the default
/// settings: the part of the check that is quick in a debug build.
#[test]
fn regressions_with_default_settings_early() {
    regressions_with_default_settings(|scene, step| {
        step.is_some_and(|s| s <= 100) && !SLOW_SCENES.contains(&scene)
    });
}

/// The other regression scenes (failing later, timing out, or slow), with the default settings.
/// Slow in a debug build; run with
/// `cargo test --release --test stress regressions_with_default_settings_late -- --ignored`.
#[test]
#[ignore]
fn regressions_with_default_settings_late() {
    regressions_with_default_settings(|scene, step| {
        step.is_none_or(|s| s > 100) || SLOW_SCENES.contains(&scene)
    });
}
