//! The preflight: how much memory each stage of a reconstruction will take, on the GPU and on
//! the host, against the adapter's limits, and what the pipeline will do where something does
//! not fit. `nkrr info` and the page print it before running; the pipeline applies the same
//! plan (its point count and inducing-point count), so what is said is what is done. The plan
//! is its own value ([`MemoryPlan::n`], [`MemoryPlan::m`]): the user's settings are never
//! rewritten.
//!
//! The formulas follow the buffers the stages allocate (features: net/gpu.rs `encode`; pairs:
//! the chunked decode; tuning: krr/gpu.rs `Workspace`, or the f64 reference's K_nm on the CPU;
//! meshing: the refine batches, the chunked decode/predict and the tiled marching cubes). The
//! meshing figures rest on measured refine-batch sizes on a sphere (about 19 R² points in the
//! largest batch), doubled: an estimate, not a bound. wgpu cannot tell an adapter's total
//! memory, so only the per-buffer limits are checked on the GPU; the totals are reported.

use crate::net::NetConfig;
use crate::settings::{Method, Settings};

/// What the plan needs to know about the adapter.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceFacts {
    /// The largest buffer a shader may bind: min(max_storage_buffer_binding_size, max_buffer_size).
    pub binding: u64,
    /// Whether the adapter is a software one (lavapipe, SwiftShader): `auto` then runs the KRR
    /// objective on the CPU.
    pub software: bool,
    /// Host memory the run may use, when known (the browser: wasm32's 4 GiB, less the page).
    pub host_budget: Option<u64>,
}

/// Host memory a wasm32 page can count on: its address space is 4 GiB, and the page, the
/// file's bytes and the viewer take their share.
pub const WASM_HOST_BUDGET: u64 = 2_500_000_000;

impl DeviceFacts {
    pub fn from_limits(limits: &wgpu::Limits, software: bool) -> DeviceFacts {
        DeviceFacts {
            binding: crate::gpu::binding_limit(limits),
            software,
            host_budget: cfg!(target_arch = "wasm32").then_some(WASM_HOST_BUDGET),
        }
    }

    pub fn of(gpu: &crate::gpu::Gpu) -> DeviceFacts {
        Self::from_limits(&gpu.limits, gpu.is_software())
    }

    /// WebGPU's default limits (128 MiB bindings), for a machine without an adapter.
    pub fn webgpu_default() -> DeviceFacts {
        Self::from_limits(&wgpu::Limits::default(), false)
    }
}

/// One stage's estimate.
#[derive(Clone, Debug, PartialEq)]
pub struct StagePlan {
    pub name: &'static str,
    pub gpu_bytes: u64,
    /// The largest single buffer, which must fit [`DeviceFacts::binding`].
    pub largest_binding: u64,
    pub host_bytes: u64,
}

/// The whole estimate, and what will be done to make it fit.
#[derive(Clone, Debug, PartialEq)]
pub struct MemoryPlan {
    /// Points in the cloud, and those the network and the regression will see.
    pub points: usize,
    pub n: usize,
    /// Inducing points the regression will use (nkrr).
    pub m: usize,
    /// Whether the method is nkrr (m and the tuning apply).
    pub nkrr: bool,
    pub krr_on_gpu: bool,
    pub stages: Vec<StagePlan>,
    pub binding_limit: u64,
    pub host_budget: Option<u64>,
    /// What the pipeline will change to fit, one sentence each (empty when everything fits).
    pub actions: Vec<String>,
}

const MIB: f64 = 1024.0 * 1024.0;

fn mib(b: u64) -> String {
    if b as f64 >= 1024.0 * MIB {
        format!("{:.2} GiB", b as f64 / 1024.0 / MIB)
    } else {
        format!("{:.1} MiB", b as f64 / MIB)
    }
}

impl MemoryPlan {
    /// Peak GPU memory over the stages (each stage's buffers are freed before the next's).
    pub fn peak_gpu(&self) -> u64 {
        self.stages.iter().map(|s| s.gpu_bytes).max().unwrap_or(0)
    }

    /// Peak host memory over the stages.
    pub fn peak_host(&self) -> u64 {
        self.stages.iter().map(|s| s.host_bytes).max().unwrap_or(0)
    }

    /// Human-readable lines: one per stage, the limits, then what will be done.
    pub fn lines(&self) -> Vec<String> {
        let mut out: Vec<String> = self
            .stages
            .iter()
            .map(|s| {
                format!(
                    "{:<9} GPU {:>10} (largest buffer {:>10}), host {:>10}",
                    s.name,
                    mib(s.gpu_bytes),
                    mib(s.largest_binding),
                    mib(s.host_bytes)
                )
            })
            .collect();
        let budget = self.host_budget.map_or(String::new(), |b| format!("; host budget {}", mib(b)));
        out.push(format!(
            "limits    largest buffer {} (adapter){budget}; the adapter's total memory is not knowable through WebGPU",
            mib(self.binding_limit)
        ));
        if self.actions.is_empty() {
            let m = if self.nkrr { format!(", m = {}", self.m) } else { String::new() };
            out.push(format!("fits: {} points{m}, as set", self.n));
        }
        out.extend(self.actions.iter().map(|a| format!("will {a}")));
        out
    }
}

/// The network's shape that memory depends on.
struct Net {
    c: u64,
    hb: u64,
    cb: u64,
    reso: u64,
    /// U-Net activations and planes of one encode (bytes).
    unet: u64,
}

impl Net {
    fn of(cfg: &NetConfig) -> Net {
        let (c, reso) = (cfg.c_dim as u64, cfg.reso as u64);
        let (hb, cb) = ((cfg.h as u64).div_ceil(4), (cfg.c_dim as u64).div_ceil(4));
        // As net/gpu.rs `unet` allocates: inputs, per level two convolutions (and a pool
        // below the top), per upward level an up-convolution and a concatenation, then the
        // output planes of 4·cb channels.
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
        Net { c, hb, cb, reso, unet: 4 * floats }
    }
}

/// Queries per decode submission, as [`crate::net::GpuNet`] picks them, for `queries` queries.
fn decode_chunk(binding: u64, c: u64, queries: u64) -> u64 {
    let max = crate::net::gpu::max_decode_queries(binding, c as usize).min(crate::net::gpu::MAX_DECODE_CHUNK);
    (max as u64).min(queries).max(1)
}

/// The plan for a cloud of `points` points (`colours`: whether it has colours) reconstructed
/// with `settings` by the network `cfg` on `device`.
pub fn memory_plan(points: usize, colours: bool, settings: &Settings, cfg: &NetConfig, device: &DeviceFacts) -> MemoryPlan {
    let net = Net::of(cfg);
    let b = device.binding.max(1);
    let nkrr = settings.method == Method::Nkrr;
    let krr_on_gpu = settings.krr_backend.on_gpu(device.software);
    let d = crate::field::input_dim(settings, cfg.c_dim) as u64;
    let mut actions = Vec::new();

    // Points: the encoder's per-point buffers (16·max(hb, cb) bytes a point) and, for nkrr,
    // the training features X (4·d bytes a pair, two pairs a point) are not tiled.
    let mut n = points.min(settings.max_points).max(1) as u64;
    let mut n_fit = b / (16 * net.hb.max(net.cb));
    if nkrr {
        n_fit = n_fit.min(b / (8 * d));
    }
    // m: the GPU objective's m×m accumulator (12 bytes an entry) is one buffer.
    let m_fit = ((b / 12) as f64).sqrt() as u64;
    let mut m = (settings.m as u64).clamp(1, 2 * n);
    // The CPU objective's host memory: per point (two pairs), the f64 K_nm row, X twice and
    // the targets; plus the m×m f64 matrices.
    let cpu_krr_per_point = |m: u64| 16 * (m + 2 * d + 3) + 16 * (d + 1);
    let cpu_krr_host = |n: u64, m: u64| n * cpu_krr_per_point(m) + 96 * m * m;
    let nn = points as u64;
    let attrs = 12 * nn + if colours { 4 * nn } else { 0 };
    if n > n_fit {
        actions.push(format!(
            "subsample to {n_fit} points (from {n}): the largest buffer would exceed the adapter's {}",
            mib(b)
        ));
        n = n_fit;
    }
    if nkrr && krr_on_gpu && m > m_fit {
        actions.push(format!("use m = {m_fit} inducing points (not {m}): the m×m accumulator would exceed one buffer"));
        m = m_fit;
    }
    if let (true, false, Some(budget)) = (nkrr, krr_on_gpu, device.host_budget) {
        if cpu_krr_host(n, m) > budget {
            // The f64 kernel matrix grows with n: find the largest n that fits.
            let fit = budget.saturating_sub(96 * m * m + attrs) / cpu_krr_per_point(m).max(1);
            actions.push(format!(
                "subsample the regression to {fit} points (from {n}): its f64 kernel matrix would exceed the {} host budget",
                mib(budget)
            ));
            n = fit.max(1);
        }
    }
    let np = 2 * n;

    let mut stages = Vec::new();
    stages.push(StagePlan { name: "load", gpu_bytes: 0, largest_binding: 0, host_bytes: attrs + 12 * nn + 12 * n });

    let k = (3 * n).min(3 * net.reso * net.reso);
    let point_buf = 16 * net.hb.max(net.cb) * n;
    stages.push(StagePlan {
        name: "features",
        gpu_bytes: (36 + 16 * net.hb + 16 * net.cb) * n + (8 + 16 * net.hb) * k + net.unet,
        largest_binding: point_buf.max(16 * net.hb * k).max(48 * net.cb * net.reso * net.reso),
        host_bytes: attrs + 48 * n,
    });
    let planes = 48 * net.cb * net.reso * net.reso;

    if nkrr {
        let cd = decode_chunk(b, net.c, np);
        stages.push(StagePlan {
            name: "pairs",
            gpu_bytes: planes + (20 + 8 * net.c) * cd,
            largest_binding: 4 * net.c * cd,
            host_bytes: attrs + np * (4 * net.c + 8 * d + 20) + 40 * n,
        });
        let rows = (b / (4 * m)).min(crate::krr::gpu::MAX_BLOCK_ROWS as u64).min(np).max(1);
        let (gpu, binding, host) = if krr_on_gpu {
            (
                planes + 4 * np * (m + d + 4) + 4 * rows * m + 16 * m * m + 48 * m * d,
                (4 * d * np).max(4 * rows * m).max(12 * m * m),
                attrs + 8 * np * (d + 1) + 4 * np * (d + 3) + 96 * m * m,
            )
        } else {
            (planes, 0, attrs + cpu_krr_host(n, m))
        };
        stages.push(StagePlan { name: "tuning", gpu_bytes: gpu, largest_binding: binding, host_bytes: host });
    }

    // Meshing: the refine batches (the first is the coarse grid), their decoded features on
    // the host, the chunked decode/predict on the GPU, the tiled marching cubes.
    let r = settings.resolution as u64;
    let coarse = 33u64.pow(3);
    let batch = ((r + 1).pow(3)).min(coarse.max(40 * r * r));
    let evaluated = ((r + 1).pow(3)).min(coarse + 55 * r * r);
    let active = (r.pow(3)).min(7 * r * r);
    let triangles = 2 * active;
    let cd = decode_chunk(b, net.c, batch);
    let predict = if nkrr { 4 * m * d + (4 * d + 16) * cd } else { 0 };
    let n_b = active.min(b / 240).max(1);
    stages.push(StagePlan {
        name: "meshing",
        gpu_bytes: planes + ((20 + 8 * net.c) * cd + predict).max(16_384 + 52 * n_b + 96 * n_b),
        largest_binding: (4 * net.c * cd).max(4 * m * d * u64::from(nkrr)).max(240 * n_b),
        // The CPU predictor (nkrr with the f64 objective) widens each batch's features to f64.
        host_bytes: attrs
            + batch * (40 + 4 * net.c + if nkrr && !krr_on_gpu { 8 * d + 8 } else { 0 })
            + 32 * evaluated
            + 92 * active
            + 108 * triangles,
    });
    if settings.trim.is_some() || (colours && settings.colors) {
        let mut host = attrs + 12 * triangles + 12 * active;
        if settings.trim.is_some() {
            host += 2 * (12 * n + 8 * n);
        }
        if colours && settings.colors {
            host += 24 * nn;
        }
        stages.push(StagePlan { name: "finish", gpu_bytes: 0, largest_binding: 0, host_bytes: host });
    }
    if let Some(budget) = device.host_budget {
        let peak = stages.iter().map(|s| s.host_bytes).max().unwrap_or(0);
        if peak > budget {
            actions.push(format!(
                "probably run out of host memory: the peak estimate is {} against a budget of {} (lower the points, m or the resolution)",
                mib(peak),
                mib(budget)
            ));
        }
    }
    MemoryPlan {
        points,
        n: n as usize,
        m: m as usize,
        nkrr,
        krr_on_gpu,
        stages,
        binding_limit: b,
        host_budget: device.host_budget,
        actions,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> NetConfig {
        NetConfig::prior().unwrap()
    }

    fn device(binding: u64) -> DeviceFacts {
        DeviceFacts { binding, software: false, host_budget: None }
    }

    #[test]
    fn small_clouds_fit_the_default_limits_unchanged() {
        let p = memory_plan(10_000, false, &Settings::default(), &cfg(), &DeviceFacts::webgpu_default());
        assert!(p.actions.is_empty(), "{:?}", p.actions);
        assert_eq!((p.n, p.m), (10_000, 500));
        assert!(p.stages.iter().all(|s| s.largest_binding <= p.binding_limit));
        // The tuning keeps K~ (4 bytes × 2n × m) on the GPU: at least 40 MB here.
        let tuning = p.stages.iter().find(|s| s.name == "tuning").unwrap();
        assert!(tuning.gpu_bytes >= 4 * 20_000 * 500, "{}", tuning.gpu_bytes);
    }

    #[test]
    fn too_many_points_for_one_buffer_are_subsampled_and_said() {
        let s = Settings { max_points: 10_000_000, ..Settings::default() };
        let p = memory_plan(5_000_000, false, &s, &cfg(), &device(128 << 20));
        // X holds 2n pairs of 32 f32: n ≤ 128 MiB / 256 B.
        assert_eq!(p.n, (128 << 20) / 256);
        assert!(p.actions[0].starts_with("subsample to 524288 points"), "{:?}", p.actions);
        assert!(p.stages.iter().all(|s| s.largest_binding <= p.binding_limit), "{:?}", p.stages);
    }

    #[test]
    fn too_many_inducing_points_are_clamped() {
        let s = Settings { m: 5000, ..Settings::default() };
        let p = memory_plan(100_000, false, &s, &cfg(), &device(128 << 20));
        assert_eq!(p.m, 3344);
        assert!(p.actions.iter().any(|a| a.contains("m = 3344")), "{:?}", p.actions);
    }

    #[test]
    fn the_cpu_regression_respects_a_host_budget() {
        let s = Settings { max_points: 1_000_000, m: 1000, ..Settings::default() };
        let dev = DeviceFacts { binding: 1 << 40, software: true, host_budget: Some(WASM_HOST_BUDGET) };
        let p = memory_plan(1_000_000, false, &s, &cfg(), &dev);
        assert!(!p.krr_on_gpu);
        assert!(p.n < 1_000_000 && p.actions.iter().any(|a| a.contains("host budget")), "{:?}", p.actions);
        let tuning = p.stages.iter().find(|s| s.name == "tuning").unwrap();
        assert!(tuning.host_bytes <= WASM_HOST_BUDGET, "{}", tuning.host_bytes);
    }
}
