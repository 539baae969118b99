//! The full run of the random-scene stress suite (docs/stress.md):
//!
//! ```text
//! cargo run --release --example stress -- [--solvers newton,path,conic] [--seed S] [--count N]
//!     [--out out/stress] [--only TEXT] [--jobs J] [--steps N] [--time-limit SECONDS]
//!     [--fallbacks]   (the run driver's fallbacks on, as `ecp run` by default; off: each
//!                      backend by itself)
//!     [--scenes DIR] [--write-failing DIR]
//! ```
//!
//! Generates `--count` scenes from `--seed` (default: the documented 156 scenes), writes them to
//! `OUT/scenes/`, runs each with every backend (hull formulation, keep going after failed steps,
//! 60 s per run), and writes `OUT/runs.csv`, `OUT/runs.json` and `OUT/summary.md`; prints the
//! tables. `--only TEXT` keeps the scenes whose name contains TEXT (a category name, or a scene
//! name). `--scenes DIR` runs the scene files of DIR instead of generated ones (the regression
//! scenes: `--scenes tests/stress_regressions`). `--write-failing DIR` copies every scene that did
//! not pass with some backend into DIR with its mesh files, and appends to `DIR/manifest.csv`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use ecp::stress::report::{backend_table, category_table, criteria, failure_list, write_outputs};
use ecp::stress::{DEFAULT_COUNT, DEFAULT_SEED, RunResult, SuiteOptions, generate};

struct Args {
    solvers: Vec<String>,
    seed: u64,
    count: usize,
    out: PathBuf,
    only: Option<String>,
    jobs: usize,
    steps: Option<usize>,
    time_limit: f64,
    scenes: Option<PathBuf>,
    write_failing: Option<PathBuf>,
    fallbacks: bool,
}

fn parse() -> Result<Args, String> {
    let mut a = Args {
        solvers: ecp::solvers::registry::BUILTIN.map(String::from).to_vec(),
        seed: DEFAULT_SEED,
        count: DEFAULT_COUNT,
        out: PathBuf::from("out/stress"),
        only: None,
        jobs: 1,
        steps: None,
        time_limit: 60.0,
        scenes: None,
        write_failing: None,
        fallbacks: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || {
            it.next().ok_or_else(|| {
                format!("{flag} needs a value (see the header of examples/stress.rs)")
            })
        };
        let bad = |v: &str| format!("{flag}: cannot read \"{v}\"");
        match flag.as_str() {
            "--solvers" => {
                a.solvers = value()?
                    .split(',')
                    .map(|s| {
                        let registry = ecp::solvers::Registry::builtin();
                        registry
                            .get(s)
                            .map(|b| b.name().to_string())
                            .map_err(|e| e.to_string())
                    })
                    .collect::<Result<_, _>>()?;
            }
            "--seed" => {
                let v = value()?;
                a.seed = v.parse().map_err(|_| bad(&v))?;
            }
            "--count" => {
                let v = value()?;
                a.count = v.parse().map_err(|_| bad(&v))?;
            }
            "--out" => a.out = PathBuf::from(value()?),
            "--only" => a.only = Some(value()?),
            "--jobs" => {
                let v = value()?;
                a.jobs = v.parse().map_err(|_| bad(&v))?;
            }
            "--steps" => {
                let v = value()?;
                a.steps = Some(v.parse().map_err(|_| bad(&v))?);
            }
            "--fallbacks" => a.fallbacks = true,
            "--time-limit" => {
                let v = value()?;
                a.time_limit = v
                    .parse()
                    .ok()
                    .filter(|t: &f64| *t > 0.0 && t.is_finite())
                    .ok_or_else(|| bad(&v))?;
            }
            "--scenes" => a.scenes = Some(PathBuf::from(value()?)),
            "--write-failing" => a.write_failing = Some(PathBuf::from(value()?)),
            other => {
                return Err(format!(
                    "unknown option {other}; the options are listed in the header of examples/stress.rs"
                ));
            }
        }
    }
    Ok(a)
}

fn main() -> ExitCode {
    let args = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let options = SuiteOptions {
        out_dir: args.out.clone(),
        solvers: args.solvers.clone(),
        steps: args.steps,
        time_limit: Some(Duration::from_secs_f64(args.time_limit)),
        jobs: args.jobs,
        fallbacks: args.fallbacks,
    };
    let keep = |name: &str| args.only.as_deref().is_none_or(|o| name.contains(o));
    let progress = |r: &RunResult| {
        eprintln!(
            "{:<24} {:<6} {:>5}/{:<5} failed {:<5} pen {:.1e} rise {:.1e} {:.2} s{}",
            r.scene,
            r.solver,
            r.steps,
            r.planned_steps,
            r.failed_steps,
            r.max_penetration,
            r.energy_rise_outside_openings,
            r.wall_s,
            if r.timed_out { " TIMEOUT" } else { "" }
        );
    };
    let (header, results) = match &args.scenes {
        Some(dir) => {
            let mut paths: Vec<PathBuf> = match std::fs::read_dir(dir) {
                Ok(d) => d
                    .filter_map(|e| e.ok().map(|e| e.path()))
                    .filter(|p| p.extension().is_some_and(|e| e == "toml"))
                    .filter(|p| p.file_stem().and_then(|s| s.to_str()).is_some_and(keep))
                    .collect(),
                Err(e) => {
                    eprintln!("error: cannot read {}: {e}", dir.display());
                    return ExitCode::from(2);
                }
            };
            paths.sort();
            let header = format!("# Stress runs of the scene files in {}", dir.display());
            (header, ecp::stress::run_paths(&paths, &options, progress))
        }
        None => {
            let scenes: Vec<_> = generate(args.seed, args.count)
                .into_iter()
                .filter(|s| keep(&s.name))
                .collect();
            let header = format!(
                "# Stress suite: seed {}, {} scenes, backends {}",
                args.seed,
                scenes.len(),
                args.solvers
                    .iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            let results = ecp::stress::run_suite(&scenes, &options, progress);
            (header, results)
        }
    };
    let results = match results {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    if let Err(e) = write_outputs(&args.out, &results, &header) {
        eprintln!(
            "error: cannot write the outputs into {}: {e}",
            args.out.display()
        );
        return ExitCode::FAILURE;
    }
    if let Some(dir) = &args.write_failing
        && let Err(e) = write_failing(&args, &results, dir)
    {
        eprintln!(
            "error: cannot write the failing scenes into {}: {e}",
            dir.display()
        );
        return ExitCode::FAILURE;
    }
    println!("{header}\n");
    println!("{}", backend_table(&results));
    println!("{}", category_table(&results));
    println!("{}", criteria(&results));
    println!("{}", failure_list(&results));
    println!(
        "runs.csv, runs.json and summary.md are in {}",
        args.out.display()
    );
    ExitCode::SUCCESS
}

/// Copies each scene that did not pass with some backend (and its mesh files) into `dir`, and
/// appends one line per failing run to `dir/manifest.csv`: scene, backend, first failing step,
/// failure.
fn write_failing(args: &Args, results: &[RunResult], dir: &std::path::Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let source = match &args.scenes {
        Some(d) => d.clone(),
        None => args.out.join("scenes"),
    };
    let manifest = dir.join("manifest.csv");
    let mut lines = if manifest.exists() {
        std::fs::read_to_string(&manifest)?
    } else {
        "scene,backend,first_failing_step,failure\n".to_string()
    };
    for r in results.iter().filter(|r| !r.passed()) {
        let toml = source.join(format!("{}.toml", r.scene));
        std::fs::copy(&toml, dir.join(format!("{}.toml", r.scene)))?;
        for ext in ["obj", "stl"] {
            let mesh = source.join(format!("{}.{ext}", r.scene));
            if mesh.exists() {
                std::fs::copy(&mesh, dir.join(format!("{}.{ext}", r.scene)))?;
            }
        }
        let failure = if r.timed_out {
            format!("timeout after {} steps", r.steps)
        } else if r.failed_steps > 0 {
            format!(
                "{} failed steps: {}",
                r.failed_steps,
                r.first_failure.as_deref().unwrap_or("?")
            )
        } else if r.penetrates() {
            format!(
                "penetration {:.2e} m at step {}",
                r.max_penetration, r.penetration_step
            )
        } else if let Some(e) = &r.error {
            e.clone()
        } else {
            format!(
                "energy rise {:.2e} of the scale",
                r.energy_rise_outside_openings
            )
        };
        let line = format!(
            "{},{},{},\"{}\"\n",
            r.scene,
            r.solver,
            r.first_failed_step
                .or((r.penetration_step > 0).then_some(r.penetration_step))
                .unwrap_or(0),
            failure.replace('"', "'")
        );
        if !lines.contains(&line) {
            lines.push_str(&line);
        }
    }
    std::fs::write(manifest, lines)
}
