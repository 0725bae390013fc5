//! Issue 16, item 2: files that were read wrongly without a word, a valid file that was refused,
//! and reading-side messages that pointed nowhere. One test per finding; the inputs are the
//! small files in tests/fixtures/malformed (see its README.md) or generated here.

use std::path::PathBuf;

use nkrr::cloud::{Normalization, PointCloud};
use nkrr::io::{read_cloud, ScanFormat};

fn fixture(name: &str) -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/malformed").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn read_ok(bytes: &[u8], name: &str) -> nkrr::io::ScanFile {
    read_cloud(bytes, Some(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn read_err(bytes: &[u8], name: &str) -> String {
    match read_cloud(bytes, Some(name)) {
        Ok(f) => panic!("{name}: read as {} with {} points, expected an error", f.format, f.cloud.len()),
        Err(e) => e.to_string(),
    }
}

/// A PLY that starts with a UTF-8 BOM, or whose magic is `PLY`, is a PLY (it was read as a
/// one-point text cloud).
#[test]
fn ply_with_bom_or_capital_magic_is_read_as_ply() {
    for name in ["bom.ply", "caps.ply"] {
        let f = read_ok(&fixture(name), name);
        assert_eq!(f.format, ScanFormat::Ply, "{name}");
        assert_eq!(f.cloud.positions, vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "{name}");
    }
}

/// Semicolon-separated fields with decimal commas are read as numbers (they were read as six
/// columns with x = ±0); an ambiguous mix is refused with the reason and the line.
#[test]
fn decimal_commas_are_read_when_unambiguous() {
    let f = read_ok(&fixture("decimal_comma.csv"), "decimal_comma.csv");
    assert_eq!(f.cloud.len(), 4);
    let want = [[-0.1646, 0.3188, -0.3483], [0.25, -1.0, 2.75], [1.0, 1.5, -0.125], [0.0, 2.0, 3.0]];
    for (p, w) in f.cloud.positions.iter().zip(want) {
        for a in 0..3 {
            assert!((p[a] as f64 - w[a]).abs() < 1e-6, "{p:?} vs {w:?}");
        }
    }
    assert!(f.layout.contains("decimal comma"), "{}", f.layout);
    // A comma-separated line after semicolon lines with decimal commas: ambiguous, refused.
    let e = read_err(b"0,5;1,5;2,5\n1,5;2,5;3,5\n1,2,3\n", "mixed.csv");
    assert!(e.contains("line 3") && e.contains("decimal comma"), "{e}");
    // The same numbers separated by spaces or tabs (were six columns, y = 1646).
    let f = read_ok(b"-0,1646 0,3188 -0,3483\n0,25\t-1,0\t2,75\n1,0 1,5 -0,125\n", "spaces.xyz");
    assert_eq!(f.cloud.len(), 3);
    for (p, w) in f.cloud.positions.iter().zip(&want[..3]) {
        for a in 0..3 {
            assert!((p[a] as f64 - w[a]).abs() < 1e-6, "{p:?} vs {w:?}");
        }
    }
    // Decimal commas on some numbers only, separated by spaces: refused with the reason (was
    // read as CSV, 2,5 splitting into two columns).
    let e = read_err(b"1 2,5 3\n0 0,5 1\n1 1 1,25\n", "mixed.xyz");
    assert!(e.contains("line 1") && e.contains("decimal comma"), "{e}");
    // Ordinary CSV, with or without spaces after its commas, is still CSV.
    for csv in [&b"1,2,3\n4,5,6\n7,8,9\n"[..], b"1, 2, 3\n4, 5, 6\n7, 8, 9\n", b"1.5,2.5,3.5\n4,5,6\n7,8,9\n"] {
        let f = read_ok(csv, "plain.csv");
        assert!(!f.layout.contains("decimal comma"), "{}", f.layout);
        assert_eq!(f.cloud.positions[1], [4.0, 5.0, 6.0]);
    }
}

/// One NUL byte: the message says so, with its byte offset (it said "not a point cloud").
#[test]
fn a_nul_byte_is_named_with_its_offset() {
    let e = read_err(&fixture("nul.csv"), "nul.csv");
    assert!(e.contains("NUL") && e.contains("byte 15"), "{e}");
}

/// CR-only line endings are line breaks (the file was "no line of numbers").
#[test]
fn cr_only_line_endings_are_line_breaks() {
    let f = read_ok(&fixture("cr_only.xyz"), "cr_only.xyz");
    assert_eq!(f.cloud.positions, vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
}

/// More than 64 columns: the message gives the count, the limit and the line.
#[test]
fn too_many_columns_are_named() {
    let e = read_err(&fixture("wide.xyz"), "wide.xyz");
    assert!(e.contains("65") && e.contains("64") && e.contains("line 1"), "{e}");
}

/// A finite value too large for an f32 is called that, with the value and the line (it was
/// "NaN or infinite"); in a PLY `double`, with the vertex.
#[test]
fn values_too_large_for_f32_are_named() {
    let e = read_err(&fixture("f32_overflow.xyz"), "f32_overflow.xyz");
    assert!(e.contains("too large") && e.contains("32-bit") && e.contains("line 3") && e.contains("1e39"), "{e}");
    let mut ply = b"ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\nend_header\n".to_vec();
    ply.extend_from_slice(b"0 0 0\n1 0 0\n0 -1e300 0\n0 0 1\n");
    let e = read_err(&ply, "big.ply");
    assert!(e.contains("too large") && e.contains("32-bit") && e.contains("vertex 2"), "{e}");
}

/// Far-off coordinates are recentred at any magnitude: detail around 1e15 and 1e18 survives
/// (it collapsed: no origin was chosen at 1e15 and beyond).
#[test]
fn recentring_works_at_any_magnitude() {
    // Around 1e15 an f64 holds 1/8 units; around 1e18, 128 units: the detail is chosen so that
    // the file's values are exact in f64, and must come back exact relative to the origin.
    for (base, unit) in [(1e15f64, 1.0f64), (3e15, 0.5), (1e18, 256.0), (-2e18, 512.0)] {
        let offsets = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0], [1.0, 1.0, 1.0]];
        let text: String = offsets
            .iter()
            .map(|o| format!("{} {} {}\n", base + o[0] * unit, base + o[1] * unit, base + o[2] * unit))
            .collect();
        let f = read_ok(text.as_bytes(), "far.xyz");
        let c = &f.cloud;
        assert_eq!(c.len(), 5, "{base}");
        for (p, o) in c.positions.iter().zip(offsets) {
            for a in 0..3 {
                let back = c.origin[a] + p[a] as f64;
                assert_eq!(back, base + o[a] * unit, "{base}: {p:?} + {:?}", c.origin);
                assert_eq!(p[a] as f64 - c.positions[0][a] as f64, o[a] * unit, "{base}");
            }
        }
    }
}

fn cloud_of(points: Vec<[f32; 3]>) -> PointCloud {
    PointCloud { positions: points, ..Default::default() }
}

/// A flat or collinear cloud that is not axis-aligned is refused like an axis-aligned one,
/// with the reason (it passed and gave a needle).
#[test]
fn tilted_flat_and_collinear_clouds_are_refused() {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut unit = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    // Random points on x + y + z = 0.
    let plane: Vec<[f32; 3]> = (0..2000)
        .map(|_| {
            let (a, b) = (unit(), unit());
            [a as f32, b as f32, (-a - b) as f32]
        })
        .collect();
    let e = Normalization::of(&cloud_of(plane)).unwrap_err().to_string();
    assert!(e.contains("plane"), "{e}");
    // Random points on a tilted line.
    let line: Vec<[f32; 3]> = (0..2000)
        .map(|_| {
            let t = unit();
            [(1.0 + 2.0 * t) as f32, (3.0 - t) as f32, (0.5 + 0.7 * t) as f32]
        })
        .collect();
    let e = Normalization::of(&cloud_of(line)).unwrap_err().to_string();
    assert!(e.contains("line"), "{e}");
    // A thin but real slab is still accepted.
    let slab: Vec<[f32; 3]> = (0..2000)
        .map(|_| {
            let (a, b, c) = (unit(), unit(), unit() * 0.01);
            [(a + c) as f32, (b + c) as f32, (-a - b + c) as f32]
        })
        .collect();
    assert!(Normalization::of(&cloud_of(slab)).is_ok());
}

/// A flat 1000×1000 grid compresses to about 84 points a byte: it must be read, not called
/// truncated.
#[test]
fn a_highly_compressible_laz_is_read() {
    let f = read_ok(&fixture("grid_1000x1000.laz"), "grid_1000x1000.laz");
    assert_eq!(f.cloud.len(), 1_000_000);
}

/// A truncated LAZ says where it failed (which points, which byte), not just the
/// decompressor's "failed to fill whole buffer".
#[test]
fn a_truncated_laz_says_where() {
    let full = fixture("grid_1000x1000.laz");
    // The point data cut to two thirds, the chunk table kept after it (and pointed to): the
    // decompressor runs out of data in the middle of the points.
    let at = u32::from_le_bytes(full[96..100].try_into().unwrap()) as usize;
    let table = u64::from_le_bytes(full[at..at + 8].try_into().unwrap()) as usize;
    let keep = at + (table - at) * 2 / 3;
    let mut cut = full[..keep].to_vec();
    cut.extend_from_slice(&full[table..]);
    cut[at..at + 8].copy_from_slice(&(keep as u64).to_le_bytes());
    let e = read_err(&cut, "cut.laz");
    eprintln!("{e}");
    assert!(e.contains("byte") && e.contains("point"), "{e}");
    assert!(e.contains("chunk"), "{e}");
}

/// A LAS whose variable-length record runs past the file's end names the record (it said
/// "header: failed to fill whole buffer").
#[test]
fn a_las_record_past_the_end_is_named() {
    let mut las = std::fs::read(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats/spot-las12-pf3.las")).unwrap();
    // One VLR of 60000 declared bytes between the header (227 bytes) and the points.
    let header = u16::from_le_bytes(las[94..96].try_into().unwrap()) as usize;
    let mut vlr = vec![0u8; 54];
    vlr[2..9].copy_from_slice(b"nkrr-fz");
    vlr[18..20].copy_from_slice(&7u16.to_le_bytes());
    vlr[20..22].copy_from_slice(&60000u16.to_le_bytes());
    las.splice(header..header, vlr);
    las[100..104].copy_from_slice(&1u32.to_le_bytes());
    let offset = u32::from_le_bytes(las[96..100].try_into().unwrap()) + 54;
    las[96..100].copy_from_slice(&offset.to_le_bytes());
    let cut = &las[..header + 54 + 100];
    let e = read_err(cut, "vlr.las");
    // A record that fits is read past (the length is at byte 20 of its header).
    let mut ok = las.clone();
    ok[header + 20..header + 22].copy_from_slice(&10u16.to_le_bytes());
    ok.splice(header + 54..header + 54, [7u8; 10]);
    ok[96..100].copy_from_slice(&(offset + 10).to_le_bytes());
    assert_eq!(read_ok(&ok, "vlr-ok.las").cloud.len(), 3000);
    assert!(e.contains("variable-length record 0") && e.contains("60000 bytes") && e.contains("past the file's end"), "{e}");
    assert!(!e.contains("failed to fill whole buffer"), "{e}");
}

/// A LAZ with 16 damaged bytes in the middle of its points says the data is damaged, not that
/// the file is truncated.
#[test]
fn a_damaged_laz_is_not_called_truncated() {
    let full = std::fs::read(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats/spot-las12-pf1.laz")).unwrap();
    let mut bad = full.clone();
    let mid = full.len() / 2;
    for b in &mut bad[mid..mid + 16] {
        *b ^= 0x5a;
    }
    let e = read_err(&bad, "damaged.laz");
    assert!(e.contains("damaged") && e.contains("points 0.."), "{e}");
    assert!(!e.contains("truncated"), "{e}");
}

/// CRC-32C (Castagnoli), as E57 pages carry it, to damage a page without its checksum noticing.
fn crc32c(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = (crc >> 1) ^ if crc & 1 == 1 { 0x82f6_3b78 } else { 0 };
        }
    }
    !crc
}

/// An E57 with a damaged data packet (its page checksum made to match) or a damaged page says
/// the point data is damaged, not "Internal error: ... logic error" or "failed to fill whole
/// buffer".
#[test]
fn a_damaged_e57_packet_is_named_as_damage() {
    let full = std::fs::read(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats/spot-single.e57")).unwrap();
    // The points' section header is at the XML's fileOffset (48); its data starts at byte 16
    // of it: a data packet's header (type, flags, length, byte-stream count).
    let data = u64::from_le_bytes(full[48 + 16..48 + 24].try_into().unwrap()) as usize;
    assert_eq!(full[data], 1, "a data packet");
    let reseal = |b: &mut Vec<u8>, at: usize| {
        let page = at / 1024 * 1024;
        let crc = crc32c(&b[page..page + 1020]);
        b[page + 1020..page + 1024].copy_from_slice(&crc.to_be_bytes());
    };
    for (offset, value) in [(0usize, 0x80u8), (2, 0x80), (4, 0), (5, 0x80), (15, 0x80)] {
        let mut bad = full.clone();
        bad[data + offset] = value;
        reseal(&mut bad, data + offset);
        let e = read_err(&bad, "damaged.e57");
        assert!(e.contains("point data is damaged"), "byte {offset}: {e}");
        assert!(!e.contains("cut short"), "byte {offset}: {e}");
    }
    let mut bad = full.clone();
    bad[data + 100] ^= 0xff;
    let e = read_err(&bad, "page.e57");
    assert!(e.contains("checksum does not match") && !e.contains("cut short"), "{e}");
}

/// An E57 whose XML declares more points for a scan than its data holds is refused: the `e57`
/// crate went on into the next scan's data and invented the points without a word.
#[test]
fn an_e57_count_beyond_its_data_is_refused() {
    let full = std::fs::read(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/formats/spot-two-scans.e57")).unwrap();
    let before = read_ok(&full, "two.e57").cloud.len();
    // The XML (logical bytes at the header's offset, checksums in between) names each scan's
    // recordCount; raise the first by one and reseal the pages it spans.
    let xml_at = u64::from_le_bytes(full[24..32].try_into().unwrap()) as usize;
    let logical: Vec<usize> = (xml_at..full.len()).filter(|i| i % 1024 < 1020).collect();
    let text: Vec<u8> = logical.iter().map(|&i| full[i]).collect();
    let key = b"recordCount=\"";
    let at = text.windows(key.len()).position(|w| w == key).unwrap() + key.len();
    let end = at + text[at..].iter().position(|&c| c == b'"').unwrap();
    let n: u64 = std::str::from_utf8(&text[at..end]).unwrap().parse().unwrap();
    let new = (n + 1).to_string();
    assert_eq!(new.len(), end - at, "same width, so nothing moves");
    let mut bad = full.clone();
    for (k, c) in new.bytes().enumerate() {
        bad[logical[at + k]] = c;
    }
    for page in [logical[at] / 1024, logical[end - 1] / 1024] {
        let p = page * 1024;
        let crc = crc32c(&bad[p..p + 1020]);
        bad[p + 1020..p + 1024].copy_from_slice(&crc.to_be_bytes());
    }
    let e = read_err(&bad, "more.e57");
    assert!(e.contains(&format!("declares {} points", n + 1)) && e.contains(&format!("holds at most {n}")), "{e}");
    assert!(before as u64 > n, "{before} points in both scans, {n} in the first");
}
