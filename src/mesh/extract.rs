//! Mesh extraction end to end: coarse-to-fine search ([`super::refine`]) → marching cubes (CPU
//! or GPU) → optional small-component removal → area-weighted vertex normals.
//!
//! Blocking drivers take a [`Field`]; the `_async` drivers take a closure returning a future of
//! the values (the browser's GPU readback is asynchronous). Both drive the same
//! [`Refiner`] state machine, so they make the same evaluations and the same mesh.

use std::future::Future;

use super::components::{remove_small_components, triangle_components, Removal};
use super::marching_cubes::polygonize;
use super::marching_cubes_gpu::MarchingCubesGpu;
use super::refine::{ActiveCells, ExtractError, ExtractOptions, Field, FieldError, RefineStats, Refiner};
use super::types::Mesh;
use crate::gpu::Gpu;

/// The extracted mesh and what it took.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Extraction {
    /// In the domain's coordinates, welded, watertight (every component found is closed),
    /// counter-clockwise seen from outside, with outward unit normals.
    pub mesh: Mesh,
    pub stats: ExtractStats,
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExtractStats {
    pub refine: RefineStats,
    /// Triangles marching cubes made (before small components were removed).
    pub triangles_extracted: usize,
    pub removal: Removal,
    /// True when marching cubes ran on the GPU.
    pub gpu: bool,
}

/// The coarse-to-fine search with a blocking field.
pub fn refine<F: Field + ?Sized>(
    field: &mut F,
    opts: &ExtractOptions,
) -> Result<(ActiveCells, RefineStats), ExtractError> {
    let mut r = Refiner::new(opts)?;
    while let Some(points) = r.pending() {
        let values = field.eval(points)?;
        r.supply(&values)?;
    }
    r.finish()
}

/// The coarse-to-fine search with an asynchronous field: `eval(points)` resolves to their
/// values.
pub async fn refine_async<E, Fut>(
    mut eval: E,
    opts: &ExtractOptions,
) -> Result<(ActiveCells, RefineStats), ExtractError>
where
    E: FnMut(Vec<[f32; 3]>) -> Fut,
    Fut: Future<Output = Result<Vec<f32>, FieldError>>,
{
    let mut r = Refiner::new(opts)?;
    while let Some(points) = r.pending() {
        let values = eval(points.to_vec()).await?;
        r.supply(&values)?;
    }
    r.finish()
}

/// The steps after marching cubes: small-component removal (if asked) and vertex normals. The
/// components are counted either way (a report of 0 pieces for a mesh would be wrong).
pub fn postprocess(mut mesh: Mesh, opts: &ExtractOptions) -> (Mesh, Removal) {
    let removal = match opts.remove_small_components {
        Some(f) => remove_small_components(&mut mesh, f),
        None => Removal { components: triangle_components(&mesh).1.len(), ..Removal::default() },
    };
    mesh.compute_vertex_normals();
    (mesh, removal)
}

fn assemble(mesh: Mesh, refine: RefineStats, opts: &ExtractOptions, gpu: bool) -> Extraction {
    let triangles_extracted = mesh.triangle_count();
    let (mesh, removal) = postprocess(mesh, opts);
    Extraction { mesh, stats: ExtractStats { refine, triangles_extracted, removal, gpu } }
}

/// Extracts the 0 level of `field` (INSIDE where `> 0`), marching cubes on the CPU.
pub fn extract<F: Field + ?Sized>(field: &mut F, opts: &ExtractOptions) -> Result<Extraction, ExtractError> {
    let (cells, stats) = refine(field, opts)?;
    Ok(assemble(polygonize(&cells), stats, opts, false))
}

/// [`extract`] with an asynchronous field.
pub async fn extract_async<E, Fut>(eval: E, opts: &ExtractOptions) -> Result<Extraction, ExtractError>
where
    E: FnMut(Vec<[f32; 3]>) -> Fut,
    Fut: Future<Output = Result<Vec<f32>, FieldError>>,
{
    let (cells, stats) = refine_async(eval, opts).await?;
    Ok(assemble(polygonize(&cells), stats, opts, false))
}

/// [`extract`] with marching cubes on the GPU (the search itself is on the CPU, driving the
/// field). The mesh is the CPU path's up to float rounding of the positions.
pub async fn extract_gpu_async<E, Fut>(gpu: &Gpu, eval: E, opts: &ExtractOptions) -> Result<Extraction, ExtractError>
where
    E: FnMut(Vec<[f32; 3]>) -> Fut,
    Fut: Future<Output = Result<Vec<f32>, FieldError>>,
{
    let (cells, stats) = refine_async(eval, opts).await?;
    let mesh = MarchingCubesGpu::new(gpu).polygonize(gpu, &cells).await?;
    Ok(assemble(mesh, stats, opts, true))
}

/// Blocking [`extract_gpu_async`] for native code.
#[cfg(not(target_arch = "wasm32"))]
pub fn extract_gpu<F: Field + ?Sized>(
    gpu: &Gpu,
    field: &mut F,
    opts: &ExtractOptions,
) -> Result<Extraction, ExtractError> {
    let (cells, stats) = refine(field, opts)?;
    let mesh = pollster::block_on(MarchingCubesGpu::new(gpu).polygonize(gpu, &cells))?;
    Ok(assemble(mesh, stats, opts, true))
}
