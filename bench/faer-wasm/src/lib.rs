//! `krr::linalg` (ours) against faer 0.24 in the wasm32 build, the wasm half of
//! `examples/linalg_vs_faer.rs` (same matrices, same hash, same table): the Cholesky factor, a
//! single-right-hand-side solve and the inverse of a symmetric positive-definite m × m matrix,
//! on one thread (wasm32 has none). Timed with `performance.now()` (`std::time::Instant`
//! panics on wasm32-unknown-unknown).

use faer::linalg::solvers::{DenseSolveCore, Solve};
use faer::{Mat, Par, Side};
use nkrr::krr::linalg;
use wasm_bindgen::prelude::*;

fn now_s() -> f64 {
    let perf = js_sys::Reflect::get(&js_sys::global(), &JsValue::from_str("performance")).expect("performance");
    let now = js_sys::Reflect::get(&perf, &JsValue::from_str("now")).expect("performance.now");
    let now: js_sys::Function = now.into();
    now.call0(&perf).expect("performance.now()").as_f64().expect("a number") / 1e3
}

fn spd(m: usize, seed: u64) -> Vec<f64> {
    // A Gaussian kernel matrix of random points plus jitter, as K_mm + jitter I is.
    let mut rng = nkrr::rng::SplitMix64(seed);
    let pts: Vec<[f64; 4]> = (0..m).map(|_| [rng.unit(), rng.unit(), rng.unit(), rng.unit()]).collect();
    let mut a = vec![0.0; m * m];
    for i in 0..m {
        for j in 0..m {
            let d2: f64 = (0..4).map(|k| (pts[i][k] - pts[j][k]).powi(2)).sum();
            a[i * m + j] = (-d2 / 0.5).exp() + if i == j { 1e-3 } else { 0.0 };
        }
    }
    a
}

fn hash(v: &[f64]) -> u64 {
    v.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, x| (h ^ x.to_bits()).wrapping_mul(0x100_0000_01b3))
}

fn median(mut t: Vec<f64>) -> f64 {
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

/// The table rows (markdown), as the native example prints them.
#[wasm_bindgen]
pub fn run() -> String {
    use std::fmt::Write;
    faer::set_global_parallelism(Par::Seq);
    let mut out = String::new();
    let simd = if cfg!(target_feature = "simd128") { "simd128" } else { "no simd128" };
    writeln!(out, "ours: {} thread (wasm32, {simd}); faer: 1 (Par::Seq)", linalg::max_threads()).unwrap();
    writeln!(out, "| m | op | ours s | faer s | faer/ours | ours hash | faer hash | max |diff| |").unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- | --- | --- | --- |").unwrap();
    for m in [250, 500, 1000] {
        let a = spd(m, m as u64);
        let b: Vec<f64> = (0..m).map(|i| (i as f64 * 0.37).sin()).collect();
        let am = Mat::from_fn(m, m, |i, j| a[i * m + j]);
        let bm = Mat::from_fn(m, 1, |i, _| b[i]);
        let reps = if m >= 1000 { 3 } else { 7 };
        let time = |f: &mut dyn FnMut()| median((0..reps).map(|_| { let t = now_s(); f(); now_s() - t }).collect());

        let mut l = Vec::new();
        let t_ours = time(&mut || l = linalg::cholesky(&a, m, "A").expect("SPD"));
        let mut llt = None;
        let t_faer = time(&mut || llt = Some(am.llt(Side::Lower).expect("SPD")));
        let llt = llt.unwrap();
        let lf: Vec<f64> = (0..m * m).map(|k| { let (i, j) = (k / m, k % m); if j <= i { llt.L()[(i, j)] } else { 0.0 } }).collect();
        let diff = l.iter().zip(&lf).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        writeln!(out, "| {m} | cholesky | {t_ours:.4} | {t_faer:.4} | {:.2} | {:016x} | {:016x} | {diff:.1e} |", t_faer / t_ours, hash(&l), hash(&lf)).unwrap();

        let mut x = Vec::new();
        let t_ours = time(&mut || x = linalg::cholesky_solve(&l, m, &b, 1));
        let mut xf = Mat::<f64>::zeros(m, 1);
        let t_faer = time(&mut || xf = llt.solve(&bm));
        let xfv: Vec<f64> = (0..m).map(|i| xf[(i, 0)]).collect();
        let diff = x.iter().zip(&xfv).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
        writeln!(out, "| {m} | solve | {t_ours:.5} | {t_faer:.5} | {:.2} | {:016x} | {:016x} | {diff:.1e} |", t_faer / t_ours, hash(&x), hash(&xfv)).unwrap();

        let mut inv = Vec::new();
        let t_ours = time(&mut || inv = linalg::cholesky_inverse(&l, m));
        let mut invf = Mat::<f64>::zeros(m, m);
        let t_faer = time(&mut || invf = llt.inverse());
        let invfv: Vec<f64> = (0..m * m).map(|k| invf[(k / m, k % m)]).collect();
        let diff = inv.iter().zip(&invfv).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
        writeln!(out, "| {m} | inverse | {t_ours:.4} | {t_faer:.4} | {:.2} | {:016x} | {:016x} | {diff:.1e} |", t_faer / t_ours, hash(&inv), hash(&invfv)).unwrap();
    }
    out
}
