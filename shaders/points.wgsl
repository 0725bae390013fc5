// Point sprites: each point is an instanced screen-aligned quad of `point_size` pixels, drawn as
// a shaded disc. Colour is the point's own RGBA when the cloud has colours, else a ramp over
// height so an uncoloured scan still reads as a shape.

struct View {
    view_proj: mat4x4<f32>,
    viewport: vec2<f32>,
    point_size: f32,
    use_color: f32,
    height_lo: f32,
    height_hi: f32,
    _pad: vec2<f32>,
}

@group(0) @binding(0) var<uniform> view: View;

struct VOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) color: vec3<f32>,
    @location(1) corner: vec2<f32>,
}

fn ramp(t: f32) -> vec3<f32> {
    let a = vec3<f32>(0.18, 0.32, 0.62);
    let b = vec3<f32>(0.20, 0.66, 0.62);
    let c = vec3<f32>(0.96, 0.80, 0.35);
    let s = clamp(t, 0.0, 1.0);
    return select(mix(b, c, (s - 0.5) * 2.0), mix(a, b, s * 2.0), s < 0.5);
}

@vertex
fn vs(@builtin(vertex_index) vi: u32, @location(0) p: vec3<f32>, @location(1) rgba: vec4<f32>) -> VOut {
    var corners = array<vec2<f32>, 4>(vec2(-1.0, -1.0), vec2(1.0, -1.0), vec2(-1.0, 1.0), vec2(1.0, 1.0));
    let corner = corners[vi];
    let clip = view.view_proj * vec4<f32>(p, 1.0);
    var out: VOut;
    out.pos = vec4<f32>(clip.xy + corner * view.point_size / view.viewport * clip.w, clip.zw);
    let h = (p.y - view.height_lo) / max(view.height_hi - view.height_lo, 1e-20);
    out.color = select(ramp(h), rgba.rgb, view.use_color > 0.5);
    out.corner = corner;
    return out;
}

@fragment
fn fs(in: VOut) -> @location(0) vec4<f32> {
    let r2 = dot(in.corner, in.corner);
    if (r2 > 1.0) {
        discard;
    }
    // A little sphere-like shading so dense clouds keep depth cues.
    let shade = 0.55 + 0.45 * sqrt(1.0 - r2);
    return vec4<f32>(in.color * shade, 1.0);
}
