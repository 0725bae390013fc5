//! Test-time tuning: Adam on `(log s, Z)` (`docs/method.md` §4, last paragraph).
//!
//! [`TuneSettings::default`] follows the paper: Adam, lr 0.1, 100 steps (the product's defaults are
//! in `settings.rs`), and the returned parameters are those with
//! the **lowest training squared error** `(1/n)‖g(X) − y‖²` seen — not the lowest loss, and not
//! the last iterate: the objective is a model-selection criterion whose minimiser need not fit
//! best, and Adam at lr 0.1 is not monotone. On top of the paper: an early stop when neither the
//! loss nor the training error has improved by a relative `rel_tol` for `patience` steps (the
//! loss alone can plateau while the error we keep the best of still falls), switches to freeze θ (the
//! length-scales) or Z, and a progress callback that can cancel.
//!
//! **Validated tuning** ([`tune_scored`], [`tune_async_scored`]): the driver also scores each
//! iterate (the error on held-out pairs, see `field::fit`); the tuner then keeps the iterate
//! with the lowest score instead of the lowest training error, which rewards over-fitting, and
//! stops once the score has not improved by `rel_tol` for `patience` evaluations: a criterion,
//! not a count.
//!
//! The loop is generic over [`Objective`], so the f64 [`Reference`](super::reference::Reference) and a GPU
//! implementation are driven by the same code.

use super::error::KrrError;
use super::problem::{Eval, Grad, Objective, Params};

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
    /// The driver's score (held-out error) in validated tuning.
    pub score: Option<f64>,
}

/// Result of [`tune`].
#[derive(Clone, Debug, PartialEq)]
pub struct TuneResult {
    /// The parameters with the lowest training squared error seen (the lowest score, in
    /// validated tuning).
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
pub fn tune<O, F>(objective: &mut O, init: Params, settings: &TuneSettings, progress: F) -> Result<TuneResult, KrrError>
where
    O: Objective + ?Sized,
    F: FnMut(usize, &Eval) -> bool,
{
    tune_scored(objective, init, settings, |_, _| Ok(None), progress)
}

/// [`tune`], keeping the iterate with the lowest `score(params, eval)` (e.g. the error on
/// held-out pairs) and stopping when it no longer improves (see the module docs); a score of
/// `None` selects by the training error as [`tune`] does.
pub fn tune_scored<O, S, F>(objective: &mut O, init: Params, settings: &TuneSettings, mut score: S, mut progress: F) -> Result<TuneResult, KrrError>
where
    O: Objective + ?Sized,
    S: FnMut(&Params, &Eval) -> Result<Option<f64>, KrrError>,
    F: FnMut(usize, &Eval) -> bool,
{
    let mut tuner = Tuner::new(init, settings)?;
    while let Some((params, needs_grad)) = tuner.next_request() {
        let result = if needs_grad {
            objective.eval_grad(params).map(|(e, g)| (e, Some(g)))
        } else {
            objective.eval(params).map(|e| (e, None))
        };
        let result = result.and_then(|(e, g)| score(params, &e).map(|s| (e, g, s)));
        tuner.supply_scored(result, &mut progress)?;
    }
    Ok(tuner.finish())
}

/// [`tune`] with an asynchronous objective (the browser's GPU readbacks resolve on its event
/// loop): `evaluate(params, needs_grad)` resolves to the evaluation and, when asked, the gradient.
pub async fn tune_async<E, Fut, F>(mut evaluate: E, init: Params, settings: &TuneSettings, progress: F) -> Result<TuneResult, KrrError>
where
    E: FnMut(Params, bool) -> Fut,
    Fut: std::future::Future<Output = Result<(Eval, Option<Grad>), KrrError>>,
    F: FnMut(usize, &Eval) -> bool,
{
    let scored = |params: Params, needs_grad: bool| {
        let fut = evaluate(params, needs_grad);
        async move { fut.await.map(|(e, g)| (e, g, None)) }
    };
    tune_async_scored(scored, init, settings, progress).await
}

/// [`tune_async`] where `evaluate` also resolves to a score (see [`tune_scored`]).
pub async fn tune_async_scored<E, Fut, F>(mut evaluate: E, init: Params, settings: &TuneSettings, mut progress: F) -> Result<TuneResult, KrrError>
where
    E: FnMut(Params, bool) -> Fut,
    Fut: std::future::Future<Output = Result<Scored, KrrError>>,
    F: FnMut(usize, &Eval) -> bool,
{
    let mut tuner = Tuner::new(init, settings)?;
    while let Some((params, needs_grad)) = tuner.next_request() {
        let result = evaluate(params.clone(), needs_grad).await;
        tuner.supply_scored(result, &mut progress)?;
    }
    Ok(tuner.finish())
}

/// One evaluation as a driver hands it to the tuner: the evaluation, its gradient (all but the
/// last step) and, in validated tuning, its score.
pub type Scored = (Eval, Option<Grad>, Option<f64>);

/// The tuning loop as a state machine: it says which parameters to evaluate next and takes the
/// result, so blocking and asynchronous drivers run exactly the same steps.
pub struct Tuner {
    s: TuneSettings,
    nothing: bool,
    params: Params,
    adam_s: Adam,
    adam_z: Adam,
    /// The kept iterate and its selection key (the score, or the training error).
    best: Option<(Params, Eval, usize, f64)>,
    history: Vec<StepLog>,
    best_loss: f64,
    stale: usize,
    step: usize,
    stop: Option<StopReason>,
}

impl Tuner {
    pub fn new(init: Params, settings: &TuneSettings) -> Result<Tuner, KrrError> {
        let s = *settings;
        let ok = s.lr > 0.0
            && s.lr.is_finite()
            && (0.0..1.0).contains(&s.beta1)
            && (0.0..1.0).contains(&s.beta2)
            && s.eps > 0.0
            && s.rel_tol >= 0.0;
        if !ok {
            return Err(KrrError::Setting(format!("tuning settings out of range: {s:?}")));
        }
        Ok(Tuner {
            nothing: !s.tune_theta && !s.tune_z,
            adam_s: Adam::new(init.log_s.len()),
            adam_z: Adam::new(init.z.len()),
            params: init,
            s,
            best: None,
            history: Vec::new(),
            best_loss: f64::INFINITY,
            stale: 0,
            step: 0,
            stop: None,
        })
    }

    fn is_last(&self) -> bool {
        self.step == self.s.steps || self.nothing
    }

    /// The parameters to evaluate next and whether their gradient is needed (the final
    /// iterate's is not); `None` once the loop has stopped.
    pub fn next_request(&self) -> Option<(&Params, bool)> {
        match self.stop {
            Some(_) => None,
            None => Some((&self.params, !self.is_last())),
        }
    }

    /// Takes the evaluation of the parameters from [`Tuner::next_request`].
    pub fn supply<F>(&mut self, result: Result<(Eval, Option<Grad>), KrrError>, progress: &mut F) -> Result<(), KrrError>
    where
        F: FnMut(usize, &Eval) -> bool,
    {
        self.supply_scored(result.map(|(e, g)| (e, g, None)), progress)
    }

    /// [`Tuner::supply`] with the iterate's score, if the driver validates (see the module docs).
    pub fn supply_scored<F>(&mut self, result: Result<Scored, KrrError>, progress: &mut F) -> Result<(), KrrError>
    where
        F: FnMut(usize, &Eval) -> bool,
    {
        let s = self.s;
        let step = self.step;
        let last = self.is_last();
        let result = result.and_then(|(e, g, score)| match (&g, last) {
            _ if score.is_some_and(|v| !v.is_finite()) => Err(KrrError::NonFinite("tuning score".into())),
            (Some(g), _) => check_grad(&self.params, g).map(|_| (e, Some(g.clone()), score)),
            (None, true) => Ok((e, None, score)),
            (None, false) => Err(KrrError::Shape("the tuner needs a gradient for this step".into())),
        });
        let (eval, grad, score) = match result {
            Ok(v) => v,
            Err(e) if self.best.is_none() => return Err(e),
            Err(e) => {
                self.stop = Some(StopReason::Failed(e));
                return Ok(());
            }
        };
        self.history.push(StepLog { step, loss: eval.loss, data_fit: eval.data_fit, score });
        // The selection key: the score, or the training error. The kept iterate's is the lowest
        // seen so far, which the early stop below compares against too.
        let key = score.unwrap_or(eval.data_fit);
        let best_key = self.best.as_ref().map_or(f64::INFINITY, |b| b.3);
        let loss = eval.loss;
        let go_on = progress(step, &eval);
        if self.best.is_none() || key < best_key {
            self.best = Some((self.params.clone(), eval, step, key));
        }
        if !go_on {
            self.stop = Some(StopReason::Cancelled);
            return Ok(());
        }
        if last {
            self.stop = Some(if self.nothing { StopReason::NothingToTune } else { StopReason::MaxSteps });
            return Ok(());
        }
        let better = |v: f64, best: f64| v < best - s.rel_tol * best.abs();
        // Validated, only the score counts: the loss may fall for ever while the iterate
        // over-fits. Otherwise the loss or the training error.
        let progressed = better(key, best_key) || (score.is_none() && better(loss, self.best_loss));
        self.best_loss = self.best_loss.min(loss);
        if step == 0 || progressed {
            self.stale = 0;
        } else {
            self.stale += 1;
            if s.patience > 0 && self.stale >= s.patience {
                self.stop = Some(StopReason::Converged);
                return Ok(());
            }
        }
        let grad = grad.expect("checked above: non-final steps carry a gradient");
        if s.tune_theta {
            self.adam_s.step(&mut self.params.log_s, &grad.log_s, &s);
        }
        if s.tune_z {
            self.adam_z.step(&mut self.params.z, &grad.z, &s);
        }
        self.step += 1;
        Ok(())
    }

    /// The best parameters seen (at least one evaluation must have succeeded, which
    /// [`Tuner::supply`] guarantees by returning the first failure as an error).
    pub fn finish(self) -> TuneResult {
        let (params, eval, best_step, _) = self.best.expect("at least one evaluation succeeded");
        TuneResult { params, eval, best_step, stop: self.stop.unwrap_or(StopReason::MaxSteps), history: self.history }
    }
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
