//! What a reconstruction returns: the mesh in the cloud's coordinates and what each stage did
//! ([`crate::pipeline`] makes it; [`crate::scene`] adds its tiles' report), or what went wrong.

use std::fmt;

use crate::cloud::CloudError;
use crate::field::{FitError, TuningSummary};
use crate::gpu::GpuError;
use crate::krr::KrrError;
use crate::mesh::fit::FitReport;
use crate::mesh::{ExtractError, ExtractStats, Mesh, TrimReport};
use crate::net::NetError;
use crate::settings::Method;

/// The result: the mesh, what happened, and how long each stage took.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    /// In the cloud's coordinates: user coordinates are `origin + position`.
    pub mesh: Mesh,
    /// The cloud's [`crate::PointCloud::origin`]: zero unless the reader moved a far-off cloud near 0.
    pub origin: [f64; 3],
    /// What the last fit to the points did, when [`crate::settings::Settings::fit`] asked for it.
    pub fit: Option<FitReport>,
    /// What trimming removed, when [`crate::settings::Settings::trim`] asked for it (its spacing and threshold
    /// are in the network's unit cube: times the cloud's longest side for the cloud's units).
    pub trim: Option<TrimReport>,
    /// What the simplification did, when [`crate::settings::Settings::triangles`] or [`crate::settings::Settings::max_error`] asked for it.
    pub simplify: Option<crate::mesh::simplify::SimplifyReport>,
    pub notices: Vec<String>,
    /// What the user must not miss (a filter that took a large share of the points).
    pub warnings: Vec<String>,
    pub extract: ExtractStats,
    /// What the test-time tuning did (nkrr only).
    pub tuning: Option<TuningSummary>,
    /// (stage, seconds).
    pub timings: Vec<(&'static str, f64)>,
    /// (stage, bytes): the most buffer memory each stage held on the device beyond what the
    /// engine held before the reconstruction, named as the plan names its stages; empty where
    /// the device does not count its memory (see [`crate::gpu::ledger`]).
    pub gpu_peaks: Vec<(&'static str, u64)>,
    /// A scene's tiles and its blend's size ([`crate::scene`]); None for one object.
    pub scene: Option<SceneReport>,
}

/// What a scene's sweep did ([`crate::scene`]), for the report and the tests.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneReport {
    pub tiles: usize,
    /// Band nodes blended, in all.
    pub nodes: usize,
    /// The most band nodes held at once: the sweep's front.
    pub peak_nodes: usize,
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

/// What went wrong, in words a user can act on.
#[derive(Debug)]
pub enum PipelineError {
    Cloud(CloudError),
    Gpu(GpuError),
    Net(NetError),
    Mesh(ExtractError),
    Krr(KrrError),
    /// The field has no inside anywhere in the domain: there is no surface to mesh.
    NoSurface { evaluations: u64, field_max: f32, method: Method },
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
            PipelineError::NoSurface { evaluations, field_max, method } => {
                let (who, hint) = match method {
                    Method::Nkrr => ("NKRR", "; the network alone (--method network) may still find one"),
                    Method::Network => ("the network", ""),
                };
                write!(f, "no surface found: the field ({who}) is at or below 0, outside, at all {evaluations} points evaluated \
                 (largest value {field_max:.3}), so nothing is inside anywhere. The prior sees the cloud as no \
                 closed object: a flat patch, a sparse or scattered cloud, or a scene larger than one object{hint}")
            }
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

impl From<FitError> for PipelineError {
    fn from(e: FitError) -> Self {
        match e {
            FitError::Gpu(e) => PipelineError::Gpu(e),
            FitError::Krr(e) => PipelineError::Krr(e),
            FitError::Cancelled => PipelineError::Cancelled,
        }
    }
}
