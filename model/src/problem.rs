//! The problem builder: variable blocks paired with residual blocks, data blocks they read, and
//! terms added to paired rows, assembled into one MCP.

use std::sync::{Arc, Mutex, PoisonError};

use crate::bounds::VarBlock;
pub use crate::bounds::VarId;
use crate::data::{DataBlock, DataId, Input, IntoInputs};
use crate::error::ModelError;
use crate::mcp::Mcp;
use crate::pattern::CscPattern;
use crate::residual::{InputKind, InputRange, JacobianBlocks, Params, ResidualBlock};

/// Handle of a residual block (paired or a term) inside a [`Problem`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ResId(pub usize);

struct PendingResidual {
    block: Arc<dyn ResidualBlock>,
    /// The variable block whose rows this block provides (paired) or adds to (term).
    rows_of: VarId,
    reads: Vec<Input>,
    term: bool,
}

/// Builder of a block-structured MCP (`docs/model.md#mcp`, `docs/model.md#unknowns`): variable
/// blocks, each paired with one residual block of the same length, the data blocks residual
/// blocks read ([`crate::data`]), and terms adding rows to paired blocks ([`Problem::add_term`]).
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
    data: Vec<DataBlock>,
    residuals: Vec<PendingResidual>,
    groups: Vec<Vec<VarId>>,
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

    /// Marks variable blocks whose unknowns (with their paired rows) a linear solver may
    /// eliminate first ([`Mcp::elimination_groups`]): a body's `ν` and `q`. A block belongs to
    /// one group at most (checked when the problem is built).
    pub fn add_elimination_group(&mut self, vars: &[VarId]) {
        self.groups.push(vars.to_vec());
    }

    /// Adds a data block (model parameters residual blocks read, [`crate::data`]); its values
    /// are checked (finite) when the problem is built, and may change afterwards with
    /// [`BlockMcp::set_data`].
    pub fn add_data_block(&mut self, block: DataBlock) -> DataId {
        self.data.push(block);
        DataId(self.data.len() - 1)
    }

    /// Adds a residual block paired with the variable block `pairs_with` (same length), reading
    /// the inputs `reads` (variable blocks, or [`Input`]s mixing variable and data blocks) in the
    /// order of its `parameter_sizes`.
    pub fn add_residual_block(
        &mut self,
        pairs_with: VarId,
        block: impl ResidualBlock + 'static,
        reads: impl IntoInputs,
    ) -> Result<ResId, ModelError> {
        self.add_shared_residual_block(pairs_with, Arc::new(block), reads)
    }

    /// Like [`Problem::add_residual_block`] for a block that is already shared.
    pub fn add_shared_residual_block(
        &mut self,
        pairs_with: VarId,
        block: Arc<dyn ResidualBlock>,
        reads: impl IntoInputs,
    ) -> Result<ResId, ModelError> {
        self.push(pairs_with, block, reads.into_inputs(), false)
    }

    /// Adds a **term**: a residual block whose rows are added to those of the residual block
    /// paired with `adds_to` (same length). Any number of terms may add to a variable block's
    /// rows; the pairing (one paired block per variable block) is unchanged. This is how a model
    /// adds a force to a body's Newton–Euler rows.
    ///
    /// ```
    /// use ecp_model::*;
    ///
    /// /// r(x) = x − 1.
    /// struct Shift;
    /// impl ResidualBlock for Shift {
    ///     fn name(&self) -> &str { "shift" }
    ///     fn num_residuals(&self) -> usize { 1 }
    ///     fn parameter_sizes(&self) -> &[usize] { &[1] }
    ///     fn evaluate(&self, x: Params<'_>, out: &mut [f64]) { out[0] = x.block(0)[0] - 1.0; }
    ///     fn jacobian(&self, _x: Params<'_>, jac: &mut JacobianBlocks<'_>) { jac.set(0, 0, 0, 1.0); }
    /// }
    /// /// A spring term −k x with stiffness k a data block.
    /// struct Spring;
    /// impl ResidualBlock for Spring {
    ///     fn name(&self) -> &str { "spring" }
    ///     fn num_residuals(&self) -> usize { 1 }
    ///     fn parameter_sizes(&self) -> &[usize] { &[1, 1] }
    ///     fn evaluate(&self, p: Params<'_>, out: &mut [f64]) { out[0] = -p.block(1)[0] * p.block(0)[0]; }
    ///     fn jacobian(&self, p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
    ///         jac.set(0, 0, 0, -p.block(1)[0]);
    ///         jac.set(1, 0, 0, -p.block(0)[0]);
    ///     }
    /// }
    ///
    /// let mut p = Problem::new();
    /// let x = p.add_variable_block(VarBlock::free("x", 1));
    /// let k = p.add_data_block(DataBlock::new("k", [3.0]));
    /// p.add_residual_block(x, Shift, &[x]).unwrap();
    /// p.add_term(x, Spring, &[Input::from(x), Input::from(k)]).unwrap();
    /// let mcp = p.build().unwrap();
    /// let mut f = [0.0];
    /// mcp.evaluate(&[2.0], &mut f);
    /// assert_eq!(f[0], (2.0 - 1.0) - 3.0 * 2.0);
    /// ```
    pub fn add_term(
        &mut self,
        adds_to: VarId,
        block: impl ResidualBlock + 'static,
        reads: impl IntoInputs,
    ) -> Result<ResId, ModelError> {
        self.add_shared_term(adds_to, Arc::new(block), reads)
    }

    /// Like [`Problem::add_term`] for a block that is already shared.
    pub fn add_shared_term(
        &mut self,
        adds_to: VarId,
        block: Arc<dyn ResidualBlock>,
        reads: impl IntoInputs,
    ) -> Result<ResId, ModelError> {
        self.push(adds_to, block, reads.into_inputs(), true)
    }

    fn push(
        &mut self,
        rows_of: VarId,
        block: Arc<dyn ResidualBlock>,
        reads: Vec<Input>,
        term: bool,
    ) -> Result<ResId, ModelError> {
        let name = block.name().to_string();
        let var = self
            .vars
            .get(rows_of.0)
            .ok_or_else(|| ModelError::InvalidBlock {
                block: name.clone(),
                reason: format!(
                    "{} unknown variable block #{}",
                    if term { "adds to" } else { "paired with" },
                    rows_of.0
                ),
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
                    "declares {} inputs but {} were bound",
                    sizes.len(),
                    reads.len()
                ),
            });
        }
        for (k, (&s, r)) in sizes.iter().zip(&reads).enumerate() {
            let (what, input_name, size) = match *r {
                Input::Var(v) => {
                    let b = self.vars.get(v.0).ok_or_else(|| ModelError::InvalidBlock {
                        block: name.clone(),
                        reason: format!("input {k} bound to unknown variable block #{}", v.0),
                    })?;
                    ("variable", b.name(), b.size())
                }
                Input::Data(d) => {
                    let b = self.data.get(d.0).ok_or_else(|| ModelError::InvalidBlock {
                        block: name.clone(),
                        reason: format!("input {k} bound to unknown data block #{}", d.0),
                    })?;
                    ("data", b.name(), b.size())
                }
            };
            if size != s {
                return Err(ModelError::InvalidBlock {
                    block: name.clone(),
                    reason: format!(
                        "input {k} has size {s} but {what} block '{input_name}' has size {size}"
                    ),
                });
            }
            if reads[..k].contains(r) {
                return Err(ModelError::InvalidBlock {
                    block: name.clone(),
                    reason: format!("{what} block '{input_name}' is bound twice"),
                });
            }
        }
        self.residuals.push(PendingResidual {
            block,
            rows_of,
            reads,
            term,
        });
        Ok(ResId(self.residuals.len() - 1))
    }

    /// Checks the pairing (every variable block paired exactly once) and the data, and
    /// assembles the MCP: flat layout, bounds, sparsity pattern (terms included) and the
    /// Jacobian scatter map.
    pub fn build(self) -> Result<BlockMcp, ModelError> {
        for v in &self.vars {
            v.validate()?;
        }
        for d in &self.data {
            d.validate()?;
        }
        let mut offsets = Vec::with_capacity(self.vars.len());
        let mut n = 0;
        for v in &self.vars {
            offsets.push(n);
            n += v.size();
        }
        let mut data_offsets = Vec::with_capacity(self.data.len());
        let mut data_values = Vec::new();
        for d in &self.data {
            data_offsets.push(data_values.len());
            data_values.extend_from_slice(d.values());
        }
        let mut paired: Vec<Option<usize>> = vec![None; self.vars.len()];
        for (r, res) in self.residuals.iter().enumerate().filter(|(_, r)| !r.term) {
            if let Some(prev) = paired[res.rows_of.0] {
                return Err(ModelError::Pairing(format!(
                    "variable block '{}' is paired with both '{}' and '{}'; add extra rows with \
                     Problem::add_term",
                    self.vars[res.rows_of.0].name(),
                    self.residuals[prev].block.name(),
                    res.block.name()
                )));
            }
            paired[res.rows_of.0] = Some(r);
        }
        if let Some(v) = paired.iter().position(Option::is_none) {
            return Err(ModelError::Pairing(format!(
                "variable block '{}' has no residual block paired with it",
                self.vars[v].name()
            )));
        }

        // Rows of F are ordered like the variables: the residual paired with block V (and every
        // term adding to it) occupies V's range, so F_i pairs with z_i. Data inputs have no
        // columns: they never change the pattern.
        let mut columns: Vec<Vec<usize>> = vec![Vec::new(); n];
        for res in &self.residuals {
            let r0 = offsets[res.rows_of.0];
            let m = res.block.num_residuals();
            for input in &res.reads {
                if let Input::Var(v) = input {
                    let c0 = offsets[v.0];
                    for col in &mut columns[c0..c0 + self.vars[v.0].size()] {
                        col.extend(r0..r0 + m);
                    }
                }
            }
        }
        let pattern = CscPattern::from_columns(n, columns)?;

        let mut blocks = Vec::with_capacity(self.residuals.len());
        for res in self.residuals {
            let r0 = offsets[res.rows_of.0];
            let rows = res.block.num_residuals();
            let mut ranges = Vec::with_capacity(res.reads.len());
            let mut col_pos = Vec::new();
            let mut block_start = vec![0];
            for input in &res.reads {
                match *input {
                    Input::Var(v) => {
                        let c0 = offsets[v.0];
                        let size = self.vars[v.0].size();
                        ranges.push(InputRange::var(c0, size));
                        for c in c0..c0 + size {
                            let p = pattern.position(r0, c).ok_or_else(|| {
                                ModelError::Pattern(format!("internal: entry ({r0}, {c}) missing"))
                            })?;
                            col_pos.push(p);
                        }
                    }
                    Input::Data(d) => {
                        let size = self.data[d.0].size();
                        ranges.push(InputRange::data(data_offsets[d.0], size));
                        col_pos.extend(std::iter::repeat_n(JacobianBlocks::DISCARD, size));
                    }
                }
                block_start.push(col_pos.len());
            }
            let discards = col_pos.contains(&JacobianBlocks::DISCARD);
            let (constant, constant_pos, varying_pos) = if res.term {
                (Constancy::None, Vec::new(), Vec::new())
            } else {
                constant_columns(res.block.as_ref(), &res.reads, &col_pos, &block_start)
            };
            let constant_cols = constant_pos
                .iter()
                .copied()
                .filter(|&p| p != JacobianBlocks::DISCARD)
                .collect();
            blocks.push(AssembledBlock {
                discards,
                constant,
                constant_cols,
                constant_pos,
                varying_pos,
                block: res.block,
                rows_of: res.rows_of,
                row0: r0,
                rows,
                inputs: res.reads,
                ranges,
                col_pos,
                block_start,
                term: res.term,
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
        let has_terms = blocks.iter().any(|b| b.term);
        let mut grouped = vec![false; self.vars.len()];
        let mut groups = Vec::with_capacity(self.groups.len());
        for group in &self.groups {
            let mut indices = Vec::new();
            for v in group {
                match grouped.get_mut(v.0) {
                    Some(g) if !*g => *g = true,
                    _ => {
                        return Err(ModelError::Pairing(format!(
                            "variable block {} is in two elimination groups or does not exist",
                            v.0
                        )));
                    }
                }
                indices.extend(offsets[v.0]..offsets[v.0] + self.vars[v.0].size());
            }
            groups.push(indices);
        }
        // The paired blocks whose constant Jacobian entries read each data block.
        let mut constant_readers = vec![Vec::new(); self.data.len()];
        for (i, b) in blocks.iter().enumerate() {
            if b.constant == Constancy::None {
                continue;
            }
            for k in 0..b.inputs.len() {
                if b.constant_pos[b.block_start[k]..b.block_start[k + 1]]
                    .first()
                    .is_none_or(|&p| p == JacobianBlocks::DISCARD)
                {
                    continue;
                }
                for &l in b.block.jacobian_depends_on(k).unwrap_or(&[]) {
                    if let Some(Input::Data(d)) = b.inputs.get(l)
                        && constant_readers[d.0].last() != Some(&i)
                    {
                        constant_readers[d.0].push(i);
                    }
                }
            }
        }
        let has_constants = blocks.iter().any(|b| b.constant != Constancy::None);
        let constant = ConstantJacobian {
            values: vec![0.0; if has_constants { pattern.nnz() } else { 0 }],
            stale: blocks
                .iter()
                .map(|b| b.constant != Constancy::None)
                .collect(),
            any_stale: has_constants,
        };
        Ok(BlockMcp {
            n,
            lower,
            upper,
            constant: Mutex::new(constant),
            constant_readers,
            has_constants,
            vars: self.vars,
            offsets,
            data: self.data,
            data_offsets,
            data_values,
            blocks,
            has_terms,
            pattern: Arc::new(pattern),
            groups,
        })
    }
}

/// Which of a paired block's variable inputs have a Jacobian that is constant while the data are
/// ([`ResidualBlock::jacobian_depends_on`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Constancy {
    /// None: the block writes its whole Jacobian at every point.
    None,
    /// Some: the others are written at every point.
    Some,
    /// All: the block's Jacobian is the template's.
    All,
}

/// The constant entries of a block's Jacobian: its inputs `k` whose
/// [`ResidualBlock::jacobian_depends_on`] lists data inputs only.
/// Returns the constancy, the column positions of the constant inputs (the others discarded)
/// and those of the varying ones (the constant ones discarded).
fn constant_columns(
    block: &dyn ResidualBlock,
    reads: &[Input],
    col_pos: &[usize],
    block_start: &[usize],
) -> (Constancy, Vec<usize>, Vec<usize>) {
    // (A variable block is bound to one input of a block at most, `Problem::add_residual_block`:
    // no other input's writes land on a constant input's entries.)
    let is_constant = |k: usize| {
        matches!(reads[k], Input::Var(_))
            && block.jacobian_depends_on(k).is_some_and(|deps| {
                deps.iter()
                    .all(|&l| matches!(reads.get(l), Some(Input::Data(_))))
            })
    };
    let constant: Vec<bool> = (0..reads.len()).map(is_constant).collect();
    let variables = reads.iter().filter(|r| matches!(r, Input::Var(_))).count();
    let count = constant.iter().filter(|&&c| c).count();
    if count == 0 {
        return (Constancy::None, Vec::new(), Vec::new());
    }
    let mut constant_pos = Vec::with_capacity(col_pos.len());
    let mut varying_pos = Vec::with_capacity(col_pos.len());
    for (k, &c) in constant.iter().enumerate() {
        for &p in &col_pos[block_start[k]..block_start[k + 1]] {
            let (keep, drop) = if c {
                (&mut constant_pos, &mut varying_pos)
            } else {
                (&mut varying_pos, &mut constant_pos)
            };
            keep.push(p);
            drop.push(JacobianBlocks::DISCARD);
        }
    }
    let constancy = if count == variables {
        Constancy::All
    } else {
        Constancy::Some
    };
    (constancy, constant_pos, varying_pos)
}

/// Zeroes `rows` entries from each position of `cols`. The columns are short (a block's rows),
/// so the common lengths are zeroed by stores of a known size rather than a `memset` call each.
fn zero_columns(values: &mut [f64], cols: &[usize], rows: usize) {
    fn zero<const N: usize>(values: &mut [f64], cols: &[usize]) {
        for &p in cols {
            values[p..p + N].copy_from_slice(&[0.0; N]);
        }
    }
    match rows {
        1 => zero::<1>(values, cols),
        3 => zero::<3>(values, cols),
        6 => zero::<6>(values, cols),
        7 => zero::<7>(values, cols),
        _ => {
            for &p in cols {
                values[p..p + rows].fill(0.0);
            }
        }
    }
}

/// The constant entries of the MCP Jacobian at the problem's data, and zeros elsewhere: what
/// [`Mcp::jacobian`] starts from instead of zeroing the values.
struct ConstantJacobian {
    values: Vec<f64>,
    /// Per residual block: its constant entries are to be written again (its data changed).
    stale: Vec<bool>,
    any_stale: bool,
}

struct AssembledBlock {
    block: Arc<dyn ResidualBlock>,
    rows_of: VarId,
    row0: usize,
    rows: usize,
    inputs: Vec<Input>,
    ranges: Vec<InputRange>,
    /// Positions in the sparse Jacobian of each input column; data columns are discarded.
    col_pos: Vec<usize>,
    block_start: Vec<usize>,
    /// Whether the block has data inputs (whose columns `col_pos` discards).
    discards: bool,
    /// Which variable inputs have a constant Jacobian ([`ResidualBlock::jacobian_depends_on`]).
    constant: Constancy,
    /// `col_pos` with only the constant inputs' columns (empty without any).
    constant_pos: Vec<usize>,
    /// The stored columns of `constant_pos` (its positions that are not discarded).
    constant_cols: Vec<usize>,
    /// `col_pos` without the constant inputs' columns (empty without any).
    varying_pos: Vec<usize>,
    term: bool,
}

impl AssembledBlock {
    /// Write access to this block's entries of the sparse MCP Jacobian `values`.
    #[inline]
    fn sparse<'a>(&'a self, values: &'a mut [f64]) -> JacobianBlocks<'a> {
        JacobianBlocks::with_discards(
            values,
            &self.col_pos,
            &self.block_start,
            self.rows,
            self.discards,
        )
    }

    /// Write access to this block's varying entries (not the constant ones, which the values
    /// hold from the template) when `templated`, else to all of them.
    #[inline]
    fn varying<'a>(&'a self, values: &'a mut [f64], templated: bool) -> JacobianBlocks<'a> {
        if templated && self.constant == Constancy::Some {
            JacobianBlocks::with_discards(
                values,
                &self.varying_pos,
                &self.block_start,
                self.rows,
                true,
            )
        } else {
            self.sparse(values)
        }
    }

    /// Number of variable columns (the width of a term's local Jacobian).
    fn var_cols(&self) -> usize {
        self.ranges
            .iter()
            .filter(|r| r.kind == InputKind::Variable)
            .map(|r| r.len)
            .sum()
    }

    /// Evaluates a term and adds its rows to `f`.
    fn add_term_rows(&self, params: Params<'_>, f: &mut [f64]) {
        let mut local = vec![0.0; self.rows];
        self.block.evaluate(params, &mut local);
        for (d, v) in f[self.row0..self.row0 + self.rows].iter_mut().zip(&local) {
            *d += v;
        }
    }

    /// Computes a term's variable Jacobian in a local buffer and adds it into the sparse
    /// `values`: the entries it shares with the paired block must add, not overwrite.
    fn add_term_jacobian(&self, params: Params<'_>, values: &mut [f64]) {
        let m = self.rows;
        let mut local_pos = Vec::with_capacity(self.col_pos.len());
        let mut scatter = Vec::new();
        for &p in &self.col_pos {
            if p == JacobianBlocks::DISCARD {
                local_pos.push(JacobianBlocks::DISCARD);
            } else {
                local_pos.push(scatter.len() * m);
                scatter.push(p);
            }
        }
        let mut local = vec![0.0; self.var_cols() * m];
        {
            let mut jac = JacobianBlocks::new(&mut local, &local_pos, &self.block_start, m);
            self.block.jacobian(params, &mut jac);
        }
        for (c, &p) in scatter.iter().enumerate() {
            for (d, v) in values[p..p + m].iter_mut().zip(&local[c * m..(c + 1) * m]) {
                *d += v;
            }
        }
    }
}

/// The bookkeeping of [`BlockMcp::data_jacobian_with`], kept between calls.
#[derive(Clone, Debug, Default)]
pub struct DataJacobianWork {
    /// Column of the first entry of each data block, if wanted.
    column: Vec<Option<usize>>,
    /// A term's local dense rows.
    local: Vec<f64>,
    /// A block's column positions.
    positions: Vec<usize>,
    /// A term's local columns' columns of θ.
    scatter: Vec<usize>,
}

/// An MCP assembled from blocks: one flat layout, bounds, `F` and a sparse `J`, and the data
/// blocks its residual blocks read.
pub struct BlockMcp {
    n: usize,
    lower: Vec<f64>,
    upper: Vec<f64>,
    vars: Vec<VarBlock>,
    offsets: Vec<usize>,
    data: Vec<DataBlock>,
    data_offsets: Vec<usize>,
    data_values: Vec<f64>,
    blocks: Vec<AssembledBlock>,
    has_terms: bool,
    /// The constant Jacobian entries at the problem's data ([`ResidualBlock::jacobian_depends_on`]),
    /// written again after a change of the data they read; a lock only because `jacobian`
    /// takes `&self` (never waited for: a held lock means the plain path).
    constant: Mutex<ConstantJacobian>,
    /// Per data block: the residual blocks whose constant entries read it.
    constant_readers: Vec<Vec<usize>>,
    /// Whether some block has constant entries.
    has_constants: bool,
    pattern: Arc<CscPattern>,
    /// [`Mcp::elimination_groups`], as index lists.
    groups: Vec<Vec<usize>>,
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
    /// The data blocks with their current values, in layout order.
    pub fn data_blocks(&self) -> &[DataBlock] {
        &self.data
    }
    /// Current values of data block `d` (empty for an unknown id).
    pub fn data(&self, d: DataId) -> &[f64] {
        self.data.get(d.0).map_or(&[], |b| b.values())
    }
    /// Every data value, the blocks laid out one after the other ([`BlockMcp::data_offset`]).
    pub fn data_values(&self) -> &[f64] {
        &self.data_values
    }
    /// Offset of data block `d` in [`BlockMcp::data_values`].
    pub fn data_offset(&self, d: DataId) -> usize {
        self.data_offsets[d.0]
    }
    /// Total number of data scalars.
    pub fn num_data(&self) -> usize {
        self.data_values.len()
    }

    /// Replaces the values of data block `d`: the problem, its layout and its sparsity pattern
    /// are unchanged, so every backend's symbolic analysis stays valid. An unknown id, a wrong
    /// length or a value that is not finite is an error, and nothing changes.
    pub fn set_data(&mut self, d: DataId, values: &[f64]) -> Result<(), ModelError> {
        let block = self
            .data
            .get_mut(d.0)
            .ok_or_else(|| ModelError::InvalidBlock {
                block: format!("data #{}", d.0),
                reason: format!(
                    "no such data block: this problem has {} data blocks",
                    self.data_offsets.len()
                ),
            })?;
        block.check_values(values)?;
        block.set_values(values);
        let o = self.data_offsets[d.0];
        let old = &mut self.data_values[o..o + values.len()];
        let changed = !old
            .iter()
            .zip(values)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        old.copy_from_slice(values);
        if changed && !self.constant_readers[d.0].is_empty() {
            let constant = self
                .constant
                .get_mut()
                .unwrap_or_else(PoisonError::into_inner);
            for &b in &self.constant_readers[d.0] {
                constant.stale[b] = true;
            }
            constant.any_stale = true;
        }
        Ok(())
    }

    /// Starts the MCP Jacobian `values` at `z` with data `data`: the constant entries from the
    /// template (written again first where their data changed) and zeros elsewhere, when `data`
    /// are the problem's own; otherwise zeros. Returns whether the template was used (then the
    /// blocks write only their varying entries: the same bits, as the constant ones do not
    /// depend on `z`).
    #[inline]
    fn start_jacobian(&self, data: &[f64], z: &[f64], values: &mut [f64]) -> bool {
        if self.has_constants
            && std::ptr::eq(data, self.data_values.as_slice())
            && values.len() == self.pattern.nnz()
            && let Ok(mut constant) = self.constant.try_lock()
        {
            if constant.any_stale {
                self.write_constant_entries(&mut constant, z);
            }
            values.copy_from_slice(&constant.values);
            return true;
        }
        values.fill(0.0);
        false
    }

    /// Writes the constant entries of the stale blocks into the template, as `jacobian` would
    /// write them at `z` (from zero, asked for those inputs only).
    #[cold]
    fn write_constant_entries(&self, constant: &mut ConstantJacobian, z: &[f64]) {
        let ConstantJacobian {
            values,
            stale,
            any_stale,
        } = constant;
        for (b, stale) in self.blocks.iter().zip(stale.iter_mut()) {
            if !*stale {
                continue;
            }
            zero_columns(values, &b.constant_cols, b.rows);
            let mut jac = JacobianBlocks::with_discards(
                values,
                &b.constant_pos,
                &b.block_start,
                b.rows,
                true,
            );
            b.block
                .jacobian(Params::new(z, &self.data_values, &b.ranges), &mut jac);
            *stale = false;
        }
        *any_stale = false;
    }

    /// Number of residual blocks (paired blocks and terms).
    pub fn num_residual_blocks(&self) -> usize {
        self.blocks.len()
    }
    /// Residual block `r`, where its inputs live and its first row.
    pub fn residual_block(&self, r: ResId) -> (&dyn ResidualBlock, &[InputRange], usize) {
        let b = &self.blocks[r.0];
        (b.block.as_ref(), &b.ranges, b.row0)
    }
    /// The inputs residual block `r` is bound to.
    pub fn residual_inputs(&self, r: ResId) -> &[Input] {
        &self.blocks[r.0].inputs
    }
    /// The variable block whose rows residual block `r` provides, and whether it is a term
    /// (adding to those rows, [`Problem::add_term`]) rather than the paired block.
    pub fn residual_rows(&self, r: ResId) -> (VarId, bool) {
        let b = &self.blocks[r.0];
        (b.rows_of, b.term)
    }
    /// Name of input `k` of residual block `r` (its variable or data block's name).
    pub fn input_name(&self, r: ResId, k: usize) -> String {
        match self.blocks[r.0].inputs[k] {
            Input::Var(v) => self.vars[v.0].name().to_string(),
            Input::Data(d) => self.data[d.0].name().to_string(),
        }
    }
    /// Name of component `j` of input `k` of residual block `r`.
    pub fn input_component_name(&self, r: ResId, k: usize, j: usize) -> String {
        match self.blocks[r.0].inputs[k] {
            Input::Var(v) => self.vars[v.0].component_name(j),
            Input::Data(d) => self.data[d.0].component_name(j),
        }
    }

    /// Assembles `∂F/∂θ` at `z` for the data blocks `wrt`: `out` is the dense `n × p` matrix,
    /// column-major, `p` the total size of `wrt` (the columns of `wrt[0]` first), overwritten.
    /// Each residual block reading one of them writes its derivatives through the same
    /// [`ResidualBlock::jacobian`] as the MCP Jacobian, asked for those data inputs only.
    ///
    /// An unknown or repeated id, or an `out` or `z` of the wrong length, is an error (nothing
    /// is written).
    pub fn data_jacobian(
        &self,
        z: &[f64],
        wrt: &[DataId],
        out: &mut [f64],
    ) -> Result<(), ModelError> {
        self.data_jacobian_with(z, wrt, out, &mut DataJacobianWork::default())
    }

    /// [`BlockMcp::data_jacobian`] with its bookkeeping in `work`, kept by the caller: no
    /// allocation once it has grown (the step sensitivities, `docs/latency.md`).
    pub fn data_jacobian_with(
        &self,
        z: &[f64],
        wrt: &[DataId],
        out: &mut [f64],
        work: &mut DataJacobianWork,
    ) -> Result<(), ModelError> {
        let DataJacobianWork {
            column,
            local,
            positions,
            scatter,
        } = work;
        // Column of the first entry of each data block, if wanted.
        column.clear();
        column.resize(self.data.len(), None);
        let mut p = 0;
        for d in wrt {
            let slot = column.get_mut(d.0).ok_or_else(|| {
                ModelError::Dimension(format!(
                    "data_jacobian: unknown data block #{} (this problem has {})",
                    d.0,
                    self.data.len()
                ))
            })?;
            if slot.is_some() {
                return Err(ModelError::Dimension(format!(
                    "data_jacobian: data block '{}' is asked for twice",
                    self.data[d.0].name()
                )));
            }
            *slot = Some(p);
            p += self.data[d.0].size();
        }
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
        out.fill(0.0);
        let wanted = |i: &Input| matches!(i, Input::Data(d) if column[d.0].is_some());
        // Paired blocks own their rows and write straight into `out` (entry (i, j) of a data
        // input at column c of θ lives at c·n + row0 + i); the terms, after them, add theirs
        // through a local buffer, as in the MCP Jacobian.
        for b in self.blocks.iter().filter(|b| !b.term) {
            if !b.inputs.iter().any(wanted) {
                continue;
            }
            positions.clear();
            for (input, range) in b.inputs.iter().zip(&b.ranges) {
                let first = match input {
                    Input::Data(d) => column[d.0],
                    Input::Var(_) => None,
                };
                positions.extend(
                    (0..range.len).map(|j| {
                        first.map_or(JacobianBlocks::DISCARD, |c| (c + j) * self.n + b.row0)
                    }),
                );
            }
            let mut jac =
                JacobianBlocks::with_discards(out, positions, &b.block_start, b.rows, true);
            b.block
                .jacobian(Params::new(z, &self.data_values, &b.ranges), &mut jac);
        }
        for b in self.blocks.iter().filter(|b| b.term) {
            if !b.inputs.iter().any(wanted) {
                continue;
            }
            // Local dense rows × (wanted data columns); `scatter` maps them to columns of θ.
            positions.clear();
            scatter.clear();
            for (input, range) in b.inputs.iter().zip(&b.ranges) {
                let first = match input {
                    Input::Data(d) => column[d.0],
                    Input::Var(_) => None,
                };
                for j in 0..range.len {
                    match first {
                        Some(c) => {
                            positions.push(scatter.len() * b.rows);
                            scatter.push(c + j);
                        }
                        None => positions.push(JacobianBlocks::DISCARD),
                    }
                }
            }
            local.clear();
            local.resize(scatter.len() * b.rows, 0.0);
            {
                let mut jac = JacobianBlocks::new(local, positions, &b.block_start, b.rows);
                b.block
                    .jacobian(Params::new(z, &self.data_values, &b.ranges), &mut jac);
            }
            for (lc, &c) in scatter.iter().enumerate() {
                let dst = &mut out[c * self.n + b.row0..c * self.n + b.row0 + b.rows];
                for (d, v) in dst.iter_mut().zip(&local[lc * b.rows..(lc + 1) * b.rows]) {
                    *d += v;
                }
            }
        }
        Ok(())
    }
    /// [`Mcp::evaluate`] with the data blocks' values `data` in place of the problem's own
    /// ([`BlockMcp::data_values`] layout): `F(z; θ)` at other data without changing the problem
    /// (a backend's continuation in a parameter, [`Mcp::friction_family`]).
    #[inline(always)]
    pub fn evaluate_with_data(&self, data: &[f64], z: &[f64], f: &mut [f64]) {
        // Paired blocks first (they own their rows), then the terms add to them.
        for b in self.blocks.iter().filter(|b| !b.term) {
            b.block.evaluate(
                Params::new(z, data, &b.ranges),
                &mut f[b.row0..b.row0 + b.rows],
            );
        }
        if self.has_terms {
            for b in self.blocks.iter().filter(|b| b.term) {
                b.add_term_rows(Params::new(z, data, &b.ranges), f);
            }
        }
    }

    /// The rows of `F` paired with variable block `v` at `z` (`f[self.range(v)]`), the rest of
    /// `f` untouched: the paired block, then the terms adding to those rows in the order
    /// [`Mcp::evaluate`] adds them, so the same bits as `evaluate` gives there (a guard that
    /// needs a few rows of `F` at a trial point, `ecp_formulations`' warm start).
    pub fn evaluate_rows_of(&self, v: VarId, z: &[f64], f: &mut [f64]) {
        let data = &self.data_values;
        for b in self.blocks.iter().filter(|b| !b.term && b.rows_of == v) {
            b.block.evaluate(
                Params::new(z, data, &b.ranges),
                &mut f[b.row0..b.row0 + b.rows],
            );
        }
        if self.has_terms {
            for b in self.blocks.iter().filter(|b| b.term && b.rows_of == v) {
                b.add_term_rows(Params::new(z, data, &b.ranges), f);
            }
        }
    }

    /// [`Mcp::evaluate_with_jacobian`] with the data blocks' values `data` in place of the
    /// problem's own, as [`BlockMcp::evaluate_with_data`].
    #[inline(always)]
    pub fn evaluate_with_jacobian_with_data(
        &self,
        data: &[f64],
        z: &[f64],
        f: &mut [f64],
        values: &mut [f64],
    ) {
        let templated = self.start_jacobian(data, z, values);
        for b in self.blocks.iter().filter(|b| !b.term) {
            let params = Params::new(z, data, &b.ranges);
            let out = &mut f[b.row0..b.row0 + b.rows];
            if templated && b.constant == Constancy::All {
                b.block.evaluate(params, out);
            } else {
                let mut jac = b.varying(values, templated);
                b.block.evaluate_with_jacobian(params, out, &mut jac);
            }
        }
        if self.has_terms {
            for b in self.blocks.iter().filter(|b| b.term) {
                let params = Params::new(z, data, &b.ranges);
                b.add_term_rows(params, f);
                b.add_term_jacobian(params, values);
            }
        }
    }

    /// Input slices of residual block `r` at `z` (variables from `z`, data from the problem).
    pub fn residual_block_params<'a>(&'a self, r: ResId, z: &'a [f64]) -> Params<'a> {
        Params::new(z, &self.data_values, &self.blocks[r.0].ranges)
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
        self.evaluate_with_data(&self.data_values, z, f)
    }
    fn jacobian_pattern(&self) -> &Arc<CscPattern> {
        &self.pattern
    }
    fn jacobian(&self, z: &[f64], values: &mut [f64]) {
        let templated = self.start_jacobian(&self.data_values, z, values);
        for b in self.blocks.iter().filter(|b| !b.term) {
            if templated && b.constant == Constancy::All {
                continue;
            }
            let mut jac = b.varying(values, templated);
            b.block
                .jacobian(Params::new(z, &self.data_values, &b.ranges), &mut jac);
        }
        if self.has_terms {
            for b in self.blocks.iter().filter(|b| b.term) {
                b.add_term_jacobian(Params::new(z, &self.data_values, &b.ranges), values);
            }
        }
    }
    fn evaluate_with_jacobian(&self, z: &[f64], f: &mut [f64], values: &mut [f64]) {
        self.evaluate_with_jacobian_with_data(&self.data_values, z, f, values)
    }
    fn component_name(&self, i: usize) -> String {
        let mut name = String::new();
        self.write_component_name(i, &mut name);
        name
    }
    fn write_component_name(&self, i: usize, out: &mut String) {
        // Offsets are sorted; find the block containing i.
        let v = self.offsets.partition_point(|&o| o <= i).saturating_sub(1);
        match self.vars.get(v) {
            Some(block) => block.write_component_name(i - self.offsets[v], out),
            None => {
                use std::fmt::Write;
                // Writing into a String cannot fail.
                _ = write!(out, "z[{i}]");
            }
        }
    }
    fn elimination_groups(&self) -> &[Vec<usize>] {
        &self.groups
    }
}
