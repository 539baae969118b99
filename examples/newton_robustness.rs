//! A seeded set of ordinary scenes, of the kinds users write, run step by step with one backend
//! and the hull formulation, continuing past failed steps: tosses of boxes with spin, drops from
//! a tilt, a box on an edge at gap 0 falling over (h = 1.25 ms, μ = 0.72), pushes on inclines,
//! unions of boxes, a box tossed into a corner, and convex point meshes. Step lengths 1e-3…1e-2,
//! μ 0.1…1.2. Prints one line per run and a table per kind of scene: runs with every step
//! converged by the backend itself, failed steps, and the terminations of the failed steps.
//! `docs/newton.md` records its numbers.
//!
//! ```text
//! cargo run --release --example newton_robustness -- [newton|path] [RUNS] [SEED] [ONLY]
//! ```
//!
//! Defaults: `newton 70 1`; `ONLY` runs just the run with that index (and prints each failed
//! step's worst component).

use std::collections::BTreeMap;

use ecp::formulations::blocks::FrictionParams;
use ecp::formulations::geometry::{ConvexPiece, HalfSpace, MassProperties, Shape};
use ecp::formulations::rotation::{quat_from_axis_angle, rotation_matrix};
use ecp::formulations::{BodySpec, BodyState, Load, Scene, Simulation};
use ecp::model::McpSolver;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};
use nalgebra::{Vector3, Vector4, Vector6};

/// A small deterministic generator (64-bit LCG, high bits), so the set needs no dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
    fn log_range(&mut self, a: f64, b: f64) -> f64 {
        (a.ln() + (b.ln() - a.ln()) * self.next()).exp()
    }
    fn vec(&mut self, r: f64) -> Vector3<f64> {
        Vector3::new(self.range(-r, r), self.range(-r, r), self.range(-r, r))
    }
    fn quat(&mut self) -> Vector4<f64> {
        loop {
            let q = Vector4::new(
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
            );
            let n = q.norm();
            if n > 0.1 && n <= 1.0 {
                return q / n;
            }
        }
    }
}

const KINDS: [&str; 7] = [
    "toss",
    "tilt-drop",
    "edge-fall",
    "incline-push",
    "union",
    "corner",
    "mesh",
];

fn cuboid_body(
    rng: &mut Rng,
    dims: Vector3<f64>,
    state: BodyState,
    load: Load,
) -> Result<BodySpec, String> {
    let mass = rng.log_range(0.05, 20.0);
    Ok(BodySpec {
        name: "box".into(),
        mass: MassProperties::solid_cuboid(mass, dims.x, dims.y, dims.z)
            .map_err(|e| e.to_string())?,
        shape: Shape::cuboid(dims.x, dims.y, dims.z).map_err(|e| e.to_string())?,
        initial: state,
        load,
    })
}

/// Places the body so that its lowest vertex is `gap` above `plane`.
fn place(
    shape: &Shape,
    q: Vector4<f64>,
    plane: &HalfSpace,
    gap: f64,
    at: Vector3<f64>,
) -> Vector3<f64> {
    let r = rotation_matrix(&q);
    let lowest = shape
        .vertices()
        .iter()
        .map(|v| plane.value(&(at + r * v)))
        .fold(f64::INFINITY, f64::min);
    at + plane.normal() * (gap - lowest)
}

fn make_scene(kind: &str, rng: &mut Rng) -> Result<Scene, String> {
    let mut h = rng.log_range(1e-3, 1e-2);
    let mut mu = rng.range(0.1, 1.2);
    let ground = HalfSpace::ground();
    let mut planes = vec![ground];
    let dims = Vector3::new(
        rng.range(0.05, 0.5),
        rng.range(0.05, 0.5),
        rng.range(0.03, 0.3),
    );
    let body = match kind {
        "toss" => {
            let q = rng.quat();
            let shape = Shape::cuboid(dims.x, dims.y, dims.z).map_err(|e| e.to_string())?;
            let x = place(&shape, q, &ground, rng.range(0.0, 0.3), Vector3::zeros());
            let v = rng.vec(2.0);
            let w = rng.vec(10.0);
            cuboid_body(rng, dims, BodyState { x, q, v, w }, Load::None)?
        }
        "tilt-drop" => {
            let axis = Vector3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 0.0);
            let q = quat_from_axis_angle(&axis, rng.range(0.05, 1.2))
                .unwrap_or(Vector4::new(1.0, 0.0, 0.0, 0.0));
            let shape = Shape::cuboid(dims.x, dims.y, dims.z).map_err(|e| e.to_string())?;
            let x = place(&shape, q, &ground, rng.range(0.0, 0.1), Vector3::zeros());
            cuboid_body(
                rng,
                dims,
                BodyState {
                    x,
                    q,
                    v: Vector3::zeros(),
                    w: Vector3::zeros(),
                },
                Load::None,
            )?
        }
        "edge-fall" => {
            // On an edge at gap 0, tilted past or short of its balance angle.
            if rng.next() < 0.3 {
                h = 1.25e-3;
                mu = 0.72;
            }
            let q = quat_from_axis_angle(&Vector3::y(), rng.range(0.1, 1.4))
                .unwrap_or(Vector4::new(1.0, 0.0, 0.0, 0.0));
            let shape = Shape::cuboid(dims.x, dims.y, dims.z).map_err(|e| e.to_string())?;
            let x = place(&shape, q, &ground, 0.0, Vector3::zeros());
            cuboid_body(
                rng,
                dims,
                BodyState {
                    x,
                    q,
                    v: Vector3::zeros(),
                    w: Vector3::zeros(),
                },
                Load::None,
            )?
        }
        "incline-push" => {
            let theta = rng.range(0.0, 0.5);
            let plane = HalfSpace::incline(theta).map_err(|e| e.to_string())?;
            planes[0] = plane;
            let q = quat_from_axis_angle(&Vector3::y(), -theta)
                .unwrap_or(Vector4::new(1.0, 0.0, 0.0, 0.0));
            let shape = Shape::cuboid(dims.x, dims.y, dims.z).map_err(|e| e.to_string())?;
            let x = place(&shape, q, &plane, 0.0, Vector3::zeros());
            let mut body = cuboid_body(
                rng,
                dims,
                BodyState {
                    x,
                    q,
                    v: Vector3::zeros(),
                    w: Vector3::zeros(),
                },
                Load::None,
            )?;
            let m = body.mass.mass;
            let f = m * 9.8 * rng.range(0.0, 1.5);
            let dir = Vector3::new(theta.cos(), 0.0, theta.sin()) * rng.range(-1.0, 1.0).signum();
            let lever = rng.range(0.0, 0.5) * dims.z;
            let torque = Vector3::new(0.0, lever, 0.0).cross(&(dir * f));
            body.load = Load::Constant(Vector6::new(
                dir.x * f,
                dir.y * f,
                dir.z * f,
                torque.x,
                torque.y,
                torque.z,
            ));
            body
        }
        "union" => {
            let a = Vector3::new(
                rng.range(0.03, 0.2),
                rng.range(0.03, 0.2),
                rng.range(0.02, 0.1),
            );
            let b = Vector3::new(
                rng.range(0.02, 0.1),
                rng.range(0.03, 0.2),
                rng.range(0.02, 0.2),
            );
            let boxes = [
                (a, Vector3::zeros()),
                (b, Vector3::new(a.x + b.x, 0.0, b.z - a.z)),
            ];
            let mass = rng.log_range(0.05, 20.0);
            let (mp, cm) =
                MassProperties::uniform_cuboids(mass, &boxes).map_err(|e| e.to_string())?;
            let shape = Shape::from_pieces(
                boxes
                    .iter()
                    .map(|(h, c)| ConvexPiece::cuboid(*h, c - cm))
                    .collect(),
            )
            .map_err(|e| e.to_string())?;
            let q = rng.quat();
            let x = place(&shape, q, &ground, rng.range(0.0, 0.2), Vector3::zeros());
            BodySpec {
                name: "union".into(),
                mass: mp,
                shape,
                initial: BodyState {
                    x,
                    q,
                    v: rng.vec(1.0),
                    w: rng.vec(5.0),
                },
                load: Load::None,
            }
        }
        "corner" => {
            // A wall x ≥ 0.3 (solid on +x) beside the ground; the box thrown at it.
            let wall =
                HalfSpace::new(Vector3::new(-1.0, 0.0, 0.0), -0.3).map_err(|e| e.to_string())?;
            planes.push(wall);
            let q = rng.quat();
            let shape = Shape::cuboid(dims.x, dims.y, dims.z).map_err(|e| e.to_string())?;
            let x0 = place(&shape, q, &ground, rng.range(0.0, 0.15), Vector3::zeros());
            let x = place(&shape, q, &wall, rng.range(0.0, 0.1), x0);
            let v = Vector3::new(
                rng.range(0.0, 2.0),
                rng.range(-0.5, 0.5),
                rng.range(-1.0, 1.0),
            );
            let w = rng.vec(5.0);
            cuboid_body(rng, dims, BodyState { x, q, v, w }, Load::None)?
        }
        _ => {
            // A convex mesh: points on an ellipsoid.
            let n = 8 + (rng.next() * 20.0) as usize;
            let radii = dims * 0.5;
            let points: Vec<Vector3<f64>> = (0..n)
                .map(|_| {
                    let d = rng.vec(1.0).normalize();
                    d.component_mul(&radii)
                })
                .collect();
            let shape =
                Shape::from_pieces(vec![ConvexPiece::Points(points)]).map_err(|e| e.to_string())?;
            let mass = rng.log_range(0.05, 20.0);
            let mp = MassProperties::solid_cuboid(mass, dims.x * 0.6, dims.y * 0.6, dims.z * 0.6)
                .map_err(|e| e.to_string())?;
            let q = rng.quat();
            let x = place(&shape, q, &ground, rng.range(0.0, 0.2), Vector3::zeros());
            BodySpec {
                name: "mesh".into(),
                mass: mp,
                shape,
                initial: BodyState {
                    x,
                    q,
                    v: rng.vec(1.0),
                    w: rng.vec(6.0),
                },
                load: Load::None,
            }
        }
    };
    let duration = (0.4f64).min(300.0 * h);
    Ok(Scene {
        name: kind.into(),
        bodies: vec![body],
        planes,
        friction: FrictionParams {
            mu,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.1 * dims.min(),
        },
        gravity: Vector3::new(0.0, 0.0, -9.8),
        h,
        duration,
        world: Default::default(),
    })
}

/// The scene of run `index` of the set seeded by `seed`, with its kind.
fn scene_of(seed: u64, index: usize) -> Result<(&'static str, Scene), String> {
    let kind = KINDS[index % KINDS.len()];
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (index as u64 + 1));
    for _ in 0..4 {
        rng.next();
    }
    Ok((kind, make_scene(kind, &mut rng)?))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let backend = args.first().map_or("newton", String::as_str).to_string();
    let runs: usize = args.get(1).map_or(Ok(70), |s| s.parse())?;
    let seed: u64 = args.get(2).map_or(Ok(1), |s| s.parse())?;
    let only: Option<usize> = args.get(3).map(|s| s.parse()).transpose()?;
    let mut per_kind: BTreeMap<&str, (usize, usize, usize, usize)> = BTreeMap::new();
    let mut terminations: BTreeMap<String, usize> = BTreeMap::new();
    let (mut total_steps, mut total_failed, mut clean_runs, mut total_iterations) = (0, 0, 0, 0);
    for index in 0..runs {
        if only.is_some_and(|o| o != index) {
            continue;
        }
        let (kind, scene) = scene_of(seed, index)?;
        let (h, mu) = (scene.h, scene.friction.mu);
        let mut solver: Box<dyn McpSolver> = match backend.as_str() {
            "path" => Box::new(PathSolver::new(PathSettings::default())),
            _ => Box::new(NewtonSolver::new(NewtonSettings {
                trace: only.is_some(),
                ..NewtonSettings::default()
            })),
        };
        let mut sim = Simulation::new(scene)?;
        let (mut steps, mut failed, mut first) = (0usize, 0usize, None);
        let mut iterations = 0usize;
        sim.run(solver.as_mut(), |rec| {
            steps += 1;
            iterations += rec.summary.iterations;
            if !rec.converged {
                failed += 1;
                let t = format!("{:?}", rec.summary.termination);
                *terminations.entry(t.clone()).or_default() += 1;
                if first.is_none() {
                    first = Some((
                        rec.step,
                        t,
                        rec.summary.residual,
                        rec.contacts
                            .iter()
                            .map(|c| c.min_gap)
                            .fold(f64::INFINITY, f64::min),
                    ));
                }
                if only.is_some() {
                    println!(
                        "  step {} {:?} residual {:.1e} worst {:?} gap {:.2e} pn {:.2e}",
                        rec.step,
                        rec.summary.termination,
                        rec.summary.residual,
                        rec.summary.worst,
                        rec.contacts[0].min_gap,
                        rec.contacts[0].pn
                    );
                    if failed == 1 {
                        for r in &rec.summary.trace {
                            println!(
                                "    it {:3} res {:.2e} merit {:.2e} {:?} t {:.1e} |d| {:.1e}",
                                r.iteration,
                                r.residual,
                                r.merit,
                                r.step,
                                r.step_length,
                                r.direction_norm
                            );
                        }
                    }
                }
            }
            true
        })?;
        total_steps += steps;
        total_failed += failed;
        total_iterations += iterations;
        clean_runs += usize::from(failed == 0);
        let e = per_kind.entry(kind).or_default();
        e.0 += 1;
        e.1 += usize::from(failed == 0);
        e.2 += steps;
        e.3 += failed;
        let first = first.map_or(String::new(), |(s, t, r, g)| {
            format!(" first at step {s}: {t} residual {r:.1e} gap {g:.1e}")
        });
        println!(
            "run {index:3} {kind:12} h {h:.2e} mu {mu:.2} steps {steps:4} failed {failed:4} \
             iterations/step {:.1}{first}",
            iterations as f64 / steps.max(1) as f64
        );
    }
    println!("\n| kind | runs | runs with every step converged | steps | failed steps |");
    println!("|---|---|---|---|---|");
    for (kind, (r, c, s, f)) in &per_kind {
        println!("| {kind} | {r} | {c} | {s} | {f} |");
    }
    let total_runs: usize = per_kind.values().map(|v| v.0).sum();
    println!(
        "| all | {total_runs} | {clean_runs} | {total_steps} | {total_failed} |\n\n\
         backend {backend}, seed {seed}; mean iterations per step {:.2}; failed steps by \
         termination: {terminations:?}",
        total_iterations as f64 / total_steps.max(1) as f64
    );
    Ok(())
}
