// The scaled squared distances of a 64 x 64 tile, sum_d ((x_d - z_d) / s_d)^2, written once for
// the kernels that need them (krr_kernel_block.wgsl: K_nm blocks; krr_predict.wgsl: the
// predictor). Prepended to those shaders at pipeline creation; it uses their module-scope
// declarations: D, TD (= 16), the storage arrays x (points, row-major D), z (m x D) and inv_s
// (D), and the workgroup arrays xs[64][16], zs[16][16] (vec4) and ws[16].
//
// The workgroup (16 x 16 invocations) stages rows [row_begin, row_begin + 64) of x (those below
// row_end) and columns [col_begin, col_begin + 64) of z (those below col_end) 16 dimensions at a
// time; invocation (x, y) gets rows y + 16 a and columns x + 16 b (a, b = 0..3) as four vec4s —
// no dynamically indexed private arrays, which llvmpipe spills to memory. Differences, not the
// |x|^2 + |z|^2 - 2 x.z expansion, which cancels badly in f32. Staging rows and columns past the
// ends read as 0. Call from uniform control flow (it has barriers).

struct DistanceTile { d0: vec4<f32>, d1: vec4<f32>, d2: vec4<f32>, d3: vec4<f32> }

fn distance_tile(row_begin: u32, row_end: u32, col_begin: u32, col_end: u32, li: u32, lid: vec3<u32>) -> DistanceTile {
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
            let row = row_begin + rr;
            let col = col_begin + rr;
            var xv = 0.0;
            if (row < row_end && dim < D) {
                xv = x[row * D + dim];
            }
            xs[rr][t] = xv;
            var zv = 0.0;
            if (col < col_end && dim < D) {
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
    return DistanceTile(d0s, d1s, d2s, d3s);
}
