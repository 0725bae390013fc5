//! What the GPU side of the Nyström KRR shares: its sizes and limits, the footprints the memory
//! plan sums ([`objective_footprint`], [`predict_footprint`]), its error and timing types, and
//! the f32 views of the parameters both kernels take. The two users are files of their own:
//! [`gpu_objective`](super::gpu_objective) (the tuning objective and its gradient, `docs/method.md`
//! §5–§6) and [`gpu_predictor`](super::gpu_predictor) (`g(q) = Σ_j β_j k(q, z_j)` for many queries).
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

use super::error::KrrError;
use super::problem::{Params, Ridge};
use crate::gpu::{Footprint, GpuError};

/// Largest feature dimension the kernels support.
pub const MAX_D: usize = 64;
/// Output tile (rows and columns) of the kernel-block, Gram and `P` kernels.
pub(super) const TILE: usize = 64;
/// Inducing points per `grad_reduce` workgroup, and rows per staged tile there.
pub(super) const RED_J: usize = 32;
pub(super) const RED_ROWS: usize = 32;
/// Rows per `grad_reduce` chunk: about `n / TARGET_CHUNKS`, at least `MIN_CHUNK_ROWS`.
pub(super) const TARGET_CHUNKS: usize = 32;
pub(super) const MIN_CHUNK_ROWS: usize = 256;
/// Rows per Gram dispatch. llvmpipe (lavapipe, the CI adapter) silently ends an invocation's
/// loops after 65535 iterations in total (Mesa's `LP_MAX_TGSI_LOOP_ITERATIONS`; measured: one
/// Gram dispatch over 60001 rows lost every row past ~52400), so no invocation may loop long;
/// this and the next two constants keep every loop below a few thousand iterations.
pub const GRAM_ROWS: usize = 2048;
/// Most rows per `grad_reduce` chunk (see [`GRAM_ROWS`]).
pub(super) const MAX_CHUNK_ROWS: usize = 2048;
/// Inducing points per predict dispatch (see [`GRAM_ROWS`]).
pub const PREDICT_SEGMENT: usize = 256;
/// Most rows per block, whatever the binding limit allows: keeps each `K~` buffer moderate
/// (≤ 256 KiB per inducing point). The exact sums would not need it.
pub const MAX_BLOCK_ROWS: usize = 65535;

/// Workgroup size of the 1-D kernels (`residual`, `grad_sum`).
pub(super) const WG: u32 = 64;
/// Queries per predict submission, whatever the limits allow: short enough not to trip a
/// browser's GPU watchdog (65536 queries × m = 500 × d = 32 ≈ 3 GFLOP).
pub const PREDICT_CHUNK: usize = 65536;

/// What [`GpuObjective`] allocates for `pairs` training pairs of `d` features and `m` inducing
/// points when bindings are at most `binding` bytes: on the GPU `X`, `y` and the `K~` blocks
/// (`4·pairs·(m + d + 4)`), one row block's scratch, the m×m accumulator, W and the staging
/// buffer the accumulator is read back through, and the gradient sums; on
/// the host the problem in f64 and its f32 upload (`8·pairs·(d + 1) + 4·pairs·(d + 3)`) and the
/// f64 m×m algebra (about twelve m×m matrices).
pub fn objective_footprint(pairs: u64, m: u64, d: u64, binding: u64) -> Footprint {
    let rows = (binding / (4 * m)).min(MAX_BLOCK_ROWS as u64).min(pairs).max(1);
    let (_, chunks) = reduction_chunks(pairs as usize, rows as usize);
    let chunks = chunks as u64;
    Footprint {
        // K~, X, y (f32 and fixed point), r; P; A's accumulator, W and the staging copy of each
        // step's W, A's readback; the partial gradient sums per reduction chunk; Z, the sums; β
        // and b's accumulator.
        gpu: 4 * pairs * (m + d + 4) + 4 * rows * m + 32 * m * m + 8 * m * d * chunks + 12 * m * d + 40 * m,
        largest: (4 * d * pairs).max(4 * rows * m).max(12 * m * m).max(8 * m * d * chunks),
        host: 8 * pairs * (d + 1) + 4 * pairs * (d + 3) + 96 * m * m,
    }
}

/// The gradient's reduction over `n` rows in blocks of at most `block_rows`: rows per chunk
/// (about `n / TARGET_CHUNKS`), and chunks over all blocks.
pub(super) fn reduction_chunks(n: usize, block_rows: usize) -> (usize, usize) {
    let chunk_rows = n.div_ceil(TARGET_CHUNKS).next_multiple_of(RED_ROWS).clamp(MIN_CHUNK_ROWS, MAX_CHUNK_ROWS);
    let block_rows = block_rows.max(1);
    let full = n / block_rows;
    let last = n % block_rows;
    let chunks = full * block_rows.div_ceil(chunk_rows) + last.div_ceil(chunk_rows);
    (chunk_rows, chunks)
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

/// What a [`PreparedPredictor`](super::PreparedPredictor) predictor holds on the GPU for chunks of
/// `chunk` queries: the inducing points, 1/s and β, the chunk's features, its two output halves
/// and their staging copy, and a uniform per segment of inducing points.
pub fn predict_footprint(m: u64, d: u64, chunk: u64) -> Footprint {
    let segments = m.div_ceil(PREDICT_SEGMENT as u64);
    Footprint { gpu: 4 * m * (d + 1) + 4 * d + (4 * d + 16) * chunk + 32 * segments, largest: (4 * m * d).max(4 * d * chunk), host: 0 }
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

pub(super) fn check_d(d: usize) -> Result<(), KrrError> {
    if d == 0 {
        return Err(KrrError::Empty("feature dimension d = 0".into()));
    }
    if d > MAX_D {
        return Err(KrrError::Shape(format!("the GPU kernels support d <= {MAX_D}, got d = {d}")));
    }
    Ok(())
}

pub(super) fn check_settings(s: &Ridge) -> Result<(), KrrError> {
    if s.lambda <= 0.0 || !s.lambda.is_finite() {
        return Err(KrrError::Setting(format!("lambda must be finite and > 0, got {}", s.lambda)));
    }
    if s.jitter < 0.0 || !s.jitter.is_finite() {
        return Err(KrrError::Setting(format!("jitter must be finite and >= 0, got {}", s.jitter)));
    }
    Ok(())
}

/// `1/s` and `Z` rounded to f32 as the GPU sees them, checked finite (and `1/s > 0`).
pub(super) fn params_f32(params: &Params) -> Result<(Vec<f32>, Vec<f32>), KrrError> {
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
pub(super) fn fixed_point_y(y: &[f32]) -> (Vec<[u32; 2]>, f64, f64) {
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
