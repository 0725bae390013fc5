// The decoder: one invocation per two queries computes their features F(q) (bilinear samples of
// the three planes, summed) and the occupancy logits of the MLP, entirely in private memory.
//
// Layouts chosen for this kernel:
// - The planes are channel-last, [3][R][R][CB] vec4 (CB = ceil(c_dim / 4), zero-padded): each
//   bilinear corner is CB vector loads instead of c_dim scattered scalar loads. (The U-Net's
//   final 1x1 convolution writes this layout; the host transposes when planes cross to the CPU.)
// - Feature and hidden vectors are arrays of vec4 (channel 4b + l = lane l of vec4 b), and every
//   Linear layer is a sequence of `mat4x4 * vec4` over 4x4 blocks of its weights, repacked by the
//   host in a fixed order, so offsets follow from the sizes (no offset table):
//     fc_p; per block b: fc_c.b, blocks.b.fc_0, blocks.b.fc_1; fc_out
//   each as [out blocks][in blocks] mat4x4 (4 vec4 columns), then [out blocks] vec4 bias.
// WGSL needs constant array sizes, so `{{CB}}`, `{{C_DIM}}`, `{{HB}}` (= ceil(h_dec / 4)) and
// `{{N_BLOCKS}}` are replaced from the weights' metadata at pipeline creation. The loops, however,
// run to the same sizes read from the uniform: with constant bounds llvmpipe (Mesa's software
// Vulkan, our CI and CPU-only fallback) unrolls them and then takes 5-30 s to compile the kernel
// and runs it ~2x slower (measured); a GPU driver may prefer constant bounds (arrays in registers
// rather than scratch), to be measured on hardware.
// The plane coordinates follow docs/network.md operation by operation (division by the f32
// divisor, + 0.5, clamp, * (R-1), floor); the host passes the divisor and the clamp bound as f32
// so they equal the CPU's exactly. Dispatch: 1-D work folded into 2-D
// (index = gid.x + gid.y * nwg.x * WG).

const CB: u32 = {{CB}}u;
const C_DIM: u32 = {{C_DIM}}u;
const HB: u32 = {{HB}}u;
const N_BLOCKS: u32 = {{N_BLOCKS}}u;
const WG: u32 = 64u;

// Offsets (vec4 units) of the packed layers.
const FCP_W: u32 = 0u;                       // HB x 1 blocks
const FCP_B: u32 = FCP_W + 4u * HB;
const BLOCK0: u32 = FCP_B + HB;
const FCC_LEN: u32 = 4u * HB * CB + HB;
const FC_LEN: u32 = 4u * HB * HB + HB;
const BLOCK_LEN: u32 = FCC_LEN + 2u * FC_LEN;
const OUT_W: u32 = BLOCK0 + N_BLOCKS * BLOCK_LEN;  // 1 x HB blocks
const OUT_B: u32 = OUT_W + 4u * HB;

struct Params {
    n: u32,        // queries in this chunk
    reso: u32,
    divisor: f32,  // (1 + padding) rounded to f32
    uv_max: f32,   // 1 - 1e-5 rounded to f32
    // The sizes again, as run-time loop bounds (see the header).
    n_blocks: u32, // = N_BLOCKS
    hb: u32,       // = HB
    cb: u32,       // = CB
    _pad: u32,
}

@group(0) @binding(0) var<uniform> prm: Params;
@group(0) @binding(1) var<storage, read> w: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> planes: array<vec4<f32>>;       // 3 x R x R x CB
@group(0) @binding(3) var<storage, read> queries: array<f32>;            // n x 3
@group(0) @binding(4) var<storage, read_write> features: array<f32>;     // n x C_DIM
@group(0) @binding(5) var<storage, read_write> logits: array<f32>;       // n

fn mat_at(i: u32) -> mat4x4<f32> {
    return mat4x4<f32>(w[i], w[i + 1u], w[i + 2u], w[i + 3u]);
}

fn uv_of(x: f32) -> f32 {
    return clamp(x / prm.divisor + 0.5, 0.0, prm.uv_max);
}

// f += bilinear sample (align corners, border clamp) of plane p at plane coordinates (u, v).
fn sample_plane(p: u32, u: f32, v: f32, f: ptr<function, array<vec4<f32>, CB>>) {
    let r = prm.reso;
    let rm1 = f32(r - 1u);
    let x = u * rm1;
    let y = v * rm1;
    let x0f = floor(x);
    let y0f = floor(y);
    let wx = x - x0f;
    let wy = y - y0f;
    let x0 = min(u32(x0f), r - 1u);
    let y0 = min(u32(y0f), r - 1u);
    let x1 = min(x0 + 1u, r - 1u);
    let y1 = min(y0 + 1u, r - 1u);
    let plane = p * r * r;
    let i00 = (plane + y0 * r + x0) * CB;
    let i01 = (plane + y0 * r + x1) * CB;
    let i10 = (plane + y1 * r + x0) * CB;
    let i11 = (plane + y1 * r + x1) * CB;
    for (var b = 0u; b < prm.cb; b++) {
        let s = planes[i00 + b] * (1.0 - wx) * (1.0 - wy)
            + planes[i01 + b] * wx * (1.0 - wy)
            + planes[i10 + b] * (1.0 - wx) * wy
            + planes[i11 + b] * wx * wy;
        (*f)[b] += s;
    }
}

fn write_features(i: u32, f: ptr<function, array<vec4<f32>, CB>>) {
    for (var b = 0u; b < prm.cb; b++) {
        for (var l = 0u; l < 4u; l++) {
            if (4u * b + l < C_DIM) {
                features[i * C_DIM + 4u * b + l] = (*f)[b][l];
            }
        }
    }
}

fn feature(i: u32, f: ptr<function, array<vec4<f32>, CB>>) -> vec4<f32> {
    let q = vec4<f32>(queries[3u * i], queries[3u * i + 1u], queries[3u * i + 2u], 0.0);
    let ux = uv_of(q.x);
    let uy = uv_of(q.y);
    let uz = uv_of(q.z);
    sample_plane(0u, ux, uz, f); // xz
    sample_plane(1u, ux, uy, f); // xy
    sample_plane(2u, uy, uz, f); // yz
    return q;
}

// Two queries per invocation (i0 = 2 * index, i1 = i0 + 1) so that every weight load feeds both:
// the MLP is bound by weight loads, not arithmetic. A missing second query (odd count) repeats
// the first and is not written.
@compute @workgroup_size(64)
fn decode(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i0 = 2u * (gid.x + gid.y * nwg.x * WG);
    if (i0 >= prm.n) {
        return;
    }
    let has1 = i0 + 1u < prm.n;
    let i1 = select(i0, i0 + 1u, has1);
    var f0: array<vec4<f32>, CB>;
    var f1: array<vec4<f32>, CB>;
    let q0 = feature(i0, &f0);
    let q1 = feature(i1, &f1);
    write_features(i0, &f0);
    if (has1) {
        write_features(i1, &f1);
    }

    // net = fc_p(q)
    var n0: array<vec4<f32>, HB>;
    var n1: array<vec4<f32>, HB>;
    for (var o = 0u; o < prm.hb; o++) {
        let m = mat_at(FCP_W + 4u * o);
        let b = w[FCP_B + o];
        n0[o] = m * q0 + b;
        n1[o] = m * q1 + b;
    }
    var h0: array<vec4<f32>, HB>;
    var h1: array<vec4<f32>, HB>;
    let zero = vec4<f32>(0.0);
    for (var blk = 0u; blk < prm.n_blocks; blk++) {
        let fcc_w = BLOCK0 + blk * BLOCK_LEN;
        let fcc_b = fcc_w + 4u * HB * CB;
        let f0_w = fcc_b + HB;
        let f0_b = f0_w + 4u * HB * HB;
        let f1_w = f0_b + HB;
        let f1_b = f1_w + 4u * HB * HB;
        // t = net + fc_c(F), in place (t[o] needs only net[o])
        for (var o = 0u; o < prm.hb; o++) {
            var a0 = zero;
            var a1 = zero;
            for (var k = 0u; k < prm.cb; k++) {
                let m = mat_at(fcc_w + 4u * (o * CB + k));
                a0 += m * f0[k];
                a1 += m * f1[k];
            }
            let b = w[fcc_b + o];
            n0[o] = n0[o] + (a0 + b);
            n1[o] = n1[o] + (a1 + b);
        }
        // hid = fc_0(relu(t))
        for (var o = 0u; o < prm.hb; o++) {
            var a0 = zero;
            var a1 = zero;
            for (var k = 0u; k < prm.hb; k++) {
                let m = mat_at(f0_w + 4u * (o * HB + k));
                a0 += m * max(n0[k], zero);
                a1 += m * max(n1[k], zero);
            }
            let b = w[f0_b + o];
            h0[o] = a0 + b;
            h1[o] = a1 + b;
        }
        // net = t + fc_1(relu(hid)), in place
        for (var o = 0u; o < prm.hb; o++) {
            var a0 = zero;
            var a1 = zero;
            for (var k = 0u; k < prm.hb; k++) {
                let m = mat_at(f1_w + 4u * (o * HB + k));
                a0 += m * max(h0[k], zero);
                a1 += m * max(h1[k], zero);
            }
            let b = w[f1_b + o];
            n0[o] = n0[o] + (a0 + b);
            n1[o] = n1[o] + (a1 + b);
        }
    }
    var a0 = zero;
    var a1 = zero;
    for (var k = 0u; k < prm.hb; k++) {
        let m = mat_at(OUT_W + 4u * k);
        a0 += m * max(n0[k], zero);
        a1 += m * max(n1[k], zero);
    }
    let b = w[OUT_B].x;
    logits[i0] = a0.x + b;
    if (has1) {
        logits[i1] = a1.x + b;
    }
}
