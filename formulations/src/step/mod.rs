//! The step driver layer (`docs/architecture.md`): what a formulation supplies
//! ([`StepFormulation`], [`Capabilities`], [`StepContext`]), the handles it publishes
//! ([`StepHandles`]), the user's forces and terms ([`Force`], [`Term`]), model parameters and
//! state components ([`Param`], [`StateComponent`]), the fallbacks ([`Fallbacks`]) and the one
//! driver every formulation runs in ([`Simulation`]).
//!
//! Inside the layer, each file imports only those listed before it: `handles`, `history`,
//! `formulation`, `params`, `terms`, `body`, `fallback`, then `driver` (`docs/architecture.md`).

pub mod body;
pub mod driver;
pub mod fallback;
pub mod formulation;
pub mod handles;
pub mod history;
pub mod params;
pub mod terms;

pub use driver::{LastStep, Simulation, SimulationBuilder, StepProblem, WarmStart};
pub use fallback::Fallbacks;
pub use formulation::{Capabilities, Prepared, SensitivitySupport, StepContext, StepFormulation};
pub use handles::{BodyHandles, ContactHandles, StepHandles};
pub use history::Iterates;
pub use params::{InertiaEntry, Param, ParamError, STATE_SIZE, StateComponent};
pub use terms::{Force, ForceHandles, Term};
