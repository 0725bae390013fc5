//! The GPU runtime against CPU references, on whatever adapter is present (lavapipe in CI).

use nkrr::gpu::{matmul, Gpu};

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
