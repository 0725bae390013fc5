//! The stages strung together: cloud → unit cube → network features → field → mesh → user
//! coordinates. Async so the browser (whose GPU readbacks resolve on its event loop) and the
//! CLI (which blocks on the same future) run one code path. Progress is reported per stage
//! through a callback that can also cancel between steps.

use std::cell::RefCell;

use crate::cloud::{subsample, Normalization, PointCloud};
use crate::field::{self, Field};
use crate::gpu::{now, Gpu};
use crate::mesh::finish::Closure;
use crate::mesh::{extract_gpu_async, ExtractError, ExtractOptions, FieldError};
use crate::net::{GpuNet, Weights};
use crate::plan::{DeviceFacts, MemoryPlan};
use crate::settings::{Method, Settings, Surface};
pub use crate::reconstruction::{PipelineError, Reconstruction, SceneReport};

/// A stage of the pipeline, as reported to the progress callback.
#[derive(Clone, Debug, PartialEq)]
pub enum Stage {
    Features,
    /// Training pairs: extra points sampled and labelled by the network.
    Pairs,
    /// Test-time tuning: `step` of at most `of`, with the objective's value.
    Tuning { step: usize, of: usize, loss: f64 },
    /// Field evaluations made so far while meshing, and about how many it will take
    /// ([`crate::mesh::refine::MeshingSize::expected`]: a typical count, which a run may pass).
    Meshing { evaluated: usize, expected: usize },
    /// The screened Poisson surface ([`crate::poisson`]): the field's mesh orients the points'
    /// normals, then the solve and its marching cubes.
    Surface,
    /// A scene's tiles ([`crate::scene`]): `done` of `of` reconstructed.
    Tile { done: usize, of: usize },
    /// A scene's triangles that are final before the finish stage (the blend around them is
    /// complete), to show while the rest is computed: in the mesh's coordinates (as
    /// [`Reconstruction::mesh`]), indices into this piece's own `positions`. The finish (last
    /// fit, trim, simplification) may still move or drop them.
    Meshed { positions: Vec<[f32; 3]>, indices: Vec<u32> },
    /// The network's own field meshed and finished, to compare with the tuned field's mesh (the
    /// guard in [`Engine::reconstruct`]); reported at each of that run's steps, in place of them.
    Prior,
    /// Once, when the result is ready.
    Done,
}

/// One pass of [`Engine::reconstruct`]: the result, or the Poisson surface's reason to mesh the
/// field instead and the seconds that pass took.
enum Attempt {
    /// The result and, where the field's level set is the surface under `--surface auto` (a
    /// scan the Poisson surface ballooned over, a cloud under 1,000 points), how far its mesh
    /// lies from the points ([`Closure::distance`], in the unit cube).
    Done(Reconstruction, Option<f64>),
    FieldInstead { notice: String, seconds: f64 },
}

/// The GPU-resident parts that outlive one reconstruction (weights uploaded once).
pub struct Engine {
    pub gpu: Gpu,
    pub net: GpuNet,
}

impl Engine {
    /// Uploads the built-in network prior to `gpu`.
    pub async fn new(gpu: Gpu) -> Result<Engine, PipelineError> {
        Engine::with_weights(gpu, &Weights::prior().map_err(PipelineError::Net)?).await
    }

    /// Uploads `weights`, a prior in the same format (a retrained one, `nkrr --weights`), to `gpu`.
    pub async fn with_weights(gpu: Gpu, weights: &Weights) -> Result<Engine, PipelineError> {
        Ok(Engine { net: GpuNet::new(&gpu, weights).await?, gpu })
    }

    /// The memory each stage will take for a cloud of `points` points on this engine's
    /// adapter, and what will be changed to fit (see [`crate::plan`]).
    pub fn memory_plan(&self, points: usize, colours: bool, settings: &Settings) -> MemoryPlan {
        crate::plan::memory_plan(points, colours, settings, self.net.config(), &DeviceFacts::of(&self.gpu))
    }

    /// Reconstructs `cloud`. `progress` is called at each stage and during meshing; returning
    /// false cancels at the next step.
    pub async fn reconstruct(&self, cloud: &PointCloud, settings: &Settings, progress: &mut dyn FnMut(&Stage) -> bool) -> Result<Reconstruction, PipelineError> {
        let (mut settings, mut first) = (settings.clone(), None);
        loop {
            // The second attempt knows the scan saw one side (`first` holds the balloon's notice).
            // Only nkrr's run is compared with the network's (the guard below): only it measures.
            match self.attempt(cloud, &settings, first.is_some(), settings.method == Method::Nkrr, progress).await? {
                Attempt::Done(mut rec, distance) => {
                    // Never worse than the prior on a shell: where the tuned field's mesh lies
                    // farther from the points than the network's (holes in a sheet it thinned, a
                    // fill no point carries), the network's mesh (docs/poisson.md, "Open shells").
                    if let Some(tuned) = distance {
                        let t = now();
                        // Its steps show as one stage: the bar and the words do not start over.
                        let mut as_prior = |_: &Stage| progress(&Stage::Prior);
                        if let Attempt::Done(net, Some(prior)) = self.attempt(cloud, &Settings { method: Method::Network, ..settings.clone() }, first.is_some(), true, &mut as_prior).await? {
                            rec = if tuned > prior { Reconstruction { notices: [vec![crate::mesh::trim::farther_notice(tuned, prior)], net.notices].concat(), ..net } } else { rec };
                            rec.timings.push(("the network's mesh", now() - t));
                        }
                    }
                    if let Some((notice, seconds)) = first {
                        rec.notices.insert(0, notice);
                        rec.timings.insert(0, ("poisson attempt", seconds));
                    }
                    progress(&Stage::Done);
                    return Ok(rec);
                }
                // The Poisson surface ballooned (a one-sided scan): the whole run again on the
                // field's level set, nkrr's tuning included (`Surface::Field` never comes here).
                Attempt::FieldInstead { notice, seconds } => (first, settings.surface) = (Some((notice, seconds)), Surface::Field),
            }
        }
    }

    /// `measure`: the caller compares this run's mesh with another's, so where the field's level
    /// set is the surface its distance to the points comes back ([`Closure::distance`]).
    async fn attempt(&self, cloud: &PointCloud, settings: &Settings, one_sided: bool, measure: bool, progress: &mut dyn FnMut(&Stage) -> bool) -> Result<Attempt, PipelineError> {
        let t_all = now();
        let mut timings = Vec::new();
        let mut notices = Vec::new();
        let mut warnings = Vec::new();
        // Too few points first; the shape checks wait for the stray-point filter (a far one made a sphere "a line").
        Normalization::enough_points(cloud.len()).map_err(PipelineError::Cloud)?;
        // The preflight's plan decides how many points and inducing points fit this adapter
        // (and, in the browser, the host budget); its actions become notices. The settings stay
        // what the user asked for.
        let plan = self.memory_plan(cloud.len(), cloud.colors.is_some(), settings);
        notices.extend(plan.actions.iter().map(|a| format!("to fit in memory, nkrr will {a}")));
        notices.extend(plan.decisions.iter().map(|d| format!("nkrr will {d}")));
        let max_points = plan.n.min(settings.max_points);
        let mut seen = if cloud.len() > max_points {
            notices.push(format!("the cloud has {} points; the network sees a uniform subsample of {max_points}", cloud.len()));
            subsample(&cloud.positions, max_points, 1)
        } else {
            cloud.positions.clone()
        };
        // Stray points go before the normalisation, which they would otherwise stretch (see
        // crate::outliers); the filter scores the points the network will see.
        if let Some(ratio) = settings.outliers {
            let t = now();
            let said;
            (seen, said) = crate::outliers::filter(seen, ratio);
            said.into_iter().for_each(|(text, warning)| if warning { warnings.push(text) } else { notices.push(text) });
            timings.push(("outliers", now() - t));
        }
        let seen = PointCloud { positions: seen, origin: cloud.origin, normals: None, colors: None };
        let norm = Normalization::of(&seen).map_err(PipelineError::Cloud)?;
        let points: Vec<[f32; 3]> = seen.positions.iter().map(|p| norm.forward(*p)).collect();

        if !progress(&Stage::Features) {
            return Err(PipelineError::Cancelled);
        }
        let mut peaks = crate::gpu::StagePeaks::start(&self.gpu);
        let t = now();
        let planes = self.net.encode(&points).await?;
        self.gpu.work_done().await;
        timings.push(("features", now() - t));
        peaks.end("features");

        let mut tuning = None;
        // With the Poisson surface the field only signs the normals, which the tuning does not
        // change (docs/poisson.md): nkrr tunes only if the surface falls back to the field.
        let field = if settings.method == Method::Nkrr && !plan.poisson {
            if !progress(&Stage::Pairs) {
                return Err(PipelineError::Cancelled);
            }
            let t = now();
            let pairs = field::training_pairs(&self.net, &planes, &points, settings).await?;
            timings.push(("pairs", now() - t));
            peaks.end("pairs");
            let t = now();
            let mut report = |step: usize, loss: f64| progress(&Stage::Tuning { step, of: settings.steps, loss });
            // The plan's regression, for the points the stray-point filter kept (fewer pairs).
            let (regression, fewer) = plan.regression(settings, points.len());
            notices.extend(fewer);
            let (fit, summary) = field::fit(&self.gpu, &pairs, settings, regression, &mut report).await?;
            timings.push(("tuning", now() - t));
            peaks.end("tuning");
            tuning = Some(summary);
            Field::Krr(fit)
        } else {
            Field::Network
        };

        let opts = ExtractOptions { resolution: settings.resolution, remove_small_components: settings.remove_small_components, ..Default::default() };
        // The field's own mesh: the result, or (Poisson) what orients the normals, coarser.
        let field_opts = ExtractOptions { resolution: if plan.poisson { crate::poisson::orient_resolution(opts.resolution) } else { opts.resolution }, ..opts.clone() };
        let t = now();
        let evaluated = RefCell::new(0usize);
        let cancelled = RefCell::new(false);
        let progress = RefCell::new(progress);
        // Made once for the whole extraction: the decoder's and the predictor's buffers.
        let evaluator = &field.evaluator(&self.net, &planes, field::EVALUATION_CHUNK).map_err(|e| PipelineError::Mesh(ExtractError::Field(FieldError(e))))?;
        // A refinement batch can hold a third of all evaluations: evaluated in chunks, with the
        // evaluations done so far told before each, the bar moves with the work instead of
        // jumping ahead of it.
        let expected = crate::mesh::refine::MeshingSize::at(field_opts.resolution).expected as usize;
        let eval = |pts: Vec<[f32; 3]>| {
            let (evaluated, cancelled, progress) = (&evaluated, &cancelled, &progress);
            async move {
                let mut values = Vec::with_capacity(pts.len());
                for chunk in pts.chunks(field::EVALUATION_CHUNK) {
                    if !(progress.borrow_mut())(&Stage::Meshing { evaluated: *evaluated.borrow(), expected }) {
                        *cancelled.borrow_mut() = true;
                        return Err(FieldError("cancelled".into()));
                    }
                    values.extend(evaluator.evaluate(chunk).await.map_err(FieldError)?);
                    *evaluated.borrow_mut() += chunk.len();
                }
                Ok(values)
            }
        };
        let extraction = extract_gpu_async(&self.gpu, eval, &field_opts).await;
        if *cancelled.borrow() {
            return Err(PipelineError::Cancelled);
        }
        let mut extraction = extraction.map_err(PipelineError::Mesh)?;
        // The points as the balloon guard measures "far" (index, spacing, hull), made once for the
        // guard and the opening of a Poisson surface it keeps over a worse field (thin walls).
        let guard = (plan.poisson && settings.surface == Surface::Auto).then(|| crate::mesh::trim::Reach::of(&points));
        let mut open_far = false;
        timings.push(("mesh", now() - t));
        peaks.end("meshing");
        if extraction.mesh.indices.is_empty() {
            let r = &extraction.stats.refine;
            return Err(PipelineError::NoSurface { evaluations: r.evaluations, field_max: r.field_max, method: settings.method });
        }
        if plan.poisson {
            if !(progress.borrow_mut())(&Stage::Surface) {
                return Err(PipelineError::Cancelled);
            }
            let t = now();
            let (chi, orientation) = crate::poisson::from_mesh(&extraction.mesh, &points, crate::poisson::grid_for(opts.domain, opts.resolution, points.len()));
            // χ is a cubic lookup, searched coarse to fine as the field is (the dense grid gave the
            // same triangles on the tuning shapes, for twice the memory); the field's count is kept.
            let field_stats = extraction.stats.refine.clone();
            let values = |q: Vec<[f32; 3]>| std::future::ready(Ok(q.iter().map(|&p| chi.value(p)).collect()));
            let surface = extract_gpu_async(&self.gpu, values, &opts).await.map_err(PipelineError::Mesh)?;
            // Judged only where the surface is ours to choose (`--surface poisson` keeps it).
            match guard.as_ref().map(|reach| crate::poisson::Balloon::check(&surface.mesh, &extraction.mesh, reach, settings.trim)) {
                Some(crate::poisson::Balloon::FieldInstead(notice)) => return Ok(Attempt::FieldInstead { notice, seconds: now() - t_all }),
                Some(crate::poisson::Balloon::Kept { notice, open }) => { open_far = open; notices.push(notice) }
                _ => {}
            }
            notices.push(chi.notice(&orientation, points.len()));
            notices.extend((settings.method == Method::Nkrr).then(|| crate::poisson::UNTUNED.to_string()));
            extraction = surface;
            extraction.stats.refine = field_stats;
            timings.push(("poisson", now() - t));
            peaks.end("poisson");
        }

        let mut mesh = extraction.mesh;
        // Fitted and trimmed in the unit cube, against the points the network saw.
        // Where the field's level set is the surface we chose (a scan the Poisson surface
        // ballooned over, a cloud too small for it), an open shell's fill may go, and the guard
        // in `reconstruct` compares how far its mesh and the network's lie from the points.
        let closure = if one_sided {
            Closure::OneSided
        } else if let Some(reach) = guard.as_ref().filter(|_| open_far) {
            Closure::Open(reach)
        } else if settings.surface == Surface::Auto && !plan.poisson {
            Closure::Sparse
        } else {
            Closure::Keep
        };
        let finished = crate::mesh::finish::finish(&mut mesh, &points, settings, crate::mesh::fit::Fitted::object(plan.poisson), closure, None, &mut notices, &mut timings);
        let distance = if measure { closure.distance(&mesh, &points) } else { None };
        for p in &mut mesh.positions {
            *p = norm.inverse(*p);
        }
        if settings.colors && cloud.colors.is_some() {
            let t = now();
            crate::mesh::colour::transfer(&mut mesh, cloud, crate::mesh::colour::DEFAULT_K);
            timings.push(("colours", now() - t));
        }
        // Units last: every stage above works in the cloud's own coordinates (the network's
        // normalisation makes the scale irrelevant to it), and a similarity keeps normals.
        let origin = crate::units::to_metres(settings.units, &mut mesh.positions, cloud.origin);
        let crate::mesh::finish::Finished { fit, trim, simplify } = finished;
        Ok(Attempt::Done(Reconstruction { mesh, origin, fit, trim, simplify, notices, warnings, extract: extraction.stats, tuning, timings, gpu_peaks: peaks.peaks, scene: None }, distance))
    }
}
