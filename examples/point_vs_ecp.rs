//! The point-contact baseline (`docs/model.md#point-contacts`) beside the ECP model (the paper's
//! hull formulation) on the same scenes, with the Newton and PATH backends: largest differences in
//! `v` and `ω`, largest penetration of each model, the largest gap across which a point still
//! carries load, the centre of pressure against the ECP, and the solve time per step.
//!
//! ```text
//! cargo run --release --example point_vs_ecp
//! ```

use ecp::formulations::point::{PointContacts, centre_of_pressure};
use ecp::formulations::record::penetration;
use ecp::formulations::scenarios;
use ecp::formulations::{Scene, Simulation, StepRecord};
use ecp::model::McpSolver;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};
use nalgebra::Vector3;

/// Runs `sim` to the end; returns the records.
fn run(
    sim: &mut Simulation,
    solver: &mut dyn McpSolver,
) -> Result<Vec<StepRecord>, Box<dyn std::error::Error>> {
    let mut records = Vec::new();
    sim.run(solver, |rec| {
        records.push(rec.clone());
        true
    })?;
    Ok(records)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() { 0.0 } else { v[v.len() / 2] }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// The A5 tilted drop spinning about the vertical at `w_z` rad/s: the scene where the
/// linearised gap lets a vertex end below the plane.
fn spinning_tilted_drop(w_z: f64) -> Scene {
    let mut scene = scenarios::a5_drop_tilted();
    scene.name = format!("a5_drop_tilted_spin_{w_z}");
    scene.bodies[0].initial.w = Vector3::new(0.0, 0.0, w_z);
    scene
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scenes = vec![
        ("A1 sliding", scenarios::a1_sliding()),
        ("A5 tilted drop", scenarios::a5_drop_tilted()),
        ("A5 tilted drop, ω_z = 10", spinning_tilted_drop(10.0)),
        ("A6 tip 110 N", scenarios::a6_tip(110.0)),
        ("desk", scenarios::desk()),
    ];
    println!(
        "| scene | backend | steps | conv. point/hull | max |Δv| | max |Δω| | penetration point | penetration hull | max gap under load (point) | max |CoP − ECP| | µs/step point (mean, median) | µs/step hull (mean, median) | iterations/step point, hull |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut agreement = Vec::new();
    for (name, scene) in scenes {
        let mut by_backend: Vec<(Vec<StepRecord>, Vec<StepRecord>)> = Vec::new();
        for backend in ["newton", "path"] {
            let mut solver: Box<dyn McpSolver> = match backend {
                "newton" => Box::new(NewtonSolver::new(NewtonSettings::default())),
                _ => Box::new(PathSolver::new(PathSettings::default())),
            };
            let mut point = Simulation::builder(scene.clone())
                .formulation(Box::new(PointContacts::new()))
                .build()?;
            let per_body = point.contacts_per_body();
            let p = run(&mut point, solver.as_mut())?;
            let mut hull = Simulation::new(scene.clone())?;
            let h = run(&mut hull, solver.as_mut())?;
            let (mut dv, mut dw, mut gap_loaded, mut dcop) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for (a, b) in p.iter().zip(&h) {
                dv = dv.max((a.bodies[0].v - b.bodies[0].v).norm());
                dw = dw.max((a.bodies[0].w - b.bodies[0].w).norm());
                for c in &a.contacts[..per_body] {
                    if c.pn > 1e-6 {
                        gap_loaded = gap_loaded.max(c.lg);
                    }
                }
                if let Some(cop) = centre_of_pressure(&a.contacts[..per_body])
                    && b.contacts[0].pn > 1e-6
                {
                    dcop = dcop.max((cop - b.contacts[0].a1).norm());
                }
            }
            let pen = |r: &[StepRecord]| r.iter().map(penetration).fold(0.0, f64::max);
            let conv = |r: &[StepRecord]| {
                r.iter()
                    .filter(|x| x.converged && x.summary.residual <= 1e-10)
                    .count()
            };
            let iters = |r: &[StepRecord]| {
                r.iter().map(|x| x.summary.iterations as f64).sum::<f64>() / r.len().max(1) as f64
            };
            let tp: Vec<f64> = p.iter().map(|r| r.solve_us).collect();
            let th: Vec<f64> = h.iter().map(|r| r.solve_us).collect();
            println!(
                "| {name} | {backend} | {} | {}/{} | {dv:.3e} | {dw:.3e} | {:.3e} | {:.3e} | {gap_loaded:.3e} | {dcop:.3e} | {:.0}, {:.0} | {:.0}, {:.0} | {:.1}, {:.1} |",
                p.len(),
                conv(&p),
                conv(&h),
                pen(&p),
                pen(&h),
                mean(&tp),
                median(tp.clone()),
                mean(&th),
                median(th.clone()),
                iters(&p),
                iters(&h),
            );
            by_backend.push((p, h));
        }
        // Newton against PATH on the same model: the motion of a model is unique only when
        // both backends find the same one.
        let gap = |a: &[StepRecord], b: &[StepRecord]| {
            a.iter().zip(b).fold((0.0f64, 0.0f64), |(v, w), (x, y)| {
                (
                    v.max((x.bodies[0].v - y.bodies[0].v).norm()),
                    w.max((x.bodies[0].w - y.bodies[0].w).norm()),
                )
            })
        };
        let (pv, pw) = gap(&by_backend[0].0, &by_backend[1].0);
        let (hv, hw) = gap(&by_backend[0].1, &by_backend[1].1);
        agreement.push(format!(
            "| {name} | {pv:.3e} | {pw:.3e} | {hv:.3e} | {hw:.3e} |"
        ));
    }
    println!();
    println!("Newton against PATH, same model: max |Δv|, |Δω|");
    println!();
    println!("| scene | point Δv | point Δω | hull Δv | hull Δω |");
    println!("|---|---|---|---|---|");
    for line in agreement {
        println!("{line}");
    }
    Ok(())
}
