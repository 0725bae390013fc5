//! The documentation names only files that are in the repository: a render, a script or another
//! page linked from README.md or docs/ must be there in a fresh clone. (The report once named a
//! dozen renders made on a machine that kept them and lost with it.)

use std::path::{Path, PathBuf};

/// The relative file links of a Markdown text: `[text](path)` and `![alt](path)` outside fenced
/// code, whose target has a file extension (so `f](x)` in a formula is not taken for a link),
/// without a scheme or a fragment alone.
fn file_links(markdown: &str) -> Vec<String> {
    let mut links = Vec::new();
    let mut fenced = false;
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        let mut rest = line;
        while let Some(i) = rest.find("](") {
            rest = &rest[i + 2..];
            let Some(end) = rest.find(')') else { break };
            let target = rest[..end].split('#').next().unwrap_or("");
            let is_path = !target.is_empty()
                && !target.contains(':')
                && !target.contains(char::is_whitespace)
                && target.rsplit('/').next().is_some_and(|name| name.rsplit_once('.').is_some_and(|(stem, ext)| !stem.is_empty() && ext.chars().all(|c| c.is_ascii_alphanumeric()) && !ext.is_empty()));
            if is_path {
                links.push(target.to_string());
            }
            rest = &rest[end..];
        }
    }
    links
}

fn pages() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut pages = vec![root.join("README.md")];
    for dir in ["docs", "training", "scripts", "tests/data/eval"] {
        let Ok(entries) = std::fs::read_dir(root.join(dir)) else { continue };
        for e in entries.flatten() {
            if e.path().extension().is_some_and(|x| x == "md") {
                pages.push(e.path());
            }
        }
    }
    pages.sort();
    pages
}

#[test]
fn the_links_of_a_page_are_its_paths_with_extensions() {
    let text = "see [the report](docs/results.md#iPSR) and ![a render](img/a-b.png), \
                not [the site](https://example.org/x.html), f](1-wx) or [a](#anchor)\n\
                ```\n[in code](nothing.md)\n```\n[last](../scripts/render.py)";
    assert_eq!(file_links(text), ["docs/results.md", "img/a-b.png", "../scripts/render.py"]);
}

#[test]
fn every_file_the_docs_link_to_is_in_the_repository() {
    let mut missing = Vec::new();
    let mut seen = 0;
    for page in pages() {
        let text = std::fs::read_to_string(&page).expect("a readable page");
        for link in file_links(&text) {
            seen += 1;
            let path = page.parent().expect("a page in a folder").join(&link);
            if !path.exists() {
                missing.push(format!("{} names {link}", page.display()));
            }
        }
    }
    assert!(seen > 20, "only {seen} links found: the link reader is broken");
    assert!(missing.is_empty(), "linked but not in the repository:\n{}", missing.join("\n"));
}
