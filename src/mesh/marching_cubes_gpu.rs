//! Marching cubes on the GPU (`shaders/marching_cubes.wgsl`): the same triangle soup as the CPU
//! reference [`super::marching_cubes::soup`], in the same order.
//!
//! Per block of active cells: `classify` (case and triangle count per cell) → read the counts
//! back, exclusive prefix sum on the CPU (deterministic offsets, so the output order is the
//! cell order) → `emit` (each cell writes its triangles at its offset) → read the soup back.
//! Welding by edge key is done on the CPU after readback ([`super::marching_cubes::weld`], a
//! hash map): the soup is small next to the field evaluations, and this keeps the vertex order
//! identical to the CPU path's.

use super::marching_cubes::weld;
use super::refine::ActiveCells;
use super::tables::CaseTable;
use super::types::Mesh;
use crate::gpu::{Footprint, Gpu, GpuError};

const SHADER: &str = include_str!("../../shaders/marching_cubes.wgsl");
const WG: u32 = 64;

/// Binding indices of `shaders/marching_cubes.wgsl` (its `@group(0) @binding(N)` declarations;
/// keep the two in step).
mod at {
    pub const PARAMS: u32 = 0;
    pub const VALUES: u32 = 1;
    pub const TABLE: u32 = 2;
    pub const CLASSES: u32 = 3;
    pub const CELLS: u32 = 4;
    pub const OFFSETS: u32 = 5;
    pub const SOUP: u32 = 6;
}

/// The largest resolution the GPU kernels take: edge keys `3 (R+1)³` must fit 32 bits.
pub const GPU_MAX_RESOLUTION: u32 = 1124;

/// What [`polygonize_gpu`] allocates for `active` active cells when bindings are at most
/// `binding` bytes: it tiles the cells so that the triangle soup (240 bytes a cell: five
/// triangles of three f32 vertices and their keys) fits one binding; per tile the cells'
/// values, classes and offsets (52 bytes a cell), the soup and its readback copy, and the
/// uniforms and case table (16 KiB).
pub fn footprint(active: u64, binding: u64) -> Footprint {
    let tile = active.min(binding / 240).max(1);
    Footprint { gpu: 16_384 + 52 * tile + 96 * tile, largest: 240 * tile, host: 0 }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    n_cells: u32,
    resolution: u32,
    stride: u32,
    _pad: u32,
    lo: [f32; 4],
    ext: [f32; 4],
}

/// The compiled kernels and the case table on the device; build once, use for many meshes.
pub struct MarchingCubesGpu {
    classify: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
    table: wgpu::Buffer,
    stride: u32,
    max_triangles: usize,
}

impl MarchingCubesGpu {
    pub fn new(gpu: &Gpu) -> MarchingCubesGpu {
        let t = CaseTable::get();
        MarchingCubesGpu {
            classify: gpu.compute_pipeline("marching_cubes.classify", SHADER, "classify"),
            emit: gpu.compute_pipeline("marching_cubes.emit", SHADER, "emit"),
            table: gpu.upload("marching_cubes.table", &t.gpu_words()),
            stride: t.gpu_stride() as u32,
            max_triangles: t.max_triangles,
        }
    }

    /// The triangle soup (keys, positions; three per triangle) of `cells`.
    pub async fn soup(&self, gpu: &Gpu, cells: &ActiveCells) -> Result<(Vec<u64>, Vec<[f32; 3]>), GpuError> {
        if cells.resolution > GPU_MAX_RESOLUTION {
            return Err(GpuError::TooLarge(format!(
                "marching cubes on the GPU takes resolution <= {GPU_MAX_RESOLUTION}, not {}",
                cells.resolution
            )));
        }
        assert_eq!(cells.cells.len(), cells.values.len());
        // Blocks small enough that the values and the worst-case soup fit one binding each.
        let per_cell_out = (3 * 4 * 4 * self.max_triangles.max(1)) as u64;
        let block = gpu.rows_per_binding(32).min(gpu.rows_per_binding(per_cell_out)).max(1);
        let (lo, hi) = cells.domain;
        let mut keys = Vec::new();
        let mut positions = Vec::new();
        let mut base = 0usize;
        while base < cells.len() {
            let n = (cells.len() - base).min(block);
            let params = Params {
                n_cells: n as u32,
                resolution: cells.resolution,
                stride: self.stride,
                _pad: 0,
                lo: [lo[0], lo[1], lo[2], 0.0],
                ext: [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 0.0],
            };
            let params = gpu.uniform("marching_cubes.params", &params);
            let values = gpu.upload("marching_cubes.values", &cells.values[base..base + n]);
            let coords = gpu.upload("marching_cubes.cells", &cells.cells[base..base + n]);
            let classes = gpu.storage::<u32>("marching_cubes.classes", n)?;
            let groups = gpu.dispatch_linear(n as u64, WG)?;

            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            let bg = gpu.bind_at(
                &self.classify,
                &[(at::PARAMS, &params), (at::VALUES, &values), (at::TABLE, &self.table), (at::CLASSES, &classes)],
            );
            gpu.encode_pass(&mut encoder, &self.classify, &bg, groups);
            gpu.queue.submit([encoder.finish()]);
            let counts: Vec<u32> = gpu.read(&classes, n).await?;

            let mut offsets = Vec::with_capacity(n);
            let mut total = 0u64;
            for c in &counts {
                offsets.push(total as u32);
                total += (c >> 8) as u64;
            }
            if total > 0 {
                let words = (total * 12) as usize;
                let soup = gpu.storage::<u32>("marching_cubes.soup", words)?;
                let offsets = gpu.upload("marching_cubes.offsets", &offsets);
                let mut encoder = gpu.device.create_command_encoder(&Default::default());
                let bg = gpu.bind_at(
                    &self.emit,
                    &[
                        (at::PARAMS, &params),
                        (at::VALUES, &values),
                        (at::TABLE, &self.table),
                        (at::CLASSES, &classes),
                        (at::CELLS, &coords),
                        (at::OFFSETS, &offsets),
                        (at::SOUP, &soup),
                    ],
                );
                gpu.encode_pass(&mut encoder, &self.emit, &bg, groups);
                gpu.queue.submit([encoder.finish()]);
                let out: Vec<u32> = gpu.read(&soup, words).await?;
                keys.reserve(words / 4);
                positions.reserve(words / 4);
                for w in out.chunks_exact(4) {
                    keys.push(w[0] as u64);
                    positions.push([f32::from_bits(w[1]), f32::from_bits(w[2]), f32::from_bits(w[3])]);
                }
            }
            base += n;
        }
        Ok((keys, positions))
    }

    /// Marching cubes on the GPU: the welded mesh of the active cells (no normals).
    pub async fn polygonize(&self, gpu: &Gpu, cells: &ActiveCells) -> Result<Mesh, GpuError> {
        let (keys, positions) = self.soup(gpu, cells).await?;
        Ok(weld(&keys, &positions))
    }
}

/// Marching cubes on the GPU (compiles the kernels each call; keep a [`MarchingCubesGpu`] to
/// reuse them).
pub async fn polygonize_gpu(gpu: &Gpu, cells: &ActiveCells) -> Result<Mesh, GpuError> {
    MarchingCubesGpu::new(gpu).polygonize(gpu, cells).await
}

/// Blocking [`polygonize_gpu`] for native code.
#[cfg(not(target_arch = "wasm32"))]
pub fn polygonize_gpu_blocking(gpu: &Gpu, cells: &ActiveCells) -> Result<Mesh, GpuError> {
    pollster::block_on(polygonize_gpu(gpu, cells))
}
