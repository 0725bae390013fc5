//! The f64 Nyström KRR reference (`src/krr`, `docs/method.md` §3–§6, §8): the linear algebra,
//! the solve, the trace identities, the hand-derived gradient against central finite
//! differences (both weightings), the Adam tuner, and error handling.
//!
//! Printed with `--nocapture`: the finite-difference relative errors. `#[ignore]`d: the timing at
//! the paper's sizes and the length-scale initialisation sweep (run with `--ignored`).

use std::time::Instant;

use nkrr::krr::init::SplitMix64;
use nkrr::krr::linalg;
use nkrr::krr::{
    init_length_scales, init_params, init_z, kernel, objective, objective_and_grad, predict, tune,
    Eval, Grad, KrrError, LengthScaleInit, Objective, Params, Problem, Reference, Ridge,
    StopReason, TuneSettings, Weighting,
};

// ---------------------------------------------------------------------------------------------
// helpers

fn gauss(rng: &mut SplitMix64) -> f64 {
    // Box–Muller.
    let u1 = rng.unit().max(1e-300);
    let u2 = rng.unit();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// A random regression problem: X ~ N(0, diag(scale_d²)), y a smooth function of a few
/// dimensions plus noise.
fn random_problem(n: usize, d: usize, seed: u64) -> Problem {
    let mut rng = SplitMix64(seed);
    let scales: Vec<f64> = (0..d).map(|t| 0.5 + (t % 5) as f64 * 0.3).collect();
    let x: Vec<f64> = (0..n * d).map(|i| gauss(&mut rng) * scales[i % d]).collect();
    let y: Vec<f64> = (0..n)
        .map(|i| {
            let r = &x[i * d..(i + 1) * d];
            (1.5 * r[0]).sin() + 0.5 * r[d.min(2) - 1] * r[0] + 0.05 * gauss(&mut rng)
        })
        .collect();
    Problem::new(x, y, d).unwrap()
}

/// Initial parameters perturbed off the data rows and off a uniform length-scale, so that no
/// gradient component is special.
fn random_params(p: &Problem, m: usize, seed: u64) -> Params {
    let mut params = init_params(p, m, seed, LengthScaleInit::ScaledStd(1.0));
    let mut rng = SplitMix64(seed ^ 0xABCD);
    for v in params.log_s.iter_mut() {
        *v += 0.3 * gauss(&mut rng);
    }
    for v in params.z.iter_mut() {
        *v += 0.1 * gauss(&mut rng);
    }
    params
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

struct FdReport {
    norm_rel: f64,
    worst_component_rel: f64,
}

/// Compare the analytic gradient block `analytic` with central differences of the loss along
/// the coordinates `coords` of the block selected by `which` (0: log_s, 1: z).
fn fd_check(p: &Problem, params: &Params, s: &Ridge, analytic: &[f64], which: usize, coords: &[usize], h: f64) -> FdReport {
    let mut fd = Vec::with_capacity(coords.len());
    for &c in coords {
        let at = |delta: f64| {
            let mut q = params.clone();
            let v = if which == 0 { &mut q.log_s } else { &mut q.z };
            v[c] += delta;
            objective(p, &q, s).unwrap().loss
        };
        // Fourth-order central stencil: truncation O(h⁴), so h can stay large enough that the
        // objective's own rounding noise (≈1e-12 relative, from T2 = n − Tr(K_j⁻¹A)) is
        // divided by a large h.
        fd.push((-at(2.0 * h) + 8.0 * at(h) - 8.0 * at(-h) + at(-2.0 * h)) / (12.0 * h));
    }
    let an: Vec<f64> = coords.iter().map(|&c| analytic[c]).collect();
    let diff: Vec<f64> = an.iter().zip(&fd).map(|(a, f)| a - f).collect();
    let norm_rel = norm(&diff) / norm(&fd);
    // Per component, for components not near zero (above 1% of the largest).
    let big = fd.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let worst_component_rel = an
        .iter()
        .zip(&fd)
        .filter(|(_, f)| f.abs() > 1e-2 * big)
        .map(|(a, f)| ((a - f) / f).abs())
        .fold(0.0, f64::max);
    FdReport { norm_rel, worst_component_rel }
}

#[allow(clippy::too_many_arguments)]
fn run_fd(label: &str, n: usize, m: usize, d: usize, lambda: f64, jitter: Option<f64>, z_coords: usize, seed: u64) {
    let p = random_problem(n, d, seed);
    let params = random_params(&p, m, seed + 1);
    // full_n: the loss of a subsample standing for 4n pairs (what tuning on a subsample runs).
    for (weighting, full_n) in
        [(Weighting::Falkon, None), (Weighting::Paper, None), (Weighting::Falkon, Some(4 * n)), (Weighting::Paper, Some(4 * n))]
    {
        let mut s = Ridge::new(lambda, m);
        s.weighting = weighting;
        s.full_n = full_n;
        if let Some(j) = jitter {
            s.jitter = j;
        }
        let (eval, grad) = objective_and_grad(&p, &params, &s).unwrap();
        assert_eq!(eval, objective(&p, &params, &s).unwrap());
        let all_s: Vec<usize> = (0..d).collect();
        let zs: Vec<usize> = if z_coords >= m * d {
            (0..m * d).collect()
        } else {
            let mut rng = SplitMix64(seed + 7);
            (0..z_coords).map(|_| rng.below((m * d) as u64) as usize).collect()
        };
        let rs = fd_check(&p, &params, &s, &grad.log_s, 0, &all_s, 1e-3);
        let rz = fd_check(&p, &params, &s, &grad.z, 1, &zs, 1e-3);
        println!(
            "FD {label} {weighting:?} full_n {full_n:?} jitter {:.0e}: loss {:.6e} (T1 {:.3}, T2 {:.3e}, D {:.3e}) | \
             log_s: norm rel {:.2e}, worst comp {:.2e} | z ({} comps): norm rel {:.2e}, worst comp {:.2e}",
            s.jitter, eval.loss, eval.t1, eval.t2, eval.d_term, rs.norm_rel, rs.worst_component_rel, zs.len(),
            rz.norm_rel, rz.worst_component_rel
        );
        assert!(rs.norm_rel < 1e-4 && rs.worst_component_rel < 1e-4, "{label} {weighting:?} {full_n:?} log_s");
        assert!(rz.norm_rel < 1e-4 && rz.worst_component_rel < 1e-4, "{label} {weighting:?} {full_n:?} z");
    }
}

// ---------------------------------------------------------------------------------------------
// linear algebra

fn naive_matmul(a: &[f64], b: &[f64], n: usize, k: usize, p: usize) -> Vec<f64> {
    let mut c = vec![0.0; n * p];
    for i in 0..n {
        for j in 0..p {
            c[i * p + j] = (0..k).map(|t| a[i * k + t] * b[t * p + j]).sum();
        }
    }
    c
}

fn uniform_vec(len: usize, seed: u64) -> Vec<f64> {
    let mut rng = SplitMix64(seed);
    (0..len).map(|_| rng.unit() - 0.5).collect()
}

#[test]
fn linalg_products_match_naive() {
    for &(n, k, p) in &[(1, 1, 1), (7, 5, 3), (9, 300, 261), (130, 129, 300), (5, 2, 600)] {
        let a = uniform_vec(n * k, 1);
        let b = uniform_vec(k * p, 2);
        let want = naive_matmul(&a, &b, n, k, p);
        assert!(max_abs_diff(&linalg::matmul(&a, &b, n, k, p), &want) < 1e-12);
        // Aᵀ B and A Bᵀ through explicit transposes.
        let at = linalg::transpose(&a, n, k);
        assert!(max_abs_diff(&linalg::matmul_tn(&at, &b, k, n, p), &want) < 1e-12);
        let bt = linalg::transpose(&b, k, p);
        assert!(max_abs_diff(&linalg::matmul_nt(&a, &bt, n, k, p), &want) < 1e-12);
        let g = linalg::gram(&a, n, k);
        assert!(max_abs_diff(&g, &naive_matmul(&at, &a, k, n, k)) < 1e-12);
        let x = uniform_vec(k, 3);
        assert!(max_abs_diff(&linalg::matvec(&a, &x, n, k), &naive_matmul(&a, &x, n, k, 1)) < 1e-12);
        let y = uniform_vec(n, 4);
        assert!(max_abs_diff(&linalg::matvec_t(&a, &y, n, k), &naive_matmul(&at, &y, k, n, 1)) < 1e-12);
    }
}

#[test]
fn linalg_cholesky_solves_inverts_and_rejects_indefinite() {
    let n = 37;
    let r = uniform_vec(n * n, 5);
    let mut a = linalg::gram(&r, n, n);
    for i in 0..n {
        a[i * n + i] += 0.5;
    }
    let l = linalg::cholesky(&a, n, "test").unwrap();
    assert!(max_abs_diff(&linalg::matmul_nt(&l, &l, n, n, n), &a) < 1e-12);
    let b = uniform_vec(n * 3, 6);
    let x = linalg::spd_solve(&a, n, &b, 3, "test").unwrap();
    assert!(max_abs_diff(&linalg::matmul(&a, &x, n, n, 3), &b) < 1e-12);
    let inv = linalg::spd_inverse(&a, n, "test").unwrap();
    assert!(max_abs_diff(&linalg::matmul(&a, &inv, n, n, n), &linalg::identity(n)) < 1e-10);
    assert!((linalg::trace_prod(&a, &inv, n) - n as f64).abs() < 1e-10);
    assert!((linalg::trace(&linalg::identity(n), n) - n as f64).abs() == 0.0);

    let mut bad = linalg::identity(3);
    bad[4] = -1.0;
    match linalg::cholesky(&bad, 3, "bad") {
        Err(KrrError::NotPositiveDefinite { what: "bad", index: 1, pivot }) => assert_eq!(pivot, -1.0),
        other => panic!("expected NotPositiveDefinite, got {other:?}"),
    }
    let mut nan = linalg::identity(2);
    nan[3] = f64::NAN;
    assert!(matches!(linalg::cholesky(&nan, 2, "nan"), Err(KrrError::NotPositiveDefinite { .. })));
    // A singular Gram matrix (two identical columns) with no jitter is rejected too.
    let sing = [1.0, 1.0, 1.0, 1.0];
    assert!(linalg::cholesky(&sing, 2, "singular").is_err());
}

#[test]
fn kernel_matches_definition() {
    let p = random_problem(5, 3, 11);
    let params = random_params(&p, 4, 12);
    let knm = kernel::k_nm(p.x(), &params.z, &params.log_s);
    let kmm = kernel::k_mm(&params.z, &params.log_s);
    let s = params.length_scales();
    for i in 0..5 {
        for j in 0..4 {
            let e: f64 = (0..3).map(|t| ((p.x()[i * 3 + t] - params.z[j * 3 + t]) / s[t]).powi(2)).sum();
            assert!((knm[i * 4 + j] - (-0.5 * e).exp()).abs() < 1e-15);
        }
    }
    for j in 0..4 {
        assert_eq!(kmm[j * 4 + j], 1.0);
        for k in 0..4 {
            assert_eq!(kmm[j * 4 + k], kmm[k * 4 + j]);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// the solve and the identities

#[test]
fn nystrom_solve_satisfies_normal_equations() {
    let (n, m, d, lambda) = (300, 30, 5, 1e-3);
    let p = random_problem(n, d, 21);
    let params = random_params(&p, m, 22);
    for jitter in [0.0, 1e-6 * m as f64] {
        let s = Ridge { lambda, jitter, weighting: Weighting::Falkon, full_n: None };
        let eval = objective(&p, &params, &s).unwrap();
        let knm = kernel::k_nm(p.x(), &params.z, &params.log_s);
        let mut kj = kernel::k_mm(&params.z, &params.log_s);
        for j in 0..m {
            kj[j * m + j] += jitter;
        }
        // (K_nmᵀ K_nm + λ n K_j) β = K_nmᵀ y, all products done naively here.
        let knm_t = linalg::transpose(&knm, n, m);
        let a = naive_matmul(&knm_t, &knm, m, n, m);
        let lhs: Vec<f64> = (0..m)
            .map(|j| (0..m).map(|k| (a[j * m + k] + lambda * n as f64 * kj[j * m + k]) * eval.beta[k]).sum())
            .collect();
        let rhs = naive_matmul(&knm_t, p.y(), m, n, 1);
        let res: Vec<f64> = lhs.iter().zip(&rhs).map(|(l, r)| l - r).collect();
        let rel = norm(&res) / norm(&rhs);
        println!("Nyström solve, jitter {jitter:.0e}: relative residual {rel:.2e}");
        assert!(rel < 1e-8, "{rel}");
        // D, data fit and the RKHS norm from their definitions.
        let pred = predict(&eval.beta, &params.z, &params.log_s, p.x()).unwrap();
        let fit = pred.iter().zip(p.y()).map(|(g, y)| (g - y).powi(2)).sum::<f64>() / n as f64;
        assert!((fit - eval.data_fit).abs() <= 1e-10 * fit);
        let kb = naive_matmul(&kj, &eval.beta, m, m, 1);
        let rkhs: f64 = kb.iter().zip(&eval.beta).map(|(a, b)| a * b).sum();
        assert!((rkhs - eval.rkhs_norm2).abs() <= 1e-9 * rkhs);
        assert!((eval.d_term - (fit + lambda * rkhs)).abs() <= 1e-9 * eval.d_term);
    }
}

#[test]
fn trace_identities_hold_against_the_n_by_n_forms() {
    let (n, m, d, lambda) = (40, 8, 3, 1e-2);
    let p = random_problem(n, d, 31);
    let params = random_params(&p, m, 32);
    let s = Ridge { lambda, jitter: 1e-8, weighting: Weighting::Paper, full_n: None };
    let eval = objective(&p, &params, &s).unwrap();

    // K̃ = K_nm K_j⁻¹ K_nmᵀ (n × n), explicitly.
    let knm = kernel::k_nm(p.x(), &params.z, &params.log_s);
    let mut kj = kernel::k_mm(&params.z, &params.log_s);
    for j in 0..m {
        kj[j * m + j] += s.jitter;
    }
    let kinv_knm_t = linalg::spd_solve(&kj, m, &linalg::transpose(&knm, n, m), n, "K_j").unwrap();
    let kt = naive_matmul(&knm, &kinv_knm_t, n, m, n);
    // T1 = Tr((K̃ + nλI)⁻¹ K̃).
    let mut shifted = kt.clone();
    for i in 0..n {
        shifted[i * n + i] += n as f64 * lambda;
    }
    let t1 = linalg::trace(&linalg::spd_solve(&shifted, n, &kt, n, "K~ + n lambda I").unwrap(), n);
    // T2 = Tr(K − K̃), K's diagonal being 1.
    let t2: f64 = (0..n).map(|i| 1.0 - kt[i * n + i]).sum();
    println!("T1: m×m {:.12} vs n×n {t1:.12}; T2: m×m {:.6e} vs n×n {t2:.6e}", eval.t1, eval.t2);
    assert!((eval.t1 - t1).abs() < 1e-9 * t1);
    assert!((eval.t2 - t2).abs() < 1e-7 * t2.abs().max(1e-3));
    // The loss from its parts, paper weighting.
    let c = 2.0 / (n as f64 * lambda);
    let want = 2.0 / n as f64 * t1 + c * t2 * eval.d_term + 2.0 * eval.d_term;
    assert!((eval.loss - want).abs() < 1e-9 * want);
    assert!(t1 > 0.0 && t1 < m as f64 && t2 > 0.0);
}

// ---------------------------------------------------------------------------------------------
// the gradient

#[test]
fn gradient_matches_finite_differences_small() {
    // The configuration method.md §6 was checked on.
    run_fd("n200 m20 d4", 200, 20, 4, 1e-3, Some(1e-9), usize::MAX, 41);
    run_fd("n200 m20 d4", 200, 20, 4, 1e-3, None, usize::MAX, 42);
}

#[test]
fn gradient_matches_finite_differences_d32() {
    run_fd("n300 m50 d32", 300, 50, 32, 1e-3, None, 300, 51);
}

#[test]
fn gradient_matches_finite_differences_large_lambda() {
    run_fd("n150 m15 d3 lambda 0.1", 150, 15, 3, 1e-1, None, usize::MAX, 61);
}

// ---------------------------------------------------------------------------------------------
// tuning

/// X ~ U(−1, 1)⁴, y = sin(3 x₀): only dimension 0 matters.
fn relevance_problem(n: usize, seed: u64) -> Problem {
    let mut rng = SplitMix64(seed);
    let x: Vec<f64> = (0..n * 4).map(|_| 2.0 * rng.unit() - 1.0).collect();
    let y: Vec<f64> = (0..n).map(|i| (3.0 * x[i * 4]).sin()).collect();
    Problem::new(x, y, 4).unwrap()
}

#[test]
fn tuning_learns_the_relevant_dimension() {
    let (n, m) = (400, 40);
    let p = relevance_problem(n, 71);
    let init = init_params(&p, m, 72, LengthScaleInit::default());
    let settings = Ridge::new(1e-4, m);
    let mut obj = Reference { problem: &p, settings };
    let first = obj.eval(&init).unwrap();
    let res = tune(&mut obj, init.clone(), &TuneSettings { patience: 0, ..Default::default() }, |_, _| true).unwrap();
    let s = res.params.length_scales();
    let last = res.history.last().unwrap();
    println!(
        "relevance: s0 {:?} -> {s:?}; loss {:.4e} -> {:.4e} (last); train mse {:.3e} -> {:.3e} (best, step {}) stop {:?}",
        init.length_scales(), first.loss, last.loss, first.data_fit, res.eval.data_fit, res.best_step, res.stop
    );
    assert_eq!(res.stop, StopReason::MaxSteps);
    assert_eq!(res.history.len(), 101);
    assert!(last.loss < first.loss, "loss must decrease");
    assert!(res.history.iter().map(|h| h.loss).fold(f64::INFINITY, f64::min) < 0.5 * first.loss);
    assert!(res.eval.data_fit < 0.5 * first.data_fit, "training error must decrease");
    for t in 1..4 {
        assert!(s[0] * 3.0 < s[t], "dimension 0 should be the most relevant: {s:?}");
    }
    // And it generalises: held-out error with the tuned model.
    let q = relevance_problem(500, 73);
    let g = predict(&res.eval.beta, &res.params.z, &res.params.log_s, q.x()).unwrap();
    let test = g.iter().zip(q.y()).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / 500.0;
    println!("relevance: held-out mse {test:.3e}");
    assert!(test < 1e-2);
}

#[test]
fn tuning_keeps_the_lowest_training_error() {
    let (n, m) = (200, 20);
    let p = random_problem(n, 4, 81);
    let init = random_params(&p, m, 82);
    let mut obj = Reference { problem: &p, settings: Ridge::new(1e-3, m) };
    // A large learning rate makes the iterates oscillate, so the best is not the last.
    let ts = TuneSettings { lr: 0.5, steps: 30, patience: 0, ..Default::default() };
    let mut seen = Vec::new();
    let res = tune(&mut obj, init, &ts, |step, e: &Eval| {
        seen.push((step, e.data_fit));
        true
    })
    .unwrap();
    let min = seen.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
    let argmin = seen.iter().find(|s| s.1 == min).unwrap().0;
    println!(
        "keep-best: min train mse {min:.4e} at step {argmin}, last {:.4e}; returned {:.4e} (step {})",
        seen.last().unwrap().1, res.eval.data_fit, res.best_step
    );
    assert_eq!(res.eval.data_fit, min);
    assert_eq!(res.best_step, argmin);
    assert_eq!(res.history.iter().map(|h| h.data_fit).collect::<Vec<_>>(), seen.iter().map(|s| s.1).collect::<Vec<_>>());
    // Re-evaluating the returned parameters reproduces the returned evaluation.
    assert_eq!(obj.eval(&res.params).unwrap(), res.eval);
}

#[test]
fn tuning_switches_cancel_and_early_stop() {
    let (n, m) = (120, 12);
    let p = random_problem(n, 3, 91);
    let init = random_params(&p, m, 92);
    let mut obj = Reference { problem: &p, settings: Ridge::new(1e-3, m) };
    let ts = TuneSettings { steps: 10, patience: 0, ..Default::default() };

    let r = tune(&mut obj, init.clone(), &TuneSettings { tune_theta: false, ..ts }, |_, _| true).unwrap();
    assert_eq!(r.params.log_s, init.log_s);
    let r = tune(&mut obj, init.clone(), &TuneSettings { tune_z: false, ..ts }, |_, _| true).unwrap();
    assert_eq!(r.params.z, init.z);
    let r = tune(&mut obj, init.clone(), &TuneSettings { tune_z: false, tune_theta: false, ..ts }, |_, _| true).unwrap();
    assert_eq!((r.stop, r.history.len(), r.params), (StopReason::NothingToTune, 1, init.clone()));

    let r = tune(&mut obj, init.clone(), &ts, |step, _| step < 3).unwrap();
    assert_eq!((r.stop, r.history.len()), (StopReason::Cancelled, 4));

    // Early stop: a tolerance no step can meet stops after `patience` evaluations.
    let r = tune(&mut obj, init.clone(), &TuneSettings { steps: 100, patience: 5, rel_tol: 10.0, ..ts }, |_, _| true).unwrap();
    assert_eq!((r.stop, r.history.len()), (StopReason::Converged, 6));

    assert!(matches!(tune(&mut obj, init, &TuneSettings { lr: -1.0, ..ts }, |_, _| true), Err(KrrError::Setting(_))));
}

/// An objective that fails after a few evaluations, to check the tuner returns the best so far.
struct Flaky<'a> {
    inner: Reference<'a>,
    left: usize,
}

impl Objective for Flaky<'_> {
    fn eval_grad(&mut self, params: &Params) -> Result<(Eval, Grad), KrrError> {
        if self.left == 0 {
            return Err(KrrError::NonFinite("injected".into()));
        }
        self.left -= 1;
        self.inner.eval_grad(params)
    }
}

#[test]
fn tuning_survives_a_failing_evaluation() {
    let p = random_problem(100, 3, 101);
    let init = random_params(&p, 10, 102);
    let inner = Reference { problem: &p, settings: Ridge::new(1e-3, 10) };
    let mut flaky = Flaky { inner, left: 3 };
    let r = tune(&mut flaky, init.clone(), &TuneSettings::default(), |_, _| true).unwrap();
    assert!(matches!(r.stop, StopReason::Failed(KrrError::NonFinite(_))));
    assert_eq!(r.history.len(), 3);
    let mut dead = Flaky { inner, left: 0 };
    assert!(tune(&mut dead, init, &TuneSettings::default(), |_, _| true).is_err());
}

// ---------------------------------------------------------------------------------------------
// initialisation and errors

#[test]
fn init_helpers() {
    let p = random_problem(50, 3, 111);
    let z = init_z(&p, 20, 5);
    assert_eq!(z.len(), 60);
    assert_eq!(z, init_z(&p, 20, 5), "seeded");
    assert_ne!(z, init_z(&p, 20, 6));
    let rows: Vec<&[f64]> = z.chunks(3).collect();
    for (a, ra) in rows.iter().enumerate() {
        assert!(p.x().chunks(3).any(|r| r == *ra), "row of X");
        for rb in &rows[..a] {
            assert_ne!(ra, rb, "distinct rows");
        }
    }
    assert_eq!(init_z(&p, 80, 5).len(), 150, "m > n takes all n rows");
    let ls = init_length_scales(&p, LengthScaleInit::Constant(0.001));
    assert!(ls.iter().all(|&l| (l - 0.001f64.ln()).abs() < 1e-15));
    // Constant dimension: gets the mean spread of the others.
    let x: Vec<f64> = (0..40).map(|i| if i % 2 == 0 { i as f64 } else { 3.0 }).collect();
    let q = Problem::new(x, vec![0.0; 20], 2).unwrap();
    let ls = init_length_scales(&q, LengthScaleInit::ScaledStd(1.0));
    assert!(ls.iter().all(|l| l.is_finite()) && (ls[0] - ls[1]).abs() < 1e-12);
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    assert!(matches!(Problem::new(vec![], vec![], 3), Err(KrrError::Empty(_))));
    assert!(matches!(Problem::new(vec![1.0; 6], vec![0.0; 2], 0), Err(KrrError::Empty(_))));
    assert!(matches!(Problem::new(vec![1.0; 7], vec![0.0; 2], 3), Err(KrrError::Shape(_))));
    assert!(matches!(Problem::new(vec![1.0, f64::NAN, 0.0, 0.0], vec![0.0; 2], 2), Err(KrrError::NonFinite(_))));
    assert!(matches!(Problem::new(vec![1.0; 4], vec![0.0, f64::INFINITY], 2), Err(KrrError::NonFinite(_))));
    assert!(matches!(Problem::from_f32(&[1.0, f32::NAN], &[0.0], 2), Err(KrrError::NonFinite(_))));

    let p = random_problem(30, 3, 121);
    let good = random_params(&p, 5, 122);
    let s = Ridge::new(1e-3, 5);
    assert!(objective(&p, &good, &s).is_ok());
    let wrong_d = Params { log_s: vec![0.0; 4], ..good.clone() };
    assert!(matches!(objective(&p, &wrong_d, &s), Err(KrrError::Shape(_))));
    let ragged = Params { z: good.z[..7].to_vec(), ..good.clone() };
    assert!(matches!(objective_and_grad(&p, &ragged, &s), Err(KrrError::Shape(_))));
    let no_z = Params { z: vec![], ..good.clone() };
    assert!(matches!(objective(&p, &no_z, &s), Err(KrrError::Empty(_))));
    let mut nan = good.clone();
    nan.z[2] = f64::NAN;
    assert!(matches!(objective_and_grad(&p, &nan, &s), Err(KrrError::NonFinite(_))));
    let mut nan = good.clone();
    nan.log_s[1] = f64::NAN;
    assert!(matches!(objective(&p, &nan, &s), Err(KrrError::NonFinite(_))));
    for bad in [Ridge { lambda: 0.0, ..s }, Ridge { lambda: f64::NAN, ..s }, Ridge { jitter: -1.0, ..s }] {
        assert!(matches!(objective(&p, &good, &bad), Err(KrrError::Setting(_))));
    }

    let beta = vec![1.0; 5];
    assert!(predict(&beta, &good.z, &good.log_s, &[0.0; 6]).is_ok());
    assert!(matches!(predict(&beta, &good.z, &good.log_s, &[0.0; 7]), Err(KrrError::Shape(_))));
    assert!(matches!(predict(&beta[..4], &good.z, &good.log_s, &[0.0; 6]), Err(KrrError::Shape(_))));
    assert!(matches!(predict(&[], &[], &good.log_s, &[0.0; 6]), Err(KrrError::Empty(_))));
    assert!(matches!(predict(&beta, &good.z, &[f64::NAN; 3], &[0.0; 6]), Err(KrrError::NonFinite(_))));
    // Errors display.
    let e = KrrError::NotPositiveDefinite { what: "K_mm + jitter I", index: 3, pivot: -1e-9 };
    assert!(e.to_string().contains("jitter"));
}

// ---------------------------------------------------------------------------------------------
// measurements (`cargo test --test krr -- --ignored --nocapture`)

#[test]
#[ignore]
fn timing_objective_and_grad_n20000_m500_d32() {
    let (n, m, d) = (20000, 500, 32);
    let p = random_problem(n, d, 131);
    let params = init_params(&p, m, 132, LengthScaleInit::default());
    let s = Ridge::new(1e-4, m);
    let t0 = Instant::now();
    let e = objective(&p, &params, &s).unwrap();
    let t_obj = t0.elapsed();
    let t0 = Instant::now();
    let (e2, _) = objective_and_grad(&p, &params, &s).unwrap();
    let t_grad = t0.elapsed();
    assert_eq!(e, e2);
    println!(
        "timing n={n} m={m} d={d}: objective {:.2} s, objective+gradient {:.2} s (loss {:.4e}, T1 {:.2}, T2 {:.3e})",
        t_obj.as_secs_f64(), t_grad.as_secs_f64(), e.loss, e.t1, e.t2
    );
}

/// A d = 32 problem with heterogeneous feature scales and a few relevant dimensions.
fn sweep_problem_d32(n: usize, seed: u64) -> Problem {
    let d = 32;
    let mut rng = SplitMix64(seed);
    let scales: Vec<f64> = (0..d).map(|t| 0.05 * 1.25f64.powi(t as i32)).collect(); // 0.05 … 50
    let x: Vec<f64> = (0..n * d).map(|i| gauss(&mut rng) * scales[i % d]).collect();
    let y: Vec<f64> = (0..n)
        .map(|i| {
            let r = &x[i * d..(i + 1) * d];
            (2.0 * r[20] / scales[20]).sin() + 0.5 * (r[5] / scales[5]) * (r[27] / scales[27]).tanh()
        })
        .collect();
    Problem::new(x, y, d).unwrap()
}

#[test]
#[ignore]
fn length_scale_init_sweep() {
    let inits = [
        LengthScaleInit::Constant(0.001),
        LengthScaleInit::Constant(1.0),
        LengthScaleInit::ScaledStd(0.25),
        LengthScaleInit::ScaledStd(0.5),
        LengthScaleInit::ScaledStd(1.0),
        LengthScaleInit::ScaledStd(2.0),
        LengthScaleInit::ScaledStd(4.0),
    ];
    type Case = (&'static str, Box<dyn Fn(usize, u64) -> Problem>, usize, usize, f64);
    let cases: [Case; 2] = [
        ("d4 sin(3x0)", Box::new(relevance_problem), 400, 40, 1e-4),
        ("d32 mixed scales", Box::new(sweep_problem_d32), 2000, 100, 1e-4),
    ];
    for (name, make, n, m, lambda) in cases.iter() {
        let train = make(*n, 1);
        let test = make(1000, 2);
        for init in inits {
            let params = init_params(&train, *m, 3, init);
            let mut obj = Reference { problem: &train, settings: Ridge::new(*lambda, *m) };
            let e0 = match obj.eval(&params) {
                Ok(e) => e,
                Err(e) => {
                    println!("{name:18} {init:?}: initial evaluation failed: {e}");
                    continue;
                }
            };
            let r = tune(&mut obj, params, &TuneSettings::default(), |_, _| true);
            match r {
                Ok(r) => {
                    let g = predict(&r.eval.beta, &r.params.z, &r.params.log_s, test.x()).unwrap();
                    let var = {
                        let mu = test.y().iter().sum::<f64>() / 1000.0;
                        test.y().iter().map(|v| (v - mu).powi(2)).sum::<f64>() / 1000.0
                    };
                    let mse = g.iter().zip(test.y()).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / 1000.0;
                    println!(
                        "{name:18} {init:?}: train mse {:.3e} -> {:.3e} (best step {:3}, {} evals, {:?}); held-out mse/var {:.3e}",
                        e0.data_fit, r.eval.data_fit, r.best_step, r.history.len(), r.stop, mse / var
                    );
                }
                Err(e) => println!("{name:18} {init:?}: tuning failed: {e}"),
            }
        }
    }
}

/// A flat loss with a falling training error: the early stop must wait for the error too,
/// since the error is what the tuner keeps the best of.
#[test]
fn early_stop_waits_while_the_training_error_falls() {
    struct FlatLoss(usize);
    impl nkrr::krr::Objective for FlatLoss {
        fn eval_grad(&mut self, p: &Params) -> Result<(Eval, nkrr::krr::Grad), KrrError> {
            self.0 += 1;
            let eval = Eval { loss: 1.0, data_fit: 1.0 / self.0 as f64, rkhs_norm2: 0.0, d_term: 0.0, t1: 0.0, t2: 0.0, beta: vec![0.0] };
            Ok((eval, nkrr::krr::Grad { log_s: vec![1e-3; p.log_s.len()], z: vec![1e-3; p.z.len()] }))
        }
    }
    let init = Params { log_s: vec![0.0], z: vec![0.0] };
    let ts = TuneSettings { steps: 40, patience: 5, ..Default::default() };
    let r = tune(&mut FlatLoss(0), init.clone(), &ts, |_, _| true).unwrap();
    assert_eq!(r.stop, StopReason::MaxSteps);
    assert_eq!(r.best_step, 40);
}

/// The asynchronous driver (for the browser's GPU objective) takes the same steps as the
/// blocking one.
#[test]
fn async_tuning_matches_blocking_tuning() {
    let (n, m) = (150, 10);
    let p = random_problem(n, 3, 31);
    let init = random_params(&p, m, 32);
    let settings = Ridge::new(1e-3, m);
    let ts = TuneSettings { steps: 15, ..Default::default() };
    let blocking = tune(&mut Reference { problem: &p, settings }, init.clone(), &ts, |_, _| true).unwrap();
    let asynchronous = pollster::block_on(nkrr::krr::tune_async(
        |params: Params, needs_grad: bool| {
            let p = &p;
            async move {
                if needs_grad {
                    objective_and_grad(p, &params, &settings).map(|(e, g)| (e, Some(g)))
                } else {
                    objective(p, &params, &settings).map(|e| (e, None))
                }
            }
        },
        init,
        &ts,
        |_, _| true,
    ))
    .unwrap();
    assert_eq!(blocking.params, asynchronous.params);
    assert_eq!(blocking.history, asynchronous.history);
    assert_eq!(blocking.stop, asynchronous.stop);
}

/// What `field::fit` does with `--tune-pairs`: tune θ and Z on a subsample of the pairs, then
/// solve β once on all of them. On a problem whose answer needs the right length-scales, the
/// held-out error must match tuning on all pairs, and beat not tuning at all by far; β from
/// the subsample alone (no final solve) must be worse, or the final solve would be pointless.
#[test]
fn tuning_on_a_subsample_then_solving_on_all_matches_full_tuning() {
    let (n, m, lambda) = (3000, 60, 1e-4);
    let train = relevance_problem(n, 81);
    let test = relevance_problem(1000, 82);
    let ridge = Ridge::new(lambda, m);
    let ts = TuneSettings { steps: 60, ..Default::default() };
    let held_out = |beta: &[f64], p: &Params| {
        let g = predict(beta, &p.z, &p.log_s, test.x()).unwrap();
        g.iter().zip(test.y()).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / 1000.0
    };

    let full = tune(&mut Reference { problem: &train, settings: ridge }, init_params(&train, m, 3, LengthScaleInit::default()), &ts, |_, _| true).unwrap();
    let mse_full = held_out(&full.eval.beta, &full.params);

    let rows: Vec<usize> = (0..n).step_by(10).collect();
    let sub = train.select(&rows);
    assert_eq!((sub.n(), sub.d()), (300, 4));
    assert_eq!(&sub.x()[4..8], &train.x()[40..44]);
    let tuned = tune(&mut Reference { problem: &sub, settings: ridge }, init_params(&sub, m, 3, LengthScaleInit::default()), &ts, |_, _| true).unwrap();
    let beta_all = objective(&train, &tuned.params, &ridge).unwrap().beta;
    let mse_sub = held_out(&beta_all, &tuned.params);
    let mse_sub_only = held_out(&tuned.eval.beta, &tuned.params);

    let init = init_params(&train, m, 3, LengthScaleInit::default());
    let mse_untuned = held_out(&objective(&train, &init, &ridge).unwrap().beta, &init);
    println!("held-out mse: full {mse_full:.3e}, subsample + solve on all {mse_sub:.3e}, subsample only {mse_sub_only:.3e}, untuned {mse_untuned:.3e}");
    assert!(mse_sub < 1.5 * mse_full, "subsample tuning: {mse_sub:.3e} vs full {mse_full:.3e}");
    assert!(mse_sub < 0.2 * mse_untuned, "subsample tuning {mse_sub:.3e} vs untuned {mse_untuned:.3e}");
    assert!(mse_sub < mse_sub_only, "the solve on all pairs {mse_sub:.3e} vs the subsample's β {mse_sub_only:.3e}");
}

/// `Ridge::full_n`: a uniform subsample's loss estimates the loss on all the pairs (both
/// weightings), where the subsample's own loss, which weighs the complexity terms for fewer
/// pairs, does not (Falkon's weighting). T1 = Tr(H⁻¹A) is not linear in the pairs, hence the
/// few per cent left.
#[test]
fn a_subsample_estimates_the_full_objective() {
    let (n, m, lambda) = (4000, 40, 1e-4);
    let all = relevance_problem(n, 91);
    let params = init_params(&all, m, 3, LengthScaleInit::default());
    let rows: Vec<usize> = (0..n).step_by(4).collect();
    let sub = all.select(&rows);
    for weighting in [Weighting::Falkon, Weighting::Paper] {
        let ridge = Ridge { weighting, ..Ridge::new(lambda, m) };
        let full = objective(&all, &params, &ridge).unwrap();
        let own = objective(&sub, &params, &ridge).unwrap();
        let est = objective(&sub, &params, &Ridge { full_n: Some(n), ..ridge }).unwrap();
        let rel = |e: &Eval| (e.loss - full.loss).abs() / full.loss;
        println!("{weighting:?}: full loss {:.5e}, subsample's own {:.5e} ({:.1e}), as an estimate {:.5e} ({:.1e})", full.loss, own.loss, rel(&own), est.loss, rel(&est));
        assert!(rel(&est) < 0.1, "{weighting:?}: estimate off by {:.3}", rel(&est));
        // With the paper's c = 2/(nλ), c·T2 does not depend on n and only T1's small term moves;
        // with Falkon's, the subsample's own loss weighs T2·D four times too heavily here.
        if weighting == Weighting::Falkon {
            assert!(rel(&est) < 0.25 * rel(&own), "{weighting:?}: the estimate is no better than the subsample's own loss");
        }
        // β and D do not depend on full_n.
        assert_eq!((est.beta.clone(), est.d_term), (own.beta.clone(), own.d_term));
    }
}

/// Validated tuning (`tune_scored`): the iterate with the lowest score is kept, not the lowest
/// training error, and the loop stops once the score has not improved for `patience`
/// evaluations, even while the loss and the training error still fall.
#[test]
fn scored_tuning_keeps_the_lowest_score_and_stops_when_it_rises() {
    struct Falling(usize);
    impl nkrr::krr::Objective for Falling {
        fn eval_grad(&mut self, p: &Params) -> Result<(Eval, nkrr::krr::Grad), KrrError> {
            self.0 += 1;
            let v = 1.0 / self.0 as f64;
            let eval = Eval { loss: v, data_fit: v, rkhs_norm2: 0.0, d_term: 0.0, t1: 0.0, t2: 0.0, beta: vec![0.0] };
            Ok((eval, nkrr::krr::Grad { log_s: vec![1e-3; p.log_s.len()], z: vec![1e-3; p.z.len()] }))
        }
    }
    let init = Params { log_s: vec![0.0], z: vec![0.0] };
    let ts = TuneSettings { steps: 100, patience: 4, ..Default::default() };
    // The score falls to its lowest at the 7th evaluation (step 6), then rises.
    let mut calls = 0;
    let score = |_: &Params, _: &Eval| {
        calls += 1;
        Ok(Some((calls as f64 - 7.0).abs() + 1.0))
    };
    let r = nkrr::krr::tune_scored(&mut Falling(0), init.clone(), &ts, score, |_, _| true).unwrap();
    assert_eq!(r.best_step, 6);
    assert_eq!(r.stop, StopReason::Converged);
    assert_eq!(r.history.len(), 7 + 4, "stops after `patience` evaluations without a better score");
    assert_eq!(r.history[6].score, Some(1.0));
    // Unscored, the same objective runs to the end and keeps the last (lowest training error).
    let r = tune(&mut Falling(0), init, &ts, |_, _| true).unwrap();
    assert_eq!((r.best_step, r.stop), (100, StopReason::MaxSteps));
    assert!(r.history.iter().all(|h| h.score.is_none()));
}

/// `predict` (blocks of the kernel matrix by the expanded distance, folded with β) against the
/// definition, one query and one centre at a time, across the block boundary (4096 queries);
/// and the expanded kernel against the difference form, also for points far from the origin.
#[test]
fn predict_matches_the_definition() {
    let (nq, m, d) = (5000, 23, 6);
    let queries = random_problem(nq, d, 101);
    let p = random_params(&queries, m, 102);
    let beta: Vec<f64> = uniform_vec(m, 103).iter().map(|v| v - 0.5).collect();
    let got = predict(&beta, &p.z, &p.log_s, queries.x()).unwrap();
    let inv_s = kernel::inv_scales(&p.log_s);
    assert_eq!(got.len(), nq);
    for (i, q) in queries.x().chunks_exact(d).enumerate() {
        let want: f64 = (0..m).map(|j| beta[j] * kernel::k_pair(q, &p.z[j * d..(j + 1) * d], &inv_s)).sum();
        assert!((got[i] - want).abs() <= 1e-12 * (1.0 + want.abs()), "query {i}: {} vs {want}", got[i]);
    }
    for offset in [0.0, 30.0] {
        let a: Vec<f64> = queries.x()[..300 * d].iter().map(|v| v + offset).collect();
        let b: Vec<f64> = p.z.iter().map(|v| v + offset).collect();
        let (k1, k2) = (kernel::cross(&a, &b, &inv_s), kernel::cross_expanded(&a, &b, &inv_s));
        let worst = k1.iter().zip(&k2).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        println!("expanded vs difference kernel, offset {offset}: worst {worst:.1e}");
        assert!(worst < 1e-10, "offset {offset}: {worst:e}");
    }
}
