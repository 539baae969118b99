//! Replays the failing steps of a backend against variants of it (docs/stress.md, "Probing
//! failed steps"):
//!
//! ```text
//! cargo run --release --example step_probe -- DIR [--only TEXT] [--solver newton|path|conic]
//!     [--steps N] [--variants a,b,..] [--verbose]
//! ```
//!
//! Runs every scene file of DIR (e.g. `out/stress/scenes`, written by the stress example) with
//! the hull formulation. Every solve of the backend is also solved by each variant from the same
//! start, and a failed one by PATH (the reference); when the backend fails a step (its retry
//! included), PATH solves it as a fallback, so the trajectory stays on the reference and every
//! failure is a fresh one. For each failed solve it prints the step, the termination, the residual, the worst
//! component, the kind of step (contacts opening or closing, a contact changing its closest
//! feature) and which variants solve it; at the end, per variant, the solves it wins and loses
//! against the backend.

use std::path::PathBuf;
use std::process::ExitCode;

use ecp::scene::load_scene;
use ecp_formulations::{Fallbacks, Formulation, StepMethod, build_stepper};
use ecp_model::{Mcp, McpSolver, Solution, SolveError};
use ecp_solvers::conic::{ConicSettings, ConicSolver};
use ecp_solvers::{NewtonSettings, NewtonSolver, PathSettings, PathSolver};

/// `F` with rows multiplied by `w` (same solutions; different merit and natural residual).
struct RowScaled<'a> {
    inner: &'a dyn Mcp,
    w: Vec<f64>,
}

impl Mcp for RowScaled<'_> {
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
        for (v, w) in f.iter_mut().zip(&self.w) {
            *v *= w;
        }
    }
    fn jacobian_pattern(&self) -> &std::sync::Arc<ecp_model::CscPattern> {
        self.inner.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        self.inner.jacobian(z, values);
        let ri = self.inner.jacobian_pattern().row_idx().to_vec();
        for (v, r) in values.iter_mut().zip(ri) {
            *v *= self.w[r];
        }
    }
    fn component_name(&self, i: usize) -> String {
        self.inner.component_name(i)
    }
    fn structure(&self) -> Option<&dyn ecp_model::StepStructure> {
        self.inner.structure()
    }
}

/// Solves a row-scaled copy of the problem (kinematic rows divided by h) and judges the answer
/// on the original.
struct KinScaled(Box<dyn McpSolver>);

impl McpSolver for KinScaled {
    fn name(&self) -> &str {
        "kin-scaled"
    }
    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let h = mcp.structure().map_or(1.0, |s| s.step_length());
        let w = (0..mcp.dim())
            .map(|i| {
                if mcp.component_name(i).contains(".q.") {
                    1.0 / h
                } else {
                    1.0
                }
            })
            .collect();
        let scaled = RowScaled { inner: mcp, w };
        let r = self.0.solve(&scaled, z0);
        let z = match &r {
            Ok(s) => s.z.clone(),
            Err(SolveError::NotConverged { best }) => best.z.clone(),
            Err(_) => return r,
        };
        let mut f = vec![0.0; mcp.dim()];
        mcp.evaluate(&z, &mut f);
        let res = ecp_model::natural_residual(&z, &f, mcp.lower(), mcp.upper());
        match r {
            Ok(mut s) if res <= 1e-10 => {
                s.summary.residual = res;
                Ok(s)
            }
            Ok(s) => {
                let mut s = s;
                s.summary.residual = res;
                Err(SolveError::NotConverged { best: Box::new(s) })
            }
            Err(SolveError::NotConverged { mut best }) => {
                best.summary.residual = res;
                if res <= 1e-10 {
                    Ok(*best)
                } else {
                    Err(SolveError::NotConverged { best })
                }
            }
            e => e,
        }
    }
}

/// The CHKS-smoothed equation system of an MCP with lower-bounded and free components:
/// `G_i = F_i` (free), `G_i = a + b − √((a − b)² + 4μ²)`, `a = z_i − l_i`, `b = F_i`.
struct Smoothed<'a> {
    inner: &'a dyn Mcp,
    mu: f64,
    lo: Vec<f64>,
    hi: Vec<f64>,
}

impl Mcp for Smoothed<'_> {
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn lower(&self) -> &[f64] {
        &self.lo
    }
    fn upper(&self) -> &[f64] {
        &self.hi
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        self.inner.evaluate(z, f);
        let l = self.inner.lower();
        for i in 0..z.len() {
            if l[i].is_finite() {
                let (a, b) = (z[i] - l[i], f[i]);
                f[i] = a + b - ((a - b) * (a - b) + 4.0 * self.mu * self.mu).sqrt();
            }
        }
    }
    fn jacobian_pattern(&self) -> &std::sync::Arc<ecp_model::CscPattern> {
        self.inner.jacobian_pattern()
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        let mut f = vec![0.0; z.len()];
        self.inner.evaluate_with_jacobian(z, &mut f, values);
        let l = self.inner.lower();
        let pat = self.inner.jacobian_pattern();
        let ri = pat.row_idx();
        let mut c = vec![f64::NAN; z.len()];
        for i in 0..z.len() {
            if l[i].is_finite() {
                let (a, b) = (z[i] - l[i], f[i]);
                let r = ((a - b) * (a - b) + 4.0 * self.mu * self.mu).sqrt();
                c[i] = if r > 0.0 { (a - b) / r } else { 0.0 };
            }
        }
        for (p, v) in values.iter_mut().enumerate() {
            let r = ri[p];
            if !c[r].is_nan() {
                *v *= 1.0 + c[r];
            }
        }
        for (j, &p) in pat.diag_pos().iter().enumerate() {
            if !c[j].is_nan() {
                values[p] += 1.0 - c[j];
            }
        }
    }
    fn component_name(&self, i: usize) -> String {
        self.inner.component_name(i)
    }
}

/// Smoothing continuation: Newton on the CHKS system for μ = μ0, μ0·θ, … then the plain backend.
struct Continuation {
    path: bool,
    theta: f64,
    rel: f64,
    tol: f64,
    maxit: usize,
    end: f64,
}

impl McpSolver for Continuation {
    fn name(&self) -> &str {
        "smooth"
    }
    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        let n = mcp.dim();
        let mut f = vec![0.0; n];
        mcp.evaluate(z0, &mut f);
        let mut phi = vec![0.0; n];
        ecp_model::mcp::fb_vector(z0, &f, mcp.lower(), mcp.upper(), &mut phi);
        let scale = phi.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let mut mu = self.rel * scale;
        let mut z = z0.to_vec();
        let (path, maxit) = (self.path, self.maxit);
        let make = |tol: f64| -> Box<dyn McpSolver> {
            if path {
                Box::new(PathSolver::new(PathSettings {
                    tolerance: tol,
                    max_iterations: maxit,
                    fischer_restart: false,
                    best_point_restart: false,
                    guarded_watchdog: false,
                    restarts: 0,
                    smoothing: None,
                    ..PathSettings::default()
                }))
            } else {
                Box::new(NewtonSolver::new(NewtonSettings {
                    tolerance: tol,
                    max_iterations: maxit,
                    smoothing: None,
                    ..NewtonSettings::default()
                }))
            }
        };
        let mut its = 0;
        let mut tol;
        while mu > self.end * scale {
            let sm = Smoothed {
                inner: mcp,
                mu,
                lo: vec![f64::NEG_INFINITY; n],
                hi: vec![f64::INFINITY; n],
            };
            tol = self.tol * mu;
            match make(tol).solve(&sm, &z) {
                Ok(s) => {
                    its += s.summary.iterations;
                    z = s.z;
                }
                Err(SolveError::NotConverged { best }) => {
                    its += best.summary.iterations;
                    z = best.z;
                }
                Err(e) => return Err(e),
            }
            mu *= self.theta;
        }
        let mut last: Box<dyn McpSolver> = if self.path {
            Box::new(PathSolver::new(PathSettings::default()))
        } else {
            Box::new(NewtonSolver::new(NewtonSettings::default()))
        };
        let r = last.solve(mcp, &z);
        match r {
            Ok(mut s) => {
                s.summary.iterations += its;
                Ok(s)
            }
            e => e,
        }
    }
}

/// Prototype of the smoothing Newton method of Qi, Sun & Zhou (Math. Prog. 87, 2000) on the
/// smoothed Fischer–Burmeister function `√(a² + b² + 2ε²) − a − b`, dense.
struct SmoothingNewton {
    gamma: f64,
    rel: f64,
    maxit: usize,
}

impl McpSolver for SmoothingNewton {
    fn name(&self) -> &str {
        "smoothing-newton"
    }
    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        use nalgebra::{DMatrix, DVector};
        let n = mcp.dim();
        let (l, u) = (mcp.lower().to_vec(), mcp.upper().to_vec());
        let pat = mcp.jacobian_pattern().clone();
        let mut jv = vec![0.0; pat.nnz()];
        let mut dense = vec![0.0; n * n];
        let mut f = vec![0.0; n];
        // Φ_ε(z) and its partials.
        let phi = |z: &[f64],
                   f: &[f64],
                   eps: f64,
                   out: &mut [f64],
                   da: &mut [f64],
                   db: &mut [f64],
                   de: &mut [f64]| {
            for i in 0..z.len() {
                if l[i].is_finite() && !u[i].is_finite() {
                    let (a, b) = (z[i] - l[i], f[i]);
                    let r = (a * a + b * b + 2.0 * eps * eps).sqrt();
                    out[i] = r - a - b;
                    if r > 0.0 {
                        da[i] = a / r - 1.0;
                        db[i] = b / r - 1.0;
                        de[i] = 2.0 * eps / r;
                    } else {
                        da[i] = std::f64::consts::FRAC_1_SQRT_2 - 1.0;
                        db[i] = da[i];
                        de[i] = 0.0;
                    }
                } else {
                    out[i] = f[i];
                    da[i] = 0.0;
                    db[i] = 1.0;
                    de[i] = 0.0;
                }
            }
        };
        let (mut ph, mut da, mut db, mut de) =
            (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut z = z0.to_vec();
        mcp.evaluate(&z, &mut f);
        phi(&z, &f, 0.0, &mut ph, &mut da, &mut db, &mut de);
        let eps_bar = self.rel * ph.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut eps = eps_bar;
        phi(&z, &f, eps, &mut ph, &mut da, &mut db, &mut de);
        let mut psi = eps * eps + ph.iter().map(|v| v * v).sum::<f64>();
        let psi0 = psi;
        let mut best = (f64::INFINITY, z.clone());
        let mut its = 0;
        let mut term = ecp_model::Termination::MaxIterations;
        let (mut zt, mut ft, mut pht, mut dat, mut dbt, mut det) = (
            vec![0.0; n],
            vec![0.0; n],
            vec![0.0; n],
            vec![0.0; n],
            vec![0.0; n],
            vec![0.0; n],
        );
        loop {
            let res = ecp_model::natural_residual(&z, &f, &l, &u);
            if res < best.0 {
                best = (res, z.clone());
            }
            if res <= 1e-10 {
                term = ecp_model::Termination::Converged;
                break;
            }
            if its >= self.maxit {
                break;
            }
            its += 1;
            mcp.jacobian(&z, &mut jv);
            pat.to_dense(&jv, &mut dense);
            let mut h = DMatrix::from_column_slice(n, n, &dense);
            for i in 0..n {
                for j in 0..n {
                    h[(i, j)] *= db[i];
                }
                h[(i, i)] += da[i];
            }
            let beta = self.gamma * (psi / psi0).min(1.0);
            let deps = beta * eps_bar - eps;
            let rhs = DVector::from_iterator(n, (0..n).map(|i| -ph[i] - de[i] * deps));
            let Some(d) = h.lu().solve(&rhs) else {
                term = ecp_model::Termination::SubproblemFailed;
                break;
            };
            let mut t = 1.0;
            let mut accepted = false;
            while t > 1e-10 {
                for i in 0..n {
                    zt[i] = z[i] + t * d[i];
                }
                let et = eps + t * deps;
                mcp.evaluate(&zt, &mut ft);
                phi(&zt, &ft, et, &mut pht, &mut dat, &mut dbt, &mut det);
                let p = et * et + pht.iter().map(|v| v * v).sum::<f64>();
                if p.is_finite() && p <= (1.0 - 2e-4 * (1.0 - self.gamma) * t) * psi {
                    std::mem::swap(&mut z, &mut zt);
                    std::mem::swap(&mut f, &mut ft);
                    std::mem::swap(&mut ph, &mut pht);
                    std::mem::swap(&mut da, &mut dat);
                    std::mem::swap(&mut db, &mut dbt);
                    std::mem::swap(&mut de, &mut det);
                    eps = et;
                    psi = p;
                    accepted = true;
                    break;
                }
                t *= 0.5;
            }
            if !accepted {
                term = ecp_model::Termination::LineSearchFailed;
                break;
            }
        }
        ecp_model::finish_solve(
            mcp,
            best.1,
            ecp_model::SolveReport {
                solver: "smoothing-newton",
                termination: term,
                tolerance: 1e-10,
                iterations: its,
                f_evals: 0,
                jac_evals: 0,
                started: std::time::Instant::now(),
                trace: Vec::new(),
                counters: Vec::new(),
            },
        )
    }
}

fn variant(name: &str) -> Option<Box<dyn McpSolver>> {
    if let Some(rest) = name.strip_prefix("nt:") {
        // nt:θ:μ0:stage_iterations:max_cuts — the Newton backend with these smoothing settings.
        let v: Vec<f64> = rest.split(':').filter_map(|v| v.parse().ok()).collect();
        let d = ecp_solvers::smoothing::SmoothingSettings::default();
        let sm = ecp_solvers::smoothing::SmoothingSettings {
            reduction: v.first().copied().unwrap_or(d.reduction),
            start: v.get(1).copied().unwrap_or(d.start),
            stage_iterations: v.get(2).map_or(d.stage_iterations, |x| *x as usize),
            max_cuts: v.get(3).map_or(d.max_cuts, |x| *x as usize),
            ..d
        };
        return Some(Box::new(NewtonSolver::new(NewtonSettings {
            smoothing: Some(sm),
            ..NewtonSettings::default()
        })));
    }
    if let Some(rest) = name.strip_prefix("sn:") {
        let mut it = rest.split(':').map(|v| v.parse::<f64>().ok());
        let gamma = it.next().flatten()?;
        let rel = it.next().flatten()?;
        let maxit = it.next().flatten().unwrap_or(200.0) as usize;
        return Some(Box::new(SmoothingNewton { gamma, rel, maxit }));
    }
    if let Some(rest) = name
        .strip_prefix("smooth:")
        .or_else(|| name.strip_prefix("psmooth:"))
    {
        let path = name.starts_with("psmooth:");
        let mut it = rest.split(':').map(|v| v.parse::<f64>().ok());
        let theta = it.next().flatten()?;
        let rel = it.next().flatten()?;
        let tol = it.next().flatten().unwrap_or(0.1);
        let maxit = it.next().flatten().unwrap_or(30.0) as usize;
        let end = it.next().flatten().unwrap_or(1e-9);
        return Some(Box::new(Continuation {
            path,
            theta,
            rel,
            tol,
            maxit,
            end,
        }));
    }
    if let Some(rest) = name.strip_prefix("kin:") {
        return variant(rest).map(|v| Box::new(KinScaled(v)) as Box<dyn McpSolver>);
    }
    let newton =
        |s: NewtonSettings| -> Option<Box<dyn McpSolver>> { Some(Box::new(NewtonSolver::new(s))) };
    let d = NewtonSettings::default();
    match name {
        "newton" => newton(d),
        "path" => Some(Box::new(PathSolver::new(PathSettings::default()))),
        "conic" => Some(Box::new(ConicSolver::new(ConicSettings::default()))),
        "conic-polish" => Some(Box::new(ConicSolver::new(ConicSettings {
            newton_polish: 50,
            ..ConicSettings::default()
        }))),
        "path-nocrash" => Some(Box::new(PathSolver::new(PathSettings {
            crash_iterations: 0,
            ..PathSettings::default()
        }))),
        "path-old" => Some(Box::new(PathSolver::new(PathSettings {
            fischer_restart: false,
            best_point_restart: false,
            smoothing: None,
            ..PathSettings::default()
        }))),
        "path-nofb" => Some(Box::new(PathSolver::new(PathSettings {
            fischer_restart: false,
            ..PathSettings::default()
        }))),
        "path-nobest" => Some(Box::new(PathSolver::new(PathSettings {
            best_point_restart: false,
            ..PathSettings::default()
        }))),
        "newton-nomn" => newton(NewtonSettings {
            min_norm_step: false,
            ..d
        }),
        "newton-nosmooth" => newton(NewtonSettings {
            smoothing: None,
            ..d
        }),
        "newton-400" => newton(NewtonSettings {
            max_iterations: 400,
            ..d
        }),
        _ => None,
    }
}

struct Outcome {
    ok: bool,
    residual: f64,
    iterations: usize,
    termination: String,
}

fn outcome(r: &Result<Solution, SolveError>) -> Outcome {
    match r {
        Ok(s) => Outcome {
            ok: true,
            residual: s.summary.residual,
            iterations: s.summary.iterations,
            termination: format!("{:?}", s.summary.termination),
        },
        Err(SolveError::NotConverged { best }) => Outcome {
            ok: false,
            residual: best.summary.residual,
            iterations: best.summary.iterations,
            termination: format!("{:?}", best.summary.termination),
        },
        Err(e) => Outcome {
            ok: false,
            residual: f64::INFINITY,
            iterations: 0,
            termination: format!("error {e}"),
        },
    }
}

/// The kind of a step from its start `z0` and a solution `zs`: contacts closing (`p_n` from 0 to
/// positive), opening, staying closed, and contacts whose active face multipliers change.
fn classify(mcp: &dyn Mcp, z0: &[f64], zs: &[f64]) -> String {
    let n = mcp.dim();
    let names: Vec<String> = (0..n).map(|i| mcp.component_name(i)).collect();
    let mut kinds = Vec::new();
    let mut i = 0;
    while i < n {
        let name = &names[i];
        if name.contains(".pn") {
            let tag = name.split(".pn").next().unwrap_or("");
            let (a, b) = (z0[i] > 1e-14, zs[i] > 1e-14);
            let k = match (a, b) {
                (false, true) => "closing",
                (true, false) => "opening",
                (true, true) => "closed",
                (false, false) => "open",
            };
            // Face multipliers of this contact.
            let l: Vec<usize> = (0..n)
                .filter(|&j| names[j].starts_with(&format!("{tag}.l[")))
                .collect();
            let act = |z: &[f64]| -> Vec<usize> {
                l.iter()
                    .enumerate()
                    .filter(|&(_, &j)| z[j] > 1e-12)
                    .map(|(k, _)| k)
                    .collect()
            };
            let (f0, f1) = (act(z0), act(zs));
            let feature = if f0 != f1 {
                format!(" feature {f0:?}->{f1:?}")
            } else {
                String::new()
            };
            if k != "open" || !feature.is_empty() {
                kinds.push(format!("{tag}:{k}{feature}"));
            }
        }
        i += 1;
    }
    if kinds.is_empty() {
        "free flight".into()
    } else {
        kinds.join(" ")
    }
}

struct Probe {
    inner: Box<dyn McpSolver>,
    reference: PathSolver,
    variants: Vec<(String, Box<dyn McpSolver>)>,
    step: usize,
    scene: String,
    verbose: bool,
    /// Per variant: (wins: solves the backend failed and it solved, losses, solves of failed ones).
    tally: Vec<(usize, usize)>,
    failed_solves: usize,
    solves: usize,
}

impl McpSolver for Probe {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn solve(&mut self, mcp: &dyn Mcp, z0: &[f64]) -> Result<Solution, SolveError> {
        self.solves += 1;
        let r = self.inner.solve(mcp, z0);
        let base = outcome(&r);
        let mut var_ok = Vec::new();
        for (k, (_, v)) in self.variants.iter_mut().enumerate() {
            let o = outcome(&v.solve(mcp, z0));
            if o.ok && !base.ok {
                self.tally[k].0 += 1;
            }
            if !o.ok && base.ok {
                self.tally[k].1 += 1;
            }
            var_ok.push(o);
        }
        if base.ok {
            if self.verbose {
                let losses: Vec<&str> = self
                    .variants
                    .iter()
                    .zip(&var_ok)
                    .filter(|(_, o)| !o.ok)
                    .map(|(v, _)| v.0.as_str())
                    .collect();
                if !losses.is_empty() {
                    println!(
                        "{} step {}: backend ok in {}, lost by {:?}",
                        self.scene, self.step, base.iterations, losses
                    );
                }
            }
            return r;
        }
        self.failed_solves += 1;
        let reference = self.reference.solve(mcp, z0);
        let worst = match &r {
            Err(SolveError::NotConverged { best }) => best
                .summary
                .worst
                .as_ref()
                .map(|w| format!("{} {:.1e}", w.name, w.value))
                .unwrap_or_default(),
            _ => String::new(),
        };
        let kind = match &reference {
            Ok(s) => format!(
                "{} (PATH crash {} path {})",
                classify(mcp, z0, &s.z),
                s.summary.counter("crash_steps"),
                s.summary.counter("path_steps")
            ),
            Err(_) => "PATH fails too".into(),
        };
        let vars: Vec<String> = self
            .variants
            .iter()
            .zip(&var_ok)
            .map(|((n, _), o)| {
                format!(
                    "{n}:{}",
                    if o.ok {
                        format!("ok{}", o.iterations)
                    } else {
                        format!("{:.0e}", o.residual)
                    }
                )
            })
            .collect();
        let dump = std::env::var("PROBE_DUMP")
            .ok()
            .is_some_and(|d| d == format!("{}:{}", self.scene, self.step));
        if dump {
            let zb = match &r {
                Err(SolveError::NotConverged { best }) => best.z.clone(),
                _ => z0.to_vec(),
            };
            let zs = match &reference {
                Ok(s) => s.z.clone(),
                Err(SolveError::NotConverged { best }) => best.z.clone(),
                _ => z0.to_vec(),
            };
            let n = mcp.dim();
            let (mut fb, mut fs) = (vec![0.0; n], vec![0.0; n]);
            mcp.evaluate(&zb, &mut fb);
            mcp.evaluate(&zs, &mut fs);
            println!(
                "{:<22} {:>13} {:>13} {:>13} {:>11} {:>11}",
                "component", "z0", "z backend", "z PATH", "F backend", "F PATH"
            );
            for i in 0..n {
                println!(
                    "{:<22} {:>13.6e} {:>13.6e} {:>13.6e} {:>11.3e} {:>11.3e}",
                    mcp.component_name(i),
                    z0[i],
                    zb[i],
                    zs[i],
                    fb[i],
                    fs[i]
                );
            }
        }
        println!(
            "{} step {}: {} r={:.1e} it={} worst [{}] | {} | {}",
            self.scene,
            self.step,
            base.termination,
            base.residual,
            base.iterations,
            worst,
            kind,
            vars.join(" ")
        );
        r
    }
}

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let Some(dir) = args.next().map(PathBuf::from) else {
        eprintln!("usage: step_probe DIR [--only TEXT] [--solver S] [--steps N] [--variants a,b]");
        return ExitCode::from(2);
    };
    let (mut only, mut solver, mut steps, mut variants, mut verbose) = (
        None,
        "newton".to_string(),
        usize::MAX,
        Vec::<String>::new(),
        false,
    );
    while let Some(flag) = args.next() {
        match flag.as_str() {
            "--only" => only = args.next(),
            "--solver" => solver = args.next().unwrap_or_default(),
            "--steps" => {
                steps = args
                    .next()
                    .and_then(|s| s.parse().ok())
                    .unwrap_or(usize::MAX)
            }
            "--variants" => {
                variants = args
                    .next()
                    .unwrap_or_default()
                    .split(',')
                    .filter(|s| !s.is_empty())
                    .map(String::from)
                    .collect()
            }
            "--verbose" => verbose = true,
            f => {
                eprintln!("unknown flag {f}");
                return ExitCode::from(2);
            }
        }
    }
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    paths.retain(|p| {
        p.extension().is_some_and(|e| e == "toml")
            && p.file_stem()
                .and_then(|s| s.to_str())
                .is_some_and(|s| only.as_deref().is_none_or(|o| s.contains(o)))
    });
    paths.sort();
    let Some(inner) = variant(&solver) else {
        eprintln!("unknown solver {solver}");
        return ExitCode::from(2);
    };
    let mut probe = Probe {
        inner,
        reference: PathSolver::new(PathSettings::default()),
        variants: Vec::new(),
        step: 0,
        scene: String::new(),
        verbose,
        tally: vec![(0, 0); variants.len()],
        failed_solves: 0,
        solves: 0,
    };
    for v in &variants {
        match variant(v) {
            Some(s) => probe.variants.push((v.clone(), s)),
            None => {
                eprintln!("unknown variant {v}");
                return ExitCode::from(2);
            }
        }
    }
    let (mut failed_steps, mut total_steps, mut failed_runs) = (0, 0, 0);
    for path in &paths {
        let file = match load_scene(path) {
            Ok(f) => f,
            Err(e) => {
                eprintln!("{}: {e}", path.display());
                continue;
            }
        };
        probe.scene = file.scene.name.clone();
        let mut sim = match build_stepper(file.scene.clone(), Formulation::Hull) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{}: {e}", path.display());
                continue;
            }
        };
        let n = file.scene.num_steps().min(steps);
        let mut run_failed = false;
        for k in 0..n {
            probe.step = k + 1;
            // The reference backends, the probed one left out (it failed already).
            let mut backends: Vec<Box<dyn McpSolver>> = Vec::new();
            if solver != "path" {
                backends.push(Box::new(PathSolver::new(PathSettings::default())));
            }
            if solver != "newton" {
                backends.push(Box::new(NewtonSolver::new(NewtonSettings::default())));
            }
            let mut fallback = Fallbacks {
                backends,
                max_halvings: 4,
            };
            match sim.step_with(&mut probe, &mut fallback) {
                Ok(rec) => {
                    total_steps += 1;
                    if rec.method != StepMethod::Direct {
                        println!(
                            "STEP FAILED {} step {}: {}",
                            probe.scene,
                            k + 1,
                            rec.method.column()
                        );
                        failed_steps += 1;
                        run_failed = true;
                    }
                }
                Err(e) => {
                    println!("{} step {}: stepper error {e}", probe.scene, k + 1);
                    run_failed = true;
                    break;
                }
            }
        }
        failed_runs += usize::from(run_failed);
    }
    println!(
        "\n{} scenes, {failed_runs} with a failed step; {failed_steps} of {total_steps} steps \
         failed; {} of {} solves failed",
        paths.len(),
        probe.failed_solves,
        probe.solves
    );
    for ((name, _), (wins, losses)) in probe.variants.iter().zip(&probe.tally) {
        println!("variant {name}: solves {wins} failed solves, fails {losses} solved ones");
    }
    ExitCode::SUCCESS
}
