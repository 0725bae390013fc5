//! PLY point-cloud reader: bytes in, [`PointCloud`] out.
//!
//! The reader takes a byte slice rather than a path because the same code runs in the browser
//! (a dropped `File` read into an `ArrayBuffer`) and natively; it does no I/O of its own.
//!
//! What it accepts, and why:
//! - `ascii`, `binary_little_endian` and `binary_big_endian`, version 1.0 — the three formats of
//!   the PLY specification; scanners and tools write all of them.
//! - Vertex `x`/`y`/`z` of any of the eight numeric types (names and `int8`-style aliases):
//!   quantised scans store positions as integers, and we would rather convert than refuse.
//!   Positions are stored as `f32`; when x/y/z are `double`, `int` or `uint` and the first point
//!   lies far from 0 (georeferenced scans), they are stored relative to
//!   [`PointCloud::origin`] (see [`crate::cloud::origin_for`]), which keeps the offset in `f64`.
//! - Optional `nx`/`ny`/`nz` (read by value, whatever their type) and `red`/`green`/`blue`
//!   (`alpha` optional; `diffuse_red` etc. as aliases). Colour conversion to 0..=255:
//!   floats are taken as 0..1; 8-bit integers as 0..255; 16-bit integers as 0..65535 (divided by
//!   257, rounded); 32-bit integers as 0..255, clamped, because the writers that use `int` for a
//!   colour store 0..255 in it, not a full 32-bit range.
//! - Any other property (including list properties inside `vertex`) and any other element
//!   (faces, edges, ... before or after `vertex`) is skipped, in all three formats. They are still
//!   walked, so a truncated face list is reported rather than silently ignored.
//! - `comment` and `obj_info` lines, LF, CRLF and lone-CR (classic Mac OS) line endings, tabs
//!   and runs of spaces, blank header lines. An ascii record is one line, as the specification
//!   has it: a line with a value too many or too few is refused with its line number (read as a
//!   stream of tokens, it shifted every later value into the wrong property without a word).
//!   Data after the last declared element is not read, and said in [`PlyInfo::warnings`].
//! - Refused with the cause: a second vertex property of a name the reader uses (`x` twice:
//!   which one holds the value?), and a body declared binary that is lines of text numbers.
//!
//! Robustness contract (the input is an arbitrary file a user dropped on a web page): no input
//! makes the reader panic, loop for longer than the input's length justifies, or allocate more
//! than a small multiple of the input's size. Declared counts are checked against the bytes that
//! follow the header *before* anything is allocated, and all size arithmetic is checked or done in
//! `u128`, so `element vertex 18446744073709551615` fails at once with [`PlyError::TooManyRecords`].
//!
//! Vertices whose position has a NaN or infinite coordinate are dropped and counted in
//! [`PlyInfo::dropped_non_finite`]: one bad point should not cost the user the whole cloud, but
//! it must not reach the reconstruction either. If every vertex is dropped the cloud is useless
//! and that is an error ([`PlyError::AllNonFinite`]).

use super::builder::{CloudBuilder, Pushed};
use super::bytes::{ends_line, line_of};
use crate::cloud::PointCloud;
use std::fmt;

/// The body encoding declared on the `format` line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PlyFormat {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

impl fmt::Display for PlyFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            PlyFormat::Ascii => "ascii",
            PlyFormat::BinaryLittleEndian => "binary_little_endian",
            PlyFormat::BinaryBigEndian => "binary_big_endian",
        })
    }
}

/// One of the eight PLY numeric types. Both spellings are accepted (`uchar` / `uint8`, ...);
/// `Display` prints the classic one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ScalarType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl ScalarType {
    /// Size in bytes in the binary formats.
    pub fn size(self) -> usize {
        match self {
            ScalarType::I8 | ScalarType::U8 => 1,
            ScalarType::I16 | ScalarType::U16 => 2,
            ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }

    /// The classic PLY name (`char`, `uchar`, `short`, `ushort`, `int`, `uint`, `float`, `double`).
    pub fn name(self) -> &'static str {
        match self {
            ScalarType::I8 => "char",
            ScalarType::U8 => "uchar",
            ScalarType::I16 => "short",
            ScalarType::U16 => "ushort",
            ScalarType::I32 => "int",
            ScalarType::U32 => "uint",
            ScalarType::F32 => "float",
            ScalarType::F64 => "double",
        }
    }

    fn from_name(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => ScalarType::I8,
            "uchar" | "uint8" => ScalarType::U8,
            "short" | "int16" => ScalarType::I16,
            "ushort" | "uint16" => ScalarType::U16,
            "int" | "int32" => ScalarType::I32,
            "uint" | "uint32" => ScalarType::U32,
            "float" | "float32" => ScalarType::F32,
            "double" | "float64" => ScalarType::F64,
            _ => return None,
        })
    }

    /// `float` or `double`: list counts must not be, and colours of these types are 0..1.
    pub fn is_float(self) -> bool {
        matches!(self, ScalarType::F32 | ScalarType::F64)
    }
}

impl fmt::Display for ScalarType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The type of a property: a single value, or a list (a count followed by that many items).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PropertyKind {
    Scalar(ScalarType),
    List { count: ScalarType, item: ScalarType },
}

impl fmt::Display for PropertyKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PropertyKind::Scalar(t) => write!(f, "{t}"),
            PropertyKind::List { count, item } => write!(f, "list {count} {item}"),
        }
    }
}

/// A declared property, in declaration order.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlyProperty {
    pub name: String,
    pub kind: PropertyKind,
}

/// A declared element (`vertex`, `face`, ...) with its declared record count.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlyElement {
    pub name: String,
    pub count: u64,
    pub properties: Vec<PlyProperty>,
}

/// A parsed and validated header. Obtained from [`read_ply_header`], which needs only the header
/// bytes, so a caller can inspect a file (point count, colours, normals) from a small prefix
/// before reading the rest.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PlyHeader {
    pub format: PlyFormat,
    /// All elements in file order, `vertex` included.
    pub elements: Vec<PlyElement>,
    pub comments: Vec<String>,
    pub obj_info: Vec<String>,
    /// Byte offset of the first body byte (just past the `end_header` line's newline).
    pub body_offset: usize,
    /// Index in `elements` of the (first) `vertex` element.
    pub vertex_index: usize,
}

impl PlyHeader {
    /// The element the cloud is read from. (Panics only if `vertex_index` was changed by hand
    /// to point outside `elements`.)
    pub fn vertex(&self) -> &PlyElement {
        &self.elements[self.vertex_index]
    }
}

/// What the reader found besides the points; meant for the UI ("10,000 points, colours, 2
/// dropped") and for diagnosing odd files.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyInfo {
    pub format: PlyFormat,
    /// The count declared in the header (the cloud holds this minus `dropped_non_finite`).
    pub vertex_count: u64,
    /// Every property of the `vertex` element, used or not.
    pub vertex_properties: Vec<PlyProperty>,
    /// Name and declared count of every element other than the `vertex` one, in file order.
    pub other_elements: Vec<(String, u64)>,
    pub comments: Vec<String>,
    pub obj_info: Vec<String>,
    /// Vertices dropped because `x`, `y` or `z` was NaN or infinite (this includes `double`
    /// coordinates too large for `f32`).
    pub dropped_non_finite: usize,
    /// What the user should know about the file's structure (data after the last element).
    pub warnings: Vec<String>,
}

/// A cloud and what the file said about it.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyCloud {
    pub cloud: PointCloud,
    pub info: PlyInfo,
}

/// Vertex properties the pipeline reads; everything else is reported as ignored.
const USED: [&str; 10] = ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha"];

impl PlyCloud {
    /// "binary_little_endian; x y z: float; normals; colours" — format, coordinate type, and
    /// which optional attributes are present.
    pub fn describe_layout(&self) -> String {
        let props = &self.info.vertex_properties;
        let ty = |n: &str| props.iter().find(|p| p.name == n).map(|p| p.kind.to_string());
        let mut parts = vec![self.info.format.to_string()];
        let (tx, ty_, tz) = (ty("x"), ty("y"), ty("z"));
        if tx == ty_ && ty_ == tz {
            parts.push(format!("x y z: {}", tx.unwrap_or_default()));
        } else {
            parts.push(format!(
                "x: {}, y: {}, z: {}",
                tx.unwrap_or_default(),
                ty_.unwrap_or_default(),
                tz.unwrap_or_default()
            ));
        }
        if self.cloud.normals.is_some() {
            parts.push("normals (not needed, ignored by the reconstruction)".into());
        }
        if self.cloud.colors.is_some() {
            parts.push("colours".into());
        }
        parts.join("; ")
    }

    /// What the file holds that the pipeline does not use.
    pub fn format_notes(&self) -> Vec<String> {
        let mut w = Vec::new();
        let ignored: Vec<&PlyProperty> =
            self.info.vertex_properties.iter().filter(|p| !USED.contains(&p.name.as_str())).collect();
        if !ignored.is_empty() {
            let names: Vec<&str> = ignored.iter().map(|p| p.name.as_str()).collect();
            w.push(format!("ignored vertex properties: {}", names.join(", ")));
        }
        if !self.info.other_elements.is_empty() {
            let els: Vec<String> =
                self.info.other_elements.iter().map(|(name, count)| format!("{name} ({count})")).collect();
            w.push(format!("skipped elements: {}", els.join(", ")));
        }
        w.extend(self.info.warnings.iter().cloned());
        w
    }
}

/// Where in the body an error happened: a byte offset (binary) or a 1-based line (ascii).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BodyPos {
    Offset(usize),
    Line(usize),
}

impl fmt::Display for BodyPos {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BodyPos::Offset(o) => write!(f, "byte offset {o}"),
            BodyPos::Line(l) => write!(f, "line {l}"),
        }
    }
}

/// Why a PLY file could not be read. Every variant says where: a 1-based header line, or the
/// element, record index and property plus a byte offset or line in the body. Indices are
/// 0-based record numbers within their element.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PlyError {
    /// The file does not start with a `ply` line.
    NotPly,
    UnsupportedFormat {
        line: usize,
        format: String,
    },
    UnsupportedVersion {
        line: usize,
        version: String,
    },
    /// A header line that is not valid PLY syntax; `text` is the line (shortened).
    MalformedHeader {
        line: usize,
        reason: &'static str,
        text: String,
    },
    UnknownPropertyType {
        line: usize,
        type_name: String,
    },
    /// The input ended before an `end_header` line; `lines` is how many lines were read.
    MissingEndHeader {
        lines: usize,
    },
    NoVertexElement,
    /// The `vertex` element (declared on `line`) has no scalar property `axis`.
    MissingCoordinate {
        line: usize,
        axis: &'static str,
    },
    /// The header declares more records than the body could possibly hold: `element`'s records
    /// (together with those of the elements before it) need at least `needed` bytes, but only
    /// `available` bytes follow the header, which ends at byte offset `body_offset`.
    TooManyRecords {
        element: String,
        count: u64,
        needed: u128,
        available: usize,
        body_offset: usize,
    },
    /// A binary body ends early: reading `property` of record `index` of `element` needs
    /// `needed` bytes at byte `offset`, but the file has only `file_len` bytes.
    Truncated {
        element: String,
        index: u64,
        property: String,
        needed: u64,
        offset: usize,
        file_len: usize,
    },
    /// An ascii body ends (at `line`) before `property` of record `index` of `element`.
    UnexpectedEof {
        element: String,
        index: u64,
        property: String,
        line: usize,
    },
    /// An ascii token that is not a number of the property's type.
    BadValue {
        element: String,
        index: u64,
        property: String,
        line: usize,
        token: String,
    },
    /// A list count that is negative.
    BadListCount {
        element: String,
        index: u64,
        property: String,
        at: BodyPos,
        value: i64,
    },
    /// An ascii record (one line) that ends before its last property: it goes on on `line`.
    ShortLine {
        element: String,
        index: u64,
        properties: usize,
        first: usize,
        line: usize,
    },
    /// An ascii record (one line) with values left after its last property.
    LongLine {
        element: String,
        index: u64,
        properties: usize,
        line: usize,
        extra: String,
    },
    /// The header says `format` (binary) but the body is lines of numbers as text.
    TextBody {
        format: PlyFormat,
    },
    /// The header declares zero vertices.
    EmptyCloud,
    /// Vertex `index` has a finite coordinate too large for an `f32`; `message` says which.
    TooLarge { index: u64, message: String },
    /// Every one of the `count` vertices has a NaN or infinite coordinate.
    AllNonFinite {
        count: u64,
    },
}

impl fmt::Display for PlyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use PlyError::*;
        match self {
            NotPly => write!(f, "not a PLY file: it does not start with a 'ply' line"),
            UnsupportedFormat { line, format } => write!(
                f,
                "PLY header line {line}: unsupported format '{format}' (expected ascii, \
                 binary_little_endian or binary_big_endian)"
            ),
            UnsupportedVersion { line, version } => {
                write!(
                    f,
                    "PLY header line {line}: unsupported version '{version}' (expected 1.0)"
                )
            }
            MalformedHeader { line, reason, text } => {
                write!(f, "PLY header line {line}: {reason}: '{text}'")
            }
            UnknownPropertyType { line, type_name } => {
                write!(
                    f,
                    "PLY header line {line}: unknown property type '{type_name}'"
                )
            }
            MissingEndHeader { lines } => write!(
                f,
                "PLY header has no 'end_header' line (input ends after {lines} header lines)"
            ),
            NoVertexElement => write!(f, "PLY header declares no 'vertex' element"),
            MissingCoordinate { line, axis } => write!(
                f,
                "PLY header line {line}: element 'vertex' has no scalar property '{axis}'"
            ),
            TooManyRecords {
                element,
                count,
                needed,
                available,
                body_offset,
            } => write!(
                f,
                "PLY element '{element}' declares {count} records; with the elements before it \
                 they need at least {needed} bytes, but only {available} bytes follow the header \
                 (which ends at byte offset {body_offset})"
            ),
            Truncated {
                element,
                index,
                property,
                needed,
                offset,
                file_len,
            } => write!(
                f,
                "PLY body truncated in element '{element}' record {index}, property \
                 '{property}': needs {needed} bytes at offset {offset}, file has {file_len}"
            ),
            UnexpectedEof {
                element,
                index,
                property,
                line,
            } => write!(
                f,
                "PLY ascii body ends at line {line} in element '{element}' record {index}, \
                 before property '{property}'"
            ),
            BadValue {
                element,
                index,
                property,
                line,
                token,
            } => write!(
                f,
                "PLY ascii body line {line}: element '{element}' record {index}, property \
                 '{property}': '{token}' is not a valid value"
            ),
            BadListCount {
                element,
                index,
                property,
                at,
                value,
            } => write!(
                f,
                "PLY body at {at}: element '{element}' record {index}, list property \
                 '{property}' has negative count {value}"
            ),
            ShortLine { element, index, properties, first, line } => write!(
                f,
                "PLY ascii body line {first}: element '{element}' record {index} has fewer values than its \
                 {properties} properties and goes on on line {line}: each record must be one line (is a value \
                 missing on line {first}?)"
            ),
            LongLine { element, index, properties, line, extra } => write!(
                f,
                "PLY ascii body line {line}: element '{element}' record {index} has more values than its \
                 {properties} properties ('{extra}' left over): the line does not match the header"
            ),
            TextBody { format } => write!(
                f,
                "PLY header says 'format {format} 1.0', but the body is lines of numbers written as text: the \
                 format line should say 'format ascii 1.0' (read as binary, every point would be garbage)"
            ),
            EmptyCloud => write!(f, "PLY file declares 0 vertices"),
            TooLarge { index, message } => write!(f, "PLY vertex {index}: {message}"),
            AllNonFinite { count } => write!(
                f,
                "all {count} PLY vertices have a NaN or infinite coordinate; nothing to read"
            ),
        }
    }
}

impl std::error::Error for PlyError {}

/// Cap on how much of an offending line or token an error message quotes.
const QUOTE_MAX: usize = 80;

fn quote(bytes: &[u8]) -> String {
    let s = String::from_utf8_lossy(&bytes[..bytes.len().min(QUOTE_MAX)]);
    if bytes.len() > QUOTE_MAX {
        format!("{s}...")
    } else {
        s.into_owned()
    }
}

fn is_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | b'\n' | 0x0b | 0x0c)
}

/// The UTF-8 byte-order mark, accepted before a PLY header's magic.
pub const UTF8_BOM: &[u8] = b"\xEF\xBB\xBF";

/// Whether `bytes` (after any BOM) start with the PLY magic line: `ply` in any case, then
/// spaces or tabs at most, then a line break or the end of the bytes. Looks at 64 bytes at
/// most, so a large non-PLY file is not scanned for a newline.
pub fn has_magic(bytes: &[u8]) -> bool {
    if bytes.len() < 3 || !bytes[..3].eq_ignore_ascii_case(b"ply") {
        return false;
    }
    let rest = &bytes[3..bytes.len().min(64)];
    match rest.iter().position(|&b| b == b'\n' || b == b'\r') {
        Some(end) => rest[..end].iter().all(|&b| b == b' ' || b == b'\t'),
        None => bytes.len() <= 64 && rest.iter().all(|&b| b == b' ' || b == b'\t'),
    }
}

/// Whether the magic line at the start of `bytes` ends with a lone CR (classic Mac OS).
fn cr_only(bytes: &[u8]) -> bool {
    let head = &bytes[..bytes.len().min(64)];
    match head.iter().position(|&b| b == b'\n' || b == b'\r') {
        Some(i) => head[i] == b'\r' && bytes.get(i + 1) != Some(&b'\n'),
        None => false,
    }
}

/// Properties the reader takes values from: a second one of these names in `vertex` leaves it
/// to chance which value is read, so the header is refused.
const READ_NAMES: [&str; 14] = [
    "x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha", "diffuse_red", "diffuse_green", "diffuse_blue",
    "diffuse_alpha",
];

/// Parses and validates the header. Needs only the bytes up to and including the `end_header`
/// line, so it can be called on a prefix of a large file (a prefix that cuts the header short
/// gives [`PlyError::MissingEndHeader`]: read more); it therefore does not check declared
/// counts against the body (that is [`read_ply`]'s first step). It does check everything the
/// header alone decides: syntax, format and version, property types, that there is a `vertex`
/// element with scalar `x`, `y` and `z`, and that it declares at least one vertex.
pub fn read_ply_header(bytes: &[u8]) -> Result<PlyHeader, PlyError> {
    let mut pos = 0usize;
    let mut line_no = 0usize;
    let mut format: Option<PlyFormat> = None;
    let mut elements: Vec<PlyElement> = Vec::new();
    let mut element_lines: Vec<usize> = Vec::new();
    let mut comments = Vec::new();
    let mut obj_info = Vec::new();

    // A UTF-8 byte-order mark (some Windows editors add one) and `PLY` in capitals are
    // accepted: the rest of the file decides, and refusing them read such files as text.
    if bytes.starts_with(UTF8_BOM) {
        pos = UTF8_BOM.len();
    }
    if !has_magic(&bytes[pos..]) {
        return Err(PlyError::NotPly); // without scanning a large non-PLY file for a newline
    }
    // Lines end as the magic line ends: LF or CRLF, or a lone CR (classic Mac OS exports),
    // which read as LF made the whole file one line ("does not start with a 'ply' line").
    let end_byte = if cr_only(&bytes[pos..]) { b'\r' } else { b'\n' };
    let body_offset = loop {
        if pos >= bytes.len() {
            return Err(PlyError::MissingEndHeader { lines: line_no });
        }
        let rest = &bytes[pos..];
        let (raw, next, terminated) = match rest.iter().position(|&b| b == end_byte) {
            Some(n) => (&rest[..n], pos + n + 1, true),
            None => (rest, bytes.len(), false),
        };
        let line = raw.strip_suffix(b"\r").unwrap_or(raw);
        line_no += 1;
        pos = next;
        // An unterminated last line is a header cut short, unless it is `end_header` itself
        // (a header-only prefix, or a file whose body is empty).
        if !terminated && line.trim_ascii() != b"end_header" {
            if line_no == 1 && !line.trim_ascii().eq_ignore_ascii_case(b"ply") {
                return Err(PlyError::NotPly);
            }
            return Err(PlyError::MissingEndHeader { lines: line_no - 1 });
        }

        let malformed = |reason: &'static str| PlyError::MalformedHeader {
            line: line_no,
            reason,
            text: quote(line),
        };

        if line_no == 1 {
            if !line.trim_ascii().eq_ignore_ascii_case(b"ply") {
                return Err(PlyError::NotPly);
            }
            continue;
        }

        let trimmed = line.trim_ascii_start();
        let kw_len = trimmed
            .iter()
            .position(|&b| is_space(b))
            .unwrap_or(trimmed.len());
        let (kw, after) = trimmed.split_at(kw_len);
        match kw {
            b"comment" | b"obj_info" => {
                let text = String::from_utf8_lossy(after.trim_ascii()).into_owned();
                if kw == b"comment" {
                    comments.push(text);
                } else {
                    obj_info.push(text);
                }
                continue;
            }
            b"" => continue, // blank line: tolerated
            _ => {}
        }
        let Ok(text) = std::str::from_utf8(line) else {
            return Err(malformed("header line is not text"));
        };
        let mut toks = text.split_ascii_whitespace();
        let kw = toks.next().unwrap_or("");
        let args: Vec<&str> = toks.collect();
        match kw {
            "format" => {
                if format.is_some() {
                    return Err(malformed("second 'format' line"));
                }
                let [fmt_name, version] = args[..] else {
                    return Err(malformed("expected 'format <type> <version>'"));
                };
                format = Some(match fmt_name {
                    "ascii" => PlyFormat::Ascii,
                    "binary_little_endian" => PlyFormat::BinaryLittleEndian,
                    "binary_big_endian" => PlyFormat::BinaryBigEndian,
                    _ => {
                        return Err(PlyError::UnsupportedFormat {
                            line: line_no,
                            format: quote(fmt_name.as_bytes()),
                        })
                    }
                });
                if version.parse::<f64>() != Ok(1.0) {
                    return Err(PlyError::UnsupportedVersion {
                        line: line_no,
                        version: quote(version.as_bytes()),
                    });
                }
            }
            "element" => {
                let [name, count] = args[..] else {
                    return Err(malformed("expected 'element <name> <count>'"));
                };
                let Ok(count) = count.parse::<u64>() else {
                    return Err(malformed("element count is not an integer in 0..2^64"));
                };
                elements.push(PlyElement {
                    name: name.to_string(),
                    count,
                    properties: Vec::new(),
                });
                element_lines.push(line_no);
            }
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(malformed("'property' before any 'element'"));
                };
                let ty = |name: &str| {
                    ScalarType::from_name(name).ok_or_else(|| PlyError::UnknownPropertyType {
                        line: line_no,
                        type_name: quote(name.as_bytes()),
                    })
                };
                let (kind, name) = match args[..] {
                    ["list", count, item, name] => {
                        let count = ty(count)?;
                        let item = ty(item)?;
                        if count.is_float() {
                            return Err(malformed("list count type must be an integer type"));
                        }
                        (PropertyKind::List { count, item }, name)
                    }
                    ["list", ..] => {
                        return Err(malformed(
                            "expected 'property list <count type> <item type> <name>'",
                        ))
                    }
                    [t, name] => (PropertyKind::Scalar(ty(t)?), name),
                    _ => return Err(malformed("expected 'property <type> <name>'")),
                };
                if element.name == "vertex" && READ_NAMES.contains(&name) && element.properties.iter().any(|p| p.name == name) {
                    return Err(malformed("a second vertex property of this name: which one holds the value is not clear"));
                }
                element.properties.push(PlyProperty {
                    name: name.to_string(),
                    kind,
                });
            }
            "end_header" => {
                if !args.is_empty() {
                    return Err(malformed("text after 'end_header'"));
                }
                break pos;
            }
            _ => return Err(malformed("unknown header keyword")),
        }
    };

    let Some(format) = format else {
        return Err(PlyError::MalformedHeader {
            line: line_no,
            reason: "no 'format' line before 'end_header'",
            text: "end_header".into(),
        });
    };
    let Some(vertex_index) = elements.iter().position(|e| e.name == "vertex") else {
        return Err(PlyError::NoVertexElement);
    };
    let vertex = &elements[vertex_index];
    for axis in ["x", "y", "z"] {
        if find_scalar(vertex, &[axis]).is_none() {
            return Err(PlyError::MissingCoordinate {
                line: element_lines[vertex_index],
                axis,
            });
        }
    }
    if vertex.count == 0 {
        return Err(PlyError::EmptyCloud);
    }
    Ok(PlyHeader {
        format,
        elements,
        comments,
        obj_info,
        body_offset,
        vertex_index,
    })
}

/// Index of the first scalar property with one of `names`.
fn find_scalar(e: &PlyElement, names: &[&str]) -> Option<usize> {
    e.properties
        .iter()
        .position(|p| matches!(p.kind, PropertyKind::Scalar(_)) && names.contains(&p.name.as_str()))
}

/// Reads a whole PLY file. See the module documentation for what is accepted and how values
/// are converted.
pub fn read_ply(bytes: &[u8]) -> Result<PlyCloud, PlyError> {
    let header = read_ply_header(bytes)?;
    if header.format != PlyFormat::Ascii && looks_like_text_body(&header, &bytes[header.body_offset..]) {
        return Err(PlyError::TextBody { format: header.format });
    }
    check_capacity(&header, bytes.len())?;
    let (cloud, dropped, leftover) = match header.format {
        PlyFormat::Ascii => read_body(&header, &mut Ascii::new(bytes, header.body_offset))?,
        PlyFormat::BinaryLittleEndian => read_body(
            &header,
            &mut Binary::<false> {
                data: bytes,
                pos: header.body_offset,
            },
        )?,
        PlyFormat::BinaryBigEndian => read_body(
            &header,
            &mut Binary::<true> {
                data: bytes,
                pos: header.body_offset,
            },
        )?,
    };
    let vertex = header.vertex();
    let info = PlyInfo {
        format: header.format,
        vertex_count: vertex.count,
        vertex_properties: vertex.properties.clone(),
        other_elements: header
            .elements
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != header.vertex_index)
            .map(|(_, e)| (e.name.clone(), e.count))
            .collect(),
        comments: header.comments,
        obj_info: header.obj_info,
        dropped_non_finite: dropped,
        warnings: leftover
            .map(|l| format!("{l}: the header may declare too few records, and what follows was not read"))
            .into_iter()
            .collect(),
    };
    Ok(PlyCloud { cloud, info })
}

/// Rejects declared counts the body cannot hold, before anything is allocated. A binary record
/// needs at least the sum of its scalar sizes plus one list count per list; an ascii value needs
/// at least one character and a separator. `u128` makes overflow impossible: counts are `u64`
/// and a record's minimum size is tiny next to 2^64.
fn check_capacity(header: &PlyHeader, file_len: usize) -> Result<(), PlyError> {
    let available = file_len - header.body_offset;
    let binary = header.format != PlyFormat::Ascii;
    let mut total: u128 = 0;
    for e in &header.elements {
        let per_record: u128 = if binary {
            e.properties
                .iter()
                .map(|p| match p.kind {
                    PropertyKind::Scalar(t) => t.size() as u128,
                    PropertyKind::List { count, .. } => count.size() as u128,
                })
                .sum()
        } else {
            e.properties.len() as u128
        };
        total = total.saturating_add((e.count as u128).saturating_mul(per_record));
        let needed = if binary {
            total
        } else {
            total.saturating_mul(2).saturating_sub(1)
        };
        if needed > available as u128 {
            return Err(PlyError::TooManyRecords {
                element: e.name.clone(),
                count: e.count,
                needed,
                available,
                body_offset: header.body_offset,
            });
        }
    }
    Ok(())
}

/// Slots of the values the cloud keeps, in `VertexPlan::slots` and the per-record value array.
const X: usize = 0;
const NX: usize = 3;
const R: usize = 6;
const A: usize = 9;
const NSLOTS: usize = 10;

/// Why a read failed, before the caller adds which element/record/property it was reading.
enum Fail {
    /// Binary: `needed` bytes at `offset` run past the end.
    Truncated {
        needed: u64,
        offset: usize,
    },
    /// Ascii: the input ended at `line`.
    Eof {
        line: usize,
    },
    BadToken {
        line: usize,
        token: String,
    },
    NegativeCount {
        at: BodyPos,
        value: i64,
    },
    /// Ascii: a record that began on line `first` goes on on `line`.
    Wrapped {
        first: usize,
        line: usize,
    },
    /// Ascii: values left on `line` after the record's last property.
    Extra {
        line: usize,
        token: String,
    },
}

/// A body decoder. Binary and ascii implement it; the record walker is generic over it so
/// each format gets a monomorphised, branch-light inner loop.
trait Source {
    /// Reads one value as `f64` (exact: PLY has no 64-bit integers).
    fn scalar(&mut self, t: ScalarType) -> Result<f64, Fail>;
    /// Reads a list count (an integer type) as a non-negative count.
    fn list_count(&mut self, t: ScalarType) -> Result<u64, Fail>;
    /// Skips `n` values of type `t`.
    fn skip(&mut self, n: u64, t: ScalarType) -> Result<(), Fail>;
    /// Binary only: consumes `count` records of `size` bytes and returns their byte range,
    /// or `None` (ascii, or they do not fit, which [`check_capacity`] has already excluded).
    fn fixed_block(&mut self, count: u64, size: usize) -> Option<std::ops::Range<usize>>;
    /// Binary only: decodes a value from the start of `b`, which holds at least its size.
    fn decode(b: &[u8], t: ScalarType) -> f64;
    /// The whole input.
    fn data(&self) -> &[u8];
    /// After a record's last property (ascii: the line must end here).
    fn end_record(&mut self) -> Result<(), Fail> {
        Ok(())
    }
    /// What follows the last element, said for a warning (None when nothing does).
    fn leftover(&self) -> Option<String>;
}

struct Binary<'a, const BE: bool> {
    data: &'a [u8],
    pos: usize,
}

/// Decodes a `t` from the start of `b` (0 if `b` is too short, which callers exclude).
#[inline(always)]
fn decode<const BE: bool>(b: &[u8], t: ScalarType) -> f64 {
    macro_rules! num {
        ($t:ty) => {
            match b.first_chunk::<{ std::mem::size_of::<$t>() }>() {
                Some(&c) if BE => <$t>::from_be_bytes(c) as f64,
                Some(&c) => <$t>::from_le_bytes(c) as f64,
                None => 0.0,
            }
        };
    }
    match t {
        ScalarType::I8 => num!(i8),
        ScalarType::U8 => num!(u8),
        ScalarType::I16 => num!(i16),
        ScalarType::U16 => num!(u16),
        ScalarType::I32 => num!(i32),
        ScalarType::U32 => num!(u32),
        ScalarType::F32 => num!(f32),
        ScalarType::F64 => num!(f64),
    }
}

impl<const BE: bool> Source for Binary<'_, BE> {
    #[inline(always)]
    fn scalar(&mut self, t: ScalarType) -> Result<f64, Fail> {
        let n = t.size();
        match self.data.get(self.pos..self.pos + n) {
            Some(b) => {
                self.pos += n;
                Ok(decode::<BE>(b, t))
            }
            None => Err(Fail::Truncated {
                needed: n as u64,
                offset: self.pos,
            }),
        }
    }

    fn list_count(&mut self, t: ScalarType) -> Result<u64, Fail> {
        let at = BodyPos::Offset(self.pos);
        let v = self.scalar(t)?;
        // Integer types only (the header enforces it), so `v` is an exact integer < 2^32.
        if v < 0.0 {
            return Err(Fail::NegativeCount {
                at,
                value: v as i64,
            });
        }
        Ok(v as u64)
    }

    fn skip(&mut self, n: u64, t: ScalarType) -> Result<(), Fail> {
        let needed = n.saturating_mul(t.size() as u64);
        let left = (self.data.len() - self.pos) as u64;
        if needed > left {
            return Err(Fail::Truncated {
                needed,
                offset: self.pos,
            });
        }
        self.pos += needed as usize; // needed <= left, which is a usize
        Ok(())
    }

    fn fixed_block(&mut self, count: u64, size: usize) -> Option<std::ops::Range<usize>> {
        // check_capacity guarantees count * size <= bytes left; stay defensive anyway.
        let n = (count as u128).checked_mul(size as u128)?;
        if n > (self.data.len() - self.pos) as u128 {
            return None;
        }
        let start = self.pos;
        self.pos += n as usize;
        Some(start..self.pos)
    }

    #[inline(always)]
    fn decode(b: &[u8], t: ScalarType) -> f64 {
        decode::<BE>(b, t)
    }

    fn data(&self) -> &[u8] {
        self.data
    }

    fn leftover(&self) -> Option<String> {
        let left = self.data.len() - self.pos;
        (left > 0).then(|| format!("{left} bytes follow the last element, at byte {}", self.pos))
    }
}

struct Ascii<'a> {
    data: &'a [u8],
    pos: usize,
    /// 1-based line of `pos`.
    line: usize,
    /// The line of the current record's first value (None between records).
    record_line: Option<usize>,
}

impl<'a> Ascii<'a> {
    fn new(data: &'a [u8], body_offset: usize) -> Self {
        let line = line_of(&data[..body_offset]);
        Ascii {
            data,
            pos: body_offset,
            line,
            record_line: None,
        }
    }

    /// Next whitespace-separated token and its line. A record is one line: read as a stream of
    /// tokens, a line with a value too many or too few shifted every later value into the wrong
    /// property without a word ("0 0 0 9 9" then "1 1 1" read as (0,0,0) and (9,9,1)).
    #[inline]
    fn token(&mut self) -> Result<(&'a [u8], usize), Fail> {
        let d = self.data;
        let mut p = self.pos;
        while p < d.len() && is_space(d[p]) {
            if ends_line(d, p) {
                self.line += 1;
            }
            p += 1;
        }
        let start = p;
        while p < d.len() && !is_space(d[p]) {
            p += 1;
        }
        self.pos = p;
        if start == p {
            return Err(Fail::Eof { line: self.line });
        }
        match self.record_line {
            None => self.record_line = Some(self.line),
            Some(first) if first != self.line => return Err(Fail::Wrapped { first, line: self.line }),
            Some(_) => {}
        }
        Ok((&d[start..p], self.line))
    }

    fn parse(&mut self, t: ScalarType) -> Result<f64, Fail> {
        let (tok, line) = self.token()?;
        let bad = || Fail::BadToken {
            line,
            token: quote(tok),
        };
        let s = std::str::from_utf8(tok).map_err(|_| bad())?;
        match t {
            // Parse f32 directly: parsing as f64 and narrowing can round twice.
            ScalarType::F32 => s.parse::<f32>().map(f64::from).map_err(|_| bad()),
            ScalarType::F64 => s.parse::<f64>().map_err(|_| bad()),
            _ => s.parse::<i64>().map(|v| v as f64).map_err(|_| bad()),
        }
    }
}

impl Source for Ascii<'_> {
    fn scalar(&mut self, t: ScalarType) -> Result<f64, Fail> {
        self.parse(t)
    }

    fn list_count(&mut self, _t: ScalarType) -> Result<u64, Fail> {
        let (tok, line) = self.token()?;
        let bad = || Fail::BadToken {
            line,
            token: quote(tok),
        };
        let v = std::str::from_utf8(tok)
            .map_err(|_| bad())?
            .parse::<i64>()
            .map_err(|_| bad())?;
        if v < 0 {
            return Err(Fail::NegativeCount {
                at: BodyPos::Line(line),
                value: v,
            });
        }
        Ok(v as u64)
    }

    fn skip(&mut self, n: u64, t: ScalarType) -> Result<(), Fail> {
        // Each iteration consumes a token or fails, so this is bounded by the input length.
        for _ in 0..n {
            self.parse(t)?;
        }
        Ok(())
    }

    fn fixed_block(&mut self, _count: u64, _size: usize) -> Option<std::ops::Range<usize>> {
        None
    }

    fn decode(_b: &[u8], _t: ScalarType) -> f64 {
        0.0 // never called: fixed_block is None
    }

    fn data(&self) -> &[u8] {
        self.data
    }

    fn end_record(&mut self) -> Result<(), Fail> {
        let d = self.data;
        let mut p = self.pos;
        while p < d.len() && is_space(d[p]) && !ends_line(d, p) {
            p += 1;
        }
        if p < d.len() && !is_space(d[p]) {
            let end = (p..d.len()).find(|&i| ends_line(d, i)).unwrap_or(d.len());
            return Err(Fail::Extra { line: self.line, token: quote(d[p..end].trim_ascii()) });
        }
        self.record_line = None;
        Ok(())
    }

    fn leftover(&self) -> Option<String> {
        let rest = &self.data[self.pos..];
        let lines = rest
            .split(|&b| b == b'\n' || b == b'\r')
            .filter(|l| !l.trim_ascii().is_empty())
            .count();
        (lines > 0).then(|| {
            let first = rest.iter().position(|b| !is_space(*b)).unwrap_or(0);
            format!("{lines} more lines follow the last element, from line {}", line_of(&self.data[..self.pos + first]))
        })
    }
}

/// Turns a [`Fail`] into a [`PlyError`] naming the element, record and property.
#[cold]
fn located(fail: Fail, e: &PlyElement, index: u64, prop: usize, file_len: usize) -> PlyError {
    let element = e.name.clone();
    let property = e.properties[prop].name.clone();
    match fail {
        Fail::Eof { line } => PlyError::UnexpectedEof {
            element,
            index,
            property,
            line,
        },
        Fail::Truncated { needed, offset } => PlyError::Truncated {
            element,
            index,
            property,
            needed,
            offset,
            file_len,
        },
        Fail::BadToken { line, token } => PlyError::BadValue {
            element,
            index,
            property,
            line,
            token,
        },
        Fail::NegativeCount { at, value } => PlyError::BadListCount {
            element,
            index,
            property,
            at,
            value,
        },
        Fail::Wrapped { first, line } => PlyError::ShortLine { element, index, properties: e.properties.len(), first, line },
        Fail::Extra { line, token } => PlyError::LongLine { element, index, properties: e.properties.len(), line, extra: token },
    }
}

/// Walks every element in file order, keeping the vertex values the cloud needs.
/// Also says what follows the last element: more records than declared are points the header
/// does not count, which the user should hear of.
fn read_body<S: Source>(header: &PlyHeader, src: &mut S) -> Result<(PointCloud, usize, Option<String>), PlyError> {
    let mut cloud = PointCloud::default();
    let mut dropped = 0usize;
    for (ei, e) in header.elements.iter().enumerate() {
        if ei == header.vertex_index {
            (cloud, dropped) = read_vertices(e, src)?;
        } else {
            skip_element(e, src)?;
        }
    }
    Ok((cloud, dropped, src.leftover()))
}

/// Whether a body declared binary is in fact lines of text numbers (a wrong format line): its
/// first bytes are only digits, signs, points, exponents, spaces and line breaks, and its first
/// line holds as many numbers as the first element has properties (at least, when it has
/// lists). Binary values rarely pass the first test over a short body (`ushort` values
/// 0x0d30-0x0d36 are the bytes '0'-'6' and CR), and almost never both.
fn looks_like_text_body(header: &PlyHeader, body: &[u8]) -> bool {
    let head = &body[..body.len().min(512)];
    if head.len() < 16 || !head.iter().all(|b| b"0123456789+-.eE \t\r\n".contains(b)) {
        return false;
    }
    let Some(end) = head.iter().position(|&b| b == b'\n' || b == b'\r') else { return false };
    let Ok(line) = std::str::from_utf8(&head[..end]) else { return false };
    let values: Vec<&str> = line.split_ascii_whitespace().collect();
    let Some(first) = header.elements.iter().find(|e| e.count > 0) else { return false };
    let lists = first.properties.iter().any(|p| matches!(p.kind, PropertyKind::List { .. }));
    let fits = if lists { values.len() >= first.properties.len() } else { values.len() == first.properties.len() };
    fits && values.iter().all(|v| v.parse::<f64>().is_ok())
}

fn skip_element<S: Source>(e: &PlyElement, src: &mut S) -> Result<(), PlyError> {
    if e.properties.is_empty() {
        return Ok(()); // nothing to read, however large the count
    }
    if let Some(size) = fixed_size(e) {
        if src.fixed_block(e.count, size).is_some() {
            return Ok(());
        }
    }
    // Every record consumes at least one byte or token or fails, so this loop is bounded by
    // the input length, not by the declared count.
    for index in 0..e.count {
        for (pi, p) in e.properties.iter().enumerate() {
            let r = match p.kind {
                PropertyKind::Scalar(t) => src.skip(1, t),
                PropertyKind::List { count, item } => {
                    src.list_count(count).and_then(|n| src.skip(n, item))
                }
            };
            r.map_err(|f| located_src(f, e, index, pi, src))?;
        }
        src.end_record().map_err(|f| located_src(f, e, index, e.properties.len() - 1, src))?;
    }
    Ok(())
}

/// Record size in bytes if the element has no list property.
fn fixed_size(e: &PlyElement) -> Option<usize> {
    e.properties
        .iter()
        .map(|p| match p.kind {
            PropertyKind::Scalar(t) => Some(t.size()),
            PropertyKind::List { .. } => None,
        })
        .sum()
}

/// [`located`] with the file length taken from the source.
#[cold]
fn located_src<S: Source>(
    fail: Fail,
    e: &PlyElement,
    index: u64,
    prop: usize,
    src: &S,
) -> PlyError {
    located(fail, e, index, prop, src.data().len())
}

/// How each vertex property is used: the value slot it fills, if any.
struct VertexPlan {
    slots: Vec<Option<usize>>,
    types: [ScalarType; NSLOTS],
    has_normals: bool,
    has_colors: bool,
    has_alpha: bool,
}

fn plan(e: &PlyElement) -> VertexPlan {
    let mut slots = vec![None; e.properties.len()];
    let mut types = [ScalarType::F32; NSLOTS];
    let mut set = |names: &[&str], slot: usize| -> bool {
        match find_scalar(e, names) {
            Some(i) => {
                slots[i] = Some(slot);
                if let PropertyKind::Scalar(t) = e.properties[i].kind {
                    types[slot] = t;
                }
                true
            }
            None => false,
        }
    };
    // x, y, z exist: read_ply_header checked.
    set(&["x"], X);
    set(&["y"], X + 1);
    set(&["z"], X + 2);
    let n = [set(&["nx"], NX), set(&["ny"], NX + 1), set(&["nz"], NX + 2)];
    let c = [
        set(&["red", "diffuse_red"], R),
        set(&["green", "diffuse_green"], R + 1),
        set(&["blue", "diffuse_blue"], R + 2),
    ];
    let has_alpha = set(&["alpha", "diffuse_alpha"], A);
    let has_normals = n.iter().all(|&b| b);
    let has_colors = c.iter().all(|&b| b);
    if !has_normals {
        slots
            .iter_mut()
            .for_each(|s| *s = s.filter(|&s| !(NX..NX + 3).contains(&s)));
    }
    if !has_colors {
        slots.iter_mut().for_each(|s| *s = s.filter(|&s| s < R));
    }
    VertexPlan {
        slots,
        types,
        has_normals,
        has_colors,
        has_alpha: has_colors && has_alpha,
    }
}

/// Colour channel to 0..=255; see the module documentation for the rules.
fn color_u8(v: f64, t: ScalarType) -> u8 {
    let v = match t {
        ScalarType::F32 | ScalarType::F64 => v * 255.0,
        ScalarType::I16 | ScalarType::U16 => v / 257.0,
        _ => v,
    };
    // `as u8` saturates and maps NaN to 0.
    v.round().clamp(0.0, 255.0) as u8
}

/// Decodes one vertex's used values into the shared [`CloudBuilder`] (which recentres far-off
/// clouds and counts vertices with a non-finite position instead of storing them).
#[inline(always)]
fn push_vertex(out: &mut CloudBuilder, v: &[f64; NSLOTS], p: &VertexPlan) -> Pushed {
    let normal = if p.has_normals { [v[NX] as f32, v[NX + 1] as f32, v[NX + 2] as f32] } else { [0.0; 3] };
    let colour = if p.has_colors {
        let t = &p.types;
        let a = if p.has_alpha { color_u8(v[A], t[A]) } else { 255 };
        [color_u8(v[R], t[R]), color_u8(v[R + 1], t[R + 1]), color_u8(v[R + 2], t[R + 2]), a]
    } else {
        [0; 4]
    };
    out.push([v[X], v[X + 1], v[X + 2]], normal, colour)
}

/// Refuses a vertex whose position an `f32` cannot hold (see [`Pushed`]).
fn check_pushed(pushed: Pushed, index: u64) -> Result<(), PlyError> {
    match pushed {
        Pushed::TooLarge { axis, value, origin } => {
            Err(PlyError::TooLarge { index, message: Pushed::too_large(axis, value, origin) })
        }
        _ => Ok(()),
    }
}

fn read_vertices<S: Source>(e: &PlyElement, src: &mut S) -> Result<(PointCloud, usize), PlyError> {
    let p = plan(e);
    // check_capacity has bounded e.count by the body length (at least 3 bytes or tokens per
    // vertex), so this reservation is justified by the input and fits in usize.
    let cap = usize::try_from(e.count).unwrap_or(0);
    // Only types whose values an f32 may not hold exactly are recentred; `float` coordinates are
    // read as-is.
    let wide = p.types[X..X + 3].iter().any(|t| matches!(t, ScalarType::F64 | ScalarType::I32 | ScalarType::U32));
    let mut out = CloudBuilder::new(p.has_normals, p.has_colors, wide);
    out.reserve(cap);
    let mut v = [0f64; NSLOTS];
    let fixed = fixed_size(e).filter(|&size| size > 0);
    if let Some(range) = fixed.and_then(|size| src.fixed_block(e.count, size)) {
        // Binary records of one size (the common case): decode the used values at precomputed
        // offsets, with no per-value bounds bookkeeping.
        let size = fixed.unwrap_or(1);
        let mut used = Vec::new();
        let mut off = 0;
        for (prop, slot) in e.properties.iter().zip(&p.slots) {
            if let PropertyKind::Scalar(t) = prop.kind {
                if let Some(s) = *slot {
                    used.push((off, t, s));
                }
                off += t.size();
            }
        }
        for (index, rec) in src.data()[range].chunks_exact(size).enumerate() {
            for &(off, t, s) in &used {
                v[s] = S::decode(&rec[off..], t);
            }
            check_pushed(push_vertex(&mut out, &v, &p), index as u64)?;
        }
    } else {
        for index in 0..e.count {
            for (pi, (prop, slot)) in e.properties.iter().zip(&p.slots).enumerate() {
                let r = match (prop.kind, slot) {
                    (PropertyKind::Scalar(t), Some(s)) => src.scalar(t).map(|x| v[*s] = x),
                    (PropertyKind::Scalar(t), None) => src.skip(1, t),
                    (PropertyKind::List { count, item }, _) => {
                        src.list_count(count).and_then(|n| src.skip(n, item))
                    }
                };
                r.map_err(|f| located_src(f, e, index, pi, src))?;
            }
            src.end_record().map_err(|f| located_src(f, e, index, e.properties.len() - 1, src))?;
            check_pushed(push_vertex(&mut out, &v, &p), index)?;
        }
    }
    if out.len() == 0 {
        return Err(PlyError::AllNonFinite { count: e.count });
    }
    let dropped = out.dropped as usize;
    Ok((out.finish(), dropped))
}
