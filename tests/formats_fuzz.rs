//! A deterministic fuzz harness for the LAS/LAZ, E57 and text readers (and the content
//! detection in front of them), run as an ordinary test, like tests/ply_fuzz.rs for PLY.
//!
//! Seeds are the independent-tool fixtures (tests/fixtures/formats) and a CSV; mutations are
//! bit flips, byte runs overwritten with extreme values (0, 0xff.., i32/u32/u64 maxima) at
//! random offsets — most in the headers, where the counts and offsets live — truncation,
//! insertion and deletion. For every input, `read_cloud` must return (no panic, in the
//! reader or in the `las`, `laz` and `e57` crates), quickly, without any single allocation out
//! of proportion to the input, and a successful read holds no more points than the file could.
//!
//! `NKRR_FUZZ_CASES` sets the number of inputs per seed (default 3000), `NKRR_FUZZ_SEED` the
//! PRNG seed. A failure names the seed, the case and the mutation.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

#[path = "common/fuzz.rs"]
mod fuzz;

use fuzz::{Rng, Watch, LARGEST};

#[global_allocator]
static GLOBAL: Watch = Watch;

const EXTREMES: [&[u8]; 7] = [
    &[0; 8],
    &[0xff; 8],
    &[0xff, 0xff, 0xff, 0x7f],
    &[0x00, 0x00, 0x00, 0x80],
    &[0x00, 0x94, 0x35, 0x77], // 2e9 little-endian
    &[0, 0, 0, 0, 0, 0, 0xf0, 0x7f], // f64 infinity
    &[0, 0, 0, 0, 0, 0, 0xf8, 0x7f], // f64 NaN
];

/// One mutation of `seed`, and its description.
fn mutate(seed: &[u8], rng: &mut Rng) -> (Vec<u8>, String) {
    let mut b = seed.to_vec();
    // Most mutations hit the first 400 bytes (LAS header, E57 header) or the E57 XML's end.
    let pick = |rng: &mut Rng, len: usize| if rng.below(4) > 0 { rng.below(len.min(400)) } else { rng.below(len) };
    match rng.below(6) {
        0 => {
            let n = 1 + rng.below(8);
            for _ in 0..n {
                let at = pick(rng, b.len());
                b[at] ^= 1 << rng.below(8);
            }
            (b, format!("{n} bit flips"))
        }
        1 => {
            let at = pick(rng, b.len());
            let v = EXTREMES[rng.below(EXTREMES.len())];
            let end = (at + v.len()).min(b.len());
            b[at..end].copy_from_slice(&v[..end - at]);
            (b, format!("{v:02x?} at {at}"))
        }
        2 => {
            let at = rng.below(b.len());
            b.truncate(at);
            (b, format!("truncated to {at}"))
        }
        3 => {
            let at = pick(rng, b.len());
            let n = 1 + rng.below(16);
            let junk: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
            b.splice(at..at, junk);
            (b, format!("{n} bytes inserted at {at}"))
        }
        4 => {
            let at = pick(rng, b.len());
            let n = (1 + rng.below(16)).min(b.len() - at);
            b.drain(at..at + n);
            (b, format!("{n} bytes deleted at {at}"))
        }
        _ => {
            // A little-endian u32 or u64 somewhere in the header set to a random size.
            let at = pick(rng, b.len()) & !3;
            let v = rng.next() >> rng.below(64);
            let bytes = v.to_le_bytes();
            let w = if rng.below(2) == 0 { 4 } else { 8 };
            let end = (at + w).min(b.len());
            b[at..end].copy_from_slice(&bytes[..end - at]);
            (b, format!("{v} at {at}"))
        }
    }
}

fn seeds() -> Vec<(String, Vec<u8>)> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats");
    let mut out: Vec<(String, Vec<u8>)> = [
        "spot-las12-pf3.las",
        "spot-las14-pf10.las",
        "spot-las12-pf1.laz",
        "spot-las14-pf7.laz",
        "spot-single.e57",
        "spot-two-scans.e57",
    ]
    .iter()
    .map(|n| (n.to_string(), std::fs::read(dir.join(n)).unwrap_or_else(|e| panic!("{n}: {e}"))))
    .collect();
    let mut csv = String::from("x,y,z,red,green,blue\n");
    for i in 0..200 {
        let t = i as f64 * 0.1;
        csv.push_str(&format!("{},{},{},{},{},{}\n", t.cos(), t.sin(), t * 0.01, i % 256, 255 - i % 256, 7));
    }
    out.push(("cloud.csv".into(), csv.into_bytes()));
    out.push(("cloud.pts".into(), b"4\n0 0 0 1 2 3 4\n1 0 0 1 2 3 4\n0 1 0 1 2 3 4\n0 0 1 1 2 3 4\n".to_vec()));
    out
}

#[test]
fn fuzz_scan_readers_no_panics() {
    let cases: usize = std::env::var("NKRR_FUZZ_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(3000);
    let seed: u64 = std::env::var("NKRR_FUZZ_SEED").ok().and_then(|s| s.parse().ok()).unwrap_or(0x5eed_57);
    let mut failures = Vec::new();
    let t0 = Instant::now();
    let (mut oks, mut errs) = (0usize, 0usize);
    for (name, bytes) in seeds() {
        nkrr::io::read_cloud(&bytes, Some(&name)).unwrap_or_else(|e| panic!("seed {name} does not read: {e}"));
        let mut rng = Rng(seed ^ bytes.len() as u64);
        for case in 0..cases {
            let (input, how) = mutate(&bytes, &mut rng);
            LARGEST.store(0, Ordering::Relaxed);
            let t = Instant::now();
            let r = std::panic::catch_unwind(|| nkrr::io::read_cloud(&input, Some(&name)));
            let dt = t.elapsed();
            let largest = LARGEST.load(Ordering::Relaxed);
            let why = match &r {
                Err(p) => Some(format!(
                    "panicked: {}",
                    p.downcast_ref::<String>().cloned().or(p.downcast_ref::<&str>().map(|s| s.to_string())).unwrap_or_default()
                )),
                Ok(_) if dt > Duration::from_secs(2) => Some(format!("took {dt:.2?}")),
                Ok(_) if largest > (48 << 20) + 256 * input.len() => Some(format!("allocated {largest} bytes at once")),
                // LAZ can hold far more than 64 points a byte (a flat grid: 84); its bound is
                // the chunk structure's (nkrr::io::las::laz_points_cap; 20-byte records, the
                // usual 50000-point chunks).
                Ok(Ok(s))
                    if s.cloud.len() as u64
                        > (64 * input.len() as u64 + 64).max(nkrr::io::las::laz_points_cap(input.len() as u64, 20, 50_000)) =>
                {
                    Some(format!("{} points from {} bytes", s.cloud.len(), input.len()))
                }
                _ => None,
            };
            match r {
                Ok(Ok(_)) => oks += 1,
                _ => errs += 1,
            }
            if let Some(why) = why {
                failures.push(format!("{name}, case {case} ({how}): {why}"));
            }
        }
    }
    eprintln!("scan fuzz: {cases} cases per seed in {:.2?}: {oks} read, {errs} rejected", t0.elapsed());
    assert!(failures.is_empty(), "{} failures; first ones:\n{}", failures.len(), failures[..failures.len().min(10)].join("\n"));
}
