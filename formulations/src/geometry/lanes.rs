//! A vertex set in lanes (one array per coordinate) and its world positions and gaps to a
//! half-space at a pose, computed a chunk of vertices at a time in loops the compiler makes
//! two lanes wide: the gaps of every vertex of a contact record and of the warm start's lowest
//! feature (`docs/latency.md`, branch wip-deskrest).
//!
//! Each lane computes what `plane.value(&(x + r * v))` computes for one vertex, operation by
//! operation: `(R v)_i = (r_i0 v_0 + r_i1 v_1) + r_i2 v_2` (nalgebra's product, a column at a
//! time), `p = x + R v`, `g = ((n_0 p_0 + n_1 p_1) + n_2 p_2) − c` (its three-term dot), each
//! product rounded before its sum (no fused multiply-add): the same bits, vertex by vertex.

use nalgebra::{Matrix3, Vector3};

use super::HalfSpace;

/// The most vertices one [`WorldChunk`] holds (on the stack).
pub const LANE_CHUNK: usize = 16;

/// A vertex set (body frame) as three coordinate arrays (module documentation).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VertexLanes {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

/// The world positions and gaps of up to [`LANE_CHUNK`] vertices (the first `len`).
#[derive(Clone, Copy, Debug)]
pub struct WorldChunk {
    /// World coordinates of each vertex, `x + R v`.
    pub x: [f64; LANE_CHUNK],
    /// (As `x`.)
    pub y: [f64; LANE_CHUNK],
    /// (As `x`.)
    pub z: [f64; LANE_CHUNK],
    /// Each vertex's gap `g(x + R v)` to the half-space.
    pub gap: [f64; LANE_CHUNK],
    /// How many entries hold vertices.
    pub len: usize,
}

impl Default for WorldChunk {
    fn default() -> Self {
        WorldChunk {
            x: [0.0; LANE_CHUNK],
            y: [0.0; LANE_CHUNK],
            z: [0.0; LANE_CHUNK],
            gap: [0.0; LANE_CHUNK],
            len: 0,
        }
    }
}

impl WorldChunk {
    /// The world position of entry `k`.
    pub fn point(&self, k: usize) -> Vector3<f64> {
        Vector3::new(self.x[k], self.y[k], self.z[k])
    }
}

/// The rotation's entries by rows, `[[r_00, r_01, r_02], ...]`.
#[inline(always)]
fn rows(r: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [r[(i, 0)], r[(i, 1)], r[(i, 2)]])
}

impl VertexLanes {
    /// The lanes of `vertices`, in their order.
    pub fn of(vertices: &[Vector3<f64>]) -> Self {
        VertexLanes {
            x: vertices.iter().map(|v| v.x).collect(),
            y: vertices.iter().map(|v| v.y).collect(),
            z: vertices.iter().map(|v| v.z).collect(),
        }
    }

    /// The number of vertices.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there is no vertex.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Whether these are the lanes of `vertices` (the same bits, in order).
    pub fn holds(&self, vertices: &[Vector3<f64>]) -> bool {
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits();
        vertices.len() == self.len()
            && vertices
                .iter()
                .enumerate()
                .all(|(k, v)| same(v.x, self.x[k]) && same(v.y, self.y[k]) && same(v.z, self.z[k]))
    }

    /// The gaps `g(x + R v)` to `plane` at the pose `(x, r)` of the vertices `[start, start +
    /// gaps.len())` (fewer at the end: the entries past the last vertex are left as they are),
    /// in `gaps`: the bits of `plane.value(&(x + r * v))` for each (module documentation).
    pub fn gaps_into(
        &self,
        start: usize,
        (x, r): (&Vector3<f64>, &Matrix3<f64>),
        plane: &HalfSpace,
        gaps: &mut [f64],
    ) {
        let end = self.len().min(start.saturating_add(gaps.len()));
        let len = end.saturating_sub(start);
        let (vx, vy, vz) = (
            &self.x[start.min(end)..end],
            &self.y[start.min(end)..end],
            &self.z[start.min(end)..end],
        );
        let (n, c) = (plane.normal(), plane.offset());
        let [[r00, r01, r02], [r10, r11, r12], [r20, r21, r22]] = rows(r);
        for (k, g) in gaps[..len].iter_mut().enumerate() {
            let (a, b, d) = (vx[k], vy[k], vz[k]);
            let wx = x.x + ((r00 * a + r01 * b) + r02 * d);
            let wy = x.y + ((r10 * a + r11 * b) + r12 * d);
            let wz = x.z + ((r20 * a + r21 * b) + r22 * d);
            *g = ((n.x * wx + n.y * wy) + n.z * wz) - c;
        }
    }

    /// The world positions `x + R v` and gaps `g(x + R v)` to `plane` at the pose `(x, r)` of
    /// the vertices `[start, start + LANE_CHUNK)` (fewer at the end), into `out`: the bits of
    /// `x + r * v` and `plane.value(&(x + r * v))` for each (module documentation).
    pub fn world_into(
        &self,
        start: usize,
        (x, r): (&Vector3<f64>, &Matrix3<f64>),
        plane: &HalfSpace,
        out: &mut WorldChunk,
    ) {
        let end = self.len().min(start.saturating_add(LANE_CHUNK));
        let len = end.saturating_sub(start);
        out.len = len;
        let (vx, vy, vz) = (
            &self.x[start.min(end)..end],
            &self.y[start.min(end)..end],
            &self.z[start.min(end)..end],
        );
        let (n, c) = (plane.normal(), plane.offset());
        let [[r00, r01, r02], [r10, r11, r12], [r20, r21, r22]] = rows(r);
        let (px, py, pz, gap) = (
            &mut out.x[..len],
            &mut out.y[..len],
            &mut out.z[..len],
            &mut out.gap[..len],
        );
        for k in 0..len {
            let (a, b, d) = (vx[k], vy[k], vz[k]);
            let wx = x.x + ((r00 * a + r01 * b) + r02 * d);
            let wy = x.y + ((r10 * a + r11 * b) + r12 * d);
            let wz = x.z + ((r20 * a + r21 * b) + r22 * d);
            px[k] = wx;
            py[k] = wy;
            pz[k] = wz;
            gap[k] = ((n.x * wx + n.y * wy) + n.z * wz) - c;
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector4;

    use super::*;
    use crate::geometry::Shape;
    use crate::rotation::{quat_normalize, rotation_matrix};

    /// A deterministic sequence in (−1, 1) (no test dependency on a random crate).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        }
    }

    /// Every lane's world position and gap has the bits of `x + r * v` and
    /// `plane.value(&(x + r * v))`: the desk's, the T-bar's and random vertex sets, random
    /// poses near and far from the origin, tilted half-spaces, signed zeros, and non-finite
    /// positions (NaN compared as NaN).
    #[test]
    fn lanes_give_the_bits_of_the_vertex_by_vertex_gaps() {
        let mut rng = Lcg(7);
        let mut sets: Vec<Vec<Vector3<f64>>> = vec![
            Shape::desk().vertices().to_vec(),
            Shape::t_bar().vertices().to_vec(),
            vec![Vector3::new(-0.0, 0.0, -0.0), Vector3::new(0.0, -0.0, 0.0)],
            Vec::new(),
        ];
        for n in [1, 3, 16, 17, 33, 70] {
            sets.push(
                (0..n)
                    .map(|_| Vector3::new(rng.next(), rng.next(), rng.next()) * 3.0)
                    .collect(),
            );
        }
        let mut checked = 0;
        for set in &sets {
            let lanes = VertexLanes::of(set);
            assert!(lanes.holds(set));
            assert_eq!(lanes.len(), set.len());
            for trial in 0..60 {
                let q = quat_normalize(&Vector4::new(
                    rng.next(),
                    rng.next(),
                    rng.next(),
                    rng.next(),
                ))
                .unwrap_or_else(|| Vector4::new(1.0, 0.0, 0.0, 0.0));
                let r = match trial {
                    0 => Matrix3::identity(),
                    1 => -Matrix3::identity(),
                    _ => rotation_matrix(&q),
                };
                let far = [1.0, 1e3, 1e14][trial % 3];
                let x = match trial {
                    2 => Vector3::new(-0.0, 0.0, -0.0),
                    3 => Vector3::new(f64::NAN, 0.0, 1.0),
                    4 => Vector3::new(f64::INFINITY, 0.0, 1.0),
                    _ => Vector3::new(rng.next(), rng.next(), rng.next()) * far,
                };
                let normal = match trial % 4 {
                    0 => Vector3::z(),
                    1 => Vector3::new(0.0, 0.6, 0.8),
                    _ => Vector3::new(rng.next(), rng.next(), rng.next()),
                };
                let plane =
                    HalfSpace::new(normal, rng.next()).unwrap_or_else(|_| HalfSpace::ground());
                let same =
                    |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
                let mut chunk = WorldChunk::default();
                for start in (0..set.len().max(1)).step_by(LANE_CHUNK) {
                    lanes.world_into(start, (&x, &r), &plane, &mut chunk);
                    assert_eq!(chunk.len, set.len().saturating_sub(start).min(LANE_CHUNK));
                    for k in 0..chunk.len {
                        let p = x + r * set[start + k];
                        let g = plane.value(&p);
                        assert!(same(chunk.gap[k], g), "gap {} vs {g}", chunk.gap[k]);
                        for (a, b) in chunk.point(k).iter().zip(p.iter()) {
                            assert!(same(*a, *b), "coordinate {a} vs {b}");
                        }
                        checked += 1;
                    }
                }
                // The gaps alone, from every start and with buffers longer than what is left.
                for (start, size) in [(0, set.len()), (1, 5), (3, 40), (set.len(), 2)] {
                    let mut gaps = vec![-7.0; size];
                    lanes.gaps_into(start, (&x, &r), &plane, &mut gaps);
                    for (k, g) in gaps.iter().enumerate() {
                        match set.get(start + k) {
                            Some(v) => assert!(same(*g, plane.value(&(x + r * v)))),
                            None => assert_eq!(*g, -7.0, "past the last vertex"),
                        }
                    }
                }
            }
        }
        assert!(checked > 10_000, "{checked}");
    }
}
