//! The data blocks of the step problem (`docs/model.md#data-blocks`): the model parameters the
//! residual blocks read, changed between steps with [`ecp_model::BlockMcp::set_data`] instead of
//! rebuilding or replacing blocks.
//!
//! | block | size | components | read by |
//! |---|---|---|---|
//! | `gravity` | 3 | [`GRAVITY_DATA`] | [`super::NewtonEuler`] |
//! | `h` | 1 | [`STEP_LENGTH_DATA`]: the step (or substep) length | [`super::NewtonEuler`], [`super::KinematicMap`] |
//! | `friction` | 4 | [`FRICTION_DATA`]: μ, e_t, e_o, e_r, shared by every contact | [`super::FrictionDissipation`], [`super::FrictionEllipsoid`] |
//! | `<body>.mass` | 1 | [`MASS_DATA`] | [`super::NewtonEuler`] |
//! | `<body>.inertia` | 6 | [`INERTIA_DATA`]: body frame, about the CM | [`super::NewtonEuler`] |
//! | `<body>.start` | 13 | [`START_DATA`]: x, Q, v, ω at `t_u` (x in the step problem's coordinates) | [`super::NewtonEuler`], [`super::KinematicMap`] |
//! | `<body>.wrench` | 6 | [`WRENCH_DATA`]: applied force and torque at the CM at `t_u`, world frame, without gravity | [`super::NewtonEuler`] |
//! | `halfspace<p>.offset` | 1 | [`PLANE_DATA`]: the offset c of `g(p) = n·p − c` in the step problem's coordinates | [`super::HalfSpaceSide`], [`super::NonPenetration`] |
//!
//! The half-space's normal is not data: it fixes the contact frame `(n, t, o)` of every block
//! of the contact, which is structure.

use nalgebra::{Matrix3, Vector3, Vector4, Vector6};

use ecp_model::{DataBlock, DataId, Problem};

use super::common::inertia_entries;
use super::friction::FrictionParams;

/// Components of a `mass` data block.
pub const MASS_DATA: [&str; 1] = ["m"];
/// Components of an `inertia` data block, in the order of [`super::INERTIA_ENTRIES`].
pub const INERTIA_DATA: [&str; 6] = ["xx", "yy", "zz", "xy", "xz", "yz"];
/// Components of a `start` data block: the state at the start of the step.
pub const START_DATA: [&str; 13] = [
    "x.x", "x.y", "x.z", "q.w", "q.x", "q.y", "q.z", "v.x", "v.y", "v.z", "w.x", "w.y", "w.z",
];
/// Components of a `wrench` data block.
pub const WRENCH_DATA: [&str; 6] = [
    "force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z",
];
/// Components of the `gravity` data block.
pub const GRAVITY_DATA: [&str; 3] = ["x", "y", "z"];
/// Components of the `h` data block.
pub const STEP_LENGTH_DATA: [&str; 1] = ["h"];
/// Components of the `friction` data block.
pub const FRICTION_DATA: [&str; 4] = ["mu", "e_t", "e_o", "e_r"];
/// Components of a half-space's data block.
pub const PLANE_DATA: [&str; 1] = ["offset"];

/// Offsets within a `start` data block ([`START_DATA`]).
pub mod start {
    /// Position x (3).
    pub const X: usize = 0;
    /// Quaternion Q (4).
    pub const Q: usize = 3;
    /// Linear velocity v (3).
    pub const V: usize = 7;
    /// Angular velocity ω (3).
    pub const W: usize = 10;
}

/// The data blocks of one body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BodyDataIds {
    /// Mass m (1).
    pub mass: DataId,
    /// Body-frame inertia (6, [`INERTIA_DATA`]).
    pub inertia: DataId,
    /// State at the start of the step (13, [`START_DATA`]).
    pub start: DataId,
    /// Applied wrench at `t_u` (6, [`WRENCH_DATA`]).
    pub wrench: DataId,
}

/// The data blocks shared by the whole step problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SceneDataIds {
    /// Gravity acceleration (3).
    pub gravity: DataId,
    /// Step length h (1).
    pub h: DataId,
    /// Friction parameters (4, [`FRICTION_DATA`]).
    pub friction: DataId,
}

/// The `start` values of a state: x, Q, v, ω.
pub fn start_values(
    x: &Vector3<f64>,
    q: &Vector4<f64>,
    v: &Vector3<f64>,
    w: &Vector3<f64>,
) -> [f64; 13] {
    [
        x.x, x.y, x.z, q[0], q[1], q[2], q[3], v.x, v.y, v.z, w.x, w.y, w.z,
    ]
}

/// Declares the scene-wide data blocks (`gravity`, `h`, `friction`).
pub fn add_scene_data(
    problem: &mut Problem,
    gravity: &Vector3<f64>,
    h: f64,
    friction: &FrictionParams,
) -> SceneDataIds {
    SceneDataIds {
        gravity: problem.add_data_block(
            DataBlock::new("gravity", gravity.as_slice()).with_component_names(GRAVITY_DATA),
        ),
        h: problem.add_data_block(DataBlock::new("h", [h]).with_component_names(STEP_LENGTH_DATA)),
        friction: problem.add_data_block(
            DataBlock::new("friction", friction.values()).with_component_names(FRICTION_DATA),
        ),
    }
}

/// Declares the data blocks of body `name` with its mass properties; the start state and the
/// wrench start at zero and are set before each step.
pub fn add_body_data(
    problem: &mut Problem,
    name: &str,
    mass: f64,
    inertia: &Matrix3<f64>,
) -> BodyDataIds {
    BodyDataIds {
        mass: problem.add_data_block(
            DataBlock::new(format!("{name}.mass"), [mass]).with_component_names(MASS_DATA),
        ),
        inertia: problem.add_data_block(
            DataBlock::new(format!("{name}.inertia"), inertia_entries(inertia))
                .with_component_names(INERTIA_DATA),
        ),
        start: problem.add_data_block(
            DataBlock::new(format!("{name}.start"), [0.0; 13]).with_component_names(START_DATA),
        ),
        wrench: problem.add_data_block(
            DataBlock::new(format!("{name}.wrench"), Vector6::<f64>::zeros().as_slice())
                .with_component_names(WRENCH_DATA),
        ),
    }
}

/// Declares the data block of half-space `p`, its offset in the step problem's coordinates.
pub fn add_plane_data(problem: &mut Problem, p: usize, offset: f64) -> DataId {
    problem.add_data_block(
        DataBlock::new(format!("halfspace{p}.offset"), [offset]).with_component_names(PLANE_DATA),
    )
}
