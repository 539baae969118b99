//! The ECP formulations (`docs/model.md`): the paper's **hull** formulation, one contact between
//! Conv(F) and each half-space, and the **union** formulation, one contact per convex piece of F
//! that can touch a half-space (`docs/model.md#union`). Both are [`EcpContacts`]: the step
//! problem of `docs/model.md#unknowns`, its warm start ([`guess`]), its structural view for the
//! conic backend (`structure`), and the recentred origin of far scenes
//! (`docs/model.md#far-scenes`).
//!
//! ```
//! use ecp_formulations::{scenarios, Simulation};
//! use ecp_solvers::newton::{NewtonSettings, NewtonSolver};
//!
//! // Scenario A1: a box sliding on the ground at 1 m/s decelerates by μ g h per step.
//! let mut sim = Simulation::new(scenarios::a1_sliding()).unwrap();
//! let mut solver = NewtonSolver::new(NewtonSettings::default());
//! let rec = sim.step(&mut solver).unwrap();
//! assert!(rec.converged && rec.summary.residual <= 1e-10);
//! assert!((rec.bodies[0].v.x - (1.0 - 0.3 * 9.8 * 0.01)).abs() < 1e-9);
//! ```

pub mod guess;
mod layout;
mod scales;
mod structure;
pub mod union;

use std::cell::Cell;

use nalgebra::{Matrix3, Vector3, Vector4};

use ecp_model::{
    BlockMcp, DataId, Input, Mcp, McpScales, Problem, ResId, StepStructure, VarBlock,
    fb_residual_into, fb_residual_of_rows,
};

use crate::blocks::{
    ClosestPointAlignment, ContactFrame, FrictionDissipation, FrictionEllipsoid, HalfSpaceSide,
    HullFaces, KinematicMap, NewtonEuler, NonPenetration, NormalCone, SceneDataIds, add_body_data,
    add_plane_data, add_scene_data,
};
use crate::geometry::{ConvexHull, HalfSpace, VertexSpacing, gap_and_mode_spaced, min_gap};
use crate::record::{ContactRecord, MODE_TOLERANCE};
use crate::rotation::rotation_matrix;
use crate::scene::{BodyState, Scene, SceneError, check_body_penetration, validate_parameters};
use crate::step::body::{is_closing, predict_pose, set_body_span_data, store_states};
use crate::step::{
    BodyHandles, Capabilities, ContactHandles, Iterates, Prepared, SensitivitySupport, StepContext,
    StepFormulation, StepHandles,
};
use guess::{Guess, Past, clamp_nonnegative, closest_point_guess_into, extrapolate};
pub use layout::ContactVars;
use layout::{EcpBody, Layout};
use union::union_pieces;

/// Row scale of the length-valued contact rows (C1, C3–C5) is `GEOMETRY_SCALE / h`.
/// See `docs/model.md#contact` and `docs/decisions.md#geometry-rows-scaled-by-1h`.
pub const GEOMETRY_SCALE: f64 = 1.0;

/// Distance (m, any axis) from the step problem's origin beyond which the formulation moves the
/// origin to the bodies' centroid. Round-off in the position rows grows with the coordinates'
/// size (about 2e-16·|x|, amplified by the 1/h row scale), so far from the origin a step could
/// not reach the tolerance; within this distance the loss is below 1e-11.
/// See `docs/decisions.md#recentred-origin-for-far-scenes`.
pub const RECENTRE_DISTANCE: f64 = 100.0;

/// The Fischer–Burmeister residual `‖Φ(z₀)‖₂`, relative to `max(1, ‖z₀‖∞)`, at or below which
/// an extrapolated warm start is taken without the guard's comparison with the plain one: a
/// solution to round-off (Newton returns a start of natural residual `1e-3 × 1e-10` as it is).
const EXACT_START: f64 = 1e-13;

/// The hull and union formulations (module documentation).
#[derive(Clone, Debug)]
pub struct EcpContacts {
    union: bool,
    layout: Layout,
    /// Storage of the warm start kept across steps (`docs/latency.md#allocations`): the face
    /// multipliers of the closest-point guesses and each body's predicted pose.
    faces: Kept<Vec<f64>>,
    motion: Vec<(Vector3<f64>, Matrix3<f64>)>,
    /// The touching vertices of the contact records' modes (storage kept across steps).
    touching: Kept<Vec<Vector3<f64>>>,
    /// The rotations of the bodies' last states (the records', the next warm start's).
    rotations: Rotations,
    /// The span's warm start was extrapolated from the last two steps (`guess::extrapolate`):
    /// the first retry is then today's warm start.
    extrapolated: bool,
    /// The order of that extrapolation (`StepFormulation::warm_start_order`), 0 without one.
    order: usize,
    /// Storage of the guard of the extrapolated warm start (`warm_start`): the start chosen,
    /// `F` and `Φ` there (`StepFormulation::warm_start_value`, `warm_start_fb_vector`), and `F`
    /// and `Φ` at the other start.
    start: Vec<f64>,
    start_f: Vec<f64>,
    start_phi: Vec<f64>,
    f: Vec<f64>,
    phi: Vec<f64>,
    /// `start` and `start_f` are the last warm start's.
    start_known: bool,
    /// Whether a term ([`ecp_model::Problem::add_term`]) adds to some body's `ν` rows, for the
    /// step problem of that many residual blocks (`momentum_rows_decide`).
    terms_on_nu: Option<(usize, bool)>,
    /// The run of iterates with the contact modes of the newest, from the last warm start
    /// ([`EcpContacts::smooth_iterates`]).
    mode_run: Option<ModeRun>,
}

/// How many iterates in a row, from the newest of the iterates of `serial` ([`Iterates::serial`])
/// back, have its discrete contact modes ([`EcpContacts::same_discrete_modes`]), itself included.
#[derive(Clone, Copy, Debug)]
struct ModeRun {
    serial: (u64, u64),
    run: usize,
    /// The iterate after the run has other modes (or the run reaches [`RUN_READ`]); else it
    /// ended where the iterates given did.
    ended: bool,
}

/// The most iterates the mode test reads, from `z_k` back: those of the highest order.
const RUN_READ: usize = guess::MAX_ORDER + 1;

/// The rotation `R(Q)` of the orientation each body was last asked for, kept across calls: the
/// contact records of a step and the warm start and retries of the next one read the rotation
/// of the same state (the end of one step is the start of the next); computed again for any
/// other orientation, so the same matrix either way.
#[derive(Clone, Debug, Default)]
pub(crate) struct Rotations(Kept<Vec<(Vector4<f64>, Matrix3<f64>)>>);

impl Rotations {
    /// `R(q)` for body `b`.
    pub(crate) fn of(&self, b: usize, q: &Vector4<f64>) -> Matrix3<f64> {
        let mut kept = self.0.0.take();
        let same = |k: &Vector4<f64>| {
            k.iter()
                .zip(q.iter())
                .all(|(a, c)| a.to_bits() == c.to_bits())
        };
        let r = match kept.get(b) {
            Some((k, r)) if same(k) => *r,
            _ => {
                let r = rotation_matrix(q);
                if kept.len() <= b {
                    kept.resize(b + 1, (Vector4::repeat(f64::NAN), Matrix3::zeros()));
                }
                kept[b] = (*q, r);
                r
            }
        };
        self.0.0.set(kept);
        r
    }
}

/// Storage reused across steps by methods that take `&self`: a clone starts empty, and `Debug`
/// does not show it.
#[derive(Default)]
struct Kept<T>(Cell<T>);

impl<T: Default> Clone for Kept<T> {
    fn clone(&self) -> Self {
        Kept(Cell::default())
    }
}

impl<T> std::fmt::Debug for Kept<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Kept")
    }
}

impl EcpContacts {
    /// The paper's model: one contact between Conv(F) and each half-space.
    pub fn hull() -> Self {
        EcpContacts {
            union: false,
            layout: Layout::default(),
            faces: Kept::default(),
            motion: Vec::new(),
            touching: Kept::default(),
            rotations: Rotations::default(),
            extrapolated: false,
            order: 0,
            start: Vec::new(),
            start_f: Vec::new(),
            start_phi: Vec::new(),
            f: Vec::new(),
            phi: Vec::new(),
            start_known: false,
            terms_on_nu: None,
            mode_run: None,
        }
    }

    /// One contact, with its own ECP, multipliers, impulses and friction ellipsoid, between each
    /// convex piece of F that can touch a half-space and that half-space
    /// (`docs/model.md#union`, [`union_pieces`]).
    pub fn union() -> Self {
        EcpContacts {
            union: true,
            layout: Layout::default(),
            faces: Kept::default(),
            motion: Vec::new(),
            touching: Kept::default(),
            rotations: Rotations::default(),
            extrapolated: false,
            order: 0,
            start: Vec::new(),
            start_f: Vec::new(),
            start_phi: Vec::new(),
            f: Vec::new(),
            phi: Vec::new(),
            start_known: false,
            terms_on_nu: None,
            mode_run: None,
        }
    }

    /// Whether this is the union formulation.
    pub fn is_union(&self) -> bool {
        self.union
    }
    /// Contact handles.
    pub fn contacts(&self) -> &[ContactVars] {
        &self.layout.contacts
    }
    /// Convex hull of body `b`.
    pub fn hull_of(&self, b: usize) -> &ConvexHull {
        &self.layout.bodies[b].hull
    }
    /// The convex set of contact `i` ([`EcpContacts::contacts`]): Conv(F) of its body for the
    /// hull formulation, its piece's hull for the union formulation.
    pub fn contact_hull(&self, i: usize) -> &ConvexHull {
        &self.layout.contact_hulls[i]
    }
    /// The residual blocks of body `b`: its Newton–Euler and kinematic-map blocks.
    pub fn body_blocks(&self, b: usize) -> (ResId, ResId) {
        let body = &self.layout.bodies[b];
        (body.newton_euler, body.kinematic)
    }
    /// The offset data block of half-space `p` (in the step problem's coordinates; `None` for a
    /// half-space the scene does not have).
    pub fn plane_data(&self, p: usize) -> Option<DataId> {
        self.layout.plane_data.get(p).copied()
    }

    /// Moves the step problem's origin to the bodies' centroid when a body at `states` is
    /// farther than [`RECENTRE_DISTANCE`] from it: the positions in the warm start and the
    /// half-spaces' offset data are shifted (the start positions follow with the span's data);
    /// nothing else holds an absolute position.
    fn recentre_if_far(
        &mut self,
        scene: &Scene,
        states: &[BodyState],
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<(), SceneError> {
        let l = &mut self.layout;
        let far = states
            .iter()
            .map(|s| (s.x - l.origin).amax())
            .fold(0.0, f64::max);
        if far <= RECENTRE_DISTANCE || states.is_empty() {
            return Ok(());
        }
        let centroid =
            states.iter().fold(Vector3::zeros(), |acc, s| acc + s.x) / states.len() as f64;
        if !centroid.iter().all(|c| c.is_finite()) {
            return Ok(());
        }
        let shift = centroid - l.origin;
        let positions = l.bodies.iter().map(|b| b.q);
        let points = l.contacts.iter().flat_map(|c| [c.a1, c.a2]);
        for v in positions.chain(points) {
            let range = mcp.range(v);
            for k in 0..3 {
                z[range.start + k] -= shift[k];
            }
        }
        l.origin = centroid;
        for (p, plane) in scene.planes.iter().enumerate() {
            let n = plane.normal();
            l.step_planes[p] =
                HalfSpace::new(n, plane.offset() - n.dot(&centroid)).map_err(|source| {
                    SceneError::Geometry {
                        body: format!("half-space #{p}"),
                        source,
                    }
                })?;
            mcp.set_data(l.plane_data[p], &[l.step_planes[p].offset()])?;
        }
        Ok(())
    }
}

impl EcpContacts {
    /// The closest-point guesses of this step's start ([`Guess`]), on the formulation's layout
    /// and kept face-multiplier storage.
    fn guess<'g>(&'g self, ctx: &StepContext<'g>, mcp: &'g BlockMcp) -> Guess<'g> {
        Guess {
            layout: &self.layout,
            scene: ctx.scene,
            states: ctx.states,
            mcp,
            faces: &self.faces.0,
            rotations: &self.rotations,
        }
    }

    /// Whether every contact has the same mode in the iterates `a` and `b`: open in both (`p_n`
    /// at most the open threshold of [`StepFormulation::warm_start`]), or closed in both with
    /// `p_n` changed by at most [`IMPULSE_CHANGE`] of the larger, the same friction mode
    /// (sliding, σ > 0, or sticking) and the same active faces of the closest-point condition
    /// (`l_i > 0`). A contact that lands, lands flat on a face (an impact over several steps),
    /// sticks or starts to slide is no smooth step (the T-bar landing flat at steps 125–128:
    /// 35, 30, 2, 0 iterations from the previous solution, 40, 168, 32, 31 from the
    /// extrapolated one with only the open/closed test).
    ///
    /// The test in two parts: [`EcpContacts::same_discrete_modes`] (open or closed, sliding or
    /// sticking, active faces: an equality of values, so transitive, which
    /// [`EcpContacts::smooth_iterates`] keeps from step to step) and
    /// [`EcpContacts::close_impulses`] (the change of `p_n`, not transitive). The test of
    /// before branch wip-warm, kept as the reference of the two parts.
    #[cfg(test)]
    fn same_contact_modes(
        &self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        a: &[f64],
        b: &[f64],
    ) -> bool {
        // σ is a slip speed: sticking below a billionth of the speed gravity gives in a step.
        let sliding = 1e-9 * ctx.scene.gravity.norm() * ctx.h;
        self.layout.contacts.iter().all(|c| {
            let open_pn = open_impulse(ctx.scene, c.body, ctx.h);
            let (pn, sigma) = (mcp.range(c.pn).start, mcp.range(c.sigma).start);
            let closed = a[pn] > open_pn;
            if closed != (b[pn] > open_pn) {
                return false;
            }
            !closed
                || ((a[pn] - b[pn]).abs() <= IMPULSE_CHANGE * a[pn].max(b[pn])
                    && (a[sigma] > sliding) == (b[sigma] > sliding)
                    && mcp
                        .range(c.l)
                        .all(|j| (a[j] > ACTIVE_FACE) == (b[j] > ACTIVE_FACE)))
        })
    }

    /// The discrete part of the mode test (`same_contact_modes`): every contact open in both
    /// iterates, or closed in both with the same friction mode and the same active faces. Each
    /// contact's discrete mode is a value of one iterate, so the test is an equality of values:
    /// `a ~ b` and `b ~ c` give `a ~ c`.
    fn same_discrete_modes(
        &self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        a: &[f64],
        b: &[f64],
    ) -> bool {
        // σ is a slip speed: sticking below a billionth of the speed gravity gives in a step.
        let sliding = 1e-9 * ctx.scene.gravity.norm() * ctx.h;
        self.layout.contacts.iter().all(|c| {
            let open_pn = open_impulse(ctx.scene, c.body, ctx.h);
            let (pn, sigma) = (mcp.range(c.pn).start, mcp.range(c.sigma).start);
            let closed = a[pn] > open_pn;
            if closed != (b[pn] > open_pn) {
                return false;
            }
            if !closed {
                return true;
            }
            if (a[sigma] > sliding) != (b[sigma] > sliding) {
                return false;
            }
            let l = mcp.range(c.l);
            let (la, lb) = (&a[l.clone()], &b[l]);
            la.iter()
                .zip(lb)
                .all(|(x, y)| (*x > ACTIVE_FACE) == (*y > ACTIVE_FACE))
        })
    }

    /// The continuous part of the mode test (`same_contact_modes`), for iterates of the same
    /// discrete modes ([`EcpContacts::same_discrete_modes`]): the first `back` in `1..until` where
    /// `z_{k−back}` fails it against `z_k` (a contact closed in `z_k` whose `p_n` changed by more
    /// than [`IMPULSE_CHANGE`] of the larger of the two), else `until`. `z` holds the iterates,
    /// newest first.
    fn first_impulse_change(
        &self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &[&[f64]; RUN_READ],
        until: usize,
    ) -> usize {
        let mut first = until;
        for c in &self.layout.contacts {
            let pn = mcp.range(c.pn).start;
            let b = z[0][pn];
            if b <= open_impulse(ctx.scene, c.body, ctx.h) {
                continue;
            }
            for (back, older) in z.iter().enumerate().take(first).skip(1) {
                let a = older[pn];
                // False for NaN: a change that is not small.
                let close = (a - b).abs() <= IMPULSE_CHANGE * a.max(b);
                if !close {
                    first = back;
                    break;
                }
            }
        }
        first
    }

    /// The iterates of `it` a smooth start extrapolates from, `None` when the last step is no
    /// smooth step: `z_{k−1}` and `z_k` of the same contact modes (`same_contact_modes`) and some
    /// body moving ([`EcpContacts::moving`]), then the older ones back to the first whose modes
    /// are not those of `z_k` (at most [`guess::MAX_ORDER`] back). The decision of testing each
    /// older iterate against `z_k`, with one discrete test a step: the discrete modes are an
    /// equality of values ([`EcpContacts::same_discrete_modes`]), so the run of iterates with the
    /// modes of `z_k` is that of `z_{k−1}` plus one when `z_{k−1}` has those modes, else `z_k`
    /// alone; the run is kept from the last step's test (`mode_run`, keyed on the iterates'
    /// [`Iterates::serial`]: `z_{k−1}` is the last step's `z_k` exactly when its serial is one
    /// before) and only the impulses' change is tested on each older iterate.
    fn smooth_iterates<'a>(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        mut it: Iterates<'a>,
    ) -> Option<Iterates<'a>> {
        // The older iterates the decision reads: at most `MAX_ORDER` back.
        let depth = it.depth().min(RUN_READ);
        let (kept, pushed) = it.serial;
        let (mut run, mut ended) = match self.mode_run {
            Some(m) if kept != 0 && m.serial == it.serial => (m.run, m.ended),
            Some(m) if kept != 0 && m.serial == (kept, pushed.wrapping_sub(1)) => {
                if self.same_discrete_modes(ctx, mcp, it.before, it.last) {
                    (m.run + 1, m.ended)
                } else {
                    (1, true)
                }
            }
            _ => (1, false),
        };
        // Where the run kept ended short of the iterates given (fewer were given, or none was
        // kept), the older iterates tested as before.
        while !ended && run < depth {
            match it.at(run) {
                Some(z) if self.same_discrete_modes(ctx, mcp, z, it.last) => run += 1,
                _ => ended = true,
            }
        }
        if run >= RUN_READ {
            // No older iterate is read.
            (run, ended) = (RUN_READ, true);
        }
        self.mode_run = (kept != 0).then_some(ModeRun {
            serial: it.serial,
            run,
            ended,
        });
        if run < 2 {
            return None;
        }
        // The older iterates only as far back as each has the same modes too (and as the
        // highest order reads): to the first whose discrete modes (`run`) or impulses differ.
        it.truncate(guess::MAX_ORDER);
        // (Those past the depth are not read.)
        let [e3, e4, e5] = it.earlier.map(|e| e.unwrap_or(it.last));
        let z = [it.last, it.before, it.older.unwrap_or(it.last), e3, e4, e5];
        let differ = self.first_impulse_change(ctx, mcp, &z, run.min(it.depth()));
        if differ < 2 || !self.moving(ctx, mcp, &it) {
            return None;
        }
        if differ < it.depth() {
            it.truncate(differ - 1);
        }
        Some(it)
    }

    /// [`EcpContacts::smooth_iterates`] as it was before branch wip-warm: every older iterate's
    /// modes tested against `z_k` in full (the reference of its tests).
    #[cfg(test)]
    fn smooth_iterates_pairwise<'a>(
        &self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        mut it: Iterates<'a>,
    ) -> Option<Iterates<'a>> {
        if !self.same_contact_modes(ctx, mcp, it.before, it.last) || !self.moving(ctx, mcp, &it) {
            return None;
        }
        it.truncate(guess::MAX_ORDER);
        for back in 2..it.depth() {
            if !it
                .at(back)
                .is_some_and(|z| self.same_contact_modes(ctx, mcp, z, it.last))
            {
                it.truncate(back - 1);
                break;
            }
        }
        Some(it)
    }

    /// Whether some body's `ν` changed between the last two steps by more than a millionth of
    /// what gravity gives in a step: otherwise the extrapolation gains nothing, and near rest it
    /// moves a start that is already a solution off it (the stress suite's `023_room_corner`
    /// at rest in a corner: 0 iterations from the previous solution, up to 385 from the
    /// extrapolated one).
    fn moving(&self, ctx: &StepContext<'_>, mcp: &BlockMcp, it: &Iterates<'_>) -> bool {
        let change = 1e-6 * ctx.scene.gravity.norm() * ctx.h;
        self.layout.bodies.iter().any(|b| {
            mcp.range(b.nu)
                .any(|j| (it.last[j] - it.before[j]).abs() > change)
        })
    }

    /// Whether the extrapolated start's Fischer–Burmeister residual `merit` is below that of the
    /// plain warm start's translational Newton–Euler rows (each body's first three `ν` rows, the
    /// momentum balance `−m (v − v^u) + h (m g + f) + Σ (n p_n + t p_t + o p_o)`), found at the last
    /// step's iterate `last` without building the plain start: so below the plain start's whole
    /// residual, the guard's choice without the plain start (`warm_start`).
    ///
    /// Those rows read only `ν`, each contact's `p_n` and `p_f` and the span's data, never `q` or
    /// `a1` (test `momentum_rows_at_the_last_iterate_are_those_of_the_plain_start`). The plain start
    /// ([`EcpContacts::warm_start_from`] without iterates, from `last`) keeps `last`'s `ν`, and the
    /// impulses of every contact closed in `last` (an open one whose predicted pose penetrates starts
    /// active instead): with every contact closed and no term adding to the `ν` rows, `F` of those
    /// rows at `last` has the plain start's bits, and their residual over those rows, in index order,
    /// is at most the plain start's whole one ([`fb_residual_of_rows`]). `false` (undecided) otherwise;
    /// `f` is scratch (`F` at `last` in those rows on return). Without `evaluate`, only the rows'
    /// lower bound ([`EcpContacts::momentum_rows_bound`]) decides (`false` when it does not).
    fn momentum_rows_decide(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        last: &[f64],
        merit: f64,
        (f, evaluate): (&mut [f64], bool),
    ) -> bool {
        let blocks = mcp.num_residual_blocks();
        let terms = match self.terms_on_nu {
            Some((n, terms)) if n == blocks => terms,
            _ => {
                let bodies = &self.layout.bodies;
                let terms = (0..blocks).any(|r| {
                    let (v, term) = mcp.residual_rows(ResId(r));
                    term && bodies.iter().any(|b| b.nu == v)
                });
                self.terms_on_nu = Some((blocks, terms));
                terms
            }
        };
        let l = &self.layout;
        let closed = l
            .contacts
            .iter()
            .all(|c| last[mcp.range(c.pn)][0] > open_impulse(ctx.scene, c.body, ctx.h));
        if terms || !closed {
            return false;
        }
        if !evaluate {
            // A lower bound of those rows' residual from the rows themselves, without the
            // Newton–Euler block's evaluation (its rotations and angular rows, ≈ 0.9 k
            // instructions on the desk): below it, `merit` is below the residual.
            let below = self.momentum_rows_bound(mcp, last);
            #[cfg(test)]
            {
                // The tests check the bound against the rows' residual on every guarded step.
                let rows = self.momentum_rows_residual(mcp, last, f);
                assert!(below <= rows, "{below} {rows}");
                tests::BOUND_CHECKS.with(|n| n.set(n.get() + usize::from(merit < below)));
            }
            return merit < below;
        }
        merit < self.momentum_rows_residual(mcp, last, f)
    }

    /// The residual of the bodies' momentum rows at `last` (`momentum_rows_decide`), `F` of
    /// those rows written into `f`.
    fn momentum_rows_residual(&self, mcp: &BlockMcp, last: &[f64], f: &mut [f64]) -> f64 {
        let l = &self.layout;
        for body in &l.bodies {
            mcp.evaluate_rows_of(body.nu, last, f);
        }
        let rows = l.bodies.iter().map(|b| {
            let nu = mcp.range(b.nu);
            nu.start..nu.start + 3
        });
        fb_residual_of_rows(last, f, mcp.lower(), mcp.upper(), rows)
    }

    /// A lower bound of the residual of the bodies' momentum rows at `last`
    /// (`fb_residual_of_rows` of `momentum_rows_decide`, as `evaluate_rows_of` gives them), `0`
    /// when it has none: each row `−m (v − v^u) + h (m g + f) + Σ (n p_n + t p_t + o p_o)`
    /// computed from the span's data (`Layout::span`, what the Newton–Euler block reads, and its
    /// impulse `h (m g + f)` by the block's own [`crate::blocks::BodyStepData::impulse`]) and
    /// the contacts' frames and impulses in `last`, less `1e-13 S`, `S` the sum of the terms'
    /// magnitudes: the block's value and this one are each within a few units of round-off of
    /// `S` (sums of at most `3 + 3 c` products) of the exact row, so the row's magnitude is at
    /// least this. The rows' variables are free (`Φ_i = F_i`), so the residual is at least the
    /// norm of those bounds, taken `(1 − 1e-12)` times against the sums' and the square root's
    /// round-off. Rows of non-finite or huge terms (`S ≥ 1e300`, NaN) give no bound.
    fn momentum_rows_bound(&self, mcp: &BlockMcp, last: &[f64]) -> f64 {
        let l = &self.layout;
        if l.span.bodies.len() != l.bodies.len() {
            return 0.0;
        }
        let (lower, upper) = (mcp.lower(), mcp.upper());
        let mut sum = 0.0;
        for (b, (body, data)) in l.bodies.iter().zip(&l.span.bodies).enumerate() {
            let nu = mcp.range(body.nu).start;
            let free =
                (nu..nu + 3).all(|i| lower[i] == f64::NEG_INFINITY && upper[i] == f64::INFINITY);
            if !free {
                return 0.0;
            }
            let m = data.mass;
            let impulse = data.impulse();
            let mut row = [0.0; 3];
            let mut size = [0.0; 3];
            for i in 0..3 {
                let (v1, v0) = (last[nu + i], data.nu_start[i]);
                row[i] = -(v1 - v0) * m + impulse[i];
                size[i] = m.abs() * (v1.abs() + v0.abs()) + impulse[i].abs();
            }
            let mine = l.contacts.iter().filter(|c| c.body == b);
            for (c, frame) in mine.zip(&body.frames) {
                let pn = last[mcp.range(c.pn).start];
                let pf = mcp.range(c.pf).start;
                let (pt, po) = (last[pf], last[pf + 1]);
                for i in 0..3 {
                    let (n, t, o) = (frame.n[i] * pn, frame.t[i] * pt, frame.o[i] * po);
                    row[i] += n + t + o;
                    size[i] += n.abs() + t.abs() + o.abs();
                }
            }
            for i in 0..3 {
                // False for NaN.
                let moderate = size[i] < 1e300;
                if !moderate {
                    return 0.0;
                }
                let least = row[i].abs() - (1e-13 * size[i] + f64::MIN_POSITIVE);
                if least > 0.0 {
                    sum += least * least;
                }
            }
        }
        sum.sqrt() * (1.0 - 1e-12)
    }

    /// The order of the extrapolation from the iterates `past`: the highest they allow (at most
    /// [`guess::MAX_ORDER`]), but 2 when the quadratic extrapolation from the steps before the
    /// last one hit the last one's `ν` to round-off (at most [`EXACT_START`] of `max(1, ‖ν‖∞)`):
    /// the motion is then polynomial of degree 2 at most (A1's constant deceleration, a box
    /// sliding down an incline), where higher orders only amplify the round-off (their
    /// coefficients sum to 15, 31, 63 against 7) and a start solved to round-off returned in 0
    /// iterations becomes a start needing one (`a4_incline_25`, Newton: 92 iterations with order
    /// 2, 98 with 4 always, 105 with 5 always).
    fn extrapolation_order<'a>(&self, mcp: &BlockMcp, past: Past<'a>) -> Past<'a> {
        // A higher order only after a whole run of `MAX_ORDER + 1` smooth steps: a sustained
        // smooth motion, not the few steps between two events, where the start of the next
        // event step decides which of several solutions a step with a non-unique impulse split
        // takes (`s20261128_061_v_trough`, Newton without fallbacks: with orders 3 and 4 on its
        // steps 5–6, step 6 ends 2.2e-7 away, and step 16 fails after 3 353 iterations).
        if past.order() < guess::MAX_ORDER {
            return past.with_order(2);
        }
        let last = past.newest();
        let (mut miss, mut size) = (0.0f64, 1.0f64);
        for body in &self.layout.bodies {
            let nu = mcp.range(body.nu);
            size = last[nu.clone()].iter().fold(size, |m, v| m.max(v.abs()));
            // `None` only with fewer than four iterates: no evidence for the quadratic.
            miss = miss.max(past.miss(2, nu).unwrap_or(f64::INFINITY));
        }
        if miss <= EXACT_START * size {
            past.with_order(2)
        } else {
            past
        }
    }

    /// The warm start of [`StepFormulation::warm_start`], extrapolated from the iterates
    /// `smooth` when given.
    fn warm_start_from(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        smooth: Option<(&[f64], Past<'_>)>,
    ) {
        let l = &self.layout;
        let o = l.origin;
        if let Some((last, past)) = &smooth {
            // From the last step's iterate (the same start however often it is asked for).
            z.copy_from_slice(last);
            for body in &l.bodies {
                extrapolate(z, mcp.range(body.nu), past, false);
            }
        }
        let mut motion = std::mem::take(&mut self.motion);
        motion.clear();
        motion.extend(
            l.bodies
                .iter()
                .zip(ctx.states)
                .map(|(body, s)| predict_pose(mcp, z, (body.nu, body.q), s, &o, ctx.h)),
        );
        let guess = self.guess(ctx, mcp);
        let scene = ctx.scene;
        for i in 0..l.contacts.len() {
            let c = l.contacts[i];
            if z[mcp.range(c.pn)][0] > open_impulse(scene, c.body, ctx.h) {
                // A closed contact keeps its unknowns unless the predicted pose brings another
                // feature lowest.
                let (x1, r1) = &motion[c.body];
                let moved = guess.follow_closest_feature(i, (x1, r1), z);
                if let Some((_, past)) = &smooth
                    && !moved
                {
                    if l.contacts_in_order {
                        // The contact's unknowns in one pass (`a1` … `σ` lie in a row), then the
                        // non-negative ones (`l`, `l_g`, `p_n` in a row, and `σ`) clamped.
                        let (a1, faces) = (mcp.range(c.a1), mcp.range(c.l));
                        let (pn, sigma) = (mcp.range(c.pn), mcp.range(c.sigma));
                        extrapolate(z, a1.start..sigma.end, past, false);
                        clamp_nonnegative(z, faces.start..pn.end);
                        clamp_nonnegative(z, sigma);
                    } else {
                        for v in [c.a1, c.a2, c.pf] {
                            extrapolate(z, mcp.range(v), past, false);
                        }
                        for v in [c.l, c.lg, c.pn, c.sigma] {
                            extrapolate(z, mcp.range(v), past, true);
                        }
                    }
                }
                continue;
            }
            let (x1, r1) = motion[c.body];
            let plane = scene.planes[c.plane];
            let mut faces = self.faces.0.take();
            let (a1, gap) =
                closest_point_guess_into(&l.contact_hulls[i], &plane, &x1, &r1, &mut faces);
            if !a1.iter().all(|v| v.is_finite()) {
                self.faces.0.set(faces);
                continue;
            }
            if gap > 0.0 {
                let a2 = plane.project(&a1);
                z[mcp.range(c.a1)].copy_from_slice((a1 - o).as_slice());
                z[mcp.range(c.a2)].copy_from_slice((a2 - o).as_slice());
                z[mcp.range(c.lg)][0] = gap;
                z[mcp.range(c.l)].copy_from_slice(&faces);
                self.faces.0.set(faces);
                let sigma = guess.open_contact_sigma(i, z);
                if z[mcp.range(c.sigma)][0] < sigma {
                    z[mcp.range(c.sigma)][0] = sigma;
                }
            } else {
                self.faces.0.set(faces);
                // The predicted pose penetrates: the contact closes within the span.
                guess.contact_at(i, true, (&x1, &r1), z);
            }
        }
        self.motion = motion;
    }
}

impl StepFormulation for EcpContacts {
    fn name(&self) -> &str {
        if self.union { "union" } else { "hull" }
    }

    fn capabilities(&self) -> Capabilities {
        Capabilities {
            step_structure: true,
            fallback_backends: true,
            substeps: true,
            user_terms: true,
            sensitivities: if self.union {
                SensitivitySupport::NotUnique
            } else {
                SensitivitySupport::Exact
            },
            non_isolated_solutions: self.union,
        }
    }

    fn build(
        &mut self,
        scene: &Scene,
        states: &[BodyState],
        problem: &mut Problem,
    ) -> Result<StepHandles, SceneError> {
        validate_parameters(scene, true)?;
        self.terms_on_nu = None;
        self.mode_run = None;
        let mut layout = Layout::default();
        let scene_data = add_scene_data(problem, &scene.gravity, scene.h, &scene.friction);
        layout.plane_data = (scene.planes.iter().enumerate())
            .map(|(p, plane)| add_plane_data(problem, p, plane.offset()))
            .collect();
        for (b, (spec, state)) in scene.bodies.iter().zip(states).enumerate() {
            let hull = spec.shape.hull().map_err(|source| SceneError::Geometry {
                body: spec.name.clone(),
                source,
            })?;
            check_body_penetration(spec, state, &scene.planes, 1e-9)?;
            let nu = problem.add_variable_block(
                VarBlock::free(format!("{}.nu", spec.name), 6)
                    .with_component_names(["vx", "vy", "vz", "wx", "wy", "wz"]),
            );
            let q = problem.add_variable_block(
                VarBlock::free(format!("{}.q", spec.name), 7)
                    .with_component_names(["x", "y", "z", "qw", "qx", "qy", "qz"]),
            );
            // The Newton–Euler and kinematic-map rows involve only this body's ν and q besides
            // the contact unknowns: a linear solver eliminates them first.
            problem.add_elimination_group(&[nu, q]);
            // The convex sets that get a contact: Conv(F), or every piece that can touch (union).
            let sets: Vec<(Option<usize>, ConvexHull)> = if self.union {
                let mut sets = Vec::new();
                for i in union_pieces(spec, state, &scene.planes) {
                    let piece = &spec.shape.pieces()[i];
                    let h = piece.hull().map_err(|source| SceneError::Geometry {
                        body: format!("{} (piece {i})", spec.name),
                        source,
                    })?;
                    sets.push((Some(i), h));
                }
                sets
            } else {
                vec![(None, hull.clone())]
            };
            let mut frames = Vec::new();
            for (p, plane) in scene.planes.iter().enumerate() {
                for (piece, set) in &sets {
                    let m = set.num_faces();
                    let mut tag = if scene.planes.len() > 1 || scene.bodies.len() > 1 {
                        format!("{}.c{}", spec.name, p)
                    } else {
                        "contact".to_string()
                    };
                    if let Some(i) = piece {
                        tag = format!("{tag}.piece{i}");
                    }
                    let cv = ContactVars {
                        body: b,
                        plane: p,
                        piece: *piece,
                        a1: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.a1"), 3)
                                .with_component_names(["x", "y", "z"]),
                        ),
                        a2: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.a2"), 3)
                                .with_component_names(["x", "y", "z"]),
                        ),
                        l: problem.add_variable_block(VarBlock::nonnegative(format!("{tag}.l"), m)),
                        lg: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.lg"), 1)),
                        pn: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.pn"), 1)),
                        pf: problem.add_variable_block(
                            VarBlock::free(format!("{tag}.pf"), 3)
                                .with_component_names(["pt", "po", "pr"]),
                        ),
                        sigma: problem
                            .add_variable_block(VarBlock::nonnegative(format!("{tag}.sigma"), 1)),
                    };
                    let (n, t, o) = plane.contact_frame();
                    frames.push(ContactFrame { n, t, o });
                    layout.contacts.push(cv);
                    layout.contact_hulls.push(set.clone());
                }
            }
            let data = add_body_data(problem, &spec.name, spec.mass.mass, &spec.mass.inertia);
            layout.bodies.push(EcpBody {
                length: scales::bounding_diagonal(hull.vertices()),
                spacing: VertexSpacing::of(spec.shape.vertices()),
                hull,
                nu,
                q,
                newton_euler: ResId(0),
                kinematic: ResId(0),
                frames,
                data,
            });
        }

        // Residual blocks (`docs/model.md#residual-blocks`), paired as in `docs/model.md#unknowns`,
        // reading the data blocks of `docs/model.md#data-blocks`; `update_data` sets the
        // per-span data.
        let SceneDataIds {
            gravity,
            h: step_length,
            friction,
        } = scene_data;
        for (b, body) in layout.bodies.iter_mut().enumerate() {
            let mine: Vec<(&ContactVars, &ConvexHull)> = layout
                .contacts
                .iter()
                .zip(&layout.contact_hulls)
                .filter(|(c, _)| c.body == b)
                .collect();
            let mut reads: Vec<Input> = vec![body.nu.into(), body.q.into()];
            for (c, _) in &mine {
                reads.extend([c.a1, c.pn, c.pf].map(Input::from));
            }
            let d = body.data;
            reads.extend(
                [d.mass, d.inertia, d.start, d.wrench, gravity, step_length].map(Input::from),
            );
            body.newton_euler = problem.add_residual_block(
                body.nu,
                NewtonEuler::new(body.frames.clone()),
                reads,
            )?;
            body.kinematic = problem.add_residual_block(
                body.q,
                KinematicMap,
                &[
                    body.q.into(),
                    body.nu.into(),
                    Input::from(d.start),
                    step_length.into(),
                ],
            )?;
            // Length-valued rows in velocity units (1/h): a penetration of h·Δv then weighs
            // like a velocity error Δv (`docs/model.md#contact`,
            // `docs/decisions.md#geometry-rows-scaled-by-1h`).
            let scale = GEOMETRY_SCALE / scene.h;
            for ((c, set), frame) in mine.iter().zip(&body.frames) {
                let normals: Vec<Vector3<f64>> = set.faces().iter().map(|f| f.normal).collect();
                let offsets: Vec<f64> = set.faces().iter().map(|f| f.offset).collect();
                let ng = scene.planes[c.plane].normal();
                problem.add_residual_block(
                    c.a1,
                    ClosestPointAlignment { normal: ng, scale },
                    &[c.a1, c.a2, c.lg],
                )?;
                problem.add_residual_block(
                    c.a2,
                    NormalCone::new(ng, normals.clone()),
                    &[c.l, body.q],
                )?;
                problem.add_residual_block(
                    c.l,
                    HullFaces {
                        face_normals: normals,
                        offsets,
                        scale,
                    },
                    &[c.a1, body.q],
                )?;
                let offset = Input::from(layout.plane_data[c.plane]);
                problem.add_residual_block(
                    c.lg,
                    HalfSpaceSide { normal: ng, scale },
                    &[c.a2.into(), offset],
                )?;
                problem.add_residual_block(
                    c.pn,
                    NonPenetration { normal: ng, scale },
                    &[c.a1.into(), offset],
                )?;
                let vars = [body.nu, body.q, c.a1, c.pn, c.pf, c.sigma];
                let mut reads: Vec<Input> = vars.map(Input::from).to_vec();
                reads.push(friction.into());
                problem.add_residual_block(c.pf, FrictionDissipation { frame: *frame }, reads)?;
                problem.add_residual_block(
                    c.sigma,
                    FrictionEllipsoid,
                    &[c.pn.into(), c.pf.into(), Input::from(friction)],
                )?;
            }
        }
        layout.scene_data = Some(scene_data);
        layout.step_planes = scene.planes.clone();
        // Each contact's blocks were added in a row: `a1`, `a2`, `l`, `l_g`, `p_n`, `p_f`, `σ`.
        layout.contacts_in_order = layout.contacts.iter().all(|c| {
            [c.a2, c.l, c.lg, c.pn, c.pf, c.sigma]
                .iter()
                .enumerate()
                .all(|(k, v)| v.0 == c.a1.0 + 1 + k)
        });
        let handles = StepHandles {
            bodies: layout
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
            contacts: layout
                .contacts
                .iter()
                .map(|c| ContactHandles {
                    body: c.body,
                    normal: c.pn,
                    friction: vec![c.pf, c.sigma],
                    geometry: vec![c.a1, c.a2, c.l, c.lg],
                })
                .collect(),
        };
        self.layout = layout;
        Ok(handles)
    }

    fn contacts_per_body(&self) -> usize {
        self.layout.contacts.len() / self.layout.bodies.len().max(1)
    }

    /// First-step guess (`docs/model.md#stepper`): `ν` from the state and, for each contact,
    /// `a1` on Conv(F) nearest to G and its projection `a2`, the gap as `l_g`, face multipliers
    /// of the closest-point condition; where the body already touches G, the impulses start
    /// active (`guess::Guess::contact`). The origin starts at zero.
    fn initial_guess(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<(), SceneError> {
        let l = &mut self.layout;
        l.origin = Vector3::zeros();
        l.step_planes = ctx.scene.planes.clone();
        for (p, plane) in ctx.scene.planes.iter().enumerate() {
            mcp.set_data(l.plane_data[p], &[plane.offset()])?;
        }
        self.recentre_if_far(ctx.scene, ctx.states, mcp, z)?;
        for (body, s) in self.layout.bodies.iter().zip(ctx.states) {
            z[mcp.range(body.nu)].copy_from_slice(&[s.v.x, s.v.y, s.v.z, s.w.x, s.w.y, s.w.z]);
        }
        let guess = self.guess(ctx, mcp);
        for i in 0..self.layout.contacts.len() {
            guess.contact(i, false, z);
        }
        Ok(())
    }

    fn begin_step(
        &mut self,
        ctx: &StepContext<'_>,
        mcp: &mut BlockMcp,
        z: &mut [f64],
    ) -> Result<Prepared, SceneError> {
        self.recentre_if_far(ctx.scene, ctx.states, mcp, z)?;
        Ok(Prepared::Ready)
    }

    /// The span's data (`docs/model.md#data-blocks`): each body's start state and applied
    /// wrench at `t0`, and the span length.
    fn update_data(&mut self, ctx: &StepContext<'_>, mcp: &mut BlockMcp) -> Result<(), SceneError> {
        let l = &mut self.layout;
        if let Some(d) = l.scene_data {
            mcp.set_data(d.h, &[ctx.h])?;
        }
        for (b, (body, s)) in l.bodies.iter().zip(ctx.states).enumerate() {
            set_body_span_data(mcp, &body.data, s, &ctx.wrench(b), &l.origin)?;
        }
        l.record_span(mcp, ctx.states);
        Ok(())
    }

    /// Warm start from the previous solution: `q` predicted by the kinematic map; a contact that
    /// ended the last step open (`p_n = 0`) starts at the closest points of the predicted pose
    /// (`a1`, `a2`, `l_g`, face multipliers that satisfy C2 there, [`guess::closest_point_guess`]) when
    /// that pose is still separated, with σ kept > 0 (`guess::Guess::open_contact_sigma`: the
    /// solution leaves σ free, and σ = 0 makes the friction rows' linearisation vanish at the
    /// warm start); when the predicted pose penetrates, the contact closes within the span and
    /// starts active. On a smooth step (the driver's [`StepContext::history`], every contact in
    /// the same mode in the last two steps and some body's `ν` changing: `same_contact_modes`,
    /// `moving`) `ν` and the closed contacts' unknowns are extrapolated from the last steps
    /// instead (`guess::extrapolate`), when that start's Fischer–Burmeister residual is below
    /// the plain warm start's.
    fn warm_start(&mut self, ctx: &StepContext<'_>, mcp: &BlockMcp, z: &mut [f64]) {
        // Not for the union formulation: its impulse split is not unique, and extrapolating it
        // left PATH short of the tolerance on the union desk's step 78 (tests/union.rs).
        let history = ctx.history.filter(|_| !self.union);
        let smooth = history.and_then(|it| self.smooth_iterates(ctx, mcp, it));
        #[cfg(test)]
        if let Some(it) = history {
            // The decision of the pairwise test, checked on every warm start of the tests.
            let pairwise = self.smooth_iterates_pairwise(ctx, mcp, it);
            assert_eq!(
                pairwise.map(|i| i.depth()),
                smooth.map(|i| i.depth()),
                "step {}",
                ctx.step
            );
            tests::MODE_CHECKS.with(|n| {
                let mut seen = n.get();
                seen[smooth.map_or(0, |i| i.depth() - 1)] += 1;
                n.set(seen);
            });
        }
        self.start_known = false;
        let Some(it) = smooth else {
            self.extrapolated = false;
            self.order = 0;
            self.warm_start_from(ctx, mcp, z, None);
            return;
        };
        let past = self.extrapolation_order(mcp, Past::new(&it));
        // The guard: the extrapolated start only when its Fischer–Burmeister residual is below
        // that of the plain warm start (`F` at both: the plain start's momentum rows first, from
        // the last iterate without building it, then its Newton–Euler rows, and the rest only
        // when those do not decide): near an event the extrapolation
        // can land far from the solution (the stress suite's 023_room_corner, Newton: 670
        // iterations without the guard, 133 with it, 131 with the plain start). `F` at the start
        // chosen is kept for the backend (`warm_start_value`).
        // An extrapolated start that solves the step to round-off (A1's constant deceleration)
        // is taken without the plain one (its warm start, `F` and residual, ≈ 6 k instructions
        // on A1): the plain start, a step's change of `ν` away (`moving`), is not below it.
        let mut start = std::mem::take(&mut self.start);
        let mut start_f = std::mem::take(&mut self.start_f);
        let mut f = std::mem::take(&mut self.f);
        let mut start_phi = std::mem::take(&mut self.start_phi);
        let mut phi = std::mem::take(&mut self.phi);
        f.resize(z.len(), 0.0);
        start_f.resize(z.len(), 0.0);
        phi.resize(z.len(), 0.0);
        start_phi.resize(z.len(), 0.0);
        self.warm_start_from(ctx, mcp, z, Some((it.last, past)));
        mcp.evaluate(z, &mut f);
        // `Φ` kept beside the residual: the backend's merit at the start chosen is its sum.
        let merit = fb_residual_into(z, &f, mcp.lower(), mcp.upper(), &mut phi);
        // `max(1, ‖z‖∞)`, a NaN passed over as `f64::max` does (by a comparison, which the
        // compiler makes one `max` instruction).
        let size = |z: &[f64]| {
            z.iter()
                .fold(1.0, |m: f64, v| if v.abs() > m { v.abs() } else { m })
        };
        // Then the plain start's momentum rows at the last iterate, without the plain start
        // (`momentum_rows_decide`: on the desk they carry most of its residual): their lower
        // bound first, then the start at round-off, then the rows themselves. The choice of
        // `merit ≤ EXACT_START · size || rows` (the bound deciding implies the rows do, and
        // neither test has another effect), with `‖z‖∞` only where the bound does not decide.
        self.extrapolated =
            self.momentum_rows_decide(ctx, mcp, it.last, merit, (&mut start_f, false))
                || merit <= EXACT_START * size(z)
                || self.momentum_rows_decide(ctx, mcp, it.last, merit, (&mut start_f, true));
        if !self.extrapolated {
            start.clear();
            start.extend_from_slice(it.last);
            self.warm_start_from(ctx, mcp, &mut start, None);
            // The plain start's Newton–Euler rows first: their residual is at most the whole
            // one's (`fb_residual_of_rows`), so an extrapolated start below it is below the
            // plain one's too, the choice made without the plain start's other rows (its whole
            // `F` and residual, ≈ 4 k instructions on the desk, where those rows carry 0.2215 of
            // the plain start's 0.2215 against the extrapolated start's 6e-4).
            let bodies = &self.layout.bodies;
            for body in bodies {
                mcp.evaluate_rows_of(body.nu, &start, &mut start_f);
            }
            let rows = bodies.iter().map(|body| mcp.range(body.nu));
            let bound = fb_residual_of_rows(&start, &start_f, mcp.lower(), mcp.upper(), rows);
            self.extrapolated = merit < bound;
            if !self.extrapolated {
                mcp.evaluate(&start, &mut start_f);
                let plain_merit =
                    fb_residual_into(&start, &start_f, mcp.lower(), mcp.upper(), &mut start_phi);
                self.extrapolated = merit < plain_merit;
            }
        }
        self.order = if self.extrapolated { past.order() } else { 0 };
        if self.extrapolated {
            start.clear();
            start.extend_from_slice(z);
            std::mem::swap(&mut start_f, &mut f);
            std::mem::swap(&mut start_phi, &mut phi);
        } else {
            z.copy_from_slice(&start);
        }
        self.start = start;
        self.start_f = start_f;
        self.start_phi = start_phi;
        self.f = f;
        self.phi = phi;
        self.start_known = true;
    }

    fn warm_start_extrapolated(&self) -> bool {
        self.extrapolated
    }

    fn warm_start_order(&self) -> usize {
        self.order
    }

    fn warm_start_value(&self) -> Option<(&[f64], &[f64])> {
        self.start_known
            .then_some((self.start.as_slice(), self.start_f.as_slice()))
    }

    fn warm_start_fb_vector(&self) -> Option<&[f64]> {
        self.start_known.then_some(self.start_phi.as_slice())
    }

    /// One retry from the active-contact guess of every contact that is closed or closing (a
    /// warm start from a separated step is a poor start for a landing step,
    /// `docs/decisions.md#retry-from-the-active-contact-guess`). After an extrapolated warm start, the
    /// warm start without extrapolation comes first.
    fn retry_start(
        &mut self,
        attempt: usize,
        ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
    ) -> bool {
        // After an extrapolated warm start, first the warm start of a step that is not smooth.
        let attempt = match (self.extrapolated, ctx.history) {
            (true, Some(it)) if attempt == 0 => {
                z.copy_from_slice(it.last);
                self.warm_start_from(ctx, mcp, z, None);
                return true;
            }
            (true, _) => attempt.saturating_sub(1),
            (false, _) => attempt,
        };
        if attempt > 0 {
            return false;
        }
        let l = &self.layout;
        let guess = self.guess(ctx, mcp);
        for i in 0..l.contacts.len() {
            let c = l.contacts[i];
            let s = ctx.states[c.body];
            let plane = &ctx.scene.planes[c.plane];
            let r = self.rotations.of(c.body, &s.q);
            let gap = min_gap(l.contact_hulls[i].vertices(), &s.x, &r, plane);
            let n = plane.normal();
            if is_closing(gap, &s, &ctx.scene.gravity, &n, ctx.h, 1e-9) {
                guess.contact(i, true, z);
            }
        }
        true
    }

    /// The end-of-span states: `x`, `Q` renormalised (also in `z`, for the warm start), `v`, ω.
    fn read_out(
        &mut self,
        _ctx: &StepContext<'_>,
        mcp: &BlockMcp,
        z: &mut [f64],
        states: &mut [BodyState],
    ) -> Result<(), SceneError> {
        let l = &self.layout;
        store_states(
            mcp,
            z,
            l.bodies.iter().map(|b| (b.nu, b.q)),
            states,
            &l.origin,
        );
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
        let o = self.layout.origin;
        let get = |v| &z[mcp.range(v)];
        let mut touching = self.touching.0.take();
        for c in &self.layout.contacts {
            // `scene_gaps_and_modes`' entry of the contact's body and plane, without its table.
            let (s, plane) = (&states[c.body], &scene.planes[c.plane]);
            let vertices = scene.bodies[c.body].shape.vertices();
            let r = self.rotations.of(c.body, &s.q);
            let spacing = &self.layout.bodies[c.body].spacing;
            let (gap, mode) = gap_and_mode_spaced(
                vertices,
                spacing,
                (&s.x, &r),
                plane,
                MODE_TOLERANCE,
                &mut touching,
            );
            let (a1, a2, pf) = (get(c.a1), get(c.a2), get(c.pf));
            out.push(ContactRecord {
                a1: Vector3::new(a1[0], a1[1], a1[2]) + o,
                a2: Vector3::new(a2[0], a2[1], a2[2]) + o,
                lg: get(c.lg)[0],
                pn: get(c.pn)[0],
                pt: pf[0],
                po: pf[1],
                pr: pf[2],
                sigma: get(c.sigma)[0],
                min_gap: gap,
                mode,
            });
        }
        self.touching.0.set(touching);
    }

    fn origin(&self) -> Vector3<f64> {
        self.layout.origin
    }

    fn structure(&self) -> Option<&dyn StepStructure> {
        Some(&self.layout)
    }

    fn scales(&self) -> Option<&McpScales> {
        self.layout.scales.as_ref()
    }

    fn scales_usage(&self, n: usize) -> Option<(&McpScales, ecp_model::ScalesUsage)> {
        let scales = self.layout.scales.as_ref()?;
        match self.layout.scales_usage {
            Some((m, usage)) if m == n => Some((scales, usage)),
            _ => Some((scales, scales.usage(n))),
        }
    }
}

/// The largest change of a closed contact's normal impulse from one step to the next, relative
/// to the larger of the two, in a smooth step: more is an impact.
const IMPULSE_CHANGE: f64 = 0.2;

/// A face multiplier of the closest-point condition above this is active (the multipliers are
/// the weights of unit normals that sum to a unit vector).
const ACTIVE_FACE: f64 = 1e-9;

/// The normal impulse at or below which the warm start takes a contact of `body` as open: a
/// millionth of a millionth of the impulse of its weight over a span of length `h`.
fn open_impulse(scene: &Scene, body: usize, h: f64) -> f64 {
    let m = scene.bodies[body].mass.mass;
    1e-12 * m * (scene.gravity.norm() * h).max(f64::MIN_POSITIVE)
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector4;

    use super::*;
    use crate::blocks::FrictionParams;
    use crate::geometry::{MassProperties, Shape};
    use crate::rotation::{quat_normalize, rotation_matrix};
    use crate::scenarios;
    use crate::scene::{BodySpec, Load};
    use crate::step::Simulation;
    use ecp_model::Mcp;

    /// A 0.4 × 0.3 × 0.2 m box, 2 kg, tossed with spin, its lowest vertex 0.1 m above the
    /// ground (no other vertex as low: the closest feature of Conv(F) is a vertex).
    fn tossed_box() -> Scene {
        let axis = Vector3::new(0.3, -0.8, 0.5);
        let q = crate::rotation::quat_from_axis_angle(&axis, 0.9)
            .unwrap_or_else(|| panic!("non-zero axis"));
        let shape = Shape::cuboid(0.4, 0.3, 0.2).unwrap_or_else(|e| panic!("{e}"));
        let r = rotation_matrix(&q);
        let lowest = shape
            .vertices()
            .iter()
            .map(|v| (r * v).z)
            .fold(f64::INFINITY, f64::min);
        Scene {
            name: "toss".into(),
            bodies: vec![BodySpec {
                name: "box".into(),
                mass: MassProperties::solid_cuboid(2.0, 0.4, 0.3, 0.2)
                    .unwrap_or_else(|e| panic!("{e}")),
                shape,
                initial: BodyState {
                    x: Vector3::new(0.0, 0.0, 0.1 - lowest),
                    q,
                    v: Vector3::new(0.5, -0.3, 1.0),
                    w: Vector3::new(6.0, -4.0, 8.0),
                },
                load: Load::None,
            }],
            planes: vec![HalfSpace::ground()],
            friction: FrictionParams {
                mu: 0.5,
                e_t: 1.0,
                e_o: 1.0,
                e_r: 0.02,
            },
            gravity: Vector3::new(0.0, 0.0, -9.8),
            h: 0.007,
            duration: 0.1,
            world: Default::default(),
        }
    }

    thread_local! {
        /// The guarded steps whose momentum rows' lower bound (`momentum_rows_bound`) decided.
        pub(super) static BOUND_CHECKS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
        /// The decisions of `EcpContacts::smooth_iterates` checked against the pairwise test in
        /// this thread: `[None, depth 2, …, depth 6]`.
        pub(super) static MODE_CHECKS: std::cell::Cell<[usize; 6]> =
            const { std::cell::Cell::new([0; 6]) };
    }

    /// The mode test kept from step to step (`EcpContacts::smooth_iterates`) decides as testing
    /// every older iterate against the newest in full (`smooth_iterates_pairwise`, asserted on
    /// every warm start with history): over runs with landings, tipping, sliding to rest and
    /// sticking (A1, A4 at 25°, A5 tilted, A6 at 110 N, the desk, the T-bar, a tossed box), with
    /// Newton and PATH, a warm start asked for twice, and the warm start switched from
    /// `Quadratic` (three iterates) to `Extrapolated` (six) and back within a run. Every outcome
    /// (no smooth step, and 2 to 6 iterates) is met.
    #[test]
    fn the_kept_mode_run_decides_as_the_pairwise_test() {
        use crate::step::WarmStart;
        use ecp_solvers::newton::NewtonSolver;
        use ecp_solvers::path::PathSolver;
        MODE_CHECKS.with(|n| n.set([0; 6]));
        let scenes = [
            (scenarios::a1_sliding(), 60),
            (scenarios::a4_incline(25.0), 100),
            (scenarios::a5_drop_tilted(), 120),
            (scenarios::a6_tip(110.0), 150),
            (scenarios::desk(), 150),
            (scenarios::t_bar(), 300),
            (tossed_box(), 14),
        ];
        for (scene, steps) in scenes {
            for path in [false, true] {
                let name = scene.name.clone();
                let mut sim = Simulation::new(scene.clone()).unwrap_or_else(|e| panic!("{e}"));
                let mut newton = NewtonSolver::new(Default::default());
                let mut pathsolver = PathSolver::new(Default::default());
                for step in 1..=steps {
                    // A warm start asked for twice (the second from the kept run of the same
                    // iterates), and the iterates cut to three for a while.
                    if step % 7 == 0 {
                        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
                    }
                    if step % 40 == 20 {
                        sim.set_warm_start(WarmStart::Quadratic);
                    } else if step % 40 == 30 {
                        sim.set_warm_start(WarmStart::Extrapolated);
                    }
                    let solver: &mut dyn ecp_model::McpSolver =
                        if path { &mut pathsolver } else { &mut newton };
                    let rec = sim.step(solver).unwrap_or_else(|e| panic!("{e}"));
                    assert!(rec.converged, "{name} step {step}");
                }
            }
        }
        let seen = MODE_CHECKS.with(|n| n.get());
        assert!(seen.iter().all(|&n| n > 0), "{seen:?}");
        // The momentum rows' lower bound decided guarded steps (and was checked on each).
        assert!(BOUND_CHECKS.with(|n| n.get()) > 0);
    }

    fn ecp(sim: &Simulation) -> &EcpContacts {
        sim.formulation_as::<EcpContacts>()
            .unwrap_or_else(|| panic!("an ECP formulation"))
    }

    /// The warm start of an open contact: the closest-point conditions C1–C4 hold at the
    /// predicted pose (C2 with the multipliers of the three faces through the lowest vertex),
    /// the friction rows vanish, and σ > 0.
    #[test]
    fn open_contact_warm_start_meets_the_closest_point_conditions() {
        let mut sim = Simulation::new(tossed_box()).unwrap_or_else(|e| panic!("{e}"));
        sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
        let z = sim.z().to_vec();
        let mcp = sim.mcp();
        let mut f = vec![0.0; mcp.dim()];
        mcp.evaluate(&z, &mut f);
        let c = ecp(&sim).contacts()[0];
        let l = &z[mcp.range(c.l)];
        assert_eq!(l.iter().filter(|v| **v > 0.0).count(), 3, "l = {l:?}");
        // C2 rows are paired with a2, C1 rows with a1; C3 and C4 rows with l and l_g.
        for (what, var) in [("C1", c.a1), ("C2", c.a2), ("friction", c.pf)] {
            for i in mcp.range(var) {
                assert!(
                    f[i].abs() <= 1e-12,
                    "{what}: {} = {:e}",
                    mcp.component_name(i),
                    f[i]
                );
            }
        }
        for i in mcp.range(c.l).chain(mcp.range(c.lg)) {
            // Complementarity: multiplier 0 or row 0, both non-negative.
            assert!(z[i] >= 0.0 && f[i] >= -1e-12 && (z[i] * f[i]).abs() <= 1e-12);
        }
        assert!(z[mcp.range(c.sigma)][0] > 0.0);
        // The closest point is the lowest vertex at the predicted pose.
        let qv = sim.handles().bodies[0]
            .q
            .unwrap_or_else(|| panic!("q block"));
        let q = &z[mcp.range(qv)];
        let x = Vector3::new(q[0], q[1], q[2]);
        let rq = quat_normalize(&Vector4::new(q[3], q[4], q[5], q[6]))
            .map(|q| rotation_matrix(&q))
            .unwrap_or_else(|| panic!("non-zero quaternion"));
        let lowest = ecp(&sim)
            .hull_of(0)
            .vertices()
            .iter()
            .map(|v| (x + rq * v).z)
            .fold(f64::INFINITY, f64::min);
        let a1 = &z[mcp.range(c.a1)];
        assert!(
            (a1[2] - lowest).abs() <= 1e-12,
            "a1 {a1:?}, lowest {lowest}"
        );
    }

    /// A resting box's first warm start carries its weight and stops the approach over the step
    /// (`docs/model.md#stepper`): `p_n = m g h + m g h` at the face centre; the union desk has
    /// one contact per leg.
    #[test]
    fn first_guess_of_a_resting_box_and_the_union_desk() {
        let sim = Simulation::new(scenarios::a2_push(0.0)).unwrap_or_else(|e| panic!("{e}"));
        let c = ecp(&sim).contacts()[0];
        let z = sim.z();
        let pn = z[sim.mcp().range(c.pn)][0];
        assert!((pn - 2.0 * 10.0 * 9.8 * 0.01).abs() <= 1e-12, "p_n {pn}");
        let a1 = &z[sim.mcp().range(c.a1)];
        assert!(a1.iter().all(|v| v.abs() <= 1e-12), "a1 {a1:?}");
        let union = Simulation::with_formulation(scenarios::desk(), "union")
            .unwrap_or_else(|e| panic!("{e}"));
        let pieces: Vec<Option<usize>> = ecp(&union).contacts().iter().map(|c| c.piece).collect();
        assert_eq!(pieces, [Some(1), Some(2), Some(3), Some(4)]);
        assert_eq!(union.contacts_per_body(), 4);
        assert!(union.capabilities().non_isolated_solutions);
    }

    /// The guard's momentum rows (`EcpContacts::momentum_rows_decide`): at the last step's
    /// iterate, each body's first three `ν` rows have the bits of the plain warm start's (they
    /// read neither `q` nor `a1`, and the plain start keeps `ν` and the closed contacts'
    /// impulses), their residual is at most the plain start's whole one, and they change with
    /// `v` and `p_n` (what they do read). Desk, A1 and T-bar, every step with its contacts closed.
    #[test]
    fn momentum_rows_at_the_last_iterate_are_those_of_the_plain_start() {
        use crate::step::WarmStart;
        use ecp_model::{fb_residual, fb_residual_of_rows};
        for (scene, steps) in [
            (scenarios::desk(), 40),
            (scenarios::a1_sliding(), 30),
            (scenarios::t_bar(), 100),
        ] {
            let name = scene.name.clone();
            let mut sim = Simulation::new(scene).unwrap_or_else(|e| panic!("{e}"));
            let mut solver = ecp_solvers::newton::NewtonSolver::new(Default::default());
            let mut checked = 0;
            for step in 1..=steps {
                let rec = sim.step(&mut solver).unwrap_or_else(|e| panic!("{e}"));
                assert!(rec.converged, "{name} step {step}");
                let last = sim.z().to_vec();
                sim.set_warm_start(WarmStart::Previous);
                sim.prepare_step().unwrap_or_else(|e| panic!("{e}"));
                sim.set_warm_start(WarmStart::Extrapolated);
                let plain = sim.z().to_vec();
                let (mcp, scene) = (sim.mcp(), sim.scene());
                let contacts = ecp(&sim).contacts();
                let closed = contacts
                    .iter()
                    .all(|c| last[mcp.range(c.pn)][0] > open_impulse(scene, c.body, scene.h));
                if !closed {
                    continue;
                }
                let n = mcp.dim();
                let (mut at_last, mut at_plain) = (vec![0.0; n], vec![0.0; n]);
                let nus: Vec<_> = sim.handles().bodies.iter().filter_map(|b| b.nu).collect();
                for &nu in &nus {
                    mcp.evaluate_rows_of(nu, &last, &mut at_last);
                    mcp.evaluate_rows_of(nu, &plain, &mut at_plain);
                    for i in mcp.range(nu).take(3) {
                        assert_eq!(at_last[i].to_bits(), at_plain[i].to_bits(), "{name} {step}");
                    }
                }
                let rows = || {
                    nus.iter().map(|&nu| {
                        let r = mcp.range(nu);
                        r.start..r.start + 3
                    })
                };
                let bound = fb_residual_of_rows(&last, &at_last, mcp.lower(), mcp.upper(), rows());
                let mut f = vec![0.0; n];
                mcp.evaluate(&plain, &mut f);
                let whole = fb_residual(&plain, &f, mcp.lower(), mcp.upper());
                assert!(
                    bound <= whole && bound > 0.0,
                    "{name} {step}: {bound} {whole}"
                );
                // What the rows read: `v` and `p_n` move them.
                let (nu, pn) = (nus[0], contacts[0].pn);
                for (v, k) in [(nu, 0), (pn, 0)] {
                    let mut moved = last.clone();
                    moved[mcp.range(v).start + k] += 1e-3;
                    let mut f = vec![0.0; n];
                    mcp.evaluate_rows_of(nu, &moved, &mut f);
                    let again = fb_residual_of_rows(&moved, &f, mcp.lower(), mcp.upper(), rows());
                    assert_ne!(again.to_bits(), bound.to_bits(), "{name} {step}");
                }
                checked += 1;
            }
            assert!(checked >= steps / 2, "{name}: {checked} of {steps}");
        }
    }

    /// A scene a million metres from the world origin is stepped in coordinates relative to an
    /// origin moved to the bodies (`docs/model.md#far-scenes`): the same motion as near the
    /// origin, and the records in world coordinates.
    #[test]
    fn a_far_scene_moves_the_origin_and_keeps_its_motion() {
        let near = scenarios::a1_sliding();
        let mut far = near.clone();
        let shift = Vector3::new(1e6, -2e6, 0.0);
        far.bodies[0].initial.x += shift;
        let mut a = Simulation::new(near).unwrap_or_else(|e| panic!("{e}"));
        let mut b = Simulation::new(far).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(b.origin(), b.state(0).x);
        let mut solver = ecp_solvers::newton::NewtonSolver::new(Default::default());
        for _ in 0..5 {
            let (ra, rb) = (
                a.step(&mut solver).unwrap_or_else(|e| panic!("{e}")),
                b.step(&mut solver).unwrap_or_else(|e| panic!("{e}")),
            );
            assert!(rb.converged);
            assert!((ra.bodies[0].v - rb.bodies[0].v).amax() <= 1e-9);
            assert!((ra.bodies[0].x + shift - rb.bodies[0].x).amax() <= 1e-8);
            assert!((ra.contacts[0].a1 + shift - rb.contacts[0].a1).amax() <= 1e-8);
        }
    }
}
