//! Point contacts (`docs/model.md#point-contacts`): the classic, geometrically explicit model the
//! paper argues against, kept as a baseline.
//!
//! A fixed set of contact points — the vertices of the convex pieces of each body, coincident
//! ones merged ([`Shape::vertices`](crate::geometry::Shape::vertices)) — each against each
//! half-space. Everything geometric is frozen at the START of the step (Stewart–Trinkle,
//! Anitescu–Potra): the lever arm `r_i = R(Q^u) b_i` of point `i` (body-frame position `b_i`),
//! its wrenches `W_n,i = [n; r_i × n]`, `W_t,i = [t; r_i × t]`, `W_o,i = [o; r_i × o]` and its
//! gap `g_i(q^u)`. The step problem per body and half-space is then
//!
//! - Newton–Euler with every point's wrench, its mass matrix and gyroscopic impulse
//!   at the end of the step as in the hull model (`docs/energy.md`; [`PointNewtonEuler`]);
//! - the kinematic map (`docs/model.md#kinematic-map`, [`KinematicMap`]);
//! - non-penetration of the linearised gap, in velocity units,
//!   `0 ≤ p_n,i ⊥ g_i(q^u)/h + W_n,iᵀ ν ≥ 0` ([`PointNonPenetration`]);
//! - the elliptic maximum-dissipation friction law of `docs/model.md#friction` restricted to the
//!   tangent plane (a point has no torsion): `e_t² μ p_n W_tᵀν + p_t σ = 0`, `e_o² μ p_n W_oᵀν +
//!   p_o σ = 0` ([`PointFrictionDissipation`]) and `0 ≤ μ p_n − ‖(p_t/e_t, p_o/e_o)‖ ⊥ σ ≥ 0`
//!   ([`PointFrictionEllipsoid`]).
//!
//! The artefacts the paper points at show up here (measured in `tests/point_contacts.rs` and
//! the example `point_vs_ecp`):
//! - the load split among the points is not unique when more than three of them touch. In pure
//!   translation the motion still is (the total wrench is, hence the [`centre_of_pressure`] of
//!   a flat patch, which equals the ECP model's ECP), but when the body turns while it slides the corners
//!   slip in different directions, the friction wrench depends on the split, and the motion is
//!   not unique either (the desk: Newton and PATH converge to ω_z 1e-2 rad/s apart);
//! - the gap is linearised: the rotation over a step moves a vertex towards the rotation axis
//!   through the CM, off its linear prediction by `O(h² |ω|² |r|)`. When ω is parallel to the
//!   plane (tipping) that lifts the vertices in contact, which then carry load across a gap;
//!   when ω is tilted from the normal (a spinning body landing) a vertex can end below the plane
//!   ([`penetration`](crate::record::penetration)).
//!
//! ```
//! use ecp_formulations::{Simulation, point::PointContacts, scenarios};
//! use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
//!
//! // Scenario A1 on its four bottom corners: the same μ g h deceleration as the ECP model.
//! let scene = scenarios::a1_sliding();
//! let mut pc = Simulation::builder(scene).formulation(Box::new(PointContacts::new())).build().unwrap();
//! let mut solver = NewtonSolver::new(NewtonSettings::default());
//! let rec = pc.step(&mut solver).unwrap();
//! assert!(rec.converged && rec.summary.residual <= 1e-10);
//! assert!((rec.bodies[0].v.x - (1.0 - 0.3 * 9.8 * 0.01)).abs() < 1e-9);
//! ```

pub mod blocks;

use nalgebra::Vector3;

use ecp_model::{BlockMcp, DataBlock, DataId, Input, Problem, VarBlock, VarId};

use crate::blocks::{
    BodyDataIds, ContactFrame, KinematicMap, SceneDataIds, add_body_data, add_scene_data,
};
use crate::record::{ContactRecord, scene_gaps_and_modes};
use crate::rotation::rotation_matrix;
use crate::scene::{BodyState, Scene, SceneError, check_penetration, validate_parameters};
use crate::step::body::{is_closing, predict_pose, set_body_span_data, store_states};
use crate::step::{
    BodyHandles, Capabilities, ContactHandles, SensitivitySupport, StepContext, StepFormulation,
    StepHandles,
};
pub use blocks::{
    POINT_GEOMETRY, PointFrictionDissipation, PointFrictionEllipsoid, PointNewtonEuler,
    PointNonPenetration, PointWrenches, centre_of_pressure,
};

/// A point whose gap at the step start is at most this (m) is closed: its impulse starts active.
pub const CLOSED_GAP: f64 = 1e-9;

/// A point whose normal impulse in the previous step was at most this (N s, the order of the
/// solvers' tolerance) carried no load: its warm start is reset (see
/// [`PointContacts`]'s warm start).
pub const UNLOADED_IMPULSE: f64 = 1e-10;

/// Warm-start slip rate σ (m/s) of an open, unloaded point: any σ ≥ 0 solves its friction
/// rows, and one well away from 0 keeps them regular for Newton.
pub const OPEN_SIGMA: f64 = 1.0;

/// Handles of one contact point's unknowns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PointVars {
    /// Body index.
    pub body: usize,
    /// Half-space index.
    pub plane: usize,
    /// Index of the point among the body's contact points ([`PointContacts::points`]).
    pub point: usize,
    /// Normal impulse `p_n ≥ 0`.
    pub pn: VarId,
    /// Friction impulses `(p_t, p_o)`, free.
    pub pf: VarId,
    /// Slip rate `σ ≥ 0`.
    pub sigma: VarId,
}

#[derive(Clone, Debug)]
struct PointBody {
    nu: VarId,
    q: VarId,
    data: BodyDataIds,
}

/// The point-contact formulation (`docs/model.md#point-contacts`): the step problem is built once
/// and its per-step data set with [`BlockMcp::set_data`] (the data blocks of
/// `docs/model.md#data-blocks`, and each point's `geometry`). Records have one [`ContactRecord`]
/// per (point, half-space), body-major and then half-space-major: `a1 = a2` the point at the step
/// end, `lg` its gap, `p_r = 0`.
#[derive(Clone, Debug, Default)]
pub struct PointContacts {
    /// Chosen contact points per body (body frame); `None`: every vertex of each body's pieces.
    chosen: Option<Vec<Vec<Vector3<f64>>>>,
    /// The contact points of each body (body frame).
    points: Vec<Vec<Vector3<f64>>>,
    bodies: Vec<PointBody>,
    contacts: Vec<PointVars>,
    /// The `geometry` data block of each point (parallel to `contacts`).
    geometry: Vec<DataId>,
    scene_data: Option<SceneDataIds>,
}

/// The name prefix of point `i` of a body against half-space `p` (just `point{i}` in a scene of
/// one body and one half-space).
fn point_tag(tagged: bool, body: &str, p: usize, i: usize) -> String {
    if tagged {
        format!("{body}.c{p}.point{i}")
    } else {
        format!("point{i}")
    }
}

impl PointContacts {
    /// The formulation with contact points at the vertices of each body's convex pieces,
    /// coincident ones merged ([`Shape::vertices`](crate::geometry::Shape::vertices)).
    pub fn new() -> Self {
        Self::default()
    }

    /// With a chosen set of contact points per body (body frame), for instance only the corners
    /// of a desk's feet; `points[b]` are body `b`'s. The records still measure the gap and the
    /// mode over every vertex of the real body, so a vertex left out of the set shows up as
    /// penetration.
    pub fn with_points(points: Vec<Vec<Vector3<f64>>>) -> Self {
        PointContacts {
            chosen: Some(points),
            ..Self::default()
        }
    }

    /// Contact handles, in the order of the records' contacts.
    pub fn contacts(&self) -> &[PointVars] {
        &self.contacts
    }
    /// The contact points of body `b` (body frame).
    pub fn points(&self, b: usize) -> &[Vector3<f64>] {
        &self.points[b]
    }

    /// Gap of contact `i` for the bodies at `states` (m).
    fn gap(&self, scene: &Scene, states: &[BodyState], i: usize) -> f64 {
        let c = self.contacts[i];
        let s = states[c.body];
        let p = s.x + rotation_matrix(&s.q) * self.points[c.body][c.point];
        scene.planes[c.plane].value(&p)
    }

    /// Active-contact guess for contact `i` (see the ECP formulation's
    /// [`crate::ecp::guess`]): the normal impulse that carries the body's weight and stops its
    /// approach over the step, shared by the `sharing` points of the same body and half-space
    /// that start it, and the friction impulse on the ellipse opposing the point's current slip
    /// with σ its slip rate (a point of the sliding branch). `p_n = 0` would zero every friction
    /// row, where Newton's merit function has a spurious minimiser.
    fn contact_guess(
        &self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        i: usize,
        sharing: usize,
    ) {
        let c = self.contacts[i];
        let scene = ctx.scene;
        let plane = &scene.planes[c.plane];
        let s = ctx.states[c.body];
        let r = rotation_matrix(&s.q) * self.points[c.body][c.point];
        let n = plane.normal();
        let (h, g) = (scene.h, scene.gravity);
        let m = scene.bodies[c.body].mass.mass;
        let v_pred = s.v + g * h;
        let pn = ((-m * g.dot(&n) * h).max(0.0) + (-m * v_pred.dot(&n)).max(0.0))
            / sharing.max(1) as f64;
        let (_, t, o) = plane.contact_frame();
        let vel = s.v + s.w.cross(&r);
        let (vt, vo) = (t.dot(&vel), o.dot(&vel));
        let f = scene.friction;
        let slip = ((f.e_t * vt).powi(2) + (f.e_o * vo).powi(2)).sqrt();
        let (pf, sigma) = if slip > 1e-12 {
            let k = -f.mu * pn / slip;
            ([k * f.e_t * f.e_t * vt, k * f.e_o * f.e_o * vo], slip)
        } else {
            ([0.0, 0.0], 0.0)
        };
        z[mcp.range(c.pn)][0] = pn;
        z[mcp.range(c.pf)].copy_from_slice(&pf);
        z[mcp.range(c.sigma)][0] = sigma;
    }

    /// Starts the contacts with `pick[i]` from the active guess, each with an equal share of the
    /// load among the contacts with `share[j]` on the same body and half-space.
    fn guess_active(
        &self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        pick: &[bool],
        share: &[bool],
    ) {
        for i in (0..self.contacts.len()).filter(|&i| pick[i]) {
            let c = self.contacts[i];
            let sharing = self
                .contacts
                .iter()
                .zip(share)
                .filter(|(d, s)| **s && d.body == c.body && d.plane == c.plane)
                .count();
            self.contact_guess(ctx, mcp, z, i, sharing);
        }
    }
}

impl StepFormulation for PointContacts {
    fn name(&self) -> &str {
        "point"
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            step_structure: false,
            fallback_backends: true,
            substeps: true,
            user_terms: true,
            // The step's gaps and contact frames are data computed from the start state, whose
            // derivatives the step inputs would miss (`docs/decisions.md`).
            sensitivities: SensitivitySupport::None,
            non_isolated_solutions: false,
        }
    }

    /// Validates the scene and builds the point-contact step problem: per body `ν`, `q`, and per
    /// (half-space, contact point of the body) `p_n`, `(p_t, p_o)`, `σ`.
    fn build(
        &mut self,
        scene: &Scene,
        states: &[BodyState],
        problem: &mut Problem,
    ) -> Result<StepHandles, SceneError> {
        let not_applicable = |reason: String| SceneError::NotApplicable {
            formulation: "point".into(),
            step: None,
            reason,
        };
        let points = match &self.chosen {
            Some(points) => points.clone(),
            None => scene
                .bodies
                .iter()
                .map(|b| b.shape.vertices().to_vec())
                .collect(),
        };
        if points.len() != scene.bodies.len() {
            return Err(not_applicable(format!(
                "{} point sets were given for {} bodies; give one list of contact points per body",
                points.len(),
                scene.bodies.len()
            )));
        }
        for (spec, pts) in scene.bodies.iter().zip(&points) {
            if pts.is_empty() || pts.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
                return Err(not_applicable(format!(
                    "body '{}': the contact points must be a non-empty list of finite body-frame \
                     points",
                    spec.name
                )));
            }
            // The records hold the same number of contacts per body (the trajectory's columns).
            if pts.len() != points[0].len() {
                return Err(not_applicable(format!(
                    "body '{}' has {} contact points and body '{}' has {}; the point formulation \
                     records one contact per point and needs the same number on every body",
                    scene.bodies[0].name,
                    points[0].len(),
                    spec.name,
                    pts.len()
                )));
            }
        }
        // No torsional friction at a point: e_r is not used.
        validate_parameters(scene, false)?;
        check_penetration(scene, states, CLOSED_GAP)?;
        let scene_data = add_scene_data(problem, &scene.gravity, scene.h, &scene.friction);
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        let mut contacts = Vec::new();
        let tagged = scene.bodies.len() > 1 || scene.planes.len() > 1;
        for (b, (spec, points)) in scene.bodies.iter().zip(&points).enumerate() {
            let nu = problem.add_variable_block(
                VarBlock::free(format!("{}.nu", spec.name), 6)
                    .with_component_names(["vx", "vy", "vz", "wx", "wy", "wz"]),
            );
            let q = problem.add_variable_block(
                VarBlock::free(format!("{}.q", spec.name), 7)
                    .with_component_names(["x", "y", "z", "qw", "qx", "qy", "qz"]),
            );
            for p in 0..scene.planes.len() {
                for i in 0..points.len() {
                    let tag = point_tag(tagged, &spec.name, p, i);
                    contacts.push(PointVars {
                        body: b,
                        plane: p,
                        point: i,
                        pn: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.pn"), 1)),
                        pf: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.pf"), 2)
                                .with_component_names(["pt", "po"]),
                        ),
                        sigma: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.sigma"), 1)),
                    });
                }
            }
            let data = add_body_data(problem, &spec.name, spec.mass.mass, &spec.mass.inertia);
            bodies.push(PointBody { nu, q, data });
        }

        // Residual blocks, paired as in `docs/model.md#unknowns` (with the
        // `docs/model.md#point-contacts` unknowns); `update_data` sets their per-step data.
        let SceneDataIds {
            gravity,
            h,
            friction,
        } = scene_data;
        let geometry: Vec<DataId> = contacts
            .iter()
            .map(|c| {
                let tag = point_tag(tagged, &scene.bodies[c.body].name, c.plane, c.point);
                problem.add_data_block(DataBlock::new(
                    format!("{tag}.geometry"),
                    [0.0; POINT_GEOMETRY],
                ))
            })
            .collect();
        let mut newton_euler = Vec::with_capacity(bodies.len());
        for (b, body) in bodies.iter().enumerate() {
            let d = body.data;
            let mut reads: Vec<Input> = vec![body.nu.into(), body.q.into()];
            reads.extend([d.mass, d.inertia, d.start, d.wrench, gravity, h].map(Input::from));
            let mut points = 0;
            for (c, g) in contacts.iter().zip(&geometry).filter(|(c, _)| c.body == b) {
                reads.extend([c.pn.into(), c.pf.into(), Input::from(*g)]);
                points += 1;
            }
            newton_euler.push(problem.add_residual_block(
                body.nu,
                PointNewtonEuler::new(points),
                reads,
            )?);
            problem.add_residual_block(
                body.q,
                KinematicMap,
                &[
                    body.q.into(),
                    body.nu.into(),
                    Input::from(d.start),
                    h.into(),
                ],
            )?;
        }
        for (c, g) in contacts.iter().zip(&geometry) {
            let nu = bodies[c.body].nu;
            let g = Input::from(*g);
            problem.add_residual_block(
                c.pn,
                PointNonPenetration,
                &[nu.into(), g, Input::from(h)],
            )?;
            let vars = [nu, c.pn, c.pf, c.sigma].map(Input::from);
            let mut reads = vars.to_vec();
            reads.extend([g, friction.into()]);
            problem.add_residual_block(c.pf, PointFrictionDissipation, reads)?;
            problem.add_residual_block(
                c.sigma,
                PointFrictionEllipsoid,
                &[c.pn.into(), c.pf.into(), Input::from(friction)],
            )?;
        }
        let handles = StepHandles {
            bodies: bodies
                .iter()
                .zip(newton_euler)
                .map(|(b, ne)| BodyHandles {
                    nu: Some(b.nu),
                    q: Some(b.q),
                    newton_euler: Some(ne),
                    data: Some(b.data),
                })
                .collect(),
            gravity: Some(gravity),
            h: Some(h),
            friction: Some(friction),
            contacts: contacts
                .iter()
                .map(|c| ContactHandles {
                    body: c.body,
                    normal: c.pn,
                    friction: vec![c.pf, c.sigma],
                    geometry: Vec::new(),
                })
                .collect(),
        };
        self.points = points;
        self.bodies = bodies;
        self.contacts = contacts;
        self.geometry = geometry;
        self.scene_data = Some(scene_data);
        Ok(handles)
    }

    fn contacts_per_body(&self) -> usize {
        self.contacts.len() / self.bodies.len().max(1)
    }

    /// `ν` from the initial states; impulses and σ start at 0 (the first step's warm start
    /// restarts every point).
    fn initial_guess(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<(), SceneError> {
        for (body, s) in self.bodies.iter().zip(ctx.states) {
            z[mcp.range(body.nu)].copy_from_slice(&[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z]);
        }
        Ok(())
    }

    /// The span's data: the body data of the Newton–Euler rows (whose mass matrix and
    /// gyroscopic impulse are those of the end of the span) and the points' wrenches and gaps at
    /// the start of the span.
    fn update_data(&mut self, ctx: &StepContext<'_>, mcp: &mut BlockMcp) -> Result<(), SceneError> {
        if let Some(d) = self.scene_data {
            mcp.set_data(d.h, &[ctx.h])?;
        }
        let o = Vector3::zeros();
        for (b, body) in self.bodies.iter().enumerate() {
            let s = ctx.states[b];
            let rot = rotation_matrix(&s.q);
            set_body_span_data(mcp, &body.data, &s, &ctx.wrench(b), &o)?;
            for (c, g) in self.contacts.iter().zip(&self.geometry) {
                if c.body != b {
                    continue;
                }
                let plane = &ctx.scene.planes[c.plane];
                let (n, t, o) = plane.contact_frame();
                let r = rot * self.points[b][c.point];
                let w = PointWrenches::new(&r, &ContactFrame { n, t, o });
                mcp.set_data(*g, &w.geometry_values(plane.value(&(s.x + r))))?;
            }
        }
        Ok(())
    }

    /// The warm start: the previous solution, `q` predicted by the kinematic map, and a fresh
    /// start for every point that carried no load in the previous step (the active guess when
    /// it is closed, together with the other closed points of its body and half-space; `p = 0`
    /// and σ = [`OPEN_SIGMA`] when it is open).
    fn warm_start(&mut self, ctx: &StepContext<'_>, mcp: &BlockMcp, z: &mut [f64]) {
        let o = Vector3::zeros();
        for (body, s) in self.bodies.iter().zip(ctx.states) {
            predict_pose(mcp, z, (body.nu, body.q), s, &o, ctx.h);
        }
        // Every point that carried no load in the previous step gets a fresh start. A closed one
        // gets the active guess (p_n = 0 kills its friction rows, where Newton's merit has a
        // spurious minimiser), and so do the other closed points of its body and half-space, so
        // that the guessed loads add up to the weight. An open one gets p = 0 and σ = OPEN_SIGMA.
        // An unloaded point's friction rows `p_f σ = 0` and `−‖p_f‖ ⊥ σ` hold for every σ ≥ 0, and
        // a σ well away from 0 keeps their Jacobian (σ I on p_f) regular; left at σ ≈ 0 they are
        // doubly degenerate and Newton crawls
        // (`docs/decisions.md#point-contacts-restarting-unloaded-points`). Loaded points keep
        // their warm values, even when the curvature of the step left them a hair above the
        // plane (tipping).
        let n = self.contacts.len();
        let closed: Vec<bool> = (0..n)
            .map(|i| self.gap(ctx.scene, ctx.states, i) <= CLOSED_GAP)
            .collect();
        let unloaded: Vec<bool> = (0..n)
            .map(|i| z[mcp.range(self.contacts[i].pn)][0] <= UNLOADED_IMPULSE)
            .collect();
        let group = |i: usize| (self.contacts[i].body, self.contacts[i].plane);
        let restart: Vec<bool> = (0..n)
            .map(|i| closed[i] && (0..n).any(|j| group(j) == group(i) && closed[j] && unloaded[j]))
            .collect();
        self.guess_active(ctx, mcp, z, &restart, &closed);
        for i in (0..n).filter(|&i| !closed[i] && unloaded[i]) {
            let c = self.contacts[i];
            z[mcp.range(c.pn)][0] = 0.0;
            z[mcp.range(c.pf)].copy_from_slice(&[0.0, 0.0]);
            z[mcp.range(c.sigma)][0] = OPEN_SIGMA;
        }
    }

    /// One retry from the active guess of every point that is closed or closing (as the ECP
    /// formulation does).
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
        let closing: Vec<bool> = (0..self.contacts.len())
            .map(|i| {
                let c = self.contacts[i];
                let n = ctx.scene.planes[c.plane].normal();
                let gap = self.gap(ctx.scene, ctx.states, i);
                let s = &ctx.states[c.body];
                is_closing(gap, s, &ctx.scene.gravity, &n, ctx.h, CLOSED_GAP)
            })
            .collect();
        self.guess_active(ctx, mcp, z, &closing, &closing);
        true
    }

    fn read_out(
        &mut self,
        _ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        states: &mut [BodyState],
    ) -> Result<(), SceneError> {
        let o = Vector3::zeros();
        store_states(mcp, z, self.bodies.iter().map(|b| (b.nu, b.q)), states, &o);
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
        for c in &self.contacts {
            let plane = &scene.planes[c.plane];
            let s = states[c.body];
            let a = s.x + rotation_matrix(&s.q) * self.points[c.body][c.point];
            let (gap, mode) = table[c.body][c.plane];
            let pf = &z[mcp.range(c.pf)];
            out.push(ContactRecord {
                a1: a,
                a2: a,
                lg: plane.value(&a),
                pn: z[mcp.range(c.pn)][0],
                pt: pf[0],
                po: pf[1],
                pr: 0.0,
                sigma: z[mcp.range(c.sigma)][0],
                min_gap: gap,
                mode,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use ecp_solvers::newton::{NewtonSettings, NewtonSolver};

    use super::*;
    use crate::scenarios;
    use crate::step::Simulation;

    fn point_sim(scene: Scene) -> Simulation {
        Simulation::builder(scene)
            .formulation(Box::new(PointContacts::new()))
            .build()
            .unwrap_or_else(|e| panic!("{e}"))
    }

    fn contacts(sim: &Simulation) -> &[PointVars] {
        sim.formulation_as::<PointContacts>()
            .map(|p| p.contacts())
            .unwrap_or_else(|| panic!("the point formulation"))
    }

    /// The first warm start of A1: the four bottom corners start active with a quarter of the
    /// weight each (plus the approach of one step), the four top corners open with
    /// σ = `OPEN_SIGMA`.
    #[test]
    fn first_warm_start_shares_the_weight_among_the_closed_points() {
        let mut sim = point_sim(scenarios::a1_sliding());
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let (mcp, z) = (sim.mcp(), sim.z());
        let (mut closed, mut open) = (0, 0);
        for c in contacts(&sim) {
            let (pn, sigma) = (z[mcp.range(c.pn)][0], z[mcp.range(c.sigma)][0]);
            let p = sim
                .formulation_as::<PointContacts>()
                .map(|f| f.points(0)[c.point])
                .unwrap_or_else(|| panic!("points"));
            if p.z < 0.0 {
                closed += 1;
                assert!(
                    (pn - 2.0 * 10.0 * 9.8 * 0.01 / 4.0).abs() <= 1e-12,
                    "p_n {pn}"
                );
                // Sliding at 1 m/s along x: on the ellipse against the slip.
                let pf = &z[mcp.range(c.pf)];
                assert!((pf[0] + 0.3 * pn).abs() <= 1e-12 && pf[1].abs() <= 1e-15);
                assert!((sigma - 1.0).abs() <= 1e-12);
            } else {
                open += 1;
                assert_eq!((pn, sigma), (0.0, OPEN_SIGMA));
            }
        }
        assert_eq!((closed, open), (4, 4));
    }

    /// A1's first step: the point model's deceleration is the hull model's, `μ g h`, and the
    /// records put each contact at its point with its gap.
    #[test]
    fn a1_first_step_decelerates_by_mu_g_h() {
        let mut sim = point_sim(scenarios::a1_sliding());
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
        assert!(rec.converged);
        assert!((rec.bodies[0].v.x - (1.0 - 0.3 * 9.8 * 0.01)).abs() <= 1e-9);
        let total: f64 = rec.contacts.iter().map(|c| c.pn).sum();
        assert!((total - 10.0 * 9.8 * 0.01).abs() <= 1e-9, "total {total}");
        for c in &rec.contacts {
            assert_eq!(c.a1, c.a2);
            assert!((c.lg - c.a1.z).abs() <= 1e-15 && c.pr == 0.0);
        }
    }
}
