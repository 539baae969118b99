//! A user's own residual block with an analytic Jacobian and a data block (`README.md`, "A new
//! residual block"): a mass on a hardening spring above a floor, `cargo run --example
//! custom_block`.
//!
//! Unknowns: the height `y` (free) and the floor's force `λ ≥ 0`. Rows: the equilibrium
//! `k (L − y) + c (L − y)³ − m g + λ = 0`, paired with `y`, and `0 ≤ λ ⊥ y ≥ 0`. The parameters
//! `(k, c, m, g, L)` are a data block: the block writes its derivatives with respect to them in
//! the same `jacobian`, the one checker entry point (`check_problem`) checks variables and data,
//! a backend from the registry solves the problem, and `set_data` changes the mass without
//! rebuilding it.

use ecp::model::{
    BlockMcp, CheckOptions, DataBlock, DataId, Input, JacobianBlocks, Params, Problem,
    ResidualBlock, VarBlock, VarId, check_problem,
};
use ecp::solvers::registry::{BackendOptions, Registry};

/// `k (L − y) + c (L − y)³ − m g + λ`; inputs `y` (1), `λ` (1), data `(k, c, m, g, L)` (5).
pub struct Equilibrium;

impl ResidualBlock for Equilibrium {
    fn name(&self) -> &str {
        "equilibrium"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1, 1, 5]
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        let (y, lambda, d) = (p.block(0)[0], p.block(1)[0], p.block(2));
        let (k, c, m, g, l) = (d[0], d[1], d[2], d[3], d[4]);
        out[0] = k * (l - y) + c * (l - y).powi(3) - m * g + lambda;
    }
    fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let (y, d) = (p.block(0)[0], p.block(2));
        let (k, c, m, g, l) = (d[0], d[1], d[2], d[3], d[4]);
        let s = l - y;
        jac.set(0, 0, 0, -k - 3.0 * c * s * s);
        jac.set(1, 0, 0, 1.0);
        // The data derivatives, in the same code (asked only for sensitivities).
        if jac.wants(2) {
            for (j, v) in [s, s.powi(3), -g, -m, k + 3.0 * c * s * s]
                .into_iter()
                .enumerate()
            {
                jac.set(2, 0, j, v);
            }
        }
    }
}

/// `y`, paired with `λ ≥ 0`: the floor.
pub struct Floor;

impl ResidualBlock for Floor {
    fn name(&self) -> &str {
        "floor"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[1]
    }
    fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
        out[0] = p.block(0)[0];
    }
    fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        jac.set(0, 0, 0, 1.0);
    }
}

/// The problem with parameters `(k, c, m, g, L)`, and the handles of `y`, `λ` and the data.
pub fn build(
    params: [f64; 5],
) -> Result<(BlockMcp, VarId, VarId, DataId), Box<dyn std::error::Error>> {
    let mut problem = Problem::new();
    let y = problem.add_variable_block(VarBlock::free("y", 1));
    let lambda = problem.add_variable_block(VarBlock::nonnegative("lambda", 1));
    let data = problem.add_data_block(
        DataBlock::new("spring", params).with_component_names(["k", "c", "m", "g", "L"]),
    );
    problem.add_residual_block(
        y,
        Equilibrium,
        &[y.into(), lambda.into(), Input::from(data)],
    )?;
    problem.add_residual_block(lambda, Floor, &[y])?;
    Ok((problem.build()?, y, lambda, data))
}

/// Checks the Jacobians at a point, then solves with the registry's Newton backend for each mass
/// in `masses`, changing the data in place; returns `(y, λ)` per mass.
pub fn run(masses: &[f64]) -> Result<Vec<(f64, f64)>, Box<dyn std::error::Error>> {
    let (k, c, g, l) = (100.0, 400.0, 9.8, 0.3);
    let (mut mcp, y, lambda, data) = build([k, c, masses[0], g, l])?;
    for report in check_problem(&mcp, &[0.2, 1.5], &CheckOptions::default()) {
        if !report.ok() {
            return Err(format!("Jacobian check failed:\n{report}").into());
        }
    }
    let mut solver = Registry::builtin().build("newton", &BackendOptions::default())?;
    let mut out = Vec::new();
    for &m in masses {
        mcp.set_data(data, &[k, c, m, g, l])?;
        let sol = solver.solve(&mcp, &[l, 0.0])?;
        out.push((sol.z[mcp.range(y)][0], sol.z[mcp.range(lambda)][0]));
    }
    Ok(out)
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    for (m, (y, lambda)) in [1.0, 5.0].iter().zip(run(&[1.0, 5.0])?) {
        println!("m = {m} kg: y = {y:.6} m, floor force λ = {lambda:.6} N");
    }
    Ok(())
}
