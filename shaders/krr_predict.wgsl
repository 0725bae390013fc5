// The Nyström predictor g(q) = sum_j beta_j k(q, z_j) for a chunk of queries.
//
// Tiled like krr_kernel_block.wgsl: a workgroup of 16 x 16 invocations owns 64 queries and sweeps
// the inducing points [j_begin, j_end) 64 at a time; invocation (x, y) computes the kernel for
// queries y + 16 a and inducing points x + 16 b (a, b = 0..3) as four vec4s, dimensions staged 16
// at a time (queries, Z and 1/s in workgroup memory), then adds beta-weighted rows into a
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

@group(0) @binding(0) var<storage, read> queries: array<f32>;  // q x D
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
        var d0s = vec4<f32>();
        var d1s = vec4<f32>();
        var d2s = vec4<f32>();
        var d3s = vec4<f32>();
        for (var d0 = 0u; d0 < D; d0 += TD) {
            for (var q = 0u; q < 4u; q++) {
                let e = li + 256u * q;
                let rr = e / TD;
                let t = e % TD;
                let dim = d0 + t;
                let row = r0 + rr;
                let col = j0 + rr;
                var xv = 0.0;
                if (row < dims.q && dim < D) {
                    xv = queries[row * D + dim];
                }
                xs[rr][t] = xv;
                var zv = 0.0;
                if (col < dims.j_end && dim < D) {
                    zv = z[col * D + dim];
                }
                zs[t][rr % 16u][rr / 16u] = zv;
            }
            if (li < TD) {
                var wv = 0.0;
                if (d0 + li < D) {
                    wv = inv_s[d0 + li];
                }
                ws[li] = wv;
            }
            workgroupBarrier();
            for (var t = 0u; t < TD; t++) {
                let w = ws[t];
                let zv = zs[t][lid.x];
                let u0 = (xs[lid.y][t] - zv) * w;
                let u1 = (xs[lid.y + 16u][t] - zv) * w;
                let u2 = (xs[lid.y + 32u][t] - zv) * w;
                let u3 = (xs[lid.y + 48u][t] - zv) * w;
                d0s += u0 * u0;
                d1s += u1 * u1;
                d2s += u2 * u2;
                d3s += u3 * u3;
            }
            workgroupBarrier();
        }
        // beta of this invocation's four inducing points (0 past the end).
        var bv = vec4<f32>();
        for (var b = 0u; b < 4u; b++) {
            let j = j0 + lid.x + 16u * b;
            if (j < dims.j_end) {
                bv[b] = beta[j];
            }
        }
        s0 = kahan(s0, dot(bv, exp(-0.5 * d0s)));
        s1 = kahan(s1, dot(bv, exp(-0.5 * d1s)));
        s2 = kahan(s2, dot(bv, exp(-0.5 * d2s)));
        s3 = kahan(s3, dot(bv, exp(-0.5 * d3s)));
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
