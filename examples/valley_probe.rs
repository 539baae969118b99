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

fn lu_solve(n: usize, a: &mut [f64], b: &mut [f64]) -> bool {
    // Row-major n×n, partial pivoting.
    for k in 0..n {
        let mut piv = k;
        for i in k + 1..n {
            if a[i * n + k].abs() > a[piv * n + k].abs() { piv = i; }
        }
        if a[piv * n + k].abs() < 1e-300 { return false; }
        if piv != k {
            for j in 0..n { a.swap(k * n + j, piv * n + j); }
            b.swap(k, piv);
        }
        let d = a[k * n + k];
        for i in k + 1..n {
            let m = a[i * n + k] / d;
            if m != 0.0 {
                for j in k..n { a[i * n + j] -= m * a[k * n + j]; }
                b[i] -= m * b[k];
            }
        }
    }
    for k in (0..n).rev() {
        let mut s = b[k];
        for j in k + 1..n { s -= a[k * n + j] * b[j]; }
        b[k] = s / a[k * n + k];
    }
    true
}

/// Φ(z, τ) and its (n × (n+1)) Jacobian (row-major, last column ∂/∂τ), FB on [l, ∞) pairs.
fn fb_system(p: &dyn Mcp, c: &[f64], x: &[f64], phi: &mut [f64], jac: Option<&mut [f64]>) {
    let n = p.dim();
    let tau = x[n];
    let z = &x[..n];
    let mut f = vec![0.0; n];
    p.evaluate(z, &mut f);
    let (l, u) = (p.lower(), p.upper());
    let mut da = vec![0.0; n];
    let mut db = vec![0.0; n];
    for i in 0..n {
        let g = f[i] - (1.0 - tau) * c[i];
        if l[i].is_finite() {
            assert!(!u[i].is_finite());
            let a = z[i] - l[i];
            let r = (a * a + g * g).sqrt();
            phi[i] = a + g - r;
            if r > 0.0 { da[i] = 1.0 - a / r; db[i] = 1.0 - g / r; } else { da[i] = 1.0 - 0.5f64.sqrt(); db[i] = da[i]; }
        } else {
            assert!(!u[i].is_finite());
            phi[i] = g;
            da[i] = 0.0;
            db[i] = 1.0;
        }
    }
    if let Some(jac) = jac {
        let pat = p.jacobian_pattern().clone();
        let mut vals = vec![0.0; pat.nnz()];
        p.jacobian(z, &mut vals);
        let mut dense = vec![0.0; n * n];
        pat.to_dense(&vals, &mut dense);
        let m = n + 1;
        jac.fill(0.0);
        for i in 0..n {
            for j in 0..n {
                jac[i * m + j] = db[i] * dense[j * n + i];
            }
            jac[i * m + i] += da[i];
            jac[i * m + n] = db[i] * c[i];
        }
    }
}

/// Pseudo-arclength continuation of Φ(z, τ) = 0 from (z0, 0) to τ = 1; returns z at τ ≈ 1.
fn arclength(p: &dyn Mcp, z0: &[f64], verbose: bool) -> Option<(Vec<f64>, usize)> {
    let n = p.dim();
    let m = n + 1;
    let mut f = vec![0.0; n];
    p.evaluate(z0, &mut f);
    let (l, u) = (p.lower(), p.upper());
    let z: Vec<f64> = (0..n).map(|i| z0[i].clamp(l[i], u[i])).collect();
    let c: Vec<f64> = (0..n)
        .map(|i| if (z[i] <= l[i] && f[i] >= 0.0) || (z[i] >= u[i] && f[i] <= 0.0) { 0.0 } else { f[i] })
        .collect();
    // Correct the start so that Φ(z, 0) = 0 exactly (c from the clamped z).
    p.evaluate(&z, &mut f);
    let c: Vec<f64> = (0..n).map(|i| if z[i] <= l[i] && f[i] >= 0.0 { 0.0 } else if c[i] == 0.0 && z[i] <= l[i] { f[i] } else { f[i] }).collect();
    let mut x: Vec<f64> = z.clone();
    x.push(0.0);
    let mut phi = vec![0.0; n];
    let mut jac = vec![0.0; n * m];
    fb_system(p, &c, &x, &mut phi, Some(&mut jac));
    let norm = |v: &[f64]| v.iter().map(|a| a * a).sum::<f64>().sqrt();
    if verbose { println!("  start |Φ| {:.2e}", norm(&phi)); }
    let tangent = |jac: &[f64], prev: &[f64]| -> Option<Vec<f64>> {
        let mut a = vec![0.0; m * m];
        a[..n * m].copy_from_slice(jac);
        a[n * m..].copy_from_slice(prev);
        let mut b = vec![0.0; m];
        b[n] = 1.0;
        if !lu_solve(m, &mut a, &mut b) { return None; }
        let s = norm(&b);
        Some(b.iter().map(|v| v / s).collect())
    };
    let mut e = vec![0.0; m];
    e[n] = 1.0;
    let mut t = tangent(&jac, &e)?;
    let mut ds = 1e-2;
    let mut steps = 0;
    let mut evals = 0;
    while steps < 20000 {
        steps += 1;
        let xp: Vec<f64> = x.iter().zip(&t).map(|(a, b)| a + ds * b).collect();
        let mut xc = xp.clone();
        let mut ok = false;
        let mut its = 0;
        for _ in 0..10 {
            its += 1;
            evals += 1;
            fb_system(p, &c, &xc, &mut phi, Some(&mut jac));
            let arc: f64 = t.iter().zip(xc.iter().zip(&xp)).map(|(ti, (a, b))| ti * (a - b)).sum();
            let r = norm(&phi).max(arc.abs());
            if r < 1e-11 { ok = true; break; }
            let mut a = vec![0.0; m * m];
            a[..n * m].copy_from_slice(&jac);
            a[n * m..].copy_from_slice(&t);
            let mut b: Vec<f64> = phi.iter().map(|v| -v).collect();
            b.push(-arc);
            if !lu_solve(m, &mut a, &mut b) { break; }
            if norm(&b) > 10.0 * ds.max(1e-3) { break; }
            for (xi, di) in xc.iter_mut().zip(&b) { *xi += di; }
        }
        if !ok {
            ds *= 0.5;
            if ds < 1e-14 { if verbose { println!("  step too small at tau {:.4}", x[n]); } return None; }
            continue;
        }
        let tn = match tangent(&jac, &t) { Some(v) => v, None => return None };
        let dot: f64 = tn.iter().zip(&t).map(|(a, b)| a * b).sum();
        let tn: Vec<f64> = if dot < 0.0 { tn.iter().map(|v| -v).collect() } else { tn };
        let turned = (tn[n] > 0.0) != (t[n] > 0.0);
        if verbose && (turned || steps % 200 == 0) {
            println!("  step {steps} tau {:.5} ds {ds:.2e} dtau/ds {:.2e}{}", xc[n], tn[n], if turned { " (fold)" } else { "" });
        }
        x = xc;
        t = tn;
        if its <= 3 { ds = (ds * 1.5).min(0.5); }
        if x[n] >= 1.0 { if verbose { println!("  tau 1 reached after {steps} steps, {evals} corrector iterations"); } return Some((x[..n].to_vec(), evals)); }
        if x[n] < -50.0 || norm(&x) > 1e4 { if verbose { println!("  tau {:.3} |x| {:.2e}: gave up", x[n], norm(&x)); } return None; }
    }
    None
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
    if std::env::var("ARC").is_ok() {
        match arclength(&p, &z0, true) {
            Some((z, evals)) => {
                let idx: Vec<usize> = names.iter().enumerate().filter(|(_, n)| n.contains(".pn") || n.contains(".pf.pt")).map(|(i, _)| i).collect();
                let v: Vec<String> = idx.iter().map(|&i| format!("{}={:.4e}", &names[i][5..], z[i])).collect();
                println!("arclength end ({evals} corrector iterations): {}", v.join(" "));
                run("newton from the arclength end", &mut NewtonSolver::new(ns.clone()), &p, &z);
            }
            None => println!("arclength failed"),
        }
        return;
    }
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
