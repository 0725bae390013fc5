//! The network prior against PyTorch: the CPU reference and the GPU kernels on the fixtures
//! exported by `training/export.py` (`tests/fixtures/net_tiny`: odd sizes, random weights;
//! `tests/fixtures/net`: the shipped prior), the GPU against the CPU on a workload larger than
//! one decode chunk, and the safetensors loader against malformed files.
//!
//! Error measures (printed with `--nocapture`):
//! - planes, features: max |got - want| over all elements, divided by max |want| over the
//!   fixture ("relative to the fixture's largest magnitude");
//! - logits: max |got - want| absolute for the trained prior; for `net_tiny`, whose random
//!   weights give logits up to ~2e4 (where one f32 ulp is 2e-3), divided by max |want| as well.

use std::path::PathBuf;
use std::time::Instant;

use nkrr::gpu::Gpu;
use nkrr::net::{cpu, GpuNet, NetError, Planes, Weights, PRIOR};

fn fixture_dir(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

fn read_f32(path: &PathBuf) -> Vec<f32> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(bytes.len() % 4, 0, "{}", path.display());
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}

fn triples(v: &[f32]) -> Vec<[f32; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

struct Fixture {
    name: &'static str,
    weights: Weights,
    cloud: Vec<[f32; 3]>,
    queries: Vec<[f32; 3]>,
    planes: Planes,
    features: Vec<f32>,
    logits: Vec<f32>,
}

fn load(name: &'static str) -> Fixture {
    let dir = fixture_dir(name);
    let weights = if name == "net" {
        Weights::from_safetensors(PRIOR).expect("the built-in prior loads")
    } else {
        let bytes = std::fs::read(dir.join("weights.safetensors")).unwrap();
        Weights::from_safetensors(&bytes).expect("the tiny weights load")
    };
    let cfg = weights.config().clone();
    let cloud = triples(&read_f32(&dir.join("cloud.bin")));
    let queries = triples(&read_f32(&dir.join("queries.bin")));
    let planes = Planes { c_dim: cfg.c_dim, reso: cfg.reso, data: read_f32(&dir.join("planes.bin")) };
    let features = read_f32(&dir.join("features.bin"));
    let logits = read_f32(&dir.join("logits.bin"));
    assert_eq!(planes.data.len(), 3 * cfg.c_dim * cfg.reso * cfg.reso, "{name}: planes.bin size");
    assert_eq!(features.len(), queries.len() * cfg.c_dim, "{name}: features.bin size");
    assert_eq!(logits.len(), queries.len(), "{name}: logits.bin size");
    Fixture { name, weights, cloud, queries, planes, features, logits }
}

fn max_abs(v: &[f32]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs() as f64))
}

fn max_err(got: &[f32], want: &[f32]) -> (f64, usize) {
    assert_eq!(got.len(), want.len());
    let mut worst = (0.0f64, 0usize);
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let e = (*g as f64 - *w as f64).abs();
        assert!(e.is_finite(), "non-finite value at {i}: got {g}, want {w}");
        if e > worst.0 {
            worst = (e, i);
        }
    }
    worst
}

/// Tolerances of one comparison; `logit_abs` is absolute unless `logit_rel` is set.
struct Tol {
    planes_rel: f64,
    features_rel: f64,
    logits: f64,
    logits_relative: bool,
}

const TRAINED: Tol = Tol { planes_rel: 1e-4, features_rel: 1e-4, logits: 1e-3, logits_relative: false };
const TINY: Tol = Tol { planes_rel: 1e-4, features_rel: 1e-4, logits: 1e-5, logits_relative: true };

fn check(what: &str, f: &Fixture, planes: Option<&Planes>, features: &[f32], logits: &[f32], tol: &Tol) {
    if let Some(p) = planes {
        let (e, i) = max_err(&p.data, &f.planes.data);
        let rel = e / max_abs(&f.planes.data);
        eprintln!("{what} [{}] planes: max abs err {e:.3e} (at {i}), relative {rel:.3e}", f.name);
        assert!(rel < tol.planes_rel, "{what} [{}]: planes relative error {rel:.3e} >= {:.0e}", f.name, tol.planes_rel);
    }
    let (e, i) = max_err(features, &f.features);
    let rel = e / max_abs(&f.features);
    eprintln!("{what} [{}] features: max abs err {e:.3e} (at {i}), relative {rel:.3e}", f.name);
    assert!(rel < tol.features_rel, "{what} [{}]: features relative error {rel:.3e}", f.name);
    let (e, i) = max_err(logits, &f.logits);
    let scale = if tol.logits_relative { max_abs(&f.logits) } else { 1.0 };
    eprintln!(
        "{what} [{}] logits: max abs err {e:.3e} (at {i}: got {}, want {}){}",
        f.name,
        logits[i],
        f.logits[i],
        if tol.logits_relative { format!(", relative {:.3e}", e / scale) } else { String::new() }
    );
    assert!(e / scale < tol.logits, "{what} [{}]: logit error {:.3e}", f.name, e / scale);
    // The sign (inside / outside) must agree wherever the fixture is not within the tolerance
    // of the surface.
    for (g, w) in logits.iter().zip(&f.logits) {
        if (*w as f64).abs() > tol.logits * scale {
            assert_eq!(g.is_sign_positive(), w.is_sign_positive(), "{what} [{}]: logit sign flips", f.name);
        }
    }
}

fn gpu() -> Gpu {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir());
    }
    Gpu::new_blocking().unwrap_or_else(|e| {
        panic!("{e}\nInstall Mesa's software Vulkan (scripts/setup.sh apt) to run GPU tests without a GPU.")
    })
}

// ---------------------------------------------------------------------------------------------
// Weights

#[test]
fn weights_load_with_config_from_metadata() {
    let w = Weights::prior().unwrap();
    let c = w.config();
    assert_eq!(
        (c.h, c.c_dim, c.reso, c.unet_depth, c.unet_filters, c.h_dec, c.n_blocks_dec),
        (32, 32, 64, 3, 32, 32, 5)
    );
    assert_eq!(c.padding, 0.1);
    assert_eq!(c.plane_divisor(), 1.1f32);
    assert_eq!(w.names().count(), c.expected_tensors().len());
    assert_eq!(w.shape("unet.up.1.upconv.weight"), Some(&[128usize, 64, 2, 2][..]));
    assert_eq!(w.get("decoder.fc_out.bias").unwrap().len(), 1);
    assert!(w.get("nope").is_none());
    assert!(matches!(w.tensor("nope"), Err(NetError::Tensor { .. })));

    let tiny = Weights::from_safetensors(&std::fs::read(fixture_dir("net_tiny").join("weights.safetensors")).unwrap()).unwrap();
    let c = tiny.config();
    assert_eq!(
        (c.h, c.c_dim, c.reso, c.unet_depth, c.unet_filters, c.h_dec, c.n_blocks_dec),
        (12, 8, 8, 2, 4, 16, 3)
    );
    // "every weight and bias non-zero" (docs/network.md): the loader read real data.
    for name in tiny.names() {
        assert!(tiny.get(name).unwrap().iter().any(|v| *v != 0.0), "{name} is all zero");
    }
}

/// A safetensors writer for building malformed files.
struct St {
    meta: Vec<(String, String)>,
    /// name, dtype, shape, data bytes
    tensors: Vec<(String, String, Vec<usize>, Vec<u8>)>,
}

impl St {
    fn from_weights(w: &Weights) -> St {
        let meta = w.metadata().iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        let tensors = w
            .names()
            .map(|n| {
                let bytes = w.get(n).unwrap().iter().flat_map(|v| v.to_le_bytes()).collect();
                (n.to_string(), "F32".to_string(), w.shape(n).unwrap().to_vec(), bytes)
            })
            .collect();
        St { meta, tensors }
    }

    /// Header entries with honest offsets, optionally rewritten by `edit(name, entry) -> entry`.
    fn bytes_with(&self, edit: &dyn Fn(&str, String) -> String) -> Vec<u8> {
        let meta: Vec<String> = self.meta.iter().map(|(k, v)| format!("\"{k}\":\"{v}\"")).collect();
        let mut entries = vec![format!("\"__metadata__\":{{{}}}", meta.join(","))];
        let mut data = Vec::new();
        for (name, dtype, shape, bytes) in &self.tensors {
            let shape: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
            let entry = format!(
                "{{\"dtype\":\"{dtype}\",\"shape\":[{}],\"data_offsets\":[{},{}]}}",
                shape.join(","),
                data.len(),
                data.len() + bytes.len()
            );
            entries.push(format!("\"{name}\":{}", edit(name, entry)));
            data.extend_from_slice(bytes);
        }
        let mut header = format!("{{{}}}", entries.join(",")).into_bytes();
        while header.len() % 8 != 0 {
            header.push(b' ');
        }
        let mut out = (header.len() as u64).to_le_bytes().to_vec();
        out.extend_from_slice(&header);
        out.extend_from_slice(&data);
        out
    }

    fn bytes(&self) -> Vec<u8> {
        self.bytes_with(&|_, e| e)
    }
}

#[track_caller]
fn expect_err(bytes: &[u8], what: &str, needle: &str) -> NetError {
    match Weights::from_safetensors(bytes) {
        Ok(_) => panic!("{what}: loaded a malformed file"),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.contains(needle), "{what}: error {msg:?} does not mention {needle:?}");
            e
        }
    }
}

#[test]
fn malformed_safetensors_are_errors_not_panics() {
    let good_bytes = std::fs::read(fixture_dir("net_tiny").join("weights.safetensors")).unwrap();
    let good = Weights::from_safetensors(&good_bytes).unwrap();
    let st = St::from_weights(&good);
    assert_eq!(Weights::from_safetensors(&st.bytes()).unwrap(), good, "the writer round-trips");

    // Truncation anywhere: inside the length, the header, or the data.
    let n = u64::from_le_bytes(good_bytes[..8].try_into().unwrap()) as usize;
    let mut cuts: Vec<usize> = (0..8 + n + 16).collect();
    cuts.extend((8 + n + 16..good_bytes.len()).step_by(61));
    cuts.push(good_bytes.len() - 1);
    for cut in cuts {
        assert!(Weights::from_safetensors(&good_bytes[..cut]).is_err(), "truncated to {cut} bytes loaded");
    }
    let e = expect_err(&good_bytes[..good_bytes.len() - 4], "truncated data", "tensor");
    eprintln!("truncated data → {e}");
    expect_err(&good_bytes[..8 + n - 10], "truncated header", "header length");

    // Trailing bytes after the last tensor.
    let mut long = good_bytes.clone();
    long.extend_from_slice(&[0; 4]);
    expect_err(&long, "trailing data", "cover");

    // Header length field absurd / overflowing.
    let mut huge = good_bytes.clone();
    huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    expect_err(&huge, "huge header length", "header length");

    // Not JSON, not an object.
    let raw = |h: &str| {
        let mut b = (h.len() as u64).to_le_bytes().to_vec();
        b.extend_from_slice(h.as_bytes());
        b
    };
    expect_err(&raw("{\"a\": [1, 2"), "bad JSON", "JSON");
    expect_err(&raw("[1, 2]"), "array header", "not an object");

    // Offsets: past the end, reversed, overlapping, not matching the shape, not integers.
    let victim = "unet.final.weight";
    let edit_offsets = |f: &'static dyn Fn(u64, u64) -> String| {
        st.bytes_with(&move |name, e| {
            if name != victim {
                return e;
            }
            let at = e.find("\"data_offsets\":[").unwrap() + 16;
            let nums: Vec<u64> = e[at..e.len() - 2].split(',').map(|s| s.parse().unwrap()).collect();
            format!("{}{}]}}", &e[..at], f(nums[0], nums[1]))
        })
    };
    expect_err(&edit_offsets(&|b, _| format!("{b},99999999")), "offset past the end", victim);
    expect_err(&edit_offsets(&|b, e| format!("{e},{b}")), "reversed offsets", victim);
    expect_err(&edit_offsets(&|b, e| format!("{},{}", b + 4, e + 4)), "shifted offsets", "");
    expect_err(&edit_offsets(&|b, e| format!("{b},{}", e - 4)), "short span", victim);
    expect_err(&edit_offsets(&|b, _| format!("{b},18446744073709551616")), "offset overflows u64", victim);
    expect_err(&edit_offsets(&|b, e| format!("{b}.0,{e}")), "float offset", victim);
    expect_err(&edit_offsets(&|b, e| format!("-{b},{e}")), "negative offset", victim);
    expect_err(&edit_offsets(&|b, _| format!("{b}")), "one offset", victim);
    // Two tensors claiming the same bytes.
    let overlap = st.bytes_with(&|name, e| {
        if name == "unet.final.bias" {
            // final.bias is c_dim = 8 floats; point it at the first 32 bytes of the data.
            e.replace(&e[e.find("\"data_offsets\"").unwrap()..], "\"data_offsets\":[0,32]}")
        } else {
            e
        }
    });
    expect_err(&overlap, "overlapping tensors", "");

    // Wrong dtype.
    let mut f16 = St::from_weights(&good);
    f16.tensors[3].1 = "F16".into();
    let name = f16.tensors[3].0.clone();
    let e = expect_err(&f16.bytes(), "F16 tensor", "only F32");
    assert!(matches!(e, NetError::Tensor { name: ref n, .. } if *n == name));
    let mut f64s = St::from_weights(&good);
    let t = &mut f64s.tensors[0];
    t.1 = "F64".into();
    t.3.extend(t.3.clone()); // the right byte count for F64
    expect_err(&f64s.bytes(), "F64 tensor", "only F32");

    // Missing tensor (header and data both gone), unexpected tensor, wrong shape.
    let mut missing = St::from_weights(&good);
    let gone = missing.tensors.remove(10).0;
    let e = expect_err(&missing.bytes(), "missing tensor", &gone);
    assert!(e.to_string().contains("missing"), "{e}");
    let mut extra = St::from_weights(&good);
    extra.tensors.push(("encoder.blocks.5.fc_0.bias".into(), "F32".into(), vec![1], vec![0; 4]));
    expect_err(&extra.bytes(), "extra tensor", "encoder.blocks.5.fc_0.bias");
    let mut transposed = St::from_weights(&good);
    let i = transposed.tensors.iter().position(|t| t.0 == "encoder.fc_pos.weight").unwrap();
    transposed.tensors[i].2.reverse(); // [24, 3] → [3, 24]: same bytes, wrong shape
    expect_err(&transposed.bytes(), "transposed tensor", "encoder.fc_pos.weight");

    // Metadata: missing, malformed, inconsistent with the tensors, wrong format.
    let with_meta = |k: &str, v: Option<&str>| {
        let mut s = St::from_weights(&good);
        s.meta.retain(|(key, _)| key != k);
        if let Some(v) = v {
            s.meta.push((k.into(), v.into()));
        }
        s.bytes()
    };
    expect_err(&with_meta("reso", None), "no reso", "reso");
    expect_err(&with_meta("h", Some("twelve")), "non-numeric h", "\"h\"");
    expect_err(&with_meta("h", Some("-12")), "negative h", "\"h\"");
    expect_err(&with_meta("h", Some("16")), "h inconsistent with the tensors", "tensor");
    expect_err(&with_meta("reso", Some("9")), "reso not divisible by 2^(D-1)", "divisible");
    expect_err(&with_meta("reso", Some("1000000")), "absurd reso", "reso");
    expect_err(&with_meta("format", Some("convonet-2")), "other format", "format");
    expect_err(&with_meta("padding", Some("nan")), "NaN padding", "padding");
    expect_err(&with_meta("unet_depth", Some("3")), "depth inconsistent with the tensors", "");

    // Random corruption of the header: any result but a panic.
    let mut seed = 0x5eed_u64;
    for _ in 0..2000 {
        let mut b = good_bytes.clone();
        for _ in 0..3 {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let at = 8 + (seed >> 33) as usize % n;
            b[at] = (seed >> 17) as u8;
        }
        let _ = Weights::from_safetensors(&b);
    }
}

// ---------------------------------------------------------------------------------------------
// CPU reference vs PyTorch

fn cpu_parity(name: &'static str, tol: &Tol) {
    let f = load(name);
    let t = Instant::now();
    let planes = cpu::encode(&f.weights, &f.cloud);
    let t_enc = t.elapsed();
    // Decode from the fixture's planes (isolates the decoder) and from ours (end to end).
    let (feat_fx, logit_fx) = cpu::decode(&f.weights, &f.planes, &f.queries);
    check("cpu decode(fixture planes)", &f, None, &feat_fx, &logit_fx, tol);
    let (feat, logit) = cpu::decode(&f.weights, &planes, &f.queries);
    check("cpu encode+decode", &f, Some(&planes), &feat, &logit, tol);
    eprintln!("cpu [{name}] encode of {} points: {:.1} ms", f.cloud.len(), t_enc.as_secs_f64() * 1e3);
}

#[test]
fn cpu_matches_fixture_tiny() {
    cpu_parity("net_tiny", &TINY);
}

#[test]
fn cpu_matches_fixture_trained() {
    cpu_parity("net", &TRAINED);
}

// ---------------------------------------------------------------------------------------------
// GPU vs PyTorch

fn gpu_parity(name: &'static str, tol: &Tol) {
    let f = load(name);
    let gpu = gpu();
    eprintln!("adapter: {}", gpu.describe());
    let mut net = GpuNet::new_blocking(&gpu, &f.weights).unwrap();

    let t = Instant::now();
    let planes_gpu = net.encode_blocking(&f.cloud).unwrap();
    gpu.poll_wait();
    let first = t.elapsed();
    let t = Instant::now();
    let planes_gpu = {
        drop(planes_gpu);
        let p = net.encode_blocking(&f.cloud).unwrap();
        gpu.poll_wait();
        p
    };
    let second = t.elapsed();
    let planes = net.read_planes_blocking(&planes_gpu).unwrap();

    let fixture_planes = net.upload_planes(&f.planes).unwrap();
    let (feat_fx, logit_fx) = net.decode_blocking(&fixture_planes, &f.queries).unwrap();
    check("gpu decode(fixture planes)", &f, None, &feat_fx, &logit_fx, tol);

    let t = Instant::now();
    let (feat, logit) = net.decode_blocking(&planes_gpu, &f.queries).unwrap();
    let dec = t.elapsed();
    check("gpu encode+decode", &f, Some(&planes), &feat, &logit, tol);

    // Ragged chunks give the same answer.
    net.set_chunk_queries(7);
    let (feat7, logit7) = net.decode_blocking(&planes_gpu, &f.queries).unwrap();
    assert_eq!((feat7, logit7), (feat, logit), "chunked decode differs");

    eprintln!(
        "gpu [{name}] encode of {} points: {:.1} ms (first call {:.1} ms); decode of {} queries: {:.1} ms",
        f.cloud.len(),
        second.as_secs_f64() * 1e3,
        first.as_secs_f64() * 1e3,
        f.queries.len(),
        dec.as_secs_f64() * 1e3
    );
}

#[test]
fn gpu_matches_fixture_tiny() {
    gpu_parity("net_tiny", &TINY);
}

#[test]
fn gpu_matches_fixture_trained() {
    gpu_parity("net", &TRAINED);
}

/// More queries than one decode chunk: the GPU agrees with the CPU reference on all of them.
/// The queries are the fixture's, repeated with a per-repeat jitter, so that no two chunks see
/// the same inputs (a chunk offset error cannot hide behind periodic data).
#[test]
fn gpu_decode_beyond_one_chunk_matches_cpu() {
    let f = load("net");
    let gpu = gpu();
    let net = GpuNet::new_blocking(&gpu, &f.weights).unwrap();
    let total = 200_000;
    assert!(net.chunk_queries() < total, "chunk of {} queries does not split {total}", net.chunk_queries());
    let mut seed = 12345u64;
    let mut jitter = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.02
    };
    let queries: Vec<[f32; 3]> =
        (0..total).map(|i| f.queries[i % f.queries.len()].map(|x| x + jitter())).collect();

    let planes = net.upload_planes(&f.planes).unwrap();
    net.decode_blocking(&planes, &f.queries[..64]).unwrap(); // warm up
    let t = Instant::now();
    let (feat, logit) = net.decode_blocking(&planes, &queries).unwrap();
    let gpu_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let (feat_cpu, logit_cpu) = cpu::decode(&f.weights, &f.planes, &queries);
    let cpu_s = t.elapsed().as_secs_f64();

    let (ef, i) = max_err(&feat, &feat_cpu);
    let ef_rel = ef / max_abs(&feat_cpu);
    let (el, j) = max_err(&logit, &logit_cpu);
    eprintln!(
        "gpu vs cpu, {total} queries in chunks of {}: features max abs err {ef:.3e} (at {i}), relative {ef_rel:.3e}; \
         logits max abs err {el:.3e} (at {j})",
        net.chunk_queries()
    );
    eprintln!(
        "decode per 100k queries: gpu {:.0} ms, cpu reference {:.0} ms",
        gpu_s * 1e3 * 1e5 / total as f64,
        cpu_s * 1e3 * 1e5 / total as f64
    );
    assert!(ef_rel < 1e-5, "features differ: {ef_rel:.3e}");
    assert!(el < 2e-4, "logits differ: {el:.3e}");
}

/// Clouds no fixture covers — empty, every point in one cell, and a large random one with
/// crowded cells — encode on the GPU as on the CPU.
#[test]
fn gpu_encode_matches_cpu_on_other_clouds() {
    let w = Weights::prior().unwrap();
    let gpu = gpu();
    let net = GpuNet::new_blocking(&gpu, &w).unwrap();
    let mut seed = 99u64;
    let mut rnd = move || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    };
    let same: Vec<[f32; 3]> = (0..300).map(|_| [0.1, -0.2, 0.3]).collect();
    // Points on a sphere plus outliers outside the padded cube (clamped to the border cells).
    let random: Vec<[f32; 3]> = (0..20_000)
        .map(|i| {
            let v = [rnd(), rnd(), rnd()];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-6);
            if i % 100 == 0 { v.map(|x| x * 3.0) } else { v.map(|x| 0.4 * x / n) }
        })
        .collect();
    for (what, cloud) in [("empty", &[][..]), ("one cell", &same[..]), ("20k random", &random[..])] {
        let want = cpu::encode(&w, cloud);
        let got = net.read_planes_blocking(&net.encode_blocking(cloud).unwrap()).unwrap();
        let (e, i) = max_err(&got.data, &want.data);
        let rel = e / max_abs(&want.data).max(1e-30);
        eprintln!("gpu vs cpu encode, {what} cloud: planes max abs err {e:.3e} (at {i}), relative {rel:.3e}");
        assert!(rel < 1e-5, "{what}: relative error {rel:.3e}");
    }
}
