//! A deterministic fuzz harness for the PLY reader that runs as an ordinary test.
//!
//! It mutates valid PLY files (bit flips, byte insertion and deletion, truncation, header tokens
//! replaced by extreme numbers, header lines spliced between files, formats swapped, list counts
//! blown up, crossover) and also feeds random bytes behind valid-looking headers. For every input
//! it checks that `read_ply` and `read_ply_header` return instead of panicking, that each call is
//! quick, that no single allocation is out of proportion to the input, and that a successful read
//! holds no more points than the input has bytes.
//!
//! `NKRR_FUZZ_CASES` sets the number of inputs (default 100,000: about a second in the dev
//! profile); `NKRR_FUZZ_SEED` the PRNG seed.
//! A failure prints the first offending input as a hex dump.

use nkrr::io::ply::{read_ply, read_ply_header};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

#[path = "common/fuzz.rs"]
mod fuzz;

use fuzz::{Rng, Watch, LARGEST};

#[global_allocator]
static GLOBAL: Watch = Watch;

// ---------------------------------------------------------------------------------------------
// Seed corpus: small valid files covering the formats and features.
// ---------------------------------------------------------------------------------------------

const FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];

#[derive(Clone, Copy)]
enum T {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl T {
    fn name(self) -> &'static str {
        [
            "char", "uchar", "short", "ushort", "int", "uint", "float", "double",
        ][self as usize]
    }
    fn put(self, out: &mut Vec<u8>, fmt: &str, v: f64) {
        if fmt == "ascii" {
            let s = match self {
                T::F32 => format!("{:?}", v as f32),
                T::F64 => format!("{v:?}"),
                _ => format!("{}", v as i64),
            };
            out.extend_from_slice(s.as_bytes());
            return;
        }
        let be = fmt == "binary_big_endian";
        macro_rules! b {
            ($x:expr) => {
                if be {
                    out.extend_from_slice(&$x.to_be_bytes())
                } else {
                    out.extend_from_slice(&$x.to_le_bytes())
                }
            };
        }
        match self {
            T::I8 => b!(v as i8),
            T::U8 => b!(v as u8),
            T::I16 => b!(v as i16),
            T::U16 => b!(v as u16),
            T::I32 => b!(v as i32),
            T::U32 => b!(v as u32),
            T::F32 => b!(v as f32),
            T::F64 => b!(v),
        }
    }
}

enum P {
    S(&'static str, T),
    L(&'static str, T, T),
}

struct E {
    name: &'static str,
    count: usize,
    props: Vec<P>,
}

fn build(fmt: &str, elems: &[E], crlf: bool, rng: &mut Rng) -> Vec<u8> {
    let nl = if crlf { "\r\n" } else { "\n" };
    let mut h = format!("ply{nl}format {fmt} 1.0{nl}comment fuzz seed{nl}");
    for e in elems {
        h += &format!("element {} {}{nl}", e.name, e.count);
        for p in &e.props {
            match p {
                P::S(n, t) => h += &format!("property {} {n}{nl}", t.name()),
                P::L(n, c, t) => h += &format!("property list {} {} {n}{nl}", c.name(), t.name()),
            }
        }
    }
    h += &format!("obj_info generated{nl}end_header{nl}");
    let mut out = h.into_bytes();
    for e in elems {
        for _ in 0..e.count {
            for (i, p) in e.props.iter().enumerate() {
                if fmt == "ascii" && i > 0 {
                    out.push(b' ');
                }
                match p {
                    P::S(_, t) => t.put(&mut out, fmt, (rng.below(200) as f64) - 50.0 + 0.25),
                    P::L(_, c, t) => {
                        let n = rng.below(5);
                        c.put(&mut out, fmt, n as f64);
                        for _ in 0..n {
                            if fmt == "ascii" {
                                out.push(b' ');
                            }
                            t.put(&mut out, fmt, rng.below(100) as f64);
                        }
                    }
                }
            }
            if fmt == "ascii" {
                out.extend_from_slice(nl.as_bytes());
            }
        }
    }
    out
}

fn seeds() -> Vec<Vec<u8>> {
    let mut rng = Rng(7);
    let xyz = |t: T| vec![P::S("x", t), P::S("y", t), P::S("z", t)];
    let face = |n: usize| E {
        name: "face",
        count: n,
        props: vec![P::L("vertex_indices", T::U8, T::I32), P::S("flags", T::U8)],
    };
    let mut out = Vec::new();
    for (k, fmt) in FORMATS.iter().enumerate() {
        let crlf = k == 0;
        let layouts: Vec<Vec<E>> = vec![
            vec![E {
                name: "vertex",
                count: 8,
                props: xyz(T::F32),
            }],
            vec![E {
                name: "vertex",
                count: 5,
                props: xyz(T::F64),
            }],
            vec![E {
                name: "vertex",
                count: 6,
                props: xyz(T::I16),
            }],
            vec![E {
                name: "vertex",
                count: 6,
                props: {
                    let mut p = xyz(T::F32);
                    p.extend([P::S("nx", T::F32), P::S("ny", T::F32), P::S("nz", T::F32)]);
                    p.extend([
                        P::S("red", T::U8),
                        P::S("green", T::U8),
                        P::S("blue", T::U8),
                        P::S("alpha", T::U8),
                    ]);
                    p
                },
            }],
            vec![
                face(3),
                E {
                    name: "vertex",
                    count: 5,
                    props: xyz(T::F32),
                },
                face(4),
            ],
            vec![E {
                name: "vertex",
                count: 5,
                props: vec![
                    P::S("x", T::U8),
                    P::L("nbrs", T::U16, T::F32),
                    P::S("y", T::U32),
                    P::S("z", T::I8),
                    P::S("red", T::F32),
                    P::S("green", T::F64),
                    P::S("blue", T::U16),
                ],
            }],
            vec![
                E {
                    name: "edge",
                    count: 3,
                    props: vec![P::S("a", T::I32), P::S("b", T::I32)],
                },
                E {
                    name: "marker",
                    count: 4,
                    props: vec![],
                },
                E {
                    name: "vertex",
                    count: 4,
                    props: xyz(T::F32),
                },
                E {
                    name: "face",
                    count: 2,
                    props: vec![P::L("vertex_indices", T::U32, T::U32)],
                },
            ],
        ];
        for elems in &layouts {
            out.push(build(fmt, elems, crlf, &mut rng));
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Mutations.
// ---------------------------------------------------------------------------------------------

const EXTREME: &[&str] = &[
    "4294967295",
    "4294967296",
    "2147483647",
    "2147483648",
    "-2147483649",
    "99999999999999999999",
    "18446744073709551615",
    "18446744073709551616",
    "9223372036854775807",
    "9223372036854775808",
    "1537228672809129301",
    "1431655766",
    "-1",
    "-0",
    "0",
    "1",
    "255",
    "256",
    "65535",
    "65536",
    "1e308",
    "1e39",
    "-1e39",
    "nan",
    "inf",
    "-inf",
    "0x10",
    "",
    " ",
    "1.0",
    "2.0",
    "list",
    "uchar",
    "float",
    "double",
    "int64",
    "vertex",
    "face",
    "x",
    "element",
    "property",
    "end_header",
    "\r",
    "\n",
    "\0",
];

const HEADER_LINES: &[&str] = &[
    "element vertex 4294967295",
    "element vertex 2147483648",
    "element vertex 18446744073709551615",
    "element face 99999999999999999999",
    "element face 1431655765",
    "element vertex 0",
    "element vertex -1",
    "property list uint uint vertex_indices",
    "property list uchar double big",
    "property list float float bad",
    "property list int int x",
    "property double x",
    "property float y",
    "property uchar z",
    "property uchar red",
    "property float nx",
    "property half w",
    "property",
    "element",
    "format ascii 1.0",
    "format binary_little_endian 1.0",
    "format binary_big_endian 1.0",
    "format binary_big_endian 2.0",
    "comment \u{ff}\u{fe}",
    "obj_info x",
    "end_header",
    "",
    "ply",
];

/// Offset just past the `end_header` line (LF or CRLF).
fn header_end(b: &[u8]) -> Option<usize> {
    let p = b.windows(10).position(|w| w == b"end_header")?;
    let nl = b[p..].iter().position(|&c| c == b'\n')?;
    Some(p + nl + 1)
}

/// Byte ranges of whitespace-separated tokens in the header part of `b`.
fn header_tokens(b: &[u8]) -> Vec<(usize, usize)> {
    let end = header_end(b).unwrap_or(b.len().min(1024));
    let mut toks = Vec::new();
    let mut i = 0;
    while i < end {
        while i < end && b[i].is_ascii_whitespace() {
            i += 1;
        }
        let s = i;
        while i < end && !b[i].is_ascii_whitespace() {
            i += 1;
        }
        if s < i {
            toks.push((s, i));
        }
    }
    toks
}

/// A position in `b` (or `b.len()` when empty): half the time in the body, where header-only
/// damage would stop the reader before it gets there.
fn spot(b: &[u8], rng: &mut Rng) -> usize {
    let body = header_end(b).unwrap_or(0);
    if b.is_empty() {
        return 0;
    }
    if body < b.len() && rng.chance(2) {
        body + rng.below(b.len() - body)
    } else {
        rng.below(b.len())
    }
}

fn mutate(input: &[u8], corpus: &[Vec<u8>], rng: &mut Rng) -> Vec<u8> {
    let mut b = input.to_vec();
    let rounds = if rng.chance(2) { 1 } else { 2 + rng.below(3) };
    for _ in 0..rounds {
        match rng.below(11) {
            // Bit flips.
            0 => {
                for _ in 0..1 + rng.below(8) {
                    if !b.is_empty() {
                        let i = spot(&b, rng);
                        b[i] ^= 1 << rng.below(8);
                    }
                }
            }
            // Insert bytes (often structural characters).
            1 => {
                let i = spot(&b, rng);
                let n = 1 + rng.below(8);
                for _ in 0..n {
                    let c = if rng.chance(2) {
                        *rng.pick(b" \n\r\t0123456789-.e")
                    } else {
                        rng.next() as u8
                    };
                    b.insert(i.min(b.len()), c);
                }
            }
            // Delete a range.
            2 => {
                if !b.is_empty() {
                    let i = spot(&b, rng);
                    let n = (1 + rng.below(16)).min(b.len() - i);
                    b.drain(i..i + n);
                }
            }
            // Truncate.
            3 => {
                let n = spot(&b, rng);
                b.truncate(n);
            }
            // Replace a header token by an extreme value.
            4 | 5 => {
                let toks = header_tokens(&b);
                if !toks.is_empty() {
                    let (s, e) = *rng.pick(&toks);
                    b.splice(s..e, rng.pick(EXTREME).bytes());
                }
            }
            // Splice header lines: insert, delete, duplicate or swap.
            6 => {
                let Some(end) = header_end(&b) else { continue };
                let mut lines: Vec<Vec<u8>> = b[..end]
                    .split(|&c| c == b'\n')
                    .map(|l| l.to_vec())
                    .collect();
                lines.pop(); // empty piece after the final newline
                let body = b[end..].to_vec();
                let n = lines.len();
                match rng.below(4) {
                    0 => lines.insert(rng.below(n + 1), rng.pick(HEADER_LINES).as_bytes().to_vec()),
                    1 if n > 0 => {
                        lines.remove(rng.below(n));
                    }
                    2 if n > 0 => {
                        let l = lines[rng.below(n)].clone();
                        lines.insert(rng.below(n + 1), l);
                    }
                    _ if n > 1 => lines.swap(rng.below(n), rng.below(n)),
                    _ => {}
                }
                b = lines.join(&b'\n');
                b.push(b'\n');
                b.extend_from_slice(&body);
            }
            // Swap the format, keeping the body.
            7 => {
                let s = String::from_utf8_lossy(&b[..header_end(&b).unwrap_or(0)]).into_owned();
                for f in FORMATS {
                    if let Some(i) = s.find(f) {
                        let to = *rng.pick(&FORMATS);
                        b.splice(i..i + f.len(), to.bytes());
                        break;
                    }
                }
            }
            // Overwrite body bytes with 0xff / 0x7f runs (huge list counts, NaNs).
            8 => {
                let start = header_end(&b).unwrap_or(0);
                if start < b.len() {
                    let i = start + rng.below(b.len() - start);
                    let v = *rng.pick(&[0xffu8, 0x7f, 0x80, 0x00]);
                    for c in b.iter_mut().skip(i).take(1 + rng.below(4)) {
                        *c = v;
                    }
                }
            }
            // Crossover: this file's head with another's tail.
            9 => {
                let other = rng.pick(corpus);
                let i = rng.below(b.len() + 1);
                let j = rng.below(other.len() + 1);
                b.truncate(i);
                b.extend_from_slice(&other[j..]);
            }
            // Duplicate a chunk (repeated records, repeated header lines).
            _ => {
                if !b.is_empty() {
                    let i = rng.below(b.len());
                    let n = (1 + rng.below(64)).min(b.len() - i);
                    let chunk = b[i..i + n].to_vec();
                    let at = rng.below(b.len() + 1);
                    b.splice(at..at, chunk);
                }
            }
        }
    }
    b
}

/// A valid-looking header from the corpus (possibly with a token replaced) followed by random
/// bytes; for ascii, random digits and separators half the time.
fn random_body(corpus: &[Vec<u8>], rng: &mut Rng) -> Vec<u8> {
    let seed = rng.pick(corpus);
    let end = header_end(seed).unwrap_or(seed.len());
    let mut b = seed[..end].to_vec();
    if rng.chance(3) {
        b = mutate(&b, corpus, rng);
    }
    let max = if rng.chance(8) { 8192 } else { 256 };
    let n = rng.below(max);
    let digits = rng.chance(2);
    for _ in 0..n {
        b.push(if digits {
            *rng.pick(b"0123456789 \n-.e")
        } else {
            rng.next() as u8
        });
    }
    b
}

// ---------------------------------------------------------------------------------------------
// The harness.
// ---------------------------------------------------------------------------------------------

fn hex_dump(b: &[u8]) -> String {
    let mut s = String::new();
    for (i, row) in b.chunks(16).take(256).enumerate() {
        s += &format!("{:06x}  ", i * 16);
        for c in row {
            s += &format!("{c:02x} ");
        }
        s += &" ".repeat(3 * (16 - row.len()));
        s += " |";
        s.extend(row.iter().map(|&c| {
            if (0x20..0x7f).contains(&c) {
                c as char
            } else {
                '.'
            }
        }));
        s += "|\n";
    }
    if b.len() > 4096 {
        s += &format!("... ({} bytes in all)\n", b.len());
    }
    s
}

/// Runs the reader on one input: its time and the error variant's name ("" for a cloud), or
/// what went wrong.
fn check(input: &[u8]) -> Result<(Duration, String), String> {
    LARGEST.store(0, Ordering::Relaxed);
    let t = Instant::now();
    let r = std::panic::catch_unwind(|| {
        let h = read_ply_header(input).map(|h| h.body_offset);
        let r = read_ply(input);
        (h, r)
    });
    let dt = t.elapsed();
    let largest = LARGEST.load(Ordering::Relaxed);
    let (h, r) = match r {
        Ok(x) => x,
        Err(p) => {
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            return Err(format!("panic: {msg}"));
        }
    };
    // Allocation proportional to the input: the largest buffer is the position array, 12 bytes
    // per vertex, and a vertex takes at least 3 input bytes, so 4x the input; allow 16x plus
    // slack for fixed-size bookkeeping.
    let limit = 16 * input.len() + (64 << 10);
    if largest > limit {
        return Err(format!(
            "allocated {largest} bytes at once for a {}-byte input",
            input.len()
        ));
    }
    if let Ok(c) = &r {
        if c.cloud.len() > input.len() / 3 {
            return Err(format!(
                "{} points from {} bytes",
                c.cloud.len(),
                input.len()
            ));
        }
        if h.is_err() {
            return Err("read_ply succeeded where read_ply_header failed".into());
        }
        if c.cloud
            .positions
            .iter()
            .any(|p| p.iter().any(|v| !v.is_finite()))
        {
            return Err("non-finite position in the cloud".into());
        }
    }
    if let Err(e) = &r {
        // Every error renders, without panicking, to a non-empty message.
        let s = std::panic::catch_unwind(|| e.to_string())
            .map_err(|_| "Display panicked".to_string())?;
        if s.is_empty() {
            return Err("empty error message".into());
        }
    }
    let kind = match &r {
        Ok(_) => String::new(),
        Err(e) => format!("{e:?}")
            .split([' ', '{'])
            .next()
            .unwrap_or("")
            .to_string(),
    };
    Ok((dt, kind))
}

/// The tests in this file share `LARGEST`; they take turns.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn huge_declared_counts_allocate_nothing_large() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let counts = [
        "2147483648",
        "4294967295",
        "9223372036854775808",
        "18446744073709551615",
    ];
    for fmt in FORMATS {
        for count in counts {
            for face_first in [false, true] {
                let face =
                    format!("element face {count}\nproperty list uchar int vertex_indices\n");
                let vcount = if face_first { "3" } else { count };
                let text = format!(
                    "ply\nformat {fmt} 1.0\n{}element vertex {vcount}\nproperty float x\n\
                     property float y\nproperty float z\n{}end_header\n{}",
                    if face_first { face.as_str() } else { "" },
                    if face_first { "" } else { face.as_str() },
                    "0 ".repeat(64),
                );
                LARGEST.store(0, Ordering::Relaxed);
                let t = Instant::now();
                let r = read_ply(text.as_bytes());
                let (dt, largest) = (t.elapsed(), LARGEST.load(Ordering::Relaxed));
                assert!(r.is_err(), "{fmt} {count} face_first={face_first}");
                assert!(
                    largest < 4096,
                    "{fmt} {count}: allocated {largest} bytes at once"
                );
                assert!(dt < Duration::from_millis(50), "{fmt} {count}: took {dt:?}");
            }
        }
    }
}

#[test]
fn fuzz_read_ply_no_panics() {
    let cases: usize = std::env::var("NKRR_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100_000);
    let seed: u64 = std::env::var("NKRR_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x6e6b_7272);
    let per_case_limit = Duration::from_millis(500);
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());

    let corpus = seeds();
    for s in &corpus {
        read_ply(s).unwrap_or_else(|e| panic!("seed does not parse: {e}\n{}", hex_dump(s)));
    }

    // Silence the default hook while panics are being caught; restore it afterwards.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));

    let mut rng = Rng(seed);
    let started = Instant::now();
    let (mut oks, mut errs, mut failures) = (0usize, 0usize, 0usize);
    let mut first_failure: Option<(usize, String, Vec<u8>)> = None;
    let mut slowest = (Duration::ZERO, 0usize);
    let mut kinds = std::collections::BTreeMap::new();
    for i in 0..cases {
        let input = match rng.below(10) {
            0 => random_body(&corpus, &mut rng),
            1 => {
                // Pure noise, sometimes behind a bare "ply\n".
                let n = rng.below(512);
                let mut b: Vec<u8> = if rng.chance(2) {
                    b"ply\n".to_vec()
                } else {
                    Vec::new()
                };
                b.extend((0..n).map(|_| rng.next() as u8));
                b
            }
            _ => {
                let base = rng.pick(&corpus).clone();
                mutate(&base, &corpus, &mut rng)
            }
        };
        match check(&input) {
            Ok((dt, kind)) => {
                if dt > slowest.0 {
                    slowest = (dt, input.len());
                }
                if dt > per_case_limit {
                    failures += 1;
                    first_failure.get_or_insert((i, format!("took {dt:?}"), input.clone()));
                } else if kind.is_empty() {
                    oks += 1;
                } else {
                    errs += 1;
                    *kinds.entry(kind).or_insert(0usize) += 1;
                }
            }
            Err(why) => {
                failures += 1;
                first_failure.get_or_insert((i, why, input.clone()));
            }
        }
    }
    let total = started.elapsed();
    std::panic::set_hook(hook);

    eprintln!(
        "ply fuzz: {cases} cases (seed {seed:#x}) in {total:.2?}: {oks} read, {errs} rejected, \
         {failures} failures; slowest case {:?} ({} bytes)",
        slowest.0, slowest.1
    );
    eprintln!("ply fuzz: rejections by error: {kinds:?}");

    if let Some((i, why, input)) = first_failure {
        panic!(
            "{failures} of {cases} fuzz cases failed; first: case {i}: {why}\ninput ({} bytes):\n{}",
            input.len(),
            hex_dump(&input)
        );
    }
}
