//! Test-time tuning: Adam on `(log s, Z)` (`docs/method.md` §4, last paragraph).
//!
//! Defaults follow the paper: Adam, lr 0.1, 100 steps, and the returned parameters are those with
//! the **lowest training squared error** `(1/n)‖g(X) − y‖²` seen — not the lowest loss, and not
//! the last iterate: the objective is a model-selection criterion whose minimiser need not fit
//! best, and Adam at lr 0.1 is not monotone. On top of the paper: an early stop when neither the
//! loss nor the training error has improved by a relative `rel_tol` for `patience` steps (the
//! loss alone can plateau while the error we keep the best of still falls), switches to freeze θ (the
//! length-scales) or Z, and a progress callback that can cancel.
//!
//! The loop is generic over [`Objective`], so the f64 [`Reference`](super::Reference) and a GPU
//! implementation are driven by the same code.

use super::reference::{Eval, Grad, Params};
use super::KrrError;

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

/// Settings of the tuning loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TuneSettings {
    /// Maximum number of Adam updates (the loop evaluates `steps + 1` iterates).
    pub steps: usize,
    /// Adam learning rate (in log-length-scale units for θ, feature units for Z).
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// Tune the length-scales.
    pub tune_theta: bool,
    /// Tune the inducing points.
    pub tune_z: bool,
    /// Stop after this many consecutive evaluations in which neither the loss nor the training
    /// error improved by at least `rel_tol` (relative) over its best so far (0: never stop early).
    pub patience: usize,
    pub rel_tol: f64,
}

impl Default for TuneSettings {
    fn default() -> Self {
        TuneSettings {
            steps: 100,
            lr: 0.1,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            tune_theta: true,
            tune_z: true,
            patience: 10,
            rel_tol: 1e-4,
        }
    }
}

/// Why the loop ended.
#[derive(Clone, Debug, PartialEq)]
pub enum StopReason {
    /// All `steps` updates were made.
    MaxSteps,
    /// The early-stop criterion fired.
    Converged,
    /// The progress callback returned `false`.
    Cancelled,
    /// Both switches off: the initial parameters were evaluated once.
    NothingToTune,
    /// An evaluation after the first one failed (e.g. H lost positive definiteness); the best
    /// parameters seen before it are returned.
    Failed(KrrError),
}

/// One evaluated iterate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepLog {
    /// Number of Adam updates applied before this evaluation.
    pub step: usize,
    pub loss: f64,
    pub data_fit: f64,
}

/// Result of [`tune`].
#[derive(Clone, Debug, PartialEq)]
pub struct TuneResult {
    /// The parameters with the lowest training squared error seen.
    pub params: Params,
    /// Their evaluation (β for [`predict`](super::predict) is `eval.beta`).
    pub eval: Eval,
    /// The `step` at which they were evaluated.
    pub best_step: usize,
    pub stop: StopReason,
    /// Every evaluation, in order.
    pub history: Vec<StepLog>,
}

/// Tune `init` with Adam on `objective`, calling `progress(step, &eval)` after every evaluation
/// (return `false` to cancel; the result so far is still returned).
///
/// Errors only when the settings are invalid or the very first evaluation fails; a later failure
/// ends the loop with [`StopReason::Failed`] and the best parameters seen.
pub fn tune<O, F>(objective: &mut O, init: Params, settings: &TuneSettings, mut progress: F) -> Result<TuneResult, KrrError>
where
    O: Objective + ?Sized,
    F: FnMut(usize, &Eval) -> bool,
{
    let s = settings;
    let ok = s.lr > 0.0
        && s.lr.is_finite()
        && (0.0..1.0).contains(&s.beta1)
        && (0.0..1.0).contains(&s.beta2)
        && s.eps > 0.0
        && s.rel_tol >= 0.0;
    if !ok {
        return Err(KrrError::Setting(format!("tuning settings out of range: {s:?}")));
    }
    let nothing = !s.tune_theta && !s.tune_z;
    let mut params = init;
    let mut adam_s = Adam::new(params.log_s.len());
    let mut adam_z = Adam::new(params.z.len());
    let mut best: Option<(Params, Eval, usize)> = None;
    let mut history = Vec::new();
    let mut best_loss = f64::INFINITY;
    let mut best_fit = f64::INFINITY;
    let mut stale = 0;
    let mut stop = StopReason::MaxSteps;

    for step in 0..=s.steps {
        let last = step == s.steps || nothing;
        let result = if last {
            objective.eval(&params).map(|e| (e, None))
        } else {
            objective.eval_grad(&params).and_then(|(e, g)| check_grad(&params, &g).map(|_| (e, Some(g))))
        };
        let (eval, grad) = match result {
            Ok(v) => v,
            Err(e) if best.is_none() => return Err(e),
            Err(e) => {
                stop = StopReason::Failed(e);
                break;
            }
        };
        history.push(StepLog { step, loss: eval.loss, data_fit: eval.data_fit });
        let improved_fit = best.as_ref().is_none_or(|b| eval.data_fit < b.1.data_fit);
        let (loss, fit) = (eval.loss, eval.data_fit);
        let go_on = progress(step, &eval);
        if improved_fit {
            best = Some((params.clone(), eval, step));
        }
        if !go_on {
            stop = StopReason::Cancelled;
            break;
        }
        if last {
            stop = if nothing { StopReason::NothingToTune } else { StopReason::MaxSteps };
            break;
        }
        let loss_improved = loss < best_loss - s.rel_tol * best_loss.abs();
        let fit_improved = fit < best_fit - s.rel_tol * best_fit.abs();
        best_loss = best_loss.min(loss);
        best_fit = best_fit.min(fit);
        if step == 0 || loss_improved || fit_improved {
            stale = 0;
        } else {
            stale += 1;
            if s.patience > 0 && stale >= s.patience {
                stop = StopReason::Converged;
                break;
            }
        }
        let grad = grad.expect("gradient requested for non-final steps");
        if s.tune_theta {
            adam_s.step(&mut params.log_s, &grad.log_s, s);
        }
        if s.tune_z {
            adam_z.step(&mut params.z, &grad.z, s);
        }
    }
    let (params, eval, best_step) = best.expect("at least one evaluation succeeded");
    Ok(TuneResult { params, eval, best_step, stop, history })
}

fn check_grad(params: &Params, g: &Grad) -> Result<(), KrrError> {
    if g.log_s.len() != params.log_s.len() || g.z.len() != params.z.len() {
        return Err(KrrError::Shape("gradient shapes differ from the parameters".into()));
    }
    if g.log_s.iter().chain(&g.z).any(|v| !v.is_finite()) {
        return Err(KrrError::NonFinite("gradient".into()));
    }
    Ok(())
}

/// Adam state for one parameter block (Kingma & Ba, with bias correction).
struct Adam {
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
}

impl Adam {
    fn new(len: usize) -> Self {
        Adam { m: vec![0.0; len], v: vec![0.0; len], t: 0 }
    }

    fn step(&mut self, x: &mut [f64], g: &[f64], s: &TuneSettings) {
        self.t += 1;
        let c1 = 1.0 - s.beta1.powi(self.t);
        let c2 = 1.0 - s.beta2.powi(self.t);
        for i in 0..x.len() {
            self.m[i] = s.beta1 * self.m[i] + (1.0 - s.beta1) * g[i];
            self.v[i] = s.beta2 * self.v[i] + (1.0 - s.beta2) * g[i] * g[i];
            let mh = self.m[i] / c1;
            let vh = self.v[i] / c2;
            x[i] -= s.lr * mh / (vh.sqrt() + s.eps);
        }
    }
}
