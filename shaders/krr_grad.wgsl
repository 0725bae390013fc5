// The n-sized half of the gradient of the Nyström tuning objective (docs/method.md §6), per row
// block of K~ (24-bit fixed point, rows x m, from krr_kernel_block.wgsl; K~_ij = q_ij 2^-24):
//
//   residual:     r_i = sum_j K~_ij beta_j - y_i
//   grad_p:       P_ij = G_ij K~_ij,  G = K~ W + s_r r beta^T   (G is formed tile by tile, never stored)
//   grad_reduce:  per chunk of rows, for every (j, d):
//                   gz_jd = sum_i P_ij (x_id - z_jd),   gs_jd = sum_i P_ij (x_id - z_jd)^2
//                 into partials[chunk] (differences, not P^T X - diag(P^T 1) Z: no cancellation)
//   grad_sum:     partials summed over chunks -> 2 x m x D values for the host
//
// Sums longer than a tile use Kahan compensation: f32 only (browsers have no f64); the uniform
// `one` (= 1.0) keeps the compiler from simplifying the compensation away (see krr_gram.wgsl).
// D is pasted in at pipeline creation ({{D}}); DQ = ceil(D / 8), DP = 8 DQ.
// Binding numbers are unique across the module; each entry point uses a subset.

struct Dims {
    rows: u32,       // rows in this block
    row0: u32,       // global index of the block's first row
    m: u32,
    _s: u32,
    chunk_rows: u32, // rows per grad_reduce chunk
    chunk0: u32,     // global index of the block's first chunk
    s_r: f32,        // (c T2 + 2)(2 / n)
    one: f32,        // 1.0, opaque to the compiler (see krr_gram.wgsl)
}

struct SumDims { len: u32, chunks: u32, one: f32, _b: u32 }

const Q: f32 = 5.9604644775390625e-8; // 2^-24
const D: u32 = {{D}}u;
const DQ: u32 = {{DQ}}u;
const DP: u32 = {{DP}}u;

@group(0) @binding(0) var<storage, read> kb: array<u32>;          // rows x m (block), fixed point
@group(0) @binding(1) var<storage, read> w: array<f32>;           // m x m
@group(0) @binding(2) var<storage, read> beta: array<f32>;        // m
@group(0) @binding(3) var<storage, read_write> r: array<f32>;     // n (global rows)
@group(0) @binding(4) var<storage, read_write> p: array<f32>;     // rows x m (block)
@group(0) @binding(5) var<storage, read> x: array<f32>;           // n x D
@group(0) @binding(6) var<storage, read> z: array<f32>;           // m x D
@group(0) @binding(7) var<storage, read_write> part: array<f32>;  // chunks x 2 x m x D
@group(0) @binding(8) var<uniform> dims: Dims;
@group(0) @binding(9) var<storage, read> part_in: array<f32>;     // chunks x len
@group(0) @binding(10) var<storage, read_write> sums: array<f32>; // len
@group(0) @binding(11) var<uniform> sdims: SumDims;
@group(0) @binding(12) var<storage, read> y: array<f32>;          // n

// ---------------------------------------------------------------------------------------------

@compute @workgroup_size(64)
fn residual(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nw: vec3<u32>) {
    let i = gid.x + gid.y * nw.x * 64u;
    if (i >= dims.rows) {
        return;
    }
    let base = i * dims.m;
    var sum = 0.0;
    var comp = 0.0;
    for (var j = 0u; j < dims.m; j++) {
        let yv = f32(kb[base + j]) * Q * beta[j] - comp;
        let t = (sum + yv) * dims.one;
        comp = (t - sum) - yv;
        sum = t;
    }
    // (sum - comp) - y, with the nearly-equal pair subtracted first.
    r[dims.row0 + i] = (sum - y[dims.row0 + i]) - comp;
}

// ---------------------------------------------------------------------------------------------

var<workgroup> ka: array<array<f32, 16>, 64>;          // ka[row][k]
var<workgroup> wb: array<array<vec4<f32>, 16>, 16>;    // wb[k][c] = W[k][c + 16 b], b = 0..3

// Kahan-compensated running sum of vec4s (see `one` above).
struct Kahan4 { s: vec4<f32>, c: vec4<f32> }

fn kahan4(k: Kahan4, v: vec4<f32>) -> Kahan4 {
    let y = v - k.c;
    let t = (k.s + y) * dims.one;
    return Kahan4(t, (t - k.s) - y);
}

// Epilogue for one output row: P = (K~ W + s_r r beta^T) o K~ at columns c + 16 b.
fn store_p(row: u32, c: u32, kw: Kahan4) {
    if (row >= dims.rows) {
        return;
    }
    let m = dims.m;
    let sr_ri = dims.s_r * r[dims.row0 + row];
    let g = kw.s - kw.c;
    for (var b = 0u; b < 4u; b++) {
        let col = c + 16u * b;
        if (col < m) {
            p[row * m + col] = (g[b] + sr_ri * beta[col]) * (f32(kb[row * m + col]) * Q);
        }
    }
}

// 64 x 64 tile of P per workgroup; invocation (x, y) owns rows y + 16 a and columns x + 16 b
// (a, b = 0..3) as four vec4 accumulators — no dynamically indexed private arrays, which
// llvmpipe spills to memory.
@compute @workgroup_size(16, 16)
fn grad_p(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let r0 = wg.y * 64u;
    let c0 = wg.x * 64u;
    let m = dims.m;
    var k0s = Kahan4(vec4<f32>(), vec4<f32>());
    var k1s = k0s;
    var k2s = k0s;
    var k3s = k0s;
    for (var k0 = 0u; k0 < m; k0 += 16u) {
        for (var q = 0u; q < 4u; q++) {
            let e = li + 256u * q;
            // K tile: 64 rows x 16 k.
            let rr = e / 16u;
            let kk = e % 16u;
            let row = r0 + rr;
            var kv = 0.0;
            if (row < dims.rows && k0 + kk < m) {
                kv = f32(kb[row * m + k0 + kk]) * Q;
            }
            ka[rr][kk] = kv;
            // W tile: 16 k x 64 cols.
            let wk = e / 64u;
            let wc = e % 64u;
            var wv = 0.0;
            if (k0 + wk < m && c0 + wc < m) {
                wv = w[(k0 + wk) * m + c0 + wc];
            }
            wb[wk][wc % 16u][wc / 16u] = wv;
        }
        workgroupBarrier();
        var a0 = vec4<f32>();
        var a1 = vec4<f32>();
        var a2 = vec4<f32>();
        var a3 = vec4<f32>();
        for (var kk = 0u; kk < 16u; kk++) {
            let bv = wb[kk][lid.x];
            a0 += ka[lid.y][kk] * bv;
            a1 += ka[lid.y + 16u][kk] * bv;
            a2 += ka[lid.y + 32u][kk] * bv;
            a3 += ka[lid.y + 48u][kk] * bv;
        }
        workgroupBarrier();
        k0s = kahan4(k0s, a0);
        k1s = kahan4(k1s, a1);
        k2s = kahan4(k2s, a2);
        k3s = kahan4(k3s, a3);
    }
    let c = c0 + lid.x;
    store_p(r0 + lid.y, c, k0s);
    store_p(r0 + lid.y + 16u, c, k1s);
    store_p(r0 + lid.y + 32u, c, k2s);
    store_p(r0 + lid.y + 48u, c, k3s);
}

// ---------------------------------------------------------------------------------------------

var<workgroup> xs: array<f32, 32u * DP>;       // 32 rows x DP dims
var<workgroup> ps: array<array<f32, 32>, 32>;  // ps[row][j - j0]

// 256 invocations: 32 inducing points x 8 dimension groups (dimension t = dg + 8 q).
@compute @workgroup_size(256)
fn grad_reduce(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let m = dims.m;
    let jl = li % 32u;
    let dg = li / 32u;
    let j0 = wg.x * 32u;
    let j = j0 + jl;
    let start = wg.y * dims.chunk_rows;
    let end = min(start + dims.chunk_rows, dims.rows);
    var zj: array<f32, DQ>;
    for (var q = 0u; q < DQ; q++) {
        let t = dg + 8u * q;
        if (j < m && t < D) {
            zj[q] = z[j * D + t];
        }
    }
    var gz: array<f32, DQ>;
    var cz: array<f32, DQ>;
    var gs: array<f32, DQ>;
    var cs: array<f32, DQ>;
    for (var r0 = start; r0 < end; r0 += 32u) {
        for (var e = li; e < 32u * DP; e += 256u) {
            let rr = e / DP;
            let t = e % DP;
            let row = r0 + rr;
            var xv = 0.0;
            if (row < end && t < D) {
                xv = x[(dims.row0 + row) * D + t];
            }
            xs[e] = xv;
        }
        for (var q = 0u; q < 4u; q++) {
            let e = li + 256u * q;
            let rr = e / 32u;
            let cc = e % 32u;
            let row = r0 + rr;
            var pv = 0.0;
            if (row < end && j0 + cc < m) {
                pv = p[row * m + j0 + cc];
            }
            ps[rr][cc] = pv;
        }
        workgroupBarrier();
        var tz: array<f32, DQ>;
        var ts: array<f32, DQ>;
        for (var rr = 0u; rr < 32u; rr++) {
            let pv = ps[rr][jl];
            for (var q = 0u; q < DQ; q++) {
                let e = xs[rr * DP + dg + 8u * q] - zj[q];
                let pe = pv * e;
                tz[q] += pe;
                ts[q] += pe * e;
            }
        }
        workgroupBarrier();
        for (var q = 0u; q < DQ; q++) {
            let y1 = tz[q] - cz[q];
            let t1 = (gz[q] + y1) * dims.one;
            cz[q] = (t1 - gz[q]) - y1;
            gz[q] = t1;
            let y2 = ts[q] - cs[q];
            let t2 = (gs[q] + y2) * dims.one;
            cs[q] = (t2 - gs[q]) - y2;
            gs[q] = t2;
        }
    }
    if (j < m) {
        let base = (dims.chunk0 + wg.y) * 2u * m * D;
        for (var q = 0u; q < DQ; q++) {
            let t = dg + 8u * q;
            if (t < D) {
                part[base + j * D + t] = gz[q] - cz[q];
                part[base + m * D + j * D + t] = gs[q] - cs[q];
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------

@compute @workgroup_size(64)
fn grad_sum(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nw: vec3<u32>) {
    let i = gid.x + gid.y * nw.x * 64u;
    if (i >= sdims.len) {
        return;
    }
    var sum = 0.0;
    var comp = 0.0;
    for (var c = 0u; c < sdims.chunks; c++) {
        let yv = part_in[c * sdims.len + i] - comp;
        let t = (sum + yv) * sdims.one;
        comp = (t - sum) - yv;
        sum = t;
    }
    sums[i] = sum - comp;
}
