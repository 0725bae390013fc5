// The U-Net's layers over the three planes at once: tensors are [P = 3][C][R][R] f32.
//
// All weighted layers compute blocks of 16 output channels per invocation (4 vec4 accumulators,
// register blocking; no workgroup memory, so no barriers, which software rasterisers handle
// badly). The host repacks the PyTorch weights as vec4s whose lane l of vec4 v holds output
// channel 4v + l (zero past the last channel), 4 * ceil(O / 16) vec4s per (input channel, tap),
// followed by the bias as 4 * ceil(O / 16) vec4s; see `pack_conv` in src/net/gpu.rs.
// - conv3x3: 3x3, stride 1, zero padding 1, optional ReLU; 16 channels at 4 consecutive pixels
//   of a row: per input channel and kernel row it loads 6 input values and 3 x 4 weight vec4s
//   for 192 multiply-adds. Weights [9 taps][C][vec4s]. Out-of-image taps read as 0 (adding
//   0 * w leaves a sum unchanged, so this equals skipping them). The input may be the channel
//   concatenation of two tensors (U-Net up path: upconv output first, then the skip): channels
//   < c_a come from `in_a`, the rest from `in_b`, so the concatenation is never materialised.
// - upconv2 (ConvTranspose2d k=2 s=2): 16 channels at the 4 output pixels of one input pixel.
// - final1x1: 16 channels at one pixel, written channel-last for the decoder (vec4 loads).
// - maxpool2: one invocation per output element.
// Neighbouring invocations take neighbouring pixels (coalesced input loads) and share the
// weights (uniform loads). Every sum starts from 0 and adds the bias last; conv3x3 sums over
// kernel row, input channel, kernel column in that order, like the CPU reference.
// Dispatch: 1-D work folded into 2-D (index = gid.x + gid.y * nwg.x * WG).

const WG: u32 = 64u;

struct Params {
    total: u32,  // invocations
    r: u32,      // output resolution
    c_a: u32,    // channels of in_a
    c_b: u32,    // channels of in_b (0: no concatenation)
    c_out: u32,
    groups: u32, // blocks of 16 output channels, ceil(c_out / 16)
    w_off: u32,  // weight offset, vec4 units into wv
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
@group(0) @binding(5) var<storage, read_write> out4: array<vec4<f32>>;

fn linear_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG;
}

// acc += v * w for one pixel's 16 output channels.
fn madd(acc: ptr<function, array<vec4<f32>, 4>>, v: f32, w: array<vec4<f32>, 4>) {
    (*acc)[0] += v * w[0];
    (*acc)[1] += v * w[1];
    (*acc)[2] += v * w[2];
    (*acc)[3] += v * w[3];
}

// The 16 output channels of block `blk` for tap `tap`, input channel `c`.
fn conv_w(tap: u32, c: u32, c_in: u32, blk: u32) -> array<vec4<f32>, 4> {
    let i = prm.w_off + (tap * c_in + c) * 4u * prm.groups + 4u * blk;
    return array<vec4<f32>, 4>(wv[i], wv[i + 1u], wv[i + 2u], wv[i + 3u]);
}

// Row segment in[c, sy, x0 - 1 .. x0 + 4] of one input, zero outside the image.
fn row6(from_b: bool, base: u32, x0: i32, r: i32) -> array<f32, 6> {
    var v: array<f32, 6>;
    for (var i = 0; i < 6; i++) {
        let sx = x0 + i - 1;
        let at = base + u32(clamp(sx, 0, r - 1));
        var val: f32;
        if (from_b) {
            val = in_b[at];
        } else {
            val = in_a[at];
        }
        v[i] = select(0.0, val, sx >= 0 && sx < r);
    }
    return v;
}

// One input channel's contribution, for taps (ky, 0..3), to the 4 pixels' accumulators.
fn conv_row(
    v: array<f32, 6>, tap0: u32, c: u32, c_in: u32, blk: u32,
    a0: ptr<function, array<vec4<f32>, 4>>, a1: ptr<function, array<vec4<f32>, 4>>,
    a2: ptr<function, array<vec4<f32>, 4>>, a3: ptr<function, array<vec4<f32>, 4>>,
) {
    for (var kx = 0u; kx < 3u; kx++) {
        let w = conv_w(tap0 + kx, c, c_in, blk);
        madd(a0, v[kx], w);
        madd(a1, v[kx + 1u], w);
        madd(a2, v[kx + 2u], w);
        madd(a3, v[kx + 3u], w);
    }
}

@compute @workgroup_size(64)
fn conv3x3(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.total) {
        return;
    }
    let r = prm.r;
    let rr = r * r;
    let xblocks = (r + 3u) / 4u;
    let x0 = (idx % xblocks) * 4u;
    var t = idx / xblocks;
    let y = t % r;
    t = t / r;
    let blk = t % prm.groups;
    let p = t / prm.groups;
    let ri = i32(r);
    let c_in = prm.c_a + prm.c_b;
    var a0: array<vec4<f32>, 4>;
    var a1: array<vec4<f32>, 4>;
    var a2: array<vec4<f32>, 4>;
    var a3: array<vec4<f32>, 4>;
    for (var ky = 0u; ky < 3u; ky++) {
        let sy = i32(y) + i32(ky) - 1;
        if (sy < 0 || sy >= ri) {
            continue;
        }
        let row = u32(sy) * r;
        for (var c = 0u; c < prm.c_a; c++) {
            let v = row6(false, (p * prm.c_a + c) * rr + row, i32(x0), ri);
            conv_row(v, 3u * ky, c, c_in, blk, &a0, &a1, &a2, &a3);
        }
        for (var c = 0u; c < prm.c_b; c++) {
            let v = row6(true, (p * prm.c_b + c) * rr + row, i32(x0), ri);
            conv_row(v, 3u * ky, prm.c_a + c, c_in, blk, &a0, &a1, &a2, &a3);
        }
    }
    let bi = prm.b_off + 4u * blk;
    let bias = array<vec4<f32>, 4>(wv[bi], wv[bi + 1u], wv[bi + 2u], wv[bi + 3u]);
    let px = array<array<vec4<f32>, 4>, 4>(a0, a1, a2, a3);
    let o0 = 16u * blk;
    for (var i = 0u; i < 4u; i++) {
        let x = x0 + i;
        if (x >= r) {
            break;
        }
        let base = (p * prm.c_out + o0) * rr + y * r + x;
        for (var j = 0u; j < 4u; j++) {
            var v = px[i][j] + bias[j];
            if (prm.relu != 0u) {
                v = max(v, vec4<f32>(0.0));
            }
            for (var l = 0u; l < 4u; l++) {
                if (o0 + 4u * j + l < prm.c_out) {
                    out[base + (4u * j + l) * rr] = v[l];
                }
            }
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

// ConvTranspose2d(c_a -> c_out, kernel 2, stride 2), no activation:
// out[o, 2i+di, 2j+dj] = bias[o] + sum_c in[c, i, j] W[c, o, di, dj].
// One invocation per (plane, block of 16 output channels, input pixel (i, j)) computes the 4
// output pixels it feeds. Weights repacked as vec4s [C][4 taps (di * 2 + dj)][4 * blocks], then
// the bias as 4 * blocks vec4s. r = output reso; total = 3 * blocks * (r / 2)^2.
@compute @workgroup_size(64)
fn upconv2(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.total) {
        return;
    }
    let r = prm.r;
    let rin = r / 2u;
    let j = idx % rin;
    var t = idx / rin;
    let i = t % rin;
    t = t / rin;
    let blk = t % prm.groups;
    let p = t / prm.groups;
    let vstride = 4u * prm.groups;
    var a0: array<vec4<f32>, 4>;
    var a1: array<vec4<f32>, 4>;
    var a2: array<vec4<f32>, 4>;
    var a3: array<vec4<f32>, 4>;
    var ii = p * prm.c_a * rin * rin + i * rin + j;
    var wi = prm.w_off + 4u * blk;
    for (var c = 0u; c < prm.c_a; c++) {
        let v = in_a[ii];
        madd(&a0, v, array<vec4<f32>, 4>(wv[wi], wv[wi + 1u], wv[wi + 2u], wv[wi + 3u]));
        wi += vstride;
        madd(&a1, v, array<vec4<f32>, 4>(wv[wi], wv[wi + 1u], wv[wi + 2u], wv[wi + 3u]));
        wi += vstride;
        madd(&a2, v, array<vec4<f32>, 4>(wv[wi], wv[wi + 1u], wv[wi + 2u], wv[wi + 3u]));
        wi += vstride;
        madd(&a3, v, array<vec4<f32>, 4>(wv[wi], wv[wi + 1u], wv[wi + 2u], wv[wi + 3u]));
        wi += vstride;
        ii += rin * rin;
    }
    let bi = prm.b_off + 4u * blk;
    let bias = array<vec4<f32>, 4>(wv[bi], wv[bi + 1u], wv[bi + 2u], wv[bi + 3u]);
    let taps = array<array<vec4<f32>, 4>, 4>(a0, a1, a2, a3);
    let rr = r * r;
    let o0 = 16u * blk;
    for (var tap = 0u; tap < 4u; tap++) {
        let y = 2u * i + tap / 2u;
        let x = 2u * j + tap % 2u;
        let base = (p * prm.c_out + o0) * rr + y * r + x;
        for (var q = 0u; q < 4u; q++) {
            let v = taps[tap][q] + bias[q];
            for (var l = 0u; l < 4u; l++) {
                if (o0 + 4u * q + l < prm.c_out) {
                    out[base + (4u * q + l) * rr] = v[l];
                }
            }
        }
    }
}

// The final 1x1 convolution, no activation, writing the decoder's channel-last layout:
// out[(p * rr + pixel) * 4 * cb + o] with cb = ceil(c_out / 4) (channels past c_out are zero).
// One invocation per (plane, block of 16 output channels, pixel). Weights repacked as vec4s
// [C][4 * blocks], then the bias as 4 * blocks vec4s. total = 3 * blocks * r * r.
@compute @workgroup_size(64)
fn final1x1(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let idx = linear_index(gid, nwg);
    if (idx >= prm.total) {
        return;
    }
    let rr = prm.r * prm.r;
    let pix = idx % rr;
    let t = idx / rr;
    let blk = t % prm.groups;
    let p = t / prm.groups;
    let vstride = 4u * prm.groups;
    var acc: array<vec4<f32>, 4>;
    var ii = p * prm.c_a * rr + pix;
    var wi = prm.w_off + 4u * blk;
    for (var c = 0u; c < prm.c_a; c++) {
        madd(&acc, in_a[ii], array<vec4<f32>, 4>(wv[wi], wv[wi + 1u], wv[wi + 2u], wv[wi + 3u]));
        ii += rr;
        wi += vstride;
    }
    let bi = prm.b_off + 4u * blk;
    let cb = (prm.c_out + 3u) / 4u;
    let base = (p * rr + pix) * cb;
    for (var q = 0u; q < 4u; q++) {
        let b = 4u * blk + q;
        if (b < cb) {
            out4[base + b] = acc[q] + wv[bi + q];
        }
    }
}
