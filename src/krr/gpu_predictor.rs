//! The Nyström predictor on the GPU: `g(q) = Σ_j β_j k(q, z_j)` at millions of queries
//! (`shaders/krr_predict.wgsl`), in chunks of at most [`PREDICT_CHUNK`] queries and dispatches of
//! [`PREDICT_SEGMENT`] inducing points (llvmpipe's loop limit: see [`super::gpu`]).

use super::gpu::{check_d, params_f32, KrrGpuError, PREDICT_CHUNK, PREDICT_SEGMENT, TILE, WG};
use super::error::KrrError;
use super::problem::Params;
use crate::gpu::{specialise, to_u32, Gpu, GpuError};

/// The predictor, after the distance tile it shares with the objective's kernel block.
const PREDICT_WGSL: &str = concat!(include_str!("../../shaders/krr_distance_tile.wgsl"), include_str!("../../shaders/krr_predict.wgsl"));


/// Binding indices of `shaders/krr_predict.wgsl`.
mod predict_at {
    pub const QUERIES: u32 = 0;
    pub const Z: u32 = 1;
    pub const INV_S: u32 = 2;
    pub const BETA: u32 = 3;
    pub const OUT: u32 = 4;
    pub const DIMS: u32 = 5;
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


fn dims_of(rows: usize, j_begin: usize, m: usize) -> Result<PredictDims, GpuError> {
    Ok(PredictDims {
        q: to_u32("queries", rows)?,
        j_begin: j_begin as u32,
        j_end: to_u32("m", (j_begin + PREDICT_SEGMENT).min(m))?,
        first: (j_begin == 0) as u32,
        one: 1.0,
        _pad: [0; 3],
    })
}

struct Segment {
    j_begin: usize,
    dims: wgpu::Buffer,
    bind: wgpu::BindGroup,
}

/// The predictor with its coefficients uploaded and its buffers made ([`GpuPredictor::prepare`]).
pub struct PreparedPredictor {
    gpu: Gpu,
    pipe: wgpu::ComputePipeline,
    d: usize,
    m: usize,
    chunk: usize,
    /// The query count the segments' uniforms hold now.
    rows: std::cell::Cell<usize>,
    q_buf: wgpu::Buffer,
    o_buf: wgpu::Buffer,
    segments: Vec<Segment>,
    staging: crate::gpu::Readback,
    /// Z, 1/s and β, bound by the segments.
    held: [wgpu::Buffer; 3],
}

impl PreparedPredictor {
    /// Queries per submission.
    pub fn chunk_queries(&self) -> usize {
        self.chunk
    }

    /// `g` at each row of `queries` (`q × d`).
    pub async fn predict(&self, queries: &[f32]) -> Result<Vec<f32>, KrrGpuError> {
        let d = self.d;
        if !queries.len().is_multiple_of(d) {
            return Err(KrrError::Shape(format!("predict: {} query values, not a multiple of d = {d}", queries.len())).into());
        }
        let nq = queries.len() / d;
        let g = &self.gpu;
        let mut out = Vec::with_capacity(nq);
        let scope = g.device.push_error_scope(wgpu::ErrorFilter::Validation);
        for q0 in (0..nq).step_by(self.chunk) {
            let rows = self.chunk.min(nq - q0);
            g.queue.write_buffer(&self.q_buf, 0, bytemuck::cast_slice(&queries[q0 * d..(q0 + rows) * d]));
            if rows != self.rows.get() {
                for s in &self.segments {
                    g.queue.write_buffer(&s.dims, 0, bytemuck::bytes_of(&dims_of(rows, s.j_begin, self.m)?));
                }
                self.rows.set(rows);
            }
            let groups = g.dispatch_linear(rows as u64, TILE as u32)?;
            let mut enc = g.device.create_command_encoder(&Default::default());
            for s in &self.segments {
                g.encode_pass(&mut enc, &self.pipe, &s.bind, groups);
            }
            g.queue.submit([enc.finish()]);
            let hl = g.read_via::<f32>(&self.staging, &self.o_buf, 2 * rows).await?;
            out.extend((0..rows).map(|i| (hl[i] as f64 + hl[rows + i] as f64) as f32));
        }
        if let Some(e) = scope.pop().await {
            return Err(GpuError::Kernel(format!("predict: {e}")).into());
        }
        Ok(out)
    }
}

/// Destroyed with its holder, not left to the browser's garbage collector ([`Gpu::retire`]): a
/// scene prepares a predictor per tile.
impl Drop for PreparedPredictor {
    fn drop(&mut self) {
        let own = [&self.q_buf, &self.o_buf, self.staging.buffer()];
        let dims = self.segments.iter().map(|s| &s.dims);
        self.gpu.retire(own.into_iter().chain(dims).chain(&self.held).cloned());
    }
}

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
    /// Builds the kernel for feature dimension `d` (1 ..= [`MAX_D`](super::gpu::MAX_D)).
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
    /// The same checks as [`predict`](super::predict). For repeated calls with the same
    /// coefficients (meshing), keep a [`GpuPredictor::prepare`]d one instead.
    pub async fn predict(&self, beta: &[f64], z: &[f64], log_s: &[f64], queries: &[f32]) -> Result<Vec<f32>, KrrGpuError> {
        let d = self.d;
        if !queries.len().is_multiple_of(d) {
            return Err(KrrError::Shape(format!("predict: {} query values, not a multiple of d = {d}", queries.len())).into());
        }
        let prepared = self.prepare(beta, z, log_s, queries.len() / d)?;
        prepared.predict(queries).await
    }

    /// Uploads the coefficients and makes the buffers, bind groups and staging buffer for
    /// submissions of at most `queries` queries (and at most [`GpuPredictor::chunk_queries`]),
    /// once for every [`PreparedPredictor::predict`]: [`predict_footprint`](super::gpu::predict_footprint)
    /// is what it holds.
    pub fn prepare(&self, beta: &[f64], z: &[f64], log_s: &[f64], queries: usize) -> Result<PreparedPredictor, KrrGpuError> {
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
        if beta.iter().chain(z).chain(log_s).any(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite("predict: beta, z or log_s".into()).into());
        }
        let (inv_s, z32) = params_f32(&Params { log_s: log_s.to_vec(), z: z.to_vec() })?;
        let beta32: Vec<f32> = beta.iter().map(|&v| v as f32).collect();
        let g = &self.gpu;
        g.check_binding::<f32>("inducing points", m * d)?;
        let z_buf = g.upload("krr predict z", &z32);
        let s_buf = g.upload("krr predict 1/s", &inv_s);
        let b_buf = g.upload("krr predict beta", &beta32);
        let chunk = self.chunk.min(queries).max(1);
        let q_buf = g.storage::<f32>("krr predict queries", chunk * d)?;
        let o_buf = g.storage::<f32>("krr predict out", 2 * chunk)?;
        // One uniform and bind group per segment of inducing points, reused by every chunk;
        // only a shorter chunk rewrites the query count (queue writes are ordered after the
        // earlier chunks' submissions).
        let mut segments = Vec::new();
        for j_begin in (0..m).step_by(PREDICT_SEGMENT) {
            let dims = g.uniform("krr predict dims", &dims_of(chunk, j_begin, m)?);
            let bind = g.bind_at(
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
            segments.push(Segment { j_begin, dims, bind });
        }
        let staging = g.readback((8 * chunk) as u64);
        Ok(PreparedPredictor { gpu: g.clone(), pipe: self.pipe.clone(), d, m, chunk, rows: std::cell::Cell::new(chunk), q_buf, o_buf, segments, staging, held: [z_buf, s_buf, b_buf] })
    }

    /// [`GpuPredictor::predict`], blocking (native only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn predict_blocking(&self, beta: &[f64], z: &[f64], log_s: &[f64], queries: &[f32]) -> Result<Vec<f32>, KrrGpuError> {
        pollster::block_on(self.predict(beta, z, log_s, queries))
    }
}
