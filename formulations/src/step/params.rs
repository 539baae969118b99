//! Model parameters of a scene ([`Param`]) — what fitting, trajectory gradients and
//! [`super::Simulation::set_param`] name — and the components of a body's state
//! ([`StateComponent`]) that derivatives are addressed by.
//!
//! A parameter lives in the scene and, where the step problem reads it, in a data block
//! (`docs/model.md#data-blocks`): [`Param::data`] says which. Setting it on a running
//! simulation changes that data block in place, without rebuilding the step problem.

use std::fmt;
use std::str::FromStr;

use nalgebra::{Matrix3, Vector6};

use ecp_model::DataId;

use super::handles::StepHandles;
use crate::blocks::{FrictionParams, inertia_entries};
use crate::geometry::MassProperties;
use crate::scene::{BodyState, Load, Scene};

/// A parameter name or value that cannot be used.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ParamError {
    /// A parameter name or index is wrong (the message lists the valid ones).
    #[error("{0}")]
    Name(String),
    /// A parameter value is out of range.
    #[error("{param} = {value} is invalid: {hint}")]
    Invalid {
        /// The parameter.
        param: String,
        /// The value given.
        value: f64,
        /// How to fix it.
        hint: &'static str,
    },
}

/// A component of a body's state (`docs/model.md#conventions`): the 13 numbers x, Q, v, ω
/// passed from step to step, in that order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StateComponent {
    /// A coordinate of the CM position (0, 1, 2 for x, y, z).
    Position(usize),
    /// A component of the unit quaternion (0..4 for w, x, y, z).
    Orientation(usize),
    /// A component of the CM velocity.
    Velocity(usize),
    /// A component of the angular velocity (world frame).
    AngularVelocity(usize),
}

/// Number of state components of a body ([`StateComponent`]).
pub const STATE_SIZE: usize = 13;

impl StateComponent {
    /// The 13 components in order.
    pub const ALL: [StateComponent; STATE_SIZE] = [
        StateComponent::Position(0),
        StateComponent::Position(1),
        StateComponent::Position(2),
        StateComponent::Orientation(0),
        StateComponent::Orientation(1),
        StateComponent::Orientation(2),
        StateComponent::Orientation(3),
        StateComponent::Velocity(0),
        StateComponent::Velocity(1),
        StateComponent::Velocity(2),
        StateComponent::AngularVelocity(0),
        StateComponent::AngularVelocity(1),
        StateComponent::AngularVelocity(2),
    ];

    /// Index 0..13 in x, Q, v, ω order; `None` for a component out of range (`Velocity(3)`).
    pub fn index(&self) -> Option<usize> {
        let (offset, len, k) = match *self {
            StateComponent::Position(k) => (0, 3, k),
            StateComponent::Orientation(k) => (3, 4, k),
            StateComponent::Velocity(k) => (7, 3, k),
            StateComponent::AngularVelocity(k) => (10, 3, k),
        };
        (k < len).then_some(offset + k)
    }

    /// The component of `state` (`None` out of range).
    pub fn of(&self, state: &BodyState) -> Option<f64> {
        Some(match *self {
            StateComponent::Position(k) => *state.x.get(k)?,
            StateComponent::Orientation(k) => *state.q.get(k)?,
            StateComponent::Velocity(k) => *state.v.get(k)?,
            StateComponent::AngularVelocity(k) => *state.w.get(k)?,
        })
    }
}

/// An entry of the symmetric body-frame inertia matrix, the inertia parametrisation of the
/// sensitivities: an off-diagonal entry moves both `I_ij` and `I_ji`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InertiaEntry {
    /// `I_xx`.
    Xx,
    /// `I_yy`.
    Yy,
    /// `I_zz`.
    Zz,
    /// `I_xy = I_yx`.
    Xy,
    /// `I_xz = I_zx`.
    Xz,
    /// `I_yz = I_zy`.
    Yz,
}

impl InertiaEntry {
    /// The six entries, in the order of the data of the Newton–Euler block.
    pub const ALL: [InertiaEntry; 6] = [
        InertiaEntry::Xx,
        InertiaEntry::Yy,
        InertiaEntry::Zz,
        InertiaEntry::Xy,
        InertiaEntry::Xz,
        InertiaEntry::Yz,
    ];
    /// Index 0..6 in [`InertiaEntry::ALL`].
    pub fn index(&self) -> usize {
        *self as usize
    }
    /// `(row, col)` of the entry (row ≤ col).
    pub fn position(&self) -> (usize, usize) {
        crate::blocks::INERTIA_ENTRIES[self.index()]
    }
    fn suffix(&self) -> &'static str {
        ["xx", "yy", "zz", "xy", "xz", "yz"][self.index()]
    }
}

/// A scalar model parameter θ of a [`Scene`], for trajectory gradients and fitting.
///
/// Names (for [`Param::from_str`] and `Display`): `mu`, `e_t`, `e_o`, `e_r`; per body `mass`,
/// `i_xx`, `i_yy`, `i_zz`, `i_xy`, `i_xz`, `i_yz`, the initial state `x0`, `y0`, `z0`, `qw0`,
/// `qx0`, `qy0`, `qz0`, `vx0`, `vy0`, `vz0`, `wx0`, `wy0`, `wz0`, and the components of a
/// constant applied load `fx`, `fy`, `fz`, `tx`, `ty`, `tz`; a body other than 0 is written
/// `mass[1]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Param {
    /// Friction coefficient μ (all contacts).
    Mu,
    /// Tangential semi-axis e_t of the friction ellipsoid.
    Et,
    /// Tangential semi-axis e_o.
    Eo,
    /// Torsional semi-axis e_r (m).
    Er,
    /// Mass of a body.
    Mass {
        /// Body index.
        body: usize,
    },
    /// An entry of a body's body-frame inertia.
    Inertia {
        /// Body index.
        body: usize,
        /// Which entry.
        entry: InertiaEntry,
    },
    /// A coordinate of a body's initial CM position.
    InitialPosition {
        /// Body index.
        body: usize,
        /// 0, 1, 2 for x, y, z.
        axis: usize,
    },
    /// A component of a body's initial quaternion (w, x, y, z) as given in the scene; the
    /// simulation normalises it, and the derivative goes through that normalisation.
    InitialOrientation {
        /// Body index.
        body: usize,
        /// 0..4 for w, x, y, z.
        component: usize,
    },
    /// A component of a body's initial linear velocity.
    InitialVelocity {
        /// Body index.
        body: usize,
        /// 0, 1, 2 for x, y, z.
        axis: usize,
    },
    /// A component of a body's initial angular velocity (world frame).
    InitialAngularVelocity {
        /// Body index.
        body: usize,
        /// 0, 1, 2 for x, y, z.
        axis: usize,
    },
    /// A component of a body's constant applied wrench (`Load::Constant`, or `Load::None` read
    /// as zero): 0..3 force, 3..6 torque. Its gradient is the sum of the per-step wrench
    /// gradients; a load given as a function of time has no such parameter.
    Load {
        /// Body index.
        body: usize,
        /// 0..6: fx, fy, fz, τx, τy, τz.
        component: usize,
    },
}

const STATE_NAMES: [&str; 13] = [
    "x0", "y0", "z0", "qw0", "qx0", "qy0", "qz0", "vx0", "vy0", "vz0", "wx0", "wy0", "wz0",
];
const LOAD_NAMES: [&str; 6] = ["fx", "fy", "fz", "tx", "ty", "tz"];

impl Param {
    /// The body the parameter belongs to (`None` for the friction parameters).
    pub fn body(&self) -> Option<usize> {
        match *self {
            Param::Mu | Param::Et | Param::Eo | Param::Er => None,
            Param::Mass { body }
            | Param::Inertia { body, .. }
            | Param::InitialPosition { body, .. }
            | Param::InitialOrientation { body, .. }
            | Param::InitialVelocity { body, .. }
            | Param::InitialAngularVelocity { body, .. }
            | Param::Load { body, .. } => Some(body),
        }
    }

    fn check_index(&self, scene: &Scene) -> Result<(), ParamError> {
        let (index, limit) = match *self {
            Param::InitialPosition { axis, .. }
            | Param::InitialVelocity { axis, .. }
            | Param::InitialAngularVelocity { axis, .. } => (axis, 3),
            Param::InitialOrientation { component, .. } => (component, 4),
            Param::Load { component, .. } => (component, 6),
            _ => (0, 1),
        };
        if index >= limit {
            return Err(ParamError::Name(format!(
                "parameter {self:?}: component {index} out of range (0..{limit})"
            )));
        }
        if let Some(b) = self.body()
            && b >= scene.bodies.len()
        {
            return Err(ParamError::Name(format!(
                "parameter {self} names body {b}, but scene '{}' has {} bod{}",
                scene.name,
                scene.bodies.len(),
                if scene.bodies.len() == 1 { "y" } else { "ies" }
            )));
        }
        Ok(())
    }

    /// The parameter's value in `scene`.
    pub fn get(&self, scene: &Scene) -> Result<f64, ParamError> {
        self.check_index(scene)?;
        let f = &scene.friction;
        Ok(match *self {
            Param::Mu => f.mu,
            Param::Et => f.e_t,
            Param::Eo => f.e_o,
            Param::Er => f.e_r,
            Param::Mass { body } => scene.bodies[body].mass.mass,
            Param::Inertia { body, entry } => {
                let (i, j) = entry.position();
                scene.bodies[body].mass.inertia[(i, j)]
            }
            Param::InitialPosition { body, axis } => scene.bodies[body].initial.x[axis],
            Param::InitialOrientation { body, component } => {
                scene.bodies[body].initial.q[component]
            }
            Param::InitialVelocity { body, axis } => scene.bodies[body].initial.v[axis],
            Param::InitialAngularVelocity { body, axis } => scene.bodies[body].initial.w[axis],
            Param::Load { body, component } => match &scene.bodies[body].load {
                Load::None => 0.0,
                Load::Constant(w) => w[component],
                Load::Function(_) => return Err(self.function_load(scene, body)),
            },
        })
    }

    fn function_load(&self, scene: &Scene, body: usize) -> ParamError {
        ParamError::Name(format!(
            "parameter {self}: the load of body '{}' is a function of time, not a constant; \
             use the per-step wrench gradient (TrajectoryGradient::wrench_gradient) and chain \
             your load parametrisation through it",
            scene.bodies[body].name
        ))
    }

    /// Sets the parameter's value in `scene`, with the checks the simulation makes (μ ≥ 0,
    /// e_t, e_o, e_r > 0, mass > 0, a symmetric positive definite inertia, finite values).
    pub fn set(&self, scene: &mut Scene, value: f64) -> Result<(), ParamError> {
        self.check_index(scene)?;
        let invalid = |hint: &'static str| ParamError::Invalid {
            param: self.to_string(),
            value,
            hint,
        };
        if !value.is_finite() {
            return Err(invalid("parameter values must be finite"));
        }
        let f = &mut scene.friction;
        match *self {
            Param::Mu if value < 0.0 => return Err(invalid("μ must be ≥ 0")),
            Param::Mu => f.mu = value,
            Param::Et | Param::Eo | Param::Er if value <= 0.0 => {
                return Err(invalid("the ellipsoid semi-axes e_t, e_o, e_r must be > 0"));
            }
            Param::Et => f.e_t = value,
            Param::Eo => f.e_o = value,
            Param::Er => f.e_r = value,
            Param::Mass { body } => {
                let mp = &scene.bodies[body].mass;
                scene.bodies[body].mass = MassProperties::new(value, mp.inertia)
                    .map_err(|_| invalid("the mass must be > 0"))?;
            }
            Param::Inertia { body, entry } => {
                let mp = &scene.bodies[body].mass;
                let (i, j) = entry.position();
                let mut inertia: Matrix3<f64> = mp.inertia;
                inertia[(i, j)] = value;
                inertia[(j, i)] = value;
                scene.bodies[body].mass = MassProperties::new(mp.mass, inertia)
                    .map_err(|_| invalid("the inertia must stay symmetric positive definite"))?;
            }
            Param::InitialPosition { body, axis } => scene.bodies[body].initial.x[axis] = value,
            Param::InitialOrientation { body, component } => {
                scene.bodies[body].initial.q[component] = value;
            }
            Param::InitialVelocity { body, axis } => scene.bodies[body].initial.v[axis] = value,
            Param::InitialAngularVelocity { body, axis } => {
                scene.bodies[body].initial.w[axis] = value;
            }
            Param::Load { body, component } => {
                let mut w = match &scene.bodies[body].load {
                    Load::None => Vector6::zeros(),
                    Load::Constant(w) => *w,
                    Load::Function(_) => return Err(self.function_load(scene, body)),
                };
                w[component] = value;
                scene.bodies[body].load = Load::Constant(w);
            }
        }
        Ok(())
    }
}

impl fmt::Display for Param {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (name, body): (String, Option<usize>) = match *self {
            Param::Mu => ("mu".into(), None),
            Param::Et => ("e_t".into(), None),
            Param::Eo => ("e_o".into(), None),
            Param::Er => ("e_r".into(), None),
            Param::Mass { body } => ("mass".into(), Some(body)),
            Param::Inertia { body, entry } => (format!("i_{}", entry.suffix()), Some(body)),
            Param::InitialPosition { body, axis } => (STATE_NAMES[axis % 3].into(), Some(body)),
            Param::InitialOrientation { body, component } => {
                (STATE_NAMES[3 + component % 4].into(), Some(body))
            }
            Param::InitialVelocity { body, axis } => (STATE_NAMES[7 + axis % 3].into(), Some(body)),
            Param::InitialAngularVelocity { body, axis } => {
                (STATE_NAMES[10 + axis % 3].into(), Some(body))
            }
            Param::Load { body, component } => (LOAD_NAMES[component % 6].into(), Some(body)),
        };
        match body {
            Some(b) if b > 0 => write!(f, "{name}[{b}]"),
            _ => f.write_str(&name),
        }
    }
}

impl FromStr for Param {
    type Err = ParamError;
    fn from_str(s: &str) -> Result<Self, ParamError> {
        let s = s.trim();
        let (name, body) = match s.split_once('[') {
            Some((n, rest)) => {
                let b = rest
                    .strip_suffix(']')
                    .and_then(|b| b.trim().parse::<usize>().ok())
                    .ok_or_else(|| {
                        ParamError::Name(format!(
                            "parameter \"{s}\": a body index is written name[b] with b a number, e.g. mass[1]"
                        ))
                    })?;
                (n.trim(), b)
            }
            None => (s, 0),
        };
        let global = match name {
            "mu" => Some(Param::Mu),
            "e_t" => Some(Param::Et),
            "e_o" => Some(Param::Eo),
            "e_r" => Some(Param::Er),
            _ => None,
        };
        if let Some(p) = global {
            if s.contains('[') {
                return Err(ParamError::Name(format!(
                    "parameter \"{s}\": {name} is shared by all contacts and takes no body index"
                )));
            }
            return Ok(p);
        }
        if name == "mass" {
            return Ok(Param::Mass { body });
        }
        if let Some(e) = InertiaEntry::ALL
            .iter()
            .find(|e| name == format!("i_{}", e.suffix()))
        {
            return Ok(Param::Inertia { body, entry: *e });
        }
        if let Some(k) = STATE_NAMES.iter().position(|n| *n == name) {
            return Ok(match k {
                0..3 => Param::InitialPosition { body, axis: k },
                3..7 => Param::InitialOrientation {
                    body,
                    component: k - 3,
                },
                7..10 => Param::InitialVelocity { body, axis: k - 7 },
                _ => Param::InitialAngularVelocity { body, axis: k - 10 },
            });
        }
        if let Some(k) = LOAD_NAMES.iter().position(|n| *n == name) {
            return Ok(Param::Load { body, component: k });
        }
        Err(ParamError::Name(format!(
            "unknown parameter \"{s}\"; the parameters are mu, e_t, e_o, e_r, mass, \
             i_xx, i_yy, i_zz, i_xy, i_xz, i_yz, {}, {} (a body other than 0 as mass[1])",
            STATE_NAMES.join(", "),
            LOAD_NAMES.join(", ")
        )))
    }
}

impl Param {
    /// The initial-state parameter of `component` of body `body`'s state.
    pub fn initial(body: usize, component: StateComponent) -> Param {
        match component {
            StateComponent::Position(axis) => Param::InitialPosition { body, axis },
            StateComponent::Orientation(component) => Param::InitialOrientation { body, component },
            StateComponent::Velocity(axis) => Param::InitialVelocity { body, axis },
            StateComponent::AngularVelocity(axis) => Param::InitialAngularVelocity { body, axis },
        }
    }

    /// True for the parameters of the initial state (they take effect when a simulation
    /// starts, [`super::Simulation::reset`]).
    pub fn is_initial_state(&self) -> bool {
        matches!(
            self,
            Param::InitialPosition { .. }
                | Param::InitialOrientation { .. }
                | Param::InitialVelocity { .. }
                | Param::InitialAngularVelocity { .. }
        )
    }

    /// The data block of a step problem that holds this parameter, with the block's values for
    /// `scene` (`None` when the step problem does not read it as data: the initial state, a
    /// load — written into each step's `wrench` data from the scene — or a formulation that
    /// reads the scene instead).
    pub fn data(&self, scene: &Scene, handles: &StepHandles) -> Option<(DataId, Vec<f64>)> {
        let body_data = |b: usize| handles.bodies.get(b).and_then(|h| h.data);
        match *self {
            Param::Mu | Param::Et | Param::Eo | Param::Er => handles
                .friction
                .map(|d| (d, FrictionParams::values(&scene.friction).to_vec())),
            Param::Mass { body } => {
                body_data(body).map(|d| (d.mass, vec![scene.bodies[body].mass.mass]))
            }
            Param::Inertia { body, .. } => body_data(body).map(|d| {
                (
                    d.inertia,
                    inertia_entries(&scene.bodies[body].mass.inertia).to_vec(),
                )
            }),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenarios;

    #[test]
    fn names_round_trip() {
        for name in [
            "mu", "e_r", "mass", "i_xy", "mass[1]", "vx0", "qz0", "tz[2]",
        ] {
            let p: Param = name.parse().unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(p.to_string(), name);
        }
        assert!("nope".parse::<Param>().is_err());
        assert!("mu[1]".parse::<Param>().is_err());
    }

    #[test]
    fn set_checks_values_and_get_reads_them_back() {
        let mut scene = scenarios::a1_sliding();
        Param::Mu
            .set(&mut scene, 0.4)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(Param::Mu.get(&scene), Ok(0.4));
        assert!(matches!(
            Param::Mu.set(&mut scene, -1.0),
            Err(ParamError::Invalid { .. })
        ));
        let ixy = Param::Inertia {
            body: 0,
            entry: InertiaEntry::Xy,
        };
        ixy.set(&mut scene, 0.01).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.bodies[0].mass.inertia[(1, 0)], 0.01);
        // Not positive definite.
        assert!(ixy.set(&mut scene, 10.0).is_err());
        assert!(Param::Mass { body: 3 }.get(&scene).is_err());
        let vx = Param::initial(0, StateComponent::Velocity(0));
        assert_eq!(vx, Param::InitialVelocity { body: 0, axis: 0 });
        assert!(vx.is_initial_state() && !Param::Mu.is_initial_state());
    }

    #[test]
    fn state_components_index_the_thirteen_numbers() {
        let indices: Vec<usize> = StateComponent::ALL
            .iter()
            .filter_map(|c| c.index())
            .collect();
        assert_eq!(indices, (0..STATE_SIZE).collect::<Vec<_>>());
        assert_eq!(StateComponent::Velocity(3).index(), None);
        let s = BodyState {
            v: nalgebra::Vector3::new(1.0, 2.0, 3.0),
            ..BodyState::at_rest(nalgebra::Vector3::zeros())
        };
        assert_eq!(StateComponent::Velocity(1).of(&s), Some(2.0));
        assert_eq!(StateComponent::Orientation(0).of(&s), Some(1.0));
    }
}
