//! The seeded generator of stress scenes: ordinary scene files of every kind a new user would
//! try (see `docs/stress.md` for the categories and the ranges of every parameter).
//!
//! Everything is drawn from a local SplitMix64 stream and computed with `+ − × ÷ √` only
//! (sines and cosines by a fixed polynomial, [`det_sin_cos`]), so the scene text depends on
//! the seed alone, on every platform and with every version of the standard library.
//! See `docs/decisions.md#local-prng-of-the-stress-suite`.

use std::fmt::Write as _;

use nalgebra::{Matrix3, Vector3, Vector4};

/// The kinds of scenes of the stress suite.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Category {
    /// A box or convex point set dropped from a tilt onto the floor.
    ConvexDrop,
    /// A box or convex point set tossed with spin onto the floor.
    ConvexToss,
    /// A box or convex point set resting on the floor, pushed by a time-varying force.
    ConvexPush,
    /// A union of 2–5 boxes (T, L, U, arch, table, chain) resting, with or without a small
    /// time-varying load.
    UnionRest,
    /// A union of boxes sliding (and spinning) on the floor.
    UnionSlide,
    /// A union of boxes tipped by a time-varying torque and force.
    UnionTip,
    /// A body resting or sliding on an incline of 0–40°.
    Incline,
    /// Floor and a wall: a body sliding into the wall.
    CornerWall,
    /// A ladder (long thin box) leaning against a wall.
    Ladder,
    /// A body in a V trough of two inclined planes.
    VTrough,
    /// A body in a room corner (floor and two walls).
    RoomCorner,
    /// An OBJ or STL mesh (some in millimetres) dropped, pushed or slid.
    Mesh,
    /// Several separate bodies in one scene.
    MultiBody,
}

impl Category {
    /// Every category, in generation order (scene `i` is of category `ALL[i % 13]`).
    pub const ALL: [Category; 13] = [
        Category::ConvexDrop,
        Category::ConvexToss,
        Category::ConvexPush,
        Category::UnionRest,
        Category::UnionSlide,
        Category::UnionTip,
        Category::Incline,
        Category::CornerWall,
        Category::Ladder,
        Category::VTrough,
        Category::RoomCorner,
        Category::Mesh,
        Category::MultiBody,
    ];

    /// The name used in scene names and reports.
    pub fn as_str(&self) -> &'static str {
        match self {
            Category::ConvexDrop => "convex_drop",
            Category::ConvexToss => "convex_toss",
            Category::ConvexPush => "convex_push",
            Category::UnionRest => "union_rest",
            Category::UnionSlide => "union_slide",
            Category::UnionTip => "union_tip",
            Category::Incline => "incline",
            Category::CornerWall => "corner_wall",
            Category::Ladder => "ladder",
            Category::VTrough => "v_trough",
            Category::RoomCorner => "room_corner",
            Category::Mesh => "mesh",
            Category::MultiBody => "multi_body",
        }
    }
}

impl std::fmt::Display for Category {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One generated scene: an ordinary scene file and the mesh files it names.
#[derive(Clone, Debug, PartialEq)]
pub struct StressScene {
    /// Scene name (also the file stem): `<index>_<category>`.
    pub name: String,
    /// Its category.
    pub category: Category,
    /// The TOML text of the scene file (docs/scene-format.md).
    pub toml: String,
    /// Mesh files the scene names, `(file name, contents)`, to be written beside the scene file.
    pub files: Vec<(String, Vec<u8>)>,
    /// No applied load besides gravity on any body: the total energy must not rise.
    pub unforced: bool,
}

impl StressScene {
    /// Writes the scene file `<dir>/<name>.toml` and its mesh files into `dir` (created if
    /// missing); returns the scene file's path.
    pub fn write_to(&self, dir: &std::path::Path) -> std::io::Result<std::path::PathBuf> {
        std::fs::create_dir_all(dir)?;
        for (name, bytes) in &self.files {
            std::fs::write(dir.join(name), bytes)?;
        }
        let path = dir.join(format!("{}.toml", self.name));
        std::fs::write(&path, &self.toml)?;
        Ok(path)
    }
}

/// `count` scenes from `seed`: scene `i` is of category `Category::ALL[i % 13]` and is drawn
/// from its own stream (seeded by `seed` and `i`), so a scene does not change when `count` does.
pub fn generate(seed: u64, count: usize) -> Vec<StressScene> {
    (0..count)
        .map(|i| {
            let category = Category::ALL[i % Category::ALL.len()];
            let mut rng =
                SplitMix64::new(seed ^ (i as u64 + 1).wrapping_mul(0xD1B5_4A32_D192_ED03));
            let name = format!("{i:03}_{category}");
            build(&name, category, i / Category::ALL.len(), &mut rng)
        })
        .collect()
}

/// SplitMix64 (Steele, Lea & Flood): a tiny, well-mixed 64-bit stream, identical everywhere.
#[derive(Clone, Debug)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A stream starting from `seed`.
    pub fn new(seed: u64) -> Self {
        SplitMix64 { state: seed }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) with 53 bits.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform in [lo, hi) rounded to a multiple of `step` (readable scene files).
    pub fn rounded(&mut self, lo: f64, hi: f64, step: f64) -> f64 {
        round_to(self.range(lo, hi), step)
    }

    /// Uniform integer in [lo, hi] (inclusive).
    pub fn int(&mut self, lo: usize, hi: usize) -> usize {
        lo + (self.next_u64() % (hi - lo + 1) as u64) as usize
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// One of `items`.
    pub fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.int(0, items.len() - 1)]
    }

    /// A uniformly distributed unit vector (rejection from the cube).
    pub fn direction(&mut self) -> Vector3<f64> {
        loop {
            let v = Vector3::new(
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
            );
            let n = v.norm();
            if n > 0.2 && n <= 1.0 {
                return v / n;
            }
        }
    }
}

/// `x` rounded to a multiple of `step` (a power of ten or a simple fraction of one): divided by
/// the integer `1/step`, so that the result prints as a short decimal.
fn round_to(x: f64, step: f64) -> f64 {
    let inv = (1.0 / step).round();
    (x * inv).round() / inv
}

/// `(sin x, cos x)` by range reduction to [−π/4, π/4] and Taylor polynomials of degree 17/18
/// (error below 1e-16): plain arithmetic only, so identical on every platform.
pub fn det_sin_cos(x: f64) -> (f64, f64) {
    let half_pi = std::f64::consts::FRAC_PI_2;
    let k = (x / half_pi).round();
    let r = x - k * half_pi;
    let r2 = r * r;
    let mut s = 0.0;
    let mut c = 0.0;
    // Horner from the highest term: sin r = r Σ (−r²)^n/(2n+1)!, cos r = Σ (−r²)^n/(2n)!.
    for n in (0..10).rev() {
        let n = n as f64;
        s = 1.0 - s * r2 / ((2.0 * n + 2.0) * (2.0 * n + 3.0));
        c = 1.0 - c * r2 / ((2.0 * n + 1.0) * (2.0 * n + 2.0));
    }
    let s = s * r;
    match (k as i64).rem_euclid(4) {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Unit quaternion `(w, x, y, z)` of a rotation by `angle` (rad) about the unit `axis`.
fn axis_angle(axis: &Vector3<f64>, angle: f64) -> Vector4<f64> {
    let (s, c) = det_sin_cos(0.5 * angle);
    Vector4::new(c, s * axis.x, s * axis.y, s * axis.z)
}

/// Hamilton product `a ⊗ b` (apply `b` first).
fn quat_mul(a: &Vector4<f64>, b: &Vector4<f64>) -> Vector4<f64> {
    Vector4::new(
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    )
}

/// Rotation matrix of a quaternion `(w, x, y, z)` (normalised here).
pub fn quat_to_matrix(q: &Vector4<f64>) -> Matrix3<f64> {
    let q = q / q.norm();
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

const G: f64 = 9.8;

/// A plane as the generator writes it.
#[derive(Clone, Debug)]
struct Plane {
    /// Unit outward normal (as the loader will normalise it).
    normal: Vector3<f64>,
    offset: f64,
    /// `incline_deg = θ` instead of a normal.
    incline_deg: Option<f64>,
}

impl Plane {
    fn new(normal: Vector3<f64>, offset: f64) -> Self {
        let n = normal.norm();
        Plane {
            normal: normal / n,
            offset: offset / n,
            incline_deg: None,
        }
    }
    fn floor() -> Self {
        Plane::new(Vector3::z(), 0.0)
    }
    /// A wall with the obstacle on the side `normal` points away from, through `point`.
    fn wall(normal: Vector3<f64>, point: Vector3<f64>) -> Self {
        let n = normal.normalize();
        Plane::new(n, n.dot(&point))
    }
    fn incline(deg: f64) -> Self {
        let (s, c) = det_sin_cos(deg.to_radians());
        Plane {
            normal: Vector3::new(-s, 0.0, c),
            offset: 0.0,
            incline_deg: Some(deg),
        }
    }
    fn toml(&self, out: &mut String) {
        out.push_str("\n[[half_spaces]]\n");
        match self.incline_deg {
            Some(d) => {
                let _ = writeln!(out, "incline_deg = {}", num(d));
            }
            None => {
                let _ = writeln!(out, "normal = {}", vec3(&self.normal));
                if self.offset != 0.0 {
                    let _ = writeln!(out, "offset = {}", num(self.offset));
                }
            }
        }
    }
}

/// The geometry of one body: its piece tables, inertia, and body-frame (CM-frame) vertices.
#[derive(Clone, Debug)]
struct Geom {
    /// A short description (`box`, `points`, `T`, `mesh-obj-mm`, ...).
    kind: String,
    pieces: String,
    inertia: String,
    /// Vertices in the body frame, origin at the CM, as the loader will build them.
    verts: Vec<Vector3<f64>>,
    files: Vec<(String, Vec<u8>)>,
}

impl Geom {
    /// Half the largest extent along any axis (a size for speeds and loads).
    fn radius(&self) -> f64 {
        self.verts.iter().map(|v| v.norm()).fold(0.0, f64::max)
    }
    /// Minimum of `n · R v` over the vertices.
    fn support_min(&self, r: &Matrix3<f64>, n: &Vector3<f64>) -> f64 {
        self.verts
            .iter()
            .map(|v| n.dot(&(r * v)))
            .fold(f64::INFINITY, f64::min)
    }
    /// Half extents of the body-frame bounding box.
    fn half_box(&self) -> Vector3<f64> {
        let mut h = Vector3::zeros();
        for v in &self.verts {
            for k in 0..3 {
                h[k] = f64::max(h[k], v[k].abs());
            }
        }
        h
    }
}

fn num(x: f64) -> String {
    let x = if x == 0.0 { 0.0 } else { x };
    format!("{x}")
}

fn vec3(v: &Vector3<f64>) -> String {
    format!("[{}, {}, {}]", num(v.x), num(v.y), num(v.z))
}

fn box_vertices(half: &Vector3<f64>, center: &Vector3<f64>) -> Vec<Vector3<f64>> {
    let mut out = Vec::with_capacity(8);
    for sx in [-1.0, 1.0] {
        for sy in [-1.0, 1.0] {
            for sz in [-1.0, 1.0] {
                out.push(center + Vector3::new(sx * half.x, sy * half.y, sz * half.z));
            }
        }
    }
    out
}

/// A union of axis-aligned boxes `(size, center)` with uniform density (`inertia = "uniform"`).
fn union_of_boxes(kind: &str, boxes: &[(Vector3<f64>, Vector3<f64>)]) -> Geom {
    let vols: Vec<f64> = boxes.iter().map(|(s, _)| s.x * s.y * s.z).collect();
    let total: f64 = vols.iter().sum();
    let cm: Vector3<f64> = boxes
        .iter()
        .zip(&vols)
        .map(|((_, c), v)| c * (v / total))
        .sum();
    let mut pieces = String::new();
    let mut verts = Vec::new();
    for (size, center) in boxes {
        let _ = write!(
            pieces,
            "\n[[bodies.pieces]]\nbox = {}\ncenter = {}\n",
            vec3(size),
            vec3(center)
        );
        verts.extend(box_vertices(&(size / 2.0), &(center - cm)));
    }
    Geom {
        kind: kind.to_string(),
        pieces,
        inertia: "\"uniform\"".into(),
        verts,
        files: Vec::new(),
    }
}

fn single_box(rng: &mut SplitMix64) -> Geom {
    let size = Vector3::new(
        rng.rounded(0.06, 0.5, 0.01),
        rng.rounded(0.06, 0.5, 0.01),
        rng.rounded(0.04, 0.4, 0.01),
    );
    union_of_boxes("box", &[(size, Vector3::zeros())])
}

/// Solid-ellipsoid inertia of semi-axes `a` (a plausible inertia for a convex point set).
fn ellipsoid_inertia(mass: f64, a: &Vector3<f64>) -> String {
    let i = Vector3::new(
        a.y * a.y + a.z * a.z,
        a.x * a.x + a.z * a.z,
        a.x * a.x + a.y * a.y,
    ) * (mass / 5.0);
    vec3(&i.map(|x| round_to(x, 1e-7).max(1e-7)))
}

/// A convex point set: the six axis points of an ellipsoid (so the hull has a volume) and
/// 6–12 random points on it.
fn point_set(rng: &mut SplitMix64, mass: f64) -> Geom {
    let a = Vector3::new(
        rng.rounded(0.04, 0.25, 0.005),
        rng.rounded(0.04, 0.25, 0.005),
        rng.rounded(0.03, 0.2, 0.005),
    );
    let mut pts = vec![
        Vector3::new(a.x, 0.0, 0.0),
        Vector3::new(-a.x, 0.0, 0.0),
        Vector3::new(0.0, a.y, 0.0),
        Vector3::new(0.0, -a.y, 0.0),
        Vector3::new(0.0, 0.0, a.z),
        Vector3::new(0.0, 0.0, -a.z),
    ];
    for _ in 0..rng.int(6, 12) {
        let d = rng.direction();
        pts.push(Vector3::new(
            round_to(d.x * a.x, 1e-4),
            round_to(d.y * a.y, 1e-4),
            round_to(d.z * a.z, 1e-4),
        ));
    }
    let list = pts.iter().map(vec3).collect::<Vec<_>>().join(", ");
    Geom {
        kind: "points".into(),
        pieces: format!("\n[[bodies.pieces]]\npoints = [{list}]\n"),
        inertia: ellipsoid_inertia(mass, &a),
        verts: pts,
        files: Vec::new(),
    }
}

/// The union shapes of the issue, in turn.
const UNIONS: [&str; 6] = ["T", "L", "U", "arch", "table", "chain"];

fn union_shape(kind: &str, rng: &mut SplitMix64) -> Geom {
    let t = rng.rounded(0.03, 0.12, 0.01);
    let boxes: Vec<(Vector3<f64>, Vector3<f64>)> = match kind {
        // Flat in plan view, as the paper's T-bar: a bar across and a stem.
        "T" => {
            let (a, b) = (rng.rounded(0.3, 0.8, 0.01), rng.rounded(0.06, 0.15, 0.01));
            let (c, d) = (rng.rounded(0.06, 0.15, 0.01), rng.rounded(0.2, 0.6, 0.01));
            vec![
                (Vector3::new(a, b, t), Vector3::zeros()),
                (
                    Vector3::new(c, d, t),
                    Vector3::new(0.0, -(b + d) / 2.0, 0.0),
                ),
            ]
        }
        "L" => {
            let (a, b) = (rng.rounded(0.3, 0.8, 0.01), rng.rounded(0.06, 0.15, 0.01));
            let (c, d) = (rng.rounded(0.06, 0.15, 0.01), rng.rounded(0.2, 0.6, 0.01));
            vec![
                (Vector3::new(a, b, t), Vector3::zeros()),
                (
                    Vector3::new(c, d, t),
                    Vector3::new((a - c) / 2.0, (b + d) / 2.0, 0.0),
                ),
            ]
        }
        "U" => {
            let (a, b) = (rng.rounded(0.3, 0.8, 0.01), rng.rounded(0.06, 0.15, 0.01));
            let (c, d) = (rng.rounded(0.06, 0.15, 0.01), rng.rounded(0.15, 0.5, 0.01));
            vec![
                (Vector3::new(a, b, t), Vector3::zeros()),
                (
                    Vector3::new(c, d, t),
                    Vector3::new((a - c) / 2.0, (b + d) / 2.0, 0.0),
                ),
                (
                    Vector3::new(c, d, t),
                    Vector3::new(-(a - c) / 2.0, (b + d) / 2.0, 0.0),
                ),
            ]
        }
        // Two pillars and a lintel on top.
        "arch" => {
            let p = rng.rounded(0.05, 0.12, 0.01);
            let hgt = rng.rounded(0.15, 0.5, 0.01);
            let span = rng.rounded(0.2, 0.6, 0.01);
            let depth = rng.rounded(0.05, 0.2, 0.01);
            vec![
                (
                    Vector3::new(p, depth, hgt),
                    Vector3::new(-(span + p) / 2.0, 0.0, hgt / 2.0),
                ),
                (
                    Vector3::new(p, depth, hgt),
                    Vector3::new((span + p) / 2.0, 0.0, hgt / 2.0),
                ),
                (
                    Vector3::new(span + 2.0 * p, depth, t),
                    Vector3::new(0.0, 0.0, hgt + t / 2.0),
                ),
            ]
        }
        // A slab on four legs, like the paper's desk.
        "table" => {
            let (a, b) = (rng.rounded(0.3, 0.9, 0.01), rng.rounded(0.3, 0.9, 0.01));
            let leg = rng.rounded(0.03, 0.08, 0.01);
            let hgt = rng.rounded(0.2, 0.8, 0.01);
            let mut v = vec![(Vector3::new(a, b, t), Vector3::new(0.0, 0.0, hgt + t / 2.0))];
            for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                v.push((
                    Vector3::new(leg, leg, hgt),
                    Vector3::new(sx * (a - leg) / 2.0, sy * (b - leg) / 2.0, hgt / 2.0),
                ));
            }
            v
        }
        // 2–5 boxes in a row, face to face, of different sizes.
        _ => {
            let n = rng.int(2, 5);
            let mut v = Vec::new();
            let mut x = 0.0;
            for _ in 0..n {
                let s = Vector3::new(
                    rng.rounded(0.05, 0.2, 0.01),
                    rng.rounded(0.05, 0.2, 0.01),
                    rng.rounded(0.04, 0.15, 0.01),
                );
                v.push((s, Vector3::new(x + s.x / 2.0, 0.0, s.z / 2.0)));
                x += s.x;
            }
            v
        }
    };
    union_of_boxes(kind, &boxes)
}

/// A mesh: a prism over a regular n-gon (n = 3..8) or an L-shaped extrusion (non-convex; the
/// hull is used), written as OBJ or binary STL, in metres or millimetres (`scale = 0.001`).
fn mesh_shape(name: &str, rng: &mut SplitMix64, mass: f64, variant: usize) -> Geom {
    let stl = variant % 2 == 1;
    let mm = (variant / 2) % 2 == 1;
    let unit = if mm { 1000.0 } else { 1.0 };
    let height = rng.rounded(0.04, 0.3, 0.005);
    // The outline in the xy plane (metres), then extruded over ±height/2.
    let (outline, triangles_2d): (Vec<[f64; 2]>, Vec<[usize; 3]>) = if rng.chance(0.75) {
        let n = rng.int(3, 8);
        let r = rng.rounded(0.05, 0.25, 0.005);
        let pts = (0..n)
            .map(|k| {
                let (s, c) = det_sin_cos(2.0 * std::f64::consts::PI * k as f64 / n as f64);
                [r * c, r * s]
            })
            .collect();
        let tris = (1..n - 1).map(|k| [0, k, k + 1]).collect();
        (pts, tris)
    } else {
        let a = rng.rounded(0.15, 0.4, 0.005);
        let b = rng.rounded(0.05, 0.12, 0.005);
        // L outline: (0,0) (a,0) (a,b) (b,b) (b,a) (0,a), shifted to centre it.
        let c = a / 3.0;
        let pts: Vec<[f64; 2]> = [[0.0, 0.0], [a, 0.0], [a, b], [b, b], [b, a], [0.0, a]]
            .iter()
            .map(|p| [p[0] - c, p[1] - c])
            .collect();
        (pts, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]])
    };
    let n = outline.len();
    // File coordinates (f32-exact in the file's unit), and the same points in metres.
    let file_pts: Vec<[f32; 3]> = (0..2 * n)
        .map(|i| {
            let p = outline[i % n];
            let z = if i < n { -height / 2.0 } else { height / 2.0 };
            [
                (p[0] * unit) as f32,
                (p[1] * unit) as f32,
                (z * unit) as f32,
            ]
        })
        .collect();
    let scale = if mm { 0.001 } else { 1.0 };
    let verts: Vec<Vector3<f64>> = file_pts
        .iter()
        .map(|p| Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) * scale)
        .collect();
    let mut faces: Vec<[usize; 3]> = Vec::new();
    for t in &triangles_2d {
        faces.push([t[0], t[2], t[1]]);
        faces.push([t[0] + n, t[1] + n, t[2] + n]);
    }
    for k in 0..n {
        let j = (k + 1) % n;
        faces.push([k, j, j + n]);
        faces.push([k, j + n, k + n]);
    }
    let file_name = format!("{name}.{}", if stl { "stl" } else { "obj" });
    let bytes = if stl {
        let tris: Vec<stl_io::Triangle> = faces
            .iter()
            .map(|f| stl_io::Triangle {
                normal: stl_io::Normal::new([0.0, 0.0, 0.0]),
                vertices: [
                    stl_io::Vertex::new(file_pts[f[0]]),
                    stl_io::Vertex::new(file_pts[f[1]]),
                    stl_io::Vertex::new(file_pts[f[2]]),
                ],
            })
            .collect();
        let mut buf = Vec::new();
        // Writing into a Vec cannot fail.
        let _ = stl_io::write_stl(&mut buf, tris.iter());
        buf
    } else {
        let mut s = format!("# {name}: generated by ecp::stress\n");
        for p in &file_pts {
            let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
        }
        for f in &faces {
            let _ = writeln!(s, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
        }
        s.into_bytes()
    };
    let half = {
        let mut h = Vector3::zeros();
        for v in &verts {
            for k in 0..3 {
                h[k] = f64::max(h[k], v[k].abs());
            }
        }
        h
    };
    let mut pieces = format!("\n[[bodies.pieces]]\nmesh = \"{file_name}\"\n");
    if mm {
        pieces.push_str("scale = 0.001\n");
    }
    Geom {
        kind: format!(
            "mesh-{}-{}{}",
            if n == 6 && triangles_2d.len() == 4 {
                "L"
            } else {
                "prism"
            },
            if stl { "stl" } else { "obj" },
            if mm { "-mm" } else { "" }
        ),
        pieces,
        inertia: ellipsoid_inertia(mass, &(half * 1.2)),
        verts,
        files: vec![(file_name, bytes)],
    }
}

/// One body as the generator writes it.
#[derive(Clone, Debug)]
struct Body {
    name: String,
    mass: f64,
    geom: Geom,
    q: Vector4<f64>,
    x: Vector3<f64>,
    v: Vector3<f64>,
    w: Vector3<f64>,
    /// `(force, torque)` expressions of t.
    load: Option<([String; 3], [String; 3])>,
}

impl Body {
    fn new(name: &str, mass: f64, geom: Geom) -> Self {
        Body {
            name: name.into(),
            mass,
            geom,
            q: Vector4::new(1.0, 0.0, 0.0, 0.0),
            x: Vector3::zeros(),
            v: Vector3::zeros(),
            w: Vector3::zeros(),
            load: None,
        }
    }

    fn rotation(&self) -> Matrix3<f64> {
        quat_to_matrix(&self.q)
    }

    /// Moves the body (keeping its orientation) so that its lowest vertex is exactly `gaps[i]`
    /// above each plane `planes[i]`: `n_i · x + min_v n_i · R v − c_i = gap_i`, solved for the
    /// smallest shift of `x` (along the span of the normals).
    fn place(&mut self, planes: &[&Plane], gaps: &[f64]) {
        let r = self.rotation();
        let k = planes.len();
        let mut a = nalgebra::DMatrix::<f64>::zeros(k, k);
        let mut rhs = nalgebra::DVector::<f64>::zeros(k);
        for i in 0..k {
            for j in 0..k {
                a[(i, j)] = planes[i].normal.dot(&planes[j].normal);
            }
            rhs[i] = gaps[i] + planes[i].offset
                - self.geom.support_min(&r, &planes[i].normal)
                - planes[i].normal.dot(&self.x);
        }
        if let Some(lambda) = a.lu().solve(&rhs) {
            for j in 0..k {
                self.x += planes[j].normal * lambda[j];
            }
        }
    }

    /// The smallest gap of the body to `plane`.
    fn gap(&self, plane: &Plane) -> f64 {
        plane.normal.dot(&self.x) + self.geom.support_min(&self.rotation(), &plane.normal)
            - plane.offset
    }

    fn toml(&self, out: &mut String) {
        let _ = write!(
            out,
            "\n[[bodies]]\nname = \"{}\"   # {}\nmass = {}\ninertia = {}\nposition = {}\n\
             orientation = [{}, {}, {}, {}]\n",
            self.name,
            self.geom.kind,
            num(self.mass),
            self.geom.inertia,
            vec3(&self.x),
            num(self.q[0]),
            num(self.q[1]),
            num(self.q[2]),
            num(self.q[3]),
        );
        if self.v != Vector3::zeros() {
            let _ = writeln!(out, "velocity = {}", vec3(&self.v));
        }
        if self.w != Vector3::zeros() {
            let _ = writeln!(out, "angular_velocity = {}", vec3(&self.w));
        }
        if let Some((f, t)) = &self.load {
            let _ = write!(
                out,
                "\n[bodies.load]\nforce = [{}]\ntorque = [{}]\n",
                f.join(", "),
                t.join(", ")
            );
        }
        out.push_str(&self.geom.pieces);
    }
}

/// A time-varying load component `"A*(1 + B*sin(2*pi*f*t))"` or `"A*sin(pi*t/T)^2"`.
fn wave(rng: &mut SplitMix64, amplitude: f64) -> String {
    let a = round_to(amplitude, 1e-3);
    let f = rng.rounded(0.3, 3.0, 0.1);
    match rng.int(0, 2) {
        0 => format!(
            "\"{}*(1 + {}*sin(2*pi*{}*t))\"",
            num(a),
            num(rng.rounded(0.1, 0.9, 0.1)),
            num(f)
        ),
        1 => format!("\"{}*sin(pi*{}*t)^2\"", num(a), num(f)),
        _ => format!(
            "\"{}*min(1, {}*t)\"",
            num(a),
            num(rng.rounded(1.0, 10.0, 0.5))
        ),
    }
}

/// A yaw (about z) quaternion.
fn yaw(rng: &mut SplitMix64) -> Vector4<f64> {
    axis_angle(&Vector3::z(), rng.range(-3.1, 3.1))
}

/// A random tilt: rotation by `lo..hi` degrees about a horizontal axis, after a random yaw.
fn tilt(rng: &mut SplitMix64, lo: f64, hi: f64) -> Vector4<f64> {
    let (s, c) = det_sin_cos(rng.range(0.0, 2.0 * std::f64::consts::PI));
    let axis = Vector3::new(c, s, 0.0);
    quat_mul(
        &axis_angle(&axis, rng.range(lo, hi).to_radians()),
        &yaw(rng),
    )
}

/// A box or a point set (alternating with `variant`).
fn convex(rng: &mut SplitMix64, mass: f64, variant: usize) -> Geom {
    if variant.is_multiple_of(2) {
        single_box(rng)
    } else {
        point_set(rng, mass)
    }
}

/// Any single-body geometry: box, point set or union (by `variant`).
fn any_shape(rng: &mut SplitMix64, mass: f64, variant: usize) -> Geom {
    match variant % 3 {
        0 => single_box(rng),
        1 => point_set(rng, mass),
        _ => union_shape(UNIONS[(variant / 3) % UNIONS.len()], rng),
    }
}

fn build(name: &str, category: Category, variant: usize, rng: &mut SplitMix64) -> StressScene {
    let h = rng.pick(&[
        0.001, 0.0015, 0.002, 0.0025, 0.003, 0.004, 0.005, 0.006, 0.008, 0.01,
    ]);
    let duration = rng.pick(&[0.5, 0.75, 1.0, 1.25, 1.5, 2.0]);
    let mu = rng.rounded(0.1, 1.2, 0.01);
    let e_r = rng.rounded(0.02, 0.15, 0.005);
    let mass = rng.rounded(0.2, 20.0, 0.1);
    let floor = Plane::floor();
    let mut planes = vec![floor.clone()];
    let mut bodies = Vec::new();
    let mut notes = String::new();
    match category {
        Category::ConvexDrop => {
            let mut b = Body::new("body", mass, convex(rng, mass, variant));
            b.q = tilt(rng, 5.0, 40.0);
            let height = if rng.chance(0.25) {
                0.0
            } else {
                rng.rounded(0.0, 0.15, 0.005)
            };
            if rng.chance(0.4) {
                b.v = Vector3::new(
                    rng.rounded(-0.5, 0.5, 0.05),
                    rng.rounded(-0.5, 0.5, 0.05),
                    0.0,
                );
            }
            b.place(&[&floor], &[height]);
            let _ = write!(notes, "dropped from {height} m with a tilt");
            bodies.push(b);
        }
        Category::ConvexToss => {
            let mut b = Body::new("body", mass, convex(rng, mass, variant));
            let d = rng.direction();
            b.q = axis_angle(&d, rng.range(0.0, 3.1));
            b.v = Vector3::new(
                rng.rounded(-3.0, 3.0, 0.05),
                rng.rounded(-3.0, 3.0, 0.05),
                rng.rounded(-1.0, 2.0, 0.05),
            );
            b.w = rng.direction().map(|c| round_to(c, 1e-3)) * rng.rounded(2.0, 15.0, 0.5);
            b.place(&[&floor], &[rng.rounded(0.02, 0.3, 0.005)]);
            notes.push_str("tossed with spin");
            bodies.push(b);
        }
        Category::ConvexPush => {
            let mut b = Body::new("body", mass, convex(rng, mass, variant));
            b.q = if variant.is_multiple_of(2) {
                yaw(rng)
            } else {
                tilt(rng, 0.0, 30.0)
            };
            b.place(&[&floor], &[0.0]);
            let push = rng.range(0.5, 2.0) * mu * mass * G;
            let fy = if rng.chance(0.5) {
                wave(rng, 0.3 * push)
            } else {
                "0".into()
            };
            let tz = if rng.chance(0.5) {
                wave(rng, 0.2 * push * b.geom.radius())
            } else {
                "0".into()
            };
            b.load = Some((
                [wave(rng, push), fy, "0".into()],
                ["0".into(), "0".into(), tz],
            ));
            notes.push_str("pushed by a time-varying force");
            bodies.push(b);
        }
        Category::UnionRest | Category::UnionSlide | Category::UnionTip => {
            let kind = UNIONS[variant % UNIONS.len()];
            let mut b = Body::new("body", mass, union_shape(kind, rng));
            b.q = yaw(rng);
            b.place(&[&floor], &[0.0]);
            let half = b.geom.half_box();
            match category {
                Category::UnionRest => {
                    if variant % 2 == 1 {
                        let f = rng.range(0.1, 0.5) * mu * mass * G;
                        b.load = Some((
                            [wave(rng, f), wave(rng, 0.5 * f), "0".into()],
                            ["0".into(), "0".into(), "0".into()],
                        ));
                        notes.push_str("resting under a small time-varying load");
                    } else {
                        notes.push_str("resting");
                    }
                }
                Category::UnionSlide => {
                    b.v = Vector3::new(
                        rng.rounded(-2.0, 2.0, 0.05),
                        rng.rounded(-2.0, 2.0, 0.05),
                        0.0,
                    );
                    b.w = Vector3::new(0.0, 0.0, rng.rounded(-4.0, 4.0, 0.1));
                    if variant % 2 == 1 {
                        let f = rng.range(0.2, 1.5) * mu * mass * G;
                        b.load = Some((
                            [wave(rng, f), "0".into(), "0".into()],
                            ["0".into(), "0".into(), wave(rng, 0.2 * f * half.x)],
                        ));
                        notes.push_str("sliding under a time-varying load");
                    } else {
                        notes.push_str("sliding and spinning");
                    }
                }
                _ => {
                    // A torque about a horizontal axis of 0.5–3 times the gravity moment about
                    // the edge of the bounding box, ramped in, plus a push.
                    let tipping = rng.range(0.5, 3.0) * mass * G * half.x.min(half.y);
                    let ty = wave(rng, tipping);
                    let push = rng.range(0.0, 0.8) * mu * mass * G;
                    let fx = wave(rng, push);
                    b.load = Some((
                        [fx, "0".into(), "0".into()],
                        [
                            if rng.chance(0.5) {
                                wave(rng, 0.5 * tipping)
                            } else {
                                "0".into()
                            },
                            ty,
                            "0".into(),
                        ],
                    ));
                    notes.push_str("tipped by a time-varying torque");
                }
            }
            bodies.push(b);
        }
        Category::Incline => {
            let deg = rng.rounded(0.0, 40.0, 0.5);
            let plane = Plane::incline(deg);
            let mut b = Body::new("body", mass, any_shape(rng, mass, variant));
            // Bottom face on the incline: pitch −θ about y, after a yaw.
            b.q = quat_mul(&axis_angle(&Vector3::y(), -deg.to_radians()), &yaw(rng));
            b.place(&[&plane], &[0.0]);
            if rng.chance(0.5) {
                let (s, c) = det_sin_cos(deg.to_radians());
                let speed = rng.rounded(-1.0, 1.5, 0.05);
                b.v = Vector3::new(c, 0.0, s) * speed;
            }
            let _ = write!(notes, "on an incline of {deg}°");
            planes = vec![plane];
            bodies.push(b);
        }
        Category::CornerWall => {
            let wall_x = rng.rounded(0.3, 1.0, 0.01);
            let wall = Plane::wall(-Vector3::x(), Vector3::new(wall_x, 0.0, 0.0));
            let mut b = Body::new("body", mass, any_shape(rng, mass, variant));
            b.q = if rng.chance(0.5) {
                yaw(rng)
            } else {
                tilt(rng, 0.0, 20.0)
            };
            if rng.chance(0.3) {
                // Resting against the wall, pushed into it.
                b.place(&[&floor, &wall], &[0.0, 0.0]);
                let f = rng.range(0.2, 1.0) * mass * G;
                b.load = Some((
                    [wave(rng, f), "0".into(), "0".into()],
                    ["0".into(), "0".into(), "0".into()],
                ));
                notes.push_str("floor and wall: pushed into the wall");
            } else {
                b.place(&[&floor, &wall], &[0.0, rng.rounded(0.02, 0.3, 0.01)]);
                b.v = Vector3::new(
                    rng.rounded(0.5, 2.5, 0.05),
                    rng.rounded(-0.5, 0.5, 0.05),
                    0.0,
                );
                b.w = Vector3::new(0.0, 0.0, rng.rounded(-3.0, 3.0, 0.1));
                notes.push_str("floor and wall: sliding into the wall");
            }
            planes.push(wall);
            bodies.push(b);
        }
        Category::Ladder => {
            let wall_x = rng.rounded(0.3, 1.0, 0.01);
            let wall = Plane::wall(-Vector3::x(), Vector3::new(wall_x, 0.0, 0.0));
            let length = rng.rounded(0.6, 2.0, 0.05);
            let cross = rng.rounded(0.03, 0.1, 0.005);
            let width = rng.rounded(0.2, 0.5, 0.01);
            let geom = if variant.is_multiple_of(2) {
                union_of_boxes(
                    "ladder",
                    &[(Vector3::new(cross, width, length), Vector3::zeros())],
                )
            } else {
                // Two rails and three rungs.
                let mut boxes = vec![
                    (
                        Vector3::new(cross, cross, length),
                        Vector3::new(0.0, -(width - cross) / 2.0, 0.0),
                    ),
                    (
                        Vector3::new(cross, cross, length),
                        Vector3::new(0.0, (width - cross) / 2.0, 0.0),
                    ),
                ];
                for k in [-1.0, 0.0, 1.0] {
                    boxes.push((
                        Vector3::new(cross * 0.6, width - 2.0 * cross, cross * 0.6),
                        Vector3::new(0.0, 0.0, k * length / 4.0),
                    ));
                }
                union_of_boxes("ladder-rungs", &boxes)
            };
            let mut b = Body::new("ladder", mass, geom);
            // Leaning: the top towards +x (the wall), 8–35° from the vertical.
            b.q = axis_angle(&Vector3::y(), rng.range(8.0, 35.0).to_radians());
            b.place(&[&floor, &wall], &[0.0, 0.0]);
            notes.push_str("ladder against a wall");
            planes.push(wall);
            bodies.push(b);
        }
        Category::VTrough => {
            let a1 = rng.rounded(15.0, 60.0, 0.5);
            let a2 = rng.rounded(15.0, 60.0, 0.5);
            let (s1, c1) = det_sin_cos(a1.to_radians());
            let (s2, c2) = det_sin_cos(a2.to_radians());
            let left = Plane::new(Vector3::new(s1, 0.0, c1), 0.0);
            let right = Plane::new(Vector3::new(-s2, 0.0, c2), 0.0);
            let mut b = Body::new("body", mass, any_shape(rng, mass, variant));
            b.q = if rng.chance(0.5) {
                yaw(rng)
            } else {
                tilt(rng, 0.0, 30.0)
            };
            b.place(&[&left, &right], &[0.0, 0.0]);
            if rng.chance(0.5) {
                b.x.z += rng.rounded(0.0, 0.2, 0.005);
            }
            if rng.chance(0.3) {
                b.v = Vector3::new(0.0, rng.rounded(-1.0, 1.0, 0.05), 0.0);
            }
            let _ = write!(notes, "V trough, sides {a1}° and {a2}°");
            planes = vec![left, right];
            bodies.push(b);
        }
        Category::RoomCorner => {
            let wx = Plane::wall(
                -Vector3::x(),
                Vector3::new(rng.rounded(0.2, 1.0, 0.01), 0.0, 0.0),
            );
            let wy = Plane::wall(
                -Vector3::y(),
                Vector3::new(0.0, rng.rounded(0.2, 1.0, 0.01), 0.0),
            );
            let mut b = Body::new("body", mass, any_shape(rng, mass, variant));
            b.q = if rng.chance(0.5) {
                yaw(rng)
            } else {
                tilt(rng, 0.0, 25.0)
            };
            if rng.chance(0.4) {
                b.place(&[&floor, &wx, &wy], &[0.0, 0.0, 0.0]);
                notes.push_str("room corner: resting in the corner");
            } else {
                b.place(
                    &[&floor, &wx, &wy],
                    &[
                        rng.rounded(0.0, 0.2, 0.005),
                        rng.rounded(0.02, 0.2, 0.01),
                        rng.rounded(0.02, 0.2, 0.01),
                    ],
                );
                b.v = Vector3::new(
                    rng.rounded(0.3, 2.0, 0.05),
                    rng.rounded(0.3, 2.0, 0.05),
                    0.0,
                );
                b.w = rng.direction().map(|c| round_to(c, 1e-3)) * rng.rounded(0.0, 6.0, 0.5);
                notes.push_str("room corner: tossed into the corner");
            }
            planes.push(wx);
            planes.push(wy);
            bodies.push(b);
        }
        Category::Mesh => {
            let geom = mesh_shape(name, rng, mass, variant);
            let mut b = Body::new("body", mass, geom);
            match variant % 3 {
                0 => {
                    b.q = tilt(rng, 5.0, 35.0);
                    b.place(&[&floor], &[rng.rounded(0.0, 0.15, 0.005)]);
                    notes.push_str("mesh dropped from a tilt");
                }
                1 => {
                    b.q = yaw(rng);
                    b.place(&[&floor], &[0.0]);
                    let push = rng.range(0.5, 2.0) * mu * mass * G;
                    b.load = Some((
                        [wave(rng, push), "0".into(), "0".into()],
                        ["0".into(), "0".into(), "0".into()],
                    ));
                    notes.push_str("mesh pushed");
                }
                _ => {
                    b.q = yaw(rng);
                    b.place(&[&floor], &[0.0]);
                    b.v = Vector3::new(
                        rng.rounded(-2.0, 2.0, 0.05),
                        rng.rounded(-2.0, 2.0, 0.05),
                        0.0,
                    );
                    b.w = Vector3::new(0.0, 0.0, rng.rounded(-5.0, 5.0, 0.1));
                    notes.push_str("mesh sliding and spinning");
                }
            }
            bodies.push(b);
        }
        Category::MultiBody => {
            let n = rng.int(2, 4);
            for k in 0..n {
                let m = rng.rounded(0.2, 20.0, 0.1);
                let mut b = Body::new(&format!("body{k}"), m, any_shape(rng, m, variant + k));
                // Lanes 1.5 m apart along y: the bodies do not meet (bodies do not collide
                // with each other in this model, only with the half-spaces).
                let lane = Vector3::new(0.0, 1.5 * k as f64, 0.0);
                b.x = lane;
                match rng.int(0, 3) {
                    0 => {
                        b.q = tilt(rng, 5.0, 30.0);
                        b.place(&[&floor], &[rng.rounded(0.0, 0.15, 0.005)]);
                    }
                    1 => {
                        b.q = yaw(rng);
                        b.place(&[&floor], &[0.0]);
                        b.v = Vector3::new(rng.rounded(-1.5, 1.5, 0.05), 0.0, 0.0);
                    }
                    2 => {
                        b.q = yaw(rng);
                        b.place(&[&floor], &[0.0]);
                        let push = rng.range(0.5, 1.5) * mu * m * G;
                        b.load = Some((
                            [wave(rng, push), "0".into(), "0".into()],
                            ["0".into(), "0".into(), "0".into()],
                        ));
                    }
                    _ => {
                        b.q = yaw(rng);
                        b.place(&[&floor], &[0.0]);
                    }
                }
                bodies.push(b);
            }
            let _ = write!(notes, "{n} separate bodies");
        }
    }

    let unforced = bodies.iter().all(|b| b.load.is_none());
    let mut toml = format!(
        "# Stress scene {name} ({category}): {notes}.\n# Generated by ecp::stress::generate; \
         see docs/stress.md.\nname = \"{name}\"\n\n[simulation]\nh = {}\nduration = {}\n\n\
         [friction]\nmu = {}\ne_r = {}\n",
        num(h),
        num(duration),
        num(mu),
        num(e_r)
    );
    for p in &planes {
        p.toml(&mut toml);
    }
    let mut files = Vec::new();
    for b in &bodies {
        debug_assert!(
            planes.iter().all(|p| b.gap(p) >= -1e-12),
            "{name}: body {} starts inside a plane",
            b.name
        );
        b.toml(&mut toml);
        files.extend(b.geom.files.iter().cloned());
    }
    StressScene {
        name: name.to_string(),
        category,
        toml,
        files,
        unforced,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn det_sin_cos_matches_std() {
        // The generator's angles are within ±2π (the range reduction by one constant π/2 loses
        // about k ulps of π/2 further out).
        for k in -85..=85 {
            let x = k as f64 * 0.0731;
            let (s, c) = det_sin_cos(x);
            assert!((s - x.sin()).abs() <= 4e-16, "sin {x}: {s} vs {}", x.sin());
            assert!((c - x.cos()).abs() <= 4e-16, "cos {x}: {c} vs {}", x.cos());
        }
    }

    #[test]
    fn splitmix_reference_values() {
        // The first outputs of SplitMix64 from seed 0 (the reference implementation's).
        let mut r = SplitMix64::new(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
    }
}
