// One row block of K_nm = k(X_blk, Z) (rows x m, row-major), stored in 24-bit fixed point:
//   q_ij = round(k(x_i, z_j) * 2^24)   (u32, 0 ..= 2^24),   K~_ij = q_ij * 2^-24 exactly.
// Every later pass uses K~ (a perturbation of K by at most 2^-25 absolute, below the f32 rounding
// of the kernel itself near 1), and the fixed point lets krr_gram.wgsl form K~^T K~ *exactly* in
// integer arithmetic (see there for why that matters).
//
// k(x, z) = exp(-1/2 sum_d ((x_d - z_d) / s_d)^2), the distances from krr_distance_tile.wgsl
// (prepended at pipeline creation). A 64 x 64 output tile per workgroup of 16 x 16 invocations
// (4 x 4 outputs each); X and Z are staged in workgroup memory 16 dimensions at a time (8 KiB),
// so any D <= 64 fits the 16 KiB WebGPU default.
//
// D (the feature dimension) is pasted in at pipeline creation ({{D}}).

struct Dims { rows: u32, row0: u32, m: u32, _pad: u32 }

const D: u32 = {{D}}u;
const TD: u32 = 16u;

@group(0) @binding(0) var<storage, read> x: array<f32>;       // n x D, whole problem
@group(0) @binding(1) var<storage, read> z: array<f32>;       // m x D
@group(0) @binding(2) var<storage, read> inv_s: array<f32>;   // D
@group(0) @binding(3) var<storage, read_write> kout: array<u32>; // rows x m, this block
@group(0) @binding(4) var<uniform> dims: Dims;

var<workgroup> xs: array<array<f32, 16>, 64>;          // xs[row][t]
var<workgroup> zs: array<array<vec4<f32>, 16>, 16>;    // zs[t][c] = Z[c + 16 b][t], b = 0..3
var<workgroup> ws: array<f32, 16>;

fn store_row(row: u32, c: u32, d2: vec4<f32>) {
    if (row >= dims.rows) {
        return;
    }
    let q = round(exp(-0.5 * d2) * 16777216.0);
    for (var b = 0u; b < 4u; b++) {
        let col = c + 16u * b;
        if (col < dims.m) {
            kout[row * dims.m + col] = u32(q[b]);
        }
    }
}

// Invocation (x, y) owns rows y + 16 a and columns x + 16 b (a, b = 0..3) as four vec4s — no
// dynamically indexed private arrays, which llvmpipe spills to memory.
@compute @workgroup_size(16, 16)
fn kernel_block(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let r0 = wg.y * 64u;
    let c0 = wg.x * 64u;
    // Rows of this block are rows dims.row0 + r0 + ... of the whole problem's x.
    let tile = distance_tile(dims.row0 + r0, dims.row0 + dims.rows, c0, dims.m, li, lid);
    let c = c0 + lid.x;
    store_row(r0 + lid.y, c, tile.d0);
    store_row(r0 + lid.y + 16u, c, tile.d1);
    store_row(r0 + lid.y + 32u, c, tile.d2);
    store_row(r0 + lid.y + 48u, c, tile.d3);
}
