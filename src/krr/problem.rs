//! The regression problem and what the tuning moves and measures: the training set
//! ([`Problem`]), the tuned parameters ([`Params`]), the fixed ridge settings ([`Ridge`]), one
//! evaluation ([`Eval`]) and its gradient ([`Grad`]), and the [`Objective`] trait that the f64
//! reference (`reference.rs`) and the GPU objective (`gpu.rs`) implement and the tuner
//! (`tune.rs`) drives. Shared by all of them, it imports none of them.

use super::error::KrrError;

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

    /// The problem made of rows `rows` of this one, in that order (at least one).
    pub fn select(&self, rows: &[usize]) -> Problem {
        assert!(!rows.is_empty(), "Problem::select needs at least one row");
        let d = self.d;
        Problem {
            x: rows.iter().flat_map(|&i| self.x[i * d..(i + 1) * d].iter().copied()).collect(),
            y: rows.iter().map(|&i| self.y[i]).collect(),
            n: rows.len(),
            d,
        }
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
pub struct Ridge {
    /// Ridge parameter λ (> 0); the KRR "variance" is `λ n` as in Falkon (§4).
    pub lambda: f64,
    /// Absolute jitter added to the diagonal of `K_mm` (≥ 0), see the module docs and §8.
    pub jitter: f64,
    /// Which `c` in front of `T2·D`.
    pub weighting: Weighting,
    /// When the problem is a uniform subsample of `N` pairs (tuning on fewer pairs than the
    /// final solve): `Some(N)`, and the loss estimates the objective on all `N` instead of
    /// being the subsample's own. `None`: the problem is all the data.
    pub full_n: Option<usize>,
}

impl Ridge {
    /// Default jitter per inducing point: `jitter = 1e-6 · m` (§8's suggestion). K_mm has a unit
    /// diagonal, so this is a relative jitter; at m = 500 it is 5e-4, comfortably above what an
    /// f32 Cholesky of a 500 × 500 Gaussian Gram matrix needs (≈ m·ε_f32 ≈ 3e-5), and the f64
    /// reference uses the same value so that the two compute the same objective.
    pub const JITTER_PER_CENTRE: f64 = 1e-6;

    /// `lambda`, the default jitter for `m` inducing points, Falkon's weighting.
    pub fn new(lambda: f64, m: usize) -> Self {
        Ridge { lambda, jitter: Self::JITTER_PER_CENTRE * m as f64, weighting: Weighting::Falkon, full_n: None }
    }

    /// The weights `(α, c)` of `L = α T1 + c T2 D + 2 D` for a problem of `n` pairs.
    ///
    /// All data: `α = 2/n` and `c` = [`Weighting::c`]. A subsample of `n` out of `N` pairs
    /// stands for all of them: `A_N ≈ (N/n) A_n` and `b_N ≈ (N/n) b_n`, so `H_N ≈ (N/n) H_n`,
    /// β and D are unchanged, `T1_N ≈ T1_n` and `T2_N ≈ (N/n) T2_n`; the full loss is then
    /// `(2/N) T1_n + c(N)·(N/n) T2_n D + 2D`. Without this the subsample's own loss weighs the
    /// complexity terms as for n pairs (N/n times heavier) and tunes smoother kernels than all
    /// the pairs support.
    pub fn weights(&self, n: usize) -> (f64, f64) {
        let big_n = self.full_n.unwrap_or(n).max(n);
        (2.0 / big_n as f64, self.weighting.c(big_n, self.lambda) * big_n as f64 / n as f64)
    }

    pub(crate) fn check(&self) -> Result<(), KrrError> {
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

/// Something that evaluates the tuning objective and its gradient at given parameters.
pub trait Objective {
    /// Loss, diagnostics and β at `params`, and the gradient of the loss (same shapes as
    /// `params`).
    fn eval_grad(&mut self, params: &Params) -> Result<(Eval, Grad), KrrError>;

    /// The evaluation alone; override when it is cheaper than [`Objective::eval_grad`] (the
    /// tuner calls it for the final iterate, whose gradient is not needed).
    fn eval(&mut self, params: &Params) -> Result<Eval, KrrError> {
        self.eval_grad(params).map(|(e, _)| e)
    }
}
