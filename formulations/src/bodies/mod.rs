//! The multi-body ECP formulation, `bodies` (`docs/model.md#bodies-touching-bodies`): dynamic
//! bodies touching each other, fixed and kinematic bodies and half-spaces. Every contact is one
//! contact set between two convex hulls (the pair blocks of
//! `docs/model.md#contact-between-two-bodies`; a half-space is the one-face body); the contact
//! sets of a step are chosen from the reach of the step ([`pairs`]), and the step problem is
//! built again when they change. At every step end the real bodies are checked for overlap
//! between every two of them ([`overlap`]).
//!
//! ```
//! use ecp_formulations::{scenarios, Simulation};
//! use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
//!
//! // D1: a box B resting on a box A on the ground; nothing moves.
//! let mut sim = Simulation::with_formulation(scenarios::d1_stack(), "bodies").unwrap();
//! let mut solver = NewtonSolver::new(NewtonSettings::default());
//! let rec = sim.step(&mut solver).unwrap();
//! assert!(rec.converged && rec.bodies[1].v.norm() < 1e-9);
//! let top = rec.pairs.iter().find(|p| p.body_a == "B").unwrap();
//! assert!((top.pn - 1.0 * 9.8 * 0.01).abs() < 1e-9 && top.body_b == "A");
//! ```

pub mod overlap;
pub mod pairs;
mod structure;

use nalgebra::{Vector3, Vector4};

use ecp_model::{
    BlockMcp, DataBlock, DataId, Input, Problem, ResId, StepStructure, VarBlock, VarId,
};

use crate::blocks::{
    AXIS_DATA, BodyDataIds, FaceSet, FrictionParams, KinematicMap, NewtonEuler, PairBody,
    PairContactVars, PairDataIds, PairMotion, SceneDataIds, SupportNormal, add_body_data,
    add_pair_contact, add_pair_data, add_scene_data, pair_guess, reference_axis,
};
use crate::geometry::{
    ContactMode, HalfSpace, HullPose, contact_mode, pair_features, predicted_pose, world_vertices,
};
use crate::record::{ContactRecord, MODE_TOLERANCE, PairRecord, scene_gaps_and_modes};
use crate::rotation::{quat_normalize, rotation_matrix};
use crate::scene::{BodyState, Scene, SceneError, validate_scene_parameters};
use crate::step::body::{predict_pose, set_body_span_data, store_states};
use crate::step::{
    BodyHandles, Capabilities, ContactHandles, Prepared, SensitivitySupport, StepContext,
    StepFormulation, StepHandles,
};
use overlap::{OVERLAP_TOLERANCE, RealPieces};
use pairs::{PairKey, Partner, Reach, place_all, select_pairs};

/// A dynamic body in the step problem.
#[derive(Clone, Debug)]
struct DynamicBody {
    nu: VarId,
    q: VarId,
    data: BodyDataIds,
    newton_euler: ResId,
    faces: FaceSet,
    vertices: Vec<Vector3<f64>>,
    hull: crate::geometry::ConvexHull,
}

/// A fixed or kinematic body, or a half-space: pose and velocity are data.
#[derive(Clone, Debug)]
struct DataBody {
    nu: DataId,
    q: DataId,
    faces: FaceSet,
    /// Hull (obstacles; `None` for a half-space).
    hull: Option<crate::geometry::ConvexHull>,
}

/// One contact set.
#[derive(Clone, Debug)]
struct Contact {
    key: PairKey,
    vars: PairContactVars,
    data: PairDataIds,
    /// The normal of the last solution (or of the first guess): the frame's reference axis of
    /// the next step is chosen from it.
    normal: Vector3<f64>,
    /// Not yet given a starting point (new since the last build).
    fresh: bool,
}

/// The multi-body formulation (module documentation).
#[derive(Clone, Debug, Default)]
pub struct MultiBody {
    reach: Reach,
    bodies: Vec<DynamicBody>,
    obstacles: Vec<DataBody>,
    planes: Vec<DataBody>,
    contacts: Vec<Contact>,
    scene_data: Option<SceneDataIds>,
    pieces: RealPieces,
    /// Start time of the step being prepared (the pose of kinematic bodies).
    t0: f64,
    /// The contact sets the next build is to have (chosen by `begin_step`).
    pending: Option<Vec<PairKey>>,
    /// The normals of the contacts the last problem had, by key (carried over a rebuild).
    normals: Vec<(PairKey, Vector3<f64>)>,
    /// The span's data for the structural view ([`StepStructure`], `structure.rs`).
    span: structure::Span,
}

impl MultiBody {
    /// The formulation with the default reach ([`Reach::default`]).
    pub fn new() -> Self {
        Self::default()
    }

    /// The formulation with the given reach of a step. A reach that is too short leaves out
    /// contacts that close within the step; the overlap check at the step's end then fails the
    /// run ([`overlap`]).
    pub fn with_reach(reach: Reach) -> Self {
        MultiBody {
            reach,
            ..Self::default()
        }
    }

    /// The contact sets of the step problem (sorted by body, then partner).
    pub fn pairs(&self) -> Vec<PairKey> {
        self.contacts.iter().map(|c| c.key).collect()
    }

    /// The name of the partner of a contact.
    fn partner_name(scene: &Scene, g: Partner) -> String {
        match g {
            Partner::Plane(p) => scene.world.plane_name(p),
            Partner::Body(b) => scene.bodies[b].name.clone(),
            Partner::Obstacle(k) => scene.world.obstacles[k].name.clone(),
        }
    }

    /// The contact sets for a step from `t0` with the bodies at `states`.
    fn select(&self, scene: &Scene, states: &[BodyState], t0: f64, h: f64) -> Vec<PairKey> {
        let hulls: Vec<Vec<Vector3<f64>>> =
            self.bodies.iter().map(|b| b.vertices.clone()).collect();
        let obstacle_hulls: Vec<Vec<Vector3<f64>>> = self
            .obstacles
            .iter()
            .map(|o| {
                o.hull
                    .as_ref()
                    .map(|h| h.vertices().to_vec())
                    .unwrap_or_default()
            })
            .collect();
        let (bodies, obstacles) = place_all(scene, states, &hulls, &obstacle_hulls, t0, h);
        select_pairs(&scene.planes, &bodies, &obstacles, h, &self.reach)
    }

    /// G of a contact as the pair blocks see it.
    fn partner(&self, g: Partner) -> PairBody<'_> {
        match g {
            Partner::Plane(p) => {
                let b = &self.planes[p];
                PairBody {
                    nu: b.nu.into(),
                    q: b.q.into(),
                    faces: &b.faces,
                }
            }
            Partner::Obstacle(k) => {
                let b = &self.obstacles[k];
                PairBody {
                    nu: b.nu.into(),
                    q: b.q.into(),
                    faces: &b.faces,
                }
            }
            Partner::Body(b) => {
                let b = &self.bodies[b];
                PairBody {
                    nu: b.nu.into(),
                    q: b.q.into(),
                    faces: &b.faces,
                }
            }
        }
    }

    /// G's end-of-span orientation: from `z` (dynamic) or its data.
    fn partner_quaternion(&self, g: Partner, mcp: &BlockMcp, z: &[f64]) -> Vector4<f64> {
        let q = match g {
            Partner::Body(b) => &z[mcp.range(self.bodies[b].q)],
            Partner::Obstacle(k) => mcp.data(self.obstacles[k].q),
            Partner::Plane(p) => mcp.data(self.planes[p].q),
        };
        Vector4::new(q[3], q[4], q[5], q[6])
    }

    /// The unit normal `ν_G/|ν_G|` of contact `i` in `z` and `|ν_G|`.
    fn normal_of(&self, i: usize, mcp: &BlockMcp, z: &[f64]) -> (Vector3<f64>, f64) {
        let c = &self.contacts[i];
        let mu = &z[mcp.range(c.vars.mu)];
        let q = self.partner_quaternion(c.key.g, mcp, z);
        let faces = self.partner(c.key.g).faces;
        let nu_g = SupportNormal::new(&faces.normals, mu, &q).value;
        let len = nu_g.norm();
        if len > 0.0 && len.is_finite() {
            (nu_g / len, len)
        } else {
            (c.normal, 0.0)
        }
    }

    /// Whether contact `key` has friction of its own (a `[[pair_friction]]` entry for its pair
    /// or its materials) rather than the scene's.
    fn has_own_friction(scene: &Scene, key: PairKey) -> bool {
        let a = &scene.bodies[key.f].name;
        let b = Self::partner_name(scene, key.g);
        let mut marked = scene.friction;
        marked.mu = f64::NAN;
        !Self::friction_between_or(scene, a, &b, &marked).mu.is_nan()
    }

    fn friction_between_or(
        scene: &Scene,
        a: &str,
        b: &str,
        default: &FrictionParams,
    ) -> FrictionParams {
        scene.world.friction_between(a, b, default)
    }

    /// The friction of contact `key` (its pair's, its materials', or the scene's).
    fn friction_of(scene: &Scene, key: PairKey) -> FrictionParams {
        let a = &scene.bodies[key.f].name;
        let b = Self::partner_name(scene, key.g);
        scene.world.friction_between(a, &b, &scene.friction)
    }

    /// The pose (world), velocity and mass of a contact's partner at the start of the span, and
    /// its hull pose at the start (`predicted = false`) or at the end of the span.
    fn partner_motion(
        &self,
        ctx: &StepContext<'_>,
        g: Partner,
        predicted: bool,
    ) -> Option<(PairMotion, Vector3<f64>, nalgebra::Matrix3<f64>)> {
        match g {
            Partner::Plane(_) => None,
            Partner::Body(b) => {
                let s = &ctx.states[b];
                let m = ctx.scene.bodies[b].mass.mass;
                let (x, r) = if predicted {
                    predicted_pose(&s.x, &s.q, &(s.v + ctx.scene.gravity * ctx.h), &s.w, ctx.h)?
                } else {
                    (s.x, rotation_matrix(&s.q))
                };
                Some((
                    PairMotion {
                        mass: Some(m),
                        x: s.x,
                        v: s.v,
                        w: s.w,
                    },
                    x,
                    r,
                ))
            }
            Partner::Obstacle(k) => {
                let span = ctx.scene.world.obstacles[k].span(ctx.t0, ctx.h);
                let (x, q) = if predicted {
                    (span.x1, span.q1)
                } else {
                    (span.x0, span.q0)
                };
                Some((
                    PairMotion {
                        mass: None,
                        x: span.x0,
                        v: span.v,
                        w: span.w,
                    },
                    x,
                    rotation_matrix(&q),
                ))
            }
        }
    }

    /// A starting point of contact `i` from the closest features at the span's start poses
    /// (`predicted = false`) or at the predicted end-of-span poses with the impulses forced
    /// active (the deterministic retry), `docs/model.md#starting-guesses`.
    fn guess_contact(
        &mut self,
        i: usize,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        predicted: bool,
    ) {
        let c = &self.contacts[i];
        let key = c.key;
        let s = &ctx.states[key.f];
        let scene = ctx.scene;
        let motion_f = PairMotion {
            mass: Some(scene.bodies[key.f].mass.mass),
            x: s.x,
            v: s.v,
            w: s.w,
        };
        let (xf, rf) = if predicted {
            predicted_pose(&s.x, &s.q, &(s.v + scene.gravity * ctx.h), &s.w, ctx.h)
                .unwrap_or((s.x, rotation_matrix(&s.q)))
        } else {
            (s.x, rotation_matrix(&s.q))
        };
        let f_pose = HullPose {
            hull: &self.bodies[key.f].hull,
            x: xf,
            rotation: rf,
        };
        let friction = Self::friction_of(scene, key);
        let values = match key.g {
            Partner::Plane(p) => {
                // The half-space: the lowest vertices of F's hull, as the half-space stepper's
                // guess; p_n from the weight when they touch (or when forced).
                let plane = &scene.planes[p];
                self.contacts[i].normal = plane.normal();
                plane_guess(
                    &f_pose, plane, &motion_f, &friction, scene, ctx.h, predicted,
                )
            }
            g => {
                let Some((motion_g, xg, rg)) = self.partner_motion(ctx, g, predicted) else {
                    return;
                };
                let hull_g = match g {
                    Partner::Body(b) => &self.bodies[b].hull,
                    Partner::Obstacle(k) => match &self.obstacles[k].hull {
                        Some(h) => h,
                        None => return,
                    },
                    Partner::Plane(_) => return,
                };
                let g_pose = HullPose {
                    hull: hull_g,
                    x: xg,
                    rotation: rg,
                };
                let Some(features) = touching_features(&f_pose, &g_pose) else {
                    return;
                };
                self.contacts[i].normal = features.normal;
                let axis = reference_axis(&features.normal);
                pair_guess(
                    &features,
                    &motion_f,
                    &motion_g,
                    &axis,
                    &friction,
                    &scene.gravity,
                    ctx.h,
                    predicted,
                )
            }
        };
        if values.a1.iter().all(|v| v.is_finite()) {
            let vars = self.contacts[i].vars;
            // A size mismatch cannot happen (the blocks were built from the same faces).
            let _ = vars.write(mcp, z, &values);
            self.contacts[i].fresh = false;
        }
    }
}

impl MultiBody {
    /// Adds to each loaded contact's starting `p_n` the loads of the loaded contacts of the
    /// bodies resting on F, along its normal (a stack's lower contacts carry the bodies above:
    /// the weight of F alone is a poor start for the bottom of a tower). The friction impulses
    /// are scaled with `p_n`.
    fn carry_loads(&self, mcp: &BlockMcp, z: &mut [f64]) {
        let pn: Vec<f64> = self
            .contacts
            .iter()
            .map(|c| z[mcp.range(c.vars.pn)][0])
            .collect();
        let mut load = pn.clone();
        for _ in 0..self.bodies.len() {
            let previous = load.clone();
            for (i, c) in self.contacts.iter().enumerate() {
                if pn[i] <= 0.0 {
                    continue;
                }
                let above: f64 = (self.contacts.iter().enumerate())
                    .filter(|(j, d)| d.key.g == Partner::Body(c.key.f) && pn[*j] > 0.0)
                    .map(|(j, d)| previous[j] * d.normal.dot(&c.normal).max(0.0))
                    .sum();
                load[i] = pn[i] + above;
            }
        }
        for (i, c) in self.contacts.iter().enumerate() {
            if pn[i] > 0.0 && load[i] != pn[i] {
                let k = load[i] / pn[i];
                z[mcp.range(c.vars.pn)][0] = load[i];
                for v in &mut z[mcp.range(c.vars.pf)] {
                    *v *= k;
                }
            }
        }
    }
}

/// [`pair_features`] of F and G, made robust for hulls that touch face to face: parry's EPA
/// may return any normal along which two exactly touching polytopes overlap by round-off (the
/// side of a cube stacked on an equal cube). When the hulls touch or overlap by less than
/// 1e-9 m along one of their face normals (the direction of least overlap among the face
/// normals of both), the features are taken from F lifted 1e-7 m beyond touching along it, where
/// GJK's closest features are unambiguous, and then put back in touch (`d = 0`, `a1 = a2`).
fn touching_features(f: &HullPose<'_>, g: &HullPose<'_>) -> Option<crate::geometry::PairFeatures> {
    let features = pair_features(f, g).ok()?;
    if features.distance > 1e-9 {
        return Some(features);
    }
    let world = |p: &HullPose<'_>| world_vertices(p.hull.vertices(), &p.x, &p.rotation);
    let (vf, vg) = (world(f), world(g));
    let extent = |v: &[Vector3<f64>], m: &Vector3<f64>| {
        v.iter()
            .map(|p| m.dot(p))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            })
    };
    // Separation of F from G along m (from G towards F): min over F − max over G.
    let separation = |m: &Vector3<f64>| extent(&vf, m).0 - extent(&vg, m).1;
    let normals = (g.hull.faces().iter().map(|face| g.rotation * face.normal)).chain(
        f.hull
            .faces()
            .iter()
            .map(|face| -(f.rotation * face.normal)),
    );
    let (best, sep) = normals
        .map(|m| (m, separation(&m)))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    if sep < -1e-9 || (best - features.normal).norm() <= 1e-9 {
        return Some(features);
    }
    let lifted = HullPose {
        x: f.x + best * (1e-7 - sep),
        ..*f
    };
    let mut apart = pair_features(&lifted, g).ok()?;
    apart.a1 = apart.a2;
    apart.d = 0.0;
    apart.distance = sep;
    Some(apart)
}

/// The guess of a contact with a half-space: `a1` the centroid of F's lowest hull vertices,
/// `a2` its projection, `d` the gap, the face of F most aligned with `−n` active; touching (or
/// `active`), `p_n` carries F's weight along `−n` and stops its approach, and the friction
/// impulse lies on the ellipsoid against the slip (`docs/model.md#stepper`).
fn plane_guess(
    f: &HullPose<'_>,
    plane: &HalfSpace,
    motion: &PairMotion,
    friction: &FrictionParams,
    scene: &Scene,
    h: f64,
    active: bool,
) -> crate::blocks::PairContactValues {
    let n = plane.normal();
    let world = world_vertices(f.hull.vertices(), &f.x, &f.rotation);
    let low = world
        .iter()
        .map(|p| plane.value(p))
        .fold(f64::INFINITY, f64::min);
    let lowest: Vec<&Vector3<f64>> = world
        .iter()
        .filter(|p| plane.value(p) <= low + 1e-9)
        .collect();
    let a1 = lowest.iter().fold(Vector3::zeros(), |s, p| s + **p) / lowest.len().max(1) as f64;
    let gap = plane.value(&a1).max(0.0);
    let mut l = vec![0.0; f.hull.num_faces()];
    l[f.hull.most_aligned_face(&(f.rotation.transpose() * -n))] = 1.0;
    let features = crate::geometry::PairFeatures {
        a1,
        a2: plane.project(&a1),
        d: gap,
        l,
        mu: vec![1.0],
        normal: n,
        distance: gap,
        face_to_face: true,
    };
    let fixed = PairMotion {
        mass: None,
        x: Vector3::zeros(),
        v: Vector3::zeros(),
        w: Vector3::zeros(),
    };
    let axis = reference_axis(&n);
    let touching = active || gap <= 1e-9;
    let mut values = pair_guess(
        &features,
        motion,
        &fixed,
        &axis,
        friction,
        &scene.gravity,
        h,
        touching,
    );
    if touching {
        values.d = 0.0;
    }
    values
}

/// The contact mode of a pair from the real vertices of both sides at the end of a step: the
/// touching features of each side on the contact plane through `a2` with normal `n`, and the
/// fewer of the two (an edge across an edge touches at a point).
fn pair_mode(
    vf: &[Vector3<f64>],
    vg: Option<&[Vector3<f64>]>,
    n: &Vector3<f64>,
    a2: &Vector3<f64>,
) -> ContactMode {
    let rank = |m: ContactMode| match m {
        ContactMode::None => 0,
        ContactMode::Point => 1,
        ContactMode::Line => 2,
        ContactMode::Patch => 3,
    };
    // F lies on the side of +n, G on the side of −n: each side's touching vertices are within
    // tolerance of the plane.
    let (Ok(plane_f), Ok(plane_g)) = (
        HalfSpace::new(*n, n.dot(a2)),
        HalfSpace::new(-n, -n.dot(a2)),
    ) else {
        return ContactMode::None;
    };
    let mf = contact_mode(vf, &plane_f, MODE_TOLERANCE);
    let Some(vg) = vg else {
        return mf;
    };
    let mg = contact_mode(vg, &plane_g, MODE_TOLERANCE);
    if mf == ContactMode::Line && mg == ContactMode::Line {
        // Two lines on the plane meet at a point unless they are parallel.
        let direction = |v: &[Vector3<f64>], plane: &HalfSpace| {
            let on: Vec<&Vector3<f64>> = v
                .iter()
                .filter(|p| plane.value(p) <= MODE_TOLERANCE)
                .collect();
            let p0 = on.first().copied().copied().unwrap_or_default();
            on.iter()
                .map(|p| *p - p0)
                .max_by(|a, b| a.norm().total_cmp(&b.norm()))
                .map(|d| d.normalize())
                .unwrap_or_default()
        };
        let (df, dg) = (direction(vf, &plane_f), direction(vg, &plane_g));
        if df.cross(&dg).norm() > 1e-6 {
            return ContactMode::Point;
        }
    }
    if rank(mg) < rank(mf) { mg } else { mf }
}

impl StepFormulation for MultiBody {
    fn name(&self) -> &str {
        "bodies"
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            // The structural view of `structure.rs`: the conic backend solves these steps.
            step_structure: true,
            fallback_backends: true,
            substeps: true,
            user_terms: true,
            sensitivities: SensitivitySupport::Exact,
            non_isolated_solutions: false,
        }
    }

    fn build(
        &mut self,
        scene: &Scene,
        states: &[BodyState],
        problem: &mut Problem,
    ) -> Result<StepHandles, SceneError> {
        validate_scene_parameters(scene, true)?;
        let h = scene.h;
        let scene_data = add_scene_data(problem, &scene.gravity, h, &scene.friction);
        let mut bodies = Vec::new();
        for spec in &scene.bodies {
            let hull = spec.shape.hull().map_err(|source| SceneError::Geometry {
                body: spec.name.clone(),
                source,
            })?;
            let nu = problem.add_variable_block(
                VarBlock::free(format!("{}.nu", spec.name), 6)
                    .with_component_names(["vx", "vy", "vz", "wx", "wy", "wz"]),
            );
            let q = problem.add_variable_block(
                VarBlock::free(format!("{}.q", spec.name), 7)
                    .with_component_names(["x", "y", "z", "qw", "qx", "qy", "qz"]),
            );
            let data = add_body_data(problem, &spec.name, spec.mass.mass, &spec.mass.inertia);
            bodies.push(DynamicBody {
                nu,
                q,
                data,
                newton_euler: ResId(0),
                faces: FaceSet::of_hull(&hull),
                vertices: hull.vertices().to_vec(),
                hull,
            });
        }
        let pose_data = |problem: &mut Problem, name: &str, v: [f64; 6], q: [f64; 7]| {
            (
                problem.add_data_block(
                    DataBlock::new(format!("{name}.nu"), v)
                        .with_component_names(["vx", "vy", "vz", "wx", "wy", "wz"]),
                ),
                problem.add_data_block(
                    DataBlock::new(format!("{name}.q"), q)
                        .with_component_names(["x", "y", "z", "qw", "qx", "qy", "qz"]),
                ),
            )
        };
        let mut obstacles = Vec::new();
        for o in &scene.world.obstacles {
            let hull = o.shape.hull().map_err(|source| SceneError::Geometry {
                body: o.name.clone(),
                source,
            })?;
            let s = o.span(self.t0, h);
            let (nu, q) = pose_data(
                problem,
                &o.name,
                [s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z],
                [s.x1.x, s.x1.y, s.x1.z, s.q1[0], s.q1[1], s.q1[2], s.q1[3]],
            );
            obstacles.push(DataBody {
                nu,
                q,
                faces: FaceSet::of_hull(&hull),
                hull: Some(hull),
            });
        }
        let mut planes = Vec::new();
        for (p, plane) in scene.planes.iter().enumerate() {
            let name = scene.world.plane_name(p);
            let (nu, q) = pose_data(
                problem,
                &name,
                [0.0; 6],
                [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            );
            let faces = FaceSet::half_space(&plane.normal(), plane.offset()).ok_or_else(|| {
                SceneError::Parameter {
                    what: format!("half-space '{name}'"),
                    value: plane.offset(),
                    hint: "a half-space needs a finite non-zero normal and a finite offset",
                }
            })?;
            planes.push(DataBody {
                nu,
                q,
                faces,
                hull: None,
            });
        }
        self.bodies = bodies;
        self.obstacles = obstacles;
        self.planes = planes;
        self.pieces = RealPieces::of(scene);
        let keys = match self.pending.take() {
            Some(k) => k,
            None => self.select(scene, states, self.t0, h),
        };
        // Newton–Euler and the kinematic map of each dynamic body; the contacts add their
        // impulses as terms on the Newton–Euler rows (`docs/model.md#impulses-on-both-bodies`).
        let SceneDataIds {
            gravity,
            h: step_length,
            friction,
        } = scene_data;
        for b in &mut self.bodies {
            let d = b.data;
            let reads: Vec<Input> = [b.nu, b.q]
                .map(Input::from)
                .into_iter()
                .chain(
                    [d.mass, d.inertia, d.start, d.wrench, gravity, step_length].map(Input::from),
                )
                .collect();
            b.newton_euler = problem.add_residual_block(b.nu, NewtonEuler::new(vec![]), reads)?;
            problem.add_residual_block(
                b.q,
                KinematicMap,
                &[
                    b.q.into(),
                    b.nu.into(),
                    Input::from(d.start),
                    step_length.into(),
                ],
            )?;
        }
        let scale = 1.0 / h;
        let mut contacts = Vec::new();
        for key in keys {
            let tag = format!(
                "{}~{}",
                scene.bodies[key.f].name,
                Self::partner_name(scene, key.g)
            );
            let previous = self
                .normals
                .iter()
                .find(|(k, _)| *k == key)
                .map(|(_, n)| *n);
            let normal = previous.unwrap_or_else(Vector3::z);
            // A pair with the scene's friction reads the scene's `friction` block (so `set_param`
            // and the step sensitivities of μ, e_t, e_o, e_r reach it); a pair with its own
            // friction has its own `<tag>.friction` block.
            let data = if Self::has_own_friction(scene, key) {
                add_pair_data(
                    problem,
                    &tag,
                    &Self::friction_of(scene, key),
                    &reference_axis(&normal),
                )
            } else {
                PairDataIds {
                    friction: scene_data.friction,
                    axis: problem.add_data_block(
                        DataBlock::new(format!("{tag}.axis"), reference_axis(&normal).as_slice())
                            .with_component_names(AXIS_DATA),
                    ),
                }
            };
            let fb = &self.bodies[key.f];
            let f = PairBody {
                nu: fb.nu.into(),
                q: fb.q.into(),
                faces: &fb.faces,
            };
            let g = self.partner(key.g);
            let vars = add_pair_contact(problem, &tag, &f, &g, data, scale)?;
            contacts.push(Contact {
                key,
                vars,
                data,
                normal,
                fresh: previous.is_none(),
            });
        }
        self.contacts = contacts;
        self.scene_data = Some(scene_data);
        Ok(StepHandles {
            bodies: self
                .bodies
                .iter()
                .map(|b| BodyHandles {
                    nu: Some(b.nu),
                    q: Some(b.q),
                    newton_euler: Some(b.newton_euler),
                    data: Some(b.data),
                })
                .collect(),
            gravity: Some(gravity),
            h: Some(step_length),
            friction: Some(friction),
            contacts: self
                .contacts
                .iter()
                .map(|c| ContactHandles {
                    body: c.key.f,
                    normal: c.vars.pn,
                    friction: vec![c.vars.pf, c.vars.sigma],
                    geometry: vec![c.vars.a1, c.vars.a2, c.vars.l, c.vars.mu, c.vars.d],
                })
                .collect(),
        })
    }

    fn contacts_per_body(&self) -> usize {
        self.planes.len()
    }

    /// The bodies at their initial states and each contact from its closest features
    /// (`docs/model.md#starting-guesses`).
    fn initial_guess(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<(), SceneError> {
        self.t0 = ctx.t0;
        if let Some(o) = self
            .pieces
            .deepest_overlap(ctx.scene, ctx.states, ctx.t0, 1e-9)
        {
            return Err(SceneError::Overlap {
                a: o.a,
                b: o.b,
                depth: o.depth,
                step: None,
                hint: "move the bodies apart so that they at most touch at the start",
            });
        }
        for (b, s) in self.bodies.iter().zip(ctx.states) {
            z[mcp.range(b.nu)].copy_from_slice(&[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z]);
            z[mcp.range(b.q)]
                .copy_from_slice(&[s.x.x, s.x.y, s.x.z, s.q[0], s.q[1], s.q[2], s.q[3]]);
        }
        for i in 0..self.contacts.len() {
            self.guess_contact(i, ctx, mcp, z, false);
        }
        self.carry_loads(mcp, z);
        Ok(())
    }

    /// Chooses the step's contact sets ([`pairs::select_pairs`]) and asks for a rebuild when
    /// they differ from the problem's.
    fn begin_step(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<Prepared, SceneError> {
        self.t0 = ctx.t0;
        let keys = self.select(ctx.scene, ctx.states, ctx.t0, ctx.h);
        if keys == self.pairs() {
            return Ok(Prepared::Ready);
        }
        self.normals = (0..self.contacts.len())
            .map(|i| (self.contacts[i].key, self.normal_of(i, mcp, z).0))
            .collect();
        self.pending = Some(keys);
        Ok(Prepared::Rebuild)
    }

    /// The span's data: each dynamic body's start state and load, each kinematic body's end
    /// pose and velocity over the span, the scene's friction and the frames' reference axes.
    fn update_data(&mut self, ctx: &StepContext<'_>, mcp: &mut BlockMcp) -> Result<(), SceneError> {
        if let Some(d) = self.scene_data {
            mcp.set_data(d.h, &[ctx.h])?;
            mcp.set_data(d.friction, &ctx.scene.friction.values())?;
        }
        let o = Vector3::zeros();
        for (i, (b, s)) in self.bodies.iter().zip(ctx.states).enumerate() {
            set_body_span_data(mcp, &b.data, s, &ctx.wrench(i), &o)?;
        }
        for (b, o) in self.obstacles.iter().zip(&ctx.scene.world.obstacles) {
            let s = o.span(ctx.t0, ctx.h);
            mcp.set_data(b.nu, &[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z])?;
            mcp.set_data(
                b.q,
                &[s.x1.x, s.x1.y, s.x1.z, s.q1[0], s.q1[1], s.q1[2], s.q1[3]],
            )?;
        }
        // A pair's own friction block is written when it is built (and carried over a rebuild
        // by name), not here, so that `Simulation::set_data` on `<F>~<G>.friction` changes that
        // pair's friction from the next step on.
        for c in &self.contacts {
            mcp.set_data(c.data.axis, reference_axis(&c.normal).as_slice())?;
        }
        self.record_span(mcp);
        Ok(())
    }

    /// Each body's `q` predicted by the kinematic map; a contact new since the last build
    /// starts from its closest features; the others from the last solution.
    fn warm_start(&mut self, ctx: &StepContext<'_>, mcp: &BlockMcp, z: &mut [f64]) {
        let o = Vector3::zeros();
        for (b, s) in self.bodies.iter().zip(ctx.states) {
            predict_pose(mcp, z, (b.nu, b.q), s, &o, ctx.h);
        }
        for i in 0..self.contacts.len() {
            if self.contacts[i].fresh {
                self.guess_contact(i, ctx, mcp, z, false);
            }
        }
    }

    /// One retry that restarts every contact from the overlapping features of the predicted
    /// end-of-step poses with the impulses active (`docs/model.md#starting-guesses`).
    fn retry_start(
        &mut self,
        attempt: usize,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
    ) -> bool {
        if attempt > 0 {
            return false;
        }
        for i in 0..self.contacts.len() {
            self.guess_contact(i, ctx, mcp, z, true);
        }
        true
    }

    /// The end-of-span states; then the overlap check between every two real bodies, which
    /// refuses the solution when two overlap (a contact set was missing).
    fn read_out(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        states: &mut [BodyState],
    ) -> Result<(), SceneError> {
        store_states(
            mcp,
            z,
            self.bodies.iter().map(|b| (b.nu, b.q)),
            states,
            &Vector3::zeros(),
        );
        for i in 0..self.contacts.len() {
            let (n, len) = self.normal_of(i, mcp, z);
            if len > 0.0 {
                self.contacts[i].normal = n;
            }
        }
        let t1 = ctx.t0 + ctx.h;
        if let Some(o) = self
            .pieces
            .deepest_overlap(ctx.scene, states, t1, OVERLAP_TOLERANCE)
        {
            return Err(SceneError::Overlap {
                a: o.a,
                b: o.b,
                depth: o.depth,
                step: Some(ctx.step),
                hint: "the pair had no contact set in this step (its reach was under-estimated) \
                       or the step's solution is wrong; this is a bug, please report it with \
                       the scene",
            });
        }
        Ok(())
    }

    fn contact_records(
        &self,
        scene: &Scene,
        states: &[BodyState],
        _solved: bool,
        mcp: &BlockMcp,
        z: &[f64],
        out: &mut Vec<ContactRecord>,
    ) {
        let table = scene_gaps_and_modes(scene, states);
        for f in 0..self.bodies.len() {
            for p in 0..self.planes.len() {
                let key = PairKey {
                    f,
                    g: Partner::Plane(p),
                };
                let (gap, mode) = table[f][p];
                let Some(c) = self.contacts.iter().find(|c| c.key == key) else {
                    // No contact set this step: no ECP (NaN), no impulse; `lg` the hull's
                    // height above the half-space.
                    let s = &states[f];
                    let plane = &scene.planes[p];
                    let r = rotation_matrix(&s.q);
                    let low = world_vertices(self.bodies[f].hull.vertices(), &s.x, &r)
                        .iter()
                        .map(|v| plane.value(v))
                        .fold(f64::INFINITY, f64::min);
                    let none = Vector3::repeat(f64::NAN);
                    out.push(ContactRecord {
                        a1: none,
                        a2: none,
                        lg: low,
                        pn: 0.0,
                        pt: 0.0,
                        po: 0.0,
                        pr: 0.0,
                        sigma: 0.0,
                        min_gap: gap,
                        mode,
                    });
                    continue;
                };
                let v = c.vars.read(mcp, z);
                out.push(ContactRecord {
                    a1: v.a1,
                    a2: v.a2,
                    lg: v.d,
                    pn: v.pn,
                    pt: v.pf[0],
                    po: v.pf[1],
                    pr: v.pf[2],
                    sigma: v.sigma,
                    min_gap: gap,
                    mode,
                });
            }
        }
    }

    fn pair_records(
        &self,
        scene: &Scene,
        _solved: bool,
        mcp: &BlockMcp,
        z: &[f64],
        out: &mut Vec<PairRecord>,
    ) {
        let pose = |q: &[f64]| {
            let quat = quat_normalize(&Vector4::new(q[3], q[4], q[5], q[6]))
                .unwrap_or(Vector4::new(1.0, 0.0, 0.0, 0.0));
            (Vector3::new(q[0], q[1], q[2]), rotation_matrix(&quat))
        };
        for (i, c) in self.contacts.iter().enumerate() {
            let v = c.vars.read(mcp, z);
            let (n, len) = self.normal_of(i, mcp, z);
            let gap = v.d * len;
            let (xf, rf) = pose(&z[mcp.range(self.bodies[c.key.f].q)]);
            let vf = world_vertices(scene.bodies[c.key.f].shape.vertices(), &xf, &rf);
            let vg = match c.key.g {
                Partner::Plane(_) => None,
                Partner::Body(b) => {
                    let (x, r) = pose(&z[mcp.range(self.bodies[b].q)]);
                    Some(world_vertices(scene.bodies[b].shape.vertices(), &x, &r))
                }
                Partner::Obstacle(k) => {
                    let (x, r) = pose(mcp.data(self.obstacles[k].q));
                    Some(world_vertices(
                        scene.world.obstacles[k].shape.vertices(),
                        &x,
                        &r,
                    ))
                }
            };
            let mode = if gap > MODE_TOLERANCE && v.pn == 0.0 {
                ContactMode::None
            } else {
                pair_mode(&vf, vg.as_deref(), &n, &v.a2)
            };
            out.push(PairRecord {
                body_a: scene.bodies[c.key.f].name.clone(),
                body_b: Self::partner_name(scene, c.key.g),
                a1: v.a1,
                a2: v.a2,
                normal: n,
                pn: v.pn,
                pt: v.pf[0],
                po: v.pf[1],
                pr: v.pf[2],
                sigma: v.sigma,
                gap,
                mode,
            });
        }
    }

    fn structure(&self) -> Option<&dyn StepStructure> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenarios;
    use crate::step::Simulation;
    use ecp_solvers::newton::NewtonSolver;

    /// D1 for 0.2 s: nothing moves, `p_n(B–A) = m_B g h`, `p_n(A–ground) = (m_A + m_B) g h`,
    /// the ECPs at (0, 0, 0.2) and (0, 0, 0).
    #[test]
    fn d1_stack_rests() {
        let mut scene = scenarios::d1_stack();
        scene.duration = 0.2;
        let mut sim = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(sim.formulation().name(), "bodies");
        let mut solver = NewtonSolver::new(Default::default());
        while !sim.finished() {
            let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
            assert!(rec.converged, "step {}", rec.step);
            for b in &rec.bodies {
                assert!(b.v.norm() <= 1e-9 && b.w.norm() <= 1e-9, "{b:?}");
            }
            // B is 0.2 m above the ground, beyond the reach: no contact set.
            assert_eq!(rec.pairs.len(), 2, "{:?}", rec.pairs);
            for p in &rec.pairs {
                let (pn, ecp) = match (p.body_a.as_str(), p.body_b.as_str()) {
                    ("A", "ground") => (0.294, Vector3::zeros()),
                    ("B", "A") => (0.098, Vector3::new(0.0, 0.0, 0.2)),
                    ("B", "ground") => (0.0, p.a1),
                    other => panic!("unexpected pair {other:?}"),
                };
                assert!((p.pn - pn).abs() <= 1e-9, "{p:?}");
                assert!((p.a1 - ecp).norm() <= 1e-8, "{p:?}");
            }
        }
    }
}
