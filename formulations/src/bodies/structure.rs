//! The structural view of a multi-body step (`docs/backends.md#conic`): the
//! [`ecp_model::StepStructure`] of the span prepared last, for the conic backend. Every contact
//! set is one contact between F (a dynamic body) and G (another dynamic body, a fixed or
//! kinematic body, or a half-space), `docs/model.md#contact-between-two-bodies`.
//!
//! At a trial point the normal is the pair's own, `ν_G/|ν_G|` from the `μ` of the trial vector,
//! with the frame of the friction rows (`PairFrame`, the contact's reference axis). The contact
//! patch is found along that normal: the vertices of F over G, the vertices of G under F, and
//! the points where an edge of F crosses an edge of G, each with its gap measured along the
//! normal between the two hulls' surfaces, kept when it may close within the step (the band of
//! [`StepStructure::contact`]). The map back puts the ECP at the centre of pressure of the
//! patch impulses, re-evaluated at the new poses, and the multipliers `μ`, `l` on the faces
//! active there; a contact without load gets the closest features of the two hulls.

use std::ops::Range;

use nalgebra::{Matrix3, Vector3, Vector4, Vector6};

use ecp_model::{
    BlockMcp, BodyDynamics, ConicPoint, ContactFriction, ContactGeometry, ContactImpulses,
    ContactPartner, PatchVertex, StepStructure,
};

use super::pairs::Partner;
use super::{MultiBody, touching_features};
use crate::blocks::{BodyStepData, FaceSet, FrictionParams, PairFrame};
use crate::geometry::{ConvexHull, HullPose, cone_combination};
use crate::rotation::{kinematic_map, rotation_matrix};

/// Points within this (m) of a hull's boundary count as on it (footprints of the patch search).
const ON_BOUNDARY: f64 = 1e-9;
/// A face whose normal makes `|m·n| ≤` this with the contact normal is parallel to it: the
/// patch search treats it as a side of the footprint, not a bound along the normal.
const PARALLEL: f64 = 1e-6;
/// Faces within this (m) of the most active one at the ECP count as active in the map back.
const ACTIVE: f64 = 1e-6;
/// Vertices whose gap is within this (m) of the smallest one form the closest feature of a
/// hull separated from a half-space (as the hull formulation's map back).
const SUPPORT_TIE: f64 = 1e-12;

/// The data of the span prepared last, as the structural view reads them.
#[derive(Clone, Debug, Default)]
pub(super) struct Span {
    h: f64,
    bodies: Vec<SpanBody>,
    /// End-of-span pose and velocity over the span of every fixed or kinematic body.
    obstacles: Vec<(Vector3<f64>, Vector4<f64>, [f64; 6])>,
    contacts: Vec<SpanContact>,
    /// Edges (vertex index pairs) of every dynamic body's hull, then of every obstacle's.
    body_edges: Vec<Vec<(usize, usize)>>,
    obstacle_edges: Vec<Vec<(usize, usize)>>,
}

#[derive(Clone, Debug)]
struct SpanBody {
    data: BodyStepData,
    start_x: Vector3<f64>,
    nu: Range<usize>,
    q: Range<usize>,
}

#[derive(Clone, Debug)]
struct SpanContact {
    friction: FrictionParams,
    axis: Vector3<f64>,
    a1: Range<usize>,
    a2: Range<usize>,
    l: Range<usize>,
    mu: Range<usize>,
    d: Range<usize>,
    pn: Range<usize>,
    pf: Range<usize>,
    sigma: Range<usize>,
}

/// The edges of a hull: consecutive corners of its faces, each once.
fn hull_edges(hull: &ConvexHull) -> Vec<(usize, usize)> {
    let mut edges: Vec<(usize, usize)> = Vec::new();
    for face in hull.faces() {
        let k = face.vertices.len();
        for i in 0..k {
            let (a, b) = (face.vertices[i], face.vertices[(i + 1) % k]);
            let e = (a.min(b), a.max(b));
            if a != b && !edges.contains(&e) {
                edges.push(e);
            }
        }
    }
    edges
}

/// One side of a contact placed in the world: vertices, faces `m·p ≤ e` and edges.
struct Placed<'a> {
    x: Vector3<f64>,
    rotation: Matrix3<f64>,
    vertices: Vec<Vector3<f64>>,
    normals: Vec<Vector3<f64>>,
    offsets: Vec<f64>,
    edges: &'a [(usize, usize)],
    hull: Option<&'a ConvexHull>,
}

impl<'a> Placed<'a> {
    fn new(
        faces: &FaceSet,
        hull: Option<&'a ConvexHull>,
        edges: &'a [(usize, usize)],
        x: Vector3<f64>,
        rotation: Matrix3<f64>,
    ) -> Self {
        let normals: Vec<Vector3<f64>> = faces.normals.iter().map(|m| rotation * m).collect();
        let offsets = normals
            .iter()
            .zip(&faces.offsets)
            .map(|(m, e)| e + m.dot(&x))
            .collect();
        Placed {
            x,
            rotation,
            vertices: hull
                .map(|h| h.vertices().iter().map(|v| x + rotation * v).collect())
                .unwrap_or_default(),
            normals,
            offsets,
            edges,
            hull,
        }
    }

    fn value(&self, i: usize, p: &Vector3<f64>) -> f64 {
        self.normals[i].dot(p) - self.offsets[i]
    }

    /// The interval of `s` where `p + s n` lies in the hull, `None` when the line misses it.
    fn line_interval(&self, p: &Vector3<f64>, n: &Vector3<f64>) -> Option<(f64, f64)> {
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for i in 0..self.normals.len() {
            let a = self.normals[i].dot(n);
            let v = self.value(i, p);
            if a.abs() <= PARALLEL {
                if v > ON_BOUNDARY {
                    return None;
                }
                continue;
            }
            let s = -v / a;
            if a > 0.0 {
                hi = hi.min(s);
            } else {
                lo = lo.max(s);
            }
        }
        (lo <= hi + ON_BOUNDARY).then_some((lo, hi))
    }
}

/// Closest points of the lines through `a + s da` and `c + u dc`: their midpoint, and the
/// parameters `(s, u)`; `None` for parallel lines.
fn line_crossing(
    a: &Vector3<f64>,
    da: &Vector3<f64>,
    c: &Vector3<f64>,
    dc: &Vector3<f64>,
    n: &Vector3<f64>,
) -> Option<(f64, f64)> {
    // Seen along n: the components in the plane ⊥ n.
    let flat = |v: &Vector3<f64>| v - n * n.dot(v);
    let (pa, pda, pc, pdc) = (flat(a), flat(da), flat(c), flat(dc));
    let cross = pda.cross(&pdc);
    let den = cross.norm_squared();
    if den <= 1e-20 * pda.norm_squared() * pdc.norm_squared() || den == 0.0 {
        return None;
    }
    let w = pc - pa;
    let s = w.cross(&pdc).dot(&cross) / den;
    let u = w.cross(&pda).dot(&cross) / den;
    Some((s, u))
}

fn arr(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn v3(s: &[f64]) -> Vector3<f64> {
    Vector3::new(s[0], s[1], s[2])
}

impl MultiBody {
    /// Caches the data of the span just prepared in `mcp` (the structural view reads them; they
    /// do not change during the span's solves).
    pub(super) fn record_span(&mut self, mcp: &BlockMcp) {
        let Some(scene) = self.scene_data else {
            return;
        };
        let h = mcp.data(scene.h)[0];
        let gravity = v3(mcp.data(scene.gravity));
        let span = &mut self.span;
        span.h = h;
        span.bodies = self
            .bodies
            .iter()
            .map(|b| {
                let (data, start_x) = BodyStepData::from_mcp(mcp, &b.data, gravity, h);
                SpanBody {
                    data,
                    start_x,
                    nu: mcp.range(b.nu),
                    q: mcp.range(b.q),
                }
            })
            .collect();
        span.obstacles = self
            .obstacles
            .iter()
            .map(|o| {
                let q = mcp.data(o.q);
                let nu = mcp.data(o.nu);
                (
                    v3(q),
                    Vector4::new(q[3], q[4], q[5], q[6]),
                    [nu[0], nu[1], nu[2], nu[3], nu[4], nu[5]],
                )
            })
            .collect();
        span.contacts = self
            .contacts
            .iter()
            .map(|c| SpanContact {
                friction: FrictionParams::from_slice(mcp.data(c.data.friction)),
                axis: v3(mcp.data(c.data.axis)),
                a1: mcp.range(c.vars.a1),
                a2: mcp.range(c.vars.a2),
                l: mcp.range(c.vars.l),
                mu: mcp.range(c.vars.mu),
                d: mcp.range(c.vars.d),
                pn: mcp.range(c.vars.pn),
                pf: mcp.range(c.vars.pf),
                sigma: mcp.range(c.vars.sigma),
            })
            .collect();
        if span.body_edges.len() != self.bodies.len() {
            span.body_edges = self.bodies.iter().map(|b| hull_edges(&b.hull)).collect();
        }
        if span.obstacle_edges.len() != self.obstacles.len() {
            span.obstacle_edges = (self.obstacles.iter())
                .map(|o| o.hull.as_ref().map(hull_edges).unwrap_or_default())
                .collect();
        }
    }

    /// The quaternion `Q` stored in `q` (or the start's, for a zero or broken one).
    fn quaternion(&self, b: usize, q: &[f64]) -> Vector4<f64> {
        let quat = Vector4::new(q[3], q[4], q[5], q[6]);
        if quat.norm_squared() > 1e-300 && quat.iter().all(|v| v.is_finite()) {
            quat
        } else {
            self.span.bodies[b].data.q_start
        }
    }

    /// Position and rotation of dynamic body `b` in `z`.
    fn body_pose(&self, b: usize, z: &[f64]) -> (Vector3<f64>, Matrix3<f64>) {
        let q = &z[self.span.bodies[b].q.clone()];
        (v3(q), rotation_matrix(&self.quaternion(b, q)))
    }

    /// The trial rotation and angular velocity of dynamic body `b` in `z`.
    fn body_trial(&self, b: usize, z: &[f64]) -> (Matrix3<f64>, Vector3<f64>) {
        let (_, r1) = self.body_pose(b, z);
        let nu = &z[self.span.bodies[b].nu.clone()];
        let w = Vector3::new(nu[3], nu[4], nu[5]);
        let w = if w.iter().all(|v| v.is_finite()) {
            w
        } else {
            self.span.bodies[b]
                .data
                .nu_start
                .fixed_rows::<3>(3)
                .into_owned()
        };
        (r1, w)
    }

    /// F of contact `c` placed at `z`.
    fn placed_f(&self, c: usize, z: &[f64]) -> Placed<'_> {
        let f = self.contacts[c].key.f;
        let (x, r) = self.body_pose(f, z);
        let b = &self.bodies[f];
        Placed::new(&b.faces, Some(&b.hull), &self.span.body_edges[f], x, r)
    }

    /// G of contact `c` placed at `z` (dynamic), at its span data (fixed, kinematic) or the
    /// identity pose (a half-space, one face and no vertex).
    fn placed_g(&self, c: usize, z: &[f64]) -> Placed<'_> {
        match self.contacts[c].key.g {
            Partner::Body(b) => {
                let (x, r) = self.body_pose(b, z);
                let body = &self.bodies[b];
                Placed::new(
                    &body.faces,
                    Some(&body.hull),
                    &self.span.body_edges[b],
                    x,
                    r,
                )
            }
            Partner::Obstacle(k) => {
                let (x, q, _) = self.span.obstacles[k];
                let o = &self.obstacles[k];
                Placed::new(
                    &o.faces,
                    o.hull.as_ref(),
                    &self.span.obstacle_edges[k],
                    x,
                    rotation_matrix(&q),
                )
            }
            Partner::Plane(p) => Placed::new(
                &self.planes[p].faces,
                None,
                &[],
                Vector3::zeros(),
                Matrix3::identity(),
            ),
        }
    }

    /// G's velocity at world point `p` given F's velocities `nu` per dynamic body.
    fn partner_velocity(
        &self,
        g: Partner,
        x_g: &Vector3<f64>,
        nu: &dyn Fn(usize) -> Vector6<f64>,
        p: &Vector3<f64>,
    ) -> Vector3<f64> {
        let v = match g {
            Partner::Body(b) => nu(b),
            Partner::Obstacle(k) => Vector6::from_column_slice(&self.span.obstacles[k].2),
            Partner::Plane(_) => Vector6::zeros(),
        };
        v.fixed_rows::<3>(0) + v.fixed_rows::<3>(3).cross(&(p - x_g))
    }

    /// The patch point `index` of contact `c` (see [`StepStructure::contact`]) with both sides
    /// placed at new poses.
    fn patch_point(index: usize, f: &Placed<'_>, g: &Placed<'_>) -> Option<Vector3<f64>> {
        let (nf, ng) = (f.vertices.len(), g.vertices.len());
        if index < nf {
            return Some(f.vertices[index]);
        }
        if index < nf + ng {
            return Some(g.vertices[index - nf]);
        }
        let e = index - nf - ng;
        let neg = g.edges.len().max(1);
        let (ef, eg) = (f.edges.get(e / neg)?, g.edges.get(e % neg)?);
        let (a, b) = (f.vertices[ef.0], f.vertices[ef.1]);
        let (c, d) = (g.vertices[eg.0], g.vertices[eg.1]);
        // Closest points of the two edge lines, in 3-D.
        let (da, dc) = (b - a, d - c);
        let n = da.cross(&dc);
        let len = n.norm();
        if !(len > 0.0 && len.is_finite()) {
            return Some((a + b + c + d) / 4.0);
        }
        let (s, u) = line_crossing(&a, &da, &c, &dc, &(n / len))?;
        Some((a + da * s + c + dc * u) * 0.5)
    }
}

impl StepStructure for MultiBody {
    fn step_length(&self) -> f64 {
        self.span.h
    }

    fn num_bodies(&self) -> usize {
        self.bodies.len()
    }

    fn body(&self, b: usize, z: &[f64]) -> BodyDynamics {
        let (r1, w) = self.body_trial(b, z);
        self.span.bodies[b].data.dynamics(&r1, &w)
    }

    fn num_contacts(&self) -> usize {
        self.contacts.len()
    }

    fn normal_impulse(&self, c: usize, z: &[f64]) -> Option<f64> {
        let sc = self.span.contacts.get(c)?;
        z.get(sc.pn.clone()).and_then(|p| p.first()).copied()
    }

    fn velocities(&self, z: &[f64]) -> Vec<[f64; 6]> {
        self.span
            .bodies
            .iter()
            .map(|b| {
                let nu = &z[b.nu.clone()];
                [nu[0], nu[1], nu[2], nu[3], nu[4], nu[5]]
            })
            .collect()
    }

    /// Contact `c` at the trial point: the patch points are indexed `j` (vertex `j` of F over
    /// G), `n_F + k` (vertex `k` of G under F) and `n_F + n_G + i n_EG + j` (edge `i` of F across
    /// edge `j` of G), with `n_F`, `n_G` the hulls' vertex counts and `n_EG` G's edge count.
    fn contact(&self, c: usize, z: &[f64], band: f64) -> ContactGeometry {
        let contact = &self.contacts[c];
        let key = contact.key;
        let sc = &self.span.contacts[c];
        let h = self.span.h;
        let f = self.placed_f(c, z);
        let g = self.placed_g(c, z);
        let mu = &z[sc.mu.clone()];
        let nu_g: Vector3<f64> = g.normals.iter().zip(mu).map(|(m, w)| m * *w).sum();
        let nu_g = if nu_g.norm() > 1e-12 && nu_g.iter().all(|v| v.is_finite()) {
            nu_g
        } else {
            contact.normal
        };
        let frame = PairFrame::new(&nu_g, &sc.axis);
        let (n, t, o) = (frame.n, frame.t, frame.o);
        // Velocities of both sides at the trial point and without contact impulses.
        let trial = |b: usize| Vector6::from_column_slice(&z[self.span.bodies[b].nu.clone()]);
        let free = |b: usize| {
            let (r1, w) = self.body_trial(b, z);
            self.span.bodies[b].data.free_velocity(&r1, &w)
        };
        let (nu_trial_f, nu_free_f) = (trial(key.f), free(key.f));
        let approach = |p: &Vector3<f64>| {
            let rate = |nu_f: &Vector6<f64>, nu: &dyn Fn(usize) -> Vector6<f64>| {
                let vf = nu_f.fixed_rows::<3>(0) + nu_f.fixed_rows::<3>(3).cross(&(p - f.x));
                n.dot(&(vf - self.partner_velocity(key.g, &g.x, nu, p)))
            };
            (-rate(&nu_trial_f, &trial))
                .max(-rate(&nu_free_f, &free))
                .max(0.0)
        };
        let mut patch: Vec<PatchVertex> = Vec::new();
        let seen = |patch: &[PatchVertex], p: &Vector3<f64>| {
            patch.iter().any(|q| {
                let d = v3(&q.position) - p;
                (d - n * n.dot(&d)).norm() <= ON_BOUNDARY
            })
        };
        let (nf, ng) = (f.vertices.len(), g.vertices.len());
        let mut fastest: f64 = 0.0;
        // Vertices of F over G: G's top along the normal below each.
        for (j, v) in f.vertices.iter().enumerate() {
            let Some((_, top)) = g.line_interval(v, &n).filter(|(_, hi)| hi.is_finite()) else {
                continue;
            };
            let gap = -top;
            let a = approach(v);
            fastest = fastest.max(a);
            if gap <= band + 2.0 * h * a {
                patch.push(PatchVertex {
                    index: j,
                    position: arr(v),
                    gap,
                    partner_position: arr(&(v + n * top)),
                });
            }
        }
        // Vertices of G under F: F's bottom along the normal above each.
        for (k, u) in g.vertices.iter().enumerate() {
            let Some((bottom, _)) = f.line_interval(u, &n).filter(|(lo, _)| lo.is_finite()) else {
                continue;
            };
            let p = u + n * bottom;
            let a = approach(&p);
            fastest = fastest.max(a);
            if bottom <= band + 2.0 * h * a && !seen(&patch, &p) {
                patch.push(PatchVertex {
                    index: nf + k,
                    position: arr(&p),
                    gap: bottom,
                    partner_position: arr(u),
                });
            }
        }
        // Edges of F across edges of G, seen along the normal, among the edges near each
        // hull's support.
        if !g.edges.is_empty() && !f.edges.is_empty() {
            let reach = band + 2.0 * h * fastest;
            let low_f = f
                .vertices
                .iter()
                .map(|v| n.dot(v))
                .fold(f64::INFINITY, f64::min);
            let high_g = (g.vertices.iter().map(|v| n.dot(v))).fold(f64::NEG_INFINITY, f64::max);
            let near_f: Vec<usize> = (0..f.edges.len())
                .filter(|&i| {
                    let (a, b) = f.edges[i];
                    n.dot(&f.vertices[a]) - low_f <= reach && n.dot(&f.vertices[b]) - low_f <= reach
                })
                .collect();
            let near_g: Vec<usize> = (0..g.edges.len())
                .filter(|&i| {
                    let (a, b) = g.edges[i];
                    high_g - n.dot(&g.vertices[a]) <= reach
                        && high_g - n.dot(&g.vertices[b]) <= reach
                })
                .collect();
            let neg = g.edges.len();
            for &i in &near_f {
                let (a, b) = (f.vertices[f.edges[i].0], f.vertices[f.edges[i].1]);
                for &j in &near_g {
                    let (cg, dg) = (g.vertices[g.edges[j].0], g.vertices[g.edges[j].1]);
                    let Some((s, u)) = line_crossing(&a, &(b - a), &cg, &(dg - cg), &n) else {
                        continue;
                    };
                    let inside = |x: f64| x > 1e-9 && x < 1.0 - 1e-9;
                    if !(inside(s) && inside(u)) {
                        continue;
                    }
                    let pf = a + (b - a) * s;
                    let pg = cg + (dg - cg) * u;
                    let gap = n.dot(&(pf - pg));
                    // Only where the edges are the facing surfaces: pf F's bottom and pg G's top
                    // along the normal.
                    let on_surfaces = f
                        .line_interval(&pf, &n)
                        .is_some_and(|(lo, _)| lo.abs() <= 1e-9)
                        && g.line_interval(&pf, &n)
                            .is_some_and(|(_, hi)| (hi + gap).abs() <= 1e-9);
                    if !on_surfaces || seen(&patch, &pf) {
                        continue;
                    }
                    if gap <= band + 2.0 * h * approach(&pf) {
                        patch.push(PatchVertex {
                            index: nf + ng + i * neg + j,
                            position: arr(&pf),
                            gap,
                            partner_position: arr(&pg),
                        });
                    }
                }
            }
        }
        let gap = patch.iter().map(|p| p.gap).fold(f64::INFINITY, f64::min);
        let a1 = &z[sc.a1.clone()];
        let fr = sc.friction;
        let partner = match key.g {
            Partner::Plane(_) => ContactPartner::HalfSpace,
            Partner::Body(b) => ContactPartner::Body {
                body: b,
                center_of_mass: arr(&g.x),
            },
            Partner::Obstacle(k) => ContactPartner::Prescribed {
                velocity: self.span.obstacles[k].2,
                center_of_mass: arr(&g.x),
            },
        };
        ContactGeometry {
            body: key.f,
            normal: arr(&n),
            tangent: arr(&t),
            bitangent: arr(&o),
            center_of_mass: arr(&f.x),
            gap,
            patch,
            ecp: [a1[0], a1[1], a1[2]],
            friction: ContactFriction {
                mu: fr.mu,
                e_t: fr.e_t,
                e_o: fr.e_o,
                e_r: fr.e_r,
            },
            partner,
        }
    }

    /// Maps a conic point back: `ν` as given, `q` by the kinematic map; per contact with load,
    /// `a1 = a2` the centre of pressure of the patch impulses at the new poses, `d = 0`, the
    /// normal from the faces active there (one face of either side: its normal; an edge of each:
    /// their common perpendicular; otherwise the normal the impulses were computed with), `μ`
    /// and `l` the non-negative combinations of the active faces along it; without load, the
    /// closest features of the two hulls at the new poses (for a half-space, the closest
    /// feature of F and its projection, as the hull formulation's map back).
    fn assemble(&self, point: &ConicPoint, z: &mut [f64]) {
        let h = self.span.h;
        for (b, body) in self.span.bodies.iter().enumerate() {
            let nu = point.velocities.get(b).copied().unwrap_or([0.0; 6]);
            z[body.nu.clone()].copy_from_slice(&nu);
            let (x0, q0) = (body.start_x, body.data.q_start);
            let v = Vector3::new(nu[0], nu[1], nu[2]);
            let w = Vector3::new(nu[3], nu[4], nu[5]);
            let x = x0 + v * h;
            let q = q0 + kinematic_map(&q0) * w * (0.5 * h);
            z[body.q.clone()].copy_from_slice(&[x.x, x.y, x.z, q[0], q[1], q[2], q[3]]);
        }
        let empty = ContactImpulses::default();
        for c in 0..self.contacts.len() {
            let sc = &self.span.contacts[c];
            let f = self.placed_f(c, z);
            let g = self.placed_g(c, z);
            let imp = point.contacts.get(c).unwrap_or(&empty);
            let pn: f64 = imp.vertex_impulses.iter().map(|(_, l)| l.max(0.0)).sum();
            let hint = {
                let n = Vector3::from(imp.normal);
                if n.norm() > 0.5 {
                    n
                } else {
                    self.contacts[c].normal
                }
            };
            let values = if pn > 0.0 {
                let mut a = Vector3::zeros();
                for &(j, l) in &imp.vertex_impulses {
                    if let Some(p) = Self::patch_point(j, &f, &g) {
                        a += p * (l.max(0.0) / pn);
                    }
                }
                loaded_contact(&f, &g, &a, &hint)
            } else {
                separated_contact(self, c, &f, &g)
            };
            let Some((a1, a2, d, l, mu)) = values else {
                continue;
            };
            z[sc.a1.clone()].copy_from_slice(a1.as_slice());
            z[sc.a2.clone()].copy_from_slice(a2.as_slice());
            z[sc.l.clone()].copy_from_slice(&l);
            z[sc.mu.clone()].copy_from_slice(&mu);
            z[sc.d.clone()][0] = d;
            z[sc.pn.clone()][0] = pn;
            z[sc.pf.clone()].copy_from_slice(&imp.friction);
            z[sc.sigma.clone()][0] = imp.sigma.max(0.0);
        }
    }
}

/// `(a1, a2, d, l, μ)` of a pair contact.
type PairValues = (Vector3<f64>, Vector3<f64>, f64, Vec<f64>, Vec<f64>);

/// Indices of the faces of `side` within [`ACTIVE`] of the most active one at `a`, and the
/// tolerance that selects them.
fn active_faces(side: &Placed<'_>, a: &Vector3<f64>) -> (Vec<usize>, f64) {
    let values: Vec<f64> = (0..side.normals.len()).map(|i| side.value(i, a)).collect();
    let top = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let tol = ACTIVE + (-top).max(0.0);
    (
        (0..values.len()).filter(|&i| values[i] >= -tol).collect(),
        tol,
    )
}

/// A loaded contact at the centre of pressure `a` (touching: `a1 = a2 = a`, `d = 0`).
fn loaded_contact(
    f: &Placed<'_>,
    g: &Placed<'_>,
    a: &Vector3<f64>,
    hint: &Vector3<f64>,
) -> Option<PairValues> {
    let (af, tol_f) = active_faces(f, a);
    let (ag, tol_g) = active_faces(g, a);
    let n = if ag.len() == 1 {
        g.normals[ag[0]]
    } else if af.len() == 1 {
        -f.normals[af[0]]
    } else if ag.len() == 2 && af.len() == 2 {
        let eg = g.normals[ag[0]].cross(&g.normals[ag[1]]);
        let ef = f.normals[af[0]].cross(&f.normals[af[1]]);
        let m = ef.cross(&eg);
        let len = m.norm();
        if len > 1e-9 * ef.norm() * eg.norm() && len.is_finite() {
            if m.dot(hint) < 0.0 { -m / len } else { m / len }
        } else {
            *hint
        }
    } else {
        *hint
    };
    let values_g: Vec<f64> = (0..g.normals.len()).map(|i| g.value(i, a)).collect();
    let mu = cone_combination(&g.normals, &values_g, tol_g, &n);
    let sum: f64 = mu.iter().sum();
    if !(sum > 0.0 && sum.is_finite()) {
        return None;
    }
    let mu: Vec<f64> = mu.iter().map(|m| m / sum).collect();
    let nu_g: Vector3<f64> = g.normals.iter().zip(&mu).map(|(m, w)| m * *w).sum();
    let values_f: Vec<f64> = (0..f.normals.len()).map(|i| f.value(i, a)).collect();
    let mut l = cone_combination(&f.normals, &values_f, tol_f, &(-nu_g.normalize()));
    let lsum: Vector3<f64> = f.normals.iter().zip(&l).map(|(m, li)| m * *li).sum();
    let k = nu_g.norm() / lsum.norm().max(f64::MIN_POSITIVE);
    for li in &mut l {
        *li *= k;
    }
    Some((*a, *a, 0.0, l, mu))
}

/// A contact without load: the closest features of the two hulls (for a half-space, F's
/// closest feature at its centroid and its projection).
fn separated_contact(
    body: &MultiBody,
    c: usize,
    f: &Placed<'_>,
    g: &Placed<'_>,
) -> Option<PairValues> {
    let Some(hull_g) = g.hull else {
        // A half-space: one face, μ = 1.
        let (m, e) = (g.normals[0], g.offsets[0]);
        let gaps: Vec<f64> = f.vertices.iter().map(|p| m.dot(p) - e).collect();
        let gmin = gaps.iter().copied().fold(f64::INFINITY, f64::min);
        let mut a = Vector3::zeros();
        let mut k = 0.0;
        for (p, gap) in f.vertices.iter().zip(&gaps) {
            if *gap <= gmin + SUPPORT_TIE {
                a += p;
                k += 1.0;
            }
        }
        let a1 = a / f64::max(k, 1.0);
        let d = (m.dot(&a1) - e).max(0.0);
        let a2 = a1 - m * d;
        let values_f: Vec<f64> = (0..f.normals.len()).map(|i| f.value(i, &a1)).collect();
        let l = cone_combination(&f.normals, &values_f, 1e-9, &(-m));
        return Some((a1, a2, d, l, vec![1.0]));
    };
    let key = body.contacts[c].key;
    let hull_f = &body.bodies[key.f].hull;
    let pose_f = HullPose {
        hull: hull_f,
        x: f.x,
        rotation: f.rotation,
    };
    let pose_g = HullPose {
        hull: hull_g,
        x: g.x,
        rotation: g.rotation,
    };
    let features = touching_features(&pose_f, &pose_g)?;
    Some((
        features.a1,
        features.a2,
        features.d,
        features.l,
        features.mu,
    ))
}
