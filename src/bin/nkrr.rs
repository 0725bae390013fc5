//! The `nkrr` command line: the same library as the web page, run natively through wgpu.

use std::process::ExitCode;

const USAGE: &str = "\
nkrr — surface reconstruction from raw point clouds

USAGE:
    nkrr info CLOUD.ply     point count, bounds, properties found, warnings
    nkrr reconstruct CLOUD.ply -o OUT.glb [OPTIONS]
                            a watertight mesh of the cloud, as glTF binary
        --method nkrr|network      field to mesh (network: the prior alone)  [nkrr]
        --resolution N             marching-cubes resolution (16..=1024)     [128]
        --remove-small F           drop components below F x the largest's triangle count
        --trim [F]                 open the surface where there are no points: drop triangles
                                   farther than F x the mean point spacing from them  [3]
        --no-colors                leave the mesh uncoloured (default: vertex colours from a
                                   coloured cloud, written as COLOR_0)
        --max-points N             subsample larger clouds for the encoder   [100000]
        --m N                      inducing points of the KRR                [500]
        --steps N                  Adam steps of the test-time tuning        [100]
        --lambda X                 ridge parameter of the KRR                [1e-5]
        --label-clip C             clip the network logits used as targets to [-C, C]  [4]
        --no-label-clip            regress the raw logits (the paper's targets)
        --no-tune | --no-theta | --no-z   the paper's ablations
        --euclidean                KRR on Fourier-encoded coordinates, not features (ablation)
        --krr-backend auto|gpu|cpu where the KRR objective runs (auto: CPU f64 on software
                                   adapters, GPU otherwise)                  [auto]
    nkrr bench [--sizes 3000,10000,50000] [--ms 500,1000] [--steps N] [--method nkrr|network]
                            per-stage times on a synthetic noisy torus (adapter printed)
    nkrr gpu                the GPU adapter wgpu finds here and its limits
    nkrr --help | --version
";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("info") => match &args[1..] {
            [path] => info(path),
            _ => Err(usage("info takes exactly one PLY path")),
        },
        Some("reconstruct") => reconstruct(&args[1..]),
        Some("bench") => bench(&args[1..]),
        Some("gpu") => gpu(),
        Some("-h" | "--help" | "help") => {
            print!("{USAGE}");
            Ok(())
        }
        Some("-V" | "--version") => {
            println!("nkrr {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Some(other) => Err(usage(&format!("unknown command '{other}'"))),
        None => Err(usage("no command given")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure { message, code }) => {
            eprintln!("nkrr: {message}");
            ExitCode::from(code)
        }
    }
}

struct Failure {
    message: String,
    code: u8,
}

fn usage(what: &str) -> Failure {
    Failure { message: format!("{what}\n\n{USAGE}"), code: 2 }
}

fn fail(message: String) -> Failure {
    Failure { message, code: 1 }
}

fn info(path: &str) -> Result<(), Failure> {
    let bytes = std::fs::read(path).map_err(|e| fail(format!("cannot read {path}: {e}")))?;
    let parsed = nkrr::io::ply::read_ply(&bytes).map_err(|e| fail(format!("{path}: {e}")))?;
    let cloud = &parsed.cloud;
    println!("file:       {path} ({} bytes)", bytes.len());
    println!("format:     {}", parsed.describe_layout());
    println!("points:     {} (declared {})", cloud.len(), parsed.info.vertex_count);
    if let Some(b) = cloud.bounds() {
        let e = b.extent();
        if cloud.origin != [0.0; 3] {
            let o = cloud.origin;
            println!("origin:     [{}, {}, {}] (far-off coordinates: positions are stored relative to it)", o[0], o[1], o[2]);
            let (lo, hi) = (b.min.map(f64::from), b.max.map(f64::from));
            let (lo, hi) = ([0, 1, 2].map(|a| lo[a] + o[a]), [0, 1, 2].map(|a| hi[a] + o[a]));
            println!("bounds:     [{}, {}, {}] .. [{}, {}, {}]", lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        } else {
            println!("bounds:     [{}, {}, {}] .. [{}, {}, {}]", b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]);
        }
        println!("extent:     {} x {} x {}", e[0], e[1], e[2]);
    }
    let props: Vec<String> =
        parsed.info.vertex_properties.iter().map(|p| format!("{} {}", p.kind, p.name)).collect();
    println!("properties: {}", props.join(", "));
    println!("normals:    {}", if cloud.normals.is_some() { "yes (not needed: nkrr ignores them)" } else { "no (not needed)" });
    println!("colours:    {}", if cloud.colors.is_some() { "yes" } else { "no" });
    for c in &parsed.info.comments {
        println!("comment:    {c}");
    }
    for w in parsed.warnings() {
        println!("warning:    {w}");
    }
    Ok(())
}

fn gpu() -> Result<(), Failure> {
    let gpu = nkrr::gpu::Gpu::new_blocking().map_err(|e| fail(e.to_string()))?;
    println!("{}", gpu.describe());
    Ok(())
}

fn reconstruct(args: &[String]) -> Result<(), Failure> {
    use nkrr::pipeline::{Engine, Settings, Stage};
    let mut settings = Settings::default();
    let mut input = None;
    let mut output = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().cloned().ok_or_else(|| usage(&format!("{name} needs a value")));
        match a.as_str() {
            "-o" | "--output" => output = Some(value(a)?),
            "--method" => settings.method = value(a)?.parse().map_err(|e: String| usage(&e))?,
            "--resolution" => {
                let r: u32 = parse(&value(a)?, a)?;
                if !(16..=1024).contains(&r) {
                    return Err(usage("--resolution must be between 16 and 1024"));
                }
                settings.resolution = r;
            }
            "--remove-small" => {
                let f: f32 = parse(&value(a)?, a)?;
                if !(0.0..=1.0).contains(&f) {
                    return Err(usage("--remove-small must be between 0 and 1"));
                }
                settings.remove_small_components = Some(f);
            }
            "--max-points" => settings.max_points = parse::<usize>(&value(a)?, a)?.max(1),
            "--m" => settings.m = parse::<usize>(&value(a)?, a)?.max(1),
            "--steps" => settings.steps = parse(&value(a)?, a)?,
            "--no-label-clip" => settings.label_clip = None,
            "--label-clip" => {
                let c: f32 = parse(&value(a)?, a)?;
                if !(c > 0.0) {
                    return Err(usage("--label-clip must be > 0"));
                }
                settings.label_clip = Some(c);
            }
            "--lambda" => {
                let l: f64 = parse(&value(a)?, a)?;
                if !(l > 0.0 && l.is_finite()) {
                    return Err(usage("--lambda must be > 0"));
                }
                settings.lambda = l;
            }
            "--no-tune" => settings.steps = 0,
            "--no-theta" => settings.tune_theta = false,
            "--no-z" => settings.tune_z = false,
            "--euclidean" => settings.euclidean = true,
            "--krr-backend" => settings.krr_backend = value(a)?.parse().map_err(|e: String| usage(&e))?,
            "--no-colors" => settings.colors = false,
            "--trim" => {
                // The factor is optional: take the next argument only when it is a number.
                let f = match it.as_slice().first().and_then(|s| s.parse::<f32>().ok()) {
                    Some(f) => {
                        it.next();
                        f
                    }
                    None => nkrr::mesh::trim::DEFAULT_TRIM,
                };
                if !(f > 0.0 && f.is_finite()) {
                    return Err(usage("--trim must be > 0"));
                }
                settings.trim = Some(f);
            }
            s if s.starts_with('-') => return Err(usage(&format!("unknown option '{s}'"))),
            s if input.is_none() => input = Some(s.to_string()),
            s => return Err(usage(&format!("unexpected argument '{s}'"))),
        }
    }
    let input = input.ok_or_else(|| usage("reconstruct needs an input PLY"))?;
    let output = output.ok_or_else(|| usage("reconstruct needs -o OUT.glb"))?;
    if !output.to_ascii_lowercase().ends_with(".glb") {
        return Err(usage("only .glb output is supported so far"));
    }

    let t0 = nkrr::pipeline::now();
    let bytes = std::fs::read(&input).map_err(|e| fail(format!("cannot read {input}: {e}")))?;
    let parsed = nkrr::io::ply::read_ply(&bytes).map_err(|e| fail(format!("{input}: {e}")))?;
    for w in parsed.warnings() {
        eprintln!("warning: {w}");
    }
    eprintln!("read {} points from {input}", parsed.cloud.len());
    let gpu = nkrr::gpu::Gpu::new_blocking().map_err(|e| fail(e.to_string()))?;
    eprintln!("GPU: {}", gpu.info.name);
    let engine = pollster::block_on(Engine::new(gpu)).map_err(|e| fail(e.to_string()))?;
    let mut last = String::new();
    let mut report = |s: &Stage| {
        let line = match s {
            Stage::Features => "computing features".to_string(),
            Stage::Pairs => "sampling and labelling training pairs".to_string(),
            Stage::Tuning { step, of, loss } => format!("tuning: step {step}/{of}, loss {loss:.6}"),
            Stage::Meshing { evaluated } => format!("meshing: {evaluated} field evaluations"),
            Stage::Done => "done".to_string(),
        };
        if line != last {
            eprintln!("{line}");
            last = line;
        }
        true
    };
    let rec = pollster::block_on(engine.reconstruct(&parsed.cloud, &settings, &mut report))
        .map_err(|e| fail(format!("{input}: {e}")))?;
    if let Some(t) = &rec.tuning {
        eprintln!(
            "tuning ({}): n {} m {}, {} steps ({}), loss {:.5} -> {:.5}, training error {:.3e} -> {:.3e} (best at step {})",
            t.backend, t.n, t.m, t.steps_run, t.stop, t.initial_loss, t.final_loss, t.initial_data_fit, t.best_data_fit, t.best_step
        );
        if let Some(p) = &t.phases {
            eprintln!("tuning phases over {} evaluations: {}", t.evaluations, p.summary());
        }
    }
    for n in &rec.notices {
        eprintln!("notice: {n}");
    }
    let name = std::path::Path::new(&input).file_stem().map(|s| s.to_string_lossy().into_owned());
    let (glb, glb_report) = nkrr::io::gltf::write_glb_with_report(&rec.mesh, &nkrr::io::gltf::GlbOptions { name, translation: rec.translation() })
        .map_err(|e| fail(format!("writing {output}: {e}")))?;
    std::fs::write(&output, &glb).map_err(|e| fail(format!("cannot write {output}: {e}")))?;
    let times: Vec<String> = rec.timings.iter().map(|(s, t)| format!("{s} {t:.2}s")).collect();
    println!(
        "{output}: {} vertices, {} triangles, watertight: {}; {} (total {:.2}s); {} field evaluations",
        glb_report.vertices_written,
        glb_report.triangles_written,
        if rec.mesh.is_watertight() { "yes" } else { "no" },
        times.join(", "),
        nkrr::pipeline::now() - t0,
        rec.extract.refine.evaluations,
    );
    Ok(())
}

fn parse<T: std::str::FromStr>(s: &str, name: &str) -> Result<T, Failure> {
    s.parse().map_err(|_| usage(&format!("{name}: '{s}' is not a valid value")))
}

/// A torus (R = 0.3, r = 0.12) sampled uniformly by area, with Gaussian noise: a closed genus-1
/// shape of known size for benchmarks that must not depend on data files.
fn synthetic_torus(n: usize, noise: f64, seed: u64) -> nkrr::PointCloud {
    use std::f64::consts::TAU;
    let (big, small) = (0.3, 0.12);
    let mut rng = nkrr::rng::SplitMix64(seed);
    let mut positions = Vec::with_capacity(n);
    while positions.len() < n {
        let (u, v) = (TAU * rng.unit(), TAU * rng.unit());
        // Area element ∝ (R + r cos v): accept with that weight.
        if rng.unit() * (big + small) > big + small * v.cos() {
            continue;
        }
        let ring = big + small * v.cos();
        let p = [ring * u.cos(), small * v.sin(), ring * u.sin()];
        positions.push(p.map(|x| (x + noise * rng.normal()) as f32));
    }
    nkrr::PointCloud { positions, ..Default::default() }
}

fn list(s: &str, name: &str) -> Result<Vec<usize>, Failure> {
    s.split(',').map(|x| parse::<usize>(x.trim(), name)).collect()
}

fn bench(args: &[String]) -> Result<(), Failure> {
    use nkrr::pipeline::{Engine, Method, Settings};
    let mut sizes = vec![3000, 10000, 50000];
    let mut ms = vec![500, 1000];
    let mut settings = Settings { method: Method::Nkrr, steps: 10, ..Settings::default() };
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().cloned().ok_or_else(|| usage(&format!("{name} needs a value")));
        match a.as_str() {
            "--sizes" => sizes = list(&value(a)?, a)?,
            "--ms" => ms = list(&value(a)?, a)?,
            "--steps" => settings.steps = parse(&value(a)?, a)?,
            "--method" => settings.method = value(a)?.parse().map_err(|e: String| usage(&e))?,
            "--resolution" => settings.resolution = parse(&value(a)?, a)?,
            "--krr-backend" => settings.krr_backend = value(a)?.parse().map_err(|e: String| usage(&e))?,
            s => return Err(usage(&format!("unknown bench option '{s}'"))),
        }
    }
    let gpu = nkrr::gpu::Gpu::new_blocking().map_err(|e| fail(e.to_string()))?;
    println!("adapter: {}", gpu.describe());
    let engine = pollster::block_on(Engine::new(gpu)).map_err(|e| fail(e.to_string()))?;
    if settings.method == Method::Network {
        ms = vec![0];
    }
    println!("method {:?}, {} Adam steps, resolution {}", settings.method, settings.steps, settings.resolution);
    println!("Per objective evaluation (ms): kernel = K_nm blocks + A = K_nm^T K_nm on the GPU; solve = the f64 m x m");
    println!("algebra on the CPU (Cholesky solves, traces, W, G_mm); gradient = residual + G_nm o K_nm pass + reductions");
    println!("on the GPU; readback = device-to-host copies. mesh = field evaluations + marching cubes.");
    println!("| points | m | features s | pairs s | tuning s | evals | s/eval | kernel ms | solve ms | gradient ms | readback ms | mesh s | total s | field evals |");
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for &n in &sizes {
        let cloud = synthetic_torus(n, 0.005, n as u64);
        for &m in &ms {
            let s = Settings { m: m.max(1), ..settings.clone() };
            let t0 = nkrr::pipeline::now();
            let rec = pollster::block_on(engine.reconstruct(&cloud, &s, &mut |_| true))
                .map_err(|e| fail(format!("{n} points, m {m}: {e}")))?;
            let total = nkrr::pipeline::now() - t0;
            let t = |stage: &str| rec.timings.iter().find(|(k, _)| *k == stage).map_or(0.0, |(_, v)| *v);
            let evals = rec.tuning.as_ref().map_or(0, |x| x.evaluations);
            let per_eval = if evals > 0 { t("tuning") / evals as f64 } else { 0.0 };
            let ph = rec.tuning.as_ref().and_then(|x| x.phases);
            let ms = |f: fn(&nkrr::krr::PhaseTimings) -> f64| match ph {
                Some(p) if evals > 0 => format!("{:.1}", f(&p) * 1e3 / evals as f64),
                _ => "-".into(),
            };
            println!(
                "| {n} | {m} | {:.2} | {:.2} | {:.2} | {evals} | {:.3} | {} | {} | {} | {} | {:.2} | {:.2} | {} |",
                t("features"), t("pairs"), t("tuning"), per_eval,
                ms(|p| p.kernel + p.gram), ms(|p| p.cpu_algebra), ms(|p| p.grad_pass), ms(|p| p.readback),
                t("mesh"), total, rec.extract.refine.evaluations
            );
        }
    }
    Ok(())
}
