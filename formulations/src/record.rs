//! What a simulation reports for every step (`docs/outputs.md`): the body states, one
//! [`ContactRecord`] per contact, the solver's summary and how the step was solved
//! ([`StepMethod`]); the columns of `trajectory.csv`, the energy and the contact mode.

use nalgebra::Vector3;

use ecp_model::Summary;

use crate::geometry::{
    ContactMode, HalfSpace, MassProperties, Shape, contact_mode, min_gap, world_vertices,
};
use crate::rotation::rotation_matrix;
use crate::scene::{BodyState, Scene};

/// Tolerance on a vertex's distance to the plane for the contact mode (`docs/model.md#scenarios`).
pub const MODE_TOLERANCE: f64 = 1e-7;

/// Per-contact values at the end of a step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactRecord {
    /// ECP on Conv(F) (`a1`).
    pub a1: Vector3<f64>,
    /// ECP on G (`a2`).
    pub a2: Vector3<f64>,
    /// Gap multiplier `l_g` (the distance while separated).
    pub lg: f64,
    /// Normal impulse.
    pub pn: f64,
    /// Friction impulse along t.
    pub pt: f64,
    /// Friction impulse along o.
    pub po: f64,
    /// Torsional friction impulse.
    pub pr: f64,
    /// Slip magnitude.
    pub sigma: f64,
    /// Minimum gap over the vertices of the real body.
    pub min_gap: f64,
    /// Contact mode from the state (`docs/model.md#scenarios`).
    pub mode: ContactMode,
}

/// One active contact between a dynamic body and another body or a half-space at the end of
/// a step (a row of `contacts.csv`, `docs/outputs.md#contactscsv`): the names the scene gives
/// the two, the ECPs, the normal and the impulses.
#[derive(Clone, Debug, PartialEq)]
pub struct PairRecord {
    /// The dynamic body of the pair (F).
    pub body_a: String,
    /// The other body (dynamic, fixed or kinematic) or half-space (G).
    pub body_b: String,
    /// ECP on Conv(F).
    pub a1: Vector3<f64>,
    /// ECP on Conv(G).
    pub a2: Vector3<f64>,
    /// Unit contact normal, from G into F.
    pub normal: Vector3<f64>,
    /// Normal impulse.
    pub pn: f64,
    /// Friction impulse along t.
    pub pt: f64,
    /// Friction impulse along o.
    pub po: f64,
    /// Torsional friction impulse.
    pub pr: f64,
    /// Slip rate σ.
    pub sigma: f64,
    /// Distance between the two hulls (`d |ν_G|`; 0 when they touch).
    pub gap: f64,
    /// Contact mode of the pair (the fewer touching features of the two sides).
    pub mode: ContactMode,
}

/// How a step was solved.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum StepMethod {
    /// By the primary backend, in one piece (the normal case).
    #[default]
    Direct,
    /// By the named fallback backend, in one piece.
    Backend(String),
    /// In `pieces` substeps, the shortest `h / finest`.
    Substeps {
        /// Number of substeps that together cover the step.
        pieces: usize,
        /// Denominator of the shortest substep (2, 4, 8, …).
        finest: usize,
    },
    /// Not solved: the bodies keep the state at the start of the step.
    Failed,
    /// Taken from the backend's point without the natural-residual test, on request
    /// ([`crate::step::Simulation::step_unchecked`], for studying relaxed models such as
    /// Anitescu's); never used by the run driver.
    Unchecked,
}

impl StepMethod {
    /// The kind, as counted in `summary.json`: `direct`, `backend`, `substeps` or `failed`.
    pub fn kind(&self) -> &'static str {
        match self {
            StepMethod::Direct => "direct",
            StepMethod::Backend(_) => "backend",
            StepMethod::Substeps { .. } => "substeps",
            StepMethod::Failed => "failed",
            StepMethod::Unchecked => "unchecked",
        }
    }

    /// The `fallback` column of `trajectory.csv`: empty for a direct solve, else
    /// `backend:NAME`, `substeps:PIECES:h/FINEST` or `failed`.
    pub fn column(&self) -> String {
        match self {
            StepMethod::Direct => String::new(),
            StepMethod::Backend(name) => format!("backend:{name}"),
            StepMethod::Substeps { pieces, finest } => format!("substeps:{pieces}:h/{finest}"),
            StepMethod::Failed => "failed".to_string(),
            StepMethod::Unchecked => "unchecked".to_string(),
        }
    }

    /// True when the step passed the natural-residual test (every method but
    /// [`StepMethod::Failed`] and [`StepMethod::Unchecked`]).
    pub fn solved(&self) -> bool {
        !matches!(self, StepMethod::Failed | StepMethod::Unchecked)
    }
}

/// Everything recorded for one step (the rows of `trajectory.csv`, `docs/outputs.md`). The
/// default is empty storage for [`crate::step::Simulation::step_into`] to fill.
#[derive(Clone, Debug, Default)]
pub struct StepRecord {
    /// Step index, from 1.
    pub step: usize,
    /// Time at the end of the step.
    pub t: f64,
    /// Body states at the end of the step.
    pub bodies: Vec<BodyState>,
    /// Contacts (body-major, then plane).
    pub contacts: Vec<ContactRecord>,
    /// The active contacts between bodies (and, for the multi-body formulation, between each
    /// dynamic body and each half-space), by name; empty for the single-body formulations.
    pub pairs: Vec<PairRecord>,
    /// Kinetic plus potential energy of all bodies.
    pub energy: f64,
    /// Solver summary (of the best iterate when the step did not converge).
    pub summary: Summary,
    /// Whether the step was solved (by its backend or a fallback). A step that was not keeps
    /// the bodies' state at its start (`docs/fallbacks.md`).
    pub converged: bool,
    /// Wall time of the step in microseconds: from the formulation's `begin_step` through the
    /// checkpoint, the span's data and warm start, every solve attempt (retry starts, fallback
    /// backends, substeps), the read-out of the states and the driver's bookkeeping for the
    /// next step (the last step kept, the warm start's history); not this record itself (the
    /// contact records, the energy) nor what the caller does with it (`docs/outputs.md`).
    pub solve_us: f64,
    /// How the step was solved: directly, by a fallback backend, in substeps, or not at all.
    pub method: StepMethod,
}

/// The `trajectory.csv` columns of one body and one contact (`docs/outputs.md`).
pub const TRAJECTORY_COLUMNS: [&str; 28] = [
    "t",
    "x",
    "y",
    "z",
    "qw",
    "qx",
    "qy",
    "qz",
    "vx",
    "vy",
    "vz",
    "wx",
    "wy",
    "wz",
    "ecp_x",
    "ecp_y",
    "ecp_z",
    "pn",
    "pt",
    "po",
    "pr",
    "sigma",
    "min_gap",
    "mode",
    "iterations",
    "residual",
    "solve_us",
    "fallback",
];

impl StepRecord {
    /// The header row of `trajectory.csv` for `bodies` bodies with `contacts_per_body` contacts
    /// each (`docs/outputs.md`): one body and one contact use the plain names; more append columns
    /// suffixed `_b<i>` (body fields) and `_b<i>_c<j>` (contact fields).
    pub fn csv_header(bodies: usize, contacts_per_body: usize) -> Vec<String> {
        let single = bodies == 1 && contacts_per_body == 1;
        let mut cols = vec!["t".to_string()];
        for b in 0..bodies {
            let sb = if single {
                String::new()
            } else {
                format!("_b{b}")
            };
            for c in &TRAJECTORY_COLUMNS[1..14] {
                cols.push(format!("{c}{sb}"));
            }
            for j in 0..contacts_per_body {
                let sc = if single {
                    String::new()
                } else {
                    format!("{sb}_c{j}")
                };
                for c in &TRAJECTORY_COLUMNS[14..24] {
                    cols.push(format!("{c}{sc}"));
                }
            }
        }
        for c in &TRAJECTORY_COLUMNS[24..] {
            cols.push((*c).to_string());
        }
        cols
    }

    /// This record as the fields of a `trajectory.csv` row, in [`StepRecord::csv_header`] order.
    pub fn csv_fields(&self) -> Vec<String> {
        let mut f = vec![format!("{}", self.t)];
        let per_body = if self.bodies.is_empty() {
            0
        } else {
            self.contacts.len() / self.bodies.len()
        };
        for (b, s) in self.bodies.iter().enumerate() {
            for v in [
                s.x.x, s.x.y, s.x.z, s.q[0], s.q[1], s.q[2], s.q[3], s.v.x, s.v.y, s.v.z, s.w.x,
                s.w.y, s.w.z,
            ] {
                f.push(format!("{v:e}"));
            }
            for c in &self.contacts[b * per_body..(b + 1) * per_body] {
                for v in [
                    c.a1.x, c.a1.y, c.a1.z, c.pn, c.pt, c.po, c.pr, c.sigma, c.min_gap,
                ] {
                    f.push(format!("{v:e}"));
                }
                f.push(c.mode.as_str().to_string());
            }
        }
        f.push(self.summary.iterations.to_string());
        f.push(format!("{:e}", self.summary.residual));
        f.push(format!("{:.3}", self.solve_us));
        f.push(self.method.column());
        f
    }
}

/// Kinetic plus gravitational potential energy of one body in `state` (`docs/model.md#invariants`).
pub fn body_energy(mass: &MassProperties, state: &BodyState, gravity: &Vector3<f64>) -> f64 {
    let r = rotation_matrix(&state.q);
    let iw = r * mass.inertia * r.transpose();
    0.5 * mass.mass * state.v.norm_squared() + 0.5 * state.w.dot(&(iw * state.w))
        - mass.mass * gravity.dot(&state.x)
}

/// Minimum gap and contact mode of every body (at `states`) against every plane, indexed
/// `[body][plane]`: computed once per step and shared by all the contacts of a (body, plane)
/// pair (one per piece in the union formulation, one per point in the point formulation).
pub fn gaps_and_modes(
    bodies: &[(&Shape, BodyState)],
    planes: &[HalfSpace],
) -> Vec<Vec<(f64, ContactMode)>> {
    bodies
        .iter()
        .map(|(shape, s)| {
            let r = rotation_matrix(&s.q);
            let verts = world_vertices(shape.vertices(), &s.x, &r);
            planes
                .iter()
                .map(|plane| {
                    (
                        min_gap(shape.vertices(), &s.x, &r, plane),
                        contact_mode(&verts, plane, MODE_TOLERANCE),
                    )
                })
                .collect()
        })
        .collect()
}

/// [`gaps_and_modes`] of the bodies of `scene` at `states`.
pub fn scene_gaps_and_modes(scene: &Scene, states: &[BodyState]) -> Vec<Vec<(f64, ContactMode)>> {
    let shapes: Vec<_> = scene
        .bodies
        .iter()
        .zip(states)
        .map(|(b, s)| (&b.shape, *s))
        .collect();
    gaps_and_modes(&shapes, &scene.planes)
}

/// Penetration at the end of a step: `max(0, −min_gap)` over the records' contacts, i.e. over
/// every vertex of the real bodies against every half-space. The same measure for every
/// formulation, so they are compared on equal terms.
pub fn penetration(record: &StepRecord) -> f64 {
    record
        .contacts
        .iter()
        .map(|c| (-c.min_gap).max(0.0))
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_and_kinds() {
        assert_eq!(StepMethod::Direct.column(), "");
        assert_eq!(StepMethod::Backend("path".into()).column(), "backend:path");
        let s = StepMethod::Substeps {
            pieces: 3,
            finest: 4,
        };
        assert_eq!(s.column(), "substeps:3:h/4");
        assert_eq!(s.kind(), "substeps");
        assert!(!StepMethod::Failed.solved());
        assert!(!StepMethod::Unchecked.solved());
    }

    #[test]
    fn csv_header_names_bodies_and_contacts() {
        let one = StepRecord::csv_header(1, 1);
        assert_eq!(one.len(), TRAJECTORY_COLUMNS.len());
        assert_eq!(one[14], "ecp_x");
        let two = StepRecord::csv_header(2, 2);
        assert_eq!(two.len(), 1 + 2 * (13 + 2 * 10) + 4);
        assert_eq!(two[1], "x_b0");
        assert_eq!(two[14], "ecp_x_b0_c0");
        assert!(two.contains(&"mode_b1_c1".to_string()));
    }

    #[test]
    fn energy_of_a_body_at_rest_is_its_potential() {
        let mass =
            MassProperties::solid_cuboid(2.0, 0.1, 0.2, 0.3).unwrap_or_else(|e| panic!("{e}"));
        let s = BodyState::at_rest(Vector3::new(0.0, 0.0, 1.5));
        let g = Vector3::new(0.0, 0.0, -9.8);
        assert!((body_energy(&mass, &s, &g) - 2.0 * 9.8 * 1.5).abs() < 1e-12);
        let spinning = BodyState {
            w: Vector3::new(0.0, 0.0, 2.0),
            ..s
        };
        // ½ I_zz ω², I_zz = m (0.1² + 0.2²)/12.
        let izz = 2.0 * (0.01 + 0.04) / 12.0;
        assert!(
            (body_energy(&mass, &spinning, &g) - body_energy(&mass, &s, &g) - 0.5 * izz * 4.0)
                .abs()
                < 1e-12
        );
    }
}
