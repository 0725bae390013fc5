// The decoder: one invocation per query computes its feature F(q) (bilinear samples of the three
// planes, summed) and the occupancy logit of the MLP, entirely in private memory.
//
// WGSL needs constant array sizes, so `{{C_DIM}}`, `{{H_DEC}}` and `{{N_BLOCKS}}` are replaced
// from the weights' metadata at pipeline creation. The decoder weights are repacked by the host
// in a fixed order (so offsets follow from the sizes, no offset table):
//   fc_p.w [H,3], fc_p.b [H]; per block b: fc_c.b.w [H,C], fc_c.b.b [H], blocks.b.fc_0.w [H,H],
//   .fc_0.b [H], .fc_1.w [H,H], .fc_1.b [H]; then fc_out.w [H], fc_out.b [1].
// The plane coordinates follow docs/network.md operation by operation (division by the f32
// divisor, + 0.5, clamp, * (R-1), floor); the host passes the divisor and the clamp bound as
// f32 bits so they equal the CPU's exactly. Sums start at 0 and add the bias last, like the CPU
// reference. Dispatch: 1-D work folded into 2-D (index = gid.x + gid.y * nwg.x * WG).

const C_DIM: u32 = {{C_DIM}}u;
const H: u32 = {{H_DEC}}u;
const N_BLOCKS: u32 = {{N_BLOCKS}}u;
const WG: u32 = 64u;

const BLOCK0: u32 = H * 3u + H;                      // first block's offset
const BLOCK_LEN: u32 = H * C_DIM + H + 2u * (H * H + H);
const OUT: u32 = BLOCK0 + N_BLOCKS * BLOCK_LEN;        // fc_out.w, then fc_out.b

struct Params {
    n: u32,        // queries in this chunk
    reso: u32,
    divisor: f32,  // (1 + padding) rounded to f32
    uv_max: f32,   // 1 - 1e-5 rounded to f32
}

@group(0) @binding(0) var<uniform> prm: Params;
@group(0) @binding(1) var<storage, read> w: array<f32>;
@group(0) @binding(2) var<storage, read> planes: array<f32>;           // 3 x C x R x R
@group(0) @binding(3) var<storage, read> queries: array<f32>;          // n x 3
@group(0) @binding(4) var<storage, read_write> features: array<f32>;   // n x C
@group(0) @binding(5) var<storage, read_write> logits: array<f32>;     // n

fn uv_of(x: f32) -> f32 {
    return clamp(x / prm.divisor + 0.5, 0.0, prm.uv_max);
}

// f += bilinear sample (align corners, border clamp) of plane p at plane coordinates (u, v).
fn sample_plane(p: u32, u: f32, v: f32, f: ptr<function, array<f32, C_DIM>>) {
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
    let rr = r * r;
    for (var ch = 0u; ch < C_DIM; ch++) {
        let base = (p * C_DIM + ch) * rr;
        let s = planes[base + y0 * r + x0] * (1.0 - wx) * (1.0 - wy)
            + planes[base + y0 * r + x1] * wx * (1.0 - wy)
            + planes[base + y1 * r + x0] * (1.0 - wx) * wy
            + planes[base + y1 * r + x1] * wx * wy;
        (*f)[ch] += s;
    }
}

@compute @workgroup_size(64)
fn decode(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * WG;
    if (i >= prm.n) {
        return;
    }
    let q = array<f32, 3>(queries[3u * i], queries[3u * i + 1u], queries[3u * i + 2u]);
    let ux = uv_of(q[0]);
    let uy = uv_of(q[1]);
    let uz = uv_of(q[2]);
    var f: array<f32, C_DIM>;
    for (var ch = 0u; ch < C_DIM; ch++) {
        f[ch] = 0.0;
    }
    sample_plane(0u, ux, uz, &f); // xz
    sample_plane(1u, ux, uy, &f); // xy
    sample_plane(2u, uy, uz, &f); // yz
    for (var ch = 0u; ch < C_DIM; ch++) {
        features[i * C_DIM + ch] = f[ch];
    }

    var net: array<f32, H>;
    for (var o = 0u; o < H; o++) {
        var acc = 0.0;
        for (var k = 0u; k < 3u; k++) {
            acc += w[o * 3u + k] * q[k];
        }
        net[o] = acc + w[H * 3u + o];
    }
    var t: array<f32, H>;
    var hid: array<f32, H>;
    for (var b = 0u; b < N_BLOCKS; b++) {
        let fc_w = BLOCK0 + b * BLOCK_LEN;
        let fc_b = fc_w + H * C_DIM;
        let f0_w = fc_b + H;
        let f0_b = f0_w + H * H;
        let f1_w = f0_b + H;
        let f1_b = f1_w + H * H;
        for (var o = 0u; o < H; o++) {
            var acc = 0.0;
            for (var k = 0u; k < C_DIM; k++) {
                acc += w[fc_w + o * C_DIM + k] * f[k];
            }
            t[o] = net[o] + (acc + w[fc_b + o]);
        }
        for (var o = 0u; o < H; o++) {
            var acc = 0.0;
            for (var k = 0u; k < H; k++) {
                acc += w[f0_w + o * H + k] * max(t[k], 0.0);
            }
            hid[o] = acc + w[f0_b + o];
        }
        for (var o = 0u; o < H; o++) {
            var acc = 0.0;
            for (var k = 0u; k < H; k++) {
                acc += w[f1_w + o * H + k] * max(hid[k], 0.0);
            }
            net[o] = t[o] + (acc + w[f1_b + o]);
        }
    }
    var acc = 0.0;
    for (var k = 0u; k < H; k++) {
        acc += w[OUT + k] * max(net[k], 0.0);
    }
    logits[i] = acc + w[OUT + H];
}
