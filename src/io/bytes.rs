//! What the readers share of reading bytes: little-endian integers from binary headers (LAS,
//! E57), and line endings in text (PLY's ascii body, text clouds).

/// Little-endian integers at byte `at` of a binary header (the caller has checked the length),
/// widened to u64.
pub(crate) fn u16_at(b: &[u8], at: usize) -> u64 {
    u16::from_le_bytes([b[at], b[at + 1]]) as u64
}
pub(crate) fn u32_at(b: &[u8], at: usize) -> u64 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]) as u64
}
pub(crate) fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut v = [0; 8];
    v.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(v)
}

/// Whether `b[i]` ends a line: LF, or a CR not followed by LF (CRLF ends at its LF; classic
/// Mac OS ends lines with a lone CR).
pub(crate) fn ends_line(b: &[u8], i: usize) -> bool {
    b[i] == b'\n' || (b[i] == b'\r' && b.get(i + 1) != Some(&b'\n'))
}

/// The 1-based line that the byte after `before` is on, line endings as [`ends_line`] has them.
pub(crate) fn line_of(before: &[u8]) -> usize {
    1 + (0..before.len()).filter(|&i| ends_line(before, i)).count()
}
