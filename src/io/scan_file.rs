//! What a reader returns, in the same terms for every format: the [`ScanFormat`] it was, the
//! [`ScanFile`] (cloud, counts, layout, notes) and the warnings worth showing, so `nkrr info` and
//! the page say the same things whatever the format.

use std::fmt;

use super::ply;
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

impl ScanFile {
    /// The points with an all-zero normal (zero when the cloud has no normals): such normals
    /// carry no information.
    pub fn zero_normals(&self) -> usize {
        let normals = self.cloud.normals.as_deref().unwrap_or_default();
        normals.iter().filter(|v| v.iter().all(|c| *c == 0.0)).count()
    }

    /// What the cloud's size, or the file's own statement, suggests about its units.
    pub fn units_guess(&self) -> crate::units::UnitsGuess {
        // LAS is a geospatial format: without a coordinate system nkrr reads, its numbers are
        // taken as metres (the reader's note says so), whatever the size.
        if self.format == ScanFormat::Las && self.stated_units.is_none() {
            let reason = "LAS coordinates without a coordinate system nkrr reads are taken as metres".to_string();
            return crate::units::UnitsGuess { units: Some(crate::units::Units::Metres), reason, warn: false, stated: true };
        }
        // The object's size, not a reflection's distance from it (the points lying apart, which
        // the stray-point filter drops, stretch the box by any factor).
        let side = |b: Option<crate::cloud::Bounds>| b.map_or(0.0, |b| b.longest_side() as f64);
        let longest = side(crate::outliers::bulk_bounds(&self.cloud.positions));
        let mut g = crate::units::guess(longest, self.stated_units);
        let all = side(self.cloud.bounds());
        if !g.stated && all > longest {
            g.reason.push_str(&format!(" (without the few points lying apart from the rest; with them {all:.4})"));
        }
        g
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
        w.extend(cloud_warnings(&self.cloud));
        let zeros = self.zero_normals();
        if zeros > 0 && n > 0 {
            w.push(format!("{zeros} of {n} points have a zero normal (normals are not needed: nkrr ignores them)"));
        }
        w.extend(self.notes.iter().cloned());
        w
    }
}

/// Fewer points than this and a reconstruction can only be a blob.
pub const FEW_POINTS: usize = 100;

/// Warnings about the cloud itself, whatever its format: too few points, all at one place, flat.
pub fn cloud_warnings(cloud: &PointCloud) -> Vec<String> {
    let mut w = Vec::new();
    let n = cloud.len();
    if n == 1 {
        w.push("the cloud has a single point: there is no surface to reconstruct".into());
    } else if n < FEW_POINTS {
        w.push(format!("only {n} points: the reconstruction will be very coarse"));
    }
    if n > 1 {
        if let Some(b) = cloud.bounds() {
            if b.longest_side() == 0.0 {
                w.push("all points are at the same position: there is no surface to reconstruct".into());
            } else {
                let e = b.extent();
                let flat = e.iter().filter(|&&x| x <= b.longest_side() * 1e-6).count();
                if flat > 0 {
                    w.push(format!("the cloud is flat in {flat} axis(es): a closed surface will be a thin slab"));
                }
            }
        }
    }
    w
}
