// The Nyström predictor g(q) = sum_j beta_j k(q, z_j) for a chunk of queries.
//
// Tiled like krr_kernel_block.wgsl, with the same distances (krr_distance_tile.wgsl, prepended at
// pipeline creation): a workgroup of 16 x 16 invocations owns 64 queries and sweeps the inducing
// points [j_begin, j_end) 64 at a time; invocation (x, y) gets the kernel for queries y + 16 a
// and inducing points x + 16 b (a, b = 0..3) as four vec4s, then adds beta-weighted rows into a
// Kahan-compensated sum (beta can be large with cancelling signs); at the end the 16 partial sums
// of each query are added in workgroup memory.
//
// The host splits m into dispatches of a few hundred inducing points, each added into
// (out_hi, out_lo) with a TwoSum (the first overwrites): llvmpipe (lavapipe) silently ends an
// invocation's loops after 65535 iterations in total (see krr_gram.wgsl). `one` = 1.0 keeps the
// compiler from simplifying the compensation away. Workgroups fold into 2-D dispatches
// (index = wg.x + wg.y * nw.x).

struct Dims { q: u32, j_begin: u32, j_end: u32, first: u32, one: f32, _a: u32, _b: u32, _c: u32 }

const D: u32 = {{D}}u;
const TD: u32 = 16u;

@group(0) @binding(0) var<storage, read> x: array<f32>;        // queries, q x D
@group(0) @binding(1) var<storage, read> z: array<f32>;        // m x D
@group(0) @binding(2) var<storage, read> inv_s: array<f32>;    // D
@group(0) @binding(3) var<storage, read> beta: array<f32>;     // m
@group(0) @binding(4) var<storage, read_write> out: array<f32>; // 2 x q: hi, then lo
@group(0) @binding(5) var<uniform> dims: Dims;

var<workgroup> xs: array<array<f32, 16>, 64>;        // xs[query][t]
var<workgroup> zs: array<array<vec4<f32>, 16>, 16>;  // zs[t][c] = Z[j0 + c + 16 b][t]
var<workgroup> ws: array<f32, 16>;
var<workgroup> red: array<array<f32, 16>, 64>;       // red[query][x]

struct Kahan { s: f32, c: f32 }

fn kahan(k: Kahan, v: f32) -> Kahan {
    let y = v - k.c;
    let t = (k.s + y) * dims.one;
    return Kahan(t, (t - k.s) - y);
}

@compute @workgroup_size(16, 16)
fn predict(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nw: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let r0 = (wg.x + wg.y * nw.x) * 64u;
    var s0 = Kahan(0.0, 0.0);
    var s1 = s0;
    var s2 = s0;
    var s3 = s0;
    for (var j0 = dims.j_begin; j0 < dims.j_end; j0 += 64u) {
        let tile = distance_tile(r0, dims.q, j0, dims.j_end, li, lid);
        // beta of this invocation's four inducing points (0 past the end).
        var bv = vec4<f32>();
        for (var b = 0u; b < 4u; b++) {
            let j = j0 + lid.x + 16u * b;
            if (j < dims.j_end) {
                bv[b] = beta[j];
            }
        }
        s0 = kahan(s0, dot(bv, exp(-0.5 * tile.d0)));
        s1 = kahan(s1, dot(bv, exp(-0.5 * tile.d1)));
        s2 = kahan(s2, dot(bv, exp(-0.5 * tile.d2)));
        s3 = kahan(s3, dot(bv, exp(-0.5 * tile.d3)));
    }
    red[lid.y][lid.x] = s0.s - s0.c;
    red[lid.y + 16u][lid.x] = s1.s - s1.c;
    red[lid.y + 32u][lid.x] = s2.s - s2.c;
    red[lid.y + 48u][lid.x] = s3.s - s3.c;
    workgroupBarrier();
    if (li < 64u) {
        let row = r0 + li;
        if (row < dims.q) {
            // Pairwise over the 16 partial sums.
            var v: array<f32, 16>;
            for (var x = 0u; x < 16u; x++) {
                v[x] = red[li][x];
            }
            for (var h = 8u; h > 0u; h = h / 2u) {
                for (var x = 0u; x < h; x++) {
                    v[x] = v[x] + v[x + h];
                }
            }
            let part = v[0];
            if (dims.first != 0u) {
                out[row] = part;
                out[dims.q + row] = 0.0;
            } else {
                // TwoSum(hi, part).
                let hi = out[row];
                let t = (hi + part) * dims.one;
                let bp = (t - hi) * dims.one;
                let err = (hi - (t - bp)) + (part - bp);
                out[row] = t;
                out[dims.q + row] = out[dims.q + row] + err;
            }
        }
    }
}
