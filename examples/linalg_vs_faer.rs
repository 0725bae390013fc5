//! The m × m algebra of a tuning step, `krr::linalg` (ours) against faer, natively: the Cholesky
//! factor, a solve and the inverse of a symmetric positive-definite m × m matrix, as the
//! objective needs them (`krr::mm::mm_forward`). Prints median seconds per operation and a hash
//! of each result's bits, so that two runs with other thread counts show whether the result
//! depends on them:
//!
//!     NKRR_THREADS=1 cargo run --release --features faer-bench --example linalg_vs_faer -- 1
//!     NKRR_THREADS=2 cargo run --release --features faer-bench --example linalg_vs_faer -- 2
//!
//! The argument is faer's thread count (1: sequential); NKRR_THREADS is ours.

use std::time::Instant;

use faer::linalg::solvers::{DenseSolveCore, Solve};
use faer::{Mat, Par, Side};
use nkrr::krr::linalg;

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

fn main() {
    let faer_threads: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(1);
    let par = if faer_threads <= 1 { Par::Seq } else { Par::rayon(faer_threads) };
    faer::set_global_parallelism(par);
    println!("ours: {} threads (NKRR_THREADS); faer: {faer_threads}", linalg::max_threads());
    println!("| m | op | ours s | faer s | faer/ours | ours hash | faer hash | max |diff| |");
    println!("| --- | --- | --- | --- | --- | --- | --- | --- |");
    for m in [250, 500, 1000] {
        let a = spd(m, m as u64);
        let b: Vec<f64> = (0..m).map(|i| (i as f64 * 0.37).sin()).collect();
        let am = Mat::from_fn(m, m, |i, j| a[i * m + j]);
        let bm = Mat::from_fn(m, 1, |i, _| b[i]);
        let reps = if m >= 1000 { 3 } else { 7 };
        let time = |f: &mut dyn FnMut()| median((0..reps).map(|_| { let t = Instant::now(); f(); t.elapsed().as_secs_f64() }).collect());

        let mut l = Vec::new();
        let t_ours = time(&mut || l = linalg::cholesky(&a, m, "A").expect("SPD"));
        let mut llt = None;
        let t_faer = time(&mut || llt = Some(am.llt(Side::Lower).expect("SPD")));
        let llt = llt.unwrap();
        let lf: Vec<f64> = (0..m * m).map(|k| { let (i, j) = (k / m, k % m); if j <= i { llt.L()[(i, j)] } else { 0.0 } }).collect();
        let diff = l.iter().zip(&lf).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        println!("| {m} | cholesky | {t_ours:.4} | {t_faer:.4} | {:.2} | {:016x} | {:016x} | {diff:.1e} |", t_faer / t_ours, hash(&l), hash(&lf));

        let mut x = Vec::new();
        let t_ours = time(&mut || x = linalg::cholesky_solve(&l, m, &b, 1));
        let mut xf = Mat::<f64>::zeros(m, 1);
        let t_faer = time(&mut || xf = llt.solve(&bm));
        let xfv: Vec<f64> = (0..m).map(|i| xf[(i, 0)]).collect();
        let diff = x.iter().zip(&xfv).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
        println!("| {m} | solve | {t_ours:.5} | {t_faer:.5} | {:.2} | {:016x} | {:016x} | {diff:.1e} |", t_faer / t_ours, hash(&x), hash(&xfv));

        let mut inv = Vec::new();
        let t_ours = time(&mut || inv = linalg::cholesky_inverse(&l, m));
        let mut invf = Mat::<f64>::zeros(m, m);
        let t_faer = time(&mut || invf = llt.inverse());
        let invfv: Vec<f64> = (0..m * m).map(|k| invf[(k / m, k % m)]).collect();
        let diff = inv.iter().zip(&invfv).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
        println!("| {m} | inverse | {t_ours:.4} | {t_faer:.4} | {:.2} | {:016x} | {:016x} | {diff:.1e} |", t_faer / t_ours, hash(&inv), hash(&invfv));
    }
}
