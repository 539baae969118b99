//! `ecp animate` and `ecp run --animate` (`docs/outputs.md#animationgif`): the GIF has the frames
//! the options ask for and shows the bodies moving; bad input is a clear error with exit status
//! 2; a multi-body run gets its multi-body plots, a one-body run does not.

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

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecp-animate-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// A decoded GIF: its size and each frame's delay (1/100 s) and RGBA pixels.
struct Gif {
    width: u16,
    height: u16,
    frames: Vec<(u16, Vec<u8>)>,
}

fn decode(path: &Path) -> Gif {
    let mut options = gif::DecodeOptions::new();
    options.set_color_output(gif::ColorOutput::RGBA);
    let file = std::fs::File::open(path).expect("the GIF exists");
    let mut decoder = options.read_info(file).expect("a GIF");
    let (width, height) = (decoder.width(), decoder.height());
    let mut frames = Vec::new();
    while let Some(frame) = decoder.read_next_frame().expect("a valid frame") {
        assert_eq!((frame.width, frame.height), (width, height), "full frames");
        frames.push((frame.delay, frame.buffer.to_vec()));
    }
    Gif {
        width,
        height,
        frames,
    }
}

/// Fraction of pixels that are not near-white.
fn inked(rgba: &[u8]) -> f64 {
    let px = rgba.chunks(4);
    let n = px.len();
    px.filter(|p| p[..3].iter().any(|&c| c < 200)).count() as f64 / n as f64
}

/// D5 (C hits B at 1 m/s): 12 steps.
fn d5_run(dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        "scenes/d5_collision.toml",
        "--steps",
        "12",
        "--quiet",
        "--out",
    ];
    let out = s(dir);
    args.push(&out);
    args.extend_from_slice(extra);
    ecp(&args)
}

#[test]
fn run_animate_draws_t0_and_every_step_of_a_short_run() {
    let dir = temp_dir("run");
    let o = d5_run(&dir, &["--animate", "--no-plots"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let gif = decode(&dir.join("animation.gif"));
    // 12 steps at the defaults (20 fps, at most 10 s): every step, and t = 0.
    assert_eq!(gif.frames.len(), 13);
    assert_eq!((gif.width, gif.height), (800, 600));
    assert!(gif.frames.iter().all(|(delay, _)| *delay == 5), "1/20 s");
    // Bodies, ground and text cover a good part of the image, and C moves between frames.
    let first = &gif.frames[0].1;
    let last = &gif.frames[12].1;
    assert!(inked(first) > 0.10, "inked {}", inked(first));
    let changed = first
        .chunks(4)
        .zip(last.chunks(4))
        .filter(|(a, b)| a != b)
        .count();
    assert!(changed > 1000, "only {changed} pixels changed");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn animate_takes_every_kth_step_fps_size_and_writes_png_frames() {
    let dir = temp_dir("every");
    let o = d5_run(&dir, &["--no-plots"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let frames = dir.join("frames");
    let o = ecp(&[
        "animate",
        &s(&dir),
        "--every",
        "5",
        "--fps",
        "10",
        "--size",
        "320x240",
        "--frames",
        &s(&frames),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let gif = decode(&dir.join("animation.gif"));
    // t = 0, steps 5 and 10, and the last (12).
    assert_eq!(gif.frames.len(), 4);
    assert_eq!((gif.width, gif.height), (320, 240));
    assert!(gif.frames.iter().all(|(delay, _)| *delay == 10), "1/10 s");
    let pngs = std::fs::read_dir(&frames)
        .expect("frames written")
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "png"))
        .count();
    assert_eq!(pngs, 4);
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        stdout.contains("4 frames (every 5 steps) at 10 fps"),
        "{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn animate_bad_input_is_a_clear_error_with_status_2() {
    let dir = temp_dir("bad");
    let expect_2 = |args: &[&str], needle: &str| {
        let o = ecp(args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: `{needle}` not in: {err}");
        assert!(!err.contains("panicked"), "{err}");
    };
    let missing = dir.join("missing");
    expect_2(&["animate", &s(&missing)], "not a directory");
    expect_2(&["animate", &s(&dir)], "no trajectory.csv");

    let run = dir.join("run");
    let o = d5_run(&run, &["--no-plots"]);
    assert!(o.status.success(), "{}", stderr(&o));
    expect_2(&["animate", &s(&run), "--every", "0"], "--every");
    expect_2(&["animate", &s(&run), "--fps", "0"], "--fps");
    expect_2(&["animate", &s(&run), "--size", "10x10"], "--size");
    // A scene that cannot be found, named on the command line or in summary.json.
    expect_2(
        &["animate", &s(&run), "--scene", "scenes/no_such.toml"],
        "no_such.toml",
    );
    // The wrong scene: one body where the run has two.
    expect_2(
        &["animate", &s(&run), "--scene", "scenes/a1_sliding.toml"],
        "more dynamic bodies than the scene",
    );
    let summary = run.join("summary.json");
    let text = std::fs::read_to_string(&summary).expect("summary.json");
    let mut json: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    json["scene_path"] = serde_json::Value::from("/nowhere/d5.toml");
    std::fs::write(&summary, json.to_string()).expect("written");
    expect_2(&["animate", &s(&run)], "--scene PATH");
    // ... which --scene then fixes.
    let o = ecp(&[
        "animate",
        &s(&run),
        "--scene",
        "scenes/d5_collision.toml",
        "--every",
        "6",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(decode(&run.join("animation.gif")).frames.len(), 3);
    let _ = std::fs::remove_dir_all(&dir);
}

fn is_png(path: &Path) -> bool {
    std::fs::read(path).is_ok_and(|b| b.len() > 1000 && b.starts_with(b"\x89PNG"))
}

#[test]
fn a_multibody_run_gets_the_multibody_plots_and_a_one_body_run_does_not() {
    let dir = temp_dir("plots");
    let bodies = dir.join("d5");
    let o = d5_run(&bodies, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    for name in [
        "bodies_footprint.png",
        "pair_impulses.png",
        "footprint.png",
        "velocity.png",
    ] {
        assert!(is_png(&bodies.join("plots").join(name)), "{name}");
    }
    let one = dir.join("a1");
    let o = ecp(&[
        "run",
        "scenes/a1_sliding.toml",
        "--steps",
        "3",
        "--quiet",
        "--out",
        &s(&one),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(is_png(&one.join("plots/footprint.png")));
    assert!(!one.join("plots/bodies_footprint.png").exists());
    assert!(!one.join("plots/pair_impulses.png").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
