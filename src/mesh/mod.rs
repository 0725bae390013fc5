//! The triangle mesh the pipeline produces and `io::gltf` writes, and its extraction from an
//! implicit field: coarse-to-fine marching cubes on the CPU ([`marching_cubes`]) or the GPU
//! ([`marching_cubes_gpu`]); see [`extract`] for the entry points and [`refine`] for the search.

pub mod colour;
pub mod components;
pub mod extract;
pub mod finish;
pub mod fit;
pub mod marching_cubes;
pub mod marching_cubes_gpu;
pub mod refine;
pub mod sheets;
pub mod simplify;
pub mod tables;
pub mod trim;
mod types;

pub use components::{remove_small_components, remove_unsupported_components, triangle_components, Removal};
#[cfg(not(target_arch = "wasm32"))]
pub use extract::extract_gpu;
pub use extract::{extract, extract_async, extract_gpu_async, postprocess, refine_async, ExtractStats, Extraction};
pub use marching_cubes::polygonize;
pub use marching_cubes_gpu::{polygonize_gpu, MarchingCubesGpu};
pub use trim::{retain_triangles, trim, TrimReport};
pub use refine::{ActiveCells, ExtractError, ExtractOptions, Field, FieldError, Plan, RefineStats, Refiner};
pub use types::{area_weighted_normals, Mesh, FALLBACK_NORMAL};
pub(crate) use types::normalize_f64;
