//! The Jacobian checker, in the spirit of Ceres' `GradientChecker`: compares analytic
//! Jacobians with central finite differences, block by block, and names the worst entries.
//!
//! [`check_problem`] is the entry point for an assembled problem: it checks every residual block
//! with respect to every input, variable or data (perturbing a data block through the block's
//! inputs), so a wrong derivative with respect to a model parameter is caught like any other.
//! [`check_residual_block`] checks a standalone block (every input it reads), and [`check_mcp`]
//! the whole Jacobian of any [`Mcp`].
//!
//! ```
//! use ecp_model::{check_residual_block, CheckOptions, JacobianBlocks, Params, ResidualBlock};
//!
//! /// r(x, y) = x·y, with a correct Jacobian.
//! struct Product;
//! impl ResidualBlock for Product {
//!     fn name(&self) -> &str { "product" }
//!     fn num_residuals(&self) -> usize { 1 }
//!     fn parameter_sizes(&self) -> &[usize] { &[1, 1] }
//!     fn evaluate(&self, p: Params<'_>, out: &mut [f64]) { out[0] = p.block(0)[0] * p.block(1)[0]; }
//!     fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
//!         jac.set(0, 0, 0, p.block(1)[0]);
//!         jac.set(1, 0, 0, p.block(0)[0]);
//!     }
//! }
//! let report = check_residual_block(&Product, &[&[2.0], &[3.0]], &CheckOptions::default()).unwrap();
//! assert!(report.ok(), "{report}");
//! ```

use std::fmt;

use crate::error::ModelError;
use crate::mcp::Mcp;
use crate::problem::{BlockMcp, ResId};
use crate::residual::{InputKind, InputRange, JacobianBlocks, Params, ResidualBlock};

/// Settings of the Jacobian checker.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CheckOptions {
    /// Central-difference step relative to `max(1, |x_j|)`. Default `1e-6`.
    pub relative_step: f64,
    /// Relative tolerance on an entry. Default `1e-6`.
    pub rel_tol: f64,
    /// Absolute tolerance on an entry. Default `1e-7`.
    pub abs_tol: f64,
    /// How many of the worst entries the report lists. Default 8.
    pub max_listed: usize,
}

impl Default for CheckOptions {
    fn default() -> Self {
        CheckOptions {
            relative_step: 1e-6,
            rel_tol: 1e-6,
            abs_tol: 1e-7,
            max_listed: 8,
        }
    }
}

/// One compared Jacobian entry.
#[derive(Clone, Debug, PartialEq)]
pub struct EntryCheck {
    /// Residual row (within the residual block, or the flat row for a whole MCP).
    pub row: usize,
    /// Input index among those the residual block reads (0 for a whole MCP).
    pub block: usize,
    /// Column within that block (or the flat column).
    pub col: usize,
    /// Readable location, e.g. `"friction[1] / nu[5]"`.
    pub location: String,
    /// Analytic value.
    pub analytic: f64,
    /// Central-difference value.
    pub numeric: f64,
    /// `|analytic − numeric|`.
    pub abs_error: f64,
    /// `abs_error / max(|analytic|, |numeric|)` (0 when both vanish).
    pub rel_error: f64,
    /// Whether the entry is outside tolerance.
    pub failed: bool,
}

/// Errors of one (residual block, input) pair.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockPairCheck {
    /// Index of the input among those the residual block reads.
    pub block: usize,
    /// Name of the input: its variable or data block's name ([`check_problem`]), or `input k`
    /// for a standalone block.
    pub input: String,
    /// Whether the input is a variable or a data block (`None` for a standalone block, whose
    /// inputs are just values).
    pub kind: Option<InputKind>,
    /// Largest absolute error in this pair.
    pub max_abs_error: f64,
    /// Largest relative error in this pair.
    pub max_rel_error: f64,
    /// Entries outside tolerance.
    pub failures: usize,
}

/// Result of a Jacobian check.
#[derive(Clone, Debug, PartialEq)]
pub struct JacobianReport {
    /// What was checked.
    pub name: String,
    /// Per input read.
    pub pairs: Vec<BlockPairCheck>,
    /// The worst entries, largest error first.
    pub worst: Vec<EntryCheck>,
    /// Number of entries outside tolerance.
    pub failures: usize,
    /// Number of entries compared.
    pub entries: usize,
    /// Largest absolute error.
    pub max_abs_error: f64,
    /// Largest relative error.
    pub max_rel_error: f64,
}

impl JacobianReport {
    /// True when every entry is within tolerance.
    pub fn ok(&self) -> bool {
        self.failures == 0
    }
}

impl fmt::Display for JacobianReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "Jacobian check of {}: {} ({} of {} entries outside tolerance; max abs error {:.3e}, max rel error {:.3e})",
            self.name,
            if self.ok() { "OK" } else { "FAILED" },
            self.failures,
            self.entries,
            self.max_abs_error,
            self.max_rel_error
        )?;
        if !self.worst.is_empty() {
            writeln!(
                f,
                "  {:<36} {:>14} {:>14} {:>10} {:>10}",
                "entry", "analytic", "numeric", "abs err", "rel err"
            )?;
            for e in &self.worst {
                writeln!(
                    f,
                    "{} {:<36} {:>14.6e} {:>14.6e} {:>10.2e} {:>10.2e}",
                    if e.failed { "!" } else { " " },
                    e.location,
                    e.analytic,
                    e.numeric,
                    e.abs_error,
                    e.rel_error
                )?;
            }
        }
        Ok(())
    }
}

struct Collector {
    opts: CheckOptions,
    all: Vec<EntryCheck>,
    pairs: Vec<BlockPairCheck>,
}

impl Collector {
    /// Records one entry. `noise` bounds the round-off of the central difference
    /// (`≈ 4 ε max|r(x ± h)| / 2h`): rows with large values would otherwise fail on round-off.
    fn push(
        &mut self,
        row: usize,
        block: usize,
        col: usize,
        location: String,
        a: f64,
        n: f64,
        noise: f64,
    ) {
        let abs_error = if a.is_finite() && n.is_finite() {
            (a - n).abs()
        } else {
            f64::INFINITY
        };
        let scale = a.abs().max(n.abs());
        let rel_error = if scale > 0.0 { abs_error / scale } else { 0.0 };
        // NaN errors count as failures.
        let failed =
            abs_error.is_nan() || abs_error > self.opts.abs_tol + self.opts.rel_tol * scale + noise;
        while self.pairs.len() <= block {
            let b = self.pairs.len();
            self.pairs.push(BlockPairCheck {
                block: b,
                input: format!("input {b}"),
                kind: None,
                max_abs_error: 0.0,
                max_rel_error: 0.0,
                failures: 0,
            });
        }
        let p = &mut self.pairs[block];
        p.max_abs_error = p.max_abs_error.max(abs_error);
        p.max_rel_error = p.max_rel_error.max(rel_error);
        p.failures += usize::from(failed);
        self.all.push(EntryCheck {
            row,
            block,
            col,
            location,
            analytic: a,
            numeric: n,
            abs_error,
            rel_error,
            failed,
        });
    }

    /// Records an entry that failed whatever the tolerances: `a` and `b` are its analytic
    /// values at two points where they must be the same.
    fn push_failure(
        &mut self,
        row: usize,
        block: usize,
        col: usize,
        location: String,
        a: f64,
        b: f64,
    ) {
        self.push(row, block, col, location, a, b, 0.0);
        if let Some(e) = self.all.last_mut()
            && !e.failed
        {
            e.failed = true;
            self.pairs[block].failures += 1;
        }
    }

    fn finish(mut self, name: String) -> JacobianReport {
        let failures = self.all.iter().filter(|e| e.failed).count();
        let entries = self.all.len();
        let max_abs_error = self.all.iter().map(|e| e.abs_error).fold(0.0, f64::max);
        let max_rel_error = self.all.iter().map(|e| e.rel_error).fold(0.0, f64::max);
        // Failed entries first, then by how far outside tolerance they are.
        let tol = |e: &EntryCheck| {
            e.abs_error
                / (self.opts.abs_tol + self.opts.rel_tol * e.analytic.abs().max(e.numeric.abs()))
        };
        self.all.sort_by(|a, b| {
            tol(b)
                .partial_cmp(&tol(a))
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        self.all.truncate(self.opts.max_listed);
        JacobianReport {
            name,
            pairs: self.pairs,
            worst: self.all,
            failures,
            entries,
            max_abs_error,
            max_rel_error,
        }
    }
}

/// A flat copy of a block's inputs, the range of each, and their sizes.
type FlatParams = (Vec<f64>, Vec<InputRange>, Vec<usize>);

/// `params` (one slice per input `block` reads) as one flat vector with the ranges that
/// [`Params`] views it through, and the block's declared sizes; an error when the slices do not
/// have those sizes.
fn flat_params(block: &dyn ResidualBlock, params: &[&[f64]]) -> Result<FlatParams, ModelError> {
    let sizes = block.parameter_sizes().to_vec();
    if sizes.len() != params.len() || sizes.iter().zip(params).any(|(s, p)| *s != p.len()) {
        return Err(ModelError::InvalidBlock {
            block: block.name().to_string(),
            reason: format!(
                "checker given parameter sizes {:?}, block declares {:?}",
                params.iter().map(|p| p.len()).collect::<Vec<_>>(),
                sizes
            ),
        });
    }
    let z: Vec<f64> = params.iter().flat_map(|p| p.iter().copied()).collect();
    let mut ranges = Vec::with_capacity(sizes.len());
    let mut o = 0;
    for &s in &sizes {
        ranges.push(InputRange::var(o, s));
        o += s;
    }
    Ok((z, ranges, sizes))
}

/// Checks one residual block's analytic Jacobian at `params` (one slice per input it reads,
/// variable or data: the checker differentiates them all) against central differences, input by
/// input.
pub fn check_residual_block(
    block: &dyn ResidualBlock,
    params: &[&[f64]],
    opts: &CheckOptions,
) -> Result<JacobianReport, ModelError> {
    let (mut z, ranges, sizes) = flat_params(block, params)?;
    let o = z.len();
    let m = block.num_residuals();
    // Local dense storage: block k column j row i at (start_k + j) * m + i.
    let total_cols = o;
    let col_pos: Vec<usize> = (0..total_cols).map(|c| c * m).collect();
    let mut block_start = vec![0];
    for &s in &sizes {
        let last = *block_start.last().unwrap_or(&0);
        block_start.push(last + s);
    }
    let mut analytic = vec![0.0; total_cols * m];
    {
        let mut jac = JacobianBlocks::new(&mut analytic, &col_pos, &block_start, m);
        block.jacobian(Params::new(&z, &[], &ranges), &mut jac);
    }
    let mut collector = Collector {
        opts: *opts,
        all: Vec::new(),
        pairs: Vec::new(),
    };
    let mut diff = Differences::new(m);
    for (k, r) in ranges.iter().enumerate() {
        let (off, size) = (r.offset, r.len);
        for j in 0..size {
            let c = off + j;
            let x0 = z[c];
            let h = opts.relative_step * x0.abs().max(1.0);
            diff.compute(x0, h, |x, out| {
                z[c] = x;
                block.evaluate(Params::new(&z, &[], &ranges), out);
            });
            z[c] = x0;
            for i in 0..m {
                collector.push(
                    i,
                    k,
                    j,
                    format!("{}[{}] / input{}[{}]", block.name(), i, k, j),
                    analytic[c * m + i],
                    diff.numeric[i],
                    diff.noise[i],
                );
            }
        }
    }
    check_constant_inputs(
        block,
        &z,
        &ranges,
        &col_pos,
        &block_start,
        &analytic,
        &mut collector,
    );
    Ok(collector.finish(block.name().to_string()))
}

/// The inputs `k` whose Jacobian the block says depends on a few inputs only
/// ([`ResidualBlock::jacobian_depends_on`]): the Jacobian again with every other input moved
/// (`x → 1.5 x + 0.25`) must give input `k`'s entries bit for bit, else each entry that moved is
/// a failure (the assembled MCP would keep a stale entry).
fn check_constant_inputs(
    block: &dyn ResidualBlock,
    z: &[f64],
    ranges: &[InputRange],
    col_pos: &[usize],
    block_start: &[usize],
    analytic: &[f64],
    collector: &mut Collector,
) {
    let m = block.num_residuals();
    for (k, r) in ranges.iter().enumerate() {
        let Some(deps) = block.jacobian_depends_on(k) else {
            continue;
        };
        let mut moved = z.to_vec();
        for (l, rl) in ranges.iter().enumerate() {
            if !deps.contains(&l) {
                for v in &mut moved[rl.offset..rl.offset + rl.len] {
                    *v = 1.5 * *v + 0.25;
                }
            }
        }
        let mut again = vec![0.0; analytic.len()];
        {
            let mut jac = JacobianBlocks::new(&mut again, col_pos, block_start, m);
            block.jacobian(Params::new(&moved, &[], ranges), &mut jac);
        }
        for j in 0..r.len {
            let c = r.offset + j;
            for i in 0..m {
                let (a, b) = (analytic[c * m + i], again[c * m + i]);
                if a.to_bits() != b.to_bits() {
                    collector.push_failure(
                        i,
                        k,
                        j,
                        format!(
                            "{}[{}] / input{}[{}] (said to depend on inputs {:?} only)",
                            block.name(),
                            i,
                            k,
                            j,
                            deps
                        ),
                        a,
                        b,
                    );
                }
            }
        }
    }
}

/// Checks every residual block of an assembled problem at `z` with respect to every input,
/// variable or data, against central differences (a data block is perturbed through the
/// block's inputs; the problem itself is not changed). One report per residual block, named
/// after the block and the variable block whose rows it provides; its `pairs` name each input
/// and its kind, and its entries read `block[row] / input.component`.
///
/// ```
/// use ecp_model::*;
///
/// /// r(x; c) = c·x², paired with x, with the data c.
/// struct Scaled;
/// impl ResidualBlock for Scaled {
///     fn name(&self) -> &str { "scaled" }
///     fn num_residuals(&self) -> usize { 1 }
///     fn parameter_sizes(&self) -> &[usize] { &[1, 1] }
///     fn evaluate(&self, p: Params<'_>, out: &mut [f64]) { out[0] = p.block(1)[0] * p.block(0)[0].powi(2); }
///     fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
///         let (x, c) = (p.block(0)[0], p.block(1)[0]);
///         jac.set(0, 0, 0, 2.0 * c * x);
///         jac.set(1, 0, 0, x * x);
///     }
/// }
/// let mut p = Problem::new();
/// let x = p.add_variable_block(VarBlock::free("x", 1));
/// let c = p.add_data_block(DataBlock::new("c", [3.0]));
/// p.add_residual_block(x, Scaled, &[Input::Var(x), Input::Data(c)]).unwrap();
/// let mcp = p.build().unwrap();
/// let reports = check_problem(&mcp, &[2.0], &CheckOptions::default());
/// assert!(reports.iter().all(|r| r.ok()), "{}", reports[0]);
/// assert_eq!(reports[0].pairs[1].kind, Some(InputKind::Data));
/// assert_eq!(reports[0].entries, 2);
/// ```
pub fn check_problem(mcp: &BlockMcp, z: &[f64], opts: &CheckOptions) -> Vec<JacobianReport> {
    (0..mcp.num_residual_blocks())
        .map(|r| {
            let id = ResId(r);
            let (block, ranges, _) = mcp.residual_block(id);
            let params = mcp.residual_block_params(id, z);
            let slices: Vec<&[f64]> = (0..ranges.len()).map(|k| params.block(k)).collect();
            let (rows_of, term) = mcp.residual_rows(id);
            let rows = mcp.variable_blocks()[rows_of.0].name();
            let name = format!(
                "{} (#{r}, {} rows of {rows})",
                block.name(),
                if term { "a term adding to the" } else { "the" }
            );
            match check_residual_block(block, &slices, opts) {
                Ok(mut rep) => {
                    rep.name = name;
                    for p in rep.pairs.iter_mut() {
                        p.input = mcp.input_name(id, p.block);
                        p.kind = Some(ranges[p.block].kind);
                    }
                    for e in rep.worst.iter_mut() {
                        let kind = ranges[e.block].kind;
                        e.location = format!(
                            "{}[{}] / {}{}",
                            block.name(),
                            e.row,
                            mcp.input_component_name(id, e.block, e.col),
                            if kind == InputKind::Data {
                                " (data)"
                            } else {
                                ""
                            }
                        );
                    }
                    rep
                }
                // An assembled block always has matching sizes; report the impossible as a
                // failed check rather than hide it.
                Err(e) => JacobianReport {
                    name: format!("{name}: {e}"),
                    pairs: Vec::new(),
                    worst: Vec::new(),
                    failures: 1,
                    entries: 0,
                    max_abs_error: f64::INFINITY,
                    max_rel_error: f64::INFINITY,
                },
            }
        })
        .collect()
}

/// Checks the whole Jacobian of any [`Mcp`] (for problems given by closures) at `z`.
pub fn check_mcp(mcp: &dyn Mcp, z: &[f64], opts: &CheckOptions) -> JacobianReport {
    let n = mcp.dim();
    let pattern = mcp.jacobian_pattern().clone();
    let mut values = vec![0.0; pattern.nnz()];
    mcp.jacobian(z, &mut values);
    let mut dense = vec![0.0; n * n];
    pattern.to_dense(&values, &mut dense);
    let mut zz = z.to_vec();
    let mut diff = Differences::new(n);
    let mut collector = Collector {
        opts: *opts,
        all: Vec::new(),
        pairs: Vec::new(),
    };
    for j in 0..n {
        let x0 = zz[j];
        let h = opts.relative_step * x0.abs().max(1.0);
        diff.compute(x0, h, |x, out| {
            zz[j] = x;
            mcp.evaluate(&zz, out);
        });
        zz[j] = x0;
        for i in 0..n {
            let (numeric, noise) = (diff.numeric[i], diff.noise[i]);
            let analytic = dense[j * n + i];
            if analytic == 0.0 && numeric == 0.0 {
                continue;
            }
            collector.push(
                i,
                0,
                j,
                format!("F[{}] / {}", mcp.component_name(i), mcp.component_name(j)),
                analytic,
                numeric,
                noise,
            );
        }
    }
    collector.finish("MCP Jacobian".to_string())
}

/// Central differences in one coordinate at steps `h` and `h/2`, combined by Richardson
/// extrapolation. `noise` bounds the round-off of the combination plus the truncation error
/// estimated from the two steps: it is large only where the function bends sharply within the
/// step (near a kink such as `‖p‖` at `p ≈ 0`), where a finite difference cannot be trusted.
/// See `docs/decisions.md#jacobian-checker-richardson-extrapolation`.
struct Differences {
    plus: Vec<f64>,
    minus: Vec<f64>,
    coarse: Vec<f64>,
    coarse_noise: Vec<f64>,
    numeric: Vec<f64>,
    noise: Vec<f64>,
}

impl Differences {
    fn new(m: usize) -> Self {
        Differences {
            plus: vec![0.0; m],
            minus: vec![0.0; m],
            coarse: vec![0.0; m],
            coarse_noise: vec![0.0; m],
            numeric: vec![0.0; m],
            noise: vec![0.0; m],
        }
    }

    /// Fills `numeric` and `noise` for the coordinate at `x0`; `eval(x, out)` evaluates the
    /// residuals with that coordinate set to `x`.
    fn compute(&mut self, x0: f64, h: f64, mut eval: impl FnMut(f64, &mut [f64])) {
        for (pass, step) in [h, 0.5 * h].into_iter().enumerate() {
            eval(x0 + step, &mut self.plus);
            eval(x0 - step, &mut self.minus);
            for i in 0..self.plus.len() {
                let (p, m) = (self.plus[i], self.minus[i]);
                let d = (p - m) / (2.0 * step);
                let roundoff = 4.0 * f64::EPSILON * p.abs().max(m.abs()) / (2.0 * step);
                if pass == 0 {
                    self.coarse[i] = d;
                    self.coarse_noise[i] = roundoff;
                } else {
                    self.numeric[i] = (4.0 * d - self.coarse[i]) / 3.0;
                    self.noise[i] =
                        (4.0 * roundoff + self.coarse_noise[i]) / 3.0 + (d - self.coarse[i]).abs();
                }
            }
        }
    }
}
