//! The network's forward pass as WGSL compute kernels (`shaders/net_*.wgsl`).
//!
//! Why this shape:
//! - Weights are repacked and uploaded once, in [`GpuNet::new`], into three vec4 buffers
//!   (encoder, U-Net, decoder), laid out for the kernels rather than as PyTorch stores them:
//!   Linear layers as 4x4 blocks for `mat4x4 * vec4`, convolutions as vec4s of 4 output
//!   channels per (input channel, tap). On every device measured (llvmpipe) the kernels are
//!   bound by loads, not arithmetic, so the layouts aim at few, wide, uniform loads.
//! - Sizes come from the weights' metadata and are pasted into the shader text (`{{HB}}`, …)
//!   because WGSL private arrays need constant sizes; nothing is fixed at the default sizes.
//! - WGSL has no float atomics, so the encoder's per-cell max pooling and scatter-mean are
//!   gathers over a cell → points list built on the CPU by a stable counting sort ([`Cells`],
//!   O(N)); each (cell, 4 channels) is reduced by one invocation in point order. That is also
//!   where the contract's exact f32 cell assignment is computed, once, shared with the CPU
//!   reference, so both put every point in the same cell and results are deterministic.
//! - The encoder and the U-Net are recorded into one command buffer (about 30 dispatches, each
//!   over all three planes at once); intermediate buffers are per call. The U-Net's final 1x1
//!   convolution writes the planes channel-last ([`GpuPlanes`]) so each bilinear corner the
//!   decoder reads is a few vec4 loads.
//! - Decoding goes in chunks of [`GpuNet::chunk_queries`] queries (at most [`MAX_DECODE_CHUNK`],
//!   fewer where the device's binding limit requires), so a call with millions of queries
//!   respects binding and dispatch limits and no submission runs long enough to trip a
//!   browser's GPU watchdog; the chunk buffers are allocated once per [`Decoder`] and reused.
//! - Everything is f32 (browsers have no f64), workgroups are 64 invocations, and 1-D work is
//!   folded into 2-D dispatches by [`Gpu::dispatch_linear`]. Device errors during a call are
//!   caught with an error scope and returned as [`GpuError::Kernel`].
//! - `GpuNet` keeps its own handles to the device (wgpu handles are reference-counted clones),
//!   so it can be stored next to the [`Gpu`] it came from without a borrow.

use std::collections::BTreeMap;

use super::geometry::{Cells, Planes, UV_MAX};
use super::weights::{NetConfig, Weights, ENCODER_BLOCKS};
use crate::gpu::{specialise, to_u32, Footprint, Gpu, GpuError};

const POINTNET_WGSL: &str = include_str!("../../shaders/net_pointnet.wgsl");
const CONV2D_WGSL: &str = include_str!("../../shaders/net_conv2d.wgsl");
const DECODER_WGSL: &str = include_str!("../../shaders/net_decoder.wgsl");

/// Binding indices of `shaders/net_pointnet.wgsl` (its `@group(0) @binding(N)` declarations;
/// keep the two in step).
mod pointnet_at {
    pub const PRM: u32 = 0;
    pub const W: u32 = 1;
    pub const POINTS: u32 = 2;
    pub const NET: u32 = 3;
    pub const CELL_OF: u32 = 4;
    pub const CELL_START: u32 = 5;
    pub const CELL_PTS: u32 = 6;
    pub const CELL_MAX: u32 = 7;
    pub const CFEAT: u32 = 8;
    pub const CELL_DST: u32 = 9;
    pub const PLANES: u32 = 10;
}

/// Binding indices of `shaders/net_conv2d.wgsl` (its `@group(0) @binding(N)` declarations).
mod conv2d_at {
    pub const PRM: u32 = 0;
    pub const IN_A: u32 = 1;
    pub const IN_B: u32 = 2;
    pub const WV: u32 = 3;
    pub const OUT: u32 = 4;
    pub const OUT4: u32 = 5;
}

/// Binding indices of `shaders/net_decoder.wgsl` (its `@group(0) @binding(N)` declarations).
mod decoder_at {
    pub const PRM: u32 = 0;
    pub const W: u32 = 1;
    pub const PLANES: u32 = 2;
    pub const QUERIES: u32 = 3;
    pub const FEATURES: u32 = 4;
    pub const LOGITS: u32 = 5;
}

/// Workgroup size of every kernel here.
const WG: u32 = 64;

/// Most queries per decode submission, whatever the limits allow: about 1 G multiply-adds with
/// the default sizes, short enough not to trip a browser's GPU watchdog on a weak device (and
/// under a second per chunk on llvmpipe).
pub const MAX_DECODE_CHUNK: usize = 65536;

/// The most queries one decode submission can hold when bindings are at most `binding` bytes:
/// the largest per-query binding is the features, `c_dim` f32 (at least 3, the query itself).
pub fn max_decode_queries(binding: u64, c_dim: usize) -> usize {
    (binding / (c_dim.max(3) * 4) as u64).max(1) as usize
}

/// Bytes of the planes [`GpuNet::encode`] returns (three planes of `4·⌈c/4⌉` channels).
pub fn planes_bytes(cfg: &NetConfig) -> u64 {
    48 * cfg.c_dim.div_ceil(4) as u64 * (cfg.reso * cfg.reso) as u64
}

/// What one [`GpuNet::encode`] of `n` points allocates, as it and `unet` do: per point, the
/// input, the PointNet's activations (`hb`, `cb` vec4s) and the cell indices; per occupied cell
/// (at most `3 reso²`) the pooled features; the U-Net's activations and the output planes. On
/// the host: the points and their cell indices (48 bytes a point).
pub fn encode_footprint(cfg: &NetConfig, n: u64) -> Footprint {
    let (c, reso) = (cfg.c_dim as u64, cfg.reso as u64);
    let (hb, cb) = ((cfg.h as u64).div_ceil(4), c.div_ceil(4));
    // As `unet` allocates: inputs, per level two convolutions (and a pool below the top), per
    // upward level an up-convolution and a concatenation, then the output planes.
    let mut floats = 3 * c * reso * reso;
    for k in 0..cfg.unet_depth {
        let r = reso >> k;
        let f = cfg.filters(k) as u64;
        if k > 0 {
            floats += 3 * cfg.filters(k - 1) as u64 * r * r;
        }
        floats += 6 * f * r * r;
        if k + 1 < cfg.unet_depth {
            floats += 9 * f * r * r;
        }
    }
    floats += 12 * cb * reso * reso;
    let cells = (3 * n).min(3 * reso * reso);
    Footprint {
        gpu: (36 + 16 * hb + 16 * cb) * n + (8 + 16 * hb) * cells + 4 * floats,
        largest: (16 * hb.max(cb) * n).max(16 * hb * cells).max(planes_bytes(cfg)),
        host: 48 * n,
    }
}

/// The most points one encode can take: its per-point buffers (`16·max(hb, cb)` bytes a point)
/// are not tiled.
pub fn max_encode_points(cfg: &NetConfig, binding: u64) -> u64 {
    binding / (16 * (cfg.h as u64).div_ceil(4).max((cfg.c_dim as u64).div_ceil(4)))
}

/// Queries per decode submission, as [`GpuNet::decode`] picks them, for `queries` queries.
pub fn decode_chunk(cfg: &NetConfig, binding: u64, queries: u64) -> u64 {
    let max = max_decode_queries(binding, cfg.c_dim).min(MAX_DECODE_CHUNK);
    (max as u64).min(queries).max(1)
}

/// What a [`Decoder`] for submissions of `queries` queries holds on the GPU: queries, features
/// and logits of a chunk, the staging buffer both are read back through, and its parameters (the
/// planes are counted by their owner).
pub fn decode_footprint(cfg: &NetConfig, binding: u64, queries: u64) -> Footprint {
    let (c, cd) = (cfg.c_dim as u64, decode_chunk(cfg, binding, queries));
    let params = std::mem::size_of::<DecParams>() as u64;
    Footprint { gpu: (16 + 8 * c) * cd + params, largest: 4 * c * cd, host: 0 }
}

#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct EncParams {
    n: u32,
    fc0_w: u32,
    fc0_b: u32,
    fc1_w: u32,
    fc1_b: u32,
    sc_w: u32,
    nin: u32,
    lin_w: u32,
    lin_b: u32,
    last: u32,
    rr: u32,
    _pad: u32,
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
    n_blocks: u32,
    hb: u32,
    cb: u32,
    _pad: u32,
}

/// Where a repacked layer lives in its vec4 buffer (vec4 units).
#[derive(Clone, Copy, Debug)]
struct Slot {
    w_off: u32,
    b_off: u32,
    /// Output channels.
    n_out: usize,
}

/// Feature planes on the GPU, in the decoder's layout: channel-last, `[3][reso][reso][4 cb]` f32
/// with `cb = ceil(c_dim / 4)` and channels past `c_dim` zero. [`GpuNet::read_planes`] and
/// [`GpuNet::upload_planes`] convert from and to the contract's `[3][c_dim][reso][reso]`.
pub struct GpuPlanes {
    pub buffer: wgpu::Buffer,
    pub c_dim: usize,
    pub reso: usize,
}

impl GpuPlanes {
    /// Padded channels per pixel.
    fn stride(&self) -> usize {
        4 * self.c_dim.div_ceil(4)
    }
    /// f32 elements in the buffer.
    pub fn len(&self) -> usize {
        3 * self.reso * self.reso * self.stride()
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
    final1x1: wgpu::ComputePipeline,
    decode: wgpu::ComputePipeline,
}

/// The network, uploaded to a GPU.
pub struct GpuNet {
    gpu: Gpu,
    config: NetConfig,
    enc_w: wgpu::Buffer,
    enc_slots: BTreeMap<String, Slot>,
    unet_w: wgpu::Buffer,
    unet_slots: BTreeMap<String, Slot>,
    dec_w: wgpu::Buffer,
    pipes: Pipelines,
    chunk: usize,
}


/// An encoding's command encoder and the scratch buffers its passes use, retired once it is
/// submitted ([`Gpu::retire`]): a scene encodes once per tile.
struct Recording {
    enc: wgpu::CommandEncoder,
    scratch: Vec<wgpu::Buffer>,
}

impl Recording {
    /// `b`, noted as scratch (a handle: the clone is the same buffer).
    fn scratch(&mut self, b: wgpu::Buffer) -> wgpu::Buffer {
        self.scratch.push(b.clone());
        b
    }
}

/// Output channels one U-Net invocation computes (4 vec4 accumulators).
const CONV_BLOCK: usize = 16;

fn slot(w_off: usize, b_off: usize, n_out: usize) -> Slot {
    Slot { w_off: w_off as u32, b_off: b_off as u32, n_out }
}

/// A convolution repacked for `shaders/net_conv2d.wgsl`: for each `(c, tap)` of `rows`, in that
/// order, `4 * ceil(c_out / 16)` vec4s whose lane l of vec4 v is `get(4v + l, c, tap)` (zero past
/// `c_out`); then the bias in as many vec4s.
fn pack_conv(
    out: &mut Vec<[f32; 4]>,
    bias: &[f32],
    rows: impl Iterator<Item = (usize, usize)>,
    get: impl Fn(usize, usize, usize) -> f32,
) -> Slot {
    let c_out = bias.len();
    let vecs = 4 * c_out.div_ceil(CONV_BLOCK);
    let w_off = out.len();
    for (c, tap) in rows {
        for v in 0..vecs {
            out.push(std::array::from_fn(|l| {
                let o = 4 * v + l;
                if o < c_out { get(o, c, tap) } else { 0.0 }
            }));
        }
    }
    let b_off = out.len();
    for v in 0..vecs {
        out.push(std::array::from_fn(|l| bias.get(4 * v + l).copied().unwrap_or(0.0)));
    }
    slot(w_off, b_off, c_out)
}

/// Input positions of a zero-padded vector of `n` values: position i holds value i.
fn plain(n: usize) -> Vec<Option<usize>> {
    (0..4 * n.div_ceil(4)).map(|i| (i < n).then_some(i)).collect()
}

/// Input positions of the encoder's `[net | pooled]`, each half padded to whole vec4s.
fn concat_halves(h: usize) -> Vec<Option<usize>> {
    let half = plain(h);
    let len = half.len();
    half.iter().copied().chain(half.iter().map(|i| i.map(|i| i + h))).take(2 * len).collect()
}

/// A Linear layer (`w` is `[n_out, n_in]`) repacked as 4x4 blocks for `mat4x4 * vec4`: for each
/// output block, for each input block, 4 vec4 columns (column j = the weights of input position
/// 4k + j for outputs 4o .. 4o + 3; `inputs[p]` says which input a position holds, if any); then
/// the bias as vec4s (zero when absent).
fn pack_linear(out: &mut Vec<[f32; 4]>, w: &[f32], b: Option<&[f32]>, n_out: usize, inputs: &[Option<usize>]) -> Slot {
    let n_in = w.len() / n_out;
    let (ob, ib) = (n_out.div_ceil(4), inputs.len() / 4);
    let w_off = out.len();
    for o in 0..ob {
        for k in 0..ib {
            for j in 0..4 {
                out.push(std::array::from_fn(|l| match inputs[4 * k + j] {
                    Some(i) if 4 * o + l < n_out => w[(4 * o + l) * n_in + i],
                    _ => 0.0,
                }));
            }
        }
    }
    let b_off = out.len();
    for o in 0..ob {
        out.push(std::array::from_fn(|l| b.and_then(|b| b.get(4 * o + l)).copied().unwrap_or(0.0)));
    }
    slot(w_off, b_off, n_out)
}

fn pack_linear_named(out: &mut Vec<[f32; 4]>, w: &Weights, name: &str, inputs: &[Option<usize>]) -> Slot {
    let bias = w.get(&format!("{name}.bias"));
    let wt = w.t(&format!("{name}.weight"));
    let n_out = w.shape(&format!("{name}.weight")).expect("validated")[0];
    pack_linear(out, wt, bias, n_out, inputs)
}

/// The decoder's layers in the order `shaders/net_decoder.wgsl` expects.
fn pack_decoder(w: &Weights) -> Vec<[f32; 4]> {
    let cfg = w.config();
    let mut v = Vec::new();
    pack_linear_named(&mut v, w, "decoder.fc_p", &plain(3));
    for b in 0..cfg.n_blocks_dec {
        pack_linear_named(&mut v, w, &format!("decoder.fc_c.{b}"), &plain(cfg.c_dim));
        pack_linear_named(&mut v, w, &format!("decoder.blocks.{b}.fc_0"), &plain(cfg.h_dec));
        pack_linear_named(&mut v, w, &format!("decoder.blocks.{b}.fc_1"), &plain(cfg.h_dec));
    }
    pack_linear_named(&mut v, w, "decoder.fc_out", &plain(cfg.h_dec));
    // The shader derives these offsets from the sizes; keep the two in step.
    let (hb, cb) = (cfg.h_dec.div_ceil(4), cfg.c_dim.div_ceil(4));
    let block = (4 * hb * cb + hb) + 2 * (4 * hb * hb + hb);
    debug_assert_eq!(v.len(), 5 * hb + cfg.n_blocks_dec * block + 4 * hb + 1);
    v
}

/// The encoder's layers, by state-dict prefix.
fn pack_encoder(w: &Weights) -> (Vec<[f32; 4]>, BTreeMap<String, Slot>) {
    let h = w.config().h;
    let mut v = Vec::new();
    let mut slots = BTreeMap::new();
    let mut add = |name: String, inputs: &[Option<usize>]| {
        let s = pack_linear_named(&mut v, w, &name, inputs);
        slots.insert(name, s);
    };
    add("encoder.fc_pos".into(), &plain(3));
    for b in 0..ENCODER_BLOCKS {
        // Block 0 reads fc_pos's 2h outputs; the others read [net | pooled].
        let inputs = if b == 0 { plain(2 * h) } else { concat_halves(h) };
        add(format!("encoder.blocks.{b}.fc_0"), &inputs);
        add(format!("encoder.blocks.{b}.fc_1"), &plain(h));
        add(format!("encoder.blocks.{b}.shortcut"), &inputs);
    }
    add("encoder.fc_c".into(), &plain(h));
    (v, slots)
}

/// The U-Net's weighted layers, by state-dict prefix.
fn pack_unet(w: &Weights) -> (Vec<[f32; 4]>, BTreeMap<String, Slot>) {
    let cfg = w.config();
    let mut v = Vec::new();
    let mut slots = BTreeMap::new();
    let mut conv3 = |v: &mut Vec<[f32; 4]>, name: String, c_in: usize| {
        let wt = w.t(&format!("{name}.weight"));
        let rows = (0..9).flat_map(move |tap| (0..c_in).map(move |c| (c, tap)));
        let s = pack_conv(v, w.t(&format!("{name}.bias")), rows, |o, c, tap| wt[(o * c_in + c) * 9 + tap]);
        slots.insert(name, s);
    };
    for k in 0..cfg.unet_depth {
        let fin = if k == 0 { cfg.c_dim } else { cfg.filters(k - 1) };
        conv3(&mut v, format!("unet.down.{k}.conv0"), fin);
        conv3(&mut v, format!("unet.down.{k}.conv1"), cfg.filters(k));
    }
    for k in 0..cfg.unet_depth - 1 {
        conv3(&mut v, format!("unet.up.{k}.conv0"), 2 * cfg.filters(k));
        conv3(&mut v, format!("unet.up.{k}.conv1"), cfg.filters(k));
    }
    for k in 0..cfg.unet_depth - 1 {
        let name = format!("unet.up.{k}.upconv");
        let (c_in, c_out) = (cfg.filters(k + 1), cfg.filters(k));
        let wt = w.t(&format!("{name}.weight"));
        let rows = (0..c_in).flat_map(|c| (0..4).map(move |tap| (c, tap)));
        let s = pack_conv(&mut v, w.t(&format!("{name}.bias")), rows, |o, c, tap| wt[(c * c_out + o) * 4 + tap]);
        slots.insert(name, s);
    }
    let c_in = cfg.unet_filters;
    let wt = w.t("unet.final.weight");
    let s = pack_conv(&mut v, w.t("unet.final.bias"), (0..c_in).map(|c| (c, 0)), |o, c, _| wt[o * c_in + c]);
    slots.insert("unet.final".into(), s);
    (v, slots)
}

impl GpuNet {
    /// Uploads `weights` (repacked for the kernels) and builds the kernels for its sizes.
    pub async fn new(gpu: &Gpu, weights: &Weights) -> Result<GpuNet, GpuError> {
        let cfg = weights.config().clone();
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);

        let (enc, enc_slots) = pack_encoder(weights);
        let (unet, unet_slots) = pack_unet(weights);
        let dec = pack_decoder(weights);
        for (label, len) in [("encoder weights", enc.len()), ("U-Net weights", unet.len()), ("decoder weights", dec.len())] {
            gpu.check_binding::<[f32; 4]>(label, len)?;
            to_u32(label, len)?;
        }
        let enc_w = gpu.upload("net encoder weights", &enc);
        let unet_w = gpu.upload("net U-Net weights", &unet);
        let dec_w = gpu.upload("net decoder weights", &dec);

        let (hb, cb) = (cfg.h.div_ceil(4), cfg.c_dim.div_ceil(4));
        let pointnet = specialise(
            POINTNET_WGSL,
            &[("HB", hb), ("CB", cb), ("XB", (2 * hb).max(cb)), ("C_DIM", cfg.c_dim)],
        );
        let decoder = specialise(
            DECODER_WGSL,
            &[("CB", cb), ("C_DIM", cfg.c_dim), ("HB", cfg.h_dec.div_ceil(4)), ("N_BLOCKS", cfg.n_blocks_dec)],
        );
        let mut e = gpu.compute_pipelines("net_pointnet", &pointnet, &["enc_first", "enc_cellmax", "enc_block", "enc_scatter"]).into_iter();
        let mut c = gpu.compute_pipelines("net_conv2d", CONV2D_WGSL, &["conv3x3", "maxpool2", "upconv2", "final1x1"]).into_iter();
        let mut d = gpu.compute_pipelines("net_decoder", &decoder, &["decode"]).into_iter();
        let next = |it: &mut std::vec::IntoIter<wgpu::ComputePipeline>| it.next().expect("one pipeline per entry");
        let pipes = Pipelines {
            enc_first: next(&mut e),
            enc_cellmax: next(&mut e),
            enc_block: next(&mut e),
            enc_scatter: next(&mut e),
            conv3x3: next(&mut c),
            maxpool2: next(&mut c),
            upconv2: next(&mut c),
            final1x1: next(&mut c),
            decode: next(&mut d),
        };
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("building the network kernels: {e}")));
        }
        let mut net = GpuNet {
            // A second handle on the same device (wgpu handles are reference-counted).
            gpu: gpu.clone(),
            config: cfg,
            enc_w,
            enc_slots,
            unet_w,
            unet_slots,
            dec_w,
            pipes,
            chunk: 0,
        };
        net.set_chunk_queries(MAX_DECODE_CHUNK);
        Ok(net)
    }

    /// [`GpuNet::new`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_blocking(gpu: &Gpu, weights: &Weights) -> Result<GpuNet, GpuError> {
        pollster::block_on(Self::new(gpu, weights))
    }

    pub fn config(&self) -> &NetConfig {
        &self.config
    }

    /// Queries per decode submission on this device: [`MAX_DECODE_CHUNK`], or fewer where the
    /// device's storage binding limit cannot hold that many features.
    pub fn chunk_queries(&self) -> usize {
        self.chunk
    }

    /// Sets the queries per decode submission (clamped to 1 ..= what one binding holds); for
    /// tests, and for callers that want shorter or longer submissions.
    pub fn set_chunk_queries(&mut self, n: usize) {
        self.chunk = n.clamp(1, max_decode_queries(crate::gpu::binding_limit(&self.gpu.limits), self.config.c_dim));
    }

    fn enc_slot(&self, name: &str) -> Slot {
        *self.enc_slots.get(name).unwrap_or_else(|| panic!("{name} was packed at load"))
    }

    fn unet_slot(&self, name: &str) -> Slot {
        *self.unet_slots.get(name).unwrap_or_else(|| panic!("{name} was packed at load"))
    }

    /// Records one dispatch of `pipeline` over `n` invocations.
    fn pass(
        &self,
        enc: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        entries: &[(u32, &wgpu::Buffer)],
        n: u64,
    ) -> Result<(), GpuError> {
        let groups = self.gpu.dispatch_linear(n, WG)?;
        let bg = self.gpu.bind_at(pipeline, entries);
        self.gpu.encode_pass(enc, pipeline, &bg, groups);
        Ok(())
    }

    /// A zeroed storage buffer of `len` f32, within the device's limits and u32 indexing.
    /// (At least one vec4: bindings of `array<vec4<f32>>` must hold one element.)
    fn buf(&self, label: &str, len: usize) -> Result<wgpu::Buffer, GpuError> {
        to_u32(label, len)?;
        self.gpu.storage::<f32>(label, len.max(4))
    }

    /// Points (normalised, in [-0.5, 0.5]³) → the planes the decoder samples (after the U-Net).
    /// The work is submitted; the returned buffer is ready for [`GpuNet::decode`] (queue order)
    /// or [`GpuNet::read_planes`].
    pub async fn encode(&self, points: &[[f32; 3]]) -> Result<GpuPlanes, GpuError> {
        let cfg = &self.config;
        let (r, c_dim) = (cfg.reso, cfg.c_dim);
        let (hb, cb) = (cfg.h.div_ceil(4), c_dim.div_ceil(4));
        let rr = r * r;
        let n = points.len();
        let cells = Cells::new(points, r, cfg.plane_divisor());
        let k = cells.len();

        let scope = self.gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let g = &self.gpu;
        // Checks first: every binding within the device's limits, every index within u32.
        for (label, len) in [
            ("cloud", 3 * n),
            ("point features", n * 4 * hb),
            ("point codes", n * 4 * cb),
            ("cell maxima", k * 4 * hb),
            ("planes", 3 * 4 * cb.max(c_dim) * rr),
            ("U-Net activations", 3 * 2 * cfg.unet_filters * rr),
        ] {
            g.check_binding::<f32>(label, len)?;
            to_u32(label, len)?;
        }
        let mut rec = Recording { enc: g.device.create_command_encoder(&Default::default()), scratch: Vec::new() };
        let pts_buf = rec.scratch(g.upload("cloud", bytemuck::cast_slice::<[f32; 3], f32>(points)));
        let cell_of = rec.scratch(g.upload("cell_of", &cells.cell_of));
        let cell_start = rec.scratch(g.upload("cell_start", &cells.cell_start));
        let cell_pts = rec.scratch(g.upload("cell_pts", &cells.points));
        let cell_dst = rec.scratch(g.upload("cell_dst", &cells.cell_plane_cell));
        let net = rec.scratch(self.buf("point features", n * 4 * hb)?);
        let cell_max = rec.scratch(self.buf("cell maxima", k * 4 * hb)?);
        let cfeat = rec.scratch(self.buf("point codes", n * 4 * cb)?);
        let scattered = rec.scratch(self.buf("scattered planes", 3 * c_dim * rr)?);

        let block = |b: usize| {
            let s = |l: &str| self.enc_slot(&format!("encoder.blocks.{b}.{l}"));
            EncParams {
                fc0_w: s("fc_0").w_off,
                fc0_b: s("fc_0").b_off,
                fc1_w: s("fc_1").w_off,
                fc1_b: s("fc_1").b_off,
                sc_w: s("shortcut").w_off,
                nin: if b == 0 { (2 * cfg.h).div_ceil(4) } else { 2 * hb } as u32,
                ..Default::default()
            }
        };
        let (pos, fc_c) = (self.enc_slot("encoder.fc_pos"), self.enc_slot("encoder.fc_c"));
        let first = rec.scratch(g.uniform("enc params", &EncParams { n: n as u32, lin_w: pos.w_off, lin_b: pos.b_off, ..block(0) }));
        let cellmax = rec.scratch(g.uniform("enc params", &EncParams { n: (k * hb) as u32, ..Default::default() }));
        let blocks: Vec<wgpu::Buffer> = (1..ENCODER_BLOCKS)
            .map(|b| {
                let p = EncParams {
                    n: n as u32,
                    lin_w: fc_c.w_off,
                    lin_b: fc_c.b_off,
                    last: (b == ENCODER_BLOCKS - 1) as u32,
                    ..block(b)
                };
                rec.scratch(g.uniform("enc params", &p))
            })
            .collect();
        let scatter = rec.scratch(g.uniform("enc params", &EncParams { n: (k * cb) as u32, rr: rr as u32, ..Default::default() }));

        let enc = &mut rec.enc;
        let p = &self.pipes;
        use pointnet_at as at;
        self.pass(
            enc,
            &p.enc_first,
            &[(at::PRM, &first), (at::W, &self.enc_w), (at::POINTS, &pts_buf), (at::NET, &net)],
            n as u64,
        )?;
        for u in &blocks {
            self.pass(
                enc,
                &p.enc_cellmax,
                &[
                    (at::PRM, &cellmax),
                    (at::NET, &net),
                    (at::CELL_START, &cell_start),
                    (at::CELL_PTS, &cell_pts),
                    (at::CELL_MAX, &cell_max),
                ],
                (k * hb) as u64,
            )?;
            self.pass(
                enc,
                &p.enc_block,
                &[
                    (at::PRM, u),
                    (at::W, &self.enc_w),
                    (at::NET, &net),
                    (at::CELL_OF, &cell_of),
                    (at::CELL_MAX, &cell_max),
                    (at::CFEAT, &cfeat),
                ],
                n as u64,
            )?;
        }
        self.pass(
            enc,
            &p.enc_scatter,
            &[
                (at::PRM, &scatter),
                (at::CELL_START, &cell_start),
                (at::CELL_PTS, &cell_pts),
                (at::CFEAT, &cfeat),
                (at::CELL_DST, &cell_dst),
                (at::PLANES, &scattered),
            ],
            (k * cb) as u64,
        )?;

        let out = self.unet(&mut rec, scattered)?;
        g.queue.submit([rec.enc.finish()]);
        // Every buffer but the planes is spent once the work is submitted.
        g.retire(rec.scratch);
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("encoding: {e}")));
        }
        Ok(GpuPlanes { buffer: out, c_dim, reso: r })
    }

    /// Records one U-Net layer: a uniform with `prm`, then the dispatch.
    fn layer(
        &self,
        rec: &mut Recording,
        pipeline: &wgpu::ComputePipeline,
        prm: ConvParams,
        entries: &[(u32, &wgpu::Buffer)],
    ) -> Result<(), GpuError> {
        let u = rec.scratch(self.gpu.uniform("U-Net params", &prm));
        let mut all = vec![(conv2d_at::PRM, &u)];
        all.extend_from_slice(entries);
        self.pass(&mut rec.enc, pipeline, &all, prm.total as u64)
    }

    /// 3x3 conv + ReLU of `a` (`c_a` channels), or of the concatenation `[a | b]`, at reso `r`.
    fn conv3x3(
        &self,
        rec: &mut Recording,
        name: &str,
        a: &wgpu::Buffer,
        b: Option<&wgpu::Buffer>,
        c_a: usize,
        r: usize,
    ) -> Result<wgpu::Buffer, GpuError> {
        let s = self.unet_slot(name);
        let c_out = s.n_out;
        // Concatenation only on the up path, where the skip has as many channels as the output.
        let c_b = if b.is_some() { c_out } else { 0 };
        let groups = c_out.div_ceil(CONV_BLOCK);
        let out = rec.scratch(self.buf(name, 3 * c_out * r * r)?);
        let total = 3 * groups * r * r.div_ceil(4);
        let prm = ConvParams {
            total: to_u32(name, total)?,
            r: r as u32,
            c_a: c_a as u32,
            c_b: c_b as u32,
            c_out: c_out as u32,
            groups: groups as u32,
            w_off: s.w_off,
            b_off: s.b_off,
            relu: 1,
            _pad: [0; 3],
        };
        use conv2d_at as at;
        let entries = [(at::IN_A, a), (at::IN_B, b.unwrap_or(a)), (at::WV, &self.unet_w), (at::OUT, &out)];
        self.layer(rec, &self.pipes.conv3x3, prm, &entries)?;
        Ok(out)
    }

    /// Records the U-Net over the three planes in `x` (`[3][c_dim][R][R]`); returns its output in
    /// the channel-last layout of [`GpuPlanes`].
    fn unet(&self, rec: &mut Recording, x: wgpu::Buffer) -> Result<wgpu::Buffer, GpuError> {
        let cfg = &self.config;
        let d = cfg.unet_depth;
        let mut x = x;
        let mut c = cfg.c_dim;
        let mut r = cfg.reso;
        let mut skips: Vec<wgpu::Buffer> = Vec::new();
        for k in 0..d {
            if k > 0 {
                r /= 2;
                let out = rec.scratch(self.buf("maxpool", 3 * c * r * r)?);
                let total = to_u32("maxpool", 3 * c * r * r)?;
                let prm = ConvParams { total, r: r as u32, ..Default::default() };
                self.layer(rec, &self.pipes.maxpool2, prm, &[(conv2d_at::IN_A, &x), (conv2d_at::OUT, &out)])?;
                x = out;
            }
            let y = self.conv3x3(rec, &format!("unet.down.{k}.conv0"), &x, None, c, r)?;
            c = cfg.filters(k);
            x = self.conv3x3(rec, &format!("unet.down.{k}.conv1"), &y, None, c, r)?;
            if k + 1 < d {
                skips.push(x.clone());
            }
        }
        for k in (0..d - 1).rev() {
            let f = cfg.filters(k);
            let name = format!("unet.up.{k}");
            let s = self.unet_slot(&format!("{name}.upconv"));
            r *= 2;
            let up = rec.scratch(self.buf("upconv", 3 * f * r * r)?);
            let groups = f.div_ceil(CONV_BLOCK);
            let prm = ConvParams {
                total: to_u32("upconv", 3 * groups * (r / 2) * (r / 2))?,
                r: r as u32,
                c_a: c as u32,
                c_out: f as u32,
                groups: groups as u32,
                w_off: s.w_off,
                b_off: s.b_off,
                ..Default::default()
            };
            let entries = [(conv2d_at::IN_A, &x), (conv2d_at::WV, &self.unet_w), (conv2d_at::OUT, &up)];
            self.layer(rec, &self.pipes.upconv2, prm, &entries)?;
            let y = self.conv3x3(rec, &format!("{name}.conv0"), &up, Some(&skips[k]), f, r)?;
            x = self.conv3x3(rec, &format!("{name}.conv1"), &y, None, f, r)?;
            c = f;
        }
        let s = self.unet_slot("unet.final");
        let cb = cfg.c_dim.div_ceil(4);
        let out = self.buf("planes", 3 * r * r * 4 * cb)?;
        let groups = cfg.c_dim.div_ceil(CONV_BLOCK);
        let prm = ConvParams {
            total: to_u32("final", 3 * groups * r * r)?,
            r: r as u32,
            c_a: c as u32,
            c_out: cfg.c_dim as u32,
            groups: groups as u32,
            w_off: s.w_off,
            b_off: s.b_off,
            ..Default::default()
        };
        let entries = [(conv2d_at::IN_A, &x), (conv2d_at::WV, &self.unet_w), (conv2d_at::OUT4, &out)];
        self.layer(rec, &self.pipes.final1x1, prm, &entries)?;
        Ok(out)
    }

    /// Uploads CPU planes (e.g. from [`super::cpu::encode`] or a fixture).
    pub fn upload_planes(&self, planes: &Planes) -> Result<GpuPlanes, GpuError> {
        let (c_dim, r) = (planes.c_dim, planes.reso);
        if (c_dim, r) != (self.config.c_dim, self.config.reso) || planes.data.len() != 3 * c_dim * r * r {
            return Err(GpuError::Kernel(format!(
                "planes are {c_dim} x {r}², the network needs {} x {}²",
                self.config.c_dim, self.config.reso
            )));
        }
        let gp = GpuPlanes { buffer: self.gpu.upload("planes", &[0u32]), c_dim, reso: r };
        let stride = gp.stride();
        let mut data = vec![0.0f32; gp.len()];
        for p in 0..3 {
            for ch in 0..c_dim {
                for pix in 0..r * r {
                    data[(p * r * r + pix) * stride + ch] = planes.data[(p * c_dim + ch) * r * r + pix];
                }
            }
        }
        self.gpu.check_binding::<f32>("planes", data.len())?;
        Ok(GpuPlanes { buffer: self.gpu.upload("planes", &data), ..gp })
    }

    /// Downloads planes, in the contract's `[3][c_dim][reso][reso]` layout.
    pub async fn read_planes(&self, planes: &GpuPlanes) -> Result<Planes, GpuError> {
        let raw = self.gpu.read::<f32>(&planes.buffer, planes.len()).await?;
        let (c_dim, r, stride) = (planes.c_dim, planes.reso, planes.stride());
        let mut out = Planes::zeros(c_dim, r);
        for p in 0..3 {
            for ch in 0..c_dim {
                for pix in 0..r * r {
                    out.data[(p * c_dim + ch) * r * r + pix] = raw[(p * r * r + pix) * stride + ch];
                }
            }
        }
        Ok(out)
    }
    /// Queries (normalised coordinates) → (features `Q × c_dim`, row-major; logits `Q`), in
    /// chunks of [`GpuNet::chunk_queries`]. For repeated calls on the same planes (meshing),
    /// keep a [`GpuNet::decoder`] instead: this makes one for the call.
    pub async fn decode(&self, planes: &GpuPlanes, queries: &[[f32; 3]]) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
        if queries.is_empty() {
            self.check_planes(planes)?;
            return Ok((Vec::new(), Vec::new()));
        }
        self.decoder(planes, queries.len())?.decode(queries).await
    }

    fn check_planes(&self, planes: &GpuPlanes) -> Result<(), GpuError> {
        let cfg = &self.config;
        if (planes.c_dim, planes.reso) != (cfg.c_dim, cfg.reso) {
            return Err(GpuError::Kernel(format!(
                "planes are {}x{}², the network needs {}x{}²",
                planes.c_dim, planes.reso, cfg.c_dim, cfg.reso
            )));
        }
        Ok(())
    }

    /// The buffers, bind group and staging buffer for decoding `planes` in submissions of at
    /// most `queries` queries (and at most [`GpuNet::chunk_queries`]), made once and reused by
    /// every [`Decoder::decode`]: [`decode_footprint`] is what it holds.
    pub fn decoder<'a>(&'a self, planes: &GpuPlanes, queries: usize) -> Result<Decoder<'a>, GpuError> {
        self.check_planes(planes)?;
        let c = self.config.c_dim;
        let chunk = self.chunk.min(queries).max(1);
        let g = &self.gpu;
        let q_buf = self.buf("queries", 3 * chunk)?;
        let f_buf = self.buf("features", c * chunk)?;
        let l_buf = self.buf("logits", chunk)?;
        let params = g.uniform("decode params", &DecParams::default());
        use decoder_at as at;
        let bind = g.bind_at(
            &self.pipes.decode,
            &[
                (at::PRM, &params),
                (at::W, &self.dec_w),
                (at::PLANES, &planes.buffer),
                (at::QUERIES, &q_buf),
                (at::FEATURES, &f_buf),
                (at::LOGITS, &l_buf),
            ],
        );
        let staging = g.readback((4 * c * chunk) as u64);
        Ok(Decoder { net: self, chunk, q_buf, f_buf, l_buf, params, bind, staging })
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
}

/// A decode of one set of planes, its buffers made once ([`GpuNet::decoder`]).
pub struct Decoder<'a> {
    net: &'a GpuNet,
    chunk: usize,
    q_buf: wgpu::Buffer,
    f_buf: wgpu::Buffer,
    l_buf: wgpu::Buffer,
    params: wgpu::Buffer,
    bind: wgpu::BindGroup,
    staging: crate::gpu::Readback,
}

/// Destroyed with its holder, not left to the browser's garbage collector ([`Gpu::retire`]): a
/// scene's regression decodes its training pairs once per tile.
impl Drop for Decoder<'_> {
    fn drop(&mut self) {
        let own = [&self.q_buf, &self.f_buf, &self.l_buf, &self.params, self.staging.buffer()];
        self.net.gpu.retire(own.into_iter().cloned());
    }
}

impl Decoder<'_> {
    /// Queries per submission.
    pub fn chunk_queries(&self) -> usize {
        self.chunk
    }

    /// Decodes from `planes` from now on (a scene's next tile): one new bind group, the
    /// buffers kept.
    pub fn rebind(&mut self, planes: &GpuPlanes) -> Result<(), GpuError> {
        self.net.check_planes(planes)?;
        use decoder_at as at;
        self.bind = self.net.gpu.bind_at(
            &self.net.pipes.decode,
            &[
                (at::PRM, &self.params),
                (at::W, &self.net.dec_w),
                (at::PLANES, &planes.buffer),
                (at::QUERIES, &self.q_buf),
                (at::FEATURES, &self.f_buf),
                (at::LOGITS, &self.l_buf),
            ],
        );
        Ok(())
    }

    /// Queries (normalised coordinates) → (features `Q × c_dim`, row-major; logits `Q`).
    pub async fn decode(&self, queries: &[[f32; 3]]) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
        let (net, g) = (self.net, &self.net.gpu);
        let cfg = &net.config;
        let c = cfg.c_dim;
        let mut features = Vec::with_capacity(queries.len() * c);
        let mut logits = Vec::with_capacity(queries.len());
        let scope = g.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let mut result = Ok(());
        for part in queries.chunks(self.chunk) {
            let m = part.len();
            let p = DecParams {
                n: m as u32,
                reso: cfg.reso as u32,
                divisor: cfg.plane_divisor(),
                uv_max: UV_MAX,
                n_blocks: cfg.n_blocks_dec as u32,
                hb: cfg.h_dec.div_ceil(4) as u32,
                cb: cfg.c_dim.div_ceil(4) as u32,
                _pad: 0,
            };
            g.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&p));
            g.queue.write_buffer(&self.q_buf, 0, bytemuck::cast_slice(part));
            let mut enc = g.device.create_command_encoder(&Default::default());
            // Two queries per invocation.
            let groups = match g.dispatch_linear(m.div_ceil(2) as u64, WG) {
                Ok(gr) => gr,
                Err(e) => {
                    result = Err(e);
                    break;
                }
            };
            g.encode_pass(&mut enc, &net.pipes.decode, &self.bind, groups);
            g.queue.submit([enc.finish()]);
            match g.read_via::<f32>(&self.staging, &self.f_buf, m * c).await {
                Ok(v) => features.extend_from_slice(&v),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
            match g.read_via::<f32>(&self.staging, &self.l_buf, m).await {
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
}
