//! What a reconstruction carries besides the surface (issue 8): vertex colours from a coloured
//! cloud, trimming the closing bubble of a one-sided scan, and far-off (georeferenced) clouds.
//! Each test runs the real pipeline (the network prior at resolution 64, which is quick on
//! lavapipe) on `tests/data/eval/spot-10k.ply`.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use gltf::json::Value;
use nkrr::io::gltf::{write_glb, GlbOptions};
use nkrr::mesh::finish::Closure;
use nkrr::mesh::Mesh;
use nkrr::pipeline::{Engine, Reconstruction};
use nkrr::settings::{Method, Settings, Surface};
use nkrr::sample::{mean_spacing, PointIndex};
use nkrr::PointCloud;

fn spot() -> PointCloud {
    let path = common::repo_root().join("tests/data/eval/spot-10k.ply");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    nkrr::io::ply::read_ply(&bytes).unwrap().cloud
}

fn settings() -> Settings {
    Settings { method: Method::Network, resolution: 64, ..Settings::default() }
}

fn reconstruct(cloud: &PointCloud, settings: &Settings) -> Reconstruction {
    let gpu = nkrr::gpu::Gpu::new_blocking().expect("a wgpu adapter (lavapipe will do)");
    let engine = pollster::block_on(Engine::new(gpu)).unwrap();
    pollster::block_on(engine.reconstruct(cloud, settings, &mut |_| true)).unwrap()
}

/// Runs the `nkrr` binary: (exit code, stderr).
fn cli(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_nkrr")).args(args).output().expect("run nkrr");
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
}

fn out_dir() -> PathBuf {
    let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("reconstruct");
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Binary little-endian PLY of positions (as `double` when `offset` is given, with the offset
/// added in f64) and optional colours.
fn ply_bytes(points: &[[f32; 3]], colors: Option<&[[u8; 4]]>, offset: Option<[f64; 3]>) -> Vec<u8> {
    let ty = if offset.is_some() { "double" } else { "float" };
    let mut h = format!("ply\nformat binary_little_endian 1.0\nelement vertex {}\n", points.len());
    for a in ["x", "y", "z"] {
        h += &format!("property {ty} {a}\n");
    }
    if colors.is_some() {
        h += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    h += "end_header\n";
    let mut b = h.into_bytes();
    for (i, p) in points.iter().enumerate() {
        for a in 0..3 {
            match offset {
                Some(o) => b.extend_from_slice(&(p[a] as f64 + o[a]).to_le_bytes()),
                None => b.extend_from_slice(&p[a].to_le_bytes()),
            }
        }
        if let Some(c) = colors {
            b.extend_from_slice(&c[i][..3]);
        }
    }
    b
}

/// What the GLB holds: positions as the buffer has them, the root node's translation (read as
/// f64 from the JSON, which the `gltf` crate would round to f32), indices and colours.
struct Glb {
    positions: Vec<[f32; 3]>,
    translation: Option<[f64; 3]>,
    indices: Vec<u32>,
    colors: Option<Vec<[u8; 4]>>,
}

fn read_glb(bytes: &[u8]) -> Glb {
    let (doc, buffers, _) = gltf::import_slice(bytes).expect("the gltf crate imports the GLB");
    let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
    let r = prim.reader(|b| Some(&buffers[b.index()]));
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json: Value = gltf::json::deserialize::from_slice(&bytes[20..20 + json_len]).unwrap();
    let translation = json["nodes"][0].get("translation").map(|t| {
        let t = t.as_array().unwrap();
        [0, 1, 2].map(|a| t[a].as_f64().unwrap())
    });
    Glb {
        positions: r.read_positions().unwrap().collect(),
        translation,
        indices: r.read_indices().unwrap().into_u32().collect(),
        colors: r.read_colors(0).map(|c| c.into_rgba_u8().collect()),
    }
}

fn validate(files: &[PathBuf]) {
    let (ok, text) = common::run_validator(files);
    println!("{text}");
    assert!(ok && text.contains("TOTAL errors=0 warnings=0"), "the glTF validator complained:\n{text}");
}

fn bounds(points: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// Undirected edges used by exactly one triangle.
fn boundary_edges(indices: &[u32]) -> usize {
    let mut count = std::collections::HashMap::new();
    for t in indices.chunks_exact(3) {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            *count.entry((a.min(b), a.max(b))).or_insert(0usize) += 1;
        }
    }
    count.values().filter(|&&c| c == 1).count()
}

fn centroids(mesh: &Mesh) -> Vec<[f32; 3]> {
    mesh.indices
        .chunks_exact(3)
        .map(|t| {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| mesh.positions[i as usize]);
            [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0)
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Colours

/// A colour field linear in position: each channel runs 0..255 across the cloud's bounds along
/// one axis (red along x, green along y, blue along z).
struct Field {
    lo: [f32; 3],
    hi: [f32; 3],
}

impl Field {
    fn at(&self, p: [f32; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| 255.0 * (p[a] - self.lo[a]) as f64 / (self.hi[a] - self.lo[a]) as f64)
    }
    /// Colour units per unit of length along each axis.
    fn gradient(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| 255.0 / (self.hi[a] - self.lo[a]) as f64)
    }
}

#[test]
fn vertex_colours_follow_the_clouds_colour_field() {
    let mut cloud = spot();
    let (lo, hi) = bounds(&cloud.positions);
    let field = Field { lo, hi };
    let colors: Vec<[u8; 4]> = cloud
        .positions
        .iter()
        .map(|&p| {
            let c = field.at(p).map(|x| x.round().clamp(0.0, 255.0) as u8);
            [c[0], c[1], c[2], 255]
        })
        .collect();
    cloud.colors = Some(colors.clone());
    // The PLY reader's colour path too: write the coloured cloud, read it back.
    let dir = out_dir();
    let ply = ply_bytes(&cloud.positions, Some(&colors), None);
    write(&dir, "spot-coloured.ply", &ply);
    let cloud = nkrr::io::ply::read_ply(&ply).unwrap().cloud;
    assert_eq!(cloud.colors.as_deref(), Some(&colors[..]));

    let rec = reconstruct(&cloud, &settings());
    let glb_bytes = write_glb(&rec.mesh, &GlbOptions { translation: rec.translation(), ..Default::default() }).unwrap();
    let path = write(&dir, "spot-coloured.glb", &glb_bytes);
    validate(&[path]);
    let glb = read_glb(&glb_bytes);
    assert_eq!(glb.translation, None);
    let got = glb.colors.expect("the GLB has COLOR_0");
    assert_eq!(got.len(), glb.positions.len());

    // Per vertex, a convex combination of the k nearest points' colours can be no farther from
    // the field at the vertex than the field varies over those points (|gradient| x distance to
    // the k-th), plus the rounding of the cloud's colours and of the result (0.5 each).
    let index = PointIndex::new(&cloud.positions);
    let g = field.gradient();
    let mut near = Vec::new();
    let (mut sum, mut sum_nearest, mut worst, mut n) = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for (p, c) in glb.positions.iter().zip(&got) {
        assert_eq!(c[3], 255);
        index.k_nearest(*p, nkrr::mesh::colour::DEFAULT_K, &mut near);
        let reach = near.last().unwrap().0.sqrt() as f64;
        let want = field.at(*p);
        // What copying the nearest point's colour would give (the simplest transfer).
        let nearest = colors[near[0].1 as usize];
        for a in 0..3 {
            sum_nearest += (nearest[a] as f64 - want[a]).abs();
            let e = (c[a] as f64 - want[a]).abs();
            assert!(e <= g[a] * reach + 1.0 + 1e-9, "vertex {p:?} channel {a}: {} vs {:.2}, bound {:.2}", c[a], want[a], g[a] * reach + 1.0);
            sum += e;
            worst = worst.max(e);
            n += 1;
        }
    }
    let mean = sum / n as f64;
    let mean_nearest = sum_nearest / n as f64;
    let spacing = mean_spacing(&cloud.positions) as f64;
    println!(
        "colour transfer: {} vertices, mean |error| {mean:.3} (of 255; nearest point's colour: \
         {mean_nearest:.3}), worst {worst:.1}; gradient {:.0}/{:.0}/{:.0} per unit, point spacing {spacing:.4}",
        got.len(),
        g[0],
        g[1],
        g[2]
    );
    // The error has two sources: rounding (of the result: 0.25 on average; the cloud's own
    // rounding mostly averages out over 8 points) and the field's change between a vertex and
    // the points it averages. Those lie around the vertex, about a spacing (0.016) away, so
    // their offsets mostly cancel; what does not is the vertex's distance from the sampled
    // surface (the reconstruction's error plus the cloud's noise, sigma 0.009), times the
    // gradient (150-260 per unit). Measured 1.16 with 1/d² weights (network, resolution 64);
    // copying the nearest point's colour gives 1.63: the averaging must beat it, and stay below
    // 1.5 (0.6 % of the range).
    // The switch, through the CLI: --no-colors writes no COLOR_0.
    let plain = dir.join("spot-plain.glb");
    let (code, err) = cli(&["reconstruct", dir.join("spot-coloured.ply").to_str().unwrap(), "-o", plain.to_str().unwrap(), "--method", "network", "--resolution", "64", "--no-colors"]);
    assert_eq!(code, 0, "{err}");
    let plain = read_glb(&std::fs::read(&plain).unwrap());
    assert!(plain.colors.is_none());
    assert_eq!(plain.positions, glb.positions);

    assert!(mean < mean_nearest, "averaging ({mean:.3}) is no better than the nearest colour ({mean_nearest:.3})");
    assert!(mean < 1.5, "mean colour error {mean:.3}");
}

// ---------------------------------------------------------------------------------------------
// Trim

#[test]
fn trim_opens_a_one_sided_scan() {
    let cloud = spot();
    let (lo, hi) = bounds(&cloud.positions);
    let cx = 0.5 * (lo[0] + hi[0]);
    // The half of the cow that faces +x: a scan from one side.
    let half = PointCloud { positions: cloud.positions.iter().copied().filter(|p| p[0] > cx).collect(), ..Default::default() };
    let dir = out_dir();
    write(&dir, "spot-half.ply", &ply_bytes(&half.positions, None, None));

    // The field's level set as asked (`--surface auto` opens a one-sided scan's fill between
    // its sheets by itself: `a_one_sided_scan_keeps_the_fields_level_set`).
    let field = Settings { surface: Surface::Field, ..settings() };
    let before = reconstruct(&half, &field);
    let factor = nkrr::mesh::trim::DEFAULT_TRIM;
    let after = reconstruct(&half, &Settings { trim: Some(factor), colors: false, ..field.clone() });
    for (name, rec) in [("spot-half-before.glb", &before), ("spot-half-after.glb", &after)] {
        let glb = write_glb(&rec.mesh, &GlbOptions::default()).unwrap();
        write(&dir, name, &glb);
    }
    validate(&[dir.join("spot-half-after.glb")]);
    // The CLI: `--trim` without a number is the default factor; a bad factor is a usage error.
    let half_ply = dir.join("spot-half.ply");
    let cli_glb = dir.join("spot-half-cli.glb");
    let (code, err) = cli(&["reconstruct", half_ply.to_str().unwrap(), "--trim", "-o", cli_glb.to_str().unwrap(), "--method", "network", "--resolution", "64", "--surface", "field"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("trimmed"), "{err}");
    assert_eq!(read_glb(&std::fs::read(&cli_glb).unwrap()).indices.len(), after.mesh.indices.len());
    let (code, err) = cli(&["reconstruct", half_ply.to_str().unwrap(), "-o", cli_glb.to_str().unwrap(), "--trim", "-1"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--trim: trim must be a number from 0.1 to 1000, or 0 for off, not -1"), "{err}");

    let (b, a) = (&before.mesh, &after.mesh);
    assert!(before.trim.is_none() && b.is_watertight(), "untrimmed output stays watertight");
    let report = after.trim.clone().expect("a trim report");
    assert!(a.colors.is_none());
    // Re-indexed: every vertex used, normals kept one per vertex.
    let mut used = vec![false; a.vertex_count()];
    a.indices.iter().for_each(|&i| used[i as usize] = true);
    assert!(used.iter().all(|&u| u), "unused vertices after trimming");
    assert_eq!(a.normals.len(), a.vertex_count());
    assert_eq!(b.triangle_count() - a.triangle_count(), report.triangles_removed);
    assert_eq!(b.vertex_count() - a.vertex_count(), report.vertices_removed);

    // Open: it has a boundary now.
    let open_edges = boundary_edges(&a.indices);
    assert!(!a.is_watertight() && open_edges > 0);

    // In user coordinates: the threshold is factor x the half cloud's mean spacing.
    let spacing = mean_spacing(&half.positions);
    let threshold = factor * spacing;
    let index = PointIndex::new(&half.positions);
    let mut s = Vec::new();
    let dist = |cs: &[[f32; 3]], s: &mut Vec<(f32, u32)>| -> Vec<f32> { cs.iter().map(|&c| index.nearest_distance(c, s)).collect() };
    let (db, da) = (dist(&centroids(b), &mut s), dist(&centroids(a), &mut s));
    // No face farther than the threshold survives (1 % slack: the pipeline measured it in the
    // unit cube, in f32).
    let far = da.iter().copied().fold(0.0f32, f32::max);
    assert!(far <= threshold * 1.01, "a face {far} from the points survived (threshold {threshold})");
    // Every face of the closed mesh that is near the points is kept (counts: the trimmed mesh is
    // the closed one minus its far faces, so the near ones must all be there).
    let near_before = db.iter().filter(|&&d| d <= threshold * 0.99).count();
    let kept = a.triangle_count();
    assert!(kept >= near_before, "kept {kept} faces, but {near_before} were near the points");
    // What closes the scan: the prior does not invent the missing half (no face lies beyond
    // the cut plane, before or after), it closes the opening with caps and inner sheets, up to
    // ~17 spacings from any point. Those are what trimming removes.
    let far_before = db.iter().filter(|&&d| d > threshold).count();
    let farthest_before = db.iter().copied().fold(0.0f32, f32::max);
    assert!(far_before * 10 > b.triangle_count() && farthest_before > 3.0 * threshold, "{far_before} far faces, farthest {farthest_before}");
    // Faces at the cut (centroid within 5 % of the length of the plane) facing the empty side
    // (normal x < -0.7): the cap over the opening.
    let cap = |m: &Mesh| {
        m.indices
            .chunks_exact(3)
            .filter(|t| {
                let [p, q, r] = [t[0], t[1], t[2]].map(|i| m.positions[i as usize].map(f64::from));
                let (u, v) = ([0, 1, 2].map(|k| q[k] - p[k]), [0, 1, 2].map(|k| r[k] - p[k]));
                let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                let cx_face = (p[0] + q[0] + r[0]) / 3.0;
                len > 0.0 && n[0] / len < -0.7 && cx_face < (cx + 0.05 * (hi[0] - lo[0])) as f64
            })
            .count()
    };
    let (cap_b, cap_a) = (cap(b), cap(a));
    let beyond = |m: &Mesh| centroids(m).iter().filter(|c| c[0] < cx).count();
    println!(
        "trim: spacing {spacing:.5}, threshold {threshold:.5}; faces {} -> {kept} ({} removed, {far_before} of them \
         farther than the threshold, the farthest {farthest_before:.3}); {open_edges} boundary edges; \
         cap faces at the cut facing the empty side {cap_b} -> {cap_a}; faces beyond the cut {} -> {}; \
         farthest kept face {far:.5}",
        b.triangle_count(),
        report.triangles_removed,
        beyond(b),
        beyond(a)
    );
    // The pipeline measured in the unit cube (f32): allow a face or so at the threshold.
    assert!(report.triangles_removed.abs_diff(far_before) <= far_before / 100, "{} vs {far_before}", report.triangles_removed);
    assert!(cap_a * 10 < cap_b * 7, "cap at the cut: {cap_b} -> {cap_a} faces");
}

// ---------------------------------------------------------------------------------------------
// Large coordinates

#[test]
fn far_off_clouds_reconstruct_like_their_recentred_twin() {
    let cloud = spot();
    let dir = out_dir();
    // The twin as float PLY, the far-off copy as double PLY (as georeferenced scans come). The
    // offset is not a whole number, so the reader's origin (rounded) leaves a fraction in the
    // f32 positions and the two runs do not see bit-identical input.
    let offset = [5e6 + 0.371_f64, 5e6 - 0.614, 0.0];
    let twin_ply = ply_bytes(&cloud.positions, None, None);
    let far_ply = ply_bytes(&cloud.positions, None, Some(offset));
    write(&dir, "spot-twin.ply", &twin_ply);
    let far_path = write(&dir, "spot-far.ply", &far_ply);
    let twin = nkrr::io::ply::read_ply(&twin_ply).unwrap().cloud;
    let far = nkrr::io::ply::read_ply(&far_ply).unwrap().cloud;
    assert_eq!(twin.origin, [0.0; 3]);
    assert_eq!(far.origin[2], 0.0);
    for a in 0..2 {
        assert!((far.origin[a] - offset[a]).abs() <= 1.0 && far.origin[a].fract() == 0.0, "{:?}", far.origin);
    }

    let (lo, hi) = bounds(&twin.positions);
    let extent = (0..3).map(|a| (hi[a] - lo[a]) as f64).fold(0.0, f64::max);
    let rec_twin = reconstruct(&twin, &settings());
    let rec_far = reconstruct(&far, &settings());

    // Compare in f64 user coordinates, minus the offset: vertex by vertex when the meshes have
    // the same connectivity (the field differs by rounding only), and both ways by the nearest
    // vertex in any case.
    let pa: Vec<[f64; 3]> = rec_twin.positions_f64();
    let pb: Vec<[f64; 3]> = rec_far.positions_f64().iter().map(|p| [0, 1, 2].map(|a| p[a] - offset[a])).collect();
    let d = |p: &[f64; 3], q: &[f64; 3]| (0..3).map(|a| (p[a] - q[a]).powi(2)).sum::<f64>().sqrt();
    let nearest_max = |from: &[[f64; 3]], to: &[[f64; 3]]| -> f64 {
        let to32: Vec<[f32; 3]> = to.iter().map(|p| p.map(|x| x as f32)).collect();
        let index = PointIndex::new(&to32);
        let mut s = Vec::new();
        from.iter()
            .map(|p| {
                index.k_nearest(p.map(|x| x as f32), 1, &mut s);
                d(p, &to[s[0].1 as usize])
            })
            .fold(0.0, f64::max)
    };
    let hausdorff = nearest_max(&pa, &pb).max(nearest_max(&pb, &pa)) / extent;
    let same_topology = rec_twin.mesh.indices == rec_far.mesh.indices;
    let per_vertex = same_topology.then(|| pa.iter().zip(&pb).map(|(p, q)| d(p, q)).fold(0.0, f64::max) / extent);
    println!(
        "offset {offset:?}: origin {:?}; {} vs {} vertices, same connectivity: {same_topology}; \
         max vertex difference / extent: {per_vertex:?}; symmetric Hausdorff / extent: {hausdorff:.3e}",
        far.origin,
        pa.len(),
        pb.len()
    );
    assert!(hausdorff < 1e-4, "Hausdorff {hausdorff:e} x extent");
    if let Some(e) = per_vertex {
        assert!(e < 1e-4, "vertex difference {e:e} x extent");
    }

    // The CLI writes the offset as the GLB root translation, and f32 positions near 0.
    let glb_path = dir.join("spot-far.glb");
    let (code, err) = cli(&["reconstruct", far_path.to_str().unwrap(), "-o", glb_path.to_str().unwrap(), "--method", "network", "--resolution", "64"]);
    assert_eq!(code, 0, "{err}");
    validate(std::slice::from_ref(&glb_path));
    let glb = read_glb(&std::fs::read(&glb_path).unwrap());
    assert_eq!(glb.translation, Some(far.origin));
    assert!(glb.positions.iter().all(|p| p.iter().all(|x| x.abs() < 2.0 * extent as f32)));
    let user: Vec<[f64; 3]> = glb
        .positions
        .iter()
        .map(|p| [0, 1, 2].map(|a| p[a] as f64 + far.origin[a] - offset[a]))
        .collect();
    assert_eq!(glb.indices, rec_far.mesh.indices);
    let e = user.iter().zip(&pb).map(|(p, q)| d(p, q)).fold(0.0, f64::max) / extent;
    assert!(e < 1e-6, "CLI GLB vs library: {e:e}");
}

/// The last fit of the mesh to the points: on spot-10k (the network's field at 128³), the fitted
/// mesh is closer to the ground truth in Chamfer distance and F-score, is still watertight, and
/// its normals agree with the ground truth's at least as well; `--no-fit` (Settings::fit =
/// false) leaves the level set as it is.
#[test]
fn the_fit_to_the_points_brings_the_mesh_to_the_surface() {
    let cloud = spot();
    let gt = nkrr::io::obj::read_obj(&std::fs::read(common::repo_root().join("tests/data/eval/spot.obj")).unwrap()).unwrap();
    let base = Settings { method: Method::Network, resolution: 128, colors: false, surface: Surface::Field, ..Settings::default() };
    let fitted = reconstruct(&cloud, &base);
    let plain = reconstruct(&cloud, &Settings { fit: false, ..base.clone() });
    assert!(plain.fit.is_none());
    let report = fitted.fit.clone().expect("a fit report");
    assert!(report.moved > report.kept * 20, "{report:?}");
    assert!(fitted.mesh.is_watertight());
    assert_eq!(fitted.mesh.indices, plain.mesh.indices, "the fit moves vertices, it does not change the triangles");
    let protocol = nkrr::eval::Protocol::default();
    let (f, p) = (
        nkrr::eval::evaluate(&gt, &fitted.mesh, &protocol).unwrap(),
        nkrr::eval::evaluate(&gt, &plain.mesh, &protocol).unwrap(),
    );
    assert!(f.cd1x100() < 0.85 * p.cd1x100(), "CD1 x100 fitted {} vs plain {}", f.cd1x100(), p.cd1x100());
    assert!(f.fscore > p.fscore + 0.03, "F fitted {} vs plain {}", f.fscore, p.fscore);
    assert!(f.nc >= p.nc - 0.002, "NC fitted {} vs plain {}", f.nc, p.nc);
}

/// The Poisson surface (issue 26): on spot-10k, where `--surface auto` chooses it, the
/// network's field orients the normals of a screened Poisson solve whose mesh is closer to the
/// ground truth than the field's own level set (docs/poisson.md: 0.297 against 0.360 CD1 x100),
/// watertight, with normals as consistent; the run says which surface it made.
#[test]
fn the_poisson_surface_comes_closer_than_the_fields_level_set() {
    let cloud = spot();
    let gt = nkrr::io::obj::read_obj(&std::fs::read(common::repo_root().join("tests/data/eval/spot.obj")).unwrap()).unwrap();
    let base = Settings { method: Method::Network, resolution: 128, colors: false, ..Settings::default() };
    let poisson = reconstruct(&cloud, &base);
    let field = reconstruct(&cloud, &Settings { surface: Surface::Field, ..base.clone() });
    let said = |r: &Reconstruction| r.notices.iter().any(|n| n.contains("screened Poisson surface"));
    assert!(said(&poisson) && !said(&field), "{:?}", poisson.notices);
    assert!(poisson.mesh.is_watertight());
    let protocol = nkrr::eval::Protocol::default();
    let (p, f) = (nkrr::eval::evaluate(&gt, &poisson.mesh, &protocol).unwrap(), nkrr::eval::evaluate(&gt, &field.mesh, &protocol).unwrap());
    assert!(p.cd1x100() < 0.9 * f.cd1x100(), "CD1 x100 Poisson {} vs field {}", p.cd1x100(), f.cd1x100());
    assert!(p.fscore > f.fscore + 0.01, "F Poisson {} vs field {}", p.fscore, f.fscore);
    assert!(p.nc >= f.nc - 0.005, "NC Poisson {} vs field {}", p.nc, f.nc);
}

/// A scan of one side (the half of spot facing +x): the Poisson surface would balloon over the
/// side never seen, so `--surface auto` keeps the field's level set and says why; `--surface
/// poisson` keeps the Poisson surface as asked. `poisson::far_share` measures the balloon.
#[test]
fn a_one_sided_scan_keeps_the_fields_level_set() {
    let cloud = spot();
    let (lo, hi) = bounds(&cloud.positions);
    let cx = 0.5 * (lo[0] + hi[0]);
    let half = PointCloud { positions: cloud.positions.iter().copied().filter(|p| p[0] > cx).collect(), ..Default::default() };
    let auto = reconstruct(&half, &settings());
    let field = reconstruct(&half, &Settings { surface: Surface::Field, ..settings() });
    let poisson = reconstruct(&half, &Settings { surface: Surface::Poisson, ..settings() });
    assert!(auto.notices.iter().any(|n| n.contains("far from every point") && n.contains("--surface poisson")), "{:?}", auto.notices);
    // The field's level set, as --surface field makes it, but for the pieces no point is near,
    // which a one-sided scan keeps (the network's guess of the unseen side; --surface field
    // drops them), and the fill far from the points deep inside their hull, which it opens
    // (here the inner sheets behind the cut): every vertex of the field's level set near the
    // points is there, and what went is said.
    let kept: std::collections::HashSet<[u32; 3]> = auto.mesh.positions.iter().map(|p| p.map(f32::to_bits)).collect();
    let index = PointIndex::new(&half.positions);
    let (near, mut s) = (nkrr::mesh::trim::DEFAULT_TRIM * mean_spacing(&half.positions), Vec::new());
    let missing = field.mesh.positions.iter().filter(|p| index.nearest_distance(**p, &mut s) < 0.9 * near && !kept.contains(&p.map(f32::to_bits))).count();
    assert_eq!(missing, 0, "vertices of the field's level set near the points missing");
    let opened = auto.notices.iter().any(|n| n.contains("between sheets of points"));
    assert_eq!(opened, !auto.mesh.is_watertight(), "{:?}", auto.notices);
    assert!(opened, "the cut half's inner sheets are far from the points and deep inside their hull");
    assert!(poisson.notices.iter().any(|n| n.contains("screened Poisson surface")), "{:?}", poisson.notices);
    // In the same (unit-cube-free, user) coordinates as the points: the balloon is measured.
    let far = nkrr::poisson::far_share(&poisson.mesh, &half.positions);
    assert!(far > nkrr::poisson::MAX_FAR_SHARE, "{far}");
    assert!(nkrr::poisson::ballooned(far, nkrr::poisson::far_share(&field.mesh, &half.positions)));
}

/// `n` noisy points on a cup (radius 0.4, height 0.8, open at the top) whose wall and floor are
/// `t` thick: its outside, inside, floor and rim, spread by area, with Gaussian noise `sigma`
/// (scripts/thin_clouds.py's cups, made here).
fn thin_cup(n: usize, t: f64, sigma: f64) -> PointCloud {
    use std::f64::consts::TAU;
    let (r, h) = (0.4, 0.8);
    let ri = r - t;
    // (area, sampler from two uniforms) for each part.
    let parts: [(f64, Box<dyn Fn(f64, f64) -> [f64; 3]>); 5] = [
        (TAU * r * h, Box::new(move |u, v| [r * (TAU * u).cos(), r * (TAU * u).sin(), h * v])),
        (TAU * ri * (h - t), Box::new(move |u, v| [ri * (TAU * u).cos(), ri * (TAU * u).sin(), t + (h - t) * v])),
        (0.5 * TAU * r * r, Box::new(move |u, v| [r * v.sqrt() * (TAU * u).cos(), r * v.sqrt() * (TAU * u).sin(), 0.0])),
        (0.5 * TAU * ri * ri, Box::new(move |u, v| [ri * v.sqrt() * (TAU * u).cos(), ri * v.sqrt() * (TAU * u).sin(), t])),
        (TAU * r * t, Box::new(move |u, v| [(ri + t * v) * (TAU * u).cos(), (ri + t * v) * (TAU * u).sin(), h])),
    ];
    let total: f64 = parts.iter().map(|p| p.0).sum();
    let mut rng = nkrr::rng::SplitMix64(11);
    let positions = (0..n)
        .map(|_| {
            let mut pick = rng.unit() * total;
            let part = parts.iter().find(|p| {
                pick -= p.0;
                pick < 0.0
            });
            let p = (part.unwrap_or(&parts[0]).1)(rng.unit(), rng.unit());
            [0, 1, 2].map(|a| (p[a] + sigma * rng.normal()) as f32)
        })
        .collect();
    PointCloud { positions, ..Default::default() }
}

/// A cup whose wall is thinner than the field resolves (1.25 % of its height, 2.5 sigma of the
/// noise): the Poisson surface puts its lid over the opening far from the points, but the
/// field's own level set is farther from them still (a lumpy fill), so `--surface auto` keeps
/// the Poisson surface, opened where it is far from the points as `--trim` opens it, and says
/// why, where a one-sided scan (above) falls back to the field. `--surface poisson` keeps the
/// lid (closed).
#[test]
fn a_thin_walled_cup_keeps_the_poisson_surface_opened() {
    let cup = thin_cup(3000, 0.01, 0.004);
    let auto = reconstruct(&cup, &settings());
    let poisson = reconstruct(&cup, &Settings { surface: Surface::Poisson, ..settings() });
    let trimmed = reconstruct(&cup, &Settings { surface: Surface::Poisson, trim: Some(nkrr::mesh::trim::DEFAULT_TRIM), ..settings() });
    let field = reconstruct(&cup, &Settings { surface: Surface::Field, ..settings() });
    assert!(auto.notices.iter().any(|n| n.contains("far from every point") && n.contains("the Poisson surface is kept and opened")), "{:?}", auto.notices);
    assert_eq!(auto.mesh.indices, trimmed.mesh.indices, "the Poisson surface, as --surface poisson --trim makes it");
    assert!(poisson.mesh.is_watertight() && !auto.mesh.is_watertight());
    assert!(auto.mesh.indices.len() < poisson.mesh.indices.len());
    let far = nkrr::poisson::far_share(&poisson.mesh, &cup.positions);
    let field_far = nkrr::poisson::far_share(&field.mesh, &cup.positions);
    assert!(far > nkrr::poisson::MAX_FAR_SHARE && !nkrr::poisson::ballooned(far, field_far), "Poisson {far}, field {field_far}");
}

/// An open shell: `n` noisy points on a bowl, the lower half of a sphere of radius 0.5 as a
/// sheet (no thickness), noise `sigma`. Returns the cloud and each point's distance to the bowl.
fn bowl(n: usize, sigma: f64) -> (PointCloud, impl Fn([f32; 3]) -> f64) {
    let mut rng = nkrr::rng::SplitMix64(5);
    let positions = (0..n)
        .map(|_| {
            // Uniform on the half sphere: z uniform in [-r, 0], the angle uniform.
            let (z, phi) = (-0.5 * rng.unit(), std::f64::consts::TAU * rng.unit());
            let rho = (0.25 - z * z).sqrt();
            [rho * phi.cos(), rho * phi.sin(), z].map(|c| (c + sigma * rng.normal()) as f32)
        })
        .collect();
    let distance = |p: [f32; 3]| {
        let [x, y, z] = p.map(f64::from);
        let rho = (x * x + y * y).sqrt();
        if z <= 0.0 { ((rho * rho + z * z).sqrt() - 0.5).abs() } else { ((rho - 0.5).powi(2) + z * z).sqrt() }
    };
    (PointCloud { positions, ..Default::default() }, distance)
}

/// A bowl scanned all over (a sheet, open at the top): the prior reads it as a solid and fills
/// it; the Poisson surface balloons, so `--surface auto` meshes the field's level set, then
/// opens the fill, which lies far from the points and deep inside their hull, and says so.
/// The mesh comes closer to the bowl than the field's level set as `--surface field` keeps it.
/// Below 1,000 points (500 here) the field's level set is the surface without a balloon, and
/// the fill, a large share of the mesh, goes the same way; a closed object's few far triangles
/// (suzanne-500, the eval cloud) stay, and its mesh stays watertight.
#[test]
fn an_open_shell_loses_the_fill_between_its_sheets() {
    for n in [3000, 500] {
        let (cloud, distance) = bowl(n, 0.004);
        let auto = reconstruct(&cloud, &settings());
        let field = reconstruct(&cloud, &Settings { surface: Surface::Field, ..settings() });
        assert_eq!(auto.notices.iter().any(|n| n.contains("far from every point")), n >= nkrr::plan::POISSON_POINTS, "{n}: {:?}", auto.notices);
        assert!(auto.notices.iter().any(|n| n.contains("between sheets of points") && n.contains("not watertight")), "{n}: {:?}", auto.notices);
        assert!(!auto.mesh.is_watertight() && field.mesh.is_watertight(), "{n}");
        let error = |m: &Mesh| {
            let c = centroids(m);
            c.iter().map(|&p| distance(p)).sum::<f64>() / c.len() as f64
        };
        let (e_auto, e_field) = (error(&auto.mesh), error(&field.mesh));
        println!("bowl, {n} points: mean distance of the triangles to the bowl {e_field:.4} (field's level set) -> {e_auto:.4} (opened)");
        assert!(e_auto < 0.5 * e_field, "{n}: {e_auto} vs {e_field}");
    }
    let path = common::repo_root().join("tests/data/eval/suzanne-500.ply");
    let closed = reconstruct(&nkrr::io::ply::read_ply(&std::fs::read(&path).unwrap()).unwrap().cloud, &settings());
    assert!(closed.mesh.is_watertight() && !closed.notices.iter().any(|n| n.contains("between sheets")), "{:?}", closed.notices);
}

/// The guard against the prior on the shell fixture `name` (tests/data/shells): nkrr's run is
/// the network's mesh and says why (its notices returned), its progress shows the network's run
/// as one stage and is done once, and the tuned field's own mesh
/// (`--surface field`: what was asked for, no guard) lies farther from the points than it, as
/// `closure` measures it (the run's: one-sided after a balloon, sparse below 1,000 points).
fn gives_way_to_the_network(name: &str, closure: Closure) -> Vec<String> {
    let path = common::repo_root().join("tests/data/shells").join(name);
    let cloud = nkrr::io::ply::read_ply(&std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap().cloud;
    let nkrr_settings = Settings { method: Method::Nkrr, ..settings() };
    let gpu = nkrr::gpu::Gpu::new_blocking().expect("a wgpu adapter (lavapipe will do)");
    let engine = pollster::block_on(Engine::new(gpu)).unwrap();
    let mut stages = Vec::new();
    let nkrr_run = pollster::block_on(engine.reconstruct(&cloud, &nkrr_settings, &mut |s| {
        stages.push(format!("{s:?}").split([' ', '{']).next().unwrap().to_string());
        true
    }))
    .unwrap();
    // The network's run shows as one stage after the tuned field's, and the run is done once, at
    // the end: the page's bar and words do not start over.
    let prior = stages.iter().position(|s| s == "Prior").unwrap_or_else(|| panic!("{name}: {stages:?}"));
    assert!(stages[..prior].iter().any(|s| s == "Tuning") && stages[prior..stages.len() - 1].iter().all(|s| s == "Prior"), "{name}: {stages:?}");
    assert_eq!((stages.last().map(String::as_str), stages.iter().filter(|s| *s == "Done").count()), (Some("Done"), 1), "{name}: {stages:?}");
    let network = reconstruct(&cloud, &settings());
    assert!(nkrr_run.notices.iter().any(|n| n.contains("farther from the points than the network's")), "{name}: {:?}", nkrr_run.notices);
    assert_eq!((&nkrr_run.mesh.indices, &nkrr_run.mesh.positions), (&network.mesh.indices, &network.mesh.positions), "{name}: the network's mesh");
    let tuned = reconstruct(&cloud, &Settings { surface: Surface::Field, ..nkrr_settings });
    assert!(tuned.tuning.is_some() && !tuned.notices.iter().any(|n| n.contains("than the network's")), "{name}: {:?}", tuned.notices);
    let far = |m: &Mesh| closure.distance(m, &cloud.positions).unwrap();
    assert!(far(&tuned.mesh) > far(&network.mesh), "{name}: {} vs {}", far(&tuned.mesh), far(&network.mesh));
    nkrr_run.notices
}

/// Issue 26's bound, on an open box whose sheets the tuned field thins through (holes in its
/// walls, the points farther from its mesh than from the network's; tests/data/shells): the
/// run keeps the network's mesh and says why, so nkrr is the network alone there, not worse.
#[test]
fn a_tuned_field_that_thins_a_sheet_through_gives_way_to_the_network() {
    let notices = gives_way_to_the_network("crate-3k.ply", Closure::OneSided);
    // At 3k points the Poisson surface ballooned first (its notice stays) and fell back to the field.
    assert!(notices.iter().any(|n| n.contains("far from every point")), "{notices:?}");
}

/// Below 1,000 points the field's level set is the surface (no Poisson solve, no balloon), and
/// the same guard holds: on 500 points of the open box the tuned field's mesh leaves the points
/// farther than the network's (crate-500, by 5 % at resolution 64), so the network's mesh is the
/// result, said in a notice. (Until 2026-12-05 this was crate-1k, then below the Poisson
/// surface's 2,000 points; from 1,000 points its Poisson surface is tried first, and whether that
/// balloons sits at the guard's own bound there: the field's far share 0.49 of the Poisson
/// surface's at resolution 128, against 0.5.)
#[test]
fn a_sparse_shell_whose_tuned_field_leaves_the_points_gives_way_to_the_network() {
    gives_way_to_the_network("crate-500.ply", Closure::Sparse);
}

/// Below 1,000 points the guard measures both ways: on 500 points of a cup whose walls are
/// 1.9 % of its height (tests/data/shells), both fields fill the cup and the fill is opened,
/// but the tuned field leaves foam inside that no point carries, nearer the points than the
/// network's mesh (the points' side alone kept it: CD1 x100 2.10 against the network's 1.74 at
/// resolution 64, 2.17 against 1.74 at 128). Its surface lies farther from them, so the
/// network's mesh is the result, said in a notice.
#[test]
fn a_cup_the_tuned_field_fills_with_foam_gives_way_to_the_network() {
    gives_way_to_the_network("cup015-500.ply", Closure::Sparse);
}

/// Meshing progress moves with the work done (issue 17): the evaluations reported never run
/// ahead of the evaluations made, grow in steps of at most one chunk (32768), and end at the
/// extraction's own count.
#[test]
fn meshing_progress_follows_the_evaluations() {
    let cloud = spot();
    let gpu = nkrr::gpu::Gpu::new_blocking().expect("a wgpu adapter (lavapipe will do)");
    let engine = pollster::block_on(Engine::new(gpu)).unwrap();
    let mut seen = Vec::new();
    let mut expect = 0;
    // The field meshed at the resolution asked (a Poisson surface meshes it coarser).
    let s = Settings { resolution: 96, surface: Surface::Field, ..settings() };
    let rec = pollster::block_on(engine.reconstruct(&cloud, &s, &mut |stage| {
        if let nkrr::pipeline::Stage::Meshing { evaluated, expected } = stage {
            seen.push(*evaluated);
            expect = *expected;
        }
        true
    }))
    .unwrap();
    let total = rec.extract.refine.evaluations as usize;
    assert!(seen.windows(2).all(|w| w[0] <= w[1] && w[1] - w[0] <= 32_768), "progress steps: {seen:?}");
    assert!(seen.len() >= total / 32_768, "{} reports for {total} evaluations", seen.len());
    assert!(*seen.last().unwrap() < total, "the last report comes before the last chunk is evaluated");
    assert!(total - seen.last().unwrap() <= 32_768);
    // The event carries the total it is measured against: the typical count at this resolution,
    // within a factor of two of this closed surface's.
    assert_eq!(expect, nkrr::mesh::refine::MeshingSize::at(96).expected as usize);
    assert!(expect / 2 <= total && total <= 2 * expect, "{total} evaluations, about {expect} expected");
}

/// A sphere of 2,000 points with one stray point 1e7 away reconstructs: the shape checks run
/// on the points the stray-point filter keeps (it was refused as "all points lie on one line").
/// With the filter off, the refusal names the far point instead of calling the sphere a line.
/// A filter set to take half of a clean cloud warns with the count.
#[test]
fn a_far_stray_point_does_not_make_the_cloud_a_line() {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut positions: Vec<[f32; 3]> = (0..2000)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / 2000.0;
            let r = (1.0 - y * y).sqrt();
            let t = golden * i as f64;
            [(0.3 * r * t.cos()) as f32, (0.3 * y) as f32, (0.3 * r * t.sin()) as f32]
        })
        .collect();
    positions.push([1e7, 0.0, 0.0]);
    let cloud = PointCloud { positions, ..Default::default() };
    let rec = reconstruct(&cloud, &settings());
    assert!(rec.mesh.is_watertight() && rec.mesh.indices.len() > 3000, "{} triangles", rec.mesh.indices.len() / 3);
    let b = rec.mesh.bounds().unwrap();
    assert!(b.max[0] < 0.4 && b.min[0] > -0.4, "{b:?}");
    assert!(rec.notices.iter().any(|n| n.contains("dropped 1 stray points")), "{:?}", rec.notices);
    assert!(rec.warnings.is_empty(), "{:?}", rec.warnings);

    let gpu = nkrr::gpu::Gpu::new_blocking().unwrap();
    let engine = pollster::block_on(Engine::new(gpu)).unwrap();
    let keep = Settings { outliers: None, ..settings() };
    let e = pollster::block_on(engine.reconstruct(&cloud, &keep, &mut |_| true)).err().expect("refused").to_string();
    assert!(e.contains("only because of 1 point(s) far from the rest") && e.contains("--outliers"), "{e}");
    assert!(!e.contains("all points lie on one line"), "{e}");

    // The filter at ratio 1 takes about half of this even sphere: a warning with the count.
    let mut even = cloud.clone();
    even.positions.pop();
    let harsh = Settings { outliers: Some(1.0), ..settings() };
    let rec = pollster::block_on(engine.reconstruct(&even, &harsh, &mut |_| true)).unwrap();
    let w = rec.warnings.join(" | ");
    assert!(w.contains("stray-point filter dropped") && w.contains("of 2000 points") && w.contains("--keep-outliers"), "{w}");
    assert!(!rec.notices.iter().any(|n| n.contains("stray")), "{:?}", rec.notices);
}

/// Never worse than the prior (issue 26 item 3): on suzanne-500 (the eval cloud,
/// `scripts/results_clouds.py`), where the regression is tuned and its field meshed, the default
/// field (the network's logit as the regression's prior mean) is within 0.01 CD1 x100 of the
/// network alone. The regression alone (the paper's zero prior mean, the default before) lost to
/// the network here by 0.012 (docs/results.md: 0.719 against 0.707). The tuned field is asked
/// for (`--surface field`): under `auto` the guard against the prior compares it with the
/// network's mesh, and on this cloud keeps the network's (docs/poisson.md, "Below 2,000 points
/// too"; since 2026-12-05 below 1,000), which would leave nothing of the tuned field to test.
#[test]
fn the_tuned_field_does_not_lose_to_the_network_on_a_sparse_cloud() {
    let path = common::repo_root().join("tests/data/eval/suzanne-500.ply");
    let cloud = nkrr::io::ply::read_ply(&std::fs::read(&path).unwrap()).unwrap().cloud;
    let gt = nkrr::io::obj::read_obj(&std::fs::read(common::repo_root().join("tests/data/eval/suzanne.obj")).unwrap()).unwrap();
    let base = Settings { colors: false, ..Settings::default() };
    let tuned = reconstruct(&cloud, &Settings { surface: Surface::Field, ..base.clone() });
    let network = reconstruct(&cloud, &Settings { method: Method::Network, ..base.clone() });
    let tuning = tuned.tuning.as_ref().expect("500 points: the regression is tuned");
    assert!(tuning.steps_run > 0, "{tuning:?}");
    let protocol = nkrr::eval::Protocol::default();
    let (t, n) = (nkrr::eval::evaluate(&gt, &tuned.mesh, &protocol).unwrap(), nkrr::eval::evaluate(&gt, &network.mesh, &protocol).unwrap());
    eprintln!("suzanne-500 CD1 x100: tuned {:.4}, network {:.4}", t.cd1x100(), n.cd1x100());
    assert!(t.cd1x100() <= n.cd1x100() + 0.01, "CD1 x100 tuned {} vs network {}", t.cd1x100(), n.cd1x100());
}
