//! The `ecp` binary against `docs/outputs.md`: outputs and exit statuses of `run`, `check` and
//! `compare` on every scene file, and one broken file per bad-input class (exit status 2, a
//! one-paragraph error naming file, key and line, no panic).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn ecp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ecp"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("the ecp binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// A fresh directory for one test's files.
fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecp-cli-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn scene_files() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes"))
            .expect("scenes/ exists")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "toml"))
            .collect();
    files.sort();
    files
}

#[test]
fn every_scenario_of_the_spec_has_its_scene_file() {
    let names: Vec<String> = scene_files()
        .iter()
        .filter_map(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .collect();
    for want in [
        "a1_sliding",
        "a2_push_stick",
        "a2_push_slide",
        "a3_spin",
        "a4_incline_10",
        "a4_incline_25",
        "a5_drop",
        "a5_drop_tilted",
        "a6_tip_90",
        "a6_tip_110",
        "desk",
    ] {
        assert!(
            names.iter().any(|n| n == want),
            "scenes/{want}.toml is missing"
        );
    }
}

#[test]
fn check_validates_every_scene_file() {
    for file in scene_files() {
        let path = file.to_string_lossy().into_owned();
        let o = ecp(&["check", &path]);
        assert!(o.status.success(), "check {path}: {}", stderr(&o));
        let out = stdout(&o);
        for what in [
            "bodies:",
            "hull:",
            "faces",
            "pieces:",
            "mass",
            "contacts:",
            "half-spaces:",
        ] {
            assert!(
                out.contains(what),
                "check {path} does not print {what}:\n{out}"
            );
        }
    }
    let o = ecp(&["check", "scenes/desk.toml"]);
    let out = stdout(&o);
    assert!(out.contains("pieces: 5 (36 vertices"), "{out}");
    assert!(out.contains("hull: 8 vertices, 6 faces"), "{out}");
}

#[test]
fn compare_runs_on_every_scene_file() {
    let dir = temp_dir("compare");
    for file in scene_files() {
        let path = file.to_string_lossy().into_owned();
        let stem = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let out = dir.join(&stem);
        let o = ecp(&[
            "compare",
            &path,
            "--steps",
            "3",
            "--out",
            &out.to_string_lossy(),
        ]);
        assert!(o.status.success(), "compare {path}: {}", stderr(&o));
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("compare.json")).expect("compare.json written"),
        )
        .expect("compare.json is JSON");
        assert_eq!(json["scene"], stem.as_str());
        let runs = json["runs"].as_array().expect("runs");
        assert!(!runs.is_empty());
        for r in runs {
            for key in [
                "formulation",
                "solver",
                "steps",
                "max_residual",
                "step_us",
                "max_diff_v",
                "max_diff_w",
            ] {
                assert!(!r[key].is_null(), "compare.json run lacks {key}");
            }
            assert_eq!(r["steps"], 3);
        }
        assert_eq!(runs[0]["max_diff_v"], 0.0);
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn run_writes_trajectory_summary_and_status_0() {
    let dir = temp_dir("run");
    let out = dir.join("a1");
    let o = ecp(&[
        "run",
        "scenes/a1_sliding.toml",
        "--out",
        &out.to_string_lossy(),
        "--steps",
        "12",
        "--no-plots",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(out.join("trajectory.csv")).expect("trajectory.csv");
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(
        lines[0],
        "t,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz,ecp_x,ecp_y,ecp_z,pn,pt,po,pr,sigma,min_gap,mode,iterations,residual,solve_us,fallback"
    );
    assert_eq!(lines.len(), 13, "header plus 12 rows");
    let vx: f64 = lines[1]
        .split(',')
        .nth(8)
        .and_then(|v| v.parse().ok())
        .expect("vx");
    assert!((vx - (1.0 - 0.3 * 9.8 * 0.01)).abs() <= 1e-9, "vx = {vx}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary"))
            .expect("JSON");
    for key in [
        "scene",
        "formulation",
        "solver",
        "h",
        "steps",
        "converged_steps",
        "failed_steps",
        "wall_s",
        "step_us",
        "iterations",
        "max_residual",
        "max_penetration",
        "mode_sequence",
        "final",
    ] {
        assert!(!summary[key].is_null(), "summary.json lacks {key}");
    }
    for key in ["min", "median", "mean", "p95", "max"] {
        assert!(summary["step_us"][key].is_number(), "step_us.{key}");
    }
    assert_eq!(summary["scene"], "a1_sliding");
    assert_eq!(summary["solver"], "newton");
    assert_eq!(summary["formulation"], "hull");
    assert_eq!(summary["steps"], 12);
    assert_eq!(summary["failed_steps"], 0);
    assert_eq!(summary["mode_sequence"][0]["mode"], "patch");
    assert!(summary["max_residual"].as_f64().is_some_and(|r| r <= 1e-10));
    assert_eq!(
        summary["final"]["position"].as_array().map(Vec::len),
        Some(3)
    );
    assert_eq!(
        summary["final"]["orientation"].as_array().map(Vec::len),
        Some(4)
    );
    // Not a terminal: no progress bar, and --quiet silences standard output.
    let o = ecp(&[
        "run",
        "scenes/a1_sliding.toml",
        "--out",
        &out.to_string_lossy(),
        "--steps",
        "2",
        "--no-plots",
        "--quiet",
    ]);
    assert!(o.status.success());
    assert!(
        o.stdout.is_empty() && o.stderr.is_empty(),
        "{}{}",
        stdout(&o),
        stderr(&o)
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// A2 (pushed, sliding) with Newton limited to one iteration per step, written into `dir`: its
/// first step cannot be solved by Newton alone. (A1's first step can: it is a linear LCP, which
/// one Josephy–Newton step, the MCP linearised and solved by pivoting, solves exactly.)
fn a2_with_one_newton_iteration(dir: &Path) -> std::path::PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/a2_push_slide.toml"),
    )
    .expect("a2")
    .replace(
        "[solver]\nname = \"newton\"",
        "[solver]\nname = \"newton\"\nmax_iterations = 1",
    );
    assert!(
        text.contains("max_iterations = 1"),
        "the scene's solver section changed"
    );
    let scene = dir.join("a2_one_iteration.toml");
    std::fs::write(&scene, text).expect("write");
    scene
}

#[test]
fn a_failed_step_gives_status_1_and_keeps_what_was_computed() {
    let dir = temp_dir("fail");
    // Sliding needs several iterations; one is not enough, so the first step fails.
    let scene = a2_with_one_newton_iteration(&dir);
    let out = dir.join("out");
    let o = ecp(&[
        "run",
        &scene.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--no-plots",
        "--no-fallbacks",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("could not be solved"), "{}", stderr(&o));
    let csv = std::fs::read_to_string(out.join("trajectory.csv")).expect("csv kept");
    assert_eq!(csv.lines().count(), 2, "header and the failed step's row");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary"))
            .expect("JSON");
    assert_eq!(summary["failed_steps"], 1);
    assert_eq!(summary["failure"]["step"], 1);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_step_the_backend_cannot_solve_is_solved_by_a_fallback_and_marked() {
    let dir = temp_dir("fallback");
    // One Newton iteration cannot solve A2's first step; the fallbacks (PATH, conic, then
    // substeps, each with the same one-iteration limit) must, with the same physics.
    let scene = a2_with_one_newton_iteration(&dir);
    let out = dir.join("out");
    let o = ecp(&[
        "run",
        &scene.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--no-plots",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(out.join("trajectory.csv")).expect("csv");
    let lines: Vec<&str> = csv.lines().collect();
    assert!(lines[0].ends_with(",fallback"));
    let first: Vec<&str> = lines[1].split(',').collect();
    let how = first.last().expect("fallback column");
    assert!(
        how.starts_with("backend:") || how.starts_with("substeps:"),
        "first step solved by {how:?}"
    );
    // The same first step as Newton's without the limit, whoever solved it.
    let free = dir.join("free");
    let o = ecp(&[
        "run",
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenes/a2_push_slide.toml")
            .to_string_lossy(),
        "--out",
        &free.to_string_lossy(),
        "--no-plots",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let free_csv = std::fs::read_to_string(free.join("trajectory.csv")).expect("csv");
    let free_first: Vec<&str> = free_csv
        .lines()
        .nth(1)
        .expect("a step")
        .split(',')
        .collect();
    let vx: f64 = first[8].parse().expect("vx");
    let free_vx: f64 = free_first[8].parse().expect("vx");
    assert!(
        (vx - free_vx).abs() < 1e-9,
        "v_x = {vx}, without the limit {free_vx}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary"))
            .expect("JSON");
    assert_eq!(summary["failed_steps"], 0);
    let fb = &summary["fallbacks"];
    assert!(fb["backend"].as_u64().unwrap_or(0) + fb["substeps"].as_u64().unwrap_or(0) >= 1);
    assert_eq!(fb["failed"], 0);
    let _ = std::fs::remove_dir_all(dir);
}

/// A valid base scene; each bad-input case edits one line of it.
const BASE: &str = r#"name = "broken"

[simulation]
h = 0.01
duration = 0.05

[friction]
mu = 0.3
e_r = 0.1

[solver]
name = "newton"

[[half_spaces]]
normal = [0, 0, 1]

[[bodies]]
name = "box"
mass = 10.0
inertia = [0.1667, 0.1667, 0.2667]
position = [0, 0, 0.1]

[bodies.load]
force = ["5*sin(2*pi*t)", 0, 0]

[[bodies.pieces]]
box = [0.4, 0.4, 0.2]
"#;

struct Case {
    class: &'static str,
    from: &'static str,
    to: &'static str,
    key: Option<&'static str>,
    /// The line the error must name: the line of `to` in the broken file.
    has_line: bool,
    words: &'static str,
}

#[test]
fn every_bad_input_class_is_a_clear_error_with_status_2() {
    let cases = [
        Case {
            class: "TOML syntax",
            from: "mass = 10.0",
            to: "mass = = 10.0",
            key: None,
            has_line: true,
            words: "syntax",
        },
        Case {
            class: "unknown key",
            from: "mass = 10.0",
            to: "mass = 10.0\nmas = 10.0",
            key: Some("mas"),
            has_line: true,
            words: "unknown",
        },
        Case {
            class: "wrong type",
            from: "mass = 10.0",
            to: "mass = \"ten\"",
            key: Some("bodies[0].mass"),
            has_line: true,
            words: "wrong type",
        },
        Case {
            class: "negative mass",
            from: "mass = 10.0",
            to: "mass = -10.0",
            key: Some("bodies[0].mass"),
            has_line: true,
            words: "must be > 0",
        },
        Case {
            class: "inertia not positive definite",
            from: "inertia = [0.1667, 0.1667, 0.2667]",
            to: "inertia = [0.1667, -0.1667, 0.2667]",
            key: Some("bodies[0].inertia"),
            has_line: true,
            words: "positive definite",
        },
        Case {
            class: "flat hull",
            from: "box = [0.4, 0.4, 0.2]",
            to: "points = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]",
            key: Some("bodies[0].pieces[0].points"),
            has_line: true,
            words: "coplanar",
        },
        Case {
            class: "degenerate hull",
            from: "box = [0.4, 0.4, 0.2]",
            to: "points = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]",
            key: Some("bodies[0].pieces[0].points"),
            has_line: true,
            words: "collinear",
        },
        Case {
            class: "mu < 0",
            from: "mu = 0.3",
            to: "mu = -0.3",
            key: Some("friction.mu"),
            has_line: true,
            words: "μ must be ≥ 0",
        },
        Case {
            class: "h <= 0",
            from: "h = 0.01",
            to: "h = 0.0",
            key: Some("simulation.h"),
            has_line: true,
            words: "must be > 0",
        },
        Case {
            class: "NaN",
            from: "position = [0, 0, 0.1]",
            to: "position = [0, nan, 0.1]",
            key: Some("bodies[0].position"),
            has_line: true,
            words: "finite",
        },
        Case {
            class: "unknown solver name",
            from: "name = \"newton\"",
            to: "name = \"newtn\"",
            key: Some("solver.name"),
            has_line: true,
            words: "unknown solver",
        },
        Case {
            class: "expression that does not parse",
            from: "\"5*sin(2*pi*t)\"",
            to: "\"5*sin(2*pi*t\"",
            key: Some("bodies[0].load.force"),
            has_line: true,
            words: "does not parse",
        },
        Case {
            class: "expression with an unknown name",
            from: "\"5*sin(2*pi*t)\"",
            to: "\"5*sin(2*pi*tt)\"",
            key: Some("bodies[0].load.force"),
            has_line: true,
            words: "unknown name `tt`",
        },
        Case {
            class: "missing key",
            from: "mu = 0.3\n",
            to: "",
            key: Some("mu"),
            has_line: false,
            words: "missing",
        },
        Case {
            class: "body inside the ground",
            from: "position = [0, 0, 0.1]",
            to: "position = [0, 0, 0.05]",
            key: Some("bodies[0].position"),
            has_line: true,
            words: "inside",
        },
    ];
    let dir = temp_dir("bad");
    for (i, case) in cases.iter().enumerate() {
        assert!(
            BASE.contains(case.from),
            "{}: base lacks {:?}",
            case.class,
            case.from
        );
        let text = BASE.replacen(case.from, case.to, 1);
        let path = dir.join(format!("case{i}.toml"));
        std::fs::write(&path, &text).expect("write");
        let o = ecp(&[
            "run",
            &path.to_string_lossy(),
            "--out",
            &dir.join("out").to_string_lossy(),
            "--no-plots",
        ]);
        let err = stderr(&o);
        assert_eq!(
            o.status.code(),
            Some(2),
            "{}: status {:?}, stderr {err}",
            case.class,
            o.status.code()
        );
        assert!(
            !err.contains("panicked") && !err.contains("RUST_BACKTRACE"),
            "{}: panic: {err}",
            case.class
        );
        assert_eq!(
            err.trim_end().lines().count(),
            1,
            "{}: one paragraph expected: {err}",
            case.class
        );
        assert!(
            err.contains(&path.to_string_lossy().into_owned()),
            "{}: file not named: {err}",
            case.class
        );
        if let Some(key) = case.key {
            assert!(
                err.contains(key),
                "{}: key {key} not named: {err}",
                case.class
            );
        }
        if case.has_line {
            let first = case.to.lines().last().unwrap_or(case.to);
            let line = text
                .lines()
                .position(|l| l.contains(first))
                .map(|l| l + 1)
                .expect("line");
            assert!(
                err.contains(&format!("line {line}")),
                "{}: line {line} not named: {err}",
                case.class
            );
        }
        assert!(
            err.contains(case.words),
            "{}: expected {:?} in: {err}",
            case.class,
            case.words
        );
        assert!(
            !dir.join("out").join("summary.json").exists(),
            "{}: outputs written for bad input",
            case.class
        );
    }
    // File missing.
    let o = ecp(&["run", "scenes/no_such_scene.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("scenes/no_such_scene.toml") && stderr(&o).contains("cannot read"),
        "{}",
        stderr(&o)
    );
    // Unknown solver name on the command line.
    let o = ecp(&["run", "scenes/a1_sliding.toml", "--solver", "simplex"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("unknown solver \"simplex\""),
        "{}",
        stderr(&o)
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn lcp_command_solves_reports_rays_and_refuses_bad_files() {
    let dir = temp_dir("lcp");
    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).expect("write");
        p.to_string_lossy().into_owned()
    };
    // 0 ≤ z ⊥ M z + q ≥ 0 with M = [[2, 1], [1, 2]], q = (−1, 1): z = (½, 0), w = (0, 3/2).
    let ok = write("ok.json", r#"{"M": [[2, 1], [1, 2]], "q": [-1, 1]}"#);
    let o = ecp(&["lcp", &ok]);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON on stdout");
    let z: Vec<f64> = serde_json::from_value(json["z"].clone()).expect("z");
    let w: Vec<f64> = serde_json::from_value(json["w"].clone()).expect("w");
    assert!((z[0] - 0.5).abs() < 1e-14 && z[1].abs() < 1e-14, "{z:?}");
    assert!(w[0].abs() < 1e-14 && (w[1] - 1.5).abs() < 1e-14, "{w:?}");
    assert!(json["pivots"].as_u64().is_some_and(|p| p >= 1));
    assert!(json["solve_us"].is_number());
    assert!(json["residual"].as_f64().is_some_and(|r| r <= 1e-12));
    assert!(json.get("best_us").is_none() && json.get("repeat").is_none());
    // --repeat N: N warm solves after the first, their best and median time.
    let o = ecp(&["lcp", &ok, "--repeat", "5"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON on stdout");
    assert_eq!(json["repeat"], 5);
    let (best, median) = (json["best_us"].as_f64(), json["median_us"].as_f64());
    assert!(
        best.zip(median).is_some_and(|(b, m)| b > 0.0 && b <= m),
        "{best:?} {median:?}"
    );
    let z2: Vec<f64> = serde_json::from_value(json["z"].clone()).expect("z");
    assert_eq!(z, z2);
    // Infeasible: w = −z − 1 < 0 for every z ≥ 0. Lemke ends on a ray: status 1, a clear error.
    let ray = write("ray.json", r#"{"M": [[-1, 0], [0, -1]], "q": [-1, -1]}"#);
    let o = ecp(&["lcp", &ray]);
    assert_eq!(o.status.code(), Some(1));
    let json: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("JSON on stdout");
    assert_eq!(json["status"], "ray_termination");
    assert!(stderr(&o).contains("ray"), "{}", stderr(&o));
    // Bad files: status 2, file and key named.
    for (name, text, words) in [
        ("notsquare.json", r#"{"M": [[1, 2]], "q": [1]}"#, "M[0]"),
        ("syntax.json", r#"{"M": [[1]], "q": [1]"#, "line 1"),
        (
            "unknown.json",
            r#"{"M": [[1]], "q": [1], "r": 2}"#,
            "unknown field",
        ),
        ("type.json", r#"{"M": [["a"]], "q": [1]}"#, "invalid type"),
    ] {
        let p = write(name, text);
        let o = ecp(&["lcp", &p]);
        assert_eq!(o.status.code(), Some(2), "{name}: {}", stderr(&o));
        assert!(
            stderr(&o).contains(&p) && stderr(&o).contains(words),
            "{name}: {}",
            stderr(&o)
        );
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// Every formulation of `docs/model.md#unknowns`, `docs/model.md#other-formulations` is reachable
/// from the command line; the conic backend refuses (status 2, naming the way out) the formulations
/// that have no step structure; `compare` runs what can run and lists the rest as skipped in
/// `compare.json`.
#[test]
fn formulations_from_the_command_line() {
    let dir = temp_dir("formulations");
    let out = dir.join("union");
    let o = ecp(&[
        "run",
        "scenes/a1_sliding.toml",
        "--formulation",
        "union",
        "--steps",
        "5",
        "--no-plots",
        "--out",
        &out.to_string_lossy(),
    ]);
    assert!(o.status.success(), "union run: {}", stderr(&o));
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("summary.json")).expect("summary.json"),
    )
    .expect("JSON");
    assert_eq!(summary["formulation"], "union");
    assert_eq!(summary["failed_steps"], 0);

    for f in ["reduced", "point"] {
        let o = ecp(&[
            "run",
            "scenes/a1_sliding.toml",
            "--formulation",
            f,
            "--solver",
            "conic",
            "--steps",
            "1",
            "--out",
            &dir.join(f).to_string_lossy(),
        ]);
        assert_eq!(o.status.code(), Some(2), "conic with {f}: {}", stderr(&o));
        let err = stderr(&o);
        assert!(
            err.contains("conic") && err.contains(f) && err.contains("--solver newton"),
            "{err}"
        );
        assert!(!err.contains("panicked"), "{err}");
    }
    let o = ecp(&["run", "scenes/a1_sliding.toml", "--formulation", "bogus"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("\"reduced\""), "{}", stderr(&o));

    let cmp = dir.join("compare");
    let o = ecp(&[
        "compare",
        "scenes/a1_sliding.toml",
        "--formulations",
        "hull,union,point",
        "--solvers",
        "newton,conic",
        "--steps",
        "3",
        "--out",
        &cmp.to_string_lossy(),
    ]);
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(cmp.join("compare.json")).expect("compare.json written"),
    )
    .expect("JSON");
    let labels: Vec<String> = json["runs"]
        .as_array()
        .expect("runs")
        .iter()
        .map(|r| format!("{}-{}", r["formulation"], r["solver"]).replace('"', ""))
        .collect();
    for l in ["hull-newton", "hull-conic", "union-newton", "union-conic"] {
        assert!(labels.iter().any(|x| x == l), "{l} missing from {labels:?}");
    }
    let skipped = json["skipped"].as_array().expect("skipped");
    assert!(
        skipped
            .iter()
            .any(|k| k["formulation"] == "point" && k["solver"] == "conic"),
        "{skipped:?}"
    );
    assert!(stdout(&o).contains("skipped"), "{}", stdout(&o));
    let _ = std::fs::remove_dir_all(dir);
}
