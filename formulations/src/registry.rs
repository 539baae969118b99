//! The formulations by name (`docs/model.md#other-formulations`): a [`FormulationRegistry`] maps
//! the names of scene files and the command line to factories and [`Capabilities`], so that the
//! command line, `compare`, fitting and the conic backend's refusal ask a formulation what it can
//! do instead of matching a closed list. [`FormulationRegistry::builtin`] holds the four of this
//! crate; [`FormulationRegistry::register`] adds a user's own (`examples/custom_formulation.rs`).
//!
//! This module is also where [`Simulation::new`] and [`Simulation::builder`] choose the hull
//! formulation by default: the driver layer does not know the formulations built on it.
//!
//! | name | type | step problem |
//! |---|---|---|
//! | `hull` | [`EcpContacts::hull`] | one ECP contact between Conv(F) and each half-space (the paper) |
//! | `union` | [`EcpContacts::union`] | one ECP contact per convex piece of F (`docs/model.md#union`) |
//! | `reduced` | [`ReducedSliding`] | planar sliding with the whole patch in contact (`docs/model.md#reduced`) |
//! | `point` | [`PointContacts`] | fixed points at the vertices, gap linearised at the step start (`docs/model.md#point-contacts`) |

use std::sync::Arc;

use crate::bodies::MultiBody;
use crate::ecp::EcpContacts;
use crate::point::PointContacts;
use crate::reduced::ReducedSliding;
use crate::scene::{Scene, SceneError};
use crate::step::{Capabilities, Simulation, SimulationBuilder, StepFormulation};

/// Makes a fresh formulation object.
pub type FormulationFactory = Arc<dyn Fn() -> Box<dyn StepFormulation> + Send + Sync>;

#[derive(Clone)]
struct Entry {
    name: String,
    capabilities: Capabilities,
    factory: FormulationFactory,
}

/// Formulations by name (module documentation).
#[derive(Clone, Default)]
pub struct FormulationRegistry {
    entries: Vec<Entry>,
}

impl std::fmt::Debug for FormulationRegistry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.names()).finish()
    }
}

/// A name that is not in the registry, or one registered twice.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RegistryError {
    /// No formulation of this name.
    #[error("unknown formulation \"{name}\"; the formulations are {known}")]
    Unknown {
        /// The name asked for.
        name: String,
        /// The names known, quoted and comma-separated.
        known: String,
    },
    /// A formulation of this name is registered already.
    #[error("a formulation named \"{0}\" is registered already; choose another name")]
    Duplicate(String),
}

impl FormulationRegistry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// The formulations of this crate, in the order of `docs/model.md`: hull, union, reduced,
    /// point, bodies.
    pub fn builtin() -> Self {
        let mut r = Self::new();
        let builtins: [FormulationFactory; 5] = [
            Arc::new(|| Box::new(EcpContacts::hull())),
            Arc::new(|| Box::new(EcpContacts::union())),
            Arc::new(|| Box::new(ReducedSliding::new())),
            Arc::new(|| Box::new(PointContacts::new())),
            Arc::new(|| Box::new(MultiBody::new())),
        ];
        for factory in builtins {
            let f = factory();
            r.entries.push(Entry {
                name: f.name().to_string(),
                capabilities: f.capabilities(),
                factory,
            });
        }
        r
    }

    /// Adds a formulation made by `factory` under its own name (`factory().name()`).
    pub fn register(
        &mut self,
        factory: impl Fn() -> Box<dyn StepFormulation> + Send + Sync + 'static,
    ) -> Result<(), RegistryError> {
        let f = factory();
        let name = f.name().to_string();
        if self.contains(&name) {
            return Err(RegistryError::Duplicate(name));
        }
        self.entries.push(Entry {
            name,
            capabilities: f.capabilities(),
            factory: Arc::new(factory),
        });
        Ok(())
    }

    /// The names, in registration order.
    pub fn names(&self) -> Vec<&str> {
        self.entries.iter().map(|e| e.name.as_str()).collect()
    }

    /// Whether `name` is registered.
    pub fn contains(&self, name: &str) -> bool {
        self.entries.iter().any(|e| e.name == name)
    }

    fn entry(&self, name: &str) -> Result<&Entry, RegistryError> {
        let name = name.trim();
        self.entries
            .iter()
            .find(|e| e.name == name)
            .ok_or_else(|| RegistryError::Unknown {
                name: name.to_string(),
                known: self
                    .names()
                    .iter()
                    .map(|n| format!("\"{n}\""))
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// Checks that `name` is registered and returns it as registered (trimmed).
    pub fn resolve(&self, name: &str) -> Result<String, RegistryError> {
        self.entry(name).map(|e| e.name.clone())
    }

    /// What formulation `name` can do.
    pub fn capabilities(&self, name: &str) -> Result<Capabilities, RegistryError> {
        self.entry(name).map(|e| e.capabilities)
    }

    /// The names of the formulations whose capabilities satisfy `keep`.
    pub fn names_with(&self, keep: impl Fn(&Capabilities) -> bool) -> Vec<&str> {
        self.entries
            .iter()
            .filter(|e| keep(&e.capabilities))
            .map(|e| e.name.as_str())
            .collect()
    }

    /// A fresh formulation `name`.
    pub fn create(&self, name: &str) -> Result<Box<dyn StepFormulation>, RegistryError> {
        self.entry(name).map(|e| (e.factory)())
    }
}

impl Simulation {
    /// Validates `scene` and builds the step problem of the hull formulation (the paper's), or
    /// of the multi-body formulation for a multi-body scene ([`Simulation::builder`]).
    pub fn new(scene: Scene) -> Result<Self, SceneError> {
        Self::builder(scene).build()
    }

    /// Validates `scene` and builds the step problem of the builtin formulation `name`
    /// ([`FormulationRegistry::builtin`]).
    pub fn with_formulation(scene: Scene, name: &str) -> Result<Self, SceneError> {
        let formulation =
            FormulationRegistry::builtin()
                .create(name)
                .map_err(|e| SceneError::NotApplicable {
                    formulation: name.to_string(),
                    step: None,
                    reason: e.to_string(),
                })?;
        SimulationBuilder::new(scene, formulation).build()
    }

    /// A builder for `scene` with the hull formulation (the multi-body formulation for a scene
    /// with fixed or kinematic bodies, pair friction or touching bodies,
    /// [`crate::world::World::is_multibody`]); choose another with
    /// [`SimulationBuilder::formulation`], add forces and terms, then
    /// [`SimulationBuilder::build`].
    pub fn builder(scene: Scene) -> SimulationBuilder {
        if scene.world.is_multibody() {
            SimulationBuilder::new(scene, Box::new(MultiBody::new()))
        } else {
            SimulationBuilder::new(scene, Box::new(EcpContacts::hull()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_names_and_capabilities() {
        let r = FormulationRegistry::builtin();
        assert_eq!(r.names(), ["hull", "union", "reduced", "point", "bodies"]);
        assert_eq!(
            r.names_with(|c| c.step_structure),
            ["hull", "union", "bodies"]
        );
        assert!(
            r.capabilities("union")
                .is_ok_and(|c| c.non_isolated_solutions)
        );
        assert_eq!(r.resolve(" point "), Ok("point".to_string()));
        let e = r.create("nope").err().map(|e| e.to_string());
        assert_eq!(
            e.as_deref(),
            Some(
                "unknown formulation \"nope\"; the formulations are \"hull\", \"union\", \
                 \"reduced\", \"point\", \"bodies\""
            )
        );
    }

    #[test]
    fn register_refuses_a_second_formulation_of_the_same_name() {
        let mut r = FormulationRegistry::builtin();
        let e = r.register(|| Box::new(EcpContacts::hull()));
        assert_eq!(e, Err(RegistryError::Duplicate("hull".into())));
        let mut empty = FormulationRegistry::new();
        assert!(empty.register(|| Box::new(PointContacts::new())).is_ok());
        assert_eq!(empty.names(), ["point"]);
    }
}
