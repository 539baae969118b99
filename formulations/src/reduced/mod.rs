//! The reduced sliding model (`docs/model.md#reduced`; Xie & Chakraborty 2018b): a body sliding
//! with a whole face of Conv(F) on one fixed half-space, in planar motion (in-plane translation and
//! spin about the plane normal). The derivation is in `docs/reduced-sliding.md`; equation numbers
//! (R1)–(R14) below refer to it.
//!
//! With planar motion (`v·n = 0`, `ω = ω_n n`) the normal balance fixes `p_n` (R4), the two
//! tilting-moment balances fix the ECP's in-plane offset `ρ` (R6), Newton–Euler gives the
//! friction impulses as functions of the velocities (R5, R7), and the step of the hull model
//! (`docs/model.md`) reduces to four equations in `(v_t, v_o, ω_n, σ)`: the three
//! maximum-dissipation rows (R10) and the friction ellipsoid in its cone form (R11) — the same
//! form as [`crate::blocks::FrictionEllipsoid`], so the two models have the same solution set.
//! The step MCP has four unknowns and two residual blocks, [`ReducedFriction`] and
//! [`ReducedEllipsoid`] ([`blocks`]), built once; they read the `friction` data block and the step's
//! `sliding` data block ([`SLIDING_DATA`]: (R1)–(R3)), which is updated per step with
//! [`BlockMcp::set_data`].
//!
//! The model applies while the body stays in that planar sliding (or sticking) motion: the
//! formulation refuses scenes it does not describe, and a step stops with
//! [`SceneError::NotApplicable`] where the normal impulse would vanish (lift-off) or the ECP
//! would leave the convex hull of the contact patch (tipping). Sticking (`σ = 0`) is a branch of the same complementarity problem and needs no
//! special handling.

pub mod blocks;

use nalgebra::{Vector3, Vector4};

use ecp_model::{BlockMcp, DataBlock, DataId, Input, Problem, VarBlock, VarId};

use crate::blocks::{ContactFrame, FRICTION_DATA};
use crate::geometry::{ContactMode, contact_mode, convex_hull_2d, min_gap, world_vertices};
use crate::record::{ContactRecord, MODE_TOLERANCE};
use crate::rotation::{kinematic_map, quat_normalize, rotation_matrix};
use crate::scene::{BodyState, Scene, SceneError, validate_parameters};
use crate::step::{
    BodyHandles, Capabilities, SensitivitySupport, StepContext, StepFormulation, StepHandles,
};
pub use blocks::{ReducedEllipsoid, ReducedFriction, SLIDING_DATA, SlidingPoint, SlidingStepData};

/// Distance to the plane (m) within which a vertex of the body belongs to the contact patch at
/// construction.
pub const PATCH_TOLERANCE: f64 = 1e-9;

/// How far (m) the ECP may lie outside the convex hull of the contact patch before the step is
/// refused as tipping (R14). Round-off of the ECP is ~1e-15 m on the reference scenes; the hull
/// model keeps a tipping body's ECP on the hull's edge to ~1e-9 (`docs/model.md#scenarios`).
pub const ECP_TOLERANCE: f64 = 1e-9;

/// Relative tolerance on the initial velocity's normal component and the initial angular
/// velocity's tangential component (m/s and rad/s, relative to `max(1, |v|)`, `max(1, |ω|)`).
pub const PLANAR_TOLERANCE: f64 = 1e-9;

const NOT_APPLICABLE_HINT: &str = "use the hull formulation (--formulation hull), which handles \
                                   every contact mode";

/// The convex hull of the contact patch as a polygon in the body frame (R14): 2-D coordinates
/// in an orthonormal basis `(u1, u2)` of the contact face, counter-clockwise.
#[derive(Clone, Debug)]
struct PatchPolygon {
    u1: Vector3<f64>,
    u2: Vector3<f64>,
    corners: Vec<[f64; 2]>,
}

impl PatchPolygon {
    /// The polygon of the body-frame points `patch` of a face with body-frame normal `nb`.
    fn new(patch: &[Vector3<f64>], nb: &Vector3<f64>) -> Self {
        let seed = if nb.x.abs() > 0.9 {
            Vector3::y()
        } else {
            Vector3::x()
        };
        let u1 = (seed - nb * nb.dot(&seed)).normalize();
        let u2 = nb.cross(&u1);
        let pts: Vec<[f64; 2]> = patch.iter().map(|p| [p.dot(&u1), p.dot(&u2)]).collect();
        PatchPolygon {
            u1,
            u2,
            // Duplicates within 1e-15 m merged, collinear points dropped.
            corners: convex_hull_2d(pts, 1e-15, 0.0),
        }
    }

    /// Largest signed distance (m) of the body-frame point `p` (projected on the face) beyond
    /// the polygon's edges: ≤ 0 inside, the distance to the nearest edge line outside.
    fn outside_distance(&self, p: &Vector3<f64>) -> f64 {
        let q = [p.dot(&self.u1), p.dot(&self.u2)];
        let k = self.corners.len();
        let mut worst = f64::NEG_INFINITY;
        for i in 0..k {
            let a = self.corners[i];
            let b = self.corners[(i + 1) % k];
            let e = [b[0] - a[0], b[1] - a[1]];
            let len = (e[0] * e[0] + e[1] * e[1]).sqrt();
            if len <= 1e-15 {
                continue;
            }
            // Outward normal of a counter-clockwise polygon's edge.
            let d = (e[1] * (q[0] - a[0]) - e[0] * (q[1] - a[1])) / len;
            worst = worst.max(d);
        }
        worst
    }
}

/// The reduced sliding model as a formulation (`docs/model.md#reduced`): one body with a face of
/// Conv(F) on one half-space, sliding or sticking in planar motion. Its step problem has the
/// four unknowns `(v_t, v_o, ω_n, σ)`; its records have the shape of the hull formulation's.
#[derive(Clone, Debug)]
pub struct ReducedSliding {
    frame: ContactFrame,
    patch: Option<PatchPolygon>,
    velocity: VarId,
    sigma: VarId,
    /// The `sliding` data block ([`SLIDING_DATA`]), set per span.
    sliding: DataId,
    /// The data (R1)–(R3) of the span prepared last.
    data: SlidingStepData,
    /// Friction impulses `(p_t, p_o, p_r)` of the last span taken (the warm start's impulses).
    impulses: Option<[f64; 3]>,
}

impl Default for ReducedSliding {
    fn default() -> Self {
        Self::new()
    }
}

impl ReducedSliding {
    /// The formulation; it checks that it applies when the simulation is built.
    pub fn new() -> Self {
        let frame = ContactFrame {
            n: Vector3::z(),
            t: Vector3::x(),
            o: Vector3::y(),
        };
        ReducedSliding {
            frame,
            patch: None,
            velocity: VarId(0),
            sigma: VarId(1),
            sliding: DataId(1),
            data: SlidingStepData {
                frame,
                friction: crate::blocks::FrictionParams {
                    mu: 0.0,
                    e_t: 1.0,
                    e_o: 1.0,
                    e_r: 1.0,
                },
                mass: 1.0,
                height: 0.0,
                momentum: Vector3::zeros(),
                spin_inertia: Vector3::zeros(),
                angular: Vector3::zeros(),
            },
            impulses: None,
        }
    }

    /// The data (R1)–(R3) of the span prepared last.
    pub fn step_data(&self) -> &SlidingStepData {
        &self.data
    }

    /// The span's impulses, ECP offset and slip at the unknowns `z` of the step problem `mcp`.
    pub fn point_at(&self, mcp: &BlockMcp, z: &[f64]) -> SlidingPoint {
        self.data.point(&z[mcp.range(self.velocity)])
    }

    /// The data (R1)–(R3) of the span `ctx` from its start state.
    fn data_at_start(&self, ctx: &StepContext<'_>) -> SlidingStepData {
        let scene = ctx.scene;
        let body = &scene.bodies[0];
        let s = ctx.states[0];
        let h = ctx.h;
        let mp = &body.mass;
        let r = rotation_matrix(&s.q);
        let iw = r * mp.inertia * r.transpose();
        let load = ctx.wrench(0);
        let force = scene.gravity * mp.mass + load.fixed_rows::<3>(0).into_owned();
        let torque = load.fixed_rows::<3>(3).into_owned() - s.w.cross(&(iw * s.w));
        SlidingStepData {
            frame: self.frame,
            friction: scene.friction,
            mass: mp.mass,
            height: scene.planes[0].value(&s.x),
            momentum: s.v * mp.mass + force * h,
            spin_inertia: iw * self.frame.n,
            angular: iw * s.w + torque * h,
        }
    }

    /// Warm start on the sliding branch from the velocities of `s`: `y` from the state, σ the
    /// slip rate at the CM's projection `‖E s‖` (what the friction rows give on the ellipsoid).
    fn sliding_guess(&self, scene: &Scene, s: &BodyState, mcp: &BlockMcp, z: &mut [f64]) {
        let ContactFrame { n, t, o } = self.frame;
        let y = [t.dot(&s.v), o.dot(&s.v), n.dot(&s.w)];
        let f = scene.friction;
        let sigma =
            ((f.e_t * y[0]).powi(2) + (f.e_o * y[1]).powi(2) + (f.e_r * y[2]).powi(2)).sqrt();
        z[mcp.range(self.velocity)].copy_from_slice(&y);
        z[mcp.range(self.sigma)][0] = sigma;
    }

    /// Warm start from the previous solution's impulses and σ: the velocities `y` at which
    /// (R5) and (R7) give the previous step's friction impulses (`v_t`, `v_o` exactly, `ω_n` by
    /// one Newton step on (R7), exact when J ∥ n). The hull formulation's warm start carries the
    /// previous impulses as unknowns; here they are functions of y, and starting from the
    /// previous *velocities* would start from the previous impulses minus the change of the
    /// applied load (`docs/decisions.md#reduced-model-warm-start-from-the-previous-impulses`).
    fn warm_start_from_impulses(&self, pf: [f64; 3], mcp: &BlockMcp, z: &mut [f64]) {
        let d = &self.data;
        let ContactFrame { t, o, .. } = d.frame;
        let mut y = [
            (t.dot(&d.momentum) + pf[0]) / d.mass,
            (o.dot(&d.momentum) + pf[1]) / d.mass,
            z[mcp.range(self.velocity)][2],
        ];
        let p = d.point(&y);
        let slope = p.d_pf[2][2];
        let next = y[2] + (pf[2] - p.pf[2]) / slope;
        if next.is_finite() {
            y[2] = next;
        }
        if y.iter().all(|v| v.is_finite()) {
            z[mcp.range(self.velocity)].copy_from_slice(&y);
        }
    }

    /// The refusal of a span where the normal impulse (R4) would be ≤ 0 (lift-off); `step`
    /// `None` for the scene as given.
    fn check_loaded(
        &self,
        ctx: &StepContext<'_>,
        data: &SlidingStepData,
        step: Option<usize>,
    ) -> Result<(), SceneError> {
        let pn = data.normal_impulse();
        if !(pn.is_nan() || pn <= 0.0) {
            return Ok(());
        }
        let name = &ctx.scene.bodies[0].name;
        let reason = match step {
            None => format!(
                "the normal impulse of the first step would be {pn:.3e} N s: gravity and the \
                 applied load do not press body '{name}' onto the half-space; {NOT_APPLICABLE_HINT}"
            ),
            Some(_) => format!(
                "lift-off: the normal impulse would be {pn:.3e} N s at t = {:.6} s (the \
                 applied load no longer presses body '{name}' onto the half-space); \
                 {NOT_APPLICABLE_HINT}",
                ctx.t0
            ),
        };
        Err(SceneError::NotApplicable {
            formulation: "reduced".into(),
            step,
            reason,
        })
    }
}

impl StepFormulation for ReducedSliding {
    fn name(&self) -> &str {
        "reduced"
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            step_structure: false,
            fallback_backends: true,
            substeps: true,
            user_terms: false,
            sensitivities: SensitivitySupport::None,
            non_isolated_solutions: false,
        }
    }

    /// Validates that the reduced model describes `scene` and builds its step problem.
    ///
    /// Refuses with [`SceneError::NotApplicable`] (`step: None`): more or fewer than one body or
    /// one half-space; a body not resting with a face of Conv(F) on the plane (fewer than three
    /// non-collinear vertices within [`PATCH_TOLERANCE`]); an initial velocity with a normal
    /// component or an angular velocity with a tangential one ([`PLANAR_TOLERANCE`]); a contact
    /// that is not loaded at t = 0 (normal impulse ≤ 0, checked by the first step's starting
    /// point). Bad parameters and penetration are [`SceneError::Parameter`] and
    /// [`SceneError::InitialPenetration`], as for the hull formulation.
    fn build(
        &mut self,
        scene: &Scene,
        states: &[BodyState],
        problem: &mut Problem,
    ) -> Result<StepHandles, SceneError> {
        let refuse = |reason: String| SceneError::NotApplicable {
            formulation: "reduced".into(),
            step: None,
            reason: format!("{reason}; {NOT_APPLICABLE_HINT}"),
        };
        if scene.bodies.len() != 1 {
            return Err(refuse(format!(
                "the reduced sliding model describes one body, the scene has {}",
                scene.bodies.len()
            )));
        }
        if scene.planes.len() != 1 {
            return Err(refuse(format!(
                "the reduced sliding model describes one contact with one half-space, the scene \
                 has {} half-spaces",
                scene.planes.len()
            )));
        }
        validate_parameters(scene, true)?;
        let body = &scene.bodies[0];
        // Conv(F) must exist, as for the hull formulation (a flat body has none).
        body.shape.hull().map_err(|source| SceneError::Geometry {
            body: body.name.clone(),
            source,
        })?;
        let plane = scene.planes[0];
        let (n, t, o) = plane.contact_frame();
        let frame = ContactFrame { n, t, o };
        let state = states[0];
        if state
            .x
            .iter()
            .chain(state.v.iter())
            .chain(state.w.iter())
            .any(|c| !c.is_finite())
        {
            return Err(SceneError::Parameter {
                what: format!("{}.initial state", body.name),
                value: f64::NAN,
                hint: "the initial position and velocities must be finite",
            });
        }
        let r = rotation_matrix(&state.q);
        let gap = min_gap(body.shape.vertices(), &state.x, &r, &plane);
        if gap < -PATCH_TOLERANCE {
            return Err(SceneError::InitialPenetration {
                body: body.name.clone(),
                plane: 0,
                depth: -gap,
            });
        }
        // (R12) patch contact: a face of Conv(F) on the plane.
        let world = world_vertices(body.shape.vertices(), &state.x, &r);
        let mode = contact_mode(&world, &plane, PATCH_TOLERANCE);
        if mode != ContactMode::Patch {
            return Err(refuse(format!(
                "body '{}' does not rest with a face of its convex hull on the half-space (its \
                 contact is '{mode}': fewer than three non-collinear vertices within {:e} m of \
                 the plane, lowest vertex {gap:.3e} m above it)",
                body.name, PATCH_TOLERANCE
            )));
        }
        // (R13) planar motion.
        let vn = state.v.dot(&n);
        if vn.abs() > PLANAR_TOLERANCE * state.v.norm().max(1.0) {
            return Err(refuse(format!(
                "body '{}' starts with a velocity of {vn:.3e} m/s along the plane normal; the \
                 reduced model needs planar motion (an impact or lift-off is not sliding)",
                body.name
            )));
        }
        let w_tan = (state.w - n * state.w.dot(&n)).norm();
        if w_tan > PLANAR_TOLERANCE * state.w.norm().max(1.0) {
            return Err(refuse(format!(
                "body '{}' starts with an angular velocity of {w_tan:.3e} rad/s about an axis \
                 in the plane; the reduced model needs spin about the plane normal only \
                 (tilting is not sliding)",
                body.name
            )));
        }
        let patch: Vec<Vector3<f64>> = body
            .shape
            .vertices()
            .iter()
            .filter(|v| plane.value(&(state.x + r * *v)) <= PATCH_TOLERANCE)
            .copied()
            .collect();
        let nb = r.transpose() * n;

        let velocity = problem.add_variable_block(
            VarBlock::free(format!("{}.velocity", body.name), 3)
                .with_component_names(["vt", "vo", "wn"]),
        );
        let sigma =
            problem.add_variable_block(VarBlock::nonnegative(format!("{}.sigma", body.name), 1));
        let data = SlidingStepData {
            frame,
            friction: scene.friction,
            mass: body.mass.mass,
            height: plane.value(&state.x),
            momentum: Vector3::zeros(),
            spin_inertia: Vector3::zeros(),
            angular: Vector3::zeros(),
        };
        let friction = problem.add_data_block(
            DataBlock::new("friction", scene.friction.values()).with_component_names(FRICTION_DATA),
        );
        let sliding = problem.add_data_block(
            DataBlock::new(format!("{}.sliding", body.name), data.sliding_values())
                .with_component_names(SLIDING_DATA),
        );
        let (f, sl) = (Input::from(friction), Input::from(sliding));
        problem.add_residual_block(
            velocity,
            ReducedFriction { frame },
            &[velocity.into(), sigma.into(), f, sl],
        )?;
        problem.add_residual_block(sigma, ReducedEllipsoid { frame }, &[velocity.into(), f, sl])?;
        *self = ReducedSliding {
            frame,
            patch: Some(PatchPolygon::new(&patch, &nb)),
            velocity,
            sigma,
            sliding,
            data,
            impulses: None,
        };
        Ok(StepHandles {
            bodies: vec![BodyHandles::default()],
            friction: Some(friction),
            ..StepHandles::default()
        })
    }

    fn contacts_per_body(&self) -> usize {
        1
    }

    /// The first step's data (refusing a contact that is not loaded at t = 0) and the warm start
    /// on the sliding branch from the initial velocities.
    fn initial_guess(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<(), SceneError> {
        self.impulses = None;
        let first = self.data_at_start(ctx);
        self.check_loaded(ctx, &first, None)?;
        self.update_data(ctx, mcp)?;
        self.sliding_guess(ctx.scene, &ctx.states[0], mcp, z);
        Ok(())
    }

    /// The span's data (R1)–(R3) at `t0` (the `sliding` data block); refuses the span (lift-off)
    /// when the normal impulse (R4) would be ≤ 0.
    fn update_data(&mut self, ctx: &StepContext<'_>, mcp: &mut BlockMcp) -> Result<(), SceneError> {
        let data = self.data_at_start(ctx);
        self.check_loaded(ctx, &data, Some(ctx.step))?;
        self.data = data;
        mcp.set_data(self.sliding, &data.sliding_values())?;
        Ok(())
    }

    fn warm_start(&mut self, _ctx: &StepContext<'_>, mcp: &BlockMcp, z: &mut [f64]) {
        if let Some(pf) = self.impulses {
            self.warm_start_from_impulses(pf, mcp, z);
        }
    }

    /// Deterministic retries: from rest on the sticking branch, then on the sliding branch from
    /// the start-of-span velocities.
    fn retry_start(
        &mut self,
        attempt: usize,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
    ) -> bool {
        match attempt {
            0 => {
                for v in [self.velocity, self.sigma] {
                    z[mcp.range(v)].iter_mut().for_each(|x| *x = 0.0);
                }
                true
            }
            1 => {
                self.sliding_guess(ctx.scene, &ctx.states[0], mcp, z);
                true
            }
            _ => false,
        }
    }

    /// Takes the solution: refuses it when the ECP leaves the patch (R14), else advances the
    /// state with the kinematic map exactly as the hull formulation does.
    fn read_out(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        states: &mut [BodyState],
    ) -> Result<(), SceneError> {
        let h = ctx.h;
        let p = self.point_at(mcp, z);
        let y = &z[mcp.range(self.velocity)];
        let ContactFrame { n, t, o } = self.frame;
        let s0 = ctx.states[0];
        let v = t * y[0] + o * y[1];
        let w = n * y[2];
        let x = s0.x + v * h;
        // (R9) kinematic map with ω = ω_n n, then renormalised (`docs/model.md#kinematic-map`).
        let q_raw: Vector4<f64> = s0.q + kinematic_map(&s0.q) * w * (0.5 * h);
        let q = quat_normalize(&q_raw).unwrap_or(s0.q);
        let r = rotation_matrix(&q);
        let rho = t * p.rho[0] + o * p.rho[1];
        let a1 = x - n * self.data.height + rho;
        // (R14) the ECP must stay in the convex hull of the patch, which moves with the body.
        let outside = self.patch.as_ref().map_or(f64::NAN, |patch| {
            patch.outside_distance(&(r.transpose() * (a1 - x)))
        });
        if outside.is_nan() || outside > ECP_TOLERANCE {
            return Err(SceneError::NotApplicable {
                formulation: "reduced".into(),
                step: Some(ctx.step),
                reason: format!(
                    "tipping: the ECP that balances the tilting moments would lie {outside:.3e} m \
                     outside the convex hull of the contact patch (tolerance {ECP_TOLERANCE:e} m) \
                     at t = {:.6} s, so body '{}' would tip over the patch's edge; {}",
                    ctx.t0 + h,
                    ctx.scene.bodies[0].name,
                    NOT_APPLICABLE_HINT
                ),
            });
        }
        self.impulses = Some(p.pf);
        states[0] = BodyState { x, q, v, w };
        Ok(())
    }

    fn contact_records(
        &self,
        scene: &Scene,
        states: &[BodyState],
        solved: bool,
        mcp: &BlockMcp,
        z: &[f64],
        out: &mut Vec<ContactRecord>,
    ) {
        let (body, plane) = (&scene.bodies[0], &scene.planes[0]);
        let s = states[0];
        let r = rotation_matrix(&s.q);
        let verts = world_vertices(body.shape.vertices(), &s.x, &r);
        let n = self.frame.n;
        let (a1, pn, pf, sigma) = if solved {
            let p = self.point_at(mcp, z);
            let ContactFrame { t, o, .. } = self.frame;
            let rho = t * p.rho[0] + o * p.rho[1];
            let a1 = s.x - n * self.data.height + rho;
            (a1, p.pn, p.pf, z[mcp.range(self.sigma)][0])
        } else {
            // No impulses were taken; the ECP is reported below the CM.
            (s.x - n * self.data.height, 0.0, [0.0; 3], 0.0)
        };
        out.push(ContactRecord {
            a1,
            a2: a1,
            lg: 0.0,
            pn,
            pt: pf[0],
            po: pf[1],
            pr: pf[2],
            sigma,
            min_gap: min_gap(body.shape.vertices(), &s.x, &r, plane),
            mode: contact_mode(&verts, plane, MODE_TOLERANCE),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_polygon_distances() {
        let pts = [
            Vector3::new(-0.25, -0.25, -0.45),
            Vector3::new(0.25, -0.25, -0.45),
            Vector3::new(0.25, 0.25, -0.45),
            Vector3::new(-0.25, 0.25, -0.45),
            Vector3::new(0.0, 0.25, -0.45),
            Vector3::new(0.1, 0.1, -0.45),
        ];
        let poly = PatchPolygon::new(&pts, &Vector3::new(0.0, 0.0, -1.0));
        assert_eq!(poly.corners.len(), 4);
        let d = poly.outside_distance(&Vector3::new(0.0, 0.0, -0.45));
        assert!((d + 0.25).abs() < 1e-15, "{d}");
        let d = poly.outside_distance(&Vector3::new(0.3, 0.1, -0.45));
        assert!((d - 0.05).abs() < 1e-15, "{d}");
    }
}

#[cfg(test)]
mod formulation_tests {
    use ecp_solvers::newton::{NewtonSettings, NewtonSolver};

    use super::*;
    use crate::scenarios;
    use crate::step::Simulation;

    fn reduced_sim(scene: Scene) -> Result<Simulation, SceneError> {
        Simulation::builder(scene)
            .formulation(Box::new(ReducedSliding::new()))
            .build()
    }

    /// A1 in the reduced model: four unknowns, `v_x` down by `μ g h` per step, the ECP leading
    /// the CM by `μ H` (`docs/model.md#scenarios`).
    #[test]
    fn a1_slides_as_the_hull_model() {
        let mut sim = reduced_sim(scenarios::a1_sliding()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(ecp_model::Mcp::dim(sim.mcp()), 4);
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        for k in 1..=5 {
            let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
            let v = 1.0 - 0.3 * 9.8 * 0.01 * k as f64;
            assert!((rec.bodies[0].v.x - v).abs() <= 1e-9, "step {k}");
            let c = rec.contacts[0];
            assert!((c.a1.x - rec.bodies[0].x.x - 0.3 * 0.1).abs() <= 1e-9);
            assert!((c.pn - 10.0 * 9.8 * 0.01).abs() <= 1e-9);
        }
    }

    /// A load that lifts the box off makes the step refuse, naming the step.
    #[test]
    fn lift_off_is_refused_at_its_step() {
        let mut scene = scenarios::a1_sliding();
        scene.bodies[0].load = crate::scene::Load::Function(std::sync::Arc::new(|t: f64| {
            let fz = if t > 0.025 { 200.0 } else { 0.0 };
            nalgebra::Vector6::new(0.0, 0.0, fz, 0.0, 0.0, 0.0)
        }));
        let mut sim = reduced_sim(scene).unwrap_or_else(|e| panic!("{e}"));
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        let mut taken = 0;
        let err = loop {
            match sim.step(&mut solver) {
                Ok(_) => taken += 1,
                Err(e) => break e,
            }
        };
        assert_eq!(taken, 3);
        assert!(
            matches!(&err, SceneError::NotApplicable { step: Some(4), reason, .. }
                if reason.contains("lift-off")),
            "{err}"
        );
        assert_eq!(sim.steps_taken(), 3);
    }
}
