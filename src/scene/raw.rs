//! The scene file as serde sees it: every table refuses unknown keys. Values are checked and
//! turned into the physics types in [`super`].

use serde::Deserialize;

/// The whole file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawScene {
    pub name: Option<String>,
    pub simulation: RawSimulation,
    pub friction: RawFriction,
    #[serde(default)]
    pub solver: RawSolver,
    #[serde(default)]
    pub half_spaces: Vec<RawHalfSpace>,
    #[serde(default)]
    pub bodies: Vec<RawBody>,
    #[serde(default)]
    pub pair_friction: Vec<RawPairFriction>,
}

/// `[[pair_friction]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPairFriction {
    pub between: [String; 2],
    pub mu: f64,
    pub e_t: Option<f64>,
    pub e_o: Option<f64>,
    pub e_r: Option<f64>,
}

/// `[bodies.motion]` of a kinematic body.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawMotion {
    pub velocity: Option<[f64; 3]>,
    pub angular_velocity: Option<[f64; 3]>,
    pub displacement: Option<Vec<toml::Value>>,
    pub rpy_deg: Option<Vec<toml::Value>>,
}

/// `[simulation]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSimulation {
    pub h: f64,
    pub duration: f64,
    pub gravity: Option<[f64; 3]>,
    pub formulation: Option<String>,
}

/// `[friction]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawFriction {
    pub mu: f64,
    pub e_t: Option<f64>,
    pub e_o: Option<f64>,
    pub e_r: f64,
}

/// `[solver]`.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSolver {
    pub name: Option<String>,
    pub tolerance: Option<f64>,
    pub max_iterations: Option<usize>,
}

/// `[[half_spaces]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawHalfSpace {
    pub name: Option<String>,
    pub normal: Option<[f64; 3]>,
    pub offset: Option<f64>,
    pub incline_deg: Option<f64>,
}

/// `[[bodies]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawBody {
    pub name: Option<String>,
    pub kind: Option<String>,
    pub material: Option<String>,
    pub mass: Option<f64>,
    pub inertia: Option<toml::Value>,
    pub position: [f64; 3],
    pub orientation: Option<[f64; 4]>,
    pub rpy_deg: Option<[f64; 3]>,
    pub velocity: Option<[f64; 3]>,
    pub angular_velocity: Option<[f64; 3]>,
    pub load: Option<RawLoad>,
    pub motion: Option<RawMotion>,
    #[serde(default)]
    pub pieces: Vec<RawPiece>,
}

/// `[bodies.load]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawLoad {
    pub force: Option<Vec<toml::Value>>,
    pub torque: Option<Vec<toml::Value>>,
}

/// `[[bodies.pieces]]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPiece {
    #[serde(rename = "box")]
    pub cuboid: Option<[f64; 3]>,
    pub points: Option<Vec<[f64; 3]>>,
    pub mesh: Option<String>,
    pub scale: Option<f64>,
    pub center: Option<[f64; 3]>,
    pub orientation: Option<[f64; 4]>,
    pub rpy_deg: Option<[f64; 3]>,
}
