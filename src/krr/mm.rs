//! The m × m algebra of the objective and its gradient (`docs/method.md` §5–§6): from the
//! n-sized products `A = K_nmᵀK_nm`, `b = K_nmᵀy` and `K_j`, everything the loss and the gradient
//! need in m × m terms. Shared by the f64 reference and the GPU objective (which forms `A` and
//! `b` on the GPU and runs this part on the CPU in f64).

use super::error::KrrError;
use super::linalg;

/// The m × m algebra of the forward pass (`docs/method.md` §5), shared by the f64 reference and
/// the GPU objective: from `A`, `K_j` and `b`, with `nl = nλ` and `n` the number of points.
pub(crate) struct MmForward {
    /// Cholesky factor of `K_j` (the gradient needs `K_j = L_K L_Kᵀ`).
    pub lk: Vec<f64>,
    pub beta: Vec<f64>,
    pub h_inv: Vec<f64>,
    pub kj_inv: Vec<f64>,
    /// `T1 = Tr(H⁻¹A)`.
    pub t1: f64,
    /// `T2 = n − Tr(K_j⁻¹A)`.
    pub t2: f64,
}

/// `H = A + nλK_j`, its Cholesky factor, `β = H⁻¹b`, the factor of `K_j`, both inverses (from
/// the triangular inverses of the factors) and the traces (as `Σ_ij X_ij A_ij`, all symmetric).
/// Four `m³/6` blocked kernels per matrix pair: factor, triangular inverse, `L⁻ᵀL⁻¹`.
pub(crate) fn mm_forward(a: &[f64], kj: &[f64], b: &[f64], nl: f64, n: f64, m: usize) -> Result<MmForward, KrrError> {
    // The H chain and the K_j chain are independent: each on its share of the threads.
    let (h_side, k_side) = linalg::join(
        linalg::max_threads(),
        0.5,
        |threads| -> Result<_, KrrError> {
            let mut h = a.to_vec();
            for (hv, kv) in h.iter_mut().zip(kj) {
                *hv += nl * kv;
            }
            let lh = linalg::cholesky_threads(&h, m, "H = K_nm^T K_nm + n lambda (K_mm + jitter I)", threads)?;
            drop(h);
            let beta = linalg::cholesky_solve(&lh, m, b, 1);
            let h_inv = linalg::cholesky_inverse_threads(&lh, m, threads);
            let t1 = linalg::frobenius_dot(&h_inv, a);
            Ok((beta, h_inv, t1))
        },
        |threads| -> Result<_, KrrError> {
            let lk = linalg::cholesky_threads(kj, m, "K_mm + jitter I", threads)?;
            let kj_inv = linalg::cholesky_inverse_threads(&lk, m, threads);
            let t2 = n - linalg::frobenius_dot(&kj_inv, a);
            Ok((lk, kj_inv, t2))
        },
    );
    // H's failure first, as when the two ran one after the other.
    let (beta, h_inv, t1) = h_side?;
    let (lk, kj_inv, t2) = k_side?;
    Ok(MmForward { lk, beta, h_inv, kj_inv, t1, t2 })
}

/// The objective from its parts (`docs/method.md` §4), assembled here once for the f64
/// reference and the GPU objective: `D = data_fit + λ βᵀK_jβ`, `loss = αT1 + cT2·D + 2D`, with
/// `(α, c)` = [`Ridge::weights`](super::problem::Ridge::weights) for `n` points. Returns the
/// evaluation and `(α, c)`, which the gradient needs; a loss that is not finite is an error.
pub(crate) fn assemble(
    data_fit: f64,
    (t1, t2): (f64, f64),
    beta: Vec<f64>,
    kj: &[f64],
    settings: &super::problem::Ridge,
    (n, m): (usize, usize),
) -> Result<(super::problem::Eval, f64, f64), KrrError> {
    let rkhs_norm2 = linalg::dot(&beta, &linalg::matvec(kj, &beta, m, m));
    let d_term = data_fit + settings.lambda * rkhs_norm2;
    let (alpha, c) = settings.weights(n);
    let loss = alpha * t1 + c * t2 * d_term + 2.0 * d_term;
    if !loss.is_finite() {
        return Err(KrrError::NonFinite(format!("objective: loss = {loss} (T1 = {t1}, T2 = {t2}, D = {d_term})")));
    }
    Ok((super::problem::Eval { loss, data_fit, rkhs_norm2, d_term, t1, t2, beta }, alpha, c))
}

/// The m × m inputs of the gradient's m × m part (method.md §6).
pub(crate) struct MmParts<'a> {
    pub h_inv: &'a [f64],
    /// Cholesky factor of `K_j`.
    pub lk: &'a [f64],
    pub kj_inv: &'a [f64],
    pub a: &'a [f64],
    pub beta: &'a [f64],
    pub lambda: f64,
    /// The weight of `T1` in the loss (`2/n` for all data, see [`super::problem::Ridge::weights`]).
    pub alpha: f64,
    pub c: f64,
    pub dd: f64,
    pub t2: f64,
    pub n: f64,
    pub m: usize,
}

/// The gradient's m × m part: `W` (so that `G_nm = K_nm W + s_r r βᵀ`), `G_mm`, and `s_r`.
/// Shared by the f64 reference and the GPU objective, which does this part on the CPU too.
pub(crate) struct MmGrad {
    pub w: Vec<f64>,
    pub gmm: Vec<f64>,
    pub s_r: f64,
}

/// Three products, `2.5 m³` multiply-adds (was six general products, `6 m³`):
/// - `H⁻¹K_jH⁻¹ = (H⁻¹L_K)(H⁻¹L_K)ᵀ` — a product with a triangular factor, then a symmetric one;
/// - `H⁻¹AH⁻¹ = H⁻¹ − nλ H⁻¹K_jH⁻¹` (from `A = H − nλK_j`): no product at all. The difference
///   cancels where `A` is small against `nλK_j`, but only to the absolute level `ε‖H⁻¹‖` that
///   the inverse itself carries (the finite-difference tests are the check);
/// - `K_j⁻¹AK_j⁻¹ = K_j⁻¹(AK_j⁻¹)`, the second product symmetric (upper triangle only).
///
/// Every term is exactly symmetric, so `W` and `G_mm` are too.
pub(crate) fn mm_grad(p: &MmParts) -> MmGrad {
    use linalg::{Op, Tri};
    let m = p.m;
    let nl = p.n * p.lambda;
    // Two independent chains (m³ and 1.5 m³ multiply-adds), each on its share of the threads.
    let (hkh, kak) = linalg::join(
        linalg::max_threads(),
        0.4,
        |threads| {
            let mut hl = vec![0.0; m * m];
            linalg::gemm_threads(&mut hl, m, Tri::Full, 1.0, Op::new(p.h_inv, m), Op::new(p.lk, m).lower(), m, m, m, threads);
            linalg::gram_rows_threads(&hl, m, m, threads)
        },
        |threads| {
            let ak = linalg::matmul_threads(p.a, p.kj_inv, m, m, m, threads);
            linalg::matmul_sym_threads(p.kj_inv, &ak, m, threads)
        },
    );
    let cd = p.c * p.dd;
    let s_beta = (p.c * p.t2 + 2.0) * p.lambda;
    // T1's terms: α·∂T1/∂K_mm = −α nλ H⁻¹AH⁻¹ and α·∂T1/∂K_nm = 2α K_nm M1 (with α = 2/n these
    // are the −2λ H⁻¹AH⁻¹ and (4/n) M1 of method.md §6).
    let t1_mm = p.alpha * nl;
    let t1_nm = 2.0 * p.alpha * nl;
    // Elementwise, threaded over rows: G_mm first (it reads H⁻¹K_jH⁻¹), then W in place of it.
    const ROWS: usize = 16;
    let threads = linalg::max_threads();
    let work = |_| (ROWS * m * 4) as f64;
    let mut gmm = kak;
    linalg::par_row_units(&mut gmm, m, m, ROWS, threads, &work, |u0, u1, rows| {
        for (j, grow) in (u0 * ROWS..(u1 * ROWS).min(m)).zip(rows.chunks_mut(m)) {
            let bj = p.beta[j];
            let (hrow, hkhrow) = (&p.h_inv[j * m..(j + 1) * m], &hkh[j * m..(j + 1) * m]);
            for k in 0..m {
                let hah = hrow[k] - nl * hkhrow[k];
                // s_β (β_j β_k), not (s_β β_j) β_k: exactly symmetric.
                grow[k] = -t1_mm * hah + cd * grow[k] + s_beta * (bj * p.beta[k]);
            }
        }
    });
    let mut w = hkh;
    linalg::par_row_units(&mut w, m, m, ROWS, threads, &work, |u0, u1, rows| {
        for (j, wrow) in (u0 * ROWS..(u1 * ROWS).min(m)).zip(rows.chunks_mut(m)) {
            for (wv, kv) in wrow.iter_mut().zip(&p.kj_inv[j * m..(j + 1) * m]) {
                // 2α M1 with M1 = nλ H⁻¹K_jH⁻¹.
                *wv = t1_nm * *wv - 2.0 * cd * kv;
            }
        }
    });
    MmGrad { w, gmm, s_r: (p.c * p.t2 + 2.0) * (2.0 / p.n) }
}

/// The `K_mm` side of the `Z` and length-scale gradients (before the `1/s²` factor), with
/// `Q = G_mm ∘ K_mm` (the jitter is constant, so `K_mm`, not `K_j`):
/// `gz_j = 2 Σ_k Q_jk (z_k − z_j)` (`m × d`) and `gs = Σ_jk Q_jk (z_j − z_k)²` (`d`).
/// Threaded over `j`; `gs` is summed over `j` in order, so the result does not depend on the
/// thread count.
pub(crate) fn kmm_side(gmm: &[f64], kmm: &[f64], z: &[f64], m: usize, d: usize) -> (Vec<f64>, Vec<f64>) {
    const ROWS: usize = 8;
    // Row j: [gz_j (d) | gs_j (d)].
    let mut part = vec![0.0; m * 2 * d];
    linalg::par_row_units(&mut part, 2 * d, m, ROWS, linalg::max_threads(), &|_| (ROWS * m * d * 2) as f64, |u0, u1, out| {
        for j in u0 * ROWS..(u1 * ROWS).min(m) {
            let o = &mut out[(j - u0 * ROWS) * 2 * d..(j - u0 * ROWS + 1) * 2 * d];
            let (gzj, gsj) = o.split_at_mut(d);
            let zj = &z[j * d..(j + 1) * d];
            for k in 0..m {
                if k == j {
                    continue; // z_j − z_j = 0
                }
                let q = gmm[j * m + k] * kmm[j * m + k];
                let zk = &z[k * d..(k + 1) * d];
                for ((g, s), (a, b)) in gzj.iter_mut().zip(gsj.iter_mut()).zip(zk.iter().zip(zj)) {
                    let e = a - b;
                    let qe = q * e;
                    *g += qe;
                    *s += qe * e;
                }
            }
            gzj.iter_mut().for_each(|g| *g *= 2.0);
        }
    });
    let mut gz = vec![0.0; m * d];
    let mut gs = vec![0.0; d];
    for j in 0..m {
        gz[j * d..(j + 1) * d].copy_from_slice(&part[j * 2 * d..j * 2 * d + d]);
        for (s, v) in gs.iter_mut().zip(&part[j * 2 * d + d..(j + 1) * 2 * d]) {
            *s += v;
        }
    }
    (gz, gs)
}

/// Inputs of the m × m algebra as the objective meets them, on random data: the Gram matrix
/// `A` of a Gaussian `K_nm` (`n` points, `m` centres, `d` features), `K_mm` of the same centres
/// (no jitter), `b = K_nmᵀy`, the centres and the log length-scales.
pub(crate) struct MmInputs {
    pub a: Vec<f64>,
    pub kmm: Vec<f64>,
    pub b: Vec<f64>,
    pub z: Vec<f64>,
    /// Only the tests need them back (the benchmark times the algebra alone).
    #[cfg_attr(not(test), allow(dead_code))]
    pub log_s: Vec<f64>,
}

impl MmInputs {
    pub fn synthetic(n: usize, m: usize, d: usize, seed: u64) -> MmInputs {
        use super::kernel;
        let mut rng = crate::rng::SplitMix64(seed);
        let x: Vec<f64> = (0..n * d).map(|_| rng.unit() - 0.5).collect();
        let y: Vec<f64> = (0..n).map(|_| rng.unit() - 0.5).collect();
        let z: Vec<f64> = (0..m * d).map(|_| rng.unit() - 0.5).collect();
        let log_s = vec![(0.3f64 * (d as f64).sqrt()).ln(); d];
        let knm = kernel::k_nm(&x, &z, &log_s);
        let kmm = kernel::k_mm(&z, &log_s);
        let a = linalg::gram(&knm, n, m);
        let b = linalg::matvec_t(&knm, &y, n, m);
        MmInputs { a, kmm, b, z, log_s }
    }
}

/// Seconds of the CPU's share of one tuning step on a GPU objective with `m` inducing points
/// and `d` features (the median of `reps` runs): the m × m algebra of the forward pass, of the
/// gradient and the `K_mm` side, which the GPU objective runs in f64 on the CPU at every step
/// (in the browser: wasm, on the worker's one thread). On synthetic inputs of the objective's
/// shapes (`A` the Gram matrix of a Gaussian `K_nm` with n = 2m). For `nkrr bench` and the
/// page's `tuning_step_ms`.
pub fn algebra_step_seconds(m: usize, d: usize, reps: usize) -> f64 {
    let n = 2 * m;
    let MmInputs { a, kmm, b, z, .. } = MmInputs::synthetic(n, m, d, m as u64);
    let ridge = super::problem::Ridge::new(1e-5, m);
    let (alpha, c) = ridge.weights(n);
    let (nf, lambda) = (n as f64, ridge.lambda);
    let mut times: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let t = crate::gpu::now();
            let mut kj = kmm.clone();
            for j in 0..m {
                kj[j * m + j] += ridge.jitter;
            }
            let f = mm_forward(&a, &kj, &b, nf * lambda, nf, m).expect("a Gaussian Gram matrix with jitter is positive definite");
            let g = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &a, beta: &f.beta, lambda, alpha, c, dd: 0.1, t2: f.t2, n: nf, m });
            std::hint::black_box(kmm_side(&g.gmm, &kmm, &z, m, d));
            crate::gpu::now() - t
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::krr::problem::Weighting;

    /// [`MmInputs::synthetic`] as a tuple `(A, K_mm, b, Z, log s)`.
    #[allow(clippy::type_complexity)]
    fn mm_inputs(n: usize, m: usize, d: usize, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let MmInputs { a, kmm, b, z, log_s } = MmInputs::synthetic(n, m, d, seed);
        (a, kmm, b, z, log_s)
    }

    /// What the GPU objective does on the CPU per evaluation with gradient: `K_j`, the forward
    /// algebra, the gradient's m × m part and the `K_mm` side. Returns `(W/G_mm, gs, T1, T2)`.
    #[allow(clippy::too_many_arguments)]
    fn mm_algebra(a: &[f64], kmm: &[f64], b: &[f64], z: &[f64], n: usize, m: usize, d: usize, lambda: f64, jitter: f64) -> (MmGrad, Vec<f64>, f64, f64) {
        let nf = n as f64;
        let mut kj = kmm.to_vec();
        for j in 0..m {
            kj[j * m + j] += jitter;
        }
        let f = mm_forward(a, &kj, b, nf * lambda, nf, m).unwrap();
        let c = Weighting::Falkon.c(n, lambda);
        let g = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a, beta: &f.beta, lambda, alpha: 2.0 / nf, c, dd: 0.1, t2: f.t2, n: nf, m });
        let (_, gs) = kmm_side(&g.gmm, kmm, z, m, d);
        (g, gs, f.t1, f.t2)
    }

    /// `mm_grad`'s rearranged algebra against the §6 formulas with explicit products:
    /// `W = 4λ H⁻¹K_jH⁻¹ − 2cD K_j⁻¹`, `G_mm = −2λ H⁻¹AH⁻¹ + cD K_j⁻¹AK_j⁻¹ + (cT2 + 2)λ ββᵀ`.
    ///
    /// `H⁻¹AH⁻¹` is computed as `H⁻¹ − nλ H⁻¹K_jH⁻¹`, which cancels where `A` is small against
    /// `nλK_j`. The yardstick is how far the explicit products are from themselves grouped the
    /// other way (`(H⁻¹A)H⁻¹` vs `H⁻¹(AH⁻¹)`, likewise `K_j⁻¹AK_j⁻¹`): the rearranged `G_mm` must
    /// stay within a small multiple of that. (Measured alone, `H⁻¹ − nλH⁻¹K_jH⁻¹` is 1.4 times
    /// the regrouping noise of `H⁻¹AH⁻¹`: 4e-9 to 9e-6 of its largest entry in these cases.)
    #[test]
    fn mm_grad_matches_the_explicit_products() {
        for &(n, m, lambda) in &[(300, 37, 1e-3), (200, 64, 0.1), (500, 130, 1e-5)] {
            let d = 3;
            let (a, kmm, b, _, _) = mm_inputs(n, m, d, 11 + m as u64);
            let nf = n as f64;
            let mut kj = kmm.clone();
            for j in 0..m {
                kj[j * m + j] += 1e-6 * m as f64;
            }
            let f = mm_forward(&a, &kj, &b, nf * lambda, nf, m).unwrap();
            let (c, dd) = (Weighting::Paper.c(n, lambda), 0.3);
            let g = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &a, beta: &f.beta, lambda, alpha: 2.0 / nf, c, dd, t2: f.t2, n: nf, m });
            let mul = |x: &[f64], y: &[f64]| linalg::matmul(x, y, m, m, m);
            let max_abs = |v: &[f64]| v.iter().fold(0.0f64, |x, y| x.max(y.abs()));
            let max_diff = |u: &[f64], v: &[f64]| u.iter().zip(v).fold(0.0f64, |x, (p, q)| x.max((p - q).abs()));
            let hkh = mul(&mul(&f.h_inv, &kj), &f.h_inv);
            let hah = mul(&mul(&f.h_inv, &a), &f.h_inv);
            let hah_other = mul(&f.h_inv, &mul(&a, &f.h_inv));
            let kak = mul(&mul(&f.kj_inv, &a), &f.kj_inv);
            let kak_other = mul(&f.kj_inv, &mul(&a, &f.kj_inv));
            let s_beta = (c * f.t2 + 2.0) * lambda;
            let mut w = vec![0.0; m * m];
            let mut gmm = vec![0.0; m * m];
            for j in 0..m {
                for k in 0..m {
                    let i = j * m + k;
                    w[i] = 4.0 * lambda * hkh[i] - 2.0 * c * dd * f.kj_inv[i];
                    gmm[i] = -2.0 * lambda * hah[i] + c * dd * kak[i] + s_beta * f.beta[j] * f.beta[k];
                    assert_eq!(g.w[i], g.w[k * m + j], "W not symmetric");
                    assert_eq!(g.gmm[i], g.gmm[k * m + j], "G_mm not symmetric");
                }
            }
            let (ew, eg) = (max_diff(&g.w, &w), max_diff(&g.gmm, &gmm));
            let noise = 2.0 * lambda * max_diff(&hah, &hah_other) + c * dd * max_diff(&kak, &kak_other);
            println!(
                "m {m} lambda {lambda:e}: |ΔW| {:.2e}, |ΔG_mm| {:.2e} (of max |W| {:.2e}, |G_mm| {:.2e}); regrouping noise of the explicit G_mm {:.2e}",
                ew,
                eg,
                max_abs(&w),
                max_abs(&gmm),
                noise
            );
            assert!(ew <= 1e-11 * max_abs(&w), "W: {ew:e}");
            assert!(eg <= 4.0 * noise + 1e-12 * max_abs(&gmm), "G_mm: {eg:e} vs explicit-product noise {noise:e}");
            // T1 and T2 against the definitions, within the rounding of sums whose terms are far
            // larger than the result (ε Σ|terms|).
            let t1 = linalg::trace_prod(&f.h_inv, &a, m);
            let t1_scale: f64 = f.h_inv.iter().zip(&a).map(|(x, y)| (x * y).abs()).sum();
            let t2 = nf - linalg::trace(&mul(&f.kj_inv, &a), m);
            let t2_scale: f64 = f.kj_inv.iter().zip(&a).map(|(x, y)| (x * y).abs()).sum();
            println!("   T1 {} vs {t1} (scale {t1_scale:.1e}), T2 {} vs {t2} (scale {t2_scale:.1e})", f.t1, f.t2);
            assert!((f.t1 - t1).abs() <= 1e-14 * t1_scale, "T1 {} vs {t1}", f.t1);
            assert!((f.t2 - t2).abs() <= 1e-14 * t2_scale, "T2 {} vs {t2}", f.t2);
        }
    }

    /// The CPU part of one GPU objective + gradient evaluation (`GpuObjective::run` and
    /// `backward`) at m = 500 and 1000, best of three, and its parts (`cargo test --release --lib
    /// -- --ignored --nocapture --test-threads=1 timing_mm_algebra`; `NKRR_THREADS` to vary the
    /// threads).
    #[test]
    #[ignore]
    fn timing_mm_algebra() {
        let best_of = |f: &mut dyn FnMut()| {
            (0..3)
                .map(|_| {
                    let t = std::time::Instant::now();
                    f();
                    t.elapsed().as_secs_f64() * 1e3
                })
                .fold(f64::INFINITY, f64::min)
        };
        println!("threads: {}", linalg::max_threads());
        for &m in &[500usize, 1000] {
            let (n, d) = (2000, 32);
            let (a, kmm, b, z, _) = mm_inputs(n, m, d, 7);
            let (lambda, jitter) = (1e-4, 1e-6 * m as f64);
            let (nf, c) = (n as f64, Weighting::Falkon.c(n, lambda));
            let mut out = None;
            let total = best_of(&mut || out = Some(mm_algebra(&a, &kmm, &b, &z, n, m, d, lambda, jitter)));
            let (g, gs, t1, t2) = out.unwrap();
            println!("timing_mm_algebra m {m}: {total:.1} ms (T1 {t1:.6}, T2 {t2:.6e}, W[0] {:e}, gs[0] {:e})", g.w[0], gs[0]);
            let mut kj = kmm.clone();
            for j in 0..m {
                kj[j * m + j] += jitter;
            }
            let f = mm_forward(&a, &kj, &b, nf * lambda, nf, m).unwrap();
            let t_fwd = best_of(&mut || drop(mm_forward(&a, &kj, &b, nf * lambda, nf, m).unwrap()));
            let parts = MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &a, beta: &f.beta, lambda, alpha: 2.0 / nf, c, dd: 0.1, t2: f.t2, n: nf, m };
            let t_grad = best_of(&mut || drop(mm_grad(&parts)));
            let t_q = best_of(&mut || drop(kmm_side(&g.gmm, &kmm, &z, m, d)));
            println!("  m {m}: mm_forward {t_fwd:.1} ms, mm_grad {t_grad:.1} ms, kmm_side {t_q:.1} ms");
        }
    }
}
