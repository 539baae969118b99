//! A contact formulation defined outside the crate: every body is a frictionless sphere of a
//! given radius around its centre of mass against the scene's half-spaces (geometrically
//! implicit, like the ECP model: the gap is taken at the end of the step). It implements
//! `StepFormulation`, is registered in a `FormulationRegistry` beside the built-in ones and runs
//! through the same driver (warm start, retries, fallbacks, records) and the same `ecp run`
//! outputs: `cargo run --example custom_formulation` writes `out/custom_formulation/`.
//!
//! Per body: `ν`, `q` and one normal impulse `p_n` per half-space; Newton–Euler
//! (`docs/model.md#newton-euler`) with the impulses `n p_n` through the CM, the crate's
//! kinematic map, and `0 ≤ p_n ⊥ (n·x⁺ − c − r)/h ≥ 0`.

use std::path::Path;

use ecp::formulations::blocks::{
    BODY_DATA_SIZES, BodyStepData, KinematicMap, add_body_data, add_scene_data,
    newton_euler::body_rows_jacobian,
};
use ecp::formulations::geometry::MassProperties;
use ecp::formulations::record::scene_gaps_and_modes;
use ecp::formulations::step::body::{predict_pose, set_body_data, store_states};
use ecp::formulations::step::{
    BodyHandles, Capabilities, ContactHandles, SensitivitySupport, StepContext, StepFormulation,
    StepHandles,
};
use ecp::formulations::{BodyState, ContactRecord, FormulationRegistry, Scene, SceneError};
use ecp::model::{
    BlockMcp, Input, JacobianBlocks, Params, Problem, ResidualBlock, VarBlock, VarId,
};
use ecp::run::{RunOptions, RunOutcome, run_scene};
use nalgebra::{Vector3, Vector4, Vector6};

/// The formulation's name in the registry, scene files and reports.
pub const NAME: &str = "sphere";

/// Newton–Euler of a sphere: `inertial rows + applied impulse + Σ_p [n_p; 0] p_n,p`. Reads `ν`,
/// `q`, the body data ([`BODY_DATA_SIZES`]) and one `p_n` per half-space.
struct SphereNewtonEuler {
    normals: Vec<Vector3<f64>>,
    sizes: Vec<usize>,
}

impl SphereNewtonEuler {
    fn new(normals: Vec<Vector3<f64>>) -> Self {
        let mut sizes = vec![6, 7];
        sizes.extend(BODY_DATA_SIZES);
        sizes.extend(normals.iter().map(|_| 1));
        SphereNewtonEuler { normals, sizes }
    }
    const DATA: usize = 2;
    fn impulse(&self, p: usize) -> usize {
        Self::DATA + BODY_DATA_SIZES.len() + p
    }
}

impl ResidualBlock for SphereNewtonEuler {
    fn name(&self) -> &str {
        "sphere_newton_euler"
    }
    fn num_residuals(&self) -> usize {
        6
    }
    fn parameter_sizes(&self) -> &[usize] {
        &self.sizes
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let nu = Vector6::from_column_slice(x.block(0));
        let q = x.block(1);
        let b = BodyStepData::from_inputs(x, Self::DATA);
        let mut r = b.inertial_rows(&nu, &Vector4::new(q[3], q[4], q[5], q[6])) + b.impulse();
        for (p, n) in self.normals.iter().enumerate() {
            let pn = x.block(self.impulse(p))[0];
            r += Vector6::new(n.x, n.y, n.z, 0.0, 0.0, 0.0) * pn;
        }
        out.copy_from_slice(r.as_slice());
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let nu = Vector6::from_column_slice(x.block(0));
        let q = x.block(1);
        let b = BodyStepData::from_inputs(x, Self::DATA);
        body_rows_jacobian(
            &b,
            &nu,
            &Vector4::new(q[3], q[4], q[5], q[6]),
            Self::DATA,
            jac,
        );
        for (p, n) in self.normals.iter().enumerate() {
            for i in 0..3 {
                jac.set(self.impulse(p), i, 0, n[i]);
            }
        }
    }
}

/// `(n·x − c − r)/h`: the sphere's gap at the end of the span, in velocity units (the 1/h row
/// scale of `docs/model.md#contact`). Reads `q` (7) and `h` (1).
struct SphereGap {
    normal: Vector3<f64>,
    offset: f64,
    radius: f64,
}

impl ResidualBlock for SphereGap {
    fn name(&self) -> &str {
        "sphere_gap"
    }
    fn num_residuals(&self) -> usize {
        1
    }
    fn parameter_sizes(&self) -> &[usize] {
        &[7, 1]
    }
    fn evaluate(&self, x: Params<'_>, out: &mut [f64]) {
        let (q, h) = (x.block(0), x.block(1)[0]);
        let gap = self.normal.dot(&Vector3::new(q[0], q[1], q[2])) - self.offset - self.radius;
        out[0] = gap / h;
    }
    fn jacobian(&self, x: Params<'_>, jac: &mut JacobianBlocks<'_>) {
        let (q, h) = (x.block(0), x.block(1)[0]);
        for i in 0..3 {
            jac.set(0, 0, i, self.normal[i] / h);
        }
        let gap = self.normal.dot(&Vector3::new(q[0], q[1], q[2])) - self.offset - self.radius;
        jac.set(1, 0, 0, -gap / (h * h));
    }
}

/// The frictionless-sphere formulation (module documentation).
#[derive(Clone, Debug)]
pub struct Spheres {
    radius: f64,
    /// Per body `(ν, q, body data)`.
    bodies: Vec<(VarId, VarId, ecp::formulations::blocks::BodyDataIds)>,
    /// Per body and half-space, `p_n`.
    impulses: Vec<Vec<VarId>>,
}

impl Spheres {
    /// Spheres of `radius` (m) around every body's CM.
    pub fn new(radius: f64) -> Self {
        Spheres {
            radius,
            bodies: Vec::new(),
            impulses: Vec::new(),
        }
    }
}

impl StepFormulation for Spheres {
    fn name(&self) -> &str {
        NAME
    }
    fn capabilities(&self) -> Capabilities {
        Capabilities {
            step_structure: false,
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
        let refuse = |reason: String| SceneError::NotApplicable {
            formulation: NAME.into(),
            step: None,
            reason,
        };
        if !(self.radius > 0.0 && self.radius.is_finite()) {
            return Err(refuse(format!("the radius {} must be > 0", self.radius)));
        }
        for (spec, s) in scene.bodies.iter().zip(states) {
            for (p, plane) in scene.planes.iter().enumerate() {
                if plane.value(&s.x) < self.radius - 1e-9 {
                    return Err(refuse(format!(
                        "body '{}' starts closer than its radius to half-space #{p}",
                        spec.name
                    )));
                }
            }
        }
        let data = add_scene_data(problem, &scene.gravity, scene.h, &scene.friction);
        let normals: Vec<Vector3<f64>> = scene.planes.iter().map(|p| p.normal()).collect();
        self.bodies.clear();
        self.impulses.clear();
        let mut handles = StepHandles {
            gravity: Some(data.gravity),
            h: Some(data.h),
            friction: Some(data.friction),
            ..StepHandles::default()
        };
        for (b, spec) in scene.bodies.iter().enumerate() {
            let nu = problem.add_variable_block(VarBlock::free(format!("{}.nu", spec.name), 6));
            let q = problem.add_variable_block(VarBlock::free(format!("{}.q", spec.name), 7));
            let pn: Vec<VarId> = (0..scene.planes.len())
                .map(|p| {
                    problem.add_variable_block(VarBlock::nonnegative(
                        format!("{}.pn{p}", spec.name),
                        1,
                    ))
                })
                .collect();
            let MassProperties { mass, inertia, .. } = spec.mass;
            let d = add_body_data(problem, &spec.name, mass, &inertia);
            let mut reads: Vec<Input> = vec![nu.into(), q.into()];
            reads.extend(
                [d.mass, d.inertia, d.start, d.wrench, data.gravity, data.h].map(Input::from),
            );
            reads.extend(pn.iter().map(|v| Input::from(*v)));
            let ne =
                problem.add_residual_block(nu, SphereNewtonEuler::new(normals.clone()), reads)?;
            problem.add_residual_block(
                q,
                KinematicMap,
                &[q.into(), nu.into(), Input::from(d.start), data.h.into()],
            )?;
            for (plane, v) in scene.planes.iter().zip(&pn) {
                let gap = SphereGap {
                    normal: plane.normal(),
                    offset: plane.offset(),
                    radius: self.radius,
                };
                problem.add_residual_block(*v, gap, &[q.into(), Input::from(data.h)])?;
                handles.contacts.push(ContactHandles {
                    body: b,
                    normal: *v,
                    friction: Vec::new(),
                    geometry: Vec::new(),
                });
            }
            handles.bodies.push(BodyHandles {
                nu: Some(nu),
                q: Some(q),
                newton_euler: Some(ne),
                data: Some(d),
            });
            self.bodies.push((nu, q, d));
            self.impulses.push(pn);
        }
        Ok(handles)
    }
    fn contacts_per_body(&self) -> usize {
        self.impulses.first().map_or(0, Vec::len)
    }
    fn initial_guess(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<(), SceneError> {
        for ((nu, _, _), s) in self.bodies.iter().zip(ctx.states) {
            z[mcp.range(*nu)].copy_from_slice(&[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z]);
        }
        Ok(())
    }
    fn update_data(&mut self, ctx: &StepContext<'_>, mcp: &mut BlockMcp) -> Result<(), SceneError> {
        let origin = Vector3::zeros();
        for (((_, _, d), spec), s) in self.bodies.iter().zip(&ctx.scene.bodies).zip(ctx.states) {
            set_body_data(mcp, d, spec, s, &origin, ctx.t0)?;
        }
        Ok(())
    }
    fn warm_start(&mut self, ctx: &StepContext<'_>, mcp: &BlockMcp, z: &mut [f64]) {
        for ((nu, q, _), s) in self.bodies.iter().zip(ctx.states) {
            predict_pose(mcp, z, (*nu, *q), s, &Vector3::zeros(), ctx.h);
        }
    }
    fn read_out(
        &mut self,
        _ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        states: &mut [BodyState],
    ) -> Result<(), SceneError> {
        let vars = self.bodies.iter().map(|(nu, q, _)| (*nu, *q));
        store_states(mcp, z, vars, states, &Vector3::zeros());
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
        for (b, (s, pn)) in states.iter().zip(&self.impulses).enumerate() {
            for (p, (plane, v)) in scene.planes.iter().zip(pn).enumerate() {
                let a = s.x - plane.normal() * self.radius;
                let (min_gap, mode) = table[b][p];
                out.push(ContactRecord {
                    a1: a,
                    a2: plane.project(&a),
                    lg: plane.value(&a),
                    pn: z[mcp.range(*v)][0],
                    pt: 0.0,
                    po: 0.0,
                    pr: 0.0,
                    sigma: 0.0,
                    min_gap,
                    mode,
                });
            }
        }
    }
}

/// Runs `scene_file` with `formulation` ("sphere" or a built-in one) through `ecp run`'s driver
/// into `out`, with the sphere registered beside the built-ins (radius `radius`).
pub fn run(
    scene_file: &Path,
    formulation: &str,
    radius: f64,
    out: &Path,
) -> Result<RunOutcome, Box<dyn std::error::Error>> {
    let mut formulations = FormulationRegistry::builtin();
    formulations.register(move || Box::new(Spheres::new(radius)))?;
    let file = ecp::scene::load_scene(scene_file)?;
    let options = RunOptions {
        out_dir: out.to_path_buf(),
        formulation: Some(formulation.to_string()),
        formulations,
        ..RunOptions::default()
    };
    Ok(run_scene(&file, &options, |_| {})?)
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The A5 box, 0.05 m above the ground, dropped as a sphere of its half height.
    let out = Path::new("out/custom_formulation");
    let outcome = run(Path::new("scenes/a5_drop.toml"), NAME, 0.1, out)?;
    let last = outcome.records.last().ok_or("no step")?;
    println!(
        "{} steps with the '{NAME}' formulation: z = {:.6} m, v_z = {:.2e} m/s at t = {} s; \
         outputs in {}",
        outcome.records.len(),
        last.bodies[0].x.z,
        last.bodies[0].v.z,
        last.t,
        out.display()
    );
    Ok(())
}
