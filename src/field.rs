//! The field whose zero level is the surface: the network's logit l(q), or the paper's kernel
//! regression g(F(q)) fitted to the cloud (`docs/method.md` §1–§4).
//!
//! This stage owns everything between the network's features and the mesher's field
//! evaluations: the training pairs (input points at label 0, extra points labelled by the
//! network, paper eq. 6), the initialisation and test-time tuning of the Nyström KRR (on the GPU
//! or the f64 CPU reference), and one `evaluate` for the mesher that decodes queries and applies
//! the fitted regression on the backend it was tuned on. [`crate::pipeline`] only strings it
//! between the other stages.

use std::cell::RefCell;

use crate::gpu::{Gpu, GpuError};
use crate::krr::{self, KrrError, LengthScaleInit, TuneSettings};
use crate::net::{GpuNet, GpuPlanes};
use crate::orient;
use crate::settings::{Method, PriorMean, SelectBy, Settings};

/// Octaves of the coordinate encoding used by the "w/o features" ablation: x, and
/// sin/cos(2^k π x) for k < FOURIER_OCTAVES, per axis (3 + 6·5 = 33 dimensions).
pub const FOURIER_OCTAVES: usize = 5;

/// Dimensions of [`fourier_encode`]'s output.
pub const FOURIER_DIM: usize = 3 + 6 * FOURIER_OCTAVES;

/// The regression's input for the "w/o features" ablation.
pub fn fourier_encode(points: &[[f32; 3]]) -> Vec<f32> {
    let mut out = Vec::with_capacity(points.len() * FOURIER_DIM);
    for p in points {
        out.extend_from_slice(p);
        for k in 0..FOURIER_OCTAVES {
            let w = std::f32::consts::PI * (1u32 << k) as f32;
            for &x in p {
                out.push((w * x).sin());
                out.push((w * x).cos());
            }
        }
    }
    out
}

/// Dimensions of the regression's input for `settings` and a network with `c_dim` features.
pub fn input_dim(settings: &Settings, c_dim: usize) -> usize {
    if settings.euclidean {
        FOURIER_DIM
    } else {
        c_dim + if settings.position { 3 } else { 0 }
    }
}

/// What the regression sees at `points` whose network features are `features`: the features,
/// the features followed by the position ([`Settings::position`]: the features are bilinear on
/// 64² plane cells, so within a cell they cannot place the surface finer than the decoder does
/// with q; each coordinate gets its own tuned length-scale like every feature), or, for the
/// ablation, Fourier-encoded coordinates alone.
fn regression_input(euclidean: bool, position: bool, points: &[[f32; 3]], features: Vec<f32>) -> Vec<f32> {
    if euclidean {
        return fourier_encode(points);
    }
    if !position || points.is_empty() {
        return features;
    }
    let c = features.len() / points.len();
    let mut out = Vec::with_capacity(points.len() * (c + 3));
    for (f, p) in features.chunks_exact(c).zip(points) {
        out.extend_from_slice(f);
        out.extend_from_slice(p);
    }
    out
}

/// The fitted regression g(x) = Σ_j β_j k(x, z_j), evaluated where it was tuned.
pub struct KrrField {
    params: krr::Params,
    beta: Vec<f64>,
    /// Fourier-encoded coordinates instead of the network's features (the ablation).
    euclidean: bool,
    /// The position follows the features in the regression's input.
    position: bool,
    /// g regressed the residual of the network's logit: the field is l(q) + g(q).
    network_mean: bool,
    /// The GPU predictor when the regression was tuned on the GPU; else the f64 reference.
    gpu: Option<krr::GpuPredictor>,
}

impl KrrField {
    /// The field at `points`, whose network features and logits are `features` and `logits`:
    /// g, or l + g when g regressed the logit's residual. On the GPU this uploads the
    /// coefficients for the call; [`Field::evaluator`] keeps them for many.
    pub async fn predict(&self, points: &[[f32; 3]], features: Vec<f32>, logits: &[f32]) -> Result<Vec<f32>, String> {
        let prepared = self.prepare(points.len())?;
        self.predict_with(prepared.as_ref(), points, features, logits).await
    }

    /// The GPU predictor with this fit's coefficients uploaded, for calls of up to `queries`
    /// points (None when the fit runs on the CPU reference).
    fn prepare(&self, queries: usize) -> Result<Option<krr::PreparedPredictor>, String> {
        let Some(p) = &self.gpu else { return Ok(None) };
        let prepared = p.prepare(&self.beta, &self.params.z, &self.params.log_s, queries).map_err(|e| e.to_string())?;
        Ok(Some(prepared))
    }

    async fn predict_with(&self, prepared: Option<&krr::PreparedPredictor>, points: &[[f32; 3]], features: Vec<f32>, logits: &[f32]) -> Result<Vec<f32>, String> {
        let x = regression_input(self.euclidean, self.position, points, features);
        let mut g = match prepared {
            Some(p) => p.predict(&x).await.map_err(|e| e.to_string())?,
            None => {
                let (beta, z, log_s) = (&self.beta, &self.params.z, &self.params.log_s);
                let x: Vec<f64> = x.iter().map(|&v| v as f64).collect();
                krr::predict(beta, z, log_s, &x).map(|g| g.into_iter().map(|v| v as f32).collect()).map_err(|e| e.to_string())?
            }
        };
        if self.network_mean {
            g.iter_mut().zip(logits).for_each(|(g, l)| *g += l);
        }
        Ok(g)
    }
}

/// Points per call to an [`Evaluator`] while meshing: the buffers are sized for it (and the
/// plan counts them so), and meshing progress is reported between calls.
pub const EVALUATION_CHUNK: usize = 32_768;

/// The field the mesher evaluates: the network alone, or the network's features through the
/// fitted regression.
pub enum Field {
    Network,
    Krr(KrrField),
}

impl Field {
    /// What evaluates this field on `planes` in calls of at most `queries` points (the unit
    /// cube): the decoder's buffers and, for the regression on the GPU, the predictor's with
    /// its coefficients, made here once for every call (the mesher makes hundreds).
    pub fn evaluator<'a>(self, net: &'a GpuNet, planes: &GpuPlanes, queries: usize) -> Result<Evaluator<'a>, String> {
        let decoder = net.decoder(planes, queries).map_err(|e| e.to_string())?;
        let mut evaluator = Evaluator { field: Field::Network, decoder, queries, predictor: None };
        evaluator.set_field(self)?;
        Ok(evaluator)
    }
}

/// A [`Field`] ready to evaluate ([`Field::evaluator`]).
pub struct Evaluator<'a> {
    field: Field,
    decoder: crate::net::Decoder<'a>,
    queries: usize,
    predictor: Option<krr::PreparedPredictor>,
}

impl Evaluator<'_> {
    /// Evaluates `field` on `planes` from now on (a scene's next tile), keeping the decoder's
    /// buffers. A regression's predictor holds its coefficients, so it is made anew for a new
    /// fit (the last one's buffers destroyed first).
    pub fn rebind(&mut self, planes: &GpuPlanes, field: Field) -> Result<(), String> {
        self.decoder.rebind(planes).map_err(|e| e.to_string())?;
        self.set_field(field)
    }

    fn set_field(&mut self, field: Field) -> Result<(), String> {
        self.predictor = None;
        if let Field::Krr(fit) = &field {
            self.predictor = fit.prepare(self.queries)?;
        }
        self.field = field;
        Ok(())
    }

    /// The field at `points`, decoding their features from the planes.
    pub async fn evaluate(&self, points: &[[f32; 3]]) -> Result<Vec<f32>, String> {
        let (features, logits) = self.decoder.decode(points).await.map_err(|e| e.to_string())?;
        match &self.field {
            Field::Network => Ok(logits),
            Field::Krr(fit) => fit.predict_with(self.predictor.as_ref(), points, features, &logits).await,
        }
    }
}

/// What the kernel regression's tuning did, for reports and benchmarks.
#[derive(Clone, Debug)]
pub struct TuningSummary {
    /// "gpu" or "cpu": where the objective ran.
    pub backend: &'static str,
    /// Training pairs β was solved on.
    pub n: usize,
    /// Training pairs the tuning saw (a subsample of `n`, or all of them).
    pub tuned_on: usize,
    /// Pairs held out to score the iterates (0: the iterate was kept by its training error).
    pub held_out: usize,
    /// The held-out error of the first and of the kept iterate, when held out.
    pub initial_score: Option<f64>,
    pub best_score: Option<f64>,
    pub m: usize,
    pub steps_run: usize,
    pub best_step: usize,
    pub stop: String,
    pub initial_loss: f64,
    pub final_loss: f64,
    pub initial_data_fit: f64,
    pub best_data_fit: f64,
    pub length_scales: Vec<f64>,
    /// Objective evaluations and their summed phase times, when the objective ran on the GPU.
    pub evaluations: usize,
    pub phases: Option<krr::PhaseTimings>,
}

/// Why the field could not be fitted.
#[derive(Debug)]
pub enum FitError {
    Gpu(GpuError),
    Krr(KrrError),
    Cancelled,
}

impl From<GpuError> for FitError {
    fn from(e: GpuError) -> Self {
        FitError::Gpu(e)
    }
}

impl From<KrrError> for FitError {
    fn from(e: KrrError) -> Self {
        FitError::Krr(e)
    }
}

/// Host bytes of [`training_pairs`] for `points` points with `per_point` extra points each
/// (see [`Settings::offsets`]) and a network of `c_dim` features and `d` regression inputs: the
/// extra points and their neighbour search, the decoded features and logits, and the problem
/// in f64.
pub fn pairs_host_bytes(points: u64, per_point: u64, c_dim: u64, d: u64) -> u64 {
    (1 + per_point) * points * (4 * c_dim + 8 * d + 20) + 40 * points
}

/// The regression's training set: the problem and how many of its first rows are input points.
pub struct TrainingPairs {
    pub problem: krr::Problem,
    /// Rows `0..inputs` are the input points (label 0); the rest are the extra points.
    pub inputs: usize,
}

/// X = F([P, P~]), y = [0, l(P~)] (paper eq. 6): the input points lie on the surface (logit 0),
/// the extra points take the network's logit as a pseudo-label, clipped to
/// [`Settings::label_clip`]. With [`PriorMean::Network`] the targets are the residual of the
/// network's logit (see [`targets`]), so that g corrects the network and is 0 where the data
/// says nothing.
pub async fn training_pairs(
    net: &GpuNet,
    planes: &GpuPlanes,
    points: &[[f32; 3]],
    settings: &Settings,
) -> Result<TrainingPairs, FitError> {
    let offsets = settings.offsets(points.len());
    let extra = crate::sample::upsample(points, &offsets, 2);
    let mut all = points.to_vec();
    all.extend_from_slice(&extra);
    // The pairs across the surface (crate::orient): one neighbour search gives their normals,
    // their offsets (the near scale's distance) and, below, the vote on their labels.
    let across = settings.across.map(|f| {
        let nb = orient::neighbourhoods(points, orient::NEIGHBOURS, offsets.near_k.unwrap_or(orient::NEIGHBOURS));
        let normals = orient::pca_normals(points, &nb);
        let delta: Vec<f32> = nb.spacing.iter().map(|d| f * d).collect();
        (orient::across(points, &normals, &delta), normals, nb)
    });
    if let Some((pairs, _, _)) = &across {
        all.extend_from_slice(pairs);
    }
    let (features, logits) = net.decode(planes, &all).await?;
    let clip = settings.label_clip.unwrap_or(f32::INFINITY);
    let mut y = targets(&logits, points.len(), clip, settings.prior_mean);
    if let Some((_, normals, nb)) = &across {
        // Their labels come from the orderings, not from the logits' signs.
        let start = points.len() + extra.len();
        let labels = orient::across_targets(normals, nb, &logits[start..], orient::FLOOR, clip);
        for (i, l) in labels.into_iter().enumerate() {
            y[start + i] = match settings.prior_mean {
                PriorMean::Zero => l,
                PriorMean::Network => l - logits[start + i],
            };
        }
    }
    let x = regression_input(settings.euclidean, settings.position, &all, features);
    let problem = krr::Problem::from_f32(&x, &y, input_dim(settings, net.config().c_dim))?;
    Ok(TrainingPairs { problem, inputs: points.len() })
}

/// The regression's targets for pairs whose network logits are `logits`, the first `inputs` of
/// them input points: 0 there and the logit clipped to ±`clip` elsewhere; when the network is
/// the prior mean, the residual: −l at the input points and 0 at the extra points.
///
/// The residual ignores the clip: what the clipping takes off a logit of −30 is a residual of
/// +26, which g then fits far from the surface, undoing the network where it is surest and
/// raising stray surface (measured on cow-10k: CD1 ×100 5.5 against 0.34 without).
pub fn targets(logits: &[f32], inputs: usize, clip: f32, mean: PriorMean) -> Vec<f32> {
    logits
        .iter()
        .enumerate()
        .map(|(i, &l)| match (mean, i < inputs) {
            (PriorMean::Zero, true) => 0.0,
            (PriorMean::Zero, false) => l.clamp(-clip, clip),
            (PriorMean::Network, true) => -l,
            (PriorMean::Network, false) => 0.0,
        })
        .collect()
}

/// Most pairs held out to score the tuning's iterates (see [`split_rows`]): enough that the
/// score's noise is far below the differences between iterates, few enough that scoring an
/// iterate (held × m × d) costs a small share of a step.
pub const HELD_OUT_MAX: usize = 1000;

/// `keep` of `rows` (sorted row indices), drawn (seeded) from the input points (rows below
/// `inputs`) and the extra points in proportion to their counts, so that the surface and the
/// pseudo-labels keep their shares; sorted.
fn stratified(rows: &[usize], inputs: usize, keep: usize, seed: u64) -> Vec<usize> {
    let split = rows.partition_point(|&r| r < inputs);
    let keep = keep.min(rows.len());
    let keep_inputs = ((keep as f64 * split as f64 / rows.len().max(1) as f64).round() as usize).min(split).min(keep);
    let keep_extra = (keep - keep_inputs).min(rows.len() - split);
    let mut out: Vec<usize> = krr::init::sample_rows(split, keep_inputs, seed).into_iter().map(|i| rows[i]).collect();
    out.extend(krr::init::sample_rows(rows.len() - split, keep_extra, seed + 1).into_iter().map(|i| rows[split + i]));
    out.sort_unstable();
    out
}

/// Most pairs held out under `settings`: [`HELD_OUT_MAX`] to select by them, none otherwise.
fn held_out_max(settings: &Settings) -> usize {
    if settings.select_by == SelectBy::HeldOut { HELD_OUT_MAX } else { 0 }
}

/// Pairs held out of `n` when at most `most` are asked for: at most a fifth of them.
fn held_count(n: usize, most: usize) -> usize {
    most.min(n / 5)
}

/// Which of `n` training pairs (the first `inputs` of them the input points) the tuning sees and
/// which score its iterates.
#[derive(Clone, Debug, PartialEq)]
pub struct RowSplit {
    /// The pairs the objective is tuned on; `None`: all of them.
    pub tune: Option<Vec<usize>>,
    /// The pairs held out to score each iterate (empty: select by the training error).
    pub held: Vec<usize>,
}

/// Splits `n` pairs: `held` of them (at most a fifth) held out, stratified, and at most `keep`
/// of the rest to tune on, stratified too.
///
/// Why a subsample is enough to tune on: the objective (with `Ridge::full_n`) is estimated from
/// a uniform subsample, and the length-scales and inducing points it tunes are a few thousand
/// numbers, which a few thousand pairs determine; the n·m² Gram, the cost of a step, shrinks
/// with n. β, which has to reach every point, is then solved once on all pairs.
pub fn split_rows(n: usize, inputs: usize, keep: Option<usize>, held: usize, seed: u64) -> RowSplit {
    let all: Vec<usize> = (0..n).collect();
    let held = stratified(&all, inputs, held_count(n, held), seed);
    let rest: Vec<usize> = if held.is_empty() {
        all
    } else {
        let mut is_held = vec![false; n];
        held.iter().for_each(|&r| is_held[r] = true);
        (0..n).filter(|&r| !is_held[r]).collect()
    };
    let tune = match keep {
        Some(k) if k < rest.len() => Some(stratified(&rest, inputs, k, seed + 2)),
        _ if rest.len() < n => Some(rest),
        _ => None,
    };
    RowSplit { tune, held }
}

/// What the memory plan decided for the regression ([`crate::plan::MemoryPlan::regression`]),
/// which [`fit`] takes as it is: the inducing points and where the objective runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Regression {
    pub m: usize,
    pub on_gpu: bool,
}

/// How many of `pairs` training pairs the tuning sees under `settings`: what [`split_rows`]
/// leaves to tune on once the held-out pairs are set aside, at most [`Settings::tune_pairs`].
/// The inducing points are drawn from these rows, so m cannot exceed it (see
/// [`crate::plan::inducing_points`], which decides m).
pub fn tuning_rows(pairs: usize, settings: &Settings) -> usize {
    let rest = pairs - held_count(pairs, held_out_max(settings));
    settings.tune_pairs.map_or(rest, |k| k.min(rest))
}

/// Initialises (Z from rows of X, length-scales from the features' spread) and tunes the
/// Nyström KRR with the plan's `m` inducing points and backend (`regression`) on [`Settings::tune_pairs`] of the pairs (see
/// [`split_rows`]), keeping the parameters with the lowest error on held-out pairs or, as the
/// paper does, the lowest training error (method.md §4; [`Settings::select_by`]), then solves β
/// on all pairs.
/// `progress(step, loss)` returning false cancels.
pub async fn fit(
    gpu: &Gpu,
    pairs: &TrainingPairs,
    settings: &Settings,
    regression: Regression,
    progress: &mut dyn FnMut(usize, f64) -> bool,
) -> Result<(KrrField, TuningSummary), FitError> {
    let Regression { m, on_gpu } = regression;
    debug_assert_eq!(settings.method, Method::Nkrr);
    let all = &pairs.problem;
    let held = held_out_max(settings);
    let split = split_rows(all.n(), pairs.inputs, settings.tune_pairs, held, 5);
    let subset = split.tune.as_ref().map(|rows| all.select(rows));
    let validation = (!split.held.is_empty()).then(|| all.select(&split.held));
    let problem = subset.as_ref().unwrap_or(all);
    // m is the plan's (crate::plan::inducing_points), never changed here: a stage that caps it
    // again changes the user's setting without a word.
    if m == 0 || m > problem.n() {
        return Err(FitError::Krr(KrrError::Setting(format!(
            "{m} inducing points planned for {} tuning pairs: the plan and the pairs disagree (a bug)",
            problem.n()
        ))));
    }
    let init = krr::init_params(problem, m, 3, LengthScaleInit::default());
    // Tuning on a subsample minimises its estimate of the objective on all pairs.
    let ridge = krr::Ridge { full_n: subset.as_ref().map(|_| all.n()), ..krr::Ridge::new(settings.lambda, m) };
    let solve = krr::Ridge { full_n: None, ..ridge };
    let ts = TuneSettings {
        steps: settings.steps,
        lr: settings.lr,
        tune_theta: settings.tune_theta,
        tune_z: settings.tune_z,
        ..Default::default()
    };
    // The held-out pairs' mean squared error under the iterate's own β.
    let score = |params: &krr::Params, eval: &krr::Eval| -> Result<Option<f64>, KrrError> {
        let Some(v) = &validation else { return Ok(None) };
        let g = krr::predict(&eval.beta, &params.z, &params.log_s, v.x())?;
        Ok(Some(g.iter().zip(v.y()).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / v.n() as f64))
    };
    let report = |step: usize, eval: &krr::Eval| progress(step, eval.loss);
    let (result, predictor, evaluations, phases, beta) = if on_gpu {
        let objective = krr::GpuObjective::new(gpu, problem, ridge).await.map_err(KrrError::from)?;
        let objective = RefCell::new(objective);
        let evaluate = |params: krr::Params, needs_grad: bool| {
            let (objective, score) = (&objective, &score);
            async move {
                let (e, g) = objective.borrow_mut().evaluate(&params, needs_grad).await?;
                let s = score(&params, &e)?;
                Ok((e, g, s))
            }
        };
        let result = krr::tune_async_scored(evaluate, init, &ts, report).await?;
        let mut objective = objective.into_inner();
        let mut evaluations = objective.evaluations;
        let mut phases = objective.total_timings;
        let beta = if subset.is_some() && !matches!(result.stop, krr::StopReason::Cancelled) {
            // One objective at a time on the device: the subset's buffers go before all pairs'
            // (natively the device frees them at its next poll, so poll before allocating).
            drop(objective);
            gpu.poll_wait();
            objective = krr::GpuObjective::new(gpu, all, solve).await.map_err(KrrError::from)?;
            let (eval, _) = objective.evaluate(&result.params, false).await?;
            evaluations += objective.evaluations;
            phases.accumulate(&objective.total_timings);
            eval.beta
        } else {
            result.eval.beta.clone()
        };
        (result, Some(objective.predictor().clone()), evaluations, Some(phases), beta)
    } else {
        let mut objective = krr::Reference { problem, settings: ridge };
        let result = krr::tune_scored(&mut objective, init, &ts, score, report)?;
        let mut evaluations = result.history.len();
        let beta = if subset.is_some() && !matches!(result.stop, krr::StopReason::Cancelled) {
            evaluations += 1;
            krr::objective(all, &result.params, &solve)?.beta
        } else {
            result.eval.beta.clone()
        };
        (result, None, evaluations, None, beta)
    };
    if matches!(result.stop, krr::StopReason::Cancelled) {
        return Err(FitError::Cancelled);
    }
    // The tuner's first evaluation is of the initial parameters.
    let (first, last) = (result.history[0], result.history[result.history.len() - 1]);
    let summary = TuningSummary {
        backend: if on_gpu { "gpu" } else { "cpu" },
        n: all.n(),
        tuned_on: problem.n(),
        held_out: split.held.len(),
        initial_score: first.score,
        best_score: result.history.iter().find(|h| h.step == result.best_step).and_then(|h| h.score),
        m,
        steps_run: result.history.len() - 1,
        best_step: result.best_step,
        stop: format!("{:?}", result.stop),
        initial_loss: first.loss,
        final_loss: last.loss,
        initial_data_fit: first.data_fit,
        best_data_fit: result.eval.data_fit,
        length_scales: result.params.length_scales(),
        evaluations,
        phases,
    };
    let field = KrrField {
        beta,
        params: result.params,
        euclidean: settings.euclidean,
        position: settings.position,
        network_mean: settings.prior_mean == PriorMean::Network,
        gpu: predictor,
    };
    Ok((field, summary))
}

#[cfg(test)]
mod tests {
    use super::{input_dim, regression_input, split_rows, targets, KrrField, FOURIER_DIM};
    use crate::settings::{PriorMean, Settings};

    #[test]
    fn the_position_follows_each_points_features() {
        let points = [[0.5, -0.25, 0.125], [1.0, 2.0, 3.0]];
        let features = vec![1.0, 2.0, 3.0, 4.0];
        assert_eq!(regression_input(false, false, &points, features.clone()), features);
        assert_eq!(
            regression_input(false, true, &points, features.clone()),
            vec![1.0, 2.0, 0.5, -0.25, 0.125, 3.0, 4.0, 1.0, 2.0, 3.0]
        );
        assert_eq!(regression_input(true, true, &points, features).len(), 2 * FOURIER_DIM);
        let mut s = Settings::default();
        assert_eq!(input_dim(&s, 32), 32);
        s.position = true;
        assert_eq!(input_dim(&s, 32), 35);
    }


    #[test]
    fn targets_with_and_without_the_network_as_prior_mean() {
        // Two input points, then three extra points (one beyond the clip).
        let logits = [0.5, -0.25, 2.0, -7.0, 1.0];
        assert_eq!(targets(&logits, 2, 4.0, PriorMean::Zero), vec![0.0, 0.0, 2.0, -4.0, 1.0]);
        // The residual: −l at the input points, 0 at the extra points, whatever the clip.
        assert_eq!(targets(&logits, 2, 4.0, PriorMean::Network), vec![-0.5, 0.25, 0.0, 0.0, 0.0]);
        assert_eq!(targets(&logits, 2, f32::INFINITY, PriorMean::Network), vec![-0.5, 0.25, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn the_field_adds_the_logit_when_the_network_is_the_mean() {
        let params = crate::krr::Params { log_s: vec![0.0, 0.0], z: vec![0.0, 0.0, 1.0, 0.5] };
        let field = |network_mean| KrrField { params: params.clone(), beta: vec![0.7, -0.3], euclidean: false, position: false, network_mean, gpu: None };
        let points = [[0.0f32; 3]; 3];
        let features = vec![0.0f32, 0.0, 1.0, 0.5, 0.2, -0.4];
        let logits = [1.5f32, -2.0, 0.25];
        let g = pollster::block_on(field(false).predict(&points, features.clone(), &logits)).unwrap();
        let lg = pollster::block_on(field(true).predict(&points, features, &logits)).unwrap();
        for i in 0..3 {
            assert_eq!(lg[i], g[i] + logits[i]);
        }
        assert!((g[0] - (0.7 - 0.3 * (-0.5f32 * 1.25).exp())).abs() < 1e-6, "g at the first centre: {}", g[0]);
    }

    #[test]
    fn tuning_rows_keep_each_kind_in_proportion() {
        // 3000 input points and 3000 extra points: half of the 1000 rows from each.
        let rows = split_rows(6000, 3000, Some(1000), 0, 5).tune.expect("a subsample");
        assert_eq!(rows.len(), 1000);
        assert!(rows.windows(2).all(|w| w[0] < w[1]), "sorted and distinct");
        assert_eq!(rows.iter().filter(|&&i| i < 3000).count(), 500);
        assert!(*rows.last().unwrap() < 6000);
        // Unequal kinds keep their shares; the same seed gives the same rows.
        let rows = split_rows(4000, 1000, Some(400), 0, 9).tune.unwrap();
        assert_eq!(rows.iter().filter(|&&i| i < 1000).count(), 100);
        assert_eq!(split_rows(4000, 1000, Some(400), 0, 9).tune.unwrap(), rows);
        assert_ne!(split_rows(4000, 1000, Some(400), 0, 10).tune.unwrap(), rows);
    }

    #[test]
    fn tuning_rows_are_all_rows_when_there_are_few() {
        assert_eq!(split_rows(500, 250, Some(500), 0, 5).tune, None);
        assert_eq!(split_rows(500, 250, Some(4000), 0, 5).tune, None);
        assert_eq!(split_rows(500, 250, None, 0, 5).tune, None);
        assert_eq!(split_rows(501, 250, Some(500), 0, 5).tune.map(|r| r.len()), Some(500));
    }

    #[test]
    fn held_out_rows_are_apart_from_the_tuning_rows() {
        // At most a fifth held out, stratified; the tuning rows are the others (subsampled).
        let s = split_rows(1000, 500, Some(4000), 1000, 3);
        let tune = s.tune.expect("the held-out rows are left out");
        assert_eq!((s.held.len(), tune.len()), (200, 800));
        assert_eq!(s.held.iter().filter(|&&i| i < 500).count(), 100);
        assert!(s.held.iter().all(|r| tune.binary_search(r).is_err()));
        let s = split_rows(20000, 10000, Some(4000), 1000, 3);
        let tune = s.tune.unwrap();
        assert_eq!((s.held.len(), tune.len()), (1000, 4000));
        assert!(s.held.iter().all(|r| tune.binary_search(r).is_err()));
        assert_eq!(tune.iter().filter(|&&i| i < 10000).count(), 2000);
    }
}
