//! The scan formats besides PLY (issue 8): every fixture in tests/fixtures/formats — written
//! by laspy/lazrs and pye57 from spot-3k.ply, see its manifest.json — read by nkrr's readers
//! and compared point by point with spot-3k.ply (plus the manifest's offset, with each E57
//! scan's pose applied) and colour by colour with the manifest's formula; content detection;
//! text clouds; units; and `nkrr reconstruct` on each format.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use nkrr::io::{read_cloud, ScanError, ScanFormat};
use serde_json::Value;

fn fixtures() -> PathBuf {
    common::repo_root().join("tests/fixtures/formats")
}

fn manifest() -> Value {
    let text = std::fs::read_to_string(fixtures().join("manifest.json")).expect("manifest.json");
    serde_json::from_str(&text).expect("manifest.json parses")
}

/// spot-3k.ply's points, in f64.
fn spot() -> Vec<[f64; 3]> {
    let bytes = std::fs::read(common::repo_root().join("tests/data/eval/spot-3k.ply")).unwrap();
    let c = nkrr::io::ply::read_ply(&bytes).unwrap().cloud;
    c.positions.iter().map(|p| p.map(f64::from)).collect()
}

fn f3(v: &Value) -> [f64; 3] {
    [0, 1, 2].map(|i| v[i].as_f64().unwrap())
}

/// The manifest's colour formula for one spot-3k point.
fn colour(p: [f64; 3], formula: &Value) -> [u8; 3] {
    let (lo, hi) = (f3(&formula["min"]), f3(&formula["max"]));
    [0, 1, 2].map(|a| (255.0 * (p[a] - lo[a]) / (hi[a] - lo[a])).round_ties_even() as u8)
}

/// The spot-3k indices a fixture holds, in file order.
fn indices(file: &Value, spot: &[[f64; 3]]) -> Vec<usize> {
    if let Some(s) = file.get("source_indices").filter(|s| s.is_object()) {
        let (a, b, step) = (s["start"].as_u64().unwrap(), s["stop"].as_u64().unwrap(), s["step"].as_u64().unwrap());
        return (a..b).step_by(step as usize).map(|i| i as usize).collect();
    }
    if let Some(split) = file.get("split") {
        let median = split["median_x"].as_f64().unwrap();
        let mut low: Vec<usize> = (0..spot.len()).filter(|&i| spot[i][0] < median).collect();
        low.extend((0..spot.len()).filter(|&i| spot[i][0] >= median));
        return low;
    }
    (0..spot.len()).collect()
}

#[test]
fn every_fixture_reads_back_as_the_source_cloud() {
    let m = manifest();
    let spot = spot();
    let formula = &m["colour_formula"];
    let files = m["files"].as_array().unwrap();
    assert!(files.len() >= 17, "{} fixtures", files.len());
    let mut seen = std::collections::BTreeSet::new();
    for file in files {
        let name = file["path"].as_str().unwrap();
        let bytes = std::fs::read(fixtures().join(name)).unwrap();
        let scan = read_cloud(&bytes, Some(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let expected_format = match file["format"].as_str().unwrap() {
            "las" | "laz" => ScanFormat::Las,
            "e57" => ScanFormat::E57,
            f => panic!("{name}: format {f}"),
        };
        assert_eq!(scan.format, expected_format, "{name}");
        if let Some(pf) = file.get("point_format").and_then(Value::as_u64) {
            seen.insert(pf);
            assert!(scan.layout.contains(&format!("point format {pf}")), "{name}: {}", scan.layout);
        }
        let idx = indices(file, &spot);
        let count = file["point_count"].as_u64().unwrap() as usize;
        assert_eq!(idx.len(), count, "{name}");
        assert_eq!(scan.cloud.len(), count, "{name}");
        let offset = f3(&file["coordinate_offset_added"]);
        let origin = scan.cloud.origin;
        // Far-off files are read relative to an origin (f32 keeps precision there).
        if offset[0] != 0.0 {
            assert!(origin[0] != 0.0 && origin[1] != 0.0, "{name}: origin {origin:?}");
        }
        let mut worst = 0f64;
        for (p, &i) in scan.cloud.positions.iter().zip(&idx) {
            for a in 0..3 {
                let got = p[a] as f64 + origin[a];
                worst = worst.max((got - (spot[i][a] + offset[a])).abs());
            }
        }
        // Quantisation (LAS scale 1e-4, E57 scaled integers 1e-6) and f32 storage.
        assert!(worst < 1e-4, "{name}: worst coordinate error {worst}");
        let has_colour = file["colour"].as_bool().unwrap();
        assert_eq!(scan.cloud.colors.is_some(), has_colour, "{name}");
        if let Some(colours) = &scan.cloud.colors {
            let mut worst = 0i32;
            for (c, &i) in colours.iter().zip(&idx) {
                let want = colour(spot[i], formula);
                for a in 0..3 {
                    worst = worst.max((c[a] as i32 - want[a] as i32).abs());
                }
                assert_eq!(c[3], 255);
            }
            assert!(worst <= 1, "{name}: colour off by {worst}/255");
        }
        if expected_format == ScanFormat::E57 {
            assert_eq!(scan.stated_units, Some(nkrr::units::Units::Metres));
            let scans = file["scans"].as_array().unwrap().len();
            assert!(scan.layout.starts_with(&format!("E57, {scans} scan")), "{name}: {}", scan.layout);
        }
    }
    assert_eq!(seen, (0..=10).collect(), "every LAS point format is covered");
}

#[test]
fn content_decides_the_format_and_a_wrong_name_is_noted() {
    let las = std::fs::read(fixtures().join("spot-las12-pf3.las")).unwrap();
    let scan = read_cloud(&las, Some("scan.ply")).unwrap();
    assert_eq!(scan.format, ScanFormat::Las);
    assert!(scan.warnings().iter().any(|w| w.contains("name says PLY")), "{:?}", scan.warnings());
    let e57 = std::fs::read(fixtures().join("spot-single.e57")).unwrap();
    assert_eq!(read_cloud(&e57, Some("cloud.xyz")).unwrap().format, ScanFormat::E57);
    let text = read_cloud(b"0 0 0\n1 0 0\n0 1 0\n0 0 1\n", Some("scan.las")).unwrap();
    assert_eq!(text.format, ScanFormat::Text);
    // Binary that is none of them: a clear error that names what the file starts with.
    let e = read_cloud(&[0x89, b'P', b'N', b'G', 0, 0, 0, 0, 1, 2], Some("photo.e57")).unwrap_err();
    assert!(matches!(e, ScanError::Unrecognised(_)), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("89 50 4e 47") && msg.contains("name says E57"), "{msg}");
    assert!(read_cloud(b"", None).unwrap_err().to_string().contains("empty"));
}

#[test]
fn a_text_export_of_the_fixture_reads_like_the_ply() {
    let spot = spot();
    let formula = &manifest()["colour_formula"];
    // CloudCompare's "//X,Y,Z,R,G,B" header, commas, colours; offset far away.
    let mut csv = String::from("//X,Y,Z,R,G,B\n");
    for p in &spot {
        let c = colour(*p, formula);
        csv.push_str(&format!("{},{},{},{},{},{}\n", p[0] + 5e6, p[1] + 5e6, p[2], c[0], c[1], c[2]));
    }
    let scan = read_cloud(csv.as_bytes(), Some("spot.csv")).unwrap();
    assert_eq!(scan.cloud.len(), spot.len());
    assert_eq!(scan.cloud.origin[0], (spot[0][0] + 5e6).round());
    let colours = scan.cloud.colors.as_ref().expect("colours");
    for ((p, c), s) in scan.cloud.positions.iter().zip(colours).zip(&spot) {
        let got = [p[0] as f64 + scan.cloud.origin[0], p[1] as f64 + scan.cloud.origin[1], p[2] as f64];
        for a in 0..3 {
            assert!((got[a] - [s[0] + 5e6, s[1] + 5e6, s[2]][a]).abs() < 1e-5);
        }
        assert_eq!(c[..3], colour(*s, formula));
    }
    // PTS: a count line, x y z intensity r g b.
    let mut pts = format!("{}\n", spot.len());
    for (i, p) in spot.iter().enumerate() {
        pts.push_str(&format!("{} {} {} {} 10 20 30\n", p[0], p[1], p[2], i as i64 - 1000));
    }
    let scan = read_cloud(pts.as_bytes(), Some("spot.pts")).unwrap();
    assert_eq!(scan.cloud.colors.as_ref().unwrap()[7], [10, 20, 30, 255]);
    assert_eq!(scan.notes, vec!["ignored columns: column 4 (intensity)".to_string()]);
}

fn run(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nkrr")).args(args).output().expect("run nkrr");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout))
}

fn out_dir() -> PathBuf {
    let d = common::repo_root().join("target/test-formats");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The box of `points`: (min, max) per axis.
fn bounds<'a>(points: impl IntoIterator<Item = &'a [f64; 3]>) -> ([f64; 3], [f64; 3]) {
    points.into_iter().fold(([f64::MAX; 3], [f64::MIN; 3]), |(lo, hi), p| {
        ([0, 1, 2].map(|a| lo[a].min(p[a])), [0, 1, 2].map(|a| hi[a].max(p[a])))
    })
}

/// The bounds of the GLB's positions, with the root translation added (f64).
fn glb_bounds(path: &Path) -> ([f64; 3], [f64; 3]) {
    bounds(&glb_vertices(path).0)
}

/// Positions (with the root translation added, f64) and COLOR_0 (if any) of a GLB.
fn glb_vertices(path: &Path) -> (Vec<[f64; 3]>, Option<Vec<[u8; 4]>>) {
    let (doc, buffers, _) = gltf::import(path).unwrap();
    let node = doc.nodes().next().unwrap();
    let t = node.transform().decomposed().0.map(f64::from);
    let prim = node.mesh().unwrap().primitives().next().unwrap();
    let reader = prim.reader(|b| Some(&buffers[b.index()]));
    let positions = reader.read_positions().unwrap().map(|p| [0, 1, 2].map(|a| p[a] as f64 + t[a])).collect();
    let colours = reader.read_colors(0).map(|c| c.into_rgba_u8().collect());
    (positions, colours)
}

/// `nkrr reconstruct` on every fixture (each LAS point format, each LAZ, each E57) and on a
/// text export: the mesh lies where the cloud does (offsets and poses applied), and where the
/// cloud has colours the mesh's COLOR_0 matches the manifest's colour ramp at each vertex; the
/// coloured GLBs pass the Khronos validator.
#[test]
fn reconstruct_reads_every_format() {
    let m = manifest();
    let formula = &m["colour_formula"];
    let spot = spot();
    let xyz = out_dir().join("spot.xyz");
    std::fs::write(&xyz, spot.iter().map(|p| format!("{} {} {}\n", p[0], p[1], p[2])).collect::<String>()).unwrap();
    let mut cases: Vec<(PathBuf, [f64; 3], bool)> = m["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            let offset = f3(&f["coordinate_offset_added"]);
            (fixtures().join(f["path"].as_str().unwrap()), offset, f["colour"].as_bool().unwrap())
        })
        .collect();
    cases.push((xyz, [0.0; 3], false));
    let (lo0, hi0) = bounds(&spot);
    let mut coloured = Vec::new();
    for (input, offset, has_colour) in cases {
        let name = input.file_name().unwrap().to_string_lossy().into_owned();
        let out = out_dir().join(format!("{name}.glb"));
        let (ok, log) = run(&["reconstruct", input.to_str().unwrap(), "--method", "network", "--resolution", "40", "-o", out.to_str().unwrap()]);
        assert!(ok, "{name}: {log}");
        let (positions, colours) = glb_vertices(&out);
        let unshifted: Vec<[f64; 3]> = positions.iter().map(|p| [0, 1, 2].map(|a| p[a] - offset[a])).collect();
        let (lo, hi) = bounds(&unshifted);
        // Points from half the shape (formats 4, 5, 9, 10 hold every other point) still span it.
        for a in 0..3 {
            let tol = 0.08 * (hi0[a] - lo0[a]);
            assert!((lo[a] - lo0[a]).abs() < tol && (hi[a] - hi0[a]).abs() < tol, "{name}: axis {a}: [{}, {}] vs [{}, {}]", lo[a], hi[a], lo0[a], hi0[a]);
        }
        assert_eq!(colours.is_some(), has_colour, "{name}");
        if let Some(colours) = colours {
            // The ramp is linear in position: a vertex's colour should be the ramp's there.
            let err: f64 = unshifted
                .iter()
                .zip(&colours)
                .map(|(p, c)| {
                    let want = colour(*p, formula);
                    (0..3).map(|a| (c[a] as f64 - want[a] as f64).abs()).sum::<f64>() / 3.0
                })
                .sum::<f64>()
                / positions.len() as f64;
            assert!(err < 6.0, "{name}: mean colour error {err:.2}/255");
            eprintln!("{name}: {} vertices, mean colour error {err:.2}/255", positions.len());
            coloured.push(out);
        }
    }
    let (ok, text) = common::run_validator(&coloured);
    assert!(ok, "Khronos validator: {text}");
}

#[test]
fn units_scale_the_mesh_to_metres_and_millimetres_are_suspected() {
    // spot, in millimetres: 1.7 m becomes 1732 units.
    let spot = spot();
    let mm = out_dir().join("spot-mm.xyz");
    std::fs::write(&mm, spot.iter().map(|p| format!("{} {} {}\n", p[0] * 1e3, p[1] * 1e3, p[2] * 1e3)).collect::<String>()).unwrap();
    let (ok, info) = run(&["info", mm.to_str().unwrap()]);
    assert!(ok, "{info}");
    assert!(info.contains("units:      mm?"), "{info}");
    let plain = out_dir().join("spot-mm-plain.glb");
    let scaled = out_dir().join("spot-mm-scaled.glb");
    let base = ["reconstruct", mm.to_str().unwrap(), "--method", "network", "--resolution", "32"];
    let (ok, log) = run(&[&base[..], &["-o", plain.to_str().unwrap()]].concat());
    assert!(ok && log.contains("--units mm"), "the run without units warns: {log}");
    let (ok, log) = run(&[&base[..], &["--units", "mm", "-o", scaled.to_str().unwrap()]].concat());
    assert!(ok && !log.contains("no --units given"), "{log}");
    let ((lo_p, hi_p), (lo_s, hi_s)) = (glb_bounds(&plain), glb_bounds(&scaled));
    for a in 0..3 {
        assert!(((hi_s[a] - lo_s[a]) * 1e3 - (hi_p[a] - lo_p[a])).abs() < 1e-3 * (hi_p[a] - lo_p[a]), "axis {a}");
    }
    let (ok, log) = run(&[&base[..], &["--units", "furlong", "-o", scaled.to_str().unwrap()]].concat());
    assert!(!ok && log.contains("--units: units must be one of mm, cm, m, in, ft, or empty for none, not 'furlong'"), "{log}");
}
