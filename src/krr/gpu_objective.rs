//! The Nyström KRR tuning objective and its gradient on the GPU (`docs/method.md` §5–§6); the
//! predictor it hands on is [`super::gpu_predictor`], the sizes and types both share [`super::gpu`].
//!
//! **Hybrid, exact (§5).** The GPU does every O(n·m·d) and O(n·m²) part in f32 (and u32); the CPU
//! does the m × m algebra in f64 with [`linalg`] — the same formulas, in the same order, as the
//! f64 [`reference`](super::reference). Per evaluation:
//!
//! 1. GPU (`shaders/krr_kernel_block.wgsl`): `K_nm` in row blocks that fit a storage binding, as
//!    24-bit fixed point `q = round(K·2²⁴)` (u32; `K~ = q·2⁻²⁴`, within 2⁻²⁵ of the f32 kernel
//!    value). Every later pass uses this `K~`. Kept on the device for the whole evaluation.
//! 2. GPU (`shaders/krr_gram.wgsl`): `A = K~ᵀK~` and `b = K~ᵀy~` **exactly**, in integer
//!    arithmetic (12-bit limbs, u32 partial sums, 96-bit totals; `y~` is y in two 24-bit
//!    fixed-point levels, within 2⁻⁴⁹·max|y| of it), `A` from upper-triangle tiles only.
//!    Readback: `3m² + 9m` u32, converted to f64 on the CPU.
//! 3. CPU f64: `K_mm` (from the same f32-rounded `Z` and `1/s` the GPU used), `H = A + nλK_j`, its
//!    Cholesky factor, `β = H⁻¹b`, and from the exact `A`, `b`: `(1/n)‖K~β − y~‖² =
//!    (y~ᵀy~ − 2bᵀβ + βᵀAβ)/n` (no residual pass; f64 rounding only), `D`, `T1`, `T2`, the loss.
//!    That is all [`Objective::eval`](super::Objective::eval) needs.
//! 4. CPU f64, for the gradient: `W = 4λH⁻¹K_jH⁻¹ − 2cD K_j⁻¹`, `s_r = (cT2 + 2)(2/n)`, `G_mm` and
//!    the whole `Q = G_mm ∘ K_mm` side of the gradient.
//!
//!    Steps 3–4 are the reference's own functions (`reference::mm_forward`, `mm_grad`,
//!    `kmm_side`): blocked, threaded f64 kernels, about `3.5 m³` multiply-adds per evaluation
//!    with gradient (see `mm_grad` for the algebra).
//! 5. GPU (`shaders/krr_grad.wgsl`): `r = K~β − y` (`residual`, Kahan over m), then
//!    `P = (K~W + s_r r βᵀ) ∘ K~` tile by tile (`grad_p`; `G_nm` is never stored, `P` one row block
//!    at a time), then per chunk of rows `Σ_i P_ij (x_id − z_jd)` and `Σ_i P_ij (x_id − z_jd)²`
//!    for every `(j, d)` (`grad_reduce`; differences, not `PᵀX − diag(Pᵀ1)Z`), summed over chunks
//!    (`grad_sum`). Readback: `2·m·d` f32.
//! 6. CPU: `∂L/∂z = (GPU part + Q part)/s²`, `∂L/∂log s = (Σ_j GPU part + Q part)/s²`.
//!
//! **Precision** (measured in `tests/krr_gpu.rs`, lavapipe):
//! - *Why `A` and `b` are exact.* `H`'s smallest eigenvalues can be as small as `nλ·jitter`
//!   (1.6e-6 on `tests/krr.rs`'s relevance problem) while `‖A‖ ≈ n·m`: once the length-scales
//!   grow, `K_nm` is numerically low-rank. Any unstructured error in `A` — f32 rounding of
//!   products and sums, even Kahan-compensated, 2e-7 relative per entry — then exceeds them: `T1`
//!   was off by 5 % and the tuner died at step 12 with "H not positive definite". `K~ᵀK~` is the
//!   exact Gram matrix of a perturbed `K`, positive semi-definite like the true one, and the tuner
//!   runs through. Likewise an f32 `b` moved β by 19 % (`H⁻¹` amplifies it); exact, 0.16 %, the
//!   floor set by the f32 kernel values themselves. The forward pass is also bitwise independent
//!   of the row blocking.
//! - *Compensated sums are protected from the compiler.* Mesa's NIR simplified Kahan's
//!   `((s + y) − s) − y` to 0: with plain Kahan an f32 Gram matrix over n = 6000 rows was off by
//!   1.1e-6 (what uncompensated sums give) and the gradient by 1e-3. Every compensated sum now
//!   multiplies the new sum by `one` = 1.0 read from a uniform, exact but opaque to the optimiser:
//!   1.7e-7 and 4e-5. WGSL has no "precise".
//! - *What is left*: in ordinary regimes 1e-9–1e-6 relative on the loss and its terms and
//!   1e-6–3e-4 on the gradient. Where `T2 ≪ n` (long length-scales, Nyström almost exact) the
//!   objective is ill-conditioned in `K` (`K_j⁻¹` has entries ~1/jitter): the loss terms stay
//!   within 1e-4 (near the floor the f32 kernel values set) but the gradient's `K~W` product (f32,
//!   `W` with entries up to ~1/jitter, cancelling) loses 6e-3 to 1 relative — see
//!   `precision_survey` (ignored test).
//!
//! **Timing.** Natively each GPU phase is submitted and waited for on its own, so
//! [`PhaseTimings`] splits GPU time by phase; on the web the browser runs the work
//! asynchronously and GPU time shows up in `readback`.

use super::gpu::{check_d, check_settings, fixed_point_y, params_f32, KrrGpuError, PhaseTimings, reduction_chunks, GRAM_ROWS, MAX_BLOCK_ROWS, RED_J, TILE, WG};
use super::gpu_predictor::GpuPredictor;
use super::kernel;
use super::linalg::{self, dot};
use super::error::KrrError;
use super::mm::{assemble, kmm_side, mm_forward, mm_grad, MmForward, MmGrad, MmParts};
use super::problem::{Eval, Grad, Params, Problem, Ridge};
use crate::gpu::{now as now_s, specialise, to_u32, Gpu, GpuError};

/// The kernel block, after the distance tile it shares with the predictor.
const KERNEL_WGSL: &str = concat!(include_str!("../../shaders/krr_distance_tile.wgsl"), include_str!("../../shaders/krr_kernel_block.wgsl"));
const GRAM_WGSL: &str = include_str!("../../shaders/krr_gram.wgsl");
const GRAD_WGSL: &str = include_str!("../../shaders/krr_grad.wgsl");

/// Binding indices of `shaders/krr_kernel_block.wgsl` (its `@group(0) @binding(N)`
/// declarations; keep the two in step).
mod kernel_at {
    pub const X: u32 = 0;
    pub const Z: u32 = 1;
    pub const INV_S: u32 = 2;
    pub const K: u32 = 3;
    pub const DIMS: u32 = 4;
}

/// Binding indices of `shaders/krr_gram.wgsl`.
mod gram_at {
    pub const K: u32 = 0;
    pub const ACC: u32 = 1;
    pub const DIMS: u32 = 2;
    pub const YQ: u32 = 3;
    pub const BACC: u32 = 4;
}

/// Binding indices of `shaders/krr_grad.wgsl`.
mod grad_at {
    pub const K: u32 = 0;
    pub const W: u32 = 1;
    pub const BETA: u32 = 2;
    pub const R: u32 = 3;
    pub const P: u32 = 4;
    pub const X: u32 = 5;
    pub const Z: u32 = 6;
    pub const PART: u32 = 7;
    pub const DIMS: u32 = 8;
    pub const PART_IN: u32 = 9;
    pub const SUMS: u32 = 10;
    pub const SUM_DIMS: u32 = 11;
    pub const Y: u32 = 12;
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct KernelDims {
    rows: u32,
    row0: u32,
    m: u32,
    _pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GramDims {
    r_begin: u32,
    r_end: u32,
    row0: u32,
    m: u32,
    first: u32,
    _pad: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct GradDims {
    rows: u32,
    row0: u32,
    m: u32,
    _s: u32,
    chunk_rows: u32,
    chunk0: u32,
    s_r: f32,
    one: f32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SumDims {
    len: u32,
    chunks: u32,
    one: f32,
    _b: u32,
}


struct Pipes {
    kernel_block: wgpu::ComputePipeline,
    gram: wgpu::ComputePipeline,
    gram_b: wgpu::ComputePipeline,
    residual: wgpu::ComputePipeline,
    grad_p: wgpu::ComputePipeline,
    grad_reduce: wgpu::ComputePipeline,
    grad_sum: wgpu::ComputePipeline,
}

/// One row block of the problem.
#[derive(Clone, Copy, Debug)]
struct Block {
    row0: usize,
    rows: usize,
    /// Global index of its first `grad_reduce` chunk, and its number of chunks.
    chunk0: usize,
    chunks: usize,
}

/// The problem's own buffers, which every workspace binds.
struct Data<'a> {
    x: &'a wgpu::Buffer,
    y: &'a wgpu::Buffer,
    yq: &'a wgpu::Buffer,
}

/// One row block's passes of the gradient: its uniform (rewritten each evaluation, for `s_r`)
/// and the bind groups of its three kernels.
struct GradBinds {
    dims: wgpu::Buffer,
    residual: wgpu::BindGroup,
    grad_p: wgpu::BindGroup,
    reduce: wgpu::BindGroup,
}

/// Device buffers, uniforms and bind groups for one inducing-point count `m`, made once and
/// reused by every evaluation (rebuilt only when `m` or the block size changes).
struct Workspace {
    gpu: Gpu,
    m: usize,
    max_rows: usize,
    blocks: Vec<Block>,
    chunk_rows: usize,
    z: wgpu::Buffer,
    inv_s: wgpu::Buffer,
    /// `Σ q q'` as three u32 words per entry (`3 × m × m`), and the sums behind `b` (`9 × m`, see
    /// `krr_gram.wgsl`).
    acc: wgpu::Buffer,
    bacc: wgpu::Buffer,
    beta: wgpu::Buffer,
    w: wgpu::Buffer,
    sums: wgpu::Buffer,
    /// Per block: the kernel block's bind group; the gram's (`gram`, `gram_b`) per slice of
    /// [`GRAM_ROWS`] rows; the gradient's.
    kernel: Vec<wgpu::BindGroup>,
    gram: Vec<Vec<(wgpu::BindGroup, wgpu::BindGroup)>>,
    grad: Vec<GradBinds>,
    sum: wgpu::BindGroup,
    /// Every readback of an evaluation (`A`, `b`, the gradient sums) goes through it.
    staging: crate::gpu::Readback,
    /// Buffers only the bind groups refer to: `K~` row blocks (u32 fixed point,
    /// `q = round(K · 2²⁴)`), r, P, the partial sums and the fixed uniforms.
    held: Vec<wgpu::Buffer>,
}

impl Workspace {
    fn new(gpu: &Gpu, pipes: &Pipes, data: Data, n: usize, d: usize, m: usize, block_rows: usize) -> Result<Workspace, GpuError> {
        let dim = gpu.limits.max_compute_workgroups_per_dimension as usize;
        let col_groups = m.div_ceil(TILE);
        if col_groups > dim {
            return Err(GpuError::TooLarge(format!("m = {m} needs {col_groups} workgroups in one dimension")));
        }
        let max_rows = gpu
            .rows_per_binding((m * 4) as u64)
            .min(dim * TILE)
            .min(MAX_BLOCK_ROWS)
            .min(block_rows)
            .max(1);
        let (chunk_rows, _) = reduction_chunks(n, max_rows);
        let mut blocks = Vec::new();
        let mut chunk0 = 0;
        for row0 in (0..n).step_by(max_rows) {
            let rows = max_rows.min(n - row0);
            let chunks = rows.div_ceil(chunk_rows);
            if chunks > dim {
                return Err(GpuError::TooLarge(format!("{chunks} reduction chunks in one dispatch dimension")));
            }
            blocks.push(Block { row0, rows, chunk0, chunks });
            chunk0 += chunks;
        }
        let total_chunks = chunk0;
        debug_assert_eq!(total_chunks, reduction_chunks(n, max_rows).1, "the footprint counts the chunks made here");
        let largest_rows = blocks.iter().map(|b| b.rows).max().unwrap_or(1);
        for (label, len) in [
            ("Z", m * d),
            ("A = K^T K accumulator", 3 * m * m),
            ("W", m * m),
            ("P block", largest_rows * m),
            ("gradient partial sums", total_chunks * 2 * m * d),
        ] {
            gpu.check_binding::<f32>(label, len)?;
            to_u32(label, len)?;
        }
        let k = blocks
            .iter()
            .map(|b| gpu.storage::<u32>("K block", b.rows * m))
            .collect::<Result<Vec<_>, _>>()?;
        let z = gpu.storage::<f32>("Z", m * d)?;
        let inv_s = gpu.storage::<f32>("1/s", d)?;
        let acc = gpu.storage::<u32>("A = K^T K accumulator", 3 * m * m)?;
        let bacc = gpu.storage::<u32>("b = K^T y accumulator", 9 * m)?;
        let beta = gpu.storage::<f32>("beta", m)?;
        let w = gpu.storage::<f32>("W", m * m)?;
        let r = gpu.storage::<f32>("r", n)?;
        let p = gpu.storage::<f32>("P block", largest_rows * m)?;
        let part = gpu.storage::<f32>("gradient partial sums", total_chunks * 2 * m * d)?;
        let sums = gpu.storage::<f32>("gradient sums", 2 * m * d)?;
        let mut held = Vec::new();
        let mut kernel = Vec::new();
        let mut gram = Vec::new();
        let mut grad = Vec::new();
        for (b, blk) in blocks.iter().enumerate() {
            let dims = gpu.uniform("krr kernel dims", &KernelDims { rows: blk.rows as u32, row0: blk.row0 as u32, m: m as u32, _pad: 0 });
            kernel.push(gpu.bind_at(
                &pipes.kernel_block,
                &[(kernel_at::X, data.x), (kernel_at::Z, &z), (kernel_at::INV_S, &inv_s), (kernel_at::K, &k[b]), (kernel_at::DIMS, &dims)],
            ));
            held.push(dims);
            let mut slices = Vec::new();
            for r_begin in (0..blk.rows).step_by(GRAM_ROWS) {
                let dims = gpu.uniform(
                    "krr gram dims",
                    &GramDims {
                        r_begin: r_begin as u32,
                        r_end: (r_begin + GRAM_ROWS).min(blk.rows) as u32,
                        row0: blk.row0 as u32,
                        m: m as u32,
                        first: (b == 0 && r_begin == 0) as u32,
                        _pad: [0; 3],
                    },
                );
                let a = gpu.bind_at(&pipes.gram, &[(gram_at::K, &k[b]), (gram_at::ACC, &acc), (gram_at::DIMS, &dims)]);
                let bb = gpu.bind_at(&pipes.gram_b, &[(gram_at::K, &k[b]), (gram_at::DIMS, &dims), (gram_at::YQ, data.yq), (gram_at::BACC, &bacc)]);
                slices.push((a, bb));
                held.push(dims);
            }
            gram.push(slices);
            let dims = gpu.uniform("krr grad dims", &grad_dims(blk, m, chunk_rows, 0.0));
            let residual = gpu.bind_at(
                &pipes.residual,
                &[(grad_at::K, &k[b]), (grad_at::BETA, &beta), (grad_at::R, &r), (grad_at::DIMS, &dims), (grad_at::Y, data.y)],
            );
            let grad_p = gpu.bind_at(
                &pipes.grad_p,
                &[(grad_at::K, &k[b]), (grad_at::W, &w), (grad_at::BETA, &beta), (grad_at::R, &r), (grad_at::P, &p), (grad_at::DIMS, &dims)],
            );
            let reduce = gpu.bind_at(
                &pipes.grad_reduce,
                &[(grad_at::P, &p), (grad_at::X, data.x), (grad_at::Z, &z), (grad_at::PART, &part), (grad_at::DIMS, &dims)],
            );
            grad.push(GradBinds { dims, residual, grad_p, reduce });
        }
        let len = 2 * m * d;
        let sdims = gpu.uniform("krr sum dims", &SumDims { len: len as u32, chunks: total_chunks as u32, one: 1.0, _b: 0 });
        let sum = gpu.bind_at(&pipes.grad_sum, &[(grad_at::PART_IN, &part), (grad_at::SUMS, &sums), (grad_at::SUM_DIMS, &sdims)]);
        let staging = gpu.readback(4 * (3 * m * m).max(9 * m).max(len) as u64);
        held.extend(k);
        held.extend([r, p, part, sdims]);
        Ok(Workspace {
            gpu: gpu.clone(),
            m,
            max_rows: block_rows,
            blocks,
            chunk_rows,
            z,
            inv_s,
            acc,
            bacc,
            beta,
            w,
            sums,
            kernel,
            gram,
            grad,
            sum,
            staging,
            held,
        })
    }
}

/// Destroyed with its holder, not left to the browser's garbage collector ([`Gpu::retire`]): a
/// scene tunes a regression per tile, each with its own workspace.
impl Drop for Workspace {
    fn drop(&mut self) {
        let own = [&self.z, &self.inv_s, &self.acc, &self.bacc, &self.beta, &self.w, &self.sums, self.staging.buffer()];
        let grad = self.grad.iter().map(|g| &g.dims);
        self.gpu.retire(own.into_iter().chain(grad).chain(&self.held).cloned());
    }
}

/// The gradient's uniform for row block `blk` (`s_r` changes with every evaluation).
fn grad_dims(blk: &Block, m: usize, chunk_rows: usize, s_r: f32) -> GradDims {
    GradDims {
        rows: blk.rows as u32,
        row0: blk.row0 as u32,
        m: m as u32,
        _s: m as u32,
        chunk_rows: chunk_rows as u32,
        chunk0: blk.chunk0 as u32,
        s_r,
        one: 1.0,
    }
}

/// What the forward pass leaves for the backward pass (all f64, m × m unless noted).
struct Forward {
    m: usize,
    /// `Z` and `1/s` as the GPU used them (f32 values, widened).
    z: Vec<f64>,
    inv_s: Vec<f64>,
    kmm: Vec<f64>,
    /// Cholesky factor of `K_j`.
    lk: Vec<f64>,
    a: Vec<f64>,
    h_inv: Vec<f64>,
    kj_inv: Vec<f64>,
    alpha: f64,
    c: f64,
    eval: Eval,
}

/// The tuning objective of `docs/method.md` §5–§6 on the GPU; see the module docs.
///
/// Construct once per problem (uploads `X` and `y`), then call [`GpuObjective::eval_grad_async`]
/// (browser) or the [`Objective`](super::Objective) trait (native, blocking) as often as the
/// tuner needs. Buffers are kept between evaluations with the same `m`.
pub struct GpuObjective {
    gpu: Gpu,
    n: usize,
    d: usize,
    x: wgpu::Buffer,
    y: wgpu::Buffer,
    /// y in two 24-bit fixed-point levels, `(qh + 2²⁴, ql + 2²⁴)` per row, scale `y_scale`.
    yq: wgpu::Buffer,
    y_scale: f64,
    /// `‖y~‖²` of the fixed-point y, in f64.
    yy: f64,
    settings: Ridge,
    pipes: Pipes,
    predictor: GpuPredictor,
    block_rows: usize,
    ws: Option<Workspace>,
    /// Timings of the last evaluation.
    pub timings: PhaseTimings,
    /// Timings summed over every evaluation since construction (or [`GpuObjective::reset_timings`]).
    pub total_timings: PhaseTimings,
    /// Evaluations counted in `total_timings`.
    pub evaluations: usize,
}

/// The training data's buffers destroyed with it (the workspace destroys its own): see
/// [`Workspace`]'s drop.
impl Drop for GpuObjective {
    fn drop(&mut self) {
        self.gpu.retire([self.x.clone(), self.y.clone(), self.yq.clone()]);
    }
}

impl GpuObjective {
    /// Uploads `problem` (as f32) and builds the kernels for its feature dimension (≤ [`MAX_D`](super::gpu::MAX_D)).
    pub async fn new(gpu: &Gpu, problem: &Problem, settings: Ridge) -> Result<GpuObjective, KrrGpuError> {
        check_settings(&settings)?;
        let (n, d) = (problem.n(), problem.d());
        check_d(d)?;
        gpu.check_binding::<f32>("training features X", n * d)?;
        to_u32("training features X", n * d)?;
        let x32: Vec<f32> = problem.x().iter().map(|&v| v as f32).collect();
        let y32: Vec<f32> = problem.y().iter().map(|&v| v as f32).collect();
        if x32.iter().chain(&y32).any(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite("training data out of f32 range".into()).into());
        }
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let x = gpu.upload("krr X", &x32);
        let y = gpu.upload("krr y", &y32);
        let (yq32, y_scale, yy) = fixed_point_y(&y32);
        let yq = gpu.upload("krr y fixed point", &yq32);
        let dq = d.div_ceil(8);
        let kernel_src = specialise(KERNEL_WGSL, &[("D", d)]);
        let grad_src = specialise(GRAD_WGSL, &[("D", d), ("DQ", dq), ("DP", dq * 8)]);
        let kernel_block = gpu.compute_pipelines("krr_kernel_block", &kernel_src, &["kernel_block"]).pop().expect("one");
        let mut gr = gpu.compute_pipelines("krr_gram", GRAM_WGSL, &["gram", "gram_b"]).into_iter();
        let (gram, gram_b) = (gr.next().expect("gram"), gr.next().expect("gram_b"));
        let mut g = gpu.compute_pipelines("krr_grad", &grad_src, &["residual", "grad_p", "grad_reduce", "grad_sum"]).into_iter();
        let mut next = || g.next().expect("one pipeline per entry point");
        let pipes = Pipes {
            kernel_block,
            gram,
            gram_b,
            residual: next(),
            grad_p: next(),
            grad_reduce: next(),
            grad_sum: next(),
        };
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("building the KRR kernels: {e}")).into());
        }
        let predictor = GpuPredictor::new(gpu, d).await?;
        // X's staging copy goes before the workspace is made.
        gpu.flush_uploads();
        Ok(GpuObjective {
            gpu: gpu.clone(),
            n,
            d,
            x,
            y,
            yq,
            y_scale,
            yy,
            settings,
            pipes,
            predictor,
            block_rows: usize::MAX,
            ws: None,
            timings: PhaseTimings::default(),
            total_timings: PhaseTimings::default(),
            evaluations: 0,
        })
    }

    /// [`GpuObjective::new`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_blocking(gpu: &Gpu, problem: &Problem, settings: Ridge) -> Result<GpuObjective, KrrGpuError> {
        pollster::block_on(Self::new(gpu, problem, settings))
    }

    pub fn settings(&self) -> &Ridge {
        &self.settings
    }

    /// Number of training points.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Feature dimension.
    pub fn d(&self) -> usize {
        self.d
    }

    /// Caps the rows per block below what the device's binding limit allows (at least 1) — for
    /// tests of the multi-block path, and for devices that want smaller buffers.
    pub fn set_max_block_rows(&mut self, rows: usize) {
        self.block_rows = rows.max(1);
        self.ws = None;
    }

    /// Row blocks the last evaluation used (0 before the first).
    pub fn blocks(&self) -> usize {
        self.ws.as_ref().map_or(0, |w| w.blocks.len())
    }

    pub fn reset_timings(&mut self) {
        self.total_timings = PhaseTimings::default();
        self.evaluations = 0;
    }

    /// The predictor for this problem's feature dimension.
    pub fn predictor(&self) -> &GpuPredictor {
        &self.predictor
    }

    /// Loss, diagnostics and gradient at `params` (see the module docs for the split).
    pub async fn eval_grad_async(&mut self, params: &Params) -> Result<(Eval, Grad), KrrGpuError> {
        let (e, g) = self.run(params, true).await?;
        Ok((e, g.expect("gradient requested")))
    }

    /// Loss and diagnostics at `params`, without the gradient pass.
    pub async fn eval_async(&mut self, params: &Params) -> Result<Eval, KrrGpuError> {
        Ok(self.run(params, false).await?.0)
    }

    /// What [`tune_async`](super::tune_async)'s `evaluate` resolves to: the evaluation, and the
    /// gradient when `needs_grad`, with GPU failures as [`KrrError`] (see `From<KrrGpuError>`).
    /// In the browser, share the objective through `Rc<RefCell<_>>` and call this in the closure.
    pub async fn evaluate(&mut self, params: &Params, needs_grad: bool) -> Result<(Eval, Option<Grad>), KrrError> {
        self.run(params, needs_grad).await.map_err(Into::into)
    }

    /// `g(q)` at each row of `queries` (`q × d`) on the GPU (see [`GpuPredictor::predict`]).
    pub async fn predict(&self, beta: &[f64], z: &[f64], log_s: &[f64], queries: &[f32]) -> Result<Vec<f32>, KrrGpuError> {
        self.predictor.predict(beta, z, log_s, queries).await
    }

    /// [`GpuObjective::predict`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn predict_blocking(&self, beta: &[f64], z: &[f64], log_s: &[f64], queries: &[f32]) -> Result<Vec<f32>, KrrGpuError> {
        pollster::block_on(self.predict(beta, z, log_s, queries))
    }

    /// `A = K~ᵀK~` (`m × m`) and `b = K~ᵀy` as the GPU forms them — for precision tests.
    #[doc(hidden)]
    pub async fn gram_async(&mut self, params: &Params) -> Result<(Vec<f64>, Vec<f64>), KrrGpuError> {
        check_settings(&self.settings)?;
        let m = params.check(self.d)?;
        let (inv_s, z) = params_f32(params)?;
        let mut tm = PhaseTimings::default();
        self.gram_phase(m, &z, &inv_s, &mut tm).await
    }

    fn ensure_workspace(&mut self, m: usize) -> Result<(), GpuError> {
        let stale = self.ws.as_ref().is_none_or(|w| w.m != m || w.max_rows != self.block_rows);
        if stale {
            self.ws = None; // free the old buffers first
            let data = Data { x: &self.x, y: &self.y, yq: &self.yq };
            self.ws = Some(Workspace::new(&self.gpu, &self.pipes, data, self.n, self.d, m, self.block_rows)?);
        }
        Ok(())
    }

    /// Phase 1: upload `Z`, `1/s`; `K~` blocks; `A = K~ᵀK~` (exact) and `b = K~ᵀy`; read back and
    /// convert to f64 (`A` full, mirrored).
    async fn gram_phase(
        &mut self,
        m: usize,
        z32: &[f32],
        inv_s32: &[f32],
        tm: &mut PhaseTimings,
    ) -> Result<(Vec<f64>, Vec<f64>), KrrGpuError> {
        self.ensure_workspace(m)?;
        let g = &self.gpu;
        let ws = self.ws.as_ref().expect("workspace built");
        g.queue.write_buffer(&ws.z, 0, bytemuck::cast_slice(z32));
        g.queue.write_buffer(&ws.inv_s, 0, bytemuck::cast_slice(inv_s32));

        let t = now_s();
        let mut enc = g.device.create_command_encoder(&Default::default());
        for (blk, bind) in ws.blocks.iter().zip(&ws.kernel) {
            let groups = [m.div_ceil(TILE) as u32, blk.rows.div_ceil(TILE) as u32, 1];
            g.encode_pass(&mut enc, &self.pipes.kernel_block, bind, groups);
        }
        g.queue.submit([enc.finish()]);
        g.poll_wait();
        tm.kernel += now_s() - t;

        let t = now_s();
        let mut enc = g.device.create_command_encoder(&Default::default());
        let tiles = m.div_ceil(TILE) as u32;
        for (a, b) in ws.gram.iter().flatten() {
            g.encode_pass(&mut enc, &self.pipes.gram, a, [tiles, tiles, 1]);
            g.encode_pass(&mut enc, &self.pipes.gram_b, b, [tiles, 1, 1]);
        }
        g.queue.submit([enc.finish()]);
        g.poll_wait();
        tm.gram += now_s() - t;

        let t = now_s();
        let words = g.read_via::<u32>(&ws.staging, &ws.acc, 3 * m * m).await?;
        let bw = g.read_via::<u32>(&ws.staging, &ws.bacc, 9 * m).await?;
        tm.readback += now_s() - t;

        // Σ_i q_ij q_ik = w0 + 2³² w1 + 2⁶⁴ w2, and A = that · 2⁻⁴⁸.
        let t = now_s();
        let mm = m * m;
        let mut a = vec![0.0; mm];
        // The upper triangle, threaded over rows, then mirrored.
        const ROWS: usize = 16;
        let work = |u: usize| (ROWS * (m - (u * ROWS).min(m)) * 4) as f64;
        linalg::par_row_units(&mut a, m, m, ROWS, linalg::max_threads(), &work, |u0, u1, rows| {
            for (j, row) in (u0 * ROWS..(u1 * ROWS).min(m)).zip(rows.chunks_mut(m)) {
                for (k, v) in row.iter_mut().enumerate().skip(j) {
                    let i = j * m + k;
                    let exact = words[i] as u128 | (words[mm + i] as u128) << 32 | (words[2 * mm + i] as u128) << 64;
                    *v = exact as f64 * 2f64.powi(-48);
                }
            }
        });
        linalg::mirror_upper(&mut a, m);
        // Nh = Σ q·uh, Nl = Σ q·ul, Nq = Σ q (96-bit words); Σ q·qh = Nh − 2²⁴Nq, likewise ql;
        // b = S·2⁻²⁴·(Σ q·qh·2⁻²⁴ + Σ q·ql·2⁻⁴⁸), all in exact integers until the last step.
        let word = |k: usize, j: usize| -> i128 {
            let base = 3 * k * m + j;
            (bw[base] as i128) | ((bw[base + m] as i128) << 32) | ((bw[base + 2 * m] as i128) << 64)
        };
        let b: Vec<f64> = (0..m)
            .map(|j| {
                let nq = word(2, j) << 24;
                let exact = ((word(0, j) - nq) << 24) + (word(1, j) - nq);
                exact as f64 * self.y_scale * 2f64.powi(-72)
            })
            .collect();
        tm.cpu_algebra += now_s() - t;
        Ok((a, b))
    }

    async fn run(&mut self, params: &Params, want_grad: bool) -> Result<(Eval, Option<Grad>), KrrGpuError> {
        let t_start = now_s();
        let mut tm = PhaseTimings::default();
        check_settings(&self.settings)?;
        let (n, d) = (self.n, self.d);
        let m = params.check(d)?;
        let (inv_s32, z32) = params_f32(params)?;
        let scope = self.gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);

        // 1. GPU: K_aug blocks and A_aug.
        let (a, b) = self.gram_phase(m, &z32, &inv_s32, &mut tm).await?;

        // 2. CPU: K_mm, the m × m algebra of the forward pass, the loss.
        let t = now_s();
        let settings = self.settings;
        let lambda = settings.lambda;
        let nf = n as f64;
        let nl = nf * lambda;
        let z64: Vec<f64> = z32.iter().map(|&v| v as f64).collect();
        let inv_s64: Vec<f64> = inv_s32.iter().map(|&v| v as f64).collect();
        // K_mm in f64 from the same f32-rounded parameters. (Measured: taking it from the GPU's
        // kernel code instead, for consistency with K_nm, changes nothing measurable.)
        let kmm = kernel::cross_sym(&z64, &inv_s64);
        let mut kj = kmm.clone();
        for j in 0..m {
            kj[j * m + j] += settings.jitter;
        }
        // H, its factor, β, K_j's factor, both inverses, T1 and T2.
        let MmForward { lk, beta, h_inv, kj_inv, t1, t2 } = mm_forward(&a, &kj, &b, nl, nf, m)?;

        // D and the loss. A and b are exact (for K~ and the fixed-point y~), so the m × m form of
        // ‖K~β − y~‖² is exact up to f64 rounding: no residual pass needed.
        let ab = linalg::matvec(&a, &beta, m, m);
        let data_fit = ((self.yy - 2.0 * dot(&b, &beta) + dot(&beta, &ab)) / nf).max(0.0);
        let (eval, alpha, c) = assemble(data_fit, (t1, t2), beta, &kj, &settings, (n, m))?;
        tm.cpu_algebra += now_s() - t;

        let grad = if want_grad {
            let fwd = Forward { m, z: z64, inv_s: inv_s64, kmm, lk, a, h_inv, kj_inv, alpha, c, eval: eval.clone() };
            Some(self.backward(&fwd, &mut tm).await?)
        } else {
            None
        };
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("KRR objective: {e}")).into());
        }
        tm.total = now_s() - t_start;
        self.timings = tm;
        self.total_timings.accumulate(&tm);
        self.evaluations += 1;
        Ok((eval, grad))
    }

    /// Steps 4–6 of the module docs: `W`, `G_mm` and the `Q` side on the CPU, the `P` side on the
    /// GPU, and the assembly.
    async fn backward(&self, f: &Forward, tm: &mut PhaseTimings) -> Result<Grad, KrrGpuError> {
        let t = now_s();
        let (n, d, m) = (self.n, self.d, f.m);
        let lambda = self.settings.lambda;
        let nf = n as f64;
        let (c, dd, t2) = (f.c, f.eval.d_term, f.eval.t2);
        let beta = &f.eval.beta;
        let MmGrad { w, gmm, s_r } = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &f.a, beta, lambda, alpha: f.alpha, c, dd, t2, n: nf, m });
        let w32: Vec<f32> = w.iter().map(|&v| v as f32).collect();
        if w32.iter().any(|v| !v.is_finite()) || !(s_r as f32).is_finite() {
            return Err(KrrError::NonFinite("gradient weights W out of f32 range".into()).into());
        }

        // The K_mm side: Q = G_mm ∘ K_mm.
        let (mut gz, mut gs) = kmm_side(&gmm, &f.kmm, &f.z, m, d);
        tm.cpu_algebra += now_s() - t;

        // The K_nm side on the GPU.
        let t = now_s();
        let g = &self.gpu;
        let ws = self.ws.as_ref().expect("workspace built");
        let beta32: Vec<f32> = beta.iter().map(|&v| v as f32).collect();
        if beta32.iter().any(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite("beta out of f32 range".into()).into());
        }
        g.queue.write_buffer(&ws.beta, 0, bytemuck::cast_slice(&beta32));
        g.queue.write_buffer(&ws.w, 0, bytemuck::cast_slice(&w32));
        let mut enc = g.device.create_command_encoder(&Default::default());
        for (blk, binds) in ws.blocks.iter().zip(&ws.grad) {
            g.queue.write_buffer(&binds.dims, 0, bytemuck::bytes_of(&grad_dims(blk, m, ws.chunk_rows, s_r as f32)));
            // r = K~β − y for this block, then P, then its share of the sums.
            g.encode_pass(&mut enc, &self.pipes.residual, &binds.residual, g.dispatch_linear(blk.rows as u64, WG)?);
            g.encode_pass(&mut enc, &self.pipes.grad_p, &binds.grad_p, [m.div_ceil(TILE) as u32, blk.rows.div_ceil(TILE) as u32, 1]);
            g.encode_pass(&mut enc, &self.pipes.grad_reduce, &binds.reduce, [m.div_ceil(RED_J) as u32, blk.chunks as u32, 1]);
        }
        let len = 2 * m * d;
        g.encode_pass(&mut enc, &self.pipes.grad_sum, &ws.sum, g.dispatch_linear(len as u64, WG)?);
        g.queue.submit([enc.finish()]);
        g.poll_wait();
        tm.grad_pass += now_s() - t;
        let t = now_s();
        let sums = g.read_via::<f32>(&ws.staging, &ws.sums, len).await?;
        tm.readback += now_s() - t;

        // Assembly: ∂L/∂z = (P side + Q side)/s², ∂L/∂log s = s·∂L/∂s = (Σ …)/s².
        let t = now_s();
        let inv_s2: Vec<f64> = f.inv_s.iter().map(|w| w * w).collect();
        for j in 0..m {
            for t in 0..d {
                let i = j * d + t;
                gz[i] = (gz[i] + sums[i] as f64) * inv_s2[t];
                gs[t] += sums[m * d + i] as f64;
            }
        }
        let glog: Vec<f64> = gs.iter().zip(&inv_s2).map(|(g, w)| g * w).collect();
        tm.cpu_algebra += now_s() - t;
        if glog.iter().chain(&gz).any(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite("objective gradient".into()).into());
        }
        Ok(Grad { log_s: glog, z: gz })
    }
}

#[cfg(not(target_arch = "wasm32"))]
impl super::problem::Objective for GpuObjective {
    fn eval_grad(&mut self, params: &Params) -> Result<(Eval, Grad), KrrError> {
        pollster::block_on(self.eval_grad_async(params)).map_err(Into::into)
    }
    fn eval(&mut self, params: &Params) -> Result<Eval, KrrError> {
        pollster::block_on(self.eval_async(params)).map_err(Into::into)
    }
}
