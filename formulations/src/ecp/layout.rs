//! The layout of an ECP step problem (`docs/model.md#unknowns`): each body's and each contact's
//! unknowns, residual and data blocks, the convex set of each contact, the step problem's origin
//! and half-spaces, and the data of the span prepared last (what the structural view reads).

use std::ops::Range;

use nalgebra::Vector3;

use ecp_model::{BlockMcp, DataId, ResId, VarId};

use super::scales::BodyUnits;
use crate::blocks::{BodyDataIds, BodyStepData, ContactFrame, SceneDataIds};
use crate::geometry::{ConvexHull, HalfSpace, VertexSpacing};
use crate::scene::BodyState;

/// Handles of one contact's variable blocks.
#[derive(Clone, Copy, Debug)]
pub struct ContactVars {
    /// Body index.
    pub body: usize,
    /// Half-space index.
    pub plane: usize,
    /// The convex piece of the body this contact belongs to (union formulation,
    /// `docs/model.md#union`); `None` for the hull formulation, whose contact is Conv(F) itself.
    pub piece: Option<usize>,
    /// ECP on Conv(F).
    pub a1: VarId,
    /// ECP on G.
    pub a2: VarId,
    /// Face multipliers of Conv(F).
    pub l: VarId,
    /// Multiplier of G.
    pub lg: VarId,
    /// Normal impulse.
    pub pn: VarId,
    /// Friction impulses (p_t, p_o, p_r).
    pub pf: VarId,
    /// Slip magnitude σ.
    pub sigma: VarId,
}

/// One body of the step problem.
#[derive(Clone, Debug)]
pub(crate) struct EcpBody {
    /// Conv(F).
    pub(crate) hull: ConvexHull,
    pub(crate) nu: VarId,
    pub(crate) q: VarId,
    pub(crate) newton_euler: ResId,
    pub(crate) kinematic: ResId,
    /// The contact frame of each of the body's contacts.
    pub(crate) frames: Vec<ContactFrame>,
    /// The body's data blocks (`docs/model.md#data-blocks`).
    pub(crate) data: BodyDataIds,
    /// The body's length unit `L` of its scene scales: the diagonal of the bounding box of
    /// Conv(F) (`scales.rs`).
    pub(crate) length: f64,
    /// How far apart the body's vertices are (its contact records' merge tests).
    pub(crate) spacing: VertexSpacing,
}

/// The data of the span prepared last, as the step's blocks read them.
#[derive(Clone, Debug, Default)]
pub(crate) struct SpanData {
    /// Per body, the Newton–Euler block's data.
    pub(crate) bodies: Vec<BodyStepData>,
    /// The states at the start of the span (world frame).
    pub(crate) start: Vec<BodyState>,
    /// Start position (step coordinates) of each body, from its `start` data.
    pub(crate) start_x: Vec<Vector3<f64>>,
    /// The friction data (μ, e_t, e_o, e_r).
    pub(crate) friction: [f64; 4],
    /// The span length.
    pub(crate) h: f64,
    /// The range in `z` of every variable block, by `VarId`.
    pub(crate) ranges: Vec<Range<usize>>,
    /// Each body's rounded units (`scales.rs`; storage kept across spans), those of the scales
    /// in [`Layout::scales`].
    pub(crate) units: Vec<BodyUnits>,
}

/// The layout of an ECP step problem (module documentation).
#[derive(Clone, Debug, Default)]
pub(crate) struct Layout {
    pub(crate) bodies: Vec<EcpBody>,
    pub(crate) contacts: Vec<ContactVars>,
    /// The convex set of each contact (parallel to `contacts`): Conv(F) for the hull
    /// formulation, the piece's hull for the union formulation.
    pub(crate) contact_hulls: Vec<ConvexHull>,
    /// The scene-wide data blocks.
    pub(crate) scene_data: Option<SceneDataIds>,
    /// The offset data block of each half-space, the only data that hold an absolute position
    /// besides the bodies' start positions.
    pub(crate) plane_data: Vec<DataId>,
    /// Origin of the step problem's coordinates: positions in `z` and in the blocks are relative
    /// to it (world = origin + z).
    pub(crate) origin: Vector3<f64>,
    /// The half-spaces in the step problem's coordinates (relative to `origin`).
    pub(crate) step_planes: Vec<HalfSpace>,
    /// The span prepared last.
    pub(crate) span: SpanData,
    /// The scene scales of the span prepared last (`scales.rs`).
    pub(crate) scales: Option<ecp_model::McpScales>,
    /// [`ecp_model::McpScales::usage`] of [`Layout::scales`] for a problem of the dimension
    /// given, computed when they are filled: kept with them while they are kept.
    pub(crate) scales_usage: Option<(usize, ecp_model::ScalesUsage)>,
    /// Every contact's variable blocks were added in a row (`a1`, `a2`, `l`, `l_g`, `p_n`,
    /// `p_f`, `σ`), so they lie in a row in `z`: the warm start extrapolates them in one pass.
    pub(crate) contacts_in_order: bool,
}

impl Layout {
    /// The range of variable block `v` in `z` (from the span prepared last, else from `mcp`).
    pub(crate) fn range(&self, v: VarId) -> Range<usize> {
        self.span.ranges[v.0].clone()
    }

    /// Records the variable blocks' ranges of `mcp`.
    pub(crate) fn record_ranges(&mut self, mcp: &BlockMcp) {
        let n = mcp.variable_blocks().len();
        if self.span.ranges.len() != n {
            self.span.ranges = (0..n).map(|i| mcp.range(VarId(i))).collect();
        }
    }
}
