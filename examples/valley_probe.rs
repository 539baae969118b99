//! Throw-away probe for the V-trough jam (s20261212_022_v_trough step 62).
use ecp::formulations::{FormulationRegistry, SimulationBuilder};
use ecp::model::{Mcp, McpSolver, SolveError};
use ecp::scene::load_scene;
use ecp::solvers::newton::{NewtonSettings, NewtonSolver};
use ecp::solvers::path::{PathSettings, PathSolver};
use ecp::solvers::registry::{BackendOptions, Registry};

fn run(name: &str, s: &mut dyn McpSolver, p: &dyn Mcp, z: &[f64]) -> (bool, Vec<f64>) {
    let r = s.solve(p, z);
    let (sol, ok) = match &r {
        Ok(s) => (s, true),
        Err(SolveError::NotConverged { best }) => (&**best, false),
        Err(e) => {
            println!("{name}: {e}");
            return (false, z.to_vec());
        }
    };
    println!(
        "{name}: ok {ok} it {} res {:.2e}",
        sol.summary.iterations, sol.summary.residual
    );
    (ok, sol.z.clone())
}

/// MCP(F − s·c).
struct Shifted<'a> {
    inner: &'a dyn Mcp,
    c: Vec<f64>,
    s: f64,
}

impl Mcp for Shifted<'_> {
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn lower(&self) -> &[f64] {
        self.inner.lower()
    }
    fn upper(&self) -> &[f64] {
        self.inner.upper()
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        self.inner.evaluate(z, f);
        for (fi, ci) in f.iter_mut().zip(&self.c) {
            *fi -= self.s * ci;
        }
    }
    fn jacobian_pattern(&self) -> &std::sync::Arc<ecp::model::CscPattern> {
        self.inner.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        self.inner.jacobian(z, values)
    }
    fn component_name(&self, i: usize) -> String {
        self.inner.component_name(i)
    }
    fn scales(&self) -> Option<&ecp::model::McpScales> {
        self.inner.scales()
    }
    fn structure(&self) -> Option<&dyn ecp::model::StepStructure> {
        self.inner.structure()
    }
    fn elimination_groups(&self) -> &[Vec<usize>] {
        self.inner.elimination_groups()
    }
}

/// The Newton homotopy from z0: MCP(F − (1 − τ) c), τ: 0 → 1, z0 solving τ = 0.
fn homotopy(p: &dyn Mcp, z0: &[f64], ns: &NewtonSettings, budget: usize, verbose: bool) -> (bool, usize, Vec<f64>) {
    let n = p.dim();
    let mut f = vec![0.0; n];
    p.evaluate(z0, &mut f);
    let (l, u) = (p.lower(), p.upper());
    let c: Vec<f64> = (0..n)
        .map(|i| {
            let at_l = z0[i] <= l[i];
            let at_u = z0[i] >= u[i];
            if (at_l && f[i] >= 0.0) || (at_u && f[i] <= 0.0) { 0.0 } else { f[i] }
        })
        .collect();
    let mut z = z0.to_vec();
    let mut z_proj: Vec<f64> = z.iter().enumerate().map(|(i, v)| v.clamp(l[i], u[i])).collect();
    std::mem::swap(&mut z, &mut z_proj);
    let (mut tau, mut dtau, mut total) = (0.0f64, 0.25f64, 0usize);
    let mut solver = NewtonSolver::new(ns.clone());
    solver.set_iteration_budget(Some(budget));
    let mut stages = 0;
    while tau < 1.0 && stages < 200 {
        stages += 1;
        let next = (tau + dtau).min(1.0);
        let q = Shifted { inner: p, c: c.clone(), s: 1.0 - next };
        let r = solver.solve(&q, &z);
        match r {
            Ok(sol) => {
                total += sol.summary.iterations;
                if verbose { println!("  tau {next:.4} ok in {}", sol.summary.iterations); }
                z = sol.z.clone();
                tau = next;
                if sol.summary.iterations <= 4 { dtau *= 2.0; }
            }
            Err(SolveError::NotConverged { best }) => {
                total += best.summary.iterations;
                if verbose { println!("  tau {next:.4} failed ({} its, res {:.2e})", best.summary.iterations, best.summary.residual); }
                dtau *= 0.5;
                if dtau < 1e-6 { println!("  stuck at tau {tau:.4}"); return (false, total, z); }
            }
            Err(e) => { println!("{e}"); return (false, total, z); }
        }
    }
    (tau >= 1.0, total, z)
}

fn main() {
    let mut a = std::env::args().skip(1);
    let path = a.next().unwrap();
    let step: usize = a.next().unwrap().parse().unwrap();
    let with = a.next().unwrap_or("newton".into());
    let file = load_scene(std::path::Path::new(&path)).unwrap();
    let stepper = FormulationRegistry::builtin().create("hull").unwrap();
    let mut sim = SimulationBuilder::new(file.scene.clone(), stepper).build().unwrap();
    let options = BackendOptions {
        tolerance: file.solver.tolerance,
        max_iterations: file.solver.max_iterations,
        non_isolated_solutions: false,
    };
    let mut driver = Registry::builtin().build(&with, &options).unwrap();
    for _ in 1..step {
        sim.step(driver.as_mut()).unwrap();
    }
    sim.prepare_step().unwrap();
    let z0 = sim.z().to_vec();
    let tol = options.tolerance.unwrap_or(1e-10);
    let ns = NewtonSettings { tolerance: tol, ..NewtonSettings::default() };
    let p = sim.step_problem();
    let mcp = sim.mcp();
    let names: Vec<String> = (0..z0.len()).map(|i| mcp.component_name(i).to_string()).collect();
    if std::env::var("HOMOTOPY").is_ok() {
        let (_, zstall) = run("newton", &mut NewtonSolver::new(ns.clone()), &p, &z0);
        let cold: Vec<f64> = z0.iter().zip(&names).map(|(v, n)| if n.contains(".pn") || n.contains(".pf") || n.contains("sigma") { 0.0 } else { *v }).collect();
        let x4: Vec<f64> = z0.iter().zip(&names).map(|(v, n)| if n.contains(".pn") || n.contains(".pf") { 3.0 * v } else { *v }).collect();
        for (label, start) in [("stall", &zstall), ("cold", &cold), ("x3", &x4), ("z0", &z0)] {
        for budget in [20usize] {
            println!("start {label}");
            let (ok, it, z) = homotopy(&p, start, &ns, budget, false);
            let mut fz = vec![0.0; z.len()];
            p.evaluate(&z, &mut fz);
            let idx: Vec<usize> = names.iter().enumerate().filter(|(_, n)| n.contains(".pn") || n.contains(".pf.pt")).map(|(i, _)| i).collect();
            let v: Vec<String> = idx.iter().map(|&i| format!("{}={:.4e}", &names[i][5..], z[i])).collect();
            println!("homotopy budget {budget}: ok {ok} iterations {it} residual {:.2e} {}", ecp::model::natural_residual(&z, &fz, p.lower(), p.upper()), v.join(" "));
        }
        }
        return;
    }
    if std::env::var("CRAWL").is_ok() {
        let idx: Vec<usize> = names.iter().enumerate().filter(|(_, n)| n.contains(".pn") || n.contains(".pf") || n.contains("sigma") || n.contains(".lg")).map(|(i, _)| i).collect();
        let mut z = z0.clone();
        let mut s = NewtonSolver::new(ns.clone());
        s.set_iteration_budget(Some(200));
        for c in 0..40 {
            let (ok, zz) = run(&format!("chunk {c}"), &mut s, &p, &z);
            z = zz;
            let v: Vec<String> = idx.iter().map(|&i| format!("{}={:.4e}", &names[i][5..], z[i])).collect();
            println!("   {}", v.join(" "));
            if ok { break; }
        }
        return;
    }
    let (okp, zp) = run("path", &mut PathSolver::new(PathSettings { tolerance: tol, ..PathSettings::default() }), &p, &z0);
    if okp {
        run("newton from path's solution", &mut NewtonSolver::new(ns.clone()), &p, &zp);
        for eps in [1e-6, 1e-4, 1e-2] {
            let zz: Vec<f64> = zp.iter().zip(&z0).map(|(a, b)| a + eps * (b - a) / (b - a).abs().max(1e-300) * (b - a).abs().min(1.0)).collect();
            run(&format!("newton from path's solution moved {eps} to z0"), &mut NewtonSolver::new(ns.clone()), &p, &zz);
        }
        for th in [0.5, 0.8, 0.9, 0.95] {
            let zz: Vec<f64> = zp.iter().zip(&z0).map(|(a, b)| a + th * (b - a)).collect();
            run(&format!("newton from {th} of the way path->z0"), &mut NewtonSolver::new(ns.clone()), &p, &zz);
        }
    }
    for (label, keep) in [("forces zero", 0.0), ("forces and sigma zero", -1.0)] {
        let zz: Vec<f64> = z0
            .iter()
            .zip(&names)
            .map(|(v, n)| if n.contains(".pn") || n.contains(".pf") || (keep < 0.0 && n.contains("sigma")) { 0.0 } else { *v })
            .collect();
        run(&format!("newton from z0 with {label}"), &mut NewtonSolver::new(ns.clone()), &p, &zz);
    }
    for k in [2.0, 4.0, 6.0, 8.0] {
        let zz: Vec<f64> = z0
            .iter()
            .zip(&names)
            .map(|(v, n)| if n.contains(".pn") || n.contains(".pf") { v * k } else { *v })
            .collect();
        run(&format!("newton from z0 with forces x{k}"), &mut NewtonSolver::new(ns.clone()), &p, &zz);
    }
    let mut ps = PathSettings { tolerance: tol, ..PathSettings::default() };
    ps.max_iterations = 100000;
    run("path long", &mut PathSolver::new(ps), &p, &z0);
}
