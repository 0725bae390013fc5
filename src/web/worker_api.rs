//! The reconstruction as a JavaScript API, meant to run in a Web Worker (`web/worker.js`) so
//! the page stays responsive: cloud bytes and a plain options object in, a GLB, the mesh's arrays
//! (for the viewer) and a stats object out. One [`Engine`] (device + uploaded network weights)
//! is kept per thread and reused by later calls; it is dropped when its device is lost, and the
//! next call makes a new one. What the page itself calls is [`super::page_api`].

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;

use js_sys::{Array, Float32Array, Function, Object, Uint32Array, Uint8Array};
use wasm_bindgen::prelude::*;

use super::js::set;
use super::options::{error, Options};
use crate::gpu::{now, Gpu};
use crate::io::gltf;
use crate::pipeline::{Engine, PipelineError, Reconstruction, Stage};
use crate::settings::{self, Settings};

thread_local! {
    static ENGINE: RefCell<Option<Rc<Engine>>> = const { RefCell::new(None) };
    /// Set by the device-lost callback and the uncaptured-error handler; read (and cleared) by
    /// the next call, which reports it.
    static GPU_TROUBLE: RefCell<Option<String>> = const { RefCell::new(None) };
}

fn note_trouble(msg: String) {
    GPU_TROUBLE.with(|t| {
        let mut t = t.borrow_mut();
        if t.is_none() {
            *t = Some(msg);
        }
    });
}

fn take_trouble() -> Option<String> {
    GPU_TROUBLE.with(|t| t.borrow_mut().take())
}

/// The engine of this thread, made on first use (a GPU device and the network weights).
async fn engine() -> Result<Rc<Engine>, JsValue> {
    if let Some(e) = ENGINE.with(|c| c.borrow().clone()) {
        return Ok(e);
    }
    let gpu = Gpu::new().await.map_err(|e| error("GpuError", &e.to_string()))?;
    // Without a handler wgpu panics on an uncaptured error, which would poison the module for
    // good; record it instead, and fail the reconstruction that caused it.
    gpu.device.on_uncaptured_error(Arc::new(|e: wgpu::Error| {
        web_sys::console::error_1(&format!("nkrr: GPU error: {e}").into());
        note_trouble(format!("the GPU reported an error: {e}"));
    }));
    gpu.device.set_device_lost_callback(|reason, msg| {
        // A deliberate destroy (the worker ending) is not news.
        if reason != wgpu::DeviceLostReason::Destroyed {
            note_trouble(format!("the GPU device was lost ({reason:?}): {msg}"));
        }
        ENGINE.with(|c| c.borrow_mut().take());
    });
    let engine = Rc::new(Engine::new(gpu).await.map_err(pipeline_error)?);
    ENGINE.with(|c| *c.borrow_mut() = Some(engine.clone()));
    Ok(engine)
}

/// Prepares the engine (device, weights, shaders) ahead of the first reconstruction and
/// resolves to a one-line description of the GPU adapter.
#[wasm_bindgen(js_name = prepareEngine)]
pub async fn prepare_engine() -> Result<String, JsValue> {
    let _ = take_trouble();
    Ok(engine().await?.gpu.describe())
}

/// Test hook: destroys this thread's GPU device as a driver reset would lose it. A run in
/// progress fails with a `GpuError`; the next call makes a new engine. Returns false when there
/// was no engine.
#[wasm_bindgen(js_name = simulateDeviceLoss)]
pub fn simulate_device_loss() -> bool {
    let Some(engine) = ENGINE.with(|c| c.borrow_mut().take()) else { return false };
    note_trouble("the GPU device was lost (simulated)".into());
    engine.gpu.device.destroy();
    true
}

/// Reconstructs a surface from a cloud file's bytes (any format of [`crate::io::read_cloud`]).
///
/// `options` is a plain object, every field optional: any key of [`settings_table`] (the same
/// settings, defaults and ranges as the CLI's flags; a value out of range rejects with a
/// `RangeError` that names the key and its range), and `name` (the glTF node's name).
///
/// `on_progress(p)` is called at each stage with `{ stage: "features" | "pairs" | "tuning" |
/// "meshing" | "tiles" | "meshed" | "done", step?, of?, loss?, evaluated?, expected?, done? }`;
/// returning `false` cancels, and the promise then rejects with an `Error` whose `name` is
/// `"AbortError"`. A scene sends `"meshed"` with a finished piece of its mesh (`positions`,
/// `normals`, `indices`, `triangles`; indices into the piece's own vertices, in the result's
/// coordinates) each time a tile completes some, to show before the whole mesh is done.
///
/// Resolves to `{ glb: Uint8Array, positions: Float32Array, normals: Float32Array,
/// indices: Uint32Array, stats }` (see `stats_object` for the fields of `stats`).
#[wasm_bindgen]
pub async fn reconstruct(bytes: Vec<u8>, options: JsValue, on_progress: Function) -> Result<JsValue, JsValue> {
    let t0 = now();
    let opts = Options::from_js(&options)?;
    let parsed = crate::io::read_cloud(&bytes, None).map_err(|e| error("CloudError", &e.to_string()))?;
    drop(bytes);
    let _ = take_trouble();
    let engine = engine().await?;
    let t_ready = now();

    let mut report = |s: &Stage| -> bool {
        let p = Object::new();
        let (stage, fields): (&str, Vec<(&str, f64)>) = match s {
            Stage::Meshed { positions, indices } => {
                // A piece of a scene's mesh, with normals to draw it by.
                let mut piece = crate::mesh::Mesh { positions: positions.clone(), indices: indices.clone(), ..Default::default() };
                piece.compute_vertex_normals();
                set(&p, "positions", Float32Array::from(bytemuck::cast_slice::<[f32; 3], f32>(&piece.positions)));
                set(&p, "normals", Float32Array::from(bytemuck::cast_slice::<[f32; 3], f32>(&piece.normals)));
                set(&p, "indices", Uint32Array::from(piece.indices.as_slice()));
                ("meshed", vec![("triangles", (indices.len() / 3) as f64)])
            }
            Stage::Features => ("features", vec![]),
            Stage::Pairs => ("pairs", vec![]),
            Stage::Surface => ("surface", vec![]),
            Stage::Tuning { step, of, loss } => ("tuning", vec![("step", *step as f64), ("of", *of as f64), ("loss", *loss)]),
            Stage::Meshing { evaluated, expected } => {
                ("meshing", vec![("evaluated", *evaluated as f64), ("expected", *expected as f64)])
            }
            Stage::Tile { done, of } => ("tiles", vec![("done", *done as f64), ("of", *of as f64)]),
            Stage::Prior => ("prior", vec![]),
            Stage::Done => ("done", vec![]),
        };
        set(&p, "stage", stage);
        for (k, v) in fields {
            set(&p, k, v);
        }
        match on_progress.call1(&JsValue::NULL, &p) {
            // Only an explicit `false` cancels; a callback that returns nothing continues.
            Ok(v) => v.as_bool() != Some(false),
            Err(e) => {
                web_sys::console::error_2(&"nkrr: the progress callback threw".into(), &e);
                true
            }
        }
    };
    // Made once: it sorts a sample of the cloud, and the notices say it again.
    let guess = parsed.units_guess();
    let result = crate::scene::reconstruct_auto(&engine, &parsed.cloud, &opts.settings, (&guess).into(), &mut report).await;
    if let Some(trouble) = take_trouble() {
        return Err(error("GpuError", &trouble));
    }
    let mut rec = result.map_err(pipeline_error)?;

    let t = now();
    let translation = rec.translation();
    let mut mesh = std::mem::take(&mut rec.mesh);
    if mesh.normals.len() != mesh.positions.len() {
        mesh.compute_vertex_normals();
    }
    let (glb, report) = gltf::write_glb_with_report(&mesh, &gltf::GlbOptions { name: opts.name.clone(), translation, compression: opts.settings.glb })
        .map_err(|e| error("GltfError", &format!("the mesh could not be written as glTF: {e}")))?;
    let mut timings: Vec<(&str, f64)> = vec![("setup", t_ready - t0)];
    timings.extend(rec.timings.iter().copied());
    timings.push(("glb", now() - t));

    let stats = stats_object(&parsed, &opts.settings, &rec, &mesh, &report, &timings);
    set(&stats, "seconds", now() - t0);
    set(&stats, "notices", notices(&parsed, &guess, &opts.settings, &rec, &report));
    set(&stats, "tuning", rec.tuning.as_ref().map_or(JsValue::NULL, |t| tuning_object(t).into()));
    set(&stats, "adapter", engine.gpu.describe());

    let out = Object::new();
    set(&out, "glb", Uint8Array::from(glb.as_slice()));
    set(&out, "positions", Float32Array::from(bytemuck::cast_slice::<[f32; 3], f32>(&mesh.positions)));
    set(&out, "normals", Float32Array::from(bytemuck::cast_slice::<[f32; 3], f32>(&mesh.normals)));
    set(&out, "indices", Uint32Array::from(mesh.indices.as_slice()));
    let colors: Vec<u8> = mesh.colors.as_ref().map(|c| c.iter().flatten().copied().collect()).unwrap_or_default();
    set(&out, "colors", Uint8Array::from(colors.as_slice()));
    let translation: Vec<f64> = translation.map(|t| t.to_vec()).unwrap_or_default();
    set(&out, "translation", js_sys::Float64Array::from(translation.as_slice()));
    set(&out, "stats", stats);
    Ok(out.into())
}

/// The result's `stats`: what was read, the settings that matter, the mesh and the time per
/// stage.
fn stats_object(
    parsed: &crate::io::ScanFile,
    settings: &Settings,
    rec: &Reconstruction,
    mesh: &crate::mesh::Mesh,
    report: &gltf::GlbReport,
    timings: &[(&str, f64)],
) -> Object {
    let stats = Object::new();
    set(&stats, "points", parsed.cloud.len() as f64);
    set(&stats, "method", settings::value_text(settings::by_key("method").expect("in the table").get(settings)));
    set(&stats, "resolution", settings.resolution as f64);
    // The GLB's geometry ("plain", "quantized", "meshopt"): the page writes a trimmed GLB in it.
    set(&stats, "glb", settings::value_text(settings::by_key("glb").expect("in the table").get(settings)));
    set(&stats, "vertices", report.vertices_written as f64);
    set(&stats, "triangles", report.triangles_written as f64);
    set(&stats, "watertight", mesh.is_watertight());
    set(&stats, "bytes", report.bytes as f64);
    set(&stats, "evaluations", rec.extract.refine.evaluations as f64);
    set(&stats, "denseEvaluations", rec.extract.refine.dense_evaluations as f64);
    set(&stats, "components", rec.extract.removal.components as f64);
    set(&stats, "componentsRemoved", rec.extract.removal.components_removed as f64);
    let list = Array::new();
    for (stage, seconds) in timings {
        let o = Object::new();
        set(&o, "stage", *stage);
        set(&o, "seconds", *seconds);
        list.push(&o);
    }
    set(&stats, "timings", list);
    stats
}

/// Everything the user should know about the run, one sentence each: the pipeline's notices,
/// the reader's warnings, a units warning, what the GLB left out.
fn notices(parsed: &crate::io::ScanFile, guess: &crate::units::UnitsGuess, settings: &Settings, rec: &Reconstruction, report: &gltf::GlbReport) -> Array {
    let mut lines: Vec<String> = crate::settings::unused(settings, None).iter().map(|u| format!("Warning: {}", u.page())).collect();
    lines.extend(rec.warnings.iter().map(|w| format!("Warning: {w}")));
    lines.extend(rec.notices.iter().cloned());
    lines.extend(parsed.warnings());
    if settings.units.is_none() && guess.warn {
        lines.push(format!(
            "no units given and {}; the mesh keeps the file's numbers as metres (glTF's unit): choose mm if they are millimetres",
            guess.reason
        ));
    }
    if report.degenerate_triangles_dropped > 0 {
        lines.push(format!("{} degenerate triangles were left out of the GLB", report.degenerate_triangles_dropped));
    }
    lines.iter().map(|n| JsValue::from_str(n)).collect()
}

/// The tuning's summary for the page.
fn tuning_object(t: &crate::field::TuningSummary) -> Object {
    let o = Object::new();
    set(&o, "backend", t.backend);
    set(&o, "n", t.n as f64);
    set(&o, "m", t.m as f64);
    set(&o, "tunedOn", t.tuned_on as f64);
    set(&o, "heldOut", t.held_out as f64);
    set(&o, "initialScore", t.initial_score.map_or(JsValue::NULL, JsValue::from_f64));
    set(&o, "bestScore", t.best_score.map_or(JsValue::NULL, JsValue::from_f64));
    set(&o, "stepsRun", t.steps_run as f64);
    set(&o, "bestStep", t.best_step as f64);
    set(&o, "stop", t.stop.as_str());
    set(&o, "initialLoss", t.initial_loss);
    set(&o, "finalLoss", t.final_loss);
    set(&o, "initialDataFit", t.initial_data_fit);
    set(&o, "bestDataFit", t.best_data_fit);
    o
}

fn pipeline_error(e: PipelineError) -> JsValue {
    match e {
        PipelineError::Cancelled => error("AbortError", "cancelled"),
        PipelineError::Gpu(_) => error("GpuError", &e.to_string()),
        PipelineError::Cloud(_) => error("CloudError", &e.to_string()),
        _ => error("Error", &e.to_string()),
    }
}
