//! The structural view of an ECP step problem (`docs/backends.md#conic`): the
//! [`ecp_model::StepStructure`] of the span prepared last, for backends that exploit the
//! structure of the contact step (the conic backend of ecp-solvers) without depending on this
//! crate. The driver hands it to every backend with the step's MCP, so generic backends see the
//! same problem as without it.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SVector, Vector3, Vector4, Vector6};

use ecp_model::{
    BlockMcp, BodyDynamics, ConicPoint, ContactFriction, ContactGeometry, ContactPartner,
    McpScales, PatchVertex, StepStructure,
};

use super::layout::Layout;
use crate::blocks::{BodyStepData, FrictionParams};
use crate::rotation::{kinematic_map, rotation_matrix};
use crate::scene::BodyState;

/// A face of Conv(F) counts as active at the ECP when `f_i(a1) ≥ −FACE_ACTIVE` (m): the ECP is a
/// convex combination of hull vertices, which lie on their faces to round-off.
const FACE_ACTIVE: f64 = 1e-9;
/// Vertices whose gap is within this (m) of the smallest one form the closest feature of a
/// separated hull (a face, an edge or a vertex, `docs/model.md#degenerate-cases`).
const SUPPORT_TIE: f64 = 1e-12;

impl Layout {
    /// Caches the data of the span just prepared in `mcp` (the structural view reads them; they
    /// do not change during the span's solves), with `start` the states at the span's start.
    pub(crate) fn record_span(&mut self, mcp: &BlockMcp, start: &[BodyState]) {
        self.record_ranges(mcp);
        let Some(scene) = self.scene_data else {
            return;
        };
        let h = mcp.data(scene.h)[0];
        let gravity = Vector3::from_column_slice(mcp.data(scene.gravity));
        self.span.bodies.clear();
        self.span.start_x.clear();
        for body in &self.bodies {
            let (data, start_x) = BodyStepData::from_mcp(mcp, &body.data, gravity, h);
            self.span.bodies.push(data);
            self.span.start_x.push(start_x);
        }
        self.span.start.clear();
        self.span.start.extend_from_slice(start);
        self.span.friction.copy_from_slice(mcp.data(scene.friction));
        self.span.h = h;
        // Into the storage of the last span's scales.
        let mut scales = self.scales.take().unwrap_or_else(|| McpScales {
            variables: Vec::new(),
            rows: Vec::new(),
        });
        let mut units = std::mem::take(&mut self.span.units);
        let refilled = self.scene_scales_into(mcp, &mut scales, &mut units);
        self.span.units = units;
        let n = ecp_model::Mcp::dim(mcp);
        if refilled || self.scales_usage.is_none_or(|(m, _)| m != n) {
            self.scales_usage = Some((n, scales.usage(n)));
        }
        self.scales = Some(scales);
    }

    fn quat_or_start(&self, b: usize, q: Vector4<f64>) -> Vector4<f64> {
        // The homogeneous R(Q) is a rotation for every Q ≠ 0 (`docs/model.md#conventions`); a zero
        // or non-finite quaternion can only come from a broken iterate: fall back on Q^u.
        if q.norm_squared() > 1e-300 && q.iter().all(|v| v.is_finite()) {
            q
        } else {
            self.span.start[b].q
        }
    }

    /// Position `x` and rotation `R(Q)` of body `b` stored in `z`.
    fn pose(&self, b: usize, z: &[f64]) -> (Vector3<f64>, Matrix3<f64>) {
        let q = &z[self.range(self.bodies[b].q)];
        let quat = self.quat_or_start(b, Vector4::new(q[3], q[4], q[5], q[6]));
        (Vector3::new(q[0], q[1], q[2]), rotation_matrix(&quat))
    }

    /// The body data of body `b` as the step's Newton–Euler block reads them (its data blocks,
    /// `docs/model.md#data-blocks`).
    fn body_data(&self, b: usize) -> BodyStepData {
        self.span.bodies[b]
    }

    /// The free-motion velocity of body `b` ([`BodyStepData::free_velocity`]).
    fn free_velocity(&self, b: usize, r1: &Matrix3<f64>, w_trial: &Vector3<f64>) -> Vector6<f64> {
        self.body_data(b).free_velocity(r1, w_trial)
    }

    /// Start position (step coordinates) and orientation of body `b`, from its `start` data.
    fn start_pose(&self, b: usize) -> (Vector3<f64>, Vector4<f64>) {
        (self.span.start_x[b], self.span.bodies[b].q_start)
    }

    /// The trial end-of-step rotation and angular velocity of body `b` stored in `z`.
    fn trial(&self, b: usize, z: &[f64]) -> (Matrix3<f64>, Vector3<f64>) {
        let (_, r1) = self.pose(b, z);
        let nu = &z[self.range(self.bodies[b].nu)];
        let w = Vector3::new(nu[3], nu[4], nu[5]);
        let w = if w.iter().all(|v| v.is_finite()) {
            w
        } else {
            self.span.start[b].w
        };
        (r1, w)
    }
}

fn arr(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// One inner step of the active-set NNLS ([`nnls`], [`nnls_fixed`]): `s` solves the least
/// squares on the passive columns `idx`. All positive: `x` takes it and the step is done (`true`).
/// Otherwise `x` moves towards `s` until a passive variable reaches zero, which is dropped.
fn take_passive_solution(x: &mut [f64], passive: &mut [bool], idx: &[usize], s: &[f64]) -> bool {
    if s.iter().all(|v| *v > 0.0) {
        for (k, &j) in idx.iter().enumerate() {
            x[j] = s[k];
        }
        return true;
    }
    let mut alpha = 1.0f64;
    for (k, &j) in idx.iter().enumerate() {
        if s[k] <= 0.0 {
            let d = x[j] - s[k];
            if d > 0.0 {
                alpha = alpha.min(x[j] / d);
            }
        }
    }
    for (k, &j) in idx.iter().enumerate() {
        x[j] += alpha * (s[k] - x[j]);
        if x[j] <= 1e-15 {
            x[j] = 0.0;
            passive[j] = false;
        }
    }
    false
}

/// Non-negative least squares `min ‖A l − b‖, l ≥ 0` (Lawson–Hanson active set), for the face
/// multipliers of C2 (3 rows, a handful of columns).
fn nnls(a: &DMatrix<f64>, b: &DVector<f64>) -> DVector<f64> {
    let n = a.ncols();
    let mut x = DVector::zeros(n);
    let mut passive = vec![false; n];
    let tol = 1e-14 * (1.0 + b.norm());
    for _outer in 0..3 * n + 3 {
        let w = a.transpose() * (b - a * &x);
        let candidate = (0..n)
            .filter(|&j| !passive[j] && w[j] > tol)
            .max_by(|&i, &j| w[i].total_cmp(&w[j]));
        let Some(j) = candidate else { break };
        passive[j] = true;
        for _inner in 0..3 * n + 3 {
            let idx: Vec<usize> = (0..n).filter(|&j| passive[j]).collect();
            let sub = DMatrix::from_fn(a.nrows(), idx.len(), |r, c| a[(r, idx[c])]);
            let Ok(s) = sub.clone().svd(true, true).solve(b, 1e-13) else {
                return x;
            };
            if take_passive_solution(x.as_mut_slice(), &mut passive, &idx, s.as_slice()) {
                break;
            }
        }
    }
    x
}

/// [`nnls`] with `N` columns known at compile time: the same operations in the same order on
/// matrices kept on the stack (the subproblem's SVD with one or two columns too; three, a corner,
/// on the heap), so the same answer bit for bit without a heap allocation on a face or an edge
/// (`face_multipliers_into`; the conic backend assembles a point three times per desk step).
fn nnls_fixed<const N: usize>(a: &SMatrix<f64, 3, N>, b: &Vector3<f64>) -> SVector<f64, N> {
    let n = N;
    let mut x = SVector::<f64, N>::zeros();
    let mut passive = [false; N];
    let tol = 1e-14 * (1.0 + b.norm());
    for _outer in 0..3 * n + 3 {
        let w = a.transpose() * (b - a * x);
        let candidate = (0..n)
            .filter(|&j| !passive[j] && w[j] > tol)
            .max_by(|&i, &j| w[i].total_cmp(&w[j]));
        let Some(j) = candidate else { break };
        passive[j] = true;
        for _inner in 0..3 * n + 3 {
            let mut idx = [0usize; N];
            let mut m = 0;
            for (j, _) in passive.iter().enumerate().filter(|(_, p)| **p) {
                idx[m] = j;
                m += 1;
            }
            let idx = &idx[..m];
            // The least-squares solution on the passive columns by SVD, their count `M` a
            // constant where it can be (nalgebra's SVD needs a concrete size), in `s[..M]`.
            let mut s = [0.0; N];
            macro_rules! svd_solve {
                ($m:literal) => {{
                    let sub = SMatrix::<f64, 3, $m>::from_fn(|r, c| a[(r, idx[c])]);
                    match sub.svd(true, true).solve(b, 1e-13) {
                        Ok(v) => {
                            s[..$m].copy_from_slice(v.as_slice());
                            true
                        }
                        Err(_) => false,
                    }
                }};
            }
            let solved = match m {
                1 => svd_solve!(1),
                2 => svd_solve!(2),
                _ => {
                    // Three columns (a corner) on the heap: nalgebra computes a 3 × 3 matrix of
                    // static size by another method (`svd3`), whose answers differ in the last bits.
                    let sub = DMatrix::from_fn(3, m, |r, c| a[(r, idx[c])]);
                    match sub.svd(true, true).solve(b, 1e-13) {
                        Ok(v) => {
                            s[..m].copy_from_slice(v.as_slice());
                            true
                        }
                        Err(_) => false,
                    }
                }
            };
            if !solved {
                return x;
            }
            let s = &s[..m];
            if take_passive_solution(x.as_mut_slice(), &mut passive, idx, s) {
                break;
            }
        }
    }
    x
}

/// The face multipliers of C2 into `l` (one per face of `faces`, zero where inactive):
/// `−n_G` in the cone of the outward normals `r n_i` of the faces active at the local point
/// `local` ([`nnls`]). Up to three active faces by [`nnls_fixed`] (a box's corner has three),
/// more by [`nnls`]; the same numbers either way.
fn face_multipliers_into(
    faces: &[crate::geometry::Face],
    r: &Matrix3<f64>,
    local: &Vector3<f64>,
    ng: &Vector3<f64>,
    l: &mut [f64],
) {
    l.fill(0.0);
    let mut active = [0usize; 3];
    let mut count = 0;
    for (i, face) in faces.iter().enumerate() {
        if face.value(local) >= -FACE_ACTIVE {
            if count < 3 {
                active[count] = i;
            }
            count += 1;
        }
    }
    let rhs = -ng;
    let column = |i: usize| r * faces[i].normal;
    match count {
        0 => {}
        1 => {
            let sol = nnls_fixed(
                &SMatrix::<f64, 3, 1>::from_columns(&[column(active[0])]),
                &rhs,
            );
            l[active[0]] = sol[0];
        }
        2 => {
            let a = SMatrix::<f64, 3, 2>::from_columns(&[column(active[0]), column(active[1])]);
            let sol = nnls_fixed(&a, &rhs);
            for (k, &i) in active[..2].iter().enumerate() {
                l[i] = sol[k];
            }
        }
        3 => {
            let a = SMatrix::<f64, 3, 3>::from_columns(&[
                column(active[0]),
                column(active[1]),
                column(active[2]),
            ]);
            let sol = nnls_fixed(&a, &rhs);
            for (k, &i) in active.iter().enumerate() {
                l[i] = sol[k];
            }
        }
        _ => {
            let active: Vec<usize> = (0..faces.len())
                .filter(|&i| faces[i].value(local) >= -FACE_ACTIVE)
                .collect();
            let a = DMatrix::from_fn(3, active.len(), |row, col| column(active[col])[row]);
            let rhs = DVector::from_column_slice((-ng).as_slice());
            let sol = nnls(&a, &rhs);
            for (k, &i) in active.iter().enumerate() {
                l[i] = sol[k];
            }
        }
    }
}

impl Layout {
    /// [`StepStructure::contact`] with `patch` as the patch's storage (cleared first).
    fn contact_with_patch(
        &self,
        c: usize,
        z: &[f64],
        band: f64,
        mut patch: Vec<PatchVertex>,
    ) -> ContactGeometry {
        let cv = &self.contacts[c];
        let body = &self.bodies[cv.body];
        let plane = &self.step_planes[cv.plane];
        let (n, t, o) = plane.contact_frame();
        let (x, r) = self.pose(cv.body, z);
        let h = self.step_length();
        let nu = &z[self.range(body.nu)];
        let trial = Vector6::from_column_slice(nu);
        let (r1, w_trial) = self.trial(cv.body, z);
        let free = self.free_velocity(cv.body, &r1, &w_trial);
        let mut gap = f64::INFINITY;
        patch.clear();
        for (j, vb) in self.contact_hulls[c].vertices().iter().enumerate() {
            let p = x + r * vb;
            let g = plane.value(&p);
            gap = gap.min(g);
            let arm = p - x;
            // Normal velocity of the vertex, n·(v + ω × arm), at both velocity guesses.
            let rate = |nu: &Vector6<f64>| {
                let v = nu.fixed_rows::<3>(0).into_owned();
                let w = nu.fixed_rows::<3>(3).into_owned();
                n.dot(&(v + w.cross(&arm)))
            };
            let approach = (-rate(&trial)).max(-rate(&free)).max(0.0);
            if g <= band + 2.0 * h * approach {
                patch.push(PatchVertex {
                    index: j,
                    position: arr(&p),
                    gap: g,
                    partner_position: arr(&(p - n * g)),
                });
            }
        }
        let a1 = &z[self.range(cv.a1)];
        let f = FrictionParams::from_slice(&self.span.friction);
        ContactGeometry {
            body: cv.body,
            normal: arr(&n),
            tangent: arr(&t),
            bitangent: arr(&o),
            center_of_mass: arr(&x),
            gap,
            patch,
            ecp: [a1[0], a1[1], a1[2]],
            friction: ContactFriction {
                mu: f.mu,
                e_t: f.e_t,
                e_o: f.e_o,
                e_r: f.e_r,
            },
            partner: ContactPartner::HalfSpace,
        }
    }
}

impl StepStructure for Layout {
    fn step_length(&self) -> f64 {
        // The span prepared last (a step or a substep), as the step's blocks read it.
        self.span.h
    }

    fn num_bodies(&self) -> usize {
        self.bodies.len()
    }

    fn body(&self, b: usize, z: &[f64]) -> BodyDynamics {
        let (r1, w_trial) = self.trial(b, z);
        self.body_data(b).dynamics(&r1, &w_trial)
    }

    fn num_contacts(&self) -> usize {
        self.contacts.len()
    }

    fn normal_impulse(&self, c: usize, z: &[f64]) -> Option<f64> {
        let cv = self.contacts.get(c)?;
        z.get(self.range(cv.pn)).and_then(|p| p.first()).copied()
    }

    fn velocities(&self, z: &[f64]) -> Vec<[f64; 6]> {
        let mut out = Vec::with_capacity(self.bodies.len());
        self.velocities_into(z, &mut out);
        out
    }

    fn velocities_into(&self, z: &[f64], out: &mut Vec<[f64; 6]>) {
        out.clear();
        out.extend(self.bodies.iter().map(|body| {
            let nu = &z[self.range(body.nu)];
            [nu[0], nu[1], nu[2], nu[3], nu[4], nu[5]]
        }));
    }

    fn contact(&self, c: usize, z: &[f64], band: f64) -> ContactGeometry {
        self.contact_with_patch(c, z, band, Vec::new())
    }

    fn contact_into(&self, c: usize, z: &[f64], band: f64, out: &mut ContactGeometry) {
        let patch = std::mem::take(&mut out.patch);
        *out = self.contact_with_patch(c, z, band, patch);
    }

    fn assemble(&self, point: &ConicPoint, z: &mut [f64]) {
        let h = self.step_length();
        for (b, body) in self.bodies.iter().enumerate() {
            let nu = point.velocities.get(b).copied().unwrap_or([0.0; 6]);
            z[self.range(body.nu)].copy_from_slice(&nu);
            // Kinematic map (`docs/model.md#kinematic-map`), exactly as the KinematicMap block.
            let (x0, q0) = self.start_pose(b);
            let v = Vector3::new(nu[0], nu[1], nu[2]);
            let w = Vector3::new(nu[3], nu[4], nu[5]);
            let x = x0 + v * h;
            let q = q0 + kinematic_map(&q0) * w * (0.5 * h);
            z[self.range(body.q)].copy_from_slice(&[x.x, x.y, x.z, q[0], q[1], q[2], q[3]]);
        }
        for (c, cv) in self.contacts.iter().enumerate() {
            let plane = &self.step_planes[cv.plane];
            let ng = plane.normal();
            let (x, r) = self.pose(cv.body, z);
            let set = &self.contact_hulls[c];
            // The hull's vertices at the end-of-step pose, computed where they are read (no list
            // of them: `assemble` runs a few times per conic step, `docs/latency.md`).
            let world = |vb: &Vector3<f64>| x + r * vb;
            let empty = ecp_model::ContactImpulses::default();
            let imp = point.contacts.get(c).unwrap_or(&empty);
            let pn: f64 = imp.vertex_impulses.iter().map(|(_, l)| l.max(0.0)).sum();
            let a1 = if pn > 0.0 {
                // Centre of pressure of the vertex impulses at the end-of-step configuration.
                let mut a = Vector3::zeros();
                for &(j, l) in &imp.vertex_impulses {
                    if let Some(vb) = set.vertices().get(j) {
                        a += world(vb) * (l.max(0.0) / pn);
                    }
                }
                a
            } else {
                // Separated: the closest feature of Conv(F) to G (a face, edge or vertex), at
                // its centroid.
                let gmin = set
                    .vertices()
                    .iter()
                    .map(|vb| plane.value(&world(vb)))
                    .fold(f64::INFINITY, f64::min);
                let mut a = Vector3::zeros();
                let mut k = 0.0;
                for vb in set.vertices() {
                    let p = world(vb);
                    if plane.value(&p) <= gmin + SUPPORT_TIE {
                        a += p;
                        k += 1.0;
                    }
                }
                a / f64::max(k, 1.0)
            };
            let lg = plane.value(&a1).max(0.0);
            let a2 = a1 - ng * lg;
            // Face multipliers (C2): −n_G in the cone of the outward normals of the faces
            // active at a1.
            let local = r.transpose() * (a1 - x);
            face_multipliers_into(set.faces(), &r, &local, &ng, &mut z[self.range(cv.l)]);
            z[self.range(cv.a1)].copy_from_slice(a1.as_slice());
            z[self.range(cv.a2)].copy_from_slice(a2.as_slice());
            z[self.range(cv.lg)][0] = lg;
            z[self.range(cv.pn)][0] = pn;
            z[self.range(cv.pf)].copy_from_slice(&imp.friction);
            z[self.range(cv.sigma)][0] = imp.sigma.max(0.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stack version of the face multipliers gives the heap version's numbers bit for bit:
    /// one, two and three columns (a face, an edge, a corner of a box, tilted), right-hand sides
    /// inside and outside the cone, and a degenerate pair of parallel columns.
    #[test]
    fn nnls_fixed_matches_nnls_bit_for_bit() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut checked = [0usize; 3];
        for case in 0..3000 {
            let k = case % 3 + 1;
            let mut cols: Vec<Vector3<f64>> = (0..k)
                .map(|_| Vector3::new(uniform(), uniform(), uniform()).normalize())
                .collect();
            if case % 7 == 0 && k >= 2 {
                cols[1] = cols[0];
            }
            let b = Vector3::new(uniform(), uniform(), uniform());
            let a = DMatrix::from_fn(3, k, |r, c| cols[c][r]);
            let heap = nnls(&a, &DVector::from_column_slice(b.as_slice()));
            let stack: Vec<f64> = match k {
                1 => nnls_fixed(&SMatrix::<f64, 3, 1>::from_columns(&cols), &b)
                    .as_slice()
                    .to_vec(),
                2 => nnls_fixed(&SMatrix::<f64, 3, 2>::from_columns(&cols), &b)
                    .as_slice()
                    .to_vec(),
                _ => nnls_fixed(&SMatrix::<f64, 3, 3>::from_columns(&cols), &b)
                    .as_slice()
                    .to_vec(),
            };
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(heap.as_slice()),
                bits(&stack),
                "case {case}: {cols:?}, {b}"
            );
            if heap.iter().any(|v| *v > 0.0) {
                checked[k - 1] += 1;
            }
        }
        // Every size had answers with active columns (not only the trivial zero).
        assert!(checked.iter().all(|&c| c > 300), "{checked:?}");
    }

    #[test]
    fn nnls_finds_the_cone_combination() {
        // −e_z from the normals of the bottom face and a tilted front face.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let a = DMatrix::from_row_slice(3, 3, &[0.0, s, 1.0, 0.0, 0.0, 0.0, -1.0, -s, 0.0]);
        let b = DVector::from_column_slice(&[0.0, 0.0, -1.0]);
        let x = nnls(&a, &b);
        assert!((&a * &x - &b).norm() < 1e-12, "{x}");
        assert!(x.iter().all(|v| *v >= 0.0));
        // Not in the cone: the best non-negative fit leaves a residual.
        let b = DVector::from_column_slice(&[0.0, 0.0, 1.0]);
        let x = nnls(&a, &b);
        assert!(x.iter().all(|v| *v >= 0.0));
        assert!((&a * &x - &b).norm() > 0.5);
    }
}
