//! The network's forward pass as WGSL compute kernels (`shaders/net_*.wgsl`).
//!
//! Why this shape:
//! - Weights are uploaded once in [`GpuNet::new`]: the raw f32 tensors (PyTorch layouts, read
//!   by offset), the 3x3 convolutions repacked as vec4 output-channel groups, and the decoder
//!   repacked in a fixed order so its shader needs no offset table. Sizes come from the weights'
//!   metadata and are pasted into the shader text (`{{H}}`, …) because WGSL private arrays need
//!   constant sizes.
//! - WGSL has no float atomics, so the encoder's per-cell max pooling and scatter-mean are
//!   gathers over a cell → points list built on the CPU by a stable counting sort ([`Cells`],
//!   O(N)); each (cell, channel) is reduced by one invocation in point order. That is also where
//!   the contract's exact f32 cell assignment is computed, once, shared with the CPU reference,
//!   so both put every point in the same cell and results are deterministic.
//! - The encoder and the U-Net are recorded into one command buffer (a few dozen dispatches,
//!   each one kernel over all three planes); intermediate buffers are per call.
//! - Decoding goes in chunks of queries whose size derives from the device's binding limit (and a
//!   cap that keeps each submission short enough for browser watchdogs); buffers are allocated
//!   once per call and reused by every chunk.
//! - Everything is f32 (browsers have no f64), workgroups are 64 invocations, and 1-D work is
//!   folded into 2-D dispatches by [`Gpu::dispatch_linear`].
//! - `GpuNet` keeps its own handles to the device (wgpu handles are reference-counted clones),
//!   so it can be stored next to the [`Gpu`] it came from without a borrow.

use std::collections::BTreeMap;

use super::{Cells, NetConfig, Planes, Weights, ENCODER_BLOCKS, UV_MAX};
use crate::gpu::{Gpu, GpuError};

const POINTNET_WGSL: &str = include_str!("../../shaders/net_pointnet.wgsl");
const CONV2D_WGSL: &str = include_str!("../../shaders/net_conv2d.wgsl");
const DECODER_WGSL: &str = include_str!("../../shaders/net_decoder.wgsl");

/// Workgroup size of every kernel here.
const WG: u32 = 64;

/// Most queries per decode submission, whatever the limits allow: about 1 G multiply-adds with
/// the default sizes, short enough not to trip a browser's GPU watchdog on a weak device.
pub const MAX_DECODE_CHUNK: usize = 65536;

#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct EncParams {
    n: u32,
    fc0_w: u32,
    fc0_b: u32,
    fc1_w: u32,
    fc1_b: u32,
    sc_w: u32,
    lin_w: u32,
    lin_b: u32,
    last: u32,
    rr: u32,
    _pad: [u32; 2],
}

#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct ConvParams {
    total: u32,
    r: u32,
    c_a: u32,
    c_b: u32,
    c_out: u32,
    groups: u32,
    w_off: u32,
    b_off: u32,
    relu: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct DecParams {
    n: u32,
    reso: u32,
    divisor: f32,
    uv_max: f32,
}

/// Where a repacked 3x3 convolution lives in the vec4 weight buffer (vec4 units).
#[derive(Clone, Copy, Debug)]
struct ConvSlot {
    w_off: u32,
    b_off: u32,
    c_in: usize,
    c_out: usize,
}

/// Feature planes on the GPU: `[3][c_dim][reso][reso]` f32, as [`Planes`].
pub struct GpuPlanes {
    pub buffer: wgpu::Buffer,
    pub c_dim: usize,
    pub reso: usize,
}

impl GpuPlanes {
    pub fn len(&self) -> usize {
        3 * self.c_dim * self.reso * self.reso
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

struct Pipelines {
    enc_first: wgpu::ComputePipeline,
    enc_cellmax: wgpu::ComputePipeline,
    enc_block: wgpu::ComputePipeline,
    enc_scatter: wgpu::ComputePipeline,
    conv3x3: wgpu::ComputePipeline,
    maxpool2: wgpu::ComputePipeline,
    upconv2: wgpu::ComputePipeline,
    conv1x1: wgpu::ComputePipeline,
    decode: wgpu::ComputePipeline,
}

/// The network, uploaded to a GPU.
pub struct GpuNet {
    gpu: Gpu,
    config: NetConfig,
    /// Offsets of the raw tensors in `weights`.
    offsets: BTreeMap<String, u32>,
    weights: wgpu::Buffer,
    conv_w: wgpu::Buffer,
    convs: BTreeMap<String, ConvSlot>,
    dec_w: wgpu::Buffer,
    pipes: Pipelines,
    chunk: usize,
}

/// A second handle on the same device (wgpu handles are reference-counted).
fn share(gpu: &Gpu) -> Gpu {
    Gpu {
        adapter: gpu.adapter.clone(),
        device: gpu.device.clone(),
        queue: gpu.queue.clone(),
        info: gpu.info.clone(),
        limits: gpu.limits.clone(),
    }
}

fn to_u32(what: &str, v: usize) -> Result<u32, GpuError> {
    u32::try_from(v).map_err(|_| GpuError::TooLarge(format!("{what}: {v} does not fit 32 bits")))
}

/// The vec4 repacking of a 3x3 conv: `[c_in][9][groups]` vec4 (lane l = output 4g + l), then
/// `groups` vec4 of bias.
fn pack_conv3x3(out: &mut Vec<[f32; 4]>, wt: &[f32], bias: &[f32], c_in: usize) -> (usize, usize) {
    let c_out = bias.len();
    let groups = c_out.div_ceil(4);
    let w_off = out.len();
    for c in 0..c_in {
        for tap in 0..9 {
            for g in 0..groups {
                out.push(std::array::from_fn(|l| {
                    let o = 4 * g + l;
                    if o < c_out { wt[(o * c_in + c) * 9 + tap] } else { 0.0 }
                }));
            }
        }
    }
    let b_off = out.len();
    for g in 0..groups {
        out.push(std::array::from_fn(|l| bias.get(4 * g + l).copied().unwrap_or(0.0)));
    }
    (w_off, b_off)
}

/// The decoder's weights in the order `shaders/net_decoder.wgsl` expects.
fn pack_decoder(w: &Weights) -> Vec<f32> {
    let mut v = Vec::new();
    v.extend_from_slice(w.t("decoder.fc_p.weight"));
    v.extend_from_slice(w.t("decoder.fc_p.bias"));
    for b in 0..w.config().n_blocks_dec {
        for name in [
            format!("decoder.fc_c.{b}.weight"),
            format!("decoder.fc_c.{b}.bias"),
            format!("decoder.blocks.{b}.fc_0.weight"),
            format!("decoder.blocks.{b}.fc_0.bias"),
            format!("decoder.blocks.{b}.fc_1.weight"),
            format!("decoder.blocks.{b}.fc_1.bias"),
        ] {
            v.extend_from_slice(w.t(&name));
        }
    }
    v.extend_from_slice(w.t("decoder.fc_out.weight"));
    v.extend_from_slice(w.t("decoder.fc_out.bias"));
    v
}

/// Pipelines for several entry points of one WGSL module (layouts inferred per entry point).
fn pipelines(gpu: &Gpu, label: &str, source: &str, entries: &[&str]) -> Vec<wgpu::ComputePipeline> {
    let module = gpu.device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    entries
        .iter()
        .map(|e| {
            gpu.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(e),
                layout: None,
                module: &module,
                entry_point: Some(e),
                compilation_options: Default::default(),
                cache: None,
            })
        })
        .collect()
}

/// Substitutes `{{KEY}}` placeholders.
fn specialise(source: &str, vars: &[(&str, usize)]) -> String {
    let mut s = source.to_string();
    for (k, v) in vars {
        s = s.replace(&format!("{{{{{k}}}}}"), &v.to_string());
    }
    debug_assert!(!s.contains("{{"), "unreplaced placeholder");
    s
}

impl GpuNet {
    /// Uploads `weights` and builds the kernels for its sizes.
    pub async fn new(gpu: &Gpu, weights: &Weights) -> Result<GpuNet, GpuError> {
        let cfg = weights.config().clone();
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);

        let data = weights.data();
        gpu.check_binding::<f32>("network weights", data.len())?;
        to_u32("network weights", data.len())?;
        let offsets: BTreeMap<String, u32> =
            weights.names().map(|n| (n.to_string(), weights.off(n) as u32)).collect();
        let weights_buf = gpu.upload("net weights", data);

        let mut packed: Vec<[f32; 4]> = Vec::new();
        let mut convs = BTreeMap::new();
        let mut add_conv = |name: String, c_in: usize| {
            let wt = weights.t(&format!("{name}.weight"));
            let bias = weights.t(&format!("{name}.bias"));
            let (w_off, b_off) = pack_conv3x3(&mut packed, wt, bias, c_in);
            convs.insert(name, (w_off, b_off, c_in, bias.len()));
        };
        for k in 0..cfg.unet_depth {
            let fin = if k == 0 { cfg.c_dim } else { cfg.filters(k - 1) };
            add_conv(format!("unet.down.{k}.conv0"), fin);
            add_conv(format!("unet.down.{k}.conv1"), cfg.filters(k));
        }
        for k in 0..cfg.unet_depth - 1 {
            add_conv(format!("unet.up.{k}.conv0"), 2 * cfg.filters(k));
            add_conv(format!("unet.up.{k}.conv1"), cfg.filters(k));
        }
        gpu.check_binding::<[f32; 4]>("packed convolutions", packed.len())?;
        to_u32("packed convolutions", packed.len())?;
        let convs = convs
            .into_iter()
            .map(|(k, (w_off, b_off, c_in, c_out))| {
                (k, ConvSlot { w_off: w_off as u32, b_off: b_off as u32, c_in, c_out })
            })
            .collect();
        let conv_w = gpu.upload("net conv weights", &packed);
        let dec_w = gpu.upload("net decoder weights", &pack_decoder(weights));

        let pointnet = specialise(POINTNET_WGSL, &[("H", cfg.h), ("C_DIM", cfg.c_dim)]);
        let decoder = specialise(
            DECODER_WGSL,
            &[("C_DIM", cfg.c_dim), ("H_DEC", cfg.h_dec), ("N_BLOCKS", cfg.n_blocks_dec)],
        );
        let mut enc = pipelines(gpu, "net_pointnet", &pointnet, &["enc_first", "enc_cellmax", "enc_block", "enc_scatter"]).into_iter();
        let mut conv = pipelines(gpu, "net_conv2d", CONV2D_WGSL, &["conv3x3", "maxpool2", "upconv2", "conv1x1"]).into_iter();
        let mut dec = pipelines(gpu, "net_decoder", &decoder, &["decode"]).into_iter();
        let mut next = |it: &mut std::vec::IntoIter<wgpu::ComputePipeline>| it.next().expect("one pipeline per entry");
        let pipes = Pipelines {
            enc_first: next(&mut enc),
            enc_cellmax: next(&mut enc),
            enc_block: next(&mut enc),
            enc_scatter: next(&mut enc),
            conv3x3: next(&mut conv),
            maxpool2: next(&mut conv),
            upconv2: next(&mut conv),
            conv1x1: next(&mut conv),
            decode: next(&mut dec),
        };
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("building the network kernels: {e}")));
        }

        // Per chunk the largest binding is the features (c_dim f32 per query).
        let chunk = gpu
            .rows_per_binding((cfg.c_dim * 4) as u64)
            .min(gpu.rows_per_binding(12))
            .min(MAX_DECODE_CHUNK)
            .max(1);
        Ok(GpuNet {
            gpu: share(gpu),
            config: cfg,
            offsets,
            weights: weights_buf,
            conv_w,
            convs,
            dec_w,
            pipes,
            chunk,
        })
    }

    /// [`GpuNet::new`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_blocking(gpu: &Gpu, weights: &Weights) -> Result<GpuNet, GpuError> {
        pollster::block_on(Self::new(gpu, weights))
    }

    pub fn config(&self) -> &NetConfig {
        &self.config
    }

    /// Queries per decode submission on this device.
    pub fn chunk_queries(&self) -> usize {
        self.chunk
    }

    /// Sets the queries per decode submission (clamped to 1..=the device-derived size); for
    /// tests, and for callers that want shorter submissions.
    pub fn set_chunk_queries(&mut self, n: usize) {
        let max = self
            .gpu
            .rows_per_binding((self.config.c_dim * 4) as u64)
            .min(self.gpu.rows_per_binding(12));
        self.chunk = n.clamp(1, max);
    }

    fn off(&self, name: &str) -> u32 {
        *self.offsets.get(name).unwrap_or_else(|| panic!("tensor {name} was validated at load"))
    }

    /// A bind group for `pipeline` with buffers at explicit binding indices.
    fn bind(&self, pipeline: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(i, b)| wgpu::BindGroupEntry { binding: *i, resource: b.as_entire_binding() })
            .collect();
        self.gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Records one dispatch of `pipeline` over `n` items.
    fn pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        entries: &[(u32, &wgpu::Buffer)],
        n: u64,
    ) -> Result<(), GpuError> {
        let groups = self.gpu.dispatch_linear(n, WG)?;
        let bg = self.bind(pipeline, entries);
        self.gpu.encode_pass(enc, pipeline, &bg, groups);
        Ok(())
    }

    /// A storage buffer of `len` f32 (zeroed).
    fn buf(&self, label: &str, len: usize) -> Result<wgpu::Buffer, GpuError> {
        to_u32(label, len)?;
        self.gpu.storage::<f32>(label, len)
    }

    /// Points (normalised, in [-0.5, 0.5]³) → the planes the decoder samples (after the U-Net).
    /// The work is submitted; the returned buffer is ready for [`GpuNet::decode`] (queue order)
    /// or [`GpuNet::read_planes`].
    pub async fn encode(&self, points: &[[f32; 3]]) -> Result<GpuPlanes, GpuError> {
        let cfg = &self.config;
        let (r, h, c_dim) = (cfg.reso, cfg.h, cfg.c_dim);
        let rr = r * r;
        let n = points.len();
        let cells = Cells::new(points, r, cfg.plane_divisor());
        let k = cells.len();

        let scope = self.gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let g = &self.gpu;
        // Checks first: every binding within the device's limits, every index within u32.
        for (label, len) in [
            ("cloud", 3 * n),
            ("point features", n * h),
            ("point codes", n * c_dim),
            ("cell maxima", k * h),
            ("planes", 3 * c_dim * rr),
            ("U-Net activations", 3 * 2 * cfg.unet_filters * rr),
        ] {
            g.check_binding::<f32>(label, len)?;
            to_u32(label, len)?;
        }
        let pts_buf = g.upload("cloud", bytemuck::cast_slice::<[f32; 3], f32>(points));
        let cell_of = g.upload("cell_of", &cells.cell_of);
        let cell_start = g.upload("cell_start", &cells.cell_start);
        let cell_pts = g.upload("cell_pts", &cells.points);
        let cell_dst = g.upload("cell_dst", &cells.cell_plane_cell);
        let net = self.buf("point features", n * h)?;
        let cell_max = self.buf("cell maxima", k * h)?;
        let cfeat = self.buf("point codes", n * c_dim)?;
        let scattered = self.buf("scattered planes", 3 * c_dim * rr)?;

        let mut enc = g.device.create_command_encoder(&Default::default());
        let mut uniforms = Vec::new();
        let mut uni = |p: EncParams| {
            uniforms.push(g.uniform("enc params", &p));
            uniforms.len() - 1
        };
        let block = |b: usize| {
            let o = |s: &str| self.off(&format!("encoder.blocks.{b}.{s}"));
            EncParams {
                fc0_w: o("fc_0.weight"),
                fc0_b: o("fc_0.bias"),
                fc1_w: o("fc_1.weight"),
                fc1_b: o("fc_1.bias"),
                sc_w: o("shortcut.weight"),
                rr: rr as u32,
                ..Default::default()
            }
        };
        // Uniforms are created up front so the bind groups can borrow them.
        let first = uni(EncParams {
            n: n as u32,
            lin_w: self.off("encoder.fc_pos.weight"),
            lin_b: self.off("encoder.fc_pos.bias"),
            ..block(0)
        });
        let cellmax_u = uni(EncParams { n: (k * h) as u32, ..Default::default() });
        let blocks_u: Vec<usize> = (1..ENCODER_BLOCKS)
            .map(|b| {
                let last = b == ENCODER_BLOCKS - 1;
                uni(EncParams {
                    n: n as u32,
                    lin_w: self.off("encoder.fc_c.weight"),
                    lin_b: self.off("encoder.fc_c.bias"),
                    last: last as u32,
                    ..block(b)
                })
            })
            .collect();
        let scatter_u = uni(EncParams { n: (k * c_dim) as u32, rr: rr as u32, ..Default::default() });

        let p = &self.pipes;
        self.pass(&mut enc, &p.enc_first, &[(0, &uniforms[first]), (1, &self.weights), (2, &pts_buf), (3, &net)], n as u64)?;
        for &bu in &blocks_u {
            self.pass(
                &mut enc,
                &p.enc_cellmax,
                &[(0, &uniforms[cellmax_u]), (3, &net), (5, &cell_start), (6, &cell_pts), (7, &cell_max)],
                (k * h) as u64,
            )?;
            self.pass(
                &mut enc,
                &p.enc_block,
                &[(0, &uniforms[bu]), (1, &self.weights), (3, &net), (4, &cell_of), (7, &cell_max), (8, &cfeat)],
                n as u64,
            )?;
        }
        self.pass(
            &mut enc,
            &p.enc_scatter,
            &[(0, &uniforms[scatter_u]), (5, &cell_start), (6, &cell_pts), (8, &cfeat), (9, &cell_dst), (10, &scattered)],
            (k * c_dim) as u64,
        )?;

        let out = self.unet(&mut enc, scattered)?;
        g.queue.submit([enc.finish()]);
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("encoding: {e}")));
        }
        Ok(GpuPlanes { buffer: out, c_dim, reso: r })
    }

    /// Records the U-Net over the three planes in `x` (`[3][c_dim][R][R]`); returns its output.
    fn unet(&self, enc: &mut wgpu::CommandEncoder, x: wgpu::Buffer) -> Result<wgpu::Buffer, GpuError> {
        let cfg = &self.config;
        let g = &self.gpu;
        let d = cfg.unet_depth;
        // Keeps every uniform alive until the command buffer is submitted (wgpu also keeps
        // resources referenced by recorded commands alive; this is belt and braces).
        let mut keep: Vec<wgpu::Buffer> = Vec::new();

        let conv = |enc: &mut wgpu::CommandEncoder,
                    keep: &mut Vec<wgpu::Buffer>,
                    name: &str,
                    a: &wgpu::Buffer,
                    b: Option<&wgpu::Buffer>,
                    c_a: usize,
                    r: usize|
         -> Result<wgpu::Buffer, GpuError> {
            let s = self.convs[name];
            let groups = s.c_out.div_ceil(4);
            let c_b = s.c_in - c_a;
            let out = self.buf(name, 3 * s.c_out * r * r)?;
            let total = 3 * groups * r * r;
            let u = g.uniform(
                "conv params",
                &ConvParams {
                    total: to_u32(name, total)?,
                    r: r as u32,
                    c_a: c_a as u32,
                    c_b: c_b as u32,
                    c_out: s.c_out as u32,
                    groups: groups as u32,
                    w_off: s.w_off,
                    b_off: s.b_off,
                    relu: 1,
                    _pad: [0; 3],
                },
            );
            self.pass(
                enc,
                &self.pipes.conv3x3,
                &[(0, &u), (1, a), (2, b.unwrap_or(a)), (3, &self.conv_w), (4, &out)],
                total as u64,
            )?;
            keep.push(u);
            Ok(out)
        };

        let mut x = x;
        let mut c = cfg.c_dim;
        let mut r = cfg.reso;
        let mut skips: Vec<wgpu::Buffer> = Vec::new();
        for k in 0..d {
            if k > 0 {
                r /= 2;
                let out = self.buf("maxpool", 3 * c * r * r)?;
                let total = 3 * c * r * r;
                let u = g.uniform("pool params", &ConvParams { total: total as u32, r: r as u32, ..Default::default() });
                self.pass(enc, &self.pipes.maxpool2, &[(0, &u), (1, &x), (4, &out)], total as u64)?;
                keep.push(u);
                x = out;
            }
            let y = conv(enc, &mut keep, &format!("unet.down.{k}.conv0"), &x, None, c, r)?;
            c = cfg.filters(k);
            x = conv(enc, &mut keep, &format!("unet.down.{k}.conv1"), &y, None, c, r)?;
            if k + 1 < d {
                skips.push(x.clone());
            }
        }
        for k in (0..d - 1).rev() {
            let f = cfg.filters(k);
            let name = format!("unet.up.{k}");
            r *= 2;
            let up = self.buf("upconv", 3 * f * r * r)?;
            let total = 3 * f * r * r;
            let u = g.uniform(
                "upconv params",
                &ConvParams {
                    total: total as u32,
                    r: r as u32,
                    c_a: c as u32,
                    c_out: f as u32,
                    w_off: self.off(&format!("{name}.upconv.weight")),
                    b_off: self.off(&format!("{name}.upconv.bias")),
                    ..Default::default()
                },
            );
            self.pass(enc, &self.pipes.upconv2, &[(0, &u), (1, &x), (4, &up), (5, &self.weights)], total as u64)?;
            keep.push(u);
            let y = conv(enc, &mut keep, &format!("{name}.conv0"), &up, Some(&skips[k]), f, r)?;
            x = conv(enc, &mut keep, &format!("{name}.conv1"), &y, None, f, r)?;
            c = f;
        }
        let out = self.buf("planes", 3 * cfg.c_dim * r * r)?;
        let total = 3 * cfg.c_dim * r * r;
        let u = g.uniform(
            "final params",
            &ConvParams {
                total: total as u32,
                r: r as u32,
                c_a: c as u32,
                c_out: cfg.c_dim as u32,
                w_off: self.off("unet.final.weight"),
                b_off: self.off("unet.final.bias"),
                ..Default::default()
            },
        );
        self.pass(enc, &self.pipes.conv1x1, &[(0, &u), (1, &x), (4, &out), (5, &self.weights)], total as u64)?;
        keep.push(u);
        Ok(out)
    }

    /// Uploads CPU planes (e.g. from [`super::cpu::encode`] or a fixture).
    pub fn upload_planes(&self, planes: &Planes) -> Result<GpuPlanes, GpuError> {
        if (planes.c_dim, planes.reso) != (self.config.c_dim, self.config.reso) {
            return Err(GpuError::Kernel(format!(
                "planes are {}x{}², the network needs {}x{}²",
                planes.c_dim, planes.reso, self.config.c_dim, self.config.reso
            )));
        }
        self.gpu.check_binding::<f32>("planes", planes.data.len())?;
        Ok(GpuPlanes { buffer: self.gpu.upload("planes", &planes.data), c_dim: planes.c_dim, reso: planes.reso })
    }

    /// Downloads planes.
    pub async fn read_planes(&self, planes: &GpuPlanes) -> Result<Planes, GpuError> {
        let data = self.gpu.read::<f32>(&planes.buffer, planes.len()).await?;
        Ok(Planes { c_dim: planes.c_dim, reso: planes.reso, data })
    }

    /// Queries (normalised coordinates) → (features `Q × c_dim`, row-major; logits `Q`), in
    /// chunks of [`GpuNet::chunk_queries`].
    pub async fn decode(&self, planes: &GpuPlanes, queries: &[[f32; 3]]) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
        let cfg = &self.config;
        if (planes.c_dim, planes.reso) != (cfg.c_dim, cfg.reso) {
            return Err(GpuError::Kernel(format!(
                "planes are {}x{}², the network needs {}x{}²",
                planes.c_dim, planes.reso, cfg.c_dim, cfg.reso
            )));
        }
        let c = cfg.c_dim;
        let mut features = Vec::with_capacity(queries.len() * c);
        let mut logits = Vec::with_capacity(queries.len());
        if queries.is_empty() {
            return Ok((features, logits));
        }
        let g = &self.gpu;
        let chunk = self.chunk.min(queries.len());
        let scope = g.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let q_buf = self.buf("queries", 3 * chunk)?;
        let f_buf = self.buf("features", c * chunk)?;
        let l_buf = self.buf("logits", chunk)?;
        let params = g.uniform("decode params", &DecParams::default());
        let bg = self.bind(
            &self.pipes.decode,
            &[(0, &params), (1, &self.dec_w), (2, &planes.buffer), (3, &q_buf), (4, &f_buf), (5, &l_buf)],
        );
        let mut result = Ok(());
        for part in queries.chunks(chunk) {
            let m = part.len();
            let p = DecParams {
                n: m as u32,
                reso: cfg.reso as u32,
                divisor: cfg.plane_divisor(),
                uv_max: UV_MAX,
            };
            g.queue.write_buffer(&params, 0, bytemuck::bytes_of(&p));
            g.queue.write_buffer(&q_buf, 0, bytemuck::cast_slice(part));
            let mut enc = g.device.create_command_encoder(&Default::default());
            let groups = match g.dispatch_linear(m as u64, WG) {
                Ok(gr) => gr,
                Err(e) => {
                    result = Err(e);
                    break;
                }
            };
            g.encode_pass(&mut enc, &self.pipes.decode, &bg, groups);
            g.queue.submit([enc.finish()]);
            match g.read::<f32>(&f_buf, m * c).await {
                Ok(v) => features.extend_from_slice(&v),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
            match g.read::<f32>(&l_buf, m).await {
                Ok(v) => logits.extend_from_slice(&v),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("decoding: {e}")));
        }
        result.map(|_| (features, logits))
    }

    /// [`GpuNet::encode`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn encode_blocking(&self, points: &[[f32; 3]]) -> Result<GpuPlanes, GpuError> {
        pollster::block_on(self.encode(points))
    }

    /// [`GpuNet::decode`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn decode_blocking(&self, planes: &GpuPlanes, queries: &[[f32; 3]]) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
        pollster::block_on(self.decode(planes, queries))
    }

    /// [`GpuNet::read_planes`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn read_planes_blocking(&self, planes: &GpuPlanes) -> Result<Planes, GpuError> {
        pollster::block_on(self.read_planes(planes))
    }

    /// Waits until submitted work is done (natively; on the web the browser drives it).
    pub fn wait(&self) {
        self.gpu.poll_wait();
    }
}
