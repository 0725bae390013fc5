//! Reading a binary glTF (`.glb`) back into a [`Mesh`], to evaluate reconstructions written by
//! `nkrr reconstruct` (or any other tool) against their ground truth.
//!
//! Parsing and validation are the `gltf` crate's (hence the `read-glb` feature, native only).
//! Every triangle primitive of every mesh reachable from the default scene (or the first scene;
//! or every mesh, when there is no scene) is placed by its node's world transform, computed in
//! `f64`, and appended: positions, then indices offset by the vertices already read. Non-indexed
//! primitives get `0, 1, 2, ...`. Only positions and indices are read. Buffers must live in the
//! GLB's BIN chunk; points, lines, strips and fans are rejected rather than silently dropped.

use std::fmt;

use crate::mesh::Mesh;

/// Why a GLB cannot be read as a triangle mesh.
#[derive(Debug)]
pub struct GlbReadError(pub String);

impl fmt::Display for GlbReadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for GlbReadError {}

/// The world-space triangles of a GLB (see the module documentation).
pub fn read_glb(bytes: &[u8]) -> Result<Mesh, GlbReadError> {
    let err = |s: String| GlbReadError(s);
    let doc = ::gltf::Gltf::from_slice(bytes).map_err(|e| err(format!("not a valid glTF binary: {e}")))?;
    let blob = doc.blob.as_deref();
    let mut mesh = Mesh::default();
    const IDENTITY: [[f64; 4]; 4] = [[1., 0., 0., 0.], [0., 1., 0., 0.], [0., 0., 1., 0.], [0., 0., 0., 1.]];
    match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => {
            for node in scene.nodes() {
                add_node(&node, IDENTITY, blob, &mut mesh, 0)?;
            }
        }
        None => {
            for m in doc.meshes() {
                add_mesh(&m, &IDENTITY, blob, &mut mesh)?;
            }
        }
    }
    if mesh.indices.is_empty() {
        return Err(err("the file holds no triangles".into()));
    }
    Ok(mesh)
}

fn add_node(node: &::gltf::Node, parent: [[f64; 4]; 4], blob: Option<&[u8]>, out: &mut Mesh, depth: usize) -> Result<(), GlbReadError> {
    if depth > 64 {
        return Err(GlbReadError("node hierarchy deeper than 64 (a cycle?)".into()));
    }
    let local = node.transform().matrix().map(|c| c.map(f64::from));
    let world = mat_mul(&parent, &local);
    if let Some(m) = node.mesh() {
        add_mesh(&m, &world, blob, out)?;
    }
    for child in node.children() {
        add_node(&child, world, blob, out, depth + 1)?;
    }
    Ok(())
}

fn add_mesh(m: &::gltf::Mesh, world: &[[f64; 4]; 4], blob: Option<&[u8]>, out: &mut Mesh) -> Result<(), GlbReadError> {
    let err = |s: String| GlbReadError(format!("mesh {}: {s}", m.index()));
    for p in m.primitives() {
        if p.mode() != ::gltf::mesh::Mode::Triangles {
            return Err(err(format!("primitive {} has mode {:?}; only triangles are read", p.index(), p.mode())));
        }
        let reader = p.reader(|b| match b.source() {
            ::gltf::buffer::Source::Bin => blob,
            ::gltf::buffer::Source::Uri(_) => None,
        });
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or_else(|| err(format!("primitive {} has no readable POSITION (external buffers are not read)", p.index())))?
            .collect();
        let base = out.positions.len();
        let count = positions.len();
        if base + count > u32::MAX as usize {
            return Err(err("more than 2^32 - 1 vertices".into()));
        }
        out.positions.extend(positions.iter().map(|q| {
            let q = q.map(f64::from);
            [0, 1, 2].map(|r| (world[0][r] * q[0] + world[1][r] * q[1] + world[2][r] * q[2] + world[3][r]) as f32)
        }));
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None if p.indices().is_some() => return Err(err(format!("primitive {}: indices not readable", p.index()))),
            None => (0..count as u32).collect(),
        };
        if !indices.len().is_multiple_of(3) {
            return Err(err(format!("primitive {}: {} indices, not a multiple of 3", p.index(), indices.len())));
        }
        if let Some(&bad) = indices.iter().find(|&&i| i as usize >= count) {
            return Err(err(format!("primitive {}: index {bad} out of range ({count} vertices)", p.index())));
        }
        out.indices.extend(indices.iter().map(|&i| i + base as u32));
    }
    Ok(())
}

/// `a * b` for column-major 4x4 matrices (`m[column][row]`, glTF's layout).
fn mat_mul(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut c = [[0.0; 4]; 4];
    for (j, col) in c.iter_mut().enumerate() {
        for (i, v) in col.iter_mut().enumerate() {
            *v = (0..4).map(|k| a[k][i] * b[j][k]).sum();
        }
    }
    c
}
