//! E57 (ASTM E2807), through the `e57` crate: every point set (scan) in the file, each with its
//! pose applied, merged into one cloud in the file's common frame. Spherical scans are
//! converted to Cartesian by the crate; points without a valid position are skipped and
//! counted. Colours are normalised by each scan's colour limits. E57 is in metres.
//!
//! Before the crate parses anything, the header's XML length and the scans' declared point
//! counts are checked against the file: bit-packed data can describe many points in few
//! bytes, so the counts are capped the same way as LAZ's.

use std::io::Cursor;

use super::builder::{CloudBuilder, Pushed};
use super::bytes::u64_at;
use super::scan_file::{ScanFile, ScanFormat, MAX_COMPRESSED_POINTS};
use crate::units::Units;

/// Points an E57 file may declare per byte of file: two orders of magnitude above what real
/// scans need. (LAZ had such a cap too, until a flat grid broke it: issue 16. E57's compressed
/// vectors are bit-packed, not arithmetic-coded, so a coordinate that varies costs at least a
/// bit; not yet checked against an E57 of a flat grid.)
const E57_POINTS_PER_BYTE: u64 = 64;

fn check_header(b: &[u8]) -> Result<(), String> {
    if b.len() < 48 {
        return Err(format!("the file is {} bytes, shorter than an E57 header (48 bytes)", b.len()));
    }
    let (xml_offset, xml_length, page) = (u64_at(b, 24), u64_at(b, 32), u64_at(b, 40));
    let len = b.len() as u64;
    if page != 1024 {
        return Err(format!("the header declares a page size of {page} bytes (E57 uses 1024)"));
    }
    if xml_offset >= len || xml_length > len {
        return Err(format!(
            "the header declares {xml_length} bytes of XML at byte {xml_offset}, but the file has {len} bytes: it is truncated or not E57"
        ));
    }
    Ok(())
}

/// E57 pages: 1020 bytes of data, then a 4-byte checksum.
const PAGE: u64 = 1024;
const PAGE_DATA: u64 = 1020;

/// The byte of the file at logical offset `logical` (checksums skipped), if the file has it.
fn logical_byte(b: &[u8], logical: u64) -> Option<u8> {
    b.get(usize::try_from(logical / PAGE_DATA * PAGE + logical % PAGE_DATA).ok()?).copied()
}

/// `N` logical bytes from `logical`, if the file has them.
fn logical_bytes<const N: usize>(b: &[u8], logical: u64) -> Option<[u8; N]> {
    let mut out = [0u8; N];
    for (i, o) in out.iter_mut().enumerate() {
        *o = logical_byte(b, logical + i as u64)?;
    }
    Some(out)
}

/// Bits a record of `t` takes in its byte stream (the E57 standard's, as the `e57` crate packs).
fn bits(t: &::e57::RecordDataType) -> u64 {
    let range = |min: i64, max: i64| {
        let r = max as i128 - min as i128;
        if r > 0 { r.ilog2() as u64 + 1 } else { 0 }
    };
    match *t {
        ::e57::RecordDataType::Single { .. } => 32,
        ::e57::RecordDataType::Double { .. } => 64,
        ::e57::RecordDataType::ScaledInteger { min, max, .. } | ::e57::RecordDataType::Integer { min, max } => range(min, max),
    }
}

/// The most records the data packets of `scan`'s section can hold (None when it cannot be
/// told: a field of 0 bits, or a section this walk cannot follow, which the reader then
/// judges itself). The `e57` crate reads packets until it has the records the XML declares,
/// past the section's end if need be: a record count raised in the XML then read points from
/// the next scan's data without a word (the fuzzer found it). A stream is padded to whole
/// bytes, so fields of under 8 bits leave room for up to 7 records more than were written:
/// those no count can tell from real ones.
fn records_held(b: &[u8], scan: &::e57::PointCloud) -> Option<u64> {
    // A physical offset (as the file's offsets are) to a logical one (checksums skipped).
    let logical = |p: u64| (p % PAGE < PAGE_DATA).then(|| p / PAGE * PAGE_DATA + p % PAGE);
    let start = logical(scan.file_offset)?;
    let header = logical_bytes::<32>(b, start)?;
    let section_length = u64::from_le_bytes(header[8..16].try_into().ok()?);
    let end = start.checked_add(section_length)?;
    let mut at = logical(u64::from_le_bytes(header[16..24].try_into().ok()?))?;
    let mut stream_bytes = vec![0u64; scan.prototype.len()];
    while at + 4 <= end {
        let [kind, _flags, lo, hi] = logical_bytes::<4>(b, at)?;
        let length = u16::from_le_bytes([lo, hi]) as u64 + 1;
        if kind == 1 {
            let [c0, c1] = logical_bytes::<2>(b, at + 4)?;
            if u16::from_le_bytes([c0, c1]) as usize != stream_bytes.len() {
                return None;
            }
            for (i, total) in stream_bytes.iter_mut().enumerate() {
                let [s0, s1] = logical_bytes::<2>(b, at + 6 + 2 * i as u64)?;
                *total += u16::from_le_bytes([s0, s1]) as u64;
            }
        } else if kind > 2 {
            return None;
        }
        at += length;
    }
    scan.prototype
        .iter()
        .zip(&stream_bytes)
        .map(|(r, &n)| match bits(&r.data_type) {
            0 => None,
            k => Some(n * 8 / k),
        })
        .collect::<Option<Vec<u64>>>()?
        .into_iter()
        .min()
}

/// A failure while decoding a scan's points, in the user's terms: a damaged data packet made
/// the `e57` crate report "Internal error: ... logic error" (which reads as a bug in the reader)
/// or "failed to fill whole buffer" (which reads as a cut file). `whole`: the file is as long
/// as its header says, so running out of bytes is damage, not a cut.
fn point_error(name: &str, read: u64, e: ::e57::Error, whole: bool) -> String {
    let text = e.to_string();
    let why = match e {
        _ if text.contains("checksum") => {
            "a page of the file is damaged: its checksum does not match (the file was changed or broken after it was written)"
        }
        ::e57::Error::Internal { .. } | ::e57::Error::Invalid { .. } => {
            "the compressed point data is damaged (a corrupt data packet: the file was changed or broken after it was written)"
        }
        ::e57::Error::Read { .. } if whole => {
            "the compressed point data is damaged (a data packet runs past the data that the file holds, which is as long as its header says)"
        }
        ::e57::Error::Read { .. } => "the point data ends early: the file is shorter than its header says (cut short?)",
        _ => return format!("{name}, point {read}: {text}"),
    };
    format!("{name}, after point {read}: {why}; the E57 reader said: {text}")
}

/// Reads every scan of an E57 file into one cloud.
pub fn read_e57(bytes: &[u8]) -> Result<ScanFile, String> {
    check_header(bytes)?;
    // The header's physical length (byte 16): a file at least this long was not cut short.
    let whole = bytes.len() as u64 >= u64_at(bytes, 16);
    let mut reader = ::e57::E57Reader::new(Cursor::new(bytes)).map_err(|e| e.to_string())?;
    let scans = reader.pointclouds();
    if scans.is_empty() {
        return Err("the file holds no point sets (images only?)".into());
    }
    let declared: u64 = scans.iter().map(|s| s.records).fold(0u64, u64::saturating_add);
    let limit = (bytes.len() as u64).saturating_mul(E57_POINTS_PER_BYTE).min(MAX_COMPRESSED_POINTS);
    if declared > limit {
        return Err(format!(
            "the scans declare {declared} points in a {}-byte file; nkrr reads at most {limit} from it",
            bytes.len()
        ));
    }
    let colours = scans.iter().any(|s| s.has_color());
    let mut out = CloudBuilder::new(false, colours, true);
    out.reserve(declared.min(1 << 22) as usize);
    let mut invalid = 0u64;
    let mut comments = Vec::new();
    let mut spherical = 0usize;
    let mut posed = 0usize;
    for (i, scan) in scans.iter().enumerate() {
        if !scan.has_cartesian() && !scan.has_spherical() {
            return Err(format!("scan {i} has neither Cartesian nor spherical coordinates"));
        }
        spherical += usize::from(!scan.has_cartesian());
        posed += usize::from(scan.transform.is_some());
        let name = scan.name.clone().unwrap_or_else(|| format!("scan {i}"));
        comments.push(format!("{name}: {} points{}", scan.records, if scan.transform.is_some() { ", posed" } else { "" }));
        if let Some(held) = records_held(bytes, scan).filter(|&held| held < scan.records) {
            return Err(format!(
                "{name} declares {} points, but the data of its section holds at most {held}: the file's XML or its data is damaged",
                scan.records
            ));
        }
        let mut points = reader.pointcloud_simple(scan).map_err(|e| point_error(&name, 0, e, whole))?;
        points.apply_pose(true);
        points.spherical_to_cartesian(true);
        points.normalize_color(true);
        points.intensity_to_color(false);
        let mut read = 0u64;
        for p in points {
            let p = p.map_err(|e| point_error(&name, read, e, whole))?;
            read += 1;
            if read > scan.records {
                return Err(format!("{name} yields more points than the {} it declares", scan.records));
            }
            let ::e57::CartesianCoordinate::Valid { x, y, z } = p.cartesian else {
                invalid += 1;
                continue;
            };
            let c = p.color.map_or([0, 0, 0, 255], |c| {
                let ch = [c.red, c.green, c.blue].map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8);
                [ch[0], ch[1], ch[2], 255]
            });
            if let Pushed::TooLarge { axis, value, origin } = out.push([x, y, z], [0.0; 3], c) {
                return Err(format!("{name}, point {}: {}", read - 1, Pushed::too_large(axis, value, origin)));
            }
        }
    }
    if out.len() == 0 {
        return Err(format!("none of the {declared} points has a valid finite position"));
    }
    let mut notes = Vec::new();
    if invalid > 0 {
        notes.push(format!("{invalid} of {declared} points have no valid position (invalid or direction-only) and were skipped"));
    }
    let mut parts = vec![format!("E57, {} scan{}", scans.len(), if scans.len() == 1 { "" } else { "s" })];
    if posed > 0 {
        parts.push(format!("{posed} with a pose, applied"));
    }
    if spherical > 0 {
        parts.push(format!("{spherical} spherical, converted"));
    }
    if colours {
        parts.push("colours".into());
    }
    let dropped = out.dropped;
    Ok(ScanFile {
        format: ScanFormat::E57,
        cloud: out.finish(),
        declared,
        dropped_non_finite: dropped,
        layout: parts.join("; "),
        comments,
        notes,
        stated_units: Some(Units::Metres),
        ply: None,
    })
}
