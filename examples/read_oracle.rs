//! The checker behind `scripts/fuzz_readers.py`: reads every file of a manifest with nkrr's
//! readers (`nkrr::io::read_cloud`, what the CLI and the page use) and judges the result against
//! what an independent writer (laspy, pye57, Python's own PLY and text writers) put in it.
//!
//!     read_oracle MANIFEST.jsonl [--skip K] [--timeout SECONDS]
//!
//! A manifest line is `{"case", "file", "format", "expect", "points", "what"}`; `points` is the
//! positions written, little-endian f64 x y z per point, or null. Expectations:
//! - `exact`: a valid file; the points read must be these (count, order, positions within f32
//!   precision). A refusal is a wrong refusal, a difference a misread.
//! - `prefix`: a file cut short; a refusal is fine, or the first k <= n points, the last of which
//!   may differ only where the reader warned.
//! - `refuse_or_warn`: damage the reader must notice: a refusal, or a read with a warning.
//! - `any`: random damage: only a panic, a hang or an error without a message fails.
//!
//! One JSON line per case goes to stdout: `{"case", "outcome", "ok", "detail", "ms"}`. A case
//! that runs past the timeout is printed as a hang and the process exits with status 3 (the
//! reading thread cannot be stopped); the driver resumes with `--skip`.

use std::io::{BufRead, Write};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::{json, Value};

/// What a read gave: points in user coordinates (f64) and the warnings, or the error.
type Read = Result<(Vec<[f64; 3]>, Vec<String>), String>;

fn read(file: &str) -> Read {
    let bytes = std::fs::read(file).map_err(|e| format!("cannot read the case's file: {e}"))?;
    let scan = nkrr::io::read_cloud(&bytes, Some(file)).map_err(|e| e.to_string())?;
    let o = scan.cloud.origin;
    let points = scan.cloud.positions.iter().map(|p| [0, 1, 2].map(|a| o[a] + p[a] as f64)).collect();
    Ok((points, scan.warnings()))
}

fn expected(path: &Value) -> Option<Vec<[f64; 3]>> {
    let bytes = std::fs::read(path.as_str()?).ok()?;
    let v: Vec<f64> = bytes.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect();
    Some(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// Whether `got` is `want` within what an f32 relative to the reader's origin can hold: half an
/// ulp of the offset from the origin, which is at most the cloud's extent here (the readers put
/// the origin inside the cloud), plus a millionth of the extent for parsing paths that round twice.
fn same(got: [f64; 3], want: [f64; 3], extent: f64) -> bool {
    (0..3).all(|a| (got[a] - want[a]).abs() <= 1e-6 * extent + 1e-9 * (1.0 + want[a].abs()))
}

fn extent(points: &[[f64; 3]]) -> f64 {
    (0..3)
        .map(|a| {
            let (lo, hi) = points.iter().fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(p[a]), h.max(p[a])));
            if hi >= lo { hi - lo } else { 0.0 }
        })
        .fold(0.0, f64::max)
}

/// The first index where `got` and `want` differ, if any (over the shorter of the two).
fn first_difference(got: &[[f64; 3]], want: &[[f64; 3]], extent: f64) -> Option<usize> {
    got.iter().zip(want).position(|(g, w)| !same(*g, *w, extent))
}

/// (outcome, ok, detail) for one case.
fn judge(expect: &str, want: Option<&[[f64; 3]]>, result: &Read) -> (&'static str, bool, String) {
    match (expect, result) {
        (_, Err(e)) if e.trim().is_empty() => ("refused", false, "an error without a message".into()),
        ("exact", Err(e)) => ("wrong_refusal", false, e.clone()),
        ("exact", Ok((got, warnings))) => {
            let Some(want) = want else { return ("read", false, "no expected points".into()) };
            let ext = extent(want);
            if got.len() != want.len() {
                return ("misread", false, format!("{} points read, {} written; warnings: {warnings:?}", got.len(), want.len()));
            }
            match first_difference(got, want, ext) {
                Some(i) => ("misread", false, format!("point {i}: read {:?}, written {:?}", got[i], want[i])),
                None => ("exact", true, String::new()),
            }
        }
        ("prefix", Err(e)) => ("refused", true, e.clone()),
        ("prefix", Ok((got, warnings))) => {
            let Some(want) = want else { return ("read", false, "no expected points".into()) };
            let ext = extent(want);
            if got.len() > want.len() {
                return ("misread", false, format!("{} points read from a cut file of {} points", got.len(), want.len()));
            }
            let whole = got.len().saturating_sub(1);
            if let Some(i) = first_difference(&got[..whole], want, ext) {
                return ("misread", false, format!("point {i} of a cut file: read {:?}, written {:?}", got[i], want[i]));
            }
            match got.last() {
                Some(&last) if !same(last, want[whole], ext) && warnings.is_empty() => (
                    "silent",
                    false,
                    format!("the last point read ({whole}) is {last:?}, written {:?}, and no warning", want[whole]),
                ),
                _ if warnings.is_empty() => ("read", true, format!("{} of {} points", got.len(), want.len())),
                _ => ("warned", true, warnings.join(" | ")),
            }
        }
        ("refuse_or_warn", Err(e)) => ("refused", true, e.clone()),
        ("refuse_or_warn", Ok((got, warnings))) if warnings.is_empty() => {
            ("silent", false, format!("{} points read without a warning", got.len()))
        }
        ("refuse_or_warn", Ok((_, warnings))) => ("warned", true, warnings.join(" | ")),
        ("any", Err(e)) => ("refused", true, e.clone()),
        ("any", Ok((got, warnings))) => (if warnings.is_empty() { "read" } else { "warned" }, true, format!("{} points", got.len())),
        (other, _) => ("read", false, format!("unknown expectation '{other}'")),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(manifest) = args.first() else {
        eprintln!("usage: read_oracle MANIFEST.jsonl [--skip K] [--timeout SECONDS]");
        std::process::exit(2);
    };
    let opt = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse::<f64>().ok());
    let skip = opt("--skip").unwrap_or(0.0) as usize;
    let timeout = Duration::from_secs_f64(opt("--timeout").unwrap_or(20.0));
    // A panic is a finding, reported as a case's outcome: keep its message off stderr's noise.
    std::panic::set_hook(Box::new(|_| {}));

    let file = std::fs::File::open(manifest).unwrap_or_else(|e| {
        eprintln!("read_oracle: cannot open {manifest}: {e}");
        std::process::exit(2);
    });
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    for line in std::io::BufReader::new(file).lines().skip(skip) {
        let line = line.expect("manifest is text");
        if line.trim().is_empty() {
            continue;
        }
        let case: Value = serde_json::from_str(&line).expect("manifest line is JSON");
        let path = case["file"].as_str().unwrap_or_default().to_string();
        let expect = case["expect"].as_str().unwrap_or("any").to_string();
        let want = expected(&case["points"]);
        let t0 = Instant::now();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let r = std::panic::catch_unwind(|| read(&path));
            let _ = tx.send(r);
        });
        let (outcome, ok, detail) = match rx.recv_timeout(timeout) {
            Ok(Ok(result)) => judge(&expect, want.as_deref(), &result),
            Ok(Err(panic)) => {
                let msg = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                ("panic", false, msg)
            }
            Err(_) => {
                let row = json!({"case": case["case"], "outcome": "hang", "ok": false, "detail": format!("no answer in {timeout:?}"), "ms": t0.elapsed().as_secs_f64() * 1e3});
                let _ = writeln!(out, "{row}");
                let _ = out.flush();
                std::process::exit(3);
            }
        };
        let detail: String = detail.chars().take(600).collect();
        let row = json!({"case": case["case"], "outcome": outcome, "ok": ok, "detail": detail, "ms": t0.elapsed().as_secs_f64() * 1e3});
        let _ = writeln!(out, "{row}");
    }
    let _ = out.flush();
}
