// A = K~^T K~ (m x m) and b = K~^T y (m), exactly, for one row block of K~ (24-bit fixed point, see
// krr_kernel_block.wgsl), accumulated over row blocks on the device.
//
// Why exact integer arithmetic for A. A enters H = A + n lambda (K_mm + jitter I), whose smallest
// eigenvalues can be as small as n lambda jitter (~1e-6 at n = 400, lambda = 1e-4, m = 40) while
// |A| ~ n m (~1e4): where the length-scales are long, K_nm is numerically low-rank and A and K_mm
// share those near-null directions. Any *unstructured* error in A — f32 rounding of products and
// partial sums, even Kahan-compensated (measured: relative 2e-7 per entry) — is then larger than
// those eigenvalues, H stops being positive definite and T1 = Tr(H^-1 A) is wrong by percents
// (measured: 5e-2 relative; the tuner failed at step 12 on tests/krr.rs's relevance problem).
// With q = round(K * 2^24) = q1 2^12 + q0 (q1 <= 4096, q0 < 4096) every limb product is an exact
// u32 (< 2^24), and the sums are exact integer sums:
//   sum_i q_ij q_ik = 2^24 L2 + 2^12 L1 + L0,  L2 = sum q1 q1',  L1 = sum (q1 q0' + q0 q1'),  L0 = sum q0 q0'.
// L2, L1, L0 are u32 over 64 rows (no overflow: < 2^30, 2^31, 2^30), then folded into a 64-bit
// (lo, hi) total per output (< rows 2^48, rows <= 2048 per dispatch), and across dispatches and
// blocks into a 96-bit (w0, w1, w2) sum in `acc`. So A = K~^T K~ exactly — the Gram matrix of a
// slightly perturbed K, positive semi-definite like the true one; the host converts to f64.
// Cost: 4 integer multiply-adds per term instead of one f32 FMA.
//
// A 64 x 64 output tile per workgroup of 16 x 16 invocations (4 x 4 outputs each, strided by 16);
// upper-triangle tiles only (the host mirrors). Staging: 8 rows of limbs, 4 x 8 x 64 u32 = 8 KiB.
//
// b = K~^T y is exact too (gram_b): an unstructured error in b is amplified by H^-1 in the same
// near-null directions (measured: beta off by 19 % in a long-length-scale case with f32 Kahan
// sums). The host writes y in two 24-bit fixed-point levels with a power-of-two scale S >= max|y|:
//   y = S (qh 2^-24 + ql 2^-48) + O(S 2^-49),   uh = qh + 2^24, ul = ql + 2^24  in [0, 2^25],
// and the kernel sums sum_i q uh, sum_i q ul and sum_i q exactly (12-bit limbs again), from which
// the host recovers sum_i q qh = sum q uh - 2^24 sum q (likewise ql) in exact integer arithmetic.
//
// Rows [r_begin, r_end) of the block in this dispatch: the host splits a block into dispatches of
// a few thousand rows because llvmpipe (lavapipe, the CI adapter) silently ends any invocation's
// loops after 65535 iterations in total (LP_MAX_TGSI_LOOP_ITERATIONS) — measured: a 60001-row
// block in one dispatch lost every row past ~52400.
struct Dims { r_begin: u32, r_end: u32, row0: u32, m: u32, first: u32, _a: u32, _b: u32, _c: u32 }

@group(0) @binding(0) var<storage, read> kb: array<u32>;          // rows x m, this block
@group(0) @binding(1) var<storage, read_write> acc: array<u32>;   // 3 x m x m words of sum q q'
@group(0) @binding(2) var<uniform> dims: Dims;
@group(0) @binding(3) var<storage, read> yq: array<vec2<u32>>;    // n, whole problem: (uh, ul)
@group(0) @binding(4) var<storage, read_write> bacc: array<u32>;  // 9 x m words, see gram_b

// Limbs of the staged rows: a-side (rows of tile I) as scalars, b-side (tile J) as vec4 over the
// four columns c + 16 b an invocation owns.
var<workgroup> a1: array<array<u32, 64>, 8>;
var<workgroup> a0: array<array<u32, 64>, 8>;
var<workgroup> b1: array<array<vec4<u32>, 16>, 8>;
var<workgroup> b0: array<array<vec4<u32>, 16>, 8>;

// Per output row a: the limb sums over <= 64 rows and the 64-bit total (lo, hi), four columns each.
// Plain vec4 variables, no dynamically indexed private arrays (llvmpipe spills those to memory).
struct Acc { l2: vec4<u32>, l1: vec4<u32>, l0: vec4<u32>, lo: vec4<u32>, hi: vec4<u32> }

fn add64(x: Acc, add_lo: vec4<u32>, add_hi: vec4<u32>) -> Acc {
    let lo = x.lo + add_lo;
    let carry = select(vec4<u32>(0u), vec4<u32>(1u), lo < x.lo);
    return Acc(x.l2, x.l1, x.l0, lo, x.hi + add_hi + carry);
}

// total += 2^24 l2 + 2^12 l1 + l0, and the limb sums restart.
fn flush(x: Acc) -> Acc {
    var y = add64(x, x.l2 << vec4<u32>(24u), x.l2 >> vec4<u32>(8u));
    y = add64(y, x.l1 << vec4<u32>(12u), x.l1 >> vec4<u32>(20u));
    y = add64(y, x.l0, vec4<u32>(0u));
    return Acc(vec4<u32>(0u), vec4<u32>(0u), vec4<u32>(0u), y.lo, y.hi);
}

fn mac(x: Acc, p1: u32, p0: u32, q1: vec4<u32>, q0: vec4<u32>) -> Acc {
    return Acc(x.l2 + p1 * q1, x.l1 + p1 * q0 + p0 * q1, x.l0 + p0 * q0, x.lo, x.hi);
}

// Adds the 64-bit totals of one output row into the 96-bit words of `acc`.
fn store_row(row: u32, c: u32, x: Acc) {
    let m = dims.m;
    if (row >= m) {
        return;
    }
    let mm = m * m;
    for (var b = 0u; b < 4u; b++) {
        let col = c + 16u * b;
        if (col >= m) {
            continue;
        }
        let idx = row * m + col;
        if (dims.first != 0u) {
            acc[idx] = x.lo[b];
            acc[mm + idx] = x.hi[b];
            acc[2u * mm + idx] = 0u;
        } else {
            let w0 = acc[idx];
            let s0 = w0 + x.lo[b];
            let w1 = acc[mm + idx];
            let s1 = w1 + x.hi[b];
            let s1c = s1 + select(0u, 1u, s0 < w0);
            let carry = select(0u, 1u, s1 < w1) + select(0u, 1u, s1c < s1);
            acc[idx] = s0;
            acc[mm + idx] = s1c;
            acc[2u * mm + idx] = acc[2u * mm + idx] + carry;
        }
    }
}

@compute @workgroup_size(16, 16)
fn gram(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    // Tiles strictly below the diagonal are not needed (uniform per workgroup).
    if (wg.y > wg.x) {
        return;
    }
    let m = dims.m;
    let ci = wg.y * 64u;
    let cj = wg.x * 64u;
    let zero = vec4<u32>(0u);
    var x0 = Acc(zero, zero, zero, zero, zero);
    var x1 = x0;
    var x2 = x0;
    var x3 = x0;
    var since = 0u;
    for (var r0 = dims.r_begin; r0 < dims.r_end; r0 += 8u) {
        for (var q = 0u; q < 2u; q++) {
            let e = li + 256u * q;
            let rr = e / 64u;
            let cc = e % 64u;
            let row = r0 + rr;
            var qa = 0u;
            var qb = 0u;
            if (row < dims.r_end) {
                if (ci + cc < m) {
                    qa = kb[row * m + ci + cc];
                }
                if (cj + cc < m) {
                    qb = kb[row * m + cj + cc];
                }
            }
            a1[rr][cc] = qa >> 12u;
            a0[rr][cc] = qa & 0xFFFu;
            b1[rr][cc % 16u][cc / 16u] = qb >> 12u;
            b0[rr][cc % 16u][cc / 16u] = qb & 0xFFFu;
        }
        workgroupBarrier();
        for (var r = 0u; r < 8u; r++) {
            let q1 = b1[r][lid.x];
            let q0 = b0[r][lid.x];
            x0 = mac(x0, a1[r][lid.y], a0[r][lid.y], q1, q0);
            x1 = mac(x1, a1[r][lid.y + 16u], a0[r][lid.y + 16u], q1, q0);
            x2 = mac(x2, a1[r][lid.y + 32u], a0[r][lid.y + 32u], q1, q0);
            x3 = mac(x3, a1[r][lid.y + 48u], a0[r][lid.y + 48u], q1, q0);
        }
        workgroupBarrier();
        since += 8u;
        if (since == 64u) {
            since = 0u;
            x0 = flush(x0);
            x1 = flush(x1);
            x2 = flush(x2);
            x3 = flush(x3);
        }
    }
    x0 = flush(x0);
    x1 = flush(x1);
    x2 = flush(x2);
    x3 = flush(x3);
    let c = cj + lid.x;
    store_row(ci + lid.y, c, x0);
    store_row(ci + lid.y + 16u, c, x1);
    store_row(ci + lid.y + 32u, c, x2);
    store_row(ci + lid.y + 48u, c, x3);
}

// ---------------------------------------------------------------------------------------------

// 64-bit (lo, hi) scalar helpers for gram_b.
fn add64s(x: vec2<u32>, add_lo: u32, add_hi: u32) -> vec2<u32> {
    let lo = x.x + add_lo;
    return vec2<u32>(lo, x.y + add_hi + select(0u, 1u, lo < x.x));
}

// x + 2^24 l2 + 2^12 l1 + l0.
fn fold64(x: vec2<u32>, l2: u32, l1: u32, l0: u32) -> vec2<u32> {
    return add64s(add64s(add64s(x, l2 << 24u, l2 >> 8u), l1 << 12u, l1 >> 20u), l0, 0u);
}

// Adds a 64-bit value into the 96-bit (w0, w1, w2) words at base, base + m, base + 2m.
fn store96(base: u32, m: u32, v: vec2<u32>) {
    if (dims.first != 0u) {
        bacc[base] = v.x;
        bacc[base + m] = v.y;
        bacc[base + 2u * m] = 0u;
    } else {
        let w0 = bacc[base];
        let s0 = w0 + v.x;
        let w1 = bacc[base + m];
        let s1 = w1 + v.y;
        let s1c = s1 + select(0u, 1u, s0 < w0);
        let carry = select(0u, 1u, s1 < w1) + select(0u, 1u, s1c < s1);
        bacc[base] = s0;
        bacc[base + m] = s1c;
        bacc[base + 2u * m] = bacc[base + 2u * m] + carry;
    }
}

var<workgroup> red: array<array<vec2<u32>, 64>, 12>;  // red[3 lane + quantity][column]

// Exact sums over the dispatch's rows, per column j: Nh = sum q uh, Nl = sum q ul, Nq = sum q, into
// bacc words [Nh (3 m) | Nl (3 m) | Nq (3 m)]. 64 columns x 4 row lanes per workgroup.
@compute @workgroup_size(64, 4)
fn gram_b(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let m = dims.m;
    let j = wg.x * 64u + lid.x;
    var th = vec2<u32>(0u);
    var tl = vec2<u32>(0u);
    var tq = vec2<u32>(0u);
    if (j < m) {
        var h2 = 0u; var h1 = 0u; var h0 = 0u;
        var g2 = 0u; var g1 = 0u; var g0 = 0u;
        var sq = 0u;
        var since = 0u;
        for (var r = dims.r_begin + lid.y; r < dims.r_end; r += 4u) {
            let q = kb[r * m + j];
            let q1 = q >> 12u;
            let q0 = q & 0xFFFu;
            let u = yq[dims.row0 + r];
            let uh1 = u.x >> 12u;
            let uh0 = u.x & 0xFFFu;
            let ul1 = u.y >> 12u;
            let ul0 = u.y & 0xFFFu;
            // Limb products < 2^25 (u1 <= 8192): 32 rows per u32 partial sum.
            h2 += q1 * uh1;
            h1 += q1 * uh0 + q0 * uh1;
            h0 += q0 * uh0;
            g2 += q1 * ul1;
            g1 += q1 * ul0 + q0 * ul1;
            g0 += q0 * ul0;
            sq += q;
            since += 1u;
            if (since == 32u) {
                since = 0u;
                th = fold64(th, h2, h1, h0);
                tl = fold64(tl, g2, g1, g0);
                tq = add64s(tq, sq, 0u);
                h2 = 0u; h1 = 0u; h0 = 0u;
                g2 = 0u; g1 = 0u; g0 = 0u;
                sq = 0u;
            }
        }
        th = fold64(th, h2, h1, h0);
        tl = fold64(tl, g2, g1, g0);
        tq = add64s(tq, sq, 0u);
    }
    red[3u * lid.y][lid.x] = th;
    red[3u * lid.y + 1u][lid.x] = tl;
    red[3u * lid.y + 2u][lid.x] = tq;
    workgroupBarrier();
    if (lid.y == 0u && j < m) {
        for (var k = 0u; k < 3u; k++) {
            var t = red[k][lid.x];
            for (var lane = 1u; lane < 4u; lane++) {
                let v = red[3u * lane + k][lid.x];
                t = add64s(t, v.x, v.y);
            }
            store96(3u * k * m + j, m, t);
        }
    }
}
