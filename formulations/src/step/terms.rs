//! A user's own terms in the built-in step problem: generalised forces added to a body's
//! Newton–Euler rows ([`Force`]) and extra residual blocks with their own unknowns ([`Term`]).
//! Both join the step problem the formulation builds, so they keep the driver's warm start
//! (their unknowns start each step from the previous solution), fallbacks, records (their values
//! are in [`super::Simulation::z`]) and sensitivities.

use std::sync::Arc;

use nalgebra::Vector3;

use ecp_model::{BlockMcp, DataBlock, DataId, Input, Problem, ResId, ResidualBlock};

use super::handles::StepHandles;
use crate::scene::SceneError;

/// A generalised force on one body: a residual block whose six rows are **added** to the body's
/// Newton–Euler rows (`docs/model.md#newton-euler`,
/// `0 = −M(ν − ν^u) + P_c + p_app + p_vp + p_user`).
///
/// The rows are an **impulse over the span**, world frame: force × h in N·s (rows 0–2) and
/// torque × h in N·m·s about the CM (rows 3–5), the sign of an applied load (a spring pulling
/// the body towards an anchor has rows `−h k (x − anchor)`). The block reads, in this order:
///
/// | input | size | what |
/// |---|---|---|
/// | [`Force::NU`] | 6 | `ν = (v, ω)` at the end of the span |
/// | [`Force::Q`] | 7 | `q = (x, Q)` at the end of the span (x in the step problem's coordinates, relative to [`super::Simulation::origin`]) |
/// | [`Force::H`] | 1 | the span length `h` (data) |
/// | [`Force::DATA`]… | any | the force's own data blocks ([`Force::with_data`]) in the order given |
///
/// Its Jacobian with respect to every input is written by the block (an implicit force:
/// evaluated at the end of the span like the contact impulses), and checked like every block
/// with `ecp_model::check_problem`.
#[derive(Clone)]
pub struct Force {
    pub(crate) block: Arc<dyn ResidualBlock>,
    pub(crate) data: Vec<DataBlock>,
}

impl Force {
    /// Input index of the body's `ν`.
    pub const NU: usize = 0;
    /// Input index of the body's `q`.
    pub const Q: usize = 1;
    /// Input index of the span length `h`.
    pub const H: usize = 2;
    /// Input index of the force's first own data block.
    pub const DATA: usize = 3;

    /// A force computed by `block` (six rows, inputs as in the type's documentation).
    pub fn new(block: impl ResidualBlock + 'static) -> Self {
        Force {
            block: Arc::new(block),
            data: Vec::new(),
        }
    }

    /// A linear spring of stiffness `k` (N/m) from the body's CM to `anchor`
    /// ([`crate::blocks::Spring`]), with its data blocks `<name>.k` and `<name>.anchor`.
    pub fn spring(name: &str, k: f64, anchor: &Vector3<f64>) -> Self {
        Force::new(crate::blocks::Spring)
            .with_data(DataBlock::new(format!("{name}.k"), [k]))
            .with_data(DataBlock::new(format!("{name}.anchor"), anchor.as_slice()))
    }

    /// Adds a data block the force reads after `h` (its parameters: a stiffness, an anchor…);
    /// change it between steps with [`super::Simulation::set_data`].
    pub fn with_data(mut self, block: DataBlock) -> Self {
        self.data.push(block);
        self
    }
}

impl std::fmt::Debug for Force {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let data: Vec<&str> = self.data.iter().map(|d| d.name()).collect();
        f.debug_struct("Force")
            .field("block", &self.block.name())
            .field("data", &data)
            .finish()
    }
}

/// The handles of a force in the step problem.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ForceHandles {
    /// The body it acts on.
    pub body: usize,
    /// Its residual block (a term of the body's Newton–Euler rows).
    pub term: ResId,
    /// Its own data blocks, in the order given.
    pub data: Vec<DataId>,
}

/// Adds `force` on body `body` to `problem`, bound through `handles`.
pub(crate) fn add_force(
    problem: &mut Problem,
    handles: &StepHandles,
    formulation: &str,
    body: usize,
    force: &Force,
) -> Result<ForceHandles, SceneError> {
    let refuse = |reason: String| SceneError::NotApplicable {
        formulation: formulation.to_string(),
        step: None,
        reason,
    };
    let b = handles.body(body).ok_or_else(|| {
        refuse(format!(
            "force '{}' acts on body {body}, but the scene has {} bodies",
            force.block.name(),
            handles.bodies.len()
        ))
    })?;
    let (Some(nu), Some(q), Some(h)) = (b.nu, b.q, handles.h) else {
        return Err(refuse(format!(
            "force '{}': the step problem has no ν and q unknowns for body {body} (user terms \
             need a formulation whose capabilities include user_terms: hull, union or point)",
            force.block.name()
        )));
    };
    let data: Vec<DataId> = force
        .data
        .iter()
        .map(|d| problem.add_data_block(d.clone()))
        .collect();
    let mut reads: Vec<Input> = vec![nu.into(), q.into(), h.into()];
    reads.extend(data.iter().map(|d| Input::from(*d)));
    let term = problem.add_shared_term(nu, Arc::clone(&force.block), reads)?;
    Ok(ForceHandles { body, term, data })
}

/// An extra part of the step problem with its own unknowns: variable blocks paired with residual
/// blocks (and data blocks) that read the formulation's unknowns and data through the
/// [`StepHandles`] — a constraint between two bodies' velocities, an actuator's state, … Terms
/// may also add rows to the formulation's blocks with [`Problem::add_term`].
pub trait Term: Send {
    /// A name for error messages.
    fn name(&self) -> &str;
    /// Declares the term's blocks in `problem`, after the formulation's. Called again when the
    /// driver rebuilds the step problem (then with new handles).
    fn build(&mut self, handles: &StepHandles, problem: &mut Problem) -> Result<(), SceneError>;
    /// The term's starting values in `z` for the first step (zero before the call); afterwards
    /// its unknowns start each step from the previous solution.
    fn initial_guess(&self, mcp: &BlockMcp, z: &mut [f64]) {
        let _ = (mcp, z);
    }
}

#[cfg(test)]
mod tests {
    use ecp_model::{CheckOptions, JacobianBlocks, Params, VarBlock, VarId, check_problem};
    use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
    use nalgebra::Vector3;

    use super::*;
    use crate::scenarios;
    use crate::scene::Scene;
    use crate::step::Simulation;

    /// The A1 box lifted 0.5 m and tossed sideways: free flight for the first steps.
    fn flying() -> Scene {
        let mut scene = scenarios::a1_sliding();
        scene.bodies[0].initial.x.z += 0.5;
        scene.bodies[0].initial.v = Vector3::new(1.0, 0.5, 0.0);
        scene
    }

    /// One step of free flight with the spring: per axis `m (v⁺ − v) = h m g − h k (x + h v⁺ − a)`,
    /// so `v⁺ = (m v + h m g − h k (x − a)) / (m + h² k)`.
    #[test]
    fn a_spring_force_joins_newton_euler() {
        let scene = flying();
        let (k, anchor) = (300.0, Vector3::new(0.2, -0.1, 0.3));
        let spring = Force::spring("spring", k, &anchor);
        let mut sim = Simulation::builder(scene.clone())
            .force(0, spring)
            .build()
            .unwrap_or_else(|e| panic!("{e}"));
        let mut solver = NewtonSolver::new(NewtonSettings::default());
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        for report in check_problem(sim.mcp(), sim.z(), &CheckOptions::default()) {
            assert!(report.ok(), "{report}");
        }
        let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
        let (m, h) = (scene.bodies[0].mass.mass, scene.h);
        let s0 = scene.bodies[0].initial;
        for i in 0..3 {
            let want = (m * s0.v[i] + h * m * scene.gravity[i] - h * k * (s0.x[i] - anchor[i]))
                / (m + h * h * k);
            assert!(
                (rec.bodies[0].v[i] - want).abs() <= 1e-12,
                "axis {i}: {} vs {want}",
                rec.bodies[0].v[i]
            );
        }
        // Its data change between steps like any data block.
        let data = sim.force_handles()[0].data.clone();
        sim.set_data(data[0], &[0.0])
            .unwrap_or_else(|e| panic!("{e}"));
        let before = sim.state(0);
        let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
        let free = before.v + scene.gravity * h;
        assert!((rec.bodies[0].v - free).amax() <= 1e-12);
    }

    /// A term with its own unknown: a multiplier λ (an impulse along y, added to the y row of
    /// Newton–Euler) paired with the row `v_y⁺ = 0`. In free flight it stops the y motion at
    /// once: `λ = −m v_y`.
    struct LockY {
        lambda: Option<VarId>,
    }

    struct VelocityY;
    impl ResidualBlock for VelocityY {
        fn name(&self) -> &str {
            "velocity_y"
        }
        fn num_residuals(&self) -> usize {
            1
        }
        fn parameter_sizes(&self) -> &[usize] {
            &[6]
        }
        fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
            out[0] = p.block(0)[1];
        }
        fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
            jac.set(0, 0, 1, 1.0);
        }
    }

    struct ImpulseY;
    impl ResidualBlock for ImpulseY {
        fn name(&self) -> &str {
            "impulse_y"
        }
        fn num_residuals(&self) -> usize {
            6
        }
        fn parameter_sizes(&self) -> &[usize] {
            &[1]
        }
        fn evaluate(&self, p: Params<'_>, out: &mut [f64]) {
            out.fill(0.0);
            out[1] = p.block(0)[0];
        }
        fn jacobian(&self, _p: Params<'_>, jac: &mut JacobianBlocks<'_>) {
            jac.set(0, 1, 0, 1.0);
        }
    }

    impl Term for LockY {
        fn name(&self) -> &str {
            "lock_y"
        }
        fn build(
            &mut self,
            handles: &StepHandles,
            problem: &mut Problem,
        ) -> Result<(), SceneError> {
            let nu = handles.bodies[0]
                .nu
                .ok_or_else(|| SceneError::NotApplicable {
                    formulation: "?".into(),
                    step: None,
                    reason: "no ν".into(),
                })?;
            let lambda = problem.add_variable_block(VarBlock::free("lock_y.lambda", 1));
            problem.add_residual_block(lambda, VelocityY, &[nu])?;
            problem.add_term(nu, ImpulseY, &[lambda])?;
            self.lambda = Some(lambda);
            Ok(())
        }
    }

    #[test]
    fn a_term_with_its_own_unknown_joins_the_step_problem() {
        for formulation in ["hull", "point"] {
            let scene = flying();
            let f = crate::registry::FormulationRegistry::builtin()
                .create(formulation)
                .unwrap_or_else(|e| panic!("{e}"));
            let mut sim = Simulation::builder_with(scene.clone(), f)
                .term(LockY { lambda: None })
                .build()
                .unwrap_or_else(|e| panic!("{e}"));
            let lambda = VarId(sim.mcp().variable_blocks().len() - 1);
            assert_eq!(
                sim.mcp().variable_blocks()[lambda.0].name(),
                "lock_y.lambda"
            );
            let mut solver = NewtonSolver::new(NewtonSettings::default());
            let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
            let m = scene.bodies[0].mass.mass;
            assert!(rec.bodies[0].v.y.abs() <= 1e-12, "{formulation}");
            assert!(
                (sim.values(lambda)[0] + m * 0.5).abs() <= 1e-10,
                "{formulation}"
            );
            assert!((rec.bodies[0].v.x - 1.0).abs() <= 1e-12, "{formulation}");
            // The next step starts from the previous λ and needs none.
            let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
            assert!(rec.bodies[0].v.y.abs() <= 1e-12 && sim.values(lambda)[0].abs() <= 1e-10);
        }
    }

    #[test]
    fn a_force_with_the_wrong_inputs_is_refused_with_the_block_named() {
        struct Short;
        impl ResidualBlock for Short {
            fn name(&self) -> &str {
                "short"
            }
            fn num_residuals(&self) -> usize {
                6
            }
            fn parameter_sizes(&self) -> &[usize] {
                &[6, 7]
            }
            fn evaluate(&self, _p: Params<'_>, out: &mut [f64]) {
                out.fill(0.0);
            }
            fn jacobian(&self, _p: Params<'_>, _jac: &mut JacobianBlocks<'_>) {}
        }
        let e = Simulation::builder(flying())
            .force(0, Force::new(Short))
            .build()
            .err()
            .map(|e| e.to_string());
        assert!(e.is_some_and(|m| m.contains("short") && m.contains("inputs")));
        let e = Simulation::builder(flying())
            .force(3, Force::spring("far", 1.0, &Vector3::zeros()))
            .build()
            .err()
            .map(|e| e.to_string());
        assert!(e.is_some_and(|m| m.contains("body 3")));
    }
}
