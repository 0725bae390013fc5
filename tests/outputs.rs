//! What the CLI writes and prints when things go wrong: outputs replaced only whole (a failed
//! write leaves an existing file byte-identical), bad output paths refused before any work, and
//! text from a file shown with its control bytes escaped and its comments counted, not flooded.

use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_nkrr");

fn run(cmd: &mut Command) -> (i32, Vec<u8>, String, Duration) {
    let t0 = Instant::now();
    let out = cmd.output().expect("run nkrr");
    (out.status.code().unwrap_or(-1), out.stdout, String::from_utf8_lossy(&out.stderr).into_owned(), t0.elapsed())
}

fn eval(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/eval").join(name).to_string_lossy().into_owned()
}

/// A fresh, empty folder for one test.
fn folder(name: &str) -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("outputs").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[cfg(unix)]
#[test]
fn a_write_cut_short_by_a_file_size_limit_leaves_the_existing_output_intact() {
    let d = folder("ulimit");
    let out = d.join("spot.glb");
    // An existing output: any bytes, smaller than the limit, that must survive.
    let old: Vec<u8> = (0..20_000u32).map(|i| (i * 7 % 251) as u8).collect();
    std::fs::write(&out, &old).unwrap();
    // spot-3k at resolution 64 gives a GLB of about 400 KB; the limit (100 blocks of 512 or
    // 1024 bytes, by shell) stops the write at 50-100 KB.
    let script = format!(
        "ulimit -f 100; exec '{BIN}' reconstruct '{}' -o '{}' --method network --resolution 64",
        eval("spot-3k.ply"),
        out.display()
    );
    let (code, _, err, _) = run(Command::new("sh").args(["-c", &script]));
    assert_ne!(code, 0, "{err}");
    assert!(err.contains("cannot write") && err.contains("spot.glb"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), old, "the existing output changed");
    // No temporary file is left beside it.
    let names: Vec<_> = std::fs::read_dir(&d).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 1, "{names:?}");
    // Without the limit the same run succeeds and replaces the file whole.
    let (code, _, err, _) = run(Command::new(BIN).args([
        "reconstruct",
        &eval("spot-3k.ply"),
        "-o",
        &out.to_string_lossy(),
        "--method",
        "network",
        "--resolution",
        "64",
    ]));
    assert_eq!(code, 0, "{err}");
    let new = std::fs::read(&out).unwrap();
    assert!(new.len() > 100 * 1024, "the GLB ({} bytes) must exceed the limit for this test to mean anything", new.len());
    assert_eq!(&new[..4], b"glTF");
    assert_eq!(u32::from_le_bytes(new[8..12].try_into().unwrap()) as usize, new.len());
}

/// `reconstruct` with this `-o`: its exit code and stderr, after checking it did no work.
fn refused(output: &str) -> (i32, String) {
    let (code, _, err, took) = run(Command::new(BIN).args(["reconstruct", &eval("spot-3k.ply"), "-o", output]));
    assert!(!err.contains("computing features") && !err.contains("read 3000 points"), "{output}: work was done: {err}");
    assert!(took < Duration::from_secs(5), "{output}: took {took:?}");
    (code, err)
}

#[test]
fn bad_output_paths_are_refused_before_any_work() {
    let d = folder("paths");
    let missing = d.join("no/such/folder/a.glb").to_string_lossy().into_owned();
    let (code, err) = refused(&missing);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains(&missing) && err.contains("does not exist"), "{err}");

    let dir = d.join("a-folder.glb");
    std::fs::create_dir(&dir).unwrap();
    let (code, err) = refused(&dir.to_string_lossy());
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("a-folder.glb") && err.contains("is a folder"), "{err}");

    let (code, err) = refused(&d.join("a.fbx").to_string_lossy());
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(".glb, .ply, .obj or .stl"), "{err}");

    // A device has no mesh extension: refused as usage, never renamed over.
    let (code, err) = refused("/dev/full");
    assert_eq!(code, 2, "{err}");

    // eval's reports are checked the same way, before the first reconstruction.
    let prefix = d.join("missing/report").to_string_lossy().into_owned();
    let (code, _, err, took) = run(Command::new(BIN).args([
        "eval",
        &eval(""),
        "--sizes",
        "3k",
        "--methods",
        "network",
        "--shapes",
        "spot",
        "--out",
        &prefix,
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("does not exist") && !err.contains("spot-3k network"), "{err}");
    assert!(took < Duration::from_secs(5), "took {took:?}");
}

/// `reconstruct IN -o OUT` with OUT naming IN in some way: refused before any work, IN
/// byte-identical, the error naming the input.
fn input_kept(input: &std::path::Path, output: &str, original: &[u8]) {
    let (code, _, err, _) = run(Command::new(BIN).args(["reconstruct", &input.to_string_lossy(), "-o", output, "--method", "network"]));
    assert_eq!(code, 1, "{output}: {err}");
    assert!(err.contains("is the input") || err.contains("same file as the input"), "{output}: {err}");
    assert!(!err.contains("read ") && !err.contains("GPU:"), "{output}: work was done: {err}");
    assert_eq!(std::fs::read(input).unwrap(), original, "{output}: the input changed");
}

#[cfg(unix)]
#[test]
fn an_output_naming_the_input_is_refused_and_the_input_kept() {
    let d = folder("input-is-output");
    let original = std::fs::read(eval("spot-3k.ply")).unwrap();
    let cloud = d.join("in.ply");
    std::fs::write(&cloud, &original).unwrap();
    input_kept(&cloud, &cloud.to_string_lossy(), &original);
    input_kept(&cloud, &d.join(".").join("in.ply").to_string_lossy(), &original);
    std::os::unix::fs::symlink(&cloud, d.join("link.ply")).unwrap();
    input_kept(&cloud, &d.join("link.ply").to_string_lossy(), &original);
    input_kept(&d.join("link.ply"), &cloud.to_string_lossy(), &original);
    std::fs::hard_link(&cloud, d.join("hard.ply")).unwrap();
    input_kept(&cloud, &d.join("hard.ply").to_string_lossy(), &original);
    // A PLY cloud whose name says mesh: read by its content, and still not overwritten.
    for ext in ["glb", "obj", "stl"] {
        let named = d.join(format!("x.{ext}"));
        std::fs::write(&named, &original).unwrap();
        input_kept(&named, &named.to_string_lossy(), &original);
    }
    // eval: a kept mesh or report that would land on a cloud it reads.
    let data = d.join("data");
    std::fs::create_dir(&data).unwrap();
    std::fs::copy(eval("spot.obj"), data.join("spot.obj")).unwrap();
    std::fs::write(data.join("spot-3k.ply"), &original).unwrap();
    std::os::unix::fs::symlink(data.join("spot-3k.ply"), d.join("r.json")).unwrap();
    let (code, _, err, _) = run(Command::new(BIN).args([
        "eval",
        &data.to_string_lossy(),
        "--sizes",
        "3k",
        "--methods",
        "network",
        "--out",
        &d.join("r").to_string_lossy(),
    ]));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("same file as the input") && err.contains("spot-3k.ply"), "{err}");
    assert_eq!(std::fs::read(data.join("spot-3k.ply")).unwrap(), original);
}

fn ply_with_comments(comments: &[String]) -> Vec<u8> {
    let mut s = String::from("ply\nformat ascii 1.0\n");
    for c in comments {
        s += &format!("comment {c}\n");
    }
    s += "element vertex 4\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n";
    s.into_bytes()
}

#[test]
fn control_bytes_from_a_file_are_shown_escaped() {
    let d = folder("controls");
    let path = d.join("title.ply");
    std::fs::write(&path, ply_with_comments(&["\x1b]0;pwned\x07 and \u{9b}2J".to_string()])).unwrap();
    let (code, out, err, _) = run(Command::new(BIN).args(["info", &path.to_string_lossy()]));
    assert_eq!(code, 0, "{err}");
    let text = String::from_utf8(out).unwrap();
    assert!(!text.contains(['\x1b', '\x07', '\u{9b}']), "raw control bytes: {text:?}");
    assert!(text.contains("comment:    \\x1b]0;pwned\\x07 and \\u{9b}2J"), "{text}");

    // A file name with an escape sequence, in an error message.
    let name = d.join("clear\x1b[2J.ply").to_string_lossy().into_owned();
    let (code, _, err, _) = run(Command::new(BIN).args(["info", &name]));
    assert_eq!(code, 1);
    assert!(!err.contains('\x1b'), "{err:?}");
    assert!(err.contains("clear\\x1b[2J.ply"), "{err}");
}

#[test]
fn info_counts_header_comments_instead_of_printing_them_all() {
    let d = folder("comments");
    let path = d.join("chatty.ply");
    let comments: Vec<String> = (0..100_000).map(|i| format!("note {i}")).collect();
    std::fs::write(&path, ply_with_comments(&comments)).unwrap();
    let (code, out, err, _) = run(Command::new(BIN).args(["info", &path.to_string_lossy()]));
    assert_eq!(code, 0, "{err}");
    let text = String::from_utf8(out).unwrap();
    assert!(text.lines().count() < 60, "{} lines", text.lines().count());
    assert!(text.contains("comment:    note 0\n"), "{text}");
    assert!(text.contains("and 99990 more comments"), "{text}");
    assert!(!text.contains("note 99999"), "{text}");
}
