//! The `ecp` command line (`docs/outputs.md`): `run`, `compare`, `sweep` and `check` on scene files,
//! `animate` on a run's outputs.
//!
//! Exit status: 0 when every step converged, 1 when some step failed (what was computed is still
//! written), 2 for bad input.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use ecp::backends::parse_formulation;
use ecp::fit::{FitError, GradientMethod, Method};
use ecp::formulations::WarmStart;
use ecp::run::{RunError, RunOptions, compare_scene, run_scene};
use ecp::scene::{SceneFile, load_scene};
use indicatif::{ProgressBar, ProgressStyle};

/// Rigid bodies in intermittent contact: geometrically implicit time stepping with an
/// equivalent contact point, on pluggable MCP solvers.
#[derive(Parser, Debug)]
#[command(name = "ecp", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Simulate a scene; write trajectory.csv, summary.json and plots.
    Run {
        /// The scene file (TOML; see docs/scene-format.md).
        scene: PathBuf,
        /// Solver backend, instead of the scene's [solver] name: newton, path or conic.
        #[arg(long)]
        solver: Option<String>,
        /// Contact formulation, instead of the scene's: hull, union, reduced or point.
        #[arg(long, value_parser = parse_formulation)]
        formulation: Option<String>,
        /// Output directory [default: out/<scene name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Stop after N steps (at most the scene's duration).
        #[arg(long, value_name = "N")]
        steps: Option<usize>,
        /// Do not write the PNG plots.
        #[arg(long)]
        no_plots: bool,
        /// No progress bar and no summary on standard output.
        #[arg(long)]
        quiet: bool,
        /// Go on after a step that no backend, fallback or substep could solve, instead of
        /// stopping; the failed step keeps the bodies' state at its start (never its iterate).
        #[arg(long)]
        keep_going: bool,
        /// Do not fall back on other backends and substeps when the backend cannot solve a
        /// step (docs/fallbacks.md); such a step then fails at once.
        #[arg(long)]
        no_fallbacks: bool,
        /// Also render the run in 3-D into animation.gif (as `ecp animate` with its defaults).
        #[arg(long)]
        animate: bool,
        /// The steps' warm start: `extrapolated` from the last smooth steps (Newton and PATH;
        /// conic starts from the last step), or `previous`, from the last step alone
        /// (docs/input.md#warm-start).
        #[arg(long, value_name = "previous|extrapolated", default_value = "extrapolated", value_parser = parse_warm_start)]
        warm_start: WarmStart,
    },
    /// Render a run's motion in 3-D as an animated GIF, OUT_DIR/animation.gif: the bodies, the
    /// half-spaces, the ECPs of the active contacts and their normal impulses
    /// (docs/outputs.md#animationgif).
    Animate {
        /// The output directory of an `ecp run` (it holds trajectory.csv and summary.json).
        out_dir: PathBuf,
        /// Frames per second of playback (1 to 100; GIF rounds the delay to 1/100 s).
        #[arg(long, default_value_t = 20)]
        fps: u32,
        /// Draw every N-th step [default: the fewest that keep the animation within 10 s and
        /// 300 frames].
        #[arg(long, value_name = "N")]
        every: Option<usize>,
        /// Image size in pixels, WIDTHxHEIGHT.
        #[arg(long, default_value = "800x600", value_parser = parse_size)]
        size: (u32, u32),
        /// The scene file, instead of the one summary.json names (when it moved).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Also write every frame as a PNG into this directory.
        #[arg(long, value_name = "DIR")]
        frames: Option<PathBuf>,
    },
    /// Run every combination of solvers and formulations on one scene and compare them.
    Compare {
        /// The scene file.
        scene: PathBuf,
        /// Comma-separated backends [default: newton,path,conic].
        #[arg(long, value_delimiter = ',')]
        solvers: Option<Vec<String>>,
        /// Comma-separated formulations [default: hull; bodies for a scene whose formulation is
        /// bodies].
        #[arg(long, value_delimiter = ',', value_parser = parse_formulation)]
        formulations: Option<Vec<String>>,
        /// Output directory [default: out/<scene name>/compare].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Stop each run after N steps.
        #[arg(long, value_name = "N")]
        steps: Option<usize>,
    },
    /// Run one scene over a grid of parameter values on every core; write sweep.csv (one row
    /// of results per grid point) and sweep_timing.csv (docs/outputs.md).
    Sweep {
        /// The scene file.
        scene: PathBuf,
        /// A grid axis NAME=START:STOP:COUNT or NAME=v1,v2,... (repeat for more axes; the last
        /// varies fastest). Names as for fit: mu, e_r, mass, vx0, fx, mass[1], ...
        #[arg(long = "param", value_name = "NAME=VALUES")]
        params: Vec<String>,
        /// Output directory [default: out/<scene name>/sweep].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Threads [default: one per core]; the results do not depend on it.
        #[arg(long, value_name = "N")]
        threads: Option<usize>,
        /// Stop each run after N steps.
        #[arg(long, value_name = "N")]
        steps: Option<usize>,
        /// Solver backend, instead of the scene's [solver] name: newton, path or conic.
        #[arg(long)]
        solver: Option<String>,
        /// Contact formulation, instead of the scene's.
        #[arg(long, value_parser = parse_formulation)]
        formulation: Option<String>,
        /// Do not fall back on other backends and substeps (docs/fallbacks.md).
        #[arg(long)]
        no_fallbacks: bool,
    },
    /// Validate a scene and print what it builds, without simulating.
    Check {
        /// The scene file.
        scene: PathBuf,
    },
    /// Fit scene parameters (mu, e_r, ...) so that the simulated trajectory matches a reference
    /// trajectory.csv, starting from the scene's values; print JSON {"params", "cost",
    /// "iterations", "wall_s", ...} (docs/fitting.md).
    Fit {
        /// The scene file.
        scene: PathBuf,
        /// The reference trajectory (a trajectory.csv written by `ecp run` for this scene,
        /// possibly shorter than the scene's duration).
        #[arg(long, value_name = "TRAJ.csv")]
        reference: PathBuf,
        /// Comma-separated parameters to fit: mu, e_t, e_o, e_r, mass, i_xx, i_yy, i_zz, i_xy,
        /// i_xz, i_yz, the initial state x0 .. wz0, a constant load fx .. tz (body i > 0 as
        /// mass[i]).
        #[arg(long, value_delimiter = ',', required = true)]
        params: Vec<String>,
        /// Optimiser.
        #[arg(long, value_enum, default_value_t = Method::Lbfgs)]
        method: Method,
        /// How L-BFGS gets the loss gradient: adjoint (the trajectory sensitivities), forward,
        /// or fd (central finite differences).
        #[arg(long, value_enum, default_value_t = GradientMethod::default())]
        gradient: GradientMethod,
        /// Solver backend, instead of the scene's [solver] name: newton, path or conic.
        #[arg(long)]
        solver: Option<String>,
        /// Contact formulation, instead of the scene's.
        #[arg(long, value_parser = parse_formulation)]
        formulation: Option<String>,
        /// Iteration limit of the optimiser [default: 100 for lbfgs, 400 for nelder-mead].
        #[arg(long, value_name = "N")]
        max_iters: Option<u64>,
        /// Fit only the first N steps of the reference.
        #[arg(long, value_name = "N")]
        steps: Option<usize>,
        /// Loss weights, e.g. v=1,w=1,x=0,q=0,yaw=0 (velocity, angular velocity, position,
        /// orientation, yaw) [default: v=1,w=1].
        #[arg(long, value_name = "LIST")]
        weights: Option<String>,
        /// Start values other than the scene's, e.g. mu=0.286,e_r=0.07.
        #[arg(long, value_name = "LIST")]
        start: Option<String>,
        /// Stopping tolerance (lbfgs: scaled gradient norm; nelder-mead: spread of the
        /// simplex's scaled costs) [default: 1e-12].
        #[arg(long)]
        tolerance: Option<f64>,
    },
    /// Solve an LCP {"M": [[..],..], "q": [..]} with Lemke's method; print JSON
    /// {"z", "w", "pivots", "solve_us", "residual"} (exit status 1 when it has no solution).
    Lcp {
        /// The LCP file (JSON).
        file: PathBuf,
        /// Then solve it N more times with the same solver (warm) and add "repeat", "best_us"
        /// and "median_us" (the fastest and the median of those solves) to the JSON.
        #[arg(long, value_name = "N", default_value_t = 0)]
        repeat: usize,
    },
}

/// `print!` that ignores a closed standard output (`ecp run ... | head`): the run's files are
/// what matters, and a broken pipe must not turn into a panic.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write;
        let _ = write!(std::io::stdout(), $($arg)*);
    }};
}

/// `println!` that ignores a closed standard output, like [`say!`].
macro_rules! sayln {
    ($($arg:tt)*) => {{
        use std::io::Write;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run {
            scene,
            solver,
            formulation,
            out,
            steps,
            no_plots,
            quiet,
            keep_going,
            no_fallbacks,
            animate,
            warm_start,
        } => load(&scene).and_then(|file| {
            let options = RunOptions {
                out_dir: out.unwrap_or_else(|| RunOptions::default_out_dir(&file)),
                solver,
                formulation,
                steps,
                plots: !no_plots,
                keep_going,
                fallbacks: !no_fallbacks,
                warm_start,
                ..RunOptions::default()
            };
            let code = run(&file, &options, quiet)?;
            if animate {
                animate_run(
                    &options.out_dir,
                    &ecp::animate::AnimateOptions::default(),
                    quiet,
                )?;
            }
            Ok(code)
        }),
        Command::Animate {
            out_dir,
            fps,
            every,
            size,
            scene,
            frames,
        } => {
            let options = ecp::animate::AnimateOptions {
                fps,
                every,
                size,
                scene,
                frames_dir: frames,
            };
            animate_run(&out_dir, &options, false).map(|()| ExitCode::SUCCESS)
        }
        Command::Compare {
            scene,
            solvers,
            formulations,
            out,
            steps,
        } => load(&scene).and_then(|file| {
            let options = RunOptions {
                out_dir: out.unwrap_or_else(|| RunOptions::default_out_dir(&file).join("compare")),
                steps,
                plots: false,
                ..RunOptions::default()
            };
            compare(
                &file,
                &solvers.unwrap_or_else(|| {
                    options
                        .registry
                        .names()
                        .into_iter()
                        .map(str::to_string)
                        .collect()
                }),
                &formulations.unwrap_or_else(|| {
                    // The hull formulation, or the multi-body one for a multi-body scene.
                    let default = if file.formulation == "bodies" {
                        "bodies"
                    } else {
                        "hull"
                    };
                    vec![default.to_string()]
                }),
                &options,
            )
        }),
        Command::Fit {
            scene,
            reference,
            params,
            method,
            gradient,
            solver,
            formulation,
            max_iters,
            steps,
            weights,
            start,
            tolerance,
        } => load(&scene).and_then(|file| {
            let request = FitRequest {
                reference,
                params,
                method,
                gradient,
                solver,
                formulation,
                max_iters,
                steps,
                weights,
                start,
                tolerance,
            };
            fit(&file, &request)
        }),
        Command::Sweep {
            scene,
            params,
            out,
            threads,
            steps,
            solver,
            formulation,
            no_fallbacks,
        } => load(&scene).and_then(|file| {
            let options = ecp::batch::BatchOptions {
                threads,
                steps,
                solver,
                formulation,
                fallbacks: !no_fallbacks,
                ..ecp::batch::BatchOptions::default()
            };
            let out = out.unwrap_or_else(|| RunOptions::default_out_dir(&file).join("sweep"));
            sweep(&file, &params, &options, &out)
        }),
        Command::Check { scene } => load(&scene).map(|file| {
            say!("{}", ecp::scene::describe(&file));
            ExitCode::SUCCESS
        }),
        Command::Lcp { file, repeat } => ecp::lcp::load_lcp(&file)
            .map_err(RunError::from)
            .and_then(|lcp| {
                let report = ecp::lcp::solve_lcp_repeated(&lcp, repeat);
                let json = serde_json::to_string(&report).map_err(|e| {
                    RunError::Output(ecp::output::OutputError {
                        path: PathBuf::from("<stdout>"),
                        source: e.into(),
                    })
                })?;
                sayln!("{json}");
                if let Some(e) = &report.error {
                    eprintln!("error: {}: {e}", file.display());
                }
                Ok(if report.solved() {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::from(1)
                })
            }),
    };
    result.unwrap_or_else(|e| {
        eprintln!("error: {e}");
        ExitCode::from(2)
    })
}

/// `previous` or `extrapolated` ([`WarmStart`]).
fn parse_warm_start(text: &str) -> Result<WarmStart, String> {
    match text {
        "previous" => Ok(WarmStart::Previous),
        "extrapolated" => Ok(WarmStart::Extrapolated),
        other => Err(format!(
            "`{other}` is not a warm start: previous or extrapolated"
        )),
    }
}

/// `WIDTHxHEIGHT` in pixels.
fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{text}` is not WIDTHxHEIGHT in pixels, e.g. 800x600");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    Ok((
        w.trim().parse().map_err(|_| bad())?,
        h.trim().parse().map_err(|_| bad())?,
    ))
}

/// Renders the run in `out_dir` and says where it went.
fn animate_run(
    out_dir: &Path,
    options: &ecp::animate::AnimateOptions,
    quiet: bool,
) -> Result<(), RunError> {
    let a = ecp::animate::animate_dir(out_dir, options)?;
    if !quiet {
        sayln!(
            "written {}: {} frames (every {} step{}) at {} fps, {:.3}× real time; longest \
             impulse arrow {:.3e} N s",
            a.path.display(),
            a.frames,
            a.every,
            if a.every == 1 { "" } else { "s" },
            a.fps,
            a.speed,
            a.max_pn
        );
    }
    Ok(())
}

fn load(path: &Path) -> Result<SceneFile, RunError> {
    load_scene(path).map_err(RunError::from)
}

fn run(file: &SceneFile, options: &RunOptions, quiet: bool) -> Result<ExitCode, RunError> {
    let total = options
        .steps
        .map_or(file.scene.num_steps(), |n| n.min(file.scene.num_steps()));
    let bar = if !quiet && std::io::stderr().is_terminal() {
        let bar = ProgressBar::new(total as u64);
        if let Ok(style) = ProgressStyle::with_template(
            "{prefix} [{bar:40}] {pos}/{len} steps, t = {msg} s, ETA {eta}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_prefix(file.scene.name.clone());
        bar.set_message("0.00");
        Some(bar)
    } else {
        None
    };
    let outcome = run_scene(file, options, |rec| {
        if let Some(bar) = &bar {
            bar.set_message(format!("{:.2}", rec.t));
            bar.inc(1);
        }
    });
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    let outcome = outcome?;
    let s = &outcome.summary;
    if !quiet {
        sayln!(
            "{}: {} steps ({} converged, {} failed) with {} / {} in {:.2} s; median step {:.1} µs, \
             mean {:.1} iterations, max residual {:.2e}, max penetration {:.2e} m",
            s.scene,
            s.steps,
            s.converged_steps,
            s.failed_steps,
            s.formulation,
            s.solver,
            s.wall_s,
            s.step_us.median,
            s.iterations.mean,
            s.max_residual,
            s.max_penetration
        );
        sayln!("outputs in {}", options.out_dir.display());
    }
    if let Some(e) = &outcome.plot_error {
        eprintln!("warning: the plots were not written: {e}");
    }
    if let (Some(f), None) = (&s.failure, &outcome.stepper_error) {
        let by = if options.fallbacks {
            "by its backend or any fallback"
        } else {
            "by its backend (fallbacks off)"
        };
        let hint = if options.keep_going {
            format!(
                "the run went on with the bodies' state held over each failed step ({} failed); \
                 every step is in {}",
                s.failed_steps,
                options.out_dir.join("trajectory.csv").display()
            )
        } else {
            format!(
                "the steps before it are in {}; try a smaller h{} or --keep-going (which keeps \
                 the bodies' state over a failed step)",
                options.out_dir.join("trajectory.csv").display(),
                if options.fallbacks {
                    ""
                } else {
                    ", the fallbacks (drop --no-fallbacks)"
                }
            )
        };
        eprintln!(
            "error: step {} (t = {:.4} s) could not be solved {by}: {} (best residual {:.3e}); \
             {hint}",
            f.step, f.t, f.reason, f.residual,
        );
        if let Some(rec) = outcome.records.iter().find(|r| r.step == f.step) {
            eprintln!("  the step's last solve: {}", rec.summary.brief_report());
        }
    }
    if let Some(e) = &outcome.stepper_error {
        eprintln!("error: the run stopped early: {e}");
    }
    Ok(if outcome.succeeded() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn compare(
    file: &SceneFile,
    solvers: &[String],
    formulations: &[String],
    options: &RunOptions,
) -> Result<ExitCode, RunError> {
    let report = compare_scene(file, solvers, formulations, options, |label| {
        eprintln!("running {label} ...");
    })?;
    sayln!(
        "{:<10} {:<8} {:>6} {:>6} {:>11} {:>11} {:>7} {:>10} {:>10} {:>10}",
        "model",
        "solver",
        "steps",
        "failed",
        "median µs",
        "mean µs",
        "iters",
        "max res",
        "Δv max",
        "Δω max"
    );
    for r in &report.runs {
        let s = &r.summary;
        sayln!(
            "{:<10} {:<8} {:>6} {:>6} {:>11.1} {:>11.1} {:>7.2} {:>10.2e} {:>10.2e} {:>10.2e}",
            s.formulation,
            s.solver,
            s.steps,
            s.failed_steps,
            s.step_us.median,
            s.step_us.mean,
            s.iterations.mean,
            s.max_residual,
            r.max_diff_v,
            r.max_diff_w
        );
    }
    for k in &report.skipped {
        sayln!(
            "{:<10} {:<8} skipped: {}",
            k.formulation,
            k.solver,
            k.reason
        );
    }
    sayln!("written {}", options.out_dir.join("compare.json").display());
    let all_ok = report.runs.iter().all(|r| r.summary.failed_steps == 0);
    Ok(if all_ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

fn sweep(
    file: &SceneFile,
    params: &[String],
    options: &ecp::batch::BatchOptions,
    out: &Path,
) -> Result<ExitCode, RunError> {
    let outcome = ecp::sweep::sweep_scene(file, params, options, out)?;
    let failed = outcome.failed_runs();
    sayln!(
        "{}: {} runs on {} thread{} in {:.2} s, {failed} with a failed step; written {} and {}",
        file.scene.name,
        outcome.results.len(),
        outcome.threads,
        if outcome.threads == 1 { "" } else { "s" },
        outcome.wall_s,
        outcome.table.display(),
        outcome.timing.display()
    );
    if let Some(r) = outcome.results.iter().find(|r| r.error.is_some()) {
        eprintln!(
            "error: run {} ({}): {}",
            r.index,
            r.params
                .iter()
                .map(|(p, v)| format!("{p} = {v}"))
                .collect::<Vec<_>>()
                .join(", "),
            r.error.as_deref().unwrap_or_default()
        );
    }
    Ok(if failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

/// The options of `ecp fit`.
struct FitRequest {
    reference: PathBuf,
    params: Vec<String>,
    method: Method,
    gradient: GradientMethod,
    solver: Option<String>,
    formulation: Option<String>,
    max_iters: Option<u64>,
    steps: Option<usize>,
    weights: Option<String>,
    start: Option<String>,
    tolerance: Option<f64>,
}

/// `ecp fit`: exit status 0 when the optimiser finished, 1 when a simulation failed during the
/// optimisation (the JSON then has the best point so far and "error"), 2 for bad input.
fn fit(file: &SceneFile, request: &FitRequest) -> Result<ExitCode, RunError> {
    use ecp::error::{InputError, InputErrorKind};
    use ecp::fit::{
        FitOptions, TrajectoryProblem, default_weights, parse_params, parse_weights, read_reference,
    };

    let mut scene = file.scene.clone();
    if let Some(text) = &request.start {
        ecp::fit::apply_start(&mut scene, text)?;
    }
    let params = parse_params(&request.params, &scene)?;
    let weights = match &request.weights {
        Some(w) => parse_weights(w)?,
        None => default_weights(),
    };
    if let Some(t) = request.tolerance
        && !(t.is_finite() && t >= 0.0)
    {
        return Err(InputError::option(
            "--tolerance",
            InputErrorKind::InvalidValue,
            format!("the tolerance must be a finite number ≥ 0, not {t}"),
        )
        .into());
    }
    if request.steps == Some(0) {
        return Err(InputError::option(
            "--steps",
            InputErrorKind::InvalidValue,
            "fit at least one step (--steps 1 or more)",
        )
        .into());
    }
    let mut reference = read_reference(&request.reference, file.scene.bodies.len())?;
    if let Some(n) = request.steps {
        reference = reference.truncated(n);
    }
    let mut config = file.solver.clone();
    if let Some(name) = &request.solver {
        config.name = name.trim().to_string();
    }
    let formulation = request.formulation.as_ref().unwrap_or(&file.formulation);
    let problem = TrajectoryProblem::from_scene(scene, formulation, config, reference, params);
    let options = FitOptions {
        method: request.method,
        max_iters: request.max_iters.unwrap_or(match request.method {
            Method::Lbfgs => 100,
            Method::NelderMead => 400,
        }),
        tolerance: request.tolerance.unwrap_or(FitOptions::default().tolerance),
    };
    let report = problem
        .and_then(|p| p.with_weights(weights).with_gradient(request.gradient))
        .and_then(|p| ecp::fit::fit(p, &options));
    match report {
        Ok(report) => {
            let json = serde_json::to_string(&report).map_err(|e| {
                RunError::Output(ecp::output::OutputError {
                    path: PathBuf::from("<stdout>"),
                    source: e.into(),
                })
            })?;
            sayln!("{json}");
            if let Some(e) = &report.error {
                eprintln!("error: the fit stopped early: {e}");
                return Ok(ExitCode::from(1));
            }
            Ok(ExitCode::SUCCESS)
        }
        Err(FitError::Input(e)) => Err(e.into()),
        Err(e) => {
            eprintln!("error: {e}");
            Ok(ExitCode::from(1))
        }
    }
}
