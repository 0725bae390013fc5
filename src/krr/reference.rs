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
//! **Cost.** `K_nm` (n·m·d), `A` (n·m²/2, symmetric), `K_nm W` for the gradient (n·m²), a few m³
//! products and inverses, and two n·m·d passes for the chain rule. Memory: `K_nm` (n·m f64) plus
//! one row block of `K_nm W`.

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
    kj: Vec<f64>,
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

    let mut h = a.clone();
    for (hv, kv) in h.iter_mut().zip(&kj) {
        *hv += nl * kv;
    }
    let lh = linalg::cholesky(&h, m, "H = K_nm^T K_nm + n lambda (K_mm + jitter I)")?;
    let beta = linalg::cholesky_solve(&lh, m, &b, 1);
    let mut r = linalg::matvec(&knm, &beta, n, m);
    for (ri, yi) in r.iter_mut().zip(&problem.y) {
        *ri -= yi;
    }
    let data_fit = dot(&r, &r) / n as f64;
    let rkhs_norm2 = dot(&beta, &linalg::matvec(&kj, &beta, m, m));
    let d_term = data_fit + lambda * rkhs_norm2;

    let h_inv = linalg::cholesky_inverse(&lh, m);
    let lk = linalg::cholesky(&kj, m, "K_mm + jitter I")?;
    let kj_inv = linalg::cholesky_inverse(&lk, m);
    let t1 = linalg::trace_prod(&h_inv, &a, m);
    let t2 = n as f64 - linalg::trace_prod(&kj_inv, &a, m);

    let c = settings.weighting.c(n, lambda);
    let loss = 2.0 / n as f64 * t1 + c * t2 * d_term + 2.0 * d_term;
    if !loss.is_finite() {
        return Err(KrrError::NonFinite(format!(
            "objective: loss = {loss} (T1 = {t1}, T2 = {t2}, D = {d_term})"
        )));
    }
    let eval = Eval { loss, data_fit, rkhs_norm2, d_term, t1, t2, beta };
    Ok(Forward { n, m, knm, kmm, kj, a, h_inv, kj_inv, r, c, eval })
}

/// The objective at `params` (no gradient). See the module docs for the definitions.
pub fn objective(problem: &Problem, params: &Params, settings: &Settings) -> Result<Eval, KrrError> {
    forward(problem, params, settings).map(|f| f.eval)
}

/// Rows of `K_nm` per block when forming `G_nm = K_nm W + s_r r βᵀ` (never stored whole).
const ROW_BLOCK: usize = 256;

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
/// The m × m inputs of the gradient's m × m part (method.md §6).
pub(crate) struct MmParts<'a> {
    pub h_inv: &'a [f64],
    pub kj: &'a [f64],
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

pub(crate) fn mm_grad(p: &MmParts) -> MmGrad {
    let m = p.m;
    let hkh = linalg::matmul(&linalg::matmul(p.h_inv, p.kj, m, m, m), p.h_inv, m, m, m);
    let hah = linalg::matmul(&linalg::matmul(p.h_inv, p.a, m, m, m), p.h_inv, m, m, m);
    let kak = linalg::matmul(&linalg::matmul(p.kj_inv, p.a, m, m, m), p.kj_inv, m, m, m);
    let mut w = vec![0.0; m * m];
    let mut gmm = vec![0.0; m * m];
    let s_beta = (p.c * p.t2 + 2.0) * p.lambda;
    for j in 0..m {
        for k in 0..m {
            let i = j * m + k;
            // (4/n) M1 with M1 = nλ H⁻¹K_jH⁻¹ is 4λ H⁻¹K_jH⁻¹.
            w[i] = 4.0 * p.lambda * hkh[i] - 2.0 * p.c * p.dd * p.kj_inv[i];
            gmm[i] = -2.0 * p.lambda * hah[i] + p.c * p.dd * kak[i] + s_beta * p.beta[j] * p.beta[k];
        }
    }
    linalg::symmetrize(&mut w, m);
    linalg::symmetrize(&mut gmm, m);
    MmGrad { w, gmm, s_r: (p.c * p.t2 + 2.0) * (2.0 / p.n) }
}

pub fn objective_and_grad(problem: &Problem, params: &Params, settings: &Settings) -> Result<(Eval, Grad), KrrError> {
    let f = forward(problem, params, settings)?;
    let (n, m, d) = (f.n, f.m, problem.d);
    let lambda = settings.lambda;
    let nf = n as f64;
    let (c, dd, t2) = (f.c, f.eval.d_term, f.eval.t2);
    let beta = &f.eval.beta;

    let MmGrad { w, gmm, s_r } = mm_grad(&MmParts { h_inv: &f.h_inv, kj: &f.kj, kj_inv: &f.kj_inv, a: &f.a, beta, lambda, c, dd, t2, n: nf, m });

    let x = &problem.x;
    let z = &params.z;
    let mut gz = vec![0.0; m * d];
    let mut gs = vec![0.0; d]; // Σ P (x − z)² + Σ Q (z − z)², before the 1/s² factor
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
    // K_mm part: Q_jk = G_mm,jk · K_mm,jk (the jitter is constant, so K_mm, not K_j).
    for j in 0..m {
        for k in 0..m {
            if j == k {
                continue; // z_j − z_j = 0
            }
            let q = gmm[j * m + k] * f.kmm[j * m + k];
            for t in 0..d {
                let e = z[k * d + t] - z[j * d + t];
                gz[j * d + t] += 2.0 * q * e;
                gs[t] += q * e * e;
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
