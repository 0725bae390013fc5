//! Helpers shared by integration tests (each test binary includes this with `mod common;`).
// Each binary uses its own part of them: what one leaves unused is not dead code.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `node tests/validate_glb.mjs` on `files`; panics (never skips) when node or the npm
/// package is missing.
pub fn run_validator(files: &[PathBuf]) -> (bool, String) {
    const SETUP: &str =
        "run `scripts/setup.sh npm` (needs node and the npm package gltf-validator)";
    match Command::new("node").arg("--version").output() {
        Ok(o) if o.status.success() => {}
        Ok(o) => panic!("`node --version` failed ({}); {SETUP}", o.status),
        Err(e) => panic!("cannot run `node` ({e}); {SETUP}"),
    }
    let root = repo_root();
    assert!(
        root.join("node_modules/gltf-validator/package.json").is_file(),
        "node_modules/gltf-validator is missing under {}; {SETUP}",
        root.display()
    );
    let out = Command::new("node")
        .current_dir(&root)
        .arg(root.join("tests/validate_glb.mjs"))
        .args(files)
        .output()
        .expect("running node");
    let text =
        format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.code() != Some(2), "the validator script could not run: {text}\n{SETUP}");
    (out.status.success(), text)
}
