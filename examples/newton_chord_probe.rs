//! The desk's Newton steps, step by step: the natural residual at each iteration's start (the
//! first is the warm start's), the factorisations and chord steps of each solve, for the
//! defaults or for chord steps on the LU kept from every solve
//! (`NewtonSettings::kept_lu_every_solve`, an experiment: `docs/latency.md`, branch
//! wip-newton).
//!
//! ```text
//! cargo build --release --example newton_chord_probe
//! target/release/examples/newton_chord_probe N [KAPPA]   # KAPPA: the experiment's contraction
//! ```
//!
//! Prints one line per step (`step r0 r1 … | final, LU, chord steps, on the kept LU, refused`)
//! and the totals, then a digest of the records' bits (as `step_latency`'s).

use std::sync::{Arc, Mutex};

use ecp::formulations::{Simulation, scenarios};
use ecp::model::{IterationRecord, Observer};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};

/// The residuals at the iterations' starts, collected across the solves.
struct Residuals(Arc<Mutex<Vec<f64>>>);

impl Observer for Residuals {
    fn observe(&mut self, record: &IterationRecord) {
        if let Ok(mut v) = self.0.lock() {
            v.push(record.residual);
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(120);
    let kappa: Option<f64> = args.get(2).and_then(|a| a.parse().ok());
    let mut settings = NewtonSettings::default();
    if let Some(kappa) = kappa {
        settings.chord_across_solves = Some(kappa);
        settings.kept_lu_every_solve = true;
    }
    let seen = Arc::new(Mutex::new(Vec::new()));
    let mut solver = NewtonSolver::new(settings)
        .with_profile()
        .with_observer(Box::new(Residuals(seen.clone())));
    let mut sim = Simulation::new(scenarios::desk()).expect("desk scene");
    let (mut lu, mut chord, mut kept, mut refused, mut iters) = (0, 0, 0, 0, 0);
    let mut digest: u64 = 0xcbf2_9ce4_8422_2325;
    for k in 1..=n {
        let rec = sim.step(&mut solver).expect("desk step");
        let p = solver.take_profile();
        let rs: Vec<f64> = seen
            .lock()
            .map(|mut v| v.drain(..).collect())
            .unwrap_or_default();
        let line: Vec<String> = rs.iter().map(|r| format!("{r:.1e}")).collect();
        println!(
            "{k:4} {} | {:.1e} LU {} chord {} kept {} refused {}",
            line.join(" "),
            rec.summary.residual,
            p.lu_factorizations,
            p.chord_steps,
            p.kept_lu_steps,
            p.kept_lu_refusals
        );
        lu += p.lu_factorizations;
        chord += p.chord_steps;
        kept += p.kept_lu_steps;
        refused += p.kept_lu_refusals;
        iters += rec.summary.iterations;
        for b in &rec.bodies {
            for v in b.x.iter().chain(&b.q).chain(&b.v).chain(&b.w) {
                for byte in v.to_bits().to_le_bytes() {
                    digest = (digest ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3);
                }
            }
        }
    }
    println!(
        "total: iterations {iters}, LU {lu}, chord steps {chord}, on the kept LU {kept} \
         (refused {refused}); bodies digest {digest:016x}"
    );
}
