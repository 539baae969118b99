//! Contacts between two bodies (`docs/model.md#contact-between-two-bodies`) in step problems
//! assembled BY HAND from the body blocks (Newton–Euler, kinematic map), the half-space contact
//! blocks (C1–C5 and friction, for a body on the ground) and the pair blocks
//! (`ecp::formulations::blocks::add_pair_contact`), solved with the registry's Newton and PATH
//! backends:
//!
//! - a half-space given as a fixed one-face body reproduces scenario A1 of the half-space
//!   stepper to 1e-12;
//! - D1, the stack at rest, and D2, the offset stack, hold the numbers of the reference
//!   (velocities 1e-9, ECPs 1e-8, impulses 1e-9);
//! - two free bodies colliding (no ground, no gravity) keep their total linear momentum to
//!   1e-12 at every step.
//!
//! Every step must converge to a natural residual ≤ 1e-10; a step that does not fails the test.

use ecp::formulations::Simulation;
use ecp::formulations::blocks::{
    BodyDataIds, ClosestPointAlignment, ContactFrame, FaceSet, FrictionDissipation,
    FrictionEllipsoid, FrictionParams, HalfSpaceSide, HullFaces, KinematicMap, NewtonEuler,
    NonPenetration, NormalCone, PairBody, PairContactValues, PairContactVars, PairDataIds,
    PairMotion, SupportNormal, add_body_data, add_pair_contact, add_pair_data, add_plane_data,
    add_scene_data, pair_guess, reference_axis, start_values,
};
use ecp::formulations::geometry::{
    ConvexHull, HalfSpace, HullPose, MassProperties, Shape, pair_features, predicted_pose,
};
use ecp::formulations::rotation::{quat_normalize, rotation_matrix};
use ecp::formulations::scenarios;
use ecp::model::{
    BlockMcp, DataBlock, DataId, Input, McpSolver, Problem, VarBlock, VarId, residual_of,
};
use ecp::solvers::{BackendOptions, Registry};
use nalgebra::{Matrix3, Vector3, Vector4};

type V3 = Vector3<f64>;

const G: f64 = 9.8;
const H: f64 = 0.01;

// ---------------------------------------------------------------------------------------------
// A small hand-built multi-body step problem
// ---------------------------------------------------------------------------------------------

/// A dynamic box.
#[derive(Clone, Debug)]
struct BodyDef {
    name: &'static str,
    mass: f64,
    inertia: Matrix3<f64>,
    hull: ConvexHull,
    x: V3,
    q: Vector4<f64>,
    v: V3,
    w: V3,
}

fn cuboid(name: &'static str, mass: f64, size: [f64; 3], x: V3) -> BodyDef {
    let [lx, ly, lz] = size;
    BodyDef {
        name,
        mass,
        inertia: MassProperties::solid_cuboid(mass, lx, ly, lz)
            .expect("positive box")
            .inertia,
        hull: Shape::cuboid(lx, ly, lz)
            .and_then(|s| s.hull())
            .expect("positive box"),
        x,
        q: Vector4::new(1.0, 0.0, 0.0, 0.0),
        v: V3::zeros(),
        w: V3::zeros(),
    }
}

/// The other body of a pair contact.
#[derive(Clone, Copy, Debug)]
enum Partner {
    /// A dynamic body.
    Body(usize),
    /// The ground z ≤ 0 as a fixed one-face body (pose and velocity are data).
    FixedGround,
    /// A kinematic body of `WorldDef::kinematic` (pose and velocity are data, set per step).
    Kinematic(usize),
}

/// What a world holds: dynamic bodies, the bodies with a half-space contact on the ground z ≤ 0
/// (the existing C1–C5 blocks), and pair contacts (F, G) with their friction.
struct WorldDef {
    bodies: Vec<BodyDef>,
    ground: Vec<usize>,
    pairs: Vec<(usize, Partner, FrictionParams)>,
    ground_friction: FrictionParams,
    gravity: V3,
    /// Kinematic bodies moving at a constant velocity `u` (their `x` is the pose at the start of
    /// the step).
    kinematic: Vec<(BodyDef, V3)>,
}

/// A half-space contact's unknowns.
#[derive(Clone, Copy)]
struct GroundVars {
    body: usize,
    a1: VarId,
    a2: VarId,
    l: VarId,
    lg: VarId,
    pn: VarId,
    pf: VarId,
    sigma: VarId,
}

struct PairState {
    f: usize,
    g: Partner,
    vars: PairContactVars,
    data: PairDataIds,
    friction: FrictionParams,
    /// The normal at the end of the last step (the frame's reference axis is chosen from it).
    normal: V3,
}

/// Values of the unknowns of one step, per body and per contact.
#[derive(Clone, Debug)]
struct Record {
    x: Vec<V3>,
    q: Vec<Vector4<f64>>,
    v: Vec<V3>,
    w: Vec<V3>,
    /// Half-space contacts: (a1, p_n, p_f).
    ground: Vec<(V3, f64, [f64; 3])>,
    pairs: Vec<PairContactValues>,
    residual: f64,
    retried: bool,
    iterations: usize,
}

struct World {
    def: WorldDef,
    mcp: BlockMcp,
    z: Vec<f64>,
    nu: Vec<VarId>,
    q: Vec<VarId>,
    body_data: Vec<BodyDataIds>,
    ground: Vec<GroundVars>,
    pairs: Vec<PairState>,
    ground_faces: FaceSet,
    faces: Vec<FaceSet>,
    kinematic_faces: Vec<FaceSet>,
    /// The `ν` and end-of-step `q` data blocks of each kinematic body.
    kinematic_data: Vec<(DataId, DataId)>,
}

fn ground_frame() -> ContactFrame {
    let (n, t, o) = HalfSpace::ground().contact_frame();
    ContactFrame { n, t, o }
}

impl World {
    fn new(def: WorldDef) -> Self {
        let mut p = Problem::new();
        let scene = add_scene_data(&mut p, &def.gravity, H, &def.ground_friction);
        let plane = add_plane_data(&mut p, 0, 0.0);
        let faces: Vec<FaceSet> = def
            .bodies
            .iter()
            .map(|b| FaceSet::of_hull(&b.hull))
            .collect();
        let ground_faces = FaceSet::half_space(&V3::z(), 0.0).expect("unit normal");
        let mut nu = Vec::new();
        let mut q = Vec::new();
        let mut body_data = Vec::new();
        for b in &def.bodies {
            nu.push(p.add_variable_block(VarBlock::free(format!("{}.nu", b.name), 6)));
            q.push(p.add_variable_block(VarBlock::free(format!("{}.q", b.name), 7)));
            body_data.push(add_body_data(&mut p, b.name, b.mass, &b.inertia));
        }
        let mut ground = Vec::new();
        for &b in &def.ground {
            let tag = format!("{}.ground", def.bodies[b].name);
            let m = faces[b].len();
            ground.push(GroundVars {
                body: b,
                a1: p.add_variable_block(VarBlock::free(format!("{tag}.a1"), 3)),
                a2: p.add_variable_block(VarBlock::free(format!("{tag}.a2"), 3)),
                l: p.add_variable_block(VarBlock::nonnegative(format!("{tag}.l"), m)),
                lg: p.add_variable_block(VarBlock::nonnegative(format!("{tag}.lg"), 1)),
                pn: p.add_variable_block(VarBlock::nonnegative(format!("{tag}.pn"), 1)),
                pf: p.add_variable_block(VarBlock::free(format!("{tag}.pf"), 3)),
                sigma: p.add_variable_block(VarBlock::nonnegative(format!("{tag}.sigma"), 1)),
            });
        }
        // The fixed ground as a body: pose and velocity are data.
        let fixed_nu = p.add_data_block(DataBlock::new("ground.nu", [0.0; 6]));
        let fixed_q = p.add_data_block(DataBlock::new(
            "ground.q",
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        ));
        let kinematic_faces: Vec<FaceSet> = (def.kinematic.iter())
            .map(|(b, _)| FaceSet::of_hull(&b.hull))
            .collect();
        let kinematic_data: Vec<(DataId, DataId)> = (def.kinematic.iter())
            .map(|(b, u)| {
                (
                    p.add_data_block(DataBlock::new(
                        format!("{}.nu", b.name),
                        [u.x, u.y, u.z, 0.0, 0.0, 0.0],
                    )),
                    p.add_data_block(DataBlock::new(format!("{}.q", b.name), [0.0; 7])),
                )
            })
            .collect();
        // Newton–Euler (with the half-space contacts) and the kinematic map of every body.
        for (b, body) in def.bodies.iter().enumerate() {
            let _ = body;
            let mine: Vec<&GroundVars> = ground.iter().filter(|c| c.body == b).collect();
            let mut reads: Vec<Input> = vec![nu[b].into(), q[b].into()];
            for c in &mine {
                reads.extend([c.a1, c.pn, c.pf].map(Input::from));
            }
            let d = body_data[b];
            reads.extend(
                [d.mass, d.inertia, d.start, d.wrench, scene.gravity, scene.h].map(Input::from),
            );
            let frames = vec![ground_frame(); mine.len()];
            p.add_residual_block(nu[b], NewtonEuler::new(frames), reads)
                .expect("newton-euler");
            p.add_residual_block(
                q[b],
                KinematicMap,
                &[
                    q[b].into(),
                    nu[b].into(),
                    Input::from(d.start),
                    scene.h.into(),
                ],
            )
            .expect("kinematic map");
        }
        let scale = 1.0 / H;
        for c in &ground {
            let n = V3::z();
            let f = &faces[c.body];
            let qb = q[c.body];
            p.add_residual_block(
                c.a1,
                ClosestPointAlignment { normal: n, scale },
                &[c.a1, c.a2, c.lg],
            )
            .expect("c1");
            p.add_residual_block(c.a2, NormalCone::new(n, f.normals.clone()), &[c.l, qb])
                .expect("c2");
            p.add_residual_block(
                c.l,
                HullFaces {
                    face_normals: f.normals.clone(),
                    offsets: f.offsets.clone(),
                    scale,
                },
                &[c.a1, qb],
            )
            .expect("c3");
            p.add_residual_block(
                c.lg,
                HalfSpaceSide { normal: n, scale },
                &[c.a2.into(), Input::from(plane)],
            )
            .expect("c4");
            p.add_residual_block(
                c.pn,
                NonPenetration { normal: n, scale },
                &[c.a1.into(), Input::from(plane)],
            )
            .expect("c5");
            let mut reads: Vec<Input> = [nu[c.body], qb, c.a1, c.pn, c.pf, c.sigma]
                .map(Input::from)
                .to_vec();
            reads.push(scene.friction.into());
            p.add_residual_block(
                c.pf,
                FrictionDissipation {
                    frame: ground_frame(),
                },
                reads,
            )
            .expect("friction");
            p.add_residual_block(
                c.sigma,
                FrictionEllipsoid,
                &[c.pn.into(), c.pf.into(), Input::from(scene.friction)],
            )
            .expect("cone");
        }
        let mut pairs = Vec::new();
        for (k, &(fi, g, friction)) in def.pairs.iter().enumerate() {
            let tag = format!("pair{k}");
            let data = add_pair_data(&mut p, &tag, &friction, &V3::x());
            let fb = PairBody {
                nu: nu[fi].into(),
                q: q[fi].into(),
                faces: &faces[fi],
            };
            let gb = match g {
                Partner::Body(gi) => PairBody {
                    nu: nu[gi].into(),
                    q: q[gi].into(),
                    faces: &faces[gi],
                },
                Partner::FixedGround => PairBody {
                    nu: fixed_nu.into(),
                    q: fixed_q.into(),
                    faces: &ground_faces,
                },
                Partner::Kinematic(ki) => PairBody {
                    nu: kinematic_data[ki].0.into(),
                    q: kinematic_data[ki].1.into(),
                    faces: &kinematic_faces[ki],
                },
            };
            let vars = add_pair_contact(&mut p, &tag, &fb, &gb, data, scale).expect("pair contact");
            pairs.push(PairState {
                f: fi,
                g,
                vars,
                data,
                friction,
                normal: V3::z(),
            });
        }
        let mcp = p.build().expect("step problem");
        let z = vec![0.0; ecp::model::Mcp::dim(&mcp)];
        let mut world = World {
            def,
            mcp,
            z,
            nu,
            q,
            body_data,
            ground,
            pairs,
            ground_faces,
            faces,
            kinematic_faces,
            kinematic_data,
        };
        world.initial_guess();
        world
    }

    fn put(&mut self, v: VarId, values: &[f64]) {
        let r = self.mcp.range(v);
        self.z[r].copy_from_slice(values);
    }

    fn get(&self, v: VarId) -> &[f64] {
        &self.z[self.mcp.range(v)]
    }

    fn motion(&self, b: usize) -> PairMotion {
        let d = &self.def.bodies[b];
        PairMotion {
            mass: Some(d.mass),
            x: d.x,
            v: d.v,
            w: d.w,
        }
    }

    fn hull_pose(&self, b: usize, predicted: bool) -> HullPose<'_> {
        let d = &self.def.bodies[b];
        let (x, rotation) = if predicted {
            predicted_pose(&d.x, &d.q, &(d.v + self.def.gravity * H), &d.w, H)
                .expect("finite state")
        } else {
            (d.x, rotation_matrix(&d.q))
        };
        HullPose {
            hull: &d.hull,
            x,
            rotation,
        }
    }

    /// The first step's guess: bodies at their state, contacts from the closest features.
    fn initial_guess(&mut self) {
        for b in 0..self.def.bodies.len() {
            let d = &self.def.bodies[b];
            let (nu, q) = (
                [d.v.x, d.v.y, d.v.z, d.w.x, d.w.y, d.w.z],
                [d.x.x, d.x.y, d.x.z, d.q[0], d.q[1], d.q[2], d.q[3]],
            );
            let (vn, vq) = (self.nu[b], self.q[b]);
            self.put(vn, &nu);
            self.put(vq, &q);
        }
        for c in 0..self.ground.len() {
            self.ground_guess(c, false);
        }
        for k in 0..self.pairs.len() {
            self.pair_guess(k, false);
        }
    }

    /// A half-space contact's guess, as the stepper's: `a1` the centroid of the lowest vertices,
    /// `a2` below it, the bottom-most face's multiplier 1; touching: the body's weight and the
    /// friction impulse against the slip.
    fn ground_guess(&mut self, c: usize, active: bool) {
        let gv = self.ground[c];
        let d = &self.def.bodies[gv.body];
        let r = rotation_matrix(&d.q);
        let world: Vec<V3> = d.hull.vertices().iter().map(|v| d.x + r * v).collect();
        let low = world.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
        let lowest: Vec<&V3> = world.iter().filter(|p| p.z <= low + 1e-9).collect();
        let a1 = lowest.iter().fold(V3::zeros(), |s, p| s + **p) / lowest.len() as f64;
        let mut l = vec![0.0; d.hull.num_faces()];
        l[d.hull.most_aligned_face(&(r.transpose() * -V3::z()))] = 1.0;
        let f = self.def.ground_friction;
        let vs = d.v + d.w.cross(&(a1 - d.x));
        let slip =
            ((f.e_t * vs.x).powi(2) + (f.e_o * vs.y).powi(2) + (f.e_r * d.w.z).powi(2)).sqrt();
        let floor = (self.def.gravity.norm() * H).max(1e-3);
        let (mut pn, mut pf, mut sigma) = (0.0, [0.0; 3], slip.max(floor));
        if low <= 1e-9 || active {
            pn = d.mass * self.def.gravity.norm() * H;
            if slip > 1e-12 {
                let k = -f.mu * pn / slip;
                pf = [
                    k * f.e_t * f.e_t * vs.x,
                    k * f.e_o * f.e_o * vs.y,
                    k * f.e_r * f.e_r * d.w.z,
                ];
                sigma = slip;
            }
        }
        self.put(gv.a1, a1.as_slice());
        self.put(gv.a2, &[a1.x, a1.y, 0.0]);
        self.put(gv.l, &l);
        self.put(gv.lg, &[low.max(0.0)]);
        self.put(gv.pn, &[pn]);
        self.put(gv.pf, &pf);
        self.put(gv.sigma, &[sigma]);
    }

    /// A pair contact's guess from the closest features at the current poses, or (`retry`)
    /// from the overlapping features at the predicted end-of-step poses with active impulses.
    fn pair_guess(&mut self, k: usize, retry: bool) {
        let (fi, g, friction) = (self.pairs[k].f, self.pairs[k].g, self.pairs[k].friction);
        let fixed = PairMotion {
            mass: None,
            x: V3::zeros(),
            v: V3::zeros(),
            w: V3::zeros(),
        };
        let (features, gm) = match g {
            Partner::Body(gi) => (
                pair_features(&self.hull_pose(fi, retry), &self.hull_pose(gi, retry))
                    .expect("features"),
                self.motion(gi),
            ),
            Partner::Kinematic(ki) => {
                let (b, u) = &self.def.kinematic[ki];
                let offset = if retry { u * H } else { V3::zeros() };
                let pose = HullPose {
                    hull: &b.hull,
                    x: b.x + offset,
                    rotation: rotation_matrix(&b.q),
                };
                (
                    pair_features(&self.hull_pose(fi, retry), &pose).expect("features"),
                    PairMotion {
                        mass: None,
                        x: b.x,
                        v: *u,
                        w: V3::zeros(),
                    },
                )
            }
            Partner::FixedGround => {
                // A one-face G: its closest feature is the plane; F's the lowest vertices.
                let d = &self.def.bodies[fi];
                let r = rotation_matrix(&d.q);
                let world: Vec<V3> = d.hull.vertices().iter().map(|v| d.x + r * v).collect();
                let low = world.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
                let lowest: Vec<&V3> = world.iter().filter(|p| p.z <= low + 1e-9).collect();
                let a1 = lowest.iter().fold(V3::zeros(), |s, p| s + **p) / lowest.len() as f64;
                let mut l = vec![0.0; d.hull.num_faces()];
                l[d.hull.most_aligned_face(&(r.transpose() * -V3::z()))] = 1.0;
                (
                    ecp::formulations::geometry::PairFeatures {
                        a1,
                        a2: V3::new(a1.x, a1.y, 0.0),
                        d: low.max(0.0),
                        l,
                        mu: vec![1.0],
                        normal: V3::z(),
                        distance: low,
                        face_to_face: true,
                    },
                    fixed,
                )
            }
        };
        let axis = reference_axis(&features.normal);
        self.mcp
            .set_data(self.pairs[k].data.axis, axis.as_slice())
            .expect("axis");
        self.pairs[k].normal = features.normal;
        let values = pair_guess(
            &features,
            &self.motion(fi),
            &gm,
            &axis,
            &friction,
            &self.def.gravity,
            H,
            retry,
        );
        self.pairs[k]
            .vars
            .write(&self.mcp, &mut self.z, &values)
            .expect("sizes");
    }

    /// The normal of pair `k` in the current `z`.
    fn normal_in_z(&self, k: usize) -> V3 {
        let pc = &self.pairs[k];
        let mu = self.get(pc.vars.mu);
        let (faces, q) = match pc.g {
            Partner::Body(gi) => (
                &self.faces[gi],
                Vector4::from_column_slice(&self.get(self.q[gi])[3..7]),
            ),
            Partner::FixedGround => (&self.ground_faces, Vector4::new(1.0, 0.0, 0.0, 0.0)),
            Partner::Kinematic(ki) => (&self.kinematic_faces[ki], self.def.kinematic[ki].0.q),
        };
        SupportNormal::new(&faces.normals, mu, &q).value.normalize()
    }

    /// One step: start data, the frame's reference axis, a warm start, a solve and, when it
    /// fails, one deterministic retry from the predicted end-of-step poses.
    fn step(&mut self, solver: &mut dyn McpSolver) -> Record {
        for b in 0..self.def.bodies.len() {
            let d = &self.def.bodies[b];
            let start = start_values(&d.x, &d.q, &d.v, &d.w);
            self.mcp
                .set_data(self.body_data[b].start, &start)
                .expect("start");
        }
        for (ki, (b, u)) in self.def.kinematic.iter().enumerate() {
            let x = b.x + u * H;
            let q = [x.x, x.y, x.z, b.q[0], b.q[1], b.q[2], b.q[3]];
            self.mcp
                .set_data(self.kinematic_data[ki].1, &q)
                .expect("kinematic pose");
        }
        for k in 0..self.pairs.len() {
            let axis = reference_axis(&self.pairs[k].normal);
            self.mcp
                .set_data(self.pairs[k].data.axis, axis.as_slice())
                .expect("axis");
        }
        let mut retried = false;
        let sol = match solver.solve(&self.mcp, &self.z) {
            Ok(s) => s,
            Err(first) => {
                retried = true;
                for c in 0..self.ground.len() {
                    self.ground_guess(c, true);
                }
                for k in 0..self.pairs.len() {
                    self.pair_guess(k, true);
                }
                solver
                    .solve(&self.mcp, &self.z)
                    .unwrap_or_else(|e| panic!("step failed: {first}; retry: {e}"))
            }
        };
        let residual = residual_of(&self.mcp, &sol.z);
        assert!(residual <= 1e-10, "residual {residual:.3e}");
        self.z.copy_from_slice(&sol.z);
        let mut rec = Record {
            x: Vec::new(),
            q: Vec::new(),
            v: Vec::new(),
            w: Vec::new(),
            ground: Vec::new(),
            pairs: Vec::new(),
            residual,
            retried,
            iterations: sol.summary.iterations,
        };
        for b in 0..self.def.bodies.len() {
            let nu = self.get(self.nu[b]).to_vec();
            let q = self.get(self.q[b]).to_vec();
            let quat = quat_normalize(&Vector4::new(q[3], q[4], q[5], q[6])).expect("non-zero Q");
            let vq = self.q[b];
            self.put(vq, &[q[0], q[1], q[2], quat[0], quat[1], quat[2], quat[3]]);
            let d = &mut self.def.bodies[b];
            d.x = V3::new(q[0], q[1], q[2]);
            d.q = quat;
            d.v = V3::new(nu[0], nu[1], nu[2]);
            d.w = V3::new(nu[3], nu[4], nu[5]);
            rec.x.push(d.x);
            rec.q.push(d.q);
            rec.v.push(d.v);
            rec.w.push(d.w);
        }
        for (b, u) in &mut self.def.kinematic {
            b.x += *u * H;
        }
        for c in &self.ground {
            let pf = self.get(c.pf);
            rec.ground.push((
                V3::from_column_slice(self.get(c.a1)),
                self.get(c.pn)[0],
                [pf[0], pf[1], pf[2]],
            ));
        }
        for k in 0..self.pairs.len() {
            self.pairs[k].normal = self.normal_in_z(k);
            rec.pairs.push(self.pairs[k].vars.read(&self.mcp, &self.z));
        }
        rec
    }
}

fn solver(name: &str) -> Box<dyn McpSolver> {
    Registry::builtin()
        .build(name, &BackendOptions::default())
        .expect("builtin backend")
}

fn friction(mu: f64) -> FrictionParams {
    FrictionParams {
        mu,
        e_t: 1.0,
        e_o: 1.0,
        e_r: 0.1,
    }
}

fn close(what: &str, got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "{what}: got {got:.15}, want {want:.15} (tolerance {tol:e})"
    );
}

// ---------------------------------------------------------------------------------------------
// A half-space is a fixed one-face body
// ---------------------------------------------------------------------------------------------

/// A1 (`docs/model.md#scenarios`) with the ground given as a fixed one-face body and the pair
/// blocks: the same ν, q, ECP and impulses as the half-space stepper at every step, to 1e-12.
#[test]
fn a_one_face_fixed_body_reproduces_a1() {
    let scene = scenarios::a1_sliding();
    let steps = scene.num_steps();
    let mut sim = Simulation::new(scene.clone()).expect("valid scene");
    let spec = &scene.bodies[0];
    let mut body = cuboid("box", spec.mass.mass, scenarios::BOX_SIZE, spec.initial.x);
    body.v = spec.initial.v;
    let mut world = World::new(WorldDef {
        bodies: vec![body],
        ground: vec![],
        pairs: vec![(0, Partner::FixedGround, scene.friction)],
        ground_friction: scene.friction,
        gravity: scene.gravity,
        kinematic: vec![],
    });
    let mut newton = solver("newton");
    let mut reference = solver("newton");
    let mut worst: f64 = 0.0;
    for step in 1..=steps {
        let want = sim.step(reference.as_mut()).expect("half-space step");
        assert!(want.converged);
        let got = world.step(newton.as_mut());
        let c = &want.contacts[0];
        let p = &got.pairs[0];
        let b = &want.bodies[0];
        let pairs = [
            ("v", (got.v[0] - b.v).norm()),
            ("w", (got.w[0] - b.w).norm()),
            ("x", (got.x[0] - b.x).norm()),
            ("q", (got.q[0] - b.q).norm()),
            ("a1", (p.a1 - c.a1).norm()),
            ("a2", (p.a2 - c.a2).norm()),
            ("d = l_g", (p.d - c.lg).abs()),
            ("p_n", (p.pn - c.pn).abs()),
            ("p_t", (p.pf[0] - c.pt).abs()),
            ("p_o", (p.pf[1] - c.po).abs()),
            ("p_r", (p.pf[2] - c.pr).abs()),
            ("mu", (p.mu[0] - 1.0).abs()),
        ];
        for (what, err) in pairs {
            assert!(err <= 1e-12, "step {step}: {what} differs by {err:.3e}");
            worst = worst.max(err);
        }
    }
    // The box slid and stopped: the comparison covered both branches of the friction law.
    assert!(world.def.bodies[0].v.norm() < 1e-9);
    eprintln!("A1 as a one-face body: largest difference {worst:.3e} over {steps} steps");
}

// ---------------------------------------------------------------------------------------------
// D1, D2: stacks at rest (`bodies.md` §6)
// ---------------------------------------------------------------------------------------------

/// A (0.4 × 0.4 × 0.2 m, 2 kg) flat on the ground, B (0.2 m cube, 1 kg) on A with its CM at
/// `b_xy`, μ = 0.3 on both contacts.
fn stack(b_xy: (f64, f64)) -> World {
    let a = cuboid("A", 2.0, [0.4, 0.4, 0.2], V3::new(0.0, 0.0, 0.1));
    let b = cuboid("B", 1.0, [0.2, 0.2, 0.2], V3::new(b_xy.0, b_xy.1, 0.3));
    World::new(WorldDef {
        bodies: vec![a, b],
        ground: vec![0],
        pairs: vec![(1, Partner::Body(0), friction(0.3))],
        ground_friction: friction(0.3),
        gravity: V3::new(0.0, 0.0, -G),
        kinematic: vec![],
    })
}

fn check_stack(backend: &str, b_xy: (f64, f64), steps: usize) {
    let mut world = stack(b_xy);
    let mut s = solver(backend);
    let ground_ecp = V3::new(b_xy.0 / 3.0, b_xy.1 / 3.0, 0.0);
    let pair_ecp = V3::new(b_xy.0, b_xy.1, 0.2);
    let mut iterations = Vec::new();
    for step in 1..=steps {
        let r = world.step(s.as_mut());
        iterations.push(r.iterations);
        assert!(!r.retried, "{backend}: step {step} needed the retry");
        let at = format!("{backend}, B at {b_xy:?}, step {step}");
        for b in 0..2 {
            assert!(
                r.v[b].norm() <= 1e-9 && r.w[b].norm() <= 1e-9,
                "{at}: body {b} moves: v {} ω {}",
                r.v[b],
                r.w[b]
            );
        }
        let p = &r.pairs[0];
        close(&format!("{at}: p_n(B–A)"), p.pn, 1.0 * G * H, 1e-9);
        close(
            &format!("{at}: p_n(A–ground)"),
            r.ground[0].1,
            3.0 * G * H,
            1e-9,
        );
        assert!((p.a1 - pair_ecp).norm() <= 1e-8, "{at}: ECP(B–A) {}", p.a1);
        assert!((p.a2 - pair_ecp).norm() <= 1e-8, "{at}: a2(B–A) {}", p.a2);
        assert!(
            (r.ground[0].0 - ground_ecp).norm() <= 1e-8,
            "{at}: ECP(A–ground) {}",
            r.ground[0].0
        );
        let fr =
            p.pf.iter()
                .chain(&r.ground[0].2)
                .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(fr <= 1e-9, "{at}: friction impulse {fr:.3e}");
        close(&format!("{at}: d"), p.d, 0.0, 1e-12);
        assert!(
            (world.pairs[0].normal - V3::z()).norm() <= 1e-12,
            "{at}: normal"
        );
    }
    report(&format!("stack {b_xy:?}, {backend}"), &iterations);
}

/// Prints the iterations per step (for `docs/decisions.md`; run with `--nocapture`).
fn report(what: &str, iterations: &[usize]) {
    let max = iterations.iter().max().copied().unwrap_or(0);
    let mean = iterations.iter().sum::<usize>() as f64 / iterations.len().max(1) as f64;
    eprintln!(
        "{what}: {} steps, iterations mean {mean:.2} max {max}",
        iterations.len()
    );
}

/// D1 for 1 s with Newton.
#[test]
fn d1_stack_at_rest_newton() {
    check_stack("newton", (0.0, 0.0), 100);
}

/// D1 for 1 s with PATH.
#[test]
fn d1_stack_at_rest_path() {
    check_stack("path", (0.0, 0.0), 100);
}

/// D2 (B's CM at (0.1, 0.05)) for 0.2 s with Newton.
#[test]
fn d2_offset_stack_newton() {
    check_stack("newton", (0.1, 0.05), 20);
}

/// D2 for 0.2 s with PATH.
#[test]
fn d2_offset_stack_path() {
    check_stack("path", (0.1, 0.05), 20);
}

// ---------------------------------------------------------------------------------------------
// Two free bodies colliding
// ---------------------------------------------------------------------------------------------

/// B (0.2 m cube, 1 kg) at rest at the origin, C (0.2 m cube, 1.5 kg) 0.05 m to its left and
/// 0.05 m aside, thrown at it with v = (1, 0.2, 0) and ω = (0, 0, 0.5); μ = 0.3; no ground, no
/// gravity. The total linear momentum is `m_C v_C^0` at every step to 1e-12, through the approach,
/// the impact and the sliding contact after it.
fn collision(backend: &str) {
    let b = cuboid("B", 1.0, [0.2; 3], V3::zeros());
    let mut c = cuboid("C", 1.5, [0.2; 3], V3::new(-0.25, 0.05, 0.0));
    c.v = V3::new(1.0, 0.2, 0.0);
    c.w = V3::new(0.0, 0.0, 0.5);
    let p0 = c.v * c.mass;
    let mut world = World::new(WorldDef {
        bodies: vec![b, c],
        ground: vec![],
        pairs: vec![(1, Partner::Body(0), friction(0.3))],
        ground_friction: friction(0.3),
        gravity: V3::zeros(),
        kinematic: vec![],
    });
    let mut s = solver(backend);
    let (mut touched, mut retries, mut worst_residual) = (0, 0, 0.0f64);
    let mut iterations = Vec::new();
    for step in 1..=25 {
        let r = world.step(s.as_mut());
        iterations.push(r.iterations);
        retries += usize::from(r.retried);
        worst_residual = worst_residual.max(r.residual);
        let momentum = r.v[0] * 1.0 + r.v[1] * 1.5;
        let err = (momentum - p0).norm();
        assert!(
            err <= 1e-12,
            "{backend}, step {step}: momentum off by {err:.3e}"
        );
        if r.pairs[0].pn > 0.0 {
            touched += 1;
        }
    }
    assert!(touched > 0, "{backend}: the bodies never touched");
    report(&format!("collision, {backend}"), &iterations);
    eprintln!(
        "{backend}: {touched} contact steps, {retries} retries, largest residual \
         {worst_residual:.1e}, B: v {:?} ω {:?}, C: v {:?} ω {:?}",
        world.def.bodies[0].v.as_slice(),
        world.def.bodies[0].w.as_slice(),
        world.def.bodies[1].v.as_slice(),
        world.def.bodies[1].w.as_slice()
    );
    // The impact moved B.
    assert!(
        world.def.bodies[0].v.x > 0.1,
        "{backend}: B at {}",
        world.def.bodies[0].v
    );
}

#[test]
fn collision_conserves_momentum_newton() {
    collision("newton");
}

#[test]
fn collision_conserves_momentum_path() {
    collision("path");
}

// ---------------------------------------------------------------------------------------------
// A kinematic body: friction on the relative velocity
// ---------------------------------------------------------------------------------------------

/// D4, the conveyor (`bodies.md` §6): a kinematic plate of A's shape moving at u = (0.5, 0, 0)
/// carries B (μ = 0.3), which starts at rest on it: `v_x^k = min(0.5, 0.3 g h k)`, sticking
/// at step 18 and moving with the plate exactly after; the ECP 0.03 m BEHIND B's CM while B
/// slips, under it after (at the sticking step, where the moment balance puts it). The plate's pose and velocity are data.
fn conveyor(backend: &str) {
    let plate = cuboid("plate", 2.0, [0.4, 0.4, 0.2], V3::new(0.0, 0.0, 0.1));
    let b = cuboid("B", 1.0, [0.2; 3], V3::new(0.0, 0.0, 0.3));
    let mut world = World::new(WorldDef {
        bodies: vec![b],
        ground: vec![],
        pairs: vec![(0, Partner::Kinematic(0), friction(0.3))],
        ground_friction: friction(0.3),
        gravity: V3::new(0.0, 0.0, -G),
        kinematic: vec![(plate, V3::new(0.5, 0.0, 0.0))],
    });
    let mut s = solver(backend);
    let mut iterations = Vec::new();
    for k in 1..=30 {
        let r = world.step(s.as_mut());
        iterations.push(r.iterations);
        assert!(!r.retried, "{backend}: step {k} needed the retry");
        let at = format!("{backend}, step {k}");
        let vx = (0.3 * G * H * k as f64).min(0.5);
        close(&format!("{at}: v_x"), r.v[0].x, vx, 1e-9);
        close(&format!("{at}: v_y"), r.v[0].y, 0.0, 1e-9);
        close(&format!("{at}: v_z"), r.v[0].z, 0.0, 1e-9);
        assert!(r.w[0].norm() <= 1e-9, "{at}: ω {}", r.w[0]);
        let p = &r.pairs[0];
        close(&format!("{at}: p_n"), p.pn, G * H, 1e-9);
        let lead = p.a1.x - r.x[0].x;
        // Moment balance: the friction impulse m Δv at 0.1 m below the CM against p_n = m g h
        // (−0.03 while slipping; at step 18 the partial impulse that reaches 0.5 m/s; then 0).
        let dv = vx - (0.3 * G * H * (k - 1) as f64).min(0.5);
        let want = -0.1 * dv / (G * H);
        close(&format!("{at}: ECP behind the CM"), lead, want, 1e-8);
        close(&format!("{at}: ECP height"), p.a1.z, 0.2, 1e-8);
    }
    report(&format!("conveyor, {backend}"), &iterations);
}

#[test]
fn d4_conveyor_newton() {
    conveyor("newton");
}

#[test]
fn d4_conveyor_path() {
    conveyor("path");
}
