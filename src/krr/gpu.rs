//! The Nyström KRR tuning objective and its gradient on the GPU (`docs/method.md` §5–§6), and the
//! predictor `g(q) = Σ_j β_j k(q, z_j)` for many queries.
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
//! **llvmpipe's loop limit.** lavapipe (the CI adapter) silently ends an invocation's loops after
//! 65535 iterations in total (Mesa's `LP_MAX_TGSI_LOOP_ITERATIONS`). So the host splits long loops
//! over dispatches: Gram dispatches of [`GRAM_ROWS`] rows, reduction chunks of at most
//! `MAX_CHUNK_ROWS` rows, predict dispatches of [`PREDICT_SEGMENT`] inducing points.
//!
//! **Sizes.** `d ≤ 64` ([`MAX_D`]; pasted into the shaders at pipeline creation). Row blocks hold
//! at most `min(binding limit / 4m, 65535)` rows. Every kernel stays within 256 invocations and
//! 16 KiB of workgroup memory (the WebGPU defaults). Device memory per evaluation ≈ `4·n·m`
//! (all `K~` blocks) + one block of `P` + `4m²` words + `2·m·d` per reduction chunk.
//!
//! **Timing.** Natively each GPU phase is submitted and waited for on its own, so
//! [`PhaseTimings`] splits GPU time by phase; on the web the browser runs the work
//! asynchronously and GPU time shows up in `readback`.

use super::kernel;
use super::linalg::{self, dot};
use super::error::KrrError;
use super::mm::{kmm_side, mm_forward, mm_grad, MmForward, MmGrad, MmParts};
use super::problem::{Eval, Grad, Params, Problem, Ridge};
use crate::gpu::{now as now_s, specialise, to_u32, Footprint, Gpu, GpuError};

const KERNEL_WGSL: &str = include_str!("../../shaders/krr_kernel_block.wgsl");
const GRAM_WGSL: &str = include_str!("../../shaders/krr_gram.wgsl");
const GRAD_WGSL: &str = include_str!("../../shaders/krr_grad.wgsl");
const PREDICT_WGSL: &str = include_str!("../../shaders/krr_predict.wgsl");

/// Largest feature dimension the kernels support.
pub const MAX_D: usize = 64;
/// Output tile (rows and columns) of the kernel-block, Gram and `P` kernels.
const TILE: usize = 64;
/// Inducing points per `grad_reduce` workgroup, and rows per staged tile there.
const RED_J: usize = 32;
const RED_ROWS: usize = 32;
/// Rows per `grad_reduce` chunk: about `n / TARGET_CHUNKS`, at least `MIN_CHUNK_ROWS`.
const TARGET_CHUNKS: usize = 32;
const MIN_CHUNK_ROWS: usize = 256;
/// Rows per Gram dispatch. llvmpipe (lavapipe, the CI adapter) silently ends an invocation's
/// loops after 65535 iterations in total (Mesa's `LP_MAX_TGSI_LOOP_ITERATIONS`; measured: one
/// Gram dispatch over 60001 rows lost every row past ~52400), so no invocation may loop long;
/// this and the next two constants keep every loop below a few thousand iterations.
pub const GRAM_ROWS: usize = 2048;
/// Most rows per `grad_reduce` chunk (see [`GRAM_ROWS`]).
const MAX_CHUNK_ROWS: usize = 2048;
/// Inducing points per predict dispatch (see [`GRAM_ROWS`]).
pub const PREDICT_SEGMENT: usize = 256;
/// Most rows per block, whatever the binding limit allows: keeps each `K~` buffer moderate
/// (≤ 256 KiB per inducing point). The exact sums would not need it.
pub const MAX_BLOCK_ROWS: usize = 65535;
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

/// Binding indices of `shaders/krr_predict.wgsl`.
mod predict_at {
    pub const QUERIES: u32 = 0;
    pub const Z: u32 = 1;
    pub const INV_S: u32 = 2;
    pub const BETA: u32 = 3;
    pub const OUT: u32 = 4;
    pub const DIMS: u32 = 5;
}

/// Workgroup size of the 1-D kernels (`residual`, `grad_sum`).
const WG: u32 = 64;
/// Queries per predict submission, whatever the limits allow: short enough not to trip a
/// browser's GPU watchdog (65536 queries × m = 500 × d = 32 ≈ 3 GFLOP).
pub const PREDICT_CHUNK: usize = 65536;

/// What [`GpuObjective`] allocates for `pairs` training pairs of `d` features and `m` inducing
/// points when bindings are at most `binding` bytes: on the GPU `X`, `y` and the `K~` blocks
/// (`4·pairs·(m + d + 4)`), one row block's scratch, the m×m accumulator and gradient sums; on
/// the host the problem in f64 and its f32 upload (`8·pairs·(d + 1) + 4·pairs·(d + 3)`) and the
/// f64 m×m algebra (about twelve m×m matrices).
pub fn objective_footprint(pairs: u64, m: u64, d: u64, binding: u64) -> Footprint {
    let rows = (binding / (4 * m)).min(MAX_BLOCK_ROWS as u64).min(pairs).max(1);
    Footprint {
        gpu: 4 * pairs * (m + d + 4) + 4 * rows * m + 16 * m * m + 48 * m * d,
        largest: (4 * d * pairs).max(4 * rows * m).max(12 * m * m),
        host: 8 * pairs * (d + 1) + 4 * pairs * (d + 3) + 96 * m * m,
    }
}

/// The most training pairs of `d` features the GPU objective can take: `X` (4·d bytes a pair)
/// is one buffer.
pub fn max_pairs(binding: u64, d: u64) -> u64 {
    binding / (4 * d)
}

/// The most inducing points the GPU objective can take: its m×m accumulator (12 bytes an entry)
/// is one buffer.
pub fn max_inducing_points(binding: u64) -> u64 {
    ((binding / 12) as f64).sqrt() as u64
}

/// What [`GpuPredictor::predict`] allocates on the GPU for a chunk of `chunk` queries: the
/// inducing points and the chunk's features and outputs.
pub fn predict_footprint(m: u64, d: u64, chunk: u64) -> Footprint {
    Footprint { gpu: 4 * m * d + (4 * d + 16) * chunk, largest: 4 * m * d, host: 0 }
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

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PredictDims {
    q: u32,
    j_begin: u32,
    j_end: u32,
    first: u32,
    one: f32,
    _pad: [u32; 3],
}

// ---------------------------------------------------------------------------------------------
// errors and timings

/// Why a GPU evaluation failed: bad input or a numerical failure (as the reference reports it),
/// or the GPU itself.
#[derive(Debug)]
pub enum KrrGpuError {
    Krr(KrrError),
    Gpu(GpuError),
}

impl std::fmt::Display for KrrGpuError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            KrrGpuError::Krr(e) => e.fmt(f),
            KrrGpuError::Gpu(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for KrrGpuError {}

impl From<KrrError> for KrrGpuError {
    fn from(e: KrrError) -> Self {
        KrrGpuError::Krr(e)
    }
}

impl From<GpuError> for KrrGpuError {
    fn from(e: GpuError) -> Self {
        KrrGpuError::Gpu(e)
    }
}

/// For the [`Objective`](super::Objective) trait, whose error type is [`KrrError`]: GPU failures
/// (which [`KrrError`] has no variant for) become [`KrrError::Setting`] with a `"GPU: "` message —
/// the configuration does not run on this device.
impl From<KrrGpuError> for KrrError {
    fn from(e: KrrGpuError) -> Self {
        match e {
            KrrGpuError::Krr(k) => k,
            KrrGpuError::Gpu(g) => KrrError::Setting(format!("GPU: {g}")),
        }
    }
}

/// Wall-clock seconds per phase of one evaluation (or summed over several).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhaseTimings {
    /// `K_aug` row blocks (n·m·d).
    pub kernel: f64,
    /// `A_aug = K_augᵀ K_aug` (n·m²/2, the dominant GEMM of the forward pass).
    pub gram: f64,
    /// Every f64 m × m step on the CPU: `K_mm`, Cholesky factors, solves, inverses, traces, `W`,
    /// `G_mm` and the `Q` side of the gradient, and the final assembly.
    pub cpu_algebra: f64,
    /// `r = K~β − y` (n·m), `P = G_nm ∘ K~` (n·m², the dominant GEMM of the backward pass) and
    /// the reductions.
    pub grad_pass: f64,
    /// Copies from the device and buffer maps (`A` and `b`; the gradient sums).
    pub readback: f64,
    /// The whole evaluation, including uploads and bookkeeping.
    pub total: f64,
}

impl PhaseTimings {
    /// Adds `o`'s timings to these.
    pub(crate) fn accumulate(&mut self, o: &PhaseTimings) {
        self.kernel += o.kernel;
        self.gram += o.gram;
        self.cpu_algebra += o.cpu_algebra;
        self.grad_pass += o.grad_pass;
        self.readback += o.readback;
        self.total += o.total;
    }

    /// One line, milliseconds.
    pub fn summary(&self) -> String {
        format!(
            "kernel {:.1} ms, gram {:.1} ms, cpu_algebra {:.1} ms, grad_pass {:.1} ms, \
             readback {:.1} ms, total {:.1} ms",
            self.kernel * 1e3,
            self.gram * 1e3,
            self.cpu_algebra * 1e3,
            self.grad_pass * 1e3,
            self.readback * 1e3,
            self.total * 1e3
        )
    }
}

// ---------------------------------------------------------------------------------------------
// pipelines

fn check_d(d: usize) -> Result<(), KrrError> {
    if d == 0 {
        return Err(KrrError::Empty("feature dimension d = 0".into()));
    }
    if d > MAX_D {
        return Err(KrrError::Shape(format!("the GPU kernels support d <= {MAX_D}, got d = {d}")));
    }
    Ok(())
}

fn check_settings(s: &Ridge) -> Result<(), KrrError> {
    if s.lambda <= 0.0 || !s.lambda.is_finite() {
        return Err(KrrError::Setting(format!("lambda must be finite and > 0, got {}", s.lambda)));
    }
    if s.jitter < 0.0 || !s.jitter.is_finite() {
        return Err(KrrError::Setting(format!("jitter must be finite and >= 0, got {}", s.jitter)));
    }
    Ok(())
}

/// `1/s` and `Z` rounded to f32 as the GPU sees them, checked finite (and `1/s > 0`).
fn params_f32(params: &Params) -> Result<(Vec<f32>, Vec<f32>), KrrError> {
    let inv_s: Vec<f32> = params.log_s.iter().map(|l| (-l).exp() as f32).collect();
    if let Some(t) = inv_s.iter().position(|v| !v.is_finite() || *v <= 0.0) {
        return Err(KrrError::NonFinite(format!(
            "length-scale s[{t}] = exp({}) is out of f32 range",
            params.log_s[t]
        )));
    }
    let z: Vec<f32> = params.z.iter().map(|&v| v as f32).collect();
    if let Some(i) = z.iter().position(|v| !v.is_finite()) {
        return Err(KrrError::NonFinite(format!("z value {} is out of f32 range", params.z[i])));
    }
    Ok((inv_s, z))
}

/// `y` in two 24-bit fixed-point levels for the exact `b = K~ᵀy` (see `krr_gram.wgsl`): with a
/// power-of-two scale `S ≥ max|y|`, `y~ = S·(qh·2⁻²⁴ + ql·2⁻⁴⁸)` (within `S·2⁻⁴⁹` of y), stored as
/// `(qh + 2²⁴, ql + 2²⁴)` per row. Returns the pairs, `S` and `‖y~‖²`.
fn fixed_point_y(y: &[f32]) -> (Vec<[u32; 2]>, f64, f64) {
    let max = y.iter().fold(0.0f64, |a, &v| a.max((v as f64).abs()));
    let scale = if max > 0.0 { 2f64.powi(max.log2().ceil() as i32) } else { 1.0 };
    let p24 = 16777216.0;
    let mut yy = 0.0;
    let q = y
        .iter()
        .map(|&v| {
            let t = v as f64 / scale * p24; // |t| <= 2^24, exact
            let qh = t.round();
            let ql = ((t - qh) * p24).round(); // |t - qh| <= 1/2, exact
            let yt = scale * (qh + ql / p24) / p24;
            yy += yt * yt;
            [(qh + p24) as u32, (ql + p24) as u32]
        })
        .collect();
    (q, scale, yy)
}

// ---------------------------------------------------------------------------------------------
// predictor

/// The Nyström predictor on the GPU for feature dimension `d`: `g(q) = Σ_j β_j k(q, z_j)` at
/// millions of queries, in chunks of at most [`PREDICT_CHUNK`] (fewer where a binding cannot hold
/// that many).
#[derive(Clone)]
pub struct GpuPredictor {
    gpu: Gpu,
    d: usize,
    pipe: wgpu::ComputePipeline,
    chunk: usize,
}

impl GpuPredictor {
    /// Builds the kernel for feature dimension `d` (1 ..= [`MAX_D`]).
    pub async fn new(gpu: &Gpu, d: usize) -> Result<GpuPredictor, KrrGpuError> {
        check_d(d)?;
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let src = specialise(PREDICT_WGSL, &[("D", d)]);
        let pipe = gpu.compute_pipelines("krr_predict", &src, &["predict"]).pop().expect("one pipeline");
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("building the predict kernel: {e}")).into());
        }
        let mut p = GpuPredictor { gpu: gpu.clone(), d, pipe, chunk: 0 };
        p.set_chunk_queries(PREDICT_CHUNK);
        Ok(p)
    }

    /// [`GpuPredictor::new`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_blocking(gpu: &Gpu, d: usize) -> Result<GpuPredictor, KrrGpuError> {
        pollster::block_on(Self::new(gpu, d))
    }

    /// Feature dimension.
    pub fn d(&self) -> usize {
        self.d
    }

    /// Queries per submission.
    pub fn chunk_queries(&self) -> usize {
        self.chunk
    }

    /// Sets the queries per submission (clamped to 1 ..= what one binding and one 2-D dispatch
    /// hold).
    pub fn set_chunk_queries(&mut self, n: usize) {
        let max = self.gpu.rows_per_binding((self.d * 4) as u64);
        let dim = self.gpu.limits.max_compute_workgroups_per_dimension as usize;
        let max_dispatch = dim.saturating_mul(dim).saturating_mul(WG as usize);
        self.chunk = n.clamp(1, max.min(max_dispatch));
    }

    /// `g` at each row of `queries` (`q × d`, f32 as the network produces features), for
    /// coefficients `beta` (m), inducing points `z` (`m × d`) and log length-scales (`d`).
    /// The same checks as [`predict`](super::predict).
    pub async fn predict(&self, beta: &[f64], z: &[f64], log_s: &[f64], queries: &[f32]) -> Result<Vec<f32>, KrrGpuError> {
        let d = self.d;
        let m = beta.len();
        if log_s.len() != d {
            return Err(KrrError::Shape(format!("predict: log_s has {} entries, expected d = {d}", log_s.len())).into());
        }
        if m == 0 {
            return Err(KrrError::Empty("predict: m = 0".into()).into());
        }
        if z.len() != m * d {
            return Err(KrrError::Shape(format!("predict: z has {} values, expected m·d = {}", z.len(), m * d)).into());
        }
        if !queries.len().is_multiple_of(d) {
            return Err(KrrError::Shape(format!("predict: {} query values, not a multiple of d = {d}", queries.len())).into());
        }
        if beta.iter().chain(z).chain(log_s).any(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite("predict: beta, z or log_s".into()).into());
        }
        let nq = queries.len() / d;
        if nq == 0 {
            return Ok(Vec::new());
        }
        let (inv_s, z32) = params_f32(&Params { log_s: log_s.to_vec(), z: z.to_vec() })?;
        let beta32: Vec<f32> = beta.iter().map(|&v| v as f32).collect();
        let g = &self.gpu;
        g.check_binding::<f32>("inducing points", m * d)?;
        let z_buf = g.upload("krr predict z", &z32);
        let s_buf = g.upload("krr predict 1/s", &inv_s);
        let b_buf = g.upload("krr predict beta", &beta32);
        let chunk = self.chunk.min(nq);
        let q_buf = g.storage::<f32>("krr predict queries", chunk * d)?;
        let o_buf = g.storage::<f32>("krr predict out", 2 * chunk)?;
        let mut out = Vec::with_capacity(nq);
        let scope = g.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let dims_of = |rows: usize, j_begin: usize| -> Result<PredictDims, GpuError> {
            Ok(PredictDims {
                q: to_u32("queries", rows)?,
                j_begin: j_begin as u32,
                j_end: to_u32("m", (j_begin + PREDICT_SEGMENT).min(m))?,
                first: (j_begin == 0) as u32,
                one: 1.0,
                _pad: [0; 3],
            })
        };
        // One uniform and bind group per segment of inducing points, built once per call and
        // reused by every chunk; only a shorter last chunk rewrites the query count (queue
        // writes are ordered after the earlier chunks' submissions).
        let mut segments = Vec::new();
        for j_begin in (0..m).step_by(PREDICT_SEGMENT) {
            let dims = g.uniform("krr predict dims", &dims_of(chunk, j_begin)?);
            let bg = g.bind_at(
                &self.pipe,
                &[
                    (predict_at::QUERIES, &q_buf),
                    (predict_at::Z, &z_buf),
                    (predict_at::INV_S, &s_buf),
                    (predict_at::BETA, &b_buf),
                    (predict_at::OUT, &o_buf),
                    (predict_at::DIMS, &dims),
                ],
            );
            segments.push((j_begin, dims, bg));
        }
        for q0 in (0..nq).step_by(chunk) {
            let rows = chunk.min(nq - q0);
            g.queue.write_buffer(&q_buf, 0, bytemuck::cast_slice(&queries[q0 * d..(q0 + rows) * d]));
            if rows != chunk {
                for (j_begin, dims, _) in &segments {
                    g.queue.write_buffer(dims, 0, bytemuck::bytes_of(&dims_of(rows, *j_begin)?));
                }
            }
            let groups = g.dispatch_linear(rows as u64, TILE as u32)?;
            let mut enc = g.device.create_command_encoder(&Default::default());
            for (_, _, bg) in &segments {
                g.encode_pass(&mut enc, &self.pipe, bg, groups);
            }
            g.queue.submit([enc.finish()]);
            let hl = g.read::<f32>(&o_buf, 2 * rows).await?;
            out.extend((0..rows).map(|i| (hl[i] as f64 + hl[rows + i] as f64) as f32));
        }
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("predict: {e}")).into());
        }
        Ok(out)
    }

    /// [`GpuPredictor::predict`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn predict_blocking(&self, beta: &[f64], z: &[f64], log_s: &[f64], queries: &[f32]) -> Result<Vec<f32>, KrrGpuError> {
        pollster::block_on(self.predict(beta, z, log_s, queries))
    }
}

// ---------------------------------------------------------------------------------------------
// objective

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

/// Device buffers for one inducing-point count `m` (rebuilt when `m` or the block size changes).
struct Workspace {
    m: usize,
    max_rows: usize,
    blocks: Vec<Block>,
    chunk_rows: usize,
    total_chunks: usize,
    z: wgpu::Buffer,
    inv_s: wgpu::Buffer,
    /// `K~` row blocks, u32 fixed point (`q = round(K · 2²⁴)`).
    k: Vec<wgpu::Buffer>,
    /// `Σ q q'` as three u32 words per entry (`3 × m × m`), and the sums behind `b` (`9 × m`, see
    /// `krr_gram.wgsl`).
    acc: wgpu::Buffer,
    bacc: wgpu::Buffer,
    beta: wgpu::Buffer,
    w: wgpu::Buffer,
    r: wgpu::Buffer,
    p: wgpu::Buffer,
    part: wgpu::Buffer,
    sums: wgpu::Buffer,
}

impl Workspace {
    fn new(gpu: &Gpu, n: usize, d: usize, m: usize, block_rows: usize) -> Result<Workspace, GpuError> {
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
        let chunk_rows = n.div_ceil(TARGET_CHUNKS).next_multiple_of(RED_ROWS).clamp(MIN_CHUNK_ROWS, MAX_CHUNK_ROWS);
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
        let max_rows = blocks.iter().map(|b| b.rows).max().unwrap_or(1);
        for (label, len) in [
            ("Z", m * d),
            ("A = K^T K accumulator", 3 * m * m),
            ("W", m * m),
            ("P block", max_rows * m),
            ("gradient partial sums", total_chunks * 2 * m * d),
        ] {
            gpu.check_binding::<f32>(label, len)?;
            to_u32(label, len)?;
        }
        let k = blocks
            .iter()
            .map(|b| gpu.storage::<u32>("K block", b.rows * m))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Workspace {
            m,
            max_rows: block_rows,
            blocks,
            chunk_rows,
            total_chunks,
            z: gpu.storage::<f32>("Z", m * d)?,
            inv_s: gpu.storage::<f32>("1/s", d)?,
            k,
            acc: gpu.storage::<u32>("A = K^T K accumulator", 3 * m * m)?,
            bacc: gpu.storage::<u32>("b = K^T y accumulator", 9 * m)?,
            beta: gpu.storage::<f32>("beta", m)?,
            w: gpu.storage::<f32>("W", m * m)?,
            r: gpu.storage::<f32>("r", n)?,
            p: gpu.storage::<f32>("P block", max_rows * m)?,
            part: gpu.storage::<f32>("gradient partial sums", total_chunks * 2 * m * d)?,
            sums: gpu.storage::<f32>("gradient sums", 2 * m * d)?,
        })
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

impl GpuObjective {
    /// Uploads `problem` (as f32) and builds the kernels for its feature dimension (≤ [`MAX_D`]).
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
            self.ws = Some(Workspace::new(&self.gpu, self.n, self.d, m, self.block_rows)?);
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
        for (b, blk) in ws.blocks.iter().enumerate() {
            let dims = g.uniform(
                "krr kernel dims",
                &KernelDims { rows: blk.rows as u32, row0: blk.row0 as u32, m: m as u32, _pad: 0 },
            );
            let bg = g.bind_at(
                &self.pipes.kernel_block,
                &[(kernel_at::X, &self.x), (kernel_at::Z, &ws.z), (kernel_at::INV_S, &ws.inv_s), (kernel_at::K, &ws.k[b]), (kernel_at::DIMS, &dims)],
            );
            let groups = [m.div_ceil(TILE) as u32, blk.rows.div_ceil(TILE) as u32, 1];
            g.encode_pass(&mut enc, &self.pipes.kernel_block, &bg, groups);
        }
        g.queue.submit([enc.finish()]);
        g.poll_wait();
        tm.kernel += now_s() - t;

        let t = now_s();
        let mut enc = g.device.create_command_encoder(&Default::default());
        let tiles = m.div_ceil(TILE) as u32;
        for (b, blk) in ws.blocks.iter().enumerate() {
            for r_begin in (0..blk.rows).step_by(GRAM_ROWS) {
                let dims = g.uniform(
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
                let bg = g.bind_at(&self.pipes.gram, &[(gram_at::K, &ws.k[b]), (gram_at::ACC, &ws.acc), (gram_at::DIMS, &dims)]);
                g.encode_pass(&mut enc, &self.pipes.gram, &bg, [tiles, tiles, 1]);
                let bg = g.bind_at(&self.pipes.gram_b, &[(gram_at::K, &ws.k[b]), (gram_at::DIMS, &dims), (gram_at::YQ, &self.yq), (gram_at::BACC, &ws.bacc)]);
                g.encode_pass(&mut enc, &self.pipes.gram_b, &bg, [tiles, 1, 1]);
            }
        }
        g.queue.submit([enc.finish()]);
        g.poll_wait();
        tm.gram += now_s() - t;

        let t = now_s();
        let words = g.read::<u32>(&ws.acc, 3 * m * m).await?;
        let bw = g.read::<u32>(&ws.bacc, 9 * m).await?;
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
        let rkhs_norm2 = dot(&beta, &linalg::matvec(&kj, &beta, m, m));
        let d_term = data_fit + lambda * rkhs_norm2;
        let (alpha, c) = settings.weights(n);
        let loss = alpha * t1 + c * t2 * d_term + 2.0 * d_term;
        if !loss.is_finite() {
            return Err(KrrError::NonFinite(format!(
                "objective: loss = {loss} (T1 = {t1}, T2 = {t2}, D = {d_term})"
            ))
            .into());
        }
        let eval = Eval { loss, data_fit, rkhs_norm2, d_term, t1, t2, beta };
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
        for (bi, blk) in ws.blocks.iter().enumerate() {
            let dims = g.uniform(
                "krr grad dims",
                &GradDims {
                    rows: blk.rows as u32,
                    row0: blk.row0 as u32,
                    m: m as u32,
                    _s: m as u32,
                    chunk_rows: ws.chunk_rows as u32,
                    chunk0: blk.chunk0 as u32,
                    s_r: s_r as f32,
                    one: 1.0,
                },
            );
            // r = K~β − y for this block, then P.
            let bg = g.bind_at(
                &self.pipes.residual,
                &[(grad_at::K, &ws.k[bi]), (grad_at::BETA, &ws.beta), (grad_at::R, &ws.r), (grad_at::DIMS, &dims), (grad_at::Y, &self.y)],
            );
            g.encode_pass(&mut enc, &self.pipes.residual, &bg, g.dispatch_linear(blk.rows as u64, WG)?);
            let bg = g.bind_at(
                &self.pipes.grad_p,
                &[
                    (grad_at::K, &ws.k[bi]),
                    (grad_at::W, &ws.w),
                    (grad_at::BETA, &ws.beta),
                    (grad_at::R, &ws.r),
                    (grad_at::P, &ws.p),
                    (grad_at::DIMS, &dims),
                ],
            );
            g.encode_pass(&mut enc, &self.pipes.grad_p, &bg, [m.div_ceil(TILE) as u32, blk.rows.div_ceil(TILE) as u32, 1]);
            let bg = g.bind_at(
                &self.pipes.grad_reduce,
                &[(grad_at::P, &ws.p), (grad_at::X, &self.x), (grad_at::Z, &ws.z), (grad_at::PART, &ws.part), (grad_at::DIMS, &dims)],
            );
            g.encode_pass(&mut enc, &self.pipes.grad_reduce, &bg, [m.div_ceil(RED_J) as u32, blk.chunks as u32, 1]);
        }
        let len = 2 * m * d;
        let sdims = g.uniform("krr sum dims", &SumDims { len: len as u32, chunks: ws.total_chunks as u32, one: 1.0, _b: 0 });
        let bg = g.bind_at(&self.pipes.grad_sum, &[(grad_at::PART_IN, &ws.part), (grad_at::SUMS, &ws.sums), (grad_at::SUM_DIMS, &sdims)]);
        g.encode_pass(&mut enc, &self.pipes.grad_sum, &bg, g.dispatch_linear(len as u64, WG)?);
        g.queue.submit([enc.finish()]);
        g.poll_wait();
        tm.grad_pass += now_s() - t;
        let t = now_s();
        let sums = g.read::<f32>(&ws.sums, len).await?;
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
