//! What the page calls on its own thread: the settings table for its form and share links, the
//! memory preflight, mesh files for downloads and the live trim, and the tuning-step benchmark.
//! The reconstruction itself runs in the worker ([`super::worker_api`]).

use js_sys::{Array, Object};
use wasm_bindgen::prelude::*;

use super::js::set;
use super::options::{error, Options};
use crate::io::mesh_out::{self, MeshFormat};
use crate::settings::{self, Kind, Settings, Value};

/// A mesh file written on the page from the arrays `reconstruct` resolves to (`positions`,
/// `normals`: xyz per vertex; `colors`: RGBA per vertex or empty; `indices`: three per
/// triangle, possibly a subset after trimming), so downloads match what the view shows.
/// `format` is "glb", "ply", "obj" or "stl"; vertices no triangle uses are left out;
/// `translation` (empty or xyz) is the GLB root translation of far-off clouds (the other
/// formats add it to their f32 positions); `glb` is the GLB geometry ("plain", "quantized" or
/// "meshopt": the `glb` setting's values).
#[wasm_bindgen]
pub fn mesh_file(
    format: &str,
    positions: &[f32],
    normals: &[f32],
    colors: &[u8],
    indices: &[u32],
    name: &str,
    translation: &[f64],
    glb: &str,
) -> Result<Vec<u8>, JsError> {
    let n = positions.len() / 3;
    if positions.len() % 3 != 0 || normals.len() != positions.len() || !(colors.is_empty() || colors.len() == 4 * n) {
        return Err(JsError::new("mesh_file: positions and normals need 3 floats per vertex, colours 4 bytes"));
    }
    let triples = |v: &[f32]| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    let mut mesh = crate::mesh::Mesh {
        positions: triples(positions),
        normals: triples(normals),
        colors: (!colors.is_empty()).then(|| colors.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect()),
        indices: indices.to_vec(),
    };
    if mesh.indices.len() % 3 != 0 || mesh.indices.iter().any(|&i| i as usize >= n) {
        return Err(JsError::new("mesh_file: indices must be triples of vertex indices in range"));
    }
    let keep = vec![true; mesh.indices.len() / 3];
    crate::mesh::trim::retain_triangles(&mut mesh, &keep);
    let translation: Option<[f64; 3]> = (translation.len() == 3).then(|| [translation[0], translation[1], translation[2]]);
    let format = MeshFormat::from_extension(format)
        .ok_or_else(|| JsError::new(&format!("mesh_file: unknown format '{format}' (glb, ply, obj or stl)")))?;
    let mut settings = Settings::default();
    let glb_setting = settings::by_key("glb").expect("in the table");
    glb_setting
        .parse(glb)
        .and_then(|v| glb_setting.set(&mut settings, v))
        .map_err(|e| JsError::new(&format!("mesh_file: {e}")))?;
    mesh_out::write(format, &mesh, Some(name.to_string()), translation, &format!("nkrr reconstruction of {name}"), settings.glb)
        .map(|w| w.bytes)
        .map_err(|e| JsError::new(&format!("mesh_file ({format:?}): {e}")))
}

/// Milliseconds of the CPU's share of one tuning step with `m` inducing points and 32 features
/// (median of `reps`), in this build: what a real GPU leaves to the worker's thread at every
/// step (see `krr::mm::algebra_step_seconds`). For the benchmark in tests/browser.
#[wasm_bindgen]
pub fn tuning_step_ms(m: usize, reps: usize) -> Result<f64, JsError> {
    // m within the settings table's range, refused outside it (not quietly clamped).
    let def = crate::settings::by_key("m").expect("the table has m");
    def.check(Value::Num(m as f64)).map_err(|e| JsError::new(&format!("tuning_step_ms: {e}")))?;
    Ok(1e3 * crate::krr::mm::algebra_step_seconds(m, 32, reps))
}

/// The triangles of a mesh (given as `reconstruct`'s arrays) that lie within `factor` × the
/// point spacing of `points` (the mean, wider where they are sparser) (xyz, the cloud or an even subsample of it), as indices into
/// the same vertices: the page's live trim, without re-running the reconstruction (the
/// pipeline's `trim` option does the same on the points the network saw).
#[wasm_bindgen]
pub fn trim_indices(points: &[f32], positions: &[f32], indices: &[u32], factor: f32) -> Vec<u32> {
    let triples = |v: &[f32]| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
    match crate::mesh::trim::near_triangles(&triples(positions), indices, &triples(points), factor).keep {
        None => indices.to_vec(),
        Some(keep) => indices.chunks_exact(3).zip(keep).filter(|(_, k)| *k).flat_map(|(t, _)| t).copied().collect(),
    }
}

/// Every setting the options of [`reconstruct`] and [`preflight`] take, for the page's form and
/// share links (`web/settings.js`), in display order: `{ key, flag, label, help, kind ("int" |
/// "float" | "choice" | "switch"), min?, max?, choices? [{value, label}], presets [{value,
/// label}], default (null: off), canBeOff, nkrrOnly, advanced }`. From [`crate::settings::TABLE`].
#[wasm_bindgen]
pub fn settings_table() -> Array {
    let js = |v: Value| -> JsValue {
        match v {
            Value::Off => JsValue::NULL,
            Value::Bool(b) => b.into(),
            Value::Num(x) => x.into(),
            Value::Choice(c) => c.into(),
        }
    };
    let pairs = |items: Vec<(JsValue, &str)>| -> Array {
        items
            .into_iter()
            .map(|(value, label)| {
                let o = Object::new();
                set(&o, "value", value);
                set(&o, "label", label);
                JsValue::from(o)
            })
            .collect()
    };
    settings::TABLE
        .iter()
        .map(|def| {
            let o = Object::new();
            set(&o, "key", def.key);
            set(&o, "flag", def.flag);
            set(&o, "label", def.label);
            set(&o, "help", def.help);
            let kind = match def.kind {
                Kind::Int { min, max } | Kind::Float { min, max } => {
                    set(&o, "min", min);
                    set(&o, "max", max);
                    if matches!(def.kind, Kind::Int { .. }) { "int" } else { "float" }
                }
                Kind::Choice(choices) => {
                    set(&o, "choices", pairs(choices.iter().map(|(v, l)| (JsValue::from_str(v), *l)).collect()));
                    "choice"
                }
                Kind::Switch => "switch",
            };
            set(&o, "kind", kind);
            set(&o, "presets", pairs(def.presets.iter().map(|(v, l)| (JsValue::from_f64(*v), *l)).collect()));
            set(&o, "default", js(def.default));
            set(&o, "canBeOff", def.can_be_off);
            set(&o, "nkrrOnly", def.nkrr_only);
            set(&o, "advanced", def.advanced);
            JsValue::from(o)
        })
        .collect()
}

/// The preflight for a cloud of `points` points (`colours`: whether it has colours)
/// reconstructed with `options` (as for [`reconstruct`]) on an adapter whose largest buffer
/// binding is `binding` bytes (`software`: a CPU adapter such as SwiftShader; the page takes
/// both from [`super::Viewer::adapter_facts`], whose adapter the worker shares): one line per
/// stage with its GPU and host memory, the limits, and what will be changed to fit. The
/// reconstruction applies the same plan.
///
/// `sample` (optional): an even sample of the cloud's positions, xyz flat, and `units` /
/// `stated` what the file says of its units (the cloud's `units_guess`): with them a scene is
/// planned as the worker will cut it, and the stages are those of its largest tile.
#[wasm_bindgen]
pub fn preflight(
    points: usize,
    colours: bool,
    options: JsValue,
    binding: f64,
    software: bool,
    sample: Option<Vec<f32>>,
    units: Option<String>,
    stated: bool,
) -> Result<Vec<String>, JsValue> {
    let opts = Options::from_js(&options)?;
    let config = crate::net::NetConfig::prior().map_err(|e| error("NetError", &e.to_string()))?;
    let facts = crate::plan::DeviceFacts {
        binding: binding.max(0.0) as u64,
        software,
        host_budget: Some(crate::plan::WASM_HOST_BUDGET),
    };
    let sample: Vec<[f32; 3]> = sample.unwrap_or_default().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let scale = crate::scene::Scale { units: units.and_then(|u| u.parse().ok()), stated };
    let weight = points as f64 / sample.len().max(1) as f64;
    match crate::scene::decide_sample(&sample, weight, &opts.settings, scale) {
        Some(tiles) => {
            let largest = tiles.largest_tile(&sample, weight);
            let mut lines = vec![
                format!("scene     will {}", tiles.reason),
                format!("per tile  one tile at a time, the largest taking in about {largest} points with its overlap:"),
            ];
            lines.extend(crate::plan::memory_plan(largest, colours, &crate::scene::tile_settings(&opts.settings), &config, &facts).lines());
            Ok(lines)
        }
        None => Ok(crate::plan::memory_plan(points, colours, &opts.settings, &config, &facts).lines()),
    }
}

/// Reads `text` as a value of setting `key` by the settings table's one rule
/// ([`crate::settings::Setting::parse`], the CLI's too): the page's share links and form come
/// here, so they take the same text and give the same wording. Returns the value as the page
/// holds it (a number, a boolean, a choice's string, `""` for an empty choice, null for off) or
/// throws a RangeError whose message names the setting and its range.
#[wasm_bindgen]
pub fn parse_setting(key: &str, text: &str) -> Result<JsValue, JsValue> {
    let def = settings::by_key(key).ok_or_else(|| error("RangeError", &format!("{key} is not a setting")))?;
    let v = def.parse(text).map_err(|e| error("RangeError", &e))?;
    Ok(match (v, def.kind) {
        (Value::Off, Kind::Choice(_)) => JsValue::from_str(""),
        (Value::Off, _) => JsValue::NULL,
        (Value::Bool(b), _) => JsValue::from_bool(b),
        (Value::Num(x), _) => JsValue::from_f64(x),
        (Value::Choice(c), _) => JsValue::from_str(c),
    })
}

