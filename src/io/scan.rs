//! Any scan file in, one [`PointCloud`](crate::cloud::PointCloud) out: PLY, XYZ/PTS/CSV text,
//! LAS/LAZ and E57, told apart by their content (a file's name only breaks ties and feeds a
//! warning when it disagrees).
//!
//! Each format has its own reader module; this one detects and dispatches. What every reader
//! returns (and how it is described, the same way whatever the format, so `nkrr info` and the
//! page say the same things) is in `scan_file.rs`, below the readers.
//! Every reader follows the PLY reader's discipline: an error says what is wrong and where, no
//! input makes it panic, and nothing is allocated for a declared count before that count has
//! been checked against the bytes that could hold it.

use std::fmt;

use super::ply::{self, PlyError};
use super::{e57, las, text};
pub use super::scan_file::{ScanFile, ScanFormat, EXTENSIONS, MAX_COMPRESSED_POINTS};

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
    if ply::has_magic(bytes.strip_prefix(ply::UTF8_BOM).unwrap_or(bytes)) {
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
