//! Any scan file in, one [`PointCloud`] out: PLY, XYZ/PTS/CSV text, LAS/LAZ and E57, told apart
//! by their content (a file's name only breaks ties and feeds a warning when it disagrees).
//!
//! Each format has its own reader module; this one detects, dispatches, and describes the
//! result the same way whatever the format, so `nkrr info` and the page say the same things.
//! Every reader follows the PLY reader's discipline: an error says what is wrong and where, no
//! input makes it panic, and nothing is allocated for a declared count before that count has
//! been checked against the bytes that could hold it.

use std::fmt;

use super::ply::{self, PlyError};
use super::{e57, las, text};
use crate::cloud::PointCloud;

/// The formats nkrr reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanFormat {
    Ply,
    /// One point per line: x y z, optionally intensity, colour and normals (XYZ, PTS, CSV, TXT).
    Text,
    /// ASPRS LAS 1.0–1.4, compressed (LAZ) or not: the header says which.
    Las,
    E57,
}

impl ScanFormat {
    pub fn name(self) -> &'static str {
        match self {
            ScanFormat::Ply => "PLY",
            ScanFormat::Text => "text (XYZ/PTS/CSV)",
            ScanFormat::Las => "LAS/LAZ",
            ScanFormat::E57 => "E57",
        }
    }

    /// The format a file name's extension suggests, if any.
    pub fn from_name(name: &str) -> Option<ScanFormat> {
        let ext = name.rsplit_once('.')?.1.to_ascii_lowercase();
        Some(match ext.as_str() {
            "ply" => ScanFormat::Ply,
            "xyz" | "pts" | "csv" | "txt" | "asc" | "xyzrgb" | "xyzn" => ScanFormat::Text,
            "las" | "laz" => ScanFormat::Las,
            "e57" => ScanFormat::E57,
            _ => return None,
        })
    }
}

impl fmt::Display for ScanFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The file extensions the readers accept, for file pickers (`accept=`) and usage texts.
pub const EXTENSIONS: [&str; 10] = ["ply", "xyz", "pts", "csv", "txt", "asc", "xyzrgb", "las", "laz", "e57"];

/// The most points a compressed file (LAZ, E57) may declare. Their counts are not bounded by
/// the file's size (a run of equal points compresses to almost nothing), so this is what keeps
/// a small hostile file from asking for gigabytes: 200M points are 2.4 GB of positions.
pub const MAX_COMPRESSED_POINTS: u64 = 200_000_000;

/// A cloud and what its file said about it, in the same terms for every format.
#[derive(Clone, Debug, PartialEq)]
pub struct ScanFile {
    pub format: ScanFormat,
    pub cloud: PointCloud,
    /// How many points the file holds (declared, or counted for text); the cloud holds this
    /// minus `dropped_non_finite` (and, for E57, minus points marked invalid).
    pub declared: u64,
    pub dropped_non_finite: u64,
    /// Format, coordinate encoding, and attributes, in one line: "LAS 1.4, point format 7
    /// (LAZ-compressed); scale 0.001 0.001 0.001, offset …; colours (16-bit)".
    pub layout: String,
    /// Comments and metadata worth showing (PLY comments, LAS system/software, E57 scan names).
    pub comments: Vec<String>,
    /// Format-specific warnings (ignored properties, skipped elements, invalid points, a
    /// name that disagrees with the content).
    pub notes: Vec<String>,
    /// The units the file itself states, when it does (E57 is in metres by definition).
    pub stated_units: Option<crate::units::Units>,
    /// The whole parsed PLY, when the file was one (its header details for `nkrr info`).
    pub ply: Option<ply::PlyInfo>,
}

/// Why a file could not be read as a cloud.
#[derive(Clone, Debug, PartialEq)]
pub enum ScanError {
    Ply(PlyError),
    Text(text::TextError),
    /// LAS/LAZ: what is wrong (and where, as the message says).
    Las(String),
    E57(String),
    /// Not a format nkrr recognises; the message says what the start of the file looked like.
    Unrecognised(String),
}

impl fmt::Display for ScanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ScanError::Ply(e) => write!(f, "{e}"),
            ScanError::Text(e) => write!(f, "{e}"),
            ScanError::Las(m) => write!(f, "LAS/LAZ: {m}"),
            ScanError::E57(m) => write!(f, "E57: {m}"),
            ScanError::Unrecognised(m) => write!(f, "{m}"),
        }
    }
}

impl std::error::Error for ScanError {}

impl From<PlyError> for ScanError {
    fn from(e: PlyError) -> Self {
        ScanError::Ply(e)
    }
}

/// The format of `bytes`, from their first bytes; `name` (a file name) is used only when the
/// content alone cannot tell.
pub fn detect(bytes: &[u8], name: Option<&str>) -> Result<ScanFormat, ScanError> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r") || bytes == b"ply" {
        return Ok(ScanFormat::Ply);
    }
    if bytes.starts_with(b"LASF") {
        return Ok(ScanFormat::Las);
    }
    if bytes.starts_with(b"ASTM-E57") {
        return Ok(ScanFormat::E57);
    }
    if bytes.is_empty() {
        return Err(ScanError::Unrecognised("the file is empty".into()));
    }
    if text::looks_like_text(bytes) {
        return Ok(ScanFormat::Text);
    }
    let said = name.and_then(ScanFormat::from_name);
    let head: String = bytes.iter().take(8).map(|b| format!("{b:02x}")).collect::<Vec<_>>().join(" ");
    let mut msg = format!(
        "not a point cloud nkrr can read: a PLY file starts with 'ply', LAS/LAZ with 'LASF', E57 with \
         'ASTM-E57', and a text cloud is lines of numbers; this file starts with bytes {head}"
    );
    if let Some(f) = said {
        msg.push_str(&format!(" (its name says {f}, but its content is not)"));
    }
    Err(ScanError::Unrecognised(msg))
}

/// Reads a cloud in any supported format. `name` is the file's name, if known: it only
/// breaks ties and adds a note when the extension and the content disagree.
pub fn read_cloud(bytes: &[u8], name: Option<&str>) -> Result<ScanFile, ScanError> {
    let format = detect(bytes, name)?;
    let mut file = match format {
        ScanFormat::Ply => from_ply(ply::read_ply(bytes)?),
        ScanFormat::Text => text::read_text(bytes).map_err(ScanError::Text)?,
        ScanFormat::Las => las::read_las(bytes).map_err(ScanError::Las)?,
        ScanFormat::E57 => e57::read_e57(bytes).map_err(ScanError::E57)?,
    };
    if let Some(said) = name.and_then(ScanFormat::from_name) {
        if said != format {
            file.notes.push(format!("the file's name says {said}, but its content is {format}: read as {format}"));
        }
    }
    Ok(file)
}

fn from_ply(parsed: ply::PlyCloud) -> ScanFile {
    let layout = parsed.describe_layout();
    let notes = parsed.format_notes();
    let mut comments = parsed.info.comments.clone();
    comments.extend(parsed.info.obj_info.iter().map(|o| format!("obj_info {o}")));
    ScanFile {
        format: ScanFormat::Ply,
        declared: parsed.info.vertex_count,
        dropped_non_finite: parsed.info.dropped_non_finite as u64,
        layout,
        comments,
        notes,
        stated_units: None,
        cloud: parsed.cloud,
        ply: Some(parsed.info),
    }
}

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

/// Builds a cloud from `f64` points, as every reader does: the origin is chosen at the first
/// finite point (see [`crate::cloud::origin_for`]) unless recentring is off, points with a
/// non-finite coordinate are counted and dropped, and attributes stay aligned with the kept
/// points.
pub(crate) struct CloudBuilder {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    colors: Option<Vec<[u8; 4]>>,
    origin: Option<[f64; 3]>,
    pub dropped: u64,
}

impl CloudBuilder {
    /// `recentre`: choose an origin for far-off points (off for coordinates an `f32` already
    /// holds exactly, such as PLY `float`s).
    pub fn new(normals: bool, colors: bool, recentre: bool) -> Self {
        CloudBuilder {
            positions: Vec::new(),
            normals: normals.then(Vec::new),
            colors: colors.then(Vec::new),
            origin: (!recentre).then_some([0.0; 3]),
            dropped: 0,
        }
    }

    /// Reserves room for `n` more points; callers pass a count already bounded by the input.
    pub fn reserve(&mut self, n: usize) {
        self.positions.reserve(n);
        if let Some(v) = &mut self.normals {
            v.reserve(n);
        }
        if let Some(v) = &mut self.colors {
            v.reserve(n);
        }
    }

    #[inline]
    pub fn push(&mut self, p: [f64; 3], normal: [f32; 3], color: [u8; 4]) {
        if !p.iter().all(|c| c.is_finite()) {
            self.dropped += 1;
            return;
        }
        let o = *self.origin.get_or_insert_with(|| crate::cloud::origin_for(p));
        let pos = [(p[0] - o[0]) as f32, (p[1] - o[1]) as f32, (p[2] - o[2]) as f32];
        if !pos.iter().all(|c| c.is_finite()) {
            self.dropped += 1;
            return;
        }
        self.positions.push(pos);
        if let Some(v) = &mut self.normals {
            v.push(normal);
        }
        if let Some(v) = &mut self.colors {
            v.push(color);
        }
    }

    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn finish(self) -> PointCloud {
        PointCloud {
            positions: self.positions,
            origin: self.origin.unwrap_or([0.0; 3]),
            normals: self.normals,
            colors: self.colors,
        }
    }
}

impl ScanFile {
    /// The points with an all-zero normal (zero when the cloud has no normals): such normals
    /// carry no information.
    pub fn zero_normals(&self) -> usize {
        let normals = self.cloud.normals.as_deref().unwrap_or_default();
        normals.iter().filter(|v| v.iter().all(|c| *c == 0.0)).count()
    }

    /// What the cloud's size, or the file's own statement, suggests about its units.
    pub fn units_guess(&self) -> crate::units::UnitsGuess {
        let longest = self.cloud.bounds().map_or(0.0, |b| b.longest_side() as f64);
        crate::units::guess(longest, self.stated_units)
    }

    /// Things the user should know before reconstructing, one sentence each.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        let n = self.cloud.len();
        if self.dropped_non_finite > 0 {
            w.push(format!(
                "{} of {} points had NaN or infinite coordinates and were dropped",
                self.dropped_non_finite, self.declared
            ));
        }
        w.extend(super::summary::cloud_warnings(&self.cloud));
        let zeros = self.zero_normals();
        if zeros > 0 && n > 0 {
            w.push(format!("{zeros} of {n} points have a zero normal (normals are not needed: nkrr ignores them)"));
        }
        w.extend(self.notes.iter().cloned());
        w
    }
}
