//! Mesh output besides GLB: binary PLY, Wavefront OBJ and binary STL, for the tools scan users
//! already have (MeshLab, CloudCompare, slicers). The format follows the file name's extension
//! ([`MeshFormat::from_path`]).
//!
//! Each writer takes the same [`Mesh`] the GLB writer takes (positions, unit vertex normals,
//! optional RGBA colours, counter-clockwise triangles seen from outside) and keeps everything
//! the format can hold: PLY keeps normals and colours, OBJ keeps normals, STL only has per-face
//! normals (computed from the triangle, or the vertices' mean for a degenerate one). Writers
//! never fail on content; they check only that indices are in range and counts fit the format.

use crate::mesh::Mesh;

/// The mesh file formats `nkrr reconstruct -o` can write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    Glb,
    Ply,
    Obj,
    Stl,
}

impl MeshFormat {
    /// The format named by a path's extension (case-insensitive), or None.
    pub fn from_path(path: &str) -> Option<MeshFormat> {
        Self::from_extension(std::path::Path::new(path).extension()?.to_str()?)
    }

    /// The format named by an extension without the dot ("glb", "PLY", …), or None.
    pub fn from_extension(ext: &str) -> Option<MeshFormat> {
        match ext.to_ascii_lowercase().as_str() {
            "glb" => Some(MeshFormat::Glb),
            "ply" => Some(MeshFormat::Ply),
            "obj" => Some(MeshFormat::Obj),
            "stl" => Some(MeshFormat::Stl),
            _ => None,
        }
    }
}

/// A written mesh file and what it holds.
pub struct Written {
    pub bytes: Vec<u8>,
    pub vertices: usize,
    pub triangles: usize,
}

/// `mesh` as a file of `format`: the one dispatch the CLI's `-o` and the page's downloads share.
/// `translation` is a far-off cloud's origin: GLB keeps it as the root node's translation (f64);
/// the other formats have none, so it is added to their positions (in f64, then rounded to
/// f32, losing precision there). `name` names the glTF node; `comment` heads the other formats;
/// `compression` is the GLB's (the other formats have none).
pub fn write(
    format: MeshFormat,
    mesh: &Mesh,
    name: Option<String>,
    translation: Option<[f64; 3]>,
    comment: &str,
    compression: crate::io::gltf::Compression,
) -> Result<Written, String> {
    if format == MeshFormat::Glb {
        let (bytes, r) = crate::io::gltf::write_glb_with_report(mesh, &crate::io::gltf::GlbOptions { name, translation, compression })
            .map_err(|e| e.to_string())?;
        return Ok(Written { bytes, vertices: r.vertices_written, triangles: r.triangles_written });
    }
    let moved;
    let mesh = match translation {
        Some(t) => {
            let mut m = mesh.clone();
            for p in &mut m.positions {
                *p = [0, 1, 2].map(|k| (p[k] as f64 + t[k]) as f32);
            }
            moved = m;
            &moved
        }
        None => mesh,
    };
    let bytes = match format {
        MeshFormat::Ply => write_ply(mesh, comment)?,
        MeshFormat::Obj => write_obj(mesh, comment)?,
        _ => write_stl(mesh, comment)?,
    };
    Ok(Written { bytes, vertices: mesh.vertex_count(), triangles: mesh.indices.len() / 3 })
}

fn check(mesh: &Mesh) -> Result<(), String> {
    if mesh.indices.len() % 3 != 0 {
        return Err(format!("{} indices is not a multiple of 3", mesh.indices.len()));
    }
    let n = mesh.positions.len();
    if let Some(&i) = mesh.indices.iter().find(|&&i| i as usize >= n) {
        return Err(format!("index {i} is out of range ({n} vertices)"));
    }
    if mesh.normals.len() != n {
        return Err(format!("{} normals for {n} vertices", mesh.normals.len()));
    }
    if let Some(c) = &mesh.colors {
        if c.len() != n {
            return Err(format!("{} colours for {n} vertices", c.len()));
        }
    }
    Ok(())
}

/// Binary little-endian PLY: vertex x y z nx ny nz (float) [red green blue alpha (uchar)], face
/// vertex_indices (uchar count, int indices).
pub fn write_ply(mesh: &Mesh, comment: &str) -> Result<Vec<u8>, String> {
    check(mesh)?;
    if mesh.positions.len() > i32::MAX as usize {
        return Err("too many vertices for PLY int indices".into());
    }
    let tris = mesh.indices.len() / 3;
    let colors = mesh.colors.as_deref();
    let mut h = String::from("ply\nformat binary_little_endian 1.0\n");
    for line in comment.lines() {
        h += &format!("comment {line}\n");
    }
    h += &format!("element vertex {}\n", mesh.positions.len());
    h += "property float x\nproperty float y\nproperty float z\n";
    h += "property float nx\nproperty float ny\nproperty float nz\n";
    if colors.is_some() {
        h += "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n";
    }
    h += &format!("element face {tris}\nproperty list uchar int vertex_indices\nend_header\n");
    let vsize = 24 + if colors.is_some() { 4 } else { 0 };
    let mut out = Vec::with_capacity(h.len() + mesh.positions.len() * vsize + tris * 13);
    out.extend_from_slice(h.as_bytes());
    for (i, (p, n)) in mesh.positions.iter().zip(&mesh.normals).enumerate() {
        for v in p.iter().chain(n) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        if let Some(c) = colors {
            out.extend_from_slice(&c[i]);
        }
    }
    for t in mesh.indices.chunks_exact(3) {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    Ok(out)
}

/// Wavefront OBJ: `v`, `vn` and `f a//a b//b c//c` (1-based), preceded by `#` comment lines.
/// Shortest round-trip float formatting, so positions survive a write and read exactly.
pub fn write_obj(mesh: &Mesh, comment: &str) -> Result<Vec<u8>, String> {
    use std::fmt::Write;
    check(mesh)?;
    let mut s = String::with_capacity(mesh.positions.len() * 80 + mesh.indices.len() * 12);
    for line in comment.lines() {
        let _ = writeln!(s, "# {line}");
    }
    for p in &mesh.positions {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for n in &mesh.normals {
        let _ = writeln!(s, "vn {} {} {}", n[0], n[1], n[2]);
    }
    for t in mesh.indices.chunks_exact(3) {
        let (a, b, c) = (t[0] + 1, t[1] + 1, t[2] + 1);
        let _ = writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}");
    }
    Ok(s.into_bytes())
}

/// Binary STL: an 80-byte header (the comment, truncated), the triangle count, and per
/// triangle its unit normal, three vertices and a zero attribute word.
pub fn write_stl(mesh: &Mesh, comment: &str) -> Result<Vec<u8>, String> {
    check(mesh)?;
    let tris = mesh.indices.len() / 3;
    let count = u32::try_from(tris).map_err(|_| "too many triangles for STL".to_string())?;
    let mut out = Vec::with_capacity(84 + tris * 50);
    let mut header = [b' '; 80];
    // "solid" at the start makes some readers take a binary file for ASCII.
    let text = format!("nkrr {comment}");
    for (d, s) in header.iter_mut().zip(text.bytes().filter(|b| b.is_ascii() && *b != b'\n')) {
        *d = s;
    }
    out.extend_from_slice(&header);
    out.extend_from_slice(&count.to_le_bytes());
    let v = |i: u32| glam::Vec3::from(mesh.positions[i as usize]);
    for t in mesh.indices.chunks_exact(3) {
        let (a, b, c) = (v(t[0]), v(t[1]), v(t[2]));
        let mut n = (b - a).cross(c - a).normalize_or_zero();
        if n == glam::Vec3::ZERO {
            let m: glam::Vec3 = t.iter().map(|&i| glam::Vec3::from(mesh.normals[i as usize])).sum();
            n = m.normalize_or_zero();
        }
        for x in [n, a, b, c] {
            for f in x.to_array() {
                out.extend_from_slice(&f.to_le_bytes());
            }
        }
        out.extend_from_slice(&[0, 0]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra(colors: bool) -> Mesh {
        let positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let indices = vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];
        let mut m = Mesh { positions, normals: vec![[0.0; 3]; 4], colors: None, indices };
        m.compute_vertex_normals();
        if colors {
            m.colors = Some(vec![[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [9, 9, 9, 255]]);
        }
        m
    }

    #[test]
    fn formats_from_extensions() {
        assert_eq!(MeshFormat::from_path("a/b.PLY"), Some(MeshFormat::Ply));
        assert_eq!(MeshFormat::from_path("x.obj"), Some(MeshFormat::Obj));
        assert_eq!(MeshFormat::from_path("x.stl"), Some(MeshFormat::Stl));
        assert_eq!(MeshFormat::from_path("x.glb"), Some(MeshFormat::Glb));
        assert_eq!(MeshFormat::from_path("x.gltf"), None);
        assert_eq!(MeshFormat::from_path("noext"), None);
        assert_eq!(MeshFormat::from_extension("Stl"), Some(MeshFormat::Stl));
    }

    #[test]
    fn ply_reads_back_with_our_reader() {
        for colors in [false, true] {
            let m = tetra(colors);
            let bytes = write_ply(&m, "test mesh\nsecond line").unwrap();
            let parsed = crate::io::ply::read_ply(&bytes).unwrap();
            assert_eq!(parsed.cloud.positions, m.positions);
            let normals = parsed.cloud.normals.as_ref().expect("normals kept");
            assert_eq!(normals, &m.normals);
            assert_eq!(parsed.cloud.colors.is_some(), colors);
            // The face element follows the vertices: 4 faces of 1 + 3 * 4 bytes.
            let vsize = if colors { 28 } else { 24 };
            let header_end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
            assert_eq!(bytes.len(), header_end + 4 * vsize + 4 * 13);
            let faces = &bytes[header_end + 4 * vsize..];
            let idx: Vec<i32> = faces
                .chunks_exact(13)
                .flat_map(|f| {
                    assert_eq!(f[0], 3);
                    f[1..].chunks_exact(4).map(|b| i32::from_le_bytes(b.try_into().unwrap())).collect::<Vec<_>>()
                })
                .collect();
            assert_eq!(idx, m.indices.iter().map(|&i| i as i32).collect::<Vec<_>>());
        }
    }

    #[test]
    fn obj_lines_are_one_based_and_exact() {
        let m = Mesh { positions: vec![[0.1, -2.5e-7, 3.0]; 3], normals: vec![[0.0, 0.0, 1.0]; 3], colors: None, indices: vec![0, 1, 2] };
        let s = String::from_utf8(write_obj(&m, "c").unwrap()).unwrap();
        let lines: Vec<&str> = s.lines().collect();
        assert_eq!(lines[0], "# c");
        assert_eq!(lines[1], "v 0.1 -0.00000025 3");
        let back: Vec<f32> = lines[1][2..].split(' ').map(|x| x.parse().unwrap()).collect();
        assert_eq!(back, vec![0.1, -2.5e-7, 3.0]);
        assert_eq!(lines[4], "vn 0 0 1");
        assert_eq!(lines[7], "f 1//1 2//2 3//3");
        assert_eq!(lines.len(), 8);
    }

    #[test]
    fn stl_has_outward_unit_normals_and_the_right_size() {
        let m = tetra(false);
        let b = write_stl(&m, "tetra").unwrap();
        assert_eq!(b.len(), 84 + 4 * 50);
        assert_eq!(&b[..10], b"nkrr tetra");
        assert_eq!(u32::from_le_bytes(b[80..84].try_into().unwrap()), 4);
        let f = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        let centroid = glam::Vec3::splat(0.25);
        for t in 0..4 {
            let o = 84 + t * 50;
            let n = glam::Vec3::new(f(o), f(o + 4), f(o + 8));
            assert!((n.length() - 1.0).abs() < 1e-6);
            let a = glam::Vec3::new(f(o + 12), f(o + 16), f(o + 20));
            assert!(n.dot(a - centroid) > 0.0, "normal of triangle {t} points inwards");
        }
    }

    #[test]
    fn bad_meshes_are_errors_not_panics() {
        let mut m = tetra(false);
        m.indices.push(0);
        assert!(write_ply(&m, "").unwrap_err().contains("multiple of 3"));
        let mut m = tetra(false);
        m.indices[5] = 99;
        assert!(write_obj(&m, "").unwrap_err().contains("out of range"));
        let mut m = tetra(false);
        m.normals.pop();
        assert!(write_stl(&m, "").unwrap_err().contains("normals"));
    }
}
