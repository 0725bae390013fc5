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
//! - [`problem`]: [`Problem`], [`Params`], [`Ridge`], [`Eval`], [`Grad`] and the [`Objective`] trait;
//! - [`mm`]: the m × m algebra of the objective and gradient, shared with the GPU objective;
//! - [`reference`](mod@reference): the f64 objective, its gradient, prediction;
//! - [`tune`](mod@tune): Adam over an [`Objective`] (the f64 reference or [`gpu`]'s);
//! - [`init`]: initial inducing points and length-scales;
//! - [`error`]: [`KrrError`].
//!
//! This file only declares and re-exports: the files below import each other, never it.
//!
//! Nothing here panics on bad *input data*: shapes, emptiness, NaN/∞ and non-positive-definite
//! matrices are reported as [`KrrError`]. (The low-level [`linalg`] helpers assert their slice
//! lengths: a mismatch there is a bug in the caller, not bad data.)

pub mod error;
pub mod gpu;
pub mod gpu_objective;
pub mod gpu_predictor;
pub mod init;
pub mod kernel;
pub mod linalg;
pub mod mm;
pub mod problem;
pub mod reference;
pub mod tune;

pub use error::KrrError;
pub use gpu::{KrrGpuError, PhaseTimings};
pub use gpu_objective::GpuObjective;
pub use gpu_predictor::{GpuPredictor, PreparedPredictor};
pub use init::{init_length_scales, init_params, init_z, LengthScaleInit};
pub use problem::{Eval, Grad, Objective, Params, Problem, Ridge, Weighting};
pub use reference::{objective, objective_and_grad, predict, Reference};
pub use tune::{tune, tune_async, tune_async_scored, tune_scored, Scored, StepLog, StopReason, TuneResult, TuneSettings, Tuner};
