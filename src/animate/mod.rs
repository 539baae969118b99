//! `ecp animate`: the motion of a run in 3-D as an animated GIF (`docs/outputs.md#animationgif`).
//!
//! The run directory holds the states (`trajectory.csv`), the contacts (`contacts.csv`) and the
//! scene file's path (`summary.json`); the scene gives the shapes and the poses of fixed and
//! kinematic bodies. [`read_run`] gathers them, `animate/draw.rs` renders a frame.

mod draw;
mod read;

use std::path::{Path, PathBuf};

use crate::error::{InputError, InputErrorKind};
use crate::output::OutputError;
use crate::run::RunError;

pub use draw::ARROW_FRACTION;
pub use read::{Arrow, RunData, read_run};

/// Longest animation the automatic decimation aims for (s of playback).
pub const MAX_SECONDS: f64 = 10.0;
/// Most frames the automatic decimation gives (the frame at t = 0 comes on top).
pub const MAX_FRAMES: usize = 300;

/// Options of [`animate_dir`].
#[derive(Clone, Debug)]
pub struct AnimateOptions {
    /// Frames per second of playback.
    pub fps: u32,
    /// Draw every this many steps; `None`: the smallest that keeps the animation within
    /// [`MAX_SECONDS`] and [`MAX_FRAMES`].
    pub every: Option<usize>,
    /// Image size in pixels.
    pub size: (u32, u32),
    /// The scene file, instead of the one `summary.json` names.
    pub scene: Option<PathBuf>,
    /// Also write each frame as a PNG into this directory.
    pub frames_dir: Option<PathBuf>,
}

impl Default for AnimateOptions {
    fn default() -> Self {
        AnimateOptions {
            fps: 20,
            every: None,
            size: (800, 600),
            scene: None,
            frames_dir: None,
        }
    }
}

/// What [`animate_dir`] wrote.
#[derive(Clone, Debug)]
pub struct Animation {
    /// The GIF.
    pub path: PathBuf,
    /// Frames in it: the state at t = 0, then every `every`-th step end and the last one.
    pub frames: usize,
    /// Steps between frames.
    pub every: usize,
    /// Frames per second of playback.
    pub fps: u32,
    /// Playback speed: simulated seconds per second of animation.
    pub speed: f64,
    /// The largest normal impulse drawn (N s); its arrow is [`ARROW_FRACTION`] of the scene's
    /// size.
    pub max_pn: f64,
}

/// The steps drawn: `every` from `(steps, fps, h)` unless given, and the record indices.
pub fn frame_plan(steps: usize, fps: u32, every: Option<usize>) -> (usize, Vec<usize>) {
    let every = every.unwrap_or_else(|| {
        let cap = ((MAX_SECONDS * f64::from(fps.max(1))) as usize).clamp(1, MAX_FRAMES - 1);
        steps.div_ceil(cap).max(1)
    });
    let mut rows: Vec<usize> = (1..=steps / every).map(|k| k * every - 1).collect();
    if steps > 0 && rows.last() != Some(&(steps - 1)) {
        rows.push(steps - 1);
    }
    (every, rows)
}

fn option_error(option: &str, message: String) -> RunError {
    InputError::option(option, InputErrorKind::InvalidValue, message).into()
}

/// Renders the run in `out_dir` into `out_dir/animation.gif`.
pub fn animate_dir(out_dir: &Path, options: &AnimateOptions) -> Result<Animation, RunError> {
    if !(1..=100).contains(&options.fps) {
        return Err(option_error(
            "--fps",
            format!("give 1 to 100 frames per second, not {}", options.fps),
        ));
    }
    if options.every == Some(0) {
        return Err(option_error(
            "--every",
            "draw every 1 or more steps (--every 1 draws every step)".into(),
        ));
    }
    let (w, h) = options.size;
    if !(64..=4096).contains(&w) || !(64..=4096).contains(&h) {
        return Err(option_error(
            "--size",
            format!("give a width and height of 64 to 4096 pixels, e.g. 800x600, not {w}x{h}"),
        ));
    }
    let data = read_run(out_dir, options.scene.as_deref())?;
    let (every, rows) = frame_plan(data.states.len(), options.fps, options.every);
    let path = out_dir.join("animation.gif");
    crate::plots::register_bundled_font().map_err(|e| draw_error(&path, e.to_string()))?;
    let view = draw::View::new(&data, options.size);
    // GIF delays are in hundredths of a second: 1/fps rounded to them.
    let delay_ms = (1000 / options.fps).max(10);
    let frames: Vec<Option<usize>> = std::iter::once(None)
        .chain(rows.iter().map(|&r| Some(r)))
        .collect();
    {
        use plotters::prelude::*;
        let root = BitMapBackend::gif(&path, options.size, delay_ms)
            .map_err(|e| draw_error(&path, e.to_string()))?
            .into_drawing_area();
        for (k, row) in frames.iter().enumerate() {
            view.frame(&root, &data, *row, (k, frames.len()))
                .map_err(|e| draw_error(&path, e))?;
            root.present()
                .map_err(|e| draw_error(&path, e.to_string()))?;
        }
    }
    if let Some(dir) = &options.frames_dir {
        std::fs::create_dir_all(dir).map_err(|source| OutputError {
            path: dir.clone(),
            source,
        })?;
        for (k, row) in frames.iter().enumerate() {
            use plotters::prelude::*;
            let png = dir.join(format!("frame_{k:04}.png"));
            let root = BitMapBackend::new(&png, options.size).into_drawing_area();
            view.frame(&root, &data, *row, (k, frames.len()))
                .map_err(|e| draw_error(&png, e))?;
            root.present()
                .map_err(|e| draw_error(&png, e.to_string()))?;
        }
    }
    let step_time = data.h * every as f64;
    Ok(Animation {
        path,
        frames: frames.len(),
        every,
        fps: options.fps,
        speed: step_time * f64::from(options.fps),
        max_pn: view.max_pn,
    })
}

fn draw_error(path: &Path, message: String) -> RunError {
    OutputError {
        path: path.to_path_buf(),
        source: std::io::Error::other(message),
    }
    .into()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_plan_takes_every_kth_step_and_the_last() {
        assert_eq!(frame_plan(10, 20, Some(3)), (3, vec![2, 5, 8, 9]));
        assert_eq!(frame_plan(9, 20, Some(3)), (3, vec![2, 5, 8]));
        assert_eq!(frame_plan(0, 20, None), (1, vec![]));
        // 20 fps for at most 10 s: 200 frames; 1000 steps -> every 5th.
        let (every, rows) = frame_plan(1000, 20, None);
        assert_eq!((every, rows.len()), (5, 200));
        // 100 fps would be 1000 frames: capped at 299 (+ t = 0).
        let (every, rows) = frame_plan(1000, 100, None);
        assert_eq!((every, rows.len()), (4, 250));
    }
}
