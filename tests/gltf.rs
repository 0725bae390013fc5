//! The GLB writer (`nkrr::io::gltf`) and the `Mesh` helpers it relies on: round trips through
//! the `gltf` crate's importer, the Khronos glTF validator (via node), error cases, and
//! `Mesh::is_watertight` / `Mesh::compute_vertex_normals`.

mod common;
use common::run_validator;
use std::path::{Path, PathBuf};

use gltf::json::Value;
use nkrr::io::gltf::{write_glb, write_glb_with_report, Compression, GlbOptions, GltfError};
use nkrr::mesh::Mesh;
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Test meshes

/// The unit cube [0,1]^3: 8 shared vertices (index = x + 2y + 4z), 12 triangles, CCW outward.
fn cube() -> Mesh {
    let positions =
        (0..8u32).map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32]).collect();
    #[rustfmt::skip]
    let indices = vec![
        0, 2, 3, 0, 3, 1, // -z
        4, 5, 7, 4, 7, 6, // +z
        0, 1, 5, 0, 5, 4, // -y
        2, 6, 7, 2, 7, 3, // +y
        0, 4, 6, 0, 6, 2, // -x
        1, 3, 7, 1, 7, 5, // +x
    ];
    Mesh { positions, normals: Vec::new(), colors: None, indices }
}

/// A unit icosphere subdivided `levels` times (welded, CCW outward), with normals equal to the
/// positions and, if asked, colours derived from the normals.
fn icosphere(levels: u32, with_colors: bool) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    #[rustfmt::skip]
    let mut positions: Vec<[f32; 3]> = [
        [-1.0, t, 0.0], [1.0, t, 0.0], [-1.0, -t, 0.0], [1.0, -t, 0.0],
        [0.0, -1.0, t], [0.0, 1.0, t], [0.0, -1.0, -t], [0.0, 1.0, -t],
        [t, 0.0, -1.0], [t, 0.0, 1.0], [-t, 0.0, -1.0], [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| unit(*p))
    .collect();
    #[rustfmt::skip]
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut midpoint = |a: u32, b: u32, positions: &mut Vec<[f32; 3]>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                let (p, q) = (positions[a as usize], positions[b as usize]);
                positions.push(unit([p[0] + q[0], p[1] + q[1], p[2] + q[2]]));
                positions.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(tris.len() * 4);
        for [a, b, c] in tris {
            let ab = midpoint(a, b, &mut positions);
            let bc = midpoint(b, c, &mut positions);
            let ca = midpoint(c, a, &mut positions);
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    let colors = with_colors.then(|| {
        positions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let c = |x: f32| ((x * 0.5 + 0.5) * 255.0).round() as u8;
                [c(p[0]), c(p[1]), c(p[2]), (i % 256) as u8]
            })
            .collect()
    });
    Mesh { normals: positions.clone(), positions, colors, indices: tris.concat() }
}

/// A torus with `nu * nv * 2` triangles (welded, closed, consistently oriented).
fn torus(nu: u32, nv: u32) -> Mesh {
    let (big_r, small_r) = (1.0f32, 0.3f32);
    let mut positions = Vec::with_capacity((nu * nv) as usize);
    for i in 0..nu {
        let u = i as f32 / nu as f32 * std::f32::consts::TAU;
        for j in 0..nv {
            let v = j as f32 / nv as f32 * std::f32::consts::TAU;
            let r = big_r + small_r * v.cos();
            positions.push([r * u.cos(), r * u.sin(), small_r * v.sin()]);
        }
    }
    let id = |i: u32, j: u32| (i % nu) * nv + (j % nv);
    let mut indices = Vec::with_capacity((nu * nv * 6) as usize);
    for i in 0..nu {
        for j in 0..nv {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            indices.extend_from_slice(&[a, b, c, a, c, d]);
        }
    }
    let mut m = Mesh { positions, normals: Vec::new(), colors: None, indices };
    m.compute_vertex_normals();
    m
}

fn unit(p: [f32; 3]) -> [f32; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / l, p[1] / l, p[2] / l]
}

fn len(v: [f32; 3]) -> f32 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

// ---------------------------------------------------------------------------------------------
// Reading back

/// What the `gltf` crate reads back from a GLB (single primitive).
#[derive(Debug)]
struct ReadBack {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    colors: Option<Vec<[u8; 4]>>,
    indices: Vec<u32>,
    min: Vec<f64>,
    max: Vec<f64>,
}

fn read_back(glb: &[u8]) -> ReadBack {
    let (doc, buffers, images) = gltf::import_slice(glb).expect("gltf crate imports our GLB");
    assert!(images.is_empty());
    assert_eq!(buffers.len(), 1);
    assert_eq!(doc.scenes().count(), 1);
    assert_eq!(doc.default_scene().map(|s| s.index()), Some(0), "scene: 0 is set");
    assert_eq!(doc.nodes().count(), 1);
    assert_eq!(doc.meshes().count(), 1);
    let scene = doc.default_scene().unwrap();
    let roots: Vec<_> = scene.nodes().collect();
    assert_eq!(roots.len(), 1);
    assert_eq!(roots[0].children().count(), 0);
    let mesh = roots[0].mesh().expect("node has the mesh");
    let prims: Vec<_> = mesh.primitives().collect();
    assert_eq!(prims.len(), 1);
    let p = &prims[0];
    assert_eq!(p.mode(), gltf::mesh::Mode::Triangles);
    let mat = p.material();
    assert_eq!(mat.index(), Some(0), "a real material, not the implicit default");
    assert!(!mat.double_sided());
    assert_eq!(mat.alpha_mode(), gltf::material::AlphaMode::Opaque);
    assert_eq!(mat.pbr_metallic_roughness().metallic_factor(), 0.0);

    let pos_acc = p.get(&gltf::Semantic::Positions).unwrap();
    let nums = |v: Option<Value>| -> Vec<f64> {
        v.expect("min/max present")
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (min, max) = (nums(pos_acc.min()), nums(pos_acc.max()));
    let nrm_acc = p.get(&gltf::Semantic::Normals).unwrap();
    assert_eq!(nrm_acc.data_type(), gltf::accessor::DataType::F32);
    if let Some(c) = p.get(&gltf::Semantic::Colors(0)) {
        assert_eq!(c.data_type(), gltf::accessor::DataType::U8);
        assert_eq!(c.dimensions(), gltf::accessor::Dimensions::Vec4);
        assert!(c.normalized());
    }
    assert_eq!(p.indices().unwrap().data_type(), gltf::accessor::DataType::U32);

    let r = p.reader(|b| Some(&buffers[b.index()]));
    ReadBack {
        positions: r.read_positions().unwrap().collect(),
        normals: r.read_normals().unwrap().collect(),
        colors: r.read_colors(0).map(|c| c.into_rgba_u8().collect()),
        indices: r.read_indices().unwrap().into_u32().collect(),
        min,
        max,
    }
}

/// The GLB's two chunks, after checking the container layout.
fn chunks(glb: &[u8]) -> (Value, &[u8]) {
    let u32_at = |o: usize| u32::from_le_bytes(glb[o..o + 4].try_into().unwrap());
    assert_eq!(&glb[0..4], b"glTF");
    assert_eq!(u32_at(4), 2, "GLB version");
    assert_eq!(u32_at(8) as usize, glb.len(), "GLB total length");
    let json_len = u32_at(12) as usize;
    assert_eq!(&glb[16..20], b"JSON");
    assert_eq!(json_len % 4, 0, "JSON chunk 4-byte aligned");
    let json = &glb[20..20 + json_len];
    let trimmed = json.iter().rposition(|&b| b == b'}').unwrap() + 1;
    assert!(json_len - trimmed < 4 && json[trimmed..].iter().all(|&b| b == b' '), "space padding");
    let bin_off = 20 + json_len;
    let bin_len = u32_at(bin_off) as usize;
    assert_eq!(&glb[bin_off + 4..bin_off + 8], b"BIN\0");
    assert_eq!(bin_len % 4, 0, "BIN chunk 4-byte aligned");
    assert_eq!(bin_off + 8 + bin_len, glb.len(), "nothing after the BIN chunk");
    let value: Value = gltf::json::deserialize::from_slice(json).expect("JSON chunk parses");
    (value, &glb[bin_off + 8..])
}

// ---------------------------------------------------------------------------------------------
// Round trips

#[test]
fn round_trip_cube_computes_normals() {
    let m = cube();
    let (glb, report) = write_glb_with_report(&m, &GlbOptions::default()).unwrap();
    assert!(report.normals_computed);
    assert_eq!(report.triangles_written, 12);
    assert_eq!((report.degenerate_triangles_dropped, report.unused_vertices), (0, 0));
    assert_eq!(report.bytes, glb.len());
    let r = read_back(&glb);
    assert_eq!(r.positions, m.positions);
    assert_eq!(r.indices, m.indices);
    assert_eq!(r.colors, None);
    let mut with_normals = m.clone();
    with_normals.compute_vertex_normals();
    assert_eq!(r.normals, with_normals.normals);
    assert_eq!(r.min, vec![0.0; 3]);
    assert_eq!(r.max, vec![1.0; 3]);
}

#[test]
fn round_trip_colored_icosphere() {
    let mut m = icosphere(3, true);
    assert_eq!(m.triangle_count(), 1280);
    // Scale and shift so that the bounds are not round numbers.
    m.positions.iter_mut().for_each(|p| *p = p.map(|x| x * 0.7 + 0.1));
    let glb = write_glb(&m, &GlbOptions::default()).unwrap();
    let r = read_back(&glb);
    assert_eq!(r.positions, m.positions);
    assert_eq!(r.indices, m.indices);
    assert_eq!(r.colors, m.colors);
    for (got, given) in r.normals.iter().zip(&m.normals) {
        for k in 0..3 {
            assert!((got[k] - given[k]).abs() < 1e-6, "{got:?} vs {given:?}");
        }
        assert!((len(*got) - 1.0).abs() < 1e-6);
    }
    // min/max exactly the f32 bounds (these are not round decimals).
    let b = m.bounds().unwrap();
    assert_eq!(r.min, b.min.map(f64::from).to_vec());
    assert_eq!(r.max, b.max.map(f64::from).to_vec());
    assert!(r.min.iter().chain(&r.max).any(|x| (x * 1e6).fract() != 0.0));
}

#[test]
fn round_trip_odd_coordinates_keeps_exact_bounds() {
    // Values whose shortest f32 decimal differs from the f64 value (0.1f32 != 0.1f64), tiny,
    // huge and negative-zero coordinates.
    let mut m = cube();
    m.positions[0] = [0.1, -0.0, 1e-30];
    m.positions[7] = [3.4e38, 123456.79, -7.0e-39];
    m.positions[3] = [-1e20, 0.3, 0.7];
    let glb = write_glb(&m, &GlbOptions::default()).unwrap();
    let r = read_back(&glb);
    assert_eq!(r.positions, m.positions);
    // Compared as f32: serde_json (without its `float_roundtrip` feature) may parse a long
    // decimal 1 ulp off in f64, which never changes the f32 it rounds to. The exact-f64 text is
    // checked by the writer's unit tests and by the validator test.
    let b = m.bounds().unwrap();
    for k in 0..3 {
        assert_eq!(r.min[k] as f32, b.min[k], "min[{k}]");
        assert_eq!(r.max[k] as f32, b.max[k], "max[{k}]");
    }
}

#[test]
fn glb_layout_scene_node_translation_and_name() {
    let name = "a \"quoted\" \\ name\nwith\ttabs, \u{1} control, é and 漢字";
    let opts = GlbOptions { translation: Some([5e6, -5e6, 5e6 + 0.125]), name: Some(name.into()), ..Default::default() };
    let mut m = icosphere(1, true);
    m.positions.iter_mut().for_each(|p| p[0] += 0.5);
    let glb = write_glb(&m, &opts).unwrap();
    let (json, bin) = chunks(&glb);

    assert_eq!(json["asset"]["version"], "2.0");
    assert_eq!(json["asset"]["generator"], format!("nkrr {}", env!("CARGO_PKG_VERSION")));
    assert_eq!(json["scene"], 0);
    assert_eq!(json["scenes"].as_array().unwrap().len(), 1);
    assert_eq!(json["scenes"][0]["nodes"], serde_like_array(&[0]));
    let node = &json["nodes"][0];
    assert_eq!(node["mesh"], 0);
    assert_eq!(node["name"], name);
    assert_eq!(json["meshes"][0]["name"], name);
    let tr: Vec<f64> =
        node["translation"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    assert_eq!(tr, vec![5e6, -5e6, 5e6 + 0.125], "translation written exactly, as f64");
    assert_eq!(json["materials"][0]["doubleSided"], false);
    assert!(json["materials"][0]["pbrMetallicRoughness"].is_object());

    // Buffer and views: one buffer = the BIN chunk; separate, aligned, targeted views.
    assert_eq!(json["buffers"].as_array().unwrap().len(), 1);
    assert_eq!(json["buffers"][0]["byteLength"].as_u64().unwrap() as usize, bin.len());
    let prim = &json["meshes"][0]["primitives"][0];
    assert_eq!(prim["mode"], 4);
    let view_of = |acc: &Value| &json["bufferViews"][acc.as_u64().unwrap() as usize];
    let acc = |i: &Value| &json["accessors"][i.as_u64().unwrap() as usize];
    let attrs = &prim["attributes"];
    let mut seen_views = Vec::new();
    for (sem, ty, ct) in
        [("POSITION", "VEC3", 5126), ("NORMAL", "VEC3", 5126), ("COLOR_0", "VEC4", 5121)]
    {
        let a = acc(&attrs[sem]);
        assert_eq!(a["type"], ty, "{sem}");
        assert_eq!(a["componentType"], ct, "{sem}");
        assert_eq!(a["count"].as_u64().unwrap() as usize, m.positions.len());
        let v = view_of(&a["bufferView"]);
        assert_eq!(v["target"], 34962, "{sem} view targets ARRAY_BUFFER");
        assert_eq!(v["byteOffset"].as_u64().unwrap() % 4, 0);
        if let Some(s) = v["byteStride"].as_u64() {
            assert_eq!(s % 4, 0);
        }
        seen_views.push(a["bufferView"].as_u64().unwrap());
    }
    assert_eq!(acc(&attrs["COLOR_0"])["normalized"], true);
    let ia = acc(&prim["indices"]);
    assert_eq!(ia["componentType"], 5125);
    assert_eq!(ia["type"], "SCALAR");
    let iv = view_of(&ia["bufferView"]);
    assert_eq!(iv["target"], 34963, "index view targets ELEMENT_ARRAY_BUFFER");
    assert!(iv.get("byteStride").is_none());
    seen_views.push(ia["bufferView"].as_u64().unwrap());
    seen_views.sort();
    seen_views.dedup();
    assert_eq!(seen_views.len(), 4, "one buffer view per accessor");

    // The gltf crate agrees (translation as f32, name unescaped).
    let doc = gltf::Gltf::from_slice(&glb).unwrap();
    let n = doc.nodes().next().unwrap();
    assert_eq!(n.name(), Some(name));
    let (t, r, s) = n.transform().decomposed();
    assert_eq!(t, [5e6f32, -5e6, (5e6 + 0.125) as f32]);
    assert_eq!((r, s), ([0.0, 0.0, 0.0, 1.0], [1.0; 3]));
    let rb = read_back(&glb);
    assert_eq!(rb.positions, m.positions);
}

fn serde_like_array(xs: &[u64]) -> Value {
    Value::Array(xs.iter().map(|&x| Value::from(x)).collect())
}

#[test]
fn degenerate_triangles_dropped_unused_vertices_kept() {
    let mut m = cube();
    m.positions.push([9.0, 9.0, 9.0]); // unused vertex 8
    m.indices.extend_from_slice(&[0, 0, 1, 2, 3, 2, 5, 6, 6]); // 3 degenerate
    let (glb, report) = write_glb_with_report(&m, &GlbOptions::default()).unwrap();
    assert_eq!(report.degenerate_triangles_dropped, 3);
    assert_eq!(report.triangles_written, 12);
    assert_eq!(report.unused_vertices, 1);
    let r = read_back(&glb);
    assert_eq!(r.indices, cube().indices);
    assert_eq!(r.positions.len(), 9);
    assert_eq!(r.max, vec![9.0; 3], "bounds include unused vertices (the validator checks all)");
}

#[test]
fn bad_normals_are_repaired_to_unit_length() {
    let mut m = cube();
    m.compute_vertex_normals();
    let good = m.normals.clone();
    m.normals[0] = [0.0, 0.0, 0.0];
    m.normals[1] = [f32::NAN, 1.0, 0.0];
    m.normals[2] = [f32::INFINITY, 0.0, 0.0];
    m.normals[3] = [2.0, 0.0, 0.0];
    m.normals[4] = [1e-40, 0.0, -1e-40]; // denormal but has a direction
    m.normals[5] = [3e38, 3e38, 0.0]; // would overflow when squared in f32
    let (glb, report) = write_glb_with_report(&m, &GlbOptions::default()).unwrap();
    assert_eq!(report.normals_repaired, 3);
    assert!(!report.normals_computed);
    let r = read_back(&glb);
    for n in &r.normals {
        assert!((len(*n) - 1.0).abs() < 1e-6, "{n:?}");
    }
    assert_eq!(&r.normals[0..3], &good[0..3], "repaired from the area-weighted normal");
    assert_eq!(r.normals[3], [1.0, 0.0, 0.0]);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert!((r.normals[4][0] - h).abs() < 1e-6 && (r.normals[4][2] + h).abs() < 1e-6);
    assert!((r.normals[5][0] - h).abs() < 1e-6 && (r.normals[5][1] - h).abs() < 1e-6);
}

// ---------------------------------------------------------------------------------------------
// Errors

#[test]
fn invalid_meshes_are_errors_not_panics() {
    let o = GlbOptions::default();
    let err = |m: &Mesh| write_glb(m, &o).unwrap_err();

    assert_eq!(err(&Mesh::default()), GltfError::EmptyMesh);
    let mut no_tris = cube();
    no_tris.indices.clear();
    assert_eq!(err(&no_tris), GltfError::EmptyMesh);
    let no_positions = Mesh { indices: vec![0, 1, 2], ..Mesh::default() };
    assert_eq!(err(&no_positions), GltfError::EmptyMesh);

    let mut m = cube();
    m.indices.push(0);
    assert_eq!(err(&m), GltfError::IndexCountNotMultipleOf3 { count: 37 });

    let mut m = cube();
    m.indices[7] = 8;
    assert_eq!(err(&m), GltfError::IndexOutOfRange { at: 7, index: 8, vertex_count: 8 });
    m.indices[7] = u32::MAX;
    assert!(matches!(err(&m), GltfError::IndexOutOfRange { index: u32::MAX, .. }));

    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut m = cube();
        m.positions[5][1] = bad;
        assert!(matches!(err(&m), GltfError::NonFinitePosition { vertex: 5, .. }), "{bad}");
    }

    let mut m = cube();
    m.normals = vec![[0.0, 0.0, 1.0]; 7];
    assert_eq!(
        err(&m),
        GltfError::AttributeCountMismatch { attribute: "normals", expected: 8, found: 7 }
    );
    let mut m = cube();
    m.colors = Some(vec![[0; 4]; 9]);
    assert_eq!(
        err(&m),
        GltfError::AttributeCountMismatch { attribute: "colors", expected: 8, found: 9 }
    );

    let mut m = cube();
    m.indices = vec![0, 0, 1, 2, 3, 3];
    assert_eq!(err(&m), GltfError::AllTrianglesDegenerate { triangles: 2 });

    for t in [[f64::NAN, 0.0, 0.0], [0.0, f64::INFINITY, 0.0]] {
        let opts = GlbOptions { translation: Some(t), ..Default::default() };
        assert!(matches!(write_glb(&cube(), &opts), Err(GltfError::NonFiniteTranslation { .. })));
    }

    // Every error has a message.
    assert!(GltfError::EmptyMesh.to_string().contains("empty"));
    let e: Box<dyn std::error::Error> = Box::new(GltfError::IndexCountNotMultipleOf3 { count: 4 });
    assert!(e.to_string().contains("multiple of 3"));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// Arbitrary small meshes (including out-of-range indices, odd index counts, degenerate
    /// triangles and non-finite values) never panic; what is written reads back.
    #[test]
    fn arbitrary_meshes_never_panic(
        positions in prop::collection::vec(prop::array::uniform3(
            prop_oneof![8 => -1e3f32..1e3, 1 => Just(f32::NAN), 1 => Just(0.0f32)]), 0..12),
        normals in prop::collection::vec(prop::array::uniform3(
            prop_oneof![8 => -2f32..2.0, 1 => Just(f32::NAN), 1 => Just(0.0f32)]), 0..12),
        indices in prop::collection::vec(0u32..13, 0..40),
        with_colors in any::<bool>(),
    ) {
        let n = positions.len();
        let normals = if normals.len() >= n { normals[..n].to_vec() } else { Vec::new() };
        let colors = with_colors.then(|| (0..n).map(|i| [i as u8, 1, 2, 255]).collect());
        let m = Mesh { positions, normals, colors, indices };
        match write_glb_with_report(&m, &GlbOptions::default()) {
            Ok((glb, report)) => {
                let r = read_back(&glb);
                prop_assert_eq!(&r.positions, &m.positions);
                prop_assert_eq!(&r.colors, &m.colors);
                let kept: Vec<u32> = m.indices.chunks(3)
                    .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
                    .flatten().copied().collect();
                prop_assert_eq!(&r.indices, &kept);
                prop_assert_eq!(report.triangles_written, kept.len() / 3);
                for nrm in &r.normals {
                    prop_assert!((len(*nrm) - 1.0).abs() < 1e-6);
                }
            }
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Mesh helpers

#[test]
fn watertight_positive_cases() {
    assert!(cube().is_watertight());
    assert!(icosphere(0, false).is_watertight());
    assert!(icosphere(2, true).is_watertight());
    assert!(torus(12, 8).is_watertight());
    // A tetrahedron, both orientations.
    let mut tet = Mesh {
        positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        indices: vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3],
        ..Mesh::default()
    };
    assert!(tet.is_watertight());
    tet.indices.reverse();
    assert!(tet.is_watertight());
}

#[test]
fn watertight_negative_cases() {
    assert!(!Mesh::default().is_watertight());
    // A hole: one triangle removed.
    let mut m = cube();
    m.indices.truncate(33);
    assert!(!m.is_watertight());
    // One face flipped: orientation inconsistent although every edge has two triangles.
    let mut m = cube();
    m.indices.swap(1, 2);
    assert!(!m.is_watertight());
    // A single open triangle / open square.
    let tri = Mesh {
        positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        indices: vec![0, 1, 2],
        ..Mesh::default()
    };
    assert!(!tri.is_watertight());
    // An edge shared by three triangles (a fin glued onto a closed cube).
    let mut m = cube();
    m.positions.push([0.5, 0.5, 2.0]);
    m.indices.extend_from_slice(&[4, 5, 8]);
    assert!(!m.is_watertight());
    // Two copies of the same closed cube sharing vertices: every edge used four times.
    let mut m = cube();
    let again = m.indices.clone();
    m.indices.extend(again);
    assert!(!m.is_watertight());
    // Degenerate triangle, out-of-range index, ragged index count.
    let mut m = cube();
    m.indices.extend_from_slice(&[0, 0, 1]);
    assert!(!m.is_watertight());
    let mut m = cube();
    m.indices[0] = 99;
    assert!(!m.is_watertight());
    let mut m = cube();
    m.indices.push(0);
    assert!(!m.is_watertight());
    // Unwelded cube: the same positions duplicated per triangle.
    let c = cube();
    let unwelded = Mesh {
        positions: c.indices.iter().map(|&i| c.positions[i as usize]).collect(),
        indices: (0..c.indices.len() as u32).collect(),
        ..Mesh::default()
    };
    assert!(!unwelded.is_watertight());
}

#[test]
fn cube_vertex_normals_point_outward() {
    let mut m = cube();
    m.compute_vertex_normals();
    assert_eq!(m.normals.len(), 8);
    let s = 1.0 / 3f32.sqrt();
    assert!(m.normals[0].iter().all(|&c| (c + s).abs() < 1e-6), "corner 0 gets equal shares");
    for (p, n) in m.positions.iter().zip(&m.normals) {
        assert!((len(*n) - 1.0).abs() < 1e-6);
        let outward = [p[0] - 0.5, p[1] - 0.5, p[2] - 0.5];
        let dot: f32 = (0..3).map(|k| outward[k] * n[k]).sum();
        assert!(dot > 0.0, "normal {n:?} at {p:?} points inward");
        // Every corner touches three faces, but each face's split into two triangles gives
        // its corners unequal area shares, so the components differ (from 1/√6 to 2/√6)
        // while their signs are the corner's.
        for k in 0..3 {
            assert_eq!(n[k].signum(), outward[k].signum(), "{n:?} at {p:?}");
            assert!(n[k].abs() > 0.4 && n[k].abs() < 0.82, "{n:?} at {p:?}");
        }
    }
    let b = m.bounds().unwrap();
    assert_eq!((b.min, b.max), ([0.0; 3], [1.0; 3]));
    // Icosphere: computed normals close to the radial direction.
    let mut ico = icosphere(3, false);
    let radial = ico.normals.clone();
    ico.compute_vertex_normals();
    for (a, b) in ico.normals.iter().zip(&radial) {
        let dot: f32 = (0..3).map(|k| a[k] * b[k]).sum();
        assert!(dot > 0.99, "{a:?} vs {b:?}");
    }
}

#[test]
fn test_meshes_are_valid_fixtures() {
    // The fixtures themselves: every face faces outward and the meshes are closed.
    for m in [cube(), icosphere(2, false), torus(10, 6)] {
        assert!(m.is_watertight());
    }
    let ico = icosphere(2, false);
    for t in ico.indices.chunks(3) {
        let p = |i: u32| ico.positions[i as usize];
        let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        assert!(n[0] * a[0] + n[1] * a[1] + n[2] * a[2] > 0.0);
    }
}

// ---------------------------------------------------------------------------------------------
// The Khronos validator


fn write_to(dir: &Path, name: &str, glb: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, glb).unwrap();
    p
}

#[test]
fn khronos_validator_finds_no_errors_or_warnings() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gltf_validator");
    std::fs::create_dir_all(&dir).unwrap();
    let o = GlbOptions::default();

    let big = torus(250, 200);
    assert_eq!(big.triangle_count(), 100_000);
    let mut messy = icosphere(2, true);
    messy.positions.push([0.0, 0.0, 0.0]); // unused vertex
    messy.normals.push([0.0, 0.0, 0.0]); // with a zero normal
    messy.colors.as_mut().unwrap().push([0, 0, 0, 0]);
    messy.normals[3] = [f32::NAN; 3];
    messy.normals[4] = [0.0, 5.0, 0.0];
    messy.indices.extend_from_slice(&[1, 1, 2, 7, 8, 7]); // degenerate triangles
    let (messy_glb, messy_report) = write_glb_with_report(&messy, &o).unwrap();
    assert_eq!(messy_report.degenerate_triangles_dropped, 2);
    assert_eq!(messy_report.unused_vertices, 1);
    assert_eq!(messy_report.normals_repaired, 2);

    let files = vec![
        write_to(&dir, "cube.glb", &write_glb(&cube(), &o).unwrap()),
        write_to(&dir, "icosphere_colors.glb", &write_glb(&icosphere(4, true), &o).unwrap()),
        write_to(&dir, "torus_100k.glb", &write_glb(&big, &o).unwrap()),
        write_to(
            &dir,
            "translated_5e6.glb",
            &write_glb(
                &icosphere(2, false),
                &GlbOptions {
                    translation: Some([5e6, -5e6, 5e6 + 0.125]),
                    name: Some("reconstruction \"#1\" \\ é\n".into()),
                    ..Default::default()
                },
            )
            .unwrap(),
        ),
        write_to(&dir, "messy_degenerate_unused.glb", &messy_glb),
    ];
    let (ok, text) = run_validator(&files);
    println!("{text}");
    assert!(ok, "the glTF validator reported errors or warnings:\n{text}");
    assert!(text.contains("TOTAL errors=0 warnings=0"), "{text}");
    // Not even infos for the clean meshes.
    assert!(text.contains("cube.glb: errors=0 warnings=0 infos=0 hints=0"), "{text}");
    assert!(text.contains("torus_100k.glb: errors=0 warnings=0 infos=0 hints=0"), "{text}");
    assert!(text.contains("triangles=100000"), "{text}");
}

#[test]
fn khronos_validator_script_fails_on_a_broken_file() {
    // The script must exit non-zero when the validator finds errors, or the test above proves
    // nothing: break the declared POSITION max of a valid file (same length, so the GLB
    // container stays intact).
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gltf_validator");
    std::fs::create_dir_all(&dir).unwrap();
    let mut glb = write_glb(&cube(), &GlbOptions::default()).unwrap();
    let needle = b"\"max\":[1,1,1]";
    let at = glb.windows(needle.len()).position(|w| w == needle).expect("max in JSON");
    glb[at + needle.len() - 2] = b'2';
    let (ok, text) = run_validator(&[write_to(&dir, "broken_max.glb", &glb)]);
    assert!(!ok, "{text}");
    assert!(text.contains("ACCESSOR_MAX_MISMATCH"), "{text}");
}

/// Every compact form of `mesh`, written with `translation`.
fn compact_forms(mesh: &Mesh, translation: Option<[f64; 3]>) -> Vec<(Compression, Vec<u8>)> {
    [Compression::Quantized, Compression::Meshopt]
        .into_iter()
        .map(|c| (c, write_glb(mesh, &GlbOptions { translation, compression: c, ..Default::default() }).unwrap()))
        .collect()
}

#[test]
fn compact_glbs_read_back_to_the_same_surface() {
    // A torus with colours, far from the origin: every compact form must give back the same
    // triangles (as position triples, in any vertex order, each corner within the
    // quantization step) and nothing else.
    let mut mesh = torus(60, 40);
    mesh.colors = Some((0..mesh.positions.len()).map(|i| [(i % 256) as u8, 3, 200, 255]).collect());
    let t = [1000.5, -20.0, 3.25];
    let extent = 2.6f64; // the torus's largest side: 2 × (1 + 0.3), see `torus`
    let step = extent / f64::from((1u32 << 14) - 1);
    let plain = nkrr::io::gltf_read::read_glb(&write_glb(&mesh, &GlbOptions { translation: Some(t), ..Default::default() }).unwrap()).unwrap();
    // A triangle as its corners' indices in `plain`, rotated to start at the smallest (the
    // codec may rotate corners, never flip them).
    let canonical = |t: [u32; 3]| {
        let k = (0..3).min_by_key(|&k| t[k]).unwrap();
        [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
    };
    let mut want: Vec<[u32; 3]> = plain.indices.chunks_exact(3).map(|t| canonical([t[0], t[1], t[2]])).collect();
    want.sort_unstable();
    for (c, glb) in compact_forms(&mesh, Some(t)) {
        let back = nkrr::io::gltf_read::read_glb(&glb).unwrap_or_else(|e| panic!("{c:?}: {e}"));
        assert_eq!(back.triangle_count(), plain.triangle_count(), "{c:?}");
        assert_eq!(back.positions.len(), plain.positions.len(), "{c:?}");
        // Each read-back vertex is its nearest plain one, within half a step per axis (plus
        // f32 rounding at |x| = 1000).
        let nearest: Vec<u32> = back
            .positions
            .iter()
            .map(|p| {
                let dist = |q: &[f32; 3]| (0..3).map(|a| (f64::from(p[a]) - f64::from(q[a])).abs()).fold(0.0, f64::max);
                let (i, q) = plain.positions.iter().enumerate().min_by(|x, y| dist(x.1).total_cmp(&dist(y.1))).unwrap();
                assert!(dist(q) <= 0.5 * step + 2e-4, "{c:?}: a vertex moved by {} (step {step})", dist(q));
                i as u32
            })
            .collect();
        let mut got: Vec<[u32; 3]> = back.indices.chunks_exact(3).map(|t| canonical([t[0], t[1], t[2]].map(|i| nearest[i as usize]))).collect();
        got.sort_unstable();
        assert_eq!(got, want, "{c:?}: other triangles");
        assert!(back.is_watertight(), "{c:?}");
    }
}

#[test]
fn compact_glbs_are_small_and_valid() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gltf_validator_compact");
    std::fs::create_dir_all(&dir).unwrap();
    let big = torus(250, 200);
    let plain = write_glb(&big, &GlbOptions::default()).unwrap();
    let forms = compact_forms(&big, None);
    let (quantized, meshopt) = (&forms[0].1, &forms[1].1);
    // Quantized: 8 + 4 bytes a vertex and 4-byte indices (50k vertices need u32), against 24 + 4.
    assert!(quantized.len() * 10 < plain.len() * 6, "{} vs {}", quantized.len(), plain.len());
    assert!(meshopt.len() * 4 < plain.len(), "meshopt {} vs plain {}", meshopt.len(), plain.len());
    let mut files = vec![write_to(&dir, "torus_quantized.glb", quantized), write_to(&dir, "torus_meshopt.glb", meshopt)];
    for (c, glb) in compact_forms(&icosphere(3, true), Some([5e6, -5e6, 1.0])) {
        files.push(write_to(&dir, &format!("icosphere_colors_{c:?}.glb"), &glb));
    }
    let (ok, text) = run_validator(&files);
    println!("{text}");
    assert!(ok && text.contains("TOTAL errors=0 warnings=0"), "{text}");
    // The validator cannot look inside EXT_meshopt_compression (it says so as an info); the
    // decoding is checked by the read-back test above and by three.js in the browser tests.
    assert!(text.contains("torus_quantized.glb: errors=0 warnings=0 infos=0 hints=0"), "{text}");
}

#[test]
fn corrupt_compressed_views_are_errors_not_panics() {
    let glb = write_glb(&icosphere(3, false), &GlbOptions { compression: Compression::Meshopt, ..Default::default() }).unwrap();
    // Flip bytes through the BIN chunk: every read must end in Ok or a message, never a panic.
    let bin_start = 20 + u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize + 8;
    let mut errors = 0;
    for at in (bin_start..glb.len()).step_by(7) {
        let mut bad = glb.clone();
        bad[at] ^= 0x5a;
        if nkrr::io::gltf_read::read_glb(&bad).is_err() {
            errors += 1;
        }
    }
    assert!(errors > 0, "no corruption was noticed");
    // A compressed view that points elsewhere is named.
    let text = String::from_utf8_lossy(&glb).into_owned();
    let needle = "\"EXT_meshopt_compression\":{\"buffer\":0,\"byteOffset\":0,";
    assert!(text.contains(needle), "{text}");
    let mut bad = glb.clone();
    let at = bad.windows(needle.len()).position(|w| w == needle.as_bytes()).unwrap() + needle.len() - 2;
    bad[at] = b'9';
    let e = nkrr::io::gltf_read::read_glb(&bad).unwrap_err().to_string();
    assert!(e.contains("bufferViews[0]") && e.contains("does not decode"), "{e}");
}
