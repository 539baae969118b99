//! A user's own terms in the built-in step problem: generalised forces added to a body's
//! Newton–Euler rows ([`Force`]) and extra residual blocks with their own unknowns ([`Term`]).
//! Both join the step problem the formulation builds, so they keep the driver's warm start
//! (their unknowns start each step from the previous solution), fallbacks, records (their values
//! are in [`super::Simulation::z`]) and sensitivities.

use std::sync::Arc;

use ecp_model::{BlockMcp, DataBlock, DataId, Input, Problem, ResId, ResidualBlock};

use super::handles::StepHandles;
use crate::scene::SceneError;

/// A generalised force on one body: a residual block whose six rows are **added** to the body's
/// Newton–Euler rows (`docs/model.md#newton-euler`,
/// `0 = −M(ν − ν^u) + P_c + p_app + p_vp + p_user`).
///
/// The rows are an **impulse over the span**, world frame: force × h in N·s (rows 0–2) and
/// torque × h in N·m·s about the CM (rows 3–5), the sign of an applied load (a spring pulling
/// the body towards an anchor has rows `−h k (x − anchor)`). The block reads, in this order:
///
/// | input | size | what |
/// |---|---|---|
/// | [`Force::NU`] | 6 | `ν = (v, ω)` at the end of the span |
/// | [`Force::Q`] | 7 | `q = (x, Q)` at the end of the span (x in the step problem's coordinates, relative to [`super::Simulation::origin`]) |
/// | [`Force::H`] | 1 | the span length `h` (data) |
/// | [`Force::DATA`]… | any | the force's own data blocks ([`Force::with_data`]) in the order given |
///
/// Its Jacobian with respect to every input is written by the block (an implicit force:
/// evaluated at the end of the span like the contact impulses), and checked like every block
/// with `ecp_model::check_problem`.
#[derive(Clone)]
pub struct Force {
    pub(crate) block: Arc<dyn ResidualBlock>,
    pub(crate) data: Vec<DataBlock>,
}

impl Force {
    /// Input index of the body's `ν`.
    pub const NU: usize = 0;
    /// Input index of the body's `q`.
    pub const Q: usize = 1;
    /// Input index of the span length `h`.
    pub const H: usize = 2;
    /// Input index of the force's first own data block.
    pub const DATA: usize = 3;

    /// A force computed by `block` (six rows, inputs as in the type's documentation).
    pub fn new(block: impl ResidualBlock + 'static) -> Self {
        Force {
            block: Arc::new(block),
            data: Vec::new(),
        }
    }

    /// Adds a data block the force reads after `h` (its parameters: a stiffness, an anchor…);
    /// change it between steps with [`super::Simulation::set_data`].
    pub fn with_data(mut self, block: DataBlock) -> Self {
        self.data.push(block);
        self
    }
}

impl std::fmt::Debug for Force {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let data: Vec<&str> = self.data.iter().map(|d| d.name()).collect();
        f.debug_struct("Force")
            .field("block", &self.block.name())
            .field("data", &data)
            .finish()
    }
}

/// The handles of a force in the step problem.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ForceHandles {
    /// The body it acts on.
    pub body: usize,
    /// Its residual block (a term of the body's Newton–Euler rows).
    pub term: ResId,
    /// Its own data blocks, in the order given.
    pub data: Vec<DataId>,
}

/// Adds `force` on body `body` to `problem`, bound through `handles`.
pub(crate) fn add_force(
    problem: &mut Problem,
    handles: &StepHandles,
    formulation: &str,
    body: usize,
    force: &Force,
) -> Result<ForceHandles, SceneError> {
    let refuse = |reason: String| SceneError::NotApplicable {
        formulation: formulation.to_string(),
        step: None,
        reason,
    };
    let b = handles.body(body).ok_or_else(|| {
        refuse(format!(
            "force '{}' acts on body {body}, but the scene has {} bodies",
            force.block.name(),
            handles.bodies.len()
        ))
    })?;
    let (Some(nu), Some(q), Some(h)) = (b.nu, b.q, handles.h) else {
        return Err(refuse(format!(
            "force '{}': the step problem has no ν and q unknowns for body {body} (user terms \
             need a formulation whose capabilities include user_terms: hull, union or point)",
            force.block.name()
        )));
    };
    let data: Vec<DataId> = force
        .data
        .iter()
        .map(|d| problem.add_data_block(d.clone()))
        .collect();
    let mut reads: Vec<Input> = vec![nu.into(), q.into(), h.into()];
    reads.extend(data.iter().map(|d| Input::from(*d)));
    let term = problem.add_shared_term(nu, Arc::clone(&force.block), reads)?;
    Ok(ForceHandles { body, term, data })
}

/// An extra part of the step problem with its own unknowns: variable blocks paired with residual
/// blocks (and data blocks) that read the formulation's unknowns and data through the
/// [`StepHandles`] — a constraint between two bodies' velocities, an actuator's state, … Terms
/// may also add rows to the formulation's blocks with [`Problem::add_term`].
pub trait Term: Send {
    /// A name for error messages.
    fn name(&self) -> &str;
    /// Declares the term's blocks in `problem`, after the formulation's. Called again when the
    /// driver rebuilds the step problem (then with new handles).
    fn build(&mut self, handles: &StepHandles, problem: &mut Problem) -> Result<(), SceneError>;
    /// The term's starting values in `z` for the first step (zero before the call); afterwards
    /// its unknowns start each step from the previous solution.
    fn initial_guess(&self, mcp: &BlockMcp, z: &mut [f64]) {
        let _ = (mcp, z);
    }
}
