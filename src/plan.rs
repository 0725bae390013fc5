//! The preflight: how much memory each stage of a reconstruction will take, on the GPU and on
//! the host, against the adapter's limits, and what the pipeline will do where something does
//! not fit. `nkrr info` and the page print it before running; the pipeline applies the same
//! plan (its point count and inducing-point count), so what is said is what is done. The plan
//! is its own value ([`MemoryPlan::n`], [`MemoryPlan::m`]): the user's settings are never
//! rewritten.
//!
//! Each stage states what it allocates, next to the code that allocates it
//! (`net::gpu::encode_footprint` and `decode_footprint`, `field::pairs_host_bytes`,
//! `krr::gpu::objective_footprint` and `predict_footprint`, `krr::reference::host_bytes`,
//! `mesh::refine::MeshingSize`, `mesh::marching_cubes_gpu::footprint`); the plan adds them up per
//! stage. The meshing figures rest on measured refine-batch sizes on a sphere, doubled: an
//! estimate, not a bound. wgpu cannot tell an adapter's total
//! memory, so only the per-buffer limits are checked on the GPU; the totals are reported.

use crate::gpu::Footprint;
use crate::krr::{gpu as krr_gpu, reference};
use crate::mesh::{marching_cubes_gpu, refine::MeshingSize};
use crate::net::{gpu as net_gpu, NetConfig};
use crate::settings::{Method, Settings, Surface};

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
    /// Whether the mesh comes from a screened Poisson solve ([`crate::poisson`]), not the
    /// field's level set: [`surface`]'s decision.
    pub poisson: bool,
    /// What the pipeline will change to fit, one sentence each (empty when everything fits).
    pub actions: Vec<String>,
    /// What the run will do otherwise than asked, for a reason other than memory, one sentence
    /// each (m capped at the pairs the tuning sees).
    pub decisions: Vec<String>,
}

/// Points from which `--surface auto` meshes a screened Poisson solve oriented by the field.
/// First 2,000, between the sizes measured then (3k and 10k closer than the field's level set on
/// the tuning shapes, 500 not: docs/results.md, Lever 9). Measured again on 2026-12-05 with the
/// Poisson surface as it is now, on the eval clouds of all six shapes (mean CD1 x100, the field
/// as `auto` made it -> the Poisson surface): 1,500 points 0.511 -> 0.442 and 1k 0.558 -> 0.501,
/// lower on every shape at both; 500 0.691 -> 0.687, mixed (fandisk and spot +0.05, bunny
/// -0.09), so 500 keeps the field. On clouds whose density falls 55x along the object it was
/// the sparse end that the field lost: 1k 1.004 -> 0.788, 1,500 0.743 -> 0.616 (docs/poisson.md,
/// "Uneven density").
pub const POISSON_POINTS: usize = 1000;

/// Whether a cloud of `n` points (those the network sees) is meshed through a Poisson solve, and
/// the sentence that says what of it differs from what was asked (a mesh finer than the solve's
/// grid). Auto's choice is not a change to what was asked: the run says it with the solve's
/// report ([`crate::poisson::Solution::notice`]).
pub fn surface(settings: &Settings, n: usize) -> (bool, Option<String>) {
    let poisson = match settings.surface {
        Surface::Field => false,
        Surface::Poisson => true,
        Surface::Auto => n >= POISSON_POINTS,
    };
    let (grid, wanted) = (crate::poisson::grid_resolution(settings.resolution, n), crate::poisson::grid_wanted(settings.resolution, n));
    let coarser = (poisson && wanted > grid)
        .then(|| format!("solve the Poisson surface on a {grid}³ grid (not the {wanted}³ a {}³ mesh of {n} points would have: the most it solves) and march it at {}³", settings.resolution, settings.resolution));
    (poisson, coarser)
}

/// The inducing points for a regression on `points` points: `m` (what the settings and the
/// memory allow), at most the pairs the tuning sees ([`crate::field::tuning_rows`]), since the
/// inducing points are drawn from those rows; and, when that is fewer than `settings.m`, the
/// sentence that says so. The one place m is decided from the pairs: the preflight calls it
/// with the planned points, the pipeline again with the points the stray-point filter kept.
pub fn inducing_points(settings: &Settings, m: usize, points: usize) -> (usize, Option<String>) {
    let rows = crate::field::tuning_rows(settings.training_pairs(points), settings).max(1);
    if m <= rows {
        return (m, None);
    }
    let why = match settings.tune_pairs {
        Some(k) if k <= rows => format!("the tuning sees {rows} training pairs (--tune-pairs {k}, \"Pairs for tuning\")"),
        _ => format!("the tuning sees {rows} training pairs ({points} points)"),
    };
    (rows, Some(format!("use m = {rows} inducing points, not {}: {why}, and the inducing points are drawn from them", settings.m)))
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

    /// The regression the fit runs ([`crate::field::Regression`]) on the `points` the stray-point filter
    /// kept, which may be fewer than planned: m is decided again by the same rule
    /// ([`inducing_points`]), and the sentence says so when that lowers it.
    pub fn regression(&self, settings: &Settings, points: usize) -> (crate::field::Regression, Option<String>) {
        let (m, why) = inducing_points(settings, self.m, points);
        let fewer = why.filter(|_| m < self.m).map(|d| format!("after the stray-point filter, nkrr will {d}"));
        (crate::field::Regression { m, on_gpu: self.krr_on_gpu }, fewer)
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
        if self.actions.is_empty() && self.decisions.is_empty() {
            let m = if self.nkrr { format!(", m = {}", self.m) } else { String::new() };
            out.push(format!("fits: {} points{m}, as set", self.n));
        }
        out.extend(self.actions.iter().chain(&self.decisions).map(|a| format!("will {a}")));
        out
    }
}

/// The plan for a cloud of `points` points (`colours`: whether it has colours) reconstructed
/// with `settings` by the network `cfg` on `device`. Each stage's bytes are what that stage's
/// module says it allocates; this adds them up and decides what must change to fit.
pub fn memory_plan(points: usize, colours: bool, settings: &Settings, cfg: &NetConfig, device: &DeviceFacts) -> MemoryPlan {
    let b = device.binding.max(1);
    let nkrr = settings.method == Method::Nkrr;
    let krr_on_gpu = settings.krr_backend.on_gpu(device.software);
    let c = cfg.c_dim as u64;
    let d = crate::field::input_dim(settings, cfg.c_dim) as u64;
    let mut actions = Vec::new();

    // Points: the encoder's per-point buffers and, for nkrr, the training features X (`rows`
    // pairs a point: itself, its offsets and the two across the surface) are not tiled.
    let mut n = points.min(settings.max_points).max(1) as u64;
    let rows = 1 + settings.extra_per_point(n as usize) as u64;
    let mut n_fit = net_gpu::max_encode_points(cfg, b);
    if nkrr {
        n_fit = n_fit.min(krr_gpu::max_pairs(b, d) / rows);
    }
    let m_fit = krr_gpu::max_inducing_points(b);
    let mut m = settings.m.max(1) as u64;
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
        if reference::host_bytes(rows * n, m, d) > budget {
            // The f64 kernel matrix grows with n: find the largest n that fits.
            let per_point = rows * reference::host_bytes_per_pair(m, d);
            let fit = budget.saturating_sub(reference::host_bytes(0, m, d) + attrs) / per_point.max(1);
            actions.push(format!(
                "subsample the regression to {fit} points (from {n}): its f64 kernel matrix would exceed the {} host budget",
                mib(budget)
            ));
            n = fit.max(1);
        }
    }
    let per_point = settings.extra_per_point(n as usize) as u64;
    let np = settings.training_pairs(n as usize) as u64;
    let mut decisions = Vec::new();
    if nkrr {
        let (fit, why) = inducing_points(settings, m as usize, n as usize);
        m = fit as u64;
        decisions.extend(why);
    }
    let (poisson, why) = surface(settings, n as usize);
    decisions.extend(why);
    let planes = Footprint { gpu: net_gpu::planes_bytes(cfg), ..Default::default() };
    let stage = |name: &'static str, f: Footprint| StagePlan {
        name,
        gpu_bytes: f.gpu,
        largest_binding: f.largest,
        host_bytes: attrs + f.host,
    };

    let mut stages = vec![stage("load", Footprint::host(12 * nn + 12 * n))];
    stages.push(stage("features", net_gpu::encode_footprint(cfg, n)));
    if nkrr {
        let pairs = Footprint::host(crate::field::pairs_host_bytes(n, per_point, c, d));
        stages.push(stage("pairs", planes.and(net_gpu::decode_footprint(cfg, b, np)).and(pairs)));
        let tuning = if krr_on_gpu {
            krr_gpu::objective_footprint(np, m, d, b)
        } else {
            Footprint::host(reference::host_bytes(np, m, d))
        };
        stages.push(stage("tuning", planes.and(tuning)));
    }

    // Meshing: the refine batches (the first is the coarse grid) and their decoded features on
    // the host; on the GPU the chunked decode and predict, then the tiled marching cubes.
    let size = MeshingSize::at(settings.resolution);
    // The field is evaluated in calls of at most this many points, by one evaluator whose
    // decoder and predictor are sized for them.
    let queries = size.batch.min(crate::field::EVALUATION_CHUNK as u64);
    let decode = net_gpu::decode_footprint(cfg, b, queries);
    let field = match (nkrr, krr_on_gpu) {
        (true, true) => krr_gpu::predict_footprint(m, d, queries.min(krr_gpu::PREDICT_CHUNK as u64)),
        // The CPU predictor (nkrr with the f64 objective) widens each batch's features to f64.
        (true, false) => Footprint::host(reference::predict_host_bytes(size.batch, d) + reference::predict_block_bytes(m, d)),
        (false, _) => Footprint::default(),
    };
    let evaluate = decode.and(field).and(Footprint::host(size.batch * 4 * c + size.host_bytes()));
    // The evaluator's buffers (made once for the extraction) are still held while the marching
    // cubes run.
    let polygonize = marching_cubes_gpu::footprint(size.active, b);
    stages.push(stage("meshing", planes.and(evaluate).and(polygonize)));
    if poisson {
        // The solve on the host while the evaluator is still held, then χ's marching cubes.
        stages.push(stage("poisson", planes.and(evaluate).and(polygonize).and(Footprint::host(crate::poisson::host_bytes(settings.resolution, n as usize)))));
    }
    if settings.fit || settings.trim.is_some() || (colours && settings.colors) {
        let mut host = 12 * size.triangles + 12 * size.active;
        // The fit and the trim each index the points (and their neighbour lists).
        let index = 2 * (12 * n + 8 * n);
        host += index * (u64::from(settings.fit) + u64::from(settings.trim.is_some()));
        if colours && settings.colors {
            host += 24 * nn;
        }
        stages.push(stage("finish", Footprint::host(host)));
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
        poisson,
        actions,
        decisions,
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
        // The tuning keeps K~ (4 bytes × 4n × m: each point, its offset and the two across the
        // surface) on the GPU: at least 80 MB here.
        let tuning = p.stages.iter().find(|s| s.name == "tuning").unwrap();
        assert!(tuning.gpu_bytes >= 4 * 40_000 * 500, "{}", tuning.gpu_bytes);
    }

    #[test]
    fn too_many_points_for_one_buffer_are_subsampled_and_said() {
        let s = Settings { max_points: 10_000_000, ..Settings::default() };
        let p = memory_plan(5_000_000, false, &s, &cfg(), &device(128 << 20));
        // X holds 4n pairs (each point, its offset, two across the surface) of 32 f32:
        // n ≤ 128 MiB / 512 B; without the pairs across, 2n pairs and twice the points.
        assert_eq!(p.n, (128 << 20) / 512);
        assert!(p.actions[0].starts_with("subsample to 262144 points"), "{:?}", p.actions);
        let p = memory_plan(5_000_000, false, &Settings { across: None, ..s }, &cfg(), &device(128 << 20));
        assert_eq!(p.n, (128 << 20) / 256);
        assert!(p.stages.iter().all(|s| s.largest_binding <= p.binding_limit), "{:?}", p.stages);
    }

    #[test]
    fn the_surface_is_decided_once_and_said() {
        let plan = |points: usize, s: &Settings| memory_plan(points, false, s, &cfg(), &DeviceFacts::webgpu_default());
        let auto = Settings::default();
        // Auto: Poisson from POISSON_POINTS up (the run's notice says so, not the plan: it is
        // what was asked), the field's level set below.
        let p = plan(POISSON_POINTS, &auto);
        assert!(p.poisson && p.decisions.is_empty(), "{:?}", p.decisions);
        assert!(p.stages.iter().any(|s| s.name == "poisson" && s.host_bytes >= crate::poisson::host_bytes(auto.resolution, POISSON_POINTS)));
        let p = plan(POISSON_POINTS - 1, &auto);
        assert!(!p.poisson && p.decisions.is_empty() && !p.stages.iter().any(|s| s.name == "poisson"), "{:?}", p.decisions);
        // Asked for: as asked, whatever the size; a finer mesh than the solve's grid is said.
        assert!(!plan(50_000, &Settings { surface: Surface::Field, ..auto.clone() }).poisson);
        let p = plan(500, &Settings { surface: Surface::Poisson, ..auto.clone() });
        assert!(p.poisson && p.decisions.is_empty(), "{:?}", p.decisions);
        let p = plan(500, &Settings { surface: Surface::Poisson, resolution: 256, ..auto.clone() });
        assert!(p.decisions.is_empty(), "{:?}", p.decisions);
        // The solve's grid follows the points (40³ for a few thousand), so a finer mesh asks
        // no finer solve; only a cloud beyond 160k points would want more than the cap.
        let p = plan(500, &Settings { surface: Surface::Poisson, resolution: 512, ..auto.clone() });
        assert!(p.decisions.is_empty(), "{:?}", p.decisions);
        let (_, said) = surface(&Settings { surface: Surface::Poisson, resolution: 512, ..auto.clone() }, 250_000);
        assert!(said.as_deref().is_some_and(|d| d.contains("128³ grid") && d.contains("160³") && d.contains("at 512³")), "{said:?}");
        // The help that users read names the same threshold.
        let help = crate::settings::by_key("surface").unwrap().help;
        assert!(help.contains(&format!("from {POISSON_POINTS} points")), "{help}");
    }

    #[test]
    fn m_beyond_the_tuning_pairs_is_capped_and_said() {
        // `--m 5000 --tune-pairs 1000`: the tuning sees 1000 pairs, from which Z is drawn.
        let s = Settings { m: 5000, tune_pairs: Some(1000), surface: Surface::Field, ..Settings::default() };
        let p = memory_plan(3000, false, &s, &cfg(), &DeviceFacts::webgpu_default());
        assert_eq!(p.m, 1000);
        assert_eq!(p.decisions.len(), 1, "{:?}", p.decisions);
        assert!(p.decisions[0].contains("m = 1000 inducing points, not 5000") && p.decisions[0].contains("--tune-pairs 1000"), "{:?}", p.decisions);
        assert!(p.lines().iter().any(|l| l.starts_with("will use m = 1000")), "{:?}", p.lines());
        assert!(!p.lines().iter().any(|l| l.starts_with("fits:")), "{:?}", p.lines());
        // Within the pairs: as set, nothing said.
        let p = memory_plan(3000, false, &Settings { m: 800, ..s.clone() }, &cfg(), &DeviceFacts::webgpu_default());
        assert_eq!((p.m, p.decisions.len()), (800, 0));
        // Few points: the pairs themselves are the cap.
        let p = memory_plan(100, false, &Settings { m: 5000, tune_pairs: None, ..s }, &cfg(), &DeviceFacts::webgpu_default());
        let pairs = 100 * (1 + Settings::default().extra_per_point(100));
        assert_eq!(p.m, crate::field::tuning_rows(pairs, &Settings::default()));
        assert!(p.decisions[0].contains("(100 points)"), "{:?}", p.decisions);
    }

    #[test]
    fn the_tuning_rows_are_what_the_split_leaves() {
        for select_by in [crate::settings::SelectBy::HeldOut, crate::settings::SelectBy::Training] {
            for tune_pairs in [None, Some(16), Some(1000), Some(4000)] {
                let s = Settings { select_by, tune_pairs, ..Settings::default() };
                for pairs in [5, 80, 999, 4000, 5001, 12_345, 40_000] {
                    let held = if select_by == crate::settings::SelectBy::HeldOut { crate::field::HELD_OUT_MAX } else { 0 };
                    let split = crate::field::split_rows(pairs, pairs / 4, tune_pairs, held, 5);
                    let tuned = split.tune.as_ref().map_or(pairs, Vec::len);
                    assert_eq!(crate::field::tuning_rows(pairs, &s), tuned, "{select_by:?} {tune_pairs:?} {pairs}");
                }
            }
        }
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
