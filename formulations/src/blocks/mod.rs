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
//! | [`spring`] | [`Spring`], a user force (a spring from the CM to an anchor) | its stiffness and anchor |
//! | [`common`] | helpers: [`ContactFrame`], the inertia parametrisation, [`mass_matrix`] | |
//!
//! A contact between two bodies (`docs/model.md#contact-between-two-bodies`), either of which
//! may move, has its own blocks, reading each body's `ν` and `q` as variables (dynamic) or data
//! (fixed, kinematic):
//!
//! | file | blocks | data read |
//! |---|---|---|
//! | [`pair_contact`] | (K1)–(K4): [`PairAlignment`], [`PairNormalCone`], [`PairNormalisation`], [`PairSeparation`]; the face rows are [`HullFaces`] on each body | |
//! | [`pair_friction`] | [`PairFriction`] on the relative velocity; the cone row is [`FrictionEllipsoid`] | the pair's `friction`, `axis` |
//! | [`pair_wrench`] | [`PairWrench`], terms on each dynamic body's Newton–Euler rows | `axis` |
//! | [`pair_frame`] | helpers: [`PairFrame`] (the frame of the unknown normal), [`SupportNormal`], [`reference_axis`] | |
//! | [`pair_assembly`] | [`add_pair_contact`]: every unknown and block of one pair; [`add_pair_data`] | |
//! | [`mod@pair_guess`] | [`pair_guess()`]: a starting guess from the closest features | |

pub mod common;
pub mod contact;
pub mod data;
pub mod friction;
pub mod kinematic_map;
pub mod newton_euler;
pub mod pair_assembly;
pub mod pair_contact;
pub mod pair_frame;
pub mod pair_friction;
pub mod pair_guess;
pub mod pair_wrench;
pub mod spring;

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
pub use pair_assembly::{
    AXIS_DATA, FaceSet, PairBody, PairContactValues, PairContactVars, PairDataIds,
    add_pair_contact, add_pair_data,
};
pub use pair_contact::{PairAlignment, PairNormalCone, PairNormalisation, PairSeparation};
pub use pair_frame::{PairFrame, SupportNormal, reference_axis};
pub use pair_friction::{PairFriction, RelativeVelocity};
pub use pair_guess::{PairMotion, pair_guess};
pub use pair_wrench::{PairSide, PairWrench, PairWrenchInputs};
pub use spring::Spring;
