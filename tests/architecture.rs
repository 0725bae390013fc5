//! The shape of the crate: data flows one way, so no file under `src/` imports from a file that
//! imports it back, directly or around a circle. A `mod.rs` counts as a file: one that
//! re-exports its children must not also hold what they import (that goes in a sibling file).
//!
//! "Imports" are `use` items and `crate::…`/`super::…`/`self::…` paths in code (comments and
//! `#[cfg(test)] mod tests` blocks are left out), resolved to the file that defines the module
//! they name.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Module path (e.g. ["krr", "tune"]; [] for lib.rs) → file.
fn module_files(src: &Path) -> BTreeMap<Vec<String>, PathBuf> {
    let mut out = BTreeMap::new();
    let mut stack = vec![src.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                if path.file_name().unwrap() != "bin" {
                    stack.push(path);
                }
                continue;
            }
            if path.extension().is_none_or(|e| e != "rs") {
                continue;
            }
            let rel = path.strip_prefix(src).unwrap().with_extension("");
            let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
            if matches!(parts.last().map(String::as_str), Some("mod" | "lib")) {
                parts.pop();
            }
            out.insert(parts, path);
        }
    }
    out
}

/// The source without comments and without the unit-test module.
fn code_of(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let b = text.as_bytes();
    let mut i = 0;
    let mut in_str = false;
    while i < b.len() {
        if in_str {
            if b[i] == b'\\' {
                i += 2;
                continue;
            }
            if b[i] == b'"' {
                in_str = false;
            }
            i += 1;
            continue;
        }
        if b[i] == b'"' {
            in_str = true;
            out.push(' ');
            i += 1;
        } else if text[i..].starts_with("//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if text[i..].starts_with("/*") {
            i = text[i..].find("*/").map_or(b.len(), |j| i + j + 2);
        } else {
            let c = text[i..].chars().next().unwrap();
            out.push(c);
            i += c.len_utf8();
        }
    }
    // The unit tests may use anything of their file's module.
    let cut = out.find("#[cfg(test)]\nmod tests").unwrap_or(out.len());
    out.truncate(cut);
    out
}

/// Expands `a::{b, c::{d, e}}` into `a::b`, `a::c::d`, `a::c::e`.
fn expand(body: &str) -> Vec<String> {
    let body = body.trim();
    let Some(open) = body.find('{') else { return vec![body.to_string()] };
    let close = body.rfind('}').unwrap_or(body.len());
    let prefix = body[..open].trim_end_matches("::").trim();
    let inner = &body[open + 1..close];
    let mut items = Vec::new();
    let (mut depth, mut start) = (0, 0);
    for (i, ch) in inner.char_indices() {
        match ch {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                items.push(&inner[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    items.push(&inner[start..]);
    items
        .into_iter()
        .filter(|s| !s.trim().is_empty())
        .flat_map(|s| expand(s).into_iter().map(|e| format!("{prefix}::{e}")).collect::<Vec<_>>())
        .collect()
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// Every path the code names: `use` items expanded, and `crate::`/`super::`/`self::` paths.
fn paths_in(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("use ") {
        let before_ok = i == 0 || !is_ident(rest[..i].chars().next_back().unwrap());
        let end = rest[i..].find(';').map_or(rest.len(), |j| i + j);
        if before_ok {
            out.extend(expand(&rest[i + 4..end]));
        }
        rest = &rest[(i + 4).min(end.max(i + 4))..];
    }
    for start in ["crate::", "super::", "self::"] {
        let mut from = 0;
        while let Some(j) = code[from..].find(start) {
            let at = from + j;
            from = at + start.len();
            if at > 0 && is_ident(code[..at].chars().next_back().unwrap()) {
                continue;
            }
            let end = code[at..].find(|c: char| !(is_ident(c) || c == ':')).map_or(code.len(), |k| at + k);
            let path = code[at..end].trim_end_matches(':');
            // `super::{a, b}` is a `use` list, expanded above; the bare prefix names nothing.
            if path.contains("::") {
                out.push(path.to_string());
            }
        }
    }
    out
}

/// The file-level import graph of `src/`.
fn graph(src: &Path) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
    let files = module_files(src);
    let resolve = |segs: &[String]| -> Option<Vec<String>> {
        (0..=segs.len()).rev().map(|i| segs[..i].to_vec()).find(|p| files.contains_key(p))
    };
    let mut edges = BTreeMap::new();
    for (module, file) in &files {
        let code = code_of(&std::fs::read_to_string(file).unwrap());
        let mut targets = BTreeSet::new();
        for path in paths_in(&code) {
            let path = path.split(" as ").next().unwrap().trim().to_string();
            let mut segs: Vec<String> = path.split("::").map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect();
            if segs.is_empty() {
                continue;
            }
            let base: Vec<String> = match segs[0].as_str() {
                "crate" => {
                    segs.remove(0);
                    Vec::new()
                }
                "super" | "self" => {
                    let mut base = module.clone();
                    while matches!(segs.first().map(String::as_str), Some("super" | "self")) {
                        if segs.remove(0) == "super" {
                            base.pop();
                        }
                    }
                    base
                }
                // A relative path (2018 edition): a child module of this one, or an outside crate.
                _ => {
                    let mut cand = module.clone();
                    cand.extend(segs.iter().cloned());
                    if let Some(r) = resolve(&cand).filter(|r| r.len() > module.len()) {
                        targets.insert(r);
                    }
                    continue;
                }
            };
            let mut full = base;
            full.extend(segs);
            if let Some(r) = resolve(&full).filter(|r| r != module) {
                targets.insert(r);
            }
        }
        edges.insert(module.clone(), targets);
    }
    edges
}

fn name(m: &[String]) -> String {
    if m.is_empty() {
        "lib".into()
    } else {
        m.join("/")
    }
}

#[test]
fn no_file_imports_a_file_that_imports_it_back() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let edges = graph(&src);
    assert!(edges.len() > 40, "found only {} modules: is the parser right?", edges.len());
    // Sanity: the parser sees known edges.
    let edge = |a: &str, b: &str| edges[&a.split('/').map(String::from).collect::<Vec<_>>()].contains(&b.split('/').map(String::from).collect::<Vec<_>>());
    assert!(edge("pipeline", "field") && edge("field", "krr") && edge("krr/tune", "krr/problem"));

    // Every cycle, by depth-first search from each module.
    let mut cycles = Vec::new();
    for start in edges.keys() {
        let mut stack = vec![(start.clone(), vec![start.clone()])];
        let mut seen = BTreeSet::new();
        while let Some((at, path)) = stack.pop() {
            for next in &edges[&at] {
                if next == start {
                    let names: Vec<String> = path.iter().map(|m| name(m)).collect();
                    cycles.push(format!("{} -> {}", names.join(" -> "), name(start)));
                } else if seen.insert(next.clone()) {
                    let mut p = path.clone();
                    p.push(next.clone());
                    stack.push((next.clone(), p));
                }
            }
        }
    }
    assert!(cycles.is_empty(), "files that import each other:\n{}", cycles.join("\n"));
}

#[test]
fn pipeline_is_orchestration_only() {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/pipeline.rs")).unwrap();
    let lines = text.lines().count();
    assert!(lines < 300, "src/pipeline.rs has {lines} lines: a stage's work belongs in its own module");
}

#[test]
fn use_lists_expand() {
    assert_eq!(expand("super::{a, b::{C, D}}"), ["super::a", "super::b::C", "super::b::D"]);
    let code = code_of("use crate::x::Y; // crate::z\nuse super::{w};\nfn f() { super::w::g(); \"crate::s\"; }\n#[cfg(test)]\nmod tests { use crate::t; }");
    let mut paths = paths_in(&code);
    paths.dedup();
    assert_eq!(paths, ["crate::x::Y", "super::w", "crate::x::Y", "super::w::g"]);
}
