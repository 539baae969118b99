//! Runs the paper's T-bar example (`docs/model.md#scenarios`, `scenes/tbar.toml`) and prints its
//! contact story: every change of contact mode with the touching vertices (body frame), the ECP in
//! the body frame, the yaw reached, the largest penetration and `|a1_z|` while in contact, and the
//! time per step.
//!
//! `cargo run --release --example tbar -- [newton|path|conic] [SCENE.toml] [--verbose]`

use std::path::PathBuf;

use ecp::backends::{SolverConfig, make_solver};
use ecp::formulations::geometry::{ContactMode, HalfSpace};
use ecp::formulations::rotation::rotation_matrix;
use ecp::formulations::stepper::{MODE_TOLERANCE, Simulation};
use ecp::model::Counter;
use nalgebra::Vector3;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let verbose = args.iter().any(|a| a == "--verbose");
    let mut kind = "newton";
    let mut path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/tbar.toml");
    for a in args.iter().filter(|a| !a.starts_with("--")) {
        match a.as_str() {
            "newton" => kind = "newton",
            "path" => kind = "path",
            "conic" => kind = "conic",
            other => path = PathBuf::from(other),
        }
    }
    let file = ecp::scene::load_scene(&path)?;
    let vertices = file.scene.bodies[0].shape.vertices().to_vec();
    let ground = HalfSpace::ground();
    let mut sim = Simulation::new(file.scene)?;
    let mut solver = make_solver(&SolverConfig {
        name: kind.into(),
        ..file.solver.clone()
    })?;
    let mut last: Option<(ContactMode, Vec<usize>)> = None;
    let (mut max_pen, mut max_a1z, mut max_res) = (0.0f64, 0.0f64, 0.0f64);
    let (mut times, mut failed) = (Vec::new(), 0usize);
    let mut max_tilt = 0.0f64;
    sim.run(solver.as_mut(), |rec| {
        let b = &rec.bodies[0];
        let c = &rec.contacts[0];
        let r = rotation_matrix(&b.q);
        let touching: Vec<usize> = vertices
            .iter()
            .enumerate()
            .filter(|(_, v)| ground.value(&(b.x + r * *v)) <= MODE_TOLERANCE)
            .map(|(i, _)| i)
            .collect();
        let yaw = r[(1, 0)].atan2(r[(0, 0)]);
        let tilt = (r * Vector3::z()).z.clamp(-1.0, 1.0).acos();
        max_tilt = max_tilt.max(tilt);
        times.push(rec.solve_us);
        failed += usize::from(!rec.converged);
        if rec.summary.counter(Counter::Retries).unwrap_or(0) > 0 {
            println!(
                "t={:.2} solved on the stepper's retry ({} iterations, {:.0} µs)",
                rec.t, rec.summary.iterations, rec.solve_us
            );
        }
        if !rec.converged {
            println!(
                "t={:.2} NOT CONVERGED: {} after {} iterations, residual {:.2e}",
                rec.t,
                rec.summary.termination.as_str(),
                rec.summary.iterations,
                rec.summary.residual
            );
        }
        max_res = max_res.max(rec.summary.residual);
        max_pen = max_pen.max(-c.min_gap);
        if c.pn > 0.0 {
            max_a1z = max_a1z.max(c.a1.z.abs());
        }
        let local = r.transpose() * (c.a1 - b.x);
        let key = (c.mode, touching.clone());
        let changed = last.as_ref() != Some(&key);
        if changed || verbose {
            let pts: Vec<String> = touching
                .iter()
                .map(|&i| {
                    let v = vertices[i];
                    format!("({:+.4},{:+.4},{:+.4})", v.x, v.y, v.z)
                })
                .collect();
            println!(
                "t={:.2} mode={:5} yaw={:+.4} tilt={:.4} ecp_body=({:+.5},{:+.5},{:+.5}) a1z={:+.1e} pn={:.4} it={} res={:.1e} touching[{}] {}",
                rec.t,
                c.mode,
                yaw,
                tilt,
                local.x,
                local.y,
                local.z,
                c.a1.z,
                c.pn,
                rec.summary.iterations,
                rec.summary.residual,
                touching.len(),
                if touching.len() <= 4 {
                    pts.join(" ")
                } else {
                    String::new()
                }
            );
            last = Some(key);
        }
        true
    })?;
    let s = sim.state(0);
    let r = rotation_matrix(&s.q);
    let yaw = r[(1, 0)].atan2(r[(0, 0)]);
    let steps = times.len();
    let mean = times.iter().sum::<f64>() / steps.max(1) as f64;
    times.sort_by(f64::total_cmp);
    let median = times.get(steps / 2).copied().unwrap_or(0.0);
    println!(
        "{kind}: {steps} steps, {failed} not converged, max residual {max_res:.2e}, max penetration {max_pen:.2e} m, \
         max |a1_z| in contact {max_a1z:.2e} m, max tilt {:.2} deg, final yaw {:.2} deg",
        max_tilt.to_degrees(),
        yaw.to_degrees()
    );
    println!("solve time per step: mean {mean:.1} µs, median {median:.1} µs");
    Ok(())
}
