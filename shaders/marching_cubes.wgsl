// Marching cubes over a sparse list of active cells, in two kernels (see src/mesh/
// marching_cubes_gpu.rs; src/mesh/marching_cubes.rs is the CPU reference computing the same):
//
//   classify: per cell, the case index from its 8 corner values and the case's triangle count,
//             packed as `case | count << 8`;
//   emit:     per cell, its triangles at `offsets[i]` (an exclusive prefix sum of the counts,
//             computed by the host), each vertex as 4 words: key, x, y, z (bitcast f32).
//
// Corner c of a cell is at offset (c & 1, c >> 1 & 1, c >> 2 & 1); inside means value > 0.
// Edge e runs along axis a = e / 4 from its low corner, whose bit (a+1)%3 is e & 1 and bit
// (a+2)%3 is (e >> 1) & 1. The key of an edge crossing is 3 * (x + (R+1) (y + (R+1) z)) + a
// for the edge's low corner (x, y, z).
// Work is 1-D: index = gid.x + gid.y * num_workgroups.x * WG.

struct Params {
    n_cells: u32,
    resolution: u32,
    stride: u32,      // u32 words per case in `table`
    _pad: u32,
    lo: vec4<f32>,    // domain min (xyz)
    ext: vec4<f32>,   // domain max - min (xyz)
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> values: array<f32>;      // 8 per cell
@group(0) @binding(2) var<storage, read> table: array<u32>;       // [count, 3 * max_tris edge ids] per case
@group(0) @binding(3) var<storage, read_write> classes: array<u32>; // case | count << 8 per cell
@group(0) @binding(4) var<storage, read> cells: array<u32>;       // x, y, z per cell
@group(0) @binding(5) var<storage, read> offsets: array<u32>;     // first triangle per cell
@group(0) @binding(6) var<storage, read_write> soup: array<u32>;   // 4 words per vertex

const WG: u32 = 64u;
const HEADER: u32 = 1u;

fn linear_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG;
}

@compute @workgroup_size(64)
fn classify(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg);
    if (i >= params.n_cells) {
        return;
    }
    var c = 0u;
    for (var k = 0u; k < 8u; k++) {
        if (values[i * 8u + k] > 0.0) {
            c |= 1u << k;
        }
    }
    classes[i] = c | (table[c * params.stride] << 8u);
}

@compute @workgroup_size(64)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_index(gid, nwg);
    if (i >= params.n_cells) {
        return;
    }
    let cls = classes[i];
    let c = cls & 255u;
    let ntris = cls >> 8u;
    if (ntris == 0u) {
        return;
    }
    var v: array<f32, 8>;
    for (var k = 0u; k < 8u; k++) {
        v[k] = values[i * 8u + k];
    }
    let cell = vec3<u32>(cells[i * 3u], cells[i * 3u + 1u], cells[i * 3u + 2u]);
    let r = f32(params.resolution);
    let n = params.resolution + 1u;

    var key: array<u32, 12>;
    var pos: array<vec3<f32>, 12>;
    for (var e = 0u; e < 12u; e++) {
        let a = e / 4u;
        let lo_c = ((e & 1u) << ((a + 1u) % 3u)) | (((e >> 1u) & 1u) << ((a + 2u) % 3u));
        let hi_c = lo_c | (1u << a);
        let v0 = v[lo_c];
        let v1 = v[hi_c];
        if ((v0 > 0.0) == (v1 > 0.0)) {
            continue;
        }
        let t = v0 / (v0 - v1);
        let g = cell + vec3<u32>(lo_c & 1u, (lo_c >> 1u) & 1u, (lo_c >> 2u) & 1u);
        var p = params.lo.xyz + params.ext.xyz * (vec3<f32>(g) / r);
        p[a] = params.lo[a] + params.ext[a] * ((f32(g[a]) + t) / r);
        pos[e] = p;
        key[e] = 3u * (g.x + n * (g.y + n * g.z)) + a;
    }
    let base = c * params.stride;
    let first_tri = offsets[i];
    for (var t = 0u; t < ntris; t++) {
        for (var k = 0u; k < 3u; k++) {
            let lv = table[base + HEADER + 3u * t + k];
            let o = 4u * (3u * (first_tri + t) + k);
            soup[o] = key[lv];
            soup[o + 1u] = bitcast<u32>(pos[lv].x);
            soup[o + 2u] = bitcast<u32>(pos[lv].y);
            soup[o + 3u] = bitcast<u32>(pos[lv].z);
        }
    }
}
