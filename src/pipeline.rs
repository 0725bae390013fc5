//! The stages strung together: cloud → unit cube → network features → field → mesh → user
//! coordinates. Async so the browser (whose GPU readbacks resolve on its event loop) and the
//! CLI (which blocks on the same future) run one code path. Progress is reported per stage
//! through a callback that can also cancel between steps.

use std::cell::RefCell;
use std::fmt;

use crate::cloud::{subsample, CloudError, Normalization, PointCloud};
use crate::gpu::{Gpu, GpuError};
use crate::krr::{self, KrrError, LengthScaleInit, Objective, TuneSettings};
use crate::mesh::{extract_gpu_async, ExtractError, ExtractOptions, ExtractStats, FieldError, Mesh, TrimReport};
use crate::net::{GpuNet, NetError, Weights};

/// Which field the surface is the level set of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// The network prior alone: occupancy sigmoid(l(q)).
    Network,
    /// The paper's method: Nyström KRR on the network's features, tuned to the shape.
    Nkrr,
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "network" => Ok(Method::Network),
            "nkrr" => Ok(Method::Nkrr),
            _ => Err(format!("unknown method '{s}' (expected 'network' or 'nkrr')")),
        }
    }
}

/// Everything a reconstruction can be told. Defaults are the paper's where it has one.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    pub method: Method,
    /// Marching-cubes resolution over the padded unit cube (128 ≈ ConvONet's default output).
    pub resolution: u32,
    /// Drop components with fewer than this fraction of the largest one's triangles.
    pub remove_small_components: Option<f32>,
    /// The encoder sees at most this many points; larger clouds are subsampled (uniformly,
    /// seeded) with a notice. The network was trained on 500–10k points; far denser input only
    /// costs memory and time (features are pooled per plane cell, so density matters little).
    pub max_points: usize,
    /// Inducing points of the Nyström KRR (paper: 500; 1000 slightly better; 5000 overfits).
    pub m: usize,
    /// Adam steps of the test-time tuning (paper: 100; 0 = no tuning).
    pub steps: usize,
    /// Ridge parameter λ (the paper does not give it; see docs/krr.md for how it was chosen).
    pub lambda: f64,
    /// Tune the kernel length-scales (ablation "w/o θ" turns this off).
    pub tune_theta: bool,
    /// Tune the inducing points (ablation "w/o Z" turns this off).
    pub tune_z: bool,
    /// Neighbour rank whose distance scales the offsets of the extra training points.
    pub knn_k: usize,
    /// Clip the network's logits used as regression targets to [-c, c] (None: the raw logits,
    /// as in the paper). Only the sign near the surface matters for the mesh; large |logit|s far
    /// from it otherwise dominate the squared error the regression minimises. Default 4, chosen
    /// with λ on the eval clouds (docs/krr.md).
    pub label_clip: Option<f32>,
    /// Ablation "w/o features": regress on Fourier-encoded coordinates instead of the
    /// network's features (the pseudo-labels still come from the network).
    pub euclidean: bool,
    /// Where the regression's objective runs.
    pub krr_backend: KrrBackend,
    /// Open the surface where there is no data: drop triangles whose centroid is farther than
    /// `trim` × the input's mean nearest-neighbour spacing from every input point (measured on
    /// the points the network sees; see [`crate::mesh::trim`]). None (the default) keeps the
    /// mesh watertight.
    pub trim: Option<f32>,
    /// Colour the mesh's vertices from the cloud's colours, when it has them (see
    /// [`crate::mesh::colour::transfer`]).
    pub colors: bool,
    /// The cloud's length unit: the mesh is scaled to metres (glTF's unit) when given. None
    /// leaves coordinates as they are (the caller warns when they look like millimetres:
    /// [`crate::units::guess`]).
    pub units: Option<crate::units::Units>,
}

/// Where the kernel regression's objective and gradient are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KrrBackend {
    /// The GPU on real GPUs; the f64 CPU reference on software adapters (lavapipe,
    /// SwiftShader), where the GPU path's exact fixed-point Gram matrix is measured to be ~5x
    /// slower than the CPU (docs/krr.md).
    Auto,
    Gpu,
    Cpu,
}

impl KrrBackend {
    /// Whether the objective runs on the GPU, on an adapter that is (`software`) or is not a
    /// software one.
    pub fn on_gpu(self, software: bool) -> bool {
        match self {
            KrrBackend::Gpu => true,
            KrrBackend::Cpu => false,
            KrrBackend::Auto => !software,
        }
    }
}

impl std::str::FromStr for KrrBackend {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(KrrBackend::Auto),
            "gpu" => Ok(KrrBackend::Gpu),
            "cpu" => Ok(KrrBackend::Cpu),
            _ => Err(format!("unknown backend '{s}' (expected auto, gpu or cpu)")),
        }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            method: Method::Nkrr,
            resolution: 128,
            remove_small_components: None,
            max_points: 100_000,
            m: 500,
            steps: 100,
            lambda: 1e-5,
            tune_theta: true,
            tune_z: true,
            knn_k: crate::sample::DEFAULT_K,
            label_clip: Some(4.0),
            euclidean: false,
            krr_backend: KrrBackend::Auto,
            trim: None,
            colors: true,
            units: None,
        }
    }
}

/// A stage of the pipeline, as reported to the progress callback.
#[derive(Clone, Debug, PartialEq)]
pub enum Stage {
    Features,
    /// Training pairs: extra points sampled and labelled by the network.
    Pairs,
    /// Test-time tuning: `step` of at most `of`, with the objective's value.
    Tuning { step: usize, of: usize, loss: f64 },
    /// Field evaluations made so far while meshing.
    Meshing { evaluated: usize },
    Done,
}

/// What went wrong, in words a user can act on.
#[derive(Debug)]
pub enum PipelineError {
    Cloud(CloudError),
    Gpu(GpuError),
    Net(NetError),
    Mesh(ExtractError),
    Krr(KrrError),
    Cancelled,
}

impl fmt::Display for PipelineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PipelineError::Cloud(e) => write!(f, "{e}"),
            PipelineError::Gpu(e) => write!(f, "{e}"),
            PipelineError::Net(e) => write!(f, "the network prior could not be loaded: {e}"),
            PipelineError::Mesh(e) => write!(f, "mesh extraction failed: {e}"),
            PipelineError::Krr(e) => write!(f, "the kernel regression failed: {e}"),
            PipelineError::Cancelled => write!(f, "cancelled"),
        }
    }
}

impl std::error::Error for PipelineError {}

impl From<GpuError> for PipelineError {
    fn from(e: GpuError) -> Self {
        PipelineError::Gpu(e)
    }
}

/// The result: the mesh, what happened, and how long each stage took.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    /// In the cloud's coordinates: user coordinates are `origin + position`.
    pub mesh: Mesh,
    /// The cloud's [`PointCloud::origin`]: zero unless the reader moved a far-off cloud near 0.
    pub origin: [f64; 3],
    /// What trimming removed, when [`Settings::trim`] asked for it (its spacing and threshold
    /// are in the network's unit cube: times the cloud's longest side for the cloud's units).
    pub trim: Option<TrimReport>,
    pub notices: Vec<String>,
    pub extract: ExtractStats,
    /// What the test-time tuning did (nkrr only).
    pub tuning: Option<TuningSummary>,
    /// (stage, seconds).
    pub timings: Vec<(&'static str, f64)>,
}

impl Reconstruction {
    /// The origin as a glTF root translation ([`crate::io::gltf::GlbOptions::translation`]),
    /// or None when it is zero.
    pub fn translation(&self) -> Option<[f64; 3]> {
        (self.origin != [0.0; 3]).then_some(self.origin)
    }

    /// The mesh's vertex positions in user coordinates, in f64.
    pub fn positions_f64(&self) -> Vec<[f64; 3]> {
        self.mesh.positions.iter().map(|p| [0, 1, 2].map(|a| p[a] as f64 + self.origin[a])).collect()
    }
}

/// What the kernel regression's tuning did, for reports and benchmarks.
#[derive(Clone, Debug)]
pub struct TuningSummary {
    /// "gpu" or "cpu": where the objective ran.
    pub backend: &'static str,
    pub n: usize,
    pub m: usize,
    pub steps_run: usize,
    pub best_step: usize,
    pub stop: String,
    pub initial_loss: f64,
    pub final_loss: f64,
    pub initial_data_fit: f64,
    pub best_data_fit: f64,
    pub length_scales: Vec<f64>,
    /// Objective evaluations (the initial one included) and their summed phase times, when the
    /// objective ran on the GPU.
    pub evaluations: usize,
    pub phases: Option<krr::PhaseTimings>,
}

/// The fitted regression: g(x) = Σ_j β_j k(x, z_j) on feature vectors x.
struct KrrFit {
    params: krr::Params,
    beta: Vec<f64>,
    euclidean: bool,
    /// The GPU predictor when the regression ran on the GPU; else the f64 CPU one is used.
    predictor: Option<krr::GpuPredictor>,
}

impl KrrFit {
    async fn predict(&self, features: &[f32]) -> Result<Vec<f32>, String> {
        match &self.predictor {
            Some(p) => p.predict(&self.beta, &self.params.z, &self.params.log_s, features).await.map_err(|e| e.to_string()),
            None => {
                let x: Vec<f64> = features.iter().map(|&v| v as f64).collect();
                krr::predict(&self.beta, &self.params.z, &self.params.log_s, &x)
                    .map(|g| g.into_iter().map(|v| v as f32).collect())
                    .map_err(|e| e.to_string())
            }
        }
    }
}

/// Frequencies of the coordinate encoding used by the "w/o features" ablation: x, and
/// sin/cos(2^k π x) for k < FOURIER_OCTAVES, per axis (3 + 6·5 = 33 dimensions).
pub const FOURIER_OCTAVES: usize = 5;

/// The regression's input for the "w/o features" ablation.
pub fn fourier_encode(points: &[[f32; 3]]) -> Vec<f32> {
    let mut out = Vec::with_capacity(points.len() * (3 + 6 * FOURIER_OCTAVES));
    for p in points {
        out.extend_from_slice(p);
        for k in 0..FOURIER_OCTAVES {
            let w = std::f32::consts::PI * (1u32 << k) as f32;
            for &x in p {
                out.push((w * x).sin());
                out.push((w * x).cos());
            }
        }
    }
    out
}

/// Seconds since an arbitrary origin; `Instant` does not exist on wasm32-unknown-unknown.
pub fn now() -> f64 {
    #[cfg(target_arch = "wasm32")]
    {
        js_sys::Date::now() / 1000.0
    }
    #[cfg(not(target_arch = "wasm32"))]
    {
        use std::sync::OnceLock;
        use std::time::Instant;
        static T0: OnceLock<Instant> = OnceLock::new();
        T0.get_or_init(Instant::now).elapsed().as_secs_f64()
    }
}

/// The GPU-resident parts that outlive one reconstruction (weights uploaded once).
pub struct Engine {
    pub gpu: Gpu,
    pub net: GpuNet,
}

impl Engine {
    /// Uploads the built-in network prior to `gpu`.
    pub async fn new(gpu: Gpu) -> Result<Engine, PipelineError> {
        let weights = Weights::prior().map_err(PipelineError::Net)?;
        let net = GpuNet::new(&gpu, &weights).await?;
        Ok(Engine { gpu, net })
    }

    /// The memory each stage will take for a cloud of `points` points on this engine's
    /// adapter, and what will be changed to fit (see [`crate::plan`]).
    pub fn memory_plan(&self, points: usize, colours: bool, settings: &Settings) -> crate::plan::MemoryPlan {
        crate::plan::memory_plan(points, colours, settings, self.net.config(), &crate::plan::DeviceFacts::of(&self.gpu))
    }

    /// Reconstructs `cloud`. `progress` is called at each stage and during meshing; returning
    /// false cancels at the next step.
    pub async fn reconstruct(
        &self,
        cloud: &PointCloud,
        settings: &Settings,
        progress: &mut dyn FnMut(&Stage) -> bool,
    ) -> Result<Reconstruction, PipelineError> {
        let mut timings = Vec::new();
        let mut notices = Vec::new();
        let norm = Normalization::of(cloud).map_err(PipelineError::Cloud)?;
        // The preflight's plan decides how many points and inducing points fit this adapter
        // (and, in the browser, the host budget); its actions become notices.
        let plan = self.memory_plan(cloud.len(), cloud.colors.is_some(), settings);
        notices.extend(plan.actions.iter().map(|a| format!("to fit in memory, nkrr will {a}")));
        let settings = &Settings { max_points: plan.n.min(settings.max_points), m: plan.m.max(1), ..settings.clone() };
        let mut points: Vec<[f32; 3]> = cloud.positions.iter().map(|p| norm.forward(*p)).collect();
        if points.len() > settings.max_points {
            notices.push(format!(
                "the cloud has {} points; the network sees a uniform subsample of {}",
                points.len(),
                settings.max_points
            ));
            points = subsample(&points, settings.max_points, 1);
        }

        if !progress(&Stage::Features) {
            return Err(PipelineError::Cancelled);
        }
        let t = now();
        let planes = self.net.encode(&points).await?;
        self.net.wait();
        timings.push(("features", now() - t));

        let mut tuning = None;
        let fit = if settings.method == Method::Nkrr {
            if !progress(&Stage::Pairs) {
                return Err(PipelineError::Cancelled);
            }
            let t = now();
            let (problem, n_surface) = self.training_pairs(&planes, &points, settings).await?;
            timings.push(("pairs", now() - t));
            let t = now();
            let (fit, summary) = fit_krr(&self.gpu, &problem, settings, progress).await?;
            timings.push(("tuning", now() - t));
            let _ = n_surface;
            tuning = Some(summary);
            Some(fit)
        } else {
            None
        };

        let t = now();
        let opts = ExtractOptions {
            resolution: settings.resolution,
            remove_small_components: settings.remove_small_components,
            ..Default::default()
        };
        let evaluated = RefCell::new(0usize);
        let cancelled = RefCell::new(false);
        let progress = RefCell::new(progress);
        let net = &self.net;
        let planes = &planes;
        let fit = fit.as_ref();
        let eval = |pts: Vec<[f32; 3]>| {
            let evaluated = &evaluated;
            let cancelled = &cancelled;
            let progress = &progress;
            async move {
                *evaluated.borrow_mut() += pts.len();
                if !(progress.borrow_mut())(&Stage::Meshing { evaluated: *evaluated.borrow() }) {
                    *cancelled.borrow_mut() = true;
                    return Err(FieldError("cancelled".into()));
                }
                let (features, logits) = net.decode(planes, &pts).await.map_err(|e| FieldError(e.to_string()))?;
                match fit {
                    None => Ok(logits),
                    Some(fit) => {
                        let features = if fit.euclidean { fourier_encode(&pts) } else { features };
                        fit.predict(&features).await.map_err(FieldError)
                    }
                }
            }
        };
        let extraction = extract_gpu_async(&self.gpu, eval, &opts).await;
        if *cancelled.borrow() {
            return Err(PipelineError::Cancelled);
        }
        let extraction = extraction.map_err(PipelineError::Mesh)?;
        timings.push(("mesh", now() - t));

        let mut mesh = extraction.mesh;
        // Trimmed in the unit cube, against the points the network saw.
        let trim = settings.trim.map(|factor| {
            let t = now();
            let r = crate::mesh::trim(&mut mesh, &points, factor);
            timings.push(("trim", now() - t));
            notices.push(format!(
                "trimmed {} triangles farther than {factor} x the mean point spacing from the input",
                r.triangles_removed
            ));
            r
        });
        for p in &mut mesh.positions {
            *p = norm.inverse(*p);
        }
        if settings.colors && cloud.colors.is_some() {
            let t = now();
            crate::mesh::colour::transfer(&mut mesh, cloud, crate::mesh::colour::DEFAULT_K);
            timings.push(("colours", now() - t));
        }
        // Units last: every stage above works in the cloud's own coordinates (the network's
        // normalisation makes the scale irrelevant to it), and a similarity keeps normals.
        let mut origin = cloud.origin;
        if let Some(u) = settings.units.filter(|u| u.metres() != 1.0) {
            let s = u.metres();
            for p in &mut mesh.positions {
                *p = p.map(|c| (c as f64 * s) as f32);
            }
            origin = origin.map(|c| c * s);
        }
        (progress.borrow_mut())(&Stage::Done);
        Ok(Reconstruction { mesh, origin, trim, notices, extract: extraction.stats, tuning, timings })
    }

    /// X = F([P, P~]), y = [0, l(P~)] (paper eq. 6): the input points lie on the surface
    /// (logit 0), the extra points take the network's logit as a pseudo-label.
    async fn training_pairs(
        &self,
        planes: &crate::net::GpuPlanes,
        points: &[[f32; 3]],
        settings: &Settings,
    ) -> Result<(krr::Problem, usize), PipelineError> {
        let extra = crate::sample::upsample(points, settings.knn_k, 2);
        let mut all = points.to_vec();
        all.extend_from_slice(&extra);
        let (features, logits) = self.net.decode(planes, &all).await?;
        let clip = settings.label_clip.unwrap_or(f32::INFINITY);
        let y: Vec<f32> =
            logits.iter().enumerate().map(|(i, &l)| if i < points.len() { 0.0 } else { l.clamp(-clip, clip) }).collect();
        let (x, d) = if settings.euclidean {
            (fourier_encode(&all), 3 + 6 * FOURIER_OCTAVES)
        } else {
            (features, self.net.config().c_dim)
        };
        let problem = krr::Problem::from_f32(&x, &y, d).map_err(PipelineError::Krr)?;
        Ok((problem, points.len()))
    }
}

/// Initialises (Z from rows of X, length-scales from the features' spread) and tunes the
/// Nyström KRR, keeping the parameters with the lowest training error (method.md §4).
async fn fit_krr(
    gpu: &Gpu,
    problem: &krr::Problem,
    settings: &Settings,
    progress: &mut dyn FnMut(&Stage) -> bool,
) -> Result<(KrrFit, TuningSummary), PipelineError> {
    let m = settings.m.clamp(1, problem.n());
    let init = krr::init_params(problem, m, 3, LengthScaleInit::default());
    let ks = krr::Settings::new(settings.lambda, m);
    let ts = TuneSettings {
        steps: settings.steps,
        tune_theta: settings.tune_theta,
        tune_z: settings.tune_z,
        ..Default::default()
    };
    let on_gpu = settings.krr_backend.on_gpu(gpu.is_software());
    let of = settings.steps;
    let report = |step: usize, eval: &krr::Eval| progress(&Stage::Tuning { step, of, loss: eval.loss });
    let (initial, result, predictor, (evaluations, phases)) = if on_gpu {
        let objective = krr::GpuObjective::new(gpu, problem, ks).await.map_err(|e| PipelineError::Krr(e.into()))?;
        let objective = RefCell::new(objective);
        let initial = objective.borrow_mut().eval_async(&init).await.map_err(|e| PipelineError::Krr(e.into()))?;
        let evaluate = |params: krr::Params, needs_grad: bool| {
            let objective = &objective;
            async move { objective.borrow_mut().evaluate(&params, needs_grad).await }
        };
        let result = krr::tune_async(evaluate, init, &ts, report).await.map_err(PipelineError::Krr)?;
        let objective = objective.into_inner();
        let phases = (objective.evaluations, Some(objective.total_timings));
        (initial, result, Some(objective.predictor().clone()), phases)
    } else {
        let mut objective = krr::Reference { problem, settings: ks };
        let initial = objective.eval(&init).map_err(PipelineError::Krr)?;
        let result = krr::tune(&mut objective, init, &ts, report).map_err(PipelineError::Krr)?;
        let evaluations = result.history.len() + 1;
        (initial, result, None, (evaluations, None))
    };
    if matches!(result.stop, krr::StopReason::Cancelled) {
        return Err(PipelineError::Cancelled);
    }
    let summary = TuningSummary {
        backend: if on_gpu { "gpu" } else { "cpu" },
        n: problem.n(),
        m,
        steps_run: result.history.len().saturating_sub(1),
        best_step: result.best_step,
        stop: format!("{:?}", result.stop),
        initial_loss: initial.loss,
        final_loss: result.history.last().map_or(initial.loss, |h| h.loss),
        initial_data_fit: initial.data_fit,
        best_data_fit: result.eval.data_fit,
        length_scales: result.params.length_scales(),
        evaluations,
        phases,
    };
    let fit = KrrFit { beta: result.eval.beta, params: result.params, euclidean: settings.euclidean, predictor };
    Ok((fit, summary))
}
