//! The f64 reference of the tuning objective and its gradient (`docs/method.md` §3–§6, §8).
//!
//! Notation (§0, §5): training features `X: n × d`, targets `y: n`, inducing points `Z: m × d`,
//! length-scales `s = exp(log_s)`. With the jittered `K_j = K_mm + jitter·I` (§8):
//!
//! ```text
//! A = K_nmᵀ K_nm,   H = A + nλ K_j,   b = K_nmᵀ y,   β = H⁻¹ b,   r = K_nm β − y
//! D  = (1/n) rᵀr + λ βᵀ K_j β                       (training error + RKHS penalty)
//! T1 = Tr(H⁻¹ A)       = Tr((K̃ + nλI)⁻¹ K̃)        (push-through identity; K̃ = K_nm K_j⁻¹ K_nmᵀ)
//! T2 = n − Tr(K_j⁻¹ A) = Tr(K − K̃)
//! L  = (2/n) T1 + c T2 D + 2 D,   c = 2/(n²λ) (Falkon, default) or 2/(nλ) (paper)
//! ```
//!
//! **Jitter.** Everything — β, D, K̃, T2 and the gradient — uses `K_j` in place of `K_mm`. That is
//! the exact objective of a slightly modified model (a Nyström model whose regulariser and
//! approximation use `K_j`), so the gradient formulas of §6 stay exact with `K_mm → K_j`: the
//! jitter does not depend on (s, Z), so `∂K_j/∂θ = ∂K_mm/∂θ`. The GPU (f32) implementation must
//! use the same jitter to be comparable.
//!
//! **Weighting.** The loss is reported in the §5 form for both weightings; Falkon's own
//! `NystromCompReg` value is `(n/2)·L` with Falkon's `c` (§4). Adam is invariant to that scale.
//!
//! **Cost.** `K_nm` (n·m·d), `A` (n·m²/2, symmetric), `K_nm W` for the gradient (n·m²), about
//! `3.5 m³` multiply-adds of m × m algebra (`m³` for the objective: two Cholesky factors and two
//! inverses; `2.5 m³` for the gradient's m × m part, see `mm_grad`), and two n·m·d passes for
//! the chain rule. The products are blocked and threaded ([`linalg`]). Memory: `K_nm` (n·m f64)
//! plus one row block of `K_nm W`.

use super::kernel;
use super::linalg::{self, dot};
use super::tune::Objective;
use super::KrrError;

/// Which constant multiplies `T2·D` in the loss (`docs/method.md` §4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Weighting {
    /// Falkon's `NystromCompReg` (what the paper ran): `c = 2/(n² λ)`.
    #[default]
    Falkon,
    /// The paper's printed eq. 11–12: `c = 2/(n λ)` — the trace term n times heavier.
    Paper,
}

impl Weighting {
    /// The constant `c` of §5 for `n` training points and regularisation `lambda`.
    pub fn c(self, n: usize, lambda: f64) -> f64 {
        let n = n as f64;
        match self {
            Weighting::Falkon => 2.0 / (n * n * lambda),
            Weighting::Paper => 2.0 / (n * lambda),
        }
    }
}

/// Training data: features `x` (`n × d`, row-major) and targets `y` (`n`), validated.
#[derive(Clone, Debug, PartialEq)]
pub struct Problem {
    x: Vec<f64>,
    y: Vec<f64>,
    n: usize,
    d: usize,
}

impl Problem {
    /// Checks `n > 0`, `d > 0`, `x.len() == n·d` and that every value is finite.
    pub fn new(x: Vec<f64>, y: Vec<f64>, d: usize) -> Result<Self, KrrError> {
        let n = y.len();
        if d == 0 {
            return Err(KrrError::Empty("feature dimension d = 0".into()));
        }
        if n == 0 {
            return Err(KrrError::Empty("no training points (n = 0)".into()));
        }
        if x.len() != n * d {
            return Err(KrrError::Shape(format!(
                "x has {} values, expected n·d = {n}·{d} = {}",
                x.len(),
                n * d
            )));
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite(format!("x[{}, {}] = {}", i / d, i % d, x[i])));
        }
        if let Some(i) = y.iter().position(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite(format!("y[{i}] = {}", y[i])));
        }
        Ok(Problem { x, y, n, d })
    }

    /// The same from f32 data (as the network produces it), widened to f64.
    pub fn from_f32(x: &[f32], y: &[f32], d: usize) -> Result<Self, KrrError> {
        Problem::new(x.iter().map(|&v| v as f64).collect(), y.iter().map(|&v| v as f64).collect(), d)
    }

    /// Features, `n × d` row-major.
    pub fn x(&self) -> &[f64] {
        &self.x
    }
    /// Targets, length `n`.
    pub fn y(&self) -> &[f64] {
        &self.y
    }
    /// Number of training points.
    pub fn n(&self) -> usize {
        self.n
    }
    /// Feature dimension.
    pub fn d(&self) -> usize {
        self.d
    }
}

/// The tuned parameters: log length-scales (`d`) and inducing points (`m × d`, row-major).
///
/// Length-scales are optimised in log space (§6: "optimise log s"): positivity for free, and
/// Adam's per-coordinate step then acts multiplicatively on `s`.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    pub log_s: Vec<f64>,
    pub z: Vec<f64>,
}

impl Params {
    /// The length-scales `s = exp(log_s)`.
    pub fn length_scales(&self) -> Vec<f64> {
        self.log_s.iter().map(|l| l.exp()).collect()
    }

    /// Number of inducing points for feature dimension `d` after checking the shapes (`log_s`
    /// has `d` entries, `z` a positive multiple of `d`) and that every value is finite.
    pub fn check(&self, d: usize) -> Result<usize, KrrError> {
        if self.log_s.len() != d {
            return Err(KrrError::Shape(format!("log_s has {} entries, expected d = {d}", self.log_s.len())));
        }
        if d == 0 || self.z.is_empty() {
            return Err(KrrError::Empty("no inducing points (m = 0)".into()));
        }
        if !self.z.len().is_multiple_of(d) {
            return Err(KrrError::Shape(format!("z has {} values, not a multiple of d = {d}", self.z.len())));
        }
        if let Some(i) = self.log_s.iter().position(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite(format!("log_s[{i}] = {}", self.log_s[i])));
        }
        if let Some(i) = self.z.iter().position(|v| !v.is_finite()) {
            return Err(KrrError::NonFinite(format!("z[{}, {}] = {}", i / d, i % d, self.z[i])));
        }
        Ok(self.z.len() / d)
    }
}

/// Fixed (not tuned) settings of the objective.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Ridge parameter λ (> 0); the KRR "variance" is `λ n` as in Falkon (§4).
    pub lambda: f64,
    /// Absolute jitter added to the diagonal of `K_mm` (≥ 0), see the module docs and §8.
    pub jitter: f64,
    /// Which `c` in front of `T2·D`.
    pub weighting: Weighting,
}

impl Settings {
    /// Default jitter per inducing point: `jitter = 1e-6 · m` (§8's suggestion). K_mm has a unit
    /// diagonal, so this is a relative jitter; at m = 500 it is 5e-4, comfortably above what an
    /// f32 Cholesky of a 500 × 500 Gaussian Gram matrix needs (≈ m·ε_f32 ≈ 3e-5), and the f64
    /// reference uses the same value so that the two compute the same objective.
    pub const JITTER_PER_CENTRE: f64 = 1e-6;

    /// `lambda`, the default jitter for `m` inducing points, Falkon's weighting.
    pub fn new(lambda: f64, m: usize) -> Self {
        Settings { lambda, jitter: Self::JITTER_PER_CENTRE * m as f64, weighting: Weighting::Falkon }
    }

    fn check(&self) -> Result<(), KrrError> {
        if self.lambda <= 0.0 || !self.lambda.is_finite() {
            return Err(KrrError::Setting(format!("lambda must be finite and > 0, got {}", self.lambda)));
        }
        if self.jitter < 0.0 || !self.jitter.is_finite() {
            return Err(KrrError::Setting(format!("jitter must be finite and >= 0, got {}", self.jitter)));
        }
        Ok(())
    }
}

/// One evaluation of the objective at some parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Eval {
    /// `L = (2/n) T1 + c T2 D + 2 D` (§5 form, for both weightings).
    pub loss: f64,
    /// Training squared error `(1/n) ‖K_nm β − y‖²` — what the tuner keeps the best of.
    pub data_fit: f64,
    /// `‖g‖²_H = βᵀ K_j β`.
    pub rkhs_norm2: f64,
    /// `D = data_fit + λ ‖g‖²_H`.
    pub d_term: f64,
    /// Effective dimension `T1 = Tr(H⁻¹ A)`.
    pub t1: f64,
    /// Nyström trace error `T2 = Tr(K − K̃)`.
    pub t2: f64,
    /// Nyström coefficients β (length m): `g(x) = Σ_j β_j k(x, z_j)`.
    pub beta: Vec<f64>,
}

/// Gradient of [`Eval::loss`] with respect to [`Params`] (same shapes).
#[derive(Clone, Debug, PartialEq)]
pub struct Grad {
    /// `∂L/∂log s_d = s_d · ∂L/∂s_d`.
    pub log_s: Vec<f64>,
    /// `∂L/∂Z`, `m × d` row-major.
    pub z: Vec<f64>,
}

/// The forward pass, keeping what the backward pass needs.
struct Forward {
    n: usize,
    m: usize,
    knm: Vec<f64>,
    kmm: Vec<f64>,
    lk: Vec<f64>,
    a: Vec<f64>,
    h_inv: Vec<f64>,
    kj_inv: Vec<f64>,
    r: Vec<f64>,
    c: f64,
    eval: Eval,
}

fn forward(problem: &Problem, params: &Params, settings: &Settings) -> Result<Forward, KrrError> {
    settings.check()?;
    let (n, d) = (problem.n, problem.d);
    let m = params.check(d)?;
    let lambda = settings.lambda;
    let nl = n as f64 * lambda;

    // §5: the n-sized work is K_nm, A = K_nmᵀ K_nm and b = K_nmᵀ y; the rest is m × m.
    let knm = kernel::k_nm(&problem.x, &params.z, &params.log_s);
    let kmm = kernel::k_mm(&params.z, &params.log_s);
    let mut kj = kmm.clone();
    for j in 0..m {
        kj[j * m + j] += settings.jitter;
    }
    let a = linalg::gram(&knm, n, m);
    let b = linalg::matvec_t(&knm, &problem.y, n, m);

    let MmForward { lk, beta, h_inv, kj_inv, t1, t2 } = mm_forward(&a, &kj, &b, nl, n as f64, m)?;
    let mut r = linalg::matvec(&knm, &beta, n, m);
    for (ri, yi) in r.iter_mut().zip(&problem.y) {
        *ri -= yi;
    }
    let data_fit = dot(&r, &r) / n as f64;
    let rkhs_norm2 = dot(&beta, &linalg::matvec(&kj, &beta, m, m));
    let d_term = data_fit + lambda * rkhs_norm2;

    let c = settings.weighting.c(n, lambda);
    let loss = 2.0 / n as f64 * t1 + c * t2 * d_term + 2.0 * d_term;
    if !loss.is_finite() {
        return Err(KrrError::NonFinite(format!(
            "objective: loss = {loss} (T1 = {t1}, T2 = {t2}, D = {d_term})"
        )));
    }
    let eval = Eval { loss, data_fit, rkhs_norm2, d_term, t1, t2, beta };
    Ok(Forward { n, m, knm, kmm, lk, a, h_inv, kj_inv, r, c, eval })
}

/// The objective at `params` (no gradient). See the module docs for the definitions.
pub fn objective(problem: &Problem, params: &Params, settings: &Settings) -> Result<Eval, KrrError> {
    forward(problem, params, settings).map(|f| f.eval)
}

/// Rows of `K_nm` per block when forming `G_nm = K_nm W + s_r r βᵀ` (never stored whole).
const ROW_BLOCK: usize = 256;

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

/// The m × m inputs of the gradient's m × m part (method.md §6).
pub(crate) struct MmParts<'a> {
    pub h_inv: &'a [f64],
    /// Cholesky factor of `K_j`.
    pub lk: &'a [f64],
    pub kj_inv: &'a [f64],
    pub a: &'a [f64],
    pub beta: &'a [f64],
    pub lambda: f64,
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
                grow[k] = -2.0 * p.lambda * hah + cd * grow[k] + s_beta * (bj * p.beta[k]);
            }
        }
    });
    let mut w = hkh;
    linalg::par_row_units(&mut w, m, m, ROWS, threads, &work, |u0, u1, rows| {
        for (j, wrow) in (u0 * ROWS..(u1 * ROWS).min(m)).zip(rows.chunks_mut(m)) {
            for (wv, kv) in wrow.iter_mut().zip(&p.kj_inv[j * m..(j + 1) * m]) {
                // (4/n) M1 with M1 = nλ H⁻¹K_jH⁻¹ is 4λ H⁻¹K_jH⁻¹.
                *wv = 4.0 * p.lambda * *wv - 2.0 * cd * kv;
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

/// The objective and its exact gradient with respect to `log_s` and `Z` (`docs/method.md` §6).
///
/// Reverse mode, by hand:
/// - `∂L/∂K_nm = G_nm = K_nm W + s_r r βᵀ` with `M1 = nλ H⁻¹ K_j H⁻¹`,
///   `W = (4/n) M1 − 2cD K_j⁻¹`, `s_r = (c T2 + 2)(2/n)` — the data-fit part uses the envelope
///   theorem (β minimises nD, so D's total derivative holds β fixed);
/// - `∂L/∂K_mm = G_mm = −2λ H⁻¹AH⁻¹ + cD K_j⁻¹AK_j⁻¹ + (c T2 + 2) λ ββᵀ`;
/// - chain through the kernel with `P = G_nm ∘ K_nm`, `Q = G_mm ∘ K_mm`:
///   `∂L/∂z_jd = [Σ_i P_ij (x_id − z_jd) + 2 Σ_k Q_jk (z_kd − z_jd)] / s_d²`,
///   `∂L/∂s_d = [Σ_ij P_ij (x_id − z_jd)² + Σ_jk Q_jk (z_jd − z_kd)²] / s_d³`,
///   and `∂L/∂log s_d = s_d ∂L/∂s_d`.
///
/// `G_mm` is the gradient with respect to the entries of `K_mm` taken as independent (it is
/// symmetric), hence the factor 2 in the `Z` term: `z_j` enters row j and column j.
pub fn objective_and_grad(problem: &Problem, params: &Params, settings: &Settings) -> Result<(Eval, Grad), KrrError> {
    let f = forward(problem, params, settings)?;
    let (n, m, d) = (f.n, f.m, problem.d);
    let lambda = settings.lambda;
    let nf = n as f64;
    let (c, dd, t2) = (f.c, f.eval.d_term, f.eval.t2);
    let beta = &f.eval.beta;

    let MmGrad { w, gmm, s_r } = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &f.a, beta, lambda, c, dd, t2, n: nf, m });

    let x = &problem.x;
    let z = &params.z;
    // Σ Q (z − z) and Σ Q (z − z)², then the P side on top; all before the 1/s² factor.
    let (mut gz, mut gs) = kmm_side(&gmm, &f.kmm, z, m, d);
    let mut diff = vec![0.0; d];

    // K_nm part, one block of rows at a time: P_ij = (K_nm W + s_r r βᵀ)_ij · K_nm,ij.
    for i0 in (0..n).step_by(ROW_BLOCK) {
        let i1 = (i0 + ROW_BLOCK).min(n);
        let rows = i1 - i0;
        let kblk = &f.knm[i0 * m..i1 * m];
        let gblk = linalg::matmul(kblk, &w, rows, m, m);
        for ii in 0..rows {
            let i = i0 + ii;
            let xi = &x[i * d..(i + 1) * d];
            let sr_ri = s_r * f.r[i];
            for j in 0..m {
                let p = (gblk[ii * m + j] + sr_ri * beta[j]) * kblk[ii * m + j];
                let zj = &z[j * d..(j + 1) * d];
                let gzj = &mut gz[j * d..(j + 1) * d];
                for t in 0..d {
                    let e = xi[t] - zj[t];
                    diff[t] = e;
                    gzj[t] += p * e;
                }
                for t in 0..d {
                    gs[t] += p * diff[t] * diff[t];
                }
            }
        }
    }
    let inv_s2: Vec<f64> = params.log_s.iter().map(|l| (-2.0 * l).exp()).collect();
    for j in 0..m {
        for t in 0..d {
            gz[j * d + t] *= inv_s2[t];
        }
    }
    // ∂L/∂log s = s · ∂L/∂s = s · gs / s³ = gs / s².
    let glog: Vec<f64> = gs.iter().zip(&inv_s2).map(|(g, w)| g * w).collect();
    if glog.iter().chain(&gz).any(|v| !v.is_finite()) {
        return Err(KrrError::NonFinite("objective gradient".into()));
    }
    Ok((f.eval, Grad { log_s: glog, z: gz }))
}

/// The Nyström predictor `g(q) = Σ_j β_j k(q, z_j)` at each row of `queries` (`n_q × d`, with
/// `d = log_s.len()`), for coefficients `beta` (m) and inducing points `z` (`m × d`).
pub fn predict(beta: &[f64], z: &[f64], log_s: &[f64], queries: &[f64]) -> Result<Vec<f64>, KrrError> {
    let d = log_s.len();
    let m = beta.len();
    if d == 0 || m == 0 {
        return Err(KrrError::Empty(format!("predict: d = {d}, m = {m}")));
    }
    if z.len() != m * d {
        return Err(KrrError::Shape(format!("predict: z has {} values, expected m·d = {}", z.len(), m * d)));
    }
    if !queries.len().is_multiple_of(d) {
        return Err(KrrError::Shape(format!("predict: {} query values, not a multiple of d = {d}", queries.len())));
    }
    if beta.iter().chain(z).chain(log_s).any(|v| !v.is_finite()) {
        return Err(KrrError::NonFinite("predict: beta, z or log_s".into()));
    }
    let inv_s = kernel::inv_scales(log_s);
    Ok(queries
        .chunks_exact(d)
        .map(|q| (0..m).map(|j| beta[j] * kernel::k_pair(q, &z[j * d..(j + 1) * d], &inv_s)).sum())
        .collect())
}

/// The f64 reference as an [`Objective`] for the tuner.
#[derive(Clone, Copy, Debug)]
pub struct Reference<'a> {
    pub problem: &'a Problem,
    pub settings: Settings,
}

impl Objective for Reference<'_> {
    fn eval_grad(&mut self, params: &Params) -> Result<(Eval, Grad), KrrError> {
        objective_and_grad(self.problem, params, &self.settings)
    }
    fn eval(&mut self, params: &Params) -> Result<Eval, KrrError> {
        objective(self.problem, params, &self.settings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// Random inputs of the m × m algebra as the objective meets them: a Gram matrix `A` of a
    /// Gaussian `K_nm`, `K_j` of the same centres, `b`.
    #[allow(clippy::type_complexity)]
    fn mm_inputs(n: usize, m: usize, d: usize, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let mut rng = SplitMix64(seed);
        let x: Vec<f64> = (0..n * d).map(|_| rng.unit() - 0.5).collect();
        let y: Vec<f64> = (0..n).map(|_| rng.unit() - 0.5).collect();
        let z: Vec<f64> = (0..m * d).map(|_| rng.unit() - 0.5).collect();
        let log_s = vec![(0.3f64 * (d as f64).sqrt()).ln(); d];
        let knm = kernel::k_nm(&x, &z, &log_s);
        let kmm = kernel::k_mm(&z, &log_s);
        let a = linalg::gram(&knm, n, m);
        let b = linalg::matvec_t(&knm, &y, n, m);
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
        let g = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a, beta: &f.beta, lambda, c, dd: 0.1, t2: f.t2, n: nf, m });
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
            let g = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &a, beta: &f.beta, lambda, c, dd, t2: f.t2, n: nf, m });
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
            let parts = MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &a, beta: &f.beta, lambda, c, dd: 0.1, t2: f.t2, n: nf, m };
            let t_grad = best_of(&mut || drop(mm_grad(&parts)));
            let t_q = best_of(&mut || drop(kmm_side(&g.gmm, &kmm, &z, m, d)));
            println!("  m {m}: mm_forward {t_fwd:.1} ms, mm_grad {t_grad:.1} ms, kmm_side {t_q:.1} ms");
        }
    }
}
