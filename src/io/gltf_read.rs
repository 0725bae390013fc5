//! Reading a binary glTF (`.glb`) back into a [`Mesh`], to evaluate reconstructions written by
//! `nkrr reconstruct` (or any other tool) against their ground truth.
//!
//! Parsing and validation are the `gltf` crate's (hence the `read-glb` feature, native only).
//! Every triangle primitive of every mesh reachable from the default scene (or the first scene;
//! or every mesh, when there is no scene) is placed by its node's world transform, computed in
//! `f64`, and appended: positions, then indices offset by the vertices already read. Non-indexed
//! primitives get `0, 1, 2, ...`. Only positions and indices are read. Buffers must live in the
//! GLB's BIN chunk; points, lines, strips and fans are rejected rather than silently dropped.
//!
//! Compact files (`EXT_meshopt_compression`, `KHR_mesh_quantization`: what `--glb meshopt` and
//! `--glb quantized` write, and gltfpack) are first expanded into a plain GLB ([`expand`]):
//! the compressed views decoded, integer positions turned into floats.

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
    let expanded = expand(bytes)?;
    let bytes = expanded.as_deref().unwrap_or(bytes);
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

const MESHOPT: &str = "EXT_meshopt_compression";
const QUANTIZATION: &str = "KHR_mesh_quantization";

/// A GLB's JSON and BIN chunks.
fn chunks(bytes: &[u8]) -> Result<(serde_json::Value, &[u8]), GlbReadError> {
    let err = |s: &str| GlbReadError(format!("not a valid glTF binary: {s}"));
    let word = |at: usize| bytes.get(at..at + 4).map(|b| u32::from_le_bytes(b.try_into().unwrap()) as usize);
    if word(0) != Some(0x4654_6C67) {
        return Err(err("no glTF magic"));
    }
    let json_len = word(12).ok_or_else(|| err("truncated header"))?;
    let json = bytes.get(20..20 + json_len).ok_or_else(|| err("truncated JSON chunk"))?;
    let json: serde_json::Value = serde_json::from_slice(json).map_err(|e| err(&format!("JSON: {e}")))?;
    let at = 20 + json_len;
    let bin = match word(at) {
        Some(len) => bytes.get(at + 8..at + 8 + len).ok_or_else(|| err("truncated BIN chunk"))?,
        None => &[],
    };
    Ok((json, bin))
}

/// A plain GLB with the same content as `bytes`, when `bytes` uses `EXT_meshopt_compression`
/// or `KHR_mesh_quantization` (else `None`): every buffer view's bytes in one new BIN chunk
/// (compressed ones decoded), and every `POSITION` accessor as floats.
pub fn expand(bytes: &[u8]) -> Result<Option<Vec<u8>>, GlbReadError> {
    use serde_json::{json, Value};
    let err = |s: String| GlbReadError(s);
    if bytes.len() < 20 || !bytes.starts_with(b"glTF") {
        return Ok(None); // not ours to judge: the gltf crate says what is wrong
    }
    let (mut doc, bin) = chunks(bytes)?;
    let used: Vec<String> = doc["extensionsUsed"].as_array().map(|a| a.iter().filter_map(|v| v.as_str().map(String::from)).collect()).unwrap_or_default();
    if !used.iter().any(|e| e == MESHOPT || e == QUANTIZATION) {
        return Ok(None);
    }
    let num = |v: &Value, what: &str| v.as_u64().map(|x| x as usize).ok_or_else(|| err(format!("{what} is missing or not a whole number")));
    // Which buffers are the BIN chunk (no uri); fallback buffers have no data of their own.
    let buffers = doc["buffers"].as_array().cloned().unwrap_or_default();
    let is_bin = |b: usize| buffers.get(b).is_some_and(|v| v.get("uri").is_none() && v["extensions"][MESHOPT]["fallback"] != json!(true));
    let mut out: Vec<u8> = Vec::new();
    let views = doc["bufferViews"].as_array_mut().ok_or_else(|| err("no bufferViews".into()))?;
    for (i, view) in views.iter_mut().enumerate() {
        let what = |s: &str| format!("bufferViews[{i}].{s}");
        let ext = view["extensions"][MESHOPT].clone();
        let data: Vec<u8> = if ext.is_object() {
            let (b, off, len) = (num(&ext["buffer"], &what("extensions.buffer"))?, num(&ext["byteOffset"], &what("byteOffset")).unwrap_or(0), num(&ext["byteLength"], &what("byteLength"))?);
            if !is_bin(b) {
                return Err(err(format!("{} points to buffer {b}, not the GLB's BIN chunk", what("extensions"))));
            }
            let src = bin.get(off..off + len).ok_or_else(|| err(format!("{} reaches past the BIN chunk", what("extensions"))))?;
            let (count, stride) = (num(&ext["count"], &what("count"))?, num(&ext["byteStride"], &what("byteStride"))?);
            let mode = ext["mode"].as_str().unwrap_or("");
            let mut raw = crate::io::meshopt_codec::decode(src, count, stride, mode, ext["filter"].as_str()).map_err(|e| err(format!("{}: {}", what("extensions"), e.0)))?;
            raw.truncate(num(&view["byteLength"], &what("byteLength"))?.min(raw.len()));
            raw
        } else {
            let (b, off, len) = (num(&view["buffer"], &what("buffer"))?, num(&view["byteOffset"], &what("byteOffset")).unwrap_or(0), num(&view["byteLength"], &what("byteLength"))?);
            if !is_bin(b) {
                return Err(err(format!("{} points to buffer {b}, not the GLB's BIN chunk", what("buffer"))));
            }
            bin.get(off..off + len).ok_or_else(|| err(format!("{} reaches past the BIN chunk", what("byteLength"))))?.to_vec()
        };
        out.resize(out.len().div_ceil(4) * 4, 0);
        let obj = view.as_object_mut().ok_or_else(|| err(what("")))?;
        obj.insert("buffer".into(), json!(0));
        obj.insert("byteOffset".into(), json!(out.len()));
        obj.insert("byteLength".into(), json!(data.len()));
        obj.remove("extensions");
        out.extend_from_slice(&data);
    }

    // Integer positions as floats, in new views: the gltf crate reads positions as f32 only.
    let positions: Vec<usize> = doc["meshes"].as_array().into_iter().flatten().flat_map(|m| m["primitives"].as_array().into_iter().flatten()).filter_map(|p| p["attributes"]["POSITION"].as_u64().map(|a| a as usize)).collect();
    for a in positions {
        let acc = doc["accessors"][a].clone();
        let ct = acc["componentType"].as_u64().unwrap_or(0);
        if ct == 5126 {
            continue;
        }
        let what = |s: &str| format!("accessors[{a}].{s}");
        let (size, scale): (usize, f64) = match ct {
            5120 => (1, 127.0),
            5121 => (1, 255.0),
            5122 => (2, 32767.0),
            5123 => (2, 65535.0),
            _ => return Err(err(format!("{} {ct} is not one glTF allows for POSITION", what("componentType")))),
        };
        let normalized = acc["normalized"] == json!(true);
        let count = num(&acc["count"], &what("count"))?;
        let v = num(&acc["bufferView"], &what("bufferView"))?;
        let view = &doc["bufferViews"][v];
        let stride = view["byteStride"].as_u64().map_or(3 * size, |s| s as usize);
        let base = num(&view["byteOffset"], "byteOffset")? + acc["byteOffset"].as_u64().unwrap_or(0) as usize;
        let mut floats: Vec<u8> = Vec::with_capacity(12 * count);
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for e in 0..count {
            for c in 0..3 {
                let at = base + e * stride + c * size;
                let b = out.get(at..at + size).ok_or_else(|| err(format!("{} reaches past its buffer view", what("count"))))?;
                let x = match ct {
                    5120 => f64::from(b[0] as i8),
                    5121 => f64::from(b[0]),
                    5122 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                    _ => f64::from(u16::from_le_bytes([b[0], b[1]])),
                };
                // Normalised signed values clamp at -1 (the spec's max(c / 127, -1)).
                let x = if normalized { (x / scale).max(-1.0) } else { x } as f32;
                lo[c] = lo[c].min(x);
                hi[c] = hi[c].max(x);
                floats.extend_from_slice(&x.to_le_bytes());
            }
        }
        out.resize(out.len().div_ceil(4) * 4, 0);
        let new_view = doc["bufferViews"].as_array().map_or(0, Vec::len);
        doc["bufferViews"].as_array_mut().unwrap().push(json!({"buffer": 0, "byteOffset": out.len(), "byteLength": floats.len()}));
        out.extend_from_slice(&floats);
        let mut acc = json!({"bufferView": new_view, "componentType": 5126, "count": count, "type": "VEC3"});
        if count > 0 {
            acc["min"] = json!(lo);
            acc["max"] = json!(hi);
        }
        doc["accessors"][a] = acc;
    }
    out.resize(out.len().div_ceil(4) * 4, 0);
    doc["buffers"] = json!([{"byteLength": out.len()}]);
    for key in ["extensionsUsed", "extensionsRequired"] {
        if let Some(list) = doc[key].as_array_mut() {
            list.retain(|e| e != MESHOPT && e != QUANTIZATION);
        }
    }
    let mut text = serde_json::to_vec(&doc).map_err(|e| err(e.to_string()))?;
    text.resize(text.len().div_ceil(4) * 4, b' ');
    let total = 12 + 8 + text.len() + 8 + out.len();
    let mut glb = Vec::with_capacity(total);
    for w in [0x4654_6C67u32, 2, total as u32, text.len() as u32, 0x4E4F_534A] {
        glb.extend_from_slice(&w.to_le_bytes());
    }
    glb.extend_from_slice(&text);
    for w in [out.len() as u32, 0x004E_4942] {
        glb.extend_from_slice(&w.to_le_bytes());
    }
    glb.extend_from_slice(&out);
    Ok(Some(glb))
}
