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
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/eval").join(name).to_string_lossy().into_owned()
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
    assert!(out.contains("points:     10000 (in the file: 10000)"), "{out}");
    assert!(out.contains("units:      m? (a guess: --units sets them): the longest side is 1.7"), "{out}");
    assert!(out.contains("normals:    no (not needed"), "{out}");
    // The preflight: every stage, the adapter's limit, and that it fits as set.
    for stage in ["load", "features", "pairs", "tuning", "meshing"] {
        assert!(out.contains(&format!("memory:     {stage}")), "{stage}: {out}");
    }
    assert!(out.contains("memory:     fits: 10000 points, m = 500, as set"), "{out}");
    assert!(out.contains("binary_little_endian; x y z: float"), "{out}");
    assert!(out.contains("bounds:"), "{out}");
    assert!(out.contains("colours:    no"), "{out}");
    assert!(!out.contains("warning:"), "{out}");
}

#[test]
fn info_plans_a_scenes_memory_by_its_largest_tile() {
    // The committed small room, tiled when asked: the preflight is the largest tile's, under
    // what a tile runs (the network; the regression per tile when asked for).
    let room = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/scenes/room-small.laz").to_string_lossy().into_owned();
    let (code, out, err) = nkrr(&["info", &room, "--tiles", "on"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("one tile at a time, the largest taking in"), "{out}");
    assert!(out.contains("memory:     meshing") && !out.contains("memory:     tuning"), "{out}");
    let (code, out, err) = nkrr(&["info", &room, "--tiles", "on", "--tile-regression"]);
    assert_eq!(code, 0, "{err}");
    for stage in ["pairs", "tuning", "meshing"] {
        assert!(out.contains(&format!("memory:     {stage}")), "{stage}: {out}");
    }
}

#[test]
fn info_warns_about_dropped_points_and_extra_properties() {
    let ply = "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float intensity\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0 1\n1 0 0 1\nnan 0 0 1\n0 1 0 1\n3 0 1 3\n";
    let path = temp_file("odd.ply", ply.as_bytes());
    let (code, out, err) = nkrr(&["info", &path]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("points:     3 (in the file: 4)"), "{out}");
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

#[test]
fn info_says_what_will_be_done_where_memory_does_not_fit() {
    // m = 5000 on the GPU objective: the m×m accumulator (300 MB) exceeds a 128 MiB binding
    // (lavapipe's limit); the plan lowers m and says so.
    let (code, out, err) = nkrr(&["info", &eval("spot-3k.ply"), "--krr-backend", "gpu", "--m", "5000"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("memory:     will use m = "), "{out}");
}

/// The closed box [lo, hi] as OBJ text (12 triangles), optionally without its last triangle.
fn box_obj(lo: [f64; 3], hi: [f64; 3], open: bool) -> String {
    let mut s = String::new();
    for i in 0..8 {
        let p = [0, 1, 2].map(|a| if (i >> a) & 1 == 1 { hi[a] } else { lo[a] });
        s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    let quads = [[1, 3, 4, 2], [5, 6, 8, 7], [1, 2, 6, 5], [3, 7, 8, 4], [1, 5, 7, 3], [2, 4, 8, 6]];
    for (k, q) in quads.iter().enumerate() {
        if open && k == 5 {
            s += &format!("f {} {} {}\n", q[0], q[1], q[2]);
        } else {
            s += &format!("f {} {} {} {}\n", q[0], q[1], q[2], q[3]); // a quad: fan-triangulated
        }
    }
    s
}

/// A number from one `"key": value` of a JSON line.
fn field(line: &str, key: &str) -> String {
    let at = line.find(&format!("\"{key}\": ")).unwrap_or_else(|| panic!("no {key} in {line}")) + key.len() + 4;
    line[at..].split([',', '}']).next().unwrap().trim().to_string()
}

#[test]
fn metrics_prints_one_json_line_per_reconstruction() {
    let gt = temp_file("box.obj", box_obj([0.0; 3], [1.0; 3], false).as_bytes());
    let same = temp_file("box-same.obj", box_obj([0.0; 3], [1.0; 3], false).as_bytes());
    // The reconstruction as GLB: the box moved by 5 % along x (IoU 0.95 / 1.05).
    let shifted = nkrr::io::obj::read_obj(box_obj([0.05, 0.0, 0.0], [1.05, 1.0, 1.0], false).as_bytes()).unwrap();
    let glb = temp_file("box-shifted.glb", &nkrr::io::gltf::write_glb(&shifted, &Default::default()).unwrap());
    let (code, out, err) = nkrr(&["metrics", &gt, &same, &glb]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 2, "{out}");
    assert!(lines[0].starts_with('{') && lines[0].ends_with('}'), "{out}");
    assert_eq!(field(lines[0], "iou"), "1.0000");
    assert_eq!(field(lines[0], "watertight"), "true");
    assert!(field(lines[0], "fscore").parse::<f64>().unwrap() > 0.99, "{out}");
    assert!(field(lines[0], "cd1x100").parse::<f64>().unwrap() < 0.5, "{out}");
    let iou: f64 = field(lines[1], "iou").parse().unwrap();
    assert!((iou - 0.95 / 1.05).abs() < 0.006, "{out}");
    assert!(field(lines[1], "recon").contains("box-shifted.glb"), "{out}");
    assert_eq!(field(lines[1], "faces"), "12");
    for key in ["cd1x100", "fscore", "nc", "iou", "watertight"] {
        field(lines[1], key);
    }
    // An open ground truth: no IoU.
    let open = temp_file("box-open.obj", box_obj([0.0; 3], [1.0; 3], true).as_bytes());
    let (code, out, err) = nkrr(&["metrics", &open, &same]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(field(&out, "iou"), "null");
    assert_eq!(field(&out, "gt_watertight"), "false");
}

#[test]
fn metrics_and_eval_usage_errors() {
    let gt = temp_file("box2.obj", box_obj([0.0; 3], [1.0; 3], false).as_bytes());
    let bad = temp_file("bad.obj", b"v 0 0 0\nf 1 2 3\n");
    for args in [&["metrics"][..], &["metrics", &gt], &["metrics", &gt, "--frob", &gt], &["metrics", &gt, "x.stl"]] {
        let (code, _, err) = nkrr(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains("USAGE"), "{err}");
    }
    let (code, _, err) = nkrr(&["metrics", &gt, "/nonexistent/r.glb"]);
    assert_eq!(code, 1);
    assert!(err.contains("cannot read /nonexistent/r.glb"), "{err}");
    let (code, _, err) = nkrr(&["metrics", &bad, &gt]);
    assert_eq!(code, 1);
    assert!(err.contains("bad.obj: line 2") && err.contains("out of range"), "{err}");

    let dir = eval("");
    for args in [&["eval"][..], &["eval", &dir, "--methods", "nkrr,bogus"], &["eval", &dir, "--method", "nkrr"], &["eval", &dir, "--resolution", "8"], &["eval", &dir, "extra"]] {
        let (code, _, err) = nkrr(args);
        assert_eq!(code, 2, "{args:?}: {err}");
    }
    let (code, _, err) = nkrr(&["eval", "/nonexistent/dir"]);
    assert_eq!(code, 1);
    assert!(err.contains("cannot read directory"), "{err}");
    let (code, _, err) = nkrr(&["eval", &dir, "--sizes", "7k"]);
    assert_eq!(code, 1);
    assert!(err.contains("no NAME.obj with a NAME-SIZE.ply"), "{err}");
}

/// One real run of `eval` (network prior only, coarse grid): the report files and their shape.
#[test]
fn eval_writes_markdown_and_json() {
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("cli").join("eval-small");
    std::fs::create_dir_all(out.parent().unwrap()).unwrap();
    let out = out.to_string_lossy().into_owned();
    let (code, stdout, err) =
        nkrr(&["eval", &eval(""), "--shapes", "cow", "--sizes", "3k", "--methods", "network", "--resolution", "32", "--out", &out]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("1 runs"), "{stdout}");
    let md = std::fs::read_to_string(format!("{out}.md")).unwrap();
    assert!(md.contains("## 3k points") && md.contains("| cow | network |") && md.contains("| **mean** | network |"), "{md}");
    let json = std::fs::read_to_string(format!("{out}.json")).unwrap();
    assert!(json.contains("\"shape\": \"cow\"") && json.contains("\"method\": \"network\""), "{json}");
    let iou: f64 = field(&json, "iou").parse().unwrap();
    assert!(iou > 0.5, "{json}"); // cow is watertight; even a 32³ grid gets most of it
    for key in ["cd1x100", "fscore", "nc", "features", "mesh", "total", "metrics"] {
        field(&json, key);
    }
}

#[test]
fn reconstruct_writes_ply_obj_and_stl_by_extension() {
    let dir = std::env::temp_dir().join(format!("nkrr-cli-formats-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cloud = eval("spot-3k.ply");
    let out = |ext: &str| dir.join(format!("spot.{ext}")).to_string_lossy().into_owned();
    let mut counts = Vec::new();
    for ext in ["glb", "ply", "obj", "stl"] {
        let (code, stdout, stderr) =
            nkrr(&["reconstruct", &cloud, "-o", &out(ext), "--method", "network", "--resolution", "32"]);
        assert_eq!(code, 0, "{ext}: {stderr}");
        assert!(stdout.contains("watertight: yes"), "{ext}: {stdout}");
        let tris: usize = stdout.split(" triangles").next().unwrap().rsplit(' ').next().unwrap().parse().unwrap();
        counts.push(tris);
    }
    // The same reconstruction each time (the pipeline is deterministic).
    assert!(counts.windows(2).all(|w| w[0] == w[1]), "triangle counts {counts:?}");
    let tris = counts[0];
    // OBJ: read back by our reader, closed and consistently oriented.
    let obj = nkrr::io::obj::read_obj(&std::fs::read(out("obj")).unwrap()).unwrap();
    assert_eq!(obj.indices.len() / 3, tris);
    assert!(obj.is_watertight());
    // PLY: our reader sees the vertices with their normals; the faces follow them.
    let ply_bytes = std::fs::read(out("ply")).unwrap();
    let ply = nkrr::io::ply::read_ply(&ply_bytes).unwrap();
    assert_eq!(ply.cloud.positions.len(), obj.positions.len());
    assert!(ply.cloud.normals.is_some());
    assert!(String::from_utf8_lossy(&ply_bytes[..400]).contains(&format!("element face {tris}\n")));
    // STL: 84 + 50 bytes per triangle.
    assert_eq!(std::fs::metadata(out("stl")).unwrap().len() as usize, 84 + 50 * tris);
    // An unknown extension is a usage error before any work.
    let (code, _, stderr) = nkrr(&["reconstruct", &cloud, "-o", &out("fbx")]);
    assert_eq!(code, 2);
    assert!(stderr.contains(".glb, .ply, .obj or .stl"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn no_graphics_stack_noise_without_xdg_runtime_dir() {
    // Root in a container and CI runners often have no XDG_RUNTIME_DIR; the run succeeds, so
    // nothing on stderr may read like an error.
    let out = Command::new(env!("CARGO_BIN_EXE_nkrr")).arg("gpu").env_remove("XDG_RUNTIME_DIR").output().expect("run nkrr");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}

/// A cloud the prior sees no closed object in (two tight clusters far apart): the run fails
/// with why, not with "cannot write an empty mesh" (issue 16), and writes nothing.
#[test]
fn no_surface_says_why() {
    let mut text = String::new();
    let mut rng = nkrr::rng::SplitMix64(7);
    for i in 0..1000 {
        let c = if i % 2 == 0 { 0.0 } else { 10.0 };
        text.push_str(&format!("{} {} {}\n", c + 0.01 * rng.normal(), c + 0.01 * rng.normal(), c + 0.01 * rng.normal()));
    }
    let cloud = temp_file("two-clusters.xyz", text.as_bytes());
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("cli").join("two-clusters.glb");
    let _ = std::fs::remove_file(&out);
    let (code, _, err) = nkrr(&["reconstruct", &cloud, "-o", out.to_str().unwrap(), "--method", "network"]);
    assert_ne!(code, 0);
    assert!(err.contains("no surface found") && err.contains("nothing is inside anywhere"), "{err}");
    assert!(!err.contains("empty mesh"), "{err}");
    assert!(!out.exists(), "nothing is written");
}

#[test]
fn simplified_and_compressed_glbs_keep_the_surface() {
    // The web-viewer outputs on a 10k eval cloud: a meshopt-compressed GLB at most a quarter of
    // the plain one's size at the same triangles, and one simplified to 10 % of them within
    // 0.02 CD1 x100 of the full mesh; both read back closed by `nkrr metrics`.
    let dir = std::env::temp_dir().join(format!("nkrr-cli-compact-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cloud = eval("spot-10k.ply");
    let out = |name: &str| dir.join(name).to_string_lossy().into_owned();
    let run = |name: &str, extra: &[&str]| -> usize {
        let o = out(name);
        let mut args = vec!["reconstruct", &cloud, "-o", &o, "--method", "network"];
        args.extend_from_slice(extra);
        let (code, stdout, stderr) = nkrr(&args);
        assert_eq!(code, 0, "{name}: {stderr}");
        assert!(stdout.contains("watertight: yes"), "{name}: {stdout}");
        stdout.split(" triangles").next().unwrap().rsplit(' ').next().unwrap().parse().unwrap()
    };
    let full = run("plain.glb", &[]);
    assert_eq!(run("meshopt.glb", &["--glb", "meshopt"]), full);
    let tenth = (full / 10).to_string();
    let simplified = run("simplified.glb", &["--glb", "meshopt", "--triangles", &tenth]);
    assert!(simplified <= full / 10 && simplified > full / 12, "{simplified} of {full}");
    let size = |name: &str| std::fs::metadata(out(name)).unwrap().len();
    assert!(4 * size("meshopt.glb") <= size("plain.glb"), "{} vs {}", size("meshopt.glb"), size("plain.glb"));
    let (code, stdout, stderr) = nkrr(&["metrics", &eval("spot.obj"), &out("plain.glb"), &out("meshopt.glb"), &out("simplified.glb")]);
    assert_eq!(code, 0, "{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    let cd: Vec<f64> = lines.iter().map(|l| field(l, "cd1x100").parse().unwrap()).collect();
    assert!(lines.iter().all(|l| field(l, "watertight") == "true"), "{stdout}");
    assert!((cd[1] - cd[0]).abs() < 0.005, "compression moved the surface: {cd:?}");
    assert!(cd[2] - cd[0] < 0.02, "simplification lost too much: {cd:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn weights_flag_uses_the_given_prior_and_rejects_bad_files() {
    let dir = std::env::temp_dir().join(format!("nkrr-cli-weights-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cloud = eval("spot-3k.ply");
    let prior = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/prior.safetensors");
    let prior_bytes = std::fs::read(&prior).unwrap();
    let run = |name: &str, weights: Option<&str>| -> Vec<u8> {
        let out = dir.join(name).to_string_lossy().into_owned();
        // The field's own mesh: a Poisson surface takes only its normals' signs from the prior.
        let mut args = vec!["reconstruct", &cloud, "-o", &out, "--method", "network", "--resolution", "32", "--surface", "field"];
        if let Some(w) = weights {
            args.extend(["--weights", w]);
        }
        let (code, _, stderr) = nkrr(&args);
        assert_eq!(code, 0, "{name}: {stderr}");
        std::fs::read(&out).unwrap()
    };
    // The built-in prior given as a file: the same mesh, byte for byte.
    let builtin = run("builtin.ply", None);
    assert_eq!(run("file.ply", Some(prior.to_str().unwrap())), builtin);
    // Another prior of the same format (the last weight of the file changed): another mesh,
    // so the file is what the network runs with.
    let mut other = prior_bytes.clone();
    let n = other.len();
    other[n - 4..].copy_from_slice(&25.0f32.to_le_bytes());
    let other_path = temp_file("nkrr-other-prior.safetensors", &other);
    assert_ne!(run("other.ply", Some(&other_path)), builtin);
    // A missing file and a damaged one: errors that name the flag and the file, before any work.
    let missing = dir.join("missing.safetensors").to_string_lossy().into_owned();
    let out = dir.join("never.glb").to_string_lossy().into_owned();
    let (code, _, stderr) = nkrr(&["reconstruct", &cloud, "-o", &out, "--weights", &missing]);
    assert_ne!(code, 0);
    assert!(stderr.contains(&format!("--weights {missing}: cannot read it")), "{stderr}");
    let cut = temp_file("nkrr-cut-prior.safetensors", &prior_bytes[..prior_bytes.len() / 2]);
    let (code, _, stderr) = nkrr(&["eval", &eval(""), "--weights", &cut]);
    assert_ne!(code, 0);
    assert!(stderr.contains("not a network prior nkrr can use"), "{stderr}");
    assert!(!std::path::Path::new(&out).exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A setting the run will not use is said before any work, one rule for every setting of the
/// table (it was dropped without a word: `--glb meshopt` with an `.stl`).
#[test]
fn settings_that_do_not_apply_are_warned_of() {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("cli");
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("unused.stl").to_string_lossy().into_owned();
    let (code, _, err) = nkrr(&[
        "reconstruct", &eval("spot-3k.ply"), "-o", &out, "--method", "network", "--resolution", "32", "--glb", "meshopt", "--m", "800",
        "--no-tune", "--two-layers", "--detail", "0.01", "--tile-regression",
    ]);
    assert_eq!(code, 0, "{err}");
    // Scene settings on a cloud reconstructed as one object (decided from the cloud, so said
    // after it is read).
    assert!(err.contains("--two-layers is for scenes in tiles"), "{err}");
    assert!(err.contains("--detail 0.01 is for scenes in tiles"), "{err}");
    let first = err.lines().position(|l| l.starts_with("read ")).unwrap();
    let before: Vec<&str> = err.lines().take(first).collect();
    assert!(before.contains(&"warning: --glb meshopt has no effect and is ignored: it needs a .glb output"), "{err}");
    assert!(before.contains(&"warning: --m 800 has no effect and is ignored: it needs the nkrr method (--method nkrr)"), "{err}");
    assert!(before.contains(&"warning: --steps 0 has no effect and is ignored: it needs the nkrr method (--method nkrr)"), "{err}");
    assert!(before.contains(&"warning: --tile-regression has no effect and is ignored: it needs the nkrr method (--method nkrr)"), "{err}");
    // Settings that apply, and defaults, are not mentioned.
    let glb = dir.join("used.glb").to_string_lossy().into_owned();
    let (code, _, err) = nkrr(&["reconstruct", &eval("spot-3k.ply"), "-o", &glb, "--method", "network", "--resolution", "32", "--glb", "meshopt"]);
    assert_eq!(code, 0, "{err}");
    assert!(!err.contains("no effect"), "{err}");
}

/// `--m 5000 --tune-pairs 1000`: the preflight names the m the run will use and why, as the run
/// does (it ran with m 1000 and said so only inside the tuning summary).
#[test]
fn the_preflight_names_an_m_capped_by_the_tuning_pairs() {
    let (code, out, err) = nkrr(&["info", &eval("spot-3k.ply"), "--m", "5000", "--tune-pairs", "1000"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("memory:     will use m = 1000 inducing points, not 5000: the tuning sees 1000 training pairs (--tune-pairs 1000"), "{out}");
    assert!(!out.contains("fits:"), "{out}");
    let (code, out, _) = nkrr(&["info", &eval("spot-3k.ply"), "--m", "800"]);
    assert_eq!(code, 0);
    assert!(out.contains("memory:     fits: 3000 points, m = 800, as set"), "{out}");
}
