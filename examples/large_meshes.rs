//! Writes large OBJ and STL meshes and a scene file for each into a directory, for measuring
//! `ecp check` on them (`docs/input.md`):
//!
//! - `ellipsoid_N.{obj,stl}`: a latitude–longitude ellipsoid with about N vertices, every one an
//!   extreme point (refused above the hull size limit);
//! - `box_N.{obj,stl}`: a 0.4 × 0.3 × 0.2 m box given by its 8 corners, N interior points and
//!   every vertex repeated (the hull is the box);
//! - `tiled_box_N.obj`: the same box with each face tiled into a grid, about N vertices all on
//!   the surface (the hull is the box).
//!
//! It also prints the time `ConvexHull::from_points` takes on each mesh's vertices (as read, with
//! their repetitions), the hull stage of `ecp check` without the file parsing.
//!
//! `cargo run --release --example large_meshes -- DIR [N ...]` (default N: 100000 1000000), then
//! e.g. `time target/release/ecp check DIR/box_1000000_obj.toml`.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::time::Instant;

use ecp::formulations::geometry::ConvexHull;
use nalgebra::Vector3;

type Tri = [[f32; 3]; 3];

/// A latitude–longitude ellipsoid with semi-axes (0.1, 0.08, 0.06) m and about `n` vertices.
fn ellipsoid(n: usize) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let rows = ((n as f64 / 2.0).sqrt() as usize).max(3);
    let cols = 2 * rows;
    let mut v = vec![[0.0, 0.0, 0.06], [0.0, 0.0, -0.06]];
    for r in 1..rows {
        let th = std::f64::consts::PI * r as f64 / rows as f64;
        for c in 0..cols {
            let ph = 2.0 * std::f64::consts::PI * c as f64 / cols as f64;
            v.push([
                (0.1 * th.sin() * ph.cos()) as f32,
                (0.08 * th.sin() * ph.sin()) as f32,
                (0.06 * th.cos()) as f32,
            ]);
        }
    }
    let at = |r: usize, c: usize| 2 + (r - 1) * cols + c % cols;
    let mut f = Vec::new();
    for c in 0..cols {
        f.push([0, at(1, c), at(1, c + 1)]);
        f.push([1, at(rows - 1, c + 1), at(rows - 1, c)]);
    }
    for r in 1..rows - 1 {
        for c in 0..cols {
            f.push([at(r, c), at(r + 1, c), at(r + 1, c + 1)]);
            f.push([at(r, c), at(r + 1, c + 1), at(r, c + 1)]);
        }
    }
    (v, f)
}

/// The box's 8 corners and `n` pseudo-random interior points, each listed twice; the faces are
/// consecutive triples (they only have to use every vertex).
fn box_with_interior(n: usize) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let h = [0.2f32, 0.15, 0.1];
    let mut v = Vec::with_capacity(2 * (n + 8));
    for i in 0..8 {
        v.push([
            if i & 1 == 0 { -h[0] } else { h[0] },
            if i & 2 == 0 { -h[1] } else { h[1] },
            if i & 4 == 0 { -h[2] } else { h[2] },
        ]);
    }
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 / (1u64 << 53) as f64) as f32 * 1.98 - 0.99
    };
    for _ in 0..n {
        v.push([uniform() * h[0], uniform() * h[1], uniform() * h[2]]);
    }
    let copy = v.clone();
    v.extend(copy);
    let f = (0..v.len() / 3)
        .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
        .chain([[v.len() - 3, v.len() - 2, v.len() - 1]])
        .collect();
    (v, f)
}

/// The same box with each face tiled into a `k × k` grid of squares (about `6 k²` vertices).
fn tiled_box(n: usize) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let k = ((n as f64 / 6.0).sqrt() as usize).max(1);
    let h = [0.2f32, 0.15, 0.1];
    let (mut v, mut f) = (Vec::new(), Vec::new());
    for axis in 0..3 {
        for side in [-1.0f32, 1.0] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = v.len();
            for i in 0..=k {
                for j in 0..=k {
                    let mut p = [0.0f32; 3];
                    p[axis] = side * h[axis];
                    p[a] = h[a] * (2.0 * i as f32 / k as f32 - 1.0);
                    p[b] = h[b] * (2.0 * j as f32 / k as f32 - 1.0);
                    v.push(p);
                }
            }
            let at = |i: usize, j: usize| base + i * (k + 1) + j;
            for i in 0..k {
                for j in 0..k {
                    f.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                    f.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
                }
            }
        }
    }
    (v, f)
}

fn write_obj(path: &Path, v: &[[f32; 3]], f: &[[usize; 3]]) -> std::io::Result<()> {
    let mut s = String::with_capacity(40 * (v.len() + f.len()));
    for p in v {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for t in f {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fs::write(path, s)
}

fn write_stl(path: &Path, v: &[[f32; 3]], f: &[[usize; 3]]) -> std::io::Result<()> {
    let tris: Vec<Tri> = f.iter().map(|t| t.map(|i| v[i])).collect();
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    out.write_all(&[0u8; 80])?;
    out.write_all(&(tris.len() as u32).to_le_bytes())?;
    for t in &tris {
        out.write_all(&[0u8; 12])?;
        for p in t {
            for c in p {
                out.write_all(&c.to_le_bytes())?;
            }
        }
        out.write_all(&[0u8; 2])?;
    }
    out.flush()
}

fn write_scene(dir: &Path, mesh: &str) -> std::io::Result<()> {
    let scene = format!(
        "[simulation]\nh = 0.01\nduration = 0.1\n[friction]\nmu = 0.3\ne_r = 0.1\n\
         [[half_spaces]]\nnormal = [0, 0, 1]\n[[bodies]]\nmass = 1\n\
         inertia = [0.01, 0.01, 0.01]\nposition = [0, 0, 0.5]\n[[bodies.pieces]]\n\
         mesh = \"{mesh}\"\n"
    );
    std::fs::write(dir.join(format!("{}.toml", mesh.replace('.', "_"))), scene)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = args
        .next()
        .ok_or("usage: large_meshes DIR [N ...] (N: vertices, default 100000 1000000)")?;
    let dir = Path::new(&dir);
    std::fs::create_dir_all(dir)?;
    let mut sizes: Vec<usize> = args
        .map(|a| a.parse())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("N must be a whole number: {e}"))?;
    if sizes.is_empty() {
        sizes = vec![100_000, 1_000_000];
    }
    for n in sizes {
        for (name, (v, f)) in [
            ("ellipsoid", ellipsoid(n)),
            ("box", box_with_interior(n)),
            ("tiled_box", tiled_box(n)),
        ] {
            for ext in ["obj", "stl"] {
                let file = format!("{name}_{n}.{ext}");
                if ext == "obj" {
                    write_obj(&dir.join(&file), &v, &f)?;
                } else {
                    write_stl(&dir.join(&file), &v, &f)?;
                }
                write_scene(dir, &file)?;
                println!("{file}: {} vertices, {} triangles", v.len(), f.len());
            }
            // The vertices as an STL reader sees them: three per triangle.
            let soup: Vec<Vector3<f64>> = f
                .iter()
                .flat_map(|t| t.map(|i| v[i].map(f64::from).into()))
                .collect();
            let started = Instant::now();
            let hull = ConvexHull::from_points(&soup);
            let took = started.elapsed().as_secs_f64();
            match hull {
                Ok(h) => println!(
                    "  hull of {} points: {} vertices, {} faces in {took:.3} s",
                    soup.len(),
                    h.vertices().len(),
                    h.num_faces()
                ),
                Err(e) => println!(
                    "  hull of {} points refused in {took:.3} s: {e}",
                    soup.len()
                ),
            }
        }
    }
    Ok(())
}
