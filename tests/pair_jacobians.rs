//! Property tests of the analytic Jacobians of the blocks of a contact between two bodies
//! (`docs/model.md#contact-between-two-bodies`): (K1)–(K4), the face rows of both bodies, the
//! friction rows on the relative velocity, the cone row and the wrench terms on both bodies,
//! assembled by `add_pair_contact` into a step problem and checked with `check_problem` against
//! central differences with respect to every input, variable or data.
//!
//! Random cases: F and G are boxes or hulls of random point sets, at random poses with NON-UNIT
//! quaternions (the end-of-step Q is four free unknowns), with random velocities; each body's
//! `ν` and `q` are independently variables (a dynamic body, which also gets its Newton–Euler
//! rows and the wrench term) or data (a fixed or kinematic body). The ECPs are free points or
//! points of the hulls, the multipliers and impulses are random with exact zeros among them, the
//! reference axis is the one the steppers choose or a random one. One test plants a wrong
//! derivative in a pair block and checks that the checker finds it.

mod common;

use common::strategies::{unit_quat, unit3, vec3};

use ecp::formulations::blocks::{
    FaceSet, FrictionParams, KinematicMap, NewtonEuler, PairBody, PairFrame, PairFriction,
    SupportNormal, add_body_data, add_pair_contact, add_pair_data, add_scene_data, reference_axis,
    start_values,
};
use ecp::formulations::geometry::{ConvexHull, Shape};
use ecp::model::{
    BlockMcp, CheckOptions, DataBlock, Input, InputKind, JacobianBlocks, Mcp, Params, Problem,
    ResidualBlock, VarBlock, check_problem, check_residual_block,
};
use nalgebra::{Matrix3, Vector3, Vector4};
use proptest::prelude::*;

type V3 = Vector3<f64>;

/// A quaternion of norm between 0.5 and 2.
fn non_unit_quat() -> impl Strategy<Value = Vector4<f64>> {
    (unit_quat(), 0.5..2.0f64).prop_map(|(q, s)| q * s)
}

/// A box, or the hull of 5–14 random points.
fn hull() -> impl Strategy<Value = ConvexHull> {
    prop_oneof![
        (0.05..1.0f64, 0.05..1.0f64, 0.05..1.0f64).prop_map(|(a, b, c)| {
            Shape::cuboid(a, b, c)
                .and_then(|s| s.hull())
                .expect("positive box")
        }),
        prop::collection::vec(vec3(-0.5, 0.5), 5..14)
            .prop_filter_map("points spanning a volume", |p| ConvexHull::from_points(&p)
                .ok()),
    ]
}

fn six(lo: f64, hi: f64) -> impl Strategy<Value = [f64; 6]> {
    (vec3(lo, hi), vec3(lo, hi)).prop_map(|(a, b)| [a.x, a.y, a.z, b.x, b.y, b.z])
}

fn maybe_zero(hi: f64) -> impl Strategy<Value = f64> {
    prop_oneof![Just(0.0), 0.0..hi]
}

/// One body: hull, pose, velocity, and whether `ν`, `q` are variables.
#[derive(Clone, Debug)]
struct Side {
    hull: ConvexHull,
    q: [f64; 7],
    nu: [f64; 6],
    var_nu: bool,
    var_q: bool,
    /// Where its ECP is: a free point, or between two hull vertices (`i`, `j`, `t`).
    point: (Option<V3>, usize, usize, f64),
    /// Face multipliers (first m used).
    mult: Vec<f64>,
}

fn side() -> impl Strategy<Value = Side> {
    (
        hull(),
        (vec3(-1.0, 1.0), non_unit_quat(), six(-3.0, 3.0)),
        (any::<bool>(), any::<bool>()),
        (
            prop_oneof![Just(None), vec3(-1.5, 1.5).prop_map(Some)],
            any::<usize>(),
            any::<usize>(),
            prop_oneof![Just(0.0), Just(0.5), 0.0..1.0f64],
        ),
        prop::collection::vec(maybe_zero(2.0), 40),
    )
        .prop_map(|(hull, (x, q, nu), (var_nu, var_q), point, mult)| Side {
            hull,
            q: [x.x, x.y, x.z, q[0], q[1], q[2], q[3]],
            nu,
            var_nu,
            var_q,
            point,
            mult,
        })
}

impl Side {
    fn point(&self) -> V3 {
        match self.point {
            (Some(p), ..) => p,
            (None, i, j, t) => {
                let v = self.hull.vertices();
                let (vi, vj) = (v[i % v.len()], v[j % v.len()]);
                let r = ecp::formulations::rotation::rotation_matrix(&Vector4::new(
                    self.q[3], self.q[4], self.q[5], self.q[6],
                ));
                V3::new(self.q[0], self.q[1], self.q[2]) + r * (vi + (vj - vi) * t)
            }
        }
    }
    fn multipliers(&self) -> Vec<f64> {
        self.mult[..self.hull.num_faces()].to_vec()
    }
}

#[derive(Clone, Debug)]
struct Case {
    f: Side,
    g: Side,
    d: f64,
    pn: f64,
    pf: [f64; 3],
    sigma: f64,
    friction: FrictionParams,
    /// A random reference axis instead of the one least aligned with the normal.
    axis: Option<V3>,
    scale: f64,
}

fn case() -> impl Strategy<Value = Case> {
    (
        side(),
        side(),
        (prop_oneof![Just(0.0), -0.2..0.5f64], maybe_zero(20.0)),
        ((-5.0..5.0f64, -5.0..5.0f64, -1.0..1.0f64), maybe_zero(5.0)),
        (maybe_zero(1.5), 0.5..2.0f64, 0.5..2.0f64, 0.02..0.5f64),
        prop_oneof![Just(None), unit3().prop_map(Some)],
        prop_oneof![Just(1.0), Just(100.0), 0.1..1000.0f64],
    )
        .prop_map(
            |(f, g, (d, pn), ((pt, po, pr), sigma), (mu, e_t, e_o, e_r), axis, scale)| Case {
                f,
                g,
                d,
                pn,
                pf: [pt, po, pr],
                sigma,
                friction: FrictionParams { mu, e_t, e_o, e_r },
                axis,
                scale,
            },
        )
        .prop_filter("ν_G has a direction and the axis is off the normal", |c| {
            let nu = SupportNormal::new(
                &FaceSet::of_hull(&c.g.hull).normals,
                &c.g.multipliers(),
                &Vector4::new(c.g.q[3], c.g.q[4], c.g.q[5], c.g.q[6]),
            )
            .value;
            let axis = c.axis.unwrap_or_else(|| reference_axis(&nu));
            nu.norm() > 0.05 && nu.normalize().cross(&axis).norm() > 0.2
        })
}

/// The step problem of one pair contact, each body's `ν` and `q` variables or data as drawn, a
/// dynamic body with its Newton–Euler rows (and the wrench term) and its kinematic map; and the
/// point `z` of the case.
fn assemble(c: &Case) -> (BlockMcp, Vec<f64>) {
    let mut p = Problem::new();
    let scene = add_scene_data(&mut p, &V3::new(0.0, 0.0, -9.8), 0.01, &c.friction);
    let faces = [FaceSet::of_hull(&c.f.hull), FaceSet::of_hull(&c.g.hull)];
    let mut values: Vec<(Input, Vec<f64>)> = Vec::new();
    let mut inputs = Vec::new();
    for (k, s) in [&c.f, &c.g].into_iter().enumerate() {
        let name = ["F", "G"][k];
        let nu = if s.var_nu {
            Input::Var(p.add_variable_block(VarBlock::free(format!("{name}.nu"), 6)))
        } else {
            Input::Data(p.add_data_block(DataBlock::new(format!("{name}.nu"), s.nu)))
        };
        let q = if s.var_q {
            Input::Var(p.add_variable_block(VarBlock::free(format!("{name}.q"), 7)))
        } else {
            Input::Data(p.add_data_block(DataBlock::new(format!("{name}.q"), s.q)))
        };
        values.push((nu, s.nu.to_vec()));
        values.push((q, s.q.to_vec()));
        let inertia = Matrix3::from_diagonal(&V3::new(0.4, 0.5, 0.6));
        let body = add_body_data(&mut p, name, 2.0, &inertia);
        let start = start_values(
            &V3::new(0.1, 0.0, 0.3),
            &Vector4::new(0.9, 0.1, -0.2, 0.3).normalize(),
            &V3::new(0.5, 0.0, -0.2),
            &V3::new(0.0, 1.0, 0.3),
        );
        if let Input::Var(v) = nu {
            let mut reads = vec![nu, q];
            reads.extend(
                [
                    body.mass,
                    body.inertia,
                    body.start,
                    body.wrench,
                    scene.gravity,
                    scene.h,
                ]
                .map(Input::from),
            );
            p.add_residual_block(v, NewtonEuler::new(vec![]), reads)
                .expect("newton-euler");
        }
        if let Input::Var(v) = q {
            p.add_residual_block(v, KinematicMap, &[q, nu, body.start.into(), scene.h.into()])
                .expect("kinematic map");
        }
        inputs.push((nu, q, body.start, start));
    }
    let nu_g = SupportNormal::new(
        &faces[1].normals,
        &c.g.multipliers(),
        &Vector4::new(c.g.q[3], c.g.q[4], c.g.q[5], c.g.q[6]),
    )
    .value;
    let axis = c.axis.unwrap_or_else(|| reference_axis(&nu_g));
    let data = add_pair_data(&mut p, "pair", &c.friction, &axis);
    let body = |k: usize| PairBody {
        nu: inputs[k].0,
        q: inputs[k].1,
        faces: &faces[k],
    };
    let vars =
        add_pair_contact(&mut p, "pair", &body(0), &body(1), data, c.scale).expect("pair contact");
    let mut mcp = p.build().expect("problem");
    for (_, _, start, values) in &inputs {
        mcp.set_data(*start, values).expect("start");
    }
    let mut z = vec![0.0; mcp.dim()];
    for (input, v) in &values {
        if let Input::Var(id) = input {
            z[mcp.range(*id)].copy_from_slice(v);
        }
    }
    let put = |z: &mut [f64], id, v: &[f64]| z[mcp.range(id)].copy_from_slice(v);
    put(&mut z, vars.a1, c.f.point().as_slice());
    put(&mut z, vars.a2, c.g.point().as_slice());
    put(&mut z, vars.l, &c.f.multipliers());
    put(&mut z, vars.mu, &c.g.multipliers());
    put(&mut z, vars.d, &[c.d]);
    put(&mut z, vars.pn, &[c.pn]);
    put(&mut z, vars.pf, &c.pf);
    put(&mut z, vars.sigma, &[c.sigma]);
    (mcp, z)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Every block of the assembled pair contact, with respect to every input.
    #[test]
    fn pair_contact_blocks(c in case()) {
        let (mcp, z) = assemble(&c);
        // The central differences' round-off grows with the row scale of the length rows.
        let opts = CheckOptions {
            abs_tol: CheckOptions::default().abs_tol * c.scale.max(1.0),
            ..CheckOptions::default()
        };
        let reports = check_problem(&mcp, &z, &opts);
        for r in &reports {
            prop_assert!(r.ok(), "{}", r);
        }
        let names: Vec<&str> = reports.iter().map(|r| r.name.split(' ').next().unwrap_or("")).collect();
        let mut expected = vec!["pair_k1", "pair_k2", "pair_k3", "ecp_c3", "ecp_c3", "pair_k4", "pair_friction", "friction_ellipsoid"];
        if c.f.var_nu { expected.push("pair_wrench_f"); }
        if c.g.var_nu { expected.push("pair_wrench_g"); }
        for e in expected {
            prop_assert!(names.contains(&e), "{e} not checked: {names:?}");
        }
        let wrench_terms = names.iter().filter(|n| n.starts_with("pair_wrench")).count();
        prop_assert_eq!(wrench_terms, usize::from(c.f.var_nu) + usize::from(c.g.var_nu));
        // Data inputs were compared too.
        let data_pairs = reports.iter().flat_map(|r| &r.pairs).filter(|p| p.kind == Some(InputKind::Data)).count();
        prop_assert!(data_pairs >= 3);
    }

    /// The frame is a right-handed orthonormal triad whose normal is ν_G / |ν_G|.
    #[test]
    fn pair_frame_is_orthonormal(nu in vec3(-2.0, 2.0), axis in unit3()) {
        prop_assume!(nu.norm() > 1e-3 && nu.normalize().cross(&axis).norm() > 1e-3);
        let f = PairFrame::new(&nu, &axis);
        let m = Matrix3::from_columns(&[f.n, f.t, f.o]);
        prop_assert!((m.transpose() * m - Matrix3::identity()).norm() < 1e-12);
        prop_assert!((m.determinant() - 1.0).abs() < 1e-12);
        prop_assert!((f.n - nu.normalize()).norm() < 1e-14);
    }
}

/// PairFriction with one planted error in a derivative through the normal: `∂r_0/∂μ_1` off by
/// 0.25.
struct Planted(PairFriction);

impl ResidualBlock for Planted {
    fn name(&self) -> &str {
        "planted"
    }
    fn num_residuals(&self) -> usize {
        3
    }
    fn parameter_sizes(&self) -> &[usize] {
        self.0.parameter_sizes()
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        self.0.evaluate(x, out);
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        self.0.jacobian(x, jac);
        jac.add(PairFriction::MU, 0, 1, 0.25);
    }
}

#[test]
fn checker_finds_a_planted_error_in_a_pair_block() {
    let normals = vec![V3::z(), V3::new(0.0, 0.6, 0.8), -V3::x()];
    let params: [&[f64]; 12] = [
        &[1.0, -0.3, 0.2, 0.4, -0.5, 2.0],
        &[0.0, 0.1, 0.5, 0.9, 0.1, 0.2, -0.3],
        &[0.2, 0.1, 0.0, 0.0, 0.3, -0.4],
        &[0.1, 0.0, 0.2, 0.8, -0.3, 0.1, 0.2],
        &[0.05, -0.1, 0.3],
        &[0.05, -0.1, 0.25],
        &[0.6, 0.4, 0.0],
        &[2.0],
        &[-0.3, 0.1, 0.02],
        &[0.5],
        &[0.4, 1.0, 0.8, 0.05],
        &[1.0, 0.0, 0.0],
    ];
    let good = check_residual_block(
        &PairFriction::new(normals.clone()),
        &params,
        &CheckOptions::default(),
    )
    .expect("sizes");
    assert!(good.ok(), "{good}");
    let bad = check_residual_block(
        &Planted(PairFriction::new(normals)),
        &params,
        &CheckOptions::default(),
    )
    .expect("sizes");
    assert_eq!(bad.failures, 1, "{bad}");
    let worst = &bad.worst[0];
    assert!(
        worst.failed && (worst.row, worst.block, worst.col) == (0, PairFriction::MU, 1),
        "{bad}"
    );
    assert!(
        (worst.analytic - worst.numeric - 0.25).abs() < 1e-7,
        "{bad}"
    );
}
