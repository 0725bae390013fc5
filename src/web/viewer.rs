//! The 3D view: a wgpu surface on the page's canvas, an orbit camera, the cloud drawn as
//! instanced point sprites and the reconstructed mesh as lit, indexed triangles; either or both
//! can be shown. Rendering is on demand (the page calls `render` after input), so an idle page
//! costs nothing.

use glam::{Mat4, Vec3};
use js_sys::{Float32Array, Uint32Array, Uint8Array};
use wasm_bindgen::prelude::*;
use wgpu::util::DeviceExt;

use super::cloud::Cloud;
use crate::gpu::Gpu;

const SHADER: &str = include_str!("../../shaders/points.wgsl");
const MESH_SHADER: &str = include_str!("../../shaders/mesh.wgsl");
const MESH_COLOR: [f32; 4] = [0.78, 0.80, 0.83, 1.0];
/// By default, larger clouds are drawn as an even subsample (every k-th point); the
/// reconstruction still reads the whole file.
const POINT_BUDGET: usize = 4_000_000;
const DEPTH: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
const BACKGROUND: wgpu::Color = wgpu::Color { r: 0.07, g: 0.08, b: 0.10, a: 1.0 };

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ViewUniform {
    view_proj: [[f32; 4]; 4],
    viewport: [f32; 2],
    point_size: f32,
    use_color: f32,
    height_lo: f32,
    height_hi: f32,
    _pad: [f32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MeshUniform {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    light: [f32; 4],
    base: [f32; 4],
    /// x: how far back faces are pushed away from the eye (world units), see [`BACK_OFFSET`].
    params: [f32; 4],
}

/// Back faces are drawn pushed away from the eye by this share of the mesh's radius, so that
/// where two opposite layers coincide (a scene's walls: the prior reads a scanned sheet as a
/// thin slab, and the last fit lays both faces on the sheet) the front face wins the depth test
/// instead of flickering with the back face's warning colour. A hole still shows the inside.
const BACK_OFFSET: f32 = 0.004;

/// How long the GPU took for the last frame, from its submission until the queue reported it
/// done (a software adapter draws a million points in seconds, and a scene's tiles wait behind
/// the frame in the same GPU process): the page spaces a scene's preview redraws by it and draws
/// no frame while one is in flight. Atomics because wgpu's callback must be `Send` on native.
#[derive(Default)]
struct FrameClock {
    /// Milliseconds (f64 bits) of the last finished frame; 0 before the first.
    last_ms: std::sync::atomic::AtomicU64,
    in_flight: std::sync::atomic::AtomicBool,
}

/// Orbit camera around a target: yaw/pitch in radians, distance along the view direction.
struct Orbit {
    target: Vec3,
    yaw: f32,
    pitch: f32,
    distance: f32,
    radius: f32,
}

impl Orbit {
    const FOV_Y: f32 = 0.8;

    fn eye(&self) -> Vec3 {
        let dir = Vec3::new(self.pitch.cos() * self.yaw.sin(), self.pitch.sin(), self.pitch.cos() * self.yaw.cos());
        self.target + dir * self.distance
    }

    fn view_proj(&self, aspect: f32) -> Mat4 {
        let near = (self.distance - 2.0 * self.radius).max(self.distance * 1e-3);
        let far = self.distance + 2.0 * self.radius;
        Mat4::perspective_rh(Self::FOV_Y, aspect, near, far) * Mat4::look_at_rh(self.eye(), self.target, Vec3::Y)
    }

    /// Frames a sphere of `radius` around `center` with a small margin.
    fn fit(&mut self, center: Vec3, radius: f32) {
        self.target = center;
        self.radius = radius.max(1e-12);
        self.distance = self.radius / (Self::FOV_Y * 0.5).sin() * 1.1;
    }
}

struct MeshDraw {
    positions: wgpu::Buffer,
    normals: wgpu::Buffer,
    /// RGBA8 per vertex; alpha 0 (a mesh without colours) means the viewer's base colour.
    colors: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
    /// Each undirected edge once, as a line list, for the wireframe; `None` until the wireframe
    /// is shown with this mesh (a sort of every edge, which a big scene's mesh would pay for
    /// nothing).
    edges: Option<(wgpu::Buffer, u32)>,
    center: Vec3,
    radius: f32,
}

impl Drop for MeshDraw {
    /// Frees the GPU memory now: wgpu's web backend only drops its handle, which leaves the
    /// buffer to the garbage collector, and a scene's result replacing its pieces would hold
    /// both in the GPU process for a while. Work already submitted still completes.
    fn drop(&mut self) {
        for b in [&self.positions, &self.normals, &self.colors, &self.indices] {
            b.destroy();
        }
        if let Some((e, _)) = &self.edges {
            e.destroy();
        }
    }
}

impl MeshDraw {
    /// Draws `count` indices of `indices` over the mesh's vertex buffers with `pipeline`: the
    /// triangles for the shaded mesh, the edge list for the wireframe.
    fn draw(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        pipeline: &wgpu::RenderPipeline,
        bind_group: &wgpu::BindGroup,
        indices: &wgpu::Buffer,
        count: u32,
    ) {
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bind_group, &[]);
        pass.set_vertex_buffer(0, self.positions.slice(..));
        pass.set_vertex_buffer(1, self.normals.slice(..));
        pass.set_vertex_buffer(2, self.colors.slice(..));
        pass.set_index_buffer(indices.slice(..), wgpu::IndexFormat::Uint32);
        pass.draw_indexed(0..count, 0, 0..1);
    }
}

struct CloudDraw {
    positions: wgpu::Buffer,
    colors: wgpu::Buffer,
    count: u32,
    has_color: bool,
    center: Vec3,
    radius: f32,
    height: (f32, f32),
}

/// The page's 3D view.
#[wasm_bindgen]
pub struct Viewer {
    gpu: Gpu,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    pipeline: wgpu::RenderPipeline,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    depth: wgpu::TextureView,
    orbit: Orbit,
    cloud: Option<CloudDraw>,
    point_size: f32,
    mesh_pipeline: wgpu::RenderPipeline,
    /// The mesh's back faces (culled from `mesh_pipeline`), pushed back ([`BACK_OFFSET`]).
    mesh_back_pipeline: wgpu::RenderPipeline,
    /// Its bind group (each pipeline has its own default layout).
    mesh_back_bind_group: wgpu::BindGroup,
    mesh_uniform: wgpu::Buffer,
    mesh_bind_group: wgpu::BindGroup,
    wire_pipeline: wgpu::RenderPipeline,
    wire_bind_group: wgpu::BindGroup,
    /// The mesh as drawn: one piece for a result, or a scene's finished pieces as they come
    /// (each uploaded once, [`Viewer::add_mesh_piece`]).
    mesh: Vec<MeshDraw>,
    show_cloud: bool,
    show_mesh: bool,
    show_wire: bool,
    drawn_points: usize,
    point_budget: usize,
    frames: std::sync::Arc<FrameClock>,
}

#[wasm_bindgen]
impl Viewer {
    /// Creates the view on `canvas`; fails with a readable message where WebGPU is missing.
    pub async fn create(canvas: web_sys::HtmlCanvasElement) -> Result<Viewer, JsError> {
        let (width, height) = (canvas.width().max(1), canvas.height().max(1));
        let instance = Gpu::instance();
        let surface = instance
            .create_surface(wgpu::SurfaceTarget::Canvas(canvas))
            .map_err(|e| JsError::new(&format!("cannot draw on the canvas: {e}")))?;
        let gpu = Gpu::with_instance(&instance, Some(&surface)).await.map_err(|e| JsError::new(&e.to_string()))?;
        let caps = surface.get_capabilities(&gpu.adapter);
        // Prefer a non-sRGB format: the shader's colours are meant as displayed.
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| !f.is_srgb())
            .or_else(|| caps.formats.first().copied())
            .ok_or_else(|| JsError::new("the canvas offers no texture format"))?;
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            format,
            width,
            height,
            present_mode: wgpu::PresentMode::Fifo,
            desired_maximum_frame_latency: 2,
            alpha_mode: wgpu::CompositeAlphaMode::Opaque,
            view_formats: vec![],
            color_space: Default::default(),
        };
        surface.configure(&gpu.device, &config);
        // wgpu's default handler panics, which would end the page's module for good: log instead
        // (the operations that can fail check their sizes first).
        gpu.device.on_uncaptured_error(std::sync::Arc::new(|e: wgpu::Error| {
            web_sys::console::error_1(&format!("nkrr viewer: GPU error: {e}").into());
        }));

        let module = gpu.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("points"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = gpu.device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("points"),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs"),
                compilation_options: Default::default(),
                buffers: &[
                    Some(wgpu::VertexBufferLayout {
                        array_stride: 12,
                        step_mode: wgpu::VertexStepMode::Instance,
                        attributes: &wgpu::vertex_attr_array![0 => Float32x3],
                    }),
                    Some(wgpu::VertexBufferLayout {
                        array_stride: 4,
                        step_mode: wgpu::VertexStepMode::Instance,
                        attributes: &wgpu::vertex_attr_array![1 => Unorm8x4],
                    }),
                ],
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[Some(format.into())],
            }),
            primitive: wgpu::PrimitiveState { topology: wgpu::PrimitiveTopology::TriangleStrip, ..Default::default() },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            multiview_mask: None,
            cache: None,
        });
        let uniform = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("view"),
            size: std::mem::size_of::<ViewUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("view"),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() }],
        });
        let ((mesh_pipeline, mesh_bind_group), (mesh_back_pipeline, mesh_back_bind_group), mesh_uniform) = mesh_pipeline(&gpu.device, format);
        let (wire_pipeline, wire_bind_group) = wire_pipeline(&gpu.device, format, &mesh_uniform);
        let depth = depth_view(&gpu.device, width, height);
        Ok(Viewer {
            gpu,
            surface,
            config,
            pipeline,
            uniform,
            bind_group,
            depth,
            orbit: Orbit { target: Vec3::ZERO, yaw: 0.6, pitch: 0.35, distance: 3.0, radius: 1.0 },
            cloud: None,
            point_size: 2.5,
            mesh_pipeline,
            mesh_back_pipeline,
            mesh_back_bind_group,
            wire_pipeline,
            wire_bind_group,
            mesh_uniform,
            mesh_bind_group,
            mesh: Vec::new(),
            show_cloud: true,
            show_mesh: true,
            show_wire: false,
            drawn_points: 0,
            point_budget: POINT_BUDGET,
            frames: Default::default(),
        })
    }

    /// A one-line description of the adapter, for the page's footer and bug reports.
    #[wasm_bindgen(getter)]
    pub fn adapter(&self) -> String {
        self.gpu.describe()
    }

    /// The largest buffer a shader may bind on this adapter, in bytes (for [`super::preflight`];
    /// the worker's device is on the same adapter).
    #[wasm_bindgen(getter)]
    pub fn binding_limit(&self) -> f64 {
        crate::gpu::binding_limit(&self.gpu.limits) as f64
    }

    /// Whether the adapter is a software one (SwiftShader): nkrr's tuning then runs on the CPU.
    #[wasm_bindgen(getter)]
    pub fn software(&self) -> bool {
        self.gpu.is_software()
    }

    /// Shows `cloud` and frames it; a mesh of an earlier cloud is removed.
    pub fn set_cloud(&mut self, cloud: &Cloud) {
        self.mesh.clear();
        let pc = &cloud.parsed.cloud;
        let Some(b) = pc.bounds() else {
            self.cloud = None;
            self.drawn_points = 0;
            return;
        };
        let max = (self.gpu.limits.max_buffer_size / 12).max(1) as usize;
        let stride = pc.len().div_ceil(pc.len().min(self.point_budget).min(max).max(1));
        let drawn: Vec<[f32; 3]> = pc.positions.iter().step_by(stride).copied().collect();
        let colors: Vec<[u8; 4]> = match &pc.colors {
            Some(c) => c.iter().step_by(stride).copied().collect(),
            None => vec![[0, 0, 0, 255]; drawn.len()],
        };
        let device = &self.gpu.device;
        let positions = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("cloud positions"),
            contents: bytemuck::cast_slice(&drawn),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let colors = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("cloud colours"),
            contents: bytemuck::cast_slice(&colors),
            usage: wgpu::BufferUsages::VERTEX,
        });
        let center = Vec3::from(b.center());
        let radius = 0.5 * Vec3::from(b.extent()).length();
        self.cloud = Some(CloudDraw {
            positions,
            colors,
            count: drawn.len() as u32,
            has_color: pc.colors.is_some(),
            center,
            radius,
            height: (b.min[1], b.max[1]),
        });
        self.drawn_points = drawn.len();
        self.fit();
    }

    /// Sets how many points at most are drawn (from the next `set_cloud`; default 4M). A slow
    /// GPU draws large clouds more smoothly with a smaller budget.
    pub fn set_point_budget(&mut self, points: usize) {
        self.point_budget = points.max(1);
    }

    /// How many of the cloud's points are drawn (fewer than it has when it is very large).
    #[wasm_bindgen(getter)]
    pub fn drawn_points(&self) -> usize {
        self.drawn_points
    }

    /// Shows a triangle mesh: `positions` and `normals` hold x, y, z per vertex, `indices`
    /// three vertex indices per triangle (counter-clockwise seen from outside). Replaces an
    /// earlier mesh; the camera stays where it is unless nothing was shown before. Fails on
    /// inconsistent lengths or an index out of range.
    /// `colors` (optional): RGBA8 per vertex, the mesh's COLOR_0; without them the mesh is
    /// drawn in the viewer's base colour.
    /// `wireframe` (optional, default: whether the wireframe is shown now): whether to build the
    /// wireframe's edge list, a sort of every edge held in the page's memory while it is built.
    /// The arrays are read a chunk at a time into the GPU's buffers: the page's wasm memory,
    /// which never shrinks, does not grow by the mesh (a big scene's is hundreds of MB).
    pub fn set_mesh(
        &mut self,
        positions: &Float32Array,
        normals: &Float32Array,
        indices: &Uint32Array,
        colors: Option<Uint8Array>,
        wireframe: Option<bool>,
    ) -> Result<(), JsError> {
        let had_content = self.cloud.is_some() || !self.mesh.is_empty();
        // The old mesh's buffers go first, so the GPU never holds both.
        self.mesh.clear();
        let piece = self.upload(positions, normals, indices, colors.as_ref(), wireframe.unwrap_or(self.show_wire))?;
        self.mesh = piece.into_iter().collect();
        if !had_content {
            self.fit();
        }
        Ok(())
    }

    /// Adds a piece to the mesh shown (a scene's finished block, while the other tiles run),
    /// with the same arguments and checks as [`Viewer::set_mesh`] but no colours and no
    /// wireframe. Each piece goes to the GPU once, as it comes: nothing is gathered or copied
    /// again on the page (a 5M-point room sends hundreds of pieces); [`Viewer::set_mesh`] or
    /// [`Viewer::clear_mesh`] replaces them all.
    pub fn add_mesh_piece(&mut self, positions: &Float32Array, normals: &Float32Array, indices: &Uint32Array) -> Result<(), JsError> {
        let had_content = self.cloud.is_some() || !self.mesh.is_empty();
        self.mesh.extend(self.upload(positions, normals, indices, None, false)?);
        if !had_content {
            self.fit();
        }
        Ok(())
    }

    /// Whether the mesh shown has its wireframe's edges (see `set_mesh`'s `wireframe`): the page
    /// sets the mesh again, with them, when the wireframe is first shown.
    #[wasm_bindgen(getter)]
    pub fn has_wireframe(&self) -> bool {
        !self.mesh.is_empty() && self.mesh.iter().all(|m| m.edges.is_some())
    }

    /// Removes the mesh.
    pub fn clear_mesh(&mut self) {
        self.mesh.clear();
    }

    /// Whether a mesh is loaded.
    #[wasm_bindgen(getter)]
    pub fn has_mesh(&self) -> bool {
        !self.mesh.is_empty()
    }

    /// Chooses what is drawn: the cloud, the mesh, or both.
    pub fn set_visible(&mut self, cloud: bool, mesh: bool) {
        self.show_cloud = cloud;
        self.show_mesh = mesh;
    }

    /// Draws the mesh's edges on top of it (or alone, when the mesh itself is hidden).
    pub fn set_wireframe(&mut self, on: bool) {
        self.show_wire = on;
    }

    /// Frames the content shown (the cloud, the mesh, or both together; all of it when neither
    /// is shown): with the cloud hidden, the mesh alone, so that points the run dropped far
    /// from the object (`outliers::apart`) do not leave the mesh a dot in the view.
    pub fn fit(&mut self) {
        let shown_mesh = self.show_mesh || self.show_wire;
        let (cloud, mesh) = match (self.show_cloud && self.cloud.is_some(), shown_mesh && !self.mesh.is_empty()) {
            (false, false) => (true, true),
            shown => shown,
        };
        let spheres = [
            self.cloud.as_ref().filter(|_| cloud).map(|c| (c.center, c.radius)),
        ];
        let mut it = spheres.into_iter().flatten().chain(self.mesh.iter().filter(|_| mesh).map(|m| (m.center, m.radius)));
        let Some(first) = it.next() else { return };
        let (center, radius) = it.fold(first, |(c0, r0), (c1, r1)| {
            // The smallest sphere holding both.
            let d = (c1 - c0).length();
            if d + r1 <= r0 {
                (c0, r0)
            } else if d + r0 <= r1 {
                (c1, r1)
            } else {
                let r = 0.5 * (d + r0 + r1);
                (c0 + (c1 - c0) * ((r - r0) / d), r)
            }
        });
        self.orbit.fit(center, radius);
    }

    /// Rotates by a drag of (dx, dy) pixels.
    pub fn orbit(&mut self, dx: f32, dy: f32) {
        self.orbit.yaw -= dx * 0.01;
        self.orbit.pitch = (self.orbit.pitch + dy * 0.01).clamp(-1.55, 1.55);
    }

    /// Zooms by a wheel delta (positive: away).
    pub fn zoom(&mut self, delta: f32) {
        let f = (delta * 0.001).clamp(-0.5, 0.5).exp();
        self.orbit.distance = (self.orbit.distance * f).clamp(self.orbit.radius * 0.05, self.orbit.radius * 50.0);
    }

    /// Sets the point size in device pixels.
    pub fn set_point_size(&mut self, px: f32) {
        self.point_size = px.clamp(1.0, 20.0);
    }

    /// Follows a canvas size change (device pixels).
    pub fn resize(&mut self, width: u32, height: u32) {
        let (w, h) = (width.max(1), height.max(1));
        let max = self.gpu.limits.max_texture_dimension_2d;
        self.config.width = w.min(max);
        self.config.height = h.min(max);
        self.surface.configure(&self.gpu.device, &self.config);
        self.depth = depth_view(&self.gpu.device, self.config.width, self.config.height);
    }

    /// Draws one frame to the canvas.
    pub fn render(&mut self) -> Result<(), JsError> {
        let frame = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(f) | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
            other => {
                // Lost/outdated: reconfigure and let the next render draw.
                self.surface.configure(&self.gpu.device, &self.config);
                return Err(JsError::new(&format!("the canvas was not ready: {other:?}")));
            }
        };
        let view = frame.texture.create_view(&Default::default());
        self.draw(&view);
        self.gpu.queue.present(frame);
        Ok(())
    }

    /// Milliseconds the GPU took for the last frame drawn (0 before the first), see [`FrameClock`].
    #[wasm_bindgen(getter)]
    pub fn frame_ms(&self) -> f64 {
        f64::from_bits(self.frames.last_ms.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// Whether the last frame's GPU work is still under way: the page draws no other meanwhile.
    #[wasm_bindgen(getter)]
    pub fn frame_in_flight(&self) -> bool {
        self.frames.in_flight.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Bytes of the GPU buffers the view holds now (uniforms, the cloud's and the mesh's vertex
    /// and index buffers): the soak test checks that it does not grow from one run to the next
    /// (a replaced cloud or mesh frees its buffers).
    pub fn gpu_bytes(&self) -> f64 {
        let mut b = self.uniform.size() + self.mesh_uniform.size();
        if let Some(c) = &self.cloud {
            b += c.positions.size() + c.colors.size();
        }
        for m in &self.mesh {
            b += m.positions.size() + m.normals.size() + m.colors.size() + m.indices.size();
            b += m.edges.as_ref().map_or(0, |(e, _)| e.size());
        }
        b as f64
    }

    /// Test hook: renders offscreen and resolves to the fraction of pixels that differ from the
    /// background, so a browser test can tell a drawn cloud from an empty view. The borrow of
    /// the viewer ends before the promise's readback, so renders may interleave with it.
    pub fn coverage(&mut self) -> js_sys::Promise {
        self.offscreen_stats(|covered, _, total| covered as f64 / total as f64)
    }

    /// Test hook: like [`Viewer::coverage`], the fraction of the covered pixels that are
    /// saturated (channels differing by 48 or more), so a test can tell a mesh drawn in its
    /// vertex colours from the grey one.
    pub fn saturation(&mut self) -> js_sys::Promise {
        self.offscreen_stats(|covered, saturated, _| saturated as f64 / covered.max(1) as f64)
    }
}

impl Viewer {
    /// Renders offscreen and resolves to `stat(covered, saturated, total)` over the pixels.
    fn offscreen_stats(&mut self, stat: fn(usize, usize, usize) -> f64) -> js_sys::Promise {
        let (w, h) = (self.config.width, self.config.height);
        let scope = self.gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let texture = self.gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("coverage"),
            size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: self.config.format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        self.draw(&texture.create_view(&Default::default()));
        let row = (w * 4).div_ceil(256) * 256;
        let buffer = self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("coverage readback"),
            size: (row * h) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(row), rows_per_image: Some(h) },
            },
            wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        );
        self.gpu.queue.submit([encoder.finish()]);
        let gpu = self.gpu.clone();
        let scope = scope.pop();
        wasm_bindgen_futures::future_to_promise(async move {
            if let Some(e) = scope.await {
                return Err(JsError::new(&format!("offscreen render failed: {e}")).into());
            }
            let bytes: Vec<u8> = gpu.read(&buffer, (row * h) as usize).await.map_err(|e| JsError::new(&e.to_string()))?;
            drop(texture);
            let bg = [BACKGROUND.r, BACKGROUND.g, BACKGROUND.b].map(|c| (c * 255.0).round() as i32);
            let near = |a: i32, b: i32| (a - b).abs() <= 3;
            let (mut covered, mut saturated) = (0usize, 0usize);
            for y in 0..h as usize {
                for p in bytes[y * row as usize..][..w as usize * 4].chunks_exact(4) {
                    // BGRA or RGBA: compare both channel orders against the background.
                    let (r, g, b) = (p[0] as i32, p[1] as i32, p[2] as i32);
                    let is_bg = (near(r, bg[0]) && near(g, bg[1]) && near(b, bg[2]))
                        || (near(b, bg[0]) && near(g, bg[1]) && near(r, bg[2]));
                    if !is_bg {
                        covered += 1;
                        saturated += (r.max(g).max(b) - r.min(g).min(b) >= 48) as usize;
                    }
                }
            }
            Ok(JsValue::from_f64(stat(covered, saturated, (w * h) as usize)))
        })
    }
}

impl Viewer {
    /// Checks a mesh's arrays (see [`Viewer::set_mesh`]) and uploads them; `None` when empty.
    fn upload(
        &self,
        positions: &Float32Array,
        normals: &Float32Array,
        indices: &Uint32Array,
        colors: Option<&Uint8Array>,
        wireframe: bool,
    ) -> Result<Option<MeshDraw>, JsError> {
        let (floats, index_len) = (positions.length(), indices.length());
        let n = floats / 3;
        let colors = colors.filter(|c| c.length() > 0);
        if let Some(c) = colors {
            if c.length() != 4 * n {
                return Err(JsError::new(&format!("set_mesh: {} colour bytes for {n} vertices (4 per vertex)", c.length())));
            }
        }
        if floats % 3 != 0 || normals.length() != floats {
            return Err(JsError::new(&format!(
                "set_mesh: {floats} position and {} normal floats (both must be 3 per vertex)",
                normals.length()
            )));
        }
        if index_len % 3 != 0 {
            return Err(JsError::new(&format!("set_mesh: {index_len} indices is not a multiple of 3")));
        }
        if n == 0 || index_len == 0 {
            return Ok(None);
        }
        let max = self.gpu.limits.max_buffer_size;
        if (floats as u64) * 4 > max || (index_len as u64) * 4 > max {
            return Err(JsError::new(&format!(
                "the mesh ({n} vertices, {} triangles) is too large to show on this GPU (buffers up to {} MiB); \
                 download it instead",
                index_len / 3,
                max >> 20
            )));
        }
        let device = &self.gpu.device;
        // Zero-filled (WebGPU clears new buffers): a mesh without colours writes none.
        let buffer = |label: &str, bytes: u32, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes as u64,
                usage: usage | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let queue = &self.gpu.queue;
        let index_buffer = buffer("mesh indices", 4 * index_len, wgpu::BufferUsages::INDEX);
        let mut out_of_range = None;
        in_chunks(index_len, |a, b, dst| indices.subarray(a, b).copy_to(dst), |start, chunk: &[u32]| {
            if out_of_range.is_none() {
                out_of_range = chunk.iter().find(|&&i| i >= n).copied();
            }
            queue.write_buffer(&index_buffer, 4 * start as u64, bytemuck::cast_slice(chunk));
        });
        if let Some(i) = out_of_range {
            index_buffer.destroy();
            return Err(JsError::new(&format!("set_mesh: index {i} is out of range ({n} vertices)")));
        }
        let position_buffer = buffer("mesh positions", 4 * floats, wgpu::BufferUsages::VERTEX);
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        in_chunks(floats, |a, b, dst| positions.subarray(a, b).copy_to(dst), |start, chunk: &[f32]| {
            for p in chunk.chunks_exact(3) {
                let p = Vec3::new(p[0], p[1], p[2]);
                if p.is_finite() {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
            queue.write_buffer(&position_buffer, 4 * start as u64, bytemuck::cast_slice(chunk));
        });
        if !lo.is_finite() {
            index_buffer.destroy();
            position_buffer.destroy();
            return Err(JsError::new("set_mesh: no finite vertex position"));
        }
        let normal_buffer = buffer("mesh normals", 4 * floats, wgpu::BufferUsages::VERTEX);
        in_chunks(floats, |a, b, dst| normals.subarray(a, b).copy_to(dst), |start, chunk: &[f32]| {
            queue.write_buffer(&normal_buffer, 4 * start as u64, bytemuck::cast_slice(chunk));
        });
        let color_buffer = buffer("mesh colours", 4 * n, wgpu::BufferUsages::VERTEX);
        if let Some(c) = colors {
            in_chunks(4 * n, |a, b, dst| c.subarray(a, b).copy_to(dst), |start, chunk: &[u8]| {
                queue.write_buffer(&color_buffer, start as u64, chunk);
            });
        }
        let edges = wireframe.then(|| {
            let edges = unique_edges(&indices.to_vec());
            // Never empty (a buffer slice cannot be); a mesh has at least one edge.
            let b = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("mesh edges"),
                contents: bytemuck::cast_slice(&edges),
                usage: wgpu::BufferUsages::INDEX,
            });
            (b, edges.len() as u32)
        });
        Ok(Some(MeshDraw {
            positions: position_buffer,
            normals: normal_buffer,
            colors: color_buffer,
            indices: index_buffer,
            index_count: index_len,
            edges,
            center: (lo + hi) * 0.5,
            radius: 0.5 * (hi - lo).length(),
        }))
    }

    fn draw(&mut self, target: &wgpu::TextureView) {
        let aspect = self.config.width as f32 / self.config.height as f32;
        let (use_color, height) = match &self.cloud {
            Some(c) => (c.has_color, c.height),
            None => (false, (0.0, 1.0)),
        };
        let u = ViewUniform {
            view_proj: self.orbit.view_proj(aspect).to_cols_array_2d(),
            viewport: [self.config.width as f32, self.config.height as f32],
            point_size: self.point_size,
            use_color: use_color as u32 as f32,
            height_lo: height.0,
            height_hi: height.1,
            _pad: [0.0; 2],
        };
        self.gpu.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&u));
        let eye = self.orbit.eye();
        let forward = (self.orbit.target - eye).normalize_or_zero();
        let right = forward.cross(Vec3::Y).normalize_or_zero();
        let up = right.cross(forward);
        let light = (-forward + 0.6 * up - 0.45 * right).normalize_or_zero();
        let mu = MeshUniform {
            view_proj: u.view_proj,
            eye: eye.extend(1.0).to_array(),
            light: light.extend(0.0).to_array(),
            base: MESH_COLOR,
            // The largest piece's radius: a result is one piece; a preview's pieces are blocks of
            // one scene, whose offset need only clear the coincident layers within a block.
            params: [BACK_OFFSET * self.mesh.iter().map(|m| m.radius).fold(0.0, f32::max), 0.0, 0.0, 0.0],
        };
        self.gpu.queue.write_buffer(&self.mesh_uniform, 0, bytemuck::bytes_of(&mu));
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("view"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Clear(BACKGROUND), store: wgpu::StoreOp::Store },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &self.depth,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            for m in self.mesh.iter().filter(|_| self.show_mesh) {
                m.draw(&mut pass, &self.mesh_pipeline, &self.mesh_bind_group, &m.indices, m.index_count);
                m.draw(&mut pass, &self.mesh_back_pipeline, &self.mesh_back_bind_group, &m.indices, m.index_count);
            }
            for (m, (edges, count)) in self.mesh.iter().filter_map(|m| Some((m, m.edges.as_ref()?))).filter(|_| self.show_wire) {
                m.draw(&mut pass, &self.wire_pipeline, &self.wire_bind_group, edges, *count);
            }
            if let (Some(c), true) = (&self.cloud, self.show_cloud) {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &self.bind_group, &[]);
                pass.set_vertex_buffer(0, c.positions.slice(..));
                pass.set_vertex_buffer(1, c.colors.slice(..));
                pass.draw(0..4, 0..c.count);
            }
        }
        self.gpu.queue.submit([encoder.finish()]);
        use std::sync::atomic::Ordering::Relaxed;
        let (clock, submitted) = (self.frames.clone(), crate::gpu::now());
        clock.in_flight.store(true, Relaxed);
        self.gpu.queue.on_submitted_work_done(move || {
            clock.last_ms.store((1e3 * (crate::gpu::now() - submitted)).to_bits(), Relaxed);
            clock.in_flight.store(false, Relaxed);
        });
    }
}

/// The mesh's render pipelines with their bind groups (lit triangles: front faces, and back
/// faces pushed back) and their uniform buffer.
type PipelineAndGroup = (wgpu::RenderPipeline, wgpu::BindGroup);
fn mesh_pipeline(device: &wgpu::Device, format: wgpu::TextureFormat) -> (PipelineAndGroup, PipelineAndGroup, wgpu::Buffer) {
    let uniform = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("mesh view"),
        size: std::mem::size_of::<MeshUniform>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    // Both sides: back faces are shaded differently, not culled, so holes show. Pushed back a
    // little so points lying on the surface (and the wireframe) stay visible over it.
    let depth = wgpu::DepthStencilState {
        format: DEPTH,
        depth_write_enabled: Some(true),
        depth_compare: Some(wgpu::CompareFunction::Less),
        stencil: Default::default(),
        bias: wgpu::DepthBiasState { constant: 2, slope_scale: 1.0, clamp: 0.0 },
    };
    let triangles = |cull| wgpu::PrimitiveState { topology: wgpu::PrimitiveTopology::TriangleList, cull_mode: Some(cull), ..Default::default() };
    let front = mesh_vertex_pipeline(device, format, &uniform, "mesh", ("vs", "fs"), triangles(wgpu::Face::Back), depth.clone());
    let back = mesh_vertex_pipeline(device, format, &uniform, "mesh back faces", ("vs_back", "fs"), triangles(wgpu::Face::Front), depth);
    (front, back, uniform)
}

/// Elements a mesh's array is copied in at a time (16 MiB of f32 or u32; a multiple of 3 and
/// of 4, so vertices and colours never straddle two chunks).
const UPLOAD_CHUNK: u32 = 3 << 22;

/// Visits `len` elements of a JS typed array in chunks copied (by `copy(begin, end, dst)`) into
/// one reused wasm buffer, calling `visit(first element, chunk)`.
fn in_chunks<T: Copy + Default>(len: u32, copy: impl Fn(u32, u32, &mut [T]), mut visit: impl FnMut(u32, &[T])) {
    let mut buf = vec![T::default(); len.min(UPLOAD_CHUNK) as usize];
    let mut start = 0;
    while start < len {
        let end = (start + UPLOAD_CHUNK).min(len);
        let dst = &mut buf[..(end - start) as usize];
        copy(start, end, dst);
        visit(start, dst);
        start = end;
    }
}

/// Every undirected edge of the triangles once, as pairs of vertex indices (a line list).
fn unique_edges(indices: &[u32]) -> Vec<u32> {
    let mut keys: Vec<u64> = indices
        .chunks_exact(3)
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| ((a.min(b) as u64) << 32) | a.max(b) as u64)
        .collect();
    keys.sort_unstable();
    keys.dedup();
    keys.iter().flat_map(|&k| [(k >> 32) as u32, k as u32]).collect()
}

/// The wireframe's pipeline: the mesh's vertices and uniform, a line list, a flat colour. The
/// shaded mesh is drawn with a depth bias pushing it back, so its own edges pass the depth test
/// and the hidden ones do not.
fn wire_pipeline(
    device: &wgpu::Device,
    format: wgpu::TextureFormat,
    uniform: &wgpu::Buffer,
) -> (wgpu::RenderPipeline, wgpu::BindGroup) {
    let depth = wgpu::DepthStencilState {
        format: DEPTH,
        depth_write_enabled: Some(false),
        depth_compare: Some(wgpu::CompareFunction::LessEqual),
        stencil: Default::default(),
        bias: Default::default(),
    };
    let lines = wgpu::PrimitiveState { topology: wgpu::PrimitiveTopology::LineList, ..Default::default() };
    mesh_vertex_pipeline(device, format, uniform, "mesh wireframe", ("vs", "fs_wire"), lines, depth)
}

/// A pipeline over the mesh's vertex buffers (positions, normals, colours) and its view uniform, with
/// `shaders/mesh.wgsl`'s given (vertex, fragment) entries, primitive state and depth state.
fn mesh_vertex_pipeline(
    device: &wgpu::Device,
    format: wgpu::TextureFormat,
    uniform: &wgpu::Buffer,
    label: &str,
    (vertex_entry, fragment_entry): (&str, &str),
    primitive: wgpu::PrimitiveState,
    depth: wgpu::DepthStencilState,
) -> (wgpu::RenderPipeline, wgpu::BindGroup) {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(MESH_SHADER.into()),
    });
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some(label),
        layout: None,
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some(vertex_entry),
            compilation_options: Default::default(),
            buffers: &[
                Some(wgpu::VertexBufferLayout {
                    array_stride: 12,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![0 => Float32x3],
                }),
                Some(wgpu::VertexBufferLayout {
                    array_stride: 12,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![1 => Float32x3],
                }),
                Some(wgpu::VertexBufferLayout {
                    array_stride: 4,
                    step_mode: wgpu::VertexStepMode::Vertex,
                    attributes: &wgpu::vertex_attr_array![2 => Unorm8x4],
                }),
            ],
        },
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some(fragment_entry),
            compilation_options: Default::default(),
            targets: &[Some(format.into())],
        }),
        primitive,
        depth_stencil: Some(depth),
        multisample: Default::default(),
        multiview_mask: None,
        cache: None,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(label),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() }],
    });
    (pipeline, bind_group)
}

fn depth_view(device: &wgpu::Device, width: u32, height: u32) -> wgpu::TextureView {
    device
        .create_texture(&wgpu::TextureDescriptor {
            label: Some("depth"),
            size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        })
        .create_view(&Default::default())
}
