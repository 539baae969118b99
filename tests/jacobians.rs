//! Property tests of the analytic Jacobians of every residual block of the step problem
//! (`docs/model.md#residual-blocks`, `ecp::formulations::blocks`) against central differences, with
//! the model's Jacobian checker (`check_residual_block` for a block, `check_problem` for an
//! assembled step problem), with respect to every input: the unknowns and the data blocks.
//!
//! States are random: rotated bodies with NON-UNIT quaternions (norm in [0.5, 2]: the step
//! solver treats Q as four free unknowns), ECPs that are free points, hull vertices, or points on
//! hull edges/faces, bodies separated from or touching the half-space, impulses with `p_n = 0` and
//! `σ = 0` among them, contact frames of the ground, of inclines and of random half-spaces, and
//! face normals of real hulls (box, desk, T-bar). All checks use `CheckOptions::default()`.
//!
//! One test plants a wrong Jacobian entry and checks that the checker finds exactly it, so a
//! green run here means something.
//!
//! The data inputs (the Newton–Euler block's mass, inertia, start state, load, gravity and step;
//! the kinematic map's start state and step; the half-space offsets; the friction blocks' μ,
//! e_t, e_o, e_r) are checked by the same calls, on the same random states plus random body
//! data (full symmetric inertias, unit and non-unit start quaternions); a planted error in a data
//! derivative is found too.

mod common;

use common::strategies::{unit_quat, unit3, vec3};
use std::sync::LazyLock;

use ecp::formulations::blocks::{
    BodyStepData, ClosestPointAlignment, ContactFrame, FrictionDissipation, FrictionEllipsoid,
    FrictionParams, HalfSpaceSide, HullFaces, KinematicMap, NewtonEuler, NonPenetration,
    NormalCone, inertia_entries, start_values,
};
use ecp::formulations::geometry::{HalfSpace, MassProperties, Shape};
use ecp::formulations::rotation::rotation_matrix;
use ecp::formulations::scenarios;
use ecp::formulations::{BodySpec, BodyState, Load, Scene, Simulation};
use ecp::model::{
    CheckOptions, InputKind, InputRange, JacobianBlocks, JacobianReport, Mcp, Params,
    ResidualBlock, VarId, check_problem, check_residual_block,
};
use nalgebra::{Matrix3, Vector3, Vector4, Vector6};
use proptest::prelude::*;

type V3 = Vector3<f64>;

// ---------------------------------------------------------------------------------------------
// Strategies
// ---------------------------------------------------------------------------------------------

/// A quaternion of norm between 0.5 and 2: the end-of-step Q is a free unknown.
fn non_unit_quat() -> impl Strategy<Value = Vector4<f64>> {
    (unit_quat(), 0.5..2.0f64).prop_map(|(q, s)| q * s)
}

/// The fixed half-space G: ground, an incline, a random half-space (normal given
/// un-normalised), or a near-vertical one (whose contact frame takes the other tangent seed).
fn half_space() -> impl Strategy<Value = HalfSpace> {
    prop_oneof![
        Just(HalfSpace::ground()),
        (-0.8..0.8f64).prop_map(|th| HalfSpace::incline(th).expect("finite angle")),
        (unit3(), 0.3..3.0f64, -1.0..1.0f64)
            .prop_map(|(n, s, c)| HalfSpace::new(n * s, c).expect("non-zero normal")),
        (-0.3..0.3f64, -0.3..0.3f64, -1.0..1.0f64).prop_map(|(y, z, c)| {
            HalfSpace::new(V3::new(-1.0, y, z), c).expect("non-zero normal")
        }),
    ]
}

fn frame_of(g: &HalfSpace) -> ContactFrame {
    let (n, t, o) = g.contact_frame();
    ContactFrame { n, t, o }
}

/// Face data of a real hull (body frame).
#[derive(Clone, Debug)]
struct Hull {
    name: &'static str,
    normals: Vec<V3>,
    offsets: Vec<f64>,
    vertices: Vec<V3>,
}

fn hull_of(name: &'static str, shape: &Shape) -> Hull {
    let h = shape.hull().expect("valid scenario shape");
    Hull {
        name,
        normals: h.faces().iter().map(|f| f.normal).collect(),
        offsets: h.faces().iter().map(|f| f.offset).collect(),
        vertices: h.vertices().to_vec(),
    }
}

static DESK: LazyLock<Hull> = LazyLock::new(|| hull_of("desk", &Shape::desk()));
static T_BAR: LazyLock<Hull> = LazyLock::new(|| hull_of("t_bar", &Shape::t_bar()));

fn hull() -> impl Strategy<Value = Hull> {
    prop_oneof![
        (0.05..1.0f64, 0.05..1.0f64, 0.05..1.0f64).prop_map(|(a, b, c)| {
            hull_of("cuboid", &Shape::cuboid(a, b, c).expect("positive edges"))
        }),
        Just(()).prop_map(|_| DESK.clone()),
        Just(()).prop_map(|_| T_BAR.clone()),
    ]
}

/// Where an ECP `a1` sits: a free point, or `v_i + t (v_j − v_i)` on the hull (t = 0: a vertex;
/// otherwise on an edge, a face or inside, depending on the pair).
#[derive(Clone, Debug)]
enum PointDraw {
    Free(V3),
    OnHull { i: usize, j: usize, t: f64 },
}

fn point_draw() -> impl Strategy<Value = PointDraw> {
    prop_oneof![
        vec3(-1.5, 1.5).prop_map(PointDraw::Free),
        (
            any::<usize>(),
            any::<usize>(),
            prop_oneof![Just(0.0), Just(0.5), 0.0..1.0f64]
        )
            .prop_map(|(i, j, t)| PointDraw::OnHull { i, j, t }),
    ]
}

/// Impulse-like value that is exactly 0 a good share of the time.
fn maybe_zero(hi: f64) -> impl Strategy<Value = f64> {
    prop_oneof![Just(0.0), 0.0..hi]
}

/// One contact's unknowns (besides ν and q) and its half-space.
#[derive(Clone, Debug)]
struct ContactDraw {
    plane: HalfSpace,
    point: PointDraw,
    /// Translate the body along the plane normal so that `a1` lies on the plane (`a2 = a1`).
    touching: bool,
    /// `a2` when not touching: the projection of `a1` plus this in-plane/out-of-plane offset.
    a2_offset: V3,
    lg: f64,
    pn: f64,
    pf: [f64; 3],
    sigma: f64,
    /// Face multipliers (first `m` used).
    l: Vec<f64>,
}

fn contact_draw() -> impl Strategy<Value = ContactDraw> {
    (
        half_space(),
        point_draw(),
        any::<bool>(),
        prop_oneof![Just(V3::zeros()), vec3(-0.5, 0.5)],
        maybe_zero(1.0),
        maybe_zero(20.0),
        (-5.0..5.0f64, -5.0..5.0f64, -1.0..1.0f64),
        maybe_zero(5.0),
        prop::collection::vec(maybe_zero(3.0), 8),
    )
        .prop_map(
            |(plane, point, touching, a2_offset, lg, pn, (pt, po, pr), sigma, l)| ContactDraw {
                plane,
                point,
                touching,
                a2_offset,
                lg,
                pn,
                pf: [pt, po, pr],
                sigma,
                l,
            },
        )
}

/// A random state of one body with up to two contacts.
#[derive(Clone, Debug)]
struct Case {
    hull: Hull,
    x: V3,
    /// End-of-step quaternion (non-unit).
    q: Vector4<f64>,
    nu: [f64; 6],
    /// Start-of-step data (unit quaternion).
    x_start: V3,
    q_start: Vector4<f64>,
    nu_start: [f64; 6],
    impulse: [f64; 6],
    mass: f64,
    inertia_diag: V3,
    h: f64,
    /// Row scale of the length-valued contact rows (C1, C3–C5).
    scale: f64,
    friction: FrictionParams,
    contacts: [ContactDraw; 2],
}

fn six(lo: f64, hi: f64) -> impl Strategy<Value = [f64; 6]> {
    (vec3(lo, hi), vec3(lo, hi)).prop_map(|(a, b)| [a.x, a.y, a.z, b.x, b.y, b.z])
}

fn case() -> impl Strategy<Value = Case> {
    (
        hull(),
        (vec3(-1.0, 1.0), non_unit_quat(), six(-3.0, 3.0)),
        (vec3(-1.0, 1.0), unit_quat(), six(-3.0, 3.0), six(-5.0, 5.0)),
        (
            0.5..20.0f64,
            vec3(0.01, 2.0),
            prop_oneof![Just(0.01), 1e-3..0.05f64],
            prop_oneof![Just(1.0), Just(100.0), 0.1..1000.0f64],
        ),
        (maybe_zero(1.5), 0.5..2.0f64, 0.5..2.0f64, 0.02..0.5f64),
        (contact_draw(), contact_draw()),
    )
        .prop_map(
            |(
                hull,
                (x, q, nu),
                (x_start, q_start, nu_start, impulse),
                (mass, inertia_diag, h, scale),
                (mu, e_t, e_o, e_r),
                (c0, c1),
            )| Case {
                hull,
                x,
                q,
                nu,
                x_start,
                q_start,
                nu_start,
                impulse,
                mass,
                inertia_diag,
                h,
                scale,
                friction: FrictionParams { mu, e_t, e_o, e_r },
                contacts: [c0, c1],
            },
        )
}

/// The realised unknowns of one contact.
#[derive(Clone, Debug)]
struct Contact {
    plane: HalfSpace,
    frame: ContactFrame,
    a1: [f64; 3],
    a2: [f64; 3],
    lg: [f64; 1],
    pn: [f64; 1],
    pf: [f64; 3],
    sigma: [f64; 1],
    l: Vec<f64>,
}

/// The realised state: `q = (x, Q)` flat, ν, and the contacts.
#[derive(Clone, Debug)]
struct State {
    q: [f64; 7],
    nu: [f64; 6],
    contacts: Vec<Contact>,
}

impl Case {
    fn realise(&self) -> State {
        let r = rotation_matrix(&self.q);
        let m = self.hull.normals.len();
        let nv = self.hull.vertices.len();
        let mut x = self.x;
        let mut contacts = Vec::new();
        for (k, c) in self.contacts.iter().enumerate() {
            let mut a1 = match c.point {
                PointDraw::Free(p) => p,
                PointDraw::OnHull { i, j, t } => {
                    let (vi, vj) = (self.hull.vertices[i % nv], self.hull.vertices[j % nv]);
                    x + r * (vi + (vj - vi) * t)
                }
            };
            let n = c.plane.normal();
            // Only the first contact may move the body (a second plane would undo it).
            let touching = c.touching && k == 0;
            if touching {
                let shift = n * c.plane.value(&a1);
                x -= shift;
                a1 -= shift;
            }
            let a2 = if touching {
                a1
            } else {
                c.plane.project(&a1) + c.a2_offset
            };
            contacts.push(Contact {
                plane: c.plane,
                frame: frame_of(&c.plane),
                a1: [a1.x, a1.y, a1.z],
                a2: [a2.x, a2.y, a2.z],
                lg: [if touching { 0.0 } else { c.lg }],
                pn: [c.pn],
                pf: c.pf,
                sigma: [c.sigma],
                l: c.l[..m].to_vec(),
            });
        }
        State {
            q: [x.x, x.y, x.z, self.q[0], self.q[1], self.q[2], self.q[3]],
            nu: self.nu,
            contacts,
        }
    }

    /// The body data of the case (diagonal inertia, the case's start state, `impulse` as the
    /// applied wrench, gravity along −z).
    fn body(&self) -> BodyStepData {
        BodyStepData {
            mass: self.mass,
            inertia: Matrix3::from_diagonal(&self.inertia_diag),
            q_start: self.q_start,
            nu_start: Vector6::from_row_slice(&self.nu_start),
            wrench: Vector6::from_row_slice(&self.impulse),
            gravity: V3::new(0.0, 0.0, -scenarios::G),
            h: self.h,
        }
    }

    fn start(&self) -> [f64; 13] {
        start(&self.x_start, &self.body())
    }

    fn newton_euler(&self, s: &State, contacts: usize) -> NewtonEuler {
        NewtonEuler::new(s.contacts[..contacts].iter().map(|c| c.frame).collect())
    }
}

/// The `start` data values of body data `b` with start position `x`.
fn start(x: &V3, b: &BodyStepData) -> [f64; 13] {
    let (v, w) = (
        V3::new(b.nu_start[0], b.nu_start[1], b.nu_start[2]),
        V3::new(b.nu_start[3], b.nu_start[4], b.nu_start[5]),
    );
    start_values(x, &b.q_start, &v, &w)
}

/// The body data inputs of a Newton–Euler block (`mass`, `inertia`, `start`, `wrench`,
/// `gravity`, `h`), owned.
struct BodyInputs {
    mass: [f64; 1],
    inertia: [f64; 6],
    start: [f64; 13],
    wrench: [f64; 6],
    gravity: [f64; 3],
    h: [f64; 1],
}

impl BodyInputs {
    fn new(x: &V3, b: &BodyStepData) -> Self {
        BodyInputs {
            mass: [b.mass],
            inertia: inertia_entries(&b.inertia),
            start: start(x, b),
            wrench: [0, 1, 2, 3, 4, 5].map(|i| b.wrench[i]),
            gravity: [b.gravity.x, b.gravity.y, b.gravity.z],
            h: [b.h],
        }
    }
    fn slices(&self) -> [&[f64]; 6] {
        [
            &self.mass,
            &self.inertia,
            &self.start,
            &self.wrench,
            &self.gravity,
            &self.h,
        ]
    }
}

/// `vars` followed by the body data inputs.
fn with_body<'a>(vars: &[&'a [f64]], body: &'a BodyInputs) -> Vec<&'a [f64]> {
    let mut v = vars.to_vec();
    v.extend(body.slices());
    v
}

// ---------------------------------------------------------------------------------------------
// Checking
// ---------------------------------------------------------------------------------------------

/// Runs the checker with default options and asserts every entry is within tolerance and that
/// every entry of the block's Jacobian was compared.
fn check(block: &dyn ResidualBlock, params: &[&[f64]]) -> Result<JacobianReport, TestCaseError> {
    check_scaled(block, params, 1.0)
}

/// Like [`check`] for a block whose rows are multiplied by `scale`: the round-off of the
/// central differences grows with the scaled intermediate values (up to `scale · |a1 − x|`), so
/// the absolute tolerance is scaled with it.
fn check_scaled(
    block: &dyn ResidualBlock,
    params: &[&[f64]],
    scale: f64,
) -> Result<JacobianReport, TestCaseError> {
    let opts = CheckOptions {
        abs_tol: CheckOptions::default().abs_tol * scale.max(1.0),
        ..CheckOptions::default()
    };
    let report = check_residual_block(block, params, &opts)
        .map_err(|e| TestCaseError::fail(format!("checker rejected {}: {e}", block.name())))?;
    let cols: usize = block.parameter_sizes().iter().sum();
    prop_assert_eq!(
        report.entries,
        block.num_residuals() * cols,
        "not every entry of {} was compared",
        block.name()
    );
    prop_assert!(report.ok(), "{}", report);
    Ok(report)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, ..ProptestConfig::default() })]

    #[test]
    fn newton_euler_one_contact(case in case()) {
        let s = case.realise();
        let c = &s.contacts[0];
        let ne = case.newton_euler(&s, 1);
        let body = BodyInputs::new(&case.x_start, &case.body());
        check(&ne, &with_body(&[&s.nu, &s.q, &c.a1, &c.pn, &c.pf], &body))?;
    }

    #[test]
    fn newton_euler_two_contacts(case in case()) {
        let s = case.realise();
        let (c0, c1) = (&s.contacts[0], &s.contacts[1]);
        let ne = case.newton_euler(&s, 2);
        let body = BodyInputs::new(&case.x_start, &case.body());
        check(&ne, &with_body(&[&s.nu, &s.q, &c0.a1, &c0.pn, &c0.pf, &c1.a1, &c1.pn, &c1.pf], &body))?;
    }

    #[test]
    fn newton_euler_without_contacts(case in case()) {
        let s = case.realise();
        let ne = case.newton_euler(&s, 0);
        let body = BodyInputs::new(&case.x_start, &case.body());
        check(&ne, &with_body(&[&s.nu, &s.q], &body))?;
    }

    #[test]
    fn kinematic_map(case in case()) {
        let s = case.realise();
        check(&KinematicMap, &[&s.q, &s.nu, &case.start(), &[case.h]])?;
        // Also from a non-unit start quaternion (the block is linear either way).
        let mut start = case.start();
        start[3..7].copy_from_slice(case.q.as_slice());
        check(&KinematicMap, &[&s.q, &s.nu, &start, &[case.h]])?;
    }

    #[test]
    fn closest_point_alignment(case in case()) {
        let s = case.realise();
        for c in &s.contacts {
            let b = ClosestPointAlignment { normal: c.plane.normal(), scale: case.scale };
            check(&b, &[&c.a1, &c.a2, &c.lg])?;
        }
    }

    #[test]
    fn normal_cone(case in case()) {
        let s = case.realise();
        for c in &s.contacts {
            let b = NormalCone::new(c.plane.normal(), case.hull.normals.clone());
            check(&b, &[&c.l, &s.q])?;
        }
    }

    #[test]
    fn hull_faces(case in case()) {
        let s = case.realise();
        for c in &s.contacts {
            let b = HullFaces {
                face_normals: case.hull.normals.clone(),
                offsets: case.hull.offsets.clone(),
                scale: case.scale,
            };
            let rep = check_scaled(&b, &[&c.a1, &s.q], case.scale)?;
            prop_assert_eq!(rep.entries, case.hull.normals.len() * 10, "hull {}", case.hull.name);
        }
    }

    #[test]
    fn half_space_side(case in case()) {
        let s = case.realise();
        for c in &s.contacts {
            let b = HalfSpaceSide { normal: c.plane.normal(), scale: case.scale };
            check(&b, &[&c.a2, &[c.plane.offset()]])?;
        }
    }

    #[test]
    fn non_penetration(case in case()) {
        let s = case.realise();
        for c in &s.contacts {
            let b = NonPenetration { normal: c.plane.normal(), scale: case.scale };
            check(&b, &[&c.a1, &[c.plane.offset()]])?;
        }
    }

    #[test]
    fn friction_dissipation(case in case()) {
        let s = case.realise();
        for c in &s.contacts {
            let b = FrictionDissipation { frame: c.frame };
            check(&b, &[&s.nu, &s.q, &c.a1, &c.pn, &c.pf, &c.sigma, &case.friction.values()])?;
        }
    }

    #[test]
    fn friction_ellipsoid(case in case()) {
        let s = case.realise();
        for c in &s.contacts {
            check(&FrictionEllipsoid, &[&c.pn, &c.pf, &case.friction.values()])?;
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Data Jacobians ∂r/∂θ
// ---------------------------------------------------------------------------------------------

/// Body data of a Newton–Euler block: a full symmetric positive definite inertia (principal
/// moments in a random body frame), a unit or non-unit start quaternion, random velocities,
/// loads, gravity and step.
fn body_data() -> impl Strategy<Value = BodyStepData> {
    (
        (0.5..20.0f64, vec3(0.01, 2.0), unit_quat()),
        prop_oneof![unit_quat(), non_unit_quat()],
        (six(-3.0, 3.0), six(-50.0, 50.0)),
        (vec3(-10.0, 10.0), prop_oneof![Just(0.01), 1e-3..0.05f64]),
    )
        .prop_map(
            |((mass, moments, axes), q_start, (nu, wrench), (gravity, h))| {
                let r = rotation_matrix(&axes);
                BodyStepData {
                    mass,
                    inertia: r * Matrix3::from_diagonal(&moments) * r.transpose(),
                    q_start,
                    nu_start: Vector6::from_row_slice(&nu),
                    wrench: Vector6::from_row_slice(&wrench),
                    gravity,
                    h,
                }
            },
        )
}

/// The inputs as one flat vector of variables (as the checker lays them out), for evaluating a
/// standalone block.
fn flat(params: &[&[f64]]) -> (Vec<f64>, Vec<InputRange>) {
    let mut z = Vec::new();
    let mut ranges = Vec::new();
    for p in params {
        ranges.push(InputRange::var(z.len(), p.len()));
        z.extend_from_slice(p);
    }
    (z, ranges)
}

fn eval(block: &dyn ResidualBlock, params: &[&[f64]]) -> Vec<f64> {
    let (z, ranges) = flat(params);
    let mut out = vec![0.0; block.num_residuals()];
    block.evaluate(Params::new(&z, &[], &ranges), &mut out);
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Full body data (symmetric inertia, unit or non-unit start quaternion, any gravity and
    /// step), with two contacts: every input, variable and data, checked.
    #[test]
    fn newton_euler_data(case in case(), data in body_data()) {
        let s = case.realise();
        let (c0, c1) = (&s.contacts[0], &s.contacts[1]);
        let body = BodyInputs::new(&case.x_start, &data);
        let ne = NewtonEuler::new(vec![c0.frame, c1.frame]);
        check(&ne, &with_body(&[&s.nu, &s.q, &c0.a1, &c0.pn, &c0.pf, &c1.a1, &c1.pn, &c1.pf], &body))?;
        // The contact part is the contact impulse Σ W p, whatever the body data: the rows with a
        // contact minus the rows without it.
        let one = eval(&NewtonEuler::new(vec![c0.frame]), &with_body(&[&s.nu, &s.q, &c0.a1, &c0.pn, &c0.pf], &body));
        let d = eval(&NewtonEuler::new(vec![]), &with_body(&[&s.nu, &s.q], &body));
        let fr = c0.frame;
        let force = fr.n * c0.pn[0] + fr.t * c0.pf[0] + fr.o * c0.pf[1];
        let arm = V3::new(c0.a1[0] - s.q[0], c0.a1[1] - s.q[1], c0.a1[2] - s.q[2]);
        let torque = arm.cross(&force) + fr.n * c0.pf[2];
        for i in 0..3 {
            for (row, expect) in [(i, force[i]), (3 + i, torque[i])] {
                let tol = 1e-12 * (1.0 + one[row].abs() + d[row].abs());
                prop_assert!((one[row] - d[row] - expect).abs() <= tol, "row {}", row);
            }
        }
        // The gyroscopic term does no work on the end-of-step angular velocity: without
        // contacts, ω·(r_ang − h τ) = −Ω·I_b Ω + Ω·I_b Ω^u with Ω = R1ᵀω, Ω^u = R0ᵀω^u.
        let r0 = rotation_matrix(&data.q_start);
        let r1 = rotation_matrix(&Vector4::new(s.q[3], s.q[4], s.q[5], s.q[6]));
        let w1 = Vector3::new(s.nu[3], s.nu[4], s.nu[5]);
        let w0 = Vector3::new(data.nu_start[3], data.nu_start[4], data.nu_start[5]);
        let (om1, om0) = (r1.transpose() * w1, r0.transpose() * w0);
        let r_ang = Vector3::new(d[3], d[4], d[5])
            - Vector3::new(data.wrench[3], data.wrench[4], data.wrench[5]) * data.h;
        let expected = -om1.dot(&(data.inertia * om1)) + om1.dot(&(data.inertia * om0));
        let scale = 1.0 + w1.norm() * (data.inertia * om1).norm() * (1.0 + data.h * w1.norm())
            + w1.norm() * (data.inertia * om0).norm();
        prop_assert!(
            (w1.dot(&r_ang) - expected).abs() <= 1e-12 * scale,
            "ω·r = {} expected {}", w1.dot(&r_ang), expected
        );
    }
}

/// FrictionDissipation with one planted error in a data derivative: `∂r_1/∂e_o` (input 6, the
/// `friction` data, column 2) is off by 0.25.
struct PlantedDataError(FrictionDissipation);

impl ResidualBlock for PlantedDataError {
    fn name(&self) -> &str {
        "planted_data"
    }
    fn num_residuals(&self) -> usize {
        self.0.num_residuals()
    }
    fn parameter_sizes(&self) -> &[usize] {
        self.0.parameter_sizes()
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        self.0.evaluate(x, out);
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        self.0.jacobian(x, jac);
        jac.add(FrictionDissipation::FRICTION, 1, 2, 0.25);
    }
}

#[test]
fn checker_finds_a_planted_wrong_data_entry() {
    let g = HalfSpace::ground();
    let block = FrictionDissipation {
        frame: frame_of(&g),
    };
    let friction = [0.3, 1.0, 1.2, 0.1];
    let (nu, q) = (
        [0.5, -0.2, 0.0, 0.0, 0.0, 1.0],
        [0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.0],
    );
    let (a1, pn, pf, sigma) = ([0.01, 0.02, 0.0], [1.5], [-0.2, 0.1, 0.01], [0.4]);
    let params: [&[f64]; 7] = [&nu, &q, &a1, &pn, &pf, &sigma, &friction];
    let good = check_residual_block(&block, &params, &CheckOptions::default()).expect("sizes");
    assert!(good.ok() && good.entries == 3 * 25, "{good}");
    let bad = check_residual_block(&PlantedDataError(block), &params, &CheckOptions::default())
        .expect("sizes");
    assert_eq!(bad.failures, 1, "{bad}");
    let worst = &bad.worst[0];
    assert!(
        worst.failed && (worst.row, worst.block, worst.col) == (1, 6, 2),
        "{bad}"
    );
    assert_eq!(bad.pairs[6].failures, 1, "{bad}");
    // ∂r_o/∂e_o = 2 e_o μ p_n (W_oᵀν) with W_oᵀν = o·v + ((a1 − x) × o)·ω.
    let (_, _, o) = g.contact_frame();
    let r = V3::new(a1[0] - q[0], a1[1] - q[1], a1[2] - q[2]);
    let slip =
        o.dot(&V3::new(nu[0], nu[1], nu[2])) + r.cross(&o).dot(&V3::new(nu[3], nu[4], nu[5]));
    let exact = 2.0 * 1.2 * 0.3 * 1.5 * slip;
    assert!((worst.numeric - exact).abs() < 1e-8, "{bad}");
    assert!((worst.analytic - exact - 0.25).abs() < 1e-12, "{bad}");
    assert!(
        bad.to_string().contains("planted_data[1] / input6[2]"),
        "{bad}"
    );
}

/// The contact frames used above are right-handed and orthonormal, so the blocks are tested
/// with the frames the stepper really builds.
#[test]
fn contact_frames_are_orthonormal() {
    let mut runner = proptest::test_runner::TestRunner::default();
    runner
        .run(&half_space(), |g| {
            let f = frame_of(&g);
            let m = Matrix3::from_columns(&[f.n, f.t, f.o]);
            prop_assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-12);
            prop_assert!((m.determinant() - 1.0).abs() < 1e-12);
            Ok(())
        })
        .expect("orthonormal frames");
}

// ---------------------------------------------------------------------------------------------
// The checker can fail
// ---------------------------------------------------------------------------------------------

/// FrictionEllipsoid with one planted error: `∂r/∂p_r` is off by 0.5.
struct PlantedError(FrictionEllipsoid);

impl ResidualBlock for PlantedError {
    fn name(&self) -> &str {
        "planted"
    }
    fn num_residuals(&self) -> usize {
        self.0.num_residuals()
    }
    fn parameter_sizes(&self) -> &[usize] {
        self.0.parameter_sizes()
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        self.0.evaluate(x, out);
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        self.0.jacobian(x, jac);
        // Block 1 (p_f), row 0, column 2 (p_r).
        jac.add(1, 0, 2, 0.5);
    }
}

#[test]
fn checker_finds_a_planted_wrong_entry() {
    let friction = FrictionParams {
        mu: 0.3,
        e_t: 1.0,
        e_o: 1.2,
        e_r: 0.1,
    };
    let pn = [2.0];
    let pf = [0.3, -0.2, 0.01];
    // The unmodified block passes at this point ...
    let good = check_residual_block(
        &FrictionEllipsoid,
        &[&pn, &pf, &friction.values()],
        &CheckOptions::default(),
    )
    .expect("sizes match");
    assert!(good.ok(), "{good}");
    // ... the planted error is found, and it is the only and the worst entry.
    let bad = check_residual_block(
        &PlantedError(FrictionEllipsoid),
        &[&pn, &pf, &friction.values()],
        &CheckOptions::default(),
    )
    .expect("sizes match");
    assert!(!bad.ok(), "the planted error was not detected:\n{bad}");
    assert_eq!(bad.failures, 1, "{bad}");
    let worst = &bad.worst[0];
    assert!(
        worst.failed && (worst.row, worst.block, worst.col) == (0, 1, 2),
        "worst entry is not the planted one:\n{bad}"
    );
    // ∂(μ p_n − ‖E⁻¹p‖)/∂p_r = −(p_r / e_r²) / ‖E⁻¹p‖; the planted entry adds 0.5.
    let norm = ((pf[0] / friction.e_t).powi(2)
        + (pf[1] / friction.e_o).powi(2)
        + (pf[2] / friction.e_r).powi(2))
    .sqrt();
    let exact = -(pf[2] / (friction.e_r * friction.e_r)) / norm;
    assert!((worst.analytic - (exact + 0.5)).abs() < 1e-12, "{bad}");
    assert!((worst.numeric - exact).abs() < 1e-6, "{bad}");
    assert!((bad.max_abs_error - 0.5).abs() < 1e-6, "{bad}");
    let text = bad.to_string();
    assert!(
        text.contains("FAILED") && text.contains("planted[0] / input1[2]"),
        "{text}"
    );
}

// ---------------------------------------------------------------------------------------------
// The assembled step MCP of every scenario
// ---------------------------------------------------------------------------------------------

/// A T-bar (slanted hull faces) at rest flat on the ground, sliding and spinning.
fn t_bar_scene() -> Scene {
    let shape = Shape::t_bar();
    let hull = shape.hull().expect("valid T-bar");
    let bottom = hull
        .vertices()
        .iter()
        .map(|v| v.z)
        .fold(f64::INFINITY, f64::min);
    Scene {
        name: "t_bar".into(),
        bodies: vec![BodySpec {
            name: "t_bar".into(),
            mass: MassProperties::t_bar(0.5).expect("positive mass"),
            shape,
            initial: BodyState {
                x: V3::new(0.0, 0.0, -bottom),
                q: Vector4::new(1.0, 0.0, 0.0, 0.0),
                v: V3::new(0.2, -0.1, 0.0),
                w: V3::new(0.0, 0.0, 1.0),
            },
            load: Load::None,
        }],
        planes: vec![HalfSpace::ground()],
        friction: FrictionParams {
            mu: 0.3,
            e_t: 1.0,
            e_o: 1.0,
            e_r: 0.05,
        },
        gravity: V3::new(0.0, 0.0, -scenarios::G),
        h: 0.01,
        duration: 0.1,
        world: Default::default(),
    }
}

/// The A1 box with a second half-space (a tilted wall): two contacts on one body, so the
/// Newton–Euler block of the assembled MCP reads two contact sets.
fn two_plane_scene() -> Scene {
    let mut scene = scenarios::a1_sliding();
    scene.name = "box_and_wall".into();
    scene
        .planes
        .push(HalfSpace::new(V3::new(-1.0, 0.2, 0.3), -0.5).expect("non-zero normal"));
    scene
}

fn all_scenes() -> Vec<Scene> {
    vec![
        scenarios::a1_sliding(),
        scenarios::a2_push(20.0),
        scenarios::a2_push(40.0),
        scenarios::a3_spin(),
        scenarios::a4_incline(10.0),
        scenarios::a4_incline(25.0),
        scenarios::a5_drop(),
        scenarios::a5_drop_tilted(),
        scenarios::a6_tip(90.0),
        scenarios::a6_tip(110.0),
        scenarios::desk(),
        t_bar_scene(),
        two_plane_scene(),
    ]
}

/// Checks every residual block of the prepared step MCP at `z` with respect to every input,
/// variables and data blocks; `what` names the point.
fn check_mcp_at(sim: &Simulation, z: &[f64], what: &str) -> Result<(), TestCaseError> {
    let mcp = sim.mcp();
    let reports = check_problem(mcp, z, &CheckOptions::default());
    prop_assert_eq!(
        reports.len(),
        mcp.num_residual_blocks(),
        "{}: some residual blocks were not checked",
        what
    );
    for rep in &reports {
        prop_assert!(rep.ok(), "{} ({}):\n{}", sim.scene().name, what, rep);
    }
    // The blocks that read data: Newton–Euler (6 data inputs) and the kinematic map (2) per body,
    // C4, C5 (1 each) and the two friction blocks (1 each) per contact.
    let data_pairs = reports
        .iter()
        .flat_map(|r| &r.pairs)
        .filter(|p| p.kind == Some(InputKind::Data))
        .count();
    prop_assert_eq!(
        data_pairs,
        8 * sim.scene().bodies.len() + 4 * sim.handles().contacts.len(),
        "{}: not every data input was checked",
        what
    );
    Ok(())
}

#[test]
fn every_scenario_mcp_at_its_warm_start() {
    for scene in all_scenes() {
        let mut sim = Simulation::new(scene).expect("valid scenario");
        sim.prepare_step().expect("step data");
        let z = sim.z().to_vec();
        assert_eq!(z.len(), sim.mcp().dim());
        check_mcp_at(&sim, &z, "warm start").expect("warm start");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Random perturbations of the warm start of every scenario's first step, with the
    /// end-of-step quaternion rescaled to a non-unit norm.
    #[test]
    fn every_scenario_mcp_at_perturbed_points(
        noise in prop::collection::vec(-1.0..1.0f64, 96),
        scale in prop_oneof![Just(1e-3), 0.01..0.5f64],
        q_norm in 0.5..2.0f64,
    ) {
        for scene in all_scenes() {
            let mut sim = Simulation::new(scene).expect("valid scenario");
            sim.prepare_step().expect("step data");
            let mut z = sim.z().to_vec();
            prop_assert!(z.len() <= noise.len());
            for (zi, d) in z.iter_mut().zip(&noise) {
                *zi += scale * d * (1.0 + zi.abs());
            }
            // Rescale each body's quaternion (components 3..7 of every ".q" block).
            let mcp = sim.mcp();
            for (i, vb) in mcp.variable_blocks().iter().enumerate() {
                if vb.name().ends_with(".q") {
                    let o = mcp.offset(VarId(i));
                    let q = Vector4::new(z[o + 3], z[o + 4], z[o + 5], z[o + 6]);
                    let q = q * (q_norm / q.norm());
                    z[o + 3..o + 7].copy_from_slice(q.as_slice());
                }
            }
            check_mcp_at(&sim, &z, "perturbed")?;
        }
    }
}
