//! Text clouds: one point per line, as XYZ, PTS, CSV and TXT exports write them.
//!
//! Values are separated by whitespace, commas or semicolons. Lines before the first line of
//! numbers are headers (a CSV's column names are used to find x, y, z, colours and normals);
//! lines starting with `#` or `//` are comments anywhere; a lone integer before the data is a
//! PTS point count. Without names, the columns are read by count: `x y z`, then an intensity
//! when the count is 4, 7 or 10 (PTS and CloudCompare order), then up to two triples, each
//! taken as normals when they are unit vectors and as colours when they are 0–255 integers,
//! 0–1 fractions or 16-bit values (judged on the first 1000 points).
//! Every data line must have as many values as the first; an error names the line.
//!
//! Lines end with LF, CRLF or a lone CR (classic Mac OS exports): reading only LF made a
//! CR-only file one long line. A decimal-comma dialect (`-0,1646;0,3188;-0,3483`, as European
//! spreadsheets export, or the same separated by spaces or tabs) is read when the first data
//! line makes it unambiguous: fields separated by `;` or whitespace, each holding exactly one
//! comma with digits on both sides. Read as ordinary CSV, such
//! a line is six columns with x = ±0, a cloud that is wrong without a word. Once the dialect is
//! chosen, a line that does not fit it (a field with two commas, or a comma not between digits)
//! is refused with its line number rather than guessed at; so is a first data line with both
//! `;` and `,` that is not unambiguous (`1,5;2;3,25`: decimal commas on some fields only, or
//! two separators).
//! A NUL byte is refused with its byte offset, and a line of more than [`MAX_COLUMNS`] numbers
//! with its count: both used to end as "not a point cloud" or "no line of numbers", which
//! pointed nowhere.

use std::fmt;

use super::builder::{CloudBuilder, Pushed};
use super::bytes::line_of;
use super::scan_file::{ScanFile, ScanFormat};

/// Why a text cloud could not be read; `line` is 1-based (0 when it is about the whole file).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TextError {
    pub line: usize,
    pub message: String,
}

impl fmt::Display for TextError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 {
            write!(f, "text cloud: {}", self.message)
        } else {
            write!(f, "text cloud, line {}: {}", self.line, self.message)
        }
    }
}

impl std::error::Error for TextError {}

fn err(line: usize, message: impl Into<String>) -> TextError {
    TextError { line, message: message.into() }
}

/// Header lines allowed before the data: beyond this the file is taken for something else.
const MAX_HEADER_LINES: usize = 64;
/// Data lines looked at to decide what the columns hold.
const SAMPLE_LINES: usize = 1000;
/// Values per line beyond which a line is not a point.
const MAX_COLUMNS: usize = 64;

/// Whether `bytes` start like a text file: almost only printable ASCII in the first 4 KB
/// (at most one byte in 50 otherwise: a binary file has far more), with at least one digit.
/// A stray NUL (one in 50 bytes, or one in a short file) is let through, so that the text
/// reader can say where it is; UTF-16 text and binary files have far more.
///
/// The digit is looked for from the first line that is not a comment (`#`, `//`), within the
/// first [`COMMENT_SCAN`] bytes: a long first comment (an export's whole settings on one line)
/// used to hide every digit from a 4 KB look and the file was refused as "not a point cloud".
pub fn looks_like_text(bytes: &[u8]) -> bool {
    let bytes = strip_boms(bytes);
    let head = &bytes[..bytes.len().min(4096)];
    let data = &bytes[after_comments(&bytes[..bytes.len().min(COMMENT_SCAN)])..];
    if !data[..data.len().min(4096)].iter().any(u8::is_ascii_digit) {
        return false;
    }
    let nul = head.iter().filter(|&&b| b == 0).count();
    let odd = head.iter().filter(|&&b| b != 0 && !(b.is_ascii_graphic() || b.is_ascii_whitespace())).count();
    nul * 50 <= head.len().max(50) && odd * 50 <= head.len()
}

/// How far [`looks_like_text`] reads past leading comment lines to find the data.
const COMMENT_SCAN: usize = 1 << 20;

/// The UTF-8 byte-order mark.
const BOM: &[u8] = b"\xEF\xBB\xBF";

/// `bytes` without the byte-order marks they start with: editors and concatenated exports can
/// leave two, and a second one left in front of the first line made it a header, losing its
/// point without a word.
fn strip_boms(mut bytes: &[u8]) -> &[u8] {
    while let Some(rest) = bytes.strip_prefix(BOM) {
        bytes = rest;
    }
    bytes
}

/// The offset of the first line of `bytes` that is not blank and not a comment (`#`, `//`), or
/// of the end of `bytes` when they hold none.
fn after_comments(bytes: &[u8]) -> usize {
    let mut at = 0;
    while at < bytes.len() {
        let end = bytes[at..].iter().position(|&b| b == b'\n' || b == b'\r').map_or(bytes.len(), |e| at + e);
        let line = bytes[at..end].trim_ascii();
        if !(line.is_empty() || line.starts_with(b"#") || line.starts_with(b"//")) {
            return at;
        }
        at = end + 1;
    }
    bytes.len()
}

/// The fields of a line: separated by `;`, whitespace and, unless the file writes decimal
/// commas, `,`.
fn fields(line: &str, decimal_comma: bool) -> impl Iterator<Item = &str> {
    line.split(move |c: char| c == ';' || c.is_ascii_whitespace() || (c == ',' && !decimal_comma)).filter(|t| !t.is_empty())
}

fn tokens(line: &str) -> impl Iterator<Item = &str> {
    fields(line, false)
}

/// The fields of a decimal-comma line: separated by `;` or whitespace, never by `,`.
fn dc_tokens(line: &str) -> impl Iterator<Item = &str> {
    fields(line, true)
}

/// Whether a field is a number written with a decimal comma: exactly one comma, digits on
/// both sides.
fn is_decimal_comma_field(t: &str) -> bool {
    let b = t.as_bytes();
    let mut commas = b.iter().enumerate().filter(|(_, &c)| c == b',');
    match (commas.next(), commas.next()) {
        (Some((i, _)), None) => i > 0 && i + 1 < b.len() && b[i - 1].is_ascii_digit() && b[i + 1].is_ascii_digit(),
        _ => false,
    }
}

/// Whether `line` is unambiguously a line of decimal-comma numbers: `;` or whitespace separates
/// at least three fields, and every field has exactly one comma with digits around it
/// (`-0,1646;0,3188;-0,3483` or `-0,1646 0,3188 -0,3483`). Ordinary CSV never qualifies: its
/// commas separate fields, so a whitespace-separated field of it holds either no comma, several,
/// or one at its end (`1, 2, 3`).
fn is_decimal_comma_line(line: &str) -> bool {
    let t = line.trim();
    dc_tokens(t).count() >= 3
        && dc_tokens(t).all(|f| is_decimal_comma_field(f) && f.replacen(',', ".", 1).parse::<f64>().is_ok())
}

/// Whether `line` has at least three whitespace-separated fields, no `;`, and mixes fields
/// with one decimal comma (`2,5`) with plain numbers (`1 2,5 3`): a decimal-comma line with
/// whole numbers written bare, or spaces and commas both separating; either reading may be wrong.
fn is_mixed_decimal_comma_line(line: &str) -> bool {
    let t = line.trim();
    let fields: Vec<&str> = t.split_ascii_whitespace().collect();
    !t.contains(';')
        && fields.len() >= 3
        && fields.iter().any(|f| is_decimal_comma_field(f))
        && fields.iter().all(|f| is_decimal_comma_field(f) || (!f.contains(',') && f.parse::<f64>().is_ok()))
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Role {
    X,
    Y,
    Z,
    R,
    G,
    B,
    Nx,
    Ny,
    Nz,
    Ignored,
}

/// What a column name says it holds.
fn role_of_name(name: &str) -> Role {
    let n = name.trim_matches(|c: char| c == '"' || c == '\'' || c == '/' || c == '/').to_ascii_lowercase();
    match n.as_str() {
        "x" | "//x" | "px" | "pos_x" => Role::X,
        "y" | "py" | "pos_y" => Role::Y,
        "z" | "pz" | "pos_z" => Role::Z,
        "r" | "red" | "diffuse_red" => Role::R,
        "g" | "green" | "diffuse_green" => Role::G,
        "b" | "blue" | "diffuse_blue" => Role::B,
        "nx" | "normal_x" | "normalx" | "n_x" => Role::Nx,
        "ny" | "normal_y" | "normaly" | "n_y" => Role::Ny,
        "nz" | "normal_z" | "normalz" | "n_z" => Role::Nz,
        _ => Role::Ignored,
    }
}

/// Column roles from a header's names, when they name x, y and z.
fn roles_from_names(names: &[String], columns: usize) -> Option<Vec<Role>> {
    if names.len() != columns {
        return None;
    }
    let roles: Vec<Role> = names.iter().map(|n| role_of_name(n)).collect();
    let has = |r: Role| roles.iter().filter(|&&x| x == r).count() == 1;
    if !(has(Role::X) && has(Role::Y) && has(Role::Z)) {
        return None;
    }
    // Partial triples are ignored: a colour needs all three channels.
    let keep = |trio: [Role; 3]| trio.iter().all(|&r| has(r));
    let (colour, normal) = (keep([Role::R, Role::G, Role::B]), keep([Role::Nx, Role::Ny, Role::Nz]));
    Some(
        roles
            .into_iter()
            .map(|r| match r {
                Role::R | Role::G | Role::B if !colour => Role::Ignored,
                Role::Nx | Role::Ny | Role::Nz if !normal => Role::Ignored,
                r => r,
            })
            .collect(),
    )
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Triple {
    Normals,
    Colours,
    Unknown,
}

/// What three sampled columns look like.
fn classify(samples: &[[f64; 3]]) -> Triple {
    if samples.is_empty() {
        return Triple::Unknown;
    }
    let unit = samples
        .iter()
        .filter(|v| {
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            (0.95..=1.05).contains(&n) || n == 0.0
        })
        .count();
    let any_negative = samples.iter().flatten().any(|&c| c < 0.0);
    if unit * 20 >= samples.len() * 19 && (any_negative || samples.iter().flatten().any(|&c| c.fract() != 0.0)) {
        return Triple::Normals;
    }
    let all = |f: &dyn Fn(f64) -> bool| samples.iter().flatten().all(|&c| f(c));
    if all(&|c| (0.0..=65535.0).contains(&c) && c.fract() == 0.0) || all(&|c| (0.0..=1.0).contains(&c)) {
        return Triple::Colours;
    }
    Triple::Unknown
}

/// Column roles from the sampled values, for files without usable names.
fn roles_from_values(samples: &[Vec<f64>], columns: usize) -> Vec<Role> {
    let mut roles = vec![Role::Ignored; columns];
    roles[..3].copy_from_slice(&[Role::X, Role::Y, Role::Z]);
    // 4, 7 and 10 columns: an intensity follows x y z (PTS; CloudCompare's "x y z i r g b ...").
    let start = if columns % 3 == 1 { 4 } else { 3 };
    let (mut colour, mut normal) = (false, false);
    let mut at = start;
    while at + 3 <= columns {
        let trio: Vec<[f64; 3]> = samples.iter().map(|s| [s[at], s[at + 1], s[at + 2]]).collect();
        match classify(&trio) {
            Triple::Normals if !normal => {
                roles[at..at + 3].copy_from_slice(&[Role::Nx, Role::Ny, Role::Nz]);
                normal = true;
            }
            Triple::Colours if !colour => {
                roles[at..at + 3].copy_from_slice(&[Role::R, Role::G, Role::B]);
                colour = true;
            }
            _ => {}
        }
        at += 3;
    }
    roles
}

/// How colour values map to 0..=255, from the sampled maximum.
fn colour_scale(max: f64, any_fraction: bool) -> f64 {
    if max <= 1.0 && (any_fraction || max < 1.0) {
        255.0
    } else if max > 255.0 {
        1.0 / 257.0
    } else {
        1.0
    }
}

/// One line of the file, classified.
enum Line<'a> {
    Blank,
    Comment(&'a str),
    Values(usize),
    Words,
    /// Numbers only, but more than [`MAX_COLUMNS`] of them.
    TooMany(usize),
    /// In a decimal-comma file: a field whose commas do not make one decimal comma.
    BadDecimal(&'a str),
}

fn classify_line<'a>(line: &'a str, values: &mut Vec<f64>, decimal_comma: bool) -> Line<'a> {
    let t = line.trim();
    if t.is_empty() {
        return Line::Blank;
    }
    if let Some(c) = t.strip_prefix('#').or_else(|| t.strip_prefix("//")) {
        // "//X,Y,Z,R,G,B" is CloudCompare's header, not a comment.
        if !(t.starts_with("//") && tokens(c).next().is_some_and(|w| role_of_name(w) == Role::X)) {
            return Line::Comment(c.trim());
        }
    }
    values.clear();
    let mut count = 0usize;
    // A decimal comma is read as a point.
    for tok in fields(t, decimal_comma) {
        let parsed = if decimal_comma && tok.contains(',') {
            if !is_decimal_comma_field(tok) {
                return Line::BadDecimal(tok);
            }
            tok.replacen(',', ".", 1).parse::<f64>()
        } else {
            tok.parse::<f64>()
        };
        match parsed {
            Ok(v) => {
                count += 1;
                if count <= MAX_COLUMNS {
                    values.push(v);
                }
            }
            Err(_) => return Line::Words,
        }
    }
    if count > MAX_COLUMNS {
        return Line::TooMany(count);
    }
    Line::Values(count)
}

fn too_many(count: usize) -> String {
    format!(
        "{count} numbers on one line, more than the {MAX_COLUMNS} a point may have (x y z and its attributes): \
         is this a matrix or an image rather than a point cloud?"
    )
}

struct Lines<'a> {
    text: &'a str,
    pos: usize,
    number: usize,
}

impl<'a> Lines<'a> {
    fn new(text: &'a str) -> Self {
        Lines { text, pos: 0, number: 0 }
    }

    /// Whether the line last returned was the file's last and had no line ending: a file cut
    /// while it was being written (or one whose writer left the last line open).
    fn ended_open(&self) -> bool {
        self.pos > self.text.len()
    }
}

impl<'a> Iterator for Lines<'a> {
    type Item = (usize, &'a str);
    fn next(&mut self) -> Option<(usize, &'a str)> {
        if self.pos >= self.text.len() {
            return None;
        }
        // LF, CRLF and a lone CR (classic Mac OS) all end a line.
        let rest = &self.text[self.pos..];
        let end = rest.find(['\n', '\r']).unwrap_or(rest.len());
        let crlf = rest.as_bytes().get(end) == Some(&b'\r') && rest.as_bytes().get(end + 1) == Some(&b'\n');
        self.pos += end + if crlf { 2 } else { 1 };
        self.number += 1;
        // A byte-order mark at a line's start (files joined with `cat`, each with its own) is
        // not part of its first value.
        Some((self.number, rest[..end].trim_start_matches('\u{feff}')))
    }
}

/// The decimals of the last value of the data lines read so far: one count on every line is a
/// writer with a fixed format ("%.6f"), against which a last line with fewer looks cut; shortest
/// round-trip writers give each value its own count, and then nothing can be told.
#[derive(Clone, Copy)]
enum Decimals {
    Unseen,
    /// Every line so far (`lines` of them) has `count` decimals.
    Fixed { count: usize, lines: usize },
    /// The counts differ, or a value has no decimal point.
    Varied,
}

impl Decimals {
    /// The state after one more data line whose last value has `d` decimals.
    fn after(self, d: Option<usize>) -> Decimals {
        match (self, d) {
            (Decimals::Unseen, Some(count)) => Decimals::Fixed { count, lines: 1 },
            (Decimals::Fixed { count, lines }, Some(d)) if d == count => Decimals::Fixed { count, lines: lines + 1 },
            _ => Decimals::Varied,
        }
    }
}

/// Digits after the decimal point of the last field of `line` (None without one).
fn last_decimals(line: &str, decimal_comma: bool) -> Option<usize> {
    let last = fields(line.trim(), decimal_comma).last()?;
    let mantissa = last.split(['e', 'E']).next().unwrap_or(last);
    let (_, frac) = mantissa.split_once(if decimal_comma { ',' } else { '.' })?;
    Some(frac.len())
}

/// Reads a text cloud.
pub fn read_text(bytes: &[u8]) -> Result<ScanFile, TextError> {
    if let Some(at) = bytes.iter().position(|&b| b == 0) {
        let line = line_of(&bytes[..at]);
        return Err(err(
            line,
            format!("a NUL byte at byte {at}: a text cloud holds no NUL bytes (is the file damaged, or UTF-16?)"),
        ));
    }
    let bom = bytes.len() - strip_boms(bytes).len();
    let bytes = &bytes[bom..];
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let at = e.valid_up_to();
        let msg = format!("not text: invalid UTF-8 at byte {} (is this a binary file with a text extension?)", at + bom);
        err(line_of(&bytes[..at]), msg)
    })?;

    // Pass 1: header, comments, the column count, and a sample of the values.
    let mut values = Vec::new();
    let mut header: Option<Vec<String>> = None;
    let mut comments = Vec::new();
    let mut pts_count: Option<u64> = None;
    let mut columns = 0usize;
    let mut first_data_line = 0usize;
    let mut samples: Vec<Vec<f64>> = Vec::new();
    let mut header_lines = 0usize;
    // The decimal-comma dialect, decided by the first line that is numbers either way.
    let mut decimal_comma = false;
    for (number, line) in Lines::new(text) {
        if columns == 0 && !decimal_comma {
            if is_decimal_comma_line(line) {
                decimal_comma = true;
            } else if is_mixed_decimal_comma_line(line) {
                return Err(err(
                    number,
                    "some numbers have a decimal comma (2,5) and others none, separated by spaces: read as CSV the \
                     commas would split them. Write every value with one (2,0) or use '.'; nkrr will not guess",
                ));
            } else if line.contains(';') && line.contains(',') && matches!(classify_line(line, &mut values, false), Line::Values(_)) {
                // Numbers separated by both ';' and ',': decimal commas on some fields only
                // ("1,5;2;3,25") or two separators at once. Either reading may be wrong.
                return Err(err(
                    number,
                    "numbers separated by both ';' and ',': are the commas decimal commas (then every value \
                     needs one, e.g. 2,0) or separators? nkrr will not guess",
                ));
            }
        }
        match classify_line(line, &mut values, decimal_comma) {
            Line::Blank => {}
            Line::Comment(c) => {
                if comments.len() < 16 {
                    comments.push(c.chars().take(200).collect());
                }
            }
            Line::Words if columns == 0 => {
                header_lines += 1;
                if header_lines > MAX_HEADER_LINES {
                    return Err(err(number, format!("{MAX_HEADER_LINES} lines without a point: this is not a text cloud")));
                }
                let line = line.trim().trim_start_matches("//");
                header = Some(tokens(line).map(str::to_string).collect());
            }
            Line::Values(1) if columns == 0 && pts_count.is_none() && values[0].fract() == 0.0 && values[0] >= 0.0 => {
                // PTS: the point count on its own line.
                pts_count = Some(values[0] as u64);
            }
            Line::Values(c) if columns == 0 => {
                if c < 3 {
                    return Err(err(number, format!("{c} value(s); a point needs at least x y z")));
                }
                columns = c;
                first_data_line = number;
                samples.push(values.clone());
            }
            Line::Values(c) if c == columns => {
                samples.push(values.clone());
                if samples.len() >= SAMPLE_LINES {
                    break;
                }
            }
            Line::TooMany(c) if columns == 0 => return Err(err(number, too_many(c))),
            // A line that does not fit the first point: pass 2 reports it, where it is.
            Line::Words | Line::Values(_) | Line::TooMany(_) | Line::BadDecimal(_) => break,
        }
    }
    if columns == 0 {
        return Err(err(0, "no line of numbers: there are no points"));
    }

    let named = header.as_deref().and_then(|h| roles_from_names(h, columns));
    let roles = named.clone().unwrap_or_else(|| roles_from_values(&samples, columns));
    let col = |r: Role| roles.iter().position(|&x| x == r);
    let (ix, iy, iz) = (col(Role::X).unwrap_or(0), col(Role::Y).unwrap_or(1), col(Role::Z).unwrap_or(2));
    let normals = match (col(Role::Nx), col(Role::Ny), col(Role::Nz)) {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    let colours = match (col(Role::R), col(Role::G), col(Role::B)) {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    let scale = colours.map(|c| {
        let vals = samples.iter().flat_map(|s| c.map(|i| s[i]));
        let (max, frac) = vals.fold((0f64, false), |(m, f), v| (m.max(v), f || v.fract() != 0.0));
        colour_scale(max, frac)
    });

    // Pass 2: every point.
    let mut out = CloudBuilder::new(normals.is_some(), colours.is_some(), true);
    // At least 6 bytes ("0 0 0\n") per point: a bound the input justifies.
    out.reserve((text.len() / 6).min(1 << 22));
    let mut declared = 0u64;
    let mut notes = Vec::new();
    // The decimals of the data lines' last values so far, to judge a last line that has no line
    // ending.
    let mut decimals = Decimals::Unseen;
    let mut lines = Lines::new(text);
    while let Some((number, line)) = lines.next() {
        if number < first_data_line {
            continue;
        }
        let kind = classify_line(line, &mut values, decimal_comma);
        if lines.ended_open() {
            // A last line without a line ending may be a file cut while it was written: a
            // number cut short reads as a smaller, complete one. Left out where the line shows
            // it (too few values, not a number, fewer decimals than every line before), else
            // read and named.
            let shown: String = line.trim().chars().take(60).collect();
            let cut = match kind {
                Line::Values(c) if c < columns => Some(format!("it has {c} of the {columns} values of a point")),
                Line::Words | Line::BadDecimal(_) => Some("it does not end in a number".to_string()),
                Line::Values(c) if c == columns => match (last_decimals(line, decimal_comma), decimals) {
                    (Some(d), Decimals::Fixed { count, lines }) if d < count && lines >= 2 => {
                        Some(format!("its last value has {d} decimals where every line before has {count}"))
                    }
                    _ => None,
                },
                _ => None,
            };
            match cut {
                Some(why) => {
                    notes.push(format!(
                        "the last line ({number}: '{shown}') has no line ending and {why}: the file looks cut short (still \
                         being written?), so that line was left out"
                    ));
                    break;
                }
                None if matches!(kind, Line::Values(c) if c == columns) => notes.push(format!(
                    "the last line ({number}: '{shown}') has no line ending: if the file was cut short (still being \
                     written?) its last point may be incomplete; it was read as it is"
                )),
                None => {}
            }
        }
        if matches!(kind, Line::Values(_)) {
            decimals = decimals.after(last_decimals(line, decimal_comma));
        }
        match kind {
            Line::Blank | Line::Comment(_) => {}
            Line::TooMany(c) => return Err(err(number, too_many(c))),
            Line::BadDecimal(field) => {
                let shown: String = field.chars().take(40).collect();
                return Err(err(
                    number,
                    format!(
                        "'{shown}' is not a number with one decimal comma, but line {first_data_line} made this a \
                         semicolon-separated file with decimal commas: the file mixes two dialects, nkrr will not guess"
                    ),
                ));
            }
            Line::Words => {
                let shown: String = line.trim().chars().take(60).collect();
                return Err(err(number, format!("expected {columns} numbers, found '{shown}'")));
            }
            Line::Values(c) if c != columns => {
                return Err(err(
                    number,
                    format!("{c} values, but the first point (line {first_data_line}) has {columns}"),
                ));
            }
            Line::Values(_) => {
                declared += 1;
                let n = normals.map_or([0.0; 3], |n| n.map(|i| values[i] as f32));
                let c = match (colours, scale) {
                    (Some(c), Some(s)) => {
                        let ch = c.map(|i| (values[i] * s).round().clamp(0.0, 255.0) as u8);
                        [ch[0], ch[1], ch[2], 255]
                    }
                    _ => [0, 0, 0, 255],
                };
                if let Pushed::TooLarge { axis, value, origin } = out.push([values[ix], values[iy], values[iz]], n, c) {
                    return Err(err(number, Pushed::too_large(axis, value, origin)));
                }
            }
        }
    }
    if declared == 0 {
        return Err(err(0, notes.pop().unwrap_or_else(|| "no complete point".into())));
    }
    if out.len() == 0 {
        return Err(err(0, format!("all {declared} points have NaN or infinite coordinates")));
    }

    if let Some(n) = pts_count {
        if n != declared {
            notes.push(format!("the file's point count says {n}, but it holds {declared} points"));
        }
    }
    let ignored: Vec<String> = roles
        .iter()
        .enumerate()
        .filter(|(_, r)| **r == Role::Ignored)
        .map(|(i, _)| match (&named, &header) {
            (Some(_), Some(h)) => h[i].clone(),
            _ if i == 3 && columns % 3 == 1 => "column 4 (intensity)".to_string(),
            _ => format!("column {}", i + 1),
        })
        .collect();
    if !ignored.is_empty() {
        notes.push(format!("ignored columns: {}", ignored.join(", ")));
    }
    // Bytes, not a str slice: 4096 may fall inside a multi-byte character (the libFuzzer
    // target found that).
    let head = &text.as_bytes()[..text.len().min(4096)];
    let sep = if decimal_comma {
        "semicolon-separated with decimal commas"
    } else if head.contains(&b',') {
        "comma-separated"
    } else if head.contains(&b';') {
        "semicolon-separated"
    } else {
        "whitespace-separated"
    };
    let mut parts = vec![format!(
        "text, {columns} columns ({}), {sep}",
        if named.is_some() { "named by the header" } else { "by position" }
    )];
    if normals.is_some() {
        parts.push("normals (not needed, ignored by the reconstruction)".into());
    }
    if colours.is_some() {
        parts.push("colours".into());
    }
    let dropped = out.dropped;
    Ok(ScanFile {
        format: ScanFormat::Text,
        cloud: out.finish(),
        declared,
        dropped_non_finite: dropped,
        layout: parts.join("; "),
        comments,
        notes,
        stated_units: None,
        ply: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(s: &str) -> ScanFile {
        read_text(s.as_bytes()).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn plain_xyz() {
        let f = read("0 0 0\n1 0 0\n0 1 0\n0 0 1\n");
        assert_eq!(f.cloud.positions, vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        assert!(f.cloud.colors.is_none() && f.cloud.normals.is_none());
        assert_eq!(f.declared, 4);
    }

    #[test]
    fn csv_with_named_columns_in_any_order() {
        let f = read("red,x,y,z,green,blue,intensity\n255,1,2,3,0,128,7\n10,4,5,6,20,30,7\n");
        assert_eq!(f.cloud.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(f.cloud.colors, Some(vec![[255, 0, 128, 255], [10, 20, 30, 255]]));
        assert!(f.notes.iter().any(|n| n.contains("intensity")), "{:?}", f.notes);
    }

    #[test]
    fn pts_count_intensity_and_colours() {
        let f = read("3\n1 2 3 -200 10 20 30\n4 5 6 100 40 50 60\n7 8 9 0 70 80 90\n");
        assert_eq!(f.cloud.len(), 3);
        assert_eq!(f.cloud.colors.as_ref().unwrap()[2], [70, 80, 90, 255]);
        assert_eq!(f.notes, vec!["ignored columns: column 4 (intensity)".to_string()]);
    }

    #[test]
    fn six_columns_are_normals_or_colours_by_value() {
        let n = read("0 0 0 0 0 1\n1 0 0 0.6 0.8 0\n0 1 0 -1 0 0\n");
        assert!(n.cloud.normals.is_some() && n.cloud.colors.is_none());
        let c = read("0 0 0 0 0 1\n1 0 0 12 200 0\n0 1 0 255 0 0\n");
        assert!(c.cloud.colors.is_some() && c.cloud.normals.is_none());
        assert_eq!(c.cloud.colors.as_ref().unwrap()[1], [12, 200, 0, 255]);
        let f = read("0 0 0 0.5 0.25 1\n1 0 0 0 1 0.1\n");
        assert_eq!(f.cloud.colors.as_ref().unwrap()[0], [128, 64, 255, 255]);
    }

    #[test]
    fn nine_columns_colour_then_normals() {
        let f = read("0;0;0;10;20;30;0;0;1\n1;0;0;40;50;60;0;-1;0\n");
        assert_eq!(f.cloud.colors.as_ref().unwrap()[1], [40, 50, 60, 255]);
        assert_eq!(f.cloud.normals.as_ref().unwrap()[1], [0.0, -1.0, 0.0]);
    }

    #[test]
    fn errors_name_the_line() {
        let e = read_text(b"1 2 3\n4 5\n").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.to_string().contains("line 2"), "{e}");
        let e = read_text(b"1 2 3\n4 5 six\n").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(read_text(b"x y z\n").is_err());
        assert!(read_text(b"1 2\n3 4\n").is_err());
        assert!(read_text(b"1 2 3\n\xff\xfe 4 5\n").is_err());
    }

    #[test]
    fn far_coordinates_and_non_finite_points() {
        let f = read("5000000.25 4000000.5 10\n5000001.25 4000000.5 10\nnan 0 0\n5000000.25 4000001.5 11\n");
        assert_eq!(f.cloud.origin, [5000000.0, 4000001.0, 0.0]);
        assert_eq!(f.cloud.positions[0], [0.25, -0.5, 10.0]);
        assert_eq!(f.dropped_non_finite, 1);
        assert_eq!(f.declared, 4);
        assert!(read_text(b"nan 0 0\ninf 1 1\n").is_err());
    }

    #[test]
    fn comments_blank_lines_and_crlf() {
        let f = read("# scanner export\r\n\r\n//X,Y,Z\r\n1,2,3\r\n4,5,6\r\n");
        assert_eq!(f.cloud.len(), 2);
        assert_eq!(f.comments, vec!["scanner export".to_string()]);
    }

    #[test]
    fn a_multibyte_character_across_the_4_kb_head_is_fine() {
        let mut s = "# ".to_string() + &"x".repeat(4093) + "\u{61ca}\n";
        s.push_str("0 0 0\n1 0 0\n0 1 0\n");
        assert_eq!(s.char_indices().find(|(_, c)| *c == '\u{61ca}').map(|(i, _)| i), Some(4095));
        assert_eq!(read(&s).cloud.len(), 3);
    }

    #[test]
    fn decimal_commas_only_when_unambiguous() {
        // Plain CSV, and semicolons with decimal points, are unchanged.
        assert_eq!(read("1,2,3\n4,5,6\n").cloud.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert_eq!(read("1.5;2;3\n4;5;6\n").cloud.positions[0], [1.5, 2.0, 3.0]);
        // A header, then decimal commas; later lines may hold integers.
        let f = read("x;y;z\n1,5;2,0;3,25\n4;5,5;6\n");
        assert_eq!(f.cloud.positions, vec![[1.5, 2.0, 3.25], [4.0, 5.5, 6.0]]);
        // Decimal commas on some fields only, in the first data line: refused, with the line.
        let e = read_text(b"x;y;z\n1,5;2;3,25\n").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("will not guess"), "{e}");
        // A comma that is not between digits, after the dialect is set.
        let e = read_text(b"1,5;2,5;3,5\n1,;2,5;3,5\n").unwrap_err();
        assert_eq!(e.line, 2);
    }

    #[test]
    fn cr_nul_and_columns() {
        assert_eq!(read("0 0 0\r1 0 0\r\n0 1 0\n").cloud.len(), 3);
        let e = read_text(b"0 0 0\r1 0\x00 0\n").unwrap_err();
        assert_eq!((e.line, e.message.contains("byte 9")), (2, true), "{e}");
        let wide: String = (0..70).map(|i| format!("{i} ")).collect();
        let e = read_text(format!("0 0 0\n{wide}\n").as_bytes()).unwrap_err();
        assert!(e.line == 2 && e.message.contains("70"), "{e}");
    }

    #[test]
    fn byte_order_marks_at_the_start_and_at_a_line_start_are_not_data() {
        let body: String = (0..300).map(|i| format!("{i} {} 0.5\n", i * 2)).collect();
        for boms in 1..=3 {
            let file = "\u{feff}".repeat(boms) + &body;
            assert!(looks_like_text(file.as_bytes()));
            let f = read(&file);
            assert_eq!(f.cloud.len(), 300, "{boms} marks");
            assert_eq!(f.cloud.positions[0], [0.0, 0.0, 0.5]);
        }
        // Two files joined with `cat`, each with its mark.
        let f = read(&format!("\u{feff}1 2 3\n4 5 6\n\u{feff}7 8 9\n"));
        assert_eq!(f.cloud.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]);
    }

    #[test]
    fn a_long_first_comment_is_a_comment() {
        for len in [5_000, 100_000] {
            let file = format!("# {}\n1 2 3\n4 5 6\n7 8 10\n", "settings ".repeat(len / 9));
            assert!(looks_like_text(file.as_bytes()), "{len}");
            let f = crate::io::read_cloud(file.as_bytes(), Some("long.xyz")).unwrap();
            assert_eq!(f.cloud.len(), 3);
        }
        // Prose is still not a cloud.
        assert!(!looks_like_text(b"# notes\nthe scan of the hall, see the report\n"));
    }

    #[test]
    fn a_last_line_without_line_ending_is_named_or_left_out() {
        let lines = "0.100000 0.200000 0.300000\n1.100000 1.200000 1.300000\n";
        // Complete as far as can be told: read, and named.
        let f = read(&format!("{lines}2.100000 2.200000 2.300000"));
        assert_eq!(f.cloud.len(), 3);
        assert!(f.warnings().iter().any(|w| w.contains("last line (3") && w.contains("no line ending")), "{:?}", f.warnings());
        // Shortest round-trip values (decimals vary from line to line): read, and named.
        let f = read("0.1 0.25 0.3\n1.125 1.5 1.0625\n2.1 2.2 2.3");
        assert_eq!(f.cloud.len(), 3);
        assert!(f.warnings().iter().any(|w| w.contains("no line ending") && w.contains("read as it is")), "{:?}", f.warnings());
        // A number cut short (fewer decimals than every line before), or a value missing: left out.
        for cut in ["2.100000 2.200000 2.3", "2.100000 2.200000", "2.100000 2.200000 2.3e"] {
            let f = read(&format!("{lines}{cut}"));
            assert_eq!(f.cloud.len(), 2, "{cut}");
            assert!(f.warnings().iter().any(|w| w.contains("looks cut short") && w.contains("left out")), "{cut}: {:?}", f.warnings());
        }
        // With a line ending, no warning.
        assert!(!read(&format!("{lines}2.1 2.2 2.3\n")).warnings().iter().any(|w| w.contains("line ending")));
    }

    #[test]
    fn text_detection() {
        assert!(looks_like_text(b"1 2 3\n"));
        assert!(!looks_like_text(b"\x00\x01\x02 1"));
        assert!(!looks_like_text(b"hello world"));
    }
}
