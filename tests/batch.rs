//! Batch runs (`ecp::batch`) and `ecp sweep`: results in input order, bitwise identical on 1 and
//! 2 threads and from run to run, parameters applied as the scene applies them, a failing run
//! reported in its row, bad `--param` specifications refused with a clear message.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use ecp::batch::{Axis, Batch, BatchOptions, Column, Grid, linspace, result_bytes, table};
use ecp::scene::{SceneFile, load_scene};
use ecp_formulations::sensitivity::Param;

fn scene(name: &str) -> SceneFile {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name);
    load_scene(&path).expect("the scene file loads")
}

fn specs(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

#[test]
fn a_desk_grid_is_bitwise_identical_on_one_and_two_threads_and_from_run_to_run() {
    let file = scene("desk.toml");
    let grid = Grid::parse(&specs(&["mu=0.15:0.3:3", "vx0=0.1,0.4"]), &file.scene).unwrap();
    let batch = Batch::grid(&file, &grid).unwrap();
    let options = |threads| BatchOptions {
        threads: Some(threads),
        steps: Some(60),
        records: true,
        ..BatchOptions::default()
    };
    let one = batch.run(&options(1)).unwrap();
    let two = batch.run(&options(2)).unwrap();
    let again = batch.run(&options(2)).unwrap();
    assert_eq!(one.len(), 6);
    assert!(
        one.iter()
            .all(|r| r.error.is_none() && r.records.len() == 60)
    );
    let bytes = result_bytes(&one);
    // The records are in the bytes: 6 runs × 60 steps of at least the 13 state numbers.
    assert!(bytes.len() > 6 * 60 * 13 * 8, "{} bytes", bytes.len());
    assert!(bytes == result_bytes(&two), "1 and 2 threads differ");
    assert!(
        bytes == result_bytes(&again),
        "two runs on 2 threads differ"
    );
    // Input order: the last axis varies fastest.
    let mid = (0.3 - 0.15) / 2.0 + 0.15; // numpy.linspace(0.15, 0.3, 3)[1], bit for bit
    let expected = [
        (0.15, 0.1),
        (0.15, 0.4),
        (mid, 0.1),
        (mid, 0.4),
        (0.3, 0.1),
        (0.3, 0.4),
    ];
    for (k, (r, (mu, vx0))) in two.iter().zip(expected).enumerate() {
        assert_eq!(r.index, k);
        assert_eq!(r.params[0], (Param::Mu, mu));
        assert_eq!(
            r.params[1],
            (Param::InitialVelocity { body: 0, axis: 0 }, vx0)
        );
    }
}

#[test]
fn each_grid_point_runs_the_scene_with_its_parameters() {
    // A1 (`docs/model.md#scenarios`): a box sliding at 1 m/s loses μ g h per step.
    let file = scene("a1_sliding.toml");
    let grid = Grid::parse(&specs(&["mu=0.1:0.3:3"]), &file.scene).unwrap();
    let results = Batch::grid(&file, &grid)
        .unwrap()
        .run(&BatchOptions {
            threads: Some(2),
            steps: Some(5),
            ..BatchOptions::default()
        })
        .unwrap();
    for (r, mu) in results.iter().zip([0.1, 0.2, 0.3]) {
        let v = r.summary.final_bodies[0].v.x;
        let want = 1.0 - mu * 9.8 * 0.01 * 5.0;
        assert!((v - want).abs() < 1e-9, "mu = {mu}: v = {v}, want {want}");
        assert_eq!(
            (
                r.summary.steps,
                r.summary.converged_steps,
                r.summary.failed_steps
            ),
            (5, 5, 0)
        );
        assert!(r.summary.max_residual < 1e-9);
        assert!(r.records.is_empty(), "records only when asked for");
    }
    // The same runs one by one, with the stepper directly: the same numbers, bit for bit.
    for (r, mu) in results.iter().zip([0.1, 0.2, 0.3]) {
        let mut single = file.clone();
        Param::Mu.set(&mut single.scene, mu).unwrap();
        let alone = Batch::scenes([single])
            .run(&BatchOptions {
                threads: Some(1),
                steps: Some(5),
                ..BatchOptions::default()
            })
            .unwrap();
        assert_eq!(alone[0].summary, r.summary);
    }
}

#[test]
fn a_run_that_fails_is_a_row_with_its_error_and_the_others_still_run() {
    // The reduced formulation needs the whole patch sliding on the support: the dropped box of
    // A5 starts in the air and is refused; A1 slides and runs.
    let batch = Batch::scenes([scene("a1_sliding.toml"), scene("a5_drop.toml")]);
    let results = batch
        .run(&BatchOptions {
            threads: Some(2),
            steps: Some(3),
            formulation: Some("reduced".to_string()),
            ..BatchOptions::default()
        })
        .unwrap();
    assert!(results[0].error.is_none(), "{:?}", results[0].error);
    assert_eq!(results[0].summary.converged_steps, 3);
    let err = results[1].error.as_deref().unwrap_or_default();
    assert!(err.contains("reduced"), "{err}");
    assert_eq!(results[1].summary.steps, 0);
    let cols = table(&results);
    let error = cols.iter().find(|(n, _)| n == "error").unwrap();
    match &error.1 {
        Column::Str(v) => assert!(v[0].is_empty() && v[1].contains("reduced")),
        other => panic!("error column {other:?}"),
    }
}

#[test]
fn grid_specifications_parse_and_bad_ones_say_how_to_fix_them() {
    let s = scene("a2_push_slide.toml").scene;
    let a = Axis::parse("mu=0.1:0.5:9", &s).unwrap();
    assert_eq!(a.values.len(), 9);
    assert_eq!((a.values[0], a.values[8]), (0.1, 0.5));
    assert!((a.values[4] - 0.3).abs() < 1e-15);
    let b = Axis::parse("fx=10,20,40", &s).unwrap();
    assert_eq!(
        b.param,
        Param::Load {
            body: 0,
            component: 0
        }
    );
    assert_eq!(b.values, vec![10.0, 20.0, 40.0]);
    assert_eq!(linspace(1.0, 2.0, 1), vec![1.0]);
    let grid = Grid {
        axes: vec![a.clone(), b],
    };
    assert_eq!(grid.len(), 27);
    assert_eq!(grid.points()[4][1].1, 20.0);
    for (spec, needle) in [
        ("mu", "NAME=VALUES"),
        ("friction=0.3", "unknown parameter"),
        ("mu=1:2", "neither START:STOP:COUNT nor a list"),
        ("mu=0.1:0.2:0", "whole number"),
        ("mu=a,b", "not a finite number"),
        ("mass[3]=1", "names body 3"),
    ] {
        let e = Axis::parse(spec, &s).unwrap_err().to_string();
        assert!(e.contains("--param") && e.contains(needle), "{spec}: {e}");
    }
    let twice = Grid::parse(&specs(&["mu=0.1", "mu=0.2"]), &s).unwrap_err();
    assert!(twice.to_string().contains("two --param"), "{twice}");
    // Values are checked as the scene checks them.
    let file = scene("a2_push_slide.toml");
    let neg = Grid::parse(&specs(&["mu=-0.1,0.2"]), &file.scene).unwrap();
    let e = Batch::grid(&file, &neg).unwrap_err().to_string();
    assert!(e.contains("μ must be ≥ 0"), "{e}");
    // A load given as a function of time has no constant component to sweep.
    let desk = scene("desk.toml");
    let e = Axis::parse("fx=1,2", &desk.scene).unwrap_err().to_string();
    assert!(e.contains("function of time"), "{e}");
}

fn ecp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ecp"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("the ecp binary runs")
}

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecp-batch-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

#[test]
fn ecp_sweep_writes_one_row_per_grid_point_whatever_the_thread_count() {
    let dir = temp_dir("sweep");
    let run = |threads: &str, out: &str| {
        let out = dir.join(out);
        let o = ecp(&[
            "sweep",
            "scenes/a2_push_slide.toml",
            "--param",
            "mu=0.2:0.4:3",
            "--param",
            "fx=20,40",
            "--steps",
            "10",
            "--threads",
            threads,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(out.join("sweep.csv")).unwrap()
    };
    let one = run("1", "one");
    let two = run("2", "two");
    assert_eq!(one, two, "sweep.csv must not depend on --threads");
    let lines: Vec<&str> = one.lines().collect();
    assert_eq!(lines.len(), 1 + 6);
    let header: Vec<&str> = lines[0].split(',').collect();
    assert_eq!(&header[..4], &["index", "scene", "mu", "fx"]);
    for col in [
        "steps",
        "failed_steps",
        "x",
        "vx",
        "wz",
        "max_residual",
        "error",
    ] {
        assert!(header.contains(&col), "{col} missing from {header:?}");
    }
    assert!(!header.contains(&"wall_s"), "timings are not results");
    // Row 1 is mu = 0.2, fx = 40: pushed at 40 N > μ m g, it slides: after 10 steps
    // v = (F/m − μ g) t = (4 − 1.96) · 0.1.
    let row: Vec<&str> = lines[2].split(',').collect();
    let vx: f64 = row[header.iter().position(|c| *c == "vx").unwrap()]
        .parse()
        .unwrap();
    assert_eq!((row[2], row[3]), ("0.2", "40"));
    assert!((vx - 2.04 * 0.1).abs() < 1e-9, "vx = {vx}");
    let timing = std::fs::read_to_string(dir.join("one").join("sweep_timing.csv")).unwrap();
    assert!(timing.starts_with("index,wall_s,solve_s"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn ecp_sweep_refuses_a_bad_param_with_exit_status_2() {
    let o = ecp(&["sweep", "scenes/a1_sliding.toml", "--param", "mu=0.1:0.2"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("option `--param`") && err.contains("START:STOP:COUNT"),
        "{err}"
    );
    let o = ecp(&["sweep", "scenes/a1_sliding.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("at least one --param"));
}
