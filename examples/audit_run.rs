//! The checks of `tests/user_scenes.rs` on a run already made, from its output files, for runs
//! too long to repeat in a test (bin50: `docs/bodies.md#bins`):
//!
//! ```text
//! cargo run --release -- run scenes/bin50.toml --no-plots --out out/bin50
//! cargo run --release --example audit_run -- out/bin50 scenes/bin50.toml
//! ```
//!
//! Reads `trajectory.csv` (the poses, each body's half-space contacts, the fallback column) and
//! `contacts.csv` (the contact pairs) back into step records and prints: the steps converged and
//! solved by a fallback; the deepest overlap between two real bodies, piece by piece, at any step
//! end, and the deepest dip into a half-space; and for an unforced scene (no load, no kinematic
//! body) the energy audit of
//! `stress::measure_records` (opening steps, the energy they changed, the gains outside them).
//! The recorded values are Rust's shortest round-trip decimals, so the records are the run's.
//! Exit status 1 when a check fails (a failed step, an overlap or dip above 1e-8 m, a gain
//! outside the openings above 1e-9 of the energy scale).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use ecp::formulations::bodies::overlap::RealPieces;
use ecp::formulations::geometry::ContactMode;
use ecp::formulations::{BodyState, ContactRecord, PairRecord, Scene, StepMethod, StepRecord};
use ecp::model::{Counters, Summary, Termination};
use ecp::scene::load_scene;
use ecp::stress::measure_records;
use ecp::stress::runner::penetration;
use nalgebra::{Vector3, Vector4};

/// Overlap or dip allowed (m), as `tests/user_scenes.rs`.
const PENETRATION: f64 = 1e-8;
/// Gains outside the openings allowed (of the energy scale), as `tests/user_scenes.rs`.
const ENERGY_GAIN: f64 = 1e-9;

/// The column indices of a CSV file by name.
type Columns = HashMap<String, usize>;

/// A CSV file as its header and rows (no quoting: the run's files have none).
fn read_csv(path: &Path) -> Result<(Columns, Vec<Vec<String>>), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text.lines();
    let header = lines
        .next()
        .ok_or_else(|| format!("{}: empty", path.display()))?;
    let cols = header
        .split(',')
        .enumerate()
        .map(|(i, c)| (c.to_string(), i))
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    Ok((cols, rows))
}

fn field<'a>(cols: &Columns, row: &'a [String], name: &str) -> Result<&'a str, String> {
    cols.get(name)
        .and_then(|&i| row.get(i))
        .map(String::as_str)
        .ok_or_else(|| format!("no column {name}"))
}

fn num(cols: &Columns, row: &[String], name: &str) -> Result<f64, String> {
    let s = field(cols, row, name)?;
    s.parse().map_err(|e| format!("{name} = {s:?}: {e}"))
}

fn vec3(cols: &Columns, row: &[String], names: [&str; 3]) -> Result<Vector3<f64>, String> {
    Ok(Vector3::new(
        num(cols, row, names[0])?,
        num(cols, row, names[1])?,
        num(cols, row, names[2])?,
    ))
}

fn mode(s: &str) -> ContactMode {
    match s {
        "patch" => ContactMode::Patch,
        "line" => ContactMode::Line,
        "point" => ContactMode::Point,
        _ => ContactMode::None,
    }
}

/// The step records of the run in `dir` of `scene`.
fn records(dir: &Path, scene: &Scene) -> Result<Vec<StepRecord>, String> {
    let (tc, trows) = read_csv(&dir.join("trajectory.csv"))?;
    let (cc, crows) = read_csv(&dir.join("contacts.csv"))?;
    let mut pairs: HashMap<usize, Vec<PairRecord>> = HashMap::new();
    for row in &crows {
        let step: usize = field(&cc, row, "step")?
            .parse()
            .map_err(|e| format!("contacts.csv step: {e}"))?;
        pairs.entry(step).or_default().push(PairRecord {
            body_a: field(&cc, row, "body_a")?.to_string(),
            body_b: field(&cc, row, "body_b")?.to_string(),
            a1: vec3(&cc, row, ["a1_x", "a1_y", "a1_z"])?,
            a2: vec3(&cc, row, ["a2_x", "a2_y", "a2_z"])?,
            normal: vec3(&cc, row, ["n_x", "n_y", "n_z"])?,
            pn: num(&cc, row, "pn")?,
            pt: num(&cc, row, "pt")?,
            po: num(&cc, row, "po")?,
            pr: num(&cc, row, "pr")?,
            sigma: num(&cc, row, "sigma")?,
            gap: num(&cc, row, "gap")?,
            mode: mode(field(&cc, row, "mode")?),
        });
    }
    let single = scene.bodies.len() == 1 && scene.planes.len() == 1;
    let mut out = Vec::with_capacity(trows.len());
    for (k, row) in trows.iter().enumerate() {
        let mut bodies = Vec::new();
        let mut contacts = Vec::new();
        for b in 0..scene.bodies.len() {
            let sb = if single {
                String::new()
            } else {
                format!("_b{b}")
            };
            let c = |n: &str| format!("{n}{sb}");
            bodies.push(BodyState {
                x: vec3(&tc, row, [&c("x"), &c("y"), &c("z")])?,
                q: Vector4::new(
                    num(&tc, row, &c("qw"))?,
                    num(&tc, row, &c("qx"))?,
                    num(&tc, row, &c("qy"))?,
                    num(&tc, row, &c("qz"))?,
                ),
                v: vec3(&tc, row, [&c("vx"), &c("vy"), &c("vz")])?,
                w: vec3(&tc, row, [&c("wx"), &c("wy"), &c("wz")])?,
            });
            for j in 0..scene.planes.len() {
                let sc = if single {
                    String::new()
                } else {
                    format!("{sb}_c{j}")
                };
                let c = |n: &str| format!("{n}{sc}");
                let a1 = vec3(&tc, row, [&c("ecp_x"), &c("ecp_y"), &c("ecp_z")])?;
                contacts.push(ContactRecord {
                    a1,
                    a2: a1,
                    lg: f64::NAN,
                    pn: num(&tc, row, &c("pn"))?,
                    pt: num(&tc, row, &c("pt"))?,
                    po: num(&tc, row, &c("po"))?,
                    pr: num(&tc, row, &c("pr"))?,
                    sigma: num(&tc, row, &c("sigma"))?,
                    min_gap: num(&tc, row, &c("min_gap"))?,
                    mode: mode(field(&tc, row, &c("mode"))?),
                });
            }
        }
        let fallback = field(&tc, row, "fallback")?;
        let method = match fallback {
            "" => StepMethod::Direct,
            "failed" => StepMethod::Failed,
            "unchecked" => StepMethod::Unchecked,
            other => StepMethod::Backend(other.to_string()),
        };
        let converged = method.solved();
        out.push(StepRecord {
            step: k + 1,
            t: num(&tc, row, "t")?,
            bodies,
            contacts,
            pairs: pairs.remove(&(k + 1)).unwrap_or_default(),
            energy: f64::NAN,
            summary: Summary {
                solver: String::new(),
                termination: if converged {
                    Termination::Converged
                } else {
                    Termination::MaxIterations
                },
                iterations: field(&tc, row, "iterations")?.parse().unwrap_or(0),
                f_evals: 0,
                jac_evals: 0,
                residual: num(&tc, row, "residual")?,
                fb_residual: f64::NAN,
                worst: None,
                time: Duration::ZERO,
                trace: Vec::new(),
                counters: Counters::default(),
            },
            converged,
            solve_us: num(&tc, row, "solve_us")?,
            method,
        });
    }
    Ok(out)
}

fn audit(dir: &Path, scene_path: &Path) -> Result<bool, String> {
    let scene = load_scene(scene_path).map_err(|e| e.to_string())?.scene;
    let records = records(dir, &scene)?;
    let planned = (scene.duration / scene.h - 1e-9).ceil() as usize;
    let converged = records.iter().filter(|r| r.converged).count();
    let fallback = records
        .iter()
        .filter(|r| r.method != StepMethod::Direct)
        .count();
    let pieces = RealPieces::of(&scene);
    let (mut overlap, mut overlap_at) = (0.0_f64, String::from("none"));
    let (mut dip, mut dip_step) = (0.0_f64, 0);
    for r in &records {
        if let Some(o) = pieces.deepest_overlap(&scene, &r.bodies, r.t, 0.0)
            && o.depth > overlap
        {
            overlap = o.depth;
            overlap_at = format!("step {}: {} and {}", r.step, o.a, o.b);
        }
        let d = penetration(&scene, &r.bodies);
        if d > dip {
            (dip, dip_step) = (d, r.step);
        }
    }
    let mut ok = converged == planned && records.len() == planned;
    ok &= overlap <= PENETRATION && dip <= PENETRATION;
    println!(
        "{}: {converged} of {planned} planned steps converged ({} recorded), {fallback} by a fallback",
        scene.name,
        records.len()
    );
    println!(
        "deepest overlap between real bodies (and half-spaces): {overlap:.2e} m ({overlap_at})"
    );
    println!("deepest dip into a half-space: {dip:.2e} m (step {dip_step})");
    let m = measure_records(&scene, &records);
    // Kinematic bodies do work on the others: only a scene without them and without loads is
    // audited.
    let kinematic = scene.world.obstacles.iter().any(|o| !o.is_fixed());
    if m.unforced && !kinematic {
        ok &= m.energy_step_gains <= ENERGY_GAIN;
        println!(
            "energy (of the scale {:.3} J): {} opening steps, Σ ΔE over them {:.2e}, largest gain \
             at one {:.2e}; gains outside them {:.2e}; largest rise above E_0 {:.2e}, outside \
             the openings {:.2e}",
            m.energy_scale,
            m.opening_steps,
            m.opening_energy,
            m.opening_max_gain,
            m.energy_step_gains,
            m.energy_rise,
            m.energy_rise_outside_openings
        );
    }
    Ok(ok)
}

fn main() -> ExitCode {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [dir, scene] = args.as_slice() else {
        eprintln!("usage: audit_run OUT_DIR SCENE.toml");
        return ExitCode::from(2);
    };
    match audit(dir, scene) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => {
            println!("a check failed");
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("{e}");
            ExitCode::from(2)
        }
    }
}
