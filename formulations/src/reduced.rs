//! Placeholder: the reduced sliding model (§7.2) is being written (issue #7).

use crate::formulation::{Formulation, Stepper};
use crate::stepper::{BodyState, Scene, SceneError, StepRecord};
use ecp_model::McpSolver;

/// Placeholder for the reduced sliding model (§7.2).
pub struct ReducedSliding {
    scene: Scene,
}

impl ReducedSliding {
    /// Not yet available.
    pub fn new(scene: Scene) -> Result<Self, SceneError> {
        let _ = &scene;
        Err(SceneError::NotApplicable {
            formulation: Formulation::Reduced,
            step: None,
            reason: "not implemented yet".into(),
        })
    }
}

impl Stepper for ReducedSliding {
    fn formulation(&self) -> Formulation {
        Formulation::Reduced
    }
    fn scene(&self) -> &Scene {
        &self.scene
    }
    fn contacts_per_body(&self) -> usize {
        1
    }
    fn state(&self, _b: usize) -> BodyState {
        unimplemented!()
    }
    fn steps_taken(&self) -> usize {
        0
    }
    fn step(&mut self, _solver: &mut dyn McpSolver) -> Result<StepRecord, SceneError> {
        unimplemented!()
    }
}
