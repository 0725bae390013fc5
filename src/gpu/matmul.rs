//! A tiled dense matrix product: the smallest real kernel, used to prove the runtime (upload,
//! block-split dispatch, readback) against a CPU reference, and a building block for later stages.

use super::{Gpu, GpuError};

const SHADER: &str = include_str!("../../shaders/matmul.wgsl");
const TILE: u64 = 16;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Dims {
    m: u32,
    k: u32,
    n: u32,
    row0: u32,
}

/// C = A B for row-major A (m x k) and B (k x n), on the GPU.
pub async fn matmul(gpu: &Gpu, a: &[f32], b: &[f32], m: usize, k: usize, n: usize) -> Result<Vec<f32>, GpuError> {
    assert_eq!(a.len(), m * k, "A must be m x k");
    assert_eq!(b.len(), k * n, "B must be k x n");
    gpu.check_binding::<f32>("A", a.len())?;
    gpu.check_binding::<f32>("B", b.len())?;
    let out = gpu.storage::<f32>("C", m * n)?;
    let a_buf = gpu.upload("A", a);
    let b_buf = gpu.upload("B", b);
    let pipeline = gpu.compute_pipeline("matmul", SHADER, "main");

    // Row blocks: at most max_compute_workgroups_per_dimension tiles tall per dispatch.
    let max_groups = gpu.limits.max_compute_workgroups_per_dimension as u64;
    let rows_per_block = max_groups * TILE;
    let col_groups = (n as u64).div_ceil(TILE);
    if col_groups > max_groups {
        return Err(GpuError::TooLarge(format!("{n} columns need {col_groups} workgroups")));
    }
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let mut uniforms = Vec::new();
    let mut row0 = 0u64;
    while row0 < m as u64 {
        let rows = (m as u64 - row0).min(rows_per_block);
        let dims = gpu.uniform("dims", &Dims { m: m as u32, k: k as u32, n: n as u32, row0: row0 as u32 });
        let bg = gpu.bind(&pipeline, &[&a_buf, &b_buf, &out, &dims]);
        gpu.encode_pass(&mut encoder, &pipeline, &bg, [col_groups.max(1) as u32, rows.div_ceil(TILE) as u32, 1]);
        uniforms.push(dims);
        row0 += rows;
    }
    gpu.queue.submit([encoder.finish()]);
    gpu.read::<f32>(&out, m * n).await
}

/// The CPU reference, accumulated in f64.
pub fn matmul_cpu(a: &[f32], b: &[f32], m: usize, k: usize, n: usize) -> Vec<f64> {
    let mut c = vec![0.0f64; m * n];
    for i in 0..m {
        for p in 0..k {
            let aip = a[i * k + p] as f64;
            let row = &b[p * n..(p + 1) * n];
            for (cj, bj) in c[i * n..(i + 1) * n].iter_mut().zip(row) {
                *cj += aip * *bj as f64;
            }
        }
    }
    c
}
