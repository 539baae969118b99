//! Placeholder: the point contacts (§7.3) is being written (issue #7).

use crate::formulation::{Formulation, Stepper};
use crate::stepper::{BodyState, Scene, SceneError, StepRecord};
use ecp_model::McpSolver;

/// Placeholder for the point contacts (§7.3).
pub struct PointContacts {
    scene: Scene,
}

impl PointContacts {
    /// Not yet available.
    pub fn new(scene: Scene) -> Result<Self, SceneError> {
        let _ = &scene;
        Err(SceneError::NotApplicable {
            formulation: Formulation::Point,
            step: None,
            reason: "not implemented yet".into(),
        })
    }
}

impl Stepper for PointContacts {
    fn formulation(&self) -> Formulation {
        Formulation::Point
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
