//! Diagnosis of a μ > 1 wedge step (`docs/stress.md`, "The μ > 1 wedges ... (branch wip-wedge)"):
//!
//! ```text
//! cargo run --release --example wedge_probe -- SCENE.toml --step K [--with conic|newton|path]
//! ```
//!
//! steps 1 … K−1 with `--with` (default conic; hull formulation, the scene's tolerance, no
//! fallbacks), prepares step K, solves it with the conic backend from the warm start, checks the
//! conic answer's natural residual on the step problem (scaled) and on the plain MCP, prints its
//! unknowns with `F`, then starts Newton and PATH from the conic answer and from the warm start,
//! and reports the singular values of the natural map's B-Jacobian at the conic answer (row i
//! is `J_i` where `z_i` is strictly inside its bounds, `e_i` where it is at a bound).
use std::process::ExitCode;

use ecp::formulations::{FormulationRegistry, SimulationBuilder};
use ecp::model::{Mcp, SolveError, diagnose};
use ecp::scene::load_scene;
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
    let (mut path, mut step, mut with) = (None, None, "conic".to_string());
    let (mut previous, mut sets) = (false, Vec::<String>::new());
    while let Some(a) = args.next() {
        match a.as_str() {
            "--previous" => previous = true,
            "--set" => sets.push(args.next().unwrap_or_default()),
            "--step" => step = args.next().and_then(|v| v.parse::<usize>().ok()),
            "--with" => with = args.next().unwrap_or_default(),
            _ => path = Some(a),
        }
    }
    let (Some(path), Some(step)) = (path, step) else {
        return Err("usage: wedge_probe SCENE.toml --step K [--with B]".into());
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
    let build = |name: &str| {
        Registry::builtin()
            .build(name, &options)
            .map_err(|e| e.to_string())
    };
    let mut driver = build(&with)?;
    for k in 1..step {
        let rec = sim.step(driver.as_mut()).map_err(|e| e.to_string())?;
        if !rec.converged {
            println!("step {k}: not converged with {with} (state kept)");
        }
    }
    if previous {
        // The plain warm start (the last step's answer), the driver's first retry start.
        sim.set_warm_start(ecp::formulations::WarmStart::Previous);
    }
    sim.prepare_step().map_err(|e| e.to_string())?;
    let mut z0 = sim.z().to_vec();
    // `--set PREFIX=V`: the warm start with the unknowns named PREFIX… at V (clamped).
    for kv in &sets {
        let (prefix, v) = kv.split_once('=').unwrap_or((kv.as_str(), "0"));
        let v: f64 = v.parse().map_err(|_| format!("bad --set {kv}"))?;
        let mcp = sim.mcp();
        for (i, zi) in z0.iter_mut().enumerate() {
            if mcp.component_name(i).starts_with(prefix) {
                *zi = v.clamp(mcp.lower()[i], mcp.upper()[i]);
            }
        }
    }
    let problem = sim.step_problem();
    let mcp = sim.mcp();
    let n = z0.len();
    println!(
        "step {step}: {n} unknowns; warm start residual {:.2e}",
        diagnose(mcp, &z0).0
    );
    let solve = |name: &str, start: &[f64], label: &str| -> Vec<f64> {
        let mut s = match build(name) {
            Ok(s) => s,
            Err(e) => {
                println!("{e}");
                return start.to_vec();
            }
        };
        let r = s.solve(&problem, start);
        let (sol, ok): (&ecp::model::Solution, bool) = match &r {
            Ok(s) => (s, true),
            Err(SolveError::NotConverged { best }) => (&**best, false),
            Err(e) => {
                println!("{name} from {label}: {e}");
                return start.to_vec();
            }
        };
        let (res, worst) = diagnose(mcp, &sol.z);
        println!(
            "{name} from {label}: converged {ok}, {:?}, {} iterations, reported residual {:.2e}; plain MCP residual {res:.2e} worst {:?}",
            sol.summary.termination,
            sol.summary.iterations,
            sol.summary.residual,
            worst.map(|w| (w.name, w.value))
        );
        sol.z.clone()
    };
    let zc = solve("conic", &z0, "warm start");
    let mut f = vec![0.0; n];
    mcp.evaluate(&zc, &mut f);
    let (lo, up) = (mcp.lower(), mcp.upper());
    for i in 0..n {
        println!(
            "{i:3} {:24} [{:9.2e},{:9.2e}] z0 {:12.5e} conic {:12.5e} F {:10.3e}",
            mcp.component_name(i),
            lo[i],
            up[i],
            z0[i],
            zc[i],
            f[i]
        );
    }
    for b in ["newton", "path"] {
        solve(b, &zc, "conic answer");
        solve(b, &z0, "warm start");
    }
    // The natural map's B-Jacobian at the conic answer: J_i for z_i strictly inside its bounds
    // (up to 1e-12 of the bound's scale), the unit row where z_i is at a bound.
    let pat = mcp.jacobian_pattern().clone();
    let mut vals = vec![0.0; pat.nnz()];
    mcp.jacobian(&zc, &mut vals);
    let mut jm = nalgebra::DMatrix::<f64>::zeros(n, n);
    for c in 0..n {
        for k in pat.col_ptr()[c]..pat.col_ptr()[c + 1] {
            jm[(pat.row_idx()[k], c)] = vals[k];
        }
    }
    let at_bound = |i: usize| {
        let t = 1e-12 * (1.0 + zc[i].abs());
        (zc[i] - lo[i]).abs() <= t || (up[i] - zc[i]).abs() <= t
    };
    let mut bj = jm.clone();
    let mut active = Vec::new();
    for i in 0..n {
        if at_bound(i) {
            active.push(i);
            for c in 0..n {
                bj[(i, c)] = if c == i { 1.0 } else { 0.0 };
            }
        }
    }
    // The B-Jacobian's near-null right singular vectors: their largest entries.
    let svd = bj.clone().svd(false, true);
    if let Some(vt) = &svd.v_t {
        for (k, &sk) in svd.singular_values.iter().enumerate() {
            if sk < 1e-6 {
                let mut e: Vec<(usize, f64)> = (0..n).map(|c| (c, vt[(k, c)])).collect();
                e.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
                let top: Vec<String> = e
                    .iter()
                    .take(6)
                    .filter(|x| x.1.abs() > 1e-3)
                    .map(|&(c, x)| format!("{} {x:.3}", mcp.component_name(c)))
                    .collect();
                println!("  null direction (singular value {sk:.2e}): {top:?}");
            }
        }
    }
    let sv = |m: &nalgebra::DMatrix<f64>| {
        let mut s: Vec<f64> = m
            .clone()
            .svd(false, false)
            .singular_values
            .iter()
            .copied()
            .collect();
        s.sort_by(|a, b| a.total_cmp(b));
        s
    };
    let s = sv(&bj);
    println!(
        "B-Jacobian at the conic answer ({} at a bound: {:?}): smallest singular values {:?}, largest {:.3e}",
        active.len(),
        active
            .iter()
            .map(|&i| mcp.component_name(i))
            .collect::<Vec<_>>(),
        &s[..6.min(s.len())],
        s[s.len() - 1]
    );
    // Degenerate pairs: at a bound with |F| tiny (both branches of the kink in play).
    for &i in &active {
        if f[i].abs() < 1e-8 {
            println!(
                "  degenerate: {} z {:.3e} F {:.3e}",
                mcp.component_name(i),
                zc[i],
                f[i]
            );
        }
    }
    let s2 = sv(&jm);
    println!(
        "full Jacobian J at the conic answer: smallest singular values {:?}",
        &s2[..6.min(s2.len())]
    );
    Ok(())
}
