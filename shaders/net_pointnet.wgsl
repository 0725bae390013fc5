// The encoder's per-point PointNet, its local max pooling, and the scatter-mean to the planes.
//
// WGSL has no float atomics, so the pooling is a gather, not a scatter: the host groups the
// points by (plane, cell) with a stable counting sort and uploads that CSR (`cell_start`,
// `cell_pts`, `cell_of`, `cell_dst`); one invocation then reduces one (cell, 4 channels) over
// its points in increasing point order, which makes the result deterministic.
//
// Per-point kernels are one invocation per point. Feature vectors are arrays of vec4 (channel
// 4b + l is lane l of vec4 b, zero-padded), and every Linear layer is a sequence of
// `mat4x4 * vec4` products over 4x4 blocks of its weight matrix, repacked by the host (see
// `pack_linear` in src/net/gpu.rs): 16 multiply-adds per 4 vector loads, and loops short enough
// for drivers to keep the arrays in registers. Block counts are pasted in from the config at
// pipeline creation: `{{HB}}` = ceil(h / 4), `{{CB}}` = ceil(c_dim / 4), `{{XB}}` = the widest
// input in blocks (the concatenation [net | pooled], 2 HB). Each block sum starts from 0 and the
// bias is added last. Dispatch: 1-D work folded into 2-D (index = gid.x + gid.y * nwg.x * WG).

const HB: u32 = {{HB}}u;
const CB: u32 = {{CB}}u;
const XB: u32 = {{XB}}u;
const C_DIM: u32 = {{C_DIM}}u;
const WG: u32 = 64u;

struct Params {
    n: u32,      // items in this dispatch
    fc0_w: u32,  // offsets (vec4 units) into `w` of the ResBlock's packed layers
    fc0_b: u32,
    fc1_w: u32,
    fc1_b: u32,
    sc_w: u32,
    nin: u32,    // the ResBlock's input width in blocks
    lin_w: u32,  // fc_pos (enc_first) or fc_c (the last enc_block)
    lin_b: u32,
    last: u32,   // enc_block: 1 = apply fc_c and write `cfeat` instead of `net`
    rr: u32,     // reso * reso
    _pad: u32,
}

@group(0) @binding(0) var<uniform> prm: Params;
@group(0) @binding(1) var<storage, read> w: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> points: array<f32>;              // N x 3
@group(0) @binding(3) var<storage, read_write> net: array<vec4<f32>>;     // N x HB
@group(0) @binding(4) var<storage, read> cell_of: array<u32>;             // N x 3 (compact cell ids)
@group(0) @binding(5) var<storage, read> cell_start: array<u32>;          // K + 1
@group(0) @binding(6) var<storage, read> cell_pts: array<u32>;            // 3 N point ids
@group(0) @binding(7) var<storage, read_write> cell_max: array<vec4<f32>>; // K x HB
@group(0) @binding(8) var<storage, read_write> cfeat: array<vec4<f32>>;   // N x CB
@group(0) @binding(9) var<storage, read> cell_dst: array<u32>;            // K: plane * rr + cell
@group(0) @binding(10) var<storage, read_write> planes: array<f32>;       // 3 x C_DIM x rr

fn linear_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG;
}

fn mat_at(i: u32) -> mat4x4<f32> {
    return mat4x4<f32>(w[i], w[i + 1u], w[i + 2u], w[i + 3u]);
}

// out[0..nout] = W (relu?(x))[0..nin] (+ bias when b_off != NO_BIAS), in 4x4 blocks.
const NO_BIAS: u32 = 0xffffffffu;
fn linear(
    x: ptr<function, array<vec4<f32>, XB>>, nin: u32, relu_in: bool,
    w_off: u32, b_off: u32, nout: u32, out: ptr<function, array<vec4<f32>, XB>>,
) {
    for (var o = 0u; o < nout; o++) {
        var acc = vec4<f32>(0.0);
        for (var k = 0u; k < nin; k++) {
            var v = (*x)[k];
            if (relu_in) {
                v = max(v, vec4<f32>(0.0));
            }
            acc += mat_at(w_off + 4u * (o * nin + k)) * v;
        }
        if (b_off != NO_BIAS) {
            acc += w[b_off + o];
        }
        (*out)[o] = acc;
    }
}

// ResBlock(nin blocks -> HB) with a bias-free shortcut: out = sc(x) + fc_1(relu(fc_0(relu(x)))).
fn resblock(x: ptr<function, array<vec4<f32>, XB>>, out: ptr<function, array<vec4<f32>, XB>>) {
    var hid: array<vec4<f32>, XB>;
    var dx: array<vec4<f32>, XB>;
    linear(x, prm.nin, true, prm.fc0_w, prm.fc0_b, HB, &hid);
    linear(&hid, HB, true, prm.fc1_w, prm.fc1_b, HB, &dx);
    linear(x, prm.nin, false, prm.sc_w, NO_BIAS, HB, out);
    for (var o = 0u; o < HB; o++) {
        (*out)[o] += dx[o];
    }
}

// net = blocks[0](fc_pos(p)), one invocation per point.
@compute @workgroup_size(64)
fn enc_first(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = linear_index(gid, nwg);
    if (n >= prm.n) {
        return;
    }
    var p: array<vec4<f32>, XB>;
    p[0] = vec4<f32>(points[3u * n], points[3u * n + 1u], points[3u * n + 2u], 0.0);
    var x: array<vec4<f32>, XB>;
    linear(&p, 1u, false, prm.lin_w, prm.lin_b, prm.nin, &x);
    var out: array<vec4<f32>, XB>;
    resblock(&x, &out);
    for (var o = 0u; o < HB; o++) {
        net[n * HB + o] = out[o];
    }
}

// cell_max[k, b] = max over the points of non-empty cell k of net[., b] (4 channels).
@compute @workgroup_size(64)
fn enc_cellmax(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.n) {
        return;
    }
    let k = idx / HB;
    let b = idx % HB;
    let s = cell_start[k];
    let e = cell_start[k + 1u];
    // Cells in the list are never empty, so start from the first point (no -inf literal in WGSL).
    var m = net[cell_pts[s] * HB + b];
    for (var j = s + 1u; j < e; j++) {
        m = max(m, net[cell_pts[j] * HB + b]);
    }
    cell_max[idx] = m;
}

// net = blocks[i](concat(net, pooled)), pooled = sum over the 3 planes of the point's cell max;
// for the last block also c = fc_c(net), written to `cfeat`. One invocation per point; it reads
// and writes only its own row of `net`, so the update is in place.
@compute @workgroup_size(64)
fn enc_block(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = linear_index(gid, nwg);
    if (n >= prm.n) {
        return;
    }
    var x: array<vec4<f32>, XB>;
    let k0 = cell_of[3u * n] * HB;
    let k1 = cell_of[3u * n + 1u] * HB;
    let k2 = cell_of[3u * n + 2u] * HB;
    for (var b = 0u; b < HB; b++) {
        x[b] = net[n * HB + b];
        var s = vec4<f32>(0.0);
        s += cell_max[k0 + b];
        s += cell_max[k1 + b];
        s += cell_max[k2 + b];
        x[HB + b] = s;
    }
    var out: array<vec4<f32>, XB>;
    resblock(&x, &out);
    if (prm.last != 0u) {
        var c: array<vec4<f32>, XB>;
        linear(&out, HB, false, prm.lin_w, prm.lin_b, CB, &c);
        for (var o = 0u; o < CB; o++) {
            cfeat[n * CB + o] = c[o];
        }
    } else {
        for (var o = 0u; o < HB; o++) {
            net[n * HB + o] = out[o];
        }
    }
}

// planes[plane, 4b + l, cell] = mean over the points of non-empty cell k of cfeat[., b][l]
// (sum in point order, then one division). Empty cells keep the buffer's zeros.
@compute @workgroup_size(64)
fn enc_scatter(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.n) {
        return;
    }
    let k = idx / CB;
    let b = idx % CB;
    let s = cell_start[k];
    let e = cell_start[k + 1u];
    var acc = vec4<f32>(0.0);
    for (var j = s; j < e; j++) {
        acc += cfeat[cell_pts[j] * CB + b];
    }
    let mean = acc / f32(e - s);
    let dst = cell_dst[k];
    let plane = dst / prm.rr;
    let cell = dst % prm.rr;
    for (var l = 0u; l < 4u; l++) {
        let ch = 4u * b + l;
        if (ch < C_DIM) {
            planes[(plane * C_DIM + ch) * prm.rr + cell] = mean[l];
        }
    }
}
