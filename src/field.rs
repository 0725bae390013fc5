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
use crate::settings::{Method, Settings};

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
        c_dim
    }
}

/// The fitted regression g(x) = Σ_j β_j k(x, z_j), evaluated where it was tuned.
pub struct KrrField {
    params: krr::Params,
    beta: Vec<f64>,
    /// Fourier-encoded coordinates instead of the network's features (the ablation).
    euclidean: bool,
    /// The GPU predictor when the regression was tuned on the GPU; else the f64 reference.
    gpu: Option<krr::GpuPredictor>,
}

impl KrrField {
    /// g at `points`, whose network features are `features`.
    pub async fn predict(&self, points: &[[f32; 3]], features: Vec<f32>) -> Result<Vec<f32>, String> {
        let x = if self.euclidean { fourier_encode(points) } else { features };
        let (beta, z, log_s) = (&self.beta, &self.params.z, &self.params.log_s);
        match &self.gpu {
            Some(p) => p.predict(beta, z, log_s, &x).await.map_err(|e| e.to_string()),
            None => {
                let x: Vec<f64> = x.iter().map(|&v| v as f64).collect();
                krr::predict(beta, z, log_s, &x).map(|g| g.into_iter().map(|v| v as f32).collect()).map_err(|e| e.to_string())
            }
        }
    }
}

/// The field the mesher evaluates: the network alone, or the network's features through the
/// fitted regression.
pub enum Field {
    Network,
    Krr(KrrField),
}

impl Field {
    /// The field at `points` (the unit cube), decoding their features from `planes`.
    pub async fn evaluate(&self, net: &GpuNet, planes: &GpuPlanes, points: &[[f32; 3]]) -> Result<Vec<f32>, String> {
        let (features, logits) = net.decode(planes, points).await.map_err(|e| e.to_string())?;
        match self {
            Field::Network => Ok(logits),
            Field::Krr(fit) => fit.predict(points, features).await,
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

/// Host bytes of [`training_pairs`] for `points` points (two pairs a point) with a network of
/// `c_dim` features and `d` regression inputs: the extra points and their neighbour search,
/// the decoded features and logits, and the problem in f64.
pub fn pairs_host_bytes(points: u64, c_dim: u64, d: u64) -> u64 {
    2 * points * (4 * c_dim + 8 * d + 20) + 40 * points
}

/// The regression's training set: the problem and how many of its first rows are input points.
pub struct TrainingPairs {
    pub problem: krr::Problem,
    /// Rows `0..inputs` are the input points (label 0); the rest are the extra points.
    pub inputs: usize,
}

/// X = F([P, P~]), y = [0, l(P~)] (paper eq. 6): the input points lie on the surface (logit 0),
/// the extra points take the network's logit as a pseudo-label, clipped to
/// [`Settings::label_clip`].
pub async fn training_pairs(
    net: &GpuNet,
    planes: &GpuPlanes,
    points: &[[f32; 3]],
    settings: &Settings,
) -> Result<TrainingPairs, FitError> {
    let extra = crate::sample::upsample(points, settings.knn_k, 2);
    let mut all = points.to_vec();
    all.extend_from_slice(&extra);
    let (features, logits) = net.decode(planes, &all).await?;
    let clip = settings.label_clip.unwrap_or(f32::INFINITY);
    let y: Vec<f32> =
        logits.iter().enumerate().map(|(i, &l)| if i < points.len() { 0.0 } else { l.clamp(-clip, clip) }).collect();
    let x = if settings.euclidean { fourier_encode(&all) } else { features };
    let problem = krr::Problem::from_f32(&x, &y, input_dim(settings, net.config().c_dim))?;
    Ok(TrainingPairs { problem, inputs: points.len() })
}

/// The rows the tuning sees: `keep` of `n` rows, drawn (seeded) from the input points
/// (`0..inputs`) and the extra points in proportion to their counts, so that the surface and
/// the pseudo-labels keep their shares; `None` when there are no more than `keep` rows.
///
/// Why a subsample is enough: the objective is a mean over pairs plus traces that scale with
/// n, and the length-scales and inducing points it tunes are a few thousand numbers, which a
/// few thousand pairs determine; the n·m² Gram, the cost of a step, shrinks with n. β, which
/// has to reach every point, is then solved once on all pairs.
pub fn tuning_rows(n: usize, inputs: usize, keep: usize, seed: u64) -> Option<Vec<usize>> {
    if keep >= n {
        return None;
    }
    let inputs = inputs.min(n);
    let keep_inputs = ((keep as f64 * inputs as f64 / n as f64).round() as usize).min(inputs).min(keep);
    let mut rows = krr::init::sample_rows(inputs, keep_inputs, seed);
    rows.extend(krr::init::sample_rows(n - inputs, keep - keep_inputs, seed + 1).into_iter().map(|i| i + inputs));
    rows.sort_unstable();
    Some(rows)
}

/// Initialises (Z from rows of X, length-scales from the features' spread) and tunes the
/// Nyström KRR with `m` inducing points on [`Settings::tune_pairs`] of the pairs, keeping the
/// parameters with the lowest training error (method.md §4), then solves β on all pairs.
/// `progress(step, loss)` returning false cancels.
pub async fn fit(
    gpu: &Gpu,
    pairs: &TrainingPairs,
    settings: &Settings,
    m: usize,
    progress: &mut dyn FnMut(usize, f64) -> bool,
) -> Result<(KrrField, TuningSummary), FitError> {
    debug_assert_eq!(settings.method, Method::Nkrr);
    let all = &pairs.problem;
    let subset = settings.tune_pairs.and_then(|k| tuning_rows(all.n(), pairs.inputs, k, 5)).map(|rows| all.select(&rows));
    let problem = subset.as_ref().unwrap_or(all);
    let m = m.clamp(1, problem.n());
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
    let on_gpu = settings.krr_backend.on_gpu(gpu.is_software());
    let report = |step: usize, eval: &krr::Eval| progress(step, eval.loss);
    let (result, predictor, evaluations, phases, beta) = if on_gpu {
        let objective = krr::GpuObjective::new(gpu, problem, ridge).await.map_err(KrrError::from)?;
        let objective = RefCell::new(objective);
        let evaluate = |params: krr::Params, needs_grad: bool| {
            let objective = &objective;
            async move { objective.borrow_mut().evaluate(&params, needs_grad).await }
        };
        let result = krr::tune_async(evaluate, init, &ts, report).await?;
        let mut objective = objective.into_inner();
        let mut evaluations = objective.evaluations;
        let mut phases = objective.total_timings;
        let beta = if subset.is_some() && !matches!(result.stop, krr::StopReason::Cancelled) {
            // One objective at a time on the device: the subset's buffers go before all pairs'.
            drop(objective);
            objective = krr::GpuObjective::new(gpu, all, solve).await.map_err(KrrError::from)?;
            let (eval, _) = objective.evaluate(&result.params, false).await?;
            evaluations += objective.evaluations;
            phases = phases.plus(&objective.total_timings);
            eval.beta
        } else {
            result.eval.beta.clone()
        };
        (result, Some(objective.predictor().clone()), evaluations, Some(phases), beta)
    } else {
        let mut objective = krr::Reference { problem, settings: ridge };
        let result = krr::tune(&mut objective, init, &ts, report)?;
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
    let field = KrrField { beta, params: result.params, euclidean: settings.euclidean, gpu: predictor };
    Ok((field, summary))
}

#[cfg(test)]
mod tests {
    use super::tuning_rows;

    #[test]
    fn tuning_rows_keep_each_kind_in_proportion() {
        // 3000 input points and 3000 extra points: half of the 1000 rows from each.
        let rows = tuning_rows(6000, 3000, 1000, 5).expect("a subsample");
        assert_eq!(rows.len(), 1000);
        assert!(rows.windows(2).all(|w| w[0] < w[1]), "sorted and distinct");
        assert_eq!(rows.iter().filter(|&&i| i < 3000).count(), 500);
        assert!(*rows.last().unwrap() < 6000);
        // Unequal kinds keep their shares; the same seed gives the same rows.
        let rows = tuning_rows(4000, 1000, 400, 9).unwrap();
        assert_eq!(rows.iter().filter(|&&i| i < 1000).count(), 100);
        assert_eq!(tuning_rows(4000, 1000, 400, 9).unwrap(), rows);
        assert_ne!(tuning_rows(4000, 1000, 400, 10).unwrap(), rows);
    }

    #[test]
    fn tuning_rows_are_all_rows_when_there_are_few() {
        assert_eq!(tuning_rows(500, 250, 500, 5), None);
        assert_eq!(tuning_rows(500, 250, 4000, 5), None);
        assert_eq!(tuning_rows(501, 250, 500, 5).map(|r| r.len()), Some(500));
    }
}
