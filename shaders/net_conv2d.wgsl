// The U-Net's layers over the three planes at once: tensors are [P = 3][C][R][R] f32.
//
// conv3x3: 3x3, stride 1, zero padding 1, optional ReLU. One invocation computes 4 output
// channels (a vec4) of one pixel, so every input tap loaded is used 4 times; neighbouring
// invocations take neighbouring pixels (coalesced input loads) and share the weights (uniform
// loads). The host repacks the PyTorch weights [O][C][3][3] as vec4s [C][9][ceil(O/4)] (lanes past
// O are zero) followed by the bias as ceil(O/4) vec4s. The input may be the channel concatenation
// of two tensors (U-Net up path: upconv output first, then the skip): channels < c_a come from
// `in_a`, the rest from `in_b`, so the concatenation is never materialised.
// maxpool2, upconv2 (ConvTranspose2d k=2 s=2) and conv1x1 are one invocation per output element
// reading the PyTorch layouts directly from `w`.
// Every sum starts from 0, runs over input channels then taps in order, and adds the bias last,
// like the CPU reference. Dispatch: 1-D work folded into 2-D (index = gid.x + gid.y * nwg.x * WG).

const WG: u32 = 64u;

struct Params {
    total: u32,  // output elements (conv3x3: pixels * channel groups)
    r: u32,      // output resolution
    c_a: u32,    // channels of in_a
    c_b: u32,    // channels of in_b (0: no concatenation)
    c_out: u32,
    groups: u32, // ceil(c_out / 4) (conv3x3)
    w_off: u32,  // weight offset (conv3x3: vec4 units into wv; others: f32 units into w)
    b_off: u32,  // bias offset, same units
    relu: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> prm: Params;
@group(0) @binding(1) var<storage, read> in_a: array<f32>;
@group(0) @binding(2) var<storage, read> in_b: array<f32>;
@group(0) @binding(3) var<storage, read> wv: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;
@group(0) @binding(5) var<storage, read> w: array<f32>;

fn linear_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG;
}

@compute @workgroup_size(64)
fn conv3x3(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.total) {
        return;
    }
    let r = prm.r;
    let rr = r * r;
    let x = idx % r;
    var t = idx / r;
    let y = t % r;
    t = t / r;
    let g = t % prm.groups;
    let p = t / prm.groups;
    let xi = i32(x);
    let yi = i32(y);
    let ri = i32(r);
    var acc = vec4<f32>(0.0);
    for (var c = 0u; c < prm.c_a; c++) {
        let base = (p * prm.c_a + c) * rr;
        let wbase = prm.w_off + c * 9u * prm.groups + g;
        for (var ky = 0; ky < 3; ky++) {
            let sy = yi + ky - 1;
            if (sy < 0 || sy >= ri) {
                continue;
            }
            for (var kx = 0; kx < 3; kx++) {
                let sx = xi + kx - 1;
                if (sx < 0 || sx >= ri) {
                    continue;
                }
                let v = in_a[base + u32(sy) * r + u32(sx)];
                acc += v * wv[wbase + u32(ky * 3 + kx) * prm.groups];
            }
        }
    }
    for (var c = 0u; c < prm.c_b; c++) {
        let base = (p * prm.c_b + c) * rr;
        let wbase = prm.w_off + (prm.c_a + c) * 9u * prm.groups + g;
        for (var ky = 0; ky < 3; ky++) {
            let sy = yi + ky - 1;
            if (sy < 0 || sy >= ri) {
                continue;
            }
            for (var kx = 0; kx < 3; kx++) {
                let sx = xi + kx - 1;
                if (sx < 0 || sx >= ri) {
                    continue;
                }
                let v = in_b[base + u32(sy) * r + u32(sx)];
                acc += v * wv[wbase + u32(ky * 3 + kx) * prm.groups];
            }
        }
    }
    acc += wv[prm.b_off + g];
    if (prm.relu != 0u) {
        acc = max(acc, vec4<f32>(0.0));
    }
    for (var l = 0u; l < 4u; l++) {
        let o = 4u * g + l;
        if (o < prm.c_out) {
            out[(p * prm.c_out + o) * rr + y * r + x] = acc[l];
        }
    }
}

// out[pc, i, j] = max of in[pc, 2i..2i+1, 2j..2j+1]; total = 3 * C * r * r, r = output reso.
@compute @workgroup_size(64)
fn maxpool2(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.total) {
        return;
    }
    let r = prm.r;
    let x = idx % r;
    let y = (idx / r) % r;
    let pc = idx / (r * r);
    let ri = 2u * r;
    let base = pc * ri * ri + 2u * y * ri + 2u * x;
    let m = max(max(in_a[base], in_a[base + 1u]), max(in_a[base + ri], in_a[base + ri + 1u]));
    out[idx] = m;
}

// ConvTranspose2d(c_a -> c_out, kernel 2, stride 2), PyTorch weight [c_a][c_out][2][2]:
// out[o, 2i+di, 2j+dj] = bias[o] + sum_c in[c, i, j] W[c, o, di, dj]; r = output reso.
@compute @workgroup_size(64)
fn upconv2(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.total) {
        return;
    }
    let r = prm.r;
    let x = idx % r;
    let y = (idx / r) % r;
    let t = idx / (r * r);
    let o = t % prm.c_out;
    let p = t / prm.c_out;
    let rin = r / 2u;
    let i = y / 2u;
    let j = x / 2u;
    let tap = (y % 2u) * 2u + (x % 2u);
    var acc = 0.0;
    for (var c = 0u; c < prm.c_a; c++) {
        acc += in_a[((p * prm.c_a + c) * rin + i) * rin + j] * w[prm.w_off + (c * prm.c_out + o) * 4u + tap];
    }
    out[idx] = acc + w[prm.b_off + o];
}

// 1x1 convolution, PyTorch weight [c_out][c_a][1][1], no activation.
@compute @workgroup_size(64)
fn conv1x1(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.total) {
        return;
    }
    let rr = prm.r * prm.r;
    let i = idx % rr;
    let t = idx / rr;
    let o = t % prm.c_out;
    let p = t / prm.c_out;
    var acc = 0.0;
    for (var c = 0u; c < prm.c_a; c++) {
        acc += in_a[(p * prm.c_a + c) * rr + i] * w[prm.w_off + o * prm.c_a + c];
    }
    out[idx] = acc + w[prm.b_off + o];
}
