//! Residual blocks of the step problem (`docs/model.md#residual-blocks`), named after the paper,
//! and the data blocks they read (`docs/model.md#data-blocks`).
//!
//! Each block is paired with the variable block of the same length listed in
//! `docs/model.md#unknowns` and carries its analytic Jacobian with respect to every input —
//! the unknowns it reads and the data blocks ([`data`]) holding the model parameters — checked
//! against central differences by the model's Jacobian checker (unit tests next to each block
//! and property tests in `tests/`). The data derivatives are what the step sensitivities of
//! [`crate::sensitivity`] are made of.
//!
//! | file | blocks | data read |
//! |---|---|---|
//! | [`newton_euler`] | [`NewtonEuler`] | `mass`, `inertia`, `start`, `wrench`, `gravity`, `h` |
//! | [`kinematic_map`] | [`KinematicMap`] | `start`, `h` |
//! | [`contact`] | C1–C5: [`ClosestPointAlignment`], [`NormalCone`], [`HullFaces`], [`HalfSpaceSide`], [`NonPenetration`] | the half-space offset (C4, C5) |
//! | [`friction`] | [`FrictionDissipation`], [`FrictionEllipsoid`] | `friction` |
//! | [`common`] | helpers: [`ContactFrame`], the inertia parametrisation, [`mass_matrix`] | |

pub mod common;
pub mod contact;
pub mod data;
pub mod friction;
pub mod kinematic_map;
pub mod newton_euler;

pub use common::{
    ContactFrame, INERTIA_ENTRIES, inertia_direction, inertia_entries, inertia_from_entries,
    mass_matrix,
};
pub use contact::{ClosestPointAlignment, HalfSpaceSide, HullFaces, NonPenetration, NormalCone};
pub use data::{
    BodyDataIds, FRICTION_DATA, GRAVITY_DATA, INERTIA_DATA, MASS_DATA, PLANE_DATA, START_DATA,
    STEP_LENGTH_DATA, SceneDataIds, WRENCH_DATA, add_body_data, add_plane_data, add_scene_data,
    start_values,
};
pub use friction::{FrictionDissipation, FrictionEllipsoid, FrictionParams};
pub use kinematic_map::KinematicMap;
pub use newton_euler::{BODY_DATA_SIZES, BodyStepData, NewtonEuler, body_input};
