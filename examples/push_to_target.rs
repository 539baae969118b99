//! An MPC-flavoured use of the trajectory gradients (`docs/fitting.md`): find a piecewise-constant
//! push force on the paper's desk so that its centre of mass reaches a target point at
//! t = 1 s, with L-BFGS (argmin) on the adjoint gradients.
//!
//! ```text
//! cargo run --release --example push_to_target [-- TARGET_X TARGET_Y]
//! ```
//!
//! The desk starts as in the paper (sliding at (0.3, 0.2) m/s and turning at 0.5 rad/s, μ = 0.22,
//! e_r = 0.1) but its periodic loads are replaced by the push: `K = 10` segments of 0.1 s, each
//! a horizontal force `(f_x, f_y)` at the CM (20 unknowns). The loss is
//!
//! `J(f) = |x_CM(1 s) − x*|² + λ Σ_k Δt |f_k|²`,
//!
//! the terminal miss (the sensitivities' `TerminalPositionLoss`) plus a small regularisation:
//! two target coordinates do not determine 20 force values, and the regularisation (λ =
//! 1e-8 m²/(N² s)) picks the least-effort profile among those that reach the target. It
//! shifts the optimum by about `λ f Δt / (2 ∂x/∂f)` ≈ 0.01 mm here, well below the miss we ask
//! for.
//!
//! `dJ/df_k` chains the per-step wrench gradient of the adjoint sweep, `dL/dw_j`, over the steps
//! `j` of segment `k`: `dJ/df_k = Σ_{j ∈ k} dL/dF_j + 2 λ Δt f_k`. Mode switches inside the
//! window (the desk stopping and sticking, a foot lifting) would make the loss only piecewise
//! smooth; the sweep reports them, and so does this example.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use argmin::core::{CostFunction, Executor, Gradient, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use ecp::formulations::scenarios;
use ecp::formulations::sensitivity::{GradientMode, TerminalPositionLoss, trajectory_gradient};
use ecp::formulations::{Load, Scene};
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use nalgebra::{Vector3, Vector6};

/// `println!` that ignores a closed standard output (`... | head`).
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

/// Force segments over the horizon.
const SEGMENTS: usize = 10;
/// Horizon (s).
const HORIZON: f64 = 1.0;
/// Regularisation weight λ (m² per N² s).
const LAMBDA: f64 = 1e-8;

/// The push-to-target problem over `f = (f_x0, f_y0, f_x1, f_y1, ...)` in newtons.
#[derive(Clone)]
struct PushProblem {
    scene: Scene,
    target: Vector3<f64>,
    steps_per_segment: usize,
    /// Simulations run, mode events of the last one.
    stats: Arc<Mutex<(usize, usize)>>,
}

/// The outcome of one evaluation.
struct Evaluation {
    cost: f64,
    gradient: Vec<f64>,
    final_position: Vector3<f64>,
    events: usize,
}

impl PushProblem {
    fn segment_duration(&self) -> f64 {
        self.steps_per_segment as f64 * self.scene.h
    }

    /// The scene with the push `f` as its load (step `k`, starting at `t = k h`, is in segment
    /// `k / steps_per_segment`).
    fn scene_with(&self, f: &[f64]) -> Scene {
        let mut scene = self.scene.clone();
        let forces: Vec<[f64; 2]> = f.chunks(2).map(|c| [c[0], c[1]]).collect();
        let (h, per) = (scene.h, self.steps_per_segment);
        scene.bodies[0].load = Load::Function(Arc::new(move |t: f64| {
            let k = (t / h).round() as usize;
            let [fx, fy] = forces[(k / per).min(forces.len() - 1)];
            Vector6::new(fx, fy, 0.0, 0.0, 0.0, 0.0)
        }));
        scene
    }

    fn evaluate(&self, f: &[f64]) -> Result<Evaluation, argmin::core::Error> {
        let scene = self.scene_with(f);
        let loss = TerminalPositionLoss {
            body: 0,
            target: self.target,
            weight: 1.0,
        };
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        let g = trajectory_gradient(&scene, &[], &loss, &mut solver, GradientMode::Adjoint)
            .map_err(|e| argmin::core::Error::msg(format!("push {f:?}: {e}")))?;
        let dt = self.segment_duration();
        let mut gradient = vec![0.0; f.len()];
        for (k, w) in g.wrench_gradient.iter().enumerate() {
            let s = (k / self.steps_per_segment).min(SEGMENTS - 1);
            gradient[2 * s] += w[0][0];
            gradient[2 * s + 1] += w[0][1];
        }
        let mut reg = 0.0;
        for (gi, fi) in gradient.iter_mut().zip(f) {
            reg += LAMBDA * dt * fi * fi;
            *gi += 2.0 * LAMBDA * dt * fi;
        }
        let final_position = g
            .records
            .last()
            .map_or(self.scene.bodies[0].initial.x, |r| r.bodies[0].x);
        if let Ok(mut s) = self.stats.lock() {
            s.0 += 1;
            s.1 = g.events.len();
        }
        Ok(Evaluation {
            cost: g.loss + reg,
            gradient,
            final_position,
            events: g.events.len(),
        })
    }
}

impl CostFunction for PushProblem {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, f: &Vec<f64>) -> Result<f64, argmin::core::Error> {
        Ok(self.evaluate(f)?.cost)
    }
}

impl Gradient for PushProblem {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, f: &Vec<f64>) -> Result<Vec<f64>, argmin::core::Error> {
        Ok(self.evaluate(f)?.gradient)
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<f64> = std::env::args()
        .skip(1)
        .map(|a| {
            a.parse::<f64>()
                .map_err(|e| format!("target coordinate \"{a}\": {e}"))
        })
        .collect::<Result<_, _>>()?;
    let (tx, ty) = match args.as_slice() {
        [] => (0.8, 0.5),
        [x, y] => (*x, *y),
        _ => return Err("give the target as two numbers, X Y (metres), or nothing".into()),
    };
    let mut scene = scenarios::desk();
    scene.duration = HORIZON;
    scene.bodies[0].load = Load::None;
    let start = scene.bodies[0].initial.x;
    let target = Vector3::new(tx, ty, start.z);
    let steps = scene.num_steps();
    let steps_per_segment = steps / SEGMENTS;
    let stats = Arc::new(Mutex::new((0usize, 0usize)));
    let problem = PushProblem {
        scene,
        target,
        steps_per_segment,
        stats: Arc::clone(&stats),
    };

    // Start: a constant 40 N towards the target (a little above μ m g = 32.3 N, so the desk
    // keeps sliding and the loss is smooth).
    let dir = (target - start).xy().normalize();
    let f0: Vec<f64> = (0..SEGMENTS)
        .flat_map(|_| [40.0 * dir.x, 40.0 * dir.y])
        .collect();
    let first = problem.evaluate(&f0)?;
    say!(
        "desk, target ({tx}, {ty}) m at t = {HORIZON} s, {SEGMENTS} force segments of {} s",
        problem.segment_duration()
    );
    say!(
        "start: 40 N towards the target, miss {:.4} m, J = {:.4e}",
        (first.final_position - target).norm(),
        first.cost
    );

    let started = Instant::now();
    let solver = LBFGS::new(MoreThuenteLineSearch::new(), 10)
        .with_tolerance_grad(1e-12)?
        .with_tolerance_cost(0.0)?;
    let result = Executor::new(problem.clone(), solver)
        .configure(|s| s.param(f0).max_iters(100))
        .run()?;
    let wall = started.elapsed().as_secs_f64();
    let state = result.state();
    let best = state
        .get_best_param()
        .cloned()
        .ok_or("L-BFGS returned no parameters")?;
    let sims = stats.lock().map(|s| s.0).unwrap_or(0);
    let end = problem.evaluate(&best)?;
    let miss = (end.final_position - target).norm();
    say!(
        "L-BFGS: {} iterations, {sims} simulations with adjoint gradients, {wall:.2} s ({})",
        state.get_iter(),
        state.get_termination_status()
    );
    say!(
        "final CM ({:.6}, {:.6}) m, miss {:.3e} m, J = {:.4e}, mode events {}",
        end.final_position.x,
        end.final_position.y,
        miss,
        end.cost,
        end.events
    );
    say!("force profile:");
    say!(
        "  {:>11} {:>10} {:>10} {:>10}",
        "t (s)",
        "f_x (N)",
        "f_y (N)",
        "|f| (N)"
    );
    for (k, f) in best.chunks(2).enumerate() {
        let t0 = k as f64 * problem.segment_duration();
        say!(
            "  {:>4.1}–{:<4.1}  {:>10.3} {:>10.3} {:>10.3}",
            t0,
            t0 + problem.segment_duration(),
            f[0],
            f[1],
            (f[0] * f[0] + f[1] * f[1]).sqrt()
        );
    }
    Ok(())
}
