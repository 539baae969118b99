//! The extension examples run in the test suite: each example's core is a function, included
//! here as a module and called (the example's `main` only prints what it returns).

use std::path::{Path, PathBuf};

use ecp::model::Counter;

#[allow(dead_code)]
#[path = "../examples/custom_backend.rs"]
mod custom_backend;

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecp-examples-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
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
