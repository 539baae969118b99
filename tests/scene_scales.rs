//! Convergence judged in the scene's own units (`docs/decisions.md#scene-scaled-convergence`):
//! A1 (`scenes/a1_sliding.toml`) and the tilted drop (`scenes/a5_drop_tilted.toml`) written in
//! millimetres, stepped at `h = 1e-5`, with `μ = 1e6`, and moved 1e6 m, each with Newton and
//! PATH (no fallbacks, no retries beyond the stepper's own): every step converges and, where the
//! physics is the same, the motion agrees with the original's.
//!
//! The variants are the scene files with their numbers rewritten (text substitutions checked to
//! apply), so they are exactly what a user would write.

use std::path::Path;

use ecp::backends::{SolverConfig, make_solver};
use ecp::formulations::{Simulation, StepRecord};
use ecp::scene::parse_scene;

/// Steps run per variant: A1 slides through them; the tilted drop (0.1 m, landing at step 15)
/// lands on a vertex and tips.
const STEPS_A1: usize = 15;
const STEPS_A5: usize = 25;

fn scene_text(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(format!("{name}.toml"));
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `text` with each `(from, to)` replaced; every `from` must occur.
fn rewrite(text: &str, edits: &[(&str, &str)]) -> String {
    let mut t = text.to_string();
    for (from, to) in edits {
        assert!(t.contains(from), "`{from}` is not in the scene text");
        t = t.replace(from, to);
    }
    t
}

/// Runs `steps` steps of the scene `text` with backend `kind` (no fallbacks); every step must
/// converge (the backend's own report).
fn run(text: &str, kind: &str, steps: usize, what: &str) -> Vec<StepRecord> {
    let file = parse_scene(text, Path::new("variant.toml")).unwrap_or_else(|e| panic!("{e}"));
    let mut sim = Simulation::new(file.scene).unwrap_or_else(|e| panic!("{what}: {e}"));
    let mut solver = make_solver(&SolverConfig {
        name: kind.into(),
        ..SolverConfig::default()
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let mut records = Vec::new();
    for _ in 0..steps {
        let rec = sim
            .step(solver.as_mut())
            .unwrap_or_else(|e| panic!("{what} ({kind}): step {}: {e}", records.len() + 1));
        assert!(
            rec.converged,
            "{what} ({kind}): step {} did not converge: {:?}, residual {:.3e}",
            rec.step, rec.summary.termination, rec.summary.residual
        );
        records.push(rec);
    }
    records
}

/// The largest difference between the variant's positions (scaled by `1 / length`, shifted by
/// `-shift`) and velocities (scaled by `1 / length`) and the original's, and of the
/// orientations and angular velocities.
fn max_difference(
    original: &[StepRecord],
    variant: &[StepRecord],
    length: f64,
    shift: [f64; 3],
) -> (f64, f64) {
    let (mut dx, mut dv) = (0.0f64, 0.0f64);
    for (a, b) in original.iter().zip(variant) {
        let (a, b) = (&a.bodies[0], &b.bodies[0]);
        for k in 0..3 {
            dx = dx.max(((b.x[k] - shift[k]) / length - a.x[k]).abs());
            dv = dv.max((b.v[k] / length - a.v[k]).abs());
            dv = dv.max((b.w[k] - a.w[k]).abs());
        }
        for k in 0..4 {
            dx = dx.max((b.q[k] - a.q[k]).abs());
        }
    }
    (dx, dv)
}

/// A1 and the tilted drop in millimetres: lengths, g, e_r, positions and velocities × 1000
/// (inertia `uniform`, so computed from the mm box: × 1e6).
fn millimetres(name: &str) -> String {
    let t = scene_text(name);
    let mut edits = vec![
        ("gravity = [0, 0, -9.8]", "gravity = [0, 0, -9800]"),
        ("e_r = 0.1", "e_r = 100"),
        ("box = [0.4, 0.4, 0.2]", "box = [400, 400, 200]"),
    ];
    if name == "a1_sliding" {
        edits.push(("position = [0, 0, 0.1]", "position = [0, 0, 100]"));
        edits.push(("velocity = [1, 0, 0]", "velocity = [1000, 0, 0]"));
    } else {
        edits.push((
            "position = [0, 0, 0.29463611113991145]",
            "position = [0, 0, 294.63611113991145]",
        ));
    }
    rewrite(&t, &edits)
}

/// Positions agree with the original's to this fraction of the scene's length (m/m), velocities
/// to this in m/s of the original (the steps converge to a natural residual of 1e-10 in the
/// scene's units, so the two runs may differ by a few times that).
const AGREE_MM: f64 = 1e-8;

#[test]
fn a1_and_the_tilted_drop_in_millimetres_agree_with_the_originals() {
    for (name, steps) in [("a1_sliding", STEPS_A1), ("a5_drop_tilted", STEPS_A5)] {
        for kind in ["newton", "path"] {
            let original = run(&scene_text(name), kind, steps, name);
            let mm = run(&millimetres(name), kind, steps, &format!("{name} in mm"));
            let (dx, dv) = max_difference(&original, &mm, 1000.0, [0.0; 3]);
            assert!(
                dx <= AGREE_MM && dv <= AGREE_MM,
                "{name} in mm ({kind}): positions differ by {dx:.2e} m, velocities by {dv:.2e} m/s"
            );
        }
    }
}

#[test]
fn a1_and_the_tilted_drop_converge_at_h_1e_5() {
    for name in ["a1_sliding", "a5_drop_tilted"] {
        let text = rewrite(&scene_text(name), &[("h = 0.01", "h = 0.00001")]);
        for kind in ["newton", "path"] {
            let recs = run(&text, kind, 20, &format!("{name} at h = 1e-5"));
            // Nothing changes in 0.2 ms but what gravity and friction do: A1 slows by μ g t.
            if name == "a1_sliding" {
                let v = recs[19].bodies[0].v.x;
                let want = 1.0 - 0.3 * 9.8 * 20.0 * 1e-5;
                assert!(
                    (v - want).abs() <= 1e-9,
                    "A1 at h = 1e-5 ({kind}): v_x = {v}, want {want}"
                );
            }
        }
    }
}

#[test]
fn a1_with_mu_1e6_converges_and_dissipates() {
    let text = rewrite(&scene_text("a1_sliding"), &[("mu = 0.3", "mu = 1e6")]);
    for kind in ["newton", "path"] {
        let recs = run(&text, kind, STEPS_A1, "A1 with μ = 1e6");
        // The friction bound μ p_n is far above any impulse the box can take: its bottom
        // sticks at once and the box pitches forward over its front edge (v_z, ω_y > 0). No
        // applied work, so the energy (kinetic + potential, 5 J at the start) never rises.
        assert!(
            recs[0].bodies[0].w.y > 0.1,
            "A1 with μ = 1e6 ({kind}): the box does not pitch forward: ω = {:?}",
            recs[0].bodies[0].w
        );
        for w in recs.windows(2) {
            assert!(
                w[1].energy <= w[0].energy + 1e-9,
                "A1 with μ = 1e6 ({kind}): energy rises at step {}: {} → {}",
                w[1].step,
                w[0].energy,
                w[1].energy
            );
        }
    }
}

#[test]
fn a1_and_the_tilted_drop_moved_1e6_m_converge_and_agree() {
    for (name, steps) in [("a1_sliding", STEPS_A1), ("a5_drop_tilted", STEPS_A5)] {
        let t = scene_text(name);
        let position = if name == "a1_sliding" {
            (
                "position = [0, 0, 0.1]",
                "position = [1e6, -1e6, 1000000.1]",
            )
        } else {
            (
                "position = [0, 0, 0.29463611113991145]",
                "position = [1e6, -1e6, 1000000.29463611113991145]",
            )
        };
        let text = rewrite(&t, &[position, ("offset = 0", "offset = 1e6")]);
        for kind in ["newton", "path"] {
            let original = run(&t, kind, steps, name);
            let far = run(&text, kind, steps, &format!("{name} moved 1e6 m"));
            let (dx, dv) = max_difference(&original, &far, 1.0, [1e6, -1e6, 1e6]);
            // Positions near 1e6 m carry round-off of 1e6 · 2.2e-16 = 2.2e-10 m, the start
            // height included, so the tilted box lands on a slightly different gap: its velocities
            // after the landing differ by 3.2e-8 m/s (measured, Newton), hence 1e-7.
            assert!(
                dx <= 1e-8 && dv <= 1e-7,
                "{name} moved 1e6 m ({kind}): positions differ by {dx:.2e} m, velocities by {dv:.2e} m/s"
            );
        }
    }
}
