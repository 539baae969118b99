//! One hard step of a scene, solved again by each backend with its counters and trace
//! (`docs/newton.md#hard-steps`, `docs/path.md#hard-steps`):
//!
//! ```text
//! cargo run --release --example step_probe -- SCENE.toml --step K [--with newton|path]
//!     [--trace] [--compare] [--as-given] [--states] [--sweep] [--driver] [--previous] [--newton NAME=VALUE ..] [--path NAME=VALUE ..]
//! ```
//!
//! runs the scene's steps 1 … K−1 with the backend `--with` (default `path`; hull formulation,
//! the scene's tolerance, no fallbacks, as the stress suite), prepares step K and solves that
//! step problem from its warm start with PATH and with Newton (each built as the registry builds
//! it, then changed by the `--newton` / `--path` settings), printing the summary, the counters
//! and, with `--trace`, every iteration (residual, merit, step kind, step length).
//! `--driver` solves step K as a step does instead (the backend `--with` through the driver's
//! budgeted starts and retry starts; `--path` / `--newton` settings change that step's backend
//! when it is PATH / Newton) and prints each solve it makes: its budget, result and
//! iterations. `--previous` prepares step K from the plain warm start (the last step's
//! solution; `WarmStart::Previous`) instead of the extrapolated one.
use std::process::ExitCode;
use std::time::Instant;

use ecp::formulations::{FormulationRegistry, SimulationBuilder, WarmStart};
use ecp::model::{IterationRecord, Mcp, McpSolver, Observer, Solution, SolveError};
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};
use ecp::solvers::registry::{BackendOptions, Registry};

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{e}");
            ExitCode::from(2)
        }
    }
}

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let (mut path, mut step, mut with, mut trace) = (None, None, "path".to_string(), false);
    let (mut compare, mut as_given, mut states, mut sweep) = (false, false, false, false);
    let (mut through_driver, mut previous) = (false, false);
    let (mut newton_sets, mut path_sets) = (Vec::new(), Vec::new());
    let mut blends: Vec<String> = Vec::new();
    while let Some(a) = args.next() {
        let mut value = || args.next().unwrap_or_default();
        match a.as_str() {
            "--step" => step = value().parse::<usize>().ok(),
            "--with" => with = value(),
            "--trace" => trace = true,
            "--compare" => compare = true,
            "--as-given" => as_given = true,
            "--states" => states = true,
            "--sweep" => sweep = true,
            "--driver" => through_driver = true,
            "--previous" => previous = true,
            "--blend" => blends.push(value()),
            "--newton" => newton_sets.push(value()),
            "--path" => path_sets.push(value()),
            _ => path = Some(a),
        }
    }
    if sweep && let Some(path) = &path {
        return sweep_steps(path, &newton_sets);
    }
    let (Some(path), Some(step)) = (path, step) else {
        return Err("usage: step_probe SCENE.toml --step K [--with B] [--trace] [--compare] [--as-given] [--states] [--sweep] [--newton K=V] [--path K=V]".into());
    };
    let file = load_scene(std::path::Path::new(&path)).map_err(|e| e.to_string())?;
    let stepper = FormulationRegistry::builtin()
        .create("hull")
        .map_err(|e| e.to_string())?;
    let mut sim = SimulationBuilder::new(file.scene.clone(), stepper)
        .build()
        .map_err(|e| e.to_string())?;
    let options = BackendOptions {
        tolerance: file.solver.tolerance,
        max_iterations: file.solver.max_iterations,
        non_isolated_solutions: false,
    };
    // `newton-monotone`: Newton without the non-monotone restart (the trajectory of before it).
    let mut driver: Box<dyn McpSolver> = if with == "newton-monotone" {
        let d = NewtonSettings::default();
        Box::new(NewtonSolver::new(NewtonSettings {
            tolerance: options.tolerance.unwrap_or(d.tolerance),
            nonmonotone_restart: false,
            ..d
        }))
    } else {
        Registry::builtin()
            .build(&with, &options)
            .map_err(|e| e.to_string())?
    };
    for k in 1..step {
        let rec = sim.step(driver.as_mut()).map_err(|e| e.to_string())?;
        if !rec.converged {
            println!("step {k}: not converged with {with} (state kept)");
        }
    }
    if previous {
        // Step K from the plain warm start (the last step's solution), the driver's first
        // retry start after an extrapolated one.
        sim.set_warm_start(WarmStart::Previous);
    }
    if through_driver {
        // Step K as a step solves it, each solve of the driver logged. The `--path` /
        // `--newton` settings apply to this step's backend (the steps before it ran on the
        // registry's defaults, as the stress suite's trajectory did).
        let mut changed: Option<Box<dyn McpSolver>> = match with.as_str() {
            "path" if !path_sets.is_empty() => Some(Box::new(PathSolver::new(path_settings(
                &options, false, &path_sets,
            )?))),
            "newton" if !newton_sets.is_empty() => Some(Box::new(NewtonSolver::new(
                newton_settings(&options, false, &newton_sets)?,
            ))),
            _ if path_sets.is_empty() && newton_sets.is_empty() => None,
            _ => {
                return Err(format!(
                    "--driver applies --path settings with `--with path` and --newton settings with `--with newton` only (here `--with {with}`)"
                ));
            }
        };
        let backend: &mut dyn McpSolver = match changed.as_mut() {
            Some(b) => b.as_mut(),
            None => driver.as_mut(),
        };
        let mut logged = Logged(backend, None);
        let rec = sim.step(&mut logged).map_err(|e| e.to_string())?;
        println!(
            "step {step} by the driver: converged {}, {} iterations, {:?}, {:.1} us",
            rec.converged, rec.summary.iterations, rec.method, rec.solve_us
        );
        return Ok(());
    }
    if states {
        // The bodies' states at the start of step K, as scene-file lines.
        for (b, st) in sim.states().iter().enumerate() {
            println!(
                "# body {b}\nposition = [{:?}, {:?}, {:?}]\norientation = [{:?}, {:?}, {:?}, {:?}]\nvelocity = [{:?}, {:?}, {:?}]\nangular_velocity = [{:?}, {:?}, {:?}]",
                st.x[0],
                st.x[1],
                st.x[2],
                st.q[0],
                st.q[1],
                st.q[2],
                st.q[3],
                st.v[0],
                st.v[1],
                st.v[2],
                st.w[0],
                st.w[1],
                st.w[2]
            );
        }
        println!("# t = {:?}", sim.time());
    }
    sim.prepare_step().map_err(|e| e.to_string())?;
    let z0 = sim.z().to_vec();
    println!("step {step}: {} unknowns", z0.len());

    let ps = path_settings(&options, trace, &path_sets)?;
    let ns = newton_settings(&options, trace, &newton_sets)?;
    let mut path_solver = PathSolver::new(ps);
    let mut newton_solver = NewtonSolver::new(ns).with_profile();
    if trace {
        // Every iteration of every attempt (a summary's trace has the last attempt's only).
        path_solver = path_solver.with_observer(Box::new(Printer));
        newton_solver = newton_solver.with_observer(Box::new(Printer));
    }
    let step_problem = sim.step_problem();
    let unscaled = Unscaled(&step_problem);
    let problem: &dyn Mcp = if as_given { &unscaled } else { &step_problem };
    let zp = report("path", &mut path_solver, problem, &z0, trace);
    let zn = report("newton", &mut newton_solver, problem, &z0, trace);
    // `--blend MODE:T`: Newton again from a start between the warm start and PATH's answer:
    // `all:T` moves every unknown by T of the way, `contact:T` only the `contact.*` unknowns,
    // `point:T` only the contact points `contact.a*`, `weights:T` only `contact.l*`.
    for b in &blends {
        // `reseed:empty|lowest|patch`: the warm start's velocities mapped back by the structure
        // (`StepStructure::assemble`): every contact's point from the geometry at the warm
        // start's configuration, with no impulse, or the warm start's `p_n` on the patch's
        // lowest vertex, or spread evenly over the patch; friction and slip zero.
        if let Some(kind) = b.strip_prefix("reseed:") {
            let st = problem.structure().ok_or("no structure")?;
            let mut point = ecp::model::ConicPoint {
                velocities: st.velocities(&z0),
                contacts: Vec::new(),
            };
            for c in 0..st.num_contacts() {
                let g = st.contact(c, &z0, 0.0);
                let pn = st.normal_impulse(c, &z0).unwrap_or(0.0).max(0.0);
                let mut imp = ecp::model::ContactImpulses::default();
                match kind {
                    "lowest" => {
                        if let Some(v) = g.patch.iter().min_by(|a, b| a.gap.total_cmp(&b.gap)) {
                            imp.vertex_impulses.push((v.index, pn));
                        }
                    }
                    "patch" => {
                        let n = g.patch.len().max(1) as f64;
                        for v in &g.patch {
                            imp.vertex_impulses.push((v.index, pn / n));
                        }
                    }
                    _ => {}
                }
                point.contacts.push(imp);
            }
            let mut zs = z0.clone();
            st.assemble(&point, &mut zs);
            let mut ns2 = NewtonSolver::new(newton_settings(&options, false, &newton_sets)?);
            report(&format!("newton from {b}"), &mut ns2, problem, &zs, false);
            continue;
        }
        // `zero:PREFIX` / `set:PREFIX=V`: the warm start with the unknowns named PREFIX… at V.
        if let Some(rest) = b.strip_prefix("set:") {
            let (prefix, v) = rest.split_once('=').unwrap_or((rest, "0"));
            let v: f64 = v.parse().map_err(|_| format!("bad --blend {b}"))?;
            let mcp = sim.mcp();
            let mut zs = z0.clone();
            for (i, zi) in zs.iter_mut().enumerate() {
                if mcp.component_name(i).starts_with(prefix) {
                    *zi = v.clamp(mcp.lower()[i], mcp.upper()[i]);
                }
            }
            let mut ns2 = NewtonSolver::new(newton_settings(&options, false, &newton_sets)?);
            report(&format!("newton from {b}"), &mut ns2, problem, &zs, false);
            continue;
        }
        let (mode, t) = b.split_once(':').unwrap_or((b.as_str(), "1"));
        let t: f64 = t.parse().map_err(|_| format!("bad --blend {b}"))?;
        let mcp = sim.mcp();
        let mut zs = z0.clone();
        for i in 0..z0.len() {
            let name = mcp.component_name(i);
            let pick = match mode {
                "all" => true,
                "contact" => name.starts_with("contact."),
                "point" => name.starts_with("contact.a"),
                "weights" => name.starts_with("contact.l"),
                "body" => name.starts_with("body."),
                _ => false,
            };
            if pick {
                zs[i] = z0[i] + t * (zp[i] - z0[i]);
            }
        }
        let mut ns2 = NewtonSolver::new(newton_settings(&options, false, &newton_sets)?);
        report(&format!("newton from {b}"), &mut ns2, problem, &zs, false);
    }
    if compare {
        // Each unknown at the warm start, PATH's end point and Newton's, with F there.
        let mcp = sim.mcp();
        let (mut fp, mut fnw) = (vec![0.0; z0.len()], vec![0.0; z0.len()]);
        mcp.evaluate(&zp, &mut fp);
        mcp.evaluate(&zn, &mut fnw);
        for i in 0..z0.len() {
            println!(
                "{:3} {:24} [{:9.2e},{:9.2e}] z0 {:11.4e} path {:11.4e} (F {:10.3e}) newton {:11.4e} (F {:10.3e})",
                i,
                mcp.component_name(i),
                mcp.lower()[i],
                mcp.upper()[i],
                z0[i],
                zp[i],
                fp[i],
                zn[i],
                fnw[i]
            );
        }
    }
    let p = newton_solver.take_profile();
    println!(
        "newton profile: iterations by attempt [plain, damped, smooth, dsmooth, nonmonotone] {:?}, lu {}, qr {}, lm_iters {}, lm_trials {}",
        p.attempt_iterations,
        p.lu_factorizations,
        p.min_norm_factorizations,
        p.lm_iterations,
        p.lm_trials
    );
    Ok(())
}

/// PATH's defaults with the scene's tolerance and iteration limit, then the `--path` settings.
fn path_settings(
    options: &BackendOptions,
    trace: bool,
    sets: &[String],
) -> Result<PathSettings, String> {
    let d = PathSettings::default();
    let mut ps = PathSettings {
        tolerance: options.tolerance.unwrap_or(d.tolerance),
        max_iterations: options.max_iterations.unwrap_or(d.max_iterations),
        trace,
        ..d
    };
    for kv in sets {
        set_path(&mut ps, kv)?;
    }
    Ok(ps)
}

/// Newton's defaults with the scene's tolerance and iteration limit, then the `--newton`
/// settings.
fn newton_settings(
    options: &BackendOptions,
    trace: bool,
    sets: &[String],
) -> Result<NewtonSettings, String> {
    let d = NewtonSettings::default();
    let mut ns = NewtonSettings {
        tolerance: options.tolerance.unwrap_or(d.tolerance),
        max_iterations: options.max_iterations.unwrap_or(d.max_iterations),
        trace,
        ..d
    };
    for kv in sets {
        set_newton(&mut ns, kv)?;
    }
    Ok(ns)
}

fn report(
    name: &str,
    solver: &mut dyn McpSolver,
    problem: &dyn Mcp,
    z0: &[f64],
    _trace: bool,
) -> Vec<f64> {
    let started = Instant::now();
    let result = solver.solve(problem, z0);
    let ms = started.elapsed().as_secs_f64() * 1e3;
    let (sol, converged): (&Solution, bool) = match &result {
        Ok(s) => (s, true),
        Err(SolveError::NotConverged { best }) => (best, false),
        Err(e) => {
            println!("{name}: {e}");
            return z0.to_vec();
        }
    };
    let s = &sol.summary;
    println!(
        "{name}: converged {converged}, {:?}, {} iterations, residual {:.2e}, {ms:.1} ms, worst {:?}",
        s.termination, s.iterations, s.residual, s.worst
    );
    println!("  {}", s.counters);
    sol.z.clone()
}

/// `--sweep`: steps the scene with Newton changed by the `--newton` settings, and solves each
/// step also with the default Newton from the same warm start; prints the steps where the two
/// took different iteration counts, and the totals.
fn sweep_steps(path: &str, sets: &[String]) -> Result<(), String> {
    let file = load_scene(std::path::Path::new(path)).map_err(|e| e.to_string())?;
    let stepper = FormulationRegistry::builtin()
        .create("hull")
        .map_err(|e| e.to_string())?;
    let mut sim = SimulationBuilder::new(file.scene.clone(), stepper)
        .build()
        .map_err(|e| e.to_string())?;
    let d = NewtonSettings::default();
    let base = NewtonSettings {
        tolerance: file.solver.tolerance.unwrap_or(d.tolerance),
        max_iterations: file.solver.max_iterations.unwrap_or(d.max_iterations),
        ..d
    };
    let mut changed = base.clone();
    for kv in sets {
        set_newton(&mut changed, kv)?;
    }
    let mut driver = NewtonSolver::new(changed).with_profile();
    let mut other = NewtonSolver::new(base).with_profile();
    let iterations = |r: &Result<Solution, SolveError>| match r {
        Ok(s) => (s.summary.iterations, true),
        Err(SolveError::NotConverged { best }) => (best.summary.iterations, false),
        Err(_) => (0, false),
    };
    let (mut ta, mut tb, mut wa, mut wb) = (0usize, 0usize, 0usize, 0usize);
    for k in 1..=file.scene.num_steps() {
        sim.prepare_step().map_err(|e| e.to_string())?;
        let z0 = sim.z().to_vec();
        // Not the profile of the last step's solve by `sim.step` below.
        let _ = driver.take_profile();
        let a = iterations(&sim.solve_step_problem(&mut driver, &z0));
        let b = iterations(&sim.solve_step_problem(&mut other, &z0));
        // Iterations by attempt [plain, damped, smooth, dsmooth, nonmonotone].
        let (pa, pb) = (driver.take_profile(), other.take_profile());
        ta += a.0;
        tb += b.0;
        // Iterations run, over every attempt in both unit systems (a summary counts those of the
        // unit system that answered).
        wa += pa.attempt_iterations.iter().sum::<usize>();
        wb += pb.attempt_iterations.iter().sum::<usize>();
        if a != b {
            println!(
                "step {k}: --newton settings {a:?} {:?}, defaults {b:?} {:?}",
                pa.attempt_iterations, pb.attempt_iterations
            );
        }
        sim.step(&mut driver).map_err(|e| e.to_string())?;
    }
    println!(
        "total iterations: --newton settings {ta}, defaults {tb}; run (all attempts, both unit systems): {wa}, {wb}"
    );
    Ok(())
}

/// A backend that prints each solve the driver asks of it (budget, result, iterations).
struct Logged<'a>(&'a mut dyn McpSolver, Option<usize>);

impl McpSolver for Logged<'_> {
    fn name(&self) -> &str {
        self.0.name()
    }
    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let result = self.0.solve(mcp, z0);
        let (what, s) = match &result {
            Ok(s) => ("converged", Some(&s.summary)),
            Err(SolveError::NotConverged { best }) => ("failed", Some(&best.summary)),
            Err(_) => ("error", None),
        };
        println!(
            "  solve (budget {:?}): {what}, {:?} iterations, residual {:?}",
            self.1,
            s.map(|s| s.iterations),
            s.map(|s| s.residual)
        );
        result
    }
    fn set_iteration_budget(&mut self, budget: Option<usize>) -> bool {
        self.1 = budget;
        self.0.set_iteration_budget(budget)
    }
    fn converges_to_round_off(&self) -> bool {
        self.0.converges_to_round_off()
    }
}

/// Prints every iteration it sees.
struct Printer;

impl Observer for Printer {
    fn observe(&mut self, r: &IterationRecord) {
        println!(
            "  {:4} res {:.3e} merit {:.3e} {:?} t {:.3e} |d| {:.2e}",
            r.iteration, r.residual, r.merit, r.step, r.step_length, r.direction_norm
        );
    }
}

/// The step problem without its scene scales: the backends solve it as given only.
struct Unscaled<'a>(&'a dyn Mcp);

impl Mcp for Unscaled<'_> {
    fn dim(&self) -> usize {
        self.0.dim()
    }
    fn lower(&self) -> &[f64] {
        self.0.lower()
    }
    fn upper(&self) -> &[f64] {
        self.0.upper()
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        self.0.evaluate(z, f)
    }
    fn jacobian_pattern(&self) -> &std::sync::Arc<ecp::model::CscPattern> {
        self.0.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        self.0.jacobian(z, values)
    }
    fn component_name(&self, i: usize) -> String {
        self.0.component_name(i)
    }
}

fn set_newton(s: &mut NewtonSettings, kv: &str) -> Result<(), String> {
    let (name, value) = kv.split_once('=').ok_or("expected NAME=VALUE")?;
    let f = || value.parse::<f64>().map_err(|e| e.to_string());
    let n = || value.parse::<usize>().map_err(|e| e.to_string());
    let b = || value.parse::<bool>().map_err(|e| e.to_string());
    match name {
        "lm_initial_damping" => s.lm_initial_damping = f()?,
        "stall_window" => s.stall_window = n()?,
        "slow_rate_test" => s.slow_rate_test = b()?,
        "flat_merit_window" => s.flat_merit_window = n()?,
        "ratio_test" => s.ratio_test = b()?,
        "nonmonotone_restart" => s.nonmonotone_restart = b()?,
        "forget_undone_steps" => s.forget_undone_steps = b()?,
        "complementary_restart" => s.complementary_restart = value.parse::<f64>().ok(),
        "early_complementary_restart" => s.early_complementary_restart = value.parse::<f64>().ok(),
        "complementary_restart_from_best" => {
            s.complementary_restart_from_best = value.parse::<f64>().ok()
        }
        "josephy_newton" => s.josephy_newton = value.parse::<usize>().ok(),
        "budget_grace" => s.budget_grace = value.parse::<f64>().ok(),
        "dense_max" => s.dense_max = n()?,
        "min_norm_max" => s.min_norm_max = n()?,
        "friction_continuation" => s.friction_continuation = value.parse::<usize>().ok(),
        "structure_reseed" => s.structure_reseed = b()?,
        "watchdog_steps" => s.watchdog_steps = n()?,
        "smoothing" if !b()? => s.smoothing = None,
        "damped_restart" => s.damped_restart = value.parse::<f64>().ok(),
        "smoothing_first" => s.smoothing_first = b()?,
        "min_norm_step" => s.min_norm_step = b()?,
        "kink_band" => s.kink_band = value.parse::<f64>().ok(),
        "max_iterations" => s.max_iterations = n()?,
        "lm_residual_damping_after" => s.lm_residual_damping_after = value.parse::<usize>().ok(),
        _ => return Err(format!("unknown Newton setting {name}")),
    }
    Ok(())
}

fn set_path(s: &mut PathSettings, kv: &str) -> Result<(), String> {
    let (name, value) = kv.split_once('=').ok_or("expected NAME=VALUE")?;
    let f = || value.parse::<f64>().map_err(|e| e.to_string());
    let n = || value.parse::<usize>().map_err(|e| e.to_string());
    let b = || value.parse::<bool>().map_err(|e| e.to_string());
    match name {
        "watchdog" => s.watchdog = n()?,
        "watchdog_growth" => s.watchdog_growth = f()?,
        "first_in_both_units" => s.first_in_both_units = b()?,
        "crash_iterations" => s.crash_iterations = n()?,
        "restarts" => s.restarts = n()?,
        "guarded_watchdog" => s.guarded_watchdog = b()?,
        "fischer_restart" => s.fischer_restart = b()?,
        "best_point_restart" => s.best_point_restart = b()?,
        "stall_window" => s.stall_window = n()?,
        "stall_ratio" => s.stall_ratio = f()?,
        "frozen_steps" => s.frozen_steps = n()?,
        "smoothing_failed_stages" => {
            if let Some(sm) = s.smoothing.as_mut() {
                sm.max_failed_stages = Some(n()?);
                sm.count_cut_stages = true;
            }
        }
        "smoothing" if !b()? => s.smoothing = None,
        "max_iterations" => s.max_iterations = n()?,
        "proximal_initial" => s.proximal_initial = f()?,
        "max_path_backtracks" => s.max_path_backtracks = n()?,
        _ => return Err(format!("unknown PATH setting {name}")),
    }
    Ok(())
}
