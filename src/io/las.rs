//! LAS and LAZ (ASPRS LAS 1.0–1.4, every point format 0–10), through the `las` crate for the
//! header and the point records and the `laz` crate for LASzip decompression.
//!
//! The crates trust the header's counts; this module checks them against the file first:
//! the point records against the bytes after the header (uncompressed), the point count and
//! the LASzip chunk table against what a compressed file could hold, and each extended VLR's
//! length against the file, so a tiny hostile file cannot make them allocate gigabytes.
//! Coordinates are `integer × scale + offset` in f64, then moved near zero by the shared
//! [`CloudBuilder`] (far-off, georeferenced clouds keep their precision). RGB is 16-bit by the
//! specification, but many writers store 8-bit values: when no channel exceeds 255 the values
//! are taken as 8-bit.

use std::io::{Cursor, Seek, SeekFrom};

use super::builder::{CloudBuilder, Pushed};
use super::bytes::{u16_at, u32_at, u64_at};
use super::scan_file::{ScanFile, ScanFormat, MAX_COMPRESSED_POINTS};
use crate::units::Units;

/// Points decoded at a time: bounds the record buffer whatever the file declares.
const BATCH: usize = 1 << 16;

/// The most points `after` bytes of LASzip data can hold, from what a chunk really is: every
/// chunk starts with its first point stored whole (`record_len` bytes; layered chunks add a
/// count and layer sizes) and holds at most `chunk_size` points, so there are at most
/// `after / record_len` chunks (rounded up). The arithmetic coder itself can spend far less
/// than a bit a point on regular data: a flat 1000×1000 grid is 12 KB, 84 points a byte, which
/// an earlier fixed cap of 64 points a byte called truncated. Variable-size chunks
/// (`chunk_size` u32::MAX) give no bound beyond [`MAX_COMPRESSED_POINTS`].
pub fn laz_points_cap(after: u64, record_len: u64, chunk_size: u32) -> u64 {
    if chunk_size == u32::MAX || chunk_size == 0 {
        return MAX_COMPRESSED_POINTS;
    }
    let chunks = after.div_ceil(record_len.max(1));
    chunks.saturating_mul(chunk_size as u64).min(MAX_COMPRESSED_POINTS)
}

/// The public header's fields that bound allocations, checked against the file.
struct Layout {
    version: (u8, u8),
    offset_to_points: u64,
    record_len: u64,
    count: u64,
    compressed: bool,
    format: u8,
}

fn check_layout(b: &[u8]) -> Result<Layout, String> {
    const MIN_HEADER: usize = 227;
    if b.len() < MIN_HEADER {
        return Err(format!("the file is {} bytes, shorter than a LAS header ({MIN_HEADER} bytes)", b.len()));
    }
    let version = (b[24], b[25]);
    if version.0 != 1 || version.1 > 4 {
        return Err(format!("unsupported LAS version {}.{} (nkrr reads 1.0 to 1.4)", version.0, version.1));
    }
    let header_size = u16_at(b, 94);
    let offset_to_points = u32_at(b, 96);
    let vlrs = u32_at(b, 100);
    let format_byte = b[104];
    let record_len = u16_at(b, 105);
    let legacy_count = u32_at(b, 107);
    let file_len = b.len() as u64;
    if (header_size as usize) < MIN_HEADER || header_size > file_len {
        return Err(format!("the header declares a size of {header_size} bytes (at byte 94), but the file has {file_len}"));
    }
    if offset_to_points > file_len || offset_to_points < header_size {
        return Err(format!(
            "the point data is declared to start at byte {offset_to_points} (at byte 96), outside the file's {file_len} bytes or inside its {header_size}-byte header"
        ));
    }
    if vlrs.saturating_mul(54) > offset_to_points - header_size {
        return Err(format!(
            "{vlrs} variable-length records are declared (at byte 100), more than the {} bytes before the points can hold",
            offset_to_points - header_size
        ));
    }
    // Each VLR (a 54-byte header, then as many bytes as it declares at its byte 20) must end
    // inside the file: one that runs past it failed in the `las` crate as "header: failed to
    // fill whole buffer", which named neither the record nor the header as the cause.
    let mut at = header_size;
    for i in 0..vlrs {
        if at + 54 > file_len {
            return Err(format!(
                "variable-length record {i} of {vlrs} (declared at byte 100) would start at byte {at}, but its 54-byte header runs past the file's end at byte {file_len}: the header is damaged"
            ));
        }
        let len = u16_at(b, at as usize + 20);
        if at + 54 + len > file_len {
            let user = String::from_utf8_lossy(&b[at as usize + 2..at as usize + 18]).trim_end_matches('\0').to_string();
            let id = u16_at(b, at as usize + 18);
            return Err(format!(
                "variable-length record {i} (at byte {at}, user '{user}', record {id}) declares {len} bytes of data (at byte {}), running past the file's end at byte {file_len}: the record's length or the file is damaged",
                at + 20
            ));
        }
        at += 54 + len;
    }
    // The count the `las` crate will use, by its rule (the LAS 1.4 specification's): the
    // legacy 32-bit field when it is not zero, else the 64-bit one, read for every 1.4 header
    // whatever its declared size. Checking another count than the crate's let a damaged header
    // through to `count × record length`, which overflowed inside the crate (the fuzzer found it).
    let count = if version.1 >= 4 && legacy_count == 0 && b.len() >= 255 { u64_at(b, 247) } else { legacy_count };
    let compressed = format_byte & 0x80 != 0 || format_byte & 0x40 != 0;
    let format = format_byte & 0x3f;
    let after = file_len - offset_to_points;
    if compressed {
        if count > MAX_COMPRESSED_POINTS {
            return Err(format!("the header declares {count} points; nkrr reads at most {MAX_COMPRESSED_POINTS} from a compressed file"));
        }
    } else if (count as u128) * (record_len as u128) > after as u128 {
        return Err(format!(
            "the header declares {count} points of {record_len} bytes ({} bytes), but only {after} bytes follow the header at byte {offset_to_points}: the file is truncated or its header is wrong",
            count as u128 * record_len as u128
        ));
    }
    // Extended VLRs (1.4) carry 64-bit lengths: each must fit in the file.
    if version.1 >= 4 && header_size >= 375 && b.len() >= 255 {
        let (mut at, n) = (u64_at(b, 235), u32_at(b, 243));
        if n > 0 {
            for i in 0..n {
                if at.saturating_add(60) > file_len {
                    return Err(format!("extended VLR {i} is declared at byte {at}, beyond the file's {file_len} bytes"));
                }
                let len = u64_at(b, at as usize + 20);
                if len > file_len - at - 60 {
                    return Err(format!("extended VLR {i} at byte {at} declares {len} bytes; the file has {} after it", file_len - at - 60));
                }
                at += 60 + len;
            }
        }
    }
    Ok(Layout { version, offset_to_points, record_len, count, compressed, format })
}

/// Checks the LASzip chunk table (whose entry count the `laz` crate allocates for) against the
/// file: at most one chunk a point, and at least a bit of table per chunk.
fn check_chunk_table(b: &[u8], l: &Layout) -> Result<(), String> {
    let at = l.offset_to_points as usize;
    if b.len() < at + 8 {
        return Err(format!("the compressed point data at byte {at} is truncated"));
    }
    let table = u64_at(b, at);
    if table == u64::MAX || table as usize <= at {
        return Ok(()); // No table: the decompressor reads chunk by chunk.
    }
    if table.saturating_add(8) > b.len() as u64 {
        return Err(format!("the LASzip chunk table is declared at byte {table}, beyond the file's {} bytes", b.len()));
    }
    let chunks = u32_at(b, table as usize + 4);
    let left = b.len() as u64 - table - 8;
    if chunks > l.count + 1 || chunks > left.saturating_mul(8) {
        return Err(format!(
            "the LASzip chunk table at byte {table} declares {chunks} chunks for {} points in {left} bytes",
            l.count
        ));
    }
    Ok(())
}

/// Checks that the LASzip record's items are the ones the header's point format calls for
/// (type and size; the `laz` crate panics on an empty list and slices out of bounds on sizes
/// that do not add up to the record).
fn check_laz_items(vlr: &laz::LazVlr, format: u8, extra: u16, record_len: usize) -> Result<(), String> {
    let expected = laz::LazItemRecordBuilder::default_for_point_format_id(format, extra)
        .map_err(|e| format!("LASzip: point format {format}: {e}"))?;
    let items = vlr.items();
    let same = items.len() == expected.len()
        && items.iter().zip(&expected).all(|(a, b)| a.item_type() == b.item_type() && a.size() == b.size())
        && items.iter().all(|i| (1..=4).contains(&i.version()))
        && items.iter().map(|i| i.size() as usize).sum::<usize>() == record_len;
    if !same {
        let got: Vec<String> = items.iter().map(|i| format!("{:?}/{}", i.item_type(), i.size())).collect();
        return Err(format!(
            "LASzip: the compressed items [{}] do not match point format {format} ({record_len}-byte records)",
            got.join(", ")
        ));
    }
    Ok(())
}

/// Walks the chunks of a layered (LAS 1.4, point formats 6–10) LASzip stream and checks every
/// layer size against the bytes left: the `laz` crate sizes a buffer by each before reading it,
/// so a corrupt size would otherwise allocate up to 4 GB. A chunk is the first point raw, its
/// point count, one u32 size per layer, then the layers.
fn check_laz_layers(b: &[u8], l: &Layout, vlr: &laz::LazVlr, record_len: usize) -> Result<(), String> {
    use laz::LazItemType::*;
    let layers: usize = vlr
        .items()
        .iter()
        .map(|i| match i.item_type() {
            Point14 => 9,
            RGBNIR14 => 2,
            Byte14(n) | Byte(n) => n as usize,
            _ => 1,
        })
        .sum();
    let len = b.len() as u64;
    let mut at = l.offset_to_points + 8;
    let mut points = 0u64;
    let mut chunk = 0u64;
    while points < l.count {
        let head = at + record_len as u64;
        if head + 4 + 4 * layers as u64 > len {
            return Err(format!("LASzip chunk {chunk} at byte {at} is truncated"));
        }
        let count = u32_at(b, head as usize) as u64;
        if count == 0 {
            return Err(format!("LASzip chunk {chunk} at byte {at} holds no points"));
        }
        let mut end = head + 4 + 4 * layers as u64;
        for k in 0..layers {
            let size = u32_at(b, (head + 4 + 4 * k as u64) as usize);
            end = end.saturating_add(size);
        }
        if end > len {
            return Err(format!("LASzip chunk {chunk} at byte {at} declares layers ending at byte {end}, beyond the file's {len} bytes"));
        }
        points += count;
        at = end;
        chunk += 1;
    }
    Ok(())
}

/// Looks for a coordinate system's linear unit in the OGC WKT record, when there is one.
fn crs_units(header: &::las::Header) -> Option<Units> {
    let wkt = header.all_vlrs().find(|v| v.record_id == 2112 && v.user_id.trim_end_matches('\0') == "LASF_Projection")?;
    let text = String::from_utf8_lossy(&wkt.data).to_ascii_lowercase();
    // The last UNIT of a projected CRS is its linear unit.
    let unit = text.rsplit("unit[").next()?;
    if unit.contains("foot") || unit.contains("feet") {
        Some(Units::Feet)
    } else if unit.contains("metre") || unit.contains("meter") {
        Some(Units::Metres)
    } else {
        None
    }
}

/// Reads a LAS or LAZ file.
pub fn read_las(bytes: &[u8]) -> Result<ScanFile, String> {
    let layout = check_layout(bytes)?;
    if layout.compressed {
        check_chunk_table(bytes, &layout)?;
    }
    let mut cur = Cursor::new(bytes);
    let header = ::las::Header::new(&mut cur).map_err(|e| format!("header: {e}"))?;
    let format = *header.point_format();
    if !layout.compressed && format.len() as u64 > layout.record_len {
        return Err(format!("point format {} needs {} bytes a record, but the header says {}", layout.format, format.len(), layout.record_len));
    }
    let record_len = format.len() as usize;
    let t = *header.transforms();
    let count = layout.count;
    if count == 0 {
        return Err("the file holds no points".into());
    }
    cur.seek(SeekFrom::Start(layout.offset_to_points)).map_err(|e| e.to_string())?;

    let mut out = CloudBuilder::new(false, format.has_color, true);
    out.reserve(usize::try_from(count).unwrap_or(usize::MAX).min(BATCH * 16));
    let mut rgb16: Vec<[u16; 3]> = Vec::new();
    let mut done = 0u64;
    let mut take = |rec: &[u8], done: &mut u64| -> Result<(), String> {
        let p = ::las::raw::Point::read_from(rec, &format).map_err(|e| format!("point {done}: {e}"))?;
        let before = out.len();
        let pushed = out.push([t.x.direct(p.x), t.y.direct(p.y), t.z.direct(p.z)], [0.0; 3], [0, 0, 0, 255]);
        if let Pushed::TooLarge { axis, value, origin } = pushed {
            return Err(format!("point {done}: {}", Pushed::too_large(axis, value, origin)));
        }
        if let (true, Some(c)) = (out.len() > before, p.color) {
            rgb16.push([c.red, c.green, c.blue]);
        }
        *done += 1;
        Ok(())
    };
    if layout.compressed {
        let vlr = header.laz_vlr().map_err(|e| format!("LASzip: {e}"))?;
        check_laz_items(&vlr, layout.format, format.extra_bytes, record_len)?;
        if layout.format >= 6 {
            check_laz_layers(bytes, &layout, &vlr, record_len)?;
        }
        let chunk_size = vlr.chunk_size();
        let after = bytes.len() as u64 - layout.offset_to_points;
        let cap = laz_points_cap(after, record_len as u64, chunk_size);
        if count > cap {
            return Err(format!(
                "the header declares {count} compressed points, but the {after} bytes of point data after byte {} can \
                 hold at most {cap} (each LASzip chunk of at most {chunk_size} points starts with one {record_len}-byte \
                 point stored whole): the file is truncated or its header is wrong",
                layout.offset_to_points
            ));
        }
        let mut d = laz::LasZipDecompressor::new(&mut cur, vlr).map_err(|e| {
            format!(
                "LASzip, before the first point: reading the chunk table (its offset at byte {}) failed: the file is \
                 truncated or its chunk table is damaged ({e})",
                layout.offset_to_points
            )
        })?;
        // Where a failure happened, in the user's terms: the `laz` crate's own messages ("failed
        // to fill whole buffer", "logic error") say neither which points nor which bytes.
        let fixed_chunks = chunk_size != u32::MAX && chunk_size > 0;
        let file_len = bytes.len();
        // A few MB of records at a time, whatever the record length.
        let batch = (BATCH * 64 / record_len.max(1)).clamp(1, BATCH);
        let mut buf = vec![0u8; batch * record_len];
        while done < count {
            let n = (count - done).min(batch as u64) as usize;
            let chunk = &mut buf[..n * record_len];
            d.decompress_many(chunk).map_err(|e| {
                let at = d.get_mut().position();
                let (first, last) = (done / chunk_size as u64, (done + n as u64 - 1) / chunk_size as u64);
                let chunk_no = match (fixed_chunks, first == last) {
                    (false, _) => String::new(),
                    (true, true) => format!(", in chunk {first} ({chunk_size} points a chunk)"),
                    (true, false) => format!(", in chunks {first}-{last} ({chunk_size} points a chunk)"),
                };
                // Decoding corrupt data can run on to the end of the file too: where the chunk
                // table (written after the points) is there, the file is whole and damaged.
                let table = u64_at(bytes, layout.offset_to_points as usize);
                let whole = table != u64::MAX && table > layout.offset_to_points && table + 8 <= file_len as u64;
                let why = if e.kind() == std::io::ErrorKind::UnexpectedEof && whole {
                    format!(
                        "the compressed point data is damaged (corrupt or missing bytes): decoding ran on to byte {at} of \
                         {file_len}, past the points' data, which ends where the chunk table starts (byte {table}); the \
                         table is in place, so the file was not simply cut short at its end"
                    )
                } else if e.kind() == std::io::ErrorKind::UnexpectedEof {
                    format!("the compressed data ran out at byte {at} of {file_len}, while decoding these points: the file is truncated")
                } else {
                    format!("corrupt compressed data near byte {at} of {file_len}")
                };
                format!("LASzip, decoding points {done}..{}{chunk_no}: {why} ({e})", done + n as u64)
            })?;
            for rec in chunk.chunks_exact(record_len) {
                take(rec, &mut done).map_err(|m| format!("{m} (a record decompressed from LASzip data: corrupt data?)"))?;
            }
        }
    } else {
        // check_layout has bounded count × record_len by the bytes after the header.
        let start = layout.offset_to_points as usize;
        let body = &bytes[start..start + (count * layout.record_len) as usize];
        for (i, rec) in body.chunks_exact(layout.record_len as usize).enumerate() {
            take(&rec[..record_len.min(rec.len())], &mut done)
                .map_err(|m| format!("{m} (the {}-byte record at byte {})", layout.record_len, start + i * layout.record_len as usize))?;
        }
    }
    if out.len() == 0 {
        return Err(format!("all {count} points have non-finite coordinates"));
    }
    let dropped = out.dropped;
    let mut cloud = out.finish();
    let mut colour_note = None;
    if let Some(colors) = &mut cloud.colors {
        let eight_bit = rgb16.iter().flatten().all(|&c| c <= 255);
        colour_note = Some(if eight_bit { "colours (8-bit values)" } else { "colours (16-bit)" });
        for (dst, src) in colors.iter_mut().zip(&rgb16) {
            let ch = src.map(|c| if eight_bit { c as u8 } else { ((c as u32 + 128) / 257).min(255) as u8 });
            *dst = [ch[0], ch[1], ch[2], 255];
        }
        if rgb16.iter().all(|c| *c == [0, 0, 0]) {
            cloud.colors = None;
            colour_note = Some("colour fields all zero (ignored)");
        }
    }
    let mut parts = vec![format!(
        "LAS {}.{}, point format {}{}",
        layout.version.0,
        layout.version.1,
        layout.format,
        if layout.compressed { " (LAZ-compressed)" } else { "" }
    )];
    parts.push(format!("scale {} {} {}, offset {} {} {}", t.x.scale, t.y.scale, t.z.scale, t.x.offset, t.y.offset, t.z.offset));
    if let Some(c) = colour_note {
        parts.push(c.into());
    }
    let mut comments = Vec::new();
    for (k, v) in [("system", header.system_identifier()), ("software", header.generating_software())] {
        let v = v.trim_matches(|c: char| c == '\0' || c.is_whitespace());
        if !v.is_empty() {
            comments.push(format!("{k}: {v}"));
        }
    }
    let stated_units = crs_units(&header);
    let mut notes = Vec::new();
    if stated_units.is_none() {
        notes.push("LAS coordinates are in the units of the file's coordinate system, which it does not state in a form nkrr reads: give the units if they are not metres".into());
    }
    Ok(ScanFile {
        format: ScanFormat::Las,
        cloud,
        declared: count,
        dropped_non_finite: dropped,
        layout: parts.join("; "),
        comments,
        notes,
        stated_units,
        ply: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal LAS 1.2 header for `count` points of format 0 (20 bytes each).
    #[test]
    fn the_laz_cap_follows_the_chunks() {
        // The 1000×1000 grid: 11.5 KB of 20-byte points in chunks of 50000 holds 1M easily.
        assert!(laz_points_cap(11_500, 20, 50_000) >= 1_000_000);
        // One chunk's worth of bytes holds at most one chunk.
        assert_eq!(laz_points_cap(20, 20, 50_000), 50_000);
        assert_eq!(laz_points_cap(21, 20, 50_000), 100_000);
        assert_eq!(laz_points_cap(1 << 40, 20, u32::MAX), MAX_COMPRESSED_POINTS);
        assert_eq!(laz_points_cap(1 << 40, 1, 50_000), MAX_COMPRESSED_POINTS);
    }

    fn header(count: u32, body: usize) -> Vec<u8> {
        let mut b = vec![0u8; 227 + body];
        b[..4].copy_from_slice(b"LASF");
        b[24] = 1;
        b[25] = 2;
        b[94..96].copy_from_slice(&227u16.to_le_bytes());
        b[96..100].copy_from_slice(&227u32.to_le_bytes());
        b[105..107].copy_from_slice(&20u16.to_le_bytes());
        b[107..111].copy_from_slice(&count.to_le_bytes());
        for (i, s) in [131, 139, 147].into_iter().enumerate() {
            b[s..s + 8].copy_from_slice(&[0.001f64, 0.001, 0.01][i].to_le_bytes());
        }
        b[155..163].copy_from_slice(&5e6f64.to_le_bytes());
        b
    }

    #[test]
    fn declared_counts_beyond_the_file_are_errors_before_any_allocation() {
        let e = read_las(&header(2_000_000_000, 40)).unwrap_err();
        assert!(e.contains("2000000000 points of 20 bytes"), "{e}");
        assert!(read_las(&header(1, 0)).is_err());
        assert!(read_las(b"LASF").is_err());
    }

    #[test]
    fn reads_points_with_scale_and_offset() {
        let mut b = header(2, 40);
        for (i, xyz) in [[1000i32, 2000, 300], [-1000, 0, 0]].iter().enumerate() {
            let at = 227 + 20 * i;
            for a in 0..3 {
                b[at + 4 * a..at + 4 * a + 4].copy_from_slice(&xyz[a].to_le_bytes());
            }
        }
        let f = read_las(&b).unwrap();
        assert_eq!(f.cloud.origin, [5e6 + 1.0, 0.0, 0.0]);
        assert_eq!(f.cloud.positions, vec![[0.0, 2.0, 3.0], [-2.0, 0.0, 0.0]]);
        assert!(f.cloud.colors.is_none());
    }
}
