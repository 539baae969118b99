//! A1's step 35, where the sliding box comes to rest within the step (`docs/latency.md`,
//! "Newton at the stop of a sliding box: A1 step 35"): the extrapolated warm start has `σ = 0`
//! exactly and the friction cone's row `μ p_n − ‖E⁻¹p_f‖` at round-off, so the sign of that
//! round-off chooses Newton's first row for the pair, and with it 1 or 9 iterations;
//! [`NewtonSettings::kink_band`] holds `σ` at its bound whatever the sign.

use std::path::Path;

use ecp::formulations::{FormulationRegistry, Simulation, SimulationBuilder, WarmStart};
use ecp::model::{Mcp, Solution};
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

/// A1 stepped by Newton (defaults) through step 34, with step 35 prepared from the extrapolated
/// warm start.
fn a1_at_the_stop() -> Simulation {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/a1_sliding.toml");
    let file = load_scene(&path).expect("scenes/a1_sliding.toml loads");
    let formulation = FormulationRegistry::builtin()
        .create(&file.formulation)
        .expect("the scene's formulation exists");
    let mut sim = SimulationBuilder::new(file.scene.clone(), formulation)
        .build()
        .expect("A1 builds");
    sim.set_warm_start(WarmStart::Extrapolated);
    let mut newton = NewtonSolver::new(NewtonSettings::default());
    for k in 1..35 {
        let rec = sim.step(&mut newton).expect("steps 1-34 solve");
        assert!(rec.converged, "step {k}");
    }
    sim.prepare_step().expect("step 35 prepares");
    sim
}

fn index(sim: &Simulation, name: &str) -> usize {
    let mcp = sim.mcp();
    (0..mcp.dim())
        .find(|&i| mcp.component_name(i) == name)
        .unwrap_or_else(|| panic!("no unknown {name}"))
}

fn solve(sim: &Simulation, z0: &[f64], kink_band: Option<f64>) -> Solution {
    let mut newton = NewtonSolver::new(NewtonSettings {
        kink_band,
        ..NewtonSettings::default()
    });
    sim.solve_step_problem(&mut newton, z0)
        .expect("step 35 solves")
}

/// The cone's row at the start with `p_t` moved by one part in 1e15 (|p_t| up): below zero by
/// round-off. Without the band Newton's first step is cut and it takes more than one
/// iteration; with it, the full step to sticking as from the start itself (1 iteration), to
/// the same point within 1e-12, and from the start itself (the row at +round-off) the same
/// bits with and without the band.
#[test]
fn the_stop_takes_one_newton_iteration_whatever_the_sign_of_the_round_off_with_the_kink_band() {
    let sim = a1_at_the_stop();
    let z0 = sim.z().to_vec();
    let (sigma, pt) = (
        index(&sim, "contact.sigma[0]"),
        index(&sim, "contact.pf.pt"),
    );
    assert_eq!(z0[sigma], 0.0, "σ at its bound at the start");
    let mut moved = z0.clone();
    moved[pt] *= 1.0 + 1e-15;
    let mut f = vec![0.0; z0.len()];
    sim.mcp().evaluate(&moved, &mut f);
    assert!(
        f[sigma] < 0.0 && f[sigma] > -1e-14,
        "the cone's row at round-off below zero: {:e}",
        f[sigma]
    );

    let plain = solve(&sim, &z0, None);
    let banded = solve(&sim, &z0, Some(1e-14));
    assert_eq!(plain.summary.iterations, 1);
    assert_eq!(plain.z, banded.z, "the band does not act at +round-off");

    let lottery = solve(&sim, &moved, None);
    assert!(
        lottery.summary.iterations > 1,
        "without the band: {} iterations",
        lottery.summary.iterations
    );
    let held = solve(&sim, &moved, Some(1e-14));
    assert_eq!(held.summary.iterations, 1);
    let apart = (held.z.iter().zip(&plain.z))
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(apart < 1e-12, "{apart:e} from the start's solution");
    assert!(
        held.summary.residual <= 1e-14,
        "{:e}",
        held.summary.residual
    );
}
