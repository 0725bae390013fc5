//! The GPU runtime against CPU references, on whatever adapter is present (lavapipe in CI).

use nkrr::gpu::Gpu;

/// A tiled dense matrix product (`tests/shaders/matmul.wgsl`): the smallest real kernel, used to
/// prove the runtime (upload, block-split dispatch, readback) against a CPU reference.
mod matmul {
    use nkrr::gpu::{Gpu, GpuError};

    const SHADER: &str = include_str!("shaders/matmul.wgsl");
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
}

fn gpu() -> Gpu {
    // No silent skip: a missing adapter is a failed test with instructions.
    Gpu::new_blocking().unwrap_or_else(|e| {
        panic!("{e}\nInstall Mesa's software Vulkan (scripts/setup.sh apt) to run GPU tests without a GPU.")
    })
}

fn lcg(seed: &mut u64) -> f32 {
    *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    ((*seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
}

fn check(gpu: &Gpu, m: usize, k: usize, n: usize, seed: u64) {
    let mut s = seed;
    let a: Vec<f32> = (0..m * k).map(|_| lcg(&mut s)).collect();
    let b: Vec<f32> = (0..k * n).map(|_| lcg(&mut s)).collect();
    let got = pollster::block_on(matmul::matmul(gpu, &a, &b, m, k, n)).unwrap();
    let want = matmul::matmul_cpu(&a, &b, m, k, n);
    // f32 accumulation of k products of magnitude <= 1: error grows like sqrt(k) * eps.
    let tol = 1e-5 * (k as f64).max(1.0);
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert!(((*g as f64) - w).abs() <= tol, "C[{i}] = {g}, want {w} ({m}x{k}x{n})");
    }
}

#[test]
fn adapter_reports_limits() {
    let gpu = gpu();
    let text = gpu.describe();
    eprintln!("adapter: {text}");
    assert!(text.contains("max storage binding"));
    assert!(gpu.limits.max_compute_workgroups_per_dimension >= 65535);
}

#[test]
fn matmul_matches_cpu_on_ragged_shapes() {
    let gpu = gpu();
    for &(m, k, n) in &[(1, 1, 1), (16, 16, 16), (17, 33, 5), (100, 7, 129), (257, 64, 31)] {
        check(&gpu, m, k, n, (m * 1000 + k * 10 + n) as u64);
    }
}

#[test]
fn matmul_splits_tall_products_into_row_blocks() {
    // 65535 * 16 rows is the most one dispatch covers; go past it so the host must split.
    let gpu = gpu();
    let m = 65535 * 16 + 37;
    check(&gpu, m, 3, 2, 7);
}

#[test]
fn oversized_binding_is_an_error_not_a_crash() {
    let gpu = gpu();
    let too_many = (gpu.limits.max_storage_buffer_binding_size / 4 + 1) as usize;
    assert!(gpu.check_binding::<f32>("big", too_many).is_err());
    assert!(gpu.storage::<f32>("big", too_many).is_err());
}

/// Every shader of `shaders/` passes the device's validation (the viewer's mesh and point
/// shaders run only in the page otherwise, where a broken one shows as an empty view).
#[test]
fn every_shader_validates() {
    let gpu = Gpu::new_blocking().expect("a wgpu adapter (lavapipe will do)");
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let entry = |s: &str| ["@compute", "@vertex", "@fragment"].iter().any(|e| s.contains(e));
    let mut files: Vec<(String, String)> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read_to_string(&p).unwrap()))
        .collect();
    files.sort();
    // A file without entry points is a library, prepended to the shaders that name it.
    let libraries: Vec<&(String, String)> = files.iter().filter(|(_, s)| !entry(s)).collect();
    let mut seen = 0;
    for (name, text) in files.iter().filter(|(_, s)| entry(s)) {
        let mut source: String = libraries.iter().filter(|(l, _)| text.contains(l.as_str())).map(|(_, s)| s.as_str()).collect();
        source.push_str(text);
        // Templates (`{{NAME}}`, the decoder's array sizes) get a small size: the real ones are
        // compiled by the network's own tests.
        while let (Some(a), Some(b)) = (source.find("{{"), source.find("}}")) {
            source.replace_range(a..b + 2, "4");
        }
        let scope = gpu.device.push_error_scope(wgpu::ErrorFilter::Validation);
        // Only its validation is wanted: the module is dropped at once.
        let _module = gpu.device.create_shader_module(wgpu::ShaderModuleDescriptor { label: Some(name), source: wgpu::ShaderSource::Wgsl(source.into()) });
        let error = pollster::block_on(scope.pop());
        assert!(error.is_none(), "{name}: {}", error.unwrap());
        seen += 1;
    }
    assert!(seen >= 8, "{seen} shaders");
}
