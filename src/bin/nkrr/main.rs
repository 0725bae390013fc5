//! The `nkrr` command line: the same library as the web page, run natively through wgpu.

use std::process::ExitCode;

use nkrr::settings::{Method, Settings};

use args::Parsed;

mod args;

/// `s` with control characters shown escaped (`\x1b`, `\u{9b}`), except newline and tab:
/// names, comments and messages that come from a file reach a terminal, and a raw ESC or BEL
/// there can clear it, set its title or fake output. Every line the CLI prints goes through it.
fn shown(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c as u32 {
            0x0a | 0x09 => out.push(c),
            n @ (0..=0x1f | 0x7f) => out.push_str(&format!("\\x{n:02x}")),
            n @ 0x80..=0x9f => out.push_str(&format!("\\u{{{n:x}}}")),
            _ => out.push(c),
        }
    }
    out
}

/// `println!` through [`shown`].
macro_rules! say {
    ($($t:tt)*) => { println!("{}", shown(&format!($($t)*))) };
}

/// `eprintln!` through [`shown`].
macro_rules! tell {
    ($($t:tt)*) => { eprintln!("{}", shown(&format!($($t)*))) };
}

/// At most this many of a file's header comments are listed by `info`; the rest are counted.
const COMMENTS_SHOWN: usize = 10;
/// A listed comment or property list is cut after this many characters.
const LINE_CHARS: usize = 300;

/// `s` cut to [`LINE_CHARS`] characters, saying how many were left out.
fn bounded(s: &str) -> String {
    match s.char_indices().nth(LINE_CHARS) {
        None => s.to_string(),
        Some((i, _)) => format!("{}… ({} more characters)", &s[..i], s[i..].chars().count()),
    }
}

fn main() -> ExitCode {
    // A file-size limit (`ulimit -f`) kills with SIGXFSZ by default, mid-write and without a
    // word; ignored, the write fails with EFBIG, which is reported like a full disk.
    #[cfg(unix)]
    // SAFETY: setting a standard signal's disposition to "ignore" before any thread starts.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    let runtime_dir = private_runtime_dir();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("info") => info(&args[1..]),
        Some("reconstruct") => reconstruct(&args[1..]),
        Some("bench") => bench(&args[1..]),
        Some("metrics") => metrics(&args[1..]),
        Some("eval") => eval(&args[1..]),
        Some("gpu") => gpu(),
        Some("-h" | "--help" | "help") => {
            print!("{}", args::usage());
            Ok(())
        }
        Some("-V" | "--version") => {
            say!("nkrr {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Some(other) => Err(usage(&format!("unknown command '{other}'"))),
        None => Err(usage("no command given")),
    };
    if let Some(d) = runtime_dir {
        let _ = std::fs::remove_dir(d);
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure { message, code }) => {
            tell!("nkrr: {message}");
            ExitCode::from(code)
        }
    }
}

/// Where `XDG_RUNTIME_DIR` is unset (root in a container, CI), points it at a new, empty,
/// private folder (removed at the end of `main`), and returns that folder.
///
/// Why: Mesa's Vulkan device-selection layer (`VK_LAYER_MESA_device_select`, an implicit layer
/// loaded into every Vulkan instance) probes for a Wayland compositor while wgpu enumerates
/// adapters, and libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set in the
/// environment." twice to stderr when the variable is unset, before a run that then succeeds.
/// With the variable set, the probe finds no socket in the empty folder and stays silent; the
/// layer and the adapter choice are otherwise unchanged (disabling the layer with
/// `NODEVICE_SELECT` would also drop a user's `MESA_VK_DEVICE_SELECT`). Set before any thread
/// starts, as changing the environment requires.
fn private_runtime_dir() -> Option<std::path::PathBuf> {
    if std::env::var_os("XDG_RUNTIME_DIR").is_some() {
        return None;
    }
    let dir = std::env::temp_dir().join(format!("nkrr-runtime-{}", std::process::id()));
    let mut builder = std::fs::DirBuilder::new();
    #[cfg(unix)]
    std::os::unix::fs::DirBuilderExt::mode(&mut builder, 0o700);
    builder.create(&dir).ok()?;
    std::env::set_var("XDG_RUNTIME_DIR", &dir);
    Some(dir)
}

struct Failure {
    message: String,
    code: u8,
}

fn usage(what: &str) -> Failure {
    Failure { message: format!("{what}\n\n{}", args::usage()), code: 2 }
}

fn fail(message: String) -> Failure {
    Failure { message, code: 1 }
}

fn read_scan(path: &str) -> Result<(Vec<u8>, nkrr::io::ScanFile), Failure> {
    let bytes = std::fs::read(path).map_err(|e| fail(format!("cannot read {path}: {e}")))?;
    let scan = nkrr::io::read_cloud(&bytes, Some(path)).map_err(|e| fail(format!("{path}: {e}")))?;
    Ok((bytes, scan))
}

fn info(args: &[String]) -> Result<(), Failure> {
    let p = parsed("info", args, Settings::default())?;
    let path = one_operand(&p, "info needs a cloud file")?;
    let settings = p.settings;
    let (bytes, scan) = read_scan(&path)?;
    let cloud = &scan.cloud;
    // Once: the guess sorts a sample of the cloud (the points lying apart left out).
    let guess = scan.units_guess();
    say!("file:       {path} ({} bytes)", bytes.len());
    say!("format:     {}", scan.layout);
    say!("points:     {} (in the file: {})", cloud.len(), scan.declared);
    if let Some(b) = cloud.bounds() {
        let e = b.extent();
        if cloud.origin != [0.0; 3] {
            let o = cloud.origin;
            say!("origin:     [{}, {}, {}] (far-off coordinates: positions are stored relative to it)", o[0], o[1], o[2]);
            let (lo, hi) = (b.min.map(f64::from), b.max.map(f64::from));
            let (lo, hi) = ([0, 1, 2].map(|a| lo[a] + o[a]), [0, 1, 2].map(|a| hi[a] + o[a]));
            say!("bounds:     [{}, {}, {}] .. [{}, {}, {}]", lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
        } else {
            say!("bounds:     [{}, {}, {}] .. [{}, {}, {}]", b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]);
        }
        say!("extent:     {} x {} x {}", e[0], e[1], e[2]);
        let g = &guess;
        let given = settings.units.map(|u| format!("{u} (given)"));
        say!(
            "units:      {}: {}",
            given.unwrap_or_else(|| match (scan.stated_units, g.units) {
                (Some(u), _) => u.to_string(),
                (None, Some(u)) => format!("{u}? (a guess: --units sets them)"),
                (None, None) => "unknown (--units sets them)".to_string(),
            }),
            g.reason
        );
    }
    if let Some(ply) = &scan.ply {
        let props: Vec<String> = ply.vertex_properties.iter().map(|p| format!("{} {}", p.kind, p.name)).collect();
        say!("properties: {}", bounded(&props.join(", ")));
    }
    let zeros = scan.zero_normals();
    say!(
        "normals:    {}",
        match (&cloud.normals, zeros) {
            (None, _) => "no (not needed: nkrr needs no normals, oriented or not)".to_string(),
            (Some(_), 0) => "yes (not needed: nkrr ignores them)".to_string(),
            (Some(_), z) => format!("yes, {z} of them zero (not needed: nkrr ignores them)"),
        }
    );
    say!("colours:    {}", if cloud.colors.is_some() { "yes (carried to the mesh's vertices)" } else { "no" });
    for c in scan.comments.iter().take(COMMENTS_SHOWN) {
        say!("comment:    {}", bounded(c));
    }
    if scan.comments.len() > COMMENTS_SHOWN {
        say!("comment:    … and {} more comments", scan.comments.len() - COMMENTS_SHOWN);
    }
    let scale = nkrr::scene::Scale::from(&guess);
    match nkrr::scene::decide(cloud, &settings, scale) {
        // A scene runs tile by tile, each tile as one small cloud: the memory is the largest
        // tile's, under what a tile runs (the page's preflight says the same).
        Some(tiles) => {
            let largest = tiles.largest_tile(&cloud.positions, 1.0);
            say!("scene:      will {}; one tile at a time, the largest taking in {largest} points (with its overlap):", tiles.reason);
            preflight(largest, false, &nkrr::scene::tile_settings(&settings));
        }
        None => {
            if let Some(h) = nkrr::scene::hint(cloud, &settings, scale) {
                say!("scene:      {h}");
            }
            preflight(cloud.len(), cloud.colors.is_some(), &settings)
        }
    }
    for w in scan.warnings() {
        say!("warning:    {w}");
    }
    Ok(())
}

/// The memory each stage will need on this machine's adapter, and what happens where it does
/// not fit.
fn preflight(points: usize, colours: bool, settings: &Settings) {
    let (limits, adapter) = match nkrr::gpu::Gpu::new_blocking() {
        Ok(gpu) => (nkrr::plan::DeviceFacts::of(&gpu), gpu.info.name.clone()),
        Err(e) => (nkrr::plan::DeviceFacts::webgpu_default(), format!("none ({e}); WebGPU's default limits assumed")),
    };
    say!("adapter:    {adapter}");
    let config = match nkrr::net::NetConfig::prior() {
        Ok(c) => c,
        Err(e) => return say!("memory:     no estimate: the built-in prior does not load ({e})"),
    };
    let plan = nkrr::plan::memory_plan(points, colours, settings, &config, &limits);
    for line in plan.lines() {
        say!("memory:     {line}");
    }
}

/// A prior for `--weights`, read and checked before any other work.
fn read_weights(path: &str) -> Result<nkrr::net::Weights, Failure> {
    let bytes = std::fs::read(path).map_err(|e| fail(format!("--weights {path}: cannot read it: {e}")))?;
    nkrr::net::Weights::from_safetensors(&bytes)
        .map_err(|e| fail(format!("--weights {path}: not a network prior nkrr can use: {e}")))
}

/// The engine with `weights` (`--weights`), or with the built-in prior.
fn engine(gpu: nkrr::gpu::Gpu, weights: Option<nkrr::net::Weights>) -> Result<nkrr::pipeline::Engine, Failure> {
    use nkrr::pipeline::Engine;
    let engine = match weights {
        Some(w) => pollster::block_on(Engine::with_weights(gpu, &w)),
        None => pollster::block_on(Engine::new(gpu)),
    };
    engine.map_err(|e| fail(e.to_string()))
}

fn gpu() -> Result<(), Failure> {
    let gpu = nkrr::gpu::Gpu::new_blocking().map_err(|e| fail(e.to_string()))?;
    say!("{}", gpu.describe());
    Ok(())
}

fn reconstruct(args: &[String]) -> Result<(), Failure> {
    use nkrr::pipeline::Stage;
    let p = parsed("reconstruct", args, Settings::default())?;
    let input = one_operand(&p, "reconstruct needs an input cloud")?;
    let weights = p.value("--weights").map(read_weights).transpose()?;
    let output = p.value("-o").ok_or_else(|| usage("reconstruct needs -o OUT.glb"))?.to_string();
    let settings = p.settings;
    use nkrr::io::mesh_out::{self, MeshFormat};
    let format = MeshFormat::from_path(&output)
        .ok_or_else(|| usage(&format!("-o {output}: the extension must be .glb, .ply, .obj or .stl")))?;
    // Before any work: a bad output path found after minutes of reconstruction wastes them,
    // and an output that is the input (by any path or link) would replace the user's cloud.
    let out_path = std::path::Path::new(&output);
    nkrr::io::atomic::check_not_input(out_path, &[std::path::Path::new(&input)]).map_err(|e| fail(format!("-o {e}")))?;
    nkrr::io::atomic::check_output(out_path).map_err(|e| fail(format!("-o {output}: {e}")))?;

    // Settings the run will not use are said before any work (nkrr::settings::unused).
    for u in nkrr::settings::unused(&settings, Some(format)) {
        tell!("warning: {}", u.cli());
    }

    let t0 = nkrr::gpu::now();
    let (bytes, parsed) = read_scan(&input)?;
    drop(bytes);
    for w in parsed.warnings() {
        tell!("warning: {w}");
    }
    tell!("read {} points from {input} ({})", parsed.cloud.len(), parsed.layout);
    // Once: the guess sorts a sample of the cloud (the points lying apart left out).
    let guess = parsed.units_guess();
    if settings.units.is_none() {
        let g = &guess;
        if g.warn {
            tell!("warning: no --units given and {}; the mesh keeps the file's numbers as metres (glTF's unit): pass --units mm if they are millimetres", g.reason);
        }
    }
    let gpu = nkrr::gpu::Gpu::new_blocking().map_err(|e| fail(e.to_string()))?;
    tell!("GPU: {}", gpu.info.name);
    let engine = engine(gpu, weights)?;
    let mut last = String::new();
    // When each stage with steps of about equal cost (tiles, tuning steps) began: the time left.
    let mut started: std::collections::HashMap<&str, std::time::Instant> = std::collections::HashMap::new();
    // The estimate is made when `done` moves and kept until it moves again: a stage may report
    // the same step again (a scene's tile while its regression tunes, to be cancellable), and
    // the estimate must not creep up meanwhile.
    let mut said: std::collections::HashMap<&str, (usize, String)> = std::collections::HashMap::new();
    let mut left = move |stage: &'static str, done: usize, of: usize| -> String {
        let t = started.entry(stage).or_insert_with(std::time::Instant::now).elapsed().as_secs_f64();
        if let Some((_, text)) = said.get(stage).filter(|(d, _)| *d == done) {
            return text.clone();
        }
        let text = if done > 0 && done < of && t > 1.0 { format!(", about {} left", minutes(t / done as f64 * (of - done) as f64)) } else { String::new() };
        said.insert(stage, (done, text.clone()));
        text
    };
    let mut report = |s: &Stage| {
        let line = match s {
            Stage::Features => "computing features".to_string(),
            Stage::Pairs => "sampling and labelling training pairs".to_string(),
            Stage::Tuning { step, of, loss } => format!("tuning: step {step}/{of}, loss {loss:.6}{}", left("tuning", *step, *of)),
            Stage::Surface => "solving the Poisson surface (normals signed by the field's mesh)".to_string(),
            Stage::Meshing { evaluated, expected } if evaluated <= expected => format!("meshing: {evaluated} field evaluations (of about {expected})"),
            // The count is a typical surface's; a thin or intricate one takes more.
            Stage::Meshing { evaluated, expected } => format!("meshing: {evaluated} field evaluations (more than the usual {expected}: an intricate surface)"),
            Stage::Tile { done, of } => format!("tiles: {done} of {of}{}", left("tiles", *done, *of)),
            // Pieces of a scene's mesh are for viewers to show; the tile count says enough here.
            Stage::Meshed { .. } => return true,
            Stage::Prior => "meshing the network's own field, to compare with the tuned field's".to_string(),
            Stage::Done => "done".to_string(),
        };
        if line != last {
            tell!("{line}");
            last = line;
        }
        true
    };
    let scale = nkrr::scene::Scale::from(&guess);
    let rec = pollster::block_on(nkrr::scene::reconstruct_auto(&engine, &parsed.cloud, &settings, scale, &mut report))
        .map_err(|e| fail(format!("{input}: {e}")))?;
    if let Some(t) = &rec.tuning {
        tell!(
            "tuning ({}): tuned on {} of {} pairs, m {}, {} steps ({}), loss {:.5} -> {:.5}, training error {:.3e} -> {:.3e}{} (kept step {}, {})",
            t.backend, t.tuned_on, t.n, t.m, t.steps_run, t.stop, t.initial_loss, t.final_loss, t.initial_data_fit, t.best_data_fit,
            match (t.initial_score, t.best_score) {
                (Some(a), Some(b)) => format!(", held-out error {a:.3e} -> {b:.3e}"),
                _ => String::new(),
            },
            t.best_step,
            if t.held_out > 0 { format!("lowest error on {} held-out pairs", t.held_out) } else { "lowest training error".to_string() }
        );
        if let Some(p) = &t.phases {
            tell!("tuning phases over {} evaluations: {}", t.evaluations, p.summary());
        }
    }
    if let Some(f) = &rec.fit {
        tell!(
            "fit to the points: {} vertices moved (mean {:.2} spacings){}{}{}, {} left alone; {} triangles turned over, {} after the repair{}{}",
            f.moved,
            f.mean_shift,
            if f.sparse > 0 { format!(", {} of them where the points are sparser than the cloud's mean", f.sparse) } else { String::new() },
            match (f.fewer, f.more) {
                (0, 0) => String::new(),
                (fewer, more) => format!(
                    "; planes of {} points (fewer at {fewer} vertices, where the points are over twice sparser than the cloud's mean; more at {more}, where over twice denser)",
                    f.neighbours
                ),
            },
            if f.other_side > 0 { format!("; {} vertices' planes without the points of a thin part's other side", f.other_side) } else { String::new() },
            f.kept,
            f.flipped,
            f.flipped_after_repair,
            match f.tangents {
                Some(w) if w > 0.0 => format!("; each plane moved up to {w:.2} of the way to the neighbours' tangent planes"),
                Some(_) => "; planes alone (the cloud is noisier than a clean scan)".to_string(),
                None => String::new(),
            },
            match (f.low_pass, f.average) {
                (0, _) => String::new(),
                (pairs, nkrr::mesh::fit::Average::Planes) => format!("; the field's ripples smoothed first ({pairs} Taubin pairs), its planes averaged over {} rounds", f.rounds),
                (pairs, _) => format!("; the field's ripples smoothed first ({pairs} Taubin pairs)"),
            }
        );
    }
    for w in &rec.warnings {
        tell!("warning: {w}");
    }
    for n in &rec.notices {
        tell!("notice: {n}");
    }
    let name = std::path::Path::new(&input).file_stem().map(|s| s.to_string_lossy().into_owned());
    let comment = format!("nkrr {} from {input}", env!("CARGO_PKG_VERSION"));
    if let (Some(o), false) = (rec.translation(), format == MeshFormat::Glb) {
        tell!("warning: {output} stores f32 positions with the offset {o:?} added (use .glb to keep full precision)");
    }
    let mesh_out::Written { bytes, vertices, triangles } = mesh_out::write(format, &rec.mesh, name, rec.translation(), &comment, settings.glb)
        .map_err(|e| fail(format!("writing {output}: {e}")))?;
    // Again at the write: the input may have been linked there while we worked.
    nkrr::io::atomic::check_not_input(out_path, &[std::path::Path::new(&input)]).map_err(|e| fail(format!("-o {e}")))?;
    write_file(&output, &bytes)?;
    let times: Vec<String> = rec.timings.iter().map(|(s, t)| format!("{s} {t:.2}s")).collect();
    say!(
        "{output}: {} vertices, {} triangles, watertight: {}; {} (total {:.2}s); {} field evaluations",
        vertices,
        triangles,
        if rec.mesh.is_watertight() { "yes" } else { "no" },
        times.join(", "),
        nkrr::gpu::now() - t0,
        rec.extract.refine.evaluations,
    );
    Ok(())
}

/// `bytes` written to `path` so that a failed write leaves an existing file as it was
/// ([`nkrr::io::atomic`]).
fn write_file(path: &str, bytes: &[u8]) -> Result<(), Failure> {
    nkrr::io::atomic::write_atomic(std::path::Path::new(path), bytes).map_err(|e| {
        // A device or pipe is written directly (see nkrr::io::atomic): nothing there is kept.
        let kept = std::fs::metadata(path).is_ok_and(|m| m.is_file());
        fail(format!("cannot write {path}: {e}{}", if kept { format!(" (the existing {path} is left as it was)") } else { String::new() }))
    })
}

/// `args` read for `command` by the tables (`args.rs`), from `settings`; a bad one is a usage
/// error.
fn parsed(command: &str, args: &[String], settings: Settings) -> Result<Parsed, Failure> {
    args::parse(command, args, settings).map_err(|e| usage(&e))
}

/// The one operand of a command that takes one: `missing` when there is none, a usage error
/// naming the first extra one.
fn one_operand(p: &Parsed, missing: &str) -> Result<String, Failure> {
    match p.operands.as_slice() {
        [one] => Ok(one.clone()),
        [] => Err(usage(missing)),
        [_, extra, ..] => Err(usage(&format!("unexpected argument '{extra}'"))),
    }
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
    use nkrr::pipeline::Engine;
    let p = parsed("bench", args, Settings { method: Method::Nkrr, steps: 10, ..Settings::default() })?;
    if let Some(extra) = p.operands.first() {
        return Err(usage(&format!("bench: unexpected argument '{extra}'")));
    }
    let sizes = list(p.value("--sizes").expect("a default"), "--sizes")?;
    let mut ms = list(p.value("--ms").expect("a default"), "--ms")?;
    // Each m within the settings table's range, as --m is.
    let def = nkrr::settings::by_key("m").expect("the table has m");
    for &m in &ms {
        def.check(nkrr::settings::Value::Num(m as f64)).map_err(|e| usage(&format!("--ms: {e}")))?;
    }
    let settings = p.settings;
    let gpu = nkrr::gpu::Gpu::new_blocking().map_err(|e| fail(e.to_string()))?;
    say!("adapter: {}", gpu.describe());
    say!(
        "CPU share of one tuning step on a GPU objective (f64 m x m algebra, {} threads): m 500 {:.1} ms, m 1000 {:.1} ms",
        nkrr::krr::linalg::max_threads(),
        1e3 * nkrr::krr::mm::algebra_step_seconds(500, 32, 5),
        1e3 * nkrr::krr::mm::algebra_step_seconds(1000, 32, 3)
    );
    let engine = pollster::block_on(Engine::new(gpu)).map_err(|e| fail(e.to_string()))?;
    if settings.method == Method::Network {
        ms = vec![0];
    }
    say!("method {:?}, {} Adam steps, resolution {}", settings.method, settings.steps, settings.resolution);
    say!("Per objective evaluation (ms): kernel = K_nm blocks + A = K_nm^T K_nm on the GPU; solve = the f64 m x m");
    say!("algebra on the CPU (Cholesky solves, traces, W, G_mm); gradient = residual + G_nm o K_nm pass + reductions");
    say!("on the GPU; readback = device-to-host copies. mesh = field evaluations + marching cubes.");
    say!("| points | m | features s | pairs s | tuning s | evals | s/eval | kernel ms | solve ms | gradient ms | readback ms | mesh s | total s | field evals |");
    say!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for &n in &sizes {
        let cloud = synthetic_torus(n, 0.005, n as u64);
        for &m in &ms {
            // m 0 is the network's row (no regression), not a setting.
            let s = Settings { m: m.max(1), ..settings.clone() };
            let t0 = nkrr::gpu::now();
            let rec = pollster::block_on(engine.reconstruct(&cloud, &s, &mut |_| true))
                .map_err(|e| fail(format!("{n} points, m {m}: {e}")))?;
            let total = nkrr::gpu::now() - t0;
            let t = |stage: &str| rec.timings.iter().find(|(k, _)| *k == stage).map_or(0.0, |(_, v)| *v);
            let evals = rec.tuning.as_ref().map_or(0, |x| x.evaluations);
            let per_eval = if evals > 0 { t("tuning") / evals as f64 } else { 0.0 };
            let ph = rec.tuning.as_ref().and_then(|x| x.phases);
            let ms = |f: fn(&nkrr::krr::PhaseTimings) -> f64| match ph {
                Some(p) if evals > 0 => format!("{:.1}", f(&p) * 1e3 / evals as f64),
                _ => "-".into(),
            };
            say!(
                "| {n} | {m} | {:.2} | {:.2} | {:.2} | {evals} | {:.3} | {} | {} | {} | {} | {:.2} | {:.2} | {} |",
                t("features"), t("pairs"), t("tuning"), per_eval,
                ms(|p| p.kernel + p.gram), ms(|p| p.cpu_algebra), ms(|p| p.grad_pass), ms(|p| p.readback),
                t("mesh"), total, rec.extract.refine.evaluations
            );
        }
    }
    Ok(())
}

/// A mesh file by its extension: OBJ or GLB.
fn load_mesh(path: &str) -> Result<nkrr::mesh::Mesh, Failure> {
    let lower = path.to_ascii_lowercase();
    if !(lower.ends_with(".obj") || lower.ends_with(".glb")) {
        return Err(usage(&format!("{path}: only .obj and .glb meshes can be read")));
    }
    let bytes = std::fs::read(path).map_err(|e| fail(format!("cannot read {path}: {e}")))?;
    if lower.ends_with(".obj") {
        nkrr::io::obj::read_obj(&bytes).map_err(|e| fail(format!("{path}: {e}")))
    } else {
        nkrr::io::gltf_read::read_glb(&bytes).map_err(|e| fail(format!("{path}: {e}")))
    }
}

/// `s` as a JSON string literal.
fn json_str(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            // C1 controls too, so that a line through `shown` stays valid JSON.
            c if (c as u32) < 0x20 || (0x7f..=0x9f).contains(&(c as u32)) => out.push_str(&format!("\\u{:04x}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// The metrics as JSON members (no braces), rounded to 4 decimals like scripts/eval_metrics.py.
fn metrics_json(m: &nkrr::eval::Metrics) -> String {
    format!(
        "\"cd1x100\": {:.4}, \"fscore\": {:.4}, \"nc\": {:.4}, \"iou\": {}, \"watertight\": {}, \"gt_watertight\": {}, \"precision\": {:.4}, \"recall\": {:.4}, \"accuracy_x100\": {:.4}, \"completeness_x100\": {:.4}, \"faces\": {}",
        m.cd1x100(),
        m.fscore,
        m.nc,
        m.iou.map_or("null".to_string(), |v| format!("{v:.4}")),
        m.recon_watertight,
        m.gt_watertight,
        m.precision,
        m.recall,
        100.0 * m.accuracy,
        100.0 * m.completeness,
        m.recon_triangles
    ) + &split_json(&m.split)
}

/// The error split as JSON members with scripts/eval_metrics.py's names: `precision_*`,
/// `completeness_*` and, pooled, no prefix.
fn split_json(s: &nkrr::eval::ErrorSplit) -> String {
    let x100 = |v: Option<f64>| v.map_or("null".to_string(), |v| format!("{:.4}", 100.0 * v));
    let side = |prefix: &str, s: &nkrr::eval::SideSplit, with_mean: bool| {
        let mean = if with_mean { format!(", \"{prefix}mean_x100\": {:.4}", 100.0 * s.mean) } else { String::new() };
        format!(
            "{mean}, \"{prefix}beyond_share\": {:.5}, \"{prefix}within_mean_x100\": {}, \"{prefix}beyond_mean_x100\": {}, \"{prefix}beyond_cd_share\": {:.4}",
            s.beyond_share,
            x100(s.within_mean),
            x100(s.beyond_mean),
            s.beyond_cd_share
        )
    };
    side("precision_", &s.precision, true) + &side("completeness_", &s.completeness, true) + &side("", &s.pooled, false)
}

fn metrics(args: &[String]) -> Result<(), Failure> {
    let mut protocol = nkrr::eval::Protocol::default();
    let p = parsed("metrics", args, Settings::default())?;
    if let Some(seed) = p.value("--seed") {
        protocol.seed = parse(seed, "--seed")?;
    }
    let paths = p.operands;
    let [gt_path, recons @ ..] = paths.as_slice() else {
        return Err(usage("metrics needs a ground-truth mesh and at least one reconstruction"));
    };
    if recons.is_empty() {
        return Err(usage("metrics needs a ground-truth mesh and at least one reconstruction"));
    }
    let gt_mesh = load_mesh(gt_path)?;
    let gt = nkrr::eval::GroundTruth::new(&gt_mesh, protocol).map_err(|e| fail(format!("{gt_path}: {e}")))?;
    let mut failed = None;
    for r in recons {
        let scored = load_mesh(r).and_then(|m| gt.evaluate(&m).map_err(|e| fail(format!("{r}: {e}"))));
        match scored {
            Ok(m) => say!("{{\"gt\": {}, \"recon\": {}, {}}}", json_str(gt_path), json_str(r), metrics_json(&m)),
            Err(f) => {
                tell!("nkrr: {}", f.message);
                failed = Some(f.code);
            }
        }
    }
    match failed {
        Some(code) => Err(Failure { message: "some reconstructions could not be scored".into(), code }),
        None => Ok(()),
    }
}

/// One reconstruction of the `eval` command and its scores (or why there are none).
struct EvalRun {
    shape: String,
    size: String,
    method: String,
    result: Result<nkrr::eval::Metrics, String>,
    /// (stage, seconds), then ("total", s) and ("metrics", s).
    times: Vec<(&'static str, f64)>,
}

fn eval(args: &[String]) -> Result<(), Failure> {
    let names = |s: &str| -> Vec<String> { s.split(',').map(|x| x.trim().to_string()).filter(|x| !x.is_empty()).collect() };
    let p = parsed("eval", args, Settings::default())?;
    let dir = one_operand(&p, "eval needs a directory of NAME.obj and NAME-SIZE.ply files")?;
    let sizes = names(p.value("--sizes").expect("a default"));
    let methods = names(p.value("--methods").expect("a default"));
    let shapes = p.value("--shapes").map(names);
    let out = p.value("--out").expect("a default").to_string();
    let keep = p.has("--keep-meshes");
    let weights = p.value("--weights").map(read_weights).transpose()?;
    let base = p.settings;
    if sizes.is_empty() || methods.is_empty() {
        return Err(usage("eval: --sizes and --methods need at least one entry"));
    }
    let variants: Vec<(String, Settings)> = methods
        .iter()
        .map(|m| nkrr::eval::variant_settings(m, &base).map(|s| (m.clone(), s)).map_err(|e| usage(&e)))
        .collect::<Result<_, _>>()?;
    // Before any work, like `reconstruct -o`: the reports (and kept meshes) go beside PREFIX.
    for ext in ["md", "json"] {
        let file = format!("{out}.{ext}");
        nkrr::io::atomic::check_output(std::path::Path::new(&file)).map_err(|e| fail(format!("--out {out}: cannot write {file}: {e}")))?;
    }
    let entries = std::fs::read_dir(&dir).map_err(|e| fail(format!("cannot read directory {dir}: {e}")))?;
    let mut found: Vec<String> = entries
        .filter_map(|e| e.ok()?.file_name().to_str()?.strip_suffix(".obj").map(str::to_string))
        .filter(|n| shapes.as_ref().is_none_or(|s| s.contains(n)))
        .collect();
    found.sort();
    let path = |f: String| std::path::Path::new(&dir).join(f).to_string_lossy().into_owned();
    let jobs: Vec<(String, String)> = found
        .iter()
        .flat_map(|n| sizes.iter().map(move |s| (n.clone(), s.clone())))
        .filter(|(n, s)| std::path::Path::new(&path(format!("{n}-{s}.ply"))).is_file())
        .collect();
    if jobs.is_empty() {
        return Err(fail(format!("no NAME.obj with a NAME-SIZE.ply (sizes {}) in {dir}", sizes.join(","))));
    }
    // No report or kept mesh may land on a cloud or ground truth it reads (`--out DIR/spot-3k`
    // with --keep-meshes, or a link): refused before any work, like `reconstruct -o`.
    let inputs: Vec<String> = jobs
        .iter()
        .flat_map(|(n, s)| [path(format!("{n}-{s}.ply")), path(format!("{n}.obj"))])
        .collect();
    let inputs: Vec<&std::path::Path> = inputs.iter().map(std::path::Path::new).collect();
    let mut outputs = vec![format!("{out}.md"), format!("{out}.json")];
    if keep {
        for (shape, size) in &jobs {
            outputs.extend(variants.iter().map(|(method, _)| format!("{out}-{shape}-{size}-{method}.glb")));
        }
    }
    for o in &outputs {
        nkrr::io::atomic::check_not_input(std::path::Path::new(o), &inputs).map_err(|e| fail(format!("--out {out}: {e}")))?;
    }

    let gpu = nkrr::gpu::Gpu::new_blocking().map_err(|e| fail(e.to_string()))?;
    let adapter = gpu.info.name.clone();
    tell!("GPU: {adapter}");
    let engine = engine(gpu, weights)?;
    let mut runs: Vec<EvalRun> = Vec::new();
    let mut gt_cache: Option<(String, Result<nkrr::eval::GroundTruth, String>)> = None;
    for (shape, size) in &jobs {
        if gt_cache.as_ref().is_none_or(|(n, _)| n != shape) {
            let gt_path = path(format!("{shape}.obj"));
            let gt = load_mesh(&gt_path)
                .map_err(|f| f.message)
                .and_then(|m| nkrr::eval::GroundTruth::new(&m, nkrr::eval::Protocol::default()).map_err(|e| format!("{gt_path}: {e}")));
            gt_cache = Some((shape.clone(), gt));
        }
        let gt = gt_cache.as_ref().map(|(_, g)| g.as_ref()).expect("just set");
        let cloud_path = path(format!("{shape}-{size}.ply"));
        let cloud = std::fs::read(&cloud_path)
            .map_err(|e| format!("cannot read {cloud_path}: {e}"))
            .and_then(|b| nkrr::io::ply::read_ply(&b).map_err(|e| format!("{cloud_path}: {e}")));
        for (method, settings) in &variants {
            let t0 = nkrr::gpu::now();
            let mut times = Vec::new();
            let result = cloud.as_ref().map_err(Clone::clone).and_then(|parsed| {
                let rec = pollster::block_on(engine.reconstruct(&parsed.cloud, settings, &mut |_| true))
                    .map_err(|e| format!("{cloud_path}: {e}"))?;
                times = rec.timings.clone();
                times.push(("total", nkrr::gpu::now() - t0));
                if keep {
                    let opts = nkrr::io::gltf::GlbOptions { translation: rec.translation(), compression: settings.glb, ..Default::default() };
                    let glb = nkrr::io::gltf::write_glb(&rec.mesh, &opts).map_err(|e| e.to_string())?;
                    let file = format!("{out}-{shape}-{size}-{method}.glb");
                    write_file(&file, &glb).map_err(|f| f.message)?;
                }
                let t1 = nkrr::gpu::now();
                // Scored in the ground truth's (user) coordinates: far-off clouds come back
                // relative to an origin.
                let moved;
                let mesh = match rec.translation() {
                    Some(_) => {
                        moved = nkrr::mesh::Mesh { positions: rec.positions_f64().iter().map(|p| p.map(|x| x as f32)).collect(), ..rec.mesh.clone() };
                        &moved
                    }
                    None => &rec.mesh,
                };
                let m = gt.map_err(Clone::clone)?.evaluate(mesh).map_err(|e| e.to_string())?;
                times.push(("metrics", nkrr::gpu::now() - t1));
                Ok(m)
            });
            match &result {
                Ok(m) => tell!(
                    "{shape}-{size} {method}: CD1x100 {:.4}, F {:.4}, NC {:.4}, IoU {}, {:.1}s",
                    m.cd1x100(),
                    m.fscore,
                    m.nc,
                    m.iou.map_or("-".into(), |v| format!("{v:.4}")),
                    nkrr::gpu::now() - t0
                ),
                Err(e) => tell!("{shape}-{size} {method}: failed: {e}"),
            }
            runs.push(EvalRun { shape: shape.clone(), size: size.clone(), method: method.clone(), result, times });
            // Rewritten after every run, so an interrupted evaluation keeps what it has.
            write_eval_reports(&out, &dir, &adapter, &base, &sizes, &variants, &runs)?;
        }
    }
    say!("wrote {out}.md and {out}.json ({} runs)", runs.len());
    Ok(())
}

fn write_eval_reports(
    out: &str,
    dir: &str,
    adapter: &str,
    base: &Settings,
    sizes: &[String],
    variants: &[(String, Settings)],
    runs: &[EvalRun],
) -> Result<(), Failure> {
    const STAGES: [&str; 6] = ["features", "pairs", "tuning", "mesh", "total", "metrics"];
    let time = |r: &EvalRun, k: &str| r.times.iter().find(|(s, _)| *s == k).map(|(_, t)| *t);
    let f4 = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.4}"));
    let f2 = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.2}"));

    let mut md = format!(
        "# nkrr eval: {dir}\n\nAdapter: {adapter}. Base settings (the method is set per row): {base:?}.\n\n\
         Protocol (nkrr::eval): ground truth normalised to the unit cube, 100k area-weighted samples per surface; \
         CD1 ×100 (↓), F-score at τ = 0.01 (↑), normal consistency (↑); IoU (↑) from 100k uniform points in \
         [-0.55, 0.55]³, only where the ground truth is watertight. Times in seconds (metrics: the scoring itself). \
         Beyond τ: the share of CD1 carried by the samples farther than τ (missing or extra surface; the rest is \
         the error where the surface is right), both sides pooled; the JSON has the split per side.\n"
    );
    for size in sizes {
        let rows: Vec<&EvalRun> = runs.iter().filter(|r| &r.size == size).collect();
        if rows.is_empty() {
            continue;
        }
        md += &format!("\n## {size} points\n\n| shape | method | CD1×100 | F | NC | IoU | beyond τ | triangles | watertight | features | pairs | tuning | mesh | total | metrics |\n");
        md += "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |\n";
        for r in &rows {
            match &r.result {
                Ok(m) => {
                    md += &format!(
                        "| {} | {} | {} | {} | {} | {} | {:.2} | {} | {} |",
                        r.shape,
                        r.method,
                        f4(Some(m.cd1x100())),
                        f4(Some(m.fscore)),
                        f4(Some(m.nc)),
                        f4(m.iou),
                        m.split.pooled.beyond_cd_share,
                        m.recon_triangles,
                        if m.recon_watertight { "yes" } else { "no" }
                    );
                    for s in STAGES {
                        md += &format!(" {} |", f2(time(r, s)));
                    }
                    md += "\n";
                }
                Err(e) => md += &format!("| {} | {} | failed: {} ||||||||||||\n", r.shape, r.method, e.replace('|', "/").replace('\n', " ")),
            }
        }
        // Means per method over the shapes that succeeded (IoU over those that have it).
        for (method, _) in variants {
            let ok: Vec<(&EvalRun, &nkrr::eval::Metrics)> =
                rows.iter().filter(|r| &r.method == method).filter_map(|r| r.result.as_ref().ok().map(|m| (*r, m))).collect();
            if ok.is_empty() {
                continue;
            }
            let mean = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
            let all = rows.iter().filter(|r| &r.method == method).count();
            let label = if ok.len() == all { "**mean**".to_string() } else { format!("**mean** ({} of {all})", ok.len()) };
            let ious: Vec<f64> = ok.iter().filter_map(|(_, m)| m.iou).collect();
            md += &format!(
                "| {label} | {method} | {} | {} | {} | {} | {} | | |",
                f4(mean(ok.iter().map(|(_, m)| m.cd1x100()).collect())),
                f4(mean(ok.iter().map(|(_, m)| m.fscore).collect())),
                f4(mean(ok.iter().map(|(_, m)| m.nc).collect())),
                f4(mean(ious)),
                f2(mean(ok.iter().map(|(_, m)| m.split.pooled.beyond_cd_share).collect())),
            );
            for s in STAGES {
                md += &format!(" {} |", f2(mean(ok.iter().filter_map(|(r, _)| time(r, s)).collect())));
            }
            md += "\n";
        }
    }

    let mut js = format!("{{\"dir\": {}, \"adapter\": {}, \"settings\": {}, \"runs\": [", json_str(dir), json_str(adapter), json_str(&format!("{base:?}")));
    for (i, r) in runs.iter().enumerate() {
        let times: Vec<String> = r.times.iter().map(|(s, t)| format!("\"{s}\": {t:.3}")).collect();
        let body = match &r.result {
            Ok(m) => metrics_json(m),
            Err(e) => format!("\"error\": {}", json_str(e)),
        };
        js += &format!(
            "{}\n  {{\"shape\": {}, \"size\": {}, \"method\": {}, {body}, \"times\": {{{}}}}}",
            if i > 0 { "," } else { "" },
            json_str(&r.shape),
            json_str(&r.size),
            json_str(&r.method),
            times.join(", ")
        );
    }
    js += "\n]}\n";
    write_file(&format!("{out}.md"), md.as_bytes())?;
    write_file(&format!("{out}.json"), js.as_bytes())?;
    Ok(())
}

/// `seconds` as "m:ss" (or "h:mm:ss").
fn minutes(seconds: f64) -> String {
    let s = seconds.round() as u64;
    if s >= 3600 { format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60) } else { format!("{}:{:02}", s / 60, s % 60) }
}
