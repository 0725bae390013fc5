//! Tests of the PLY reader: every format, property types, colours, normals, skipped elements,
//! header quirks, every error case (variant and location in the message), the evaluation clouds,
//! and a property test that writes random files with a test-side writer and reads them back.

use nkrr::io::ply::{
    read_ply, read_ply_header, BodyPos, PlyCloud, PlyError, PlyFormat, PropertyKind, ScalarType,
};
use proptest::prelude::*;
use std::path::PathBuf;

// ---------------------------------------------------------------------------------------------
// A small test-side writer.
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq)]
enum Fmt {
    Ascii,
    Le,
    Be,
}

const FMTS: [Fmt; 3] = [Fmt::Ascii, Fmt::Le, Fmt::Be];

impl Fmt {
    fn name(self) -> &'static str {
        match self {
            Fmt::Ascii => "ascii",
            Fmt::Le => "binary_little_endian",
            Fmt::Be => "binary_big_endian",
        }
    }
    fn ply(self) -> PlyFormat {
        match self {
            Fmt::Ascii => PlyFormat::Ascii,
            Fmt::Le => PlyFormat::BinaryLittleEndian,
            Fmt::Be => PlyFormat::BinaryBigEndian,
        }
    }
}

const TYPES: [ScalarType; 8] = [
    ScalarType::I8,
    ScalarType::U8,
    ScalarType::I16,
    ScalarType::U16,
    ScalarType::I32,
    ScalarType::U32,
    ScalarType::F32,
    ScalarType::F64,
];

/// A value of a given type; integers are held as i64/f64 and written in the declared type.
#[derive(Clone, Copy, Debug)]
struct Val(ScalarType, f64);

#[derive(Clone, Debug)]
enum Cell {
    S(Val),
    L(ScalarType, Vec<Val>),
}

#[derive(Clone, Debug)]
struct Prop {
    name: String,
    /// Header spelling of the type(s): the writer alternates between classic and sized names.
    decl: String,
}

#[derive(Clone, Debug)]
struct Elem {
    name: String,
    props: Vec<Prop>,
    rows: Vec<Vec<Cell>>,
}

fn alias(t: ScalarType, sized: bool) -> &'static str {
    if !sized {
        return t.name();
    }
    match t {
        ScalarType::I8 => "int8",
        ScalarType::U8 => "uint8",
        ScalarType::I16 => "int16",
        ScalarType::U16 => "uint16",
        ScalarType::I32 => "int32",
        ScalarType::U32 => "uint32",
        ScalarType::F32 => "float32",
        ScalarType::F64 => "float64",
    }
}

fn scalar(name: &str, t: ScalarType) -> Prop {
    Prop {
        name: name.into(),
        decl: t.name().into(),
    }
}

fn list(name: &str, c: ScalarType, i: ScalarType) -> Prop {
    Prop {
        name: name.into(),
        decl: format!("list {} {}", c.name(), i.name()),
    }
}

fn put(out: &mut Vec<u8>, fmt: Fmt, v: Val) {
    use ScalarType::*;
    if fmt == Fmt::Ascii {
        let s = match v.0 {
            F32 => format!("{:?}", v.1 as f32),
            F64 => format!("{:?}", v.1),
            _ => format!("{}", v.1 as i64),
        };
        out.extend_from_slice(s.as_bytes());
        return;
    }
    macro_rules! b {
        ($x:expr) => {
            if fmt == Fmt::Le {
                out.extend_from_slice(&$x.to_le_bytes())
            } else {
                out.extend_from_slice(&$x.to_be_bytes())
            }
        };
    }
    match v.0 {
        I8 => b!(v.1 as i8),
        U8 => b!(v.1 as u8),
        I16 => b!(v.1 as i16),
        U16 => b!(v.1 as u16),
        I32 => b!(v.1 as i32),
        U32 => b!(v.1 as u32),
        F32 => b!(v.1 as f32),
        F64 => b!(v.1),
    }
}

struct Style {
    crlf: bool,
    comments: Vec<String>,
    obj_info: Vec<String>,
    /// Separator between header tokens (" ", "\t", "   ").
    sep: &'static str,
}

impl Default for Style {
    fn default() -> Self {
        Style {
            crlf: false,
            comments: vec![],
            obj_info: vec![],
            sep: " ",
        }
    }
}

fn write_ply(fmt: Fmt, elems: &[Elem], style: &Style) -> Vec<u8> {
    let nl = if style.crlf { "\r\n" } else { "\n" };
    let sep = style.sep;
    let mut h = format!("ply{nl}format{sep}{}{sep}1.0{nl}", fmt.name());
    for c in &style.comments {
        h += &format!("comment {c}{nl}");
    }
    for e in elems {
        h += &format!("element{sep}{}{sep}{}{nl}", e.name, e.rows.len());
        for p in &e.props {
            h += &format!(
                "property{sep}{}{sep}{}{nl}",
                p.decl.replace(' ', sep),
                p.name
            );
        }
    }
    for c in &style.obj_info {
        h += &format!("obj_info {c}{nl}");
    }
    h += &format!("end_header{nl}");
    let mut out = h.into_bytes();
    for e in elems {
        for row in &e.rows {
            for (i, cell) in row.iter().enumerate() {
                if fmt == Fmt::Ascii && i > 0 {
                    out.push(b' ');
                }
                match cell {
                    Cell::S(v) => put(&mut out, fmt, *v),
                    Cell::L(ct, items) => {
                        put(&mut out, fmt, Val(*ct, items.len() as f64));
                        for it in items {
                            if fmt == Fmt::Ascii {
                                out.push(b' ');
                            }
                            put(&mut out, fmt, *it);
                        }
                    }
                }
            }
            if fmt == Fmt::Ascii {
                out.extend_from_slice(nl.as_bytes());
            }
        }
    }
    out
}

fn f(v: f32) -> Val {
    Val(ScalarType::F32, v as f64)
}

/// A vertex element with float x, y, z.
fn xyz_elem(points: &[[f32; 3]]) -> Elem {
    Elem {
        name: "vertex".into(),
        props: vec![
            scalar("x", ScalarType::F32),
            scalar("y", ScalarType::F32),
            scalar("z", ScalarType::F32),
        ],
        rows: points
            .iter()
            .map(|p| p.iter().map(|&c| Cell::S(f(c))).collect())
            .collect(),
    }
}

/// A face element with `n` triangles (uchar count, int indices) plus a scalar flag.
fn face_elem(n: usize) -> Elem {
    Elem {
        name: "face".into(),
        props: vec![
            list("vertex_indices", ScalarType::U8, ScalarType::I32),
            scalar("flags", ScalarType::U16),
        ],
        rows: (0..n)
            .map(|i| {
                vec![
                    Cell::L(
                        ScalarType::U8,
                        (0..3 + i % 3)
                            .map(|k| Val(ScalarType::I32, ((i + k) % 4) as f64))
                            .collect(),
                    ),
                    Cell::S(Val(ScalarType::U16, i as f64)),
                ]
            })
            .collect(),
    }
}

const PTS: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.5, -2.25, 3.0],
    [-0.1, 0.2, 1e-7],
    [1e30, -7.0, 0.333],
];

fn ok(bytes: &[u8]) -> PlyCloud {
    match read_ply(bytes) {
        Ok(c) => c,
        Err(e) => panic!(
            "read_ply failed: {e}\n{}",
            String::from_utf8_lossy(&bytes[..bytes.len().min(600)])
        ),
    }
}

fn err(bytes: &[u8]) -> PlyError {
    match read_ply(bytes) {
        Ok(c) => panic!("expected an error, got {} points", c.cloud.len()),
        Err(e) => e,
    }
}

fn header_only(fmt: &str, vertex_props: &str, count: u64) -> String {
    format!("ply\nformat {fmt} 1.0\nelement vertex {count}\n{vertex_props}end_header\n")
}

const XYZ: &str = "property float x\nproperty float y\nproperty float z\n";

// ---------------------------------------------------------------------------------------------
// Formats and types.
// ---------------------------------------------------------------------------------------------

#[test]
fn float_xyz_every_format() {
    for fmt in FMTS {
        let bytes = write_ply(fmt, &[xyz_elem(&PTS)], &Style::default());
        let r = ok(&bytes);
        assert_eq!(r.cloud.positions, PTS.to_vec(), "{fmt:?}");
        assert_eq!(r.cloud.normals, None);
        assert_eq!(r.cloud.colors, None);
        assert_eq!(r.info.format, fmt.ply());
        assert_eq!(r.info.vertex_count, 4);
        assert_eq!(r.info.dropped_non_finite, 0);
        let names: Vec<_> = r
            .info
            .vertex_properties
            .iter()
            .map(|p| p.name.as_str())
            .collect();
        assert_eq!(names, ["x", "y", "z"]);
        assert!(r
            .info
            .vertex_properties
            .iter()
            .all(|p| p.kind == PropertyKind::Scalar(ScalarType::F32)));
        assert!(r.info.other_elements.is_empty());
    }
}

#[test]
fn xyz_of_every_numeric_type_every_format_both_spellings() {
    // Values representable in every type, signed types get a negative one.
    for fmt in FMTS {
        for t in TYPES {
            for sized in [false, true] {
                let signed = matches!(
                    t,
                    ScalarType::I8
                        | ScalarType::I16
                        | ScalarType::I32
                        | ScalarType::F32
                        | ScalarType::F64
                );
                let pts: Vec<[f64; 3]> = vec![
                    [0.0, 1.0, 2.0],
                    [100.0, if signed { -100.0 } else { 7.0 }, 127.0],
                    [if t.is_float() { 0.5 } else { 3.0 }, 9.0, 12.0],
                ];
                let e = Elem {
                    name: "vertex".into(),
                    props: ["x", "y", "z"]
                        .iter()
                        .map(|n| Prop {
                            name: n.to_string(),
                            decl: alias(t, sized).into(),
                        })
                        .collect(),
                    rows: pts
                        .iter()
                        .map(|p| p.iter().map(|&c| Cell::S(Val(t, c))).collect())
                        .collect(),
                };
                let r = ok(&write_ply(fmt, &[e], &Style::default()));
                let want: Vec<[f32; 3]> = pts.iter().map(|p| p.map(|c| c as f32)).collect();
                assert_eq!(r.cloud.positions, want, "{fmt:?} {t:?} sized={sized}");
                assert_eq!(r.info.vertex_properties[0].kind, PropertyKind::Scalar(t));
            }
        }
    }
}

#[test]
fn extreme_integer_and_double_coordinates() {
    for fmt in FMTS {
        let e = Elem {
            name: "vertex".into(),
            props: vec![
                scalar("x", ScalarType::I32),
                scalar("y", ScalarType::U32),
                scalar("z", ScalarType::F64),
            ],
            rows: vec![
                vec![
                    Cell::S(Val(ScalarType::I32, i32::MIN as f64)),
                    Cell::S(Val(ScalarType::U32, u32::MAX as f64)),
                    Cell::S(Val(ScalarType::F64, 1.0e-300)),
                ],
                vec![
                    Cell::S(Val(ScalarType::I32, i32::MAX as f64)),
                    Cell::S(Val(ScalarType::U32, 0.0)),
                    Cell::S(Val(ScalarType::F64, -123456.789)),
                ],
            ],
        };
        let r = ok(&write_ply(fmt, &[e], &Style::default()));
        // Far-off int/double coordinates are stored relative to the first point's, rounded
        // (nkrr::cloud::origin_for): x and y here; z's first value is small, so it stays put.
        let o = [i32::MIN as f64, u32::MAX as f64, 0.0];
        assert_eq!(r.cloud.origin, o, "{fmt:?}");
        assert_eq!(
            r.cloud.positions,
            vec![
                [0.0, 0.0, 1.0e-300f64 as f32],
                [(i32::MAX as f64 - o[0]) as f32, (0.0 - o[1]) as f32, -123456.789f64 as f32]
            ],
            "{fmt:?}"
        );
    }
}

#[test]
fn mixed_types_and_unknown_vertex_properties_are_skipped() {
    for fmt in FMTS {
        let e = Elem {
            name: "vertex".into(),
            props: vec![
                scalar("confidence", ScalarType::F64),
                scalar("z", ScalarType::I16),
                scalar("label", ScalarType::U8),
                scalar("x", ScalarType::F32),
                list("neighbours", ScalarType::U32, ScalarType::F64),
                scalar("y", ScalarType::U16),
                scalar("intensity", ScalarType::I8),
            ],
            rows: (0..5)
                .map(|i| {
                    let i = i as f64;
                    vec![
                        Cell::S(Val(ScalarType::F64, 0.25 * i)),
                        Cell::S(Val(ScalarType::I16, -i)),
                        Cell::S(Val(ScalarType::U8, 200.0)),
                        Cell::S(Val(ScalarType::F32, i + 0.5)),
                        Cell::L(
                            ScalarType::U32,
                            (0..(i as usize * 2))
                                .map(|k| Val(ScalarType::F64, k as f64))
                                .collect(),
                        ),
                        Cell::S(Val(ScalarType::U16, 1000.0 + i)),
                        Cell::S(Val(ScalarType::I8, -5.0)),
                    ]
                })
                .collect(),
        };
        let r = ok(&write_ply(fmt, &[e], &Style::default()));
        let want: Vec<[f32; 3]> = (0..5)
            .map(|i| [i as f32 + 0.5, 1000.0 + i as f32, -(i as f32)])
            .collect();
        assert_eq!(r.cloud.positions, want, "{fmt:?}");
        assert_eq!(r.info.vertex_properties.len(), 7);
        assert_eq!(
            r.info.vertex_properties[4].kind,
            PropertyKind::List {
                count: ScalarType::U32,
                item: ScalarType::F64
            }
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Colours and normals.
// ---------------------------------------------------------------------------------------------

fn colour_elem(t: ScalarType, alpha: bool, rows: &[([f32; 3], [f64; 4])]) -> Elem {
    let mut props = vec![
        scalar("x", ScalarType::F32),
        scalar("y", ScalarType::F32),
        scalar("z", ScalarType::F32),
    ];
    props.extend(["red", "green", "blue"].iter().map(|n| scalar(n, t)));
    if alpha {
        props.push(scalar("alpha", t));
    }
    Elem {
        name: "vertex".into(),
        props,
        rows: rows
            .iter()
            .map(|(p, c)| {
                let mut r: Vec<Cell> = p.iter().map(|&v| Cell::S(f(v))).collect();
                r.extend(
                    c[..if alpha { 4 } else { 3 }]
                        .iter()
                        .map(|&v| Cell::S(Val(t, v))),
                );
                r
            })
            .collect(),
    }
}

#[test]
fn uchar_colours_with_and_without_alpha() {
    for fmt in FMTS {
        let rows = [
            ([0.0, 1.0, 2.0], [0.0, 128.0, 255.0, 7.0]),
            ([3.0, 4.0, 5.0], [1.0, 2.0, 3.0, 255.0]),
        ];
        let r = ok(&write_ply(
            fmt,
            &[colour_elem(ScalarType::U8, true, &rows)],
            &Style::default(),
        ));
        assert_eq!(
            r.cloud.colors,
            Some(vec![[0, 128, 255, 7], [1, 2, 3, 255]]),
            "{fmt:?}"
        );
        let r = ok(&write_ply(
            fmt,
            &[colour_elem(ScalarType::U8, false, &rows)],
            &Style::default(),
        ));
        assert_eq!(
            r.cloud.colors,
            Some(vec![[0, 128, 255, 255], [1, 2, 3, 255]]),
            "{fmt:?}"
        );
    }
}

#[test]
fn float_colours_are_scaled_from_unit_range_and_clamped() {
    for fmt in FMTS {
        for t in [ScalarType::F32, ScalarType::F64] {
            let rows = [
                ([0.0, 0.0, 0.0], [0.0, 0.5, 1.0, 1.0]),
                ([1.0, 1.0, 1.0], [-0.5, 2.0, 100.0 / 255.0, 0.25]),
            ];
            let r = ok(&write_ply(
                fmt,
                &[colour_elem(t, true, &rows)],
                &Style::default(),
            ));
            assert_eq!(
                r.cloud.colors,
                Some(vec![[0, 128, 255, 255], [0, 255, 100, 64]]),
                "{fmt:?} {t:?}"
            );
        }
    }
}

#[test]
fn sixteen_bit_colours_are_scaled_and_wide_ints_clamped() {
    for fmt in FMTS {
        let rows = [([0.0, 0.0, 0.0], [0.0, 65535.0, 257.0 * 100.0, 32768.0])];
        let r = ok(&write_ply(
            fmt,
            &[colour_elem(ScalarType::U16, true, &rows)],
            &Style::default(),
        ));
        assert_eq!(r.cloud.colors, Some(vec![[0, 255, 100, 128]]), "{fmt:?}");
        let rows = [([0.0, 0.0, 0.0], [-4.0, 300.0, 17.0, 255.0])];
        let r = ok(&write_ply(
            fmt,
            &[colour_elem(ScalarType::I32, false, &rows)],
            &Style::default(),
        ));
        assert_eq!(r.cloud.colors, Some(vec![[0, 255, 17, 255]]), "{fmt:?}");
    }
}

#[test]
fn incomplete_colours_are_ignored_and_diffuse_aliases_accepted() {
    let bytes = header_only(
        "ascii",
        &format!("{XYZ}property uchar red\nproperty uchar green\n"),
        1,
    ) + "1 2 3 4 5\n";
    let r = ok(bytes.as_bytes());
    assert_eq!(r.cloud.colors, None);
    assert_eq!(r.cloud.positions, vec![[1.0, 2.0, 3.0]]);
    let props = format!("{XYZ}property uchar diffuse_red\nproperty uchar diffuse_green\nproperty uchar diffuse_blue\n");
    let bytes = header_only("ascii", &props, 1) + "1 2 3 4 5 6\n";
    assert_eq!(
        ok(bytes.as_bytes()).cloud.colors,
        Some(vec![[4, 5, 6, 255]])
    );
}

#[test]
fn normals_every_format() {
    for fmt in FMTS {
        for t in [ScalarType::F32, ScalarType::F64] {
            let mut e = xyz_elem(&PTS[..3]);
            e.props
                .extend(["nx", "ny", "nz"].iter().map(|n| scalar(n, t)));
            let ns = [[0.0, 0.0, 1.0], [0.6, -0.8, 0.0], [-1.0, 0.0, 0.0]];
            for (row, n) in e.rows.iter_mut().zip(ns) {
                row.extend(n.iter().map(|&v| Cell::S(Val(t, v))));
            }
            let r = ok(&write_ply(fmt, &[e], &Style::default()));
            let want: Vec<[f32; 3]> = ns.iter().map(|n| n.map(|v| v as f32)).collect();
            assert_eq!(r.cloud.normals, Some(want), "{fmt:?} {t:?}");
            assert_eq!(r.cloud.positions, PTS[..3].to_vec());
        }
    }
}

#[test]
fn normals_and_colours_together_stay_aligned_when_vertices_are_dropped() {
    let props = format!(
        "{XYZ}property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n"
    );
    let body = "0 0 0 1 0 0 10 20 30\nnan 0 0 0 1 0 40 50 60\n1 inf 1 0 0 1 1 1 1\n2 2 2 0 0 -1 70 80 90\n";
    let r = ok((header_only("ascii", &props, 4) + body).as_bytes());
    assert_eq!(r.info.dropped_non_finite, 2);
    assert_eq!(r.cloud.positions, vec![[0.0, 0.0, 0.0], [2.0, 2.0, 2.0]]);
    assert_eq!(
        r.cloud.normals,
        Some(vec![[1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    );
    assert_eq!(
        r.cloud.colors,
        Some(vec![[10, 20, 30, 255], [70, 80, 90, 255]])
    );
}

#[test]
fn non_finite_vertices_are_dropped_and_counted_in_binary() {
    for fmt in [Fmt::Le, Fmt::Be] {
        let pts = [
            [0.0, 1.0, 2.0],
            [f32::NAN, 0.0, 0.0],
            [1.0, f32::NEG_INFINITY, 0.0],
            [3.0, 4.0, 5.0],
        ];
        let r = ok(&write_ply(fmt, &[xyz_elem(&pts)], &Style::default()));
        assert_eq!(r.info.dropped_non_finite, 2);
        assert_eq!(r.info.vertex_count, 4);
        assert_eq!(r.cloud.positions, vec![[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]);
    }
    // A finite double too far from the origin for an f32 is refused, saying so (issue 16: it
    // was dropped as "NaN or infinite"). Here the first point, 1e300, is the origin.
    let e = Elem {
        name: "vertex".into(),
        props: ["x", "y", "z"]
            .iter()
            .map(|n| scalar(n, ScalarType::F64))
            .collect(),
        rows: vec![
            [1e300, 0.0, 0.0]
                .iter()
                .map(|&v| Cell::S(Val(ScalarType::F64, v)))
                .collect(),
            [1.0, 2.0, 3.0]
                .iter()
                .map(|&v| Cell::S(Val(ScalarType::F64, v)))
                .collect(),
        ],
    };
    let e = err(&write_ply(Fmt::Le, &[e], &Style::default()));
    assert!(matches!(e, PlyError::TooLarge { index: 1, .. }), "{e:?}");
    assert_msg(&e, &["vertex 1", "too far for a 32-bit float", "first point"]);
}

// ---------------------------------------------------------------------------------------------
// Other elements and header quirks.
// ---------------------------------------------------------------------------------------------

#[test]
fn faces_and_edges_before_and_after_vertices_every_format() {
    for fmt in FMTS {
        let edges = Elem {
            name: "edge".into(),
            props: vec![
                scalar("vertex1", ScalarType::I32),
                scalar("vertex2", ScalarType::I32),
            ],
            rows: (0..3)
                .map(|i| vec![Cell::S(Val(ScalarType::I32, i as f64)); 2])
                .collect(),
        };
        let empty_marker = Elem {
            name: "marker".into(),
            props: vec![],
            rows: vec![vec![]; 5],
        };
        let layouts: Vec<Vec<Elem>> = vec![
            vec![face_elem(7), xyz_elem(&PTS)],
            vec![xyz_elem(&PTS), face_elem(7)],
            vec![
                face_elem(2),
                edges.clone(),
                xyz_elem(&PTS),
                face_elem(9),
                edges.clone(),
            ],
            vec![
                empty_marker,
                face_elem(0),
                xyz_elem(&PTS),
                Elem {
                    name: "face".into(),
                    ..face_elem(300)
                },
            ],
        ];
        for elems in layouts {
            let names: Vec<(String, u64)> = elems
                .iter()
                .filter(|e| e.name != "vertex")
                .map(|e| (e.name.clone(), e.rows.len() as u64))
                .collect();
            let r = ok(&write_ply(fmt, &elems, &Style::default()));
            assert_eq!(r.cloud.positions, PTS.to_vec(), "{fmt:?} {names:?}");
            assert_eq!(r.info.other_elements, names);
        }
    }
}

#[test]
fn crlf_comments_obj_info_tabs_and_spaces() {
    for fmt in FMTS {
        for (crlf, sep) in [(true, " "), (false, "\t"), (true, "  \t "), (false, "   ")] {
            let style = Style {
                crlf,
                sep,
                comments: vec!["made by a test".into(), "".into(), "Ünïcode ✓".into()],
                obj_info: vec!["scanner 3000".into()],
            };
            let r = ok(&write_ply(
                fmt,
                &[face_elem(3), xyz_elem(&PTS), face_elem(2)],
                &style,
            ));
            assert_eq!(
                r.cloud.positions,
                PTS.to_vec(),
                "{fmt:?} crlf={crlf} sep={sep:?}"
            );
            assert_eq!(r.info.comments, ["made by a test", "", "Ünïcode ✓"]);
            assert_eq!(r.info.obj_info, ["scanner 3000"]);
        }
    }
}

#[test]
fn ascii_records_use_odd_whitespace_one_line_each() {
    let bytes = header_only("ascii", XYZ, 3) + "1\t2 \r\n\r\n 3   4\t5\r\n\n6 7 8 \n";
    let e = err(bytes.as_bytes());
    assert!(matches!(e, PlyError::ShortLine { index: 0, first: 8, line: 10, .. }), "{e:?}");
    let bytes = header_only("ascii", XYZ, 3) + "1\t2 3\r\n\r\n 4   5\t6\r\n\n7 8 9 \n";
    assert_eq!(ok(bytes.as_bytes()).cloud.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]);
    // Leading/trailing spaces on header lines and blank header lines are tolerated.
    let bytes = "ply \r\n  format ascii 1.0  \r\n\r\nelement vertex 1\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n1e3 -2.5E-2 +7\n";
    assert_eq!(
        ok(bytes.as_bytes()).cloud.positions,
        vec![[1000.0, -0.025, 7.0]]
    );
}

#[test]
fn an_ascii_line_with_a_value_too_many_or_too_few_is_refused_where_it_is() {
    // Read as a stream of tokens these were (0,0,0) and (9,9,1): a misread without a word.
    let e = err((header_only("ascii", XYZ, 2) + "0 0 0 9 9\n1 1 1\n").as_bytes());
    assert_eq!(e, PlyError::LongLine { element: "vertex".into(), index: 0, properties: 3, line: 8, extra: "9 9".into() });
    assert_msg(&e, &["line 8", "record 0", "'9 9' left over", "3 properties"]);
    let e = err((header_only("ascii", XYZ, 2) + "0 0.0000\n1 1 1\n").as_bytes());
    assert!(matches!(e, PlyError::ShortLine { index: 0, first: 8, line: 9, .. }), "{e:?}");
    assert_msg(&e, &["line 8", "value missing on line 8"]);
    // The same in a skipped element, and on the last line (the body ends).
    let faces = "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\nelement vertex 1\n\
                 property float x\nproperty float y\nproperty float z\nend_header\n3 0 1 2 7\n0 0 0\n";
    assert!(matches!(err(faces.as_bytes()), PlyError::LongLine { ref element, .. } if element == "face"));
    assert!(matches!(err((header_only("ascii", XYZ, 2) + "0 0 0\n1 1.5\n").as_bytes()), PlyError::UnexpectedEof { index: 1, .. }));
}

#[test]
fn classic_mac_line_endings_read_in_the_header_and_an_ascii_body() {
    let ascii = "ply\rformat ascii 1.0\rcomment cr only\relement vertex 2\rproperty float x\rproperty float y\r\
                 property float z\rend_header\r1 2 3\r4 5 6\r";
    let r = ok(ascii.as_bytes());
    assert_eq!(r.cloud.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    assert_eq!(r.info.comments, ["cr only"]);
    let e = err(ascii.replace("4 5 6", "4 5 6 7").as_bytes());
    assert!(matches!(e, PlyError::LongLine { line: 10, .. }), "{e:?}");
    let mut binary = b"ply\rformat binary_little_endian 1.0\relement vertex 1\rproperty uchar x\rproperty uchar y\r\
                       property uchar z\rend_header\r"
        .to_vec();
    binary.extend_from_slice(b"\r\n\x07");
    assert_eq!(ok(&binary).cloud.positions, vec![[13.0, 10.0, 7.0]]);
}

#[test]
fn a_second_x_property_is_refused() {
    let bytes = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n1 2 3 4\n";
    let e = err(bytes.as_bytes());
    assert!(matches!(e, PlyError::MalformedHeader { line: 5, .. }), "{e:?}");
    assert_msg(&e, &["line 5", "second vertex property of this name", "property float x"]);
    // A repeated property the reader does not use is harmless.
    let bytes = bytes.replace("property float x\nproperty float x", "property float x\nproperty float i\nproperty float i");
    assert_eq!(ok((bytes.replace("1 2 3 4", "1 8 9 2 3")).as_bytes()).cloud.positions, vec![[1.0, 2.0, 3.0]]);
}

#[test]
fn an_ascii_body_declared_binary_is_refused_with_the_cause() {
    for fmt in ["binary_little_endian", "binary_big_endian"] {
        let body: String = (0..20).map(|i| format!("{}.25 {} -{}e-1\n", i, i * 3, i)).collect();
        let e = err((header_only(fmt, XYZ, 20) + &body).as_bytes());
        assert_eq!(e, PlyError::TextBody { format: if fmt.contains("little") { PlyFormat::BinaryLittleEndian } else { PlyFormat::BinaryBigEndian } });
        assert_msg(&e, &[fmt, "format ascii 1.0"]);
    }
}

#[test]
fn binary_body_after_crlf_end_header_starts_after_the_newline() {
    // A body whose first byte is '\n' or '\r' must not be eaten by the header.
    let mut bytes =
        b"ply\r\nformat binary_little_endian 1.0\r\nelement vertex 1\r\nproperty uchar x\r\n\
                      property uchar y\r\nproperty uchar z\r\nend_header\r\n"
            .to_vec();
    bytes.extend_from_slice(b"\n\r ");
    assert_eq!(ok(&bytes).cloud.positions, vec![[10.0, 13.0, 32.0]]);
}

#[test]
fn data_after_the_last_element_is_not_read_and_said() {
    let mut bytes = write_ply(Fmt::Le, &[xyz_elem(&PTS)], &Style::default());
    let clean = ok(&bytes);
    assert!(clean.info.warnings.is_empty(), "{:?}", clean.info.warnings);
    bytes.extend_from_slice(b"garbage");
    let r = ok(&bytes);
    assert_eq!(r.cloud.positions, PTS.to_vec());
    assert_eq!(r.info.warnings.len(), 1);
    assert!(r.info.warnings[0].contains("7 bytes follow the last element") && r.info.warnings[0].contains("too few records"), "{:?}", r.info.warnings);
    assert!(r.format_notes().iter().any(|n| n.contains("7 bytes follow")));
    // Ascii: lines beyond the declared count (a count too small) are counted.
    let ascii = header_only("ascii", XYZ, 1) + "1 2 3\n4 5 6\n7 8 9\n\n";
    let r = ok(ascii.as_bytes());
    assert_eq!(r.cloud.positions, vec![[1.0, 2.0, 3.0]]);
    assert!(r.info.warnings[0].contains("2 more lines follow the last element, from line 9"), "{:?}", r.info.warnings);
    // Blank lines after the body are nothing.
    assert!(ok((header_only("ascii", XYZ, 1) + "1 2 3\n\n \n").as_bytes()).info.warnings.is_empty());
}

#[test]
fn header_preflight_reads_a_prefix() {
    let bytes = write_ply(
        Fmt::Le,
        &[face_elem(2), xyz_elem(&PTS)],
        &Style {
            comments: vec!["hello".into()],
            ..Style::default()
        },
    );
    let full = read_ply_header(&bytes).unwrap();
    let end = full.body_offset;
    assert!(bytes[..end].ends_with(b"end_header\n"));
    // Only the header bytes: enough for the preflight, not for read_ply.
    let h = read_ply_header(&bytes[..end]).unwrap();
    assert_eq!(h, full);
    assert_eq!(h.format, PlyFormat::BinaryLittleEndian);
    assert_eq!(h.vertex().count, 4);
    assert_eq!(h.vertex().name, "vertex");
    assert_eq!(h.elements.len(), 2);
    assert_eq!(h.elements[0].name, "face");
    assert_eq!(h.comments, ["hello"]);
    assert!(matches!(
        read_ply(&bytes[..end]),
        Err(PlyError::TooManyRecords { .. })
    ));
    // end_header without a final newline is still a complete header.
    let h = read_ply_header(&bytes[..end - 1]).unwrap();
    assert_eq!(h.body_offset, end - 1);
}

// ---------------------------------------------------------------------------------------------
// Errors: variant and location.
// ---------------------------------------------------------------------------------------------

fn assert_msg(e: &PlyError, needles: &[&str]) {
    let m = e.to_string();
    for n in needles {
        assert!(m.contains(n), "message {m:?} should mention {n:?}");
    }
    // It is a std error.
    let _: &dyn std::error::Error = e;
}

#[test]
fn error_not_ply() {
    for bytes in [
        &b""[..],
        b"plx\n",
        b"ply2\n",
        b"\x00\x01",
    ] {
        let e = err(bytes);
        assert_eq!(e, PlyError::NotPly, "{bytes:?}");
        assert_msg(&e, &["not a PLY"]);
    }
    // `PLY` in capitals and a UTF-8 BOM before the magic are PLY (issue 16): these headers are
    // cut short, not "not a PLY".
    for bytes in [&b"PLY\nformat ascii 1.0\n"[..], b"\xef\xbb\xbfply\n", b"Ply\r\nformat ascii 1.0\r\n"] {
        assert!(matches!(err(bytes), PlyError::MissingEndHeader { .. }), "{bytes:?}: {:?}", err(bytes));
    }
}

#[test]
fn error_unsupported_format_and_version() {
    let e = err(b"ply\ncomment x\nformat binary_middle_endian 1.0\nend_header\n");
    assert!(
        matches!(e, PlyError::UnsupportedFormat { line: 3, .. }),
        "{e:?}"
    );
    assert_msg(&e, &["line 3", "binary_middle_endian"]);
    let e = err(b"ply\nformat ascii 2.0\nend_header\n");
    assert!(
        matches!(e, PlyError::UnsupportedVersion { line: 2, .. }),
        "{e:?}"
    );
    assert_msg(&e, &["line 2", "2.0"]);
}

#[test]
fn error_malformed_header_lines() {
    let cases: &[(&[u8], usize)] = &[
        (b"ply\nformat ascii\nend_header\n", 2),
        (b"ply\nformat ascii 1.0 extra\nend_header\n", 2),
        (b"ply\nformat ascii 1.0\nformat ascii 1.0\nend_header\n", 3),
        (b"ply\nformat ascii 1.0\nelement vertex\nend_header\n", 3),
        (b"ply\nformat ascii 1.0\nelement vertex -1\nend_header\n", 3),
        (b"ply\nformat ascii 1.0\nelement vertex 99999999999999999999\nend_header\n", 3),
        (b"ply\nformat ascii 1.0\nelement vertex 1.5\nend_header\n", 3),
        (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", 3),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float\nend_header\n", 4),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x y\nend_header\n", 4),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar x\nend_header\n", 4),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list float int x\nend_header\n", 4),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nbogus line\nend_header\n", 4),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\xff\nend_header\n", 4),
        (b"ply\r\nformat ascii 1.0\r\nelement vertex 1\r\nend_header extra\r\n", 4),
        (b"ply\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n", 6),
    ];
    for (text, line) in cases {
        let e = err(text);
        assert!(
            matches!(e, PlyError::MalformedHeader { line: l, .. } if l == *line),
            "{}: {e:?}",
            String::from_utf8_lossy(text)
        );
        assert_msg(&e, &[&format!("line {line}")]);
    }
}

#[test]
fn error_unknown_property_type() {
    let e = err(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty half y\nend_header\n",
    );
    assert!(
        matches!(&e, PlyError::UnknownPropertyType { line: 5, type_name } if type_name == "half"),
        "{e:?}"
    );
    assert_msg(&e, &["line 5", "half"]);
    let e =
        err(b"ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int64 idx\nend_header\n");
    assert!(
        matches!(&e, PlyError::UnknownPropertyType { line: 4, .. }),
        "{e:?}"
    );
}

#[test]
fn error_missing_end_header() {
    for text in [
        "ply\n",
        "ply\nformat ascii 1.0\nelement vertex 1\n",
        "ply\r\nformat ascii 1.0\r\nend_heade",
    ] {
        let e = err(text.as_bytes());
        assert!(
            matches!(e, PlyError::MissingEndHeader { .. }),
            "{text:?}: {e:?}"
        );
        assert_msg(&e, &["end_header"]);
    }
}

#[test]
fn error_no_vertex_element_and_missing_coordinates() {
    let e = err(b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n");
    assert_eq!(e, PlyError::NoVertexElement);
    assert_msg(&e, &["vertex"]);
    for (props, axis) in [
        ("property float x\nproperty float y\n", "z"),
        ("property float y\nproperty float z\n", "x"),
        (
            "property float x\nproperty list uchar float y\nproperty float z\n",
            "y",
        ),
    ] {
        let text = format!(
            "ply\nformat ascii 1.0\ncomment c\nelement vertex 1\n{props}end_header\n1 2 3\n"
        );
        let e = err(text.as_bytes());
        assert_eq!(
            e,
            PlyError::MissingCoordinate { line: 4, axis },
            "{props:?}"
        );
        assert_msg(&e, &["line 4", &format!("'{axis}'")]);
    }
}

#[test]
fn error_empty_cloud() {
    for fmt in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let e = err(header_only(fmt, XYZ, 0).as_bytes());
        assert_eq!(e, PlyError::EmptyCloud);
        assert_msg(&e, &["0 vertices"]);
    }
}

#[test]
fn error_all_non_finite() {
    let e = err((header_only("ascii", XYZ, 2) + "nan 0 0\n0 inf 0\n").as_bytes());
    assert_eq!(e, PlyError::AllNonFinite { count: 2 });
    assert_msg(&e, &["2", "NaN"]);
}

#[test]
fn error_huge_counts_fail_before_allocating() {
    let counts = [
        1u64 << 31,
        1 << 32,
        1 << 63,
        u64::MAX,
        u64::MAX / 12 + 1,
        4294967295,
    ];
    for fmt in ["ascii", "binary_little_endian", "binary_big_endian"] {
        // A binary body that is not text (a text body under a binary header is refused as such).
        let body = if fmt == "ascii" { "1 2 3 4 5 6 7 8 9 10 11 12\n" } else { "1 2 3 4 5 6 7 8 9 10 11 12\u{1}\n" };
        for count in counts {
            let t = std::time::Instant::now();
            let text = header_only(fmt, XYZ, count) + body;
            let e = err(text.as_bytes());
            assert!(
                matches!(&e, PlyError::TooManyRecords { element, count: c, .. } if element == "vertex" && *c == count),
                "{fmt} {count}: {e:?}"
            );
            assert_msg(
                &e,
                &["'vertex'", &count.to_string(), "bytes follow the header"],
            );
            assert!(t.elapsed().as_millis() < 100, "took {:?}", t.elapsed());
        }
        // A huge face element before or after the vertices fails the same way.
        for (before, after) in [(true, false), (false, true)] {
            let face = format!(
                "element face {}\nproperty list uchar int vertex_indices\n",
                u64::MAX
            );
            let text = format!(
                "ply\nformat {fmt} 1.0\n{}element vertex 1\n{XYZ}{}end_header\n{body}",
                if before { face.as_str() } else { "" },
                if after { face.as_str() } else { "" },
            );
            let e = err(text.as_bytes());
            assert!(
                matches!(&e, PlyError::TooManyRecords { element, .. } if element == "face"),
                "{e:?}"
            );
        }
    }
}

#[test]
fn error_count_just_over_what_fits() {
    // Binary: 3 floats per vertex, 2 vertices declared, 23 bytes present.
    let mut bytes = header_only("binary_little_endian", XYZ, 2).into_bytes();
    let body_offset = bytes.len();
    bytes.extend_from_slice(&[0u8; 23]);
    let e = err(&bytes);
    assert_eq!(
        e,
        PlyError::TooManyRecords {
            element: "vertex".into(),
            count: 2,
            needed: 24,
            available: 23,
            body_offset
        }
    );
    assert_msg(
        &e,
        &["24 bytes", "23 bytes", &format!("offset {body_offset}")],
    );
    bytes.push(0);
    assert_eq!(ok(&bytes).cloud.len(), 2);
    // Ascii: 6 values need at least 11 bytes ("1 2 3 4 5 6").
    let e = err((header_only("ascii", XYZ, 2) + "1 2 3 4 5").as_bytes());
    assert!(
        matches!(
            e,
            PlyError::TooManyRecords {
                needed: 11,
                available: 9,
                ..
            }
        ),
        "{e:?}"
    );
    assert_eq!(
        ok((header_only("ascii", XYZ, 2) + "1 2 3\n4 5 6").as_bytes())
            .cloud
            .len(),
        2
    );
}

#[test]
fn error_truncated_binary_list_body() {
    // A face list whose count runs past the end of the file.
    for (be, fmt) in [(false, "binary_little_endian"), (true, "binary_big_endian")] {
        let text = format!(
            "ply\nformat {fmt} 1.0\nelement face 2\nproperty list uint int vertex_indices\n\
             element vertex 1\nproperty uchar x\nproperty uchar y\nproperty uchar z\nend_header\n"
        );
        let mut bytes = text.into_bytes();
        let body = bytes.len();
        let n: u32 = 4_000_000_000;
        let one: u32 = 1;
        let enc = |v: u32| if be { v.to_be_bytes() } else { v.to_le_bytes() };
        bytes.extend_from_slice(&enc(one));
        bytes.extend_from_slice(&enc(7));
        bytes.extend_from_slice(&enc(n));
        bytes.extend_from_slice(&[1, 2, 3, 4, 5]);
        let t = std::time::Instant::now();
        let e = err(&bytes);
        assert!(t.elapsed().as_millis() < 100);
        let want = PlyError::Truncated {
            element: "face".into(),
            index: 1,
            property: "vertex_indices".into(),
            needed: 16_000_000_000,
            offset: body + 12,
            file_len: bytes.len(),
        };
        assert_eq!(e, want);
        assert_msg(
            &e,
            &[
                "'face'",
                "record 1",
                "'vertex_indices'",
                "needs 16000000000 bytes",
                &format!("offset {}", body + 12),
                &format!("file has {}", bytes.len()),
            ],
        );
    }
}

#[test]
fn error_truncated_binary_vertex_with_list() {
    // A list inside the vertex makes records variable-size; the capacity check cannot catch
    // this one, the reader must.
    let text = "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n\
                property list uchar float extra\nproperty float y\nproperty float z\nend_header\n";
    let mut bytes = text.as_bytes().to_vec();
    let body = bytes.len();
    for v in [1.0f32, 2.0, 3.0] {
        if v == 2.0 {
            bytes.push(0);
        }
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    bytes.extend_from_slice(&4.0f32.to_le_bytes());
    bytes.push(200); // 200 floats announced
    bytes.extend_from_slice(&[0u8; 10]);
    let e = err(&bytes);
    assert_eq!(
        e,
        PlyError::Truncated {
            element: "vertex".into(),
            index: 1,
            property: "extra".into(),
            needed: 800,
            offset: body + 13 + 5,
            file_len: bytes.len(),
        }
    );
}

#[test]
fn error_truncated_binary_scalar() {
    let text = "ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty list uchar uchar l\n\
                property double x\nproperty double y\nproperty double z\nend_header\n";
    let mut bytes = text.as_bytes().to_vec();
    let body = bytes.len();
    bytes.push(0);
    bytes.extend_from_slice(&[0u8; 24]);
    bytes.push(2);
    bytes.extend_from_slice(&[0u8; 2 + 8 + 8 + 7]);
    let e = err(&bytes);
    assert_eq!(
        e,
        PlyError::Truncated {
            element: "vertex".into(),
            index: 1,
            property: "z".into(),
            needed: 8,
            offset: body + 25 + 3 + 16,
            file_len: bytes.len(),
        }
    );
    assert_msg(&e, &["needs 8 bytes", "record 1", "'z'"]);
}

#[test]
fn error_ascii_unexpected_eof_and_bad_values() {
    // A list that claims more items than there are tokens.
    let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n\
                1 2 3\n3 0 1 2\n200 0 1 2 3 4 5 6\n";
    let e = err(text.as_bytes());
    assert_eq!(
        e,
        PlyError::UnexpectedEof {
            element: "face".into(),
            index: 1,
            property: "vertex_indices".into(),
            line: 13
        }
    );
    assert_msg(&e, &["line 13", "'face'", "record 1", "'vertex_indices'"]);

    let e = err((header_only("ascii", XYZ, 3) + "1 2 3\n4 five 6\n7 8 9\n").as_bytes());
    assert_eq!(
        e,
        PlyError::BadValue {
            element: "vertex".into(),
            index: 1,
            property: "y".into(),
            line: 9,
            token: "five".into()
        }
    );
    assert_msg(&e, &["line 9", "'vertex'", "record 1", "'y'", "five"]);

    let props = "property float x\nproperty float y\nproperty float z\nproperty uchar red\n\
                 property uchar green\nproperty uchar blue\n";
    let e = err((header_only("ascii", props, 1) + "1 2 3 4 5 6.5\r\n").as_bytes());
    assert!(
        matches!(&e, PlyError::BadValue { line: 11, property, token, .. } if property == "blue" && token == "6.5"),
        "{e:?}"
    );

    let mut bytes = header_only("ascii", XYZ, 1).into_bytes();
    bytes.extend_from_slice(b"1 2 \xff\n");
    let e = err(&bytes);
    assert!(matches!(&e, PlyError::BadValue { line: 8, .. }), "{e:?}");
}

#[test]
fn error_negative_list_count() {
    let text = "ply\nformat ascii 1.0\nelement face 1\nproperty list int int vertex_indices\n\
                element vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n\
                -3 0 1 2\n1 2 3\n";
    let e = err(text.as_bytes());
    assert_eq!(
        e,
        PlyError::BadListCount {
            element: "face".into(),
            index: 0,
            property: "vertex_indices".into(),
            at: BodyPos::Line(10),
            value: -3
        }
    );
    assert_msg(&e, &["line 10", "-3", "'face'"]);

    let text = "ply\nformat binary_little_endian 1.0\nelement face 1\nproperty list char int vertex_indices\n\
                element vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    let mut bytes = text.as_bytes().to_vec();
    let body = bytes.len();
    bytes.push(0xff);
    bytes.extend_from_slice(&[0u8; 12]);
    let e = err(&bytes);
    assert!(
        matches!(e, PlyError::BadListCount { at: BodyPos::Offset(o), value: -1, .. } if o == body),
        "{e:?}"
    );
    assert_msg(&e, &[&format!("byte offset {body}")]);
}

// ---------------------------------------------------------------------------------------------
// Real files and speed.
// ---------------------------------------------------------------------------------------------

#[test]
fn evaluation_clouds() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/eval");
    let mut seen = 0;
    for name in [
        "cow",
        "fandisk",
        "spot",
        "stanford-bunny",
        "suzanne",
        "teapot",
    ] {
        for n in [10_000usize, 3_000] {
            let path = dir.join(format!("{name}-{}k.ply", n / 1000));
            let Ok(bytes) = std::fs::read(&path) else {
                eprintln!("skipping {}: not found", path.display());
                continue;
            };
            let r = read_ply(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!(r.cloud.len(), n, "{}", path.display());
            assert_eq!(r.info.vertex_count, n as u64);
            assert_eq!(r.info.dropped_non_finite, 0);
            assert_eq!(r.info.format, PlyFormat::BinaryLittleEndian);
            assert_eq!(r.cloud.normals, None);
            assert_eq!(r.cloud.colors, None);
            let b = r.cloud.bounds().unwrap();
            let side = b.longest_side();
            assert!(
                side.is_finite() && side > 1e-3 && side < 1e4,
                "{}: bounds {b:?}",
                path.display()
            );
            for a in 0..3 {
                assert!(
                    b.min[a].abs() < 1e4 && b.max[a].abs() < 1e4,
                    "{}: {b:?}",
                    path.display()
                );
            }
            // Points are spread out, not collapsed onto a plane or a line.
            let e = b.extent();
            assert!(
                e.iter().filter(|&&x| x > 0.01 * side).count() >= 2,
                "{}: {b:?}",
                path.display()
            );
            seen += 1;
        }
    }
    eprintln!("read {seen} evaluation clouds");
    if dir.exists() {
        assert_eq!(seen, 12);
    }
}

#[test]
fn one_million_binary_vertices_is_fast() {
    let n = 1_000_000usize;
    let mut bytes = header_only("binary_little_endian", XYZ, n as u64).into_bytes();
    bytes.reserve(n * 12);
    for i in 0..n {
        for c in [i as f32, (i % 1000) as f32 * 0.5, -(i as f32)] {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    let t = std::time::Instant::now();
    let r = ok(&bytes);
    let dt = t.elapsed();
    eprintln!("1M binary float vertices: {dt:?}");
    assert_eq!(r.cloud.len(), n);
    assert_eq!(
        r.cloud.positions[n - 1],
        [(n - 1) as f32, 499.5, -((n - 1) as f32)]
    );
    // Well under a second in release; generous here because tests may run unoptimised and
    // share the machine.
    assert!(dt.as_secs_f64() < 2.0, "{dt:?}");
}

// ---------------------------------------------------------------------------------------------
// Property test: random clouds, extra properties/elements and formats round-trip exactly.
// ---------------------------------------------------------------------------------------------

/// A value of type `t` that survives the round trip exactly.
fn arb_val(t: ScalarType) -> BoxedStrategy<Val> {
    use ScalarType::*;
    match t {
        I8 => any::<i8>().prop_map(move |v| Val(t, v as f64)).boxed(),
        U8 => any::<u8>().prop_map(move |v| Val(t, v as f64)).boxed(),
        I16 => any::<i16>().prop_map(move |v| Val(t, v as f64)).boxed(),
        U16 => any::<u16>().prop_map(move |v| Val(t, v as f64)).boxed(),
        I32 => any::<i32>().prop_map(move |v| Val(t, v as f64)).boxed(),
        U32 => any::<u32>().prop_map(move |v| Val(t, v as f64)).boxed(),
        F32 => prop_oneof![
            4 => -1e6f32..1e6f32,
            1 => proptest::num::f32::POSITIVE
                | proptest::num::f32::NEGATIVE
                | proptest::num::f32::NORMAL
                | proptest::num::f32::SUBNORMAL
                | proptest::num::f32::ZERO,
        ]
        .prop_map(move |v| Val(t, v as f64))
        .boxed(),
        F64 => prop_oneof![
            4 => -1e6f64..1e6f64,
            1 => proptest::num::f64::POSITIVE
                | proptest::num::f64::NEGATIVE
                | proptest::num::f64::NORMAL
                | proptest::num::f64::ZERO,
        ]
        .prop_map(move |v| Val(t, v))
        .boxed(),
    }
}

fn arb_type() -> impl Strategy<Value = ScalarType> {
    proptest::sample::select(TYPES.to_vec())
}

fn arb_int_type() -> impl Strategy<Value = ScalarType> {
    proptest::sample::select(vec![
        ScalarType::U8,
        ScalarType::U16,
        ScalarType::U32,
        ScalarType::I32,
        ScalarType::I8,
    ])
}

#[derive(Clone, Debug)]
enum ExtraKind {
    S(ScalarType),
    L(ScalarType, ScalarType),
}

fn arb_extra_kind() -> impl Strategy<Value = ExtraKind> {
    prop_oneof![
        3 => arb_type().prop_map(ExtraKind::S),
        1 => (arb_int_type(), arb_type()).prop_map(|(c, i)| ExtraKind::L(c, i)),
    ]
}

fn arb_cell(k: &ExtraKind) -> BoxedStrategy<Cell> {
    match *k {
        ExtraKind::S(t) => arb_val(t).prop_map(Cell::S).boxed(),
        ExtraKind::L(c, i) => proptest::collection::vec(arb_val(i), 0..5)
            .prop_map(move |v| Cell::L(c, v))
            .boxed(),
    }
}

fn arb_elem(name: String) -> impl Strategy<Value = Elem> {
    proptest::collection::vec(arb_extra_kind(), 0..4).prop_flat_map(move |kinds| {
        let props: Vec<Prop> = kinds
            .iter()
            .enumerate()
            .map(|(i, k)| match k {
                ExtraKind::S(t) => scalar(&format!("p{i}"), *t),
                ExtraKind::L(c, t) => list(&format!("p{i}"), *c, *t),
            })
            .collect();
        let row: Vec<BoxedStrategy<Cell>> = kinds.iter().map(arb_cell).collect();
        let name = name.clone();
        proptest::collection::vec(row, 0..6).prop_map(move |rows| Elem {
            name: name.clone(),
            props: props.clone(),
            rows,
        })
    })
}

#[derive(Clone, Debug)]
struct Case {
    fmt: Fmt,
    crlf: bool,
    sized: bool,
    before: Vec<Elem>,
    after: Vec<Elem>,
    /// Vertex columns: (name, kind) in file order; x/y/z and attributes are among them.
    vprops: Vec<(String, ExtraKind)>,
    vrows: Vec<Vec<Cell>>,
}

fn arb_case() -> impl Strategy<Value = Case> {
    let fmt = proptest::sample::select(FMTS.to_vec());
    let xyz_t = arb_type();
    let normals = proptest::option::of(proptest::sample::select(vec![
        ScalarType::F32,
        ScalarType::F64,
    ]));
    let colours = proptest::option::of((
        proptest::sample::select(vec![ScalarType::U8, ScalarType::F32, ScalarType::F64]),
        any::<bool>(),
    ));
    let extras = proptest::collection::vec(arb_extra_kind(), 0..3);
    let order_seed = any::<u64>();
    (
        fmt,
        xyz_t,
        normals,
        colours,
        extras,
        order_seed,
        any::<bool>(),
        any::<bool>(),
    )
        .prop_flat_map(
            |(fmt, xyz_t, normals, colours, extras, seed, crlf, sized)| {
                let mut vprops: Vec<(String, ExtraKind)> = ["x", "y", "z"]
                    .iter()
                    .map(|n| (n.to_string(), ExtraKind::S(xyz_t)))
                    .collect();
                if let Some(t) = normals {
                    vprops.extend(
                        ["nx", "ny", "nz"]
                            .iter()
                            .map(|n| (n.to_string(), ExtraKind::S(t))),
                    );
                }
                if let Some((t, alpha)) = colours {
                    let names: &[&str] = if alpha {
                        &["red", "green", "blue", "alpha"]
                    } else {
                        &["red", "green", "blue"]
                    };
                    vprops.extend(names.iter().map(|n| (n.to_string(), ExtraKind::S(t))));
                }
                vprops.extend(
                    extras
                        .into_iter()
                        .enumerate()
                        .map(|(i, k)| (format!("extra{i}"), k)),
                );
                // Shuffle the column order deterministically from the seed.
                let mut s = seed | 1;
                for i in (1..vprops.len()).rev() {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    vprops.swap(i, (s % (i as u64 + 1)) as usize);
                }
                let row: Vec<BoxedStrategy<Cell>> = vprops
                    .iter()
                    .map(|(name, k)| match (name.as_str(), k) {
                        ("red" | "green" | "blue" | "alpha", ExtraKind::S(t)) if t.is_float() => {
                            let t = *t;
                            (0u8..=255)
                                .prop_map(move |c| Cell::S(Val(t, (c as f32 / 255.0) as f64)))
                                .boxed()
                        }
                        ("nx" | "ny" | "nz", ExtraKind::S(t)) => {
                            let t = *t;
                            (-1f32..=1f32)
                                .prop_map(move |v| Cell::S(Val(t, v as f64)))
                                .boxed()
                        }
                        _ => arb_cell(k),
                    })
                    .collect();
                let before = proptest::collection::vec(arb_elem("before".into()), 0..3);
                let after = proptest::collection::vec(arb_elem("face".into()), 0..3);
                let vrows = proptest::collection::vec(row, 1..40);
                (
                    Just(fmt),
                    Just(crlf),
                    Just(sized),
                    before,
                    after,
                    Just(vprops),
                    vrows,
                )
            },
        )
        .prop_map(|(fmt, crlf, sized, before, after, vprops, vrows)| Case {
            fmt,
            crlf,
            sized,
            before,
            after,
            vprops,
            vrows,
        })
}

fn case_bytes(c: &Case) -> Vec<u8> {
    let vertex = Elem {
        name: "vertex".into(),
        props: c
            .vprops
            .iter()
            .map(|(n, k)| match k {
                ExtraKind::S(t) => Prop {
                    name: n.clone(),
                    decl: alias(*t, c.sized).into(),
                },
                ExtraKind::L(ct, it) => Prop {
                    name: n.clone(),
                    decl: format!("list {} {}", alias(*ct, c.sized), alias(*it, c.sized)),
                },
            })
            .collect(),
        rows: c.vrows.clone(),
    };
    let mut elems = c.before.clone();
    elems.push(vertex);
    elems.extend(c.after.iter().cloned());
    write_ply(
        c.fmt,
        &elems,
        &Style {
            crlf: c.crlf,
            ..Style::default()
        },
    )
}

fn column(c: &Case, name: &str) -> Option<Vec<f64>> {
    let i = c.vprops.iter().position(|(n, _)| n == name)?;
    Some(
        c.vrows
            .iter()
            .map(|r| match &r[i] {
                Cell::S(v) => v.1,
                Cell::L(..) => unreachable!(),
            })
            .collect(),
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_files_round_trip_exactly(c in arb_case()) {
        let bytes = case_bytes(&c);
        let n = c.vrows.len();
        let (x, y, z) = (column(&c, "x").unwrap(), column(&c, "y").unwrap(), column(&c, "z").unwrap());
        // int, uint and double coordinates far from 0 are stored relative to an origin taken
        // from the first point (nkrr::cloud::origin_for; generated points are all finite, so
        // it is the first row's).
        let wide = c.vprops.iter().any(|(name, k)| {
            name == "x" && matches!(k, ExtraKind::S(ScalarType::F64 | ScalarType::I32 | ScalarType::U32))
        });
        let origin = if wide { nkrr::cloud::origin_for([x[0], y[0], z[0]]) } else { [0.0; 3] };
        let want: Vec<[f32; 3]> =
            (0..n).map(|i| [(x[i] - origin[0]) as f32, (y[i] - origin[1]) as f32, (z[i] - origin[2]) as f32]).collect();
        // Generated coordinates are finite; a double too far from the origin for an f32 makes
        // the file refused, naming the first such vertex (issue 16).
        if let Some(i) = want.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            let e = read_ply(&bytes);
            prop_assert!(matches!(e, Err(PlyError::TooLarge { index, .. }) if index == i as u64), "{:?}", e);
            return Ok(());
        }
        let keep: Vec<bool> = want.iter().map(|p| p.iter().all(|v| v.is_finite())).collect();
        let kept: Vec<[f32; 3]> = want.iter().zip(&keep).filter(|(_, &k)| k).map(|(p, _)| *p).collect();
        if kept.is_empty() {
            prop_assert_eq!(read_ply(&bytes), Err(PlyError::AllNonFinite { count: n as u64 }));
            return Ok(());
        }
        let r = read_ply(&bytes).map_err(|e| TestCaseError::fail(format!("{e}")))?;
        prop_assert_eq!(r.cloud.origin, origin);
        prop_assert_eq!(&r.cloud.positions, &kept);
        prop_assert_eq!(r.info.dropped_non_finite, n - kept.len());
        prop_assert_eq!(r.info.vertex_count, n as u64);
        prop_assert_eq!(r.info.format, c.fmt.ply());
        prop_assert_eq!(r.info.vertex_properties.len(), c.vprops.len());
        let others: Vec<(String, u64)> =
            c.before.iter().chain(&c.after).map(|e| (e.name.clone(), e.rows.len() as u64)).collect();
        prop_assert_eq!(&r.info.other_elements, &others);

        let normals = match (column(&c, "nx"), column(&c, "ny"), column(&c, "nz")) {
            (Some(a), Some(b), Some(d)) => Some(
                (0..n).filter(|&i| keep[i]).map(|i| [a[i] as f32, b[i] as f32, d[i] as f32]).collect::<Vec<_>>(),
            ),
            _ => None,
        };
        prop_assert_eq!(&r.cloud.normals, &normals);

        let colour_t = c.vprops.iter().find(|(n, _)| n == "red").map(|(_, k)| match k {
            ExtraKind::S(t) => *t,
            ExtraKind::L(..) => unreachable!(),
        });
        let colours = colour_t.map(|t| {
            let to8 = |v: f64| if t.is_float() { (v * 255.0).round() as u8 } else { v as u8 };
            let ch: Vec<Vec<f64>> = ["red", "green", "blue"].iter().map(|n| column(&c, n).unwrap()).collect();
            let a = column(&c, "alpha");
            (0..n)
                .filter(|&i| keep[i])
                .map(|i| [to8(ch[0][i]), to8(ch[1][i]), to8(ch[2][i]), a.as_ref().map_or(255, |a| to8(a[i]))])
                .collect::<Vec<_>>()
        });
        prop_assert_eq!(&r.cloud.colors, &colours);

        // The preflight agrees with the full read.
        let h = read_ply_header(&bytes).unwrap();
        prop_assert_eq!(h.vertex().count, n as u64);
        prop_assert_eq!(&h.vertex().properties, &r.info.vertex_properties);

        // Any truncation of the body is an error, never a panic or a shorter cloud.
        let cut = h.body_offset + (bytes.len() - h.body_offset) / 2;
        if c.fmt != Fmt::Ascii && cut < bytes.len() {
            prop_assert!(read_ply(&bytes[..cut]).is_err());
        }
    }
}

/// Binary values that happen to be the bytes of digits and line breaks (ushort 0x0d30: '0' and
/// CR) are still binary: the fuzzer found such a file refused as a text body.
#[test]
fn binary_values_that_look_like_digits_are_binary() {
    let props = "property ushort x\nproperty ushort y\nproperty ushort z\n";
    let mut bytes = header_only("binary_little_endian", props, 4).into_bytes();
    for i in 0..12u16 {
        bytes.extend_from_slice(&(0x0d30 + i % 7).to_le_bytes());
    }
    let r = ok(&bytes);
    assert_eq!(r.cloud.positions[0], [0x0d30 as f32, 0x0d31 as f32, 0x0d32 as f32]);
}
