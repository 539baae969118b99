//! Reading a run directory for [`super::animate_dir`]: the scene named in `summary.json`, the
//! body poses of `trajectory.csv` and the contacts of `contacts.csv` (`docs/outputs.md`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::{Vector3, Vector4};

use ecp_formulations::Scene;

use crate::error::{InputError, InputErrorKind};
use crate::run::RunError;

/// An active contact at a step end: the ECP and the normal impulse on `body_a`.
#[derive(Clone, Debug, PartialEq)]
pub struct Arrow {
    /// The ECP a1 (world frame).
    pub at: Vector3<f64>,
    /// Unit normal from `body_b` into `body_a`.
    pub normal: Vector3<f64>,
    /// Normal impulse (N s).
    pub pn: f64,
    /// Whether `body_b` is a half-space.
    pub half_space: bool,
}

/// A run as the animation needs it.
#[derive(Clone, Debug)]
pub struct RunData {
    /// The scene (shapes, obstacles, half-spaces).
    pub scene: Scene,
    /// Step length (s).
    pub h: f64,
    /// Time of each step end (s), one per `trajectory.csv` row.
    pub times: Vec<f64>,
    /// Pose `(x, Q)` of each dynamic body at each step end.
    pub states: Poses,
    /// The active contacts at each step end.
    pub contacts: Contacts,
}

impl RunData {
    /// The poses at t = 0 (from the scene).
    pub fn initial(&self) -> Vec<(Vector3<f64>, Vector4<f64>)> {
        self.scene
            .bodies
            .iter()
            .map(|b| (b.initial.x, b.initial.q))
            .collect()
    }
}

fn input(file: &Path, kind: InputErrorKind, message: String) -> RunError {
    InputError {
        file: Some(file.to_path_buf()),
        key: None,
        line: None,
        kind,
        message,
    }
    .into()
}

/// Reads the run in `dir`; `scene` replaces the scene file named in `summary.json`.
pub fn read_run(dir: &Path, scene: Option<&Path>) -> Result<RunData, RunError> {
    if !dir.is_dir() {
        return Err(input(
            dir,
            InputErrorKind::FileMissing,
            "not a directory; give the output directory of a run (`ecp run SCENE` writes \
             out/<scene name>, or the directory given with --out)"
                .into(),
        ));
    }
    let trajectory = dir.join("trajectory.csv");
    if !trajectory.is_file() {
        return Err(input(
            &trajectory,
            InputErrorKind::FileMissing,
            "no trajectory.csv: this directory holds no run; run `ecp run SCENE --out DIR` \
             first and animate DIR"
                .into(),
        ));
    }
    let scene_path = match scene {
        Some(p) => p.to_path_buf(),
        None => scene_from_summary(&dir.join("summary.json"))?,
    };
    let file = crate::scene::load_scene(&scene_path).map_err(|mut e| {
        if scene.is_none() && e.kind == InputErrorKind::FileMissing {
            e.message = format!(
                "{} (the scene file named by {}; give it with --scene PATH if it moved)",
                e.message,
                dir.join("summary.json").display()
            );
        }
        RunError::from(e)
    })?;
    let scene = file.scene;
    let (times, states, fallback) = read_trajectory(&trajectory, &scene)?;
    let contacts_path = dir.join("contacts.csv");
    let mut contacts = if contacts_path.is_file() {
        read_contacts(&contacts_path, &scene, times.len())?
    } else {
        vec![Vec::new(); times.len()]
    };
    if contacts.iter().all(Vec::is_empty) {
        // One-body formulations: the contacts are the half-space columns of trajectory.csv.
        contacts = fallback;
    }
    Ok(RunData {
        h: scene.h,
        scene,
        times,
        states,
        contacts,
    })
}

fn scene_from_summary(summary: &Path) -> Result<PathBuf, RunError> {
    let text = std::fs::read_to_string(summary).map_err(|e| {
        input(
            summary,
            InputErrorKind::FileMissing,
            format!(
                "cannot read it ({e}), so the scene is unknown; give the scene file with --scene \
                 PATH"
            ),
        )
    })?;
    let json: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
        input(
            summary,
            InputErrorKind::Syntax,
            format!("not JSON ({e}); give the scene file with --scene PATH"),
        )
    })?;
    match json.get("scene_path").and_then(|v| v.as_str()) {
        Some(p) if !p.is_empty() => Ok(PathBuf::from(p)),
        _ => Err(input(
            summary,
            InputErrorKind::MissingKey,
            "it does not name the scene file (`scene_path`, written by runs since the \
             animation came); give the scene file with --scene PATH"
                .into(),
        )),
    }
}

type Columns = HashMap<String, usize>;

fn column(cols: &Columns, file: &Path, name: &str) -> Result<usize, RunError> {
    cols.get(name).copied().ok_or_else(|| {
        input(
            file,
            InputErrorKind::MissingKey,
            format!(
                "no column `{name}`: the file does not match the scene (wrong --scene, or not \
                 written by `ecp run`)"
            ),
        )
    })
}

fn number(
    record: &csv::StringRecord,
    col: usize,
    file: &Path,
    line: usize,
) -> Result<f64, RunError> {
    let text = record.get(col).unwrap_or("");
    text.trim().parse::<f64>().map_err(|_| {
        RunError::from(InputError {
            file: Some(file.to_path_buf()),
            key: None,
            line: Some(line),
            kind: InputErrorKind::WrongType,
            message: format!("`{text}` in column {} is not a number", col + 1),
        })
    })
}

fn open(path: &Path) -> Result<(csv::Reader<std::fs::File>, Columns), RunError> {
    let mut reader = csv::Reader::from_path(path)
        .map_err(|e| input(path, InputErrorKind::FileMissing, e.to_string()))?;
    let cols = reader
        .headers()
        .map_err(|e| input(path, InputErrorKind::Syntax, e.to_string()))?
        .iter()
        .enumerate()
        .map(|(i, h)| (h.trim().to_string(), i))
        .collect();
    Ok((reader, cols))
}

type Poses = Vec<Vec<(Vector3<f64>, Vector4<f64>)>>;

/// The contacts of each step end.
type Contacts = Vec<Vec<Arrow>>;

/// Times and poses, and the half-space contacts of the `ecp_*`/`pn` columns.
fn read_trajectory(path: &Path, scene: &Scene) -> Result<(Vec<f64>, Poses, Contacts), RunError> {
    let (mut reader, cols) = open(path)?;
    let n = scene.bodies.len();
    let suffix = |b: usize| {
        if cols.contains_key("x") && n == 1 {
            String::new()
        } else {
            format!("_b{b}")
        }
    };
    let t_col = column(&cols, path, "t")?;
    let mut body_cols = Vec::with_capacity(n);
    for b in 0..n {
        let s = suffix(b);
        let mut c = [0; 7];
        for (k, name) in ["x", "y", "z", "qw", "qx", "qy", "qz"].iter().enumerate() {
            c[k] = column(&cols, path, &format!("{name}{s}"))?;
        }
        body_cols.push(c);
    }
    if cols.contains_key(&format!("x_b{n}")) {
        return Err(input(
            path,
            InputErrorKind::InvalidValue,
            format!(
                "it has more dynamic bodies than the scene ({n}); give the scene of this run \
                 with --scene PATH"
            ),
        ));
    }
    // Half-space contacts: `ecp_x<suffix>` with `pn<suffix>`.
    let mut contact_cols = Vec::new();
    for (name, &i) in &cols {
        if let Some(s) = name.strip_prefix("ecp_x")
            && let (Some(&y), Some(&z), Some(&pn)) = (
                cols.get(&format!("ecp_y{s}")),
                cols.get(&format!("ecp_z{s}")),
                cols.get(&format!("pn{s}")),
            )
        {
            contact_cols.push([i, y, z, pn]);
        }
    }
    contact_cols.sort_unstable();
    let (mut times, mut states, mut contacts) = (Vec::new(), Vec::new(), Vec::new());
    for (row, record) in reader.records().enumerate() {
        let line = row + 2;
        let record = record.map_err(|e| input(path, InputErrorKind::Syntax, e.to_string()))?;
        times.push(number(&record, t_col, path, line)?);
        let mut poses = Vec::with_capacity(n);
        for c in &body_cols {
            let v: Vec<f64> = c
                .iter()
                .map(|&i| number(&record, i, path, line))
                .collect::<Result<_, _>>()?;
            poses.push((
                Vector3::new(v[0], v[1], v[2]),
                Vector4::new(v[3], v[4], v[5], v[6]),
            ));
        }
        states.push(poses);
        let mut arrows = Vec::new();
        for c in &contact_cols {
            let at = Vector3::new(
                number(&record, c[0], path, line)?,
                number(&record, c[1], path, line)?,
                number(&record, c[2], path, line)?,
            );
            let pn = number(&record, c[3], path, line)?;
            // The half-space the ECP lies on (it is on the plane when the contact is loaded).
            let plane = scene
                .planes
                .iter()
                .min_by(|p, q| p.value(&at).abs().total_cmp(&q.value(&at).abs()));
            if let Some(plane) = plane
                && at.iter().all(|v| v.is_finite())
                && pn > 0.0
            {
                arrows.push(Arrow {
                    at,
                    normal: plane.normal(),
                    pn,
                    half_space: true,
                });
            }
        }
        contacts.push(arrows);
    }
    Ok((times, states, contacts))
}

/// The rows of `contacts.csv`, by step (from 1) into `steps` lists.
fn read_contacts(path: &Path, scene: &Scene, steps: usize) -> Result<Vec<Vec<Arrow>>, RunError> {
    let (mut reader, cols) = open(path)?;
    let names = [
        "step", "a1_x", "a1_y", "a1_z", "n_x", "n_y", "n_z", "pn", "body_b",
    ];
    let mut c = [0; 9];
    for (k, name) in names.iter().enumerate() {
        c[k] = column(&cols, path, name)?;
    }
    let planes: Vec<String> = (0..scene.planes.len())
        .map(|p| scene.world.plane_name(p))
        .collect();
    let mut out = vec![Vec::new(); steps];
    for (row, record) in reader.records().enumerate() {
        let line = row + 2;
        let record = record.map_err(|e| input(path, InputErrorKind::Syntax, e.to_string()))?;
        let step = number(&record, c[0], path, line)?;
        let v: Vec<f64> = c[1..8]
            .iter()
            .map(|&i| number(&record, i, path, line))
            .collect::<Result<_, _>>()?;
        let body_b = record.get(c[8]).unwrap_or("");
        let slot = (step as usize).checked_sub(1).and_then(|s| out.get_mut(s));
        if let Some(slot) = slot {
            slot.push(Arrow {
                at: Vector3::new(v[0], v[1], v[2]),
                normal: Vector3::new(v[3], v[4], v[5]),
                pn: v[6],
                half_space: planes.iter().any(|p| p == body_b),
            });
        }
    }
    Ok(out)
}
