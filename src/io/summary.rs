//! What to tell the user about a cloud that was read: its layout in one line and the things
//! worth a warning. Shared by `nkrr info` and the page, so both say the same.

use super::ply::{PlyCloud, PlyProperty};
use crate::cloud::PointCloud;

/// Vertex properties the pipeline reads; everything else is reported as ignored.
const USED: [&str; 10] = ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha"];

/// Fewer points than this and a reconstruction can only be a blob.
pub const FEW_POINTS: usize = 100;

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
        w
    }
}

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
