//! The contact formulations (`docs/model.md#unknowns`, `docs/model.md#other-formulations`) and the
//! [`Stepper`] trait every one of them implements, so that the command line, the reports and the
//! optimisation pipelines drive any formulation the same way.
//!
//! | formulation | module | step problem |
//! |---|---|---|
//! | [`Formulation::Hull`] | [`crate::stepper`] | one ECP contact between Conv(F) and each half-space (the paper) |
//! | [`Formulation::Union`] | [`crate::stepper`] | one ECP contact per convex piece of F
//! (`docs/model.md#union`) | | [`Formulation::Reduced`] | [`crate::reduced`] | planar sliding with
//! the whole patch in contact (`docs/model.md#reduced`) | | [`Formulation::Point`] |
//! [`crate::point`] | fixed points at the vertices, gap linearised at the step start
//! (`docs/model.md#point-contacts`) |

use std::fmt;
use std::str::FromStr;

use ecp_model::McpSolver;

use crate::fallback::Fallbacks;
use crate::stepper::{BodyState, Scene, SceneError, StepRecord};

/// A contact formulation (`docs/model.md#unknowns`, `docs/model.md#other-formulations`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Formulation {
    /// The paper's model: one contact between Conv(body) and each half-space (the ECP).
    #[default]
    Hull,
    /// One contact per convex piece of the body (`docs/model.md#union`).
    Union,
    /// The reduced sliding model with the whole patch in contact (`docs/model.md#reduced`).
    Reduced,
    /// Point contacts at the vertices of the pieces, gap linearised
    /// (`docs/model.md#point-contacts`).
    Point,
}

impl Formulation {
    /// Every formulation, in the order of `docs/model.md`.
    pub const ALL: [Formulation; 4] = [
        Formulation::Hull,
        Formulation::Union,
        Formulation::Reduced,
        Formulation::Point,
    ];

    /// The name used in scene files, on the command line and in reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            Formulation::Hull => "hull",
            Formulation::Union => "union",
            Formulation::Reduced => "reduced",
            Formulation::Point => "point",
        }
    }

    /// Whether the formulation builds a step problem with a structural view
    /// ([`ecp_model::StepStructure`]), which the conic backend needs.
    pub fn has_step_structure(&self) -> bool {
        matches!(self, Formulation::Hull | Formulation::Union)
    }
}

impl fmt::Display for Formulation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Formulation {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.as_str() == s.trim())
            .ok_or_else(|| {
                let names: Vec<String> = Self::ALL.iter().map(|f| format!("\"{f}\"")).collect();
                format!(
                    "unknown formulation \"{s}\"; the formulations are {}",
                    names.join(", ")
                )
            })
    }
}

/// A time stepper of one formulation: advances a [`Scene`] step by step with any backend and
/// records every step in the same [`StepRecord`] shape (the rows of `trajectory.csv`).
pub trait Stepper {
    /// Which formulation this is.
    fn formulation(&self) -> Formulation;
    /// The scene being simulated.
    fn scene(&self) -> &Scene;
    /// Contacts per body in every [`StepRecord`] (sets the columns of `trajectory.csv`).
    fn contacts_per_body(&self) -> usize;
    /// Current state of body `b`.
    fn state(&self, b: usize) -> BodyState;
    /// Steps taken so far.
    fn steps_taken(&self) -> usize;
    /// Advances one step with `solver`. A step that does not converge is reported as failed
    /// (`converged == false`, [`crate::StepMethod::Failed`]) and the bodies keep their state at its
    /// start: a failed iterate is never taken as a solution. An error means the step could not
    /// be set up (for instance a formulation whose assumptions stopped holding).
    fn step(&mut self, solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError>;

    /// [`Stepper::step`] with fallbacks for a step `solver` cannot solve (other backends, then
    /// substeps; see [`Fallbacks`]). A formulation that cannot use them (see
    /// [`Stepper::supports_fallbacks`]) takes the step with `solver` alone.
    fn step_with(
        &mut self,
        solver: &mut dyn McpSolver,
        fallbacks: &mut Fallbacks,
    ) -> Result<StepRecord, SceneError> {
        let _ = fallbacks;
        self.step(solver)
    }

    /// Whether [`Stepper::step_with`] uses its fallbacks.
    fn supports_fallbacks(&self) -> bool {
        false
    }

    /// Current time.
    fn time(&self) -> f64 {
        self.steps_taken() as f64 * self.scene().h
    }
    /// True once the scene's duration is covered.
    fn finished(&self) -> bool {
        self.steps_taken() >= self.scene().num_steps()
    }
    /// Runs the remaining steps, calling `on_step` after each; stops early when it returns
    /// `false`. Returns the number of steps that did not converge.
    fn run(
        &mut self,
        solver: &mut dyn McpSolver,
        on_step: &mut dyn FnMut(&StepRecord) -> bool,
    ) -> Result<usize, SceneError> {
        let mut failed = 0;
        while !self.finished() {
            let rec = self.step(solver)?;
            failed += usize::from(!rec.converged);
            if !on_step(&rec) {
                break;
            }
        }
        Ok(failed)
    }
}

/// Builds the stepper of `formulation` for `scene`; refuses, with a [`SceneError`] that says
/// why, a scene the formulation does not apply to.
pub fn build_stepper(
    scene: Scene,
    formulation: Formulation,
) -> Result<Box<dyn Stepper>, SceneError> {
    Ok(match formulation {
        Formulation::Hull => Box::new(crate::stepper::Simulation::new(scene)?),
        Formulation::Union => Box::new(crate::stepper::Simulation::with_formulation(
            scene,
            Formulation::Union,
        )?),
        Formulation::Reduced => Box::new(crate::reduced::ReducedSliding::new(scene)?),
        Formulation::Point => Box::new(crate::point::PointContacts::new(scene)?),
    })
}
