//! The problem builder: variable blocks paired with residual blocks, assembled into one MCP.

use std::sync::Arc;

use crate::ModelError;
use crate::bounds::VarBlock;
use crate::mcp::Mcp;
use crate::pattern::CscPattern;
use crate::residual::{DataJacobian, JacobianBlocks, Params, ResidualBlock};

/// Handle of a variable block inside a [`Problem`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VarId(pub usize);

/// Handle of a residual block inside a [`Problem`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ResId(pub usize);

struct PendingResidual {
    block: Arc<dyn ResidualBlock>,
    pairs_with: VarId,
    reads: Vec<VarId>,
}

/// Builder of a block-structured MCP (`docs/model.md#mcp`, `docs/model.md#unknowns`).
///
/// ```
/// use ecp_model::{Problem, VarBlock, ResidualBlock, Params, JacobianBlocks, Mcp};
///
/// /// r(x) = x − 1, paired with a free x: the equation x = 1.
/// struct Shift;
/// impl ResidualBlock for Shift {
///     fn name(&self) -> &str { "shift" }
///     fn num_residuals(&self) -> usize { 1 }
///     fn parameter_sizes(&self) -> &[usize] { &[1] }
///     fn evaluate(&self, x: Params<'_>, out: &mut [f64]) { out[0] = x.block(0)[0] - 1.0; }
///     fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) { jac.set(0, 0, 0, 1.0); }
/// }
///
/// let mut p = Problem::new();
/// let x = p.add_variable_block(VarBlock::free("x", 1));
/// p.add_residual_block(x, Shift, &[x]).unwrap();
/// let mcp = p.build().unwrap();
/// let mut f = [0.0];
/// mcp.evaluate(&[3.0], &mut f);
/// assert_eq!(f[0], 2.0);
/// ```
#[derive(Default)]
pub struct Problem {
    vars: Vec<VarBlock>,
    residuals: Vec<PendingResidual>,
}

impl Problem {
    /// An empty problem.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a variable block; its components are laid out after the previous blocks'.
    pub fn add_variable_block(&mut self, block: VarBlock) -> VarId {
        self.vars.push(block);
        VarId(self.vars.len() - 1)
    }

    /// Adds a residual block paired with the variable block `pairs_with` (same length), reading
    /// the variable blocks `reads` in the order of its `parameter_sizes`.
    pub fn add_residual_block(
        &mut self,
        pairs_with: VarId,
        block: impl ResidualBlock + 'static,
        reads: &[VarId],
    ) -> Result<ResId, ModelError> {
        self.add_shared_residual_block(pairs_with, Arc::new(block), reads)
    }

    /// Like [`Problem::add_residual_block`] for a block that is already shared.
    pub fn add_shared_residual_block(
        &mut self,
        pairs_with: VarId,
        block: Arc<dyn ResidualBlock>,
        reads: &[VarId],
    ) -> Result<ResId, ModelError> {
        let name = block.name().to_string();
        let var = self
            .vars
            .get(pairs_with.0)
            .ok_or_else(|| ModelError::InvalidBlock {
                block: name.clone(),
                reason: format!("paired with unknown variable block #{}", pairs_with.0),
            })?;
        if var.size() != block.num_residuals() {
            return Err(ModelError::SizeMismatch {
                residual: name,
                variable: var.name().to_string(),
                residual_size: block.num_residuals(),
                variable_size: var.size(),
            });
        }
        let sizes = block.parameter_sizes();
        if sizes.len() != reads.len() {
            return Err(ModelError::InvalidBlock {
                block: name,
                reason: format!(
                    "declares {} parameter blocks but {} were bound",
                    sizes.len(),
                    reads.len()
                ),
            });
        }
        for (k, (&s, r)) in sizes.iter().zip(reads).enumerate() {
            let v = self.vars.get(r.0).ok_or_else(|| ModelError::InvalidBlock {
                block: name.clone(),
                reason: format!("parameter {k} bound to unknown variable block #{}", r.0),
            })?;
            if v.size() != s {
                return Err(ModelError::InvalidBlock {
                    block: name.clone(),
                    reason: format!(
                        "parameter {k} has size {s} but variable block '{}' has size {}",
                        v.name(),
                        v.size()
                    ),
                });
            }
            if reads[..k].contains(r) {
                return Err(ModelError::InvalidBlock {
                    block: name.clone(),
                    reason: format!("variable block '{}' is bound twice", v.name()),
                });
            }
        }
        self.residuals.push(PendingResidual {
            block,
            pairs_with,
            reads: reads.to_vec(),
        });
        Ok(ResId(self.residuals.len() - 1))
    }

    /// Checks the pairing (every variable block paired exactly once) and assembles the MCP:
    /// flat layout, bounds, sparsity pattern and the Jacobian scatter map.
    pub fn build(self) -> Result<BlockMcp, ModelError> {
        for v in &self.vars {
            v.validate()?;
        }
        let mut offsets = Vec::with_capacity(self.vars.len());
        let mut n = 0;
        for v in &self.vars {
            offsets.push(n);
            n += v.size();
        }
        let mut paired: Vec<Option<usize>> = vec![None; self.vars.len()];
        for (r, res) in self.residuals.iter().enumerate() {
            if let Some(prev) = paired[res.pairs_with.0] {
                return Err(ModelError::Pairing(format!(
                    "variable block '{}' is paired with both '{}' and '{}'",
                    self.vars[res.pairs_with.0].name(),
                    self.residuals[prev].block.name(),
                    res.block.name()
                )));
            }
            paired[res.pairs_with.0] = Some(r);
        }
        if let Some(v) = paired.iter().position(Option::is_none) {
            return Err(ModelError::Pairing(format!(
                "variable block '{}' has no residual block paired with it",
                self.vars[v].name()
            )));
        }

        // Rows of F are ordered like the variables: the residual paired with block V
        // occupies V's range, so F_i pairs with z_i.
        let mut columns: Vec<Vec<usize>> = vec![Vec::new(); n];
        for res in &self.residuals {
            let r0 = offsets[res.pairs_with.0];
            let m = res.block.num_residuals();
            for v in &res.reads {
                let c0 = offsets[v.0];
                for col in &mut columns[c0..c0 + self.vars[v.0].size()] {
                    col.extend(r0..r0 + m);
                }
            }
        }
        let pattern = CscPattern::from_columns(n, columns)?;

        let mut blocks = Vec::with_capacity(self.residuals.len());
        for res in self.residuals {
            let r0 = offsets[res.pairs_with.0];
            let rows = res.block.num_residuals();
            let mut ranges = Vec::with_capacity(res.reads.len());
            let mut col_pos = Vec::new();
            let mut block_start = vec![0];
            for v in &res.reads {
                let c0 = offsets[v.0];
                let size = self.vars[v.0].size();
                ranges.push((c0, size));
                for c in c0..c0 + size {
                    let p = pattern.position(r0, c).ok_or_else(|| {
                        ModelError::Pattern(format!("internal: entry ({r0}, {c}) missing"))
                    })?;
                    col_pos.push(p);
                }
                block_start.push(col_pos.len());
            }
            blocks.push(AssembledBlock {
                block: res.block,
                row0: r0,
                rows,
                ranges,
                col_pos,
                block_start,
            });
        }

        let mut lower = Vec::with_capacity(n);
        let mut upper = Vec::with_capacity(n);
        for v in &self.vars {
            for b in v.bounds() {
                lower.push(b.lower);
                upper.push(b.upper);
            }
        }
        Ok(BlockMcp {
            n,
            lower,
            upper,
            vars: self.vars,
            offsets,
            blocks,
            pattern: Arc::new(pattern),
        })
    }
}

struct AssembledBlock {
    block: Arc<dyn ResidualBlock>,
    row0: usize,
    rows: usize,
    ranges: Vec<(usize, usize)>,
    col_pos: Vec<usize>,
    block_start: Vec<usize>,
}

/// An MCP assembled from blocks: one flat layout, bounds, `F` and a sparse `J`.
pub struct BlockMcp {
    n: usize,
    lower: Vec<f64>,
    upper: Vec<f64>,
    vars: Vec<VarBlock>,
    offsets: Vec<usize>,
    blocks: Vec<AssembledBlock>,
    pattern: Arc<CscPattern>,
}

impl BlockMcp {
    /// Offset of a variable block in the flat layout.
    pub fn offset(&self, v: VarId) -> usize {
        self.offsets[v.0]
    }
    /// The range of a variable block in the flat layout.
    pub fn range(&self, v: VarId) -> std::ops::Range<usize> {
        let o = self.offsets[v.0];
        o..o + self.vars[v.0].size()
    }
    /// The variable blocks, in layout order.
    pub fn variable_blocks(&self) -> &[VarBlock] {
        &self.vars
    }
    /// Number of residual blocks.
    pub fn num_residual_blocks(&self) -> usize {
        self.blocks.len()
    }
    /// Residual block `r`, the variable blocks it reads and its row range.
    pub fn residual_block(&self, r: ResId) -> (&dyn ResidualBlock, &[(usize, usize)], usize) {
        let b = &self.blocks[r.0];
        (b.block.as_ref(), &b.ranges, b.row0)
    }
    /// Replaces residual block `r` by another with the same shape (rows and parameter sizes),
    /// keeping the layout, the sparsity pattern and hence every solver's symbolic analysis.
    ///
    /// This is how a time stepper updates per-step data (start-of-step state, loads) without
    /// rebuilding the problem.
    pub fn replace_residual_block(
        &mut self,
        r: ResId,
        block: Arc<dyn ResidualBlock>,
    ) -> Result<(), ModelError> {
        let old = self
            .blocks
            .get_mut(r.0)
            .ok_or_else(|| ModelError::InvalidBlock {
                block: block.name().to_string(),
                reason: format!("no residual block #{} to replace", r.0),
            })?;
        if old.block.num_residuals() != block.num_residuals()
            || old.block.parameter_sizes() != block.parameter_sizes()
        {
            return Err(ModelError::InvalidBlock {
                block: block.name().to_string(),
                reason: format!(
                    "replacement has shape {}×{:?}, the original '{}' has {}×{:?}",
                    block.num_residuals(),
                    block.parameter_sizes(),
                    old.block.name(),
                    old.block.num_residuals(),
                    old.block.parameter_sizes()
                ),
            });
        }
        old.block = block;
        Ok(())
    }

    /// Assembles `∂F/∂θ` at `z` for a vector θ of `p` model parameters (the data of the residual
    /// blocks, [`ResidualBlock::num_data`]): `column(r, k)` names the entry of θ that datum `k`
    /// of residual block `r` is, or `None` when that datum is not differentiated. Several data
    /// may map to the same entry (a shared coefficient such as μ); their derivatives add up.
    ///
    /// `out` is the dense `n × p` matrix, column-major, overwritten. An entry of `column` out of
    /// range is an error (nothing is written).
    pub fn data_jacobian(
        &self,
        z: &[f64],
        p: usize,
        column: &dyn Fn(ResId, usize) -> Option<usize>,
        out: &mut [f64],
    ) -> Result<(), ModelError> {
        if z.len() != self.n || out.len() != self.n * p {
            return Err(ModelError::Dimension(format!(
                "data_jacobian: z has {} entries (problem: {}), out has {} (needs {} × {})",
                z.len(),
                self.n,
                out.len(),
                self.n,
                p
            )));
        }
        // Validate the map first, so a bad map leaves `out` untouched.
        for (r, b) in self.blocks.iter().enumerate() {
            for k in 0..b.block.num_data() {
                if let Some(c) = column(ResId(r), k)
                    && c >= p
                {
                    return Err(ModelError::Dimension(format!(
                        "data_jacobian: datum '{}' of block '{}' maps to column {c}, but θ has {p} entries",
                        b.block.data_name(k),
                        b.block.name()
                    )));
                }
            }
        }
        out.fill(0.0);
        let mut local = Vec::new();
        for (r, b) in self.blocks.iter().enumerate() {
            let nd = b.block.num_data();
            if nd == 0 {
                continue;
            }
            local.clear();
            local.resize(b.rows * nd, 0.0);
            let mut jac = DataJacobian::new(&mut local, b.rows, nd);
            b.block.data_jacobian(Params::new(z, &b.ranges), &mut jac);
            for k in 0..nd {
                if let Some(c) = column(ResId(r), k) {
                    let dst = &mut out[c * self.n + b.row0..c * self.n + b.row0 + b.rows];
                    for (d, v) in dst.iter_mut().zip(&local[k * b.rows..(k + 1) * b.rows]) {
                        *d += v;
                    }
                }
            }
        }
        Ok(())
    }

    /// Parameter slices of residual block `r` at `z`, for the Jacobian checker.
    pub fn residual_block_params<'a>(&'a self, r: ResId, z: &'a [f64]) -> Params<'a> {
        Params::new(z, &self.blocks[r.0].ranges)
    }
}

impl Mcp for BlockMcp {
    fn dim(&self) -> usize {
        self.n
    }
    fn lower(&self) -> &[f64] {
        &self.lower
    }
    fn upper(&self) -> &[f64] {
        &self.upper
    }
    fn evaluate(&self, z: &[f64], f: &mut [f64]) {
        for b in &self.blocks {
            b.block
                .evaluate(Params::new(z, &b.ranges), &mut f[b.row0..b.row0 + b.rows]);
        }
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        &self.pattern
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        values.fill(0.0);
        for b in &self.blocks {
            let mut jac = JacobianBlocks::new(values, &b.col_pos, &b.block_start, b.rows);
            b.block.jacobian(Params::new(z, &b.ranges), &mut jac);
        }
    }
    fn evaluate_with_jacobian(&self, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        values.fill(0.0);
        for b in &self.blocks {
            let mut jac = JacobianBlocks::new(values, &b.col_pos, &b.block_start, b.rows);
            b.block.evaluate_with_jacobian(
                Params::new(z, &b.ranges),
                &mut f[b.row0..b.row0 + b.rows],
                &mut jac,
            );
        }
    }
    fn component_name(&self, i: usize) -> String {
        // Offsets are sorted; find the block containing i.
        let v = self.offsets.partition_point(|&o| o <= i).saturating_sub(1);
        match self.vars.get(v) {
            Some(block) => block.component_name(i - self.offsets[v]),
            None => format!("z[{i}]"),
        }
    }
}
