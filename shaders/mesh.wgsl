// The reconstructed mesh: indexed triangles with vertex normals, lit by a key light that follows
// the camera (above and to the left of it) plus a dim fill and a little specular. Faces seen
// from behind are drawn in a darker, warmer tone so a hole or an inside-out patch is visible
// (by `vs_back`, a little farther back: see there).
// Vertex colours (the mesh's COLOR_0, alpha 255) replace the base colour where present.
// `fs_wire` colours the optional wireframe (the same vertices drawn as a line list).

struct MeshView {
    view_proj: mat4x4<f32>,
    eye: vec4<f32>,
    // xyz: direction towards the key light (world space).
    light: vec4<f32>,
    base: vec4<f32>,
    // x: how far `vs_back` pushes back faces away from the eye, in world units.
    params: vec4<f32>,
}

@group(0) @binding(0) var<uniform> view: MeshView;

struct VOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) color: vec4<f32>,
}

@vertex
fn vs(@location(0) p: vec3<f32>, @location(1) n: vec3<f32>, @location(2) c: vec4<f32>) -> VOut {
    return vertex(p, n, c);
}

fn vertex(p: vec3<f32>, n: vec3<f32>, c: vec4<f32>) -> VOut {
    var out: VOut;
    out.color = c;
    out.pos = view.view_proj * vec4<f32>(p, 1.0);
    out.world = p;
    out.normal = n;
    return out;
}

// Back faces (drawn by their own pipeline, front faces culled) pushed away from the eye, so a
// front face lying on them (two coincident layers) wins the depth test; a hole still shows them.
@vertex
fn vs_back(@location(0) p: vec3<f32>, @location(1) n: vec3<f32>, @location(2) c: vec4<f32>) -> VOut {
    var out = vertex(p, n, c);
    let away = p - view.eye.xyz;
    let len = length(away);
    let pushed = select(p, p + away * (view.params.x / len), len > 1e-20);
    out.pos = view.view_proj * vec4<f32>(pushed, 1.0);
    return out;
}

@fragment
fn fs(in: VOut) -> @location(0) vec4<f32> {
    let v = normalize(view.eye.xyz - in.world);
    var n = in.normal;
    let len = length(n);
    n = select(v, n / len, len > 1e-20);
    // Shade the side that faces the camera; remember whether it was the back.
    let back = dot(n, v) < 0.0;
    n = select(n, -n, back);
    let l = normalize(view.light.xyz);
    let key = max(dot(n, l), 0.0);
    let fill = 0.5 + 0.5 * n.y;
    let h = normalize(l + v);
    let spec = pow(max(dot(n, h), 0.0), 48.0) * 0.25;
    let front = select(view.base.rgb, in.color.rgb, in.color.a > 0.5);
    let base = select(front, vec3<f32>(0.62, 0.36, 0.30), back);
    let c = base * (0.18 + 0.72 * key + 0.15 * fill) + vec3<f32>(spec);
    return vec4<f32>(c, 1.0);
}

@fragment
fn fs_wire(in: VOut) -> @location(0) vec4<f32> {
    // The page's accent: visible on the light mesh and on the dark background alike.
    return vec4<f32>(0.16, 0.55, 0.52, 1.0);
}
