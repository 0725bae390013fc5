//! The stages strung together: cloud → unit cube → network features → field → mesh → user
//! coordinates. Async so the browser (whose GPU readbacks resolve on its event loop) and the
//! CLI (which blocks on the same future) run one code path. Progress is reported per stage
//! through a callback that can also cancel between steps.

use std::cell::RefCell;
use std::fmt;

use crate::cloud::{subsample, CloudError, Normalization, PointCloud};
use crate::gpu::{Gpu, GpuError};
use crate::mesh::{extract_gpu_async, ExtractError, ExtractOptions, ExtractStats, FieldError, Mesh};
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
}

impl Default for Settings {
    fn default() -> Self {
        Settings { method: Method::Network, resolution: 128, remove_small_components: None, max_points: 100_000 }
    }
}

/// A stage of the pipeline, as reported to the progress callback.
#[derive(Clone, Debug, PartialEq)]
pub enum Stage {
    Features,
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
    NotAvailable(String),
    Cancelled,
}

impl fmt::Display for PipelineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PipelineError::Cloud(e) => write!(f, "{e}"),
            PipelineError::Gpu(e) => write!(f, "{e}"),
            PipelineError::Net(e) => write!(f, "the network prior could not be loaded: {e}"),
            PipelineError::Mesh(e) => write!(f, "mesh extraction failed: {e}"),
            PipelineError::NotAvailable(s) => write!(f, "{s}"),
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

/// The result: the mesh in the user's coordinates, what happened, and how long each stage took.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    pub mesh: Mesh,
    pub notices: Vec<String>,
    pub extract: ExtractStats,
    /// (stage, seconds).
    pub timings: Vec<(&'static str, f64)>,
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

    /// Reconstructs `cloud`. `progress` is called at each stage and during meshing; returning
    /// false cancels at the next step.
    pub async fn reconstruct(
        &self,
        cloud: &PointCloud,
        settings: &Settings,
        progress: &mut dyn FnMut(&Stage) -> bool,
    ) -> Result<Reconstruction, PipelineError> {
        if settings.method == Method::Nkrr {
            return Err(PipelineError::NotAvailable(
                "method 'nkrr' is not implemented yet in this build; use --method network".into(),
            ));
        }
        let mut timings = Vec::new();
        let mut notices = Vec::new();
        let norm = Normalization::of(cloud).map_err(PipelineError::Cloud)?;
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
                net.decode(planes, &pts).await.map(|(_, logits)| logits).map_err(|e| FieldError(e.to_string()))
            }
        };
        let extraction = extract_gpu_async(&self.gpu, eval, &opts).await;
        if *cancelled.borrow() {
            return Err(PipelineError::Cancelled);
        }
        let extraction = extraction.map_err(PipelineError::Mesh)?;
        timings.push(("mesh", now() - t));

        let mut mesh = extraction.mesh;
        for p in &mut mesh.positions {
            *p = norm.inverse(*p);
        }
        (progress.borrow_mut())(&Stage::Done);
        Ok(Reconstruction { mesh, notices, extract: extraction.stats, timings })
    }
}
