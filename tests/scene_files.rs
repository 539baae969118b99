//! Scene-file features beyond the reference scenes: meshes (OBJ, STL), uniform-density inertia
//! with re-centring, point-set pieces, orientations, several bodies and half-spaces.

use std::path::{Path, PathBuf};

use ecp::formulations::geometry::{MassProperties, Shape};
use ecp::scene::{load_scene, parse_scene};
use nalgebra::Vector3;

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ecp-scene-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

const HEAD: &str = "[simulation]\nh = 0.01\nduration = 0.03\n[friction]\nmu = 0.3\ne_r = 0.1\n\
                    [[half_spaces]]\nnormal = [0, 0, 1]\n";

fn has_vertex(shape: &Shape, v: Vector3<f64>, tol: f64) -> bool {
    shape.vertices().iter().any(|w| (w - v).amax() <= tol)
}

#[test]
fn obj_and_stl_meshes_become_convex_pieces() {
    let dir = temp_dir("mesh");
    // A 0.2 m cube with its centre at the origin, as OBJ (quads) and as STL (triangles).
    let corners: Vec<[f32; 3]> = (0..8)
        .map(|i| {
            [
                if i & 1 == 0 { -0.1 } else { 0.1 },
                if i & 2 == 0 { -0.1 } else { 0.1 },
                if i & 4 == 0 { -0.1 } else { 0.1 },
            ]
        })
        .collect();
    let mut obj = String::new();
    for c in &corners {
        obj.push_str(&format!("v {} {} {}\n", c[0], c[1], c[2]));
    }
    obj.push_str("f 1 2 4 3\nf 5 6 8 7\nf 1 2 6 5\nf 3 4 8 7\nf 1 3 7 5\nf 2 4 8 6\n");
    std::fs::write(dir.join("cube.obj"), obj).expect("obj");
    let tris = [
        [0, 1, 3],
        [0, 3, 2],
        [4, 5, 7],
        [4, 7, 6],
        [0, 1, 5],
        [0, 5, 4],
        [2, 3, 7],
        [2, 7, 6],
        [0, 2, 6],
        [0, 6, 4],
        [1, 3, 7],
        [1, 7, 5],
    ];
    let triangles: Vec<stl_io::Triangle> = tris
        .iter()
        .map(|t| stl_io::Triangle {
            normal: stl_io::Normal::new([0.0, 0.0, 0.0]),
            vertices: t.map(|i| stl_io::Vertex::new(corners[i])),
        })
        .collect();
    let mut stl = std::fs::File::create(dir.join("cube.stl")).expect("stl");
    stl_io::write_stl(&mut stl, triangles.iter()).expect("write stl");
    for (file, extra) in [
        ("cube.obj", ""),
        ("cube.stl", ""),
        ("cube.obj", "scale = 2.0\n"),
    ] {
        let text = format!(
            "{HEAD}[[bodies]]\nmass = 1\ninertia = [0.01, 0.01, 0.01]\nposition = [0, 0, 0.5]\n\
             [[bodies.pieces]]\nmesh = \"{file}\"\n{extra}"
        );
        let path = dir.join("mesh_scene.toml");
        std::fs::write(&path, text).expect("scene");
        let loaded = match load_scene(&path) {
            Ok(f) => f,
            Err(e) => panic!("{file}: {e}"),
        };
        let shape = &loaded.scene.bodies[0].shape;
        let half = if extra.is_empty() { 0.1 } else { 0.2 };
        assert_eq!(shape.vertices().len(), 8, "{file} {extra}");
        assert!(
            has_vertex(shape, Vector3::new(half, half, half), 1e-7),
            "{file} {extra}"
        );
        let hull = shape.hull().expect("hull");
        assert_eq!(
            hull.num_faces(),
            6,
            "{file}: coplanar triangles merge into 6 faces"
        );
    }
    // A mesh that is not there is a mesh error naming the key.
    let text = format!(
        "{HEAD}[[bodies]]\nmass = 1\ninertia = [0.01, 0.01, 0.01]\nposition = [0, 0, 0.5]\n\
         [[bodies.pieces]]\nmesh = \"missing.stl\"\n"
    );
    let e = parse_scene(&text, &dir.join("x.toml")).expect_err("missing mesh");
    assert!(e.to_string().contains("bodies[0].pieces[0].mesh"), "{e}");
    assert!(e.to_string().contains("missing.stl"), "{e}");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn uniform_inertia_recentres_the_t_bar_on_its_centre_of_mass() {
    // The T-bar of `docs/model.md#scenarios`, given in a frame with the crossbar's outer edge at x
    // = 0.
    let text = format!(
        "{HEAD}[[bodies]]\nname = \"tbar\"\nmass = 2\ninertia = \"uniform\"\nposition = [0, 0, 0.025]\n\
         [[bodies.pieces]]\nbox = [0.05, 0.20, 0.05]\ncenter = [0.025, 0, 0]\n\
         [[bodies.pieces]]\nbox = [0.15, 0.05, 0.05]\ncenter = [0.125, 0, 0]\n"
    );
    let file = parse_scene(&text, Path::new("tbar.toml")).expect("valid");
    let body = &file.scene.bodies[0];
    let want = MassProperties::t_bar(2.0).expect("t-bar");
    assert!((body.mass.inertia - want.inertia).amax() <= 1e-14);
    let reference = Shape::t_bar();
    assert_eq!(body.shape.vertices().len(), reference.vertices().len());
    for v in reference.vertices() {
        assert!(has_vertex(&body.shape, *v, 1e-14), "vertex {v}");
    }
    // CM 0.0679 m from the crossbar's outer edge (`docs/model.md#scenarios`).
    let min_x = body
        .shape
        .vertices()
        .iter()
        .map(|v| v.x)
        .fold(f64::INFINITY, f64::min);
    assert!((min_x + 0.0679).abs() < 1e-4, "outer edge at {min_x}");
    assert_eq!(body.shape.hull().expect("hull").num_faces(), 8);
}

#[test]
fn uniform_inertia_refuses_rotated_boxes_and_point_sets() {
    let text = format!(
        "{HEAD}[[bodies]]\nmass = 1\ninertia = \"uniform\"\nposition = [0, 0, 1]\n\
         [[bodies.pieces]]\nbox = [0.1, 0.1, 0.1]\nrpy_deg = [0, 0, 30]\n"
    );
    let e = parse_scene(&text, Path::new("x.toml")).expect_err("rotated box");
    assert!(e.to_string().contains("bodies[0].inertia"), "{e}");
    assert_eq!(e.line, Some(11));
}

#[test]
fn point_sets_orientations_and_several_bodies_and_planes() {
    let text = format!(
        "{HEAD}[[half_spaces]]\nnormal = [1, 0, 0]\noffset = -2\n\
         [[bodies]]\nname = \"tetra\"\nmass = 1\ninertia = [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]]\n\
         position = [0, 0, 1]\norientation = [2, 0, 0, 0]\n\
         [[bodies.pieces]]\npoints = [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]\n\
         center = [0, 0, 0.5]\nrpy_deg = [0, 0, 90]\n\
         [[bodies]]\nname = \"box\"\nmass = 1\ninertia = \"uniform\"\nposition = [1, 0, 1]\n\
         [[bodies.pieces]]\nbox = [0.1, 0.2, 0.3]\n"
    );
    let file = parse_scene(&text, Path::new("two.toml")).expect("valid");
    let s = &file.scene;
    assert_eq!((s.bodies.len(), s.planes.len()), (2, 2));
    // Quaternions are normalised.
    assert_eq!(
        s.bodies[0].initial.q,
        nalgebra::Vector4::new(1.0, 0.0, 0.0, 0.0)
    );
    // The point (0.1, 0, 0) turned by 90° about z and offset by (0, 0, 0.5).
    assert!(has_vertex(
        &s.bodies[0].shape,
        Vector3::new(0.0, 0.1, 0.5),
        1e-15
    ));
    assert!((s.planes[1].offset() + 2.0).abs() < 1e-15);
    // Two bodies against two planes: suffixed CSV columns.
    let header = ecp::formulations::StepRecord::csv_header(2, 2);
    assert!(header.contains(&"pn_b1_c1".to_string()));
    // Duplicate names are refused.
    let dup = text.replace("name = \"box\"", "name = \"tetra\"");
    let e = parse_scene(&dup, Path::new("two.toml")).expect_err("duplicate");
    assert!(e.to_string().contains("two bodies are named"), "{e}");
}

#[test]
fn loads_must_be_finite_at_every_step_time() {
    let text = format!(
        "{HEAD}[[bodies]]\nmass = 1\ninertia = [0.01, 0.01, 0.01]\nposition = [0, 0, 1]\n\
         [[bodies.pieces]]\nbox = [0.1, 0.1, 0.1]\n[bodies.load]\ntorque = [0, 0, \"1/(t - 0.02)\"]\n"
    );
    let e = parse_scene(&text, Path::new("x.toml")).expect_err("singular at t = 0.02");
    let msg = e.to_string();
    assert!(
        msg.contains("bodies[0].load.torque") && msg.contains("t = 0.02"),
        "{msg}"
    );
    // The same load is fine when the run ends before t = 0.02.
    let short = text.replace("duration = 0.03", "duration = 0.02");
    assert!(parse_scene(&short, Path::new("x.toml")).is_ok());
}

/// Writes `v` and the triangles `f` as an OBJ file and as a binary STL file.
fn write_obj_and_stl(dir: &Path, stem: &str, v: &[[f32; 3]], f: &[[usize; 3]]) {
    let mut obj = String::new();
    for p in v {
        obj.push_str(&format!("v {} {} {}\n", p[0], p[1], p[2]));
    }
    for t in f {
        obj.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    std::fs::write(dir.join(format!("{stem}.obj")), obj).expect("obj");
    let triangles: Vec<stl_io::Triangle> = f
        .iter()
        .map(|t| stl_io::Triangle {
            normal: stl_io::Normal::new([0.0, 0.0, 0.0]),
            vertices: t.map(|i| stl_io::Vertex::new(v[i])),
        })
        .collect();
    let mut stl = std::fs::File::create(dir.join(format!("{stem}.stl"))).expect("stl");
    stl_io::write_stl(&mut stl, triangles.iter()).expect("write stl");
}

fn mesh_scene(dir: &Path, file: &str) -> PathBuf {
    let text = format!(
        "{HEAD}[[bodies]]\nmass = 1\ninertia = [0.01, 0.01, 0.01]\nposition = [0, 0, 0.5]\n\
         [[bodies.pieces]]\nmesh = \"{file}\"\n"
    );
    let path = dir.join(format!("{}.toml", file.replace('.', "_")));
    std::fs::write(&path, text).expect("scene");
    path
}

#[test]
fn large_meshes_are_pruned_to_their_hull_or_refused() {
    let dir = temp_dir("large-mesh");
    // A 0.4 × 0.3 × 0.2 m box: its 8 corners, 100 000 interior points, every vertex twice.
    let h = [0.2f32, 0.15, 0.1];
    let mut v: Vec<[f32; 3]> = (0..8)
        .map(|i| {
            [
                if i & 1 == 0 { -h[0] } else { h[0] },
                if i & 2 == 0 { -h[1] } else { h[1] },
                if i & 4 == 0 { -h[2] } else { h[2] },
            ]
        })
        .collect();
    let mut state = 1u64;
    let mut uniform = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 / (1u64 << 53) as f64) as f32 * 1.98 - 0.99
    };
    for _ in 0..100_000 {
        v.push([uniform() * h[0], uniform() * h[1], uniform() * h[2]]);
    }
    let copy = v.clone();
    v.extend(copy);
    let f: Vec<[usize; 3]> = (0..v.len() / 3)
        .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
        .chain([[v.len() - 3, v.len() - 2, v.len() - 1]])
        .collect();
    write_obj_and_stl(&dir, "box", &v, &f);
    for file in ["box.obj", "box.stl"] {
        let loaded = load_scene(&mesh_scene(&dir, file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        let shape = &loaded.scene.bodies[0].shape;
        assert_eq!(shape.vertices().len(), 8, "{file}");
        for c in &v[..8] {
            let c = Vector3::new(f64::from(c[0]), f64::from(c[1]), f64::from(c[2]));
            assert!(has_vertex(shape, c, 0.0), "{file}: corner {c:?}");
        }
        let hull = shape.hull().expect("hull");
        assert_eq!(hull.num_faces(), 6, "{file}");
        let volume = 8.0 * f64::from(h[0]) * f64::from(h[1]) * f64::from(h[2]);
        assert!((hull.volume() - volume).abs() < 1e-12, "{file}");
    }

    // An ellipsoid whose every vertex is an extreme point, above the limit: a mesh error that
    // names the file, the key and how to fix it.
    let rows = 40;
    let cols = 80;
    let mut e: Vec<[f32; 3]> = vec![[0.0, 0.0, 0.06], [0.0, 0.0, -0.06]];
    for r in 1..rows {
        let th = std::f64::consts::PI * r as f64 / rows as f64;
        for c in 0..cols {
            let ph = 2.0 * std::f64::consts::PI * c as f64 / cols as f64;
            e.push([
                (0.1 * th.sin() * ph.cos()) as f32,
                (0.08 * th.sin() * ph.sin()) as f32,
                (0.06 * th.cos()) as f32,
            ]);
        }
    }
    let faces: Vec<[usize; 3]> = (0..e.len() / 3)
        .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
        .chain([[e.len() - 3, e.len() - 2, e.len() - 1]])
        .collect();
    assert!(e.len() > ecp::formulations::geometry::MAX_HULL_POINTS);
    write_obj_and_stl(&dir, "ellipsoid", &e, &faces);
    for file in ["ellipsoid.obj", "ellipsoid.stl"] {
        let err = load_scene(&mesh_scene(&dir, file)).expect_err("too many hull vertices");
        let msg = err.to_string();
        for part in [
            "bodies[0].pieces[0].mesh",
            "line",
            &format!("{}", e.len()),
            "at most 2000",
            "decimate",
        ] {
            assert!(msg.contains(part), "{file}: `{part}` missing from: {msg}");
        }
    }
    let _ = std::fs::remove_dir_all(dir);
}

mod no_panic {
    use super::*;
    use proptest::prelude::*;

    const A1: &str = include_str!("../scenes/a1_sliding.toml");
    const DESK: &str = include_str!("../scenes/desk.toml");

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// Random edits of valid scene files give a scene or an error, never a panic.
        #[test]
        fn edited_scene_files_never_panic(
            desk in any::<bool>(),
            edits in proptest::collection::vec((any::<prop::sample::Index>(), 0usize..3, "[-+*/^()\\[\\]=,.\"0-9a-z tnp#\n]{0,3}"), 1..6),
        ) {
            let mut text = if desk { DESK } else { A1 }.to_string();
            for (at, op, s) in edits {
                let chars: Vec<char> = text.chars().collect();
                let i = at.index(chars.len() + 1);
                let j = (i + op).min(chars.len());
                let mut out: String = chars[..i].iter().collect();
                out.push_str(&s);
                out.extend(&chars[j..]);
                text = out;
            }
            let _ = parse_scene(&text, Path::new("edited.toml"));
        }

        /// Number-heavy expressions (scientific notation, stray exponents) never panic either.
        #[test]
        fn scientific_notation_never_panics(expr in "[-+0-9eE.*t()]{0,16}") {
            let _ = ecp::scene::TimeExpression::parse(&expr).map(|e| e.eval(0.5));
        }

        /// Arbitrary load expressions parse or are refused, never panic, and loaded loads are finite.
        #[test]
        fn load_expressions_never_panic(expr in "[-+*/^()0-9a-z. ,]{0,24}") {
            let text = format!(
                "{HEAD}[[bodies]]\nmass = 1\ninertia = [0.01, 0.01, 0.01]\nposition = [0, 0, 1]\n\
                 [[bodies.pieces]]\nbox = [0.1, 0.1, 0.1]\n[bodies.load]\nforce = [\"{expr}\", 0, 0]\n"
            );
            if let Ok(file) = parse_scene(&text, Path::new("x.toml")) {
                for k in 0..3 {
                    prop_assert!(file.scene.bodies[0].load.at(k as f64 * 0.01).iter().all(|v| v.is_finite()));
                }
            }
        }
    }
}
