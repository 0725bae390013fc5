//! The `EXT_meshopt_compression` codec (meshoptimizer's vertex and index codecs and its
//! octahedral normal filter), as safe functions over byte buffers: what the GLB writer encodes
//! and the GLB reader decodes. The `meshopt` crate's own wrappers lack the filters and cannot
//! pick the codec version, which the extension fixes at 0 (version 1 belongs to
//! `KHR_meshopt_compression`).

use meshopt::ffi;

/// The vertex codec version `EXT_meshopt_compression` readers accept.
const VERTEX_VERSION: i32 = 0;
/// meshoptimizer's default compression level (only version 1 uses it).
const LEVEL: i32 = 2;

/// `count` vertices of `stride` bytes each (`data.len() == count * stride`, stride a multiple
/// of 4 up to 256), encoded for a bufferView in mode `ATTRIBUTES`.
pub fn encode_vertices(data: &[u8], stride: usize) -> Vec<u8> {
    assert!(stride > 0 && stride % 4 == 0 && stride <= 256 && data.len() % stride == 0, "stride {stride}");
    let count = data.len() / stride;
    // SAFETY: the bound is computed for exactly these counts; the buffers are that long.
    unsafe {
        let bound = ffi::meshopt_encodeVertexBufferBound(count, stride);
        let mut out = vec![0u8; bound];
        let len = ffi::meshopt_encodeVertexBufferLevel(out.as_mut_ptr(), bound, data.as_ptr().cast(), count, stride, LEVEL, VERTEX_VERSION);
        assert!(len > 0 || count == 0, "the bound holds any input");
        out.truncate(len);
        out
    }
}

/// A triangle list (`indices.len()` a multiple of 3, every index below `vertex_count`), encoded
/// for a bufferView in mode `TRIANGLES`.
pub fn encode_triangles(indices: &[u32], vertex_count: usize) -> Vec<u8> {
    assert!(indices.len() % 3 == 0);
    // SAFETY: as above.
    unsafe {
        let bound = ffi::meshopt_encodeIndexBufferBound(indices.len(), vertex_count);
        let mut out = vec![0u8; bound];
        let len = ffi::meshopt_encodeIndexBuffer(out.as_mut_ptr(), bound, indices.as_ptr(), indices.len());
        out.truncate(len);
        out
    }
}

/// Unit vectors as the octahedral filter stores them: 8-bit signed x, y of the octahedral
/// map, z = 127 (the filter's scale) and w = 0; 4 bytes a vector.
pub fn encode_octahedral(normals: &[[f32; 3]]) -> Vec<u8> {
    let data: Vec<f32> = normals.iter().flat_map(|n| [n[0], n[1], n[2], 0.0]).collect();
    let mut out = vec![0u8; 4 * normals.len()];
    // SAFETY: 4 floats in and 4 bytes out per vector.
    unsafe { ffi::meshopt_encodeFilterOct(out.as_mut_ptr().cast(), normals.len(), 4, 8, data.as_ptr()) };
    out
}

/// Why a compressed buffer view could not be decoded.
#[derive(Debug)]
pub struct DecodeError(pub String);

/// Decodes `count` elements of `stride` bytes from a bufferView's compressed bytes, in `mode`
/// ("ATTRIBUTES", "TRIANGLES" or "INDICES"), undoing `filter` ("NONE" or absent, "OCTAHEDRAL",
/// "QUATERNION", "EXPONENTIAL").
pub fn decode(encoded: &[u8], count: usize, stride: usize, mode: &str, filter: Option<&str>) -> Result<Vec<u8>, DecodeError> {
    let err = |s: String| DecodeError(s);
    let size = count.checked_mul(stride).ok_or_else(|| err("count × byteStride overflows".into()))?;
    // A decoded element needs at least a bit or so of input; this bounds the allocation
    // before anything is decoded, so a forged count cannot ask for gigabytes.
    if size > 64 * encoded.len() + 4096 {
        return Err(err(format!("{count} elements of {stride} bytes from {} encoded bytes is not plausible", encoded.len())));
    }
    let mut out = vec![0u8; size];
    // SAFETY: `out` holds count × stride bytes; the decoders read only `encoded`.
    let rc = unsafe {
        match mode {
            "ATTRIBUTES" if stride % 4 == 0 && stride <= 256 => ffi::meshopt_decodeVertexBuffer(out.as_mut_ptr().cast(), count, stride, encoded.as_ptr(), encoded.len()),
            "TRIANGLES" if (stride == 2 || stride == 4) && count % 3 == 0 => ffi::meshopt_decodeIndexBuffer(out.as_mut_ptr().cast(), count, stride, encoded.as_ptr(), encoded.len()),
            "INDICES" if stride == 2 || stride == 4 => ffi::meshopt_decodeIndexSequence(out.as_mut_ptr().cast(), count, stride, encoded.as_ptr(), encoded.len()),
            _ => return Err(err(format!("mode {mode} with byteStride {stride} and count {count} is not one the extension allows"))),
        }
    };
    if rc != 0 {
        return Err(err(format!("the {mode} data does not decode (meshoptimizer error {rc})")));
    }
    // SAFETY: filters rewrite `out` in place, count elements of `stride` bytes.
    unsafe {
        match filter.unwrap_or("NONE") {
            "NONE" => {}
            "OCTAHEDRAL" if stride == 4 || stride == 8 => ffi::meshopt_decodeFilterOct(out.as_mut_ptr().cast(), count, stride),
            "QUATERNION" if stride == 8 => ffi::meshopt_decodeFilterQuat(out.as_mut_ptr().cast(), count, stride),
            "EXPONENTIAL" if stride % 4 == 0 => ffi::meshopt_decodeFilterExp(out.as_mut_ptr().cast(), count, stride),
            f => return Err(err(format!("filter {f} with byteStride {stride} is not one the extension allows"))),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertices_triangles_and_normals_round_trip() {
        let verts: Vec<u8> = (0..4000u32).flat_map(|i| [(i % 300) as u16, (i / 7) as u16, 5, 0]).flat_map(u16::to_le_bytes).collect();
        let enc = encode_vertices(&verts, 8);
        assert!(enc.len() < verts.len() / 2, "{} of {}", enc.len(), verts.len());
        assert_eq!(decode(&enc, 4000, 8, "ATTRIBUTES", None).unwrap(), verts);

        let tris: Vec<u32> = (0..998u32).flat_map(|i| [i, i + 1, i + 2]).collect();
        let enc = encode_triangles(&tris, 1000);
        let dec = decode(&enc, tris.len(), 4, "TRIANGLES", None).unwrap();
        let back: Vec<u32> = dec.chunks_exact(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
        // The codec may rotate a triangle's corners (same winding), nothing else.
        for (a, b) in tris.chunks_exact(3).zip(back.chunks_exact(3)) {
            let rot = |k: usize| [b[k % 3], b[(k + 1) % 3], b[(k + 2) % 3]];
            assert!((0..3).any(|k| rot(k) == [a[0], a[1], a[2]]), "{a:?} {b:?}");
        }

        let normals: Vec<[f32; 3]> = (0..500).map(|i| {
            let (t, p) = (i as f32 * 0.37, i as f32 * 0.11);
            [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
        }).collect();
        let oct = encode_octahedral(&normals);
        let dec = decode(&encode_vertices(&oct, 4), 500, 4, "ATTRIBUTES", Some("OCTAHEDRAL")).unwrap();
        for (n, b) in normals.iter().zip(dec.chunks_exact(4)) {
            let m = [0, 1, 2].map(|k| b[k] as i8 as f32 / 127.0);
            let dot = n[0] * m[0] + n[1] * m[1] + n[2] * m[2];
            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            assert!(dot / len > 0.999 && (len - 1.0).abs() < 0.02, "{n:?} {m:?}");
        }
    }

    #[test]
    fn garbage_is_an_error_not_a_crash() {
        assert!(decode(&[1, 2, 3], 10, 8, "ATTRIBUTES", None).is_err());
        assert!(decode(&[0xa1, 0, 0], 3, 4, "TRIANGLES", None).is_err());
        assert!(decode(&[0; 8], 1 << 30, 8, "ATTRIBUTES", None).is_err());
        assert!(decode(&[0; 8], 4, 6, "ATTRIBUTES", None).is_err());
        assert!(decode(&[0; 8], 4, 4, "LINES", None).is_err());
    }
}
