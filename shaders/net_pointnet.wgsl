// The encoder's per-point PointNet, its local max pooling, and the scatter-mean to the planes.
//
// WGSL has no float atomics, so the pooling is a gather, not a scatter: the host groups the
// points by (plane, cell) with a stable counting sort and uploads that CSR (`cell_start`,
// `cell_pts`, `cell_of`, `cell_dst`); one invocation then reduces one (cell, channel) over its
// points in increasing point order, which makes the result deterministic and equal to the CPU
// reference. Per-point kernels are one invocation per point with private arrays sized by the
// config: `{{H}}` and `{{C_DIM}}` are replaced from the weights' metadata at pipeline creation.
// Dispatch: 1-D work folded into 2-D (index = gid.x + gid.y * num_workgroups.x * WG).
//
// Linear layers accumulate from 0 in input order and add the bias last, like the CPU reference.

const H: u32 = {{H}}u;
const H2: u32 = 2u * {{H}}u;
const C_DIM: u32 = {{C_DIM}}u;
const WG: u32 = 64u;

struct Params {
    n: u32,      // items in this dispatch
    fc0_w: u32,  // offsets (f32 elements) into `w` of the ResBlock's tensors
    fc0_b: u32,
    fc1_w: u32,
    fc1_b: u32,
    sc_w: u32,
    lin_w: u32,  // fc_pos (enc_first) or fc_c (the last enc_block)
    lin_b: u32,
    last: u32,   // enc_block: 1 = apply fc_c and write `cfeat` instead of `net`
    rr: u32,     // reso * reso
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> prm: Params;
@group(0) @binding(1) var<storage, read> w: array<f32>;
@group(0) @binding(2) var<storage, read> points: array<f32>;        // N x 3
@group(0) @binding(3) var<storage, read_write> net: array<f32>;     // N x H
@group(0) @binding(4) var<storage, read> cell_of: array<u32>;       // N x 3 (compact cell ids)
@group(0) @binding(5) var<storage, read> cell_start: array<u32>;    // K + 1
@group(0) @binding(6) var<storage, read> cell_pts: array<u32>;      // 3 N point ids
@group(0) @binding(7) var<storage, read_write> cell_max: array<f32>; // K x H
@group(0) @binding(8) var<storage, read_write> cfeat: array<f32>;   // N x C_DIM
@group(0) @binding(9) var<storage, read> cell_dst: array<u32>;      // K: plane * rr + cell
@group(0) @binding(10) var<storage, read_write> planes: array<f32>; // 3 x C_DIM x rr

fn linear_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG;
}

// ResBlock(n_in -> H) with a bias-free shortcut: out = sc(x) + fc_1(relu(fc_0(relu(x)))).
fn resblock(x: ptr<function, array<f32, H2>>, n_in: u32, out: ptr<function, array<f32, H2>>) {
    var hid: array<f32, H2>;
    for (var o = 0u; o < H; o++) {
        var acc = 0.0;
        let row = prm.fc0_w + o * n_in;
        for (var i = 0u; i < n_in; i++) {
            acc += w[row + i] * max((*x)[i], 0.0);
        }
        hid[o] = acc + w[prm.fc0_b + o];
    }
    for (var o = 0u; o < H; o++) {
        var acc = 0.0;
        let row = prm.fc1_w + o * H;
        for (var i = 0u; i < H; i++) {
            acc += w[row + i] * max(hid[i], 0.0);
        }
        let dx = acc + w[prm.fc1_b + o];
        var sc = 0.0;
        let srow = prm.sc_w + o * n_in;
        for (var i = 0u; i < n_in; i++) {
            sc += w[srow + i] * (*x)[i];
        }
        (*out)[o] = sc + dx;
    }
}

// net = blocks[0](fc_pos(p)), one invocation per point.
@compute @workgroup_size(64)
fn enc_first(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = linear_index(gid, nwg);
    if (n >= prm.n) {
        return;
    }
    let p = array<f32, 3>(points[3u * n], points[3u * n + 1u], points[3u * n + 2u]);
    var x: array<f32, H2>;
    for (var o = 0u; o < H2; o++) {
        var acc = 0.0;
        for (var i = 0u; i < 3u; i++) {
            acc += w[prm.lin_w + o * 3u + i] * p[i];
        }
        x[o] = acc + w[prm.lin_b + o];
    }
    var out: array<f32, H2>;
    resblock(&x, H2, &out);
    for (var o = 0u; o < H; o++) {
        net[n * H + o] = out[o];
    }
}

// cell_max[k, ch] = max over the points of non-empty cell k of net[., ch].
@compute @workgroup_size(64)
fn enc_cellmax(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.n) {
        return;
    }
    let k = idx / H;
    let ch = idx % H;
    let s = cell_start[k];
    let e = cell_start[k + 1u];
    // Cells in the list are never empty, so start from the first point (no -inf literal in WGSL).
    var m = net[cell_pts[s] * H + ch];
    for (var j = s + 1u; j < e; j++) {
        m = max(m, net[cell_pts[j] * H + ch]);
    }
    cell_max[idx] = m;
}

// net = blocks[b](concat(net, pooled)), pooled = sum over the 3 planes of the point's cell max;
// for the last block also c = fc_c(net), written to `cfeat`. One invocation per point; it reads
// and writes only its own row of `net`, so the update is in place.
@compute @workgroup_size(64)
fn enc_block(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = linear_index(gid, nwg);
    if (n >= prm.n) {
        return;
    }
    var x: array<f32, H2>;
    let k0 = cell_of[3u * n] * H;
    let k1 = cell_of[3u * n + 1u] * H;
    let k2 = cell_of[3u * n + 2u] * H;
    for (var ch = 0u; ch < H; ch++) {
        x[ch] = net[n * H + ch];
        var s = 0.0;
        s += cell_max[k0 + ch];
        s += cell_max[k1 + ch];
        s += cell_max[k2 + ch];
        x[H + ch] = s;
    }
    var out: array<f32, H2>;
    resblock(&x, H2, &out);
    if (prm.last != 0u) {
        for (var o = 0u; o < C_DIM; o++) {
            var acc = 0.0;
            let row = prm.lin_w + o * H;
            for (var i = 0u; i < H; i++) {
                acc += w[row + i] * out[i];
            }
            cfeat[n * C_DIM + o] = acc + w[prm.lin_b + o];
        }
    } else {
        for (var o = 0u; o < H; o++) {
            net[n * H + o] = out[o];
        }
    }
}

// planes[plane, ch, cell] = mean over the points of non-empty cell k of cfeat[., ch]
// (sum in point order, then one division). Empty cells keep the buffer's zeros.
@compute @workgroup_size(64)
fn enc_scatter(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.n) {
        return;
    }
    let k = idx / C_DIM;
    let ch = idx % C_DIM;
    let s = cell_start[k];
    let e = cell_start[k + 1u];
    var acc = 0.0;
    for (var j = s; j < e; j++) {
        acc += cfeat[cell_pts[j] * C_DIM + ch];
    }
    let dst = cell_dst[k];
    let plane = dst / prm.rr;
    let cell = dst % prm.rr;
    planes[(plane * C_DIM + ch) * prm.rr + cell] = acc / f32(e - s);
}
