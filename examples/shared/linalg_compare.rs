//! The comparison behind `examples/linalg_vs_faer.rs` (native) and `bench/faer-wasm` (the
//! page's wasm build): the Cholesky factor, a solve and the inverse of a symmetric positive-
//! definite m × m matrix, ours (`krr::linalg`) against faer, with a hash of each result's bits
//! (to compare thread counts and builds) and the largest difference. Included by both with
//! `#[path]`; the caller sets faer's parallelism and gives the clock (wasm32 has no `Instant`).

use faer::linalg::solvers::{DenseSolveCore, Solve};
use faer::{Mat, Side};
use nkrr::krr::linalg;
use std::fmt::Write;

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

/// The table's rows (markdown) for m = 250, 500, 1000, timed by `now` (seconds).
pub fn table(now: &dyn Fn() -> f64) -> String {
    let mut out = String::new();
    writeln!(out, "| m | op | ours s | faer s | faer/ours | ours hash | faer hash | max |diff| |").unwrap();
    writeln!(out, "| --- | --- | --- | --- | --- | --- | --- | --- |").unwrap();
    for m in [250, 500, 1000] {
        let a = spd(m, m as u64);
        let b: Vec<f64> = (0..m).map(|i| (i as f64 * 0.37).sin()).collect();
        let am = Mat::from_fn(m, m, |i, j| a[i * m + j]);
        let bm = Mat::from_fn(m, 1, |i, _| b[i]);
        let reps = if m >= 1000 { 3 } else { 7 };
        let time = |f: &mut dyn FnMut()| median((0..reps).map(|_| { let t = now(); f(); now() - t }).collect());

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
