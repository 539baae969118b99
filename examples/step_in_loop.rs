//! The desk stepped in a loop (`docs/architecture.md#the-step-driver`): a spring on its CM joins
//! its own step problem, μ and the push change between steps with `set_param`, and the last
//! step's sensitivities are read by named state components. `cargo run --example step_in_loop`
use ecp::formulations::sensitivity::{SensitivityOptions, StepInput, step_sensitivity_with};
use ecp::formulations::{Force, Load, Simulation, StateComponent, scenarios};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use nalgebra::Vector6;

/// What the loop measured: `(t, x, v_x)` every 10 steps, then `dv_x/dμ` and `dv_x/dk` of the
/// last step (k the spring's stiffness).
pub type Trace = (Vec<[f64; 3]>, f64, f64);

/// Runs 60 desk steps with a 200 N/m spring to the start, pushed by 40 N along x; μ drops to 0.1
/// at step 20 and the push stops at step 40. Returns the simulation after the loop, too.
pub fn run() -> Result<(Simulation, Trace), Box<dyn std::error::Error>> {
    let mut scene = scenarios::desk();
    scene.bodies[0].load = Load::Constant(Vector6::new(40.0, 0.0, 0.0, 0.0, 0.0, 0.0));
    let anchor = scene.bodies[0].initial.x;
    let mut sim = Simulation::builder(scene)
        .force(0, Force::spring("tether", 200.0, &anchor))
        .build()?;
    let (mut solver, mut trace) = (NewtonSolver::new(NewtonSettings::default()), Vec::new());
    for step in 1..=60 {
        match step {
            20 => sim.set_param("mu".parse()?, 0.1)?,
            40 => sim.set_param("fx".parse()?, 0.0)?,
            _ => {}
        }
        let rec = sim.step(&mut solver)?;
        if !rec.converged {
            return Err(format!("step {step} did not converge").into());
        }
        if step % 10 == 0 {
            trace.push([rec.t, rec.bodies[0].x.x, rec.bodies[0].v.x]);
        }
    }
    let k = StepInput::Data(sim.force_handles()[0].data[0], 0);
    let sens = step_sensitivity_with(&sim, &SensitivityOptions::default(), &[k])?;
    let d = |input| {
        sens.d_state(0, StateComponent::Velocity(0), input)
            .ok_or("no input")
    };
    let (dmu, dk) = (d(StepInput::Mu)?, d(k)?);
    Ok((sim, (trace, dmu, dk)))
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (_, (trace, dmu, dk)) = run()?;
    for [t, x, v] in trace {
        println!("t = {t:.2} s  x = {x:+.5} m  v_x = {v:+.5} m/s");
    }
    println!("last step: dv_x/dμ = {dmu:+.4e} m/s, dv_x/dk = {dk:+.4e} (m/s)/(N/m)");
    Ok(())
}
