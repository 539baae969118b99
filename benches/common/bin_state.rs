//! The bin states the bodies benchmarks start from: `benches/bin50_states.csv`, two states of
//! `scenes/bin50.toml`'s parts written by `scripts/bin_state.py` (its docstring has the commands):
//! `falling`, the run's state at the end of step 11, and `settled`, the parts at rest in a flat
//! stack. Reaching a settled bin by simulating costs many minutes (the landing steps:
//! `docs/latency.md#bins`), so the benchmarks start from the file; `tests/user_scenes.rs`
//! (`bin50_states_fit_the_scene`) checks it against the scene.
//!
//! Shared by `benches/bodies.rs` and `tests/user_scenes.rs` (`#[path]` includes).

use std::path::{Path, PathBuf};

use ecp::formulations::{BodyState, Scene};
use ecp::scene::load_scene;
use nalgebra::{Vector3, Vector4};

/// The state `bin_step` starts from: every part at rest on the floor or on another.
pub const SETTLED: &str = "settled";

/// The state `bin_step_falling` starts from: the end of step 11 of the run, the lowest layer
/// landed, the five above it falling.
pub const FALLING: &str = "falling";

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The path of the state file.
pub fn states_path() -> PathBuf {
    root().join("benches/bin50_states.csv")
}

/// `scenes/bin50.toml` (ground, four walls and its 50 parts).
pub fn bin50() -> Scene {
    let path = root().join("scenes/bin50.toml");
    match load_scene(&path) {
        Ok(file) => file.scene,
        Err(e) => panic!("{}: {e}", path.display()),
    }
}

/// The parts' states labelled `label` in the state file, in file order, by name.
pub fn states_at(label: &str) -> Result<Vec<(String, BodyState)>, String> {
    let path = states_path();
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.starts_with('#') && !l.trim().is_empty());
    let header = lines.next().map(|(_, l)| l).unwrap_or("");
    if header != "state,body,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz" {
        return Err(format!("{}: unexpected header {header:?}", path.display()));
    }
    let mut out = Vec::new();
    for (i, line) in lines {
        let cols: Vec<&str> = line.split(',').collect();
        let bad = |what: &str| format!("{}:{}: {what}", path.display(), i + 1);
        if cols.len() != 15 {
            return Err(bad("expected 15 fields"));
        }
        if cols[0] != label {
            continue;
        }
        let v: Vec<f64> = cols[2..]
            .iter()
            .map(|s| s.parse::<f64>().map_err(|e| bad(&format!("{s:?}: {e}"))))
            .collect::<Result<_, _>>()?;
        let state = BodyState {
            x: Vector3::new(v[0], v[1], v[2]),
            q: Vector4::new(v[3], v[4], v[5], v[6]),
            v: Vector3::new(v[7], v[8], v[9]),
            w: Vector3::new(v[10], v[11], v[12]),
        };
        out.push((cols[1].to_string(), state));
    }
    if out.is_empty() {
        return Err(format!("{}: no state {label:?}", path.display()));
    }
    Ok(out)
}

/// The first `n` parts of `scenes/bin50.toml` (the lowest layers first; walls and ground kept)
/// starting from their states labelled `label`, named `bin<n>`.
pub fn bin_from(n: usize, label: &str) -> Result<Scene, String> {
    let mut scene = bin50();
    let states = states_at(label)?;
    if states.len() != scene.bodies.len() {
        return Err(format!(
            "{label}: {} states for {} parts",
            states.len(),
            scene.bodies.len()
        ));
    }
    for (body, (name, state)) in scene.bodies.iter_mut().zip(states) {
        if body.name != name {
            return Err(format!(
                "{label}: state of {name} where the scene has {}",
                body.name
            ));
        }
        body.initial = state;
    }
    scene.bodies.truncate(n);
    scene.name = format!("bin{n}");
    Ok(scene)
}
