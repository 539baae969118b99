//! The reference scenarios of `docs/model.md#scenarios` as Rust constructors (A1–A6 and the desk,
//! B).
//!
//! The scene files in `scenes/` describe the same scenes; the integration tests load both.

use std::sync::Arc;

use nalgebra::{Vector3, Vector4, Vector6};

use crate::blocks::FrictionParams;
use crate::geometry::{HalfSpace, MassProperties, Shape};
use crate::rotation::{quat_from_axis_angle, quat_mul, rotation_matrix};
use crate::scene::{BodySpec, BodyState, Load, Scene};

/// Gravity used by every scenario, m/s².
pub const G: f64 = 9.8;
/// Box of the analytic cases: 0.4 × 0.4 × 0.2 m, 10 kg.
pub const BOX_SIZE: [f64; 3] = [0.4, 0.4, 0.2];
/// Mass of the box, kg.
pub const BOX_MASS: f64 = 10.0;
/// CM height of the box lying flat, m.
pub const BOX_H: f64 = 0.1;

fn box_body(initial: BodyState, load: Load) -> BodySpec {
    let [lx, ly, lz] = BOX_SIZE;
    BodySpec {
        name: "box".into(),
        mass: match MassProperties::solid_cuboid(BOX_MASS, lx, ly, lz) {
            Ok(m) => m,
            Err(e) => unreachable!("constant box is valid: {e}"),
        },
        shape: match Shape::cuboid(lx, ly, lz) {
            Ok(s) => s,
            Err(e) => unreachable!("constant box is valid: {e}"),
        },
        initial,
        load,
    }
}

fn box_scene(name: &str, mu: f64, duration: f64, body: BodySpec, plane: HalfSpace) -> Scene {
    Scene {
        name: name.into(),
        bodies: vec![body],
        planes: vec![plane],
        friction: FrictionParams {
            mu,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.1,
        },
        gravity: Vector3::new(0.0, 0.0, -G),
        h: 0.01,
        duration,
        world: Default::default(),
    }
}

fn flat_box(v: Vector3<f64>, w: Vector3<f64>) -> BodyState {
    BodyState {
        v,
        w,
        ..BodyState::at_rest(Vector3::new(0.0, 0.0, BOX_H))
    }
}

/// A1: box sliding to rest, μ = 0.3, `v0 = (1, 0, 0)`.
pub fn a1_sliding() -> Scene {
    box_scene(
        "a1_sliding",
        0.3,
        0.5,
        box_body(
            flat_box(Vector3::new(1.0, 0.0, 0.0), Vector3::zeros()),
            Load::None,
        ),
        HalfSpace::ground(),
    )
}

/// A2: box pushed from rest by a constant force `f_x` at the CM (20 N sticks, 40 N slides).
pub fn a2_push(fx: f64) -> Scene {
    let name = if fx < 0.3 * BOX_MASS * G {
        "a2_push_stick"
    } else {
        "a2_push_slide"
    };
    box_scene(
        name,
        0.3,
        0.5,
        box_body(
            flat_box(Vector3::zeros(), Vector3::zeros()),
            Load::Constant(Vector6::new(fx, 0.0, 0.0, 0.0, 0.0, 0.0)),
        ),
        HalfSpace::ground(),
    )
}

/// A3: box spinning in place, `ω0 = (0, 0, 2)` rad/s (torsional friction).
pub fn a3_spin() -> Scene {
    box_scene(
        "a3_spin",
        0.3,
        0.5,
        box_body(
            flat_box(Vector3::zeros(), Vector3::new(0.0, 0.0, 2.0)),
            Load::None,
        ),
        HalfSpace::ground(),
    )
}

/// A4: box at rest flat on an incline of `theta_deg` degrees (10° holds, 25° slides), 1 s.
pub fn a4_incline(theta_deg: f64) -> Scene {
    let theta = theta_deg.to_radians();
    let plane = match HalfSpace::incline(theta) {
        Ok(p) => p,
        Err(e) => unreachable!("finite incline: {e}"),
    };
    let q = quat_from_axis_angle(&Vector3::y(), -theta).unwrap_or(Vector4::new(1.0, 0.0, 0.0, 0.0));
    let state = BodyState {
        q,
        ..BodyState::at_rest(plane.normal() * BOX_H)
    };
    box_scene(
        &format!("a4_incline_{}", theta_deg.round() as i64),
        0.3,
        1.0,
        box_body(state, Load::None),
        plane,
    )
}

/// A5: flat box dropped from CM height 0.15 m (gap 0.05).
pub fn a5_drop() -> Scene {
    box_scene(
        "a5_drop",
        0.3,
        0.5,
        box_body(BodyState::at_rest(Vector3::new(0.0, 0.0, 0.15)), Load::None),
        HalfSpace::ground(),
    )
}

/// A5 tilted: rotated 20° about x then 10° about y, lowest vertex 0.1 m above the ground, 2 s.
pub fn a5_drop_tilted() -> Scene {
    let qx = quat_from_axis_angle(&Vector3::x(), 20f64.to_radians());
    let qy = quat_from_axis_angle(&Vector3::y(), 10f64.to_radians());
    let q = match (qx, qy) {
        (Some(qx), Some(qy)) => quat_mul(&qy, &qx),
        _ => unreachable!("unit axes"),
    };
    let r = rotation_matrix(&q);
    let lowest = box_shape_vertices()
        .iter()
        .map(|v| (r * v).z)
        .fold(f64::INFINITY, f64::min);
    let state = BodyState {
        q,
        ..BodyState::at_rest(Vector3::new(0.0, 0.0, 0.1 - lowest))
    };
    box_scene(
        "a5_drop_tilted",
        0.3,
        2.0,
        box_body(state, Load::None),
        HalfSpace::ground(),
    )
}

fn box_shape_vertices() -> Vec<Vector3<f64>> {
    let [lx, ly, lz] = BOX_SIZE;
    let mut v = Vec::new();
    for sx in [-0.5, 0.5] {
        for sy in [-0.5, 0.5] {
            for sz in [-0.5, 0.5] {
                v.push(Vector3::new(sx * lx, sy * ly, sz * lz));
            }
        }
    }
    v
}

/// A6: tipping threshold, μ = 1.5, force `f` in +x applied on the top face (0.2 m high):
/// force at the CM plus torque `τ_y = 0.1 f`.
pub fn a6_tip(f: f64) -> Scene {
    box_scene(
        &format!("a6_tip_{}", f.round() as i64),
        1.5,
        0.5,
        box_body(
            flat_box(Vector3::zeros(), Vector3::zeros()),
            Load::Constant(Vector6::new(f, 0.0, 0.0, 0.0, 0.1 * f, 0.0)),
        ),
        HalfSpace::ground(),
    )
}

/// B: the paper's desk (`docs/model.md#scenarios`): 15 kg, four legs, pushed and twisted by
/// periodic loads for 4 s.
pub fn desk() -> Scene {
    let load: crate::scene::WrenchFn = Arc::new(|t: f64| {
        let s = (2.0 * std::f64::consts::PI * t).sin();
        let c = (2.0 * std::f64::consts::PI * t).cos();
        Vector6::new(22.5 * s + 22.5, 22.5 * c + 22.5, 0.0, 0.0, 0.0, 2.1 * c)
    });
    let mass = match MassProperties::solid_cuboid(15.0, 0.5, 0.5, 0.9) {
        Ok(m) => m,
        Err(e) => unreachable!("constant desk is valid: {e}"),
    };
    Scene {
        name: "desk".into(),
        bodies: vec![BodySpec {
            name: "desk".into(),
            mass,
            shape: Shape::desk(),
            initial: BodyState {
                x: Vector3::new(0.0, 0.0, 0.45),
                q: Vector4::new(1.0, 0.0, 0.0, 0.0),
                v: Vector3::new(0.3, 0.2, 0.0),
                w: Vector3::new(0.0, 0.0, 0.5),
            },
            load: Load::Function(load),
        }],
        planes: vec![HalfSpace::ground()],
        friction: FrictionParams {
            mu: 0.22,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.1,
        },
        gravity: Vector3::new(0.0, 0.0, -G),
        h: 0.01,
        duration: 4.0,
        world: Default::default(),
    }
}

/// `min(max(s, 0), 1)`: the unit ramp of the T-bar's load windows (`s` is finite here).
fn ramp(s: f64) -> f64 {
    s.clamp(0.0, 1.0)
}

/// Trapezoidal window of the T-bar's load: 0 before `a` and after `b`, rising and falling
/// linearly over `r` seconds, 1 in between (`scenes/tbar.toml` writes the same with min/max).
fn window(t: f64, a: f64, b: f64, r: f64) -> f64 {
    ramp((t - a) / r) * ramp((b - t) / r)
}

/// C: the paper's T-bar (`docs/model.md#scenarios`): 2 kg, uniform density, lying flat, μ = 0.22, 5
/// s. The gripper's wrench (world frame, at the CM) is the design of `scenes/tbar.toml`, where it
/// is explained: a 1.7 N m torque pulse on [0.8, 1.2] s about the hull's slanted edge on the +y
/// side, direction (−2, 1, 0)/√5, one on [1.8, 2.2] s about the −y slanted edge, (2, 1, 0)/√5, each
/// with 0.1 s ramps (two-point contacts, then flat again), and on [3.0, 3.8] s (0.05 s ramps) a
/// push `f_x = 5` N with a yaw torque `τ_z = 0.3` N m (it slides and turns in surface contact).
pub fn t_bar() -> Scene {
    let load: crate::scene::WrenchFn = Arc::new(|t: f64| {
        let a = 1.7 * window(t, 0.8, 1.2, 0.1);
        let b = 1.7 * window(t, 1.8, 2.2, 0.1);
        let yaw = window(t, 3.0, 3.8, 0.05);
        let s5 = 5f64.sqrt();
        Vector6::new(
            5.0 * yaw,
            0.0,
            0.0,
            -2.0 / s5 * a + 2.0 / s5 * b,
            1.0 / s5 * a + 1.0 / s5 * b,
            0.3 * yaw,
        )
    });
    let mass = match MassProperties::t_bar(2.0) {
        Ok(m) => m,
        Err(e) => unreachable!("constant T-bar is valid: {e}"),
    };
    Scene {
        name: "tbar".into(),
        bodies: vec![BodySpec {
            name: "tbar".into(),
            mass,
            shape: Shape::t_bar(),
            // Flat: the bottom face (z = −0.025 in the body frame) on the ground.
            initial: BodyState::at_rest(Vector3::new(0.0, 0.0, 0.025)),
            load: Load::Function(load),
        }],
        planes: vec![HalfSpace::ground()],
        friction: FrictionParams {
            mu: 0.22,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.1,
        },
        gravity: Vector3::new(0.0, 0.0, -G),
        h: 0.01,
        duration: 5.0,
        world: Default::default(),
    }
}

/// A uniform box body of the bodies scenarios (`docs/model.md#scenarios`).
fn cuboid_body(name: &str, mass: f64, size: [f64; 3], x: Vector3<f64>) -> BodySpec {
    let [lx, ly, lz] = size;
    BodySpec {
        name: name.into(),
        mass: match MassProperties::solid_cuboid(mass, lx, ly, lz) {
            Ok(m) => m,
            Err(e) => unreachable!("constant box is valid: {e}"),
        },
        shape: match Shape::cuboid(lx, ly, lz) {
            Ok(s) => s,
            Err(e) => unreachable!("constant box is valid: {e}"),
        },
        initial: BodyState::at_rest(x),
        load: Load::None,
    }
}

/// D1 (`docs/model.md#scenarios`): A (0.4 × 0.4 × 0.2 m, 2 kg) flat on the ground
/// `ground`, B (0.2 m cube, 1 kg) centred on it, μ = 0.3, 1 s; run by the multi-body formulation.
pub fn d1_stack() -> Scene {
    Scene {
        name: "d1_stack".into(),
        bodies: vec![
            cuboid_body("A", 2.0, [0.4, 0.4, 0.2], Vector3::new(0.0, 0.0, 0.1)),
            cuboid_body("B", 1.0, [0.2, 0.2, 0.2], Vector3::new(0.0, 0.0, 0.3)),
        ],
        planes: vec![HalfSpace::ground()],
        friction: FrictionParams {
            mu: 0.3,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.1,
        },
        gravity: Vector3::new(0.0, 0.0, -G),
        h: 0.01,
        duration: 1.0,
        world: crate::world::World {
            plane_names: vec!["ground".into()],
            bodies_touch: true,
            ..Default::default()
        },
    }
}
