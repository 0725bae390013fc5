//! The `nkrr` command line: the same library as the web page, run natively through wgpu.

use std::process::ExitCode;

const USAGE: &str = "\
nkrr — surface reconstruction from raw point clouds

USAGE:
    nkrr info CLOUD.ply     point count, bounds, properties found, warnings
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
        println!("bounds:     [{}, {}, {}] .. [{}, {}, {}]", b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2]);
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
