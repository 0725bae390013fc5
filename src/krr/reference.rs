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

use super::error::KrrError;
use super::kernel;
use super::linalg::{self, dot};
use super::mm::{assemble, kmm_side, mm_forward, mm_grad, MmForward, MmGrad, MmParts};
use super::problem::{Eval, Grad, Objective, Params, Problem, Ridge};

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
    alpha: f64,
    c: f64,
    eval: Eval,
}

fn forward(problem: &Problem, params: &Params, settings: &Ridge) -> Result<Forward, KrrError> {
    settings.check()?;
    let (n, d) = (problem.n(), problem.d());
    let m = params.check(d)?;
    let lambda = settings.lambda;
    let nl = n as f64 * lambda;

    // §5: the n-sized work is K_nm, A = K_nmᵀ K_nm and b = K_nmᵀ y; the rest is m × m.
    let knm = kernel::k_nm(problem.x(), &params.z, &params.log_s);
    let kmm = kernel::k_mm(&params.z, &params.log_s);
    let mut kj = kmm.clone();
    for j in 0..m {
        kj[j * m + j] += settings.jitter;
    }
    let a = linalg::gram(&knm, n, m);
    let b = linalg::matvec_t(&knm, problem.y(), n, m);

    let MmForward { lk, beta, h_inv, kj_inv, t1, t2 } = mm_forward(&a, &kj, &b, nl, n as f64, m)?;
    let mut r = linalg::matvec(&knm, &beta, n, m);
    for (ri, yi) in r.iter_mut().zip(problem.y()) {
        *ri -= yi;
    }
    let data_fit = dot(&r, &r) / n as f64;
    let (eval, alpha, c) = assemble(data_fit, (t1, t2), beta, &kj, settings, (n, m))?;
    Ok(Forward { n, m, knm, kmm, lk, a, h_inv, kj_inv, r, alpha, c, eval })
}

/// The objective at `params` (no gradient). See the module docs for the definitions.
pub fn objective(problem: &Problem, params: &Params, settings: &Ridge) -> Result<Eval, KrrError> {
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
pub fn objective_and_grad(problem: &Problem, params: &Params, settings: &Ridge) -> Result<(Eval, Grad), KrrError> {
    let f = forward(problem, params, settings)?;
    let (n, m, d) = (f.n, f.m, problem.d());
    let lambda = settings.lambda;
    let nf = n as f64;
    let (c, dd, t2) = (f.c, f.eval.d_term, f.eval.t2);
    let beta = &f.eval.beta;

    let MmGrad { w, gmm, s_r } = mm_grad(&MmParts { h_inv: &f.h_inv, lk: &f.lk, kj_inv: &f.kj_inv, a: &f.a, beta, lambda, alpha: f.alpha, c, dd, t2, n: nf, m });

    let x = problem.x();
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
    // Row blocks of K(queries, Z) from one GEMM each (`kernel::cross_expanded`), folded with β
    // at once: the mesher asks for ~300k queries, and a query at a time ran on one core.
    let inv_s = kernel::inv_scales(log_s);
    let mut out = Vec::with_capacity(queries.len() / d);
    for block in queries.chunks(PREDICT_BLOCK * d) {
        let k = kernel::cross_expanded(block, z, &inv_s);
        out.extend(k.chunks_exact(m).map(|row| dot(row, beta)));
    }
    Ok(out)
}

/// Queries per block of [`predict`]: `K` for a block is `PREDICT_BLOCK × m` f64 (16 MB at m = 500).
const PREDICT_BLOCK: usize = 4096;

/// Host bytes per training pair of the f64 objective with `m` inducing points and `d` features:
/// its `K_nm` row (f64), `X` twice (f32 and f64), the targets and a share of the gradient's
/// row blocks.
pub fn host_bytes_per_pair(m: u64, d: u64) -> u64 {
    8 * (m + 2 * d + 3) + 8 * (d + 1)
}

/// Host bytes of the f64 objective on `pairs` pairs: per pair, and the m×m f64 matrices.
pub fn host_bytes(pairs: u64, m: u64, d: u64) -> u64 {
    pairs * host_bytes_per_pair(m, d) + 96 * m * m
}

/// Host bytes [`predict`] adds for `queries` queries of `d` features: their f64 copy and the
/// result.
pub fn predict_host_bytes(queries: u64, d: u64) -> u64 {
    queries * (8 * d + 8)
}

/// Host bytes of [`predict`]'s working block for `m` inducing points and `d` features.
pub fn predict_block_bytes(m: u64, d: u64) -> u64 {
    PREDICT_BLOCK as u64 * 8 * (m + d)
}

/// The f64 reference as an [`Objective`] for the tuner.
#[derive(Clone, Copy, Debug)]
pub struct Reference<'a> {
    pub problem: &'a Problem,
    pub settings: Ridge,
}

impl Objective for Reference<'_> {
    fn eval_grad(&mut self, params: &Params) -> Result<(Eval, Grad), KrrError> {
        objective_and_grad(self.problem, params, &self.settings)
    }
    fn eval(&mut self, params: &Params) -> Result<Eval, KrrError> {
        objective(self.problem, params, &self.settings)
    }
}
