//! Mesh files (OBJ with tobj, STL with stl_io) as point sets: only the vertices matter, because
//! the contact model uses the convex hull of each piece.

use std::io::Cursor;
use std::path::Path;

use nalgebra::Vector3;

/// Reads the vertices of an OBJ or STL file (chosen by extension, case-insensitive).
/// The error is a sentence a user can act on; the caller adds the file and key.
pub fn read_mesh_vertices(path: &Path) -> Result<Vec<Vector3<f64>>, String> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let bytes = std::fs::read(path)
        .map_err(|e| format!("cannot read the mesh file {}: {e}", path.display()))?;
    let points = match ext.as_str() {
        "obj" => read_obj(&bytes),
        "stl" => read_stl(&bytes),
        _ => Err(format!(
            "the mesh file {} has an unknown extension; use a .obj or .stl file",
            path.display()
        )),
    }?;
    if let Some(i) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(format!(
            "vertex {i} of the mesh file {} is not finite",
            path.display()
        ));
    }
    Ok(points)
}

fn read_obj(bytes: &[u8]) -> Result<Vec<Vector3<f64>>, String> {
    let mut reader = Cursor::new(bytes);
    // Materials are irrelevant for contact; refuse to open .mtl files.
    let (models, _materials) =
        tobj::load_obj_buf(&mut reader, &tobj::LoadOptions::default(), |_| {
            Err(tobj::LoadError::OpenFileFailed)
        })
        .map_err(|e| format!("the OBJ file does not parse: {e}"))?;
    let points: Vec<Vector3<f64>> = models
        .iter()
        .flat_map(|m| {
            m.mesh
                .positions
                .chunks_exact(3)
                .map(|c| Vector3::new(f64::from(c[0]), f64::from(c[1]), f64::from(c[2])))
        })
        .collect();
    if points.is_empty() {
        return Err("the OBJ file has no vertices (no `v` lines used by a face)".into());
    }
    Ok(points)
}

fn read_stl(bytes: &[u8]) -> Result<Vec<Vector3<f64>>, String> {
    let mut reader = Cursor::new(bytes);
    let mesh = stl_io::read_stl(&mut reader)
        .map_err(|e| format!("the STL file does not parse (binary or ASCII STL expected): {e}"))?;
    if mesh.vertices.is_empty() {
        return Err("the STL file has no vertices".into());
    }
    Ok(mesh
        .vertices
        .iter()
        .map(|v| Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2])))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    const CUBE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
        f 1 2 3 4\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";

    #[test]
    fn obj_cube_vertices() {
        let p = read_obj(CUBE_OBJ.as_bytes()).expect("parses");
        assert!(p.len() >= 8);
        assert!(
            p.iter()
                .any(|v| (v - Vector3::new(1.0, 1.0, 1.0)).norm() == 0.0)
        );
    }

    #[test]
    fn stl_round_trip() {
        let tri = stl_io::Triangle {
            normal: stl_io::Normal::new([0.0, 0.0, 1.0]),
            vertices: [
                stl_io::Vertex::new([0.0, 0.0, 0.0]),
                stl_io::Vertex::new([1.0, 0.0, 0.0]),
                stl_io::Vertex::new([0.0, 1.0, 0.5]),
            ],
        };
        let mut buf = Vec::new();
        stl_io::write_stl(&mut buf, [tri].iter()).expect("writes");
        let p = read_stl(&buf).expect("reads");
        assert_eq!(p.len(), 3);
        assert_eq!(p[2], Vector3::new(0.0, 1.0, 0.5));
    }

    #[test]
    fn garbage_is_an_error() {
        assert!(read_stl(b"not an stl").is_err());
        assert!(read_obj(b"v 1 2\nf 1 2 3\n").is_err());
    }
}
