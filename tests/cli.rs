//! `nkrr info` as a user runs it: real scans, bad files, wrong usage.

use std::path::PathBuf;
use std::process::Command;

fn nkrr(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nkrr")).args(args).output().expect("run nkrr");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn eval(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/eval").join(name).to_string_lossy().into_owned()
}

fn temp_file(name: &str, bytes: &[u8]) -> String {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("cli");
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p.to_string_lossy().into_owned()
}

#[test]
fn info_reports_count_bounds_and_properties() {
    let (code, out, err) = nkrr(&["info", &eval("spot-10k.ply")]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("points:     10000 (declared 10000)"), "{out}");
    assert!(out.contains("binary_little_endian; x y z: float"), "{out}");
    assert!(out.contains("bounds:"), "{out}");
    assert!(out.contains("colours:    no"), "{out}");
    assert!(!out.contains("warning:"), "{out}");
}

#[test]
fn info_warns_about_dropped_points_and_extra_properties() {
    let ply = "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float intensity\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0 1\n1 0 0 1\nnan 0 0 1\n0 1 0 1\n3 0 1 3\n";
    let path = temp_file("odd.ply", ply.as_bytes());
    let (code, out, err) = nkrr(&["info", &path]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("points:     3 (declared 4)"), "{out}");
    assert!(out.contains("1 of 4 points had NaN"), "{out}");
    assert!(out.contains("ignored vertex properties: intensity"), "{out}");
    assert!(out.contains("skipped elements: face (1)"), "{out}");
    assert!(out.contains("comment:    made by hand"), "{out}");
}

#[test]
fn info_rejects_a_header_declaring_two_billion_vertices() {
    let ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 2147483648\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0";
    let path = temp_file("huge.ply", ply);
    let (code, _, err) = nkrr(&["info", &path]);
    assert_eq!(code, 1);
    assert!(err.contains("huge.ply") && err.contains("vertex"), "{err}");
}

#[test]
fn info_on_missing_file_and_bad_usage() {
    let (code, _, err) = nkrr(&["info", "/nonexistent/cloud.ply"]);
    assert_eq!(code, 1);
    assert!(err.contains("cannot read /nonexistent/cloud.ply"), "{err}");
    let (code, _, err) = nkrr(&["frobnicate"]);
    assert_eq!(code, 2);
    assert!(err.contains("unknown command 'frobnicate'") && err.contains("USAGE"), "{err}");
    let (code, _, _) = nkrr(&["info"]);
    assert_eq!(code, 2);
}
