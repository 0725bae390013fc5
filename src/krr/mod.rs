//! Nyström kernel ridge regression with test-time tuning — the CPU f64 reference.
//!
//! This module is the oracle of `docs/method.md` §3–§6 (and §8's jitter): the Nyström KRR solve,
//! the tuning objective of Meanti et al. as run by Falkon (or the paper's weighting), its
//! hand-derived reverse-mode gradient with respect to the log length-scales and the inducing
//! points, and the Adam loop that tunes them keeping the parameters with the lowest training
//! error. Everything is dense f64 in m×m terms (§5): exact, simple, and the yardstick a GPU (f32,
//! §7's blockwise/stochastic variants) implementation is tested against.
//!
//! Shape of the module:
//! - [`linalg`]: the small dense linear algebra it needs (row-major `[f64]`, hand-written: the lib
//!   also compiles to wasm32 and takes no heavy dependencies);
//! - [`kernel`]: the Gaussian kernel with one length-scale per feature dimension (§0);
//! - [`reference`](mod@reference): [`Problem`], [`Params`], [`Settings`], the objective, its gradient, prediction;
//! - [`tune`](mod@tune): Adam over an [`Objective`] trait (so a GPU implementation plugs in later);
//! - [`init`]: initial inducing points and length-scales.
//!
//! Nothing here panics on bad *input data*: shapes, emptiness, NaN/∞ and non-positive-definite
//! matrices are reported as [`KrrError`]. (The low-level [`linalg`] helpers assert their slice
//! lengths: a mismatch there is a bug in the caller, not bad data.)

pub mod gpu;
pub mod init;
pub mod kernel;
pub mod linalg;
pub mod reference;
pub mod tune;

use std::fmt;

pub use gpu::{GpuObjective, GpuPredictor, KrrGpuError, PhaseTimings};
pub use init::{init_length_scales, init_params, init_z, LengthScaleInit};
pub use reference::{
    objective, objective_and_grad, predict, Eval, Grad, Params, Problem, Reference, Settings,
    Weighting,
};
pub use tune::{tune, tune_async, Objective, StepLog, StopReason, TuneResult, TuneSettings, Tuner};

/// Why an evaluation, a solve or a tuning run could not proceed.
#[derive(Clone, Debug, PartialEq)]
pub enum KrrError {
    /// No training points (n = 0), no features (d = 0) or no inducing points (m = 0).
    Empty(String),
    /// Lengths that do not fit together (e.g. `x.len() != n * d`, `log_s.len() != d`).
    Shape(String),
    /// A NaN or ±∞ in the inputs, the parameters, or a computed quantity.
    NonFinite(String),
    /// A setting out of its domain (e.g. λ ≤ 0, negative jitter).
    Setting(String),
    /// Cholesky met a non-positive (or non-finite) pivot: the matrix is not numerically positive
    /// definite. `what` names the matrix (`"K_mm + jitter I"`, `"H"`, ...); `index` is the row
    /// where it failed and `pivot` the value found there. More jitter (§8) usually cures it.
    NotPositiveDefinite { what: &'static str, index: usize, pivot: f64 },
}

impl fmt::Display for KrrError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KrrError::Empty(s) => write!(f, "empty input: {s}"),
            KrrError::Shape(s) => write!(f, "shape mismatch: {s}"),
            KrrError::NonFinite(s) => write!(f, "non-finite value: {s}"),
            KrrError::Setting(s) => write!(f, "invalid setting: {s}"),
            KrrError::NotPositiveDefinite { what, index, pivot } => write!(
                f,
                "{what} is not numerically positive definite (Cholesky pivot {index} = {pivot:e}); \
                 increase the jitter"
            ),
        }
    }
}

impl std::error::Error for KrrError {}
