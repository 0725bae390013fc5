// C (M x N) = A (M x K) * B (K x N), row-major f32, 16x16 tiles staged in workgroup memory.
// A dispatch covers rows [row0, row0 + 16 * num_workgroups.y): the host splits tall products
// into row blocks so no dispatch dimension exceeds the device's limit.

struct Dims { m: u32, k: u32, n: u32, row0: u32 }

@group(0) @binding(0) var<storage, read> a: array<f32>;
@group(0) @binding(1) var<storage, read> b: array<f32>;
@group(0) @binding(2) var<storage, read_write> c: array<f32>;
@group(0) @binding(3) var<uniform> dims: Dims;

const T: u32 = 16u;
var<workgroup> ta: array<array<f32, 16>, 16>;
var<workgroup> tb: array<array<f32, 16>, 16>;

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let row = dims.row0 + wg.y * T + lid.y;
    let col = wg.x * T + lid.x;
    var acc = 0.0;
    let tiles = (dims.k + T - 1u) / T;
    for (var t = 0u; t < tiles; t++) {
        let ka = t * T + lid.x;
        let kb = t * T + lid.y;
        ta[lid.y][lid.x] = select(0.0, a[row * dims.k + ka], row < dims.m && ka < dims.k);
        tb[lid.y][lid.x] = select(0.0, b[kb * dims.n + col], kb < dims.k && col < dims.n);
        workgroupBarrier();
        for (var i = 0u; i < T; i++) {
            acc += ta[lid.y][i] * tb[i][lid.x];
        }
        workgroupBarrier();
    }
    if (row < dims.m && col < dims.n) {
        c[row * dims.n + col] = acc;
    }
}
