//! The handles a formulation publishes for the step problem it built: what the driver, user
//! forces and terms ([`super::terms`]), parameters ([`super::params`]) and the step
//! sensitivities bind to.

use ecp_model::{DataId, ResId, VarId};

use crate::blocks::BodyDataIds;

/// The handles of one body.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BodyHandles {
    /// The end-of-step generalised velocity `ν = (v, ω)` (6, world frame), if an unknown.
    pub nu: Option<VarId>,
    /// The end-of-step configuration `q = (x, Q)` (7), if an unknown.
    pub q: Option<VarId>,
    /// The body's Newton–Euler rows (paired with `nu`), which user forces add to.
    pub newton_euler: Option<ResId>,
    /// The body's data blocks (mass, inertia, start state, applied wrench), if the step problem
    /// reads them (`docs/model.md#data-blocks`).
    pub data: Option<BodyDataIds>,
}

/// The unknowns of one contact, as the step sensitivities need them: a contact whose normal
/// impulse is at its bound 0 has its friction unknowns held and its geometry solved separately
/// (`docs/fitting.md`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ContactHandles {
    /// The body.
    pub body: usize,
    /// The normal impulse `p_n ≥ 0` (1).
    pub normal: VarId,
    /// The friction unknowns (impulses and slip rate σ).
    pub friction: Vec<VarId>,
    /// The closest-point unknowns (ECPs and multipliers; empty for fixed contact points).
    pub geometry: Vec<VarId>,
}

/// The handles of a step problem.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StepHandles {
    /// One per body of the scene, in order.
    pub bodies: Vec<BodyHandles>,
    /// The `gravity` data block (3), if read.
    pub gravity: Option<DataId>,
    /// The `h` data block (1): the span length, if read.
    pub h: Option<DataId>,
    /// The `friction` data block (4: μ, e_t, e_o, e_r), if read.
    pub friction: Option<DataId>,
    /// The contacts, in the order of the records.
    pub contacts: Vec<ContactHandles>,
}

impl StepHandles {
    /// Handles of body `b`, if the scene has it.
    pub fn body(&self, b: usize) -> Option<&BodyHandles> {
        self.bodies.get(b)
    }
}
