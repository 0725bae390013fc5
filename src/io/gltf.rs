//! Writing a [`Mesh`] as binary glTF 2.0 (`.glb`).
//!
//! The file holds one scene with one node with one mesh with one triangle primitive:
//!
//! * `POSITION`: VEC3 float, with `min`/`max` equal to the data's bounds (exactly: each bound is
//!   written as the shortest decimal that reads back as the same `f32`);
//! * `NORMAL`: VEC3 float, every one of unit length (see "Normals" below);
//! * `COLOR_0` (when the mesh has colours): VEC4 normalised unsigned byte, in its own buffer view
//!   (4 bytes per element, so the 4-byte stride rule holds);
//! * indices: SCALAR unsigned int, buffer view target `ELEMENT_ARRAY_BUFFER` (vertex views
//!   target `ARRAY_BUFFER`);
//! * a default material: `pbrMetallicRoughness` non-metallic, light grey (white when vertex
//!   colours are present, since glTF multiplies them by the base colour), single-sided.
//!
//! The JSON is written by hand (no serde in the library, which is also built for wasm32) and
//! padded with spaces, the BIN chunk with zeros; both chunks are 4-byte aligned.
//!
//! **Degenerate triangles** (a triangle that repeats a vertex index) are legal glTF, but the
//! Khronos validator reports them (`ACCESSOR_INDEX_TRIANGLE_DEGENERATE`, an info). The writer
//! drops them and counts them in [`GlbReport::degenerate_triangles_dropped`]. Triangles with
//! three distinct indices but zero area (coincident or collinear positions) are kept: the
//! validator does not look at positions for this, and dropping them could open holes in an
//! otherwise watertight mesh.
//!
//! **Unused vertices** (referenced by no triangle) are written as they are and counted in
//! [`GlbReport::unused_vertices`]; the validator does not report them. They still count towards
//! the `POSITION` bounds, which the validator checks against all elements.
//!
//! **Normals**: when `mesh.normals` is empty, area-weighted vertex normals are computed. Given
//! normals are normalised; a zero, non-finite or denormal-tiny normal is replaced by the
//! computed area-weighted one for that vertex (or `+Z` if that is undefined too) and counted
//! in [`GlbReport::normals_repaired`], since the validator requires unit length.

use std::fmt::{self, Write as _};

use crate::mesh::{area_weighted_normals, normalize_f64, Mesh, FALLBACK_NORMAL};

/// What to write besides the mesh itself.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GlbOptions {
    /// Written as the node's `translation`. Reconstruction works near the origin; large
    /// (e.g. georeferenced) offsets belong here, in `f64`, instead of in the `f32` positions.
    pub translation: Option<[f64; 3]>,
    /// Name of the node and the mesh.
    pub name: Option<String>,
    /// How the geometry is stored (see [`Compression`]).
    pub compression: Compression,
}

/// How a GLB stores its geometry.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compression {
    /// Float positions and normals, u32 indices: what every glTF reader reads.
    #[default]
    None,
    /// `KHR_mesh_quantization`: positions as 14-bit integers in u16 (the node's scale and
    /// translation map them back; the largest error is 1/32766 of the mesh's largest side),
    /// normals as signed bytes, u16 indices where the vertices allow; vertices in the order
    /// of first use, unused ones left out.
    Quantized,
    /// The same, each buffer view packed by `EXT_meshopt_compression` (meshoptimizer's codecs,
    /// normals through its octahedral filter); three.js, Babylon.js and model-viewer decode it.
    Meshopt,
}

/// What the writer did to make the mesh a clean glTF (see the module documentation).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct GlbReport {
    pub vertices_written: usize,
    pub triangles_written: usize,
    /// Triangles that repeated a vertex index and were left out.
    pub degenerate_triangles_dropped: usize,
    /// Vertices that no written triangle uses (kept in the file, except by [`Compression`]'s
    /// compact forms, which leave them out).
    pub unused_vertices: usize,
    /// True when the mesh had no normals and area-weighted ones were computed.
    pub normals_computed: bool,
    /// Given normals that were zero or not finite and were replaced.
    pub normals_repaired: usize,
    /// Size of the GLB in bytes.
    pub bytes: usize,
}

/// Why a mesh cannot be written.
#[derive(Clone, Debug, PartialEq)]
pub enum GltfError {
    /// No positions or no indices.
    EmptyMesh,
    /// Every triangle repeats a vertex index, so nothing is left to draw.
    AllTrianglesDegenerate {
        triangles: usize,
    },
    IndexCountNotMultipleOf3 {
        count: usize,
    },
    /// `indices[at] == index`, but there are only `vertex_count` positions.
    IndexOutOfRange {
        at: usize,
        index: u32,
        vertex_count: usize,
    },
    NonFinitePosition {
        vertex: usize,
        position: [f32; 3],
    },
    /// An attribute's length differs from the number of positions.
    AttributeCountMismatch {
        attribute: &'static str,
        expected: usize,
        found: usize,
    },
    NonFiniteTranslation {
        translation: [f64; 3],
    },
    /// The GLB would exceed what its 32-bit length fields (or this platform's memory) allow.
    TooLarge {
        what: &'static str,
        needed: u64,
        limit: u64,
    },
}

impl fmt::Display for GltfError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GltfError::EmptyMesh => write!(f, "cannot write an empty mesh as glTF (no positions or no triangles)"),
            GltfError::AllTrianglesDegenerate { triangles } => write!(
                f,
                "all {triangles} triangles are degenerate (repeat a vertex index); nothing to write"
            ),
            GltfError::IndexCountNotMultipleOf3 { count } => {
                write!(f, "index count {count} is not a multiple of 3")
            }
            GltfError::IndexOutOfRange { at, index, vertex_count } => write!(
                f,
                "index {index} at position {at} is out of range: the mesh has {vertex_count} vertices"
            ),
            GltfError::NonFinitePosition { vertex, position } => {
                write!(f, "vertex {vertex} has a non-finite position {position:?}")
            }
            GltfError::AttributeCountMismatch { attribute, expected, found } => write!(
                f,
                "{attribute} has {found} elements but the mesh has {expected} positions"
            ),
            GltfError::NonFiniteTranslation { translation } => {
                write!(f, "root translation {translation:?} is not finite")
            }
            GltfError::TooLarge { what, needed, limit } => {
                write!(f, "{what} too large for glTF: {needed} exceeds the limit of {limit}")
            }
        }
    }
}

impl std::error::Error for GltfError {}

const GLB_MAGIC: u32 = 0x4654_6C67; // "glTF"
const GLB_VERSION: u32 = 2;
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const BYTE: u32 = 5120;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const MODE_TRIANGLES: u32 = 4;

/// Writes `mesh` as a GLB. See [`write_glb_with_report`] for what is changed on the way.
pub fn write_glb(mesh: &Mesh, opts: &GlbOptions) -> Result<Vec<u8>, GltfError> {
    write_glb_with_report(mesh, opts).map(|(bytes, _)| bytes)
}

/// Writes `mesh` as a GLB and reports what was dropped, computed or repaired (see the module
/// documentation). Never panics; every invalid input is a [`GltfError`].
pub fn write_glb_with_report(
    mesh: &Mesh,
    opts: &GlbOptions,
) -> Result<(Vec<u8>, GlbReport), GltfError> {
    let n = mesh.positions.len();
    if n == 0 || mesh.indices.is_empty() {
        return Err(GltfError::EmptyMesh);
    }
    if !mesh.indices.len().is_multiple_of(3) {
        return Err(GltfError::IndexCountNotMultipleOf3 { count: mesh.indices.len() });
    }
    // u32 indices: the largest index must stay below the primitive-restart value 0xFFFFFFFF.
    if n as u64 > u64::from(u32::MAX) {
        return Err(GltfError::TooLarge {
            what: "vertex count",
            needed: n as u64,
            limit: u64::from(u32::MAX),
        });
    }
    if !mesh.normals.is_empty() && mesh.normals.len() != n {
        return Err(GltfError::AttributeCountMismatch {
            attribute: "normals",
            expected: n,
            found: mesh.normals.len(),
        });
    }
    if let Some(c) = &mesh.colors {
        if c.len() != n {
            return Err(GltfError::AttributeCountMismatch {
                attribute: "colors",
                expected: n,
                found: c.len(),
            });
        }
    }
    if let Some(t) = opts.translation {
        if !t.iter().all(|x| x.is_finite()) {
            return Err(GltfError::NonFiniteTranslation { translation: t });
        }
    }
    let mut min = mesh.positions[0];
    let mut max = mesh.positions[0];
    for (vertex, p) in mesh.positions.iter().enumerate() {
        if !p.iter().all(|x| x.is_finite()) {
            return Err(GltfError::NonFinitePosition { vertex, position: *p });
        }
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
            max[a] = max[a].max(p[a]);
        }
    }
    if let Some((at, &index)) = mesh.indices.iter().enumerate().find(|(_, &i)| i as usize >= n) {
        return Err(GltfError::IndexOutOfRange { at, index, vertex_count: n });
    }

    // Drop triangles that repeat an index; note which vertices are used.
    let mut indices: Vec<u32> = Vec::with_capacity(mesh.indices.len());
    let mut used = vec![false; n];
    for t in mesh.indices.chunks_exact(3) {
        let (a, b, c) = (t[0], t[1], t[2]);
        if a == b || b == c || a == c {
            continue;
        }
        indices.extend_from_slice(t);
        for i in t {
            used[*i as usize] = true;
        }
    }
    let triangles_in = mesh.indices.len() / 3;
    if indices.is_empty() {
        return Err(GltfError::AllTrianglesDegenerate { triangles: triangles_in });
    }

    // Sizes, checked in u64 (usize is 32 bits on wasm32).
    let n64 = n as u64;
    let pos_bytes = n64 * 12;
    let nrm_bytes = n64 * 12;
    let col_bytes = if mesh.colors.is_some() { n64 * 4 } else { 0 };
    let idx_bytes = indices.len() as u64 * 4;
    let bin_len = pos_bytes + nrm_bytes + col_bytes + idx_bytes; // all multiples of 4
    let max_json_len = 4096 + 12 * opts.name.as_ref().map_or(0, |s| s.len() as u64);
    let limit = u64::from(u32::MAX).min(usize::MAX as u64);
    if 12 + 8 + max_json_len + 8 + bin_len > limit {
        return Err(GltfError::TooLarge {
            what: "GLB file",
            needed: 12 + 8 + max_json_len + 8 + bin_len,
            limit,
        });
    }

    // Normals: computed, or normalised with zero/NaN ones repaired.
    let mut normals_repaired = 0;
    let normals_computed = mesh.normals.is_empty();
    let normals: Vec<[f32; 3]> = if normals_computed {
        area_weighted_normals(&mesh.positions, &indices)
    } else {
        let mut fallback: Option<Vec<[f32; 3]>> = None;
        let mut out = Vec::with_capacity(n);
        for (i, v) in mesh.normals.iter().enumerate() {
            match normalize_f64(v.map(f64::from)) {
                Some(u) => out.push(u),
                None => {
                    normals_repaired += 1;
                    let fb = fallback
                        .get_or_insert_with(|| area_weighted_normals(&mesh.positions, &indices));
                    out.push(fb.get(i).copied().unwrap_or(FALLBACK_NORMAL));
                }
            }
        }
        out
    };

    let report = GlbReport {
        vertices_written: n,
        triangles_written: indices.len() / 3,
        degenerate_triangles_dropped: triangles_in - indices.len() / 3,
        unused_vertices: used.iter().filter(|u| !**u).count(),
        normals_computed,
        normals_repaired,
        bytes: 0,
    };
    if opts.compression != Compression::None {
        return write_compact(mesh, indices, &normals, opts, report);
    }

    // JSON.
    let has_colors = mesh.colors.is_some();
    let mut views: Vec<(u64, u64, u32)> = Vec::new(); // (offset, length, target)
    let mut offset = 0u64;
    for (len, target) in [
        (pos_bytes, ARRAY_BUFFER),
        (nrm_bytes, ARRAY_BUFFER),
        (col_bytes, ARRAY_BUFFER),
        (idx_bytes, ELEMENT_ARRAY_BUFFER),
    ] {
        if len > 0 {
            views.push((offset, len, target));
            offset += len;
        }
    }

    let mut j = String::with_capacity(2048);
    let transform = opts.translation.map_or(String::new(), |t| {
        format!(",\"translation\":[{},{},{}]", JsonF64(t[0]), JsonF64(t[1]), JsonF64(t[2]))
    });
    push_head(&mut j, &[], opts.name.as_deref(), &transform, has_colors);
    let _ = write!(j, "\"buffers\":[{{\"byteLength\":{bin_len}}}],\"bufferViews\":[");
    for (k, (off, len, target)) in views.iter().enumerate() {
        if k > 0 {
            j.push(',');
        }
        let _ = write!(
            j,
            "{{\"buffer\":0,\"byteOffset\":{off},\"byteLength\":{len},\"target\":{target}}}"
        );
    }
    j.push_str("],\"accessors\":[");
    let _ = write!(
        j,
        "{{\"bufferView\":0,\"componentType\":{FLOAT},\"count\":{n},\"type\":\"VEC3\",\
         \"min\":[{},{},{}],\"max\":[{},{},{}]}},",
        JsonF32(min[0]),
        JsonF32(min[1]),
        JsonF32(min[2]),
        JsonF32(max[0]),
        JsonF32(max[1]),
        JsonF32(max[2]),
    );
    let _ = write!(
        j,
        "{{\"bufferView\":1,\"componentType\":{FLOAT},\"count\":{n},\"type\":\"VEC3\"}},"
    );
    let mut next_view = 2;
    if has_colors {
        let _ = write!(
            j,
            "{{\"bufferView\":2,\"componentType\":{UNSIGNED_BYTE},\"normalized\":true,\
             \"count\":{n},\"type\":\"VEC4\"}},"
        );
        next_view = 3;
    }
    let _ = write!(
        j,
        "{{\"bufferView\":{next_view},\"componentType\":{UNSIGNED_INT},\"count\":{},\"type\":\"SCALAR\"}}]}}",
        indices.len()
    );
    while !j.len().is_multiple_of(4) {
        j.push(' ');
    }

    // Assemble.
    let total = 12 + 8 + j.len() as u64 + 8 + bin_len;
    if total > limit {
        return Err(GltfError::TooLarge { what: "GLB file", needed: total, limit });
    }
    let mut out = glb_start(&j, bin_len, total)?;
    for p in &mesh.positions {
        for x in p {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    for p in &normals {
        for x in p {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    if let Some(colors) = &mesh.colors {
        for c in colors {
            out.extend_from_slice(c);
        }
    }
    for i in &indices {
        out.extend_from_slice(&i.to_le_bytes());
    }
    debug_assert_eq!(out.len() as u64, total);
    let bytes = out.len();
    Ok((out, GlbReport { bytes, ..report }))
}

/// Bits of each quantized position coordinate (gltfpack's default: finer costs bytes after
/// compression and no viewer can show it).
const POSITION_BITS: u32 = 14;

/// The [`Compression::Quantized`] and [`Compression::Meshopt`] forms of a mesh already checked
/// by [`write_glb_with_report`]: `indices` without degenerate triangles, `normals` of unit
/// length, one per vertex.
fn write_compact(
    mesh: &Mesh,
    indices: Vec<u32>,
    normals: &[[f32; 3]],
    opts: &GlbOptions,
    report: GlbReport,
) -> Result<(Vec<u8>, GlbReport), GltfError> {
    let meshopt = opts.compression == Compression::Meshopt;
    // Triangles in vertex-cache order and vertices in the order of first use: what the codecs
    // compress best (consecutive indices, neighbouring vertices), and what GPUs draw fastest.
    let indices = meshopt::optimize_vertex_cache(&indices, mesh.positions.len());
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    let mut order: Vec<u32> = Vec::new();
    let indices: Vec<u32> = indices
        .iter()
        .map(|&i| {
            if remap[i as usize] == u32::MAX {
                remap[i as usize] = order.len() as u32;
                order.push(i);
            }
            remap[i as usize]
        })
        .collect();
    let nv = order.len();

    // Positions: p = origin + q * step, q integer in [0, 2^bits - 1], the same step on every
    // axis so that the node's scale is uniform and leaves the normals alone.
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &v in &order {
        for a in 0..3 {
            let x = f64::from(mesh.positions[v as usize][a]);
            lo[a] = lo[a].min(x);
            hi[a] = hi[a].max(x);
        }
    }
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    let levels = f64::from((1u32 << POSITION_BITS) - 1);
    let step = if extent > 0.0 { extent / levels } else { 1.0 };
    let mut qmin = [u16::MAX; 3];
    let mut qmax = [0u16; 3];
    let mut pos = Vec::with_capacity(8 * nv);
    for &v in &order {
        let p = mesh.positions[v as usize];
        for a in 0..3 {
            let q = ((f64::from(p[a]) - lo[a]) / step).round().clamp(0.0, levels) as u16;
            qmin[a] = qmin[a].min(q);
            qmax[a] = qmax[a].max(q);
            pos.extend_from_slice(&q.to_le_bytes());
        }
        pos.extend_from_slice(&[0, 0]); // padding to the 4-byte vertex stride
    }
    let ordered: Vec<[f32; 3]> = order.iter().map(|&v| normals[v as usize]).collect();
    let nrm = if meshopt {
        crate::io::meshopt_codec::encode_octahedral(&ordered)
    } else {
        ordered.iter().flat_map(|n| [n[0], n[1], n[2]].map(|c| ((c * 127.0).round() as i8) as u8).into_iter().chain([0])).collect()
    };
    let col: Option<Vec<u8>> = mesh.colors.as_ref().map(|c| order.iter().flat_map(|&v| c[v as usize]).collect());
    // u16 indices when every index fits below the u16 maximum (which glTF reserves).
    let short = nv < usize::from(u16::MAX);
    let (idx_type, idx_size) = if short { (UNSIGNED_SHORT, 2) } else { (UNSIGNED_INT, 4) };
    let idx: Vec<u8> = if short {
        indices.iter().flat_map(|&i| (i as u16).to_le_bytes()).collect()
    } else {
        indices.iter().flat_map(|&i| i.to_le_bytes()).collect()
    };

    // Buffer views: (raw bytes, stride for vertex data, target, codec mode and filter). The
    // uncompressed layout is what the views describe in both forms; the meshopt form stores
    // each view's encoding in the BIN chunk and describes the raw layout in a fallback buffer
    // with no data.
    struct View {
        raw_len: usize,
        stride: Option<usize>,
        target: u32,
        mode: &'static str,
        filter: Option<&'static str>,
        stored: Vec<u8>,
    }
    let mut views = Vec::new();
    let mut add = |raw: Vec<u8>, stride: Option<usize>, target, mode, filter| {
        let raw_len = raw.len();
        let stored = match (meshopt, mode) {
            (false, _) => raw,
            (true, "TRIANGLES") => crate::io::meshopt_codec::encode_triangles(&indices, nv),
            (true, _) => crate::io::meshopt_codec::encode_vertices(&raw, stride.unwrap_or(4)),
        };
        views.push(View { raw_len, stride, target, mode, filter, stored });
    };
    add(pos, Some(8), ARRAY_BUFFER, "ATTRIBUTES", None);
    add(nrm, Some(4), ARRAY_BUFFER, "ATTRIBUTES", meshopt.then_some("OCTAHEDRAL"));
    let has_colors = col.is_some();
    if let Some(c) = col {
        add(c, Some(4), ARRAY_BUFFER, "ATTRIBUTES", None);
    }
    add(idx, None, ELEMENT_ARRAY_BUFFER, "TRIANGLES", None);

    let pad4 = |x: usize| x.div_ceil(4) * 4;
    let raw_total: usize = views.iter().map(|v| pad4(v.raw_len)).sum();
    let bin_len: usize = views.iter().map(|v| pad4(v.stored.len())).sum();

    let mut j = String::with_capacity(4096);
    let extensions: &[&str] = if meshopt { &["KHR_mesh_quantization", "EXT_meshopt_compression"] } else { &["KHR_mesh_quantization"] };
    let t = opts.translation.unwrap_or([0.0; 3]);
    let origin = [0, 1, 2].map(|a| t[a] + lo[a]);
    let transform = format!(
        ",\"translation\":[{},{},{}],\"scale\":[{3},{3},{3}]",
        JsonF64(origin[0]),
        JsonF64(origin[1]),
        JsonF64(origin[2]),
        JsonF64(step)
    );
    push_head(&mut j, extensions, opts.name.as_deref(), &transform, has_colors);
    let idx_acc = if has_colors { 3 } else { 2 };
    if meshopt {
        let _ = write!(j, "\"buffers\":[{{\"byteLength\":{bin_len}}},{{\"byteLength\":{raw_total},\"extensions\":{{\"EXT_meshopt_compression\":{{\"fallback\":true}}}}}}],");
    } else {
        let _ = write!(j, "\"buffers\":[{{\"byteLength\":{bin_len}}}],");
    }
    j.push_str("\"bufferViews\":[");
    let (mut raw_off, mut bin_off) = (0usize, 0usize);
    for (k, v) in views.iter().enumerate() {
        if k > 0 {
            j.push(',');
        }
        let _ = write!(j, "{{\"buffer\":{},\"byteOffset\":{raw_off},\"byteLength\":{}", usize::from(meshopt), v.raw_len);
        if let Some(s) = v.stride {
            let _ = write!(j, ",\"byteStride\":{s}");
        }
        let _ = write!(j, ",\"target\":{}", v.target);
        if meshopt {
            let count = if v.mode == "TRIANGLES" { indices.len() } else { nv };
            let _ = write!(
                j,
                ",\"extensions\":{{\"EXT_meshopt_compression\":{{\"buffer\":0,\"byteOffset\":{bin_off},\"byteLength\":{},\"byteStride\":{},\"count\":{count},\"mode\":\"{}\"",
                v.stored.len(),
                v.stride.unwrap_or(idx_size),
                v.mode
            );
            if let Some(f) = v.filter {
                let _ = write!(j, ",\"filter\":\"{f}\"");
            }
            j.push_str("}}");
        }
        j.push('}');
        raw_off += pad4(v.raw_len);
        bin_off += pad4(v.stored.len());
    }
    j.push_str("],\"accessors\":[");
    let _ = write!(
        j,
        "{{\"bufferView\":0,\"componentType\":{UNSIGNED_SHORT},\"count\":{nv},\"type\":\"VEC3\",\"min\":[{},{},{}],\"max\":[{},{},{}]}},",
        qmin[0], qmin[1], qmin[2], qmax[0], qmax[1], qmax[2]
    );
    let _ = write!(j, "{{\"bufferView\":1,\"componentType\":{BYTE},\"normalized\":true,\"count\":{nv},\"type\":\"VEC3\"}},");
    if has_colors {
        let _ = write!(j, "{{\"bufferView\":2,\"componentType\":{UNSIGNED_BYTE},\"normalized\":true,\"count\":{nv},\"type\":\"VEC4\"}},");
    }
    let _ = write!(j, "{{\"bufferView\":{idx_acc},\"componentType\":{idx_type},\"count\":{},\"type\":\"SCALAR\"}}]}}", indices.len());
    while !j.len().is_multiple_of(4) {
        j.push(' ');
    }

    let total = 12 + 8 + j.len() as u64 + 8 + bin_len as u64;
    let limit = u64::from(u32::MAX).min(usize::MAX as u64);
    if total > limit {
        return Err(GltfError::TooLarge { what: "GLB file", needed: total, limit });
    }
    let mut out = glb_start(&j, bin_len as u64, total)?;
    for v in &views {
        out.extend_from_slice(&v.stored);
        out.resize(pad4(out.len()), 0);
    }
    debug_assert_eq!(out.len() as u64, total);
    let report = GlbReport { vertices_written: nv, bytes: out.len(), ..report };
    Ok((out, report))
}

/// The JSON of both forms up to the buffers: the asset, the `extensions` (used and required),
/// the scene with its one node (named `name`; `transform`: its translation and scale members,
/// written) and one mesh whose primitive reads POSITION, NORMAL, COLOR_0 (when `has_colors`)
/// and the indices from accessors 0, 1, 2 and the next, and the default material.
fn push_head(j: &mut String, extensions: &[&str], name: Option<&str>, transform: &str, has_colors: bool) {
    j.push_str("{\"asset\":{\"version\":\"2.0\",\"generator\":");
    push_json_string(j, concat!("nkrr ", env!("CARGO_PKG_VERSION")));
    j.push_str("},");
    if !extensions.is_empty() {
        let list = extensions.iter().map(|e| format!("\"{e}\"")).collect::<Vec<_>>().join(",");
        let _ = write!(j, "\"extensionsUsed\":[{list}],\"extensionsRequired\":[{list}],");
    }
    j.push_str("\"scene\":0,\"scenes\":[{\"nodes\":[0]}],\"nodes\":[{\"mesh\":0");
    if let Some(name) = name {
        j.push_str(",\"name\":");
        push_json_string(j, name);
    }
    j.push_str(transform);
    j.push_str("}],\"meshes\":[{");
    if let Some(name) = name {
        j.push_str("\"name\":");
        push_json_string(j, name);
        j.push(',');
    }
    j.push_str("\"primitives\":[{\"attributes\":{\"POSITION\":0,\"NORMAL\":1");
    if has_colors {
        j.push_str(",\"COLOR_0\":2");
    }
    let idx_acc = if has_colors { 3 } else { 2 };
    let _ = write!(j, "}},\"indices\":{idx_acc},\"material\":0,\"mode\":{MODE_TRIANGLES}}}]}}],");
    j.push_str("\"materials\":[{\"name\":\"nkrr default\",\"pbrMetallicRoughness\":{");
    if !has_colors {
        // glTF multiplies vertex colours by the base colour: white (the default) keeps them.
        j.push_str("\"baseColorFactor\":[0.8,0.8,0.8,1],");
    }
    j.push_str("\"metallicFactor\":0,\"roughnessFactor\":0.6},\"doubleSided\":false}],");
}

/// A GLB of `total` bytes begun: the header, the JSON chunk (`json`, padded to 4 bytes) and the
/// BIN chunk's header for `bin_len` bytes, in a buffer that can hold the rest; an error rather
/// than an abort when the memory is not there.
fn glb_start(json: &str, bin_len: u64, total: u64) -> Result<Vec<u8>, GltfError> {
    let mut out: Vec<u8> = Vec::new();
    if out.try_reserve_exact(total as usize).is_err() {
        return Err(GltfError::TooLarge { what: "GLB file (memory)", needed: total, limit: 0 });
    }
    for w in [GLB_MAGIC, GLB_VERSION, total as u32, json.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.extend_from_slice(json.as_bytes());
    for w in [bin_len as u32, CHUNK_BIN] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    Ok(out)
}

/// An `f32` as a JSON number that parses (as `f64` or `f32`) back to exactly this value: the
/// widened `f64` is exact and Rust's `Display` prints the shortest round-tripping decimal,
/// without exponent. Callers guarantee finiteness.
struct JsonF32(f32);

impl fmt::Display for JsonF32 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", JsonF64(f64::from(self.0)))
    }
}

/// A finite `f64` as a JSON number (`-0` is written as `0`).
struct JsonF64(f64);

impl fmt::Display for JsonF64 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = if self.0 == 0.0 { 0.0 } else { self.0 };
        write!(f, "{x}")
    }
}

/// Appends `s` as a JSON string literal, escaping quotes, backslashes and control characters.
fn push_json_string(out: &mut String, s: &str) {
    out.push('"');
    for ch in s.chars() {
        match ch {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            '\u{08}' => out.push_str("\\b"),
            '\u{0C}' => out.push_str("\\f"),
            c if (c as u32) < 0x20 || c == '\u{7F}' || c == '\u{2028}' || c == '\u{2029}' => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_string_escaping() {
        let mut s = String::new();
        push_json_string(&mut s, "a\"b\\c\nd\u{1}é\u{2028}");
        assert_eq!(s, "\"a\\\"b\\\\c\\nd\\u0001é\\u2028\"");
    }

    #[test]
    fn json_numbers_round_trip() {
        for x in [0.1f32, -0.0, 1.0, f32::MAX, f32::MIN_POSITIVE, 1e-45, 123456.79] {
            let s = JsonF32(x).to_string();
            assert!(!s.contains('e') && !s.contains("inf") && !s.contains("NaN"), "{s}");
            assert_eq!(s.parse::<f64>().unwrap(), f64::from(x) + 0.0, "{s}");
            assert_eq!(s.parse::<f32>().unwrap(), x + 0.0, "{s}");
        }
        assert_eq!(JsonF64(5e6).to_string(), "5000000");
    }
}
